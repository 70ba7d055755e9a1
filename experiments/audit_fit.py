"""The audit's evaluation and fits of one method on one case (`evaluate_case`, `fit_case`), and the pooled
fit of one method to the cases of several scenes (`pooled_fit`: ``rtfit run`` of a family born on the engine).

A **pooled fit** answers the question an engine's settings ask: one value of each free parameter for all the
content, not one per scene. Each case c (N_c fitted elements, reference r_c) is weighted by
w_c = 1 / (rms(r_c) √N_c), so that the pooled objective is Σ_c ‖f_c(θ) − r_c‖² / (N_c rms(r_c)²) — the sum of
each case's squared relative RMSE: every scene counts alike, whatever its brightness or size in pixels
(unweighted, the brightest case would set the value alone). A case whose reference is 0 everywhere has no
relative error (rms 0) and is left out of the pool, saying so. A case fitted on its relative error
(`FamilyCase.fit_weight` ``relative``) keeps its own weights, divided by √N_c: its RMS relative error.

Parameters declared in units of a scene length (a caster's bounding radius, the AO radius) get their start
and bounds in scene units here too (`length_scaled_params`), for every family that declares them so.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Mapping, Sequence, Set
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rtfit.fitting import fit_method
from rtfit.fitting.method_fit import fit_run
from rtfit.realtime.arrays import NUMPY_OPS, backend_float, release_backend_tables, same_bits, to_drjit
from rtfit.realtime.methods import Method, Param

from .audit import AuditError
from .audit_family import FamilyCase

__all__ = [
    "FIT_PIXELS",
    "FIT_SOLVER",
    "SUBSAMPLE_FROM",
    "FitData",
    "PooledFit",
    "channel_param_rows",
    "evaluate_case",
    "fit_case",
    "fit_data",
    "fit_subsample",
    "length_scaled_params",
    "polish_params",
    "pooled_fit",
    "stacked_agrees",
    "subsampled_case",
    "tables_as_drjit",
]  # fmt: skip

FIT_SOLVER = "trf"
"""The audit's fits: SciPy's trust-region reflective solver on the NumPy run of each kernel text
(`rtfit.fitting.fit_method`, ``solver="trf"``): nothing is compiled per scene. On Mitsuba's Cornell box at 64²
× 32 spp (2 loaded CPU cores) its 9 fits took 3.1 s against 34.3 s through the JAX run (optimistix LM), with
the same values to ~1e-9 where both converge, and a lower SSR where LM stopped early (the Evans listing form's
logB, stuck on its bound through the change of variables: SSR 8928 → 262.5).

Issue 33 (session 18), measured with a CPU-clock profiler on the same audit: the 29 fits spent 28.9 / 28.6 CPU
s (two rounds, alternated with the change), about half of it inside SciPy's TRF on threaded OpenBLAS (each m ×
p product, m ≈ 10⁴, p ≤ 7, split over the threads, which spin on a loaded machine) and the rest in ≈ 4200
kernel evaluations, 84 % of them the central-difference Jacobian's. Kept: one BLAS thread while TRF runs
(`rtfit.fitting.blas_threads`) and a stop derived from the noise (`method_fit.noise_ftol`: ftol = κ²/dof keeps
each value within κ = 1e-2 of its stderr of the optimum; checked at the stop by the Gauss–Newton gain,
`gauss_newton_gain_small`): 13.2 / 12.8 CPU s (−55 %), every determined value within 7e-4 of its stderr of the
former fit (poisson8-rotated's radius; the rest ≤ 4e-4), the same Jacobian ranks (values the data do not
determine, stderr NaN, may move along their null direction at the same SSR: aa-fitted-seed's c0, c2, c4 by
0.11–0.22). Measured and not kept: a forward-difference Jacobian while iterating (then a central one to
polish; −17 % more) moved PCSS's light scale 248 stderr to a 1.8 % lower SSR and dropped two RGB-obscurance
fits' Jacobian rank (their d_max, exponent undetermined); fitting first on a deterministic every-k-th
subsample of ≤ 4096 elements, then polishing on all (−6 % more) moved the 256² map's poisson8-rotated radius
0.50 stderr to a higher SSR (its texel steps: a subsample sees other edges), and quick runs fit fewer than
4096 elements anyway.

