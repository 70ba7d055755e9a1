r"""Ambient aperture lighting (Oat & Sander 2007): spherical-cap intersection and the shading built on it.

Source: seed ``000_540fc7eee6870c4d.txt`` chapter 8 (000:2620-2800), "Ambient Aperture Lighting".
Visibility over a point's upper hemisphere is stored as one spherical cap per texel (a unit *bent normal*
``a`` and an *aperture* angular radius ``r_a``); a sphere light is a second cap (direction ``l`` to its
centre, angular radius α). The light that gets through is the intersection of the two caps.

Conventions and units
---------------------
* Angles in radians. A cap of angular radius r ∈ [0, π] has solid angle A(r) = 2π(1 − cos r) = 4π sin²(r/2)
  steradians (the second form has no cancellation for small r).
* ``d`` ∈ [0, π] is the angle between the two cap centres.
* Solid angles are in sr; irradiance in W/m² for radiance in W/m²/sr.

Exact intersection (`cap_intersection_solid_angle`)
---------------------------------------------------
Let r1, r2 be the radii, d the centre distance, and P one of the two points where the boundary circles
cross. The spherical triangle C1 P C2 has sides r1, r2, d; β1, β2 are its angles at C1, C2, γ the angle at
P, E = β1 + β2 + γ − π its area (spherical excess). Splitting the lens into the two sectors of angle 2βᵢ
minus the kite C1 P C2 P' (area 2E):

    Ω = 2 [β1 (1 − cos r1) + β2 (1 − cos r2) − E]
      = 2 [π − γ − β1 cos r1 − β2 cos r2]                         (Gauss–Bonnet form)

which is Tovchigrechko & Vakser (2001, eq. for the intersection of two spherical caps) and Mazonka (2012,
"Solid angle of conical surfaces, polyhedral cones, and intersecting spherical caps", arXiv:1205.1396).
It holds for caps larger than a hemisphere too (checked against quadrature in tests). Cases:

* nested,   d ≤ |r1 − r2|:                 Ω = A(min(r1, r2))
* disjoint, d ≥ r1 + r2:                   Ω = 0
* covering, r1 + r2 + d ≥ 2π (the complements are disjoint: the union is the whole sphere):
                                          Ω = A(r1) + A(r2) − 4π = 4π cos((r1 − r2)/2) sin((r1 + r2 − π)/2)
* otherwise the partial formula above; the triangle exists (s = (r1 + r2 + d)/2 ≤ π, all s − x ≥ 0).

Numerics. cos β = (cos r − cos r' cos d)/(sin r' sin d) loses all digits near tangency (its acos argument
is ±1 − ε) and the Gauss–Bonnet form cancels completely for small caps (π − γ − β1 − β2 ≈ the tiny excess).
The kernel therefore uses the half-angle (l'Huilier-type) forms with s = (r1 + r2 + d)/2,

    β1 = 2 atan2(√(sin(s − r1) sin(s − d)), √(sin s sin(s − r2)))       (β2: swap r1 ↔ r2)
    tan(γ/2) = X/Y,  X = √(sin(s − r1) sin(s − r2)),  Y = √(sin s sin(s − d))
    tan(E/2) = tan(r1/2) tan(r2/2) sin γ / (1 + tan(r1/2) tan(r2/2) cos γ)
             = 2 h1 h2 XY / (c1 c2 (X² + Y²) + h1 h2 (Y² − X²)),   hᵢ = sin(rᵢ/2), cᵢ = cos(rᵢ/2)

and the sector form Ω = 4(β1 h1² + β2 h2²) − 2E, whose terms all scale with the caps' size. Every sine is
evaluated by the project's Taylor polynomial on [0, π/2] (`sincos_first_quadrant`; CUDA's float32 sin/cos are
approximate). Measured error, as a fraction of the smaller cap: ≤ 1e-14 in float64 and ≤ 4e-6 in float32
over the whole domain, tangencies included (tests/test_ambient_aperture.py).

Seed erratum (000:2672-2687). The printed *IntersectArea* has a sign error in its third term: it gives
−7.92 for r0 = r1 = d = 0.5, where the correct value (Monte Carlo, quadrature, this formula) is 0.3078.
With acos(−x) = π − acos(x), the printed terms read 2π cos r1 − 2β1 cos r1, −2β0 cos r0 and
−2(π − γ), then −2π cos r1: the sum is 2[−β0 cos r0 − β1 cos r1 − (π − γ)], whereas Gauss–Bonnet gives
2[(π − γ) − β0 cos r0 − β1 cos r1]. The third term must be **+** 2 arccos((−cos d + cos r0 cos r1)/(sin r0
sin r1)); as printed the result is short by 4(π − γ). `seed_printed_intersect_area` keeps the printed text
for the record.

Approximations of the partial-overlap region
--------------------------------------------
With r_min, r_max the smaller and larger radius and the normalised distance
x = (d − |r1 − r2|)/(r1 + r2 − |r1 − r2|) = (d − (r_max − r_min))/(2 r_min), t = 1 − saturate(x):

* ``smoothstep`` (000:2689-2762, Listing 1): Ω ≈ A(r_min) · t²(3 − 2t), exactly the listing's three cases
  (the cap area is computed as 4π sin²(r/2), mathematically the listing's 2π − 2π cos r without its float32
  cancellation for small caps). It knows nothing of the covering case r1 + r2 + d > 2π: there it errs by up
  to 0.60 of the smaller cap.
* ``linear``: Ω ≈ A(r_min) · t.
* ``fitted``: first the **complement trick** — if r1 + r2 > π, replace both caps by their complements
  (radii π − rᵢ, centres antipodal, same d): |C1 ∩ C2| = A(r1) + A(r2) − 4π + |C1ᶜ ∩ C2ᶜ|, so every case
  becomes one with r1 + r2 ≤ π — then, with ρ = r_min/r_max ∈ [0, 1], σ = (r_min + r_max)/π ∈ [0, 1] and
  u = 1 − 2t,

      f = saturate(t²(3 − 2t) + t(1 − t) · [c0 + c1 u + ρ (c2 + c3 u) + σ (c4 + c5 u)])
      Ω ≈ L + A(r_min) · f,  L = A(r1) + A(r2) − 4π if complemented else 0

  f is 0 at t = 0 and 1 at t = 1 for any coefficients, so the nested and disjoint limits stay exact and
  Ω never leaves [0, A(smaller cap)]. The coefficients c0..c5 are least-squares fitted
  (`rtfit.fitting.fit_method`, through this kernel's JAX run) to the exact formula over a dense
  (r1, r2, d) grid by the ``ambient-aperture`` experiment; `FITTED_COEFFS` holds the values of that fit.
  Cost: one more division (ρ) and six fused multiply-adds over the smoothstep.

Shading (`ambient_aperture_irradiance`)
---------------------------------------
Inputs per point: cos_na = n·a, cos_nl = n·l, cos_al = a·l (unit vectors: surface normal n, bent normal a,
light direction l), aperture r_a ∈ [0, π/2] and light radius α ∈ [0, π/2]; d = angle(a, l).

* light:  E_L = L · Ω(r_a, α, d) · max(n·c, 0), c = normalize(w l + (1 − w) a), the estimated centroid of
  the intersection. The seed (000:2763-2772) takes the plain average, w = ½; under an open sky (a = n,
  r_a = π/2) a small light at 60° gets cos 30° instead of cos 60°, 73 % too bright (erratum in the issue).
  The replacement weights by the *other* cap's size, w = A(r_a)^k / (A(r_a)^k + A(α)^k): a small light inside
  a large aperture is its own centroid (w → 1), a small aperture inside a large light is the aperture's
  (w → 0). The exponent k is fitted (`FITTED_LAMBERT_K`) to quadrature of ∫_{cap∩cap} max(n·ω, 0) dω.
* ambient fill (000:2774-2782): the part of the aperture the light does not cover is filled with the sky's
  radiance L_sky. The seed states no cosine weighting; ``fill="seed"`` uses the solid angle with the bent
  normal's Lambert factor, L_sky (A(r_a) − Ω) max(n·a, 0), which reads 2π L_sky under an open sky where the
  truth is π L_sky. ``fill="projected"`` uses the aperture's exact *projected* solid angle (the horizon-
  clipped cap integral ∫_cap max(n·ω, 0) dω, the closed form of `rtfit.realtime.diffuse`) minus the light's
  share: L_sky (P(n·a, r_a) − Ω · max(n·c, 0)). It has no free parameter: it is exact within the cap model.

Baking (`aperture_from_visibility`): the visible fraction V of the hemisphere (uniform directions) gives the
aperture of equal solid angle, 2π V = A(r_a): r_a = acos(1 − V) = 2 asin(√(V/2)) (000:2660-2668).

Methods as data (`METHODS`): every form above is one `rtfit.realtime.methods.Method` row — the four
intersection forms (ids ``exact``, ``smoothstep``, ``linear``, ``fitted``; inputs r1, r2, d in rad, Ω in
sr), the light terms ``aa-<intersection>-<lambert>`` (W/m²) and the sky fills ``fill-<fill>`` (W/m²), with
the fitted form's c0..c5 and the Lambert exponent k as free parameters (defaults: the shipped fitted values).
The public functions below and the table run the same kernels; the kernels are selected by data
(`INTERSECTION_KERNELS`, `LAMBERT_WEIGHTS`, `FILL_KERNELS`), not by branching on names.

Domain and validation: as `rtfit.realtime.diffuse` — floats, NumPy arrays (one-line ValueError naming the
interval for values outside) or Dr.Jit arrays (not checked; the kernels clamp radii and d into [0, π],
cosines into [−1, 1]).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType

from .arrays import (
    check_range,
    clamp01,
    clamp_cos,
    evaluate,
    evaluate_numpy,
    safe_div,
    safe_sqrt,
    sincos_first_quadrant,
)
from .light_models import sphere_light_irradiance_kernel
from .methods import Input, Method, Param, method_table
from .numpy_memo import KeptValues

__all__ = [
    "FILL_FORMS",
    "FITTED_COEFFS",
    "FITTED_LAMBERT_K",
    "INTERSECTION_FORMS",
    "LAMBERT_FORMS",
    "ambient_aperture_irradiance",
    "aperture_from_visibility",
    "cap_area",
    "cap_intersection_fitted",
    "cap_intersection_linear",
    "cap_intersection_smoothstep",
    "cap_intersection_solid_angle",
    "seed_printed_intersect_area",
]

PI = math.pi
HALF_PI = 0.5 * math.pi
TWO_PI = 2.0 * math.pi
FOUR_PI = 4.0 * math.pi
_PI_MAX = 3.1415927410125732  # float32(π) > π: accepted (rounds to π), the kernels clamp
_HALF_PI_MAX = 1.5707963705062866

FITTED_COEFFS: tuple[float, ...] = (-0.278338, 0.103612, -0.37048, 0.380772, 0.646645, 0.381637)
"""c0..c5 of the fitted form (see module docstring):
`rtfit.experiments.ambient_aperture_study.fit_intersection` with its full configuration (72³ cell-centred
grid of (r1, r2, d) ∈ (0, π)³, its 124 464 partial-overlap points), least squares of
(Ω_fit − Ω_exact)/A(r_min); RMS residual 0.0085, max 0.064."""

FITTED_LAMBERT_K: float = 1.19
"""Exponent k of the fitted centroid weight w = A(r_a)^k/(A(r_a)^k + A(α)^k):
`rtfit.experiments.ambient_aperture_study.fit_lambert` with its full configuration (6000 random
configurations, 2018 with overlap; k = 1.190 ± 0.019); RMS error of the Lambert-weighted intersection 0.015
of the light cap, against 0.159 for the seed's plain average."""


