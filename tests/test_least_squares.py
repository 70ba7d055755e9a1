"""rtfit.fitting.least_squares against closed forms (ordinary least squares, the covariance of the true
model's Jacobian) and synthetic data with known parameters and noise."""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from rtfit.fitting import FitResult, Param, fit_curve, fit_least_squares
from rtfit.fitting.least_squares import gauss_newton_stall


# Module-level model functions: the jitted solve is reused for the same function object.
def exp_model(p, x):
    return p["a"] * jnp.exp(-p["b"] * x) + p["c"]


def line_residual(p, args):
    x, y = args
    return p["m"] * x + p["q"] - y


def slope_residual(p, args):
    x, y = args
    return p["a"] * x - y


def wrap_model(p, c):
    """((c + w)/(1 + w))^p, clipped at 0 (zero gradient, not NaN, where clipped)."""
    base = (c + p["w"]) / (1.0 + p["w"])
    lit = base > 0
    return jnp.where(lit, jnp.where(lit, base, 1.0) ** p["p"], 0.0)


def test_exponential_recovers_parameters_with_correct_stderr():
    rng = np.random.default_rng(11)
    a, b, c, sigma = 2.0, 1.3, 0.5, 0.02
    x = np.linspace(0.0, 4.0, 200)
    y = a * np.exp(-b * x) + c + sigma * rng.standard_normal(x.size)
    params = {"a": Param(1.0), "b": Param(0.5, 0.0, 10.0), "c": Param(0.0, lower=-1.0)}
    res = fit_curve(exp_model, x, y, params)
    assert res.converged and res.message == ""
    # Closed-form covariance at the truth: σ²(JᵀJ)⁻¹ with ∂/∂a = e^{−bx}, ∂/∂b = −a x e^{−bx}, ∂/∂c = 1.
    e = np.exp(-b * x)
    jac = np.stack([e, -a * x * e, np.ones_like(x)], axis=1)
    se_true = np.sqrt(np.diag(sigma**2 * np.linalg.inv(jac.T @ jac)))
    for name, truth, se in zip("abc", (a, b, c), se_true, strict=True):
        assert abs(res.values[name] - truth) < 3 * res.stderr[name], name
        assert res.stderr[name] == pytest.approx(se, rel=0.2), name
    assert res.rms_residual == pytest.approx(sigma, rel=0.15)  # sd of rms over 200 points ≈ 5%
    assert (res.n_residuals, res.dof) == (200, 197)
    assert not any(res.at_bound.values())
    # With weights 1/σ and absolute_sigma, the stderr is σ(JᵀJ)⁻¹ at the estimate: within 2% of truth's.
    res_w = fit_curve(exp_model, x, y, params, weights=1.0 / sigma, absolute_sigma=True)
    for name, se in zip("abc", se_true, strict=True):
        assert res_w.values[name] == pytest.approx(res.values[name], rel=1e-7)
        assert res_w.stderr[name] == pytest.approx(se, rel=0.02), name


def test_linear_fit_equals_ordinary_least_squares_closed_form():
    rng = np.random.default_rng(12)
    x = np.linspace(-1.0, 3.0, 50)
    y = 0.7 * x - 0.2 + 0.1 * rng.standard_normal(x.size)
    res = fit_least_squares(line_residual, {"m": Param(0.0), "q": Param(0.0)}, (x, y))
    n = x.size
    xm, ym = x.mean(), y.mean()
    sxx = np.sum((x - xm) ** 2)
    m = np.sum((x - xm) * (y - ym)) / sxx
    q = ym - m * xm
    ssr = np.sum((y - m * x - q) ** 2)
    s2 = ssr / (n - 2)
    se_m, se_q = math.sqrt(s2 / sxx), math.sqrt(s2 * (1 / n + xm**2 / sxx))
    corr = (-xm * s2 / sxx) / (se_m * se_q)
    assert res.values["m"] == pytest.approx(m, rel=1e-10)
    assert res.values["q"] == pytest.approx(q, rel=1e-9)
    assert res.ssr == pytest.approx(ssr, rel=1e-10)
    assert res.stderr["m"] == pytest.approx(se_m, rel=1e-8)
    assert res.stderr["q"] == pytest.approx(se_q, rel=1e-8)
    assert res.correlation[0][1] == pytest.approx(corr, rel=1e-8)
    assert res.correlation[1][0] == pytest.approx(corr, rel=1e-8)
    assert res.correlation[0][0] == pytest.approx(1.0) and res.param_names == ("m", "q")
    assert res.jacobian_rank == 2


