"""The audit's reader of a Mitsuba scene: a Mitsuba 3 XML file or scene dict as `SceneInfo` parts.

Mitsuba's own parser reads the file (`rtfit.reference.mitsuba_xml.inspect_xml`: plugins, ids, properties,
where each is declared); `xml_info` turns its `XmlScene` into the audit's parts (`rtfit.experiments.
audit_parts`): each light (and its light-model kinds), the environment (a sunsky's sun a light of its own,
its sky a Nishita target), the surfaces, the geometry that can occlude itself, reflective and glass shapes,
each medium (as constant or grid fog), particles (a homogeneous medium in a convex shape), point and spot
lights inside a homogeneous medium, and bump maps that can serve as height fields; and it says in notes what
the file cannot give (an emitter no family models, a light outside a medium, a normal map).
"""

from __future__ import annotations

import os

from rtfit.reference.mitsuba_xml import XmlScene
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS

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

__all__ = ["xml_info"]

_XML_NOTES = (
    "height-fog: a homogeneous medium is audited as constant fog (c = 0) and a heterogeneous gridvolume as "
    "the exponential height density fitted to its grid; other media (a heterogeneous medium with another "
    "volume) are not height fog",
    "nishita-sky: Mitsuba XML has no atmosphere type: the Nishita sky is fitted to a sunsky emitter's sky; a "
    "path-traced spherical-shell atmosphere is an rtfit sky file (format rtfit.sky/1)",
)
_CONVEX_XML = frozenset({"sphere", "rectangle", "disk", "cube"})  # one of these alone cannot occlude itself
SDF_SHAPE_PLUGINS = frozenset(
    {
        "obj",
        "ply",
        "serialized",
        "cube",
        "mesh",
        "sphere",
        "disk",
        "cylinder",
        "rectangle",
        "instance",
        "shapegroup",
    }
)
"""The shape plugins `audit_geometry`'s distance field reads (Mitsuba's meshes, and the analytic shapes it
tessellates; an instance by its group's members, read when the field is built): the ``sdf-geometry`` part."""
_PARTICLE_XML = frozenset({"sphere", "cube"})  # convex medium boundaries with an exact chord
# Emitter kinds (`XmlEmitter.kind`) that are lights of their own; others (e.g. a projector) are not audited.
_XML_LIGHTS = frozenset({"point", "spot", "directional", "sphere", "disk", "rectangle", "area"})


def _short(location: str) -> str:
    """``/a/b/scene.xml (line 3, col 6)`` → ``scene.xml line 3``."""
    head, _, rest = location.partition(" (")
    line = rest.split(",")[0].rstrip(")") if rest else ""
    return f"{os.path.basename(head)} {line}".strip()


def _unaudited(x: XmlScene) -> str | None:
    """The ``--list`` line naming every emitter no family audits (a ``projector``, a plugin rtfit does not
    know), and what happens to it: no family's reference includes it (each renders its own light, the
    environment or the geometry alone), so it is neither audited nor lights another case (issue 31)."""
    left = [
        f"{e.kind}{f' {e.id!r}' if e.id else ''} ({_short(e.location)})"
        for e in x.emitters
        if not e.environment and e.kind not in _XML_LIGHTS
    ]
    if not left:
        return None
    return (
        f"not audited: {', '.join(left)}: no family has a light model for this emitter kind; it is left "
        "out of every reference (each family renders its own light, the environment or the geometry alone)"
    )


