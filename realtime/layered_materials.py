r"""Layered ("goopy") materials: where the inner layer is seen through a clear coat, the seed's parallax
offset without refraction against Snell's refracted offset; the seed's blur radii and layer composite.

The seed (000:1127-1371, Oat 2006, "Rendering Goopy Materials with Multiple Layers", ATI)
-----------------------------------------------------------------------------------------
A two-layer material: an outer layer (albedo, normal map, opacity) over an inner layer (albedo) at a
homogeneous distance d below it. The inner layer's texture coordinate is offset by parallax (000:1189-1217,
listing 1, ``ParallaxOffsetAndDepth``): the tangent-space view vector V is reflected about the normal N
(``reflect(-V, N)``), its z negated so that it points into the material ("the transmission vector"), the
transmission distance is s = d/|T_z| and the offset is s·T_xy (times a texel size: d is in texels). For the
flat normal N = (0, 0, 1) of a smooth coat, T = (−V_x, −V_y, −cos θ): the view ray continued **straight**
into the material, and

    offset = d·tan θ,  s = d/cos θ                         (seed: no refraction)

with θ the view angle from the normal. The inner layer's lighting is a texture-space light map blurred by a
13-tap Poisson disc of radius d texels (000:1221-1290, listing 2, ``PoissonFilter``; the tap table is
`POISSON_TAPS`), its albedo blurred by the same disc of radius s (000:1291-1319), and the composite
(000:1321-1331, listing 3) is ``lerp(outer·light, inner_albedo·inner_light, alpha·saturate(N·V))``.

Errata (seed lines): listing 1 (000:1199) declares the parameter ``mViewTS`` but reads ``vViewTS`` (one
name, read as V); listing 3 (000:1326) passes ``fLayerThicknes`` (read as fLayerThickness); the texel size
is hard-coded for a 1024² texture (000:1206, 000:1262): this module works in scene units (the offset
divided by the texel's world size is the seed's texel count). In listing 3 the lerp weight is the outer
base map's alpha times N·V and the weight **of the inner layer**: alpha = 1 shows the inner layer, so the
stored alpha acts as the outer layer's transparency, not the "opacity" the comment (000:1323) names;
`seed_composite` follows the code.

The exact quantity (``layer_offset``, scene units)
---------------------------------------------------
A smooth dielectric coat of relative index η = n_coat/n_outside ≥ 1 and thickness d over the base (the base
immersed in the coat: no second interface). The view ray refracts at the coat (Snell: sin θ_t = sin θ/η)
and meets the base at the lateral offset

    offset = d·tan θ_t = d·sin θ/√(η² − sin²θ),  s = d/cos θ_t      (exact; ``refracted``)

from the point where it entered (Born & Wolf §1.5.1; what HLSL's ``refract(−V, N, 1/η)`` gives an engine:
the best modern form, e.g. the clear-coat "refraction" parallax of layered shading models such as
Weidlich & Wilkie 2007, "Arbitrarily layered micro-facet surfaces", whose layers are seen through the
refracted direction). The seed overestimates it by tan θ/tan θ_t: √(η² − sin²θ)/cos θ, which is η at
normal incidence and grows without bound at grazing (at 60°: 2.02 for η = 1.33, 2.45 for η = 1.5; the
issue's "≈ 2× at 60°" is the water-like coat's). Rows:

* ``seed``: d·tan θ as printed (the effective depth equal to the true thickness);
* ``seed-scaled``: k·d·tan θ with the effective-depth scale k ∈ [0.05, 2] fitted (an artist's thickness:
  fits the mean, not the angle dependence);
* ``apparent-depth``: d·tan θ/η, the paraxial apparent depth d/η (Hecht, Optics, 5th ed. §5.2.3): exact to
  O(θ³) at normal incidence, low at grazing (it keeps tan θ);
* ``refracted`` (exact): d·tan θ_t.

Units, domain, float32
----------------------
``cos_theta`` = v·n ∈ [0, 1] (dimensionless, clamped: rounding), ``depth`` d ∈ [0, 1000] scene units,
``eta`` η ∈ [1, 4] (a coat denser than the outside: no total internal reflection on the way in; η is floored
at 1, the reason: below 1 the refracted ray may not exist). The result is in d's units. Guards (reasons):
cos θ is floored at `COS_MIN` = 1e-6 in the seed forms (the seed divides by |T_z| with no guard: at grazing
view its offset is unbounded; the floor keeps it finite, ≤ 1e6·d); cos θ_t = √(η² − sin²θ)/η is ≥
√(1 − 1/η²) > 0 for η > 1 and reaches 0 only at η = 1, θ = 90° (no coat, grazing): floored at the same
`COS_MIN`. sin θ is √((1 − c)(1 + c)) (relative accuracy near c = 1); η² − sin²θ is evaluated as
(η − 1)(η + 1) + cos²θ, without the cancellation of η² − sin²θ near η = 1 at grazing view (float32: the
refracted row equals the seed's at η = 1 to rounding, not to 4e-6). No NaN or Inf for inputs in the
domain (tests/test_layered_materials.py, hypothesis). Public functions validate NumPy inputs (one-line
ValueError); Dr.Jit arrays are not checked (the kernels clamp).

The composite (quantity ``coated_radiance``, W/m²/sr per channel)
-----------------------------------------------------------------
The radiance the camera sees of a clear coat over a diffuse base of albedo ρ under a uniform sky of radiance
L (the audit's second case). For a uniform base it is exact (energy balance of the coat's internal
reflections; the smooth-plastic model of Mitsuba's ``plastic``, after Weidlich & Wilkie 2007):

    L_o = F(θ)·L + (1 − F(θ))·(1 − F̄_ext)·ρ·L/(η²·(1 − ρ·F̄_int))

with F(θ) the dielectric Fresnel at the view angle, F̄_ext the cosine-weighted hemispherical mean of F seen
from outside and F̄_int = 1 − (1 − F̄_ext)/η² the internal one (reciprocity; total internal reflection
included): sky light enters with (1 − F̄_ext)πL, the base reflects ρ of it, a fraction F̄_int of that returns
to the base, the rest leaves, compressed by 1/η² in radiance. The case supplies F, F̄_ext, F̄_int (Mitsuba's
``fresnel`` and a float64 quadrature of it) and ρ read by Mitsuba at two base points: ``albedo_seed`` where
the seed's straight ray meets the base, ``albedo_refracted`` where the refracted ray does. Rows:

* ``seed-composite``: listing 3 for a clear coat: the outer layer has no diffuse albedo (its term is 0), the
  inner light is the uniform light map L (irradiance πL over π), so L_o = a·cos θ·ρ_seed·L with a = 1 (a
  clear outer layer: the inner layer fully shown); ``seed-composite-alpha``: a ∈ (0, 1) fitted;
* ``fresnel-lerp``: lerp(ρ_refr·L, L, F(θ)): the modern cheap form, a Fresnel-weighted layer blend at the
  refracted point (no internal reflections, no 1/η²);
* ``coated-diffuse`` (exact for a uniform base; on a texture the base's light is mixed over a few d by the
  internal reflections, which this leaves out: the seed's blur's job).

The blurred inner albedo (quantity ``coated_radiance``; 000:1291-1319)
------------------------------------------------------------------------
The seed blurs the inner albedo by listing 2's Poisson disc (the centre and the 12 `POISSON_TAPS`, a plain
mean) of radius s = d/cos θ (its transmission distance, listing 3) around the parallax-offset point. Here the
base's albedo is a kernel input, a `BaseTexture` (one channel's texels on a window of the base's uv square,
read bilinearly with ``ops.gather``, clamped to the window's edge: the seed's ``tex2D``), the centre a uv
point and the radius in scene units (divided by the base's scene units per uv: the seed's texel count times
its texel size). The mean is written c + Σ_k (t_k − c)/n (equal to the seed's Σ/n; at zero radius it is the
centre's texel value exactly). Rows (the radius scale k ∈ [0, 4] fitted, 1 as printed):

* ``seed-blur``: listing 3 with the 13-tap blurred albedo at the seed's point, r = k·d/cos θ, alpha fitted
  (``seed-composite-alpha`` is its unblurred comparison);
* ``coated-blur-1``, ``-5``, ``-13``: the coated-diffuse closed form with the albedo blurred at the
  refracted point, r = k·d/cos θ_t (Snell's transmission distance), by 1 tap (the texture read there, no
  blur: the comparison), 5 taps (the centre and `TAPS_5`, four of the seed's taps chosen here with the
  smallest centroid and anisotropy; not the seed's) and the seed's 13.

The exact counterpart is a scattering slab (a homogeneous medium between the coat and the base, Mitsuba
``volpath``): no closed form; the rows stand or fall by their RMSE against it. At grazing view the seed's
radius d/COS_MIN is huge; the taps then read the window's clamped edge (finite).

The blurred light map (quantity ``inner_irradiance``, W/m² per channel; 000:1221-1290)
-------------------------------------------------------------------------------------
The seed renders the outer layer's local diffuse lighting (N·L times the light, shadowed) into texture space
(a light map E_map(u, v), W/m²) and lights the inner layer with it blurred by listing 2's disc of radius
proportional to the outer layer's thickness d ("fLayerThickness" texels in listing 3: radius d). Here the
light map is a kernel input, a `BaseTexture` of E_map on the inner layer's uv window (the layers share one
texture space; (u, v) the G-buffer's point on the inner layer), read by the same `_poisson_kernel`. Rows
(E_in the irradiance the inner layer receives):

* ``lightmap-local``: E_in = t·E_map(u, v), the local light map unblurred, t ∈ [0, 2] fitted (the slab's
  transmission);
* ``lightmap-seed``: E_in = PoissonFilter(E_map, (u, v), d) as printed (t = 1, radius d: no attenuation);
* ``lightmap-blur``: E_in = t·PoissonFilter(E_map, (u, v), k·d), t and k ∈ [0, 4] fitted.

Listing 2's 12 taps are not zero-mean: their sum is (0.365428, −1.25609), so the 13-tap mean of a linear
ramp is the ramp at (u, v) + r·(0.0281, −0.0966)/units_per_uv, not at the centre (a shift of 0.1·r along
−v). At d = 0 every row reads the centre (t·E_map); a huge d reads the window's clamped edge (finite).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .arrays import cached_table, check_range, clamp01, evaluate, safe_sqrt, sin_from_cos
from .methods import Input, Method, Param, method_table

__all__ = [  # METHODS and INPUTS stay out: every family has its own (not re-exported by rtfit.realtime)
    "BLUR_MAX",
    "COS_MIN",
    "POISSON_TAPS",
    "TAPS_5",
    "BaseTexture",
    "lightmap_irradiance",
    "poisson_albedo",
    "refracted_offset",
    "seed_blur_radii",
    "seed_composite",
    "seed_offset",
]

COS_MIN = 1e-6
"""Floor of cos θ (and cos θ_t): the seed's offset d·tan θ is unbounded at grazing view (module docstring)."""
ETA_MAX = 4.0
DEPTH_MAX = 1e3
POISSON_TAPS = (
    (-0.326212, -0.40581), (-0.840144, -0.07358), (-0.695914, 0.457137), (-0.203345, 0.620716),
    (0.96234, -0.194983), (0.473434, -0.480026), (0.519456, 0.767022), (0.185461, -0.893124),
    (0.507431, 0.064425), (0.89642, 0.412458), (-0.32194, -0.932615), (-0.791559, -0.59771),
)  # fmt: skip
"""The seed's 12 Poisson-disc taps on the unit disc (000:1266-1271); the 13th tap is the centre."""
TAPS_5 = tuple(POISSON_TAPS[i] for i in (1, 3, 7, 9))
"""Four of the seed's taps for a 5-tap disc (with the centre): ours, the subset with the smallest centroid
and second-moment anisotropy (the seed has only 13)."""
BLUR_MAX = 4.0
"""The upper bound of the fitted blur radius scale k (the seed: 1)."""


