"""Ground truth for parallax occlusion mapping: the height field as a displaced Mitsuba mesh, exact
first hits along view rays (``Scene.ray_intersect``: noise-free), and the irradiance at those hits from a
rectangular area light with Monte Carlo visibility (path-traced penumbrae).

This module never sees the real-time code: the caller samples the height field (its one kernel text,
`rtfit.realtime.parallax_occlusion`) on a grid and passes the grid; the mesh interpolates it linearly
over two triangles per cell, so its own error shrinks as Δ² (measured in the experiment by comparing two
grid spacings).

Frame: tangent space of the POM kernels, texture units = scene units; the surface is
z = −s·(1 − h(x, y)) with s the height-map range.

A user's shape (`rtfit audit`): `bump_texture` finds the texture of a ``bumpmap`` BSDF, `texture_texels` and
`texture_values` read it and evaluate it with Mitsuba's own lookup, and `displaced_shape` builds the shape
displaced along its normals by that height field — a grid over the shape's UV range, each vertex
``shape.eval_parameterization(uv)`` moved by −depth·(1 − h(uv))·n (h from Mitsuba's ``eval_1``): the carved
surface whose first hits along the camera's pixel-centre rays (`pixel_surface`, `exact_hits`) are the
reference of the parallax-occlusion audit.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from .device_arrays import device_vectors, mapped_floats

__all__ = [
    "DisplacedShape",
    "HeightFieldMesh",
    "LightVisibility",
    "PixelSurface",
    "area_light_visibility",
    "bump_kind",
    "bump_texture",
    "displaced_hits",
    "displaced_shape",
    "emitter_visibility",
    "exact_hits",
    "height_field_scene",
    "height_field_shapes",
    "mesh_scene",
    "pixel_surface",
    "rectangle_light",
    "square_irradiance",
    "square_solid_angle",
    "texture_texels",
    "texture_values",
    "uv_range",
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
    return _mesh_of(mi, "heightfield", pos.T, _grid_faces(ny, nx))


def _grid_faces(ny: int, nx: int) -> np.ndarray:
    """(F, 3) two triangles per cell of an (ny, nx) vertex grid (row-major vertex indices)."""
    i = np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + nx, i.ravel() + nx + 1
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)], axis=0)


def _mesh_of(mi, name: str, positions: np.ndarray, faces: np.ndarray):
    """A Mitsuba mesh from ``positions`` (N, 3) and ``faces`` (F, 3)."""
    pos = np.ascontiguousarray(positions, np.float32)
    tri = np.ascontiguousarray(faces, np.uint32)
    mesh = mi.Mesh(name, pos.shape[0], tri.shape[0], has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(pos.ravel())
    params["faces"] = mi.UInt32(tri.ravel())
    params.update()
    return mesh


def mesh_scene(mi, positions: np.ndarray, faces: np.ndarray, name: str = "surface"):
    """A Mitsuba scene holding only the mesh (``positions`` (N, 3), ``faces`` (F, 3) vertex indices)."""
    return mi.load_dict({"type": "scene", "surface": _mesh_of(mi, name, positions, faces)})


def height_field_scene(mi, grid: HeightFieldMesh):
    """A Mitsuba scene holding only the displaced mesh (visibility and first hits need no emitter: the
    area light is sampled here, `area_light_visibility`)."""
    return mi.load_dict({"type": "scene", "surface": _mesh(mi, grid)})


def exact_hits(mi, scene, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First hits of rays (float64 in, float32 Mitsuba): positions (N, 3), the hit triangles' geometric
    normals (N, 3, facing +z) and a validity mask (N,)."""
    o = device_vectors(mi, mi.Point3f, origins)
    dv = device_vectors(mi, mi.Vector3f, dirs)
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
        o = device_vectors(mi, mi.Point3f, x)
        dv = device_vectors(mi, mi.Vector3f, d)
        ray = mi.Ray3f(o, dv)
        ray.maxt = 0.999  # the segment x → y (d unnormalised)
        occluded = np.array(scene.ray_test(ray), dtype=bool).reshape(-1)
        e_o = np.where(occluded, 0.0, e_u)
        for j, val in enumerate((e_u, e_o, e_u * e_u, e_o * e_o, e_u * e_o)):
            sums[j] += np.bincount(idx, val, n_pts)
        done += k
    return _visibility(sums, samples)


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


