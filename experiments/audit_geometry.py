"""The triangles of a loaded Mitsuba scene, in world space, for rtfit's own geometry needs (a distance field).

Issue 15 §1: geometry comes from the loaded Mitsuba shapes, not from a file reader of rtfit's own, so every
mesh format Mitsuba loads (PLY ASCII/binary, OBJ, serialized, ``cube``, ``rectangle``) is read the same way:

* a mesh (``Shape.is_mesh()``): ``vertex_positions_buffer()`` and ``faces_buffer()``, which Mitsuba has
  already transformed by the shape's ``to_world``;
* the analytic shapes have no buffers and are tessellated here from their ``to_world`` (`mi.traverse`):
  ``sphere`` (unit sphere at the origin: an icosphere, 4 subdivisions, 5,120 triangles, chord error
  ≤ 0.12 % of the radius), ``disk`` (unit disk in z = 0: a 64-gon fan, area error 0.16 %), ``cylinder``
  (radius 1, z ∈ [0, 1], open ends as Mitsuba's: 64 segments).

An ``instance`` of a ``shapegroup`` is flattened: the group's members, read as above, carried by the
instance's ``to_world`` (issue 31: instances are common in real scenes). A shape of any other kind
(``sdfgrid``, curves) raises `AuditError` naming it: its distance field would be silently missing otherwise.

The AO radius every geometry family shares (`ao_radius`: ``--ao-distance``, else the scene's default) lives
here too, so that no family module imports another's (the visible points: `rtfit.reference.gbuffer_points`),
and so do the reflective shape an applicability names (`reflective_shape`: the families of mirror and glass
shapes), the camera rays of the visible pixels (`camera_rays`) and Mitsuba rays from NumPy (`rays`).
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.reference.device_arrays import device_vectors
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS, reflective_shapes, shape_pixels

from .audit import Applicability, AuditError, default_ao_distance
from .audit_setup import AuditSetup
from .sdf_occlusion_scenes import icosphere
from .shipped import ShippedScene, Sizes

__all__ = [
    "ao_radius",
    "camera_rays",
    "rays",
    "reflective_shape",
    "scene_triangles",
    "sdf_scene",
    "shape_view",
    "visible_subset",
]

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
    if kind == "rectangle":  # Mitsuba's unit rectangle: [−1, 1]² at z = 0, its normal +z
        v = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
        return v, np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return None


def _kind(shape) -> str:
    """Mitsuba's class name of the shape in lower case (``Sphere`` → ``sphere``)."""
    return str(shape.class_name()).lower()


def _shape_triangles(mi, shape) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(vertices, faces, how) of one mesh or analytic shape in its own world (a shape group's space for a
    group's member), or None for a kind this module cannot read."""
    if shape.is_mesh():
        v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
        f = np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3)
        return v, f, f"{shape.id() or 'mesh'}: {len(f)} triangles from Mitsuba's buffers"
    kind = _kind(shape)
    unit = _unit_shape(kind)
    if unit is None:
        return None
    u, f = unit
    m = np.asarray(mi.traverse(shape)["to_world"].matrix, np.float64).reshape(4, 4)
    v = u @ m[:3, :3].T + m[:3, 3]
    return v, f, f"{shape.id() or kind}: {kind} tessellated ({len(f)} triangles) from its to_world"


def _unreadable(shape, kind: str) -> AuditError:
    return AuditError(
        f"shape {shape.id() or kind!r} ({kind}): the audit's distance field reads meshes, spheres, disks, "
        "cylinders, rectangles and instances of shape groups of them only"
    )


