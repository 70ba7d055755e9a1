"""Deterministic smooth vertex normals for the generated library meshes (float64, NumPy).

A PLY mesh without normals and with ``face_normals = false`` makes Mitsuba compute its vertex normals
at load time with a Dr.Jit ``scatter_reduce`` (atomic adds from several threads): the float32 sum then
depends on thread scheduling, so the shading normals, the probe normals taken from them and every cache
key hashed from those normals change from process to process (a cold or warm Dr.Jit kernel cache only
shifts the timing). The generated meshes that are shaded smoothly therefore ship their normals, computed
here once, in float64, in a fixed order, with Mitsuba's weighting (each face's unit normal weighted by
its interior angle at the vertex; Thürmer & Wüthrich 1998), so Mitsuba loads them instead.
The result is deterministic on one machine; across CPUs NumPy's SIMD arccos/norm may differ by ulps (a
component that is 0 in exact arithmetic can come out as ±2e-18), which is why the shipped PLY files, not
a regeneration, are what scenes and cache keys use.
"""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices, faces) -> np.ndarray:
    """Unit angle-weighted vertex normals (V, 3) float64 of a triangle mesh (faces counter-clockwise
    seen from outside). Degenerate faces contribute nothing; a vertex with no contribution gets +z."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    p = v[f]  # (F, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok = length[:, 0] > 0
    n = np.where(ok[:, None], n / np.where(length > 0, length, 1.0), 0.0)
    out = np.zeros_like(v)
    for i in range(3):
        d0 = p[:, (i + 1) % 3] - p[:, i]
        d1 = p[:, (i + 2) % 3] - p[:, i]
        l0 = np.linalg.norm(d0, axis=1)
        l1 = np.linalg.norm(d1, axis=1)
        good = ok & (l0 > 0) & (l1 > 0)
        cos = np.einsum("ij,ij->i", d0, d1) / np.where(good, l0 * l1, 1.0)
        angle = np.where(good, np.arccos(np.clip(cos, -1.0, 1.0)), 0.0)
        np.add.at(out, f[:, i], n * angle[:, None])  # unbuffered, in face order: deterministic
    length = np.linalg.norm(out, axis=1, keepdims=True)
    out = np.where(length > 0, out / np.where(length > 0, length, 1.0), 0.0)
    out[length[:, 0] == 0] = (0.0, 0.0, 1.0)
    return out
