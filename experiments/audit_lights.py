"""The lights of a user's scene as the light-irradiance families of `rtfit audit` see them.

Shared by the families that compare one light's direct irradiance (the diffuse family, the ambient-aperture
family's occluded sphere light), so that neither imports the other. A light of either scene format — a
Mitsuba XML emitter (`XmlScene.emitters`) or an rtfit TOML light (`Scene.lights`) — becomes one
`AuditLight`: the Mitsuba emitter its reference samples, and the geometry its methods read:

* **local lights** (point, spot, sphere, rectangle, disk, an area light on any mesh): the centre c (a
  point/spot position, a sphere's centre, the centre of an area light's bounding box) and, for a sphere,
  its radius r; seen from x: t = (c − x)/|c − x|, d = |c − x| (scene units), α = asin(r/d) (rad);
* **distant lights** (a directional light, a sun of finite angular radius, the sun of a ``sunsky``): the
  unit direction towards the light t, d = +inf, α = the sun's angular radius (0 for a directional light):
  a uniform disc of directions of angular radius α gives the irradiance of a sphere light of the same
  angular radius, so the exact sphere-light form applies to it too.

The light's radiance L (W/m²/sr, per RGB channel, for the exact form) is the declared one where the scene
declares it (a sphere light's ``radiance``; a TOML sun's E/(π sin²α), read from the Mitsuba plugin rtfit
builds for it), else E⊥/(π sin²α) from the reference's own E⊥.

**The light alone.** The reference samples the light with nothing else emitting: a ``sunsky``'s sun is
sampled with the emitter's ``sky_scale`` set to 0 for the duration of the passes (its sky is the
irradiance-bases family's question), and a TOML sun of finite size (whose Mitsuba emitter carries a
``constant_env`` sky folded into it, `rtfit.reference.build`) by a disc emitter of its own, without the
sky, sized to the scene for its shadow rays.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import numpy as np

from rtfit.reference import emitters as rtfit_emitters
from rtfit.reference.build import light_dicts
from rtfit.reference.cache import array_digest
from rtfit.reference.environments import emitter_scales
from rtfit.reference.light_irradiance import light_irradiance_pass

from .audit import AuditError
from .audit_setup import AuditSetup, PooledPasses, pooled_passes

__all__ = [
    "AuditLight",
    "hard_shadow",
    "light_geometry",
    "light_model_inputs",
    "light_radiance",
    "light_reference",
    "scene_light",
    "small_sphere_caveat",
    "sphere_sampling_precision",
]

FORMAT = 2  # 2: E⊥ from samples of its own (`light_irradiance.PERP_SAMPLES`)
_DIRECTIONAL_FAR = 1e7  # a distant light's "centre": this many scene diagonals away along its direction


@dataclass(frozen=True)
class AuditLight:
    """One light (module docstring): ``kind`` (words for the report), the Mitsuba ``emitter`` its reference
    samples, ``centre`` (local lights, scene units) or ``direction`` (distant lights: unit, towards the
    light), ``radius`` (a sphere light's, scene units; else 0), ``angular_radius`` (a distant disc's α, rad;
    else 0), ``radiance`` (the declared L per channel, or None), ``intensity`` (a point or spot light's
    declared I per channel, W/sr, a spot's on its axis, or None), ``scales`` (emitter parameters set during
    the passes: a sunsky's ``sky_scale`` 0) and ``key`` (what the cache key adds for this light)."""

    kind: str
    emitter: Any
    centre: np.ndarray | None = None
    direction: np.ndarray | None = None
    radius: float = 0.0
    angular_radius: float = 0.0
    radiance: tuple[float, float, float] | None = None
    intensity: tuple[float, float, float] | None = None
    scales: Mapping[str, float] = field(default_factory=dict)
    key: Mapping[str, Any] = field(default_factory=dict)


def _unit(v) -> np.ndarray:
    a = np.asarray(v, np.float64)
    return a / np.linalg.norm(a)


def _bbox_centre(emitter, what: str) -> np.ndarray:
    shape = emitter.get_shape()
    if shape is None:
        raise AuditError(f"{what}: no shape to take its centre from")
    box = shape.bbox()
    lo = np.array([float(box.min[i]) for i in range(3)])
    hi = np.array([float(box.max[i]) for i in range(3)])
    return (lo + hi) / 2


def _xml_light(setup: AuditSetup, source: int) -> AuditLight:
    light = setup.info.xml.emitters[source]
    emitter = setup.emitters[source]
    if emitter is None:
        raise AuditError(f"{light.kind} light ({light.location}): Mitsuba did not instantiate it")
    declared = None
    if light.scale_name == "radiance" and light.scale is not None and len(light.scale) in (1, 3):
        declared = tuple(float(v) for v in light.scale * (3 // len(light.scale)))
    if light.kind == "directional":
        return AuditLight("directional", emitter, direction=_unit(light.direction))
    if light.kind == "sunsky" and light.direction is not None:
        alpha = math.radians(light.angular_radius_deg or 0.0)
        return AuditLight(
            "sunsky sun", emitter, direction=_unit(light.direction), angular_radius=alpha,
            scales={"sky_scale": 0.0}, key={"light": "sunsky sun (sky_scale 0)"},
        )  # fmt: skip
    if light.environment:
        raise AuditError(f"{light.kind} environment ({light.location}): not a light of its own")
    if light.kind in ("point", "spot"):
        centre = np.asarray(light.position, np.float64)
        intensity = None
        if light.scale_name == "intensity" and light.scale is not None and len(light.scale) in (1, 3):
            r, g, b = np.broadcast_to(np.asarray(light.scale, np.float64), (3,)).tolist()  # grey: one value
            intensity = (r, g, b)
        return AuditLight(light.kind, emitter, centre=centre, radiance=declared, intensity=intensity)
    what = f"{light.kind} light ({light.location})"
    centre = _bbox_centre(emitter, what)
    radius = 0.0
    if light.spherical:
        box = emitter.get_shape().bbox()
        radius = float(box.max[0] - box.min[0]) / 2
    return AuditLight(light.kind, emitter, centre=centre, radius=radius, radiance=declared)


def _toml_emitter(mi_scene, index: int, what: str):
    """The emitter that rtfit's Mitsuba build made of ``lights[index]`` (named ``light<index>``: a free
    emitter's own id, an area light's shape's id)."""
    name = f"light{index}"
    for e in mi_scene.emitters():
        shape = e.get_shape()
        if e.id() == name or (shape is not None and shape.id() == name):
            return e
    raise AuditError(f"{what}: Mitsuba did not instantiate it")


def _toml_light(setup: AuditSetup, source: int) -> AuditLight:
    light = setup.source.lights[source]
    what = f"{light.kind} (lights[{source}])"
    mi = setup.mi
    if light.kind == "sun" and light.angular_radius_deg > 0.0:
        # a disc of its own: the scene's carries a constant sky folded into it (module docstring)
        plugin = light_dicts(mi, light)[""]
        rtfit_emitters.register(mi)
        disc = mi.load_dict(plugin)
        disc.attach_to_scene(setup.scene)
        radiance = tuple(float(plugin["radiance"][c]) for c in range(3))
        alpha = math.radians(light.angular_radius_deg)
        return AuditLight("sun disc", disc, direction=_unit(light.direction), angular_radius=alpha,
                          radiance=radiance, key={"light": "sun disc (no sky)"})  # fmt: skip
    emitter = _toml_emitter(setup.scene, source, what)
    if light.kind == "sun":
        return AuditLight("directional", emitter, direction=_unit(light.direction))
    if light.kind == "sunsky":
        alpha = math.radians(light.sun_aperture_deg / 2)
        return AuditLight(
            "sunsky sun", emitter, direction=_unit(light.sun_direction), angular_radius=alpha,
            scales={"sky_scale": 0.0}, key={"light": "sunsky sun (sky_scale 0)"},
        )  # fmt: skip
    if light.kind in ("point_light", "spot_light"):
        r, g, b = (float(v) for v in light.intensity)
        centre = np.asarray(light.position, np.float64)
        return AuditLight(light.kind.split("_")[0], emitter, centre=centre, intensity=(r, g, b))
    if light.kind == "sphere_light":
        return AuditLight("sphere", emitter, centre=np.asarray(light.center, np.float64),
                          radius=float(light.radius), radiance=tuple(light.radiance))  # fmt: skip
    if light.kind == "rect_light":
        return AuditLight("rectangle", emitter, centre=_bbox_centre(emitter, what),
                          radiance=tuple(light.radiance))  # fmt: skip
    raise AuditError(f"{what}: an environment, not a light of its own")


def scene_light(setup: AuditSetup, source: int) -> AuditLight:
    """The `AuditLight` of the scene's light ``source`` (an index into `XmlScene.emitters` for a Mitsuba
    XML scene, into `Scene.lights` for an rtfit TOML scene)."""
    if setup.info.xml is not None:
        return _xml_light(setup, source)
    if setup.info.format == "rtfit-toml" and setup.source is not None:
        return _toml_light(setup, source)
    raise AuditError(f"the audit reads lights of Mitsuba XML and rtfit TOML scenes, not {setup.info.format}")


def light_geometry(setup: AuditSetup, source: int, points: np.ndarray):
    """(towards (N, 3) unit, distance (N,), alpha (N,), centre-or-None, radius) of the light ``source``
    seen from ``points`` (N, 3) (module docstring)."""
    light = scene_light(setup, source)
    p = np.asarray(points, np.float64)
    n = len(p)
    if light.direction is not None:
        alpha = np.full(n, light.angular_radius)
        return np.tile(light.direction, (n, 1)), np.full(n, math.inf), alpha, None, 0.0
    v = light.centre - p
    dist = np.linalg.norm(v, axis=1)
    towards = v / np.maximum(dist, 1e-30)[:, None]
    r = light.radius
    alpha = np.arcsin(np.clip(r / np.maximum(dist, 1e-30), 0.0, 1.0)) if r > 0 else np.zeros(n)
    return towards, dist, alpha, light.centre, r


def hard_shadow(setup: AuditSetup, points, normals, towards, dist, radius, shape=None) -> np.ndarray:
    """1 where a shadow ray from each point towards the light's centre reaches the light (its surface for a
    sphere, the centre's neighbourhood otherwise; `_DIRECTIONAL_FAR` scene diagonals away for a distant
    light), else 0.

    An area light on a shape (``shape``: the emitter's own Mitsuba shape) is reached when the ray's first
    hit is that shape: the centre of a closed mesh's bounding box (an OBJ bulb, a cube light) lies inside
    the mesh, so a ray that must arrive there unblocked would always be stopped by the light's own surface
    (issue 31: a black shadowed case for every method). The first hit of a ray of length d − r is taken
    instead: nothing (the light's centre reached), or the light's own shape (its surface facing the point)
    means lit; any other shape means shadowed."""
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
    if shape is None:
        blocked = setup.scene.ray_test(ray)
        return (~np.asarray(blocked, dtype=bool)).astype(np.float64)
    si = setup.scene.ray_intersect(ray)
    lit = ~si.is_valid() | (si.shape == mi.ShapePtr(shape))
    return np.asarray(lit, dtype=bool).astype(np.float64)


def sphere_sampling_precision(alpha: np.ndarray) -> np.ndarray:
    """The relative precision of Mitsuba's estimate of a sphere light's irradiance at angular radius
    ``alpha`` (rad) per point (issue 31 g): Mitsuba samples the light's cone with the density
    1/(2π(1 − cos α)), cos α rounded to float32 (absolute error up to 2⁻²⁴ just below 1; 1 − cos α itself is
    then exact, Sterbenz), so its estimate carries a relative bias up to 2⁻²⁴/(1 − cos α) ≈ 2⁻²³/α², a
    bias no number of samples removes. Measured against the closed form in float64 (2²⁰ samples, r = 0.0333,
    the Veach scene's smallest sphere, normal facing the light): +6.4e-5 at d = 1 (bound 1.1e-4), −5.1e-5
    at d = 2.5 (3.4e-4), +9.7e-4 at d = 4 (1.7e-3), +5.5e-4 at d = 6 (3.9e-3): within the bound at every
    distance, and 10²–10³× the estimate's own standard error at 32 spp. It enters the reference's σ as its
    precision floor (`AuditReference.precision`): a pixel whose noise is below it carries no statistics for
    the exact row's z-check (only its tail check, within that floor), instead of failing the check on the
    reference's bias (the Veach scene's three failed checks, median z −0.72)."""
    one_minus_cos = 2.0 * np.sin(np.asarray(alpha, np.float64) / 2.0) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(one_minus_cos > 0, 2.0**-24 / one_minus_cos, 0.0)


def small_sphere_caveat(alpha: np.ndarray, mean: np.ndarray, stderr: np.ndarray) -> tuple[str, ...]:
    """A note where the reference of a very small sphere light is biased beyond its own noise
    (`sphere_sampling_precision`): ``alpha`` the light's angular radius per point (rad), ``mean``/``stderr``
    the reference's first channel."""
    bias = sphere_sampling_precision(alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.asarray(stderr, np.float64) / np.abs(np.asarray(mean, np.float64))
    rel = rel[np.isfinite(rel) & (rel > 0)]
    if not rel.size or np.median(bias) <= 0.5 * np.median(rel):
        return ()
    return (
        f"a very small sphere light (α down to {float(np.min(alpha)):.3g} rad): Mitsuba's float32 cone "
        f"sampling biases this reference by up to 2⁻²⁴/(1 − cos α), median {float(np.median(bias)):.2g} "
        f"relative (its noise: {float(np.median(rel)):.2g}); that bound is the reference's precision floor "
        "(in its σ and noise floors): the exact row is z-checked only where the noise exceeds it",
    )


def light_radiance(setup: AuditSetup, source: int, e_perp: np.ndarray, alpha: np.ndarray) -> list:
    """Per channel: the light's declared radiance, else E⊥/(π sin²α) (0 where α = 0)."""
    declared = scene_light(setup, source).radiance
    if declared is not None:
        return [float(v) for v in declared]
    s2 = np.sin(alpha) ** 2
    return [np.where(s2 > 0, e_perp[:, c] / (math.pi * np.maximum(s2, 1e-300)), 0.0) for c in range(3)]


def _rgb(params, key: str) -> np.ndarray | None:
    """A uniform RGB parameter of a Mitsuba object's `mi.traverse` (None where it is a texture)."""
    if key not in params:
        return None
    v = np.asarray(params[key], np.float64).reshape(-1)
    return np.resize(v, 3) if v.size in (1, 3) else None


def _matrix(transform) -> np.ndarray:
    return np.asarray(transform.matrix, np.float64).reshape(4, 4)


def light_model_inputs(setup: AuditSetup, source: int, points, normals, towards, dist) -> list[dict]:
    """Per RGB channel, the inputs the light models (`rtfit.realtime.light_models`) read **from the light's
    own parameters** (Mitsuba's instantiated emitter and shape, `mi.traverse`), never from the reference:

    * a point light: ``intensity`` I (W/sr, its ``intensity``);
    * a spot light: ``axis_intensity`` I₀, ``cutoff``/``beam`` (rad, its ``cutoff_angle``/``beam_width``),
      ``cos_axis`` = the spot's axis (to_world's +z) · the direction from the light to the point;
    * a sphere light of uniform radiance L and radius r: ``intensity`` π r² L (its projected area × L);
    * a rectangle or disk light of uniform radiance L (one-sided, towards to_world's +z): ``intensity``
      L·A·max(cos θ_l, 0) (A = 4|u × v| or π|u × v|, u, v the images of the x and y axes); a rectangle also
      gives the polygon row its centre, half-edges u, v and the points and normals (``px``…, ``nx``…), a
      circular disk (|u| = |v|, u ⊥ v) the disc row its centre (``dcx``…), unit normal u × v/|u × v|
      (``dmx``…), radius |u| (``disc_radius``) and the points and normals;
    * a circular ``cylinder`` light of uniform radiance L (a tube: open ends, emitting outwards; to_world
      maps the unit cylinder z ∈ [0, 1] to radius r = |u|, axis w from p0): ``intensity`` 2rℓL|sin ψ| (its
      projected area × L, ψ between the axis and the direction to the point) and the tube row its axis's
      ends p0, p0 + w (``tax``…, ``tbx``…), ``tube_radius`` r and the points and normals;

    an empty mapping per channel for any other light (its light-model rows are left out by `PROVIDES`)."""
    mi = setup.mi
    light = scene_light(setup, source)
    out: dict[str, Any] = {}
    if light.emitter is None or light.centre is None:
        return [{}, {}, {}]
    params = mi.traverse(light.emitter)
    shape = light.emitter.get_shape()
    per_channel: dict[str, np.ndarray] = {}
    if light.kind in ("point", "spot") and (i0 := _rgb(params, "intensity.value")) is not None:
        if light.kind == "point":
            per_channel["intensity"] = i0
        else:
            m = _matrix(params["to_world"])
            axis = _unit(m[:3, 2])
            out["cos_axis"] = np.clip(-(towards @ axis), -1.0, 1.0)
            out["cutoff"] = math.radians(float(np.asarray(params["cutoff_angle"]).reshape(-1)[0]))
            out["beam"] = math.radians(float(np.asarray(params["beam_width"]).reshape(-1)[0]))
            per_channel["axis_intensity"] = i0
    radiance = _rgb(params, "radiance.value")
    kind = str(shape).split("[", 1)[0].strip() if shape is not None else ""
    scale: np.ndarray | float | None = None  # intensity / radiance (sr·m² per … : the projected area)
    if radiance is not None and light.radius > 0:
        scale = math.pi * light.radius**2  # a sphere: π r²
    elif radiance is not None and kind in ("Rectangle", "Disk"):
        m = _matrix(mi.traverse(shape)["to_world"])
        u, v, c = m[:3, 0], m[:3, 1], m[:3, 3]
        cross = np.cross(u, v)
        area = (4.0 if kind == "Rectangle" else math.pi) * float(np.linalg.norm(cross))
        scale = area * np.clip(-(towards @ _unit(cross)), 0.0, None)  # A·max(cos θ_l, 0): one-sided
        p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
        if kind == "Rectangle":
            for k, a in enumerate("xyz"):
                out |= {f"p{a}": p[:, k], f"n{a}": n[:, k], f"lc{a}": float(c[k])}
                out |= {f"lu{a}": float(u[k]), f"lv{a}": float(v[k])}
            per_channel["radiance"] = radiance
        elif setup.info.xml is not None and not setup.info.xml.emitters[source].elliptical:  # a circle
            m = _unit(cross)
            for k, a in enumerate("xyz"):
                out |= {f"p{a}": p[:, k], f"n{a}": n[:, k], f"dc{a}": float(c[k]), f"dm{a}": float(m[k])}
            out["disc_radius"] = float(np.linalg.norm(u))
            per_channel["radiance"] = radiance
    elif radiance is not None and kind == "Cylinder":
        m = _matrix(mi.traverse(shape)["to_world"])
        r, w, p0 = float(np.linalg.norm(m[:3, 0])), m[:3, 2], m[:3, 3]
        length = float(np.linalg.norm(w))
        cos_psi = towards @ (w / max(length, 1e-300))
        scale = 2.0 * r * length * np.sqrt(np.clip(1.0 - cos_psi * cos_psi, 0.0, 1.0))  # 2rℓ|sin ψ|
        p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
        for k, a in enumerate("xyz"):
            out |= {f"p{a}": p[:, k], f"n{a}": n[:, k], f"ta{a}": float(p0[k]), f"tb{a}": float(p0[k] + w[k])}
        out["tube_radius"] = r
        per_channel["radiance"] = radiance
    channels = []
    for ch in range(3):
        d = dict(out)
        d.update({k: float(v[ch]) for k, v in per_channel.items()})
        if scale is not None and radiance is not None:
            d["intensity"] = scale * float(radiance[ch])
        channels.append(d)
    return channels


def light_reference(setup: AuditSetup, source: int, points, normals, towards, label: str) -> PooledPasses:
    """The light's pooled passes, mean and stderr (N, 9) in W/m²: columns 0–2 unshadowed, 3–5 shadowed, 6–8
    E⊥ (`rtfit.reference.light_irradiance`), the light alone (module docstring)."""
    light = scene_light(setup, source)
    what = {
        "format": FORMAT,
        "quantity": "light-irradiance",
        "emitter": source,
        "points": array_digest(points, normals, towards),
        **light.key,
    }

    def render(spp: int, seed: int):
        with _alone(setup.mi, light):
            return light_irradiance_pass(
                setup.mi, setup.scene, light.emitter, points, normals, towards, spp, seed
            )

    return pooled_passes(setup, what, render, (-1, 9), label)


def _alone(mi, light: AuditLight):
    """The light's emitter with its `AuditLight.scales` set (put back afterwards)."""
    if not light.scales:
        return contextlib.nullcontext(light.emitter)
    return emitter_scales(mi, light.emitter, **light.scales)
