r"""Diffuse lighting from one light: Lambert, half-Lambert, wrap lighting, exact sphere-light irradiance.

Conventions and units
---------------------
* ``cos_theta`` = n·l, with n the unit surface normal and l the unit direction from the shaded point TO the
  light (its centre, for a sphere light). Values are clamped to [−1, 1] (rounding of dot products).
* ``irradiance`` (W/m²) is the irradiance the light delivers at normal incidence, E⊥; the cosine-law models
  return irradiance in W/m² on the surface. Outgoing radiance of a Lambertian surface of albedo ρ is E·ρ/π.
* ``radiance`` (W/m²/sr) is the uniform radiance of a spherical light; ``alpha`` (radians) its angular
  radius seen from the point, α = asin(r/d) for a sphere of radius r at distance d.

Formulas
--------
* Lambert:        E = E⊥ · max(cos θ, 0)
* Half-Lambert:   E = E⊥ · (½ cos θ + ½)²                 (Valve, "Shading in Valve's Source Engine",
  SIGGRAPH 2006 course "Advanced Real-Time Rendering in 3D Graphics and Games", §7.4.4 "Half Lambert
  Diffuse"; seed file ``000_540fc7eee6870c4d.txt`` lines 2520–2534). Non-physical: not zero below the
  horizon, E⊥/4 at θ = 90°.
* Wrap lighting:  E = E⊥ · max((cos θ + w)/(1 + w), 0)^p,  w ∈ [0, 1], p ∈ (0, 8].
  (w, p) = (0, 1) is Lambert, (1, 2) is half-Lambert, (1, 1) is the exact irradiance of a uniform
  hemisphere light (see below).
* Exact irradiance of a uniform sphere light of radiance L and angular radius α ∈ [0, π/2], including the
  horizon-clipped case (Snyder 1996, "Area light sources for real-time graphics", MSR-TR-96-11; also
  Lagarde & de Rousiers 2014, "Moving Frostbite to Physically Based Rendering", §4.7 "Area lights",
  illuminance of a sphere light with the horizon):

  - cos θ ≥ sin α (whole cap above the horizon):   E = π sin²α cos θ · L
  - cos θ ≤ −sin α (whole cap below):               E = 0
  - otherwise, with y = −cos α cos θ / (sin α sin θ) ∈ [−1, 1] and s = √(1 − y²):

        E/L = sin²α cos θ acos(y) − cos α sin α sin θ s + atan2(sin α sin θ s, cos α)

    The last two terms cancel to O(α²) for small α (in float32 the textbook form loses ~3 digits for the sun,
    α = 0.27°), so the kernel evaluates, with g = sin α sin θ s and
    u = g / cos α = tan α sin θ s ∈ [0, tan α],

        E/L = sin²α (cos θ acos(y) + u) + (atan(u) − u)         for u < 0.3; atan(u) − u from its alternating
                                                                  Taylor series to u²⁵ (truncation ≤ u²⁷/27,
                                                                  ≤ 3e-14 relative to atan(u) − u)
        E/L = sin²α cos θ acos(y) + (atan2(g, cos α) − g cos α)  for u ≥ 0.3 (then α ≥ 16.7°: the
                                                                  cancellation is mild; finite at α = π/2)

  Measured against mpmath quadrature of ∫_cap max(n·ω, 0) dω (tests/test_diffuse.py, docs/diffuse.md):
  |error| ≤ 1e-15 · π sin²α L in float64 and ≤ 7.3e-7 · π sin²α L in Dr.Jit float32 (LLVM: 6.3e-7, its
  float32 atan2 is ≤ 12 ulp; CUDA/H100: 7.3e-7); for small lights the float32 error inside the horizon
  band is ≤ 2.2e-7 · π sin³α L. sin α and cos α come from the kernel's own polynomials
  (`sincos_first_quadrant`): Dr.Jit-CUDA's float32 dr.sin/dr.cos are approximate (MUFU unit, ~1e-6
  absolute), which gave 4e-3 · π sin²α L errors for small α before.
  Exact by construction: α = 0 → E = 0 (no NaN); α = π/2 (hemisphere light) → E/L = π (1 + cos θ)/2, i.e.
  wrap lighting with w = 1, p = 1; cos θ = ±1 → π sin²α L or 0.

Domain and validation
---------------------
Public functions accept Python floats (→ float), NumPy arrays (→ evaluated on the default Dr.Jit backend,
returned as NumPy of the broadcast shape; float64 in → float64 computation) or Dr.Jit arrays (→ the same
Dr.Jit type, lazily; see `rtfit.realtime.arrays`). Parameters are validated at the entry point:

* Python/NumPy scalars and NumPy arrays outside the domain (NaN included) raise a one-line ValueError naming
  the valid interval (one min/max pass over NumPy arrays). ``cos_theta`` may exceed [−1, 1] by 1e-4
  (rounding) and is then clamped; NaN entries of a ``cos_theta`` *array* propagate to the output.
* Dr.Jit arrays are never checked (no host sync in hot paths): the kernels clamp cos θ to [−1, 1],
  α to [0, π/2], w to [0, 1] and p to [1e-30, 8]; scale factors (irradiance, radiance) are applied as given;
  NaN inputs give NaN outputs.
* Dr.Jit flushes subnormal floats to zero (|x| < 2.2e-308 in float64, 1.2e-38 in float32), so tiny
  inputs and results may differ from NumPy's below those magnitudes.

Methods as data
---------------
``METHODS`` (`rtfit.realtime.methods.method_table`: ``lambert``, ``half-lambert``, ``wrap``, ``exact``, then
the light models of `rtfit.realtime.light_models`: ``punctual``, ``unreal-window``, ``frostbite-window``,
``representative-point``, ``polygon``, ``disc``, ``spot-linear``, ``spot-smoothstep``, ``spot-squared``,
which read the light's own parameters instead of E⊥) declares each formula once: its kernel text, its
inputs with units (``cos_theta`` "1", ``irradiance`` "W/m²", ``alpha`` "rad", ``radiance`` "W/m²/sr"),
wrap's free parameters w ∈ [0, 1], p ∈ [0.25, 8] (dimensionless, defaults 0.5 and 1.5) and ``exact=True``
for the sphere-light closed form (its kernel text, `sphere_light_irradiance_kernel`, lives in
`rtfit.realtime.light_models`, whose disc row reads it too).
``METHODS[id](NUMPY_OPS, inputs, params)`` is the NumPy run of the same text (benchmarks, references);
`rtfit.fitting.fit_method` fits through its JAX run. ``METHODS`` is not re-exported by
`rtfit.realtime` (every family has one): use ``rtfit.realtime.diffuse.METHODS``.

Performance notes: Python-float parameters are compiled into the Dr.Jit kernel as constants (one kernel
compile, ~15 ms on LLVM, per new value; cached afterwards). When sweeping a parameter, pass it as an array
or as ``dr.opaque(Float, value)`` to reuse one kernel.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from .arrays import (
    check_range,
    clamp_cos,
    evaluate,
    is_drjit,
    safe_div,
    safe_sqrt,
    sincos_first_quadrant,
    split3,
)
from .light_models import METHODS as LIGHT_MODELS
from .light_models import sphere_light_irradiance_kernel
from .methods import Input, Method, Param, method_table

__all__ = [
    "ambient_term",
    "half_lambert",
    "lambert",
    "sphere_light_geometry",
    "sphere_light_irradiance",
    "sphere_light_peak_irradiance",
    "wrap",
]

HALF_PI = 0.5 * math.pi
_ALPHA_MAX = 1.5707963705062866  # float32(π/2) > π/2: accept it (it rounds to π/2), the kernel clamps
_COS_SLACK = 1e-4  # |cos θ| up to 1 + 1e-4 is accepted as rounding and clamped
_FMAX = sys.float_info.max  # "finite" upper bound for scale factors
_P_MIN = 1e-30  # Dr.Jit-path clamp for the wrap exponent (p must be > 0)


# ===================================================================================== kernels (ops text)
def _lambert_kernel(ops, cos_theta, irradiance):
    """E⊥ · max(cos θ, 0); cos θ clamped to 1 from above (rounding)."""
    return irradiance * ops.clip(cos_theta, 0.0, 1.0)


def _half_lambert_kernel(ops, cos_theta, irradiance):
    """E⊥ · (½ cos θ + ½)² (Valve 2006)."""
    t = ops.fma(clamp_cos(ops, cos_theta), 0.5, 0.5)
    return irradiance * (t * t)


def _wrap_kernel(ops, cos_theta, w, p, irradiance):
    """E⊥ · max((cos θ + w)/(1 + w), 0)^p, with w clamped to [0, 1] and p to [1e-30, 8]."""
    c = clamp_cos(ops, cos_theta)
    w = ops.clip(w, 0.0, 1.0)
    p = ops.clip(p, _P_MIN, 8.0)
    base = ops.maximum((c + w) / (1.0 + w), 0.0)
    return irradiance * ops.power(base, p)


def _peak_kernel(ops, alpha, radiance):
    """π sin²α L: irradiance at normal incidence (whole cap above the horizon)."""
    sin_a, _ = sincos_first_quadrant(ops, ops.clip(alpha, 0.0, HALF_PI))
    return (math.pi * radiance) * (sin_a * sin_a)


def _ambient_kernel(ops, sky_radiance):
    """π L_sky: unoccluded upper hemisphere of a constant sky."""
    return math.pi * sky_radiance


def _geometry_kernel(ops, px, py, pz, nx, ny, nz, cx, cy, cz, radius):
    """(cos θ, α) at points p with normals n for a sphere light of centre c, radius r.

    cos θ = n·(c − p)/(|n| |c − p|) (n need not be unit length; zero n or p = c give 0);
    α = atan2(r, √(d² − r²)) = asin(min(r/d, 1)) without asin's precision loss near π/2 (π/2 inside)."""
    dx, dy, dz = cx - px, cy - py, cz - pz
    d2 = dx * dx + dy * dy + dz * dz
    n2 = nx * nx + ny * ny + nz * nz
    dn = dx * nx + dy * ny + dz * nz
    cos_t = clamp_cos(ops, safe_div(ops, dn, ops.sqrt(d2 * n2)))
    d = ops.sqrt(d2)
    alpha = ops.atan2(radius, safe_sqrt(ops, (d - radius) * (d + radius)))
    return cos_t, alpha


