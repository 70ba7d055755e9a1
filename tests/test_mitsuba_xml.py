"""User Mitsuba XML scenes (`rtfit.reference.mitsuba_xml`): every file the parser loads is in the cache key.

The regression this guards: a scene whose mesh is reached through ``<include>`` and ``<path>`` (not beside
the XML) kept its cache key when the mesh was edited, so the stale reference came back. Here the mesh is
moved and the *rendered reference* must change, through the real cache and Mitsuba."""

from __future__ import annotations

import numpy as np
import pytest

from rtfit.reference import ReferenceCache, ReferenceRequest
from rtfit.reference.mitsuba_xml import XMLSceneError, inspect_xml, xml_dependencies
from rtfit.scenes.model import Camera, ConstantEnv, MitsubaXML, ReferenceSettings, Scene

PLY = (
    "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    "{a} {a} 0\n{b} {a} 0\n{b} {b} 0\n{a} {b} 0\n3 0 1 2\n3 0 2 3\n"
)


def _write_scene(root, lo=-1.0, hi=1.0):
    (root / "assets" / "meshes").mkdir(parents=True, exist_ok=True)
    (root / "assets" / "meshes" / "quad.ply").write_text(PLY.format(a=lo, b=hi))
    (root / "assets" / "geometry.xml").write_text(
        '<scene version="3.0.0">\n'
        '  <shape type="ply"><string name="filename" value="quad.ply"/></shape>\n</scene>\n'
    )
    (root / "scene.xml").write_text(
        '<scene version="3.0.0">\n  <path value="assets/meshes"/>\n'
        '  <include filename="assets/geometry.xml"/>\n</scene>\n'
    )
    return root / "scene.xml"


def _scene(xml) -> Scene:
    return Scene(
        name="xml-quad",
        camera=Camera(
            origin=(0.0, 0.0, 4.0),
            target=(0.0, 0.0, 0.0),
            up=(0.0, 1.0, 0.0),
            fov_deg=60.0,
            width=8,
            height=8,
        ),
        shapes=(MitsubaXML(file=str(xml)),),
        lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),),
        reference=ReferenceSettings(transport="direct"),
    )


def test_dependencies_cover_includes_and_path_meshes(tmp_path):
    xml = _write_scene(tmp_path)
    dep = xml_dependencies(xml)
    assert dep.xml_files == (str(xml), str(tmp_path / "assets" / "geometry.xml"))
    assert dep.data_files == (str(tmp_path / "assets" / "meshes" / "quad.ply"),)
    before = dep.digest
    _write_scene(tmp_path, lo=2.0, hi=4.0)
    assert xml_dependencies(xml).digest != before


def test_editing_a_mesh_behind_path_changes_the_reference(tmp_path):
    xml = _write_scene(tmp_path)
    cache = ReferenceCache(tmp_path / "cache")
    request = ReferenceRequest(scene=_scene(xml), spp=4, pass_spp=4, variant="llvm_ad_rgb")
    first = cache.get(request)
    _write_scene(tmp_path, lo=2.0, hi=4.0)  # every vertex moves off-centre: the quad leaves the middle pixels
    second = cache.get(ReferenceRequest(scene=_scene(xml), spp=4, pass_spp=4, variant="llvm_ad_rgb"))
    assert second.key != first.key
    assert second.passes_rendered == 1
    assert not np.array_equal(first.mean, second.mean)


def test_a_file_mitsuba_refuses_is_one_line_naming_it(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<scene version="3.0.0">\n  <shape type="ply">\n</scen>\n')
    with pytest.raises(XMLSceneError) as e:
        xml_dependencies(bad)
    msg = str(e.value)
    assert "\n" not in msg and str(bad) in msg and "line 3" in msg
    missing = tmp_path / "inc.xml"
    missing.write_text('<scene version="3.0.0">\n<include filename="nope.xml"/>\n</scene>\n')
    with pytest.raises(XMLSceneError, match=r"nope\.xml"):
        xml_dependencies(missing)


SPHERE_SCENE = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="1, -4, 2" target="1, 0, 2" up="0, 0, 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="$w"/><integer name="height" value="20"/></film>
  </sensor>
  <shape type="sphere">
    <transform name="to_world"><scale value="0.5"/><translate x="1" y="2" z="3"/></transform>
    <emitter type="area"><rgb name="radiance" value="2, 2, 2"/></emitter>
  </shape>
  <emitter type="directional"><vector name="direction" x="0" y="0" z="-2"/></emitter>
</scene>
"""


@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_inspect_reads_the_camera_and_lights_and_keeps_the_callers_variant(tmp_path, variant):
    mi = pytest.importorskip("mitsuba")
    (tmp_path / "s.xml").write_text(SPHERE_SCENE)
    caller = "llvm_ad_rgb" if variant == "scalar_rgb" else "scalar_rgb"
    mi.set_variant(caller)
    x = inspect_xml(tmp_path / "s.xml", {"w": "30"}, variant)
    assert mi.variant() == caller
    cam = x.camera
    assert cam.origin == pytest.approx((1.0, -4.0, 2.0)) and cam.target == pytest.approx((1.0, -3.0, 2.0))
    assert cam.up == pytest.approx((0.0, 0.0, 1.0)) and (cam.width, cam.height) == (30, 20)
    assert cam.fov_deg == 50.0 and cam.x_fov_deg == pytest.approx(50.0, rel=1e-6)
    assert x.up == "+z" and x.up_reason == "+z from sensor 0's up vector (0, 0, 1)"
    sphere, sun = x.emitters
    assert (sphere.kind, sphere.spherical) == ("sphere", True)
    assert sphere.position == pytest.approx((1.0, 2.0, 3.0), abs=1e-6) and sphere.radius == pytest.approx(0.5)
    assert sphere.scale == (2.0, 2.0, 2.0)
    assert (sun.kind, sun.direction, sun.angular_radius_deg) == ("directional", (0.0, 0.0, 1.0), 0.0)
    assert inspect_xml(tmp_path / "s.xml", {"w": "30"}, variant, up="-y", width=8).up == "-y"
    with pytest.raises(XMLSceneError, match=r"--camera 1: the scene has 1 sensor"):
        inspect_xml(tmp_path / "s.xml", {"w": "30"}, variant, camera=1)
