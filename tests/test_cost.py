"""`rtfit.experiments.cost.reference_vs_stock_rows`: the side-by-side protocol and its arithmetic, with
callables whose durations are set here (no Mitsuba): the warm-up round is not counted, the calls
alternate within each round, each side keeps its best time, and the ratio is rtfit's samples/s over
the stock render's. The results' ``costs`` rows (`cost_row`, `memory_floor_row`): their arithmetic by hand.
The shared bench loops (`method_bench_rows`, `method_cost_rows`, `rate_row`): their rows, in order."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import drjit as dr
import numpy as np
import pytest

from rtfit.experiments import cost
from rtfit.experiments.cost import (
    MEDIAN_CI_REL,
    NUMPY_MAX_ELEMENTS,
    Stock,
    Timing,
    comparison_row,
    cost_row,
    median_ci,
    memory_floor_row,
    method_bench_rows,
    method_cost_rows,
    numpy_elements,
    rate_row,
    reference_vs_stock_rows,
)


def test_reference_vs_stock_rows_alternate_keep_the_best_and_divide_rates():
    calls = []

    def sleeper(name, seconds):
        def run(seed):
            calls.append((name, seed))
            time.sleep(seconds[min(seed, len(seconds) - 1)])

        return run

    # rtfit: warm-up 0.3 s (not counted), then 0.06, 0.04, 0.05; the stock render: 0.3, then 0.02 each
    ref = sleeper("ref", [0.3, 0.06, 0.04, 0.05])
    stock = sleeper("stock", [0.3, 0.02, 0.02, 0.02])
    rows = reference_vs_stock_rows("rtfit", ref, 1000, [Stock("stock", stock, 4000)], "llvm_ad_rgb", rounds=3)
    assert calls == [(n, k) for k in range(4) for n in ("ref", "stock")]  # alternating, fresh seed per round
    r, s = rows
    assert (r["what"], s["what"], r["samples"], s["samples"]) == ("rtfit", "stock", 1000, 4000)
    assert r["rtfit_vs_this"] is None
    # best times: 0.04 s and 0.02 s plus the sleep's overshoot (never less; a loaded machine adds more)
    assert 0.3 * 1000 / 0.04 / 1e6 < r["Msamples_s"] <= 1000 / 0.04 / 1e6
    assert 0.3 * 4000 / 0.02 / 1e6 < s["Msamples_s"] <= 4000 / 0.02 / 1e6
    assert s["rtfit_vs_this"] == pytest.approx(r["Msamples_s"] / s["Msamples_s"], rel=1e-12)
    assert r["ns_per_sample"] == pytest.approx(1e3 / r["Msamples_s"], rel=1e-12)


def test_cost_row_is_the_timing_per_pixel_with_the_familys_columns():
    """A results' ``costs`` row: ns per pixel = seconds / elements × 10⁹ and pixels/s its reciprocal scaled,
    by hand for 2 ms over 1000 elements; ``per`` kernel elements make one pixel; extra columns before the
    note, in the schema's order."""
    t = Timing(seconds=0.002, elements=1000, repeats=7)
    row = cost_row("sh-l2", "SH L2", "llvm", t, "a note", floats_per_probe=27)
    assert list(row) == [
        "method",
        "label",
        "backend",
        "ns_per_pixel",
        "pixels_per_second",
        "elements",
        "repeats",
        "floats_per_probe",
        "note",
    ]
    assert (row["method"], row["label"], row["backend"], row["note"]) == ("sh-l2", "SH L2", "llvm", "a note")
    assert row["ns_per_pixel"] == pytest.approx(2000.0, rel=1e-12)
    assert row["pixels_per_second"] == pytest.approx(5e5, rel=1e-12)
    assert (row["elements"], row["repeats"], row["floats_per_probe"]) == (1000, 7, 27)
    six = cost_row("conv", "convolution", "cuda", t, per=6)
    assert six["ns_per_pixel"] == pytest.approx(12000.0, rel=1e-12)
    assert six["pixels_per_second"] == pytest.approx(5e5 / 6, rel=1e-12)
    assert six["elements"] == 1000 and six["note"] is None


def test_memory_floor_row_times_the_arrays_it_loads_and_counts_them():
    """The memory-baseline row reads only the Dr.Jit arrays among the inputs (a float constant is no load)
    and names their count in its label, unless a label is given."""
    x = dr.llvm.Float(np.linspace(0.0, 1.0, 4096, dtype=np.float32))
    row = memory_floor_row((x, x, 0.5, x), 4096, "llvm", "the floor")
    assert (row["method"], row["label"], row["note"]) == (
        "memory-baseline",
        "memory traffic baseline (3 loads, 1 store)",
        "the floor",
    )
    assert row["elements"] == 4096 and row["ns_per_pixel"] > 0 and row["repeats"] >= 6
    assert memory_floor_row((x,), 4096, "llvm", "n", label="own words")["label"] == "own words"


