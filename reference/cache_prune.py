"""What is in a cache folder, and removing entries from it (``rtfit cache info`` and ``rtfit cache prune``).

`scan_cache` finds every `rtfit.reference.pass_entry.PassEntry` (and `ComputedEntry`) folder under a cache
root, in every namespace (`CACHE_NAMESPACES`), with its complete passes, size, last use and whether a live
claim holds it; `prune_plan` picks the entries to remove (oldest last use first, never one in use) and
`remove_entry` removes one whole (renamed out of the layout first, then deleted), `leftover_removals` and
`remove_leftover` finish what an interrupted prune left.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from .pass_entry import ComputedEntry, PassEntry
from .processes import process_alive

CACHE_NAMESPACES = {"images": "", "probes": "", "occlusion": "occlusion", "sky": "sky"}
"""What ``rtfit cache info`` reports, and the namespace folder each lives in (``""``: the root, where
`ReferenceCache` keeps radiance images and irradiance probes, told apart by ``entry.json``)."""


@dataclass(frozen=True)
class CacheEntry:
    """One `PassEntry` folder as found on disk."""

    path: Path
    namespace: str  # images, probes, occlusion, sky (or the folder's name for another namespace)
    passes: int  # complete passes (data and metadata both present)
    bytes: int  # every file of the folder
    last_used: float  # POSIX time: the latest mtime of entry.json and the pass files
    in_use: bool  # holds a live claim (`PassEntry.claim`): a running process is rendering a pass of it


@dataclass
class CacheSummary:
    root: Path
    entries: list[CacheEntry]
    other: dict[str, tuple[int, int]]  # files outside entries (sdf-grids, envmaps): folder -> (files, bytes)


def _is_hex(name: str, length: int) -> bool:
    return len(name) == length and all(c in "0123456789abcdef" for c in name)


def _entry_folders(base: Path):
    """``base/<key[:2]>/<key>/`` folders (a half-removed ``.KEY.removing-*`` folder is not one)."""
    for shard in sorted(base.iterdir()):
        if shard.is_dir() and _is_hex(shard.name, 2):
            for folder in sorted(shard.iterdir()):
                if folder.is_dir() and _is_hex(folder.name, 64) and folder.name.startswith(shard.name):
                    yield folder


def _scan_entry(folder: Path, namespace: str) -> CacheEntry:
    size, last, data, meta, in_use = 0, 0.0, set(), set(), False
    for f in folder.iterdir():
        try:
            st = f.stat()
        except FileNotFoundError:  # removed meanwhile (a temporary file renamed into place)
            continue
        size += st.st_size if f.is_file() else 0
        stem, _, ext = f.name.partition(".")
        if f.name == "entry.json" or (stem.startswith("pass-") and ext in ("json", "exr", "npz")):
            last = max(last, st.st_mtime)
        if f.name == ComputedEntry.RESULT:  # a `ComputedEntry`: one complete item
            last = max(last, st.st_mtime)
            data.add(stem)
            meta.add(stem)
        if stem.startswith("pass-"):
            if ext == "json":
                meta.add(stem)
            elif ext in ("exr", "npz"):
                data.add(stem)
            elif ext == "claim" and not PassEntry.claim_is_stale(f):
                in_use = True
    if namespace == "":
        try:
            quantity = json.loads((folder / "entry.json").read_text()).get("quantity")
        except (OSError, ValueError, AttributeError):
            quantity = None
        namespace = {"radiance": "images", "irradiance": "probes"}.get(quantity, "images/probes")
    return CacheEntry(folder, namespace, len(data & meta), size, last or folder.stat().st_mtime, in_use)


def scan_cache(root) -> CacheSummary:
    """Every entry under the cache ``root`` (all namespaces), and the other files beside them."""
    root = Path(root)
    entries: list[CacheEntry] = []
    other: dict[str, tuple[int, int]] = {}
    if not root.is_dir():
        return CacheSummary(root, entries, other)
    entries += [_scan_entry(f, "") for f in _entry_folders(root)]
    for sub in sorted(root.iterdir()):
        if not sub.is_dir() or _is_hex(sub.name, 2):
            continue
        found = [_scan_entry(f, sub.name) for f in _entry_folders(sub)]
        if found:
            entries += found
            continue
        files = [p for p in sub.rglob("*") if p.is_file()]
        other[sub.name] = (len(files), sum(p.stat().st_size for p in files))
    return CacheSummary(root, entries, other)


def _remove_tree(path: Path) -> None:
    for dirpath, dirnames, filenames in os.walk(path, topdown=False):
        for name in filenames:
            Path(dirpath, name).unlink(missing_ok=True)
        for name in dirnames:
            Path(dirpath, name).rmdir()
    path.rmdir()


def remove_entry(entry: CacheEntry) -> bool:
    """Remove a whole entry, never half of one: the folder is first renamed out of the cache's layout
    (``.KEY.removing-PID``, which no reader looks up), then deleted; if a process claimed one of its
    passes meanwhile, it is put back. Returns whether it was removed."""
    hidden = entry.path.with_name(f".{entry.path.name}.removing-{os.getpid()}")
    try:
        os.rename(entry.path, hidden)
    except FileNotFoundError:
        return False  # removed meanwhile by someone else
    if any(not PassEntry.claim_is_stale(c) for c in hidden.glob("pass-*.claim")):
        try:
            os.rename(hidden, entry.path)
            return False
        except OSError:
            pass  # the claimant recreated the folder already; its claim is in there, not in this one
    _remove_tree(hidden)
    try:
        hidden.parent.rmdir()  # the <key[:2]> shard, if it is now empty
    except OSError:
        pass
    return True


def leftover_removals(root) -> list[Path]:
    """Folders a pruning process left half-removed (``.KEY.removing-PID`` of a dead process)."""
    root = Path(root)
    if not root.is_dir():
        return []
    out = []
    for p in root.glob("**/.*.removing-*"):
        pid = p.name.rpartition("-")[2]
        if p.is_dir() and not (pid.isdigit() and int(pid) != os.getpid() and process_alive(int(pid))):
            out.append(p)
    return out


def remove_leftover(path: Path) -> None:
    """Delete one folder of `leftover_removals` (it is no entry any more: nothing reads it)."""
    _remove_tree(Path(path))


def prune_plan(
    entries: list[CacheEntry],
    *,
    older_than: float | None = None,
    max_size: int | None = None,
    now: float | None = None,
) -> tuple[list[CacheEntry], list[CacheEntry]]:
    """Which entries to remove, oldest last use first: every entry unused for more than ``older_than``
    seconds, then more of the oldest until the rest fit in ``max_size`` bytes. Entries in use (a live
    claim) are never chosen. Returns ``(remove, spared_in_use)``: the entries to remove, and those in
    use that the rule would otherwise have removed."""
    now = time.time() if now is None else now
    ordered = sorted(entries, key=lambda e: (e.last_used, str(e.path)))
    remove: list[CacheEntry] = []
    spared: list[CacheEntry] = []
    for e in ordered:
        if older_than is not None and now - e.last_used > older_than:
            (spared if e.in_use else remove).append(e)
    if max_size is not None:
        gone = {id(e) for e in remove}
        total = sum(e.bytes for e in ordered if id(e) not in gone)
        for e in ordered:
            if total <= max_size:
                break
            if id(e) in gone:
                continue
            if e.in_use:
                if all(s is not e for s in spared):
                    spared.append(e)
                continue
            remove.append(e)
            total -= e.bytes
    return remove, spared
