"""Obscurances (rtfit.realtime.obscurances, the obscurance/ambient_global references): closed-form and
quadrature oracles, limits, the extremes of the domain, and the Mitsuba estimators on a plane."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.special import expn

from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS, jax_ops
from rtfit.realtime.obscurances import (
    METHODS,
    cosine_spiral_directions,
    obscurance,
    plane_facing_obscurance,
    power_obscurance_kernel,
)


# ------------------------------------------------------------------------------------------- oracles
def _rho_oracle(d, d_max, p, form):
    """ρ written from the definitions (001:3284 generalised), scalar."""
    if form == "power":
        return 1.0 if d >= d_max else (d / d_max) ** p
    if form == "exponential":
        return 1.0 - math.exp(-d / d_max)
    return 1.0 if d >= d_max else 0.0


def _facing_quadrature(h, d_max, p, form):
    """W = 2 ∫₀¹ ρ(h/μ) μ dμ (point facing an infinite plane) by adaptive quadrature, kink at μ = h/d_max."""
    pts = [h / d_max] if 0 < h / d_max < 1 else None
    val, _ = quad(
        lambda mu: 2.0 * mu * _rho_oracle(h / mu, d_max, p, form),
        1e-300,
        1.0,
        points=pts,
        epsabs=1e-13,
        epsrel=1e-12,
        limit=200,
    )
    return val


@pytest.mark.parametrize("form", ["power", "exponential", "step"])
@pytest.mark.parametrize("h", [0.01, 0.1, 0.29, 0.3, 0.5])
@pytest.mark.parametrize("p", [0.25, 0.5, 1.0, 2.0, 3.0])
def test_plane_facing_closed_form_matches_quadrature(form, h, p):
    # measured max |difference| 2.2e-16 (float64 round-off)
    if form != "power" and p != 0.5:
        return
    got = plane_facing_obscurance(h, 0.3, p, form)
    assert got == pytest.approx(_facing_quadrature(h, 0.3, p, form), abs=1e-10)


def test_exponential_closed_form_is_one_minus_two_e3():
    # 1 − 2E₃(b) → 1 as b → ∞ and → 0 as b → 0 (E₃(0) = ½)
    assert plane_facing_obscurance(1e-9, 1.0, form="exponential") == pytest.approx(0.0, abs=1e-8)
    assert plane_facing_obscurance(50.0, 1.0, form="exponential") == pytest.approx(1.0, abs=1e-20)
    assert 1 - 2 * expn(3, 0.7) == pytest.approx(plane_facing_obscurance(0.7, 1.0, form="exponential"))


@pytest.mark.parametrize("form", ["power", "exponential", "step"])
def test_kernel_on_spiral_distances_converges_to_closed_form(form):
    """The estimator on the exact distances d_k = h/μ_k of K spiral directions: a midpoint rule in r² (μ² is
    uniform under cos/π) — converges to the closed form (K = 1024: 16 launches of `RAY_CHUNK` rays). Measured
    |error|: power 3.7e-8, exponential 5.3e-9, step 1.6e-4 (the jump at μ = h/d_max: ≤ 1/K)."""
    h, d_max = 0.12, 0.3
    mu = cosine_spiral_directions(1024)[:, 2]
    d = (h / mu)[:, None]
    got = float(obscurance(d, d_max, 0.5, form)[0])
    assert got == pytest.approx(plane_facing_obscurance(h, d_max, 0.5, form), abs=2.5e-4)


# ---------------------------------------------------------------------------------------------- limits
def test_limits_and_identities():
    rng = np.random.default_rng(3)
    d = rng.exponential(0.5, (32, 200))
    d[rng.random(d.shape) < 0.3] = np.inf
    escaped = np.mean(np.isinf(d), axis=0)
    rows = list(d)
    # d_max → ∞: W → fraction of escaping rays (AO with R = ∞), power (p fixed) and exponential
    w = power_obscurance_kernel(NUMPY_OPS, rows, d_max=1e30, exponent=0.5)
    assert np.max(np.abs(w - escaped)) < 1e-13  # measured 4e-15 (√(d/1e30) ≤ 1e-15 per ray)
    w = METHODS["exponential"].kernel(NUMPY_OPS, rows, d_max=1e30)
    assert np.max(np.abs(w - escaped)) < 1e-28
    # d_max → 0 or p = 0: W = 1
    assert np.all(power_obscurance_kernel(NUMPY_OPS, rows, d_max=1e-30, exponent=0.5) == 1.0)
    assert np.all(power_obscurance_kernel(NUMPY_OPS, rows, d_max=0.3, exponent=0.0) == 1.0)
    # p → ∞: the step (AO within d_max); ρ_power ≥ ρ_step always
    step = METHODS["ao"].kernel(NUMPY_OPS, rows, d_max=0.3)
    big = power_obscurance_kernel(NUMPY_OPS, rows, d_max=0.3, exponent=1e5)
    assert np.max(np.abs(big - step)) < 1e-3
    for p in (0.1, 0.5, 2.0, 8.0):
        assert np.all(power_obscurance_kernel(NUMPY_OPS, rows, d_max=0.3, exponent=p) >= step)
    # the open plane: every ray escapes → exactly 1
    assert np.all(obscurance(np.full((8, 5), np.inf)) == 1.0)
    # inside a sphere at its centre: ρ(R) exactly
    assert obscurance(np.full((8, 1), 0.2), 0.3, 0.5)[0] == pytest.approx(math.sqrt(2 / 3), rel=1e-12)


def test_monotone_in_d_max_and_exponent():
    d = np.random.default_rng(5).exponential(0.4, (16, 300))
    ws = [obscurance(d, dm, 0.5) for dm in (0.05, 0.1, 0.3, 1.0, 10.0)]
    assert all(np.all(a >= b - 1e-15) for a, b in itertools.pairwise(ws))
    ws = [obscurance(d, 0.3, p) for p in (0.0, 0.25, 0.5, 1.0, 4.0)]
    assert all(np.all(a >= b - 1e-15) for a, b in itertools.pairwise(ws))


# ---------------------------------------------------------------------------------------- the extremes
DIST = st.one_of(
    st.sampled_from([0.0, 0.3, 1e-30, 1e30, math.inf, 1e-7, 5e-324]),
    st.floats(0.0, 1e6, allow_nan=False, allow_infinity=False),
)


@settings(max_examples=50, deadline=None)
@given(
    d=st.lists(DIST, min_size=1, max_size=6),
    d_max=st.one_of(st.sampled_from([0.3, 1e-3, 1e30, 1e-30]), st.floats(1e-6, 1e6)),
    p=st.one_of(st.sampled_from([0.0, 0.5, 16.0]), st.floats(0.0, 64.0)),
)
def test_no_nan_inf_anywhere(d, d_max, p):
    """NumPy run of every kernel over the whole domain: finite, in [0, 1], no warnings (pytest errors)."""
    rows = [np.array([x]) for x in d]
    for mid, kw in (
        ("power", {"d_max": d_max, "exponent": p}),
        ("exponential", {"d_max": d_max}),
        ("ao", {"d_max": d_max}),
    ):
        w = METHODS[mid].kernel(NUMPY_OPS, rows, **kw, scale=1.0)
        assert np.all(np.isfinite(w)) and np.all((w >= 0) & (w <= 1))
        assert np.all(np.isfinite(METHODS[mid].kernel(NUMPY_OPS, np.array(d)[:, None], **kw, scale=1.0)))


# every extreme combination at once: 8 distances × 6 d_max × 5 exponents
_D = np.array([0.0, 5e-324, 1e-30, 0.3, 1.0, 1e6, 1e30, math.inf])
_DM = np.array([1e-30, 1e-3, 0.3, 1.0, 1e3, 1e30])
_P = np.array([0.0, 0.01, 0.5, 2.0, 64.0])
_GRID = np.stack(np.meshgrid(_D, _DM, _P, indexing="ij"), axis=0).reshape(3, -1)


def test_drjit_and_numpy_runs_agree_at_the_extremes():
    """One Dr.Jit float64 launch per kernel over the grid: equal to the NumPy run (measured max relative
    difference 2e-16). Subnormal distances are left out: Dr.Jit's LLVM backend flushes them to 0."""
    import drjit as dr

    d, dm, p = _GRID[:, _GRID[0] != 5e-324]
    for mid, kw in (
        ("power", {"d_max": dm, "exponent": p}),
        ("exponential", {"d_max": dm}),
        ("ao", {"d_max": dm}),
    ):
        ref = METHODS[mid].kernel(NUMPY_OPS, [d], **kw, scale=1.0)
        got = METHODS[mid].kernel(
            DRJIT_OPS, [dr.llvm.Float64(d)], **{k: dr.llvm.Float64(v) for k, v in kw.items()}, scale=1.0
        )
        assert np.all(np.isfinite(ref))
        np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-12, atol=1e-300)


