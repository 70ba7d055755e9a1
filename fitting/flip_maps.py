"""The ꟻLIP machinery of the ``flip`` metric (`rtfit.fitting.metrics`): its exposure range, its inputs,
its maps memoised by content, and the maps of several pairs computed together (`compute_flip_maps`).

ꟻLIP: HDR-ꟻLIP (`rtfit.fitting.hdr_flip`, NVIDIA's reference code step for step in float32; flip_evaluator,
that code's own Python package, is the tests' oracle) on float32 (H, W, 3) arrays with negative values
clipped to 0; the exposure range by ꟻLIP's own rule on the luminances of the masked reference
(`flip_exposures`; the module text of `rtfit.fitting.metrics` gives the details).

Memoised (results bit-identical, only the time changes): a ꟻLIP map is computed once per (reference, test,
exposures) and reused by the report's error-map figure (`flip_map`); keys are content digests
(`rtfit.fitting.metric_noise.content_digest`), and the memo keeps at most `MEMO_MAP_BYTES` of maps.
"""

from __future__ import annotations

import math
import threading
import warnings
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from .hdr_flip import FLIP_PPD, hdr_flip_maps
from .metric_noise import content_digest, noise_rng

__all__ = [
    "FLIP_MIN_SIZE",
    "FLIP_PPD",
    "MEMO_MAP_BYTES",
    "compute_flip_maps",
    "flip_exposures",
    "flip_input",
    "flip_map",
    "flip_map_keys",
    "flip_maps_shared",
    "flip_mean",
    "flip_noisy_references",
    "luminance",
    "maps_since",
    "remember_maps",
]

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
        _trim()
    return fmap


def flip_maps_shared(pairs: list[tuple[np.ndarray, np.ndarray]], params, digest_of=None) -> list[np.ndarray]:
    """The ꟻLIP maps of ``pairs`` (reference, test; float32 (H, W, 3) of one shape) at the exposures
    ``params``: each distinct image (by identity, then by content) filtered once per exposure however many
    pairs hold it (`rtfit.fitting.hdr_flip.hdr_flip_maps`): a case's rows share their reference, and the
    noise floor's draws hold it as their test. Each map equals its pair's map alone, bit for bit (an image's
    features do not depend on the others; tests/test_metrics.py). ``digest_of``: the caller's
    `_digest_by_identity` (`compute_flip_maps`: its digests made once)."""
    if not (params["startExposure"] < params["stopExposure"] and params["numExposures"] >= 2):
        raise ValueError(f"internal: bad flip exposure parameters {params}")
    digest_of = digest_of or _digest_by_identity()
    images: list[np.ndarray] = []
    by_digest: dict[tuple, int] = {}

    def index(a: np.ndarray) -> int:
        k = by_digest.setdefault(digest_of(a), len(images))
        if k == len(images):  # a new image: checked once, however many pairs hold it
            _check_input(a, pairs[0][0].shape)
            images.append(a)
        return k

    indexed = [(index(a), index(b)) for a, b in pairs]
    return hdr_flip_maps(images, indexed, params)


def _digest_by_identity() -> Callable[[np.ndarray], tuple]:
    """An array's content digest (`content_digest`), each array hashed once however often it is asked for
    (by identity: the arrays are held by the caller throughout its call): a case's shared reference is
    hashed once, not once a pair."""
    digests: dict[int, tuple] = {}

    def digest_of(a: np.ndarray) -> tuple:
        if id(a) not in digests:
            digests[id(a)] = content_digest(a)[0]
        return digests[id(a)]

    return digest_of


def _check_input(a: np.ndarray, shape) -> None:
    """ꟻLIP's inputs: finite, non-negative, contiguous float32 (H, W, 3) of one shape, at least
    `FLIP_MIN_SIZE` pixels a side (the metric's domain: ꟻLIP's widest filter)."""
    if not (
        a.dtype == np.float32
        and a.ndim == 3
        and a.shape[2] == 3
        and a.flags.c_contiguous
        and np.all(np.isfinite(a))
        and a.min() >= 0.0
    ):
        raise ValueError("internal: flip input must be finite non-negative contiguous float32 (H, W, 3)")
    if a.shape != shape or min(a.shape[:2]) < FLIP_MIN_SIZE:
        raise ValueError(f"internal: flip inputs must share a shape of at least {FLIP_MIN_SIZE} pixels")


def compute_flip_maps(pairs: list[tuple[np.ndarray, np.ndarray]], params) -> int:
    """Compute the ꟻLIP maps of the ``pairs`` (reference, test) not yet in the memo, together
    (`flip_maps_shared`: each image's share once), and keep them in the memo, where `flip_map` finds them.
    Returns the number of maps computed."""
    keyed, todo = {}, []
    digest_of = _digest_by_identity()
    for a, b in pairs:  # (the shared reference hashed once, not once a pair)
        key = ((digest_of(a), digest_of(b)), tuple(sorted(params.items())))
        with _map_lock:
            known = key in _map_memo
        if not known and key not in keyed:
            keyed[key] = len(todo)
            todo.append((a, b))
    maps = flip_maps_shared(todo, params, digest_of) if todo else []
    with _map_lock:
        for key, k in keyed.items():
            _map_memo[key] = maps[k]
        _trim()
    return len(todo)


def _trim() -> None:
    """The memo's oldest maps dropped while it holds more than `MEMO_MAP_BYTES` (under ``_map_lock``)."""
    while sum(v.nbytes for v in _map_memo.values()) > MEMO_MAP_BYTES and len(_map_memo) > 1:
        _map_memo.popitem(last=False)


def flip_map_keys() -> frozenset:
    """The memo's keys now (`maps_since`)."""
    with _map_lock:
        return frozenset(_map_memo)


def maps_since(known: frozenset) -> list[tuple[tuple, np.ndarray]]:
    """The memo's maps whose keys are not in ``known`` (`flip_map_keys`): what a task computed, handed
    back from another process (the audit's metrics helper, `rtfit.experiments.audit_cases`) to
    `remember_maps`."""
    with _map_lock:
        return [(k, v) for k, v in _map_memo.items() if k not in known]


def remember_maps(entries: list[tuple[tuple, np.ndarray]]) -> None:
    """Maps computed elsewhere (`maps_since`) kept in this process's memo, as if computed here: the report's
    figures then find them (`flip_map`)."""
    with _map_lock:
        for key, fmap in entries:
            if key not in _map_memo:
                _map_memo[key] = fmap
        _trim()


def _flip_map_uncached(ref32, test32, params) -> np.ndarray:
    """The ꟻLIP map of one pair (`flip_maps_shared`)."""
    return flip_maps_shared([(ref32, test32)], params)[0]


def flip_noisy_references(r, s, seed, draws, peak) -> list[np.ndarray]:
    """The ``draws`` noisy references r + σ·ε of the ꟻLIP noise floor (float32, clipped at 0)."""
    rng = noise_rng(seed, "flip")
    return [flip_input(r + s * rng.standard_normal(r.shape), "", peak, False) for _ in range(draws)]
