r"""Single scattering of a point or spot light along a ray through a homogeneous medium, by quadrature.

The one quadrature of the quantity the volumetric-lightning and light-cone approximations stand for
(docs/volumetric-lightning.md, docs/light-cones.md), float64 NumPy. Along a ray x(s) = o + s·ω, s ∈ [s₀, S],
inside a homogeneous medium (extinction σ_t, scattering σ_s, 1/m) lit by a light at l of intensity I (W/sr)
with angular profile f (1 for a point light),

    L = σ_s ∫_{s₀}^S I·f(θ(s))·4π p(cos ϑ(s))/(4π)·e^(−σ_t(s − s₀ + r(s)))/r(s)² ds      (W/m²/sr),

r = |x − l|; p the phase function (isotropic: 1/(4π); Henyey–Greenstein with asymmetry g:
(1 − g²)/(4π(1 + g² − 2g cos ϑ)^{3/2}), ϑ the scattering angle between the light's travel (x − l)/r and the
way to the camera −ω, cos ϑ = ω·(l − x)/r); the camera sits at s = 0 and the medium begins at s₀ (0 when the
camera is inside it: the transmittance is that of the medium part of the ray only). The light-to-point
segment is taken to lie inside the medium and unoccluded (e^(−σ_t r)).

Substitution: with c = l − o, c_∥ = c·ω and h the light's distance to the ray's line, s = c_∥ + h·sinh u
gives r = h·cosh u and ds/r² = du/(h·cosh u): the 1/r² peak at the closest approach and the exponential
tail are both smooth in u. The ray is split at breakpoints (0 and S, plus, for a spot light, its crossings
of the two cones θ = θ_b and θ = θ_c where the profile has kinks and jumps) and each piece is summed by
composite Gauss–Legendre (`panels` × 8 nodes).

* `point_single_scattering` (`POINT_PANELS` = 48 panels per piece, the pieces broken at `DECAY_BREAKS`:
  the volumetric-lightning experiment's quadrature) and `point_estimator_variance`;
* `spot_single_scattering` (`PIECE_PANELS` = 16 panels per piece between the cone crossings: the light-cone
  experiment's) and `spot_estimator_variance`, with Mitsuba 3's ``spot`` profile `spot_profile`
  (``falloff_curve`` in ``src/emitters/spot.cpp``): f = 1 for θ ≤ θ_b (``beam_width``),
  (θ_c − θ)/(θ_c − θ_b) — linear in the *angle*, not a smoothstep — for θ_b < θ < θ_c (``cutoff_angle``),
  0 beyond;
* `box_exit`: the distance from a point inside an axis-aligned box to its far wall along each ray.

The variances are the per-sample variance of Mitsuba's ``volpathmis`` estimator of the same L (free-flight
distance sampling, next-event estimation to the delta light, whose MIS weight is 1): the second moment
(σ_s²/σ_t)·I²/(16π²)·∫ f²·e^(−σ_t s − 2σ_t r)/r⁴ ds minus L² (isotropic phase, s₀ = 0), by the same
quadrature.

Checked against mpmath (tests/test_volumetric_lightning.py, tests/test_light_cones.py), against Mitsuba's
``volpathmis`` (the two experiments' reference checks) and against the audit's Monte Carlo estimator with
Mitsuba's own emitter and phase function (tests/test_audit_volumetric_lightning.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = [
    "FOUR_PI",
    "PIECE_PANELS",
    "POINT_PANELS",
    "box_exit",
    "cone_crossings",
    "hg_phase",
    "point_estimator_variance",
    "point_single_scattering",
    "spot_estimator_variance",
    "spot_profile",
    "spot_single_scattering",
]

FOUR_PI = 4.0 * math.pi
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
POINT_PANELS = 48
"""Composite Gauss–Legendre panels (8 nodes each) over a point light's ray (one smooth piece)."""
PIECE_PANELS = 16
"""Composite Gauss–Legendre panels (8 nodes each) per smooth piece of a spot light's ray."""
DECAY_BREAKS = np.array([2.0, 8.0, 32.0])
"""More breakpoints at s₀ + DECAY_BREAKS/σ_t, where e^(−σ_t(s − s₀)) has fallen by e², e⁸, e³² (each piece
gets its panels): an optically thick segment (σ_t·S ≫ 1) is integrated where its light is."""


