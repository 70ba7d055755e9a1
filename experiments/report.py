"""Reports from ``results.json``: ``report.md``, ``report.html``, ``tables.tex`` (this module: the page
assembly and the public entry points), and a suite index (:mod:`.report_index`).

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
markdown-it-py (:mod:`.report_text`) with raw HTML escaped.

The rooms: :mod:`.report_text` (numbers, the markdown dialect, escapes), :mod:`.report_doc` (the
document model and metric cells), :mod:`.report_sections` (the tables of results, cost, fits and
checks), :mod:`.report_writers` (markdown and HTML), :mod:`.report_index` (the suite index),
:mod:`.viewer` (the image viewer at the end of ``report.html``), :mod:`.latex` (``tables.tex``).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from . import latex, viewer
from .atomic import atomic_write_text
from .records import SCHEMA, Figure, Results, ResultsError, from_json, plain_json
from .report_doc import Bullets, Cell, ReportDoc, TableBlock, headline_metric
from .report_sections import (
    add_case,
    add_checks_table,
    add_cost_table,
    add_fits_table,
    add_overview_table,
)
from .report_text import config_rows, format_number, markdown_escape
from .report_writers import render_html, render_markdown
from .results import load_results

__all__ = [
    "SCHEMA",
    "ResultsError",
    "load_results",
    "missing_figures",
    "render_report",
    "report_tables",
    "write_report",
]

REPORT_FILES = ("report.md", "report.html", "tables.tex")


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


def _build(r: Results, directory: Path | None) -> ReportDoc:
    """The report of ``r`` as a :class:`~.report_doc.ReportDoc`: its sections in order, each figure record
    placed in the section it names (see the module's docstring for the layout)."""
    d = ReportDoc(r, directory)
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
            [Cell("Setting"), Cell("Value")],
            [[Cell(f"`{k}`", md=True), Cell(format_number(v, trim=True))] for k, v in cfg],
            tex=False,
        )
    if r.versions:
        d.table(
            "versions",
            "Software versions.",
            [Cell("Package"), Cell("Version")],
            [[Cell(k), Cell("not installed" if v is None else v)] for k, v in r.versions.items()],
            tex=False,
        )
    d.blocks.append(
        Bullets([f"**Device:** {markdown_escape(r.device)}", f"**Created:** {markdown_escape(r.created)}"])
    )
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
        add_overview_table(d, cases, head)
    for c in cases:
        add_case(d, c, placed)
    emit_figures(("builtin", "results"))

    # Cost, Fitted parameters, Checks: each where the run has its records or a figure placed in it.
    for key, title, has_records, add_table in (
        ("costs", "Cost", bool(r.costs), lambda: add_cost_table(d, r.costs)),
        ("fits", "Fitted parameters", bool(r.fits), lambda: add_fits_table(d, r.fits)),
        ("checks", "Checks", bool(r.checks), lambda: add_checks_table(d, r.checks)),
    ):
        if has_records or ("builtin", key) in placed:
            d.heading(2, title, key)
            if has_records:
                add_table()
            emit_figures(("builtin", key))

    emit_user("after_results")

    rest = [f for key in list(placed) if key != ("builtin", "notes") for f in placed.pop(key)]
    if rest:
        d.heading(2, "Figures", "figures")
        for fig in rest:
            d.figure([(fig.file, "")], fig.caption or "")
    if r.notes or placed:
        d.heading(2, "Notes", "notes")
        if r.notes:
            d.blocks.append(Bullets(list(r.notes)))
        emit_figures(("builtin", "notes"))
    return d


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
    tables = [b for b in d.blocks if isinstance(b, TableBlock) and b.tex]
    return {
        "report.md": render_markdown(d),
        "report.html": render_html(d),
        "tables.tex": latex.render_tables(results.experiment, tables),
    }


def report_tables(results: Results | Mapping, directory=None) -> list:
    """The tables of ``tables.tex`` (the report's table model, readable by
    :func:`rtfit.experiments.latex.render_table`), in report order. Their ``anchor`` names them:
    ``table-overview``, ``table-case-CASEID``, ``table-costs``, ``table-fits``, ``table-checks``."""
    if not isinstance(results, Results):
        results = from_json(Results, plain_json(results), "<results>")
    d = _build(results, Path(directory) if directory is not None else None)
    return [b for b in d.blocks if isinstance(b, TableBlock) and b.tex]


def write_report(directory, single_file: bool = False, results: Results | None = None) -> list[Path]:
    """Write ``report.md``, ``report.html`` and ``tables.tex`` into ``directory`` from its
    ``results.json``, with the image viewer of its ``pixels/`` (:mod:`.viewer`); ``single_file``: also
    ``report.single.html``, everything embedded. The report is rendered before anything is written, so
    an invalid results file (:class:`ResultsError`) leaves the directory as it was. Returns the written
    paths.

    ``results``: the validated record the caller has just written there (`write_results`), rendered as it
    is instead of reading the file back (the same record: a record's JSON reads back equal to it, tested;
    issue 33: reading and validating it again was 1.1 s of a quick suite's 28 reports)."""
    directory = Path(directory)
    results = load_results(directory) if results is None else results
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
