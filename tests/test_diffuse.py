"""Tests of rtfit.realtime.diffuse against independent values only.

References used here (none of them is the code's own output):
* mpmath quadrature of E/L = ∫_cap max(n·ω, 0) dω over the light's cap in its own polar coordinates
  (t ∈ [0, α] from the cap axis, φ the azimuth). The azimuthal integral of max(A − B cos φ, 0) is elementary
  (checked below against mpmath quadrature over φ); the polar integral is mpmath.quad split at the kinks
  t = |π/2 − θ|.
* closed values derived by hand (hemisphere light, fully-above cap, half-Lambert / wrap numbers).

Accuracy bounds asserted (error measured relative to the light's peak irradiance E⊥ = π sin²α L, the natural
scale: near the lower horizon boundary E → 0 and any rounding of cos θ is amplified without bound in E's
relative error). Measured maxima over 6000 (θ, α) points, α log-uniform in [1e-4, π/2], 70 % in the horizon
region: float64 9.4e-16·E⊥; Dr.Jit-LLVM float32 6.3e-7·E⊥ (its float32 atan/atan2 are ≤ 12 ulp);
NumPy float32 2.1e-7·E⊥; Dr.Jit-CUDA float32 7.3e-7·E⊥ (H100, 2²⁰ points; run by hand on the lent GPU).
"""

from __future__ import annotations

import dataclasses
import math

import drjit as dr
import mpmath as mp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import DRJIT_OPS, NUMPY_OPS, get_default_backend, set_default_backend
from rtfit.realtime import diffuse as d

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")  # kernels must not warn (0/0, overflow)

TOL64 = 1e-14  # |E − E_quad| / E⊥ in float64 (≈ 45 ulp; measured ≤ 9.4e-16)
TOL32 = 2e-6  # |E − E_quad| / E⊥ in float32 (≈ 17 ulp; measured ≤ 6.3e-7)
TINY32 = 1e-36  # absolute floor for float32 (sin²α underflows below α ≈ 1e-19)
HALF_PI = math.pi / 2
Float, Float64 = dr.llvm.Float, dr.llvm.Float64


# --------------------------------------------------------------------------------- independent reference
def _azimuthal(t, th):
    """∫_0^{2π} max(cos t cos θ − sin t sin θ cos φ, 0) dφ, elementary."""
    a = mp.cos(t) * mp.cos(th)
    b = mp.sin(t) * mp.sin(th)
    if a >= b:
        return 2 * mp.pi * a
    if a <= -b:
        return mp.mpf(0)
    p0 = mp.acos(a / b)
    return 2 * ((mp.pi - p0) * a + b * mp.sin(p0))


def cap_quadrature(theta: float, alpha: float) -> float:
    """E/L = ∫_cap max(n·ω, 0) dω for a cap of half-angle α whose axis is at angle θ from n (mpmath)."""
    with mp.workdps(30):
        th, al = mp.mpf(theta), mp.mpf(alpha)
        pts = sorted({mp.mpf(0), al} | {b for b in (mp.pi / 2 - th, th - mp.pi / 2) if 0 < b < al})
        return float(mp.quad(lambda t: _azimuthal(t, th) * mp.sin(t), pts))


def test_azimuthal_integral_is_right():
    """The elementary inner integral against plain quadrature over φ (split at the kinks)."""
    with mp.workdps(30):
        for t, th in [(0.3, 1.5), (0.9, 2.0), (0.2, 0.4), (1.2, 2.9), (0.05, math.pi / 2)]:
            t, th = mp.mpf(t), mp.mpf(th)
            a, b = mp.cos(t) * mp.cos(th), mp.sin(t) * mp.sin(th)

            def f(p, a=a, b=b):
                return max(a - b * mp.cos(p), 0)

            ratio = a / b
            pts = [0, 2 * mp.pi]
            if -1 < ratio < 1:
                p0 = mp.acos(ratio)
                pts = [0, p0, 2 * mp.pi - p0, 2 * mp.pi]
            assert abs(mp.quad(f, pts) - _azimuthal(t, th)) < mp.mpf(10) ** -25


def test_quadrature_reference_known_values():
    """Sanity of the reference itself: fully-above cap and hemisphere light."""
    assert cap_quadrature(0.3, 0.2) == pytest.approx(math.pi * math.sin(0.2) ** 2 * math.cos(0.3), rel=1e-14)
    assert cap_quadrature(1.0, HALF_PI) == pytest.approx(math.pi * (1 + math.cos(1.0)) / 2, rel=1e-14)


