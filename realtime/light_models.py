r"""Light models of the diffuse family: each evaluated from the light's own parameters, not from a reference.

The diffuse family's first rows (`rtfit.realtime.diffuse`: Lambert, half-Lambert, wrap) are handed the light's
irradiance at normal incidence E⊥, so they compare an angular falloff only. The rows here are what an engine
does instead: they read the light as the engine stores it (position, intensity or radiance and size, cone
angles) and compute the irradiance E (W/m²) on a surface of unit normal n at a point x themselves.

Conventions and units
---------------------
* ``cos_theta`` = n·t, t the unit direction from x to the light's centre; ``distance`` d = |c − x| (scene
  units, read as metres where a constant has a unit: the engines' 1 cm guards below).
* ``intensity`` I (W/sr): the light's radiant intensity towards x, from its own parameters
  (`rtfit.experiments.audit_lights.light_intensity`): a point light's I; a uniform sphere of radiance L and
  radius r: I = π r² L (its projected area times L, Φ/4π); a one-sided planar light of area A (rectangle,
  disc): I = L A max(cos θ_l, 0), θ_l the angle at the light between its normal and x.
* ``alpha`` α = asin(r/d) (rad), ``radiance`` L (W/m²/sr): a sphere light's, as in `diffuse`.
* A rectangle light: centre (``lcx``, ``lcy``, ``lcz``) and half-edge vectors u (``lux``…) and v (``lvx``…),
  corners c ± u ± v, emitting on the side of u × v (Mitsuba's ``rectangle``: to_world of [−1, 1]² at z = 0,
  normal +z); the point ``px``…, its normal ``nx``… (need not be unit length).
* A disc light: centre (``dcx``, ``dcy``, ``dcz``), unit normal m (``dmx``…: it emits on the side m points
  to; Mitsuba's ``disk``: to_world of the unit disc at z = 0, normal +z) and ``disc_radius`` R.
* A spot light: on-axis ``axis_intensity`` I₀, ``cos_axis`` = cos φ, φ the angle at the light between its axis
  and the direction to x, ``cutoff`` φ_c and ``beam`` φ_b (rad; Mitsuba's ``cutoff_angle`` and
  ``beam_width``).

Formulas (one kernel text each)
-------------------------------
* ``punctual`` — inverse-square at the light's centre: E = I·max(cos θ, 0)/d². Exact for a point light; the
  far-field limit of every local light (a sphere: exact above the horizon, `diffuse` ``exact``).
* ``unreal-window`` — E = I·max(cos θ, 0)·saturate(1 − (d/r)⁴)² / (d² + d₀²), d₀ = 1 cm (Karis 2013, "Real
  Shading in Unreal Engine 4", SIGGRAPH course notes, "Lighting model", inverse-square falloff windowed to
  zero at the light's radius r; the "+1" of the paper is 1 cm² in Unreal's centimetre units).
* ``frostbite-window`` — E = I·max(cos θ, 0)·saturate(1 − (d²/r²)²)² / max(d², d₀²), d₀ = 1 cm (Lagarde &
  de Rousiers 2014, "Moving Frostbite to Physically Based Rendering", punctual-light section, listing
  smoothDistanceAtt/getDistanceAtt: ``1/max(sqrDist, 0.01²)``). The two windows are the same function of
  d/r; they differ only in how they bound the inverse square near the light. r is an artist's setting with
  no published value (``Param.published`` False): the audit shows it fitted only, its start 2 × the
  largest distance from the light to a visible point.
* ``representative-point`` — a sphere light in Karis 2013's "Area lights" scheme: for a Lambertian receiver
  the representative point is the centre (a sphere above the horizon lights a surface exactly as a point
  light of I = π r² L does), E = π sin²α L · w(cos θ, sin α) with w = cos θ above the horizon
  (cos θ ≥ sin α), 0 below (cos θ ≤ −sin α) and, across the horizon band, Unreal's smooth wrap
  w = (sin α + cos θ)²/(4 sin α) (UE4 ``SphereHorizonCosWrap``, a smooth stand-in for the exact clipped
  form of Lagarde & de Rousiers 2014's sphere-light section).
* ``tube`` — a tube light (Mitsuba's ``cylinder`` with an ``area`` emitter: radius r, axis from L0 + x to
  L1 + x, open ends, radiance L outwards) as Karis 2013's line light ("Tube lights"): a segment of
  isotropic points of intensity I' = 2rL per unit length (the tube's width 2r times L: its intensity
  seen side-on), E = I'·ℓ·max(NoL·falloff, 0), ℓ = |L1 − L0|, with Karis's (Picott 1992) closed form of
  the segment's inverse-square integral ∫₀¹ n·L(t)/|L(t)|³ dt, L(t) = L0 + t(L1 − L0):
      NoL = (n·L0/|L0| + n·L1/|L1|)/2,  falloff = 2/(|L0||L1| + L0·L1)
  (Karis's listing; the identity is exact, tests/test_light_models.py). Assumptions: thin (r ≪ distance)
  and every point of the segment emitting the side-on I' — a real tube's element emits 2rL·|sin ψ| (ψ
  between the axis and the direction to x), so the row is exact only side-on in the thin far limit and
  overestimates elsewhere by up to 1/|sin ψ| (end-on: without bound, an open tube seen end-on shows no
  area); across the horizon the signed integral (not clipped per element) is clipped at 0. Measured
  against quadrature over the cylinder (docs/diffuse.md, "The tube row"). The punctual rows read a tube
  as I = 2rℓL|sin ψ| at its centre (its projected area × L, `audit_lights.light_model_inputs`).
  Float32: lengths divided by k = max(r, |L0|∞, |L1|∞) (E is scale-free); |L0||L1| + L0·L1 written as
  |L0 × L1|²/(|L0||L1| − L0·L1) where L0·L1 < 0 (no cancellation beside the segment).
* ``polygon`` (LTC, diffuse) — a rectangle light by Lambert's formula for a polygon of uniform radiance L,
  horizon-clipped: E = L·max(−½ Σᵢ Θᵢ (n·Γᵢ), 0) over the clipped polygon's edges (vᵢ, vᵢ₊₁) seen from x,
  Θᵢ the angle between them, Γᵢ the unit normal of their plane (Lambert 1760; Arvo 1994, "The irradiance
  Jacobian for partially occluded polyhedral sources", eq. 9). For a diffuse receiver the linearly
  transformed cosine of Heitz, Dupuy, Hill & Neubelt 2016 ("Real-time polygonal-light shading with
  linearly transformed cosines") is the clamped cosine itself (its matrix M is the identity), so this is
  the LTC-diffuse evaluation; no fit table is involved. One-sided: a point behind the light's plane sees
  the polygon wound the other way, −½ Σ is ≤ 0 and E = 0. Exact, but not marked ``exact`` (no z-check in the
  audit): Mitsuba samples a rectangle uniformly by area, and near the light its estimates are heavy-tailed
  (a 0.8 × 0.4 light 0.6 above a floor, 16 spp: z spread 0.77, 3 % of |z| > 4), so a z-check would fail on
  the reference's noise, not the formula; tests/test_light_models.py checks it against quadrature.
* ``disc`` (LTC, diffuse) — a one-sided uniform disc of radiance L, centre c, unit normal m (it emits on
  the side m points to), radius R. With h = m·(x − c) the height of x over its plane, o = (x − c) − h m
  the offset of x from its axis (ρ = |o|), A = ρ² + R² + h² and S = √(A² − 4R²ρ²), the vector form factor
  F = ∫_disc ω dω (sr; the vector irradiance over L) is, for h > 0,

      F = −πR² (2h·o + G·m) / (S (S + A)),   G = S + R² + h² − ρ²

  (Arvo 1994's contour form F = ½ ∮ p × dp/|p|² on the rim p(t) = c − x + R(cos t e₁ + sin t e₂), whose
  integrals ∫ dt/(A − B cos t) and ∫ cos t dt/(A − B cos t), B = 2Rρ, have closed forms over a full turn;
  its m and o components are π × the configuration factors of a differential element to a disc in a
  parallel and in a perpendicular plane, Howell's catalogue of radiation configuration factors, section B;
  on the axis, n = −m: E = πL R²/(h² + R²)). Heitz & Hill 2017 ("Real-time line- and disk-light shading
  with linearly transformed cosines", SIGGRAPH course "Physically Based Shading in Theory and Practice")
  find the same F for the LTC-transformed ellipse through an eigen-decomposition (length
  π·L₁L₂/√((1 + L₁²)(1 + L₂²)) along its axis); for a diffuse receiver M = I and the ellipse is the disc
  itself, so the closed form above is their vector form factor, without the 3 × 3 eigen-solve.

  - **Wholly above x's horizon** (n·(c − x) ≥ R|n × m|: the rim's lowest point over the tangent plane):
    E = L·max(n·F, 0), exact.
  - **Wholly below** (n·(c − x) ≤ −R|n × m|) **or behind the light** (h ≤ 0): E = 0, exact.
  - **Across the horizon: approximate.** The published horizon handling (Heitz & Hill 2017's disc code and
    Hill & Heitz 2016, "Real-time area lighting: a journey from research to production", the LTC
    table's clipped sphere; Unity HDRP AreaLighting.hlsl ``DiffuseSphereLightIrradiance``): the
    horizon-clipped irradiance of the sphere cap with the same vector form factor, sin²α = |F|/π, cos ω =
    n·F/|F|, evaluated by the exact clipped-cap formula (Snyder 1996, `sphere_light_irradiance_kernel`,
    the diffuse family's ``exact`` text) where the engines read a 64² table of it. Measured against
    quadrature of the clipped disc (tests/test_light_models.py, 400 crossing configurations): error ≤
    8.4 % of L|F| (rms 1.3 %, mean −0.3 %); relative to the true value ≤ 68 % where it exceeds 0.1 L|F|
    (median 1.3 %): the cap is a circle of directions, the clipped disc an ellipse cut by a plane. At the
    seam (the rim touching the horizon) the row jumps by ≤ 1.0 % of L|F| (200 seams; median 2e-9, where the
    cap is also above its own horizon).

  Float32: every length is divided by k = max(R, |x − c|∞) first (F is scale-free), so no square
  overflows or loses the small disc's R²; S is written as a sum of squares, S − (ρ² − R² − h²) as
  4h²ρ²/(S + ρ² − R² − h²) where that difference is positive: no cancellation away from the rim.
  An elliptical ``disk`` (to_world scaling x and y differently) is not this row's (the audit leaves it out).
* ``spot-linear`` — Mitsuba 3's ``spot`` (spot.cpp ``falloff_curve``): E = I₀ f(φ) max(cos θ, 0)/d² with
  f = clamp((φ_c − φ)/(φ_c − φ_b), 0, 1), linear in the angle. Exact for Mitsuba's spot, but not marked
  ``exact``: a spot's reference (one emitter sample per pixel is exact) has no noise to z-score against;
  tests/test_light_models.py asserts the agreement instead.
* ``spot-smoothstep`` — three.js ``getSpotAttenuation``: f = smoothstep(cos φ_c, cos φ_b, cos φ).
* ``spot-squared`` — Unreal's ``SpotAttenuation`` and Frostbite's getAngleAtt (Lagarde & de Rousiers 2014,
  punctual lights): f = saturate((cos φ − cos φ_c)/(cos φ_b − cos φ_c))², quadratic in the cosine.

Guards (each keeps a value finite where the formula has none; none changes a value in its domain)
--------------------------------------------------------------------------------------------------
* d² ≥ 1e-20 in ``punctual`` and the spots (`_D2_MIN`): the inverse square is infinite at the light's centre
  (d → 0); the floor only keeps the output finite, 1e-10 scene units being far below any pixel's distance.
* r ≥ 1e-30 in the windows (`safe_div`): r = 0 gives a window of 0, not 0/0.
* the polygon: a zero vertex vector (x at a corner) or antipodal vertices (x on an edge) give an edge term
  of 0, the bound |n·(â×b̂)| ≤ |â×b̂| keeps Θ·(n·Γ) ≤ π without dividing by sin Θ → 0; the horizon crossing
  parameter is clipped to [0, 1]; E is clipped at 0 (one-sided light, rounding).
* the disc: k ≥ 1e-30 (x at the centre of a disc of radius 0: all lengths 0, F = 0); S(S + A) = 0 only on
  the rim in its plane (h = 0, ρ = R), where h ≤ 0 gives E = 0 anyway (`safe_div`: 0, not 0/0); the
  4h²ρ²/(S + …) branch's denominator is clipped at its selected sign; |F|/π clipped to [0, 1] and n·F/|F|
  to [−1, 1] (rounding; |F| = 0 gives cos ω = 0, α = 0, E = 0); n or m of length 0 give E = 0.
* the tube: |L0||L1| + L0·L1 ≥ 2r² (it is 2ρ² at distance ρ beside a long segment's middle, 0 on the
  segment: the floor binds only within about r of the axis, inside or at the tube, where the thin line
  does not hold); a zero L0 or L1 (x at an end) gives its NoL half 0 (`safe_div`); k ≥ 1e-30.
* the spots: φ_c − φ_b ≥ 1e-30 (a hard cone when the beam fills it); cos φ clamped to [−1, 1] before acos.

Accuracy (tests/test_light_models.py): the polygon form against 2-D Gauss–Legendre quadrature over the
rectangle at 200 random configurations, many partly below the horizon: ≤ 1e-9 relative in float64; in
float32 its four edge terms of size ~s/d cancel to a sum of size ~(s/d)², so its relative error grows as
~1e-7·d/s for a light of size s at distance d. The disc form against polar Gauss–Legendre quadrature over
the disc at 120 configurations wholly above the horizon: ≤ 1e-9 relative in float64 (5.6e-10), 1.0e-6 in
Dr.Jit float32; across the horizon it is approximate (``disc`` above: ≤ 8.4 % of L|F|).

Methods as data: ``METHODS`` (`rtfit.realtime.methods.method_table`) declares each formula once; the diffuse
family's table (`rtfit.realtime.diffuse.METHODS`) includes them, so the audit evaluates them on every light
whose part provides their inputs (`rtfit.experiments.audit.PROVIDES`) and lists the rest as left out.
"""

