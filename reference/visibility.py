"""Visibility baking with Mitsuba ray casts: bent normal and ambient aperture per point, as a baker would.

For each point x with unit normal n, ``n_dirs`` directions ω are drawn uniformly over the hemisphere
around n (pdf 1/2π) and a ray is cast along each against the scene's *static geometry* (every declared
shape; the lights are removed first, so a sphere light's own shape never occludes). With V(ω) = 1 where
the ray escapes:

* visible fraction      V̂ = mean V(ωᵢ)                          (estimates (1/2π) ∫_Ω V dω)
* bent normal           â = normalize(Σ V(ωᵢ) ωᵢ)                (seed 000:2670: ∫ V ω dω, uniform weight)
* aperture              r_a = acos(1 − V̂) = 2 asin(√(V̂/2))      (cap of solid angle 2π V̂; 000:2660-2668)

``stderr`` is the binomial standard error of V̂, √(V̂(1 − V̂)/n_dirs). Directions are stratified on a
√n × √n grid of the unit square (jittered with Mitsuba's ``independent`` sampler), then mapped with
``mi.warp.square_to_uniform_hemisphere``; rays start at the point offset along n by Mitsuba's own
``spawn_ray`` rule. A point where no direction escapes gets â = n and r_a = 0.

Also `surface_points`: first hits of vertical rays cast downwards at given (x, y), to place bake and
probe points on a receiver (height field, floor of a well) exactly where Mitsuba sees the surface.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import drjit as dr
import numpy as np

from .build import load_mitsuba_scene
from .estimators import MAX_LANES, device_vectors, sub_seed


@dataclass(frozen=True)
class BakedVisibility:
    """Per point: visible fraction of the hemisphere, its binomial standard error, bent normal and aperture
    (rad)."""

    visible_fraction: np.ndarray  # (N,) float64 in [0, 1]
    stderr: np.ndarray  # (N,)
    bent_normal: np.ndarray  # (N, 3) unit
    aperture: np.ndarray  # (N,) radians in [0, π/2]
    n_dirs: int

    def to_dict(self) -> dict:
        return {
            "n_dirs": self.n_dirs,
            "mean_visible_fraction": float(self.visible_fraction.mean()),
            "max_stderr": float(self.stderr.max()) if self.stderr.size else 0.0,
        }


def _geometry_only(scene):
    return dataclasses.replace(scene, lights=(), name=f"{scene.name}-geometry")


def bake_visibility(
    scene, points, normals, n_dirs: int = 1024, seed: int = 0, variant: str = "llvm_ad_rgb"
) -> BakedVisibility:
    """Bake V̂, â and r_a at ``points`` (N, 3) with unit ``normals`` (N, 3); see the module docstring."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape != normals.shape:
        raise ValueError(f"points and normals must both be (N, 3) (got {points.shape} and {normals.shape})")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(normals))):
        raise ValueError("points and normals must be finite")
    if np.any(np.abs(np.linalg.norm(normals, axis=1) - 1.0) > 1e-3):
        raise ValueError("normals must be unit length")
    side = round(math.sqrt(n_dirs))
    if n_dirs < 4 or side * side != n_dirs:
        raise ValueError(f"n_dirs must be a perfect square >= 4 (got {n_dirs})")

    mi, mi_scene = load_mitsuba_scene(_geometry_only(scene), variant)
    n = len(points)
    vis = np.zeros(n)
    bent = np.zeros((n, 3))
    per = max(1, MAX_LANES // n_dirs)
    for k, a in enumerate(range(0, n, per)):
        b = min(n, a + per)
        m = b - a
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(sub_seed(seed, "bake", k), m * n_dirs)
        lane = dr.arange(mi.UInt32, m * n_dirs)
        idx = lane // n_dirs
        cell = lane % n_dirs
        jitter = sampler.next_2d()
        u = mi.Point2f((mi.Float(cell % side) + jitter.x) / side, (mi.Float(cell // side) + jitter.y) / side)
        p = dr.gather(mi.Point3f, device_vectors(mi, mi.Point3f, points[a:b]), idx)
        nrm = dr.gather(mi.Vector3f, device_vectors(mi, mi.Vector3f, normals[a:b]), idx)
        it = dr.zeros(mi.SurfaceInteraction3f)
        it.p = p
        it.n = nrm
        it.sh_frame = mi.Frame3f(nrm)
        d = mi.Frame3f(nrm).to_world(mi.warp.square_to_uniform_hemisphere(u))
        ray = it.spawn_ray(d)
        escaped = ~mi_scene.ray_test(ray)
        v = mi.Float64(dr.select(escaped, 1.0, 0.0))
        sums = [dr.block_sum(v, n_dirs)] + [dr.block_sum(v * mi.Float64(d[c]), n_dirs) for c in range(3)]
        dr.eval(sums)
        vis[a:b] = np.asarray(sums[0], dtype=np.float64) / n_dirs
        bent[a:b] = np.stack([np.asarray(s, dtype=np.float64) for s in sums[1:]], axis=-1)
    norm = np.linalg.norm(bent, axis=1, keepdims=True)
    bent = np.where(norm > 0, bent / np.maximum(norm, 1e-300), normals)
    aperture = 2.0 * np.arcsin(np.sqrt(np.clip(vis, 0.0, 1.0) / 2.0))
    stderr = np.sqrt(vis * (1.0 - vis) / n_dirs)
    return BakedVisibility(vis, stderr, bent, aperture, n_dirs)


def surface_points(scene, xy, z_top: float, variant: str = "llvm_ad_rgb", geometry_only: bool = True):
    """First hits of rays cast straight down (−z) from (x, y, z_top) for each row of ``xy`` (N, 2).

    Returns ``(points (N, 3), normals (N, 3), valid (N,))``; normals are Mitsuba's shading normals turned
    to face up (+z side), rows without a hit have ``valid`` False and zeros. With ``geometry_only`` the
    lights are removed first (a sphere light above the receiver would otherwise be hit).
    """
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise ValueError(f"xy must be a finite (N, 2) array (got shape {xy.shape})")
    mi, mi_scene = load_mitsuba_scene(_geometry_only(scene) if geometry_only else scene, variant)
    n = len(xy)
    o = mi.Point3f(np.stack([xy[:, 0], xy[:, 1], np.full(n, float(z_top))]).astype(np.float32))
    ray = mi.Ray3f(o, mi.Vector3f(0.0, 0.0, -1.0))
    si = mi_scene.ray_intersect(ray)
    nrm = si.sh_frame.n
    nrm = dr.select(nrm.z < 0, -nrm, nrm)
    dr.eval(si.p, nrm, si.is_valid())
    valid = np.asarray(si.is_valid(), dtype=bool)
    pts = np.asarray(si.p, dtype=np.float64).T if n else np.zeros((0, 3))
    nrms = np.asarray(nrm, dtype=np.float64).T if n else np.zeros((0, 3))
    pts = pts.reshape(n, 3)
    nrms = nrms.reshape(n, 3)
    nrms = nrms / np.maximum(np.linalg.norm(nrms, axis=1, keepdims=True), 1e-300)
    pts[~valid] = 0.0
    nrms[~valid] = 0.0
    return pts, nrms, valid
