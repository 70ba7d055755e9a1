"""A NumPy run's memo of a kernel's parameter-independent values (`KeptValues`).

A fit (SciPy's TRF on the NumPy run of a method's kernel text, `rtfit.fitting.fit_method`) evaluates the
kernel again and again on the same input arrays: only the fitted parameters change, and each central-
difference Jacobian moves one of them at a time. Values of the kernel that depend on the inputs alone
(clamped inputs, angles from cosines, cap areas, a geometric ramp) are then the same at every call.
`KeptValues.get` computes them once per key and identity of the input arrays and hands the same arrays back
afterwards: the same operations on the same arrays, so the same values, bit for bit.

Only the NumPy run keeps anything. A Dr.Jit, JAX or shader run (or arrays that are not NumPy) gets the values
computed as they are asked for, in the kernel's order of operations, so that a trace, a compiled kernel and a
shader are what the kernel text says.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from .arrays import NUMPY_OPS

__all__ = ["KeptValues"]

T = TypeVar("T")


def _floats(value: Any) -> int:
    """How many floats ``value`` (an array, or a tuple/list of arrays and numbers) holds."""
    if isinstance(value, (tuple, list)):
        return sum(_floats(v) for v in value)
    return int(np.size(value))


class KeptValues:
    """Values kept per (key, the identity of their input arrays), the least recently used dropped first once
    more than ``max_entries`` entries or ``max_floats`` floats in all are kept; inputs of more than
    ``max_input_floats`` elements (the largest) are not kept at all (default: ``max_floats``). The input
    arrays are held by weak references: an entry whose arrays are gone is never matched again (and is pushed
    out in turn)."""

    def __init__(self, max_floats: int, max_entries: int, max_input_floats: int | None = None) -> None:
        self.max_floats, self.max_entries = int(max_floats), int(max_entries)
        self.max_input_floats = self.max_floats if max_input_floats is None else int(max_input_floats)
        self._entries: dict[str, tuple[tuple, Any, int]] = {}
        # a fit may evaluate its Jacobian's points on several threads (`rtfit.fitting.method_fit`'s
        # `difference_map`): one at a time here (re-entrant: a kept value's ``make`` may ask for another)
        self._lock = threading.RLock()

    def get(self, ops, key: tuple, arrays: Sequence[Any], make: Callable[[bool], T]) -> T:
        """``make(True)`` (the values computed now) on the NumPy run, kept for ``key`` (plain numbers and
        strings) and these very ``arrays`` (identity). ``make(False)`` on any other run, where an array is
        not a NumPy array of at least one dimension, or where the largest is over ``max_input_floats``: the
        same values, which ``make`` may then produce as they are read (a generator), so that a trace keeps
        the kernel's order of operations."""
        if (
            ops is not NUMPY_OPS
            or not all(isinstance(a, np.ndarray) and a.ndim >= 1 for a in arrays)
            or max((a.size for a in arrays), default=0) > self.max_input_floats
            or not all(isinstance(k, str | int | float | bool | None) for k in key)
        ):
            return make(False)
        with self._lock:
            return self._get(key, arrays, make)

    def _get(self, key: tuple, arrays: Sequence[Any], make: Callable[[bool], T]) -> T:
        full = repr(key)  # exact numbers (−0.0 and 0.0 apart)
        hit = self._entries.pop(full, None)
        if (
            hit is None
            or len(hit[0]) != len(arrays)
            or not all(r() is a for r, a in zip(hit[0], arrays, strict=True))
        ):
            value = make(True)
            floats = _floats(value)
            while self._entries and (
                len(self._entries) >= self.max_entries
                or sum(e[2] for e in self._entries.values()) + floats > self.max_floats
            ):
                self._entries.pop(next(iter(self._entries)))
            hit = (tuple(weakref.ref(a) for a in arrays), value, floats)
        self._entries[full] = hit  # the most recently used last
        return hit[1]

    def clear(self) -> None:
        """Forget every entry (`rtfit.experiments.runner.forget_memos` between the experiments of a suite)."""
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
