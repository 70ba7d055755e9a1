"""`inspect_xml`: what a user's Mitsuba XML scene (or scene dict) contains, read from Mitsuba's parser.

The parser's state says which sensors, emitters, shapes, BSDFs, media and integrator the file declares
(`rtfit.reference.xml_parse.parsed_xml`); instantiating the scene (under the same scoped file resolver)
gives what the properties do not say: the film size and field of view Mitsuba derives, the mesh face
counts, the bounding boxes (a sphere light's centre and radius, the scene's extent), the medium each
point or spot light sits in (`rtfit.reference.xml_media`). Each sensor, emitter, shape and medium becomes a
record of `rtfit.reference.xml_records`; the world up axis comes from ``--up`` or the chosen sensor's up
vector (`up_from_vector`). Re-exported by `rtfit.reference.mitsuba_xml`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from .particle_media import convex_mesh
from .xml_media import medium_objects, with_medium
from .xml_parse import (
    MESH_PLUGINS,
    NOT_TEXT_ERROR,
    XMLSceneError,
    check_nodes,
    collect_dependencies,
    instantiate_checked,
    mitsuba_error_text,
    node_props,
    normalised_source,
    parsed_xml,
    resolved_file,
    source_label,
)
from .xml_records import UP_AXES, Vec3, XmlEmitter, XmlMedium, XmlScene, XmlSensor, XmlShape

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
_SUN_APERTURE_DEG = 0.5358  # Mitsuba's sunsky default `sun_aperture` (degrees, full angle)


def _convex(shape) -> bool | None:
    """Whether a loaded mesh shape is convex (None: not a mesh)."""
    if shape is None or not shape.is_mesh():
        return None
    v = np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3)
    return convex_mesh(v, np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3))


def _unit(v) -> Vec3 | None:
    n = math.sqrt(sum(float(x) ** 2 for x in v))
    return None if not n > 0.0 else (float(v[0]) / n + 0.0, float(v[1]) / n + 0.0, float(v[2]) / n + 0.0)


def _floats(value) -> tuple[float, ...]:
    """A Mitsuba/Dr.Jit number or vector (scalar, or a JIT array of width 1) as plain floats."""
    return tuple(float(x) for x in np.asarray(value, dtype=float).ravel())


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


def _emitter(mi, node, props: dict, location: str, obj, shape=None) -> XmlEmitter:
    plugin = node.props.plugin_name()
    scale, scale_name = _scale(props)
    base = dict(type=plugin, id=node.props.id(), location=location, scale=scale, scale_name=scale_name)
    m = props.get("to_world")
    if shape is not None:  # an area emitter: its kind and size from the shape it sits on
        s_node, s_props, s_obj = shape
        s_plugin = s_node.props.plugin_name()
        kind = _AREA_ON.get(s_plugin, "area")
        extra: dict = {"shape": s_plugin, "file": resolved_file(mi, s_props.get("filename"))}
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
        extra = {"environment": True, "file": resolved_file(mi, props.get("filename"))}
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


def _check_normal_map(mi, shape, location: str) -> None:
    """Mitsuba's ``normalmap`` reads an RGB normal from its texture; a one-channel bitmap (a height map
    given by mistake) loads, then fails only inside a render ("was queried for a RGB value, but it is
    monochromatic") — in any later render of the process while the scene is alive, since a BSDF call
    traces every live BSDF (CI hit this: stop 51). Said at once, as one line."""
    params = mi.traverse(shape.bsdf())
    for key in params.keys():
        if key.endswith("normalmap.data"):
            channels = params[key].shape[-1]
            if channels != 3:
                raise XMLSceneError(
                    f'{location}: <bsdf type="normalmap">: its texture has {channels} channel(s); '
                    "a normal map is an RGB image (Mitsuba fails at render time with it)"
                )


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
    path, defines = normalised_source(path, defines)
    label = source_label(path)
    if up is not None and up not in UP_AXES:
        raise XMLSceneError(f"--up {up!r}: expected one of {', '.join(UP_AXES)}")
    with parsed_xml(path, defines, variant) as (mi, parser, config, state, unread):
        deps = collect_dependencies(mi, path, defines, state)
        config.merge_meshes = False  # keep the user's shapes one by one (counts, ids, emitters)
        config.merge_equivalent = False
        try:
            parser.transform_all(config, state)
            # (read before instantiating: instantiation consumes the nodes' references)
            nodes = list(state.nodes)
            props = [node_props(n) for n in nodes]
            where = [parser.file_location(state, n) for n in nodes]
            kind = {i: str(n.type).rsplit(".", 1)[-1] for i, n in enumerate(nodes)}
            check_nodes(mi, nodes, [kind[i] for i in range(len(nodes))], props, where, camera)
            scene = instantiate_checked(parser, config, state, unread)
        except RuntimeError as e:
            raise XMLSceneError(f"{label}: {mitsuba_error_text(e)}") from None
        except UnicodeDecodeError:  # Mitsuba's message quoted bytes of a data file that is not text
            raise XMLSceneError(f"{label}: {NOT_TEXT_ERROR}") from None
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
            if bump_plugin == "normalmap" and obj is not None:
                _check_normal_map(mi, obj, where[bsdf_node])
            plugin = nodes[i].props.plugin_name()
            filename = props[i].get("filename") if plugin in MESH_PLUGINS else None  # (a mesh's data file)
            shapes.append(
                XmlShape(
                    type=plugin,
                    id=nodes[i].props.id(),
                    location=where[i],
                    file=resolved_file(mi, filename),
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
        media_objs = medium_objects(
            of_type("Medium"), shape_nodes, shape_obj, of_type("Sensor"), sensor_objs, refs
        )
        cam_obj = sensor_objs[camera] if 0 <= camera < len(sensor_objs) else None
        emitters = [with_medium(mi, scene, cam_obj, e, media_objs) for e in emitters]
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
