"""A medium-filled convex shape in a user's scene, seen along the camera's pixel rays: its chord, the opaque
depth behind it, and the path-traced opacity of its medium (the soft-particles family's audit reference).

Geometry, from Mitsuba's own ray–shape intersections (no formula of `rtfit.realtime.soft_particles`):

* the **particle**: one shape bounding a homogeneous medium (a ``sphere``, a ``cube`` under any affine
  ``to_world``, rtfit's tiled box boundary), intersected alone (a scene holding only that shape object):
  along the unit ray x(t) = o + t·d̂ from the camera position o, its entry t_in is the first hit (0 when the
  camera is inside, which the caller tells from the shape's own geometry), its exit t_out the first hit of the
  reversed ray started beyond the shape (o + (t_in + D)·d̂ towards −d̂, D = its bounding-box diagonal + 1):
  for a convex shape the reversed ray's first hit is the exit, with no spawn offset at a grazing entry (the
  silhouette band of docs/soft-particles.md);
* the **opaque depth** t_s: the first hit of the same ray in the scene's opaque shapes (every shape but the
  particle and the ``null``-BSDF shapes: a medium's boundary is not a surface), +inf where there is none.

The medium's clipped segment is [t_in, min(t_out, t_s)] (scene units). Opacity, per RGB channel c:
1 − T_c, T_c = exp(−σ_t,c·ℓ), ℓ the segment's length. The **reference** (`opacity_pass`) estimates it by
Mitsuba's free-flight sampling of the medium itself (``Medium.sample_interaction`` on channel c along the
segment, the medium's own σ_t and ``scale``): each sample is 1 when a collision falls inside the segment,
else 0 — Bernoulli(1 − T_c), whose variance (1 − T_c)·T_c per sample the pass's sample variance estimates.
Scattering (the albedo) is not part of a particle's opacity and is not sampled.
"""

from __future__ import annotations

import math
import time

import drjit as dr
import numpy as np

from .device_arrays import device_vectors
from .estimators import PassMoments, PassResult, check_spp, point_chunks

__all__ = [
    "CONVEX_MAX_FACES",
    "convex_mesh",
    "inside_convex_mesh",
    "medium_extinction",
    "mesh_volume",
    "opacity_pass",
    "particle_segments",
    "shapes_scene",
]

CONVEX_MAX_FACES = 20000
"""Meshes with more triangles are not tested for convexity (the test is O(faces × vertices))."""


