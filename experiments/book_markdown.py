"""The book's markdown as LaTeX: summaries, sections and captions of ``results.json`` (CommonMark with pipe
tables, parsed by :func:`.report_text.markdown_tokens`) rendered by :func:`tex_markdown_blocks` (block
text) and :func:`inline_markdown` (a caption): paragraphs, lists, headings as ``\\paragraph``, code
blocks in the largest of three sizes that keeps their lines whole (wrapped only beyond that), pipe tables
through the table layout of :mod:`.latex`, so that nothing runs into the margin.
"""

from __future__ import annotations

import re

from . import latex
from .latex import TexCell, TexTable, render_table, tex_text
from .report_text import markdown_tokens

__all__ = ["code_inline", "inline_markdown", "tex_markdown_blocks"]


def code_inline(text: str) -> str:
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
            out.append(code_inline(t.content))
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


def inline_markdown(md: str) -> str:
    """Inline markdown (captions) as LaTeX, on one paragraph."""
    return tex_markdown_blocks(md).strip().replace("\n\n", " ")
