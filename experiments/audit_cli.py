"""The ``rtfit audit`` command: the audit of a user's scene (`rtfit.experiments.audit_run`), or with
``--list`` the inspection (`rtfit.experiments.audit`).

    rtfit audit SCENE [--list] [-D name=value ...] [--camera N] [--width W --height H] [--up +y|-y|+z|…]
                      [--approx a,b] [--ao-distance D] [--probe-at X,Y,Z]
                      [--grid NX,NY,NZ] [--pom-depth S] [--variant V] [--spp N] [--pass-spp N] [--out DIR]
                      [--cache DIR] [--seed S] [--no-fit] [--json FILE|-] [--no-progress]

``audit`` is the click command object; the command line adds it with ``cli.add_command(audit)``. Bad input
is one line, ``rtfit: error: …``, exit status 2, nothing written.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
from pathlib import Path

import click

from rtfit.reference.mitsuba_xml import UP_AXES

from .applicability import describe
from .atomic import writable_problem
from .audit import AuditError, inspect_scene
from .audit_api import summary_document
from .audit_parallax_occlusion import check_pom_depth
from .audit_run import audit as run_audit
from .audit_run import check_ao_distance, resolve_approximations, selected_applicabilities, triple
from .cli_complete import complete_approx, complete_scene
from .cli_options import cache_option, out_option, pass_spp_option, spp_option, variant_option
from .cli_run import settings_keywords
from .families import AUDITED
from .registry import RESOLUTION_MAX

__all__ = ["AuditInputError", "audit", "input_error", "parse_defines"]


class AuditInputError(click.ClickException):
    """Bad audit input: exit status 2 and one line. ``rtfit``'s entry point prints it as ``rtfit: error: …``
    (it handles every `click.ClickException` so); run standalone (click's own handling, e.g. under
    `click.testing.CliRunner`), `show` prints the same line."""

    exit_code = 2

    def show(self, file=None) -> None:
        click.echo(f"rtfit: error: {self.format_message()}", err=True, file=file)


def input_error(message: str):
    """Stop with ``message`` (whitespace folded to one line) as the command's error line, exit status 2."""
    raise AuditInputError(" ".join(str(message).split()))


@contextlib.contextmanager
def _stdout_for_the_json_alone(active: bool):
    """With ``--json -`` stdout holds the JSON document alone: while the audit runs, whatever else writes
    to stdout (your approximation's ``print``, at import or per call; C++ code writing to file descriptor 1)
    goes to stderr. Before this, a user's ``print`` came first on stdout and the document did not parse
    (the re-check of issue 32)."""
    if not active:
        yield
        return
    sys.stdout.flush()
    try:
        saved = os.dup(1)
        os.dup2(2, 1)
    except OSError:  # no file descriptor 1 (an embedding host): Python's own prints are still redirected
        saved = None
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        sys.stderr.flush()
        if saved is not None:
            os.dup2(saved, 1)
            os.close(saved)


def _quantities(family: str) -> tuple[str, ...]:
    """The quantities an audited family compares (none for a family the audit does not run)."""
    f = AUDITED.get(family)
    return () if f is None else (f.quantity, *f.quantities)


def _json_target(path: str) -> None:
    """``--json FILE``: a file that can be written (its folder exists, it is not a folder), checked before
    anything runs."""
    p = Path(path)
    if p.is_dir():
        input_error(f"--json {path}: a folder (expected a file name, or - for stdout)")
    if not p.parent.is_dir():
        input_error(f"--json {path}: no folder {p.parent}")
    problem = writable_problem(p.parent)  # /proc, a read-only mount: refused before the audit renders
    if problem:
        input_error(f"--json {path}: {problem}")


def parse_defines(values: tuple[str, ...]) -> dict[str, str]:
    """``-D name=value`` options as a dict (a later name wins); one without ``=`` or name: an input error."""
    out: dict[str, str] = {}
    for text in values:
        name, eq, value = text.partition("=")
        if not eq or not name.strip():
            input_error(f"-D {text!r}: expected name=value")
        out[name.strip()] = value
    return out


JSON_HELP = (
    "Also write the run's summary as JSON (rtfit.audit-summary/1) to FILE; '-': to stdout, and only that on "
    "stdout (the other lines go to stderr)."
)


