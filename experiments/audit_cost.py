"""The engine's cost of a method: ns per pixel of its kernel on the run's backend, its per-pixel inputs
tiled to a measurable size (`method_cost`; split from `audit_run`, issue 30)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime.arrays import Uniforms, aligned_copy, backend_float, release_backend_tables, to_drjit
from rtfit.realtime.methods import Method

from .audit_family import FamilyCase
from .cost import time_drjit

COST_ELEMENTS = 1 << 20  # inputs are tiled to this many elements for the cost measurement
_COST_INPUT_BYTES = 64 << 20
"""At most this many bytes of tiled per-pixel inputs in a cost measurement (float32, every input together):
far beyond any CPU cache, so the memory traffic is still what is timed. The caustics' splats read 112
per-pixel inputs: at 2^20 elements their tiled copies were 0.9 GB (and as much again on the host), which
lifted the quick suite's peak memory to 3.9 GB (issue 33); they are timed on 2^17 elements now."""


_UNIFORM_FLOATS = 1024
"""A table of at most this many floats, where the kernel reads it by index (coefficients: SH L2's 27, L4's
75), is timed as a shader's constant buffer (`rtfit.realtime.arrays.Uniforms`): 256 float4, a uniform array
an engine declares; a larger table (a cube map's 6·16² texels) is a texture, gathered from as it is."""
_COST_PROBE = 1 << 12  # elements of the first, sizing call of a cost measurement
_COST_CALL_SECONDS = 0.002
"""The sized call's target kernel time (s; `cost.time_drjit` times the kernels, not the Python tracing them):
a slow kernel is timed on fewer elements, never fewer than `_COST_PROBE`. Every kernel up to 1.9 ns a pixel
runs on all 2^20 elements (4 MiB an input: the memory-bound ones stream from memory); a slower one is
compute-bound, and 2 ms is ≥ 2^16 elements up to 30 ns a pixel. Dr.Jit's LLVM backend spreads even 8192
elements over both cores here (a 60-step sin/cos kernel: 53 ns an element at 8192 against 48 at 2^18 on
2 threads, 100 and 96 on one), so a small call is not a one-core number. The median's stop
(`cost._median_time`) is what makes the number precise. Issue 33: at 0.05 s of wall time the 20 slowest
kernels of a Cornell-box audit ran 6–7 calls of 45–135 ms each (≈ 4 CPU s); session 20 set 0.02 s of
wall time, which, the tracing counted in the sizing call's 4096 elements, gave measured calls of 1–5 ms.
Session 23 times the kernels alone: at 0.005 s of kernel time the audit's 38 costs took 2.1–2.3 s, at
0.002 s 1.8 s (as before the change), their values 0.62–1.53× those at 0.005 s (geometric mean 0.98: the
run-to-run spread of this machine)."""
_COST_MIN_SECONDS = 0.01
"""The least wall time the measured call is repeated for (and at least 7 times; the median is the cost),
unless its median is known first (`cost._median_time`: its 95 % interval within ± 3 %, after 6 calls or
more). At 0.2 s, 23 methods spent ~4.6 s of a Cornell-box audit here. Issue 33, session 24: each of the 38
methods of a Cornell-box audit at 64² timed 4 times at each setting, interleaved, in one run: a run took
1.34 s at 0.05 s (sessions 19–23), 0.83 s at 0.01 s and 0.80 s with no floor; the spread of a method's 4
costs (max/min) was the same at all three (median 1.10, 1.09, 1.08; 90th percentile 1.46, 1.48, 1.34) and
the medians agreed (0.01 s against 0.05 s: geometric mean 1.02, 0.92–1.23). Repeating a 2 ms kernel for
longer does not make its cost more precise on this machine: the spread between runs is the machine's."""
_PROBE_REPEATS = 3
"""Calls of the sizing call (`_COST_PROBE` elements), the median sizing the measured call: it need only be
right to a factor (the measured call's 2 ms target, `_COST_CALL_SECONDS`); 7 before session 24."""


def _is_per_pixel(v, n: int) -> bool:
    """An input with one value per masked pixel (tiled for the timing); any other array is a table."""
    return isinstance(v, (np.ndarray, np.generic)) and np.ndim(v) > 0 and np.size(v) == n


