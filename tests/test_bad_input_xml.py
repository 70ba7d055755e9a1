"""Bad Mitsuba XML scenes, mesh files and ``--approx`` files (issue 32): each is one ``rtfit: error:`` line
naming the file (and the element, key and range where there is one), exit status 2, no traceback, nothing
under ``--out`` or in the cache — found before anything renders (`rtfit.reference.xml_checks`: the values
Mitsuba accepted, checked like a TOML scene's; a pre-scan before Mitsuba's parser, which crashes on deep
nesting; mesh files checked before Mitsuba loads them). Each case runs the full ``rtfit audit`` command at
8×8 pixels and 2 spp, so that a case refused too late would show as written files, and one accepted by
mistake would show as exit 0."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import pytest

from rtfit.experiments.cli import main
from rtfit.reference.xml_checks import MAX_DEPTH

SENSOR = """<sensor type="perspective">
    <float name="fov" value="30"/>
    <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
</sensor>"""
SPHERE = '<shape type="sphere"><float name="radius" value="1"/></shape>'
LIGHT = (
    '<emitter type="point"><point name="position" x="0" y="-4" z="4"/>'
    '<rgb name="intensity" value="10"/></emitter>'
)


def scene(*elements: str, sensor: str = SENSOR, version: str = "3.0.0", shapes: str = SPHERE) -> str:
    """A valid little scene (a perspective camera, a unit sphere, a point light) with ``elements`` added."""
    body = "\n".join((sensor, shapes, LIGHT, *elements))
    return f'<scene version="{version}">\n{textwrap.indent(body, "    ")}\n</scene>\n'


def sensor_with(
    fov: str = "30", width: str = "8", height: str = "8", extra: str = "", kind: str = "perspective"
):
    return f"""<sensor type="{kind}">
    <float name="fov" value="{fov}"/>{extra}
    <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
    <film type="hdrfilm">
        <integer name="width" value="{width}"/><integer name="height" value="{height}"/>
    </film>
