"""rtfit.scenes: scene-file parsing, validation, serialisation round trips and the physics hash."""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.scenes import (
    Camera,
    ConstantEnv,
    Cube,
    Diffuse,
    HomogeneousMedium,
    ReferenceSettings,
    Scene,
    SceneError,
    Sphere,
    SphereLight,
    Sun,
    library_path,
    load_scene,
    parse_scene_text,
    scene_hash,
    scene_to_dict,
    scene_to_toml,
)
from rtfit.scenes.parse import SCHEMA

DATA = Path(__file__).parent / "data"
CAMERA = "[camera]\norigin = [0, -6, 0]\ntarget = [0, 0, 0]\nfov_deg = 24\nwidth = 32\nheight = 32\n"
BASE = 'name = "t"\n' + CAMERA


@pytest.fixture()
def files(tmp_path):
    """A folder with the test mesh, XML and a (fake, never decoded) EXR next to where scenes go."""
    for name in ("tri.obj", "tri.ply", "tiny.xml"):
        shutil.copy(DATA / name, tmp_path / name)
    (tmp_path / "sky.exr").write_bytes(b"not really an exr")
    return tmp_path


def parse(extra: str, base_dir=None, source="s.toml") -> Scene:
    return parse_scene_text(BASE + extra, source=source, base_dir=base_dir)


def assert_round_trip(scene: Scene) -> None:
    text = scene_to_toml(scene)
    again = parse_scene_text(text, source=scene.source)
    assert again == scene, text
    assert scene_hash(again) == scene_hash(scene)
    json.dumps(scene_to_dict(scene), allow_nan=False)  # plain data


# ------------------------------------------------------------------------------------- round trips
PARTS = {
    "sphere": '[[shapes]]\ntype = "sphere"\ncenter = [1, 2, 3]\nradius = 0.5\n'
    "material = { reflectance = [0.1, 0.2, 0.3] }",
    "rectangle": '[[shapes]]\ntype = "rectangle"\ncenter = [0, 0, -1]\nnormal = [0, 0, 2]\nsize = [4, 3]\n'
    'rotation_deg = 15\nmaterial = { type = "diffuse", reflectance = 0.25 }',
    "disk": '[[shapes]]\ntype = "disk"\ncenter = [0, 0, 1]\nnormal = [1, 1, 1]\nradius = 2',
    "cube": '[[shapes]]\ntype = "cube"\ncenter = [0, 0, 0]\nsize = [1, 2, 3]\nrotate_axis = [0, 1, 1]\n'
    "rotate_deg = 30",
    "cylinder": '[[shapes]]\ntype = "cylinder"\np0 = [0, 0, 0]\np1 = [0, 0, 2]\nradius = 0.3',
    "mesh_obj": '[[shapes]]\ntype = "mesh"\nfile = "tri.obj"\ntranslate = [1, 0, 0]\n'
    "rotate_axis = [1, 0, 0]\nrotate_deg = 90\nscale = [2, 2, 2]\nface_normals = true",
    "mesh_ply": '[[shapes]]\ntype = "mesh"\nfile = "tri.ply"',
    "mitsuba_xml": '[[shapes]]\ntype = "mitsuba_xml"\nfile = "tiny.xml"\nkeep_emitters = true\n'
    'override_material = { type = "diffuse", reflectance = 0.8 }',
    "mitsuba_xml_plain": '[[shapes]]\ntype = "mitsuba_xml"\nfile = "tiny.xml"',
    "sun": '[[lights]]\ntype = "sun"\ndirection = [1, 1, 1]\nirradiance = [3, 2, 1]\n'
    "angular_radius_deg = 0.27",
    "sphere_light": '[[lights]]\ntype = "sphere_light"\ncenter = [10, 0, 0]\nradius = 0.5\nradiance = 2',
    "rect_light": '[[lights]]\ntype = "rect_light"\ncenter = [0, 0, 3]\nnormal = [0, 0, -1]\nsize = [1, 2]\n'
    "radiance = [5, 5, 4]\nrotation_deg = 45",
    "point_light": '[[lights]]\ntype = "point_light"\nposition = [1, 2, 3]\nintensity = [4, 4, 2]',
    "spot_light": '[[lights]]\ntype = "spot_light"\nposition = [0, 0, 6]\naxis = [0, 0, -1]\n'
    "intensity = 100\ncutoff_angle_deg = 30\nbeam_width_deg = 22.5",
    "constant_env": '[[lights]]\ntype = "constant_env"\nradiance = 0.5',
    "envmap": '[[lights]]\ntype = "envmap"\nfile = "sky.exr"\nscale = 2\nrotate_deg = 90',
    "sunsky": '[[lights]]\ntype = "sunsky"\nsun_direction = [0, 1, 1]\nturbidity = 4\nalbedo = 0.2\n'
    "sun_scale = 0.5\nsky_scale = 2\nsun_aperture_deg = 1\ncomplex_sun = true",
    "homogeneous_cube": '[[media]]\ntype = "homogeneous"\nboundary = { type = "cube", center = [0, 0, 0], '
    "size = [2, 2, 2] }\nsigma_t = 0.5\nalbedo = 0.9\ng = 0.3",
    "homogeneous_sphere": '[[media]]\ntype = "homogeneous"\nsigma_t = [0.1, 0.2, 0.3]\n'
    'boundary = { type = "sphere", center = [0, 0, 0], radius = 3 }',
    "reference": '[reference]\ntransport = "global"\nmax_depth = 5',
}


