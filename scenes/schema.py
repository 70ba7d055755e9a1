"""The scene file's schema: how each field of each :mod:`rtfit.scenes.model` class is read from a file and
written back (`Spec`, `SCHEMA`), the intervals and sanity limits of its numbers (`Bounds`, ``MAX_*``), and
the registries of the ``type`` names of shapes, lights, media and medium boundaries.

`rtfit.scenes.parse` reads files by it, `rtfit.scenes.serialize` writes them by it, and
`rtfit.reference.xml_checks` applies the same ranges to Mitsuba XML scenes.
"""

from __future__ import annotations

from dataclasses import dataclass

from .model import (
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
    Sphere,
    SphereLight,
    SpotLight,
    Sun,
    SunSky,
)


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
