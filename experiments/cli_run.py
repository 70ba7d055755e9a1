"""The ``rtfit`` commands that run experiments and write their reports: ``run``, ``sweep``,
``report`` and ``export-xml`` (registered on the group in `rtfit.experiments.cli`), with the options
``run`` and ``sweep`` share."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import click

from rtfit.reference.export_xml import export_xml
from rtfit.scenes import SceneError, library_path, load_scene

from .atomic import is_temporary_name
from .book import write_book
from .cli_checks import (
    check_executor,
    check_report_folders,
    config_ok,
    fail,
    parse_gpus,
    probe_overrides,
    validated,
    writable_dir,
)
from .cli_complete import complete_experiments
from .cli_options import CACHE_HELP, VARIANT_CHOICES, cache_option, out_option, spp_option, variant_option
from .executors import EXECUTORS, make_executor
from .families import describe_config
from .registry import SPP_MAX
from .report import missing_figures, write_report
from .report_index import write_index
from .run_settings import RunSettings
from .runner import check_summary, run_experiments
from .sweep import load_sweep, run_sweep

__all__ = [
    "export_xml_cmd",
    "progress_bars",
    "report_cmd",
    "run_cmd",
    "settings_keywords",
    "sweep_cmd",
]

SINGLE_FILE_HELP = (
    "Also write EXPERIMENT/report.single.html: the report with its figures, image viewer and pixel data "
    "embedded (one file to mail)."
)


def address_option():
    """``--address`` (default None: ``$RAY_ADDRESS``, else a local cluster), as the argument ``address``."""
    return click.option(
        "--address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)."
    )


def workers_option():
    """``--workers N`` (at least 1; default None: the executor's own), as the argument ``workers``."""
    return click.option(
        "--workers", type=click.IntRange(min=1), default=None, help="Pool size (process/ray on CPUs)."
    )


def no_progress_option():
    """``--no-progress`` (a flag), as the argument ``no_progress``."""
    return click.option("--no-progress", is_flag=True, help="No progress bars.")


def progress_bars(no_progress: bool) -> bool:
    """Whether this command draws progress bars (``-q``/``--no-progress``/no terminal: no)."""
    obj = click.get_current_context().find_root().obj or {}
    return obj.get("bars", False) and not no_progress


def settings_keywords(options: Mapping[str, Any]) -> dict[str, Any]:
    """The run settings among a command's ``options`` (``--variant``, ``--spp``, ``--pass-spp``, ``--seed``,
    ``--cache``, ``--no-progress``) as the keywords of `rtfit.audit` and `rtfit.compare`, which build their
    `RunSettings` from them (`RunSettings.checked`)."""
    keys = ("variant", "spp", "pass_spp", "seed", "cache")
    return {**{k: options[k] for k in keys}, "progress": progress_bars(options["no_progress"])}


@click.command("run")
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
@address_option()
@workers_option()
@click.option("--seed", type=click.IntRange(min=0, max=2**31 - 1), default=0, show_default=True)
@no_progress_option()
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
    specs, variant = validated(experiments, variant)  # before anything is written
    check_executor(executor, address)
    overrides = probe_overrides(specs, quick, probes)
    cache = writable_dir(cache, "--cache")
    writable_dir(out, "--out")
    for spec in specs:  # every configuration value, its type, range and files, before anything runs
        config_ok(spec.name, quick, spp, overrides)
    settings = RunSettings(cache, variant, spp, seed=seed, progress=progress_bars(no_progress), quick=quick)
    done = run_experiments(
        specs, out, settings, executor=executor, workers=workers, address=address, overrides=overrides,
        single_file=single_file,
    )  # fmt: skip
    click.echo(str((out / "index.html").resolve()))
    failed = [line for line in map(check_summary, done) if line]
    for line in failed:
        click.echo(f"rtfit: {line}", err=True)
    if failed:
        raise click.exceptions.Exit(1)


@click.command("sweep")
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
@address_option()
@workers_option()
@click.option("--gpus", default=None, help="process executor: one worker per listed GPU id, e.g. 0,1.")
@no_progress_option()
def sweep_cmd(
    spec_file, show_config, quick, variant, out, cache, executor, address, workers, gpus, no_progress
):
    """Run the experiment of SPEC.toml over its grid of configuration points (docs/scale-out.md):
    one results.json per point in OUT/NAME/points/, and a combined table and report in OUT/NAME/."""
    if show_config:
        click.echo(describe_config(show_config, quick))
        return
    if spec_file is None:
        fail("name a sweep file (SPEC.toml), or --show-config EXPERIMENT")
    sweep = load_sweep(spec_file)
    (_,), variant = validated([sweep.experiment], variant)
    check_executor(executor, address)
    cache = writable_dir(cache, "--cache")
    writable_dir(out, "--out")
    for i, point in enumerate(sweep.points):  # every point's values and files, before any point runs
        config_ok(sweep.experiment, sweep.quick, sweep.spp, point, f"{spec_file}: point {i}: ")
    gpu_ids = parse_gpus(gpus, executor)
    progress = progress_bars(no_progress)
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


@click.command("report")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--single-file", is_flag=True, help=SINGLE_FILE_HELP)
def report_cmd(directory, single_file):
    """Regenerate report.md/html and tables.tex from DIRECTORY/results.json (or every experiment below it)."""
    if (directory / "results.json").is_file():
        check_report_folders([directory])
        write_report(directory, single_file=single_file)
        _warn_missing_figures(directory)
        click.echo(str((directory / ("report.single.html" if single_file else "report.html")).resolve()))
        return
    subdirs = sorted(
        p for p in directory.iterdir() if not is_temporary_name(p.name) and (p / "results.json").is_file()
    )
    if not subdirs:
        fail(f"{directory}: no results.json here or in its subdirectories")
    check_report_folders([directory, *subdirs])
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


@click.command("export-xml")
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
        fail(str(e))
    if output.exists() and output.is_dir():
        fail(f"OUTPUT {output}: is a directory")
    writable_dir(output.parent, "OUTPUT")
    output.parent.mkdir(parents=True, exist_ok=True)
    result = export_xml(parsed, output)
    for part in result.left_out:
        click.echo(f"rtfit: left out {part}", err=True)
    click.echo(str(result.path.resolve()))