def hg_phase(cos_theta, g: float) -> np.ndarray:
    """Henyey–Greenstein phase function (1/sr) at the scattering angle's cosine (ϑ = 0: forward); g = 0 is
    isotropic, 1/(4π)."""
    c = np.asarray(cos_theta, np.float64)
    return (1.0 - g * g) / (FOUR_PI * (1.0 + g * g - 2.0 * g * c) ** 1.5)


def box_exit(origin, dirs: np.ndarray, lo, hi) -> np.ndarray:
    """Distance along unit ``dirs`` from ``origin`` (inside the box) to the box's far wall (float64)."""
    o = np.asarray(origin, np.float64)
    with np.errstate(divide="ignore"):
        t_lo = (np.asarray(lo) - o) / dirs
        t_hi = (np.asarray(hi) - o) / dirs
    far = np.where(dirs > 0, t_hi, np.where(dirs < 0, t_lo, np.inf))
    return np.min(far, axis=-1)


def spot_profile(cos_theta, cutoff_rad: float, beam_rad: float) -> np.ndarray:
    """Mitsuba ``spot``'s falloff f(θ) ∈ [0, 1] for cos θ (module docstring): 1 inside the beam width,
    linear in θ down to 0 at the cutoff angle, 0 beyond (``cos θ > cos θ_c`` strictly, as Mitsuba)."""
    c = np.clip(np.asarray(cos_theta, np.float64), -1.0, 1.0)
    ramp = (cutoff_rad - np.arccos(c)) / (cutoff_rad - beam_rad)
    return np.where(c > math.cos(cutoff_rad), np.where(c >= math.cos(beam_rad), 1.0, ramp), 0.0)


def cone_crossings(origin, dirs: np.ndarray, apex, axis, angle_rad: float) -> np.ndarray:
    """The parameters s of the ray's intersections with the infinite double cone of half-angle ``angle_rad``
    about ``axis`` at ``apex`` (N, 2), NaN where there is none (breakpoints only: a spurious crossing of
    the backward nappe merely splits a piece)."""
    a = np.asarray(axis, np.float64)
    w = np.asarray(origin, np.float64) - np.asarray(apex, np.float64)
    k = math.cos(angle_rad) ** 2
    # Solved about the ray's closest approach to the apex, s = s_p + t with m = w + s_p·d ⟂ d: the quadratic
    # qa t² + 2 qb t + qc = 0 then has qb = (d·a)(m·a), qc = (m·a)² − k|m|², and its discriminant is
    # k[(m·a)² + |m|² qa] without the cancellation of terms of size |w|² that qb² − qa qc suffers in s
    # (a ray passing 1e-6 m from the apex 5.7 m away lost 3 digits of its crossings: issue 32).
    da = dirs @ a
    s_p = -(dirs @ w)
    m = w + s_p[..., None] * dirs
    ma = m @ a
    qa = da * da - k
    qb = da * ma
    qc = ma * ma - k * np.sum(m * m, axis=-1)
    disc = k * (ma * ma + np.sum(m * m, axis=-1) * qa)
    sq = np.sqrt(np.maximum(disc, 0.0))
    q = -(qb + np.where(qb >= 0.0, sq, -sq))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(qa != 0.0, q / qa, np.nan)
        r2 = np.where(q != 0.0, qc / q, np.nan)
    out = s_p[..., None] + np.stack([r1, r2], axis=-1)
    return np.where((disc >= 0.0)[..., None], out, np.nan)


