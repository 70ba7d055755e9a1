r"""The sun's transmittance to ground points through a Mitsuba medium, by ratio tracking (the clouds family's
reference).

For ground points pᵢ and one unit direction s towards the sun, T(pᵢ) = exp(−∫₀^∞ σt(pᵢ + t·s) dt) through
the medium's own region (``Medium.intersect_aabb``). This is `rtfit.reference.medium_transmittance`'s
estimator (Novák, Selle & Jarosz 2014, ratio tracking, its majorant choice `MIN_COLLISIONS`,
`VARIANCE_EXPONENT`, `MAX_COLLISIONS` imported from there, unchanged) with one origin **per ray** instead of
one camera origin for all: the sun's rays from the ground are parallel, not concurrent. Added beside that
module rather than into it (session 15: helpers do not restructure shared reference modules); its loop is
the same text and the two should become one when the lead next edits medium_transmittance.

The density is the loaded medium's own ``get_scattering_coefficients`` (a ``gridvolume``: Mitsuba's own
trilinear lookup), so this estimate shares no code with the real-time march it checks. Grey extinction
(channel 0), three independent estimates per point (one per channel) so that their errors are independent;
at most ``max_steps`` tracking steps, a lane still active then is a one-line RuntimeError.
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np

from .estimators import PassResult, chunk_ranges, mean_var, sub_seed
from .medium_transmittance import MAX_COLLISIONS, MAX_STEPS, MIN_COLLISIONS, VARIANCE_EXPONENT

__all__ = ["sun_transmittance_pass"]


def sun_transmittance_pass(mi, medium, points, direction, spp: int, seed: int, max_steps: int = MAX_STEPS):
    """One pass of ``spp`` ratio-tracking samples (×3 channels) of the transmittance of ``medium`` (a loaded
    Mitsuba medium) from each of ``points`` (N, 3) along the unit ``direction`` (3,) towards the sun, over
    the ray's whole stretch in the medium's region. Returns a `PassResult` (mean, variance (N, 3))."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    s = np.asarray(direction, np.float64).reshape(3)
    s = s / np.linalg.norm(s)
    n = len(pts)
    t0 = time.perf_counter()
    sums = np.empty((n, 3))
    squares = np.empty((n, 3))
    px, py, pz = (mi.Float(pts[:, k].astype(np.float32)) for k in range(3))
    lanes = 3 * spp
    for chunk, (a, b) in enumerate(chunk_ranges(n, lanes)):
        m = (b - a) * lanes
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(sub_seed(seed, "sun-transmittance", chunk), m)
        idx = dr.arange(mi.UInt32, m) // lanes + a
        origin = mi.Point3f(
            dr.gather(mi.Float, px, idx), dr.gather(mi.Float, py, idx), dr.gather(mi.Float, pz, idx)
        )
        ray = mi.Ray3f(origin, mi.Vector3f(*[float(x) for x in s]))
        hit_box, t_in, t_out = medium.intersect_aabb(ray)
        t_in = dr.maximum(t_in, 0.0)
        active = hit_box & (t_out > t_in)
        mei = dr.zeros(mi.MediumInteraction3f, m)
        length = dr.maximum(t_out - t_in, 1e-30)
        m_bar = medium.get_majorant(mei, active)[0]
        low_variance = dr.minimum(m_bar * m_bar * length / VARIANCE_EXPONENT, MAX_COLLISIONS / length)
        bar = dr.maximum(dr.maximum(m_bar, MIN_COLLISIONS / length), low_variance)
        weight = dr.full(mi.Float, 1.0, m)
        t = mi.Float(t_in)
        for _step in range(max_steps):
            t = t - dr.log(1.0 - sampler.next_1d(active)) / bar
            active &= t < t_out
            mei.p = ray(t)
            _sigma_s, _sigma_n, sigma_t = medium.get_scattering_coefficients(mei, active)
            weight = dr.select(active, weight * dr.clip(1.0 - sigma_t[0] / bar, 0.0, 1.0), weight)
            sampler.schedule_state()  # else its state stays symbolic: step k's kernel holds all k before it
            dr.eval(weight, t, active)
            if not dr.any(active):
                break
        else:
            raise RuntimeError(
                f"sun_transmittance_pass: rays still inside the medium after {max_steps} tracking steps "
                "(majorant × segment length too large)"
            )
        w = np.asarray(weight, np.float64).reshape(b - a, spp, 3)
        sums[a:b] = w.sum(axis=1)
        squares[a:b] = (w * w).sum(axis=1)
    mean, var = mean_var(sums, squares, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
