"""The ``pcf-soft-shadows`` family on a scene's lights (`rtfit audit`, and ``rtfit run pcf-soft-shadows`` on
its shipped scenes): a shadow map from the light's centre, filtered (PCF, PCSS), standing in for the light's
penumbra, against the path-traced shadowed irradiance of that light.

Role (its ``rules``): ``soft shadows (shadow-map filtering)`` — every light of the scene (a Mitsuba XML point,
spot, sphere, rectangle, disk or mesh area light, a directional light or a sunsky's sun; the rtfit TOML ones)
together with geometry that can occlude it.

Per light, two cases on the visible surface pixels inside the maps' frustum: ``light<i>-map1024``, every row
on the seed's 1024² map, and ``light<i>-map256``, `LOW_ROWS` on a 256² map (the map's quality knob):

* **reference**: the light's shadowed direct irradiance E_s (W/m², RGB), Mitsuba's emitter sampling of that
  light alone with shadow rays (`audit_lights.light_reference`, columns 3–5: the same passes as the diffuse
  family's shadowed case, shared through the pass cache);
* **the map** (`shadow_map`): W² rays cast with Dr.Jit from the light's centre through the texel centres
  (perspective, its axis towards the visible points' mean direction, its half-angle covering them by 10 %,
  at most `MAX_HALF_ANGLE_DEG`; a hit on the light's own shape is passed through, so a sphere or a mesh bulb
  does not shadow itself), or along a distant light's direction (orthographic, covering the points by 10 %);
  the pixels outside the frustum are left out of the case (an engine would need a cube map), saying how many;
* **inputs**: ``irradiance`` E, the light's unshadowed irradiance from its closed form — a sphere light of
  declared radiance: `rtfit.realtime.diffuse` ``exact`` (horizon-clipped cap); a rectangle of uniform
  radiance: `rtfit.realtime.light_models` ``polygon``; any other light: the reference's own unshadowed
  estimate (columns 0–2, the same passes), said in a note — so every row's error is its visibility's alone;
  ``u``, ``v``, ``depth`` (`rtfit.realtime.pcf_soft_shadows.project`), ``rotation`` (a tiled 32 × 32 texture
  of random angles, `NOISE`, as the seed's lookup texture), the `ShadowMap` (PCSS's light size ℓ: a sphere's
  radius R, a planar light's √(A/π), 0 for a point or spot light; a distant light's tan α over the map's
  width);
* **parameters**: the kernel radius r (texels) and the bias b, fitted per case; b starts at two texel
  footprints at the median receiver depth, bounded by [0, 200] footprints (a step of the compare: TRF cannot
  move it where no compare changes within its difference step, and says so).
"""

from __future__ import annotations

import dataclasses
import math

import drjit as dr
import numpy as np

from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.realtime.light_models import METHODS as LIGHT_MODELS
from rtfit.realtime.methods import Param
from rtfit.realtime.pcf_soft_shadows import FAR, METHODS, ShadowMap, map_frame, project, texel_directions
from rtfit.reference.estimators import gbuffer_points

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_lights import AuditLight, light_geometry, light_model_inputs, light_reference, scene_light
from .audit_setup import AuditSetup
from .shipped import Sizes

__all__ = ["FAMILY", "LOW", "LOW_ROWS", "MAP", "NOISE", "SCENES", "pcf_cases", "shadow_map"]

MAP, LOW = 1024, 256
"""The shadow-map resolutions (texels per side): the seed's 1024² for every row, a quarter for `LOW_ROWS`."""
LOW_ROWS = ("hard", "poisson8-rotated", "pcss")
"""The rows also evaluated on the 256² map (the resolution knob: the seed's row, the baseline, the modern)."""
MAX_HALF_ANGLE_DEG = 80.0
"""The widest half-angle of a perspective map (a wider spread of receivers needs a cube map)."""
NOISE = np.random.default_rng(20060731).uniform(0.0, 2.0 * math.pi, (32, 32))
"""The per-pixel rotation texture (rad), tiled over the screen: the seed's lookup texture of rotations."""

