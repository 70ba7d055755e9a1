"""Tests of rtfit.realtime.ambient_aperture against independent values only.

References (none is the code's own output):
* mpmath quadrature of the intersection area in the polar coordinates of the smaller cap:
  Ω = ∫_0^{r_s} 2·acos(clamp((cos r_b − cos θ cos d)/(sin θ sin d))) sin θ dθ, split at the kinks
  θ = |d − r_b|, d + r_b, 2π − d − r_b (where the azimuthal arc inside the other cap starts or ends);
* closed cases: nested caps → the smaller cap 2π(1 − cos r); disjoint → 0; two hemispheres d apart → the
  lune 2(π − d); covering caps → A1 + A2 − 4π; a cap against its own complement → 0;
* the seed's numbers (000:2672-2687 erratum: −7.92 printed vs 0.3078 true for r0 = r1 = d = 0.5);
* closed irradiance values for the shading (open sky: π L_sky; small light: Ω cos θ).
"""

from __future__ import annotations

import math

import drjit as dr
import mpmath as mp
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import ambient_aperture as ap

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

PI = math.pi
Float, Float64 = dr.llvm.Float, dr.llvm.Float64


def cap(r):
    return 2 * math.pi * (1 - math.cos(r))


def quad_intersection(r1: float, r2: float, d: float) -> float:
    """mpmath quadrature of the intersection solid angle (integrating over the smaller cap)."""
    with mp.workdps(25):
        rs, rb, dd = (mp.mpf(min(r1, r2)), mp.mpf(max(r1, r2)), mp.mpf(d))
        if rs == 0:
            return 0.0
        if dd == 0:
            return float(2 * mp.pi * (1 - mp.cos(rs)))

        def f(th):
            if th == 0:
                return mp.mpf(0)
            k = (mp.cos(rb) - mp.cos(th) * mp.cos(dd)) / (mp.sin(th) * mp.sin(dd))
            return 2 * mp.acos(max(-1, min(1, k))) * mp.sin(th)

        pts = sorted(
            {mp.mpf(0), rs} | {b for b in (abs(dd - rb), dd + rb, 2 * mp.pi - dd - rb) if 0 < b < rs}
        )
        return float(mp.quad(f, pts))


def _cases():
    rng = np.random.default_rng(7)
    out = [tuple(x) for x in rng.uniform(0, PI, (40, 3))]
    for r1, r2 in [(0.5, 0.5), (0.01, 1.2), (2.5, 0.3), (2.8, 2.9), (1.5, 1.7), (0.002, 0.003)]:
        for frac in (0.05, 0.5, 0.95):
            lo, hi = abs(r1 - r2), min(r1 + r2, 2 * PI - r1 - r2)
            out.append((r1, r2, lo + frac * (hi - lo)))
    return out


CASES = _cases()
QUAD = [quad_intersection(*c) for c in CASES]


def test_quadrature_reference_is_right():
    """The reference itself on closed cases: nested, a lune, disjoint."""
    assert quad_intersection(0.3, 1.0, 0.2) == pytest.approx(cap(0.3), rel=1e-12)
    assert quad_intersection(PI / 2, PI / 2, 1.0) == pytest.approx(2 * (PI - 1.0), rel=1e-12)
    assert quad_intersection(0.3, 0.4, 0.8) == 0.0


def test_exact_matches_quadrature_float64():
    r = np.array(CASES).T
    ref = np.array(QUAD)
    a_min = 2 * np.pi * (1 - np.cos(np.minimum(r[0], r[1])))
    for name, e in [
        ("numpy f64", ap.cap_intersection_solid_angle(*r)),
        ("Dr.Jit Float64", np.asarray(ap.cap_intersection_solid_angle(*[Float64(x) for x in r]))),
        ("numpy kernel", ap.METHODS["exact"](NUMPY_OPS, dict(zip(("r1", "r2", "d"), r, strict=True)))),
        ("floats", np.array([ap.cap_intersection_solid_angle(*map(float, c)) for c in CASES])),
    ]:
        err = np.abs(np.asarray(e) - ref) / a_min
        assert err.max() < 1e-11, (name, err.max(), CASES[int(err.argmax())])


