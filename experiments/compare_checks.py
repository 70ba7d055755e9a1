"""What ``rtfit compare`` measures on one frame against the reference (`rtfit.experiments.compare`): the best
global scale, the registration offset, the metrics with noise floors, the z-scores, the error per shape, the
verdict naming its causes (the AOVs' alignment: `compare_aovs`).

Statistics (each against the reference's per-pixel standard error σ, which includes the float32 precision
floor):

* scale s = Σ f·r / Σ r² (least squares over every pixel and channel: frame ≈ s × reference), standard error
  σ_s = √(Σ r²·e²) / Σ r² with e = f − s·r (the sandwich estimate: the frame's and the reference's noise and
  any structured error all widen it); consistent with 1 when |s − 1| ≤ `SCALE_SIGMAS`·σ_s (or 10⁻⁴).
* registration: the integer shift (dx, dy) in ±`MAX_SHIFT` px for which frame[y + dy, x + dx] ≈ reference[y,
  x] (after the scale) has the least squared error on the interior that every shift sees; it counts only when
  it beats no shift by more than `SHIFT_SIGMAS` standard errors of the per-pixel paired difference.
* per shape (the first hit of each pixel's centre ray; −1: no surface): the relative bias Σ(f − r)/Σ r with
  its uncertainty (the larger of the reference's √Σσ² and the spread of f − r, over Σ r), and the RMS z-score.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtfit.fitting import MetricResults, compute_metrics, z_score_summary

from . import figures
from .records import Check

__all__ = [
    "FrameAnalysis",
    "ShapeError",
    "analyse_frame",
    "distance_bands",
    "frame_checks",
    "group_labels",
    "shape_table",
    "z_figure",
]

SCALE_SIGMAS = 4.0
MAX_SHIFT = 2
SHIFT_SIGMAS = 3.0
BIAS_SIGMAS = 3.0
Z_RMS_MAX = 2.0
"""A shape is within noise when its bias is within `BIAS_SIGMAS` of zero and its RMS z-score ≤ this (a frame
path-traced at 4× the reference's samples has ≈ 1.1)."""
EXPLAINS = 0.5
"""A scale, a shift or the shape outlines are named as the cause when they explain at least this fraction of
the squared error."""
OUTLIER_Z = 5.0
OUTLIER_FRACTION = 0.01
"""A frame is flagged when more than this fraction of its pixel channels lie beyond `OUTLIER_Z` σ."""


@dataclass(frozen=True)
class ShapeError:
    """The error of a frame on the pixels whose first hit is one shape (``index`` −1: no surface)."""

    index: int
    name: str
    pixels: int
    reference_mean: float
    bias: float
    """Σ(frame − reference) / Σ reference over the shape's pixels and channels."""
    uncertainty: float
    z_rms: float

    @property
    def within_noise(self) -> bool:
        return abs(self.bias) <= BIAS_SIGMAS * self.uncertainty and self.z_rms <= Z_RMS_MAX

    def words(self) -> str:
        """Within noise; the bias with its uncertainty; or, where the bias is within noise but the pixels are
        not, "structured" (errors of both signs, e.g. at edges)."""
        bias = f"{self.bias:+.1%} ± {self.uncertainty:.1%}"
        if self.within_noise:
            return f"within noise ({bias})"
        if abs(self.bias) <= BIAS_SIGMAS * self.uncertainty:
            return f"structured: z rms {self.z_rms:.3g} at a mean {bias}"
        return bias


@dataclass(frozen=True)
class FrameAnalysis:
    """One frame against the reference (module docstring)."""

    scale: float
    scale_stderr: float
    scale_consistent: bool
    offset: tuple[int, int]
    offset_significant: bool
    offset_errors: dict[tuple[int, int], float]
    metrics: MetricResults
    z_map: np.ndarray
    z: dict
    outlier_fraction: float
    shapes: list[ShapeError]
    hits: np.ndarray
    fit_exposure: bool
    scale_gain: float
    """The fraction of the squared error that dividing by the scale removes."""
    shift_gain: float
    """The fraction of the squared error that the registration offset removes."""
    edge_share: float
    """The share of the excess squared error (beyond σ²) on pixels at shape outlines (`edge_pixels`)."""
    edge_fraction: float
    causes: list[str] = field(default_factory=list)
    groups: dict[str, list[ShapeError]] = field(default_factory=dict)
    """Further breakdowns: title (the BSDF, the distance band) → the error per group."""

    @property
    def within_noise(self) -> bool:
        return not self.causes

    @property
    def misaligned(self) -> bool:
        """The registration offset is beyond the noise and removes `EXPLAINS` or more of the squared error."""
        return self.offset_significant and self.shift_gain >= EXPLAINS

    @property
    def verdict(self) -> str:
        after = (
            f" after the scale ×{self.scale:.4g}" if self.fit_exposure and not self.scale_consistent else ""
        )
        if self.within_noise:
            return f"within the reference's noise{after}"
        return "differs" + after + ": " + "; ".join(self.causes)

    @property
    def lines(self) -> list[str]:
        m = self.metrics
        z = self.z
        out = [
            f"**Verdict**: {self.verdict}.",
            "",
            f"- Best global scale (frame ≈ s × reference): s = {self.scale:.5g} ± {self.scale_stderr:.2g}"
            + (" (consistent with 1)" if self.scale_consistent else " (**not 1**)"),
            f"- Registration offset minimising the error: ({self.offset[0]:+d}, {self.offset[1]:+d}) px"
            + (
                f" (**the frame is shifted**: the shift removes {self.shift_gain:.0%} of the squared error)"
                if self.misaligned
                else f" (it removes {self.shift_gain:.0%} of the squared error: not a misalignment)"
                if self.offset_significant
                else " (none beyond the noise)"
            ),
            f"- Squared error beyond the noise at shape outlines: {self.edge_share:.0%} of it on "
            f"{self.edge_fraction:.0%} of the pixels",
            f"- z-scores (frame − reference)/σ: mean {z['mean']:.3g}, std {z['std']:.3g}, "
            f"max |z| {z['max_abs']:.3g}, "
            f"{self.outlier_fraction:.2%} beyond {OUTLIER_Z:g}σ",
        ]
        for k, v in m.items():
            out.append(
                f"- {k}: {v.value:.4g} (noise floor {v.noise_floor:.2g}"
                + (", resolved)" if v.resolved else ", not resolved: within noise)")
            )
        out += [f"- {k}: not computed ({why})" for k, why in m.skipped.items()]
        return out


def _z(diff: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sigma > 0, diff / sigma, np.where(diff == 0, 0.0, np.sign(diff) * np.inf))
    return z


def best_scale(frame: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(s, σ_s): the least-squares s of frame ≈ s × reference over ``mask`` (module docstring)."""
    f, r = frame[mask].ravel(), ref[mask].ravel()
    rr = float(np.sum(r * r))
    if rr <= 0:
        return 1.0, float("inf")
    s = float(np.sum(f * r)) / rr
    e = f - s * r
    return s, float(np.sqrt(np.sum(r * r * e * e))) / rr


def registration(frame: np.ndarray, ref: np.ndarray) -> tuple[tuple[int, int], bool, dict]:
    """The shift (dx, dy), whether it beats no shift beyond the noise, and the mean squared error of each."""
    h, w = ref.shape[:2]
    k = MAX_SHIFT
    if h <= 2 * k + 2 or w <= 2 * k + 2:
        return (0, 0), False, {}
    core = ref[k : h - k, k : w - k]
    errs, per_pixel = {}, {}
    for dy in range(-k, k + 1):
        for dx in range(-k, k + 1):
            win = frame[k + dy : h - k + dy, k + dx : w - k + dx]
            e = np.sum((win - core) ** 2, axis=-1).ravel()
            per_pixel[(dx, dy)], errs[(dx, dy)] = e, float(np.mean(e))
    best = min(errs, key=lambda s: (errs[s], abs(s[0]) + abs(s[1])))
    d = per_pixel[(0, 0)] - per_pixel[best]
    sd = float(np.std(d)) / np.sqrt(d.size)
    significant = best != (0, 0) and float(np.mean(d)) > SHIFT_SIGMAS * sd
    return best, significant, errs


def shape_errors(frame, ref, sigma, hits, names, rel_scale_err: float = 0.0, mask=None) -> list[ShapeError]:
    """`ShapeError` per shape seen at the pixels' first hits (those of ``mask``: None, all), most pixels
    first. ``rel_scale_err``: σ_s/s of a frame divided by its scale (an error common to every pixel, added to
    each shape's uncertainty)."""
    out = []
    for idx in np.unique(hits if mask is None else hits[mask]):
        m = hits == idx if mask is None else (hits == idx) & mask
        f, r, s = frame[m], ref[m], sigma[m]
        d = f - r
        total = float(np.sum(r))
        u_abs = max(float(np.sqrt(np.sum(s * s))), float(np.std(d)) * np.sqrt(d.size))
        u_abs = float(np.hypot(u_abs, rel_scale_err * total))
        z = _z(d, s)
        z = z[np.isfinite(z)]
        # A black reference (no sky behind a direct-only frame): relative to what the frame shows instead
        # (+100 % where it shows light there), and 0 ± 0 where it is black too (was NaN: refused by results).
        denom = total if total > 0 else max(float(np.sum(np.abs(f))), 1e-300)
        out.append(
            ShapeError(
                int(idx),
                "no surface (background)" if idx < 0 else names.get(int(idx), str(idx)),
                int(m.sum()),
                float(np.mean(r)),
                float(np.sum(d)) / denom,
                u_abs / denom,
                float(np.sqrt(np.mean(z * z))) if z.size else 0.0,
            )
        )
    return sorted(out, key=lambda e: -e.pixels)


def edge_pixels(hits: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels with a different first-hit shape (or none) among their 8 neighbours."""
    p = np.pad(hits, 1, mode="edge")
    h, w = hits.shape
    out = np.zeros(hits.shape, bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= p[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] != hits
    return out


def unsampled_outline_sigma(reference, hits: np.ndarray) -> np.ndarray:
    """(H, W, 3) extra standard error of the box-footprint pixels at shape outlines (`edge_pixels`) whose
    samples all agree (standard error 0): a part of the pixel covering a fraction p of it, of contrast Δ with
    the rest, is missed by all n samples with probability (1 − p)ⁿ — more often than not for p ≲ 1/n — and
    would move the pixel by p·Δ; so a zero sample variance there cannot rule out Δ/n, with Δ the largest
    difference to a neighbouring pixel's reference (per channel). Elsewhere 0. (Measured: a ball's outline
    clipping 0.2 % of a sky pixel, missed by all 128 samples, gave z = 500 against Mitsuba's own frame.)"""
    mean = np.asarray(reference.mean, np.float64)
    h, w = hits.shape
    p = np.pad(mean, ((1, 1), (1, 1), (0, 0)), mode="edge")
    contrast = np.zeros_like(mean)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            contrast = np.maximum(contrast, np.abs(p[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] - mean))
    unsampled = edge_pixels(hits) & np.all(np.asarray(reference.stderr) == 0, axis=-1)
    return np.where(unsampled[..., None], contrast / max(int(reference.spp), 1), 0.0)


def analyse_frame(
    frame, ref, sigma, mask, hits, names, fit_exposure: bool, metrics, seed: int, groups=None
) -> FrameAnalysis:
    """The `FrameAnalysis` of ``frame`` against the reference (mean ``ref``, standard error ``sigma``).
    ``groups``: title → (labels (H, W), names) of further breakdowns (the BSDF, the distance band)."""
    s, s_err = best_scale(frame, ref, mask)
    consistent = abs(s - 1.0) <= max(SCALE_SIGMAS * s_err, 1e-4)
    mse_raw = float(np.mean((frame - ref)[mask] ** 2))
    mse_scaled = float(np.mean((frame / s - ref)[mask] ** 2)) if s > 0 else mse_raw
    scale_gain = 1.0 - mse_scaled / mse_raw if mse_raw > 0 else 0.0
    compared = frame / s if fit_exposure and s > 0 else frame
    if fit_exposure and s > 0 and np.isfinite(s_err):  # the scale's own uncertainty joins the reference's
        sigma = np.sqrt(sigma**2 + (ref * s_err / s) ** 2)
    offset, significant, errs = registration(frame / s if s > 0 else frame, ref)
    shift_gain = 1.0 - errs[offset] / errs[(0, 0)] if errs and errs[(0, 0)] > 0 else 0.0
    res = compute_metrics(compared, ref, sigma, mask, names=metrics, seed=seed)
    zmap = _z(compared - ref, sigma)
    zs = z_score_summary(compared, ref, sigma, mask).to_dict()
    outliers = float(np.mean(~(np.abs(zmap[mask]) <= OUTLIER_Z)))
    rel_err = s_err / s if fit_exposure and s > 0 and np.isfinite(s_err) else 0.0
    shapes = shape_errors(compared, ref, sigma, hits, names, rel_err, mask)
    by_group = {
        t: shape_errors(compared, ref, sigma, lab, nm, rel_err, mask)
        for t, (lab, nm) in (groups or {}).items()
    }
    edges = edge_pixels(hits) & mask
    excess = np.maximum(np.sum((compared - ref) ** 2 - sigma**2, axis=-1), 0.0) * mask
    edge_share = float(excess[edges].sum() / excess.sum()) if excess.sum() > 0 else 0.0
    edge_fraction = float(edges.sum() / max(int(mask.sum()), 1))
    evidence = []
    rmse = res.get("rmse")
    if rmse is not None and rmse.resolved:
        evidence.append(
            f"RMSE {rmse.value:.3g} is {rmse.value / max(rmse.noise_floor, 1e-300):.1f}× its noise floor"
        )
    if outliers > OUTLIER_FRACTION:
        evidence.append(f"{outliers:.1%} of pixel channels beyond {OUTLIER_Z:g}σ")
    wrong = sorted((e for e in shapes if not e.within_noise), key=lambda e: -abs(e.bias) * e.pixels)
    causes = []
    if not consistent and not fit_exposure:
        explains = (
            f"a constant factor: it explains {scale_gain:.0%} of the squared error; --fit-exposure compares "
            "after it"
            if scale_gain >= EXPLAINS
            else f"it explains only {scale_gain:.0%} of the squared error"
        )
        causes.append(f"scale ×{s:.4g} ± {s_err:.2g} ({explains})")
    misaligned = significant and shift_gain >= EXPLAINS
    if misaligned:
        causes.append(
            f"misaligned: shifted by ({offset[0]:+d}, {offset[1]:+d}) px (the shift removes {shift_gain:.0%} "
            "of the squared error)"
        )
    at_edges = edge_share >= EXPLAINS and edge_share >= 2 * edge_fraction
    if (evidence or wrong) and not misaligned and at_edges:
        causes.append(
            f"structured error at shape outlines: {edge_share:.0%} of the excess squared error on the "
            f"{edge_fraction:.0%} of pixels there (blur, aliasing, another pixel filter or other geometry)"
        )
    if wrong:
        causes.append("error on " + ", ".join(f"{e.name}: {e.words()}" for e in wrong[:3]))
    causes += evidence
    return FrameAnalysis(
        s, s_err, consistent, offset, significant, errs, res, zmap, zs, outliers, shapes, hits, fit_exposure,
        scale_gain, shift_gain, edge_share, edge_fraction, causes, by_group,
    )  # fmt: skip


def frame_checks(label: str, a: FrameAnalysis) -> list[Check]:
    """The results' checks of one frame: within noise, scale, registration."""
    return [
        Check(
            name=f"{label}: within the reference's noise",
            value=a.verdict,
            expected="within noise",
            passed=a.within_noise,
        ),
        Check(
            name=f"{label}: global scale",
            value=a.scale,
            expected=f"1 within {SCALE_SIGMAS:g}σ ({a.scale_stderr:.2g})"
            + (" (or --fit-exposure)" if not a.scale_consistent else ""),
            passed=bool(a.scale_consistent or a.fit_exposure),
        ),
        Check(
            name=f"{label}: registration offset",
            value=f"({a.offset[0]:+d}, {a.offset[1]:+d}) px",
            expected="(+0, +0) px or not beyond the noise",
            passed=not a.misaligned,
        ),
    ]


def distance_bands(depth: np.ndarray, bands: int = 3) -> tuple[np.ndarray, dict[int, str]]:
    """(labels (H, W), names): the pixels' first-hit distances in ``bands`` bands of equal pixel counts
    (−1: no surface), each named by its range in scene units."""
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d)
    labels = np.full(d.shape, -1, np.int32)
    if not ok.any():
        return labels, {}
    edges = np.quantile(d[ok], np.linspace(0.0, 1.0, bands + 1))
    labels[ok] = np.clip(np.searchsorted(edges[1:-1], d[ok], side="right"), 0, bands - 1)
    words = ("near", "middle", "far") if bands == 3 else tuple(f"band {i + 1}" for i in range(bands))
    return labels, {i: f"{words[i]} ({edges[i]:.3g}–{edges[i + 1]:.3g})" for i in range(bands)}


def group_labels(hits: np.ndarray, of_shape: dict[int, str]) -> tuple[np.ndarray, dict[int, str]]:
    """Shapes grouped by a name per shape (e.g. its BSDF): (labels (H, W), names); −1 stays no surface."""
    distinct = sorted(set(of_shape.values()))
    index = {name: i for i, name in enumerate(distinct)}
    table = {k: index[v] for k, v in of_shape.items()}
    labels = np.vectorize(lambda k: table.get(int(k), -1), otypes=[np.int32])(hits) if hits.size else hits
    return labels.astype(np.int32), dict(enumerate(distinct))


def shape_table(shapes: list[ShapeError], what: str = "shape at the first hit") -> list[str]:
    """Markdown lines: the error per shape (or per group ``what``) at the pixels' first hits."""
    rows = [
        f"| {what} | pixels | mean reference | error (frame − reference) / reference | z rms |",
        "|---|---:|---:|---|---:|",
    ]
    rows += [
        f"| {e.name} | {e.pixels} | {e.reference_mean:.4g} | {e.words()} | {e.z_rms:.2f} |" for e in shapes
    ]
    return rows


def z_figure(path: Path, a: FrameAnalysis, label: str) -> None:
    """The frame's z-score map (mean over RGB), clipped at ±6, with the shapes' outlines."""
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(3.6, 3.2))
    z = np.clip(np.nan_to_num(np.mean(a.z_map, axis=-1), posinf=6.0, neginf=-6.0), -6.0, 6.0)
    im = ax.imshow(z, cmap="coolwarm", vmin=-6.0, vmax=6.0, interpolation="nearest")
    levels = np.unique(a.hits)
    if levels.size > 1:
        ax.contour(a.hits, levels=(levels[:-1] + 0.5), colors="k", linewidths=0.6)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"{label}: z (frame − ref)/σ", fontsize=8)
    fig.colorbar(im, ax=ax, shrink=0.8)
    figures.save_figure(fig, path)
