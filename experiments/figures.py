"""Figures for reports (matplotlib, Agg backend, PNG written atomically).

Images are shown linearly scaled by a common exposure and encoded with the sRGB transfer curve, so
that reference and approximation panels are directly comparable. Error maps are signed and
false-coloured with a diverging map symmetric about zero (red: approximation too bright, blue: too
dark), normalised by a stated scale (e.g. the light's peak irradiance) so that colours mean the
same across panels; pixels outside the comparison mask are grey.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from rtfit.reference.io import atomic_write_bytes


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (figures are written, never shown)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def srgb(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def save_figure(fig, path) -> Path:
    """Write ``fig`` atomically and close it: PDF (vector, no creation date, so the same figure gives
    the same bytes) where ``path`` ends in ``.pdf``, PNG otherwise."""
    buf = io.BytesIO()
    if Path(path).suffix.lower() == ".pdf":
        fig.savefig(buf, format="pdf", bbox_inches="tight", metadata={"CreationDate": None})
    else:
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def image_comparison(
    path,
    reference: np.ndarray,
    panels: list[tuple[str, np.ndarray]],
    mask: np.ndarray,
    error_scale: float,
    title: str = "",
    exposure: float | None = None,
) -> Path:
    """Reference, then for each (label, image): the image above its signed error map.

    ``error_scale`` normalises the error (approx − reference) / error_scale; the colour range is
    ±max(|normalised error|) over all panels, shown on a shared colour bar.
    """
    plt = pyplot()
    if exposure is None:
        exposure = float(np.percentile(reference[mask], 99.5)) if mask.any() else 1.0
        exposure = exposure if exposure > 0 else 1.0
    n = len(panels)
    fig, axes = plt.subplots(2, n + 1, figsize=(2.3 * (n + 1), 4.9), squeeze=False)
    axes[0, 0].imshow(srgb(reference / exposure))
    axes[0, 0].set_title("reference", fontsize=9)
    errors = [np.where(mask, (img - reference).mean(axis=-1) / error_scale, np.nan) for _, img in panels]
    vmax = max([float(np.nanmax(np.abs(e))) for e in errors if np.isfinite(e).any()] + [1e-6])
    im = None
    for k, ((label, img), err) in enumerate(zip(panels, errors, strict=True), start=1):
        axes[0, k].imshow(srgb(img / exposure))
        axes[0, k].set_title(label, fontsize=9)
        cmap = plt.get_cmap("RdBu_r").with_extremes(bad="0.75")
        im = axes[1, k].imshow(err, cmap=cmap, vmin=-vmax, vmax=vmax)
        axes[1, k].set_title(f"error (max {np.nanmax(np.abs(err)):.3g})", fontsize=8)
    axes[1, 0].axis("off")
    axes[1, 0].text(0.5, 0.5, f"signed error\n÷ {error_scale:.3g}", ha="center", va="center", fontsize=9)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    if im is not None:
        fig.colorbar(im, ax=list(axes[1, 1:]), shrink=0.8, pad=0.02)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def case_comparison(
    out,
    doc: dict,
    reference: np.ndarray,
    panels: list[tuple[str, np.ndarray]],
    mask: np.ndarray,
    error_scale: float,
    caption: str,
) -> dict:
    """One case's image figure, linked from the case's rows.

    Draws :func:`image_comparison` of ``reference`` and ``panels`` (the case's label as title) to
    ``OUT/figures/CASE-ID.png``, where ``doc`` is the case document (``id``, ``label``,
    ``approximations``), and points every approximation record of the case at it
    (``ap["figures"]``, so the report shows the figure with the row). Returns the figure record for
    the report: the file relative to ``out``, ``caption``, section "results".
    """
    path = image_comparison(
        Path(out) / "figures" / f"{doc['id']}.png",
        reference,
        panels,
        mask,
        error_scale=error_scale,
        title=doc["label"],
    )
    rel = f"figures/{path.name}"
    for ap in doc["approximations"]:
        ap["figures"] = [rel]
    return {"file": rel, "caption": caption, "section": "results"}


def line_plot(
    path,
    x_label: str,
    y_label: str,
    series: list[dict],
    title: str = "",
    x_log: bool = False,
    y_log: bool = False,
    panels: list[str] | None = None,
) -> Path:
    """Curves; each series dict: x, y, label, optional yerr, style ("line"/"points"), panel."""
    plt = pyplot()
    panels = panels or [""]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.6), squeeze=False)
    for ax, panel in zip(axes[0], panels, strict=True):
        for s in series:
            if s.get("panel", "") != panel:
                continue
            x, y = np.asarray(s["x"]), np.asarray(s["y"])
            if s.get("style") == "points":
                ax.errorbar(
                    x, y, yerr=s.get("yerr"), fmt="o", ms=3, capsize=2, label=s["label"], color=s.get("color")
                )
            else:
                ax.plot(x, y, s.get("ls", "-"), label=s["label"], lw=1.4, color=s.get("color"))
        _axes(ax, x_label, y_label, "log" if x_log else None, "log" if y_log else None, panel)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _axes(ax, x_label: str, y_label: str, x_scale: str | None, y_scale: str | None, title: str) -> None:
    """Labels, scales (None: linear), a title (empty: none), the grid and the legend of one panel."""
    ax.set_xlabel(x_label)
    ax.set_ylabel(y_label)
    if x_scale:
        ax.set_xscale(x_scale)
    if y_scale:
        ax.set_yscale(y_scale)
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def pareto_plot(
    path, points: list[dict], x_label: str, y_label: str, title: str = "", floor: float | None = None
) -> Path:
    """Error vs cost; each point dict: x (cost), y (error), label. The Pareto front is drawn."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    pts = sorted(points, key=lambda p: (p["x"], p["y"]))
    for p in pts:
        ax.scatter([p["x"]], [p["y"]], s=28, zorder=3)
        ax.annotate(p["label"], (p["x"], p["y"]), textcoords="offset points", xytext=(4, 4), fontsize=7)
    front, best = [], np.inf
    for p in pts:
        if p["y"] < best:
            front.append(p)
            best = p["y"]
    ax.plot([p["x"] for p in front], [p["y"] for p in front], "k--", lw=0.8, label="Pareto front")
    if floor is not None and floor > 0:
        ax.axhline(floor, color="0.5", lw=0.8, ls=":", label="reference noise floor")
    _axes(ax, x_label, y_label, None, "log", title)
    fig.tight_layout()
    return save_figure(fig, path)
