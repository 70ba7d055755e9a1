"""The audit book: one LaTeX document over a whole run, ``OUT/book.tex`` (and ``OUT/book.pdf``).

``rtfit report OUT/`` over a run directory (one sub-directory per experiment, each with its
``results.json``) writes, besides each experiment's report and the suite index:

- ``OUT/book.tex``: one ``article`` document, pure ASCII, needing only :data:`PREAMBLE` (booktabs,
  array, longtable, graphicx: ``texlive-latex-base`` and ``-recommended``);
- ``OUT/book-figures/``: the figures the book draws itself, as PDF (vector): the cross-family summary
  (``summary.pdf``) and one error-vs-cost Pareto plot per family (``pareto-EXPERIMENT.pdf``);
- ``OUT/book.pdf`` (and ``OUT/book.log``) when ``pdflatex`` is on the ``PATH``.

Everything comes from the typed ``results.json`` records (:mod:`.records`) and the figure files they
name, never from a rerun. Layout: title, contents, a table of the runs, then

1. **Summary across families**: every approximation's *normalised* error against its measured cost on
   one plot and in one table (:func:`normalised_error` states the normalisation);
2. per family, one section: summary; method (the family's ``method`` section and the table of its
   approximations); error and cost (mean error over cases with noise floors, the Pareto figure, the
   per-case overview table); measured cost; fitted parameters (the report's table, with the
   fitted-parameter files); the family's other sections with their figures; the remaining figures;
   checks; the per-case metric tables; notes.

Tables are those of ``tables.tex`` (:func:`.report.report_tables`, laid out by
:func:`.latex.render_table`) plus the book's own, all set as ``longtable`` (not floats: a family may hold
dozens, and floats are limited to 18 pending); figures are ``figure`` floats with relative paths, each
at most the text width wide and 42 % of the text height tall. The markdown of summaries, sections and
captions (CommonMark with pipe tables, parsed by :func:`.report.markdown_tokens`) is rendered by
:func:`tex_markdown_blocks`: paragraphs, lists, headings as ``\\paragraph``, code blocks in the
largest of three sizes that keeps their lines whole (wrapped only beyond that), pipe tables through
the table layout, so that nothing runs into the margin. ``docs/book.md`` is the user's page.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from . import latex
from .atomic import atomic_write_bytes, atomic_write_text
from .figures import pareto_plot, pyplot, save_figure
from .latex import TexCell, TexTable, render_table, tex_label, tex_text
from .records import Approximation, Figure, Results, ResultsError
from .report import METRICS, format_number, headline_metric, markdown_tokens, report_tables
from .results import load_results

__all__ = [
    "BOOK_FIGURES",
    "PREAMBLE",
    "SETUP",
    "BookResult",
    "FamilyPoint",
    "compile_book",
    "family_points",
    "normalised_error",
    "render_book",
    "tex_markdown_blocks",
    "write_book",
]

PREAMBLE = latex.PREAMBLE + "\\usepackage{graphicx}\n"
"""The whole preamble ``book.tex`` needs (``tables.tex``'s plus graphicx for the figures)."""
SETUP = r"\emergencystretch=3em"
"""What ``book.tex`` sets after the preamble: room for TeX to break prose lines that hold long code
spans or formulas (rather than run a line into the margin)."""
BOOK_FIGURE_WIDTH = r"0.85\linewidth"
"""Width of the figures the book draws (summary, Pareto plots), so that one fits beside text on a page."""
BOOK_FIGURES = "book-figures"
"""The folder (beside ``book.tex``) of the figures the book draws itself."""
FIGURE_FORMATS = (".pdf", ".png", ".jpg", ".jpeg")
"""Figure files pdflatex includes; others (EXR, SVG) are named in the text instead."""
_SAFE_PATH = re.compile(r"[A-Za-z0-9_./+-]+")
FLOATS_PER_FLUSH = 12
"""After this many figures without a page flush the book emits ``\\clearpage`` (LaTeX holds at most
18 unplaced floats)."""
PDFLATEX_PASSES = 3
"""At most this many pdflatex passes: until the contents and references settle ("Rerun" not in the log)."""
PDFLATEX_TIMEOUT_S = 300.0
"""Bound on one pdflatex pass."""
PDFLATEX_MISSING = "pdflatex not found (apt-get install texlive-latex-base texlive-latex-recommended)"


# ------------------------------------------------------------------------------ normalised error
def normalised_error(ap: Approximation) -> tuple[float, float | None, bool | None, str] | None:
    """The error of one approximation in one case made comparable across families, as
    ``(value, noise floor, resolved, kind)``, or None where the case holds no such metric.

    ``kind`` ``"peak"``: the RMSE relative to the peak of the reference over the compared pixels,
    ``RMSE / peak = 10^(−PSNR/20)``, read from the PSNR that rtfit measures beside the RMSE
    (``PSNR = 10·log10(peak² / mean d²)``, ``rtfit.fitting.metrics``); its floor is
    ``10^(−ceiling/20)`` with the PSNR's noise ceiling, and it is resolved exactly when the PSNR is
    (the same test as the RMSE's). ``kind`` ``"rms"``: a family without PSNR that reports ``rel_rmse``
    = RMSE / RMS of the reference (irradiance-bases) gives that; since RMS ≤ peak it is an upper bound
    of RMSE / peak. Both are dimensionless, so one light's irradiance error and a sky's radiance error
    sit on one axis.
    """
    m = ap.metrics.get("psnr")
    if m is not None and m.value is not None:
        floor = None if m.noise_floor is None else 10.0 ** (-m.noise_floor / 20.0)
        return 10.0 ** (-m.value / 20.0), floor, m.resolved, "peak"
    m = ap.metrics.get("rel_rmse")
    if m is not None and m.value is not None:
        return m.value, m.noise_floor, m.resolved, "rms"
    return None


@dataclass(frozen=True)
class FamilyPoint:
    """One approximation of one family over the cases it was evaluated in.

    ``error``/``floor``: means over those cases of the family's headline metric ``metric`` and its
    noise floor; ``resolved``: in how many of the ``cases`` the error is resolved (above the noise);
    ``ns_per_pixel``: mean measured cost (None: not timed); ``norm``/``norm_floor``/``norm_kind``/
    ``norm_resolved``: the same for :func:`normalised_error` (None where the family has none)."""

    experiment: str
    method: str
    label: str
    metric: str
    cases: int
    error: float | None
    floor: float | None
    resolved: int
    ns_per_pixel: float | None
    norm: float | None
    norm_floor: float | None
    norm_kind: str | None
    norm_resolved: int
    precompute_ns: float | None = None
    """Its precompute's share per pixel if paid every frame (`records.PixelCost.precompute_per_pixel`, mean
    over the cases; None: no precompute timed)."""
    precompute_trigger: str | None = None


def _mean(xs: list[float]) -> float | None:
    return sum(xs) / len(xs) if xs else None


def family_points(r: Results) -> list[FamilyPoint]:
    """Every approximation of ``r`` aggregated over its cases (see :class:`FamilyPoint`), in order of
    first appearance. Cost: the approximation's own measured cost, else the ``costs`` row under its id."""
    head = headline_metric(r.cases)
    order: dict[str, list[Approximation]] = {}
    for c in r.cases:
        for ap in c.approximations:
            order.setdefault(ap.method, []).append(ap)
    cost_rows = {c.method: c.ns_per_pixel for c in r.costs}
    out = []
    for method, aps in order.items():
        errs, floors, resolved, ns = [], [], 0, []
        timed = [ap.cost for ap in aps if ap.cost and ap.cost.precompute_per_pixel]
        pre = [c.precompute_per_pixel for c in timed if c.precompute_per_pixel]
        trig = timed[0].precompute_trigger if timed else None
        norms, nfloors, nres, kinds = [], [], 0, set()
        for ap in aps:
            m = ap.metrics.get(head) if head else None
            if m is not None and m.value is not None:
                errs.append(m.value)
                resolved += m.resolved is not False
                if m.noise_floor is not None:
                    floors.append(m.noise_floor)
            if ap.cost is not None and ap.cost.ns_per_pixel is not None:
                ns.append(ap.cost.ns_per_pixel)
            ne = normalised_error(ap)
            if ne is not None:
                norms.append(ne[0])
                if ne[1] is not None:
                    nfloors.append(ne[1])
                nres += ne[2] is not False
                kinds.add(ne[3])
        out.append(
            FamilyPoint(
                experiment=r.experiment,
                method=method,
                label=next((ap.display for ap in aps if ap.label), method),
                metric=head or "",
                cases=len(aps),
                error=_mean(errs),
                floor=_mean(floors) if len(floors) == len(errs) else None,
                resolved=resolved,
                ns_per_pixel=_mean(ns) if ns else cost_rows.get(method),
                norm=_mean(norms) if len(norms) == len(aps) else None,
                norm_floor=_mean(nfloors) if norms and len(nfloors) == len(norms) else None,
                norm_kind=kinds.pop() if len(kinds) == 1 and len(norms) == len(aps) else None,
                norm_resolved=nres,
                precompute_ns=_mean(pre),
                precompute_trigger=trig,
            )
        )
    return out


# ---------------------------------------------------------------------------------------- figures
_FAMILY_STYLE = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")


def summary_plot(path, families: Sequence[tuple[str, list[FamilyPoint]]]) -> Path:
    """The cross-family figure: normalised error (log) against ns/pixel (log), one colour and marker
    per family, each point numbered as in the summary table; open markers: not resolved in any case."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    colours = [plt.get_cmap("tab10")(i) for i in range(10)]
    k = 0
    for f, (name, pts) in enumerate(families):
        colour, marker = colours[f % len(colours)], _FAMILY_STYLE[f % len(_FAMILY_STYLE)]
        shown = False
        for p in pts:
            if not _plotted(p):
                continue
            k += 1
            assert p.norm is not None and p.ns_per_pixel is not None
            filled = p.norm_resolved > 0
            ax.scatter(
                [p.ns_per_pixel],
                [p.norm],
                s=30,
                marker=marker,
                facecolors=colour if filled else "none",
                edgecolors=colour,
                label=None if shown else name + (" (RMSE/RMS*)" if p.norm_kind == "rms" else ""),
                zorder=3,
            )
            shown = True
            ax.annotate(
                str(k), (p.ns_per_pixel, p.norm), textcoords="offset points", xytext=(3, 3), fontsize=6
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("cost (ns per pixel, measured on the run's device)")
    ax.set_ylabel("normalised error: RMSE / reference peak")
    ax.grid(alpha=0.3, which="both", lw=0.5)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return save_figure(fig, path)


PRECOMPUTE_PLOT_NOTE = (
    " A method with a precompute (a bake an engine pays apart from its per-pixel kernel) is drawn twice: "
    "its kernel alone, and (open marker, joined) its kernel plus the precompute spread over the case's "
    "pixels as if paid every frame (an upper bound where it is paid per light or scene change); the "
    "Pareto front is over the kernels alone."
)
"""The error-vs-cost caption's words on precomputes (`figures.pareto_plot`'s ``x_pre``)."""


def _pareto_point(p: FamilyPoint) -> dict:
    """A `pareto_plot` point: cost, error, id; ``x_pre``: the cost with the precompute paid every frame."""
    point = {"x": p.ns_per_pixel, "y": p.error, "label": p.method}
    if p.precompute_ns and p.ns_per_pixel:
        point["x_pre"] = p.ns_per_pixel + p.precompute_ns
    return point


def _plotted(p: FamilyPoint) -> bool:
    return p.norm is not None and p.norm > 0 and p.ns_per_pixel is not None and p.ns_per_pixel > 0


def _pareto_points(pts: list[FamilyPoint]) -> list[FamilyPoint]:
    return [p for p in pts if p.error is not None and p.error > 0 and p.ns_per_pixel and p.ns_per_pixel > 0]


# --------------------------------------------------------------------------------------- markdown
def _code_inline(text: str) -> str:
    """A code span: typewriter, breakable after / _ . , = - when longer than 16 characters."""
    out = []
    for ch in text:
        out.append(tex_text(ch))
        if len(text) > 16 and ch in "/_.,=-":
            out.append(r"\allowbreak{}")
    return r"\texttt{" + "".join(out) + "}"


def _inline(tokens) -> str:
    """markdown-it inline children → LaTeX."""
    out = []
    for t in tokens or ():
        if t.type == "text":
            out.append(tex_text(t.content))
        elif t.type == "code_inline":
            out.append(_code_inline(t.content))
        elif t.type == "math_inline":
            out.append(r"\textit{" + tex_text(t.content.strip("$")) + "}")
        elif t.type == "softbreak":
            out.append("\n")
        elif t.type == "hardbreak":
            out.append("\\\\\n")
        elif t.type == "strong_open":
            out.append(r"\textbf{")
        elif t.type == "em_open":
            out.append(r"\emph{")
        elif t.type in ("strong_close", "em_close"):
            out.append("}")
        elif t.type == "image":
            out.append(tex_text(t.content or "[image]"))
        elif t.type in ("link_open", "link_close"):
            continue  # a link prints its text
        else:
            out.append(tex_text(t.content))
    return "".join(out)


# Code sizes and the advance of one typewriter character in each (pt), measured with pdflatex (cmtt8
# scaled: 0.531 em).
_CODE_SIZES = ((r"\footnotesize", 4.25), (r"\scriptsize", 3.719), (r"\tiny", 2.657))


def _code_columns(line: str) -> int:
    """Typewriter columns of ``line``: a non-ASCII character is set from a math font (± is 2.0, → 2.6
    columns wide at \\tiny, measured) and counted as 3."""
    return sum(1 if ch.isascii() else 3 for ch in line)


def _code_block(text: str) -> list[str]:
    r"""A code block in typewriter, its lines kept whole (and so its columns aligned) by the largest of
    \footnotesize, \scriptsize, \tiny in which the longest fits the text width; lines longer than
    that even in \tiny are wrapped (continuations indented by two spaces). Spaces are kept and never
    break."""
    raw = text.rstrip("\n").expandtabs(4).split("\n")
    longest = max((_code_columns(line) for line in raw), default=0)
    size, char = next(
        ((s, w) for s, w in _CODE_SIZES if longest * w <= latex.TEXT_WIDTH_PT - 2.0), _CODE_SIZES[-1]
    )
    columns = int((latex.TEXT_WIDTH_PT - 2.0) / char)
    lines = []
    for line in raw:
        first = True
        while first or line:
            cut, k, limit = "", 0, columns if first else columns - 2
            while k < len(line) and _code_columns(cut + line[k]) <= limit:
                cut, k = cut + line[k], k + 1
            k = max(k, 1) if line else 0
            cut, line = line[:k], line[k:]
            body = "~".join(tex_text(w) for w in (cut if first else "  " + cut).split(" "))
            first = False
            lines.append(r"\texttt{" + body + "}" if body.strip("~") else r"\mbox{}")
    return [f"\\par\\smallskip{{{size}\\noindent", "\\\\\n".join(lines) + "\\par}\\smallskip", ""]


_NUMBER_CELL = re.compile(r"(?:[\s\d.,:;eE+\-−–×%()±~≈<>≤≥x/—]|nan|inf|NaN|∞)*")


def _md_table(tokens, i: int, experiment: str, key: str) -> tuple[list[str], int]:
    """A pipe table starting at token ``i`` (``table_open``) as a longtable; returns (lines, next i)."""
    rows: list[list[tuple[str, bool]]] = []
    cur: list[tuple[str, bool]] = []
    right = False
    while tokens[i].type != "table_close":
        t = tokens[i]
        if t.type in ("th_open", "td_open"):
            right = "right" in str(t.attrGet("style") or "")
        elif t.type == "inline":
            cur.append((t.content, right))
        elif t.type == "tr_close":
            rows.append(cur)
            cur = []
        i += 1
    if not rows:
        return [], i + 1
    n = max(len(r) for r in rows)
    rows = [r + [("", False)] * (n - len(r)) for r in rows]
    # A column of plain numbers (any alignment) is set as numbers: right-aligned, never wrapped, at
    # its natural width, leaving the rest of the line to the text columns. Any other column is text.
    numeric = [
        len(rows) > 1 and all(_NUMBER_CELL.fullmatch(r[j][0].strip()) for r in rows[1:]) for j in range(n)
    ]
    header = [TexCell(text, numeric=numeric[j], md=not numeric[j]) for j, (text, _) in enumerate(rows[0])]
    body = [
        [TexCell(text, numeric=numeric[j], md=not numeric[j]) for j, (text, _) in enumerate(r)]
        for r in rows[1:]
    ]
    tex = render_table(experiment, TexTable(f"table-{key}", "", header, body), longtable=True)
    return [tex, ""], i + 1


def tex_markdown_blocks(text: str, experiment: str = "md", key: str = "md") -> str:
    """Block markdown (summaries, sections: CommonMark with pipe tables) as LaTeX: paragraphs,
    ``\\paragraph`` headings, itemize/enumerate lists, quotes, code blocks (:func:`_code_block`),
    pipe tables as longtables laid out to fit the text width (``experiment``/``key`` name their
    labels), horizontal rules. Inline: code spans in typewriter (breakable), strong, emphasis,
    ``$math$`` in italics, links as their text."""
    tokens = markdown_tokens(text)
    out: list[str] = []
    i, n, tables = 0, len(tokens), 0
    while i < n:
        t = tokens[i]
        if t.type == "inline":
            out.append(_inline(t.children))
        elif t.type == "paragraph_close" and not t.hidden:
            out.append("\n\n")
        elif t.type == "heading_open":
            out.append(r"\paragraph{" + _inline(tokens[i + 1].children) + "}\n")
            i += 2
        elif t.type == "bullet_list_open":
            out.append("\\begin{itemize}\n")
        elif t.type == "bullet_list_close":
            out.append("\\end{itemize}\n")
        elif t.type == "ordered_list_open":
            start = int(t.attrGet("start") or 1)
            out.append(
                "\\begin{enumerate}\n" + (f"\\setcounter{{enumi}}{{{start - 1}}}\n" if start != 1 else "")
            )
        elif t.type == "ordered_list_close":
            out.append("\\end{enumerate}\n")
        elif t.type == "list_item_open":
            out.append("\\item ")
        elif t.type == "list_item_close":
            out.append("\n")
        elif t.type == "blockquote_open":
            out.append("\\begin{quote}\n")
        elif t.type == "blockquote_close":
            out.append("\\end{quote}\n")
        elif t.type in ("fence", "code_block"):
            out.append("\n".join(_code_block(t.content)))
        elif t.type == "hr":
            out.append("\\par\\noindent\\rule{\\linewidth}{0.4pt}\\par\n")
        elif t.type == "table_open":
            tables += 1
            lines, i = _md_table(tokens, i, experiment, f"{key}-{tables}")
            out.append("\n".join(lines) + "\n")
            continue
        i += 1
    return "".join(out).strip() + "\n"


# ----------------------------------------------------------------------------------------- layout
def _cell(x, numeric: bool = True, **kw) -> TexCell:
    return TexCell(format_number(x) if not isinstance(x, str) else x, numeric=numeric, **kw)


def _figure(path: str, caption_tex: str, label: str, width: str = r"\linewidth") -> list[str]:
    return [
        r"\begin{figure}[htbp]",
        r"  \centering",
        rf"  \includegraphics[width={width},height=0.42\textheight,keepaspectratio]{{{path}}}",
        rf"  \caption{{{caption_tex}}}",
        rf"  \label{{fig:{label}}}",
        r"\end{figure}",
        "",
    ]


class _Family:
    """One family's section: collects LaTeX lines and counts figures (for :data:`FLOATS_PER_FLUSH`)."""

    def __init__(self, rel: str, r: Results, out_dir: Path, pareto: str | None):
        self.rel, self.r, self.out_dir, self.pareto = rel, r, out_dir, pareto
        self.lines: list[str] = []
        self.pending = 0
        self.nfig = 0
        self.done: set[str] = set()

    def figure(self, file: str, caption_md: str) -> None:
        """Place the experiment's figure ``file`` (relative to its directory), once."""
        if file in self.done:
            return
        self.done.add(file)
        path = f"{self.rel}/{file}"
        caption = _inline_md(caption_md) if caption_md else tex_text(file)
        if not (self.out_dir / path).is_file():
            self.lines += [rf"\par\noindent\textit{{Figure file {_code_inline(path)} is missing.}}\par", ""]
            return
        if Path(file).suffix.lower() not in FIGURE_FORMATS or not _SAFE_PATH.fullmatch(path):
            self.lines += [
                rf"\par\noindent\textit{{Figure {_code_inline(path)} (not included: {caption})}}\par",
                "",
            ]
            return
        self.nfig += 1
        self.lines += _figure(path, caption, tex_label(self.r.experiment, f"fig{self.nfig}"))
        self.pending += 1
        if self.pending >= FLOATS_PER_FLUSH:
            self.lines += [r"\clearpage", ""]
            self.pending = 0


