"""`rtfit.fitting.bounded_lm`: the projected Levenberg–Marquardt loop against closed-form least squares, its
bounds and active set, recovery of a nonlinear model, and `bounded_lm_result`'s errors against the
covariance of ordinary least squares.

Independent values: linear least squares by `numpy.linalg.lstsq` and its textbook covariance
s²(AᵀA)⁻¹, s² = SSR/(m − p); the closed-form intercept when the slope sits on a bound.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.fitting import Param, bounded_lm, bounded_lm_result, param_bounds


def _line(seed=0, m=50):
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, m)
    y = 2.0 * x - 0.5 + rng.normal(0, 0.01, m)
    a_mat = np.column_stack([x, np.ones_like(x)])

    def fun(p):
        return a_mat @ p - y, a_mat

    return x, y, a_mat, fun


def test_bounded_lm_matches_linear_least_squares_and_respects_bounds():
    x, y, a_mat, fun = _line()
    exact = np.linalg.lstsq(a_mat, y, rcond=None)[0]
    out = bounded_lm(fun, [0.0, 0.0], [-10, -10], [10, 10])
    assert out["converged"]
    np.testing.assert_allclose(out["x"], exact, rtol=1e-6)
    # slope held at its upper bound 1.5: the intercept is then the mean of y − 1.5x (closed form)
    out = bounded_lm(fun, [0.0, 0.0], [-10, -10], [1.5, 10])
    assert out["x"][0] == 1.5
    assert out["x"][1] == pytest.approx(np.mean(y - 1.5 * x), abs=1e-8)
    with pytest.raises(ValueError, match="lower < upper"):
        bounded_lm(fun, [0.0, 0.0], [0, 0], [0, 1])


def test_bounded_lm_recovers_a_nonlinear_model():
    # y = a·exp(−b t): from a start far off, exact data, both parameters recovered to round-off.
    t = np.linspace(0.0, 3.0, 80)
    a_true, b_true = 1.7, 0.8
    y = a_true * np.exp(-b_true * t)

    def fun(p):
        e = np.exp(-p[1] * t)
        return p[0] * e - y, np.column_stack([e, -p[0] * t * e])

    out = bounded_lm(fun, [0.5, 3.0], [0.0, 0.0], [10.0, 10.0], max_iter=200)
    assert out["converged"], out["message"]
    np.testing.assert_allclose(out["x"], [a_true, b_true], rtol=1e-7)
    assert out["ssr"] < 1e-16 and out["evaluations"] >= out["iterations"]


def test_bounded_lm_result_matches_the_ordinary_least_squares_covariance():
    _, y, a_mat, fun = _line(seed=1)
    out = bounded_lm(fun, [0.0, 0.0], [-10, -10], [10, 10])
    fr, cov = bounded_lm_result(["slope", "intercept"], out, [-10, -10], [10, 10])
    r = a_mat @ out["x"] - y
    s2 = float(r @ r) / (len(y) - 2)
    expect = s2 * np.linalg.inv(a_mat.T @ a_mat)
    np.testing.assert_allclose(cov, expect, rtol=1e-8)
    assert fr.stderr["slope"] == pytest.approx(math.sqrt(expect[0, 0]), rel=1e-8)
    assert fr.correlation[0][1] == pytest.approx(expect[0, 1] / math.sqrt(expect[0, 0] * expect[1, 1]))
    assert fr.dof == len(y) - 2 and fr.converged and not any(fr.at_bound.values())
    out = bounded_lm(fun, [0.0, 0.0], [-10, -10], [1.5, 10])
    fr, _ = bounded_lm_result(["slope", "intercept"], out, [-10, -10], [1.5, 10])
    assert fr.at_bound == {"slope": True, "intercept": False}
    with pytest.raises(ValueError, match="names"):
        bounded_lm_result(["slope"], out, [-10, -10], [1.5, 10])


def test_param_bounds_from_declarations():
    params = {"a": Param(1.0, 0.0, 2.0), "b": Param(0.0, -1.0, 1.0), "c": Param(0.0)}
    lo, hi = param_bounds(params, ["b", "a"])
    assert lo.tolist() == [-1.0, 0.0] and hi.tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match="finite"):
        param_bounds(params, ["c"])
    with pytest.raises(ValueError, match="no bounds"):
        param_bounds(params, ["d"])


def test_bounded_lm_and_scipy_trf_reach_the_same_bound_active_optimum():
    # y = 1.7·exp(−0.8 t) fitted with b ≥ 1.2: the optimum holds b on its bound, and with b fixed the model is
    # linear in a, so a = Σ y e / Σ e² (e = exp(−1.2 t)), closed form. bounded_lm and SciPy's
    # least_squares(trf, x_scale="jac", bounds, jac) (the comparison of the module docstring) both reach it.
    from scipy.optimize import least_squares

    t = np.linspace(0.0, 3.0, 80)
    y = 1.7 * np.exp(-0.8 * t)

    def fun(p):
        e = np.exp(-p[1] * t)
        return p[0] * e - y, np.column_stack([e, -p[0] * t * e])

    lo, hi = np.array([0.0, 1.2]), np.array([10.0, 10.0])
    e = np.exp(-1.2 * t)
    a_exact = float(y @ e / (e @ e))
    r_exact = a_exact * e - y
    ssr_exact = float(r_exact @ r_exact)
    # b on its bound is optimal: the gradient of the SSR in b at (a_exact, 1.2) points out of the box
    assert float(r_exact @ (-a_exact * t * e)) > 0

    lm = bounded_lm(fun, [0.5, 3.0], lo, hi)
    sp = least_squares(
        lambda p: fun(p)[0], [0.5, 3.0], jac=lambda p: fun(p)[1], bounds=(lo, hi), method="trf", x_scale="jac"
    )
    assert lm["converged"] and sp.success
    for x, ssr in ((lm["x"], lm["ssr"]), (sp.x, 2 * sp.cost)):
        assert x[1] == pytest.approx(1.2, abs=1e-12)
        assert x[0] == pytest.approx(a_exact, rel=1e-9)
        assert ssr == pytest.approx(ssr_exact, rel=1e-12)
