"""``rtfit fitted convert FILE --engine unreal|unity-hdrp|godot`` (issue 37 §3): fitted height fog in an
engine's own properties (`rtfit.experiments.engine_presets`).

Round trip: converting to the engine and back reproduces the fitted b, c and colour. Formula: each engine's
fog, written from its documentation and source in its module (`engine_presets_unreal`: Unreal's base-2 line
integral in cm with its ×1000 scales; `engine_presets_hdrp`: HDRP's ``OpticalDepthHeightFog``;
`engine_presets_godot`: Godot's FogMaterial density) and evaluated with the converted values, against rtfit's
own kernel (`rtfit.realtime.height_fog.METHODS`) on random segments: to float64 round-off in float64, and
within float32 round-off (with the conditioning of the engine's own float32 text) in float32."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.cli import cli
from rtfit.experiments.engine_presets import ENGINES
from rtfit.experiments.engine_presets_godot import godot_extinction
from rtfit.experiments.engine_presets_hdrp import HDRP_SCALE_HEIGHT, hdrp_optical_depth
from rtfit.experiments.engine_presets_unreal import unreal_optical_depth
from rtfit.experiments.fitted import FittedFile, Provenance, method_entry, write_fitted
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.height_fog import METHODS

EPS32 = float(np.finfo(np.float32).eps)
# (b, c) over the fit's bounds (2e-7…0.2 /m, 4e-6…0.4 /m), the seed's values and a fitted pair
PAIRS = [(2e-4, 4e-3), (2e-7, 4e-6), (0.2, 0.4), (1.3266e-4, 2.8982e-3), (0.05, 1e-4)]


def _tau(method: str, z0, z1, d, b, c):
    """rtfit's kernel: τ along the segment (NumPy float64, or the inputs' dtype)."""
    return np.asarray(METHODS[method](NUMPY_OPS, {"z0": z0, "z1": z1, "distance": d}, {"b": b, "c": c}))


def _segments(rng, n, lo=0.0, hi=3000.0):
    z0 = rng.uniform(lo, hi, n)
    z1 = rng.uniform(lo, hi, n)
    d = np.abs(z1 - z0) * rng.uniform(1.0, 20.0, n) + rng.uniform(0.1, 50.0, n)
    return z0, z1, d


@pytest.mark.parametrize("engine", list(ENGINES))
@pytest.mark.parametrize(("b", "c"), PAIRS)
def test_round_trip_reproduces_the_fitted_values(engine, b, c):
    e = ENGINES[engine]
    colour = (0.068, 0.0466, 0.0315)
    for base in (0.0, 2.0, -50.0):
        values = e.to_engine(b, c, base, colour if e.colour else None)
        b2, c2, colour2 = e.from_engine(values, base)
        assert b2 == pytest.approx(b, rel=1e-12) and c2 == pytest.approx(c, rel=1e-12)
        assert colour2 == (colour if e.colour else None)


def test_unreal_scales_as_documented():
    """Unreal's defaults (FogDensity 0.02, FogHeightFalloff 0.2) are b = 0.02·(ln 2)²/10 per m and
    c = 0.2·ln 2/10 per m (÷1000 per cm, ×100 cm per m, base 2, the line integral's extra ln 2)."""
    b, c, _ = ENGINES["unreal"].from_engine({"FogDensity": 0.02, "FogHeightFalloff": 0.2}, 0.0)
    assert b == pytest.approx(0.02 * math.log(2) ** 2 / 10, rel=1e-15)
    assert c == pytest.approx(0.2 * math.log(2) / 10, rel=1e-15)


@pytest.mark.parametrize(("b", "c"), PAIRS)
def test_unreal_formula_matches_the_kernel(b, c):
    """Unreal's fog with the converted values, actor at 2 m: where its exact branch runs (|F·Δz| > 0.01),
    rtfit's stable form to float64 round-off, and in float32 within 8 ulp·(1 + 1/|x|) plus the
    conditioning of 2^(−F·z₀) (the engine's own cancellation in (1 − 2^(−x))/x); where it takes its Taylor
    polynomial, rtfit's ``taylor`` row (the same engine form, base e) to round-off, and the exact form within
    the polynomial's truncation (ln 2·x)²/6. (Unreal's float32 text leaves float32's range for c·z₀ or
    |c·Δz| past ~80, where rtfit's form stays finite: those rays are not compared in float32.)"""
    rng = np.random.default_rng(37)
    z0, z1, d = _segments(rng, 4000)
    base = 2.0
    v = ENGINES["unreal"].to_engine(b, c, base, None)
    args = (v["FogDensity"], v["FogHeightFalloff"], v["ActorLocationZ"], 100 * z0, 100 * z1, 100 * d)
    x = v["FogHeightFalloff"] / 1000 * 100 * (z1 - z0)
    exact, taylor = _tau("exact", z0, z1, d, b, c), _tau("taylor", z0, z1, d, b, c)
    ue64 = unreal_optical_depth(*args, dtype=np.float64)
    far = np.abs(x) > 0.01
    ok = far & (x > -127) & (exact > 1e-200)  # (far from float64's subnormals)
    np.testing.assert_allclose(ue64[ok], exact[ok], rtol=1e-10)
    np.testing.assert_allclose(ue64[~far], taylor[~far], rtol=1e-12)
    trunc = (math.log(2) * x[~far]) ** 2 / 6  # over φ ≥ 1 − ln 2·|x|/2 ≥ 0.996: within 1 %
    assert np.all(np.abs(ue64[~far] / exact[~far] - 1) <= 1.01 * trunc + 1e-12)
    ue32 = unreal_optical_depth(*args, dtype=np.float32).astype(np.float64)
    cond = c * (np.abs(z0 - base) + np.abs(z1 - z0))  # the exponents' own conditioning
    bound = 8 * EPS32 * (1 + 1 / np.maximum(np.abs(x), 1e-30)) + 4 * EPS32 * cond
    fine = ok & np.isfinite(ue32) & (exact > 1e-30)  # (above float32 subnormals: τ < 1e-30 is T = 1)
    # Unreal's float32 text takes 2^(−F·z) at the camera's height and 2^(−x) apart: where either leaves
    # float32's range (c·z₀ or |c·Δz| past ~80: a camera high above dense fog) it returns 0 or ∞ where
    # rtfit's form stays finite; compared where both are in range
    fine &= (c * np.abs(z0 - base) < 80) & (c * np.abs(z1 - z0) < 80)
    assert np.all(np.abs(ue32[fine] / exact[fine] - 1) <= bound[fine])


@pytest.mark.parametrize(("b", "c"), PAIRS)
def test_hdrp_formula_matches_the_kernel_above_its_base(b, c):
    """HDRP's ``OpticalDepthHeightFog`` with the converted values (base 1 m), on segments above the base with
    |cos zenith| ≥ 0.001: rtfit's stable form to float64 round-off; in float32 within 8 ulp·(1 + 1/y), y the
    segment's c·|Δz| (HDRP's 1 − e^(−y) cancels), plus 4 ulp·c·(heights): the float32 heights' rounding."""
    rng = np.random.default_rng(38)
    base = 1.0
    z0, z1, d = _segments(rng, 4000, lo=base, hi=3000.0)
    cosz = (z1 - z0) / d
    keep = np.abs(cosz) >= 0.001
    z0, z1, d, cosz = z0[keep], z1[keep], d[keep], cosz[keep]
    v = ENGINES["unity-hdrp"].to_engine(b, c, base, None)
    args = (v["FogAttenuationDistance"], v["BaseHeight"], v["MaximumHeight"], cosz, z0, d)
    exact = _tau("exact", z0, z1, d, b, c)
    hd64 = hdrp_optical_depth(*args, dtype=np.float64)
    ok = exact > 1e-200
    np.testing.assert_allclose(hd64[ok], exact[ok], rtol=1e-9)
    hd32 = hdrp_optical_depth(*args, dtype=np.float32).astype(np.float64)
    y = c * np.abs(z1 - z0)
    cond = c * (np.maximum(z0, z1) + np.abs(z1 - z0))  # heights and end height rounded: c·δh
    bound = 8 * EPS32 * (1 + 1 / np.maximum(y, 1e-30)) + 4 * EPS32 * cond
    fine = ok & np.isfinite(hd32) & (exact > 1e-30)  # (above float32 subnormals: τ < 1e-30 is T = 1)
    assert np.all(np.abs(hd32[fine] / exact[fine] - 1) <= bound[fine])
    # the layer depth HDRP is given puts e^(−d/H) = 0.001 at the Maximum Height: H = 1/c
    assert HDRP_SCALE_HEIGHT * (v["MaximumHeight"] - v["BaseHeight"]) == pytest.approx(1 / c, rel=1e-12)


@pytest.mark.parametrize(("b", "c"), PAIRS)
def test_godot_density_and_its_integral_match_the_kernel(b, c):
    """Godot's FogMaterial density with the converted values (origin at 1 m): b·e^(−c·y) above the origin
    (float64 round-off; float32 within 4 ulp plus the conditioning of 2^(−h·(y − y₀))), and its integral
    along segments above the origin (Gauss–Legendre, 64 nodes) rtfit's optical depth."""
    base = 1.0
    v = ENGINES["godot"].to_engine(b, c, base, None)
    args = (v["FogMaterial.density"], v["FogMaterial.height_falloff"], v["FogVolume.position.y"])
    y = np.linspace(base, 3000.0, 501)
    ref = b * np.exp(-c * y)
    np.testing.assert_allclose(godot_extinction(*args, y, dtype=np.float64), ref, rtol=1e-12)
    g32 = godot_extinction(*args, y, dtype=np.float32).astype(np.float64)
    big = ref > 1e-30
    assert np.all(np.abs(g32[big] / ref[big] - 1) <= 4 * EPS32 + 2 * EPS32 * c * (y[big] - base))
    assert np.all(
        godot_extinction(*args, np.array([base - 10.0]), dtype=np.float64) == v["FogMaterial.density"]
    )
    rng = np.random.default_rng(39)
    z0, z1, d = _segments(rng, 50, lo=base, hi=500.0)
    t, w = np.polynomial.legendre.leggauss(64)
    s = 0.5 * (t + 1.0)
    heights = z0[:, None] + (z1 - z0)[:, None] * s[None, :]
    quad = 0.5 * d * (godot_extinction(*args, heights, dtype=np.float64) * w[None, :]).sum(axis=1)
    np.testing.assert_allclose(quad, _tau("exact", z0, z1, d, b, c), rtol=1e-9)


# ------------------------------------------------------------------------------------ files and the CLI
def _fitted_file(tmp_path, method_id: str, values: dict) -> str:
    m = METHODS[method_id]
    entry = method_entry(
        m, params=values, case="test", domain={"z0": (2.0, 2.0), "z1": (0.5, 5000.0), "distance": (7.0, 7e4)}
    )
    doc = FittedFile(
        format="rtfit.fitted/1",
        title=f"height fog {method_id} (test)",
        provenance=Provenance(rtfit_version="0", experiment="height-fog", date="2026-12-05T00:00:00+00:00"),
        methods=[entry],
    )
    path = tmp_path / f"fog-{method_id}.json"
    write_fitted(path, doc)
    return str(path)


@pytest.mark.parametrize("engine", list(ENGINES))
def test_convert_command_round_trips_a_fitted_file(tmp_path, engine):
    """``rtfit fitted convert`` on a ``const`` height-fog file: stdout is the preset document; its values,
    read back through the engine's inverse, are the file's b, c and colour; HDRP and Godot anchor at the
    lowest height of the fit's domain (0.5 m), Unreal at rtfit's origin; what is lost is listed."""
    values = {"b": 3.164e-4, "c": 3.109e-2, "r0": 0.068, "g0": 0.0466, "b0": 0.0315}
    path = _fitted_file(tmp_path, "const", values)
    out = CliRunner().invoke(cli, ["fitted", "convert", path, "--engine", engine])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.stdout)
    assert doc["format"] == "rtfit.engine-preset/1" and doc["engine"] == engine and doc["sources"]
    (preset,) = doc["presets"]
    got = {
        v["name"]: (tuple(v["value"]) if isinstance(v["value"], list) else v["value"])
        for v in preset["values"]
    }
    base = preset["base_height_m"]
    assert base == (0.0 if engine == "unreal" else 0.5)
    b, c, colour = ENGINES[engine].from_engine(got, base)
    assert b == pytest.approx(values["b"], rel=1e-12) and c == pytest.approx(values["c"], rel=1e-12)
    if engine == "godot":
        assert colour is None and any("colour C₀" in line for line in preset["lost"])
    else:
        assert colour == pytest.approx((values["r0"], values["g0"], values["b0"]), rel=1e-15)