# ===================================================================================== validation helpers
def _cos(cos_theta):
    """Range-check cos θ (scalars and NumPy arrays, ±1e-4 slack for rounding); NaN entries of an array
    propagate to the output instead of raising (a NaN scalar raises)."""
    if isinstance(cos_theta, np.ndarray) and cos_theta.size and np.issubdtype(cos_theta.dtype, np.floating):
        lo, hi = cos_theta.min(), cos_theta.max()
        if np.isnan(lo) or np.isnan(hi):
            finite = cos_theta[~np.isnan(cos_theta)]
            if finite.size:
                check_range("cos_theta", finite, -1.0 - _COS_SLACK, 1.0 + _COS_SLACK, interval="[-1, 1]")
            return cos_theta
    return check_range("cos_theta", cos_theta, -1.0 - _COS_SLACK, 1.0 + _COS_SLACK, interval="[-1, 1]")


def _scale(name, value):
    return check_range(name, value, 0.0, _FMAX, interval="[0, inf)")


def _alpha(alpha):
    return check_range("alpha", alpha, 0.0, _ALPHA_MAX, interval="[0, pi/2]")


# ===================================================================================== public API
def lambert(cos_theta, irradiance=1.0):
    """Lambert: ``irradiance · max(cos θ, 0)`` (W/m²). See the module docstring for input types."""
    return evaluate(_lambert_kernel, _cos(cos_theta), _scale("irradiance", irradiance))


