"""The Dr.Jit run of a fit (`Method.fit_ops` ``"drjit"``): `DrJitRun`, the kernel text on float64 Dr.Jit
arrays of the default backend, one point at a time (a frozen function replayed) or several points in one
replay (`DrJitRun.many`, issue 33).

A fit evaluates its kernel a few hundred times (a scan of its start, then SciPy's TRF: each step a point and
its central-difference Jacobian, 2k points for k parameters). On the CPU each evaluation of a small image
costs Dr.Jit's call overhead more than its arithmetic: a shadow map's PCF on 64² receivers replayed in
0.27–0.50 ms, ~0.22 ms of it the call itself, whatever the taps. `many` evaluates P points in one replay of a
second frozen function, every input gathered P times over (element j of the batch reads input element
j mod n) and each parameter an array holding point i's value on elements [i·n, (i + 1)·n): the same
operations on the same values, element for element, as P calls (the callers check that, bit for bit, on a
point they know: `rtfit.fitting.difference_maps.batched_points`, `rtfit.fitting.method_fit.scan_predictions`).

Per-channel inputs (the (3, n) arrays of a stacked per-channel fit, `drjit_input`) are Dr.Jit's
``Array3f64``, broadcast against the (n,) inputs the channels share, as NumPy broadcasts (3, n) against (n,).
"""

from __future__ import annotations

import contextlib
import gc
import sys
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from rtfit.realtime.arrays import DRJIT_OPS, backend_float, backend_type, same_bits, to_drjit
from rtfit.realtime.methods import Method

__all__ = ["MANY_ELEMENTS", "DrJitRun", "collector_paused", "drjit_input", "held_arrays", "same_prediction"]

MANY_ELEMENTS = 1 << 20
"""The most elements (points × an input's elements) one `DrJitRun.many` replay evaluates; more points are
evaluated in several replays. Dr.Jit fuses the kernel: nothing of size P·n is kept but the gathered inputs'
indices, the parameters' arrays and the outputs (float64: 8 MiB each at 2^20)."""


def drjit_input(Float: type, v: np.ndarray) -> Any:
    """A fit's array input on Dr.Jit: a flat array as a ``Float`` array; a (c, n) array (the per-channel
    values of a stacked fit, `rtfit.experiments.audit_fit.fit_data` ``stacked``) as Dr.Jit's ``Array{c}f64``
    of its rows, which broadcasts against the (n,) inputs the channels share as NumPy's (c, n) against (n,)
    does: the shared work (a shadow map's taps) computed once for the c channels, each channel's values
    those of its own elementwise run, and the output back as (c, n)."""
    a = np.asarray(v, np.float64)
    if a.ndim != 2:
        return to_drjit(Float, a)
    vector = getattr(sys.modules[Float.__module__], f"Array{a.shape[0]}f64")
    return vector(*(to_drjit(Float, row) for row in a))


