"""A Mitsuba XML scene's values checked like an rtfit TOML scene's, before anything renders (issue 32).

Mitsuba accepts a ``<float name="radius" value="nan"/>``, a sphere at x = 1e308, a zero scale, a negative or
infinite radiance, ``<scene version="99.0.0">``: the shape then silently vanishes from the audit, or the
render fails after it wrote a cache entry. rtfit's TOML scenes refuse all of these
(`rtfit.scenes.parse.SCHEMA`); this module applies **the same ranges** (`Bounds`, `MAX_LENGTH`,
`MAX_RADIANCE`, `MAX_COEFFICIENT` from `rtfit.scenes.parse`) and the same message style to what Mitsuba's
parser read, in three passes:

1. `prescan(path)` — **before Mitsuba parses the file**: a streaming Expat pass over the scene and the files
   it ``<include>``s, refusing nesting deeper than `MAX_DEPTH` (Mitsuba's recursive parser overflows the C
   stack on 10,000 nested ``<bsdf>`` elements: SIGSEGV, no message), entity declarations (an XXE /
   billion-laughs vector; Mitsuba scenes use ``$name`` parameters), include cycles, a root other than
   ``<scene>`` and a ``version`` newer than the installed Mitsuba (or not ``major.minor.patch``).
2. `check_values(nodes, camera)` — on the parsed nodes (plugin, properties, file and line; before the scene
   is instantiated): every number finite and within rtfit's limit for its quantity, per `PROPERTY_BOUNDS`
   (a sphere's radius > 0, emitted radiance/intensity ≥ 0, positions within ±`MAX_LENGTH`, the field of
   view in (0°, 180°), film sizes in [1, 16384] as the TOML camera's), every ``to_world`` finite and not
   singular (a zero scale: the shape, or the area light on it, has no size), and the chosen sensor a
   ``perspective`` one (the audit traces its G-buffer through a pinhole camera); a numeric index of
   refraction in [1, 10] (`_IOR`) and a light's direction non-zero (`NONZERO`).
3. `mesh_problem(path)` (`rtfit.scenes.mesh_files`, shared with the TOML scenes' meshes) — a mesh file
   named by a shape, before Mitsuba loads it. The problem names the file; no message quotes its content.

Each problem is one line, ``<file> (line L, col C): <element type="plugin"> key: must be … (got …)``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from importlib import metadata
from xml.parsers import expat

from rtfit.scenes import mesh_files
from rtfit.scenes.model import Camera
from rtfit.scenes.parse import MAX_COEFFICIENT, MAX_LENGTH, MAX_RADIANCE, SCHEMA, Bounds

__all__ = [
    "MAX_DEPTH",
    "MAX_INCLUDES",
    "PROPERTY_BOUNDS",
    "SENSORS",
    "XmlNode",
    "check_values",
    "mesh_problem",
    "prescan",
]

MAX_DEPTH = 64
"""Element nesting (a scene and its includes together). Real scenes nest < 15 deep (scene → shape → twosided
→ blend → bsdf → texture …); Mitsuba 3.9's recursive parser crashes (SIGSEGV) at about 10⁴."""
MAX_INCLUDES = 1000  # files read through <include> (each once per including element)
SENSORS = ("perspective",)
"""Sensor plugins the audit can use: it traces the G-buffer at pixel centres through the camera's pinhole
(an ``orthographic`` sensor has no field of view; a ``thinlens`` one would blur the reference it compares)."""
GENERIC = Bounds(limit=MAX_RADIANCE)  # any other number: finite, |x| ≤ 1e12
_LENGTH = Bounds(0.0, lo_open=True, limit=MAX_LENGTH)
_COORDINATE = Bounds(limit=MAX_LENGTH)
_EMISSION = Bounds(0.0, limit=MAX_RADIANCE)


def _camera_bounds(field: str) -> Bounds:
    """The bounds of a TOML camera's field (`SCHEMA`): one table for both formats."""
    bounds = SCHEMA[Camera][field].bounds
    if bounds is None:
        raise TypeError(f"SCHEMA[Camera][{field!r}] has no bounds")
    return bounds


