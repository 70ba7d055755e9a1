"""`rtfit audit SCENE --list` (issue 15 §1–2): real Mitsuba scenes read by Mitsuba's parser, and the families
that apply to them by the rules of its declarations, `rtfit.experiments.families.RULES`.

The scenes are written here (no network): a Cornell-box-like scene with an ``<include>``, a ``<path>`` mesh
folder and a Y-up sensor; Mitsuba's own ``mi.cornell_box()`` written out by Mitsuba's XML writer; ASCII PLY
and OBJ meshes; envmap/constant environments; a homogeneous medium. Expected values come from the scene
text (geometry placed by hand), never from an earlier run of the code."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import AuditError, inspect_scene
from rtfit.experiments.audit_cli import audit
from rtfit.experiments.audit_parts import PROVIDES, Part, SceneInfo
from rtfit.experiments.families import METHOD_TABLES, RULES
from rtfit.reference.mitsuba_xml import inspect_xml
from rtfit.scenes import library_path

SENSOR = """
    <sensor type="perspective" id="{id}">
        <string name="fov_axis" value="smaller"/>
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="{up}"/></transform>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
    </sensor>"""

TRI_PLY = (  # ASCII, as Mitsuba's teapot.ply: a tetrahedron, 4 triangles
    "ply\nformat ascii 1.0\ncomment written by hand\nelement vertex 4\nproperty float x\nproperty float y\n"
    "property float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n0.4 0 0\n0 0.4 0\n0 0 0.4\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
)
QUAD_PLY = (
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
)


def _sensor(id="cam", origin="0, 0, 3.9", target="0, 0, 0", up="0, 1, 0", fov=39.3077):
    return SENSOR.format(id=id, origin=origin, target=target, up=up, fov=fov)


def _cornell(root, mesh="tet.ply", mesh_text=TRI_PLY, light_shape="rectangle", extra="", sensors=None):
    """A Cornell-box-like scene: walls x, y, z ∈ [−1, 1] in ``geometry.xml`` (included), a mesh in
    ``assets/`` reached through ``<path>``, a light under the ceiling, sensor(s) Y-up."""
    (root / "assets").mkdir(parents=True, exist_ok=True)
    (root / "assets" / mesh).write_text(mesh_text)
    (root / "geometry.xml").write_text(
        f"""<scene version="3.0.0">
    <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.8, 0.8, 0.8"/></bsdf>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><rotate x="1" angle="-90"/><translate y="-1"/></transform>
        <ref id="white"/>
    </shape>
    <shape type="rectangle" id="back">
        <transform name="to_world"><translate z="-1"/></transform>
        <ref id="white"/>
    </shape>
    <shape type="{mesh.rsplit(".", 1)[1]}" id="mesh">
        <string name="filename" value="{mesh}"/>
        <ref id="white"/>
    </shape>
</scene>
"""
    )
    light = {
        "rectangle": '<transform name="to_world"><scale value="0.2"/><rotate x="1" angle="90"/>'
        '<translate y="0.99"/></transform>',
        "sphere": '<point name="center" x="0" y="0.6" z="0"/><float name="radius" value="0.25"/>',
    }[light_shape]
    (root / "scene.xml").write_text(
        f"""<scene version="3.0.0">
    <default name="res" value="64"/>
    <path value="assets"/>
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    {sensors if sensors is not None else _sensor()}
    <include filename="geometry.xml"/>
    <shape type="{light_shape}" id="light">
        {light}
        <emitter type="area"><rgb name="radiance" value="18.4, 14.0, 6.75"/></emitter>
    </shape>
    {extra}
