"""Measured cost of an approximation: time per evaluated element on the current backend.

Dr.Jit is lazy: a kernel runs when its result is evaluated. `time_drjit` therefore forces
evaluation (``dr.eval``) and waits for the device (``dr.sync_thread``) inside the timed region,
after a warm-up call that compiles (or loads) the kernel, and reports the median of several
repetitions. Inputs are made opaque (evaluated device arrays) beforehand so that only the
approximation's own kernel is timed. `time_numpy` times the same formula through NumPy (the same
kernel text run with NumPy operations), so the two can be quoted as a ratio measured in one run.
A memory-traffic baseline (one fused multiply-add reading the same inputs) shows how close a
closed form is to the memory limit.
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.arrays import backend_float
from rtfit.reference.variants import backend_of


@dataclass(frozen=True)
class Timing:
    seconds: float  # median wall time of one call
    elements: int
    repeats: int

    @property
    def ns_per_element(self) -> float:
        return self.seconds / self.elements * 1e9

    @property
    def elements_per_second(self) -> float:
        return self.elements / self.seconds

    def to_dict(self, per: int = 1) -> dict:
        """The results schema's timing columns: ``ns_per_pixel`` (ns), ``pixels_per_second`` (1/s), the
        ``elements`` of one timed call and the ``repeats`` measured; ``per``: kernel elements per pixel
        (a kernel launched over point × texel pairs counts ``per`` of its elements as one pixel)."""
        return {
            "ns_per_pixel": self.ns_per_element * per,
            "pixels_per_second": self.elements_per_second / per,
            "elements": self.elements,
            "repeats": self.repeats,
        }


MEDIAN_CI_LEVEL = 0.95
"""Coverage of the median's distribution-free confidence interval (`median_ci`) that stops a timing loop."""
MEDIAN_CI_REL = 0.03
"""A timing loop stops once the median's `MEDIAN_CI_LEVEL` interval lies within ± this fraction of the median
(`_median_time`): more calls would not move the reported median by more than about this."""


@functools.cache
def _median_rank(n: int, level: float) -> int:
    """The largest k with P(k ≤ B ≤ n − k) ≥ ``level``, B ~ Binomial(n, ½); 0 where none."""
    k, term, below = 0, 0.5**n, 0.0  # term: P(B = k); below: P(B ≤ k), summed as k grows
    while k < n // 2:
        below += term
        if 2.0 * below > 1.0 - level:
            break
        term *= (n - k) / (k + 1)
        k += 1
    return k


def median_ci(times, level: float = MEDIAN_CI_LEVEL) -> tuple[float, float] | None:
    """The distribution-free confidence interval of the median of ``times`` at ``level`` or more: the k-th
    smallest and the k-th largest time, k the largest with P(k ≤ B ≤ n − k) ≥ level, B ~ Binomial(n, ½) the
    number of times below the true median (no assumption on their distribution, only independence). None
    where no interval reaches ``level``: fewer than 6 times at 95 % (the minimum and maximum of 5 cover
    1 − 2/2⁵ = 93.75 %)."""
    n = len(times)
    k = _median_rank(n, level)
    if k == 0:
        return None
    s = sorted(times)
    return s[k - 1], s[n - k]


def _median_known(times) -> bool:
    """The median of ``times`` is known to `MEDIAN_CI_REL`: its `median_ci` lies within ± that of it."""
    ci = median_ci(times)
    if ci is None:
        return False
    med = statistics.median(times)
    return max(ci[1] - med, med - ci[0]) <= MEDIAN_CI_REL * med