# ===================================================================================== kernels (ops text)
def _sin_0_pi(ops, x):
    """sin x for x ∈ [0, π] (clamped) via the first-quadrant polynomial: sin x = sin(min(x, π − x))."""
    x = ops.clip(x, 0.0, PI)
    s, _ = sincos_first_quadrant(ops, ops.minimum(x, PI - x))
    return s


_KEPT = KeptValues(max_floats=1 << 22, max_entries=8, max_input_floats=1 << 18)
"""The NumPy run's parameter-free values of the light kernels (`_light_terms`, `_fitted_geometry`,
`_area_ratio`; `rtfit.realtime.numpy_memo`): a fit of c0..c5 or k evaluates the kernel again and again on the
same inputs. At most 2^22 floats (32 MiB): the clamped and geometric values of a fit on up to 2^18 points
(the light inputs 4, the geometry 9, the area ratio 1 per point), a pooled fit of a few scenes included."""
MEMOS = (_KEPT,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""
_SIN_QUARTER = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(7))  # 1, −1/3!, …, 1/13!


def _cap_area_half_kernel(ops, q):
    """A(q) = 4π sin²(q/2) for q ∈ [0, π/2] (clamped): q/2 ≤ π/4, so a 7-term Taylor polynomial of sin
    suffices (truncation ≤ (π/4)¹⁵/15! ≈ 2.6e-14 relative); cheaper than the full-quadrant one."""
    x = 0.5 * ops.clip(q, 0.0, 0.5 * PI)
    x2 = x * x
    acc = _SIN_QUARTER[-1]
    for coef in reversed(_SIN_QUARTER[:-1]):
        acc = ops.fma(acc, x2, coef)
    h = x * acc
    return FOUR_PI * (h * h)