def test_convert_refuses_what_it_cannot_convert(tmp_path):
    """A file without a fog method, a file that is not rtfit.fitted/1: one line each, exit 2."""
    from rtfit.realtime.diffuse import METHODS as DIFFUSE

    m = DIFFUSE["wrap"]
    doc = FittedFile(
        format="rtfit.fitted/1",
        title="wrap",
        provenance=Provenance(rtfit_version="0", experiment="diffuse", date="2026-12-05T00:00:00+00:00"),
        methods=[method_entry(m)],
    )
    write_fitted(tmp_path / "wrap.json", doc)
    out = CliRunner().invoke(cli, ["fitted", "convert", str(tmp_path / "wrap.json"), "--engine", "unreal"])
    assert out.exit_code == 2 and "no height-fog method" in out.stderr and len(out.stderr.splitlines()) == 1
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    out = CliRunner().invoke(cli, ["fitted", "convert", str(tmp_path / "bad.json"), "--engine", "godot"])
    assert out.exit_code == 2 and "expected 'rtfit.fitted/1'" in out.stderr


def test_a_fit_an_engine_cannot_hold_is_named_and_the_others_converted(tmp_path):
    """A file with a fog fit of c < 0 (constant fog fitted upward) beside a valid one: the valid one is
    converted (its b, c back through Unreal's inverse), the other named in ``skipped`` with why; a file of
    only the invalid one is one line and exit 2."""
    good = {"b": 3.164e-4, "c": 3.109e-2, "r0": 0.068, "g0": 0.0466, "b0": 0.0315}
    bad = {**good, "c": -1.92}
    m = METHODS["const"]
    dom = {"z0": (2.0, 2.0), "z1": (0.5, 5000.0), "distance": (7.0, 7e4)}
    doc = FittedFile(
        format="rtfit.fitted/1",
        title="two fits",
        provenance=Provenance(rtfit_version="0", experiment="height-fog", date="2026-12-05T00:00:00+00:00"),
        methods=[
            method_entry(m, params=good, case="good", domain=dom),
            method_entry(m, params=bad, case="bad", domain=dom),
        ],
    )
    write_fitted(tmp_path / "two.json", doc)
    out = CliRunner().invoke(cli, ["fitted", "convert", str(tmp_path / "two.json"), "--engine", "unreal"])
    assert out.exit_code == 0, out.output
    got = json.loads(out.stdout)
    (preset,) = got["presets"]
    values = {v["name"]: v["value"] for v in preset["values"]}
    b, c, _ = ENGINES["unreal"].from_engine(values, 0.0)
    assert b == pytest.approx(good["b"], rel=1e-12) and c == pytest.approx(good["c"], rel=1e-12)
    (why,) = got["skipped"]
    assert "c = -1.92" in why and "c > 0" in why
    only_bad = _fitted_file(tmp_path, "const", bad)
    out = CliRunner().invoke(cli, ["fitted", "convert", only_bad, "--engine", "unreal"])
    assert out.exit_code == 2 and "c > 0" in out.stderr and len(out.stderr.splitlines()) == 1