def half_lambert(cos_theta, irradiance=1.0):
    """Valve's half-Lambert: ``irradiance · (½ cos θ + ½)²`` (W/m²)."""
    return evaluate(_half_lambert_kernel, _cos(cos_theta), _scale("irradiance", irradiance))


def wrap(cos_theta, w, p, irradiance=1.0):
    """Wrap lighting: ``irradiance · max((cos θ + w)/(1 + w), 0)^p`` with w ∈ [0, 1], p ∈ (0, 8].

    (0, 1) is Lambert, (1, 2) half-Lambert, (1, 1) the exact hemisphere-light irradiance."""
    w = check_range("w", w, 0.0, 1.0)
    p = check_range("p", p, 0.0, 8.0, lo_open=True)
    return evaluate(_wrap_kernel, _cos(cos_theta), w, p, _scale("irradiance", irradiance))


def sphere_light_irradiance(cos_theta, alpha, radiance=1.0):
    """Exact irradiance (W/m²) from a uniform sphere light of angular radius ``alpha`` ∈ [0, π/2] (rad) and
    ``radiance`` (W/m²/sr) whose centre is at angle θ from the normal, horizon clipping included."""
    return evaluate(
        sphere_light_irradiance_kernel, _cos(cos_theta), _alpha(alpha), _scale("radiance", radiance)
    )


def sphere_light_peak_irradiance(alpha, radiance=1.0):
    """π sin²α · L: the sphere light's irradiance at normal incidence, E⊥ (W/m²)."""
    return evaluate(_peak_kernel, _alpha(alpha), _scale("radiance", radiance))


def ambient_term(sky_radiance):
    """π · L_sky (W/m²): irradiance from a constant sky over the whole upper hemisphere (unoccluded; exact
    for any point of a convex object)."""
    return evaluate(_ambient_kernel, _scale("sky_radiance", sky_radiance))