@click.command("audit")
@click.argument("scene", shell_complete=complete_scene)
@click.option("--list", "list_only", is_flag=True, help="Print which approximation families apply, and why.")
@click.option("-D", "defines", multiple=True, metavar="NAME=VALUE", help="A Mitsuba XML parameter ($NAME).")
@click.option("--camera", type=click.IntRange(min=0), default=0, show_default=True, help="XML sensor index.")
@click.option(
    "--width", type=click.IntRange(1, RESOLUTION_MAX), default=None, help="Film width (overrides XML's)."
)
@click.option(
    "--height",
    type=click.IntRange(1, RESOLUTION_MAX),
    default=None,
    help="Film height (overrides the XML's).",
)
@click.option(
    "--up", type=click.Choice(list(UP_AXES)), default=None, help="World up axis (default: the sensor's)."
)
@click.option(
    "--approx",
    default=None,
    metavar="A,B",
    shell_complete=complete_approx,
    help="Families, shipped methods (wrap, diffuse:exact) and your approximations (my.py:f, module:f, "
    "an entry point), comma-separated. Your approximations are Python code, run with your rights "
    "(validated first in a child process, limited to $RTFIT_APPROX_TIMEOUT_S seconds, default 30).",
)
@click.option(
    "--ao-distance",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    help="AO radius in scene units (default: 0.1 × the scene's bounding-box diagonal).",
)
@click.option(
    "--probe-at",
    default=None,
    metavar="X,Y,Z",
    help="Where the environment-maps family captures its cube maps (default: each shape's centre).",
)
@click.option(
    "--grid",
    default=None,
    metavar="NX,NY,NZ",
    help="Probes of the irradiance-volumes grid over the scene's box (default: by the box's aspect).",
)
@click.option(
    "--pom-depth",
    default=None,
    metavar="S",
    help="Height range of a bump map's height field for parallax occlusion, in texture units (default 0.1).",
)
@variant_option()
@spp_option()
@pass_spp_option(
    "Samples per cached pass (32); the last pass holds the rest of --spp (at least 2), and one larger "
    "than --spp means one pass of --spp."
)
@out_option("Output directory: the report goes to OUT/audit-<scene>.")
@cache_option()
@click.option("--seed", type=click.IntRange(min=0, max=2**31 - 1), default=0, show_default=True)
@click.option("--no-fit", is_flag=True, help="Do not fit free parameters to the scene.")
@click.option("--json", "json_out", default=None, metavar="FILE", help=JSON_HELP)
@click.option("--no-progress", is_flag=True, help="No progress bars.")
@click.option(
    "--profile",
    is_flag=True,
    help="Print where the time went: reference, evaluation and fit per family, scene set-up and report.",
)
def audit(
    scene,
    list_only,
    defines,
    camera,
    width,
    height,
    up,
    approx,
    ao_distance,
    probe_at,
    grid,
    pom_depth,
    out,
    no_fit,
    json_out,
    profile,
    **run_options,
):
    """Audit SCENE (a Mitsuba .xml scene, an rtfit .toml scene or sky file, or a library name): every
    applicable approximation against the scene's own reference, with noise floors, fits, costs and a report
    in OUT/audit-<scene>. --list prints which approximation families apply to it and why."""
    if json_out is not None and list_only:
        input_error("--json writes the run's summary; --list prints what applies as text (drop one of them)")
    if json_out is not None and json_out != "-":
        _json_target(json_out)
    try:
        triple("--probe-at", probe_at, float)  # bad values: one line before anything is read or rendered
        triple("--grid", grid, int)
        check_pom_depth(pom_depth)
        if list_only:
            check_ao_distance(ao_distance)
            info = inspect_scene(
                scene, defines=parse_defines(defines), camera=camera, width=width, height=height, up=up
            )
            sel = resolve_approximations(approx)  # families, shipped methods and your own, as the run
            found = selected_applicabilities(info, sel, ao_distance)
            for line in describe(info, found, ao_distance=ao_distance, restricted=approx is not None):
                click.echo(line)
            for m in sel.user:
                fams = [a.family for a in found if m.quantity in _quantities(a.family)]
                click.echo(
                    f"yours: {m.id} ({m.quantity}) — audited beside "
                    + (", ".join(dict.fromkeys(fams)) or "no family that applies here")
                )
            return
        with _stdout_for_the_json_alone(json_out == "-"):
            result = run_audit(
                scene, approx, fit=not no_fit, out=out, defines=parse_defines(defines), camera=camera,
                width=width, height=height, up=up, ao_distance=ao_distance, probe_at=probe_at, grid=grid,
                pom_depth=pom_depth, **settings_keywords(run_options),
            )  # fmt: skip
    except AuditError as e:
        input_error(str(e))
    click.echo(f"camera: {result.info.camera}", err=True)
    click.echo(f"up: {result.info.up_reason}", err=True)
    for line in result.skipped:
        click.echo(f"note: {line}", err=True)
    t = result.timings
    click.echo(
        f"timings: reference {t['reference']:.1f} s, evaluation {t['evaluation']:.1f} s, "
        f"fit {t['fit']:.1f} s" + (f", report {t['report']:.1f} s" if "report" in t else ""),
        err=True,
    )
    if profile:
        for line in result.profile_lines():
            click.echo(f"profile: {line}", err=True)
    to_stdout = json_out == "-"  # then stdout holds the JSON document alone
    click.echo(f"summary: {result.results.summary}", err=to_stdout)
    assert result.out is not None
    click.echo(str((result.out / "report.html").resolve()), err=to_stdout)
    if json_out is not None:
        text = json.dumps(summary_document(result), indent=2, allow_nan=False)
        if to_stdout:
            click.echo(text)
        else:
            Path(json_out).write_text(text + "\n", encoding="utf-8")
    failed = [c for c in result.results.checks if not c.passed]
    for c in failed:
        click.echo(f"rtfit: check failed: {c.name}: {c.value} (expected {c.expected})", err=True)
    if failed:
        raise click.exceptions.Exit(1)