@dataclass(frozen=True, eq=False)
class BaseTexture:
    """The base's albedo: ``texels`` (C, H, W) or (H, W) (C channels; H, W ≥ 2; row j along v) at the texel
    centres of the uv window ``window`` = (u0, v0, u1, v1), and ``units_per_uv`` = (|∂p/∂u|, |∂p/∂v|), the
    base's scene units per unit uv (a radius in scene units → uv). Read bilinearly, clamped to the window's
    edge; the channel is a kernel input (one texture object for every channel: a constant of a fit)."""

    texels: np.ndarray
    window: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)
    units_per_uv: tuple[float, float] = (1.0, 1.0)
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        t = np.asarray(self.texels, np.float64)
        t = t[None] if t.ndim == 2 else t
        u0, v0, u1, v1 = self.window
        if t.ndim != 3 or min(t.shape[1:]) < 2 or not np.all(np.isfinite(t)):
            raise ValueError(f"BaseTexture: texels must be finite (C, H, W), H, W ≥ 2 (got shape {t.shape})")
        if not (u1 > u0 and v1 > v0 and min(self.units_per_uv) > 0.0):
            raise ValueError(f"BaseTexture: need u1 > u0, v1 > v0, units_per_uv > 0 (got {self.window})")
        object.__setattr__(self, "texels", t)

    def _table(self, ops, like):
        return cached_table(self._tables, ops, like, (), lambda: self.texels)

    def bilinear(self, ops, u, v, channel=0.0):
        """The bilinear read of ``channel`` at (u, v), clamped to the window's edge texels (the seed's
        tex2D)."""
        nc, h, w = self.texels.shape
        u0, v0, u1, v1 = self.window
        x = ops.clip((u - u0) * (w / (u1 - u0)) - 0.5, 0.0, w - 1.0)
        y = ops.clip((v - v0) * (h / (v1 - v0)) - 0.5, 0.0, h - 1.0)
        x0, y0 = ops.minimum(ops.floor(x), w - 2.0), ops.minimum(ops.floor(y), h - 2.0)
        fx, fy = x - x0, y - y0
        c = ops.clip(ops.floor(channel + 0.5), 0.0, nc - 1.0)
        table, i = self._table(ops, u), (c * h + y0) * w + x0
        top = ops.gather(table, i) * (1.0 - fx) + ops.gather(table, i + 1.0) * fx
        bottom = ops.gather(table, i + w) * (1.0 - fx) + ops.gather(table, i + (w + 1.0)) * fx
        return top * (1.0 - fy) + bottom * fy

    def sample(self, ops, u, v, channel=0.0):
        """The sampler protocol of `rtfit.realtime.arrays.evaluate` (passed to a kernel as it is)."""
        return self.bilinear(ops, u, v, channel)


