"""Figures for reports (matplotlib, Agg backend, PNG written atomically).

Images are shown linearly scaled by a common exposure and encoded with the sRGB transfer curve, so
that reference and approximation panels are directly comparable. Error maps are signed and
false-coloured with a diverging map symmetric about zero (red: approximation too bright, blue: too
dark), normalised by a stated scale (e.g. the light's peak irradiance) so that colours mean the
same across panels; pixels outside the comparison mask are grey.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import io
import os
import struct
import zlib
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import PIL.Image
import PIL.PngImagePlugin

from rtfit.reference.io import atomic_write_bytes

from .figure_text import PNG_DPI, text_pixels, wrap_to_width


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (figures are written, never shown), its renderers
    sharing one cache of parsed math text (`_share_math_parses`)."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    _share_math_parses()
    return plt


MATH_PARSES = 1024
"""Parsed math-text labels kept for all the figures of a process (`_share_math_parses`; matplotlib: 50)."""


@functools.cache
def _share_math_parses() -> None:
    """One math-text parser for all of matplotlib's Agg renderers, its cache of parses (keyed by the text, the
    dpi, the font and the hinting: the same parse for the same key) raised to `MATH_PARSES` entries.

    Matplotlib 3.11 gives each renderer its own ``MathTextParser`` and caches parses per parser (50 of them),
    and every figure gets new renderers: one for its layout, one for the PNG at `PNG_DPI` (a cropped canvas
    of another size). A log axis labels its ticks in math text (10², 10³), so every log-scaled figure parsed
    every tick label again, twice: 2.4 of the quick suite's ~14 s of matplotlib (issue 33, session 27); a
    two-panel log-log `line_plot` 0.44–0.50 → 0.29–0.32 s, the same bytes. Where matplotlib's internals are
    not as expected, nothing is changed."""
    import matplotlib.backends.backend_agg as agg
    import matplotlib.mathtext as mathtext

    parser_class = getattr(mathtext, "MathTextParser", None)
    cached = getattr(parser_class, "_parse_cached", None)
    if agg.MathTextParser is not parser_class or not hasattr(cached, "__wrapped__"):
        return
    shared: dict[str, Any] = {}

    def one_parser(output: str):
        if output not in shared:
            shared[output] = parser_class(output)
        return shared[output]

    parser_class._parse_cached = functools.lru_cache(MATH_PARSES)(cached.__wrapped__)
    agg.MathTextParser = one_parser


def srgb(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def tight_bbox(fig, dpi: float):
    """The box (inches) that ``bbox_inches="tight"`` crops ``fig`` to at ``dpi``: its artists' extents padded
    by :rc:`savefig.pad_inches`. Measured from the artists' extents alone: given to ``savefig`` as a box, it
    spares the second, invisible draw of the whole figure that ``"tight"`` makes to find the same box (the
    same pixels; 10-15 % of a mosaic figure's time when they were matplotlib axes, issue 33)."""
    import matplotlib

    fig.set_dpi(dpi)
    pad = matplotlib.rcParams["savefig.pad_inches"]
    return fig.get_tightbbox(fig.canvas.get_renderer()).padded(pad, pad)


def save_figure(fig, path) -> Path:
    """Write ``fig`` atomically and close it, cropped to its artists (`tight_bbox`): PDF (vector, no creation
    date, so the same figure gives the same bytes) where ``path`` ends in ``.pdf``, PNG otherwise."""
    from matplotlib.layout_engine import PlaceHolderLayoutEngine

    if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine):
        # What ``fig.tight_layout()`` leaves behind (a layout done once, no engine): savefig would draw the
        # whole figure once more, unseen, "to make sure the layout engine runs" — none runs. Without it the
        # same bytes (a log-log `line_plot`: 0.47 → 0.28–0.41 s, issue 33).
        fig.set_layout_engine(None)
    buf = io.BytesIO()
    if Path(path).suffix.lower() == ".pdf":
        fig.savefig(buf, format="pdf", bbox_inches="tight", metadata={"CreationDate": None})
    else:
        box = tight_bbox(fig, PNG_DPI)
        fig.savefig(buf, format="png", dpi=PNG_DPI, bbox_inches=box, pil_kwargs={"compress_level": 1})
    pyplot().close(fig)
    return atomic_write_bytes(path, buf.getvalue())


