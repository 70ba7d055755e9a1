"""`rtfit audit SCENE --list`: which approximation families apply to a user's scene, and why.

The inspection layer of the audit (issue 15 §2, "model only what the scene requires"). A scene — a Mitsuba 3
XML file read by Mitsuba's own parser (`rtfit.reference.mitsuba_xml.inspect_xml`), an rtfit TOML scene
(`rtfit.scenes.load_scene`) or an rtfit sky file (format ``rtfit.sky/1``) — is reduced to its **parts**
(`Part`): each light, the environment, the surfaces, the geometry that can occlude itself, each medium, an
atmosphere. Each part *provides* the named inputs the method tables declare
(`rtfit.realtime.<family>.METHODS`, ``Method.inputs``): a light gives ``cos_theta`` and ``irradiance``, a
spherical light also ``alpha`` and ``radiance``, an environment the normal and the basis coefficients,
geometry the SDF terms and aperture caps.

`RULES` is the whole decision, as data: a rule names a family, the part kinds it needs (the first is the
*trigger*: one applicability per such part; the others must be present in the scene), the inputs the
rule itself supplies (e.g. the aperture-caps role's second cap: the point's own hemisphere), the reason,
the reference quantity and the integrator it would need. A method of the family applies when every one of
its inputs is provided; so the exact sphere-light form is listed only for a spherical light, because only a
spherical light provides ``alpha``. No code branches on a family's or a method's name.

The AO radius: ``--ao-distance``, else `AO_FRACTION` × the diagonal of the scene's bounding box (all shapes
as Mitsuba loads them). A ground plane much larger than the objects dominates that box: pass
``--ao-distance`` for such scenes.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from rtfit.realtime import (
    parallax_occlusion,
    reflections,
)
from rtfit.realtime.light_cones import INPUTS as CONE_INPUTS
from rtfit.reference.build import inside_boundary, load_dict, mitsuba_scene_dict
from rtfit.reference.integrators import can_interreflect
from rtfit.reference.mitsuba_xml import UP_AXES, XmlScene, XMLSceneError, inspect_xml
from rtfit.reference.nishita_sky import load_atmosphere_scene
from rtfit.reference.parallax_occlusion import bump_kind
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS, shape_plugin
from rtfit.reference.variants import inspection_variant, scoped_variant
from rtfit.scenes import ENVIRONMENT_KINDS, Scene, SceneError, library_names, library_path, load_scene
from rtfit.scenes.model import PointLight, SpotLight
from rtfit.scenes.parse import LIBRARY_DIR

__all__ = [
    "AO_FRACTION",
    "PROVIDES",
    "SURFACE_FREE_KINDS",
    "Applicability",
    "AuditError",
    "Part",
    "Rule",
    "SceneInfo",
    "alternatives",
    "default_ao_distance",
    "family_note",
    "inspect_scene",
    "missing_text",
    "scene_summary",
    "vec_text",
]

AO_FRACTION = 0.1
"""Default AO radius as a fraction of the scene's bounding-box diagonal."""


class AuditError(ValueError):
    """Bad audit input: one line, exit 2."""


