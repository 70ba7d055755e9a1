"""The Dr.Jit run of a fit (`Method.fit_ops` "drjit") replays a frozen function after its second call
(`rtfit.fitting.drjit_run.DrJitRun`, issue 33): the same values as tracing every call, bit for bit, with
samplers' tables as inputs; a text whose replay would not be what a trace gives is caught at the first
replay and traced from then on."""

from __future__ import annotations

import numpy as np

from rtfit.fitting import fit_method
from rtfit.fitting.drjit_run import DrJitRun
from rtfit.realtime import DRJIT_OPS, Input, Method, Param
from rtfit.realtime.arrays import cached_table, same_bits


class _Table:
    """A sampler holding a table it hands to each ops namespace once (`cached_table`), as a shadow map."""

    def __init__(self, values):
        self.values = np.asarray(values, np.float64)
        self._tables: dict = {}

    def sample(self, ops, index, like):  # (the sampler protocol: an object with ``sample``)
        return ops.gather(cached_table(self._tables, ops, like, (), lambda: self.values), index)


def _looked_up(ops, t, k, table, a, b):
    return a * ops.exp(-b * t) + table.sample(ops, k, t)


def _method():
    return Method(
        "lookup", "lookup", _looked_up, inputs=(Input("t"), Input("k"), Input("table")),
        params={"a": Param(1.0, 0.0, 10.0), "b": Param(1.0, 0.01, 10.0)}, fit_ops="drjit",
    )  # fmt: skip


def test_frozen_calls_equal_traced_calls_bit_for_bit():
    rng = np.random.default_rng(3)
    n = 500
    inputs = {"t": rng.uniform(0, 3, n), "k": rng.integers(0, 8, n).astype(np.float64),
              "table": _Table(rng.uniform(0, 1, 8))}  # fmt: skip
    traces = []
    counted = Method("lookup", "lookup", lambda ops, **kw: traces.append(1) or _looked_up(ops, **kw),
                     inputs=_method().inputs, params=_method().params, fit_ops="drjit")  # fmt: skip
    frozen = DrJitRun(counted, inputs)
    values = [{"a": 1.0 + 0.1 * i, "b": 0.5 + 0.05 * i} for i in range(6)]
    got = [frozen(v) for v in values]
    assert len(traces) == 3  # a trace, the recording, the first replay's check: the rest replayed
    for v, g in zip(values, got, strict=True):
        traced = np.asarray(_method()(DRJIT_OPS, _converted(inputs), _opaque(v)), np.float64)
        assert np.array_equal(g, traced)
        expect = v["a"] * np.exp(-v["b"] * inputs["t"]) + inputs["table"].values[inputs["k"].astype(int)]
        np.testing.assert_allclose(g, expect, rtol=1e-13, atol=1e-15)


def _converted(inputs):
    import drjit as dr

    return {k: dr.llvm.Float64(v) if isinstance(v, np.ndarray) else v for k, v in inputs.items()}


def _opaque(values):
    import drjit as dr

    return {k: dr.opaque(dr.llvm.Float64, v) for k, v in values.items()}


def test_a_fit_through_the_frozen_run_recovers_its_parameters():
    rng = np.random.default_rng(5)
    n = 400
    t, k = rng.uniform(0, 3, n), rng.integers(0, 8, n).astype(np.float64)
    table = _Table(rng.uniform(0, 1, 8))
    y = 2.5 * np.exp(-1.5 * t) + table.values[k.astype(int)] + rng.normal(0, 1e-3, n)
    fit = fit_method(_method(), {"t": t, "k": k, "table": table}, y, solver="trf")
    assert fit.converged
    for name, truth in (("a", 2.5), ("b", 1.5)):
        assert abs(fit.values[name] - truth) <= 5 * fit.stderr[name]