def _cap_area_kernel(ops, r):
    """A(r) = 4π sin²(r/2) for r ∈ [0, π] (clamped)."""
    h, _ = sincos_first_quadrant(ops, 0.5 * ops.clip(r, 0.0, PI))
    return FOUR_PI * (h * h)


def _lens_kernel(ops, r1, r2, d):
    """Intersection of two caps with r1, r2 ∈ [0, π/2] (clamped): nested / disjoint / partial (sector form).

    Returns (Ω, A(r1), A(r2)). With both radii ≤ π/2 the covering case cannot occur (r1 + r2 + d ≤ 2π)."""
    r1 = ops.clip(r1, 0.0, HALF_PI)
    r2 = ops.clip(r2, 0.0, HALF_PI)
    h1, c1 = sincos_first_quadrant(ops, 0.5 * r1)
    h2, c2 = sincos_first_quadrant(ops, 0.5 * r2)
    a1 = FOUR_PI * (h1 * h1)
    a2 = FOUR_PI * (h2 * h2)
    a_min = ops.minimum(a1, a2)
    diff = ops.abs(r1 - r2)
    total = r1 + r2
    # Half-angle forms on the triangle C1 P C2 (sides r1, r2, d; s = half perimeter ≤ π).
    # The differences s − x vanish at the tangencies: each is summed in the order whose first subtraction
    # is exact (Sterbenz: operands within a factor 2), so it keeps full relative accuracy near 0.
    r_max = ops.maximum(r1, r2)
    r_min = ops.minimum(r1, r2)
    close = (r2 >= 0.5 * r1) & (r2 <= 2.0 * r1)
    sin_s = _sin_0_pi(ops, 0.5 * (total + d))
    sin_1 = _sin_0_pi(ops, 0.5 * ops.select(close, (r2 - r1) + d, (d - r1) + r2))  # sin(s − r1)
    sin_2 = _sin_0_pi(ops, 0.5 * ops.select(close, (r1 - r2) + d, (d - r2) + r1))  # sin(s − r2)
    sin_d = _sin_0_pi(ops, 0.5 * ((r_max - d) + r_min))  # sin(s − d)
    beta1 = 2.0 * ops.atan2(safe_sqrt(ops, sin_1 * sin_d), safe_sqrt(ops, sin_s * sin_2))
    beta2 = 2.0 * ops.atan2(safe_sqrt(ops, sin_2 * sin_d), safe_sqrt(ops, sin_s * sin_1))
    x2 = sin_1 * sin_2
    y2 = sin_s * sin_d
    xy = safe_sqrt(ops, x2 * y2)
    hh = h1 * h2
    excess = 2.0 * ops.atan2(2.0 * hh * xy, ops.fma(c1 * c2, x2 + y2, hh * (y2 - x2)))
    partial = 4.0 * ops.fma(beta1, h1 * h1, beta2 * (h2 * h2)) - 2.0 * excess
    # d ≤ 1e-30: equal caps at a distance that underflows in the half-angle sines (Dr.Jit flushes
    # subnormals) are nested to within rounding.
    nested = d <= ops.maximum(diff, 1e-30)
    out = ops.select(nested, a_min, ops.select(d >= total, 0.0, partial))
    return ops.clip(out, 0.0, a_min), a1, a2


