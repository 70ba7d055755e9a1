"""`rtfit audit` of aerial perspective (issue 30 §2): the fog blend L₀·T + C·(1 − T) where a scene's sky (an
environment emitter: constant, envmap, sunsky) and a medium the camera looks through meet
(`rtfit.experiments.audit_aerial_perspective`).

Scenes: tests/data/mitsuba/aerial/ (16 × 16 or 32 × 32 pixels, 32–64 samples per pixel). Expected values
are computed here, independently of the audit's code: each camera ray's stretch inside the box by the classic
slab test; in a uniform sky of radiance 1, an absorbing medium (albedo 0) leaves exp(−σt·d) (each volpathmis
sample is 1 or 0: a Bernoulli(T) mean with the exact standard error √(T(1 − T)/n)), a non-absorbing
isotropic one leaves the radiance field 1 everywhere (all orders of scattering: nothing is lost), and the
fog-free image is the sky itself, 1; a sunsky's horizon average from Mitsuba's own emitter on a finer grid
written here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import inspect_scene
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.reference.variants import scoped_variant

DATA = Path(__file__).parent / "data" / "mitsuba" / "aerial"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs"), "fit": False}
ORIGIN = np.array([0.031, -6.0, 0.517])
BOX_LO, BOX_HI = np.array([-1.2, -1.2, -0.7]), np.array([1.2, 1.2, 1.7])


def _slab_interval(dirs: np.ndarray, lo=BOX_LO, hi=BOX_HI, origin=ORIGIN):
    """[t_in, t_out] of rays from ``origin`` in the axis-aligned box (the classic slab test, written here)."""
    with np.errstate(divide="ignore"):
        a, b = (lo - origin) / dirs, (hi - origin) / dirs
    return np.max(np.minimum(a, b), axis=1).clip(min=0.0), np.min(np.maximum(a, b), axis=1)


def _slab(dirs: np.ndarray, lo=BOX_LO, hi=BOX_HI, origin=ORIGIN) -> np.ndarray:
    """The length of each ray's stretch in the axis-aligned box (`_slab_interval`)."""
    t0, t1 = _slab_interval(dirs, lo, hi, origin)
    return t1 - t0


def _directions(case) -> np.ndarray:
    g = case.channel_inputs[0]
    return np.stack([g["dx"], g["dy"], g["dz"]], axis=1)


WHITE_FOG = '''
from rtfit import Param, approximation


@approximation(quantity="fogged_radiance", params={"k": Param(1.0, lower=0.1, upper=10.0)})
def white_fog(ops, g, *, k):
    """Beer–Lambert with the medium's density scaled by k, towards a white fog."""
    t = ops.exp(-k * g.density * g.length)
    return (g.l0_r * t + (1.0 - t), g.l0_g * t + (1.0 - t), g.l0_b * t + (1.0 - t))
'''


def _run(tmp_path, scene: str, defines: dict[str, str], spp: int = 64, approx="aerial-perspective", **kw):
    return audit(str(DATA / scene), approx, defines=defines, spp=spp, pass_spp=32,
                 cache=tmp_path / "c", **{**FAST, **kw})  # fmt: skip


@pytest.mark.parametrize("scene", ["uniform_sky.xml", "uniform_envmap.xml"])
def test_absorbing_fog_under_a_uniform_sky_is_the_closed_form(tmp_path, scene):
    """Albedo 0 under a sky of radiance 1 (a constant environment, or an envmap of texels 1): the reference
    is exp(−σt·d) within its Bernoulli noise, the fog-free image L₀ is the sky (1 exactly), the horizon
    average is 1, the source function 0 (nothing scatters), so camera-source is exp(−σt·d) itself."""
    sigma = 0.8
    r = _run(tmp_path, scene, {"sigma": str(sigma), "albedo": "0"})
    (case,) = r.cases
    assert case.id == "media0-aerial" and case.parameters["falloff"] == 0.0
    assert case.parameters["density"] == pytest.approx(sigma, rel=1e-6)
    assert case.parameters["horizon_average"] == pytest.approx([1.0, 1.0, 1.0], rel=1e-5)
    g = case.channel_inputs[0]
    assert np.allclose([g["l0_r"], g["l0_g"], g["l0_b"]], 1.0, atol=1e-6)  # the sky unchanged without fog
    assert np.all(g["j_r"] == 0.0)
    length = _slab(_directions(case))
    assert np.max(np.abs(g["distance"] - length)) < 1e-4  # the stretch inside the box
    truth = np.exp(-sigma * length)
    assert np.max(np.abs(r.image(case.id, "camera-source")[case.mask][:, 0] - truth)) < 1e-5
    # horizon-flat: L₀T + H(1 − T) with L₀ = H = 1 is 1 exactly, whatever T
    assert np.max(np.abs(r.image(case.id, "horizon-flat")[case.mask] - 1.0)) < 1e-5
    ref = case.reference.mean[case.mask]
    z = (ref - truth[:, None]) / np.sqrt(truth * (1.0 - truth) / case.reference.spp)[:, None]
    assert abs(float(np.mean(z))) < 0.6 and float(np.max(np.abs(z))) < 4.5
    assert all(c.passed for c in r.results.checks)