# ------------------------------------------------------------------------ the Nishita sky: SkyAtmosphere
def test_unscaled_sky_is_unreals_documented_default():
    """rtfit's atmosphere (Bruneton's parameters) as SkyAtmosphere properties: Unreal's documented defaults
    (Rayleigh 0.0331 × (0.175287, 0.409607, 1) per km over 8 km, Mie 0.003996 / absorption 0.000444 per km
    over 1.2 km, anisotropy 0.8, ground 6360 km, atmosphere 60 km)."""
    from rtfit.experiments.engine_presets_unreal import sky_to_unreal
    from rtfit.realtime.nishita_sky import AtmosphereParams

    v = sky_to_unreal(AtmosphereParams())
    assert v["RayleighScatteringScale"] == pytest.approx(0.0331, rel=1e-12)
    assert v["RayleighScattering"] == pytest.approx((0.175287, 0.409607, 1.0), abs=5e-7)
    assert v["MieScatteringScale"] == pytest.approx(0.003996) and v["MieAbsorptionScale"] == pytest.approx(
        0.000444
    )
    assert v["RayleighExponentialDistribution"] == 8.0 and v["MieExponentialDistribution"] == 1.2
    assert (v["MieAnisotropy"], v["GroundRadius"], v["AtmosphereHeight"]) == (0.8, 6360.0, 60.0)


