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

- **Text** goes through :func:`tex_text`: LaTeX specials are escaped, every non-ASCII character of the
  results is mapped to a macro of plain LaTeX (Greek and mathematical symbols in math mode,
  sub- and superscript digits and letters as math sub-/superscripts, accented letters and combining
  accents as text accents), and a character it does not know becomes ``[U+XXXX]`` (or its
  compatibility decomposition when that is ASCII), so nothing can stop pdflatex or vanish silently.
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
import unicodedata
from dataclasses import dataclass, field

__all__ = [
    "KNOWN_CHARACTERS",
    "LONG_TABLE_PT",
    "PREAMBLE",
    "TEXT_WIDTH_PT",
    "TT_EM",
    "TexCell",
    "TexTable",
    "render_table",
    "render_tables",
    "tex_label",
    "tex_markdown",
    "tex_number",
    "tex_text",
    "text_width",
]

TEXT_WIDTH_PT = 345.0  # \textwidth of the standard article class at 10 pt (letter and A4 paper)
LONG_TABLE_PT = 430.0  # estimated table height above which a longtable is used (article: 550+ pt)
TABCOLSEP_PT = 4.0  # \tabcolsep inside the tables (LaTeX's default is 6 pt)
BODY_PT = 9.0  # \small in a 10 pt document
SUB_PT = 7.0  # \scriptsize in a 10 pt document
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