def test_an_absorbing_grid_under_a_uniform_sky_is_the_exponential_integral(tmp_path):
    """The gridvolume of b·exp(−c·(z − z_min)) (b = 1, c = 1.2, z_min = −0.7) filling the box, absorbing,
    under a sky of radiance 1: the grid is fitted back to b, c; camera-source (J = 0) is
    exp(−∫σt ds) with ∫ b·e^(−c(z − z_min)) ds = b·e^(−c(o_z − z_min))·(e^(−c·d_z·t0) − e^(−c·d_z·t1))/(c·d_z)
    over the slab interval (written here), within the trilinear interpolation error (c·h)²/8 ≈ 2e-4 of a
    cell h = 2.4/64; the reference matches it within its Bernoulli noise."""
    r = _run(tmp_path, "grid_sky.xml", {})
    (case,) = r.cases
    assert case.parameters["density"] == pytest.approx(1.0, rel=1e-5)
    assert case.parameters["falloff"] == pytest.approx(1.2, rel=1e-5)
    d = _directions(case)
    t0, t1 = _slab_interval(d)
    k = 1.2 * d[:, 2]
    tau = np.exp(-1.2 * (ORIGIN[2] + 0.7)) * (np.exp(-k * t0) - np.exp(-k * t1)) / k
    truth = np.exp(-tau)
    assert np.max(np.abs(r.image(case.id, "camera-source")[case.mask][:, 0] - truth)) < 1e-5
    ref = case.reference.mean[case.mask]
    z = (ref - truth[:, None]) / np.sqrt(truth * (1.0 - truth) / case.reference.spp)[:, None]
    assert abs(float(np.mean(z))) < 0.6 and float(np.max(np.abs(z))) < 4.5


def test_a_non_absorbing_fog_leaves_a_uniform_sky_unchanged(tmp_path):
    """Albedo 1, isotropic, sky of radiance 1: the radiance field stays 1 everywhere (all bounces), so the
    reference is 1 within its noise; the source function J = ∫ 1·(1/4π) dω = 1 (the constant sky is sampled
    uniformly: every weight is 4π) and both camera-source and horizon-flat are 1 exactly — the blend is
    exact when the source function is constant, whatever T. A user's approximation of ``fogged_radiance``
    (a white fog) joins the rows and is 1 too."""
    user = tmp_path / "white_fog.py"
    user.write_text(WHITE_FOG)
    approx = f"aerial-perspective,{user}:white_fog"
    r = _run(tmp_path, "uniform_sky.xml", {"sigma": "1.5", "albedo": "1"}, spp=128, approx=approx)
    (case,) = r.cases
    g = case.channel_inputs[0]
    assert np.allclose([g["j_r"], g["j_g"], g["j_b"]], 1.0, rtol=1e-5)
    for row in ("camera-source", "horizon-flat", "horizon-phase", "white_fog"):
        assert np.max(np.abs(r.image(case.id, row)[case.mask] - 1.0)) < 1e-5, row
    ref, err = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    pooled = float(np.mean(ref))
    pooled_err = float(np.sqrt(np.sum(err**2))) / ref.size
    assert abs(pooled - 1.0) < 4.0 * pooled_err + 1e-6, (pooled, pooled_err)


