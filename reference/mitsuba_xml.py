"""A user's Mitsuba 3 XML scene, read by Mitsuba's own parser (``mitsuba.parser``, Mitsuba 3.9).

Mitsuba's parser resolves ``<include>``, ``<path>``, ``<default>``/``$name`` parameters and ``<ref>``
exactly as ``mitsuba`` itself does, and records every XML file it read (`ParserState.files`). Data files
(meshes, textures, environment maps, spectra) are named by ``filename`` properties and found through the
file resolver, which ``<path>`` elements extend while the file is parsed. `xml_dependencies` collects
both, so that a reference's cache key covers **every file the scene loads**: edit a mesh three folders
away, reached through an ``<include>`` and a ``<path>``, and the key changes (a key over the files beside
the XML missed exactly that, and returned a stale reference).

Side effects are scoped: the parser adds ``<path>`` folders to Mitsuba's process-wide file resolver;
`xml_dependencies` and `inspect_xml` parse with a resolver of their own (a copy of the caller's, so that
plugins are still found) and put the caller's back afterwards, and the caller's Mitsuba variant too.

`inspect_xml` reads what the scene contains — sensors, emitters, shapes, BSDFs, media, the integrator —
from the parser's state, and instantiates the scene (`mitsuba.parser.instantiate`, under the same scoped
resolver) for what the properties do not say: the film size and field of view Mitsuba derives (defaults,
``focal_length``), the mesh face counts and the bounding boxes (a sphere light's centre and radius, the
scene's extent). Instantiating also loads every mesh, so a mesh Mitsuba cannot read (a PLY with
non-triangular faces: Mitsuba 3.9's PLY loader takes triangles only) is an `XMLSceneError` here, naming
the XML file and line that declares it.

Errors: a file Mitsuba refuses becomes one `XMLSceneError` line naming the file and line, as Mitsuba
reports them (e.g. ``scene.xml: Error while loading scene.xml (line 9, col 6): encountered an unsupported XML
element: <widget>``), without Mitsuba's source-location prefixes. Before Mitsuba parses a file,
`rtfit.reference.xml_checks.prescan` refuses what would crash its parser (deep nesting), entity declarations,
a newer ``version`` and XML that is not well-formed; before the scene is instantiated, `check_values` checks
every value against the TOML scene's ranges and `mesh_problem` every mesh file (issue 32).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .particle_media import convex_mesh
from .variants import inspection_variant, scoped_variant
from .xml_checks import XmlNode, check_values, mesh_problem, prescan

__all__ = [
    "DICT_SOURCE",
    "UP_AXES",
    "LoadedXml",
    "XMLSceneError",
    "XmlDependencies",
    "XmlEmitter",
    "XmlMedium",
    "XmlScene",
    "XmlSensor",
    "XmlShape",
    "inspect_xml",
    "loaded_xml",
    "xml_dependencies",
]

_CHUNK = 1 << 20
_SOURCE_PREFIX = re.compile(r"\[[A-Za-z0-9_./-]+\.(?:cpp|h):\d+\]\s*")
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


@contextlib.contextmanager
def _parsed(path, defines: Mapping[str, str], variant: str | None) -> Iterator[tuple]:
    """Parse ``path`` (or a scene dict, `DICT_SOURCE`, with ``mitsuba.parser.parse_dict``) under a file
    resolver of its own (a copy of the caller's, so that plugins are still found, with the scene's folder
    first); yields ``(mi, parser, config, state, unread)`` and puts the caller's
    resolver back afterwards. Mitsuba's refusal becomes one `XMLSceneError` line. ``unread``: each node's
    properties nobody had read when the file was parsed, for `_instantiate` (rtfit's own reading of the
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
                raise XMLSceneError(f"{_label(path)}: {_one_line(str(e))}{hint}") from None
            except UnicodeDecodeError:  # Mitsuba's message quoted bytes of a file that is not text
                raise XMLSceneError(
                    f"{path}: Mitsuba could not parse it (a file it reads is not text)"
                ) from None
            yield mi, parser, config, state, [tuple(n.props.unqueried()) for n in state.nodes]
        finally:
            mi.set_file_resolver(previous)


def _collect(mi, path, defines: Mapping[str, str], state) -> XmlDependencies:
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
            what = (str(node.type), node.props.plugin_name(), node.props.id(), _props(node), _spectra(node))
            h.update(f"\0node\0{what!r}".encode())
    for f in xml_files + data_files:
        _file_digest(h, f, root)
    return XmlDependencies(_label(path), xml_files, data_files, h.hexdigest())


DICT_SOURCE = "scene dict"
"""What stands for the file name of a scene given as a dict (``mitsuba.load_dict`` style): in
`XmlScene.path`, `XmlDependencies.path` and the first words of every error line."""


def _label(path) -> str:
    return DICT_SOURCE if isinstance(path, Mapping) else str(path)


def _normalise(path, defines) -> tuple[str | Mapping, dict[str, str]]:
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
    path, defines = _normalise(path, defines)
    with _parsed(path, defines, variant) as (mi, _parser, _config, state, _unread):
        return _collect(mi, path, defines, state)


# ------------------------------------------------------------------------------------------ inspection
Vec3 = tuple[float, float, float]

UP_AXES: dict[str, Vec3] = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}
_ENVIRONMENT_PLUGINS = {
    "envmap": "envmap",
    "constant": "constant",
    "sunsky": "sunsky",
    "timed_sunsky": "sunsky",
}
_FREE_EMITTERS = {"point": "point", "spot": "spot", "directional": "directional", "projector": "projector"}
# An area emitter takes its kind from the shape it sits on; every other shape (meshes, cubes, …) is "area".
_AREA_ON = {"sphere": "sphere", "disk": "disk", "rectangle": "rectangle"}
_SCALE_NAMES = ("radiance", "irradiance", "intensity", "scale")
_MESH_PLUGINS = ("ply", "obj", "serialized")
# Mitsuba 3.9's PLY loader reads triangle faces only; these are its messages for other faces.
_PLY_FACE_ERRORS = ("trailing tokens", "non-triangular faces", "is this a triangle mesh")
_PLY_HINT = "Mitsuba's PLY loader reads triangle faces only: triangulate the mesh, or save it as OBJ"
_SUN_APERTURE_DEG = 0.5358  # Mitsuba's sunsky default `sun_aperture` (degrees, full angle)


