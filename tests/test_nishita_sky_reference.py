"""The Mitsuba atmosphere reference (rtfit.reference.nishita_sky) and the nishita-sky experiment."""

import dataclasses
import json
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
    from rtfit.reference.nishita_sky import (
        hemisphere_directions,
        library_atmosphere,
        render_sky,
        single_scattering_quadrature,
    )

    spec = library_atmosphere(sun_elevation_deg=20.0)
    d, _, _ = hemisphere_directions(6, 3)
    r = render_sky(
        spec, d, spp=4096, pass_spp=2048, seed=3, variant="llvm_ad_rgb", max_depth=2, cache_dir=tmp_path
    )
    q = single_scattering_quadrature(spec, d, steps=1500)
    z = (r["mean"] - q) / r["stderr"]
    assert np.abs(z).max() < 4.5
    zs = (r["mean"].sum(axis=(0, 1)) - q.sum(axis=(0, 1))) / np.sqrt((r["stderr"] ** 2).sum(axis=(0, 1)))
    assert np.all(np.abs(zs) < 4)
    # cached: a second call renders nothing and returns the same numbers
    r2 = render_sky(
        spec, d, spp=4096, pass_spp=2048, seed=3, variant="llvm_ad_rgb", max_depth=2, cache_dir=tmp_path
    )
    assert np.array_equal(r2["mean"], r["mean"])
    assert list((tmp_path / "sky").glob("*/*/pass-00001.npz"))  # the one pass store (PassEntry)
    # without a store: the same passes rendered again. The per-pixel float64 sums are atomic adds inside the
    # sampling kernel (`estimators.channel_moments`): where a pixel's lanes span two threads' work blocks the
    # order of the additions varies, so a re-render agrees to float64 round-off, not bit for bit (CI saw a
    # difference of this kind once in two runs).
    r3 = render_sky(spec, d, spp=4096, pass_spp=2048, seed=3, variant="llvm_ad_rgb", max_depth=2)
    np.testing.assert_allclose(r3["mean"], r["mean"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(r3["stderr"], r["stderr"], rtol=1e-9, atol=0)  # a difference of sums: 1e-9


def test_phase_mixture_is_normalised_and_sampling_consistent(mi):
    """∫ p_c dω = 1 per channel (MC over uniform directions) and the sampled weight equals
    value/pdf with E[weight] = 1 (the sampled pdf is the mixture's)."""
    import drjit as dr

    from rtfit.reference.nishita_sky import PHASE_PLUGIN, _profile_props, library_atmosphere, register

    register(mi)
    spec = library_atmosphere()
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
    _, weight, pdf_s = phase.sample(
        ctx, mei, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n))
    )
    for c in range(3):
        assert float(np.mean(np.asarray(weight[c]))) == pytest.approx(1.0, rel=0.02)
    assert np.isfinite(np.asarray(pdf_s)).all()


def test_sunsky_and_spec_validation():
    from dataclasses import replace

    from rtfit.reference.nishita_sky import hemisphere_directions, library_atmosphere, sunsky_radiance

    d, _, _ = hemisphere_directions(8, 4)
    s = sunsky_radiance(30.0, d)
    assert np.isfinite(s["sky"]).all() and (s["sky"] > 0).all() and (s["sun_irradiance"] > 0).all()
    with pytest.raises(ValueError, match="sun_elevation_deg"):
        sunsky_radiance(-2.0, d)
    spec = library_atmosphere()
    with pytest.raises(ValueError, match="mie_g"):
        replace(spec, mie_g=1.0)
    with pytest.raises(ValueError, match="viewer_altitude_m"):
        replace(spec, viewer_altitude_m=-1.0)
    with pytest.raises(ValueError, match="sun_angular_radius"):
        replace(spec, sun_angular_radius=2.0)


