"""The G-buffer: camera rays through the pixel centres and the first surface each one hits.

A reference's pixel value and the G-buffer an approximation is evaluated on come from the same ray
(`rtfit.reference.estimators`' convention: point sampling at pixel centres): `pixel_rays` makes those rays
(for `estimators.radiance_pass` too), `gbuffer` traces them to their first hit, through the surfaces a
real-time renderer does not shade as opaque (`is_pass_through`: a medium's invisible boundary, a smooth
dielectric around a medium), and `gbuffer_points` turns its hits into the per-point estimators' probes.
`first_hit_shapes` and `uv_tangents` read more of the same first hits (the shape hit, its UV tangent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np


@dataclass(frozen=True)
class GBuffer:
    """Pixel-centre first hits. Arrays are (H, W, ·) float32; ``mask`` is True where a surface was hit.

    ``normal`` is the shading normal turned to face the camera; ``emitter`` is True where the hit
    surface is itself a light (its pixels are excluded from lighting comparisons).
    """

    position: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    albedo: np.ndarray
    mask: np.ndarray
    emitter: np.ndarray
    view_dir: np.ndarray  # unit direction from the camera through the pixel centre


def gbuffer_points(gb: GBuffer, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(points, unit normals), float64 (N, 3), of the G-buffer's pixels under ``mask`` (default
    ``gb.mask``: every hit), in row-major pixel order: the per-point estimators' probes for a scene.

    The normals are renormalised in float64 (the float32 G-buffer's are unit only to ~1e-7); a zero normal
    stays zero rather than becoming NaN (its length is floored at 1e-30), so a caller can drop it."""
    mask = gb.mask if mask is None else mask
    points = gb.position[mask].astype(np.float64)
    normals = gb.normal[mask].astype(np.float64)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    return points, normals


def pixel_rays(mi, dr, sensor, width: int, first_pixel: int, n_pixels: int, spp: int, offset=None):
    """Camera rays of ``sensor`` through the pixels ``first_pixel …`` (row-major in a film ``width`` wide;
    ``spp`` lanes each) and their weights: through the pixel centres, or with ``offset`` (a Point2f in
    [0, 1)², one per lane) at that point of each pixel."""
    idx = dr.arange(mi.UInt32, n_pixels * spp)
    # The first pixel is opaque (a device value): as a literal, every chunk of a pass was its own kernel.
    pix = idx // spp + dr.opaque(mi.UInt32, first_pixel)
    x = mi.Float(pix % width)
    y = mi.Float(pix // width)
    film_size = sensor.film().crop_size()
    ox, oy = (0.5, 0.5) if offset is None else (offset.x, offset.y)
    uv = mi.Point2f((x + ox) / film_size[0], (y + oy) / film_size[1])
    ray, weight = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5, 0.5))
    return ray, weight


MAX_PASS_THROUGH = 16
"""At most this many medium boundaries are passed through along one camera ray (nested media boxes, a
glass shell's two faces); a ray still on one after that keeps it as its first hit."""


def is_pass_through(mi, shape) -> bool:
    """True for a surface a real-time renderer does not shade as an opaque first hit (issue 31): a ``null``
    BSDF (a medium's invisible boundary: flags Null and no reflection or transmission lobe), or a
    boundary between media (``Shape.is_medium_transition``) whose BSDF has no diffuse or glossy lobe (a
    smooth or thin dielectric around a medium: delta lobes only, drawn as a transparent volume, not as a
    lit surface). Every other surface (diffuse, glossy, rough dielectric, a ``mask``'s opaque part) is a
    first hit as before."""
    bsdf = shape.bsdf()
    if bsdf is None:
        return False
    flags = bsdf.flags()
    f = mi.BSDFFlags
    lobes = any(mi.has_flag(flags, k) for k in (f.Diffuse, f.Glossy))
    if lobes:
        return False
    if mi.has_flag(flags, f.Null) and not mi.has_flag(flags, f.Delta):
        return True
    return bool(shape.is_medium_transition())


