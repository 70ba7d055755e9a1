"""The ꟻLIP machinery of the ``flip`` metric (`rtfit.fitting.metrics`): its exposure range, its inputs,
its maps memoised by content, and several maps computed side by side in one call of ꟻLIP (tiling).

ꟻLIP: ``flip_evaluator.evaluate(reference, test, "HDR", applyMagma=False)`` on contiguous float32 (H, W, 3)
arrays with negative values clipped to 0; the exposure range by ꟻLIP's own rule on the luminances of the
masked reference (`flip_exposures`; the module text of `rtfit.fitting.metrics` gives the details).
flip_evaluator calls ``sys.exit`` on bad arguments, so everything is validated before it is called.

Memoised (results bit-identical, only the time changes): a ꟻLIP map is computed once per (reference, test,
exposures) and reused by the report's error-map figure (`flip_map`); keys are content digests
(`rtfit.fitting.metric_noise.content_digest`), and the memo keeps at most `MEMO_MAP_BYTES` of maps.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import math
import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from .metric_noise import content_digest, noise_rng

__all__ = [
    "FLIP_MIN_SIZE",
    "FLIP_PPD",
    "FLIP_TILES_MAX",
    "FLIP_TILE_PAD",
    "MEMO_MAP_BYTES",
    "compute_flip_maps",
    "flip_exposures",
    "flip_input",
    "flip_map",
    "flip_maps_tiled",
    "flip_mean",
    "flip_noisy_references",
    "flip_one_thread",
    "luminance",
]

FLIP_PPD = 67.02064514160156  # ꟻLIP's default pixels per degree (0.7 m from a 0.7 m wide 4K display)
# ꟻLIP's widest filter: the colour CSF of scale 0.04, radius ceil(3·sqrt(0.04/(2π²))·ppd) = 10 → 21 px.
FLIP_MIN_SIZE = 2 * math.ceil(3.0 * math.sqrt(0.04 / (2.0 * math.pi**2)) * FLIP_PPD) + 1
_FLIP_NEG_WARN = 1e-6
MEMO_MAP_BYTES = 64 << 20
"""Bytes of ꟻLIP maps kept (a 1024² map is 8 MiB)."""
_map_lock = threading.Lock()
_map_memo: OrderedDict[tuple, np.ndarray] = OrderedDict()
MEMOS = (_map_memo,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def luminance(rgb):
    """The luminance Y of linear-sRGB ``rgb`` (..., 3): 0.2126 R + 0.7152 G + 0.0722 B."""
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def flip_exposures(r, m) -> dict:
    """ꟻLIP's HDR exposure rule (ACES, t = 0.85) on the masked reference luminances.

    The rule reads the reference as ꟻLIP does, rounded to float32 (`flip_input`), then computes in float64:
    an image saved as float32 (the report viewer's pixels, `rtfit.experiments.viewer`) gives the same
    exposures as the float64 image it was saved from, hence the same maps, found in the memo (issue 33: the
    viewer computed every row's map again for exposures a few ulps apart, ~1.5 CPU s of a 64² audit)."""
    r = np.asarray(r, dtype=np.float32).astype(np.float64)
    tc = (0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14)
    t = 0.85
    a, b, c = tc[0] - t * tc[3], tc[1] - t * tc[4], tc[2] - t * tc[5]
    x_max = (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    y = luminance(np.maximum(r, 0.0))[m]
    y_max = float(y.max())
    y_med = float(np.median(y))
    if not y_med > 0:
        y_med = float(np.median(y[y > 0]))
    start = math.log2(x_max / y_max)
    stop = math.log2(x_max / y_med)
    if not stop > start + 1e-3:
        stop = start + 1.0
    n = max(2, math.ceil(stop - start))
    return {"startExposure": float(start), "stopExposure": float(stop), "numExposures": int(n)}


def flip_input(a, name, peak, warn):
    """``a`` as ꟻLIP takes it: contiguous float32 with negative values clipped to 0; ``warn``: warn (naming
    ``name``) where values below −1e-6·``peak`` are clipped (the warning points at `compute_metrics`'
    caller)."""
    a = np.asarray(a, dtype=np.float64)
    if warn:
        lim = -_FLIP_NEG_WARN * max(peak, np.finfo(np.float32).tiny)
        n_neg = int(np.sum(a < lim))
        if n_neg:
            warnings.warn(
                f"flip: {n_neg} values of {name} below -1e-6·peak clipped to 0 (HDR-FLIP needs "
                f"non-negative radiance; min {a.min():.3g})",
                RuntimeWarning,
                stacklevel=4,
            )
    return np.ascontiguousarray(np.maximum(a, 0.0), dtype=np.float32)


def flip_mean(ref32, test32, m, params) -> float:
    """The mean over the mask ``m`` of the ꟻLIP map of ``test32`` against ``ref32`` (`flip_map`)."""
    return float(np.mean(flip_map(ref32, test32, params)[m]))


def flip_map(ref32, test32, params) -> np.ndarray:
    """The ꟻLIP map of ``test32`` against ``ref32``, computed once per content and exposures (module
    text); the caller gets its own copy."""
    key = (content_digest(ref32, test32), tuple(sorted(params.items())))
    with _map_lock:
        if key in _map_memo:
            _map_memo.move_to_end(key)
            return _map_memo[key].copy()
    fmap = _flip_map_uncached(ref32, test32, params)
    with _map_lock:
        _map_memo[key] = fmap.copy()
        while sum(v.nbytes for v in _map_memo.values()) > MEMO_MAP_BYTES and len(_map_memo) > 1:
            _map_memo.popitem(last=False)
    return fmap


FLIP_TILE_PAD = FLIP_MIN_SIZE // 2
"""Edge-replicated columns on each side of each image when several ꟻLIP maps are computed in one call
(`compute_flip_maps`, behind `rtfit.fitting.metrics.prime_flip`): ꟻLIP's widest filter radius (10 px at its
default pixels per degree; each of its filters is one pass over the input), so that no filter reaches a
neighbour's pixels and every map equals the map of its pair alone, bit for bit (tests/test_metrics.py checks
it against separate calls; 9 columns do not). One call of ꟻLIP cost ~0.1 s on 2 loaded CPU cores at any size
up to ~64² (its threads' synchronisation; a 64² map is ~10 ms of work on one idle thread): one call for a
case's rows instead of one per row is most of the saving. Issue 33 (session 18): the pad was the whole
filter width (21 columns a side) before; at 10, a 64-wide image is tiled 84 columns wide, not 106: 15 pairs
of 64² in one call took 0.40 CPU s instead of 0.52 on one thread (OMP_NUM_THREADS=1, 4 rounds alternated;
separate calls 0.29 there, but not on loaded cores)."""
FLIP_TILES_MAX = 16
"""At most this many pairs per tiled ꟻLIP call (its working memory grows with the tiled width)."""


def flip_maps_tiled(pairs: list[tuple[np.ndarray, np.ndarray]], params) -> list[np.ndarray]:
    """The ꟻLIP maps of ``pairs`` (reference, test; float32 (H, W, 3) of one shape), side by side in one call
    per `FLIP_TILES_MAX` pairs, each padded by `FLIP_TILE_PAD` edge-replicated columns."""
    pad = FLIP_TILE_PAD
    out: list[np.ndarray] = []
    for i in range(0, len(pairs), FLIP_TILES_MAX):
        chunk = pairs[i : i + FLIP_TILES_MAX]
        if len(chunk) == 1:
            out.append(_flip_map_uncached(chunk[0][0], chunk[0][1], params))
            continue
        w = chunk[0][0].shape[1]

        def tiled(images):
            return np.ascontiguousarray(
                np.concatenate([np.pad(a, ((0, 0), (pad, pad), (0, 0)), mode="edge") for a in images], axis=1)
            )

        fmap = _flip_map_uncached(tiled([a for a, _ in chunk]), tiled([b for _, b in chunk]), params)
        step = w + 2 * pad
        out += [fmap[:, k * step + pad : k * step + pad + w].copy() for k in range(len(chunk))]
    return out


def compute_flip_maps(pairs: list[tuple[np.ndarray, np.ndarray]], params) -> int:
    """Compute the ꟻLIP maps of the ``pairs`` (reference, test) not yet in the memo, side by side in as few
    calls as possible (`flip_maps_tiled`), and keep them in the memo, where `flip_map` finds them. Returns
    the number of maps computed."""
    keyed, todo = {}, []
    for a, b in pairs:
        key = (content_digest(a, b), tuple(sorted(params.items())))
        with _map_lock:
            known = key in _map_memo
        if not known and key not in keyed:
            keyed[key] = len(todo)
            todo.append((a, b))
    maps = flip_maps_tiled(todo, params)
    with _map_lock:
        for key, k in keyed.items():
            _map_memo[key] = maps[k]
        while sum(v.nbytes for v in _map_memo.values()) > MEMO_MAP_BYTES and len(_map_memo) > 1:
            _map_memo.popitem(last=False)
    return len(todo)


@functools.cache
def _flip_openmp() -> tuple | None:
    """(get, set) of the thread count of the OpenMP runtime that ꟻLIP's extension carries
    (``flip_evaluator.libs/libgomp-*.so``, loaded with it), or None where it is not found."""
    import flip_evaluator

    libs = os.path.join(os.path.dirname(os.path.dirname(flip_evaluator.__file__)), "flip_evaluator.libs")
    try:
        names = sorted(n for n in os.listdir(libs) if n.startswith("libgomp"))
    except OSError:
        return None
    for name in names:
        try:
            lib = ctypes.CDLL(os.path.join(libs, name), mode=os.RTLD_NOLOAD | os.RTLD_LOCAL)
        except OSError:
            continue
        get, put = lib.omp_get_max_threads, lib.omp_set_num_threads
        get.restype, get.argtypes = ctypes.c_int, []
        put.restype, put.argtypes = None, [ctypes.c_int]
        return get, put
    return None


@contextmanager
def flip_one_thread() -> Iterator[None]:
    """Run the block's ꟻLIP calls on one OpenMP thread, then restore the count. OpenMP's thread count is
    a setting of the calling thread, so other threads' ꟻLIP calls are not affected. Where ꟻLIP's OpenMP
    runtime is not found nothing changes. `_flip_map_uncached` uses it off the main thread only: for maps
    computed beside other work (the report's viewer thread next to the figures).

    Why (issue 33): ꟻLIP splits each of its filter passes over every OpenMP thread. On 2 CPU cores shared
    with other work the threads spend more time waiting for each other than working (session 19: 15 pairs of
    64² in one tiled call took 1.05–1.14 CPU s, 2.6–2.9 s wall, on 2 threads against 0.71–0.81 CPU s,
    1.8–2.1 s, on one), so every call ran on one thread. On 2 idle cores, where the audit's own calls run
    (session 21, 12 pairs tiled, two rounds): 256² 9.9 / 6.3 s wall on one thread, 5.8 / 3.3 s on two, the
    same CPU seconds; 64² 0.36 / 0.55 s against 0.19 / 0.22 s. The maps are bit-identical (each pixel is
    computed alike whatever thread computes it; tests/test_metrics.py)."""
    omp = _flip_openmp()
    if omp is None:
        yield
        return
    get, put = omp
    before = get()
    put(1)
    try:
        yield
    finally:
        put(before)


def _flip_map_uncached(ref32, test32, params) -> np.ndarray:
    import flip_evaluator

    # flip_evaluator exits the process on bad arguments: check everything it checks, and more.
    for a in (ref32, test32):
        if not (
            a.dtype == np.float32
            and a.ndim == 3
            and a.shape[2] == 3
            and a.flags.c_contiguous
            and np.all(np.isfinite(a))
            and a.min() >= 0.0
        ):
            raise ValueError("internal: flip input must be finite non-negative contiguous float32 (H, W, 3)")
    if ref32.shape != test32.shape or min(ref32.shape[:2]) < FLIP_MIN_SIZE:
        raise ValueError(f"internal: flip inputs must share a shape of at least {FLIP_MIN_SIZE} pixels")
    if not (params["startExposure"] < params["stopExposure"] and params["numExposures"] >= 2):
        raise ValueError(f"internal: bad flip exposure parameters {params}")
    # Off the main thread (the report's viewer maps beside the figures) one OpenMP thread; on it, ꟻLIP's own
    # threads (`flip_one_thread`'s text says why)
    beside = threading.current_thread() is not threading.main_thread()
    with flip_one_thread() if beside else contextlib.nullcontext():
        fmap, _, _ = flip_evaluator.evaluate(
            ref32, test32, "HDR", applyMagma=False, computeMeanError=False, parameters=dict(params)
        )
    return np.asarray(fmap, dtype=np.float64).reshape(ref32.shape[:2])


def flip_noisy_references(r, s, seed, draws, peak) -> list[np.ndarray]:
    """The ``draws`` noisy references r + σ·ε of the ꟻLIP noise floor (float32, clipped at 0)."""
    rng = noise_rng(seed, "flip")
    return [flip_input(r + s * rng.standard_normal(r.shape), "", peak, False) for _ in range(draws)]