def _when(created: str) -> str:
    """An ISO 8601 time as ``2026-12-01 22:32 UTC`` (anything else unchanged)."""
    m = re.fullmatch(r"(\d{4}-\d\d-\d\d)T(\d\d:\d\d)(?::[\d.]+)?(Z|[+-]00:?00)?", created.strip())
    if m is None:
        return created
    return f"{m.group(1)} {m.group(2)}" + (" UTC" if m.group(3) else "")


def _inline_md(md: str) -> str:
    """Inline markdown (captions) as LaTeX, on one paragraph."""
    return tex_markdown_blocks(md).strip().replace("\n\n", " ")


def _approximations_table(r: Results, pts: list[FamilyPoint]) -> TexTable:
    params: dict[str, str] = {}
    fitted: dict[str, bool] = {}
    for c in r.cases:
        for ap in c.approximations:
            fitted[ap.method] = fitted.get(ap.method, False) or ap.fitted
            if ap.parameters and ap.method not in params:
                params[ap.method] = format_number(dict(ap.parameters), trim=True)
    rows = [
        [
            TexCell(p.label),
            TexCell(f"`{p.method}`", md=True),
            TexCell(
                ("fitted" if fitted.get(p.method) else "fixed")
                if params.get(p.method) or fitted.get(p.method)
                else "—"
            ),
            TexCell(str(p.cases), numeric=True),
        ]
        for p in pts
    ]
    return TexTable(
        "table-approximations",
        "The approximations compared (parameters: fitted to the reference or fixed; cases: how many "
        "cases each was evaluated in).",
        [TexCell("Approximation"), TexCell("Id"), TexCell("Parameters"), TexCell("Cases", numeric=True)],
        rows,
    )