</sensor>"""


def refuse(capsys, tmp_path: Path, scene_file: Path, *extra: str) -> str:
    """``rtfit audit scene_file`` (8×8, 2 spp): exit 2, one ``rtfit: error:`` line, nothing written."""
    out, cache = tmp_path / "out", tmp_path / "cache"
    argv = ["audit", str(scene_file), "--out", str(out), "--cache", str(cache), "--no-fit", "--no-progress"]
    argv += ["--width", "8", "--height", "8", "--spp", "2", "--pass-spp", "2", *extra]
    rc = main(argv)
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert rc == 2, cap.err
    assert len(lines) == 1, cap.err
    assert lines[0].startswith("rtfit: error: "), cap.err
    assert "Traceback" not in cap.err and "Traceback" not in cap.out
    assert not out.exists()
    assert not cache.exists() or not any(cache.rglob("*"))
    return lines[0]


def write(tmp_path: Path, text: str | bytes, name: str = "s.xml") -> Path:
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


# ------------------------------------------------------------------------------------------ values
def _sphere(radius="1", center="0, 0, 0", inner=""):
    x, y, z = (c.strip() for c in center.split(","))
    return (
        f'<shape type="sphere"><point name="center" x="{x}" y="{y}" z="{z}"/>'
        f'<float name="radius" value="{radius}"/>{inner}</shape>'
    )


def _area(radiance: str) -> str:
    return f'<emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter>'


def _on(plugin: str, transform: str, inner: str = "") -> str:
    return f'<shape type="{plugin}"><transform name="to_world">{transform}</transform>{inner}</shape>'


VALUES = {
    # shapes
    "sphere radius nan": (_sphere("nan"), "radius: must be finite (got nan)"),
    "sphere radius inf": (_sphere("inf"), "radius: must be finite (got inf)"),
    "sphere radius -inf": (_sphere("-inf"), "radius: must be finite"),
    "sphere radius 0": (_sphere("0"), "radius: must be > 0 (got 0)"),
    "sphere radius -1": (_sphere("-1"), "radius: must be > 0 (got -1)"),
    "sphere radius 1e39": (_sphere("1e39"), "radius: must be within ±1e+08"),
    "sphere radius 1e9": (_sphere("1e9"), "radius: must be within ±1e+08"),
    "sphere centre x nan": (_sphere(center="nan, 0, 0"), "center: must be finite"),
    "sphere centre x 1e308": (_sphere(center="1e308, 0, 0"), "center: must be within ±1e+08"),
    "sphere centre z -1e9": (_sphere(center="0, 0, -1e9"), "center: must be within ±1e+08"),
    "sphere centre y inf": (_sphere(center="0, inf, 0"), "center: must be finite"),
    "cylinder radius 0": (
        '<shape type="cylinder"><float name="radius" value="0"/></shape>',
        "radius: must be > 0",
    ),
    "cylinder p1 1e300": (
        '<shape type="cylinder"><point name="p1" x="0" y="0" z="1e300"/></shape>',
        "p1: must be within ±1e+08",
    ),
    "sphere scale 0": (_on("sphere", '<scale value="0"/>'), "to_world: must not be singular"),
    "rectangle scale 0": (_on("rectangle", '<scale value="0"/>'), "to_world: must not be singular"),
    "cube scale x 0": (_on("cube", '<scale x="0" y="1" z="1"/>'), "to_world: must not be singular"),
    "disk scale 0": (_on("disk", '<scale value="0"/>'), "to_world: must not be singular"),
    "sphere scale nan": (_on("sphere", '<scale value="nan"/>'), "to_world: must be finite"),
    "sphere translate 1e308": (
        _on("sphere", '<translate x="1e308"/>'),
        "to_world translation: must be within",
    ),
    "sphere translate nan": (_on("sphere", '<translate y="nan"/>'), "to_world: must be finite"),
    "cube scale 1e9": (_on("cube", '<scale value="1e9"/>'), "to_world matrix: must be within ±1e+08"),
    "rectangle matrix inf": (
        _on("rectangle", '<matrix value="1 0 0 0 0 1 0 0 0 0 inf 0 0 0 0 1"/>'),
        "to_world: must be finite",
    ),
    "rectangle matrix all zero": (
        _on("rectangle", '<matrix value="0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1"/>'),
        "must not be singular",
    ),
    "sphere rotate then scale 0": (
        _on("sphere", '<rotate x="1" angle="30"/><scale value="0"/>'),
        "must not be singular",
    ),
    # area lights
    "area radiance negative": (
        _sphere(center="3, 0, 0", inner=_area("-40, -38, -34")),
        "radiance: must be >= 0",
    ),
    "area radiance -1 grey": (
        _sphere(center="3, 0, 0", inner=_area("-1")),
        "radiance: must be >= 0 (got (-1",
    ),
    "area radiance nan": (_sphere(center="3, 0, 0", inner=_area("nan")), "radiance: must be finite"),
    "area radiance inf": (_sphere(center="3, 0, 0", inner=_area("1, inf, 1")), "radiance: must be finite"),
    "area radiance 1e13": (_sphere(center="3, 0, 0", inner=_area("1e13")), "radiance: must be within ±1e+12"),
    "area light on a zero-size sphere": (_sphere("0", "3, 0, 0", _area("1")), "radius: must be > 0"),
    "area light on a zero-size rectangle": (
        _on("rectangle", '<scale value="0"/>', _area("1")),
        "must not be singular",
    ),
    "area light on a flat cube": (_on("cube", '<scale z="0"/>', _area("1")), "must not be singular"),
    # free emitters
    "point intensity -5 float": (
        '<emitter type="point"><float name="intensity" value="-5"/></emitter>',
        "intensity: must be >= 0 (got -5)",
    ),
    "point intensity -5 spectrum": (
        '<emitter type="point"><spectrum name="intensity" value="-5"/></emitter>',
        "intensity: must be >= 0",
    ),
    "point intensity inf": (
        '<emitter type="point"><rgb name="intensity" value="inf"/></emitter>',
        "intensity: must be finite",
    ),
    "point intensity nan": (
        '<emitter type="point"><float name="intensity" value="nan"/></emitter>',
        "intensity: must be finite",
    ),
    "point intensity 1e13": (
        '<emitter type="point"><float name="intensity" value="1e13"/></emitter>',
        "intensity: must be within ±1e+12",
    ),
    "point position nan": (
        '<emitter type="point"><point name="position" x="nan" y="0" z="0"/></emitter>',
        "position: must be finite",
    ),
    "point position 1e308": (
        '<emitter type="point"><point name="position" x="1e308" y="0" z="0"/></emitter>',
        "position: must be within ±1e+08",
    ),
    "spot intensity -1": (
        '<emitter type="spot"><float name="intensity" value="-1"/></emitter>',
        "intensity: must be >= 0",
    ),
    "directional direction 0": (
        '<emitter type="directional"><vector name="direction" x="0" y="0" z="0"/>'
        '<rgb name="irradiance" value="3"/></emitter>',
        "direction: must be non-zero (got (0, 0, 0))",
    ),
    # BSDFs: a numeric index of refraction (Mitsuba takes 0, then the render fails on NaN)
    "dielectric int_ior 0": (
        '<shape type="sphere"><bsdf type="dielectric"><float name="int_ior" value="0"/></bsdf></shape>',
        '<bsdf type="dielectric"> int_ior: must be in [1, 10] (got 0)',
    ),
    "roughplastic ext_ior -1": (
        '<shape type="sphere"><bsdf type="roughplastic"><float name="ext_ior" value="-1"/></bsdf></shape>',
        "ext_ior: must be in [1, 10]",
    ),
    "spot cutoff 0": (
        '<emitter type="spot"><float name="cutoff_angle" value="0"/></emitter>',
        "cutoff_angle: must be in (0, 90]",
    ),
    "spot cutoff 100": (
        '<emitter type="spot"><float name="cutoff_angle" value="100"/></emitter>',
        "cutoff_angle: must be in (0, 90]",
    ),
    "spot beam width -1": (
        '<emitter type="spot"><float name="beam_width" value="-1"/></emitter>',
        "beam_width: must be in (0, 90]",
    ),
    "spot to_world scale 0": (
        '<emitter type="spot"><transform name="to_world"><scale value="0"/></transform></emitter>',
        "must not be singular",
    ),
    "directional irradiance -1": (
        '<emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/>'
        '<rgb name="irradiance" value="-1"/></emitter>',
        "irradiance: must be >= 0",
    ),
    "directional irradiance inf": (
        '<emitter type="directional"><rgb name="irradiance" value="inf"/></emitter>',
        "irradiance: must be finite",
    ),
    "directional direction nan": (
        '<emitter type="directional"><vector name="direction" x="nan" y="0" z="-1"/></emitter>',
        "direction: must be finite",
    ),
    "constant radiance -1": (
        '<emitter type="constant"><rgb name="radiance" value="-1"/></emitter>',
        "radiance: must be >= 0",
    ),
    "constant radiance nan": (
        '<emitter type="constant"><rgb name="radiance" value="nan"/></emitter>',
        "radiance: must be finite",
    ),
    "envmap scale -1": (
        '<emitter type="envmap"><string name="filename" value="sky.exr"/>'
        '<float name="scale" value="-1"/></emitter>',
        "scale: must be >= 0",
    ),
    "sunsky sun_scale -1": (
        '<emitter type="sunsky"><float name="sun_scale" value="-1"/></emitter>',
        "sun_scale: must be >= 0",
    ),
    "sunsky sky_scale nan": (
        '<emitter type="sunsky"><float name="sky_scale" value="nan"/></emitter>',
        "sky_scale: must be finite",
    ),
    # materials and media
    "diffuse reflectance 1.5": (
        '<bsdf type="diffuse" id="b"><rgb name="reflectance" value="1.5"/></bsdf>',
        "reflectance: must be in [0, 1]",
    ),
    "diffuse reflectance -0.1": (
        '<bsdf type="diffuse" id="b"><float name="reflectance" value="-0.1"/></bsdf>',
        "reflectance: must be in [0, 1]",
    ),
    "diffuse reflectance nan": (
        '<bsdf type="diffuse" id="b"><rgb name="reflectance" value="nan"/></bsdf>',
        "reflectance: must be finite",
    ),
    "conductor roughness 1e300": (
        '<bsdf type="roughconductor" id="b"><float name="alpha" value="1e300"/></bsdf>',
        "alpha: must be within ±1e+12",
    ),
    "medium sigma_t -1": (
        '<medium type="homogeneous" id="m"><rgb name="sigma_t" value="-1"/></medium>',
        "sigma_t: must be >= 0",
    ),
    "medium sigma_t 1e7": (
        '<medium type="homogeneous" id="m"><float name="sigma_t" value="1e7"/></medium>',
        "sigma_t: must be within ±1e+06",
    ),
    "medium albedo 2": (
        '<medium type="homogeneous" id="m"><rgb name="albedo" value="2"/></medium>',
        "albedo: must be in [0, 1]",
    ),
    "medium scale -1": (
        '<medium type="homogeneous" id="m"><float name="scale" value="-1"/></medium>',
        "scale: must be >= 0",
    ),
}


@pytest.mark.parametrize(("element", "says"), list(VALUES.values()), ids=list(VALUES))
def test_xml_value_out_of_range(capsys, tmp_path, element, says):
    line = refuse(capsys, tmp_path, write(tmp_path, scene(element)))
    assert says in line
    assert str(tmp_path / "s.xml") in line and "(line " in line  # the file and the line


SENSORS = {
    "fov 0": (sensor_with(fov="0"), "fov: must be in (0, 180)"),
    "fov 180": (sensor_with(fov="180"), "fov: must be in (0, 180)"),
    "fov -10": (sensor_with(fov="-10"), "fov: must be in (0, 180)"),
    "fov nan": (sensor_with(fov="nan"), "fov: must be finite"),
    "fov 1e9": (sensor_with(fov="1e9"), "fov: must be in (0, 180)"),
    "film width 0": (sensor_with(width="0"), "width: must be in [1, 16384]"),
    "film width -1": (sensor_with(width="-1"), "width: must be in [1, 16384]"),
    "film width 100000": (sensor_with(width="100000"), "width: must be in [1, 16384]"),
    "film height 0": (sensor_with(height="0"), "height: must be in [1, 16384]"),
    "film height 20000": (sensor_with(height="20000"), "height: must be in [1, 16384]"),
    "near_clip 0": (sensor_with(extra='<float name="near_clip" value="0"/>'), "near_clip: must be > 0"),
    "near_clip -1": (sensor_with(extra='<float name="near_clip" value="-1"/>'), "near_clip: must be > 0"),
    "far_clip nan": (sensor_with(extra='<float name="far_clip" value="nan"/>'), "far_clip: must be finite"),
    "orthographic": (sensor_with(kind="orthographic"), 'sensor type="orthographic">: the audit supports'),
    "thinlens": (sensor_with(kind="thinlens"), 'sensor type="thinlens">: the audit supports perspective'),
    "radiancemeter": (
        '<sensor type="radiancemeter"><film type="hdrfilm"><integer name="width" value="1"/>'
        '<integer name="height" value="1"/></film></sensor>',
        'type="radiancemeter">: the audit supports perspective',
    ),
    "sensor to_world scale 0": (
        sensor_with(extra='<transform name="to_world"><scale value="0"/></transform>').replace(
            '<transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/>'
            "</transform>",
            "",
        ),
        "to_world: must not be singular",
    ),
}


@pytest.mark.parametrize(("sensor", "says"), list(SENSORS.values()), ids=list(SENSORS))
def test_xml_sensor_out_of_range(capsys, tmp_path, sensor, says):
    line = refuse(capsys, tmp_path, write(tmp_path, scene(sensor=sensor)))
    assert says in line and str(tmp_path / "s.xml") in line


def test_the_orthographic_sensor_need_not_be_the_chosen_one(capsys, tmp_path):
    """Only the sensor the audit uses must be perspective: --camera 1 on an orthographic one is refused,
    --camera 0 (perspective) is not refused for sensor 1's type (here refused for another reason: -D)."""
    ortho = sensor_with(kind="orthographic").replace('<float name="fov" value="30"/>', "")  # (it has no fov:
    both = scene(sensor=SENSOR + "\n" + ortho)  # Mitsuba refuses the property as unreferenced)
    path = write(tmp_path, both)
    line = refuse(capsys, tmp_path, path, "--camera", "1")
    assert "orthographic" in line and "sensor 1" in line
    rc = main(["audit", str(path), "--list"])
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()


