"""The audit's vocabulary: the parts a scene is reduced to, and the rules that say when a family applies.

A scene (`rtfit.experiments.audit.inspect_scene`; the readers `audit_inspect_xml` and `audit_inspect_toml`)
becomes a `SceneInfo`: its `Part` s, each of one or more *kinds*, and what the inspection could not tell.
`PROVIDES` says which named inputs of the method tables (``Method.inputs``) each kind of part provides (a
light gives ``cos_theta`` and ``irradiance``, a spherical light also ``alpha`` and ``radiance``, an
environment the normal and the basis coefficients, geometry the SDF terms and aperture caps). The helpers
`model_kinds`, `reflective_kinds`, `LIT_KINDS` and `volume_part` turn a light or a shape into its kinds for
both readers, so that an XML and a TOML scene with the same light get the same kinds.

A `Rule` (each audit declaration's ``rules``, gathered into `families.RULES`) names a family, the part kinds
it needs (the first is the *trigger*: one `Applicability` per such part; the others must be present in the
scene), the inputs the rule itself supplies, the reason, the reference quantity and the integrator;
`rtfit.experiments.applicability` applies them. `missing_text` and `alternatives` say in words what a scene
lacks (``--list``'s "needs …" lines).

The AO radius: ``--ao-distance``, else `AO_FRACTION` × the diagonal of the scene's bounding box (all shapes
as Mitsuba loads them; `default_ao_distance`). A ground plane much larger than the objects dominates that
box: pass ``--ao-distance`` for such scenes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rtfit.realtime import (
    parallax_occlusion,
    reflections,
)
from rtfit.realtime.light_cones import INPUTS as CONE_INPUTS
from rtfit.reference.mitsuba_xml import XmlScene
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS

__all__ = [
    "AO_FRACTION",
    "LIT_KINDS",
    "PROVIDES",
    "SURFACE_FREE_KINDS",
    "Applicability",
    "Part",
    "Rule",
    "SceneInfo",
    "alternatives",
    "counts_text",
    "default_ao_distance",
    "family_note",
    "missing_text",
    "model_kinds",
    "reflective_kinds",
    "scene_summary",
    "vec_text",
    "volume_part",
]

AO_FRACTION = 0.1
"""Default AO radius as a fraction of the scene's bounding-box diagonal."""


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
    # geometry a signed distance field is built from (`audit_geometry`: meshes and the analytic shapes it
    # tessellates); a scene with a curve shape has "geometry" but not this
    "sdf-geometry": frozenset({*_GEOMETRY_INPUTS, "cos_na", "aperture"}),
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
_INPUT_SOURCE = {name: kind for kind in reversed(PROVIDES) for name in PROVIDES[kind]}
"""What provides an input, for "not here" notes: the first kind of `PROVIDES` that has it (and ``caps``
for the bare cap-intersection inputs)."""
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
    "sdf-geometry": "geometry that can occlude itself, made only of shapes a distance field is built from "
    "(meshes, spheres, disks, cylinders, rectangles and shape-group instances; not curves)",
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
"""Each part kind (and ``caps``) in words: what ``--list`` says a family needs."""


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


# --------------------------------------------------------------------------- the kinds of a light or shape
def model_kinds(kind: str, uniform: bool, circular: bool = True) -> set[str]:
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


LIT_KINDS = {"point": ("point-in-medium", "volumetric-lightning"), "spot": ("spot-in-medium", "light-cones")}
"""A light kind → the part kind it makes inside a homogeneous medium, and the family that part triggers."""


def reflective_kinds(plugin: str, sphere: bool = False) -> frozenset[str]:
    """The part kinds of a shape with the reflective BSDF ``plugin`` (`REFLECTIVE_BSDFS`); a smooth
    ``dielectric`` is also glass (``glass-shape``), on a ``sphere`` shape a drop (``glass-sphere``)."""
    kinds = {"rough-shape" if REFLECTIVE_BSDFS[plugin].rough else "reflective-shape"}
    if plugin == "dielectric":
        kinds |= {"glass-shape", "glass-sphere"} if sphere else {"glass-shape"}
    return frozenset(kinds)


def volume_part(bbox) -> Part:
    """The probe grid's part: the scene's box, where it has a finite extent."""
    lo, hi = bbox
    extent = max(h - low for low, h in zip(lo, hi, strict=True))
    finite = all(math.isfinite(v) for v in (*lo, *hi)) and extent > 0.0
    kinds = frozenset({"volume"}) if finite else frozenset()
    return Part(kinds, f"a probe grid over the scene's box {vec_text(lo)}–{vec_text(hi)}")


# ------------------------------------------------------------------------------------------------ texts
def counts_text(items) -> str:
    """``sphere ×2, obj`` for the items ``sphere, obj, sphere``: each distinct item in first-seen order, with
    its count where it repeats ("" for none)."""
    out: dict[str, int] = {}
    for t in items:
        out[t] = out.get(t, 0) + 1
    return ", ".join(f"{t} ×{n}" if n > 1 else t for t, n in out.items())


def vec_text(v) -> str:
    """A point or vector in one line: ``(1, 2.5, -3)`` (4 significant digits)."""
    return "(" + ", ".join(f"{c:.4g}" for c in v) + ")"


def scene_summary(info: SceneInfo) -> str:
    """The scene's parts in one line (``--list``'s "the scene has …")."""
    return ", ".join(p.label for p in info.parts) if info.parts else "nothing a family uses"


def family_note(info: SceneInfo, family: str) -> str:
    """The inspection's notes for ``family`` (those starting ``family:``), each as `` (note)``."""
    notes = [n for n in info.notes if n.startswith(f"{family}:")]
    return "".join(f" ({n.split(':', 1)[1].strip()})" for n in notes)


def default_ao_distance(info: SceneInfo) -> float | None:
    """`AO_FRACTION` × the bounding-box diagonal (``None`` without a finite box)."""
    d = info.diagonal
    return None if d is None else AO_FRACTION * d