# ===================================================================================== kernels (ops text)
def _tan(ops, cos_theta):
    """tan θ = sin θ/max(cos θ, COS_MIN) for cos θ clamped to [0, 1] (the floor: module docstring)."""
    c = clamp01(ops, cos_theta)
    return sin_from_cos(ops, c) / ops.maximum(c, COS_MIN)


def _seed_kernel(ops, cos_theta, depth, scale):
    """The seed's listing 1 with a flat normal: s·|T_xy| = (d/cos θ)·sin θ, times the depth scale k."""
    return (scale * ops.maximum(depth, 0.0)) * _tan(ops, cos_theta)


def _refracted_kernel(ops, cos_theta, depth, eta):
    """d·tan θ_t, sin θ_t = sin θ/η (Snell): d·sin θ/√(η² − sin²θ), the root floored (module docstring)."""
    c = clamp01(ops, cos_theta)
    s = sin_from_cos(ops, c)
    e = ops.maximum(eta, 1.0)
    root = safe_sqrt(ops, (e - 1.0) * (e + 1.0) + c * c)  # η·cos θ_t = √(η² − sin²θ) = √(η² − 1 + cos²θ)
    return ops.maximum(depth, 0.0) * s / ops.maximum(root, COS_MIN * e)


def _apparent_depth_kernel(ops, cos_theta, depth, eta):
    """The paraxial apparent depth d/η seen along the seed's straight ray: (d/η)·tan θ."""
    return ops.maximum(depth, 0.0) / ops.maximum(eta, 1.0) * _tan(ops, cos_theta)