VERSIONS = {
    "99.0.0": "must be <= ",
    "3.10.0": "must be <= ",
    "4.0.0": "must be <= ",
    "3.9.2": "must be <= ",
    "abc": "must be major.minor.patch",
    "3.0": "must be major.minor.patch",
    "3.0.0.0": "must be major.minor.patch",
    "-1.0.0": "must be major.minor.patch",
    "": "must be major.minor.patch",
    "3.0.x": "must be major.minor.patch",
}


@pytest.mark.parametrize(
    ("version", "says"), list(VERSIONS.items()), ids=[f"v{v or 'empty'}" for v in VERSIONS]
)
def test_xml_scene_version(capsys, tmp_path, version, says):
    line = refuse(capsys, tmp_path, write(tmp_path, scene(version=version)))
    assert says in line and "<scene version=" in line and str(tmp_path / "s.xml") in line


# --------------------------------------------------------------------------------------- structure
def _nested(n: int, tag: str = "bsdf") -> str:
    opening = f'<{tag} type="twosided">' * n
    return f'<shape type="sphere">{opening}<bsdf type="diffuse"/>{f"</{tag}>" * n}</shape>'


def _include(name: str) -> str:
    return f'<include filename="{name}"/>'


STRUCTURE = {
    "10000 nested bsdf": (lambda d: write(d, scene(_nested(10_000))), f"must be <= {MAX_DEPTH}"),
    "depth limit + 1": (lambda d: write(d, scene(_nested(MAX_DEPTH))), "nested 65 deep"),
    "100000 nested bsdf": (lambda d: write(d, scene(_nested(100_000))), "Mitsuba's parser crashes"),
    "deep nesting in an include": (
        lambda d: (
            write(d, f'<scene version="3.0.0">{_nested(5000)}</scene>', "deep.xml"),
            write(d, scene(_include("deep.xml"))),
        )[1],
        "deep.xml",
    ),
    "include cycle": (
        lambda d: (
            write(d, f'<scene version="3.0.0">{_include("s.xml")}</scene>', "b.xml"),
            write(d, scene(_include("b.xml"))),
        )[1],
        "includes itself",
    ),
    "self include": (lambda d: write(d, scene(_include("s.xml"))), "includes itself"),
    "entity declaration": (
        lambda d: write(d, '<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaa">]>' + scene()),
        "entity declaration 'a'",
    ),
    "billion laughs": (
        lambda d: write(
            d,
            '<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaaaaaaaa">'
            + "".join(f'<!ENTITY a{i} "{("&a;" if i == 0 else f"&a{i - 1};") * 10}">' for i in range(9))
            + "]>"
            + scene().replace('value="30"', 'value="&a8;"'),
        ),
        "entity declaration",
    ),
    "external entity": (
        lambda d: write(d, '<?xml version="1.0"?><!DOCTYPE s [<!ENTITY x SYSTEM "/etc/passwd">]>' + scene()),
        "entity declaration 'x'",
    ),
    "root is shape": (lambda d: write(d, '<shape type="sphere"/>'), "the root element is <shape>"),
    "root is html": (lambda d: write(d, "<html><body/></html>"), "the root element is <html>"),
    "unclosed element": (lambda d: write(d, scene().replace("</scene>", "")), "not well-formed XML"),
    "mismatched tag": (lambda d: write(d, scene().replace("</scene>", "</shape>")), "not well-formed XML"),
    "empty file": (lambda d: write(d, ""), "not well-formed XML"),
    "binary garbage": (lambda d: write(d, bytes(range(256)) * 8), "not well-formed XML"),
    "utf-8 bom then garbage": (lambda d: write(d, b"\xef\xbb\xbf\xff\xfe<scene"), "not well-formed XML"),
    "text, not XML": (lambda d: write(d, "hello, world\n"), "not well-formed XML"),
    "two roots": (lambda d: write(d, scene() + scene()), "not well-formed XML"),
    "include of a missing file": (lambda d: write(d, scene(_include("nowhere.xml"))), "nowhere.xml"),
    "unknown plugin": (lambda d: write(d, scene('<shape type="teapot9000"/>')), "teapot9000"),
    "unknown tag": (lambda d: write(d, scene("<widget/>")), "widget"),
    "ref to unknown id": (
        lambda d: write(d, scene('<shape type="sphere"><ref id="nope"/></shape>')),
        "nope",
    ),
    "duplicate id": (
        lambda d: write(d, scene('<bsdf type="diffuse" id="x"/><bsdf type="diffuse" id="x"/>')),
        '"x"',
    ),
    "missing version": (
        lambda d: write(d, scene().replace('<scene version="3.0.0">', "<scene>")),
        "version",
    ),
    "no sensor": (lambda d: write(d, scene(sensor="")), "sensor"),
    "unset parameter": (lambda d: write(d, scene(_sphere("$r"))), "$r"),
    "radius not a number": (lambda d: write(d, scene(_sphere("big"))), "big"),
    # rtfit reads every value to check it; Mitsuba's "unreferenced property" refusal must still hold
    "unreferenced shape property": (
        lambda d: write(d, scene('<shape type="sphere"><float name="radus" value="2"/></shape>')),
        'unreferenced property in shape plugin of type "sphere": - float "radus"',
    ),
    "unreferenced sensor property": (
        lambda d: write(d, scene(sensor=sensor_with(extra='<float name="fovv" value="40"/>'))),
        'float "fovv"',
    ),
    "unreferenced film property": (
        lambda d: write(
            d, scene(sensor=sensor_with().replace("</film>", '<integer name="widht" value="4"/></film>'))
        ),
        'integer "widht"',
    ),
    "a directory named .xml": (lambda d: (d / "dir.xml").mkdir() or d / "dir.xml", "dir.xml"),
}