def first_surface(mi, mi_scene, ray):
    """(si, t): the first hit of the camera rays ``ray`` that is not a pass-through surface
    (`is_pass_through`), and its distance along the ray (+inf where none). In a scene without such
    surfaces this is exactly ``mi_scene.ray_intersect(ray)`` and its ``t`` (the same single trace)."""
    si = mi_scene.ray_intersect(ray)
    through_shapes = [shape for shape in mi_scene.shapes() if is_pass_through(mi, shape)]
    if not through_shapes:
        return si, si.t
    t_before = dr.zeros(type(si.t), dr.width(si.t))
    for _ in range(MAX_PASS_THROUGH):
        through = dr.full(mi.Bool, False, dr.width(si.t))
        for shape in through_shapes:
            through |= si.shape == mi.ShapePtr(shape)
        through &= si.is_valid()
        if not dr.any(through):
            break
        t_before = dr.select(through, t_before + si.t, t_before)
        nxt = mi_scene.ray_intersect(si.spawn_ray(ray.d), through)
        si = dr.select(through, nxt, si)
    return si, t_before + si.t


def _first_surface_scalar(mi, mi_scene, ray):
    """`first_surface` for one scalar ray."""
    si = mi_scene.ray_intersect(ray)
    t = 0.0
    for _ in range(MAX_PASS_THROUGH):
        if not (si.is_valid() and is_pass_through(mi, si.shape)):
            break
        t += float(si.t)
        si = mi_scene.ray_intersect(si.spawn_ray(ray.d))
    return si, t + float(si.t)


def gbuffer(mi, mi_scene, sensor=None) -> GBuffer:
    """First hits of the pixel-centre rays (the approximation's inputs) of ``sensor`` (default: the
    scene's first): the first surface a real-time renderer shades, through medium boundaries
    (`first_surface`); ``depth`` is the distance along the ray to it."""

    sensor = mi_scene.sensors()[0] if sensor is None else sensor
    width, height = sensor.film().crop_size()
    n = width * height
    if mi.variant().startswith("scalar"):
        return _gbuffer_scalar(mi, mi_scene, sensor, width, height)
    ray, _ = pixel_rays(mi, dr, sensor, width, 0, n, 1)
    si, t = first_surface(mi, mi_scene, ray)
    valid = si.is_valid()
    n_sh = si.sh_frame.n
    n_sh = dr.select(dr.dot(n_sh, ray.d) > 0, -n_sh, n_sh)
    albedo = si.bsdf(ray).eval_diffuse_reflectance(si, valid)
    emitter = si.emitter(mi_scene)
    is_emitter = valid & (emitter != None)  # noqa: E711  (Dr.Jit pointer-array comparison)
    depth = dr.select(valid, t, math.inf)
    dr.eval(si.p, n_sh, depth, albedo, valid, is_emitter, ray.d)

    def img(v, c=3):
        a = np.array(v, dtype=np.float32)
        return (a.T if c > 1 else a).reshape((height, width, c) if c > 1 else (height, width))

    mask = img(valid, 1).astype(bool)
    pos = np.where(mask[..., None], img(si.p), 0.0).astype(np.float32)
    nrm = np.where(mask[..., None], img(n_sh), 0.0).astype(np.float32)
    alb = np.where(mask[..., None], img(albedo), 0.0).astype(np.float32)
    return GBuffer(pos, nrm, img(depth, 1), alb, mask, img(is_emitter, 1).astype(bool), img(ray.d))


def first_hit_shapes(mi, mi_scene, sensor=None) -> np.ndarray:
    """(H, W) int32: the index in ``mi_scene.shapes()`` of the shape each pixel-centre ray of ``sensor``
    (default: the scene's first) hits first, through medium boundaries as `gbuffer`; −1 where it hits none.
    Vectorised variants only."""
    sensor = mi_scene.sensors()[0] if sensor is None else sensor
    width, height = sensor.film().crop_size()
    ray, _ = pixel_rays(mi, dr, sensor, width, 0, width * height, 1)
    si, _t = first_surface(mi, mi_scene, ray)
    hit = np.array(si.is_valid(), dtype=bool)
    ids = np.array(dr.reinterpret_array(mi.UInt32, si.shape), dtype=np.int64)
    index = {}
    for i, shape in enumerate(mi_scene.shapes()):
        key = np.array(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)), dtype=np.int64)
        index[int(key[0])] = i
    out = np.array([index.get(int(k), -1) for k in ids], dtype=np.int32)
    return np.where(hit, out, -1).reshape(height, width).astype(np.int32)