def _seed_radii_kernel(ops, cos_theta, depth):
    """The seed's blur radii (listing 3): the light map's d, the albedo's s = d/cos θ (cos θ floored)."""
    d = ops.maximum(depth, 0.0)
    return d, d / ops.maximum(clamp01(ops, cos_theta), COS_MIN)


def _seed_coat_kernel(ops, cos_theta, albedo_seed, sky, alpha):
    """Listing 3 for a clear coat: lerp(0, ρ_seed·L, alpha·saturate(N·V)) (module docstring)."""
    return _composite_kernel(ops, 0.0, albedo_seed * sky, alpha, cos_theta)


def _fresnel_lerp_kernel(ops, albedo_refracted, sky, fresnel):
    """lerp(ρ_refr·L, L, F): the Fresnel-weighted blend of the base and the coat's mirror of the sky."""
    f = clamp01(ops, fresnel)
    return sky * (f + (1.0 - f) * albedo_refracted)


def _coated_diffuse_kernel(ops, albedo_refracted, sky, fresnel, eta, fdr_ext, fdr_int):
    """F·L + (1 − F)(1 − F̄_ext)ρL/(η²(1 − ρF̄_int)); 1 − ρF̄_int ≥ 1 − 1·F̄_int > 0 for η ≥ 1 (F̄_int < 1:
    the refraction cone's light leaves), floored at 1e-6 (the reason: ρ = F̄_int = 1 would divide by 0)."""
    f = clamp01(ops, fresnel)
    rho = clamp01(ops, albedo_refracted)
    e = ops.maximum(eta, 1.0)
    inner = (
        (1.0 - clamp01(ops, fdr_ext)) * rho / (e * e * ops.maximum(1.0 - rho * clamp01(ops, fdr_int), 1e-6))
    )
    return sky * (f + (1.0 - f) * inner)


