"""rtfit.realtime.ambient_dice against independent values: icosahedron geometry, the partition of unity (from
the 2- and 4-design sums, not from the kernel), a constant environment reproduced exactly, least squares on
a function in the span, extremes, and the Dr.Jit LLVM run against the NumPy text."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import ambient_dice as ad
from rtfit.realtime.irradiance_bases import basis_inputs, basis_irradiance, fibonacci_sphere


def test_vertices_are_a_regular_icosahedron():
    v = np.array(ad.DICE_VERTICES)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-15)
    c = v @ v.T
    np.fill_diagonal(c, 2.0)
    # each vertex: 5 neighbours at cos = 1/√5, 5 at −1/√5, one antipode
    for row in c:
        assert np.sum(np.isclose(row, 1 / math.sqrt(5))) == 5
        assert np.sum(np.isclose(row, -1 / math.sqrt(5))) == 5
        assert np.sum(np.isclose(row, -1.0)) == 1


def test_design_sums_and_partition_of_unity():
    # Σ (v·n)² = 4 and Σ (v·n)⁴ = 12/5 over the 12 vertices for any unit n (spherical 5-design), so the
    # weights α·½c² + (1 − α)(5/6)c⁴ sum to 1; checked against direct sums, then the kernel's weights
    v = np.array(ad.DICE_VERTICES)
    n = fibonacci_sphere(500)
    d = n @ v.T
    np.testing.assert_allclose((d**2).sum(1), 4.0, atol=1e-13)
    np.testing.assert_allclose((d**4).sum(1), 12 / 5, atol=1e-13)
    c = np.maximum(d, 0.0)
    direct = 0.7 * 0.5 * c**2 + 0.3 * (5 / 6) * c**4
    np.testing.assert_allclose(ad.dice_design_matrix(n), direct, atol=1e-15)
    np.testing.assert_allclose(direct.sum(1), 1.0, atol=1e-14)  # measured 9e-16


def test_constant_environment_is_exact():
    # a constant environment of radiance L has E = πL at every normal; the fitted values are πL and the
    # reconstruction is exact (partition of unity)
    n = fibonacci_sphere(512)
    radiance = np.array([1.0, 0.5, 2.0])
    values, rms = ad.fit_ambient_dice(n, np.repeat((math.pi * radiance)[None], 512, 0))
    np.testing.assert_allclose(values, np.repeat((math.pi * radiance)[None], 12, 0), rtol=1e-12)
    assert np.all(rms < 1e-12)
    other = np.random.default_rng(0).normal(size=(300, 3))
    e = basis_irradiance(ad.DICE_METHODS["ambient-dice"], values, other)
    np.testing.assert_allclose(e, np.repeat((math.pi * radiance)[None], 300, 0), rtol=1e-13)


def test_least_squares_recovers_values_in_span():
    rng = np.random.default_rng(4)
    truth = rng.uniform(0.0, 3.0, (12, 3))
    n = fibonacci_sphere(1000)
    target = ad.dice_design_matrix(n) @ truth
    values, rms = ad.fit_ambient_dice(n, target)
    np.testing.assert_allclose(values, truth, atol=1e-11)  # measured 2e-14
    assert np.all(rms < 1e-12)


def test_vertex_value_and_locality():
    # at a vertex: its own weight 0.7/2 + 0.3·5/6 = 0.6, five neighbours share the rest equally, the far
    # half is zero (local support: 6 of 12 values are read)
    v = np.array(ad.DICE_VERTICES)
    w = ad.dice_design_matrix(v[:1])[0]
    assert w[0] == pytest.approx(0.6)
    c = 1 / math.sqrt(5)
    assert np.sum(np.isclose(w, 0.35 * c**2 + 0.25 * c**4)) == 5
    assert np.sum(w == 0.0) == 6


@settings(max_examples=50, deadline=None)
@given(
    x=st.floats(-1e3, 1e3),
    y=st.floats(-1e3, 1e3),
    z=st.floats(-1e3, 1e3),
    scale=st.one_of(st.just(0.0), st.floats(1e-300, 1e6)),
)  # no subnormals
def test_property_convex_combination(x, y, z, scale):
    # weights ≥ 0 summing to 1: the reconstruction lies between the smallest and largest stored value
    if x * x + y * y + z * z <= 1e-20:
        return
    vals = np.linspace(0.1, 1.2, 36).reshape(3, 12).T * scale
    m = ad.DICE_METHODS["ambient-dice"]
    e = np.array(m(NUMPY_OPS, basis_inputs(m, vals, np.array([[x, y, z]])), None)).reshape(3)
    assert np.all(np.isfinite(e))
    assert np.all(e >= vals.min(0) * (1 - 1e-12)) and np.all(e <= vals.max(0) * (1 + 1e-12))


def test_drjit_llvm_matches_numpy_text_and_zero_normal():
    import drjit as dr

    m = ad.DICE_METHODS["ambient-dice"]
    rng = np.random.default_rng(6)
    n = rng.normal(size=(64, 3))
    vals = rng.uniform(0.0, 2.0, (12, 3))
    want = np.stack(m(NUMPY_OPS, basis_inputs(m, vals, n), None), -1)
    got = np.stack([np.asarray(c) for c in basis_irradiance(m, vals, dr.llvm.Array3f64(n.T))], -1)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)
    zero = basis_irradiance(m, vals, dr.llvm.Array3f([0.0], [0.0], [0.0]))
    np.testing.assert_allclose([float(c[0]) for c in zero], vals.mean(0), rtol=1e-6)  # the sphere mean
    with pytest.raises(ValueError, match="non-zero length"):
        basis_irradiance(m, vals, np.zeros(3))
    with pytest.raises(ValueError, match="shape"):
        ad.fit_ambient_dice(n, np.ones((5, 3)))
    assert m.storage == 36