@pytest.mark.parametrize(("make", "says"), list(STRUCTURE.values()), ids=list(STRUCTURE))
def test_xml_structure(capsys, tmp_path, make, says):
    line = refuse(capsys, tmp_path, make(tmp_path))
    assert says in line


def test_double_hyphens_in_a_comment_pass_as_mitsuba_reads_them(capsys, tmp_path):
    """XML 1.0 forbids ``--`` inside a comment (Expat refuses it), but Mitsuba's parser reads a comment up to
    its first ``-->`` and Sionna's scenes open with one (``<!--`` / ``-- SPDX-…``, tests/data/real/sionna):
    the pre-scan lets it through, and a later problem is still found on its own line."""
    comment = "<!--\n-- SPDX-License-Identifier: Apache-2.0\n-- two -- hyphens\n  -->\n"
    path = write(tmp_path, comment + scene())
    assert main(["audit", str(path), "--list"]) == 0, capsys.readouterr().err
    capsys.readouterr()
    bad = write(tmp_path, comment + scene().replace("</scene>", ""), "bad.xml")
    line = refuse(capsys, tmp_path, bad)
    assert "not well-formed XML" in line


def test_camera_out_of_range(capsys, tmp_path):
    assert "--camera 3" in refuse(capsys, tmp_path, write(tmp_path, scene()), "--camera", "3")


# ------------------------------------------------------------------------------------------- files
PLY_HEAD = "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"


def _ply(fmt="binary_little_endian", n="3", faces=True) -> bytes:
    head = PLY_HEAD.format(fmt=fmt, n=n)
    if faces:
        head += "element face 1\nproperty list uchar int vertex_indices\n"
    return (head + "end_header\n").encode()


def _mesh_scene(name: str, plugin: str = "ply", emitter: bool = False) -> str:
    inner = _area("1") if emitter else ""
    return scene(f'<shape type="{plugin}"><string name="filename" value="{name}"/>{inner}</shape>')


FILES = {
    "random bytes .ply": ("m.ply", os.urandom(3000), "not a PLY file"),
    "zeros .ply": ("m.ply", bytes(4096), "not a PLY file"),
    "empty .ply": ("m.ply", b"", "not a PLY file"),
    "ply header without end_header": ("m.ply", b"ply\nformat ascii 1.0\n", "not a PLY file"),
    "ply header only 'ply'": ("m.ply", b"ply\n", "not a PLY file"),
    "ply binary header then garbage": (
        "m.ply",
        b"ply\n\xff\xfe\xfd format\nend_header\n",
        "header is not ASCII",
    ),
    "ply unknown format": ("m.ply", _ply(fmt="binary_middle_endian"), "no known 'format' line"),
    "ply truncated binary": ("m.ply", _ply(n="1000") + b"\0" * 24, "shorter than its 1000 declared vertices"),
    "ply vertex count not a number": ("m.ply", _ply(n="lots"), "element count 'lots'"),
    "ply vertex count 2^40": ("m.ply", _ply(n=str(1 << 40)), "not a count below 2^31"),
    "ply vertex count negative": ("m.ply", _ply(n="-1"), "element count '-1'"),
    "ply without vertices": (
        "m.ply",
        b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
        "declares no 'element vertex'",
    ),
    "ply that is a text file": ("m.ply", b"hello\nworld\n" * 20, "not a PLY file"),
    "ply that is an XML file": ("m.ply", scene().encode(), "not a PLY file"),
    "obj with NUL bytes": ("m.obj", b"v 0 0 0\n\0\0\0\0", "binary data"),
    "obj that is random bytes": ("m.obj", b"\x80\x81\xfe\xff" * 200, "not an OBJ file (not text)"),
    "obj with control bytes": ("m.obj", b"v 0 0 0\n\x01\x02\x03", "binary data"),
}


@pytest.mark.parametrize(("name", "data", "says"), list(FILES.values()), ids=list(FILES))
def test_mesh_file_is_checked_before_mitsuba_loads_it(capsys, tmp_path, name, data, says):
    write(tmp_path, data, name)
    plugin = name.rsplit(".", 1)[1]
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene(name, plugin)))
    assert says in line and str(tmp_path / name) in line and f'<shape type="{plugin}">' in line
    assert "codec" not in line  # no decoder message quoting the file's bytes


def test_emitting_mesh_garbage(capsys, tmp_path):
    write(tmp_path, os.urandom(2048), "lamp.ply")
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene("lamp.ply", emitter=True)))
    assert "lamp.ply: not a PLY file" in line


def test_mesh_symlink_to_a_system_file(capsys, tmp_path):
    (tmp_path / "x.ply").symlink_to("/etc/passwd")
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene("x.ply")))
    assert "not a PLY file" in line and "root:" not in line  # no content quoted


def test_missing_mesh_file(capsys, tmp_path):
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene("gone.ply")))
    assert "gone.ply" in line


def test_mesh_file_is_a_directory(capsys, tmp_path):
    (tmp_path / "d.ply").mkdir()
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene("d.ply")))
    assert "d.ply" in line


def test_mesh_in_an_include(capsys, tmp_path):
    write(tmp_path, os.urandom(512), "meshes/m.ply")
    write(
        tmp_path,
        '<scene version="3.0.0"><shape type="ply">'
        '<string name="filename" value="meshes/m.ply"/></shape></scene>',
        "parts/shapes.xml",
    )
    line = refuse(capsys, tmp_path, write(tmp_path, scene(_include("parts/shapes.xml"))))
    assert "shapes.xml" in line and "meshes/m.ply: not a PLY file" in line


