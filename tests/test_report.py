"""Report generator and atomic writes: synthetic results only (no Mitsuba), fast."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.atomic import (
    NonFiniteJSONError,
    atomic_directory,
    atomic_write_json,
    atomic_write_text,
    is_temporary_name,
)
from rtfit.experiments.report import ResultsError, load_results, render_report, write_report
from rtfit.experiments.report_doc import UNRESOLVED_NOTE
from rtfit.experiments.report_index import INDEX_UNRESOLVED_NOTE, write_index
from rtfit.experiments.report_text import format_number, markdown_inline, markdown_to_html
from rtfit.experiments.results import write_results


def _metric(value, floor, resolved=True):
    return {"value": value, "noise_floor": floor, "resolved": resolved, "debiased": value}


def _results() -> dict:
    return {
        "schema": "rtfit.results/1",
        "experiment": "half-lambert",
        "title": "Half-Lambert & wrap <lighting>",
        "summary": (
            "We measured **irradiance** near the terminator; see `w(α)` and $E = \\pi L$."
            "\n\nSecond paragraph."
        ),
        "created": "2026-11-23T10:00:00Z",
        "config": {
            "quick": True,
            "variant": "llvm_ad_rgb",
            "spp": 256,
            "resolution": [128, 128],
            "alphas_deg": [5.0, 30.0],
        },
        "versions": {"rtfit": "0.1.0", "mitsuba": "3.9.1", "jax": None, "python": "3.11.7"},
        "device": "CPU (LLVM backend, 2 threads): Test CPU",
        "sections": [
            {
                "id": "method",
                "title": "Method",
                "text": "A sphere.\n\n- one **bold** item\n- a [link](fitted/wrap.json)",
            }
        ],
        "cases": [
            {
                "id": "a05-sky0",
                "label": "α = 5°, no sky",
                "parameters": {"alpha_deg": 5.0, "sky_radiance": 0.0},
                "scene": {"name": "half-lambert-sphere", "hash": "ab" * 32},
                "reference": {
                    "integrator": "direct",
                    "max_depth": 2,
                    "spp": 256,
                    "passes": 4,
                    "cache_key": "cd" * 32,
                    "mean_rel_stderr": 0.004,
                    "samples_per_second": 1.2e7,
                },
                "approximations": [
                    {
                        "method": "half-lambert",
                        "label": "Half-Lambert",
                        "fitted": False,
                        "parameters": {"w": 1.0, "p": 2.0},
                        "metrics": {
                            "rmse": _metric(0.0123, 0.001),
                            "psnr": _metric(38.2, 60.0),
                            "smape": _metric(0.5, 0.01),
                        },
                        "cost": {"ns_per_pixel": 0.8, "pixels_per_second": 1.2e9, "backend": "llvm"},
                        "figures": ["figures/case.png"],
                    },
                    {
                        "method": "exact",
                        "label": "Exact",
                        "fitted": False,
                        "parameters": {},
                        "metrics": {
                            "rmse": _metric(0.00091, 0.001, resolved=False),
                            "psnr": _metric(61.0, 60.0, False),
                        },
                        "cost": None,
                    },
                ],
            },
            {
                "id": "a30-sky0",
                "label": "α = 30°, sky radiance 0.2",
                "parameters": {"alpha_deg": 30.0},
                "approximations": [
                    {
                        "method": "half-lambert",
                        "label": "Half-Lambert",
                        "metrics": {"rmse": _metric(0.05, 0.001)},
                    },
                    {"method": "exact", "label": "Exact", "metrics": {"rmse": _metric(0.0011, 0.001)}},
                ],
            },
        ],
        "fits": [
            {
                "id": "wrap-w",
                "label": "w(α) for wrap lighting",
                "model": "w(α) = c1·sin α + c2·sin² α",
                "parameters": {
                    "c1": {"value": 1.0, "stderr": 0.01, "lower": 0.0, "upper": 2.0, "at_bound": False},
                    "c2": {"value": 2.0, "stderr": 1e-5, "lower": 0.0, "upper": 2.0, "at_bound": True},
                },
                "rms_residual": 0.001,
                "n_residuals": 1000,
                "converged": True,
                "file": "fitted/wrap.json",
            }
        ],
        "figures": [
            {
                "file": "figures/terminator.png",
                "caption": "Irradiance across the *terminator*.",
                "section": "results",
            },
            {"file": "figures/pareto.png", "caption": "Error vs cost.", "section": "costs"},
        ],
        "costs": [
            {
                "method": "half-lambert",
                "label": "Half-Lambert",
                "ns_per_pixel": 0.8,
                "backend": "llvm",
                "note": "inputs in memory",
            }
        ],
        "checks": [
            {"name": "z spread", "value": 1.01, "expected": "1 ± 0.05", "passed": True},
            {"name": "mean z", "value": 0.3, "expected": "0 ± 0.1", "passed": False},
        ],
        "notes": ["Radiance is relative to the lit peak (`E⊥ = π`)."],
        "unknown_extra_key": {"ignored": True},
    }


def _png(path: Path):
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1, 1), dpi=16)
    ax.plot([0, 1], [0, 1])
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buf.getvalue())


@pytest.fixture()
def exp_dir(tmp_path) -> Path:
    d = tmp_path / "out" / "half-lambert"
    for name in ("terminator.png", "pareto.png", "case.png"):
        _png(d / "figures" / name)
    (d / "results.json").write_text(json.dumps(_results(), ensure_ascii=False, indent=1), encoding="utf-8")
    return d


# --------------------------------------------------------------------------------------------- numbers
@pytest.mark.parametrize(
    "x, text",
    [
        (0.0123, "0.01230"),
        (0.001, "0.001000"),
        (0.00091, "9.100e-4"),
        (1.2e7, "1.200e7"),
        (123456.0, "1.235e5"),
        (12345.67, "12350"),
        (99999.5, "1.000e5"),
        (9.99996, "10.00"),
        (-0.5, "-0.5000"),
        (0.0, "0"),
        (38.2, "38.20"),
        (1000, "1000"),
        (True, "yes"),
        (None, "—"),
        ("1 ± 0.05", "1 ± 0.05"),
    ],
)
def test_format_number(x, text):
    assert format_number(x) == text


def test_format_number_trim():
    assert format_number(5.0, trim=True) == "5"
    assert format_number(0.25, trim=True) == "0.25"
    assert format_number([128, 128]) == "128, 128"


# --------------------------------------------------------------------------------------------- report
def test_write_report(exp_dir):
    paths = write_report(exp_dir)
    assert [p.name for p in paths] == ["report.md", "report.html", "tables.tex"]
    assert all(p.is_file() for p in paths)
    page = (exp_dir / "report.html").read_text(encoding="utf-8")
    md = (exp_dir / "report.md").read_text(encoding="utf-8")
    tex = (exp_dir / "tables.tex").read_text(encoding="utf-8")

    # Text is escaped; case labels and sections appear; contents list present.
    assert "Half-Lambert &amp; wrap &lt;lighting&gt;" in page and "<lighting>" not in page
    for label in ("α = 5°, no sky", "α = 30°, sky radiance 0.2"):
        assert label in page and label in md
    assert '<nav class="toc">' in page and 'href="#case-a05-sky0"' in page
    assert "<strong>irradiance</strong>" in page and "<code>w(α)</code>" in page
    assert '<span class="math">$E = \\pi L$</span>' in page

    # Metric values with their noise floor, 4 significant digits.
    assert '0.01230 <span class="sub">(floor 0.001000)</span>' in page
    assert "| Exact | **0.001100** (floor 0.001000) |" in md  # the best value in bold
    assert "| Half-Lambert | 0.05000 (floor 0.001000) |" in md
    assert "# Half-Lambert & wrap \\<lighting\\>" in md  # markdown would swallow <lighting> as a tag
    assert "38.20" in page and "0.5000" in page  # generic metric key (smape) rendered too
    assert "smape" in page

    # The smallest RMSE (Exact's, not resolved) is bold and tagged, with its † and footnote; the larger
    # resolved Half-Lambert value is not bold.
    assert re.search(
        r'class="num best"[^>]*>9\.100e-4 <span class="tag">within noise</span> '
        r'<span class="sub">\(floor 0\.001000\)</span><span class="mark">†</span>',
        page,
    )
    assert "**9.100e-4** within noise (floor 0.001000)†" in md
    assert "| Half-Lambert | 0.01230 (floor 0.001000) |" in md
    assert "within 2× the reference's noise floor" in md and "within 2× the reference's noise floor" in page
    assert "below the" not in md.lower() and "below the" not in page.lower()

    # Figures: numbered in document order (per-case figure first, then the results and cost figures).
    captions = re.findall(r"<figcaption><b>Figure (\d+):</b> (.*?)</figcaption>", page)
    assert [n for n, _ in captions] == ["1", "2", "3"]
    assert "Irradiance across the <em>terminator</em>." in captions[1][1]
    assert captions[2][1].startswith("Error vs cost.")
    assert (
        page.index('src="figures/terminator.png"')
        < page.index('id="costs"')
        < page.index('src="figures/pareto.png"')
    )
    assert "**Figure 2:** Irradiance across the *terminator*." in md
    assert "missing" not in " ".join(c for _, c in captions)

    # Fits (± stderr, at-bound marked), checks (pass/fail), cost, notes.
    assert "1.000 ± 0.01000" in page
    assert re.search(r'class="num at-bound">2\.000 ± 1\.000e-5<span class="mark">‡</span>', page)
    assert '<td class="pass">pass</td>' in page and '<td class="fail">FAIL</td>' in page
    assert "1 of 2 checks FAILED" in page
    assert 'href="fitted/wrap.json"' in page
    assert "Radiance is relative to the lit peak" in page

    # LaTeX: balanced environments, booktabs rules, escaped text, metrics tables per case.
    for env in ("tabular", "table"):
        assert tex.count(f"\\begin{{{env}}}") == tex.count(f"\\end{{{env}}}") > 0
    assert (
        tex.count("\\toprule")
        == tex.count("\\midrule")
        == tex.count("\\bottomrule")
        == tex.count("\\begin{tabular}")
    )
    assert "\\label{tab:half-lambert:case-a05-sky0}" in tex
    assert "\\ensuremath{9.100\\times 10^{-4}}" in tex
    assert "\\ensuremath{\\alpha} = 5\\ensuremath{^\\circ}" in tex
    assert "\\textbf{\\boldmath \\ensuremath{9.100\\times 10^{-4}}" in tex and "\\ensuremath{\\dagger}" in tex
    for line in tex.splitlines():  # every table row has as many cells as its tabular has columns
        if line.strip().endswith("\\\\") and " & " in line:
            spec = re.findall(r"\\begin\{(?:tabular|longtable)\}\{(.*)\}$", tex[: tex.index(line)], re.M)[-1]
            assert line.count(" & ") == spec.count("p{") - 1, line


def test_report_is_deterministic_and_regenerates(exp_dir):
    first = {p.name: p.read_bytes() for p in write_report(exp_dir)}
    second = {p.name: p.read_bytes() for p in write_report(exp_dir)}
    assert first == second
    assert not [p for p in exp_dir.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_minimal_results_render(tmp_path):
    r = _results()
    for key in ("sections", "fits", "figures", "costs", "checks", "notes"):
        del r[key]
    r["cases"] = [
        {
            "id": "only",
            "label": "Only case",
            "approximations": [{"method": "m", "metrics": {"rmse": {"value": 0.2, "noise_floor": None}}}],
        }
    ]
    (tmp_path / "results.json").write_text(json.dumps(r), encoding="utf-8")
    write_report(tmp_path)
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "Only case" in page and '0.2000 <span class="sub">(floor —)</span>' in page
    r["cases"] = []
    texts = render_report(r)
    assert "No cases were evaluated." in texts["report.html"]
    assert "\\begin{tabular}" not in texts["tables.tex"]


def test_missing_figure_is_flagged(exp_dir):
    (exp_dir / "figures" / "pareto.png").unlink()
    write_report(exp_dir)
    assert "(missing: figures/pareto.png)" in (exp_dir / "report.html").read_text(encoding="utf-8")


def test_rtfit_report_says_when_figure_files_are_gone(capsys, exp_dir):
    """issue 32: ``rtfit report`` on a folder whose figures/ was deleted exited 0 without a word; now one
    warning line names the missing files (the page still marks each one), and a complete folder none."""
    import shutil

    from rtfit.experiments.cli import main

    assert main(["report", str(exp_dir)]) == 0
    assert capsys.readouterr().err == ""
    shutil.rmtree(exp_dir / "figures")
    assert main(["report", str(exp_dir)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rtfit: warning: "), err
    assert "3 figure file(s) named in results.json are missing" in err[0] and "figures/pareto.png" in err[0]
    assert "(missing: figures/pareto.png)" in (exp_dir / "report.html").read_text(encoding="utf-8")


def test_a_case_composite_shared_by_every_approximation_is_shown_once(tmp_path):
    """figures.case_comparison points every approximation of a case at one composite PNG and also returns a
    figure record for it (height-fog, light-cones, …): the page shows that image once, under the case's
    table, with the record's caption (issue 32: height-fog's report showed each composite 7 times)."""
    r = _results()
    case = r["cases"][0]
    for ap in case["approximations"]:
        ap["figures"] = ["figures/case.png"]
    own = {"file": "figures/case.png", "caption": "Composite of case a05.", "section": "results"}
    r["figures"].append(own)
    texts = render_report(r)
    page, md = texts["report.html"], texts["report.md"]
    assert page.count('src="figures/case.png"') == 1 and md.count("(figures/case.png)") == 1
    assert "Composite of case a05." in page
    # The image sits under the case's table, before the next case's heading.
    assert (
        page.index('id="table-case-a05-sky0"')
        < page.index('src="figures/case.png"')
        < page.index(f'id="case-{r["cases"][1]["id"]}"')
    )
    # Two files in one case: each once, labelled with the approximations showing it.
    case["approximations"][1]["figures"] = ["figures/terminator.png"]
    page = render_report(r)["report.html"]
    assert page.count('src="figures/case.png"') == 1 and page.count('src="figures/terminator.png"') == 1


def test_wide_tables_scroll_inside_the_column_with_their_caption_outside():
    """Issue 32: per-case tables 1,800+ px wide in a 944 px column. Every table of the page (metric tables
    and pipe tables of the markdown) is the only child of a ``div.table-wrap`` that scrolls sideways
    (``overflow-x: auto``); the caption and notes are outside that box, so they wrap at the column's width."""
    from html.parser import HTMLParser

    r = _results()
    many = {f"m{i}": _metric(0.01 * (i + 1), 0.001) for i in range(12)}  # 12 metric columns: wide
    for ap in r["cases"][0]["approximations"]:
        ap["metrics"] = {**ap["metrics"], **many}
    r["sections"][0]["text"] += "\n\n| a | b |\n|---|---|\n| 1 | 2 |\n"
    page = render_report(r)["report.html"]

    class Tables(HTMLParser):
        def __init__(self):
            super().__init__()
            self.stack: list[tuple[str, str]] = []
            self.parents: list[str] = []
            self.captions_in_wrap = 0

        def handle_starttag(self, tag, attrs):
            cls = dict(attrs).get("class") or ""
            if tag == "table":
                self.parents.append(self.stack[-1][1] if self.stack else "")
            if cls == "table-caption" and any(c == "table-wrap" for _, c in self.stack):
                self.captions_in_wrap += 1
            if tag not in ("br", "img", "meta", "link", "hr", "input"):
                self.stack.append((tag, cls))

        def handle_endtag(self, tag):
            while self.stack and self.stack.pop()[0] != tag:
                pass

    p = Tables()
    p.feed(page)
    assert len(p.parents) >= 4 and set(p.parents) == {"table-wrap"}, p.parents
    assert p.captions_in_wrap == 0 and page.count('class="table-caption"') >= 3
    assert "<caption>" not in page
    css = re.search(r"\.table-wrap \{([^}]*)\}", page)
    assert css is not None and "overflow-x: auto" in css.group(1) and "max-width: 100%" in css.group(1)
    assert 'id="table-case-a05-sky0"' in page  # the anchors that the contents and links use are kept