def _taps(n: int):
    return {1: (), 5: TAPS_5, 13: POISSON_TAPS}[n]


def _poisson_kernel(ops, texture, channel, u, v, radius, taps):
    """Listing 2: the mean of the centre and the taps at (u, v) + r·p_k (r in scene units → uv), written
    c + Σ(t_k − c)/n: zero radius gives the centre's value exactly."""
    c = texture.bilinear(ops, u, v, channel)
    su, sv = texture.units_per_uv
    r = ops.maximum(radius, 0.0)
    acc = 0.0 * c
    for ox, oy in _taps(taps):
        acc = acc + (texture.bilinear(ops, u + (ox / su) * r, v + (oy / sv) * r, channel) - c)
    return c + acc * (1.0 / taps)


def _seed_blur_kernel(ops, cos_theta, depth, texture, channel, u_seed, v_seed, sky, alpha, blur, taps):
    """Listing 3, the albedo blurred by listing 2 at the seed's point, radius k·d/cos θ (cos θ floored)."""
    _, s = _seed_radii_kernel(ops, cos_theta, depth)
    rho = _poisson_kernel(ops, texture, channel, u_seed, v_seed, blur * s, taps)
    return _seed_coat_kernel(ops, cos_theta, rho, sky, alpha)


def _coated_blur_kernel(ops, cos_theta, depth, eta, texture, channel, u_refracted, v_refracted, sky, fresnel,
                        fdr_ext, fdr_int, blur, taps):  # fmt: skip
    """Coated diffuse with the albedo blurred at the refracted point, radius k·d/cos θ_t (cos θ_t floored)."""
    c = clamp01(ops, cos_theta)
    e = ops.maximum(eta, 1.0)
    cos_t = safe_sqrt(ops, (e - 1.0) * (e + 1.0) + c * c) / e
    r = blur * ops.maximum(depth, 0.0) / ops.maximum(cos_t, COS_MIN)
    rho = _poisson_kernel(ops, texture, channel, u_refracted, v_refracted, r, taps)
    return _coated_diffuse_kernel(ops, rho, sky, fresnel, eta, fdr_ext, fdr_int)


def _lightmap_kernel(ops, lightmap, channel, u, v, depth, transmit, blur, taps):
    """The inner layer's irradiance: t × listing 2's mean of the light map at (u, v), radius k·d (taps 1:
    the local light map read at (u, v))."""
    return transmit * _poisson_kernel(ops, lightmap, channel, u, v, blur * ops.maximum(depth, 0.0), taps)


def _composite_kernel(ops, outer, inner, alpha, cos_theta):
    """Listing 3: lerp(outer, inner, alpha·saturate(N·V)) (the inner layer's weight: module docstring)."""
    w = clamp01(ops, alpha) * clamp01(ops, cos_theta)
    return outer + (inner - outer) * w


# ===================================================================================== public API
def _cos(cos_theta):
    return check_range("cos_theta", cos_theta, -1e-4, 1.0 + 1e-4, interval="[0, 1]")


def _depth(depth):
    return check_range("depth", depth, 0.0, DEPTH_MAX)


def _eta(eta):
    return check_range("eta", eta, 1.0, ETA_MAX)


def seed_offset(cos_theta, depth, scale=1.0):
    """The seed's inner-layer offset k·d·tan θ (scene units of d; k = 1 as printed)."""
    return evaluate(_seed_kernel, _cos(cos_theta), _depth(depth), check_range("scale", scale, 0.0, 1e3))


def refracted_offset(cos_theta, depth, eta):
    """The exact offset d·tan θ_t through a smooth coat of relative index η (Snell; scene units of d)."""
    return evaluate(_refracted_kernel, _cos(cos_theta), _depth(depth), _eta(eta))


def seed_blur_radii(cos_theta, depth):
    """(light-map radius d, albedo radius d/cos θ) of the seed's Poisson discs (units of d)."""
    return evaluate(_seed_radii_kernel, _cos(cos_theta), _depth(depth))


def poisson_albedo(texture: BaseTexture, u, v, radius, taps: int = 13, channel=0.0):
    """The seed's Poisson-disc mean (listing 2) of ``texture``'s ``channel`` at (u, v), radius in scene
    units; taps 1, 5 or 13."""
    if taps not in (1, 5, 13):
        raise ValueError(f"taps must be 1, 5 or 13 (got {taps})")
    r = check_range("radius", radius, 0.0, 1e9)

    def kernel(ops, texture, channel, u, v, r):
        return _poisson_kernel(ops, texture, channel, u, v, r, taps)

    return evaluate(kernel, texture, channel, u, v, r)


