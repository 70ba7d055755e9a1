"""`rtfit export-xml`: an rtfit TOML scene written as plain Mitsuba 3 XML (issue 15 §1). The oracle is
Mitsuba itself: the XML, loaded by a stock `mitsuba.load_file`, renders the same image as the scene rtfit
builds in memory (same integrator, seed and sample count), and rtfit's own plugins are named as left out."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.export_xml import export_xml, exportable_dict
from rtfit.scenes import library_path, load_scene


@pytest.mark.parametrize("name", ["sdf_sphere_plane", "aperture_bumps", "irradiance_sphere_sunsky"])
def test_exported_xml_renders_what_rtfit_renders(mi, tmp_path, name):
    scene = load_scene(library_path(name))
    out = tmp_path / name / f"{name}.xml"
    out.parent.mkdir()
    result = export_xml(scene, out)
    assert result.left_out == ()  # stock plugins only
    d = mitsuba_scene_dict(mi, scene)
    d["sensor"]["film"].update({"width": 24, "height": 16})
    ours = np.array(mi.render(load_dict(mi, d), spp=16, seed=3))
    theirs_scene = mi.load_file(str(out), resx=24, resy=16)
    theirs = np.array(mi.render(theirs_scene, spp=16, seed=3))
    assert theirs.shape == ours.shape
    # Same scene, same sampler: the images agree up to float32 round-off of the written transforms
    # (the XML holds each matrix entry to 17 digits; measured max |Δ| 0 to 3e-7 of the peak).
    np.testing.assert_allclose(theirs, ours, rtol=0, atol=1e-5 * max(float(ours.max()), 1e-6))


def test_rtfit_plugins_are_left_out_and_named(mi, tmp_path):
    scene = load_scene(library_path("fog_volumes"))
    d = mitsuba_scene_dict(mi, scene)
    kept, left = exportable_dict(d)
    assert {k for k in d if k.startswith("medium")} == {
        "medium0",
        "medium1",
        "medium0_boundary",
        "medium1_boundary",
    }
    assert not any(k.startswith("medium") for k in kept)
    assert len(left) == 4 and all("exponential height-fog" in x or "boundary shape" in x for x in left)
    out = export_xml(scene, tmp_path / "fog.xml")
    loaded = mi.load_file(str(out.path), resx=8, resy=4)
    assert len(loaded.shapes()) == len([k for k in kept if k.startswith("shape")])


def test_a_disc_sun_is_left_out(mi, tmp_path):
    scene = load_scene(library_path("half_lambert_sphere"))
    result = export_xml(scene, tmp_path / "hl.xml")
    assert any("distant-disc sun" in x for x in result.left_out)
    assert mi.load_file(str(result.path)).emitters() == []


def test_cli_export_and_bad_input(tmp_path):
    rtfit = [sys.executable, "-m", "rtfit"]
    ok = subprocess.run(
        [*rtfit, "export-xml", "fog_volumes", str(tmp_path / "f.xml")], capture_output=True, text=True
    )
    assert ok.returncode == 0, ok.stderr
    assert ok.stderr.count("rtfit: left out ") == 4
    bad = subprocess.run(
        [*rtfit, "export-xml", "no_such_scene", str(tmp_path / "x.xml")], capture_output=True, text=True
    )
    assert bad.returncode == 2
    assert bad.stderr.strip().count("\n") == 0 and "no library scene named" in bad.stderr
    assert not (tmp_path / "x.xml").exists()
    sky = subprocess.run(
        [*rtfit, "export-xml", str(library_path("sky_sun_10")), str(tmp_path / "s.xml")],
        capture_output=True,
        text=True,
    )
    assert sky.returncode == 2 and "not a scene" in sky.stderr
