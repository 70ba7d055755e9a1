"""The Mitsuba atmosphere reference (rtfit.reference.atmosphere) and the nishita-sky experiment."""

import math

import numpy as np
import pytest


@pytest.fixture(scope="module")
def mi():
    from rtfit.reference.variants import use_variant

    return use_variant("llvm_ad_rgb")


def test_single_scattering_reference_matches_independent_quadrature(tmp_path):
    """Mitsuba volpathmis (max_depth 2, Python medium + chromatic phase mixture) vs a float64
    quadrature: z of every pixel and of the sums within noise."""
    from rtfit.reference.atmosphere import (AtmosphereSpec, hemisphere_directions, render_sky,
                                            single_scattering_quadrature)

    spec = AtmosphereSpec(sun_elevation_deg=20.0)
    d, _, _ = hemisphere_directions(6, 3)
    r = render_sky(spec, d, spp=4096, pass_spp=2048, seed=3, variant="llvm_ad_rgb", max_depth=2,
                   cache_dir=tmp_path)
    q = single_scattering_quadrature(spec, d, steps=1500)
    z = (r["mean"] - q) / r["stderr"]
    assert np.abs(z).max() < 4.5
    zs = (r["mean"].sum(axis=(0, 1)) - q.sum(axis=(0, 1))) / np.sqrt((r["stderr"] ** 2).sum(axis=(0, 1)))
    assert np.all(np.abs(zs) < 4)
    # cached: a second call renders nothing and returns the same numbers
    r2 = render_sky(spec, d, spp=4096, pass_spp=2048, seed=3, variant="llvm_ad_rgb", max_depth=2,
                    cache_dir=tmp_path)
    assert np.array_equal(r2["mean"], r["mean"])


def test_phase_mixture_is_normalised_and_sampling_consistent(mi):
    """∫ p_c dω = 1 per channel (MC over uniform directions) and the sampled weight equals
    value/pdf with E[weight] = 1 (the sampled pdf is the mixture's)."""
    import drjit as dr

    from rtfit.reference.atmosphere import AtmosphereSpec, PHASE_PLUGIN, _profile_props, register

    register(mi)
    spec = AtmosphereSpec()
    phase = mi.load_dict({"type": PHASE_PLUGIN, **_profile_props(spec, mi)})
    n = 1 << 18
    rng = np.random.default_rng(1)
    mei = dr.zeros(mi.MediumInteraction3f, n)
    mei.p = mi.Point3f(0.0, 0.0, 6360.5)  # 0.5 km: Mie and Rayleigh both matter
    mei.wi = mi.Vector3f(0.0, 0.0, 1.0)
    u = rng.random((n, 2))
    z = 1 - 2 * u[:, 0]
    s = np.sqrt(1 - z * z)
    wo = mi.Vector3f(s * np.cos(2 * np.pi * u[:, 1]), s * np.sin(2 * np.pi * u[:, 1]), z)
    ctx = mi.PhaseFunctionContext()
    val, pdf = phase.eval_pdf(ctx, mei, wo)
    integ = [4 * math.pi * float(np.mean(np.asarray(val[c]))) for c in range(3)]
    assert integ == pytest.approx([1, 1, 1], rel=0.02)
    assert 4 * math.pi * float(np.mean(np.asarray(pdf))) == pytest.approx(1.0, rel=0.02)
    w_o, weight, pdf_s = phase.sample(ctx, mei, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    for c in range(3):
        assert float(np.mean(np.asarray(weight[c]))) == pytest.approx(1.0, rel=0.02)
    assert np.isfinite(np.asarray(pdf_s)).all()


def test_sunsky_and_spec_validation():
    from rtfit.reference.atmosphere import AtmosphereSpec, hemisphere_directions, sunsky_radiance

    d, _, _ = hemisphere_directions(8, 4)
    s = sunsky_radiance(30.0, d)
    assert np.isfinite(s["sky"]).all() and (s["sky"] > 0).all() and (s["sun_irradiance"] > 0).all()
    with pytest.raises(ValueError, match="sun_elevation_deg"):
        sunsky_radiance(-2.0, d)
    with pytest.raises(ValueError, match="mie_g"):
        AtmosphereSpec(mie_g=1.0)
    with pytest.raises(ValueError, match="viewer_altitude_km"):
        AtmosphereSpec(viewer_altitude_km=-1.0)


def test_library_sky_scenes_load():
    from pathlib import Path

    from rtfit.reference.atmosphere import load_atmosphere_scene

    lib = Path(__file__).resolve().parent.parent / "scenes" / "library"
    files = sorted(lib.glob("sky_*.toml"))
    assert files
    for f in files:
        spec = load_atmosphere_scene(f)
        assert spec.planet_radius_km == 6360.0


def test_tiny_experiment_run(tmp_path, monkeypatch):
    from rtfit.experiments import nishita_sky, nishita_sky_report
    from rtfit.experiments.registry import get_experiment
    from rtfit.experiments.report import load_results
    from rtfit.experiments.runner import run_experiments

    orig = nishita_sky.configure

    def tiny(quick, spp):
        cfg = orig(True, spp)
        cfg.update(sun_elevations_deg=[30.0], resolution=[16, 8], spp=64, pass_spp=32, quadrature_steps=200,
                   sweep_elevations_deg=[30.0], sweep_layers=[8], sweep_textures=[[32, 16]], sweep_tables=[32],
                   spectral_wavelengths=6, cost_elements=1 << 12,
                   fine=dict(layers=32, width=64, height=32, table_size=64, mapping="sqrt"),
                   fit_texture=[32, 16], altitude_cases=[[30.0, 5000.0]])
        return cfg

    monkeypatch.setattr(nishita_sky, "configure", tiny)
    monkeypatch.setattr(nishita_sky_report, "_figures", lambda *a, **k: [])
    run_experiments([get_experiment("nishita-sky")], tmp_path / "out", quick=True, variant="llvm_ad_rgb", spp=None,
                    seed=0, cache_dir=tmp_path / "cache", executor="inline", workers=None, progress=False)
    res = load_results(tmp_path / "out" / "nishita-sky")
    assert {c["id"] for c in res["cases"]} == {"e30-ss", "e30-ms", "e30-h5000-ss"}
    failed = [c["name"] for c in res["checks"] if not c["passed"]]
    assert not failed, failed
    assert all(f["converged"] for f in res["fits"])
    assert (tmp_path / "out" / "nishita-sky" / "fitted" / "nishita_artist_params.json").is_file()
