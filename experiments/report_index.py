"""The suite index: ``OUT/index.html`` and ``OUT/index.md`` over the experiment directories of a run
(:func:`write_index`), one entry per experiment linking its report, with its first summary paragraph, its
headline facts (cases, checks, fits) and the mean headline metric and cost per approximation.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .atomic import atomic_write_text, is_temporary_name
from .records import SCHEMA, Results, ResultsError
from .report_doc import METRICS, headline_metric
from .report_text import format_number, html_escape, markdown_escape, markdown_inline, markdown_to_html
from .report_writers import html_page
from .results import load_results

__all__ = ["INDEX_UNRESOLVED_MARK", "INDEX_UNRESOLVED_NOTE", "write_index"]

INDEX_UNRESOLVED_MARK = "not resolved†"  # the index's mean over cases where no case is resolved
INDEX_UNRESOLVED_NOTE = (
    "† Not resolved in any case: every value lies within 2× the reference's noise floor (4× for the "
    "squared relMSE; within 6.02 dB of the ceiling for PSNR), so it cannot be told apart from the "
    "Monte Carlo noise of the ground truth. The mean may exceed the mean floor: the rule is 2×."
)


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
                f'<section class="entry"><h2>{html_escape(d.name)}</h2><p class="fail">Cannot read results: '
                f"{html_escape(err)}</p></section>"
            )
            continue
        facts, rows = _index_entry(r)
        summary = _first_paragraph(r.summary)
        meta = f"`{r.experiment}` · {markdown_escape(r.created)} · {markdown_escape(r.device)}"
        md += [f"## [{markdown_escape(r.title)}]({link})", "", f"*{meta}*", "", summary, ""]
        md += ["  ·  ".join(f"**{k}:** {v}" for k, v, _ in facts), ""]
        any_unresolved |= any(b.endswith(INDEX_UNRESOLVED_MARK) for _, b, _ in rows)
        head = headline_metric(r.cases)
        hname = METRICS.get(head, (head,))[0] if head else ""
        if rows:
            md += [f"| Approximation | mean {hname} over cases | ns/pixel |", "|:---|---:|---:|"]
            md += [f"| {markdown_escape(a)} | {b} | {c} |" for a, b, c in rows] + [""]
        html_rows = "".join(
            f'<tr><td>{html_escape(a)}</td><td class="num">{html_escape(b)}</td>'
            f'<td class="num">{html_escape(c)}</td></tr>'
            for a, b, c in rows
        )
        table = (
            (
                f'<div class="table-wrap"><table><thead><tr><th>Approximation</th><th class="num">mean '
                f'{html_escape(hname)} over cases</th><th class="num">ns/pixel</th></tr></thead><tbody>'
                f"{html_rows}"
                "</tbody></table></div>"
            )
            if rows
            else ""
        )
        fact_html = "".join(
            f"<li><b>{html_escape(k)}:</b> "
            + (f'<span class="fail">{html_escape(v)}</span>' if bad else html_escape(v))
            + "</li>"
            for k, v, bad in facts
        )
        body.append(
            f'<section class="entry"><h2><a href="{html_escape(link)}">{html_escape(r.title)}</a></h2>'
            f'<p class="meta">{markdown_inline(meta)}</p>{markdown_to_html(summary)}'
            f'<ul class="headline">{fact_html}</ul>{table}</section>'
        )
    if any_unresolved:
        md += [INDEX_UNRESOLVED_NOTE, ""]
        body.append(f'<p class="table-note">{html_escape(INDEX_UNRESOLVED_NOTE)}</p>')
    body.append(
        f"<footer>Generated by rtfit from each experiment's <code>results.json</code> "
        f"(schema <code>{SCHEMA}</code>).</footer>"
    )
    md += ["---", "", f"Generated by rtfit from each experiment's `results.json` (schema `{SCHEMA}`).", ""]
    return [
        atomic_write_text(out_dir / "index.html", html_page("rtfit results", "\n".join(body))),
        atomic_write_text(out_dir / "index.md", "\n".join(md)),
    ]