Issue 33 (session 19), the same audit, CPU seconds of its 25 fits (`fit_case`) measured alternately (two
rounds): 15.8 / 14.2 and 13.9 / 13.7 → 8.6 / 8.6 and 9.4 / 7.8 (−40 %; first round: pcf-soft-shadows 6.6 /
6.0 → 3.2 / 3.5, colour-bleeding 5.4 / 4.4 → 2.9 / 3.0, obscurances 2.0 / 2.0 → 1.0 / 0.9,
ambient-aperture's caps 1.1 / 1.1 → 0.7 / 0.6), every number of the report
the same bit for bit. Kept: (1) a per-channel case's inputs the channels share (a shadow map's u, v, depth,
rotation; the rays' hit distances; the grey families' every input) passed once and broadcast (`fit_data`
``stacked``), where the kernel gives the concatenation's residuals bit for bit (`stacked_agrees`): the
kernels did each visibility three times; (2) colour-bleeding's per-channel biases stepped together in the
central-difference Jacobian (`channel_param_rows`; 8 → 4 costly evaluations a Jacobian, its ~100
Jacobians a fit crawling to its bounds). Checked and not the cost: the fitted rows' Dr.Jit evaluations
(≤ 30 ms each; kernel cache hits), NumPy ↔ Dr.Jit conversions (the fits run NumPy)."""


FIT_PIXELS = 1 << 13
"""The most masked pixels a case's fit (`fit_case`) starts on: a case of more than twice as many
(`SUBSAMPLE_FROM`) is fitted first on a deterministic stratified subsample of 8192 of its pixels
(`fit_subsample`), the same pixels in every channel, then polished on every pixel from the subsample's
values (`polish_params`: no scan), so that what is reported is the full data's optimum, its stderr and
residuals. Issue 33 (session 20): a fit's cost grows with its elements (each evaluation of the kernel, each
TRF product), and on Mitsuba's Cornell box at 256² × 256 spp the fits took 405 s against the references' 172
s on 2 cores; most of a fit's evaluations are its start scans and the steps far from the optimum, which the
subsample takes at a fraction of the cost, and the polish from near the optimum needs a few Jacobians on
every pixel.

