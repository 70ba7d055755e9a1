"""`rtfit.fitting.forked_fits.shared_map`: a serial map's results, in order, whichever process ran each task;
a task the helper fails, loses or never answers is run again here (raising what a serial run raises), and
the wait for a stuck helper is bounded."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from rtfit.fitting import forked_fits
from rtfit.fitting.forked_fits import shared_map, two_cores

PARENT = os.getpid()
needs_two = pytest.mark.skipif(not two_cores(), reason="one core (or no fork): shared_map runs serially")


def _square_and_pid(x):
    time.sleep(0.02)  # long enough that both processes take tasks
    return x * x, os.getpid()


@needs_two
def test_results_are_the_serial_maps_in_order_and_both_processes_work():
    out, seconds = shared_map(list(range(12)), _square_and_pid, [True] * 12)
    assert [v for v, _ in out] == [x * x for x in range(12)]
    pids = {p for _, p in out}
    assert PARENT in pids and len(pids) == 2, "the helper took a share of the tasks"
    assert len(seconds) == 12 and all(s >= 0.02 for s in seconds)


@needs_two
def test_a_task_the_helper_may_not_run_runs_here():
    may = [i % 2 == 0 for i in range(10)]
    out, _ = shared_map(list(range(10)), _square_and_pid, may)
    assert all(p == PARENT for (_, p), m in zip(out, may, strict=True) if not m)


def test_fewer_than_two_shareable_tasks_run_here_in_turn():
    out, _ = shared_map([1, 2, 3], _square_and_pid, [True, False, False])
    assert [v for v, _ in out] == [1, 4, 9] and {p for _, p in out} == {PARENT}


def _fails_in_the_helper(x):
    if os.getpid() != PARENT and x == 3:
        raise RuntimeError("helper only")
    time.sleep(0.02)
    return x


@needs_two
def test_a_task_that_raises_in_the_helper_is_run_again_here():
    out, _ = shared_map([0, 1, 2, 3], _fails_in_the_helper, [True] * 4)  # (the helper takes 3 first)
    assert out == [0, 1, 2, 3]


def _raises_everywhere(x):
    time.sleep(0.02)
    if x == 3:
        raise ValueError("task 3 is bad")
    return x


@needs_two
def test_an_error_is_raised_here_as_a_serial_run_raises_it():
    with pytest.raises(ValueError, match="task 3 is bad"):
        shared_map(list(range(6)), _raises_everywhere, [True] * 6)


def _helper_dies(x):
    if os.getpid() != PARENT:
        os._exit(3)  # a crash of the helper mid-task
    time.sleep(0.02)
    return x


@needs_two
def test_a_helper_that_dies_loses_nothing():
    out, _ = shared_map(list(range(6)), _helper_dies, [True] * 6)
    assert out == list(range(6))


def _helper_hangs(x):
    if os.getpid() != PARENT:
        time.sleep(3600)  # stuck (a deadlock in the helper)
    return x


@needs_two
def test_a_stuck_helper_is_killed_after_the_quiet_limit(monkeypatch):
    monkeypatch.setattr(forked_fits, "_child_quiet_limit", lambda longest: 0.5)
    t = time.perf_counter()
    out, _ = shared_map(list(range(4)), _helper_hangs, [True] * 4)
    assert out == list(range(4)) and time.perf_counter() - t < 30


def test_the_quiet_limit_is_ten_seconds_or_eight_longest_tasks():
    assert forked_fits._child_quiet_limit(0.1) == 10.0
    assert forked_fits._child_quiet_limit(5.0) == 40.0


@needs_two
def test_no_warning_where_a_caller_has_started_jax():
    """JAX warns at any fork once its backends run (its threads would deadlock a child that used it); the
    helper never does, and a run under ``-W error`` (this suite's setting) must not fail on it."""
    import warnings

    jnp = pytest.importorskip("jax.numpy")
    jnp.zeros(1).block_until_ready()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out, _ = shared_map(list(range(4)), _square_and_pid, [True] * 4)
    assert [v for v, _ in out] == [0, 1, 4, 9]


@needs_two
def test_an_audits_shared_fits_are_those_of_one_process(tmp_path, monkeypatch):
    """The Cornell box's obscurance fits (NumPy and Dr.Jit runs) and shadow-map fits (Dr.Jit runs), shared
    with the helper (Dr.Jit's pool without a worker thread: either process runs Dr.Jit fits), then all in
    one process: the same fitted values, stderr and SSR bit for bit; the helper did take some."""
    from pathlib import Path

    from rtfit.experiments.audit_run import audit

    cbox = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
    kw = {"width": 16, "height": 16, "spp": 4, "pass_spp": 2, "cache": tmp_path / "cache",
          "metrics": ("rmse",), "approximations": ["obscurances", "pcf-soft-shadows"],
          "cost_elements": 1 << 12}  # fmt: skip
    marks: list[bytes] = []
    close = forked_fits._Claims.close

    def kept(self):
        marks.append(bytes(self.bytes))
        close(self)

    monkeypatch.setattr(forked_fits._Claims, "close", kept)

    def fits(result):
        return {(o.case, o.row): o.fit for rows in result.outcomes.values() for o in rows.values() if o.fit}

    shared = fits(audit(cbox, **kw))
    assert marks and any(forked_fits._CHILD in m for m in marks), "the helper fitted some rows"
    monkeypatch.setattr(forked_fits, "two_cores", lambda: False)
    alone = fits(audit(cbox, **kw))
    assert len(shared) >= 2 and shared == alone


@needs_two
def test_an_audits_shared_metrics_and_figures_are_those_of_one_process(tmp_path, monkeypatch):
    """Every row's metrics (ꟻLIP among them: its maps come back to this process for the figures) and the
    report's figures, a case a task shared with the helper, then all in one process: the same metrics,
    notes, figure entries and PNG bytes."""
    from pathlib import Path

    from rtfit.experiments.audit_run import audit

    cbox = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
    kw = {"width": 24, "height": 24, "spp": 4, "pass_spp": 2, "cache": tmp_path / "cache", "fit": False,
          "metrics": ("rmse", "flip"), "approximations": ["diffuse", "obscurances"],
          "cost_elements": 1 << 12}  # fmt: skip

    def measured(result):
        return {
            (o.case, o.row): o.metrics.to_dict() for rows in result.outcomes.values() for o in rows.values()
        }

    shared = audit(cbox, out=tmp_path / "shared", **kw)
    monkeypatch.setattr(forked_fits, "two_cores", lambda: False)
    alone = audit(cbox, out=tmp_path / "alone", **kw)
    assert len(shared.cases) >= 2 and measured(shared) == measured(alone)
    assert shared.skipped == alone.skipped
    a, b = tmp_path / "shared" / "audit-cbox-rgb", tmp_path / "alone" / "audit-cbox-rgb"
    pngs = sorted(p.name for p in (a / "figures").iterdir())
    assert pngs == sorted(p.name for p in (b / "figures").iterdir()) and len(pngs) >= 4
    assert all((a / "figures" / n).read_bytes() == (b / "figures" / n).read_bytes() for n in pngs)
    assert shared.results.figures == alone.results.figures


def test_a_process_given_one_core_forks_no_helper(monkeypatch):
    """A pool's job worker with a one-core share (`limit_cores`, set by its initialiser) fits alone."""
    monkeypatch.setattr(forked_fits, "_CORE_BUDGET", [1])
    assert not two_cores()
    out, _ = shared_map(list(range(4)), _square_and_pid, [True] * 4)
    assert {p for _, p in out} == {PARENT}
    forked_fits.limit_cores(None)
    assert forked_fits._CORE_BUDGET == [None]


@needs_two
def test_a_helper_killed_holding_the_task_lock_does_not_stop_this_process(monkeypatch):
    """The lock is a token in a pipe: a helper that dies holding it never puts it back, and this process
    then takes the lock itself (it checks every 0.5 s of waiting that the helper still lives)."""

    def dies_holding_the_token(tasks, run, claims, order, fd, spill):
        os.read(claims.token_r, 1)
        os._exit(1)

    monkeypatch.setattr(forked_fits, "_child", dies_holding_the_token)  # (it waits for the token, takes it)
    out, _ = shared_map(list(range(6)), _square_and_pid, [True] * 6)
    assert [v for v, _ in out] == [x * x for x in range(6)] and {p for _, p in out} == {PARENT}


def _big(x: int) -> tuple[int, np.ndarray, int]:
    """A result larger than the pipe carries (`forked_fits._PIPE_PAYLOAD`), and the process's id."""
    time.sleep(0.01)
    return x, np.full(1 << 15, float(x)), os.getpid()


@needs_two
def test_large_results_come_back_through_spill_files_that_are_removed(monkeypatch):
    """A result over `_PIPE_PAYLOAD` bytes comes back through a file of the spill directory (the pipe
    carries its header): every value is the serial one, the helper ran some, and the directory is gone."""
    made = []
    real = forked_fits.tempfile.mkdtemp

    def recorded(**kw):
        made.append(real(**kw))
        return made[-1]

    monkeypatch.setattr(forked_fits.tempfile, "mkdtemp", recorded)
    out, _ = shared_map(list(range(8)), _big, [True] * 8)
    assert [x for x, _, _ in out] == list(range(8))
    assert all(np.array_equal(a, np.full(1 << 15, float(x))) for x, a, _ in out)
    pids = {p for _, _, p in out}
    assert PARENT in pids and len(pids) == 2, "the helper sent some of them"
    assert made and not os.path.exists(made[0])


def _drjit_task(k):
    """A Dr.Jit kernel of its own (k in its text: compiled or loaded where the task runs), on LLVM float64."""
    import drjit as dr

    time.sleep(0.02)  # long enough that both processes take tasks (a cached kernel runs in microseconds)
    x = dr.arange(dr.llvm.Float64, 4096) * (1e-3 * (k + 1))
    return float(dr.sum(dr.exp(-x) * dr.log(x + 1.0) + dr.sin(x * float(k)))[0]), os.getpid()


@needs_two
def test_dr_jit_tasks_run_in_the_helper_beside_a_pool_of_no_worker():
    """With Dr.Jit's pool of two shrunk to the calling thread (`_drjit_threads_beside_a_helper`), the forked
    helper runs Dr.Jit kernels of its own (new kernels compiled there): the serial map's values bit for bit,
    the helper took some, no task was run again here for want of an answer, and the pool is put back after;
    with more threads, Dr.Jit fits are not the helper's (`_drjit_beside_a_helper`)."""
    import drjit as dr

    from rtfit.experiments.audit_cases import _drjit_beside_a_helper, _drjit_threads_beside_a_helper

    threads = dr.thread_count()
    dr.set_thread_count(2)  # (a machine of two cores: the pool beside the helper is the calling thread)
    tasks = list(range(8))
    with _drjit_threads_beside_a_helper(True):
        assert dr.thread_count() == 1
        t = time.perf_counter()
        shared, _ = shared_map(tasks, _drjit_task, [True] * len(tasks))
        took = time.perf_counter() - t
    assert dr.thread_count() == 2
    dr.set_thread_count(threads)
    serial = [_drjit_task(k) for k in tasks]
    assert [v for v, _ in shared] == [v for v, _ in serial]
    assert {p for _, p in shared} - {PARENT}, "the helper ran Dr.Jit tasks"
    assert took < forked_fits._child_quiet_limit(0.0), "no task waited out the quiet limit"
    dr.set_thread_count(4)
    try:
        assert not _drjit_beside_a_helper("llvm")
    finally:
        dr.set_thread_count(threads)
    assert not _drjit_beside_a_helper("cuda")


def _pid_and_flag(x, flag):
    return x, os.getpid(), bool(flag)


@needs_two
def test_before_runs_here_once_after_the_fork():
    """``before`` runs in this process, once, after the fork (the helper's tasks do not see what it did)
    and before this process takes a task; serially, before every task."""
    done: list[int] = []
    flag = [False]

    def before():
        time.sleep(0.05)  # the helper is at the tasks meanwhile
        done.append(os.getpid())
        flag[0] = True

    out, _ = shared_map(list(range(8)), lambda x: _pid_and_flag(x, flag[0]), [True] * 8, before=before)
    assert done == [PARENT] and [v for v, _, _ in out] == list(range(8))
    assert all(seen for _, pid, seen in out if pid == PARENT), "this process's tasks come after it"
    assert not any(seen for _, pid, seen in out if pid != PARENT), "the helper was forked before it"
    assert any(pid != PARENT for _, pid, _ in out)
    done.clear()
    flag[0] = False
    out, _ = shared_map([1], lambda x: _pid_and_flag(x, flag[0]), [True], before=before)  # (one task: serial)
    assert done == [PARENT] and out == [(1, PARENT, True)]


@needs_two
def test_metrics_taken_beside_the_solver_import_are_those_taken_after_the_fits(tmp_path, monkeypatch):
    """The declared rows' metrics taken by the helper while this process imports the fits' solver
    (`CaseRun._solver_beside_metrics`), the fitted rows' after the fits: the metrics, fits and figures of
    a run that took every metric after the fits (the solver already imported), bit for bit."""
    from pathlib import Path

    from rtfit.experiments import audit_cases
    from rtfit.experiments.audit_run import audit

    cbox = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
    kw = {"width": 24, "height": 24, "spp": 4, "pass_spp": 2, "cache": tmp_path / "cache",
          "metrics": ("rmse", "flip"), "approximations": ["diffuse", "obscurances"],
          "cost_elements": 1 << 12}  # fmt: skip
    early: list[int] = []
    shared = audit_cases.shared_map

    def counted(tasks, run, may, before=None):
        if before is not None:
            early.append(len(tasks))
        return shared(tasks, run, may, before=before)

    monkeypatch.setattr(audit_cases, "shared_map", counted)
    monkeypatch.setattr(audit_cases, "_solver_imported", lambda: False)
    beside = audit(cbox, out=tmp_path / "beside", **kw)
    assert early and early[0] >= 2, "the declared rows' metrics were taken beside the import"
    monkeypatch.setattr(audit_cases, "_solver_imported", lambda: True)
    after = audit(cbox, out=tmp_path / "after", **kw)

    def rows(result):
        return {
            (o.case, o.row): (o.metrics.to_dict(), o.fit)
            for r in result.outcomes.values()
            for o in r.values()
        }

    assert rows(beside) == rows(after) and any(fit for _m, fit in rows(beside).values())
    a, b = tmp_path / "beside" / "audit-cbox-rgb", tmp_path / "after" / "audit-cbox-rgb"
    pngs = sorted(p.name for p in (a / "figures").iterdir())
    assert pngs == sorted(p.name for p in (b / "figures").iterdir()) and len(pngs) >= 4
    assert all((a / "figures" / n).read_bytes() == (b / "figures" / n).read_bytes() for n in pngs)


def test_metric_tasks_split_the_largest_case_until_there_are_four(monkeypatch):
    """`metric_tasks`: on two cores, a case's rows split in order (the largest task first) until there are
    `METRIC_TASKS_MIN` tasks or none has two rows; enough tasks, or single rows, are left as they are; on one
    core nothing is split."""
    from rtfit.experiments import audit_cases
    from rtfit.experiments.audit_cases import METRIC_TASKS_MIN, metric_tasks

    one = [("case", {f"r{i}": i for i in range(7)})]
    monkeypatch.setattr(audit_cases, "two_cores", lambda: False)
    assert metric_tasks(one) == one, "one core: a task a case (its reference's features computed once)"
    monkeypatch.setattr(audit_cases, "two_cores", lambda: True)
    split = metric_tasks(one)
    assert len(split) == METRIC_TASKS_MIN == 4
    assert [r for _c, rows in split for r in rows] == [f"r{i}" for i in range(7)]
    assert all(c == "case" and rows for c, rows in split)
    many = [(f"c{i}", {"a": 1, "b": 2}) for i in range(5)]
    assert metric_tasks(many) == many
    singles = [("c0", {"a": 1}), ("c1", {"b": 2})]
    assert metric_tasks(singles) == singles and metric_tasks([]) == []


@needs_two
def test_metrics_split_within_a_case_are_those_of_a_case_a_task(tmp_path, monkeypatch):
    """The rows of a case measured in several tasks (`metric_tasks`, the reference's ꟻLIP features and
    floors taken again where a task needs them) give a case-a-task run's metrics and figures, bit for bit."""
    from pathlib import Path

    from rtfit.experiments import audit_cases
    from rtfit.experiments.audit_run import audit

    cbox = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
    kw = {"width": 24, "height": 24, "spp": 4, "pass_spp": 2, "cache": tmp_path / "cache",
          "metrics": ("rmse", "flip", "ssim"), "approximations": ["diffuse"],
          "cost_elements": 1 << 12}  # fmt: skip

    def rows(result):
        return {(o.case, o.row): o.metrics.to_dict() for r in result.outcomes.values() for o in r.values()}

    monkeypatch.setattr(audit_cases, "METRIC_TASKS_MIN", 8)
    split = audit(cbox, out=tmp_path / "split", **kw)
    monkeypatch.setattr(audit_cases, "METRIC_TASKS_MIN", 1)
    whole = audit(cbox, out=tmp_path / "whole", **kw)
    assert rows(split) == rows(whole) and len(rows(split)) >= 4
    a, b = tmp_path / "split" / "audit-cbox-rgb", tmp_path / "whole" / "audit-cbox-rgb"
    pngs = sorted(p.name for p in (a / "figures").iterdir())
    assert all((a / "figures" / n).read_bytes() == (b / "figures" / n).read_bytes() for n in pngs) and pngs
