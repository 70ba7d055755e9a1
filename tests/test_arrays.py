"""The three ops namespaces (Dr.Jit, NumPy, JAX) agree name by name, and `evaluate` dispatches JAX arrays.

Oracle: NumPy's float64 functions (each tolerance is a few float64 ulp, measured maximum in the comment),
and for Dr.Jit's own expm1/log1p rewrites mpmath at 50 digits."""

from __future__ import annotations

import math

import drjit as dr
import mpmath as mp
import numpy as np
import pytest

from rtfit.realtime import arrays
from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS, OP_NAMES, evaluate, jax_ops

jax = pytest.importorskip("jax")
jnp = jax.numpy
jax.config.update("jax_enable_x64", True)

X = np.array([-3.0, -0.7, -1e-9, 0.0, 1e-12, 0.3, 0.9, 2.5, 40.0])
POS = np.array([1e-300, 1e-9, 0.25, 1.0, 3.0, 1e8])
UNIT = np.array([-1.0, -0.5, -1e-8, 0.0, 0.2, 0.999, 1.0])

ARGS = {
    "sqrt": (POS,), "cbrt": (X,), "exp": (X,), "log": (POS,), "expm1": (X,), "log1p": (POS,),
    "power": (POS, 1.7), "sin": (X,), "cos": (X,), "tan": (UNIT,), "asin": (UNIT,), "acos": (UNIT,),
    "atan": (X,), "atan2": (X, X[::-1]), "tanh": (X,), "abs": (X,), "floor": (X,), "ceil": (X,),
    "maximum": (X, 0.1), "minimum": (X, 0.1), "clip": (X, -0.5, 0.5), "fma": (X, 2.0, X[::-1]),
    "select": (X > 0, X, -X), "gather": (X, np.array([0.0, 3.0, 8.0, 2.9])),
}  # fmt: skip


def test_every_name_has_arguments_here():
    assert set(ARGS) == set(OP_NAMES)
    assert set(vars(jax_ops())) == set(vars(NUMPY_OPS)) == set(vars(DRJIT_OPS))


@pytest.mark.parametrize("name", OP_NAMES)
def test_three_libraries_agree(name):
    args = ARGS[name]
    want = np.asarray(getattr(NUMPY_OPS, name)(*args), dtype=np.float64)
    got_jax = np.asarray(
        getattr(jax_ops(), name)(*[jnp.asarray(a) if isinstance(a, np.ndarray) else a for a in args])
    )

    def to_dr(a):
        if isinstance(a, np.ndarray):
            return dr.llvm.Bool(a) if a.dtype == bool else dr.llvm.Float64(a)
        return a

    got_dr = np.asarray(getattr(DRJIT_OPS, name)(*[to_dr(a) for a in args]), dtype=np.float64)
    # Measured: ≤ 2 ulp relative everywhere (Dr.Jit's LLVM float64 tan/atan2 ≈ 1e-16); 1e-14 leaves room.
    np.testing.assert_allclose(got_jax, want, rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(got_dr, want, rtol=1e-14, atol=1e-300)


@pytest.mark.parametrize("x", [0.0, 1e-30, -1e-20, 1e-8, -3e-6, 1e-3, 0.4, -0.9, 5.0, 700.0, -745.0])
def test_drjit_expm1_log1p_against_mpmath(x):
    mp.mp.dps = 50
    for fn, ref in ((DRJIT_OPS.expm1, mp.expm1), (DRJIT_OPS.log1p, mp.log1p)):
        if fn is DRJIT_OPS.log1p and x <= -1:
            continue
        got = fn(dr.llvm.Float64([x]))[0]
        want = float(ref(mp.mpf(x)))
        # Kahan's rewrites: measured ≤ 4e-16 relative on LLVM float64 at these points.
        assert got == pytest.approx(want, rel=2e-15, abs=1e-320), (fn, x)
    got32 = DRJIT_OPS.expm1(dr.llvm.Float([1e-6]))[0]
    assert got32 == pytest.approx(math.expm1(1e-6), rel=3e-7)  # float32: a few ulp, not 1 − e^x cancellation


def test_drjit_expm1_log1p_extremes_are_finite_or_the_limits():
    e = np.asarray(DRJIT_OPS.expm1(dr.llvm.Float64([math.inf, -math.inf, 1000.0, -1000.0])))
    assert e[0] == math.inf and e[1] == -1.0 and e[2] == math.inf and e[3] == -1.0
    lp = np.asarray(DRJIT_OPS.log1p(dr.llvm.Float64([math.inf, -1.0, 1e300])))
    assert lp[0] == math.inf and lp[1] == -math.inf and lp[2] == pytest.approx(math.log(1e300))


def test_jax_power_gradient_is_finite_at_zero_base():
    ops = jax_ops()
    g = jax.grad(lambda p: jnp.sum(ops.power(jnp.asarray([0.0, 0.5, 2.0]), p)))(1.5)
    assert math.isfinite(float(g))
    # d/dp Σ x^p = Σ x^p ln x (the x = 0 term is 0)
    assert float(g) == pytest.approx(0.5**1.5 * math.log(0.5) + 2.0**1.5 * math.log(2.0), rel=1e-12)


def test_evaluate_runs_the_jax_text_on_jax_arrays_and_differentiates():
    def kernel(ops, x, a):
        return ops.exp(-a * x) * ops.sqrt(x)

    x = np.linspace(0.1, 2.0, 5)
    out = evaluate(kernel, jnp.asarray(x), 0.7)
    assert isinstance(out, jax.Array)
    np.testing.assert_allclose(np.asarray(out), np.exp(-0.7 * x) * np.sqrt(x), rtol=1e-15)
    g = jax.grad(lambda a: jnp.sum(evaluate(kernel, jnp.asarray(x), a)))(0.7)
    assert float(g) == pytest.approx(float(np.sum(-x * np.exp(-0.7 * x) * np.sqrt(x))), rel=1e-13)


def test_jax_is_not_imported_by_the_package(tmp_path):
    import subprocess
    import sys

    code = "import sys, rtfit.realtime, rtfit.fitting; print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    assert arrays.ops_for("numpy") is NUMPY_OPS
    with pytest.raises(ValueError, match="unknown array library"):
        arrays.ops_for("torch")


def test_aligned_copy_of_views_is_the_flattened_array_in_c_order():
    """`aligned_copy` writes straight from a broadcast or transposed view (issue 33: no flattened copy first):
    the values are NumPy's C-order flattening converted to the dtype, bit for bit, the first at a 64-byte
    boundary."""
    from rtfit.realtime.arrays import aligned_copy

    rng = np.random.default_rng(4)
    col = rng.standard_normal((37, 1))
    views = [np.broadcast_to(col, (37, 53)), rng.standard_normal((29, 31)).T, np.float64(2.5), [1, 2, 3]]
    for v in views:
        for dtype in (np.float32, np.float64):
            got = aligned_copy(v, dtype)
            want = np.ascontiguousarray(v).reshape(-1).astype(dtype)
            assert got.dtype == dtype and got.ctypes.data % 64 == 0
            assert np.array_equal(got, want)