_FILM = _camera_bounds("width")  # [1, 16384], as a TOML camera's width and height
_FOV = _camera_bounds("fov_deg")  # (0, 180)

PROPERTY_BOUNDS: dict[str, dict[str, Bounds]] = {
    "Shape": {
        "radius": _LENGTH,
        "center": _COORDINATE,
        "p0": _COORDINATE,
        "p1": _COORDINATE,
    },
    "Emitter": {
        "radiance": _EMISSION,
        "irradiance": _EMISSION,
        "intensity": _EMISSION,
        "scale": _EMISSION,
        "sun_scale": _EMISSION,
        "sky_scale": _EMISSION,
        "position": _COORDINATE,
        "cutoff_angle": Bounds(0.0, 90.0, lo_open=True),
        "beam_width": Bounds(0.0, 90.0, lo_open=True),
    },
    "Sensor": {
        "fov": _FOV,
        "near_clip": Bounds(0.0, lo_open=True, limit=MAX_RADIANCE),
        "far_clip": Bounds(0.0, lo_open=True, limit=MAX_RADIANCE),
    },
    "Film": {"width": _FILM, "height": _FILM},
    "Medium": {
        "sigma_t": Bounds(0.0, limit=MAX_COEFFICIENT),
        "albedo": Bounds(0.0, 1.0),
        "scale": Bounds(0.0, limit=MAX_COEFFICIENT),
    },
}
"""Per node kind (Mitsuba's object type), the bounds of a property by name: a number, or each component of a
colour, vector or spectrum. Numbers not named here are only kept finite and within ±1e12."""
_DIFFUSE = {"reflectance": Bounds(0.0, 1.0)}  # a diffuse BSDF's albedo, as a TOML material's
_IOR = Bounds(1.0, 10.0)
"""A dielectric's (or plastic's) ``int_ior``/``ext_ior`` given as a number: Mitsuba accepts 0 and the render
then fails on NaN after writing a cache entry; its own table spans 1.0 (vacuum) to 2.42 (diamond)."""
NONZERO: dict[str, tuple[str, ...]] = {"Emitter": ("direction", "sun_direction")}
"""Vectors that must not be zero (as a TOML light's ``direction``): Mitsuba accepts a ``directional``
emitter pointing nowhere, and the audit failed after rendering with "expected an (N, 3) array"."""


class XmlProblem(ValueError):
    """Internal: the first problem found, one line."""


@dataclass(frozen=True)
class XmlNode:
    """One parsed node: ``kind`` (Mitsuba's object type: ``Shape``, ``Emitter``, ``Sensor``, …), ``plugin``,
    ``props`` (plain values: numbers, strings, tuples for colours/vectors/spectra, 4×4 row tuples for
    transforms, ``("ref", i)`` references) and ``location`` (Mitsuba's ``file (line L, col C)``)."""

    kind: str
    plugin: str
    props: Mapping[str, object]
    location: str


# ------------------------------------------------------------------------------------------- pre-scan
def _version(text: str) -> tuple[int, ...] | None:
    m = re.fullmatch(r"\s*(\d{1,4})\.(\d{1,4})\.(\d{1,4})\s*", text)
    return tuple(int(g) for g in m.groups()) if m else None


def _installed_mitsuba() -> tuple[int, ...] | None:
    try:
        return _version(".".join(metadata.version("mitsuba").split(".")[:3]))
    except (metadata.PackageNotFoundError, ValueError):
        return None


_COMMENT = re.compile(rb"<!--.*?-->", re.DOTALL)


def _without_comments(data: bytes) -> bytes:
    """``data`` with every ``<!-- … -->`` comment replaced by its own newlines (line numbers kept). XML 1.0
    forbids ``--`` inside a comment and Expat refuses it, but Mitsuba's parser (pugixml) reads a comment up
    to the first ``-->``, as real scenes rely on: Sionna's scenes open with ``<!--`` then ``-- SPDX-…``
    lines. The pre-scan must not refuse what Mitsuba loads; a comment hides no element either way."""
    return _COMMENT.sub(lambda m: b"\n" * m.group().count(b"\n"), data)


