"""The ``diffuse`` family in `rtfit audit`: one light's direct irradiance at the scene's visible points.

For each light of the scene (point, spot, directional, sphere, disk, rectangle, or an area light on any
mesh) and the pixel-centre G-buffer of the scene's own camera (points x, camera-facing unit normals n):

* reference: the light's direct irradiance E (W/m², RGB) at x for n, **unshadowed** (the light alone) and
  **shadowed** (with the scene's own occluders), two cases reported separately, estimated by
  `rtfit.reference.light_irradiance.light_irradiance_pass` (Mitsuba's emitter sampling and shadow rays:
  the cheapest exact estimator of one light's direct irradiance) in independent passes through the pass
  cache;
* the methods' inputs (`rtfit.realtime.quantities` ``light_irradiance``), per pixel:
  ``cos_theta`` = n·t with t the unit direction from x to the light's centre (a point/spot light's
  position, a sphere's centre, the centre of an area light's bounding box, the direction of a directional
  light); ``irradiance`` E⊥ = the light's unshadowed irradiance on a surface facing t (estimated in the
  same pass from samples of its own, per channel: for a sphere light π·L·sin²α); ``alpha`` = asin(r/d)
  for a sphere light of radius r at distance d (0 for every other light); ``distance`` d = |c − x|
  (+inf for a directional light); ``radiance`` L (a sphere light's declared radiance, else E⊥/(π sin²α));
* shadowed case: each method's value times the hard shadow of the light's centre (one shadow ray from x
  towards t: 1 when nothing blocks it), which is what a shadow map gives an engine; so the shadowed case
  measures the formula together with a hard shadow against the true, soft one.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from rtfit.reference.cache import array_digest
from rtfit.reference.light_irradiance import light_irradiance_pass

from .audit import Applicability
from .audit_family import (
    AuditError,
    AuditFamily,
    AuditSetup,
    FamilyCase,
    PooledPasses,
    pooled_passes,
)

__all__ = ["FAMILY", "light_geometry", "light_radiance", "light_reference"]

FORMAT = 2  # 2: E⊥ from samples of its own (`light_irradiance.PERP_SAMPLES`)
_DIRECTIONAL_FAR = 1e7  # a directional light's "centre": this many scene diagonals away along its direction


def light_geometry(setup: AuditSetup, source: int, points: np.ndarray):
    """(towards (N, 3) unit, distance (N,), alpha (N,), centre-or-None, radius) of the light
    ``setup.info.xml.emitters[source]`` seen from ``points`` (N, 3)."""
    xml = setup.info.xml
    if xml is None:
        raise AuditError("the diffuse audit reads lights from Mitsuba XML scenes")
    light = xml.emitters[source]
    emitter = setup.emitters[source]
    if emitter is None:
        raise AuditError(f"{light.kind} light ({light.location}): Mitsuba did not instantiate it")
    p = np.asarray(points, np.float64)
    radius = 0.0
    if light.kind == "directional":
        d = np.asarray(light.direction, np.float64)
        n = len(p)
        return np.tile(d, (n, 1)), np.full(n, math.inf), np.zeros(n), None, 0.0
    if light.kind in ("point", "spot"):
        centre = np.asarray(light.position, np.float64)
    else:
        shape = emitter.get_shape()
        if shape is None:
            raise AuditError(f"{light.kind} light ({light.location}): no shape to take its centre from")
        box = shape.bbox()
        lo = np.array([float(box.min[i]) for i in range(3)])
        hi = np.array([float(box.max[i]) for i in range(3)])
        centre = (lo + hi) / 2
        if light.spherical:
            radius = float(hi[0] - lo[0]) / 2
    v = centre - p
    dist = np.linalg.norm(v, axis=1)
    towards = v / np.maximum(dist, 1e-30)[:, None]
    alpha = np.arcsin(np.clip(radius / np.maximum(dist, 1e-30), 0.0, 1.0)) if radius > 0 else np.zeros(len(p))
    return towards, dist, alpha, centre, radius


def _hard_shadow(setup: AuditSetup, points, normals, towards, dist, radius) -> np.ndarray:
    """1 where a shadow ray from each point towards the light's centre reaches the light (its surface for a
    sphere, the centre's neighbourhood otherwise), else 0."""
    mi = setup.mi
    reach = np.where(np.isfinite(dist), np.maximum(dist - radius, 0.0) * (1.0 - 1e-4), 0.0)
    diag = setup.info.diagonal or 1.0
    reach = np.where(np.isfinite(dist), reach, _DIRECTIONAL_FAR * diag)
    target = np.asarray(points, np.float64) + towards * reach[:, None]
    it = dr.zeros(mi.SurfaceInteraction3f, len(points))
    it.p = mi.Point3f(np.ascontiguousarray(points, np.float32).T)
    it.n = mi.Vector3f(np.ascontiguousarray(normals, np.float32).T)
    it.sh_frame = mi.Frame3f(it.n)
    ray = it.spawn_ray_to(mi.Point3f(np.ascontiguousarray(target, np.float32).T))
    blocked = setup.scene.ray_test(ray)
    return (~np.asarray(blocked, dtype=bool)).astype(np.float64)


