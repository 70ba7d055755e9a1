"""Atomic writes of whole directories (one experiment's output), plus re-exports of the
file-level atomic writers that live in `rtfit.reference.io`.

A directory is built in a temporary directory beside its final path by :func:`atomic_directory`;
only when the body finishes does it replace the final path. Temporary names start with a dot and
end in ``.tmp`` (under construction) or ``.old`` (being replaced); :func:`is_temporary_name`
recognises them, so directory scans can skip what a killed process left behind.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rtfit.reference.io import (
    NonFiniteJSONError,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    fsync_dir,
    is_temporary_name,
    temp_name,
)

__all__ = [
    "NonFiniteJSONError",
    "atomic_directory",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "is_temporary_name",
]


@contextmanager
def atomic_directory(final_path) -> Iterator[Path]:
    """Build a directory in a temporary directory beside ``final_path``, then swap it in.

    Yields the fresh, empty temporary directory (a :class:`~pathlib.Path`). When the body returns,
    an existing ``final_path`` is renamed aside, the new directory renamed into place, and the old
    one deleted (the two renames leave only a microsecond window without ``final_path``; if the
    second fails, the old directory is put back). When the body raises (KeyboardInterrupt
    included), the temporary directory is deleted and ``final_path`` is left untouched.
    """
    final = Path(final_path)
    if final.exists() and not final.is_dir():
        raise NotADirectoryError(f"{final}: exists and is not a directory")
    final.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = temp_name(final, "tmp")
        try:
            tmp.mkdir(mode=0o777)
            break
        except FileExistsError:
            continue
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
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
        raise
    fsync_dir(final.parent)
    if old is not None:
        if old.is_symlink() or not old.is_dir():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)