from __future__ import annotations

import math

from .arrays import (
    ATAN_SERIES_LIMIT,
    atan_minus_x_series,
    clamp01,
    clamp_cos,
    safe_div,
    safe_sqrt,
    sin_from_cos,
    sincos_first_quadrant,
)
from .methods import Input, Method, Param, method_table

__all__ = ["sphere_light_irradiance_kernel"]

D0 = 0.01
"""The engines' near-field guard, 1 cm in metres (Unreal's "+1" in cm², Frostbite's ``0.01*0.01``)."""
_D2_MIN = 1e-20  # the inverse square's floor at the light's centre (module docstring, Guards)
_TINY = 1e-30
HALF_PI = 0.5 * math.pi


# ===================================================================================== kernels (ops text)
def _inverse_square(ops, cos_theta, distance, intensity):
    """I·max(cos θ, 0)/max(d², 1e-20): the punctual term every row below shares."""
    d2 = ops.maximum(distance * distance, _D2_MIN)  # d → 0: finite (Guards)
    return intensity * ops.clip(cos_theta, 0.0, 1.0) / d2


def _punctual_kernel(ops, cos_theta, distance, intensity):
    """Inverse square at the light's centre: E = I·max(cos θ, 0)/d²."""
    return _inverse_square(ops, cos_theta, distance, intensity)


