"""Scene objects → a Mitsuba scene that holds only the plugins the scene declares.

`mitsuba_scene_dict` maps each declared part to its Mitsuba plugin and nothing else: no default
emitter, no BSDF on shapes that do not reflect, no medium plugins without media. `plugin_types`
lists the plugin types of a dict, so tests can check the "model only what a scene requires" rule.

Frames: the world is +Z up. Mitsuba's ``envmap`` is +Y up in its own frame, so it is rotated by
+90° about X (map +Y → world +Z), then by ``rotate_deg`` about world +Z. ``sunsky`` is +Z up already.
Mitsuba's ``directional`` takes the propagation direction, the scene's ``Sun`` the direction to the
sun: the sign flips here. Light geometry (sphere and rectangle lights, a sun of finite size) is
black: it emits, it does not reflect.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
import xml.etree.ElementTree as ET

import numpy as np

from rtfit.scenes.model import (
    Cube,
    Diffuse,
    HomogeneousMedium,
    Scene,
    Sphere,
)

from . import emitters, fog_integrator, height_fog
from .integrators import IntegratorChoice, choose_integrator
from .transforms import affine, frame_from_normal, rotation_matrix
from .variants import use_variant


# ------------------------------------------------------------------------------------ transforms
def _transform(mi, matrix: np.ndarray):
    return mi.ScalarTransform4f(matrix.tolist())


# ------------------------------------------------------------------------------------ plugin dicts
def _rgb(value) -> dict:
    return {"type": "rgb", "value": [float(c) for c in value]}


def _diffuse(material: Diffuse) -> dict:
    return {"type": "diffuse", "reflectance": _rgb(material.reflectance)}


_BLACK = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}


def _planar_to_world(center, normal, half_x, half_y, rotation_deg=0.0) -> np.ndarray:
    frame = frame_from_normal(normal, rotation_deg)
    return affine(frame @ np.diag([half_x, half_y, 1.0]), center)


def _shape_dict(mi, shape) -> dict:
    kind = shape.kind
    bsdf = _diffuse(shape.material)
    if kind == "sphere":
        return {"type": "sphere", "center": list(shape.center), "radius": shape.radius, "bsdf": bsdf}
    if kind == "rectangle":
        m = _planar_to_world(
            shape.center, shape.normal, shape.size[0] / 2, shape.size[1] / 2, shape.rotation_deg
        )
        # A rectangle too large for OptiX's float32 intersection near the world origin is built as its
        # `tiled_quad` (same plane, same orientation; `large_rectangle_mesh` says why and what was measured).
        tiled = large_rectangle_mesh(m)
        if tiled is not None:
            return {**tiled, "bsdf": bsdf}
        return {"type": "rectangle", "to_world": _transform(mi, m), "bsdf": bsdf}
    if kind == "disk":
        m = _planar_to_world(shape.center, shape.normal, shape.radius, shape.radius)
        return {"type": "disk", "to_world": _transform(mi, m), "bsdf": bsdf}
    if kind == "cube":
        lin = rotation_matrix(shape.rotate_axis, shape.rotate_deg) @ np.diag(np.asarray(shape.size) / 2)
        return {"type": "cube", "to_world": _transform(mi, affine(lin, shape.center)), "bsdf": bsdf}
    if kind == "cylinder":
        return {
            "type": "cylinder",
            "p0": list(shape.p0),
            "p1": list(shape.p1),
            "radius": shape.radius,
            "bsdf": bsdf,
        }
    if kind == "mesh":
        lin = rotation_matrix(shape.rotate_axis, shape.rotate_deg) @ np.diag(shape.scale)
        return {
            "type": os.path.splitext(shape.file)[1][1:].lower(),
            "filename": shape.file,
            "face_normals": shape.face_normals,
            "to_world": _transform(mi, affine(lin, shape.translate)),
            "bsdf": bsdf,
        }
    raise ValueError(f"unsupported shape kind {kind!r}")


def light_dicts(mi, light) -> dict:
    """Return ``{key_suffix: plugin dict}`` for one light (a shape light is one shape entry)."""
    kind = light.kind
    if kind == "sun":
        d = np.asarray(light.direction, dtype=np.float64)
        if light.angular_radius_deg == 0.0:
            return {
                "": {"type": "directional", "direction": (-d).tolist(), "irradiance": _rgb(light.irradiance)}
            }
        alpha = math.radians(light.angular_radius_deg)
        radiance = [e / (math.pi * math.sin(alpha) ** 2) for e in light.irradiance]
        return {
            "": {
                "type": emitters.PLUGIN,
                "direction": mi.ScalarVector3f(*d.tolist()),
                "angular_radius": alpha,
                "radiance": mi.ScalarVector3f(*radiance),
                "sky": mi.ScalarVector3f(0.0, 0.0, 0.0),
            }
        }
    if kind == "sphere_light":
        return {
            "": {
                "type": "sphere",
                "center": list(light.center),
                "radius": light.radius,
                "bsdf": _BLACK,
                "emitter": {"type": "area", "radiance": _rgb(light.radiance)},
            }
        }
    if kind == "rect_light":
        m = _planar_to_world(
            light.center, light.normal, light.size[0] / 2, light.size[1] / 2, light.rotation_deg
        )
        return {
            "": {
                "type": "rectangle",
                "to_world": _transform(mi, m),
                "bsdf": _BLACK,
                "emitter": {"type": "area", "radiance": _rgb(light.radiance)},
            }
        }
    if kind == "point_light":
        return {"": {"type": "point", "position": list(light.position), "intensity": _rgb(light.intensity)}}
    if kind == "spot_light":  # Mitsuba's spot points along its local +Z
        return {
            "": {
                "type": "spot",
                "to_world": _transform(mi, affine(frame_from_normal(light.axis), light.position)),
                "intensity": _rgb(light.intensity),
                "cutoff_angle": light.cutoff_angle_deg,
                "beam_width": light.beam_width_deg,
            }
        }
    if kind == "constant_env":
        return {"": {"type": "constant", "radiance": _rgb(light.radiance)}}
    if kind == "envmap":
        m = affine(rotation_matrix((0, 0, 1), light.rotate_deg) @ rotation_matrix((1, 0, 0), 90.0), (0, 0, 0))
        return {
            "": {
                "type": "envmap",
                "filename": light.file,
                "scale": light.scale,
                "to_world": _transform(mi, m),
            }
        }
    if kind == "sunsky":
        return {
            "": {
                "type": "sunsky",
                "sun_direction": list(light.sun_direction),
                "turbidity": light.turbidity,
                "albedo": light.albedo,
                "sun_scale": light.sun_scale,
                "sky_scale": light.sky_scale,
                "sun_aperture": light.sun_aperture_deg,
                "complex_sun": light.complex_sun,
            }
        }
    raise ValueError(f"unsupported light kind {kind!r}")


def _medium_dict(medium: HomogeneousMedium) -> dict:
    if medium.kind == "exponential_fog":  # rtfit's Python medium (rtfit.reference.height_fog)
        import mitsuba as mi  # mitsuba: the variant the caller selected (use_variant) is already active

        return height_fog.medium_dict(mi, medium)
    phase = {"type": "isotropic"} if medium.g == 0.0 else {"type": "hg", "g": medium.g}
    # Mitsuba reads an RGB `sigma_t` as a reflectance and refuses values above 1 (measured, 3.9: even a
    # grey 2); a denser medium is σ_t = scale·rgb, scale its largest channel (σ_t ≤ 1: the dict is unchanged).
    peak = max(medium.sigma_t)
    dense = {"sigma_t": _rgb([v / peak for v in medium.sigma_t]), "scale": peak} if peak > 1.0 else {}
    return {
        "type": "homogeneous",
        "sigma_t": _rgb(medium.sigma_t),
        "albedo": _rgb(medium.albedo),
        "phase": phase,
        **dense,
    }


# (axis of the outward normal, sign, first in-plane axis, second in-plane axis): a × b = sign · normal axis
_BOX_FACES = ((0, 1, 1, 2), (0, -1, 2, 1), (1, 1, 2, 0), (1, -1, 0, 2), (2, 1, 0, 1), (2, -1, 1, 0))
TILE_SIZE_FACTOR = 16.0
"""A boundary tile's edge is at most this × (1 + its smallest |p|∞ in scene units) (`box_boundary_mesh`)."""


