"""The clamped-cosine sum of a lat-long midpoint rule by prefix sums along its rows (issue 33).

`rtfit.reference.environments` integrates a distant environment with a dense midpoint rule over a
lat-long grid, E(n) = Σ_k w_k L_k max(n·d_k, 0). On one row of the grid (fixed θ, azimuths φ_i = 2π(i + ½)/W)
n·d = sin θ ρ cos(φ − φ₀) + n_z cos θ (ρ = |n_xy|, φ₀ the normal's azimuth) is positive on one arc of
columns, so the row's share is n · Σ_{i ∈ arc} w_i L_i d_i: three prefix sums per channel and row, two
look-ups per normal and row — O(rows) per normal instead of O(rows × columns). The arc's ends come from
arccos, then are checked against the sign of n·d at the end columns themselves, so the columns summed are
those the dense rule counts (up to products within round-off of zero); the sums agree with the dense ones
to round-off (the summation order moved)."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

_CHUNK = 1 << 18  # normal × row pairs per block (each gathers 2 or 3 × 3C prefix values)
_TABLES_BYTES = 128 << 20  # `cached_table` keeps the latest tables up to this size


@dataclass(frozen=True)
class LatLongTable:
    """A grid's prefix sums (`latlong_table`): ``prefix`` (rows·(cols + 1), 3 C), each row's running sums
    of w L d from φ = 0 (an arc that wraps past φ = 2π is two differences), the directions' components
    ``flat`` (3 × (rows·cols,)), each row's cos θ ``z`` and sin θ ``s``."""

    prefix: np.ndarray
    flat: tuple
    z: np.ndarray
    s: np.ndarray
    cols: int
    channels: int

    @property
    def nbytes(self) -> int:
        return self.prefix.nbytes + sum(x.nbytes for x in self.flat) + self.z.nbytes + self.s.nbytes


def latlong_table(d, wl, rows: int, cols: int) -> LatLongTable:
    """The prefix sums of a lat-long grid in row-major order: directions ``d`` (rows·cols, 3),
    d = (sin θ_j sin φ_i, sin θ_j cos φ_i, cos θ_j) with φ_i = 2π(i + ½)/cols, and weighted radiance ``wl``
    (rows·cols, C) (solid-angle weight times radiance)."""
    d = np.asarray(d, np.float64).reshape(rows, cols, 3)
    wl = np.asarray(wl, np.float64).reshape(rows, cols, -1)
    channels = wl.shape[2]
    terms = (d[:, :, :, None] * wl[:, :, None, :]).reshape(rows, cols, 3 * channels)
    prefix = np.zeros((rows, cols + 1, 3 * channels))
    np.cumsum(terms, axis=1, out=prefix[:, 1:])
    flat = tuple(np.ascontiguousarray(d[:, :, k].reshape(-1)) for k in range(3))
    z, s = d[:, 0, 2].copy(), np.hypot(d[:, 0, 0], d[:, 0, 1])
    return LatLongTable(prefix.reshape(rows * (cols + 1), 3 * channels), flat, z, s, cols, channels)


_TABLES: OrderedDict[Hashable, LatLongTable] = OrderedDict()
MEMOS = (_TABLES,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def cached_table(key: Hashable, build: Callable[[], LatLongTable]) -> LatLongTable:
    """The table under ``key`` (the caller's digest of everything ``build`` reads), built on first use;
    the most recent tables are kept while they fit in 128 MiB (an environment is integrated many times)."""
    table = _TABLES.pop(key, None) or build()
    _TABLES[key] = table
    while len(_TABLES) > 1 and sum(t.nbytes for t in _TABLES.values()) > _TABLES_BYTES:
        _TABLES.popitem(last=False)
    return table


def latlong_irradiance(normals, d, wl, rows: int, cols: int) -> np.ndarray:
    """Σ_k wl_k max(n·d_k, 0) (N, C) at unit ``normals`` (N, 3) over the lat-long grid of `latlong_table`."""
    return table_irradiance(normals, latlong_table(d, wl, rows, cols))


def table_irradiance(normals, table: LatLongTable) -> np.ndarray:
    """`latlong_irradiance` from the grid's `LatLongTable`."""
    n = np.asarray(normals, np.float64)
    out = np.zeros((len(n), table.channels))
    step = max(1, _CHUNK // len(table.z))
    for a in range(0, len(n), step):
        sums = _row_sums(n[a : a + step], table).reshape(-1, 3, table.channels)
        out[a : a + step] = np.einsum("nk,nkc->nc", n[a : a + step], sums)
    return out


def _row_sums(n: np.ndarray, table: LatLongTable):
    """Σ over the rows of each row's arc sum of the prefixed terms, (N, 3·C)."""
    flat, prefix, z, s, cols = table.flat, table.prefix, table.z, table.s, table.cols
    rows = len(z)
    nx, ny, nz = (n[:, k : k + 1] for k in range(3))
    rho = np.hypot(nx, ny)
    phi0 = np.mod(np.arctan2(nx, ny), 2.0 * math.pi)
    num, den = -nz * z[None, :], rho * s[None, :]  # n·d > 0 ⇔ cos(φ − φ₀) > num/den
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(den > 0, num / np.where(den > 0, den, 1.0), np.where(num < 0, -np.inf, np.inf))
    alpha = np.arccos(np.clip(c, -1.0, 1.0))
    delta = 2.0 * math.pi / cols
    first = np.ceil((phi0 - alpha) / delta - 0.5).astype(np.int64)
    last = np.floor((phi0 + alpha) / delta - 0.5).astype(np.int64)
    count = np.clip(last - first + 1, 0, cols)
    count = np.where(c <= -1.0, cols, np.where(c >= 1.0, 0, count))
    lo = np.mod(first, cols)
    base = np.arange(rows)[None, :] * cols

    def positive(i):
        k = base + np.mod(i, cols)
        return nx * np.take(flat[0], k) + ny * np.take(flat[1], k) + nz * np.take(flat[2], k) > 0

    for _ in range(3):  # the arc's ends by the sign of n·d itself (arccos is off by round-off at most)
        part = (count > 0) & (count < cols)
        shrink = part & ~positive(lo)
        grow = part & ~shrink & positive(lo - 1)
        lo = np.mod(lo + shrink - grow, cols)
        count = count - shrink + grow
        part = (count > 0) & (count < cols)
        last = positive(lo + count - 1)
        cut, extend = part & ~last, part & last & positive(lo + count)
        count = count - cut + extend
        if not (shrink.any() or grow.any() or cut.any() or extend.any()):
            break
    k = np.broadcast_to(np.arange(rows)[None, :] * (cols + 1), lo.shape).reshape(-1)
    start, end = lo.reshape(-1), (lo + count).reshape(-1)
    sums = np.take(prefix, k + np.minimum(end, cols), axis=0) - np.take(prefix, k + start, axis=0)
    wrap = end > cols  # the arc's part past φ = 2π: columns 0 … end − cols − 1
    sums[wrap] += np.take(prefix, k[wrap] + end[wrap] - cols, axis=0)
    return sums.reshape(len(n), rows, -1).sum(axis=1)