def test_exact_data_gives_zero_residual_and_bounded_optimum_inside():
    x = np.linspace(0.1, 2.0, 30)
    res = fit_least_squares(slope_residual, {"a": Param(0.5, 0.0, 1.0)}, (x, 0.7 * x))
    assert res.converged
    assert res.values["a"] == pytest.approx(0.7, abs=1e-10)
    assert res.rms_residual < 1e-10
    assert res.at_bound == {"a": False}


def test_optimum_beyond_a_bound_is_reported_at_bound():
    x = np.linspace(0.1, 2.0, 30)
    y = 2.0 * x  # the unconstrained optimum a = 2 lies above the upper bound 1
    res = fit_least_squares(slope_residual, {"a": Param(0.5, 0.0, 1.0)}, (x, y))
    assert res.values["a"] == pytest.approx(1.0, abs=1e-6)
    assert res.at_bound == {"a": True}
    assert res.converged and "bound" in res.message
    d = res.to_dict()["parameters"]["a"]
    assert d["at_bound"] is True and (d["lower"], d["upper"]) == (0.0, 1.0)
    # One-sided lower bound, optimum below it.
    res = fit_least_squares(slope_residual, {"a": Param(1.0, lower=0.5)}, (x, 0.1 * x))
    assert res.values["a"] == pytest.approx(0.5, abs=1e-6)
    assert res.at_bound == {"a": True} and res.converged
    assert res.to_dict()["parameters"]["a"]["upper"] is None


def test_wrap_lighting_model_recovers_w_and_p():
    rng = np.random.default_rng(13)
    c = np.linspace(-1.0, 1.0, 400)
    w, p = 0.4, 1.6
    base = np.maximum((c + w) / (1 + w), 0.0)
    exact = base**p
    params = {"w": Param(0.3, 0.0, 1.0), "p": Param(1.3, 0.25, 8.0)}
    res = fit_curve(wrap_model, c, exact, params)
    assert res.converged
    assert res.values["w"] == pytest.approx(w, abs=1e-8)
    assert res.values["p"] == pytest.approx(p, abs=1e-8)
    assert res.rms_residual < 1e-10
    noisy = exact + 0.01 * rng.standard_normal(c.size)
    res = fit_curve(wrap_model, c, noisy, params)
    assert res.converged
    assert abs(res.values["w"] - w) < 3 * res.stderr["w"]
    assert abs(res.values["p"] - p) < 3 * res.stderr["p"]
    assert 0 < res.stderr["w"] < 0.05 and 0 < res.stderr["p"] < 0.1


def test_rank_deficient_problem_reports_undetermined_parameters():
    x = np.linspace(0.0, 1.0, 20)

    def res_sum(p, args):
        return (p["a"] + p["b"]) * args - 2.0 * args

    res = fit_least_squares(res_sum, {"a": Param(0.5), "b": Param(0.1)}, x)
    assert res.values["a"] + res.values["b"] == pytest.approx(2.0, abs=1e-10)
    assert res.jacobian_rank == 1
    assert math.isnan(res.stderr["a"]) and math.isnan(res.stderr["b"])
    doc = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert doc["parameters"]["a"]["stderr"] is None


def test_to_dict_shape_and_json():
    x = np.linspace(0.0, 1.0, 10)
    res = fit_least_squares(line_residual, {"m": Param(1.0), "q": Param(0.5, -1.0, 1.0)}, (x, 2 * x + 0.1))
    assert isinstance(res, FitResult)
    doc = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert set(doc) >= {
        "parameters",
        "rms_residual",
        "ssr",
        "n_residuals",
        "dof",
        "steps",
        "converged",
        "message",
        "correlation",
        "param_names",
    }
    assert list(doc["parameters"]) == ["m", "q"]
    assert set(doc["parameters"]["q"]) == {"value", "stderr", "lower", "upper", "at_bound"}
    assert doc["parameters"]["m"]["lower"] is None and doc["parameters"]["q"]["lower"] == -1.0