# -------------------------------------------------------------------------------------------- text
_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
    "\n": " ",
    "\t": " ",
    "\r": " ",
}
_GREEK = dict(
    zip(
        "αβγδεζηθικλμνξπρστυφχψωϑϕϖϱςΓΔΘΛΞΠΣΥΦΨΩ",
        "alpha beta gamma delta varepsilon zeta eta theta iota kappa lambda mu nu xi pi rho sigma tau "
        "upsilon phi chi psi omega vartheta phi varpi varrho varsigma Gamma Delta Theta Lambda Xi Pi "
        "Sigma Upsilon Phi Psi Omega".split(),
        strict=True,
    )
)
# Greek capitals that look like Latin ones (no macro of their own), and the Greek ο.
_GREEK_LATIN = dict(zip("ΑΒΕΖΗΙΚΜΝΟΡΤΧο", "ABEZHIKMNOPTXo", strict=True))
# Math-mode symbols (set with \ensuremath{…}).
_MATH = {
    "ϵ": r"\epsilon",
    "°": r"^\circ",
    "±": r"\pm",
    "∓": r"\mp",
    "×": r"\times",
    "÷": r"\div",
    "·": r"\cdot",
    "⋅": r"\cdot",
    "∙": r"\cdot",
    "−": "-",
    "∗": "*",
    "≤": r"\le",
    "≥": r"\ge",
    "≪": r"\ll",
    "≫": r"\gg",
    "≈": r"\approx",
    "≃": r"\simeq",
    "∼": r"\sim",
    "≠": r"\ne",
    "≡": r"\equiv",
    "∝": r"\propto",
    "∞": r"\infty",
    "∂": r"\partial",
    "∇": r"\nabla",
    "∑": r"\sum",
    "∏": r"\prod",
    "∫": r"\int",
    "√": r"\surd",
    "∈": r"\in",
    "∉": r"\notin",
    "⊂": r"\subset",
    "⊆": r"\subseteq",
    "∩": r"\cap",
    "∪": r"\cup",
    "∅": r"\emptyset",
    "∀": r"\forall",
    "∃": r"\exists",
    "¬": r"\neg",
    "∧": r"\wedge",
    "∨": r"\vee",
    "⊥": r"\perp",
    "∥": r"\parallel",
    "∠": r"\angle",
    "→": r"\to",
    "←": r"\leftarrow",
    "↔": r"\leftrightarrow",
    "⇒": r"\Rightarrow",
    "⇐": r"\Leftarrow",
    "⇔": r"\Leftrightarrow",
    "↦": r"\mapsto",
    "↑": r"\uparrow",
    "↓": r"\downarrow",
    "†": r"\dagger",
    "‡": r"\ddagger",
    "★": r"\star",
    "☆": r"\star",
    "⋆": r"\star",
    "′": r"{}^\prime",
    "″": r"{}^{\prime\prime}",
    "ℓ": r"\ell",
    "ħ": r"\hbar",
    "ℝ": r"\mathbf{R}",
    "½": r"\frac{1}{2}",
    "⅓": r"\frac{1}{3}",
    "⅔": r"\frac{2}{3}",
    "¼": r"\frac{1}{4}",
    "¾": r"\frac{3}{4}",
    "µ": r"\mu",
    "⟨": r"\langle",
    "⟩": r"\rangle",
    "⌈": r"\lceil",
    "⌉": r"\rceil",
    "⌊": r"\lfloor",
    "⌋": r"\rfloor",
    "∘": r"\circ",
    "⊗": r"\otimes",
    "⊕": r"\oplus",
}
# Text-mode replacements.
_TEXT = {
    "—": "---",
    "–": "--",
    "‐": "-",
    "‑": "-",
    "…": r"\ldots{}",
    "“": "``",
    "”": "''",
    "„": ",,",
    "‘": "`",
    "’": "'",
    "«": r"\textless{}\textless{}",
    "»": r"\textgreater{}\textgreater{}",
    "\u00a0": "~",
    "\u2009": r"\,",
    "\u202f": r"\,",
    "\u200b": "",
    "\u00ad": r"\-",
    "§": r"\S{}",
    "¶": r"\P{}",
    "©": r"\copyright{}",
    "£": r"\pounds{}",
    "ß": r"\ss{}",
    "æ": r"\ae{}",
    "Æ": r"\AE{}",
    "ø": r"\o{}",
    "Ø": r"\O{}",
    "œ": r"\oe{}",
    "Œ": r"\OE{}",
    "å": r"\aa{}",
    "Å": r"\AA{}",
    "ł": r"\l{}",
    "Ł": r"\L{}",
    "ı": r"\i{}",
    "¡": r"!`",
    "¿": r"?`",
    "✓": "pass",
    "✔": "pass",
    "✗": "FAIL",
    "✘": "FAIL",
    "ꟻ": "F",  # the reversed F of ꟻLIP
}
# Sub- and superscript characters: runs become \ensuremath{_{…}} / \ensuremath{^{…}}.
_SUB = {
    **{chr(0x2080 + i): str(i) for i in range(10)},
    "₊": "+",
    "₋": "-",
    "₌": "=",
    "₍": "(",
    "₎": ")",
    **dict(zip("ₐₑₒₓₔₕₖₗₘₙₚₛₜᵢⱼᵣᵤᵥ", "aeoxehklmnpstijruv", strict=True)),  # ₔ (schwa) as e
    "ᵦ": r"\beta",
    "ᵧ": r"\gamma",
    "ᵨ": r"\rho",
    "ᵩ": r"\phi",
    "ᵪ": r"\chi",
}
_SUP = {
    "⁰": "0",
    "¹": "1",
    "²": "2",
    "³": "3",
    **{chr(0x2070 + i): str(i) for i in range(4, 10)},
    "⁺": "+",
    "⁻": "-",
    "⁼": "=",
    "⁽": "(",
    "⁾": ")",
    "ⁿ": "n",
    "ⁱ": "i",
    "ᵀ": r"\mathrm{T}",
    "ᵃ": "a",
    "ᵇ": "b",
    "ᶜ": "c",
    "ᵈ": "d",
    "ᵉ": "e",
    "ᶠ": "f",
    "ᵍ": "g",
    "ʰ": "h",
    "ʲ": "j",
    "ᵏ": "k",
    "ˡ": "l",
    "ᵐ": "m",
    "ᵒ": "o",
    "ᵖ": "p",
    "ʳ": "r",
    "ˢ": "s",
    "ᵗ": "t",
    "ᵘ": "u",
    "ᵛ": "v",
    "ʷ": "w",
    "ˣ": "x",
    "ʸ": "y",
    "ᶻ": "z",
}
# Combining accents: (text-mode accent command, math-mode accent command).
_ACCENT = {
    "\u0300": ("`", r"\grave"),
    "\u0301": ("'", r"\acute"),
    "\u0302": ("^", r"\hat"),
    "\u0303": ("~", r"\tilde"),
    "\u0304": ("=", r"\bar"),
    "\u0305": ("=", r"\bar"),
    "\u0306": ("u", r"\breve"),
    "\u0307": (".", r"\dot"),
    "\u0308": ('"', r"\ddot"),
    "\u030a": ("r", r"\mathring"),
    "\u030b": ("H", r"\acute"),
    "\u030c": ("v", r"\check"),
    "\u0323": ("d", r"\dot"),
    "\u0327": ("c", r"\bar"),
    "\u0328": ("c", r"\bar"),  # ogonek: \k exists only in T1; a cedilla stands in
    "\u0331": ("b", r"\bar"),
    "\u20d7": ("", r"\vec"),
}


