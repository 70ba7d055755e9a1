"""rtfit.realtime.irradiance_bases against independent values: R&H closed forms, scipy quadrature and
Dr.Jit's sh_eval; the method table; the dispatched run of each basis against its NumPy text."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import irradiance_bases as ir


def _theta_normals(theta):
    return np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=-1)


def test_rh_closed_form_unit_directional_light():
    theta = np.linspace(0.0, math.pi, 37)
    c = np.cos(theta)
    coeffs = ir.sh9_from_directional([0.0, 0.0, 1.0])
    l2 = ir.sh9_irradiance(coeffs, _theta_normals(theta))
    l1 = ir.sh4_irradiance(coeffs, _theta_normals(theta))
    want2 = 0.25 + c / 2 + (5.0 / 16.0) * (3 * c * c - 1) / 2
    np.testing.assert_allclose(l2, np.repeat(want2[:, None], 3, 1), atol=1e-12)
    np.testing.assert_allclose(l1, np.repeat((0.25 + c / 2)[:, None], 3, 1), atol=1e-12)


def test_basis_matches_drjit_sh_eval_up_to_condon_shortley():
    import drjit as dr
    from drjit.scalar import Array3f

    rng = np.random.default_rng(1)
    for d in rng.normal(size=(5, 3)):
        d /= np.linalg.norm(d)
        ours = ir.sh9_basis(d)
        theirs = np.array(dr.sh_eval(Array3f(*d.tolist()), 2))
        sign = np.array([1, -1, 1, -1, 1, -1, 1, -1, 1])  # (−1)^m for m = −l..l
        np.testing.assert_allclose(ours, sign * theirs, atol=2e-6)


def test_basis_orthonormal_by_scipy_quadrature():
    def g(i, j):
        def f(ph, th):
            d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
            return ir.sh9_basis(d)[[i, j]].prod() * math.sin(th)

        return integrate.dblquad(f, 0, math.pi, 0, 2 * math.pi, epsabs=1e-9)[0]

    for i, j in ((0, 0), (3, 3), (6, 6), (8, 8), (1, 3), (4, 8)):
        assert g(i, j) == pytest.approx(1.0 if i == j else 0.0, abs=1e-7)


def test_constant_environment_projects_to_dc_only_and_cube_is_exact():
    img = np.full((16, 32, 3), 2.0)
    c = ir.sh_project_latlong(img, 4)
    assert c[0, 0] == pytest.approx(2.0 * math.sqrt(4 * math.pi), rel=2e-3)
    assert np.all(np.abs(c[1:]) < 1e-3 * c[0, 0])
    n = ir.fibonacci_sphere(50)
    cube = np.full((6, 3), 2.0 * math.pi)
    np.testing.assert_allclose(ir.ambient_cube_irradiance(cube, n), 2.0 * math.pi, rtol=1e-12)


def test_disk_sun_sh_matches_scipy_projection():
    alpha = math.radians(20.0)
    d = np.array([0.3, -0.4, 0.866])
    d /= np.linalg.norm(d)
    want = ir.sh9_from_disk(d, alpha, 1.0)
    radiance = 1.0 / (math.pi * math.sin(alpha) ** 2)
    t = np.cross([0, 0, 1.0], d)
    t /= np.linalg.norm(t)
    b = np.cross(d, t)
    for k in (0, 2, 3, 6, 8):

        def f(ph, g, k=k):
            return (
                ir.sh9_basis(math.cos(g) * d + math.sin(g) * (math.cos(ph) * t + math.sin(ph) * b))[k]
                * math.sin(g)
                * radiance
            )

        assert integrate.dblquad(f, 0, alpha, 0, 2 * math.pi, epsabs=1e-10)[0] == pytest.approx(
            want[k], abs=1e-7
        )


def test_rotation_of_environment_rotates_reconstruction():
    # a smooth lobe rotated by 90° about z (u shift by W/4) gives the reconstruction rotated by 90°.
    h, w = 32, 64
    u = (np.arange(w) + 0.5) / w
    v = np.arange(h) / (h - 1)
    d = ir.latlong_directions(*np.meshgrid(u, v))
    axis = np.array([0.6, 0.0, 0.8])
    img = np.repeat(np.exp(4 * (d @ axis))[..., None], 3, axis=2)
    rolled = np.roll(img, w // 4, axis=1)  # φ → φ + 90°: (x, y) → (y·…) a rotation about +z
    n = ir.fibonacci_sphere(64)
    rot = np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1.0]])  # direction d in img ↦ d' in rolled
    e1 = ir.sh9_irradiance(ir.sh_project_latlong(img), n)
    e2 = ir.sh9_irradiance(ir.sh_project_latlong(rolled), n @ rot.T)
    np.testing.assert_allclose(e1, e2, rtol=1e-9, atol=1e-9 * e1.max())


def test_nnls_recovers_known_cube():
    rng = np.random.default_rng(7)
    cube = rng.uniform(0.0, 3.0, (6, 3))
    cube[2, 1] = 0.0
    n = ir.fibonacci_sphere(300)
    e = ir.ambient_cube_irradiance(cube, n)
    fit, rms = ir.fit_ambient_cube_nnls(n, e)
    np.testing.assert_allclose(fit, cube, atol=1e-9)
    assert np.all(rms < 1e-9)


def test_valve_cube_exact_at_axes_and_seed_listing():
    cube = np.arange(18.0).reshape(6, 3)
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    np.testing.assert_allclose(ir.ambient_cube_irradiance(cube, axes), cube)
    n = np.array([1.0, -1.0, 1.0]) / math.sqrt(3)  # between the axes: mean of +x, −y, +z
    np.testing.assert_allclose(ir.ambient_cube_irradiance(cube, n), (cube[0] + cube[3] + cube[4]) / 3)


def test_windows_and_lambda_removes_ringing():
    np.testing.assert_allclose(ir.sh_window("hann"), [1.0, 0.75, 0.25])
    np.testing.assert_allclose(
        ir.sh_window("lanczos"),
        [1.0, math.sin(math.pi / 3) / (math.pi / 3), math.sin(2 * math.pi / 3) / (2 * math.pi / 3)],
    )
    c = ir.sh9_from_directional([0.2, 0.3, 0.9])
    lam = ir.fit_window_lambda(c)
    assert lam > 0
    e = ir.sh9_irradiance(c, ir.fibonacci_sphere(20000), ir.sh_window("lambda", 2, lam))
    assert e.min() >= 0.0
    e_less = ir.sh9_irradiance(c, ir.fibonacci_sphere(20000), ir.sh_window("lambda", 2, 0.9 * lam))
    assert e_less.min() < 0.0  # smallest λ: a bit less rings again


def test_geomerics_keeps_mean_and_is_non_negative():
    c = ir.sh9_from_directional([0.0, 0.6, 0.8])[:, None] + np.array([0.1] + [0.0] * 8)[:, None] * np.ones(3)
    n = ir.fibonacci_sphere(20000)
    e = ir.sh4_irradiance_geomerics(c, n)
    assert e.min() >= 0
    np.testing.assert_allclose(e.mean(axis=0), ir.A_HAT[0] * ir.SH_C[0] * c[0], rtol=2e-3)


def test_bad_input_and_extremes():
    c = ir.sh9_from_directional([0, 0, 1])
    with pytest.raises(ValueError, match="normal"):
        ir.sh9_irradiance(c, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="normal"):
        ir.ambient_cube_irradiance(np.ones((6, 3)), np.array([[np.nan, 0, 1]]))
    with pytest.raises(ValueError, match="coeffs"):
        ir.sh9_irradiance(np.ones((5, 3)), [0, 0, 1])
    with pytest.raises(ValueError, match="direction"):
        ir.sh9_from_directional([0, 0, 0])
    with pytest.raises(ValueError, match="angular_radius"):
        ir.sh9_from_disk([0, 0, 1], 2.0)
    with pytest.raises(ValueError, match="window kind"):
        ir.sh_window("box")
    # unnormalised normals are normalised; all-zero environment gives zeros everywhere
    np.testing.assert_allclose(ir.sh9_irradiance(c, [0, 0, 5.0]), ir.sh9_irradiance(c, [0, 0, 1.0]))
    assert np.all(ir.sh9_irradiance(np.zeros((9, 3)), ir.fibonacci_sphere(10)) == 0)
    assert ir.fit_window_lambda(np.zeros((9, 3))) == 0.0
    # a sun 1e5 times brighter than the sky, at and below the horizon: finite everywhere
    for z in (0.0, -0.3):
        big = 1e5 * ir.sh9_from_directional([1.0, 0.0, z])[:, None] + np.array([1.0] + [0.0] * 8)[:, None]
        for f in (ir.sh9_irradiance, ir.sh4_irradiance, ir.sh4_irradiance_geomerics):
            assert np.all(np.isfinite(f(big, ir.fibonacci_sphere(100))))


def test_drjit_zero_normal_gives_sphere_average():
    import drjit as dr

    c = ir.sh9_from_directional([0, 0, 1])
    r = ir.sh9_irradiance(c, dr.llvm.Array3f([0.0, 0.0], [0.0, 0.0], [0.0, 1.0]))
    np.testing.assert_allclose(np.array(r[0]), [0.25, 1.0625], rtol=1e-6)
    cube = np.arange(18.0).reshape(6, 3)
    rc = ir.ambient_cube_irradiance(cube, dr.llvm.Array3f([0.0], [0.0], [0.0]))
    assert float(rc[0][0]) == pytest.approx(cube[:, 0].mean())


_unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=40, deadline=None)
@given(x=_unit, y=_unit, z=_unit, lx=_unit, ly=_unit, lz=_unit, scale=st.floats(0.0, 1e6))
def test_property_finite_and_bounded(x, y, z, lx, ly, lz, scale):
    n = np.array([[x, y, z]])
    light = np.array([lx, ly, lz])
    if np.linalg.norm(n) < 1e-6 or np.linalg.norm(light) < 1e-6:
        return
    c = scale * ir.sh9_from_directional(light)[:, None] + np.array([0.5] + [0.0] * 8)[:, None] * np.ones(3)
    for f in (ir.sh9_irradiance, ir.sh4_irradiance, ir.sh4_irradiance_geomerics):
        e = f(c, n)
        assert np.all(np.isfinite(e))
    # L2 irradiance of a unit directional light never exceeds 1.0625 (its value at the light) + DC
    e = ir.sh9_irradiance(ir.sh9_from_directional(light), n)
    assert np.all(e <= 1.0625 + 1e-9) and np.all(e >= -0.25 - 1e-9)
    g = ir.sh4_irradiance_geomerics(c, n)
    assert np.all(g >= 0)


def test_drjit_and_numpy_paths_agree():
    # the dispatched (Dr.Jit, opaque coefficients) run of every basis against its NumPy text
    rng = np.random.default_rng(5)
    n = rng.normal(size=(64, 3))
    c = rng.normal(size=(25, 3))  # enough rows for every SH order (L4: 25); lower orders read the first rows
    cube = rng.uniform(0, 2, (6, 3))
    for m in ir.METHODS.values():
        if m.exact:
            continue
        coeffs = cube if m.storage == 18 else np.abs(c) if m.id == "sh-l1-geomerics" else c
        params = {"lam": 0.05} if m.params else None
        got = ir.basis_irradiance(m, coeffs, n, params)
        want = np.stack(m(NUMPY_OPS, ir.basis_inputs(m, coeffs, n), params), -1)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12, err_msg=m.id)
    # the wrappers are the table's methods
    np.testing.assert_allclose(ir.sh9_irradiance(c, n), ir.basis_irradiance("sh-l2", c, n))
    np.testing.assert_allclose(ir.sh4_irradiance(c, n), ir.basis_irradiance("sh-l1", c, n))
    np.testing.assert_allclose(ir.ambient_cube_irradiance(cube, n), ir.basis_irradiance("cube-nnls", cube, n))
    np.testing.assert_allclose(
        ir.sh9_irradiance(c, n, ir.sh_window("hann")), ir.basis_irradiance("sh-l2-hann", c, n), rtol=1e-12
    )
    np.testing.assert_allclose(
        ir.sh9_irradiance(c, n, ir.sh_window("lambda", 2, 0.3)),
        ir.basis_irradiance("sh-l2-lambda", c, n, {"lam": 0.3}),
        rtol=1e-12,
    )


def test_method_table():
    # storage = floats per probe (RGB), one exact row, λ the one free parameter (bounded below by 0)
    storage = {m.id: m.storage for m in ir.METHODS.values()}
    assert storage["cube-valve"] == storage["cube-nnls"] == 18
    assert storage["sh-l1"] == storage["sh-l1-geomerics"] == 12
    assert storage["sh-l2"] == storage["sh-l2-lambda"] == 27
    assert [m.id for m in ir.METHODS.values() if m.exact] == ["quadrature"]
    assert [m.id for m in ir.METHODS.values() if m.fitted] == ["sh-l2-lambda", "sh-l3-lambda", "sh-l4-lambda"]
    lam = ir.METHODS["sh-l2-lambda"].params["lam"]
    assert lam.lower == 0.0 and lam.upper == math.inf
    for m in ir.METHODS.values():
        assert m.label and m.formula and m.source and m.quantity == "environment_irradiance"
        if not m.exact:
            assert m.input_names == ("nx", "ny", "nz", "coeffs")
    with pytest.raises(ValueError, match="not a basis"):
        ir.basis_irradiance("quadrature", np.ones((9, 3)), [0, 0, 1.0])
    with pytest.raises(ValueError, match="unknown irradiance basis"):
        ir.basis_irradiance("sh-l9", np.ones((9, 3)), [0, 0, 1.0])


def test_cube_design_matrix_against_its_definition():
    n = ir.fibonacci_sphere(200)
    want = np.zeros((len(n), 6))
    for i in range(3):
        want[:, 2 * i] = np.where(n[:, i] >= 0, n[:, i] ** 2, 0.0)
        want[:, 2 * i + 1] = np.where(n[:, i] < 0, n[:, i] ** 2, 0.0)
    np.testing.assert_allclose(ir.cube_design_matrix(n), want, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(ir.cube_design_matrix(np.array(ir.CUBE_AXES)), np.eye(6))


def test_constant_sh():
    c = ir.sh9_from_constant([1.0, 2.0, 3.0])
    np.testing.assert_allclose(
        ir.sh9_irradiance(c, ir.fibonacci_sphere(20)), np.pi * np.array([[1.0, 2.0, 3.0]] * 20)
    )


@settings(max_examples=30, deadline=None)
@given(x=_unit, y=_unit, z=_unit, scale=st.floats(1e-3, 1e3))
def test_property_cube_convex_combination(x, y, z, scale):
    # n_x² + n_y² + n_z² = 1: the cube's value is a convex combination of three of its colours
    if x * x + y * y + z * z < 1e-6:
        return
    cube = scale * np.arange(1.0, 19.0).reshape(6, 3)
    e = ir.ambient_cube_irradiance(cube, np.array([[x, y, z]]))[0]
    assert np.all(e >= cube.min(axis=0) - 1e-9 * scale) and np.all(e <= cube.max(axis=0) + 1e-9 * scale)


def _env(name, values, unresolved=()):
    return {
        "id": name,
        "approximations": [
            {
                "method": m,
                "metrics": {
                    "rel_rmse": {"value": v, "noise_floor": 0.01, "resolved": m not in unresolved},
                    "smape": {"value": v / 2, "noise_floor": 0.005},
                },
            }
            for m, v in values.items()
        ],
    }


def test_resolved_means_leave_out_cases_where_a_row_is_within_noise():
    from rtfit.experiments.rows import resolved_means

    cases = [_env("a", {"x": 0.1, "y": 0.3}), _env("b", {"x": 0.005, "y": 0.5}, unresolved=("x",))]
    assert resolved_means(cases, ["x", "y"]) == pytest.approx({"x": 0.1, "y": 0.3})
    assert resolved_means(cases, ["y"]) == pytest.approx({"y": 0.4})  # x's noise does not remove y's case
    assert resolved_means([cases[1]], ["x", "y"]) == {}


def test_storage_budget_winner_is_not_ranked_on_noise():
    """Issue 32: a basis whose error on an environment is within the reference's noise (a quick run's SH L4
    on Pisa and Wells, 2.4–2.7× its true error) must not win the ranking on that environment's value."""
    from rtfit.experiments.irradiance_bases_study import BASES, budget_winners
    from rtfit.realtime.environment_bases import METHODS

    stored = [r.method for r in BASES if METHODS[r.method].storage]
    assert {"sh-l2", "sh-l4"} <= set(stored)

    def env(values, unresolved=()):
        return {m: {"rel_rmse": {"value": v, "resolved": m not in unresolved}} for m, v in values.items()}

    first = {m: 0.3 for m in stored} | {"sh-l2": 0.10, "sh-l4": 0.12}
    second = {m: 0.5 for m in stored} | {"sh-l2": 0.2, "sh-l4": 0.001}  # L4 within noise here
    top = budget_winners({"env-a": env(first), "env-b": env(second, ("sh-l4",))})[-1]  # 27+: all stored
    assert top["best"] == "sh-l2" and top["rel_rmse"] == pytest.approx(0.10)
    nine = budget_winners({"env-a": env(first)})[2]  # 9 floats per channel: SH L2's 27 floats and below
    assert nine["budget"] == "9" and nine["best"] == "sh-l2" and nine["best_at_budget"] == "sh-l2"