def box_boundary_mesh(boundary) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, triangles (F, 3) int) of a box medium boundary, outward winding, each
    face tiled by a quadtree until every tile's edge is ≤ `TILE_SIZE_FACTOR`·(1 + r), r the smallest
    ∞-norm of the tile's points (a lower bound from its world bounding box).

    Why (issue 21 §1): Mitsuba offsets a ray leaving a surface point p by (1 + |p|∞)·8.9e-5 along the
    normal, but OptiX intersects triangles in float32 relative to their vertices, with errors of about
    1e-7 × the triangle's size. The box of the fog_terrain scene as Mitsuba's ``cube`` (or six
    ``rectangle``s, which Mitsuba 3.9 also turns into meshes and merges) has two 120 km triangles per
    face; where a face passes near the world origin (its bottom, 2 m under the camera) the error
    (~5 mm) exceeds the offset (0.7 mm at 7 m): a ray crossing the null boundary re-hits the same face
    at the same quantised point, forever (one lane in 8.4M on an H200: the kernel never returned). With
    tiles of at most 16·(1 + r) the error (≲ 4·6e-8·√2·16·(1 + r) = 5.4e-6·(1 + r)) stays about 16×
    below the offset everywhere, for a few hundred triangles (288 for fog_terrain). Quadtree tiles of
    different sizes meet in T-junctions: a ray through such a seam (float32 cracks) may miss the
    boundary; the medium then keeps its state for that path (rare; not a loop)."""
    rot = rotation_matrix(boundary.rotate_axis, boundary.rotate_deg)
    half = np.asarray(boundary.size, dtype=np.float64) / 2
    centre = np.asarray(boundary.center, dtype=np.float64)
    parts = []
    for axis, sign, a, b in _BOX_FACES:
        normal = sign * rot[:, axis]
        ea, eb = rot[:, a] * 2 * half[a], rot[:, b] * 2 * half[b]
        face_centre = centre + normal * half[axis]
        parts.append(tiled_quad(face_centre - ea / 2 - eb / 2, ea, eb))
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    triangles = [t + o for (_, t), o in zip(parts, offsets, strict=True)]
    return np.concatenate([v for v, _ in parts]), np.concatenate(triangles)


def tiled_quad(origin, ea, eb) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, triangles (F, 3) int) of the parallelogram origin + u·ea + v·eb (u, v ∈
    [0, 1]; normal ea × eb), tiled by a quadtree until every tile's edge is ≤ `TILE_SIZE_FACTOR`·(1 + r), r
    the smallest ∞-norm of the tile's points: the tiling of `box_boundary_mesh` (see there why: OptiX's
    float32 re-hits of large triangles near the world origin), for any large flat surface."""
    verts: list = []
    tris: list = []

    def tile(o, a, b, depth):
        corners = np.array([o, o + a, o + b, o + a + b])
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        r = float(np.max(np.maximum(np.maximum(lo, -hi), 0.0)))
        edge = max(float(np.linalg.norm(a)), float(np.linalg.norm(b)))
        if edge > TILE_SIZE_FACTOR * (1.0 + r) and depth < 40:
            for i in (0, 1):
                for j in (0, 1):
                    tile(o + i * a / 2 + j * b / 2, a / 2, b / 2, depth + 1)
            return
        k = len(verts)
        verts.extend(corners[[0, 1, 3, 2]])  # 00, 10, 11, 01
        tris.extend([(k, k + 1, k + 2), (k, k + 2, k + 3)])

    tile(np.asarray(origin, np.float64), np.asarray(ea, np.float64), np.asarray(eb, np.float64), 0)
    return np.asarray(verts), np.asarray(tris, dtype=np.int64)


