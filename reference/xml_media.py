"""Lights inside media: the medium a point of a loaded Mitsuba scene sits in, found by Mitsuba itself.

`point_medium` follows a fixed probe ray from the point to the first medium transition (`first_transition`)
and takes the medium on its incoming side; outside every bounded medium, the sensor's own medium where the
sensor is outside every boundary too (`camera_origin`). `with_medium` records it on a point or spot light's
`XmlEmitter` (`XmlEmitter.medium`, an index in `XmlScene.media`; `medium_objects` pairs the media Mitsuba
loaded with those indices). Re-exported by `rtfit.reference.mitsuba_xml`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .xml_records import XmlEmitter

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


def medium_objects(medium_nodes, shape_nodes, shape_obj, sensor_nodes, sensor_objs, refs) -> list:
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


def with_medium(mi, scene, sensor, emitter: XmlEmitter, media_objs) -> XmlEmitter:
    """``emitter`` with its `XmlEmitter.medium` (point and spot lights)."""
    if emitter.kind not in ("point", "spot") or emitter.position is None:
        return emitter
    medium = point_medium(mi, scene, sensor, emitter.position)
    index = next((k for obj, k in media_objs if medium is not None and obj is medium), None)
    return replace(emitter, medium=index)
