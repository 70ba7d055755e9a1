"""A user's Mitsuba 3 XML scene, read by Mitsuba's own parser (``mitsuba.parser``, Mitsuba 3.9).

Mitsuba's parser resolves ``<include>``, ``<path>``, ``<default>``/``$name`` parameters and ``<ref>``
exactly as ``mitsuba`` itself does, and records every XML file it read (`ParserState.files`). Data files
(meshes, textures, environment maps, spectra) are named by ``filename`` properties and found through the
file resolver, which ``<path>`` elements extend while the file is parsed. `xml_dependencies` collects
both, so that a reference's cache key covers **every file the scene loads**: edit a mesh three folders
away, reached through an ``<include>`` and a ``<path>``, and the key changes (a key over the files beside
the XML missed exactly that, and returned a stale reference).

Side effects are scoped: the parser adds ``<path>`` folders to Mitsuba's process-wide file resolver;
`xml_dependencies` parses with a resolver of its own and puts the caller's back afterwards.

Errors: a file Mitsuba refuses becomes one `XMLSceneError` line naming the file and line, as Mitsuba
reports them (e.g. ``scene.xml: Parsing of XML file "scene.xml" failed: Start-end tags mismatch (line 4,
col 3)``), without Mitsuba's source-location prefixes.
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass

from .variants import use_variant

__all__ = ["XMLSceneError", "XmlDependencies", "xml_dependencies"]

_CHUNK = 1 << 20
_SOURCE_PREFIX = re.compile(r"\[[A-Za-z0-9_./-]+\.cpp:\d+\]\s*")
_FILE_PROPERTIES = ("filename",)  # plugins name their data files so (ply, obj, serialized, bitmap, envmap, …)


class XMLSceneError(ValueError):
    """A Mitsuba XML scene that Mitsuba refuses: one line naming the user's file and line."""


@dataclass(frozen=True)
class XmlDependencies:
    """Every file a Mitsuba XML scene loads, and one digest over their contents.

    ``xml_files``: the XML files Mitsuba read (the scene and its includes), absolute. ``data_files``: the
    files named by ``filename`` properties, resolved as Mitsuba resolves them (absolute; a name that
    cannot be resolved is kept as written and counted by its name only). ``digest``: SHA-256 over the
    ``-D`` parameters and, per file in a fixed order, its path relative to the scene's folder and its
    bytes — the same on every machine that has the same files in the same layout."""

    path: str
    xml_files: tuple[str, ...]
    data_files: tuple[str, ...]
    digest: str


def _one_line(message: str) -> str:
    text = _SOURCE_PREFIX.sub("", str(message))
    return " ".join(part.strip() for part in text.splitlines() if part.strip())


def _file_digest(h, path: str, root: str) -> None:
    name = os.path.relpath(path, root) if os.path.isabs(path) else path
    h.update(f"\0file\0{name}\0".encode())
    if not os.path.isfile(path):
        h.update(b"\0unresolved")
        return
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)


def xml_dependencies(
    path: str | os.PathLike, defines: Mapping[str, str] | None = None, variant: str = "scalar_rgb"
) -> XmlDependencies:
    """Parse ``path`` with Mitsuba's parser (``defines``: the ``-D name=value`` parameters) and return
    every file it loads with their digest (`XmlDependencies`). Raises `XMLSceneError` (one line) when
    Mitsuba refuses the file."""
    path = os.path.abspath(os.fspath(path))
    defines = {str(k): str(v) for k, v in (defines or {}).items()}
    if not os.path.isfile(path):
        raise XMLSceneError(f"{path}: no such file")
    mi = use_variant(variant)
    import mitsuba.parser as parser  # mitsuba: needs the variant set above

    previous = mi.file_resolver()
    resolver = mi.FileResolver()
    resolver.prepend(os.path.dirname(path))
    mi.set_file_resolver(resolver)
    try:
        try:
            state = parser.parse_file(parser.ParserConfig(variant), path, **defines)
        except RuntimeError as e:
            raise XMLSceneError(f"{path}: {_one_line(str(e))}") from None
        xml_files = tuple(os.path.abspath(str(f)) for f in state.files)
        names = set()
        for node in state.nodes:
            for key in _FILE_PROPERTIES:
                if key in node.props:  # (has_property is deprecated in 3.9: a warning)
                    value = node.props[key]
                    if isinstance(value, str) and value:
                        names.add(value)
        data_files = tuple(sorted(str(mi.file_resolver().resolve(n)) for n in names))
    finally:
        mi.set_file_resolver(previous)
    root = os.path.dirname(path)
    h = hashlib.sha256(b"rtfit.mitsuba_xml/1")
    for k in sorted(defines):
        h.update(f"\0define\0{k}={defines[k]}".encode())
    for f in xml_files + data_files:
        _file_digest(h, f, root)
    return XmlDependencies(path, xml_files, data_files, h.hexdigest())