# ------------------------------------------------------------------------------------------- errors
def test_nan_in_results_is_an_error_and_nothing_is_written(exp_dir):
    r = _results()
    r["cases"][0]["approximations"][1]["metrics"]["rmse"]["value"] = math.nan
    (exp_dir / "results.json").write_text(json.dumps(r), encoding="utf-8")  # json.dumps writes NaN
    with pytest.raises(ResultsError) as e:
        write_report(exp_dir)
    msg = str(e.value)
    assert "\n" not in msg and "results.json" in msg and "NaN" in msg
    assert "cases[0].approximations[1].metrics.rmse.value" in msg
    assert not any((exp_dir / n).exists() for n in ("report.md", "report.html", "tables.tex"))


def test_atomic_write_json_refuses_nan(tmp_path):
    target = tmp_path / "results.json"
    atomic_write_json(target, {"ok": 1})
    with pytest.raises(NonFiniteJSONError) as e:
        atomic_write_json(target, {"cases": [{"rmse": math.inf}]})
    assert isinstance(e.value, ValueError)
    assert "$.cases[0].rmse" in str(e.value) and "results.json" in str(e.value)
    assert json.loads(target.read_text()) == {"ok": 1}  # old content untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]


def test_atomic_write_roundtrip_and_numpy(tmp_path):
    import numpy as np

    p = atomic_write_json(tmp_path / "sub" / "x.json", {"a": np.float32(0.5), "b": np.arange(3), "c": "π"})
    assert json.loads(p.read_text(encoding="utf-8")) == {"a": 0.5, "b": [0, 1, 2], "c": "π"}
    with pytest.raises(NonFiniteJSONError):
        atomic_write_json(tmp_path / "y.json", {"a": np.array([1.0, np.nan])})
    assert not (tmp_path / "y.json").exists()
    atomic_write_text(tmp_path / "t.txt", "héllo")
    assert (tmp_path / "t.txt").read_text(encoding="utf-8") == "héllo"
    assert (
        tmp_path / "t.txt"
    ).stat().st_mode & 0o044  # readable by others (umask permitting), unlike mkstemp


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_atomic_directory_keeps_old_directory_when_body_raises(tmp_path, exc):
    final = tmp_path / "half-lambert"
    final.mkdir()
    (final / "old.txt").write_text("old")
    with pytest.raises(exc):
        with atomic_directory(final) as tmp:
            assert tmp.is_dir() and tmp.parent == tmp_path and is_temporary_name(tmp.name)
            (tmp / "new.txt").write_text("new")
            raise exc("boom")
    assert [p.name for p in final.iterdir()] == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half-lambert"]  # temporary directory removed


