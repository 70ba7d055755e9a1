"""Methods as data (`rtfit.realtime.methods`) and fits through the kernel text (`rtfit.fitting.fit_method`).

Oracle for the fit: scipy's least_squares on a residual written independently in NumPy (the wrap formula
typed here as the test's own oracle), against the exact sphere-light irradiance as the target."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares

from rtfit.fitting import fit_method
from rtfit.realtime import Input, Method, Param, diffuse, method_table, sphere_light_irradiance


def _wrap(ops, cos_theta, w, p):
    base = ops.maximum((cos_theta + w) / (1.0 + w), 0.0)
    return ops.power(base, p)


WRAP = Method(
    "wrap-test",
    "Wrap",
    _wrap,
    inputs=(Input("cos_theta", "1", "n·l"),),
    params={"w": Param(0.3, 0.0, 1.0, unit="1"), "p": Param(1.3, 0.25, 8.0, unit="1")},
)


def test_declaration_checks():
    with pytest.raises(ValueError, match="declared twice"):
        Method("m", "M", _wrap, inputs=("w",), params={"w": Param(0.5, 0, 1)})
    with pytest.raises(ValueError, match="method id"):
        Method("bad id", "M", _wrap)
    with pytest.raises(ValueError, match="declared twice"):
        method_table([WRAP, WRAP])
    with pytest.raises(ValueError, match="has no parameter q"):
        WRAP.keywords({"q": 1.0})
    with pytest.raises(ValueError, match="strictly inside"):
        Param(1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="real number"):
        Param(True, 0.0, 2.0)


def test_evaluate_matches_the_public_function_on_numpy_and_floats():
    c = np.linspace(-1, 1, 11)
    got = WRAP.evaluate({"cos_theta": c}, {"w": 0.4, "p": 1.7})
    np.testing.assert_allclose(got, diffuse.wrap(c, 0.4, 1.7), rtol=1e-15)
    assert WRAP.evaluate({"cos_theta": 0.5}) == pytest.approx(((0.5 + 0.3) / 1.3) ** 1.3, rel=1e-15)
    fixed = Method("hl", "Half-Lambert as wrap", _wrap, inputs=("cos_theta",), fixed={"w": 1.0, "p": 2.0})
    np.testing.assert_allclose(fixed.evaluate({"cos_theta": c}), diffuse.half_lambert(c), rtol=1e-15)


def test_fit_through_the_kernel_lands_where_an_independent_fit_lands():
    rng = np.random.default_rng(3)
    c = rng.uniform(-1, 1, 3000)
    alpha = math.radians(25.0)
    target = sphere_light_irradiance(c, alpha, 1.0) / (math.pi * math.sin(alpha) ** 2)

    def resid(x):
        base = np.maximum((c + x[0]) / (1 + x[0]), 0.0)
        return base ** x[1] - target

    ref = least_squares(
        resid, [0.3, 1.3], bounds=([0.0, 0.25], [1.0, 8.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14
    )
    fit = fit_method(WRAP, {"cos_theta": c}, target)
    assert fit.converged
    # Same optimum of the same objective: agreement to the solvers' tolerances (measured 2e-10).
    assert fit.values["w"] == pytest.approx(ref.x[0], abs=1e-7)
    assert fit.values["p"] == pytest.approx(ref.x[1], abs=1e-7)
    held = fit_method(WRAP, {"cos_theta": c}, target, params={"p": Param(1.3, 0.25, 8.0)}, held={"w": 0.2})
    assert set(held.values) == {"p"}
    with pytest.raises(ValueError, match="both fitted and held"):
        fit_method(WRAP, {"cos_theta": c}, target, held={"w": 0.2})
    with pytest.raises(ValueError, match="needs input"):
        fit_method(WRAP, {}, target)