def _exact_kernel(ops, r1, r2, d):
    """Exact solid angle of the intersection of two caps (radii r1, r2, centre distance d), in sr.

    Caps larger than a hemisphere are replaced by their complements (radius π − r, antipodal centre), so
    the lens formula only ever sees radii ≤ π/2, where its sector terms stay comparable to the caps:
      one large (r2 > π/2):  |C1 ∩ C2| = A(r1) − |C1 ∩ C2ᶜ|,  C2ᶜ: radius π − r2 at distance π − d;
      both large:            |C1 ∩ C2| = A(r1) + A(r2) − 4π + |C1ᶜ ∩ C2ᶜ|,  distance d.
    """
    r1 = ops.clip(r1, 0.0, PI)
    r2 = ops.clip(r2, 0.0, PI)
    d = ops.clip(d, 0.0, PI)
    big1 = r1 > HALF_PI
    big2 = r2 > HALF_PI
    q1 = ops.select(big1, PI - r1, r1)
    q2 = ops.select(big2, PI - r2, r2)
    one = big1 ^ big2
    lens, a1q, a2q = _lens_kernel(ops, q1, q2, ops.select(one, PI - d, d))
    # A(r) for a large cap = 4π − A(π − r).
    a1 = ops.select(big1, FOUR_PI - a1q, a1q)
    a2 = ops.select(big2, FOUR_PI - a2q, a2q)
    # Both large: A1 + A2 − 4π = 4π − A(π − r1) − A(π − r2) ≥ 0 (each complement is at most a hemisphere).
    both = FOUR_PI - a1q - a2q + lens
    one_out = ops.select(big1, a2 - lens, a1 - lens)
    out = ops.select(big1 & big2, both, ops.select(one, one_out, lens))
    return ops.clip(out, 0.0, ops.minimum(a1, a2))


def _ramp_parts(ops, r1, r2, d):
    """(A(r_min), t) with t = 1 − saturate((d − |r1 − r2|)/(r1 + r2 − |r1 − r2|)), as in Listing 1."""
    r1 = ops.clip(r1, 0.0, PI)
    r2 = ops.clip(r2, 0.0, PI)
    d = ops.clip(d, 0.0, PI)
    r_min = ops.minimum(r1, r2)
    diff = ops.abs(r1 - r2)
    a_min = _cap_area_kernel(ops, r_min)
    t = 1.0 - clamp01(ops, safe_div(ops, d - diff, (r1 + r2) - diff))
    return a_min, t, diff, r1 + r2, d


def _smoothstep_kernel(ops, r1, r2, d):
    """Seed Listing 1 (000:2725-2755): A(r_min)·smoothstep(0, 1, t) with the nested / disjoint cases."""
    a_min, t, diff, total, d = _ramp_parts(ops, r1, r2, d)
    f = t * t * ops.fma(t, -2.0, 3.0)
    return ops.select(d <= diff, a_min, ops.select(d >= total, 0.0, a_min * f))


def _linear_kernel(ops, r1, r2, d):
    """A(r_min)·t: the linear ramp between full and no intersection."""
    a_min, t, diff, total, d = _ramp_parts(ops, r1, r2, d)
    return ops.select(d <= diff, a_min, ops.select(d >= total, 0.0, a_min * t))


def _fitted_geometry(ops, r1, r2, d):
    """The parameter-free part of `_fitted_kernel`: (complement?, A(r_min), A(q_min) or A(r_min), the ramp
    t, ρ, σ, u = 1 − 2t, nested?, disjoint?), kept on the NumPy run of a fit (`_KEPT`)."""
    r1 = ops.clip(r1, 0.0, PI)
    r2 = ops.clip(r2, 0.0, PI)
    d = ops.clip(d, 0.0, PI)
    comp = (r1 + r2) > PI
    q1 = ops.select(comp, PI - r1, r1)
    q2 = ops.select(comp, PI - r2, r2)
    q_min = ops.minimum(q1, q2)
    q_max = ops.maximum(q1, q2)
    a_min = _cap_area_kernel(ops, ops.minimum(r1, r2))  # A(min(r1, r2)): the bound
    a_q = ops.select(comp, _cap_area_half_kernel(ops, q_min), a_min)
    diff = q_max - q_min
    t = 1.0 - clamp01(ops, safe_div(ops, d - diff, 2.0 * q_min))
    rho = safe_div(ops, q_min, q_max)
    sigma = (q_min + q_max) * (1.0 / PI)
    u = ops.fma(t, -2.0, 1.0)
    return comp, a_min, a_q, t, rho, sigma, u, d <= diff, d >= q1 + q2