def test_jax_values_and_fit_derivatives_are_finite_at_the_extremes():
    """The fits' run (JAX, misses as 1e30 as the experiment passes them): values equal NumPy's, gradients
    with respect to d_max, p and s finite everywhere on the grid (d_max within its fit bounds). Subnormal
    distances are left out of the value comparison: XLA on the CPU flushes them to 0."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    d, dm, p = _GRID[:, _GRID[0] != 5e-324]
    d = np.minimum(d, 1e30)
    dm = np.clip(dm, 1e-3, 1e3)
    jd = jnp.asarray(d)[None, :]

    def power(q):
        return jnp.sum(power_obscurance_kernel(jax_ops(), jd, d_max=q[0], exponent=q[1], scale=q[2]))

    def expo(q):
        return jnp.sum(METHODS["exponential"].kernel(jax_ops(), jd, d_max=q[0], scale=q[1]))

    q = jnp.asarray(np.stack([dm, p, np.ones_like(p)]))
    np.testing.assert_allclose(
        float(power(q)),
        float(np.sum(power_obscurance_kernel(NUMPY_OPS, d[None, :], d_max=dm, exponent=p))),
        rtol=1e-12,
    )
    assert np.all(np.isfinite(np.asarray(jax.grad(power)(q))))
    assert np.all(np.isfinite(np.asarray(jax.grad(expo)(q[::2]))))


def test_bad_input_is_one_clear_error():
    with pytest.raises(ValueError, match="d_max"):
        obscurance(np.ones((2, 2)), d_max=0.0)
    with pytest.raises(ValueError, match="exponent"):
        obscurance(np.ones((2, 2)), exponent=-1.0)
    with pytest.raises(ValueError, match="distances"):
        obscurance(np.array([[np.nan]]))
    with pytest.raises(ValueError, match="form"):
        obscurance(np.ones((2, 2)), form="cubic")


# ------------------------------------------------------------------------------------------- Mitsuba
@pytest.fixture(scope="module")
def plane():
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    scene = mi.load_dict(
        {
            "type": "scene",
            "r": {
                "type": "rectangle",
                "bsdf": white,
                "to_world": mi.ScalarTransform4f().scale([5000.0, 5000.0, 1.0]),
            },
        }
    )
    return mi, scene


def test_hit_distances_facing_a_plane_are_h_over_mu(plane):
    """Noise-free: every ray of the spiral set from height h, normal down, hits at h/μ; the per-point
    rotation leaves μ unchanged."""
    from rtfit.reference.occlusion import hit_distances

    mi, scene = plane
    dirs = cosine_spiral_directions(64)
    h = np.array([0.05, 0.2, 1.0])
    pts = np.column_stack([np.zeros(3), np.zeros(3), h])
    nrm = np.tile([0.0, 0.0, -1.0], (3, 1))
    d = hit_distances(mi, scene, pts, nrm, dirs, rotate_seed=7)
    # d·μ is h less the spawn offset along n, (1 + max|p|)·8.9e-5: measured max |d·μ − h| 1.8e-4 (h = 1)
    np.testing.assert_allclose(d * dirs[:, 2:3], np.broadcast_to(h, d.shape), atol=3e-4)
    up = hit_distances(mi, scene, pts * [1, 1, 0], -nrm, dirs)
    assert np.all(np.isinf(up))


def test_mitsuba_obscurance_and_uniform_ambient_match_closed_forms(plane, tmp_path):
    """Reference (a) facing the plane vs the closed form, and reference (b) (uniform ambient, albedo a)
    facing the plane = a: |z| ≤ 4 (measured max 1.6 at 2^14 samples); an open plane gives exactly 1."""
    from rtfit.experiments.obscurances_study import spawn_height
    from rtfit.realtime.obscurances import distance_weight as weight_of
    from rtfit.reference.occlusion import OcclusionCache

    mi, scene = plane
    cache = OcclusionCache(tmp_path)
    h = np.array([0.05, 0.15, 0.3])
    pts = np.column_stack([np.zeros(3), np.zeros(3), h])
    nrm = np.tile([0.0, 0.0, -1.0], (3, 1))
    kw = dict(spp=1 << 14, pass_spp=1 << 13, seed=1, variant="llvm_ad_rgb")
    for form, p in (("power", 0.5), ("exponential", None)):
        fn, key = weight_of(form, 0.3, p)
        r = cache.get(
            mi, scene, "plane", pts, nrm, quantity="obscurance", distance_weight=fn, weight_key=key, **kw
        )
        expect = np.array([plane_facing_obscurance(spawn_height(x), 0.3, p, form) for x in h])
        assert np.max(np.abs(r.mean - expect) / r.stderr) < 4.0
    r = cache.get(mi, scene, "plane", pts, nrm, quantity="ambient_global", albedo=0.6, **kw)
    assert np.max(np.abs(r.mean - 0.6) / r.stderr) < 4.0
    fn, key = weight_of("power", 0.3, 0.5)
    r = cache.get(
        mi,
        scene,
        "plane",
        pts * [1, 1, 0],
        -nrm,
        quantity="obscurance",
        distance_weight=fn,
        weight_key=key,
        **kw,
    )
    assert np.all(r.mean == 1.0) and np.all(r.stderr == 0.0)


# ------------------------------------------------------------------ rtfit run obscurances: engine + study
def _perpendicular_plane_obscurance(h: float, radius: float, p: float = 0.5) -> float:
    """W of a point at distance h from a plane perpendicular to its own surface (the 90° crease: a floor
    point facing +z, the wall x = 0 at distance h), ρ = min(d/R, 1)^p, by scipy quadrature over the
    hemisphere: a ray towards the wall with t = −ω_x hits it at d = h/t; only d < R (t > h/R) lowers W."""
    from scipy.integrate import dblquad

    def integrand(phi, theta):
        t = -math.sin(theta) * math.cos(phi)
        if t <= h / radius:
            return 0.0
        return (1.0 - (h / (t * radius)) ** p) * math.cos(theta) * math.sin(theta)

    lost, _ = dblquad(integrand, 0.0, math.pi / 2, math.pi / 2, 3 * math.pi / 2, epsabs=1e-10)
    return 1.0 - lost / math.pi


def test_run_obscurances_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path):
    """``rtfit run obscurances`` = the engine's audit of the shipped sdf-occlusion scenes + the study, on the
    90° crease (14² pixels, 256 spp) as the engine hands it over. Independent values: on the crease's inner
    faces (away from its ends, where nothing within R = 0.3 is missing) W is a function of the distance to
    the other face alone, by scipy quadrature (`_perpendicular_plane_obscurance`): the engine's model
    reference matches it (|z| < 5) and the rows' 32-ray estimator is unbiased for it."""
    from rtfit.experiments import audit_obscurances, obscurances_study
    from rtfit.experiments.audit_run import audit
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["obscurances"]
    assert fam.module == ENGINE and fam.scenes == audit_obscurances.SCENES
    assert fam.study.target is obscurances_study.study
    assert all((LIBRARY_DIR / s.file).is_file() for s in fam.scenes)
    shipped = {s.name: s for s in fam.scenes}
    assert [s.name for s in fam.scenes if s.quick] == [
        "sdf_crease_90",
        "sdf_sphere_plane",
        "sdf_room",
        "sdf_boxes",
    ]
    s = shipped["sdf_crease_90"]
    res = audit(LIBRARY_DIR / s.file, ["obscurances"], spp=256, width=14, height=14, cache=tmp_path / "c",
                tag=("sdf_crease_90-", ""), metrics=("rmse",), **dict(s.options))  # fmt: skip
    ctx = StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "c", (res,))
    (sc,) = obscurances_study.scene_cases(ctx.audits)
    assert sc.radius == pytest.approx(0.3)
    with obscurances_study._visible_points(sc, "llvm_ad_rgb") as (_mi, _scene, pts, nrm):
        pts, nrm = np.array(pts), np.array(nrm)
    floor = (nrm[:, 2] > 0.99) & (pts[:, 0] > 0.01) & (pts[:, 0] < 1.6) & (np.abs(pts[:, 1]) < 0.6)
    wall = (nrm[:, 0] > 0.99) & (pts[:, 2] > 0.01) & (pts[:, 2] < 1.6) & (np.abs(pts[:, 1]) < 0.6)
    pick = np.flatnonzero(floor | wall)
    assert pick.size >= 20
    h = np.where(floor, pts[:, 0], pts[:, 2])[pick]
    expect = np.array([_perpendicular_plane_obscurance(x, 0.3) for x in h])
    assert expect.min() < 0.95  # some points see the other face within R
    ref = sc.model.reference.mean[sc.mask][:, 0][pick]
    err = sc.model.reference.stderr[sc.mask][:, 0][pick]
    z = (ref - expect) / np.sqrt(err**2 + 1e-6**2)
    assert np.max(np.abs(z)) < 5.0, z
    study = obscurances_study.study(ctx)
    assert all(ch.passed for ch in study.checks), study.checks
    rays = study.extra["rays"]["sdf_crease_90"]
    assert set(rays) == {str(k) for k in obscurances_study.RAYS_QUICK}
    assert rays["64"]["rmse"] < rays["4"]["rmse"]
    assert {f.file for f in study.figures} == {"figures/rays_error.png", "figures/rays_cost.png"}
    assert all((tmp_path / f.file).is_file() for f in study.figures)
    assert (tmp_path / study.extra["joint_fits_file"]).is_file()
    # the rows' 32 distances on the picked points: the seed estimator's mean against the quadrature
    seed = obscurances_study._eval("power", sc.distances()[:, pick], {"d_max": 0.3, "exponent": 0.5})
    diff = seed - expect
    assert abs(diff.mean()) < 4 * diff.std(ddof=1) / math.sqrt(diff.size) + 1e-3


