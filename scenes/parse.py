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

The schema (`SCHEMA`, `Spec`, `Bounds`, the limits and type registries) lives in `rtfit.scenes.schema` and
the value readers in `rtfit.scenes.value_readers`; this module reads whole documents and is the public face
(it re-exports what importers use).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from .mesh_files import mesh_problem
from .model import (
    ENVIRONMENT_KINDS,
    Camera,
    Cylinder,
    Diffuse,
    ReferenceSettings,
    Scene,
    SphereLight,
    SpotLight,
)
from .schema import BOUNDARY_EXCLUDES as BOUNDARY_EXCLUDES
from .schema import (
    BOUNDARY_TYPES,
    COORDINATE,
    LIGHT_TYPES,
    MAX_LENGTH,
    MEDIUM_TYPES,
    OPEN_QUADRANT,
    POSITIVE,
    SCHEMA,
    SHAPE_TYPES,
    SPHERE_LIGHT_PLACEMENT,
    TOP_LEVEL_KEYS,
    Spec,
)
from .schema import MAX_COEFFICIENT as MAX_COEFFICIENT
from .schema import MAX_RADIANCE as MAX_RADIANCE
from .schema import Bounds as Bounds
from .value_readers import (
    KeyProblem,
    join_key,
    normalised,
    read_integer,
    read_number,
    read_rgb,
    read_string,
    read_table,
    read_unit,
    read_vector,
    show_value,
    xml_problem,
)

LIBRARY_DIR = Path(__file__).resolve().parent / "library"


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


