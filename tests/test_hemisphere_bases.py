"""H-basis and radiosity normal mapping (rtfit.realtime.hemisphere_bases) against independent values.

Oracles: the H-basis polynomials written out here from Habel & Wimmer 2010's appendix (H1 = 1/√(2π),
H3 = √(3/(2π))(2z − 1), …), a fine midpoint rule in (cos θ, φ) (not the module's Gauss–Legendre rule),
the closed-form irradiance of a uniform upper-hemisphere sky, E(n) = πL(1 + n_z)/2, and Valve's basis
written as numbers (0.81649658 = √(2/3), 0.40824829 = 1/√6, 0.70710678 = 1/√2, 0.57735027 = 1/√3).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS, set_default_backend
from rtfit.realtime.hemisphere_bases import (
    HEMISPHERE_METHODS,
    RNM_BASIS,
    hbasis_design_matrix,
    hbasis_project,
    hemisphere_irradiance,
    hemisphere_quadrature,
    rnm_lightmaps_from,
    surface_frame,
    to_tangent,
)
from rtfit.realtime.irradiance_bases import basis_inputs

TWO_PI = 2.0 * math.pi


def h_oracle(n):
    """H1..H6 at unit tangent-space normals (N, 3), typed from the paper's appendix."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    return np.stack(
        [
            np.full_like(x, 1.0 / math.sqrt(TWO_PI)),
            -math.sqrt(3.0 / TWO_PI) * y,
            math.sqrt(3.0 / TWO_PI) * (2.0 * z - 1.0),
            -math.sqrt(3.0 / TWO_PI) * x,
            math.sqrt(15.0 / TWO_PI) * x * y,
            0.5 * math.sqrt(15.0 / TWO_PI) * (x * x - y * y),
        ],
        axis=-1,
    )


def midpoint_hemisphere(n_mu, n_phi):
    """Midpoint rule in (μ = cos θ, φ) over the hemisphere: weights (1/n_mu)(2π/n_phi)."""
    mu = (np.arange(n_mu) + 0.5) / n_mu
    phi = (np.arange(n_phi) + 0.5) * TWO_PI / n_phi
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - mm * mm)
    d = np.stack([s * np.cos(pp), s * np.sin(pp), mm], axis=-1).reshape(-1, 3)
    return d, np.full(len(d), TWO_PI / (n_mu * n_phi))


def random_hemisphere(rng, count):
    v = rng.normal(size=(count, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


def numpy_eval(method_id, coeffs, normals):
    m = HEMISPHERE_METHODS[method_id]
    return np.stack(m(NUMPY_OPS, basis_inputs(m, coeffs, normals)), axis=-1)


# =========================================================================================== H-basis
def test_hbasis_values_match_the_papers_functions():
    n = random_hemisphere(np.random.default_rng(1), 200)
    np.testing.assert_allclose(hbasis_design_matrix(n, 6), h_oracle(n), rtol=0, atol=1e-14)
    np.testing.assert_allclose(hbasis_design_matrix(n, 4), h_oracle(n)[:, :4], rtol=0, atol=1e-14)


def test_hbasis_is_orthonormal_on_the_hemisphere():
    d, w = midpoint_hemisphere(200, 400)
    h = hbasis_design_matrix(d, 6)
    gram = h.T @ (h * w[:, None])
    # midpoint rule, O(h²): measured max |G − I| = 2.5e-5 at 200 × 400
    np.testing.assert_allclose(gram, np.eye(6), rtol=0, atol=1e-4)


def test_module_rule_integrates_the_hemisphere():
    d, w = hemisphere_quadrature(16, 32)
    assert abs(w.sum() - TWO_PI) < 1e-12
    assert np.all(d[:, 2] > 0) and np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
    assert abs(np.sum(w * d[:, 2]) - math.pi) < 1e-12  # ∫ cos θ dω = π


def test_hbasis_reconstructs_a_function_it_represents_exactly():
    rng = np.random.default_rng(7)
    alpha = rng.normal(size=(6, 3))
    d, w = midpoint_hemisphere(200, 400)
    f = h_oracle(d) @ alpha
    c = hbasis_project(d, w, f, 6)
    # midpoint-rule error of the projection (200 × 400): measured max 3.4e-5
    np.testing.assert_allclose(c, alpha, rtol=0, atol=1e-4)
    n = random_hemisphere(rng, 300)
    got = hemisphere_irradiance("hbasis-6", alpha, n)
    np.testing.assert_allclose(got, h_oracle(n) @ alpha, rtol=1e-12, atol=1e-12)


def test_hbasis_uniform_sky_is_exact_with_four_terms():
    """A sky of radiance L over the world's upper hemisphere, frame z up: E(n) = πL(1 + n_z)/2, which is
    H1 and H3 only: c1 = πL·(3/4)√(2π), c3 = πL·(1/4)/√(3/(2π))."""
    L = 1.7
    d, w = hemisphere_quadrature(16, 32)
    e = math.pi * L * (1.0 + d[:, 2]) / 2.0
    c = hbasis_project(d, w, e, 6)[:, 0]
    expect = [
        math.pi * L * 0.75 * math.sqrt(TWO_PI),
        0.0,
        math.pi * L * 0.25 / math.sqrt(3.0 / TWO_PI),
        0,
        0,
        0,
    ]
    np.testing.assert_allclose(c, expect, rtol=0, atol=1e-12)
    n = random_hemisphere(np.random.default_rng(3), 100)
    for m in ("hbasis-4", "hbasis-6"):
        got = hemisphere_irradiance(m, c[: int(m[-1])], n)[:, 0]
        np.testing.assert_allclose(got, math.pi * L * (1.0 + n[:, 2]) / 2.0, rtol=1e-12)


# =========================================================================================== RNM
def test_rnm_basis_is_valves_orthonormal_basis():
    b = np.array(RNM_BASIS)
    expect = [
        [0.816496580927726, 0.0, 0.5773502691896258],
        [-0.408248290463863, 0.7071067811865476, 0.5773502691896258],
        [-0.408248290463863, -0.7071067811865476, 0.5773502691896258],
    ]
    np.testing.assert_allclose(b, expect, rtol=0, atol=1e-15)
    np.testing.assert_allclose(b @ b.T, np.eye(3), rtol=0, atol=1e-15)
    np.testing.assert_allclose(b.sum(axis=0), [0.0, 0.0, math.sqrt(3.0)], atol=1e-15)
    assert np.linalg.det(b) > 0


@pytest.mark.parametrize("weighting", ["linear", "squared", "normalized"])
def test_rnm_weights_at_the_basis_directions_pick_one_lightmap(weighting):
    lm = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])  # rows E_0..E_2, RGB
    got = numpy_eval(f"rnm-{weighting}", lm, np.array(RNM_BASIS))
    np.testing.assert_allclose(got, lm, rtol=1e-15, atol=1e-15)


