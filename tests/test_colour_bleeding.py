"""The colour-bleeding family (rtfit/realtime/colour_bleeding.py, experiments/audit_colour_bleeding.py and the
``bounce`` transport of rtfit.reference.estimators.irradiance_pass) against independent values only.

Oracles: the kernels by hand (math.exp, math.sqrt on a few rays); the reference by the form factor of a
diffuse disc lit at normal incidence (on its axis: F = R²/(R² + h²); off the axis: a midpoint quadrature of
cos θ cos θ' / (π r²) over the disc), an area light seen directly (no bounce: 0), and on a room the one-bounce
gather of the audit's own K rays (a second, independent estimator of the same integral: Mitsuba's direct
light at each ray's hit × albedo) agreeing with the path-traced reference on average.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import colour_bleeding as cb

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SHIPPED = LIBRARY / "colour_bleeding_box.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
FAMILY = "colour-bleeding"


def _inputs(d, a, e, channel=0.0):
    """The quantity's inputs from K-ray lists (the rest of the 16 rays repeat them cyclically), as floats: the
    kernels' float64 NumPy run (`Method.evaluate`)."""
    g = {"channel": float(channel)}
    for k in range(cb.RAYS):
        j = k % len(d)
        g[f"d{k + 1}"], g[f"a{k + 1}"], g[f"e{k + 1}"] = (float(v[j]) for v in (d, a, e))
    return g


# ------------------------------------------------------------------------------------------------ kernels
@pytest.mark.parametrize("channel", [0, 1, 2])
def test_seed_sdf_bias_by_hand(channel):
    """I·mean_k[e^{−d/D} (1 − e^{−b_c a/D})] (ρ = 1 − e^{−d/D}); b picked by the channel; misses add 0."""
    d, a = [0.2, 0.7, cb.MISS, 1.5], [0.9, 0.3, 0.0, 0.6]
    p = {"d_max": 0.5, "bias_r": 0.05, "bias_g": 0.2, "bias_b": 0.4, "ambient": 3.0}
    b = (0.05, 0.2, 0.4)[channel]
    want = 3.0 * sum(0.0 if dk > 1e20 else math.exp(-dk / 0.5) * (1 - math.exp(-b * ak / 0.5))
                     for dk, ak in zip(d, a, strict=True)) / 4  # fmt: skip
    got = cb.METHODS["seed-sdf-bias"].evaluate(_inputs(d, a, [0] * 4, channel), p)
    assert float(np.squeeze(got)) == pytest.approx(want, rel=1e-12)


