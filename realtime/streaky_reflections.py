r"""Streaky reflections: a light's reflection in a wet street as its mirror image streaked vertically.

The seed (000:757-807, Tatarchuk 2006, ToyShop, §3.5.1 "View-dependent streaky reflections")
-------------------------------------------------------------------------------------------
Bright lights reflected in wet streets "stretch very strongly toward the viewer, distorting the original
reflecting object vertically proportional to the distance from the viewer" (000:759). The demo renders a
proxy quad per bright object into a half-size reflection buffer at its mirror position, "dynamically
stretched view-dependently toward the viewer in the vertex shader ... The amount of stretching varies
depending on the distance of the object to the viewer" (000:775), blurs the buffer "in the *vertical*
direction only" (000:801) and samples it "using screen space projection" on the street (000:803). The seed
gives no stretch law beyond "proportional to the distance" and no blur width: both are fitted here.

The physics it replaces: a rough specular ground (GGX microfacets, a dielectric interface such as water on
asphalt, η = 1.33, or a rough conductor) lit by one small light (a sphere of radius r, or a point) seen by
a low camera: the glossy lobe around the mirror direction, stretched toward the viewer at grazing angles.
A small-angle reading of the lobe (docs/streaky-reflections.md) gives its extent on screen: vertically
≈ 2α/(1 + h/H) radians (camera height h, light height H), independent of the light's distance D;
horizontally ≈ 2αH/D. The seed's quad, whose projected size is ∝ 1/D, stretched by a factor ∝ D, has the
same aspect law (height/width ∝ D).

Screen coordinates are **image-plane units**: tangents on the camera's plane at unit focal length
(x right or left as the camera's local x, y its up axis), ≈ radians near the centre, independent of the
film's resolution. ``du``, ``dv``: the pixel centre's offset from the light's mirror image (its mirror
point c' = c − 2((c − p₀)·n)n projected); ``rho`` = r/z' the mirror image's radius (z' its depth along the
camera axis; 0 for a point light); ``e_mirror`` = L_e·F(θ_m)·π·rho² (W/m²/sr × image-plane area): the
mirror image's radiance L_e·F at the mirror angle θ_m times its area (for a point light of intensity I,
F·I/z'², the same limit); ``distance`` D: camera to light (m).

Methods (`METHODS`, one kernel text each)
-----------------------------------------
* ``streak-seed``: the mirror image (a Gaussian of the disc's energy and variance rho²/4 per axis)
  convolved with an anisotropic Gaussian, σx fitted, σy = k·D (the seed's stretch ∝ distance, k fitted):

      L = A·e_mirror·exp(−½(du²/Sx + dv²/Sy))/(2π√(Sx·Sy)),  Sx = σx² + rho²/4,  Sy = (k·D)² + σy₀² + rho²/4

  with σy₀ = 0 (its variant ``streak-fixed`` has k = 0 and σy₀ fitted: anisotropic, no view dependence).
  A: the streak's energy over the mirror image's (1 for α → 0, where the lobe is the mirror image).
* ``streak-quad``: the seed's vertex-shader stretch read literally: the proxy quad keeps its projected
  size rho (∝ 1/D) as the unit, widened by w and stretched by k·D in that unit (Sx = rho²(w² + ¼),
  Sy = rho²((k·D)² + ¼)): σy ∝ D·rho is then constant in D, σx ∝ 1/D, the small-angle lobe's laws. A point
  light (rho = 0) has no quad: the row is then the mirror image alone.
* ``isotropic``: Sx = Sy = σ² + rho²/4, σ fitted: the naive constant blur.
* ``ggx-point``: the microfacet BRDF of the ground evaluated per pixel toward the light's centre (the
  "point-light microfacet" form, exact as the light's solid angle → 0):

      L = E⊥·F(v·h)·D(n·h)·G₁(n·v)·G₁(n·l)/(4·n·v),  D = α²/(π((α² − 1)(n·h)² + 1)²),
      G₁(c) = 2/(1 + √(1 + α²(1 − c²)/c²))

  (Walter et al. 2007, GGX with the separable Smith masking that Mitsuba 3's ``roughplastic`` and
  ``roughconductor`` use); E⊥ = L_e·Ω (W/m²) the light's irradiance at normal incidence (Ω its solid
  angle from the point; I/d² for a point light), F the material's Fresnel at v·h (an input: the audit
  passes Mitsuba's own, so a dielectric and a conductor share the row; its ~10 flops are not in the cost).

Float32 and domain: every Gaussian variance is floored at `MIN_VARIANCE` (a reason: σ → 0 on a point
light, rho = 0, would divide by zero; the floor is far below a pixel's extent²) and σ's enter squared (a
fit may cross 0); the GGX row floors α at `MIN_ALPHA` (α → 0 makes D a delta: the row is then 0 off the
mirror direction and finite on it), n·v at `MIN_COS` (grazing view: the 1/(4 n·v) factor stays finite
and G₁(n·v) → 0 takes it to 0), c² in G₁'s tangent at 1e-30 (a light on the horizon: G₁ → 0, not 0/0) and
returns 0 where the light or the viewer is below the plane (n·l ≤ 0, n·v ≤ 0: no reflection). No NaN or
Inf for finite inputs in the declared domains (tests/test_streaky_reflections.py, hypothesis).
"""

