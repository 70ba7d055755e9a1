r"""Signed distance fields for the occlusion family: analytic primitives, mesh → voxel grid, mip chain.

Sign convention (the whole family): **s(P) > 0 outside every solid, s(P) < 0 inside, s = 0 on the
surface**, |s| = Euclidean distance to the nearest surface point (scene units). This is the convention
of the seed's listings (000:3037-3040: ``if (p) d=-d`` makes inside voxels negative) and of Mitsuba's
``sdfgrid`` shape. The seed's *text* says the opposite (000:2891-2895: "S(P) > 0 when it is inside any
body"); `seed_text_sdf` converts (S_text = −s). Formulas written in the text's convention are rewritten
here with that substitution (see `rtfit.realtime.sdf_occlusion`).

Analytic primitives (exact Euclidean SDFs, union by ``min``; Inigo Quilez's standard forms):

* sphere  s = |P − c| − r
* box (centre c, half-size b, rotation R: world = R·local): q = |R^T(P − c)| − b,
  s = |max(q, 0)| + min(max(q_x, q_y, q_z), 0)
* half-space "plane" (point o, outward unit normal n): s = n·(P − o)   (solid below the plane)
* capsule (segment a–b, radius r): h = clamp((P − a)·(b − a)/|b − a|², 0, 1), s = |P − a − h(b − a)| − r

Voxel grid (`SdfGrid`): values at cell centres x_i = origin + (i + ½)·h for i = 0..n−1 on each axis,
stored as a float32 array of shape (nz, ny, nx) (first axis z, as Mitsuba's volume tensors). Trilinear
sampling treats the values as samples at the cell centres (GPU texel-centre convention): a position is
clamped to the box spanned by the first and last cell centres and the distance from the position to
that box is *added* (outside the grid the field stays 1-Lipschitz and grows with distance; a lower
bound of the true distance's growth, documented fallback).

Mesh → grid (`mesh_sdf_grid`): exact Euclidean distance to the triangles at every cell centre in a
narrow band (|s| ≤ ``band`` voxels: every triangle, subdivided until its edges are ≤ 8 voxels, is
tested against every cell centre in its bounding box grown by the band; a region-free float64 Dr.Jit
kernel, exact for degenerate triangles too), then outside the band the
distance to the closest surface point of the nearest band voxel (closest-point propagation through
SciPy's exact Euclidean distance transform); sign from the parity of crossings of +z rays through each
column (ray origins jittered by 1e-4·h·(√2, √3) off the cell centres so that rays do not graze shared
edges). A column with an odd number of crossings means the mesh is not watertight: ``sign="parity"``
then raises a one-line ValueError; ``sign="flood"`` takes a documented fallback (cells connected to the
grid boundary through cells farther than √3·h/2 from the surface are outside; cells closer take the
sign of their nearest such far cell); ``sign="unsigned"`` returns |s|.

Mip chain (`build_mips`): level 0 is the grid; level L + 1 is level L blurred by a separable Gaussian of
σ = ``sigma`` level-L voxels and then averaged over 2×2×2 blocks (cell centres of level L + 1 sit at the
centres of the blocks: voxel size doubles, the box stays the same). The seed (000:2937-2938) samples
d_i = 2^(i−1)·h from mip level i − 1, blurred over a radius proportional to d_i. ``prefilter=False``
gives a chain of plain 2×2×2 averages without the Gaussian.

8-bit storage (`quantize_8bit`): the seed stores its 128³ SDF as 8-bit unsigned (000:2946, Listing 2:
d in voxels clamped to ±127, +128). q = clip(round(s/(h·step)) + 128, 1, 255)·... see the function;
dequantised values are what a GPU's UNORM8 sampler returns before filtering.

NumPy/SciPy, and the Dr.Jit LLVM backend for the per-cell kernels of the mesh → grid transform (always on
the CPU); no Mitsuba here (``tests/test_layering.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, cast

import drjit as dr
import numpy as np
from drjit.llvm import Array3f, Array3f64, Float, Float64, Int32, UInt32

from .arrays import NUMPY_OPS, to_drjit

__all__ = [
    "Box",
    "Capsule",
    "HalfSpace",
    "SdfGrid",
    "Sphere",
    "build_mips",
    "grid_for_bounds",
    "mesh_bounds",
    "mesh_sdf_grid",
    "point_triangle_distance",
    "primitive_sdf",
    "primitives_sdf",
    "quantize_8bit",
    "sample_grid_numpy",
    "seed_text_sdf",
    "union_grid",
]


# ===================================================================================== primitives
@dataclass(frozen=True)
class Sphere:
    center: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        _finite3("Sphere.center", self.center)
        if not (float(self.radius) > 0 and math.isfinite(self.radius)):
            raise ValueError(f"Sphere.radius must be > 0 and finite (got {self.radius!r})")


@dataclass(frozen=True)
class Box:
    """Box of half-size ``half`` about ``center``; ``rotation`` (3×3, row-major tuple of rows) maps local
    to world (world = R·local); identity by default."""

    center: tuple[float, float, float]
    half: tuple[float, float, float]
    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def __post_init__(self):
        _finite3("Box.center", self.center)
        _finite3("Box.half", self.half)
        if min(self.half) <= 0:
            raise ValueError(f"Box.half must be > 0 on every axis (got {self.half!r})")
        r = np.asarray(self.rotation, dtype=np.float64)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
            raise ValueError("Box.rotation must be a 3×3 rotation matrix")


@dataclass(frozen=True)
class HalfSpace:
    """Solid half-space below the plane through ``point`` with outward normal ``normal`` (normalised)."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def __post_init__(self):
        _finite3("HalfSpace.point", self.point)
        _finite3("HalfSpace.normal", self.normal)
        n = np.asarray(self.normal, dtype=np.float64)
        ln = float(np.linalg.norm(n))
        if ln == 0:
            raise ValueError("HalfSpace.normal must be non-zero")
        object.__setattr__(self, "normal", tuple(float(c) for c in n / ln))