def test_valid_meshes_pass_the_checks(capsys, tmp_path):
    """The checks refuse no real mesh: the repository's ASCII PLY, OBJ and Mitsuba's Cornell box."""
    from rtfit.reference.xml_checks import mesh_problem

    data = Path(__file__).parent / "data"
    for mesh in (data / "tri.ply", data / "tri.obj", data / "mitsuba" / "teapot" / "teapot.ply"):
        assert mesh_problem(str(mesh)) is None, mesh
    for mesh in (data / "mitsuba" / "cbox" / "meshes").glob("*.obj"):
        assert mesh_problem(str(mesh)) is None, mesh
    latin1 = tmp_path / "latin1.obj"  # a Latin-1 comment in an otherwise ASCII OBJ is still a mesh
    latin1.write_bytes("# café\n".encode("latin-1") + (data / "tri.obj").read_bytes())
    assert mesh_problem(str(latin1)) is None
    binary = tmp_path / "b.ply"
    binary.write_bytes(_ply(n="3") + b"\0" * 36 + bytes([3]) + b"\0\0\0\0\1\0\0\0\2\0\0\0")
    assert mesh_problem(str(binary)) is None
    rc = main(["audit", str(data / "mitsuba" / "cbox" / "cbox-rgb.xml"), "--list"])
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()


# ------------------------------------------------------------------------------------ --approx files
APPROX = {
    "syntax error": ("def f(:\n", "f", "SyntaxError"),
    "empty file": ("", "f", "no attribute 'f'"),
    "binary file": (b"\x00\x01\x02\xff", "f", "loading"),
    "missing attribute": ("x = 1\n", "g", "no attribute 'g'"),
    "plain function": ("def f(ops, g):\n    return g.irradiance\n", "f", "is not an approximation"),
    "unknown quantity": (
        "from rtfit import approximation\n@approximation(quantity='nope')\ndef f(ops, g):\n    return 0\n",
        "f",
        "nope",
    ),
    "parameter without bounds": (
        "from rtfit import approximation\n@approximation(quantity='light_irradiance', params={'w': 0.5})\n"
        "def f(ops, g, *, w):\n    return g.irradiance\n",
        "f",
        "has no bounds",
    ),
    "raises at import": ("raise RuntimeError('boom')\n", "f", "RuntimeError: boom"),
    "imports a missing module": ("import no_such_module_rtfit\n", "f", "no_such_module_rtfit"),
    "recursion at import": ("def r(): return r()\nr()\n", "f", "RecursionError"),
    "MemoryError at import": ("raise MemoryError\n", "f", "MemoryError"),
    "returns None": (None, "return None", "returned shape ()"),
    "returns a string": (None, "return 'bright'", "not numbers"),
    "returns NaN": (None, "return g.irradiance * float('nan')", "returned NaN"),
    "returns the wrong shape": (None, "return 1.0", "returned shape ()"),
    "returns a tuple": (None, "return (g.irradiance, g.irradiance)", "returned a tuple of 2"),
    "raises in f": (None, "raise ValueError('dark')", "raised ValueError: dark"),
    "reads an unknown input": (None, "return g.cos", "carries no input 'cos'"),
    "returns complex": (None, "return g.irradiance * 1j", "returned complex numbers"),
}


def _approx_file(text: str | bytes | None, body: str) -> str | bytes:
    if text is not None:
        return text
    return (
        "from rtfit import approximation\n\n"
        "@approximation(quantity='light_irradiance')\n"
        f"def f(ops, g):\n    {body}\n"
    )


@pytest.mark.parametrize(("text", "name", "says"), list(APPROX.values()), ids=list(APPROX))
def test_approx_file(capsys, tmp_path, text, name, says):
    path = write(tmp_path, _approx_file(text, name), "mine.py")
    attr = name if text is not None else "f"
    line = refuse(capsys, tmp_path, write(tmp_path, scene()), "--approx", f"{path}:{attr}")
    assert says in line


APPROX_SPECS = {
    "missing file": ("nowhere.py:f", "no such file"),
    "no name": ("mine.py:", "FILE.py:NAME"),
    "no module": (":f", "FILE.py:NAME"),
    "unknown entry point": ("not_an_entry_point_rtfit", "no entry point"),
    "missing module": ("no_such_pkg_rtfit.mod:f", "no module named"),
    "a directory": ("{dir}:f", "no such file"),
}


@pytest.mark.parametrize(("spec", "says"), list(APPROX_SPECS.values()), ids=list(APPROX_SPECS))
def test_approx_spec(capsys, tmp_path, spec, says):
    (tmp_path / "pkgdir.py").mkdir()
    spec = spec.replace("{dir}", str(tmp_path / "pkgdir.py"))
    line = refuse(capsys, tmp_path, write(tmp_path, scene()), "--approx", spec)
    assert says in line


# -------------------------------------------------------------------------- mesh files of TOML scenes
def _nan_ply(fmt: str = "ascii", value: str = "nan") -> bytes:
    head = _ply(fmt=fmt, n="3")
    if fmt == "ascii":
        return head + f"0 0 0\n1 0 0\n0 {value} 0\n3 0 1 2\n".encode()
    import numpy as np

    xyz = np.array([[0, 0, 0], [1, 0, 0], [0, float(value), 0]], "<f4").tobytes()
    return head + xyz + bytes([3]) + np.array([0, 1, 2], "<i4").tobytes()


MESHES = {
    "empty .ply": ("m.ply", b"", "not a PLY file"),
    "random bytes .ply": ("m.ply", os.urandom(1024), "not a PLY file"),
    "ascii ply with a NaN vertex": ("m.ply", _nan_ply(), "vertex 2 is not finite"),
    "ascii ply with an inf vertex": ("m.ply", _nan_ply(value="inf"), "vertex 2 is not finite"),
    "ascii ply with a far vertex": ("m.ply", _nan_ply(value="1e30"), "vertex 2 is beyond ±1e+08"),
    "ascii ply with a word for a vertex": ("m.ply", _nan_ply(value="one"), "do not read as numbers"),
    "ascii ply with too few vertex lines": ("m.ply", _ply(fmt="ascii", n="5") + b"0 0 0\n", "do not read"),
    "binary ply with a NaN vertex": ("m.ply", _nan_ply("binary_little_endian"), "vertex 2 is not finite"),
    "binary ply with a far vertex": ("m.ply", _nan_ply("binary_little_endian", "-1e20"), "beyond ±1e+08"),
    "binary ply truncated": ("m.ply", _ply(n="99") + b"\0" * 10, "shorter than its 99 declared vertices"),
    "ply without x y z": (
        "m.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float u\nend_header\n0\n",
        "no x, y, z properties",
    ),
    "obj with a NaN vertex": ("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n", "vertex 2 is not finite"),
    "obj with a far vertex": ("m.obj", b"v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n", "vertex 1 is beyond"),
    "obj with a word vertex": ("m.obj", b"v 0 zero 0\n", "vertex 0 does not read as numbers"),
    "obj with a 2-d vertex": ("m.obj", b"v 0 0\n", "fewer than 3 coordinates"),
    "obj that is binary": ("m.obj", b"\0\1\2\3" * 64, "binary data"),
}


