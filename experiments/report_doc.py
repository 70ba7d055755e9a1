"""The report's document model: the blocks a report is built of (:class:`Heading`, :class:`Prose`,
:class:`Bullets`, :class:`TableBlock` of :class:`Cell` s, :class:`FigureBlock`), the :class:`ReportDoc`
that numbers sections, tables and figures in document order, and the metric cells of the tables.

The markdown and HTML writers (:mod:`.report_writers`) and ``tables.tex`` (:mod:`.latex`) each render
the same :class:`ReportDoc`. A metric with ``resolved: false`` is set in grey italics and marked †: it is
not resolved, i.e. within 2× the reference's noise floor (the rule of ``rtfit.fitting.metrics``). Bold
marks the best value of a directed metric (:func:`mark_best`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from .records import Approximation, Case, Metric, Results
from .report_text import format_number

__all__ = [
    "METRICS",
    "UNRESOLVED_NOTE",
    "UNRESOLVED_TAG",
    "Bullets",
    "Cell",
    "FigureBlock",
    "Heading",
    "Prose",
    "ReportDoc",
    "TableBlock",
    "headline_metric",
    "mark_best",
    "metric_cell",
    "metric_keys",
    "metric_name",
]

# Known metrics: display name and direction (True: lower is better). Others render generically.
METRICS: dict[str, tuple[str, bool | None]] = {
    "rmse": ("RMSE", True),
    "rel_mse": ("relMSE", True),
    "mae": ("MAE", True),
    "max_abs": ("max |Δ|", True),
    "psnr": ("PSNR (dB)", False),
    "ssim": ("SSIM", False),
    "flip": ("FLIP", True),
}
# The resolve rule of rtfit.fitting.metrics: an error is resolved when it exceeds twice its noise floor
# (in amplitude; the squared relMSE 4×, PSNR 6.02 dB below its ceiling, SSIM by 1 − SSIM).
UNRESOLVED_NOTE = (
    "† Not resolved: within 2× the reference's noise floor (4× for the squared relMSE; within 6.02 dB "
    "of the ceiling for PSNR), so this error cannot be told apart from the Monte Carlo noise of the "
    "ground truth: at this sample count the approximation cannot be told apart from exact, and the "
    "value itself means nothing more."
)
UNRESOLVED_TAG = "within noise"  # beside a best value that is not resolved (bold still marks it)


# ----------------------------------------------------------------------------------------- document
@dataclass
class Cell:
    """One table cell: its text (plain, or inline markdown with ``md``) and how it is set."""

    text: str = ""
    sub: str = ""  # secondary text (the noise floor), smaller and grey in HTML
    numeric: bool = False
    md: bool = False  # ``text`` is inline markdown
    style: str = ""  # "", "unresolved", "best", "pass", "fail", "at-bound"
    mark: str = ""  # footnote mark
    tag: str = ""  # short qualifier after the value (UNRESOLVED_TAG on a best value that is not resolved)


@dataclass
class Heading:
    """A section heading; ``number`` ("2", "2.1") is empty for an unnumbered one (the summary)."""

    level: int
    title: str
    anchor: str
    number: str = ""


@dataclass
class Prose:
    """A paragraph (or more) of block markdown."""

    md: str


@dataclass
class Bullets:
    """A bulleted list; each item inline markdown."""

    items: list[str]


@dataclass
class TableBlock:
    """A numbered table with its caption and notes; ``tex``: also set in ``tables.tex``."""

    anchor: str
    number: int
    caption: str
    header: list[Cell]
    rows: list[list[Cell]]
    notes: list[str] = field(default_factory=list)
    tex_cols: list[int] | None = None  # columns in tables.tex (None: all)
    tex: bool = True


@dataclass
class FigureBlock:
    """A numbered figure of one or more images side by side; ``missing``: files not found."""

    number: int
    anchor: str
    images: list[tuple[str, str]]  # (relative file, sub-label)
    caption: str  # inline markdown
    missing: list[str] = field(default_factory=list)


def _slug(text: str) -> str:
    s = re.sub(r"[^\w\- ]", "", str(text).lower(), flags=re.UNICODE).strip().replace(" ", "-")
    return s or "x"


class ReportDoc:
    """A report being built: its blocks in order, with unique anchors and the numbers of its sections,
    tables and figures. ``directory`` (None: not checked) is where figure files are looked up to flag
    missing ones."""

    def __init__(self, results: Results, directory: Path | None):
        self.r = results
        self.dir = directory
        self.blocks: list = []
        self.anchors: set[str] = set()
        self.tables = 0
        self.figures = 0
        self.sec = [0, 0]

    def anchor(self, base: str) -> str:
        a, k = _slug(base), 2
        while a in self.anchors:
            a, k = f"{_slug(base)}-{k}", k + 1
        self.anchors.add(a)
        return a

    def heading(self, level: int, title: str, key: str, numbered: bool = True) -> str:
        number = ""
        if numbered and level == 2:
            self.sec = [self.sec[0] + 1, 0]
            number = str(self.sec[0])
        elif numbered and level == 3:
            self.sec[1] += 1
            number = f"{self.sec[0]}.{self.sec[1]}"
        a = self.anchor(key)
        self.blocks.append(Heading(level, title, a, number))
        return a

    def prose(self, md: str):
        if md and md.strip():
            self.blocks.append(Prose(md.strip()))

    def table(self, key, caption, header, rows, notes=(), tex_cols=None, tex=True):
        self.tables += 1
        self.blocks.append(
            TableBlock(
                self.anchor(f"table-{key}"), self.tables, caption, header, rows, list(notes), tex_cols, tex
            )
        )

    def figure(self, images, caption):
        self.figures += 1
        missing = [f for f, _ in images if self.dir is not None and not (self.dir / f).is_file()]
        self.blocks.append(
            FigureBlock(self.figures, self.anchor(f"figure-{self.figures}"), images, caption, missing)
        )


def metric_name(key: str) -> str:
    """A metric's column header: its display name with ↓ (lower is better) or ↑ where directed."""
    name, lower = METRICS.get(key, (key, None))
    return name + ("" if lower is None else (" ↓" if lower else " ↑"))