def test_atomic_directory_replaces_on_success(tmp_path):
    final = tmp_path / "exp"
    with atomic_directory(final) as tmp:  # no previous directory
        (tmp / "a.txt").write_text("1")
    assert (final / "a.txt").read_text() == "1"
    with atomic_directory(final) as tmp:
        assert not any(tmp.iterdir())
        (tmp / "b.txt").write_text("2")
    assert [p.name for p in final.iterdir()] == ["b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp"]  # old directory deleted


def test_load_results_rejects_wrong_schema(exp_dir):
    r = _results()
    r["schema"] = "rtfit.results/0"
    (exp_dir / "results.json").write_text(json.dumps(r), encoding="utf-8")
    with pytest.raises(ResultsError) as e:
        load_results(exp_dir)
    msg = str(e.value)
    assert (
        "\n" not in msg
        and str(exp_dir / "results.json") in msg
        and "schema" in msg
        and "rtfit.results/0" in msg
    )


@pytest.mark.parametrize(
    "mutate, where",
    [
        (lambda r: r.pop("title"), "title: missing required key"),
        (lambda r: r["cases"][1].pop("approximations"), "cases[1].approximations: missing required key"),
        (
            lambda r: r["cases"][0]["approximations"][0]["metrics"].update(rmse=0.1),
            "cases[0].approximations[0].metrics.rmse",
        ),
        (
            lambda r: r.update(checks=[{"name": "x", "passed": "yes"}]),
            "checks[0].passed: expected true or false",
        ),
        (
            lambda r: r.update(figures=[{"file": "../secret.png"}]),
            "figures[0].file: expected a relative path",
        ),
        (lambda r: r.update(notes="not a list"), "notes: expected a list"),
    ],
)
def test_load_results_names_the_key(exp_dir, mutate, where):
    r = copy.deepcopy(_results())
    mutate(r)
    (exp_dir / "results.json").write_text(json.dumps(r), encoding="utf-8")
    with pytest.raises(ResultsError, match=re.escape(where)) as e:
        load_results(exp_dir)
    assert "\n" not in str(e.value)


