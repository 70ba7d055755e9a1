"""`rtfit.experiments.cost.reference_vs_stock_rows`: the side-by-side protocol and its arithmetic, with
callables whose durations are set here (no Mitsuba): the warm-up round is not counted, the calls
alternate within each round, each side keeps its best time, and the ratio is rtfit's samples/s over
the stock render's. The results' ``costs`` rows (`cost_row`, `memory_floor_row`): their arithmetic by hand."""

from __future__ import annotations

import time

import drjit as dr
import numpy as np
import pytest

from rtfit.experiments.cost import (
    NUMPY_MAX_ELEMENTS,
    Stock,
    Timing,
    comparison_row,
    cost_row,
    memory_floor_row,
    numpy_elements,
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
    assert row["elements"] == 4096 and row["ns_per_pixel"] > 0 and row["repeats"] >= 7
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