@pytest.mark.parametrize(("s_r", "s_m", "g"), [(0.6937, 1.1615, 0.7797), (0.3, 0.05, 0.0), (3.0, 20.0, 0.95)])
def test_sky_round_trip_and_the_engine_medium(s_r, s_m, g):
    """The fitted scales to SkyAtmosphere and back; Unreal's medium (scale × colour × e^(−h/distribution),
    per km) is rtfit's β·e^(−h/H) per m at every altitude, and its vertical optical depth (Gauss–Legendre
    over 0…60 km) gives rtfit's sun transmittance at the zenith."""
    from rtfit.experiments.engine_presets_unreal import (
        sky_from_unreal,
        sky_to_unreal,
        unreal_sky_coefficients,
    )
    from rtfit.realtime.nishita_sky import AtmosphereParams, sun_transmittance

    params = AtmosphereParams(rayleigh_scale=s_r, mie_scale=s_m, mie_g=g)
    v = sky_to_unreal(params)
    assert sky_from_unreal(v, AtmosphereParams()) == pytest.approx((s_r, s_m, g), rel=1e-12)
    br, bm, bme = params.betas()
    h_km = np.linspace(0.0, 60.0, 61)
    ray, mie, absorption = unreal_sky_coefficients(v, h_km)
    for k in range(3):
        np.testing.assert_allclose(
            ray[k] / 1e3, br[k] * np.exp(-h_km * 1e3 / params.rayleigh_height_m), rtol=1e-12
        )
        np.testing.assert_allclose(
            mie[k] / 1e3, bm[k] * np.exp(-h_km * 1e3 / params.mie_height_m), rtol=1e-12
        )
        np.testing.assert_allclose(
            (mie[k] + absorption[k]) / 1e3, bme[k] * np.exp(-h_km * 1e3 / params.mie_height_m), rtol=1e-12
        )
    t, w = np.polynomial.legendre.leggauss(200)
    h = 30.0 * (t + 1.0)
    ray, mie, absorption = unreal_sky_coefficients(v, h)
    tau = [30.0 * np.sum(w * (ray[k] + mie[k] + absorption[k])) for k in range(3)]
    np.testing.assert_allclose(np.exp(-np.array(tau)), sun_transmittance(params, 0.0, 1.0), rtol=1e-9)


