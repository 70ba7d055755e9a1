"""Run experiments into an output directory: atomically, resumably, with a common results header.

Each experiment writes into a fresh temporary directory beside ``OUT/EXPERIMENT``; only when its
results, figures and report are complete does that directory replace ``OUT/EXPERIMENT``. An
interrupted run therefore leaves the previous output untouched, and a rerun resumes from the
reference cache (rendered passes are never rendered twice).
"""

from __future__ import annotations

import ctypes
import dataclasses
import datetime
import functools
import gc
import logging
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path

import drjit as dr

from rtfit.realtime import set_default_backend
from rtfit.reference.cache import PASS_COUNTS
from rtfit.reference.variants import backend_of, callers_variant, use_variant
from rtfit.scenes import SceneError

from .atomic import atomic_directory, is_temporary_name
from .executors import make_executor
from .figures import pngs_in_background
from .jobs import RunFailed, error_line
from .progress import Stage
from .records import SCHEMA, Results, from_json, plain_json
from .registry import ExperimentSpec, RunContext
from .report import write_report
from .report_index import write_index
from .results import RESULTS_FILE, load_results, write_results
from .run_settings import RunSettings

log = logging.getLogger("rtfit.experiments")


def versions() -> dict:
    """Installed version of each package a result depends on (None: not installed); the caller's own dict."""
    return dict(_versions())