def test_rnm_constant_environment():
    E = 2.5  # a constant environment: every lightmap holds πL = E
    lm = np.full((3, 3), E)
    n = np.concatenate(
        [random_hemisphere(np.random.default_rng(5), 2000), [[1, 0, 0], [0, 1, 0], [0.6, 0.8, 0]]]
    )
    np.testing.assert_allclose(numpy_eval("rnm-normalized", lm, n), E, rtol=1e-14)
    inside = np.all(n @ np.array(RNM_BASIS).T >= 0.0, axis=1)  # the cone where every n·b_i ≥ 0
    assert 100 < inside.sum() < len(n)
    np.testing.assert_allclose(numpy_eval("rnm-squared", lm, n[inside]), E, rtol=1e-14)
    assert np.all(numpy_eval("rnm-squared", lm, n[~inside]) < E)
    lin = numpy_eval("rnm-linear", lm, n[inside])[:, 0]
    np.testing.assert_allclose(lin, math.sqrt(3.0) * n[inside, 2] * E, rtol=1e-14)


def test_rnm_lightmaps_from_an_irradiance_function():
    lm = rnm_lightmaps_from(lambda d: np.stack([d[:, 0], d[:, 1], d[:, 2]], axis=-1))
    np.testing.assert_allclose(lm, np.array(RNM_BASIS), atol=0)


