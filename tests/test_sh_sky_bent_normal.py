"""Tests of the sh-sky-bent-normal family (rtfit.realtime.sh_sky_bent_normal,
experiments/audit_sh_sky_bent_normal.py) against independent values only.

Oracles written here: the real SH basis to l = 2 typed from Sloan's table (no Condon–Shortley phase), and
Gauss–Legendre × uniform-φ quadratures of a radiance L(ω) = Σ L_lm Y_lm(ω) over the hemisphere of a normal
and over a cone about an axis (a polynomial integrand on the cap: 24 × 48 nodes integrate it to rounding);
for the audit, a constant sky over a ground plane and a floating sphere, whose occluded irradiance at a ground
point is πL(1 − sin²α cos β) (the sphere's cap, always above the ground point's horizon: h ≥ R). Renders are
tiny (16×16 pixels, 16–64 samples per pixel).
"""

from __future__ import annotations

import math
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.realtime import DRJIT_OPS, NUMPY_OPS, cone_factors, sh_cone_irradiance, sh_radiance
from rtfit.realtime import sh_sky_bent_normal as sk

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SHIPPED = LIBRARY / "sh_sky_bent_normal_blocks.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
FAMILY = "sh-sky-bent-normal"


# ------------------------------------------------------------------------------------------------ oracles
def _y(d: np.ndarray) -> np.ndarray:
    """The 9 real SH Y_lm (l ≤ 2, index l(l + 1) + m, no Condon–Shortley phase) at unit directions (N, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    a0, a1 = 0.5 / math.sqrt(math.pi), math.sqrt(3.0 / (4.0 * math.pi))
    b, c20, c22 = (
        math.sqrt(15.0 / (4.0 * math.pi)),
        math.sqrt(5.0 / (16.0 * math.pi)),
        math.sqrt(15.0 / (16.0 * math.pi)),
    )
    return np.stack(
        [np.full_like(x, a0), a1 * y, a1 * z, a1 * x, b * x * y, b * y * z, c20 * (3 * z * z - 1), b * x * z,
         c22 * (x * x - y * y)], axis=1,
    )  # fmt: skip


def _radiance(sh9x3: np.ndarray, d: np.ndarray) -> np.ndarray:
    return _y(d) @ sh9x3  # (N, 3)


def _frame(axis):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    return t, np.cross(a, t), a


def _cap_quadrature(sh9x3, axis, half_angle, cosine_axis=None, n_theta=24, n_phi=48) -> np.ndarray:
    """∫_{cap(axis, half_angle)} L(ω) max(c·ω, 0) dω (RGB) with c = ``cosine_axis`` (default: the axis)."""
    t, s, a = _frame(axis)
    u, w = np.polynomial.legendre.leggauss(n_theta)
    cos_lo = math.cos(half_angle)
    mu = cos_lo + (u + 1.0) * 0.5 * (1.0 - cos_lo)  # cos θ about the axis
    wm = w * 0.5 * (1.0 - cos_lo)
    phi = (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    sin = np.sqrt(1.0 - m * m)
    d = (sin * np.cos(p))[..., None] * t + (sin * np.sin(p))[..., None] * s + m[..., None] * a
    d = d.reshape(-1, 3)
    c = a if cosine_axis is None else np.asarray(cosine_axis, float) / np.linalg.norm(cosine_axis)
    weight = (np.repeat(wm, n_phi) * (2.0 * math.pi / n_phi)) * np.maximum(d @ c, 0.0)
    return weight @ _radiance(sh9x3, d)


def _table(sh9x3) -> list[float]:
    return [float(v) for v in np.asarray(sh9x3).T.reshape(-1)]


def _row(mid: str, n, b, ao, aperture, sh9x3, params=None, ops=NUMPY_OPS) -> np.ndarray:
    n, b = np.atleast_2d(n).astype(float), np.atleast_2d(b).astype(float)
    inputs = {
        "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2], "bx": b[:, 0], "by": b[:, 1], "bz": b[:, 2],
        "ao": np.asarray(ao, float), "aperture": np.asarray(aperture, float), "coeffs": _table(sh9x3),
    }  # fmt: skip
    m = sk.METHODS[mid]
    out = m(ops, {k: inputs[k] for k in m.input_names}, params)
    return np.stack([np.broadcast_to(np.asarray(c, float), (len(n),)) for c in out], axis=1)


RNG = np.random.default_rng(11)
SKY = RNG.normal(0.0, 0.3, (9, 3))
SKY[0] = [3.0, 2.5, 2.0]  # positive enough that nothing rings below zero at the test directions
DIRS = np.array([[0.0, 0.0, 1.0], [0.6, -0.3, 0.74], [-0.8, 0.1, 0.59], [0.2, 0.97, -0.1]])
DIRS /= np.linalg.norm(DIRS, axis=1, keepdims=True)


# ------------------------------------------------------------------------- kernels vs independent values
def test_seed_row_is_pi_times_the_sh_radiance_times_ao():
    """The seed's lookup (000:429) at 4 bent normals on a random L2 sky: π·L_SH(b)·V with L_SH typed here
    (to 1e-12); s and p: s·π·L·V^p; the public sh_radiance is L_SH itself."""
    ao = np.array([1.0, 0.5, 0.25, 0.8])
    want = math.pi * _radiance(SKY, DIRS) * ao[:, None]
    got = _row("seed-radiance-bent", DIRS, DIRS, ao, 0.0, SKY)
    assert np.max(np.abs(got - want)) < 1e-12 * np.max(np.abs(want))
    got = _row("seed-radiance-bent", DIRS, DIRS, ao, 0.0, SKY, {"scale": 0.7, "ao_power": 2.0})
    assert np.allclose(got, 0.7 * math.pi * _radiance(SKY, DIRS) * ao[:, None] ** 2, rtol=1e-12)
    assert np.allclose(sh_radiance(SKY, DIRS), _radiance(SKY, DIRS), rtol=1e-12)


def test_irradiance_rows_are_the_hemisphere_integral_of_the_sh_sky():
    """E_SH(d) = ∫ L_SH(ω) max(d·ω, 0) dω by quadrature here (the L2 sky is exactly its projection: Funk–Hecke
    is then exact): at the bent normal and at the normal, × V; the radiance row differs (its band 2 is not
    ¼-weighted)."""
    ao = np.array([1.0, 0.6, 0.3, 0.9])
    quad = np.array([_cap_quadrature(SKY, d, math.pi / 2) for d in DIRS])
    bent = _row("irradiance-bent", -DIRS, DIRS, ao, 0.0, SKY)  # (the normal is not read)
    normal = _row("irradiance-normal", DIRS, -DIRS, ao, 0.0, SKY)  # (the bent normal is not read)
    assert np.max(np.abs(bent - quad * ao[:, None])) < 1e-10
    assert np.max(np.abs(normal - quad * ao[:, None])) < 1e-10
    seed = _row("seed-radiance-bent", DIRS, DIRS, ao, 0.0, SKY)
    assert np.max(np.abs(seed - bent)) > 0.05  # π·L ≠ E for a sky with bands 1 and 2


@pytest.mark.parametrize("half_angle", [0.0, 0.3, 0.9, 1.4, math.pi / 2])
def test_cone_row_is_the_sky_through_the_cone_with_the_cosine_about_its_axis(half_angle):
    """∫_{cone(b, r_a)} L_SH(ω)(b·ω) dω by quadrature here at 4 axes; the zonal factors at hand-computed
    values (f = 0 at r_a = 0, 1 at π/2; at 60°: c = ½ gives (¾, ⅞, ¾·7/4)); a constant sky L gives
    πL sin²r_a."""
    got = _row("cone-bent", DIRS, DIRS, 1.0, np.full(len(DIRS), half_angle), SKY)
    quad = np.array([_cap_quadrature(SKY, d, half_angle) for d in DIRS])
    assert np.max(np.abs(got - quad)) < 1e-10
    f = np.array(cone_factors(math.pi / 3))
    assert np.allclose(f, [0.75, 0.875, 0.75 * 1.75], rtol=1e-12)
    const = np.zeros((9, 3))
    const[0] = np.array([0.5, 1.0, 2.0]) * math.sqrt(4 * math.pi)
    e = sh_cone_irradiance(const, [0.3, 0.2, 0.9], half_angle)
    assert np.allclose(
        e, math.pi * math.sin(half_angle) ** 2 * np.array([0.5, 1.0, 2.0]), rtol=1e-12, atol=1e-15
    )


def test_a_constant_sky_all_rows_by_hand():
    """Constant L = (0.5, 1, 2): L00 = L√(4π); π·L_SH(b)·V = E_SH(b)·V = E_SH(n)·V = πLV for any b, n (V = 0:
    the 1e-30 floor of V, πL·1e-30); the cone with r_a = acos(1 − V_u) is πL(1 − (1 − V_u)²)."""
    lum = np.array([0.5, 1.0, 2.0])
    const = np.zeros((9, 3))
    const[0] = lum * math.sqrt(4.0 * math.pi)
    v = np.array([1.0, 0.4, 0.05, 0.0])
    for mid in ("seed-radiance-bent", "irradiance-bent", "irradiance-normal"):
        got = _row(mid, DIRS, DIRS[::-1], v, 0.0, const)
        assert np.allclose(got, math.pi * lum[None, :] * v[:, None], rtol=1e-12, atol=1e-28), mid
    vu = np.array([1.0, 0.5, 0.1, 0.0])
    got = _row("cone-bent", DIRS, DIRS, 1.0, np.arccos(1.0 - vu), const)
    assert np.allclose(got, math.pi * lum[None, :] * (1.0 - (1.0 - vu) ** 2)[:, None], rtol=1e-12, atol=1e-15)


def test_float32_drjit_agrees_with_float64_numpy():
    """The Dr.Jit float32 run of each kernel text on 2000 random inputs against the float64 NumPy run: within
    2⁻²⁰ of the largest |value| (measured ≤ 1.9e-7 relative)."""
    rng = np.random.default_rng(5)
    n = rng.normal(size=(2000, 3))
    b = rng.normal(size=(2000, 3))
    ao, ap = rng.uniform(0, 1, 2000), rng.uniform(0, math.pi / 2, 2000)
    for mid, m in sk.METHODS.items():
        params = {k: 1.3 for k in m.params}
        want = _row(mid, n, b, ao, ap, SKY, params)
        F = dr.llvm.Float
        inputs = {
            "nx": F(n[:, 0]), "ny": F(n[:, 1]), "nz": F(n[:, 2]), "bx": F(b[:, 0]), "by": F(b[:, 1]),
            "bz": F(b[:, 2]), "ao": F(ao), "aperture": F(ap), "coeffs": _table(SKY),
        }  # fmt: skip
        out = m(DRJIT_OPS, {k: inputs[k] for k in m.input_names}, params)
        got = np.stack([np.asarray(c, np.float64) for c in out], axis=1)
        assert np.max(np.abs(got - want)) <= 2.0**-20 * np.max(np.abs(want)), mid


_UNIT = st.tuples(*[st.floats(-1.0, 1.0)] * 3)
_COEF = st.lists(st.floats(-1e3, 1e3), min_size=27, max_size=27)


@settings(max_examples=150, deadline=None)
@given(
    n=_UNIT, b=_UNIT, ao=st.floats(0.0, 1.0), ap=st.floats(0.0, math.pi / 2), coeffs=_COEF,
    scale=st.floats(1e-3, 100.0), power=st.floats(0.05, 8.0),
)  # fmt: skip
def test_every_row_finite_and_nonnegative_over_the_whole_domain(n, b, ao, ap, coeffs, scale, power):
    """Any normal and bent normal (zero vectors included), V ∈ [0, 1], r_a ∈ [0, π/2], SH coefficients up to
    10³, s and p over their bounds: finite and ≥ 0 in float64 and float32."""
    sh = np.asarray(coeffs, float).reshape(3, 9).T
    for mid, m in sk.METHODS.items():
        params = {k: v for k, v in {"scale": scale, "ao_power": power}.items() if k in m.params}
        got = _row(mid, [n], [b], [ao], [ap], sh, params)
        assert np.all(np.isfinite(got)) and np.all(got >= 0.0), (mid, got)
        F = dr.llvm.Float
        inputs = {
            "nx": F(n[0]), "ny": F(n[1]), "nz": F(n[2]), "bx": F(b[0]), "by": F(b[1]), "bz": F(b[2]),
            "ao": F(ao), "aperture": F(ap), "coeffs": list(map(float, coeffs)),
        }  # fmt: skip
        out = m(DRJIT_OPS, {k: inputs[k] for k in m.input_names}, params)
        g = np.array([np.asarray(c, np.float64)[0] for c in out])
        assert np.all(np.isfinite(g)) and np.all(g >= 0.0), (mid, g)


def test_public_functions_say_what_is_wrong_in_one_line():
    with pytest.raises(ValueError, match=r"coeffs must be 27 finite floats") as e:
        sh_radiance(np.zeros((4, 3)), [0, 0, 1])
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match=r"aperture"):
        sh_cone_irradiance(SKY, [0, 0, 1], 2.0)
    with pytest.raises(ValueError, match=r"aperture"):
        cone_factors(-0.1)


# ------------------------------------------------------------------------------------------------ the audit
SPHERE_OVER_FLOOR = Path(__file__).parent / "data" / "sphere_over_floor.toml"


def test_toml_constant_sky_over_a_floating_sphere_matches_the_closed_form(tmp_path):
    """A constant sky L over a floor and a sphere (centre height h = 1, R = 0.5: its cap is above every ground
    point's horizon): at a ground point at distance d from the centre, E = πL(1 − (R/d)²·h/d) — the reference
    sits on it (pooled |z| mean < 0.5, max < 4.5 at 64 spp); the bake is L00 = L√(4π), the rest ~0; the seed
    row and the irradiance rows are πL·V (V the bake's), so within the bake's noise of the closed form."""
    r = audit(SPHERE_OVER_FLOOR, FAMILY, spp=64, pass_spp=32, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    assert case.id == "shsky0" and case.parameters["kind"] == "constant"
    g = case.channel_inputs[0]
    lum = np.array([0.5, 1.0, 2.0])
    sh = np.asarray(g["coeffs"]).reshape(3, 9)
    assert np.allclose(sh[:, 0], lum * math.sqrt(4 * math.pi), rtol=1e-4)
    assert np.max(np.abs(sh[:, 1:])) < 1e-4
    ground = np.abs(g["pz"]) < 1e-3
    assert 50 < ground.sum() < ground.size
    d = np.sqrt(g["px"] ** 2 + g["py"] ** 2 + 1.0)
    want = math.pi * lum[None, :] * (1.0 - (0.25 / d**2) * (1.0 / d))[ground, None]
    ref = case.reference.mean[case.mask][ground]
    err = case.reference.stderr[case.mask][ground]
    z = (ref - want) / err
    assert abs(float(np.mean(z))) < 0.5 and float(np.max(np.abs(z))) < 4.5, (np.mean(z), np.max(np.abs(z)))
    rows = r.outcomes[case.id]
    assert set(rows) == {f"{m}{s}" for m in sk.METHODS for s in ("", "-fitted")}
    pi_l_v = math.pi * lum[None, :] * g["ao"][:, None]
    for mid in ("seed-radiance-bent", "irradiance-bent", "irradiance-normal"):
        assert np.allclose(rows[mid].image[case.mask], pi_l_v, rtol=2e-6), mid
    v_exact = 1.0 - 0.25 / d**3
    # The bake (64 uniform rays a point) estimates V without bias, then clips it to [0, 1] as an engine's AO:
    # an open point reads low by E[min(X, 1)] − 1 ≈ −0.4σ, σ = √(1/3)/8 = 0.072 (measured mean −0.022).
    bias = float(np.mean(g["ao"][ground] - v_exact[ground]))
    assert -0.05 < bias < 0.01, bias


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    cache = tmp_path_factory.mktemp("shsky") / "c"
    return audit(str(SHIPPED), approximations=[FAMILY], width=16, height=16, spp=16, cache=cache, **FAST)


def test_shipped_scene_audit(shipped):
    """The shipped blocks under a sunsky: one case, every row and its fit finite; the sky's SH brighter above
    (L10 > 0) with the sun left out; the bent normals unit, the AO in [0, 1] with occluded pixels; fitting
    never makes a row worse."""
    (case,) = shipped.cases
    assert case.id == "shsky0" and case.parameters["kind"] == "sunsky"
    g = case.channel_inputs[0]
    sh = np.asarray(g["coeffs"]).reshape(3, 9)
    assert np.all(sh[:, 0] > 0) and np.all(sh[:, 2] > 0)
    b = np.stack([g["bx"], g["by"], g["bz"]], axis=1)
    assert np.allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-6)
    assert 0.0 <= g["ao"].min() and g["ao"].max() <= 1.0 and g["ao"].min() < 0.7
    ref = case.reference.mean[case.mask]
    assert np.all(np.isfinite(ref)) and ref.mean() > 0
    rows = shipped.outcomes[case.id]
    assert set(rows) == {f"{m}{s}" for m in sk.METHODS for s in ("", "-fitted")}
    for row in rows.values():
        assert np.all(np.isfinite(row.image[case.mask]))
    for mid in sk.METHODS:
        assert rows[f"{mid}-fitted"].metrics["rmse"].value <= 1.001 * rows[mid].metrics["rmse"].value, mid


def test_list_names_the_family_with_its_reason():
    result = CliRunner().invoke(audit_cmd, [str(SHIPPED), "--list"])
    assert result.exit_code == 0, result.output
    assert "sh-sky-bent-normal — sky ambient (SH at the bent normal): sunsky environment" in result.output
    assert "seed-radiance-bent, irradiance-bent, irradiance-normal, cone-bent" in result.output


def test_registry_entry_is_born_on_the_engine_and_runs(tmp_path):
    """``rtfit run sh-sky-bent-normal --quick`` through the engine: one case per shipped scene, the
    fitted-parameter file, no failed check."""
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.registry import ExperimentSpec
    from rtfit.experiments.results import load_results
    from rtfit.experiments.run_settings import RunSettings
    from rtfit.experiments.runner import failed_checks, run_experiments

    f = FAMILIES[FAMILY]
    assert f.module == ENGINE and f.methods is sk.METHODS
    assert [s.file for s in f.scenes] == [SHIPPED.name] and SHIPPED.is_file()
    spec = ExperimentSpec(FAMILY, ENGINE, f.title, f.description)
    run_experiments([spec], tmp_path / "out", RunSettings(tmp_path / "c", "llvm_ad_rgb", spp=8, quick=True))
    d = tmp_path / "out" / FAMILY
    res = load_results(d)
    assert [c.id for c in res.cases] == ["sh_sky_bent_normal_blocks-shsky0"]
    assert not failed_checks(res) and (d / "fitted" / f"{FAMILY}.json").is_file()