@dataclass(frozen=True)
class Capsule:
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        _finite3("Capsule.a", self.a)
        _finite3("Capsule.b", self.b)
        if not (float(self.radius) > 0 and math.isfinite(self.radius)):
            raise ValueError(f"Capsule.radius must be > 0 and finite (got {self.radius!r})")


def _finite3(name, v):
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers (got {v!r})")


def primitive_sdf(ops, prim, x, y, z):
    """Exact signed distance of one primitive at (x, y, z) (ops text: NumPy or Dr.Jit arrays)."""
    if isinstance(prim, Sphere):
        cx, cy, cz = (float(c) for c in prim.center)
        dx, dy, dz = x - cx, y - cy, z - cz
        return ops.sqrt(dx * dx + dy * dy + dz * dz) - float(prim.radius)
    if isinstance(prim, Box):
        cx, cy, cz = (float(c) for c in prim.center)
        dx, dy, dz = x - cx, y - cy, z - cz
        r = [[float(v) for v in row] for row in prim.rotation]
        # local = R^T · d
        lx = r[0][0] * dx + r[1][0] * dy + r[2][0] * dz
        ly = r[0][1] * dx + r[1][1] * dy + r[2][1] * dz
        lz = r[0][2] * dx + r[1][2] * dy + r[2][2] * dz
        qx = ops.abs(lx) - float(prim.half[0])
        qy = ops.abs(ly) - float(prim.half[1])
        qz = ops.abs(lz) - float(prim.half[2])
        ox, oy, oz = ops.maximum(qx, 0.0), ops.maximum(qy, 0.0), ops.maximum(qz, 0.0)
        sq = ox * ox + oy * oy + oz * oz
        # 0 inside; the select keeps forward-mode autodiff finite there (d√q = dq/(2√q) is 0/0 at q = 0)
        outside = ops.select(sq > 0, ops.sqrt(ops.maximum(sq, 1e-30)), sq * 0.0)
        inside = ops.minimum(ops.maximum(qx, ops.maximum(qy, qz)), 0.0)
        return outside + inside
    if isinstance(prim, HalfSpace):
        px, py, pz = (float(c) for c in prim.point)
        nx, ny, nz = prim.normal
        return (x - px) * nx + (y - py) * ny + (z - pz) * nz
    if isinstance(prim, Capsule):
        ax, ay, az = (float(c) for c in prim.a)
        bx, by, bz = float(prim.b[0]) - ax, float(prim.b[1]) - ay, float(prim.b[2]) - az
        bb = bx * bx + by * by + bz * bz
        px, py, pz = x - ax, y - ay, z - az
        h = (px * bx + py * by + pz * bz) * (1.0 / bb if bb > 0 else 0.0)
        h = ops.clip(h, 0.0, 1.0)
        qx, qy, qz = px - h * bx, py - h * by, pz - h * bz
        return ops.sqrt(qx * qx + qy * qy + qz * qz) - float(prim.radius)
    raise ValueError(f"unsupported SDF primitive {type(prim).__name__}")


EMPTY_DISTANCE = 1e30
"""Distance reported by the SDF of an empty scene (no primitives): 'very far', finite in float32."""


def primitives_sdf(ops, prims, x, y, z):
    """Union (min) of the primitives' SDFs; an empty list gives `EMPTY_DISTANCE` everywhere."""
    out = None
    for p in prims:
        d = primitive_sdf(ops, p, x, y, z)
        out = d if out is None else ops.minimum(out, d)
    if out is None:
        return x * 0.0 + EMPTY_DISTANCE
    return out


