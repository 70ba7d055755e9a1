"""`rtfit.realtime.numpy_memo.KeptValues`: a NumPy run's parameter-free values kept per key and identity of
the input arrays, computed afresh on every other run (issue 33, session 20)."""

from __future__ import annotations

import gc

import numpy as np

from rtfit.realtime import ambient_aperture as aa
from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS
from rtfit.realtime.numpy_memo import KeptValues


def counting(value):
    calls = []

    def make(kept: bool):
        calls.append(kept)
        return value

    return make, calls


def test_kept_per_key_and_identity_of_the_arrays():
    memo = KeptValues(max_floats=1000, max_entries=4)
    a, b = np.arange(5.0), np.arange(5.0)
    make, calls = counting(np.ones(5))
    first = memo.get(NUMPY_OPS, ("k",), (a,), make)
    assert memo.get(NUMPY_OPS, ("k",), (a,), make) is first and len(calls) == 1
    memo.get(NUMPY_OPS, ("k",), (b,), make)  # equal values, another array: computed again
    memo.get(NUMPY_OPS, ("k", 1.0), (b,), make)  # another key
    memo.get(NUMPY_OPS, ("k", -0.0), (b,), make)
    memo.get(NUMPY_OPS, ("k", 0.0), (b,), make)  # −0.0 and 0.0 apart
    assert len(calls) == 5


def test_other_runs_and_large_inputs_are_never_kept():
    memo = KeptValues(max_floats=10, max_entries=4)
    make, calls = counting(1.0)
    small, large = np.zeros(3), np.zeros(11)
    for _ in range(2):
        memo.get(DRJIT_OPS, ("k",), (small,), make)
        memo.get(NUMPY_OPS, ("k",), (large,), make)
        memo.get(NUMPY_OPS, ("k",), (small.tolist(),), make)
    assert calls == [False] * 6 and len(memo) == 0


def test_least_recently_used_dropped_by_entries_and_by_floats():
    memo = KeptValues(max_floats=12, max_entries=2)
    arrays = [np.zeros(1) for _ in range(3)]
    for k, a in enumerate(arrays):
        memo.get(NUMPY_OPS, (k,), (a,), lambda _: np.zeros(2))
    assert len(memo) == 2  # the first pushed out by the entry count
    make, calls = counting(np.zeros(2))
    memo.get(NUMPY_OPS, (0,), (arrays[0],), make)
    assert len(calls) == 1
    memo.get(NUMPY_OPS, ("big",), (arrays[1],), lambda _: np.zeros(11))  # 11 floats: the rest pushed out
    assert len(memo) == 1
    memo.clear()
    assert len(memo) == 0


def test_an_entry_whose_arrays_are_gone_is_not_matched():
    memo = KeptValues(max_floats=100, max_entries=4)
    a = np.zeros(4)
    memo.get(NUMPY_OPS, ("k",), (a,), lambda _: 1.0)
    del a
    gc.collect()
    make, calls = counting(2.0)
    assert memo.get(NUMPY_OPS, ("k",), (np.zeros(4),), make) == 2.0 and calls == [True]


def test_the_light_kernel_kept_or_not_gives_the_same_bits():
    """The ambient-aperture light term with c0..c5 and k varied as a fit varies them: the kept run equals a
    fresh run (memo emptied before each call) bit for bit."""
    rng = np.random.default_rng(7)
    n = 500
    inputs = {
        "cos_na": rng.uniform(-0.2, 1.0, n),
        "cos_nl": rng.uniform(-0.2, 1.0, n),
        "cos_al": rng.uniform(-1.0, 1.0, n),
        "aperture": rng.uniform(0.0, 1.6, n),
        "alpha": rng.uniform(0.0, 0.7, n),
        "radiance": rng.uniform(0.5, 2.0, n),
    }
    method = aa.METHODS["aa-fitted-fitted"]
    for step in range(4):
        params = {k: p.initial + 0.01 * step for k, p in method.params.items()}
        kept = method(NUMPY_OPS, inputs, params)
        aa._KEPT.clear()
        fresh = method(NUMPY_OPS, inputs, params)
        assert np.array_equal(kept, fresh)
    assert len(aa._KEPT) == 3
