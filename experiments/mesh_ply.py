"""Triangle meshes written as binary little-endian PLY files, for the studies that build their own meshes
(ambient aperture's hole plate and bumps, SDF occlusion's scenes): float32 x, y, z (and nx, ny, nz when
normals are given) and uchar-counted int32 triangle indices."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rtfit.reference.io import atomic_write_bytes

__all__ = ["write_ply"]


def write_ply(path, vertices, faces, normals=None, comment: str | None = None) -> Path:
    """Write the mesh (``vertices`` (V, 3), ``faces`` (F, 3), optional ``normals`` (V, 3) and one header
    ``comment`` line) to ``path`` atomically, its folder made if missing; returns ``path``."""
    v = np.ascontiguousarray(vertices, dtype="<f4")
    props = "property float x\nproperty float y\nproperty float z\n"
    if normals is not None:
        v = np.ascontiguousarray(np.concatenate([v, np.asarray(normals, dtype="<f4")], axis=1))
        props += "property float nx\nproperty float ny\nproperty float nz\n"
    f = np.asarray(faces, dtype="<i4")
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        + ("" if comment is None else f"comment {comment}\n")
        + f"element vertex {len(v)}\n{props}"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = f
    return atomic_write_bytes(Path(path), head + v.tobytes() + rec.tobytes())
