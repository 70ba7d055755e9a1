"""How a TRF fit's finite-difference points are evaluated: the ``workers`` map that SciPy's ``least_squares``
hands a Jacobian's points to (`rtfit.fitting.method_fit`'s ``solver="trf"``).

- `difference_map`: threads, for a NumPy fit of many residuals (`PARALLEL_FROM`);
- `grouped_differences`: parameters that change disjoint residuals stepped together, one evaluation a side;
- `batched_points` (with `point_batch`): the points of a NumPy fit evaluated in one call of the kernel, each
  fitted parameter an array over the points on a new leading axis.

Each keeps SciPy's points, steps and one-sided rule: the Jacobian is the one a call a point gives, bit for bit
(tests/test_fit_tolerance.py).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS, same_bits
from rtfit.realtime.methods import Method

__all__ = [
    "BATCH_ELEMENTS",
    "PARALLEL_FROM",
    "batched_points",
    "difference_map",
    "grouped_differences",
    "point_batch",
    "run_point_batch",
    "weighted_residuals",
]

PARALLEL_FROM = 1 << 16
"""A NumPy fit of at least this many residuals evaluates its Jacobian's points on `_threads` threads
(`difference_map`): NumPy's elementwise passes over such arrays release the GIL for most of their time, and a
fit otherwise leaves every core but one idle (its BLAS runs on one thread: `one_blas_thread`). Below it (a
64² audit's 4096 pixels: ~10 µs a pass) the threads would mostly wait for the GIL. Each point is evaluated
alone, as before: the same Jacobian bit for bit (tests/test_fit_tolerance.py). Issue 33: the polishes on every
pixel were 16.5 of the 23 s of a 256² Cornell-box audit's fits."""


def _threads() -> int:
    """The CPU cores this process may run on (at most 4: a Jacobian has 2k points, k ≤ 7 here)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def difference_map(size: int, ops: str) -> Callable | None:
    """The map a fit's finite differences run through: threads (`PARALLEL_FROM`) for a NumPy fit
    (``ops`` "numpy") of ``size`` residuals or more on a machine of several cores, each evaluation under
    NumPy's ``errstate(all="ignore")`` as the fit's own; None (the caller's serial map) otherwise. A Dr.Jit
    fit (`Method.fit_ops` "drjit") is left serial: its kernels already run on every core."""
    threads = _threads()
    if ops != "numpy" or size < PARALLEL_FROM or threads < 2:
        return None

    def parallel(fun, points):
        def one(x):
            with np.errstate(all="ignore"):
                return fun(x)

        with ThreadPoolExecutor(max_workers=threads) as pool:
            return list(pool.map(one, list(points)))

    return parallel


def _one_by_one(fun: Callable, xs) -> list:
    """The serial ``workers`` map: ``fun`` at each point in turn (SciPy's own, without a map)."""
    return [fun(x) for x in xs]


def grouped_differences(
    rows: list, centre: Mapping[bytes, np.ndarray], mapper: Callable | None = None
) -> Callable | None:
    """The ``workers`` map for SciPy's central-difference Jacobian (``jac="3-point"``) of a fit whose
    parameter i changes only the residuals ``rows[i]`` (a boolean mask; None: any): parameters of pairwise
    disjoint rows are stepped together, one evaluation per side for the group instead of one per parameter,
    and each parameter's column gets the group's residuals on its rows and the centre's elsewhere — what
    its own evaluation gives there, bit for bit, so SciPy's differences (its steps, bounds and one-sided rule
    untouched) are the same. ``centre``: the latest residuals by the parameters' bytes (else evaluated
    again). None where no two parameters' rows are disjoint. A map of anything but the Jacobian's 2·k points
    (each stepping one parameter of one centre) runs each point as it is. ``mapper``: the map the points
    are evaluated through (`difference_map`; None: one after another)."""
    run_all = mapper or _one_by_one
    groups: list[list[int]] = []
    for i, r in enumerate(rows):
        home = next((g for g in groups if r is not None and all(
            rows[j] is not None and not np.any(r & rows[j]) for j in g)), None)  # fmt: skip
        if home is None:
            groups.append([i])
        else:
            home.append(i)
    if all(len(g) == 1 for g in groups):
        return None
    k = len(rows)

    def workers(fun, points):
        xs = [np.array(x, np.float64) for x in points]
        if len(xs) != 2 * k or k < 2:
            return run_all(fun, xs)
        x0 = xs[2].copy()
        x0[1] = xs[0][1]  # the first pair steps parameter 0 only, the second parameter 1 only
        for i, x in enumerate(xs):
            other = np.arange(k) != i // 2
            if not np.array_equal(x[other].view(np.uint64), x0[other].view(np.uint64)):
                return run_all(fun, xs)
        f0 = centre.get(x0.tobytes())
        f0 = np.asarray(fun(x0) if f0 is None else f0, np.float64)
        todo = []  # (group, side, point): one evaluation per side of each group
        for g in groups:
            for side in (0, 1):
                if len(g) == 1:
                    x = xs[2 * g[0] + side]
                else:
                    x = x0.copy()
                    for i in g:
                        x[i] = xs[2 * i + side][i]
                todo.append((g, side, x))
        values = run_all(fun, [x for _, _, x in todo])
        out: list = [None] * (2 * k)
        for (g, side, _), f in zip(todo, values, strict=True):
            if len(g) == 1:
                out[2 * g[0] + side] = f
                continue
            f = np.asarray(f, np.float64)
            for i in g:
                col = f0.copy()
                col[rows[i]] = f[rows[i]]
                out[2 * i + side] = col
        return out

    return workers


BATCH_ELEMENTS = 1 << 16
"""The most residuals (points × residuals a point) one batched call of a kernel evaluates (`batched_points`):
a Jacobian of more is evaluated in chunks of points. The kernels' temporaries grow with it; past a few
hundred kilobytes an arithmetic-bound kernel (obscurances' 32 rays a pixel) ran slower batched than a call a
point (issue 33, session 27)."""


def point_batch(
    method: Method,
    inputs: Mapping[str, Any],
    held: Mapping[str, float],
    names: Sequence[str],
    values_of: Callable[[np.ndarray], np.ndarray],
    weights: np.ndarray,
    target: np.ndarray,
    shapes: Sequence[tuple[int, ...]],
) -> Callable[[Sequence[np.ndarray]], list[np.ndarray] | None]:
    """``evaluate(points) -> [residuals]``: the weighted residuals ``weights · (f(x; p) − target)``
    (raveled, as a fit's residual function gives them) at each of several solver points, from one call of
    ``method``'s NumPy run: each fitted parameter an array of the points' values, shaped (points, 1, …) so
    that it broadcasts against the inputs on a new leading axis, the held parameters as they are.
    ``values_of``: the parameters' values at a solver point (log-stepped ones exponentiated), computed a point
    at a time, as the fit does.

    None where the kernel does not take parameters so: an exception (a parameter read as a number: ``float``,
    an ``if``, a loop count), or an output not of the shapes ``shapes`` (the kernel's output shapes at one
    point, a tuple output's parts each) under the leading axis (a reduction over an axis, an index into one).
    A text that mixes the points while keeping the shapes (a mean over every element) is caught by the caller
    (`batched_points`: the point evaluated last, evaluated again in each batch, bit for bit)."""
    dims = max((np.ndim(v) for v in inputs.values() if isinstance(v, np.ndarray)), default=0)

    def evaluate(points: Sequence[np.ndarray]) -> list[np.ndarray] | None:
        n = len(points)
        columns = np.array([values_of(v) for v in points], np.float64)  # (n, k), a point at a time
        stacked = (n,) + (1,) * dims
        values = {**held, **{nm: columns[:, i].reshape(stacked) for i, nm in enumerate(names)}}
        try:
            with np.errstate(all="ignore"):
                pred = method(NUMPY_OPS, inputs, values)
                many = isinstance(pred, tuple | list)
                parts = [np.asarray(p, np.float64) for p in (pred if many else (pred,))]
                if (
                    not shapes
                    or len(parts) != len(shapes)
                    or any(p.shape != (n, *s) for p, s in zip(parts, shapes, strict=False))
                ):
                    return None
                p = np.stack(parts, axis=1) if many else parts[0]  # a tuple: (points, parts, …)
                # the point's shape against the target's, as one point's residuals broadcast them
                p = p.reshape((n,) + (1,) * max(0, target.ndim - (p.ndim - 1)) + p.shape[1:])
                r = np.broadcast_to(weights * (p - target), (n, *target.shape)).reshape(n, -1)
        except Exception:  # any failure: a call a point, as before
            return None
        return list(r)

    return evaluate


def run_point_batch(
    many: Callable[[Sequence[Mapping[str, float]]], list | None],
    held: Mapping[str, float],
    names: Sequence[str],
    values_of: Callable[[np.ndarray], np.ndarray],
    weights: np.ndarray,
    target: np.ndarray,
) -> Callable[[Sequence[np.ndarray]], list[np.ndarray] | None]:
    """``evaluate(points) -> [residuals]`` (as `point_batch`'s) through a run that evaluates several points
    of parameter values at once (``many``: `rtfit.fitting.drjit_run.DrJitRun.many`, a Dr.Jit fit's points in
    one replay); each point's values and residuals made as the fit's residual function makes them."""

    def evaluate(points: Sequence[np.ndarray]) -> list[np.ndarray] | None:
        values = [{**held, **dict(zip(names, (float(a) for a in values_of(v)), strict=True))} for v in points]
        preds = many(values)
        if preds is None:
            return None
        with np.errstate(all="ignore"):
            return [weighted_residuals(pred, weights, target) for pred in preds]

    return evaluate


def weighted_residuals(pred, weights: np.ndarray, target: np.ndarray) -> np.ndarray:
    """A TRF fit's residuals at one point: ``weights · (pred − target)`` over the target's shape, raveled (the
    fit's residual function, `rtfit.fitting.method_fit`, and `run_point_batch` alike: the same bits)."""
    return np.ravel(np.broadcast_to(weights * (np.asarray(pred, np.float64) - target), target.shape))


def batched_points(
    evaluate: Callable[[Sequence[np.ndarray]], list[np.ndarray] | None],
    last: Mapping[bytes, np.ndarray],
    size: int,
) -> Callable | None:
    """The ``workers`` map that evaluates a Jacobian's points through ``evaluate`` (`point_batch`), at most
    `BATCH_ELEMENTS` residuals a call (``size`` residuals a point), where that is faster than a call of the
    kernel a point.

    The fit's first Jacobian is evaluated a call a point and timed, its second in batches and timed; the
    faster way evaluates the rest (a kernel whose NumPy run keeps values between calls, obscurances' ray
    means, can be faster a call a point). Each batch also evaluates the point evaluated last (``last``: its
    bytes → its residuals, the Jacobian's centre), whose residuals it must give bit for bit: a kernel whose
    batched run differs from its run at one point (or that `point_batch` cannot run so) is evaluated a call
    a point from then on, this batch's points included. None (a call a point) where `BATCH_ELEMENTS` is
    below 1.

    Issue 33 (session 27): a small fit's cost was the per-call overhead of the kernel's NumPy run (~1 ms of
    Python and NumPy dispatch whatever the elements), 2k calls a Jacobian of k parameters."""
    if BATCH_ELEMENTS < 1:
        return None
    chunk = max(2, BATCH_ELEMENTS // max(int(size), 1))
    state: dict[str, Any] = {"mode": "time serial", "serial": math.inf}

    def workers(fun, points):
        xs = [np.array(x, np.float64) for x in points]
        known = list(last.items())[-1] if last else None
        mode = state["mode"]
        if mode == "serial" or len(xs) < 2 or known is None:
            return _one_by_one(fun, xs)
        start = time.perf_counter()
        if mode == "time serial":
            out = _one_by_one(fun, xs)
            state["serial"], state["mode"] = time.perf_counter() - start, "time batched"
            return out
        centre = np.frombuffer(known[0], np.float64).copy()
        out = []
        for i in range(0, len(xs), chunk):
            values = evaluate([*xs[i : i + chunk], centre])
            if values is None or not same_bits(np.asarray(known[1]), values[-1]):
                state["mode"] = "serial"
                return out + _one_by_one(fun, xs[len(out) :])
            out.extend(values[:-1])
        if mode == "time batched":
            faster = time.perf_counter() - start < state["serial"]
            state["mode"] = "batched" if faster else "serial"
        return out

    return workers