Why 2¹³. (1) Nothing below it changes: every ``--quick`` case and every 64² audit (≤ 4096 pixels) is fitted
on all its pixels, bit for bit as before, and so is every case of at most 2¹⁴ (`SUBSAMPLE_FROM`: a 128²
audit's). (2) The subsample's optimum lies Δ from the full data's with E[Δᵀ JᵀJ Δ] = p s² (N/n − 1) (p
parameters, s² the residual variance): for n = 8192 and p ≤ 8 the start is then within a few of the full
fit's stderr × √(N/n) of its optimum, where a local solver converges in a few steps, and each parameter
keeps ≥ 1000 pixels (× 3 channels of residuals). (3) The residuals of a real-time approximation are mostly
its model error, correlated across neighbouring pixels: the subsample is stratified (one pixel drawn in each
of n runs of consecutive masked pixels in raster order), so that it covers the image as evenly as a regular
stride without aliasing with texel or pixel periods (session 18 measured a fixed every-k-th subsample see
other shadow-map edges). Measured (docs/benchmarks.md, "Fits on a subsample at large sizes"): at 256² the
smooth fits end on the full fit's values (≤ 0.001 of its stderr); a shadow map's rows, whose SSR steps with
the texels and the scanned depth bias, may end on another step (RMSE ≤ +0.62 %), and PCSS's light scale, a
fit with several local minima, in a better one (RMSE −20 % and −4.8 %). The pooled fit (`pooled_fit`) reads
every pixel still."""


SUBSAMPLE_FROM = 2 * FIT_PIXELS
"""A case's fit starts on a subsample (`fit_subsample`) only where it has more than this many masked pixels:
where the subsample would be half the pixels or more, the polish on every pixel costs about what a fit on
every pixel does (the Cornell box at 128² × 32 spp, 15164 pixels a case: the fits 20.9 s with the subsample
start, 20.5 s without; at 256², 60805 pixels, 42 s against 96 s on the GPU host), so such a case is fitted
on every pixel at once, as before session 20."""


def fit_subsample(case: FamilyCase) -> np.ndarray | None:
    """The positions (sorted, among the case's masked pixels in raster order) that a fit of ``case`` starts
    on: None (every pixel at once) when the case has at most `SUBSAMPLE_FROM` pixels; else one position
    drawn uniformly in each of n = `FIT_PIXELS` runs of ⌊N/n⌋ or ⌈N/n⌉ consecutive masked pixels, from a
    generator seeded by the case's id (CRC-32): the same pixels at every run of the same case, whichever
    row, process or time."""
    n = int(np.count_nonzero(case.mask))
    if n <= SUBSAMPLE_FROM:
        return None
    edges = (np.arange(FIT_PIXELS + 1, dtype=np.int64) * n) // FIT_PIXELS
    u = np.random.default_rng(zlib.crc32(case.id.encode("utf-8"))).random(FIT_PIXELS)
    return edges[:-1] + (u * np.diff(edges)).astype(np.int64)


def subsampled_case(case: FamilyCase, keep: np.ndarray) -> FamilyCase | None:
    """``case`` restricted to the masked pixels at positions ``keep`` (`fit_subsample`): its mask, its
    factor and every per-pixel input of every channel (a NumPy array of one value per masked pixel), each
    indexed once here, so that a kernel memoising on its arrays' identity (a shadow map's `_kept`) sees the
    same arrays at every evaluation of the fit. Tables (arrays of another size: a sky's texels, SH
    coefficients), sampler objects and constants are passed whole. None where an input has one value per
    pixel but is not a 1-D NumPy array (its layout unknown here: fitted on every pixel)."""
    n = int(np.count_nonzero(case.mask))
    flat = np.zeros(case.mask.size, bool)
    flat[np.flatnonzero(case.mask)[keep]] = True
    taken: dict[int, np.ndarray] = {}  # an array shared by several channels: indexed once, still shared

    def take(v):
        if not (np.ndim(v) and np.size(v) == n):
            return v  # a constant, an object or a table
        if not (isinstance(v, np.ndarray) and v.ndim == 1):
            raise TypeError
        if id(v) not in taken:
            taken[id(v)] = v[keep]
        return taken[id(v)]

    try:
        channels = tuple({k: take(v) for k, v in inp.items()} for inp in case.channel_inputs)
        factor = None if case.factor is None else take(case.factor)
    except TypeError:
        return None
    return replace(case, mask=flat.reshape(case.mask.shape), channel_inputs=channels, factor=factor)


def evaluate_case(method: Method, case: FamilyCase, params: Mapping[str, float]) -> np.ndarray:
    """The method on the case's masked pixels, per channel (or once, returning (R, G, B), on a case with one
    mapping), times the case's factor: an image (H, W, 3)."""
    img = np.zeros((*case.mask.shape, 3))
    vals = []
    n = int(case.mask.sum())
    for inputs in case.channel_inputs:
        v = method.evaluate(tables_as_drjit(inputs), dict(params))
        parts = v if isinstance(v, (tuple, list)) else (v,)
        vals += [np.broadcast_to(np.asarray(p, np.float64), (n,)) for p in parts]
        release_backend_tables(inputs.values())  # a sampler's Dr.Jit tables: not kept to the case's end
    if len(vals) == 1:  # a grey value on a one-mapping case
        vals *= 3
    if len(vals) != 3:
        raise AuditError(f"{method.id}: returned {len(vals)} channels on {case.label} (expected 3: R, G, B)")
    out = np.stack(vals, axis=-1)
    if case.factor is not None:
        out = out * case.factor[:, None]
    img[case.mask] = out
    return img


def tables_as_drjit(inputs: Mapping[str, Any]) -> dict:
    """The inputs as given, except that where arrays of several lengths meet (per-pixel inputs beside a
    table, e.g. a sky texture's texel directions) every array becomes a float64 Dr.Jit array of the default
    backend, which the kernel takes as it is (NumPy arrays would be broadcast against each other), in a
    64-byte aligned buffer (`to_drjit`). Issue 33 (session 31): mapped where NumPy placed them, the arrays'
    alignments were part of each kernel's hash, so an audit compiled such rows again whenever its buffers
    fell otherwise: the Cornell box's six irradiance-volume rows, 12 kernels, 2.7 s of compiling
    in an audit at 64² (Dr.Jit's log: a "cache miss" for each, in most runs)."""
    shapes = {np.shape(v) for v in inputs.values() if isinstance(v, np.ndarray) and v.ndim}
    if len(shapes) <= 1:
        return dict(inputs)
    Float = backend_float(None, np.float64)
    return {k: to_drjit(Float, np.reshape(v, -1)) if isinstance(v, np.ndarray) else v
            for k, v in inputs.items()}  # fmt: skip