def test_library_sky_scenes_load_and_hold_the_realtime_defaults(tmp_path):
    """One atmosphere parameter set: every shipped sky scene (SI units) holds the real-time model's
    defaults (`AtmosphereParams()`, same field names and units), and the reference's km values derive
    from it."""
    from dataclasses import asdict
    from pathlib import Path

    from rtfit.realtime.nishita_sky import AtmosphereParams
    from rtfit.reference.nishita_sky import load_atmosphere_scene

    lib = Path(__file__).resolve().parent.parent / "scenes" / "library"
    files = sorted(lib.glob("sky_*.toml"))
    assert files
    defaults = asdict(AtmosphereParams())
    for f in files:
        spec = asdict(load_atmosphere_scene(f))
        shared = set(spec) & set(defaults)
        assert len(shared) == 11, sorted(shared)  # every physical parameter, by the same name
        assert {k: spec[k] for k in shared} == {k: defaults[k] for k in shared}, f.name
    spec = load_atmosphere_scene(files[0])
    assert spec.planet_radius_km == 6360.0 and spec.rayleigh_height_km == 8.0
    assert np.float32(spec.rayleigh_beta_km[1]) == np.float32(13.558e-3)
    bad = tmp_path / "sky.toml"
    bad.write_text(files[0].read_text().replace("planet_radius_m", "planet_radius_km"))
    with pytest.raises(ValueError, match=r"atmosphere\.planet_radius_km: unknown key"):
        load_atmosphere_scene(bad)


def test_tiny_engine_run(tmp_path, monkeypatch):
    """``rtfit run nishita-sky`` on one shipped sky file (16×8, 64 spp) with a tiny study: the engine's sky
    case and fitted row, and every study check (the independent quadratures against Mitsuba's single
    scattering, point and spectral; the solar spectrum; finite images) passes."""
    from rtfit.experiments import nishita_sky_report, nishita_sky_study

    from .conftest import run_tiny_experiment

    tiny = {
        **nishita_sky_study.config(True),
        "quadrature_steps": 200,
        "altitude_cases": [(10.0, 5000.0)],
        "spectral_resolution": (8, 4),
        "spectral_spp": 128,
        "spectral_pass_spp": 64,
        "sweep_layers": [8],
        "sweep_textures": [(32, 16)],
        "sweep_tables": [32],
        "cost_elements": 1 << 12,
    }
    monkeypatch.setattr(nishita_sky_study, "config", lambda quick: tiny)
    monkeypatch.setattr(nishita_sky_report, "figures", lambda *a, **k: [])
    one = {"scenes": ["sky_sun_10"], "resolution": 16, "spp": 64}
    res = run_tiny_experiment("nishita-sky", tmp_path, one)
    assert [c["id"] for c in res["cases"]] == ["sky_sun_10-sky"]
    failed = [c["name"] for c in res["checks"] if not c["passed"]]
    assert not failed, failed
    names = " ".join(c["name"] for c in res["checks"])
    for what in ("SS quadrature (point sun)", "viewer at 5000 m", "spectral SS quadrature", "solar spectrum"):
        assert what in names, what
    assert all(f["converged"] for f in res["fits"]) and len(res["fits"]) == 1
    fitted = json.loads((tmp_path / "out" / "nishita-sky" / "fitted" / "nishita-sky.json").read_text())
    assert fitted["methods"][0]["id"].startswith("nishita-fitted")
    study = res["extra"]["nishita_study"]
    sp = study["spectral"]["rows"][0]
    assert sp["sun"] == 10.0 and len(sp["rgb_model_vs_spectral_model"]) == 4
    assert {s["id"] for s in res["sections"]} >= {"ss-reference", "twilight", "sweep", "spectral"}
    out = tmp_path / "out" / "nishita-sky"
    assert (out / "viewer" / "data").is_dir() and 'id="viewer"' in (out / "report.html").read_text()


