"""The book's pages: per family one section (:func:`family_section`: summary; method; error and cost with
the Pareto figure; measured cost; fitted parameters; the family's other sections with their figures; the
remaining figures; checks; the per-case metric tables; notes) and the summary across families
(:func:`summary_section`), as lists of LaTeX lines for :func:`.book.render_book`.

Tables are those of ``tables.tex`` (:func:`.report.report_tables`, laid out by
:func:`.latex.render_table`) plus the book's own, all set as ``longtable`` (not floats: a family may hold
dozens, and floats are limited to 18 pending); figures are ``figure`` floats with relative paths, each at
most the text width wide and 42 % of the text height tall.
"""

from __future__ import annotations

import re
from pathlib import Path

from .book_markdown import code_inline, inline_markdown, tex_markdown_blocks
from .book_plots import PRECOMPUTE_PLOT_NOTE, FamilyPoint, family_points, is_plotted
from .latex import TexCell, TexTable, render_table, tex_label, tex_text
from .records import Figure, Results
from .report import report_tables
from .report_doc import METRICS
from .report_text import format_number

__all__ = [
    "BOOK_FIGURE_WIDTH",
    "FIGURE_FORMATS",
    "FLOATS_PER_FLUSH",
    "family_section",
    "format_when",
    "summary_section",
]

BOOK_FIGURE_WIDTH = r"0.85\linewidth"
"""Width of the figures the book draws (summary, Pareto plots), so that one fits beside text on a page."""
FIGURE_FORMATS = (".pdf", ".png", ".jpg", ".jpeg")
"""Figure files pdflatex includes; others (EXR, SVG) are named in the text instead."""
_SAFE_PATH = re.compile(r"[A-Za-z0-9_./+-]+")
FLOATS_PER_FLUSH = 12
"""After this many figures without a page flush the book emits ``\\clearpage`` (LaTeX holds at most
18 unplaced floats)."""


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
        caption = inline_markdown(caption_md) if caption_md else tex_text(file)
        if not (self.out_dir / path).is_file():
            self.lines += [rf"\par\noindent\textit{{Figure file {code_inline(path)} is missing.}}\par", ""]
            return
        if Path(file).suffix.lower() not in FIGURE_FORMATS or not _SAFE_PATH.fullmatch(path):
            self.lines += [
                rf"\par\noindent\textit{{Figure {code_inline(path)} (not included: {caption})}}\par",
                "",
            ]
            return
        self.nfig += 1
        self.lines += _figure(path, caption, tex_label(self.r.experiment, f"fig{self.nfig}"))
        self.pending += 1
        if self.pending >= FLOATS_PER_FLUSH:
            self.lines += [r"\clearpage", ""]
            self.pending = 0


def format_when(created: str) -> str:
    """An ISO 8601 time as ``2026-12-01 22:32 UTC`` (anything else unchanged)."""
    m = re.fullmatch(r"(\d{4}-\d\d-\d\d)T(\d\d:\d\d)(?::[\d.]+)?(Z|[+-]00:?00)?", created.strip())
    if m is None:
        return created
    return f"{m.group(1)} {m.group(2)}" + (" UTC" if m.group(3) else "")


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


def family_section(rel: str, r: Results, out_dir: Path, pareto: str | None) -> list[str]:
    """The LaTeX lines of one family's section: the experiment ``r`` stored in ``out_dir/rel``;
    ``pareto``: its Pareto figure (relative to ``out_dir``; None: none drawn)."""
    fam = _Family(rel, r, out_dir, pareto)
    exp = r.experiment
    pts = family_points(r)
    tables = {t.anchor.removeprefix("table-"): t for t in report_tables(r, fam.out_dir / fam.rel)}
    L = fam.lines
    where = "" if fam.rel == exp else f" in {code_inline(fam.rel + '/')}"
    L += [
        rf"\section{{{tex_text(r.title)}}}",
        rf"\label{{sec:{tex_label(exp)}}}",
        rf"{{\raggedright\noindent\textit{{Experiment {code_inline(exp)}{where}; "
        rf"{tex_text(format_when(r.created))}; {tex_text(r.device)}.}}\par}}\medskip",
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
                *(r"\item " + code_inline(f"{fam.rel}/{f}") for f in files),
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
            L += [
                r"\begin{itemize}",
                *(r"\item " + inline_markdown(n) for n in r.notes),
                r"\end{itemize}",
                "",
            ]
        for f in by_section.pop("notes", []):
            fam.figure(f.file, f.caption or "")
    L += [r"\clearpage", ""]
    return L


def summary_section(entries: list[tuple[str, Results]], summary_fig: str | None) -> list[str]:
    """The LaTeX lines of the summary across families: the normalised error of every approximation against
    its measured cost, as the figure ``summary_fig`` (None: not drawn) and a table."""
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
            if not is_plotted(p):
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