def test_load_results_missing_and_invalid(tmp_path):
    with pytest.raises(ResultsError, match="not found"):
        load_results(tmp_path)
    (tmp_path / "results.json").write_text("{", encoding="utf-8")
    with pytest.raises(ResultsError, match="invalid JSON"):
        load_results(tmp_path)


# ----------------------------------------------------------------------------------------- markdown
def test_markdown_inline_commonmark():
    assert markdown_inline("a <b> & **bold** *it* `x<y` [l](https://e.org/?a=1&b=2)") == (
        "a &lt;b&gt; &amp; <strong>bold</strong> <em>it</em> <code>x&lt;y</code> "
        '<a href="https://e.org/?a=1&amp;b=2">l</a>'
    )
    for bad in ("[x](javascript:alert(1))", "[x](javascript:alert)", "[x](vbscript:y)"):
        assert "<a" not in markdown_inline(bad)
    assert markdown_inline("$a*b*c$ and 2 * 3 * 4") == '<span class="math">$a*b*c$</span> and 2 * 3 * 4'
    assert markdown_inline(r"\*not italic\* and \$5") == "*not italic* and $5"
    assert markdown_inline("<https://e.org/x>") == '<a href="https://e.org/x">https://e.org/x</a>'


def test_markdown_blocks():
    out = markdown_to_html(
        "# Title\n\nPara line one\nline two.\n\n- item **1**\n  - nested *a*\n  - nested b\n- item 2\n\n"
        "1. first\n2. second\n\n```\nx < y\n```"
    )
    assert out.startswith("<h3>Title</h3>\n<p>Para line one\nline two.</p>")  # # shifted by 2
    flat = out.replace("\n", "")
    assert (
        "<ul><li>item <strong>1</strong><ul><li>nested <em>a</em></li><li>nested b</li></ul></li>"
        "<li>item 2</li></ul>"
    ) in flat
    assert "<ol><li>first</li><li>second</li></ol>" in flat
    assert "<pre><code>x &lt; y</code></pre>" in flat
    assert markdown_to_html("#### deep", heading_offset=3) == "<h6>deep</h6>"  # at most h6