def _error_cost_table(r: Results, pts: list[FamilyPoint]) -> TexTable:
    head = pts[0].metric if pts else ""
    name = METRICS.get(head, (head,))[0]
    rows = []
    for p in pts:
        err = _cell(p.error, sub="" if p.floor is None else "floor " + format_number(p.floor))
        if p.error is not None and p.resolved == 0:
            err.style, err.mark = "unresolved", "†"
        rows.append(
            [
                TexCell(p.label),
                err,
                TexCell(f"{p.resolved}/{p.cases}", numeric=True),
                _cell(p.ns_per_pixel),
            ]
        )
    notes = ["† Not resolved in any case: within 2× the reference's noise floor (rtfit.fitting.metrics)."]
    return TexTable(
        "table-error-cost",
        f"Mean {name} over the cases each approximation was evaluated in, with the mean noise floor of "
        "the reference; cases in which the error is resolved (above the noise); measured cost.",
        [
            TexCell("Approximation"),
            TexCell(f"mean {name}", numeric=True),
            TexCell("Resolved", numeric=True),
            TexCell("ns/pixel", numeric=True),
        ],
        rows,
        notes if any(row[1].mark for row in rows) else [],
    )


def _family_section(fam: _Family) -> list[str]:
    r = fam.r
    exp = r.experiment
    pts = family_points(r)
    tables = {t.anchor.removeprefix("table-"): t for t in report_tables(r, fam.out_dir / fam.rel)}
    L = fam.lines
    where = "" if fam.rel == exp else f" in {_code_inline(fam.rel + '/')}"
    L += [
        rf"\section{{{tex_text(r.title)}}}",
        rf"\label{{sec:{tex_label(exp)}}}",
        rf"{{\raggedright\noindent\textit{{Experiment {_code_inline(exp)}{where}; "
        rf"{tex_text(_when(r.created))}; {tex_text(r.device)}.}}\par}}\medskip",
        "",
        tex_markdown_blocks(r.summary, exp, "summary"),
    ]
    sections = {s.id: s for s in r.sections}
    by_section: dict[str, list[Figure]] = {}
    for f in r.figures:
        by_section.setdefault(f.section or "figures", []).append(f)

    def user_section(sid: str) -> None:
        s = sections[sid]
        L.append(tex_markdown_blocks(s.text, exp, f"section-{sid}"))
        for f in by_section.pop(sid, []):
            fam.figure(f.file, f.caption or "")

    # Method.
    L += [r"\subsection{Method}", ""]
    method_ids = [s.id for s in r.sections if s.id.lower() in ("method", "methods")]
    for sid in method_ids:
        user_section(sid)
    L += [render_table(exp, _approximations_table(r, pts), longtable=True), ""]
    if r.fits:
        models = [(f.display, f.model) for f in r.fits if f.model]
        seen: set[str] = set()
        items = []
        for lab, model in models:
            if model in seen:
                continue
            seen.add(model)
            items.append(rf"\item {tex_text(lab)}: {tex_text(model)}")
        if items:
            L += ["Fitted forms:", r"\begin{itemize}", *items, r"\end{itemize}", ""]

    # Error and cost.
    L += [r"\subsection{Error and cost}", ""]
    L += [render_table(exp, _error_cost_table(r, pts), longtable=True), ""]
    if fam.pareto is not None:
        head = pts[0].metric if pts else ""
        name = tex_text(METRICS.get(head, (head,))[0])
        caption = (
            f"Error against cost for {tex_text(exp)}: mean {name} over the cases "
            "(log scale) against the measured ns/pixel; dashed: the Pareto front (no approximation is both "
            "cheaper and more accurate); dotted: the mean noise floor of the reference. Labels are the "
            f"approximations' ids (Table~\\ref{{tab:{tex_label(exp, 'error-cost')}}}); approximations "
            "without a measured cost are not drawn. Drawn by the book from results.json."
            + (PRECOMPUTE_PLOT_NOTE if any(p.precompute_ns for p in pts) else "")
        )
        fam.lines += _figure(fam.pareto, caption, tex_label(exp, "pareto"), BOOK_FIGURE_WIDTH)
        fam.pending += 1
    if "overview" in tables:
        L += [render_table(exp, tables.pop("overview"), longtable=True), ""]

    # Cost.
    if "costs" in tables:
        L += [r"\subsection{Measured cost}", "", render_table(exp, tables.pop("costs"), longtable=True), ""]
        for f in by_section.pop("costs", []) + by_section.pop("cost", []):
            fam.figure(f.file, f.caption or "")

    # Fitted parameters.
    if "fits" in tables:
        L += [
            r"\subsection{Fitted parameters}",
            "",
            render_table(exp, tables.pop("fits"), longtable=True),
            "",
        ]
        files = sorted({f.file for f in r.fits if f.file})
        if files:
            L += [
                "Fitted-parameter files (format \\texttt{rtfit.fitted/1}, with GLSL and HLSL functions):",
                r"{\raggedright\begin{itemize}",
                *(r"\item " + _code_inline(f"{fam.rel}/{f}") for f in files),
                r"\end{itemize}}",
                "",
            ]
        for f in by_section.pop("fits", []) + by_section.pop("fit", []):
            fam.figure(f.file, f.caption or "")

    # The family's other sections.
    for s in r.sections:
        if s.id in method_ids:
            continue
        L += [rf"\subsection{{{tex_text(s.title)}}}", ""]
        user_section(s.id)

    # Remaining figures (results, figures, …; per-case images not listed among them).
    rest = [f for key in list(by_section) if key not in ("checks", "notes") for f in by_section.pop(key)]
    case_images = [(f, c.label) for c in r.cases for ap in c.approximations for f in ap.figures]
    if rest or any(f not in fam.done for f, _ in case_images):
        L += [r"\subsection{Figures}", ""]
        for f in rest:
            fam.figure(f.file, f.caption or "")
        for f, label in case_images:
            fam.figure(f, f"{label}.")

    # Checks.
    if r.checks:
        failed = [c for c in r.checks if not c.passed]
        L += [r"\subsection{Checks}", ""]
        L.append(
            (
                f"All {len(r.checks)} self-checks of the run passed."
                if not failed
                else rf"\textbf{{{len(failed)} of {len(r.checks)} self-checks FAILED.}}"
            )
            + " Table below lists them."
            + "\n"
        )
        if "checks" in tables:
            L += [render_table(exp, tables.pop("checks"), longtable=True), ""]
        for f in by_section.pop("checks", []):
            fam.figure(f.file, f.caption or "")

    # Per-case metric tables.
    cases = [k for k in tables if k.startswith("case-")]
    if cases:
        L += [r"\subsection{Per-case metrics}", ""]
        for k in cases:
            L += [render_table(exp, tables.pop(k), longtable=True), ""]

    if r.notes or by_section.get("notes"):
        L += [r"\subsection{Notes}", ""]
        if r.notes:
            L += [r"\begin{itemize}", *(r"\item " + _inline_md(n) for n in r.notes), r"\end{itemize}", ""]
        for f in by_section.pop("notes", []):
            fam.figure(f.file, f.caption or "")
    L += [r"\clearpage", ""]
    return L


