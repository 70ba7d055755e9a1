"""The environment and occlusion families audit rtfit TOML scenes (issue 30: "every one of the 14 families has
an audit test on a small XML scene and on a TOML scene"): irradiance-bases (the environment of a TOML
scene's ``constant_env`` / ``envmap`` / ``sunsky`` light), sdf-occlusion (ambient occlusion and sky
occlusion) and ambient-aperture (caps, aperture fill, occluded sphere light), on scenes written here.

Expected values come from closed forms, not from the audit's own code:

* a constant environment of radiance L: E(n) = πL at every unoccluded normal (per channel); a uniform sky
  of radiance L over the upper hemisphere: E(n) = πL(1 + n_z)/2;
* AO within R of a floor point farther than R from every other shape is exactly 1 (no ray can hit);
* the sky irradiance of the cube's top face, above every other shape, is πL (nothing above its horizon);
* a sphere light of radius r and radiance L wholly above a floor point's horizon and unoccluded gives the
  floor point E = π L sin²α cos θ = π L r² z_c / d³ (Lambert's law for a sphere; z_c its centre's height,
  d the distance to it);
* a sun nothing hides gives E⊥·(n·d) with E⊥ of Mitsuba's own sunsky loaded without its sky (the last test,
  on Mitsuba XML: the occluded-sphere-light role now reads the sun of an XML sunsky too).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import rtfit
from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import inspect_scene

FAST = {"metrics": ("rmse",), "cost_elements": 1 << 10}
EXACT_AND_SH = ["irradiance-bases:quadrature", "irradiance-bases:sh-l2"]  # (the other rows: the first test)
L_ENV = (1.0, 2.0, 0.5)
FURNACE = """
name = "furnace-sun"
[camera]
origin = [0.0, -6.0, 0.0]
target = [0.0, 0.0, 0.0]
fov_deg = 24.0
width = 16
height = 16
[[shapes]]
type = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
[[lights]]
type = "constant_env"
radiance = [1.0, 2.0, 0.5]
[[lights]]
type = "sun"
direction = [0.3, -1.0, 0.5]
irradiance = 3.0
angular_radius_deg = 2.0
"""
R_AO = 0.5
SPHERE = {"centre": (2.5, 0.0, 0.6), "radius": 0.3, "radiance": 4.0}
BLOCK = f"""
name = "block"
[camera]
origin = [1.0, -5.0, 4.0]
target = [1.0, 0.0, 0.3]
fov_deg = 50.0
width = 20
height = 20
[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [12.0, 12.0]
[[shapes]]
type = "cube"
center = [0.0, 0.0, 0.5]
size = [1.0, 1.0, 1.0]
[[lights]]
type = "constant_env"
radiance = 2.0
[[lights]]
type = "sphere_light"
center = {list(SPHERE["centre"])}
radius = {SPHERE["radius"]}
radiance = {SPHERE["radiance"]}
"""


def _z(ref: np.ndarray, err: np.ndarray, want) -> np.ndarray:
    """(reference − expected)/σ, σ the standard error plus a float32 floor."""
    return (ref - want) / (err + 1e-6 * np.abs(want) + 1e-12)


def test_irradiance_bases_reads_a_toml_constant_environment_without_the_folded_sun(tmp_path):
    """A ``constant_env`` that rtfit folds into a finite sun's emitter is audited alone: the reference, the
    exact row and the SH L2 row are πL per channel (not πL plus the sun), and nothing is noted as not
    audited on rtfit-toml scenes."""
    path = tmp_path / "furnace.toml"
    path.write_text(FURNACE)
    r = rtfit.audit(path, "irradiance-bases", spp=16, fit=False, cache=tmp_path / "c", **FAST)
    assert [c.id for c in r.cases] == ["env0", "env0-lightmap"]
    case = r.cases[0]
    assert case.parameters["kind"] == "constant"
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    want = math.pi * np.asarray(L_ENV)
    z = _z(ref, err, want)
    assert np.max(np.abs(z)) < 5.0 and abs(float(np.median(z))) < 0.5
    for row in ("quadrature", "sh-l2"):
        np.testing.assert_allclose(r.image(case.id, row)[case.mask], np.tile(want, (len(ref), 1)), rtol=1e-4)
    assert not [s for s in r.skipped if "not audited yet" in s]


SUNSKY_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="24"/>
        <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="sphere"><float name="radius" value="1"/></shape>
    <emitter type="sunsky"><vector name="sun_direction" x="0.4330127018922193" y="0.75" z="0.5"/></emitter>
</scene>
"""


def test_irradiance_bases_reads_a_toml_sunsky_as_mitsuba_xml_gives_it(tmp_path):
    """The library's TOML sunsky scene and the same scene written as Mitsuba XML (Mitsuba's own loader, the
    same defaults: turbidity 3, albedo 0.3, aperture 0.5358°): the same environment, so the same reference
    (same seeds) and the same exact row (the emitter's quadrature, its sun a disc of half the aperture), and
    the same bake parameters. (The exact row's z-scores are tests/test_audit_environment.py's question; on
    this scene, sun at 30°, the quadrature sits 0.7–1.6 % above the MIS reference, median z 0.24 at 256 spp
    — over the run's ±0.15 — for both formats alike.)"""
    from rtfit.scenes import library_path, load_scene

    path = library_path("irradiance_sphere_sunsky")
    sky = load_scene(path).lights[0]
    (tmp_path / "s.xml").write_text(SUNSKY_XML)
    runs = [
        rtfit.audit(p, EXACT_AND_SH, width=8, height=8, spp=8, fit=False, cache=tmp_path / "c", **FAST)
        for p in (path, tmp_path / "s.xml")
    ]
    toml, xml = (r.cases[0] for r in runs)
    assert toml.parameters["kind"] == xml.parameters["kind"] == "sunsky"
    assert toml.parameters["sun_angular_radius_deg"] == pytest.approx(sky.sun_aperture_deg / 2)
    np.testing.assert_array_equal(toml.mask, xml.mask)
    m = toml.mask
    np.testing.assert_allclose(toml.reference.mean[m], xml.reference.mean[m], rtol=1e-4, atol=1e-7)
    quad = runs[0].image(toml.id, "quadrature")[m]
    np.testing.assert_allclose(quad, runs[1].image(xml.id, "quadrature")[m], rtol=1e-4, atol=1e-7)


ENVMAP = """
name = "half-sky"
[camera]
origin = [0.0, -6.0, 0.0]
target = [0.0, 0.0, 0.0]
fov_deg = 24.0
width = 12
height = 12
[[shapes]]
type = "sphere"
center = [0.0, 0.0, 0.0]
radius = 1.0
[[lights]]
type = "envmap"
file = "half.exr"
scale = 2.0
"""


def test_irradiance_bases_reads_a_toml_envmap_turned_to_z_up(tmp_path):
    """A TOML ``envmap`` of radiance 1 in the upper half of its rows (Mitsuba's +Y up, turned to world +Z by
    rtfit's build), scale 2: a uniform sky of L = 2 over z > 0, whose irradiance is E(n) = πL(1 + n_z)/2 at
    every unoccluded normal; within 5σ plus 0.02 (the map's bilinear horizon, one texel of 64 rows)."""
    from rtfit.reference.environments import write_map_exr
    from rtfit.reference.variants import scoped_variant

    img = np.zeros((64, 128, 3), np.float32)
    img[:32] = 1.0
    with scoped_variant("llvm_ad_rgb"):
        write_map_exr(img, tmp_path / "half.exr")
    (tmp_path / "half.toml").write_text(ENVMAP)
    path = tmp_path / "half.toml"
    r = rtfit.audit(path, EXACT_AND_SH, spp=32, fit=False, cache=tmp_path / "c", **FAST)
    case = r.cases[0]
    assert case.parameters["kind"] == "envmap"
    nz = case.channel_inputs[0]["nz"]
    want = math.pi * 2.0 * (1.0 + nz) / 2.0
    ref, err = case.reference.mean[case.mask][:, 1], case.reference.stderr[case.mask][:, 1]
    assert np.all(np.abs(ref - want) < 5 * err + 0.02)
    assert nz.min() < -0.5 and nz.max() > 0.5


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """The block scene audited once by sdf-occlusion and ambient-aperture (every role)."""
    d = tmp_path_factory.mktemp("block")
    (d / "block.toml").write_text(BLOCK)
    r = rtfit.audit(
        d / "block.toml", ["sdf-occlusion", "ambient-aperture"], spp=32, ao_distance=R_AO, fit=False,
        cache=d / "c", **FAST,
    )  # fmt: skip
    return d / "block.toml", r


def test_list_and_run_agree_on_a_toml_scene(block):
    """Every applicability `--list` names for these families is a case of the run."""
    path, r = block
    found = applicable_families(inspect_scene(path), approx=["sdf-occlusion", "ambient-aperture"])
    assert len(found) == 5  # sky occlusion, aperture fill, AO, aperture caps, occluded sphere light
    assert [c.id for c in r.cases] == ["fill0", "caps", "light1-occluded", "sky0", "ao"]  # registry order
    assert not [s for s in r.skipped if "not audited yet" in s]


def _points(r, case_id: str = "ao"):
    inp = next(c for c in r.cases if c.id == case_id).channel_inputs[0]
    return np.stack([inp["px"], inp["py"], inp["pz"]], 1), np.stack([inp["nx"], inp["ny"], inp["nz"]], 1)


def _to_cube(p: np.ndarray) -> np.ndarray:
    """Horizontal distance from floor points to the cube's footprint [−½, ½]²."""
    gap = np.maximum(np.abs(p[:, :2]) - 0.5, 0.0)
    return np.hypot(gap[:, 0], gap[:, 1])


def test_ao_is_one_on_the_floor_far_from_the_occluders(block):
    """Floor points farther than R from the cube and the sphere light: AO = 1 exactly (no ray can hit);
    near the cube's foot it is below 1."""
    _, r = block
    case = next(c for c in r.cases if c.id == "ao")
    p, n = _points(r)
    ao = case.reference.mean[case.mask][:, 0]
    floor = (np.abs(p[:, 2]) < 1e-4) & (n[:, 2] > 0.999)
    to_cube = _to_cube(p)
    to_sphere = np.linalg.norm(p - np.asarray(SPHERE["centre"]), axis=1) - SPHERE["radius"]
    far = floor & (to_cube > R_AO + 0.02) & (to_sphere > R_AO + 0.02)
    near = floor & (to_cube < 0.1)
    assert far.sum() > 50 and near.sum() > 0
    np.testing.assert_array_equal(ao[far], 1.0)
    assert np.all(ao[near] < 0.95)
    for rid in r.outcomes["ao"]:
        assert np.all(np.isfinite(r.image("ao", rid)[case.mask]))


def test_sky_occlusion_is_pi_l_on_the_top_face(block):
    """The cube's top face (z = 1, above every other shape): sky irradiance with visibility πL (L = 2)
    within the reference's noise; occluded floor points near the cube receive less."""
    _, r = block
    case = next(c for c in r.cases if c.id == "sky0")
    p, n = _points(r, "sky0")
    ref, err = case.reference.mean[case.mask][:, 0], case.reference.stderr[case.mask][:, 0]
    top = (np.abs(p[:, 2] - 1.0) < 1e-4) & (n[:, 2] > 0.999)
    assert top.sum() >= 4
    z = _z(ref[top], err[top], 2.0 * math.pi)
    assert np.max(np.abs(z)) < 5.0
    near = (np.abs(p[:, 2]) < 1e-4) & (_to_cube(p) < 0.1)  # a wall of the cube hides ≳ 1/4 of the sky
    assert near.sum() > 0 and np.all(ref[near] < 2.0 * math.pi * 0.85)
    for cid in ("sky0", "fill0"):
        for rid in r.outcomes[cid]:
            assert np.all(np.isfinite(r.image(cid, rid)))


def test_occluded_sphere_light_is_lamberts_sphere_on_the_open_floor(block):
    """Floor points with x > 0.6 see the whole sphere light above their horizon and the cube behind them:
    the shadowed irradiance is π L r² z_c / d³ within the reference's noise; the caps case reads AO."""
    _, r = block
    case = next(c for c in r.cases if c.id == "light1-occluded")
    p, n = _points(r)
    ref, err = case.reference.mean[case.mask][:, 0], case.reference.stderr[case.mask][:, 0]
    c = np.asarray(SPHERE["centre"])
    d = np.linalg.norm(c - p, axis=1)
    open_floor = (np.abs(p[:, 2]) < 1e-4) & (n[:, 2] > 0.999) & (p[:, 0] > 0.6)
    want = math.pi * SPHERE["radiance"] * SPHERE["radius"] ** 2 * c[2] / d**3
    assert open_floor.sum() > 20
    z = _z(ref[open_floor], err[open_floor], want[open_floor])
    assert np.max(np.abs(z)) < 5.0 and abs(float(np.median(z))) < 1.0
    assert case.parameters["kind"] == "sphere"
    assert "fill-projected" in r.outcomes["caps"]


SUNSKY_BLOCK_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="1, -5, 4" target="1, 0, 0.3" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="6"/></transform></shape>
    <shape type="cube"><transform name="to_world"><scale value="0.5"/><translate z="0.5"/></transform></shape>
    <emitter type="sunsky"><vector name="sun_direction" x="0.3" y="-0.5" z="0.6"/></emitter>
</scene>
"""


def test_the_sun_of_an_xml_sunsky_is_an_occluded_sphere_light(tmp_path):
    """The occluded-sphere-light role reads its light through `audit_lights.scene_light` for both formats, so
    the sun of a Mitsuba XML ``sunsky``, which ``--list`` names as a spherical light, is audited (it was
    refused mid-run: "the audit samples lights, not environments"): on the cube's top face, nothing between
    it and the sun, its shadowed irradiance is E⊥·n_z with E⊥ that of Mitsuba's sunsky loaded with
    ``sky_scale`` 0 (`environments.sunsky_sun_irradiance`, samples of its own)."""
    import mitsuba as mi

    from rtfit.reference.environments import sunsky_sun_irradiance

    (tmp_path / "s.xml").write_text(SUNSKY_BLOCK_XML)
    r = rtfit.audit(
        tmp_path / "s.xml",
        "ambient-aperture",
        spp=8,
        fit=False,
        ao_distance=0.5,
        cache=tmp_path / "c",
        **FAST,
    )
    assert [c.id for c in r.cases] == ["fill0", "caps", "light0-occluded"]
    case = r.cases[-1]
    assert case.parameters["kind"] == "sunsky sun"
    p, n = _points(r, "caps")
    top = (np.abs(p[:, 2] - 1.0) < 1e-4) & (n[:, 2] > 0.999)
    assert top.sum() >= 2
    d = np.array([0.3, -0.5, 0.6]) / np.linalg.norm([0.3, -0.5, 0.6])
    mi.set_variant("llvm_ad_rgb")
    e_sun, _ = sunsky_sun_irradiance(
        mi, mi.load_dict({"type": "sunsky", "sun_direction": d.tolist(), "sky_scale": 0.0}), d
    )
    ref = case.reference.mean[case.mask][top]
    np.testing.assert_allclose(ref, np.tile(e_sun * d[2], (int(top.sum()), 1)), rtol=0.02)
