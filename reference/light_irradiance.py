"""One light's direct irradiance at given surface points: unshadowed, shadowed, and at normal incidence.

The audit's reference for the diffuse family (`rtfit.experiments.audit`): for each visible point x with
unit normal n (the pixel-centre G-buffer) and one emitter of the scene,

    E_u(x, n) = ∫ L_e(x ← ω) max(n·ω, 0) dω            (unshadowed: the light alone, nothing in between)
    E_s(x, n) = ∫ L_e(x ← ω) V(x, ω) max(n·ω, 0) dω    (shadowed: V = 1 where nothing blocks the way)
    E⊥(x)     = E_u(x, t)                               (at normal incidence: t = the unit direction
                                                         from x to the light's centre)

in W/m² per RGB channel, estimated with Mitsuba's own emitter sampling (``Emitter.sample_direction``:
the light's value divided by the pdf of the sampled direction, solid-angle measure) and, for E_s,
Mitsuba's own shadow rays (``Scene.ray_test`` of ``spawn_ray_to``), exactly what Mitsuba's ``direct``
integrator does for the emitter-sampling strategy on a white Lambertian receiver. Emitter sampling alone
is unbiased for every light Mitsuba can sample (delta lights: point, spot, directional — one sample is
exact; area lights: the sampled density covers the whole emitting surface), and the cheapest exact
estimator of one light's direct irradiance: no BSDF sampling, no path continuation. E_u and E_s share their
samples (their difference, the shadow, is precise). E⊥ is an input of the approximations compared with E_u
and E_s, so it is estimated from `PERP_SAMPLES` samples of its own per sample of theirs: its noise is
independent of the reference's (shared noise would let an approximation follow the reference's noise and
read below the noise floor) and smaller.

Each pass returns per point the sample mean and unbiased sample variance of ``spp`` iid samples of the 9
values (E_u, E_s, E⊥; RGB each), float64 sums on the device (`estimators.PassMoments`).
"""

from __future__ import annotations

import time

import drjit as dr

from .estimators import PassMoments, PassResult, check_spp, point_chunks

__all__ = ["CHANNELS", "PERP_SAMPLES", "environment_irradiance_pass", "light_irradiance_pass"]

PERP_SAMPLES = 4
"""Independent emitter samples of E⊥ per sample of E_u/E_s."""

CHANNELS = ("unshadowed", "shadowed", "normal_incidence")
"""The three RGB triples of a pass, in order (columns 0–2, 3–5, 6–8)."""


