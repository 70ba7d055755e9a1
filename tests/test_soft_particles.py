"""Soft particles (`rtfit.realtime.soft_particles`, `rtfit.reference.soft_particles`, experiment
``soft-particles``): values from independent computations — closed forms, a midpoint count of the chord,
the quadratic's roots, Mitsuba — and the full domain of every kernel by hypothesis."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS, jax_ops
from rtfit.realtime.soft_particles import (
    ALPHA_MAX,
    METHODS,
    beer_fraction,
    billboard_alpha,
    box_chord,
    linear_underestimate,
    sphere_chord,
)


def _ray(theta_deg: float = 0.0):
    th = math.radians(theta_deg)
    return (math.sin(th), 0.0, math.cos(th))


# ----------------------------------------------------------------------------------------- the claim
def test_claim_linear_fade_underestimates_dense_particles():
    """Issue 18: α = 0.95, half the chord: linear 0.475, exact 0.776. Derivation: α = 1 − e^(−σℓ_full), so
    the opacity of ℓ = f·ℓ_full is 1 − e^(−fσℓ_full) = 1 − (1 − α)^f = 1 − √0.05 at f = ½ (0.7763932...).
    The box on the view axis, cut through its centre, is exactly that geometry."""
    alpha, r, z = 0.95, 1.0, 4.0
    sigma = -math.log(1.0 - alpha) / (2 * r)
    linear = METHODS["box"].evaluate({"alpha": alpha, "z": z, "delta": 0.0, "radius": r})
    ray = dict(zip(("dx", "dy", "dz"), _ray(), strict=True))
    exact = METHODS["exact-box"].evaluate(
        {**ray, "cx": 0.0, "cy": 0.0, "cz": z, "t_surface": z, "radius": r, "sigma": sigma}
    )
    assert linear == pytest.approx(0.475, abs=1e-15)
    assert exact == pytest.approx(1.0 - math.sqrt(0.05), abs=1e-15)  # measured: 1e-16
    assert abs(linear - 0.48) <= 0.0051 and abs(exact - 0.78) <= 0.0051  # the issue rounds to 2 digits
    # the sphere on its axis, cut through the centre: the same half chord
    sph = METHODS["exact-sphere"].evaluate(
        {**ray, "cx": 0.0, "cy": 0.0, "cz": z, "t_surface": z, "radius": r, "sigma": sigma}
    )
    assert sph == pytest.approx(1.0 - math.sqrt(0.05), abs=1e-15)


def test_linear_underestimate_matches_a_grid_search():
    """max_f (1 − (1 − α)^f − α f) by the closed-form stationary point vs a 1e5-point grid (grid spacing
    1e-5: the maximum of a smooth function is found to ~1e-10)."""
    f = np.linspace(0.0, 1.0, 100001)
    for alpha in (0.1, 0.5, 0.95, 0.999):
        gap, f_star = linear_underestimate(alpha)
        g = 1.0 - (1.0 - alpha) ** f - alpha * f
        assert gap == pytest.approx(g.max(), abs=1e-9)
        assert f_star == pytest.approx(f[g.argmax()], abs=2e-5)
        assert np.all(g >= -1e-15)


def test_beer_fraction_closed_form():
    a = np.array([0.0, 0.3, 0.95, 1.0])
    f = np.array([0.5, 0.0, 0.5, 0.5])
    got = np.asarray(beer_fraction(a, f))
    want = 1.0 - (1.0 - np.minimum(a, ALPHA_MAX)) ** f
    assert np.allclose(got, want, rtol=0, atol=1e-7)  # float64 in, float64 Dr.Jit; measured 1e-16


# ----------------------------------------------------------------------------------------- chords
def _chord_by_roots(d, c, ts, r):
    """The sphere chord from the quadratic |t d − c|² = r² solved naively: t = b ± √(b² − |c|² + r²)."""
    b = d @ c
    disc = b * b - c @ c + r * r
    if disc <= 0:
        return 0.0
    t0, t1 = b - math.sqrt(disc), b + math.sqrt(disc)
    return max(min(t1, ts) - max(t0, 0.0), 0.0)


def test_sphere_chord_against_quadratic_roots():
    rng = np.random.default_rng(1)
    for _ in range(300):
        d = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.0])
        d /= np.linalg.norm(d)
        c = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-1, 8)])
        ts, r = rng.uniform(0.1, 10), rng.uniform(0.2, 2.0)
        got = float(sphere_chord(tuple(d), tuple(c), ts, r))
        assert got == pytest.approx(_chord_by_roots(d, c, ts, r), abs=1e-9)  # measured ≤ 4e-15


def test_box_chord_against_a_midpoint_count():
    """The slab chord vs counting 20000 midpoints of [0, t_s] inside the cube (error ≤ 2 steps)."""
    rng = np.random.default_rng(2)
    n, steps = 100, 20000
    d = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), np.ones(n)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.5, 6, n)], -1)
    ts = rng.uniform(0.5, 9.0, n)
    got = np.asarray(box_chord(tuple(d.T), tuple(c.T), ts, 1.0))
    dt = ts / steps
    t = (np.arange(steps) + 0.5)[None, :] * dt[:, None]
    inside = np.max(np.abs(t[..., None] * d[:, None, :] - c[:, None, :]), -1) <= 1.0
    counted = inside.sum(-1) * dt
    assert np.all(np.abs(got - counted) <= 2 * dt)  # measured ≤ 0.9 dt


def test_box_chord_special_cases():
    # on the axis: the full depth 2r; a ray parallel to a slab outside it misses; camera inside: from 0
    assert float(box_chord((0.0, 0.0, 1.0), (0.0, 0.0, 5.0), 1e30, 1.0)) == pytest.approx(2.0)
    assert float(box_chord((0.0, 0.0, 1.0), (1.5, 0.0, 5.0), 1e30, 1.0)) == 0.0
    assert float(box_chord((0.0, 0.0, 1.0), (0.0, 0.0, 0.5), 1e30, 1.0)) == pytest.approx(1.5)
    # off axis through the centre, exiting through the back face: 2r/cos θ
    th = math.radians(30.0)
    d = (math.sin(th), 0.0, math.cos(th))
    c = (10 * math.sin(th), 0.0, 10 * math.cos(th))
    assert float(box_chord(d, c, 1e30, 1.0)) == pytest.approx(2.0 / math.cos(th), rel=1e-12)


def test_off_axis_view_z_loses_cos_theta():
    """Box cut at its centre's depth, the ray through the centre at θ: exact optical depth σ·r/cos θ, the
    view-z methods σ·r (docs: ray length vs view z)."""
    alpha, r = 0.95, 1.0
    sigma = -math.log(1 - alpha) / (2 * r)
    for deg in (0.0, 20.0, 40.0):
        th = math.radians(deg)
        d = _ray(deg)
        c = (10 * math.tan(th), 0.0, 10.0)
        ts = 10.0 / math.cos(th)
        ex = METHODS["exact-box"].evaluate(
            dict(zip(("dx", "dy", "dz"), d, strict=True))
            | {"cx": c[0], "cy": 0.0, "cz": c[2], "t_surface": ts, "radius": r, "sigma": sigma}
        )
        bb = METHODS["box-beer"].evaluate({"alpha": alpha, "z": 10.0, "delta": 0.0, "radius": r})
        assert -math.log1p(-ex) == pytest.approx(sigma * r / math.cos(th), rel=1e-12)
        assert -math.log1p(-bb) == pytest.approx(sigma * r, rel=1e-12)


def test_spherical_billboard_camera_inside_and_billboard_alpha():
    """Camera inside the sphere on its axis: visible chord z + r (clipped at the camera plane)."""
    alpha_c, r = 0.9, 1.0
    for z in (0.1, 0.5, 0.9):
        got = METHODS["spherical"].evaluate(
            {"alpha_c": alpha_c, "z": z, "delta": 100.0, "radius": r, "q": 0.0}
        )
        assert got == pytest.approx(1 - (1 - alpha_c) ** ((z + r) / (2 * r)), abs=1e-14)
    q = np.array([0.0, 0.6, 1.0, 2.0])
    want = 1 - (1 - alpha_c) ** np.sqrt(np.maximum(1 - q**2, 0))
    assert np.allclose(np.asarray(billboard_alpha(np.full(4, alpha_c), np.ones(4), q)), want, atol=1e-14)


def test_fade_extremes():
    lin = METHODS["linear"]
    for s in (1.0, 1e-6, 0.0):
        assert lin.evaluate({"alpha": 0.95, "delta": -1e-3, "radius": 1.0}, {"s": s}) == 0.0
        assert lin.evaluate({"alpha": 0.95, "delta": 0.0, "radius": 1.0}, {"s": s}) == 0.0
    assert lin.evaluate({"alpha": 0.95, "delta": 1e-9, "radius": 1.0}, {"s": 0.0}) == 0.95
    huge = METHODS["exact-sphere"].evaluate(
        {"dx": 0.0, "dy": 0.0, "dz": 1.0, "cx": 0.0, "cy": 0.0, "cz": 4.0, "t_surface": 3.0, "radius": 1.0}
        | {"sigma": 1e38}
    )
    assert huge == 0.0  # ℓ = 0 (surface in front): no 0·∞


# ------------------------------------------------------------------- one text on three libraries; domain
def _draw(data, method):
    x = {}
    for inp in method.inputs:
        lo, hi = inp.domain or (0.0, 1.0)
        x[inp.name] = data.draw(st.floats(lo, hi, allow_nan=False, allow_infinity=False), label=inp.name)
    par = {
        k: data.draw(st.floats(p.lower, min(p.upper, 1e3), allow_nan=False), label=k)
        for k, p in method.params.items()
    }
    return x, par


@pytest.mark.parametrize("mid", list(METHODS))
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_every_method_finite_in_unit_interval(mid, data):
    m = METHODS[mid]
    x, par = _draw(data, m)
    with np.errstate(all="ignore"):
        v = float(m(NUMPY_OPS, {k: np.float64(v) for k, v in x.items()}, par))
        v32 = float(
            m(NUMPY_OPS, {k: np.float32(v) for k, v in x.items()}, {k: np.float32(p) for k, p in par.items()})
        )
    assert 0.0 <= v <= 1.0 and 0.0 <= v32 <= 1.0


@pytest.mark.parametrize("mid", list(METHODS))
def test_drjit_numpy_jax_agree(mid):
    """The same kernel text on Dr.Jit (LLVM, float64), NumPy and JAX (float64)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    m = METHODS[mid]
    rng = np.random.default_rng(4)
    x = {}
    for inp in m.inputs:
        lo, hi = inp.domain or (0.0, 1.0)
        x[inp.name] = rng.uniform(max(lo, -20.0), min(hi, 20.0), 500)
    if "dz" in x:
        d = np.stack([x["dx"], x["dy"], np.abs(x["dz"]) + 0.5], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        x["dx"], x["dy"], x["dz"] = d.T
    with np.errstate(all="ignore"):
        ref = np.asarray(m(NUMPY_OPS, x))
    dj = np.asarray(m.evaluate(x))
    jx = np.asarray(m(jax_ops(), {k: jax.numpy.asarray(v) for k, v in x.items()}))
    assert np.allclose(dj, ref, rtol=0, atol=1e-12)  # measured ≤ 2e-16
    assert np.allclose(jx, ref, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------- Mitsuba reference
@pytest.fixture(scope="module")
def _dirs():
    from rtfit.experiments.soft_particles_kernels import pixel_dirs

    return pixel_dirs((8, 8), 40.0).reshape(-1, 3)


@pytest.mark.parametrize(("shape", "inside"), [("sphere", False), ("box", False), ("sphere", True)])
def test_mitsuba_transmittance_matches_the_analytic_chord(_dirs, shape, inside):
    """volpathmis through an absorbing particle cut by a tilted emitting plane: Bernoulli(T) per sample,
    z-scores against exp(−σℓ) of the analytic chord. Camera inside: the rays start in the medium."""
    from rtfit.experiments.particle_geometry import sigma_of
    from rtfit.experiments.soft_particles_kernels import plane_distance, ray_inputs
    from rtfit.reference.soft_particles import bernoulli_stderr, transmittance_pass_particle

    centre = (0.1, 0.0, 0.6) if inside else (0.2, 0.1, 4.0)
    a = math.radians(35.0)
    normal = np.array([0.0, math.sin(a), -math.cos(a)])
    point = np.asarray(centre) + np.array([0.0, 0.0, 0.15])
    sigma, spp = sigma_of(0.9, 1.0), 1024
    res = transmittance_pass_particle(
        shape, centre, 1.0, sigma, point, normal, _dirs, spp, 3, camera_inside=inside
    )
    ts = plane_distance(_dirs, point, normal)
    exact = np.asarray(METHODS[f"exact-{shape}"](NUMPY_OPS, ray_inputs(_dirs, centre, 1.0, sigma, ts)))
    t = 1.0 - exact
    se = bernoulli_stderr(t, spp)
    ok = se > 0
    assert ok.sum() >= 16
    z = (res.mean[ok, 0] - t[ok]) / se[ok]
    assert np.max(np.abs(z)) < 4.5  # Šidák 1 % over 64 pixels: 3.8; measured ≤ 2.9
    assert abs(z.sum() / math.sqrt(z.size)) < 4.0
    assert np.all(res.mean[~ok, 0] == t[~ok])


def test_study_claim_and_extreme_checks_pass():
    """The study's own claim and extreme checks (kernel-only; the whole study with its JAX fits runs in
    `test_run_soft_particles_is_the_engine_on_its_shipped_scenes_plus_the_study`)."""
    from rtfit.experiments.soft_particles_kernels import claim_checks, extreme_checks, extreme_values

    checks = claim_checks() + extreme_checks(extreme_values())
    failed = [c.name for c in checks if not c.passed]
    assert not failed, failed
    assert len(checks) == 10


def test_fitted_file_loads_and_its_shaders_reproduce_the_kernel(tmp_path):
    """fitted/soft-particles-domain.json (the study's domain fits): strict load, and the traced GLSL/HLSL of
    the fitted fade equals the kernel text's NumPy run (float32 shader vs float64: rtol 2e-6)."""
    from rtfit.experiments import fitted as fitfiles
    from rtfit.experiments.fitted import load_fitted
    from rtfit.experiments.soft_particles_study import write_fitted

    from .test_shader import compile_function

    def fit(values, method):
        params = {
            k: {"value": v, "stderr": 1e-3, "lower": method.params[k].lower, "upper": method.params[k].upper}
            | {"at_bound": False}
            for k, v in values.items()
        }
        return {"parameters": params, "rms_residual": 0.01, "n_residuals": 100, "dof": 97, "converged": True}

    fits = {
        ("sphere", "linear-fit", 0.95): fit({"s": 0.5}, METHODS["linear"]),
        ("sphere", "fitted", 0.95): fit({"s": 1.2, "b": 0.68, "p": 0.71}, METHODS["fitted"]),
    }
    prov = fitfiles.provenance(None, "soft-particles", [], variant="llvm_ad_rgb", quick=True)
    assert write_fitted(tmp_path, fits, prov) == "fitted/soft-particles-domain.json"
    loaded = load_fitted(tmp_path / "fitted" / "soft-particles-domain.json")
    (entry,) = [m for m in loaded.methods if m.id == "fitted"]
    assert entry.parameters["p"].unit == "1" and entry.parameters["s"].unit == "r"
    rng = np.random.default_rng(8)
    a, d, r = (rng.uniform(0, 1, 200), rng.uniform(-2, 2, 200), rng.uniform(0.2, 2, 200))
    ref = METHODS["fitted"](
        NUMPY_OPS, {"alpha": a, "delta": d, "radius": r}, {"s": 1.2, "b": 0.68, "p": 0.71}
    )
    assert entry.shader is not None and entry.shader.arguments == ["alpha", "delta", "radius"]
    for lang in ("glsl", "hlsl"):
        got = compile_function(getattr(entry.shader, lang))(*(x.astype(np.float32) for x in (a, d, r)))
        np.testing.assert_allclose(got, ref, rtol=2e-6, atol=1e-6)


def test_public_opacity_function_and_bad_method():
    from rtfit.realtime import soft_particle_opacity

    got = soft_particle_opacity("box", {"alpha": 0.95, "z": 4.0, "delta": 0.0, "radius": 1.0})
    assert got == pytest.approx(0.475, abs=1e-15)
    with pytest.raises(ValueError, match="unknown soft-particle method 'nope'"):
        soft_particle_opacity("nope", {})
    with pytest.raises(ValueError, match="alpha"):
        beer_fraction(1.5, 0.5)


# ------------------------------------------------------------ rtfit run soft-particles: engine + study
def _hand_chord(d: np.ndarray, shape: str, centre, sigma: float, tilt_deg: float = 35.0) -> np.ndarray:
    """Opacity 1 − exp(−σℓ) of the unit rays ``d`` from the origin through the unit sphere / the cube
    [−1, 1]³ at ``centre``, clipped by the plane through centre + (0, 0, 0.15) of normal (0, sin t, −cos t):
    the quadratic's roots or the slab test, written here."""
    c = np.asarray(centre, np.float64)
    a = math.radians(tilt_deg)
    n = np.array([0.0, math.sin(a), -math.cos(a)])
    dn = d @ n
    point = c + np.array([0.0, 0.0, 0.15])
    t_s = np.where(np.abs(dn) > 1e-12, (point @ n) / np.where(np.abs(dn) > 1e-12, dn, 1), -1)
    t_s = np.where(t_s > 0, t_s, np.inf)
    if shape == "sphere":
        b = d @ c
        disc = b * b - (c @ c - 1.0)
        w = np.sqrt(np.maximum(disc, 0.0))
        t0, t1 = np.where(disc > 0, b - w, np.inf), np.where(disc > 0, b + w, -np.inf)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            lo, hi = (c - 1.0) / d, (c + 1.0) / d
        t0, t1 = np.max(np.minimum(lo, hi), axis=1), np.min(np.maximum(lo, hi), axis=1)
    chord = np.maximum(np.minimum(t1, t_s) - np.maximum(t0, 0.0), 0.0)
    return -np.expm1(-sigma * chord)


def test_run_soft_particles_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path, monkeypatch):
    """``rtfit run soft-particles`` = the engine's audits of the shipped scenes + the study
    (`soft_particles_study.study`), on the quick sphere and cube (12² pixels, 256 spp) as the engine hands
    them over, the study's domain shrunk. Independent values: each scene's σ gives its α_c = 1 − e^(−2σ);
    the exact rows equal the clipped chords written here (quadratic, slab test, the tilted plane), and the
    reference's z statistics against them are the study's."""
    import xml.etree.ElementTree as ET

    from rtfit.experiments import audit_soft_particles, soft_particles_study
    from rtfit.experiments.audit_run import audit
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["soft-particles"]
    assert fam.module == ENGINE and fam.scenes == audit_soft_particles.SCENES
    assert fam.study.target is soft_particles_study.study
    shipped = {s.name: s for s in audit_soft_particles.SCENES}
    assert {n for n, s in shipped.items() if s.quick} == {"sphere-a0p95", "box-a0p95", "sphere-a0p95-inside"}
    for s in shipped.values():
        alpha = float(s.name.split("-a")[1].split("-")[0].replace("p", "."))
        assert -math.expm1(-2.0 * float(s.defines["sigma"])) == pytest.approx(alpha, rel=1e-12)
        defaults = {e.get("name") for e in ET.parse(LIBRARY_DIR / s.file).getroot().iter("default")}
        assert set(s.defines) <= defaults
    names = ("sphere-a0p95", "box-a0p95")
    audits = tuple(
        audit(LIBRARY_DIR / shipped[n].file, ["soft-particles"], spp=256, width=12, height=12,
              cache=tmp_path / "cache", tag=(f"{n}-", f"{n}: "), metrics=("rmse",),
              defines=dict(shipped[n].defines))
        for n in names
    )  # fmt: skip
    spreads = {}
    for n, r in zip(names, audits, strict=True):
        (case,) = r.cases
        shape = case.parameters["shape"]
        inp = case.channel_inputs[0]
        # the exact kernels' rays in the unit shape's frame: for the cube a signed permutation A of the
        # world axes (its faces' order), recovered from the centre c_local = Aᵀ(0.3, 0.2, 4)
        c_local = np.array([inp["cx"][0], inp["cy"][0], inp["cz"][0]])
        b = np.array([0.3, 0.2, 4.0])
        perm = np.array(
            [[round(ci / bj) if abs(abs(ci) - abs(bj)) < 1e-5 else 0 for ci in c_local] for bj in b]
        )
        assert sorted(np.abs(perm).sum(axis=0)) == [1, 1, 1]
        d = np.stack([inp["dx"], inp["dy"], inp["dz"]], axis=1) @ perm.T  # world rays
        want = _hand_chord(d, shape, (0.3, 0.2, 4.0), float(shipped[n].defines["sigma"]))
        assert case.parameters["cut_pixels"] > 20
        assert np.allclose(r.image(case.id, f"exact-{shape}")[case.mask][:, 0], want, atol=3e-6)
        ref, t = case.reference.mean[case.mask][:, 0], 1.0 - want
        ok = t * (1 - t) > 0
        spreads[case.id] = np.std((ref[ok] - want[ok]) / np.sqrt(t[ok] * (1 - t[ok]) / 256))
    small = {"fit_alphas": (0.95,), "samples": 600, "scene": (24, 16)}
    monkeypatch.setitem(soft_particles_study.DOMAIN, True, small)
    res = soft_particles_study.study(
        StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", audits)
    )
    failed = [c.name for c in res.checks if not c.passed]
    assert not failed, failed
    for cid, spread in spreads.items():
        (chk,) = [c for c in res.checks if c.name.startswith(f"reference {cid}") and "spread" in c.name]
        assert chk.value == pytest.approx(spread, rel=1e-4)
    assert {f.file for f in res.figures} == {"figures/scene-100.png", "figures/error_vs_delta.png"}
    assert all((tmp_path / f.file).is_file() for f in res.figures)
    assert (tmp_path / "fitted" / "soft-particles-domain.json").is_file()
    assert {t["method"] for t in res.extra["domain_study"]} >= {"linear", "linear-fit", "spherical", "fitted"}


def test_audit_list_names_soft_particles_on_the_shipped_scenes():
    """``rtfit audit SCENE -D … --list`` on each shipped file with a scene's defines names the family."""
    from click.testing import CliRunner

    from rtfit.experiments.audit_cli import audit as audit_cli
    from rtfit.experiments.audit_soft_particles import SCENES
    from rtfit.scenes.parse import LIBRARY_DIR

    for s in (SCENES[1], SCENES[2]):  # the cube; the sphere around the camera
        args = [
            str(LIBRARY_DIR / s.file),
            "--list",
            *(x for k, v in s.defines.items() for x in ("-D", f"{k}={v}")),
        ]
        result = CliRunner().invoke(audit_cli, args)
        assert result.exit_code == 0, result.output
        assert "soft-particles — particle opacity: homogeneous medium in a" in result.stdout