# ------------------------------------------------------------------------------------------- scene parts
# The inputs each kind of part provides (names of `Method.inputs`). A part has one or more kinds.
_GEOMETRY_INPUTS = ("terms", "distance", "px", "py", "pz", "nx", "ny", "nz", "sdf", "t0", "t_max")
_SEGMENT_INPUTS = ("ox", "oy", "oz", "dx", "dy", "dz")  # a camera ray's stretch in a medium
_LIT_MEDIUM_INPUTS = ("intensity", "sigma_s", "sigma_t", "g", "single_scattering")  # the light, the medium
PROVIDES: dict[str, frozenset[str]] = {
    "light": frozenset({"cos_theta", "irradiance", "cos_nl"}),
    "spherical-light": frozenset({"cos_theta", "irradiance", "cos_nl", "alpha", "radiance", "cos_al"}),
    # the light models (`rtfit.realtime.light_models`): the light's own parameters, per kind of light
    "punctual-light": frozenset({"cos_theta", "distance", "intensity"}),
    "spot-light": frozenset({"cos_theta", "distance", "axis_intensity", "cos_axis", "cutoff", "beam"}),
    "rect-light": frozenset({f"{v}{a}" for v in ("p", "n", "lc", "lu", "lv") for a in "xyz"} | {"radiance"}),
    "disc-light": frozenset(
        {f"{v}{a}" for v in ("p", "n", "dc", "dm") for a in "xyz"} | {"disc_radius", "radiance"}
    ),
    "tube-light": frozenset(
        {f"{v}{a}" for v in ("p", "n", "ta", "tb") for a in "xyz"} | {"tube_radius", "radiance"}
    ),
    "environment": frozenset({"nx", "ny", "nz", "coeffs", "irradiance", "sky_radiance"}),
    "surface": frozenset(),
    "geometry": frozenset({*_GEOMETRY_INPUTS, "cos_na", "aperture"}),
    "fog": frozenset({"z0", "z1", "distance", "cos_sun", "l0_r", "l0_g", "l0_b"}),
    # a scene's own medium as height fog (constant, or fitted to its grid)
    "constant-fog": frozenset({"z0", "z1", "distance", "cos_sun", "l0_r", "l0_g", "l0_b"}),
    "grid-fog": frozenset({"z0", "z1", "distance", "cos_sun", "l0_r", "l0_g", "l0_b"}),
    "medium": frozenset(),
    # a medium the fog blend reads as height fog (constant, or fitted to its grid), under a sky
    "fog-medium": frozenset({"z0", "z1", "distance", "cos_sun", "l0_r", "l0_g", "l0_b"}),
    "atmosphere": frozenset({"dx", "dy", "dz", "texel_mu", "texel_nu", "tau_r", "tau_m", "sun_x", "sun_z"}),
    # a sky emitter (Mitsuba's sunsky): the Nishita texture's inputs in the sky's frame (its zenith, its sun)
    "sky": frozenset({"dx", "dy", "dz", "texel_mu", "texel_nu", "tau_r", "tau_m", "sun_x", "sun_z"}),
    "particle": frozenset(
        {"alpha", "alpha_c", "z", "delta", "radius", "q", "cos_view", "t_surface", "sigma"}
        | {"dx", "dy", "dz", "cx", "cy", "cz"}
    ),
    "point-in-medium": frozenset({*_SEGMENT_INPUTS, "lx", "ly", "lz", *_LIT_MEDIUM_INPUTS}),
    "spot-in-medium": frozenset({*(i.name for i in CONE_INPUTS), *_LIT_MEDIUM_INPUTS}),
    "reflective-shape": frozenset(i.name for i in reflections.METHODS["classic"].inputs),
    # a smooth `dielectric` (not thin glass): a clear coat or a drop; on a sphere shape, a drop
    "glass-shape": frozenset(i.name for i in reflections.METHODS["classic"].inputs),
    "glass-sphere": frozenset(i.name for i in reflections.METHODS["classic"].inputs),
    "volume": frozenset({"px", "py", "pz", "nx", "ny", "nz", "table", "grid"}),
    "rough-shape": frozenset(
        i.name for m in ("classic", "preconvolved") for i in reflections.METHODS[m].inputs
    ),
    # the march's inputs; toward each area light, the soft shadow's too (the family's case computes those)
    "height-field": frozenset(
        i.name
        for table in (parallax_occlusion.DEPTH_METHODS, parallax_occlusion.SHADOW_AUDIT_METHODS)
        for m in table.values()
        for i in m.inputs
    ),
}
# What provides an input, for "not here" notes (the first kind of `PROVIDES` that has it).
_INPUT_SOURCE = {name: kind for kind in reversed(PROVIDES) for name in PROVIDES[kind]}
# The bare cap-intersection forms (r1, r2, d → Ω in sr) have no per-pixel counterpart in a scene: the
# ambient-aperture study compares them over (r1, r2, d); the audit uses each inside its aa-<form>-* rows.
_INPUT_SOURCE.update(dict.fromkeys(("r1", "r2", "d"), "caps"))
_KIND_TEXT = {
    "light": "a light (sun, directional, point, spot, sphere, disk or area)",
    "spherical-light": "a spherical light (a sphere light, or a sun of finite angular radius)",
    "punctual-light": "a local light of known intensity (a point light, or a sphere, rectangle, disk or "
    "cylinder light of uniform radiance)",
    "spot-light": "a spot light",
    "rect-light": "a rectangle light of uniform radiance",
    "disc-light": "a circular disk light of uniform radiance",
    "tube-light": "a tube light (a circular cylinder area light of uniform radiance)",
    "environment": "an environment (envmap, constant or sunsky)",
    "surface": "a surface for the camera to see",
    "geometry": "geometry that can occlude itself (two or more shapes, or one non-convex shape)",
    "fog": "an exponential height-fog medium",
    "constant-fog": "a homogeneous medium (constant fog)",
    "grid-fog": "a heterogeneous medium with a density grid (gridvolume)",
    "medium": "a medium",
    "fog-medium": "a medium the camera looks through that reads as height fog (homogeneous, or a gridvolume)",
    "atmosphere": "an atmosphere",
    "sky": "a sky emitter (a Mitsuba sunsky)",
    "particle": "a medium-filled convex shape (a homogeneous medium in a sphere, a cube or a convex mesh)",
    "point-in-medium": "a point light inside a homogeneous medium",
    "spot-in-medium": "a spot light inside a homogeneous medium",
    "reflective-shape": "a mirror or glass shape (conductor, dielectric, thindielectric or plastic)",
    "glass-shape": "a smooth glass shape (a dielectric BSDF, not thindielectric)",
    "glass-sphere": "a smooth glass sphere (a sphere shape with a dielectric BSDF)",
    "volume": "a scene with a finite bounding box for a probe grid",
    "rough-shape": "a rough (glossy) reflective shape: roughconductor, roughdielectric or roughplastic",
    "height-field": "a shape whose BSDF is a bumpmap with a bitmap texture (its height field)",
    "caps": "two bare caps: compared over (r1, r2, d) by rtfit run ambient-aperture's study; in a scene each "
    "intersection form is audited inside its aa-<form>-* rows",
}


