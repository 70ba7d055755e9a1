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
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight", pil_kwargs={"compress_level": 1})
    pyplot().close(fig)
    return atomic_write_bytes(path, buf.getvalue())


GREY = (0.75, 0.75, 0.75)
"""The colour of pixels outside the comparison mask in an error panel."""


def mosaic_axes(plt, tiles_wide: int, tile_h: int, tile_w: int, rows: int, width_in: float, title: str):
    """One figure holding a mosaic of ``rows`` × ``tiles_wide`` tiles of tile_h × tile_w pixels, each with a
    label band above it, as one image on one axes (no per-panel axes: a 12-panel comparison drew in 1.5 s as
    22 axes, in a fraction as one). Returns (fig, ax, gap, band): pixels between tiles and of each label band.
    """
    gap = max(2, tile_w // 16)
    band = max(6, tile_h // 5)
    width = tiles_wide * tile_w + (tiles_wide - 1) * gap
    height = rows * (tile_h + band) + (rows - 1) * gap
    height_in = width_in * height / width + (0.35 if title else 0.0)
    fig = plt.figure(figsize=(width_in, height_in))
    top = 1.0 - (0.35 / height_in if title else 0.0)
    ax = fig.add_axes((0.0, 0.0, 1.0, top))
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10, y=1.0 - 0.05 / height_in, va="top")
    return fig, ax, gap, band


def tile_origin(row: int, col: int, tile_h: int, tile_w: int, gap: int, band: int) -> tuple[int, int]:
    """(y, x) of the top-left pixel of tile (row, col) in the mosaic (below its label band)."""
    return row * (tile_h + band + gap) + band, col * (tile_w + gap)


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
    ±max(|normalised error|) over all panels, shown on a shared colour bar. Pixels are drawn as pixels
    (nearest neighbour: no smoothing hides a one-pixel error).
    """
    plt = pyplot()
    from matplotlib.colors import Normalize

    if exposure is None:
        exposure = float(np.percentile(reference[mask], 99.5)) if mask.any() else 1.0
        exposure = exposure if exposure > 0 else 1.0
    n = len(panels)
    h, w = reference.shape[:2]
    fig, ax, gap, band = mosaic_axes(plt, n + 1, h, w, 2, 2.3 * (n + 1), title)
    mosaic = np.ones((2 * (h + band) + gap, (n + 1) * w + n * gap, 3))
    errors = [np.where(mask, (img - reference).mean(axis=-1) / error_scale, np.nan) for _, img in panels]
    vmax = max([float(np.nanmax(np.abs(e))) for e in errors if np.isfinite(e).any()] + [1e-6])
    cmap = plt.get_cmap("RdBu_r").with_extremes(bad=GREY)
    norm = Normalize(vmin=-vmax, vmax=vmax)
    labels = [(0, 0, "reference", 9)]
    y, x = tile_origin(0, 0, h, w, gap, band)
    mosaic[y : y + h, x : x + w] = srgb(reference / exposure)
    for k, ((label, img), err) in enumerate(zip(panels, errors, strict=True), start=1):
        y, x = tile_origin(0, k, h, w, gap, band)
        mosaic[y : y + h, x : x + w] = srgb(img / exposure)
        y, x = tile_origin(1, k, h, w, gap, band)
        mosaic[y : y + h, x : x + w] = cmap(norm(np.ma.masked_invalid(err)))[..., :3]
        worst = float(np.nanmax(np.abs(err))) if np.isfinite(err).any() else float("nan")
        labels += [(0, k, label, 9), (1, k, f"error (max {worst:.3g})", 8)]
    ax.imshow(mosaic, interpolation="nearest")
    for row, col, text, size in labels:
        y, x = tile_origin(row, col, h, w, gap, band)
        ax.text(x + w / 2, y - 1, text, ha="center", va="bottom", fontsize=size, clip_on=False)
    y, x = tile_origin(1, 0, h, w, gap, band)
    ax.text(x + w / 2, y + h / 2, f"signed error\n÷ {error_scale:.3g}", ha="center", va="center", fontsize=9)
    if n:
        from matplotlib.cm import ScalarMappable

        fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.45, pad=0.01, anchor=(0.0, 0.0))
    return save_figure(fig, path)


def flip_maps_figure(path, maps: list[tuple[str, np.ndarray]], mask: np.ndarray, title: str) -> Path:
    """Each (label, ꟻLIP map in [0, 1]) side by side with its mean over ``mask`` (magma; grey outside the
    mask), as one mosaic (`mosaic_axes`), and a shared colour bar."""
    plt = pyplot()
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    h, w = maps[0][1].shape
    fig, ax, gap, band = mosaic_axes(plt, len(maps), h, w, 1, 2.3 * len(maps), title)
    band2 = 2 * band  # (two lines of label)
    mosaic = np.ones((h + band2, len(maps) * w + (len(maps) - 1) * gap, 3))
    cmap = plt.get_cmap("magma").with_extremes(bad=GREY)
    norm = Normalize(vmin=0.0, vmax=1.0)
    for k, (label, m) in enumerate(maps):
        x = k * (w + gap)
        mosaic[band2 : band2 + h, x : x + w] = cmap(norm(np.ma.masked_where(~mask, m)))[..., :3]
        ax.text(x + w / 2, band2 - 1, f"{label}\nmean {float(np.mean(m[mask])):.3g}", ha="center",
                va="bottom", fontsize=8, clip_on=False)  # fmt: skip
    ax.set_ylim(h + band2 - 0.5, -0.5)
    ax.imshow(mosaic, interpolation="nearest")
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.8, pad=0.01)
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
    """Error vs cost; each point dict: x (cost), y (error), label, and optionally x_pre (the cost with the
    method's precompute counted, e.g. amortised per frame): drawn as an open marker joined to the point,
    labelled once in the legend. The Pareto front (over x) is drawn."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    pts = sorted(points, key=lambda p: (p["x"], p["y"]))
    pre_label = "with its precompute, paid every frame"
    for p in pts:
        dot = ax.scatter([p["x"]], [p["y"]], s=28, zorder=3)
        ax.annotate(p["label"], (p["x"], p["y"]), textcoords="offset points", xytext=(4, 4), fontsize=7)
        if p.get("x_pre"):
            colour = dot.get_facecolor()[0]
            ax.plot([p["x"], p["x_pre"]], [p["y"], p["y"]], color=colour, lw=0.8, alpha=0.6, zorder=2)
            ax.scatter([p["x_pre"]], [p["y"]], s=28, facecolors="none", edgecolors=[colour], zorder=3,
                       label=pre_label)  # fmt: skip
            pre_label = None
    front, best = [], np.inf
    for p in pts:
        if p["y"] < best:
            front.append(p)
            best = p["y"]
    ax.plot([p["x"] for p in front], [p["y"] for p in front], "k--", lw=0.8, label="Pareto front")
    if floor is not None and floor > 0:
        ax.axhline(floor, color="0.5", lw=0.8, ls=":", label="reference noise floor")
    # a precompute may cost 10³× the kernel: a log axis keeps both visible
    _axes(ax, x_label, y_label, "log" if pre_label is None else None, "log", title)
    fig.tight_layout()
    return save_figure(fig, path)