def light_irradiance_pass(mi, mi_scene, emitter, points, normals, towards, spp: int, seed: int) -> PassResult:
    """E_u, E_s, E⊥ (module docstring) of ``emitter`` at ``points`` (N, 3) with unit ``normals`` (N, 3);
    ``towards`` (N, 3): the unit direction to the light's centre at each point. Mean and variance (N, 9)."""
    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("the light-irradiance pass needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    t0 = time.perf_counter()
    acc = PassMoments(mi, len(points), 9, spp)
    columns = [(mi.Point3f, points), (mi.Vector3f, normals), (mi.Vector3f, towards)]
    for a, sampler, (p, n, t) in point_chunks(mi, spp, seed, columns):
        it = dr.zeros(mi.SurfaceInteraction3f, dr.width(p))
        it.p = p
        it.n = n
        it.sh_frame = mi.Frame3f(n)
        it.wi = mi.Vector3f(0, 0, 1)
        ds, weight = emitter.sample_direction(it, sampler.next_2d(), True)
        ok = ds.pdf > 0.0
        e_u = weight * dr.maximum(dr.dot(ds.d, n), 0.0)
        visible = ok & ~mi_scene.ray_test(it.spawn_ray_to(ds.p), ok)
        e_s = dr.select(visible, e_u, 0.0)
        e_perp = mi.Color3f(0.0)
        for _ in range(PERP_SAMPLES):
            ds2, w2 = emitter.sample_direction(it, sampler.next_2d(), True)
            e_perp += dr.select(ds2.pdf > 0.0, w2 * dr.maximum(dr.dot(ds2.d, t), 0.0), 0.0)
        e_perp = e_perp / PERP_SAMPLES
        values = [dr.select(ok, e_u[c], 0.0) for c in range(3)]
        values += [dr.select(ok, e_s[c], 0.0) for c in range(3)]
        values += [e_perp[c] for c in range(3)]
        acc.add(a, values)
    mean, var = acc.result()
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def environment_irradiance_pass(
    mi, emitter, normals, spp: int, seed: int, *, mi_scene=None, points=None
) -> PassResult:
    """An environment emitter's unoccluded irradiance E(n) = ∫ L(ω) max(n·ω, 0) dω (W/m², RGB) at unit
    ``normals`` (N, 3) — or, given ``mi_scene`` and ``points`` (N, 3), its irradiance **with visibility**
    E(x, n) = ∫ L(ω) V(x, ω) max(n·ω, 0) dω, each strategy's sample multiplied by V from Mitsuba's shadow
    ray (``Scene.ray_test`` of ``spawn_ray`` at x towards ω: the scene's shapes block the sky) — by
    multiple importance sampling of two strategies, one sample of each per sample:
    the emitter's own (``Emitter.sample_direction``, density p_e) and the cosine-weighted hemisphere of n
    (p_c = max(n·ω, 0)/π, radiance from ``Emitter.eval``, p_e from ``Emitter.pdf_direction``), each
    weighted by the balance heuristic: L(ω) max(n·ω, 0)/(p_e(ω) + p_c(ω)) per strategy, summed. Unbiased
    wherever either density covers the integrand: emitter sampling alone misses radiance its sampling table
    gives density 0 (measured on Mitsuba 3.9's ``sunsky``: the sky just above the horizon, 0.04 W/m² on
    normals facing below it), the cosine strategy covers the whole hemisphere. Mean and variance (N, 3)."""
    check_spp(spp)
    if (mi_scene is None) != (points is None):
        raise ValueError("the occluded environment pass needs both mi_scene and points")
    t0 = time.perf_counter()
    occluded = points is not None
    acc = PassMoments(mi, len(normals), 3, spp)
    columns = [(mi.Vector3f, normals)] + ([(mi.Point3f, points)] if occluded else [])
    for a, sampler, gathered in point_chunks(mi, spp, seed, columns):
        n = gathered[0]
        it = dr.zeros(mi.SurfaceInteraction3f, dr.width(n))
        it.n = n
        it.sh_frame = mi.Frame3f(n)
        it.wi = mi.Vector3f(0, 0, 1)
        if occluded:
            it.p = gathered[1]
        # strategy 1: the emitter's sampling
        ds, weight = emitter.sample_direction(it, sampler.next_2d(), True)
        ok = ds.pdf > 0.0
        if occluded:
            ok = ok & ~mi_scene.ray_test(it.spawn_ray(ds.d), ok)
        cos_e = dr.maximum(dr.dot(ds.d, n), 0.0)
        f_e = weight * ds.pdf * cos_e  # L·cos
        e_part = dr.select(ok, f_e / dr.maximum(ds.pdf + cos_e / dr.pi, 1e-30), 0.0)
        # strategy 2: the cosine-weighted hemisphere
        d = it.sh_frame.to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d()))
        cos_c = dr.maximum(dr.dot(d, n), 0.0)
        if occluded:
            cos_c = dr.select(mi_scene.ray_test(it.spawn_ray(d), cos_c > 0.0), 0.0, cos_c)
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(n))
        si.wi = -d
        radiance = emitter.eval(si)
        ds2 = dr.zeros(mi.DirectionSample3f, dr.width(n))
        ds2.d = d
        pdf_e = emitter.pdf_direction(it, ds2)
        c_part = dr.select(cos_c > 0.0, radiance * cos_c / dr.maximum(pdf_e + cos_c / dr.pi, 1e-30), 0.0)
        total = e_part + c_part
        acc.add(a, [total[c] for c in range(3)])
    mean, var = acc.result()
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
