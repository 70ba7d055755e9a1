"""Jobs and executors: how an experiment's independent pieces of work are run.

A :class:`Job` holds a function (``Job(render_case, {...})``) that is importable at its module's top
level: the executors that leave this process send its import path ``module:qualname`` (see
:func:`import_path`) and the worker imports it back, so a lambda, a nested function or a function of
``__main__`` is refused with one line before anything runs. A job carries keyword arguments of plain
data only (scene TOML text, numbers, strings, NumPy arrays, file paths). Its result is plain data too.
No Mitsuba or Dr.Jit object ever crosses a job boundary, so the same job list runs in this process, in
a local process pool, or on a cluster.

Executors share two methods:

* ``map(jobs) -> list of results`` (in job order). A job that raises makes ``map`` raise that
  exception (after the other jobs in flight finish); a *worker* that dies (killed, out of memory)
  is not the job's fault: its job is retried on a fresh worker, up to ``max_attempts`` times.
* ``run_all(jobs) -> list[Outcome]`` never raises for a job: each :class:`Outcome` says whether the
  job succeeded, its value or its one-line error, and how many attempts it took. Sweeps use it so
  that they finish with every point or say exactly which failed and why.

Executors:

* ``InlineExecutor`` runs jobs one after another in this process (the default; Dr.Jit's LLVM
  backend already uses every core inside one job).
* ``ProcessExecutor`` runs them in a pool of worker processes started with the **spawn** method
  (CUDA does not survive ``fork``). Each worker gets its own Dr.Jit kernel-cache directory, kept between
  runs (`worker_kernel_cache`; shared kernel caches can corrupt, drjit #115/#130) and, on the CPU, a share of
  the cores; with
  ``gpus=[0, 1, …]`` one worker per GPU, pinned by ``CUDA_VISIBLE_DEVICES``.
* ``RayExecutor`` (``rtfit.experiments.ray_executor``, optional extra ``rtfit[ray]``): one long-lived
  worker per GPU of a Ray cluster, or CPU workers.

``rtfit.experiments.executors.make_executor(name)`` picks one by name (it sits above this module and
``ray_executor``, which builds on the job model here).
"""

from __future__ import annotations

import fcntl
import importlib
import logging
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rtfit.fitting.forked_fits import limit_cores
from rtfit.reference.progress import progress_bar

MAX_ATTEMPTS = 3
log = logging.getLogger("rtfit.jobs")


@dataclass
class Outcome:
    """What became of one job: ``value`` if ``ok``, else ``error`` (one line: ``Type: message``)."""

    index: int
    label: str
    ok: bool
    value: Any = None
    error: str | None = None
    attempts: int = 1
    seconds: float = 0.0

    @classmethod
    def returned(cls, index: int, label: str, value: Any, attempts: int, t0: float) -> Outcome:
        """A job that returned ``value`` (started at ``time.perf_counter()`` ``t0``; ``attempts`` tries)."""
        return cls(index, label, True, value, attempts=attempts, seconds=time.perf_counter() - t0)

    @classmethod
    def raised(cls, index: int, label: str, exc: BaseException, attempts: int, t0: float) -> Outcome:
        """A job that raised ``exc``, its own error (started at ``time.perf_counter()`` ``t0``)."""
        return cls(
            index, label, False, error=error_line(exc), attempts=attempts, seconds=time.perf_counter() - t0
        )

    @classmethod
    def worker_died(cls, index: int, label: str, exc: BaseException, attempts: int) -> Outcome:
        """A job given up on: its worker died under it on all ``attempts`` tries (the last: ``exc``)."""
        return cls(
            index, label, False, attempts=attempts, error=f"worker died {attempts} times ({error_line(exc)})"
        )


def error_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