def _cases():
    """(θ, α) pairs: random over the domain, random in the horizon region, and the region's boundaries."""
    rng = np.random.default_rng(20240601)
    al = np.concatenate([np.exp(rng.uniform(np.log(1e-3), np.log(HALF_PI), 14)), rng.uniform(0, HALF_PI, 8)])
    pairs = []
    for k, a in enumerate(al):
        if k % 3 == 0:
            th = rng.uniform(0, math.pi)
        else:  # horizon region |cos θ| < sin α
            th = rng.uniform(HALF_PI - a, HALF_PI + a)
        pairs.append((th, a))
    for a in (math.radians(0.27), 0.01, 0.3, 1.0, 1.5):  # boundaries θ = π/2 ± α, and θ = π/2
        pairs += [
            (HALF_PI - a, a),
            (HALF_PI + a, a),
            (HALF_PI, a),
            (HALF_PI - a / 2, a),
            (HALF_PI + 0.999 * a, a),
        ]
    pairs += [(0.0, 1.2), (math.pi, 1.2), (0.7, HALF_PI), (2.5, HALF_PI)]
    return pairs


CASES = _cases()
QUAD = {(th, a): cap_quadrature(th, a) for th, a in CASES}


def test_closed_form_matches_quadrature_float64():
    th = np.array([c[0] for c in CASES])
    al = np.array([c[1] for c in CASES])
    cos = np.cos(th)
    ref = np.array([QUAD[c] for c in CASES])
    peak = math.pi * np.sin(al) ** 2
    for L in (1.0, 3.5):
        for name, e in [
            ("numpy input (Dr.Jit Float64)", d.sphere_light_irradiance(cos, al, L)),
            ("Dr.Jit Float64", np.asarray(d.sphere_light_irradiance(Float64(cos), Float64(al), L))),
            ("NumPy kernel", d.METHODS["exact"](NUMPY_OPS, {"cos_theta": cos, "alpha": al, "radiance": L})),
            (
                "python floats",
                np.array(
                    [d.sphere_light_irradiance(float(c), float(a), L) for c, a in zip(cos, al, strict=True)]
                ),
            ),
        ]:
            err = np.abs(np.asarray(e) - L * ref) / (L * peak)
            assert err.max() <= TOL64, (name, err.max(), CASES[int(err.argmax())])


def test_closed_form_matches_quadrature_float32():
    c32 = np.cos([c[0] for c in CASES]).astype(np.float32)
    a32 = np.minimum(np.array([c[1] for c in CASES], np.float32), np.float32(HALF_PI))
    # reference at the float32 inputs exactly (θ = acos of the float32 cosine)
    ref = np.array(
        [cap_quadrature(math.acos(float(c)), min(float(a), HALF_PI)) for c, a in zip(c32, a32, strict=True)]
    )
    peak = math.pi * np.sin(np.minimum(a32.astype(np.float64), HALF_PI)) ** 2
    for name, e in [
        ("numpy float32 input", d.sphere_light_irradiance(c32, a32)),
        ("Dr.Jit Float", d.sphere_light_irradiance(Float(c32), Float(a32))),
    ]:
        e = np.asarray(e, dtype=np.float64)
        err = np.abs(e - ref) / peak
        assert err.max() <= TOL32, (name, err.max())


@pytest.mark.parametrize("alpha_deg", [0.27, 0.01, 2.0])
def test_tiny_light_float32_horizon_band(alpha_deg):
    """Small lights in float32: inside the horizon band |cos θ| < sin α, E is of order π sin³α (not E⊥), and
    the stable form keeps the error ≤ 1e-6·π sin³α (measured 2.2e-7; the textbook form in float32 gives
    2.6e-3 at α = 0.27°) and ≤ 3e-6 relative wherever E ≥ 1 % of π sin³α (measured 1.1e-6)."""
    a = np.float32(math.radians(alpha_deg))
    s = math.sin(float(a))
    c = (np.linspace(-1.05, 1.05, 43) * s).astype(np.float32)
    ref = np.array([cap_quadrature(math.acos(float(x)), float(a)) for x in c])
    e = np.asarray(d.sphere_light_irradiance(Float(c), Float(a)), np.float64)
    band = math.pi * s**3
    assert np.max(np.abs(e - ref)) <= 1e-6 * band
    m = ref >= 0.01 * band
    assert m.sum() > 15
    assert np.max(np.abs(e - ref)[m] / ref[m]) <= 3e-6