_SPHERE = "a box, a floating plate and a ball on a grey floor under a sphere light of radius {} m (3 m up)"
_sizes = Sizes(full=(64, 64, 512), quick=(32, 32, 64))
SCENES = (
    *(
        _sizes.scene(
            "pcf_soft_shadows_sphere.xml",
            _SPHERE.format(r),
            defines={"radius": f"{r}", "radiance": f"{1.0 / (math.pi * (r / 3.0) ** 2):.4g}"},
            name=f"sphere-r{r}".replace(".", "p"),
            quick=r == 0.4,
        )
        for r in (0.1, 0.4)
    ),
    _sizes.scene(
        "pcf_soft_shadows_rect.xml",
        "the same objects under a 1 × 1 m rectangle light facing down, 3 m up",
        quick=False,
    ),
)
"""The scenes ``rtfit run pcf-soft-shadows`` audits (scenes/library/): a small and a large sphere light
(E⊥ ≈ 1 W/m² at 3 m: L = 1/(π (R/3)²)), and a rectangle light (the full run only)."""


def _light_size(light: AuditLight) -> float:
    """PCSS's light radius (scene units): a sphere's R, a planar or mesh light's √(A/π), 0 for a point."""
    if light.radius > 0:
        return light.radius
    shape = light.emitter.get_shape() if light.emitter is not None else None
    if shape is None:
        return 0.0
    return math.sqrt(float(np.asarray(shape.surface_area()).reshape(-1)[0]) / math.pi)


def _cast(setup: AuditSetup, origins: np.ndarray, direction: np.ndarray, own) -> np.ndarray:
    """Distance along each ray to its first hit (``FAR`` for none), passing through the light's own shape
    ``own`` (up to three times: in and out of a closed bulb, and once more)."""
    mi = setup.mi
    o = mi.Point3f(np.ascontiguousarray(origins, np.float32).T)
    d = mi.Vector3f(np.ascontiguousarray(direction, np.float32).T)
    si = setup.scene.ray_intersect(mi.Ray3f(o, d))
    t = dr.select(si.is_valid(), si.t, FAR)
    if own is not None:
        for _ in range(3):
            through = si.is_valid() & (si.shape == mi.ShapePtr(own))
            if not dr.any(through):
                break
            nxt = setup.scene.ray_intersect(si.spawn_ray(d))
            t = dr.select(through, dr.select(nxt.is_valid(), t + nxt.t, FAR), t)
            si = dr.select(through, nxt, si)
    return np.asarray(t, np.float64)


