"""A method's numbers (free parameters, scalar inputs) reach Dr.Jit's kernels as opaque values, so one kernel
serves every value; a cost folds them into the kernel as literals (issue 33, session 32).

Oracles: Dr.Jit's own kernel hashes (``dr.kernel_history()``) for what is compiled; Dr.Jit's ``power`` of a
number exponent (its own products, another code path than `_dr_power`'s selected ones) for the bits of a
whole power; NumPy's ``power`` for the signs and special values; the closed form of wrap lighting in float64
for the values."""

from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest
from drjit.llvm import Float

from rtfit.realtime.arrays import DRJIT_OPS, POWER_PRODUCT_BITS, evaluate
from rtfit.realtime.diffuse import METHODS

WRAP = METHODS["wrap"]


def _kernel_hashes(run) -> list[str]:
    """The hashes of the JIT kernels ``run()`` launches, in order."""
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()  # (emptied)
        run()
        return [h["hash"] for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]


@pytest.fixture(scope="module")
def cosines() -> np.ndarray:
    return np.linspace(-1.0, 1.0, 257).astype(np.float32)


def test_one_kernel_serves_every_parameter_value(cosines):
    """Wrap lighting at three (w, p) and two irradiances: one kernel hash; each value the closed form
    E·max((c + w)/(1 + w), 0)^p within float32 rounding."""
    hashes = []
    for w, p, e in ((0.5, 1.5, 1.0), (0.2, 3.7, 2.5), (0.9, 1.0, 0.3)):
        got: list[np.ndarray] = []
        hashes += _kernel_hashes(lambda w=w, p=p, e=e, got=got: got.append(_wrap(cosines, w, p, e)))
        c = cosines.astype(np.float64)
        expect = e * np.maximum((c + w) / (1.0 + w), 0.0) ** p
        np.testing.assert_allclose(got[0], expect, rtol=4e-6, atol=1e-7)
    assert len(set(hashes)) == 1


def _wrap(cos_theta, w: float, p: float, irradiance: float, folded: bool = False):
    return WRAP.evaluate({"cos_theta": cos_theta, "irradiance": irradiance}, {"w": w, "p": p}, folded=folded)


def test_a_cost_folds_its_numbers_into_the_kernel(cosines):
    """``folded``: the numbers are literals (a shader's constants), a kernel per value, the values those of
    the opaque run but where Dr.Jit divides by a literal's reciprocal (1 ulp)."""
    x = Float(cosines)
    runs = [(0.5, 1.5), (0.2, 3.7)]
    folded = [_kernel_hashes(lambda w=w, p=p: dr.eval(_wrap(x, w, p, 1.0, folded=True))) for w, p in runs]
    assert len({h for hs in folded for h in hs}) == 2
    a = np.asarray(_wrap(x, 0.5, 1.5, 1.0, folded=True))
    b = np.asarray(_wrap(x, 0.5, 1.5, 1.0))
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=0)


@pytest.mark.parametrize("n", [*range(-17, 18), 32.0, 64.0, float((1 << POWER_PRODUCT_BITS) - 1)])
def test_a_whole_opaque_exponent_takes_the_literals_products(n):
    """x^n for an opaque whole n: the bits of Dr.Jit's ``power`` of the number n (its products), on positive,
    negative, zero and large bases."""
    rng = np.random.default_rng(32)
    edges = [0.0, -0.0, 1.0, -1.0, 1e-20, 40.0]
    x = Float(np.concatenate([rng.uniform(-3.0, 3.0, 4000), edges]).astype(np.float32))
    literal = np.asarray(dr.power(x, float(n)))
    opaque = np.asarray(DRJIT_OPS.power(x, dr.opaque(Float, float(n))))
    np.testing.assert_array_equal(opaque.view(np.uint32), literal.view(np.uint32))


BIG = float(1 << POWER_PRODUCT_BITS)


@pytest.mark.parametrize("n", [0.5, 1.5, -2.5, 7.25, BIG, BIG + 1.0, -BIG - 3.0])
def test_other_opaque_exponents_match_numpy_signs_and_specials(n):
    """A fractional exponent, or a whole one beyond the products' bits: NumPy's ``power`` rounded to float32
    (NaN for a negative base and a fractional exponent, the sign of a whole one's, 0 or inf at 0), within a
    few float32 ulp of the exponent's size."""
    base = np.array([-2.0, -1.1, -0.5, 0.0, 0.25, 1.0, 1.02, 1.7, 3.0], np.float32)
    got = np.asarray(DRJIT_OPS.power(Float(base), dr.opaque(Float, n)))
    with np.errstate(all="ignore"):
        expect = np.power(base.astype(np.float64), n).astype(np.float32)  # (beyond float32: ±inf or 0)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expect))
    np.testing.assert_array_equal(np.isinf(got), np.isinf(expect))
    number = ~np.isnan(expect)
    np.testing.assert_array_equal(np.signbit(got[number]), np.signbit(expect[number]))
    finite = np.isfinite(expect) & (
        np.abs(expect) >= np.finfo(np.float32).tiny
    )  # (Dr.Jit flushes subnormals)
    np.testing.assert_allclose(got[finite], expect[finite], rtol=2e-6 * max(1.0, abs(n)))


def test_zero_to_the_zero_is_one_and_signs_of_whole_powers():
    x = Float(np.array([0.0, -2.0, -2.0, -2.0], np.float32))
    y = [0.0, 2.0, 3.0, -1.0]
    got = [float(np.asarray(DRJIT_OPS.power(x, dr.opaque(Float, v)))[i]) for i, v in enumerate(y)]
    assert got == [1.0, 4.0, -8.0, -0.5]


def test_a_text_that_needs_a_python_number_gets_the_literal():
    """A kernel text that reads a number as a Python number (a step count through ``int``, a level through
    ``math.log2``) runs as before: with the literal."""

    def kernel(ops, x, steps, scale):
        total = 0.0 * x
        for _ in range(int(steps)):
            total = total + x * scale
        return total + math.log2(scale)

    got = evaluate(kernel, np.ones(8, np.float32), 3, 2.0)
    np.testing.assert_array_equal(got, np.full(8, 7.0, np.float32))