@pytest.mark.parametrize("part", sorted(PARTS))
def test_round_trip_each_part(part, files):
    scene = parse(PARTS[part], base_dir=files)
    assert_round_trip(scene)


def test_round_trip_everything_in_one_file(files, monkeypatch):
    env = {"constant_env", "envmap", "sunsky"}
    text = BASE + "\n".join(v for k, v in PARTS.items() if k not in env) + "\n" + PARTS["envmap"]
    (files / "all.toml").write_text(text)
    monkeypatch.chdir(files.parent)  # relative to the file, not to the cwd
    scene = load_scene(files / "all.toml")
    assert scene.source == str(files / "all.toml")
    assert len(scene.shapes) == 9 and len(scene.lights) == 6 and len(scene.media) == 2
    assert_round_trip(scene)


def test_parsed_values_are_canonical(files):
    scene = parse(PARTS["rectangle"] + "\n" + PARTS["sun"] + "\n" + PARTS["homogeneous_cube"], base_dir=files)
    rect, sun, medium = scene.shapes[0], scene.lights[0], scene.media[0]
    assert rect.normal == (0.0, 0.0, 1.0) and rect.size == (4.0, 3.0)
    assert rect.material == Diffuse((0.25, 0.25, 0.25))
    assert sun.direction == pytest.approx((3**-0.5,) * 3) and math.isclose(math.hypot(*sun.direction), 1.0)
    assert all(type(c) is float for c in sun.irradiance) and sun.irradiance == (3.0, 2.0, 1.0)
    assert medium.boundary == Cube(center=(0.0, 0.0, 0.0), size=(2.0, 2.0, 2.0))
    assert medium.albedo == (0.9, 0.9, 0.9) and scene.reference == ReferenceSettings()  # defaults
    assert scene.camera.up == (0.0, 0.0, 1.0) and type(scene.camera.width) is int


def test_constructed_scene_round_trips():
    """A scene built in code (ints where floats go, numpy-free) serialises to the same canonical form."""
    scene = Scene(
        name="code",
        camera=Camera(origin=(0, -6, 0), target=(0, 0, 0)),
        shapes=(Sphere(center=(0, 0, 0), radius=1),),
        lights=(SphereLight(center=(20, 0, 0), radius=1.5, radiance=(2, 2, 2)),),
        media=(HomogeneousMedium(boundary=Sphere((0, 0, 0), 3), sigma_t=(1, 1, 1)),),
    )
    assert_round_trip(scene)
    floats = parse_scene_text(scene_to_toml(scene))
    assert scene_hash(floats) == scene_hash(scene)


finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
positive = st.floats(1e-6, 1e6)
vec = st.tuples(finite, finite, finite)
unit_rgb = st.tuples(*[st.floats(0, 1)] * 3)


@settings(max_examples=60, deadline=None)
@given(
    c=vec,
    r=positive,
    rho=unit_rgb,
    d=vec.filter(lambda v: max(map(abs, v)) > 1e-3),
    alpha=st.floats(0, 89.9),
    e=st.tuples(*[st.floats(0, 1e6)] * 3),
    g=st.floats(-0.99, 0.99),
)
def test_round_trip_random_values(c, r, rho, d, alpha, e, g):
    text = scene_to_toml(
        Scene(
            name="h",
            camera=Camera(origin=(0.0, -6.0, 0.0), target=(0.0, 0.0, 0.0)),
            shapes=(Sphere(center=c, radius=r, material=Diffuse(rho)),),
            lights=(Sun(direction=d, irradiance=e, angular_radius_deg=alpha),),
            media=(HomogeneousMedium(boundary=Sphere(c, r), sigma_t=e, g=g),),
        )
    )
    scene = parse_scene_text(text)  # normalises the sun direction
    assert_round_trip(scene)
    assert scene.shapes[0].center == c and scene.shapes[0].radius == r and scene.media[0].g == g


# ----------------------------------------------------------------------------------------- validation
N = 'name = "t"\n'
SPHERE = '+[[shapes]]\ntype = "sphere"\ncenter = [0, 0, 0]\n'
RECT = '+[[shapes]]\ntype = "rectangle"\ncenter = [0, 0, 0]\n'
MESH = '+[[shapes]]\ntype = "mesh"\n'
XML = '+[[shapes]]\ntype = "mitsuba_xml"\n'
LIGHT = '+[[lights]]\ntype = "sphere_light"\n'
PLACED = LIGHT + "direction = [1, 0, 0]\n"
SUN = '+[[lights]]\ntype = "sun"\ndirection = [0, 0, 1]\n'
SUNSKY = '+[[lights]]\ntype = "sunsky"\nsun_direction = [0, 0, 1]\n'
MEDIUM = '+[[media]]\ntype = "homogeneous"\nsigma_t = 1\n'
CUBE_MEDIUM = MEDIUM + 'boundary = { type = "cube", center = [0, 0, 0], size = [1, 1, 1] }\n'
CAM = N + CAMERA.replace("fov_deg = 24\n", "")


def cam(old: str, new: str) -> str:
    return N + CAMERA.replace(old, new)


