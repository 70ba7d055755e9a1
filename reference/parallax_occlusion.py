"""Ground truth for parallax occlusion mapping: the height field as a displaced Mitsuba mesh, exact
first hits along view rays (``Scene.ray_intersect``: noise-free), and the irradiance at those hits from a
rectangular area light with Monte Carlo visibility (path-traced penumbrae).

This module never sees the real-time code: the caller samples the height field (its one kernel text,
`rtfit.realtime.parallax_occlusion`) on a grid and passes the grid; the mesh interpolates it linearly
over two triangles per cell, so its own error shrinks as Δ² (measured in the experiment by comparing two
grid spacings).

Frame: tangent space of the POM kernels, texture units = scene units; the surface is
z = −s·(1 − h(x, y)) with s the height-map range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "HeightFieldMesh",
    "LightVisibility",
    "area_light_visibility",
    "exact_hits",
    "height_field_scene",
    "rectangle_light",
    "square_irradiance",
    "square_solid_angle",
]


@dataclass(frozen=True)
class HeightFieldMesh:
    """A displaced grid: heights ``h`` (ny, nx) ∈ [0, 1] at x = linspace(x0, x1, nx), y = linspace(y0, y1,
    ny); surface z = −scale·(1 − h)."""

    h: np.ndarray
    x0: float
    x1: float
    y0: float
    y1: float
    scale: float

    @property
    def spacing(self) -> float:
        """The larger grid spacing Δ (scene units)."""
        ny, nx = self.h.shape
        return max((self.x1 - self.x0) / (nx - 1), (self.y1 - self.y0) / (ny - 1))


def _mesh(mi, grid: HeightFieldMesh):
    ny, nx = grid.h.shape
    xs = np.linspace(grid.x0, grid.x1, nx)
    ys = np.linspace(grid.y0, grid.y1, ny)
    X, Y = np.meshgrid(xs, ys)
    Z = -grid.scale * (1.0 - grid.h)
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=0).astype(np.float32)
    i = np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + nx, i.ravel() + nx + 1
    faces = np.concatenate([np.stack([a, b, d], 0), np.stack([a, d, c], 0)], axis=1).astype(np.uint32)
    mesh = mi.Mesh("heightfield", nx * ny, faces.shape[1], has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(pos.T.ravel())
    params["faces"] = mi.UInt32(faces.T.ravel())
    params.update()
    return mesh


def height_field_scene(mi, grid: HeightFieldMesh):
    """A Mitsuba scene holding only the displaced mesh (visibility and first hits need no emitter: the
    area light is sampled here, `area_light_visibility`)."""
    return mi.load_dict({"type": "scene", "surface": _mesh(mi, grid)})


def exact_hits(mi, scene, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of rays (float64 in, float32 Mitsuba): positions (N, 3), the hit triangles' geometric
    normals (N, 3, facing +z) and a validity mask (N,)."""
    o = mi.Point3f(*[mi.Float(np.ascontiguousarray(origins[:, k], np.float32)) for k in range(3)])
    dv = mi.Vector3f(*[mi.Float(np.ascontiguousarray(dirs[:, k], np.float32)) for k in range(3)])
    si = scene.ray_intersect(mi.Ray3f(o, dv))
    p = np.array(si.p, dtype=np.float64).T.reshape(-1, 3)
    n = np.array(si.n, dtype=np.float64).T.reshape(-1, 3)
    n = np.where(n[:, 2:3] < 0, -n, n)
    valid = np.array(si.is_valid(), dtype=bool).reshape(-1)
    return p, n, valid


@dataclass(frozen=True)
class LightVisibility:
    """Irradiance at points from the area light: unoccluded and occluded means (W/m²) over ``samples``
    light samples each, the visibility ratio V = E_occ/E_unocc and its standard error (delta method on
    the paired samples)."""

    e_unoccluded: np.ndarray
    e_occluded: np.ndarray
    visibility: np.ndarray
    visibility_stderr: np.ndarray
    samples: int