from __future__ import annotations

import math

from .arrays import check_range, evaluate
from .methods import Input, Method, Param, method_table
from .quantity_types import Quantity

__all__ = [
    "MIN_ALPHA",
    "MIN_COS",
    "MIN_VARIANCE",
    "ggx_point_radiance",
    "streak_radiance",
]

MIN_VARIANCE = 1e-12
"""Floor of a Gaussian variance (image-plane units²): a point light's mirror image with σ → 0 divides by it
instead of by 0 (a pixel at 64² and 40° is ~1e-2 wide: the floor is 1e-8 of a pixel's extent²)."""
MIN_ALPHA = 1e-4
"""Floor of the GGX roughness α: α = 0 (a mirror) makes D a delta; at the floor D is finite everywhere."""
MIN_COS = 1e-6
"""Floor of n·v in 1/(4 n·v): a grazing view stays finite (G₁(n·v) → 0 takes the product to 0)."""
_TINY = 1e-30  # c² floor in G₁'s tan²θ = (1 − c²)/c² and the D denominator: a light on the horizon → 0


# ======================================================================== kernels (one text each)
def _gaussian(ops, du, dv, sx2, sy2):
    """The normalised anisotropic Gaussian exp(−½(du²/Sx + dv²/Sy))/(2π√(Sx·Sy)) (1/image-plane area)."""
    sx2 = ops.maximum(sx2, MIN_VARIANCE)
    sy2 = ops.maximum(sy2, MIN_VARIANCE)
    return ops.exp(-0.5 * (du * du / sx2 + dv * dv / sy2)) / (2.0 * math.pi * ops.sqrt(sx2 * sy2))


def _streak_kernel(ops, du, dv, e_mirror, rho, distance, amplitude, sigma_x, k, sigma_y):
    disc = 0.25 * rho * rho
    stretch = k * distance
    sx2 = sigma_x * sigma_x + disc
    sy2 = stretch * stretch + sigma_y * sigma_y + disc
    return amplitude * e_mirror * _gaussian(ops, du, dv, sx2, sy2)


def _quad_kernel(ops, du, dv, e_mirror, rho, distance, amplitude, width, k):
    r2 = rho * rho
    stretch = k * distance
    return (
        amplitude
        * e_mirror
        * _gaussian(ops, du, dv, r2 * (width * width + 0.25), r2 * (stretch * stretch + 0.25))
    )


def _isotropic_kernel(ops, du, dv, e_mirror, rho, amplitude, sigma):
    s2 = sigma * sigma + 0.25 * rho * rho
    return amplitude * e_mirror * _gaussian(ops, du, dv, s2, s2)


def _smith_g1(ops, c, a2):
    """Smith's GGX masking G₁ = 2/(1 + √(1 + α² tan²θ)) of a direction at cos θ = c > 0 from the normal."""
    c2 = ops.maximum(c * c, _TINY)
    return 2.0 / (1.0 + ops.sqrt(1.0 + a2 * ops.maximum(1.0 - c2, 0.0) / c2))


def _ggx_point_kernel(ops, cos_nl, cos_nv, cos_nh, fresnel_h, e_perp, alpha):
    a = ops.maximum(alpha, MIN_ALPHA)
    a2 = a * a
    nh = ops.minimum(ops.maximum(cos_nh, 0.0), 1.0)
    den = (a2 - 1.0) * (nh * nh) + 1.0
    ndf = a2 / (math.pi * ops.maximum(den * den, _TINY))
    nl = ops.maximum(cos_nl, 0.0)
    nv = ops.maximum(cos_nv, MIN_COS)
    g = _smith_g1(ops, nv, a2) * _smith_g1(ops, nl, a2)
    value = e_perp * fresnel_h * ndf * g / (4.0 * nv)
    return ops.select((cos_nl > 0.0) & (cos_nv > 0.0), value, 0.0 * value)


