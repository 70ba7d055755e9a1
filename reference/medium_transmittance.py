r"""Transmittance of one Mitsuba medium along rays, by ratio tracking (the audit's fog reference).

For a ray x(s) = o + s·d (unit d) and a segment [0, D] (D = +∞ for a ray that leaves the scene), the
transmittance of a medium with extinction σt(x) is

    T = exp(−∫₀ᴰ σt(x(s)) ds)  ∈ [0, 1]   (dimensionless; σt in 1/scene unit, s in scene units).

Ratio tracking (Novák, Selle & Jarosz 2014, "Residual ratio tracking for estimating attenuation in
participating media", §3) samples tentative collisions with the medium's majorant σ̄ (Mitsuba's
``Medium.sample_interaction``: free-flight distances −ln(1 − u)/σ̄ inside the medium's own bounding region,
``intersect_aabb``, clipped to the segment) and multiplies the weight by the null-collision probability
1 − σt(x_k)/σ̄ = σn(x_k)/σ̄ at every tentative collision x_k until the segment ends. Its expectation is T
exactly (unbiased for any majorant σ̄ ≥ σt, which Mitsuba's ``get_majorant`` guarantees), and each sample lies
in [0, 1]. The density is the medium's own ``get_scattering_coefficients`` — rtfit's exponential-fog medium
(`rtfit.reference.height_fog`) evaluates b·exp(−c·h) analytically — so this estimator shares no formula with
the closed form of the real-time optical depth it checks.

Grey extinction is assumed (channel 0 of σt/σ̄; rtfit's fog media are grey). Every pass runs at most
``max_steps`` tracking steps; a lane still active then is a one-line RuntimeError (a majorant too large for
the segment), never a silent truncation.
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np

from .estimators import PassResult, chunk_ranges, mean_var, sub_seed

__all__ = ["MAX_STEPS", "transmittance_pass"]

MAX_STEPS = 100_000
"""Bound on the tracking steps of one pass (expected steps per ray: σ̄ × its length in the region)."""


def transmittance_pass(
    mi, medium, origin, directions, max_distance, spp: int, seed: int, max_steps: int = MAX_STEPS
) -> PassResult:
    """One pass of ``spp`` ratio-tracking samples of the transmittance of ``medium`` (a loaded Mitsuba
    medium) along rays from ``origin`` (3,) in unit ``directions`` (N, 3) over [0, ``max_distance``] (N,;
    +inf allowed). Returns a `PassResult` with mean and variance (N, 3): the grey T in each channel."""
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    dist = np.asarray(max_distance, np.float64).reshape(-1)
    n = len(d)
    t0 = time.perf_counter()
    s = np.empty((n, 3))
    q = np.empty((n, 3))
    o = [float(x) for x in origin]
    dx, dy, dz = (mi.Float(d[:, k].astype(np.float32)) for k in range(3))
    far = mi.Float(np.where(np.isfinite(dist), dist, np.finfo(np.float32).max).astype(np.float32))
    for k, (a, b) in enumerate(chunk_ranges(n, spp)):
        m = (b - a) * spp
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(sub_seed(seed, "transmittance", k), m)
        idx = dr.arange(mi.UInt32, m) // spp + a
        direction = mi.Vector3f(
            dr.gather(mi.Float, dx, idx), dr.gather(mi.Float, dy, idx), dr.gather(mi.Float, dz, idx)
        )
        ray = mi.Ray3f(mi.Point3f(*o), dr.normalize(direction))
        ray.maxt = dr.gather(mi.Float, far, idx)
        weight = dr.full(mi.Float, 1.0, m)
        active = dr.full(mi.Bool, True, m)
        for _step in range(max_steps):
            mei = medium.sample_interaction(ray, sampler.next_1d(active), 0, active)
            hit = active & mei.is_valid() & (mei.t < ray.maxt)
            _sigma_s, sigma_n, _sigma_t = medium.get_scattering_coefficients(mei, hit)
            majorant = medium.get_majorant(mei, hit)
            ratio = dr.select(majorant[0] > 0, sigma_n[0] / majorant[0], 0.0)
            weight = dr.select(hit, weight * dr.clip(ratio, 0.0, 1.0), weight)
            ray.o = dr.select(hit, mei.p, ray.o)
            ray.maxt = dr.select(hit, ray.maxt - mei.t, ray.maxt)
            active = hit
            dr.eval(weight, ray.o, ray.maxt, active)
            if not dr.any(active):
                break
        else:
            raise RuntimeError(
                f"transmittance_pass: rays still inside the medium after {max_steps} tracking steps "
                "(majorant × segment length too large)"
            )
        w = np.asarray(weight, np.float64).reshape(b - a, spp)
        s[a:b] = w.sum(axis=1)[:, None]
        q[a:b] = (w * w).sum(axis=1)[:, None]
    mean, var = mean_var(s, q, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