def _median_time(call: Callable[[], float | None], repeats: int, min_seconds: float) -> tuple[float, int]:
    """The median time of ``call()`` and the number of calls timed: until the median is known
    (`_median_known`: its 95 % interval within ± 3 %, which needs 6 calls or more), else until
    ``repeats`` calls and ``min_seconds`` (of wall time) have passed (at most 1000 calls). A call's time is
    what it returns (`time_drjit`: its kernels' own), or its wall time where it returns None. Issue 33
    (session 19): before, every timing ran its ``repeats`` and ``min_seconds`` whatever the spread; a stable
    kernel is now known after 6 calls (the fewest whose interval reaches 95 %), and a noisy one (a loaded
    machine) still runs to that cap."""
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < repeats or (time.perf_counter() - start < min_seconds and len(times) < 1000):
        if _median_known(times):
            break
        t0 = time.perf_counter()
        own = call()
        times.append(time.perf_counter() - t0 if own is None else own)
    return statistics.median(times), len(times)


def _kernel_seconds(history: list) -> float | None:
    """Σ of the execution times (Dr.Jit reports ms) of the kernels in ``history`` (`dr.kernel_history`:
    each launch since the last read), in s; None where no launch reported one (a result that needed no
    kernel: its call's wall time stands in, `time_drjit`)."""
    times = [k["execution_time"] for k in history if k.get("execution_time") is not None]
    return sum(times) * 1e-3 if times else None


LAUNCH_BLOCKING = dr.JitFlag.LaunchBlocking
"""Set while `time_drjit` times a call: each kernel launch waits for the kernel to finish. Dr.Jit's LLVM
backend otherwise runs a kernel on its worker threads while Python goes on tracing the text's next kernel,
so a text of several kernels had each one share the cores with that tracing. Issue 33 (session 33): the SDF
cone tracer (ten kernels of 4096 elements, one per march step, and ~390 size-1 fills) timed 823 ns a pixel
traced against 410 with blocking launches (384 replayed as a frozen Dr.Jit function, whose kernels follow
each other with no Python between them); the Cornell box's audit's 37 other costs 0.76–1.03× what they
were (median 0.97; each the median of three rounds, interleaved with the former way)."""


def time_drjit(
    fn: Callable,
    args: tuple,
    elements: int,
    repeats: int = 7,
    min_seconds: float = 0.2,
    warm_up: bool = True,
) -> Timing:
    """Median time of ``fn(*args)``'s kernels, after a warm-up call (kernel compilation or cache load);
    ``warm_up`` False where the caller has just run the same kernel (Dr.Jit's kernels do not depend on the
    arrays' size: `audit_cost.method_cost`'s sizing call).

    A call's time is the execution time Dr.Jit's kernel history reports for the kernels it launched
    (``JitFlag.KernelHistory``: measured by Dr.Jit around each launch, on the CPU and the GPU), not the wall
    time around it: the wall time also held the Python tracing of the kernel text, which an engine's shader
    does not pay. Issue 33 (session 23): on a Cornell-box audit's methods that tracing added 7–180 % to
    the kernel time (the SDF cone tracer: 3.6 ms of tracing around 1.1 ms of kernel at 4096 elements), so
    each cost was raised by its own text's length, and `audit_cost.method_cost`'s sizing call, taking it
    for kernel time, sized the measured calls to 1–5 ms instead of its 20 ms. A call that launched no
    kernel is timed by its wall time (`_kernel_seconds`).

    Each launch waits for its kernel (`LAUNCH_BLOCKING`): a text of several kernels (one per march step)
    runs each alone, as a frozen replay would, instead of beside the Python tracing the next one."""
    dr.eval(*[a for a in args if dr.is_array_v(a)])
    dr.sync_thread()

    def call() -> float | None:
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True), dr.scoped_set_flag(LAUNCH_BLOCKING, True):
            dr.kernel_history()  # (read and emptied: only this call's launches below)
            out = fn(*args)
            dr.eval(out)
            dr.sync_thread()
            return _kernel_seconds(dr.kernel_history())

    if warm_up:
        call()  # warm-up: kernel compilation or cache load
    seconds, n = _median_time(call, repeats, min_seconds)
    return Timing(seconds, elements, n)


