"""Tests of rtfit.realtime.volumetric_lightning against independent values only.

References used here (none of them is the code's own output):
* mpmath quadrature at 40 digits of the integrand ∫₀¹ |d|/(k + a|c − t d|²) dt itself (`quad_integral`),
  split at the closest approach to the light, evaluated at the exact float32 (or float64) inputs the kernel
  sees: no closed form is involved;
* the elementary limits F = i|d| (a = 0), F = 0 (|d| = 0), F = i|d|/(1 + a|c|²) (|d| → 0) and the
  textbook airlight of a point light without extinction, K·θ/h for a segment symmetric about the foot of
  the perpendicular (∫ ds/(h² + s²) = 2 atan(L/2h)/h).

The domain (`domain`): a ∈ {0} ∪ log-uniform [1e-6, 1e3] /m², |c| log-uniform up to 1e4 m, |d| from 0 to
1e4 m, rays from 1e-8 rad off the axis through the light to perpendicular, the light beyond, behind or
between the end points. Inputs are drawn so that the float32 subtraction l − o is exact (o on the grid of
c's ulps): the test measures the kernel, not the rounding of its inputs (docstring of the module).

Tolerances with their measured maxima (800 points + 200 near-axial at a = 100 and 1e3; a run on 1200 + 300
gave the same bounds): float32 (Dr.Jit LLVM) 1e-5 relative, measured ≤ 7.6e-7; float64 (Dr.Jit LLVM
Float64) 1e-12, measured ≤ 8e-16; NumPy text in float64 (Python floats; Dekker splitting instead of fma)
1e-12, measured ≤ 8e-16.
"""

from __future__ import annotations

import math

import drjit as dr
import mpmath as mp
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments import audit_volumetric_lightning
from rtfit.experiments import volumetric_lightning_study as study
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import ENGINE, FAMILIES
from rtfit.experiments.shipped import StudyContext
from rtfit.experiments.volumetric_lightning_study import random_domain as domain
from rtfit.realtime import NUMPY_OPS, inverse_square_airlight, volumetric_lightning
from rtfit.realtime.volumetric_lightning import METHODS
from rtfit.reference.single_scattering import point_estimator_variance, point_single_scattering
from rtfit.scenes.parse import LIBRARY_DIR

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # kernels must not warn (0/0, overflow)

TOL32 = 1e-5  # relative, float32 (measured ≤ 7.6e-7)
TOL64 = 1e-12  # relative, float64 (measured ≤ 8e-16)
Float, Float64 = dr.llvm.Float, dr.llvm.Float64


# --------------------------------------------------------------------------------- independent reference
def quad_integral(c, d, k: float, a: float) -> float:
    """∫₀¹ |d|/(k + a|c − t d|²) dt by mpmath.quad at 40 digits, split at the closest approach t* (and a
    few widths of the peak around it), from exactly the given binary inputs."""
    with mp.workdps(40):
        c = [mp.mpf(float(x)) for x in c]
        d = [mp.mpf(float(x)) for x in d]
        k, a = mp.mpf(k), mp.mpf(a)
        dd = sum(x * x for x in d)
        if dd == 0:
            return 0.0
        length = mp.sqrt(dd)

        def f(t):
            r2 = sum((ci - t * di) ** 2 for ci, di in zip(c, d, strict=True))
            return length / (k + a * r2)

        ts = sum(ci * di for ci, di in zip(c, d, strict=True)) / dd
        cross2 = sum(ci * ci for ci in c) * dd - sum(ci * di for ci, di in zip(c, d, strict=True)) ** 2
        width = mp.sqrt(max(cross2, 0) / dd + (k / a if a > 0 else 1)) / length  # peak half-width in t
        pts = {mp.mpf(0), mp.mpf(1)}
        for m in (0, -1, 1, -10, 10, -100, 100, -1e4, 1e4):
            t = ts + m * width
            if 0 < t < 1:
                pts.add(t)
        return float(mp.quad(f, sorted(pts)))


def _oracle(o, d, lpos, a, k=1.0):
    c = lpos.astype(np.float64) - o.astype(np.float64)
    return np.array([quad_integral(c[j], d[j], k, float(a[j])) for j in range(len(a))])


def _rel(got, truth):
    got = np.asarray(got, dtype=np.float64)
    return np.abs(got - truth) / np.maximum(np.abs(truth), 1e-300)