def test_same_residual_function_is_not_traced_again():
    traces = []

    def counting(p, args):
        traces.append(1)
        x, y = args
        return p["k"] * x - y

    x = np.linspace(0.0, 1.0, 16)
    fit_least_squares(counting, {"k": Param(0.5, 0.0, 5.0)}, (x, 2.0 * x))
    n = len(traces)
    res = fit_least_squares(counting, {"k": Param(3.0, 0.5, 4.0)}, (x, 1.5 * x + 0.01))  # new data and bounds
    assert len(traces) == n
    assert res.values["k"] == pytest.approx(1.5, abs=0.05)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(initial=0.0, lower=1.0, upper=0.0),
        dict(initial=1.0, lower=1.0),
        dict(initial=2.0, upper=1.0),
        dict(initial=math.nan),
        dict(initial=math.inf),
        dict(initial=0.0, lower=math.nan),
        dict(initial=0.0, lower=math.inf),
    ],
)
def test_param_validation(kwargs):
    with pytest.raises(ValueError) as err:
        Param(**kwargs)
    assert "\n" not in str(err.value)


def test_bad_inputs():
    x = np.linspace(0.0, 1.0, 5)
    y_bad = x.copy()
    y_bad[2] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        fit_least_squares(slope_residual, {"a": Param(1.0)}, (x, y_bad))
    with pytest.raises(ValueError):
        fit_least_squares(slope_residual, {}, (x, x))
    with pytest.raises(ValueError):
        fit_least_squares(slope_residual, {"a": 1.0}, (x, x))
    with pytest.raises(ValueError):
        fit_curve(exp_model, x, np.full(5, np.nan), {"a": Param(1.0), "b": Param(1.0), "c": Param(0.0)})


def test_parameter_stopped_short_of_its_bound_is_pinned_and_flagged():
    """A solve that runs out of steps while a parameter crawls to its bound (the sigmoid reaches it only at
    z = ∞; the obscurance fit's d_max stopped at 999.4 of 1000, not flagged) pins it there and re-solves the
    rest: the closed form with m on its bound is q = mean(y − 2x); the result is flagged at_bound."""
    x = np.linspace(0.0, 1.0, 40)
    y = 3.0 * x + 1.0  # the unconstrained optimum m = 3 lies above the upper bound 2
    params = {"m": Param(0.5, 0.0, 2.0), "q": Param(0.0, -10.0, 10.0)}
    res = fit_least_squares(line_residual, params, (x, y), max_steps=12)
    q = float(np.mean(y - 2.0 * x))
    assert res.values["m"] == 2.0
    assert res.values["q"] == pytest.approx(q, abs=1e-8)
    assert res.at_bound == {"m": True, "q": False}
    assert res.converged


def test_gauss_newton_stall_is_the_closed_form_least_squares_optimum():
    """`_gauss_newton_stall` (the max_steps fallback for kinked residuals) against the closed form of a linear
    model: at the normal-equation solution it reports stalled (decrease ≤ 1e-25, step 0); 0.2 standard errors
    away it does not (step 0.2 σ > 0.05 σ); the predicted decrease equals the exact SSR drop of the linear
    model, (SSR(x) − SSR*)/SSR(x)."""
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 1.0, 200)
    jac = np.stack([x, np.ones_like(x)], axis=1)
    y = 0.7 * x + 0.2 + rng.normal(0.0, 0.01, x.size)
    best = np.linalg.lstsq(jac, y, rcond=None)[0]
    r_best = jac @ best - y
    ssr = float(r_best @ r_best)
    se = np.sqrt(np.diag(ssr / (x.size - 2) * np.linalg.inv(jac.T @ jac)))
    stalled, pred, frac = gauss_newton_stall(jac, r_best, se)
    assert stalled and abs(pred) <= 1e-25 and frac <= 1e-9
    off = best + np.array([0.2 * se[0], 0.0])
    r_off = jac @ off - y
    stalled, pred, frac = gauss_newton_stall(jac, r_off, se)
    assert not stalled
    assert frac == pytest.approx(0.2, rel=1e-6)
    assert pred == pytest.approx((float(r_off @ r_off) - ssr) / float(r_off @ r_off), rel=1e-6)


def test_max_steps_short_of_a_smooth_optimum_is_not_converged():
    """The stall fallback must not accept a solve cut short far from its optimum: the exponential model with
    3 steps from a poor start (its optimum is ≥ 1 standard error away) stays converged = False."""
    x = np.linspace(0.0, 3.0, 60)
    y = 2.0 * np.exp(-1.3 * x) + 0.5
    res = fit_curve(exp_model, x, y, {"a": Param(0.3), "b": Param(4.0), "c": Param(-1.0)}, max_steps=3)
    assert not res.converged