def seed_text_sdf(s):
    """The seed text's convention (000:2891-2895, positive inside): S_text = −s."""
    return -s


# ===================================================================================== the grid
@dataclass(frozen=True)
class SdfGrid:
    """A voxel SDF: ``values`` (nz, ny, nx) float32 at cell centres origin + (i + ½)·voxel.

    ``quantized``: True when the values went through `quantize_8bit` (their resolution is then
    ``quant_step``·voxel).
    """

    values: np.ndarray
    origin: tuple[float, float, float]
    voxel: float
    quantized: bool = False
    quant_step: float = 0.0
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        v = np.asarray(self.values)
        if v.ndim != 3 or min(v.shape) < 2:
            raise ValueError(
                f"SdfGrid.values must be a 3-D array with at least 2 cells per axis (got {v.shape})"
            )
        if not np.all(np.isfinite(v)):
            raise ValueError("SdfGrid.values must be finite")
        if not (self.voxel > 0 and math.isfinite(self.voxel)):
            raise ValueError(f"SdfGrid.voxel must be > 0 (got {self.voxel!r})")
        object.__setattr__(self, "values", np.ascontiguousarray(v, dtype=np.float32))

    @property
    def shape(self) -> tuple[int, int, int]:
        """(nx, ny, nz)."""
        nz, ny, nx = self.values.shape
        return nx, ny, nz

    @property
    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """World box covered by the cells: (lower corner, upper corner)."""
        lo = np.asarray(self.origin, dtype=np.float64)
        return lo, lo + np.asarray(self.shape, dtype=np.float64) * self.voxel

    def centres(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell-centre coordinates per axis (x, y, z) as 1-D float64 arrays."""
        nx, ny, nz = self.shape
        o = self.origin
        h = self.voxel
        return (
            o[0] + (np.arange(nx) + 0.5) * h,
            o[1] + (np.arange(ny) + 0.5) * h,
            o[2] + (np.arange(nz) + 0.5) * h,
        )

    def points(self) -> np.ndarray:
        """All cell centres, (nz, ny, nx, 3) float64 (x, y, z order in the last axis)."""
        xs, ys, zs = self.centres()
        zz, yy, xx = np.meshgrid(zs, ys, xs, indexing="ij")
        return np.stack([xx, yy, zz], axis=-1)


def grid_for_bounds(lo, hi, resolution: int, pad_voxels: float = 2.0, cubic: bool = False):
    """(origin, voxel, shape) of a cubic-voxel grid with ``resolution`` cells along the longest axis of
    the box [lo, hi] grown by ``pad_voxels`` voxels on every side; other axes get as many cells as they
    need (at least 2), or ``resolution`` too with ``cubic`` (a resolution³ grid centred on the box, as the
    seed's 128³ volume; Mitsuba 3.9's ``sdfgrid`` misses every hit on non-cubic grids, measured)."""
    if not isinstance(resolution, (int, np.integer)) or resolution < 4:
        raise ValueError(f"resolution must be an integer >= 4 (got {resolution!r})")
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("bounds must be two finite 3-vectors")
    ext = hi - lo
    if np.max(ext) <= 0:
        raise ValueError("bounds must have a positive extent")
    voxel = float(np.max(ext)) / (resolution - 2 * pad_voxels)
    n = np.maximum(np.ceil(ext / voxel + 2 * pad_voxels - 1e-9).astype(int), 2)
    n[np.argmax(ext)] = resolution
    if cubic:
        n[:] = resolution
    centre = 0.5 * (lo + hi)
    origin = centre - 0.5 * n * voxel
    return tuple(float(c) for c in origin), voxel, tuple(int(c) for c in n)


def union_grid(prims, origin, voxel, shape) -> SdfGrid:
    """Grid of the analytic union SDF sampled at the cell centres (float64 → float32)."""
    g = SdfGrid(np.zeros(tuple(reversed(shape)), np.float32), origin, voxel)
    p = g.points()
    vals = primitives_sdf(NUMPY_OPS, list(prims), p[..., 0], p[..., 1], p[..., 2])
    return SdfGrid(np.asarray(vals, dtype=np.float32), origin, voxel, meta={"source": "analytic"})


# ------------------------------------------------------------------------- point–triangle distance
def point_triangle_distance(p, a, b, c):
    """Closest point on triangle (a, b, c) to p and its distance; all (M, 3) float64 (Ericson 2005,
    *Real-Time Collision Detection* §5.1.5, Voronoi regions). Degenerate triangles (zero area) fall
    into an edge or vertex region and stay finite. Returns (closest (M, 3), distance (M,))."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    # default: interior
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
    res = a + ab * v[:, None] + ac * w[:, None]
    done = np.zeros(len(p), bool)

    def put(mask, val):
        nonlocal done
        m = mask & ~done
        if np.any(m):
            res[m] = val[m] if val.ndim == 2 and len(val) == len(p) else val
            done |= m

    put((d1 <= 0) & (d2 <= 0), a)
    put((d3 >= 0) & (d4 <= d3), b)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab[:, None])
        put((d6 >= 0) & (d5 <= d6), c)
        t_ac = np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac[:, None])
        den_bc = (d4 - d3) + (d5 - d6)
        t_bc = np.where(den_bc != 0, (d4 - d3) / den_bc, 0.0)
        put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + (c - b) * t_bc[:, None])
    # Degenerate triangles (denom == 0 and no region matched): nearest of the three edges.
    bad = ~done & (denom == 0)
    if np.any(bad):
        best = None
        for e0, e1 in ((a, b), (b, c), (c, a)):
            e = e1[bad] - e0[bad]
            ee = np.einsum("ij,ij->i", e, e)
            t = np.clip(np.einsum("ij,ij->i", p[bad] - e0[bad], e) / np.maximum(ee, 1e-300), 0.0, 1.0)
            q = e0[bad] + e * t[:, None]
            dd = np.linalg.norm(p[bad] - q, axis=1)
            if best is None:
                best, bq = dd, q
            else:
                m = dd < best
                best, bq = np.where(m, dd, best), np.where(m[:, None], q, bq)
        res[bad] = bq
    return res, np.linalg.norm(p - res, axis=1)