INVALID = [  # (whole text, or "+" and what follows BASE), key path, reason fragment
    (N + "[camera\n", "", "not valid TOML: "),
    (CAMERA, "", "missing required key 'name'"),
    (N, "", "missing required key 'camera'"),
    ('name = ""\n' + CAMERA, "name", "must be a non-empty string"),
    ("name = 3\n" + CAMERA, "name", "must be a string (got 3)"),
    (
        "colour = 1\n" + BASE,
        "colour",
        "unknown key (expected one of: camera, description, lights, media, name, reference, shapes)",
    ),
    (N + "[camera]\ntarget = [0, 0, 1]\n", "camera", "missing required key 'origin'"),
    (CAM + "fov_deg = 0\n", "camera.fov_deg", "must be in (0, 180) (got 0)"),
    (CAM + "fov_deg = 180.0\n", "camera.fov_deg", "must be in (0, 180) (got 180.0)"),
    (CAM + "fov_deg = true\n", "camera.fov_deg", "must be a number (got true)"),
    (CAM + 'fov_deg = "24"\n', "camera.fov_deg", 'must be a number (got "24")'),
    (CAM + "fov_deg = nan\n", "camera.fov_deg", "must be finite (got nan)"),
    (CAM + 'type = "ortho"\n', "camera.type", 'unknown camera type "ortho" (expected one of: perspective)'),
    (cam("width = 32", "width = 32.0"), "camera.width", "must be an integer (got 32.0)"),
    (cam("width = 32", "width = 0"), "camera.width", "must be in [1, 16384] (got 0)"),
    (cam("height = 32", "height = 16385"), "camera.height", "must be in [1, 16384]"),
    (cam("[0, 0, 0]", "[0, -6, 0]"), "camera.target", "must differ from camera.origin"),
    (cam("[0, 0, 0]", "[0, 0]"), "camera.target", "must be an array of 3 numbers (got [0, 0])"),
    (cam("[0, 0, 0]", '[0, "a", 0]'), "camera.target[1]", 'must be a number (got "a")'),
    (BASE + "up = [0, 2, 0]\n", "camera.up", "must not be parallel to target - origin (got [0.0, 1.0, 0.0])"),
    (BASE + "up = [0, 0, 0]\n", "camera.up", "must be non-zero (got [0, 0, 0])"),
    (BASE + "origin2 = 1\n", "camera.origin2", "unknown key"),
    (BASE + "near_clip = 1\nfar_clip = 0.5\n", "camera.far_clip", "must be > near_clip"),
    (SPHERE + "radius = -1.0", "shapes[0].radius", "must be > 0 (got -1.0)"),
    (SPHERE + "radius = inf", "shapes[0].radius", "must be finite (got inf)"),
    (
        SPHERE + "radiu = 1",
        "shapes[0].radiu",
        "unknown key (expected one of: center, material, radius, type)",
    ),
    (SPHERE, "shapes[0]", "missing required key 'radius'"),
    (
        '+[[shapes]]\ntype = "torus"',
        "shapes[0].type",
        'unknown shape type "torus" (expected one of: cube, cylinder, disk, mesh, mitsuba_xml, rectangle, '
        "sphere)",
    ),
    ("+[[shapes]]\nradius = 1", "shapes[0]", "missing required key 'type'"),
    (N + "shapes = 1\n" + CAMERA, "shapes", "must be an array of tables"),
    (N + "shapes = [1]\n" + CAMERA, "shapes[0]", "must be a table (got 1)"),
    (SPHERE + "radius = 1\nmaterial = 0.5", "shapes[0].material", "must be a table (got 0.5)"),
    (
        SPHERE + 'radius = 1\nmaterial = { type = "glossy" }',
        "shapes[0].material.type",
        'unknown material type "glossy"',
    ),
    (
        SPHERE + "radius = 1\nmaterial = { reflectance = 1.5 }",
        "shapes[0].material.reflectance",
        "must be in [0, 1] (got 1.5)",
    ),
    (
        SPHERE + "radius = 1\nmaterial = { reflectance = [0.5, -0.1, 0] }",
        "shapes[0].material.reflectance[1]",
        "must be in [0, 1] (got -0.1)",
    ),
    (
        SPHERE + "radius = 1\nmaterial = { reflectance = [0.5, 0.5] }",
        "shapes[0].material.reflectance",
        "must be a number or an array of 3 numbers",
    ),
    (RECT + "normal = [0, 0, 0]\nsize = [1, 1]", "shapes[0].normal", "must be non-zero"),
    (RECT + "normal = [0, 0, 1]\nsize = [1, 0]", "shapes[0].size[1]", "must be > 0 (got 0)"),
    (RECT + "normal = [0, 0, 1]\nsize = [1, 1, 1]", "shapes[0].size", "must be an array of 2 numbers"),
    (
        '+[[shapes]]\ntype = "disk"\ncenter = [0, 0, 0]\nnormal = [0, 0, 1]\nradius = 0',
        "shapes[0].radius",
        "must be > 0",
    ),
    (
        '+[[shapes]]\ntype = "cube"\ncenter = [0, 0, 0]\nsize = [1, 1, 1]\nrotate_axis = [0, 0, 0]',
        "shapes[0].rotate_axis",
        "must be non-zero",
    ),
    ('+[[shapes]]\ntype = "cube"\ncenter = [0, 0, 0]\nsize = [1, -1, 1]', "shapes[0].size[1]", "must be > 0"),
    (
        '+[[shapes]]\ntype = "cylinder"\np0 = [0, 0, 1]\np1 = [0, 0, 1]\nradius = 1',
        "shapes[0].p1",
        "must differ from p0",
    ),
    (MESH + 'file = "missing.ply"', "shapes[0].file", "file not found: "),
    (MESH + 'file = "tri.stl"', "shapes[0].file", 'must be a .ply or .obj file (got "tri.stl")'),
    (MESH + 'file = "tri.obj"\nscale = [1, 0, 1]', "shapes[0].scale[1]", "must be > 0"),
    (MESH + 'file = "tri.obj"\nface_normals = 1', "shapes[0].face_normals", "must be true or false (got 1)"),
    (XML + 'file = "other.xml"', "shapes[0].file", "file not found"),
    (XML + 'file = "tri.obj"', "shapes[0].file", "must be a .xml file"),
    (
        XML + 'file = "tiny.xml"\noverride_material = { reflectance = 2 }',
        "shapes[0].override_material.reflectance",
        "must be in [0, 1]",
    ),
    (
        LIGHT + "center = [1, 0, 0]\nradius = 1\nradiance = nan",
        "lights[0].radiance",
        "must be finite (got nan)",
    ),
    (LIGHT + "center = [1, 0, 0]\nradius = 1\nradiance = -1", "lights[0].radiance", "must be >= 0 (got -1)"),
    (LIGHT + "center = [1, 0, 0]", "lights[0]", "missing required key 'radius'"),
    (
        PLACED + "distance = 10\nangular_radius_deg = 90",
        "lights[0].angular_radius_deg",
        "must be in (0, 90) (got 90)",
    ),
    (PLACED + "distance = 10\nangular_radius_deg = 0", "lights[0].angular_radius_deg", "must be in (0, 90)"),
    (PLACED + "distance = 0\nangular_radius_deg = 5", "lights[0].distance", "must be > 0"),
    (
        PLACED + "distance = 1e308\nangular_radius_deg = 5\ntarget = [1e308, 0, 0]",
        "lights[0].target[0]",  # finite, but beyond the limit of a coordinate: refused where it is read
        "must be within ±1e+08",
    ),
    (
        LIGHT + "direction = [0, 0, 0]\ndistance = 1\nangular_radius_deg = 5",
        "lights[0].direction",
        "must be non-zero",
    ),
    (PLACED + "angular_radius_deg = 5", "lights[0]", "missing required key 'distance'"),
    (
        PLACED + "center = [1, 0, 0]\ndistance = 1\nangular_radius_deg = 5",
        "lights[0].center",
        "cannot be combined with direction",
    ),
    ('+[[lights]]\ntype = "sun"\ndirection = [0, 0, 0]', "lights[0].direction", "must be non-zero"),
    (SUN + "irradiance = [1, -1, 1]", "lights[0].irradiance[1]", ">= 0"),
    (SUN + "angular_radius_deg = 90", "lights[0].angular_radius_deg", "must be in [0, 90) (got 90)"),
    (SUN + "angular_radius_deg = -1", "lights[0].angular_radius_deg", "must be in [0, 90)"),
    (SUN + "distance = 10", "lights[0].distance", "unknown key"),
    (
        '+[[lights]]\ntype = "rect_light"\ncenter = [0, 0, 0]\nnormal = [0, 0, 1]\nsize = [0, 1]',
        "lights[0].size[0]",
        "must be > 0",
    ),
    ('+[[lights]]\ntype = "envmap"\nfile = "sky.hdr"', "lights[0].file", "must be a .exr file"),
    ('+[[lights]]\ntype = "envmap"\nfile = "none.exr"', "lights[0].file", "file not found"),
    ('+[[lights]]\ntype = "envmap"\nfile = "sky.exr"\nscale = -1', "lights[0].scale", "must be >= 0"),
    (SUNSKY + "turbidity = 0.5", "lights[0].turbidity", "must be in [1, 10] (got 0.5)"),
    (SUNSKY + "turbidity = 11", "lights[0].turbidity", "must be in [1, 10]"),
    (SUNSKY + "albedo = 1.1", "lights[0].albedo", "must be in [0, 1]"),
    (SUNSKY + "sun_aperture_deg = 0", "lights[0].sun_aperture_deg", "must be in (0, 90)"),
    (SUNSKY + "sun_scale = -1", "lights[0].sun_scale", "must be >= 0"),
    (SUNSKY + "sky_scale = -0.5", "lights[0].sky_scale", "must be >= 0"),
    (SUNSKY + "complex_sun = 0", "lights[0].complex_sun", "must be true or false"),
    (
        '+[[lights]]\ntype = "constant_env"\n' + SUN[1:] + SUNSKY[1:],
        "lights[2]",
        "at most one environment light (constant_env, envmap, sunsky); lights[0] is one already",
    ),
    ('+[[lights]]\ntype = "laser"', "lights[0].type", 'unknown light type "laser"'),
    (CUBE_MEDIUM + "albedo = 1.2", "media[0].albedo", "must be in [0, 1] (got 1.2)"),
    (CUBE_MEDIUM + "g = 1", "media[0].g", "must be in (-1, 1) (got 1)"),
    (CUBE_MEDIUM + "g = -1.0", "media[0].g", "must be in (-1, 1)"),
    (CUBE_MEDIUM.replace("sigma_t = 1", "sigma_t = -0.5"), "media[0].sigma_t", "must be >= 0 (got -0.5)"),
    (
        MEDIUM + 'boundary = { type = "disk", center = [0, 0, 0], normal = [0, 0, 1], radius = 1 }',
        "media[0].boundary.type",
        'unknown boundary type "disk" (expected one of: cube, sphere)',
    ),
    (
        MEDIUM + 'boundary = { type = "sphere", center = [0, 0, 0], radius = 1, material = {} }',
        "media[0].boundary.material",
        "unknown key (expected one of: center, radius, type)",
    ),
    (MEDIUM, "media[0]", "missing required key 'boundary'"),
    ('+[[media]]\ntype = "fog"', "media[0].type", 'unknown medium type "fog"'),
    (
        '+[reference]\ntransport = "both"',
        "reference.transport",
        'must be one of: direct, global (got "both")',
    ),
    ('+[reference]\ntype = "x"', "reference.type", "unknown key (expected one of: max_depth, transport)"),
    ("+[reference]\nmax_depth = 0", "reference.max_depth", "must be -1 (unbounded) or >= 1 (got 0)"),
    ("+[reference]\nmax_depth = -2", "reference.max_depth", "must be -1 (unbounded) or >= 1"),
    ("+[reference]\nmax_depth = 4.0", "reference.max_depth", "must be an integer (got 4.0)"),
    (
        'description = """two\nlines"""\n' + BASE + '[reference]\nmax_depth = "x\\ny"',
        "reference.max_depth",
        'must be an integer (got "x\\ny")',
    ),
]