def sphere_light_geometry(position, normal, light_center, light_radius):
    """Per-point ``(cos_theta, alpha)`` for a sphere light (centre ``light_center``, radius ``light_radius``).

    ``position``/``normal``: Dr.Jit Array3f-like (→ Float of the same precision), NumPy arrays of shape
    (..., 3) (→ NumPy arrays of shape (...)) or 3-sequences (→ floats). ``light_center``: 3-sequence,
    NumPy (3,) or Dr.Jit Array3f-like; ``light_radius`` ≥ 0 (float or array).
    cos θ = n·normalize(c − p) / |n| (normals need not be unit length; a zero normal gives 0) and
    α = asin(min(r/|c − p|, 1)) (computed as atan2(r, √(d² − r²)); points inside the light get π/2).
    """
    if not is_drjit(light_center):
        cen = np.asarray(light_center, dtype=np.float64)
        if cen.shape != (3,) or not np.all(np.isfinite(cen)):
            raise ValueError(f"light_center must be 3 finite numbers (got {light_center!r})")
        light_center = tuple(float(v) for v in cen)
    radius = _scale("light_radius", light_radius)
    return evaluate(
        _geometry_kernel,
        *split3(position, "position"),
        *split3(normal, "normal"),
        *split3(light_center, "light_center"),
        radius,
    )


# ===================================================================================== methods as data
_COS = Input(
    "cos_theta", "1", "n·l, cosine between the normal and the direction to the light (centre)", (-1.0, 1.0)
)
_IRRADIANCE = Input("irradiance", "W/m²", "E⊥, the light's irradiance at normal incidence", (0.0, 10.0))

METHODS = method_table(
    [
        Method(
            "lambert",
            "Lambert",
            _lambert_kernel,
            inputs=(_COS, _IRRADIANCE),
            quantity="light_irradiance",
            formula="E = E⊥·max(cos θ, 0)",
            source="Lambert's cosine law",
            description="Exact for a point/directional light; ignores the light's size.",
        ),
        Method(
            "half-lambert",
            "Half-Lambert",
            _half_lambert_kernel,
            inputs=(_COS, _IRRADIANCE),
            quantity="light_irradiance",
            formula="E = E⊥·(½ cos θ + ½)²",
            source="Valve 2006, Shading in Valve's Source Engine, §7.4.4 (seed 000:2520-2534)",
            description="Valve's non-physical softening: E⊥/4 at 90°, zero only at 180°.",
        ),
        Method(
            "wrap",
            "Wrap lighting",
            _wrap_kernel,
            inputs=(_COS, _IRRADIANCE),
            params={
                "w": Param(0.5, 0.0, 1.0, unit="1", description="wrap: light reaches cos θ = −w"),
                "p": Param(1.5, 0.25, 8.0, unit="1", description="exponent of the wrapped cosine"),
            },
            quantity="light_irradiance",
            formula="E = E⊥·max((cos θ + w)/(1 + w), 0)^p",
            source="real-time practice: half-Lambert generalised by an offset w and an exponent p",
            description="(w, p) = (0, 1) is Lambert, (1, 2) half-Lambert, (1, 1) a hemisphere light.",
        ),
        Method(
            "exact",
            "Exact closed form",
            sphere_light_irradiance_kernel,
            inputs=(
                _COS,
                Input(
                    "alpha", "rad", "angular radius of the sphere light seen from the point", (0.0, HALF_PI)
                ),
                Input("radiance", "W/m²/sr", "the light's uniform radiance L", (0.0, 10.0)),
            ),
            exact=True,
            quantity="light_irradiance",
            formula="E = L·∫_cap max(n·ω, 0) dω (horizon-clipped cap of half-angle α)",
            source="Snyder 1996, MSR-TR-96-11; Lagarde & de Rousiers 2014, §4.7",
            description="Closed-form irradiance of a uniform sphere light incl. horizon clipping.",
        ),
        *LIGHT_MODELS.values(),  # the light models, evaluated from the light's own parameters
    ]
)
"""The diffuse family's methods: ``METHODS[id](ops, inputs, params)`` runs the kernel text on one ops
namespace (``METHODS["wrap"](NUMPY_OPS, {"cos_theta": c, "irradiance": 1.0}, {"w": 0.5, "p": 1.5})``:
the NumPy run of benchmarks), ``.evaluate`` dispatches like the public functions (without their
validation), `rtfit.fitting.fit_method` fits ``wrap``'s (w, p) through the JAX run of the same text."""