@functools.cache
def _versions() -> dict:
    """`versions`, read once a process: each `metadata.version` walks the distributions on sys.path
    (~3 ms; every results record of a suite asked again, issue 33), and what is imported cannot change."""
    out = {"python": platform.python_version()}
    for dist in ("rtfit", "mitsuba", "drjit", "numpy", "jax", "optimistix", "scikit-image", "flip-evaluator"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def device_description(variant: str) -> str:
    """Where ``variant`` runs, in words: the GPU's name, or the CPU's with Dr.Jit's thread count."""
    if variant.startswith("cuda"):
        try:
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


def created_now() -> str:
    """The current time, ISO 8601 UTC to the second (a results document's ``created``)."""
    return datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat()


def use_variant_backend(variant: str) -> str:
    """Make the Dr.Jit backend of the Mitsuba ``variant`` (``llvm`` or ``cuda``) the default of every kernel
    that follows, and return it: the one place it is set, by the engine's entry points (`run_experiment_into`
    for ``rtfit run`` and ``rtfit sweep``, ``rtfit bench``, ``rtfit audit``), never by a family."""
    backend = backend_of(variant)
    if backend in ("llvm", "cuda"):  # a scalar variant has no JIT backend: the kernels keep the default
        set_default_backend(backend)
    return backend


def run_experiment_into(
    spec: ExperimentSpec,
    directory: Path,
    ctx: RunContext,
    executor_name: str,
    extra_config: Mapping | None = None,
    single_file: bool = False,
) -> Results:
    """Run one experiment with ``ctx`` and write ``results.json`` and the report into ``directory``
    (which the caller makes atomic). Returns the results record.

    The experiment's ``run(ctx)`` returns the body of the document (a dict); the runner adds the header
    (schema, experiment, title, created, versions, device, the run's configuration keys and
    ``extra_config``) and builds the :class:`~.records.Results` record before writing anything, so a
    body of the wrong shape is a one-line :class:`~.records.ResultsError` naming the key path and
    leaves no ``results.json`` behind."""
    if ctx.experiment != spec.name:  # its CONFIG declaration checks the run's overrides
        ctx = dataclasses.replace(ctx, experiment=spec.name, config=spec.config)
    ctx.log(f"{spec.name}: running ({'quick' if ctx.quick else 'full'}, {ctx.variant})")
    use_variant_backend(ctx.variant)
    with pngs_in_background():  # (its figures written before its results and report name them)
        body = spec.load().run(ctx)
    doc = {
        "schema": SCHEMA,
        "experiment": spec.name,
        "title": spec.title,
        "created": created_now(),
        "versions": versions(),
        "device": device_description(ctx.variant),
        **body,
    }
    doc["config"] = {
        **(body.get("config") or {}),
        "quick": ctx.quick,
        "variant": ctx.variant,
        "seed": ctx.seed,
        "executor": executor_name,
        **({"overrides": dict(ctx.overrides)} if ctx.overrides else {}),
        **dict(extra_config or {}),
    }
    results = from_json(Results, plain_json(doc), f"results of {spec.name}")
    write_results(directory, results)
    ctx.log(f"{spec.name}: writing the report ({len(results.figures)} figures)")
    write_report(Path(directory), single_file=single_file, results=results)
    return results


def run_experiments(
    specs: list[ExperimentSpec],
    out: Path,
    settings: RunSettings,
    *,
    executor: str = "inline",
    workers: int | None = None,
    address: str | None = None,
    overrides: dict | None = None,
    single_file: bool = False,
) -> list[Path]:
    """Run each experiment with ``settings`` into ``out/<name>`` (atomically) and write the suite index, on
    the ``executor`` named (with ``workers``, ``address``: `make_executor`). ``overrides``: configuration
    keys replacing the experiments' defaults (as one `rtfit sweep` point does; validated by
    `registry.apply_overrides`: an unknown key or a value of another kind is a ValueError)."""
    out = Path(out)
    progress = settings.progress
    pool = make_executor(executor, workers, progress, address=address)  # a bad address: nothing written
    done: list[Path] = []
    failed: list[str] = []
    with callers_variant():  # the experiments activate their variants; the caller's comes back
        # The run's variant active from the start, so that reading a scene (`inspection_variant`: the active
        # variant) and rendering it need no switch (issue 33: without one active, the first scene read left
        # scalar_rgb active, and each audit then switched into the run's JIT variant and back, 0.12 s each)
        use_variant(settings.variant)
        try:
            out.mkdir(parents=True, exist_ok=True)
            stage = Stage(len(specs) if len(specs) > 1 else 0, "experiments", enabled=progress)  # a bar
            for spec in specs:
                final = out / spec.name
                # Each experiment starts in the run's variant: one that left another active (issue 33:
                # nishita-sky's spectral study left llvm_ad_spectral, and every later audit then switched
                # variants three times a scene, 0.12 s each, ~7 s of the quick suite) does not slow the rest.
                use_variant(settings.variant)
                t0, cpu0 = time.perf_counter(), _cpu_seconds()
                try:
                    _run_one(spec, final, settings, pool, overrides, executor, single_file)
                except RunFailed as e:
                    # One family failing does not stop the others (the quick suite's nishita-sky failure
                    # left 15 families unrun): each is said now, all of them at the end (exit 1).
                    if len(specs) == 1:
                        raise
                    log.error("%s", e)
                    failed.append(str(e))
                    stage.advance()
                    continue
                finally:
                    release_memory()
                done.append(final)
                log.info(
                    "%s: done in %.1f s (CPU %.1f s, peak memory of the process so far %s), report at %s",
                    spec.name,
                    time.perf_counter() - t0,
                    _cpu_seconds() - cpu0,
                    _peak_memory(),
                    final / "report.html",
                )
                stage.advance()
        finally:
            pool.close()
    write_index(out, experiment_dirs(out))
    if failed:
        raise RunFailed(f"{len(failed)} of {len(specs)} experiment(s) failed: " + "; ".join(failed))
    return done


def forget_memos() -> None:
    """Empty the process-wide memos of every loaded rtfit module: a module that keeps tables, compiled or
    frozen functions or loaded scenes from one call to the next names their containers (dicts, lists) in a
    module attribute ``MEMOS``. They serve the calls of one experiment (a fit's repeated evaluations, a
    scene's cases); past it they only held its memory under the next (issue 33: the lat-long quadrature's
    tables, 128 MiB, stayed from irradiance-bases to the end of the quick suite). A memo's entry is what
    recomputing gives, so emptying it changes no result."""
    for name, module in list(sys.modules.items()):
        if name.startswith("rtfit.") and module is not None:
            for memo in vars(module).get("MEMOS", ()):
                memo.clear()


def release_memory() -> None:
    """Hand the memory an experiment freed back to the system before the next one starts: the modules'
    memos emptied (`forget_memos`), Python's cycles collected, Dr.Jit's allocation cache flushed (it keeps
    freed buffers for reuse) and glibc's free heap trimmed (`malloc_trim`, where the C library has it). A
    suite runs its experiments in one process, so without it each one's high-water mark stayed resident
    under the next (issue 33: the quick suite's peak was the sum of retained heaps, not one family's
    need).

    The objects still alive after that full collection (modules, the process-wide state an experiment
    imported or built) are then frozen (`gc.freeze`): later collections skip them. Without it each of
    these collections walked the whole heap of Mitsuba, Dr.Jit, SciPy and matplotlib objects, 0.15–0.17 s
    after every experiment (~4 s of the quick suite), and the automatic full collections inside the next
    experiments walked it too. A frozen object is still freed when its references go; only a cycle among
    frozen objects that becomes garbage later stays (the long-lived state of modules, not an experiment's
    arrays, which are gone by then)."""
    forget_memos()
    gc.collect()
    gc.freeze()
    dr.flush_malloc_cache()
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to trim
        pass


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process so far (every thread: Dr.Jit's pool, BLAS, JAX)."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _peak_memory() -> str:
    """The process's peak resident set so far (Linux reports ru_maxrss in KiB), for telling which
    experiment of a suite raised it (issue 33: the quick suite peaked at 3.9 GB)."""
    return f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GiB"


def _run_one(spec, final, settings, pool, overrides, executor, single_file) -> None:
    """One experiment of `run_experiments` into ``final`` (atomically); a failure inside it is `RunFailed`."""
    with atomic_directory(final) as tmp:
        ctx = settings.context(Path(tmp), pool, overrides)
        before = PASS_COUNTS.snapshot()
        try:
            run_experiment_into(spec, Path(tmp), ctx, executor, single_file=single_file)
        except (SceneError, ValueError) as e:
            # The input was validated before this loop (the CLI: every configuration value, file
            # and address): a ValueError from inside an experiment is the run failing — a fit
            # refusing a non-finite target, say — not bad input. The traceback: debug log (-v).
            log.debug("%s failed", spec.name, exc_info=True)
            raise RunFailed(f"{spec.name}: {error_line(e)}") from e
        print_resumed(spec.name, before, PASS_COUNTS.snapshot())


def resumed_line(name: str, before: tuple[int, int], after: tuple[int, int]) -> str | None:
    """ "NAME: resumed K of N passes from the cache" from two `PASS_COUNTS` snapshots (requested,
    rendered) taken around an experiment; None when nothing came from the cache."""
    requested, rendered = after[0] - before[0], after[1] - before[1]
    if requested - rendered <= 0:
        return None
    return f"{name}: resumed {requested - rendered} of {requested} passes from the cache"


def print_resumed(name: str, before: tuple[int, int], after: tuple[int, int]) -> None:
    """Say (an INFO line, like the report line) how much of an experiment came from the cache."""
    line = resumed_line(name, before, after)
    if line is not None:
        log.info("%s", line)


def experiment_dirs(out: Path) -> list[Path]:
    """Every complete experiment (or sweep) directory directly under ``out``."""
    return sorted(
        p for p in Path(out).iterdir() if not is_temporary_name(p.name) and (p / RESULTS_FILE).is_file()
    )


def failed_checks(results: Results) -> list:
    """The self-checks of ``results`` that did not pass."""
    return [c for c in results.checks if not c.passed]


def check_summary(directory: Path, limit: int = 3) -> str | None:
    """One line for an experiment whose self-checks failed (None: all passed), e.g. ``height-fog: 2 of
    27 checks failed: a (value 3.1, expected ≤ 2), b``; the command line prints it and exits with 1."""
    results = load_results(directory)
    bad = failed_checks(results)
    if not bad:
        return None

    def one(c) -> str:
        if c.value is None:
            return c.name
        value = f"{c.value:.4g}" if isinstance(c.value, float) else str(c.value)
        return f"{c.name} ({value}" + (f", expected {c.expected})" if c.expected else ")")

    named = "; ".join(one(c) for c in bad[:limit]) + (
        f"; … {len(bad) - limit} more" if len(bad) > limit else ""
    )
    return (
        f"{results.experiment}: {len(bad)} of {len(results.checks)} checks failed: {named} "
        f"(see {Path(directory) / 'report.html'})"
    )
