"""`rtfit.realtime.nonnegative_lsq`: the non-negative least-squares minimiser, checked against its optimality
conditions (Karush–Kuhn–Tucker: x ≥ 0; the gradient Aᵀ(b − Ax) ≈ 0 where x > 0 and ≤ 0 where x = 0) and
against SciPy's ``scipy.optimize.nnls`` (an independent implementation of Lawson–Hanson), on random,
rank-deficient, zero-column, underdetermined and all-negative problems; `nnls_columns` the same column by
column, and the cube fits built on it against their closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import irradiance_bases as ir
from rtfit.realtime.nonnegative_lsq import ENUMERATE_MAX, nnls, nnls_columns

scipy_optimize = pytest.importorskip("scipy.optimize")


_ROUNDING = 1e-9
"""Two solvers' minima of ‖Ax − b‖ differ by their rounding, ~κ(A_S)·ε·‖b‖ on the support S they solve
(hypothesis found 1.8e-12·‖b‖ between SciPy's QR and this module's SVD where the exact fit is 0): 1e-9·‖b‖
allows condition numbers up to ~10⁶, far beyond these random columns'."""


def _problem(seed: int, m: int, n: int, scale: float, kind: str):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, n))
    if kind == "zero-column":
        a[:, rng.integers(0, n)] = 0.0
    elif kind == "dependent" and n > 1:
        a[:, -1] = 2.0 * a[:, 0]
    b = rng.normal(size=m) * scale
    if kind == "negative":
        b = -np.abs(a).sum(axis=1) * scale  # every column points away from b: x = 0
        a = np.abs(a)
    return a, b


def _kkt_holds(a, b, x, rtol=1e-9) -> bool:
    g = a.T @ (b - a @ x)  # −∇(½‖Ax − b‖²)
    tol = rtol * (np.abs(a).sum() * (np.abs(b).max() + 1.0) + 1.0)
    return bool(np.all(x >= 0.0) and np.all(np.abs(g[x > 0]) <= tol) and np.all(g[x == 0] <= tol))


@settings(max_examples=300, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    m=st.integers(1, 40),
    n=st.integers(1, 12),
    scale=st.sampled_from([1e-6, 1.0, 1e6]),
    kind=st.sampled_from(["plain", "zero-column", "dependent", "negative"]),
)
def test_nnls_is_the_minimiser_scipy_finds(seed, m, n, scale, kind):
    a, b = _problem(seed, m, n, scale, kind)
    x, r = nnls(a, b)
    _xs, rs = scipy_optimize.nnls(a, b)
    assert _kkt_holds(a, b, x)
    assert r == pytest.approx(np.linalg.norm(a @ x - b), rel=1e-12, abs=1e-300)
    slack = _ROUNDING * np.linalg.norm(b)
    assert r <= rs + slack, "no worse than SciPy's"
    assert rs <= r + slack, "no better: the same minimum"
    if kind == "negative":
        assert not x.any()


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    m=st.integers(1, 30),
    n=st.integers(1, ENUMERATE_MAX + 2),
    cols=st.integers(0, 6),
    kind=st.sampled_from(["plain", "zero-column", "dependent"]),
)
def test_nnls_columns_is_nnls_of_each_column(seed, m, n, cols, kind):
    """By the supports up to `ENUMERATE_MAX` unknowns, column by column beyond: each column the minimum."""
    a, _ = _problem(seed, m, n, 1.0, kind)
    b = np.random.default_rng(seed + 1).normal(size=(m, cols))
    x = nnls_columns(a, b)
    assert x.shape == (n, cols)
    for j in range(cols):
        assert _kkt_holds(a, b[:, j], x[:, j])
        rs = scipy_optimize.nnls(a, b[:, j])[1]
        assert np.linalg.norm(a @ x[:, j] - b[:, j]) <= rs + _ROUNDING * np.linalg.norm(b[:, j])


def test_bad_input_is_refused_with_one_line():
    with pytest.raises(ValueError, match="must be"):
        nnls(np.ones((3, 2)), np.ones(4))
    with pytest.raises(ValueError, match="finite"):
        nnls(np.array([[1.0, np.nan]]), np.ones(1))
    with pytest.raises(ValueError, match="must be"):
        nnls_columns(np.ones((3, 2)), np.ones(3))


def test_the_cube_fits_recover_a_non_negative_cube_and_clip_a_negative_one():
    """A cube C ≥ 0 is E_cube's own minimiser (residual 0); one with a negative entry is not reachable:
    the fit is the KKT point of the clamped problem. The batched fit gives each probe's single fit."""
    n = ir.fibonacci_sphere(64)
    rng = np.random.default_rng(5)
    cubes = rng.uniform(0.0, 2.0, size=(4, 6, 3))
    cubes[1, 2, 0] = -0.5  # probe 1, channel 0: not a cube of non-negative colours
    design = ir.cube_design_matrix(n)
    e = np.einsum("nk,pkc->pnc", design, cubes)
    batched = ir.fit_ambient_cubes_nnls(n, e)
    for p in range(4):
        single, rms = ir.fit_ambient_cube_nnls(n, e[p])
        np.testing.assert_allclose(batched[p], single, rtol=0, atol=1e-12)
        for c in range(3):
            assert _kkt_holds(design, e[p, :, c], single[:, c])
        if p != 1:
            np.testing.assert_allclose(single, cubes[p], atol=1e-10)
            assert np.all(rms < 1e-10)
    assert batched[1, 2, 0] == 0.0 and ir.fit_ambient_cube_nnls(n, e[1])[1][0] > 1e-3