@pytest.fixture(scope="module")
def sample():
    o, d, lpos, a = domain(800, 1)
    o2, d2, l2, a2 = domain(200, 2, near_axial=1.0, a_values=(100.0, 1e3))
    o, d, lpos, a = (np.concatenate(p) for p in ((o, o2), (d, d2), (lpos, l2), (a, a2)))
    return o, d, lpos, a, _oracle(o, d, lpos, a)


# ------------------------------------------------------------------------------------------- accuracy
def test_float32_within_1e5_of_mpmath(sample):
    o, d, lpos, a, truth = sample
    got = volumetric_lightning(o, d, lpos, np.float32(1.0), a)
    assert got.dtype == np.float32
    rel = _rel(got, truth)
    assert np.all(np.isfinite(got))
    assert rel.max() <= TOL32, (rel.max(), o[rel.argmax()], d[rel.argmax()], lpos[rel.argmax()])


def test_float64_within_1e12_of_mpmath(sample):
    o, d, lpos, a, truth = sample
    got = volumetric_lightning(*(x.astype(np.float64) for x in (o, d, lpos)), 1.0, a.astype(np.float64))
    assert got.dtype == np.float64
    assert _rel(got, truth).max() <= TOL64


def test_numpy_text_float64_within_1e12(sample):
    """The NumPy run of the same text (benchmarks' baseline; Python-float calls) uses Dekker's splitting."""
    o, d, lpos, a, truth = sample
    m = METHODS["stable"]
    names = m.input_names
    vals = [*o.T, *d.T, *lpos.T]
    inputs = {n: v.astype(np.float64) for n, v in zip(names, vals, strict=True)}
    got = m(NUMPY_OPS, inputs, {"i": 1.0, "a": a.astype(np.float64)})
    assert _rel(got, truth).max() <= TOL64
    # one Python-float call goes through the same text (scalar dispatch)
    j = int(np.argmax(a))
    one = volumetric_lightning(
        tuple(map(float, o[j])), tuple(map(float, d[j])), tuple(map(float, lpos[j])), 1, float(a[j])
    )
    assert isinstance(one, float) and abs(one / truth[j] - 1) <= TOL64


def test_drjit_array3f_and_float32_inputs_agree(sample):
    o, d, lpos, a, truth = sample
    v = [dr.llvm.Array3f(*(Float(np.ascontiguousarray(x[:, k])) for k in range(3))) for x in (o, d, lpos)]
    got = volumetric_lightning(*v, 1.0, Float(a))
    assert isinstance(got, Float)
    assert _rel(np.asarray(got), truth).max() <= TOL32


def test_inverse_square_matches_mpmath_and_textbook():
    o, d, lpos, _ = domain(300, 3)
    c = lpos.astype(np.float64) - o.astype(np.float64)
    keep = np.linalg.norm(np.cross(c, d.astype(np.float64)), axis=1) > 1e-6 * np.linalg.norm(
        c, axis=1
    ) * np.maximum(np.linalg.norm(d, axis=1), 1e-30)
    o, d, lpos, c = o[keep], d[keep], lpos[keep], c[keep]
    truth = np.array([quad_integral(c[j], d[j], 0.0, 1.0) for j in range(len(c))])
    got = inverse_square_airlight(o, d, lpos, np.float32(1.0))
    assert _rel(got, truth).max() <= TOL32
    # symmetric segment at distance h: 2·atan(L/2h)/h
    for h, length in ((1.0, 2.0), (0.01, 100.0), (100.0, 1.0)):
        val = inverse_square_airlight((0.0, 0.0, 0.0), (length, 0.0, 0.0), (length / 2, h, 0.0))
        assert abs(val / (2 * math.atan(length / (2 * h)) / h) - 1) <= 1e-14