def test_sky_file_converts_for_unreal_and_hdrp(tmp_path):
    """A Nishita-sky fitted file: ``--engine unreal`` gives the SkyAtmosphere preset with ``ambient`` listed
    as lost, ``unity-hdrp`` the Physically Based Sky one; Godot is one line, exit 2."""
    par = {"value": 0.0, "stderr": None, "unit": "1", "lower": 0.0, "upper": 10.0, "at_bound": False}
    method = {
        "id": "nishita-fitted", "label": "Nishita fitted", "formula": "L", "case": "e45-ms",
        "quantity": "sky_radiance", "residual": None, "domain": {}, "shader": None,
        "shader_note": "a texture",
        "parameters": {k: {**par, "value": x} for k, x in
                       (("rayleigh_scale", 0.69), ("mie_scale", 1.16), ("mie_g", 0.78), ("ambient", 0.71))},
    }  # fmt: skip
    provenance = {"rtfit_version": "0", "experiment": "nishita-sky", "date": "2026-12-05"}
    doc = {"format": "rtfit.fitted/1", "title": "sky", "methods": [method], "provenance": provenance}
    path = tmp_path / "sky.json"
    path.write_text(json.dumps(doc))
    out = CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", "unreal"])
    assert out.exit_code == 0, out.output
    (preset,) = json.loads(out.stdout)["presets"]
    got = {v["name"]: v["value"] for v in preset["values"]}
    assert got["RayleighScatteringScale"] == pytest.approx(0.0331 * 0.69, rel=1e-12)
    assert got["MultiScatteringFactor"] == 0.0 and any(line.startswith("ambient") for line in preset["lost"])
    out = CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", "unity-hdrp"])
    assert out.exit_code == 0, out.output
    (preset,) = json.loads(out.stdout)["presets"]
    got = {v["name"]: v["value"] for v in preset["values"]}
    assert got["NumberOfBounces"] == 1 and got["AerosolAnisotropy"] == 0.78
    out = CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", "godot"])
    assert out.exit_code == 2 and "Godot's sky is not converted" in out.stderr


