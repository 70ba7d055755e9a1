r"""Total irradiance at surface points: direct (every light, delta lights included) plus indirect, for
``rtfit compare --quantity irradiance`` (issue 36).

    E(x, n) = ∫_{H(n)} L_i(x, ω) (n·ω) dω   (W/m², RGB)

split as E = E_dir + E_ind, one independent sample of each per lane:

* E_dir: `rtfit.reference.estimators.irradiance_pass`'s ``direct`` estimator (Mitsuba's emitter sampling
  with its shadow ray, MIS with cosine sampling of the emitters a ray reaches; delta lights by emitter
  sampling alone);
* E_ind = π × (L_path(y → x) − L_e(y → x)) along a cosine-distributed ray to the first surface y: Mitsuba's
  ``path`` integrator (max_depth −1: every bounce) minus its max_depth 1 (y's own emission, the part E_dir
  already counts), on the same ray — as the ``bounce`` transport does for one bounce.

The ``global`` transport of `irradiance_pass` is the cosine ray alone: it never reaches a point or spot
light, so it misses their direct light; this sum does not.
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np

from .estimators import (
    PassMoments,
    PassResult,
    as_device_probes,
    check_spp,
    irradiance_pass,
    point_chunks,
    sub_seed,
)

__all__ = ["total_irradiance_pass"]


def total_irradiance_pass(
    mi, mi_scene, points: np.ndarray, normals: np.ndarray, spp: int, seed: int
) -> PassResult:
    """One pass of ``spp`` samples of E_dir + E_ind (module docstring) at ``points`` (N, 3) with unit
    ``normals`` (N, 3): mean and variance (N, 3), W/m². The two parts are independent passes (their own
    seeds): their means and variances add."""
    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("irradiance probes need a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    t0 = time.perf_counter()
    probes = as_device_probes(mi, points, normals, normalise=False)
    direct = irradiance_pass(mi, mi_scene, probes, None, spp, sub_seed(seed, "direct", 0), transport="direct")
    acc = PassMoments(mi, probes.count, 3, spp)
    every = mi.load_dict({"type": "path", "max_depth": -1})
    one = mi.load_dict({"type": "path", "max_depth": 1})
    columns = [(mi.Point3f, probes.points), (mi.Vector3f, probes.normals)]
    for a, sampler, (p, n) in point_chunks(mi, spp, sub_seed(seed, "indirect", 0), columns):
        it = dr.zeros(mi.SurfaceInteraction3f)  # the probe: a surface point with normal n
        it.p, it.n, it.sh_frame = p, n, mi.Frame3f(n)
        ray = it.spawn_ray(mi.Frame3f(n).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d())))
        value, _, _ = every.sample(mi_scene, sampler, ray, None, True)
        emitted, _, _ = one.sample(mi_scene, sampler, ray, None, True)
        indirect = (value - emitted) * dr.pi
        acc.add(a, [indirect[c] for c in range(3)])
    mean, var = acc.result(np.float64)
    return PassResult(direct.mean + mean, direct.var + var, spp, seed, time.perf_counter() - t0)