class JobTracker:
    """Progress over a job list: done / running / failed counts and an ETA (tqdm), or nothing; and one
    log line per finished job (``rtfit.jobs``: INFO without a bar, DEBUG beside one, which shows it)."""

    def __init__(self, total: int, desc: str, enabled: bool):
        self.done = self.failed = self.running = 0
        self.total, self.desc = total, desc
        self._level = logging.DEBUG if enabled and total else logging.INFO
        self._t0 = time.perf_counter()
        self._bar = progress_bar(total, desc, enabled, unit="job")

    def started(self, n: int = 1):
        self.running += n
        self._show()

    def finished(self, ok: bool, was_running: bool = True, label: str = ""):
        self.running -= int(was_running)
        self.done += int(ok)
        self.failed += int(not ok)
        self._bar.update(1)
        self._show()
        log.log(
            self._level,
            "%s: %d/%d jobs done%s%s (%.1f s)",
            self.desc,
            self.done + self.failed,
            self.total,
            f", {self.failed} failed" if self.failed else "",
            f": {label}{'' if ok else ' failed'}" if label else "",
            time.perf_counter() - self._t0,
        )

    def requeued(self):
        self.running -= 1
        self._show()

    def _show(self):
        if hasattr(self._bar, "set_postfix_str"):
            self._bar.set_postfix_str(f"running {self.running}, failed {self.failed}", refresh=False)

    def close(self):
        self._bar.close()


def values_or_raise(outcomes: list[Outcome], exceptions: dict[int, BaseException]) -> list:
    """The values in job order; re-raise the first job's own exception if any job failed."""
    for o in outcomes:
        if not o.ok:
            if o.index in exceptions:
                raise exceptions[o.index]
            raise JobsFailed([o])
    return [o.value for o in outcomes]


class RunFailed(RuntimeError):
    """An experiment that started (its input valid) and could not finish: one line naming it and the cause;
    ``rtfit`` prints it and exits with status 1 (README: exit statuses). Raised by the runner; kept here,
    beside `JobsFailed`, so that the command line's entry point knows it without importing the runner."""


class JobsFailed(RuntimeError):
    """Jobs that could not be completed (their worker kept dying); one line naming each."""

    def __init__(self, failed: list[Outcome]):
        self.failed = failed
        super().__init__(
            "; ".join(f"{o.label or o.index}: {o.error} ({o.attempts} attempts)" for o in failed)
        )


@dataclass(frozen=True)
class Job:
    """``func`` (a function importable at its module's top level) called with ``kwargs``; ``label`` names
    it in progress bars."""

    func: Callable[..., Any]
    kwargs: dict[str, Any] = field(default_factory=dict)
    label: str = ""

    def __post_init__(self):
        if not callable(self.func):  # the old string form ("module:function") would fail only when run
            raise TypeError(f"Job takes the function itself, not {self.func!r}")

    def run(self):
        return self.func(**self.kwargs)

    @property
    def path(self) -> str:
        """The function's import path ``module:qualname``, which another process imports back."""
        return import_path(self.func)


def reference_args(ctx, cfg: dict) -> dict[str, Any]:
    """The keywords every reference job of a run takes: ``cfg``'s ``spp`` and ``pass_spp``, the run's
    seed, variant and cache directory (as text: a job's arguments are plain data)."""
    return dict(
        spp=cfg["spp"],
        pass_spp=cfg["pass_spp"],
        seed=ctx.seed,
        variant=ctx.variant,
        cache_dir=str(ctx.cache_dir),
    )


def import_path(func: Callable[..., Any]) -> str:
    """``module:qualname`` of ``func``, or a one-line ``ValueError`` if a fresh process could not import
    it back as that name: a lambda, a nested function, a method, or a function defined in ``__main__``
    (a spawned worker's ``__main__`` is not the caller's)."""
    module = getattr(func, "__module__", None)
    qualname = getattr(func, "__qualname__", None)
    name = f"{module}:{qualname}"
    if not module or not qualname or module == "__main__" or "." in qualname or "<" in qualname:
        raise ValueError(f"job function {name} is not importable at module top level; define it there")
    try:
        found = getattr(importlib.import_module(module), qualname, None)
    except ImportError as e:
        raise ValueError(f"job function {name} is not importable ({error_line(e)})") from None
    if found is not func:
        raise ValueError(f"job function {name} is not importable at module top level; define it there")
    return name