def _fitted_kernel(ops, r1, r2, d, c0, c1, c2, c3, c4, c5):
    """Complement trick + smoothstep corrected by a fitted t(1 − t)·(bilinear in u, ρ, σ) term.

    With the complement (r1 + r2 > π), |C1 ∩ C2| = A(r1) + A(r2) − 4π + A(q_min)·f, which equals
    A(r_min) − A(q_min)(1 − f) since A(r_min) = A(r1) + A(r2) − 4π + A(q_min) when q_min = π − r_max:
    written that way there is no 4π − A(·) cancellation in float32 and only two cap areas are evaluated
    (q_min ≤ π/2 takes the shorter polynomial)."""
    comp, a_min, a_q, t, rho, sigma, u, nested, disjoint = _KEPT.get(
        ops, ("fitted-geometry",), (r1, r2, d), lambda _: _fitted_geometry(ops, r1, r2, d)
    )
    corr = ops.fma(u, c1, c0) + rho * ops.fma(u, c3, c2) + sigma * ops.fma(u, c5, c4)
    f = clamp01(ops, ops.fma(t * (1.0 - t), corr, t * t * ops.fma(t, -2.0, 3.0)))
    f = ops.select(nested, 1.0, ops.select(disjoint, 0.0, f))
    out = ops.select(comp, ops.fma(-a_q, 1.0 - f, a_min), a_q * f)
    return ops.clip(out, 0.0, a_min)


def _seed_printed_kernel(ops, r0, r1, d):
    """IntersectArea exactly as printed at 000:2672-2687 (WRONG: kept to document the erratum)."""
    t1 = (
        2.0
        * ops.cos(r1)
        * ops.acos(clamp_cos(ops, (-ops.cos(r0) + ops.cos(d) * ops.cos(r1)) / (ops.sin(d) * ops.sin(r1))))
    )
    t2 = (
        2.0
        * ops.cos(r0)
        * ops.acos(clamp_cos(ops, (ops.cos(r1) - ops.cos(d) * ops.cos(r0)) / (ops.sin(d) * ops.sin(r0))))
    )
    t3 = 2.0 * ops.acos(
        clamp_cos(ops, (-ops.cos(d) + ops.cos(r0) * ops.cos(r1)) / (ops.sin(r0) * ops.sin(r1)))
    )
    return t1 - t2 - t3 - TWO_PI * ops.cos(r1)


def _angle_from_cos(ops, c):
    """acos(c) as atan2(√((1 − c)(1 + c)), c): full relative accuracy of the sine near c = ±1."""
    c = clamp_cos(ops, c)
    return ops.atan2(safe_sqrt(ops, (1.0 - c) * (1.0 + c)), c)


def _centroid_cos(ops, cos_na, cos_nl, cos_al, w):
    """n·normalize(w l + (1 − w) a) for unit a, l; 0 when the sum vanishes (a = −l, w = ½)."""
    v = 1.0 - w
    norm2 = ops.fma(w, w, v * v) + 2.0 * w * v * cos_al
    dot = ops.fma(w, cos_nl, v * cos_na)
    return clamp_cos(ops, safe_div(ops, dot, safe_sqrt(ops, norm2)))


# Lambert factor: the weight w of the light direction in the centroid c = normalize(w l + (1 − w) a).
def _seed_weight(ops, r_a, alpha, k):
    """The seed's plain average of the two directions (000:2763-2772): w = ½ (k unused)."""
    return 0.5


def _area_ratio(ops, r_a, alpha):
    """A_l / A_a (at most 1e30): the parameter-free part of `_fitted_weight`."""
    aa = _cap_area_kernel(ops, r_a)
    al = _cap_area_kernel(ops, alpha)
    return ops.minimum(safe_div(ops, al, aa), 1e30)


def _fitted_weight(ops, r_a, alpha, k):
    """w = A_a^k / (A_a^k + A_l^k) = 1 / (1 + (A_l/A_a)^k): one power, no overflow for tiny caps."""
    ratio = _KEPT.get(ops, ("area-ratio",), (r_a, alpha), lambda _: _area_ratio(ops, r_a, alpha))
    return 1.0 / (1.0 + ops.power(ratio, k))


# Ambient fill of the part of the aperture the light does not cover (000:2774-2782), per unit sky radiance.
def _seed_fill(ops, cos_na, r_a, omega, lam):
    """Solid angle times the bent normal's cosine: (A(r_a) − Ω) max(n·a, 0)."""
    return ops.maximum(_cap_area_kernel(ops, r_a) - omega, 0.0) * ops.maximum(cos_na, 0.0)


def _projected_fill(ops, cos_na, r_a, omega, lam):
    """Projected solid angle of the aperture cap (horizon clipped) minus the light's share:
    P(n·a, r_a) − Ω λ."""
    proj = sphere_light_irradiance_kernel(ops, cos_na, r_a, 1.0)  # ∫_aperture max(n·ω, 0) dω
    return ops.maximum(proj - omega * lam, 0.0)


INTERSECTION_KERNELS: Mapping[str, Callable] = MappingProxyType(
    {
        "exact": _exact_kernel,
        "smoothstep": _smoothstep_kernel,
        "linear": _linear_kernel,
        "fitted": _fitted_kernel,
    }
)
"""Ops kernel ``k(ops, r1, r2, d, **coefficients)`` of each intersection form (``fitted`` takes c0..c5)."""
LAMBERT_WEIGHTS: Mapping[str, Callable] = MappingProxyType({"seed": _seed_weight, "fitted": _fitted_weight})
"""Centroid weight ``w(ops, r_a, α, k)`` of the light direction for each Lambert factor."""
FILL_KERNELS: Mapping[str, Callable] = MappingProxyType({"seed": _seed_fill, "projected": _projected_fill})
"""Ambient fill per unit sky radiance, ``f(ops, cos_na, r_a, Ω, λ)``, for each fill form."""
INTERSECTION_FORMS = tuple(INTERSECTION_KERNELS)
LAMBERT_FORMS = tuple(LAMBERT_WEIGHTS)
FILL_FORMS = tuple(FILL_KERNELS)


