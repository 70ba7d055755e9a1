"""Atomic writes of whole directories (one experiment's output), plus re-exports of the
file-level atomic writers that live in `rtfit.reference.io`.

A directory is built in a temporary directory beside its final path by :func:`atomic_directory`;
only when the body finishes does it replace the final path. Temporary names start with a dot and
end in ``.tmp`` (under construction) or ``.old`` (being replaced); :func:`is_temporary_name`
recognises them, so directory scans can skip what a killed process left behind.

Beside each temporary directory under construction lies its owner file (`owner_file`: the directory's
name plus ``.owner``, holding host, pid and the pid's start time), removed after the swap. A process
killed with SIGKILL cannot clean up, so :func:`atomic_directory` first removes the temporary directories
of its ``final_path`` that belong to processes that are gone (`remove_stale_temporaries`): owned by a pid
of this host that no longer runs (or now runs another program: its start time differs), or, where that
cannot be known (another host, no owner file), older than a bound. Each removal is reported in one line.
Owner files are not shown by `is_temporary_name`; directory scans look for ``results.json`` in
directories, so they never mistake one for output.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from rtfit.reference.io import (
    NonFiniteJSONError,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    deferred_sync,
    fsync_dir,
    is_temporary_name,
    temp_name,
)
from rtfit.reference.processes import process_alive, process_start

log = logging.getLogger("rtfit.experiments")

__all__ = [
    "NonFiniteJSONError",
    "atomic_directory",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "is_temporary_name",
    "remove_stale_temporaries",
]

OWNER_SUFFIX = ".owner"
"""Beside a temporary directory under construction, ``<its name>.owner`` says who builds it."""
STALE_UNOWNED_SECONDS = 3600.0
"""A temporary directory without an owner file (an ``.old`` one, or one from an older rtfit) is taken
for abandoned once it has not been modified for this long."""
STALE_OWNED_SECONDS = 7 * 24 * 3600.0
"""One whose owner cannot be checked (another host) or seems alive is abandoned only after this long
(a pid reused by an unrelated process with the same start time is the only way to get here)."""

TORN_OWNER_SECONDS = 10.0
"""An owner file that does not parse is taken for its writer's last act once it is this old."""


def _owner_alive(owner: dict) -> bool | None:
    """True/False for an owner of this host, None when it cannot be checked (another host)."""
    if owner.get("host") != socket.gethostname():
        return None
    pid = owner.get("pid")
    if not isinstance(pid, int):
        return False
    return process_alive(pid, owner.get("start"))


def writable_problem(path) -> str | None:
    """Why ``path`` cannot become a directory this process writes (None: it can), checked before anything
    runs: its nearest existing ancestor must be a directory (not a file, not a broken symbolic link), and a
    probe directory is made there and removed at once — ``os.access`` says yes to root on ``/proc`` and on a
    read-only filesystem. Nothing else is created. Shared by ``run``/``sweep`` (``--out``, ``--cache``) and
    the audit (issue 32: ``audit --out /proc/x`` rendered first, then crashed)."""
    path = Path(path)
    probe = path
    try:
        while not probe.exists():
            if probe.is_symlink():
                return f"{probe} is a broken symbolic link"
            if probe.parent == probe:
                break
            probe = probe.parent
    except OSError as e:  # a folder this process may not look into (/proc/1/cwd), a symlink loop
        return f"cannot look into {probe} ({e.strerror or e})"
    if not probe.is_dir():
        return ("is a file" if probe == path else f"is under {probe}, a file") + ", not a directory"
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".rtfit-probe-", dir=probe))
    except OSError as e:
        return f"cannot create anything in {probe} ({e.strerror or e})"
    return None


def owner_file(tmp: Path) -> Path:
    """The owner file of the temporary directory ``tmp`` (beside it, so that the directory stays empty
    for the body and the owner never reaches the output)."""
    return tmp.with_name(tmp.name + OWNER_SUFFIX)


