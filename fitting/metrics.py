"""Image and point-set error metrics, each with the noise floor of a Monte Carlo reference.

The reference is a Monte Carlo estimate whose per-element standard error ``stderr`` is known. A
metric between an approximation and such a reference does not read zero even for an *exact*
approximation: the reference's own noise remains. Every metric therefore comes with its
``noise_floor`` (the value it would read for an exact approximation), a ``resolved`` flag (the
error stands clearly above that floor) and, for the mean-squared-error metrics, a ``debiased``
value with the noise contribution removed.

Inputs
    ``approx``, ``reference``: float arrays of the same shape, either an image (H, W, C) or a
    point set (N,) / (N, C). ``stderr``: the reference's standard error, same shape, finite, ≥ 0.
    ``mask``: boolean (H, W) for images or (N,) for point sets selecting the elements to measure
    (all channels of a selected pixel/point are measured); default all.

Metrics (keys of ``results.json``; d = x − r over the masked elements, σ the stderr)

=========  ===========================================  ==========================================
key        value                                        noise floor (exact approximation)
=========  ===========================================  ==========================================
rmse       sqrt(mean d²)                                sqrt(mean σ²)                   (analytic)
rel_mse    mean d² / (r² + 0.01)                        mean σ² / (r² + 0.01)           (analytic)
mae        mean |d|                                     sqrt(2/π) · mean σ              (analytic)
max_abs    max |d|                                      mean over draws of max |σ·ε|    (seeded MC)
psnr       10 log10(peak² / mean d²),                   10 log10(peak² / mean σ²): a *ceiling*
           peak = max of the masked reference            (analytic)
ssim       mean over the mask of the SSIM map of the     SSIM(t(r), t(r + σ·ε))          (seeded MC)
           tone-mapped images t(x) = x / (1 + |x|)
flip       mean over the mask of the HDR-ꟻLIP map        ꟻLIP(r + σ·ε → r)               (seeded MC)
smape      mean |d| / (|x| + |r|)  (0/0 := 0)            smape(r, r + σ·ε)               (seeded MC)
=========  ===========================================  ==========================================

ε is standard normal noise from ``numpy.random.default_rng`` seeded by ``(seed, metric)``; the MC
floors average ``floor_draws`` draws (default 4). The analytic floors follow from
E[(r − truth)²] = σ² and E|N(0, σ²)| = σ·sqrt(2/π). The rel_mse floor uses the reference value r in
the denominator in place of the unknown truth. ``smape`` is not in :data:`ALL_METRICS` (it is for
point-set families); ask for it by name.

Resolved rule ("the error is clearly above the noise"): in amplitude units the error must exceed
twice its floor. rmse, mae, max_abs, flip, smape: value > 2·floor; rel_mse (a squared quantity):
value > 4·floor; psnr: value < ceiling − 20·log10(2) dB (≈ 6.02 dB, the same test as rmse);
ssim: 1 − value > 2·(1 − floor). A floor of 0 (noise-free reference) makes any non-zero error
resolved. An unresolved value *means nothing*: the approximation cannot be told apart from exact at
this sample count.

Debiased (rmse, rel_mse only): since E[(x − r)²] = (x − truth)² + σ², rmse_debiased =
sqrt(max(rmse² − floor², 0)) and rel_mse_debiased = max(rel_mse − floor, 0).

Applicability: ssim and flip need images; flip needs exactly 3 channels and both need the image to
be at least as large as their filter (ssim: the 11-pixel Gaussian window of σ = 1.5; ꟻLIP: the
21-pixel spatial filter at its default 67 pixels per degree). psnr needs a positive peak and flip a
reference that is not black inside the mask. Metrics that do not apply are left out of the result;
``result.skipped`` maps each to the reason.

SSIM: scikit-image ``structural_similarity`` with data_range=1, channel_axis=-1,
gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True on the tone-mapped images.
The tone map x/(1+|x|) equals x/(1+x) for x ≥ 0 and keeps negative inputs finite. The SSIM map is
computed on the whole image (windows reach outside the mask) and averaged over the mask. It is written
here once for all channels (`_ssim_maps`: scikit-image's filters and expressions in its order, bit-identical
to its per-channel maps; tests/test_metrics.py), the reference's filtered tone map kept per reference and
the floor's draws filtered in one call (issue 33: 3 Gaussian filter calls a row instead of 15).

ꟻLIP: HDR-ꟻLIP (`rtfit.fitting.hdr_flip`: NVIDIA's reference code, the code of
``flip_evaluator.evaluate(reference, test, "HDR")``, step for step in float32; within 1e-4 of
flip_evaluator's float32 maps, tests/test_hdr_flip.py) on float32 (H, W, 3) arrays with negative values
clipped to 0 (HDR-ꟻLIP accepts only non-negative radiance; clipping more than 1e-6 of the peak warns). The
exposure range uses ꟻLIP's own rule, ACES tone mapper: start = log2(x_max / Y_max),
stop = log2(x_max / Y_median), exposures = max(2, ceil(stop − start)), but with the luminances Y taken over
the *masked* reference pixels (a black background would otherwise push the median to 0 and the range to ~25
stops), a median of 0 replaced by the median of the positive luminances, and a one-stop range for a
reference of constant luminance (where flip_evaluator's own rule has start = stop and exits the process).

Memoised (results bit-identical, only the time changes): a noise floor depends on the reference, its
stderr, the mask, the seed and the draws — never on the approximation — so each is computed once per
reference and reused for every row compared with it (`rtfit.fitting.metric_noise.memo_floor`); a ꟻLIP map
is computed once per (reference, test, exposures) and reused by the report's error-map figure
(`rtfit.fitting.flip_maps.flip_map`). Keys are content digests (BLAKE2b of the arrays' bytes, shapes and
dtypes), so a changed array never hits a stale entry; the memos keep at most `metric_noise.MEMO_ENTRIES`
floors and `flip_maps.MEMO_MAP_BYTES` of maps.

Rooms: this module holds the metrics, their floors and the public API; `rtfit.fitting.flip_maps` the ꟻLIP
machinery (exposures, inputs, maps, their memo and tiling); `rtfit.fitting.metric_noise` the seeded noise
draws and the floors' memo.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from dataclasses import asdict, dataclass

import numpy as np

from .flip_maps import (
    FLIP_MIN_SIZE,
    FLIP_PPD,
    compute_flip_maps,
    flip_exposures,
    flip_input,
    flip_map,
    flip_mean,
    flip_noisy_references,
    luminance,
)
from .metric_noise import content_digest, memo_floor, noise_rng

__all__ = [
    "ALL_METRICS",
    "EXTRA_METRICS",
    "FLIP_MIN_SIZE",
    "REL_MSE_EPS",
    "SSIM_MIN_SIZE",
    "MetricResults",
    "MetricValue",
    "ZScoreSummary",
    "compute_metrics",
    "flip_error_map",
    "grey_metrics",
    "prime_flip",
    "smape",
    "tone_map",
    "z_score_summary",
    "z_scores",
]

ALL_METRICS: tuple[str, ...] = ("rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim", "flip")
"""The default metric keys, in the report's order."""
EXTRA_METRICS: tuple[str, ...] = ("smape",)
"""Metrics computed only when asked for by name."""
REL_MSE_EPS = 0.01
"""Added to r² in the rel_mse denominator (in squared image units)."""
SSIM_SIGMA = 1.5
SSIM_MIN_SIZE = 2 * int(3.5 * SSIM_SIGMA + 0.5) + 1  # scikit-image's window for gaussian_weights: 11
_RESOLVE_FACTOR = 2.0
_F32_MAX = float(np.finfo(np.float32).max)