def _light_terms(ops, cos_na, cos_nl, cos_al, aperture, alpha, intersection, weight, k, coeffs):
    """(Ω, λ, r_a, n·a): the intersection of the aperture and light caps and the Lambert factor
    λ = max(n·c, 0), inputs clamped into their domain (kept on the NumPy run of a fit, `_KEPT`: the
    same arrays at each call, so that the intersection's and the weight's own kept values are found)."""

    def clamped(_kept: bool):
        r_a = ops.clip(aperture, 0.0, 0.5 * PI)
        alpha_c = ops.clip(alpha, 0.0, 0.5 * PI)
        return r_a, alpha_c, clamp_cos(ops, cos_na), _angle_from_cos(ops, cos_al)

    r_a, alpha, cos_na, d = _KEPT.get(ops, ("light-inputs",), (aperture, alpha, cos_na, cos_al), clamped)
    omega = intersection(ops, r_a, alpha, d, **coeffs)
    w = weight(ops, r_a, alpha, k)
    lam = ops.maximum(_centroid_cos(ops, cos_na, cos_nl, cos_al, w), 0.0)
    return omega, lam, r_a, cos_na


def _shading_kernel(
    ops,
    cos_na,
    cos_nl,
    cos_al,
    aperture,
    alpha,
    radiance,
    sky_radiance,
    *,
    intersection,
    weight,
    fill,
    k=FITTED_LAMBERT_K,
    **coeffs,
):
    """(E_light, E_fill) = (L Ω λ, L_sky · fill(n·a, r_a, Ω, λ)); see the module docstring."""
    omega, lam, r_a, cos_na = _light_terms(
        ops, cos_na, cos_nl, cos_al, aperture, alpha, intersection, weight, k, coeffs
    )
    e_light = radiance * (omega * lam)
    return e_light, sky_radiance * fill(ops, cos_na, r_a, omega, lam)


def _light_kernel(
    ops,
    cos_na,
    cos_nl,
    cos_al,
    aperture,
    alpha,
    radiance,
    *,
    intersection,
    weight,
    k=FITTED_LAMBERT_K,
    **coeffs,
):
    """The light term alone, E_light = L Ω max(n·c, 0) (W/m²): the ``aa-*`` methods."""
    omega, lam, _, _ = _light_terms(
        ops, cos_na, cos_nl, cos_al, aperture, alpha, intersection, weight, k, coeffs
    )
    return radiance * (omega * lam)


def _sky_fill_kernel(ops, cos_na, aperture, sky_radiance, *, fill):
    """The ambient fill with no light (Ω = 0), E_fill = L_sky · fill(n·a, r_a, 0, 0): the ``fill-*``
    methods."""
    r_a = ops.clip(aperture, 0.0, 0.5 * PI)
    return sky_radiance * fill(ops, clamp_cos(ops, cos_na), r_a, 0.0, 0.0)


def _visibility_kernel(ops, v):
    """r_a = 2 asin(√(V/2)) = acos(1 − V) for a visible hemisphere fraction V ∈ [0, 1]."""
    x = safe_sqrt(ops, 0.5 * clamp01(ops, v))
    return 2.0 * ops.atan2(x, safe_sqrt(ops, (1.0 - x) * (1.0 + x)))


# ===================================================================================== methods (data)
_CAPS = (
    Input("r1", "rad", "angular radius of the first cap, [0, π]", (0.0, math.pi)),
    Input("r2", "rad", "angular radius of the second cap, [0, π]", (0.0, math.pi)),
    Input("d", "rad", "angle between the cap centres, [0, π]", (0.0, math.pi)),
)
_LIGHT = (
    Input("cos_na", "1", "n·a: surface normal · bent normal", (-1.0, 1.0)),
    Input("cos_nl", "1", "n·l: surface normal · direction to the light centre", (-1.0, 1.0)),
    Input("cos_al", "1", "a·l: bent normal · direction to the light centre", (-1.0, 1.0)),
    Input("aperture", "rad", "aperture (visibility cap) radius r_a, [0, π/2]", (0.0, 0.5 * math.pi)),
    Input("alpha", "rad", "angular radius α of the sphere light, [0, π/2]", (0.0, 0.5 * math.pi)),
    Input("radiance", "W/m²/sr", "radiance L of the sphere light", (0.0, 10.0)),
)
_SKY = (
    Input("cos_na", "1", "n·a: surface normal · bent normal", (-1.0, 1.0)),
    Input("aperture", "rad", "aperture (visibility cap) radius r_a, [0, π/2]", (0.0, 0.5 * math.pi)),
    Input("sky_radiance", "W/m²/sr", "radiance L_sky of the uniform sky", (0.0, 10.0)),
)
COEFF_PARAMS: Mapping[str, Param] = MappingProxyType(
    {
        f"c{i}": Param(c, -4.0, 4.0, unit="1", description=f"fitted-form correction coefficient c{i}")
        for i, c in enumerate(FITTED_COEFFS)
    }
)
"""c0..c5 of the fitted intersection form: defaults `FITTED_COEFFS`, bounds [−4, 4] (dimensionless)."""
K_PARAM: Mapping[str, Param] = MappingProxyType(
    {"k": Param(FITTED_LAMBERT_K, 0.05, 8.0, unit="1", description="exponent of the centroid weight")}
)
"""k of the fitted Lambert factor: default `FITTED_LAMBERT_K`, bounds [0.05, 8] (dimensionless)."""
_OMEGA_SOURCE = "Oat & Sander 2007, seed 000:2620-2800"


