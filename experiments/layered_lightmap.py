r"""The layered-materials family's light-map case (a leaf of experiments/audit_layered_materials.py): the
irradiance the inner layer of a two-layer material receives under a scattering outer layer, against the
seed's blurred light map (000:1221-1290; `rtfit.realtime.layered_materials` ``lightmap-*`` rows).

Role ``slab over a base``: a homogeneous medium in a convex box (an XML ``particle`` part) with a delta
light (directional, point or spot) in the scene. One case ``slab-<i>-lightmap`` (quantity
``inner_irradiance``, W/m²) on the visible pixels whose first surface (through medium boundaries, the
G-buffer) is an opaque surface (the inner layer) whose normal ray enters that box first and leaves it
through the same box (the outer layer of thickness d above the point):

* **reference**, per pixel at the G-buffer's point x (normal n): E_in = E_beam + E_s with E_beam =
  E_l·max(n·l, 0)·V·exp(−σ_t·ℓ) (Mitsuba's ``sample_direction`` of the light: l and E_l; V: no opaque
  surface on the shadow ray, medium boundaries passed (`first_surface`); ℓ the ray's chord through the box;
  σ_t Mitsuba's own ``get_scattering_coefficients``: deterministic) and E_s the scattered irradiance,
  π × ``volpath`` (unbounded depth) along cosine rays (`rtfit.reference.slab_irradiance`: its Monte Carlo
  noise is the case's noise floor). Only the scene's one delta light lights it (a scene with another
  emitter gives no case: its light would be in E_s but not in the light map);
* **inputs**: the light map E_map, the outer layer's local diffuse lighting E_l·max(n·l, 0)·V at the box's
  top above each texel centre of the inner layer's uv window (the G-buffer's (u, v) padded by the largest
  blur radius, 8 texels per thickness, ≤ 512 a side; a `BaseTexture`), the pixel's (u, v) and d.

The rows' fits (t, k) start from the best point of a 17-point grid of k (with the least-squares t per k):
the error of a blurred step is piecewise in k.
"""

from __future__ import annotations

import time
from dataclasses import replace

import drjit as dr
import numpy as np

from rtfit.realtime.layered_materials import BLUR_MAX, LIGHTMAP_ROWS, METHODS, BaseTexture
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import first_surface, is_pass_through
from rtfit.reference.particle_media import medium_extinction
from rtfit.reference.slab_irradiance import scattered_irradiance_pass

from .audit import Applicability, Rule
from .audit_family import FamilyCase
from .audit_geometry import camera_rays, rays
from .audit_setup import AuditSetup, pooled_passes
from .shipped import Sizes

__all__ = ["LIGHTMAP_RULE", "LIGHTMAP_SCENE", "ROLE", "lightmap_cases", "uv_window"]

FORMAT = 1
ROLE = "slab over a base"
_TEXELS_PER_DEPTH = 8  # texels per layer thickness in a texture-space window (the albedo, the light map)
_TEXELS_MAX = 512  # per side
_sizes = Sizes(full=(32, 32, 1024), quick=(16, 16, 256))
LIGHTMAP_SCENE = _sizes.scene(
    "layered_materials_lightmap.xml",
    "a diffuse inner layer (ρ = 0.5) under a scattering slab (d = 0.1, σ_t = 10, albedo 0.95, HG g = 0.7) "
    "lit straight down by a directional light cut by a half-plane: a sharp shadow edge (volpath)",
    name="lightmap-edge",
    roles=(ROLE,),
)
"""The shipped scene of the light-map case (scenes/library/layered_materials_lightmap.xml)."""
LIGHTMAP_RULE = Rule(
    "layered-materials",
    ROLE,
    ("particle", "light"),
    "{part}: a scattering outer layer over a surface, lit by {with_}: an engine lights the inner layer with "
    "the outer layer's blurred light map (the seed's goopy materials)",
    "the irradiance the surface under the medium's box receives (W/m²; the beam through the slab plus its "
    "scattered light) where an opaque surface lies under the box and one delta light lights the scene",
    "volpath (unbounded depth) along cosine rays from the inner layer's points, plus the beam's "
    "transmittance",
    supplies=frozenset(i.name for k in LIGHTMAP_ROWS for i in METHODS[k].inputs),  # its own rows
)


