"""Text as LaTeX for the report tables (`rtfit.experiments.latex`): plain text (:func:`tex_text`),
formatted numbers (:func:`tex_number`) and inline markdown (:func:`tex_markdown`) escaped for pdflatex with
no package beyond the kernel, and the typeset width of such text estimated from Computer Modern's character
widths (:func:`text_width`), on the safe side, so a table's width is known before LaTeX sees it.

Every non-ASCII character of the results is mapped to a macro of plain LaTeX (Greek and mathematical
symbols in math mode, sub- and superscript digits and letters as math sub-/superscripts, accented letters
and combining accents as text accents); a character it does not know becomes ``[U+XXXX]`` (or its
compatibility decomposition when that is ASCII), so nothing can stop pdflatex or vanish silently.
"""

from __future__ import annotations

import re
import unicodedata

__all__ = [
    "BODY_PT",
    "KNOWN_CHARACTERS",
    "SCI_NUMBER",
    "SUB_PT",
    "TT_EM",
    "WIDTH_SAFETY",
    "is_fallback",
    "markdown_visible",
    "number_visible",
    "tex_markdown",
    "tex_number",
    "tex_text",
    "text_width",
]

BODY_PT = 9.0  # \small in a 10 pt document
SUB_PT = 7.0  # \scriptsize in a 10 pt document


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
    s = str(text)
    if s.isascii():  # (NFD leaves ASCII as it is; most of a report's cells: issue 33)
        return s.translate(_ASCII_CODES)
    return _tex_chars(unicodedata.normalize("NFD", s))


def _tex_chars(s: str) -> str:
    """`tex_text` of NFD-normalised ``s``, character by character."""
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


_ASCII_CODES = {c: _tex_chars(chr(c)) for c in range(128)}
"""`tex_text` of each ASCII character alone, for `str.translate`: no ASCII character is a sub- or superscript
or a combining mark, so an ASCII string's LaTeX is its characters' side by side (tested against `_tex_chars`
on every ASCII character pair and on random ASCII text)."""


SCI_NUMBER = re.compile(r"(?<![\w.])(-?\d+(?:\.\d+)?)e([-+]?\d+)\b")
"""A number in e-notation (``1.234e-5``; groups: mantissa, exponent), printed as ×10ⁿ."""


_NEG = re.compile(r"(?<![\w.])-(?=\.?\d)")


def tex_number(text: str, italic: bool = False) -> str:
    """A formatted number (or text holding numbers) as LaTeX: ``1.234e-5`` → 1.234×10⁻⁵, and a
    minus sign rather than a hyphen before a number. ``italic``: the maths of ×10ⁿ in ``\\mathit``
    (``\\textit`` does not reach into maths, so an italic cell's digits would stay upright)."""
    parts, pos = [], 0
    for m in SCI_NUMBER.finditer(text):
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


def markdown_visible(text: str) -> str:
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
                return markdown_visible(m.group(g))
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
WIDTH_SAFETY = 1.06  # estimates are scaled by this, plus 1 pt


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
    return 0.6 * 9 if is_fallback(ch) else 1.35


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
    return em * size_pt * optical * WIDTH_SAFETY + 1.0 if em else 0.0


def number_visible(text: str) -> str:
    """A number's printed form for width estimates: ``1.234e-5`` → ``1.234×10⁻⁵``, ``-1`` → ``−1``."""
    sup = str.maketrans("0123456789-+", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻⁺")
    text = SCI_NUMBER.sub(lambda m: f"{m.group(1)}×10{str(int(m.group(2))).translate(sup)}", text)
    return _NEG.sub("−", text)


def is_fallback(ch: str) -> bool:
    """Whether :func:`tex_text` prints non-ASCII ``ch`` as ``[U+XXXX]`` (no mapping of its own)."""
    return ord(ch) > 127 and _base(ch)[0].startswith("[U+")