def test_a_replay_that_is_not_the_trace_is_caught_and_traced_from_then_on():
    """A kernel whose text bakes a Python value that changes between calls (a counter read as a number):
    its replay would repeat the recorded value; the first replay is checked against a trace and the run
    traces every later call."""
    calls = []

    def counting(ops, t, a):
        calls.append(1)
        return a * t + float(len(calls))  # a literal: a new value at every trace

    method = Method("count", "count", counting, inputs=(Input("t"),), params={"a": Param(1.0, 0.0, 2.0)},
                    fit_ops="drjit")  # fmt: skip
    t = np.linspace(0.0, 1.0, 16)
    run = DrJitRun(method, {"t": t})
    outs = [run({"a": 1.0}) for _ in range(5)]
    # the first replay repeats the recording's 2 where a trace gives 3: caught, and every call's value is a
    # fresh trace's (the replay's own value is dropped)
    assert [float(o[0]) for o in outs] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert len(calls) == 5


def test_the_cycle_collector_is_paused_around_a_frozen_call_and_restored():
    """`drjit_run.collector_paused`: off inside (a recording must not run unrelated finalisers), back on
    after, after an exception too, and left off where the caller had it off."""
    import gc

    import pytest

    from rtfit.fitting.drjit_run import collector_paused

    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), collector_paused():
        raise RuntimeError("restored on an exception")
    assert gc.isenabled()
    gc.disable()
    try:
        with collector_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()


def _pair(ops, t, k, table, s, a, b):
    """A tuple output, one part scaled per channel where ``s`` is (3, n) (Dr.Jit: an ``Array3f64``)."""
    base = _looked_up(ops, t, k, table, a, b)
    return s * base, base - b


def test_many_points_in_one_replay_are_the_calls_values_bit_for_bit():
    """`DrJitRun.many`: the predictions at several points from one replay equal those of a call a point,
    bit for bit, with a per-channel (3, n) input (an ``Array3f64``) and a tuple output; more points than
    one replay holds (`MANY_ELEMENTS`) are split, with the same values."""
    import rtfit.fitting.drjit_run as drjit_run

    rng = np.random.default_rng(8)
    n = 300
    inputs = {"t": rng.uniform(0, 3, n), "k": rng.integers(0, 8, n).astype(np.float64),
              "table": _Table(rng.uniform(0, 1, 8)), "s": rng.uniform(0.5, 2.0, (3, n))}  # fmt: skip
    method = Method("pair", "pair", _pair, inputs=(Input("t"), Input("k"), Input("table"), Input("s")),
                    params=_method().params, fit_ops="drjit")  # fmt: skip
    points = [{"a": 1.0 + 0.25 * i, "b": 0.3 + 0.1 * i} for i in range(7)]
    one = DrJitRun(method, inputs)
    calls = [one(p) for p in points]
    assert calls[0][0].shape == (3, n) and calls[0][1].shape == (n,)
    for limit in (1 << 20, 2 * n):  # one replay; replays of two points
        drjit_run.MANY_ELEMENTS = limit
        try:
            fresh = DrJitRun(method, inputs)
            assert fresh.many(points) is None  # (not before its first, traced call)
            fresh(points[0])
            got = fresh.many(points)
        finally:
            drjit_run.MANY_ELEMENTS = 1 << 20
        assert got is not None and len(got) == len(points)
        for g, c in zip(got, calls, strict=True):
            assert all(same_bits(x, y) for x, y in zip(g, c, strict=True))


def test_a_fit_with_its_points_batched_is_the_fit_a_call_a_point(monkeypatch):
    """A Dr.Jit fit's scan and Jacobians evaluated in batched replays (`DrJitRun.many`) give the fit of a
    call a point, bit for bit."""
    rng = np.random.default_rng(9)
    n = 400
    t, k = rng.uniform(0, 3, n), rng.integers(0, 8, n).astype(np.float64)
    table = _Table(rng.uniform(0, 1, 8))
    y = 2.5 * np.exp(-1.5 * t) + table.values[k.astype(int)] + rng.normal(0, 1e-3, n)
    method = Method("lookup", "lookup", _looked_up, inputs=_method().inputs, fit_ops="drjit",
                    params={"a": Param(1.0, 0.0, 10.0, scan=9), "b": Param(1.0, 0.01, 10.0)})  # fmt: skip
    batched = fit_method(method, {"t": t, "k": k, "table": table}, y, solver="trf")
    monkeypatch.setattr(DrJitRun, "many", lambda self, points: None)
    alone = fit_method(method, {"t": t, "k": k, "table": table}, y, solver="trf")
    assert batched.to_dict() == alone.to_dict() and batched.converged