@dataclass(frozen=True)
class XmlSensor:
    """One ``<sensor>``: ``index`` in document order, plugin ``type``, ``id``, ``location`` (file and line);
    the camera frame from ``to_world`` (``origin``, ``target`` = origin + viewing direction, ``up`` = the
    frame's up column: the lookat ``up`` orthogonalised against the viewing direction), ``fov_deg`` along
    ``fov_axis`` as written (or Mitsuba's derived horizontal field of view, axis ``x``, when the XML gives
    ``focal_length`` or nothing), ``x_fov_deg`` (Mitsuba's horizontal field of view) and the film size."""

    index: int
    type: str
    id: str
    location: str
    origin: Vec3
    target: Vec3
    up: Vec3
    fov_deg: float | None
    fov_axis: str
    x_fov_deg: float | None
    width: int
    height: int


@dataclass(frozen=True)
class XmlEmitter:
    """One emitter. ``kind``: ``point spot directional projector`` (free emitters), ``sphere disk rectangle``
    (an area emitter on that shape), ``area`` (an area emitter on any other shape: a mesh, a cube, …),
    ``envmap constant sunsky`` (environments), else the plugin name. ``shape``: the plugin of the shape it
    sits on (``""`` for a free emitter). ``direction``: world unit vector **towards** the light (rtfit's
    convention; Mitsuba's ``directional`` ``direction`` is the way the light travels, negated here), for
    directional, spot (from the light to its axis: the negated axis) and sunsky (the sun). ``position``
    and ``radius``: point/spot position; a sphere's centre and radius (from the instantiated shape's
    bounding box), a disk's centre and radius. ``angular_radius_deg``: the sun's (sunsky, half its
    ``sun_aperture``), 0 for a directional light. ``scale``/``scale_name``: the emitted quantity as
    written (``radiance``, ``irradiance``, ``intensity`` or an envmap's ``scale``; a texture is
    ``None``). ``spherical``: the light is a sphere (or a cap of directions), so the exact sphere-light
    form applies. ``medium``: for a point or spot light, the index in `XmlScene.media` of the medium it sits
    in (`point_medium`), else None."""

    type: str
    kind: str
    id: str
    location: str
    shape: str = ""
    position: Vec3 | None = None
    direction: Vec3 | None = None
    radius: float | None = None
    angular_radius_deg: float | None = None
    scale: tuple[float, ...] | None = None
    scale_name: str = ""
    spherical: bool = False
    environment: bool = False
    file: str = ""
    medium: int | None = None
    patterned: bool = False
    """A spot light that projects a ``texture`` (its intensity varies across the cone, not only with the
    angle from its axis): no cone profile models it."""
    elliptical: bool = False
    """A ``disk`` whose to_world scales its x and y axes differently (or shears them): an ellipse, which
    the disc light model (a circle) does not describe."""