def lightmap_irradiance(lightmap: BaseTexture, u, v, depth, scale=1.0, transmit=1.0, taps: int = 13,
                        channel=0.0):  # fmt: skip
    """The inner layer's irradiance t·PoissonFilter(light map, (u, v), k·d) (W/m² of the light map; taps 1,
    5 or 13; k = ``scale``, 1 as printed)."""
    if taps not in (1, 5, 13):
        raise ValueError(f"taps must be 1, 5 or 13 (got {taps})")
    d, k = _depth(depth), check_range("scale", scale, 0.0, BLUR_MAX)
    t = check_range("transmit", transmit, 0.0, 1e3)

    def kernel(ops, lightmap, channel, u, v, d, t, k):
        return _lightmap_kernel(ops, lightmap, channel, u, v, d, t, k, taps)

    return evaluate(kernel, lightmap, channel, u, v, d, t, k)


def seed_composite(outer, inner, alpha, cos_theta):
    """The seed's layer composite lerp(outer, inner, alpha·saturate(cos θ)) (units of outer and inner)."""
    return evaluate(_composite_kernel, outer, inner, check_range("alpha", alpha, 0.0, 1.0), _cos(cos_theta))


# ===================================================================================== methods as data
_COS = Input("cos_theta", "1", "v·n: cosine of the view angle at the coat (viewer's side)", (0.0, 1.0))
_DEPTH = Input("depth", "m", "d: the coat's thickness along the normal (scene units)", (0.0, DEPTH_MAX))
_ETA = Input("eta", "1", "η: the coat's index relative to the outside (≥ 1)", (1.0, ETA_MAX))
INPUTS = (_COS, _DEPTH, _ETA)
"""The quantity ``layer_offset``'s inputs."""
_SEED = "Oat 2006, Rendering Goopy Materials, ParallaxOffsetAndDepth (seed 000:1189-1217, listing 1)"
_SCALE = Param(1.0, 0.05, 2.0, unit="1", description="effective depth scale k (the seed: 1)", published=False)

_ALBEDO_SEED = Input("albedo_seed", "1", "ρ of the base where the seed's straight ray meets it", (0.0, 1.0))
_ALBEDO_REFR = Input("albedo_refracted", "1", "ρ of the base where the refracted ray meets it", (0.0, 1.0))
_SKY = Input("sky", "W/m²/sr", "L: the uniform sky's radiance", (0.0, 1e4))
_FRESNEL = Input("fresnel", "1", "F(θ): the coat's Fresnel reflectance at the view angle", (0.0, 1.0))
_FDR_EXT = Input("fdr_ext", "1", "F̄_ext: the coat's cosine-weighted mean Fresnel, outside", (0.0, 1.0))
_FDR_INT = Input("fdr_int", "1", "F̄_int = 1 − (1 − F̄_ext)/η²: the mean Fresnel inside", (0.0, 1.0))
COMPOSITE_INPUTS = (_COS, _ETA, _ALBEDO_SEED, _ALBEDO_REFR, _SKY, _FRESNEL, _FDR_EXT, _FDR_INT)
"""The quantity ``coated_radiance``'s inputs."""
_SEED_COMPOSITE = "Oat 2006, the layer composite (seed 000:1321-1331, listing 3)"