# ===================================================================================== methods (data)
_STREAK_INPUTS = (
    Input("du", "1", "image-plane offset from the light's mirror image, horizontal (tangents)", (-4.0, 4.0)),
    Input("dv", "1", "image-plane offset from the light's mirror image, vertical (tangents)", (-4.0, 4.0)),
    Input("e_mirror", "W/m²/sr", "the mirror image's radiance L_e·F(θ_m) × its image-plane area π·rho²",
          (0.0, 1e4)),
    Input("rho", "1", "the mirror image's radius r/z' in image-plane units (0: a point light)", (0.0, 0.5)),
)  # fmt: skip
_DISTANCE = Input("distance", "m", "camera to light distance D", (0.01, 1e3))
_GGX_INPUTS = (
    Input("cos_nl", "1", "n·l: the plane's normal and the unit direction to the light's centre", (-1.0, 1.0)),
    Input("cos_nv", "1", "n·v: the normal and the unit direction to the camera", (-1.0, 1.0)),
    Input("cos_nh", "1", "n·h: the normal and the half vector h (v + l normalised)", (-1.0, 1.0)),
    Input("fresnel_h", "1", "the material's Fresnel reflectance at v·h (Mitsuba's, per channel)", (0.0, 1.0)),
    Input("e_perp", "W/m²", "the light's irradiance at normal incidence L_e·Ω (I/d² for a point light)",
          (0.0, 1e4)),
    Input("alpha", "1", "the ground's GGX roughness α", (0.0, 1.0)),
)  # fmt: skip
_AMPLITUDE = Param(
    1.0, 0.0, 100.0, unit="1",
    description="the streak's energy / the mirror image's (1: the mirror limit α → 0)",
)  # fmt: skip


def _sigma(initial: float, what: str) -> Param:
    return Param(
        initial, 0.0, 2.0, unit="1", description=f"{what} (image-plane units ≈ rad)", published=False
    )


_SEED = "seed 000:757-807 (ToyShop §3.5.1: mirror-image proxies stretched ∝ distance, blurred vertically)"
METHODS = method_table(
    [
        Method(
            id="streak-seed",
            label="seed: mirror image streaked vertically, σy = k·D",
            kernel=_streak_kernel,
            inputs=(*_STREAK_INPUTS, _DISTANCE),
            params={
                "amplitude": _AMPLITUDE,
                "sigma_x": _sigma(0.01, "horizontal blur σx"),
                "k": Param(
                    0.004,
                    0.0,
                    1.0,
                    unit="1/m",
                    published=False,
                    description="vertical stretch per metre of the light's distance (σy = k·D)",
                ),
            },
            fixed={"sigma_y": 0.0},
            quantity="streak_radiance",
            formula="L = A·E_m·N(du, dv; σx² + ρ²/4, (k·D)² + ρ²/4), N the normalised 2-D Gaussian",
            source=_SEED,
        ),
        Method(
            id="streak-fixed",
            label="anisotropic streak, σy fixed (no view dependence)",
            kernel=_streak_kernel,
            inputs=(*_STREAK_INPUTS, _DISTANCE),
            params={
                "amplitude": _AMPLITUDE,
                "sigma_x": _sigma(0.01, "horizontal blur σx"),
                "sigma_y": _sigma(0.05, "vertical blur σy"),
            },
            fixed={"k": 0.0},
            quantity="streak_radiance",
            formula="L = A·E_m·N(du, dv; σx² + ρ²/4, σy² + ρ²/4)",
            source=f"{_SEED}, without the distance law (the stretch's control row)",
        ),
        Method(
            id="streak-quad",
            label="seed's quad: the mirror image's own size, widened by w, stretched by k·D",
            kernel=_quad_kernel,
            inputs=(*_STREAK_INPUTS, _DISTANCE),
            params={
                "amplitude": _AMPLITUDE,
                "width": Param(
                    2.0,
                    0.0,
                    1e3,
                    unit="1",
                    published=False,
                    description="horizontal blur w in units of the mirror image's radius rho",
                ),
                "k": Param(
                    0.5,
                    0.0,
                    1e3,
                    unit="1/m",
                    published=False,
                    description="vertical stretch per metre of distance, in units of rho (σy = k·D·rho)",
                ),
            },
            quantity="streak_radiance",
            formula="L = A·E_m·N(du, dv; ρ²(w² + ¼), ρ²((k·D)² + ¼))",
            source=f"{_SEED}: the proxy quad (its projected size ∝ 1/D) stretched in the vertex shader ∝ D",
        ),
        Method(
            id="isotropic",
            label="isotropic blur of the mirror image (σ fitted)",
            kernel=_isotropic_kernel,
            inputs=_STREAK_INPUTS,
            params={"amplitude": _AMPLITUDE, "sigma": _sigma(0.02, "blur σ")},
            quantity="streak_radiance",
            formula="L = A·E_m·N(du, dv; σ² + ρ²/4, σ² + ρ²/4)",
            source="the naive baseline: a constant screen-space blur of the reflection buffer",
        ),
        Method(
            id="ggx-point",
            label="GGX microfacet BRDF toward the light's centre",
            kernel=_ggx_point_kernel,
            inputs=_GGX_INPUTS,
            quantity="streak_radiance",
            formula="L = E⊥·F(v·h)·D(n·h)·G₁(n·v)·G₁(n·l)/(4 n·v), GGX D, separable Smith G",
            source="Walter et al. 2007 (EGSR, GGX); Mitsuba 3 roughplastic/roughconductor's specular lobe",
        ),
    ]
)
"""The family's rows on ``streak_radiance`` (module docstring)."""