@pytest.mark.parametrize(
    "text,key,reason", INVALID, ids=[f"{i}:{k or 'file'}" for i, (_, k, _r) in enumerate(INVALID)]
)
def test_validation_errors_are_one_line(text, key, reason, files):
    text = BASE + text[1:] + "\n" if text.startswith("+") else text
    with pytest.raises(SceneError) as info:
        parse_scene_text(text, source="scenes/foo.toml", base_dir=files)
    e = info.value
    msg = str(e)
    assert "\n" not in msg and "\r" not in msg
    assert (e.source, e.key) == ("scenes/foo.toml", key), msg
    assert msg.startswith(f"scenes/foo.toml: {key}: " if key else "scenes/foo.toml: "), msg
    assert reason in msg


def test_every_model_field_has_a_spec():
    for cls, specs in SCHEMA.items():
        assert list(specs) == [f.name for f in dataclasses.fields(cls)], cls.__name__


def test_load_errors(tmp_path):
    with pytest.raises(SceneError, match=r"^\S*nope\.toml: cannot read scene file \(No such file"):
        load_scene(tmp_path / "nope.toml")
    (tmp_path / "bad.toml").write_bytes(b'name = "\xff"\n')
    with pytest.raises(SceneError, match=r"bad\.toml: not valid UTF-8"):
        load_scene(tmp_path / "bad.toml")
    err = pickle.loads(pickle.dumps(SceneError.at("f.toml", "camera", "boom")))
    assert (str(err), err.key) == ("f.toml: camera: boom", "camera")