def convex_mesh(vertices, faces, rel_tol: float = 1e-4) -> bool:
    """True when the closed triangle mesh (vertices (V, 3), faces (F, 3)) bounds a convex volume: every vertex
    lies on the inner side of every face's plane, within ``rel_tol`` × the mesh's bounding-box diagonal (the
    inner side: the side of the vertices' mean). Degenerate faces are skipped; more than `CONVEX_MAX_FACES`
    faces, or no face: False."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(f) or len(f) > CONVEX_MAX_FACES:
        return False
    n, offset = _outward_planes(v, f)
    tol = rel_tol * float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    for a in range(0, len(n), 512):  # signed distances of every vertex to 512 planes at a time
        if np.any(n[a : a + 512] @ v.T - offset[a : a + 512, None] > tol):
            return False
    return True


def _outward_planes(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (F', 3), offsets (F',)) of the non-degenerate faces' planes n·x = offset, each normal
    turned away from the vertices' mean (outward for a convex mesh, whatever its winding)."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    norm = np.linalg.norm(n, axis=1)
    keep = norm > 1e-12 * max(float(np.max(norm)), 1e-300)
    n, p0 = n[keep] / norm[keep, None], v[f[keep, 0]]
    n[np.einsum("ij,ij->i", n, v.mean(axis=0) - p0) > 0.0] *= -1.0
    return n, np.einsum("fk,fk->f", n, p0)


def inside_convex_mesh(vertices, faces, point) -> bool:
    """True when ``point`` lies strictly inside the convex mesh (behind every face's outward plane)."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    n, offset = _outward_planes(v, np.asarray(faces, np.int64).reshape(-1, 3))
    return bool(np.all(n @ np.asarray(point, np.float64) < offset))


def mesh_volume(vertices, faces) -> tuple[float, np.ndarray]:
    """(volume, centroid (3,)) of a closed triangle mesh by the divergence theorem (signed tetrahedra from the
    origin; the sign of the winding is taken out)."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    total = float(vol.sum())
    centroid = (vol[:, None] * (a + b + c) / 4.0).sum(axis=0) / total if total != 0.0 else v.mean(axis=0)
    return abs(total), centroid


def shapes_scene(mi, shapes):
    """A Mitsuba scene holding only the given loaded shape objects (for ray queries)."""
    return mi.load_dict({"type": "scene", **{f"s{i}": s for i, s in enumerate(shapes)}})


def _rays(mi, origin, dirs):
    o = mi.Point3f(*[float(v) for v in origin])
    d = device_vectors(mi, mi.Vector3f, dirs)
    return o, d


def particle_segments(
    mi, particle, opaque, origin, dirs, inside: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_in, t_out, t_s) (N,) float64 along the unit rays ``dirs`` (N, 3) from ``origin`` (module docstring):
    ``particle`` a scene holding the particle's shape alone, ``opaque`` one of the opaque shapes (or None),
    ``inside``: the camera is inside the particle (t_in = 0; its first hit is then the exit). t_in = +inf
    where a ray misses the particle."""
    o, d = _rays(mi, origin, dirs)
    n = len(dirs)
    si = particle.ray_intersect(mi.Ray3f(o, d))
    valid = si.is_valid()
    dr.eval(valid, si.t)  # one launch: each conversion below would trace the rays again
    hit = np.asarray(valid, bool)
    t1 = np.asarray(si.t, np.float64)
    t_in = np.where(hit, 0.0 if inside else t1, math.inf)
    box = particle.bbox()
    span = float(dr.norm(box.max - box.min)) + 1.0
    start = np.where(hit, t_in, 0.0) + span
    back = mi.Point3f(*[mi.Float(float(origin[k]) + start * dirs[:, k]) for k in range(3)])
    si2 = particle.ray_intersect(mi.Ray3f(back, -d))
    t2 = np.asarray(si2.t, np.float64)
    t_out = np.where(hit & np.asarray(si2.is_valid(), bool), start - t2, np.where(hit, t1, math.inf))
    t_out = np.maximum(t_out, t_in)
    if opaque is None:
        return t_in, t_out, np.full(n, math.inf)
    so = opaque.ray_intersect(mi.Ray3f(o, d))
    t_s = np.where(np.asarray(so.is_valid(), bool), np.asarray(so.t, np.float64), math.inf)
    return t_in, t_out, t_s


def medium_extinction(mi, medium, point) -> np.ndarray:
    """σ_t (3,) per RGB channel (1/scene unit, the medium's ``scale`` included) of a homogeneous ``medium`` at
    ``point``: Mitsuba's own ``get_scattering_coefficients``."""
    mei = dr.zeros(mi.MediumInteraction3f)
    mei.p = mi.Point3f(*[float(v) for v in point])
    _s, _n, sigma_t = medium.get_scattering_coefficients(mei)
    return np.asarray(sigma_t, np.float64).reshape(-1)[:3] * np.ones(3)


def opacity_pass(mi, medium, origin, dirs, start, length, spp: int, seed: int) -> PassResult:
    """One pass of ``spp`` samples of the opacity 1 − T_c (c = R, G, B) per ray (module docstring): the
    segment [``start``, ``start`` + ``length``] (N,) of the unit rays ``dirs`` (N, 3) from ``origin`` (a
    zero length: opacity 0). Mean and unbiased variance (N, 3)."""
    check_spp(spp)
    t0 = time.perf_counter()
    dirs = np.asarray(dirs, np.float64)
    n = len(dirs)
    ends = np.asarray(origin, np.float64) + dirs * np.asarray(start, np.float64)[:, None]
    seg = np.zeros((n, 3))
    seg[:, 0] = np.asarray(length, np.float64)
    acc = PassMoments(mi, n, 3, spp)
    columns = [(mi.Point3f, ends), (mi.Vector3f, dirs), (mi.Vector3f, seg)]
    for a, sampler, (p, d, s) in point_chunks(mi, spp, seed, columns):
        ray = mi.Ray3f(p, d)
        ray.maxt = s.x
        active = s.x > 0.0
        values = []
        for c in range(3):
            mei = medium.sample_interaction(ray, sampler.next_1d(), c, active)
            hit = active & mei.is_valid() & (mei.t <= s.x)
            values.append(dr.select(hit, mi.Float(1.0), mi.Float(0.0)))
        acc.add(a, values)
    mean, var = acc.result()
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