def test_kept_terms_follow_every_parameter_on_the_same_arrays():
    """The fit's NumPy run on the same input arrays again and again keeps ρ(d_k) and the ray mean
    (`colour_bleeding._kept`): at every parameter set of a sequence that changes D, a bias, I, and comes
    back, seed-sdf-bias and rgb-obscurance equal their closed forms to 1e-12."""
    rng = np.random.default_rng(5)
    n = 12
    channel = np.repeat([0.0, 1.0, 2.0], n // 3)
    d, a = rng.uniform(0.0, 2.0, (cb.RAYS, n)), rng.uniform(0.0, 1.0, (cb.RAYS, n))
    inputs = {"channel": channel}
    for k in range(cb.RAYS):
        inputs[f"d{k + 1}"], inputs[f"a{k + 1}"], inputs[f"e{k + 1}"] = d[k], a[k], np.zeros(n)
    sdf, rgb = cb.METHODS["seed-sdf-bias"], cb.METHODS["rgb-obscurance"]
    base = {"d_max": 0.5, "bias_r": 0.05, "bias_g": 0.2, "bias_b": 0.4, "ambient": 3.0}
    steps = [{}, {"d_max": 0.7}, {"bias_g": 0.3}, {"ambient": 2.0}, {}, {"d_max": 0.7, "ambient": 1.0}, {}]
    for step in steps:
        p = {**base, **step}
        b = np.choose(channel.astype(int), [p["bias_r"], p["bias_g"], p["bias_b"]])
        want = p["ambient"] * np.mean(np.exp(-d / p["d_max"]) * -np.expm1(-b * a / p["d_max"]), axis=0)
        assert np.allclose(sdf(NUMPY_OPS, inputs, p), want, rtol=1e-12, atol=0), step
        q = {"d_max": p["d_max"], "exponent": 0.5, "ambient": p["ambient"]}
        want = q["ambient"] * np.mean((1.0 - np.sqrt(np.minimum(d / q["d_max"], 1.0))) * a, axis=0)
        assert np.allclose(rgb(NUMPY_OPS, inputs, q), want, rtol=1e-12, atol=0), step


def test_rgb_obscurance_seed_by_hand():
    """I·mean_k (1 − √(d/d_max)) a_k, 0 beyond d_max (001:3284) — at three ray sets (the table's d_max is 1:
    lengths in units of R, which the audit sets)."""
    m = cb.METHODS["rgb-obscurance-seed"]
    for d, a, want in (
        ([0.25], [0.8], 0.8 * 0.5),  # √(0.25/1) = ½
        ([1.0, 0.004], [0.5, 0.25], (0.0 + 0.25 * (1 - 0.0632455532)) / 2),
        ([cb.MISS, 0.625], [0.0, 1.0], (0.0 + (1 - 0.790569415)) / 2),
    ):
        got = m.evaluate(_inputs(d, a, [0] * len(d)), {"ambient": 2.0})
        assert float(np.squeeze(got)) == pytest.approx(2.0 * want, rel=1e-8), d


def test_gather_and_the_few_ray_rows_read_the_first_k():
    """gather = mean a·e; the -k4 row reads rays 1–4 only; the fitted obscurance at p → its seed values."""
    d = [0.1, 0.2, 0.3, 0.4, 9.0, 9.0, 9.0, 9.0] * 2
    a = [0.5, 0.5, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0] * 2
    e = [2.0, 4.0, 6.0, 8.0, 100.0, 100.0, 100.0, 100.0] * 2
    g = _inputs(d, a, e)
    assert float(np.squeeze(cb.METHODS["gather"].evaluate(g, {}))) == pytest.approx((10.0 + 400.0) / 8)
    assert float(np.squeeze(cb.METHODS["gather-k4"].evaluate(g, {}))) == pytest.approx(2.5)
    seed = cb.METHODS["rgb-obscurance-seed"].evaluate(g, {"ambient": 1.0})
    fit = cb.METHODS["rgb-obscurance"].evaluate(g, {"ambient": 1.0, "d_max": 1.0, "exponent": 0.5})
    assert float(np.squeeze(seed)) == pytest.approx(float(np.squeeze(fit)), rel=1e-12)
    with pytest.raises(ValueError, match="rays must be in"):
        cb.bleed_on_rays(cb.METHODS["gather"], 17)


@settings(max_examples=120, deadline=None)
@given(
    d=st.lists(st.one_of(st.floats(0.0, 1e6), st.just(cb.MISS)), min_size=1, max_size=16),
    a=st.floats(0.0, 1.0),
    e=st.floats(0.0, 1e6),
    length=st.floats(1e-3, 1e3),
    bias=st.floats(0.0, 1e3),
    exponent=st.floats(1e-2, 16.0),
    ambient=st.floats(1e-6, 1e6),
    channel=st.sampled_from([0.0, 1.0, 2.0]),
)
def test_every_row_finite_and_nonnegative_at_the_extremes(d, a, e, length, bias, exponent, ambient, channel):
    g = _inputs(d, [a] * len(d), [e] * len(d), channel)
    p = {"d_max": length, "bias_r": bias, "bias_g": bias, "bias_b": bias, "ambient": ambient,
         "exponent": exponent}  # fmt: skip
    for mid, m in cb.METHODS.items():
        v = np.asarray(m.evaluate(g, {k: p[k] for k in m.params}), np.float64)
        assert np.all(np.isfinite(v)) and np.all(v >= -1e-12 * max(ambient, e, 1.0)), (mid, v)


# ------------------------------------------------------------------------------------------------ reference
def _disc_scene(mi, albedo, e0):
    return mi.load_dict({
        "type": "scene",
        "disc": {"type": "disk",
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}},
        "sun": {"type": "directional", "direction": [0, 0, -1], "irradiance": {"type": "rgb", "value": e0}},
    })  # fmt: skip


def _disc_form_factor(x, h, n=400):
    """Form factor from a point at (x, 0, h) facing down to the unit disc at z = 0: midpoint quadrature in
    polar coordinates of h² / (π r⁴) (cos θ = cos θ' = h/r)."""
    rr = (np.arange(n) + 0.5) / n
    ph = (np.arange(2 * n) + 0.5) * math.pi / n
    r, p = np.meshgrid(rr, ph, indexing="ij")
    dist2 = (r * np.cos(p) - x) ** 2 + (r * np.sin(p)) ** 2 + h * h
    return float(np.sum(h * h / (math.pi * dist2**2) * r) * (1.0 / n) * (math.pi / n))


def test_bounce_pass_matches_the_disc_form_factor():
    """A unit diffuse disc of albedo a lit at normal incidence (E₀) and a point at height h facing it: the
    one bounce is E₁ = a·E₀·F, F = 1/(1 + h²) on the axis (closed form) and the quadrature off it; the
    directional light itself never reaches the estimate (its direct light is not a bounce)."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from rtfit.reference.estimators import irradiance_pass

    albedo, e0, h = np.array([0.8, 0.4, 0.2]), 2.0, 0.5
    assert _disc_form_factor(0.0, h) == pytest.approx(1.0 / (1.0 + h * h), rel=1e-4)  # the quadrature itself
    pts = np.array([[0.0, 0.0, h], [0.6, 0.0, h], [1.4, 0.0, h]])
    nrm = np.tile([0.0, 0.0, -1.0], (3, 1))
    res = irradiance_pass(mi, _disc_scene(mi, albedo.tolist(), e0), pts, nrm, 4096, 3, transport="bounce")
    want = (
        np.array([[1.0 / (1.0 + h * h)], [_disc_form_factor(0.6, h)], [_disc_form_factor(1.4, h)]])
        * e0
        * albedo
    )
    z = (res.mean - want) / np.sqrt(res.var / res.spp)
    assert np.all(np.abs(z) < 4.5), z


def test_bounce_pass_leaves_out_a_light_seen_directly():
    """A point facing an area light (no other surface): its irradiance is all direct, the bounce exactly 0;
    the direct transport of the same pass sees it (πL·F)."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from rtfit.reference.estimators import irradiance_pass

    scene = mi.load_dict(
        {"type": "scene", "lamp": {"type": "disk", "emitter": {"type": "area", "radiance": 1.0}}}
    )
    pts, nrm = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    bounce = irradiance_pass(mi, scene, pts, nrm, 256, 1, transport="bounce")
    assert np.all(bounce.mean == 0.0)
    direct = irradiance_pass(mi, scene, pts, nrm, 1024, 1, transport="direct")
    assert direct.mean[0] == pytest.approx([math.pi * 0.5] * 3, rel=0.05)