PRECOMPUTE_REPEATS = 3
"""Timed calls of a precompute (`time_precompute`) after its warm-up, where the warm-up took less than
`PRECOMPUTE_LONG` seconds; a longer one is timed once more (a bake of 0.3–1 s on 2 shared CPU cores: five
path-map rows spent 13 s of a 16-px audit at 3 repeats)."""
PRECOMPUTE_LONG = 0.1
PRECOMPUTE_ONCE = 1.0
"""A precompute whose warm-up call took this long (s) or more is timed by that call alone: its kernels'
compilation (if any: the case that declared it has usually just run the same step) is then a small part of
it, and 16384 caustic photons traced and gathered took 4–18 s a call on 2 loaded cores."""


def time_precompute(run: Callable[[], Any], repeats: int = PRECOMPUTE_REPEATS) -> Timing:
    """Median wall time of one whole precompute ``run()`` (a bake, photons traced, a texture built), in the
    per-pixel kernel's loop (`_median_time`, each call evaluating the Dr.Jit arrays it returns and waiting for
    the device, as `time_drjit`): a warm-up call (kernel compilation, caches), then ``repeats`` calls, or one
    where the warm-up took `PRECOMPUTE_LONG` s or more, or none where it took `PRECOMPUTE_ONCE` s or more
    (the warm-up is the timing: ``repeats`` 1); no minimum duration. ``elements`` is 1: the timing is of one
    precompute (``Timing.seconds``). Wall time, unlike `time_drjit`'s kernel time: a precompute's host work
    (NumPy, Mitsuba's ray tracing, its launches) is part of what an engine's bake pays."""

    def call():
        dr.eval(run())
        dr.sync_thread()

    dr.sync_thread()
    t0 = time.perf_counter()
    call()  # warm-up
    first = time.perf_counter() - t0
    if first >= PRECOMPUTE_ONCE:
        return Timing(first, 1, 1)
    seconds, n = _median_time(call, repeats if first < PRECOMPUTE_LONG else 1, 0.0)
    return Timing(seconds, 1, n)


def time_numpy(
    fn: Callable, args: tuple, elements: int, repeats: int = 5, min_seconds: float = 0.2
) -> Timing:
    def call() -> None:  # (its wall time: NumPy runs on the host, nothing is traced)
        fn(*args)

    call()
    seconds, n = _median_time(call, repeats, min_seconds)
    return Timing(seconds, elements, n)


NUMPY_MAX_ELEMENTS = 1 << 22
"""The most elements a bench times a NumPy run on: its float64 arrays (32 MB each at 2^22) are past every
cache level, where NumPy's per-element rate no longer depends on the size. At the GPU's 2^24 elements the
irradiance-bases bench ran past 7 minutes on the H200 machine, its NumPy rows scaling with the elements (20 s
of them at 2^20 on 2 cores; docs/benchmarks.md, session 10)."""


def numpy_elements(elements: int) -> int:
    """How many of a bench's ``elements`` its NumPy rows are timed on: at most `NUMPY_MAX_ELEMENTS`."""
    return min(int(elements), NUMPY_MAX_ELEMENTS)


def memory_baseline(args: tuple, elements: int) -> Timing:
    """A kernel reading the same inputs and writing one output: the memory-bound floor."""

    def fma_all(*xs):
        acc = xs[0]
        for x in xs[1:]:
            acc = dr.fma(acc, 0.5, x)
        return acc

    floats = tuple(a for a in args if dr.is_array_v(a))
    return time_drjit(fma_all, floats, elements)


def attach_costs(case_docs: list[dict], cost_rows: list[dict], key: Callable | None = None) -> None:
    """Set every approximation's ``cost`` (ns per pixel, pixels per second, backend: the results schema's
    cost object) from the measured row whose ``method`` is ``key(approximation)`` (default: the
    approximation's own method); None where no row was measured."""
    by_method = {c["method"]: c for c in cost_rows}
    for doc in case_docs:
        for ap in doc["approximations"]:
            c = by_method.get(key(ap) if key else ap["method"])
            ap["cost"] = (
                {
                    "ns_per_pixel": c["ns_per_pixel"],
                    "pixels_per_second": c["pixels_per_second"],
                    "backend": c["backend"],
                }
                if c
                else None
            )