def shadow_map(setup: AuditSetup, light: AuditLight, points: np.ndarray, resolution: int):
    """(`ShadowMap`, u, v, depth, inside, texel) of ``light`` for the receivers ``points`` (module docstring):
    ``texel`` a texel's width in scene units at unit depth (perspective) or everywhere (orthographic)."""
    own = light.emitter.get_shape() if light.emitter is not None else None
    if light.direction is None:  # local: perspective from the centre
        c = np.asarray(light.centre, np.float64)
        rel = points - c
        dirs = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-30)
        axis = dirs.mean(axis=0)
        if np.linalg.norm(axis) < 1e-6:
            raise AuditError("pcf-soft-shadows: the visible points surround the light (a cube map's case)")
        axis /= np.linalg.norm(axis)
        angle = np.arccos(np.clip(dirs @ axis, -1.0, 1.0))
        half = min(math.radians(MAX_HALF_ANGLE_DEG), math.atan(1.1 * math.tan(min(float(angle.max()), 1.5))))
        tan_half = math.tan(half)
        u, v, depth = project(c, axis, tan_half, points)
        inside = (angle < half) & (depth > 0) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        rays = texel_directions(axis, tan_half, resolution)
        t = _cast(setup, np.broadcast_to(c, rays.shape), rays, own)
        t = np.where(t < FAR, t * (rays @ axis), FAR)  # the distance along the axis (view-space z)
        ell = _light_size(light) / (2.0 * tan_half)
        sm = ShadowMap(
            np.maximum(t, 1e-9).reshape(resolution, resolution),
            light_size=ell,
            near=float(max(t.min(), 1e-6)),
            origin=(float(c[0]), float(c[1]), float(c[2])),
            axis=(float(axis[0]), float(axis[1]), float(axis[2])),
            size=tan_half,
        )
        return sm, u, v, depth, inside, 2.0 * tan_half / resolution
    axis = -np.asarray(light.direction, np.float64)
    e1, e2 = map_frame(axis)
    centroid = points.mean(axis=0)
    extent = 2.2 * float(
        max(np.abs((points - centroid) @ e1).max(), np.abs((points - centroid) @ e2).max(), 1e-6)
    )
    far = float(setup.info.diagonal or 1.0) * 2.0
    origin = centroid - axis * far
    u, v, depth = project(origin, axis, 0.0, points, ortho_extent=extent)
    c = (np.arange(resolution) + 0.5) / resolution - 0.5
    s, q = np.meshgrid(c * extent, c * extent)
    starts = origin[None, :] + s.reshape(-1, 1) * e1 + q.reshape(-1, 1) * e2
    t = _cast(setup, starts, np.broadcast_to(axis, starts.shape), own)
    ell = math.tan(light.angular_radius) / extent
    sm = ShadowMap(
        np.maximum(t, 1e-9).reshape(resolution, resolution),
        ortho=True,
        light_size=ell,
        near=float(max(t.min(), 1e-6)),
        origin=(float(origin[0]), float(origin[1]), float(origin[2])),
        axis=(float(axis[0]), float(axis[1]), float(axis[2])),
        size=extent,
    )
    return sm, u, v, depth, np.ones(len(points), bool), extent / resolution


def _unshadowed(setup, app, light, pooled, points, normals, towards, dist, alpha):
    """Per channel E (N,) from the light's closed form where it has one, else the reference's (note)."""
    cos = np.clip(np.sum(normals * towards, axis=1), -1.0, 1.0)
    if light.radius > 0 and light.radiance is not None:
        exact = DIFFUSE["exact"]
        e = [
            exact.evaluate({"cos_theta": cos, "alpha": alpha, "radiance": light.radiance[c]})
            for c in range(3)
        ]
        return e, "unshadowed E: the sphere light's closed form (diffuse exact)"
    own = light_model_inputs(setup, app.source, points, normals, towards, dist)
    if "lcx" in own[0]:
        return [np.asarray(LIGHT_MODELS["polygon"].evaluate(own[c]), np.float64) for c in range(3)], (
            "unshadowed E: the rectangle's polygon closed form (light_models polygon)"
        )
    return [pooled.mean[:, c] for c in range(3)], (
        "unshadowed E: the reference's own unshadowed estimate (no closed form for this light)"
    )