def _shape_groups(mi, mi_scene) -> dict[str, list]:
    """The members of each ``shapegroup`` of the scene, by group name: Mitsuba lists only the top-level
    shapes (the ``instance`` shapes, not their group's members) in ``Scene.shapes()``; its parameter tree
    names each member's parameters ``<group>.<member>.<parameter>`` with the member as their owner."""
    top = {shape.ptr for shape in mi_scene.shapes()}
    groups: dict[str, dict[int, object]] = {}
    for key, entry in mi.traverse(mi_scene).properties.items():
        owner = entry[2]
        parts = key.split(".")
        if len(parts) < 3 or not isinstance(owner, mi.Shape) or owner.ptr in top:
            continue
        groups.setdefault(parts[0], {})[owner.ptr] = owner
    return {name: list(members.values()) for name, members in groups.items()}


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[(lo, hi)[i >> k & 1][k] for k in range(3)] for i in range(8)], np.float64)


def _instance_group(mi, shape, groups: dict[str, tuple]) -> tuple[str, np.ndarray]:
    """(group name, 4×4 to_world) of an ``instance``: Mitsuba does not expose an instance's group, so it is
    the group whose bounding box, carried by the instance's ``to_world``, is the instance's own
    (``Instance.bbox()``: the 8 transformed corners' box), to 1e-4 of the box's size."""
    m = np.asarray(mi.traverse(shape)["to_world"].matrix, np.float64).reshape(4, 4)
    box = shape.bbox()
    want = np.array([[float(box.min[i]) for i in range(3)], [float(box.max[i]) for i in range(3)]])
    scale = max(float(np.abs(want).max()), 1e-30)
    found = []
    for name, (v, _f, _how) in groups.items():
        c = _box_corners(v.min(0), v.max(0)) @ m[:3, :3].T + m[:3, 3]
        if np.abs(np.array([c.min(0), c.max(0)]) - want).max() <= 1e-4 * scale:
            found.append(name)
    if len(found) != 1:
        raise AuditError(
            f"shape {shape.id() or 'instance'!r} (instance): its shape group could not be told from "
            f"{'the groups ' + ', '.join(found) if found else 'no group'} by its bounding box"
        )
    return found[0], m


def scene_triangles(mi, mi_scene) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(vertices (V, 3) float64, faces (F, 3) int64, one line per shape saying how it was read) of every
    shape of ``mi_scene`` (module docstring), emitters' shapes included (they occlude too). An ``instance``
    is flattened: its shape group's members (meshes and analytic shapes, read as above in the group's
    space) carried by the instance's ``to_world``."""
    vs, fs, lines = [], [], []
    offset = 0
    groups = None
    for shape in mi_scene.shapes():
        kind = _kind(shape)
        if kind == "instance":
            if groups is None:
                groups = {}
                for name, members in _shape_groups(mi, mi_scene).items():
                    read = [_shape_triangles(mi, s) for s in members]
                    if any(r is None for r in read):
                        bad = next(s for s, r in zip(members, read, strict=True) if r is None)
                        raise _unreadable(bad, _kind(bad))
                    parts = [r for r in read if r is not None and len(r[1])]
                    if parts:
                        sizes = np.cumsum([0] + [len(p[0]) for p in parts])
                        v = np.concatenate([p[0] for p in parts])
                        f = np.concatenate([p[1] + o for p, o in zip(parts, sizes[:-1], strict=True)])
                        groups[name] = (v, f, "; ".join(p[2] for p in parts))
            name, m = _instance_group(mi, shape, groups)
            gv, f, _ = groups[name]
            v = gv @ m[:3, :3].T + m[:3, 3]
            how = f"{shape.id() or 'instance'}: instance of shape group {name!r} ({len(f)} triangles)"
        else:
            read = _shape_triangles(mi, shape)
            if read is None:
                raise _unreadable(shape, kind)
            v, f, how = read
        if not (np.all(np.isfinite(v)) and len(f)):
            continue
        vs.append(v)
        fs.append(f + offset)
        offset += len(v)
        lines.append(how)
    if not vs:
        raise AuditError("the scene has no shape to build a distance field from")
    return np.concatenate(vs), np.concatenate(fs), lines