def _window(ops, distance, r):
    """saturate(1 − (d/r)⁴)², written (d²/r²)² as Frostbite does; r = 0 gives 0 (safe_div)."""
    x = safe_div(ops, distance * distance, r * r)
    w = clamp01(ops, 1.0 - x * x)
    return w * w


def _unreal_window_kernel(ops, cos_theta, distance, intensity, r):
    """E = I·max(cos θ, 0)·saturate(1 − (d/r)⁴)²/(d² + d₀²) (Karis 2013)."""
    c = ops.clip(cos_theta, 0.0, 1.0)
    return intensity * c * _window(ops, distance, r) / (distance * distance + D0 * D0)


def _frostbite_window_kernel(ops, cos_theta, distance, intensity, r):
    """E = I·max(cos θ, 0)·saturate(1 − (d²/r²)²)²/max(d², d₀²) (Lagarde & de Rousiers 2014)."""
    c = ops.clip(cos_theta, 0.0, 1.0)
    return intensity * c * _window(ops, distance, r) / ops.maximum(distance * distance, D0 * D0)


def _representative_point_kernel(ops, cos_theta, alpha, radiance):
    """E = π sin²α L · w: w = cos θ above the horizon, (sin α + cos θ)²/(4 sin α) across it, 0 below."""
    c = clamp_cos(ops, cos_theta)
    s = ops.sin(ops.clip(alpha, 0.0, 0.5 * math.pi))
    band = safe_div(ops, (s + c) * (s + c), 4.0 * s)  # s = 0: the band is empty; finite anyway
    w = ops.select(c >= s, c, ops.select(c <= -s, 0.0, band))
    return (math.pi * radiance) * (s * s) * w