QUANTITIES = (
    Quantity(
        "streak_radiance",
        "W/m²/sr",
        "radiance a rough specular plane reflects toward the camera from one small light, per channel",
        (*_STREAK_INPUTS, _DISTANCE, *_GGX_INPUTS),
        reference="the plane's pixels path traced (Mitsuba path) with that light alone",
        note="image-plane units: tangents at unit focal length (≈ rad); the mirror image of the light in the "
        "plane is at (du, dv) = 0",
    ),
)


# ===================================================================================== public API
def streak_radiance(du, dv, e_mirror, rho=0.0, distance=10.0, amplitude=1.0, sigma_x=0.0, k=0.0, sigma_y=0.0):
    """The streak rows' radiance L (W/m²/sr) of the module docstring: offsets ``du``, ``dv`` and ``rho`` in
    image-plane units, ``e_mirror`` ≥ 0 (W/m²/sr × image-plane area), ``distance`` D > 0 m, ``amplitude``
    ≥ 0, blur widths σx, σy₀ (image-plane units) and stretch ``k`` (1/m); ``k`` = σy₀ = 0 with σx = σ is
    not the isotropic row (that one also blurs vertically by σ)."""
    check_range("e_mirror", e_mirror, 0.0, 3.4e38, interval="[0, 3.4e38] (a radiance × area: not negative)")
    check_range("rho", rho, 0.0, 1e3, interval="[0, 1e3] (a radius in image-plane units)")
    check_range("distance", distance, 0.0, 1e30, interval="[0, 1e30] m (camera to light)")
    check_range("amplitude", amplitude, 0.0, 1e30, interval="[0, 1e30] (an energy ratio: not negative)")
    return evaluate(_streak_kernel, du, dv, e_mirror, rho, distance, amplitude, sigma_x, k, sigma_y)


def ggx_point_radiance(cos_nl, cos_nv, cos_nh, fresnel_h, e_perp, alpha):
    """The ``ggx-point`` row's radiance L (W/m²/sr): cosines in [−1, 1] (1e-4 of rounding tolerated),
    ``fresnel_h`` in [0, 1], ``e_perp`` ≥ 0 W/m², ``alpha`` in [0, 1] (the GGX roughness)."""
    for name, v in (("cos_nl", cos_nl), ("cos_nv", cos_nv), ("cos_nh", cos_nh)):
        check_range(name, v, -1.0001, 1.0001, interval="[-1, 1] (a cosine; 1e-4 of rounding tolerated)")
    check_range("fresnel_h", fresnel_h, 0.0, 1.0, interval="[0, 1] (a reflectance)")
    check_range("e_perp", e_perp, 0.0, 3.4e38, interval="[0, 3.4e38] W/m² (an irradiance: not negative)")
    check_range("alpha", alpha, 0.0, 1.0, interval="[0, 1] (GGX roughness)")
    return evaluate(_ggx_point_kernel, cos_nl, cos_nv, cos_nh, fresnel_h, e_perp, alpha)