@dataclass(frozen=True)
class XmlShape:
    """One shape: plugin ``type``, ``id``, ``location``, ``file`` (a mesh's data file, resolved), ``faces``
    (triangles, where Mitsuba loads the shape as a mesh: meshes, ``cube``, ``rectangle``; ``None`` for
    analytic shapes such as ``sphere`` and, in the JIT variants, ``disk``), ``emitter`` (carries an area
    emitter), ``bsdf`` (the BSDF plugin, ``""`` for Mitsuba's default diffuse), ``interior``/``exterior``
    (medium plugins; a shape with either is a medium boundary)."""

    type: str
    id: str
    location: str
    file: str = ""
    faces: int | None = None
    emitter: bool = False
    bsdf: str = ""
    interior: str = ""
    exterior: str = ""
    bump: str = ""
    """``bumpmap`` or ``normalmap`` where the shape's BSDF is one (or a ``twosided`` wraps one), else ""."""
    bump_texture: str = ""
    """The texture plugin of that ``bump`` (``bitmap``, ``checkerboard``, …; ``""`` without one)."""
    convex: bool | None = None
    """For a mesh that bounds a medium (``interior``): whether it is convex (`particle_media.convex_mesh`);
    None otherwise."""


@dataclass(frozen=True)
class XmlMedium:
    """One medium: plugin ``type`` (``homogeneous``, ``heterogeneous``, …), ``id``, ``location``, and
    whether a shape bounds it (``boundary``) or the sensor sits in it (``on_sensor``). ``sigma_t``: the
    plugin of a nested extinction object (``gridvolume``, ``constvolume``, ``rgb``, …; ``""`` for a value
    written inline)."""

    type: str
    id: str
    location: str
    boundary: bool
    on_sensor: bool
    sigma_t: str = ""


@dataclass(frozen=True)
class XmlScene:
    """What a Mitsuba XML scene contains, read by Mitsuba's parser (`inspect_xml`).

    ``camera``: the chosen sensor (``--camera N``) with ``width``/``height`` overrides applied (``None`` when
    the scene has no sensor); ``sensors``: all of them as written. ``up``: the world up axis (a key of
    `UP_AXES`) and ``up_reason``: where it came from. ``bbox``: (min, max) of all shapes as Mitsuba loads
    them (``None`` without shapes). ``bsdfs``: the BSDF plugins declared, in document order, once each."""

    path: str
    dependencies: XmlDependencies
    integrator: str
    sensors: tuple[XmlSensor, ...]
    camera: XmlSensor | None
    up: str
    up_reason: str
    emitters: tuple[XmlEmitter, ...]
    shapes: tuple[XmlShape, ...]
    bsdfs: tuple[str, ...]
    media: tuple[XmlMedium, ...]
    bbox: tuple[Vec3, Vec3] | None
    scene_dict: Mapping | None = field(default=None, compare=False, repr=False)
    """The scene dict it was read from (``path`` is then `DICT_SOURCE`); `loaded_xml` takes either."""

    @property
    def source(self):
        """What `loaded_xml` instantiates: the scene dict, else the file's path."""
        return self.scene_dict if self.scene_dict is not None else self.path


def _convex(shape) -> bool | None:
    """Whether a loaded mesh shape is convex (None: not a mesh)."""
    if shape is None or not shape.is_mesh():
        return None
    v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
    return convex_mesh(v, np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3))


def _unit(v) -> Vec3 | None:
    n = math.sqrt(sum(float(x) ** 2 for x in v))
    return None if not n > 0.0 else (float(v[0]) / n + 0.0, float(v[1]) / n + 0.0, float(v[2]) / n + 0.0)


def _plain(value):
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


def _floats(value) -> tuple[float, ...]:
    """A Mitsuba/Dr.Jit number or vector (scalar, or a JIT array of width 1) as plain floats."""
    return tuple(float(x) for x in np.asarray(value, dtype=float).ravel())


def _instantiate(parser, config, state, unread: list[tuple[str, ...]]):
    """``parser.instantiate`` after marking unread again each property that was unread when the file was
    parsed (`_parsed`): rtfit read every value to check it (`_props`), and Mitsuba refuses a property that
    no plugin reads only if it is still unread ("Found 1 unreferenced property …"; issue 32: a misspelt
    ``<float name="radus">`` was silently ignored)."""
    for node, names in zip(state.nodes, unread, strict=False):
        for name in names:
            node.props.mark_queried(name, False)
    return parser.instantiate(config, state)


def _props(node) -> dict:
    return {k: _plain(node.props[k]) for k in node.props.keys()}


def _column(matrix, j: int) -> Vec3:
    return (matrix[0][j], matrix[1][j], matrix[2][j])


def _bbox(box) -> tuple[Vec3, Vec3]:
    lo, hi = box.min, box.max
    return (float(lo[0]), float(lo[1]), float(lo[2])), (float(hi[0]), float(hi[1]), float(hi[2]))