def xml_info(x: XmlScene) -> SceneInfo:
    """The `SceneInfo` of a Mitsuba scene read by Mitsuba's own parser (`inspect_xml`): its parts, camera,
    contents and notes."""
    parts: list[Part] = []
    for index, e in enumerate(x.emitters):
        named = f" '{e.id}'" if e.id else ""
        where = _short(e.location)
        if e.environment:
            label = f"{e.kind} environment{named} ({where})"
            kinds = {"environment"}
            if e.direction is not None:  # a sunsky: its sun is a light of its own, its sky a Nishita target
                sun = {"light", "spherical-light"} if e.spherical else {"light"}
                parts.append(Part(frozenset(sun), f"the sun of the {label}", index))
                kinds.add("sky")
        elif e.kind in _XML_LIGHTS:
            kinds = {"light", "spherical-light"} if e.spherical else {"light"}
            model = "cylinder" if e.kind == "area" and e.shape == "cylinder" else e.kind
            kinds |= model_kinds(model, e.scale is not None and not e.patterned, not e.elliptical)
            what = f"{e.kind} area light" if e.shape else f"{e.kind} light"
            if e.shape and e.kind == "area":
                what = f"area light on a {e.shape}"
            label = f"{what}{named} ({where})"
        else:
            continue
        parts.append(Part(frozenset(kinds), label, index))
    if x.shapes:
        parts.append(Part(frozenset({"surface"}), f"{len(x.shapes)} shape(s)"))
        if len(x.shapes) >= 2 or x.shapes[0].type not in _CONVEX_XML:
            types = counts_text(s.type for s in x.shapes)
            sdf = {"sdf-geometry"} if all(s.type in SDF_SHAPE_PLUGINS for s in x.shapes) else set()
            parts.append(Part(frozenset({"geometry", *sdf}), f"the scene's geometry ({types})"))
    if x.shapes and x.bbox is not None:
        parts.append(volume_part(x.bbox))
    # a medium's boundary is the medium's container, not a glass object (`shape_plugin`)
    reflective = [s for s in x.shapes if s.bsdf in REFLECTIVE_BSDFS and not (s.interior or s.exterior)]
    for ordinal, shape in enumerate(reflective):  # `Part.source`: the ordinal among the reflective shapes
        named = f" '{shape.id}'" if shape.id else ""
        text = f"{REFLECTIVE_BSDFS[shape.bsdf].text} {shape.type}{named} ({_short(shape.location)})"
        parts.append(Part(reflective_kinds(shape.bsdf, shape.type == "sphere"), text, ordinal))
    for index, m in enumerate(x.media):
        where = " bounded by a shape" if m.boundary else (" around the sensor" if m.on_sensor else "")
        named = f" '{m.id}'" if m.id and m.id not in ("interior", "exterior", "medium") else ""
        label = f"{m.type} medium{named}{where} ({_short(m.location)})"
        constant = m.type == "homogeneous" or (m.type == "heterogeneous" and m.sigma_t == "constvolume")
        grid = m.type == "heterogeneous" and m.sigma_t == "gridvolume"
        kinds = {"medium", "constant-fog"} if constant else ({"medium", "grid-fog"} if grid else {"medium"})
        kinds |= {"fog-medium"} if constant or grid else set()
        parts.append(Part(frozenset(kinds), label, index if constant or grid else None))
    for index, s in enumerate(x.shapes):  # a particle: a homogeneous medium in a convex shape
        if s.interior == "homogeneous" and (s.type in _PARTICLE_XML or s.convex):
            what = s.type if s.type in _PARTICLE_XML else f"convex {s.type} mesh"
            label = f"homogeneous medium in a {what}{f' {s.id!r}' if s.id else ''} ({_short(s.location)})"
            parts.append(Part(frozenset({"particle"}), label, index))
    lit, lit_notes = _xml_lights_in_media(x)
    parts += lit
    bumps, bump_notes = _xml_height_fields(x)
    parts += bumps
    cam = x.camera
    camera = (
        f"sensor {cam.index}{f' {cam.id!r}' if cam.id else ''} ({cam.type}, {_short(cam.location)}) of "
        f"{len(x.sensors)}: {cam.width}×{cam.height}, fov {cam.fov_deg:.4g}° ({cam.fov_axis}), origin "
        f"{vec_text(cam.origin)} looking at {vec_text(cam.target)}"
        if cam is not None and cam.fov_deg is not None
        else (
            f"sensor {cam.index} ({cam.type}): {cam.width}×{cam.height}" if cam is not None else "no sensor"
        )
    )
    shapes = counts_text(s.type for s in x.shapes) or "none"
    meshes = [s for s in x.shapes if s.file]
    contents = (
        f"Mitsuba XML: {len(x.dependencies.xml_files)} XML file(s), {len(x.dependencies.data_files)} data "
        f"file(s); integrator in the file: {x.integrator or 'none'} (each reference picks its own)",
        f"emitters: {', '.join(e.kind for e in x.emitters) or 'none'}",
        f"shapes: {shapes}"
        + (
            f"; meshes: {', '.join(f'{os.path.basename(s.file)} ({s.faces} triangles)' for s in meshes)}"
            if meshes
            else ""
        ),
        f"BSDFs: {', '.join(x.bsdfs) or 'none'}; media: {', '.join(m.type for m in x.media) or 'none'}",
    )
    unaudited = _unaudited(x)
    if unaudited:
        contents += (unaudited,)
    return SceneInfo(
        source=x.path,
        format="mitsuba-xml",
        parts=tuple(parts),
        bbox=x.bbox,
        up=x.up,
        up_reason=x.up_reason,
        camera=camera,
        contents=contents,
        notes=_XML_NOTES + lit_notes + bump_notes,
        xml=x,
    )


def _medium_text(m) -> str:
    where = " bounded by a shape" if m.boundary else (" around the sensor" if m.on_sensor else "")
    return f"the {m.type} medium{where} ({_short(m.location)})"


def _xml_lights_in_media(x: XmlScene) -> tuple[list[Part], tuple[str, ...]]:
    """A ``point-in-medium`` (``spot-in-medium``) part for each point (spot) light inside a homogeneous
    medium (`XmlEmitter.medium`), and a note for each such light that is not."""
    parts, notes = [], []
    for index, e in enumerate(x.emitters):
        if e.kind not in LIT_KINDS:
            continue
        kind, family = LIT_KINDS[e.kind]
        label = f"{e.kind} light{f' {e.id!r}' if e.id else ''} ({_short(e.location)})"
        medium = x.media[e.medium] if e.medium is not None else None
        if medium is not None and medium.type == "homogeneous":
            parts.append(Part(frozenset({kind}), f"{label} inside {_medium_text(medium)}", index))
        elif medium is not None:
            notes.append(f"{family}: {label} sits in {_medium_text(medium)}, not homogeneous")
        else:
            notes.append(f"{family}: {label} is not inside a medium")
    return parts, tuple(notes)


def _xml_height_fields(x: XmlScene) -> tuple[list[Part], tuple[str, ...]]:
    """A ``height-field`` part (source: the shape's index in `XmlScene.shapes`) for each shape whose BSDF is a
    ``bumpmap`` of a ``bitmap`` texture, and a note for each bump or normal map that cannot serve as one."""
    parts, notes = [], []
    for index, s in enumerate(x.shapes):
        if not s.bump:
            continue
        what = f"the {s.bump} on the {s.type}{f' {s.id!r}' if s.id else ''} ({_short(s.location)})"
        if s.bump == "normalmap":
            why = "stores normals, not heights (integrating them into a height field is not done: give the "
            notes.append(f"parallax-occlusion: {what} {why}shape a bumpmap of its height texture)")
        elif s.bump_texture != "bitmap":
            tex = s.bump_texture or "constant"
            notes.append(f"parallax-occlusion: {what} has a {tex} texture, not a bitmap: no texels to march")
        else:
            parts.append(
                Part(frozenset({"height-field"}), f"{what}: its bitmap texture as a height field", index)
            )
    return parts, tuple(notes)
