"""`rtfit audit` of the media families (issue 15 §2–4): height fog on an rtfit TOML scene, the Nishita sky on
an rtfit sky file, and user approximations of ``fog_transmittance`` and ``sky_radiance``.

Renders are tiny (6×6 fog pixels, an 8×4 sky panorama, 16–64 samples per pixel). Expected values come from
computations written here: the fog's transmittance e^(−τ) with τ by Gauss–Legendre quadrature of the
density b·exp(−c·(x − p₀)·ĝ) along each camera ray inside the box (its own slab intersection), least squares
of the user's formulas in closed form or by SciPy, and the Nishita sky of the experiment's own path
(`SkySetting.radiance`: `build_sky` + `shade_sky`) beside the kernel run the audit evaluates."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import least_squares

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_nishita_sky import atmosphere_params_of
from rtfit.experiments.audit_run import audit
from rtfit.experiments.results import load_results
from rtfit.realtime.nishita_sky import METHODS as SKY_METHODS
from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature
from rtfit.scenes import library_path, load_scene

FAST = {"cost_elements": 1 << 12, "metrics": ("rmse", "rel_mse", "mae", "max_abs")}

MY_FOG = '''
from rtfit import approximation, Param


@approximation(quantity="fog_transmittance", params={"k": Param(1.0, lower=0.1, upper=10.0)})
def mid_fog(ops, g, *, k):
    """The density at the segment's mid-height times its length, scaled by k."""
    return ops.exp(-k * g.density * ops.exp(-g.falloff * 0.5 * (g.z0 + g.z1)) * g.length)
'''

MY_SKY = '''
from rtfit import approximation, Param


@approximation(quantity="sky_radiance", params={"k": Param(0.05, lower=0.0, upper=10.0)})
def ray_sky(ops, g, *, k):
    """A grey Rayleigh-shaped sky: k·(1 + cos²θ), θ between the view and the sun."""
    c = g.dx * g.sx + g.dy * g.sy + g.dz * g.sz
    f = k * (1.0 + c * c)
    return (f, f, f)
