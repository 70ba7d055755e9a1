"""A scanned parameter that is a step where its scan left it is held there while the solver fits the
others (`rtfit.fitting.held_steps`, issue 33 session 33): the values, stderr and SSR of the others those of
an independent least-squares fit with it fixed, its own value the scan's, its stderr NaN, the degrees of
freedom n − k for all k parameters; a scanned parameter the residuals change with is fitted as before."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.fitting import fit_method
from rtfit.fitting.held_steps import _difference_points, flat_scanned
from rtfit.realtime.methods import Method, Param

_B = Param(0.01, 0.0, 0.5, scan=33)


def _lit_ramp(ops, z, depth, x, a, b):
    """a·x where a depth compare lights the pixel (z − b < depth), 0 where it does not: a step in b."""
    return ops.select(z - b < depth, a * x, 0.0 * x)


def _data(n=3000, seed=4):
    """Receivers' depth gaps uniform in [0, 0.1], none within 1e-4 of a scan value of `_B` (there a central
    difference of the bias would cross a step), lit by the truth b = 0.05 with a = 1.7."""
    rng = np.random.default_rng(seed)
    gap = rng.uniform(0.0, 0.1, 2 * n)
    grid = np.array([_B.initial, *_B.scan_values()])
    gap = gap[np.min(np.abs(gap[:, None] - grid[None, :]), axis=1) > 1e-4][:n]
    x = rng.uniform(0.5, 2.0, gap.size)
    y = np.where(gap < 0.05, 1.7 * x, 0.0) + rng.normal(0.0, 0.01, gap.size)
    return {"z": gap, "depth": np.zeros(n), "x": x}, y


def _method(b: Param) -> Method:
    return Method("lit-ramp", "lit ramp", _lit_ramp, inputs=("z", "depth", "x"),
                  params={"a": Param(1.0, 0.0, 10.0), "b": b})  # fmt: skip


def test_a_step_where_its_scan_left_it_is_held_and_the_others_fit_as_with_it_fixed():
    inputs, y = _data()
    b = _B
    fit = fit_method(_method(b), inputs, y, solver="trf")
    # the scan's best, found independently: of the start and the 33 scan values, the least SSR with a at its
    # start (1.0)
    values = [b.initial, *b.scan_values()]
    ssrs = [np.sum((np.where(inputs["z"] < v, inputs["x"], 0.0) - y) ** 2) for v in values]
    want_b = values[int(np.argmin(ssrs))]
    assert fit.values["b"] == want_b and math.isnan(fit.stderr["b"])
    assert "b: a step (zero derivative), the best of a 33-value scan" in fit.message
    # a with b fixed: linear least squares in closed form over the lit pixels
    lit = inputs["z"] < want_b
    xs, ys = inputs["x"][lit], y[lit]
    a = float(xs @ ys / (xs @ xs))
    ssr = float(np.sum((np.where(lit, a * inputs["x"], 0.0) - y) ** 2))
    n = y.size
    assert fit.values["a"] == pytest.approx(a, rel=1e-7)
    assert fit.ssr == pytest.approx(ssr, rel=1e-9) and fit.dof == n - 2
    # stderr of a: s·(Σx²)^{-1/2}, s² = SSR/(n − 2) (both parameters counted)
    assert fit.stderr["a"] == pytest.approx(math.sqrt(ssr / (n - 2) / float(xs @ xs)), rel=1e-5)
    assert fit.param_names == ("a", "b") and math.isnan(fit.correlation[0][1])
    assert fit.converged and not fit.at_bound["b"]


def test_a_row_whose_only_parameter_is_a_step_is_its_scan_with_no_solver_step():
    inputs, y = _data()
    only = Method("lit", "lit", lambda ops, z, depth, x, b: _lit_ramp(ops, z, depth, x, 1.7, b),
                  inputs=("z", "depth", "x"), params={"b": Param(0.01, 0.0, 0.5, scan=33)})  # fmt: skip
    fit = fit_method(only, inputs, y, solver="trf")
    lit = inputs["z"] < fit.values["b"]
    want = float(np.sum((np.where(lit, 1.7 * inputs["x"], 0.0) - y) ** 2))
    assert fit.ssr == pytest.approx(want, rel=1e-12)
    assert fit.converged and fit.param_names == ("b",) and math.isnan(fit.stderr["b"])


def test_a_scanned_parameter_the_residuals_change_with_is_fitted():
    """A scan only starts a smooth parameter (a shadow map's filter radius): its difference is not zero, so
    the solver fits it (finite stderr), as before."""
    rng = np.random.default_rng(5)
    t = rng.uniform(0, 3, 500)
    y = 2.0 * np.exp(-1.3 * t) + rng.normal(0, 1e-3, t.size)
    m = Method("exp", "exp", lambda ops, t, a, k: a * ops.exp(-k * t), inputs=("t",),
               params={"a": Param(1.0, 0.0, 10.0, scan=9), "k": Param(1.0, 0.01, 10.0)})  # fmt: skip
    flat, _ = flat_scanned(m, m.params, {"t": t}, {}, y, np.ones_like(y), None)
    assert flat == []
    fit = fit_method(m, {"t": t}, y, solver="trf")
    assert fit.values["a"] == pytest.approx(2.0, abs=5e-3) and math.isfinite(fit.stderr["a"])


_H = 6.0554544523933395e-06  # ε^{1/3} of float64 (mpmath: cbrt(2^-52))


@pytest.mark.parametrize(
    ("param", "value", "want"),
    [
        (Param(1.0, 0.0, 10.0), 4.0, (4.0 - 4.0 * _H, 4.0 + 4.0 * _H)),
        (Param(1.0, 0.0, 10.0), 0.5, (0.5 - _H, 0.5 + _H)),
        (Param(1.0, 0.0, 10.0), 0.0, (_H, 2 * _H)),  # one-sided at the lower bound
        (Param(1.0, 0.0, 10.0), 10.0, (10.0 - 10 * _H, 10.0 - 20 * _H)),  # and at the upper
    ],
)
def test_the_difference_points_are_scipys_three_point_rule(param, value, want):
    """h = ε^{1/3}·max(1, |p|) (ε^{1/3} = 6.0554544523933395e-06 for float64), one-sided at a bound."""
    assert _difference_points(param, value) == pytest.approx(want, rel=1e-12, abs=1e-18)
