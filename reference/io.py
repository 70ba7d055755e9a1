"""Atomic file writes (text, bytes, JSON) and EXR I/O (float32, named channels).

A file is written to a temporary file in the target's own directory, flushed and fsynced, then
renamed over the target with ``os.replace`` (atomic on POSIX): a reader sees either the old file
or the complete new one, never half of one, and an interrupted write leaves the old file intact.

Whole directories (one experiment's output) are swapped in by
``rtfit.experiments.atomic.atomic_directory``, which uses the same temporary names.

Inside a `deferred_sync` block (an experiment's or audit's output being built in its temporary directory,
`rtfit.experiments.atomic.atomic_directory`), files written under the block's directory skip their own
fsyncs, and one ``syncfs`` of the directory's file system at the end of the block makes them all durable
before the directory is swapped in (issue 33, session 20: two fsyncs a file cost 7–10 ms on this machine's
ext4, and the quick suite writes ~1,700 files, the Cornell-box audit ~130).

Temporary names start with a dot and end in ``.tmp`` (files, directories under construction) or
``.old`` (a directory being replaced); :func:`is_temporary_name` recognises them, so directory
scans can skip what a killed process left behind.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import json
import math
import os
import re
import secrets
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np

__all__ = [
    "NonFiniteJSONError",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "deferred_sync",
    "fsync_dir",
    "held_output",
    "is_temporary_name",
    "read_exr",
    "rgb_group",
    "temp_name",
    "write_exr",
]

_TEMP_NAME = re.compile(r"^\..+\.[0-9a-f]{12}\.(tmp|old)$")


class NonFiniteJSONError(ValueError):
    """A NaN or ±Infinity was about to be written to JSON (not valid JSON; it would hide a bug)."""


def is_temporary_name(name: str) -> bool:
    """True for names this module gives its temporary files and directories."""
    return bool(_TEMP_NAME.match(name))


def temp_name(final: Path, kind: str) -> Path:
    """A fresh temporary name beside ``final`` (``.NAME.<12 hex>.KIND``, ``kind`` ``tmp`` or ``old``),
    which :func:`is_temporary_name` recognises."""
    return final.parent / f".{final.name}.{secrets.token_hex(6)}.{kind}"


def fsync_dir(directory: Path) -> None:
    """Make a rename durable (best effort: some file systems refuse fsync on directories)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_deferred_roots: list[str] = []
"""The directories of the `deferred_sync` blocks now open (absolute paths, with a trailing separator)."""
_deferred_lock = threading.Lock()


def _sync_deferred(path: Path) -> bool:
    """Whether ``path`` lies inside an open `deferred_sync` block's directory (its fsyncs wait for the block's
    end)."""
    if not _deferred_roots:
        return False
    where = os.path.abspath(path)
    with _deferred_lock:
        return any(where.startswith(root) for root in _deferred_roots)


def _sync_file_system(directory: Path) -> None:
    """Make every file written under ``directory`` durable: Linux's ``syncfs`` of its file system (one
    journal commit for all of them), else an fsync of each file and directory under it (what each write
    would have done)."""
    try:
        syncfs = getattr(ctypes.CDLL(None, use_errno=True), "syncfs", None)
        fd = os.open(directory, os.O_RDONLY)
    except (OSError, AttributeError):
        syncfs = fd = None
    if fd is not None:
        try:
            if syncfs is not None and syncfs(fd) == 0:
                return
        finally:
            os.close(fd)
    for parent, _, files in os.walk(directory):
        for name in files:
            try:
                with open(os.path.join(parent, name), "rb") as f:
                    os.fsync(f.fileno())
            except OSError:
                pass
        fsync_dir(Path(parent))