# ---------------------------------------------------------------------------------------- placement
def test_sphere_light_placed_by_direction():
    scene = parse(
        LIGHT[1:] + "target = [1, 2, 3]\ndirection = [0, 3, 4]\ndistance = 10\nangular_radius_deg = 30"
    )
    light = scene.lights[0]
    assert light.center == pytest.approx((1.0, 8.0, 11.0), abs=1e-12)  # target + 10·(0, 0.6, 0.8)
    assert light.radius == pytest.approx(5.0, abs=1e-12)  # 10·sin 30°
    assert light.radiance == (1.0, 1.0, 1.0)
    light = parse(LIGHT[1:] + "direction = [0, 0, -2]\ndistance = 4\nangular_radius_deg = 45").lights[0]
    assert light.center == (0.0, 0.0, -4.0) and light.radius == pytest.approx(2 * math.sqrt(2))
    assert "direction" not in scene_to_toml(scene) and "center = [" in scene_to_toml(scene)


# ------------------------------------------------------------------------------------------- paths
def test_relative_paths_resolve_against_the_scene_file(tmp_path, monkeypatch):
    (tmp_path / "sub" / "meshes").mkdir(parents=True)
    shutil.copy(DATA / "tri.obj", tmp_path / "sub" / "meshes" / "tri.obj")
    mesh = '[[shapes]]\ntype = "mesh"\nfile = "meshes/../meshes/tri.obj"\n'
    (tmp_path / "sub" / "scene.toml").write_text(BASE + mesh)
    monkeypatch.chdir(tmp_path)
    expected = str(tmp_path / "sub" / "meshes" / "tri.obj")
    assert load_scene("sub/scene.toml").shapes[0].file == expected
    assert load_scene("sub/scene.toml").source == "sub/scene.toml"
    text = BASE + '[[shapes]]\ntype = "mesh"\nfile = "meshes/tri.obj"\n'
    assert parse_scene_text(text, base_dir=tmp_path / "sub").shapes[0].file == expected
    monkeypatch.chdir(tmp_path / "sub")  # text without base_dir: relative to the cwd
    assert parse_scene_text(text).shapes[0].file == expected
    absolute = BASE + f'[[shapes]]\ntype = "mesh"\nfile = "{expected}"\n'
    assert parse_scene_text(absolute, base_dir="/").shapes[0].file == expected


