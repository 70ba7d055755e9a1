"""Mesh files checked before anything loads, copies or echoes them (issue 32).

A scene names its meshes by path (a TOML ``[[shapes]] type = "mesh"``, a Mitsuba XML ``<shape type="ply">``);
Mitsuba's loaders then either fail with messages that quote the file's bytes (a UTF-8 decode error naming no
file) or load what they can. `mesh_problem(path, limit)` finds, in one reason that names no content:

* **PLY**: a header that is not ``ply`` … ``end_header`` in the first 64 KiB, not ASCII, without a known
  ``format`` (``ascii``, ``binary_little_endian``, ``binary_big_endian``) or an ``element vertex`` count
  below 2³¹; binary vertex data shorter than the declared vertices; a vertex coordinate that is NaN, ±Inf
  or beyond ±``limit`` (scene units; the TOML scenes' `MAX_LENGTH`) — checked where the vertex element comes
  first and has only scalar properties (every PLY rtfit and Mitsuba write);
* **OBJ**: not text (NUL or other control bytes; neither UTF-8 nor 95 % ASCII in the first 64 KiB), or a
  ``v`` line whose coordinates are not finite numbers within ±``limit``.

A symlink is followed (its target must itself be such a mesh: ``/etc/passwd`` named ``x.ply`` is "not a PLY
file", and nothing of it is quoted).
"""

from __future__ import annotations

import math
import os
import re

import numpy as np

__all__ = ["mesh_problem"]

_HEADER_MAX = 1 << 16
MAX_ELEMENTS = 1 << 31  # a PLY element count beyond it cannot be loaded (Mitsuba indexes with 32 bits)
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_PLY_TYPES = {
    **dict.fromkeys(("char", "int8"), "i1"),
    **dict.fromkeys(("uchar", "uint8"), "u1"),
    **dict.fromkeys(("short", "int16"), "i2"),
    **dict.fromkeys(("ushort", "uint16"), "u2"),
    **dict.fromkeys(("int", "int32"), "i4"),
    **dict.fromkeys(("uint", "uint32"), "u4"),
    **dict.fromkeys(("float", "float32"), "f4"),
    **dict.fromkeys(("double", "float64"), "f8"),
}
_POSITION = ("x", "y", "z")
_TEXT_BYTES = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0C, 0x0D}


def _coordinates_problem(xyz: np.ndarray, limit: float) -> str | None:
    """Whether the (n, 3) vertex positions are finite and within ±limit."""
    if xyz.size == 0:
        return None
    finite = np.isfinite(xyz)
    if not finite.all():
        k = int(np.argmin(finite.all(axis=1)))
        return f"vertex {k} is not finite (NaN or Inf)"
    far = np.abs(xyz) > limit
    if far.any():
        k = int(np.argmax(far.any(axis=1)))
        return f"vertex {k} is beyond ±{limit:g} (rtfit's limit for positions)"
    return None


def _ply_header(head: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int] | str:
    """(format, [(element, count, [(type, name)…])…], header length) or the problem."""
    end = re.search(rb"end_header\r?\n", head)
    if not head.startswith((b"ply\n", b"ply\r\n")) or end is None:
        return "not a PLY file (no 'ply' … 'end_header' header in its first 64 KiB)"
    try:
        lines = head[: end.start()].decode("ascii").splitlines()
    except UnicodeDecodeError:
        return "not a PLY file (its header is not ASCII text)"
    fmt = next((ln.split() for ln in lines if ln.startswith("format")), None)
    if fmt is None or len(fmt) < 2 or fmt[1] not in _PLY_FORMATS:
        return "its PLY header has no known 'format' line (ascii, binary_little_endian, binary_big_endian)"
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for ln in lines:
        parts = ln.split()
        if parts[:1] == ["element"] and len(parts) == 3:
            if not parts[2].isdigit() or int(parts[2]) >= MAX_ELEMENTS:
                return f"its PLY header's element count {parts[2][:20]!r} is not a count below 2^31"
            elements.append((parts[1], int(parts[2]), []))
        elif parts[:1] == ["property"] and elements:
            kind = "list" if parts[1:2] == ["list"] else parts[1] if len(parts) == 3 else "?"
            elements[-1][2].append((kind, parts[-1]))
    if not any(e[0] == "vertex" for e in elements):
        return "its PLY header declares no 'element vertex'"
    return fmt[1], elements, end.end()


