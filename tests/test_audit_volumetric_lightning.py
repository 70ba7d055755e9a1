"""`rtfit audit` of the volumetric-lightning family: a point light inside a homogeneous medium, on a small
Mitsuba XML scene (the medium on the sensor, and one bounded by a cube seen from outside) and on a small rtfit
TOML scene.

Independent values: Mitsuba's own ``volpathmis`` with max_depth 2 (single scattering by free-flight sampling,
a black floor so that nothing but the medium scatters) at the same pixel centres (`radiance_pass`) against
the audit's reference (equiangular sampling, `rtfit.reference.medium_lights`); the exact row is the
Gauss–Legendre quadrature of `rtfit.reference.single_scattering` (checked against mpmath in
tests/test_volumetric_lightning.py) and must sit at the reference's noise (the engine's z-checks); a user's
formula is compared with the same formula written here in NumPy. Renders are 20×20 pixels, ≤ 256 spp."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit

FAST = {"cost_elements": 1 << 12, "metrics": ("rmse", "rel_mse", "mae", "max_abs")}

XML = """<scene version="3.0.0">
  <integrator type="volpathmis"><integer name="max_depth" value="2"/></integrator>
  <medium type="homogeneous" id="fog">
    <rgb name="albedo" value="0.8"/>
    <float name="sigma_t" value="0.3"/>
    <phase type="hg"><float name="g" value="0.3"/></phase>
  </medium>
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, -4, 1" target="0, 0, 0.5" up="0, 0, 1"/></transform>
    <float name="fov" value="60"/>
    <float name="near_clip" value="0.0001"/>
    {sensor_medium}
    <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="20"/></film>
  </sensor>
  <emitter type="point" id="lamp"><point name="position" {light}/><rgb name="intensity" value="5"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf></shape>
  {cube}
</scene>
"""
CUBE = """<shape type="cube">
    <transform name="to_world"><scale value="0.8"/><translate x="0.2" z="0.9"/></transform>
    <bsdf type="null"/><ref name="interior" id="fog"/></shape>"""

TOML = """name = "lamp-in-fog"
[camera]
origin = [0.0, -4.0, 1.0]
target = [0.0, 0.0, 0.5]
up = [0.0, 0.0, 1.0]
fov_deg = 60.0
width = 20
height = 20

