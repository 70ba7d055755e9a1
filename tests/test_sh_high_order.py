"""SH L3/L4 and ZH3 (rtfit.realtime.irradiance_bases) against independent values: scipy quadrature of the
clamped cosine and of Legendre integrals, closed-form Legendre-series irradiance, Gauss-product sphere
quadrature, Dr.Jit's own sh_eval, and the Dr.Jit run of the same kernel text against its NumPy run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate
from scipy.special import eval_legendre

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import irradiance_bases as ir

NEW = [m for m in ir.METHODS.values() if m.id.startswith(("sh-l3", "sh-l4", "zh3"))]


def _coeffs_for(m, sh):
    """What basis ``m`` stores for SH coefficients ``sh``: the ZH3 bakes, else the SH rows themselves."""
    if m.id == "zh3":
        return ir.zh3_from_sh(sh)
    return ir.zh3_from_sh(sh, shared_axis=True) if m.id == "zh3-lum" else sh


def _a_hat_quad(band: int) -> float:
    """2π ∫₀^{π/2} cos θ P_l(cos θ) sin θ dθ by scipy quad (the definition, not the closed form)."""
    f = lambda th: math.cos(th) * eval_legendre(band, math.cos(th)) * math.sin(th)  # noqa: E731
    return 2.0 * math.pi * integrate.quad(f, 0.0, math.pi / 2, epsabs=1e-14, epsrel=1e-13)[0]


def _disk_factor_quad(band: int, alpha: float) -> float:
    """2 ∫_{cos α}^1 P_l(t) dt / sin²α by scipy quad (Funk–Hecke of the cap's indicator)."""
    c = math.cos(alpha)
    # absolute tolerance on the scale of the cap's width 1 − cos α (the integral can cross 0)
    val = integrate.quad(lambda t: eval_legendre(band, t), c, 1.0, epsabs=1e-13 * (1 - c), epsrel=1e-12)[0]
    return 2.0 * val / math.sin(alpha) ** 2


def _sphere_rule(n_theta=16, n_phi=32):
    """Gauss–Legendre in cos θ × uniform φ: exact for polynomials of degree < min(2·n_theta, n_phi) on S²."""
    t, wt = np.polynomial.legendre.leggauss(n_theta)
    ph = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    tt, pp = np.meshgrid(t, ph, indexing="ij")
    s = np.sqrt(1 - tt**2)
    d = np.stack([s * np.cos(pp), s * np.sin(pp), tt], -1).reshape(-1, 3)
    w = (wt[:, None] * np.full(n_phi, 2 * math.pi / n_phi)[None, :]).reshape(-1)
    return d, w


def _unit_vec(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


# ------------------------------------------------------------------------------------------ band factors
def test_band_factors_match_quadrature_and_odd_bands_vanish():
    # measured max |closed form − quad| over l ≤ 8: 3e-16
    for band in range(9):
        assert ir.clamped_cosine_band(band) == pytest.approx(_a_hat_quad(band), abs=1e-12), band
    for band in range(5):
        assert ir.A_HAT[band] == ir.clamped_cosine_band(band)
    assert ir.A_HAT[3] == 0.0 and ir.clamped_cosine_band(5) == 0.0 and ir.clamped_cosine_band(7) == 0.0
    assert ir.A_HAT[4] == pytest.approx(-math.pi / 24, rel=1e-15)
    assert ir.clamped_cosine_band(6) == pytest.approx(math.pi / 64, rel=1e-15)
    with pytest.raises(ValueError, match="band"):
        ir.clamped_cosine_band(-1)


# ------------------------------------------------------------------------------------------------ basis
def test_basis_to_l4_orthonormal_by_gauss_product_rule():
    d, w = _sphere_rule()  # exact for the degree-8 products of two l ≤ 4 polynomials
    y = ir.sh_basis(d, 4)
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(25), atol=1e-13)  # measured 3e-15


def test_basis_matches_drjit_sh_eval_up_to_condon_shortley():
    import drjit as dr
    from drjit.scalar import Array3f

    rng = np.random.default_rng(11)
    sign = np.array([(-1.0) ** abs(m) for band in range(5) for m in range(-band, band + 1)])
    for d in rng.normal(size=(6, 3)):
        d = _unit_vec(d)
        theirs = np.array(dr.sh_eval(Array3f(*d.tolist()), 4))
        np.testing.assert_allclose(ir.sh_basis(d, 4), sign * theirs, atol=3e-6)  # float32 Dr.Jit: 5e-7


# ------------------------------------------------------------------------------------------------- discs
def test_disk_zonal_factors_match_legendre_quadrature():
    for alpha in (1e-3, 0.05, 0.4, 1.0, math.pi / 2):
        got = ir.disk_zonal_factors(alpha, 4)
        want = [_disk_factor_quad(band, alpha) for band in range(5)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)  # measured 2e-13 (α = 1e-3: 4e-10)
    np.testing.assert_allclose(ir.disk_zonal_factors(0.0, 4), np.ones(5) * [1, 1, 1, 1, 1])


def test_disk_sh_coefficient_matches_sphere_integral():
    # one l = 3 and one l = 4 coefficient of a tilted disc by 2-D scipy quadrature over the cap
    alpha = math.radians(25.0)
    d = _unit_vec([0.3, -0.4, 0.866])
    want = ir.sh_from_disk(d, alpha, 1.0, order=4)
    radiance = 1.0 / (math.pi * math.sin(alpha) ** 2)
    t = _unit_vec(np.cross([0, 0, 1.0], d))
    b = np.cross(d, t)
    for k in (11, 20):  # Y3,−1 and Y40

        def f(ph, g, k=k):
            w = math.cos(g) * d + math.sin(g) * (math.cos(ph) * t + math.sin(ph) * b)
            return ir.sh_basis(w, 4)[k] * math.sin(g) * radiance

        got = integrate.dblquad(f, 0, alpha, 0, 2 * math.pi, epsabs=1e-9)[0]
        assert got == pytest.approx(want[k], abs=1e-7)


# ------------------------------------------------------------------------------------ irradiance oracle
def _legendre_irradiance(cos_theta, order, factors):
    """E(θ) = Σ_{l ≤ order} Â_l f_l (2l + 1)/(4π) P_l(cos θ): the addition theorem with Â_l by quadrature."""
    return sum(
        _a_hat_quad(band) * factors[band] * (2 * band + 1) / (4 * math.pi) * eval_legendre(band, cos_theta)
        for band in range(order + 1)
    )


@pytest.mark.parametrize("alpha", [0.0, math.radians(12.0)])
def test_l3_l4_irradiance_of_directional_light_and_disc_match_legendre_oracle(alpha):
    d = _unit_vec([0.5, -0.3, 0.7])
    n = ir.fibonacci_sphere(300)
    n = np.concatenate([n, [d, -d, [1, 0, 0], [0, 0, -1]]])
    c = n @ d
    factors = [_disk_factor_quad(b, alpha) if alpha > 0 else 1.0 for b in range(5)]
    sh = ir.sh_from_disk(d, alpha, 1.0, order=4)
    for order in (2, 3, 4):
        got = ir.sh_irradiance(sh, n, order)
        want = _legendre_irradiance(c, order, factors)
        np.testing.assert_allclose(got, np.repeat(want[:, None], 3, 1), atol=1e-12)  # measured 4e-16
    # odd bands above 1 vanish: L3 is L2 bit for bit; L4 is closer to max(cos θ, 0) at the light
    np.testing.assert_array_equal(ir.sh_irradiance(sh, n, 3), ir.sh_irradiance(sh, n, 2))
    if alpha == 0.0:
        at_light = ir.sh_irradiance(sh, d, 4)[0]
        assert at_light == pytest.approx(0.25 + 0.5 + 0.3125 - 0.09375, abs=1e-14)


def test_windows_to_order_4_and_lambda_fit():
    for order in (3, 4):
        ls = np.arange(order + 1)
        np.testing.assert_allclose(ir.sh_window("hann", order), 0.5 * (1 + np.cos(np.pi * ls / (order + 1))))
        np.testing.assert_allclose(ir.sh_window("lanczos", order), np.sinc(ls / (order + 1)), rtol=1e-15)
        np.testing.assert_allclose(ir.sh_window("lambda", order, 0.1), 1 / (1 + 0.1 * ls**2 * (ls + 1) ** 2))
    c = ir.sh_from_directional([0.2, 0.3, 0.9], 4)
    lam4 = ir.fit_window_lambda(c, order=4)
    n = ir.fibonacci_sphere(20000)
    assert lam4 > 0
    assert ir.sh_irradiance(c, n, 4, ir.sh_window("lambda", 4, lam4)).min() >= 0.0
    assert ir.sh_irradiance(c, n, 4, ir.sh_window("lambda", 4, 0.9 * lam4)).min() < 0.0  # the smallest λ
    assert ir.fit_window_lambda(c, order=3) == ir.fit_window_lambda(c, order=2)  # Â_3 = 0
    # the method rows apply the same windows
    for kind in ("hann", "lanczos"):
        np.testing.assert_allclose(
            ir.basis_irradiance(f"sh-l4-{kind}", c, n[:50]),
            ir.sh_irradiance(c, n[:50], 4, ir.sh_window(kind, 4)),
            rtol=1e-12,
            atol=1e-14,
        )
    with pytest.raises(ValueError, match="order"):
        ir.sh_window("hann", 5)
    with pytest.raises(ValueError, match="order"):
        ir.fit_window_lambda(c, order=1)


def test_projection_to_order_4_of_a_polynomial_map():
    # radiance 2 + Y40 + 0.5 Y3,−2 (a degree-4 polynomial) on a lat-long map; projection recovers it to
    # the map's bilinear interpolation error (measured max 2.4e-3, on Y40, at 64 × 128, 2× supersampled)
    h, w = 64, 128
    u = (np.arange(w) + 0.5) / w
    v = np.arange(h) / (h - 1)
    d = ir.latlong_directions(*np.meshgrid(u, v))
    y = ir.sh_basis(d, 4)
    img = np.repeat((2.0 + y[..., 20] + 0.5 * y[..., 10])[..., None], 3, axis=2)
    c = ir.sh_project_latlong(img, 2, order=4)
    want = np.zeros(25)
    want[0], want[20], want[10] = 2.0 * math.sqrt(4 * math.pi), 1.0, 0.5
    np.testing.assert_allclose(c[:, 1], want, atol=4e-3)
    # the same sums by another route (BLAS may split them differently with its thread count): equal to a few
    # ulp of the largest coefficient, 7.09 (CI once saw 2.4e-14 on the 0.0019 coefficient Y20)
    np.testing.assert_allclose(c[:9], ir.sh_project_latlong(img, 2), rtol=1e-12, atol=1e-13)


# --------------------------------------------------------------------------------------------------- ZH3
def _zonal_environment_sh(d, a, b, cz):
    """SH (9, 3) of L(ω) = a + b (d·ω) + cz P2(d·ω), projected by the exact Gauss-product sphere rule."""
    dirs, w = _sphere_rule(8, 16)
    t = dirs @ d
    rad = a + b * t + cz * 0.5 * (3 * t * t - 1)
    return ir.sh_project_samples(dirs, w, np.repeat(rad[:, None], 3, 1))


@pytest.mark.parametrize("b", [0.8, -0.5])
def test_zh3_exact_for_l2_environment_zonal_about_its_l1_direction(b):
    d = _unit_vec([0.4, -0.7, 0.3])
    a, cz = 1.5, 0.6
    sh = _zonal_environment_sh(d, a, b, cz)
    n = np.concatenate([ir.fibonacci_sphere(200), [d, -d, [0, 0, 1.0]]])
    t = n @ d
    exact = math.pi * a + (2 * math.pi / 3) * b * t + (math.pi / 4) * cz * 0.5 * (3 * t * t - 1)
    zh3 = ir.basis_irradiance("zh3", ir.zh3_from_sh(sh), n)
    np.testing.assert_allclose(zh3, np.repeat(exact[:, None], 3, 1), rtol=1e-12, atol=1e-12)  # 2e-15
    l1 = ir.basis_irradiance("sh-l1", sh, n)
    assert np.max(np.abs(l1[:, 0] - exact)) > 0.1  # L1 alone misses the quadratic band
    # the shared luminance axis: exact too when every channel's zonal axis is the same (scaled channels)
    rgb = sh * np.array([1.0, 0.5, 2.0])
    lum = ir.basis_irradiance("zh3-lum", ir.zh3_from_sh(rgb, shared_axis=True), n)
    np.testing.assert_allclose(lum, exact[:, None] * np.array([1.0, 0.5, 2.0]), rtol=1e-12, atol=1e-12)


def test_zh3_between_l1_and_l2_and_per_channel_axes():
    # random non-band-limited L2 environments: the zonal projection lowers the sphere-integrated error
    # of L1 and cannot beat L2 (exact rule for the degree-4 squared error)
    rng = np.random.default_rng(4)
    dirs, w = _sphere_rule(8, 16)
    for _ in range(5):
        sh = rng.normal(size=(9, 3))
        sh[0] = 3.0 + np.abs(sh[0])
        exact = ir.basis_irradiance("sh-l2", sh, dirs)

        def err(method, sh=sh, exact=exact):
            coeffs = _coeffs_for(ir.METHODS[method], sh)
            return np.sum(w[:, None] * (ir.basis_irradiance(method, coeffs, dirs) - exact) ** 2, axis=0)

        e1, e3, e3l = err("sh-l1"), err("zh3"), err("zh3-lum")
        assert np.all(e3 <= e1 + 1e-12) and np.all(e3 < e1)
        assert np.all(e3l <= e1 + 1e-12)  # a zonal projection about any axis cannot add error
    # each channel keeps its own axis: a red-only and a blue-only zonal environment, both exact
    sh = np.zeros((9, 3))
    sh[:, 0] = _zonal_environment_sh(_unit_vec([1, 0, 0]), 1.0, 0.5, 0.4)[:, 0]
    sh[:, 2] = _zonal_environment_sh(_unit_vec([0, 1, 1]), 1.0, 0.5, -0.3)[:, 0]
    np.testing.assert_allclose(
        ir.basis_irradiance("zh3", ir.zh3_from_sh(sh), dirs),
        ir.basis_irradiance("sh-l2", sh, dirs),
        atol=1e-12,
    )


def test_zh3_hallucinated_closed_form_and_degenerate_inputs():
    d = _unit_vec([0.1, 0.2, -0.9])
    sh = ir.sh_from_directional(d)
    # unit directional light: r = √3, z = L00 √3 (0.08 + 0.6√3); at n = d:
    # E = 1/4 + 1/2 + (π/4) z Y20(1) = 3/4 + (√15/16)(0.08 + 0.6√3)
    want = 0.75 + math.sqrt(15) / 16 * (0.08 + 0.6 * math.sqrt(3))
    assert ir.basis_irradiance("zh3-hallucinated", sh, d)[0] == pytest.approx(want, rel=1e-13)
    # the stored-coefficient ZH3 of the same light: z = Y20(1) = √5/(2√π), E(d) = L2's 1.0625
    assert ir.basis_irradiance("zh3", ir.zh3_from_sh(sh), d)[0] == pytest.approx(1.0625, rel=1e-13)
    # no L1 (constant sky): both are the DC term, no NaN from the undefined axis; all-zero stays zero
    c = ir.sh_from_constant(1.0)
    n = ir.fibonacci_sphere(20)
    for m, coeffs in (("zh3", ir.zh3_from_sh(c)), ("zh3-hallucinated", c)):
        np.testing.assert_allclose(ir.basis_irradiance(m, coeffs, n), math.pi, rtol=1e-14)
        assert np.all(ir.basis_irradiance(m, np.zeros_like(coeffs), n) == 0.0)


# ----------------------------------------------------------------------------------------- robustness
_SPECIAL = st.sampled_from([0.0, 1.0, -1.0, 1e-30, -1e-30, 1e-8, 0.5, 1e30])
_COMP = st.one_of(_SPECIAL, st.floats(-1.0, 1.0, allow_nan=False))


@settings(max_examples=50, deadline=None)
@given(x=_COMP, y=_COMP, z=_COMP, sun_scale=st.sampled_from([0.0, 1.0, 1e5]), grazing=st.booleans())
def test_property_new_bases_finite_at_grazing_and_axis_aligned_normals(x, y, z, sun_scale, grazing):
    n = np.array([[x, y, z]], dtype=np.float64)
    if not np.sum(n * n) > 1e-30 or not np.all(np.isfinite(n * n)):
        return
    sun = _unit_vec([1.0, 0.0, 0.0]) if grazing else _unit_vec([0.3, 0.5, 0.8])
    if grazing:  # the normal at exactly 90° to the sun
        n[0, 0] = 0.0
        if not np.sum(n * n) > 1e-30:
            return
    sh = sun_scale * ir.sh_from_disk(sun, 0.01, 1.0, 4)[:, None] * np.ones(3) + ir.sh_from_constant(0.5, 4)
    for m in NEW:
        coeffs = _coeffs_for(m, sh)
        e64 = np.stack(m(NUMPY_OPS, ir.basis_inputs(m, coeffs, n), {"lam": 0.01} if m.params else None), -1)
        assert np.all(np.isfinite(e64)), m.id


def test_drjit_llvm_and_numpy_run_the_same_text():
    import drjit as dr

    rng = np.random.default_rng(9)
    n = rng.normal(size=(64, 3))
    sh = rng.normal(size=(25, 3))
    sh[0] = np.abs(sh[0]) + 2.0
    nd = dr.llvm.Array3f64(n.T)
    for m in NEW:
        coeffs = _coeffs_for(m, sh)
        params = {"lam": 0.05} if m.params else None
        want = np.stack(m(NUMPY_OPS, ir.basis_inputs(m, coeffs, n), params), -1)
        got = ir.basis_irradiance(m, coeffs, nd, params)
        np.testing.assert_allclose(np.stack([np.array(g) for g in got], -1), want, rtol=1e-12, atol=1e-12)
    # axis-aligned, grazing (⊥ to a 1e5 sun) and tiny/huge normals on Dr.Jit: finite
    sun = _unit_vec([1.0, 0.0, 0.0])
    strong = 1e5 * ir.sh_from_disk(sun, 0.01, 1.0, 4)[:, None] * np.ones(3) + ir.sh_from_constant(0.5, 4)
    special = np.array(
        [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, -1], [0, 1e-30, 1e-30], [0, 1e30, -1e30], [1e-8, 1, 0]]
    )
    for m in NEW:
        coeffs = _coeffs_for(m, strong)
        got = ir.basis_irradiance(
            m, coeffs, dr.llvm.Array3f64(special.T), {"lam": 0.01} if m.params else None
        )
        assert np.all(np.isfinite(np.stack([np.array(g) for g in got]))), m.id
    # a zero normal on Dr.Jit (not checked there) gives the sphere average: the DC term
    zero = dr.llvm.Array3f64([0.0], [0.0], [0.0])
    for mid in ("sh-l4", "zh3", "zh3-lum", "zh3-hallucinated"):
        got = np.array(ir.basis_irradiance(mid, _coeffs_for(ir.METHODS[mid], sh), zero)[0])
        assert got[0] == pytest.approx(math.pi * ir.SH_C[0] * sh[0, 0], rel=1e-12)


def test_method_rows_and_bad_input():
    storage = {m.id: m.storage for m in NEW}
    assert {k: v for k, v in storage.items() if k.startswith("sh-l3")} == dict.fromkeys(
        ("sh-l3", "sh-l3-hann", "sh-l3-lanczos", "sh-l3-lambda"), 48
    )
    assert storage["sh-l4"] == storage["sh-l4-lambda"] == 75
    assert storage["zh3"] == storage["zh3-lum"] == 15 and storage["zh3-hallucinated"] == 12
    for m in NEW:
        assert m.formula and m.source and m.label
    with pytest.raises(ValueError, match="order"):
        ir.sh_irradiance(np.ones((25, 3)), [0, 0, 1.0], order=5)
    with pytest.raises(ValueError, match="coeffs"):
        ir.basis_irradiance("sh-l4", np.ones((16, 3)), [0, 0, 1.0])
    with pytest.raises(ValueError, match="angular_radius"):
        ir.disk_zonal_factors(2.0, 4)