def _point_triangle_distance_drjit(p, a, b, c):
    """Closest point and distance as `point_triangle_distance`, as one Dr.Jit LLVM kernel in float64
    (`_closest_on_triangle`); inputs and outputs as `point_triangle_distance`. The band of `mesh_sdf_grid`
    runs the same kernel through `_BandTriangles.pairs`; this NumPy entry, on any (point, triangle) pairs,
    is where tests/test_sdf_grid_kernels.py checks it on generic, degenerate and densely sampled triangles."""

    def up(x):
        x = np.ascontiguousarray(x, dtype=np.float64)
        return Array3f64(*[Float64(x[:, k]) for k in range(3)])

    res, dist = _closest_on_triangle(up(p), up(a), up(b), up(c))
    dr.eval(res, dist)
    return np.stack([np.asarray(res[k]) for k in range(3)], axis=1), np.asarray(dist)


def _closest_on_triangle(P, A, B, C):
    """(closest point, distance) of points P to triangles ABC (`Array3f64` each, traced, not evaluated), by a
    region-free formulation: the nearest of (i) the three edges (clamped segment projections) and (ii) the
    orthogonal projection onto the plane when its barycentric coordinates v, w, 1 − v − w are all ≥ 0
    (v = (d1·|ac|² − d2·ab·ac)/det, w = (d2·|ab|² − d1·ab·ac)/det, det = |ab × ac|² by Lagrange's identity,
    d1 = ab·ap, d2 = ac·ap). The closest point of a triangle lies in its interior or on an edge, so this is
    exact, and it stays exact for degenerate and nearly degenerate (needle, collinear) triangles, where
    Voronoi-region tests on rounded products pick the wrong region (det ≤ 1e-12·|ab|²|ac|² skips (ii)).
    Used by `mesh_sdf_grid`'s band (`_BandTriangles.pairs`)."""
    best = bq = None
    for e0, e1 in ((A, B), (B, C), (C, A)):
        e = e1 - e0
        t = dr.clip(dr.dot(P - e0, e) / dr.maximum(dr.dot(e, e), 1e-300), 0.0, 1.0)
        q = e0 + e * t
        dd = dr.squared_norm(P - q)
        if best is None:
            best, bq = dd, q
        else:
            m = dd < best
            best, bq = dr.select(m, dd, best), dr.select(m, q, bq)
    assert best is not None and bq is not None  # the loop above always runs (three edges)
    ab, ac, ap = B - A, C - A, P - A
    aa, cc, bc = dr.dot(ab, ab), dr.dot(ac, ac), dr.dot(ab, ac)
    d1, d2 = dr.dot(ab, ap), dr.dot(ac, ap)
    det = aa * cc - bc * bc
    ok = det > 1e-12 * aa * cc
    inv = dr.select(ok, 1.0 / dr.select(ok, det, 1.0), 0.0)
    v = (d1 * cc - d2 * bc) * inv
    w = (d2 * aa - d1 * bc) * inv
    q = A + ab * v + ac * w
    dq = dr.squared_norm(P - q)
    use = ok & (v >= 0) & (w >= 0) & (v + w <= 1) & (dq < best)
    res = dr.select(use, q, bq)
    return res, dr.norm(P - res)