def test_exact_float32_accuracy():
    """float32 error relative to the smaller cap ≤ 5e-6 + 3e-7/r_min (measured max 1.0e-3 at r_min = 1.2e-4
    next to the rim of a large cap; ≤ 2e-6 for r_min ≥ 0.1) against float64 at the same float32 inputs."""
    rng = np.random.default_rng(3)
    n = 20000
    r1 = np.exp(rng.uniform(math.log(1e-4), math.log(PI), n))
    r2 = np.exp(rng.uniform(math.log(1e-4), math.log(PI), n))
    eps = np.exp(rng.uniform(math.log(1e-7), 0, n)) * np.minimum(r1, r2)
    d = np.concatenate(
        [np.clip(r1 + r2 - eps, 0, PI), np.clip(np.abs(r1 - r2) + eps, 0, PI), rng.uniform(0, PI, n)]
    )
    r = np.stack([np.tile(r1, 3), np.tile(r2, 3), d]).astype(np.float32)
    e64 = ap.cap_intersection_solid_angle(*r.astype(np.float64))
    r_min = np.minimum(r[0], r[1]).astype(np.float64)
    a_min = 2 * np.pi * (1 - np.cos(r_min))
    for e32 in (
        ap.cap_intersection_solid_angle(*r),
        np.asarray(ap.cap_intersection_solid_angle(*map(Float, r))),
    ):
        err = np.abs(np.asarray(e32, np.float64) - e64) / a_min
        assert np.all(err <= 5e-6 + 3e-7 / r_min), err.max()


HARD_POINTS = ((0.5, 0.5, 0.5), (2.0, 1.0, 2.5), (2.6, 2.2, 1.9), (0.01, 1.2, 1.205), (1.4, 0.0003, 1.40025))
"""Equal caps, covering caps, near-tangent tiny caps (the experiment's hard points)."""


def test_exact_at_hard_points_matches_mpmath():
    """The closed form against 25-digit mpmath quadrature where it is hardest: ≤ 1e-10 of the smaller cap
    (measured 5.9e-13, at the tiny cap next to the rim of a large one)."""
    for r1, r2, d in HARD_POINTS:
        err = abs(ap.cap_intersection_solid_angle(r1, r2, d) - quad_intersection(r1, r2, d)) / cap(
            min(r1, r2)
        )
        assert err <= 1e-10, (r1, r2, d, err)


def test_closed_cases():
    f = ap.cap_intersection_solid_angle
    assert f(0.3, 1.0, 0.2) == pytest.approx(cap(0.3), rel=1e-14)  # nested
    assert f(0.3, 1.0, 0.7) == pytest.approx(cap(0.3), rel=1e-14)  # internally tangent
    assert f(0.3, 0.4, 0.7) == 0.0  # externally tangent
    assert f(0.3, 0.4, 1.5) == 0.0  # disjoint
    for d in (0.0, 0.1, 1.0, 2.0, PI):  # hemispheres: lune
        assert f(PI / 2, PI / 2, d) == pytest.approx(2 * (PI - d), abs=1e-13)
    assert f(2.5, 2.0, 2.0) == pytest.approx(cap(2.5) + cap(2.0) - 4 * PI, rel=1e-13)  # covering
    assert f(1.0, PI - 1.0, PI) == pytest.approx(0.0, abs=1e-14)  # a cap and its complement
    assert f(PI, 0.4, 1.3) == pytest.approx(cap(0.4), rel=1e-14)  # the whole sphere
    assert f(0.0, 1.0, 0.5) == 0.0 and f(0.0, 0.0, 0.0) == 0.0


def test_seed_erratum_numbers():
    """The printed formula (000:2672-2687) gives −7.92 at r0 = r1 = d = 0.5; the true value is 0.3078."""
    assert ap.seed_printed_intersect_area(0.5, 0.5, 0.5) == pytest.approx(-7.921, abs=1e-3)
    assert ap.cap_intersection_solid_angle(0.5, 0.5, 0.5) == pytest.approx(
        quad_intersection(0.5, 0.5, 0.5), rel=1e-12
    )
    assert quad_intersection(0.5, 0.5, 0.5) == pytest.approx(0.3075, abs=1e-3)