@dataclass(frozen=True)
class Part:
    """One thing in the scene that can make a family apply: ``kinds`` (keys of `PROVIDES`), ``label``
    (human text naming it and where it is declared)."""

    kinds: frozenset[str]
    label: str
    source: int | None = None
    """Index of what the part stands for in its scene record (`XmlScene.emitters` for a light or an
    environment of an XML scene, `XmlScene.shapes` for a particle of an XML scene, `Scene.lights` for a
    light or an environment and `Scene.media` for a medium of a TOML scene); ``None`` for parts that stand
    for the whole scene (surfaces, geometry)."""

    @property
    def provides(self) -> frozenset[str]:
        return frozenset().union(*(PROVIDES[k] for k in self.kinds))


@dataclass(frozen=True)
class SceneInfo:
    """A scene reduced to what the audit needs. ``format``: ``mitsuba-xml``, ``rtfit-toml`` or
    ``rtfit-sky``; ``parts``; ``bbox`` (min, max) or ``None``; ``up``/``up_reason``; ``camera`` (one line);
    ``contents`` (one line each: what the scene holds); ``notes`` (what the inspection could not tell,
    e.g. that XML has no atmosphere type); ``xml``: the full `XmlScene` of an XML input."""

    source: str
    format: str
    parts: tuple[Part, ...]
    bbox: tuple[tuple[float, float, float], tuple[float, float, float]] | None
    up: str
    up_reason: str
    camera: str
    contents: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    xml: XmlScene | None = field(default=None, compare=False)

    def has(self, kind: str) -> bool:
        return any(kind in p.kinds for p in self.parts)

    def first(self, kind: str) -> Part | None:
        return next((p for p in self.parts if kind in p.kinds), None)

    @property
    def diagonal(self) -> float | None:
        if self.bbox is None:
            return None
        lo, hi = self.bbox
        d = math.dist(lo, hi)
        return d if math.isfinite(d) and d > 0.0 else None


# ------------------------------------------------------------------------------------------------- rules
@dataclass(frozen=True)
class Rule:
    """A family applies for each part of kind ``needs[0]`` when the scene also has ``needs[1:]``.
    ``supplies``: inputs the rule's own reference provides. ``reason``, ``reference`` and ``integrator`` are
    templates (``{part}``, ``{with_}``: the other needed parts, ``{ao_distance}``)."""

    family: str
    role: str
    needs: tuple[str, ...]
    reason: str
    reference: str
    integrator: str
    supplies: frozenset[str] = frozenset()