# ------------------------------------------------------------------------------------------------ the audit
@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    cache = tmp_path_factory.mktemp("bleed") / "c"
    return audit(str(SHIPPED), approximations=[FAMILY], width=12, height=12, spp=16, cache=cache, **FAST)


def test_shipped_box_audit(shipped):
    """The mini Cornell box: one case, every row (and its fit) finite; the walls' colours reach the inputs
    (red albedo > green in channel 0 on some hit); the red wall bleeds red: the reference's red/green ratio is
    higher where more of a pixel's rays hit the red wall than the green one (the white surfaces' albedo is
    0.75 in every channel, the red wall's 0.7 in red alone, the green's 0.6 in green)."""
    (case,) = shipped.cases
    assert case.id == "bounce" and len(case.channel_inputs) == 3
    ref = case.reference.mean
    assert np.all(np.isfinite(ref)) and ref[case.mask].mean() > 0
    rows = shipped.outcomes[case.id]
    assert all(m in rows or f"{m}-fitted" in rows for m in cb.METHODS), sorted(rows)
    for row in rows.values():
        assert np.all(np.isfinite(row.image[case.mask]))
    red = sum((g["a" + str(k)] > 0.5) for k in range(1, 17) for g in case.channel_inputs[:1])
    green = sum((case.channel_inputs[1]["a" + str(k)] > 0.5) for k in range(1, 17))
    near_red, near_green = red > green + 2, green > red + 2  # more rays on the red (green) wall
    assert near_red.any() and near_green.any()
    r = ref[case.mask]
    assert r[near_red, 0].sum() / r[near_red, 1].sum() > r[near_green, 0].sum() / r[near_green, 1].sum()


TOML = """
name = "red wall over a floor"

[camera]
origin = [0, -4, 2.5]
target = [0, 0, 0.3]
fov_deg = 50
width = 10
height = 10

[[lights]]
type = "point_light"
position = [0, -0.5, 2.5]
intensity = 20

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [4, 4]
material = { type = "diffuse", reflectance = 0.7 }

[[shapes]]
type = "rectangle"
center = [0, 1, 1]
normal = [0, -1, 0]
size = [4, 2]
material = { type = "diffuse", reflectance = [0.8, 0.1, 0.1] }
"""


def test_toml_gather_agrees_with_the_path_traced_bounce_on_average(tmp_path):
    """A red wall over a white floor, one point light: the gather row (the audit's own 16 rays, each hit's
    direct light by Mitsuba's emitter sampling × its albedo) and the path-traced reference estimate the same
    integral independently: their image means agree within 4 combined standard errors per channel, and the
    floor's bounce is redder than it is green."""
    path = tmp_path / "s.toml"
    path.write_text(TOML)
    r = audit(path, FAMILY, spp=64, pass_spp=32, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    ref = case.reference.mean[case.mask]
    se = case.reference.stderr[case.mask]
    gather = r.outcomes[case.id]["gather"].image[case.mask]
    n = len(ref)
    diff = gather.mean(axis=0) - ref.mean(axis=0)
    # the gather's own spread over pixels bounds its noise; the reference's per-pixel errors add
    se_mean = np.sqrt(gather.var(axis=0) / n + (se**2).sum(axis=0) / n**2)
    assert np.all(np.abs(diff) < 4.0 * se_mean + 0.03 * ref.mean(axis=0)), (diff, se_mean)
    assert ref[:, 0].mean() > 1.2 * ref[:, 1].mean()


def test_list_names_the_family_with_its_reason():
    result = CliRunner().invoke(audit_cmd, [str(SHIPPED), "--list"])
    assert result.exit_code == 0, result.output
    assert "colour-bleeding — one diffuse bounce: the scene's geometry" in result.output
    assert "seed-sdf-bias, rgb-obscurance-seed, rgb-obscurance, gather, seed-sdf-bias-k4" in result.output


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES[FAMILY]
    assert f.module == ENGINE and f.methods is cb.METHODS
    assert [s.file for s in f.scenes] == [SHIPPED.name, "volume_room.toml"] and SHIPPED.is_file()