def test_monte_carlo_agrees():
    """Plain Monte Carlo on the sphere (2·10⁶ uniform directions; 4σ bound) at a few points."""
    rng = np.random.default_rng(11)
    v = rng.normal(size=(2_000_000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for r1, r2, d in [(0.5, 0.5, 0.5), (2.0, 1.0, 2.5), (2.6, 2.2, 1.9)]:
        c2 = np.array([math.sin(d), 0.0, math.cos(d)])
        hit = (v[:, 2] >= math.cos(r1)) & (v @ c2 >= math.cos(r2))
        p = hit.mean()
        sigma = 4 * math.pi * math.sqrt(p * (1 - p) / len(v))
        assert abs(4 * math.pi * p - ap.cap_intersection_solid_angle(r1, r2, d)) < 4 * sigma + 1e-12


def test_approximations_known_values():
    """Smoothstep/linear ramp by hand: equal caps, halfway (t = ½) → ½ of the cap; nested/disjoint exact."""
    a = cap(0.4)
    assert ap.cap_intersection_smoothstep(0.4, 0.4, 0.4) == pytest.approx(0.5 * a, rel=1e-12)
    assert ap.cap_intersection_linear(0.4, 0.4, 0.2) == pytest.approx(0.75 * a, rel=1e-12)
    assert ap.cap_intersection_smoothstep(0.4, 0.4, 0.2) == pytest.approx(0.84375 * a, rel=1e-12)
    for fn in (ap.cap_intersection_smoothstep, ap.cap_intersection_linear, ap.cap_intersection_fitted):
        assert fn(0.3, 1.0, 0.5) == pytest.approx(cap(0.3), rel=1e-12)
        assert fn(0.3, 0.4, 0.8) == 0.0
    # Fitted form: exact on the covering case thanks to the complement trick, where the seed errs.
    exact = cap(2.5) + cap(2.0) - 4 * PI
    assert ap.cap_intersection_fitted(2.5, 2.0, 2.0) == pytest.approx(exact, rel=1e-12)
    assert abs(ap.cap_intersection_smoothstep(2.5, 2.0, 2.0) - exact) > 0.1 * cap(2.0)


def test_fitted_beats_smoothstep_on_grid():
    """Over a 24³ grid of partial overlaps: the fitted form's max error (vs quadrature at 60 grid points and
    the exact form elsewhere) is below the smoothstep's, which is ≈ 0.16 of the smaller cap for r ≤ π/2."""
    g = (np.arange(24) + 0.5) / 24 * PI
    r1, r2, d = (x.ravel() for x in np.meshgrid(g, g, g, indexing="ij"))
    part = (d > np.abs(r1 - r2)) & (d < r1 + r2) & (r1 + r2 + d < 2 * PI)
    r1, r2, d = r1[part], r2[part], d[part]
    idx = np.random.default_rng(5).choice(len(r1), 60, replace=False)
    ref = np.array([quad_intersection(r1[i], r2[i], d[i]) for i in idx])
    exact = ap.cap_intersection_solid_angle(r1, r2, d)
    assert np.allclose(exact[idx], ref, rtol=0, atol=1e-10)
    a_min = 2 * np.pi * (1 - np.cos(np.minimum(r1, r2)))
    hemi = (r1 <= PI / 2) & (r2 <= PI / 2)
    e_s = np.abs(ap.cap_intersection_smoothstep(r1, r2, d) - exact) / a_min
    e_l = np.abs(ap.cap_intersection_linear(r1, r2, d) - exact) / a_min
    e_f = np.abs(ap.cap_intersection_fitted(r1, r2, d) - exact) / a_min
    assert 0.13 < e_s[hemi].max() < 0.18
    assert e_l[hemi].max() < e_s[hemi].max()
    assert e_f.max() < 0.6 * e_l[hemi].max()
    assert np.sqrt(np.mean(e_f**2)) < 0.3 * np.sqrt(np.mean(e_s[hemi] ** 2))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0, PI), st.floats(0, PI), st.floats(0, PI)), min_size=1, max_size=32),
    st.sampled_from([np.float32, np.float64]),
)
@example([(0.9375, 1.192092896e-07, 0.9375)], np.float32)  # a cap of 2 float32 ulps of d, centred on the rim
def test_property_bounds_and_symmetry(triples, dtype):
    r = np.array(triples, dtype=np.float64).T.astype(dtype)
    r = np.minimum(r, dtype(PI))
    a_min = np.asarray(ap.cap_area(np.minimum(r[0], r[1])), np.float64)
    for fn in (
        ap.cap_intersection_solid_angle,
        ap.cap_intersection_smoothstep,
        ap.cap_intersection_linear,
        ap.cap_intersection_fitted,
    ):
        x = np.asarray(fn(*r), np.float64)
        assert np.all(np.isfinite(x))
        assert np.all(x >= 0) and np.all(x <= a_min * (1 + 1e-6) + 1e-30)
        y = np.asarray(fn(r[1], r[0], r[2]), np.float64)
        tol = (1e-5 if dtype == np.float32 else 1e-12) * a_min + 1e-30  # relative to the smaller cap
        # plus the inputs' own rounding: the kernel evaluates cosines of angles known to a few ulps
        # (ε·max angle), and Ω moves by at most the lens' chord (≤ 2 sin r_min) per radian of any of them —
        # for a cap of 2 float32 ulps of d this is the answer's own size (a 1.2e-7 rad cap on the rim of a
        # 0.9375 rad one: the two orders gave 2.8e-14 and 4.3e-14, 32 % of its area 4.5e-14)
        eps = float(np.finfo(dtype).eps)
        quantised = 2.0 * np.sin(np.minimum(r[0], r[1]).astype(np.float64)) * 4.0 * eps * np.max(r, axis=0)
        assert np.all(np.abs(x - y) <= tol + quantised)


