r"""The ``streaky-reflections`` family in `rtfit audit`: a small light's glossy reflection in a rough specular
plane (a wet street), path traced, against the seed's mirror image streaked vertically (000:757-807).

For each rough reflective shape (``roughplastic``, ``roughconductor``, ``roughdielectric``:
`rtfit.reference.reflective_shapes.REFLECTIVE_BSDFS`) that the camera sees as a plane, and each point or
uniform sphere light of the scene above it (on the camera's side), one case ``plane<i>-light<j>``, in a
Mitsuba XML scene or in an rtfit TOML scene (its plane a ``mitsuba_xml`` shape keeping its file's BSDFs,
its lights TOML ``point_light``/``sphere_light``: `audit_lights.scene_light` reads either format):

* **pixels**: the pixel-centre camera rays whose first hit is that shape (`audit_geometry.shape_view`);
* **reference**: Mitsuba's ``path`` (unbounded depth) along those rays with **that light alone** (every
  other emitter's radiance, intensity or scale set to 0 for the passes, then put back: `emitters_alone`), in
  passes through the pass cache (`ray_radiance_pass`): the plane's reflected radiance of the one light
  (W/m²/sr, RGB);
* **inputs** (`rtfit.realtime.streaky_reflections`): the light's mirror point c' = c − 2((c − p₀)·n)n
  projected on the camera's image plane (tangents at unit focal length, the camera's local x and up axes),
  each pixel's offset (``du``, ``dv``) from it, its radius ``rho`` = r/z', ``e_mirror`` = L_e·F(θ_m)·π·rho²
  (F: Mitsuba's own Fresnel of the material at the mirror angle, × its uniform specular reflectance),
  ``distance`` D camera–light; per pixel n·l, n·v, n·h, Mitsuba's Fresnel at v·h, ``e_perp`` = L_e·Ω
  (I/d² for a point light) and the BSDF's α;
* **rows**: the seed's streak (σy = k·D), the same without the distance law (σy fitted), an isotropic
  blur, and the GGX point-light BRDF. The fits start from a small-angle reading of the lobe
  (docs/streaky-reflections.md): σy ≈ α/(1 + h/H), σx ≈ αH/D (h, H: the camera's and the light's height
  over the plane).

Assumptions (in each case's notes): nothing shadows the plane from the light (the rows have no shadow
term); a ``roughplastic`` with a non-black diffuse base adds a diffuse term no row models (said in the
notes); a Beckmann distribution is read as GGX by the ``ggx-point`` row (said in the notes).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Any

import numpy as np

from rtfit.realtime.streaky_reflections import METHODS
from rtfit.reference.cache import array_digest
from rtfit.reference.emitters import PLUGIN as DISC_PLUGIN
from rtfit.reference.reflective_shapes import bsdf_roughness, ray_radiance_pass

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import reflective_shape, shape_view, visible_subset
from .audit_lights import AuditLight, scene_light
from .audit_setup import AuditSetup, pooled_passes
from .case_inputs import vector_text
from .shipped import Sizes

__all__ = ["ALPHA", "FAMILY", "SCENES", "emitters_alone", "mirror_point", "streak_cases"]

FORMAT = 1
PLANE_TOLERANCE = 1e-3
"""Largest deviation of the shape's visible normals from their mean (and of its points from their plane,
relative to the camera distance) for it to count as a plane: the mirror image needs one."""
_EMISSION = ("radiance", "intensity", "irradiance", "scale", "sun_scale", "sky_scale")
"""The emitter parameters (`mi.traverse` keys, or their ``.value``) set to 0 for a light-alone pass."""
_DISC_EMISSION = ("radiance", "sky", "weight")
"""The attributes set to 0 for a light-alone pass on rtfit's own distant disc (`rtfit.reference.emitters`: an
rtfit TOML sun of finite size, a ``constant_env`` sky folded into it), a Python emitter `mi.traverse` sees no
parameter of (RGB variants: the audit's)."""
_CONDUCTORS = frozenset({"roughconductor"})
ALPHA = 0.1
"""The shipped street's GGX roughness α. One α only: every blur width scales with α (the family's page),
so the engine's pooled fit (one setting for every case) is meaningful across the street's lamps, not across
roughness; other α through ``rtfit audit … -D alpha=…``."""

SCENES = (
    Sizes(full=(64, 64, 256), quick=(32, 32, 64)).scene(
        "streaky_reflections_street.xml",
        f"a wet street (η = 1.33, GGX α = {ALPHA:g}), two sphere lamps 12 m and 28 m away, a camera at 1.7 m",
        defines={"alpha": f"{ALPHA:g}"},
    ),
)
"""The scenes ``rtfit run streaky-reflections`` audits (scenes/library/streaky_reflections_street.xml)."""


def mirror_point(centre, p0, n) -> np.ndarray:
    """c' = c − 2((c − p₀)·n)n: the light's centre mirrored in the plane through p₀ of unit normal n."""
    c = np.asarray(centre, np.float64)
    nn = np.asarray(n, np.float64)
    return c - 2.0 * float((c - np.asarray(p0, np.float64)) @ nn) * nn


@contextlib.contextmanager
def emitters_alone(mi, scene, keep):
    """The scene with every emitter but ``keep`` dark (their `_EMISSION` parameters 0; rtfit's distant disc's
    `_DISC_EMISSION` attributes 0), put back after. An emitter with none of them (a textured emission):
    `AuditError`, one line, rather than a reference lit by it."""
    saved, disc = [], []
    try:
        for e in scene.emitters():
            if e is keep:
                continue
            if str(e).startswith(f"{DISC_PLUGIN}["):
                for name in _DISC_EMISSION:
                    value = getattr(e, name)
                    disc.append((e, name, value))
                    setattr(e, name, type(value)(0.0))
                continue
            params: Any = mi.traverse(e)
            keys = [k for k in params.keys() if k.removesuffix(".value") in _EMISSION]
            if not keys:
                what = str(e).split("[", 1)[0].strip()
                raise AuditError(
                    f"{FAMILY.name}: cannot darken the emitter {what} for another light's reference (none of "
                    f"its parameters is {', '.join(_EMISSION)})"
                )
            for key in keys:
                saved.append((params, key, type(params[key])(params[key])))
                params[key] = type(params[key])(0.0)
            params.update()
        yield scene
    finally:
        for params, key, value in saved:
            params[key] = value
            params.update()
        for e, name, value in disc:
            setattr(e, name, value)


def _camera_frame(setup: AuditSetup) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), axes (3, 3): the sensor's local x, y (up), z (view) in world space, as columns)."""
    m = np.asarray(setup.sensor.world_transform().matrix, np.float64).reshape(4, 4, -1)[..., 0]
    axes = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    return m[:3, 3], axes