</scene>
"""
    )
    return root / "scene.xml"


def _run(*args):
    result = CliRunner().invoke(audit, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


def _families(found) -> dict[str, list]:
    out: dict[str, list] = {}
    for a in found:
        out.setdefault(a.family, []).append(a)
    return out


# --------------------------------------------------------------------------------------------- the scenes
def test_cornell_like_scene_with_include_lists_diffuse_and_ao(tmp_path):
    xml = _cornell(tmp_path)
    x = inspect_xml(xml)
    assert x.dependencies.xml_files == (str(xml), str(tmp_path / "geometry.xml"))
    assert x.up == "+y" and "sensor 0" in x.up_reason
    cam = x.camera
    assert cam.origin == pytest.approx((0.0, 0.0, 3.9)) and cam.up == pytest.approx((0.0, 1.0, 0.0))
    assert cam.fov_deg == pytest.approx(39.3077) and cam.fov_axis == "smaller"
    assert (cam.width, cam.height) == (64, 64)
    assert [s.id for s in x.shapes] == ["floor", "back", "mesh", "light"]
    mesh = x.shapes[2]
    assert mesh.file == str(tmp_path / "assets" / "tet.ply") and mesh.faces == 4
    assert [s.id for s in x.shapes if s.emitter] == ["light"]
    (emitter,) = x.emitters
    assert (emitter.kind, emitter.shape, emitter.spherical) == ("rectangle", "rectangle", False)
    assert emitter.scale == pytest.approx((18.4, 14.0, 6.75)) and emitter.scale_name == "radiance"
    assert x.integrator == "path" and x.bsdfs == ("diffuse",)

    info = inspect_scene(xml)
    fams = _families(applicable_families(info))
    want = {"diffuse", "sdf-occlusion", "ambient-aperture", "obscurances", "irradiance-volumes"}
    want |= {"pcf-soft-shadows", "colour-bleeding", "light-path-maps"}
    # A superset, so that a new family that applies to a lit room adds no line here (issue 30: a family
    # touches one existing file); what must not apply to a scene without media, sky or mirrors is named.
    assert want <= set(fams)
    assert not set(fams) & {"height-fog", "linear-fog", "light-cones", "volumetric-lightning", "nishita-sky",
                            "aerial-perspective", "soft-particles", "environment-maps", "probe-specular",
                            "caustics", "raindrops", "clouds", "misty-glow"}  # fmt: skip
    (diffuse,) = fams["diffuse"]
    # no exact form (a rectangle); its light models: the inverse square and its windows, the polygon
    assert diffuse.methods == (
        "lambert", "half-lambert", "wrap", "punctual", "unreal-window", "frostbite-window", "polygon",
    )  # fmt: skip
    # (a rectangle of uniform radiance gives its radiance to the polygon row: only α is missing)
    assert dict(diffuse.excluded)["exact"].startswith("needs alpha: a spherical light")
    assert "direct irradiance" in diffuse.reference and "shadowed" in diffuse.reference
    (ao,) = [a for a in fams["sdf-occlusion"] if a.role == "ambient occlusion"]
    assert ao.methods == tuple(METHOD_TABLES["sdf-occlusion"])
    # The walls span [−1, 1]³ (the light and the mesh sit inside): R = 0.1 × 2√3.
    assert f"R = {0.2 * math.sqrt(3):.4g}" in ao.reference

    code, out, err = _run(xml, "--list")
    assert code == 0 and err == ""
    assert "up: +y from sensor 0's up vector" in out
    assert f"AO distance: {0.2 * math.sqrt(3):.4g} = 0.1 × the bounding-box diagonal" in out
    assert "diffuse — direct light: rectangle area light" in out
    assert "height-fog: needs an exponential height-fog medium" in out


def test_mitsubas_own_cornell_box_written_by_its_xml_writer(tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    import mitsuba.parser as parser  # mitsuba: the variant is set above

    d = mi.cornell_box()
    path = tmp_path / "cbox.xml"
    parser.write_file(parser.parse_dict(parser.ParserConfig("scalar_rgb"), d), str(path))
    x = inspect_xml(path)
    assert x.up == "+y"
    assert x.camera.fov_deg == pytest.approx(d["sensor"]["fov"])
    assert (x.camera.width, x.camera.height) == (d["sensor"]["film"]["width"], d["sensor"]["film"]["height"])
    assert [e.kind for e in x.emitters] == ["rectangle"]
    assert len(x.shapes) == sum(
        1 for v in d.values() if isinstance(v, dict) and v.get("type") in ("rectangle", "cube")
    )
    fams = _families(applicable_families(inspect_scene(path)))
    assert fams["diffuse"][0].methods == (
        "lambert", "half-lambert", "wrap", "punctual", "unreal-window", "frostbite-window", "polygon",
    )  # fmt: skip
    assert "sdf-occlusion" in fams and "irradiance-bases" not in fams


def test_a_sphere_light_adds_the_exact_form(tmp_path):
    xml = _cornell(tmp_path, light_shape="sphere")
    (emitter,) = inspect_xml(xml).emitters
    assert emitter.kind == "sphere" and emitter.spherical
    assert emitter.position == pytest.approx((0.0, 0.6, 0.0), abs=1e-6)
    assert emitter.radius == pytest.approx(0.25, rel=1e-6)
    fams = _families(applicable_families(inspect_scene(xml)))
    assert fams["diffuse"][0].methods == (
        "lambert",
        "half-lambert",
        "wrap",
        "exact",
        "punctual",
        "unreal-window",
        "frostbite-window",
        "representative-point",
    )  # fmt: skip (and a sphere light's models)
    aa = {a.role: a for a in fams["ambient-aperture"]}
    assert aa["occluded sphere light"].methods == tuple(
        m for m in METHOD_TABLES["ambient-aperture"] if m.startswith("aa-")
    )


def _write_exr(path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    mi.Bitmap(np.full((8, 16, 3), 0.5, dtype=np.float32)).write(str(path))


@pytest.mark.parametrize("env", ["envmap", "constant"])
def test_an_environment_lists_irradiance_bases(tmp_path, env):
    if env == "envmap":
        _write_exr(tmp_path / "sky.exr")
        emitter = (
            '<emitter type="envmap"><string name="filename" value="sky.exr"/>'
            '<float name="scale" value="2"/></emitter>'
        )
    else:
        emitter = '<emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>'
    (tmp_path / "env.xml").write_text(
        f'<scene version="3.0.0"><default name="res" value="16"/>{_sensor(origin="0, -4, 0", up="0, 0, 1")}'
        f'{emitter}<shape type="sphere"/></scene>'
    )
    x = inspect_xml(tmp_path / "env.xml")
    assert x.up == "+z"
    (e,) = x.emitters
    assert e.kind == env and e.environment
    if env == "envmap":
        assert e.file == str(tmp_path / "sky.exr") and e.scale == (2.0,)
        assert x.dependencies.data_files == (str(tmp_path / "sky.exr"),)
    fams = _families(applicable_families(inspect_scene(tmp_path / "env.xml")))
    assert set(fams) == {"irradiance-bases"}  # one convex sphere: nothing occludes it
    assert fams["irradiance-bases"][0].methods == tuple(METHOD_TABLES["irradiance-bases"])
    assert "unoccluded" in fams["irradiance-bases"][0].reference


def test_an_environment_with_geometry_adds_sky_occlusion(tmp_path):
    xml = _cornell(tmp_path, extra='<emitter type="constant"/>')
    fams = _families(applicable_families(inspect_scene(xml)))
    assert {"irradiance-bases", "sdf-occlusion", "ambient-aperture", "diffuse"} <= set(fams)
    roles = {a.role for a in fams["sdf-occlusion"]} | {a.role for a in fams["ambient-aperture"]}
    assert {"sky occlusion", "ambient occlusion", "sky occlusion (aperture fill)"} <= roles


def test_a_homogeneous_medium_is_constant_height_fog(tmp_path):
    """Issue 30 §2: a Mitsuba homogeneous medium is height fog with c = 0 (it used to be refused)."""
    medium = (
        '<shape type="cube"><transform name="to_world"><scale value="0.3"/></transform>'
        '<bsdf type="null"/><medium type="homogeneous" name="interior"><rgb name="sigma_t" value="1, 1, 1"/>'
        "</medium></shape>"
    )
    xml = _cornell(tmp_path, extra=medium)
    x = inspect_xml(xml)
    assert [(m.type, m.boundary) for m in x.media] == [("homogeneous", True)]
    assert [s.interior for s in x.shapes if s.type == "cube"] == ["homogeneous"]
    (fog,) = _families(applicable_families(inspect_scene(xml)))["height-fog"]
    assert fog.role == "constant fog" and "falloff c = 0" in fog.reason
    assert fog.methods == tuple(METHOD_TABLES["height-fog"])  # the optical-depth forms and the shading models
    code, out, err = _run(xml, "--list", "--approx", "height-fog")
    assert code == 0 and err == ""
    assert "height-fog — constant fog: homogeneous medium bounded by a shape" in out
    # The same family on an rtfit TOML scene with its own exponential-fog medium: it applies.
    fog = _families(applicable_families(inspect_scene(library_path("fog_volumes"))))
    assert len(fog["height-fog"]) == 2 and fog["height-fog"][0].methods == tuple(METHOD_TABLES["height-fog"])


def test_ascii_ply_and_obj_meshes_load_through_mitsuba(tmp_path):
    x = inspect_xml(_cornell(tmp_path / "ply"))
    assert [s.faces for s in x.shapes if s.type == "ply"] == [4]
    obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 5\n"  # a quad and a triangle
    x = inspect_xml(_cornell(tmp_path / "obj", mesh="m.obj", mesh_text=obj))
    assert [s.faces for s in x.shapes if s.type == "obj"] == [3]  # Mitsuba's OBJ loader splits the quad


def test_a_ply_with_quads_is_mitsubas_one_line_error_naming_the_declaring_file(tmp_path):
    # Mitsuba 3.9's PLY loader takes triangles only (ASCII and binary): its refusal is the user's error.
    xml = _cornell(tmp_path, mesh="quad.ply", mesh_text=QUAD_PLY)
    code, out, err = _run(xml, "--list")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert str(xml) in err and "geometry.xml (line 11" in err and "ply.h" not in err and "quad.ply" in err
    assert "PLY loader reads triangle faces only" in err


def test_defines_reach_the_parser(tmp_path):
    xml = _cornell(tmp_path)
    assert inspect_xml(xml, {"res": "24"}).camera.width == 24
    code, out, _ = _run(xml, "--list", "-D", "res=24")
    assert code == 0 and "24×24" in out
    code, _, err = _run(xml, "--list", "-D", "res")
    assert code == 2 and err == "rtfit: error: -D 'res': expected name=value\n"
    code, _, err = _run(xml, "--list", "-D", "nosuch=3")  # Mitsuba refuses a parameter the scene never uses
    assert code == 2 and err.count("\n") == 1 and "unused parameters" in err and "$nosuch=3" in err


def test_a_parameter_without_default_is_one_line_naming_the_d_option(tmp_path):
    """Mitsuba's own scenes leave ``$spp`` to the command line (no ``<default>``): its refusal is one line
    that says how to give it (Mitsuba's docs/scenes/sensor_orthographic.xml, audited as a user would)."""
    xml = tmp_path / "needs_spp.xml"
    xml.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><sampler type="independent">'
        '<integer name="sample_count" value="$spp"/></sampler></sensor></scene>'
    )
    code, out, err = _run(xml, "--list")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "undefined parameter: $spp (give it a value: -D spp=VALUE)" in err and str(xml) in err