def _v3(a) -> np.ndarray:
    return np.asarray(a, np.float64).T.reshape(-1, 3)


def _interactions(mi, points: np.ndarray, normals: np.ndarray):
    it = dr.zeros(mi.SurfaceInteraction3f, len(points))
    it.p = mi.Point3f(np.ascontiguousarray(points, np.float32).T)
    it.n = mi.Vector3f(np.ascontiguousarray(normals, np.float32).T)
    it.sh_frame = mi.Frame3f(it.n)
    return it


def _chord(mi, box, points: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hit, t_in, t_out) of the rays from ``points`` along ``dirs`` through the box scene ``box`` (its shape
    alone): entry by a forward ray, exit by a ray back from beyond the box (the box is convex)."""
    o = mi.Point3f(np.ascontiguousarray(points, np.float32).T)
    d = mi.Vector3f(np.ascontiguousarray(dirs, np.float32).T)
    si = box.ray_intersect(mi.Ray3f(o, d))
    hit = np.asarray(si.is_valid(), bool)
    t_in = np.where(hit, np.asarray(si.t, np.float64), 0.0)
    span = float(dr.norm(box.bbox().max - box.bbox().min)) + 1.0
    far = points + dirs * (t_in + span)[:, None]
    back = box.ray_intersect(mi.Ray3f(mi.Point3f(np.ascontiguousarray(far, np.float32).T), -d))
    t_out = np.where(
        hit & np.asarray(back.is_valid(), bool), t_in + span - np.asarray(back.t, np.float64), t_in
    )
    return hit, t_in, np.maximum(t_out, t_in)


def _light(mi, emitter, points: np.ndarray, normals: np.ndarray, scene):
    """(E_l·max(n·l, 0)·V (N, 3), l (N, 3)): the delta light's unattenuated irradiance at ``points``, its
    shadow ray passing medium boundaries (`first_surface`) and stopping short of a local light."""
    it = _interactions(mi, points, normals)
    ds, weight = emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
    ray = it.spawn_ray(ds.d)
    ray.maxt = dr.select(dr.isfinite(ds.dist), ds.dist * (1.0 - 1e-4), dr.inf)
    si, _ = first_surface(mi, scene, ray)
    lit = ~np.asarray(si.is_valid(), bool)
    towards = _v3(ds.d)
    cos = np.maximum(np.sum(towards * normals, axis=1), 0.0)
    return _v3(weight) * (cos * lit)[:, None], towards


def _slab_shape(setup: AuditSetup, app: Applicability):
    """The loaded shape of the XML particle ``app.source`` (its order among the shapes holding a medium)."""
    xml = setup.info.xml
    if xml is None or app.source is None:
        return None
    order = [i for i, s in enumerate(xml.shapes) if s.interior].index(app.source)
    holders = [s for s in setup.scene.shapes() if s.interior_medium() is not None]
    return holders[order] if order < len(holders) else None


def uv_window(uvs: np.ndarray, units, radius: float, depth: float):
    """The texture-space window of a layer's texture (the base's albedo, the light map): the (u, v) box of
    ``uvs`` padded by ``radius`` (scene units; ``units`` = scene units per unit of u and of v), clipped to
    [0, 1]², with `_TEXELS_PER_DEPTH` texels per thickness ``depth`` (2 to `_TEXELS_MAX` a side). Returns
    ``(window (u0, v0, u1, v1), (nu, nv), uu, vv)``: the texel centres as (nv, nu) grids."""
    pad = np.array([radius / units[0], radius / units[1]])
    lo, hi = np.clip(uvs.min(0) - pad, 0.0, 1.0), np.clip(uvs.max(0) + pad, 0.0, 1.0)
    texel = max(depth, 1e-9) / _TEXELS_PER_DEPTH
    n = [int(np.clip(np.ceil((hi[k] - lo[k]) * units[k] / texel), 2, _TEXELS_MAX)) for k in range(2)]
    u = lo[0] + (np.arange(n[0]) + 0.5) * (hi[0] - lo[0]) / n[0]
    v = lo[1] + (np.arange(n[1]) + 0.5) * (hi[1] - lo[1]) / n[1]
    uu, vv = np.meshgrid(u, v)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])), (n[0], n[1]), uu, vv


def _light_map(mi, setup, base, emitter, box, uvs, si_units, radius: float, depth: float, normal):
    """The `BaseTexture` of E_map on the inner layer's uv window around ``uvs`` padded by ``radius``."""
    window, n, uu, vv = uv_window(uvs, si_units, radius, depth)
    si = base.eval_parameterization(mi.Point2f(uu.ravel().astype(np.float32), vv.ravel().astype(np.float32)))
    p = _v3(si.p)
    nrm = np.broadcast_to(normal, p.shape).copy()
    _, _, t_out = _chord(mi, box, p, nrm)
    top = p + nrm * (t_out + 1e-4 * max(depth, 1e-9))[:, None]  # just above the outer surface
    e_map, _ = _light(mi, emitter, top, nrm, setup.scene)
    return BaseTexture(e_map.T.reshape(3, n[1], n[0]), window, si_units)


