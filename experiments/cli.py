"""The ``rtfit`` command line.

    rtfit list
    rtfit run EXPERIMENT... [--quick] [--variant V] [--spp N] [--out DIR] [--cache DIR]
                            [--executor inline|process|ray] [--address A] [--workers N] [--seed S]
    rtfit sweep SPEC.toml [--variant V] [--out DIR] [--cache DIR] [--executor …] [--address A] [--gpus 0,1]
    rtfit sweep --show-config EXPERIMENT [--quick]
    rtfit report DIR
    rtfit bench EXPERIMENT [--variant V] [--size N]

Errors in what the user typed or supplied (unknown experiment, bad option, malformed scene file,
invalid value) print one line, ``rtfit: error: …``, write nothing and exit with status 2.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import click

from rtfit.reference import default_cache_dir, resolve_variant
from rtfit.scenes import SceneError

from . import scaling
from .atomic import is_temporary_name
from .executors import EXECUTORS, make_executor
from .ray_executor import RAY_EXTRA_HINT
from .registry import EXPERIMENTS, BenchContext, resolve_names
from .report import write_index, write_report
from .runner import device_description, run_experiments
from .sweep import load_sweep, run_sweep
from .sweep import show_config as show_sweep_config

VARIANT_CHOICES = ("auto", "llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb")


class UserError(click.ClickException):
    exit_code = 2


def _fail(message: str):
    raise UserError(message)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def cli():
    """rtfit: how wrong is a real-time rendering shortcut, where, at what cost, and which parameters
    make it least wrong (Mitsuba 3 ground truth, Dr.Jit approximations)."""


@cli.command("list")
def list_cmd():
    """List the experiments."""
    width = max(len(n) for n in EXPERIMENTS)
    for name, spec in EXPERIMENTS.items():
        click.echo(f"{name:<{width}}  {spec.title}")


@cli.command("run")
@click.argument("experiments", nargs=-1)
@click.option("--quick", is_flag=True, help="Small images, few samples, fewer cases (minutes on 2 cores).")
@click.option(
    "--variant",
    default="llvm_ad_rgb",
    show_default=True,
    type=click.Choice(VARIANT_CHOICES),
    help="Mitsuba variant for references and the Dr.Jit backend for approximations.",
)
@click.option(
    "--spp", type=click.IntRange(min=2), default=None, help="Reference samples per pixel (overrides)."
)
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("out"),
    show_default=True,
    help="Output directory.",
)
@click.option(
    "--cache",
    "cache",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Reference cache directory (default: $RTFIT_CACHE or ~/.cache/rtfit).",
)
@click.option(
    "--executor",
    type=click.Choice(EXECUTORS),
    default="inline",
    show_default=True,
    help="inline: this process; process: a local spawn pool; ray: a Ray cluster (rtfit[ray]).",
)
@click.option(
    "--address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)."
)
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Pool size (process/ray on CPUs).")
@click.option("--seed", type=click.IntRange(min=0, max=2**31 - 1), default=0, show_default=True)
@click.option("--no-progress", is_flag=True, help="No progress bars.")
def run_cmd(experiments, quick, variant, spp, out, cache, executor, address, workers, seed, no_progress):
    """Run EXPERIMENT... (or 'all') and write OUT/EXPERIMENT/{results.json,report.html,...}."""
    specs, variant = _validated(experiments, variant)  # before anything is written
    _check_executor(executor, address)
    run_experiments(
        specs,
        out,
        quick=quick,
        variant=variant,
        spp=spp,
        seed=seed,
        cache_dir=cache or default_cache_dir(),
        executor=executor,
        workers=workers,
        progress=not no_progress and sys.stderr.isatty(),
        address=address,
    )
    click.echo(str((out / "index.html").resolve()))


@cli.command("sweep")
@click.argument("spec_file", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--show-config",
    "show_config",
    metavar="EXPERIMENT",
    default=None,
    help="Print EXPERIMENT's configuration keys and defaults (what a sweep may set) and exit.",
)
@click.option("--quick", is_flag=True, help="With --show-config: the quick configuration.")
@click.option("--variant", default="llvm_ad_rgb", show_default=True, type=click.Choice(VARIANT_CHOICES))
@click.option(
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("out"),
    show_default=True,
    help="Output directory (the sweep goes to OUT/NAME).",
)
@click.option(
    "--cache",
    "cache",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Reference cache directory (default: $RTFIT_CACHE or ~/.cache/rtfit); share it between nodes.",
)
@click.option("--executor", type=click.Choice(EXECUTORS), default="process", show_default=True)
@click.option(
    "--address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)."
)
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Pool size (process/ray on CPUs).")
@click.option("--gpus", default=None, help="process executor: one worker per listed GPU id, e.g. 0,1.")
@click.option("--no-progress", is_flag=True, help="No progress bars.")
def sweep_cmd(
    spec_file, show_config, quick, variant, out, cache, executor, address, workers, gpus, no_progress
):
    """Run the experiment of SPEC.toml over its grid of configuration points (docs/scale-out.md):
    one results.json per point in OUT/NAME/points/, and a combined table and report in OUT/NAME/."""
    if show_config:
        click.echo(show_sweep_config(show_config, quick))
        return
    if spec_file is None:
        _fail("name a sweep file (SPEC.toml), or --show-config EXPERIMENT")
    sweep = load_sweep(spec_file)
    (_,), variant = _validated([sweep.experiment], variant)
    _check_executor(executor, address)
    gpu_ids = _parse_gpus(gpus, executor)
    progress = not no_progress and sys.stderr.isatty()
    pool = make_executor(executor, workers, progress, address=address, gpus=gpu_ids)
    try:
        summary = run_sweep(
            sweep,
            out,
            variant=variant,
            cache_dir=cache or default_cache_dir(),
            executor=pool,
            executor_name=executor,
            log=lambda m: click.echo(f"rtfit: {m}", err=True) if not no_progress else None,
        )
    finally:
        pool.close()
    for pid, reason in summary.failed:
        click.echo(f"rtfit: sweep {sweep.name}: point {pid} failed: {reason}", err=True)
    click.echo(str((summary.directory / "report.html").resolve()))
    if summary.failed:
        raise click.exceptions.Exit(1)


def _check_executor(executor: str, address):
    if address and executor != "ray":
        raise click.UsageError("--address is for --executor ray")
    if executor == "ray":
        if importlib.util.find_spec("ray") is None:
            raise click.UsageError(RAY_EXTRA_HINT)


def _parse_gpus(text, executor: str):
    if text is None:
        return None
    if executor != "process":
        raise click.UsageError("--gpus is for --executor process (Ray finds the GPUs itself)")
    try:
        ids = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise click.UsageError(f"--gpus {text!r}: expected comma-separated GPU ids, e.g. 0,1") from None
    if not ids or min(ids) < 0 or len(set(ids)) != len(ids):
        raise click.UsageError(f"--gpus {text!r}: expected distinct non-negative GPU ids, e.g. 0,1")
    return ids


@cli.command("report")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
def report_cmd(directory):
    """Regenerate report.md/html and tables.tex from DIRECTORY/results.json (or every experiment below it)."""
    if (directory / "results.json").is_file():
        write_report(directory)
        click.echo(str((directory / "report.html").resolve()))
        return
    subdirs = sorted(
        p for p in directory.iterdir() if not is_temporary_name(p.name) and (p / "results.json").is_file()
    )
    if not subdirs:
        _fail(f"{directory}: no results.json here or in its subdirectories")
    for sub in subdirs:
        write_report(sub)
    write_index(directory, subdirs)
    click.echo(str((directory / "index.html").resolve()))


@cli.command("bench")
@click.argument("experiment")
@click.option("--variant", default="auto", show_default=True, type=click.Choice(VARIANT_CHOICES))
@click.option(
    "--size",
    type=click.IntRange(min=1024),
    default=None,
    help="Elements per kernel launch (default: 2^22 on CPU, 2^24 on GPU).",
)
@click.option("--quick", is_flag=True, help="Fewer, smaller measurements.")
def bench_cmd(experiment, variant, size, quick):
    """Throughput of each approximation (Dr.Jit vs NumPy, same run) and of the ground truth;
    'executors': per-job overhead and sweep scaling of inline / process / Ray (docs/scale-out.md)."""
    if experiment == "executors":
        variant = resolve_variant(variant)
        rows = scaling.bench(BenchContext(variant=variant, size=size, quick=quick))
        click.echo(f"# rtfit bench executors — {device_description(variant)}")
        _print_table(rows)
        return
    (spec,), variant = _validated([experiment], variant)
    module = spec.load()
    rows = module.bench(BenchContext(variant=variant, size=size, quick=quick))
    click.echo(f"# rtfit bench {spec.name} — {device_description(variant)}")
    _print_table(rows)


def _validated(names, variant: str):
    """Experiment specs and the resolved variant; a bad name or variant is a ValueError, which
    `main` prints as one line with exit status 2."""
    return resolve_names(names), resolve_variant(variant)


def _print_table(rows: list[dict]):
    """Rows as aligned columns; rows with different keys form separate tables, in order."""
    groups: list[list[dict]] = []
    for r in rows:
        if groups and list(groups[-1][0].keys()) == list(r.keys()):
            groups[-1].append(r)
        else:
            groups.append([r])
    for n, group in enumerate(groups):
        cols = list(group[0].keys())
        cells = [[_fmt(r.get(c)) for c in cols] for r in group]
        widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
        if n:
            click.echo("")
        click.echo("  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)))
        for row in cells:
            click.echo("  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)))


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)


def main(argv=None) -> int:
    """Entry point: one-line errors and exit status 2 for anything the user got wrong."""
    try:
        cli.main(args=argv, prog_name="rtfit", standalone_mode=False)
    except click.exceptions.Exit as e:
        return e.exit_code
    except (click.exceptions.Abort, KeyboardInterrupt):
        click.echo("rtfit: interrupted (rendered passes are kept in the cache; rerun to resume)", err=True)
        return 130
    except click.ClickException as e:
        msg = e.format_message().replace("\n", " ")
        click.echo(f"rtfit: error: {msg}", err=True)
        return 2
    except (SceneError, ValueError) as e:
        click.echo(f"rtfit: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", err=True)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