def test_camera_width_height_and_up_options(tmp_path):
    two = _sensor() + _sensor(id="top", origin="0, 0.5, 0", target="0, -1, 0", up="0, 0, -1", fov=60)
    xml = _cornell(tmp_path, sensors=two)
    x = inspect_xml(xml, camera=1, width=40, height=30)
    assert len(x.sensors) == 2 and x.camera.id == "top" and (x.camera.width, x.camera.height) == (40, 30)
    assert x.camera.fov_deg == 60.0 and x.up == "-z"  # looking straight down: its up vector is −z
    assert inspect_xml(xml, camera=1, up="+y").up_reason == "+y as given (--up)"
    code, out, _ = _run(xml, "--list", "--camera", "1", "--up", "+y", "--width", "40", "--height", "30")
    assert code == 0 and "sensor 1 'top'" in out and "40×30" in out and "up: +y as given (--up)" in out
    code, _, err = _run(xml, "--list", "--camera", "2")
    assert code == 2 and "--camera 2: the scene has 2 sensor(s), 0..1" in err and err.count("\n") == 1


def test_a_bad_xml_is_one_line_naming_file_and_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0">\n  <shape type="sphere">\n</scen>\n')
    code, out, err = _run(bad, "--list")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith(f"rtfit: error: {bad}:") and "line 3" in err


