"""A row's precompute (a bake an engine pays apart from the per-pixel kernel, issue 30): the engine times it
beside the kernel's ns per pixel, records it in the cost records and results.json, shows it in the cost
table, and turns a precompute that raises into one failed check.

Oracles: a toy precompute whose work is known: the toy method's own kernel evaluated once on N copies of
the case's pixels (one Dr.Jit kernel of N × pixels elements), so its time over the per-pixel total (ns per
pixel × pixels) is N up to timing noise; a precompute that raises ZeroDivisionError; the records' own
fields read back from the file on disk.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments import audit_run
from rtfit.experiments.audit import AuditError
from rtfit.experiments.audit_family import Precompute
from rtfit.experiments.audit_run import audit
from rtfit.experiments.cost import time_precompute
from rtfit.experiments.records import Cost, amortised_ns
from rtfit.realtime.arrays import DRJIT_OPS, backend_float, to_drjit
from rtfit.realtime.methods import Input, Method

CBOX = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
N = 1024
"""The toy precompute's work in units of the per-pixel kernel over the case's pixels: N × ~250 pixels ≈ the
per-pixel timing's 2^18 elements (on 2 shared CPU cores the rate per element of this kernel changed 4× between
2^18 and 2^20 elements: both timings are made at one size)."""


def _chain(ops, x):
    """32 fused multiply-adds per element (compute-bound: the per-pixel and the precompute timings measure
    the same arithmetic, not memory), bounded for x ∈ [0, 1] (v ≤ 2)."""
    v = x
    for _ in range(32):
        v = ops.fma(v * v, 0.25, x)
    return v


def _toy(mid: str) -> Method:
    return Method(id=mid, label=f"toy {mid}", kernel=_chain, inputs=(Input("x", "1", "x", (0.0, 1.0)),))


def _toy_family(monkeypatch):
    """The diffuse family's cases on the Cornell box with two toy rows: ``good`` (its precompute = the kernel
    on N copies of the pixels, `N`) and ``bad`` (a precompute that raises)."""
    family = audit_run.AUDITED["diffuse"]
    original = family.cases
    Float = backend_float("llvm")

    def cases(setup, app):
        good, bad = app.methods[0], app.methods[1]  # (ids the applicability lets through)
        out = []
        for c in original(setup, app):
            n = int(c.mask.sum())
            x = np.random.default_rng(0).uniform(0.0, 1.0, n)
            big = to_drjit(Float, np.tile(x, N).astype(np.float32))  # made once: the run is the kernel alone
            pre = Precompute(lambda big=big: _chain(DRJIT_OPS, big), "light", f"{N}× the kernel")
            broken = Precompute(lambda: 1 / 0, "scene", "a bake that divides by zero")
            rows = {good: _toy(good), bad: _toy(bad)}
            inputs = ({"x": x},) * 3
            precompute = {good: pre, bad: broken}
            out.append(replace(c, methods=rows, channel_inputs=inputs, row_inputs={}, params={}, uncosted={},
                               precompute=precompute))  # fmt: skip
        return out

    monkeypatch.setitem(audit_run.AUDITED, "diffuse", type(family)(**{**family.__dict__, "cases": cases}))


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    try:
        _toy_family(mp)
        out = tmp_path_factory.mktemp("toy")
        r = audit(CBOX, ["diffuse"], width=16, height=16, spp=4, pass_spp=2, fit=False, out=out,
                  cache=out / "cache", cost_elements=1 << 18, metrics=("rmse",))  # fmt: skip
    finally:
        mp.undo()
    return r


def test_the_split_has_the_known_ratio(toy_run):
    """The toy precompute does N times the per-pixel kernel's work over the case's pixels: its time over the
    per-pixel total is N within a factor of 4 (two timings of the same arithmetic on a shared machine)."""
    r = toy_run
    (good, _bad) = [m for m in r.costs if r.costs[m].get("precompute_trigger")]
    c = r.costs[good]
    assert c["precompute_trigger"] == "light" and c["precompute_pixels"] == int(r.cases[0].mask.sum())
    per_pixel_total_ms = c["ns_per_pixel"] * c["precompute_pixels"] * 1e-6
    ratio = c["precompute_ms"] / per_pixel_total_ms
    assert N / 4 <= ratio <= 4 * N, (c, ratio)


def test_a_precompute_that_raises_is_one_failed_check(toy_run):
    r = toy_run
    failed = [ch for ch in r.results.checks if not ch.passed]
    assert len(failed) == 1, failed  # timed once (the method's cost), not once per case
    (ch,) = failed
    assert "its precompute (a bake that divides by zero) runs" in ch.name
    assert ch.value == "ZeroDivisionError: division by zero" and ch.expected == "no error"
    bad = next(m for m in r.costs if r.costs[m].get("precompute_trigger") == "scene")
    assert r.costs[bad]["precompute_ms"] is None and r.costs[bad]["ns_per_pixel"] > 0


def test_results_json_and_the_cost_table_carry_the_precompute(toy_run):
    doc = json.loads((toy_run.out / "results.json").read_text(encoding="utf-8"))
    rows = {c["method"]: c for c in doc["costs"]}
    good = next(m for m, c in rows.items() if c.get("precompute_trigger") == "light")
    assert rows[good]["precompute_ms"] > 0 and rows[good]["precompute_note"].startswith(f"{N}× the kernel")
    ap = next(a for a in doc["cases"][0]["approximations"] if a["method"] == good)
    assert ap["cost"]["precompute_ms"] == rows[good]["precompute_ms"]
    assert ap["cost"]["precompute_pixels"] == rows[good]["precompute_pixels"]
    md = (toy_run.out / "report.md").read_text(encoding="utf-8")
    assert "Precompute ms" in md and "Precompute ns/pixel per frame" in md and "Precompute paid" in md
    assert "as if it were paid every frame" in md


def test_amortised_share_per_pixel():
    assert amortised_ns(2.0, 1000) == pytest.approx(2000.0, rel=1e-15)  # 2 ms over 1000 pixels: 2 µs each
    assert amortised_ns(None, 1000) is None and amortised_ns(2.0, 0) is None
    c = Cost(method="m", precompute_ms=0.5, precompute_pixels=250)
    assert c.precompute_per_pixel == pytest.approx(2000.0, rel=1e-15)


def test_time_precompute_times_the_whole_call():
    """A call evaluating a Dr.Jit kernel: a warm-up, then repeats; the timing is of one whole call."""
    Float = backend_float("llvm")
    calls = []

    def run():
        calls.append(1)
        return Float(np.arange(1000, dtype=np.float32)) * 2.0

    t = time_precompute(run)
    assert t.elements == 1 and t.seconds > 0 and len(calls) == 1 + t.repeats and t.repeats == 3


def test_a_bad_trigger_is_refused_in_one_line():
    with pytest.raises(AuditError, match="trigger 'sometimes': one of frame, light, scene"):
        Precompute(run=lambda: None, trigger="sometimes", what="x")


def test_the_books_error_vs_cost_point_adds_the_precompute_per_frame(toy_run):
    """The book's point of a method with a precompute: its kernel's ns/pixel, and (``x_pre``) that plus the
    precompute spread over the case's pixels (records' fields, read back from results.json)."""
    from rtfit.experiments.book_plots import family_points, pareto_point
    from rtfit.experiments.results import load_results

    r = load_results(toy_run.out)
    costs = {c.method: c for c in r.costs}
    for p in family_points(r):
        c = costs[p.method]
        if c.precompute_ms is None:
            assert p.precompute_ns is None and "x_pre" not in pareto_point(p)
            continue
        share = c.precompute_ms * 1e6 / c.precompute_pixels
        assert p.precompute_ns == pytest.approx(share, rel=1e-12) and p.precompute_trigger == "light"
        assert pareto_point(p)["x_pre"] == pytest.approx(p.ns_per_pixel + share, rel=1e-12)


def test_a_second_audit_reports_the_kept_precompute_timing_without_running_it(toy_run, monkeypatch):
    """The same toy audit again into the same cache (issue 33, session 33): the good row's precompute is not
    timed again (`time_precompute` is called for the bad one alone, which kept nothing) and its
    ``precompute_ms`` is the first run's, its note saying so; the bad one is still one failed check."""
    from rtfit.experiments import audit_cases

    _toy_family(monkeypatch)
    timed = []
    real = audit_cases.time_precompute
    monkeypatch.setattr(audit_cases, "time_precompute", lambda run, *a, **k: timed.append(run) or real(run))
    cache = toy_run.out.parent / "cache"  # (the fixture's cache: ``out`` is the report's own directory)
    again = audit(CBOX, ["diffuse"], width=16, height=16, spp=4, pass_spp=2, fit=False,
                  cache=cache, cost_elements=1 << 18, metrics=("rmse",))  # fmt: skip
    good = next(m for m in again.costs if again.costs[m].get("precompute_trigger") == "light")
    assert again.costs[good]["precompute_ms"] == toy_run.costs[good]["precompute_ms"]
    assert "by an earlier run" in again.costs[good]["precompute_note"]
    assert len(timed) == 1  # the bad one, run again (nothing kept)
    assert next(ch for ch in again.results.checks if not ch.passed).value.startswith("ZeroDivisionError")