@dataclass
class CostInputs:
    """One case's per-pixel inputs as its methods' cost measurements read them (`method_cost`): each cleaned
    (a non-finite value → float32's max), cast to float32 and tiled once, in a 64-byte aligned buffer
    (`aligned_copy`) at the largest size asked so far; a method is handed a prefix (the elements a tile of its
    own size held), of which its Dr.Jit array gets an aligned copy of its own (`to_drjit`).

    Issue 33 (session 20): every method tiled and copied its own inputs (a 2^20-element tile, then an aligned
    copy of it): 1.4 of the 6.3 CPU s of a Cornell-box audit's cost loop, colour-bleeding's eight methods
    tiling the same 54 inputs to 64 MiB each time (the tiling is now once a case; the copy stays per method,
    see `method_cost`). Kept for one case (`audit_run`'s case loop makes one per
    case), at most ``budget`` bytes (the oldest tiles are dropped first)."""

    budget: int = 2 * _COST_INPUT_BYTES
    tiles: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    """(input name, id of its array) → (the array, its cleaned float32 tile); the array is kept so its id
    stays its own."""
    on_backend: dict[tuple[str, int, int, type], tuple[np.ndarray, Any]] = field(default_factory=dict)
    """(input name, id of its array, elements, Dr.Jit type) → (the array, its tile's prefix as a Dr.Jit array
    of that type: `backend_array`)."""

    def backend_array(self, name: str, v: Any, size: int, Float: type) -> Any:
        """The first ``size`` elements of ``v``'s tile (`tiled`) as a ``Float`` array of their own (an aligned
        copy, `to_drjit`), made once and handed to every method of the case that reads them at this size.

        Issue 33 (session 27): each method made its own copy, the same values: obscurances' seven methods
        copied the same 32 distance inputs (64 MiB) seven times a case, colour-bleeding's eight its 54; the
        copies (`aligned_copy`) were 2.3 s of the quick suite. A Dr.Jit array is a value no kernel writes
        into, so one copy serves them all (still a copy the array owns, not the tile's memory mapped:
        `method_cost`). At most `_COST_INPUT_BYTES` are kept (the oldest dropped first): what one method's own
        copies held at most before, so the peak memory stays where it was."""
        key = (name, id(v), int(size), Float)
        known = self.on_backend.get(key)
        if known is not None and known[0] is v:
            return known[1]
        array = to_drjit(Float, self.tiled(name, v, size))
        self.on_backend.pop(key, None)
        while self.on_backend and 4 * (sum(k[2] for k in self.on_backend) + size) > _COST_INPUT_BYTES:
            self.on_backend.pop(next(iter(self.on_backend)))
        self.on_backend[key] = (v, array)
        return array

    def tiled(self, name: str, v: Any, size: int) -> np.ndarray:
        """The first ``size`` elements of ``v`` cleaned, cast to float32 and repeated (``v`` a per-pixel
        input of ``n`` ≥ 1 elements)."""
        key = (name, id(v))
        known = self.tiles.get(key)
        if known is not None and known[0] is v and known[1].size >= size:
            return known[1][:size]
        a = np.asarray(v, np.float64).reshape(-1)
        # cleaned and cast before tiling: the same elements, 1/reps the work
        a = np.where(np.isfinite(a), a, np.finfo(np.float32).max).astype(np.float32)
        tile = aligned_copy(np.tile(a, -(-size // a.size))[:size], np.float32)
        self.tiles.pop(key, None)
        while self.tiles and sum(t.nbytes for _, t in self.tiles.values()) + tile.nbytes > self.budget:
            self.tiles.pop(next(iter(self.tiles)))
        self.tiles[key] = (v, tile)
        return tile


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
        for name in per_pixel:  # tiled once at the most this call may time, the probe a prefix of it
            tiles.tiled(name, inputs[name], size)
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
            a = tiles.tiled(name, v, size)  # the case's tile, shared by its methods (`CostInputs`)
            host.append(a[:_COST_PROBE])  # the trial below reads no more
            # An aligned copy the Dr.Jit array owns (`to_drjit`), not the shared tile mapped: the arrays of
            # a kernel own their memory, as before session 20 (a quick suite on the GPU host ended in a
            # segmentation fault once while the tiles were mapped; not reproduced, and not shown to be the
            # cause: a precaution). One copy per size a case, shared by its methods (`backend_array`).
            args.append(tiles.backend_array(name, v, size, Float))
            keys.append(name)
        else:
            consts[name] = float(v)
    elements = min(n * reps, size) if keys else 1
    if uniforms:  # a small table read by index, as a shader's constant buffer (`Uniforms`: nothing folded)
        trial = [to_drjit(Float, a) for a in host]  # reads the table by index? (small)
        try:
            dr.eval(method.evaluate({**consts, **uniforms, **dict(zip(keys, trial, strict=True))}))
            consts.update(uniforms)
        except (TypeError, IndexError, AttributeError, RuntimeError):  # a kernel that gathers from it
            pass

    def call(*xs):
        return method.evaluate({**consts, **dict(zip(keys, xs, strict=True))})

    # the sizing call compiled this kernel (and warmed it up): Dr.Jit's kernels do not depend on the size
    t = time_drjit(call, tuple(args), elements, repeats, min_seconds, warm_up=not probed)
    release_backend_tables(consts.values())  # a sampler's large tables: not kept past the timing
    return {**t.to_dict(), "backend": backend}
