"""Procedural geometry of the ``sdf-occlusion`` scenes: meshes (PLY, shipped in scenes/library/meshes/) and
the analytic primitives they were made from (for the analytic-SDF rows and tests).

Every mesh is closed (watertight) and built from non-overlapping solids (solids may touch), so the
parity sign of `rtfit.realtime.sdf_grid.mesh_sdf_grid` is exact. ``write_library_meshes(folder)``
regenerates the shipped files bit for bit (deterministic).

Scenes (scene units: metres):

* ``crease_<φ>``: a thick "V" (thickness 0.1) whose two arms of length 2 meet at an interior angle φ
  (30°, 60°, 90°, 120°) along the y axis, extruded over y ∈ [−1, 1]. Floor arm along +x (top face z = 0).
  For infinite arms the cosine-weighted visibility of a floor point is (1 − cos φ)/2 at any distance from
  the crease (the wall hides the projected angles [φ, π]: fraction (cos φ − cos π)/2 of the cosine lobe).
* ``sphere_plane``: a sphere of radius 0.5 resting on a 4 × 4 × 0.1 slab (top face z = 0).
* ``room``: a closed 2 × 2 × 1.4 room (walls 0.1 thick) with an open window 0.8 × 0.6 in the +x wall.
* ``boxes``: a 4 × 4 grid of boxes (a city block) of seeded heights on a 5 × 5 slab.
* ``character``: a figure (head, torso, arms, legs as capsules and spheres, smooth union) meshed by
  marching cubes (scikit-image) and standing on a slab; the held-out scene of the joint fit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import math
from pathlib import Path

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.sdf_grid import (
    Box,
    Capsule,
    SdfGrid,
    Sphere,
    grid_for_bounds,
    mesh_bounds,
    mesh_sdf_grid,
    primitive_sdf,
)
from rtfit.reference.io import atomic_write_bytes
from rtfit.scenes import library_path, load_scene

from .mesh_normals import vertex_normals
from .mesh_ply import write_ply

CREASE_ANGLES = (30, 60, 90, 120)
SCENE_NAMES = (*(f"crease_{a}" for a in CREASE_ANGLES), "sphere_plane", "room", "boxes", "character")
# Scenes shaded with smooth vertex normals (``face_normals = false``): their PLYs carry the normals
# (`rtfit.experiments.mesh_normals`), since Mitsuba's recomputation at load time is not deterministic.
SMOOTH = ("sphere_plane", "character")


# ------------------------------------------------------------------------------------------ PLY


def read_ply(path):
    """Read the PLY files written by `write_ply` (vertices (V, 3) float64, faces (F, 3) int64; stored
    normals are skipped)."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode()
    nv = int(head.split("element vertex ")[1].split()[0])
    nf = int(head.split("element face ")[1].split()[0])
    k = 6 if "property float nx" in head else 3
    v = np.frombuffer(data, dtype="<f4", count=k * nv, offset=end).reshape(nv, k)[:, :3].astype(np.float64)
    rec = np.frombuffer(data, dtype=[("n", "u1"), ("i", "<i4", (3,))], count=nf, offset=end + 4 * k * nv)
    if not np.all(rec["n"] == 3):
        raise ValueError(f"{path}: only triangle faces are supported")
    return v, rec["i"].astype(np.int64)


# ------------------------------------------------------------------------------------- builders
def box_mesh(center, half, rotation=None):
    c = np.asarray(center, dtype=np.float64)
    hs = np.asarray(half, dtype=np.float64)
    v = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], float) * hs
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    v = v + c
    f = np.array(
        [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ],
        dtype=np.int64,
    )
    # Vertices are not shared between faces, so interpolated (smooth) normals are the face normals.
    return v[f.reshape(-1)], np.arange(36, dtype=np.int64).reshape(12, 3)


def icosphere(center, radius, subdivisions=3):
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = [
        [-1, t, 0],
        [1, t, 0],
        [-1, -t, 0],
        [1, -t, 0],
        [0, -1, t],
        [0, 1, t],
        [0, -1, -t],
        [0, 1, -t],
        [t, 0, -1],
        [t, 0, 1],
        [-t, 0, -1],
        [-t, 0, 1],
    ]
    f = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = f
    for _ in range(subdivisions):
        cache = {}
        new = []

        def mid(a, b, cache=cache):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new
    return np.array(verts) * radius + np.asarray(center, float), np.array(faces, dtype=np.int64)