def test_sunsky_fog_bank_audits_with_the_skys_horizon_average(tmp_path):
    """The sunsky over a ground seen through a scattering fog bank: one case, every row finite, fitted; H is
    the sunsky's own radiance averaged over the horizon band (a finer grid written here: 1024 azimuths ×
    8 elevations over the same two texture rows, directions within 1° of the sun left out)."""
    r = _run(tmp_path, "sky_fog.xml", {"res": "16"}, spp=32, fit=True)
    (case,) = r.cases
    assert case.parameters["g"] == pytest.approx(0.5) and case.parameters["albedo"] == pytest.approx(
        [0.9] * 3
    )
    rows = set(r.outcomes[case.id])
    assert {"camera-source", "horizon-flat", "horizon-phase"} <= rows
    assert any(row.endswith("-fitted") for row in rows)
    for row in rows:
        assert np.all(np.isfinite(r.image(case.id, row))), row
    with scoped_variant("llvm_ad_rgb") as mi:
        sky = mi.load_dict({"type": "sunsky", "sun_direction": [0.5, 0.6, 0.62], "turbidity": 3.0})
        sun = np.array([0.5, 0.6, 0.62]) / np.linalg.norm([0.5, 0.6, 0.62])
        az = (np.arange(1024) + 0.5) / 1024 * 2 * math.pi
        el = np.radians(np.linspace(0.0, 2.8125, 9)[:-1] + 2.8125 / 16)  # midpoints of 8 sub-rows
        a, e = np.meshgrid(az, el)
        d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
        d = d[d @ sun < math.cos(math.radians(1.0))]
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(-d.T.astype(np.float32))
        expected = np.array(sky.eval(si), np.float64).reshape(3, -1).mean(axis=1)
    assert np.allclose(case.parameters["horizon_average"], expected, rtol=2e-2)


def test_list_names_aerial_perspective_with_its_reason_and_why_not():
    """``--list``: applies where a medium and a sky meet (the reason names both); where the scene has a medium
    but no sky, "does not apply" says what it needs."""
    result = CliRunner().invoke(audit_cmd, [str(DATA / "sky_fog.xml"), "--list"])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "aerial-perspective — sky through a medium: homogeneous medium 'haze'" in out
    assert "under sunsky environment" in out
    assert "methods:    camera-source, horizon-flat, horizon-phase" in out
    media = Path(__file__).parent / "data" / "mitsuba" / "fog" / "media.xml"
    result = CliRunner().invoke(audit_cmd, [str(media), "--list"])
    assert result.exit_code == 0, result.output
    assert (
        "aerial-perspective: needs an environment (envmap, constant or sunsky) and a medium the camera looks "
        "through that reads as height fog (homogeneous, or a gridvolume)" in result.output
    )
    found = applicable_families(inspect_scene(DATA / "uniform_envmap.xml"), approx="aerial-perspective")
    assert [a.role for a in found] == ["sky through a medium"]


TOML = """
name = "fog_under_sky"
[camera]
origin = [0.0, -7.0, 1.2]
target = [0.0, 0.0, 1.0]
fov_deg = 50.0
width = 12
height = 12

[[lights]]
type = "constant_env"
radiance = [1.0, 1.0, 1.0]

[[media]]
type = "homogeneous"
boundary = { type = "cube", center = [0.0, 0.0, 1.0], size = [4.0, 4.0, 3.0], rotate_deg = 20.0 }
sigma_t = 0.4
albedo = 0.0
"""


def test_toml_homogeneous_medium_under_a_constant_sky(tmp_path):
    """An rtfit TOML homogeneous medium (a rotated box) under a constant sky of radiance 1: camera-source is
    exp(−σt·d), d from a slab test in the box's own frame, and the reference matches it within its noise."""
    path = tmp_path / "fog_under_sky.toml"
    path.write_text(TOML)
    r = audit(str(path), "aerial-perspective", spp=64, pass_spp=32, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    a = math.radians(20.0)
    rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    local_o = rot.T @ (np.array([0.0, -7.0, 1.2]) - [0.0, 0.0, 1.0])
    half = np.array([2.0, 2.0, 1.5])
    truth = np.exp(-0.4 * _slab(_directions(case) @ rot, lo=-half, hi=half, origin=local_o))
    assert np.max(np.abs(r.image(case.id, "camera-source")[case.mask][:, 0] - truth)) < 1e-5
    ref = case.reference.mean[case.mask]
    z = (ref - truth[:, None]) / np.sqrt(truth * (1.0 - truth) / case.reference.spp)[:, None]
    assert abs(float(np.mean(z))) < 0.6 and float(np.max(np.abs(z))) < 4.5