def test_markdown_pipe_table_and_url_with_parentheses():
    out = markdown_to_html(
        "Worst error:\n\n| form | error | note |\n|---|--:|---|\n| stable | 3.79e-06 | a \\| b |\n"
        "| seed | ∞ | *x* |\n\nSee [fog](https://en.wikipedia.org/wiki/Fog_(disambiguation)) and "
        "[HG](https://e.org/a_(b)_c)."
    )
    flat = out.replace("\n", "")
    assert '<div class="table-wrap"><table><thead><tr><th>form</th><th style="text-align:right">error' in flat
    assert '<tr><td>stable</td><td style="text-align:right">3.79e-06</td><td>a | b</td></tr>' in flat
    assert "<td><em>x</em></td>" in flat and "|---|" not in out
    assert '<a href="https://en.wikipedia.org/wiki/Fog_(disambiguation)">fog</a>' in out
    assert '<a href="https://e.org/a_(b)_c">HG</a>.' in out


def test_raw_html_in_results_text_is_escaped(exp_dir):
    r = _results()
    r["sections"][0]["text"] = (
        "Before <script>alert('x')</script> after.\n\n<div onclick=\"x()\">block html</div>\n\n"
        "| a | b |\n|---|---|\n| <img src=x onerror=y> | 2 |"
    )
    r["summary"] = "Summary with <iframe src=evil></iframe>."
    (exp_dir / "results.json").write_text(json.dumps(r), encoding="utf-8")
    write_report(exp_dir)
    page = (exp_dir / "report.html").read_text(encoding="utf-8")
    for tag in ("<script", "<div onclick", "<img src=x", "<iframe"):
        assert tag not in page
    assert "&lt;script&gt;alert('x')&lt;/script&gt;" in page
    assert "&lt;div onclick=&quot;x()&quot;&gt;block html&lt;/div&gt;" in page
    assert "<td>&lt;img src=x onerror=y&gt;</td>" in page  # the section's pipe table is a table


