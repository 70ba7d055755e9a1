"""LaTeX tables for the reports: ``tables.tex``, which compiles under pdflatex and fits the page.

``tables.tex`` holds every table of ``report.md`` that is marked for LaTeX, as ``table`` floats (or
``longtable`` where a table is taller than a page). It needs only::

    \\documentclass{article}
    \\usepackage{booktabs}  % \\toprule, \\midrule, \\bottomrule
    \\usepackage{array}     % >{\\raggedright\\arraybackslash}p{…} columns
    \\usepackage{longtable} % tables longer than a page
    …
    \\input{tables}

(``docs/latex.md``). Three things make that hold for any ``results.json``:

- **Text** goes through :func:`tex_text` (`rtfit.experiments.latex_text`, which also estimates its
  width): LaTeX specials are escaped, every non-ASCII character of the results is mapped to a macro of
  plain LaTeX (Greek and mathematical symbols in math mode, sub- and superscript digits and letters as
  math sub-/superscripts, accented letters and combining accents as text accents), and a character it
  does not know becomes ``[U+XXXX]`` (or its compatibility decomposition when that is ASCII), so
  nothing can stop pdflatex or vanish silently.
- **Width**: every column is a fixed ``p{…}`` column whose width comes from the Computer Modern
  character widths (roman or italic; bold for bold cells), so the table's width is known in advance.
  Labels wrap; numbers never do: a metric cell is its value over the noise floor in small print,
  ``value ± s.e.`` is set the same way. A table wider than the text width
  (:data:`TEXT_WIDTH_PT`) is split into parts by column groups, each repeating the key column(s),
  "(part 1 of 2)" in the caption.
- **Height**: a table estimated taller than :data:`LONG_TABLE_PT` becomes a ``longtable`` that breaks
  across pages, its header repeated.

Numbers are right-aligned with the report's 4 significant digits; ``1.234e-5`` prints as
1.234×10⁻⁵.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from .latex_text import (
    BODY_PT,
    SCI_NUMBER,
    SUB_PT,
    WIDTH_SAFETY,
    is_fallback,
    markdown_visible,
    number_visible,
    tex_markdown,
    tex_number,
    tex_text,
    text_width,
)

__all__ = [
    "LONG_TABLE_PT",
    "PREAMBLE",
    "TEXT_WIDTH_PT",
    "TexCell",
    "TexTable",
    "render_table",
    "render_tables",
    "tex_label",
    "tex_text",
]

TEXT_WIDTH_PT = 345.0  # \textwidth of the standard article class at 10 pt (letter and A4 paper)
LONG_TABLE_PT = 430.0  # estimated table height above which a longtable is used (article: 550+ pt)
TABCOLSEP_PT = 4.0  # \tabcolsep inside the tables (LaTeX's default is 6 pt)
PREAMBLE = "\\documentclass{article}\n\\usepackage{booktabs}\n\\usepackage{array}\n\\usepackage{longtable}\n"


@dataclass
class TexCell:
    """A table cell as :func:`render_table` reads it (the report's cell model, for tables built
    outside the report). ``text``: the value (``numeric``: a formatted number, right-aligned, never
    wrapped, ``"value ± s.e."`` allowed) or text (``md``: inline markdown); ``sub``: a second line in
    small print (a metric's noise floor as ``"floor 1.2e-3"``); ``style``: ``""``, ``"best"``/``"fail"``
    (bold), ``"unresolved"``/``"at-bound"`` (italic); ``mark``: a footnote mark after the value."""

    text: str = ""
    sub: str = ""
    numeric: bool = False
    md: bool = False
    style: str = ""
    mark: str = ""


@dataclass
class TexTable:
    """A table as :func:`render_table` reads it: ``anchor`` (label key, ``table-`` prefix dropped),
    caption (plain text; empty: none), header and rows of :class:`TexCell`, notes under the table,
    ``tex_cols``: the columns to show (None: all)."""

    anchor: str
    caption: str
    header: list[TexCell]
    rows: list[list[TexCell]]
    notes: list[str] = field(default_factory=list)
    tex_cols: list[int] | None = None


# -------------------------------------------------------------------------------------------- cells
# Bold text and maths: \textbf alone leaves maths (a value's ×10ⁿ, a Greek letter) upright-medium;
# the kernel's \boldmath switches the maths inside the group to bold too, with no package needed.
_BOLD = r"\textbf{\boldmath "
# Italic maths of one ×10ⁿ number: the italic corrections TeX adds in math after the mantissa (before
# \times), before the superscript and after it (cmti9: 0.08-0.12 em each), with a margin.
_ITALIC_MATH_EM = 0.45


def _cell_lines(c) -> list[tuple[str, float, str]]:
    """A cell as lines (LaTeX, estimated width in pt, 'word' or 'line'): a 'line' never breaks."""
    if c.numeric and not c.text.strip() and not c.sub:
        return [("", 0.0, "line")]
    if c.numeric and not _is_prose(c.text):
        text, extra = c.text, ""
        if " ± " in text:  # value ± standard error: the ± part goes below in small print
            text, extra = text.split(" ± ", 1)
            extra = "± " + extra
        elif c.sub:
            extra = "(" + c.sub.removeprefix("floor ") + ")"
        italic = c.style in ("unresolved", "at-bound")
        value = tex_number(text, italic=italic)
        if c.style in ("best", "fail"):
            value = _BOLD + value + "}"
        elif italic:
            value = r"\textit{" + value + "}"
        value += tex_text(c.mark)
        bold = c.style in ("best", "fail")
        # \mbox: a number never wraps; were an estimate short, pdflatex would report an overfull box.
        width = text_width(number_visible(text) + c.mark, bold=bold)
        if italic:  # \mathit: TeX adds cmti's italic corrections (≈0.1 em each, three per ×10ⁿ)
            width += _ITALIC_MATH_EM * BODY_PT * WIDTH_SAFETY * len(SCI_NUMBER.findall(text))
        lines = [(r"\mbox{" + value + "}", width, "line")]
        if extra:
            sub = r"\mbox{\scriptsize " + tex_number(extra) + "}"
            lines.append((sub, text_width(number_visible(extra), SUB_PT), "line"))
        return lines
    body = tex_markdown(c.text) if c.md else tex_text(c.text)
    visible = markdown_visible(c.text) if c.md else c.text
    if c.style in ("best", "fail"):
        body = _BOLD + body + "}"
    elif c.style in ("unresolved", "at-bound"):
        body = r"\textit{" + body + "}"
    body += tex_text(c.mark)
    lines = [(body, text_width(visible + c.mark, bold=_bold(c)), "word")]
    if c.sub:
        lines.append((r"{\scriptsize " + tex_text(c.sub) + "}", text_width(c.sub, SUB_PT), "word"))
    return lines


def _is_prose(text: str) -> bool:
    """A cell of a numeric column that is a sentence with numbers in it (a check's value such as
    "Σ|point − disc| / Σ disc = 0.00583, low anti-solar sky 0.0184; …"), wider than a third of the text
    width: it wraps like text. As one unbreakable number it made the nishita-sky checks table 185 pt wider
    than the page (issue 32)."""
    return len(text.split()) > 3 and text_width(text) > TEXT_WIDTH_PT / 3


def _bold(c) -> bool:
    return c.style in ("best", "fail") or (c.md and "**" in c.text)


def _words_max(lines: list[tuple[str, float, str]], cell) -> float:
    """The widest unbreakable piece of a cell (pt)."""
    best = 0.0
    for k, (_, w, kind) in enumerate(lines):
        if kind == "line":
            best = max(best, w)
            continue
        text = (markdown_visible(cell.text) if cell.md else cell.text) if k == 0 else cell.sub
        size = BODY_PT if k == 0 else SUB_PT
        text = "".join(c + "\x00" if is_fallback(c) else c for c in text)  # breaks after [U+XXXX]
        # Typewriter (code spans) never breaks at a hyphen or slash (cmtt has no hyphenchar): only
        # their spaces split them.
        text = re.sub(
            "\x01[^\x02]*\x02?", lambda m: m.group(0).replace("-", "\x03").replace("/", "\x04"), text
        )
        for word in re.split(r"[ \-–—/\x00]+", text + (cell.mark if k == 0 else "")):
            word = word.replace("\x03", "-").replace("\x04", "/")
            tt = word.count("\x01") > word.count("\x02")
            word = word.replace("\x01", "").replace("\x02", "")
            best = max(best, text_width(word, size, tt, bold=k == 0 and _bold(cell)) + 2.0)
    return best


class _Column:
    def __init__(self, header, cells):
        # a column holding a sentence (`_is_prose`) is laid out as text: it wraps into the room left
        self.numeric = bool(header.numeric) and not any(c.numeric and _is_prose(c.text) for c in cells)
        self.header = header
        hl = _cell_lines(_plain(header))
        self.head_tex = hl[0][0]
        self.head_nat = hl[0][1]
        self.head_min = _words_max(hl, _plain(header))
        self.cells = [_cell_lines(c) for c in cells]
        nat = [max((w for _, w, _ in lines), default=0.0) for lines in self.cells]
        self.body_nat = max(nat, default=0.0)
        self.body_min = max(
            (_words_max(lines, c) for lines, c in zip(self.cells, cells, strict=True)), default=0.0
        )
        self.nat = max(self.body_nat, self.head_nat)
        self.min = max(self.body_min, self.head_min)
        if self.numeric:  # numbers never wrap; a long header wraps, but not below 55 pt
            self.want = max(self.body_nat, self.head_min, min(self.head_nat, 55.0))
            self.min = self.want
        else:
            self.want = self.nat
        self.width = self.want

    def empty(self, i: int) -> bool:
        return not any(t.strip() for t, _, _ in self.cells[i])


class _PlainHeader:
    def __init__(self, text):
        self.text, self.sub, self.numeric, self.md, self.style, self.mark = text, "", False, False, "", ""


def _plain(header):
    return _PlainHeader(header.text)


def _sep(ncols: int) -> float:
    return 2 * TABCOLSEP_PT * ncols


def _fit_text_columns(cols: list[_Column], room: float) -> None:
    """Give the text columns of ``cols`` widths within ``room`` (pt) in total: water-filling from
    their minimum (longest word) up to their natural width."""
    text = [c for c in cols if not c.numeric]
    for c in text:
        c.width = c.min
    spare = room - sum(c.width for c in text)
    while spare > 0.5:
        grow = [c for c in text if c.width < c.nat - 0.01]
        if not grow:
            break
        step = min(spare / len(grow), min(c.nat - c.width for c in grow))
        for c in grow:
            c.width += step
        spare -= step * len(grow)


def _layout(cols: list[_Column], n_key: int, width: float) -> list[tuple[list[int], dict[int, float]]]:
    """Column index groups (each starting with the key columns) and their column widths (pt), each
    group fitting ``width``."""
    keys = list(range(n_key))
    rest = list(range(n_key, len(cols)))
    # Key columns get at most a third of the width each when the table is wide, never less than a word.
    key_cap = max(width / 3, 60.0)
    for k in keys:
        if not cols[k].numeric:
            cols[k].want = max(cols[k].min, min(cols[k].nat, key_cap))
    # A text column outside the keys wants up to half the width.
    for j in rest:
        if not cols[j].numeric:
            cols[j].want = max(cols[j].min, min(cols[j].nat, width / 2))

    def need(group: list[int]) -> float:
        idx = keys + group
        return sum(cols[i].want if cols[i].numeric else cols[i].min for i in idx) + _sep(len(idx))

    groups: list[list[int]] = []
    cur: list[int] = []
    for j in rest:
        if cur and need([*cur, j]) > width:
            groups.append(cur)
            cur = []
        cur.append(j)
    if cur or not groups:
        groups.append(cur)
    if len(groups) > 1:  # as many parts as the greedy split, but with the columns spread evenly
        k, n = len(groups), len(rest)
        sizes = [n // k + (1 if q < n % k else 0) for q in range(k)]
        even = [rest[sum(sizes[:q]) : sum(sizes[: q + 1])] for q in range(k)]
        if all(need(g) <= width for g in even):
            groups = even
    out = []
    for g in groups:
        idx = keys + g
        fixed = sum(cols[i].want for i in idx if cols[i].numeric) + _sep(len(idx))
        for i in idx:
            if cols[i].numeric:
                cols[i].width = cols[i].want
        _fit_text_columns([cols[i] for i in idx], width - fixed)
        out.append((idx, {i: cols[i].width for i in idx}))
    return out


def _row_height(cols: list[_Column], widths: dict[int, float], idx: list[int], r: int) -> float:
    h = 1.0
    for i in idx:
        lines = 0.0
        for _, w, _ in cols[i].cells[r]:
            lines += max(1, math.ceil(w / max(widths[i], 1.0) * 1.15))
        h = max(h, lines)
    return h * 11.0


def tex_label(*parts: str) -> str:
    """A ``\\label`` key from parts: each reduced to letters, digits and hyphens, joined by ``:``."""
    return ":".join(re.sub(r"[^A-Za-z0-9\-]+", "-", p).strip("-") or "x" for p in parts)


def _cell_tex(lines) -> str:
    t = r"\par ".join(t for t, _, _ in lines if t != "")
    return "{}" + t if t.startswith("[") else t  # a row's "\\" would read a leading [ as its option


def _table_parts(experiment: str, b, width: float, force_long: bool = False) -> list[str]:
    idx_all = b.tex_cols if b.tex_cols is not None else list(range(len(b.header)))
    header = [b.header[i] for i in idx_all]
    rows = [[row[i] for i in idx_all] for row in b.rows]
    cols = [_Column(h, [r[j] for r in rows]) for j, h in enumerate(header)]
    # A table whose first column is left blank on continuation rows (the fits table: a fit's name on
    # its first parameter only) is keyed by its first two columns; every other by its first.
    grouped = len(cols) > 2 and any(cols[0].empty(r) and not cols[1].empty(r) for r in range(len(rows)))
    n_key = 2 if grouped else 1
    groups = _layout(cols, n_key, width)
    base_label = tex_label(experiment, b.anchor.removeprefix("table-"))
    out = []
    for p, (idx, widths) in enumerate(groups):
        if p > 0 and n_key == 2:
            # A later part of the fits table holds fit-level columns (filled on a fit's first row
            # only): it is keyed by the fit alone.
            if all(not cols[0].empty(r) or all(cols[i].empty(r) for i in idx[2:]) for r in range(len(rows))):
                idx = [0, *idx[2:]]
        data = idx[1:] if len(idx) < len(widths) else idx[n_key:]
        keep = [r for r in range(len(rows)) if p == 0 or any(not cols[i].empty(r) for i in data)]
        caption = tex_text(b.caption)
        part = f"(part {p + 1} of {len(groups)})" if len(groups) > 1 else ""
        if caption and part:
            caption += " " + part
        label = base_label if p == 0 else f"{base_label}:part{p + 1}"
        spec = "".join(
            (r">{\raggedleft\arraybackslash}" if cols[i].numeric else r">{\raggedright\arraybackslash}")
            + f"p{{{math.floor(widths[i] * 10) / 10:.1f}pt}}"  # rounded down: the sum stays within
            for i in idx
        )
        head = " & ".join(_cell_tex([(cols[i].head_tex, 0.0, "")]) for i in idx) + r" \\"
        body = ["    " + " & ".join(_cell_tex(cols[i].cells[r]) for i in idx) + r" \\" for r in keep]
        height = sum(_row_height(cols, widths, idx, r) for r in keep) + 60.0
        notes = (
            r"\par\smallskip{\footnotesize " + r" \par ".join(tex_text(n) for n in b.notes) + "}"
            if b.notes
            else ""
        )
        setup = rf"\small\setlength{{\tabcolsep}}{{{TABCOLSEP_PT:g}pt}}"
        if height > LONG_TABLE_PT or force_long:
            out += [
                r"\begingroup" + setup,
                rf"\begin{{longtable}}{{{spec}}}",
                *([rf"  \caption{{{caption}}}\label{{tab:{label}}} \\"] if caption else []),
                # A table without a caption names its part in a line above it.
                *(
                    [rf"  \multicolumn{{{len(idx)}}}{{@{{}}l}}{{\footnotesize\itshape {part}}} \\"]
                    if part and not caption
                    else []
                ),
                r"    \toprule",
                "    " + head,
                r"    \midrule",
                r"  \endfirsthead",
                rf"  \multicolumn{{{len(idx)}}}{{@{{}}l}}{{\footnotesize\itshape (continued)}} \\",
                r"    \toprule",
                "    " + head,
                r"    \midrule",
                r"  \endhead",
                r"    \bottomrule",
                r"  \endlastfoot",
                *body,
                r"\end{longtable}",
            ]
            if notes:
                out.append(notes.removeprefix(r"\par\smallskip") + r"\par")
            out += [r"\endgroup", ""]
        else:
            out += [
                r"\begin{table}[htbp]",
                r"  \centering" + setup,
                *([f"  \\caption{{{caption}}}", f"  \\label{{tab:{label}}}"] if caption else []),
                *([rf"  {{\footnotesize\itshape {part}}}\par"] if part and not caption else []),
                f"  \\begin{{tabular}}{{{spec}}}",
                r"    \toprule",
                "    " + head,
                r"    \midrule",
                *body,
                r"    \bottomrule",
                r"  \end{tabular}",
            ]
            if notes:
                out.append("  " + notes)
            out += [r"\end{table}", ""]
    return out


def render_table(experiment: str, table, width_pt: float = TEXT_WIDTH_PT, longtable: bool = False) -> str:
    """One report table as LaTeX (a ``table`` float, or a ``longtable`` when it is taller than
    :data:`LONG_TABLE_PT` or ``longtable`` is set; split into parts where wider than ``width_pt``).
    ``table``: as in :func:`render_tables` (e.g. a :class:`TexTable`). A table with an empty caption
    gets no ``\\caption`` and no ``\\label``. A ``longtable`` is not a float: any number of them may
    follow each other without "Too many unprocessed floats"."""
    return "\n".join(_table_parts(experiment, table, width_pt, force_long=longtable))


def render_tables(experiment: str, tables, width_pt: float = TEXT_WIDTH_PT) -> str:
    """``tables.tex`` for the report tables ``tables`` of experiment ``experiment``.

    ``tables``: objects with ``anchor``, ``caption``, ``header``, ``rows``, ``notes`` and ``tex_cols``
    (the columns to show, None for all), whose cells have ``text``, ``sub``, ``numeric``, ``md``,
    ``style`` and ``mark`` (the report's table model). ``width_pt``: the text width the tables must fit.
    """
    out = [
        f"% tables.tex - generated by rtfit from results.json (experiment {experiment}); do not edit.",
        "% Needs \\usepackage{booktabs}, \\usepackage{array} and \\usepackage{longtable}; pure ASCII",
        f"% (pdflatex and lualatex). Laid out for a text width of {width_pt:g} pt or more (docs/latex.md).",
        "% Metric cells: value over the noise floor of the reference (in parentheses).",
        "",
    ]
    for b in tables:
        out += _table_parts(experiment, b, width_pt)
    return "\n".join(out)
