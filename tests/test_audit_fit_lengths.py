"""`rtfit.experiments.audit_fit.length_scaled_params`: the parameters named as lengths get their start value
and both bounds times the scene length (0.5 × 4 = 2 etc., written out here), the others are the same objects,
and each row keeps its parameters' order."""

from __future__ import annotations

import math

from rtfit.experiments.audit_fit import length_scaled_params
from rtfit.realtime.methods import Input, Method, Param


def _kernel(ops, x, width, k):
    return x * width * k


ROW = Method(
    id="row",
    label="x·w·k",
    kernel=_kernel,
    inputs=(Input("x", "1", "abscissa", domain=(0.0, 1.0)),),
    params={"width": Param(0.5, 0.25, 1.0, unit="R"), "k": Param(2.0, 1.0, math.inf, unit="1")},
    formula="x·w·k",
)


def test_length_parameters_are_scaled_and_the_others_kept():
    params = length_scaled_params([ROW], frozenset({"width"}), 4.0)
    assert list(params) == ["row"]
    assert list(params["row"]) == ["width", "k"]
    w = params["row"]["width"]
    assert (w.initial, w.lower, w.upper) == (2.0, 1.0, 4.0)
    assert (w.unit, w.description, w.published) == ("R", "", True)
    assert params["row"]["k"] is ROW.params["k"]


def test_an_infinite_bound_stays_infinite():
    k = length_scaled_params([ROW], frozenset({"k"}), 3.0)["row"]["k"]
    assert (k.initial, k.lower, k.upper) == (6.0, 3.0, math.inf)