def _ply_problem(path: str, limit: float) -> str | None:
    with open(path, "rb") as f:
        head = f.read(_HEADER_MAX)
    header = _ply_header(head)
    if isinstance(header, str):
        return header
    fmt, elements, start = header
    name, n, props = elements[0]
    if name != "vertex" or any(t not in _PLY_TYPES for t, _ in props):
        return None  # (positions not checked: an element or a list before them; Mitsuba reads the rest)
    names = [p for _, p in props]
    if not all(c in names for c in _POSITION):
        return "its PLY vertices have no x, y, z properties"
    if fmt == "ascii":
        with open(path, "rb") as f:
            f.seek(start)
            rows = [f.readline() for _ in range(n)]
        columns = [names.index(c) for c in _POSITION]
        try:
            xyz = np.array([[float(r.split()[j]) for j in columns] for r in rows], dtype=np.float64)
        except (ValueError, IndexError):
            return f"its {n} ASCII vertices do not read as numbers (truncated or not a PLY mesh)"
        return _coordinates_problem(xyz.reshape(-1, 3), limit)
    dtype = np.dtype([(p, _PLY_FORMATS[fmt] + _PLY_TYPES[t]) for t, p in props])
    if n * dtype.itemsize > os.path.getsize(path) - start:
        return f"the file is shorter than its {n} declared vertices (truncated or not a PLY mesh)"
    with open(path, "rb") as f:
        f.seek(start)
        data = np.frombuffer(f.read(n * dtype.itemsize), dtype=dtype, count=n)
    xyz = np.stack([data[c].astype(np.float64) for c in _POSITION], axis=1)
    return _coordinates_problem(xyz, limit)


def _obj_problem(path: str, limit: float) -> str | None:
    with open(path, "rb") as f:
        data = f.read()
    head = data[:_HEADER_MAX]
    if any(b < 0x20 and b not in _TEXT_BYTES for b in head):
        return "not an OBJ file (binary data: an OBJ mesh is text)"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as e:
        ascii_share = sum(b in _TEXT_BYTES for b in head) / len(head)
        if e.start < len(head) - 4 and ascii_share < 0.95:  # (not a character cut at the block's end)
            return "not an OBJ file (not text)"
    for k, line in enumerate(ln for ln in data.splitlines() if ln.startswith(b"v ")):
        parts = line.split()[1:4]
        try:
            xyz = [float(p) for p in parts]
        except ValueError:
            return f"its vertex {k} does not read as numbers"
        if len(xyz) < 3:
            return f"its vertex {k} has fewer than 3 coordinates"
        if not all(math.isfinite(v) for v in xyz):
            return f"vertex {k} is not finite (NaN or Inf)"
        if any(abs(v) > limit for v in xyz):
            return f"vertex {k} is beyond ±{limit:g} (rtfit's limit for positions)"
    return None


def mesh_problem(path: str, limit: float) -> str | None:
    """What makes the mesh file ``path`` unreadable as its suffix's format (module docstring), as one reason
    naming no file content; None when nothing is found or the suffix is not ``.ply``/``.obj``. ``limit``:
    the largest |coordinate| accepted (scene units)."""
    check = {".ply": _ply_problem, ".obj": _obj_problem}.get(os.path.splitext(path)[1].lower())
    if check is None:
        return None
    if not os.path.isfile(path):
        return "no such file" if not os.path.isdir(path) else "a directory, not a mesh file"
    try:
        return check(path, limit)
    except OSError as e:
        return f"cannot read ({e.strerror or e})"
