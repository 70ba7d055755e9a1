"""Report generator and atomic writes: synthetic results only (no Mitsuba), fast."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

import pytest

from rtfit.experiments.atomic import (
    NonFiniteJSONError,
    atomic_directory,
    atomic_write_json,
    atomic_write_text,
    is_temporary_name,
)
from rtfit.experiments.report import (
    ResultsError,
    format_number,
    load_results,
    markdown_inline,
    markdown_to_html,
    render_report,
    write_index,
    write_report,
)


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
    assert "**0.01230** (floor 0.001000)" in md  # best resolved value in bold
    assert "| Half-Lambert | 0.05000 (floor 0.001000) |" in md
    assert "# Half-Lambert & wrap \\<lighting\\>" in md  # markdown would swallow <lighting> as a tag
    assert "38.20" in page and "0.5000" in page  # generic metric key (smape) rendered too
    assert "smape" in page

    # Unresolved: grey/italic class, † mark, footnote; in markdown italic + †.
    assert re.search(
        r'class="num unresolved"[^>]*>9\.100e-4 <span class="sub">\(floor 0\.001000\)</span>'
        r'<span class="mark">†</span>',
        page,
    )
    assert "*9.100e-4 (floor 0.001000)*†" in md
    assert "below the reference's own noise floor" in md.lower()
    assert "noise floor" in page and "means nothing" in page

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
    assert "\\textit{" in tex and "\\ensuremath{\\dagger}" in tex
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
def test_markdown_subset():
    assert markdown_inline("a <b> & **bold** *it* `x<y` [l](https://e.org/?a=1&b=2)") == (
        "a &lt;b&gt; &amp; <strong>bold</strong> <em>it</em> <code>x&lt;y</code> "
        '<a href="https://e.org/?a=1&amp;b=2">l</a>'
    )
    assert "<a" not in markdown_inline("[x](javascript:alert(1))")
    assert markdown_inline("[x](javascript:alert)") == "x"
    assert markdown_inline("$a*b*c$ and 2 * 3 * 4") == '<span class="math">$a*b*c$</span> and 2 * 3 * 4'
    assert markdown_inline(r"\*not italic\*") == "*not italic*"
    out = markdown_to_html(
        "Para line one\nline two.\n\n- item **1**\n  continued\n- item 2\n\n1. first\n2. second"
    )
    assert out == (
        "<p>Para line one line two.</p>\n<ul><li>item <strong>1</strong> continued</li>"
        "<li>item 2</li></ul>\n<ol><li>first</li><li>second</li></ol>"
    )
    assert markdown_to_html("Text:\n- a\n- b") == "<p>Text:</p>\n<ul><li>a</li><li>b</li></ul>"


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