def large_rectangle_mesh(to_world: np.ndarray) -> dict | None:
    """The ``obj`` shape dict of the rectangle [−1, 1]² × {0} under ``to_world`` (4×4) as its `tiled_quad`,
    or None where one tile covers it (the rectangle stays Mitsuba's ``rectangle``).

    Why (issue 21): OptiX intersects a triangle in float32 relative to its vertices, with errors of about
    1e-7 × its size, while Mitsuba offsets a ray leaving a surface by (1 + |p|∞)·8.9e-5. Measured on an
    NVIDIA H200 (`cuda_ad_rgb`, session 6, 2^24 rays per row): from points of fog_terrain's 120 km ground
    rectangle seen by a camera 2 m up, cosine-distributed bounce rays re-hit the plane itself — a false
    self-shadow — for 11.6 % of the points within 10 m of the camera, 0.43 % within 100 m and 4.4e-5
    within 1 km; the same plane as its tiled mesh (296 triangles): 0 in every row. Embree (LLVM): 0 for
    both. Same plane, same orientation (normal ea × eb = the rectangle's +z), same area."""
    m = np.asarray(to_world, dtype=np.float64)
    ea, eb = 2.0 * m[:3, 0], 2.0 * m[:3, 1]
    origin = m[:3, 3] - m[:3, 0] - m[:3, 1]
    vertices, triangles = tiled_quad(origin, ea, eb)
    if len(triangles) <= 2:
        return None
    return {"type": "obj", "filename": _mesh_file(vertices, triangles), "face_normals": True}


