"""The misty-glow family (docs/misty-glow.md): the Kawase bloom kernels against an independent simulation of
the passes (SciPy's bilinear sampling of an image), the Gaussian's closed-form energy, extremes without
NaN/Inf, the glow's single-scattering part (Mitsuba's volpathmis at max_depth 2) against the
volumetric-lightning quadrature, and the audit of the shipped XML scene."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.ndimage import map_coordinates

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_misty_glow import direct_irradiance, start_amplitude
from rtfit.experiments.audit_run import audit
from rtfit.realtime import NUMPY_OPS, kawase_glow, kawase_table, kawase_weight
from rtfit.realtime.misty_glow import METHODS
from rtfit.reference.single_scattering import point_single_scattering

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SCENE = LIBRARY / "misty_glow_point.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
LIGHT = np.array([0.013, 4.0, 0.011])


def _kawase_by_simulation(passes: int, size: int = 81) -> np.ndarray:
    """A unit delta at the centre of a size² image blurred by ``passes`` Kawase passes as a GPU runs them:
    pass k averages four bilinear reads at (±(k+½), ±(k+½)) texels (SciPy's order-1 interpolation)."""
    img = np.zeros((size, size))
    c = size // 2
    img[c, c] = 1.0
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    for k in range(passes):
        o = k + 0.5
        img = 0.25 * sum(
            map_coordinates(img, [yy + sy * o, xx + sx * o], order=1, mode="constant")
            for sy in (-1, 1)
            for sx in (-1, 1)
        )
    return img


@pytest.mark.parametrize("passes", [1, 2, 4, 8])
def test_kawase_weights_are_the_simulated_passes(passes):
    """W_N(i)·W_N(j) at scale 1 is the simulated N-pass blur of a delta at every texel (the seed's four
    passes included), and the table sums to 1."""
    sim = _kawase_by_simulation(passes)
    c = sim.shape[0] // 2
    j, i = np.mgrid[-c : c + 1, -c : c + 1].astype(np.float64)
    got = kawase_weight(i, j, passes=passes, scale=1.0)
    assert np.max(np.abs(got - sim)) < 1e-15
    assert math.isclose(sum(w for _, w in kawase_table(passes)), 1.0, rel_tol=0, abs_tol=1e-15)


def test_seed_first_pass_and_support_by_hand():
    """Pass 0 is the 3×3 binomial [1, 2, 1]ᵀ[1, 2, 1]/16; four passes reach 1 + 2 + 3 + 4 = 10 texels."""
    assert kawase_table(1) == ((-1, 0.25), (0, 0.5), (1, 0.25))
    table = kawase_table(4)
    assert table[0][0] == -10 and table[-1][0] == 10
    assert math.isclose(float(kawase_weight(1.0, 1.0, passes=1, scale=1.0)), 1 / 16, rel_tol=1e-15)
    assert math.isclose(float(kawase_weight(0.0, 0.0, passes=1, scale=1.0)), 4 / 16, rel_tol=1e-15)


def test_upsampled_kernel_is_the_bilinear_upsample_and_keeps_the_energy():
    """At scale s = 4 (the seed's ¼ buffer) the weight at film offset (u, v) is the bilinear interpolation
    of the texel image at (u/4, v/4) over 16 (SciPy), and it sums to 1 over the film pixels."""
    sim = _kawase_by_simulation(4, size=41)
    c = 20
    v, u = np.mgrid[-90:91, -90:91].astype(np.float64)
    got = kawase_weight(u, v, passes=4, scale=4.0)
    want = map_coordinates(sim, [c + v / 4.0, c + u / 4.0], order=1, mode="constant") / 16.0
    assert np.max(np.abs(got - want)) < 1e-15
    assert math.isclose(float(got.sum()), 1.0, rel_tol=1e-12)


def test_glow_rows_at_hand_computed_points():
    """kawase-seed: L = A·E/Ω·W(u/4)W(v/4)/16 at three points by hand (the last one past the support of
    11 texels); gaussian: Σ L·Ω = A·E (σ = 3 px)."""
    e, om, a = 2.0, 1e-4, 0.5
    # at the light's image: W(0) = 0.234619140625 (the 4-pass table's centre, by the simulation above)
    w0 = _kawase_by_simulation(4)[40, 40] ** 0.5
    for (u, v), wu, wv in (((0.0, 0.0), w0, w0), ((2.0, 0.0), None, w0), ((44.0, 44.0), 0.0, 0.0)):
        got = METHODS["kawase-seed"](
            NUMPY_OPS, {"du": u, "dv": v, "e_direct": e, "omega_px": om}, {"amplitude": a}
        )
        if wu is None:  # u/4 = 0.5: the mean of the table at 0 and 1
            table = dict(kawase_table(4))
            wu = 0.5 * (table[0] + table[1])
        assert math.isclose(float(got), a * e / om * wu * wv / 16.0, rel_tol=1e-14, abs_tol=1e-300)
    v, u = np.mgrid[-40:41, -40:41].astype(np.float64)
    g = METHODS["gaussian"](
        NUMPY_OPS, {"du": u, "dv": v, "e_direct": e, "omega_px": om}, {"amplitude": a, "sigma": 3.0}
    )
    assert math.isclose(float(np.sum(g) * om), a * e, rel_tol=1e-9)


def test_public_functions_say_what_is_wrong_in_one_line():
    for call, word in (
        (lambda: kawase_weight(0.0, 0.0, passes=0), "passes"),
        (lambda: kawase_weight(0.0, 0.0, scale=0.0), "scale"),
        (lambda: kawase_glow(0.0, 0.0, -1.0, 1e-4), "e_direct"),
        (lambda: kawase_glow(0.0, 0.0, 1.0, 0.0), "omega_px"),
    ):
        with pytest.raises(ValueError, match=word) as info:
            call()
        assert "\n" not in str(info.value)


_F = st.floats(allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(
    sigma_t=st.one_of(st.just(0.0), st.floats(0.0, 1e4), st.just(1e30)),
    albedo=st.floats(0.0, 1.0),
    g=st.one_of(st.just(0.0), st.just(0.9999), st.floats(0.0, 0.9999)),
    u=st.floats(-1e3, 1e3),
    scale=st.floats(0.05, 512.0),
    sigma=st.floats(0.05, 512.0),
)
@example(sigma_t=5e-324, albedo=0.0, g=0.0, u=0.0, scale=1.0, sigma=1.0)  # a denormal σ_t, found by CI
def test_extremes_finite(sigma_t, albedo, g, u, scale, sigma):
    """Zero and huge density, g → 0 and g → 1, fitted scales at their bounds: the audit's inputs (E_d, A₀),
    every bloom row and the single-scattering quadrature stay finite and non-negative (float32 Dr.Jit and
    float64 NumPy)."""
    e = direct_irradiance(np.full(3, 16.0), np.full(3, sigma_t), 4.0)
    a0 = start_amplitude(np.full(3, albedo * sigma_t), 4.0)
    assert np.all(np.isfinite(e)) and np.all(e >= 0) and 0 < a0 <= 1e5
    inputs = {"du": np.array([u, 0.0]), "dv": np.array([0.5, -u]), "e_direct": np.full(2, e[0]),
              "omega_px": np.full(2, 1e-4)}  # fmt: skip
    for mid, m in METHODS.items():
        if mid == "single-scattering":
            continue
        params = {
            "amplitude": a0,
            "scale" if "scale" in m.params else "sigma": scale if "scale" in m.params else sigma,
        }
        for x in (m.evaluate({k: v.astype(np.float32) for k, v in inputs.items()}, params),
                  m(NUMPY_OPS, inputs, params)):  # fmt: skip
            x = np.asarray(x)
            assert np.all(np.isfinite(x)) and np.all(x >= 0), (mid, x)
    dirs = np.array([[0.0, 1.0, 0.0], [0.05, 0.998749, 0.0]])
    st_ = min(sigma_t, 1e4)
    ss = point_single_scattering((0.0, 0.0, 0.0), dirs, np.full(2, 19.0), LIGHT, 16.0, albedo * st_, st_, g=g)
    assert np.all(np.isfinite(ss)) and np.all(ss >= 0)


# ------------------------------------------------------------------------------ Mitsuba: single scattering
def test_single_scattering_part_is_the_volumetric_lightning_quadrature():
    """The glow's first order: Mitsuba's volpathmis with max_depth = 2 (one scattering event) at the pixel
    centres of the shipped scene (σ_t = 0.5, g = 0.85) against `point_single_scattering` (the
    volumetric-lightning family's quadrature) along the same rays to the box's far wall y = 19 m."""
    import mitsuba as mi

    from rtfit.reference.estimators import radiance_pass

    mi.set_variant("llvm_ad_rgb")
    scene = mi.load_file(str(SCENE), sigma_t="0.5", g="0.85", albedo="0.9")
    sensor = scene.sensors()[0]
    params = mi.traverse(sensor)
    params["film.size"] = [12, 12]
    params.update()
    r = radiance_pass(mi, scene, 2048, 3, integrator=mi.load_dict({"type": "volpathmis", "max_depth": 2}))
    mean, err = r.mean.reshape(-1, 3)[:, 0], np.sqrt(r.var.reshape(-1, 3)[:, 0] / r.spp)
    # pixel-centre directions of a 12×12 film, fov 40° in x, camera at the origin looking along +y, +z up
    t = math.tan(math.radians(20.0))
    xs = (np.arange(12) + 0.5) / 12 * 2 - 1
    tx, tz = np.meshgrid(xs * t, -xs * t)
    d = np.stack([tx.ravel(), np.ones(144), tz.ravel()], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    truth = point_single_scattering((0.0, 0.0, 0.0), d, 19.0 / d[:, 1], LIGHT, 16.0, 0.45, 0.5, g=0.85)
    z = (mean - truth) / np.maximum(err, 1e-12)
    assert abs(float(np.median(z))) < 0.3 and float(np.mean(np.abs(z) < 3.0)) > 0.95, (np.median(z), z)
    assert float(np.sum(mean)) == pytest.approx(float(np.sum(truth)), rel=0.03)


# ------------------------------------------------------------------------------------------ the audit
@pytest.fixture(scope="module")
def glow_audit(tmp_path_factory):
    cache = tmp_path_factory.mktemp("glow") / "c"
    return audit(str(SCENE), ["misty-glow"], width=16, height=16, spp=128, pass_spp=64, cache=cache,
                 defines={"sigma_t": "0.5"}, **FAST)  # fmt: skip


def test_shipped_scene_audit(glow_audit):
    """One case on every pixel: the image offsets are the pinhole projection computed here (up to the
    film's mirror), E_d = I·e^(−σ_t R)/R², the single-scattering row is the quadrature and sits below the
    all-orders reference; every bloom row is evaluated and fitted, the fit beating the given start."""
    r = glow_audit
    (case,) = r.cases
    assert case.id == "light0-glow" and case.mask.all()
    g = case.channel_inputs[0]
    rr = float(np.linalg.norm(LIGHT))  # 4.00004 m
    assert math.isclose(g["e_direct"], 16.0 * math.exp(-0.5 * rr) / rr**2, rel_tol=1e-9)
    pitch = 2 * math.tan(math.radians(20.0)) / 16
    c = (np.arange(16) + 0.5) / 16 * 2 - 1
    tx = c * math.tan(math.radians(20.0))
    lx, lz = LIGHT[0] / LIGHT[1], LIGHT[2] / LIGHT[1]
    du = np.abs(g["du"]).reshape(16, 16)
    dv = np.abs(g["dv"]).reshape(16, 16)
    cols = [np.abs(s * tx - lx) / pitch for s in (1, -1)]
    rows = [np.abs(s * tx - lz) / pitch for s in (1, -1)]
    assert min(np.max(np.abs(du - col[None, :])) for col in cols) < 1e-3
    assert min(np.max(np.abs(dv - row[:, None])) for row in rows) < 1e-3
    outcomes = r.outcomes[case.id]
    assert {"kawase-seed", "kawase-seed-fitted", "gaussian-fitted", "single-scattering"} <= set(outcomes)
    ref = case.reference.mean[case.mask][:, 0]
    single = outcomes["single-scattering"].image[case.mask][:, 0]
    assert np.all(single >= 0) and float(ref.sum()) > float(single.sum())  # multiple scattering adds
    rmse = {k: o.metrics["rmse"].value for k, o in outcomes.items()}
    assert rmse["kawase-seed-fitted"] <= rmse["kawase-seed"]
    assert rmse["gaussian-fitted"] <= rmse["gaussian"]


def test_list_names_misty_glow():
    result = CliRunner().invoke(audit_cmd, [str(SCENE), "--list"])
    assert result.exit_code == 0, result.output
    assert "misty-glow — glow around a light in a medium: point light 'lamp'" in result.output
    assert "kawase-seed, kawase-1, kawase-2, kawase-6, kawase-8, gaussian, single-scattering" in result.output


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES["misty-glow"]
    assert f.module == ENGINE and f.methods is METHODS
    assert {s.file for s in f.scenes} == {"misty_glow_point.xml"} and SCENE.is_file()
