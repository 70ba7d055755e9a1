"""An interrupted audit leaves a partial report of its finished cases, and the rerun completes it from the
pass cache (issue 31). Oracles: the report's own files (which cases, the PARTIAL note), the exit status
a shell sees for SIGTERM (143), and the cache's pass counts (a resumed case renders no pass)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rtfit.experiments import audit_cases, audit_run
from rtfit.experiments.audit_run import audit
from rtfit.experiments.results import load_results

CBOX = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
FAST = {"cost_elements": 1 << 12, "metrics": ("rmse", "mae")}
SMALL = {"width": 16, "height": 16, "spp": 4, "pass_spp": 2, "fit": False}


def test_an_interrupted_audit_reports_its_finished_cases_and_the_rerun_completes_it(tmp_path, monkeypatch):
    """Ctrl-C while sdf-occlusion renders: the cases before it (diffuse, irradiance-volumes,
    ambient-aperture, in registry order) are in a valid report marked partial, naming what is missing; the
    rerun renders none of their passes again and reports every case."""
    family = audit_run.AUDITED["sdf-occlusion"]

    def interrupted(setup, app):
        raise KeyboardInterrupt

    monkeypatch.setitem(
        audit_run.AUDITED, "sdf-occlusion", type(family)(**{**family.__dict__, "cases": interrupted})
    )
    out, cache = tmp_path / "out", tmp_path / "cache"
    with pytest.raises(KeyboardInterrupt) as caught:
        audit(CBOX, out=out, cache=cache, **SMALL, **FAST)
    report = out / "audit-cbox-rgb"
    assert caught.value.partial_report == report  # type: ignore[attr-defined]
    partial = load_results(report)
    # the families before sdf-occlusion in registry order: diffuse, irradiance-volumes, ambient-aperture
    assert [c.id for c in partial.cases] == ["light0-unshadowed", "light0-shadowed", "volume", "caps"]
    assert (
        partial.notes[0].startswith("PARTIAL REPORT")
        and "sdf-occlusion (ambient occlusion" in partial.notes[0]
    )
    assert partial.summary.startswith("Partial (interrupted).")
    assert (report / "report.html").is_file()
    monkeypatch.undo()
    full = audit(CBOX, out=out, cache=cache, **SMALL, **FAST)
    assert [c.id for c in full.cases][:5] == ["light0-unshadowed", "light0-shadowed", "volume", "caps", "ao"]
    assert all(c.reference.passes_rendered == 0 for c in full.cases[:4])  # from the cache
    assert not any(n.startswith("PARTIAL") for n in load_results(report).notes)


def _interrupted_in_shared_phase(tmp_path, monkeypatch, nth: int, solver_imported: bool = True):
    """A fitted diffuse audit of the Cornell box, Ctrl-C at the start of its ``nth`` shared phase (1: the
    fits, 2: the metrics; `audit_cases.shared_map`, whose calls that share nothing, the partial report's
    metrics run here in turn, pass through): its partial results, and the shared phases' ``run`` functions.
    ``solver_imported`` False: the fits' solver is imported beside the declared rows' metrics first
    (`CaseRun._solver_beside_metrics`), phase 1, and the fits and the fitted rows' metrics are 2 and 3."""
    real = audit_cases.shared_map
    calls = []

    def interrupted(tasks, run, may, before=None):
        if any(may):
            calls.append(run)
            if len(calls) == nth:
                raise KeyboardInterrupt
        return real(tasks, run, may, before=before)

    monkeypatch.setattr(audit_cases, "shared_map", interrupted)
    monkeypatch.setattr(audit_cases, "_solver_imported", lambda: solver_imported)
    out, cache = tmp_path / "out", tmp_path / "cache"
    with pytest.raises(KeyboardInterrupt):
        audit(CBOX, out=out, cache=cache, approximations=["diffuse"], **{**SMALL, "fit": True}, **FAST)
    return load_results(out / "audit-cbox-rgb"), calls