def tiled_quad_shape(origin, ea, eb) -> dict:
    """A Mitsuba shape dict (``obj``) of `tiled_quad`: a large plane that OptiX intersects without re-hits."""
    return {"type": "obj", "filename": _mesh_file(*tiled_quad(origin, ea, eb)), "face_normals": True}


def _mesh_file(vertices: np.ndarray, triangles: np.ndarray) -> str:
    """A Wavefront OBJ of the mesh in the temporary directory, named by its content (written once,
    atomically: concurrent builders write the same bytes)."""
    text = "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in vertices.tolist())
    text += "".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in triangles.tolist())
    folder = os.path.join(tempfile.gettempdir(), "rtfit-meshes")
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, hashlib.sha256(text.encode()).hexdigest()[:32] + ".obj")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    return path


def _boundary_dicts(mi, boundary) -> dict:
    """``{key_suffix: shape dict}`` of a medium's boundary (its null-BSDF transition surface): a box is
    the tiled mesh of `box_boundary_mesh` (see there why not Mitsuba's ``cube``); a sphere is Mitsuba's
    analytic ``sphere``."""
    if boundary.kind != "cube":
        return {"": _shape_dict(mi, boundary)}
    return {"": box_boundary_shape(boundary)}


def box_boundary_shape(boundary) -> dict:
    """The Mitsuba shape dict (``obj``) of `box_boundary_mesh`: a box medium's boundary that OptiX crosses
    without re-hits (add ``bsdf``/``interior`` to it); never Mitsuba's ``cube`` for a large box."""
    vertices, triangles = box_boundary_mesh(boundary)
    return {"type": "obj", "filename": _mesh_file(vertices, triangles), "face_normals": True}


def inside_boundary(boundary, point) -> bool:
    """True when ``point`` lies strictly inside a medium's ``boundary`` (a `Sphere` or a rotated `Cube`)."""
    return _inside(boundary, point)


def _inside(boundary, point) -> bool:
    p = np.asarray(point, dtype=np.float64)
    if isinstance(boundary, Sphere):
        return float(np.linalg.norm(p - np.asarray(boundary.center))) < boundary.radius
    if isinstance(boundary, Cube):
        rot = rotation_matrix(boundary.rotate_axis, boundary.rotate_deg)
        local = rot.T @ (p - np.asarray(boundary.center))
        return bool(np.all(np.abs(local) < np.asarray(boundary.size) / 2))
    raise ValueError(f"unsupported medium boundary {boundary.kind!r}")


def camera_dict(mi, camera) -> dict:
    to_world = mi.ScalarTransform4f().look_at(
        origin=list(camera.origin), target=list(camera.target), up=list(camera.up)
    )
    return {
        "type": "perspective",
        "fov": camera.fov_deg,
        "fov_axis": "x",
        "to_world": to_world,
        "near_clip": camera.near_clip,
        "far_clip": camera.far_clip,
        "film": {
            "type": "hdrfilm",
            "width": camera.width,
            "height": camera.height,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
        },
        "sampler": {"type": "independent"},
    }


# ------------------------------------------------------------------------------- Mitsuba XML input
_DROP_TOP_LEVEL = ("sensor", "integrator")


def _xml_shape_objects(mi, shape) -> list:
    """Load the shapes (and, if asked, the emitters) of a user's Mitsuba XML file.

    The file is edited before loading: its sensors and integrator are dropped, its emitters unless
    ``keep_emitters``, and with ``override_material`` every BSDF of a shape is replaced by ours.
    """
    tree = ET.parse(shape.file)
    root = tree.getroot()
    for child in list(root):
        if child.tag in _DROP_TOP_LEVEL or (child.tag == "emitter" and not shape.keep_emitters):
            root.remove(child)
    for elem in root.iter("shape"):
        for child in list(elem):
            if child.tag == "emitter" and not shape.keep_emitters:
                elem.remove(child)
            elif shape.override_material is not None and (
                child.tag == "bsdf"
                or (child.tag == "ref" and child.get("name") not in ("interior", "exterior"))
            ):
                elem.remove(child)
        if shape.override_material is not None:
            bsdf = ET.SubElement(elem, "bsdf", type="diffuse")
            r = shape.override_material.reflectance
            ET.SubElement(bsdf, "rgb", name="reflectance", value=f"{r[0]!r}, {r[1]!r}, {r[2]!r}")
    resolver = mi.file_resolver()  # (Thread.file_resolver is deprecated in 3.9)
    folder = os.path.dirname(shape.file)
    resolver.prepend(folder)
    try:
        loaded = mi.load_string(ET.tostring(root, encoding="unicode"))
    finally:
        # Remove what we prepended (the resolver is process-global state).
        paths = [str(resolver[i]) for i in range(len(resolver))]
        resolver.clear()
        dropped = False
        for p in paths:
            if not dropped and p == folder:
                dropped = True
                continue
            resolver.append(p)
    objects = list(loaded.shapes())
    if shape.keep_emitters:
        objects += [e for e in loaded.emitters() if not (e.flags() & int(mi.EmitterFlags.Surface))]
    return objects