def _plane(points: np.ndarray, normals: np.ndarray, origin: np.ndarray):
    """(p₀, n toward the camera) where the points and normals lie on one plane (`PLANE_TOLERANCE`), else
    None."""
    n = normals.mean(axis=0)
    n /= np.linalg.norm(n)
    if np.max(np.linalg.norm(normals - n, axis=1)) > PLANE_TOLERANCE:
        return None
    p0 = points.mean(axis=0)
    scale = max(float(np.max(np.linalg.norm(points - origin, axis=1))), 1e-12)
    if np.max(np.abs((points - p0) @ n)) > PLANE_TOLERANCE * scale:
        return None
    return p0, (n if float((origin - p0) @ n) > 0.0 else -n)


def _uniform(params, name: str) -> np.ndarray | None:
    """A BSDF parameter's (3,) RGB value (grey copied), or None where it is absent or a texture."""
    keys = [k for k in params.keys() if k in (name, f"{name}.value")]
    if not keys:
        return None
    v = np.array(params[keys[0]], np.float64).reshape(-1)
    return np.broadcast_to(v, (3,)).copy() if v.size in (1, 3) else None


def _material(mi, shape, plugin: str):
    """(fresnel(cos) → (N, 3), α, notes) of the rough BSDF: Mitsuba's own ``fresnel`` (dielectric, relative
    η) or ``fresnel_conductor`` (η, k per channel), × a uniform specular reflectance; None where η, k or the
    specular reflectance is a texture."""
    params: Any = mi.traverse(shape.bsdf())
    eta = _uniform(params, "eta")
    spec = _uniform(params, "specular_reflectance")
    has_spec = any(k.startswith("specular_reflectance") for k in params.keys())
    kappa = _uniform(params, "k") if plugin in _CONDUCTORS else np.zeros(3)
    if eta is None or kappa is None or (has_spec and spec is None):
        return None
    spec = np.ones(3) if spec is None else spec

    def fresnel(cos) -> np.ndarray:
        c = mi.Float(np.ascontiguousarray(np.clip(cos, 0.0, 1.0), np.float32))
        if plugin in _CONDUCTORS:
            f = [
                np.array(mi.fresnel_conductor(c, mi.Complex2f(float(eta[i]), float(kappa[i]))))
                for i in range(3)
            ]
        else:
            f = [np.array(mi.fresnel(c, mi.Float(float(eta[i])))[0]) for i in range(3)]
        return np.stack(f, axis=1).astype(np.float64) * spec

    notes = [
        f"{plugin}: η = {vector_text(eta)}, k = {vector_text(kappa)}, "
        f"specular reflectance {vector_text(spec)}"
    ]
    diffuse = _uniform(params, "diffuse_reflectance")
    textured = diffuse is None and any(k.startswith("diffuse_reflectance") for k in params.keys())
    if textured or (diffuse is not None and np.any(diffuse > 0.0)):
        notes.append("its diffuse base is not black: the reference holds a diffuse term no row models")
    if "distribution = ggx" not in str(shape.bsdf()):
        notes.append("its microfacet distribution is not GGX: the ggx-point row reads its α as GGX's")
    return fresnel, bsdf_roughness(mi, shape), notes