METHODS = method_table(
    [
        Method(
            "seed",
            "Seed parallax offset (no refraction)",
            _seed_kernel,
            inputs=(_COS, _DEPTH),
            fixed={"scale": 1.0},
            quantity="layer_offset",
            formula="offset = d·tan θ (reflect(−V, N), z negated, times d/|T_z|)",
            source=_SEED,
            description="The view ray continued straight into the coat: too long by tan θ/tan θ_t.",
        ),
        Method(
            "seed-scaled",
            "Seed offset, fitted depth scale",
            _seed_kernel,
            inputs=(_COS, _DEPTH),
            params={"scale": _SCALE},
            quantity="layer_offset",
            formula="offset = k·d·tan θ, k fitted",
            source=_SEED + " with the layer thickness tuned (an effective depth)",
        ),
        Method(
            "apparent-depth",
            "Apparent depth d/η (paraxial)",
            _apparent_depth_kernel,
            inputs=INPUTS,
            quantity="layer_offset",
            formula="offset = (d/η)·tan θ",
            source="paraxial Snell: apparent depth d/η (Hecht, Optics, 5th ed. §5.2.3)",
            description="Exact near normal incidence; low at grazing view.",
        ),
        Method(
            "refracted",
            "Refracted offset (Snell)",
            _refracted_kernel,
            inputs=INPUTS,
            exact=True,
            quantity="layer_offset",
            formula="offset = d·tan θ_t = d·sin θ/√(η² − sin²θ)",
            source="Snell's law (Born & Wolf §1.5.1); HLSL refract(−V, N, 1/η)",
            description="Exact for a smooth coat over its base (the best modern form).",
        ),
        Method(
            "seed-composite",
            "Seed composite (clear coat)",
            _seed_coat_kernel,
            inputs=(_COS, _ALBEDO_SEED, _SKY),
            fixed={"alpha": 1.0},
            quantity="coated_radiance",
            formula="L_o = lerp(0, ρ(uv + d·tan θ)·L, a·N·V), a = 1",
            source=_SEED_COMPOSITE + " with listing 1's offset",
            description="No coat reflection; the inner layer faded by N·V: black at grazing view.",
        ),
        Method(
            "seed-composite-alpha",
            "Seed composite, fitted alpha",
            _seed_coat_kernel,
            inputs=(_COS, _ALBEDO_SEED, _SKY),
            params={
                "alpha": Param(
                    0.9, 0.0, 1.0, unit="1", description="a: the outer layer's alpha", published=False
                )
            },
            quantity="coated_radiance",
            formula="L_o = a·cos θ·ρ(uv + d·tan θ)·L, a fitted",
            source=_SEED_COMPOSITE,
        ),
        Method(
            "fresnel-lerp",
            "Fresnel lerp at the refracted point",
            _fresnel_lerp_kernel,
            inputs=(_ALBEDO_REFR, _SKY, _FRESNEL),
            quantity="coated_radiance",
            formula="L_o = lerp(ρ(uv + d·tan θ_t)·L, L, F(θ))",
            source="a clear-coat layer blend weighted by Fresnel (e.g. the Disney/OpenPBR coat's 1 − F "
            "attenuation of the base), at Snell's offset",
        ),
        Method(
            "coated-diffuse",
            "Coated diffuse (internal reflections)",
            _coated_diffuse_kernel,
            inputs=(_ALBEDO_REFR, _SKY, _FRESNEL, _ETA, _FDR_EXT, _FDR_INT),
            quantity="coated_radiance",
            formula="L_o = F·L + (1 − F)(1 − F̄_ext)ρL/(η²(1 − ρF̄_int))",
            source="smooth plastic (Weidlich & Wilkie 2007; Mitsuba 3 plastic), at Snell's offset",
            description="Exact for a uniform base under a uniform sky; a texture's lateral mixing left out.",
        ),
    ]
)
_TEXTURE = Input("texture", "1", "the base's albedo (`BaseTexture`: its texels on a uv window)")
_CHANNEL = Input("channel", "1", "the texture's channel: 0 red, 1 green, 2 blue", (0.0, 2.0))
_U_SEED = Input("u_seed", "1", "u of the base where the seed's straight ray meets it", (0.0, 1.0))
_V_SEED = Input("v_seed", "1", "v of the base where the seed's straight ray meets it", (0.0, 1.0))
_U_REFR = Input("u_refracted", "1", "u of the base where the refracted ray meets it", (0.0, 1.0))
_V_REFR = Input("v_refracted", "1", "v of the base where the refracted ray meets it", (0.0, 1.0))
BLUR_INPUTS = (_COS, _DEPTH, _ETA, _TEXTURE, _CHANNEL, _U_SEED, _V_SEED, _U_REFR, _V_REFR)
"""The blur rows' inputs beside the composite's."""
_BLUR = Param(1.0, 0.0, BLUR_MAX, unit="1", description="k: the blur radius over the transmission distance",
              published=False)  # fmt: skip
_SEED_BLUR = "Oat 2006, PoissonFilter of the inner albedo (seed 000:1291-1319, listings 2, 3)"


def _coated_blur(taps: int) -> Method:
    return Method(
        f"coated-blur-{taps}",
        f"Coated diffuse, albedo blurred ({taps} taps)",
        _coated_blur_kernel,
        inputs=(_COS, _DEPTH, _ETA, _TEXTURE, _CHANNEL, _U_REFR, _V_REFR, _SKY, _FRESNEL, _FDR_EXT, _FDR_INT),
        params={} if taps == 1 else {"blur": _BLUR},
        fixed={"taps": taps, **({"blur": 0.0} if taps == 1 else {})},
        quantity="coated_radiance",
        formula="L_o = coated diffuse, ρ the mean over the disc of radius k·d/cos θ_t at the refracted point"
        if taps > 1
        else "L_o = coated diffuse with ρ read from the texture at the refracted point (no blur)",
        source=f"{_SEED_BLUR}: the seed's disc at Snell's point and transmission distance",
    )