def test_phase_lobe_as_unreals_directional_inscattering():
    """The fitted lobe 4π·p_HG(θ, g) as a + k·max(cos θ, 0)^n (Unreal's inscattering plus directional
    inscattering): isotropic (g = 0) is a = 1, k = 0 exactly; for g = 0.58 the reported relative RMS error is
    the one a midpoint rule over 20 000 cosines gives for the returned (a, k, n), and no exponent 5 % away
    (with its own least-squares a, k on that grid) does better."""
    from rtfit.experiments.engine_presets_fog import hg_as_power_lobe

    a, k, n, rel = hg_as_power_lobe(0.0)
    assert a == pytest.approx(1.0, abs=1e-9) and k == pytest.approx(0.0, abs=1e-9) and rel < 1e-9
    g = 0.58
    a, k, n, rel = hg_as_power_lobe(g)
    mu = (np.arange(20000) + 0.5) / 10000 - 1.0
    w = (1 - g * g) / (1 + g * g - 2 * g * mu) ** 1.5  # 4π·p_HG, written here from its definition

    def err(a_, k_, n_):
        return math.sqrt(np.mean((a_ + k_ * np.maximum(mu, 0.0) ** n_ - w) ** 2) / np.mean(w**2))

    assert err(a, k, n) == pytest.approx(rel, rel=1e-3)
    for m in (0.95 * n, 1.05 * n):
        basis = np.stack([np.ones_like(mu), np.maximum(mu, 0.0) ** m], axis=1)
        (a2, k2), *_ = np.linalg.lstsq(basis, w, rcond=None)
        assert err(a2, k2, m) >= rel * (1 - 1e-3)