@dataclass(frozen=True)
class FitData:
    """What one case gives a fit of one method (`fit_data`): the kernel's ``inputs`` by name (arrays over the
    fitted elements, or constants), the ``target`` (the reference over those elements: (n,) for a case read
    per channel, where the channels' elements are concatenated, or (3, n) for a one-mapping case whose
    method returns (R, G, B)), and the ``params`` fitted with their starts and bounds."""

    inputs: Mapping[str, Any]
    target: np.ndarray
    params: Mapping[str, Param]
    per_channel: bool
    weights: np.ndarray | None = None
    """Each residual's weight, shaped as ``target`` (`FamilyCase.fit_weight` ``relative``: the image's
    relative residual, 1 / max(|reference|, σ), times the case's factor where the target was divided by
    it; 0 where both are 0, a pixel without a relative error); None: 1 (``absolute``)."""


def _relative_weights(ref: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """1 / max(|ref|, σ) elementwise, 0 where both are 0."""
    floor = np.maximum(np.abs(ref), sigma)
    return np.divide(1.0, floor, out=np.zeros_like(floor, dtype=np.float64), where=floor > 0)


def fit_data(method: Method, case: FamilyCase, row: str = "", stacked: bool = False) -> FitData:
    """The data of ``method``'s fit to the case's reference over the masked pixels and the three channels
    (where the case's factor is positive, the target divided by it). On a one-mapping case the method returns
    (R, G, B) and its inputs are passed as they are. Starts and bounds: the case's for the row
    (`FamilyCase.params`), else the method's declared ones. ``stacked``: a per-channel case's target and
    weights as (3, n) arrays, each input the same in the three channels (bit for bit) passed once (n,) and
    the others stacked (3, n): the kernel's elementwise text broadcasts them to the same values in the same
    order as the concatenation (`fit_case`), computing what the channels share once."""
    ref = case.reference.mean[case.mask]
    relative = case.fit_weight == "relative"
    w = _relative_weights(ref, case.reference.sigma()[case.mask]) if relative else None
    start = {k: p for k, p in case.params.get(row, {}).items() if k in method.params}
    params = {**method.params, **start}
    if len(case.channel_inputs) == 1 and case.factor is None:
        inputs = {n: case.channel_inputs[0][n] for n in method.input_names}
        return FitData(inputs, np.asarray(ref.T, np.float64), params, per_channel=False,
                       weights=None if w is None else np.ascontiguousarray(w.T))  # fmt: skip
    keep = np.ones(len(ref), bool) if case.factor is None else case.factor > 0
    scale = np.ones(len(ref)) if case.factor is None else np.where(keep, case.factor, 1.0)
    join = np.stack if stacked else np.concatenate
    inputs: dict[str, Any] = {}
    for n in method.input_names:
        first = case.channel_inputs[0][n]
        if not np.ndim(first) and all(inp[n] is first for inp in case.channel_inputs):
            inputs[n] = first  # one scalar or sampler object for every channel: a constant of the fit
            continue
        parts = []
        for inp in case.channel_inputs:
            v = inp[n]
            parts.append(
                np.asarray(v, np.float64)[keep] if np.ndim(v) else np.full(int(keep.sum()), float(v))
            )
        if stacked and all(same_bits(parts[0], p) for p in parts[1:]):
            inputs[n] = parts[0]  # the same values in every channel: once, broadcast over the channels
        else:
            inputs[n] = join(parts)
    target = join([ref[keep, c] / scale[keep] for c in range(3)])
    if w is not None:  # (f − ref/s)·s / max(|ref|, σ): the image's relative residual
        w = join([w[keep, c] * scale[keep] for c in range(3)])
    return FitData(inputs, target, params, per_channel=True, weights=w)


def fit_case(method: Method, case: FamilyCase, row: str = "") -> dict:
    """Fit ``method``'s free parameters to one case (`fit_data`), weighted by the case's `fit_weight`
    (``absolute``: the least-squares fit of the image's RMSE in the quantity's units; ``relative``: of its
    relative error over the noise floor); the `FitResult` as a dict. A per-channel case whose channels share
    inputs is fitted on its stacked data (`fit_data` ``stacked``: the shared work once, not three times) where
    the kernel's NumPy run gives there, at the start, the concatenated data's residuals bit for bit (an
    elementwise kernel; `stacked_agrees`), so that every evaluation of the fit does.

    A case of more than `SUBSAMPLE_FROM` masked pixels is fitted first on its deterministic subsample
    (`fit_subsample`, `subsampled_case`), then polished on every pixel from the subsample's values (no scan:
    `polish_params`), so that what is reported is the full data's optimum near the subsample's, with the full
    data's stderr, residuals and counts, as on a smaller case; the dict's ``subsample`` says so ({"pixels": n,
    "of": N masked}; absent where every pixel was fitted at once)."""
    keep = fit_subsample(case)
    sub = None if keep is None else subsampled_case(case, keep)
    if keep is None or sub is None:  # (None: an input of unknown layout, `subsampled_case`: every pixel)
        return _fit_case(method, case, row)[0]
    first, layout = _fit_case(method, sub, row)
    result, _ = _fit_case(method, case, row, polish_from=first, layout=layout)
    result["subsample"] = {"pixels": len(keep), "of": int(np.count_nonzero(case.mask))}
    return result


def polish_params(params: Mapping[str, Param], fitted: Mapping[str, Any]) -> dict[str, Param]:
    """``params`` started at a previous fit's values (``fitted``: a `FitResult.to_dict`'s ``parameters``),
    each moved strictly inside its bounds (a value on a bound starts a hair inside it, as `Param` requires),
    with no scan (the previous fit scanned): the start of `fit_case`'s polish on every pixel."""
    out = {}
    for k, p in params.items():
        v = fitted.get(k, {}).get("value")
        if v is None or not np.isfinite(v):
            out[k] = replace(p, scan=0)
            continue
        lo, hi = p.lower, p.upper
        span = (hi - lo) if np.isfinite(hi - lo) else max(abs(float(v)), 1.0)
        inner = 1e-9 * span
        v = float(min(max(v, lo + inner), hi - inner))
        out[k] = replace(p, initial=v, scan=0)
    return out


@dataclass(frozen=True)
class ChannelLayout:
    """How a per-channel fit's data is laid out (`_fit_case`): ``stacked`` (the channels stacked, (3, N),
    where the kernel's NumPy run gives the concatenation's values bit for bit: `stacked_agrees`), and its
    per-channel parameters of disjoint residual rows (`channel_param_rows`; None: none). Both are properties
    of the kernel's text, checked once on the first fit's data (a case's subsample) and kept for its polish
    on every pixel: at 256² the two checks evaluated the kernel ~8 times on every pixel a row (issue 33)."""

    stacked: bool
    channel_params: tuple[str, ...] | None


def _fit_case(
    method: Method,
    case: FamilyCase,
    row: str,
    polish_from: dict | None = None,
    layout: ChannelLayout | None = None,
) -> tuple[dict, ChannelLayout | None]:
    """`fit_case` on the pixels of ``case`` as given, and the `ChannelLayout` it used (None: not a per-channel
    NumPy fit); ``polish_from``: a fit's dict whose values start this one (`polish_params`); ``layout``: the
    layout decided by that fit (else checked here)."""
    d = fit_data(method, case, row)
    rows = None
    if d.per_channel and method.fit_ops in ("numpy", "drjit"):
        s = fit_data(method, case, row, stacked=True)
        if layout is None:
            stacked = any(np.ndim(v) == 1 for v in s.inputs.values()) and stacked_agrees(method, d, s)
            numpy = method.fit_ops == "numpy"  # (per-channel parameters: none of a Dr.Jit fit's methods)
            found = channel_param_rows(method, s) if stacked and numpy else None
            layout = ChannelLayout(stacked, None if found is None else tuple(found))
        if layout.stacked:
            d = s
            rows = None if layout.channel_params is None else _channel_rows(layout.channel_params, d)
    if polish_from is not None:
        d = replace(d, params=polish_params(d.params, polish_from["parameters"]))
    fit = fit_method(
        method, d.inputs, d.target, weights=d.weights, params=d.params, solver=FIT_SOLVER, param_rows=rows
    )
    return fit.to_dict(), layout


def _channel_rows(names: Sequence[str], d: FitData) -> dict[str, np.ndarray]:
    """Each per-channel parameter's residual rows in the stacked data ``d``: its channel's (the last letter
    of its name), a boolean mask over the raveled residuals (`channel_param_rows`)."""
    out = {}
    for k in names:
        own = np.zeros(d.target.shape, bool)
        own["rgb".index(k[-1])] = True
        out[k] = own.reshape(-1)
    return out


def channel_param_rows(method: Method, d: FitData) -> dict[str, np.ndarray] | None:
    """For a stacked per-channel fit (`fit_data` ``stacked``) of a method with one parameter per channel,
    named ``<x>_r``, ``<x>_g``, ``<x>_b`` (colour-bleeding's SDF biases b_c): each one's residual rows, its
    channel's, for `rtfit.fitting.fit_method`'s ``param_rows`` (its Jacobian steps the three together: one
    evaluation per side, not three). Checked on the kernel's NumPy run: with each set to either bound, the
    other channels' values stay those at the start bit for bit; else (or no such parameters) None."""
    names = [k for k in d.params if k[-2:] in ("_r", "_g", "_b")
             and all(k[:-2] + c in d.params for c in ("_r", "_g", "_b"))]  # fmt: skip
    if not names or d.target.ndim != 2 or d.target.shape[0] != 3:
        return None
    start = {k: p.initial for k, p in d.params.items()}

    def run(values) -> np.ndarray:
        with np.errstate(all="ignore"):
            out = np.asarray(method(NUMPY_OPS, d.inputs, values), np.float64)
        return np.ascontiguousarray(np.broadcast_to(out, d.target.shape))

    base = run(start)
    rows = _channel_rows(names, d)
    for k in names:
        own = rows[k].reshape(d.target.shape)
        for v in (d.params[k].lower, d.params[k].upper):
            if not (np.isfinite(v) and same_bits(run({**start, k: v})[~own], base[~own])):
                return None
    return rows


def stacked_agrees(method: Method, flat: FitData, stacked: FitData) -> bool:
    """Whether ``method``'s run where its fit evaluates it (`rtfit.fitting.method_fit.fit_run`: NumPy, or
    Dr.Jit with each (3, n) input an ``Array3f64``) at its start values gives on ``stacked`` (`fit_data`
    ``stacked``) the values it gives on ``flat`` (the concatenated channels), bit for bit in the same order:
    the test that its text is elementwise over the inputs (a kernel reading a 2-D input as a stack of rays,
    or failing on one, is fitted on the concatenation). Issue 33 (session 30): the shadow maps' Dr.Jit fits
    ran every tap three times, once a channel (the receivers' map coordinates and depths are the same in
    the three; only the unshadowed irradiance is a channel's)."""
    values = {k: p.initial for k, p in flat.params.items()}
    try:
        with np.errstate(all="ignore"):
            a = np.asarray(fit_run(method, flat.inputs)(values), np.float64)
            b = np.asarray(fit_run(method, stacked.inputs)(values), np.float64)
        a = np.ascontiguousarray(np.broadcast_to(a, flat.target.shape)).reshape(-1)
        b = np.ascontiguousarray(np.broadcast_to(b, stacked.target.shape)).reshape(-1)
    except Exception:  # any failure of the stacked run: the concatenation, as before
        return False
    return same_bits(a, b)


@dataclass(frozen=True)
class PooledFit:
    """One method fitted to several cases at once (`pooled_fit`): the `FitResult` dict ``fit``, the case ids
    pooled, and the cases left out with the reason (``left_out``: case id → why)."""

    method: Method
    fit: dict
    cases: tuple[str, ...]
    left_out: Mapping[str, str]


def _pooled_params(method: Method, datas: Sequence[FitData], starts: Sequence[Mapping[str, float]]):
    """The pooled fit's parameters: each case's bounds joined (the widest), started at the median of the
    cases' own fitted values (the first case's start where that median lies on a bound)."""
    out = {}
    for k in method.params:
        ps = [d.params[k] for d in datas]
        lower, upper = min(p.lower for p in ps), max(p.upper for p in ps)
        values = [float(s[k]) for s in starts if k in s and np.isfinite(s[k])]
        start = float(np.median(values)) if values else ps[0].initial
        if not lower < start < upper:  # a median on a bound: a start must lie inside (`Param`)
            start = ps[0].initial
        out[k] = replace(ps[0], initial=start, lower=lower, upper=upper)
    return out


def pooled_fit(
    method: Method, cases: Sequence[tuple[FamilyCase, str, Mapping[str, float]]]
) -> PooledFit | None:
    """Fit ``method`` to every case of ``cases`` ((case, row id, the case's own fitted values)) at once
    (module docstring: each case weighted by its reference's RMS and its size). None when fewer than two
    cases can be pooled. A case is left out (and named) where its reference is zero everywhere, where its
    data is read differently from the first's (per channel vs one mapping), or where it passes the kernel a
    scene object (a distance field) or reads inputs of its own row (`FamilyCase.row_inputs`: a table baked per
    scene), which other scenes cannot share."""
    datas, weights, ids, starts, left = [], [], [], [], {}
    for case, row, own in cases:
        if row in case.row_inputs:  # its own stored table (irradiance-bases' baked coefficients per scene)
            left[case.id] = "reads its own per-row inputs (a table baked per scene): fitted per scene only"
            continue
        d = fit_data(method, case, row)
        rms = float(np.sqrt(np.mean(np.square(d.target)))) if d.target.size else 0.0
        objects = [n for n, v in d.inputs.items() if not (np.ndim(v) or np.isscalar(v))]
        # An array input not one value per fitted element is a table of the scene (a sky texture's texels,
        # a case's SH coefficients): the kernel reads it whole, and another scene's table is another input.
        tables = [n for n, v in d.inputs.items() if np.ndim(v) and np.size(v) != d.target.shape[-1]]
        if objects:
            left[case.id] = f"reads a scene object ({', '.join(objects)}): fitted per scene only"
        elif tables:
            left[case.id] = f"reads a table of its scene ({', '.join(tables)}): fitted per scene only"
        elif not (rms > 0.0 and np.isfinite(rms)):
            left[case.id] = "its reference is zero everywhere: no relative error to pool"
        elif datas and d.per_channel != datas[0].per_channel:
            left[case.id] = "its data is read per channel where the first case's is one mapping (or back)"
        else:
            datas.append(d)
            # absolute: 1/(rms·√N), each case's relative RMSE; relative: its own weights / √N (its RMS
            # relative error)
            each = (
                1.0 / (rms * np.sqrt(d.target.size))
                if d.weights is None
                else d.weights / np.sqrt(d.target.size)
            )
            weights.append(np.broadcast_to(each, d.target.shape))
            ids.append(case.id)
            starts.append(own)
    if len(datas) < 2:
        return None
    inputs: dict[str, Any] = {}
    for name in method.input_names:
        parts = [
            np.broadcast_to(np.asarray(d.inputs[name], np.float64), (d.target.shape[-1],)) for d in datas
        ]
        inputs[name] = np.concatenate(parts)
    target = np.concatenate([d.target for d in datas], axis=-1)
    w = np.concatenate(weights, axis=-1)
    params = _pooled_params(method, datas, starts)
    try:
        result = fit_method(method, inputs, target, weights=w, params=params, solver=FIT_SOLVER)
    except ValueError as e:
        raise AuditError(f"{method.id}: the pooled fit over {len(ids)} cases failed: {e}") from None
    return PooledFit(method, result.to_dict(), tuple(ids), left)


def length_scaled_params(
    methods: Iterable[Method], lengths: Set[str], length: float
) -> dict[str, dict[str, Param]]:
    """Row id → its parameters, with those named in ``lengths`` (declared in units of a scene length: a
    caster's bounding radius, the AO radius) multiplied by ``length``: start value and both bounds."""
    return {
        m.id: {
            k: replace(p, initial=p.initial * length, lower=p.lower * length, upper=p.upper * length)
            if k in lengths
            else p
            for k, p in m.params.items()
        }
        for m in methods
    }