def _toml_with_mesh(tmp_path: Path, name: str) -> Path:
    from rtfit.scenes import library_path

    base = library_path("half_lambert_sphere").read_text()
    return write(tmp_path, base + f'\n[[shapes]]\ntype = "mesh"\nfile = "{name}"\n', "scene.toml")


@pytest.mark.parametrize(("name", "data", "says"), list(MESHES.values()), ids=list(MESHES))
def test_toml_mesh_file_is_checked(capsys, tmp_path, name, data, says):
    write(tmp_path, data, name)
    line = refuse(capsys, tmp_path, _toml_with_mesh(tmp_path, name))
    assert says in line and "shapes[1].file" in line and str(tmp_path / name) in line


@pytest.mark.parametrize(("name", "data", "says"), list(MESHES.values())[:6], ids=list(MESHES)[:6])
def test_xml_mesh_values_are_checked(capsys, tmp_path, name, data, says):
    write(tmp_path, data, name)
    line = refuse(capsys, tmp_path, write(tmp_path, _mesh_scene(name, name.rsplit(".", 1)[1])))
    assert says in line and str(tmp_path / name) in line


def test_toml_mesh_symlink_to_a_system_file_is_not_exported(capsys, tmp_path):
    """issue 32: export-xml copied /etc/passwd into meshes/x.ply; audit quoted its first line."""
    (tmp_path / "x.ply").symlink_to("/etc/passwd")
    scene_file = _toml_with_mesh(tmp_path, "x.ply")
    line = refuse(capsys, tmp_path, scene_file)
    assert "not a PLY file" in line and ":0:0:" not in line  # nothing of /etc/passwd quoted
    target = tmp_path / "export" / "s.xml"
    rc = main(["export-xml", str(scene_file), str(target)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: ") and "not a PLY file" in err[0]
    assert not (tmp_path / "export").exists()


# ------------------------------------------------------------------------- options and the limit table
OPTIONS = {
    "--out under /proc": (["--out", "/proc/rtfit-x"], "--out /proc/rtfit-x/audit-s: cannot create anything"),
    "--out under a file": (["--out", "{tmp}/a-file/out"], "is under"),
    "--cache under /proc": (["--cache", "/proc/rtfit-x"], "--cache /proc/rtfit-x: cannot create anything"),
    "--cache unreadable": (["--cache", "/proc/1/cwd/x"], "--cache /proc/1/cwd/x"),
    "--cache a file": (["--cache", "{tmp}/a-file"], "is a file"),
    "--width 100000": (["--width", "100000"], "'--width': 100000 is not in the range 1<=x<=4096"),
    "--height 100000": (["--height", "100000"], "'--height': 100000 is not in the range"),
    "--width 0": (["--width", "0"], "'--width': 0 is not in the range"),
    "--spp 2^24": (["--spp", str(1 << 24)], "'--spp': 16777216 is not in the range 2<=x<=1048576"),
    "--pass-spp 2^24": (["--pass-spp", str(1 << 24)], "'--pass-spp': 16777216 is not in the range"),
    "--spp 2^20 in passes of 2": (
        ["--spp", str(1 << 20), "--pass-spp", "2"],
        "= 524288: the number of cached",
    ),
    "--spp 1": (["--spp", "1"], "'--spp': 1 is not in the range"),
    "--approx empty": (["--approx", ""], "names no approximation"),
    "--approx commas": (["--approx", ",,,"], "names no approximation"),
    "--up sideways": (["--up", "sideways"], "'--up'"),
    "--camera -1": (["--camera", "-1"], "'--camera'"),
    "-D without =": (["-D", "novalue"], "expected name=value"),
    "--variant scalar": (["--variant", "scalar_rgb"], "'--variant'"),
    "--seed -1": (["--seed", "-1"], "'--seed'"),
    "--ao-distance nan": (["--ao-distance", "nan"], "--ao-distance nan: must be a finite distance"),
    "--ao-distance inf": (["--ao-distance", "inf"], "--ao-distance inf: must be a finite distance"),
    "--ao-distance 1e30": (["--ao-distance", "1e30"], "--ao-distance 1e+30: must be a finite distance"),
    "--ao-distance 0": (["--ao-distance", "0"], "'--ao-distance'"),
    "--json under /proc": (["--json", "/proc/rtfit-x.json"], "--json /proc/rtfit-x.json: cannot create"),
}


@pytest.mark.parametrize(("extra", "says"), list(OPTIONS.values()), ids=list(OPTIONS))
def test_audit_option_refused_before_anything_renders(capsys, tmp_path, extra, says):
    (tmp_path / "a-file").write_text("x")
    path = write(tmp_path, scene())
    extra = [e.replace("{tmp}", str(tmp_path)) for e in extra]
    out = tmp_path / "out"
    cache = tmp_path / "cache"
    argv = ["audit", str(path), "--no-fit", "--no-progress", "--width", "8", "--height", "8", "--spp", "2"]
    if "--out" not in extra:
        argv += ["--out", str(out)]
    if "--cache" not in extra:
        argv += ["--cache", str(cache)]
    rc = main(argv + extra)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: "), err
    assert says in err[0]
    assert not out.exists() and not cache.exists()
    assert (tmp_path / "a-file").read_text() == "x"


def test_xml_film_larger_than_the_audit_limit(capsys, tmp_path):
    """A film the TOML schema allows (≤ 16384) but the audit's limit table does not (≤ 4096)."""
    path = write(tmp_path, scene(sensor=sensor_with(width="8000")))
    out, cache = tmp_path / "out", tmp_path / "cache"
    rc = main(["audit", str(path), "--out", str(out), "--cache", str(cache)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "the sensor's film 8000" in err[0] and "[1, 4096]" in err[0], err
    assert not out.exists() and not cache.exists()


def test_api_width_beyond_the_limit(tmp_path):
    from rtfit.experiments.audit import AuditError
    from rtfit.experiments.audit_run import audit

    with pytest.raises(AuditError, match=r"--width 100000: an image side in pixels must be in \[1, 4096\]"):
        audit(write(tmp_path, scene()), width=100000, cache=tmp_path / "c")
    with pytest.raises(AuditError, match=r"--spp 16777216: samples per pixel must be in \[2, 1048576\]"):
        audit(write(tmp_path, scene()), spp=1 << 24, pass_spp=2, cache=tmp_path / "c")
    with pytest.raises(AuditError, match=r"= 131072: the number of cached passes"):
        audit(write(tmp_path, scene()), spp=1 << 18, pass_spp=2, cache=tmp_path / "c")
    assert not (tmp_path / "c").exists()


OTHER_COMMANDS = {
    "bench --size 2^40": (["bench", "diffuse", "--size", str(1 << 40)], "'--size'"),
    "bench --size 1": (["bench", "diffuse", "--size", "1"], "'--size'"),
    "bench --json under /proc": (  # was: the benchmark ran (2 minutes), then a traceback
        ["bench", "diffuse", "--json", "/proc/rtfit-x.json"],
        "--json /proc/rtfit-x.json: cannot create anything in /proc",
    ),
    "cache info unreadable": (["cache", "info", "--cache", "/proc/1/cwd"], "cannot read it"),
    "cache info symlink loop": (
        ["cache", "info", "--cache", "{tmp}/loop"],
        "a broken symbolic link (or a loop)",
    ),
    "cache info a file": (["cache", "info", "--cache", "{tmp}/a-file"], "'--cache'"),
    "cache prune unreadable": (["cache", "prune", "--cache", "/proc/1/cwd", "--max-size", "1G"], "read"),
    "cache prune symlink loop": (["cache", "prune", "--cache", "{tmp}/loop", "--max-size", "1G"], "broken"),
    "run --out under /proc": (
        ["run", "diffuse", "--quick", "--out", "/proc/rtfit-x"],
        "cannot create anything",
    ),
    "run --spp 2^21": (["run", "diffuse", "--quick", "--spp", str(1 << 21)], "'--spp'"),
}


@pytest.mark.parametrize(("argv", "says"), list(OTHER_COMMANDS.values()), ids=list(OTHER_COMMANDS))
def test_other_commands_refuse_in_one_line(capsys, tmp_path, monkeypatch, argv, says):
    monkeypatch.setenv("RTFIT_CACHE", str(tmp_path / "cache"))
    (tmp_path / "a-file").write_text("x")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: "), err
    assert says in err[0]
    assert not (tmp_path / "cache").exists()


def test_sweep_of_a_million_points_is_refused_before_expanding(capsys, tmp_path):
    spec = write(
        tmp_path,
        'experiment = "diffuse"\nquick = true\n[grid]\n'
        f"resolution = {list(range(8, 1008))}\nspp = {list(range(2, 1002))}\n",
        "big.toml",
    )
    rc = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "grid: 1000000 points: at most 10000" in err[0], err
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


@pytest.mark.parametrize("value", ["nan", "inf", "1e30"])
def test_ao_distance_in_list_mode(capsys, value):
    rc = main(["audit", "half_lambert_sphere", "--list", "--ao-distance", value])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "must be a finite distance in (0, 1e+08]" in err[0], err


def test_sweep_key_in_fixed_and_grid(capsys, tmp_path):
    spec = write(
        tmp_path, 'experiment = "diffuse"\nquick = true\n[fixed]\nspp = 8\n[grid]\nspp = [4, 16]\n', "s.toml"
    )
    rc = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "grid.spp: is in [fixed] too" in err[0], err
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


@pytest.mark.parametrize(
    "argv",
    [["run", "diffuse", "--quick"], ["audit", "{scene}"]],
    ids=["run", "audit"],
)
def test_missing_libllvm_is_one_rtfit_line_before_anything_is_written(tmp_path, argv):
    """A $DRJIT_LIBLLVM_PATH that names no file: one rtfit line, exit 2, no out/ and no cache entry, and
    nothing else (Dr.Jit's own two lines at import, ``jit_find_library(): Unable to load …``, are silenced
    by rtfit.experiments, which imports it first)."""
    import subprocess
    import sys

    path = write(tmp_path, scene())
    out, cache = tmp_path / "out", tmp_path / "cache"
    argv = [a.replace("{scene}", str(path)) for a in argv] + ["--out", str(out), "--cache", str(cache)]
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": str(tmp_path / "no-libLLVM.so")}
    proc = subprocess.run(
        [sys.executable, "-m", "rtfit", *argv], capture_output=True, text=True, timeout=300, env=env
    )
    ours = [line for line in proc.stderr.splitlines() if line.startswith("rtfit")]
    assert proc.returncode == 2, proc.stderr
    assert len(ours) == 1 and ours[0].startswith("rtfit: error: ") and "DRJIT_LIBLLVM_PATH" in ours[0]
    assert proc.stderr.strip().splitlines() == ours, proc.stderr  # no jit_find_library() lines
    assert "Traceback" not in proc.stderr
    assert not out.exists() and not cache.exists()


# ---------------------------------------------------------------------------------- results files
def _results_text() -> str:
    return (Path(__file__).parent / "data" / "results" / "half-lambert.json").read_text(encoding="utf-8")


RESULTS = {
    "nested 100000 deep": (lambda: "[" * 100_000 + "]" * 100_000, "nested too deeply"),
    "a 10^400 metric": (
        lambda: _results_text().replace("9.264250578325555e-05", "1" + "0" * 400, 1),
        "an integer of 1329 bits is not a valid result",
    ),
    "a 5000-digit integer": (
        lambda: _results_text().replace("9.264250578325555e-05", "1" * 5000, 1),
        "invalid JSON",
    ),
    "NaN metric": (lambda: _results_text().replace("9.264250578325555e-05", "NaN", 1), "NaN is not a valid"),
    "not JSON": (lambda: "{results", "invalid JSON"),
    "rmse -5": (
        lambda: _results_text().replace('"value": 9.264250578325555e-05', '"value": -5', 1),
        "metrics.rmse.value: must be >= 0 (got -5",
    ),
    "noise floor -1": (
        lambda: _results_text().replace('"noise_floor": 9.324675452328887e-05', '"noise_floor": -1', 1),
        "metrics.rmse.noise_floor: must be >= 0 (got -1",
    ),
}


@pytest.mark.parametrize(("make", "says"), list(RESULTS.values()), ids=list(RESULTS))
def test_report_of_a_bad_results_file(capsys, tmp_path, make, says):
    d = tmp_path / "exp"
    d.mkdir()
    (d / "results.json").write_text(make(), encoding="utf-8")
    rc = main(["report", str(d)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: ") and says in err[0], err
    assert sorted(p.name for p in d.iterdir()) == ["results.json"]  # nothing written


@pytest.mark.parametrize("layout", ["one experiment", "a run folder"])
def test_report_into_a_read_only_folder(capsys, tmp_path, layout):
    """``rtfit report DIR`` writes into DIR (and each experiment's folder below it): a folder that cannot be
    written ended in a traceback from the first atomic write (the re-check of issue 32); now one line before
    anything is written. Root ignores permissions, so the folder is made immutable (``chattr +i``) there."""
    import subprocess

    d = tmp_path / "run"
    exp = d if layout == "one experiment" else d / "half-lambert"
    exp.mkdir(parents=True)
    (exp / "results.json").write_text(_results_text(), encoding="utf-8")
    locked = exp
    if os.geteuid() == 0:
        if subprocess.run(["chattr", "+i", str(locked)], capture_output=True).returncode != 0:
            pytest.skip("chattr +i is not available here")
    else:
        locked.chmod(0o555)
    try:
        rc = main(["report", str(d)])
        err = capsys.readouterr().err.strip().splitlines()
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(locked)], check=True)
        else:
            locked.chmod(0o755)
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: "), err
    assert f"{locked}: the report is written there, but cannot create anything" in err[0], err
    assert sorted(p.name for p in d.iterdir()) == ["results.json" if layout == "one experiment" else exp.name]


def test_sweep_gpus_without_a_gpu(capsys, tmp_path):
    from rtfit.reference.variants import cuda_available

    if cuda_available():
        pytest.skip("this machine has a CUDA GPU")
    spec = write(tmp_path, 'experiment = "diffuse"\nquick = true\n', "s.toml")
    out, cache = tmp_path / "out", tmp_path / "cache"
    argv = ["sweep", str(spec), "--out", str(out), "--cache", str(cache), "--executor", "process"]
    rc = main([*argv, "--gpus", "0,1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--gpus 0,1: no CUDA GPU was found here" in err[0], err
    assert not out.exists() and not cache.exists()


@pytest.mark.parametrize("damage", ["garbage", "meta", "spp 0", "spp text"])
def test_an_unreadable_cached_pass_is_named_in_one_warning(tmp_path, caplog, damage):
    """A corrupt pass is re-rendered, never trusted — and one rtfit line says which (issue 32)."""
    import json
    import logging

    import numpy as np

    from rtfit.reference.cache import PassEntry, PassResult

    entry = PassEntry(tmp_path, {"test": "bad-input"})
    entry.save(0, PassResult(np.ones((2, 3)), np.ones((2, 3)) * 0.1, 16, 0, 0.01))
    data, meta = entry.folder / "pass-00000.npz", entry.folder / "pass-00000.json"
    if damage == "garbage":
        data.write_bytes(b"\x00" * 200)
    elif damage == "meta":
        meta.write_text("{not json")
    else:
        info = json.loads(meta.read_text())
        info["spp"] = 0 if damage == "spp 0" else "many"
        meta.write_text(json.dumps(info))
    with caplog.at_level(logging.WARNING, logger="rtfit.reference"):
        assert entry.load(0) is None
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1 and str(data) in lines[0] and "rendered again" in lines[0], lines


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_a_corrupt_exr_pass_prints_no_openexr_lines(tmp_path, capfd, caplog, damage):
    """OpenEXR printed its own lines (stdout and stderr) for a corrupt pass before rtfit's warning: now the
    warning alone names the pass; a sound EXR still reads (issue 32)."""
    import logging

    import numpy as np

    from rtfit.reference.cache import PassEntry, PassResult

    entry = PassEntry(tmp_path, {"test": "bad-exr"}, storage="exr")
    entry.save(0, PassResult(np.ones((4, 4, 3)), np.ones((4, 4, 3)) * 0.1, 16, 0, 0.01))
    assert entry.load(0) is not None
    data = entry.folder / "pass-00000.exr"
    good = data.read_bytes()
    if damage == "truncated":
        data.write_bytes(good[: len(good) // 2] + bytes(len(good) // 2))
    else:
        data.write_bytes(b"garbage" * 40)
    capfd.readouterr()
    with caplog.at_level(logging.WARNING, logger="rtfit.reference"):
        assert entry.load(0) is None
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1 and str(data) in lines[0] and "rendered again" in lines[0], lines
    raw = capfd.readouterr()
    assert raw.out == "" and "EXR" not in raw.err and "Exception raised" not in raw.err, raw


@pytest.mark.parametrize("damage", ["garbage npz", "edited spp"])
def test_a_bad_cached_pass_is_named_once_per_run(tmp_path, caplog, damage):
    """`PassEntry.passes` looks at a missing pass up to three times (before, while and after claiming it):
    a corrupt pass, or one whose JSON ``spp`` was edited, printed its line three times (the re-check of
    issue 32 through ``rtfit audit``); now one line, the pass rendered again, at the request's size. Random
    bytes are "not an npz (zip) archive", not NumPy's text about pickles, cut off mid-sentence."""
    import json
    import logging

    import numpy as np

    from rtfit.reference.cache import PassEntry, PassResult

    entry = PassEntry(tmp_path, {"test": "bad-pass-once"})
    entry.save(0, PassResult(np.ones((2, 3)), np.ones((2, 3)) * 0.1, 16, 0, 0.01))
    data, meta = entry.folder / "pass-00000.npz", entry.folder / "pass-00000.json"
    if damage == "garbage npz":
        data.write_bytes(os.urandom(100))
    else:
        meta.write_text(json.dumps({**json.loads(meta.read_text()), "spp": 400}))

    def render(i):
        return PassResult(np.full((2, 3), 2.0), np.zeros((2, 3)), 16, 1, 0.01)

    with caplog.at_level(logging.INFO, logger="rtfit.reference"):
        results, rendered = entry.passes(1, render, spp_of=lambda i: 16)
    said = [r.getMessage() for r in caplog.records if str(data) in r.getMessage()]
    assert len(said) == 1 and "rendered again" in said[0], said
    if damage == "garbage npz":
        assert "not an npz (zip) archive" in said[0] and "pickle" not in said[0], said
    assert rendered == 1 and results[0].spp == 16 and np.all(results[0].mean == 2.0)


def test_ray_init_retry_lines_are_held(capfd):
    """An address that answers TCP but is no Ray cluster: Ray's C++ client printed a line a second while
    retrying (21 before the error, issue 32); now the error alone, as one ValueError line. A connection
    that succeeds shows what Ray printed."""
    import types

    from rtfit.experiments.ray_executor import _init_within

    def failing(address, **kwargs):
        for _ in range(3):
            os.write(2, b"[2026-12-05 W] gcs_client.cc:210: Failed to get cluster ID from GCS server\n")
        print("SIGTERM handler is not set", file=__import__("sys").stderr)
        raise ConnectionError(f"Failed to connect to Ray cluster at {address}")

    capfd.readouterr()
    with pytest.raises(ValueError, match=r"^--address 1\.2\.3\.4:6379: ConnectionError: Failed to connect"):
        _init_within(types.SimpleNamespace(init=failing), 5, "1.2.3.4:6379")
    assert capfd.readouterr() == ("", "")

    def connecting(address, **kwargs):
        os.write(2, b"Connected to Ray cluster\n")
        return "context"

    assert _init_within(types.SimpleNamespace(init=connecting), 5, "1.2.3.4:6379") == "context"
    assert capfd.readouterr().err == "Connected to Ray cluster\n"


def test_ray_address_variable_is_checked_like_the_option(capsys, tmp_path, monkeypatch):
    """$RAY_ADDRESS naming a port nothing listens on: one line in seconds (Ray retried for > 300 s)."""
    import socket
    import time

    pytest.importorskip("ray", reason="Ray is not installed (rtfit[ray])")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    out, cache = tmp_path / "out", tmp_path / "cache"
    t0 = time.perf_counter()
    rc = main(["run", "diffuse", "--quick", "--out", str(out), "--cache", str(cache), "--executor", "ray"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"rtfit: error: $RAY_ADDRESS 127.0.0.1:{port}: cannot connect"), err
    assert time.perf_counter() - t0 < 30
    assert not out.exists() and not cache.exists()