def _summary_section(entries: list[tuple[str, Results]], summary_fig: str | None) -> list[str]:
    families = [(r.experiment, family_points(r)) for _, r in entries]
    devices = sorted({r.device for _, r in entries})
    L = [
        r"\section{Summary across families}",
        r"\label{sec:summary}",
        "",
        "Every approximation of every family, its error against its measured cost. The error is made "
        "comparable across families by normalising it: the \\emph{normalised error} is the RMSE relative "
        "to the peak of the reference over the compared pixels, "
        r"$\mathrm{RMSE}/\mathrm{peak} = 10^{-\mathrm{PSNR}/20}$, read from the PSNR that rtfit measures "
        "beside every RMSE (so a light's irradiance, an occlusion factor and a sky's radiance share one "
        "dimensionless axis). Its noise floor is the same transform of the PSNR's noise ceiling. A family "
        "without PSNR that reports the relative RMSE (RMSE over the RMS of the reference, marked *) gives "
        "that instead: the RMS is at most the peak, so it is an upper bound of RMSE/peak. Values are means "
        "over the cases each approximation was evaluated in; cost is the mean measured ns per pixel on "
        + (
            "the run's device (" + tex_text(devices[0]) + ")."
            if len(devices) == 1
            else "each experiment's device (they differ: " + tex_text("; ".join(devices)) + ")."
        )
        + " Open markers: not resolved (within 2$\\times$ the noise floor) in any case.",
        "",
    ]
    if summary_fig is not None:
        L += _figure(
            summary_fig,
            "Normalised error (RMSE/peak of the reference) against measured cost for every approximation "
            "of every family; numbers refer to Table~\\ref{tab:book:summary}. Drawn by the book from "
            "results.json.",
            "book:summary",
            BOOK_FIGURE_WIDTH,
        )
    rows, k, left = [], 0, []
    for name, pts in families:
        first = True
        for p in pts:
            if not _plotted(p):
                left.append(f"{p.label} ({name})")
                continue
            k += 1
            cell = _cell(p.norm, sub="" if p.norm_floor is None else "floor " + format_number(p.norm_floor))
            if p.norm_resolved == 0:
                cell.style, cell.mark = "unresolved", "†"
            if p.norm_kind == "rms":
                cell.mark += "*"
            rows.append(
                [
                    TexCell(str(k), numeric=True),
                    TexCell(name if first else ""),  # the family on its first row only
                    TexCell(p.label),
                    cell,
                    TexCell(f"{p.norm_resolved}/{p.cases}", numeric=True),
                    _cell(p.ns_per_pixel),
                ]
            )
            first = False
    notes = [
        "† Not resolved in any case (within 2× the reference's noise floor).",
        "* RMSE / RMS of the reference (the family reports no PSNR): an upper bound of RMSE / peak.",
    ]
    table = TexTable(
        "table-summary",
        "Normalised error (mean RMSE/peak over the cases, with the mean noise floor) and measured cost "
        "of every approximation.",
        [
            TexCell("#", numeric=True),
            TexCell("Family"),
            TexCell("Approximation"),
            TexCell("RMSE/peak", numeric=True),
            TexCell("Resolved", numeric=True),
            TexCell("ns/pixel", numeric=True),
        ],
        rows,
        notes,
    )
    L += [render_table("book", table, longtable=True), ""]
    if left:
        L += [
            "Not on the plot (no normalised error or no measured cost): " + tex_text("; ".join(left)) + ".",
            "",
        ]
    L += [r"\clearpage", ""]
    return L