# The integrand's weight along the ray besides e^(−σ_t(…))/r^(2p): (point − light (N, 3), r (N,)) → (N,).
Weight = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _u_integral(
    origin, dirs, edges: np.ndarray, light, sigma_t: float, power: int, panels: int, weight: Weight | None,
    start=0.0,
) -> np.ndarray:  # fmt: skip
    """∫ w^p·e^(−σ_t(s − s₀) − p σ_t r)/r^(2p) ds per ray over the pieces between ``edges`` (N, k) (module
    docstring), p = ``power``, w = ``weight`` (1 where None), s₀ = ``start`` (N,) or a float."""
    o = np.asarray(origin, np.float64)
    c = np.asarray(light, np.float64) - o
    c_par = dirs @ c
    h = np.linalg.norm(np.cross(c, dirs), axis=-1)
    # a ray through the light itself: the integral diverges there; keep h finite and positive
    h = np.maximum(h, 1e-12 * max(float(np.max(np.linalg.norm(c, axis=-1), initial=0.0)), 1e-30))
    s0 = np.asarray(start, np.float64)
    if sigma_t > 0.0:  # breaks where the extinction has decayed by e², e⁸, e³²: optically thick segments
        # (σ_t·S ≫ 1, the light behind the camera) left its whole decay inside one or two panels (issue 32)
        with np.errstate(over="ignore"):  # a denormal σ_t (5e-324): breaks at +inf, clipped to the end next
            decay = np.broadcast_to(s0, edges.shape[:-1])[..., None] + DECAY_BREAKS / sigma_t
        decay = np.clip(decay, edges[..., :1], edges[..., -1:])
        edges = np.sort(np.concatenate([edges, decay], axis=-1), axis=-1)
    u_edges = np.arcsinh((edges - c_par[..., None]) / h[..., None])
    frac = np.linspace(0.0, 1.0, panels + 1)
    total = np.zeros_like(h)
    for j in range(edges.shape[-1] - 1):
        u0, u1 = u_edges[..., j], u_edges[..., j + 1]
        if not np.any(u1 > u0):  # an empty piece on every ray (a break clipped to S) adds exactly 0
            continue
        for k in range(panels):
            lo = u0 + (u1 - u0) * frac[k]
            half = 0.5 * (u1 - u0) * (frac[k + 1] - frac[k])
            for x, wgt in zip(_GL_X, _GL_W, strict=True):
                u = lo + half * (x + 1.0)
                s = c_par + h * np.sinh(u)
                r = h * np.cosh(u)
                g = np.exp(-sigma_t * (s - s0) - power * sigma_t * r) / np.cosh(u) ** (2 * power - 1)
                if weight is not None:
                    g = weight(s[..., None] * dirs - c, r) ** power * g
                total += wgt * half * g
    return total / h ** (2 * power - 1)


def _phase_weight(dirs: np.ndarray, g: float) -> Weight | None:
    """4π·p_HG(cos ϑ) as an integrand weight (None: isotropic, weight 1)."""
    if g == 0.0:
        return None
    return lambda point, r: FOUR_PI * hg_phase(-np.sum(point * dirs, axis=-1) / r, g)


def _segment_edges(start, length) -> np.ndarray:
    s = np.asarray(length, np.float64)
    return np.stack([np.broadcast_to(np.asarray(start, np.float64), s.shape), s], axis=-1)


def point_single_scattering(
    origin, dirs: np.ndarray, length, light, intensity: float, sigma_s: float, sigma_t: float, *,
    start=0.0, g: float = 0.0,
) -> np.ndarray:  # fmt: skip
    """L (W/m²/sr) per ray (module docstring): single scattering from an isotropic point light at ``light``
    of intensity I (W/sr) along unit ``dirs`` (N, 3) from ``origin`` over s ∈ [``start``, ``length``] (m; the
    medium's part of the ray), σ_s, σ_t (1/m), Henyey–Greenstein ``g`` (0: isotropic). `POINT_PANELS`
    panels in u over the one piece. Checked against mpmath in tests/test_volumetric_lightning.py."""
    edges = _segment_edges(start, length)
    weight = _phase_weight(dirs, g)
    integral = _u_integral(origin, dirs, edges, light, sigma_t, 1, POINT_PANELS, weight, start)
    return sigma_s / FOUR_PI * intensity * integral