def prism_mesh(polygon_xz, y0, y1, quads):
    """Extrude a simple polygon (list of (x, z), counter-clockwise) along y; caps from the given convex
    quads/triangles (index lists into the polygon)."""
    p = np.asarray(polygon_xz, float)
    m = len(p)
    v = np.concatenate(
        [
            np.column_stack([p[:, 0], np.full(m, y0), p[:, 1]]),
            np.column_stack([p[:, 0], np.full(m, y1), p[:, 1]]),
        ]
    )
    f = []
    for i in range(m):
        j = (i + 1) % m
        f += [[i, j, m + j], [i, m + j, m + i]]
    for q in quads:
        for k in range(1, len(q) - 1):
            f.append([q[0], q[k + 1], q[k]])
            f.append([m + q[0], m + q[k], m + q[k + 1]])
    return v, np.array(f, dtype=np.int64)


def merge(*meshes):
    vs, fs, off = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


# ---------------------------------------------------------------------------------------- scenes
def crease(phi_deg: float, length: float = 2.0, thick: float = 0.1, half_width: float = 1.0):
    """Thick V of interior angle φ; returns (mesh, primitives=None)."""
    phi = math.radians(phi_deg)
    e = np.array([math.cos(phi), math.sin(phi)])
    ne = np.array([-math.sin(phi), math.cos(phi)])  # from the wall arm into its solid (away from the wedge)
    s = -thick * (1.0 + math.cos(phi)) / math.sin(phi)
    q = thick * ne + s * e  # corner where the two back faces meet (z = −thick)
    poly = [
        (0.0, 0.0),
        tuple(length * e),
        tuple(length * e + thick * ne),
        tuple(q),
        (length, -thick),
        (length, 0.0),
    ]
    # polygon order: O, Le, Le+t·ne, Q, (L,−t), (L,0): counter-clockwise seen from −y is irrelevant for parity
    mesh = prism_mesh(poly, -half_width, half_width, [[0, 1, 2, 3], [0, 3, 4, 5]])
    return mesh, None


def sphere_plane():
    prims = [Box((0.0, 0.0, -0.05), (2.0, 2.0, 0.05)), Sphere((0.0, 0.0, 0.5), 0.5)]
    mesh = merge(box_mesh((0, 0, -0.05), (2.0, 2.0, 0.05)), icosphere((0, 0, 0.5), 0.5, 3))
    return mesh, prims


def room():
    t = 0.1
    hx, hy, hz = 1.0, 1.0, 0.7  # interior half-extents
    boxes = [
        ((0, 0, -t / 2), (hx + t, hy + t, t / 2)),  # floor
        ((0, 0, 2 * hz + t / 2), (hx + t, hy + t, t / 2)),  # ceiling
        ((-hx - t / 2, 0, hz), (t / 2, hy + t, hz)),  # −x wall
        ((0, -hy - t / 2, hz), (hx, t / 2, hz)),  # −y wall
        ((0, hy + t / 2, hz), (hx, t / 2, hz)),  # +y wall
    ]
    # +x wall with a window (|y| < 0.4, 0.5 < z < 1.1): four boxes around the hole
    wx = hx + t / 2
    boxes += [
        ((wx, 0, 0.25), (t / 2, hy + t, 0.25)),  # below the window, z ∈ [0, 0.5]
        ((wx, 0, 1.25), (t / 2, hy + t, 0.15)),  # above, z ∈ [1.1, 1.4]
        ((wx, -0.4 - 0.35 - t / 2, 0.8), (t / 2, 0.35 + t / 2, 0.3)),  # left of it, y ∈ [−1.1, −0.4]
        ((wx, 0.4 + 0.35 + t / 2, 0.8), (t / 2, 0.35 + t / 2, 0.3)),  # right
    ]
    prims = [Box(c, h) for c, h in boxes]
    mesh = merge(*[box_mesh(c, h) for c, h in boxes])
    return mesh, prims


def boxes():
    rng = np.random.default_rng(7)
    items = [((0.0, 0.0, -0.05), (2.5, 2.5, 0.05))]
    for i in range(4):
        for j in range(4):
            h = float(rng.uniform(0.2, 1.2))
            w = float(rng.uniform(0.25, 0.4))
            items.append(((-1.5 + i, -1.5 + j, h / 2), (w, w, h / 2)))
    prims = [Box(c, h) for c, h in items]
    return merge(*[box_mesh(c, h) for c, h in items]), prims


def character_primitives():
    """Capsules and spheres of the figure (standing on z = 0, about 1.7 tall)."""
    return [
        Sphere((0.0, 0.0, 1.55), 0.14),  # head
        Capsule((0.0, 0.0, 0.95), (0.0, 0.0, 1.3), 0.17),  # torso
        Capsule((-0.2, 0.0, 1.3), (-0.45, 0.05, 0.95), 0.06),  # left arm
        Capsule((-0.45, 0.05, 0.95), (-0.35, -0.2, 0.75), 0.055),  # left forearm (bent forward)
        Capsule((0.2, 0.0, 1.3), (0.42, 0.0, 0.92), 0.06),  # right arm
        Capsule((0.42, 0.0, 0.92), (0.45, 0.0, 0.6), 0.055),  # right forearm
        Capsule((-0.1, 0.0, 0.9), (-0.12, 0.0, 0.5), 0.08),  # left thigh
        Capsule((-0.12, 0.0, 0.5), (-0.12, 0.0, 0.1), 0.065),  # left shin
        Capsule((0.1, 0.0, 0.9), (0.15, -0.05, 0.5), 0.08),  # right thigh
        Capsule((0.15, -0.05, 0.5), (0.15, 0.0, 0.1), 0.065),  # right shin
        Capsule((-0.12, -0.02, 0.05), (-0.12, -0.18, 0.05), 0.05),  # feet
        Capsule((0.15, -0.02, 0.05), (0.15, -0.18, 0.05), 0.05),
    ]


