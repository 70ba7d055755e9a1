"""The ``rtfit`` command line.

    rtfit [-v|-q] [--version] COMMAND …
    rtfit list
    rtfit run EXPERIMENT... [--quick] [--variant V] [--spp N] [--out DIR] [--cache DIR]
                            [--executor inline|process|ray] [--address A] [--workers N] [--seed S]
    rtfit sweep SPEC.toml [--variant V] [--out DIR] [--cache DIR] [--executor …] [--address A] [--gpus 0,1]
    rtfit sweep --show-config EXPERIMENT [--quick]
    rtfit report DIR
    rtfit bench EXPERIMENT [--variant V] [--size N] [--quick] [--json [FILE|-]]
    rtfit cache info [--cache DIR]
    rtfit cache prune [--cache DIR] [--older-than 30d] [--max-size 2G] [--dry-run]

Errors in what the user typed or supplied (unknown experiment, bad option, malformed scene file,
invalid value, an unwritable ``--out``/``--cache``, an unreadable probe file, a Ray address that does
not answer) print one line, ``rtfit: error: …``, write nothing and exit with status 2, before anything
runs: every configuration value is checked against its key's declaration (`families.validate_config`).
Exit status 1: the work ran but part of it failed (``rtfit sweep`` with failed points; ``rtfit run``
with failed self-checks: one line per experiment, ``rtfit: EXPERIMENT: N of M checks failed: …``).

Progress goes to stderr through `logging` (loggers under ``rtfit``: ``rtfit.experiments`` one line per
experiment start and end, ``rtfit.jobs`` one per finished job, ``rtfit.reference`` cache resumes),
configured here once per call: INFO by default, ``-q`` warnings and errors only, ``-v`` DEBUG. On a
terminal the jobs and the stages with a known count (`rtfit.experiments.progress.Stage`: experiments,
scenes, references, cases) show as tqdm bars instead of lines (``--no-progress``: lines). Results go to
stdout.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import math
import os
import signal
import sys
import threading
import time
from importlib import metadata
from pathlib import Path

import click
from tqdm import tqdm

import rtfit
from rtfit.reference import default_cache_dir, resolve_variant
from rtfit.reference.budget import NonFinitePass, PassBudgetExceeded, pass_budget_seconds
from rtfit.reference.export_xml import export_xml
from rtfit.reference.io import atomic_write_json
from rtfit.reference.probe_maps import parse_probe_spec, probe_spec_problem
from rtfit.reference.variants import cuda_available
from rtfit.scenes import SceneError, library_path, load_scene

from . import scaling
from .atomic import is_temporary_name, writable_problem
from .audit_cli import audit
from .book import write_book
from .cache_cli import cache_group
from .cli_complete import complete_experiments, family_list
from .cli_options import CACHE_HELP, VARIANT_CHOICES, cache_option, out_option, spp_option, variant_option
from .compare_cli import compare
from .executors import EXECUTORS, make_executor
from .families import EXPERIMENTS, describe_config, resolve_names, validate_config
from .fitted_cli import fitted_group
from .jobs import JobsFailed, error_line
from .ray_executor import RAY_EXTRA_HINT, check_address
from .registry import LIMITS, SPP_MAX, BenchContext
from .report import missing_figures, write_index, write_report
from .runner import (
    RunFailed,
    check_summary,
    created_now,
    device_description,
    run_experiments,
    use_variant_backend,
    versions,
)
from .sweep import load_sweep, run_sweep


class UserError(click.ClickException):
    exit_code = 2


SINGLE_FILE_HELP = (
    "Also write EXPERIMENT/report.single.html: the report with its figures, image viewer and pixel data "
    "embedded (one file to mail)."
)


def _fail(message: str):
    raise UserError(message)


def version_line() -> str:
    """``rtfit X.Y.Z (mitsuba A, drjit B, Python C)``, from package metadata: nothing is imported."""

    def v(dist):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "not installed"

    return (
        f"rtfit {rtfit.__version__} (mitsuba {v('mitsuba')}, drjit {v('drjit')}, "
        f"Python {sys.version.split()[0]})"
    )


def _print_version(ctx, _param, value):
    if value and not ctx.resilient_parsing:
        click.echo(version_line())
        ctx.exit(0)


class _StderrLines(logging.Handler):
    """Log records as ``rtfit: …`` lines on the *current* ``sys.stderr`` (looked up per record, since
    tests and notebooks swap it), through ``tqdm.write`` while bars may be drawn so as not to tear them."""

    def __init__(self, bars: bool, verbose: bool):
        super().__init__()
        self.bars, self.verbose = bars, verbose

    def format(self, record):
        text = record.getMessage()
        if record.levelno >= logging.WARNING:
            text = f"{record.levelname.lower()}: {text}"
        if self.verbose:
            text = f"{record.relativeCreated / 1000:7.1f}s {record.name}: {text}"
        return f"rtfit: {text}"

    def emit(self, record):
        try:
            line = self.format(record)
            if self.bars:
                tqdm.write(line, file=sys.stderr)
            else:
                sys.stderr.write(line + "\n")
                sys.stderr.flush()
        except Exception:
            self.handleError(record)


def configure_logging(verbose: bool, quiet: bool) -> bool:
    """Configure the ``rtfit`` logger for one command (replacing what an earlier call in this process
    set up); returns whether progress bars are drawn (stderr is a terminal, and not ``-q``)."""
    bars = sys.stderr.isatty() and not quiet
    logger = logging.getLogger("rtfit")
    for h in [h for h in logger.handlers if isinstance(h, _StderrLines)]:
        logger.removeHandler(h)
    logger.addHandler(_StderrLines(bars, verbose))
    logger.setLevel(logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO)
    return bars


def _bars(no_progress: bool) -> bool:
    """Whether this command draws progress bars (``-q``/``--no-progress``/no terminal: no)."""
    obj = click.get_current_context().find_root().obj or {}
    return obj.get("bars", False) and not no_progress


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "--version",
    is_flag=True,
    expose_value=False,
    is_eager=True,
    callback=_print_version,
    help="Print rtfit's version (and Mitsuba's, Dr.Jit's) and exit.",
)
@click.option("-v", "--verbose", is_flag=True, help="Debug lines too (every job, with times and loggers).")
@click.option("-q", "--quiet", is_flag=True, help="Only warnings and errors; no progress bars.")
@click.pass_context
def cli(ctx, verbose, quiet):
    """rtfit: how wrong is a real-time rendering shortcut, where, at what cost, and which parameters
    make it least wrong (Mitsuba 3 ground truth, Dr.Jit approximations)."""
    if verbose and quiet:
        raise click.UsageError("-v and -q exclude each other")
    try:  # checked before any command starts, not when the first pass arms its watchdog
        pass_budget_seconds()
    except ValueError as e:
        raise click.UsageError(str(e)) from None
    ctx.obj = {"bars": configure_logging(verbose, quiet)}


@cli.command("list")
@click.option(
    "--json", "as_json", is_flag=True, help="One JSON document: name, title, audited, methods, quantities."
)
def list_cmd(as_json):
    """List the experiments."""
    if as_json:
        click.echo(json.dumps({"families": family_list()}, indent=2))
        return
    width = max(len(n) for n in EXPERIMENTS)
    for name, spec in EXPERIMENTS.items():
        click.echo(f"{name:<{width}}  {spec.title}")


@cli.command("run")
@click.argument("experiments", nargs=-1, shell_complete=complete_experiments)
@click.option("--quick", is_flag=True, help="Small images, few samples, fewer cases (minutes on 2 cores).")
@variant_option()
@spp_option(f"Reference samples per pixel (overrides; at most {SPP_MAX}).")
@out_option()
@cache_option()
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
@click.option("--single-file", is_flag=True, help=SINGLE_FILE_HELP)
@click.option(
    "--probe",
    "probes",
    multiple=True,
    metavar="FILE[:MAPPING]",
    help="Your own light probe as one more environment, for experiments with a 'probes' key (none since "
    "irradiance-bases runs on the audit engine: audit a scene holding your probe as its envmap instead).",
)
def run_cmd(
    experiments,
    quick,
    variant,
    spp,
    out,
    cache,
    executor,
    address,
    workers,
    seed,
    no_progress,
    single_file,
    probes,
):
    """Run EXPERIMENT... (or 'all') and write OUT/EXPERIMENT/{results.json,report.html,...}."""
    specs, variant = _validated(experiments, variant)  # before anything is written
    _check_executor(executor, address)
    overrides = _probe_overrides(specs, quick, probes)
    cache = _writable_dir(cache, "--cache")
    _writable_dir(out, "--out")
    for spec in specs:  # every configuration value, its type, range and files, before anything runs
        _config_ok(spec.name, quick, spp, overrides)
    done = run_experiments(
        specs,
        out,
        quick=quick,
        variant=variant,
        spp=spp,
        seed=seed,
        cache_dir=cache,
        executor=executor,
        workers=workers,
        progress=_bars(no_progress),
        address=address,
        single_file=single_file,
        overrides=overrides,
    )
    click.echo(str((out / "index.html").resolve()))
    failed = [line for line in map(check_summary, done) if line]
    for line in failed:
        click.echo(f"rtfit: {line}", err=True)
    if failed:
        raise click.exceptions.Exit(1)


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
@out_option("Output directory (the sweep goes to OUT/NAME).")
@cache_option(CACHE_HELP[:-1] + "; share it between nodes.")
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
        click.echo(describe_config(show_config, quick))
        return
    if spec_file is None:
        _fail("name a sweep file (SPEC.toml), or --show-config EXPERIMENT")
    sweep = load_sweep(spec_file)
    (_,), variant = _validated([sweep.experiment], variant)
    _check_executor(executor, address)
    cache = _writable_dir(cache, "--cache")
    _writable_dir(out, "--out")
    for i, point in enumerate(sweep.points):  # every point's values and files, before any point runs
        _config_ok(sweep.experiment, sweep.quick, sweep.spp, point, f"{spec_file}: point {i}: ")
    gpu_ids = _parse_gpus(gpus, executor)
    progress = _bars(no_progress)
    pool = make_executor(executor, workers, progress, address=address, gpus=gpu_ids)
    try:
        summary = run_sweep(
            sweep,
            out,
            variant=variant,
            cache_dir=cache,
            executor=pool,
            executor_name=executor,
            log=logging.getLogger("rtfit.experiments").info,
        )
    finally:
        pool.close()
    for pid, reason in summary.failed:
        click.echo(f"rtfit: sweep {sweep.name}: point {pid} failed: {reason}", err=True)
    click.echo(str((summary.directory / "report.html").resolve()))
    if summary.failed:
        total = len(summary.ran) + len(summary.resumed) + len(summary.failed)
        ids = ", ".join(pid for pid, _ in summary.failed)
        click.echo(
            f"rtfit: sweep {sweep.name}: {len(summary.failed)} of {total} points failed ({ids}); "
            "the report marks them, a rerun retries only them",
            err=True,
        )
        raise click.exceptions.Exit(1)


cli.add_command(cache_group)
cli.add_command(fitted_group)
cli.add_command(audit)
cli.add_command(compare)


def _probe_overrides(specs, quick: bool, probes) -> dict:
    """``--probe`` values as the ``probes`` configuration key (paths made absolute, a ``:MAPPING`` suffix
    kept), for experiments that declare it; none: no overrides."""
    if not probes:
        return {}
    for text in probes:  # the file's own problem first (one line), then whether any experiment takes it
        problem = probe_spec_problem(text)
        if problem:
            _fail(f"--probe {text}: {problem}")
    without = []
    for s in specs:
        try:
            if "probes" not in validate_config(s.name, quick, None, {}):
                without.append(s.name)
        except ValueError as e:  # a bad default (e.g. a corrupt measured probe): the usual one line
            _fail(f"{s.name}: {e}")
    if without:
        _fail(
            f"--probe: {', '.join(without)} takes no probes (irradiance-bases runs on the audit engine's "
            "shipped scenes: put your probe in a scene as its envmap and run `rtfit audit SCENE`)"
        )
    out = []
    for text in probes:
        p = parse_probe_spec(text)
        path = str(Path(p.path).expanduser().absolute())
        out.append(f"{path}:{p.mapping}" if p.mapping else path)
    return {"probes": out}


def _config_ok(experiment: str, quick: bool, spp, overrides: dict, where: str = ""):
    """``experiment``'s configuration with ``overrides``, every value checked against its declaration
    (`families.validate_config`: type, range, files readable): a one-line error otherwise."""
    try:
        validate_config(experiment, quick, spp, overrides)
    except ValueError as e:
        _fail(f"{where}{experiment}: {e}")


def _writable_dir(path, option: str) -> Path:
    """``path`` (``None``: the default cache directory, ``$RTFIT_CACHE`` or ``~/.cache/rtfit``) checked
    as a directory this process can create and write to, before anything runs: its nearest existing
    ancestor must be a directory, and a probe directory is made there and removed at once (``os.access``
    says yes to root on a read-only filesystem). Nothing else is created."""
    if path is None:
        path = default_cache_dir()
        if os.environ.get("RTFIT_CACHE"):
            option = "$RTFIT_CACHE"
    path = Path(path)
    problem = writable_problem(path)
    if problem is not None:
        _fail(f"{option} {path}: {problem}")
    return path


def _check_executor(executor: str, address):
    if address and executor != "ray":
        raise click.UsageError("--address is for --executor ray")
    if executor == "ray":
        if importlib.util.find_spec("ray") is None:
            raise click.UsageError(RAY_EXTRA_HINT)
        if address:  # a wrong host or port: one line in seconds, before anything runs
            check_address(address)
        elif os.environ.get("RAY_ADDRESS"):  # Ray reads it by itself: the same check
            check_address(os.environ["RAY_ADDRESS"], option="$RAY_ADDRESS")


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
    if not cuda_available():  # the workers would run on the CPU, silently (issue 32)
        raise click.UsageError(
            f"--gpus {text}: no CUDA GPU was found here (leave --gpus out to run on the CPU)"
        )
    return ids


def _warn_missing_figures(directory: Path) -> None:
    """One warning line when figure files that results.json names are gone (the report marks them)."""
    missing = missing_figures(directory)
    if missing:
        shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        logging.getLogger("rtfit.experiments").warning(
            "%s: %d figure file(s) named in results.json are missing (%s): the report marks them missing",
            directory,
            len(missing),
            shown,
        )


@cli.command("report")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--single-file", is_flag=True, help=SINGLE_FILE_HELP)
def report_cmd(directory, single_file):
    """Regenerate report.md/html and tables.tex from DIRECTORY/results.json (or every experiment below it)."""
    if (directory / "results.json").is_file():
        _check_report_folders([directory])
        write_report(directory, single_file=single_file)
        _warn_missing_figures(directory)
        click.echo(str((directory / ("report.single.html" if single_file else "report.html")).resolve()))
        return
    subdirs = sorted(
        p for p in directory.iterdir() if not is_temporary_name(p.name) and (p / "results.json").is_file()
    )
    if not subdirs:
        _fail(f"{directory}: no results.json here or in its subdirectories")
    _check_report_folders([directory, *subdirs])
    for sub in subdirs:
        write_report(sub, single_file=single_file)
        _warn_missing_figures(sub)
    write_index(directory, subdirs)
    click.echo(str((directory / "index.html").resolve()))
    book = write_book(directory, subdirs)  # the audit book over the whole run (docs/book.md)
    click.echo(str(book.tex.resolve()))
    if book.pdf is not None:
        click.echo(str(book.pdf.resolve()))
    elif book.pdflatex:
        click.echo(f"rtfit: {book.tex}: {book.error} (log: {directory / 'book.log'})", err=True)
        raise click.exceptions.Exit(1)
    else:
        click.echo(f"rtfit: book.pdf not written: {book.error}", err=True)


def _check_report_folders(folders: list[Path]) -> None:
    """Each folder the report is written into must be writable, checked before anything is written (a
    read-only or immutable folder ended in a traceback from the first atomic write: the re-check of issue
    32)."""
    for folder in folders:
        problem = writable_problem(folder)
        if problem:
            _fail(f"{folder}: the report is written there, but {problem}")


@cli.command("export-xml")
@click.argument("scene")
@click.argument("output", type=click.Path(dir_okay=False, path_type=Path))
def export_xml_cmd(scene, output):
    """Write an rtfit TOML SCENE (a file, or a shipped scene's name) as plain Mitsuba 3 XML to OUTPUT.

    Mesh files go into a meshes/ folder beside OUTPUT. rtfit's own plugins (the distant-disc sun, the
    exponential height fog, the Nishita atmosphere) are left out, one line each on stderr."""
    path = Path(scene)
    try:
        parsed = load_scene(path if path.suffix == ".toml" or path.exists() else library_path(scene))
    except SceneError as e:
        _fail(str(e))
    if output.exists() and output.is_dir():
        _fail(f"OUTPUT {output}: is a directory")
    _writable_dir(output.parent, "OUTPUT")
    output.parent.mkdir(parents=True, exist_ok=True)
    result = export_xml(parsed, output)
    for part in result.left_out:
        click.echo(f"rtfit: left out {part}", err=True)
    click.echo(str(result.path.resolve()))


@cli.command("bench")
@click.argument("experiment", shell_complete=complete_experiments)
@click.option("--variant", default="auto", show_default=True, type=click.Choice(VARIANT_CHOICES))
@click.option(
    "--size",
    type=click.IntRange(min=LIMITS["bench_size"].lo, max=LIMITS["bench_size"].hi),
    default=None,
    help="Elements per kernel launch (default: 2^22 on CPU, 2^24 on GPU).",
)
@click.option("--quick", is_flag=True, help="Fewer, smaller measurements.")
@click.option(
    "--json",
    "json_out",
    is_flag=False,
    flag_value="-",
    default=None,
    metavar="[FILE|-]",
    help="Also write the rows as JSON (format rtfit.bench/1) to FILE (atomically), or alone to stdout "
    "with '-' or no value (put --json last, or write --json=FILE).",
)
def bench_cmd(experiment, variant, size, quick, json_out):
    """Throughput of each approximation (Dr.Jit vs NumPy, same run) and of the ground truth;
    'executors': per-job overhead and sweep scaling of inline / process / Ray (docs/scale-out.md)."""
    target = _json_target(json_out)
    if experiment == "executors":
        name, variant = "executors", resolve_variant(variant)
        bench = scaling.bench
    else:
        (spec,), variant = _validated([experiment], variant)
        name, bench = spec.name, spec.load().bench
    started, t0 = created_now(), time.perf_counter()
    use_variant_backend(variant)
    rows = bench(BenchContext(variant=variant, size=size, quick=quick))
    device = device_description(variant)
    if target != "-":
        click.echo(f"# rtfit bench {name} — {device}")
        _print_table(rows)
    if target is None:
        return
    header = dict(device=device, variant=variant, size=size, quick=quick, created=started)
    doc = bench_document(name, rows, **header, seconds=time.perf_counter() - t0)
    if target == "-":
        click.echo(json.dumps(doc, indent=2, allow_nan=False))
    else:
        atomic_write_json(target, doc)
        logging.getLogger("rtfit.experiments").info("bench %s: rows written to %s", name, target)


BENCH_FORMAT = "rtfit.bench/1"


def bench_document(
    name: str, rows: list[dict], *, device: str, variant: str, size, quick: bool, created: str, seconds: float
) -> dict:
    """``rtfit bench --json``: a header (format, experiment, rtfit version, date the bench started, its
    duration, device, variant, options, package versions) and the rows as objects, each with its own
    keys (rows of different keys are the separate tables of the text output). Non-finite numbers and
    absent cells are null."""
    return {
        "format": BENCH_FORMAT,
        "experiment": name,
        "rtfit": rtfit.__version__,
        "created": created,
        "seconds": round(seconds, 3),
        "device": device,
        "variant": variant,
        "size": size,
        "quick": quick,
        "versions": versions(),
        "rows": [{k: _json_value(v) for k, v in r.items()} for r in rows],
    }


def _json_value(v):
    if hasattr(v, "tolist"):  # NumPy scalars and arrays
        v = v.tolist()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    return v


def _json_target(value):
    """``--json`` checked before the benchmark runs: None, '-' (stdout) or a writable file path."""
    if value is None or value == "-":
        return value
    path = Path(value)
    if path.is_dir():
        _fail(f"--json {value}: is a directory (name a file)")
    if not path.parent.is_dir():
        _fail(f"--json {value}: no directory {path.parent}")
    problem = writable_problem(path.parent)  # /proc, a read-only mount: not after the benchmark (issue 32)
    if problem:
        _fail(f"--json {value}: {problem}")
    return path


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


class Terminated(KeyboardInterrupt):
    """SIGTERM (a `timeout`, a batch system's stop) turned into an interruption: the work ends as after Ctrl-C
    (a partial audit report, the cache kept), exit 143 (128 + 15)."""


def _raise_terminated(signum, frame):
    raise Terminated()


def _on_sigterm_interrupt():
    """Make SIGTERM raise `Terminated` in the main thread for the command's duration; returns the handler to
    put back (None where signals cannot be set: not the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _raise_terminated)


def main(argv=None) -> int:
    """Entry point: one-line errors and exit status 2 for anything the user got wrong."""
    logger, level = logging.getLogger("rtfit"), logging.getLogger("rtfit").level
    previous = _on_sigterm_interrupt()
    try:
        # Without standalone mode click *returns* the status of a command that exits (`Exit(1)`: a
        # sweep with failed points) instead of raising; a command that finishes returns None.
        status = cli.main(args=argv, prog_name="rtfit", standalone_mode=False)
    except click.exceptions.Exit as e:
        return e.exit_code
    except (click.exceptions.Abort, KeyboardInterrupt) as e:
        if isinstance(e, click.exceptions.Abort):  # click wraps the KeyboardInterrupt it caught
            e = e.__cause__ or e.__context__ or e
        partial = getattr(e, "partial_report", None)
        if partial is not None:
            click.echo(f"rtfit: interrupted: the report of the finished cases is in {partial}", err=True)
        click.echo("rtfit: interrupted (rendered passes are kept in the cache; rerun to resume)", err=True)
        return 143 if isinstance(e, Terminated) else 130
    except click.ClickException as e:
        msg = e.format_message().replace("\n", " ")
        click.echo(f"rtfit: error: {msg}", err=True)
        return 2
    except (SceneError, ValueError) as e:
        click.echo(f"rtfit: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", err=True)
        return 2
    except (PassBudgetExceeded, NonFinitePass, JobsFailed, RunFailed) as e:
        # a reference that could not be made (a pass past its budget, a non-finite pass, a job whose worker
        # kept dying) or a run that failed inside (RunFailed): not the user's input, so exit 1 — one line,
        # and the passes already stored are kept
        what = str(e) if isinstance(e, RunFailed) else error_line(e)
        click.echo(
            f"rtfit: failed: {what} (rendered passes are kept in the cache; rerun to resume)", err=True
        )
        return 1
    finally:  # the logging set up for this command ends with it (a library caller's own stays)
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        for h in [h for h in logger.handlers if isinstance(h, _StderrLines)]:
            logger.removeHandler(h)
        logger.setLevel(level)
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