def _write_owner(tmp: Path) -> bool:
    """Create the owner file of ``tmp`` (False: the name is taken, pick another). Written in place, not
    through a temporary file: a process killed inside an atomic write would leave that temporary file
    (``..NAME.<hex>.tmp.owner.<hex>.tmp``) where nothing removes it (CI saw one, stop 51); killed here, it
    leaves at worst a torn owner file without its directory, which `remove_stale_temporaries` removes."""
    owner = {"host": socket.gethostname(), "pid": os.getpid(), "start": process_start(os.getpid())}
    text = json.dumps({**owner, "created": time.time()})
    try:
        fd = os.open(owner_file(tmp), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    return True


def _owner_file_live(path: Path) -> bool:
    """Whether the owner file ``path`` names a live process of this host (one about to create its directory:
    the owner file is written first). Unreadable, foreign-host or dead owners: False (removable)."""
    try:
        owner = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(owner, dict) and _owner_alive(owner) is True


def _stale_reason(path: Path, now: float) -> str | None:
    """Why the temporary directory ``path`` is abandoned, or None if it may still be in use."""
    try:
        st = path.lstat()
        age = now - max(st.st_mtime, st.st_ctime)  # ctime: a rename (an .old directory) counts as a change
    except FileNotFoundError:
        return None
    try:
        owner = json.loads(owner_file(path).read_text())
        if not isinstance(owner, dict):
            raise ValueError("not an object")
    except FileNotFoundError:
        owner = None
    except (OSError, ValueError):  # torn: its writer died between create and write (or is writing now)
        try:
            torn_age = now - owner_file(path).stat().st_mtime
        except OSError:
            return None
        return "its owner file is torn" if torn_age > TORN_OWNER_SECONDS else None
    if owner is None:
        return f"no owner, unchanged for {age:.0f} s" if age > STALE_UNOWNED_SECONDS else None
    alive = _owner_alive(owner)
    who = f"pid {owner.get('pid')} on {owner.get('host')}"
    if alive is False:
        return f"its owner, {who}, is gone"
    if age > STALE_OWNED_SECONDS:
        return f"owner {who} unchecked, unchanged for {age:.0f} s"
    return None


def _legacy_owner_temporary(path: Path, prefix: str, now: float) -> bool:
    """Whether ``path`` is the temporary file of an owner file of ``prefix``'s directories
    (``.<prefix><hex>.tmp.owner.<hex>.tmp``) left by an rtfit that wrote owner files atomically and was killed
    inside the write; nothing writes those now, so one unchanged for `TORN_OWNER_SECONDS` is abandoned."""
    name = path.name
    if not (name.startswith("." + prefix) and is_temporary_name(name)):
        return False
    inner = name[1:].rsplit(".", 2)[0]  # the owner file's name
    if not (inner.endswith(OWNER_SUFFIX) and is_temporary_name(inner.removesuffix(OWNER_SUFFIX))):
        return False
    try:
        return path.is_file() and not path.is_symlink() and now - path.stat().st_mtime > TORN_OWNER_SECONDS
    except OSError:
        return False


def _say(message: str) -> None:
    log.info("%s", message)  # the CLI prints INFO lines as "rtfit: …" (-q silences them)


def remove_stale_temporaries(final_path, log: Callable[[str], None] | None = _say) -> list[Path]:
    """Remove the temporary directories of ``final_path`` (``.NAME.<hex>.tmp|old`` beside it) that their
    builders abandoned (see the module docstring); ``log`` gets one line per removal. Returns them."""
    final = Path(final_path)
    prefix = f".{final.name}."
    removed = []
    try:
        entries = sorted(final.parent.iterdir())
    except OSError:
        return removed
    now = time.time()
    for path in entries:
        if _legacy_owner_temporary(path, prefix, now):
            path.unlink(missing_ok=True)
            if log is not None:
                log(f"removed the abandoned temporary file {path} (an owner file's, from an older rtfit)")
            continue
        if not path.name.startswith(prefix):
            continue
        if path.name.endswith(OWNER_SUFFIX) and is_temporary_name(path.name.removesuffix(OWNER_SUFFIX)):
            if not path.with_name(path.name.removesuffix(OWNER_SUFFIX)).exists() and not _owner_file_live(
                path
            ):
                path.unlink(missing_ok=True)  # its directory was swapped in or removed, or its writer died
            continue
        if not is_temporary_name(path.name) or path.is_symlink() or not path.is_dir():
            continue
        reason = _stale_reason(path, now)
        if reason is None:
            continue
        shutil.rmtree(path, ignore_errors=True)
        if not path.exists():
            owner_file(path).unlink(missing_ok=True)
            removed.append(path)
            if log is not None:
                log(f"removed the abandoned temporary directory {path} ({reason})")
    return removed


@contextmanager
def atomic_directory(final_path, log: Callable[[str], None] | None = _say) -> Iterator[Path]:
    """Build a directory in a temporary directory beside ``final_path``, then swap it in.

    Yields the fresh, empty temporary directory (a :class:`~pathlib.Path`). When the body returns,
    an existing ``final_path`` is renamed aside, the new directory renamed into place, and the old
    one deleted (the two renames leave only a microsecond window without ``final_path``; if the
    second fails, the old directory is put back). When the body raises (KeyboardInterrupt
    included), the temporary directory is deleted and ``final_path`` is left untouched. Temporary
    directories of ``final_path`` left by processes that are gone are removed first, each with one line
    to ``log`` (`remove_stale_temporaries`).

    While the body runs, `owner_file` of the temporary directory names this process.
    """
    final = Path(final_path)
    if final.exists() and not final.is_dir():
        raise NotADirectoryError(f"{final}: exists and is not a directory")
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(final, log)
    while True:
        tmp = temp_name(final, "tmp")
        # The owner file first, then the directory: a process killed between the two leaves an owner file
        # without its directory (removed by the next `remove_stale_temporaries`), never a directory without
        # an owner, which would wait `STALE_UNOWNED_SECONDS` (tests/test_faults.py hit that under load).
        if tmp.exists() or not _write_owner(tmp):
            continue  # (random names: never in practice) another builder's: pick again
        try:
            tmp.mkdir(mode=0o777)
            break
        except FileExistsError:
            continue
    try:
        with deferred_sync(tmp):  # the files' fsyncs: one sync of the file system before the swap
            yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        owner_file(tmp).unlink(missing_ok=True)
        raise
    old = None
    try:
        if final.exists() or final.is_symlink():
            old = temp_name(final, "old")
            os.rename(final, old)
        try:
            os.rename(tmp, final)
        except BaseException:
            if old is not None:
                os.rename(old, final)
                old = None
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        owner_file(tmp).unlink(missing_ok=True)
        raise
    owner_file(tmp).unlink(missing_ok=True)
    fsync_dir(final.parent)
    if old is not None:
        if old.is_symlink() or not old.is_dir():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)