def held_arrays(value: Any, out: list, depth: int = 0) -> list:
    """The Dr.Jit arrays a sampler object holds (its cached tables: `rtfit.realtime.arrays.cached_table`),
    found through its attributes, dicts, lists and tuples (three levels deep): a frozen function's inputs
    (`DrJitRun`)."""
    import drjit as dr

    if dr.is_array_v(value):
        out.append(value)
    elif depth <= 3:
        if isinstance(value, dict):
            items = list(value.values())
        elif isinstance(value, list | tuple):
            items = list(value)
        elif hasattr(value, "__dict__") and not isinstance(value, type):
            items = list(vars(value).values())
        else:
            items = []
        for v in items:
            held_arrays(v, out, depth + 1)
    return out


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Python's cycle collector off for the block (on again after it, where it was on): a frozen function's
    recording must not run the finalisers of unrelated garbage. Issue 33 (session 23): one run of the test
    suite aborted (``Fatal Python error: Aborted``, in pcf-soft-shadows' frozen fit) while the collector ran
    inside the recording of a fit's run, in a worker holding earlier tests' garbage (Mitsuba scenes among
    it); not reproduced alone. Reference counting still frees everything else as it goes."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _as_numpy(out):
    """A kernel's Dr.Jit output as float64 NumPy (an ``ArrayNf64`` as (N, n); a tuple part by part)."""
    import drjit as dr

    parts = out if isinstance(out, tuple | list) else (out,)
    dr.eval(*parts)
    values = [np.asarray(p, np.float64) for p in parts]
    return tuple(values) if isinstance(out, tuple | list) else values[0]


def same_prediction(a, b) -> bool:
    """Whether two predictions of a kernel (arrays, or tuples of arrays part by part) are the same bit for
    bit (`rtfit.realtime.arrays.same_bits`): a replay against a trace, a batched point against a call."""
    pairs = zip(a, b, strict=True) if isinstance(a, tuple) else [(a, b)]
    return all(same_bits(np.asarray(x), np.asarray(y)) for x, y in pairs)


class DrJitRun:
    """``run(params) -> prediction``: ``method``'s kernel text on float64 Dr.Jit arrays of the default backend
    (`Method.fit_ops` ``"drjit"``), back as NumPy (a tuple output part by part). The array inputs are
    converted once (`drjit_input`); each parameter value is ``dr.opaque``, so every evaluation replays one
    compiled kernel instead of compiling one per value. Scalars and samplers pass as they are (constants of
    the fit).

    Frozen (``dr.freeze``, issue 33): the first call traces the kernel text (and fills the samplers' cached
    tables), the second records it as a frozen function of the array inputs, the samplers' tables
    (`held_arrays`) and the parameters, and later calls replay the recorded kernels without tracing the
    Python text again (pcf-soft-shadows: 1.3 → 0.6 ms a call at 64², ~1200 calls an audit). The first
    replay is checked against a fresh trace, bit for bit; where it differs, or the recording fails, the run
    goes on tracing every call, as before. `many`: several points in one replay."""

    def __init__(self, method: Method, inputs: Mapping[str, Any]):
        import drjit as dr

        self.method = method
        self.Float = backend_float(None, np.float64)
        x = {n: drjit_input(self.Float, v) if isinstance(v, np.ndarray) else v for n, v in inputs.items()}
        self.x = x
        self.arrays = {n: v for n, v in x.items() if dr.is_array_v(v)}
        self.others = {n: v for n, v in x.items() if not dr.is_array_v(v)}
        self.calls = 0
        self.frozen: Any = None  # None: not recorded yet; False: traced at every call; else (f, tables)
        self.check = False
        self.batched: Any = None  # `many`'s frozen function (None: not made yet; False: not available)
        widths = {dr.width(v) for v in self.arrays.values()}
        self.width = widths.pop() if len(widths) == 1 else None  # (`many` needs one width)

    def _kernel(self, arrays, tables, params):
        return self.method(DRJIT_OPS, {**arrays, **self.others}, params)

    def __call__(self, params: Mapping[str, float]):
        import drjit as dr

        p = {k: dr.opaque(self.Float, float(v)) for k, v in params.items()}
        self.calls += 1
        if self.calls == 1 or self.frozen is False:
            return _as_numpy(self.method(DRJIT_OPS, self.x, p))
        if self.frozen is None:  # the second call: recorded
            try:
                f, tables = dr.freeze(self._kernel), held_arrays(list(self.others.values()), [])
                with collector_paused():
                    out = _as_numpy(f(self.arrays, tables, p))
            except Exception:  # a text that cannot be frozen: traced at every call
                self.frozen = False
                return _as_numpy(self.method(DRJIT_OPS, self.x, p))
            self.frozen, self.check = (f, tables), True
            return out
        f, tables = self.frozen
        with collector_paused():
            out = _as_numpy(f(self.arrays, tables, p))
        if self.check:  # the first replay, against the trace
            self.check = False
            traced = _as_numpy(self.method(DRJIT_OPS, self.x, p))
            if not same_prediction(out, traced):
                self.frozen = False
                return traced
        return out

    def _gathered_kernel(self, arrays, tables, params, index):
        import drjit as dr

        spread = {n: dr.gather(type(a), a, index) for n, a in arrays.items()}
        return self.method(DRJIT_OPS, {**spread, **self.others}, params)

    def many(self, points: Sequence[Mapping[str, float]]) -> list | None:
        """The predictions at each of ``points`` (parameter values, every parameter at each), as the calls
        of `__call__` give them element for element, from one replay per `MANY_ELEMENTS` (module text);
        None where the run cannot batch: no array input, inputs of several widths, a frozen run that was
        given up (`__call__`), a run not called yet (its first call, traced, fills the samplers' tables that
        the replays take as inputs), or a kernel that fails so. The caller checks a point it knows, bit for
        bit."""
        import drjit as dr

        n = self.width
        if n is None or not points or self.calls == 0 or self.batched is False or self.frozen is False:
            return None
        names = list(points[0])
        chunk = max(1, MANY_ELEMENTS // n)
        out: list = []
        try:
            for start in range(0, len(points), chunk):
                part = points[start : start + chunk]
                size = len(part)
                index = to_drjit(backend_type("UInt32"), np.tile(np.arange(n, dtype=np.uint32), size))
                params = {k: to_drjit(self.Float, np.repeat([float(p[k]) for p in part], n)) for k in names}
                if self.batched is None:
                    tables = held_arrays(list(self.others.values()), [])
                    self.batched = (dr.freeze(self._gathered_kernel), tables)
                f, tables = self.batched
                with collector_paused():
                    pred = _as_numpy(f(self.arrays, tables, params, index))
                out.extend(_split(pred, size, n))
        except Exception:  # a text that does not run so: a call a point
            self.batched = False
            return None
        return out


def _split(pred, points: int, n: int) -> list:
    """A batched prediction (its last axis points × n) as one prediction a point (a tuple part by part)."""
    if isinstance(pred, tuple):
        parts = [_split(p, points, n) for p in pred]
        return [tuple(p[i] for p in parts) for i in range(points)]
    a = np.asarray(pred, np.float64)
    a = a.reshape((*a.shape[:-1], points, n))
    return [np.ascontiguousarray(a[..., i, :]) for i in range(points)]
