"""The report's tables of results: the overview of the headline metric over the cases, per case its
parameters, metric table and figure, and the tables of the Cost, Fitted parameters and Checks sections.

Each ``add_…`` function appends its blocks to a :class:`~.report_doc.ReportDoc`; the page assembly
(:mod:`.report`) decides where the sections go and places the figures around them.
"""

from __future__ import annotations

import re

from .records import Case, Check, Cost, Figure, Fit, FitParameter
from .report_doc import (
    METRICS,
    UNRESOLVED_NOTE,
    Bullets,
    Cell,
    ReportDoc,
    mark_best,
    metric_cell,
    metric_keys,
    metric_name,
)
from .report_text import format_number

__all__ = [
    "AT_BOUND_NOTE",
    "PRECOMPUTE_CAPTION",
    "SUBSAMPLE_NOTE",
    "add_case",
    "add_checks_table",
    "add_cost_table",
    "add_fits_table",
    "add_overview_table",
]


AT_BOUND_NOTE = (
    "‡ At a bound of its allowed range: the fit is constrained there, so its standard error is unreliable."
)
SUBSAMPLE_NOTE = (
    "Started on n of N pixels: a large case's fit is first made on a deterministic stratified subsample of "
    "its pixels, then polished on all of them from the subsample's values (no scan); its values, residuals "
    "and standard errors are the full data's."
)


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


def _case_figure(d: ReportDoc, label: str, aps, placed: dict[tuple[str, str], list[Figure]]) -> None:
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


def add_overview_table(d: ReportDoc, cases: list[Case], head: str) -> None:
    """The overview: the headline metric ``head`` of every approximation (columns) in every case (rows),
    the best of each row in bold."""
    methods: dict[str, str] = {}  # method id -> label of its first appearance
    for c in cases:
        for ap in c.approximations:
            methods.setdefault(ap.method, ap.display)
    rows = []
    for c in cases:
        by = {ap.method: ap for ap in c.approximations}
        entries = [by[m].metrics.get(head) if m in by else None for m in methods]
        cells = [metric_cell(e) for e in entries]
        mark_best(cells, entries, head)
        rows.append([Cell(c.label), *cells])
    d.table(
        "overview",
        f"{METRICS.get(head, (head,))[0]} of every approximation in every case "
        "(value with the reference's noise floor; bold: the best value in the row, resolved or not).",
        [Cell("Case")] + [Cell(lab, numeric=True) for lab in methods.values()],
        rows,
        [UNRESOLVED_NOTE] if any(cl.mark for row in rows for cl in row) else [],
    )


def add_case(d: ReportDoc, c: Case, placed: dict[tuple[str, str], list[Figure]]) -> None:
    """One case's subsection: its parameters, scene and reference in a sentence, its metric table (every
    value beside its noise floor, the best of each metric in bold; cost and parameters) and its figure
    (:func:`_case_figure`, which takes the records of the files it shows out of ``placed``)."""
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
        return
    keys = metric_keys(aps)
    columns = [[metric_cell(ap.metrics.get(k)) for ap in aps] for k in keys]
    for k, col in zip(keys, columns, strict=True):
        mark_best(col, [ap.metrics.get(k) for ap in aps], k)
    has_cost = any(ap.cost is not None and ap.cost.ns_per_pixel is not None for ap in aps)
    header = [Cell("Method")] + [Cell(metric_name(k), numeric=True) for k in keys]
    header += [Cell("ns/pixel", numeric=True)] if has_cost else []
    header += [Cell("Parameters")]
    rows = []
    for i, ap in enumerate(aps):
        row = [Cell(ap.display)] + [col[i] for col in columns]
        if has_cost:
            row.append(Cell(format_number(ap.cost.ns_per_pixel if ap.cost else None), numeric=True))
        params = format_number(ap.parameters, trim=True) or "—"
        row.append(Cell(("fitted: " if ap.fitted else "") + params))
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


def add_cost_table(d: ReportDoc, costs: list[Cost]) -> None:
    """The Cost section's table: one row per timed method, the columns that any row fills."""
    cols = [
        ("ns_per_pixel", "ns/pixel"),
        ("pixels_per_second", "pixels/s"),
        ("precompute_ms", "Precompute ms"),
        ("precompute_per_pixel", "Precompute ns/pixel per frame"),
        ("precompute_trigger", "Precompute paid"),
        ("backend", "Backend"),
        ("note", "Note"),
    ]
    cols = [(k, n) for k, n in cols if any(getattr(c, k) is not None for c in costs)
            or (k == "note" and any(c.precompute_note for c in costs))]  # fmt: skip
    text = ("backend", "note", "precompute_trigger")
    rows = [
        [Cell(c.display)]
        + [
            Cell(_cost_note(c), md=True)
            if k == "note"
            else Cell(format_number(getattr(c, k)), numeric=k not in text)
            for k, _ in cols
        ]
        for c in costs
    ]
    d.table(
        "costs",
        "Measured cost per pixel on this run's device."
        + (PRECOMPUTE_CAPTION if any(c.precompute_trigger for c in costs) else ""),
        [Cell("Method")] + [Cell(n, numeric=k not in text) for k, n in cols],
        rows,
    )


def add_fits_table(d: ReportDoc, fits: list[Fit]) -> None:
    """The Fitted parameters section's table (one row per parameter; ‡ at a bound) and the list of the
    fitted-parameter files."""
    rows, at_bound, files = [], False, []
    for f in fits:
        params: list[tuple[str, FitParameter | None]] = [
            (name, p if isinstance(p, FitParameter) else FitParameter(value=p))
            for name, p in f.parameters.items()
        ] or [("—", None)]
        for j, (name, p) in enumerate(params):
            val = Cell(format_number(p.value if p else None), numeric=True)
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
                    Cell(f.display if first else "", sub=(f.model or "") if first else ""),
                    Cell(name),
                    val,
                    Cell(bounds, numeric=True),
                    Cell(format_number(f.rms_residual) if first else "", numeric=True),
                    Cell(
                        format_number(f.n_residuals) if first else "",
                        sub=f"started on {f.fitted_on}" if first and f.fitted_on else "",
                        numeric=True,
                    ),
                    Cell(
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
            Cell("Fit"),
            Cell("Parameter"),
            Cell("Value ± s.e.", numeric=True),
            Cell("Bounds", numeric=True),
            Cell("RMS residual", numeric=True),
            Cell("Residuals", numeric=True),
            Cell("Converged"),
        ],
        rows,
        ([AT_BOUND_NOTE] if at_bound else []) + ([SUBSAMPLE_NOTE] if any(f.fitted_on for f in fits) else []),
    )
    if files:
        d.prose("Fitted-parameter files:")
        d.blocks.append(Bullets(files))


def add_checks_table(d: ReportDoc, checks: list[Check]) -> None:
    """The Checks section: a sentence (all passed, or how many FAILED) and the table of the checks."""
    failed = sum(1 for c in checks if not c.passed)
    n = len(checks)
    d.prose(
        ("The check passed." if n == 1 else f"All {n} checks passed.")
        if not failed
        else f"**{failed} of {n} check{'s' if n != 1 else ''} FAILED.**"
    )
    rows = [
        [
            Cell(c.name),
            Cell(format_number(c.value), numeric=True),
            Cell(format_number(c.expected)),
            Cell("pass" if c.passed else "FAIL", style="pass" if c.passed else "fail"),
        ]
        for c in checks
    ]
    d.table(
        "checks",
        "Consistency checks of this run.",
        [Cell("Check"), Cell("Value", numeric=True), Cell("Expected"), Cell("Result")],
        rows,
    )