METHODS = method_table(
    [
        *METHODS.values(),
        Method(
            "seed-blur",
            "Seed composite, albedo blurred (13 taps)",
            _seed_blur_kernel,
            inputs=(_COS, _DEPTH, _TEXTURE, _CHANNEL, _U_SEED, _V_SEED, _SKY),
            params={"alpha": METHODS["seed-composite-alpha"].params["alpha"], "blur": _BLUR},
            fixed={"taps": 13},
            quantity="coated_radiance",
            formula="L_o = a·cos θ·PoissonFilter(ρ, uv + d·tan θ, k·d/cos θ)·L, a and k fitted",
            source=_SEED_BLUR,
            description="The seed's view-dependent blur of the inner albedo at its parallax point.",
        ),
        *(_coated_blur(n) for n in (1, 5, 13)),
    ]
)
_LIGHTMAP = Input("lightmap", "W/m²", "E_map: the outer layer's local diffuse lighting (N·L, shadowed) in "
                  "texture space (`BaseTexture` on the inner layer's uv window)")  # fmt: skip
_U = Input("u", "1", "u of the inner layer's point (the G-buffer's uv)", (0.0, 1.0))
_V = Input("v", "1", "v of the inner layer's point (the G-buffer's uv)", (0.0, 1.0))
_THICK = Input("depth", "m", "d: the outer layer's thickness above the point (scene units)", (0.0, DEPTH_MAX))
LIGHTMAP_INPUTS = (_LIGHTMAP, _CHANNEL, _U, _V, _THICK)
"""The quantity ``inner_irradiance``'s inputs."""
_TRANSMIT = Param(0.7, 0.0, 2.0, unit="1", description="t: the outer layer's transmission", published=False)
_SEED_LIGHT = "Oat 2006, PoissonFilter of the light map (seed 000:1221-1290, listings 2, 3)"
METHODS = method_table(
    [
        *METHODS.values(),
        Method(
            "lightmap-local",
            "Local light map (no blur), fitted transmission",
            _lightmap_kernel,
            inputs=LIGHTMAP_INPUTS,
            params={"transmit": _TRANSMIT},
            fixed={"blur": 0.0, "taps": 1},
            quantity="inner_irradiance",
            formula="E_in = t·E_map(u, v), t fitted",
            source="the light map read where the inner point lies (the unblurred comparison)",
        ),
        Method(
            "lightmap-seed",
            "Seed light map blur (13 taps, radius d)",
            _lightmap_kernel,
            inputs=LIGHTMAP_INPUTS,
            fixed={"transmit": 1.0, "blur": 1.0, "taps": 13},
            quantity="inner_irradiance",
            formula="E_in = PoissonFilter(E_map, (u, v), d)",
            source=_SEED_LIGHT,
            description="The inner layer lit by the blurred light map as printed: no attenuation.",
        ),
        Method(
            "lightmap-blur",
            "Light map blur, fitted radius and transmission",
            _lightmap_kernel,
            inputs=LIGHTMAP_INPUTS,
            params={"transmit": _TRANSMIT, "blur": replace(_BLUR, description="k: the blur radius over d")},
            fixed={"taps": 13},
            quantity="inner_irradiance",
            formula="E_in = t·PoissonFilter(E_map, (u, v), k·d), t and k fitted",
            source=_SEED_LIGHT + " with its radius scale and a transmission fitted",
        ),
    ]
)
"""The layered-materials family's methods (module docstring): quantities ``layer_offset`` (the first four),
``coated_radiance`` and ``inner_irradiance`` (the light-map rows)."""
LIGHTMAP_ROWS = ("lightmap-local", "lightmap-seed", "lightmap-blur")
OFFSET_ROWS = tuple(k for k, m in METHODS.items() if m.quantity == "layer_offset")
BLUR_ROWS = ("seed-blur", "coated-blur-1", "coated-blur-5", "coated-blur-13")
COMPOSITE_ROWS = tuple(
    k for k, m in METHODS.items() if m.quantity == "coated_radiance" and k not in BLUR_ROWS
)  # the light-map rows: LIGHTMAP_ROWS