def render_book(
    out_dir, entries: Sequence[tuple[str, Results]], figures: dict[str, str] | None = None
) -> str:
    """``book.tex`` for the experiments ``entries`` (``(directory relative to out_dir, results)``).

    ``figures``: the book's own figure files (relative to ``out_dir``): key ``"summary"`` and
    ``"pareto:EXPERIMENT"``; a missing key leaves that figure out."""
    out_dir = Path(out_dir)
    figures = figures or {}
    entries = list(entries)
    versions = next((r.versions.get("rtfit") for _, r in entries if r.versions.get("rtfit")), None)
    L = [
        "% book.tex - generated by rtfit report from each experiment's results.json; do not edit.",
        "% Needs only the preamble below (docs/book.md); figures are PDF/PNG files at relative paths.",
        PREAMBLE.rstrip("\n"),
        SETUP,
        r"\begin{document}",
        r"\title{rtfit audit book}",
        rf"\author{{rtfit{(' ' + tex_text(versions)) if versions else ''}}}",
        rf"\date{{{len(entries)} experiment{'s' if len(entries) != 1 else ''}}}",
        r"\maketitle",
        r"\tableofcontents",
        "",
    ]
    devices = sorted({r.device for _, r in entries})
    one_device = len(devices) == 1
    runs = TexTable(
        "table-runs",
        "The experiments in this book" + (f" (device: {devices[0]})." if one_device else "."),
        [
            TexCell("Experiment"),
            TexCell("Created"),
            TexCell("Cases", numeric=True),
            TexCell("Checks"),
            TexCell("Device"),
        ],
        [
            [
                TexCell(f"`{r.experiment}`", md=True),
                TexCell(_when(r.created)),
                TexCell(str(len(r.cases)), numeric=True),
                TexCell(
                    f"{sum(c.passed for c in r.checks)}/{len(r.checks)} passed" if r.checks else "—",
                    style="" if all(c.passed for c in r.checks) else "fail",
                ),
                TexCell(r.device),
            ]
            for _, r in entries
        ],
        tex_cols=[0, 1, 2, 3] if one_device else None,
    )
    L += [render_table("book", runs, longtable=True), "", r"\clearpage", ""]
    L += _summary_section(entries, figures.get("summary"))
    for rel, r in entries:
        fam = _Family(rel, r, out_dir, figures.get(f"pareto:{r.experiment}"))
        L += _family_section(fam)
    L += [r"\end{document}", ""]
    return "\n".join(L)


