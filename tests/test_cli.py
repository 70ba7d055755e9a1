"""The command line as a user runs it: one-line errors with exit status 2 and nothing written;
an end-to-end quick run; an interrupted run leaves the old output intact and resumes from the cache."""

import json
import shutil
import subprocess
import sys

import pytest

from rtfit.experiments.cli import main


def _one_line_error(capsys, code, argv):
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    assert err.startswith("rtfit: error: ") and "\n" not in err, err
    return err


def test_list(capsys):
    assert main(["list"]) == 0
    assert "diffuse" in capsys.readouterr().out


def test_former_experiment_name_is_an_alias():
    from rtfit.experiments.registry import get_experiment, resolve_names

    assert get_experiment("half-lambert") is get_experiment("diffuse")
    assert resolve_names(["half-lambert", "diffuse"]) == [get_experiment("diffuse")]


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["run", "no-such-experiment"], "unknown experiment 'no-such-experiment'"),
        (["run"], "name an experiment"),
        (["run", "diffuse", "--variant", "bogus"], "bogus"),
        (["run", "diffuse", "--spp", "1"], "--spp"),
        (["run", "diffuse", "--executor", "carrier-pigeon"], "carrier-pigeon"),
        (["bench", "nope"], "unknown experiment"),
        (["frobnicate"], "frobnicate"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(capsys, tmp_path, argv, needle):
    out = tmp_path / "out"
    err = _one_line_error(capsys, 2, [*argv, "--out", str(out)] if argv[0] == "run" else argv)
    assert needle in err
    assert not out.exists()


def test_report_of_missing_results_is_clear(capsys, tmp_path):
    err = _one_line_error(capsys, 2, ["report", str(tmp_path)])
    assert "no results.json" in err


def test_cuda_without_gpu_is_clear(capsys, tmp_path):
    from rtfit.reference.variants import cuda_available

    if cuda_available():
        pytest.skip("a GPU is present")
    err = _one_line_error(
        capsys, 2, ["run", "diffuse", "--variant", "cuda_ad_rgb", "--out", str(tmp_path / "o")]
    )
    assert "CUDA" in err


def test_entry_point_exit_status(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "rtfit.experiments.cli", "run", "nope", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "unknown experiment" in r.stderr
    assert not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """One quick diffuse run shared by the end-to-end tests (it takes tens of seconds)."""
    root = tmp_path_factory.mktemp("e2e")
    out, cache = root / "out", root / "cache"
    assert main(["run", "diffuse", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress"]) == 0
    return out, cache


def test_quick_run_writes_a_complete_report(quick_run):
    out, _ = quick_run
    exp = out / "diffuse"
    for name in (
        "results.json",
        "report.md",
        "report.html",
        "tables.tex",
        "fitted/wrap_smooth.json",
        "fitted/wrap_per_alpha.json",
        "figures/terminator.png",
        "figures/pareto.png",
    ):
        assert (exp / name).is_file(), name
    assert (out / "index.html").is_file()
    results = json.loads((exp / "results.json").read_text())
    assert results["schema"] == "rtfit.results/1" and results["config"]["quick"] is True
    # The report's own validity checks: the exact closed form sits at the reference noise floor.
    assert all(c["passed"] for c in results["checks"]), results["checks"]
    for case in results["cases"]:
        by = {a["method"]: a for a in case["approximations"]}
        assert not by["exact"]["metrics"]["rmse"]["resolved"]  # an exact formula's error is noise
        assert by["half-lambert"]["metrics"]["rmse"]["resolved"]  # half-Lambert is visibly wrong
        assert by["wrap-fit"]["metrics"]["rmse"]["value"] <= by["half-lambert"]["metrics"]["rmse"]["value"]
        assert all(a["cost"]["ns_per_pixel"] > 0 for a in case["approximations"])


def test_interrupted_run_keeps_old_output_and_resumes(quick_run, monkeypatch, capsys):
    out, cache = quick_run
    exp = out / "diffuse"
    before = (exp / "results.json").read_text()
    # A failure at the very end (references rendered, results.json written into the temporary
    # directory, the report not yet) must leave the previous output untouched.
    from rtfit.experiments import runner

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "write_report", boom)
    assert (
        main(["run", "diffuse", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress"]) == 130
    )
    assert (exp / "results.json").read_text() == before
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []
    monkeypatch.undo()
    # Lose some cached passes (as if a run was killed), then rerun: only those passes are rendered
    # and every reference number comes out identical.
    passes = sorted(cache.rglob("pass-*.json"))
    for p in passes[::3]:
        p.unlink()
    assert main(["run", "diffuse", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress"]) == 0
    a, b = json.loads(before), json.loads((exp / "results.json").read_text())
    for ca, cb in zip(a["cases"], b["cases"], strict=True):
        assert ca["reference"]["cache_key"] == cb["reference"]["cache_key"]
        for xa, xb in zip(ca["approximations"], cb["approximations"], strict=True):
            assert xa["metrics"]["rmse"]["value"] == pytest.approx(xb["metrics"]["rmse"]["value"], rel=1e-9)


def test_report_regenerates_from_results_alone(quick_run, tmp_path):
    out, _ = quick_run
    copy = tmp_path / "copy"
    shutil.copytree(out / "diffuse", copy)
    for f in ("report.md", "report.html", "tables.tex"):
        (copy / f).unlink()
    assert main(["report", str(copy)]) == 0
    assert (copy / "report.html").read_text() == (out / "diffuse" / "report.html").read_text()
