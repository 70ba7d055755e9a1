"""The diffuse family audits the lights of rtfit TOML scenes (issue 30 §2): sphere lights, a sun of finite
angular radius (without the constant sky rtfit folds into its emitter), the sun of a ``sunsky`` (without its
sky), point, spot, rectangle and directional lights — from Python and from the command line.

Expected values come from independent computations: a midpoint quadrature of the sphere light's cap of
directions (not the closed form the exact row evaluates), the declared irradiance of a sun, Mitsuba's own
``sunsky`` loaded with ``sky_scale`` 0, and the inverse-square law of a point light."""

from __future__ import annotations

import json
import math

import numpy as np
from click.testing import CliRunner

import rtfit
from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import inspect_scene
from rtfit.experiments.audit_cli import audit as audit_cli
from rtfit.scenes import library_path, load_scene


def _cap_irradiance(cos_theta: np.ndarray, alpha: np.ndarray, radiance: float, n: int = 160) -> np.ndarray:
    """E = L ∫_cap max(n·ω, 0) dω over the cap of half-angle α around t, n·t = cos θ: the midpoint rule on
    (γ, φ) in t's frame, γ ∈ [0, α] (n rings), φ ∈ [0, 2π) (2n azimuths), dω = sin γ dγ dφ."""
    out = np.zeros(len(cos_theta))
    for i, (c, a) in enumerate(zip(cos_theta, alpha, strict=True)):
        g = (np.arange(n) + 0.5) * a / n
        phi = (np.arange(2 * n) + 0.5) * math.pi / n
        gg, pp = np.meshgrid(g, phi, indexing="ij")
        s = math.sqrt(max(1.0 - c * c, 0.0))
        ndotw = s * np.sin(gg) * np.cos(pp) + c * np.cos(gg)
        out[i] = radiance * np.sum(np.maximum(ndotw, 0.0) * np.sin(gg)) * (a / n) * (math.pi / n)
    return out


