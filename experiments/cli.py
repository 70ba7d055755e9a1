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

This module holds the group, logging and `main`; the commands live in `cli_list` (``list``), `cli_run`
(``run``, ``sweep``, ``report``, ``export-xml``), `cli_bench` (``bench``), `audit_cli`, `compare_cli`,
`cache_cli` and `fitted_cli`, the checks of what the user typed in `cli_checks`. The group imports a
command's module only when that command runs or shows its help (`cli_commands.LazyGroup`): ``rtfit --help``
lists them from their source text, and imports neither Mitsuba nor any family (issue 33: < 2 s on 2 cores).
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
from importlib import metadata

import click
from tqdm import tqdm

import rtfit
from rtfit.fitting.blas_threads import one_blas_thread_by_default
from rtfit.reference.budget import NonFinitePass, PassBudgetExceeded, pass_budget_seconds
from rtfit.scenes import SceneError

from .cli_commands import LazyGroup
from .jobs import JobsFailed, RunFailed, error_line


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


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
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
        with one_blas_thread_by_default():  # (rtfit's BLAS work is small: its threads would only spin)
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
