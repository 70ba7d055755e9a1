"""A "real-time engine" frame of a Mitsuba XML scene, composed from rtfit's own approximations (issue 36).

No real-time renderer is installed here, so this script plays one: it shades the scene's sensor the way an
engine's forward pass does, from the approximations rtfit audits, and writes the frame and its AOVs for
``rtfit compare`` (docs/compare.md, "A frame from real-time approximations")::

    python examples/realtime_frame.py SCENE.xml OUT.exr [--aov-dir DIR] [-D name=value …]

**The frame's model**, per pixel (one ray through the pixel's centre: no antialiasing, so compare it with
``--footprint centre``):

1. **G-buffer** (`rtfit.reference.estimators.gbuffer`): the first hit's position, shading normal (facing the
   camera), depth and albedo (Mitsuba's ``eval_diffuse_reflectance`` of its BSDF).
2. **Direct light, per emitter**, from the diffuse family's light-model rows (`rtfit.realtime.light_models`)
   evaluated from the light's own parameters as the audit reads them (`rtfit.experiments.audit_lights`):
   point and sphere lights ``punctual`` (I/d² at the centre; a sphere's I = π r² L), rectangle lights
   ``polygon`` (LTC for a diffuse BRDF), spot lights ``spot-linear`` (Mitsuba's own profile), disk lights
   ``punctual`` (I = L·A·cos θ_l); a directional light ``lambert`` (`rtfit.realtime.diffuse`) with its own
   ``irradiance``. Any other light (a projector, an area light on a mesh, a textured light) is left out with
   a note: no row of the family reads it.
3. **Hard shadows**: one shadow ray per pixel and light towards the light's centre, cast by Mitsuba
   (`audit_lights.hard_shadow`): an ideal shadow map (no resolution, no bias, no acne), but hard — an area
   light's penumbra is either fully lit or fully shadowed.
4. **The environment** (``constant``, ``envmap``, ``sunsky``) as SH L2 irradiance: the irradiance-bases
   family's bake and ``sh-l2`` row (`rtfit.experiments.audit_environment`), unshadowed (no ambient
   occlusion: the sky lights the floor under a ball as if it were open). A ``sunsky``'s sun is taken out of
   the SH and shaded as the engine's directional light: ``lambert`` with its disc's E⊥, a hard shadow.
5. **Radiance** L = albedo/π · E; a pixel that sees a light or the sky shows its emitted radiance (Mitsuba's
   own ``eval``: the engine's emissive material and sky box).

**Not modelled**: specular reflection (every BSDF is shaded as Lambertian with its diffuse reflectance),
indirect (bounce) light, soft shadows, occlusion of the sky, media, the lights left out above.

AOVs (with ``--aov-dir``): ``depth.exr`` (channel ``Z``: the distance along the ray, 0 where no surface) and
``normal.exr`` (world-space shading normals, 0 where no surface), so that compare checks the alignment.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rtfit.experiments.audit import AuditError, inspect_scene
from rtfit.experiments.audit_environment import ROW, environment_bases, environment_of, evaluate_row
from rtfit.experiments.audit_family import AuditSetup
from rtfit.experiments.audit_lights import hard_shadow, light_geometry, light_model_inputs, scene_light
from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.reference.estimators import gbuffer, gbuffer_points
from rtfit.reference.io import write_exr
from rtfit.reference.mitsuba_xml import loaded_xml

ROW_OF_LIGHT = {"point": "punctual", "sphere": "punctual", "rectangle": "polygon", "spot": "spot-linear"}
"""The light-model row per kind of light (any other local light of uniform radiance: ``punctual``)."""


@dataclass
class RealtimeFrame:
    """The frame: ``radiance`` (H, W, 3), its AOVs ``depth`` (H, W; 0: no surface) and ``normal`` (H, W, 3),
    ``mask`` (pixels shaded: a surface that is not a light), ``shadow`` (H, W: 1 where every light's shadow
    ray got through), and ``notes``: what each emitter became."""

    radiance: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    mask: np.ndarray
    shadow: np.ndarray
    notes: list[str] = field(default_factory=list)


def _emitted(mi, scene, sensor, gb) -> np.ndarray:
    """What each pixel-centre ray sees emitted (a light's surface, the sky), by Mitsuba's own ``eval``."""
    origin = np.asarray(sensor.world_transform().matrix, np.float64).reshape(4, 4)[:3, 3]
    d = np.asarray(gb.view_dir, np.float64).reshape(-1, 3)
    o = np.ascontiguousarray(np.tile(origin, (len(d), 1)).T, np.float32)
    ray = mi.Ray3f(mi.Point3f(o), mi.Vector3f(np.ascontiguousarray(d.T, np.float32)))
    si = scene.ray_intersect(ray)
    value = si.emitter(scene).eval(si, True)
    return np.asarray(value, np.float64).T.reshape((*gb.mask.shape, 3))


def _row(row: str, channels: list[dict], cos_theta, dist) -> np.ndarray:
    """E (N, 3): the light-model ``row`` of the diffuse family evaluated on each channel's inputs."""
    method = DIFFUSE[row]
    e = np.zeros((len(cos_theta), 3))
    for c in range(3):
        e[:, c] = np.asarray(method.evaluate({**channels[c], "cos_theta": cos_theta, "distance": dist}))
    return e


def _light(setup, k: int, points, normals, notes) -> tuple[np.ndarray, np.ndarray]:
    """E (N, 3) of the light ``k`` (unshadowed) from its light-model row, and its hard shadow (N,)."""
    none = np.zeros((len(points), 3)), np.ones(len(points))
    try:
        light = scene_light(setup, k)
    except AuditError as e:  # a projector, a light Mitsuba did not instantiate: no row reads it
        notes.append(f"light {k}: left out ({e})")
        return none
    if setup.info.xml.emitters[k].patterned:
        notes.append(f"{light.kind} light {k}: left out (it projects a texture: no cone profile models it)")
        return none
    towards, dist, _alpha, _centre, radius = light_geometry(setup, k, points)
    cos_theta = np.sum(normals * towards, axis=1)
    params = setup.mi.traverse(light.emitter)
    if light.kind == "directional" and "irradiance.value" in params:
        e_perp = np.resize(np.asarray(params["irradiance.value"]).reshape(-1), 3)
        channels, row = [{"irradiance": float(v)} for v in e_perp], "lambert"
    else:
        channels = light_model_inputs(setup, k, points, normals, towards, dist)
        row = ROW_OF_LIGHT.get(light.kind, "punctual")
    if any(name not in {**channels[0], "cos_theta": 0, "distance": 0} for name in DIFFUSE[row].input_names):
        notes.append(f"{light.kind} light {k}: left out (no {row} row: textured, or on a mesh)")
        return none
    shadow = hard_shadow(setup, points, normals, towards, dist, radius, shape=light.emitter.get_shape())
    notes.append(f"{light.kind} light {k}: {row} row, hard shadow")
    return _row(row, channels, cos_theta, dist), shadow


def _sun(setup, sun, points, normals) -> tuple[np.ndarray, np.ndarray]:
    """A sky's sun as an engine's directional light: ``lambert`` with the disc's E⊥, and its hard shadow."""
    towards = np.tile(np.asarray(sun.direction, np.float64), (len(points), 1))
    dist = np.full(len(points), math.inf)
    shadow = hard_shadow(setup, points, normals, towards, dist, 0.0)
    channels = [{"irradiance": float(v)} for v in sun.irradiance]
    return _row("lambert", channels, normals @ np.asarray(sun.direction), dist), shadow


def realtime_frame(scene_path, defines=None, *, variant: str = "llvm_ad_rgb") -> RealtimeFrame:
    """The frame of the Mitsuba XML scene ``scene_path`` through its first sensor (module docstring)."""
    info = inspect_scene(scene_path, defines=defines)
    if info.xml is None or info.xml.camera is None:
        raise AuditError(f"{scene_path}: a Mitsuba XML scene with a <sensor> is needed")
    with loaded_xml(info.xml.source, defines, variant) as loaded, tempfile.TemporaryDirectory() as cache:
        mi, scene, sensor = loaded.mi, loaded.scene, loaded.sensor
        gb = gbuffer(mi, scene, sensor)
        mask = gb.mask & ~gb.emitter
        setup = AuditSetup(mi, scene, sensor, loaded.emitters, info, gb, mask, Path(cache), variant,
                           2, 2, 0, False, "")  # fmt: skip
        points, normals = gbuffer_points(gb, mask)
        e_total = np.zeros((len(points), 3))
        lit = np.ones(len(points))
        notes: list[str] = []
        for k, light in enumerate(info.xml.emitters):
            if light.environment:
                env = environment_of(setup, k)
                if env.sun is not None:  # the sun: a directional light with a hard shadow; the sky in SH
                    e, shadow = _sun(setup, env.sun, points, normals)
                    e_total, lit = e_total + shadow[:, None] * e, lit * shadow
                    notes.append(f"{light.kind} sun {k}: lambert row (E⊥ of its disc), hard shadow")
                    env = replace(env, sun=None)
                e_total += evaluate_row(ROW["sh-l2"], environment_bases(env), normals)
                notes.append(f"{light.kind} environment {k}: sh-l2 (27 floats), unshadowed")
                continue
            e, shadow = _light(setup, k, points, normals, notes)
            e_total, lit = e_total + shadow[:, None] * e, lit * shadow
        radiance = np.where(mask[..., None], 0.0, _emitted(mi, scene, sensor, gb))
        radiance[mask] = gb.albedo[mask].astype(np.float64) / math.pi * e_total
        shadow_img = np.ones(mask.shape)
        shadow_img[mask] = lit
        depth = np.where(gb.mask, gb.depth, 0.0)
        normal = np.where(gb.mask[..., None], gb.normal, 0.0)
        return RealtimeFrame(radiance, depth, normal, mask, shadow_img, notes)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n", 1)[0])
    p.add_argument("scene", help="a Mitsuba XML scene with a sensor")
    p.add_argument("out", help="the frame, an OpenEXR file (linear RGB, 32-bit float)")
    p.add_argument("--aov-dir", help="also write depth.exr and normal.exr here")
    p.add_argument(
        "-D", action="append", default=[], metavar="NAME=VALUE", help="an XML <default> (as rtfit's)"
    )
    args = p.parse_args(argv)
    bad = [d for d in args.D if "=" not in d or not d.split("=", 1)[0]]
    if bad:
        p.error(f"-D {bad[0]!r}: expected NAME=VALUE")  # one line, exit 2, before anything is loaded
    try:
        frame = realtime_frame(args.scene, dict(d.split("=", 1) for d in args.D))
    except (AuditError, ValueError) as e:
        print(f"realtime_frame: error: {e}", file=sys.stderr)
        return 2
    write_exr(args.out, {"RGB": frame.radiance})
    print("\n".join(frame.notes) + f"\nwrote {args.out}")
    if args.aov_dir:
        Path(args.aov_dir).mkdir(parents=True, exist_ok=True)
        write_exr(Path(args.aov_dir) / "depth.exr", {"Z": frame.depth})
        write_exr(Path(args.aov_dir) / "normal.exr", {"RGB": frame.normal})
        print(f"wrote {args.aov_dir}/depth.exr, {args.aov_dir}/normal.exr")
    return 0


if __name__ == "__main__":
    sys.exit(main())
