"""``rtfit cache info|prune``: what the reference cache holds, and removing what is no longer used.

    rtfit cache info  [--cache DIR]
    rtfit cache prune [--cache DIR] [--older-than DURATION] [--max-size SIZE] [--dry-run]

The cache (``$RTFIT_CACHE``, else ``~/.cache/rtfit``) is made of `rtfit.reference.cache.PassEntry`
folders: radiance images and irradiance probes at its root, ``occlusion/`` and ``sky/`` beside them.
An entry's *last use* is the latest modification time of its ``entry.json`` and pass files: the last
time a run added passes to it (reading an entry changes no time stamp, and access times are not kept
on most mounts). ``prune`` removes whole entries, oldest last use first: those unused for longer than
``--older-than``, then more until the cache fits in ``--max-size``. An entry holding a live claim (a
running process is rendering one of its passes) is never removed; a removed entry that a later run
needs is rendered again. Files outside entries (``sdf-grids/``, ``envmaps/``) are listed by ``info``
and left alone.

DURATION: a number and a unit ``s m h d w`` (``30d``, ``12h``, ``1.5w``). SIZE: a number of bytes, or
with a unit ``K M G T`` (powers of 1024; ``2G``, ``500M``, ``1.5GiB``).
"""

from __future__ import annotations

import datetime
import os
import re
import time
from pathlib import Path

import click

from rtfit.reference import default_cache_dir
from rtfit.reference.cache import (
    CacheEntry,
    leftover_removals,
    prune_plan,
    remove_entry,
    remove_leftover,
    scan_cache,
)

from .cli_options import cache_option

DURATION_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}
SIZE_UNITS = {"": 1, "k": 1024, "m": 1024**2, "g": 1024**3, "t": 1024**4}
NAMESPACE_ORDER = ("images", "probes", "images/probes", "occlusion", "sky")


def parse_duration(text: str) -> float:
    """``30d`` → seconds; a ValueError naming the expected form otherwise."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([smhdw])\s*", text or "", re.IGNORECASE)
    if not m:
        raise ValueError(f"{text!r}: expected a duration like 30d, 12h, 90m (units s m h d w)")
    return float(m.group(1)) * DURATION_UNITS[m.group(2).lower()]


def parse_size(text: str) -> int:
    """``2G`` → bytes (powers of 1024); a ValueError naming the expected form otherwise."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([kmgt]?)(?:i?b)?\s*", text or "", re.IGNORECASE)
    if not m:
        raise ValueError(f"{text!r}: expected a size like 2G, 500M or a number of bytes (units K M G T)")
    return int(float(m.group(1)) * SIZE_UNITS[m.group(2).lower()])


class _Parsed(click.ParamType):
    def __init__(self, name: str, parse):
        self.name, self.parse = name, parse

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value
        try:
            return self.parse(value)
        except ValueError as e:
            self.fail(str(e), param, ctx)


DURATION = _Parsed("duration", parse_duration)
SIZE = _Parsed("size", parse_size)