KNOWN_CHARACTERS = frozenset(_GREEK) | set(_GREEK_LATIN) | set(_MATH) | set(_TEXT) | set(_SUB) | set(_SUP)
"""The non-ASCII characters :func:`tex_text` maps explicitly (accents come on top of these)."""


def _base(ch: str) -> tuple[str, bool]:
    """LaTeX for one character without accents: (code, is_math)."""
    if ch in _SPECIAL:
        return _SPECIAL[ch], False
    if " " <= ch <= "~":
        return ch, False
    if ch in _GREEK:
        return "\\" + _GREEK[ch], True
    if ch in _GREEK_LATIN:
        return _GREEK_LATIN[ch], False
    if ch in _MATH:
        return _MATH[ch], True
    if ch in _TEXT:
        return _TEXT[ch], False
    if unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp"):
        return "", False
    if unicodedata.category(ch).startswith("Z"):
        return " ", False
    compat = unicodedata.normalize("NFKD", ch)
    if compat != ch and all(" " <= c <= "~" for c in compat):
        return "".join(_SPECIAL.get(c, c) for c in compat), False
    return f"[U+{ord(ch):04X}]\\allowbreak{{}}", False


def tex_text(text) -> str:
    """Plain text as LaTeX (text mode) that pdflatex compiles with no package beyond the kernel.

    Specials are escaped; Greek and mathematical symbols become ``\\ensuremath{…}``; runs of sub- or
    superscript characters (``C₀``, ``10⁻⁴``) become math sub-/superscripts; accented letters and
    combining accents (``L̄``, ``ȳ``, ``á``) become text accents (math accents on math symbols); a
    character with no mapping becomes ``[U+XXXX]``.
    """
    s = unicodedata.normalize("NFD", str(text))
    out: list[str] = []
    i, n = 0, len(s)
    while i < n:
        ch = s[i]
        for table, op in ((_SUB, "_"), (_SUP, "^")):
            if ch in table:
                j = i
                while j < n and s[j] in table:
                    j += 1
                parts = [table[c] for c in s[i:j]]
                run = (" " if any(len(x) > 1 for x in parts) else "").join(parts)  # "\beta i", not "\betai"
                out.append(f"\\ensuremath{{{op}{{{run}}}}}")
                i = j
                break
        else:
            j = i + 1
            accents = []
            while j < n and unicodedata.combining(s[j]):
                accents.append(s[j])
                j += 1
            code, math_mode = _base(ch)
            for a in accents:
                text_acc, math_acc = _ACCENT.get(a, (None, None))
                if math_acc is None:
                    continue  # an unknown combining mark is dropped; its base letter stays
                if math_mode or (not text_acc and ch.isascii() and ch.isalpha()):
                    code, math_mode = f"{math_acc}{{{code}}}", True
                elif text_acc and ch.isalnum() and (ch.isascii() or ch in _GREEK_LATIN):
                    code = f"\\{text_acc}{{{code}}}"
                # else: an accent over a symbol or a special is dropped
            out.append(f"\\ensuremath{{{code}}}" if math_mode else code)
            i = j
    return "".join(out)


_SCI = re.compile(r"(?<![\w.])(-?\d+(?:\.\d+)?)e([-+]?\d+)\b")


_NEG = re.compile(r"(?<![\w.])-(?=\.?\d)")


def tex_number(text: str, italic: bool = False) -> str:
    """A formatted number (or text holding numbers) as LaTeX: ``1.234e-5`` → 1.234×10⁻⁵, and a
    minus sign rather than a hyphen before a number. ``italic``: the maths of ×10ⁿ in ``\\mathit``
    (``\\textit`` does not reach into maths, so an italic cell's digits would stay upright)."""
    parts, pos = [], 0
    for m in _SCI.finditer(text):
        parts.append(tex_text(_NEG.sub("−", text[pos : m.start()])))
        body = rf"{m.group(1)}\times 10^{{{int(m.group(2))}}}"
        parts.append(rf"\ensuremath{{\mathit{{{body}}}}}" if italic else rf"\ensuremath{{{body}}}")
        pos = m.end()
    parts.append(tex_text(_NEG.sub("−", text[pos:])))
    return "".join(parts)