SURFACE_FREE_KINDS = frozenset({"fog", "constant-fog", "grid-fog", "point-in-medium", "spot-in-medium", "sky",
                                "atmosphere", "fog-medium"})  # fmt: skip
"""Trigger part kinds (a rule's ``needs[0]``) whose family audits the camera's rays, not the surfaces they
hit: a scene whose camera sees only medium boundaries and lights still runs these (and only these)."""


@dataclass(frozen=True)
class Applicability:
    """One family applying for one reason: ``family``, ``role``, the ``part`` that triggers it, the
    ``methods`` of its table that apply (ids), ``excluded`` (``(method id, why)`` for those that do not),
    ``reason``, the ``reference`` quantity and ``integrator`` it would need."""

    family: str
    role: str
    part: str
    methods: tuple[str, ...]
    excluded: tuple[tuple[str, str], ...]
    reason: str
    reference: str
    integrator: str
    source: int | None = None  # the triggering part's `Part.source`


def missing_text(missing: set[str]) -> str:
    """``needs alpha, radiance: a spherical light …`` — the one part kind that provides them all (the
    most specific), else each input's own."""
    covering = [k for k in PROVIDES if missing <= PROVIDES[k]]
    if covering:
        kinds = [min(covering, key=lambda k: len(PROVIDES[k]))]
    else:
        kinds = list(dict.fromkeys(_INPUT_SOURCE.get(m, m) for m in sorted(missing)))
    return f"needs {', '.join(sorted(missing))}: {' and '.join(_KIND_TEXT.get(k, k) for k in kinds)}"


def alternatives(rules) -> list[str]:
    """The distinct ``needs`` of ``rules``, dropping any that includes another (the weaker one suffices)."""
    sets = list(dict.fromkeys(frozenset(r.needs) for r in rules))
    minimal = [a for a in sets if not any(b < a for b in sets)]
    order = list(PROVIDES)
    return [" and ".join(_KIND_TEXT[k] for k in sorted(a, key=order.index)) for a in minimal]


def scene_summary(info: SceneInfo) -> str:
    return ", ".join(p.label for p in info.parts) if info.parts else "nothing a family uses"


def family_note(info: SceneInfo, family: str) -> str:
    notes = [n for n in info.notes if n.startswith(f"{family}:")]
    return "".join(f" ({n.split(':', 1)[1].strip()})" for n in notes)


def default_ao_distance(info: SceneInfo) -> float | None:
    """`AO_FRACTION` × the bounding-box diagonal (``None`` without a finite box)."""
    d = info.diagonal
    return None if d is None else AO_FRACTION * d


# --------------------------------------------------------------------------------------------- inspection
_XML_NOTES = (
    "height-fog: a homogeneous medium is audited as constant fog (c = 0) and a heterogeneous gridvolume as "
    "the exponential height density fitted to its grid; other media (a heterogeneous medium with another "
    "volume) are not height fog",
    "nishita-sky: Mitsuba XML has no atmosphere type: the Nishita sky is fitted to a sunsky emitter's sky; a "
    "path-traced spherical-shell atmosphere is an rtfit sky file (format rtfit.sky/1)",
)
_CONVEX_XML = frozenset({"sphere", "rectangle", "disk", "cube"})  # one of these alone cannot occlude itself
_PARTICLE_XML = frozenset({"sphere", "cube"})  # convex medium boundaries with an exact chord
# Emitter kinds (`XmlEmitter.kind`) that are lights of their own; others (e.g. a projector) are not audited.
_XML_LIGHTS = frozenset({"point", "spot", "directional", "sphere", "disk", "rectangle", "area"})


_TOML_MODEL_KIND = {
    "point_light": "point",
    "spot_light": "spot",
    "sphere_light": "sphere",
    "rect_light": "rectangle",
}


def _model_kinds(kind: str, uniform: bool, circular: bool = True) -> set[str]:
    """The light-model kinds (`PROVIDES`) of a light of ``kind`` (an `XmlEmitter.kind`): what its own
    parameters give the rows of `rtfit.realtime.light_models`. Every light needs a uniform emission
    (``uniform``: its intensity or radiance declared as values, not a texture; a spot projecting no
    texture); an area light on a mesh has no intensity rtfit computes (its rows are left out, saying so); a
    disk gives the disc row and a cylinder (``kind`` "cylinder": a tube) any row only when ``circular``."""
    if not uniform:
        return set()
    if kind == "point":
        return {"punctual-light"}
    if kind == "spot":
        return {"spot-light"}
    disk = {"punctual-light", "disc-light"} if circular else {"punctual-light"}
    tube = {"punctual-light", "tube-light"} if circular else set()
    return {"sphere": {"punctual-light"}, "disk": disk, "cylinder": tube}.get(
        kind, {"punctual-light", "rect-light"} if kind == "rectangle" else set()
    )


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