def run_path(path: str, kwargs: dict[str, Any]):
    """Import ``module:qualname`` and call it with ``kwargs``: a job, in a worker process."""
    module, _, name = path.partition(":")
    return getattr(importlib.import_module(module), name)(**kwargs)


def diagnostic_job(seconds: float = 0.0, fail: str | None = None) -> dict:
    """A job that only waits ``seconds`` (and raises ``ValueError(fail)`` if given): it measures an
    executor's own overhead per job, and lets tests kill a worker in the middle of a job."""
    if seconds:
        time.sleep(seconds)
    if fail:
        raise ValueError(fail)
    return {"pid": os.getpid(), "cuda_visible_devices": os.environ.get("CUDA_VISIBLE_DEVICES")}


KERNEL_SLOTS = 64
"""Kernel-cache slots a machine's workers may hold at once (`worker_kernel_cache`); past them, a worker's
cache is a temporary directory of its own."""
_HELD_SLOT: list[int] = []  # the lock of this process's slot, held open until it exits


def worker_kernel_cache(root: Path | None = None) -> str:
    """A Dr.Jit kernel-cache directory for this worker process alone, kept between runs: the first slot
    ``root/slot-K`` (default ``~/.drjit/rtfit-workers``) whose lock file no live process holds, locked
    (``flock``) for this process's life; a fresh temporary directory where none is free or none can be made.

    One directory a worker: a shared kernel cache can corrupt (drjit #115/#130/#162: OptiX's cache database
    where several processes write it). Before issue 33 (session 31) each worker made a temporary one, so
    every run of a process pool (the quick suite's two workers) compiled every kernel again; a slot keeps
    them, as the main process's ``~/.drjit`` does, and a lock that dies with its process frees it."""
    root = Path.home() / ".drjit" / "rtfit-workers" if root is None else root
    for k in range(KERNEL_SLOTS):
        slot = root / f"slot-{k}"
        try:
            slot.mkdir(parents=True, exist_ok=True)
            fd = os.open(slot / ".lock", os.O_CREAT | os.O_RDWR, 0o644)
        except OSError:  # an unwritable home: a private temporary cache, as before
            break
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # another live worker's
            os.close(fd)
            continue
        _HELD_SLOT.append(fd)
        return str(slot)
    return tempfile.mkdtemp(prefix="rtfit-drjit-")


def _worker_init(threads: int | None):
    """Per-worker set-up: a kernel cache of its own (`worker_kernel_cache`; a ``DRJIT_CACHE_DIR`` the user
    set is kept) and, if given, a thread budget (Dr.Jit's threads, and the audit's fit helper:
    `rtfit.fitting.forked_fits.limit_cores`)."""
    if "DRJIT_CACHE_DIR" not in os.environ:
        os.environ["DRJIT_CACHE_DIR"] = worker_kernel_cache()
    if threads:
        limit_cores(threads)
        # drjit stays lazy here: importing it starts CUDA's initialisation, which reads
        # CUDA_VISIBLE_DEVICES, and a GPU worker imports this module before `_gpu_worker_init` pins it.
        import drjit as dr

        dr.set_thread_count(threads)


class InlineExecutor:
    name = "inline"

    def __init__(self, progress: bool = False):
        self.progress = progress

    def map(self, jobs: list[Job], desc: str = "jobs") -> list:
        tracker = JobTracker(len(jobs), desc, self.progress)
        out = []
        try:
            for job in jobs:
                tracker.started()
                out.append(job.run())
                tracker.finished(True, label=job.label)
        finally:
            tracker.close()
        return out

    def run_all(self, jobs: list[Job], desc: str = "jobs") -> list[Outcome]:
        tracker = JobTracker(len(jobs), desc, self.progress)
        out = []
        for i, job in enumerate(jobs):
            tracker.started()
            t0 = time.perf_counter()
            try:
                out.append(Outcome.returned(i, job.label, job.run(), 1, t0))
            except Exception as e:  # reported per job, never swallowed silently
                out.append(Outcome.raised(i, job.label, e, 1, t0))
            tracker.finished(out[-1].ok, label=job.label)
        tracker.close()
        return out

    def close(self):
        pass