def _omega(form, label, formula, source, *, exact=False, params=None):
    return Method(
        id=form,
        label=label,
        kernel=INTERSECTION_KERNELS[form],
        inputs=_CAPS,
        params=params or {},
        exact=exact,
        quantity="cap_intersection_solid_angle",
        formula=formula,
        source=source,
    )


FORM_PARAMS: Mapping[str, Mapping[str, Param]] = MappingProxyType({"fitted": COEFF_PARAMS})
"""Free parameters of each intersection form that has any (the others: none)."""
LAMBERT_PARAMS: Mapping[str, Mapping[str, Param]] = MappingProxyType({"fitted": K_PARAM})
"""Free parameters of each Lambert factor that has any (the seed's: none)."""


def _shading(form, lambert, label):
    return Method(
        id=f"aa-{form}-{lambert}",
        label=label,
        kernel=_light_kernel,
        inputs=_LIGHT,
        params={**FORM_PARAMS.get(form, {}), **LAMBERT_PARAMS.get(lambert, {})},
        fixed={"intersection": INTERSECTION_KERNELS[form], "weight": LAMBERT_WEIGHTS[lambert]},
        quantity="light_irradiance",
        formula=f"L·Ω_{form}(r_a, α, d)·max(n·c_{lambert}, 0)",
        source=_OMEGA_SOURCE,
    )


def _fill(fill, label, formula, source):
    return Method(
        id=f"fill-{fill}",
        label=label,
        kernel=_sky_fill_kernel,
        inputs=_SKY,
        fixed={"fill": FILL_KERNELS[fill]},
        quantity="sky_irradiance",
        formula=formula,
        source=source,
    )


METHODS: Mapping[str, Method] = method_table(
    [
        _omega(
            "exact",
            "Ω exact (closed form)",
            "Ω = 4(β1 h1² + β2 h2²) − 2E (half-angle forms; nested, disjoint, covering cases)",
            "Tovchigrechko & Vakser 2001; Mazonka 2012 (arXiv:1205.1396)",
            exact=True,
        ),
        _omega(
            "smoothstep", "Ω smoothstep (seed)", "Ω ≈ A(r_min)·t²(3 − 2t)", "seed 000:2689-2762, Listing 1"
        ),
        _omega("linear", "Ω linear ramp", "Ω ≈ A(r_min)·t", "rtfit"),
        _omega(
            "fitted",
            "Ω fitted (complement + corrected smoothstep)",
            "Ω ≈ L + A(r_min)·sat(t²(3 − 2t) + t(1 − t)[c0 + c1u + ρ(c2 + c3u) + σ(c4 + c5u)])",
            "rtfit (ambient-aperture study)",
            params=COEFF_PARAMS,
        ),
        _shading("exact", "seed", "AA: exact Ω, seed Lambert"),
        _shading("smoothstep", "seed", "AA: smoothstep Ω, seed Lambert (seed)"),
        _shading("linear", "seed", "AA: linear Ω, seed Lambert"),
        _shading("fitted", "seed", "AA: fitted Ω, seed Lambert"),
        _shading("exact", "fitted", "AA: exact Ω, fitted Lambert"),
        _shading("fitted", "fitted", "AA: fitted Ω, fitted Lambert"),
        _fill("seed", "Seed fill: A(r_a)·cos(n,a)", "L_sky·A(r_a)·max(n·a, 0)", "seed 000:2774-2782"),
        _fill(
            "projected",
            "Projected-cap fill",
            "L_sky·∫_cap(a, r_a) max(n·ω, 0) dω",
            "closed-form projected solid angle of a cap (rtfit.realtime.diffuse)",
        ),
    ]
)
"""The family's methods as data, in the experiment's row order (module docstring: formulas).

* quantity ``cap_intersection_solid_angle`` (sr): the intersection forms, inputs r1, r2, d (rad);
  ``exact`` is the closed form, ``fitted`` has the six coefficients c0..c5 (`COEFF_PARAMS`).
* quantity ``light_irradiance`` (W/m²): ``aa-<form>-<lambert>``, the light term L·Ω·max(n·c, 0) with
  an intersection form and a Lambert factor (``fitted``: exponent k, `K_PARAM`).
* quantity ``sky_irradiance`` (W/m²): ``fill-<fill>``, the ambient fill of the whole aperture (no light).

Not exported from the package root (every family has its own ``METHODS``): import it from this module."""


# ===================================================================================== validation helpers
def _radius(name, r):
    return check_range(name, r, 0.0, _PI_MAX, interval="[0, pi]")


def _half(name, r):
    return check_range(name, r, 0.0, _HALF_PI_MAX, interval="[0, pi/2]")


def _cosine(name, c):
    return check_range(name, c, -1.0 - 1e-4, 1.0 + 1e-4, interval="[-1, 1]")


def _coeffs(coeffs) -> dict[str, float]:
    c = FITTED_COEFFS if coeffs is None else tuple(float(x) for x in coeffs)
    if len(c) != 6 or not all(math.isfinite(x) for x in c):
        raise ValueError(f"coeffs must be 6 finite numbers c0..c5 (got {coeffs!r})")
    return {f"c{i}": x for i, x in enumerate(c)}


