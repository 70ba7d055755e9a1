"""The engine's cost of a method: ns per pixel of its kernel on the run's backend, its per-pixel inputs
tiled to a measurable size (`method_cost`; split from `audit_run`, issue 30)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime.arrays import Uniforms, aligned_empty, backend_float, release_backend_tables, to_drjit
from rtfit.realtime.methods import Method

from .audit_family import FamilyCase
from .cost import time_drjit

COST_ELEMENTS = 1 << 20  # inputs are tiled to this many elements for the cost measurement
_COST_INPUT_BYTES = 64 << 20
"""At most this many bytes of tiled per-pixel inputs in a cost measurement (float32, every input together).
The caustics' splats read 112 per-pixel inputs: at 2^20 elements their tiled copies were 0.9 GB (and as much
again on the host), which lifted the quick suite's peak memory to 3.9 GB (issue 33); they are timed on 2^17
elements now. Where the inputs are few, a kernel reads 4 MiB each (2^20 float32): beyond a laptop's caches,
so that memory traffic is timed there, but within the last-level cache of a large server (this project's
2-core VM reports a shared L3 of 300 MiB: a two-input Lambert kernel timed 0.13–0.21 ns a pixel, ~60–90 GB/s
of traffic, the L3's speed, not DRAM's). A cost is of the machine it was measured on, which the report
names (`runner.device_description`)."""


_UNIFORM_FLOATS = 1024
"""A table of at most this many floats, where the kernel reads it by index (coefficients: SH L2's 27, L4's
75), is timed as a shader's constant buffer (`rtfit.realtime.arrays.Uniforms`): 256 float4, a uniform array
an engine declares; a larger table (a cube map's 6·16² texels) is a texture, gathered from as it is."""
_COST_PROBE = 1 << 12  # elements of the first, sizing call of a cost measurement
_COST_CALL_SECONDS = 0.001
"""The sized call's target kernel time (s; `cost.time_drjit` times the kernels, not the Python tracing them):
a slow kernel is timed on fewer elements, never fewer than `_COST_PROBE`. Every kernel up to ~1 ns a pixel
runs on all 2^20 elements (4 MiB an input: the memory-bound ones stream from memory); a slower one is
compute-bound, and 1 ms is ≥ 2^15 elements up to 30 ns a pixel. Dr.Jit's LLVM backend spreads even 8192
elements over both cores here (a 60-step sin/cos kernel: 53 ns an element at 8192 against 48 at 2^18 on
2 threads, 100 and 96 on one), so a small call is not a one-core number. The median's stop
(`cost._median_time`) is what makes the number precise. Issue 33: at 0.05 s of wall time the 20 slowest
kernels of a Cornell-box audit ran 6–7 calls of 45–135 ms each (≈ 4 CPU s); session 20 set 0.02 s of
wall time, which, the tracing counted in the sizing call's 4096 elements, gave measured calls of 1–5 ms.
Session 23 times the kernels alone: at 0.005 s of kernel time the audit's 38 costs took 2.1–2.3 s, at
0.002 s 1.8 s (as before the change), their values 0.62–1.53× those at 0.005 s (geometric mean 0.98: the
run-to-run spread of this machine). Session 30, each of the 38 costs measured 4 times at 2 ms and 4 times
at 1 ms, interleaved, in one run: the medians' ratio 1 ms / 2 ms 0.90–1.07 (geometric mean 0.997), the
spread of a method's 4 values (max/min) median 1.07 against 1.10 (90th percentile 1.23 against 1.41), a
run of the 38 costs 0.56 s against 0.68 s."""
_COST_MIN_SECONDS = 0.005
"""The least wall time the measured call is repeated for (and at least 7 times; the median is the cost),
unless its median is known first (`cost._median_time`: its 95 % interval within ± 3 %, after 6 calls or
more). At 0.2 s, 23 methods spent ~4.6 s of a Cornell-box audit here. Issue 33, session 24: each of the 38
methods of a Cornell-box audit at 64² timed 4 times at each setting, interleaved, in one run: a run took
1.34 s at 0.05 s (sessions 19–23), 0.83 s at 0.01 s and 0.80 s with no floor; the spread of a method's 4
costs (max/min) was the same at all three (median 1.10, 1.09, 1.08; 90th percentile 1.46, 1.48, 1.34) and
the medians agreed (0.01 s against 0.05 s: geometric mean 1.02, 0.92–1.23). Repeating a 2 ms kernel for
longer does not make its cost more precise on this machine: the spread between runs is the machine's.
Session 33, each of the 38 costs measured 4 times at 0.01 and at 0.005 s, interleaved, in one run: the spread
of a method's 4 values (max/min) median 1.026 / 1.027, 90th percentile 1.13 / 1.09; the medians' ratio
0.005 s / 0.01 s geometric mean 1.003 (0.97–1.04); a run of the 38 costs 0.57 / 0.47 s. 0.005 s since. Not
kept: a shorter measured call (`_COST_CALL_SECONDS` 0.5 ms: on half the elements the inputs of the
many-input kernels fit the caches, AO's 32 distances timed 1.6 ns a pixel against 3.7), and the calls
replayed as a frozen Dr.Jit function (``dr.freeze``, no tracing between them: the SDF cone tracer's ten
kernels timed 384 ns a pixel replayed against 690 traced, whose kernels shared the cores with the tracing
of the next), which aborted the process (``RecordThreadState::enqueue_host_func(): this function cannot be
recorded!``, an uncatchable C++ exception) on a text that frees a mapped NumPy table inside the call."""
_PROBE_REPEATS = 1
"""Calls of the sizing call (`_COST_PROBE` elements) after its warm-up, the median sizing the measured call:
it need only be right to a factor (the measured call's 1 ms target, `_COST_CALL_SECONDS`); 7 before session
24, 3 before session 33. Issue 33, session 33: each of the Cornell box's 38 costs measured 4 times with 3 and
with 1, interleaved, in one run: the spread of a method's 4 values median 1.048 / 1.061 (90th percentile
1.43 / 1.33), of the elements its measured call was sized to median 1.04 both (max 1.56 / 1.73), the medians'
ratio 1 / 3 geometric mean 0.998 (0.94–1.07); a run of the 38 costs 0.74 → 0.64 s. A text slow to trace pays
most: teapot's ibl-samples depth-map rows trace ~25 ms a call."""


def _is_per_pixel(v, n: int) -> bool:
    """An input with one value per masked pixel (tiled for the timing); any other array is a table."""
    return isinstance(v, (np.ndarray, np.generic)) and np.ndim(v) > 0 and np.size(v) == n


_STAGGER_STEP = 23
"""`CostInputs.backend_array` starts its k-th input (k · 23 mod 64) cache lines into a 4 KiB page: 64 inputs
on distinct offsets (23 is prime to 64), each 64-byte aligned. Issue 33 (session 28): arrays that all start
at one offset in their pages (Dr.Jit's own allocations are 2 MiB aligned) read their i-th elements from one
cache set, and a kernel streaming many inputs thrashes it: colour bleeding's one-bounce gather (48 per-pixel
inputs) timed 1.38–1.40× slower on such arrays than on NumPy's (whose heap offsets happen to differ), the
same data. Staggered, a cost is what the kernel does with its inputs, not where an allocator put them."""


@dataclass
class CostInputs:
    """One case's per-pixel inputs as its methods' cost measurements read them (`method_cost`): each cleaned
    (a non-finite value → float32's max) and cast to float32 once (`cleaned`), then repeated to each size a
    timing asks for (`backend_array`: element i is value i mod n, the cyclic repeat), one array per input
    and size that every method of the case reading it at that size is handed.

    Issue 33 (session 20): every method tiled and copied its own inputs (a 2^20-element tile, then an aligned
    copy of it): 1.4 of the 6.3 CPU s of a Cornell-box audit's cost loop. Session 28: the repeat was made in
    three passes over its 4 MiB (NumPy's tile, an aligned copy kept on the host, the Dr.Jit array's own
    aligned copy), 0.16–0.20 s of a 64² Cornell-box audit's 0.82–1.00 s of costs; it is now written once,
    straight into the buffer the Dr.Jit array maps, and no tile is kept besides. Kept for one case
    (`audit_run`'s case loop makes one per case)."""

    budget: int = _COST_INPUT_BYTES
    """The most bytes of repeated arrays kept (`backend_array`; the oldest dropped first): what one method's
    own copies held at most before session 27, so the peak memory stays where it was."""
    clean: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    """(input name, id of its array) → (the array, its cleaned float32 values); the array is kept so its id
    stays its own."""
    on_backend: dict[tuple[str, int, int, type], tuple[np.ndarray, Any]] = field(default_factory=dict)
    """(input name, id of its array, elements, Dr.Jit type) → (the array, its values repeated to that many
    elements as a Dr.Jit array of that type: `backend_array`)."""
    made: int = 0
    """Repeats made so far (each starts at its own offset in its page: `_STAGGER_STEP`)."""
    digests: dict[int, tuple[np.ndarray, bytes]] = field(default_factory=dict)
    """The case's arrays' digests for the cost store's keys (`cost_store.cost_key`), hashed once a case."""

    def cleaned(self, name: str, v: Any) -> np.ndarray:
        """``v`` (a per-pixel input of n ≥ 1 elements) flat, each non-finite value replaced by float32's max
        (a kernel timed on NaN may take another path), as float32; made once."""
        key = (name, id(v))
        known = self.clean.get(key)
        if known is not None and known[0] is v:
            return known[1]
        a = np.asarray(v, np.float64).reshape(-1)
        out = np.where(np.isfinite(a), a, np.finfo(np.float32).max).astype(np.float32)
        self.clean[key] = (v, out)
        return out

    def host_prefix(self, name: str, v: Any, size: int) -> np.ndarray:
        """The first ``size`` elements of ``v``'s cyclic repeat (`cleaned`): the host's copy of the start of
        what `backend_array` holds, for a trial call on a few elements."""
        return np.resize(self.cleaned(name, v), size)

    def backend_array(self, name: str, v: Any, size: int, Float: type) -> Any:
        """``v``'s cleaned values (`cleaned`) repeated to ``size`` elements as a ``Float`` array: written in
        one pass into a fresh host buffer, 64-byte aligned (`rtfit.realtime.arrays.to_drjit`: one compiled
        kernel whatever the address) and staggered in its page (`_STAGGER_STEP`), which Dr.Jit's LLVM
        backend maps (the array holds it; CUDA copies it to the device). Made once per input and size and
        handed to every method of the case that reads it there."""
        key = (name, id(v), int(size), Float)
        known = self.on_backend.get(key)
        if known is not None and known[0] is v:
            return known[1]
        a = self.cleaned(name, v)
        out = aligned_empty(size, np.float32, offset=(self.made * _STAGGER_STEP) % 64 * 64, period=4096)
        self.made += 1
        reps = size // a.size
        out[: reps * a.size].reshape(reps, a.size)[...] = a
        out[reps * a.size :] = a[: size - reps * a.size]
        array = Float(out)
        self.on_backend.pop(key, None)
        while self.on_backend and 4 * (sum(k[2] for k in self.on_backend) + size) > self.budget:
            self.on_backend.pop(next(iter(self.on_backend)))
        self.on_backend[key] = (v, array)
        return array


def method_cost(
    method: Method,
    case: FamilyCase,
    backend: str,
    size: int = COST_ELEMENTS,
    min_seconds: float = _COST_MIN_SECONDS,
    tiles: CostInputs | None = None,
    repeats: int = 7,
) -> dict:
    """ns per pixel of ``method`` (declared parameters) on the backend, its per-pixel inputs (channel 0 of the
    case) tiled to ``size`` float32 elements; a table (an array that is not per pixel) is passed as it is.

    A kernel that would take longer than `_COST_CALL_SECONDS` a call at ``size`` (timed first on
    `_COST_PROBE` elements) is timed on proportionally fewer, never fewer than `_COST_PROBE`: a cone tracer at
    ~10 µs a pixel on 2 CPU cores took 10 s a call on 2^20 elements, 80 s for its 7 repeats + warm-up. The
    sizing call is the median of `_PROBE_REPEATS` calls with no minimum duration (``min_seconds`` 0: it only
    sizes the measured call, which keeps its `_COST_MIN_SECONDS`): 15 methods' sizing calls took 2.9 s of a
    Cornell-box audit's evaluation at 0.2 s each. ``tiles``: the case's tiled inputs, shared by its methods
    (`CostInputs`; None: made for this call alone). ``repeats``: the fewest calls timed
    (`cost.time_drjit`)."""
    tiles = CostInputs() if tiles is None else tiles
    n = int(case.mask.sum())
    inputs = {name: case.channel_inputs[0][name] for name in method.input_names}
    per_pixel = [name for name, v in inputs.items() if _is_per_pixel(v, n)]
    size = min(size, max(_COST_PROBE, _COST_INPUT_BYTES // (4 * max(len(per_pixel), 1))))
    probed = size > _COST_PROBE
    if probed:
        probe = method_cost(
            method, case, backend, _COST_PROBE, min_seconds=0.0, tiles=tiles, repeats=_PROBE_REPEATS
        )
        per_element = probe["ns_per_pixel"] * 1e-9
        size = int(min(size, max(_COST_PROBE, _COST_CALL_SECONDS / max(per_element, 1e-15))))
    Float = backend_float(backend)
    reps = max(1, -(-size // max(n, 1)))
    args, host, keys, consts, uniforms = [], [], [], {}, {}
    for name, v in inputs.items():
        if not isinstance(v, (int, float, np.ndarray, np.generic)):  # a sampler object (a distance field)
            consts[name] = v
        elif np.ndim(v) and not _is_per_pixel(v, n):
            table = np.ascontiguousarray(v, np.float32).reshape(-1)
            consts[name] = to_drjit(Float, table)
            if table.size <= _UNIFORM_FLOATS:
                uniforms[name] = Uniforms.of(table)
        elif np.ndim(v):
            host.append(tiles.host_prefix(name, v, min(size, _COST_PROBE)))  # the trial below reads no more
            # the case's repeat at this size, shared by its methods (`CostInputs.backend_array`): a buffer
            # of its own that the Dr.Jit array maps, no view of a shared tile (a quick suite on the GPU host
            # ended in a segmentation fault once while shared tiles were mapped; not reproduced, a precaution)
            args.append(tiles.backend_array(name, v, size, Float))
            keys.append(name)
        else:
            consts[name] = float(v)
    elements = min(n * reps, size) if keys else 1
    if uniforms:  # a small table read by index, as a shader's constant buffer (`Uniforms`: nothing folded)
        trial = [to_drjit(Float, a) for a in host]  # reads the table by index? (small)
        try:
            given = {**consts, **uniforms, **dict(zip(keys, trial, strict=True))}
            dr.eval(method.evaluate(given, folded=True))
            consts.update(uniforms)
        except (TypeError, IndexError, AttributeError, RuntimeError):  # a kernel that gathers from it
            pass

    def call(*xs):  # the declared values folded into the kernel, as a shader's constants (`evaluate`)
        return method.evaluate({**consts, **dict(zip(keys, xs, strict=True))}, folded=True)

    # the sizing call compiled this kernel (and warmed it up): Dr.Jit's kernels do not depend on the size
    t = time_drjit(call, tuple(args), elements, repeats, min_seconds, warm_up=not probed)
    release_backend_tables(consts.values())  # a sampler's large tables: not kept past the timing
    return {**t.to_dict(), "backend": backend}
