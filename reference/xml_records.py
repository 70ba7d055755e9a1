"""The records `rtfit.reference.xml_inspect.inspect_xml` returns: what a Mitsuba XML scene contains.

`XmlScene` (the file's sensors, emitters, shapes, BSDFs, media, integrator, bounding box and the files it
loads) of `XmlSensor`, `XmlEmitter`, `XmlShape` and `XmlMedium` records, plain frozen data; `UP_AXES` names
the world up axes a scene's up may be. Re-exported by `rtfit.reference.mitsuba_xml`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from .xml_parse import XmlDependencies

Vec3 = tuple[float, float, float]

UP_AXES: dict[str, Vec3] = {
    "+x": (1.0, 0.0, 0.0),
    "-x": (-1.0, 0.0, 0.0),
    "+y": (0.0, 1.0, 0.0),
    "-y": (0.0, -1.0, 0.0),
    "+z": (0.0, 0.0, 1.0),
    "-z": (0.0, 0.0, -1.0),
}


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