@contextlib.contextmanager
def deferred_sync(directory) -> Iterator[Path]:
    """Within the block, the files written by this module under ``directory`` (a temporary directory that
    no reader sees until it is swapped in) skip their own fsyncs; when the block returns normally, one
    sync of the file system makes them durable together (`_sync_file_system`) before the caller renames
    the directory into place. Where the block raises, nothing is synced (the caller removes the
    directory). A block inside another's directory leaves the sync to the outer one. Each file is still
    written to a temporary name and renamed: readers inside the process never see half a file."""
    root = os.path.join(os.path.abspath(directory), "")
    with _deferred_lock:
        nested = any(root.startswith(r) for r in _deferred_roots)
        _deferred_roots.append(root)
    try:
        yield Path(directory)
    finally:
        with _deferred_lock:
            _deferred_roots.remove(root)
    if not nested:
        _sync_file_system(Path(directory))


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (parent directories are created). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    deferred = _sync_deferred(path)
    while True:
        tmp = temp_name(path, "tmp")
        try:
            # 0o666 & ~umask, like open(): a report must stay readable by others (mkstemp gives 0600).
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            break
        except FileExistsError:
            continue
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            if not deferred:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    if not deferred:
        fsync_dir(path.parent)
    return path


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` as UTF-8 to ``path`` atomically. Returns the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _jsonable(o):
    """``json.dumps`` default hook: NumPy scalars and arrays become Python numbers and lists."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"object of type {type(o).__name__} is not JSON serialisable")


def _find_non_finite(obj, where: str = "$") -> tuple[str, float] | None:
    if isinstance(obj, float):
        return None if math.isfinite(obj) else (where, obj)
    if isinstance(obj, dict):
        for k, v in obj.items():
            hit = _find_non_finite(v, f"{where}.{k}")
            if hit:
                return hit
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            hit = _find_non_finite(v, f"{where}[{i}]")
            if hit:
                return hit
    elif hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return _find_non_finite(obj.tolist(), where)
    return None


def atomic_write_json(path, obj) -> Path:
    """Write ``obj`` as indented UTF-8 JSON to ``path`` atomically. Returns the path.

    NaN and ±Infinity are refused (``allow_nan=False``): :class:`NonFiniteJSONError` names the file
    and the key path of the first offending value, and nothing is written. NumPy scalars and arrays
    are converted to Python numbers and lists.
    """
    path = Path(path)
    try:
        text = json.dumps(obj, indent=2, ensure_ascii=False, allow_nan=False, default=_jsonable)
    except ValueError as e:
        hit = _find_non_finite(obj)
        if hit is None:
            raise ValueError(f"{path}: cannot write JSON: {e}") from None
        where, value = hit
        raise NonFiniteJSONError(
            f"{path}: {where} is {value!r}; NaN and infinities are not valid JSON results "
            "(nothing was written)"
        ) from None
    except TypeError as e:
        raise TypeError(f"{path}: cannot write JSON: {e}") from None
    return atomic_write_text(path, text + "\n")


def write_exr(path, channels: dict[str, np.ndarray]) -> Path:
    """Write 2-D float arrays as named float32 EXR channels (ZIP), atomically.

    A (H, W, 3) array under key ``"RGB"`` (or any key) is written as ``key.R, key.G, key.B``
    (plain ``R, G, B`` for key ``"RGB"``).
    """
    import OpenEXR

    flat: dict[str, np.ndarray] = {}
    for name, arr in channels.items():
        a = np.asarray(arr, dtype=np.float32)
        if a.ndim == 3:
            if a.shape[2] != 3:
                raise ValueError(f"channel group {name!r} must have 3 components (got {a.shape[2]})")
            prefix = "" if name == "RGB" else f"{name}."
            for c, comp in enumerate("RGB"):
                flat[f"{prefix}{comp}"] = np.ascontiguousarray(a[..., c])
        elif a.ndim == 2:
            flat[name] = np.ascontiguousarray(a)
        else:
            raise ValueError(f"channel {name!r} must be 2-D or (H, W, 3) (got shape {a.shape})")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    deferred = _sync_deferred(path)
    tmp = temp_name(path, "tmp")
    try:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, dict(flat)) as f:  # OpenEXR mutates the dict it is given: pass a copy
            f.write(str(tmp))
        if not deferred:
            with open(tmp, "rb") as f:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if not deferred:
        fsync_dir(path.parent)
    return path


def read_exr(path) -> dict[str, np.ndarray]:
    """Read every channel of an EXR as float32 2-D arrays keyed by full channel name (``R``, ``var.G``…).

    OpenEXR prints its own lines on a corrupt file before raising (``…exr: (EXR_ERR_INVALID_ARGUMENT)
    Invalid packed size of 0`` on stderr, ``Warning: Exception raised reading pixel data…`` on stdout):
    while it reads, file descriptors 1 and 2 go to temporary files, and what was written there is shown
    only when the read succeeds; a failed read is the exception alone, which the caller says in one line
    of its own (issue 32: a corrupt cached pass printed raw OpenEXR lines)."""
    import OpenEXR

    out: dict[str, np.ndarray] = {}
    with held_output() as held:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            for name, chan in f.channels().items():
                out[name] = np.asarray(chan.pixels, dtype=np.float32)
        held.ok = True
    return out


class _Held:
    ok = False


_HOLDING = threading.Lock()  # one holder of the process's descriptors 1 and 2 at a time


@contextlib.contextmanager
def held_output():
    """File descriptors 1 and 2 (and Python's ``sys.stdout``/``sys.stderr``) into temporary files for the
    block; afterwards their text is written back, all of it if the block set ``.ok`` on what it yields,
    else only lines that start with ``rtfit`` (another thread's log lines; what a failing C/C++ library
    printed is dropped, its exception being the caller's one line)."""
    with _HOLDING:
        yield from _holding()


def _holding():

    held = _Held()
    _c_flush()
    saved = []
    for fd, name in ((1, "stdout"), (2, "stderr")):
        stream = getattr(sys, name)
        if stream is not None:
            stream.flush()
        tmp = tempfile.TemporaryFile()
        saved.append((fd, name, stream, os.dup(fd), tmp))
        os.dup2(tmp.fileno(), fd)
        setattr(sys, name, io.StringIO())  # (C++ bindings may print through Python's sys.stdout)
    try:
        yield held
    finally:
        _c_flush()  # C/C++ stdio buffers (std::cout off a terminal is fully buffered)
        for fd, name, stream, copy, tmp in saved:
            python_text = getattr(sys, name).getvalue().encode()
            setattr(sys, name, stream)
            os.dup2(copy, fd)
            os.close(copy)
            tmp.seek(0)
            text = tmp.read() + python_text
            tmp.close()
            if not held.ok:
                text = b"".join(ln for ln in text.splitlines(keepends=True) if ln.startswith(b"rtfit"))
            if text and stream is not None:
                stream.write(text.decode(errors="replace"))
                stream.flush()


def _c_flush() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to reach: nothing buffered there to flush
        pass


def rgb_group(channels: dict[str, np.ndarray], prefix: str = "") -> np.ndarray:
    """Stack ``prefix.R/G/B`` (or ``R/G/B``) channels into an (H, W, 3) array."""
    p = f"{prefix}." if prefix else ""
    return np.stack([channels[f"{p}{c}"] for c in "RGB"], axis=-1)