def _smooth_union(values, k=0.04):
    out = values[0]
    for v in values[1:]:
        h = np.clip(0.5 + 0.5 * (v - out) / k, 0.0, 1.0)
        out = v * (1 - h) + out * h - k * h * (1 - h)
    return out


def character():
    from skimage import measure  # scikit-image: optional, only to regenerate the character mesh

    prims = character_primitives()
    h = 0.02
    xs = np.arange(-0.7, 0.7 + h / 2, h)
    ys = np.arange(-0.4, 0.4 + h / 2, h)
    zs = np.arange(0.0 + h / 2, 1.8, h)  # the figure is cut at z = h/2 where it meets the slab
    zz, yy, xx = np.meshgrid(zs, ys, xs, indexing="ij")
    vals = _smooth_union([primitive_sdf(NUMPY_OPS, p, xx, yy, zz) for p in prims])
    vals = np.pad(vals, 1, constant_values=1.0)  # closed surface
    verts, faces, _, _ = measure.marching_cubes(vals.astype(np.float64), level=0.0)
    verts = verts - 1.0
    pos = np.column_stack([xs[0] + verts[:, 2] * h, ys[0] + verts[:, 1] * h, zs[0] + verts[:, 0] * h])
    pos[:, 2] = np.maximum(pos[:, 2], 0.0)  # the bottom cap rests on the slab top (z = 0)
    slab = box_mesh((0, 0, -0.05), (1.5, 1.5, 0.05))
    return merge(slab, (pos, faces.astype(np.int64))), None


def build(name: str):
    """(vertices, faces), primitives-or-None of a named scene."""
    if name.startswith("crease_"):
        return crease(float(name.split("_")[1]))
    return {"sphere_plane": sphere_plane, "room": room, "boxes": boxes, "character": character}[name]()


def write_library_meshes(folder) -> list[Path]:
    """Write every scene's mesh as ``sdf_<name>.ply`` into ``folder``; the smoothly shaded ones
    (`SMOOTH`) with their vertex normals."""
    folder = Path(folder)
    out = []
    for name in SCENE_NAMES:
        (v, f), _ = build(name)
        p = folder / f"sdf_{name}.ply"
        write_ply(p, v, f, vertex_normals(v, f) if name in SMOOTH else None)
        out.append(p)
    return out


def load_case_scene(name: str, resolution: int):
    """The library scene ``sdf_<name>`` with a square film of ``resolution`` pixels (shared by the
    sdf-occlusion and obscurances families)."""
    sc = load_scene(library_path(f"sdf_{name}"))
    return dataclasses.replace(sc, camera=dataclasses.replace(sc.camera, width=resolution, height=resolution))


def mesh_of(scene):
    """(vertices, faces) of every mesh shape of an sdf-occlusion library ``scene`` in world units."""
    vs, fs, off = [], [], 0
    for sh in scene.shapes:
        v, f = read_ply(sh.file)
        vs.append(v * np.asarray(sh.scale) + np.asarray(sh.translate))  # library meshes: no rotation
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def grid_of(scene, resolution: int, cache_dir=None):
    """The scene mesh's voxel SDF at ``resolution`` cells on the longest axis (cached as .npz by content)."""
    v, f = mesh_of(scene)
    h = hashlib.sha256(
        v.astype(np.float32).tobytes() + f.astype(np.int32).tobytes() + str(resolution).encode()
    )
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / "sdf-grids" / f"{h.hexdigest()[:24]}-{resolution}.npz"
        if path.exists():
            z = np.load(path)
            return SdfGrid(z["values"], tuple(z["origin"]), float(z["voxel"]), meta={"source": "mesh"})
    lo, hi = mesh_bounds(v)
    origin, voxel, shape = grid_for_bounds(lo, hi, resolution, pad_voxels=3.0, cubic=True)
    g = mesh_sdf_grid(v, f, origin, voxel, shape)
    if path is not None:
        buf = io.BytesIO()
        np.savez(buf, values=g.values, origin=np.asarray(g.origin), voxel=g.voxel)
        atomic_write_bytes(path, buf.getvalue())
    return g