def ao_radius(setup: AuditSetup, family: str = "sdf-occlusion") -> float:
    """R: ``--ao-distance``, else the scene's default (`default_ao_distance`); finite and positive."""
    radius = setup.ao_distance if setup.ao_distance is not None else default_ao_distance(setup.info)
    if radius is None or not (math.isfinite(radius) and radius > 0):
        raise AuditError(f"{family}: the scene has no finite size; give --ao-distance")
    return float(radius)


def reflective_shape(setup: AuditSetup, app: Applicability, family: str, check_label: bool = True):
    """(index in the loaded scene's shapes, Mitsuba shape, BSDF plugin) of the applicability's shape:
    ``app.source`` is its ordinal among the scene's reflective shapes (`reflective_shapes`, the order the
    scene's parts were listed in); ``check_label``: the part's label must name that shape's BSDF kind (a
    mirror, glass …), else the scene was not the one listed. One line naming ``family`` otherwise."""
    found = reflective_shapes(setup.scene)
    k = app.source
    if (
        k is None
        or not 0 <= k < len(found)
        or (check_label and REFLECTIVE_BSDFS[found[k][1]].text not in app.part)
    ):
        raise AuditError(f"{family}: {app.part} is not a reflective shape of the loaded scene")
    index, plugin = found[k]
    return index, setup.scene.shapes()[index], plugin


def rays(mi, origins: np.ndarray, dirs: np.ndarray):
    """A Mitsuba ray per row of ``origins`` and ``dirs`` (N, 3), rounded to float32 on the device
    (`device_vectors`: one kernel whatever the arrays' addresses; strided columns of a float32 copy, mapped
    as they lay, gave the kernels reading them up to 3 variants, compiled again from run to run)."""
    return mi.Ray3f(device_vectors(mi, mi.Point3f, origins), device_vectors(mi, mi.Vector3f, dirs))


def camera_rays(setup: AuditSetup) -> tuple[np.ndarray, np.ndarray]:
    """(origins, unit directions) (N, 3) float64 of the pixel-centre camera rays of the visible pixels
    (``setup.mask``, row-major): each origin is the first hit minus its ray distance along the direction."""
    gb, visible = setup.gbuffer, setup.mask
    dirs = gb.view_dir[visible].astype(np.float64)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return gb.position[visible].astype(np.float64) - gb.depth[visible].astype(np.float64)[
        :, None
    ] * dirs, dirs


def shape_view(setup: AuditSetup, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The visible pixels' camera rays (`camera_rays`: origins and unit directions, (N, 3)) and which of them
    first hit the scene's shape ``index`` (`shape_pixels`: (N,) bool): the pixels a family auditing one
    shape compares."""
    origins, dirs = camera_rays(setup)
    return origins, dirs, shape_pixels(setup.mi, setup.scene, index, origins, dirs)


def visible_subset(visible: np.ndarray, sees: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """The (H, W) bool mask of the pixels of ``visible`` (H, W) that ``sees`` keeps (one bool per visible
    pixel, row-major, as `shape_view` gives it) and, where given, ``keep`` too (one bool per pixel that
    ``sees`` keeps)."""
    chosen = np.flatnonzero(sees) if keep is None else np.flatnonzero(sees)[keep]
    mask = np.zeros(visible.size, bool)
    mask[np.flatnonzero(visible.reshape(-1))[chosen]] = True
    return mask.reshape(visible.shape)


def sdf_scene(name: str, label: str, **fields) -> ShippedScene:
    """A shipped sdf-occlusion scene (``scenes/library/sdf_<name>.toml``, geometry by
    `rtfit.experiments.sdf_occlusion_scenes`) at the sizes and samples of the experiment before the engine
    (full: 128², 1024 spp; ``--quick``: 36², 64 spp), with a family's ``label`` and own ``fields`` (the AO
    radius, which scenes ``--quick`` audits): the sdf-occlusion and obscurances families ship them."""
    return Sizes(full=(128, 128, 1024), quick=(36, 36, 64)).scene(f"sdf_{name}.toml", label, **fields)