def _unit3(ops, x, y, z):
    """(x, y, z)/|(x, y, z)|; the zero vector stays zero (safe_div)."""
    n = safe_sqrt(ops, x * x + y * y + z * z)
    return safe_div(ops, x, n), safe_div(ops, y, n), safe_div(ops, z, n)


def _edge(ops, a, b, n):
    """Θ·(n·Γ) for the arc from a to b (unnormalised 3-tuples), n a unit normal: Θ = atan2(|â×b̂|, â·b̂),
    n·Γ = n·(â×b̂)/|â×b̂| ∈ [−1, 1] (clipped: 0/0 where â×b̂ = 0, then Θ·0 = 0)."""
    ax, ay, az = _unit3(ops, *a)
    bx, by, bz = _unit3(ops, *b)
    wx, wy, wz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    s = safe_sqrt(ops, wx * wx + wy * wy + wz * wz)
    c = ax * bx + ay * by + az * bz
    q = ops.clip(safe_div(ops, n[0] * wx + n[1] * wy + n[2] * wz, s), -1.0, 1.0)
    return ops.atan2(s, c) * q


def _lerp3(a, b, t):
    return tuple(ai + (bi - ai) * t for ai, bi in zip(a, b, strict=True))


def _select3(ops, m, a, b):
    return tuple(ops.select(m, ai, bi) for ai, bi in zip(a, b, strict=True))


def _polygon_kernel(
    ops, px, py, pz, nx, ny, nz, lcx, lcy, lcz, lux, luy, luz, lvx, lvy, lvz, radiance
):  # fmt: skip
    """E = L·max(−½ Σ Θᵢ n·Γᵢ, 0) over the rectangle c ± u ± v clipped to the horizon n·ω ≥ 0 at x.

    Edge by edge: both ends above the horizon — the edge; one above — the part above, ending (exit) or
    starting (entry) on the horizon; none — nothing. A convex polygon crosses the horizon plane through x
    at most twice, so the clipped polygon is closed by one arc along the horizon, from the exit point to the
    entry point."""
    n = _unit3(ops, nx, ny, nz)
    cx, cy, cz = lcx - px, lcy - py, lcz - pz
    corners = [
        (cx + su * lux + sv * lvx, cy + su * luy + sv * lvy, cz + su * luz + sv * lvz)
        for su, sv in ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))
    ]  # counter-clockwise seen from the side u × v points to, where Σ Θᵢ n·Γᵢ ≤ 0
    h = [n[0] * v[0] + n[1] * v[1] + n[2] * v[2] for v in corners]
    total = 0.0 * px
    exit_pt = entry_pt = (0.0 * px, 0.0 * px, 0.0 * px)
    crossed = h[0] > 1e300  # all False, of the backend's mask type
    for i in range(4):
        j = (i + 1) % 4
        a, b, ha, hb = corners[i], corners[j], h[i], h[j]
        up_a, up_b = ha > 0.0, hb > 0.0
        t = clamp01(ops, safe_div(ops, ha, ops.abs(ha - hb)) * ops.select(ha > hb, 1.0, -1.0))
        x = _lerp3(a, b, t)  # the horizon crossing of edge a→b (used only where it crosses)
        leaving = up_a & (hb <= 0.0)
        entering = (ha <= 0.0) & up_b
        start = _select3(ops, entering, x, a)
        end = _select3(ops, leaving, x, b)
        term = _edge(ops, start, end, n)
        total = total + ops.select(up_a | up_b, term, 0.0)
        exit_pt = _select3(ops, leaving, x, exit_pt)
        entry_pt = _select3(ops, entering, x, entry_pt)
        crossed = crossed | leaving
    total = total + ops.select(crossed, _edge(ops, exit_pt, entry_pt, n), 0.0)
    return radiance * ops.maximum(-0.5 * total, 0.0)  # counter-clockwise seen from x: Σ ≤ 0 (front)


