"""The command line as a user runs it: one-line errors with exit status 2 and nothing written;
an end-to-end quick run; an interrupted run leaves the old output intact and resumes from the cache."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

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
    from rtfit.experiments.families import get_experiment, resolve_names

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
        "fitted/diffuse.json",
        "figures/terminator.png",
        "figures/error_vs_alpha.png",
        "figures/wrap_parameters.png",
    ):
        assert (exp / name).is_file(), name
    assert (out / "index.html").is_file()
    results = json.loads((exp / "results.json").read_text())
    assert results["schema"] == "rtfit.results/1" and results["config"]["quick"] is True
    # The report's own validity checks: the exact closed form sits at the reference noise floor.
    assert all(c["passed"] for c in results["checks"]), results["checks"]
    for case in results["cases"]:
        by = {a["method"]: a for a in case["approximations"]}
        if case["parameters"]["shadowing"] == "unshadowed":  # (shadowed: × the hard shadow of the centre)
            assert not by["exact"]["metrics"]["rmse"]["resolved"]  # an exact formula's error is noise
        assert by["half-lambert"]["metrics"]["rmse"]["resolved"]  # half-Lambert is visibly wrong
        assert by["wrap-fitted"]["metrics"]["rmse"]["value"] <= by["half-lambert"]["metrics"]["rmse"]["value"]
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


# ---------------------------------------------------------------------------------- --version, -v/-q
def test_version_is_one_line_and_imports_nothing_heavy():
    from importlib import metadata

    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "rtfit", "--version"], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr[-2000:]
    line = r.stdout.strip()
    assert "\n" not in line
    assert line.startswith(f"rtfit {metadata.version('rtfit')} (")
    assert f"mitsuba {metadata.version('mitsuba')}" in line and f"drjit {metadata.version('drjit')}" in line
    # -X importtime lists every module imported, one per line: "import time: self | cumulative | name".
    imported = {ln.rsplit("|", 1)[-1].strip().split(".")[0] for ln in r.stderr.splitlines() if "|" in ln}
    assert "rtfit" in imported  # the listing is what we think it is
    assert not imported & {"mitsuba", "jax", "jaxlib", "matplotlib", "scipy", "optimistix"}


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["audit", "--help"], ["sweep", "--help"]])
def test_help_imports_nothing_heavy(argv):
    """Issue 32: `rtfit --help` must not pay for JAX, matplotlib, SciPy, Mitsuba or Ray at import (they are
    imported inside the functions that need them: tests/test_layering.py's LAZY_OK)."""
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "rtfit", *argv], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr[-2000:]
    imported = {ln.rsplit("|", 1)[-1].strip().split(".")[0] for ln in r.stderr.splitlines() if "|" in ln}
    assert "rtfit" in imported
    assert not imported & {"mitsuba", "jax", "jaxlib", "matplotlib", "scipy", "optimistix", "ray", "mpmath"}


def test_verbose_and_quiet_exclude_each_other(capsys):
    err = _one_line_error(capsys, 2, ["-v", "-q", "list"])
    assert "-v" in err and "-q" in err


def _failing_sweep(tmp_path, name="bad"):
    spec = tmp_path / f"{name}.toml"
    # Each value is valid alone (checked before the sweep starts), but one shipped scene is not enough for
    # the study's smooth law w(α), p(α), found when the point runs (tiny images: the audits take seconds).
    spec.write_text(
        'experiment = "diffuse"\nquick = true\nspp = 4\n[fixed]\nresolution = 8\n'
        '[grid]\nscenes = [["diffuse_sphere_a5"], ["diffuse_sphere_a30"]]\n'
    )
    return spec


def _entry_point(*argv, cwd):
    return subprocess.run(
        [sys.executable, "-m", "rtfit", *argv], capture_output=True, text=True, cwd=cwd, timeout=300
    )


def test_progress_lines_without_a_terminal_and_exit_status_of_a_failed_sweep(tmp_path):
    """stderr is a pipe here (no terminal): the default prints INFO lines as the work goes (sweep start,
    each experiment start, each job); -q prints only the failures; either way the status is 1."""
    spec = _failing_sweep(tmp_path)
    args = [str(spec), "--executor", "inline", "--out", "o", "--cache", "c"]
    r = _entry_point("sweep", *args, cwd=tmp_path)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.splitlines()
    assert "rtfit: sweep bad: 2 points of diffuse, 0 already done, 2 to run on inline" in lines
    assert "rtfit: diffuse: running (quick, llvm_ad_rgb)" in lines
    assert any(ln.startswith("rtfit: sweep bad: 2/2 jobs done, 2 failed") for ln in lines), lines
    failed = [ln for ln in lines if " failed: ValueError" in ln]
    assert len(failed) == 2 and all("at least two shipped scenes" in ln for ln in failed), lines
    summary = lines[-1]
    assert summary.startswith("rtfit: sweep bad: 2 of 2 points failed (p000-") and "p001-" in summary
    assert r.stdout.strip().endswith("report.html")

    q = _entry_point("-q", "sweep", *args, cwd=tmp_path)
    assert q.returncode == 1
    assert q.stderr.splitlines() == [ln for ln in lines if "failed: ValueError" in ln] + [summary]

    v = _entry_point("-v", "sweep", *args, cwd=tmp_path)
    assert v.returncode == 1
    assert any("rtfit.jobs: sweep bad: 1/2 jobs done" in ln for ln in v.stderr.splitlines()), v.stderr


