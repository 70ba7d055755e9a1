"""Typed scene description: what a scene file declares, nothing more.

Every object is a frozen dataclass holding plain Python values (floats, tuples, strings), so a scene
can be hashed, compared, pickled and sent to another process without any Mitsuba or Dr.Jit object.
`rtfit.reference` turns a :class:`Scene` into a Mitsuba scene that contains only the plugins the
scene declares.

Conventions (shared by the whole project):

* World frame: right-handed, **+Z is up**. Lengths are in scene units (metres unless a scene says
  otherwise); angles in scene files are in degrees and carry a ``_deg`` suffix.
* Directions of lights point **towards** the light (from the scene to the sun).
* Radiance is in W·m⁻²·sr⁻¹ per RGB channel, irradiance in W·m⁻² per RGB channel (linear sRGB
  primaries, as Mitsuba's ``*_rgb`` variants use).
* ``RGB`` values are 3-tuples of floats; scene files may give a single number for a grey value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]


# --------------------------------------------------------------------------------------------- camera
@dataclass(frozen=True)
class Camera:
    """Pinhole perspective camera.

    ``fov_deg`` is the full field of view along the image's horizontal (x) axis. Pixel (i, j) is
    sampled at its centre ((i + 0.5)/width, (j + 0.5)/height) by the reference and by the G-buffer.
    """

    origin: Vec3
    target: Vec3
    up: Vec3 = (0.0, 0.0, 1.0)
    fov_deg: float = 40.0
    width: int = 128
    height: int = 128
    near_clip: float = 1e-3
    far_clip: float = 1e7

    kind: ClassVar[str] = "perspective"


# ------------------------------------------------------------------------------------------ materials
@dataclass(frozen=True)
class Diffuse:
    """Lambertian BSDF with RGB reflectance (albedo) in [0, 1]."""

    reflectance: RGB = (0.5, 0.5, 0.5)

    kind: ClassVar[str] = "diffuse"


# --------------------------------------------------------------------------------------------- shapes
@dataclass(frozen=True)
class Sphere:
    center: Vec3
    radius: float
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "sphere"
    convex: ClassVar[bool] = True


@dataclass(frozen=True)
class Rectangle:
    """Planar rectangle of full extent ``size`` = (sx, sy), facing ``normal``.

    ``rotation_deg`` turns the rectangle about its normal. One-sided for emission, two-sided for
    reflection (Mitsuba's diffuse BSDF is two-sided).
    """

    center: Vec3
    normal: Vec3
    size: tuple[float, float]
    rotation_deg: float = 0.0
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "rectangle"
    convex: ClassVar[bool] = True  # a plane cannot see itself


@dataclass(frozen=True)
class Disk:
    center: Vec3
    normal: Vec3
    radius: float
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "disk"
    convex: ClassVar[bool] = True


@dataclass(frozen=True)
class Cube:
    """Box of full extent ``size`` centred at ``center``, rotated by ``rotate_deg`` about ``rotate_axis``."""

    center: Vec3
    size: Vec3
    rotate_axis: Vec3 = (0.0, 0.0, 1.0)
    rotate_deg: float = 0.0
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "cube"
    convex: ClassVar[bool] = True


@dataclass(frozen=True)
class Cylinder:
    """Open cylinder (no end caps, as Mitsuba's ``cylinder``) from ``p0`` to ``p1``.

    An open cylinder is not convex: its inside can see itself.
    """

    p0: Vec3
    p1: Vec3
    radius: float
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "cylinder"
    convex: ClassVar[bool] = False


@dataclass(frozen=True)
class Mesh:
    """Triangle mesh from a PLY or OBJ file (absolute path after parsing).

    The transform applies scale, then rotation about ``rotate_axis`` by ``rotate_deg``, then
    translation. ``face_normals`` forces flat shading.
    """

    file: str
    translate: Vec3 = (0.0, 0.0, 0.0)
    rotate_axis: Vec3 = (0.0, 0.0, 1.0)
    rotate_deg: float = 0.0
    scale: Vec3 = (1.0, 1.0, 1.0)
    face_normals: bool = False
    material: Diffuse = field(default_factory=Diffuse)

    kind: ClassVar[str] = "mesh"
    convex: ClassVar[bool] = False  # unknown in general


@dataclass(frozen=True)
class MitsubaXML:
    """Geometry taken from a user's Mitsuba 3 XML scene file (absolute path after parsing).

    Only the file's shapes are used (its sensors, integrator and, unless ``keep_emitters``, its
    emitters are dropped). ``override_material`` replaces every shape's BSDF with the given diffuse
    material, so that audits compare like with like; otherwise the file's own BSDFs are kept.
    """

    file: str
    keep_emitters: bool = False
    override_material: Diffuse | None = None

    kind: ClassVar[str] = "mitsuba_xml"
    convex: ClassVar[bool] = False


Shape = Sphere | Rectangle | Disk | Cube | Cylinder | Mesh | MitsubaXML


# --------------------------------------------------------------------------------------------- lights
@dataclass(frozen=True)
class Sun:
    """A distant light: direction towards the sun, irradiance at normal incidence, angular radius.

    ``angular_radius_deg = 0`` is an ideal directional light (Mitsuba ``directional``). A positive
    radius is a uniform disc at infinity (a spherical cap of directions, the same from every point),
    of radiance L = E / (π sin² α) so that the irradiance at normal incidence is ``irradiance``. The
    reference renders it with rtfit's own Mitsuba emitter (`rtfit.reference.emitters`), because
    Mitsuba's sphere emitter loses float32 precision in its pdf for small angular sizes.
    """

    direction: Vec3
    irradiance: RGB = (1.0, 1.0, 1.0)
    angular_radius_deg: float = 0.0

    kind: ClassVar[str] = "sun"


@dataclass(frozen=True)
class SphereLight:
    """Uniform spherical area light (Lambertian emitter) of the given radiance."""

    center: Vec3
    radius: float
    radiance: RGB = (1.0, 1.0, 1.0)

    kind: ClassVar[str] = "sphere_light"

    def angular_radius(self, point: Vec3) -> float:
        """Angular radius (radians) of the light seen from ``point``; π/2 when inside it."""
        d = math.dist(self.center, point)
        return math.pi / 2 if d <= self.radius else math.asin(self.radius / d)


@dataclass(frozen=True)
class RectLight:
    """One-sided rectangular area light emitting towards ``normal``."""

    center: Vec3
    normal: Vec3
    size: tuple[float, float]
    radiance: RGB = (1.0, 1.0, 1.0)
    rotation_deg: float = 0.0

    kind: ClassVar[str] = "rect_light"


@dataclass(frozen=True)
class PointLight:
    """Isotropic point light of radiant ``intensity`` (W/sr per channel) at ``position`` (Mitsuba ``point``).

    Seen directly it covers no pixel; it lights surfaces and media by next-event estimation only."""

    position: Vec3
    intensity: RGB = (1.0, 1.0, 1.0)

    kind: ClassVar[str] = "point_light"


@dataclass(frozen=True)
class SpotLight:
    """Spot light at ``position`` emitting around the unit ``axis`` (the direction it points to), Mitsuba
    ``spot``: radiant intensity I(ω) = ``intensity``·f(θ) (W/sr per channel), θ the angle between ω and the
    axis, f = 1 for θ ≤ ``beam_width_deg``, (θ_c − θ)/(θ_c − θ_b) (linear in the angle) up to
    ``cutoff_angle_deg`` θ_c, 0 beyond (Mitsuba 3 ``spot.cpp`` ``falloff_curve``; ``beam_width_deg`` <
    ``cutoff_angle_deg``). Like a point light it covers no pixel."""

    position: Vec3
    axis: Vec3 = (0.0, 0.0, -1.0)
    intensity: RGB = (1.0, 1.0, 1.0)
    cutoff_angle_deg: float = 20.0
    beam_width_deg: float = 15.0

    kind: ClassVar[str] = "spot_light"


@dataclass(frozen=True)
class ConstantEnv:
    """Uniform environment of the given radiance from every direction."""

    radiance: RGB = (1.0, 1.0, 1.0)

    kind: ClassVar[str] = "constant_env"


@dataclass(frozen=True)
class EnvMap:
    """Lat-long environment map from an EXR file (absolute path after parsing).

    The file is in Mitsuba's convention (+Y up in the map's own frame, see Mitsuba's ``envmap``); the
    reference rotates it so that the map's up axis is world +Z, then applies ``rotate_deg`` about
    world +Z. ``scale`` multiplies the radiance.
    """

    file: str
    scale: float = 1.0
    rotate_deg: float = 0.0

    kind: ClassVar[str] = "envmap"


@dataclass(frozen=True)
class SunSky:
    """Mitsuba's Hosek–Wilkie ``sunsky`` (+Z up, as the world). ``sun_direction`` points to the sun."""

    sun_direction: Vec3
    turbidity: float = 3.0
    albedo: float = 0.3
    sun_scale: float = 1.0
    sky_scale: float = 1.0
    sun_aperture_deg: float = 0.5358
    complex_sun: bool = False

    kind: ClassVar[str] = "sunsky"


Light = Sun | SphereLight | RectLight | PointLight | SpotLight | ConstantEnv | EnvMap | SunSky
ENVIRONMENT_KINDS = ("constant_env", "envmap", "sunsky")


# ---------------------------------------------------------------------------------------------- media
@dataclass(frozen=True)
class HomogeneousMedium:
    """Homogeneous participating medium filling a closed boundary shape (sphere or cube).

    ``sigma_t`` is the extinction coefficient per scene unit (RGB), ``albedo`` the single-scattering
    albedo, ``g`` the Henyey–Greenstein asymmetry (0 = isotropic). Later families add height fog and
    atmosphere media beside this one.
    """

    boundary: Sphere | Cube
    sigma_t: RGB
    albedo: RGB = (0.0, 0.0, 0.0)
    g: float = 0.0

    kind: ClassVar[str] = "homogeneous"


@dataclass(frozen=True)
class ExponentialFog:
    """Exponential height fog σt(p) = density·exp(−falloff·(p − gradient_origin)·gradient) (1/scene unit),
    inside ``boundary`` (a box, or a sphere), optionally restricted to the ellipsoid inscribed in a box
    boundary (``ellipsoid``). ``density`` b ≥ 0 and ``falloff`` c ≥ 0 are in 1/scene unit; ``gradient`` is
    the unit direction of increasing height (default +Z); ``albedo`` and Henyey–Greenstein ``g`` as for
    `HomogeneousMedium`. Rendered by rtfit's Python medium (`rtfit.reference.fog_media`).
    """

    boundary: Sphere | Cube
    density: float
    falloff: float = 0.0
    gradient: Vec3 = (0.0, 0.0, 1.0)
    gradient_origin: Vec3 = (0.0, 0.0, 0.0)
    albedo: RGB = (0.0, 0.0, 0.0)
    g: float = 0.0
    ellipsoid: bool = False

    kind: ClassVar[str] = "exponential_fog"


Medium = HomogeneousMedium


# ------------------------------------------------------------------------------------ reference setup
TRANSPORTS = ("direct", "global")


@dataclass(frozen=True)
class ReferenceSettings:
    """What the ground truth must contain.

    ``transport``: ``"direct"`` (light reaching a surface straight from emitters, one bounce to the
    camera: what most real-time lighting terms approximate) or ``"global"`` (all bounces).
    ``max_depth`` caps the path length for ``"global"`` (-1: unbounded with Russian roulette, which is
    unbiased); ``None`` lets the integrator rule decide.
    """

    transport: str = "global"
    max_depth: int | None = None


# ---------------------------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class Scene:
    """A whole scene. ``source`` is the file it was parsed from (or ``"<string>"``)."""

    name: str
    camera: Camera
    shapes: tuple[Shape, ...] = ()
    lights: tuple[Light, ...] = ()
    media: tuple[Medium, ...] = ()
    reference: ReferenceSettings = field(default_factory=ReferenceSettings)
    description: str = ""
    source: str = field(default="<string>", compare=False)

    def parts(self) -> frozenset[str]:
        """The kinds of every declared part, e.g. ``{"perspective", "sphere", "sun"}``."""
        kinds = {self.camera.kind}
        kinds.update(s.kind for s in self.shapes)
        kinds.update(light.kind for light in self.lights)
        kinds.update(m.kind for m in self.media)
        return frozenset(kinds)

    def environment(self) -> Light | None:
        """The scene's environment light, if any (a scene has at most one)."""
        for light in self.lights:
            if light.kind in ENVIRONMENT_KINDS:
                return light
        return None