# --------------------------------------------------------------------------------- closed special cases
def test_hemisphere_light_is_wrap_1_1():
    c = np.linspace(-1, 1, 101)
    expect = math.pi * (1 + c) / 2
    np.testing.assert_allclose(d.sphere_light_irradiance(c, HALF_PI), expect, rtol=0, atol=4e-16 * math.pi)
    np.testing.assert_allclose(d.wrap(c, 1.0, 1.0, math.pi), expect, rtol=0, atol=4e-16 * math.pi)
    e32 = np.asarray(d.sphere_light_irradiance(Float(c.astype(np.float32)), Float(np.float32(HALF_PI))))
    np.testing.assert_allclose(e32, math.pi * (1 + c.astype(np.float32).astype(np.float64)) / 2, atol=1e-6)
    assert d.sphere_light_irradiance(1.0, HALF_PI) == pytest.approx(math.pi, rel=1e-15)
    assert d.sphere_light_irradiance(-1.0, HALF_PI) == 0.0


def test_fully_above_and_below():
    for a in (1e-6, 0.01, 0.3, 1.0, 1.5):
        s = math.sin(a)
        c = np.linspace(s, 1, 23)
        np.testing.assert_allclose(
            d.sphere_light_irradiance(c, a, 2.0), 2.0 * math.pi * s * s * c, rtol=1e-15
        )
        below = np.linspace(-1, -s, 23)
        assert np.all(d.sphere_light_irradiance(below, a, 2.0) == 0.0)
        assert np.all(np.asarray(d.sphere_light_irradiance(Float(below.astype(np.float32)), a)) == 0.0)


def test_small_alpha_limit():
    c = np.linspace(-1, 1, 201)
    for a in (1e-2, 1e-4, 1e-6, 1e-9):
        ratio = d.sphere_light_irradiance(c, a) / (math.pi * math.sin(a) ** 2)
        # only the horizon band |c| < sin α differs from Lambert, by less than sin α there
        assert np.max(np.abs(ratio - np.maximum(c, 0))) <= math.sin(a)
    for x in (-1.0, -1e-300, 0.0, 1e-300, 0.5, 1.0):
        assert d.sphere_light_irradiance(x, 0.0) == 0.0
    assert np.all(d.sphere_light_irradiance(c, 0.0) == 0.0)
    assert np.all(np.asarray(d.sphere_light_irradiance(Float(c.astype(np.float32)), Float(0.0))) == 0.0)
    # at cos θ = 0 the exact value is 2α³/3 + O(α⁵) for small α (half the cap, projected)
    a = 1e-3
    assert d.sphere_light_irradiance(0.0, a) == pytest.approx(2 * a**3 / 3, rel=1e-5)


def test_half_lambert_and_wrap_by_hand():
    assert d.half_lambert(1.0) == 1.0
    assert d.half_lambert(0.0) == 0.25
    assert d.half_lambert(-1.0) == 0.0
    assert d.half_lambert(0.5, 2.0) == 2.0 * 0.5625
    assert d.half_lambert(-0.5) == 0.0625
    assert d.lambert(0.3, 2.0) == pytest.approx(0.6, rel=1e-15)
    assert d.lambert(-0.3, 2.0) == 0.0
    assert d.wrap(0.0, 0.5, 1.5) == pytest.approx((1 / 3) ** 1.5, rel=1e-15)
    assert d.wrap(0.2, 0.25, 2.0, 3.0) == pytest.approx(3.0 * (0.45 / 1.25) ** 2, rel=1e-15)
    assert d.wrap(-0.5, 0.5, 2.0) == 0.0
    assert d.wrap(-0.6, 0.5, 0.3) == 0.0
    assert d.wrap(1.0, 0.7, 8.0, 4.0) == 4.0
    peak = 2 * math.pi * math.sin(0.5) ** 2
    assert d.sphere_light_peak_irradiance(0.5, 2.0) == pytest.approx(peak, rel=1e-15)
    assert d.ambient_term(0.2) == pytest.approx(0.2 * math.pi, rel=1e-15)


@pytest.mark.parametrize("kind", ["float", "numpy64", "numpy32", "drjit32"])
def test_wrap_special_cases_are_lambert_and_half_lambert(kind):
    c = np.linspace(-1, 1, 65)
    conv = {
        "float": lambda x: x,
        "numpy64": lambda x: x,
        "numpy32": lambda x: x.astype(np.float32),
        "drjit32": lambda x: Float(x.astype(np.float32)),
    }[kind]
    if kind == "float":
        pairs = [
            (np.array([d.wrap(float(x), 0.0, 1.0) for x in c]), np.array([d.lambert(float(x)) for x in c])),
            (
                np.array([d.wrap(float(x), 1.0, 2.0) for x in c]),
                np.array([d.half_lambert(float(x)) for x in c]),
            ),
        ]
    else:
        x = conv(c)
        pairs = [(d.wrap(x, 0.0, 1.0), d.lambert(x)), (d.wrap(x, 1.0, 2.0), d.half_lambert(x))]
    for got, expect in pairs:
        np.testing.assert_array_equal(np.asarray(got), np.asarray(expect))


