"""Export an rtfit TOML scene to plain Mitsuba 3 XML (issue 15 §1).

The scene is built exactly as rtfit's references build it (`rtfit.reference.build.mitsuba_scene_dict`:
the same camera, shapes, BSDFs, lights, media and the integrator rtfit would choose), then written by
Mitsuba's own writer (``mitsuba.parser.parse_dict`` → ``transform_relocate`` → ``write_file``), so the XML
loads in a stock ``mitsuba`` and renders the same stock parts. Mesh files the scene uses (library meshes,
generated boundary meshes) are copied beside the XML by Mitsuba's relocation (its ``meshes/`` folder).

What cannot be exported is rtfit's own plugins, registered from Python at run time and unknown to a stock
Mitsuba: the distant-disc sun (a sun with ``angular_radius_deg > 0``), the exponential height-fog medium and
the Nishita atmosphere medium. They are left out, together with what only they give meaning to (a fog's
null-BSDF boundary shapes, the sensor's reference to a medium it sits in), and each is named in
`XmlExport.left_out` — the CLI prints one line per part. A scene made only of rtfit's own plugins still
writes its camera and surfaces.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from rtfit.scenes import Scene

from . import emitters, height_fog, nishita_sky
from .build import mitsuba_scene_dict
from .io import atomic_write_bytes
from .variants import inspection_variant, scoped_variant

__all__ = ["RTFIT_PLUGINS", "XmlExport", "export_xml", "exportable_dict"]

RTFIT_PLUGINS = {
    emitters.PLUGIN: "rtfit's distant-disc sun (a sun with angular_radius_deg > 0)",
    height_fog.PLUGIN: "rtfit's exponential height-fog medium",
    nishita_sky.MEDIUM_PLUGIN: "rtfit's Nishita atmosphere medium",
    nishita_sky.PHASE_PLUGIN: "rtfit's Rayleigh + Mie phase function",
}
"""rtfit's own Mitsuba plugins (registered from Python; a stock Mitsuba does not know them) and what
each one is, for the line that says it was left out."""


@dataclass(frozen=True)
class XmlExport:
    """The written XML file and the scene parts left out of it (one sentence each)."""

    path: Path
    left_out: tuple[str, ...]


def _uses_rtfit_plugin(value) -> str | None:
    """The first rtfit plugin type inside a plugin dict (recursively), else None."""
    if isinstance(value, dict):
        t = value.get("type")
        if isinstance(t, str) and t in RTFIT_PLUGINS:
            return t
        for v in value.values():
            found = _uses_rtfit_plugin(v)
            if found:
                return found
    return None


def _refers_to(value, ids: set[str]) -> bool:
    """Whether a plugin dict refers (``{"type": "ref", "id": …}``) to one of ``ids``."""
    if isinstance(value, dict):
        if value.get("type") == "ref" and value.get("id") in ids:
            return True
        return any(_refers_to(v, ids) for v in value.values())
    return False


def exportable_dict(d: dict) -> tuple[dict, list[str]]:
    """``d`` (a `mitsuba_scene_dict`) without rtfit's own plugins and what refers to them; returns the
    new dict and one sentence per part left out."""
    out = dict(d)
    left: list[str] = []
    removed: set[str] = set()
    for key, value in d.items():
        plugin = _uses_rtfit_plugin(value)
        if plugin is not None:
            del out[key]
            removed.add(key)
            left.append(f"{key}: {RTFIT_PLUGINS[plugin]} (rtfit's own plugin; a stock Mitsuba has none)")
    for key, value in list(out.items()):
        if key != "sensor" and _refers_to(value, removed):
            del out[key]
            left.append(f"{key}: the boundary shape of a medium that was left out")
    sensor = out.get("sensor")
    if isinstance(sensor, dict) and _refers_to(sensor.get("medium"), removed):
        out["sensor"] = {k: v for k, v in sensor.items() if k != "medium"}
        left.append("sensor: its reference to the medium it sits in (left out)")
    return out, left


def export_xml(scene: Scene, path: str | os.PathLike) -> XmlExport:
    """Write ``scene`` as Mitsuba 3 XML to ``path`` (atomically; mesh files copied into a ``meshes/``
    folder beside it). Returns the path and the parts left out."""
    path = Path(path)
    with scoped_variant(inspection_variant()) as mi:  # the caller's variant is put back afterwards
        import mitsuba.parser as parser  # mitsuba: needs the variant set above

        d, left = exportable_dict(mitsuba_scene_dict(mi, scene, fog_path=False))
        config = parser.ParserConfig(mi.variant())
        state = parser.parse_dict(config, d)
        parser.transform_relocate(config, state, str(path.parent))
        with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
            scratch = Path(tmp) / path.name
            parser.write_file(state, str(scratch))
            atomic_write_bytes(path, scratch.read_bytes())
    return XmlExport(path, tuple(left))