def test_comparison_row_compares_rates_when_numpy_ran_on_fewer_elements():
    """NumPy rows are timed on at most `NUMPY_MAX_ELEMENTS` (`numpy_elements`): the Dr.Jit/NumPy column is the
    ratio of elements per second, so 2^24 elements in 0.01 s against 2^22 in 0.1 s is 40×, not 10×."""
    assert numpy_elements(1 << 24) == NUMPY_MAX_ELEMENTS == 1 << 22 and numpy_elements(4096) == 4096
    dr_t, np_t, base = Timing(0.01, 1 << 24, 7), Timing(0.1, 1 << 22, 5), Timing(0.005, 1 << 24, 7)
    row = comparison_row("x", "cuda", dr_t, np_t, base)
    assert row["drjit/numpy"] == pytest.approx(40.0)
    assert row["numpy_Mpx_s"] == pytest.approx((1 << 22) / 0.1 / 1e6)
    assert row["elements"] == 1 << 24 and row["vs_memory_floor"] == pytest.approx(2.0)


def test_rate_row_puts_a_lone_timing_in_its_column():
    """2·10⁶ samples in 0.5 s: 4 M/s and 250 ns each, in the Dr.Jit column (or NumPy's), no ratio or floor."""
    row = rate_row("reference", "llvm_ad_rgb", 2_000_000, 0.5)
    assert row["drjit_Mpx_s"] == pytest.approx(4.0) and row["ns_per_px"] == pytest.approx(250.0)
    assert row["numpy_Mpx_s"] is None and row["drjit/numpy"] is None and row["vs_memory_floor"] is None
    quad = rate_row("quadrature", "numpy", 1000, 0.001, numpy=True, unit="ray")
    assert quad["numpy_Mray_s"] == pytest.approx(1.0) and quad["drjit_Mray_s"] is None
    assert quad["ns_per_ray"] == pytest.approx(1000.0)


def test_method_bench_and_cost_rows_time_every_method_then_the_floor():
    """One comparison row per method (its label, Dr.Jit beside NumPy), then the floor at 1×; one cost row per
    method (its id, its note) then the memory-baseline row."""
    from rtfit.realtime.diffuse import METHODS

    methods = {k: METHODS[k] for k in ("lambert", "half-lambert")}
    n = 4096
    cos = np.linspace(-1.0, 1.0, n, dtype=np.float32)
    np_in = {"cos_theta": cos, "irradiance": np.full(n, 2.0, np.float32)}
    dr_in = {k: dr.llvm.Float(v) for k, v in np_in.items()}
    rows = method_bench_rows(methods, "llvm", dr_in, np_in, n, baseline="floor")
    assert [r["what"] for r in rows] == [m.label for m in methods.values()] + ["floor"]
    assert all(r["numpy_Mpx_s"] > 0 for r in rows[:2]) and rows[-1]["vs_memory_floor"] == pytest.approx(1.0)
    costs = method_cost_rows(methods, "llvm", dr_in, n, lambda m: m.id, "the floor")
    assert [(r["method"], r["note"]) for r in costs] == [
        ("lambert", "lambert"),
        ("half-lambert", "half-lambert"),
        ("memory-baseline", "the floor"),
    ]
    assert costs[-1]["label"] == "memory traffic baseline (2 loads, 1 store)"