def test_an_audit_interrupted_in_its_fits_reports_every_case_with_its_declared_rows(tmp_path, monkeypatch):
    """Ctrl-C while the fits run (after every case is evaluated): every case is in the partial report, its
    declared rows with their metrics, no fitted row, and a note naming the rows not fitted."""

    partial, _ = _interrupted_in_shared_phase(tmp_path, monkeypatch, 1)
    assert [c.id for c in partial.cases] == ["light0-unshadowed", "light0-shadowed"]
    rows = [a for c in partial.cases for a in c.approximations]
    assert {a.method for a in rows} == {"lambert", "half-lambert", "wrap"} and not any(a.fitted for a in rows)
    assert all((a.metrics["rmse"].value or -1.0) >= 0 for a in rows)
    assert any("not fitted (the run was interrupted first): wrap" in n for n in partial.notes)
    assert partial.summary.startswith("Partial (interrupted).")


def test_an_audit_interrupted_beside_the_solver_import_reports_every_case_unfitted(tmp_path, monkeypatch):
    """Ctrl-C while the declared rows' metrics are taken beside the solver's import (before any fit): every
    case in the partial report with its declared rows and their metrics (taken again here), no fitted row."""
    partial, calls = _interrupted_in_shared_phase(tmp_path, monkeypatch, 1, solver_imported=False)
    assert len(calls) == 1
    assert [c.id for c in partial.cases] == ["light0-unshadowed", "light0-shadowed"]
    rows = [a for c in partial.cases for a in c.approximations]
    assert {a.method for a in rows} == {"lambert", "half-lambert", "wrap"} and not any(a.fitted for a in rows)
    assert all((a.metrics["rmse"].value or -1.0) >= 0 for a in rows)
    assert any("not fitted (the run was interrupted first): wrap" in n for n in partial.notes)


def test_an_audit_interrupted_in_its_metrics_reports_the_fits_that_ran(tmp_path, monkeypatch):
    """Ctrl-C while the metrics run (every fit done): the partial report holds every case with its fitted
    rows and every row's metrics (computed again in the audit's process), and no "not fitted" note."""
    partial, calls = _interrupted_in_shared_phase(tmp_path, monkeypatch, 2)
    assert len(calls) == 2
    assert [c.id for c in partial.cases] == ["light0-unshadowed", "light0-shadowed"]
    rows = [a for c in partial.cases for a in c.approximations]
    assert sum(a.fitted for a in rows) == 2 and all((a.metrics["rmse"].value or -1.0) >= 0 for a in rows)
    assert not any("not fitted" in n for n in partial.notes)
    assert partial.summary.startswith("Partial (interrupted).")


def test_sigterm_ends_the_command_with_143_and_a_partial_report(tmp_path):
    """``timeout`` sends SIGTERM: the audit stops as after Ctrl-C, exit 143, one line naming the partial
    report, the finished cases in it."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "rtfit", "audit", str(CBOX), "--width", "16", "--height", "16", "--spp", "4",
           "--pass-spp", "2", "--no-fit", "--out", str(out), "--cache", str(tmp_path / "cache")]  # fmt: skip
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stderr is not None
    deadline = time.monotonic() + 300
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if "light0-shadowed:" in line and "rows evaluated" in line:
            proc.send_signal(signal.SIGTERM)
            break
        assert time.monotonic() < deadline, "".join(lines)
    _, err = proc.communicate(timeout=300)
    if proc.returncode == 0:
        pytest.skip("the audit finished before SIGTERM arrived (nothing to interrupt)")
    assert proc.returncode == 143, "".join(lines) + err
    assert f"the report of the finished cases is in {out / 'audit-cbox-rgb'}" in err
    assert "Traceback" not in err
    ids = [c.id for c in load_results(out / "audit-cbox-rgb").cases]
    assert ids[:2] == ["light0-unshadowed", "light0-shadowed"] and "caps" not in ids