# -------------------------------------------------------------------------------------------- parser
class _Parser:
    """Reads one parsed TOML document; ``base_dir`` (absolute) resolves relative file paths."""

    def __init__(self, base_dir: str):
        self.base_dir = base_dir

    # values ------------------------------------------------------------------------------------
    def value(self, spec: Spec, v: Any, key: str) -> Any:
        kind = spec.kind
        if kind == "float":
            return read_number(v, key, spec.bounds)
        if kind == "int":
            return read_integer(v, key, spec.bounds)
        if kind == "depth":
            d = read_integer(v, key)
            if d != -1 and d < 1:
                raise KeyProblem(key, f"must be -1 (unbounded) or >= 1 (got {show_value(v)})")
            return d
        if kind == "bool":
            if not isinstance(v, bool):
                raise KeyProblem(key, f"must be true or false (got {show_value(v)})")
            return v
        if kind == "str":
            return read_string(v, key)
        if kind == "choice":
            if read_string(v, key) not in spec.choices:
                raise KeyProblem(key, f"must be one of: {', '.join(spec.choices)} (got {show_value(v)})")
            return v
        if kind == "vec3":
            return read_vector(v, key, 3, spec.bounds)
        if kind == "vec2":
            return read_vector(v, key, 2, spec.bounds)
        if kind == "unit":
            return read_unit(v, key)
        if kind == "rgb":
            return read_rgb(v, key, spec.bounds)
        if kind == "file":
            return self.file(v, key, spec.suffixes)
        if kind == "material":
            t = read_table(v, key)
            self.check_type(t, key, {Diffuse.kind: Diffuse}, "material", default=Diffuse.kind)
            return Diffuse(**self.fields(Diffuse, t, key))
        if kind == "boundary":
            cls = self.check_type(read_table(v, key), key, BOUNDARY_TYPES, "boundary")
            return cls(**self.fields(cls, v, key, exclude=BOUNDARY_EXCLUDES))
        raise AssertionError(f"unknown spec kind {kind!r}")

    def file(self, v: Any, key: str, suffixes: tuple[str, ...]) -> str:
        if not read_string(v, key):
            raise KeyProblem(key, "must be a non-empty path")
        if os.path.splitext(v)[1].lower() not in suffixes:
            raise KeyProblem(key, f"must be a {' or '.join(suffixes)} file (got {show_value(v)})")
        path = os.path.abspath(os.path.join(self.base_dir, os.path.expanduser(v)))
        if not os.path.isfile(path):
            raise KeyProblem(key, f"file not found: {path}")
        if path.lower().endswith(".xml"):
            problem = xml_problem(path)
            if problem:
                raise KeyProblem(key, f"{path}: {problem}")
        problem = mesh_problem(path, MAX_LENGTH)  # a .ply/.obj must be a readable mesh before it is used
        if problem:
            raise KeyProblem(key, f"{path}: {problem}")
        return path

    # tables ------------------------------------------------------------------------------------
    @staticmethod
    def check_type(
        t: dict, key: str, registry: dict[str, type], what: str, default: str | None = None
    ) -> type:
        """The class named by ``t["type"]`` (``default`` when absent, if given)."""
        if "type" not in t and default is None:
            raise KeyProblem(key, "missing required key 'type'")
        name = read_string(t.get("type", default), join_key(key, "type"))
        if name not in registry:
            expected = ", ".join(sorted(registry))
            raise KeyProblem(
                join_key(key, "type"), f"unknown {what} type {show_value(name)} (expected one of: {expected})"
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
                raise KeyProblem(
                    join_key(key, k), f"unknown key (expected one of: {', '.join(sorted(allowed))})"
                )
        out = {}
        for f in fields(cls):
            if f.name not in specs:
                continue
            if f.name in t:
                out[f.name] = self.value(specs[f.name], t[f.name], join_key(key, f.name))
            elif check_required and f.default is MISSING and f.default_factory is MISSING:
                raise KeyProblem(key, f"missing required key '{f.name}'")
        return out

    def array(self, doc: dict, name: str) -> list[dict]:
        v = doc.get(name, [])
        if not isinstance(v, list):
            raise KeyProblem(name, f"must be an array of tables ([[{name}]]) (got {show_value(v)})")
        return [read_table(item, f"{name}[{i}]") for i, item in enumerate(v)]

    # parts -------------------------------------------------------------------------------------
    def camera(self, t: dict) -> Camera:
        self.check_type(t, "camera", {Camera.kind: Camera}, "camera", default=Camera.kind)
        cam = Camera(**self.fields(Camera, t, "camera"))
        fwd = [b - a for a, b in zip(cam.origin, cam.target, strict=True)]
        if not any(fwd):
            raise KeyProblem(
                "camera.target", f"must differ from camera.origin (got {show_value(list(cam.target))})"
            )
        f = normalised(tuple(fwd))
        assert f is not None  # fwd is non-zero (checked just above)
        u = cam.up
        cross = (u[1] * f[2] - u[2] * f[1], u[2] * f[0] - u[0] * f[2], u[0] * f[1] - u[1] * f[0])
        if math.sqrt(sum(c * c for c in cross)) < 1e-6:
            raise KeyProblem(
                "camera.up", f"must not be parallel to target - origin (got {show_value(list(cam.up))})"
            )
        if cam.far_clip <= cam.near_clip:
            raise KeyProblem(
                "camera.far_clip", f"must be > near_clip = {cam.near_clip!r} (got {cam.far_clip!r})"
            )
        return cam

    def shape(self, t: dict, key: str):
        cls = self.check_type(t, key, SHAPE_TYPES, "shape")
        args = self.fields(cls, t, key)
        if cls is Cylinder and args["p0"] == args["p1"]:
            raise KeyProblem(join_key(key, "p1"), f"must differ from p0 (got {show_value(list(args['p1']))})")
        return cls(**args)

    def light(self, t: dict, key: str):
        cls = self.check_type(t, key, LIGHT_TYPES, "light")
        if cls is not SphereLight:
            args = self.fields(cls, t, key)
            if cls is SpotLight:  # (either angle may be left at its default)
                beam = args.get("beam_width_deg", SpotLight.beam_width_deg)
                if not beam < args.get("cutoff_angle_deg", SpotLight.cutoff_angle_deg):
                    what = f"must be below cutoff_angle_deg (got {beam:g})"
                    raise KeyProblem(join_key(key, "beam_width_deg"), what)
            return cls(**args)
        args = self.fields(cls, t, key, extra=SPHERE_LIGHT_PLACEMENT, check_required=False)
        alt = [k for k in SPHERE_LIGHT_PLACEMENT if k in t]
        if not alt:
            for k in ("center", "radius"):
                if k not in args:
                    raise KeyProblem(
                        key,
                        f"missing required key '{k}' (or place it by direction, distance and "
                        "angular_radius_deg)",
                    )
            return cls(**args)
        for k in ("center", "radius"):
            if k in t:
                raise KeyProblem(
                    join_key(key, k),
                    f"cannot be combined with {alt[0]} (place a sphere light "
                    "either by center/radius or by "
                    "target/direction/distance/angular_radius_deg)",
                )
        for k in ("direction", "distance", "angular_radius_deg"):
            if k not in t:
                raise KeyProblem(
                    key,
                    f"missing required key '{k}' (a sphere light placed by direction needs "
                    "direction, distance and angular_radius_deg)",
                )
        target = read_vector(t.get("target", [0.0, 0.0, 0.0]), join_key(key, "target"), 3, COORDINATE)
        direction = read_unit(t["direction"], join_key(key, "direction"))
        distance = read_number(t["distance"], join_key(key, "distance"), POSITIVE)
        alpha = read_number(t["angular_radius_deg"], join_key(key, "angular_radius_deg"), OPEN_QUADRANT)
        args["center"] = tuple(p + distance * d for p, d in zip(target, direction, strict=True))
        args["radius"] = distance * math.sin(math.radians(alpha))
        if not all(map(math.isfinite, args["center"])) or not args["radius"] > 0.0:
            raise KeyProblem(
                key,
                f"placement gives centre {show_value(list(args['center']))} and radius "
                f"{args['radius']!r} (must be finite, radius > 0)",
            )
        return cls(**args)

    def scene(self, doc: dict, source: str) -> Scene:
        if isinstance(doc.get("format"), str):  # another rtfit file format in the same library
            reader = OTHER_FORMATS.get(doc["format"], "the tool that wrote it")
            raise KeyProblem("format", f"a {doc['format']!r} file, not a scene: read it with {reader}")
        for k in doc:
            if k not in TOP_LEVEL_KEYS:
                raise KeyProblem(k, f"unknown key (expected one of: {', '.join(sorted(TOP_LEVEL_KEYS))})")
        for k in ("name", "camera"):
            if k not in doc:
                raise KeyProblem("", f"missing required key '{k}'")
        if not read_string(doc["name"], "name").strip():
            raise KeyProblem("name", "must be a non-empty string")
        description = read_string(doc.get("description", ""), "description")
        camera = self.camera(read_table(doc["camera"], "camera"))
        ref_table = read_table(doc.get("reference", {}), "reference")
        reference = ReferenceSettings(**self.fields(ReferenceSettings, ref_table, "reference", typed=False))
        shapes = tuple(self.shape(t, f"shapes[{i}]") for i, t in enumerate(self.array(doc, "shapes")))
        lights = tuple(self.light(t, f"lights[{i}]") for i, t in enumerate(self.array(doc, "lights")))
        media = []
        for i, t in enumerate(self.array(doc, "media")):
            cls = self.check_type(t, f"media[{i}]", MEDIUM_TYPES, "medium")
            media.append(cls(**self.fields(cls, t, f"media[{i}]")))
        envs = [i for i, light in enumerate(lights) if light.kind in ENVIRONMENT_KINDS]
        if len(envs) > 1:
            raise KeyProblem(
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
    except KeyProblem as e:
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
        reason = f"no library scene named {show_value(name)} (available: {available})"
        raise SceneError.at(str(LIBRARY_DIR), "", reason)
    return path
