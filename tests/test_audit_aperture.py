"""`rtfit audit` of the ambient-aperture family (experiments/audit_ambient_aperture.py): the visibility caps
against ray-cast AO within R, and the occluded sphere light. Expected values come from closed forms of the
scenes written here, never from the code's earlier output:

* two parallel planes a gap h apart, seen from between them, AO within R > h: a ray from the floor at angle
  θ is blocked when h/cos θ < R, so A = (1/π)∫_{cos θ < h/R} cos θ dω = (h/R)²; the uniform visible
  fraction is V = h/R, the bent normal n up to the bake's noise (the visible ring is symmetric about it),
  r_a = acos(1 − V), and every cap row has a closed value on each pixel's baked cap (below);
* a sphere light of radius r above a floor, nothing between them: the shadowed reference is the closed-form
  sphere-light irradiance π L sin²α cos θ, the baked cap is the whole hemisphere (r_a = π/2, a ≈ n), so the
  exact intersection is the light's own cap A(α) = 2π(1 − cos α) and the exact-Ω row with the fitted
  Lambert factor (centroid weight → 1 for a small light) reads the closed form × A(α)/(π sin²α) =
  × 2/(1 + cos α).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.experiments.results import load_results
from rtfit.realtime.quantities import approximation

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "mae"), "fit": False}
GAP = 1.0  # h: floor at z = 0, ceiling at z = 1
R = 2.0


def _sensor(z: float, res: int) -> str:
    return f"""<sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, {z}" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/><integer name="height" value="{res}"/>
        </film>
    </sensor>"""


def _planes(root: Path, res: int = 6) -> Path:
    """Floor z = 0 and ceiling z = h, 100 × 100, a camera between them looking down (Z up)."""
    path = root / "planes.xml"
    path.write_text(
        f"""<scene version="3.0.0">
    {_sensor(0.5, res)}
    <shape type="rectangle" id="floor"><transform name="to_world"><scale value="50"/></transform></shape>
    <shape type="rectangle" id="ceiling">
        <transform name="to_world">
            <scale value="50"/><rotate x="1" angle="180"/><translate z="{GAP}"/>
        </transform>
    </shape>
</scene>
"""
    )
    return path


RADIUS, HEIGHT, RADIANCE = 0.25, 2.0, 3.0


def _sphere_light(root: Path, res: int = 6) -> Path:
    """A floor z = 0 (100 × 100) under a sphere light of radius r at height 2, camera looking down."""
    path = root / "light.xml"
    path.write_text(
        f"""<scene version="3.0.0">
    {_sensor(6.0, res)}
    <shape type="rectangle" id="floor"><transform name="to_world"><scale value="50"/></transform></shape>
    <shape type="sphere" id="light">
        <point name="center" x="0.3" y="0" z="{HEIGHT}"/><float name="radius" value="{RADIUS}"/>
        <emitter type="area"><rgb name="radiance" value="{RADIANCE}"/></emitter>
    </shape>
</scene>
"""
    )
    return path


@approximation(quantity="ambient_occlusion")
def between_planes(ops, g):
    """(h/R)² with h = 1: the closed form of this scene, as a user would write it."""
    return 0.0 * g.px + (GAP / g.ao_distance) ** 2


@pytest.fixture(scope="module")
def planes(tmp_path_factory):
    root = tmp_path_factory.mktemp("planes")
    return audit(_planes(root), ["ambient-aperture", between_planes], ao_distance=R, width=6, height=6,
                 spp=256, pass_spp=128, cache=root / "cache", **FAST)  # fmt: skip


def test_caps_between_two_planes_match_the_closed_forms(planes):
    (case,) = planes.cases
    assert case.id == "caps"
    m = case.mask
    ref = case.reference.mean[m][:, 0]
    se = case.reference.stderr[m][:, 0]
    # AO within R between planes h apart: (h/R)² = 0.25 (36 px × 256 rays: the mean's z within 4)
    want = (GAP / R) ** 2
    assert abs(ref.mean() - want) < 4 * math.sqrt(np.mean(se**2) / len(ref)) + 1e-3
    # The bake (256 uniform rays per pixel): V = h/R = 0.5 on average (binomial: ±0.031 per pixel, ±0.0052
    # over 36), and the bent normal is n up to the noise of the ring's mean direction.
    p = case.parameters
    assert abs(p["mean_visible_fraction"] - GAP / R) < 4 * 0.5 / math.sqrt(36 * 256)
    inp = case.channel_inputs[0]
    r_a, cos_t = np.asarray(inp["aperture"]), np.asarray(inp["cos_na"])
    tilt = np.arccos(np.clip(cos_t, -1, 1))
    assert np.all(tilt + r_a < math.pi / 2)  # every cap lies inside the hemisphere (nested)
    rows = planes.outcomes[case.id]
    # Closed forms on each pixel's baked cap (r_a, tilt θ of a from n), the cap inside the hemisphere:
    # projected solid angle π sin²r_a cos θ; the seed fill A(r_a) cos θ with A = 2π(1 − cos r_a); every
    # intersection form is exact for nested caps, Ω = A(r_a), and the centroid is
    # c = normalize(w n + (1 − w) a) ("light" l = n): w = ½ for the seed's plain average, so
    # n·c = cos(θ/2); the fitted weight w = A(r_a)^k/(A(r_a)^k + A(π/2)^k), k = 1.19, so
    # n·c = (w + (1 − w) cos θ)/|w n + (1 − w) a|; each row is divided by π (radiance 1/π). At r_a = π/3,
    # θ = 0 they read 0.75, 1, 1.
    a_cap = 2 * math.pi * (1 - np.cos(r_a))
    w = a_cap**1.19 / (a_cap**1.19 + (2 * math.pi) ** 1.19)
    cos_fit = (w + (1 - w) * cos_t) / np.sqrt(w**2 + (1 - w) ** 2 + 2 * w * (1 - w) * cos_t)
    closed = {
        "fill-projected": np.sin(r_a) ** 2 * cos_t,
        "fill-seed": a_cap * cos_t / math.pi,
        "between_planes": np.full_like(r_a, (GAP / R) ** 2),  # (the user's row: (h/R)²)
    }
    for form in ("exact", "smoothstep", "linear", "fitted"):
        closed[f"aa-{form}-seed"] = a_cap * np.cos(tilt / 2) / math.pi
    for form in ("exact", "fitted"):
        closed[f"aa-{form}-fitted"] = a_cap * cos_fit / math.pi
    assert set(rows) == set(closed)
    for rid, value in closed.items():
        img = rows[rid].image[m][:, 0]
        err = np.abs(img - value).max()
        assert err < 1e-5, (rid, err)  # measured 5.6e-16 (float64 NumPy inputs, Dr.Jit kernels)


def test_caps_reuse_the_ao_roles_reference(planes, tmp_path):
    """The caps case reads the sdf-occlusion AO role's cache entry: both families, one render."""
    both = audit(_planes(tmp_path), "ambient-aperture,sdf-occlusion", ao_distance=R, width=6, height=6,
                 spp=256, pass_spp=128, cache=tmp_path / "cache", **FAST)  # fmt: skip
    cases = {c.id: c for c in both.cases}
    assert cases["caps"].reference.cache_key == cases["ao"].reference.cache_key
    assert cases["caps"].reference.passes_rendered + cases["ao"].reference.passes_rendered == 2  # (of 4)
    (alone,) = planes.cases
    assert alone.reference.cache_key == cases["caps"].reference.cache_key  # same key in another cache