def metric_keys(approximations: list[Approximation]) -> list[str]:
    """The metric keys of ``approximations``: the known ones in :data:`METRICS` order, then the others in
    order of first appearance."""
    seen: list[str] = []
    for ap in approximations:
        for k in ap.metrics:
            if k not in seen:
                seen.append(k)
    return [k for k in METRICS if k in seen] + [k for k in seen if k not in METRICS]


def metric_cell(m: Metric | None) -> Cell:
    """A metric's cell: its value with its noise floor, set grey and marked † where not resolved."""
    if m is None:
        return Cell("—", numeric=True)
    cell = Cell(format_number(m.value), "floor " + format_number(m.noise_floor), numeric=True)
    if m.resolved is False:
        cell.style, cell.mark = "unresolved", "†"
    return cell


def _shown(x: float) -> float:
    """``x`` rounded to the 4 significant digits :func:`format_number` prints."""
    return float(f"{x:.3e}")


def mark_best(cells: list[Cell], entries: list[Metric | None], key: str) -> None:
    """Set the best value of a directed metric in bold (only where there are two or more entries):
    the smallest (the largest for a higher-is-better metric), resolved or not: a worse value is never
    bold. A best value that is not resolved keeps its † and is tagged :data:`UNRESOLVED_TAG`."""
    lower = METRICS.get(key, (key, None))[1]
    if lower is None:
        return
    vals = [(e.value, i, e) for i, e in enumerate(entries) if e is not None and e.value is not None]
    if len(entries) < 2 or not vals:
        return
    best = _shown(min(v for v, _, _ in vals) if lower else max(v for v, _, _ in vals))
    for v, i, e in vals:
        if _shown(v) == best:  # values that print the same are tied: all bold
            cells[i].style = "best"
            if e.resolved is False:
                cells[i].mark, cells[i].tag = "†", UNRESOLVED_TAG


def headline_metric(cases: list[Case]) -> str | None:
    """The metric the overview and the suite index show: rmse where measured, else the first known
    metric (in :data:`METRICS` order) of the cases."""
    keys = metric_keys([ap for c in cases for ap in c.approximations])
    return "rmse" if "rmse" in keys else (keys[0] if keys else None)