# ------------------------------------------------------------------------------------------ write
@dataclass(frozen=True)
class BookResult:
    """What :func:`write_book` wrote: ``tex`` (book.tex), ``figures``, ``pdf`` (None: not built),
    ``error`` (why the PDF was not built: pdflatex missing or failed; None when it was), ``pdflatex``
    (whether pdflatex was run: an error then is a failed compile)."""

    tex: Path
    figures: list[Path]
    pdf: Path | None
    error: str | None
    pdflatex: bool = False


def _draw_figures(out_dir: Path, entries: list[tuple[str, Results]]) -> tuple[dict[str, str], list[Path]]:
    figs: dict[str, str] = {}
    written: list[Path] = []
    fam_points = [(r.experiment, family_points(r)) for _, r in entries]
    if any(_plotted(p) for _, pts in fam_points for p in pts):
        rel = f"{BOOK_FIGURES}/summary.pdf"
        written.append(summary_plot(out_dir / rel, fam_points))
        figs["summary"] = rel
    for name, pts in fam_points:
        pp = _pareto_points(pts)
        if len(pp) < 2:
            continue
        head = pp[0].metric
        floors = [p.floor for p in pp if p.floor is not None]
        rel = f"{BOOK_FIGURES}/pareto-{name}.pdf"
        written.append(
            pareto_plot(
                out_dir / rel,
                [_pareto_point(p) for p in pp],
                "cost (ns per pixel)",
                f"mean {METRICS.get(head, (head,))[0]} over cases",
                title=name,
                floor=sum(floors) / len(floors) if floors else None,
            )
        )
        figs[f"pareto:{name}"] = rel
    return figs, written