def point_estimator_variance(
    origin, dirs: np.ndarray, length: np.ndarray, light, intensity: float, sigma_s: float, sigma_t: float
) -> np.ndarray:
    """Variance per sample of volpathmis's estimator of `point_single_scattering`'s L (isotropic, s₀ = 0): a
    free-flight distance s ~ σ_t·e^(−σ_t·s) (none beyond S) and next-event estimation to the point light,
    W = (σ_s/σ_t)·I·e^(−σ_t·r)/(4π r²), so E[W²] = (σ_s²/σ_t)·I²/(16π²)·∫₀^S e^(−σ_t·s − 2σ_t·r)/r⁴ ds and
    Var = E[W²] − L². For a point light the phase-function sample cannot hit the light, so volpathmis's MIS
    weight of this NEE is 1."""
    edges = _segment_edges(0.0, length)
    integral = _u_integral(origin, dirs, edges, light, sigma_t, 2, POINT_PANELS, None)
    second = sigma_s**2 / sigma_t * intensity**2 / FOUR_PI**2 * integral
    mean = point_single_scattering(origin, dirs, length, light, intensity, sigma_s, sigma_t)
    return np.maximum(second - mean**2, 0.0)


def _spot_edges(origin, dirs, length, apex, axis, cutoff_rad, beam_rad, start=0.0) -> np.ndarray:
    """Sorted breakpoints (N, 6) of [s₀, S]: s₀, S and the crossings of both cones inside it."""
    s = np.asarray(length, np.float64)
    s0 = np.broadcast_to(np.asarray(start, np.float64), s.shape)
    cuts = np.concatenate(
        [
            cone_crossings(origin, dirs, apex, axis, cutoff_rad),
            cone_crossings(origin, dirs, apex, axis, beam_rad),
        ],
        axis=-1,
    )
    cuts = np.where(np.isfinite(cuts) & (cuts > s0[..., None]) & (cuts < s[..., None]), cuts, s[..., None])
    return np.sort(np.concatenate([s0[..., None], cuts, s[..., None]], axis=-1), axis=-1)


def _spot_weight(dirs, axis, cutoff_rad: float, beam_rad: float, g: float) -> Weight:
    a = np.asarray(axis, np.float64)
    phase = _phase_weight(dirs, g)

    def weight(point: np.ndarray, r: np.ndarray) -> np.ndarray:
        f = spot_profile((point @ a) / r, cutoff_rad, beam_rad)
        return f if phase is None else f * phase(point, r)

    return weight


def spot_single_scattering(
    origin, dirs: np.ndarray, length, apex, axis, cutoff_rad: float, beam_rad: float, intensity: float,
    sigma_s: float, sigma_t: float, *, start=0.0, g: float = 0.0,
) -> np.ndarray:  # fmt: skip
    """L (W/m²/sr) per camera ray (module docstring): ``origin`` (3,), unit ``dirs`` (N, 3), the medium's part
    of each ray [``start``, ``length``] (N,) in m, the spot's ``apex`` and unit ``axis``, its cutoff and beam
    angles (rad), ``intensity`` I (W/sr), σ_s and σ_t (1/m), Henyey–Greenstein ``g`` (0: isotropic). The
    light lies in the medium. `PIECE_PANELS` panels per piece between the cone crossings."""
    edges = _spot_edges(origin, dirs, length, apex, axis, cutoff_rad, beam_rad, start)
    weight = _spot_weight(dirs, axis, cutoff_rad, beam_rad, g)
    integral = _u_integral(origin, dirs, edges, apex, sigma_t, 1, PIECE_PANELS, weight, start)
    return sigma_s / FOUR_PI * intensity * integral


def spot_estimator_variance(
    origin, dirs: np.ndarray, length, apex, axis, cutoff_rad: float, beam_rad: float, intensity: float,
    sigma_s: float, sigma_t: float,
) -> np.ndarray:  # fmt: skip
    """Per-sample variance of volpathmis's single-scattering estimator of `spot_single_scattering`'s L
    (module docstring; isotropic, s₀ = 0); arguments as there."""
    edges = _spot_edges(origin, dirs, length, apex, axis, cutoff_rad, beam_rad)
    weight = _spot_weight(dirs, axis, cutoff_rad, beam_rad, 0.0)
    integral = _u_integral(origin, dirs, edges, apex, sigma_t, 2, PIECE_PANELS, weight)
    second = sigma_s**2 / sigma_t * intensity**2 / FOUR_PI**2 * integral
    mean = spot_single_scattering(origin, dirs, length, apex, axis, cutoff_rad, beam_rad, intensity, sigma_s,
                                  sigma_t)  # fmt: skip
    return np.maximum(second - mean**2, 0.0)