def _xml_info(x: XmlScene) -> SceneInfo:
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
            kinds |= _model_kinds(model, e.scale is not None and not e.patterned, not e.elliptical)
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
            types = ", ".join(f"{t} ×{n}" if n > 1 else t for t, n in _counts(s.type for s in x.shapes))
            parts.append(Part(frozenset({"geometry"}), f"the scene's geometry ({types})"))
    if x.shapes and x.bbox is not None:
        parts.append(_volume_part(x.bbox))
    # a medium's boundary is the medium's container, not a glass object (`shape_plugin`)
    reflective = [s for s in x.shapes if s.bsdf in REFLECTIVE_BSDFS and not (s.interior or s.exterior)]
    for ordinal, shape in enumerate(reflective):  # `Part.source`: the ordinal among the reflective shapes
        named = f" '{shape.id}'" if shape.id else ""
        text = f"{REFLECTIVE_BSDFS[shape.bsdf].text} {shape.type}{named} ({_short(shape.location)})"
        parts.append(Part(_reflective_kinds(shape.bsdf, shape.type == "sphere"), text, ordinal))
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
    shapes = ", ".join(f"{t} ×{n}" if n > 1 else t for t, n in _counts(s.type for s in x.shapes)) or "none"
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


_LIT_KINDS = {"point": ("point-in-medium", "volumetric-lightning"), "spot": ("spot-in-medium", "light-cones")}
"""A light kind → the part kind it makes inside a homogeneous medium, and the family that part triggers."""


def _xml_lights_in_media(x: XmlScene) -> tuple[list[Part], tuple[str, ...]]:
    """A ``point-in-medium`` (``spot-in-medium``) part for each point (spot) light inside a homogeneous
    medium (`XmlEmitter.medium`), and a note for each such light that is not."""
    parts, notes = [], []
    for index, e in enumerate(x.emitters):
        if e.kind not in _LIT_KINDS:
            continue
        kind, family = _LIT_KINDS[e.kind]
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


def _volume_part(bbox) -> Part:
    """The probe grid's part: the scene's box, where it has a finite extent."""
    lo, hi = bbox
    extent = max(h - low for low, h in zip(lo, hi, strict=True))
    finite = all(math.isfinite(v) for v in (*lo, *hi)) and extent > 0.0
    kinds = frozenset({"volume"}) if finite else frozenset()
    return Part(kinds, f"a probe grid over the scene's box {vec_text(lo)}–{vec_text(hi)}")


def _reflective_kinds(plugin: str, sphere: bool = False) -> frozenset[str]:
    """The part kinds of a shape with the reflective BSDF ``plugin`` (`REFLECTIVE_BSDFS`); a smooth
    ``dielectric`` is also glass (``glass-shape``), on a ``sphere`` shape a drop (``glass-sphere``)."""
    kinds = {"rough-shape" if REFLECTIVE_BSDFS[plugin].rough else "reflective-shape"}
    if plugin == "dielectric":
        kinds |= {"glass-shape", "glass-sphere"} if sphere else {"glass-shape"}
    return frozenset(kinds)


def _counts(items) -> list[tuple[str, int]]:
    out: dict[str, int] = {}
    for t in items:
        out[t] = out.get(t, 0) + 1
    return list(out.items())


def vec_text(v) -> str:
    return "(" + ", ".join(f"{c:.4g}" for c in v) + ")"