def _gpu_worker_init(gpu_queue, threads: int | None):
    """Per-worker set-up for a GPU pool: take one GPU id before anything imports Dr.Jit."""
    os.environ["CUDA_VISIBLE_DEVICES"] = str(gpu_queue.get())
    _worker_init(threads)


class ProcessExecutor:
    """A spawn-based process pool. ``workers`` defaults to the number of CPU cores, or to one
    worker per GPU when ``gpus`` (a list of device ids) is given.

    A worker that dies breaks the whole ``concurrent.futures`` pool; the executor then starts a new
    pool and resubmits every unfinished job, counting an attempt against each job that was in
    flight. A job whose workers died ``max_attempts`` times fails with a one-line reason."""

    name = "process"

    def __init__(
        self,
        workers: int | None = None,
        progress: bool = False,
        gpus: list[int] | None = None,
        max_attempts: int = MAX_ATTEMPTS,
    ):
        self.gpus = list(gpus) if gpus else None
        self.workers = len(self.gpus) if self.gpus else (workers or os.cpu_count() or 1)
        self.progress = progress
        self.max_attempts = max_attempts
        self._ctx = multiprocessing.get_context("spawn")
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        if self.gpus:
            queue = self._ctx.Queue()
            for g in self.gpus:
                queue.put(g)
            return ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=self._ctx,
                initializer=_gpu_worker_init,
                initargs=(queue, None),
            )
        threads = max(1, (os.cpu_count() or 1) // self.workers)
        return ProcessPoolExecutor(
            max_workers=self.workers, mp_context=self._ctx, initializer=_worker_init, initargs=(threads,)
        )

    def worker_pids(self) -> list[int]:
        """PIDs of the live worker processes (for monitoring and fault-injection tests)."""
        return [p.pid for p in (self._pool._processes or {}).values() if p.is_alive()]

    def run_all(self, jobs: list[Job], desc: str = "jobs", _exceptions: dict | None = None) -> list[Outcome]:
        paths = [job.path for job in jobs]  # a function no worker could import: refused before any job runs
        tracker = JobTracker(len(jobs), desc, self.progress)
        outcomes: list[Outcome | None] = [None] * len(jobs)
        attempts = [0] * len(jobs)
        todo = list(range(len(jobs)))
        try:
            while todo:
                t0 = time.perf_counter()
                futures = {self._pool.submit(run_path, paths[i], jobs[i].kwargs): i for i in todo}
                for i in todo:
                    attempts[i] += 1
                tracker.started(len(todo))
                broken: list[int] = []
                for fut in as_completed(futures):
                    i = futures[fut]
                    try:
                        value = fut.result()
                    except BrokenProcessPool as e:
                        broken.append(i)
                        if attempts[i] >= self.max_attempts:
                            outcomes[i] = Outcome.worker_died(i, jobs[i].label, e, attempts[i])
                            tracker.finished(False, label=jobs[i].label)
                        else:
                            tracker.requeued()
                        continue
                    except Exception as e:  # the job's own error, reported per job
                        outcomes[i] = Outcome.raised(i, jobs[i].label, e, attempts[i], t0)
                        if _exceptions is not None:
                            _exceptions[i] = e
                        tracker.finished(False, label=jobs[i].label)
                        continue
                    outcomes[i] = Outcome.returned(i, jobs[i].label, value, attempts[i], t0)
                    tracker.finished(True, label=jobs[i].label)
                todo = [i for i in broken if outcomes[i] is None]
                if broken:
                    self._pool.shutdown(wait=True, cancel_futures=True)
                    self._pool = self._new_pool()
        finally:
            tracker.close()
        return outcomes  # type: ignore[return-value]

    def map(self, jobs: list[Job], desc: str = "jobs") -> list:
        exceptions: dict[int, BaseException] = {}
        return values_or_raise(self.run_all(jobs, desc, exceptions), exceptions)

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=True)
