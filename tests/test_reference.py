"""The ground truth is itself checked: against independent quadrature, closed forms, the white
furnace, convergence with spp, and the cache's resume semantics."""

import dataclasses
import math

import numpy as np
import pytest
from scipy import integrate

from rtfit.reference import (
    ReferenceCache,
    ReferenceRequest,
    irradiance_pass,
    load_mitsuba_scene,
    radiance_pass,
    render_gbuffer,
)
from rtfit.scenes.model import ConstantEnv, Diffuse, ReferenceSettings, Sphere

from .conftest import sphere_scene


def cap_irradiance_quadrature(theta: float, alpha: float, radiance: float = 1.0) -> float:
    """∫ over a cap of angular radius α around a direction at angle θ from n of L·max(n·ω, 0) dω
    (independent of rtfit: plain 2-D quadrature in the cap's own polar coordinates)."""

    def f(phi, psi):
        c = math.cos(psi) * math.cos(theta) + math.sin(psi) * math.cos(phi) * math.sin(theta)
        return max(c, 0.0) * math.sin(psi)

    val, _ = integrate.dblquad(f, 0.0, alpha, 0.0, 2 * math.pi, epsabs=1e-12, epsrel=1e-10)
    return radiance * val


def test_sphere_light_probes_match_quadrature(mi):
    alpha_deg, dist = 5.0, 20.0
    scene = sphere_scene(alpha_deg=alpha_deg, distance=dist)
    light = scene.lights[0]
    thetas = np.radians([0.0, 60.0, 85.0, 90.0, 93.0, 95.0, 120.0])
    normals = np.stack([np.cos(thetas), -np.sin(thetas), 0 * thetas], -1)
    points = normals.copy()  # on the unit sphere, so the sphere's own horizon clips the light
    _, ms = load_mitsuba_scene(scene)
    spp = 16384
    r = irradiance_pass(mi, ms, points, normals, spp, seed=3)
    _assert_the_caps_light(r, spp, light, points, normals)


def _assert_the_caps_light(r, spp: int, light, points, normals) -> None:
    """Each probe's red irradiance in ``r`` (a pass of ``spp`` samples) is the quadrature of ``light``'s cap
    seen from it (`cap_irradiance_quadrature`), within 4.5 standard errors; exactly 0 where the cap is
    below the probe's horizon."""
    for k in range(len(points)):
        d = np.asarray(light.center) - points[k]
        alpha = math.asin(light.radius / np.linalg.norm(d))
        th = math.acos(np.clip(np.dot(normals[k], d / np.linalg.norm(d)), -1, 1))
        exact = cap_irradiance_quadrature(th, alpha, light.radiance[0])
        se = math.sqrt(r.var[k, 0] / spp)
        if exact == 0.0:
            assert r.mean[k, 0] == 0.0, (k, r.mean[k, 0])
        else:
            assert abs(r.mean[k, 0] - exact) < 4.5 * se + 1e-6 * exact, (k, r.mean[k, 0], exact, se)


def test_probes_on_a_sphere_lights_own_surface_see_only_the_other_lights(mi):
    """A probe on a sphere light's surface, its normal outward (a colour-bleeding ray's hit on a lamp): the
    lamp, convex, sends it nothing, and an emitter sample that picks the lamp has no direction (pdf 0, its
    direction 0/0: the Veach MIS scene's NaN before `direct_irradiance` masked it); the other lamp's light
    is the cap quadrature's, within 4.5 standard errors."""
    from .conftest import SphereLight

    a = SphereLight(center=(0.0, 0.0, 5.0), radius=1.0, radiance=(3.0,) * 3)
    b = SphereLight(center=(4.0, 0.0, 5.0), radius=0.5, radiance=(2.0,) * 3)  # (the ball at 0 hides neither)
    scene = sphere_scene(lights=(a, b))
    thetas = np.radians([0.0, 40.0, 85.0, 90.0, 135.0, 180.0])  # from +x: facing b … past its horizon
    normals = np.stack([np.cos(thetas), 0 * thetas, np.sin(thetas)], -1)
    points = np.asarray(a.center) + a.radius * normals
    _, ms = load_mitsuba_scene(scene)
    spp = 16384
    r = irradiance_pass(mi, ms, points, normals, spp, seed=5)
    assert np.all(np.isfinite(r.mean)) and np.all(np.isfinite(r.var))
    _assert_the_caps_light(r, spp, b, points, normals)


