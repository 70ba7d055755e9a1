"""Options several ``rtfit`` commands share (``run``, ``sweep``, ``audit``, ``cache``), written once."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["CACHE_HELP", "cache_option", "out_option"]

CACHE_HELP = "Reference cache directory (default: $RTFIT_CACHE or ~/.cache/rtfit)."


def out_option(help_text: str = "Output directory."):
    """``--out DIRECTORY`` (default ``out``), as the argument ``out``."""
    return click.option(
        "--out",
        "out",
        type=click.Path(file_okay=False, path_type=Path),
        default=Path("out"),
        show_default=True,
        help=help_text,
    )


def cache_option(help_text: str = CACHE_HELP):
    """``--cache DIRECTORY`` (default None: $RTFIT_CACHE or ~/.cache/rtfit), as the argument ``cache``."""
    return click.option(
        "--cache",
        "cache",
        type=click.Path(file_okay=False, path_type=Path),
        default=None,
        help=help_text,
    )