def test_seed_model_tends_to_inverse_square_as_a_grows():
    """i/a fixed, a → ∞: the seed's model is single scattering without extinction (docstring)."""
    o, d, lpos = (0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (3.0, 0.5, 0.2)
    ref = inverse_square_airlight(o, d, lpos)
    prev = math.inf
    for a in (1.0, 1e2, 1e4, 1e6):
        err = abs(volumetric_lightning(o, d, lpos, a, a) / ref - 1)
        assert err < prev
        prev = err
    assert prev < 1e-5


# ------------------------------------------------------------------------------------------- extremes
def test_limits_a_zero_and_zero_segment():
    o = np.zeros((3, 3), np.float32)
    d = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1e-30, 0.0, 0.0]], np.float32)
    lpos = np.array([[1.0, 2.0, 3.0]] * 3, np.float32)
    f = volumetric_lightning(o, d, lpos, np.float32(2.0), np.zeros(3, np.float32))
    assert f[0] == pytest.approx(10.0, rel=1e-7) and f[1] == 0.0
    g = volumetric_lightning(o, d, lpos, 2.0, np.float32(0.5))
    assert g[1] == 0.0
    assert g[2] == pytest.approx(2.0 * 1e-30 / (1 + 0.5 * 14), rel=1e-6)  # |d| → 0: i|d|/(1 + a|c|²)
    # the seed's printed form: 0/0 at a = 0 and at |d| = 0
    seed = METHODS["seed"].evaluate(
        {n: v for n, v in zip(METHODS["seed"].input_names, [*o.T, *d.T, *lpos.T], strict=True)},
        {"i": 2.0, "a": np.float32(0.0)},
    )
    assert np.isnan(seed[0]) and np.isnan(seed[1])


