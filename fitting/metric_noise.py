"""The pieces every Monte Carlo noise floor of `rtfit.fitting.metrics` shares: the seeded noise of each
metric's draws, content digests of arrays, and the memo that computes each floor once per reference.

A noise floor depends on the reference, its stderr, the mask, the seed and the draws — never on the
approximation — so `memo_floor` computes it once per (reference, stderr, mask, seed, draws) and reuses it
for every row compared with that reference (results bit-identical, only the time changes). Keys are
content digests (`content_digest`), so a changed array never hits a stale entry; the memo keeps at most
`MEMO_ENTRIES` floors.
"""

from __future__ import annotations

import hashlib
import threading
import zlib
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

__all__ = [
    "MEMO_ENTRIES",
    "content_digest",
    "memo_floor",
    "noise_rng",
]


def noise_rng(seed: int, name: str) -> np.random.Generator:
    """The generator of metric ``name``'s noise draws ε, seeded by ``(seed, crc32(name))``."""
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())])


MEMO_ENTRIES = 256
"""Noise floors kept (floats: a few kB)."""
_floor_lock = threading.Lock()
_floor_memo: OrderedDict[tuple, float] = OrderedDict()
MEMOS = (_floor_memo,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def content_digest(*arrays) -> tuple:
    """A content key of ``arrays``: shape, dtype and a BLAKE2b digest of the bytes of each."""
    out = []
    for a in arrays:
        a = np.ascontiguousarray(a)
        # the array's own buffer, not a copy of it (``tobytes``): a 256² float64 image is 1.5 MB a digest
        digest = hashlib.blake2b(a.reshape(-1).view(np.uint8).data, digest_size=16).digest()
        out.append((a.shape, a.dtype.str, digest))
    return tuple(out)


def memo_floor(
    name: str,
    r,
    s,
    m,
    seed: int,
    draws: int,
    compute: Callable[[], float],
    digest: Callable[[], tuple] | None = None,
) -> float:
    """The noise floor ``compute()`` of metric ``name``, computed once per (reference ``r``, stderr ``s``,
    mask ``m``, seed, draws): the floors depend on nothing else (module text). ``digest()``: their
    `content_digest`, kept by the caller (`rtfit.fitting.metrics.compute_metrics` makes it once for all its
    metrics: issue 33, three digests of 3 MB a row at 256²); None: made here."""
    key = (name, int(seed), int(draws), content_digest(r, s, m) if digest is None else digest())
    with _floor_lock:
        if key in _floor_memo:
            _floor_memo.move_to_end(key)
            return _floor_memo[key]
    value = compute()
    with _floor_lock:
        _floor_memo[key] = value
        while len(_floor_memo) > MEMO_ENTRIES:
            _floor_memo.popitem(last=False)
    return value
