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

import numpy as np

_CHUNK = 1 << 18  # normal × row pairs per block (each gathers 2 × 3 × C prefix values)


def latlong_irradiance(normals, d, wl, rows: int, cols: int) -> np.ndarray:
    """Σ_k wl_k max(n·d_k, 0) (N, C) at unit ``normals`` (N, 3) over a lat-long grid in row-major
    order: directions ``d`` (rows·cols, 3), d = (sin θ_j sin φ_i, sin θ_j cos φ_i, cos θ_j) with
    φ_i = 2π(i + ½)/cols, and weighted radiance ``wl`` (rows·cols, C) (solid-angle weight times radiance)."""
    n = np.asarray(normals, np.float64)
    d = np.asarray(d, np.float64).reshape(rows, cols, 3)
    wl = np.asarray(wl, np.float64).reshape(rows, cols, -1)
    channels = wl.shape[2]
    terms = (d[:, :, :, None] * wl[:, :, None, :]).reshape(rows, cols, 3 * channels)
    prefix = np.zeros((rows, 2 * cols + 1, 3 * channels))
    np.cumsum(np.concatenate([terms, terms], axis=1), axis=1, out=prefix[:, 1:])  # doubled: arcs wrap
    prefix = prefix.reshape(rows * (2 * cols + 1), 3 * channels)
    flat = [np.ascontiguousarray(d[:, :, k].reshape(-1)) for k in range(3)]
    z = d[:, 0, 2]
    s = np.hypot(d[:, 0, 0], d[:, 0, 1])
    out = np.zeros((len(n), channels))
    step = max(1, _CHUNK // rows)
    for a in range(0, len(n), step):
        sums = _row_sums(n[a : a + step], flat, prefix, z, s, cols).reshape(-1, 3, channels)
        out[a : a + step] = np.einsum("nk,nkc->nc", n[a : a + step], sums)
    return out


def _row_sums(n: np.ndarray, flat: list, prefix: np.ndarray, z: np.ndarray, s: np.ndarray, cols: int):
    """Σ over the rows of each row's arc sum of the prefixed terms, (N, 3·C)."""
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

    for _ in range(2):  # the arc's ends by the sign of n·d itself (arccos is off by round-off at most)
        part = (count > 0) & (count < cols)
        shrink = part & ~positive(lo)
        grow = part & ~shrink & positive(lo - 1)
        lo = np.mod(lo + shrink - grow, cols)
        count = count - shrink + grow
        part = (count > 0) & (count < cols)
        end = positive(lo + count - 1)
        count = count - (part & ~end) + (part & end & positive(lo + count))
    k = (np.arange(rows)[None, :] * (2 * cols + 1) + lo).reshape(-1)
    sums = np.take(prefix, k + count.reshape(-1), axis=0) - np.take(prefix, k, axis=0)
    return sums.reshape(len(n), rows, -1).sum(axis=1)