def pcf_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The cases of the light ``app.source``: every row on the seed's 1024² map, the `LOW_ROWS` on a 256² map
    (module docstring)."""
    if app.source is None:
        raise AuditError(f"pcf-soft-shadows: {app.part} is not a light of the scene")
    light = scene_light(setup, app.source)
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    towards, dist, alpha, _centre, radius = light_geometry(setup, app.source, points)
    tag = f"light{app.source}"
    pooled = light_reference(setup, app.source, points, normals, towards, f"{tag}: {app.part}")
    e, e_note = _unshadowed(setup, app, light, pooled, points, normals, towards, dist, alpha)
    rows, cols = np.nonzero(setup.mask)
    rotation = NOISE[rows % NOISE.shape[0], cols % NOISE.shape[1]]
    keep = dist > radius * (1.0 + 1e-4) if radius > 0 else np.ones(len(points), bool)
    maps = {res: shadow_map(setup, light, points, res) for res in (MAP, LOW)}
    for _sm, _u, _v, depth, inside, _texel in maps.values():
        keep &= inside & np.isfinite(depth)
    left = int((~keep).sum())
    if not keep.any():
        raise AuditError(f"pcf-soft-shadows: {app.part}: no visible point inside its shadow map's frustum")
    mask = np.zeros_like(setup.mask)
    mask[rows[keep], cols[keep]] = True
    sub = dataclasses.replace(pooled, mean=pooled.mean[keep], stderr=pooled.stderr[keep])
    ref = sub.reference(
        mask,
        quantity="direct irradiance of one light, shadowed (W/m²)",
        integrator="light-irradiance (emitter sampling, shadow rays)",
        integrator_reason=f"{light.kind} light: Mitsuba emitter sampling of this light alone with shadow "
        "rays, white Lambertian receiver at each visible point",
        columns=slice(3, 6),
    )
    cases = []
    for res, (sm, u, v, depth, _inside, texel) in maps.items():
        footprint = texel * (1.0 if sm.ortho else float(np.median(depth[keep])))
        inputs = {
            "u": u[keep],
            "v": v[keep],
            "depth": depth[keep],
            "rotation": rotation[keep],
            "shadow_map": sm,
        }
        methods = METHODS if res == MAP else {m: METHODS[m] for m in LOW_ROWS}
        # The bias is a step in the depth compare: the residuals' derivative is 0 between steps (a solver
        # left it at its start: "zero derivative at every element" on every real scene), so it is scanned
        # over 33 values, 24 % apart, from 0.2 to 200 texel footprints before the solver (`Param.scan`).
        bias = Param(2.0 * footprint, 0.0, 200.0 * footprint, unit="m", published=False, scan=33,
                     description="depth bias b (scene units): the receiver compared at z_r − b")  # fmt: skip
        notes = (
            e_note,
            f"shadow map {res}² from the light's centre ({'orthographic' if sm.ortho else 'perspective'}), "
            f"texel footprint {footprint:.3g} at the median receiver depth (the bias starts at two); PCSS "
            f"light size ℓ = {sm.light_size:.3g}",
            *((f"{left} visible pixels outside the map's frustum or on the light left out",) if left else ()),
        )
        params = {"light": app.part, "kind": light.kind, "map_resolution": res, "texel_footprint": footprint}
        cases.append(
            FamilyCase(
                id=f"{tag}-map{res}",
                label=f"{app.part}, shadow map {res}²",
                reference=ref,
                channel_inputs=tuple({"irradiance": e[c][keep], **inputs} for c in range(3)),
                parameters={**params, "light_size_uv": sm.light_size, "pixels": int(keep.sum())},
                units="W/m²",
                notes=notes,
                methods=methods,
                params={rid: {"bias": bias} for rid in methods},
            )
        )
    return cases


FAMILY = AuditFamily(
    name="pcf-soft-shadows",
    quantity="shadowed_light_irradiance",
    cases=pcf_cases,
    describe=(
        "Per light with occluding geometry: its shadowed direct irradiance E_s (W/m², RGB) at each visible "
        "point, by Mitsuba's emitter sampling of that light alone with shadow rays, in independent passes "
        "with per-pixel standard errors — against the light's closed-form unshadowed irradiance times the "
        "visibility a shadow map gives: a depth map cast with Dr.Jit from the light's centre (perspective; "
        "orthographic for a distant light) at 256² and the seed's 1024², read by a hard compare, the seed's "
        "8-tap Poisson PCF (fixed and rotated per pixel), 16-tap rotated Poisson, 3×3 and 5×5 box PCF and "
        "PCSS (blocker search + penumbra estimate). Kernel radius, depth bias and PCSS's light-size scale "
        "are fitted per light and map resolution; pixels outside the map's frustum are left out."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "pcf-soft-shadows",
            "soft shadows (shadow-map filtering)",
            ("light", "geometry"),
            "{part} casts shadows of {with_}: an engine filters a shadow map from its centre (PCF, PCSS) "
            "for the penumbra",
            "that light's shadowed direct irradiance at the visible points",
            "direct, that light alone (emitter sampling, shadow rays); the shadow map by Dr.Jit ray casts "
            "from the light's centre",
            supplies=frozenset({"irradiance", "u", "v", "depth", "rotation", "shadow_map"}),
        ),
    ),
)
