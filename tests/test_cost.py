"""`rtfit.experiments.cost.reference_vs_stock_rows`: the side-by-side protocol and its arithmetic, with
callables whose durations are set here (no Mitsuba): the warm-up round is not counted, the calls
alternate within each round, each side keeps its best time, and the ratio is rtfit's samples/s over
the stock render's."""

from __future__ import annotations

import time

import pytest

from rtfit.experiments.cost import Stock, reference_vs_stock_rows


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