# --------------------------------------------------------------------------------- properties (hypothesis)
# Subnormals excluded: Dr.Jit flushes denormal inputs to zero (documented in rtfit.realtime.diffuse).
unit = st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)
alphas = st.floats(0.0, HALF_PI, allow_nan=False, allow_subnormal=False)
radiances = st.floats(0.0, 100.0, allow_subnormal=False)
batch = st.lists(st.tuples(unit, alphas, radiances), min_size=2, max_size=48)


@settings(max_examples=60, deadline=None)
@given(batch)
def test_exact_properties(rows):
    c, a, L = (np.array(v, dtype=np.float64) for v in zip(*rows, strict=True))
    e = d.sphere_light_irradiance(c, a, L)
    peak = d.sphere_light_peak_irradiance(a, L)
    assert np.all(np.isfinite(e))
    assert np.all(e >= 0.0)
    assert np.all(e <= peak * (1 + 1e-15))
    # float32 Dr.Jit vs float64 NumPy of the same kernel at the same (float32-rounded) inputs
    c32, a32, L32 = c.astype(np.float32), a.astype(np.float32), L.astype(np.float32)
    e32 = np.asarray(d.sphere_light_irradiance(Float(c32), Float(a32), Float(L32)), np.float64)
    e64 = d.METHODS["exact"](
        NUMPY_OPS,
        {
            "cos_theta": c32.astype(np.float64),
            "alpha": a32.astype(np.float64),
            "radiance": L32.astype(np.float64),
        },
    )
    p64 = L32 * math.pi * np.sin(np.minimum(a32.astype(np.float64), HALF_PI)) ** 2
    assert np.all(np.abs(e32 - e64) <= TOL32 * p64 + TINY32)


@settings(max_examples=40, deadline=None)
@given(alphas, st.lists(unit, min_size=2, max_size=64))
def test_exact_monotone_in_cos(alpha, cs):
    c = np.sort(np.array(cs))
    a = np.full_like(c, alpha)  # an array: one compiled kernel for all examples
    peak = math.pi * math.sin(alpha) ** 2
    e = d.sphere_light_irradiance(c, a)
    assert np.all(np.diff(e) >= -TOL64 * peak)
    e32 = np.asarray(
        d.sphere_light_irradiance(Float(c.astype(np.float32)), dr.opaque(Float, alpha)), np.float64
    )
    assert np.all(np.diff(e32) >= -2 * TOL32 * peak - TINY32)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(unit, min_size=2, max_size=48),
    st.floats(0.0, 1.0, allow_subnormal=False),
    st.floats(0.25, 8.0),
    st.floats(0.0, 50.0, allow_subnormal=False),
)
def test_wrap_properties(cs, w, p, irr):
    c = np.sort(np.array(cs))
    # parameters as arrays (broadcast), so the examples share one kernel
    e = d.wrap(c, np.array([w]), np.array([p]), np.array([irr]))
    assert np.all(np.isfinite(e)) and np.all(e >= 0.0) and np.all(e <= irr * (1 + 1e-15))
    assert np.all(np.diff(e) >= -1e-15 * irr)
    ref = irr * np.maximum((c + w) / (1 + w), 0.0) ** p
    np.testing.assert_allclose(e, ref, rtol=1e-13, atol=1e-300)
    e32 = np.asarray(
        d.wrap(Float(c.astype(np.float32)), dr.opaque(Float, w), dr.opaque(Float, p), dr.opaque(Float, irr)),
        np.float64,
    )
    assert np.all(e32 >= 0.0) and np.all(e32 <= np.float32(irr) * (1 + 1e-6))
    # float32 pow via exp2/log2: error grows like p·|log x|·eps; 1e-5·irr absolute is ample
    assert np.all(np.abs(e32 - ref) <= 1e-5 * irr + 1e-30)


@settings(max_examples=30, deadline=None)
@given(st.lists(unit, min_size=2, max_size=48), st.floats(0.0, 20.0, allow_subnormal=False))
def test_half_lambert_and_lambert_range(cs, irr):
    c = np.array(cs)
    h = d.half_lambert(c, irr)
    lam = d.lambert(c, irr)
    assert np.all((h >= 0) & (h <= irr)) and np.all((lam >= 0) & (lam <= irr))
    assert np.all(h >= lam - 1e-15 * irr) or irr == 0  # (½c+½)² ≥ max(c, 0) on [−1, 1]