# -------------------------------------------------------------------------- the results' ``costs`` rows
def cost_backend(variant: str) -> tuple[str, type]:
    """The Dr.Jit backend of a Mitsuba ``variant`` (`backend_of`: ``cuda`` or ``llvm``; runs refuse scalar
    variants) and that backend's float32 array type, which the timed inputs are made of."""
    backend = backend_of(variant)
    return backend, backend_float(backend)


def cost_row(
    method: str, label: str, backend: str, timing: Timing, note: str | None = None, per: int = 1, **columns
) -> dict:
    """One row of a results' ``costs`` (docs/results-schema.md): the ``method`` id it is attached to
    (`attach_costs`), its ``label``, the Dr.Jit ``backend``, the measured ``timing`` as ``ns_per_pixel``
    (ns per pixel, ray, lookup or normal: what the experiment evaluates once), ``pixels_per_second``,
    ``elements`` and ``repeats`` (``per``: kernel elements per pixel, `Timing.to_dict`), the family's own
    ``columns`` (e.g. ``floats_per_probe``: storage per probe in floats) and the ``note`` (words)."""
    return {
        "method": method,
        "label": label,
        "backend": backend,
        **timing.to_dict(per),
        **columns,
        "note": note,
    }


def memory_floor_row(inputs: tuple, elements: int, backend: str, note: str, label: str | None = None) -> dict:
    """The ``memory-baseline`` row of a results' ``costs``: `memory_baseline` timed on the Dr.Jit arrays among
    ``inputs`` (the timed kernels' own inputs, ``elements`` float32 each: one load of each, one fused
    multiply-add per load, one float32 store), ns per pixel like the rows it bounds (`cost_row`). Labelled
    ``memory traffic baseline (K loads, 1 store)`` with K the arrays counted, unless ``label`` is given."""
    floats = tuple(a for a in inputs if dr.is_array_v(a))
    label = label or f"memory traffic baseline ({len(floats)} loads, 1 store)"
    return cost_row("memory-baseline", label, backend, memory_baseline(floats, elements), note)


# ------------------------------------------------------------------------------ `rtfit bench` rows
def bench_backend(ctx) -> tuple[str, int]:
    """The Dr.Jit backend of ``ctx.variant`` (``rtfit bench`` made it the default,
    `runner.use_variant_backend`) and the kernel size: ``ctx.size``, else 2^24 elements on the GPU and 2^22
    on the CPU."""
    backend = backend_of(ctx.variant)
    return backend, ctx.size or (1 << (24 if backend == "cuda" else 22))


def comparison_row(
    what: str,
    backend: str,
    t_drjit: Timing,
    t_numpy: Timing | None,
    base: Timing,
    unit: str = "px",
    per: str | None = None,
) -> dict:
    """One bench row: Dr.Jit and NumPy throughput of the same kernel text (millions of ``unit``/s),
    their ratio, ns per element (``per``, default ``unit``) and the multiple of the memory floor."""
    per = per or unit
    return {
        "what": what,
        "backend": backend,
        "elements": t_drjit.elements,
        f"drjit_M{unit}_s": t_drjit.elements_per_second / 1e6,
        f"numpy_M{unit}_s": t_numpy.elements_per_second / 1e6 if t_numpy else None,
        # rates, not times: NumPy may be timed on fewer elements (`numpy_elements`)
        "drjit/numpy": t_drjit.elements_per_second / t_numpy.elements_per_second if t_numpy else None,
        f"ns_per_{per}": t_drjit.ns_per_element,
        "vs_memory_floor": t_drjit.seconds / base.seconds,
    }


BASELINE = "memory baseline (fma of the inputs)"
"""The default name of a bench's memory-floor row."""


def baseline_row(
    base: Timing,
    backend: str,
    what: str = BASELINE,
    unit: str = "px",
    per: str | None = None,
) -> dict:
    """The memory-traffic floor as a bench row (1× by definition)."""
    return comparison_row(what, backend, base, None, base, unit, per)