# Inline markdown of the kind rtfit writes: escapes, code spans, strong, emphasis, links, autolinks.
_MD = re.compile(
    r"(?P<esc>\\[!-/:-@\[-`{-~])"
    r"|(?P<tick>`+)(?P<code>.+?)(?P=tick)"
    r"|\*\*(?P<strong>[^*\s](?:.*?[^*\s])?)\*\*"
    r"|(?<![\w*])\*(?P<em>[^*\s](?:.*?[^*\s])?)\*(?![\w*])"
    r"|(?<![\w\\])_(?P<em2>[^_\s](?:.*?[^_\s])?)_(?!\w)"
    r"|\[(?P<ltext>[^\]]*)\]\((?P<url>[^()\s]*(?:\([^()\s]*\)[^()\s]*)*)\)"
    r"|<(?P<auto>[a-z][a-z0-9+.-]*:[^<>\s]+)>"
)


def tex_markdown(text: str) -> str:
    """Inline markdown as LaTeX: code spans in ``\\texttt``, strong/emphasis kept, links as their text."""
    out, pos = [], 0
    for m in _MD.finditer(text):
        out.append(tex_text(text[pos : m.start()]))
        pos = m.end()
        if m.group("esc"):
            out.append(tex_text(m.group("esc")[1]))
        elif m.group("tick"):
            out.append(r"\texttt{" + tex_text(m.group("code").strip()) + "}")
        elif m.group("strong") is not None:
            out.append(r"\textbf{" + tex_markdown(m.group("strong")) + "}")
        elif m.group("em") is not None or m.group("em2") is not None:
            out.append(r"\emph{" + tex_markdown(m.group("em") or m.group("em2")) + "}")
        elif m.group("ltext") is not None:
            out.append(tex_markdown(m.group("ltext")))
        else:
            out.append(r"\texttt{" + tex_text(m.group("auto")) + "}")
    out.append(tex_text(text[pos:]))
    return "".join(out)


def _md_visible(text: str) -> str:
    """What inline markdown shows (for width estimates); code spans marked by \x01 … \x02."""

    def one(m: re.Match) -> str:
        if m.group("esc"):
            return m.group("esc")[1]
        if m.group("tick"):
            return "\x01" + m.group("code").strip() + "\x02"
        if m.group("auto"):
            return "\x01" + m.group("auto") + "\x02"
        for g in ("strong", "em", "em2", "ltext"):
            if m.group(g) is not None:
                return _md_visible(m.group(g))
        return m.group(0)

    return _MD.sub(one, text)


# ------------------------------------------------------------------------------------------- widths
# Advance widths (1/1000 em) of ASCII 33–126 from the TFM files: regular text is the wider of cmr9 and
# cmti9, bold is cmbx9. Characters typeset from the math fonts in OT1 (< > \ _ { } | ~ ^) are set by hand.
def _em_table(widths: str) -> dict[str, float]:
    table = dict(zip((chr(c) for c in range(33, 127)), (int(v) / 1000 for v in widths.split()), strict=True))
    table.update({"<": 0.8, ">": 0.8, "\\": 0.55, "_": 0.55, "{": 0.55, "}": 0.55, "|": 0.3, "~": 0.55})
    table.update({"^": 0.55, " ": 0.36})
    return table


