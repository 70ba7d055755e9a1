"""The audit book (``rtfit report OUT/`` → ``book.tex``, ``book.pdf``) built from a real run.

The run: the six stored quick-suite results (``tests/data/results``, every family, no figure files)
plus a tiny real ``diffuse`` run with its figures (`conftest.run_tiny_experiment`). The compile tests
run pdflatex exactly as ``rtfit report`` does and read the log: no error, no overfull ``\\hbox``
wider than 1 pt, no missing character, no float too large, no undefined reference. They are skipped,
with the reason, where pdflatex is not installed (Debian: ``texlive-latex-base
texlive-latex-recommended``, which ``.ci/run`` installs).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments import book as book_mod
from rtfit.experiments.book import PREAMBLE, SETUP
from rtfit.experiments.book_markdown import tex_markdown_blocks
from rtfit.experiments.book_plots import family_points, normalised_error
from rtfit.experiments.cli import main
from rtfit.experiments.latex import tex_text
from rtfit.experiments.records import Approximation, Metric, Results, from_json, plain_json
from rtfit.experiments.results import load_results
from rtfit.fitting.metrics import compute_metrics

ROOT = Path(__file__).resolve().parent.parent
STORED = sorted((ROOT / "tests" / "data" / "results").glob("*.json"))
PDFLATEX = shutil.which("pdflatex")
needs_pdflatex = pytest.mark.skipif(
    PDFLATEX is None,
    reason="pdflatex is not installed (apt-get install texlive-latex-base texlive-latex-recommended)",
)
TINY_DIFFUSE = dict(scenes=["diffuse_sphere_a5", "diffuse_sphere_a30"], resolution=24, spp=64)


def _stored_run(out: Path) -> list[Path]:
    dirs = []
    for p in STORED:
        d = out / p.stem
        d.mkdir(parents=True)
        shutil.copy(p, d / "results.json")
        dirs.append(d)
    return dirs


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A whole run: the six stored families plus a tiny real diffuse run (with figures)."""
    from .conftest import run_tiny_experiment

    base = tmp_path_factory.mktemp("book")
    run_tiny_experiment("diffuse", base, TINY_DIFFUSE)  # → base/out/diffuse
    _stored_run(base / "out")
    return base / "out"


def _assert_clean_log(log: str) -> None:
    errors = [line for line in log.splitlines() if line.startswith("!")]
    assert not errors, errors[:5]
    overfull = [float(w) for w in re.findall(r"Overfull \\hbox \(([0-9.]+)pt too wide\)", log)]
    assert not [w for w in overfull if w > 1.0], f"overfull boxes (pt): {overfull}"
    assert "Missing character" not in log
    assert "Float too large" not in log
    assert "Overfull \\vbox" not in log
    assert "There were undefined references" not in log
    assert "Rerun to get" not in log


# --------------------------------------------------------------------------------- normalisation
def test_normalised_error_is_rmse_over_the_reference_peak():
    """RMSE/peak from the PSNR equals the RMSE over the reference's maximum computed here with
    NumPy; its floor is the noise floor of the RMSE over the same peak."""
    rng = np.random.default_rng(7)
    ref = rng.uniform(0.1, 3.0, size=(16, 16, 3))
    approx = ref + rng.normal(0.0, 0.05, size=ref.shape)
    stderr = np.full_like(ref, 0.01)
    mask = np.ones((16, 16), bool)
    mask[:4] = False
    m = compute_metrics(approx, ref, stderr, mask, names=("rmse", "psnr"))
    ap = Approximation(
        method="x", metrics={k: Metric(v.value, v.noise_floor, v.resolved) for k, v in m.items()}
    )
    value, floor, resolved, kind = normalised_error(ap)
    peak = ref[mask].max()
    rmse = np.sqrt(np.mean((approx[mask] - ref[mask]) ** 2))
    assert kind == "peak" and resolved is True
    assert value == pytest.approx(rmse / peak, rel=1e-12)  # measured: 2e-16
    assert floor == pytest.approx(0.01 / peak, rel=1e-12)
    # A family with only rel_rmse (irradiance-bases) gives it as is.
    ap2 = Approximation(method="y", metrics={"rel_rmse": Metric(0.25, 0.01, True)})
    assert normalised_error(ap2) == (0.25, 0.01, True, "rms")
    assert normalised_error(Approximation(method="z", metrics={"mae": Metric(1.0)})) is None