def test_a_shared_step_is_timed_once_and_added_to_each_rows_own_part(monkeypatch):
    """`Precompute.shared` (issue 33, session 33): rows whose precomputes start with one step
    (light-path-maps' entry points and shadow rays before each K's clusters) time it once; each row's
    ``precompute_ms`` is its own part's time plus the shared one's (stand-in timings: 100 ms shared, 5 and
    7 ms own)."""
    from rtfit.experiments import audit_cases
    from rtfit.experiments.cost import Timing

    shared = Precompute(lambda: "shared", "scene", "the shared step")
    # each row's own part is handed the shared step's product (else it names a time the test has not)
    rows = [
        Precompute(lambda made, own=own: own if made == "shared" else made, "scene", own, shared=shared)
        for own in ("own a", "own b")
    ]
    took = {"shared": 0.100, "own a": 0.005, "own b": 0.007}
    calls = []
    monkeypatch.setattr(audit_cases, "time_precompute",
                        lambda run: calls.append(run()) or Timing(took[run()], 1, 1))  # fmt: skip
    run = audit_cases.CaseRun.__new__(audit_cases.CaseRun)
    run.shared_ms, run.shared_products = {}, {}
    ms = [run._precompute_ms(p) for p in rows]
    assert ms == pytest.approx([105.0, 107.0]) and calls.count("shared") == 1