# ------------------------------------------------------------------------------------------ a user's shape
def _children(mi, obj) -> dict:
    """The objects ``obj`` holds (``traverse``'s ``put_object``: a BSDF's nested BSDF and textures)."""

    class _Objects(mi.TraversalCallback):
        def __init__(self):
            super().__init__()
            self.found = {}

        def put_object(self, name, child, flags):
            self.found[name] = child

        def put(self, name, value, *args, **kwargs):
            if isinstance(value, mi.Object):
                self.found[name] = value

        def put_parameter(self, *args, **kwargs):
            pass

    cb = _Objects()
    obj.traverse(cb)
    return cb.found


def bump_texture(mi, bsdf, depth: int = 0):
    """The texture of the ``bumpmap`` that is ``bsdf`` or that a ``twosided`` ``bsdf`` wraps (None without
    one): the height field the bump map perturbs the normals with."""
    if bsdf is None or depth > 4:
        return None
    name = str(bsdf.class_name())
    kids = _children(mi, bsdf)
    if name == "BumpMap":
        return kids.get("nested_texture")
    if name == "TwoSidedBRDF":
        for child in kids.values():
            if isinstance(child, mi.BSDF):
                found = bump_texture(mi, child, depth + 1)
                if found is not None:
                    return found
    return None


def bump_kind(mi, bsdf, depth: int = 0) -> str:
    """What ``bsdf`` (or the BSDF a ``twosided`` wraps) offers as a height field: ``"bitmap"`` (a bumpmap of a
    bitmap texture), ``"texture"`` (a bumpmap of another texture), ``"normalmap"`` or ``""`` (neither)."""
    if bsdf is None or depth > 4:
        return ""
    name = str(bsdf.class_name())
    if name == "NormalMap":
        return "normalmap"
    if name == "BumpMap":
        tex = bump_texture(mi, bsdf)
        return "bitmap" if tex is not None and "data" in mi.traverse(tex) else "texture"
    if name == "TwoSidedBRDF":
        kinds = [bump_kind(mi, c, depth + 1) for c in _children(mi, bsdf).values() if isinstance(c, mi.BSDF)]
        return next((k for k in kinds if k), "")
    return ""


def height_field_shapes(mi, shapes) -> list:
    """The shapes among ``shapes`` whose BSDF is a bumpmap of a bitmap (`bump_kind`), in their order, except
    that shapes of a scene built from an rtfit TOML file (ids ``xml<i>_<j>``) are ordered by (i, j): the
    order of its scene dict (`rtfit.reference.build.mitsuba_scene_dict`), which Mitsuba does not keep."""
    found = [s for s in shapes if bump_kind(mi, s.bsdf()) == "bitmap"]
    keys = [re.fullmatch(r"xml(\d+)_(\d+)", str(s.id())) for s in found]
    if found and all(keys):
        order = sorted(range(len(found)), key=lambda k: (int(keys[k].group(1)), int(keys[k].group(2))))  # type: ignore[union-attr]
        found = [found[k] for k in order]
    return found


_LUMINANCE = (0.212671, 0.715160, 0.072169)
"""Mitsuba's ``luminance`` weights: a texture's one-channel value (``eval_1``) of RGB texels."""


