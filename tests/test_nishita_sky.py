"""rtfit.realtime.nishita_sky against independent values: mpmath quadrature, closed forms, scipy."""

import math

import mpmath as mp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rtfit.realtime import nishita_sky as sky
from rtfit.realtime import phase
from rtfit.realtime.arrays import NUMPY_OPS, jax_ops

RG, RT = 6360e3, 6420e3
TOP = RT - RG


def od_mpmath(h, mu, H, rg=RG, rt=RT):
    """∫ exp(−(|o + t v| − R_g)/H) dt to the top, straight in t (independent of the x-substitution)."""
    mp.mp.dps = 30
    h, mu, H = mp.mpf(h), mp.mpf(mu), mp.mpf(H)
    r0 = rg + h
    f = lambda t: mp.exp(-(mp.sqrt(r0**2 + t**2 + 2 * r0 * t * mu) - rg) / H)  # noqa: E731
    t_top = -r0 * mu + mp.sqrt(r0**2 * mu**2 - r0**2 + mp.mpf(rt) ** 2)
    pts = [0, -r0 * mu, t_top] if mu < 0 else [0, t_top]
    # split further so the quadrature resolves the exponential near the low end
    return float(mp.quad(f, pts, maxdegree=10))


@pytest.mark.parametrize(
    "h,mu,H",
    [
        (0.0, 0.0, 8000.0),  # horizontal ray at the ground (Chapman regime)
        (0.0, 0.0, 1200.0),
        (0.0, 1e-3, 8000.0),
        (0.0, 1.0, 1200.0),
        (1500.0, -0.02, 8000.0),  # down-going, passes above the ground
        (30e3, -0.05, 1200.0),
        (12e3, 0.3, 8000.0),
        (TOP - 1.0, 0.0, 8000.0),  # 1 m below the top, horizontal
    ],
)
def test_optical_depth_matches_mpmath(h, mu, H):
    got = sky.atmosphere_optical_depth(h, mu, H)
    ref = od_mpmath(h, mu, H)
    assert got == pytest.approx(ref, rel=1e-10)


def test_optical_depth_vertical_closed_form_and_limits():
    for h in (0.0, 1000.0, 20e3, 59e3):
        for H in (1200.0, 8000.0):
            ref = H * (math.exp(-h / H) - math.exp(-TOP / H))
            assert sky.atmosphere_optical_depth(h, 1.0, H) == pytest.approx(ref, rel=1e-12)
    assert sky.atmosphere_optical_depth(TOP, 0.5, 8000.0) == 0.0  # at the top, going up
    assert sky.atmosphere_optical_depth(TOP, 0.0, 8000.0) == 0.0  # at the top, horizontal
    assert math.isinf(sky.atmosphere_optical_depth(0.0, -1e-6, 8000.0))  # into the ground
    assert math.isinf(sky.atmosphere_optical_depth(1000.0, -0.5, 8000.0))
    # the grazing boundary from 10 km: μ = −√(1 − (R_g/r)²) touches the ground
    r = RG + 10e3
    mu_g = -math.sqrt(1 - (RG / r) ** 2)
    assert math.isinf(sky.atmosphere_optical_depth(10e3, mu_g * 1.0001, 8000.0))
    assert math.isfinite(sky.atmosphere_optical_depth(10e3, mu_g * 0.9999, 8000.0))


def test_optical_depth_drjit_float32_and_no_nan():
    import drjit as dr

    hs = np.array([0.0, 0.0, 0.0, 10.0, 5e3, TOP, TOP, 30e3])
    mus = np.array([0.0, 1.0, -1.0, -1e-7, 1e-7, -0.2, 1.0, -1.0])
    ref = sky.atmosphere_optical_depth(hs, mus, 8000.0)  # float64 → Float64
    got = sky.atmosphere_optical_depth(dr.llvm.Float(hs), dr.llvm.Float(mus), 8000.0)
    got = np.asarray(got, dtype=np.float64)
    assert not np.isnan(got).any() and not np.isnan(ref).any()
    fin = np.isfinite(ref)
    assert np.array_equal(fin, np.isfinite(got))
    assert np.allclose(got[fin], ref[fin], rtol=2e-4, atol=1e-3)