def test_median_ci_is_the_widest_order_statistics_pair_reaching_95_percent():
    """The interval (k-th smallest, k-th largest) covers the median with probability 1 − 2 P(B < k),
    B ~ Binomial(n, ½), summed here exactly with integers: `median_ci` takes the largest k at 95 %."""
    for n in range(1, 120):
        times = [float(i) for i in range(n)][::-1]  # order given does not matter

        def cover(k, n=n):
            return 1 - 2 * sum(math.comb(n, i) for i in range(k)) / 2**n

        ks = [k for k in range(1, n // 2 + 1) if cover(k) >= 0.95]
        expect = (float(max(ks) - 1), float(n - max(ks))) if ks else None
        assert median_ci(times) == expect
    assert median_ci([1.0] * 5) is None and median_ci([1.0] * 6) == (1.0, 1.0)  # 93.75 % < 95 % ≤ 96.9 %


def _timed_on_a_fake_clock(monkeypatch, durations, repeats, min_seconds):
    """`cost._median_time` of a call whose k-th run takes ``durations[k % len]`` on a clock set here (the
    suite's own patch of it, conftest.py, undone first)."""
    monkeypatch.undo()
    clock = SimpleNamespace(t=0.0)
    monkeypatch.setattr(cost, "time", SimpleNamespace(perf_counter=lambda: clock.t))
    runs = []

    def call():
        clock.t += durations[len(runs) % len(durations)]
        runs.append(1)

    median, n = cost._median_time(call, repeats, min_seconds)
    assert n == len(runs)
    return median, n


def test_a_stable_timing_stops_once_its_median_is_known(monkeypatch):
    """Equal times: the median's 95 % interval is one point after 6 calls (the fewest that reach 95 %), so
    the loop stops there instead of running 1 s of 10 ms calls; within ± 3 % likewise (1 % apart)."""
    median, n = _timed_on_a_fake_clock(monkeypatch, [0.01], 7, 1.0)
    assert n == 6 and median == pytest.approx(0.01)
    median, n = _timed_on_a_fake_clock(monkeypatch, [0.010, 0.0101, 0.0099], 7, 1.0)
    assert n == 6 and median == pytest.approx(0.01)


def test_a_noisy_timing_runs_to_its_repeats_and_minimum_duration(monkeypatch):
    """Times 2× apart never put the interval within ± 3 % of the median: the loop runs to the cap, the
    old rule (``repeats`` calls and ``min_seconds``: 0.2 s of calls alternating 10 and 20 ms → 14 calls)."""
    median, n = _timed_on_a_fake_clock(monkeypatch, [0.01, 0.02], 7, 0.2)
    assert n == 14 and median == pytest.approx(0.015)
    assert MEDIAN_CI_REL < 0.5  # (0.02 − 0.015) / 0.015 = 1/3 is outside it
    # fewer repeats than 6 (a precompute's 3): the interval never reaches 95 %, the repeats alone count
    assert _timed_on_a_fake_clock(monkeypatch, [0.01], 3, 0.0)[1] == 3


# ------------------------------------------------------- the engine's cost inputs, tiled once per case
def test_cost_inputs_are_the_cyclic_repeat_of_the_cleaned_input_at_every_size_asked():
    """`CostInputs.backend_array`: element i of the repeat is value i mod n of the input, each non-finite
    value float32's max, at sizes below, at and above n (checked against NumPy's own ``resize``)."""
    import drjit as dr

    from rtfit.experiments.audit_cost import CostInputs
    from rtfit.realtime.arrays import backend_float

    v = np.array([0.5, np.nan, -2.0, np.inf, 3.25], np.float64)
    clean = np.array([0.5, np.finfo(np.float32).max, -2.0, np.finfo(np.float32).max, 3.25], np.float32)
    Float = backend_float("llvm")
    tiles = CostInputs()
    for size in (3, 5, 7, 23, 4099):
        arr = tiles.backend_array("x", v, size, Float)
        assert type(arr) is Float and dr.width(arr) == size
        np.testing.assert_array_equal(np.asarray(arr), np.resize(clean, size))
        np.testing.assert_array_equal(tiles.host_prefix("x", v, size), np.resize(clean, size))
    assert tiles.backend_array("x", v, 23, Float) is tiles.backend_array("x", v, 23, Float)  # made once
    other = np.array(v)  # another array of the same name (a row's own inputs) has its own repeat
    assert tiles.backend_array("x", other, 23, Float) is not tiles.backend_array("x", v, 23, Float)
    assert len(tiles.clean) == 2  # cleaned once an array, whatever the sizes


def test_cost_inputs_start_aligned_on_distinct_offsets_of_their_pages():
    """64 inputs of one case: each Dr.Jit array maps its own buffer (its values read back after the
    buffers' other references are gone), 64-byte aligned, and no two start at the same offset in a 4 KiB
    page (`_STAGGER_STEP`: arrays at one offset read from one cache set)."""
    import gc

    from rtfit.experiments.audit_cost import CostInputs
    from rtfit.realtime.arrays import backend_float

    Float = backend_float("llvm")
    tiles = CostInputs(budget=1 << 30)
    inputs = [np.arange(k, k + 37, dtype=np.float64) for k in range(64)]
    arrays = [tiles.backend_array(f"in{k}", a, 5000, Float) for k, a in enumerate(inputs)]
    tiles.clean.clear()
    gc.collect()
    starts = [np.asarray(x).ctypes.data for x in arrays]
    assert all(p % 64 == 0 for p in starts)
    assert len({p % 4096 for p in starts}) == 64
    for a, x in zip(inputs, arrays, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.resize(a.astype(np.float32), 5000))


def test_cost_inputs_keep_at_most_their_budget_dropping_the_oldest():
    from rtfit.experiments.audit_cost import CostInputs
    from rtfit.realtime.arrays import backend_float

    Float = backend_float("llvm")
    tiles = CostInputs(budget=3 * 400)
    arrays = [np.full(10, float(k)) for k in range(4)]
    for k, a in enumerate(arrays):
        tiles.backend_array(f"in{k}", a, 100, Float)  # 400 bytes each
    assert [name for name, *_ in tiles.on_backend] == ["in1", "in2", "in3"]
    again = tiles.backend_array("in0", arrays[0], 100, Float)
    np.testing.assert_array_equal(np.asarray(again), np.zeros(100))


def test_method_cost_methods_of_one_case_share_its_repeated_inputs():
    from rtfit.experiments.audit_cost import CostInputs, method_cost
    from rtfit.realtime.diffuse import METHODS

    n = 300
    rng = np.random.default_rng(1)
    case = SimpleNamespace(
        mask=np.ones(n, bool),
        channel_inputs=[{"cos_theta": rng.uniform(-1, 1, n), "irradiance": rng.uniform(0, 2, n)}],
    )
    tiles = CostInputs()
    made = []
    backend_array = tiles.backend_array
    tiles.backend_array = lambda name, v, size, F: (
        made.append((name, size)) or backend_array(name, v, size, F)
    )  # type: ignore[method-assign]
    rows = [method_cost(METHODS[m], case, "llvm", 1 << 13, tiles=tiles) for m in ("lambert", "half-lambert")]
    assert all(r["elements"] <= 1 << 13 and r["ns_per_pixel"] > 0 and r["repeats"] >= 6 for r in rows)
    assert len(tiles.clean) == 2  # cos_theta and irradiance: cleaned once each for both methods
    # one Dr.Jit array per input and size (the sizing call's and the timed call's), handed to both methods,
    # its values the input's cyclic repeat
    sizes = {key[2] for key in tiles.on_backend}
    assert len(tiles.on_backend) == 2 * len(sizes) and len(sizes) <= 2
    assert set(made) == {(name, size) for name, _, size, _ in tiles.on_backend}  # both asked, one made
    for (_, _, size, _), (src, arr) in tiles.on_backend.items():
        np.testing.assert_array_equal(np.asarray(arr), np.resize(src.astype(np.float32), size))


# ------------------------------------------------------------ a timing is its kernels', not its tracing
def test_a_drjit_timing_is_its_kernels_execution_not_the_python_around_them():
    """`cost.time_drjit` times the kernels a call launches (Dr.Jit's kernel history), not the Python that
    traces them: a call that spends 20 ms in Python before building a kernel of 2^16 elements is timed at
    that kernel's milliseconds, within 1 ms of the same kernel without the sleep (issue 33: the tracing was
    3–180 % of the engine's costs); the caller's KernelHistory flag is left as it was. A call that launches
    no kernel (its result already evaluated) is timed by its wall time: positive."""
    from rtfit.realtime.arrays import backend_float

    Float = backend_float("llvm")
    x = dr.linspace(Float, 0.0, 1.0, 1 << 16)

    def kernel(a):
        return dr.sin(a) * dr.cos(a) + a

    def slow(a):
        time.sleep(0.02)
        return kernel(a)

    flag = dr.flag(dr.JitFlag.KernelHistory)
    plain = cost.time_drjit(kernel, (x,), 1 << 16, repeats=6, min_seconds=0.0)
    traced = cost.time_drjit(slow, (x,), 1 << 16, repeats=6, min_seconds=0.0)
    assert dr.flag(dr.JitFlag.KernelHistory) == flag
    assert 0.0 < traced.seconds < 0.005 and abs(traced.seconds - plain.seconds) < 1e-3
    dr.eval(x)
    idle = cost.time_drjit(lambda a: a, (x,), 1 << 16, repeats=6, min_seconds=0.0)
    assert 0.0 < idle.seconds < 0.01


def test_a_drjit_timing_runs_each_kernel_alone_and_leaves_the_flags_as_they_were():
    """`cost.time_drjit` times each call with blocking launches (`cost.LAUNCH_BLOCKING`: a text of several
    kernels runs each alone, not beside the tracing of the next); the flag is the caller's again after."""
    from rtfit.realtime.arrays import backend_float

    Float = backend_float("llvm")
    x = dr.linspace(Float, 0.0, 1.0, 1 << 12)
    seen = []

    def steps(a):
        seen.append(dr.flag(cost.LAUNCH_BLOCKING))
        for _ in range(3):  # a march: a kernel a step
            a = dr.sin(a) + 0.5
            dr.eval(a)
        return a

    before = dr.flag(cost.LAUNCH_BLOCKING)
    t = cost.time_drjit(steps, (x,), 1 << 12, repeats=6, min_seconds=0.0)
    assert seen and all(seen) and dr.flag(cost.LAUNCH_BLOCKING) == before and t.seconds > 0.0