def test_image_matches_closed_form_within_noise(mi):
    """Point-sampled reference vs the exact irradiance at the same pixel centres: unit-spread z-scores."""
    from rtfit.realtime.diffuse import sphere_light_geometry, sphere_light_irradiance

    scene = sphere_scene(alpha_deg=10.0, res=48)
    light = scene.lights[0]
    _, ms = load_mitsuba_scene(scene)
    spp = 1024
    r = radiance_pass(mi, ms, spp, seed=11)
    gb = render_gbuffer(scene)
    m = gb.mask & ~gb.emitter
    cos_t, a = sphere_light_geometry(
        gb.position[m].astype(np.float64),
        gb.normal[m].astype(np.float64),
        np.asarray(light.center),
        light.radius,
    )
    exact = np.asarray(sphere_light_irradiance(cos_t, a, light.radiance[0])) / math.pi
    se = np.sqrt(r.var[m][:, 0] / spp)
    lit = se > 0
    z = (r.mean[m][:, 0][lit] - exact[lit]) / se[lit]
    assert lit.sum() > 400
    assert abs(np.std(z) - 1.0) < 0.1
    assert abs(np.mean(z)) < 4 / math.sqrt(lit.sum())
    # Pixels with zero variance got no light sample at all: fully shadowed, or so close to the lower
    # horizon boundary that a hit is unlikely in 1024 samples (exact radiance < 1e-3 of the peak).
    assert np.all(exact[~lit] < 1e-3) and np.all(r.mean[m][:, 0][~lit] == 0.0)


@pytest.mark.parametrize("integrator_transport,shapes_extra", [("global", ()), ("direct", ())])
def test_white_furnace(mi, integrator_transport, shapes_extra):
    """Uniform environment of radiance 1 on a Lambertian sphere of albedo ρ: radiance is exactly ρ."""
    rho = 0.8
    scene = sphere_scene(
        lights=(ConstantEnv((1.0, 1.0, 1.0)),), transport=integrator_transport, reflectance=rho, res=24
    )
    _, ms = load_mitsuba_scene(scene)
    spp = 256
    r = radiance_pass(mi, ms, spp, seed=5)
    gb = render_gbuffer(scene)
    vals = r.mean[gb.mask]
    se = np.sqrt(r.var[gb.mask] / spp)
    z = (vals - rho) / np.maximum(se, 1e-12)
    assert np.all(np.abs(z) < 5.5)
    se_of_mean = np.sqrt(np.sum(se**2)) / se.size  # independent pixels
    assert abs(vals.mean() - rho) < 4 * se_of_mean
    np.testing.assert_allclose(r.mean[~gb.mask], 1.0, rtol=1e-6)  # background: the environment itself


def test_white_furnace_with_path_integrator(mi):
    """Forcing the path integrator (two spheres far apart, albedo ρ) keeps the furnace exact: the mean
    over the image of the near sphere approaches ρ·(1 + small interreflection), bounded by ρ/(1-ρ·f)."""
    rho = 0.5
    shapes = (Sphere((0, 0, 0), 1.0, Diffuse((rho,) * 3)), Sphere((0, 1000, 0), 1.0, Diffuse((rho,) * 3)))
    scene = sphere_scene(lights=(ConstantEnv((1.0, 1.0, 1.0)),), transport="global", shapes=shapes, res=24)
    from rtfit.reference import choose_integrator

    assert choose_integrator(scene).type == "path"
    _, ms = load_mitsuba_scene(scene)
    r = radiance_pass(mi, ms, 256, seed=6)
    gb = render_gbuffer(scene)
    # The far sphere subtends ~π·1e-6 sr: its interreflection changes the radiance by < 1e-6,
    # far below the noise; the rest is the furnace identity.
    se = np.sqrt(r.var[gb.mask] / 256)
    assert abs(r.mean[gb.mask].mean() - rho) < 4 * np.sqrt(np.sum(se**2)) / se.size + 1e-6


def test_noise_falls_as_one_over_sqrt_spp(mi):
    scene = sphere_scene(alpha_deg=10.0, res=24)
    _, ms = load_mitsuba_scene(scene)
    lo = radiance_pass(mi, ms, 64, seed=1)
    hi = radiance_pass(mi, ms, 1024, seed=2)
    m = (lo.var[..., 0] > 0) & (hi.var[..., 0] > 0)
    ratio = np.mean(np.sqrt(lo.var[m, 0] / 64)) / np.mean(np.sqrt(hi.var[m, 0] / 1024))
    assert 3.6 < ratio < 4.4  # sqrt(1024/64) = 4


def test_probe_transports_agree_without_occluders(mi):
    scene = sphere_scene(lights=(ConstantEnv((0.5, 0.5, 0.5)),), shapes=())
    _, ms = load_mitsuba_scene(scene)
    p = np.zeros((1, 3))
    n = np.array([[0.0, 0.0, 1.0]])
    for transport in ("direct", "global"):
        r = irradiance_pass(mi, ms, p, n, 4096, seed=2, transport=transport)
        assert abs(r.mean[0, 0] - 0.5 * math.pi) < 4 * math.sqrt(r.var[0, 0] / 4096) + 1e-5