# =========================================================================================== frames
def test_surface_frame_is_right_handed_and_orthonormal():
    n = np.array([0.3, -0.5, 0.8])
    f = surface_frame(n)
    np.testing.assert_allclose(f @ f.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(f[2], n / np.linalg.norm(n), atol=1e-15)
    assert np.linalg.det(f) > 0
    np.testing.assert_allclose(to_tangent(f, f[2]), [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(
        surface_frame([1.0, 0, 0]) @ surface_frame([1.0, 0, 0]).T, np.eye(3), atol=1e-15
    )
    with pytest.raises(ValueError, match="normal"):
        surface_frame([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="unknown hemisphere basis"):
        hemisphere_irradiance("hbasis-5", np.zeros((6, 3)), [0.0, 0.0, 1.0])


# =========================================================================================== domains
normals_incl_grazing = st.tuples(
    st.one_of(st.floats(0.0, math.pi / 2), st.just(math.pi / 2), st.just(0.0)),
    st.floats(0.0, 2.0 * math.pi),
)


@settings(max_examples=50, deadline=None)
@given(normals_incl_grazing, st.sampled_from(sorted(HEMISPHERE_METHODS)))
def test_every_basis_is_finite_over_the_hemisphere_incl_grazing(angles, method_id):
    th, ph = angles
    n = np.array([[math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]])
    rng = np.random.default_rng(0)
    coeffs = rng.uniform(0.0, 3.0, (6 if method_id == "hbasis-6" else 4 if method_id == "hbasis-4" else 3, 3))
    got = numpy_eval(method_id, coeffs, n)
    assert np.all(np.isfinite(got))
    if method_id.startswith("rnm"):  # non-negative weights of non-negative lightmaps
        assert np.all(got >= 0.0)
        if method_id == "rnm-normalized":  # a convex combination of the lightmaps
            assert np.all(got <= coeffs.max(axis=0) * (1 + 1e-12))


def test_float32_grazing_and_zero_normals_stay_finite():
    set_default_backend("llvm")
    n = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 1e-30], [0.0, 0.0, 1.0], [0.7071, 0.7071, 0.0]], np.float32)
    for m in HEMISPHERE_METHODS:
        rows = (HEMISPHERE_METHODS[m].storage or 0) // 3
        got = hemisphere_irradiance(m, np.ones((rows, 3)), n)
        assert got.dtype == np.float32 and np.all(np.isfinite(got))


# =========================================================================================== one text
@pytest.mark.parametrize("method_id", sorted(HEMISPHERE_METHODS))
def test_drjit_and_numpy_run_the_same_text(method_id):
    set_default_backend("llvm")
    rng = np.random.default_rng(11)
    rows = (HEMISPHERE_METHODS[method_id].storage or 0) // 3
    coeffs = rng.uniform(0.1, 2.0, (rows, 3))
    n = random_hemisphere(rng, 512)
    dr_out = hemisphere_irradiance(method_id, coeffs, n)  # NumPy float64 in → Dr.Jit LLVM Float64
    np_out = numpy_eval(method_id, coeffs, n)
    # measured max |Δ| = 0.0 here (float64 on both sides); the bound allows for fused multiply-adds
    np.testing.assert_allclose(dr_out, np_out, rtol=1e-13, atol=1e-13)


# =========================================================================================== the bake
def test_bake_in_a_tilted_frame_reproduces_a_linear_irradiance():
    """The experiment's bake (rtfit.experiments.irradiance_hemisphere) in its tilted frame: a uniform sky
    over the world's upper hemisphere, E(n) = πL(1 + n_z)/2, is linear in the tangent-space normal too,
    so the 4-term H-basis reproduces it (world → tangent → world round trip), and the RNM lightmaps are E
    at the world images of Valve's directions."""
    from rtfit.experiments.irradiance_hemisphere import FRAMES, bake_frame

    def sky(world):
        return np.repeat((math.pi * 1.3 * (1.0 + world[:, 2]) / 2.0)[:, None], 3, axis=1)

    frame = surface_frame(FRAMES[1][1])
    texel = bake_frame(frame, sky, (8, 16))
    n = random_hemisphere(np.random.default_rng(2), 400) @ frame  # tangent hemisphere → world
    for m in ("hbasis-4", "hbasis-6"):
        got = hemisphere_irradiance(m, texel[m], to_tangent(frame, n))
        np.testing.assert_allclose(got, sky(n), rtol=1e-12)
    np.testing.assert_allclose(texel["rnm"], sky(np.array(RNM_BASIS) @ frame), rtol=1e-15)


def test_fitted_lightmap_file_loads_and_its_shader_literals_are_the_texel(tmp_path):
    """The experiment's fitted file: it passes the ``rtfit.fitted/1`` loader, and the traced GLSL of the
    normalised RNM carries the texel's lightmaps (float32 literals) in the order of the kernel."""
    from rtfit.experiments.fitted import load_fitted
    from rtfit.experiments.irradiance_hemisphere import write_fitted

    lm = [[1.25, 2.5, 3.75], [0.5, 0.625, 0.75], [4.0, 4.5, 5.0]]  # rows E_0..E_2, RGB
    rec = {"environment": "env", "frame": "up", "geometric_normal": [0.0, 0.0, 1.0], "rnm_lightmaps": lm}
    rec["hbasis_6"] = np.arange(18.0).reshape(6, 3).tolist()
    (name,) = write_fitted(tmp_path, [rec])
    doc = load_fitted(tmp_path / name)
    assert [m.id for m in doc.methods] == [f"{m}-up" for m in HEMISPHERE_METHODS]
    glsl = next(m for m in doc.methods if m.id == "rnm-normalized-up").shader.glsl
    for v in ("1.25", "0.5", "4.0", "2.5", "0.625", "4.5"):
        assert f" {v}" in glsl or f"({v}" in glsl
