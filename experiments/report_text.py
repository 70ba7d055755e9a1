"""The text of the reports: numbers as printed (:func:`format_number`), a run's configuration as rows, and
the markdown dialect of ``results.json`` texts with its renderers and escapes.

The markdown of results (summary, sections, captions, notes, cost notes) is CommonMark with pipe tables,
rendered by markdown-it-py (:func:`markdown_to_html`, :func:`markdown_inline`; :func:`markdown_tokens`
for renderers to other formats, such as the book's LaTeX) with raw HTML escaped. Plain text that goes
into a report is escaped here too (:func:`html_escape`, :func:`markdown_escape`,
:func:`markdown_table_cell`).
"""

from __future__ import annotations

import html
import math
import re

from markdown_it import MarkdownIt
from markdown_it.rules_inline import StateInline

__all__ = [
    "config_rows",
    "format_number",
    "html_escape",
    "markdown_escape",
    "markdown_inline",
    "markdown_table",
    "markdown_table_cell",
    "markdown_to_html",
    "markdown_tokens",
]


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


def html_escape(text) -> str:
    """Plain text → HTML text (quotes escaped too, for attribute values)."""
    return html.escape(str(text), quote=True)


def markdown_escape(text) -> str:
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
    :func:`markdown_escape` is not escaped twice."""
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