[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [6.0, 6.0]
material = { type = "diffuse", reflectance = 0.5 }

[[lights]]
type = "point_light"
position = [0.3, 0.2, 1.2]
intensity = 5.0
%s
[[media]]
type = "homogeneous"
boundary = { type = "cube", center = [0.0, 0.0, 1.49], size = [8.0, 10.0, 3.0] }
sigma_t = [0.2, 0.3, 0.4]
albedo = 0.9
g = -0.2
"""

MY_LIGHT = '''
from rtfit import approximation, Param


@approximation(quantity="inscattered_radiance", params={"c": Param(1.0, lower=0.0, upper=10.0)})
def flat_glow(ops, g, *, c):
    """c·σ_s·I/(4π)·|d|/(|l − o|² + 1): a crude glow."""
    lx, ly, lz = g.lx - g.ox, g.ly - g.oy, g.lz - g.oz
    length = ops.sqrt(g.dx * g.dx + g.dy * g.dy + g.dz * g.dz)
    level = c * g.sigma_s * g.intensity / (4.0 * 3.141592653589793)
    return level * length / (lx * lx + ly * ly + lz * lz + 1.0)
'''


DATA = Path(__file__).parent / "data" / "mitsuba" / "media"


def _xml(tmp_path, *, in_cube: bool = False, light: str = 'x="0.3" y="0.2" z="1.2"') -> str:
    text = XML.format(
        sensor_medium="" if in_cube else '<ref id="fog"/>', light=light, cube=CUBE if in_cube else ""
    )
    path = tmp_path / ("cube.xml" if in_cube else "fog.xml")
    path.write_text(text)
    return str(path)


def _checks(r) -> dict:
    return {c.name.rsplit(": ", 1)[1].split(" (")[0]: c for c in r.results.checks}


def _exact_row_at_noise(r, case) -> None:
    """The engine's z-checks of the exact row: the spread and tail checks pass; the median is asserted within
    3 of its own standard errors (1.2533/√n for n pixels: the three channels of a pixel share their samples,
    so the engine's ±0.15 on 3n elements fails by chance on a few dozen pixels)."""
    checks = _checks(r)
    assert set(checks) == {"robust z spread", "median z", "fraction with |z| > 4"}, checks
    assert checks["robust z spread"].passed and checks["fraction with |z| > 4"].passed, checks
    n = int(case.mask.sum())
    assert abs(checks["median z"].value) < 3 * 1.2533 / math.sqrt(n), (checks["median z"].value, n)


def test_xml_sensor_medium_reference_is_mitsubas_single_scattering(tmp_path):
    """The sensor's medium: the audit's reference equals Mitsuba volpathmis' single scattering at the same
    pixel centres within both noises; the exact quadrature row passes the engine's z-checks; the methods are
    evaluated with the scene's K, and the fits bring the seed's model and the inverse-square row near it."""
    import mitsuba as mi

    from rtfit.reference.estimators import radiance_pass
    from rtfit.reference.variants import scoped_variant

    path = _xml(tmp_path)
    assert Path(path).read_text() in (DATA / "lamp_in_fog.xml").read_text()  # docs/audit.md's example
    r = audit(path, "volumetric-lightning", spp=128, pass_spp=64, cache=tmp_path / "cache", **FAST)
    assert [c.id for c in r.cases] == ["light0-inscatter"]
    case = r.cases[0]
    assert case.mask.sum() > 100 and case.parameters["camera_inside_medium"]
    _exact_row_at_noise(r, case)
    rows = set(r.outcomes[case.id])
    assert {"stable", "seed", "inverse-square", "quadrature", "stable-fitted", "seed-fitted"} <= rows
    # the inverse-square row with the scene's K = σ_s·I/(4π)
    k = 0.8 * 0.3 * 5.0 / (4 * math.pi)
    assert abs(r.outcomes[case.id]["inverse-square"].parameters["k"] - k) < 1e-7
    rmse = {row: r.metrics(case.id, row)["rmse"].value for row in rows}
    assert rmse["stable-fitted"] < 0.3 * rmse["stable"] and rmse["quadrature"] < rmse["stable-fitted"]

    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(path)
        got = radiance_pass(mi, scene, 1024, 7)
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    mit, mit_err = got.mean[case.mask], np.sqrt(got.var[case.mask] / 1024)
    z = (ref - mit) / np.sqrt(err**2 + mit_err**2)
    assert abs(float(np.median(z))) < 0.2 and 0.7 < float(np.std(z)) < 1.3, (np.median(z), np.std(z))
    assert float(np.max(np.abs(z))) < 5.0


def test_xml_medium_in_a_cube_seen_from_outside(tmp_path):
    """A medium bounded by a null cube around the light, the camera outside: each pixel's stretch starts
    where its ray enters the cube (s₀ > 0) and ends on the floor or the far face; the quadrature row sits
    at the reference's noise; a user's approximation is evaluated as its formula."""
    path = _xml(tmp_path, in_cube=True)
    (tmp_path / "my.py").write_text(MY_LIGHT)
    r = audit(path, f"volumetric-lightning,{tmp_path / 'my.py'}:flat_glow", spp=64, pass_spp=32,
              cache=tmp_path / "cache", fit=False, **FAST)  # fmt: skip
    case = r.cases[0]
    assert not case.parameters["camera_inside_medium"]
    g = case.channel_inputs[0]
    start = np.stack([g["ox"], g["oy"], g["oz"]], axis=1)
    assert np.all(np.linalg.norm(start - np.array([0.0, -4.0, 1.0]), axis=1) > 3.0)  # the cube's near face
    assert np.all(np.max(np.abs(start - np.array([0.2, 0.0, 0.9])), axis=1) < 0.8 + 1e-3)  # on the cube
    _exact_row_at_noise(r, case)
    c = g["sigma_s"] * g["intensity"] / (4 * math.pi)
    d2 = (g["lx"] - g["ox"]) ** 2 + (g["ly"] - g["oy"]) ** 2 + (g["lz"] - g["oz"]) ** 2
    want = c * np.sqrt(g["dx"] ** 2 + g["dy"] ** 2 + g["dz"] ** 2) / (d2 + 1.0)
    assert np.max(np.abs(r.image(case.id, "flat_glow")[case.mask][:, 0] - want)) < 1e-6 * np.max(want)


def test_toml_scene_audits_and_lists(tmp_path):
    """An rtfit TOML scene with a coloured (σ_t per channel) forward-scattering medium box around camera and
    light: the case's exact row passes the z-checks per channel; ``--list`` names the family with its reason,
    and a second point light outside the medium is named as not triggering it."""
    outside = '[[lights]]\ntype = "point_light"\nposition = [0.0, 0.0, 5.0]\nintensity = 1.0\n'
    path = tmp_path / "lamp.toml"
    path.write_text(TOML % outside)
    out = CliRunner().invoke(audit_cmd, [str(path), "--list"])
    assert out.exit_code == 0, out.output
    assert (
        "volumetric-lightning — point light in a medium: point light (lights[0]) inside the homogeneous"
        in out.output
    )
    assert "quadrature" in out.output
    r = audit(str(path), "volumetric-lightning", spp=64, pass_spp=32, cache=tmp_path / "cache", fit=False,
              **FAST)  # fmt: skip
    assert [c.id for c in r.cases] == ["light0-inscatter"]  # lights[1] is outside the medium: no case
    case = r.cases[0]
    _exact_row_at_noise(r, case)
    assert [round(ch["sigma_t"], 6) for ch in case.channel_inputs] == [0.2, 0.3, 0.4]
    ref = case.reference.mean[case.mask]
    assert np.all(ref[:, 0] > 0) and np.median(ref[:, 2] / ref[:, 0]) != 1.0  # coloured by σ_t


def test_list_names_lights_outside_media(tmp_path):
    """A point light outside every medium (the medium is a cube elsewhere, the camera outside it): the family
    does not apply, and ``--list`` says why for that light."""
    path = _xml(tmp_path, in_cube=True, light='x="0" y="0" z="2.5"')
    out = CliRunner().invoke(audit_cmd, [path, "--list"])
    assert out.exit_code == 0, out.output
    assert "volumetric-lightning: needs a point light inside a homogeneous medium" in out.output
    assert "point light 'lamp'" in out.output and "is not inside a medium" in out.output


def test_extreme_densities_and_a_ray_through_the_light_stay_finite(tmp_path):
    """σ_t from 1e-6 to 50 /m (a transparent and an opaque fog), and the quadrature on a ray through the light
    itself: every row finite (a non-finite value would be a one-line error of the run), the reference
    non-negative with finite standard errors."""
    from rtfit.reference.single_scattering import point_single_scattering

    for sigma in ("1e-6", "50"):
        path = tmp_path / f"fog{sigma}.xml"
        path.write_text(
            Path(_xml(tmp_path)).read_text().replace('"sigma_t" value="0.3"', f'"sigma_t" value="{sigma}"')
        )
        r = audit(str(path), "volumetric-lightning", spp=8, pass_spp=8, cache=tmp_path / "cache", fit=False,
                  **FAST)  # fmt: skip
        case = r.cases[0]
        for row in r.outcomes[case.id].values():
            assert np.all(np.isfinite(row.image)), row.row
        assert np.all(case.reference.mean >= 0) and np.all(np.isfinite(case.reference.stderr))
    through = point_single_scattering((0.0, 0.0, 0.0), np.array([[0.0, 1.0, 0.0]]), np.array([5.0]),
                                      (0.0, 2.0, 0.0), 1.0, 0.1, 0.1)  # fmt: skip
    assert np.all(np.isfinite(through)) and through[0] > 0