def _light_emission(light: AuditLight):
    """(radiance L_e (3,) or None, intensity I (3,) W/sr, radius r) of a sphere or point light, as the scene
    declares it (either format: `audit_lights.scene_light`); None for any other light, or one whose emission
    is not uniform."""
    if light.kind == "sphere" and light.radiance is not None and light.radius > 0.0:
        le = np.asarray(light.radiance, np.float64)
        return le, le * math.pi * light.radius**2, light.radius
    if light.kind == "point" and light.intensity is not None:
        return None, np.asarray(light.intensity, np.float64), 0.0
    return None


def _starts(alpha: float, h_cam: float, h_light: float, distance: float, rho: float) -> dict[str, dict]:
    """The fits' starts from the small-angle reading of the lobe (module docstring), inside the bounds; the
    quad row's in units of the mirror image's radius rho."""
    a = max(alpha, 1e-3)
    sy = a / (1.0 + h_cam / h_light)
    sx = a * h_light / distance
    unit = max(rho, 1e-6)
    start = {"sigma_x": sx, "sigma_y": sy, "k": sy / distance, "sigma": math.sqrt(sx * sy)}
    quad = {"width": sx / unit, "k": sy / (distance * unit)}
    out: dict[str, dict] = {}
    for mid, m in METHODS.items():
        values = quad if "width" in m.params else start
        out[mid] = {
            name: dataclasses.replace(p, initial=float(np.clip(values[name], p.lower + 1e-6, p.upper * 0.99)))
            for name, p in m.params.items()
            if name in values
        }
    return out