def test_family_points_are_means_over_each_methods_cases():
    """Mean error, mean floor, resolved count and mean cost per approximation, recomputed from the
    JSON with plain arithmetic."""
    path = ROOT / "tests" / "data" / "results" / "height-fog.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    pts = {p.method: p for p in family_points(from_json(Results, plain_json(doc), "<test>"))}
    for method, p in pts.items():
        aps = [a for c in doc["cases"] for a in c["approximations"] if a["method"] == method]
        vals = [a["metrics"]["rmse"]["value"] for a in aps]
        assert p.cases == len(aps)
        assert p.error == pytest.approx(sum(vals) / len(vals), rel=1e-14)
        assert p.resolved == sum(a["metrics"]["rmse"].get("resolved", True) is not False for a in aps)
        ns = [a["cost"]["ns_per_pixel"] for a in aps if a.get("cost")]
        if ns:
            assert p.ns_per_pixel == pytest.approx(sum(ns) / len(ns), rel=1e-14)
        norms = [10 ** (-a["metrics"]["psnr"]["value"] / 20) for a in aps]
        assert p.norm == pytest.approx(sum(norms) / len(norms), rel=1e-12)


# ------------------------------------------------------------------------------------------ book
@needs_pdflatex
def test_report_over_a_run_writes_a_clean_book(run_dir):
    rc = main(["report", str(run_dir)])
    assert rc == 0
    tex = (run_dir / "book.tex").read_text(encoding="utf-8")
    assert tex.isascii()
    assert tex.startswith("% book.tex") and PREAMBLE in tex
    assert (run_dir / "book.pdf").stat().st_size > 10_000
    _assert_clean_log((run_dir / "book.log").read_text(encoding="latin-1"))
    # One section per family, the summary first; every figure included exists (relative paths).
    sections = re.findall(r"\\section\{(.*)\}", tex)
    assert sections[0] == "Summary across families" and len(sections) == 1 + 7
    paths = re.findall(r"\\includegraphics\[[^\]]*\]\{([^}]*)\}", tex)
    assert paths and all(not p.startswith("/") and (run_dir / p).is_file() for p in paths)
    assert "book-figures/summary.pdf" in paths
    assert "book-figures/pareto-height-fog.pdf" in paths
    assert any(p.startswith("diffuse/figures/") and p.endswith(".png") for p in paths)
    # The stored results carry no figure files: the book says so instead of failing.
    assert r"Figure file \texttt{height-fog/figures/" in tex.replace(r"\allowbreak{}", "")
    # Every approximation with a normalised error and a cost is in the summary table.
    diffuse = load_results(run_dir / "diffuse")
    for ap in diffuse.cases[0].approximations:
        assert tex_text(ap.display) in tex