class _BandTriangles:
    """The (sub-divided) triangles of `mesh_sdf_grid`'s band as Dr.Jit tables, uploaded once: their corners
    (float64) and the first cell and extent of each one's box of cells (int32)."""

    def __init__(self, tri: np.ndarray, lo: np.ndarray, ext: np.ndarray):
        self.corners = [Array3f64(*[to_drjit(Float64, tri[:, j, k]) for k in range(3)]) for j in range(3)]
        self.lo = [to_drjit(Int32, lo[:, k]) for k in range(3)]
        self.ext = [to_drjit(Int32, ext[:, k]) for k in range(3)]

    def pairs(self, t_id: np.ndarray, local: np.ndarray, o: np.ndarray, h: float, shape: tuple[int, ...]):
        """(voxel index, closest point (n, 3), distance) of each pair (triangle ``t_id``, its ``local``-th
        cell in x-fastest order of its box): the cell's centre o + (i + ½)·h, the triangle's closest point to
        it. One kernel: the per-pair gathers of the corners and boxes run in it (issue 33: as NumPy fancy
        indexing they were 2.7 of the 2.9 s of a quick sdf-occlusion study's mesh bakes), the same float64
        operations as before, so the same bits."""
        nx, ny, _ = shape
        t, local_ = to_drjit(UInt32, t_id), to_drjit(Int32, local)
        # ≥ 1 on every pair (a triangle with a pair has a box of ≥ 1 cell a side); the max keeps the lanes
        # past the end of the last packet, whose gathers read 0, from dividing by 0 (a SIGFPE on x86)
        ex, ey = (dr.maximum(dr.gather(Int32, self.ext[k], t), 1) for k in range(2))
        ix = local_ % ex + dr.gather(Int32, self.lo[0], t)
        iy = (local_ // ex) % ey + dr.gather(Int32, self.lo[1], t)
        iz = local_ // (ex * ey) + dr.gather(Int32, self.lo[2], t)
        P = Array3f64(*[o[k] + (Float64(i) + 0.5) * h for k, i in enumerate((ix, iy, iz))])
        A, B, C = (dr.gather(Array3f64, c, t) for c in self.corners)
        res, dist = _closest_on_triangle(P, A, B, C)
        vox = (UInt32(iz) * ny + UInt32(iy)) * nx + UInt32(ix)
        dr.eval(res, dist, vox)
        cp = np.stack([np.asarray(res[k]) for k in range(3)], axis=1)
        return np.asarray(vox).astype(np.int64), cp, np.asarray(dist)


# ------------------------------------------------------------------------------------ mesh → grid
def mesh_bounds(vertices) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    return v.min(axis=0), v.max(axis=0)


def _validate_mesh(vertices, faces):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise ValueError(f"mesh vertices must be (V >= 3, 3) (got shape {v.shape})")
    if not np.all(np.isfinite(v)):
        raise ValueError("mesh vertices must be finite")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(
            f"mesh faces must be (F >= 1, 3) integer indices (got shape {f.shape}, dtype {f.dtype})"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"mesh faces index vertices outside [0, {len(v) - 1}]")
    return v, f.astype(np.int64)


def _subdivide(tri: np.ndarray, max_edge: float) -> np.ndarray:
    """Split triangles (T, 3, 3) at the midpoint of their longest edge until every edge ≤ max_edge."""
    out = []
    todo = tri
    for _ in range(64):
        e = np.stack(
            [
                np.linalg.norm(todo[:, 1] - todo[:, 0], axis=1),
                np.linalg.norm(todo[:, 2] - todo[:, 1], axis=1),
                np.linalg.norm(todo[:, 0] - todo[:, 2], axis=1),
            ],
            axis=1,
        )
        big = e.max(axis=1) > max_edge
        out.append(todo[~big])
        if not np.any(big):
            break
        t = todo[big]
        k = np.argmax(e[big], axis=1)
        # rotate so that the longest edge is (v0, v1)
        idx = np.stack([k, (k + 1) % 3, (k + 2) % 3], axis=1)
        t = np.take_along_axis(t, idx[:, :, None], axis=1)
        m = 0.5 * (t[:, 0] + t[:, 1])
        todo = np.concatenate(
            [np.stack([t[:, 0], m, t[:, 2]], axis=1), np.stack([m, t[:, 1], t[:, 2]], axis=1)]
        )
    else:
        out.append(todo)
    return np.concatenate(out)


_JITTER = (1e-4 * math.sqrt(2.0), 1e-4 * math.sqrt(3.0))
SIGN_MODES = ("parity", "flood", "unsigned")


def mesh_sdf_grid(
    vertices,
    faces,
    origin,
    voxel: float,
    shape,
    *,
    band: float = 2.0,
    sign: str = "parity",
    chunk_pairs: int = 1 << 21,
) -> SdfGrid:
    """Signed distance of a triangle mesh at the cell centres of the grid (origin, voxel, shape=(nx, ny, nz)).

    See the module docstring for the method. ``band`` (voxels, ≥ 1): width of the exactly computed band.
    ``sign``: "parity" (watertight meshes; a one-line ValueError otherwise), "flood" (fallback for open
    meshes), "unsigned".
    """
    from scipy import ndimage

    v, f = _validate_mesh(vertices, faces)
    if sign not in SIGN_MODES:
        raise ValueError(f"sign must be one of {SIGN_MODES} (got {sign!r})")
    if not (band >= 1.0 and math.isfinite(band)):
        raise ValueError(f"band must be >= 1 voxel (got {band!r})")
    nx, ny, nz = (int(c) for c in shape)
    if min(nx, ny, nz) < 2:
        raise ValueError(f"shape must have >= 2 cells per axis (got {shape!r})")
    h = float(voxel)
    o = np.asarray(origin, dtype=np.float64)
    nvox = nx * ny * nz
    best_d = np.full(nvox, np.inf)
    best_p = np.zeros((nvox, 3))

    tri = _subdivide(v[f], 8.0 * h)
    lo = np.floor((tri.min(axis=1) - band * h - o) / h - 0.5).astype(np.int64)
    hi = np.ceil((tri.max(axis=1) + band * h - o) / h - 0.5).astype(np.int64)
    lo = np.clip(lo, 0, [nx - 1, ny - 1, nz - 1])
    hi = np.clip(hi, 0, [nx - 1, ny - 1, nz - 1])
    ext = np.maximum(hi - lo + 1, 0)
    counts = ext.prod(axis=1)
    if nvox >= 1 << 31:
        raise ValueError(f"a grid of {nvox} cells: at most 2^31 - 1 (its cell indices are 32-bit)")
    table = _BandTriangles(tri, lo, ext)
    start = 0
    cum = np.cumsum(counts)
    while start < len(tri):
        base = cum[start - 1] if start > 0 else 0
        stop = int(np.searchsorted(cum, base + chunk_pairs, side="right"))
        stop = max(stop, start + 1)
        sel = np.arange(start, stop)
        cnt = counts[sel]
        t_id = np.repeat(sel, cnt)
        local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        vox, cp, d = table.pairs(t_id, local, o, h, (nx, ny, nz))
        keep = d <= band * h  # pairs outside the band cannot win a band cell
        vox, d, cp = vox[keep], d[keep], cp[keep]
        np.minimum.at(best_d, vox, d)
        win = d == best_d[vox]  # ties: any winner (same distance)
        best_p[vox[win]] = cp[win]
        start = stop

    in_band = best_d <= band * h
    if not np.any(in_band):
        raise ValueError(
            "the mesh does not come within the band of any grid cell (grid and mesh do not overlap)"
        )
    # Closest-point propagation beyond the band.
    mask3 = in_band.reshape(nz, ny, nx)
    idx: Any = ndimage.distance_transform_edt(~mask3, return_distances=False, return_indices=True)
    src3 = ((idx[0] * ny + idx[1]) * nx + idx[2]).astype(np.int64)
    del idx
    far_d = _propagate_closest_points(best_p, src3.reshape(-1), o, h, (nx, ny, nz))
    best_d = np.where(in_band, best_d, far_d)
    dist = best_d.reshape(nz, ny, nx)

    meta = {"source": "mesh", "triangles": len(f), "band_voxels": float(band), "sign": sign}
    if sign == "unsigned":
        return SdfGrid(dist.astype(np.float32), tuple(o), h, meta=meta)
    inside, odd_columns = _parity_inside(v[f], o, h, (nx, ny, nz))
    meta["odd_columns"] = int(odd_columns)
    if sign == "parity":
        if odd_columns:
            raise ValueError(
                f"mesh is not watertight: {odd_columns} grid column(s) cross its surface an odd "
                "number of times (use sign='flood' for the documented fallback, or 'unsigned')"
            )
    else:
        inside = _flood_inside(dist, h)
    return SdfGrid(np.where(inside, -dist, dist).astype(np.float32), tuple(o), h, meta=meta)


def _propagate_closest_points(best_p, src, o, h, shape, sweeps: int = 2) -> np.ndarray:
    """Distance of every cell centre to the closest surface point held by its source cell ``src`` (the
    nearest band cell, from the Euclidean distance transform), then ``sweeps`` Jacobi sweeps in which each
    cell also tries the points held by its 6 neighbours' sources and keeps the nearest. Every candidate is
    a true surface point, so each value is an upper bound of the exact distance that the sweeps can only
    lower; they fix the cells where the nearest band cell does not hold the nearest surface point (near
    medial sheets). One Dr.Jit LLVM kernel per sweep over all cells (float32, as the grid is stored).
    Returns the distances (flat, float64)."""
    nx, ny, nz = shape
    n = nx * ny * nz
    pts = [to_drjit(Float, best_p[:, k]) for k in range(3)]
    S = to_drjit(UInt32, src)
    idx = dr.arange(Int32, n)
    coords = (idx % nx, (idx // nx) % ny, idx // (nx * ny))
    centre = Array3f(*[o[k] + (Float(coords[k]) + 0.5) * h for k in range(3)])

    def dist(s):
        return dr.norm(centre - Array3f(*[dr.gather(Float, pts[k], s) for k in range(3)]))

    d = dist(S)
    dr.eval(d)
    for _ in range(sweeps):
        best_s, best = S, d
        for axis, stride, size in ((0, 1, nx), (1, nx, ny), (2, nx * ny, nz)):
            for step in (-1, 1):
                ok = (coords[axis] + step >= 0) & (coords[axis] + step < size)
                cand = dr.gather(UInt32, S, UInt32(dr.select(ok, idx + step * stride, idx)))
                dc = dist(cand)
                better = dc < best
                best = dr.select(better, dc, best)
                best_s = dr.select(better, cand, best_s)
        S, d = best_s, best
        dr.eval(S, d)
    return np.asarray(d, dtype=np.float64)


def _parity_inside(tri, o, h, shape):
    """Inside/outside of every cell centre from the parity of crossings along +z; also the number of
    columns with an odd total count (not watertight)."""
    nx, ny, nz = shape
    jx, jy = _JITTER[0] * h, _JITTER[1] * h
    x0, y0, z0 = o[0] + 0.5 * h + jx, o[1] + 0.5 * h + jy, o[2] + 0.5 * h
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ilo = np.clip(np.ceil((tri[:, :, 0].min(axis=1) - x0) / h), 0, nx).astype(np.int64)
    ihi = np.clip(np.floor((tri[:, :, 0].max(axis=1) - x0) / h), -1, nx - 1).astype(np.int64)
    jlo = np.clip(np.ceil((tri[:, :, 1].min(axis=1) - y0) / h), 0, ny).astype(np.int64)
    jhi = np.clip(np.floor((tri[:, :, 1].max(axis=1) - y0) / h), -1, ny - 1).astype(np.int64)
    ex = np.maximum(ihi - ilo + 1, 0)
    ey = np.maximum(jhi - jlo + 1, 0)
    cnt = ex * ey
    hist = np.zeros((ny * nx, nz + 1), np.int32)
    total = np.zeros(ny * nx, np.int64)
    cum = np.cumsum(cnt)
    start = 0
    while start < len(tri):
        base = cum[start - 1] if start > 0 else 0
        stop = max(int(np.searchsorted(cum, base + (1 << 21), side="right")), start + 1)
        sel = np.arange(start, stop)
        c_sel = cnt[sel]
        t = np.repeat(sel, c_sel)
        local = np.arange(int(c_sel.sum())) - np.repeat(np.cumsum(c_sel) - c_sel, c_sel)
        i = ilo[t] + local % ex[t]
        j = jlo[t] + local // np.maximum(ex[t], 1)
        px = x0 + i * h
        py = y0 + j * h
        # 2-D barycentric coordinates in xy (edge functions); a hit needs all of one sign.
        ax, ay, bx, by, cx, cy = a[t, 0], a[t, 1], b[t, 0], b[t, 1], c[t, 0], c[t, 1]
        w0 = (bx - px) * (cy - py) - (by - py) * (cx - px)
        w1 = (cx - px) * (ay - py) - (cy - py) * (ax - px)
        w2 = (ax - px) * (by - py) - (ay - py) * (bx - px)
        area = w0 + w1 + w2
        hit = (area != 0) & (((w0 > 0) & (w1 > 0) & (w2 > 0)) | ((w0 < 0) & (w1 < 0) & (w2 < 0)))
        zh = (w0 * a[t, 2] + w1 * b[t, 2] + w2 * c[t, 2])[hit] / area[hit]
        col = (j * nx + i)[hit]
        k = np.clip(np.floor((zh - z0) / h).astype(np.int64) + 1, 0, nz)
        np.add.at(hist, (col, k), 1)
        np.add.at(total, col, 1)
        start = stop
    inside = np.cumsum(hist, axis=1)[:, :nz] % 2 == 1  # (ny*nx, nz)
    inside = inside.reshape(ny, nx, nz).transpose(2, 0, 1)
    return inside, int(np.count_nonzero(total % 2))


def _flood_inside(dist, h):
    from scipy import ndimage

    far = dist > 0.5 * math.sqrt(3.0) * h
    lab, _ = cast(tuple[Any, int], ndimage.label(far))  # (labels, count): no ``output`` given
    border = np.unique(
        np.concatenate(
            [
                lab[0].ravel(),
                lab[-1].ravel(),
                lab[:, 0].ravel(),
                lab[:, -1].ravel(),
                lab[:, :, 0].ravel(),
                lab[:, :, -1].ravel(),
            ]
        )
    )
    border = border[border > 0]
    outside_far = np.isin(lab, border)
    inside_far = far & ~outside_far
    idx: Any = ndimage.distance_transform_edt(~far, return_distances=False, return_indices=True)
    near_inside = inside_far[idx[0], idx[1], idx[2]]
    return np.where(far, inside_far, near_inside)


# ------------------------------------------------------------------------------------ mips, 8 bit
def _downsample2(a: np.ndarray) -> np.ndarray:
    nz, ny, nx = a.shape
    a = a[: nz - nz % 2, : ny - ny % 2, : nx - nx % 2]
    return a.reshape(nz // 2, 2, ny // 2, 2, nx // 2, 2).mean(axis=(1, 3, 5))


def build_mips(grid: SdfGrid, levels: int, *, prefilter: bool = True, sigma: float = 1.0) -> list[SdfGrid]:
    """Mip chain of ``levels`` grids (level 0 = ``grid``); see the module docstring. Stops early when an
    axis would drop below 2 cells. ``sigma`` in voxels of the finer level (> 0)."""
    from scipy import ndimage

    if not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ValueError(f"levels must be an integer >= 1 (got {levels!r})")
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"sigma must be > 0 (got {sigma!r})")
    out = [grid]
    cur = grid.values.astype(np.float64)
    h = grid.voxel
    for _ in range(1, levels):
        if min(cur.shape) < 4:
            break
        if prefilter:
            cur = ndimage.gaussian_filter(cur, sigma=sigma, mode="nearest", truncate=3.0)
        cur = _downsample2(cur)
        h *= 2.0
        out.append(
            SdfGrid(
                cur.astype(np.float32),
                grid.origin,
                h,
                quantized=grid.quantized,
                quant_step=grid.quant_step,
                meta={**grid.meta, "prefilter": prefilter},
            )
        )
    return out


def quantize_8bit(grid: SdfGrid, step_voxels: float = 1.0) -> SdfGrid:
    """8-bit storage as in the seed (Listing 2, 000:3030-3041): q = clip(round(s/(step·h)), −127, 127) + 128
    stored in a byte, read back as (q − 128)·step·h. ``step_voxels`` = 1 is the seed's (one voxel per code,
    distances clamped to ±127 voxels); the rounding error is ≤ step·h/2."""
    if not (step_voxels > 0 and math.isfinite(step_voxels)):
        raise ValueError(f"step_voxels must be > 0 (got {step_voxels!r})")
    q = np.clip(np.rint(grid.values.astype(np.float64) / (step_voxels * grid.voxel)), -127, 127) + 128
    q = q.astype(np.uint8)
    back = (q.astype(np.float64) - 128.0) * step_voxels * grid.voxel
    return SdfGrid(
        back.astype(np.float32),
        grid.origin,
        grid.voxel,
        quantized=True,
        quant_step=float(step_voxels),
        meta={**grid.meta, "bytes": int(q.nbytes)},
    )


def sample_grid_numpy(grid: SdfGrid, points) -> np.ndarray:
    """Trilinear sample (float64) at (N, 3) points with the clamp-plus-distance rule (reference helper)."""
    p = np.asarray(points, dtype=np.float64)
    nx, ny, nz = grid.shape
    u = (p - np.asarray(grid.origin)) / grid.voxel - 0.5
    n = np.array([nx, ny, nz], dtype=np.float64)
    uc = np.clip(u, 0.0, n - 1.0)
    outside = np.linalg.norm((u - uc) * grid.voxel, axis=-1)
    i0 = np.minimum(np.floor(uc).astype(np.int64), (n - 2).astype(np.int64))
    f = uc - i0
    v = grid.values.astype(np.float64)
    acc = 0.0
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                w = (
                    (f[..., 0] if dx else 1 - f[..., 0])
                    * (f[..., 1] if dy else 1 - f[..., 1])
                    * (f[..., 2] if dz else 1 - f[..., 2])
                )
                acc = acc + w * v[i0[..., 2] + dz, i0[..., 1] + dy, i0[..., 0] + dx]
    return acc + outside
