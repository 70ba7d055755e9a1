"""Reports from ``results.json``: ``report.md``, ``report.html``, ``tables.tex``, and a suite index.

Everything a report shows comes from ``results.json`` (schema ``rtfit.results/1``, described in
``docs/results-schema.md``), so ``rtfit report DIR`` regenerates it without rerunning anything.
The output is deterministic: the same results give byte-identical files.

Layout (paper-like): title; summary; contents; 1 Setup (configuration, versions, device); each
``sections`` entry; Results (an overview table of the headline metric when there are several cases,
then per case: parameters, reference, and a metrics table with every value beside its noise floor);
Cost; Fitted parameters; Checks; Figures not placed in a section; Notes. Tables and figures are
numbered in document order. A metric with ``resolved: false`` is set in grey italics and marked †:
it is not resolved, i.e. within 2× the reference's noise floor (the rule of ``rtfit.fitting.metrics``),
and cannot be told apart from the ground truth's Monte Carlo noise. Bold marks the best value of a
directed metric (the smallest; the largest for ↑ metrics), resolved or not, so a worse value is never
bold; a best value that is not resolved keeps its † and is tagged "within noise".

``tables.tex`` holds the same tables as LaTeX ``table`` floats (needs ``\\usepackage{booktabs}``).
The HTML is one self-contained page (inline CSS) referring to the figures by relative path; the
markdown of ``summary``, ``sections``, captions and notes is CommonMark with pipe tables, rendered by
markdown-it-py (:func:`markdown_to_html`, :func:`markdown_inline`) with raw HTML escaped.
"""

from __future__ import annotations

import html
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from markdown_it import MarkdownIt
from markdown_it.rules_inline import StateInline

from . import latex, viewer
from .atomic import atomic_write_text, is_temporary_name
from .records import (
    SCHEMA,
    Approximation,
    Case,
    Cost,
    Figure,
    FitParameter,
    Metric,
    Results,
    ResultsError,
    from_json,
    plain_json,
)
from .results import load_results

__all__ = [
    "SCHEMA",
    "ResultsError",
    "config_rows",
    "format_number",
    "headline_metric",
    "load_results",
    "markdown_inline",
    "markdown_table",
    "markdown_table_cell",
    "markdown_to_html",
    "markdown_tokens",
    "render_report",
    "report_tables",
    "write_index",
    "write_report",
]

REPORT_FILES = ("report.md", "report.html", "tables.tex")

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
INDEX_UNRESOLVED_MARK = "not resolved†"  # the index's mean over cases where no case is resolved
INDEX_UNRESOLVED_NOTE = (
    "† Not resolved in any case: every value lies within 2× the reference's noise floor (4× for the "
    "squared relMSE; within 6.02 dB of the ceiling for PSNR), so it cannot be told apart from the "
    "Monte Carlo noise of the ground truth. The mean may exceed the mean floor: the rule is 2×."
)
AT_BOUND_NOTE = (
    "‡ At a bound of its allowed range: the fit is constrained there, so its standard error is unreliable."
)


# ------------------------------------------------------------------------------------------ numbers
def format_number(x, trim: bool = False) -> str:
    """4 significant digits; scientific (``1.234e-5``) for |x| < 1e-3 or |x| ≥ 1e5.

    Integers print exactly, booleans as yes/no, None as an em dash, strings unchanged. ``trim``
    drops trailing zeros (for inputs such as configuration values: ``5`` rather than ``5.000``).
    """
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    if isinstance(x, float):
        if math.isnan(x):
            return "NaN"
        if math.isinf(x):
            return "∞" if x > 0 else "−∞"
        if x == 0:
            return "0"
        mant, exp = f"{x:.3e}".split("e")
        e = int(exp)
        if e < -3 or e >= 5:
            if trim:
                mant = mant.rstrip("0").rstrip(".")
            return f"{mant}e{e}"
        s = f"{float(mant + 'e' + exp):.{max(0, 3 - e)}f}"
        if trim and "." in s:
            s = s.rstrip("0").rstrip(".")
        return s
    if isinstance(x, (list, tuple)):
        return ", ".join(format_number(v, trim) for v in x)
    if isinstance(x, dict):
        return ", ".join(f"{k} = {format_number(v, trim)}" for k, v in x.items())
    return str(x)


def config_rows(config: dict, prefix: str = "") -> list[tuple[str, object]]:
    """(setting, value) rows of a run's configuration for the Setup table: a non-empty dict value
    (the audit's ``extra``) shows each of its keys as a row of its own, named ``extra.scene``
    (nested dicts likewise: ``extra.timings_s.render``), instead of one cell of flattened
    ``k = v, …`` text."""
    rows: list[tuple[str, object]] = []
    for k, v in config.items():
        if isinstance(v, dict) and v:
            rows += config_rows(v, f"{prefix}{k}.")
        else:
            rows.append((f"{prefix}{k}", v))
    return rows


# ----------------------------------------------------------------------------------- markdown text
# The markdown of results (summary, sections, captions, notes, cost notes) is CommonMark with pipe
# tables, rendered by markdown-it-py. Raw HTML is off (``html=False``): a ``<script>`` in a results
# text is escaped, never passed through. Links keep markdown-it's own check (no ``javascript:``,
# ``vbscript:``, ``file:`` or non-image ``data:`` URLs). One extension of rtfit's own: inline math
# ``$…$`` is left as text in a ``span.math`` (not parsed as emphasis).
_MATH = re.compile(r"\$(?![\s$])[^$\n]*?(?<![\s\\])\$")


def _math_inline(state: StateInline, silent: bool) -> bool:
    if state.src[state.pos] != "$":
        return False
    m = _MATH.match(state.src, state.pos, state.posMax)
    if m is None:
        return False
    if not silent:
        state.push("math_inline", "", 0).content = m.group(0)
    state.pos = m.end()
    return True


def _render_math(self, tokens, idx, options, env) -> str:
    return f'<span class="math">{html.escape(tokens[idx].content, quote=False)}</span>'