@needs_pdflatex
def test_pasted_blocks_compile_in_the_documented_preamble(run_dir, tmp_path):
    """A figure block and a table block cut from book.tex compile as they are in the minimal document
    of docs/book.md (figures found through their relative paths)."""
    if not (run_dir / "book.tex").is_file():
        assert main(["report", str(run_dir)]) == 0
    tex = (run_dir / "book.tex").read_text(encoding="utf-8")
    figure = re.search(r"\\begin\{figure\}.*?\\end\{figure\}", tex, re.S)
    table = re.search(r"\\begingroup.*?\\endgroup", tex, re.S)
    assert figure and table
    doc = re.search(r"```latex\n(.*?)```", (ROOT / "docs" / "book.md").read_text(encoding="utf-8"), re.S)
    assert doc, "docs/book.md has no ```latex block with the preamble"
    text = doc.group(1)
    assert text.startswith(PREAMBLE)
    body = figure.group(0) + "\n" + table.group(0) + "\n"
    (run_dir / "paste.tex").write_text(
        text.replace("% your text, tables and figures\n", body), encoding="utf-8"
    )
    try:
        proc = subprocess.run(
            [
                PDFLATEX,
                "-interaction=nonstopmode",
                "-halt-on-error",
                f"-output-directory={tmp_path}",
                "paste.tex",
            ],
            cwd=run_dir,
            capture_output=True,
            timeout=300,
            check=False,
        )
    finally:
        (run_dir / "paste.tex").unlink()
    log = (tmp_path / "paste.log").read_text(encoding="latin-1")
    assert proc.returncode == 0, [line for line in log.splitlines() if line.startswith("!")][:5]
    overfull = [float(w) for w in re.findall(r"Overfull \\hbox \(([0-9.]+)pt too wide\)", log)]
    assert not [w for w in overfull if w > 1.0], overfull


@needs_pdflatex
def test_markdown_blocks_fit_the_page(tmp_path):
    """Every markdown construct of results texts: nested lists, a pipe table wider than the page, a
    code block with lines longer than the page (aligned columns kept in a smaller size), a very long
    code block line (wrapped), inline code, math, links, emphasis, non-ASCII."""
    wide = "| " + " | ".join(f"column header {j}" for j in range(12)) + " |\n"
    wide += "|" + "---:|" * 12 + "\n" + "| " + " | ".join(f"{j}.125e-3" for j in range(12)) + " |\n"
    md = (
        "# A heading\n\nSome *emphasis*, **bold**, `code_span/with/a/long/path_name.json`, $L = L₀·T$, "
        "a [link](https://example.org/a(b)c) and 10⁻⁴ ± 5 %.\n\n"
        "- one\n  - nested **two**\n    1. three\n\n"
        "> a quote\n\n"
        + wide
        + "\n```\n"
        + "case      α ± s.e.     " * 6
        + "\n"
        + "x" * 400
        + "\n```\n\n---\n\nEnd."
    )
    body = tex_markdown_blocks(md, "md", "t")
    assert body.isascii()
    (tmp_path / "t.tex").write_text(
        PREAMBLE + SETUP + "\n\\begin{document}\n" + body + "\\end{document}\n", encoding="utf-8"
    )
    proc = subprocess.run(
        [PDFLATEX, "-interaction=nonstopmode", "-halt-on-error", "t.tex"],
        cwd=tmp_path,
        capture_output=True,
        timeout=300,
        check=False,
    )
    log = (tmp_path / "t.log").read_text(encoding="latin-1")
    assert proc.returncode == 0, [line for line in log.splitlines() if line.startswith("!")][:5]
    _assert_clean_log(log)


def test_without_pdflatex_the_tex_is_written_and_the_run_succeeds(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    _stored_run(out)
    real_which = shutil.which
    monkeypatch.setattr(
        shutil, "which", lambda name, *a, **k: None if name == "pdflatex" else real_which(name)
    )
    assert main(["report", str(out)]) == 0
    assert (out / "book.tex").is_file() and not (out / "book.pdf").exists()
    assert "book.pdf not written: pdflatex not found" in capsys.readouterr().err


def test_a_failed_compile_exits_1(tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    _stored_run(out)
    real_which = shutil.which
    monkeypatch.setattr(
        shutil, "which", lambda name, *a, **k: "/bin/false" if name == "pdflatex" else real_which(name)
    )
    monkeypatch.setattr(book_mod, "compile_book", lambda *a, **k: (None, "pdflatex failed: ! Boom."))
    assert main(["report", str(out)]) == 1
    assert "pdflatex failed: ! Boom." in capsys.readouterr().err
    assert (out / "book.tex").is_file()