def test_python_audit_of_the_sphere_light_scene_returns_metrics_and_fits_and_keeps_the_variant(tmp_path):
    """`rtfit.audit("…/sphere_light.toml")`: the unshadowed reference is the cap quadrature within the
    reference's noise, the exact row is the quadrature, every row has metrics, the wrap row is fitted, and
    the caller's Mitsuba variant is the same after the call."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    r = rtfit.audit(
        library_path("sphere_light"), width=24, height=24, spp=32, cache=tmp_path / "c",
        metrics=("rmse", "mae"),
    )  # fmt: skip
    assert mi.variant() == "scalar_rgb"
    assert [c.id for c in r.cases][:2] == ["light0-unshadowed", "light0-shadowed"]  # (then obscurances)
    assert set(r.outcomes["light0-unshadowed"]) == {
        "lambert",
        "half-lambert",
        "wrap",
        "wrap-fitted",
        "exact",
        "punctual",
        "unreal-window-fitted",
        "frostbite-window-fitted",
        "representative-point",
    }  # fmt: skip (the light models of a sphere light; the windows' r has no published value: fitted only)
    for row in r.outcomes["light0-unshadowed"]:
        assert math.isfinite(r.metrics("light0-unshadowed", row)["rmse"].value)
    fit = r.fits["light0-unshadowed/wrap-fitted"]
    assert set(fit) == {"w", "p"} and all(math.isfinite(v["value"]) for v in fit.values())
    assert all(c.passed for c in r.results.checks)  # the exact form's z-scores are standard normal

    case = r.cases[0]
    inp = case.channel_inputs[1]
    assert inp["radiance"] == 10.0  # the scene's declared radiance
    quad = _cap_irradiance(inp["cos_theta"], inp["alpha"], 10.0)
    ref = case.reference.mean[case.mask][:, 1]
    err = case.reference.stderr[case.mask][:, 1]
    exact = r.image(case.id, "exact")[case.mask][:, 1]
    lit = quad > 1e-3 * quad.max()
    assert np.max(np.abs(exact - quad)[lit] / quad[lit]) < 2e-3  # the closed form is the quadrature
    z = (quad - ref)[err > 0] / err[err > 0]
    assert abs(float(np.median(z))) < 0.3 and np.mean(np.abs(z) > 4) < 0.02
    # E⊥ = π L sin²α on a surface facing the light (its own samples): the cap quadrature at cos θ = 1
    e_perp = inp["irradiance"]
    want = _cap_irradiance(np.ones(len(e_perp)), inp["alpha"], 10.0)
    assert np.allclose(e_perp, want, rtol=0.02)


def test_cli_audits_the_sphere_light_library_scene(tmp_path):
    """`rtfit audit sphere_light --width 24 --height 24 --spp 32 --approx irradiance-volumes` exits 0 with a
    report. irradiance-volumes' nearest-sh-l2 rings below 0 on 3 pixels of this scene (min −8.5e-4: SH L2
    ringing, a property of the basis); ꟻLIP clips them to 0 and warns: the engine keeps that as a note of the
    report (under the suite's filterwarnings = error a warning leaking out of the run would fail it). (Every
    family of this scene is audited by the Python test above through the same engine; here the command line
    runs the one family whose note it checks: 1.5 s instead of 13 s.)"""
    result = CliRunner().invoke(
        audit_cli,
        ["sphere_light", "--width", "24", "--height", "24", "--spp", "32", "--approx", "irradiance-volumes",
         "--out", str(tmp_path / "out"), "--cache", str(tmp_path / "c"), "--no-progress"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    report = tmp_path / "out" / "audit-sphere_light"
    assert (report / "report.html").is_file() and (report / "results.json").is_file()
    assert str(report / "report.html") in result.stdout
    notes = json.loads((report / "results.json").read_text())["notes"]
    assert any("nearest-sh-l2" in n and "clipped to 0" in n for n in notes)


LIGHTS = """
name = "lights"
[camera]
origin = [0.0, -6.0, 3.0]
target = [0.0, 0.0, 0.5]
fov_deg = 40.0
width = 12
height = 12
[[shapes]]
type = "sphere"
center = [0.0, 0.0, 1.0]
radius = 1.0
[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [8.0, 8.0]
[[lights]]
type = "point_light"
position = [1.5, -1.5, 3.0]
intensity = 4.0
[[lights]]
type = "spot_light"
position = [-1.5, -1.5, 3.0]
axis = [0.3, 0.3, -1.0]
intensity = 4.0
cutoff_angle_deg = 40
beam_width_deg = 30
[[lights]]
type = "rect_light"
center = [0.0, 2.0, 3.0]
normal = [0.0, -0.5, -1.0]
size = [1.0, 0.5]
radiance = 5.0
[[lights]]
type = "sun"
direction = [1.0, -0.5, 1.0]
irradiance = 2.0
angular_radius_deg = 5.0
[[lights]]
type = "sun"
direction = [-1.0, -1.0, 2.0]
irradiance = 0.5
[[lights]]
type = "constant_env"
radiance = 5.0
"""


def test_every_light_of_a_toml_scene_is_audited_alone(tmp_path):
    """Point, spot, rectangle, finite sun, directional sun: one pair of cases each. The point light's
    unshadowed irradiance is I·max(n·t, 0)/d² (one emitter sample is exact; Lambert equals it to float32);
    the finite sun's E⊥ is its declared irradiance (2), not 2 + the constant sky folded into its emitter; the
    directional sun's is 0.5."""
    path = tmp_path / "lights.toml"
    path.write_text(LIGHTS)
    r = rtfit.audit(path, "diffuse", spp=8, fit=False, cache=tmp_path / "c", metrics=("rmse",))
    assert [c.id for c in r.cases] == [f"light{i}-{s}" for i in range(5) for s in ("unshadowed", "shadowed")]
    case = r.cases[0]
    scene = load_scene(path)
    pos = np.asarray(scene.lights[0].position)
    cos, dist = case.channel_inputs[0]["cos_theta"], case.channel_inputs[0]["distance"]
    want = 4.0 * np.maximum(cos, 0.0) / dist**2
    assert np.allclose(case.reference.mean[case.mask][:, 0], want, rtol=1e-5, atol=1e-7)
    assert r.metrics(case.id, "lambert")["rmse"].value < 1e-6
    assert np.all(dist > 0) and pos[2] == 3.0
    sun = next(c for c in r.cases if c.id == "light3-unshadowed")
    assert "exact" in r.outcomes[sun.id]  # a finite sun is a spherical light
    assert np.allclose(sun.channel_inputs[0]["irradiance"], 2.0, rtol=2e-3)
    assert np.allclose(sun.channel_inputs[0]["radiance"], 2.0 / (math.pi * math.sin(math.radians(5)) ** 2))
    directional = next(c for c in r.cases if c.id == "light4-unshadowed")
    assert np.allclose(directional.channel_inputs[0]["irradiance"], 0.5, rtol=1e-5)
    assert np.all(np.isinf(directional.channel_inputs[0]["distance"]))


def test_the_sun_of_a_toml_sunsky_is_sampled_without_its_sky(tmp_path):
    """The sunsky's sun: E⊥ is Mitsuba's own sunsky loaded with ``sky_scale`` 0 (its emitter-sampling
    estimate, `environments.sunsky_sun_irradiance`), far below the sun + sky; α is half the aperture."""
    import mitsuba as mi

    from rtfit.reference.environments import sunsky_sun_irradiance

    scene = load_scene(library_path("irradiance_sphere_sunsky"))
    found = applicable_families(inspect_scene(library_path("irradiance_sphere_sunsky")), approx="diffuse")
    assert [a.source for a in found] == [0]
    r = rtfit.audit(
        library_path("irradiance_sphere_sunsky"), "diffuse", width=8, height=8, spp=8, fit=False,
        cache=tmp_path / "c", metrics=("rmse",),
    )  # fmt: skip
    case = r.cases[0]
    sky = scene.lights[0]
    mi.set_variant("llvm_ad_rgb")
    sun_only = mi.load_dict(
        {"type": "sunsky", "sun_direction": list(sky.sun_direction), "turbidity": sky.turbidity,
         "albedo": sky.albedo, "sun_aperture": sky.sun_aperture_deg, "sky_scale": 0.0}
    )  # fmt: skip
    e_sun, _ = sunsky_sun_irradiance(mi, sun_only, np.asarray(sky.sun_direction))
    for c in range(3):
        assert np.allclose(case.channel_inputs[c]["irradiance"], e_sun[c], rtol=0.01)
    assert np.allclose(case.channel_inputs[0]["alpha"], math.radians(sky.sun_aperture_deg / 2))


SUNSKY_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="sphere"><float name="radius" value="1"/></shape>
    <emitter type="sunsky"><vector name="sun_direction" x="0.3" y="-0.5" z="0.6"/></emitter>
</scene>
"""


def test_the_sun_of_an_xml_sunsky_is_audited_as_its_list_says(tmp_path):
    """`--list` names the sun of a Mitsuba XML sunsky as a light (issue 31: the run used to refuse it): it
    is audited alone (E⊥ of Mitsuba's sunsky with ``sky_scale`` 0), α = half the default aperture 0.5358°."""
    import mitsuba as mi

    from rtfit.reference.environments import sunsky_sun_irradiance

    (tmp_path / "s.xml").write_text(SUNSKY_XML)
    r = rtfit.audit(tmp_path / "s.xml", "diffuse", spp=8, fit=False, cache=tmp_path / "c", metrics=("rmse",))
    case = r.cases[0]
    assert case.id == "light0-unshadowed" and "exact" in r.outcomes[case.id]
    mi.set_variant("llvm_ad_rgb")
    d = np.array([0.3, -0.5, 0.6]) / np.linalg.norm([0.3, -0.5, 0.6])
    sun_only = mi.load_dict({"type": "sunsky", "sun_direction": d.tolist(), "sky_scale": 0.0})
    e_sun, _ = sunsky_sun_irradiance(mi, sun_only, d)
    for c in range(3):
        assert np.allclose(case.channel_inputs[c]["irradiance"], e_sun[c], rtol=0.01)
    assert np.allclose(case.channel_inputs[0]["alpha"], math.radians(0.5358 / 2))


def test_the_white_furnace_toml_scene_is_audited_by_irradiance_bases(tmp_path):
    """A sphere in a constant sky of radiance 1 (once refused: irradiance-bases read Mitsuba XML only) is
    audited: its one family's reference is E = π within the noise, nothing noted as not audited."""
    r = rtfit.audit(
        library_path("white_furnace_sphere"), width=8, height=8, spp=8, fit=False, cache=tmp_path / "c",
        metrics=("rmse",), cost_elements=1 << 10,
    )  # fmt: skip
    case = r.cases[0]
    assert case.id == "env0" and not [s for s in r.skipped if "not audited yet" in s]
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    assert np.all(np.abs(ref - math.pi) < 5 * err + 1e-5)