def test_run_is_the_engine_on_the_shipped_spheres_plus_the_study(tmp_path):
    """``rtfit run irradiance-bases`` = the engine's audits of the shipped white sphere (constant, sunsky at
    five elevations, studio, overcast) + `irradiance_bases_study.study`. Independent values: the white
    furnace (constant radiance 1: E = π at every normal, every SH / cube row exact); under a lone sun the
    clamped cosine's band energies (π/4, π/3, 5π/64, 0, π/256 of a total 2π/3) give the relative RMSE of SH
    L1, L2 and L4 over the sphere: √(1/8), √(1/128), √(1/512); the shipped maps are rtfit's procedural maps
    at 64 × 128; every old self-check is there and passes."""
    from rtfit.experiments import audit_irradiance_bases as decl
    from rtfit.experiments import irradiance_bases_study as study
    from rtfit.experiments.audit_run import audit
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.realtime.environment_bases import METHODS
    from rtfit.reference import environments as envs
    from rtfit.scenes import library_path
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["irradiance-bases"]
    assert fam.module == ENGINE and fam.scenes == decl.SCENES and fam.study.target is study.study
    assert [s.name for s in fam.scenes if s.quick] == [
        "constant",
        "sunsky-10",
        "sunsky-60",
        "studio",
        "overcast",
    ]
    for m, make in (("studio", envs.studio_map), ("overcast", envs.overcast_map)):
        shipped = envs.read_image(LIBRARY_DIR / "envmaps" / f"{m}.exr")
        np.testing.assert_allclose(shipped, make(64, 128), rtol=1e-6, atol=0)
    r = audit(library_path("irradiance_sphere"), "irradiance-bases", spp=64, pass_spp=8, width=24, height=24,
              fit=False, cache=tmp_path / "cache", cost_elements=1 << 10, metrics=("rmse",))  # fmt: skip
    case = r.cases[0]
    m = case.mask
    z = (case.reference.mean[m] - math.pi) / case.reference.stderr[m]  # Mitsuba's MIS estimate: noisy
    assert np.all(np.abs(z) < 5) and abs(np.mean(z)) < 4 / math.sqrt(z.size)
    for row in ("quadrature", "sh-l2", "sh-l4", "cube-valve", "cube-nnls", "ambient-dice"):
        np.testing.assert_allclose(r.outcomes[case.id][row].image[m], math.pi, rtol=1e-4)
    res = study.study(StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", (r,)))
    assert all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    names = " ".join(c.name for c in res.checks)
    olds = ("white furnace", "no worse than", "L3 irradiance equals L2", "fitted λ window",
            "reproduces a constant", "SG ⊗ clamped", "hemisphere: constant", "hbasis-6 no worse")  # fmt: skip
    for old in olds:
        assert old in names, old
    sun = res.extra["sphere_metrics"]["sun-0.27"]
    for row, want in (
        ("sh-l1", math.sqrt(1 / 8)),
        ("sh-l2", math.sqrt(1 / 128)),
        ("sh-l4", math.sqrt(1 / 512)),
    ):
        assert sun[row]["rel_rmse"]["value"] == pytest.approx(want, rel=0.03), row
    top = res.extra["budgets"][-1]  # 27+ floats: every stored basis a candidate
    assert top["candidates"] == sum(1 for r in study.BASES if METHODS[r.method].storage)
    assert (
        top["best"] is None
    )  # the furnace resolves no basis's error (all exact): nothing is ranked on noise