def time_method(method, inputs: Mapping[str, Any], elements: int, params: Mapping | None = None) -> Timing:
    """Dr.Jit time of ``method.evaluate`` on its named ``inputs`` (Dr.Jit arrays, one per input name)."""
    names = method.input_names
    return time_drjit(
        lambda *a: method.evaluate(dict(zip(names, a, strict=True)), params),
        tuple(inputs[k] for k in names),
        elements,
    )


def time_method_numpy(
    method, inputs: Mapping[str, Any], elements: int, params: Mapping | None = None
) -> Timing:
    """NumPy time of the same kernel text, ``method(NUMPY_OPS, inputs, params)``, on NumPy ``inputs``."""
    names = method.input_names
    with np.errstate(all="ignore"):  # NumPy evaluates both branches of every select
        return time_numpy(
            lambda *a: method(NUMPY_OPS, dict(zip(names, a, strict=True)), params),
            tuple(inputs[k] for k in names),
            elements,
        )


def comparison_rows(
    backend: str,
    floor_inputs: tuple,
    elements: int,
    timed: Iterable[tuple[str, Timing, Timing | None]],
    unit: str = "px",
    per: str | None = None,
    baseline: str | None = None,
) -> list[dict]:
    """Bench rows of kernels timed against one memory floor: the `memory_baseline` of ``floor_inputs`` is
    measured first, then ``timed`` (a generator, so that its kernels run after the floor) yields (what, Dr.Jit
    timing, NumPy timing or None) per kernel, each a `comparison_row`; last the floor itself as a
    `baseline_row` named ``baseline`` (None: no such row)."""
    base = memory_baseline(floor_inputs, elements)
    rows = [comparison_row(what, backend, t_dr, t_np, base, unit, per) for what, t_dr, t_np in timed]
    return rows if baseline is None else [*rows, baseline_row(base, backend, baseline, unit, per)]


def method_bench_rows(
    methods: Mapping[str, Any],
    backend: str,
    inputs: Mapping[str, Any],
    numpy_inputs: Mapping[str, Any],
    elements: int,
    params: Mapping[str, Mapping] | None = None,
    unit: str = "px",
    floor_inputs: tuple | None = None,
    baseline: str | None = None,
) -> list[dict]:
    """`comparison_rows` of every method of ``methods`` (id → method) with ``params[id]`` (None: the declared
    defaults): `time_method` on the Dr.Jit ``inputs`` beside `time_method_numpy` on ``numpy_inputs``, against
    the floor of ``floor_inputs`` (default: every array of ``inputs``)."""
    params = params or {}

    timed = (
        (m.label, time_method(m, inputs, elements, p), time_method_numpy(m, numpy_inputs, elements, p))
        for mid, m in methods.items()
        for p in (params.get(mid),)
    )
    floor = tuple(inputs.values()) if floor_inputs is None else floor_inputs
    return comparison_rows(backend, floor, elements, timed, unit, baseline=baseline)


def method_cost_rows(
    methods: Mapping[str, Any],
    backend: str,
    inputs: Mapping[str, Any],
    elements: int,
    note: str | Callable[[Any], str],
    floor_note: str,
    params: Mapping[str, Mapping] | None = None,
    floor_inputs: tuple | None = None,
) -> list[dict]:
    """The results' ``costs``: `cost_row` of every method of ``methods`` (`time_method` on ``inputs`` with
    ``params[id]``; ``note`` text or ``note(method)``), then the `memory_floor_row` of ``floor_inputs``
    (default: every array of ``inputs``)."""
    params = params or {}
    rows = [
        cost_row(
            mid,
            m.label,
            backend,
            time_method(m, inputs, elements, params.get(mid)),
            note(m) if callable(note) else note,
        )
        for mid, m in methods.items()
    ]
    floor = tuple(inputs.values()) if floor_inputs is None else floor_inputs
    return [*rows, memory_floor_row(floor, elements, backend, floor_note)]


