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

This module is the public face: `inspect_scene` (every kind of input, each bad one an `AuditError`) and the
names the audit's other modules and users import from it. The rooms behind it: `audit_parts` (the part
kinds, `Part`, `SceneInfo`, `Rule`, `Applicability` and their texts), `audit_inspect_xml` (a Mitsuba scene's
parts) and `audit_inspect_toml` (an rtfit TOML scene's or sky file's).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from rtfit.reference.mitsuba_xml import UP_AXES, XMLSceneError, inspect_xml
from rtfit.scenes import SceneError, library_names, library_path, load_scene
from rtfit.scenes.parse import LIBRARY_DIR

from .audit_inspect_toml import sky_info, toml_info
from .audit_inspect_xml import xml_info
from .audit_parts import (
    AO_FRACTION,
    PROVIDES,
    SURFACE_FREE_KINDS,
    Applicability,
    Part,
    Rule,
    SceneInfo,
    alternatives,
    default_ao_distance,
    family_note,
    missing_text,
    scene_summary,
    vec_text,
)

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


class AuditError(ValueError):
    """Bad audit input: one line, exit 2."""


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
            return xml_info(inspect_xml(scene, defines, camera=camera, width=width, height=height, up=up))
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
            return xml_info(inspect_xml(path, defines, camera=camera, width=width, height=height, up=up))
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
            return sky_info(str(path))
        toml = load_scene(path)
        if width or height:
            size = {"width": width or toml.camera.width, "height": height or toml.camera.height}
            toml = replace(toml, camera=replace(toml.camera, **size))
        return toml_info(toml, str(path), up)
    except (SceneError, ValueError) as e:
        raise AuditError(str(e).splitlines()[0]) from None
