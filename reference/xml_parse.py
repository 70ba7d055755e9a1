"""Mitsuba's parser on a user's XML scene (or a scene dict), scoped, and what every reader of it shares.

`parsed_xml` parses a file (``mitsuba.parser``, Mitsuba 3.9) under a file resolver of its own and the
caller's variant put back afterwards; a file Mitsuba refuses is one `XMLSceneError` line naming the file
and line (`mitsuba_error_text`). `xml_dependencies` (`collect_dependencies`) lists every file the scene
loads and digests them for a reference's cache key. The parsed nodes' values as plain Python
(`node_props`, `plain_value`) are checked against rtfit's ranges and the mesh files read before anything
is instantiated (`check_nodes`: `rtfit.reference.xml_checks`), and `instantiate_checked` instantiates the
scene with Mitsuba's own check of properties no plugin reads. `rtfit.reference.mitsuba_xml` re-exports the
public names; `rtfit.reference.xml_inspect` and `mitsuba_xml.loaded_xml` read scenes through this module.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from .variants import inspection_variant, scoped_variant
from .xml_checks import XmlNode, check_values, mesh_problem, prescan

_CHUNK = 1 << 20
_SOURCE_PREFIX = re.compile(r"\[[A-Za-z0-9_./-]+\.(?:cpp|h):\d+\]\s*")
_FILE_PROPERTIES = ("filename",)  # plugins name their data files so (ply, obj, serialized, bitmap, envmap, …)

MESH_PLUGINS = ("ply", "obj", "serialized")
"""The shape plugins that load a mesh file (``filename``): checked before instantiating (`check_nodes`)."""
# Mitsuba 3.9's PLY loader reads triangle faces only; these are its messages for other faces.
_PLY_FACE_ERRORS = ("trailing tokens", "non-triangular faces", "is this a triangle mesh")
_PLY_HINT = "Mitsuba's PLY loader reads triangle faces only: triangulate the mesh, or save it as OBJ"


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


@contextlib.contextmanager
def parsed_xml(path, defines: Mapping[str, str], variant: str | None) -> Iterator[tuple]:
    """Parse ``path`` (or a scene dict, `DICT_SOURCE`, with ``mitsuba.parser.parse_dict``) under a file
    resolver of its own (a copy of the caller's, so that plugins are still found, with the scene's folder
    first); yields ``(mi, parser, config, state, unread)`` and puts the caller's
    resolver back afterwards. Mitsuba's refusal becomes one `XMLSceneError` line. ``unread``: each node's
    properties nobody had read when the file was parsed, for `instantiate_checked` (rtfit's own reading of the
    values marks them read, which would hide a property no plugin uses from Mitsuba's check)."""
    given = path if isinstance(path, Mapping) else None
    if given is None and not os.path.isfile(path):
        raise XMLSceneError(f"{path}: no such file")
    problem = prescan(path) if given is None else None  # its parser crashes on deep nesting
    if problem is not None:
        raise XMLSceneError(problem)
    variant = variant or inspection_variant()
    with scoped_variant(variant) as mi:  # the caller's variant is put back afterwards
        import mitsuba.parser as parser  # mitsuba: needs the variant set above

        previous = mi.file_resolver()
        resolver = mi.FileResolver(previous)
        if given is None:
            resolver.prepend(os.path.dirname(path))
        mi.set_file_resolver(resolver)
        try:
            config = parser.ParserConfig(variant)
            try:
                if given is not None:
                    state = parser.parse_dict(config, dict(given))
                    parser.write_string(state)  # refuses what the dict cannot describe as text
                else:
                    state = parser.parse_file(config, path, **defines)
            except RuntimeError as e:
                hint = (
                    " (give each part as its plugin dict, {'type': ...}, not an instantiated object)"
                    if given is not None and "object" in str(e)
                    else ""
                )
                raise XMLSceneError(f"{source_label(path)}: {mitsuba_error_text(e)}{hint}") from None
            except UnicodeDecodeError:  # Mitsuba's message quoted bytes of a file that is not text
                raise XMLSceneError(
                    f"{path}: Mitsuba could not parse it (a file it reads is not text)"
                ) from None
            yield mi, parser, config, state, [tuple(n.props.unqueried()) for n in state.nodes]
        finally:
            mi.set_file_resolver(previous)


def collect_dependencies(mi, path, defines: Mapping[str, str], state) -> XmlDependencies:
    """Every file the parsed ``state`` loads (the XML files Mitsuba read, the data files its ``filename``
    properties name, resolved by the current file resolver) and their digest (`XmlDependencies`); for a
    scene dict, its parsed nodes stand for the XML text in the digest."""
    xml_files = tuple(os.path.abspath(str(f)) for f in state.files)
    given = isinstance(path, Mapping)
    names = set()
    for node in state.nodes:
        for key in _FILE_PROPERTIES:
            if key in node.props:  # (has_property is deprecated in 3.9: a warning)
                value = node.props[key]
                if isinstance(value, str) and value:
                    names.add(value)
    data_files = tuple(sorted(str(mi.file_resolver().resolve(n)) for n in names))
    root = os.getcwd() if given else os.path.dirname(path)
    h = hashlib.sha256(b"rtfit.mitsuba_xml/1")
    for k in sorted(defines):
        h.update(f"\0define\0{k}={defines[k]}".encode())
    if given:  # a scene dict: its parsed nodes (plugin, id, every property's value) stand for the XML text
        for node in state.nodes:
            what = (
                str(node.type),
                node.props.plugin_name(),
                node.props.id(),
                node_props(node),
                _spectra(node),
            )
            h.update(f"\0node\0{what!r}".encode())
    for f in xml_files + data_files:
        _file_digest(h, f, root)
    return XmlDependencies(source_label(path), xml_files, data_files, h.hexdigest())


DICT_SOURCE = "scene dict"
"""What stands for the file name of a scene given as a dict (``mitsuba.load_dict`` style): in
`XmlScene.path`, `XmlDependencies.path` and the first words of every error line."""


def source_label(path) -> str:
    """What error lines and records call ``path``: the path as given, or `DICT_SOURCE` for a scene dict."""
    return DICT_SOURCE if isinstance(path, Mapping) else str(path)


def normalised_source(path, defines) -> tuple[str | Mapping, dict[str, str]]:
    """(the absolute path, or the scene dict as given; the ``-D`` parameters as strings). A scene dict
    takes no ``-D`` parameters (they are XML's ``$name`` substitution)."""
    defines = {str(k): str(v) for k, v in (defines or {}).items()}
    if isinstance(path, Mapping):
        if defines:
            raise XMLSceneError(
                f"{DICT_SOURCE}: -D parameters are for XML files (put the values in the dict)"
            )
        return path, defines
    return os.path.abspath(os.fspath(path)), defines


def xml_dependencies(
    path: str | os.PathLike, defines: Mapping[str, str] | None = None, variant: str | None = None
) -> XmlDependencies:
    """Parse ``path`` with Mitsuba's parser (``defines``: the ``-D name=value`` parameters) and return
    every file it loads with their digest (`XmlDependencies`). Raises `XMLSceneError` (one line) when
    Mitsuba refuses the file."""
    path, defines = normalised_source(path, defines)
    with parsed_xml(path, defines, variant) as (mi, _parser, _config, state, _unread):
        return collect_dependencies(mi, path, defines, state)


def plain_value(value):
    """A property value as plain Python: numbers and strings as they are, colours/vectors as tuples,
    transforms as 4×4 row tuples, references as the node index (``("ref", i)``)."""
    if isinstance(value, bool | int | float | str):
        return value
    index = getattr(value, "index", None)
    if callable(index):
        return ("ref", int(index()))
    matrix = getattr(value, "matrix", None) if "Transform" in type(value).__name__ else None
    if matrix is not None:
        return tuple(tuple(float(x) for x in row) for row in np.asarray(matrix, dtype=float))
    try:
        return tuple(float(x) for x in value)
    except TypeError:
        return None


def instantiate_checked(parser, config, state, unread: list[tuple[str, ...]]):
    """``parser.instantiate`` after marking unread again each property that was unread when the file was
    parsed (`parsed_xml`): rtfit read every value to check it (`node_props`), and Mitsuba refuses a property
    that no plugin reads only if it is still unread ("Found 1 unreferenced property …"; issue 32: a misspelt
    ``<float name="radus">`` was silently ignored)."""
    for node, names in zip(state.nodes, unread, strict=False):
        for name in names:
            node.props.mark_queried(name, False)
    return parser.instantiate(config, state)


def node_props(node) -> dict:
    """A parsed node's properties as plain Python (`plain_value` of each), by name."""
    return {k: plain_value(node.props[k]) for k in node.props.keys()}


def resolved_file(mi, name) -> str:
    """``name`` (a ``filename`` property) resolved by Mitsuba's current file resolver; ``""`` for no name."""
    return str(mi.file_resolver().resolve(name)) if isinstance(name, str) and name else ""


NOT_TEXT_ERROR = (
    "Mitsuba could not load it, and its message is not text (a mesh or image file that is corrupt?)"
)
"""The error line's text when instantiating a scene fails with a message that is not text."""


def mitsuba_error_text(e: RuntimeError) -> str:
    """Mitsuba's error ``e`` as one line without its source-location prefixes, with a hint for a PLY file
    of non-triangular faces (Mitsuba 3.9's PLY loader reads triangles only) and for a ``$name`` the scene
    uses without a ``<default>`` (Mitsuba's own scenes leave ``$spp`` and ``$res`` to the command line)."""
    text = _one_line(str(e))
    if "PLYMesh" in text and any(m in text for m in _PLY_FACE_ERRORS):
        text += f" ({_PLY_HINT})"
    undefined = re.search(r"undefined parameter: \$(\w+)", text)
    if undefined:
        text += f" (give it a value: -D {undefined.group(1)}=VALUE)"
    return text


def _spectra(node) -> dict:
    """A node's spectrum properties (``<spectrum value="5"/>``, wavelength:value lists) as their values."""
    out = {}
    for k in node.props.keys():
        v = node.props[k]
        if type(v).__name__ == "Spectrum":
            out[k] = tuple(float(x) for x in np.asarray(v.values, dtype=float).ravel())
    return out


def check_nodes(mi, nodes, kinds, props, where, camera: int) -> None:
    """The scene's values in rtfit's ranges and its mesh files readable (`rtfit.reference.xml_checks`),
    before it is instantiated: one `XMLSceneError` line naming the file, element, key and range."""
    records = [
        XmlNode(k, n.props.plugin_name(), {**p, **_spectra(n)}, w)
        for n, k, p, w in zip(nodes, kinds, props, where, strict=True)
    ]
    problem = check_values(records, camera)
    if problem is not None:
        raise XMLSceneError(problem)
    for r in records:
        if r.kind == "Shape" and r.plugin in MESH_PLUGINS and isinstance(r.props.get("filename"), str):
            file = resolved_file(mi, r.props["filename"])
            problem = mesh_problem(file)
            if problem is not None:
                raise XMLSceneError(f'{r.location}: <shape type="{r.plugin}"> filename {file}: {problem}')