# -------------------------------------------------------------------------------------------- hash
def test_hash_is_stable_and_ignores_labels(files):
    text = BASE + PARTS["sphere"] + "\n" + PARTS["sphere_light"] + "\n" + PARTS["mesh_obj"]
    a = parse_scene_text(text, base_dir=files)
    b = parse_scene_text(text, base_dir=files)
    h = scene_hash(a)
    assert len(h) == 64 and int(h, 16) >= 0
    assert scene_hash(b) == h and scene_hash(parse_scene_text(scene_to_toml(a))) == h
    relabelled = dataclasses.replace(a, name="other", description="words", source="elsewhere.toml")
    assert scene_hash(relabelled) == h
    code = [
        sys.executable,
        "-c",
        "import sys; from rtfit.scenes import parse_scene_text, scene_hash; "
        "print(scene_hash(parse_scene_text(sys.stdin.read())))",
    ]
    out = subprocess.run(code, input=scene_to_toml(a), capture_output=True, text=True, check=True)
    assert out.stdout.strip() == h  # same in a fresh process (no hash randomisation leaks in)


@pytest.mark.parametrize(
    "change",
    [
        lambda s: dataclasses.replace(s, shapes=(dataclasses.replace(s.shapes[0], radius=1.0000001),)),
        lambda s: dataclasses.replace(s, shapes=(Sphere((0, 0, 0), 1.0, Diffuse((0.5, 1, 1))),)),
        lambda s: dataclasses.replace(s, lights=(dataclasses.replace(s.lights[0], irradiance=(1, 1, 2)),)),
        lambda s: dataclasses.replace(
            s, lights=(dataclasses.replace(s.lights[0], angular_radius_deg=5.001),)
        ),
        lambda s: dataclasses.replace(s, lights=(*s.lights, ConstantEnv())),
        lambda s: dataclasses.replace(s, camera=dataclasses.replace(s.camera, width=64)),
        lambda s: dataclasses.replace(s, camera=dataclasses.replace(s.camera, fov_deg=25.0)),
        lambda s: dataclasses.replace(s, reference=ReferenceSettings("global")),
        lambda s: dataclasses.replace(s, reference=ReferenceSettings("direct", max_depth=3)),
        lambda s: dataclasses.replace(
            s, media=(HomogeneousMedium(Sphere((0, 0, 0), 2.0), sigma_t=(0.1,) * 3),)
        ),
    ],
    ids=[
        "radius",
        "reflectance",
        "irradiance",
        "sun_size",
        "env",
        "width",
        "fov",
        "transport",
        "max_depth",
        "medium",
    ],
)
def test_hash_sees_physical_changes(change):
    scene = load_scene(library_path("half_lambert_sphere"))
    assert scene_hash(change(scene)) != scene_hash(scene)