def compile_book(out_dir, tex_name: str = "book.tex") -> tuple[Path | None, str | None]:
    """Compile ``out_dir/tex_name`` with pdflatex (until contents and references settle, at most
    :data:`PDFLATEX_PASSES` passes) in a
    temporary directory; write ``book.pdf`` and ``book.log`` into ``out_dir`` atomically. Returns
    ``(pdf, None)``, or ``(None, reason)`` where pdflatex is missing or fails (its first error line)."""
    out_dir = Path(out_dir)
    exe = shutil.which("pdflatex")
    if exe is None:
        return None, PDFLATEX_MISSING
    stem = Path(tex_name).stem
    with tempfile.TemporaryDirectory(prefix="rtfit-book-") as tmp:
        for _ in range(PDFLATEX_PASSES):
            try:
                run = subprocess.run(
                    [
                        exe,
                        "-interaction=nonstopmode",
                        "-halt-on-error",
                        "-no-shell-escape",
                        f"-output-directory={tmp}",
                        tex_name,
                    ],
                    cwd=out_dir,
                    capture_output=True,
                    timeout=PDFLATEX_TIMEOUT_S,
                    check=False,
                )
            except subprocess.TimeoutExpired:
                return None, f"pdflatex ran past {PDFLATEX_TIMEOUT_S:g} s"
            log_path = Path(tmp) / f"{stem}.log"
            log = log_path.read_text(encoding="latin-1") if log_path.is_file() else ""
            if log:
                atomic_write_text(out_dir / f"{stem}.log", log)
            if run.returncode != 0:
                errors = [line for line in log.splitlines() if line.startswith("!")]
                return None, "pdflatex failed: " + (errors[0] if errors else f"exit status {run.returncode}")
            if "Rerun to get" not in log and "Rerun LaTeX" not in log:
                break
        pdf = Path(tmp) / f"{stem}.pdf"
        return atomic_write_bytes(out_dir / f"{stem}.pdf", pdf.read_bytes()), None


def write_book(out_dir, experiment_dirs, pdf: bool = True) -> BookResult:
    """Write ``out_dir/book.tex`` and the book's figures for the experiment directories
    ``experiment_dirs`` (those whose results cannot be read are left out), and ``book.pdf`` when
    ``pdf`` and pdflatex is present. Everything is rendered before ``book.tex`` is written."""
    out_dir = Path(out_dir)
    entries: list[tuple[str, Results]] = []
    for d in experiment_dirs:
        d = Path(d)
        try:
            entries.append((os.path.relpath(d, out_dir).replace(os.sep, "/"), load_results(d)))
        except ResultsError:
            continue
    figs, written = _draw_figures(out_dir, entries)
    tex = render_book(out_dir, entries, figs)
    path = atomic_write_text(out_dir / "book.tex", tex)
    if not pdf:
        return BookResult(path, written, None, "not requested")
    if shutil.which("pdflatex") is None:
        return BookResult(path, written, None, PDFLATEX_MISSING)
    built, error = compile_book(out_dir)
    return BookResult(path, written, built, error, pdflatex=True)