class _Scan:
    """The state of one pre-scan: files on the include stack, files read, `<path>` folders."""

    def __init__(self, root: str):
        self.stack: list[str] = []
        self.files = 0
        self.folders = [os.path.dirname(root)]
        self.installed = _installed_mitsuba()

    def include(self, name: str, here: str) -> str | None:
        """The file an ``<include filename=…>`` names, as the scan can find it (None: left to Mitsuba)."""
        if not name or "$" in name:
            return None
        for folder in (os.path.dirname(here), *self.folders):
            candidate = os.path.normpath(os.path.join(folder, name))
            if os.path.isfile(candidate):
                return candidate
        return None

    def file(self, path: str, depth0: int) -> None:
        if path in self.stack:
            raise XmlProblem(
                f"{path}: includes itself (through {' → '.join(map(os.path.basename, self.stack))})"
            )
        self.files += 1
        if self.files > MAX_INCLUDES:
            raise XmlProblem(f"{path}: more than {MAX_INCLUDES} included files (rtfit's limit)")
        self.stack.append(path)
        parser = expat.ParserCreate()
        parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
        depth = [depth0]
        first = [True]
        includes: list[tuple[str, int]] = []

        def where() -> str:
            return f"{path} (line {parser.CurrentLineNumber})"

        def refuse_entity(name, *_):
            raise XmlProblem(f"{where()}: entity declaration {name!r} (not allowed in a scene file)")

        def start(name, attrs):
            depth[0] += 1
            if depth[0] > MAX_DEPTH:
                raise XmlProblem(
                    f"{where()}: <{name}> nested {depth[0]} deep: must be <= {MAX_DEPTH} (rtfit's limit; "
                    f"Mitsuba's parser crashes on deep nesting)"
                )
            if first[0]:
                first[0] = False
                self.root(name, attrs, where())
            elif name == "include":
                includes.append((attrs.get("filename", ""), depth[0]))
            elif name == "path" and attrs.get("value") and "$" not in attrs["value"]:
                self.folders.append(os.path.join(os.path.dirname(path), attrs["value"]))

        def end(_name):
            depth[0] -= 1

        parser.EntityDeclHandler = refuse_entity
        parser.StartElementHandler = start
        parser.EndElementHandler = end
        try:
            with open(path, "rb") as f:
                parser.Parse(_without_comments(f.read()), True)
        except expat.ExpatError as e:
            what = expat.ErrorString(e.code)
            raise XmlProblem(
                f"{path}: not well-formed XML (line {e.lineno}, column {e.offset}: {what})"
            ) from None
        except OSError as e:
            raise XmlProblem(f"{path}: cannot read ({e.strerror or e})") from None
        for name, at in includes:  # after the file: Mitsuba reads an include where it stands, at that depth
            target = self.include(name, path)
            if target is not None:
                self.file(target, at)
        self.stack.pop()

    def root(self, name: str, attrs: Mapping[str, str], where: str) -> None:
        if name != "scene" and len(self.stack) == 1:
            raise XmlProblem(f"{where}: the root element is <{name}>, not <scene>")
        text = attrs.get("version")
        if text is None:
            return  # Mitsuba's own message names the missing attribute
        v = _version(text)
        if v is None:
            raise XmlProblem(
                f'{where}: <{name} version="{text[:40]}">: must be major.minor.patch, e.g. 3.0.0'
            )
        if self.installed is not None and v > self.installed:
            have = ".".join(map(str, self.installed))
            raise XmlProblem(
                f'{where}: <{name} version="{text}">: must be <= {have} (the installed Mitsuba; a newer '
                f"file may use what this one does not know)"
            )


def prescan(path: str) -> str | None:
    """What makes the scene ``path`` (and its includes) unsafe to hand to Mitsuba's parser (module
    docstring, pass 1), as one line; None when nothing is found."""
    try:
        _Scan(path).file(os.path.abspath(path), 0)
    except XmlProblem as e:
        return str(e)
    return None


# ---------------------------------------------------------------------------------------------- values
def _show(x: object) -> str:
    if isinstance(x, float):
        return repr(x) if not math.isfinite(x) else f"{x:g}"
    if isinstance(x, tuple):
        return "(" + ", ".join(_show(v) for v in x[:6]) + (", …" if len(x) > 6 else "") + ")"
    return repr(x)