def _toml_info(scene: Scene, source: str, up: str | None) -> SceneInfo:
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
        kinds |= _model_kinds(_TOML_MODEL_KIND.get(light.kind, light.kind), True)
        parts.append(Part(frozenset(kinds), f"{light.kind.replace('_', ' ')} ({where})", i))
    if scene.shapes:
        parts.append(Part(frozenset({"surface"}), f"{len(scene.shapes)} shape(s)"))
        if can_interreflect(scene):
            types = ", ".join(f"{t} ×{n}" if n > 1 else t for t, n in _counts(s.kind for s in scene.shapes))
            parts.append(Part(frozenset({"geometry"}), f"the scene's geometry ({types})"))
        if bbox is not None:
            parts.append(_volume_part(bbox))
        for index, plugin, where, sphere in _toml_reflective(scene):
            text = f"{REFLECTIVE_BSDFS[plugin].text} shape ({where}: {plugin})"
            parts.append(Part(_reflective_kinds(plugin, sphere), text, index))
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
        kind, family = _LIT_KINDS["point" if isinstance(light, PointLight) else "spot"]
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


def _sky_info(path: str) -> SceneInfo:
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


def _not_a_scene(scene) -> str:
    """The refusal of a scene that is neither a path nor a scene dict (one line; a loaded ``mi.Scene`` says
    why it cannot be read)."""
    kind = type(scene)
    if kind.__name__ == "Scene" and kind.__module__.startswith("mitsuba"):
        return (
            "a loaded mitsuba Scene cannot be audited: it no longer holds the plugin names, ids and "
            "properties the audit reads (which lights, BSDFs and media, as declared); pass the dict you gave "
            "mi.load_dict, or the scene file's path"
        )
    return f"{kind.__name__}: expected a scene file's path or a scene dict (mi.load_dict style)"


def inspect_scene(
    scene: str | os.PathLike | Mapping,
    *,
    defines: Mapping[str, str] | None = None,
    camera: int = 0,
    width: int | None = None,
    height: int | None = None,
    up: str | None = None,
) -> SceneInfo:
    """Read ``scene`` (a ``.xml`` Mitsuba scene, a ``.toml`` rtfit scene or sky file, a library scene
    name, or a Mitsuba scene dict as ``mi.load_dict`` takes it) into a `SceneInfo`. Every bad input is an
    `AuditError` (one line)."""
    if up is not None and up not in UP_AXES:
        raise AuditError(f"--up {up!r}: expected one of {', '.join(UP_AXES)}")
    if isinstance(scene, Mapping):  # a scene dict: Mitsuba's parser reads it as it reads XML
        try:
            return _xml_info(inspect_xml(scene, defines, camera=camera, width=width, height=height, up=up))
        except XMLSceneError as e:
            raise AuditError(str(e)) from None
    if not isinstance(scene, str | os.PathLike):
        raise AuditError(_not_a_scene(scene))
    text = os.fspath(scene)
    path = Path(text)
    if not path.exists() and text.removesuffix(".toml").replace("-", "_") in library_names():
        path = library_path(text)
    elif not path.exists() and "/" not in text and os.sep not in text:  # a shipped Mitsuba XML scene
        xml = LIBRARY_DIR / f"{text.removesuffix('.xml').replace('-', '_')}.xml"
        path = xml if xml.is_file() else path
    if not path.is_file():
        raise AuditError(
            f"{text}: no such scene file (a .xml Mitsuba scene, a .toml rtfit scene, or the name of a scene "
            "of rtfit's library, scenes/library/)"
        )
    if path.suffix.lower() == ".xml":
        try:
            return _xml_info(inspect_xml(path, defines, camera=camera, width=width, height=height, up=up))
        except XMLSceneError as e:
            raise AuditError(str(e)) from None
    if path.suffix.lower() != ".toml":
        raise AuditError(f"{text}: expected a .xml Mitsuba scene or a .toml rtfit scene")
    for name, value in (("-D", defines), ("--camera", camera or None)):
        if value:
            raise AuditError(f"{name} is for Mitsuba XML scenes; {text} is an rtfit TOML scene")
    try:
        fmt = tomllib.loads(path.read_text(encoding="utf-8")).get("format")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, OSError) as e:
        raise AuditError(f"{text}: not a readable TOML file ({str(e).splitlines()[0]})") from None
    try:
        if fmt == "rtfit.sky/1":
            return _sky_info(str(path))
        toml = load_scene(path)
        if width or height:
            size = {"width": width or toml.camera.width, "height": height or toml.camera.height}
            toml = replace(toml, camera=replace(toml.camera, **size))
        return _toml_info(toml, str(path), up)
    except (SceneError, ValueError) as e:
        raise AuditError(str(e).splitlines()[0]) from None