# ------------------------------------------------------------------------------------- data types
def _json_float(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class MetricValue:
    """One metric: its value, the reference-noise floor, whether it is resolved above the floor,
    and (for MSE-type metrics) the value with the noise contribution removed."""

    value: float
    noise_floor: float
    resolved: bool
    debiased: float | None = None

    def __float__(self) -> float:
        return float(self.value)

    def to_dict(self) -> dict:
        """JSON-ready plain data; non-finite numbers (e.g. the PSNR of an exact match) become None."""
        return {
            "value": _json_float(self.value),
            "noise_floor": _json_float(self.noise_floor),
            "resolved": bool(self.resolved),
            "debiased": _json_float(self.debiased),
        }


class MetricResults(dict):
    """``dict[str, MetricValue]`` in the requested order, plus ``skipped``: metric → reason for each
    requested metric that does not apply to these inputs."""

    def __init__(self, values=(), skipped=None):
        super().__init__(values)
        self.skipped: dict[str, str] = dict(skipped or {})

    def to_dict(self) -> dict:
        return {k: v.to_dict() for k, v in self.items()}


@dataclass(frozen=True)
class ZScoreSummary:
    """Spread of the per-element z-scores (x − r)/σ. For an exact approximation mean ≈ 0, std ≈ 1.

    ``n`` counts the z-scores (masked elements with σ > 0); ``n_zero_stderr`` the masked elements
    dropped because σ == 0, of which ``n_zero_stderr_differing`` have x ≠ r (an error that no
    noise explains). ``frac_abs_above_4``: fraction with |z| > 4 (normal: 6.3e-5)."""

    n: int
    n_zero_stderr: int
    n_zero_stderr_differing: int
    mean: float
    std: float
    max_abs: float
    frac_abs_above_4: float

    def to_dict(self) -> dict:
        d = asdict(self)
        return {k: (_json_float(v) if isinstance(v, float) else v) for k, v in d.items()}


# ------------------------------------------------------------------------------------- validation
def _validate(approx, reference, stderr, mask):
    """Return float64 arrays, the (H, W)/(N,) mask, and whether the inputs are an image."""
    x = np.asarray(approx)
    r = np.asarray(reference)
    s = np.asarray(stderr)
    for name, a in (("approx", x), ("reference", r), ("stderr", s)):
        if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"{name} must be a real numeric array, got dtype {a.dtype}")
    if x.ndim not in (1, 2, 3):
        raise ValueError(f"approx must be an image (H, W, C) or a point set (N,)/(N, C), got shape {x.shape}")
    if r.shape != x.shape:
        raise ValueError(f"reference shape {r.shape} does not match approx shape {x.shape}")
    if s.shape != r.shape:
        raise ValueError(f"stderr shape {s.shape} does not match reference shape {r.shape}")
    if x.size == 0:
        raise ValueError("approx is empty")
    x = x.astype(np.float64)
    r = r.astype(np.float64)
    s = s.astype(np.float64)
    for name, a in (("approx", x), ("reference", r), ("stderr", s)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains {int(np.sum(~np.isfinite(a)))} non-finite values (NaN or inf)")
    if np.any(s < 0):
        raise ValueError(f"stderr contains {int(np.sum(s < 0))} negative values")
    is_image = x.ndim == 3
    mshape = x.shape[:2] if is_image else x.shape[:1]
    if mask is None:
        m = np.ones(mshape, dtype=bool)
    else:
        m = np.asarray(mask)
        if m.dtype != np.bool_:
            raise ValueError(f"mask must be a boolean array, got dtype {m.dtype}")
        if m.shape != mshape:
            kind = "image" if is_image else "point set"
            raise ValueError(f"mask shape {m.shape} does not match the {kind} shape {mshape}")
        if not m.any():
            raise ValueError("mask selects no elements")
    return x, r, s, m, is_image


def _sel(a, m):
    """Masked elements as a flat array (all channels of each selected pixel/point)."""
    return a[m].ravel()


class _Masked:
    """The masked elements one `compute_metrics` call's metrics read, each selected once and shared: the
    difference x − r, the stderr s and the reference r (`_sel`; the same arrays each metric made for itself
    before, so the same values). Issue 33 (session 23): rmse, rel_mse, mae, max_abs and psnr made 13
    selections a row between them, 23 of the 87 ms of a row's metrics at 256²."""

    def __init__(self, x, r, s, m):
        self.x, self.r, self.s, self.m = x, r, s, m

    @functools.cached_property
    def diff(self) -> np.ndarray:
        return _sel(self.x - self.r, self.m)

    @functools.cached_property
    def stderr(self) -> np.ndarray:
        return _sel(self.s, self.m)

    @functools.cached_property
    def reference(self) -> np.ndarray:
        return _sel(self.r, self.m)


def tone_map(x):
    """t(x) = x / (1 + |x|): Reinhard's x/(1+x) for x ≥ 0, odd and bounded for negative inputs."""
    x = np.asarray(x, dtype=np.float64)
    return x / (1.0 + np.abs(x))


# ---------------------------------------------------------------------------------- applicability
def _skip_reason(name, x, r, m, is_image) -> str | None:
    if name in ("ssim", "flip"):
        if not is_image:
            return f"{name} needs an image (H, W, C); got a point set of shape {x.shape}"
        h, w = x.shape[:2]
        need = SSIM_MIN_SIZE if name == "ssim" else FLIP_MIN_SIZE
        what = (
            "its 11-pixel Gaussian window (sigma 1.5)"
            if name == "ssim"
            else f"ꟻLIP's {FLIP_MIN_SIZE}-pixel spatial filter at {FLIP_PPD:.0f} pixels per degree"
        )
        if min(h, w) < need:
            return f"{name} needs at least {need}x{need} pixels ({what}); image is {h}x{w}"
        if name == "flip":
            if x.shape[2] != 3:
                return f"flip needs 3 colour channels (linear RGB); image has {x.shape[2]}"
            if np.abs(r).max() > _F32_MAX or np.abs(x).max() > _F32_MAX:
                return "flip works in float32 and the inputs exceed its range"
            if not np.any(luminance(np.maximum(r, 0.0))[m] > 0):
                return "flip's exposure range is undefined: the reference is black inside the mask"
    if name == "psnr" and not _sel(r, m).max() > 0:
        return "psnr needs a positive peak (max of the masked reference)"
    return None


# ----------------------------------------------------------------------------------- the metrics
def _resolved_above(value, floor, factor=_RESOLVE_FACTOR) -> bool:
    return bool(value > factor * floor)


def _rmse(x, r, s, m, masked: _Masked, **_):
    d = masked.diff
    mse = float(np.mean(d * d))
    floor2 = float(np.mean(masked.stderr**2))
    return MetricValue(
        math.sqrt(mse),
        math.sqrt(floor2),
        _resolved_above(math.sqrt(mse), math.sqrt(floor2)),
        math.sqrt(max(mse - floor2, 0.0)),
    )


def _rel_mse(x, r, s, m, masked: _Masked, **_):
    den = masked.reference**2 + REL_MSE_EPS
    val = float(np.mean(masked.diff**2 / den))
    floor = float(np.mean(masked.stderr**2 / den))
    # A squared quantity: "2x in amplitude" is 4x here (the same decision as rmse on uniform data).
    return MetricValue(val, floor, _resolved_above(val, floor, _RESOLVE_FACTOR**2), max(val - floor, 0.0))


def _mae(x, r, s, m, masked: _Masked, **_):
    val = float(np.mean(np.abs(masked.diff)))
    floor = math.sqrt(2.0 / math.pi) * float(np.mean(masked.stderr))
    return MetricValue(val, floor, _resolved_above(val, floor))


def _max_abs(x, r, s, m, seed, draws, masked: _Masked, floor_digest=None, **_):
    val = float(np.max(np.abs(masked.diff)))
    sm = masked.stderr

    def compute() -> float:
        rng = noise_rng(seed, "max_abs")
        return float(np.mean([np.max(np.abs(sm * rng.standard_normal(sm.shape))) for _ in range(draws)]))

    floor = memo_floor("max_abs", r, s, m, seed, draws, compute, floor_digest)
    return MetricValue(val, floor, _resolved_above(val, floor))


def _psnr(x, r, s, m, masked: _Masked, **_):
    peak = float(masked.reference.max())
    mse = float(np.mean(masked.diff**2))
    floor_mse = float(np.mean(masked.stderr**2))

    def db(e):
        return math.inf if e == 0 else 10.0 * math.log10(peak * peak / e)

    val, ceiling = db(mse), db(floor_mse)
    # Same test as rmse > 2·floor: mse > 4·floor_mse ⇔ psnr < ceiling − 20·log10(2).
    resolved = bool(mse > _RESOLVE_FACTOR**2 * floor_mse)
    return MetricValue(val, ceiling, resolved)


SSIM_TRUNCATE = 3.5  # scikit-image's truncation of the Gaussian window (radius int(3.5 σ + 0.5) = 5)
_SSIM_C1 = (0.01 * 1.0) ** 2  # (K1 · data_range)², scikit-image's K1 = 0.01, data_range 1
_SSIM_C2 = (0.03 * 1.0) ** 2  # (K2 · data_range)², K2 = 0.03
_SSIM_MEMO_ENTRIES = 2
"""References whose filtered tone map `_ssim_reference` keeps (the audit compares one reference's rows at
a time; a 1024² reference's three arrays are 75 MB)."""
_ssim_lock = threading.Lock()
_ssim_memo: OrderedDict[tuple, tuple] = OrderedDict()
MEMOS = (_ssim_memo,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _ssim_filter(a: np.ndarray) -> np.ndarray:
    """scikit-image's SSIM window on (..., H, W, C): ``scipy.ndimage.gaussian_filter`` of σ = 1.5 along H and
    W (mode ``reflect``, truncate 3.5) and none along the other axes (an axis of σ 0 is not filtered): per
    (H, W) plane the same passes, in the same order, as scikit-image's call on each channel."""
    from scipy.ndimage import gaussian_filter

    sigma = (0.0,) * (a.ndim - 3) + (SSIM_SIGMA, SSIM_SIGMA, 0.0)
    return gaussian_filter(a, sigma, mode="reflect", truncate=SSIM_TRUNCATE)


def _ssim_maps(t1, t2, f1=None, f2=None) -> np.ndarray:
    """The SSIM maps of tone-mapped images ``t1`` against ``t2`` ((..., H, W, C), broadcast against each
    other: several draws against one reference in one call), ``f1``/``f2`` their filtered (mean, mean of
    squares) where already known. scikit-image's ``structural_similarity`` (gaussian_weights, σ 1.5,
    population covariance, data_range 1, full map) written once for all channels and images: its
    expressions in its order, so the maps are bit-identical to its per-channel ones (a test)."""
    ux, uxx = f1 if f1 is not None else (_ssim_filter(t1), _ssim_filter(t1 * t1))
    uy, uyy = f2 if f2 is not None else (_ssim_filter(t2), _ssim_filter(t2 * t2))
    uxy = _ssim_filter(t1 * t2)
    cov_norm = 1.0  # use_sample_covariance=False (as scikit-image writes it)
    vx = cov_norm * (uxx - ux * ux)
    vy = cov_norm * (uyy - uy * uy)
    vxy = cov_norm * (uxy - ux * uy)
    a1, a2, b1, b2 = (
        2 * ux * uy + _SSIM_C1,
        2 * vxy + _SSIM_C2,
        ux**2 + uy**2 + _SSIM_C1,
        vx + vy + _SSIM_C2,
    )
    return (a1 * a2) / (b1 * b2)


def _ssim_reference(r, key: tuple) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The reference's tone map and its filtered (mean, mean of squares), computed once per reference
    content (every row and every noise draw is compared with the same ones): ``key`` a content digest of
    ``r`` (`compute_metrics`: of (r, s, m), which holds r's)."""
    with _ssim_lock:
        if key in _ssim_memo:
            _ssim_memo.move_to_end(key)
            return _ssim_memo[key]
    t = tone_map(r)
    value = (t, (_ssim_filter(t), _ssim_filter(t * t)))
    with _ssim_lock:
        _ssim_memo[key] = value
        while len(_ssim_memo) > _SSIM_MEMO_ENTRIES:
            _ssim_memo.popitem(last=False)
    return value


def _ssim(x, r, s, m, seed, draws, floor_digest, **_):
    tr, fr = _ssim_reference(r, floor_digest())
    val = float(np.mean(_ssim_maps(tr, tone_map(x), f1=fr)[m]))

    def compute() -> float:
        rng = noise_rng(seed, "ssim")
        noisy = np.stack([tone_map(r + s * rng.standard_normal(r.shape)) for _ in range(draws)])
        maps = _ssim_maps(noisy, tr, f2=fr)
        return float(np.mean([float(np.mean(smap[m])) for smap in maps]))

    floor = memo_floor("ssim", r, s, m, seed, draws, compute, floor_digest)
    return MetricValue(val, floor, _resolved_above(1.0 - val, 1.0 - floor))


def _flip(x, r, s, m, seed, draws, floor_digest=None, **_):
    params = flip_exposures(r, m)
    peak = float(np.max(r[m]))
    r32 = flip_input(r, "reference", peak, True)
    val = flip_mean(r32, flip_input(x, "approx", peak, True), m, params)

    def compute() -> float:
        noisy = flip_noisy_references(r, s, seed, draws, peak)
        return float(np.mean([flip_mean(n, r32, m, params) for n in noisy]))

    floor = memo_floor("flip", r, s, m, seed, draws, compute, floor_digest)
    return MetricValue(val, floor, _resolved_above(val, floor))


def _smape_value(x, r):
    num = np.abs(x - r)
    den = np.abs(x) + np.abs(r)
    return float(np.mean(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)))


def _smape(x, r, s, m, seed, draws, floor_digest=None, **_):
    xs, rs, ss = _sel(x, m), _sel(r, m), _sel(s, m)
    val = _smape_value(xs, rs)

    def compute() -> float:
        rng = noise_rng(seed, "smape")
        draws_ = [_smape_value(rs, rs + ss * rng.standard_normal(rs.shape)) for _ in range(draws)]
        return float(np.mean(draws_))

    floor = memo_floor("smape", r, s, m, seed, draws, compute, floor_digest)
    return MetricValue(val, floor, _resolved_above(val, floor))


_METRICS = {
    "rmse": _rmse,
    "rel_mse": _rel_mse,
    "mae": _mae,
    "max_abs": _max_abs,
    "psnr": _psnr,
    "ssim": _ssim,
    "flip": _flip,
    "smape": _smape,
}


# ------------------------------------------------------------------------------------- public API
def compute_metrics(
    approx,
    reference,
    stderr,
    mask=None,
    names=ALL_METRICS,
    seed: int = 0,
    floor_draws: int = 4,
    reference_key: tuple | None = None,
) -> MetricResults:
    """Compute the metrics ``names`` (default :data:`ALL_METRICS`) over the masked elements.

    Returns a :class:`MetricResults` (a ``dict[str, MetricValue]`` in the order of ``names``);
    metrics that do not apply to these inputs are left out and listed in ``.skipped`` with the
    reason. ``seed`` and ``floor_draws`` control the Monte Carlo noise floors. ``reference_key``: the
    `content_digest` of (``reference``, ``stderr``, ``mask``) as given, where the caller compares many
    approximations with one reference (the audit: once per case; issue 33, 13 of the 87 ms of a row's
    metrics at 256² were these digests, made again for every row); None: made here when a noise floor or
    SSIM first asks for it."""
    x, r, s, m, is_image = _validate(approx, reference, stderr, mask)
    if isinstance(names, str):
        names = (names,)
    unknown = [n for n in names if n not in _METRICS]
    if unknown:
        raise ValueError(f"unknown metric(s) {unknown}; known: {list(_METRICS)}")
    if int(floor_draws) < 1:
        raise ValueError(f"floor_draws must be >= 1, got {floor_draws}")
    out, skipped = {}, {}
    # (r, s, m)'s content key, the caller's or made at the first floor that asks for it and kept for the
    # others (`memo_floor`, `_ssim_reference`)
    digest = functools.cache(lambda: content_digest(r, s, m) if reference_key is None else reference_key)
    masked = _Masked(x, r, s, m)
    for name in dict.fromkeys(names):
        reason = _skip_reason(name, x, r, m, is_image)
        if reason is not None:
            skipped[name] = reason
            continue
        out[name] = _METRICS[name](
            x, r, s, m, seed=seed, draws=int(floor_draws), floor_digest=digest, masked=masked
        )
    return MetricResults(out, skipped)


def grey_metrics(approx, reference, stderr, mask, names) -> dict:
    """`compute_metrics` (as plain data, `MetricResults.to_dict`) of single-channel images (H, W), each
    repeated to three equal channels."""
    x, r, s = (np.asarray(a)[..., None].repeat(3, -1) for a in (approx, reference, stderr))
    return compute_metrics(x, r, s, mask, names=names).to_dict()


def prime_flip(approxes, reference, stderr, mask=None, seed: int = 0, floor_draws: int = 4) -> int:
    """Compute, in as few ꟻLIP calls as possible (`rtfit.fitting.flip_maps.compute_flip_maps`), the ꟻLIP
    maps that `compute_metrics` of each of ``approxes`` against one ``reference`` will ask for (each
    approximation's map and the noise floor's ``floor_draws`` maps), and keep them in the map memo, where
    `compute_metrics` and `flip_error_map` find them: the same values, fewer calls. Returns the number of
    maps computed (0 where ꟻLIP does not apply to these images or every map is already known)."""
    _, r, s, m, is_image = _validate(reference, reference, stderr, mask)
    if _skip_reason("flip", r, r, m, is_image) is not None:
        return 0
    params = flip_exposures(r, m)
    peak = float(np.max(r[m]))
    r32 = flip_input(r, "reference", peak, False)
    tests = [np.asarray(x, np.float64) for x in approxes]
    pairs = [
        (r32, flip_input(x, "", peak, False))
        for x in tests
        if x.shape == r.shape and np.all(np.isfinite(x)) and np.abs(x).max() <= _F32_MAX
    ]  # (another is refused by compute_metrics itself)
    pairs += [(n, r32) for n in flip_noisy_references(r, s, seed, int(floor_draws), peak)]
    return compute_flip_maps(pairs, params)


def flip_error_map(approx, reference, mask=None) -> np.ndarray:
    """The per-pixel HDR-ꟻLIP error map (H, W) in [0, 1] of ``approx`` against ``reference``
    (linear RGB images (H, W, 3)), with the exposure range of the ``flip`` metric (ꟻLIP's rule on the
    luminances of the masked reference; see the module text). Its mean over ``mask`` is the ``flip``
    metric's value. Raises ValueError with the reason where ꟻLIP does not apply (too small, not RGB,
    black reference inside the mask)."""
    x, r, _, m, is_image = _validate(approx, reference, np.zeros(np.shape(reference)), mask)
    reason = _skip_reason("flip", x, r, m, is_image)
    if reason is not None:
        raise ValueError(reason)
    peak = float(np.max(r[m]))
    return flip_map(
        flip_input(r, "reference", peak, False), flip_input(x, "", peak, False), flip_exposures(r, m)
    )


def smape(approx, reference, stderr, mask=None, seed: int = 0, floor_draws: int = 4) -> MetricValue:
    """Symmetric relative error mean |x − r| / (|x| + |r|) (0/0 counts as 0; range [0, 1]) with
    its seeded Monte Carlo noise floor smape(r, r + σ·ε). For point sets and images alike."""
    return compute_metrics(
        approx, reference, stderr, mask, names=("smape",), seed=seed, floor_draws=floor_draws
    )["smape"]


def _z_parts(approx, reference, stderr, mask):
    x, r, s, m, _ = _validate(approx, reference, stderr, mask)
    xs, rs, ss = _sel(x, m), _sel(r, m), _sel(s, m)
    ok = ss > 0
    return (xs[ok] - rs[ok]) / ss[ok], int(np.sum(~ok)), int(np.sum(~ok & (xs != rs)))


def z_scores(approx, reference, stderr, mask=None) -> np.ndarray:
    """(x − r)/σ for the masked elements with σ > 0, as a flat float64 array (pixel-major, then
    channel). Elements with σ == 0 are dropped; :func:`z_score_summary` counts them."""
    return _z_parts(approx, reference, stderr, mask)[0]


def z_score_summary(approx, reference, stderr, mask=None) -> ZScoreSummary:
    """Summary of :func:`z_scores`, with the count of elements dropped for σ == 0."""
    z, n0, n0_diff = _z_parts(approx, reference, stderr, mask)
    if z.size == 0:
        nan = float("nan")
        return ZScoreSummary(0, n0, n0_diff, nan, nan, nan, nan)
    return ZScoreSummary(
        int(z.size),
        n0,
        n0_diff,
        float(np.mean(z)),
        float(np.std(z)),
        float(np.max(np.abs(z))),
        float(np.mean(np.abs(z) > 4.0)),
    )