# The exact sphere light (`rtfit.realtime.diffuse` ``exact``; its formula, accuracy and guards are stated
# there): its text lives here because the disc row below reads it for its horizon band, and the diffuse
# module imports this one (not the reverse).
def sphere_light_irradiance_kernel(ops, cos_theta, alpha, radiance):
    """Exact irradiance from a uniform sphere light (cap of half-angle α), horizon clipping included.

    Kernel text (``ops`` an ops namespace of `rtfit.realtime.arrays`, no validation): public so that other
    kernels (ambient aperture's projected cap) can call the one text inside their own."""
    c = clamp_cos(ops, cos_theta)
    a = ops.clip(alpha, 0.0, HALF_PI)
    sin_a, cos_a = sincos_first_quadrant(ops, a)  # not ops.sin/cos: CUDA float32 sin/cos are approximate
    cos_a = ops.maximum(cos_a, 0.0)  # float32(π/2) exceeds π/2: its cosine would be −4.4e-8
    sin2_a = sin_a * sin_a
    sin_t = sin_from_cos(ops, c)

    above = math.pi * sin2_a * c  # whole cap above the horizon

    # Horizon-clipped cap. Denominators are guarded so that the branch not selected stays finite.
    y = clamp_cos(ops, safe_div(ops, -cos_a * c, sin_a * sin_t))
    s = safe_sqrt(ops, (1.0 - y) * (1.0 + y))
    g = sin_a * sin_t * s  # sin α sin θ √(1 − y²)
    u = safe_div(ops, g, cos_a)  # tan α sin θ √(1 − y²) ≥ 0
    c_acos = c * ops.acos(y)
    small = sin2_a * (c_acos + u) + atan_minus_x_series(ops, ops.minimum(u, ATAN_SERIES_LIMIT))
    large = sin2_a * c_acos + (ops.atan2(g, cos_a) - g * cos_a)
    partial = ops.select(u < ATAN_SERIES_LIMIT, small, large)
    partial = ops.clip(partial, 0.0, math.pi * sin2_a)  # rounding only: 0 ≤ E ≤ E⊥ holds exactly

    e = ops.select(c >= sin_a, above, ops.select(c <= -sin_a, 0.0, partial))
    return radiance * e


