"""The ``rtfit list`` command: the registry's families, one line each (``--json``: their methods and
quantities too).

A module of its own so that ``rtfit list`` imports the registry alone (`rtfit.experiments.families`), not
what ``rtfit run`` needs (the runner, the executors, reports and the book): issue 33, start-up under 2 s
on 2 cores.
"""

from __future__ import annotations

import json

import click

from .cli_complete import family_list
from .families import EXPERIMENTS

__all__ = ["list_cmd"]


@click.command("list")
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
