"""Ground truth of the sdf-occlusion family (Mitsuba ray casts) against closed forms and quadrature,
the sdfgrid geometry, the pass cache, and a tiny ``rtfit run sdf-occlusion``: the engine + the study."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.experiments.sdf_occlusion_scenes import SCENE_NAMES, load_case_scene
from rtfit.experiments.sdf_occlusion_study import CREASE_PROBE_X, crease_ao
from rtfit.realtime.sdf_grid import HalfSpace, Sphere, union_grid

from .conftest import upper_hemisphere_nodes


@pytest.mark.parametrize("phi_deg", [30, 60, 90, 120])
def test_crease_quadrature_closed_form_at_infinite_range(phi_deg):
    phi = math.radians(phi_deg)
    for x in (0.01, 0.3, 2.0):
        assert crease_ao(phi, x, math.inf) == pytest.approx((1 - math.cos(phi)) / 2, abs=1e-9)
    # with a finite range less is occluded, and more so farther from the edge
    assert crease_ao(phi, 0.1, 1.0) > (1 - math.cos(phi)) / 2
    assert crease_ao(phi, 0.4, 1.0) > crease_ao(phi, 0.1, 1.0)


@pytest.fixture(scope="module")
def crease_scene(request):
    from rtfit.reference import load_mitsuba_scene

    sc = load_case_scene("crease_60", 8)
    return load_mitsuba_scene(sc, "llvm_ad_rgb")


def test_mitsuba_ao_in_a_crease_matches_the_wedge_integral(crease_scene):
    from rtfit.reference.occlusion import occlusion_pass

    mi, s = crease_scene
    xs = np.array(CREASE_PROBE_X)
    p = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, 1e-6)])
    n = np.tile([0.0, 0.0, 1.0], (len(xs), 1))
    r = occlusion_pass(mi, s, p, n, 16384, 7, quantity="ao", max_distance=1.0)
    expect = np.array([crease_ao(math.radians(60), x, 1.0) for x in xs])
    z = (r.mean - expect) / np.sqrt(r.var / r.spp)
    assert np.max(np.abs(z)) < 4.0, z
    # sky light: on the floor facing up the upper-hemisphere sky equals the AO at infinite range (−ε)
    r2 = occlusion_pass(mi, s, p, n, 16384, 8, quantity="sky_direct")
    expect2 = (1 - math.cos(math.radians(60))) / 2
    # the arms are finite (2 long, 2 wide): sky seen past their ends can only raise the value
    assert np.all(r2.mean >= expect2 - 4 * np.sqrt(r2.var / r2.spp))


def test_open_sky_and_global_on_an_unoccluded_point(crease_scene):
    from rtfit.reference.occlusion import occlusion_pass

    mi, s = crease_scene
    p = np.array([[0.5, 0.0, 50.0], [0.5, 0.0, 50.0]])  # far above everything
    n = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    r = occlusion_pass(mi, s, p, n, 4096, 1, quantity="sky_direct")
    assert r.mean[0] == 1.0 and r.var[0] == 0.0
    assert abs(r.mean[1] - 0.5) < 4 * math.sqrt(0.25 / 4096)  # vertical: half the cosine lobe sees sky
    g = occlusion_pass(mi, s, p[:1], n[:1], 1024, 2, quantity="sky_global", albedo=0.8)
    assert g.mean[0] == 1.0
    with pytest.raises(ValueError, match="quantity"):
        occlusion_pass(mi, s, p, n, 16, 1, quantity="nope")
    with pytest.raises(ValueError, match="albedo"):
        occlusion_pass(mi, s, p, n, 16, 1, quantity="sky_global", albedo=1.0)


def test_occlusion_pass_normalises_its_normals_and_refuses_degenerate_ones(crease_scene):
    """The pass normalises its normals on the device (float64, then float32): a normal scaled by 2 or 1/8
    (exact in binary) is the same unit normal, so the same seed gives a bit-identical pass; zero, NaN and
    infinite normals (and lengths whose square overflows float64) are refused with one line; probes made
    resident on the device once (`device_probes`) give the same pass."""
    from rtfit.reference.estimators import device_probes
    from rtfit.reference.occlusion import occlusion_pass

    mi, s = crease_scene
    xs = np.array(CREASE_PROBE_X)
    p = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, 1e-6)])
    n = np.column_stack([np.full_like(xs, 0.3), np.zeros_like(xs), np.ones_like(xs)])
    base = occlusion_pass(mi, s, p, n, 64, 3, quantity="ao", max_distance=1.0)
    for scale in (2.0, 0.125):
        again = occlusion_pass(mi, s, p.astype(np.float32), n * scale, 64, 3, quantity="ao", max_distance=1.0)
        np.testing.assert_array_equal(again.mean, base.mean)
        np.testing.assert_array_equal(again.var, base.var)
    for bad in ((0.0, 0.0, 0.0), (np.nan, 0.0, 1.0), (np.inf, 0.0, 1.0), (1e200, 0.0, 0.0)):
        nb = n.copy()
        nb[1] = bad
        with pytest.raises(ValueError, match="normals must be finite and non-zero"):
            occlusion_pass(mi, s, p, nb, 16, 1, quantity="ao")
    with pytest.raises(ValueError, match=r"must both be \(N, 3\)"):
        occlusion_pass(mi, s, p, n[:, :2], 16, 1, quantity="ao")
    # probes uploaded once (as the occlusion cache does for a reference's passes): the same pass, bit for bit
    resident = device_probes(mi, p, n, normalise=True)
    again = occlusion_pass(mi, s, resident, None, 64, 3, quantity="ao", max_distance=1.0)
    np.testing.assert_array_equal(again.mean, base.mean)
    np.testing.assert_array_equal(again.var, base.var)
    with pytest.raises(ValueError, match="normals must be None"):
        occlusion_pass(mi, s, resident, n, 16, 1, quantity="ao")
    with pytest.raises(ValueError, match="not normalised"):
        occlusion_pass(mi, s, device_probes(mi, p, n, normalise=False), None, 16, 1, quantity="ao")


def _sunsky_gauss_legendre(mi, sky, normals, n_mu=160, n_phi=720):
    """Independent quadrature of the sunsky emitter itself over the upper hemisphere (no bake): Gauss–Legendre
    in μ = cos θ ∈ (0, 1) × midpoint rule in φ; luminance irradiance E(n) = ∫ L(ω) max(n·ω, 0) dω."""
    import drjit as dr

    from rtfit.reference.occlusion import LUMINANCE, sunsky_emitter

    d, w = upper_hemisphere_nodes(n_mu, n_phi)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(np.ascontiguousarray(-d.T, dtype=np.float32))
    lum = np.maximum(
        np.array(sunsky_emitter(mi, sky).eval(si), dtype=np.float64).T @ np.asarray(LUMINANCE), 0.0
    )
    return np.array([np.sum(w * lum * np.maximum(d @ n, 0.0)) for n in np.asarray(normals, np.float64)])


def test_sunsky_reference_at_an_unoccluded_point_equals_the_sky_irradiance_quadrature(crease_scene):
    from rtfit.reference.occlusion import (
        SunskySky,
        occlusion_pass,
        sunsky_horizontal_irradiance,
        sunsky_irradiance,
    )

    mi, s = crease_scene
    sky = SunskySky(30.0, 60.0, 3.0)
    sd = sky.sun_direction()
    assert sd[2] == pytest.approx(0.5) and sd[0] == pytest.approx(
        math.cos(math.radians(30)) * math.sin(math.radians(60))
    )
    hs = np.array([sd[0], sd[1], 0.0]) / np.hypot(sd[0], sd[1])
    n = np.array([[0.0, 0.0, 1.0], hs, -hs, [-hs[1], hs[0], 0.0], [0.3, -0.2, 0.93]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    e_gl = _sunsky_gauss_legendre(mi, sky, n)
    # E_h (the normaliser, from the baked map) agrees with the quadrature of the emitter itself
    assert sunsky_horizontal_irradiance(mi, sky) == pytest.approx(e_gl[0], rel=2e-4)
    np.testing.assert_allclose(sunsky_irradiance(mi, sky, n), e_gl, rtol=2e-3)
    # the sky is anisotropic: facing the sun's azimuth sees more than facing away
    assert e_gl[1] > 1.3 * e_gl[2]
    p = np.tile([0.5, 0.0, 50.0], (len(n), 1))  # far above everything: nothing occludes the upper sky
    r = occlusion_pass(mi, s, p, n, 1 << 16, 11, quantity="sunsky_direct", sky=sky)
    z = (r.mean - e_gl / e_gl[0]) / np.sqrt(r.var / r.spp)
    assert np.max(np.abs(z)) < 4.0, z
    g = occlusion_pass(mi, s, p[:1], n[:1], 1 << 16, 12, quantity="sunsky_global", albedo=0.8, sky=sky)
    assert abs(g.mean[0] - 1.0) < 4 * math.sqrt(g.var[0] / g.spp)
    # the constant-sky quantity is unchanged by the sky argument
    c = occlusion_pass(mi, s, p[:1], n[:1], 64, 1, quantity="sky_direct", sky=sky)
    assert c.mean[0] == 1.0
    with pytest.raises(ValueError, match="SunskySky"):
        occlusion_pass(mi, s, p, n, 16, 1, quantity="sunsky_direct", sky={"elevation_deg": 30})


def test_sunsky_sky_validation():
    from rtfit.reference.occlusion import SunskySky

    with pytest.raises(ValueError, match="elevation"):
        SunskySky(elevation_deg=-5.0)
    with pytest.raises(ValueError, match="turbidity"):
        SunskySky(turbidity=20.0)
    with pytest.raises(ValueError, match="finite"):
        SunskySky(azimuth_deg=float("nan"))


def test_sunsky_cache_key_separates_skies(tmp_path, crease_scene):
    from rtfit.reference.occlusion import OcclusionCache, SunskySky

    mi, s = crease_scene
    p = np.array([[0.2, 0.0, 1e-6]])
    n = np.array([[0.0, 0.0, 1.0]])
    c = OcclusionCache(tmp_path)
    a = c.get(
        mi,
        s,
        "geo",
        p,
        n,
        spp=8,
        pass_spp=8,
        seed=3,
        variant="llvm_ad_rgb",
        quantity="sunsky_direct",
        sky=SunskySky(30.0, 60.0),
    )
    b = c.get(
        mi,
        s,
        "geo",
        p,
        n,
        spp=8,
        pass_spp=8,
        seed=3,
        variant="llvm_ad_rgb",
        quantity="sunsky_direct",
        sky=SunskySky(45.0, 60.0),
    )
    assert a.key != b.key and a.to_dict()["sky"]["sun_elevation_deg"] == 30.0


def test_sdfgrid_scene_places_the_surface_where_the_grid_says(crease_scene):
    from rtfit.reference.occlusion import sdfgrid_scene

    mi, _ = crease_scene
    g = union_grid(
        [HalfSpace((0, 0, 0.3), (0, 0, 1)), Sphere((0.5, 0.5, 0.6), 0.2)], (0, 0, 0), 1 / 24, (24, 24, 24)
    )
    s = sdfgrid_scene(mi, g)
    ray = mi.Ray3f(mi.Point3f(0.2, 0.2, 0.95), mi.Vector3f(0, 0, -1))
    si = s.ray_intersect(ray)
    assert float(si.p.z[0]) == pytest.approx(0.3, abs=1e-3)  # plane: trilinear zero set is exact
    ray = mi.Ray3f(mi.Point3f(0.5, 0.5, 0.99), mi.Vector3f(0, 0, -1))
    assert float(s.ray_intersect(ray).p.z[0]) == pytest.approx(0.8, abs=0.5 / 24)  # sphere top within ½ voxel


def test_cache_resumes_identically(tmp_path, crease_scene):
    from rtfit.reference.occlusion import OcclusionCache

    mi, s = crease_scene
    p = np.array([[0.2, 0.0, 1e-6]])
    n = np.array([[0.0, 0.0, 1.0]])
    c = OcclusionCache(tmp_path)
    a = c.get(mi, s, "geo", p, n, spp=64, pass_spp=32, seed=3, variant="llvm_ad_rgb")
    b = c.get(mi, s, "geo", p, n, spp=64, pass_spp=32, seed=3, variant="llvm_ad_rgb")
    assert a.passes == 2 and np.array_equal(a.mean, b.mean) and np.array_equal(a.stderr, b.stderr)


def test_run_sdf_occlusion_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path):
    """``rtfit run sdf-occlusion`` = the engine's audit of the shipped scenes + the study, on the 90° crease
    (12² pixels, 16 spp) as the engine hands it over, with a tiny sweep. Independent values, through the
    study's checks: Mitsuba AO at the crease's floor probes against the wedge integral (`crease_ao`), the
    sunsky reference at an open point against the sky-irradiance quadrature, Evans on an unoccluded plane = 1;
    and the continuous fit never above its grid start."""
    import json

    from rtfit.experiments import audit_ambient_occlusion, sdf_occlusion_study
    from rtfit.experiments.audit_run import audit
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["sdf-occlusion"]
    assert fam.module == ENGINE and fam.scenes == audit_ambient_occlusion.SCENES
    assert fam.study.target is sdf_occlusion_study.study
    assert all((LIBRARY_DIR / s.file).is_file() for s in fam.scenes)
    assert [s.name for s in fam.scenes if s.quick] == [f"sdf_{n}" for n in SCENE_NAMES]
    s = {s.name: s for s in fam.scenes}["sdf_crease_90"]
    assert dict(s.options) == {"ao_distance": 1.0}
    res = audit(LIBRARY_DIR / s.file, ["sdf-occlusion"], spp=16, width=12, height=12, cache=tmp_path / "c",
                tag=("sdf_crease_90-", ""), metrics=("rmse",), **dict(s.options))  # fmt: skip
    (tmp_path / "figures").mkdir()
    ctx = StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "c", (res,))
    tiny = dict(
        targets=["sunsky"], alphas=[0.0], sweep_grids=[24], sweep_n=[1, 2], probe_spp=256, cost_points=4096
    )
    study = sdf_occlusion_study.study(ctx, tiny)
    assert all(c.passed for c in study.checks), [c for c in study.checks if not c.passed]
    names = [c.name for c in study.checks]
    for part in (
        "floor probes of the 90° crease",
        "sunsky one bounce",
        "continuous Evans fit",
        "unoccluded plane",
    ):
        assert any(part in nm for nm in names), (part, names)
    (ao, sun) = study.extra["study_rmse"]
    assert (ao["target"], sun["target"]) == ("ao", "sunsky")
    assert {"evans-fit", "evans-joint", "sdfgrid", "evans-on-sdfgrid", "evans-listing"} <= set(ao["rows"])
    assert {"evans-text", "evans-listing", "evans-fit", "curvature", "cone"} <= set(sun["rows"])
    # the continuous fit has α and base free: never worse than the seed listing (k, B fitted) on its own case
    assert sun["rows"]["evans-fit"]["value"] <= sun["rows"]["evans-listing"]["value"] + 1e-9
    cost = study.extra["kernel_ns_per_pixel"]
    assert set(cost) == {"evans-text", "evans-listing", "evans-fit", "curvature", "cone"}
    assert all(0 < ns < 1e7 for ns in cost.values())
    assert {f.file for f in study.figures} == {"figures/pareto_steps.png", "figures/crease_profile.png"}
    assert all((tmp_path / f.file).is_file() for f in study.figures)
    joint = json.loads((tmp_path / "fitted" / "evans_joint_sunsky.json").read_text())
    assert joint["format"] == "rtfit.fitted/1"
    params = joint["methods"][0]["parameters"]
    for key in ("k", "alpha", "base_voxels", "B", "w2"):
        assert key in params and "stderr" in params[key]
    assert set(joint["methods"][0]["data"]["base_scene_units"]) == {"crease_90"}
