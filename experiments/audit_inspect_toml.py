"""The audit's reader of rtfit's own scenes: a TOML scene or an rtfit sky file as `SceneInfo` parts.

`toml_info` turns a loaded rtfit TOML scene (`rtfit.scenes.load_scene`) into the audit's parts
(`rtfit.experiments.audit_parts`): each light (a sunsky's sun a light of its own, its sky a Nishita target),
the surfaces, the geometry that can occlude itself (`can_interreflect`), the probe grid's box and the
reflective shapes (both as Mitsuba loads the shapes, in a scoped inspection variant), each medium, point and
spot lights inside a homogeneous medium's boundary, and the bump maps of ``mitsuba_xml`` shapes that keep
their file's BSDFs. `sky_info` reads an rtfit sky file (format ``rtfit.sky/1``): a spherical-shell
atmosphere. rtfit TOML scenes are +z up.
"""

from __future__ import annotations

from rtfit.reference.build import inside_boundary, load_dict, mitsuba_scene_dict
from rtfit.reference.integrators import can_interreflect
from rtfit.reference.nishita_sky import load_atmosphere_scene
from rtfit.reference.parallax_occlusion import bump_kind
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS, shape_plugin
from rtfit.reference.variants import inspection_variant, scoped_variant
from rtfit.scenes import ENVIRONMENT_KINDS, Scene
from rtfit.scenes.model import PointLight, SpotLight

from .audit_parts import (
    LIT_KINDS,
    Part,
    SceneInfo,
    counts_text,
    model_kinds,
    reflective_kinds,
    vec_text,
    volume_part,
)

__all__ = ["sky_info", "toml_info"]

_TOML_MODEL_KIND = {
    "point_light": "point",
    "spot_light": "spot",
    "sphere_light": "sphere",
    "rect_light": "rectangle",
}


def toml_info(scene: Scene, source: str, up: str | None) -> SceneInfo:
    """The `SceneInfo` of a loaded rtfit TOML scene (``source``: its path; ``up``: ``--up``, else ``None``:
    +z)."""
    parts: list[Part] = []
    bbox = _toml_bbox(scene)
    for i, light in enumerate(scene.lights):
        where = f"lights[{i}]"
        if light.kind in ENVIRONMENT_KINDS:
            label = f"{light.kind} environment ({where})"
            kinds = {"environment"}
            if getattr(light, "sun_direction", None) is not None:  # a sunsky: its sun is a light of its own
                sun = {"light", "spherical-light"} if light.sun_aperture_deg > 0.0 else {"light"}
                parts.append(Part(frozenset(sun), f"the sun of the {label}", i))
                kinds.add("sky")  # and its sky a Nishita target
            parts.append(Part(frozenset(kinds), label, i))
            continue
        spherical = light.kind == "sphere_light" or getattr(light, "angular_radius_deg", 0.0) > 0.0
        kinds = {"light", "spherical-light"} if spherical else {"light"}
        kinds |= model_kinds(_TOML_MODEL_KIND.get(light.kind, light.kind), True)
        parts.append(Part(frozenset(kinds), f"{light.kind.replace('_', ' ')} ({where})", i))
    if scene.shapes:
        parts.append(Part(frozenset({"surface"}), f"{len(scene.shapes)} shape(s)"))
        if can_interreflect(scene):
            types = counts_text(s.kind for s in scene.shapes)
            # (rtfit's TOML shapes are spheres, boxes, rectangles and meshes: a distance field reads them all)
            parts.append(Part(frozenset({"geometry", "sdf-geometry"}), f"the scene's geometry ({types})"))
        if bbox is not None:
            parts.append(volume_part(bbox))
        for index, plugin, where, sphere in _toml_reflective(scene):
            text = f"{REFLECTIVE_BSDFS[plugin].text} shape ({where}: {plugin})"
            parts.append(Part(reflective_kinds(plugin, sphere), text, index))
    for i, medium in enumerate(scene.media):
        kind = {
            "exponential_fog": {"fog"},
            "homogeneous": {"medium", "particle", "constant-fog", "fog-medium"},
        }.get(medium.kind, {"medium"})
        label = f"{medium.kind.replace('_', ' ')} medium (media[{i}])"
        if "particle" in kind:
            label = f"homogeneous medium in a {medium.boundary.kind} (media[{i}])"
        parts.append(Part(frozenset(kind), label, i))
    lit, lit_notes = _toml_lights_in_media(scene)
    parts += lit
    bumps, bump_notes = _toml_height_fields(scene)
    parts += bumps
    c = scene.camera
    axis = up or "+z"
    reason = f"{up} as given (--up)" if up else "+z: rtfit TOML scenes are +z up (the world-frame convention)"
    notes = (
        "height-fog: an exponential_fog medium is height fog; a homogeneous medium is audited as constant "
        "fog (c = 0)",
        *lit_notes,
        *bump_notes,
    )
    return SceneInfo(
        source=source,
        format="rtfit-toml",
        parts=tuple(parts),
        bbox=bbox,
        up=axis,
        up_reason=reason,
        camera=f"{c.width}×{c.height}, fov {c.fov_deg:.4g}° (x), origin {vec_text(c.origin)} looking at "
        f"{vec_text(c.target)}",
        contents=(f"rtfit TOML scene {scene.name!r}: {', '.join(sorted(scene.parts()))}",),
        notes=notes,
    )