# ------------------------------------------------------------------------------------- whole scene
def mitsuba_scene_dict(
    mi, scene: Scene, integrator: IntegratorChoice | None = None, fog_path: bool = True
) -> dict:
    """The ``mi.load_dict`` input for ``scene`` (``mi``: the mitsuba module with a variant set).

    A scene whose only medium is one exponential fog is rendered by `fog_integrator` (closed-form free
    flight; same paths as ``volpathmis``) unless ``fog_path`` is False: then by ``volpathmis`` with
    rtfit's fog medium (XML export, benches)."""
    integrator = integrator or choose_integrator(scene)
    d: dict = {
        "type": "scene",
        "integrator": integrator.mitsuba_dict(),
        "sensor": camera_dict(mi, scene.camera),
    }
    for i, shape in enumerate(scene.shapes):
        if shape.kind == "mitsuba_xml":
            for j, obj in enumerate(_xml_shape_objects(mi, shape)):
                d[f"xml{i}_{j}"] = obj
        else:
            d[f"shape{i}"] = _shape_dict(mi, shape)
    for i, light in enumerate(scene.lights):
        for suffix, plugin in light_dicts(mi, light).items():
            d[f"light{i}{suffix}"] = plugin
    _merge_environments(mi, scene, d)
    for i, medium in enumerate(scene.media):
        d[f"medium{i}"] = _medium_dict(medium)
        for suffix, boundary in _boundary_dicts(mi, medium.boundary).items():
            boundary["bsdf"] = {"type": "null"}
            boundary["interior"] = {"type": "ref", "id": f"medium{i}"}
            d[f"medium{i}_boundary{suffix}"] = boundary
        if _inside(medium.boundary, scene.camera.origin):
            d["sensor"]["medium"] = {"type": "ref", "id": f"medium{i}"}
    if fog_path and fog_integrator.applies(scene, d["integrator"]):
        return fog_integrator.scene_dict(mi, scene, d, int(d["integrator"]["max_depth"]))
    return d


def _merge_environments(mi, scene: Scene, d: dict) -> None:
    """Mitsuba takes one environment emitter: fold a constant sky into a finite sun's emitter."""
    suns = [k for k, v in d.items() if isinstance(v, dict) and v.get("type") == emitters.PLUGIN]
    envs = [
        k for k, v in d.items() if isinstance(v, dict) and v.get("type") in ("constant", "envmap", "sunsky")
    ]
    if len(suns) > 1:
        raise ValueError(
            f"{scene.source}: at most one sun with angular_radius_deg > 0 per scene "
            "(Mitsuba takes one environment emitter)"
        )
    if suns and envs:
        env = d[envs[0]]
        if env["type"] != "constant":
            raise ValueError(
                f"{scene.source}: a sun with angular_radius_deg > 0 cannot share a scene with "
                f"an {env['type']} environment (Mitsuba takes one environment emitter)"
            )
        d[suns[0]]["sky"] = mi.ScalarVector3f(*env["radiance"]["value"])
        del d[envs[0]]


def plugin_types(d) -> set[str]:
    """Every plugin ``type`` named in a scene dict, recursively (objects already loaded excluded)."""
    found: set[str] = set()

    def walk(x):
        if isinstance(x, dict):
            t = x.get("type")
            if isinstance(t, str) and t not in ("ref", "rgb"):
                found.add(t)
            for v in x.values():
                walk(v)

    walk(d)
    found.discard("scene")
    return found


def load_mitsuba_scene(
    scene: Scene, variant: str = "llvm_ad_rgb", integrator: IntegratorChoice | None = None
):
    """Build and load the Mitsuba scene for ``scene`` under ``variant``; returns ``(mi, mi_scene)``."""
    mi = use_variant(variant)
    return mi, load_dict(mi, mitsuba_scene_dict(mi, scene, integrator))


def load_dict(mi, d: dict):
    """``mi.load_dict`` with rtfit's own plugins registered and attached to the loaded scene."""
    emitters.register(mi)
    height_fog.register(mi)
    fog_integrator.register(mi)
    mi_scene = mi.load_dict(d)
    emitters.attach(mi_scene)
    return mi_scene
