"""`rtfit audit` of the light-cones family: a spot light inside a homogeneous medium, on a small Mitsuba XML
scene (the medium on the sensor) and on a small rtfit TOML scene.

Independent values: Mitsuba's own ``volpathmis`` with max_depth 2 (single scattering by free-flight sampling
and next-event estimation to Mitsuba's ``spot``, a black floor so that nothing but the medium scatters) at the
same pixel centres (`radiance_pass`) against the audit's reference (equiangular sampling inside the spot's
cone, `rtfit.reference.medium_lights`); the exact row is the quadrature with Mitsuba's linear-in-angle
profile (`rtfit.reference.single_scattering.spot_single_scattering`, checked against mpmath in
tests/test_light_cones.py) and must sit at the reference's noise; the chord row's K and the shell's start
are computed here from the scene's numbers. Renders are 20×20 pixels, ≤ 128 spp (1024 for Mitsuba's)."""

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
    <transform name="to_world"><lookat origin="0, -3, 1.5" target="0, 0, 1" up="0, 0, 1"/></transform>
    <float name="fov" value="70"/>
    <float name="near_clip" value="0.0001"/>
    <ref id="fog"/>
    <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="20"/></film>
  </sensor>
  <emitter type="spot" id="lamp">
    <transform name="to_world"><lookat origin="0, 0.5, 3" target="0, 0.5, 0" up="0, 1, 0"/></transform>
    <float name="cutoff_angle" value="40"/><float name="beam_width" value="30"/>
    <rgb name="intensity" value="20"/>
  </emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf></shape>
</scene>
"""

TOML = """name = "spot-in-fog"
[camera]
origin = [0.0, -3.0, 1.5]
target = [0.0, 0.0, 1.0]
up = [0.0, 0.0, 1.0]
fov_deg = 70.0
width = 20
height = 20

[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [8.0, 8.0]
material = { type = "diffuse", reflectance = 0.5 }

[[lights]]
type = "spot_light"
position = [0.0, 0.5, 3.0]
axis = [0.0, 0.0, -1.0]
intensity = [20.0, 15.0, 10.0]
cutoff_angle_deg = 40.0
beam_width_deg = 30.0

[[lights]]
type = "spot_light"
position = [0.0, 0.0, 6.0]
cutoff_angle_deg = 20.0
beam_width_deg = 15.0

[[media]]
type = "homogeneous"
boundary = { type = "cube", center = [0.0, 0.0, 1.99], size = [8.0, 8.0, 4.0] }
sigma_t = 0.25
albedo = 0.9
"""


def _checks(r) -> dict:
    return {c.name.rsplit(": ", 1)[1].split(" (")[0]: c for c in r.results.checks}


def _exact_row_at_noise(r, case) -> None:
    """The engine's z-checks of the exact row (as in tests/test_audit_volumetric_lightning.py): the tail check
    passes; the robust spread and the median are asserted within 3 of their own standard errors
    (1.167/√n and 1.2533/√n for the n lit pixels: a pixel's three channels share their samples)."""
    checks = _checks(r)
    assert set(checks) == {"robust z spread", "median z", "fraction with |z| > 4"}, checks
    assert checks["fraction with |z| > 4"].passed, checks
    n = int(checks["robust z spread"].name.split("MAD, ")[1].split(" ")[0]) // 3
    assert abs(checks["robust z spread"].value - 1.0) < 3 * 1.167 / math.sqrt(n), (checks, n)
    assert abs(checks["median z"].value) < 3 * 1.2533 / math.sqrt(n), (checks, n)


def test_xml_spot_reference_is_mitsubas_single_scattering(tmp_path):
    """The spot in the sensor's medium: the audit's reference equals Mitsuba volpathmis' single scattering at
    the same pixel centres within both noises (dark outside the cone too); the exact row sits at its noise;
    the chord row carries the scene's K, the shells the start k₀ = 8K·tan θ_½/L with L the apex's height
    above the floor; the fits bring the shells near."""
    import mitsuba as mi

    from rtfit.reference.estimators import radiance_pass
    from rtfit.reference.variants import scoped_variant

    path = Path(__file__).parent / "data" / "mitsuba" / "media" / "spot_in_fog.xml"
    assert XML in path.read_text()  # docs/audit.md's example
    r = audit(str(path), "light-cones", spp=128, pass_spp=64, cache=tmp_path / "cache", **FAST)
    assert [c.id for c in r.cases] == ["light0-beam"]
    case = r.cases[0]
    _exact_row_at_noise(r, case)
    k = 0.8 * 0.3 * 20.0 / (4 * math.pi)
    rows = r.outcomes[case.id]
    assert abs(rows["chord"].parameters["k"] - k) < 1e-6
    assert abs(case.parameters["cone_length_m"] - 3.0) < 1e-4  # apex 3 m above the floor, axis straight down
    half = math.radians(35.0)
    assert abs(rows["shell"].parameters["k"] - 8 * k * math.tan(half) / 3.0) < 1e-6
    rmse = {row: r.metrics(case.id, row)["rmse"].value for row in rows}
    assert rmse["shell-fitted"] < rmse["shell"] and rmse["quadrature"] < rmse["shell-fitted"]

    with scoped_variant("llvm_ad_rgb"):
        got = radiance_pass(mi, mi.load_file(str(path)), 1024, 7)
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    mit, mit_err = got.mean[case.mask], np.sqrt(got.var[case.mask] / 1024)
    lit = (err[:, 0] > 0) | (mit_err[:, 0] > 0)
    assert lit.sum() > 100 and np.all(mit[~lit] == 0)  # outside the cone both are exactly dark
    z = (ref[lit] - mit[lit]) / np.sqrt(err[lit] ** 2 + mit_err[lit] ** 2)
    assert abs(float(np.median(z))) < 0.2 and 0.7 < float(np.std(z)) < 1.3, (np.median(z), np.std(z))
    assert float(np.max(np.abs(z))) < 5.0


def test_toml_spot_audits_and_lists(tmp_path):
    """An rtfit TOML spot (coloured intensity) in a homogeneous medium box: the exact row sits at the
    reference's noise; ``--list`` names the family for lights[0] and says lights[1] (above the box) is not
    inside a medium."""
    path = tmp_path / "spot.toml"
    path.write_text(TOML)
    out = CliRunner().invoke(audit_cmd, [str(path), "--list"])
    assert out.exit_code == 0, out.output
    assert "light-cones — spot light in a medium: spot light (lights[0]) inside the homogeneous" in out.output
    assert "shell, shell-front, chord, quadrature" in out.output
    r = audit(str(path), "light-cones", spp=64, pass_spp=32, cache=tmp_path / "cache", fit=False, **FAST)
    assert [c.id for c in r.cases] == ["light0-beam"]
    case = r.cases[0]
    _exact_row_at_noise(r, case)
    assert [ch["intensity"] for ch in case.channel_inputs] == [20.0, 15.0, 10.0]
    assert case.parameters["cutoff_deg"] == 40.0 and case.parameters["beam_width_deg"] == 30.0


def test_list_names_spots_outside_media(tmp_path):
    """The TOML scene without its medium: light-cones does not apply, and ``--list`` says why per spot."""
    path = tmp_path / "dry.toml"
    path.write_text(TOML.split("[[media]]")[0])
    out = CliRunner().invoke(audit_cmd, [str(path), "--list"])
    assert out.exit_code == 0, out.output
    assert "light-cones: needs a spot light inside a homogeneous medium" in out.output
    assert "the spot light lights[0] is not inside a medium" in out.output