def up_from_vector(up: Vec3, right: Vec3 | None = None) -> tuple[str, float]:
    """The signed world axis nearest to ``up`` (among those perpendicular to the camera's ``right`` vector
    when given: a world up axis lies in the plane of the camera's up and viewing direction unless the
    camera is rolled) and the angle in degrees between them."""
    best, best_dot = "+z", -2.0
    for name, axis in UP_AXES.items():
        if right is not None and abs(sum(a * r for a, r in zip(axis, right, strict=True))) > 0.5:
            continue
        dot = sum(a * u for a, u in zip(axis, up, strict=True))
        if dot > best_dot:
            best, best_dot = name, dot
    return best, math.degrees(math.acos(max(-1.0, min(1.0, best_dot))))


def _sensor(mi, index: int, node, props: dict, obj, location: str) -> XmlSensor:
    params = mi.traverse(obj)
    m = props.get("to_world") or tuple(tuple(float(i == j) for j in range(4)) for i in range(4))
    origin = _column(m, 3)
    forward = _unit(_column(m, 2)) or (0.0, 0.0, 1.0)
    up = _unit(_column(m, 1)) or (0.0, 1.0, 0.0)
    x_fov = _floats(params["x_fov"])[0] if "x_fov" in params else None
    size = obj.film().size()
    fov = props.get("fov")
    return XmlSensor(
        index=index,
        type=node.props.plugin_name(),
        id=node.props.id(),
        location=location,
        origin=origin,
        target=tuple(o + f for o, f in zip(origin, forward, strict=True)),
        up=up,
        fov_deg=float(fov) if isinstance(fov, float | int) else x_fov,
        fov_axis=str(props.get("fov_axis", "x")) if isinstance(fov, float | int) else "x",
        x_fov_deg=x_fov,
        width=int(size[0]),
        height=int(size[1]),
    )


def _scale(props: dict) -> tuple[tuple[float, ...] | None, str]:
    for name in _SCALE_NAMES:
        if name in props:
            v = props[name]
            if isinstance(v, float | int) and not isinstance(v, bool):
                return (float(v),), name
            if isinstance(v, tuple) and v and v[0] != "ref":
                return tuple(float(x) for x in v), name
            return None, name  # a texture or spectrum node
    return None, ""


def _resolved(mi, name) -> str:
    return str(mi.file_resolver().resolve(name)) if isinstance(name, str) and name else ""


def _emitter(mi, node, props: dict, location: str, obj, shape=None) -> XmlEmitter:
    plugin = node.props.plugin_name()
    scale, scale_name = _scale(props)
    base = dict(type=plugin, id=node.props.id(), location=location, scale=scale, scale_name=scale_name)
    m = props.get("to_world")
    if shape is not None:  # an area emitter: its kind and size from the shape it sits on
        s_node, s_props, s_obj = shape
        s_plugin = s_node.props.plugin_name()
        kind = _AREA_ON.get(s_plugin, "area")
        extra: dict = {"shape": s_plugin, "file": _resolved(mi, s_props.get("filename"))}
        if s_obj is not None and kind == "sphere":
            lo, hi = _bbox(s_obj.bbox())
            extra["position"] = tuple((a + b) / 2 for a, b in zip(lo, hi, strict=True))
            extra["radius"] = (hi[0] - lo[0]) / 2
            extra["spherical"] = True
        elif s_plugin == "cylinder" and (sm := s_props.get("to_world")) is not None:  # a tube's circle
            u, v, w = _column(sm, 0), _column(sm, 1), _column(sm, 2)
            uu, vv, uv, uw, vw = (
                sum(a * b for a, b in zip(x, y, strict=True))
                for x, y in ((u, u), (v, v), (u, v), (u, w), (v, w))
            )
            tol = 1e-4 * (uu + vv)
            extra["elliptical"] = abs(uu - vv) > tol or max(abs(uv), abs(uw), abs(vw)) > tol
        elif kind == "disk":
            sm = s_props.get("to_world")
            if sm is not None:
                extra["position"] = _column(sm, 3)
                extra["radius"] = math.sqrt(sum(x * x for x in _column(sm, 0)))
                extra["direction"] = _unit(_column(sm, 2))
                u, v = _column(sm, 0), _column(sm, 1)
                uu, vv, uv = (
                    sum(a * b for a, b in zip(x, y, strict=True)) for x, y in ((u, u), (v, v), (u, v))
                )
                extra["elliptical"] = abs(uu - vv) > 1e-4 * (uu + vv) or abs(uv) > 1e-4 * (uu + vv)
            else:
                extra["position"], extra["radius"], extra["direction"] = (0.0, 0.0, 0.0), 1.0, (0.0, 0.0, 1.0)
        return XmlEmitter(kind=kind, **base, **extra)
    if plugin in _ENVIRONMENT_PLUGINS:
        kind = _ENVIRONMENT_PLUGINS[plugin]
        extra = {"environment": True, "file": _resolved(mi, props.get("filename"))}
        if kind == "sunsky":
            params = mi.traverse(obj) if obj is not None else {}
            if "sun_direction" in params:
                extra["direction"] = _unit(_floats(params["sun_direction"]))
            aperture = props.get("sun_aperture", _SUN_APERTURE_DEG)
            extra["angular_radius_deg"] = float(aperture) / 2
            extra["spherical"] = float(aperture) > 0.0
        return XmlEmitter(kind=kind, **base, **extra)
    kind = _FREE_EMITTERS.get(plugin, plugin)
    extra = {}
    if kind == "directional":
        d = props.get("direction")
        travel = d if isinstance(d, tuple) and len(d) == 3 else (_column(m, 2) if m else (0.0, 0.0, 1.0))
        extra["direction"] = _unit(tuple(-x for x in travel))
        extra["angular_radius_deg"] = 0.0
    elif kind in ("point", "spot"):
        p = props.get("position")
        extra["position"] = (
            p if isinstance(p, tuple) and len(p) == 3 else (_column(m, 3) if m else (0.0,) * 3)
        )
        if kind == "spot" and m:
            extra["direction"] = _unit(tuple(-x for x in _column(m, 2)))
        if kind == "spot":
            extra["patterned"] = "texture" in props
    return XmlEmitter(kind=kind, **base, **extra)