def texture_texels(mi, texture) -> np.ndarray:
    """The texels of a ``bitmap`` ``texture`` (H, W), float64: its ``data`` as Mitsuba holds it (after its own
    sRGB decoding unless ``raw``), one channel as is, RGB as the luminance ``eval_1`` returns."""
    params = mi.traverse(texture)
    if "data" not in params:
        raise ValueError(f"{texture.class_name()} has no texels (not a bitmap)")
    data = np.array(params["data"], np.float64)
    if data.ndim == 2:
        return data
    if data.shape[-1] == 1:
        return data[..., 0]
    return data[..., :3] @ np.array(_LUMINANCE)


def texture_values(mi, texture, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``texture.eval_1`` at texture coordinates (u, v) (before the texture's ``to_uv``: the shape's own),
    float64 (N,): Mitsuba's own lookup (filter, wrap mode, transform)."""
    import drjit as dr

    n = int(np.size(u))
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(
        np.ascontiguousarray(u, np.float32).ravel(), np.ascontiguousarray(v, np.float32).ravel()
    )
    return np.array(texture.eval_1(si), np.float64).reshape(-1)


def uv_range(mi, shape) -> tuple[float, float, float, float]:
    """(u0, u1, v0, v1): the UV box of a mesh's texture coordinates, else the unit square."""
    if shape.is_mesh() and shape.has_vertex_texcoords():
        t = np.array(shape.vertex_texcoords_buffer(), np.float64).reshape(-1, 2)
        return float(t[:, 0].min()), float(t[:, 0].max()), float(t[:, 1].min()), float(t[:, 1].max())
    return 0.0, 1.0, 0.0, 1.0


@dataclass(frozen=True)
class DisplacedShape:
    """A shape displaced along its normals by a height field: ``positions`` (N, 3) and ``faces`` (F, 3) of
    the carved mesh, the ``cells`` (nu, nv) of its UV grid over ``uv_range`` (u0, u1, v0, v1) and ``spacing``
    (the larger UV step)."""

    positions: np.ndarray
    faces: np.ndarray
    cells: tuple[int, int]
    uv_range: tuple[float, float, float, float]
    spacing: float

    def scene(self, mi):
        return mesh_scene(mi, self.positions, self.faces, "displaced")

    def vertex_uv(self) -> np.ndarray:
        """(N, 2): the shape's (u, v) of each vertex of the grid (row-major over v, then u)."""
        u0, u1, v0, v1 = self.uv_range
        nu, nv = self.cells
        uu, vv = np.meshgrid(np.linspace(u0, u1, nu + 1), np.linspace(v0, v1, nv + 1))
        return np.stack([uu.ravel(), vv.ravel()], axis=1)


def displaced_hits(mi, displaced: DisplacedShape, scene, origins: np.ndarray, dirs: np.ndarray):
    """First hits of rays on the displaced mesh (``scene``: ``displaced.scene(mi)``): positions (N, 3), the
    hit triangles' geometric normals (N, 3, unoriented), the shape's (u, v) there (N, 2: the barycentric
    coordinates of the hit in its triangle, from the float64 vertex positions, interpolating the vertices'
    `DisplacedShape.vertex_uv`) and a validity mask (N,)."""
    o = device_vectors(mi, mi.Point3f, origins)
    dv = device_vectors(mi, mi.Vector3f, dirs)
    si = scene.ray_intersect(mi.Ray3f(o, dv))
    p = np.array(si.p, dtype=np.float64).T.reshape(-1, 3)
    n = np.array(si.n, dtype=np.float64).T.reshape(-1, 3)
    valid = np.array(si.is_valid(), dtype=bool).reshape(-1)
    prim = np.where(valid, np.array(si.prim_index, dtype=np.int64).reshape(-1), 0)
    tri = displaced.faces[prim]
    a, b, c = (displaced.positions[tri[:, k]] for k in range(3))
    e1, e2, r = b - a, c - a, p - a
    d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", r, e1), np.einsum("ij,ij->i", r, e2)
    det = d11 * d22 - d12 * d12
    det = np.where(np.abs(det) > 0, det, 1.0)
    beta = (d22 * r1 - d12 * r2) / det
    gamma = (d11 * r2 - d12 * r1) / det
    uv = displaced.vertex_uv()
    t_a, t_b, t_c = (uv[tri[:, k]] for k in range(3))
    uv_hit = t_a + beta[:, None] * (t_b - t_a) + gamma[:, None] * (t_c - t_a)
    return p, n, uv_hit, valid


def emitter_visibility(
    mi, emitter, occluders, points: np.ndarray, normals: np.ndarray, samples: int, seed: int = 0,
    offset: float = 1e-4, chunk: int = 1 << 18,
) -> LightVisibility:  # fmt: skip
    """`LightVisibility` of a Mitsuba area ``emitter`` at ``points`` with unit ``normals``. Each of the
    ``samples`` per point is Mitsuba's own light sampling (``emitter.sample_direction``: a point y on the
    emitter and its weight L_e/pdf in solid angle, zero where y faces away); it adds weight·max(n·ω, 0)
    (the mean of the RGB channels) to E_unoccluded and, where ``occluders.ray_test`` finds nothing between
    the point (offset by ``offset`` along n) and y, to E_occluded. Uniform 2D samples from NumPy's PCG64
    with ``seed``; float64 accumulation; V = E_occ/E_unocc with its delta-method standard error (paired
    samples, as `area_light_visibility`)."""
    n_pts = points.shape[0]
    rng = np.random.default_rng(seed)
    sums = np.zeros((5, n_pts))
    per = max(1, chunk // max(n_pts, 1))
    done = 0
    while done < samples:
        k = min(per, samples - done)
        idx = np.repeat(np.arange(n_pts), k)
        x = points[idx] + offset * normals[idx]
        it = mi.Interaction3f()
        it.p = device_vectors(mi, mi.Point3f, x)
        u = rng.random((idx.size, 2))
        ds, weight = emitter.sample_direction(
            it, mi.Point2f(mapped_floats(mi.Float, u[:, 0]), mapped_floats(mi.Float, u[:, 1]))
        )
        y = np.array(ds.p, np.float64).T.reshape(-1, 3)
        w = np.array(weight, np.float64).T.reshape(idx.size, -1).mean(axis=1)
        d = y - x
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        cos_x = np.maximum(np.einsum("ij,ij->i", normals[idx], d) / np.where(r > 0, r, 1.0), 0.0)
        e_u = np.where(np.isfinite(w), w, 0.0) * cos_x
        dv = device_vectors(mi, mi.Vector3f, d)
        ray = mi.Ray3f(it.p, dv)
        ray.maxt = 0.999  # the segment x → y (d unnormalised)
        occluded = np.array(occluders.ray_test(ray), dtype=bool).reshape(-1)
        e_o = np.where(occluded, 0.0, e_u)
        for j, val in enumerate((e_u, e_o, e_u * e_u, e_o * e_o, e_u * e_o)):
            sums[j] += np.bincount(idx, val, n_pts)
        done += k
    return _visibility(sums, samples)


def _visibility(sums: np.ndarray, samples: int) -> LightVisibility:
    """`LightVisibility` from the sums of E_u, E_o, E_u², E_o², E_u·E_o over ``samples`` paired samples."""
    m = float(samples)
    mu, mo = sums[0] / m, sums[1] / m
    vu = np.maximum(sums[2] / m - mu * mu, 0.0)
    vo = np.maximum(sums[3] / m - mo * mo, 0.0)
    cuo = sums[4] / m - mu * mo
    safe = np.where(mu > 0, mu, 1.0)
    vis = np.where(mu > 0, mo / safe, 1.0)
    var = (vo - 2.0 * vis * cuo + vis * vis * vu) / (safe * safe) / m
    return LightVisibility(mu, mo, vis, np.sqrt(np.maximum(var, 0.0)), samples)


def displaced_shape(mi, shape, texture, depth: float, side: float, cells: tuple[int, int]) -> DisplacedShape:
    """``shape`` carved by the height field of ``texture``: a (nu + 1) × (nv + 1) vertex grid over its UV
    range (`uv_range`), each vertex p(u, v) (``eval_parameterization``) moved by −side·d·(1 − h)·n(u, v),
    d = ``depth`` (the height range, scene units), h Mitsuba's ``eval_1`` of the texture, n the shading
    normal, ``side`` ±1 (the face the camera sees). Triangles with a vertex outside the shape's UV charts, or
    longer than 8× the median (a cell spanning two charts), are left out."""
    import drjit as dr

    u0, u1, v0, v1 = uv_range(mi, shape)
    nu, nv = cells
    uu, vv = np.meshgrid(np.linspace(u0, u1, nu + 1), np.linspace(v0, v1, nv + 1))
    uv = mi.Point2f(
        np.ascontiguousarray(uu, np.float32).ravel(), np.ascontiguousarray(vv, np.float32).ravel()
    )
    si = shape.eval_parameterization(uv)
    dr.eval(si.p, si.sh_frame.n)
    p = np.array(si.p, np.float64).T.reshape(-1, 3)
    n = np.array(si.sh_frame.n, np.float64).T.reshape(-1, 3)
    valid = np.array(si.is_valid(), bool).reshape(-1) & np.all(np.isfinite(p), axis=1)
    h = texture_values(mi, texture, uu, vv)
    pos = p - (side * depth * (1.0 - h))[:, None] * n
    faces = _grid_faces(nv + 1, nu + 1)
    keep = valid[faces].all(axis=1)
    edges = np.stack(
        [np.linalg.norm(pos[faces[:, a]] - pos[faces[:, b]], axis=1) for a, b in ((0, 1), (1, 2), (2, 0))], 1
    )
    longest = edges.max(axis=1)
    if keep.any():
        keep &= longest <= 8.0 * np.median(longest[keep])
    pos = np.where(valid[:, None], pos, 0.0)
    spacing = max((u1 - u0) / nu, (v1 - v0) / nv)
    return DisplacedShape(pos, faces[keep], (nu, nv), (u0, u1, v0, v1), spacing)


@dataclass(frozen=True)
class PixelSurface:
    """The pixel-centre camera rays (``origins``, ``dirs``: (H·W, 3), float64) and what they hit first on
    the user's scene: ``on_shape`` (H·W,) True where that is the given shape, and there the hit ``p``, its
    ``uv``, ``dp_du``, ``dp_dv`` and the shading normal ``n``."""

    origins: np.ndarray
    dirs: np.ndarray
    on_shape: np.ndarray
    p: np.ndarray
    uv: np.ndarray
    dp_du: np.ndarray
    dp_dv: np.ndarray
    n: np.ndarray


def pixel_surface(mi, scene, sensor, shape) -> PixelSurface:
    """`PixelSurface` of ``sensor``'s pixel-centre rays (film crop size, rays through (x + ½, y + ½)) on
    ``scene``, for ``shape``."""
    import drjit as dr

    width, height = sensor.film().crop_size()
    idx = np.arange(width * height)
    x = ((idx % width) + 0.5) / width
    y = ((idx // width) + 0.5) / height
    ray, _ = sensor.sample_ray(
        0.0, 0.5, mi.Point2f(x.astype(np.float32), y.astype(np.float32)), mi.Point2f(0.5, 0.5)
    )
    si = scene.ray_intersect(ray)
    on = si.is_valid() & (si.shape == mi.ShapePtr(shape))
    dr.eval(si.p, si.uv, si.dp_du, si.dp_dv, si.sh_frame.n, on, ray.o, ray.d)

    def arr(v, c=3):
        return np.array(v, np.float64).T.reshape(-1, c)

    return PixelSurface(
        arr(ray.o),
        arr(ray.d),
        np.array(on, bool).reshape(-1),
        arr(si.p),
        arr(si.uv, 2),
        arr(si.dp_du),
        arr(si.dp_dv),
        arr(si.sh_frame.n),
    )