def _caps(kernel, r1, r2, d, **params):
    return evaluate(
        lambda ops, a, b, e: kernel(ops, a, b, e, **params),
        _radius("r1", r1),
        _radius("r2", r2),
        _radius("d", d),
    )


# ===================================================================================== public API
def cap_area(r):
    """Solid angle (sr) of a spherical cap of angular radius r ∈ [0, π]: 2π(1 − cos r) = 4π sin²(r/2)."""
    return evaluate(_cap_area_kernel, _radius("r", r))


def cap_intersection_solid_angle(r1, r2, d):
    """Exact solid angle (sr) of the intersection of two caps of radii r1, r2 ∈ [0, π] whose centres are
    d ∈ [0, π] apart (all radians). Nested, disjoint, covering and tangent cases included; see module doc."""
    return _caps(_exact_kernel, r1, r2, d)


def cap_intersection_smoothstep(r1, r2, d):
    """The seed's approximation (000:2725-2755):
    A(r_min)·smoothstep(0, 1, 1 − (d − |r1−r2|)/(r1+r2−|r1−r2|))."""
    return _caps(_smoothstep_kernel, r1, r2, d)


def cap_intersection_linear(r1, r2, d):
    """Linear ramp: A(r_min)·(1 − (d − |r1−r2|)/(r1+r2−|r1−r2|)), clamped to [0, 1] inside."""
    return _caps(_linear_kernel, r1, r2, d)


def cap_intersection_fitted(r1, r2, d, coeffs: Sequence[float] | None = None):
    """Fitted replacement (complement trick + corrected smoothstep); ``coeffs`` c0..c5 default to
    `FITTED_COEFFS`. Always within [0, A(min(r1, r2))]."""
    return _caps(_fitted_kernel, r1, r2, d, **_coeffs(coeffs))


def seed_printed_intersect_area(r0, r1, d):
    """The seed's printed IntersectArea (000:2672-2687) verbatim, for the erratum only (it is wrong)."""
    return evaluate_numpy(_seed_printed_kernel, r0, r1, d)


def aperture_from_visibility(visible_fraction):
    """Aperture radius (rad) of the cap whose solid angle is the visible part of the hemisphere:
    r_a = acos(1 − V), V ∈ [0, 1] the visible fraction of uniformly distributed hemisphere directions."""
    return evaluate(_visibility_kernel, check_range("visible_fraction", visible_fraction, 0.0, 1.0))


def ambient_aperture_irradiance(
    cos_na,
    cos_nl,
    cos_al,
    aperture,
    alpha,
    radiance=1.0,
    sky_radiance=0.0,
    *,
    intersection: str = "exact",
    lambert: str = "seed",
    fill: str = "seed",
    coeffs: Sequence[float] | None = None,
    k: float | None = None,
):
    """Ambient-aperture irradiance (W/m²): returns ``(E_light, E_fill)``.

    ``cos_na`` = n·a, ``cos_nl`` = n·l, ``cos_al`` = a·l (unit normal n, bent normal a, light direction l);
    ``aperture`` r_a and ``alpha`` (light angular radius) in [0, π/2] rad; ``radiance`` of the light and
    ``sky_radiance`` of the ambient fill in W/m²/sr. ``intersection`` ∈ `INTERSECTION_FORMS`, ``lambert`` ∈
    `LAMBERT_FORMS` ("seed": plain average direction; "fitted": cap-size weights with exponent ``k``),
    ``fill`` ∈ `FILL_FORMS` ("seed": solid angle × bent-normal cosine; "projected": exact projected solid
    angle of the aperture). See the module docstring for the formulas; `METHODS` holds the same light
    terms (``aa-<intersection>-<lambert>``) and fills (``fill-<fill>``) as data.
    """
    if intersection not in INTERSECTION_FORMS:
        raise ValueError(f"intersection must be one of {INTERSECTION_FORMS} (got {intersection!r})")
    if lambert not in LAMBERT_FORMS:
        raise ValueError(f"lambert must be one of {LAMBERT_FORMS} (got {lambert!r})")
    if fill not in FILL_FORMS:
        raise ValueError(f"fill must be one of {FILL_FORMS} (got {fill!r})")
    kk = FITTED_LAMBERT_K if k is None else float(k)
    if not (0.0 < kk <= 16.0):
        raise ValueError(f"k must be in (0, 16] (got {k!r})")
    # Only the fitted form takes coefficients (``coeffs`` is ignored, unchecked, for the others).
    coeff_kw = _coeffs(coeffs) if intersection in FORM_PARAMS else {}
    modes = {
        "intersection": INTERSECTION_KERNELS[intersection],
        "weight": LAMBERT_WEIGHTS[lambert],
        "fill": FILL_KERNELS[fill],
    }

    def kernel(ops, *args):
        return _shading_kernel(ops, *args, **modes, k=kk, **coeff_kw)

    return evaluate(
        kernel,
        _cosine("cos_na", cos_na),
        _cosine("cos_nl", cos_nl),
        _cosine("cos_al", cos_al),
        _half("aperture", aperture),
        _half("alpha", alpha),
        check_range("radiance", radiance, 0.0, 1.7e308, interval="[0, inf)"),
        check_range("sky_radiance", sky_radiance, 0.0, 1.7e308, interval="[0, inf)"),
    )
