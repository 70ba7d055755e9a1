"""The ``rtfit audit`` command (its ``--list`` inspection; the audit itself is built later).

    rtfit audit SCENE --list [-D name=value ...] [--camera N] [--width W --height H] [--up +y|-y|+z|…]
                             [--approx a,b] [--ao-distance D]

``audit`` is the click command object; the command line adds it with ``cli.add_command(audit)``. Bad input
is one line, ``rtfit: error: …``, exit status 2, nothing written.
"""

from __future__ import annotations

import click

from rtfit.reference.mitsuba_xml import UP_AXES

from .audit import AuditError, applicable_families, describe, inspect_scene

__all__ = ["AuditInputError", "audit"]


class AuditInputError(click.ClickException):
    """Bad audit input: exit status 2 and one line. ``rtfit``'s entry point prints it as ``rtfit: error: …``
    (it handles every `click.ClickException` so); run standalone (click's own handling, e.g. under
    `click.testing.CliRunner`), `show` prints the same line."""

    exit_code = 2

    def show(self, file=None) -> None:
        click.echo(f"rtfit: error: {self.format_message()}", err=True, file=file)


def _error(message: str):
    raise AuditInputError(" ".join(str(message).split()))


def _defines(values: tuple[str, ...]) -> dict[str, str]:
    out: dict[str, str] = {}
    for text in values:
        name, eq, value = text.partition("=")
        if not eq or not name.strip():
            _error(f"-D {text!r}: expected name=value")
        out[name.strip()] = value
    return out


@click.command("audit")
@click.argument("scene")
@click.option("--list", "list_only", is_flag=True, help="Print which approximation families apply, and why.")
@click.option("-D", "defines", multiple=True, metavar="NAME=VALUE", help="A Mitsuba XML parameter ($NAME).")
@click.option("--camera", type=click.IntRange(min=0), default=0, show_default=True, help="XML sensor index.")
@click.option("--width", type=click.IntRange(min=1), default=None, help="Film width (overrides the XML's).")
@click.option("--height", type=click.IntRange(min=1), default=None, help="Film height (overrides the XML's).")
@click.option(
    "--up", type=click.Choice(list(UP_AXES)), default=None, help="World up axis (default: the sensor's)."
)
@click.option("--approx", default=None, metavar="A,B", help="Only these families (comma-separated).")
@click.option(
    "--ao-distance",
    type=click.FloatRange(min=0.0, min_open=True),
    default=None,
    help="AO radius in scene units (default: 0.1 × the scene's bounding-box diagonal).",
)
def audit(scene, list_only, defines, camera, width, height, up, approx, ao_distance):
    """Audit SCENE (a Mitsuba .xml scene, an rtfit .toml scene, or a library name); --list prints which
    approximation families apply to it and why."""
    if not list_only:
        _error("the audit itself is not built yet; use --list")
    try:
        info = inspect_scene(
            scene, defines=_defines(defines), camera=camera, width=width, height=height, up=up
        )
        found = applicable_families(info, approx=approx, ao_distance=ao_distance)
    except AuditError as e:
        _error(str(e))
    for line in describe(info, found, ao_distance=ao_distance, restricted=approx is not None):
        click.echo(line)