def light_radiance(setup: AuditSetup, source: int, e_perp: np.ndarray, alpha: np.ndarray) -> list:
    """Per channel: a sphere light's declared radiance, else E⊥/(π sin²α) (0 where α = 0)."""
    light = setup.info.xml.emitters[source]
    if light.scale_name == "radiance" and light.scale is not None and len(light.scale) in (1, 3):
        values = light.scale * (3 // len(light.scale))
        return [float(v) for v in values]
    s2 = np.sin(alpha) ** 2
    return [np.where(s2 > 0, e_perp[:, c] / (math.pi * np.maximum(s2, 1e-300)), 0.0) for c in range(3)]


def light_reference(setup: AuditSetup, source: int, points, normals, towards, label: str) -> PooledPasses:
    """The light's pooled passes, mean and stderr (N, 9) in W/m²: columns 0–2 unshadowed, 3–5 shadowed, 6–8
    E⊥ (the ambient-aperture family reads the same entry for its occluded sphere light)."""
    emitter = setup.emitters[source]
    what = {
        "format": FORMAT,
        "quantity": "light-irradiance",
        "emitter": source,
        "points": array_digest(points, normals, towards),
    }

    def render(spp: int, seed: int):
        return light_irradiance_pass(setup.mi, setup.scene, emitter, points, normals, towards, spp, seed)

    return pooled_passes(setup, what, render, (-1, 9), label)


def diffuse_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The unshadowed and the shadowed case of the light ``app.source`` (module docstring)."""
    if app.source is None:
        raise AuditError(f"diffuse: {app.part} is not a light of the scene")
    light = setup.info.xml.emitters[app.source] if setup.info.xml is not None else None
    if light is None or light.environment:
        raise AuditError(f"diffuse: {app.part}: the audit samples lights, not environments, for this family")
    mask = setup.mask
    gb = setup.gbuffer
    points = gb.position[mask].astype(np.float64)
    normals = gb.normal[mask].astype(np.float64)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    towards, dist, alpha, _centre, radius = light_geometry(setup, app.source, points)
    tag = f"light{app.source}"
    pooled = light_reference(setup, app.source, points, normals, towards, f"{tag}: {app.part}")
    cos = np.clip(np.sum(normals * towards, axis=1), -1.0, 1.0)
    e_perp = pooled.mean[:, 6:9]
    radiance = light_radiance(setup, app.source, e_perp, alpha)
    inputs = tuple(
        {
            "cos_theta": cos,
            "irradiance": e_perp[:, c],
            "alpha": alpha,
            "distance": dist,
            "radiance": radiance[c],
        }
        for c in range(3)
    )
    shadow = _hard_shadow(setup, points, normals, towards, dist, radius)
    params = {
        "light": app.part,
        "kind": light.kind,
        "alpha_max_deg": float(np.degrees(alpha.max())) if alpha.size else 0.0,
        "pixels": int(mask.sum()),
    }
    reason = (
        f"{light.kind} light: Mitsuba emitter sampling of this light alone (Emitter.sample_direction), "
        "white Lambertian receiver at each visible point"
    )
    cases = []
    for k, (what, note, factor) in enumerate(
        (
            ("unshadowed", "the light alone: no occluder between it and the point", None),
            (
                "shadowed",
                "with the scene's own occluders (shadow rays); each method × the hard shadow of the "
                "light's centre, as a shadow map gives it",
                shadow,
            ),
        )
    ):
        ref = pooled.reference(
            mask,
            quantity=f"direct irradiance of one light, {what} (W/m²)",
            integrator="light-irradiance (emitter sampling" + (", shadow rays)" if k else ")"),
            integrator_reason=reason,
            columns=slice(3 * k, 3 * k + 3),
        )
        cases.append(
            FamilyCase(
                id=f"{tag}-{what}",
                label=f"{app.part}, {what}",
                reference=ref,
                mask=mask,
                channel_inputs=inputs,
                parameters={**params, "shadowing": what},
                factor=factor,
                units="W/m²",
                notes=(note,),
            )
        )
    return cases


FAMILY = AuditFamily(
    name="diffuse",
    quantity="light_irradiance",
    cases=diffuse_cases,
    describe=(
        "Per light: its direct irradiance E (W/m², RGB) at each visible point, for the point's normal, "
        "unshadowed and shadowed (separate cases), estimated with Mitsuba's emitter sampling of that light "
        "alone and Mitsuba's shadow rays, in independent passes with per-pixel standard errors. Each method "
        "gets cos θ = n·t (t: towards the light's centre), E⊥ (the light's irradiance on a surface facing "
        "t, from independent samples of the same pass), the light's angular radius α (sphere lights; 0 "
        "otherwise) and distance. "
        "In the shadowed case each method is multiplied by the hard shadow of the light's centre (one "
        "shadow ray), as a shadow map would give it."
    ),
)