def rate_row(
    what: str, backend: str, elements: int, seconds: float, numpy: bool = False, unit: str = "px"
) -> dict:
    """A bench row timed alone (a reference pass, a NumPy quadrature): its rate in the Dr.Jit column (the
    NumPy one if ``numpy``), no ratio and no memory floor."""
    rate = elements / seconds / 1e6
    return {
        "what": what,
        "backend": backend,
        "elements": elements,
        f"drjit_M{unit}_s": None if numpy else rate,
        f"numpy_M{unit}_s": rate if numpy else None,
        "drjit/numpy": None,
        f"ns_per_{unit}": seconds / elements * 1e9,
        "vs_memory_floor": None,
    }


# ----------------------------------------------------- ground truth vs its stock Mitsuba equivalent
@dataclass(frozen=True)
class Stock:
    """A stock Mitsuba render comparable to an rtfit reference pass: its label, ``run(seed)`` (the whole
    render, returning host data) and the samples one call draws."""

    what: str
    run: Callable[[int], object]
    samples: int


def stock_render(mi, mi_scene, spp: int) -> Callable[[int], object]:
    """``seed ↦ mi.render(mi_scene, spp, seed)`` read back to the host: Mitsuba's own render of a scene."""
    return lambda seed: np.asarray(mi.render(mi_scene, spp=spp, seed=seed))


PIXEL_BOUND_SIZE = (1024, 64)
"""(image side, spp) of the surface references' second bench row (non-``--quick``): 2^20 pixels at a low spp,
where a pass's per-pixel cost (not its per-sample cost) shows. On an H200 this row measured 0.18×
``mi.render`` before the moments stayed on the device (issue 21 §3; docs/benchmarks.md)."""


def reference_sizes(
    quick: bool, quick_size: tuple[int, int], full_size: tuple[int, int]
) -> list[tuple[int, int]]:
    """(image side, spp) of each reference-vs-stock measurement of a surface family's bench: ``quick_size``
    with ``--quick``; else ``full_size`` (sample-bound) and `PIXEL_BOUND_SIZE` (pixel-bound)."""
    return [quick_size] if quick else [full_size, PIXEL_BOUND_SIZE]


def reference_vs_stock_rows(
    reference: str,
    run_reference: Callable[[int], object],
    samples: int,
    stocks: list[Stock],
    variant: str,
    rounds: int = 5,
) -> list[dict]:
    """Samples/s of an rtfit reference pass beside the stock Mitsuba renders a user would otherwise run,
    measured **side by side**: one warm-up call each (kernel compile or cache load), then ``rounds``
    rounds of one call each, alternating, each round with a fresh seed (``run(seed)`` must do the whole
    pass and return host data; ``dr.sync_thread`` is called around it too). The best (smallest) time of
    each is kept: on a shared machine the minimum is the estimate least disturbed by other load, and
    alternating exposes every side to the same load.

    Rows: ``what``, ``backend`` (the variant), ``samples`` per call, ``Msamples_s``, ``ns_per_sample`` and,
    on each stock row, ``rtfit_vs_this``: rtfit's samples/s over that render's (issue 21's goal: ≥ 0.9
    against the same integrator, i.e. rtfit's pass machinery costs at most 11 % over ``mi.render``)."""

    def timed(call, seed) -> float:
        dr.sync_thread()
        t0 = time.perf_counter()
        call(seed)
        dr.sync_thread()
        return time.perf_counter() - t0

    calls = [(reference, run_reference, samples)] + [(s.what, s.run, s.samples) for s in stocks]
    best = [math.inf] * len(calls)
    for k in range(rounds + 1):  # round 0: warm-up, not counted
        for i, (_, run, _) in enumerate(calls):
            t = timed(run, k)
            if k:
                best[i] = min(best[i], t)
    rates = [n / t for (_, _, n), t in zip(calls, best, strict=True)]
    return [
        {
            "what": what,
            "backend": variant,
            "samples": n,
            "Msamples_s": rate / 1e6,
            "ns_per_sample": 1e9 / rate,
            "rtfit_vs_this": rates[0] / rate if i else None,
        }
        for i, ((what, _, n), rate) in enumerate(zip(calls, rates, strict=True))
    ]
