r"""Scattered irradiance at points under a participating medium (the layered-materials light-map reference).

For a point x with unit normal n (a surface under a scattering slab), the irradiance arriving from the
hemisphere above it, carried by light the media scatter (any number of scatterings and surface bounces):

    E_s(x) = ∫ L_i(x, ω) (n·ω) dω ≈ π · L(ray from x along ω),  ω ~ cos/π

with L the radiance Mitsuba's ``volpath`` (unbounded depth, Russian roulette) returns along the ray: its
null-BSDF boundaries are passed and their media entered, next-event estimation at every scattering vertex
with the media's transmittance, the diffuse surfaces' bounces. A delta light (directional, spot, point) is
never hit by a ray, so E_s leaves out the light's unscattered beam at x: the caller adds it in closed form
(its transmittance through the slab; experiments/layered_lightmap.py). The ray starts outside every medium
(``medium`` None): x must lie in a vacuum gap under the medium's boundary.
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np

from .estimators import PassMoments, PassResult, as_device_probes, check_spp, point_chunks

__all__ = ["scattered_irradiance_pass"]


def scattered_irradiance_pass(mi, mi_scene, points, normals, spp: int, seed: int) -> PassResult:
    """One pass of ``spp`` samples of E_s (W/m², RGB) at ``points`` (N, 3) for unit ``normals`` (N, 3)
    (module docstring): mean and unbiased variance (N, 3)."""
    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("scattered irradiance needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    t0 = time.perf_counter()
    probes = as_device_probes(mi, np.asarray(points, np.float64), np.asarray(normals, np.float64), True)
    acc = PassMoments(mi, probes.count, 3, spp)
    volpath = mi.load_dict({"type": "volpath", "max_depth": -1})
    columns = [(mi.Point3f, probes.points), (mi.Vector3f, probes.normals)]
    for a, sampler, (p, n) in point_chunks(mi, spp, seed, columns):
        it = dr.zeros(mi.SurfaceInteraction3f)
        it.p, it.n, it.sh_frame = p, n, mi.Frame3f(n)
        d = mi.Frame3f(n).to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        value, _, _ = volpath.sample(mi_scene, sampler, mi.RayDifferential3f(it.spawn_ray(d)), None, True)
        e = value * dr.pi
        acc.add(a, [e[c] for c in range(3)])
    mean, var = acc.result(np.float64)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
