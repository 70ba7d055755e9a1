"""The ``irradiance-volumes`` family of `rtfit audit` (`rtfit.experiments.audit_irradiance_volumes`): a probe
grid over a user's scene, looked up at the visible points, against path-traced irradiance there.

Scenes are written here and tiny (16 × 16 pixels, ≤ 32 spp). The independent check: a diffuse floor under a
constant sky L, with only a tiny black sphere (radius 0.05, out of view, 2 above the floor: it gives the
scene's box its height) — every floor point receives E = πL(1 − sin²α·cos θ) from the sky minus that sphere
(α its angular radius, θ its angle from the normal: the closed form of a sphere wholly above the horizon),
within 6·10⁻⁴ of πL; and every probe's ambient-cube entry along +z is the irradiance of its upper hemisphere,
the same sky (the floor lies below), so the Valve-cube rows at the floor's upward normals are πL up to the
probes' noise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import inspect_scene
from rtfit.experiments.audit_cli import audit as audit_command
from rtfit.experiments.audit_irradiance_volumes import probe_grid
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import METHOD_TABLES

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "rel_mse", "mae", "max_abs")}
SKY = np.array([0.8, 0.9, 1.0])

FLOOR_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -3, 4" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.0"/></emitter>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.4, 0.3"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="2.9" y="2.9" z="2"/><float name="radius" value="0.05"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf></shape>
</scene>
"""


def test_probe_grid_is_centred_in_the_box_with_cubic_cells():
    g = probe_grid((-3, -3, 0), (3, 3, 2.05))
    assert g.dims == (4, 4, 1) and g.spacing == pytest.approx(1.5)
    assert np.allclose(g.positions()[:, 0].min(), -2.25) and np.allclose(g.positions()[:, 2], 1.025)
    g = probe_grid((0, 0, 0), (4, 2, 1), (2, 2, 2))  # h = max(4/2, 2/2, 1/2) = 2: centred, x-cells fill
    assert g.spacing == 2.0 and np.allclose(g.origin, (1.0, 0.0, -0.5))


def test_floor_under_a_constant_sky(tmp_path):
    (tmp_path / "f.xml").write_text(FLOOR_XML)
    info = inspect_scene(tmp_path / "f.xml")
    (app,) = [a for a in applicable_families(info) if a.family == "irradiance-volumes"]
    assert app.methods == tuple(METHOD_TABLES["irradiance-volumes"])
    assert app.part.startswith("a probe grid over the scene's box (-3, -3, 0)–(3, 3, 2.05)")
    r = audit(tmp_path / "f.xml", "irradiance-volumes", spp=32, pass_spp=16, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["grid_dims"] == [4, 4, 1] and case.parameters["probe_spp"] == 64 * 32
    m = case.mask
    ref, se = case.reference.mean[m], case.reference.stderr[m]
    want = math.pi * SKY
    # the closed form within 6e-4 of πL (the tiny sphere's shadow), at the reference's noise
    assert np.all(np.abs(ref - want) <= 5 * se + 1e-3 * want)  # measured max |z| 0 (no ray met the sphere)
    rows = r.outcomes[case.id]
    assert set(rows) == set(METHOD_TABLES["irradiance-volumes"])
    for row in rows.values():
        assert np.all(np.isfinite(row.image[m])), row.row
    # Valve's cube at the floor's upward normal reads each probe's +z entry: the sky's πL, probe noise
    # ≈ 1.29/√2048 = 2.9 % per probe (4π·max(ω_z, 0)·L over uniform directions)
    for row in ("nearest-cube-valve", "trilinear-cube-valve"):
        v = rows[row].image[m] / want
        assert abs(np.mean(v) - 1) < 0.03 and np.all(np.abs(v - 1) < 0.12), (
            row
        )  # measured mean +1.5 %, +1.1 %, max 6.6 %


TOML = """
name = "sphere on a floor"

[camera]
origin = [0, -6, 3]
target = [0, 0, 0.5]
fov_deg = 35
width = 16
height = 16

[[lights]]
type = "constant_env"
radiance = [0.8, 0.9, 1.0]

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [6, 6]

[[shapes]]
type = "sphere"
center = [0, 0, 1]
radius = 0.8
"""


def test_a_toml_scene_with_its_own_grid(tmp_path):
    (tmp_path / "s.toml").write_text(TOML)
    listing = CliRunner().invoke(audit_command, [str(tmp_path / "s.toml"), "--list"])
    assert listing.exit_code == 0
    assert "irradiance-volumes — probe grid: a probe grid over the scene's box" in listing.stdout
    r = audit(tmp_path / "s.toml", "irradiance-volumes", spp=16, pass_spp=8, fit=False, grid="4,4,2",
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["grid_dims"] == [4, 4, 2] and case.parameters["grid_from"] == "--grid"
    rows = r.outcomes[case.id]
    for row in rows.values():
        assert np.all(np.isfinite(row.image))
    # the floor under the sphere is shadowed, the sphere's top is not: every row sees the contrast, the
    # trilinear rows blur it less than a constant would (relative MSE below that of the mean irradiance)
    m = case.mask
    ref = case.reference.mean[m]
    flat = np.mean((ref.mean(0) - ref) ** 2 / np.maximum(ref, 1e-6) ** 2)
    good = rows["trilinear-sh-l2"].metrics["rel_mse"].value
    assert good < flat  # measured 0.035 against 0.052
    # a grid whose cells do not fit the box: h = 2, nodes at z = −0.1 (under the floor, seeing its black
    # back) and 1.9: every probe outside the box, the light leaks (measured relative MSE 0.71)
    r = audit(tmp_path / "s.toml", "irradiance-volumes", spp=16, pass_spp=8, fit=False, grid=(3, 3, 2),
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["probes_outside_the_box"] == 18
    assert r.outcomes[case.id]["trilinear-sh-l2"].metrics["rel_mse"].value > 5 * good