def _disc_kernel(
    ops, px, py, pz, nx, ny, nz, dcx, dcy, dcz, dmx, dmy, dmz, disc_radius, radiance
):  # fmt: skip
    """E = L·n·F for the one-sided disc (centre c, normal m, radius R) wholly above x's horizon, 0 wholly
    below or behind, else the sphere cap of F's length and direction (module docstring, ``disc``).

    Lengths are divided by k = max(R, |x − c|∞) first: F is scale-free, and every square below is then ≤ 3
    (no float32 overflow of R⁴ or d⁴ for any finite input)."""
    n = _unit3(ops, nx, ny, nz)
    m = _unit3(ops, dmx, dmy, dmz)
    wx, wy, wz = px - dcx, py - dcy, pz - dcz  # x − c
    r_abs = ops.abs(disc_radius)
    k = ops.maximum(ops.maximum(r_abs, ops.abs(wx)), ops.maximum(ops.abs(wy), ops.abs(wz)))
    k = ops.maximum(k, _TINY)  # x = c and R = 0: every length 0, F = 0 below (Guards)
    rad, wx, wy, wz = r_abs / k, wx / k, wy / k, wz / k
    h = m[0] * wx + m[1] * wy + m[2] * wz  # height of x over the disc's plane, > 0 on its emitting side
    ox, oy, oz = wx - h * m[0], wy - h * m[1], wz - h * m[2]  # in-plane offset of x from the axis, |o| = ρ
    rho2, r2, h2 = ox * ox + oy * oy + oz * oz, rad * rad, h * h
    a = rho2 + r2 + h2
    q = rho2 - r2
    s = safe_sqrt(ops, q * q + h2 * (2.0 * (rho2 + r2) + h2))  # √(A² − 4R²ρ²), a sum of squares
    dd = q - h2  # S² − dd² = 4h²ρ²: S − dd without cancellation on either sign of dd
    g = ops.select(dd <= 0.0, s - dd, safe_div(ops, 4.0 * h2 * rho2, s + ops.maximum(dd, 0.0)))
    scale = safe_div(ops, math.pi * r2, s * (s + a))  # S = 0 only on the rim (h = 0, ρ = R): 0 (Guards)
    fx = -scale * (2.0 * h * ox + g * m[0])  # F = −πR²(2h·o + G·m)/(S(S + A))
    fy = -scale * (2.0 * h * oy + g * m[1])
    fz = -scale * (2.0 * h * oz + g * m[2])
    nf = n[0] * fx + n[1] * fy + n[2] * fz
    f = safe_sqrt(ops, fx * fx + fy * fy + fz * fz)
    # The disc against x's tangent plane: its rim's lowest point is n·(c − x) − R|n × m| over it.
    hn = -(n[0] * wx + n[1] * wy + n[2] * wz)
    cx, cy, cz = n[1] * m[2] - n[2] * m[1], n[2] * m[0] - n[0] * m[2], n[0] * m[1] - n[1] * m[0]
    reach = rad * safe_sqrt(ops, cx * cx + cy * cy + cz * cz)
    above, up = hn >= reach, hn > -reach  # wholly above; not wholly below
    # Across the horizon: the cap of solid-angle form factor |F| = π sin²α around F/|F| (Heitz & Hill).
    sin2 = ops.clip(f / math.pi, 0.0, 1.0)  # |F| ≤ π: rounding only
    alpha = ops.atan2(safe_sqrt(ops, sin2), safe_sqrt(ops, 1.0 - sin2))
    cap = sphere_light_irradiance_kernel(ops, clamp_cos(ops, safe_div(ops, nf, f)), alpha, 1.0)
    e = ops.select(above, ops.maximum(nf, 0.0), cap)
    return radiance * ops.select(h > 0.0, ops.select(up, e, 0.0), 0.0)  # one-sided: 0 behind


def _tube_kernel(
    ops, px, py, pz, nx, ny, nz, tax, tay, taz, tbx, tby, tbz, tube_radius, radiance
):  # fmt: skip
    """Karis 2013's tube: E = 2rL·ℓ·max(NoL·falloff, 0), NoL = (n·L̂0 + n·L̂1)/2, falloff =
    2/(|L0||L1| + L0·L1), L0, L1 the axis's ends seen from x (module docstring, ``tube``)."""
    n = _unit3(ops, nx, ny, nz)
    ax, ay, az = tax - px, tay - py, taz - pz  # L0
    bx, by, bz = tbx - px, tby - py, tbz - pz  # L1
    r_abs = ops.abs(tube_radius)
    k = ops.maximum(ops.maximum(r_abs, ops.maximum(ops.abs(ax), ops.abs(ay))), ops.abs(az))
    k = ops.maximum(ops.maximum(k, ops.maximum(ops.abs(bx), ops.abs(by))), ops.abs(bz))
    k = ops.maximum(k, _TINY)  # E is scale-free: every square below is ≤ 3 after this (Guards)
    rad, ax, ay, az, bx, by, bz = r_abs / k, ax / k, ay / k, az / k, bx / k, by / k, bz / k
    la = safe_sqrt(ops, ax * ax + ay * ay + az * az)
    lb = safe_sqrt(ops, bx * bx + by * by + bz * bz)
    dx, dy, dz = bx - ax, by - ay, bz - az
    length = safe_sqrt(ops, dx * dx + dy * dy + dz * dz)
    nol = 0.5 * (
        safe_div(ops, n[0] * ax + n[1] * ay + n[2] * az, la)
        + safe_div(ops, n[0] * bx + n[1] * by + n[2] * bz, lb)
    )
    dot = ax * bx + ay * by + az * bz
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    beside = safe_div(ops, cx * cx + cy * cy + cz * cz, la * lb - ops.minimum(dot, 0.0))
    den = ops.select(dot >= 0.0, la * lb + dot, beside)  # |L0||L1| + L0·L1 without cancellation
    den = ops.maximum(den, 2.0 * rad * rad)  # within ~r of the axis: the tube, not a line (Guards)
    e = safe_div(ops, 2.0 * nol, den) * (2.0 * rad * length)  # falloff·NoL·I'ℓ/L
    return radiance * ops.maximum(e, 0.0)


def _spot_cos(ops, cos_axis):
    return clamp_cos(ops, cos_axis)


def _spot_linear_kernel(ops, cos_theta, distance, axis_intensity, cos_axis, cutoff, beam):
    """Mitsuba's spot: f = clamp((φ_c − φ)/(φ_c − φ_b), 0, 1), E = I₀ f max(cos θ, 0)/d²."""
    phi = ops.acos(_spot_cos(ops, cos_axis))
    f = clamp01(ops, safe_div(ops, cutoff - phi, ops.maximum(cutoff - beam, 0.0)))
    f = ops.select(cutoff - beam > 0.0, f, ops.select(phi < cutoff, 1.0, 0.0))  # a hard cone (Guards)
    return f * _inverse_square(ops, cos_theta, distance, axis_intensity)