def test_unoccluded_sphere_light_exact_cap_is_the_closed_form(tmp_path):
    r = audit(_sphere_light(tmp_path), "ambient-aperture", width=6, height=6, spp=64, pass_spp=32,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    ids = [c.id for c in r.cases]
    assert ids == ["caps", "light0-occluded"]  # (the floor and the light sphere: two shapes)
    case = next(c for c in r.cases if c.id == "light0-occluded")
    m = case.mask
    assert case.parameters["mean_visible_fraction"] == 1.0
    assert case.parameters["mean_aperture_deg"] == pytest.approx(90.0, abs=1e-9)
    # Independent closed form at the visible floor points (pixel centres hit z = 0; recover x, y from the
    # case's own inputs is not used: the points come from the G-buffer, so compute them from cos θ and d).
    inputs = case.channel_inputs[0]
    d = np.asarray(inputs["distance"])
    cos_t = np.asarray(inputs["cos_theta"])
    assert np.allclose(cos_t, HEIGHT / d, atol=1e-5)  # the floor's normal is +z: n·l = h/d
    alpha = np.arcsin(RADIUS / d)
    closed = math.pi * RADIANCE * np.sin(alpha) ** 2 * cos_t
    ref = case.reference.mean[m][:, 0]
    se = case.reference.stderr[m][:, 0]
    z = (ref - closed) / se
    assert np.abs(z).max() < 5.0 and abs(z.mean()) < 4.0 / math.sqrt(len(z))  # measured 2.4, 0.09
    img = r.outcomes[case.id]["aa-exact-fitted"].image[m][:, 0]
    ratio = img / (closed * 2.0 / (1.0 + np.cos(alpha)))
    # centroid weight w = 1/(1 + (A(α)/2π)^1.19) ≈ 0.997: c is l tilted towards n by 0.3 % of their angle
    assert np.abs(ratio - 1).max() < 2e-3, np.abs(ratio - 1).max()  # measured 9.8e-4


def test_command_line_on_a_tiny_scene(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(
        audit_cmd,
        [str(_planes(tmp_path, 4)), "--approx", "ambient-aperture", "--ao-distance", str(R), "--spp", "4",
         "--pass-spp", "2", "--no-fit", "--no-progress", "--out", str(out), "--cache", str(tmp_path / "c")],
    )  # fmt: skip
    assert result.exit_code == 0, result.stderr
    res = load_results(out / "audit-planes")
    (case,) = res.cases
    assert case.id == "caps"
    assert {a.method for a in case.approximations} == {
        "aa-exact-seed", "aa-smoothstep-seed", "aa-linear-seed", "aa-fitted-seed", "aa-exact-fitted",
        "aa-fitted-fitted", "fill-projected", "fill-seed",
    }  # fmt: skip
    assert "not audited yet" not in result.stderr


def test_nothing_self_occluding_is_one_line_exit_2(tmp_path):
    path = tmp_path / "ball.xml"
    path.write_text(
        f"""<scene version="3.0.0">
    {_sensor(5.0, 4)}
    <emitter type="point"><point name="position" x="0" y="0" z="3"/></emitter>
    <shape type="sphere"/>
</scene>
"""
    )
    out = tmp_path / "out"
    result = CliRunner().invoke(audit_cmd, [str(path), "--approx", "ambient-aperture", "--out", str(out)])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rtfit: error: ambient-aperture does not apply")
    assert "geometry that can occlude itself" in lines[0]
    assert not out.exists()