def test_a_sweep_with_a_failed_point_exits_1(tmp_path, monkeypatch, capsys):
    """In process, through `main`: one point raises at run time, the other completes (quick config
    shrunk so that it renders in seconds)."""
    from rtfit.experiments import sweep as sweep_mod

    spec = tmp_path / "half.toml"
    spec.write_text(
        'experiment = "diffuse"\nquick = true\nspp = 64\n[fixed]\nscenes = ["diffuse_sphere_a2", '
        '"diffuse_sphere_a10"]\n[grid]\nresolution = [8, 9]\n'
    )
    real = sweep_mod.run_point

    def flaky(**kw):
        if kw["overrides"]["resolution"] == 9:
            raise RuntimeError("planted failure")
        return real(**kw)

    monkeypatch.setattr(sweep_mod, "run_point", flaky)
    argv = ["sweep", str(spec), "--executor", "inline", "--out", str(tmp_path / "o"), "--cache"]
    assert main([*argv, str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err.splitlines()
    assert any(
        ln.startswith("rtfit: sweep half: point p001-") and "RuntimeError: planted failure" in ln
        for ln in err
    )
    assert err[-1].startswith("rtfit: sweep half: 1 of 2 points failed (p001-")
    assert (tmp_path / "o" / "half" / "points").is_dir()
    done = [p.name for p in (tmp_path / "o" / "half" / "points").iterdir()]
    assert len(done) == 1 and done[0].startswith("p000-")


# -------------------------------------------------------------------------------------- bench --json
def test_bench_json_file_and_stdout(tmp_path, capsys):
    import datetime

    import rtfit

    target = tmp_path / "bench.json"
    assert main(["bench", "diffuse", "--quick", "--size", "4096", "--json", str(target)]) == 0
    text_out = capsys.readouterr().out
    assert text_out.startswith("# rtfit bench diffuse — ")  # the table is still printed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.json"]  # atomic: no temporary left
    doc = json.loads(target.read_text())
    assert doc["format"] == "rtfit.bench/1" and doc["experiment"] == "diffuse"
    assert doc["rtfit"] == rtfit.__version__ and doc["versions"]["mitsuba"]
    assert doc["variant"] in ("llvm_ad_rgb", "cuda_ad_rgb") and doc["device"] in text_out
    assert doc["size"] == 4096 and doc["quick"] is True and doc["seconds"] > 0
    datetime.datetime.fromisoformat(doc["created"])
    rows = doc["rows"]
    assert isinstance(rows, list) and all(isinstance(r, dict) for r in rows)
    assert {"Lambert", "Half-Lambert", "Exact closed form"} <= {r.get("what") for r in rows}
    kernel_rows = [r for r in rows if r.get("elements") == 4096]
    assert kernel_rows and all(r["ns_per_px"] > 0 for r in kernel_rows)

    assert main(["bench", "diffuse", "--quick", "--size", "4096", "--json", "-"]) == 0
    out = capsys.readouterr().out
    assert json.loads(out)["format"] == "rtfit.bench/1"  # stdout holds the JSON alone


def test_bench_json_to_a_missing_directory_is_refused_before_running(capsys, tmp_path):
    err = _one_line_error(capsys, 2, ["bench", "diffuse", "--json", str(tmp_path / "no" / "b.json")])
    assert "no directory" in err
    assert not (tmp_path / "no").exists()


def test_help_listing_matches_each_commands_own_short_help():
    """`rtfit --help` reads each command's one-line help from its source (`cli_commands.short_help`): it must
    be what click itself makes of the imported command, at every listing width."""
    import importlib

    from rtfit.experiments.cli_commands import COMMANDS, short_help

    for name, (module, attribute) in COMMANDS.items():
        command = getattr(importlib.import_module(f"rtfit.experiments.{module}"), attribute)
        assert command.name == name
        for limit in (20, 45, 63, 120):
            assert short_help(name, limit) == command.get_short_help_str(limit), (name, limit)


def test_help_imports_no_command():
    """`rtfit --help` lists the commands without importing their modules, Mitsuba, JAX, matplotlib, SciPy or
    any family (issue 33: start-up under 2 s on 2 cores; what remains is Dr.Jit and the reference package
    the failure classes live in)."""
    heavy = ["mitsuba", "jax", "matplotlib", "scipy"]
    heavy += [f"rtfit.experiments.{m}" for m in ("families", "audit_cli", "runner", "cli_run")]
    probe = (
        "import sys; from rtfit.experiments.cli import main; code = main(['--help']); "
        f"heavy = [m for m in {heavy!r} if m in sys.modules]; print('HEAVY', heavy, code)"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert "HEAVY [] 0" in out, out
    assert "audit       Audit SCENE" in out and "compare     Compare FRAMES" in out


def test_list_and_audit_list_import_nothing_heavy():
    """`rtfit list` reads the registry without ``cli_run``'s runner and reports or Mitsuba, and neither it nor
    `rtfit audit SCENE --list` imports matplotlib, SciPy or JAX (issue 33: start-up under 2 s on 2 cores)."""
    scene = str(Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml")
    for argv, heavy in (
        (["list"], ["rtfit.experiments.cli_run", "rtfit.experiments.runner", "mitsuba"]),
        (["audit", scene, "--list"], []),
    ):
        probe = (
            f"import sys; from rtfit.experiments.cli import main; code = main({argv!r}); "
            f"found = [m for m in sys.modules if m in {heavy!r} "
            "or m.split('.')[0] in ('matplotlib', 'scipy', 'jax')]; print('FOUND', found, code)"
        )
        run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=False)
        assert "FOUND [] 0" in run.stdout, (argv, run.stdout[-500:], run.stderr[-500:])