def test_cache_resumes_and_extends(mi, tmp_path):
    scene = sphere_scene(alpha_deg=10.0, res=16)
    cache = ReferenceCache(tmp_path)
    req = ReferenceRequest(scene=scene, spp=256, pass_spp=64, seed=9)
    first = cache.get(req)
    assert (first.passes, first.passes_rendered, first.spp) == (4, 4, 256)
    again = cache.get(req)
    assert again.passes_rendered == 0
    np.testing.assert_array_equal(again.mean, first.mean)
    # Interrupted run: pass 2 never finished (its sidecar is missing). Only it is rendered again,
    # and the result equals the uninterrupted one (same seeds).
    folder = tmp_path / first.key[:2] / first.key
    (folder / "pass-00002.json").unlink()
    resumed = cache.get(req)
    assert resumed.passes_rendered == 1
    np.testing.assert_allclose(resumed.mean, first.mean, rtol=1e-6, atol=1e-9)
    # More samples extend the same entry.
    more = cache.get(dataclasses.replace(req, spp=512))
    assert (more.key, more.passes, more.passes_rendered) == (first.key, 8, 4)
    assert np.mean(more.stderr[more.stderr > 0]) < np.mean(first.stderr[first.stderr > 0])
    # Nothing half-written is left behind.
    assert not list(folder.glob("*.tmp")) and not list(folder.glob(".*"))


def test_cache_key_tracks_physics_not_labels(mi, tmp_path):
    scene = sphere_scene(alpha_deg=10.0, res=16)
    base = ReferenceRequest(scene=scene, spp=64)
    assert ReferenceRequest(scene=dataclasses.replace(scene, name="other"), spp=64).key() == base.key()
    assert ReferenceRequest(scene=sphere_scene(alpha_deg=11.0, res=16), spp=64).key() != base.key()
    assert dataclasses.replace(base, seed=1).key() != base.key()
    assert dataclasses.replace(base, spp=128).key() == base.key()  # spp: passes inside one entry
    assert dataclasses.replace(base, variant="scalar_rgb").key() != base.key()
    direct = dataclasses.replace(scene, reference=ReferenceSettings("global"))
    assert ReferenceRequest(scene=direct, spp=64).key() != base.key()


def test_scalar_variant_agrees_with_llvm(mi):
    import mitsuba

    scene = sphere_scene(alpha_deg=20.0, res=4)
    _, ms = load_mitsuba_scene(scene, "llvm_ad_rgb")
    llvm = radiance_pass(mi, ms, 4096, seed=1)
    try:
        smi, sms = load_mitsuba_scene(scene, "scalar_rgb")
        scalar = radiance_pass(smi, sms, 64, seed=1)
        gb = render_gbuffer(scene, "scalar_rgb")
    finally:
        mitsuba.set_variant("llvm_ad_rgb")
    se = np.sqrt(scalar.var / 64 + llvm.var / 4096)
    ok = se > 0
    assert np.all(np.abs(scalar.mean - llvm.mean)[ok] < 5 * se[ok])
    assert gb.mask.sum() > 0


def test_bad_requests_are_clear():
    scene = sphere_scene()
    with pytest.raises(ValueError, match="spp"):
        ReferenceRequest(scene=scene, spp=1)
    with pytest.raises(ValueError, match="quantity"):
        ReferenceRequest(scene=scene, spp=64, quantity="albedo")
    with pytest.raises(ValueError, match="unit length"):
        ReferenceRequest(
            scene=scene, spp=64, quantity="irradiance", points=np.zeros((2, 3)), normals=np.ones((2, 3))
        )


def test_gbuffer_points_are_the_sphere_hits_with_unit_normals():
    """A sphere's first hits: every point lies on the sphere and its normal is the radial direction
    (closed form), unit in float64; a zero normal stays zero rather than NaN."""
    from rtfit.reference import gbuffer_points

    scene = sphere_scene(res=16)
    gb = render_gbuffer(scene, "llvm_ad_rgb")
    points, normals = gbuffer_points(gb)
    assert points.dtype == normals.dtype == np.float64 and len(points) == gb.mask.sum() > 0
    sphere = next(s for s in scene.shapes if isinstance(s, Sphere))
    radial = points - np.asarray(sphere.center)
    r = np.linalg.norm(radial, axis=1)
    np.testing.assert_allclose(r, sphere.radius, rtol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(normals, radial / r[:, None], atol=1e-3)
    flat = dataclasses.replace(gb, normal=np.zeros_like(gb.normal))
    assert np.all(gbuffer_points(flat)[1] == 0.0)
