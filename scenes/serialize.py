"""Scene → canonical dict / TOML text, and the scene's physics hash.

:func:`scene_to_dict` writes every field explicitly in the file format (sphere lights as
``center``/``radius``, RGB as 3-lists, absolute file paths, numbers as ``float`` except integer
fields). Optional fields whose value is ``None`` (``reference.max_depth``,
``override_material``) are left out, since TOML has no null. ``Scene.source`` is not part of the
file format, so ``parse_scene_text(scene_to_toml(s), source=s.source) == s``.

:func:`scene_hash` identifies the physics: name, description and source are left out, and every
referenced file is represented by the SHA-256 of its contents (for a Mitsuba XML file, also of the
files it references), so a moved file keeps the hash and an edited one changes it.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import xml.etree.ElementTree as ET
from typing import Any

import tomli_w

from .model import Scene
from .parse import BOUNDARY_EXCLUDES, SCHEMA, SceneError, Spec

HASH_FORMAT = 1  # bump when the meaning of a hashed field changes
_CHUNK = 1 << 20


# -------------------------------------------------------------------------------------------- dicts
def _dump_value(spec: Spec, v: Any) -> Any:
    kind = spec.kind
    if kind == "float":
        return float(v)
    if kind in ("int", "depth"):
        return int(v)
    if kind == "bool":
        return bool(v)
    if kind in ("str", "choice", "file"):
        return str(v)
    if kind in ("vec3", "vec2", "unit"):
        return [float(c) for c in v]
    if kind == "rgb":
        return [float(v)] * 3 if isinstance(v, (int, float)) else [float(c) for c in v]
    if kind == "material":
        return _dump_object(v)
    if kind == "boundary":
        return _dump_object(v, exclude=BOUNDARY_EXCLUDES)
    raise AssertionError(f"unknown spec kind {kind!r}")


def _dump_object(obj: Any, exclude=()) -> dict[str, Any]:
    specs = SCHEMA.get(type(obj))
    if specs is None:
        raise TypeError(f"cannot serialise {type(obj).__name__}: not a rtfit.scenes.model class")
    out: dict[str, Any] = {"type": obj.kind} if hasattr(obj, "kind") else {}
    for name, spec in specs.items():
        v = getattr(obj, name)
        if name not in exclude and not (v is None and spec.optional):
            out[name] = _dump_value(spec, v)
    return out


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """The canonical plain dict of ``scene`` in the file format (JSON- and TOML-serialisable)."""
    return {
        "name": scene.name,
        "description": scene.description,
        "camera": _dump_object(scene.camera),
        "reference": _dump_object(scene.reference),
        "shapes": [_dump_object(s) for s in scene.shapes],
        "lights": [_dump_object(light) for light in scene.lights],
        "media": [_dump_object(m) for m in scene.media],
    }


_NUMBER_ARRAY = re.compile(r"\[\n((?:[ \t]+[-+0-9.eEinfa_]+,\n)+)\]")


def scene_to_toml(scene: Scene) -> str:
    """``scene`` as scene-file text (number arrays written on one line)."""

    text = tomli_w.dumps(scene_to_dict(scene))
    return _NUMBER_ARRAY.sub(_one_line_array, text)


def _one_line_array(m: re.Match) -> str:
    return "[" + ", ".join(x.strip().rstrip(",") for x in m.group(1).splitlines()) + "]"


# --------------------------------------------------------------------------------------------- hash
def _file_sha256(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def _xml_sha256(path: str, seen: frozenset[str] = frozenset()) -> str:
    """SHA-256 of a Mitsuba XML file and of the files it references (``filename`` properties and
    ``<include>``s, relative to its folder, recursively for XML). A reference that cannot be
    resolved here (missing, or using a ``$parameter``) contributes its text only."""
    with open(path, "rb") as f:
        data = f.read()
    h = hashlib.sha256(data)
    try:
        root = ET.fromstring(data)
    except ET.ParseError:
        return h.hexdigest()  # Mitsuba will report it; the bytes still identify the file
    refs = {el.get("value") for el in root.iter() if el.get("name") == "filename"}
    refs |= {el.get("filename") for el in root.iter("include")}
    folder = os.path.dirname(path)
    for ref in sorted(r for r in refs if r):
        target = os.path.normpath(os.path.join(folder, ref))
        digest = "unresolved"
        if "$" not in ref and os.path.isfile(target):
            if target.lower().endswith(".xml") and target not in seen:
                digest = _xml_sha256(target, seen | {path})
            elif not target.lower().endswith(".xml"):
                digest = _file_sha256(target)
        h.update(f"\0{ref}\0{digest}".encode())
    return h.hexdigest()


def _replace_files(node: Any, key: str, source: str) -> Any:
    """A copy of the dict tree with every ``file`` path replaced by ``{"sha256": ...}``."""
    if isinstance(node, list):
        return [_replace_files(x, f"{key}[{i}]", source) for i, x in enumerate(node)]
    if not isinstance(node, dict):
        return node
    out = {}
    for k, v in node.items():
        sub = f"{key}.{k}" if key else k
        if k == "file" and isinstance(v, str):
            try:
                v = {"sha256": _xml_sha256(v) if node.get("type") == "mitsuba_xml" else _file_sha256(v)}
            except OSError as e:
                reason = f"cannot read {v} ({e.strerror or type(e).__name__})"
                raise SceneError.at(source, sub, reason) from None
        out[k] = _replace_files(v, sub, source)
    return out


def scene_hash(scene: Scene) -> str:
    """Hex SHA-256 identifying the scene's physics (see the module docstring). Stable across
    processes and platforms: canonical JSON with sorted keys, floats written by ``repr``."""
    d = scene_to_dict(scene)
    for k in ("name", "description", "source"):
        d.pop(k, None)
    payload = {"format": HASH_FORMAT, "scene": _replace_files(d, "", scene.source)}
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)
    return hashlib.sha256(text.encode("ascii")).hexdigest()
