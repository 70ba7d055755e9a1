"""The triangles of a loaded Mitsuba scene, in world space, for rtfit's own geometry needs (a distance field).

Issue 15 §1: geometry comes from the loaded Mitsuba shapes, not from a file reader of rtfit's own, so every
mesh format Mitsuba loads (PLY ASCII/binary, OBJ, serialized, ``cube``, ``rectangle``) is read the same way:

* a mesh (``Shape.is_mesh()``): ``vertex_positions_buffer()`` and ``faces_buffer()``, which Mitsuba has
  already transformed by the shape's ``to_world``;
* the analytic shapes have no buffers and are tessellated here from their ``to_world`` (`mi.traverse`):
  ``sphere`` (unit sphere at the origin: an icosphere, 4 subdivisions, 5,120 triangles, chord error
  ≤ 0.12 % of the radius), ``disk`` (unit disk in z = 0: a 64-gon fan, area error 0.16 %), ``cylinder``
  (radius 1, z ∈ [0, 1], open ends as Mitsuba's: 64 segments).

A shape of any other kind (``sdfgrid``, curves) raises `AuditError` naming it: its distance field would be
silently missing otherwise.
"""

from __future__ import annotations

import math

import numpy as np

from .audit_family import AuditError
from .sdf_occlusion_scenes import icosphere

__all__ = ["scene_triangles"]

_SEGMENTS = 64
_SPHERE_SUBDIVISIONS = 4


def _disk(segments: int = _SEGMENTS):
    a = 2.0 * math.pi * np.arange(segments) / segments
    v = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([np.cos(a), np.sin(a), np.zeros(segments)], 1)])
    i = np.arange(segments)
    f = np.stack([np.zeros(segments, np.int64), 1 + i, 1 + (i + 1) % segments], 1)
    return v, f


def _cylinder(segments: int = _SEGMENTS):
    a = 2.0 * math.pi * np.arange(segments) / segments
    ring = np.stack([np.cos(a), np.sin(a)], 1)
    v = np.concatenate([np.c_[ring, np.zeros(segments)], np.c_[ring, np.ones(segments)]])
    i = np.arange(segments)
    j = (i + 1) % segments
    f = np.concatenate([np.stack([i, j, segments + j], 1), np.stack([i, segments + j, segments + i], 1)])
    return v, f


def _unit_shape(kind: str):
    if kind == "sphere":
        v, f = icosphere((0.0, 0.0, 0.0), 1.0, _SPHERE_SUBDIVISIONS)
        return np.asarray(v, np.float64), np.asarray(f, np.int64)
    if kind == "disk":
        return _disk()
    if kind == "cylinder":
        return _cylinder()
    return None


def _kind(shape) -> str:
    """Mitsuba's class name of the shape in lower case (``Sphere`` → ``sphere``)."""
    return str(shape.class_name()).lower()


def scene_triangles(mi, mi_scene) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(vertices (V, 3) float64, faces (F, 3) int64, one line per shape saying how it was read) of every
    shape of ``mi_scene`` (module docstring), emitters' shapes included (they occlude too)."""
    vs, fs, lines = [], [], []
    offset = 0
    for shape in mi_scene.shapes():
        if shape.is_mesh():
            v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
            f = np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3)
            how = f"{shape.id() or 'mesh'}: {len(f)} triangles from Mitsuba's buffers"
        else:
            kind = _kind(shape)
            unit = _unit_shape(kind)
            if unit is None:
                raise AuditError(
                    f"shape {shape.id() or kind!r} ({kind}): the audit's distance field reads meshes, "
                    "spheres, disks and cylinders only"
                )
            u, f = unit
            m = np.asarray(mi.traverse(shape)["to_world"].matrix, np.float64).reshape(4, 4)
            v = u @ m[:3, :3].T + m[:3, 3]
            how = f"{shape.id() or kind}: {kind} tessellated ({len(f)} triangles) from its to_world"
        if not (np.all(np.isfinite(v)) and len(f)):
            continue
        vs.append(v)
        fs.append(f + offset)
        offset += len(v)
        lines.append(how)
    if not vs:
        raise AuditError("the scene has no shape to build a distance field from")
    return np.concatenate(vs), np.concatenate(fs), lines
