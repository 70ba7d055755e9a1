"""``rtfit bench executors``: what an executor costs per job, and what it buys on a real sweep.

Two measurements, side by side in one run (ratios are only meaningful within one run):

* **Overhead per job**: ``diagnostic_job`` (does nothing) through each executor; the round-trip
  latency of one job at a time (median), and the time per job when a batch of them is queued
  (scheduling + transfer of a job and its result, amortised over the workers).
* **Scaling on a sweep**: the same small sweep (``sweep_points`` diffuse points, every point a
  full experiment run with its own reference renders, each executor with a fresh cache) under every
  executor; wall time and the speed-up over ``inline``. On CUDA, the process and Ray executors run
  one worker per GPU, first on one GPU and then on all GPUs listed in ``RTFIT_BENCH_GPUS``
  (default ``0``), so the multi-GPU speed-up is measured in the same run.
"""

from __future__ import annotations

import importlib.util
import os
import statistics
import tempfile
import time
from pathlib import Path

from .executors import make_executor
from .jobs import Job, diagnostic_job
from .ray_executor import RayExecutor
from .sweep import load_sweep, run_sweep


def _available(name: str) -> bool:
    if name != "ray":
        return True
    return importlib.util.find_spec("ray") is not None


def _overhead_rows(name: str, n_jobs: int, workers: int | None, gpus=None) -> dict:
    t0 = time.perf_counter()
    ex = make_executor(name, workers, gpus=gpus)
    try:
        ex.map([Job(diagnostic_job, {}, "warm")] * (getattr(ex, "workers", 1) or 1))  # start every worker
        startup = time.perf_counter() - t0
        lat = []
        for _ in range(15):
            t = time.perf_counter()
            ex.map([Job(diagnostic_job, {}, "one")])
            lat.append(time.perf_counter() - t)
        t = time.perf_counter()
        ex.map([Job(diagnostic_job, {}, f"j{i}") for i in range(n_jobs)])
        batch = (time.perf_counter() - t) / n_jobs
    finally:
        ex.close()
    return {
        "measurement": "overhead",
        "executor": name,
        "workers": getattr(ex, "workers", 1),
        "startup_s": startup,
        "latency_ms": 1e3 * statistics.median(lat),
        "per_job_ms_batched": 1e3 * batch,
    }


def sweep_spec_text(points: int, variant: str) -> str:
    """A small diffuse sweep: ``points`` configuration points of (nearly) equal cost: the α = 5° and 30°
    shipped scenes at image widths res, res + 1, …"""
    gpu = variant.startswith("cuda")
    res, spp = (192, 1024) if gpu else (40, 128)
    return (
        f'name = "scaling"\nexperiment = "diffuse"\nquick = true\nspp = {spp}\n'
        '[fixed]\nscenes = ["diffuse_sphere_a5", "diffuse_sphere_a30"]\n'
        "[grid]\nresolution = [" + ", ".join(str(res + i) for i in range(points)) + "]\n"
    )


def _executor(name: str, workers, gpus):
    if name == "ray" and gpus:
        return RayExecutor(num_gpus=len(gpus))
    return make_executor(name, workers, gpus=gpus)


def _sweep_row(name: str, points: int, variant: str, workers, gpus=None, label=None) -> dict:
    with tempfile.TemporaryDirectory(prefix="rtfit-scaling-") as tmp:
        spec_path = Path(tmp) / "scaling.toml"
        spec_path.write_text(sweep_spec_text(points, variant))
        sweep = load_sweep(spec_path)
        t0 = time.perf_counter()
        ex = _executor(name, workers, gpus)
        try:
            summary = run_sweep(
                sweep,
                Path(tmp) / "out",
                variant=variant,
                cache_dir=Path(tmp) / "cache",
                executor=ex,
                executor_name=name,
            )
        finally:
            ex.close()
        wall = time.perf_counter() - t0
    return {
        "measurement": "sweep",
        "executor": label or name,
        "workers": getattr(ex, "workers", 1),
        "points": points,
        "failed": len(summary.failed),
        "wall_s": wall,
    }


def bench(ctx) -> list[dict]:
    """Rows for ``rtfit bench executors`` (``ctx.quick``: fewer jobs and points)."""
    gpus = None
    if ctx.variant.startswith("cuda"):
        env = os.environ.get("RTFIT_BENCH_GPUS")
        gpus = [int(g) for g in env.split(",")] if env else [0]
    names = [n for n in ("inline", "process", "ray") if _available(n)]
    rows = [_overhead_rows(n, 50 if ctx.quick else 400, None) for n in names]
    points = 2 if ctx.quick else 4
    sweeps = []
    for n in names:
        if ctx.variant.startswith("cuda") and n != "inline":
            continue  # on GPUs, the pinned process pool below is the meaningful comparison
        sweeps.append(_sweep_row(n, points, ctx.variant, None))
    if gpus:
        for n in ("process", "ray") if _available("ray") else ("process",):
            sweeps.append(_sweep_row(n, points, ctx.variant, None, gpus=gpus[:1], label=f"{n}, 1 GPU"))
            if len(gpus) > 1:
                sweeps.append(
                    _sweep_row(n, points, ctx.variant, None, gpus=gpus, label=f"{n}, {len(gpus)} GPUs")
                )
    base = sweeps[0]["wall_s"]
    for r in sweeps:
        r["speedup_vs_inline"] = base / r["wall_s"]
    return rows + sweeps