def _render_table_open(self, tokens, idx, options, env) -> str:
    return '<div class="table-wrap"><table>\n'


def _render_table_close(self, tokens, idx, options, env) -> str:
    return "</table></div>\n"


_MD = MarkdownIt("commonmark", {"html": False}).enable("table")
_MD.inline.ruler.before("escape", "math", _math_inline)
_MD.add_render_rule("math_inline", _render_math)
_MD.add_render_rule("table_open", _render_table_open)
_MD.add_render_rule("table_close", _render_table_close)

# Plain text that goes into markdown output is backslash-escaped where markdown would read it as markup.
_MD_SPECIAL = re.compile(r"([\\`*_\[\]|<>$~]|&(?=#?\w+;))")


def _esc(text) -> str:
    """Plain text → HTML text (quotes escaped too, for attribute values)."""
    return html.escape(str(text), quote=True)


def _md_text(text) -> str:
    """Plain text for markdown output, on one line: characters markdown would read as markup are
    backslash-escaped (so the text reads the same in report.md and, through markdown-it, in HTML)."""
    return _MD_SPECIAL.sub(r"\\\1", str(text)).replace("\n", " ")


# A "|" that is not already escaped (an even number of backslashes before it): in a pipe table it
# would end the cell.
_TABLE_PIPE = re.compile(r"(?<!\\)((?:\\\\)*)\|")


def markdown_table_cell(text) -> str:
    """Cell text (inline markdown) for a pipe table, on one line: every ``|`` not already escaped
    becomes ``\\|`` (GFM reads it as a literal bar; an unescaped one would end the cell, so
    ``mean |error|`` split one header cell into three). Idempotent, so text escaped by
    :func:`_md_text` is not escaped twice."""
    return _TABLE_PIPE.sub(r"\1\\|", str(text).replace("\n", " "))


