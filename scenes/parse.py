"""Scene files (TOML) → validated :class:`~rtfit.scenes.model.Scene`.

The file format is documented for users in ``scenes/README.md``. In short: keys are the dataclass
field names of :mod:`rtfit.scenes.model`, plus ``type`` naming the kind of a shape, light, medium,
medium boundary, material (optional, ``"diffuse"``) or camera (optional, ``"perspective"``).

Conventions applied while parsing (the model's units: scene units, degrees, linear-sRGB radiance):

* numbers: TOML integers or floats (booleans are *not* numbers), always finite; stored as ``float``.
  Integer fields need a TOML integer (``128``, not ``128.0``).
* vectors are 3-arrays (``size`` of rectangles and rect lights: 2-arrays); RGB values are a number
  (grey) or a 3-array; both are stored as tuples of floats.
* normals, directions, rotation axes and the camera's ``up`` are stored normalised (a vector whose
  length is already within 1e-12 of 1 is kept as written, so parsing is idempotent).
* file paths are resolved against the scene file's folder (``base_dir`` for text) and stored absolute.
* a sphere light may be placed by ``direction``/``distance``/``angular_radius_deg`` (and optional
  ``target``) instead of ``center``/``radius``; it is converted to ``center``/``radius``.

Every problem raises :class:`SceneError` with a one-line ``"<file>: <key path>: <reason>"`` message.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any
from xml.parsers import expat

from .mesh_files import mesh_problem
from .model import (
    ENVIRONMENT_KINDS,
    TRANSPORTS,
    Camera,
    ConstantEnv,
    Cube,
    Cylinder,
    Diffuse,
    Disk,
    EnvMap,
    ExponentialFog,
    HomogeneousMedium,
    Mesh,
    MitsubaXML,
    PointLight,
    Rectangle,
    RectLight,
    ReferenceSettings,
    Scene,
    Sphere,
    SphereLight,
    SpotLight,
    Sun,
    SunSky,
)

LIBRARY_DIR = Path(__file__).resolve().parent / "library"
UNIT_TOLERANCE = 1e-12  # a vector this close to unit length is kept as written


# ---------------------------------------------------------------------------------------------- errors
class SceneError(ValueError):
    """A scene file is missing, unreadable, not TOML or not a valid scene.

    ``str(err)`` is always one line, ``"<file>: <key path>: <reason>"`` (the key path is left out
    where the problem is the whole file). ``source``, ``key`` and ``reason`` hold the parts.
    """

    def __init__(self, message: str, *, source: str = "", key: str = "", reason: str = ""):
        super().__init__(re.sub(r"[\r\n]+", " ", str(message)))
        self.source, self.key, self.reason = source, key, reason

    @classmethod
    def at(cls, source: str, key: str, reason: str) -> SceneError:
        return cls(": ".join(p for p in (source, key, reason) if p), source=source, key=key, reason=reason)

    def __reduce__(self):  # keep the parts across processes
        return (_rebuild_error, (str(self), self.source, self.key, self.reason))


def _rebuild_error(message, source, key, reason):
    return SceneError(message, source=source, key=key, reason=reason)


class _Invalid(Exception):
    """Internal: a problem at ``key``; turned into a :class:`SceneError` naming the file."""

    def __init__(self, key: str, reason: str):
        super().__init__(key, reason)
        self.key, self.reason = key, reason


def _show(v: Any, limit: int = 80) -> str:
    """A value as TOML-ish text for messages (booleans ``true``, strings double-quoted), truncated."""
    if isinstance(v, bool):
        s = "true" if v else "false"
    elif isinstance(v, str):
        s = json.dumps(v)
    elif isinstance(v, (list, tuple)):
        s = "[" + ", ".join(_show(x, limit) for x in v) + "]"
    elif isinstance(v, dict):
        s = "{ " + ", ".join(f"{k} = {_show(x, limit)}" for k, x in v.items()) + " }"
    else:
        s = repr(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _join(key: str, name: str) -> str:
    return f"{key}.{name}" if key else name


def xml_problem(path: str) -> str | None:
    """What makes ``path`` unusable as a Mitsuba XML scene before anything renders (None: nothing
    found): not well-formed XML (with its line), an entity declaration (refused: entity expansion is an
    XXE / billion-laughs vector, and Mitsuba scenes use ``$name`` parameters instead), or a root element
    other than ``<scene>``. Mitsuba's own loader still checks plugins and properties at render time."""
    parser = expat.ParserCreate()
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    root: list[str] = []

    def refuse_entity(name, *_):
        raise ValueError(f"entity declaration {name!r} (not allowed in a scene file)")

    def start(name, _attrs):
        if not root:
            root.append(name)

    parser.EntityDeclHandler = refuse_entity
    parser.StartElementHandler = start
    try:
        with open(path, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as e:
        return f"not well-formed XML (line {e.lineno}, column {e.offset}: {expat.ErrorString(e.code)})"
    except ValueError as e:
        return str(e)
    except OSError as e:
        return f"cannot read ({e.strerror or e})"
    if root and root[0] != "scene":
        return f"the root element is <{root[0]}>, not <scene>"
    return None


# ---------------------------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class Bounds:
    """A closed or open interval; ``None`` ends are unbounded. ``limit``: a sanity bound on the
    magnitude besides (``|x| ≤ limit``), so that no finite but huge value (1e308) reaches a render."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    limit: float | None = None

    def contains(self, x: float) -> bool:
        return self.within(x) and (self.limit is None or abs(x) <= self.limit)

    def within(self, x: float) -> bool:
        """In the interval (the limit aside)."""
        lo_ok = self.lo is None or (x > self.lo if self.lo_open else x >= self.lo)
        hi_ok = self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)
        return lo_ok and hi_ok

    def problem(self, x: float) -> str:
        """Why ``x`` is not contained, as ``must be …``."""
        if self.within(x):
            return f"must be within ±{self.limit:g} (rtfit's limit for this quantity)"
        return f"must be {self.text()}"

    def text(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {self.lo:g}"
        return f"{'<' if self.hi_open else '<='} {self.hi:g}"


@dataclass(frozen=True)
class Spec:
    """How one field is read from a file and written back.

    ``kind``: float | int | depth | bool | str | choice | vec3 | vec2 | unit | rgb | file | material |
    boundary. ``bounds`` applies to numbers and to each vector/RGB component. ``optional``: ``None``
    is a valid value (written by leaving the key out).
    """

    kind: str
    bounds: Bounds | None = None
    suffixes: tuple[str, ...] = ()
    choices: tuple[str, ...] = ()
    optional: bool = False


# Every number has finite bounds: a finite but huge value (1e308) would otherwise reach a render as an
# infinite radiance or optical depth, and its reference the cache. The bounds are far outside any
# physical scene in its units (metres: a planet is 6.4e6 m; radiance: the sun's is ~2e7 W·m⁻²·sr⁻¹).
MAX_LENGTH = 1e8  # positions, sizes, radii, clip distances (scene units)
MAX_RADIANCE = 1e12  # radiance, irradiance, emitter and map scales
MAX_COEFFICIENT = 1e6  # extinction σ_t, fog density b (per unit length)
MAX_FALLOFF = 1e3  # fog falloff c (per unit length)
POSITIVE = Bounds(0.0, lo_open=True, limit=MAX_LENGTH)
NON_NEGATIVE = Bounds(0.0, limit=MAX_RADIANCE)
ZERO_ONE = Bounds(0.0, 1.0)
OPEN_QUADRANT = Bounds(0.0, 90.0, lo_open=True, hi_open=True)  # angles strictly between 0° and 90°
COORDINATE = Bounds(limit=MAX_LENGTH)
ROTATION = Bounds(limit=3600.0)  # degrees (ten turns either way)

_VEC = Spec("vec3", COORDINATE)
_UNIT = Spec("unit")
_ANGLE = Spec("float", ROTATION)
_POS = Spec("float", POSITIVE)
_RADIANCE = Spec("rgb", NON_NEGATIVE)
_EXTINCTION = Spec("rgb", Bounds(0.0, limit=MAX_COEFFICIENT))
_MATERIAL = Spec("material")
_SIZE2 = Spec("vec2", POSITIVE)

#: Field specs of every model class, in the order they are written.
SCHEMA: dict[type, dict[str, Spec]] = {
    Camera: {
        "origin": _VEC,
        "target": _VEC,
        "up": _UNIT,
        "fov_deg": Spec("float", Bounds(0, 180, lo_open=True, hi_open=True)),
        "width": Spec("int", Bounds(1, 16384)),
        "height": Spec("int", Bounds(1, 16384)),
        "near_clip": _POS,
        "far_clip": _POS,
    },
    Diffuse: {"reflectance": Spec("rgb", ZERO_ONE)},
    Sphere: {"center": _VEC, "radius": _POS, "material": _MATERIAL},
    Rectangle: {
        "center": _VEC,
        "normal": _UNIT,
        "size": _SIZE2,
        "rotation_deg": _ANGLE,
        "material": _MATERIAL,
    },
    Disk: {"center": _VEC, "normal": _UNIT, "radius": _POS, "material": _MATERIAL},
    Cube: {
        "center": _VEC,
        "size": Spec("vec3", POSITIVE),
        "rotate_axis": _UNIT,
        "rotate_deg": _ANGLE,
        "material": _MATERIAL,
    },
    Cylinder: {"p0": _VEC, "p1": _VEC, "radius": _POS, "material": _MATERIAL},
    Mesh: {
        "file": Spec("file", suffixes=(".ply", ".obj")),
        "translate": _VEC,
        "rotate_axis": _UNIT,
        "rotate_deg": _ANGLE,
        "scale": Spec("vec3", POSITIVE),
        "face_normals": Spec("bool"),
        "material": _MATERIAL,
    },
    MitsubaXML: {
        "file": Spec("file", suffixes=(".xml",)),
        "keep_emitters": Spec("bool"),
        "override_material": Spec("material", optional=True),
    },
    Sun: {
        "direction": _UNIT,
        "irradiance": _RADIANCE,
        "angular_radius_deg": Spec("float", Bounds(0, 90, hi_open=True)),
    },
    SphereLight: {"center": _VEC, "radius": _POS, "radiance": _RADIANCE},
    RectLight: {
        "center": _VEC,
        "normal": _UNIT,
        "size": _SIZE2,
        "radiance": _RADIANCE,
        "rotation_deg": _ANGLE,
    },
    PointLight: {"position": _VEC, "intensity": _RADIANCE},
    SpotLight: {
        "position": _VEC,
        "axis": _UNIT,
        "intensity": _RADIANCE,
        "cutoff_angle_deg": Spec("float", OPEN_QUADRANT),
        "beam_width_deg": Spec("float", OPEN_QUADRANT),
    },
    ConstantEnv: {"radiance": _RADIANCE},
    EnvMap: {
        "file": Spec("file", suffixes=(".exr",)),
        "scale": Spec("float", NON_NEGATIVE),
        "rotate_deg": _ANGLE,
    },
    SunSky: {
        "sun_direction": _UNIT,
        "turbidity": Spec("float", Bounds(1, 10)),
        "albedo": Spec("float", ZERO_ONE),
        "sun_scale": Spec("float", NON_NEGATIVE),
        "sky_scale": Spec("float", NON_NEGATIVE),
        "sun_aperture_deg": Spec("float", OPEN_QUADRANT),
        "complex_sun": Spec("bool"),
    },
    HomogeneousMedium: {
        "boundary": Spec("boundary"),
        "sigma_t": _EXTINCTION,
        "albedo": Spec("rgb", ZERO_ONE),
        "g": Spec("float", Bounds(-1, 1, lo_open=True, hi_open=True)),
    },
    ExponentialFog: {
        "boundary": Spec("boundary"),
        "density": Spec("float", Bounds(0.0, limit=MAX_COEFFICIENT)),
        "falloff": Spec("float", Bounds(0.0, limit=MAX_FALLOFF)),
        "gradient": _UNIT,
        "gradient_origin": _VEC,
        "albedo": Spec("rgb", ZERO_ONE),
        "g": Spec("float", Bounds(-1, 1, lo_open=True, hi_open=True)),
        "ellipsoid": Spec("bool"),
    },
    ReferenceSettings: {
        "transport": Spec("choice", choices=TRANSPORTS),
        "max_depth": Spec("depth", optional=True),
    },
}

SHAPE_TYPES = {c.kind: c for c in (Sphere, Rectangle, Disk, Cube, Cylinder, Mesh, MitsubaXML)}
LIGHT_TYPES = {
    c.kind: c for c in (Sun, SphereLight, RectLight, PointLight, SpotLight, ConstantEnv, EnvMap, SunSky)
}
MEDIUM_TYPES = {c.kind: c for c in (HomogeneousMedium, ExponentialFog)}
BOUNDARY_TYPES = {c.kind: c for c in (Sphere, Cube)}
BOUNDARY_EXCLUDES = ("material",)  # a medium boundary is an interface (null BSDF), not a surface
SPHERE_LIGHT_PLACEMENT = ("target", "direction", "distance", "angular_radius_deg")
TOP_LEVEL_KEYS = ("name", "description", "camera", "reference", "shapes", "lights", "media")


# ------------------------------------------------------------------------------------- value readers
def _number(v: Any, key: str, bounds: Bounds | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _Invalid(key, f"must be a number (got {_show(v)})")
    try:
        x = float(v)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise _Invalid(key, f"must be finite (got {_show(v)})")
    if bounds is not None and not bounds.contains(x):
        raise _Invalid(key, f"{bounds.problem(x)} (got {_show(v)})")
    return x


def _integer(v: Any, key: str, bounds: Bounds | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise _Invalid(key, f"must be an integer (got {_show(v)})")
    if bounds is not None and not bounds.contains(v):
        raise _Invalid(key, f"{bounds.problem(v)} (got {_show(v)})")
    return v


def _vector(v: Any, key: str, n: int, bounds: Bounds | None = None) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) != n:
        raise _Invalid(key, f"must be an array of {n} numbers (got {_show(v)})")
    return tuple(_number(x, f"{key}[{i}]", bounds) for i, x in enumerate(v))


def normalised(v: tuple[float, ...]) -> tuple[float, ...] | None:
    """``v`` scaled to unit length (``v`` itself if already within ``UNIT_TOLERANCE``); None if zero."""
    m = max(abs(c) for c in v)
    if m == 0.0:
        return None
    if abs(math.sqrt(sum(c * c for c in v)) - 1.0) <= UNIT_TOLERANCE:
        return tuple(v)
    s = [c / m for c in v]  # pre-scaled so huge or tiny components neither overflow nor underflow
    n = math.sqrt(sum(c * c for c in s))
    return tuple(c / n for c in s)


def _unit(v: Any, key: str) -> tuple[float, ...]:
    u = normalised(_vector(v, key, 3, COORDINATE))
    if u is None:
        raise _Invalid(key, f"must be non-zero (got {_show(v)})")
    return u


def _rgb(v: Any, key: str, bounds: Bounds | None) -> tuple[float, float, float]:
    if isinstance(v, list) and len(v) == 3:
        r, g, b = _vector(v, key, 3, bounds)
        return (r, g, b)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        x = _number(v, key, bounds)
        return (x, x, x)
    raise _Invalid(key, f"must be a number or an array of 3 numbers (got {_show(v)})")


def _string(v: Any, key: str) -> str:
    if not isinstance(v, str):
        raise _Invalid(key, f"must be a string (got {_show(v)})")
    return v


def _table(v: Any, key: str) -> dict:
    if not isinstance(v, dict):
        raise _Invalid(key, f"must be a table (got {_show(v)})")
    return v


# -------------------------------------------------------------------------------------------- parser
class _Parser:
    """Reads one parsed TOML document; ``base_dir`` (absolute) resolves relative file paths."""

    def __init__(self, base_dir: str):
        self.base_dir = base_dir

    # values ------------------------------------------------------------------------------------
    def value(self, spec: Spec, v: Any, key: str) -> Any:
        kind = spec.kind
        if kind == "float":
            return _number(v, key, spec.bounds)
        if kind == "int":
            return _integer(v, key, spec.bounds)
        if kind == "depth":
            d = _integer(v, key)
            if d != -1 and d < 1:
                raise _Invalid(key, f"must be -1 (unbounded) or >= 1 (got {_show(v)})")
            return d
        if kind == "bool":
            if not isinstance(v, bool):
                raise _Invalid(key, f"must be true or false (got {_show(v)})")
            return v
        if kind == "str":
            return _string(v, key)
        if kind == "choice":
            if _string(v, key) not in spec.choices:
                raise _Invalid(key, f"must be one of: {', '.join(spec.choices)} (got {_show(v)})")
            return v
        if kind == "vec3":
            return _vector(v, key, 3, spec.bounds)
        if kind == "vec2":
            return _vector(v, key, 2, spec.bounds)
        if kind == "unit":
            return _unit(v, key)
        if kind == "rgb":
            return _rgb(v, key, spec.bounds)
        if kind == "file":
            return self.file(v, key, spec.suffixes)
        if kind == "material":
            t = _table(v, key)
            self.check_type(t, key, {Diffuse.kind: Diffuse}, "material", default=Diffuse.kind)
            return Diffuse(**self.fields(Diffuse, t, key))
        if kind == "boundary":
            cls = self.check_type(_table(v, key), key, BOUNDARY_TYPES, "boundary")
            return cls(**self.fields(cls, v, key, exclude=BOUNDARY_EXCLUDES))
        raise AssertionError(f"unknown spec kind {kind!r}")

    def file(self, v: Any, key: str, suffixes: tuple[str, ...]) -> str:
        if not _string(v, key):
            raise _Invalid(key, "must be a non-empty path")
        if os.path.splitext(v)[1].lower() not in suffixes:
            raise _Invalid(key, f"must be a {' or '.join(suffixes)} file (got {_show(v)})")
        path = os.path.abspath(os.path.join(self.base_dir, os.path.expanduser(v)))
        if not os.path.isfile(path):
            raise _Invalid(key, f"file not found: {path}")
        if path.lower().endswith(".xml"):
            problem = xml_problem(path)
            if problem:
                raise _Invalid(key, f"{path}: {problem}")
        problem = mesh_problem(path, MAX_LENGTH)  # a .ply/.obj must be a readable mesh before it is used
        if problem:
            raise _Invalid(key, f"{path}: {problem}")
        return path

    # tables ------------------------------------------------------------------------------------
    @staticmethod
    def check_type(
        t: dict, key: str, registry: dict[str, type], what: str, default: str | None = None
    ) -> type:
        """The class named by ``t["type"]`` (``default`` when absent, if given)."""
        if "type" not in t and default is None:
            raise _Invalid(key, "missing required key 'type'")
        name = _string(t.get("type", default), _join(key, "type"))
        if name not in registry:
            expected = ", ".join(sorted(registry))
            raise _Invalid(
                _join(key, "type"), f"unknown {what} type {_show(name)} (expected one of: {expected})"
            )
        return registry[name]

    def fields(
        self, cls: type, t: dict, key: str, *, exclude=(), extra=(), typed=True, check_required=True
    ) -> dict[str, Any]:
        """Constructor arguments of ``cls`` given in ``t`` (absent optional fields keep their defaults).

        ``extra`` keys are allowed in ``t`` but left to the caller, as is a missing required field
        when ``check_required`` is false."""
        specs = {n: s for n, s in SCHEMA[cls].items() if n not in exclude}
        allowed = set(specs) | set(extra) | ({"type"} if typed else set())
        for k in t:
            if k not in allowed:
                raise _Invalid(_join(key, k), f"unknown key (expected one of: {', '.join(sorted(allowed))})")
        out = {}
        for f in fields(cls):
            if f.name not in specs:
                continue
            if f.name in t:
                out[f.name] = self.value(specs[f.name], t[f.name], _join(key, f.name))
            elif check_required and f.default is MISSING and f.default_factory is MISSING:
                raise _Invalid(key, f"missing required key '{f.name}'")
        return out

    def array(self, doc: dict, name: str) -> list[dict]:
        v = doc.get(name, [])
        if not isinstance(v, list):
            raise _Invalid(name, f"must be an array of tables ([[{name}]]) (got {_show(v)})")
        return [_table(item, f"{name}[{i}]") for i, item in enumerate(v)]

    # parts -------------------------------------------------------------------------------------
    def camera(self, t: dict) -> Camera:
        self.check_type(t, "camera", {Camera.kind: Camera}, "camera", default=Camera.kind)
        cam = Camera(**self.fields(Camera, t, "camera"))
        fwd = [b - a for a, b in zip(cam.origin, cam.target, strict=True)]
        if not any(fwd):
            raise _Invalid("camera.target", f"must differ from camera.origin (got {_show(list(cam.target))})")
        f = normalised(tuple(fwd))
        assert f is not None  # fwd is non-zero (checked just above)
        u = cam.up
        cross = (u[1] * f[2] - u[2] * f[1], u[2] * f[0] - u[0] * f[2], u[0] * f[1] - u[1] * f[0])
        if math.sqrt(sum(c * c for c in cross)) < 1e-6:
            raise _Invalid(
                "camera.up", f"must not be parallel to target - origin (got {_show(list(cam.up))})"
            )
        if cam.far_clip <= cam.near_clip:
            raise _Invalid(
                "camera.far_clip", f"must be > near_clip = {cam.near_clip!r} (got {cam.far_clip!r})"
            )
        return cam

    def shape(self, t: dict, key: str):
        cls = self.check_type(t, key, SHAPE_TYPES, "shape")
        args = self.fields(cls, t, key)
        if cls is Cylinder and args["p0"] == args["p1"]:
            raise _Invalid(_join(key, "p1"), f"must differ from p0 (got {_show(list(args['p1']))})")
        return cls(**args)

    def light(self, t: dict, key: str):
        cls = self.check_type(t, key, LIGHT_TYPES, "light")
        if cls is not SphereLight:
            args = self.fields(cls, t, key)
            if cls is SpotLight:  # (either angle may be left at its default)
                beam = args.get("beam_width_deg", SpotLight.beam_width_deg)
                if not beam < args.get("cutoff_angle_deg", SpotLight.cutoff_angle_deg):
                    what = f"must be below cutoff_angle_deg (got {beam:g})"
                    raise _Invalid(_join(key, "beam_width_deg"), what)
            return cls(**args)
        args = self.fields(cls, t, key, extra=SPHERE_LIGHT_PLACEMENT, check_required=False)
        alt = [k for k in SPHERE_LIGHT_PLACEMENT if k in t]
        if not alt:
            for k in ("center", "radius"):
                if k not in args:
                    raise _Invalid(
                        key,
                        f"missing required key '{k}' (or place it by direction, distance and "
                        "angular_radius_deg)",
                    )
            return cls(**args)
        for k in ("center", "radius"):
            if k in t:
                raise _Invalid(
                    _join(key, k),
                    f"cannot be combined with {alt[0]} (place a sphere light "
                    "either by center/radius or by "
                    "target/direction/distance/angular_radius_deg)",
                )
        for k in ("direction", "distance", "angular_radius_deg"):
            if k not in t:
                raise _Invalid(
                    key,
                    f"missing required key '{k}' (a sphere light placed by direction needs "
                    "direction, distance and angular_radius_deg)",
                )
        target = _vector(t.get("target", [0.0, 0.0, 0.0]), _join(key, "target"), 3, COORDINATE)
        direction = _unit(t["direction"], _join(key, "direction"))
        distance = _number(t["distance"], _join(key, "distance"), POSITIVE)
        alpha = _number(t["angular_radius_deg"], _join(key, "angular_radius_deg"), OPEN_QUADRANT)
        args["center"] = tuple(p + distance * d for p, d in zip(target, direction, strict=True))
        args["radius"] = distance * math.sin(math.radians(alpha))
        if not all(map(math.isfinite, args["center"])) or not args["radius"] > 0.0:
            raise _Invalid(
                key,
                f"placement gives centre {_show(list(args['center']))} and radius "
                f"{args['radius']!r} (must be finite, radius > 0)",
            )
        return cls(**args)

    def scene(self, doc: dict, source: str) -> Scene:
        if isinstance(doc.get("format"), str):  # another rtfit file format in the same library
            reader = OTHER_FORMATS.get(doc["format"], "the tool that wrote it")
            raise _Invalid("format", f"a {doc['format']!r} file, not a scene: read it with {reader}")
        for k in doc:
            if k not in TOP_LEVEL_KEYS:
                raise _Invalid(k, f"unknown key (expected one of: {', '.join(sorted(TOP_LEVEL_KEYS))})")
        for k in ("name", "camera"):
            if k not in doc:
                raise _Invalid("", f"missing required key '{k}'")
        if not _string(doc["name"], "name").strip():
            raise _Invalid("name", "must be a non-empty string")
        description = _string(doc.get("description", ""), "description")
        camera = self.camera(_table(doc["camera"], "camera"))
        ref_table = _table(doc.get("reference", {}), "reference")
        reference = ReferenceSettings(**self.fields(ReferenceSettings, ref_table, "reference", typed=False))
        shapes = tuple(self.shape(t, f"shapes[{i}]") for i, t in enumerate(self.array(doc, "shapes")))
        lights = tuple(self.light(t, f"lights[{i}]") for i, t in enumerate(self.array(doc, "lights")))
        media = []
        for i, t in enumerate(self.array(doc, "media")):
            cls = self.check_type(t, f"media[{i}]", MEDIUM_TYPES, "medium")
            media.append(cls(**self.fields(cls, t, f"media[{i}]")))
        envs = [i for i, light in enumerate(lights) if light.kind in ENVIRONMENT_KINDS]
        if len(envs) > 1:
            raise _Invalid(
                f"lights[{envs[1]}]",
                f"a scene has at most one environment light ({', '.join(ENVIRONMENT_KINDS)}); "
                f"lights[{envs[0]}] is one already",
            )
        return Scene(
            name=doc["name"],
            camera=camera,
            shapes=shapes,
            lights=lights,
            media=tuple(media),
            reference=reference,
            description=description,
            source=source,
        )


# ----------------------------------------------------------------------------------------------- API
# Files in scenes/library/ that are not scene files, by their ``format`` key.
OTHER_FORMATS = {"rtfit.sky/1": "rtfit.reference.nishita_sky.load_atmosphere_scene"}


def parse_scene_text(
    text: str, *, source: str = "<string>", base_dir: str | os.PathLike | None = None
) -> Scene:
    """Parse scene-file text. ``source`` names it in errors and in ``Scene.source``; relative file paths
    resolve against ``base_dir`` (default: the current directory at call time)."""
    base = os.path.abspath(os.fspath(base_dir)) if base_dir is not None else os.getcwd()
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError.at(source, "", f"not valid TOML: {e}") from None
    try:
        return _Parser(base).scene(doc, source)
    except _Invalid as e:
        raise SceneError.at(source, e.key, e.reason) from None


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and parse a scene file (UTF-8 TOML); ``Scene.source`` is ``str(path)`` as given."""
    source = os.fspath(path)
    try:
        data = Path(source).read_bytes()
    except OSError as e:
        reason = f"cannot read scene file ({e.strerror or type(e).__name__})"
        raise SceneError.at(source, "", reason) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SceneError.at(source, "", f"not valid UTF-8 (byte offset {e.start})") from None
    return parse_scene_text(text, source=source, base_dir=os.path.dirname(os.path.abspath(source)))


def library_names() -> list[str]:
    """Names of the scenes shipped in ``scenes/library/`` (file stems)."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.toml"))


def library_path(name: str) -> Path:
    """Path of a shipped scene, e.g. ``library_path("half_lambert_sphere")`` (``-`` may stand for ``_``,
    a ``.toml`` suffix is optional)."""
    stem = name.removesuffix(".toml").replace("-", "_")
    path = LIBRARY_DIR / f"{stem}.toml"
    if "/" in stem or os.sep in stem or not path.is_file():
        available = ", ".join(library_names()) or "none"
        reason = f"no library scene named {_show(name)} (available: {available})"
        raise SceneError.at(str(LIBRARY_DIR), "", reason)
    return path
