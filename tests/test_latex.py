"""tables.tex: the text → LaTeX mapping, and every experiment's tables compiled by pdflatex.

The compile tests run pdflatex (``-interaction=nonstopmode -halt-on-error``) on each ``tables.tex``
wrapped in the preamble that ``docs/latex.md`` documents, and read its log: no error, no overfull
``\\hbox`` wider than 1 pt, no missing character, no float taller than the page. They are skipped,
with the reason, where pdflatex is not installed (Debian: ``texlive-latex-base
texlive-latex-recommended``).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rtfit.experiments import latex, latex_text
from rtfit.experiments.report import render_report

ROOT = Path(__file__).resolve().parent.parent
RESULTS = sorted((ROOT / "tests" / "data" / "results").glob("*.json"))
PDFLATEX = shutil.which("pdflatex")
needs_pdflatex = pytest.mark.skipif(
    PDFLATEX is None,
    reason="pdflatex is not installed (apt-get install texlive-latex-base texlive-latex-recommended)",
)
# Characters the report itself writes into tables (arrows of metric names, marks, dashes, signs).
REPORT_CHARS = "↓↑†‡—–−∞±×·≤"


def _documented_preamble() -> str:
    text = (ROOT / "docs" / "latex.md").read_text(encoding="utf-8")
    block = re.search(r"```latex\n(.*?)```", text, re.S)
    assert block, "docs/latex.md has no ```latex block with the preamble"
    return block.group(1)


def _compile(tmp_path: Path, tables_tex: str) -> str:
    """Compile ``tables_tex`` in the documented minimal document; return the log (asserting rc 0)."""
    (tmp_path / "tables.tex").write_text(tables_tex, encoding="utf-8")
    doc = _documented_preamble()
    assert "\\input{tables}" in doc
    (tmp_path / "doc.tex").write_text(doc, encoding="utf-8")
    assert PDFLATEX is not None
    run = subprocess.run(
        [PDFLATEX, "-interaction=nonstopmode", "-halt-on-error", "doc.tex"],
        cwd=tmp_path,
        capture_output=True,
        timeout=300,
        check=False,
    )
    log = (tmp_path / "doc.log").read_text(encoding="latin-1")
    errors = [line for line in log.splitlines() if line.startswith("!")]
    assert run.returncode == 0, f"pdflatex failed: {errors[:5]}"
    return log


def _assert_clean(log: str) -> None:
    overfull = [float(w) for w in re.findall(r"Overfull \\hbox \(([0-9.]+)pt too wide\)", log)]
    assert not [w for w in overfull if w > 1.0], f"overfull boxes (pt): {overfull}"
    assert "Missing character" not in log
    assert "Float too large" not in log
    assert "Overfull \\vbox" not in log


# ------------------------------------------------------------------------------------------- mapping
@pytest.mark.parametrize(
    "text, expected",
    [
        ("C₀ + C₁", r"C\ensuremath{_{0}} + C\ensuremath{_{1}}"),
        ("xᵢ", r"x\ensuremath{_{i}}"),
        ("C₁₀", r"C\ensuremath{_{10}}"),
        ("10⁻⁴ m⁶", r"10\ensuremath{^{-4}} m\ensuremath{^{6}}"),
        ("r² s³", r"r\ensuremath{^{2}} s\ensuremath{^{3}}"),
        ("Mᵀ", r"M\ensuremath{^{\mathrm{T}}}"),
        ("L\u0304_sky", r"\={L}\_sky"),  # combining macron
        ("ȳ", r"\={y}"),  # precomposed y with macron
        ("α\u0304", r"\ensuremath{\bar{\alpha}}"),
        ("Šá", r"\v{S}\'{a}"),
        ("α = 5°", r"\ensuremath{\alpha} = 5\ensuremath{^\circ}"),
        ("θ λ Ω Δ", r"\ensuremath{\theta} \ensuremath{\lambda} \ensuremath{\Omega} \ensuremath{\Delta}"),
        ("2 × 3 · 4 − 1", r"2 \ensuremath{\times} 3 \ensuremath{\cdot} 4 \ensuremath{-} 1"),
        ("a ≤ b ≥ c ≈ d", r"a \ensuremath{\le} b \ensuremath{\ge} c \ensuremath{\approx} d"),
        (
            "x ∈ [0, ∞) → ½",
            r"x \ensuremath{\in} [0, \ensuremath{\infty}) \ensuremath{\to} \ensuremath{\frac{1}{2}}",
        ),
        ("§9.5 — a–b …", r"\S{}9.5 --- a--b \ldots{}"),
        ("ꟻLIP ★", r"FLIP \ensuremath{\star}"),
        (
            "50% & $5 #1 a_b {c} ~ ^ \\ < > |",
            r"50\% \& \$5 \#1 a\_b \{c\} \textasciitilde{} \textasciicircum{} "
            r"\textbackslash{} \textless{} \textgreater{} \textbar{}",
        ),
        ("RMSE ↓ † ‡", r"RMSE \ensuremath{\downarrow} \ensuremath{\dagger} \ensuremath{\ddagger}"),
        ("ﬁt", "fit"),  # compatibility decomposition to ASCII
        ("a\nb", "a b"),
    ],
)
def test_tex_text(text, expected):
    assert latex_text.tex_text(text) == expected


def test_unknown_character_falls_back():
    assert latex_text.tex_text("snow ☃") == r"snow [U+2603]\allowbreak{}"  # a line may break after it
    assert latex_text.tex_text("中☃") == r"[U+4E2D]\allowbreak{}[U+2603]\allowbreak{}"
    assert latex_text.tex_text("a\u0362b") == "ab"  # unknown combining mark: dropped, letters kept
    assert latex_text.tex_text("\\\u0304") == r"\textbackslash{}"  # accent over a special: dropped


def test_tex_number():
    assert latex_text.tex_number("9.264e-5") == r"\ensuremath{9.264\times 10^{-5}}"
    assert latex_text.tex_number("-1.5e+06") == r"\ensuremath{-1.5\times 10^{6}}"
    assert latex_text.tex_number("[-0.95, 0.95]") == r"[\ensuremath{-}0.95, 0.95]"
    assert latex_text.tex_number("—") == "---"


def test_tex_markdown():
    assert latex_text.tex_markdown("`r_a` and **bold** *it* [link](a(b)c) r_a") == (
        r"\texttt{r\_a} and \textbf{bold} \emph{it} link r\_a"
    )


def _non_ascii(obj, found: set[str]) -> None:
    if isinstance(obj, str):
        found |= {c for c in obj if ord(c) > 127}
    elif isinstance(obj, dict):
        for k, v in obj.items():
            _non_ascii(k, found)
            _non_ascii(v, found)
    elif isinstance(obj, list):
        for v in obj:
            _non_ascii(v, found)


def test_every_character_of_the_results_is_mapped():
    """Every non-ASCII character in the stored results (and in what the report adds) has a real
    mapping: ASCII LaTeX, not the [U+XXXX] fallback."""
    found: set[str] = set(REPORT_CHARS)
    for p in RESULTS:
        _non_ascii(json.loads(p.read_text(encoding="utf-8")), found)
    assert {"₀", "₁", "ᵢ", "⁴", "⁶", "\u0304", "°", "×", "−", "≤", "·", "²"} <= found
    for ch in sorted(found):
        out = latex_text.tex_text(("L" if unicodedata.combining(ch) else "") + ch)
        assert out.isascii() and "[U+" not in out, (ch, hex(ord(ch)), out)


@given(st.text(max_size=40))
def test_any_text_becomes_ascii_with_balanced_braces(text):
    out = latex_text.tex_text(text)
    assert out.isascii()
    depth = 0
    for m in re.finditer(r"\\.|[{}]", out):
        depth += {"{": 1, "}": -1}.get(m.group(0), 0)
        assert depth >= 0
    assert depth == 0


# ------------------------------------------------------------------------------------------- compile
@dataclass
class _Cell:
    text: str = ""
    sub: str = ""
    numeric: bool = False
    md: bool = False
    style: str = ""
    mark: str = ""


@dataclass
class _Table:
    anchor: str
    caption: str
    header: list
    rows: list
    notes: list = field(default_factory=list)
    tex_cols: list | None = None


def test_preamble_is_documented():
    doc = _documented_preamble()
    assert doc.startswith(latex.PREAMBLE)


@needs_pdflatex
@pytest.mark.parametrize("path", RESULTS, ids=[p.stem for p in RESULTS])
def test_tables_tex_compiles_and_fits(tmp_path, path):
    tex = render_report(json.loads(path.read_text(encoding="utf-8")))["tables.tex"]
    assert tex.isascii()
    assert "\\begin{table}" in tex or "\\begin{longtable}" in tex
    _assert_clean(_compile(tmp_path, tex))


@needs_pdflatex
def test_fallback_and_every_mapped_character_compile(tmp_path):
    """A table holding every mapped character, a sample of the whole BMP below the CJK block (mostly
    fallbacks) and unknown combining marks compiles without error or missing glyph."""
    mapped = "".join(sorted(latex_text.KNOWN_CHARACTERS))
    sample = "".join(chr(c) for c in range(0xA0, 0x3000, 37) if unicodedata.category(chr(c))[0] != "C")
    pieces = [mapped[i : i + 12] for i in range(0, len(mapped), 12)]
    pieces += [sample[i : i + 12] for i in range(0, len(sample), 12)]
    pieces += ["L\u0304 x\u0362y \u0301 ☃ 中"]
    pieces += [
        f"a{chr(c)} α{chr(c)} 1{chr(c)} &{chr(c)}" for c in range(0x300, 0x370)
    ]  # every combining mark
    rows = [[_Cell(p), _Cell("1.5e-3", sub="floor 2e-4", numeric=True, style="best")] for p in pieces]
    table = _Table(
        "table-x", "Every character ☃ ₀ L\u0304", [_Cell("Text"), _Cell("Value", numeric=True)], rows
    )
    tex = latex.render_tables("chars", [table])
    assert tex.isascii() and "[U+2603]" in tex
    _assert_clean(_compile(tmp_path, tex))


@needs_pdflatex
def test_wide_and_long_tables_are_split_and_broken(tmp_path):
    """Fourteen metric columns with long method names split into parts that fit; 120 rows become a
    longtable across pages."""
    header = [_Cell("Method")] + [
        _Cell(f"metric number {j} (a long header)", numeric=True) for j in range(14)
    ]
    rows = [
        [_Cell(f"approximation {i} with a rather long descriptive name, seed setting")]
        + [
            _Cell("-9.264e-5", sub="floor 9.325e-5", numeric=True, style="unresolved", mark="†")
            for _ in range(14)
        ]
        for i in range(120)
    ]
    tex = latex.render_tables("wide", [_Table("table-wide", "A wide table.", header, rows, ["† a note"])])
    assert "(part 1 of" in tex and "\\begin{longtable}" in tex
    for spec in re.findall(r"\\begin\{(?:tabular|longtable)\}\{(.*)\}\n", tex):
        widths = [float(w) for w in re.findall(r"p\{([0-9.]+)pt\}", spec)]
        assert sum(widths) + 2 * latex.TABCOLSEP_PT * len(widths) <= latex.TEXT_WIDTH_PT
    _assert_clean(_compile(tmp_path, tex))


@needs_pdflatex
def test_a_sentence_in_a_numeric_column_wraps(tmp_path):
    """A checks table's value column holds numbers and, in one row, a sentence with numbers in it (the
    nishita-sky disc-sun check): laid out as one unbreakable number it was 185 pt wider than the page;
    the column now wraps like text and the table fits (issue 32, the book's overfull boxes)."""
    sentence = ("Σ|point − disc| / Σ disc = 0.00583, low anti-solar sky 0.0184; 0.12 σ of this run's SS "
                "reference sum")  # fmt: skip
    header = [_Cell("Check"), _Cell("Value", numeric=True)]
    rows = [
        [_Cell("sun 45°: Σ quadrature / Σ Mitsuba SS (G)"), _Cell("0.9939", numeric=True)],
        [
            _Cell("sun −4°: the sun's disc vs a point sun in the SS quadrature (G)"),
            _Cell(sentence, numeric=True),
        ],
        [_Cell("solar spectrum: max relative difference"), _Cell("2.220e-16", numeric=True)],
    ]
    tex = latex.render_tables("checks", [_Table("table-checks", "Checks.", header, rows, [])])
    for spec in re.findall(r"\\begin\{(?:tabular|longtable)\}\{(.*)\}\n", tex):
        widths = [float(w) for w in re.findall(r"p\{([0-9.]+)pt\}", spec)]
        assert sum(widths) + 2 * latex.TABCOLSEP_PT * len(widths) <= latex.TEXT_WIDTH_PT
    assert "0.00583" in tex
    _assert_clean(_compile(tmp_path, tex))


def test_fits_table_split_keys_later_parts_by_fit():
    """height-fog's fits table is split; its second part holds the per-fit columns, one row per fit,
    without the Parameter column."""
    doc = json.loads((ROOT / "tests" / "data" / "results" / "height-fog.json").read_text(encoding="utf-8"))
    tex = render_report(doc)["tables.tex"]
    part = tex[tex.index(r"\label{tab:height-fog:fits:part2}") :]
    part = part[: part.index(r"\end{")]
    lines = [line.strip() for line in part.splitlines()]
    headers = {line for line in lines if line.startswith("Fit &")}
    assert headers == {r"Fit & RMS residual & Residuals & Converged \\"}
    rows = [line for line in lines if line.endswith("\\\\") and " & " in line and line not in headers]
    assert len(rows) == len(doc["fits"])


# ------------------------------------------------------------------------- bold and italic maths
def _one_value_table(style: str) -> latex.TexTable:
    """A one-column table whose only value, 4.458e-4, is set in ``style`` (its ×10ⁿ is maths)."""
    return latex.TexTable(
        anchor="table-style",
        caption="",
        header=[latex.TexCell("value", numeric=True)],
        rows=[[latex.TexCell("4.458e-4", numeric=True, style=style)]],
    )


def test_best_and_unresolved_values_mark_their_maths():
    """``\\textbf``/``\\textit`` do not reach into ``\\ensuremath``: a best value written with ×10ⁿ
    must switch the maths to bold (``\\boldmath``), an unresolved one set its maths in ``\\mathit``."""
    bold = latex.render_table("x", _one_value_table("best"))
    assert r"\textbf{\boldmath \ensuremath{4.458\times 10^{-4}}}" in bold
    italic = latex.render_table("x", _one_value_table("unresolved"))
    assert r"\textit{\ensuremath{\mathit{4.458\times 10^{-4}}}}" in italic
    plain = latex.render_table("x", _one_value_table(""))
    assert r"\boldmath" not in plain and r"\mathit" not in plain
    assert latex_text.tex_number("4.458e-4", italic=True) == r"\ensuremath{\mathit{4.458\times 10^{-4}}}"


@needs_pdflatex
@pytest.mark.parametrize("style, font", [("best", "cmbx"), ("unresolved", "cmti"), ("", None)])
def test_marked_values_compile_in_their_font(tmp_path, style, font):
    """Compiled, the value's digits come from the bold (cmbx) or text-italic (cmti) font: pdflatex's
    log lists every Type 1 font it embedded. An unmarked value uses neither."""
    log = _compile(tmp_path, latex.render_table("x", _one_value_table(style)))
    _assert_clean(log)
    embedded = set(re.findall(r"/(cm[a-z]+)\d+\.pfb", log))
    marks = {"cmbx", "cmti"}
    assert embedded & marks == ({font} if font else set()), embedded


def test_ascii_fast_path_is_the_character_loop_on_every_pair():
    """`tex_text` translates an ASCII string character by character (`_ASCII_CODES`): the same as the full
    loop (`_tex_chars`) on every pair of ASCII characters (specials, controls and DEL included)."""
    for a in range(128):
        for b in range(128):
            s = chr(a) + chr(b)
            assert latex_text.tex_text(s) == latex_text._tex_chars(s), repr(s)


@given(st.text(alphabet=st.characters(max_codepoint=127), max_size=60))
def test_ascii_fast_path_is_the_character_loop(text):
    assert latex_text.tex_text(text) == latex_text._tex_chars(unicodedata.normalize("NFD", text))
