r"""Exact single scattering of a spot light in a homogeneous medium, by quadrature (float64 NumPy).

The quantity the light-cone approximations stand for (docs/light-cones.md): along a camera ray
x(s) = o + s·ω, s ∈ [0, S], inside a homogeneous medium (extinction σ_t, scattering σ_s, isotropic phase),
lit by a spot light at P with unit axis a,

    L = σ_s/(4π) ∫₀^S I·f(θ(s))·e^(−σ_t(s + r(s)))/r(s)² ds      (W/m²/sr),

r = |x − P|, cos θ = (x − P)·a/r, and f Mitsuba 3's ``spot`` profile (``falloff_curve`` in
``src/emitters/spot.cpp``): f = 1 for θ ≤ θ_b (``beam_width``), (θ_c − θ)/(θ_c − θ_b) — linear in the
*angle*, not a smoothstep — for θ_b < θ < θ_c (``cutoff_angle``), 0 beyond. The integrand is smooth
except where the ray crosses the two cones θ = θ_b and θ = θ_c (kinks and jumps of f) and near the ray's
closest approach h to P (the 1/r² peak). `spot_single_scattering` therefore splits [0, S] at the ray's
intersections with both cones, substitutes s = c_∥ + h·sinh u on each piece (r = h·cosh u,
ds/r² = du/(h cosh u): the peak and the exponential tail are smooth in u, as in the volumetric-lightning
reference) and sums composite Gauss–Legendre panels per piece. Checked against mpmath, against the
volumetric-lightning point-light quadrature inside a wide beam, and against §1's closed form over the
chord for a hard-edged beam without extinction (tests/test_light_cones.py).

`spot_estimator_variance` is the per-sample variance of Mitsuba's ``volpathmis`` estimator of the same L
(free-flight distance sampling, next-event estimation to the delta light, whose MIS weight is 1): the
second moment (σ_s²/σ_t)·I²/(16π²)·∫ f²·e^(−σ_t s − 2σ_t r)/r⁴ ds minus L², by the same quadrature.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "PIECE_PANELS",
    "cone_crossings",
    "spot_estimator_variance",
    "spot_profile",
    "spot_single_scattering",
]

FOUR_PI = 4.0 * math.pi
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
PIECE_PANELS = 16
"""Composite Gauss–Legendre panels (8 nodes each) per smooth piece of the ray."""


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
    da = dirs @ a
    qa = da * da - k
    qb = da * (w @ a) - k * (dirs @ w)
    qc = (w @ a) ** 2 - k * (w @ w)
    disc = qb * qb - qa * qc
    sq = np.sqrt(np.maximum(disc, 0.0))
    q = -(qb + np.where(qb >= 0.0, sq, -sq))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(qa != 0.0, q / qa, np.nan)
        r2 = np.where(q != 0.0, qc / q, np.nan)
    out = np.stack([r1, r2], axis=-1)
    return np.where((disc >= 0.0)[..., None], out, np.nan)


def _pieces(origin, dirs, length, apex, axis, cutoff_rad, beam_rad) -> np.ndarray:
    """Sorted breakpoints (N, 6) of [0, S]: 0, S and the crossings of both cones inside it."""
    s = np.asarray(length, np.float64)
    cuts = np.concatenate(
        [
            cone_crossings(origin, dirs, apex, axis, cutoff_rad),
            cone_crossings(origin, dirs, apex, axis, beam_rad),
        ],
        axis=-1,
    )
    cuts = np.where(np.isfinite(cuts) & (cuts > 0.0) & (cuts < s[..., None]), cuts, s[..., None])
    return np.sort(np.concatenate([np.zeros_like(s)[..., None], cuts, s[..., None]], axis=-1), axis=-1)


def _spot_integral(origin, dirs, length, apex, axis, cutoff_rad, beam_rad, sigma_t, power) -> np.ndarray:
    """∫₀^S f^p·e^(−σ_t s − p σ_t r)/r^(2p) ds per ray (p = ``power``), piecewise in u (module docstring)."""
    o = np.asarray(origin, np.float64)
    a = np.asarray(axis, np.float64)
    c = np.asarray(apex, np.float64) - o
    c_par = dirs @ c
    h = np.linalg.norm(np.cross(c, dirs), axis=-1)
    h = np.maximum(h, 1e-12 * max(float(np.linalg.norm(c)), 1e-30))
    edges = _pieces(o, dirs, length, apex, axis, cutoff_rad, beam_rad)
    u_edges = np.arcsinh((edges - c_par[..., None]) / h[..., None])
    frac = np.linspace(0.0, 1.0, PIECE_PANELS + 1)
    total = np.zeros_like(h)
    for j in range(edges.shape[-1] - 1):
        u0, u1 = u_edges[..., j], u_edges[..., j + 1]
        for k in range(PIECE_PANELS):
            lo = u0 + (u1 - u0) * frac[k]
            half = 0.5 * (u1 - u0) * (frac[k + 1] - frac[k])
            for x, wgt in zip(_GL_X, _GL_W, strict=True):
                u = lo + half * (x + 1.0)
                s = c_par + h * np.sinh(u)
                r = h * np.cosh(u)
                point = s[..., None] * dirs - c  # x − P
                f = spot_profile((point @ a) / r, cutoff_rad, beam_rad)
                g = f**power * np.exp(-sigma_t * s - power * sigma_t * r) / np.cosh(u) ** (2 * power - 1)
                total += wgt * half * g
    return total / h ** (2 * power - 1)


def spot_single_scattering(
    origin, dirs: np.ndarray, length, apex, axis, cutoff_rad: float, beam_rad: float, intensity: float,
    sigma_s: float, sigma_t: float,
) -> np.ndarray:  # fmt: skip
    """L (W/m²/sr) per camera ray (module docstring): ``origin`` (3,), unit ``dirs`` (N, 3), ray lengths
    ``length`` (N,) in m (the medium's far wall), the spot's ``apex`` and unit ``axis``, its cutoff and beam
    angles (rad), ``intensity`` I (W/sr), σ_s and σ_t (1/m). The whole ray and the light lie in the medium."""
    return (
        sigma_s
        / FOUR_PI
        * intensity
        * _spot_integral(origin, dirs, length, apex, axis, cutoff_rad, beam_rad, sigma_t, 1)
    )


def spot_estimator_variance(
    origin, dirs: np.ndarray, length, apex, axis, cutoff_rad: float, beam_rad: float, intensity: float,
    sigma_s: float, sigma_t: float,
) -> np.ndarray:  # fmt: skip
    """Per-sample variance of volpathmis's single-scattering estimator of `spot_single_scattering`'s L
    (module docstring); arguments as there."""
    args = (origin, dirs, length, apex, axis, cutoff_rad, beam_rad)
    second = sigma_s**2 / sigma_t * intensity**2 / FOUR_PI**2 * _spot_integral(*args, sigma_t, 2)
    mean = spot_single_scattering(*args, intensity, sigma_s, sigma_t)
    return np.maximum(second - mean**2, 0.0)