@settings(max_examples=15, deadline=None)
@given(
    arrays(np.float64, 16, elements=st.floats(0.0, TOP)),
    arrays(np.float64, 16, elements=st.floats(-1.0, 1.0)),
    st.floats(100.0, 1e5),
)
def test_optical_depth_properties(h, mu, H):
    od = sky.atmosphere_optical_depth(h, mu, np.full(16, H))
    assert not np.isnan(od).any()
    assert (od >= 0).all()
    # +inf exactly where the ray meets the ground: d = r sin θ < R_g, i.e. h < r(1 − sin θ) = rμ²/(1 + sin θ).
    # A ray within round-off of grazing the ground (|h − r μ²/(1 + sin θ)| ≤ 1e-12 r: 6 µm) may go either way:
    # hypothesis found h = 0, μ = −7.7e-160, whose r μ² is a subnormal 4e-312 that Dr.Jit's LLVM backend
    # flushes to zero (the tangent point then sits on the ground: a miss), while NumPy keeps it (a hit).
    r = RG + h
    sin_t = np.sqrt(np.maximum(1 - mu * mu, 0))
    tangent = r * mu * mu / (1 + sin_t)
    hits = (mu < 0) & (h < tangent)
    decided = np.abs(h - tangent) > 1e-12 * r
    assert np.array_equal(np.isinf(od)[decided], hits[decided])
    # a steeper up-going ray never sees more air
    od2 = sky.atmosphere_optical_depth(h, np.clip(np.abs(mu) + 0.05, 0, 1), np.full(16, H))
    od1 = sky.atmosphere_optical_depth(h, np.abs(mu), np.full(16, H))
    assert (od2 <= od1 * (1 + 1e-12) + 1e-9).all()


def test_optical_depth_bad_input():
    with pytest.raises(ValueError, match="altitude_m"):
        sky.atmosphere_optical_depth(-1.0, 0.5, 8000.0)
    with pytest.raises(ValueError, match="cos_zenith"):
        sky.atmosphere_optical_depth(0.0, 1.5, 8000.0)
    with pytest.raises(ValueError, match="scale_height_m"):
        sky.atmosphere_optical_depth(0.0, 0.5, 0.0)
    with pytest.raises(ValueError, match="top_radius_m"):
        sky.atmosphere_optical_depth(0.0, 0.5, 8000.0, 6360e3, 6000e3)


# ------------------------------------------------------------------------------------ phase functions
@pytest.mark.parametrize(
    "fn,g",
    [
        (lambda c, g: phase.rayleigh_phase(c), 0.0),
        (phase.hg_phase, 0.8),
        (phase.hg_phase, -0.5),
        (phase.cornette_shanks_phase, 0.76),
        (phase.hg_phase, 0.99),
    ],
)
def test_phase_functions_are_normalised(fn, g):
    from scipy.integrate import quad

    val, _ = quad(lambda c: 2 * math.pi * fn(c, g), -1, 1, points=[1.0 - 1e-3], limit=200)
    assert val == pytest.approx(1.0, rel=1e-6)


def test_phase_extremes_finite():
    c = np.linspace(-1, 1, 101)
    for g in (-0.999, 0.999):
        p = phase.hg_phase(c, g)
        assert np.isfinite(p).all() and (p >= 0).all()
    with pytest.raises(ValueError, match="g must be"):
        phase.hg_phase(0.0, 1.0)


# ------------------------------------------------------------------------------------------ the sky
@pytest.fixture(scope="module")
def params():
    return sky.AtmosphereParams()