@settings(max_examples=40, deadline=None)
@given(st.floats(1e-3, PI), st.floats(1e-3, PI), st.lists(st.floats(0, PI), min_size=2, max_size=24))
def test_property_exact_monotone_in_distance(r1, r2, ds):
    d = np.sort(np.array(ds))
    x = ap.cap_intersection_solid_angle(np.full_like(d, r1), np.full_like(d, r2), d)
    assert np.all(np.diff(x) <= 1e-12 * cap(min(r1, r2)) + 1e-15)


def test_extremes_no_nan():
    r = np.array([0.0, 1e-30, 1e-7, PI / 2, PI - 1e-7, PI, np.float32(PI)], dtype=np.float32)
    g = np.stack(np.meshgrid(r, r, r, indexing="ij")).reshape(3, -1)
    for fn in (ap.cap_intersection_solid_angle, ap.cap_intersection_smoothstep, ap.cap_intersection_fitted):
        for x in (fn(*g), fn(*g.astype(np.float64)), np.asarray(fn(*map(Float, g)))):
            assert np.all(np.isfinite(x)) and np.all(x >= 0)


def test_validation_errors():
    with pytest.raises(ValueError, match="r1 must be in"):
        ap.cap_intersection_solid_angle(-0.1, 0.5, 0.5)
    with pytest.raises(ValueError, match="d must be in"):
        ap.cap_intersection_smoothstep(0.1, 0.5, np.array([0.5, 4.0]))
    with pytest.raises(ValueError, match="r2 must be in"):
        ap.cap_intersection_fitted(0.1, float("nan"), 0.5)
    with pytest.raises(ValueError, match="coeffs"):
        ap.cap_intersection_fitted(0.1, 0.2, 0.5, coeffs=(1.0, 2.0))
    with pytest.raises(ValueError, match="aperture must be in"):
        ap.ambient_aperture_irradiance(1.0, 1.0, 1.0, 2.0, 0.1)
    with pytest.raises(ValueError, match="intersection must be one of"):
        ap.ambient_aperture_irradiance(1.0, 1.0, 1.0, 1.0, 0.1, intersection="cubic")
    with pytest.raises(ValueError, match="visible_fraction"):
        ap.aperture_from_visibility(1.5)


def test_aperture_from_visibility():
    v = np.array([0.0, 1e-6, 0.25, 0.5, 1.0])
    r = ap.aperture_from_visibility(v)
    assert np.allclose(4 * np.pi * np.sin(r / 2) ** 2, 2 * np.pi * v, rtol=1e-12, atol=1e-18)
    assert r[-1] == pytest.approx(PI / 2, rel=1e-15)


def test_shading_open_sky_erratum_and_fill():
    """Open sky (a = n, r_a = π/2), small light at 60°: the exact irradiance is Ω cos 60° L; the seed's
    plain-average Lambert factor gives cos 30° (73 % too bright); the fitted weights recover cos 60°.
    Fill with no light: exact π L_sky; the seed's solid-angle fill gives 2π L_sky."""
    alpha = 0.01
    c60 = 0.5
    omega = cap(alpha)
    seed, _ = ap.ambient_aperture_irradiance(1.0, c60, c60, PI / 2, alpha, 1.0, 0.0)
    fit, _ = ap.ambient_aperture_irradiance(1.0, c60, c60, PI / 2, alpha, 1.0, 0.0, lambert="fitted")
    assert seed / (omega * c60) == pytest.approx(math.cos(math.radians(30)) / 0.5, rel=1e-3)  # 1.732
    assert fit / (omega * c60) == pytest.approx(1.0, abs=2e-4)
    _, fill_seed = ap.ambient_aperture_irradiance(1.0, 0.0, -1.0, PI / 2, 0.0, 0.0, 1.0)
    _, fill_proj = ap.ambient_aperture_irradiance(1.0, 0.0, -1.0, PI / 2, 0.0, 0.0, 1.0, fill="projected")
    assert fill_seed == pytest.approx(2 * PI, rel=1e-12)
    assert fill_proj == pytest.approx(PI, rel=1e-12)
    # Tilted aperture cap fully above the horizon: projected solid angle π sin²r cos θ.
    _, f = ap.ambient_aperture_irradiance(math.cos(0.3), 0.0, -1.0, 0.5, 0.0, 0.0, 2.0, fill="projected")
    assert f == pytest.approx(2.0 * PI * math.sin(0.5) ** 2 * math.cos(0.3), rel=1e-12)