def _with_overrides(sensor: XmlSensor | None, width, height) -> XmlSensor | None:
    if sensor is None:
        return None
    for name, v in (("--width", width), ("--height", height)):
        if v is not None and (not isinstance(v, int) or v < 1):
            raise XMLSceneError(f"{name} {v!r}: must be a positive integer")
    return replace(sensor, width=width or sensor.width, height=height or sensor.height)


def _up(camera: XmlSensor | None, up: str | None) -> tuple[str, str]:
    if up is not None:
        if up not in UP_AXES:
            raise XMLSceneError(f"--up {up!r}: expected one of {', '.join(UP_AXES)}")
        return up, f"{up} as given (--up)"
    if camera is None:
        return "+z", "+z: rtfit's default (the scene has no sensor to take an up vector from)"
    forward = _unit(tuple(t - o for t, o in zip(camera.target, camera.origin, strict=True)))
    right = None
    if forward is not None:
        c = camera.up
        right = _unit(
            (
                c[1] * forward[2] - c[2] * forward[1],
                c[2] * forward[0] - c[0] * forward[2],
                c[0] * forward[1] - c[1] * forward[0],
            )
        )
    axis, angle = up_from_vector(camera.up, right)
    vec = ", ".join(f"{x:.3g}" for x in camera.up)
    reason = f"{axis} from sensor {camera.index}'s up vector ({vec})"
    if angle > 1e-3:
        reason += f", the nearest axis ({angle:.1f}° off: the camera is tilted; pass --up if that is wrong)"
    return axis, reason