def test_distant_source_and_through_the_light():
    # a ray pointing at a light 1e4 m away, segment 1 m: F = i·L/(1 + a|c||c − d|) (to ≤ 1e-9 here)
    f = volumetric_lightning(
        np.zeros(3, np.float32),
        np.array([1.0, 0, 0], np.float32),
        np.array([1e4, 0, 0], np.float32),
        1.0,
        np.float32(1e3),
    )
    assert float(f) == pytest.approx(1.0 / (1 + 1e3 * 1e4 * (1e4 - 1)), rel=1e-6)
    # a segment through the light: finite for the seed (i·2 atan(√a L/2)/√a), +∞ for inverse square
    f = volumetric_lightning((0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (1.0, 0.0, 0.0), 1.0, 4.0)
    assert f == pytest.approx(2 * math.atan(2.0) / 2.0, rel=1e-14)
    assert inverse_square_airlight((0.0, 0.0, 0.0), (2.0, 0.0, 0.0), (1.0, 0.0, 0.0)) == math.inf


def test_seed_printed_form_fails_near_axis_at_a100():
    """The issue's claim: D² = 4uw − v² ≤ 0 → NaN for some near-axial rays at a = 100 (printed form, float32),
    and large errors on others; the stable form stays within TOL32 on the same rays."""
    o, d, lpos, a = domain(300, 4, near_axial=1.0, a_values=(100.0,))
    truth = _oracle(o, d, lpos, a)
    m = METHODS["seed"]
    inputs = {n: v for n, v in zip(m.input_names, [*o.T, *d.T, *lpos.T], strict=True)}
    seed = np.asarray(m.evaluate(inputs, {"i": 1.0, "a": a}), dtype=np.float64)
    ok = truth > 0
    bad = ~np.isfinite(seed[ok])
    rel = np.where(np.isfinite(seed), _rel(seed, truth), np.inf)[ok]
    assert bad.sum() >= 20  # measured: 45 of 295 non-finite
    assert (
        np.sort(rel[np.isfinite(rel)])[-5:].min() > 1e-2
    )  # measured: 8 % of the finite ones > 1e-2, up to 0.95
    stable = volumetric_lightning(o, d, lpos, 1.0, a)
    assert _rel(stable, truth)[ok].max() <= TOL32


# ------------------------------------------------------------------------------------------- hypothesis
_coord = st.floats(-1e4, 1e4, allow_nan=False, width=32)


@settings(max_examples=200, deadline=None)
@given(
    o=st.tuples(_coord, _coord, _coord),
    d=st.tuples(_coord, _coord, _coord),
    lp=st.tuples(_coord, _coord, _coord),
    i=st.floats(0, 1e6, width=32),
    a=st.one_of(st.just(0.0), st.floats(0, 1e6, width=32)),
)
def test_finite_nonnegative_over_full_domain(o, d, lp, i, a):
    args = [np.asarray([x], np.float32) for x in (o, d, lp)]  # arrays, not literals: one compiled kernel
    f32 = volumetric_lightning(*args, np.asarray([i], np.float32), np.asarray([a], np.float32))
    f64 = volumetric_lightning(o, d, lp, i, a)
    assert np.all(np.isfinite(f32)) and np.all(f32 >= 0)
    assert math.isfinite(f64) and f64 >= 0
    # bounded by i·|d| (the attenuation never exceeds i)
    length = math.sqrt(sum(x * x for x in d))
    assert f64 <= i * length * (1 + 1e-12) + 1e-300


def test_bad_input_is_one_line_error():
    with pytest.raises(ValueError, match=r"a must be in"):
        volumetric_lightning((0, 0, 0), (1, 0, 0), (0, 1, 0), 1.0, -1.0)
    with pytest.raises(ValueError, match=r"intensity must be in"):
        volumetric_lightning((0, 0, 0), (1, 0, 0), (0, 1, 0), float("nan"), 1.0)
    with pytest.raises(ValueError, match=r"origin must be finite"):
        volumetric_lightning((0, float("inf"), 0), (1, 0, 0), (0, 1, 0), 1.0, 1.0)
    with pytest.raises(ValueError, match=r"segment must have shape"):
        volumetric_lightning((0, 0, 0), np.zeros((4, 2)), (0, 1, 0), 1.0, 1.0)


def test_three_libraries_run_one_text():
    """Dr.Jit, NumPy and JAX runs of ``stable`` agree (float64) on random inputs; the JAX gradient in (i, a)
    is finite (fits differentiate it)."""
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    o, d, lpos, a = domain(200, 5)
    a = np.maximum(a, 1e-3).astype(np.float64)
    m = METHODS["stable"]
    vals = [x.astype(np.float64) for x in (*o.T, *d.T, *lpos.T)]
    inputs = dict(zip(m.input_names, vals, strict=True))
    dr_out = m.evaluate(inputs, {"i": 2.0, "a": a})
    np_out = m(NUMPY_OPS, inputs, {"i": 2.0, "a": a})
    jx_inputs = {k: jnp.asarray(v) for k, v in inputs.items()}
    jx_out = np.asarray(m.evaluate(jx_inputs, {"i": 2.0, "a": jnp.asarray(a)}))
    assert _rel(np_out, dr_out).max() <= 1e-13
    assert _rel(jx_out, dr_out).max() <= 1e-13

    def total(p):
        return jnp.sum(m.evaluate(jx_inputs, {"i": p[0], "a": p[1]}))

    g = jax.grad(total)(jnp.asarray([2.0, 0.5]))
    assert np.all(np.isfinite(np.asarray(g)))


# ------------------------------------------------------------------------------- the experiment's pieces
def _ss_mpmath(c, u, length, sigma_s, sigma_t, intensity, power=1, rate=1.0):
    """σ_s/(4π)·∫₀^S I·e^(−σ_t(s + rate·r))/r^(2·power) ds along the unit direction u (mpmath, split at the
    closest approach and around it)."""
    with mp.workdps(30):
        c = [mp.mpf(float(x)) for x in c]
        u = [mp.mpf(float(x)) for x in u]

        def f(s):
            r2 = sum((ci - s * ui) ** 2 for ci, ui in zip(c, u, strict=True))
            return mp.exp(-sigma_t * (s + rate * mp.sqrt(r2))) / r2**power

        sp = sum(ci * ui for ci, ui in zip(c, u, strict=True))
        h = mp.sqrt(max(sum(ci * ci for ci in c) - sp * sp, 0))
        pts = sorted(
            {mp.mpf(0), mp.mpf(length)}
            | {sp + m * h for m in (-10, -1, 0, 1, 10) if 0 < sp + m * h < length}
            | {mp.mpf(2) ** k / 100 for k in range(24) if 0 < mp.mpf(2) ** k / 100 < length}  # thick media
        )
        return float(sigma_s / (4 * mp.pi) * intensity * mp.quad(f, pts))


@pytest.mark.parametrize("sigma_t", [0.0, 0.005, 0.05, 0.5])
def test_single_scattering_quadrature_matches_mpmath(sigma_t):
    """The experiment's reference oracle (composite Gauss–Legendre in u = asinh((s − c_∥)/h)) against
    mpmath, for rays passing the light at h/|c| from 1e-3 to 1 (tolerance 1e-12, measured ≤ 5.8e-15)."""
    rng = np.random.default_rng(9)
    light = np.array([0.8, 12.0, 0.3])
    dirs, lengths = [], []
    for h_rel in (1e-3, 1e-2, 0.1, 0.5, 1.0):
        axis = light / np.linalg.norm(light)
        perp = np.cross(axis, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        u = axis + h_rel * perp
        dirs.append(u / np.linalg.norm(u))
        lengths.append(rng.uniform(5, 40))
    dirs, lengths = np.array(dirs), np.array(lengths)
    got = point_single_scattering((0.0, 0.0, 0.0), dirs, lengths, light, 3.0, 0.02, sigma_t)
    want = np.array([_ss_mpmath(light, u, s, 0.02, sigma_t, 3.0) for u, s in zip(dirs, lengths, strict=True)])
    assert _rel(got, want).max() <= 1e-12
    if sigma_t > 0.0:  # the estimator's second moment (σ_s²/σ_t)·I²/(16π²)·∫ e^(−σ_t(s + 2r))/r⁴ ds
        var = point_estimator_variance((0.0, 0.0, 0.0), dirs, lengths, light, 3.0, 0.02, sigma_t)
        second = [
            _ss_mpmath(light, u, s, 0.02, sigma_t, 3.0, power=2, rate=2.0)
            * 0.02
            * 3.0
            / (4 * math.pi)
            / sigma_t
            for u, s in zip(dirs, lengths, strict=True)
        ]
        assert _rel(var, np.array(second) - want**2).max() <= 1e-9
    if sigma_t == 0.0:  # no extinction: the closed form K·|d|·θ/|c × d| (inverse_square_airlight)
        closed = inverse_square_airlight(
            np.zeros((5, 3)), dirs * lengths[:, None], light, 0.02 * 3.0 / (4 * math.pi)
        )
        assert _rel(got, closed).max() <= 1e-12


@pytest.mark.parametrize(
    "light, h_rel, sigma_t, length, tol",
    [
        ((0.8, 12.0, 0.3), 1e-5, 0.05, 30.0, 1e-12),  # near-axial: the edge of the ≤ 1e-12 domain
        ((0.8, 12.0, 0.3), 1e-6, 0.05, 30.0, 2e-11),  # beyond it: float64's conditioning of h
        ((0.8, -12.0, 0.3), None, 10.0, 1e4, 1e-10),  # optically thick (σ_t·S = 1e5), light behind
        ((0.8, -12.0, 0.3), None, 2.0, 1e3, 1e-12),
    ],
)
def test_single_scattering_quadrature_at_the_edges_of_its_domain(light, h_rel, sigma_t, length, tol):
    """Issue 32: docs/volumetric-lightning.md's bound held only where tested (h/|c| ≥ 1e-3, σ_t·S ≤ 20): a
    near-axial ray gave 2e-12, and σ_t = 10/m over 1e4 m with the light behind the camera 1.8e-4 (the whole
    decay fell inside one or two of the 48 panels; now the pieces break at s₀ + 2, 8, 32 /σ_t). Measured:
    5.9e-13, 8.2e-12, 2.2e-12 (2.6e-3 before the breaks), 1.8e-15 (2.3e-14 before)."""
    light = np.array(light)
    if h_rel is None:
        u = np.array([0.1, 1.0, 0.05])
    else:
        axis = light / np.linalg.norm(light)
        perp = np.cross(axis, np.array([0.3, -0.2, 0.9]))
        u = axis + h_rel * perp / np.linalg.norm(perp)
    u /= np.linalg.norm(u)
    got = point_single_scattering((0.0, 0.0, 0.0), u[None], np.array([length]), light, 3.0, 0.02, sigma_t)
    want = _ss_mpmath(light, u, length, 0.02, sigma_t, 3.0)
    assert abs(got[0] / want - 1) <= tol


def test_study_mpmath_closed_form_matches_the_quadrature(sample):
    """The study's mpmath truth (the closed form at 50 digits, `mpmath_value`) against `quad_integral` (no
    closed form) at 40 points of the domain, the first 20 of them generic and the last 20 near-axial at
    a = 100 and 1e3, and at the limits a = 0 and |d| = 0."""
    o, d, lpos, a, truth = sample
    for j in [*range(20), *range(len(a) - 20, len(a))]:
        got = study.mpmath_value(o[j], d[j], lpos[j], a[j])
        assert abs(got - truth[j]) <= 1e-13 * abs(truth[j]), (j, got, truth[j])
    assert study.mpmath_value((0, 0, 0), (3.0, 4.0, 0.0), (1.0, 2.0, 3.0), 0.0) == 5.0
    assert study.mpmath_value((0, 0, 0), (0.0, 0.0, 0.0), (1.0, 2.0, 3.0), 0.5) == 0.0


def _shipped_audit(tmp_path, name: str, width: int = 12, height: int = 8):
    shipped = {s.name: s for s in audit_volumetric_lightning.SCENES}[name]
    tag = (f"{shipped.name}-", f"{shipped.name}: ")
    return audit(LIBRARY_DIR / shipped.file, ["volumetric-lightning"], spp=256, width=width, height=height,
                 defines=shipped.defines, cache=tmp_path / "cache", tag=tag, metrics=("rmse",))  # fmt: skip


def test_run_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path):
    """``rtfit run volumetric-lightning`` = the engine's audits of the shipped scenes (one XML file, a point
    light in a homogeneous medium, with ``-D`` values per scene) + `volumetric_lightning_study.study`, on two
    of them (D = 4 m, σ_t = 0.01 and 0.05 /m; 12×8 pixels, 256 spp). Independent values: the light's
    position, intensity and σ_t as Mitsuba loaded them from the defines (D·(0.1, 1, 0.04), D², σ_t); the
    engine's z-checks of the quadrature row; the softening profile's inverse-square column against the
    textbook airlight K·(atan(s₁/h) − atan(s₀/h))/h per pixel; the float32 table's known failure of the
    printed form near the axis; every study check passes."""
    fam = FAMILIES["volumetric-lightning"]
    assert fam.module == ENGINE and fam.scenes == audit_volumetric_lightning.SCENES
    assert fam.study.target is study.study
    assert len(fam.scenes) == 12 and sum(s.quick for s in fam.scenes) == 4
    audits = tuple(_shipped_audit(tmp_path, n) for n in ("D4-s0p01", "D4-s0p05"))
    for r, sigma in zip(audits, (0.01, 0.05), strict=True):
        (case,) = r.cases
        p = case.parameters
        np.testing.assert_allclose(p["position_m"], [0.4, 4.0, 0.16], rtol=1e-6)
        np.testing.assert_allclose(p["intensity_W_per_sr"], [16.0] * 3, rtol=1e-6)
        np.testing.assert_allclose(p["sigma_t_per_m"], [sigma] * 3, rtol=1e-6)
        assert p["pixels"] == 12 * 8 and p["camera_inside_medium"]
        assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]
    ctx = StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", audits)
    res = study.study(ctx)
    assert all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    near = [t for t in res.extra["float32_accuracy"] if t["inputs"].startswith("near-axial rays, a = 100 ")]
    assert {t["form"]: t["non_finite"] > 0 for t in near} == {"stable": False, "seed": True}
    for r in audits:
        (case,) = r.cases
        soft = res.extra["softening"][case.id]
        g = case.channel_inputs[0]
        o = np.stack([g["ox"], g["oy"], g["oz"]], 1)
        d = np.stack([g["dx"], g["dy"], g["dz"]], 1)
        c = np.stack([g["lx"], g["ly"], g["lz"]], 1) - o
        length = np.linalg.norm(d, axis=1)
        u = d / length[:, None]
        along = np.sum(c * u, axis=1)
        h = np.linalg.norm(c - along[:, None] * u, axis=1)
        k = float(case.parameters["K_W_per_m_sr"])
        airlight = k * (np.arctan((length - along) / h) + np.arctan(along / h)) / h
        ref = case.reference.mean[case.mask][:, 0]
        bins = np.digitize(h / soft["distance_m"], study.SOFTENING_BINS) - 1
        prof = soft["profile"]
        for (lo, _hi), mean in zip(prof["h_over_D"], prof["inverse-square"], strict=True):
            sel = bins == int(np.searchsorted(study.SOFTENING_BINS, lo))
            assert mean == pytest.approx(float(np.mean(airlight[sel] / ref[sel] - 1)), rel=1e-4, abs=1e-6)
    dense, thin = (res.extra["softening"][r.cases[0].id]["fitted_K_over_true_K"] for r in audits[::-1])
    assert dense < thin < 1.05  # extinction dims the far field, more in the denser medium
    assert (tmp_path / "figures" / "error_vs_closest_approach.png").is_file()


def test_audit_list_names_the_family_on_the_shipped_scene():
    scene = LIBRARY_DIR / "volumetric_lightning_point.xml"
    out = CliRunner().invoke(audit_cmd, [str(scene), "--list", "-D", "sigma_t=0.002"])
    assert out.exit_code == 0, out.output
    line = next(x for x in out.output.splitlines() if x.strip().startswith("volumetric-lightning"))
    assert "point light 'lamp'" in line and "inside the homogeneous medium" in line