def test_shading_drjit_matches_numpy_and_is_finite():
    rng = np.random.default_rng(2)
    n = 4096
    args = [
        rng.uniform(-1, 1, n),
        rng.uniform(-1, 1, n),
        rng.uniform(-1, 1, n),
        rng.uniform(0, PI / 2, n),
        rng.uniform(0, PI / 2, n),
    ]
    args[3][:5] = [0.0, PI / 2, 0.0, PI / 2, 1e-20]
    args[4][:5] = [0.0, 0.0, PI / 2, PI / 2, 1e-20]
    for form in ap.INTERSECTION_FORMS:
        for lam in ap.LAMBERT_FORMS:
            for fill in ap.FILL_FORMS:
                e64 = ap.ambient_aperture_irradiance(
                    *args, 1.0, 0.5, intersection=form, lambert=lam, fill=fill
                )
                e32 = ap.ambient_aperture_irradiance(
                    *[a.astype(np.float32) for a in args], 1.0, 0.5, intersection=form, lambert=lam, fill=fill
                )
                for a, b in zip(e64, e32, strict=True):
                    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(a >= 0)
                    assert np.allclose(a, b, atol=2e-4)


def test_methods_table_matches_the_public_functions():
    """Every row of `METHODS` runs the same kernel as the public function it stands for (bit for bit on the
    default backend), its NumPy run agrees to rounding, and its parameter defaults are the shipped values."""
    rng = np.random.default_rng(4)
    n = 2000
    caps = dict(zip(("r1", "r2", "d"), rng.uniform(0, PI, (3, n)), strict=True))
    public = {
        "exact": ap.cap_intersection_solid_angle,
        "smoothstep": ap.cap_intersection_smoothstep,
        "linear": ap.cap_intersection_linear,
        "fitted": ap.cap_intersection_fitted,
    }
    for form, fn in public.items():
        m = ap.METHODS[form]
        assert [i.unit for i in m.inputs] == ["rad"] * 3 and m.exact == (form == "exact")
        x = m.evaluate(caps)
        assert np.array_equal(x, fn(**caps)), form
        assert np.allclose(m(NUMPY_OPS, caps), x, rtol=0, atol=1e-13), form
    assert tuple(ap.METHODS["fitted"].defaults().values()) == ap.FITTED_COEFFS
    assert ap.METHODS["aa-fitted-fitted"].defaults()["k"] == ap.FITTED_LAMBERT_K
    shade = {
        "cos_na": rng.uniform(-1, 1, n),
        "cos_nl": rng.uniform(-1, 1, n),
        "cos_al": rng.uniform(-1, 1, n),
        "aperture": rng.uniform(0, PI / 2, n),
        "alpha": rng.uniform(0, PI / 2, n),
    }
    args = [shade[k] for k in ("cos_na", "cos_nl", "cos_al", "aperture", "alpha")]
    rows = [m for m in ap.METHODS.values() if m.quantity != "cap_intersection_solid_angle"]
    assert {m.id for m in rows} >= {"aa-smoothstep-seed", "aa-fitted-fitted", "fill-seed", "fill-projected"}
    for m in rows:
        kind, form, variant = m.id.split("-") if m.id.startswith("aa-") else ("fill", "exact", m.id[5:])
        if kind == "aa":
            want, _ = ap.ambient_aperture_irradiance(*args, 1.5, 0.0, intersection=form, lambert=variant)
            got = m.evaluate({**shade, "radiance": 1.5})
        else:  # the fill alone: no light (α = 0)
            zero = np.zeros(n)
            _, want = ap.ambient_aperture_irradiance(
                args[0], zero, zero - 1, args[3], zero, 0.0, 2.0, fill=variant
            )
            got = m.evaluate({"cos_na": args[0], "aperture": args[3], "sky_radiance": 2.0})
        assert np.array_equal(got, want), m.id