def _light_case(
    setup, app, index, shape_text, rays, plane, material, source, light_part
) -> FamilyCase | None:
    mi, scene = setup.mi, setup.scene
    origins, dirs, points, mask = rays
    p0, n = plane
    fresnel, alpha, material_notes = material
    light = scene_light(setup, source)
    emission = _light_emission(light)
    if emission is None or light.centre is None:
        return None
    le, intensity, radius = emission
    centre = np.asarray(light.centre, np.float64)
    origin, axes = _camera_frame(setup)
    h_light, h_cam = float((centre - p0) @ n), float((origin - p0) @ n)
    mirror = mirror_point(centre, p0, n)
    m = (mirror - origin) @ axes
    if h_light <= radius or h_cam <= 0.0 or m[2] <= 0.0:
        return None  # below the plane, touching it, or its mirror image behind the camera
    # per pixel: image-plane offsets from the mirror image
    local = dirs @ axes
    tan = local[:, :2] / np.maximum(local[:, 2:3], 1e-12)
    du, dv = tan[:, 0] - m[0] / m[2], tan[:, 1] - m[1] / m[2]
    rho = radius / m[2]
    to_mirror = mirror - origin
    cos_m = abs(float(to_mirror @ n)) / float(np.linalg.norm(to_mirror))
    f_m = fresnel(np.array([cos_m]))[0]
    e_mirror = (le * f_m * math.pi * rho**2) if le is not None else f_m * intensity / m[2] ** 2
    distance = float(np.linalg.norm(centre - origin))
    # per pixel: the microfacet terms toward the light's centre
    to_light = centre - points
    d = np.linalg.norm(to_light, axis=1)
    l_dir = to_light / d[:, None]
    v = -dirs
    h = l_dir + v
    h /= np.maximum(np.linalg.norm(h, axis=1), 1e-30)[:, None]
    f_h = fresnel(np.einsum("ij,ij->i", v, h))
    if le is not None:
        s2 = np.minimum((radius / d) ** 2, 1.0)
        e_perp = le[None, :] * (2.0 * math.pi * s2 / (1.0 + np.sqrt(1.0 - s2)))[:, None]
    else:
        e_perp = intensity[None, :] / (d * d)[:, None]
    geometry = {"du": du, "dv": dv, "rho": rho, "distance": distance, "cos_nl": l_dir @ n, "cos_nv": v @ n,
                "cos_nh": h @ n, "alpha": alpha}  # fmt: skip
    channels = tuple(
        {**geometry, "e_mirror": float(e_mirror[c]), "fresnel_h": f_h[:, c], "e_perp": e_perp[:, c]}
        for c in range(3)
    )
    tag = f"plane{app.source}-light{source}"
    what = {"format": FORMAT, "quantity": "streak-radiance", "shape": index, "emitter": source,
            "rays": array_digest(origins, dirs)}  # fmt: skip

    with emitters_alone(mi, scene, light.emitter):
        pass  # every other emitter can be darkened (else one line, before any pass; cached or not)

    def render(spp: int, seed: int):
        with emitters_alone(mi, scene, light.emitter):
            return ray_radiance_pass(mi, scene, origins, dirs, spp, seed)

    pooled = pooled_passes(setup, what, render, (-1, 3), f"{tag}: {shape_text} × {light_part}")
    reference = pooled.reference(
        mask,
        quantity="radiance of the plane's pixels with that light alone (W/m²/sr)",
        integrator="path (unbounded depth, Russian roulette) along the pixel-centre rays, that light alone",
        integrator_reason="Mitsuba's own rough BSDF and the light's emitter sampling: the glossy reflection",
    )  # fmt: skip
    return FamilyCase(
        id=tag,
        label=f"{shape_text} × {light_part}, reflected radiance",
        reference=reference,
        channel_inputs=channels,
        parameters={
            "shape": shape_text,
            "light": light_part,
            "alpha": alpha,
            "distance": distance,
            "camera_height": h_cam,
            "light_height": h_light,
            "mirror_angle_deg": math.degrees(math.acos(cos_m)),
            "mirror_image": [float(m[0] / m[2]), float(m[1] / m[2])],
            "rho": rho,
            "pixels": int(mask.sum()),
        },
        units="W/m²/sr",
        notes=(
            *material_notes,
            f"light at {vector_text(centre)} (r = {radius:.3g}), D = {distance:.3g} m, "
            f"height {h_light:.3g} m over the plane (camera: {h_cam:.3g} m); "
            f"mirror angle {math.degrees(math.acos(cos_m)):.3g}° "
            f"(F = {vector_text(f_m)})",
            "the rows have no shadow term: nothing may shadow the plane from the light",
            f"fits start at σy = α/(1 + h/H), σx = αH/D, k = σy/D, w = σx/rho (small-angle lobe; "
            f"α = {alpha:.3g})",
        ),
        params=_starts(alpha, h_cam, h_light, distance, rho),
    )


def streak_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per point or sphere light above the rough plane ``app`` names (module docstring); none where
    the shape is not a plane, the camera sees none of it, or its material's Fresnel is a texture."""
    if not setup.wants(FAMILY.quantity):
        return []
    index, shape, plugin = reflective_shape(setup, app, FAMILY.name)
    material = _material(setup.mi, shape, plugin)
    origins, dirs, sees = shape_view(setup, index)
    if material is None or not sees.any():
        return []
    points = setup.gbuffer.position[setup.mask][sees].astype(np.float64)
    normals = setup.gbuffer.normal[setup.mask][sees].astype(np.float64)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    plane = _plane(points, normals, origins[0])
    if plane is None:
        return []
    rays = (origins[sees], dirs[sees], points, visible_subset(setup.mask, sees))
    lights = [p for p in setup.info.parts if "punctual-light" in p.kinds and p.source is not None]
    cases = [
        _light_case(setup, app, index, app.part, rays, plane, material, p.source, p.label) for p in lights
    ]
    return [c for c in cases if c is not None]


FAMILY = AuditFamily(
    name="streaky-reflections",
    quantity="streak_radiance",
    cases=streak_cases,
    describe=(
        "Per rough specular plane (roughplastic, roughconductor: a wet street) and each point or sphere "
        "light above it: the plane's reflected radiance of that light alone, path traced along the "
        "pixel-centre rays, against the seed's mirror image streaked vertically with σy = k·D "
        "(000:757-807), the same streak without the distance law, an isotropic blur, and the GGX microfacet "
        "BRDF toward the light's centre."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "streaky-reflections",
            "light streak in a rough plane",
            ("rough-shape", "punctual-light"),
            "{part} reflects {with_}: an engine draws the light's glossy reflection as its mirror image "
            "streaked vertically toward the viewer (a plane, a point or sphere light above it)",
            "the plane's path-traced radiance of each point or sphere light alone (W/m²/sr, RGB)",
            "path (unbounded depth) along the pixel-centre camera rays, every other emitter dark",
            supplies=frozenset(i.name for m in METHODS.values() for i in m.inputs),
        ),
    ),
)
