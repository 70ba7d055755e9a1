"""Options several ``rtfit`` commands share (``run``, ``sweep``, ``audit``, ``cache``), written once."""

from __future__ import annotations

from pathlib import Path

import click

from .registry import SPP_MAX

__all__ = [
    "CACHE_HELP",
    "VARIANT_CHOICES",
    "cache_option",
    "out_option",
    "pass_spp_option",
    "spp_option",
    "variant_option",
]

CACHE_HELP = "Reference cache directory (default: $RTFIT_CACHE or ~/.cache/rtfit)."
VARIANT_CHOICES = ("auto", "llvm_ad_rgb", "cuda_ad_rgb")
"""The variants a command offers (Mitsuba's ``scalar_rgb`` renders one sample at a time: not one of them)."""


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


def variant_option(
    help_text: str = "Mitsuba variant for references and the Dr.Jit backend for approximations.",
    default: str = "llvm_ad_rgb",
):
    """``--variant`` (one of `VARIANT_CHOICES`), as the argument ``variant``."""
    return click.option(
        "--variant", default=default, show_default=True, type=click.Choice(VARIANT_CHOICES), help=help_text
    )


def spp_option(help_text: str = "Reference samples per pixel (256)."):
    """``--spp N`` (2 … `registry.SPP_MAX`; default None: the command's own), as the argument ``spp``."""
    return click.option("--spp", type=click.IntRange(min=2, max=SPP_MAX), default=None, help=help_text)


def pass_spp_option(help_text: str = "Samples per cached pass (32)."):
    """``--pass-spp N`` (2 … `registry.SPP_MAX`; default None), as the argument ``pass_spp``."""
    return click.option("--pass-spp", type=click.IntRange(min=2, max=SPP_MAX), default=None, help=help_text)