def inspect_xml(
    path: str | os.PathLike | Mapping,
    defines: Mapping[str, str] | None = None,
    variant: str | None = None,
    *,
    camera: int = 0,
    width: int | None = None,
    height: int | None = None,
    up: str | None = None,
) -> XmlScene:
    """What the Mitsuba XML scene ``path`` (or a scene dict, ``mitsuba.load_dict`` style, read by
    ``mitsuba.parser.parse_dict``) contains (`XmlScene`), read by Mitsuba's parser with the
    ``-D`` ``defines`` and instantiated under the same scoped file resolver. ``camera`` picks the sensor
    (document order), ``width``/``height`` override its film size, ``up`` (a key of `UP_AXES`) overrides
    the up axis otherwise taken from the chosen sensor's up vector. Raises `XMLSceneError` (one line)
    for anything Mitsuba refuses or an option the scene cannot satisfy."""
    path, defines = _normalise(path, defines)
    label = _label(path)
    if up is not None and up not in UP_AXES:
        raise XMLSceneError(f"--up {up!r}: expected one of {', '.join(UP_AXES)}")
    with _parsed(path, defines, variant) as (mi, parser, config, state, unread):
        deps = _collect(mi, path, defines, state)
        config.merge_meshes = False  # keep the user's shapes one by one (counts, ids, emitters)
        config.merge_equivalent = False
        try:
            parser.transform_all(config, state)
            # (read before instantiating: instantiation consumes the nodes' references)
            nodes = list(state.nodes)
            props = [_props(n) for n in nodes]
            where = [parser.file_location(state, n) for n in nodes]
            kind = {i: str(n.type).rsplit(".", 1)[-1] for i, n in enumerate(nodes)}
            _check(mi, nodes, [kind[i] for i in range(len(nodes))], props, where, camera)
            scene = _instantiate(parser, config, state, unread)
        except RuntimeError as e:
            raise XMLSceneError(f"{label}: {_mitsuba_text(e)}") from None
        except UnicodeDecodeError:  # Mitsuba's message quoted bytes of a data file that is not text
            raise XMLSceneError(f"{label}: {_NOT_TEXT}") from None
        if isinstance(scene, list | tuple) or not hasattr(scene, "shapes"):
            raise XMLSceneError(f"{label}: the file's root is not a <scene>")

        def refs(i: int) -> list[tuple[str, int]]:
            return [(k, v[1]) for k, v in props[i].items() if isinstance(v, tuple) and v[:1] == ("ref",)]

        def of_type(t: str) -> list[int]:
            return [i for i in kind if kind[i] == t]

        shape_objs = list(scene.shapes())
        shape_nodes = [i for i in of_type("Shape") if nodes[i].props.plugin_name() not in ("shapegroup",)]
        by_id = {s.id(): s for s in shape_objs}
        shape_obj = {}
        for k, i in enumerate(shape_nodes):
            sid = nodes[i].props.id()
            shape_obj[i] = (
                by_id.get(sid) if sid else (shape_objs[k] if len(shape_objs) == len(shape_nodes) else None)
            )
        sensor_objs = list(scene.sensors())
        sensors = tuple(
            _sensor(mi, k, nodes[i], props[i], sensor_objs[k], where[i])
            for k, i in enumerate(of_type("Sensor"))
            if k < len(sensor_objs)
        )
        surface = mi.EmitterFlags.Surface
        frees = [e for e in scene.emitters() if not mi.has_flag(e.flags(), surface)]
        by_eid = {e.id(): e for e in frees}
        owner = {j: i for i in shape_nodes for _, j in refs(i) if kind[j] == "Emitter"}
        emitters = []
        free = 0
        for i in of_type("Emitter"):
            if i in owner:
                s = owner[i]
                emitters.append(
                    _emitter(mi, nodes[i], props[i], where[i], None, (nodes[s], props[s], shape_obj.get(s)))
                )
                continue
            eid = nodes[i].props.id()
            obj = by_eid.get(eid) if eid else (frees[free] if free < len(frees) else None)
            emitters.append(_emitter(mi, nodes[i], props[i], where[i], obj))
            free += 1

        def bump(j: int, depth: int = 0) -> tuple[str, str]:
            """(bump BSDF plugin, its texture plugin) of BSDF node ``j``, through ``twosided`` wrappers."""
            plugin = nodes[j].props.plugin_name()
            if plugin in ("bumpmap", "normalmap"):
                tex = next((nodes[k].props.plugin_name() for _, k in refs(j) if kind[k] == "Texture"), "")
                return plugin, tex
            inner = [k for _, k in refs(j) if kind[k] == "BSDF"]
            return bump(inner[0], depth + 1) if plugin == "twosided" and inner and depth < 4 else ("", "")

        shapes = []
        boundaries: set[int] = set()
        for i in shape_nodes:
            named = dict(refs(i))
            bsdf_node = next((j for _, j in refs(i) if kind[j] == "BSDF"), None)
            bsdf = nodes[bsdf_node].props.plugin_name() if bsdf_node is not None else ""
            bump_plugin, bump_texture = bump(bsdf_node) if bsdf_node is not None else ("", "")
            media = {
                k: nodes[j].props.plugin_name() for k, j in named.items() if k in ("interior", "exterior")
            }
            boundaries.update(j for k, j in named.items() if k in ("interior", "exterior"))
            obj = shape_obj.get(i)
            plugin = nodes[i].props.plugin_name()
            filename = props[i].get("filename") if plugin in _MESH_PLUGINS else None  # (a mesh's data file)
            shapes.append(
                XmlShape(
                    type=plugin,
                    id=nodes[i].props.id(),
                    location=where[i],
                    file=_resolved(mi, filename),
                    faces=int(obj.face_count()) if obj is not None and obj.is_mesh() else None,
                    emitter=any(kind[j] == "Emitter" for _, j in refs(i)),
                    bsdf=bsdf,
                    bump=bump_plugin,
                    bump_texture=bump_texture,
                    interior=media.get("interior", ""),
                    exterior=media.get("exterior", ""),
                    convex=_convex(obj) if media.get("interior") else None,
                )
            )
        on_sensor = {j for i in of_type("Sensor") for _, j in refs(i) if kind[j] == "Medium"}
        media_out = tuple(
            XmlMedium(
                nodes[i].props.plugin_name(),
                nodes[i].props.id(),
                where[i],
                i in boundaries,
                i in on_sensor,
                next((nodes[j].props.plugin_name() for k, j in refs(i) if k == "sigma_t"), ""),
            )
            for i in of_type("Medium")
        )
        media_objs = _medium_objects(
            of_type("Medium"), shape_nodes, shape_obj, of_type("Sensor"), sensor_objs, refs
        )
        cam_obj = sensor_objs[camera] if 0 <= camera < len(sensor_objs) else None
        emitters = [_with_medium(mi, scene, cam_obj, e, media_objs) for e in emitters]
        bsdfs = tuple(dict.fromkeys(nodes[i].props.plugin_name() for i in of_type("BSDF")))
        integrators = of_type("Integrator")
        integrator = nodes[integrators[0]].props.plugin_name() if integrators else ""
        bbox = _bbox(scene.bbox()) if shape_objs else None
    if sensors and not 0 <= camera < len(sensors):
        raise XMLSceneError(
            f"{label}: --camera {camera}: the scene has {len(sensors)} sensor(s), 0..{len(sensors) - 1}"
        )
    if not sensors and camera != 0:
        raise XMLSceneError(f"{label}: --camera {camera}: the scene has no sensor")
    chosen = _with_overrides(sensors[camera] if sensors else None, width, height)
    axis, reason = _up(chosen, up)
    return XmlScene(
        path=label,
        dependencies=deps,
        integrator=integrator,
        sensors=sensors,
        camera=chosen,
        up=axis,
        up_reason=reason,
        emitters=tuple(emitters),
        shapes=tuple(shapes),
        bsdfs=bsdfs,
        media=media_out,
        bbox=bbox,
        scene_dict=path if isinstance(path, Mapping) else None,
    )