_EM_REGULAR = _em_table(
    "315 528 856 786 856 799 315 420 420 525 799 315 367 315 525 525 525 525 525 525 525 525 525 525 "
    "525 315 315 315 799 525 525 799 771 728 742 785 699 671 806 771 396 539 799 644 942 771 799 699 "
    "799 756 577 742 771 771 1056 771 771 630 315 528 315 525 315 315 525 571 472 571 472 315 514 571 "
    "315 315 542 285 856 577 525 571 542 433 420 400 571 542 742 542 542 457 525 1049 525 525"
)
_EM_BOLD = _em_table(
    "360 618 986 786 986 920 329 460 460 592 920 329 394 329 592 592 592 592 592 592 592 592 592 592 "
    "592 329 329 360 920 559 559 920 893 841 855 907 777 744 930 924 446 611 926 711 1122 924 889 808 "
    "889 887 657 823 909 893 1222 893 893 723 329 618 329 592 329 329 575 657 526 657 543 362 592 657 "
    "329 362 625 329 986 657 592 657 625 488 467 460 657 625 855 625 625 526 592 1183 592 592"
)
_EM_SPECIAL = {"—": 1.0, "–": 0.5, "…": 1.0, "†": 0.5, "‡": 0.5, "°": 0.5, "·": 0.9}
TT_EM = 0.525  # cmtt: every character (em)
_SAFETY = 1.06  # estimates are scaled by this, plus 1 pt


def _char_em(ch: str, table: dict[str, float]) -> float:
    if ch in table:
        return table[ch]
    if unicodedata.combining(ch):
        return 0.0
    if ch in _EM_SPECIAL:
        return _EM_SPECIAL[ch]
    if ch in _SUB or ch in _SUP:
        return 0.45
    if ch in _TEXT:
        return 0.6 * max(1, len(_TEXT[ch].lstrip("\\").rstrip("{}")))
    if ch in _GREEK or ch in _GREEK_LATIN:
        return 0.8
    if ch in _MATH:  # a binary operator or relation with its spaces
        return 1.35 if not _MATH[ch].startswith(r"\frac") else 0.8
    return 0.6 * 9 if _is_fallback(ch) else 1.35


def text_width(text: str, size_pt: float = BODY_PT, tt: bool = False, bold: bool = False) -> float:
    """Estimated typeset width (pt) of ``text`` on one line at ``size_pt`` in Computer Modern, on the
    safe side (regular: the wider of roman and italic; ``bold``: bold extended). Text between \\x01 and
    \\x02 counts as typewriter."""
    table = _EM_BOLD if bold else _EM_REGULAR
    em, mono = 0.0, tt
    for ch in unicodedata.normalize("NFD", text):
        if ch == "\x01":
            mono = True
        elif ch == "\x02":
            mono = tt
        elif mono and not unicodedata.combining(ch):
            em += TT_EM
        else:
            em += _char_em(ch, table)
    optical = 1.11 if size_pt < 8.5 else 1.0  # cmr7 is relatively wider than cmr9 (digits 0.569 vs 0.514 em)
    return em * size_pt * optical * _SAFETY + 1.0 if em else 0.0


def _sci_visible(text: str) -> str:
    """A number's printed form for width estimates: ``1.234e-5`` → ``1.234×10⁻⁵``, ``-1`` → ``−1``."""
    sup = str.maketrans("0123456789-+", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺")
    text = _SCI.sub(lambda m: f"{m.group(1)}×10{str(int(m.group(2))).translate(sup)}", text)
    return _NEG.sub("−", text)


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
        width = text_width(_sci_visible(text) + c.mark, bold=bold)
        if italic:  # \mathit: TeX adds cmti's italic corrections (≈0.1 em each, three per ×10ⁿ)
            width += _ITALIC_MATH_EM * BODY_PT * _SAFETY * len(_SCI.findall(text))
        lines = [(r"\mbox{" + value + "}", width, "line")]
        if extra:
            sub = r"\mbox{\scriptsize " + tex_number(extra) + "}"
            lines.append((sub, text_width(_sci_visible(extra), SUB_PT), "line"))
        return lines
    body = tex_markdown(c.text) if c.md else tex_text(c.text)
    visible = _md_visible(c.text) if c.md else c.text
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


def _is_fallback(ch: str) -> bool:
    return ord(ch) > 127 and _base(ch)[0].startswith("[U+")


def _words_max(lines: list[tuple[str, float, str]], cell) -> float:
    """The widest unbreakable piece of a cell (pt)."""
    best = 0.0
    for k, (_, w, kind) in enumerate(lines):
        if kind == "line":
            best = max(best, w)
            continue
        text = (_md_visible(cell.text) if cell.md else cell.text) if k == 0 else cell.sub
        size = BODY_PT if k == 0 else SUB_PT
        text = "".join(c + "\x00" if _is_fallback(c) else c for c in text)  # breaks after [U+XXXX]
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