# ------------------------------------------------------------------------------ spectral reference
def _planck_si(lam_nm, t_k):
    """Planck spectral radiance W·m⁻²·sr⁻¹·nm⁻¹ from the SI constants (independent of rtfit)."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = np.asarray(lam_nm, dtype=np.float64) * 1e-9
    return 2 * h * c * c / lam**5 / np.expm1(h * c / (lam * k * t_k)) * 1e-9


def test_film_srgb_matches_mitsubas_film():
    """`film_srgb` (quadrature with Mitsuba's CIE table) equals what Mitsuba's hdrfilm makes of a
    constant emitter in the spectral variant: a flat spectrum and a 5778 K blackbody (Mitsuba's own
    `blackbody` plugin vs the SI Planck law here), within the render's noise."""
    from rtfit.realtime.nishita_sky import XYZ_TO_SRGB
    from rtfit.reference.nishita_sky import CIE_Y_NORMALIZATION, _use_variant, film_srgb, film_xyz_to_srgb

    mi = _use_variant("llvm_ad_spectral")
    assert CIE_Y_NORMALIZATION == pytest.approx(mi.MI_CIE_Y_NORMALIZATION, rel=1e-7)
    m = np.asarray(mi.xyz_to_srgb(mi.Color3f(1, 0, 0))).ravel()
    assert m == pytest.approx(film_xyz_to_srgb()[:, 0], rel=1e-7)
    # the one typed copy (the real-time conversion) has Mitsuba's digits
    assert film_xyz_to_srgb() == pytest.approx(XYZ_TO_SRGB, rel=1e-7)

    def render(radiance):
        sc = mi.load_dict(
            {
                "type": "scene",
                "em": {"type": "constant", "radiance": radiance},
                "integrator": {"type": "path"},
                "sensor": {
                    "type": "perspective",
                    "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}},
                },
            }
        )
        img = np.asarray(mi.render(sc, spp=16384, seed=1))
        return img.reshape(-1, img.shape[-1])[:, :3].mean(axis=0)

    lam = np.arange(360.0, 830.5, 1.0)
    flat = render({"type": "uniform", "value": 1.0})
    assert flat == pytest.approx(film_srgb(np.ones_like(lam), lam), rel=2e-3)
    bb = render({"type": "blackbody", "temperature": 5778.0})
    assert bb == pytest.approx(film_srgb(_planck_si(lam, 5778.0), lam), rel=2e-3)
    with pytest.raises(ValueError, match="ascending"):
        film_srgb(np.ones(3), [500.0, 400.0, 600.0])
    with pytest.raises(ValueError, match="360"):
        film_srgb(np.ones(2), [300.0, 400.0])


def test_solar_spectrum_is_the_realtime_one_and_a_5778k_blackbody():
    from rtfit.realtime.nishita_sky import AtmosphereParams
    from rtfit.reference.nishita_sky import solar_spectrum

    lam = np.linspace(400.0, 700.0, 16)
    rt = np.asarray(AtmosphereParams().spectral(lam).solar_irradiance)
    assert solar_spectrum(lam) == pytest.approx(rt, rel=1e-12)
    assert float(solar_spectrum(np.array([550.0]))[0]) == pytest.approx(1.8504, rel=1e-14)
    fine = np.arange(480.0, 520.0, 0.01)
    peak = fine[np.argmax(solar_spectrum(fine))]
    assert peak == pytest.approx(2.897771955e-3 / 5778.0 * 1e9, abs=0.02)  # Wien's displacement law
    ratio = solar_spectrum(np.array([440.0]))[0] / 1.8504
    assert ratio == pytest.approx(_planck_si(440.0, 5778.0) / _planck_si(550.0, 5778.0), rel=1e-6)
    with pytest.raises(ValueError, match="lam_nm"):
        solar_spectrum([-1.0])


def test_spectral_medium_phase_and_sun_at_the_sampled_wavelengths():
    """In the spectral variant the medium returns β_R(550)(550/λ)⁴ + grey Mie at the interaction's
    wavelengths, the phase mixture integrates to 1 per wavelength, and the sun's disc radiance is
    E₀(λ)/(π sin²α) of the 5778 K sun (closed forms)."""
    import drjit as dr

    from rtfit.reference.nishita_sky import _use_variant, library_atmosphere, load_sky

    mi = _use_variant("llvm_ad_spectral")
    spec = library_atmosphere()
    scene, medium = load_sky(mi, spec, 2)
    lam = [380.0, 450.0, 550.0, 700.0]
    n = 1 << 16
    mei = dr.zeros(mi.MediumInteraction3f, n)
    mei.p = mi.Point3f(0.0, 0.0, spec.planet_radius_km)  # ground: densities 1
    mei.wavelengths = mi.Spectrum(*[mi.Float(x) for x in lam])
    mei.wi = mi.Vector3f(0.0, 0.0, 1.0)
    s, nn, t = medium.get_scattering_coefficients(mei)
    for j, x in enumerate(lam):
        br = spec.rayleigh_beta_km[1] * (550.0 / x) ** 4
        assert float(np.asarray(s[j])[0]) == pytest.approx(br + spec.mie_beta_km[1], rel=1e-5)
        assert float(np.asarray(t[j])[0]) == pytest.approx(br + spec.mie_extinction_km[1], rel=1e-5)
    maj = spec.rayleigh_beta_km[1] * (550.0 / 380.0) ** 4 + spec.mie_extinction_km[1]
    assert float(np.asarray(medium.get_majorant(mei)[3])[0]) == pytest.approx(maj, rel=1e-5)
    assert np.asarray(nn[0]).min() >= 0
    # phase mixture normalised per wavelength (uniform directions)
    rng = np.random.default_rng(2)
    u = rng.random((n, 2))
    z = 1 - 2 * u[:, 0]
    r = np.sqrt(1 - z * z)
    wo = mi.Vector3f(r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z)
    mei.p = mi.Point3f(0.0, 0.0, spec.planet_radius_km + 0.5)
    val, _ = medium.phase_function().eval_pdf(mi.PhaseFunctionContext(), mei, wo)
    for j in range(4):
        assert 4 * math.pi * float(np.mean(np.asarray(val[j]))) == pytest.approx(1.0, rel=0.03)
    # the sun
    sun = scene.emitters()[0]
    it = dr.zeros(mi.Interaction3f, 1)
    it.wavelengths = mi.Spectrum(450.0, 500.0, 550.0, 650.0)
    ds = dr.zeros(mi.DirectionSample3f, 1)
    ds.d = mi.Vector3f(*spec.sun_direction.tolist())
    L = np.asarray(sun.eval_direction(it, ds)).ravel()
    a = spec.sun_angular_radius
    e0 = 1.8504 * _planck_si([450.0, 500.0, 550.0, 650.0], 5778.0) / _planck_si(550.0, 5778.0)
    assert L == pytest.approx(e0 / (math.pi * math.sin(a) ** 2), rel=1e-5)


def test_spectral_quadrature_at_550nm_is_the_rgb_green_channel():
    """The spec's G channel is its 550 nm value: the spectral quadrature's spectrum at 550 nm
    equals the RGB quadrature's green (same coefficients), and step_nm must divide 5 nm."""
    from rtfit.reference.nishita_sky import (
        hemisphere_directions,
        library_atmosphere,
        single_scattering_quadrature,
        spectral_single_scattering_quadrature,
    )

    spec = library_atmosphere(sun_elevation_deg=10.0)
    d, _, _ = hemisphere_directions(4, 2)
    q = spectral_single_scattering_quadrature(spec, d, steps=300, step_nm=5.0)
    g = single_scattering_quadrature(spec, d, steps=300)[..., 1]
    i = int(np.flatnonzero(q["wavelengths_nm"] == 550.0)[0])
    assert q["spectra"][..., i] == pytest.approx(g, rel=1e-12)
    assert np.isfinite(q["srgb"]).all() and (q["srgb"][..., 2] > q["srgb"][..., 0]).all()  # a blue sky
    with pytest.raises(ValueError, match="step_nm"):
        spectral_single_scattering_quadrature(spec, d, step_nm=2.0)


def test_spectral_reference_matches_spectral_quadrature(tmp_path):
    """Mitsuba's spectral variant (volpathmis, max_depth 2, λ⁻⁴ medium, 5778 K sun, film
    conversion per path) vs the float64 spectral quadrature: z of every pixel and of the sums."""
    import mitsuba

    from rtfit.reference.nishita_sky import (
        hemisphere_directions,
        library_atmosphere,
        render_sky,
        spectral_single_scattering_quadrature,
    )

    spec = library_atmosphere(sun_elevation_deg=20.0)
    d, _, _ = hemisphere_directions(6, 3)
    mitsuba.set_variant("llvm_ad_rgb")  # the caller's: put back afterwards (issue 33: it was left spectral)
    r = render_sky(
        spec, d, spp=4096, pass_spp=2048, seed=5, variant="llvm_ad_spectral", max_depth=2, cache_dir=tmp_path
    )
    assert mitsuba.variant() == "llvm_ad_rgb"
    q = spectral_single_scattering_quadrature(spec, d, steps=1000)["srgb"]
    z = (r["mean"] - q) / r["stderr"]
    assert np.abs(z).max() < 4.5
    zs = (r["mean"].sum(axis=(0, 1)) - q.sum(axis=(0, 1))) / np.sqrt((r["stderr"] ** 2).sum(axis=(0, 1)))
    assert np.all(np.abs(zs) < 4)
    with pytest.raises(ValueError, match="spectral variant"):
        render_sky(spec, d, spp=4, pass_spp=2, seed=0, variant="llvm_mono_spectral", max_depth=2)


def test_disc_sun_quadrature_against_a_two_dimensional_disc_integral():
    """The disc-sun single scattering (`point_sun=False`: 1-D Gauss–Chebyshev across the disc diameter
    through the zenith of each point) against an independent 2-D integral over the disc: a polar grid
    (4 rings uniform in cos θ' × 12 azimuths) of point-sun quadratures, each sun direction ω reached by
    its elevation and a rotation of the view about the zenith (the atmosphere is spherically
    symmetric), weighted by L_d dω = E₀ dω/(π sin²α). Sun −4°, low anti-solar sky (elevation 16.9°):
    the disc adds 2.3 % over the point sun there; the two disc integrals agree to 3.6e-5 relative
    (measured; 0.16 % of the disc's effect). Bound: 2 % of the effect."""
    from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature

    spec = library_atmosphere(sun_elevation_deg=-4.0, viewer_altitude_m=0.0)
    d = np.array([[-0.938553, 0.1866898, 0.29028468]])
    d /= np.linalg.norm(d)
    point = single_scattering_quadrature(spec, d, steps=150)[0, 1]
    disc = single_scattering_quadrature(spec, d, steps=150, point_sun=False)[0, 1]
    s, a = np.asarray(spec.sun_direction), spec.sun_angular_radius
    e1 = np.cross(s, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(s, e1)
    nr, nf = 4, 12
    brute = 0.0
    for i in range(nr):
        ct = 1 - (i + 0.5) / nr * (1 - math.cos(a))
        st = math.sqrt(1 - ct * ct)
        for k in range(nf):
            f = 2 * math.pi * (k + 0.5) / nf
            om = ct * s + st * (math.cos(f) * e1 + math.sin(f) * e2)
            sp = dataclasses.replace(spec, sun_elevation_deg=math.degrees(math.asin(om[2])))
            c, sn = math.cos(-math.atan2(om[1], om[0])), math.sin(-math.atan2(om[1], om[0]))
            dr_ = np.stack([c * d[:, 0] - sn * d[:, 1], sn * d[:, 0] + c * d[:, 1], d[:, 2]], -1)
            q = single_scattering_quadrature(sp, dr_, steps=150)[0, 1]
            brute += q * (2 * math.pi * (1 - math.cos(a)) / (nr * nf)) / (math.pi * math.sin(a) ** 2)
    assert abs(brute / point - 1) > 0.02  # the disc is resolved here
    assert abs(disc - brute) <= 0.02 * abs(brute - point), (point, disc, brute)


def test_quadrature_rows_on_threads_equal_rows_alone_and_the_job_caches(tmp_path):
    """`_ss_quadrature` computes the sun rays of its rows in one Dr.Jit kernel and its rows on a thread
    pool: each row must be the number that row gives when computed alone (one row: one kernel of its own
    rays, no pool), bit for bit, point and disc sun; and `cached_quadrature` reads
    the same arrays back from its cache (`ComputedEntry`) instead of recomputing."""
    from rtfit.reference.nishita_sky import (
        cached_quadrature,
        hemisphere_directions,
        library_atmosphere,
        single_scattering_quadrature,
    )

    spec = library_atmosphere(sun_elevation_deg=1.0, viewer_altitude_m=0.0)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(5, 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for ps in (True, False):
        together = single_scattering_quadrature(spec, d, steps=60, point_sun=ps)
        rows = [single_scattering_quadrature(spec, d[i : i + 1], steps=60, point_sun=ps) for i in range(5)]
        assert np.array_equal(together, np.concatenate(rows))
    sub = hemisphere_directions(8, 4)[0][1::2, 2::4]
    first, again = (cached_quadrature(spec, sub, 40, tmp_path) for _ in range(2))
    assert not first["cached"] and again["cached"]
    assert np.array_equal(first["value"], again["value"]) and np.array_equal(first["disc"], again["disc"])
    high = dataclasses.replace(spec, sun_elevation_deg=10.0)  # above DISC_MAX_DEG: no disc, read back too
    assert cached_quadrature(high, sub, 40, tmp_path)["disc"] is None
    assert cached_quadrature(high, sub, 40, tmp_path)["disc"] is None


def test_run_is_the_engine_on_the_shipped_sky_files():
    """``rtfit run nishita-sky`` = the engine on one shipped sky file per sun elevation (the old experiment's
    90, 45, 10, 2, 0, −4°; quick 45, 10, −4° with 4× the samples below the horizon) plus the study; each file
    holds its elevation and the shared atmosphere, and the audit's list names the family on it."""
    from rtfit.experiments import audit_nishita_sky, nishita_sky_study
    from rtfit.experiments.applicability import applicable_families
    from rtfit.experiments.audit import inspect_scene
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.reference.nishita_sky import library_atmosphere, load_atmosphere_scene
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["nishita-sky"]
    assert fam.module == ENGINE and fam.scenes == audit_nishita_sky.SCENES
    assert fam.study.target is nishita_sky_study.study
    assert [s.name for s in fam.scenes if s.quick] == ["sky_sun_45", "sky_sun_10", "sky_sun_m4"]
    assert [s.quick_spp for s in fam.scenes if s.quick] == [256, 256, 1024]
    base = dataclasses.asdict(library_atmosphere())
    for s, e in zip(fam.scenes, (90.0, 45.0, 10.0, 2.0, 0.0, -4.0), strict=True):
        spec = dataclasses.asdict(load_atmosphere_scene(LIBRARY_DIR / s.file))
        assert spec.pop("sun_elevation_deg") == e
        assert spec == {k: v for k, v in base.items() if k != "sun_elevation_deg"}
        assert [a.family for a in applicable_families(inspect_scene(LIBRARY_DIR / s.file))] == ["nishita-sky"]


def test_sun_optical_depth_against_adaptive_quadrature():
    """`_sun_optical_depth` (Gauss–Legendre on 8 geometric pieces, a Dr.Jit float64 kernel) against SciPy's
    adaptive ``quad`` of the Rayleigh and Mie densities along each sun ray (split at the ray's perigee):
    points on the ground, at 2 km and at 30 km, the sun at the zenith, 10°, on the horizon and 3° below it
    (a grazing ray over the planet's limb), and blocked rays (inf). Agreement 1e-9 relative."""
    import math

    from scipy.integrate import quad

    from rtfit.reference.nishita_sky import _sun_optical_depth, library_atmosphere

    spec = library_atmosphere()
    rg, rt = spec.planet_radius_km, spec.top_radius_km
    pts, dirs = [], []
    for alt in (0.0, 2.0, 30.0):
        for elev in (90.0, 10.0, 0.0, -3.0):
            e = math.radians(elev)
            pts.append([0.0, 0.0, rg + alt])
            dirs.append([math.cos(e), 0.0, math.sin(e)])
    p, s = np.array(pts), np.array(dirs)
    tr, tm = _sun_optical_depth(p, s, spec)
    for i in range(len(p)):
        b, pp = p[i] @ s[i], p[i] @ p[i]
        if b < 0 and pp - b * b < rg * rg:  # the ray's perigee ahead and below the ground: the planet blocks
            assert tr[i] == math.inf and tm[i] == math.inf
            continue
        t_top = -b + math.sqrt(b * b - (pp - rt * rt))
        split = [min(max(-b, 0.0), t_top)]  # the perigee, where the density peaks on a grazing ray

        def density(t, height, pp=pp, b=b):
            h = math.sqrt(max(pp + 2.0 * t * b + t * t, 0.0)) - rg
            return math.exp(-max(h, 0.0) / height)

        for got, height in ((tr[i], spec.rayleigh_height_km), (tm[i], spec.mie_height_km)):
            want = quad(density, 0.0, t_top, args=(height,), points=split, epsabs=0, epsrel=1e-12, limit=400)
            want = want[0]
            assert got == pytest.approx(want, rel=1e-9, abs=0.0), (i, got, want)
    assert np.isinf(tr).sum() == 2  # the sun 3° below the horizon from the ground and from 2 km
