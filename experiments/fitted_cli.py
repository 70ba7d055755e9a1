"""``rtfit fitted convert FILE --engine unreal|unity-hdrp|godot``: a fitted file's height fog (and the
Nishita sky's artist fit, the irradiance-bases SH fits in the engines' SH layouts) in an engine's own
properties (`rtfit.experiments.engine_presets`, format ``rtfit.engine-preset/1``).

    rtfit fitted convert fitted/fog-e10-single-const.json --engine unreal [--base-height M] [--out FILE|-]

The document goes to stdout (``--out -``, the default) or to FILE. A fitted file written by a run carries the
same presets in its ``engine_presets`` section (`rtfit.experiments.fitted.write_fitted`); without
``--base-height`` the command prints that section as it is, and says so on stderr where this rtfit's
conversion of the file's values differs from it (a file written by another version), printing its own.
Bad input (a file that is not ``rtfit.fitted/1``, one without a height-fog method) is one line,
``rtfit: error: …``, exit status 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from .engine_presets import ENGINES, ConvertError, convert_fitted, preset_document
from .fitted import FittedError, load_fitted

__all__ = ["fitted_group"]


def _same(a, b) -> bool:
    """Two JSON values equal up to float64 round-off in their numbers (1e-12 relative)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)
    return a == b


class _InputError(click.ClickException):
    exit_code = 2

    def show(self, file=None) -> None:
        click.echo(f"rtfit: error: {self.format_message()}", err=True, file=file)


@click.group("fitted")
def fitted_group():
    """Fitted-parameter files (rtfit.fitted/1)."""


@fitted_group.command("convert")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--engine", required=True, type=click.Choice(list(ENGINES)), help="The engine's properties.")
@click.option(
    "--base-height",
    type=float,
    default=None,
    metavar="M",
    help="Height (m, rtfit's frame) the engine's fog is anchored at (default: Unreal 0; HDRP and Godot the "
    "lowest height the fit saw, below which their fog is constant).",
)
@click.option("--out", "out", default="-", metavar="FILE", help="Where the document goes ('-': stdout).")
def convert_cmd(file, engine, base_height, out):
    """Convert FILE's height-fog fits into ENGINE's own fog properties (a Nishita-sky fit into its sky, SH
    irradiance fits into its SH layout), with what the engine cannot hold."""
    if base_height is not None and not math.isfinite(base_height):
        raise _InputError(f"--base-height {base_height}: expected a finite height in metres")
    try:
        fitted = load_fitted(file)
        doc = convert_fitted(fitted, engine, base_height, source=str(file))
    except (FittedError, ConvertError) as e:
        raise _InputError(" ".join(str(e).split())) from None
    stored = fitted.engine_presets.get(engine)
    if stored is not None and base_height is None:
        # The file's own presets (written by the same conversion): printed as they are where this rtfit
        # converts the same; a file written by another conversion is said so, and today's is printed.
        kept = preset_document(stored, engine, fitted.provenance.experiment, str(file))
        if _same(kept, doc):
            doc = kept
        else:
            click.echo(
                f"rtfit: note: {file}: its engine_presets.{engine} (rtfit {fitted.provenance.rtfit_version})"
                " differs from this rtfit's conversion of its fitted values; printing this conversion",
                err=True,
            )
    text = json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False)
    if out == "-":
        click.echo(text)
    else:
        Path(out).write_text(text + "\n", encoding="utf-8")