def _smooth_t(ops, cos_axis, cutoff, beam):
    """saturate((cos φ − cos φ_c)/(cos φ_b − cos φ_c)); a hard cone where cos φ_b ≤ cos φ_c."""
    ca = _spot_cos(ops, cos_axis)
    lo, hi = ops.cos(cutoff), ops.cos(beam)
    t = clamp01(ops, safe_div(ops, ca - lo, ops.maximum(hi - lo, 0.0)))
    return ops.select(hi - lo > 0.0, t, ops.select(ca > lo, 1.0, 0.0))


def _spot_smoothstep_kernel(ops, cos_theta, distance, axis_intensity, cos_axis, cutoff, beam):
    """three.js: f = smoothstep(cos φ_c, cos φ_b, cos φ) = t²(3 − 2t)."""
    t = _smooth_t(ops, cos_axis, cutoff, beam)
    return t * t * (3.0 - 2.0 * t) * _inverse_square(ops, cos_theta, distance, axis_intensity)


def _spot_squared_kernel(ops, cos_theta, distance, axis_intensity, cos_axis, cutoff, beam):
    """Unreal / Frostbite: f = saturate((cos φ − cos φ_c)/(cos φ_b − cos φ_c))²."""
    t = _smooth_t(ops, cos_axis, cutoff, beam)
    return t * t * _inverse_square(ops, cos_theta, distance, axis_intensity)


# ===================================================================================== methods as data
_COS = Input(
    "cos_theta", "1", "n·t, cosine between the normal and the direction to the light's centre", (-1.0, 1.0)
)
_DIST = Input("distance", "m", "d, distance from the point to the light's centre", (1e-3, 100.0))
_INTENSITY = Input("intensity", "W/sr", "the light's radiant intensity towards the point", (0.0, 100.0))
_ALPHA = Input("alpha", "rad", "angular radius of the sphere light seen from the point", (0.0, 0.5 * math.pi))
_RADIANCE = Input("radiance", "W/m²/sr", "the light's uniform radiance L", (0.0, 10.0))
_WINDOW_R = Param(
    10.0, 1e-3, 1e6, unit="m", published=False,
    description="window radius r: the falloff reaches 0 at d = r (an artist's setting per light)",
)  # fmt: skip
_POLYGON_INPUTS = tuple(
    Input(name, "m", text, (lo, hi))
    for name, text, lo, hi in (
        *((f"p{a}", f"the shaded point, {a}", -1.0, 1.0) for a in "xyz"),
        *((f"n{a}", f"the point's normal, {a}", -1.0, 1.0) for a in "xyz"),
        *((f"lc{a}", f"the rectangle's centre, {a}", -3.0, 3.0) for a in "xyz"),
        *((f"lu{a}", f"the rectangle's first half-edge u, {a}", -1.0, 1.0) for a in "xyz"),
        *((f"lv{a}", f"the rectangle's second half-edge v, {a}", -1.0, 1.0) for a in "xyz"),
    )
)
_DISC_INPUTS = (
    *_POLYGON_INPUTS[:6],
    *(Input(f"dc{a}", "m", f"the disc's centre, {a}", (-3.0, 3.0)) for a in "xyz"),
    *(
        Input(f"dm{a}", "1", f"the disc's unit normal (it emits on this side), {a}", (-1.0, 1.0))
        for a in "xyz"
    ),
    Input("disc_radius", "m", "the disc's radius R", (0.0, 2.0)),
)
_TUBE_INPUTS = (
    *_POLYGON_INPUTS[:6],
    *(Input(f"ta{a}", "m", f"the tube's axis, first end (Mitsuba's p0), {a}", (-3.0, 3.0)) for a in "xyz"),
    *(Input(f"tb{a}", "m", f"the tube's axis, second end (Mitsuba's p1), {a}", (-3.0, 3.0)) for a in "xyz"),
    Input("tube_radius", "m", "the tube's radius r", (0.0, 0.5)),
)
_SPOT_INPUTS = (
    _COS,
    _DIST,
    Input("axis_intensity", "W/sr", "the spot's on-axis radiant intensity I₀", (0.0, 100.0)),
    Input("cos_axis", "1", "cos φ: the spot's axis · the direction from the light to the point", (-1.0, 1.0)),
    Input("cutoff", "rad", "φ_c, Mitsuba's cutoff_angle", (0.3, 1.2)),
    Input("beam", "rad", "φ_b, Mitsuba's beam_width", (0.0, 0.29)),
)
_SPOT_SOURCE = "cone angles φ_b (beam_width), φ_c (cutoff_angle) of Mitsuba's spot"