# --------------------------------------------------------------------------------- lights inside media
MAX_CROSSINGS = 16
"""Surfaces a probe ray is followed through before it is given up (`first_transition`)."""
OUTER = "outer"
"""`first_transition`'s answer for a point outside every bounded medium."""
_PROBE = (0.2672612419124244, 0.5345224838248488, 0.8017837257372732)  # (1, 2, 3)/√14: off every axis


def first_transition(mi, scene, point):
    """The medium on the incoming side of the first medium transition (a shape with an interior or exterior
    medium) along a fixed probe ray from ``point`` (a Mitsuba Medium, or None for vacuum), surfaces that
    are not transitions passed through; `OUTER` where the ray leaves the scene first; None after
    `MAX_CROSSINGS` surfaces."""
    ray = mi.Ray3f(mi.Point3f(*(float(x) for x in point)), mi.Vector3f(*_PROBE))
    for _ in range(MAX_CROSSINGS):
        si = scene.ray_intersect(ray)
        if not bool(np.asarray(si.is_valid()).ravel()[0]):
            return OUTER
        if bool(np.asarray(si.is_medium_transition()).ravel()[0]):
            medium = si.target_medium(-ray.d)  # a MediumPtr array in JIT variants, a Medium in scalar ones
            return medium[0] if type(medium).__name__ == "MediumPtr" else medium
        ray = si.spawn_ray(ray.d)
    return None


def camera_origin(mi, sensor) -> tuple[float, float, float]:
    """The sensor's position: the translation of its ``to_world`` (a perspective camera's rays start there;
    Mitsuba's own rays start at the near clip plane, a few mm along them)."""
    m = np.asarray(sensor.world_transform().matrix, np.float64).reshape(4, 4, -1)[..., 0]
    return float(m[0, 3]), float(m[1, 3]), float(m[2, 3])


def point_medium(mi, scene, sensor, point):
    """The Mitsuba medium ``point`` sits in, or None: the incoming side of the first transition along the
    probe (`first_transition`); outside every bounded medium, the scene's unbounded medium — the
    ``sensor``'s own medium when the sensor is outside every boundary too, else none."""
    found = first_transition(mi, scene, point)
    if found is not OUTER:
        return found
    if sensor is None:
        return None
    return sensor.get_medium() if first_transition(mi, scene, camera_origin(mi, sensor)) is OUTER else None


def _medium_objects(medium_nodes, shape_nodes, shape_obj, sensor_nodes, sensor_objs, refs) -> list:
    """(Mitsuba medium object, index in `XmlScene.media`) of every medium a shape or sensor refers to."""
    out = []
    for i in shape_nodes:
        for name, j in refs(i):
            if name in ("interior", "exterior") and shape_obj.get(i) is not None and j in medium_nodes:
                out.append((getattr(shape_obj[i], f"{name}_medium")(), medium_nodes.index(j)))
    for k, i in enumerate(sensor_nodes):
        for _, j in refs(i):
            if j in medium_nodes and k < len(sensor_objs):
                out.append((sensor_objs[k].get_medium(), medium_nodes.index(j)))
    return out


def _with_medium(mi, scene, sensor, emitter: XmlEmitter, media_objs) -> XmlEmitter:
    """``emitter`` with its `XmlEmitter.medium` (point and spot lights)."""
    if emitter.kind not in ("point", "spot") or emitter.position is None:
        return emitter
    medium = point_medium(mi, scene, sensor, emitter.position)
    index = next((k for obj, k in media_objs if medium is not None and obj is medium), None)
    return replace(emitter, medium=index)


