"""Jobs and executors: how an experiment's independent pieces of work are run.

A :class:`Job` names a function by import path (``"rtfit.experiments.half_lambert:render_case"``)
and carries keyword arguments of plain data only (scene TOML text, numbers, strings, NumPy arrays,
file paths). Its result is plain data too. No Mitsuba or Dr.Jit object ever crosses a job
boundary, so the same job list runs in this process, in a local process pool, or on a cluster.

Executors share one method, ``map(jobs) -> list of results`` (in job order):

* ``InlineExecutor`` runs jobs one after another in this process (the default; Dr.Jit's LLVM
  backend already uses every core inside one job).
* ``ProcessExecutor`` runs them in a pool of worker processes started with the **spawn** method
  (CUDA does not survive ``fork``). Each worker gets its own Dr.Jit kernel-cache directory (shared
  kernel caches can corrupt, drjit #115/#130) and, on the CPU, a share of the cores.
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from typing import Any

from rtfit.reference.progress import progress_bar

EXECUTORS = ("inline", "process")


@dataclass(frozen=True)
class Job:
    """``func`` ("package.module:function") called with ``kwargs``; ``label`` names it in progress bars."""

    func: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    label: str = ""

    def run(self):
        module, _, name = self.func.partition(":")
        return getattr(importlib.import_module(module), name)(**self.kwargs)


def _run_job(job: Job):
    return job.run()


def _worker_init(threads: int | None):
    """Per-worker set-up: a private Dr.Jit kernel cache and, if given, a thread budget."""
    os.environ.setdefault("DRJIT_CACHE_DIR", tempfile.mkdtemp(prefix="rtfit-drjit-"))
    if threads:
        import drjit as dr

        dr.set_thread_count(threads)


class InlineExecutor:
    name = "inline"

    def __init__(self, progress: bool = False):
        self.progress = progress

    def map(self, jobs: list[Job], desc: str = "jobs") -> list:
        bar = progress_bar(len(jobs), desc, self.progress, unit="job")
        out = []
        for job in jobs:
            out.append(job.run())
            bar.update(1)
        bar.close()
        return out

    def close(self):
        pass


class ProcessExecutor:
    """A spawn-based process pool. ``workers`` defaults to the number of CPU cores."""

    name = "process"

    def __init__(self, workers: int | None = None, progress: bool = False):
        self.workers = workers or os.cpu_count() or 1
        self.progress = progress
        threads = max(1, (os.cpu_count() or 1) // self.workers)
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_worker_init, initargs=(threads,))

    def map(self, jobs: list[Job], desc: str = "jobs") -> list:
        bar = progress_bar(len(jobs), desc, self.progress, unit="job")
        futures = {self._pool.submit(_run_job, job): i for i, job in enumerate(jobs)}
        out: list = [None] * len(jobs)
        try:
            for fut in as_completed(futures):
                out[futures[fut]] = fut.result()
                bar.update(1)
        finally:
            bar.close()
        return out

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=True)


def make_executor(name: str = "inline", workers: int | None = None, progress: bool = False):
    if name == "inline":
        return InlineExecutor(progress)
    if name == "process":
        return ProcessExecutor(workers, progress)
    raise ValueError(f"unknown executor {name!r} (expected one of: {', '.join(EXECUTORS)})")