def test_plain_text_survives_markdown(tmp_path):
    """Plain-text fields (titles, labels) are escaped for markdown and read back unchanged."""
    r = _results()
    r["title"] = "a*b*c_d_ [x](y) `z` $m$ &amp; <t> | ~s~ \\"
    texts = render_report(r)
    assert "<title>a*b*c_d_ [x](y) `z` $m$ &amp;amp; &lt;t&gt; | ~s~ \\</title>" in texts["report.html"]
    md_title = texts["report.md"].splitlines()[0].removeprefix("# ")
    assert markdown_inline(md_title) == "a*b*c_d_ [x](y) `z` $m$ &amp;amp; &lt;t&gt; | ~s~ \\"


# ------------------------------------------------------------------------------------------ bold rule
def _one_case(key, entries):
    """Results with one case whose approximations have ``key`` metrics ``(value, floor, resolved)``."""
    r = _results()
    r["cases"] = [
        {
            "id": "c",
            "label": "C",
            "approximations": [
                {"method": f"m{i}", "label": f"M{i}", "metrics": {key: _metric(v, f, res)}}
                for i, (v, f, res) in enumerate(entries)
            ],
        }
    ]
    return render_report(r)


def _md_row(md, label):
    return next(line for line in md.splitlines() if line.startswith(f"| {label} |"))


def test_bold_is_the_smallest_value_even_when_not_resolved():
    # diffuse's α = 0.27° row: Half-Lambert 0.132 (resolved) vs Lambert 9.3e-5 (below 2× its floor).
    t = _one_case("rmse", [(0.132, 9.325e-5, True), (9.3e-5, 9.325e-5, False), (2.0e-4, 9.325e-5, False)])
    md, page, tex = t["report.md"], t["report.html"], t["tables.tex"]
    assert _md_row(md, "M0") == "| M0 | 0.1320 (floor 9.325e-5) | — |"
    assert _md_row(md, "M1") == "| M1 | **9.300e-5** within noise (floor 9.325e-5)† | — |"
    assert _md_row(md, "M2") == "| M2 | *2.000e-4 (floor 9.325e-5)*† | — |"
    assert '<td class="num">0.1320 ' in page
    assert '<td class="num best" title="not resolved' in page and '9.300e-5 <span class="tag">' in page
    assert page.count('class="num best"') == 1
    tex_rows = {line.split(" & ")[0].strip(): line for line in tex.splitlines() if " & " in line}
    assert "\\textbf{\\boldmath \\ensuremath{9.300\\times 10^{-5}}}\\ensuremath{\\dagger}" in tex_rows["M1"]
    assert "\\textbf" not in tex_rows["M0"] and "\\textbf" not in tex_rows["M2"]


def test_bold_resolved_best_has_no_tag_and_higher_is_better():
    md = _one_case("rmse", [(0.05, 0.001, True), (0.01, 0.001, True)])["report.md"]
    assert _md_row(md, "M1") == "| M1 | **0.01000** (floor 0.001000) | — |" and "within noise (" not in md
    assert _md_row(md, "M0") == "| M0 | 0.05000 (floor 0.001000) | — |"
    md = _one_case("psnr", [(38.2, 60.0, True), (61.0, 60.0, False)])["report.md"]
    assert _md_row(md, "M1") == "| M1 | **61.00** within noise (floor 60.00)† | — |"
    assert _md_row(md, "M0") == "| M0 | 38.20 (floor 60.00) | — |"


def test_bold_ties_at_the_printed_precision():
    entries = [(9.2641e-5, 1e-4, False), (9.2638e-5, 1e-4, False), (0.1, 1e-4, True)]
    md = _one_case("rmse", entries)["report.md"]
    assert _md_row(md, "M0").startswith("| M0 | **9.264e-5** within noise")
    assert _md_row(md, "M1").startswith("| M1 | **9.264e-5** within noise")
    assert _md_row(md, "M2") == "| M2 | 0.1000 (floor 1.000e-4) | — |"


# -------------------------------------------------------------------------------------------- index
def test_write_index(exp_dir):
    out = exp_dir.parent
    write_report(exp_dir)
    broken = out / "broken"
    broken.mkdir()
    (broken / "results.json").write_text('{"schema": "other"}', encoding="utf-8")
    stale = out / ".half-lambert.0123456789ab.tmp"
    stale.mkdir()
    paths = write_index(out, [exp_dir, broken, stale])
    assert [p.name for p in paths] == ["index.html", "index.md"]
    page = (out / "index.html").read_text(encoding="utf-8")
    md = (out / "index.md").read_text(encoding="utf-8")
    assert 'href="half-lambert/report.html"' in page and "(half-lambert/report.html)" in md
    assert "Half-Lambert &amp; wrap &lt;lighting&gt;" in page
    assert "<strong>irradiance</strong>" in page and "Second paragraph" not in page  # first paragraph only
    assert "1/2 passed" in page and '<span class="fail">' in page
    assert "0.03115 (floor 0.001000)" in page  # mean RMSE of Half-Lambert over the two cases
    assert "broken" in page and "schema" in page
    assert ".tmp" not in page