def test_unknown_approx_is_one_line(tmp_path):
    xml = _cornell(tmp_path)
    code, out, err = _run(xml, "--list", "--approx", "diffuse,phong")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "--approx 'phong': not a family (diffuse, irradiance-bases" in err
    code, out, _ = _run(xml, "--list", "--approx", "diffuse")
    assert code == 0 and "diffuse —" in out and "sdf-occlusion —" not in out and "does not apply" not in out


def test_list_previews_the_run_of_method_names_and_user_files(tmp_path):
    """``--list --approx`` takes what the run takes: a shipped method (``half-lambert`` is the diffuse row,
    not the former experiment's whole family) lists that row alone, and a user file is validated and named
    with the families it is audited beside; a method that does not apply here is one line, exit 2."""
    xml = _cornell(tmp_path)
    code, out, err = _run(xml, "--list", "--approx", "half-lambert")
    assert code == 0, err
    assert "methods:    half-lambert\n" in out and "wrap" not in out and "sdf-occlusion" not in out
    mine = tmp_path / "mine.py"
    mine.write_text(
        "from rtfit import approximation\n\n\n@approximation(quantity='light_irradiance')\n"
        "def flat(ops, g):\n    return g.irradiance * ops.maximum(g.cos_theta, 0.0)\n"
    )
    code, out, err = _run(xml, "--list", "--approx", f"wrap,{mine}:flat")
    assert code == 0, err
    assert "methods:    wrap\n" in out and out.rstrip().endswith(
        "yours: flat (light_irradiance) — audited beside diffuse"
    )
    code, out, err = _run(xml, "--list", "--approx", "diffuse:exact")
    assert code == 2 and out == "" and err.count("\n") == 1 and "diffuse:exact does not apply" in err