# -------------------------------------------------------------------------------------------- loading
@dataclass(frozen=True)
class LoadedXml:
    """A Mitsuba XML scene instantiated for rendering (`loaded_xml`): ``mi`` (the module, in the scoped
    variant), ``scene``, the chosen ``sensor`` (its film resized by ``--width``/``--height``) and
    ``emitters``: the Mitsuba emitter objects in the document order of `XmlScene.emitters`."""

    mi: object
    scene: object
    sensor: object
    emitters: tuple


@contextlib.contextmanager
def loaded_xml(
    path: str | os.PathLike | Mapping,
    defines: Mapping[str, str] | None = None,
    variant: str = "llvm_ad_rgb",
    *,
    camera: int = 0,
    width: int | None = None,
    height: int | None = None,
) -> Iterator[LoadedXml]:
    """Instantiate the XML scene ``path`` (or a scene dict, `XmlScene.source`) in ``variant`` (scoped: the
    caller's variant and file resolver are put back on exit) with only what the file declares: Mitsuba's
    parser, then the chosen sensor's film resized (``width``/``height``; the field of view along
    ``fov_axis`` is kept), each emitter tagged so
    that the rendered objects are matched to the document's emitters one to one. Raises `XMLSceneError`
    (one line) for anything Mitsuba refuses."""
    path, defines = _normalise(path, defines)
    label = _label(path)
    with _parsed(path, defines, variant) as (mi, parser, config, state, unread):
        config.merge_meshes = False
        config.merge_equivalent = False
        try:
            parser.transform_all(config, state)
            nodes = list(state.nodes)
            kinds = [str(n.type).rsplit(".", 1)[-1] for n in nodes]
            emitter_nodes = [i for i, k in enumerate(kinds) if k == "Emitter"]
            for k, i in enumerate(emitter_nodes):  # references are resolved already: ids are free now
                nodes[i].props.set_id(f"rtfit-emitter-{k}")
            sensors = [i for i, k in enumerate(kinds) if k == "Sensor"]
            if sensors and not 0 <= camera < len(sensors):
                last = len(sensors) - 1
                raise XMLSceneError(
                    f"{label}: --camera {camera}: the scene has {len(sensors)} sensor(s), 0..{last}"
                )
            if not sensors:
                raise XMLSceneError(
                    f"{label}: the scene has no <sensor> (the audit renders the scene's own view)"
                )
            _check(
                mi,
                nodes,
                kinds,
                [_props(n) for n in nodes],
                [parser.file_location(state, n) for n in nodes],
                camera,
            )
            films = _films_of(state, nodes, kinds, sensors[camera])
            for film in films:
                if width is not None:
                    film.props["width"] = int(width)
                if height is not None:
                    film.props["height"] = int(height)
            scene = _instantiate(parser, config, state, unread)
        except RuntimeError as e:
            raise XMLSceneError(f"{label}: {_mitsuba_text(e)}") from None
        except UnicodeDecodeError:
            raise XMLSceneError(f"{label}: {_NOT_TEXT}") from None
        if isinstance(scene, list | tuple) or not hasattr(scene, "sensors"):
            raise XMLSceneError(f"{label}: the file's root is not a <scene>")
        by_id = {e.id(): e for e in scene.emitters()}
        emitters = tuple(by_id.get(f"rtfit-emitter-{k}") for k in range(len(emitter_nodes)))
        yield LoadedXml(mi, scene, scene.sensors()[camera], emitters)


_NOT_TEXT = "Mitsuba could not load it, and its message is not text (a mesh or image file that is corrupt?)"


def _mitsuba_text(e: RuntimeError) -> str:
    text = _one_line(str(e))
    if "PLYMesh" in text and any(m in text for m in _PLY_FACE_ERRORS):
        text += f" ({_PLY_HINT})"
    return text


def _spectra(node) -> dict:
    """A node's spectrum properties (``<spectrum value="5"/>``, wavelength:value lists) as their values."""
    out = {}
    for k in node.props.keys():
        v = node.props[k]
        if type(v).__name__ == "Spectrum":
            out[k] = tuple(float(x) for x in np.asarray(v.values, dtype=float).ravel())
    return out


def _check(mi, nodes, kinds, props, where, camera: int) -> None:
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
        if r.kind == "Shape" and r.plugin in _MESH_PLUGINS and isinstance(r.props.get("filename"), str):
            file = _resolved(mi, r.props["filename"])
            problem = mesh_problem(file)
            if problem is not None:
                raise XMLSceneError(f'{r.location}: <shape type="{r.plugin}"> filename {file}: {problem}')


def _films_of(state, nodes, kinds, sensor_index: int) -> list:
    """The film node(s) a sensor node refers to (its ``_arg_*``/named references)."""
    out = []
    for key in nodes[sensor_index].props.keys():
        value = _plain(nodes[sensor_index].props[key])
        if isinstance(value, tuple) and value[:1] == ("ref",) and kinds[value[1]] == "Film":
            out.append(nodes[value[1]])
    return out