def test_a_fit_keeps_the_ray_mean_where_only_the_scale_moves(monkeypatch):
    """The NumPy run keeps each form's ray mean by (ρ, d_max, p) and distance arrays (`_kept_mean`): a mean
    asked for again with only the scale s changed is not computed again, every kernel value is the fresh
    computation's bit for bit, and a TRF fit ends where the same fit without the memo ends, bit for bit."""
    from rtfit.fitting import fit_method
    from rtfit.realtime import obscurances as ob

    rng = np.random.default_rng(5)
    n, k = 600, 8
    d = tuple(np.where(rng.random(n) < 0.3, 1e30, rng.exponential(2.0, n)) for _ in range(k))
    calls = []

    def counted(ops, dd, d_max, p):
        calls.append(d_max)
        return rho(ops, dd, d_max, p)

    rho = ob.rho_power
    monkeypatch.setattr(ob, "rho_power", counted)
    ob._KEPT_MEANS.clear()
    a = power_obscurance_kernel(NUMPY_OPS, d, 1.5, 0.7, 1.0)
    b = power_obscurance_kernel(NUMPY_OPS, d, 1.5, 0.7, 0.8)
    assert len(calls) == k  # the second call, s alone changed, reused the mean
    fresh = sum(((np.minimum(x, 1.5) / 1.5) ** 0.7 for x in d), np.zeros(n)) / k
    np.testing.assert_allclose(a, fresh, rtol=1e-13)
    assert np.array_equal(b, 0.8 * (a / 1.0))
    monkeypatch.setattr(ob, "rho_power", rho)

    from rtfit.experiments.audit_obscurances import on_rays

    method = on_rays(METHODS["power"], k)
    inputs = {f"d{i + 1}": d[i] for i in range(k)}
    y = power_obscurance_kernel(NUMPY_OPS, d, 2.2, 0.6, 0.9) + rng.normal(0.0, 0.01, n)
    kept = fit_method(method, inputs, y, solver="trf")
    monkeypatch.setattr(ob._KEPT_MEANS, "get", lambda ops, key, arrays, make: make(False))
    unkept = fit_method(method, inputs, y, solver="trf")
    assert kept.values == unkept.values and kept.ssr == unkept.ssr and kept.steps == unkept.steps