GREY = (0.75, 0.75, 0.75)
"""The colour of pixels outside the comparison mask in an error panel."""


def mosaic_axes(plt, tiles_wide: int, tile_h: int, tile_w: int, rows: int, width_in: float, title: str):
    """One figure holding a mosaic of ``rows`` × ``tiles_wide`` tiles of tile_h × tile_w pixels, each with a
    label band above it, as one image on one axes (no per-panel axes: a 12-panel comparison drew in 1.5 s as
    22 axes, in a fraction as one). Returns (fig, ax, gap, band): pixels between tiles and of each label band.
    """
    gap, band = mosaic_spacing(tile_h, tile_w)
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
    ±max(|normalised error|) over all panels, shown on a shared colour bar beside the error row. Pixels are
    drawn as pixels (nearest neighbour: no smoothing hides a one-pixel error). One mosaic image
    (`MosaicFigure`).
    """
    import matplotlib
    from matplotlib.colors import Normalize

    if exposure is None:
        exposure = float(np.percentile(reference[mask], 99.5)) if mask.any() else 1.0
        exposure = exposure if exposure > 0 else 1.0
    n = len(panels)
    h, w = reference.shape[:2]
    gap, band = mosaic_spacing(h, w)
    mosaic = np.ones((2 * (h + band) + gap, (n + 1) * w + n * gap, 3))
    errors = [np.where(mask, (img - reference).mean(axis=-1) / error_scale, np.nan) for _, img in panels]
    vmax = max([float(np.nanmax(np.abs(e))) for e in errors if np.isfinite(e).any()] + [1e-6])
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=GREY)
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
    fig = MosaicFigure(mosaic, title, w)
    for row, col, text, size in labels:
        y, x = tile_origin(row, col, h, w, gap, band)
        fig.text(x + w / 2, y - 1, text, size, va="bottom", width=w + gap)
    y, x = tile_origin(1, 0, h, w, gap, band)
    fig.text(x + w / 2, y + h / 2, f"signed error\n÷ {error_scale:.3g}", 9, va="center")
    if n:
        fig.colour_bar(cmap, norm, y, y + h)  # beside the error row
    return fig.save(path)


def flip_maps_figure(path, maps: list[tuple[str, np.ndarray]], mask: np.ndarray, title: str) -> Path:
    """Each (label, ꟻLIP map in [0, 1]) side by side with its mean over ``mask`` (magma; grey outside the
    mask), as one mosaic image (`MosaicFigure`), and a shared colour bar."""
    import matplotlib
    from matplotlib.colors import Normalize

    h, w = maps[0][1].shape
    gap, band = mosaic_spacing(h, w)
    band2 = 2 * band  # (two lines of label)
    mosaic = np.ones((h + band2, len(maps) * w + (len(maps) - 1) * gap, 3))
    cmap = matplotlib.colormaps["magma"].with_extremes(bad=GREY)
    norm = Normalize(vmin=0.0, vmax=1.0)
    texts = []
    for k, (label, m) in enumerate(maps):
        x = k * (w + gap)
        mosaic[band2 : band2 + h, x : x + w] = cmap(norm(np.ma.masked_where(~mask, m)))[..., :3]
        texts.append((x + w / 2, f"{label}\nmean {float(np.mean(m[mask])):.3g}"))
    fig = MosaicFigure(mosaic, title, w)
    for x, text in texts:
        fig.text(x, band2 - 1, text, 8, va="bottom", width=w + gap)
    fig.colour_bar(cmap, norm, 0, h + band2)
    return fig.save(path)


def mosaic_spacing(tile_h: int, tile_w: int) -> tuple[int, int]:
    """(gap, band): mosaic pixels between tiles and of each tile's label band (`mosaic_axes`,
    `MosaicFigure`)."""
    return max(2, tile_w // 16), max(6, tile_h // 5)


MOSAIC_COLUMN_PX = 214
"""Figure pixels of one tile and its gap in a `MosaicFigure` (what `mosaic_axes` gave a tile at 110 dpi beside
a colour bar)."""


class MosaicFigure:
    """A figure that is one RGB mosaic (tiles with label bands, `tile_origin`) shown at a fixed scale (nearest
    neighbour: each mosaic pixel a block of figure pixels), its labels and title as text, and optionally a
    colour bar (a gradient with its frame, ticks and tick labels), composed as one array of pixels and
    written as PNG; the text is drawn by matplotlib's FreeType font (`text_pixels`: the font, size
    and hinting of matplotlib's text). The layout is computed, not searched: no matplotlib figure, axes,
    colour-bar axes or ``bbox_inches="tight"`` (drawing each figure twice, measuring every artist, and
    matplotlib's drawing of text and image took 95 % of an audit's figure time, issue 33). Text positions
    are in mosaic pixels from the top-left, pixel centres at integers."""

    MARGIN = 11  # figure pixels around the content (savefig's pad of 0.1 in at 110 dpi)
    TITLE_BAND = 38  # figure pixels of the title's band above the mosaic (0.35 in)
    BAR_PAD, BAR_ASPECT, TICK, TICK_PAD = (
        11,
        20,
        5,
        5,
    )  # matplotlib's colour bar at 110 dpi: pad, aspect, ticks
    TICK_FONT = 10

    def __init__(self, mosaic: np.ndarray, title: str, tile_w: int):
        gap, _ = mosaic_spacing(1, tile_w)
        self.scale = MOSAIC_COLUMN_PX / (tile_w + gap)
        self.mosaic, self.title = mosaic, title
        self.texts: list = []  # (text, size, ha, va, x, y): figure pixels from the image's top-left
        self.bar = None

    def text(self, x: float, y: float, text: str, size: float, va: str, width: float | None = None) -> None:
        """``text`` centred on mosaic pixel column ``x``, its ``va`` ("bottom", "center") at row ``y``; with
        ``width`` (mosaic pixels, e.g. a tile's), its lines wrapped at spaces to fit that width
        (`wrap_to_width`), so that neighbouring tiles' labels do not run into each other."""
        if width is not None:
            text = wrap_to_width(text, size, width * self.scale)
        self.texts.append((text, size, "center", va, (x + 0.5) * self.scale, (y + 0.5) * self.scale))

    def colour_bar(self, cmap, norm, top: int, bottom: int) -> None:
        """A vertical colour bar of ``cmap`` over ``norm``'s range, right of the mosaic, from mosaic row
        ``top`` to ``bottom`` (exclusive), ticked as matplotlib ticks a colour bar that long
        (`colour_bar_ticks`)."""
        self.bar = (cmap, norm, round(top * self.scale), round(bottom * self.scale))

    def _indices(self) -> tuple[np.ndarray, np.ndarray]:
        """The mosaic's row and column shown at each figure pixel row and column (nearest neighbour)."""
        mh, mw = self.mosaic.shape[:2]
        rows = (np.arange(round(mh * self.scale)) + 0.5) / self.scale
        cols = (np.arange(round(mw * self.scale)) + 0.5) / self.scale
        return np.minimum(rows.astype(int), mh - 1), np.minimum(cols.astype(int), mw - 1)

    def save(self, path) -> Path:
        """Lay the figure out around its content and write it as PNG (atomically).

        The figure's pixels are 8-bit: round(255 × v) of each pixel's value v in [0, 1] (the mosaic's, the
        colour bar's, white around them), text darkening v by (1 − coverage) for each text over it in
        turn. Composed in 8 bits where no text lies (the mosaic rounded once, then enlarged) and in floats
        only under the texts' boxes: the same pixels as composing every pixel in floats first, without a
        float canvas of the whole figure (issue 33)."""
        m = self.MARGIN
        row_of, col_of = self._indices()
        ih, iw = len(row_of), len(col_of)
        texts, ticks = list(self.texts), []
        bar_w = x0 = 0  # (the colour bar's width and left edge, where there is one)
        if self.bar is not None:
            cmap, norm, top, bottom = self.bar
            bar_w, x0 = max(2, round((bottom - top) / self.BAR_ASPECT)), iw + self.BAR_PAD
            locs, labels, offset = colour_bar_ticks(
                norm.vmin, norm.vmax, (bottom - top) / PNG_DPI * 72, self.TICK_FONT
            )
            for loc, label in zip(locs, labels, strict=True):
                ticks.append(
                    round(bottom - 1 - (loc - norm.vmin) / (norm.vmax - norm.vmin) * (bottom - top - 1))
                )
                texts.append(
                    (
                        label,
                        self.TICK_FONT,
                        "left",
                        "center",
                        x0 + bar_w + self.TICK + self.TICK_PAD,
                        ticks[-1],
                    )
                )
            if offset:
                texts.append((offset, self.TICK_FONT, "left", "bottom", x0, top - self.TICK_PAD))
        # the content's box (figure pixels from the image's top-left): the image, bar, and every text
        x_lo, y_lo, x_hi, y_hi = 0.0, 0.0, float(iw), float(ih)
        if self.bar is not None:
            x_hi = float(x0 + bar_w)
        placed = []
        for text, size, ha, va, x, y in texts:
            alpha = text_pixels(text, size, ha)
            th, tw = alpha.shape
            left = round(x - tw / 2 if ha == "center" else x)
            top = round(y - th / 2 if va == "center" else y - th)
            placed.append((alpha, left, top))
            x_lo, x_hi, y_lo, y_hi = (
                min(x_lo, left),
                max(x_hi, left + tw),
                min(y_lo, top),
                max(y_hi, top + th),
            )
        title = text_pixels(self.title, 10, "center") if self.title else np.zeros((0, 0))
        width = int(np.ceil(max(x_hi - x_lo, title.shape[1]) + 2 * m))
        ox = round(m - x_lo + max(0.0, (title.shape[1] - (x_hi - x_lo)) / 2))
        oy = round(m - y_lo + (self.TITLE_BAND if self.title else 0))
        height = int(np.ceil(oy + y_hi + m))
        # the layers under the text, in order: (top, left, a block of values in [0, 1]; a function giving
        # the block's rows and columns where it is large: the mosaic enlarged)
        layers: list = [(oy, ox, ih, iw, lambda r, c: self.mosaic[row_of[r]][:, col_of[c]])]
        if self.bar is not None:
            cmap, norm, top, bottom = self.bar
            block = np.repeat(cmap(np.linspace(1.0, 0.0, bottom - top))[:, None, :3], bar_w, axis=1)
            block[:, 0] = block[:, -1] = block[0] = block[-1] = 0.0  # the frame
            layers.append((oy + top, ox + x0, bottom - top, bar_w, block))
            layers += [(oy + y, ox + x0 + bar_w, 1, self.TICK, np.zeros((1, self.TICK, 3))) for y in ticks]
        canvas = np.full((height, width, 3), 255, np.uint8)
        small = np.round(np.asarray(self.mosaic, np.float64) * 255).astype(np.uint8)
        # columns first, on the mosaic's own rows, then rows: the same gathers (the same bytes) as
        # small[row_of][:, col_of], whose column gather on the enlarged rows was a third of the quick suite's
        # mosaic time (2.5 of 8.2 s; this order 6.5x faster on a 600 x 1680 figure, issue 33)
        canvas[oy : oy + ih, ox : ox + iw] = small.take(col_of, axis=1).take(row_of, axis=0)
        for y, x, h, w, block in layers[1:]:
            canvas[y : y + h, x : x + w] = np.round(block * 255).astype(np.uint8)
        if self.title:
            placed.append((title, (width - title.shape[1]) // 2 - ox, m - oy))
        boxes = [(oy + top, ox + left, *alpha.shape) for alpha, left, top in placed]
        for k, (y, x, h, w) in enumerate(boxes):  # black text: each box's pixels in floats, every text over
            values = _base_values(layers, y, x, h, w)  # them (this one and those before) in turn
            for (alpha, _, _), (ay, ax, ah, aw) in zip(placed[: k + 1], boxes[: k + 1], strict=True):
                r0, r1, c0, c1 = max(y, ay), min(y + h, ay + ah), max(x, ax), min(x + w, ax + aw)
                if r0 < r1 and c0 < c1:
                    values[r0 - y : r1 - y, c0 - x : c1 - x] *= (
                        1.0 - alpha[r0 - ay : r1 - ay, c0 - ax : c1 - ax, None]
                    )
            canvas[y : y + h, x : x + w] = np.round(values * 255).astype(np.uint8)
        return _written(path, canvas)


def _write_png(path, canvas: np.ndarray) -> Path:
    """``canvas`` (8-bit RGB) encoded (`png_rows_up`) and written to ``path`` atomically."""
    return atomic_write_bytes(path, png_rows_up(canvas, PNG_DPI))


_BACKGROUND: contextvars.ContextVar[tuple | None] = contextvars.ContextVar("rtfit_pngs", default=None)
"""(executor, pending futures, most pending, the id of the process that made them) inside
`pngs_in_background`; None outside it."""
PNGS_PENDING = 8
"""The most mosaic figures composed and not yet written (`pngs_in_background`): a figure's canvas is a few
MB (a 1575 × 571 mosaic: 2.7 MB), so at most ~20 MB wait; the next one waits for the oldest."""


def _written(path, canvas: np.ndarray) -> Path:
    """Write ``canvas`` to ``path`` now, or hand it to the writer thread of an enclosing
    `pngs_in_background` (the canvas is not changed after: a figure's own array)."""
    background = _BACKGROUND.get()
    if background is None or background[3] != os.getpid():  # (a forked helper: not its parent's writer)
        return _write_png(path, canvas)
    executor, pending, most, _pid = background
    while len(pending) >= most:
        pending.popleft().result()  # (an earlier write's error surfaces here, at once)
    pending.append(executor.submit(_write_png, path, canvas))
    return Path(path)


@contextlib.contextmanager
def pngs_in_background(most: int = PNGS_PENDING) -> Iterator[None]:
    """Within the block, `MosaicFigure.save` composes a figure and hands its PNG encoding and atomic write to
    one writer thread, which runs beside the next figure's composition (zlib's deflate and NumPy's row
    differences release the GIL); on leaving, every figure is written (the first error of a write raised
    there, unless the block itself raised). The figures' bytes and files are those a plain `save` writes.
    Issue 33 (session 28): encoding the mosaics was 1.5 s of the Veach MIS scene's 11.3 s report (144
    figures) and 0.2 of the Cornell box's 2.0 s. A block inside another of the same process adds nothing
    (the outer one's writer serves it, and its leaving writes them all); in a process forked inside one (a
    helper, `rtfit.fitting.forked_fits`), which has no writer thread, a block makes its own."""
    outer = _BACKGROUND.get()
    if outer is not None and outer[3] == os.getpid():
        yield
        return
    executor = ThreadPoolExecutor(1, thread_name_prefix="rtfit-png")
    pending: deque[Future] = deque()
    token = _BACKGROUND.set((executor, pending, most, os.getpid()))
    raised = True
    try:
        yield
        raised = False
    finally:
        _BACKGROUND.reset(token)
        executor.shutdown(wait=True)
        errors = [e for e in (f.exception() for f in pending) if e is not None]
        if errors and not raised:
            raise errors[0]


def _base_values(layers: list, y: int, x: int, h: int, w: int) -> np.ndarray:
    """The values in [0, 1] of the figure's pixels [y, y + h) × [x, x + w) under any text: white, then each of
    `MosaicFigure.save`'s ``layers`` (top, left, height, width, block) in turn."""
    values = np.ones((h, w, 3))
    for ly, lx, lh, lw, block in layers:
        r0, r1, c0, c1 = max(y, ly), min(y + h, ly + lh), max(x, lx), min(x + w, lx + lw)
        if r0 < r1 and c0 < c1:
            rows, cols = slice(r0 - ly, r1 - ly), slice(c0 - lx, c1 - lx)
            part = np.asarray(block(rows, cols) if callable(block) else block[rows, cols])
            values[r0 - y : r1 - y, c0 - x : c1 - x] = part
    return values


def png_rows_up(rgb8: np.ndarray, dpi: float) -> bytes:
    """PNG of 8-bit RGB pixels (H, W, 3): the pixels `png_bytes` writes (it adds an opaque alpha channel, as
    matplotlib does), as an RGB PNG of resolution ``dpi``, encoded for speed: every row PNG's "Up" filter (the
    difference from the row above: zero for the repeated rows of an enlarged mosaic), deflated at zlib level
    1. Pillow's encoder chooses a filter per row by trying each, which was two thirds of writing a mosaic
    figure (36 ms of 50 for a 1575 × 571 figure, issue 33), for files ~5 % smaller; the alpha channel, always
    opaque, was half of what was left (a 1576 × 572 mosaic: 35.7 → 15.7 ms without it, issue 33)."""
    h, w = rgb8.shape[:2]
    rows = np.empty((h, 1 + 3 * w), np.uint8)
    rows[:, 1:] = np.ascontiguousarray(rgb8, np.uint8).reshape(h, 3 * w)
    rows[1:, 1:] -= rows[:-1, 1:].copy()  # (mod 256: uint8 arithmetic wraps)
    rows[:, 0] = 2  # the Up filter

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ppm = round(dpi / 0.0254)
    return b"".join(
        (
            b"\x89PNG\r\n\x1a\n",
            chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)),  # colour type 2: RGB
            chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)),
            chunk(b"IDAT", zlib.compress(rows.tobytes(), 1)),
            chunk(b"IEND", b""),
        )
    )