@pytest.fixture(scope="module")
def quad_ref():
    """Independent float64 single-scattering quadrature (rtfit.reference.nishita_sky) for a few
    directions at sun 20°, viewer 10 m."""
    from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature

    dirs = np.array([[0, 0, 1.0], [0.6, 0.0, 0.8], [-0.6, 0.5, 0.6], [0.97, 0.1, 0.2], [0.2, -0.97, 0.12]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    spec = library_atmosphere(sun_elevation_deg=20.0, viewer_altitude_m=10.0)
    return dirs, single_scattering_quadrature(spec, dirs, steps=1500)


def test_single_scattering_converges_to_independent_quadrature(params, quad_ref):
    dirs, q = quad_ref
    fine = sky.build_sky(
        params, 20.0, 10.0, layers=128, width=512, height=256, table_size=512, mapping="sqrt"
    )
    L = sky.shade_sky(fine, dirs)
    assert np.allclose(L, q, rtol=0.012)
    seed = sky.build_sky(params, 20.0, 10.0)  # n = 32, 128×64: the seed's setting
    L = sky.shade_sky(seed, dirs)
    assert np.allclose(L, q, rtol=0.07)


def test_drjit_and_numpy_textures_agree(params):
    a = sky.build_sky(params, 5.0, 0.0, layers=16, width=32, height=16, backend="llvm")
    b = sky.build_sky(params, 5.0, 0.0, layers=16, width=32, height=16, backend="numpy")
    for x, y in zip(sky.texture_arrays(a), sky.texture_arrays(b), strict=True):
        assert np.allclose(x, y, rtol=1e-3, atol=1e-9)  # float32 (Dr.Jit) vs float64 (NumPy)


def test_frozen_device_build_replays_with_new_inputs(params):
    """The Dr.Jit build is a `dr.freeze` function: calls after the first replay recorded kernels.
    Each replay must see its own sun angle, altitude, coefficients and mapping (not the first
    call's): compare every call with the float64 NumPy build of the same inputs."""
    from dataclasses import replace

    kw = dict(layers=8, width=16, height=8, table_size=32)
    cases = [
        (params, 30.0, 0.0, "linear"),
        (params, -4.0, 0.0, "linear"),
        (replace(params, rayleigh_scale=2.0, mie_scale=0.3), 10.0, 5000.0, "linear"),
        (params, 10.0, 5000.0, "sqrt"),
        (params, 60.0, 80e3, "sqrt"),
        (params, 2.0, 10.0, "linear"),
    ]
    for p, e, h, mapping in cases:
        a = sky.build_sky(p, e, h, backend="llvm", mapping=mapping, **kw)
        b = sky.build_sky(p, e, h, backend="numpy", mapping=mapping, **kw)
        for x, y in zip(sky.texture_arrays(a), sky.texture_arrays(b), strict=True):
            assert np.allclose(x, y, rtol=2e-3, atol=1e-9 * np.max(np.abs(y))), (e, h, mapping)
        assert np.allclose(a.sun_transmittance, b.sun_transmittance, rtol=1e-12)


def test_optically_thin_limit_closed_form(params):
    """β → 0: S_k = β_k ∫ρ_k dt; straight up from h₀: β_k H_k (e^{−h₀/H_k} − e^{−top/H_k})."""
    from dataclasses import replace

    p = replace(params, rayleigh_scale=1e-6, mie_scale=1e-6)
    h0 = 100.0
    S_r, S_m = sky._inscatter_kernel(
        NUMPY_OPS,
        np.array([1.0]),
        np.array([0.5]),
        h0,
        0.5,
        sky._cfg(p, 128, 64),
        *[t.ravel() for t in sky.build_optical_depth_table(p, 128, 64)],
        p.betas(),
    )
    br, bm, _ = p.betas()
    for c in range(3):
        ref_r = br[c] * 8000.0 * (math.exp(-h0 / 8000.0) - math.exp(-TOP / 8000.0))
        ref_m = bm[c] * 1200.0 * (math.exp(-h0 / 1200.0) - math.exp(-TOP / 1200.0))
        assert float(S_r[c][0]) == pytest.approx(ref_r, rel=6e-3)  # trapezoid over 128 layers
        assert float(S_m[c][0]) == pytest.approx(ref_m, rel=6e-3)


@pytest.mark.parametrize(
    "kw",
    [
        dict(sun=0.0, alt=0.0),
        dict(sun=-4.0, alt=0.0),
        dict(sun=-30.0, alt=0.0),
        dict(sun=90.0, alt=0.0),
        dict(sun=10.0, alt=100e3),
        dict(sun=2.0, alt=30e3, layers=1),
        dict(sun=45.0, alt=0.0, g=0.999),
        dict(sun=45.0, alt=0.0, g=-0.999),
        dict(sun=45.0, alt=0.0, mie=0.0),
    ],
)
def test_extremes_finite_nonnegative(params, kw):
    from dataclasses import replace

    p = replace(params, mie_g=kw.get("g", 0.8), mie_scale=kw.get("mie", 1.0))
    s = sky.build_sky(p, kw["sun"], kw["alt"], layers=kw.get("layers", 8), width=16, height=8, table_size=16)
    R, M = sky.texture_arrays(s)
    assert np.isfinite(R).all() and np.isfinite(M).all() and (R >= 0).all() and (M >= 0).all()
    rng = np.random.default_rng(0)
    d = rng.normal(size=(400, 3))
    d = np.concatenate([d, [[1, 0, 0], [0, 0, 1], [0, 0, -1], [1, 0, 1e-9]]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    L = sky.shade_sky(s, d)
    assert np.isfinite(L).all() and (L >= 0).all()


def test_bad_sky_input(params):
    with pytest.raises(ValueError, match="layers"):
        sky.build_sky(params, 10.0, layers=0)
    with pytest.raises(ValueError, match="mapping"):
        sky.build_sky(params, 10.0, mapping="cubic")
    with pytest.raises(ValueError, match="sun_elevation_deg"):
        sky.build_sky(params, 95.0)
    with pytest.raises(ValueError, match="mie_g"):
        sky.AtmosphereParams(mie_g=1.2)
    with pytest.raises(ValueError, match="mie_extinction"):
        sky.AtmosphereParams(mie_extinction=(1e-7, 1e-7, 1e-7))


# -------------------------------------------------------------------------------- aerial perspective
def test_aerial_perspective_limits_and_sky_consistency(params, quad_ref):
    T, L = sky.aerial_perspective(
        params, 20.0, np.array([10.0]), np.array([0.3]), np.array([0.5]), np.array([0.0])
    )
    assert all(np.allclose(t, 1.0) for t in T) and all(np.allclose(x, 0.0) for x in L)
    # horizontal 20 km path near the ground: T = exp(−(β_R + β_M^ext) · 20 km) to < 1e-3 (ρ ≈ 1 there)
    T, L = sky.aerial_perspective(
        params, 20.0, np.array([0.0]), np.array([0.0]), np.array([0.5]), np.array([20e3]), steps=64
    )
    br, _, bme = params.betas()
    for c in range(3):
        assert float(T[c][0]) == pytest.approx(math.exp(-(br[c] + bme[c]) * 20e3), rel=2e-3)
    # a ray to the top of the atmosphere reproduces the sky (independent quadrature), zenith
    dirs, q = quad_ref
    s = np.array([math.cos(math.radians(20)), 0, math.sin(math.radians(20))])
    T, L = sky.aerial_perspective(
        params,
        20.0,
        np.array([10.0]),
        np.array([1.0]),
        np.array([dirs[0] @ s]),
        np.array([TOP - 10.0]),
        steps=256,
        layers=128,
        table_size=256,
    )
    assert np.allclose([float(x[0]) for x in L], q[0], rtol=0.01)


# -------------------------------------------------------------------------------------- spectral
def test_spectral_to_srgb_white_and_cmf():
    lam = np.linspace(380, 780, 401)
    ybar = sky.cie_xyz_fit(lam)[:, 1]
    assert np.trapezoid(ybar, lam) == pytest.approx(106.86, rel=0.02)  # CIE 1931 ∫ȳ dλ
    w = np.ones(16)
    rgb = sky.spectral_to_srgb(w, np.linspace(400, 700, 16), white=w, white_rgb=(1.0, 2.0, 3.0))
    assert np.allclose(rgb, [1.0, 2.0, 3.0])


def test_spectral_sky_close_to_rgb_sky(params):
    lam = np.linspace(400, 700, 16)
    ps = params.spectral(lam)
    assert ps.rayleigh_beta[0] == pytest.approx(13.558e-6 * (550 / 400) ** 4)
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.9, 0.436]])
    a = sky.shade_sky(sky.build_sky(ps, 30.0, 0.0, layers=16, width=32, height=16), d, include_sun=False)
    rgb = sky.spectral_to_srgb(
        a, lam, white=np.asarray(ps.solar_irradiance), white_rgb=params.solar_irradiance
    )
    b = sky.shade_sky(sky.build_sky(params, 30.0, 0.0, layers=16, width=32, height=16), d, include_sun=False)
    # same sky in the same units, different colour rendering: within 25 % per channel, blue sky both
    assert np.allclose(rgb, b, rtol=0.25)
    assert (rgb[:, 2] > rgb[:, 0]).all()


def test_jax_kernel_matches_numpy(params):
    """The fit's JAX path (lax.fori_loop over the same kernel text) equals the NumPy build."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    s = sky.build_sky(params, 15.0, 10.0, layers=8, width=16, height=8, table_size=32, backend="numpy")
    A, E = sky._texel_directions(16, 8, s.el_lo, s.el_hi, "linear")
    e = math.radians(15.0)
    mu = np.sin(E).ravel()
    nu = (np.cos(E) * math.cos(e) * np.cos(A) + np.sin(E) * math.sin(e)).ravel()
    tr, tm = sky.build_optical_depth_table(params, 8, 32)
    S_r, S_m = sky._inscatter_kernel(
        jax_ops(),
        jnp.asarray(mu),
        jnp.asarray(nu),
        10.0,
        math.sin(e),
        sky._cfg(params, 8, 32),
        jnp.asarray(tr.ravel()),
        jnp.asarray(tm.ravel()),
        params.betas(),
    )
    R, M = sky.texture_arrays(s)
    assert np.allclose(np.stack([np.asarray(x).reshape(8, 16) for x in S_r]), R, rtol=1e-10)
    assert np.allclose(np.stack([np.asarray(x).reshape(8, 16) for x in S_m]), M, rtol=1e-10)


def test_method_kernel_is_the_built_and_shaded_sky(params):
    """`METHODS`' one kernel text (the texture rebuilt from its inputs, then the per-pixel shading) equals
    `build_sky` + `shade_sky` (NumPy, sun excluded); its JAX run (the fit's path) equals its NumPy run; the
    fitted method at the atmosphere's own artist values is the seed method."""
    from dataclasses import replace

    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    setting = sky.SkySetting(layers=8, width=16, height=8, table_size=32)
    rng = np.random.default_rng(4)
    d = rng.normal(size=(64, 3))
    d[:, 2] = np.abs(d[:, 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    fixed = {"atmosphere": params, "setting": setting, "altitude_m": 10.0}
    seed = replace(sky.METHODS["nishita-seed"], fixed=fixed)
    fitted = replace(sky.METHODS["nishita-fitted"], fixed=fixed)
    inputs = sky.sky_kernel_inputs(params, 15.0, d, setting, 10.0)
    got = np.stack(seed(NUMPY_OPS, inputs), axis=-1)
    built = sky.build_sky(params, 15.0, 10.0, backend="numpy", **setting.build_keywords())
    assert np.allclose(got, sky.shade_sky(built, d, include_sun=False), rtol=1e-12, atol=0)
    jx = seed(jax_ops(), {k: jnp.asarray(v) for k, v in inputs.items()})
    assert np.allclose(np.stack([np.asarray(x) for x in jx], axis=-1), got, rtol=1e-10)
    own = {"rayleigh_scale": 1.0, "mie_scale": 1.0, "mie_g": params.mie_g, "ambient": params.ambient}
    assert np.array_equal(np.stack(fitted(NUMPY_OPS, inputs, own), axis=-1), got)
    assert set(sky.METHODS["nishita-fitted"].params) <= {f for f in vars(params)}  # AtmosphereParams fields


def test_disc_sun_line_reports_the_disc_term_and_its_share():
    """The study's disc-sun term on synthetic quadratures: the disc is 1 % brighter everywhere, so the
    disc term is |q − 1.01 q| / 1.01 q = 0.0099; the model (a constant 1.5e-3) has its own error against
    the disc sky, the share is their ratio, and with σ = 1e-5 per pixel the effect on the G sum is
    resolved (≥ 4 σ)."""
    from rtfit.experiments import nishita_sky_study as st
    from rtfit.reference.nishita_sky import hemisphere_directions

    w, h = 32, 16
    dirs = hemisphere_directions(w, h)[0]
    sl = st._subset((4, 2))
    mask = ~st.near_sun(dirs, -4.0)
    keep = mask[sl]
    q = np.random.default_rng(0).uniform(1e-3, 2e-3, dirs[sl].shape)
    images = {m: np.full((h, w, 3), 1.5e-3) for m in st.RGB}
    ss = (np.full((h, w, 3), 1e-3), np.full((h, w, 3), 1e-5))
    s = st.Sky(-4.0, None, dirs, mask, ss, ss, 1024, images, None, "sky")
    checks = []
    row = st._disc_line(s, {"value": q, "disc": q * 1.01}, keep, sl, checks)
    assert len(checks) == 1 and checks[0].name.startswith("sun -4°")
    assert row[:3] == ["-4°", "0.0099", "0.0099"] and "(resolved)" in row[4]
    tot = np.abs(1.5e-3 - 1.01 * q[keep]).sum() / (1.01 * q[keep]).sum()  # the model's error, all channels
    assert f"{tot:.3g} (disc share {(0.01 / 1.01) / tot:.2g})" in row[3]


def test_the_fits_dr_jit_residual_recovers_known_artist_parameters():
    """`Method.fit_ops` "drjit" (issue 33): the TRF fit evaluates the kernel text on float64 Dr.Jit arrays
    with opaque parameters. A sky made with known artist parameters (s_R 1.3, s_M 2.0, g 0.7, A 0.4) on a
    small texture is fitted from the declared start: the fit returns those values (the data are exact, so
    to the solver's tolerance), and it compiled one kernel per evaluation shape, not one per value."""
    import dataclasses

    import drjit as dr

    from rtfit.fitting import fit_method
    from rtfit.reference.nishita_sky import hemisphere_directions

    m = sky.METHODS["nishita-fitted"]
    assert m.fit_ops == "drjit"
    setting = dataclasses.replace(m.fixed["setting"], layers=8, width=32, height=16, table_size=32)
    small = dataclasses.replace(m, fixed={**m.fixed, "setting": setting, "altitude_m": 10.0})
    d = hemisphere_directions(16, 8)[0].reshape(-1, 3)
    inputs = sky.sky_kernel_inputs(sky.AtmosphereParams(), 20.0, d, setting, 10.0)
    truth = {"rayleigh_scale": 1.3, "mie_scale": 2.0, "mie_g": 0.7, "ambient": 0.4}
    target = np.stack(small(NUMPY_OPS, inputs, truth))
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # (clears it)
    res = fit_method(small, inputs, target, solver="trf")
    # compiled kernels only (reading a parameter's value for the in-scatter's reuse is a memcpy, no kernel)
    launches = [h for h in dr.kernel_history() if h.get("size", 0) > 1 and h["type"] == dr.KernelType.JIT]
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    for k, v in truth.items():
        assert res.values[k] == pytest.approx(v, rel=1e-6), k
    assert res.steps >= 3 and len({(h["hash"], h["size"]) for h in launches}) <= 8


def test_inscatter_store_serves_the_jacobians_centre(monkeypatch):
    """`_inscatter_reused` (issue 33): in the order SciPy's 3-point Jacobian evaluates (the centre x, then
    x ± h for s_R, s_M, g and A in turn) the in-scatter texture is computed 5 times, not 7 (a store of the
    last texture only: g's first step follows s_M's +h) or 9; every result equals the same evaluation on
    freshly converted inputs (no texture to reuse), bit for bit."""
    import dataclasses

    import drjit as dr

    from rtfit.realtime.arrays import DRJIT_OPS, backend_float, to_drjit
    from rtfit.reference.nishita_sky import hemisphere_directions

    m = sky.METHODS["nishita-fitted"]
    setting = dataclasses.replace(m.fixed["setting"], layers=8, width=32, height=16, table_size=32)
    small = dataclasses.replace(m, fixed={**m.fixed, "setting": setting, "altitude_m": 10.0})
    d = hemisphere_directions(16, 8)[0].reshape(-1, 3)
    inputs = sky.sky_kernel_inputs(sky.AtmosphereParams(), 20.0, d, setting, 10.0)
    Float = backend_float(None, np.float64)

    def converted():
        return {k: to_drjit(Float, v) if isinstance(v, np.ndarray) else v for k, v in inputs.items()}

    def run(x, p):
        out = small(DRJIT_OPS, x, {k: dr.opaque(Float, v) for k, v in p.items()})
        return np.stack([np.asarray(c, np.float64) for c in out])

    centre = {"rayleigh_scale": 1.1, "mie_scale": 1.7, "mie_g": 0.75, "ambient": 0.3}
    order = [centre] + [{**centre, k: centre[k] + s * 1e-3} for k in centre for s in (-1, 1)]
    computed = []
    inner = sky._inscatter_kernel
    monkeypatch.setattr(sky, "_inscatter_kernel", lambda *a: computed.append(1) or inner(*a))
    x = converted()
    got = [run(x, p) for p in order]
    assert len(computed) == 5
    for p, g in zip(order, got, strict=True):
        assert np.array_equal(run(converted(), p), g)
    assert len(computed) == 5 + len(order)
