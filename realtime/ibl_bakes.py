r"""The light bakes of the ``ibl-samples`` family (`rtfit.realtime.ibl_samples`, docs/ibl-samples.md): an
environment map's texels reduced to N directional lights, offline and in NumPy, as an engine does once per
map. Split from ibl_samples.py (the kernel, its shadow test and its rows stay there).

Units: the texels are unit directions d_t, solid angles w_t (sr) and radiances L_t (W·m⁻²·sr⁻¹, RGB, clamped
at 0), on an (H, W) lat-long grid of rows of equal polar angle; a texel's energy is e_t = w_t·Y(L_t), Y the
Rec. 709 luminance (`LUMINANCE`). A bake returns the 6·N table, sample-major: light k's unit direction
towards the light and its power P_k = Σ_{t ∈ cell k} w_t L_t (W/m², RGB), so that Σ_k P_k = ∫ L dω exactly.
The bakes (`bake_lights`): ``seed-lloyd`` / ``seed-depthmap`` (`lloyd_lights`: energy-CDF placement, then
Lloyd's relaxation on the sphere), ``importance`` (the placement alone), ``median-cut`` (`median_cut_lights`,
Debevec 2005); ibl_samples.py's module text gives their sources and readings.

Guards (reasons): negative texels are clamped to 0 (a map below the horizon); a black map gives N lights of
zero power on a Fibonacci sphere (`fibonacci_directions`), a cell without energy keeps its direction with
zero power, fewer texels than lights are padded with dark lights; texels must be finite with non-negative
solid angles, N an integer in [1, 65536] (each refused with one line).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "LLOYD_ITERATIONS",
    "bake_lights",
    "fibonacci_directions",
    "lloyd_lights",
    "median_cut_lights",
]

LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights: a texel's energy is w·Y(L) (not exported: linear_fog's ``LUMINANCE`` is the
root's; the same weights)."""
LLOYD_ITERATIONS = 32
"""Lloyd steps of the seed's bake (the relaxation has converged to < 10⁻³ rad on the shipped map by then)."""
_TINY = 1e-30
_CHUNK = 1 << 13  # texels per block of the nearest-direction assignment (N·_CHUNK dot products)


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` unit directions (n, 3) spread evenly over the sphere (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = math.pi * (3.0 - math.sqrt(5.0)) * np.arange(n)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def _texels(dirs, weights, radiance):
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    w = np.asarray(weights, np.float64).reshape(-1)
    L = np.maximum(np.asarray(radiance, np.float64).reshape(-1, 3), 0.0)
    if len(d) != len(w) or len(d) != len(L) or not len(d):
        raise ValueError(f"texels: {len(d)} directions, {len(w)} weights, {len(L)} radiances (one each)")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(w)) and np.all(np.isfinite(L))) or np.any(w < 0):
        raise ValueError("texels: finite directions and radiances, finite non-negative solid angles")
    wl = w[:, None] * L
    return d, wl, wl @ np.asarray(LUMINANCE)


def _count(n) -> int:
    if isinstance(n, bool) or int(n) != n or not 1 <= int(n) <= 1 << 16:
        raise ValueError(f"n = {n!r}: the number of lights is an integer in [1, 65536]")
    return int(n)


def _nearest(d: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index of the nearest centre (largest dot product) of each direction (its spherical Voronoi cell)."""
    out = np.empty(len(d), np.int64)
    for a in range(0, len(d), _CHUNK):
        out[a : a + _CHUNK] = np.argmax(d[a : a + _CHUNK] @ centres.T, axis=1)
    return out


def _table(directions: np.ndarray, powers: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.concatenate([directions, powers], axis=1).reshape(-1))


def _cells(d, wl, e, cell, n, fallback):
    """(directions, powers) of the cells: each cell's energy centroid (``fallback`` where it has none)."""
    centroid = np.stack([np.bincount(cell, e * d[:, c], minlength=n) for c in range(3)], axis=-1)
    length = np.linalg.norm(centroid, axis=1, keepdims=True)
    ok = length[:, 0] > 1e-12 * max(float(e.sum()), _TINY)
    dirs = np.where(ok[:, None], centroid / np.maximum(length, _TINY), fallback)
    powers = np.stack([np.bincount(cell, wl[:, c], minlength=n) for c in range(3)], axis=-1)
    return dirs, powers


def lloyd_lights(dirs, weights, radiance, n: int, iterations: int = LLOYD_ITERATIONS) -> np.ndarray:
    """The ``seed-lloyd`` bake (``iterations`` = 0: ``importance``): ``n`` lights (the 6·n table, module
    docstring) of the texels (``dirs`` (..., 3), ``weights`` (...) sr, ``radiance`` (..., 3)): energy-CDF
    placement, then Lloyd's relaxation on the sphere with the energy as density."""
    n = _count(n)
    if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 0:
        raise ValueError(f"iterations = {iterations!r}: a non-negative integer")
    d, wl, e = _texels(dirs, weights, radiance)
    total = float(e.sum())
    if total <= 0.0:  # a black map: evenly spread directions, zero power
        centres = fibonacci_directions(n)
    else:
        cdf = np.cumsum(e) / total
        picks = np.unique(np.minimum(np.searchsorted(cdf, (np.arange(n) + 0.5) / n), len(d) - 1))
        if len(picks) < n:  # a texel holding more than 1/n of the energy (a sun): the next brightest ones
            order = np.argsort(-e, kind="stable")
            rest = order[~np.isin(order, picks)]
            picks = np.concatenate([picks, rest[: n - len(picks)]])
        centres = d[picks] / np.linalg.norm(d[picks], axis=1, keepdims=True)
        if len(centres) < n:  # fewer texels than lights
            centres = np.concatenate([centres, fibonacci_directions(n - len(centres))])
    cell = _nearest(d, centres)
    for _ in range(int(iterations)):
        centres, _p = _cells(d, wl, e, cell, n, centres)
        new = _nearest(d, centres)
        if np.array_equal(new, cell):
            break
        cell = new
    return _table(*_cells(d, wl, e, cell, n, centres))


def _split(e: np.ndarray, region, rows: int) -> tuple | None:
    """Two halves of equal energy of ``region`` (j0, j1, i0, i1) cut across its longer side, or None for
    one texel."""
    j0, j1, i0, i1 = region
    h, w = j1 - j0, i1 - i0
    if h * w <= 1:
        return None
    theta = math.pi * 0.5 * (j0 + j1) / rows
    across_rows = h * math.pi / rows >= w * 2.0 * math.pi / e.shape[1] * math.sin(theta)
    if h == 1 or (w > 1 and not across_rows):
        profile, size = e[j0:j1, i0:i1].sum(axis=0), w
    else:
        profile, size = e[j0:j1, i0:i1].sum(axis=1), h
    total = float(profile.sum())
    cut = int(np.searchsorted(np.cumsum(profile), 0.5 * total)) + 1 if total > 0 else size // 2
    cut = min(max(cut, 1), size - 1)
    if size == w and (h == 1 or (w > 1 and not across_rows)):
        return (j0, j1, i0, i0 + cut), (j0, j1, i0 + cut, i1)
    return (j0, j0 + cut, i0, i1), (j0 + cut, j1, i0, i1)


def median_cut_lights(dirs, weights, radiance, n: int) -> np.ndarray:
    """The ``median-cut`` bake (Debevec 2005): ``n`` lights (the 6·n table) of the texels on their (H, W)
    grid (``dirs`` (H, W, 3), ``weights`` (H, W) sr, ``radiance`` (H, W, 3); rows of equal polar angle)."""
    n = _count(n)
    grid = np.asarray(dirs, np.float64)
    if grid.ndim != 3 or grid.shape[2] != 3:
        raise ValueError(f"median cut: dirs must be an (H, W, 3) grid (got {grid.shape})")
    rows, cols = grid.shape[:2]
    d, wl, e = _texels(grid, weights, radiance)
    eg = e.reshape(rows, cols)
    regions = [(0, rows, 0, cols)]
    energy = lambda r: float(eg[r[0] : r[1], r[2] : r[3]].sum())  # noqa: E731
    while len(regions) < n:
        level = len(regions) * 2 <= n
        order = regions if level else sorted(regions, key=energy, reverse=True)[: n - len(regions)]
        out, split_any = [], False
        for r in regions:
            halves = _split(eg, r, rows) if r in order else None
            split_any |= halves is not None
            out.extend(halves if halves is not None else (r,))
        regions = out
        if not split_any:  # every region one texel: fewer texels than lights
            break
    cell = np.empty((rows, cols), np.int64)
    centre = np.empty((len(regions), 3))
    for k, (j0, j1, i0, i1) in enumerate(regions):
        cell[j0:j1, i0:i1] = k
        centre[k] = grid[(j0 + j1 - 1) // 2, (i0 + i1 - 1) // 2]
    dirs_k, powers = _cells(d, wl, e, cell.reshape(-1), len(regions), centre)
    if len(regions) < n:  # pad with dark lights
        pad = n - len(regions)
        dirs_k = np.concatenate([dirs_k, fibonacci_directions(pad)])
        powers = np.concatenate([powers, np.zeros((pad, 3))])
    return _table(dirs_k, powers)


def bake_lights(bake: str, dirs, weights, radiance, n: int) -> np.ndarray:
    """The 6·n light table of the bake ``bake`` (``seed-lloyd`` and ``seed-depthmap``: the same lights,
    ``importance``, ``median-cut``) of the texels
    on their (H, W) grid (`median_cut_lights`' arguments)."""
    if bake in ("seed-lloyd", "seed-depthmap"):
        return lloyd_lights(dirs, weights, radiance, n)
    if bake == "importance":
        return lloyd_lights(dirs, weights, radiance, n, iterations=0)
    if bake == "median-cut":
        return median_cut_lights(dirs, weights, radiance, n)
    raise ValueError(f"unknown bake {bake!r} (known: seed-lloyd, seed-depthmap, importance, median-cut)")