def _toml_lights_in_media(scene: Scene) -> tuple[list[Part], tuple[str, ...]]:
    """A ``point-in-medium`` (``spot-in-medium``) part (source: the light's index) for each point (spot)
    light inside a homogeneous medium's boundary, and a note for each such light that is not."""
    parts, notes = [], []
    for i, light in enumerate(scene.lights):
        if not isinstance(light, PointLight | SpotLight):
            continue
        kind, family = LIT_KINDS["point" if isinstance(light, PointLight) else "spot"]
        inside = [j for j, m in enumerate(scene.media) if inside_boundary(m.boundary, light.position)]
        homogeneous = [j for j in inside if scene.media[j].kind == "homogeneous"]
        what = light.kind.replace("_", " ")
        if homogeneous:
            text = f"{what} (lights[{i}]) inside the homogeneous medium (media[{homogeneous[0]}])"
            parts.append(Part(frozenset({kind}), text, i))
        elif inside:
            notes.append(f"{family}: the {what} lights[{i}] sits in media[{inside[0]}], not homogeneous")
        else:
            notes.append(f"{family}: the {what} lights[{i}] is not inside a medium")
    return parts, tuple(notes)


def _toml_height_fields(scene: Scene) -> tuple[list[Part], tuple[str, ...]]:
    """A ``height-field`` part (source: its ordinal, the order of `height_field_shapes`) for each shape of a
    ``mitsuba_xml`` shape that keeps its file's BSDFs, where that BSDF is a bumpmap of a bitmap; a note for
    each bump or normal map that cannot serve (rtfit's own materials are diffuse: they have none)."""
    keeps = [getattr(s, "override_material", None) is None for s in scene.shapes if s.kind == "mitsuba_xml"]
    if not any(keeps):
        return [], ("parallax-occlusion: rtfit TOML materials are diffuse: a bump map comes only with a "
                    "mitsuba_xml shape that keeps its file's BSDFs",)  # fmt: skip
    parts, notes = [], []
    with scoped_variant(inspection_variant()) as mi:
        d = mitsuba_scene_dict(mi, Scene(name=scene.name, camera=scene.camera, shapes=scene.shapes))
        for key, obj in d.items():
            if not (key.startswith("xml") and isinstance(obj, mi.Shape)):
                continue
            kind = bump_kind(mi, obj.bsdf())
            plugin = "normalmap" if kind == "normalmap" else "bumpmap"
            what = f"the {plugin} on shapes[{key[3:].split('_')[0]}] ({key})"
            if kind == "bitmap":
                label = f"{what}: its bitmap texture as a height field"
                parts.append(Part(frozenset({"height-field"}), label, len(parts)))
            elif kind == "normalmap":
                notes.append(f"parallax-occlusion: {what} stores normals, not heights")
            elif kind:
                notes.append(
                    f"parallax-occlusion: {what} has a texture that is not a bitmap: no texels to march"
                )
    return parts, tuple(notes)


def _toml_bbox(scene: Scene):
    """The bounding box of the TOML scene's shapes as Mitsuba loads them (``None`` without shapes)."""
    if not scene.shapes:
        return None
    with scoped_variant(inspection_variant()) as mi:  # the caller's variant is put back afterwards
        d = mitsuba_scene_dict(mi, Scene(name=scene.name, camera=scene.camera, shapes=scene.shapes))
        box = load_dict(mi, d).bbox()
        lo, hi = box.min, box.max
    return (float(lo[0]), float(lo[1]), float(lo[2])), (float(hi[0]), float(hi[1]), float(hi[2]))


def _toml_reflective(scene: Scene) -> list[tuple[int, str, str, bool]]:
    """(ordinal, BSDF plugin, where, is a sphere) of each reflective shape of a TOML scene, in the order of
    the Mitsuba scene dict's keys (`mitsuba_scene_dict`: ``xml<i>_<j>``, the j-th shape of TOML shape i; the
    order `rtfit.reference.reflective_shapes.reflective_shapes` gives them). rtfit's own materials are
    diffuse, so these come from ``mitsuba_xml`` shapes that keep their file's BSDFs."""
    keeps = [getattr(s, "override_material", None) is None for s in scene.shapes if s.kind == "mitsuba_xml"]
    if not any(keeps):
        return []
    out = []
    with scoped_variant(inspection_variant()) as mi:
        d = mitsuba_scene_dict(mi, Scene(name=scene.name, camera=scene.camera, shapes=scene.shapes))
        for key, obj in d.items():
            if not (key.startswith("xml") and isinstance(obj, mi.Shape)):
                continue
            plugin = shape_plugin(obj)
            if plugin is not None:
                sphere = obj.shape_type() == int(mi.ShapeType.Sphere)
                out.append((len(out), plugin, f"shapes[{key[3:].split('_')[0]}], {key}", sphere))
    return out


def sky_info(path: str) -> SceneInfo:
    """The `SceneInfo` of an rtfit sky file (format ``rtfit.sky/1``): one part, its atmosphere."""
    spec = load_atmosphere_scene(path)
    return SceneInfo(
        source=path,
        format="rtfit-sky",
        parts=(Part(frozenset({"atmosphere"}), "a spherical-shell atmosphere (rtfit.sky/1)"),),
        bbox=None,
        up="+z",
        up_reason="+z: an rtfit sky file is +z up",
        camera=f"viewer {spec.viewer_altitude_m:g} m above the ground, sun at {spec.sun_elevation_deg:g}°",
        contents=(
            f"rtfit sky file: planet {spec.planet_radius_m / 1e3:g} km, atmosphere top "
            f"{spec.top_radius_m / 1e3:g} km, Rayleigh H = {spec.rayleigh_height_m:g} m, Mie H = "
            f"{spec.mie_height_m:g} m",
        ),
    )