def png_bytes(rgb8: np.ndarray, dpi: float, compress_level: int | None = None) -> bytes:
    """PNG of 8-bit RGB pixels (H, W, 3) as ``matplotlib.image.imsave`` writes them with
    ``metadata={"Software": None}`` (RGBA, opaque, its resolution ``dpi``; the same bytes), written by
    Pillow directly: no colour mapping of pixels that are already bytes, and no import of matplotlib's
    image module."""
    h, w = rgb8.shape[:2]
    rgba = np.empty((h, w, 4), np.uint8)
    rgba[..., :3] = rgb8
    rgba[..., 3] = 255
    image = PIL.Image.frombuffer("RGBA", (w, h), rgba, "raw", "RGBA", 0, 1)
    buf = io.BytesIO()
    options = {} if compress_level is None else {"compress_level": compress_level}
    image.save(buf, format="png", pnginfo=PIL.PngImagePlugin.PngInfo(), dpi=(dpi, dpi), **options)
    return buf.getvalue()


def colour_bar_ticks(vmin: float, vmax: float, length_pt: float, font_pt: float) -> tuple[list, list, str]:
    """(values, labels, offset text) of the ticks matplotlib puts on a vertical colour bar of ``length_pt``
    points over [vmin, vmax] with tick labels of ``font_pt``: its `AutoLocator`'s bins ('auto': one per two
    label heights, at most 9) and `ScalarFormatter` (its offset text, e.g. ``1e−5``, set above the bar)."""
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    nbins = max(min(int(np.floor(length_pt / (2 * font_pt))), 9), 1)
    locs = MaxNLocator(nbins=nbins, steps=[1, 2, 2.5, 5, 10]).tick_values(vmin, vmax)
    span = abs(vmax - vmin)
    locs = [float(v) for v in locs if vmin - 1e-10 * span <= v <= vmax + 1e-10 * span]
    fmt = ScalarFormatter()
    fmt.create_dummy_axis()
    assert fmt.axis is not None
    fmt.axis.set_view_interval(vmin, vmax)
    labels = fmt.format_ticks(locs)
    return locs, labels, fmt.get_offset()


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