DATA = Path(__file__).parent / "data" / "results"


def _index_rows(md: str) -> dict[str, list[str]]:
    """The index's per-approximation rows: label -> [mean metric cell, ns/pixel cell]."""
    rows = {}
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) == 3 and cells[0] != "Approximation":
            rows[cells[0]] = cells[1:]
    return rows


def test_index_cost_and_resolve_marker_on_height_fog(tmp_path):
    doc = json.loads((DATA / "height-fog.json").read_text(encoding="utf-8"))
    d = tmp_path / "height-fog"
    d.mkdir()
    (d / "results.json").write_text(json.dumps(doc), encoding="utf-8")
    write_index(tmp_path, [d])
    md = (tmp_path / "index.md").read_text(encoding="utf-8")
    page = (tmp_path / "index.html").read_text(encoding="utf-8")
    rows = _index_rows(md)

    # Costs are timed under their own ids (tau-exact, fog-pass-const, …), none an approximation's:
    # the index takes each approximation's own measured cost, the mean over its cases.
    aps = [ap for c in doc["cases"] for ap in c["approximations"]]
    assert not {c["method"] for c in doc["costs"]} & {ap["method"] for ap in aps}
    labels = {ap["method"]: ap["label"] for ap in aps}
    assert len(labels) == 5 and all(ap["cost"]["ns_per_pixel"] > 0 for ap in aps)
    for method, label in labels.items():
        ns = [ap["cost"]["ns_per_pixel"] for ap in aps if ap["method"] == method]
        shown = rows[label.replace("_", "\\_")][1]
        assert shown != "—" and float(shown) == pytest.approx(sum(ns) / len(ns), rel=5e-4)

    # fit-phase is unresolved in all three cases although its mean RMSE is 1.4x the mean floor: the
    # marker says "not resolved" (the 2x rule), never "≤ floor".
    vals = [ap["metrics"]["rmse"] for ap in aps if ap["method"] == "fit-phase"]
    assert [v["resolved"] for v in vals] == [False] * 3
    mean = sum(v["value"] for v in vals) / 3
    floor = sum(v["noise_floor"] for v in vals) / 3
    assert 1.0 < mean / floor < 2.0
    cell = rows[labels["fit-phase"]][0]
    assert cell.endswith(" not resolved†") and float(cell.split()[0]) == pytest.approx(mean, rel=5e-4)
    assert sum(r[0].endswith("not resolved†") for r in rows.values()) == 1  # others resolved somewhere
    for text in (md, page):
        assert "≤ floor" not in text and "within 2× the reference" in text


def test_unresolved_marker_text_states_the_rule_it_applies():
    """The † rule of `rtfit.fitting.metrics` and every text that describes it agree: an error is
    unresolved up to 2× its noise floor (4× for the squared relMSE, 6.02 dB for PSNR), so a value at
    1.5× its floor is marked although it lies *above* the floor: no text may call it "below"."""
    from rtfit.fitting import compute_metrics

    rng = np.random.default_rng(3)
    ref = rng.uniform(0.5, 1.0, (32, 32, 3))
    sigma = np.full_like(ref, 1e-3)
    names = ("rmse", "rel_mse", "psnr")
    for k, resolved in ((1.5, False), (1.99, False), (2.01, True), (3.0, True)):
        # A constant offset k·σ: RMSE = k·σ and floor σ exactly; relMSE and PSNR square both sides.
        res = compute_metrics(ref + k * 1e-3, ref, sigma, names=names)
        assert res["rmse"].value / res["rmse"].noise_floor == pytest.approx(k, rel=1e-9)
        assert res["rmse"].resolved is resolved and res["rel_mse"].resolved is resolved
        assert res["psnr"].resolved is resolved
        assert (res["psnr"].noise_floor - res["psnr"].value > 20 * math.log10(2)) is resolved
    factor = re.findall(r"within (\d+)× the reference's noise floor", UNRESOLVED_NOTE + INDEX_UNRESOLVED_NOTE)
    assert factor == ["2", "2"]
    assert "(4× for the squared relMSE" in UNRESOLVED_NOTE and "6.02 dB" in UNRESOLVED_NOTE
    docs = Path(__file__).resolve().parent.parent / "docs"
    for page in docs.glob("*.md"):
        text = page.read_text(encoding="utf-8").lower()
        for wrong in ("below the noise floor", "below its noise floor", "≤ floor"):
            assert wrong not in text, f"{page.name} describes the † rule as {wrong!r}"