def _element(node: XmlNode) -> str:
    return f'<{node.kind.lower()} type="{node.plugin}">'


def _number(node: XmlNode, key: str, x: float, shown: object, bounds: Bounds) -> None:
    if not math.isfinite(x):
        raise XmlProblem(f"{node.location}: {_element(node)} {key}: must be finite (got {_show(shown)})")
    if not bounds.contains(x):
        raise XmlProblem(f"{node.location}: {_element(node)} {key}: {bounds.problem(x)} (got {_show(shown)})")


def _is_matrix(v: object) -> bool:
    return isinstance(v, tuple) and len(v) == 4 and all(isinstance(r, tuple) and len(r) == 4 for r in v)


def _transform(node: XmlNode, key: str, m: tuple) -> None:
    flat = [float(x) for row in m for x in row]
    if not all(math.isfinite(x) for x in flat):
        bad = next(x for x in flat if not math.isfinite(x))
        raise XmlProblem(f"{node.location}: {_element(node)} {key}: must be finite (got an entry {bad!r})")
    for i in range(3):
        _number(node, f"{key} translation", float(m[i][3]), float(m[i][3]), _COORDINATE)
        for j in range(3):
            _number(node, f"{key} matrix", float(m[i][j]), float(m[i][j]), Bounds(limit=MAX_LENGTH))
    a = [[float(m[i][j]) for j in range(3)] for i in range(3)]
    det = (
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    )
    if det == 0.0:
        what = (
            "a zero scale: the shape, and a light on it, has no size"
            if node.kind == "Shape"
            else "a zero scale"
        )
        raise XmlProblem(
            f"{node.location}: {_element(node)} {key}: must not be singular ({what}; got determinant 0)"
        )


def _value(node: XmlNode, key: str, v: object, bounds: Bounds) -> None:
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return
    if isinstance(v, int):
        if key in ("width", "height") and node.kind == "Film":
            _number(node, key, float(v), v, bounds)
        return
    if isinstance(v, float):
        _number(node, key, v, v, bounds)
        return
    if isinstance(v, tuple) and v[:1] != ("ref",):
        if _is_matrix(v):
            _transform(node, key, v)
            return
        for x in v:
            if isinstance(x, int | float) and not isinstance(x, bool):
                _number(node, key, float(x), v, bounds)


def _bounds(node: XmlNode, key: str) -> Bounds:
    if node.kind == "BSDF" and node.plugin == "diffuse" and key in _DIFFUSE:
        return _DIFFUSE[key]
    if node.kind == "BSDF" and key in ("int_ior", "ext_ior"):
        return _IOR
    return PROPERTY_BOUNDS.get(node.kind, {}).get(key, GENERIC)


def check_values(nodes: Iterable[XmlNode], camera: int = 0) -> str | None:
    """The first value of the parsed ``nodes`` outside rtfit's ranges (module docstring, pass 2), as one
    line; None when all are within. ``camera``: the index (document order) of the sensor the audit uses."""
    try:
        sensors = 0
        for node in nodes:
            if node.kind == "Sensor":
                if sensors == camera and node.plugin not in SENSORS:
                    raise XmlProblem(
                        f"{node.location}: {_element(node)}: the audit supports {', '.join(SENSORS)} sensors "
                        f"only (sensor {camera}; --camera picks another)"
                    )
                sensors += 1
            for key, v in node.props.items():
                if key.startswith("_arg_"):
                    continue
                _value(node, key, v, _bounds(node, key))
                if key in NONZERO.get(node.kind, ()) and isinstance(v, tuple) and not any(v):
                    raise XmlProblem(
                        f"{node.location}: {_element(node)} {key}: must be non-zero (got {_show(v)})"
                    )
    except XmlProblem as e:
        return str(e)
    return None


def mesh_problem(path: str) -> str | None:
    """What makes the mesh file ``path`` unreadable (`rtfit.scenes.mesh_files.mesh_problem`, positions within
    ±`MAX_LENGTH` as a TOML scene's), as one reason naming no file content; None when nothing is found."""
    return mesh_files.mesh_problem(path, MAX_LENGTH)