def area_light_visibility(
    mi, scene, points: np.ndarray, normals: np.ndarray, light: dict, samples: int, seed: int = 0,
    chunk: int = 1 << 18,
) -> LightVisibility:  # fmt: skip
    """E = ∫ L_e·V·max(n·ω, 0) dω over a square light (`rectangle_light`) by uniform area sampling:
    each sample y on the square contributes L_e·A·max(n·ω, 0)·max(−n_l·ω, 0)/|y − x|² (ω = (y − x)/|y − x|,
    n_l the light's normal), times V from Mitsuba's ``ray_test`` between the point (offset 1e-4 along n)
    and y. The same samples without V give E_unoccluded. Float64 accumulation; uniform samples from
    NumPy's PCG64 with ``seed``."""
    n_pts = points.shape[0]
    rng = np.random.default_rng(seed)
    centre = np.asarray(light["center"], float)
    n_l = np.asarray(light["normal_to"], float) - centre
    n_l /= np.linalg.norm(n_l)
    a_axis = np.cross(n_l, [0.0, 1.0, 0.0] if abs(n_l[1]) < 0.9 else [1.0, 0.0, 0.0])
    a_axis /= np.linalg.norm(a_axis)
    b_axis = np.cross(n_l, a_axis)
    size = float(light["size"])
    le_area = float(light["radiance"]) * size * size
    sums = np.zeros((5, n_pts))
    per = max(1, chunk // max(n_pts, 1))
    done = 0
    while done < samples:
        k = min(per, samples - done)
        idx = np.repeat(np.arange(n_pts), k)
        x = points[idx] + 1e-4 * normals[idx]
        ab = (rng.random((idx.size, 2)) - 0.5) * size
        y = centre + ab[:, :1] * a_axis + ab[:, 1:] * b_axis
        d = y - x
        r2 = np.einsum("ij,ij->i", d, d)
        w = d / np.sqrt(r2)[:, None]
        cos_x = np.maximum(np.einsum("ij,ij->i", normals[idx], w), 0.0)
        cos_y = np.maximum(-(w @ n_l), 0.0)
        e_u = le_area * cos_x * cos_y / r2
        o = mi.Point3f(*[mi.Float(np.ascontiguousarray(x[:, j], np.float32)) for j in range(3)])
        dv = mi.Vector3f(*[mi.Float(np.ascontiguousarray(d[:, j], np.float32)) for j in range(3)])
        ray = mi.Ray3f(o, dv)
        ray.maxt = 0.999  # the segment x → y (d unnormalised)
        occluded = np.array(scene.ray_test(ray), dtype=bool).reshape(-1)
        e_o = np.where(occluded, 0.0, e_u)
        for j, val in enumerate((e_u, e_o, e_u * e_u, e_o * e_o, e_u * e_o)):
            sums[j] += np.bincount(idx, val, n_pts)
        done += k
    m = float(samples)
    mu, mo = sums[0] / m, sums[1] / m
    vu = np.maximum(sums[2] / m - mu * mu, 0.0)
    vo = np.maximum(sums[3] / m - mo * mo, 0.0)
    cuo = sums[4] / m - mu * mo
    safe = np.where(mu > 0, mu, 1.0)
    vis = np.where(mu > 0, mo / safe, 1.0)
    var = (vo - 2.0 * vis * cuo + vis * vis * vu) / (safe * safe) / m
    return LightVisibility(mu, mo, vis, np.sqrt(np.maximum(var, 0.0)), samples)


def rectangle_light(direction: np.ndarray, distance: float, size: float, radiance: float) -> dict:
    """A square light of side ``size`` centred at ``distance``·``direction`` from the tile centre (0.5, 0.5,
    0), facing it; its solid angle seen from the centre is ≈ size²/distance² (exact: `square_solid_angle`)."""
    c = np.array([0.5, 0.5, 0.0]) + distance * np.asarray(direction, float)
    return {"center": tuple(c), "normal_to": (0.5, 0.5, 0.0), "size": size, "radiance": radiance}


def square_solid_angle(size: float, distance: float) -> float:
    """Solid angle of a w × w square seen on its axis from distance D: 4·asin(a²/(1 + a²)), a = w/(2D)."""
    a = size / (2.0 * distance)
    return 4.0 * math.asin(a * a / (1.0 + a * a))


def square_irradiance(point: np.ndarray, normal: np.ndarray, light: dict) -> float:
    """Unoccluded irradiance (W/m²) at ``point`` with ``normal`` from the square light, in closed form
    (Lambert's polygon formula E = L_e/2·Σ_i β_i·(n·γ̂_i), β_i the angle each edge subtends and γ̂_i the
    unit normal of the plane through the point and that edge; exact while the whole square is above the
    point's tangent plane). The independent check of `area_light_visibility`'s Monte Carlo estimator."""
    centre = np.asarray(light["center"], float)
    n_l = np.asarray(light["normal_to"], float) - centre
    n_l /= np.linalg.norm(n_l)
    a = np.cross(n_l, [0.0, 1.0, 0.0] if abs(n_l[1]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n_l, a)
    h = 0.5 * float(light["size"])
    corners = [centre + h * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    rel = [c - np.asarray(point, float) for c in corners]
    total = 0.0
    for i in range(4):
        p, q = rel[i], rel[(i + 1) % 4]
        g = np.cross(p, q)
        beta = math.atan2(np.linalg.norm(g), float(p @ q))
        total += beta * float(np.asarray(normal, float) @ (g / np.linalg.norm(g)))
    return 0.5 * float(light["radiance"]) * abs(total)