# ------------------------------------------------------------------------- pipe tables: "|" in cells
def _html_table_cells(html_text: str) -> list[list[str]]:
    """Rows of cell texts of the (one) HTML table in ``html_text``."""
    rows = re.findall(r"<tr>(.*?)</tr>", html_text, re.S)
    return [re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", r, re.S) for r in rows]


def test_markdown_table_escapes_bars_in_cells_once():
    """A ``|`` in a header or cell is a literal bar, not a cell boundary: 2 columns stay 2 (before the
    fix, "mean |error|" made 4 header cells), and a bar escaped already is not escaped twice."""
    from rtfit.experiments.report_text import markdown_table, markdown_table_cell

    md = markdown_table(["case", "mean |error|"], [["a|b", "1.0"], ["c\\|d", "2"]], [False, True])
    assert md.splitlines()[0] == "| case | mean \\|error\\| |"
    assert md.splitlines()[3] == "| c\\|d | 2 |"  # escaped once, not "c\\\\|d"
    cells = _html_table_cells(markdown_to_html(md))
    assert cells == [["case", "mean |error|"], ["a|b", "1.0"], ["c|d", "2"]]
    assert markdown_table_cell(markdown_table_cell("x|y")) == markdown_table_cell("x|y") == "x\\|y"
    assert markdown_table_cell("a\\\\|b") == "a\\\\\\|b"  # an escaped backslash, then a bare bar


def test_soft_particles_domain_tables_keep_their_columns():
    """soft-particles' study: its "Errors over the domain" and 100-particle scene tables, from a synthetic
    study: every row has as many cells as the header, and the header reads "mean |error|" (issue 32)."""
    from rtfit.experiments.soft_particles_study import _text

    dom = {
        "table": [
            {
                "shape": "sphere",
                "alpha_c": 0.5,
                "method": "linear",
                "mean_error": -0.01,
                "mean_abs_error": 0.02,
                "rms_error": 0.03,
                "max_abs_error": 0.1,
            }
        ],
        "fits": {},
    }
    extremes = {"camera_inside": {}, "delta": {}, "off_axis": {}}
    scene = {
        "n": 100,
        "straddle": 30,
        "metrics": {"linear": {k: 0.25 for k in ("rmse", "mae", "max_abs", "mean_error")}},
        "silhouette": 3,
        "silhouette_max": 0.5,
    }
    parts = _text(dom, extremes, scene, []).split("\n\n**")
    by_id = {"domain": next(p for p in parts if p.startswith("Errors over the domain")),
             "scene": next(p for p in parts if p.startswith("100 particles"))}  # fmt: skip
    for key, n_cols in (("domain", 7), ("scene", 5)):
        cells = _html_table_cells(markdown_to_html(by_id[key]))
        assert len(cells) == 2 and all(len(r) == n_cols for r in cells), cells
        assert "mean |error|" in cells[0] and "max |error|" in cells[0]
    assert _html_table_cells(markdown_to_html(by_id["domain"]))[1][:3] == ["sphere", "0.5", "linear"]


# ------------------------------------------------------------------------- Setup: a dict config value
def test_setup_table_shows_a_dict_settings_keys_as_rows():
    """The audit's ``config.extra`` (a dict, with a nested dict) becomes one Setup row per key,
    ``extra.scene`` … ``extra.timings_s.render``, not one cell of flattened "k = v, …" text."""
    r = _results()
    r["config"] = {
        "spp": 64,
        "extra": {
            "scene": "scenes/a.xml",
            "families": ["diffuse", "height-fog"],
            "timings_s": {"load": 0.5, "render": 2.25},
            "none": {},
        },
    }
    md = render_report(r)["report.md"]
    setup = md[md.index("| Setting | Value |") : md.index("Software versions")]
    assert _md_row(setup, "`spp`") == "| `spp` | 64 |"
    assert _md_row(setup, "`extra.scene`") == "| `extra.scene` | scenes/a.xml |"
    assert _md_row(setup, "`extra.families`") == "| `extra.families` | diffuse, height-fog |"
    assert _md_row(setup, "`extra.timings_s.load`") == "| `extra.timings_s.load` | 0.5 |"
    assert _md_row(setup, "`extra.timings_s.render`") == "| `extra.timings_s.render` | 2.25 |"
    assert "| `extra.none` |" in setup  # an empty dict keeps its row
    assert "| `extra` |" not in setup and " = " not in setup


def test_report_from_the_written_record_equals_the_report_read_back(exp_dir):
    """`write_report(..., results=)` renders the record the caller just wrote instead of reading the file
    back: the record read back equals it, and the written files are the same bytes."""
    record = load_results(exp_dir)
    write_results(exp_dir, record)
    assert load_results(exp_dir) == record
    read_back = {p.name: p.read_bytes() for p in write_report(exp_dir)}
    passed = {p.name: p.read_bytes() for p in write_report(exp_dir, results=record)}
    assert passed == read_back