def lightmap_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The light-map case of one medium box (module docstring); none where no opaque surface lies under it,
    or the scene has other lights than one delta light."""
    mi, scene = setup.mi, setup.scene
    shape = _slab_shape(setup, app)
    emitters = list(scene.emitters())
    delta = mi.EmitterFlags.DeltaDirection | mi.EmitterFlags.DeltaPosition
    if shape is None or len(emitters) != 1 or not mi.has_flag(emitters[0].flags(), delta):
        return []
    if not setup.wants("inner_irradiance"):
        return []
    t0 = time.perf_counter()
    gb, visible = setup.gbuffer, setup.mask
    points = gb.position[visible].astype(np.float64)
    normals = gb.normal[visible].astype(np.float64)
    box = mi.load_dict({"type": "scene", "s": shape})
    hit, t_in, t_out = _chord(mi, box, points, normals)
    ids = np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)), np.int64)[0]
    up = scene.ray_intersect(
        _interactions(mi, points, normals).spawn_ray(mi.Vector3f(normals.T.astype(np.float32)))
    )
    first = np.asarray(dr.reinterpret_array(mi.UInt32, up.shape), np.int64) == ids
    keep = hit & first & (t_out > t_in)
    if not keep.any():
        return []
    idx = np.flatnonzero(visible.reshape(-1))[keep]
    mask = np.zeros(visible.size, bool)
    mask[idx] = True
    mask = mask.reshape(visible.shape)
    p, n, depth = points[keep], normals[keep], t_out[keep]
    origins, dirs = camera_rays(setup)
    si = first_surface(mi, scene, rays(mi, origins[keep], dirs[keep]))[0]
    base_shape = si.shape
    uvs = np.stack([np.asarray(si.uv.x, np.float64), np.asarray(si.uv.y, np.float64)], 1)
    units = (float(np.median(np.linalg.norm(_v3(si.dp_du), axis=1))),
             float(np.median(np.linalg.norm(_v3(si.dp_dv), axis=1))))  # fmt: skip
    bases = np.unique(np.asarray(dr.reinterpret_array(mi.UInt32, base_shape), np.int64))
    base = next(s for s in scene.shapes() if _ptr(mi, s) == int(bases[0]))
    if len(bases) != 1 or is_pass_through(mi, base) or not np.allclose(n, n[0], atol=1e-4):
        return []  # one flat inner layer: its uv is the light map's texture space
    emitter = emitters[0]
    direct, towards = _light(mi, emitter, p, n, scene)
    hit_l, a, b = _chord(mi, box, p, towards)
    sigma_t = medium_extinction(mi, shape.interior_medium(), p[0])
    beam = direct * np.exp(-np.outer(np.where(hit_l, b - a, 0.0), sigma_t))
    radius = BLUR_MAX * float(depth.max())
    lightmap = _light_map(mi, setup, base, emitter, box, uvs, units, radius, float(depth.min()), n[0])
    what = {"format": FORMAT, "quantity": "inner-irradiance", "part": app.part, "points": array_digest(p, n)}

    def render(spp: int, seed: int):
        return scattered_irradiance_pass(mi, scene, p, n, spp, seed)

    pooled = pooled_passes(setup, what, render, (-1, 3), f"slab{app.source}: inner-layer irradiance")
    pooled = replace(pooled, mean=pooled.mean + beam)
    reference = pooled.reference(
        mask,
        quantity="irradiance the inner layer receives under the slab (W/m²)",
        integrator="volpath",
        integrator_reason="the slab's multiple scattering and the inner layer's bounces (unbounded depth, "
        "Russian roulette), along cosine rays; the light's beam added in closed form (its transmittance "
        "exp(−σ_t·ℓ), shadow rays)",
        extra_seconds=time.perf_counter() - t0,
    )
    shared = {"lightmap": lightmap, "u": uvs[:, 0], "v": uvs[:, 1], "depth": depth}
    channels = tuple({**shared, "channel": float(c)} for c in range(3))
    sigma = float(np.mean(sigma_t))
    return [
        FamilyCase(
            id=f"slab-{app.source}-lightmap",
            label=f"{app.part}: the inner layer's irradiance under it",
            reference=reference,
            channel_inputs=channels,
            parameters={
                "part": app.part,
                "depth_min": float(depth.min()),
                "depth_max": float(depth.max()),
                "sigma_t": sigma,
                "optical_depth": sigma * float(np.median(depth)),
                "texels": list(lightmap.texels.shape[1:]),
                "pixels": int(mask.sum()),
            },
            units="W/m²",
            notes=(
                f"outer layer thickness d = {np.median(depth):.4g}, σ_t = {sigma:.4g} (optical depth "
                f"{sigma * np.median(depth):.3g}); the beam's share of the reference: "
                f"{float(np.sum(beam) / max(np.sum(pooled.mean), 1e-30)):.3g}",
                f"the light map: {lightmap.texels.shape[2]}×{lightmap.texels.shape[1]} texels of the outer "
                "layer's local diffuse lighting (N·L, shadowed) on the inner layer's uv window",
            ),
            methods={k: METHODS[k] for k in LIGHTMAP_ROWS},
            quantity="inner_irradiance",
            params=_starts(pooled.mean, channels),
        )
    ]


def _ptr(mi, shape) -> int:
    return int(np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape)), np.int64)[0])


def _starts(ref: np.ndarray, channels) -> dict:
    """The fits' starts: k of a 17-point grid over [0, BLUR_MAX] with the least squared error against
    ``ref`` (N, 3), each with its least-squares t (E_in is t times its value at t = 1)."""
    grid = np.linspace(0.0, BLUR_MAX, 17)
    m = METHODS["lightmap-blur"]
    fits = []
    for k in grid:
        f = np.stack(
            [np.asarray(m.evaluate(ch, {"blur": k, "transmit": 1.0}), np.float64) for ch in channels], 1
        )
        t = float(np.clip(np.sum(f * ref) / max(np.sum(f * f), 1e-30), 0.0, 2.0))
        fits.append((float(np.sum((t * f - ref) ** 2)), float(k), t))
    _, k, t = min(fits)
    starts = {"lightmap-local": {"transmit": fits[0][2]}, "lightmap-blur": {"blur": k, "transmit": t}}
    return {
        row: {
            name: replace(p, initial=_inside(starts[row][name], p)) for name, p in METHODS[row].params.items()
        }
        for row in starts
    }


def _inside(x: float, p) -> float:
    margin = 1e-3 * (p.upper - p.lower)
    return float(np.clip(x, p.lower + margin, p.upper - margin))