def markdown_table(header, rows, numeric=None) -> str:
    """A markdown pipe table: ``header`` (cell texts), ``rows`` (lists of cell texts, inline
    markdown), ``numeric``: per column, right-aligned (None: none). The one place a table's cell
    text is escaped for the table (:func:`markdown_table_cell`)."""
    numeric = list(numeric) if numeric is not None else [False] * len(header)
    lines = ["| " + " | ".join(markdown_table_cell(h) for h in header) + " |"]
    lines.append("|" + "|".join("---:" if n else ":---" for n in numeric) + "|")
    lines += ["| " + " | ".join(markdown_table_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def markdown_inline(text: str) -> str:
    """Inline markdown (CommonMark: emphasis, code, links, autolinks, escapes; ``$math$`` kept as
    text in a ``span.math``) → HTML, no enclosing paragraph. Raw HTML is escaped."""
    return _MD.renderInline(str(text)).rstrip("\n")


def markdown_tokens(text: str) -> list:
    """Block markdown (the dialect of :func:`markdown_to_html`: CommonMark, pipe tables, ``$math$``
    as ``math_inline`` tokens) parsed into markdown-it-py tokens, for renderers to other formats."""
    return _MD.parse(str(text))


def markdown_to_html(text: str, heading_offset: int = 2) -> str:
    """Block markdown (CommonMark with pipe tables) → HTML. ``#`` headings are shifted down by
    ``heading_offset`` levels (at most h6) so they nest under the report's own headings; pipe tables
    come wrapped in ``div.table-wrap`` (scrolls when wide). Raw HTML is escaped."""
    tokens = _MD.parse(str(text))
    for t in tokens:
        if t.type in ("heading_open", "heading_close"):
            t.tag = f"h{min(6, int(t.tag[1:]) + heading_offset)}"
    return _MD.renderer.render(tokens, _MD.options, {}).rstrip("\n")


# ----------------------------------------------------------------------------------------- document
@dataclass
class _Cell:
    text: str = ""
    sub: str = ""  # secondary text (the noise floor), smaller and grey in HTML
    numeric: bool = False
    md: bool = False  # ``text`` is inline markdown
    style: str = ""  # "", "unresolved", "best", "pass", "fail", "at-bound"
    mark: str = ""  # footnote mark
    tag: str = ""  # short qualifier after the value (UNRESOLVED_TAG on a best value that is not resolved)


@dataclass
class _Heading:
    level: int
    title: str
    anchor: str
    number: str = ""


@dataclass
class _Prose:
    md: str


@dataclass
class _Bullets:
    items: list[str]


@dataclass
class _Table:
    anchor: str
    number: int
    caption: str
    header: list[_Cell]
    rows: list[list[_Cell]]
    notes: list[str] = field(default_factory=list)
    tex_cols: list[int] | None = None  # columns in tables.tex (None: all)
    tex: bool = True


@dataclass
class _Figure:
    number: int
    anchor: str
    images: list[tuple[str, str]]  # (relative file, sub-label)
    caption: str  # inline markdown
    missing: list[str] = field(default_factory=list)


def _slug(text: str) -> str:
    s = re.sub(r"[^\w\- ]", "", str(text).lower(), flags=re.UNICODE).strip().replace(" ", "-")
    return s or "x"


class _Doc:
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
        self.blocks.append(_Heading(level, title, a, number))
        return a

    def prose(self, md: str):
        if md and md.strip():
            self.blocks.append(_Prose(md.strip()))

    def table(self, key, caption, header, rows, notes=(), tex_cols=None, tex=True):
        self.tables += 1
        self.blocks.append(
            _Table(
                self.anchor(f"table-{key}"), self.tables, caption, header, rows, list(notes), tex_cols, tex
            )
        )

    def figure(self, images, caption):
        self.figures += 1
        missing = [f for f, _ in images if self.dir is not None and not (self.dir / f).is_file()]
        self.blocks.append(
            _Figure(self.figures, self.anchor(f"figure-{self.figures}"), images, caption, missing)
        )


def _metric_name(key: str) -> str:
    name, lower = METRICS.get(key, (key, None))
    return name + ("" if lower is None else (" ↓" if lower else " ↑"))


def _metric_keys(approximations: list[Approximation]) -> list[str]:
    seen: list[str] = []
    for ap in approximations:
        for k in ap.metrics:
            if k not in seen:
                seen.append(k)
    return [k for k in METRICS if k in seen] + [k for k in seen if k not in METRICS]


def _metric_cell(m: Metric | None) -> _Cell:
    if m is None:
        return _Cell("—", numeric=True)
    cell = _Cell(format_number(m.value), "floor " + format_number(m.noise_floor), numeric=True)
    if m.resolved is False:
        cell.style, cell.mark = "unresolved", "†"
    return cell


def _shown(x: float) -> float:
    """``x`` rounded to the 4 significant digits :func:`format_number` prints."""
    return float(f"{x:.3e}")


def _mark_best(cells: list[_Cell], entries: list[Metric | None], key: str) -> None:
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
    keys = _metric_keys([ap for c in cases for ap in c.approximations])
    return "rmse" if "rmse" in keys else (keys[0] if keys else None)


def _kv_line(pairs, trim: bool = True) -> str:
    """``key = value`` pairs (an iterable of pairs) as one markdown line (keys in code spans)."""
    parts = []
    for k, v in pairs:
        if v is None:
            continue
        if isinstance(v, str) and re.fullmatch(r"[0-9a-f]{24,}", v):
            v = f"`{v[:12]}…`"
        elif not isinstance(v, str):
            v = format_number(v, trim)
        parts.append(f"`{k}` = {v}")
    return ", ".join(parts)


_BUILTIN_TARGETS = {
    "summary": "summary",
    "setup": "setup",
    "results": "results",
    "result": "results",
    "costs": "costs",
    "cost": "costs",
    "fits": "fits",
    "fit": "fits",
    "checks": "checks",
    "check": "checks",
    "notes": "notes",
    "figures": "figures",
}


def _case_figure(d: _Doc, label: str, aps, placed: dict[tuple[str, str], list[Figure]]) -> None:
    """The figure under a case's table: each distinct file of its approximations' ``figures`` once, labelled
    with the approximations that point at it. A file every approximation shares (one composite image of
    the case, `figures.case_comparison`) is shown once with its own figure record's caption, and that record
    is not shown again elsewhere (height-fog's report showed one composite seven times)."""
    groups: dict[str, list[str]] = {}
    for ap in aps:
        for f in ap.figures:
            names = groups.setdefault(str(f), [])
            if ap.display not in names:
                names.append(ap.display)
    if not groups:
        return
    records = {str(fig.file): fig for figs in placed.values() for fig in figs}
    if len(groups) == 1:
        (file,) = groups
        fig = records.get(file)
        own = fig.caption if fig is not None else None
        caption = own or f"{label}: " + ", ".join(groups[file]) + "."
        d.figure([(file, "")], caption)
    else:
        imgs = [(f, ", ".join(names)) for f, names in groups.items()]
        d.figure(imgs, f"{label}: " + "; ".join(lab for _, lab in imgs) + " (left to right).")
    for key in list(placed):  # records of files shown here are not shown a second time
        placed[key] = [fig for fig in placed[key] if str(fig.file) not in groups]
        if not placed[key]:
            del placed[key]


PRECOMPUTE_CAPTION = (
    " Precompute: one whole run of the method's precompute (a bake an engine pays apart from the per-pixel "
    "kernel; the median of up to 3 calls after a warm-up in the same timing loop, the warm-up alone for a "
    "step of a second or more), paid again as *Precompute "
    "paid* says; *per frame* spreads it over the pixels of the case it was timed on, as if it were paid "
    "every frame."
)
"""The cost table's caption where a method has a precompute (`records.Cost.precompute_ms`)."""


def _cost_note(c: Cost) -> str:
    """A cost row's note, and what its precompute does (`records.Cost.precompute_note`)."""
    pre = f"Precompute: {c.precompute_note}." if c.precompute_note else ""
    return " ".join(x for x in (c.note or "", pre) if x)


def _build(r: Results, directory: Path | None) -> _Doc:
    d = _Doc(r, directory)
    cases = r.cases
    user_ids = {s.id for s in r.sections}

    # Figures grouped by where they go: a `sections` id wins over a built-in section name.
    placed: dict[tuple[str, str], list[Figure]] = {}
    for fig in r.figures:
        target = fig.section or "figures"
        key = (
            ("user", target)
            if target in user_ids
            else ("builtin", _BUILTIN_TARGETS.get(target.lower(), "figures"))
        )
        placed.setdefault(key, []).append(fig)

    def emit_figures(key):
        for fig in placed.pop(key, []):
            d.figure([(fig.file, "")], fig.caption or "")

    d.heading(2, "Summary", "summary", numbered=False)
    d.prose(r.summary)
    emit_figures(("builtin", "summary"))

    # Setup.
    d.heading(2, "Setup", "setup")
    cfg = config_rows(r.config)
    if cfg:
        d.table(
            "config",
            "Configuration of this run.",
            [_Cell("Setting"), _Cell("Value")],
            [[_Cell(f"`{k}`", md=True), _Cell(format_number(v, trim=True))] for k, v in cfg],
            tex=False,
        )
    if r.versions:
        d.table(
            "versions",
            "Software versions.",
            [_Cell("Package"), _Cell("Version")],
            [[_Cell(k), _Cell("not installed" if v is None else v)] for k, v in r.versions.items()],
            tex=False,
        )
    d.blocks.append(_Bullets([f"**Device:** {_md_text(r.device)}", f"**Created:** {_md_text(r.created)}"]))
    emit_figures(("builtin", "setup"))

    def emit_user(placement):
        for s in r.sections:
            if (s.placement or "before_results") == placement:
                d.heading(2, s.title, s.id)
                d.prose(s.text)
                emit_figures(("user", s.id))

    emit_user("before_results")

    # Results.
    d.heading(2, "Results", "results")
    if not cases:
        d.prose("No cases were evaluated.")
    head = headline_metric(cases)
    if len(cases) > 1 and head:
        methods: dict[str, str] = {}  # method id -> label of its first appearance
        for c in cases:
            for ap in c.approximations:
                methods.setdefault(ap.method, ap.display)
        rows = []
        for c in cases:
            by = {ap.method: ap for ap in c.approximations}
            entries = [by[m].metrics.get(head) if m in by else None for m in methods]
            cells = [_metric_cell(e) for e in entries]
            _mark_best(cells, entries, head)
            rows.append([_Cell(c.label), *cells])
        d.table(
            "overview",
            f"{METRICS.get(head, (head,))[0]} of every approximation in every case "
            "(value with the reference's noise floor; bold: the best value in the row, resolved or not).",
            [_Cell("Case")] + [_Cell(lab, numeric=True) for lab in methods.values()],
            rows,
            [UNRESOLVED_NOTE] if any(cl.mark for row in rows for cl in row) else [],
        )
    for c in cases:
        d.heading(3, c.label, f"case-{c.id}")
        lines = [f"Case `{c.id}`" + (f": {_kv_line(c.parameters.items())}." if c.parameters else ".")]
        if c.scene is not None and (c.scene.name or c.scene.hash):
            lines.append(
                "Scene "
                + (f"`{c.scene.name}`" if c.scene.name else "")
                + (f" (sha256 `{c.scene.hash[:12]}…`)" if c.scene.hash else "")
                + "."
            )
        if c.reference is not None and any(True for _ in c.reference.items()):
            lines.append(f"Reference: {_kv_line(c.reference.items())}.")
        d.prose(" ".join(lines))
        aps = c.approximations
        if not aps:
            d.prose("No approximations were evaluated in this case.")
            continue
        keys = _metric_keys(aps)
        columns = [[_metric_cell(ap.metrics.get(k)) for ap in aps] for k in keys]
        for k, col in zip(keys, columns, strict=True):
            _mark_best(col, [ap.metrics.get(k) for ap in aps], k)
        has_cost = any(ap.cost is not None and ap.cost.ns_per_pixel is not None for ap in aps)
        header = [_Cell("Method")] + [_Cell(_metric_name(k), numeric=True) for k in keys]
        header += [_Cell("ns/pixel", numeric=True)] if has_cost else []
        header += [_Cell("Parameters")]
        rows = []
        for i, ap in enumerate(aps):
            row = [_Cell(ap.display)] + [col[i] for col in columns]
            if has_cost:
                row.append(_Cell(format_number(ap.cost.ns_per_pixel if ap.cost else None), numeric=True))
            params = format_number(ap.parameters, trim=True) or "—"
            row.append(_Cell(("fitted: " if ap.fitted else "") + params))
            rows.append(row)
        unresolved = any(cl.mark for col in columns for cl in col)
        d.table(
            f"case-{c.id}",
            f"Error metrics for {c.label}: each value with the reference's noise floor "
            "(↓ lower is better, ↑ higher is better; bold: the best value, resolved or not).",
            header,
            rows,
            [UNRESOLVED_NOTE] if unresolved else [],
            tex_cols=list(range(1 + len(keys))),
        )
        _case_figure(d, c.label, aps, placed)
    emit_figures(("builtin", "results"))

    # Cost.
    if r.costs or ("builtin", "costs") in placed:
        d.heading(2, "Cost", "costs")
        if r.costs:
            cols = [
                ("ns_per_pixel", "ns/pixel"),
                ("pixels_per_second", "pixels/s"),
                ("precompute_ms", "Precompute ms"),
                ("precompute_per_pixel", "Precompute ns/pixel per frame"),
                ("precompute_trigger", "Precompute paid"),
                ("backend", "Backend"),
                ("note", "Note"),
            ]
            cols = [(k, n) for k, n in cols if any(getattr(c, k) is not None for c in r.costs)
                    or (k == "note" and any(c.precompute_note for c in r.costs))]  # fmt: skip
            text = ("backend", "note", "precompute_trigger")
            rows = [
                [_Cell(c.display)]
                + [
                    _Cell(_cost_note(c), md=True)
                    if k == "note"
                    else _Cell(format_number(getattr(c, k)), numeric=k not in text)
                    for k, _ in cols
                ]
                for c in r.costs
            ]
            d.table(
                "costs",
                "Measured cost per pixel on this run's device."
                + (PRECOMPUTE_CAPTION if any(c.precompute_trigger for c in r.costs) else ""),
                [_Cell("Method")] + [_Cell(n, numeric=k not in text) for k, n in cols],
                rows,
            )
        emit_figures(("builtin", "costs"))

    # Fits.
    if r.fits or ("builtin", "fits") in placed:
        d.heading(2, "Fitted parameters", "fits")
        if r.fits:
            rows, at_bound, files = [], False, []
            for f in r.fits:
                params: list[tuple[str, FitParameter | None]] = [
                    (name, p if isinstance(p, FitParameter) else FitParameter(value=p))
                    for name, p in f.parameters.items()
                ] or [("—", None)]
                for j, (name, p) in enumerate(params):
                    val = _Cell(format_number(p.value if p else None), numeric=True)
                    if p is not None and p.stderr is not None:
                        val.text += " ± " + format_number(p.stderr)
                    if p is not None and p.at_bound:
                        val.style, val.mark, at_bound = "at-bound", "‡", True
                    bounds = (
                        ""
                        if p is None or (p.lower is None and p.upper is None)
                        else f"[{format_number(p.lower)}, {format_number(p.upper)}]"
                    )
                    first = j == 0
                    conv = f.converged
                    rows.append(
                        [
                            _Cell(f.display if first else "", sub=(f.model or "") if first else ""),
                            _Cell(name),
                            val,
                            _Cell(bounds, numeric=True),
                            _Cell(format_number(f.rms_residual) if first else "", numeric=True),
                            _Cell(format_number(f.n_residuals) if first else "", numeric=True),
                            _Cell(
                                ("yes" if conv else "no") if first and conv is not None else "",
                                style="" if conv or not first or conv is None else "fail",
                            ),
                        ]
                    )
                if f.file:
                    files.append(f"[`{f.file}`]({f.file}) ({f.display})")
            d.table(
                "fits",
                "Fitted parameters (value ± standard error; bounds of the allowed range).",
                [
                    _Cell("Fit"),
                    _Cell("Parameter"),
                    _Cell("Value ± s.e.", numeric=True),
                    _Cell("Bounds", numeric=True),
                    _Cell("RMS residual", numeric=True),
                    _Cell("Residuals", numeric=True),
                    _Cell("Converged"),
                ],
                rows,
                [AT_BOUND_NOTE] if at_bound else [],
            )
            if files:
                d.prose("Fitted-parameter files:")
                d.blocks.append(_Bullets(files))
        emit_figures(("builtin", "fits"))

    # Checks.
    if r.checks or ("builtin", "checks") in placed:
        d.heading(2, "Checks", "checks")
        if r.checks:
            failed = sum(1 for c in r.checks if not c.passed)
            n = len(r.checks)
            d.prose(
                ("The check passed." if n == 1 else f"All {n} checks passed.")
                if not failed
                else f"**{failed} of {n} check{'s' if n != 1 else ''} FAILED.**"
            )
            rows = [
                [
                    _Cell(c.name),
                    _Cell(format_number(c.value), numeric=True),
                    _Cell(format_number(c.expected)),
                    _Cell("pass" if c.passed else "FAIL", style="pass" if c.passed else "fail"),
                ]
                for c in r.checks
            ]
            d.table(
                "checks",
                "Consistency checks of this run.",
                [_Cell("Check"), _Cell("Value", numeric=True), _Cell("Expected"), _Cell("Result")],
                rows,
            )
        emit_figures(("builtin", "checks"))

    emit_user("after_results")

    rest = [f for key in list(placed) if key != ("builtin", "notes") for f in placed.pop(key)]
    if rest:
        d.heading(2, "Figures", "figures")
        for fig in rest:
            d.figure([(fig.file, "")], fig.caption or "")
    if r.notes or placed:
        d.heading(2, "Notes", "notes")
        if r.notes:
            d.blocks.append(_Bullets(list(r.notes)))
        emit_figures(("builtin", "notes"))
    return d


# ----------------------------------------------------------------------------------------- markdown
def _md_cell(c: _Cell) -> str:
    t = c.text if c.md else _md_text(c.text)
    if c.style == "best":
        t = f"**{t}**"
    if c.tag:
        t = f"{t} {_md_text(c.tag)}"
    if c.sub:
        t = f"{t} ({c.sub})"
    if c.style in ("unresolved", "at-bound"):
        t = f"*{t}*"
    if c.style == "fail":
        t = f"**{t}**"
    return t + c.mark


def _heading_text(h: _Heading) -> str:
    return _md_text(f"{h.number} {h.title}" if h.number else h.title)


def _toc(d: _Doc) -> list[tuple[_Heading, list[_Heading]]]:
    """Numbered sections with their subsections (the contents list, placed after the summary)."""
    items: list[tuple[_Heading, list[_Heading]]] = []
    for h in d.blocks:
        if isinstance(h, _Heading) and h.number:
            if h.level == 2 or not items:
                items.append((h, []))
            else:
                items[-1][1].append(h)
    return items


def _render_md(d: _Doc) -> str:
    r = d.r
    out = [
        f"# {_md_text(r.title)}",
        "",
        f"*rtfit experiment `{r.experiment}` · {_md_text(r.created)} · {_md_text(r.device)}*",
        "",
    ]
    toc = ["**Contents**", ""]
    for h, subs in _toc(d):
        toc.append(f"- [{_heading_text(h)}](#{h.anchor})")
        toc += [f"  - [{_heading_text(s)}](#{s.anchor})" for s in subs]
    toc.append("")
    for b in d.blocks:
        if isinstance(b, _Heading):
            if b.number and toc:
                out += toc
                toc = []
            out += [f'<a id="{b.anchor}"></a>', "", f"{'#' * b.level} {_heading_text(b)}", ""]
        elif isinstance(b, _Prose):
            out += [b.md, ""]
        elif isinstance(b, _Bullets):
            out += [f"- {item}" for item in b.items] + [""]
        elif isinstance(b, _Table):
            out += [f'<a id="{b.anchor}"></a>', "", f"**Table {b.number}:** {_md_text(b.caption)}", ""]
            out.append(
                markdown_table(
                    [_md_cell(c) for c in b.header],
                    [[_md_cell(c) for c in row] for row in b.rows],
                    [c.numeric for c in b.header],
                )
            )
            out += [""] + [f"{n}  " for n in b.notes] + ([""] if b.notes else [])
        elif isinstance(b, _Figure):
            out.append(f'<a id="{b.anchor}"></a>')
            out.append("")
            out += [f"![{_md_text(sub or f'Figure {b.number}')}]({f})" for f, sub in b.images]
            missing = f" (missing: {', '.join(b.missing)})" if b.missing else ""
            out += ["", f"**Figure {b.number}:** {b.caption}{missing}", ""]
    out += ["---", "", _footer_text(r), ""]
    return "\n".join(out)


def _footer_text(r: Results) -> str:
    v = r.versions.get("rtfit")
    return (
        f"Generated by rtfit{' ' + str(v) if v else ''} from `results.json` (schema `{SCHEMA}`); "
        "regenerate with `rtfit report DIR`."
    )


# --------------------------------------------------------------------------------------------- html
_CSS = """
:root { --fg: #1d1d1f; --muted: #6e6e73; --rule: #1d1d1f; --light: #d2d2d7; --accent: #0a58ca;
        --pass: #1a7f37; --fail: #cf222e; --bg-alt: #f6f8fa; }
* { box-sizing: border-box; }
body { margin: 0; color: var(--fg); background: #fff;
       font: 17px/1.55 "Charter", "Iowan Old Style", "Source Serif Pro", Georgia, "Times New Roman", serif; }
main { max-width: 62rem; margin: 0 auto; padding: 2.5rem 1.5rem 4rem; }
h1, h2, h3, h4, h5, h6, nav, table, figcaption, .meta, footer {
  font-family: -apple-system, "Segoe UI", "Helvetica Neue", Arial, sans-serif; }
h1 { font-size: 1.9rem; line-height: 1.25; margin: 0 0 .4rem; }
h2 { font-size: 1.35rem; margin: 2.4rem 0 .8rem; padding-bottom: .25rem; border-bottom: 1px solid var(--light); }
h3 { font-size: 1.1rem; margin: 1.8rem 0 .6rem; }
.secnum { color: var(--muted); margin-right: .5rem; }
.meta { color: var(--muted); font-size: .9rem; margin: 0 0 1.5rem; }
.abstract { background: var(--bg-alt); border-left: 3px solid var(--accent); padding: .2rem 1.2rem; }
.abstract h2 { border: 0; margin-top: 1rem; font-size: 1.05rem; text-transform: uppercase; letter-spacing: .05em; }
a { color: var(--accent); text-decoration: none; } a:hover { text-decoration: underline; }
code { font: .85em/1.4 ui-monospace, "SF Mono", Menlo, Consolas, monospace; background: var(--bg-alt);
       padding: .05em .3em; border-radius: 3px; }
pre { background: var(--bg-alt); padding: .8rem 1rem; overflow-x: auto; border-radius: 4px; }
pre code { background: none; padding: 0; }
.math { font-style: italic; white-space: nowrap; }
nav.toc { font-size: .92rem; margin: 1.5rem 0 2rem; }
nav.toc h2 { font-size: 1rem; border: 0; margin: 0 0 .4rem; }
nav.toc ol { list-style: none; padding-left: 0; margin: 0; }
nav.toc ol ol { padding-left: 1.6rem; }
.table-block { margin: 1.2rem 0 1.6rem; }
.table-wrap { overflow-x: auto; max-width: 100%; margin: 1.2rem 0 1.6rem; }
.table-block .table-wrap { margin: 0; }
.table-caption { font-size: .86rem; margin: 0 0 .5rem; }
.table-caption b { margin-right: .3rem; }
table { border-collapse: collapse; font-size: .86rem; margin: 0 auto;
        border-top: 2px solid var(--rule); border-bottom: 2px solid var(--rule); }
th, td { padding: .3rem .65rem; vertical-align: top; text-align: left; }
thead th { border-bottom: 1px solid var(--rule); font-weight: 600; white-space: nowrap; }
tbody tr:hover { background: var(--bg-alt); }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.sub { color: var(--muted); font-size: .88em; }
td.sub-block .sub { display: block; white-space: normal; }
.unresolved { color: #8e8e93; font-style: italic; }
.best { font-weight: 700; }
.tag { font-weight: 400; font-style: italic; color: #8e8e93; font-size: .85em; }
.at-bound { font-style: italic; }
.pass { color: var(--pass); font-weight: 600; }
.fail { color: var(--fail); font-weight: 700; }
.mark { font-size: .8em; vertical-align: super; line-height: 0; }
.table-note { font-size: .8rem; color: var(--muted); margin: .4rem 0 0; }
figure { margin: 1.8rem 0; text-align: center; }
figure .images { display: flex; flex-wrap: wrap; gap: .6rem; justify-content: center; }
figure .images div { flex: 1 1 14rem; max-width: 100%; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--light); }
figcaption { font-size: .88rem; text-align: left; margin: .5rem auto 0; max-width: 48rem; }
figcaption .sublabel { display: block; font-size: .8rem; color: var(--muted); text-align: center; }
.missing { color: var(--fail); }
footer { margin-top: 3rem; padding-top: .8rem; border-top: 1px solid var(--light); color: var(--muted); font-size: .82rem; }
.entry { margin: 0 0 2.2rem; }
.entry h2 { margin-bottom: .3rem; }
.headline { list-style: none; padding: 0; display: flex; flex-wrap: wrap; gap: .4rem 1.2rem;
            font-family: -apple-system, "Segoe UI", "Helvetica Neue", Arial, sans-serif; font-size: .88rem; }
.headline b { font-weight: 600; }
@media print { main { max-width: none; padding: 0; } nav.toc { display: none; } a { color: inherit; } }
"""  # noqa: E501 (CSS rules one per line)


def _html_cell(c: _Cell, tag: str = "td") -> str:
    classes = [
        x for x in ("num" if c.numeric else "", c.style, "sub-block" if c.sub and not c.numeric else "") if x
    ]
    body = markdown_inline(c.text) if c.md else _esc(c.text)
    if c.tag:
        body += f' <span class="tag">{_esc(c.tag)}</span>'
    if c.sub:
        body += (
            f' <span class="sub">({_esc(c.sub)})</span>'
            if c.numeric
            else f'<span class="sub">{_esc(c.sub)}</span>'
        )
    if c.mark:
        body += f'<span class="mark">{_esc(c.mark)}</span>'
    cls = f' class="{" ".join(classes)}"' if classes else ""
    if c.mark == "†":
        cls += ' title="not resolved: within 2× the reference\'s noise floor"'
    return f"<{tag}{cls}>{body}</{tag}>"


def _html_table(b: _Table) -> str:
    head = "".join(_html_cell(c, "th") for c in b.header)
    body = "\n".join("<tr>" + "".join(_html_cell(c) for c in row) + "</tr>" for row in b.rows)
    notes = "".join(f'<p class="table-note">{_esc(n)}</p>' for n in b.notes)
    # The caption and notes sit outside the scrolling box, at the column's width: a wide table scrolls
    # sideways inside `div.table-wrap` without carrying its caption off-screen.
    return (
        f'<div class="table-block" id="{b.anchor}">'
        f'<p class="table-caption"><b>Table {b.number}:</b> {_esc(b.caption)}</p>\n'
        f'<div class="table-wrap" role="region" tabindex="0" aria-label="Table {b.number}"><table>\n'
        f"<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody></table></div>{notes}</div>"
    )


def _html_figure(b: _Figure) -> str:
    imgs = "".join(
        f'<div><img src="{_esc(f)}" alt="{_esc(sub or f"Figure {b.number}")}" loading="lazy">'
        + (f'<span class="sublabel">{_esc(sub)}</span>' if sub and len(b.images) > 1 else "")
        + "</div>"
        for f, sub in b.images
    )
    missing = f' <span class="missing">(missing: {_esc(", ".join(b.missing))})</span>' if b.missing else ""
    return (
        f'<figure id="{b.anchor}"><div class="images">{imgs}</div>'
        f"<figcaption><b>Figure {b.number}:</b> {markdown_inline(b.caption)}{missing}</figcaption></figure>"
    )


def _html_page(title: str, body: str) -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{_esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n<main>\n{body}\n</main>\n"
        "</body>\n</html>\n"
    )


def _render_html(d: _Doc) -> str:
    r = d.r
    parts = [
        f"<header><h1>{_esc(r.title)}</h1>",
        f'<p class="meta">rtfit experiment <code>{_esc(r.experiment)}</code> · {_esc(r.created)} · '
        f"{_esc(r.device)}</p></header>",
    ]

    def link(h):
        return f'<a href="#{h.anchor}"><span class="secnum">{_esc(h.number)}</span>{_esc(h.title)}</a>'

    toc = (
        '<nav class="toc"><h2>Contents</h2><ol>'
        + "".join(
            f"<li>{link(h)}"
            + (f"<ol>{''.join(f'<li>{link(s)}</li>' for s in subs)}</ol>" if subs else "")
            + "</li>"
            for h, subs in _toc(d)
        )
        + "</ol></nav>"
    )
    in_abstract = False
    for b in d.blocks:
        if isinstance(b, _Heading):
            if in_abstract:
                parts.append("</section>")
                in_abstract = False
            if b.number and toc:
                parts.append(toc)
                toc = ""
            num = f'<span class="secnum">{_esc(b.number)}</span>' if b.number else ""
            h = f'<h{b.level} id="{b.anchor}">{num}{_esc(b.title)}</h{b.level}>'
            if b.anchor == "summary":
                parts.append('<section class="abstract">' + h)
                in_abstract = True
            else:
                parts.append(h)
        elif isinstance(b, _Prose):
            parts.append(markdown_to_html(b.md, heading_offset=3))
        elif isinstance(b, _Bullets):
            parts.append("<ul>" + "".join(f"<li>{markdown_inline(i)}</li>" for i in b.items) + "</ul>")
        elif isinstance(b, _Table):
            parts.append(_html_table(b))
        elif isinstance(b, _Figure):
            parts.append(_html_figure(b))
    if in_abstract:
        parts.append("</section>")
    parts.append(f"<footer>{markdown_inline(_footer_text(r))}</footer>")
    return _html_page(r.title, "\n".join(parts))


# ------------------------------------------------------------------------------------------- public
def render_report(results: Results | Mapping, directory=None) -> dict[str, str]:
    """Render results to ``{"report.md": …, "report.html": …, "tables.tex": …}``.

    ``results``: a :class:`~.records.Results`, or the document as parsed JSON (validated here:
    :class:`ResultsError`). ``directory`` (optional) is where figure files are looked up to flag missing
    ones.
    """
    if not isinstance(results, Results):
        results = from_json(Results, plain_json(results), "<results>")
    d = _build(results, Path(directory) if directory is not None else None)
    tables = [b for b in d.blocks if isinstance(b, _Table) and b.tex]
    return {
        "report.md": _render_md(d),
        "report.html": _render_html(d),
        "tables.tex": latex.render_tables(results.experiment, tables),
    }


def report_tables(results: Results | Mapping, directory=None) -> list:
    """The tables of ``tables.tex`` (the report's table model, readable by
    :func:`rtfit.experiments.latex.render_table`), in report order. Their ``anchor`` names them:
    ``table-overview``, ``table-case-CASEID``, ``table-costs``, ``table-fits``, ``table-checks``."""
    if not isinstance(results, Results):
        results = from_json(Results, plain_json(results), "<results>")
    d = _build(results, Path(directory) if directory is not None else None)
    return [b for b in d.blocks if isinstance(b, _Table) and b.tex]


def write_report(directory, single_file: bool = False) -> list[Path]:
    """Write ``report.md``, ``report.html`` and ``tables.tex`` into ``directory`` from its
    ``results.json``, with the image viewer of its ``pixels/`` (:mod:`.viewer`); ``single_file``: also
    ``report.single.html``, everything embedded. The report is rendered before anything is written, so
    an invalid results file (:class:`ResultsError`) leaves the directory as it was. Returns the written
    paths."""
    directory = Path(directory)
    results = load_results(directory)
    texts = render_report(results, directory)
    extra = viewer.write_viewer(directory, results, texts, single_file=single_file)  # adds to report.html
    return [atomic_write_text(directory / name, texts[name]) for name in REPORT_FILES] + extra


def missing_figures(directory) -> list[str]:
    """The figure files ``directory/results.json`` names (its figures and each approximation's) that are
    not files under ``directory``, each once in the order named: the report marks them "(missing: …)";
    ``rtfit report`` also says so in one warning line (issue 32: a deleted ``figures/`` went unsaid)."""
    directory = Path(directory)
    results = load_results(directory)
    named = [f.file for f in results.figures]
    named += [f for c in results.cases for ap in c.approximations for f in ap.figures]
    return [f for f in dict.fromkeys(named) if not (directory / f).is_file()]


def _first_paragraph(md: str) -> str:
    return re.split(r"\n\s*\n", md.strip(), maxsplit=1)[0]


def _index_entry(results: Results) -> tuple[list[tuple[str, str, bool]], list[tuple[str, str, str]]]:
    """Headline facts ``(label, value, is_bad)`` and per-method rows ``(method, mean metric, ns/pixel)``."""
    cases = results.cases
    facts = [
        (h.label or "", format_number(h.value) + (f" {h.unit}" if h.unit else ""), False)
        for h in results.headline
    ]
    methods: list[str] = []
    for c in cases:
        for ap in c.approximations:
            if ap.method not in methods:
                methods.append(ap.method)
    facts.append(("cases", f"{len(cases)} × {len(methods)} approximations", False))
    checks = results.checks
    if checks:
        ok = sum(1 for c in checks if c.passed)
        facts.append(
            (
                "checks",
                f"{ok}/{len(checks)} passed" + ("" if ok == len(checks) else " — FAILURES"),
                ok != len(checks),
            )
        )
    fits = results.fits
    if fits:
        bad = sum(1 for f in fits if f.converged is False)
        facts.append(
            ("fits", f"{len(fits)} ({'all converged' if not bad else f'{bad} not converged'})", bad > 0)
        )
    head = headline_metric(cases)
    rows = []
    if head:
        # Cost rows (``costs``) are keyed by what was timed, which need not be an approximation's id;
        # the approximations carry their own measured cost (``attach_costs``): that is what is shown.
        # A row of ``costs`` under the approximation's own id stands in where none carries one.
        cost_rows = {c.method: c.ns_per_pixel for c in results.costs}
        for m in methods:
            vals, floors, ns, unresolved, label = [], [], [], 0, m
            for c in cases:
                for ap in c.approximations:
                    if ap.method != m:
                        continue
                    if ap.cost is not None and ap.cost.ns_per_pixel is not None:
                        ns.append(ap.cost.ns_per_pixel)
                    e = ap.metrics.get(head)
                    if e is not None and e.value is not None:
                        label = ap.display
                        vals.append(e.value)
                        unresolved += e.resolved is False
                        if e.noise_floor is not None:
                            floors.append(e.noise_floor)
            if vals:
                mean = format_number(sum(vals) / len(vals))
                if floors:
                    mean += f" (floor {format_number(sum(floors) / len(floors))})"
                if unresolved == len(vals):
                    mean += f" {INDEX_UNRESOLVED_MARK}"
                cost = sum(ns) / len(ns) if ns else cost_rows.get(m)
                rows.append((label, mean, format_number(cost)))
    return facts, rows


def write_index(out_dir, experiment_dirs) -> list[Path]:
    """Write ``OUT/index.html`` and ``OUT/index.md``: one entry per experiment directory, linking
    its report, with its first summary paragraph and headline numbers (cases, checks, fits, and
    the mean headline metric per approximation). A directory whose results cannot be read is
    listed with the error; temporary directories of :mod:`.atomic` are skipped. Returns the paths."""
    out_dir = Path(out_dir)
    entries, any_unresolved = [], False
    for d in experiment_dirs:
        d = Path(d)
        if is_temporary_name(d.name):
            continue
        link = os.path.relpath(d / "report.html", out_dir).replace(os.sep, "/")
        try:
            entries.append((d, link, load_results(d), None))
        except ResultsError as e:
            entries.append((d, link, None, str(e)))
    md = ["# rtfit results", "", f"{len(entries)} experiment{'s' if len(entries) != 1 else ''}.", ""]
    body = [
        "<header><h1>rtfit results</h1>",
        f'<p class="meta">{len(entries)} experiment{"s" if len(entries) != 1 else ""}.</p></header>',
    ]
    for d, link, r, err in entries:
        if r is None:
            md += [f"## {d.name}", "", f"**Cannot read results:** {err}", ""]
            body.append(
                f'<section class="entry"><h2>{_esc(d.name)}</h2><p class="fail">Cannot read results: '
                f"{_esc(err)}</p></section>"
            )
            continue
        facts, rows = _index_entry(r)
        summary = _first_paragraph(r.summary)
        meta = f"`{r.experiment}` · {_md_text(r.created)} · {_md_text(r.device)}"
        md += [f"## [{_md_text(r.title)}]({link})", "", f"*{meta}*", "", summary, ""]
        md += ["  ·  ".join(f"**{k}:** {v}" for k, v, _ in facts), ""]
        any_unresolved |= any(b.endswith(INDEX_UNRESOLVED_MARK) for _, b, _ in rows)
        head = headline_metric(r.cases)
        hname = METRICS.get(head, (head,))[0] if head else ""
        if rows:
            md += [f"| Approximation | mean {hname} over cases | ns/pixel |", "|:---|---:|---:|"]
            md += [f"| {_md_text(a)} | {b} | {c} |" for a, b, c in rows] + [""]
        html_rows = "".join(
            f'<tr><td>{_esc(a)}</td><td class="num">{_esc(b)}</td><td class="num">{_esc(c)}</td></tr>'
            for a, b, c in rows
        )
        table = (
            (
                f'<div class="table-wrap"><table><thead><tr><th>Approximation</th><th class="num">mean '
                f'{_esc(hname)} over cases</th><th class="num">ns/pixel</th></tr></thead><tbody>{html_rows}'
                "</tbody></table></div>"
            )
            if rows
            else ""
        )
        fact_html = "".join(
            f"<li><b>{_esc(k)}:</b> " + (f'<span class="fail">{_esc(v)}</span>' if bad else _esc(v)) + "</li>"
            for k, v, bad in facts
        )
        body.append(
            f'<section class="entry"><h2><a href="{_esc(link)}">{_esc(r.title)}</a></h2>'
            f'<p class="meta">{markdown_inline(meta)}</p>{markdown_to_html(summary)}'
            f'<ul class="headline">{fact_html}</ul>{table}</section>'
        )
    if any_unresolved:
        md += [INDEX_UNRESOLVED_NOTE, ""]
        body.append(f'<p class="table-note">{_esc(INDEX_UNRESOLVED_NOTE)}</p>')
    body.append(
        f"<footer>Generated by rtfit from each experiment's <code>results.json</code> "
        f"(schema <code>{SCHEMA}</code>).</footer>"
    )
    md += ["---", "", f"Generated by rtfit from each experiment's `results.json` (schema `{SCHEMA}`).", ""]
    return [
        atomic_write_text(out_dir / "index.html", _html_page("rtfit results", "\n".join(body))),
        atomic_write_text(out_dir / "index.md", "\n".join(md)),
    ]
