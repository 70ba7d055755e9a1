"""The ``rtfit`` group's command table: each command's module imported only when the command is used.

``rtfit --help`` lists every command with its one-line help; importing the commands' modules for that cost
~1.3 s of CPU (the audit's applicability rules import every family declaration and its study, the runner
Dr.Jit and Mitsuba's reference code), against the 2 s start-up goal of issue 33. `LazyGroup` names each
command by its module and function (`COMMANDS`) and reads the one-line help from the module's source text
(the function's docstring, which click itself turns into the short help: `short_help`), so the listing
imports no command; ``rtfit COMMAND …`` (its run or its ``--help``) imports that command's module alone.
What the entry point itself needs at import (`cli`: the failure classes it turns into exit statuses) is
kept light: ~0.5 s of CPU for ``rtfit --help``, against ~1.8 s before.
tests/test_cli.py checks the listing against click's own short help of every imported command.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
from functools import cache

import click

__all__ = ["COMMANDS", "LazyGroup", "short_help"]

COMMANDS: dict[str, tuple[str, str]] = {
    "list": ("cli_list", "list_cmd"),
    "run": ("cli_run", "run_cmd"),
    "sweep": ("cli_run", "sweep_cmd"),
    "report": ("cli_run", "report_cmd"),
    "export-xml": ("cli_run", "export_xml_cmd"),
    "bench": ("cli_bench", "bench_cmd"),
    "cache": ("cache_cli", "cache_group"),
    "fitted": ("fitted_cli", "fitted_group"),
    "audit": ("audit_cli", "audit"),
    "compare": ("compare_cli", "compare"),
}
"""Command name → (module of `rtfit.experiments`, the click command object's name in it)."""


@cache
def _docstring(module: str, function: str) -> str:
    """The docstring of ``function`` in ``module``'s source, read without importing it (cleaned as
    `inspect.cleandoc` does, as click cleans a command's help); "" where there is none."""
    spec = importlib.util.find_spec(f"{__package__}.{module}")
    if spec is None or spec.origin is None:
        return ""
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read(), spec.origin)
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == function:
            return ast.get_docstring(node, clean=True) or ""
    return ""


def short_help(name: str, limit: int = 45) -> str:
    """Command ``name``'s one-line help as click prints it in a listing ``limit`` characters wide: click's
    own rule (the first sentence of the help, the text before a form feed, cut at ``limit``) applied to its
    docstring, through a stand-in `click.Command` that holds only that text."""
    return click.Command(name, help=_docstring(*COMMANDS[name]) or None).get_short_help_str(limit)


class LazyGroup(click.Group):
    """A click group whose commands (`COMMANDS`) are imported when one is looked up to run or to show its
    own help; its listing (``rtfit --help``) comes from `short_help`. Commands added the usual way
    (`add_command`) are listed and run as in any group."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.commands or cmd_name not in COMMANDS:
            return super().get_command(ctx, cmd_name)
        module, attribute = COMMANDS[cmd_name]
        command = getattr(importlib.import_module(f"{__package__}.{module}"), attribute)
        self.add_command(command, cmd_name)
        return command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The command listing of ``--help`` (click's layout) without importing a command not yet used."""
        names = self.list_commands(ctx)
        if not names:
            return
        limit = formatter.width - 6 - max(len(n) for n in names)
        rows = []
        for name in names:
            command = self.commands.get(name)
            if command is not None:
                if command.hidden:
                    continue
                rows.append((name, command.get_short_help_str(limit)))
            else:
                rows.append((name, short_help(name, limit)))
        with formatter.section("Commands"):
            formatter.write_dl(rows)