'''


def _fog_depth(dirs: np.ndarray, nodes: int = 256):
    """τ(b, c) of the fog_transmittance scene's medium along rays from its camera, as a function of the
    density b and falloff c: Gauss–Legendre quadrature of b·exp(−c·(x − p₀)·ĝ) over the ray's segment inside
    the rotated box (slab test here)."""
    scene = load_scene(library_path("fog_transmittance"))
    m = scene.media[0]
    o = np.asarray(scene.camera.origin, np.float64)
    box = m.boundary
    a = math.radians(box.rotate_deg)
    rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    half = np.asarray(box.size, np.float64) / 2
    lo = rot.T @ (o - np.asarray(box.center)) / half
    ld = (dirs @ rot) / half
    with np.errstate(divide="ignore"):
        t1, t2 = (-1.0 - lo) / ld, (1.0 - lo) / ld
    t_in = np.max(np.minimum(t1, t2), axis=1).clip(min=0.0)
    t_out = np.max([np.min(np.maximum(t1, t2), axis=1), t_in], axis=0)
    g = np.asarray(m.gradient, np.float64) / np.linalg.norm(m.gradient)
    x, w = np.polynomial.legendre.leggauss(nodes)
    t = t_in[:, None] + (t_out - t_in)[:, None] * (x + 1) / 2
    h = (o + t[..., None] * dirs[:, None, :] - np.asarray(m.gradient_origin)) @ g

    def tau(b, c):
        return b * np.sum(w * np.exp(-c * h), axis=1) * (t_out - t_in) / 2

    return tau, m.density, m.falloff


def _fog_truth(dirs: np.ndarray) -> np.ndarray:
    """e^(−τ) with the scene's own b, c (`_fog_depth`)."""
    tau, b, c = _fog_depth(dirs)
    return np.exp(-tau(b, c))


def test_height_fog_transmittance_against_quadrature_and_a_user_fit(tmp_path):
    """The library's fog_transmittance scene (a purely absorbing exponential fog box with a tilted, shifted
    gradient in front of an emissive backdrop): the ratio-tracking reference sits on e^(−τ) from quadrature
    within its noise; the exact form (as T = e^(−τ)) equals it to float64 rounding and its fit lands on the
    scene's b, c; a user's fog_transmittance approximation is evaluated (equal to its formula computed here)
    and fitted (where SciPy's fit of the same formula to the same reference lands)."""
    (tmp_path / "my_fog.py").write_text(MY_FOG)
    r = audit(
        "fog_transmittance",
        f"height-fog:exact,{tmp_path / 'my_fog.py'}:mid_fog",
        width=6,
        height=6,
        spp=64,
        pass_spp=32,
        cache=tmp_path / "cache",
        **FAST,
    )
    assert [c.id for c in r.cases] == ["fog0-transmittance"]  # no shading row asked for: no radiance case
    case = r.cases[0]
    g = case.channel_inputs[0]
    dirs = np.stack([g["dx"], g["dy"], g["dz"]], axis=1)
    truth = _fog_truth(dirs)
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    assert case.mask.sum() == 20  # the rays that cross the box
    z = (ref - truth[:, None]) / err  # three independent estimates of the grey T per pixel
    assert abs(float(np.mean(z))) < 0.6 and float(np.max(np.abs(z))) < 4.5  # measured: 0.026, 2.0
    assert truth.min() < 0.05 and truth.max() > 0.95  # from nearly opaque to nearly clear (0.014–0.994)
    exact = r.image(case.id, "exact")[case.mask][:, 0]  # a grey value in each channel
    assert np.max(np.abs(exact - truth)) < 1e-9  # measured 9.0e-12 (float64 inputs and kernel)
    # the exact form's fit of (b, c) lands where SciPy's fit of e^(−τ(b, c)) by quadrature lands
    tau, b0, c0 = _fog_depth(dirs)
    ls = least_squares(lambda p: (np.exp(-tau(*p))[:, None] - ref).ravel(), [b0, c0], xtol=1e-12, ftol=1e-12)
    fit = r.fits[f"{case.id}/exact-fitted"]
    for name, value in zip("bc", ls.x, strict=True):
        assert abs(fit[name]["value"] / value - 1.0) < 1e-5, (name, fit[name], value)  # measured < 1e-8
    assert abs(ls.x[0] / b0 - 1.0) < 0.05 and abs(ls.x[1] / c0 - 1.0) < 0.05  # (3 %: the noise of 20 pixels)

    # the user's formula: evaluated as written, and fitted where SciPy lands on the same data
    def mid(k):
        return np.exp(-k * g["density"] * np.exp(-g["falloff"] * 0.5 * (g["z0"] + g["z1"])) * g["length"])

    assert np.max(np.abs(r.image(case.id, "mid_fog")[case.mask][:, 0] - mid(1.0))) < 1e-12  # measured 1e-16
    ls = least_squares(
        lambda k: (mid(k[0])[:, None] - ref).ravel(), [1.0], bounds=([0.1], [10.0]), xtol=1e-12, ftol=1e-12
    )
    k_fit = r.fits[f"{case.id}/mid_fog-fitted"]["k"]["value"]
    assert abs(k_fit - ls.x[0]) < 1e-6 * ls.x[0]  # measured 4e-11 relative
    assert r.outcomes[case.id]["mid_fog"].user and "mid_fog" in r.costs
    # the engine's self-check of the exact form: its z-scores are standard normal (median, tails); the
    # robust spread of 60 elements has a sampling error of ~0.15 itself, so it is asserted within ±0.35
    checks = {c.name.rsplit(": ", 1)[1].split(" (")[0]: c for c in r.results.checks}
    assert set(checks) == {"robust z spread", "median z", "fraction with |z| > 4"}, checks
    assert checks["median z"].passed and checks["fraction with |z| > 4"].passed
    assert abs(checks["robust z spread"].value - 1.0) < 0.35  # measured 1.25


def test_height_fog_cli_end_to_end_with_the_radiance_case(tmp_path):
    """``rtfit audit fog_transmittance`` as a user runs it: exit 0, the report; the transmittance case with
    the three optical-depth forms and the radiance case with the two shading models; the fog is purely
    absorbing in front of a backdrop of radiance 1, so the radiance reference is e^(−τ) too."""
    out = tmp_path / "out"
    result = CliRunner().invoke(
        audit_cmd,
        ["fog_transmittance", "--width", "6", "--height", "6", "--spp", "128", "--pass-spp", "64",
         "--out", str(out), "--cache", str(tmp_path / "cache"), "--no-fit", "--no-progress"],
    )  # fmt: skip
    assert result.exit_code == 0, result.stderr
    report = out / "audit-fog_transmittance"
    for f in ("results.json", "report.html", "report.md", "tables.tex"):
        assert (report / f).is_file()
    res = load_results(report)
    assert [c.id for c in res.cases] == ["fog0-transmittance", "fog0-radiance"]
    assert [a.method for a in res.cases[0].approximations] == ["exact", "seed", "taylor"]
    assert [a.method for a in res.cases[1].approximations] == ["const", "phase", "absorbing"]  # albedo 0
    assert "timings: reference" in result.stderr


def test_height_fog_radiance_reference_of_an_absorbing_fog_is_the_transmittance(tmp_path):
    r = audit(
        "fog_transmittance", "height-fog:const", width=6, height=6, spp=64, pass_spp=32, fit=False,
        cache=tmp_path / "cache", **FAST,
    )  # fmt: skip
    case = r.cases[0]
    assert case.id == "fog0-radiance"
    g = case.channel_inputs[0]
    truth = _fog_truth(np.stack([g["dx"], g["dy"], g["dz"]], axis=1))
    ref = case.reference.mean[case.mask]
    # Mitsuba's delta tracking through a purely absorbing fog in front of radiance 1: each sample is 1
    # (the path got through) or 0, a Bernoulli(T) variable, so the 64-sample mean has the exact standard
    # error √(T(1 − T)/64) under the hypothesis tested. The sample standard error is not usable here: at
    # T ≈ 0.98 all 64 samples get through with probability 0.98⁶⁴ ≈ 0.27 (a stderr of 0: z = ∞ for an
    # unbiased estimate; seen with the per-segment majorant's random stream)
    z = (ref - truth[:, None]) / np.sqrt(truth * (1.0 - truth) / 64)[:, None]
    assert abs(float(np.mean(z))) < 0.6 and float(np.max(np.abs(z))) < 4.5  # measured: −0.14, 2.7
    assert np.allclose(g["l0_r"], 1.0, atol=1e-6)  # the fog-free image: the backdrop's radiance 1


@pytest.fixture(scope="module")
def sky_audit(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sky")
    (tmp / "my_sky.py").write_text(MY_SKY)
    return audit(
        "sky_sun_45",
        f"nishita-seed,{tmp / 'my_sky.py'}:ray_sky",
        width=8,
        height=4,
        spp=256,
        pass_spp=128,
        cache=tmp / "cache",
        **FAST,
    )


def test_nishita_sky_rows_are_the_experiments_sky_of_the_files_atmosphere(sky_audit):
    """The nishita-seed row (the kernel with the file's atmosphere and altitude, on its setting's inputs)
    equals the experiment's own path (`SkySetting.radiance`: `build_sky` then `shade_sky`) on the same
    directions; the reference is the multiple-scattering sky: summed over the pixels, above the independent
    single-scattering quadrature by many standard errors, and by less than a factor 2 at sun 45°."""
    r = sky_audit
    case = r.cases[0]
    assert case.id == "sky" and case.mask.sum() == 32  # no pixel within 1° of the sun at 8×4
    spec = library_atmosphere("sky_sun_45")
    g = case.channel_inputs[0]
    dirs = np.stack([g["dx"], g["dy"], g["dz"]], axis=1)
    setting = SKY_METHODS["nishita-seed"].fixed["setting"]
    expected = setting.radiance(atmosphere_params_of(spec), 45.0, dirs, altitude_m=10.0)
    got = r.image("sky", "nishita-seed")[case.mask]
    assert np.max(np.abs(got / expected - 1.0)) < 1e-4  # measured 1.1e-6 (float64 vs float32 texture)
    ss = single_scattering_quadrature(spec, dirs, steps=400)
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    excess = np.sum(ref - ss, axis=0) / np.sqrt(np.sum(err**2, axis=0))  # summed: per-pixel noise is heavy
    ratio = np.sum(ref, axis=0) / np.sum(ss, axis=0)
    assert np.all(excess > 3.0), excess  # measured 8.9, 12.9, 11.7 standard errors above
    assert np.all((ratio > 1.05) & (ratio < 2.0)), ratio  # measured 1.23, 1.35, 1.61 (R, G, B)


def test_nishita_sky_user_approximation_is_evaluated_and_fitted(sky_audit):
    """The user's grey k·(1 + cos²θ) sky: evaluated as written (the sun direction and the view directions
    the audit gives), and its k fitted where the closed-form linear least squares on the same reference
    lands (Σ f·L / (3 Σ f²) over the three channels)."""
    r = sky_audit
    case = r.cases[0]
    g = case.channel_inputs[0]
    c = g["dx"] * g["sx"] + g["dy"] * g["sy"] + g["dz"] * g["sz"]
    assert np.allclose(g["sz"], math.sin(math.radians(45.0))) and np.allclose(g["sy"], 0.0)
    f = 1.0 + c * c
    img = r.image("sky", "ray_sky")[case.mask]
    assert np.max(np.abs(img - 0.05 * f[:, None])) < 1e-12
    ref = case.reference.mean[case.mask]
    k_ls = float(np.sum(f[:, None] * ref) / (3.0 * np.sum(f * f)))
    k_fit = r.fits["sky/ray_sky-fitted"]["k"]["value"]
    assert abs(k_fit / k_ls - 1.0) < 1e-6  # measured 3e-10
    assert r.outcomes["sky"]["ray_sky"].user and r.costs["ray_sky"]["ns_per_pixel"] > 0