_UV_ANALYTIC = frozenset({"sphere", "disk", "cylinder", "rectangle"})
"""Mitsuba's analytic shapes, each with its own (u, v) parametrisation (a sphere: longitude, latitude)."""


def shape_has_uv(shape) -> bool:
    """True when Mitsuba gives ``shape`` a UV parametrisation of its own: a mesh with texture coordinates
    (``has_vertex_texcoords``), or an analytic sphere, disk, cylinder or rectangle. A mesh without
    texcoords has none: Mitsuba then reports the hit's barycentrics as ``uv`` and the triangle's edges
    as ``dp_du``/``dp_dv`` (measured, Mitsuba 3.6), a frame no texture or lightmap is laid out in."""
    if shape.is_mesh():
        return bool(shape.has_vertex_texcoords())
    return str(shape.class_name()).lower() in _UV_ANALYTIC


def uv_tangents(mi, mi_scene, sensor=None) -> tuple[np.ndarray, np.ndarray]:
    """The UV tangent ∂p/∂u (Mitsuba's ``dp_du``, world units per unit u) at the pixel-centre first hits of
    ``sensor`` (the rays `gbuffer` traces), (H, W, 3) float32, and (H, W) bool: the hit lies on a shape
    with a UV parametrisation (`shape_has_uv`) and its ``dp_du`` is finite and non-zero (a sphere's poles
    have none). Zero where False."""
    sensor = mi_scene.sensors()[0] if sensor is None else sensor
    width, height = sensor.film().crop_size()
    if mi.variant().startswith("scalar"):
        raise ValueError("uv_tangents needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    ray, _ = pixel_rays(mi, dr, sensor, width, 0, width * height, 1)
    si, _ = first_surface(mi, mi_scene, ray)
    has_uv = dr.full(mi.Bool, False, width * height)
    for shape in mi_scene.shapes():
        if shape_has_uv(shape):
            has_uv |= si.shape == mi.ShapePtr(shape)
    has_uv &= si.is_valid()
    dr.eval(si.dp_du, has_uv)
    t = np.array(si.dp_du, dtype=np.float64).T.reshape(height, width, 3)
    ok = np.array(has_uv, dtype=bool).reshape(height, width)
    ok &= np.all(np.isfinite(t), axis=-1) & (np.linalg.norm(t, axis=-1) > 0.0)
    return np.where(ok[..., None], t, 0.0).astype(np.float32), ok


def _gbuffer_scalar(mi, mi_scene, sensor, width, height) -> GBuffer:
    pos = np.zeros((height, width, 3), np.float32)
    nrm = np.zeros_like(pos)
    alb = np.zeros_like(pos)
    view = np.zeros_like(pos)
    depth = np.full((height, width), np.inf, np.float32)
    mask = np.zeros((height, width), bool)
    emit = np.zeros_like(mask)
    for j in range(height):
        for i in range(width):
            ray, _ = sensor.sample_ray(
                0.0, 0.5, mi.Point2f((i + 0.5) / width, (j + 0.5) / height), mi.Point2f(0.5, 0.5)
            )
            view[j, i] = np.array(ray.d)
            si, t = _first_surface_scalar(mi, mi_scene, ray)
            if not si.is_valid():
                continue
            n = np.array(si.sh_frame.n)
            if np.dot(n, np.array(ray.d)) > 0:
                n = -n
            mask[j, i] = True
            pos[j, i] = np.array(si.p)
            nrm[j, i] = n
            depth[j, i] = t
            alb[j, i] = np.array(si.bsdf(ray).eval_diffuse_reflectance(si))
            emit[j, i] = si.emitter(mi_scene) is not None
    return GBuffer(pos, nrm, depth, alb, mask, emit, view)