def test_phase_file_for_unreal_carries_the_lobe(tmp_path):
    """A ``phase`` height-fog file for Unreal: b and c round-trip, FogInscatteringColor = C₀ + a·C₁ and
    DirectionalInscatteringColor = k·C₁ with the lobe fit's (a, k, n), the fit's error listed as lost."""
    from rtfit.experiments.engine_presets_fog import hg_as_power_lobe

    values = {"b": 1.3266e-4, "c": 2.898e-3, "r0": 0.0109, "g0": 0.0188, "b0": 0.0245}
    values |= {"r1": 0.0704, "g1": 0.0431, "b1": 0.0159, "g": 0.58}
    out = CliRunner().invoke(
        cli, ["fitted", "convert", _fitted_file(tmp_path, "phase", values), "--engine", "unreal"]
    )
    assert out.exit_code == 0, out.output
    (preset,) = json.loads(out.stdout)["presets"]
    got = {v["name"]: v["value"] for v in preset["values"]}
    b, c, _ = ENGINES["unreal"].from_engine(got, 0.0)
    assert b == pytest.approx(values["b"], rel=1e-12) and c == pytest.approx(values["c"], rel=1e-12)
    a, k, n, rel = hg_as_power_lobe(0.58)
    c0, c1 = [values[x] for x in ("r0", "g0", "b0")], [values[x] for x in ("r1", "g1", "b1")]
    assert got["FogInscatteringColor"] == pytest.approx([x + a * y for x, y in zip(c0, c1, strict=True)])
    assert got["DirectionalInscatteringColor"] == pytest.approx([k * y for y in c1])
    assert got["DirectionalInscatteringExponent"] == pytest.approx(n)
    assert f"{rel:.2g}" in preset["lost"][0]


@pytest.mark.parametrize(("s_r", "s_m", "g"), [(0.6937, 1.1615, 0.7797), (0.3, 0.05, 0.0), (3.0, 20.0, 0.95)])
def test_hdrp_sky_round_trip_and_medium(s_r, s_m, g):
    """The fitted scales as HDRP Physically Based Sky properties and back; HDRP's medium (zenith opacity →
    extinction −ln(1 − α)/H, H = 0.144765 × Maximum Altitude, scattering = extinction × tint) is rtfit's
    β·e^(−h/H) at every altitude."""
    from rtfit.experiments.engine_presets_hdrp import hdrp_sky_coefficients, sky_from_hdrp, sky_to_hdrp
    from rtfit.realtime.nishita_sky import AtmosphereParams

    params = AtmosphereParams(rayleigh_scale=s_r, mie_scale=s_m, mie_g=g)
    v = sky_to_hdrp(params)
    assert sky_from_hdrp(v, AtmosphereParams()) == pytest.approx((s_r, s_m, g), rel=1e-12)
    br, bm, bme = params.betas()
    h = np.linspace(0.0, 60e3, 61)
    air, aer, ext = hdrp_sky_coefficients(v, h)
    for k in range(3):
        np.testing.assert_allclose(air[k], br[k] * np.exp(-h / params.rayleigh_height_m), rtol=1e-12)
        np.testing.assert_allclose(aer[k], bm[k] * np.exp(-h / params.mie_height_m), rtol=1e-12)
        np.testing.assert_allclose(ext[k], bme[k] * np.exp(-h / params.mie_height_m), rtol=1e-12)


def test_unscaled_sky_is_close_to_hdrps_earth():
    """rtfit's unscaled air, converted and read back as HDRP does, is HDRP's built-in Earth air extinction
    (5.8e-6, 1.35e-5, 3.31e-5 per m) within 0.5 % (both are Bruneton's coefficients, HDRP's rounded), and the
    aerosol's scale height is Earth's 1200 m: the units (per metre, metres) agree."""
    from rtfit.experiments.engine_presets_hdrp import hdrp_sky_coefficients, sky_to_hdrp
    from rtfit.realtime.nishita_sky import AtmosphereParams

    v = sky_to_hdrp(AtmosphereParams())
    air, _aer, _ext = hdrp_sky_coefficients(v, 0.0)
    np.testing.assert_allclose([float(a) for a in air], [5.8e-6, 1.35e-5, 3.31e-5], rtol=5e-3)
    assert HDRP_SCALE_HEIGHT * v["AerosolMaximumAltitude"] == pytest.approx(1200.0, rel=1e-12)