METHODS = method_table(
    [
        Method(
            "punctual",
            "Punctual (inverse square)",
            _punctual_kernel,
            inputs=(_COS, _DIST, _INTENSITY),
            quantity="light_irradiance",
            formula="E = I·max(cos θ, 0)/d²",
            source="inverse-square law at the light's centre (I: the light's intensity towards the point)",
            description="The light as a point at its centre: exact for a point light, the far field of any.",
        ),
        Method(
            "unreal-window",
            "Unreal windowed falloff",
            _unreal_window_kernel,
            inputs=(_COS, _DIST, _INTENSITY),
            params={"r": _WINDOW_R},
            quantity="light_irradiance",
            formula="E = I·max(cos θ, 0)·saturate(1 − (d/r)⁴)²/(d² + (1 cm)²)",
            source="Karis 2013, Real Shading in Unreal Engine 4, lighting model (inverse-square falloff)",
            description="Inverse square windowed to 0 at the radius r (fitted); +1 cm² near the light.",
        ),
        Method(
            "frostbite-window",
            "Frostbite smooth window",
            _frostbite_window_kernel,
            inputs=(_COS, _DIST, _INTENSITY),
            params={"r": _WINDOW_R},
            quantity="light_irradiance",
            formula="E = I·max(cos θ, 0)·saturate(1 − (d²/r²)²)²/max(d², (1 cm)²)",
            source="Lagarde & de Rousiers 2014, Moving Frostbite to PBR, punctual lights (smoothDistanceAtt)",
            description="Unreal's window with the inverse square floored at 1 cm instead of offset.",
        ),
        Method(
            "representative-point",
            "Representative point (sphere)",
            _representative_point_kernel,
            inputs=(_COS, _ALPHA, _RADIANCE),
            quantity="light_irradiance",
            formula="E = π sin²α L·{cos θ; (sin α + cos θ)²/(4 sin α) across the horizon; 0}",
            source="Karis 2013, area lights (sphere = point above the horizon); UE4 SphereHorizonCosWrap",
            description="A sphere light as its centre, with Unreal's smooth wrap across the horizon.",
        ),
        Method(
            "polygon",
            "LTC polygon (diffuse)",
            _polygon_kernel,
            inputs=(*_POLYGON_INPUTS, _RADIANCE),
            quantity="light_irradiance",
            formula="E = L·max(−½ Σᵢ Θᵢ n·Γᵢ, 0) (corners counter-clockwise), edges clipped to the horizon",
            source="Lambert's polygon formula (Arvo 1994 eq. 9) = LTC with M = I (Heitz et al. 2016)",
            description="Exact irradiance of a uniform rectangle light: LTC for a diffuse BRDF.",
        ),
        Method(
            "disc",
            "LTC disc (diffuse)",
            _disc_kernel,
            inputs=(*_DISC_INPUTS, _RADIANCE),
            quantity="light_irradiance",
            formula="E = L·n·F, F = −πR²(2h·o + G·m)/(S(S + A)); across the horizon the cap of |F| (Snyder)",
            source="Arvo 1994 eq. 9 on the rim in closed form (Howell's catalogue, element to disc) = "
            "Heitz & Hill 2017's LTC disc with M = I; horizon: their clipped-sphere table (Snyder 1996)",
            description="A uniform disc light: exact wholly above the horizon, the sphere cap across it.",
        ),
        Method(
            "tube",
            "Tube as a line (Karis)",
            _tube_kernel,
            inputs=(*_TUBE_INPUTS, _RADIANCE),
            quantity="light_irradiance",
            formula="E = 2rL·ℓ·max((n·L̂0 + n·L̂1)/2 · 2/(|L0||L1| + L0·L1), 0)",
            source="Karis 2013, Real Shading in Unreal Engine 4, tube lights (line irradiance, Picott 1992)",
            description="A cylinder light as a segment of side-on intensity 2rL per length: thin, side-on.",
        ),
        Method(
            "spot-linear",
            "Spot, Mitsuba's linear profile",
            _spot_linear_kernel,
            inputs=_SPOT_INPUTS,
            quantity="light_irradiance",
            formula="E = I₀·clamp((φ_c − φ)/(φ_c − φ_b), 0, 1)·max(cos θ, 0)/d²",
            source=f"Mitsuba 3 spot.cpp falloff_curve ({_SPOT_SOURCE})",
            description="Mitsuba's own spot profile, linear in the angle: the exact row for its spot.",
        ),
        Method(
            "spot-smoothstep",
            "Spot, smoothstep cone",
            _spot_smoothstep_kernel,
            inputs=_SPOT_INPUTS,
            quantity="light_irradiance",
            formula="E = I₀·smoothstep(cos φ_c, cos φ_b, cos φ)·max(cos θ, 0)/d²",
            source="three.js getSpotAttenuation (smoothstep in the cosine)",
            description="The engines' smooth cone, Hermite in cos φ between the two cone angles.",
        ),
        Method(
            "spot-squared",
            "Spot, squared linear-in-cosine",
            _spot_squared_kernel,
            inputs=_SPOT_INPUTS,
            quantity="light_irradiance",
            formula="E = I₀·saturate((cos φ − cos φ_c)/(cos φ_b − cos φ_c))²·max(cos θ, 0)/d²",
            source="Karis 2013 / UE4 SpotAttenuation; Lagarde & de Rousiers 2014 getAngleAtt",
            description="Unreal's and Frostbite's cone: the linear ramp in cos φ, squared.",
        ),
    ]
)
"""The light models (module docstring); part of `rtfit.realtime.diffuse.METHODS`."""