def test_a_scene_no_family_applies_to_is_one_line(tmp_path):
    lonely = tmp_path / "lonely.xml"  # a light, but nothing for it to light
    lonely.write_text(
        f'<scene version="3.0.0"><default name="res" value="8"/>{_sensor()}'
        '<emitter type="point"><point name="position" x="0" y="1" z="0"/></emitter></scene>'
    )
    code, out, err = _run(lonely, "--list")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert "no approximation family applies to" in err and "point light" in err


def test_rtfit_toml_scenes(tmp_path):
    fams = _families(applicable_families(inspect_scene(library_path("irradiance_sphere_sunsky"))))
    assert set(fams) == {"diffuse", "irradiance-bases", "nishita-sky"}  # the sunsky's sky: a Nishita target
    assert "exact" in fams["diffuse"][0].methods  # the sunsky's sun has an angular radius
    sky = applicable_families(inspect_scene(library_path("sky_sun_10")))
    assert [a.family for a in sky] == ["nishita-sky"]
    code, _, err = _run(library_path("half_lambert_sphere"), "--list", "-D", "a=b")
    assert code == 2 and "-D is for Mitsuba XML scenes" in err
    code, out, _ = _run(library_path("half_lambert_sphere"), "--list", "--width", "20", "--height", "10")
    assert code == 0 and "camera: 20×10" in out and "up: +z: rtfit TOML scenes are +z up" in out
    xml = _cornell(tmp_path)
    with pytest.raises(AuditError, match="Mitsuba XML has no atmosphere type"):
        applicable_families(inspect_scene(xml), approx="nishita-sky")