def test_opaque_scalars_reuse_one_kernel():
    """Hypothesis-style per-example scalars wrapped in dr.opaque do not compile a new kernel each time."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for k in range(2):  # warm-up (may compile)
            dr.eval(d.sphere_light_irradiance(dr.opaque(Float, 0.1 * k), dr.opaque(Float, 0.2), 1.0))
        dr.kernel_history_clear()
        for k in range(8):
            c, a = dr.opaque(Float, 0.05 * k - 0.2), dr.opaque(Float, 0.1 + 0.01 * k)
            dr.eval(d.sphere_light_irradiance(c, a, 1.0))
        hist = [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
        assert len(hist) == 8 and all(h.get("cache_hit") for h in hist)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# --------------------------------------------------------------------------------- validation
BAD = [
    (lambda: d.sphere_light_irradiance(0.1, 2.0), "alpha must be in [0, pi/2] (got 2.0)"),
    (lambda: d.sphere_light_irradiance(0.1, -0.1), "alpha must be in [0, pi/2]"),
    (lambda: d.sphere_light_irradiance(0.1, float("nan")), "alpha must be in [0, pi/2] (got nan)"),
    (lambda: d.sphere_light_irradiance(np.zeros(4), np.array([0.1, 0.2, np.nan, 0.3])), "alpha must be in"),
    (
        lambda: d.sphere_light_irradiance(np.zeros(2), np.array([0.1, 1.6])),
        "alpha must be in [0, pi/2] (got 1.6)",
    ),
    (lambda: d.sphere_light_irradiance(0.1, 0.2, -1.0), "radiance must be in [0, inf)"),
    (lambda: d.sphere_light_irradiance(0.1, 0.2, float("inf")), "radiance must be in [0, inf)"),
    (lambda: d.wrap(0.1, -0.1, 1.0), "w must be in [0, 1] (got -0.1)"),
    (lambda: d.wrap(0.1, 1.5, 1.0), "w must be in [0, 1]"),
    (lambda: d.wrap(0.1, float("nan"), 1.0), "w must be in [0, 1] (got nan)"),
    (lambda: d.wrap(0.1, 0.5, 0.0), "p must be in (0, 8] (got 0.0)"),
    (lambda: d.wrap(0.1, 0.5, -1.0), "p must be in (0, 8]"),
    (lambda: d.wrap(0.1, 0.5, 9.0), "p must be in (0, 8]"),
    (lambda: d.wrap(0.1, 0.5, np.float32("nan")), "p must be in (0, 8] (got nan)"),
    (lambda: d.lambert(float("nan")), "cos_theta must be in [-1, 1] (got nan)"),
    (lambda: d.half_lambert(1.5), "cos_theta must be in [-1, 1] (got 1.5)"),
    (lambda: d.lambert(np.array([0.0, -2.0])), "cos_theta must be in [-1, 1] (got -2.0)"),
    (lambda: d.lambert(0.5, -2.0), "irradiance must be in [0, inf)"),
    (
        lambda: d.sphere_light_geometry((0, 0, 0), (0, 0, 1), (0, 0, 5), -1.0),
        "light_radius must be in [0, inf)",
    ),
    (
        lambda: d.sphere_light_geometry((0, 0, 0), (0, 0, 1), (0, float("nan"), 5), 1.0),
        "light_center must be",
    ),
    (
        lambda: d.sphere_light_geometry(np.zeros((4, 2)), np.zeros((4, 3)), (0, 0, 5), 1.0),
        "position must have shape",
    ),
    (lambda: set_default_backend("metal"), "backend must be one of"),
    (lambda: d.METHODS["wrap"](NUMPY_OPS, {"irradiance": 1.0}), "needs input(s) cos_theta"),
    (lambda: d.METHODS["wrap"].keywords({"q": 1.0}), "has no parameter q"),
]


@pytest.mark.parametrize("call,msg", BAD, ids=[m for _, m in BAD])
def test_bad_parameters_raise_one_line(call, msg):
    with pytest.raises(ValueError) as info:
        call()
    text = str(info.value)
    assert msg in text and "\n" not in text


def test_rounding_tolerance_and_nan_propagation():
    assert d.lambert(1.00001) == 1.0  # dot products a hair above 1 are clamped, not rejected
    # float32(π/2) > π/2 is accepted (it is π/2 rounded) and clamped
    assert d.sphere_light_irradiance(np.float32(0.5), np.float32(HALF_PI)) == pytest.approx(0.75 * math.pi)
    e = d.sphere_light_irradiance(np.array([np.nan, 0.5]), 0.3)
    assert np.isnan(e[0]) and e[1] == pytest.approx(cap_quadrature(math.acos(0.5), 0.3), rel=1e-14)
    # Dr.Jit inputs are not validated but clamped into the domain (documented)
    out = np.asarray(d.sphere_light_irradiance(Float([0.5, 0.5, 1.5]), Float([-1.0, 3.0, 0.2])))
    np.testing.assert_allclose(out, [0.0, math.pi * 0.75, math.pi * math.sin(0.2) ** 2], rtol=1e-6)
    out = np.asarray(d.wrap(Float([0.0, 0.0]), Float([-1.0, 2.0]), Float([1.0, 1.0])))
    np.testing.assert_allclose(out, [0.0, 0.5], rtol=1e-6)


# --------------------------------------------------------------------------------- input/output types
FUNCS = [
    ("lambert", lambda c, a: d.lambert(c, 2.0)),
    ("half_lambert", lambda c, a: d.half_lambert(c)),
    ("wrap", lambda c, a: d.wrap(c, 0.5, 1.5)),
    ("exact", lambda c, a: d.sphere_light_irradiance(c, a, 1.5)),
    ("peak", lambda c, a: d.sphere_light_peak_irradiance(a, 1.5)),
]


@pytest.mark.parametrize("name,f", FUNCS, ids=[n for n, _ in FUNCS])
def test_types_in_out(name, f):
    r = f(0.3, 0.2)
    assert type(r) is float
    r = f(np.float32(0.3), np.float64(0.2))  # NumPy scalars behave like Python floats
    assert type(r) is float
    c = np.linspace(-1, 1, 12).reshape(3, 4)
    a = np.full((3, 4), 0.2)
    for dt in (np.float64, np.float32):
        r = f(c.astype(dt), a.astype(dt))
        assert isinstance(r, np.ndarray) and r.shape == (3, 4) and r.dtype == dt
    for T in (dr.llvm.Float, dr.llvm.Float64, dr.llvm.ad.Float):
        r = f(T(c.ravel()), T(a.ravel()))
        assert type(r) is T and dr.width(r) == 12
        np.testing.assert_allclose(np.asarray(r), f(c, a).ravel(), rtol=3e-6, atol=1e-6)


def test_drjit_cuda_if_available():
    """On CUDA, float32 dr.sin/dr.cos are approximate (MUFU unit, ~1e-6 absolute): the kernels avoid them, so
    the float32 bound holds there too, including tiny α (measured on an H100: see docs/diffuse.md)."""
    if not dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("no CUDA device")
    rng = np.random.default_rng(5)
    al = np.exp(rng.uniform(np.log(1e-4), np.log(HALF_PI), 4096)).astype(np.float32)
    c = (rng.uniform(-1.2, 1.2, 4096) * np.sin(al)).clip(-1, 1).astype(np.float32)
    r = d.sphere_light_irradiance(dr.cuda.Float(c), dr.cuda.Float(al), 1.0)
    assert type(r) is dr.cuda.Float
    ref = d.METHODS["exact"](
        NUMPY_OPS, {"cos_theta": c.astype(np.float64), "alpha": al.astype(np.float64), "radiance": 1.0}
    )
    peak = math.pi * np.sin(al.astype(np.float64)) ** 2
    assert np.all(np.abs(np.asarray(r, np.float64) - ref) <= TOL32 * peak + TINY32)
    p = np.asarray(d.sphere_light_peak_irradiance(dr.cuda.Float(al), 1.0), np.float64)
    np.testing.assert_allclose(p, peak, rtol=2e-6)


def test_sincos_polynomial():
    """The kernels' own sin/cos on [0, π/2] (used instead of the backend's): relative accuracy of sin even
    for tiny angles, absolute accuracy of cos, in float64 (NumPy) and float32 (Dr.Jit)."""
    from rtfit.realtime.arrays import sincos_first_quadrant

    a = np.concatenate(
        [np.exp(np.linspace(np.log(1e-30), np.log(HALF_PI), 2000)), np.linspace(1e-9, HALF_PI, 2000)]
    )
    s, c = sincos_first_quadrant(NUMPY_OPS, a)
    assert np.max(np.abs(s - np.sin(a)) / np.sin(a)) <= 4e-16
    assert np.max(np.abs(c - np.cos(a))) <= 4e-16
    a32 = a.astype(np.float32)
    s32, c32 = sincos_first_quadrant(DRJIT_OPS, Float(a32))
    a64 = a32.astype(np.float64)
    assert np.max(np.abs(np.asarray(s32, np.float64) - np.sin(a64)) / np.sin(a64)) <= 2.5e-7
    assert np.max(np.abs(np.asarray(c32, np.float64) - np.cos(a64))) <= 2e-7


def test_default_backend_and_numpy_run_of_the_methods():
    assert get_default_backend() == "llvm"
    set_default_backend("llvm")
    c = np.linspace(-1, 1, 9)
    out = d.METHODS["wrap"](NUMPY_OPS, {"cos_theta": c, "irradiance": 1.0}, {"w": 0.5, "p": 1.5})
    assert isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, np.maximum((c + 0.5) / 1.5, 0) ** 1.5, rtol=1e-15)
    assert float(d.METHODS["half-lambert"](NUMPY_OPS, {"cos_theta": 0.0, "irradiance": 1.0})) == 0.25
    assert set(vars(DRJIT_OPS)) == set(vars(NUMPY_OPS))


def test_sphere_light_geometry():
    # independent: explicit vectors
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(50, 3))
    nrm = rng.normal(size=(50, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    center, radius = np.array([0.5, -2.0, 7.0]), 1.3
    v = center - pos
    dist = np.linalg.norm(v, axis=1)
    cos_ref = np.sum(nrm * v, axis=1) / dist
    alpha_ref = np.arcsin(np.minimum(radius / dist, 1.0))
    cos_t, alpha = d.sphere_light_geometry(pos, nrm, center, radius)
    np.testing.assert_allclose(cos_t, cos_ref, rtol=0, atol=1e-14)
    np.testing.assert_allclose(alpha, alpha_ref, rtol=1e-13)
    # Dr.Jit Array3f in → Float out
    cos32, alpha32 = d.sphere_light_geometry(
        dr.llvm.Array3f(pos.T.astype(np.float32)),
        dr.llvm.Array3f(nrm.T.astype(np.float32)),
        tuple(center),
        radius,
    )
    assert type(cos32) is Float and type(alpha32) is Float
    np.testing.assert_allclose(np.asarray(cos32), cos_ref, atol=2e-6)
    np.testing.assert_allclose(np.asarray(alpha32), alpha_ref, atol=2e-6)
    # single point (sequences) → floats; hand values
    c1, a1 = d.sphere_light_geometry((0, 0, 0), (0, 0, 1), (0, 0, 10), 1.0)
    assert type(c1) is float and c1 == 1.0 and a1 == pytest.approx(math.asin(0.1), rel=1e-15)
    c2, _ = d.sphere_light_geometry((0, 0, 0), (2, 0, 0), (0, 0, 10), 1.0)  # normal not unit: normalised
    assert c2 == 0.0
    _, a3 = d.sphere_light_geometry((0, 0, 9.5), (0, 0, 1), (0, 0, 10), 1.0)  # inside the light
    assert a3 == HALF_PI
    c4, _ = d.sphere_light_geometry((0, 0, 0), (0, 0, 0), (0, 0, 10), 1.0)  # zero normal (background)
    assert c4 == 0.0
    # NumPy (H, W, 3) keeps its leading shape
    ct, at = d.sphere_light_geometry(pos.reshape(5, 10, 3), nrm.reshape(5, 10, 3), center, radius)
    assert ct.shape == (5, 10) and at.shape == (5, 10)


def test_method_table():
    from rtfit.realtime.light_models import METHODS as LIGHT_MODELS  # (tests/test_light_models.py)

    assert set(d.METHODS) == {"lambert", "half-lambert", "wrap", "exact", *LIGHT_MODELS}
    formulas = [m for k, m in d.METHODS.items() if k not in LIGHT_MODELS]
    w = d.METHODS["wrap"]
    assert w.defaults() == {"w": 0.5, "p": 1.5}
    assert w.bounds() == {"w": (0.0, 1.0), "p": (0.25, 8.0)}
    assert [m.id for m in d.METHODS.values() if m.exact] == ["exact"]
    units = {i.name: i.unit for m in formulas for i in m.inputs}
    assert units == {"cos_theta": "1", "irradiance": "W/m²", "alpha": "rad", "radiance": "W/m²/sr"}
    assert all(p.unit == "1" for p in w.params.values())
    for m in d.METHODS.values():
        assert m.label and m.description and "\n" not in m.description and m.formula
        with pytest.raises(dataclasses.FrozenInstanceError):
            m.label = "x"
    assert w.evaluate({"cos_theta": 0.2, "irradiance": 1.0}) == pytest.approx((0.7 / 1.5) ** 1.5, rel=1e-15)
    # Each method's dispatch equals its public function (same kernel text, the function adds validation).
    c = np.linspace(-1, 1, 13)
    for mid, fn in (("lambert", d.lambert), ("half-lambert", d.half_lambert)):
        np.testing.assert_array_equal(
            d.METHODS[mid].evaluate({"cos_theta": c, "irradiance": 2.0}), fn(c, 2.0)
        )
    np.testing.assert_array_equal(
        d.METHODS["exact"].evaluate({"cos_theta": c, "alpha": 0.3, "radiance": 1.5}),
        d.sphere_light_irradiance(c, 0.3, 1.5),
    )
    np.testing.assert_array_equal(w.evaluate({"cos_theta": c, "irradiance": 1.0}), d.wrap(c, 0.5, 1.5))


# --------------------------------------------------------------------- rtfit run diffuse: engine + study
def test_run_diffuse_is_the_engine_on_its_shipped_suns_plus_the_study(tmp_path):
    """``rtfit run diffuse`` = the engine's audits of the shipped scenes + `diffuse_study.study`, on two of
    them (α = 5°, 30°, 12² pixels) as the engine hands them over. Independent values: each file's α (its
    TOML), half-Lambert's error against the mpmath cap quadrature on the same pixels (its error ≫ the
    reference noise, so the Mitsuba reference must give it within that noise), and the smooth law, which
    with two α has exactly as many coefficients as targets: the 2 × 2 linear solves of the per-α fits."""
    import tomllib

    from rtfit.experiments import audit_diffuse, diffuse_study
    from rtfit.experiments.audit_run import audit
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes.parse import LIBRARY_DIR

    fam = FAMILIES["diffuse"]
    assert fam.module == ENGINE and fam.scenes == audit_diffuse.SCENES
    assert fam.study.target is diffuse_study.study
    shipped = {s.name: s for s in audit_diffuse.SCENES}
    declared = {
        n: tomllib.loads((LIBRARY_DIR / s.file).read_text())["lights"][0]["angular_radius_deg"]
        for n, s in shipped.items()
    }
    assert sorted(declared.values()) == [0.27, 1, 2, 5, 10, 15, 20, 30]
    audits = tuple(
        audit(
            LIBRARY_DIR / shipped[n].file,
            ["diffuse"],
            spp=64,
            width=12,
            height=12,
            cache=tmp_path / "cache",
            tag=(f"{n}-", f"{n}: "),
            metrics=("rmse",),
        )
        for n in ("diffuse_sphere_a5", "diffuse_sphere_a30")
    )
    ctx = StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", audits)
    cases = diffuse_study.alpha_cases(audits)
    assert [c.alpha_deg for c in cases] == pytest.approx([5.0, 30.0], rel=1e-12)
    res = diffuse_study.study(ctx)
    table = {round(t["alpha_deg"]): t for t in res.extra["per_alpha"]}
    for ac in cases:
        c = ac.case
        cos = np.asarray(c.channel_inputs[0]["cos_theta"], np.float64)
        a = math.radians(ac.alpha_deg)
        exact = np.array([cap_quadrature(math.acos(x), a) for x in cos]) / math.sin(a) ** 2 / math.pi
        hl = (0.5 * cos + 0.5) ** 2
        rmse_quad = float(np.sqrt(np.mean((hl - exact) ** 2)))  # E/E⊥, one value per pixel (grey light)
        t = table[round(ac.alpha_deg)]
        assert t["rmse"]["half-lambert"] == pytest.approx(rmse_quad, abs=3 * t["floor"] + 1e-3)
        assert ac.e_perp == pytest.approx(math.pi, rel=2e-3)  # the reference's own E⊥: the file's π
    # two α, four coefficients: w(α) = w1 s + w2 s², p(α) − 1 = p1 s + p2 s² through both fits exactly
    s = np.sin(np.radians([5.0, 30.0]))
    m = np.stack([s, s**2], axis=1)
    w = np.linalg.solve(m, [table[5]["wp"]["w"]["value"], table[30]["wp"]["w"]["value"]])
    p = np.linalg.solve(m, [table[5]["wp"]["p"]["value"] - 1, table[30]["wp"]["p"]["value"] - 1])
    law = res.extra["smooth_law"]
    np.testing.assert_allclose([law["w1"], law["w2"], law["p1"], law["p2"]], [*w, *p], rtol=1e-4, atol=1e-6)
    assert all(ch.passed for ch in res.checks), res.checks
    assert {f.file for f in res.figures} == {
        "figures/error_vs_alpha.png", "figures/terminator.png", "figures/wrap_parameters.png"
    }  # fmt: skip
    assert all((tmp_path / f.file).is_file() for f in res.figures)
    assert (tmp_path / "fitted" / "wrap_smooth.json").is_file()
