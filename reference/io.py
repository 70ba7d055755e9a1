"""Atomic file writes and EXR I/O (float32, named channels).

Every file rtfit writes goes to a temporary file in the target directory, is flushed and fsynced,
then renamed over the target (``os.replace`` is atomic on POSIX): a reader never sees half a file,
and an interrupted run leaves either the old file or the new one.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def atomic_write_bytes(path, data: bytes) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def _check_finite(obj, where="$"):
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ValueError(f"non-finite number {obj!r} at {where}: refusing to write it to JSON")
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _check_finite(v, f"{where}[{i}]")


def atomic_write_json(path, obj) -> Path:
    """Write JSON atomically; NaN/Inf are an error (they are not JSON and would hide bugs)."""
    _check_finite(obj)
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False, allow_nan=False) + "\n")


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
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".exr", dir=path.parent)
    os.close(fd)
    try:
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, dict(flat)) as f:  # OpenEXR mutates the dict it is given: pass a copy
            f.write(tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def read_exr(path) -> dict[str, np.ndarray]:
    """Read every channel of an EXR as float32 2-D arrays keyed by full channel name (``R``, ``var.G``…)."""
    import OpenEXR

    out: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for name, chan in f.channels().items():
            out[name] = np.asarray(chan.pixels, dtype=np.float32)
    return out


def rgb_group(channels: dict[str, np.ndarray], prefix: str = "") -> np.ndarray:
    """Stack ``prefix.R/G/B`` (or ``R/G/B``) channels into an (H, W, 3) array."""
    p = f"{prefix}." if prefix else ""
    return np.stack([channels[f"{p}{c}"] for c in "RGB"], axis=-1)