def human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(n) < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def when(t: float) -> str:
    return datetime.datetime.fromtimestamp(t, datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")


def _namespace_order(name: str):
    return (0, NAMESPACE_ORDER.index(name), "") if name in NAMESPACE_ORDER else (1, 0, name)


def _describe(e: CacheEntry, root: Path) -> str:
    rel = e.path.relative_to(root).as_posix()
    short = rel[: rel.rindex("/") + 13]  # the key's first 12 hex digits
    return (
        f"{short}… ({e.namespace}, {e.passes} passes, {human_bytes(e.bytes)}, last used {when(e.last_used)})"
    )


CACHE_OPTION = cache_option()


def _cache_root(cache) -> Path:
    """The cache directory to read: ``--cache`` or the default, refused in one line (exit 2) when it is a
    file, a broken or looping symbolic link, or a folder this process may not read (``/proc/1/cwd``)."""
    root = Path(cache or default_cache_dir())
    try:
        if root.is_symlink() and not root.exists():
            raise click.ClickException(f"--cache {root}: a broken symbolic link (or a loop)")
        if root.exists() and not root.is_dir():
            raise click.ClickException(f"--cache {root}: a file, not a directory")
        if root.is_dir():
            os.listdir(root)
    except OSError as e:
        raise click.ClickException(f"--cache {root}: cannot read it ({e.strerror or e})") from None
    return root


@click.group("cache")
def cache_group():
    """Inspect the reference cache (info) or remove entries no longer used (prune)."""


@cache_group.command("info")
@CACHE_OPTION
def info_cmd(cache):
    """Entries, passes and bytes per namespace (images, probes, occlusion, sky), oldest and newest use."""
    root = _cache_root(cache)
    summary = scan_cache(root)
    entries = summary.entries
    total = sum(e.bytes for e in entries)
    if not entries:
        click.echo(f"rtfit cache {root}: no entries")
    else:
        click.echo(
            f"rtfit cache {root}: {len(entries)} entries, {sum(e.passes for e in entries)} passes, "
            f"{human_bytes(total)}; last used {when(min(e.last_used for e in entries))} … "
            f"{when(max(e.last_used for e in entries))}"
        )
        names = sorted({e.namespace for e in entries}, key=_namespace_order)
        rows = []
        for n in names:
            group = [e for e in entries if e.namespace == n]
            rows.append(
                [
                    n,
                    str(len(group)),
                    str(sum(e.passes for e in group)),
                    human_bytes(sum(e.bytes for e in group)),
                    when(min(e.last_used for e in group)),
                    when(max(e.last_used for e in group)),
                ]
            )
        header = ["namespace", "entries", "passes", "size", "oldest use", "newest use"]
        widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
        for r in [header, *rows]:
            cells = [
                c.rjust(w) if 0 < i < 4 else c.ljust(w)
                for i, (c, w) in enumerate(zip(r, widths, strict=True))
            ]
            click.echo("  ".join(cells).rstrip())
        in_use = [e for e in entries if e.in_use]
        if in_use:
            click.echo(f"{len(in_use)} entries in use now (a running process is rendering passes)")
    for name, (files, size) in summary.other.items():
        click.echo(f"{name}/: {files} files, {human_bytes(size)} (not entries; prune leaves them)")


@cache_group.command("prune")
@CACHE_OPTION
@click.option(
    "--older-than", type=DURATION, default=None, help="Remove entries unused for longer (30d, 12h)."
)
@click.option(
    "--max-size", type=SIZE, default=None, help="Then remove the oldest until the rest fit (2G, 500M)."
)
@click.option("--dry-run", is_flag=True, help="Print what would be removed; remove nothing.")
def prune_cmd(cache, older_than, max_size, dry_run):
    """Remove whole entries, oldest last use first (never one a running process is rendering into)."""
    if older_than is None and max_size is None:
        raise click.UsageError("say what to prune: --older-than DURATION and/or --max-size SIZE")
    root = _cache_root(cache)
    summary = scan_cache(root)
    remove, spared = prune_plan(summary.entries, older_than=older_than, max_size=max_size, now=time.time())
    verb = "would remove" if dry_run else "removed"
    freed = 0
    removed = 0
    for e in remove:
        if dry_run or remove_entry(e):
            click.echo(f"{verb} {_describe(e, root)}")
            freed += e.bytes
            removed += 1
        else:
            click.echo(f"kept {_describe(e, root)}: claimed or removed by another process meanwhile")
    for e in spared:
        click.echo(f"kept {_describe(e, root)}: in use by a running process")
    leftovers = leftover_removals(root)
    for p in leftovers:
        if not dry_run:
            remove_leftover(p)
        click.echo(f"{verb} {p.relative_to(root).as_posix()} (left half-removed by an interrupted prune)")
    left = sum(e.bytes for e in summary.entries) - freed
    click.echo(
        f"rtfit cache {root}: {verb} {removed} of {len(summary.entries)} entries ({human_bytes(freed)}); "
        f"{human_bytes(left)} left"
    )