@pytest.mark.parametrize(
    "part,edited",
    [("mesh_obj", "tri.obj"), ("envmap", "sky.exr"), ("mitsuba_xml", "tiny.xml"), ("mitsuba_xml", "tri.obj")],
)
def test_hash_follows_file_contents(part, edited, files, tmp_path_factory):
    scene = parse(PARTS[part], base_dir=files)
    before = scene_hash(scene)
    moved = tmp_path_factory.mktemp("moved")
    for f in files.iterdir():
        shutil.copy(f, moved / f.name)
    assert scene_hash(parse(PARTS[part], base_dir=moved)) == before  # same contents elsewhere
    with open(files / edited, "ab") as f:  # tri.obj is referenced by tiny.xml
        f.write(b"\n# edited\n")
    assert scene_hash(scene) != before


def test_hash_of_a_deleted_file_is_a_scene_error(files):
    scene = parse(PARTS["mesh_ply"], base_dir=files)
    (files / "tri.ply").unlink()
    with pytest.raises(SceneError, match=r"^s\.toml: shapes\[0\]\.file: cannot read .*tri\.ply"):
        scene_hash(scene)


def test_hash_value_is_pinned():
    """Changing this value invalidates every reference cache: bump HASH_FORMAT deliberately if so."""
    scene = load_scene(library_path("white_furnace_sphere"))
    assert scene_hash(scene) == "6efdaa0a2109abff2a625a5167e475f19f73e1db8dcbae7464adf5201b4935b8"


# ----------------------------------------------------------------------------------------- library
def test_library_scenes():
    hl = load_scene(library_path("half_lambert_sphere"))
    assert hl.shapes == (Sphere((0.0, 0.0, 0.0), 1.0, Diffuse((1.0, 1.0, 1.0))),)
    assert hl.camera == Camera((0.0, -6.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 24.0, 128, 128)
    assert hl.reference.transport == "direct"
    (light,) = hl.lights
    assert light == Sun(direction=(1.0, 0.0, 0.0), irradiance=(math.pi,) * 3, angular_radius_deg=5.0)
    wf = load_scene(library_path("white-furnace-sphere.toml"))
    assert wf.lights == (ConstantEnv((1.0, 1.0, 1.0)),) and wf.reference.transport == "global"
    assert (wf.shapes, wf.camera) == (hl.shapes, hl.camera)
    with pytest.raises(SceneError, match=r'no library scene named "nope" \(available: .*half_lambert_sphere'):
        library_path("nope")


def test_a_sky_file_is_named_as_such_not_parsed_as_a_scene():
    from rtfit.scenes import SceneError, library_path, load_scene

    with pytest.raises(
        SceneError,
        match=r"format: a 'rtfit\.sky/1' file, not a scene: read it with "
        r"rtfit\.reference\.nishita_sky\.load_atmosphere_scene",
    ):
        load_scene(library_path("sky_sun_10"))