# always with "light"
_LIGHT_KINDS = {"spherical-light", "punctual-light", "spot-light", "rect-light", "disc-light", "tube-light"}


def test_rules_are_data_and_reach_every_method():
    """Every family has a rule, and in a scene holding every kind of part every method of every table
    applies through some rule: nothing is reachable only by a name-specific branch."""
    assert {r.family for r in RULES} == set(METHOD_TABLES)
    everything = SceneInfo(
        source="all",
        format="test",
        parts=tuple(Part(frozenset({k, "light"} if k in _LIGHT_KINDS else {k}), k) for k in PROVIDES),
        bbox=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),
        up="+z",
        up_reason="",
        camera="",
    )
    found = applicable_families(everything)
    # Except the bare cap-intersection forms (r1, r2, d → Ω in sr): a scene has no per-pixel pair of caps to
    # give them; the ambient-aperture study compares them over (r1, r2, d), the audit each inside its
    # aa-<form>-* rows (`--list` says so in its "not here" line).
    for family, table in METHOD_TABLES.items():
        bare = {m for m, v in table.items() if v.quantity == "cap_intersection_solid_angle"}
        assert {m for a in found if a.family == family for m in a.methods} == set(table) - bare, family


def test_through_rtfits_entry_point_errors_exit_2(tmp_path, monkeypatch, capsys):
    """The lead adds ``cli.add_command(audit)``; here it is added for the test only. Through `main`, the
    command's errors are one line and exit 2 (not click's standalone handling), and a listing exits 0."""
    from rtfit.experiments.cli import cli, main

    monkeypatch.setitem(cli.commands, "audit", audit)
    xml = _cornell(tmp_path)
    bad = (
        [xml, "--approx", "phong"],
        [xml, "--list", "--approx", "phong"],
        [xml, "--list", "--camera", "-1"],
    )
    for argv in bad:
        assert main(["audit", *map(str, argv)]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.startswith("rtfit: error: ")
        assert captured.err.count("\n") == 1
    assert main(["audit", str(xml), "--list"]) == 0
    assert "applies:" in capsys.readouterr().out


def test_an_area_emitter_declared_in_an_include_and_referenced_by_id(tmp_path):
    """The pattern of Mitsuba's ``cbox-rgb.xml`` (the one an ElementTree edit broke: "unresolved reference
    to area-emitter"): the emitter is declared by id in an included file and ``<ref>``-ed by the shape."""
    (tmp_path / "common.xml").write_text(
        f'<scene version="3.0.0">{_sensor()}'
        '<emitter type="area" id="area-emitter"><rgb name="radiance" value="18, 14, 7"/></emitter></scene>'
    )
    (tmp_path / "cbox-rgb.xml").write_text(
        '<scene version="3.0.0"><default name="res" value="8"/><include filename="common.xml"/>\n'
        '<shape type="sphere" id="bulb"><float name="radius" value="0.1"/><ref id="area-emitter"/></shape>\n'
        '<shape type="cube"><transform name="to_world"><scale value="0.3"/></transform></shape></scene>'
    )
    x = inspect_xml(tmp_path / "cbox-rgb.xml")
    (e,) = x.emitters  # once: attached to the sphere, not also a free emitter
    assert (e.id, e.kind, e.shape, e.spherical) == ("area-emitter", "sphere", "sphere", True)
    assert e.radius == pytest.approx(0.1) and "common.xml (line 7" in e.location
    assert [s.emitter for s in x.shapes] == [True, False]
    fams = _families(applicable_families(inspect_scene(tmp_path / "cbox-rgb.xml")))
    assert "exact" in fams["diffuse"][0].methods


def test_distance_field_families_need_shapes_a_distance_field_reads(tmp_path):
    """A curve (Mitsuba's ``bsplinecurve``) is geometry the ray-cast families audit, but no distance field is
    built from it: the families that read one (sdf-occlusion; ambient-aperture's caps and fill) do not apply,
    saying why, before anything runs; rectangles (the walls) and meshes are read."""
    code, out, _ = _run(_cornell(tmp_path / "plain"), "--list")
    assert code == 0
    applies = out.split("does not apply:")[0]
    assert (
        "sdf-occlusion — ambient occlusion" in applies and "ambient-aperture — ambient occlusion" in applies
    )
    (tmp_path / "curved" / "assets").mkdir(parents=True)
    (tmp_path / "curved" / "assets" / "curve.txt").write_text(
        "-1 0 0 0.05\n-0.3 0 0 0.05\n0.3 0 0 0.05\n1 0 0 0.05\n"
    )
    curve = '<shape type="bsplinecurve"><string name="filename" value="curve.txt"/></shape>'
    code, out, _ = _run(_cornell(tmp_path / "curved", extra=curve), "--list")
    assert code == 0
    applies, rest = out.split("does not apply:")
    assert "sdf-occlusion" not in applies and "ambient-aperture — ambient occlusion" not in applies
    assert "obscurances — obscurance" in applies  # (ray-cast: the curve occludes as any shape does)
    assert "sdf-occlusion: needs" in rest and "not curves" in rest


def test_a_rectangles_triangles_are_mitsubas_rectangle(mi):
    """`audit_geometry`'s tessellation of a ``rectangle``: its four corners on Mitsuba's shape (a ray down
    onto each hits it there) and its area Mitsuba's."""
    from rtfit.experiments.audit_geometry import _shape_triangles

    shape = mi.load_dict({"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.5, -1.0, 2.0])
                          @ mi.ScalarTransform4f().scale([2.0, 0.5, 1.0])})  # fmt: skip
    v, f, _ = _shape_triangles(mi, shape)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    assert area == pytest.approx(float(shape.surface_area()[0]), rel=1e-6)
    inner = 0.999 * (v - v.mean(axis=0)) + v.mean(axis=0)  # (just inside each corner)
    for p in inner:
        ray = mi.Ray3f(mi.Point3f(float(p[0]), float(p[1]), float(p[2]) + 1.0), mi.Vector3f(0.0, 0.0, -1.0))
        si = shape.ray_intersect(ray)
        assert bool(si.is_valid()[0]) and float(si.t[0]) == pytest.approx(1.0, abs=1e-5)


def test_every_analytic_shape_the_xml_scan_calls_readable_is_read_by_the_distance_field(mi):
    """`audit_inspect_xml.SDF_SHAPE_PLUGINS` (what --list promises) and `audit_geometry` (what the field
    reads) name the same shapes: each analytic one loads and gives triangles; a curve does not."""
    from rtfit.experiments.audit_geometry import _shape_triangles
    from rtfit.experiments.audit_inspect_xml import SDF_SHAPE_PLUGINS

    for plugin in sorted(SDF_SHAPE_PLUGINS & {"sphere", "disk", "cylinder", "rectangle", "cube"}):
        assert _shape_triangles(mi, mi.load_dict({"type": plugin})) is not None, plugin
    assert "bsplinecurve" not in SDF_SHAPE_PLUGINS and "linearcurve" not in SDF_SHAPE_PLUGINS
