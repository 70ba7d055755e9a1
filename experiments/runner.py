"""Run experiments into an output directory: atomically, resumably, with a common results header.

Each experiment writes into a fresh temporary directory beside ``OUT/EXPERIMENT``; only when its
results, figures and report are complete does that directory replace ``OUT/EXPERIMENT``. An
interrupted run therefore leaves the previous output untouched, and a rerun resumes from the
reference cache (rendered passes are never rendered twice).
"""

from __future__ import annotations

import datetime as _dt
import platform
import sys
from importlib import metadata
from pathlib import Path

from .atomic import atomic_directory, atomic_write_json, is_temporary_name
from .jobs import make_executor
from .registry import ExperimentSpec, RunContext
from .report import write_index, write_report
from .results import SCHEMA


def versions() -> dict:
    out = {"python": platform.python_version()}
    for dist in ("rtfit", "mitsuba", "drjit", "numpy", "jax", "optimistix", "scikit-image", "flip-evaluator"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def device_description(variant: str) -> str:
    import drjit as dr

    if variant.startswith("cuda"):
        try:
            import subprocess

            name = (
                subprocess.run(
                    ["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                    capture_output=True,
                    text=True,
                    timeout=10,
                )
                .stdout.strip()
                .splitlines()
            )
            return f"GPU (CUDA backend): {name[0] if name else 'unknown'}"
        except (OSError, subprocess.SubprocessError):
            return "GPU (CUDA backend)"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    threads = dr.thread_count() if variant.startswith("llvm") else 1
    backend = "LLVM" if variant.startswith("llvm") else "scalar"
    return f"CPU ({backend} backend, {threads} threads): {cpu}"


def run_experiment_into(spec: ExperimentSpec, directory: Path, ctx: RunContext, executor_name: str) -> dict:
    """Run one experiment with ``ctx`` and write ``results.json`` and the report into ``directory``
    (which the caller makes atomic). Returns the results document."""
    ctx.log(f"{spec.name}: running ({'quick' if ctx.quick else 'full'}, {ctx.variant})")
    body = spec.load().run(ctx)
    results = {
        "schema": SCHEMA,
        "experiment": spec.name,
        "title": spec.title,
        "created": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat(),
        "versions": versions(),
        "device": device_description(ctx.variant),
        **body,
    }
    results.setdefault("config", {}).update(
        {"quick": ctx.quick, "variant": ctx.variant, "seed": ctx.seed, "executor": executor_name}
    )
    if ctx.overrides:
        results["config"]["overrides"] = dict(ctx.overrides)
    atomic_write_json(Path(directory) / "results.json", results)
    write_report(Path(directory))
    return results


def run_experiments(
    specs: list[ExperimentSpec],
    out: Path,
    *,
    quick: bool,
    variant: str,
    spp: int | None,
    seed: int,
    cache_dir: Path,
    executor: str,
    workers: int | None,
    progress: bool,
    address: str | None = None,
    overrides: dict | None = None,
) -> list[Path]:
    """Run each experiment into ``out/<name>`` (atomically) and write the suite index. ``overrides``:
    configuration keys replacing the experiments' defaults (as one `rtfit sweep` point does; validated
    by `registry.apply_overrides`: an unknown key or a value of another kind is a ValueError)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    done: list[Path] = []
    pool = make_executor(executor, workers, progress, address=address)
    try:
        for spec in specs:
            final = out / spec.name
            with atomic_directory(final) as tmp:
                ctx = RunContext(
                    out_dir=Path(tmp),
                    cache_dir=Path(cache_dir),
                    executor=pool,
                    quick=quick,
                    variant=variant,
                    spp=spp,
                    seed=seed,
                    progress=progress,
                    overrides=dict(overrides or {}),
                )
                run_experiment_into(spec, Path(tmp), ctx, executor)
            done.append(final)
            print(f"rtfit: {spec.name}: report at {final / 'report.html'}", file=sys.stderr)
    finally:
        pool.close()
    write_index(out, experiment_dirs(out))
    return done


def experiment_dirs(out: Path) -> list[Path]:
    """Every complete experiment (or sweep) directory directly under ``out``."""
    return sorted(
        p for p in Path(out).iterdir() if not is_temporary_name(p.name) and (p / "results.json").is_file()
    )
