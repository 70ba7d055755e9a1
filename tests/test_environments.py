"""rtfit.reference.environments: lat-long frame against Mitsuba itself, quadrature against Mitsuba and
closed forms, probes, sunsky bake, and a tiny end-to-end run of the irradiance-bases experiment."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.realtime import irradiance_bases as ir
from rtfit.reference import environments as envs


@pytest.fixture(scope="module")
def mi():
    from rtfit.reference import use_variant

    return use_variant("llvm_ad_rgb")


def _mitsuba_env(mi, img):
    from rtfit.reference.build import affine, rotation_matrix

    m = affine(rotation_matrix((1, 0, 0), 90.0), (0, 0, 0))  # the builder's +Y → +Z rotation
    return mi.load_dict(
        {
            "type": "envmap",
            "bitmap": mi.Bitmap(np.asarray(img, np.float32)),
            "to_world": mi.ScalarTransform4f(m.tolist()),
        }
    )


def _eval(mi, emitter, d):
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(np.ascontiguousarray(-d.T, dtype=np.float32))
    return np.array(emitter.eval(si)).T


def test_one_bright_texel_lands_where_expected(mi):
    h, w = 8, 16
    img = np.zeros((h, w, 3), np.float32)
    j, i = 3, 5
    img[j, i] = 1.0
    em = _mitsuba_env(mi, img)
    d = envs.node_directions(h, w)[j, i]
    assert _eval(mi, em, d[None])[0, 0] == pytest.approx(1.0, abs=1e-5)
    # the realtime side's frame is the same
    np.testing.assert_allclose(ir.latlong_directions((i + 0.5) / w, j / (h - 1)), d, atol=1e-12)
    # bilinear between nodes, as envs.bilinear models it, on random directions
    rng = np.random.default_rng(0)
    img = rng.uniform(0.1, 2.0, (h, w, 3)).astype(np.float32)
    u, v = rng.uniform(0, 1, 200), rng.uniform(0.02, 0.98, 200)
    got = _eval(mi, _mitsuba_env(mi, img), envs.uv_to_direction(u, v))
    np.testing.assert_allclose(got, envs.bilinear(img.astype(np.float64), u, v), rtol=2e-4)


def test_furnace_and_disc_closed_forms():
    n = ir.fibonacci_sphere(64)
    np.testing.assert_allclose(envs.irradiance_quadrature(envs.constant_environment(0.7), n), 0.7 * math.pi)
    img = np.full((32, 64, 3), 0.7, np.float32)
    e = envs.irradiance_quadrature(envs.map_environment("c", "c", "map", img), n, 4)
    np.testing.assert_allclose(e, 0.7 * math.pi, rtol=2e-3)
    from rtfit.realtime.diffuse import sphere_light_irradiance

    sun = envs.sun_environment(15.0, 30.0)
    a = math.radians(15.0)
    ct = np.clip(n @ np.array(sun.sun.direction), -1, 1)
    want = np.asarray(
        sphere_light_irradiance(ct, np.full_like(ct, a), math.pi / (math.pi * math.sin(a) ** 2))
    )
    np.testing.assert_allclose(envs.irradiance_quadrature(sun, n)[:, 0], want, atol=2e-5)


def test_quadrature_agrees_with_mitsuba_irradiance(mi, tmp_path):
    import dataclasses

    from rtfit.reference import ReferenceCache, ReferenceRequest
    from rtfit.scenes import EnvMap, library_path, load_scene

    env = envs.map_environment("studio", "studio", "studio", envs.studio_map(16, 32))
    path = envs.write_map_exr(env.radiance_map, tmp_path / "studio.exr")
    base = load_scene(library_path("irradiance_sphere"))  # the white unit sphere, its light swapped
    cam = dataclasses.replace(base.camera, width=8, height=8)
    scene = dataclasses.replace(base, camera=cam, lights=(EnvMap(file=str(path)),))
    n = ir.fibonacci_sphere(96).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ref = ReferenceCache(tmp_path / "cache").get(
        ReferenceRequest(scene=scene, spp=4096, pass_spp=1024, quantity="irradiance", points=n, normals=n)
    )
    quad = envs.irradiance_quadrature(env, n, 4)
    z = (quad - ref.mean) / ref.sigma()
    assert abs(np.median(z)) < 0.3
    assert 0.7 < 1.4826 * np.median(np.abs(z - np.median(z))) < 1.3
    assert np.mean(np.abs(z) > 4) < 0.02


@pytest.mark.skipif(
    not (envs.probe_available("grace") and envs.probe_available("uffizi")),
    reason="measured probes not found (../shared/probes or $RTFIT_PROBE_DIR)",
)
def test_probes_load_with_sky_up():
    for name in ("grace", "uffizi"):
        env = envs.probe_environment(name, 32)
        img = env.radiance_map
        assert img.shape == (32, 64, 3) and np.all(np.isfinite(img)) and img.min() >= 0
        assert img[:16].mean() > img[16:].mean()  # the upper hemisphere (sky, windows, lamps) is brighter


def test_probe_projection_conventions():
    # probulator: u = 0.5 looks along −Z of the file (+Y up), which the +Y → +Z rotation sends to world +Y;
    # u = 0.75 looks along +X
    u, v = envs.probe_source_uv("probulator", np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0, 0, 1.0]]))
    np.testing.assert_allclose(u[:2], [0.5, 0.75], atol=1e-12)
    assert v[2] == pytest.approx(0.0)
    # pbrt-v2 grace: world up (+Z) is the bottom row of the file
    _, v = envs.probe_source_uv("pbrt", np.array([[0, 0, 1.0]]))
    assert v[0] == pytest.approx(1.0)


def test_sunsky_bake(mi):
    env = envs.sunsky_environment(mi, 30.0, 16, 32)
    assert env.sun is not None and env.sun.angular_radius_deg == pytest.approx(0.2679)
    e = np.array(env.sun.irradiance)
    assert np.all(e > 0.1) and np.all(e < 10)  # W/m² per channel, about 1 at 30° (facts note §6)
    assert env.radiance_map.max() < 1e-3 * e.max() / (math.pi * math.radians(0.2679) ** 2)
    with pytest.raises(ValueError, match="elevation"):
        envs.sunsky_environment(mi, -5.0, 8, 16)


def test_all_zero_environment():
    zero = envs.map_environment("zero", "zero", "map", np.zeros((8, 16, 3)))
    n = ir.fibonacci_sphere(32)
    assert np.all(envs.irradiance_quadrature(zero, n) == 0)
    c = ir.sh_project_latlong(zero.radiance_map)
    assert np.all(c == 0) and ir.fit_window_lambda(c) == 0.0
    cube, rms = ir.fit_ambient_cube_nnls(n, envs.irradiance_quadrature(zero, n))
    assert np.all(cube == 0) and np.all(rms == 0)


def test_drjit_quadrature_matches_numpy():
    env = envs.map_environment("s", "s", "studio", envs.studio_map(16, 32))
    n = ir.fibonacci_sphere(40)
    np.testing.assert_allclose(
        envs.irradiance_quadrature(env, n, 2, "llvm"),
        envs.irradiance_quadrature(env, n, 2),
        rtol=1e-12,
        atol=1e-14,
    )


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match="unknown probe"):
        envs.probe_environment("nowhere")
    with pytest.raises(ValueError, match="probe file not found"):
        envs.probe_environment("grace", probe_dir=tmp_path)
    assert not envs.probe_available("grace", tmp_path) and not envs.probe_available("nowhere")
    with pytest.raises(ValueError, match="angular_radius_deg"):
        envs.sun_environment(0.0)
    with pytest.raises(ValueError, match="finite"):
        envs.map_environment("x", "x", "map", np.full((4, 8, 3), np.nan))
