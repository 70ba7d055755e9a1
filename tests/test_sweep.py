"""Sweeps and executors: spec validation, identical results under inline / process / Ray, workers
killed mid-job (the sweep still completes, the cache holds no partial entry), resume from the cache."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from rtfit.experiments.atomic import is_temporary_name
from rtfit.experiments.cli import main
from rtfit.experiments.executors import make_executor
from rtfit.experiments.jobs import Job, ProcessExecutor, diagnostic_job
from rtfit.experiments.registry import apply_overrides
from rtfit.experiments.sweep import SweepError, load_sweep, run_sweep

SWEEP = """
name = "tiny"
experiment = "diffuse"
quick = true
spp = 32
[fixed]
scenes = ["diffuse_sphere_a5", "diffuse_sphere_a30"]
[grid]
resolution = [16, 20]
"""


def _write(tmp_path, text, name="sweep.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


# ------------------------------------------------------------------------------------ validation
def test_apply_overrides_checks_keys_and_kinds():
    d = {"resolution": 64, "alphas_deg": [1.0, 2.0], "scale": 0.5, "flag": False}
    assert apply_overrides(d, {"resolution": 32, "scale": 1}) == {**d, "resolution": 32, "scale": 1.0}
    with pytest.raises(ValueError, match="'bogus' is not a configuration key"):
        apply_overrides(d, {"bogus": 1})
    for bad in (
        {"resolution": "64"},
        {"alphas_deg": 5.0},
        {"scale": float("nan")},
        {"flag": 1},
        {"resolution": True},
        {"alphas_deg": [float("inf")]},
    ):
        with pytest.raises(ValueError, match="expected a value like"):
            apply_overrides(d, bad)


@pytest.mark.parametrize(
    "text, message",
    [
        ("experiment = 'nope'", "unknown experiment 'nope'"),
        ("", "experiment: required"),
        ("experiment = 'diffuse'\nbogus = 1", "bogus: unknown key"),
        (
            "experiment = 'diffuse'\n[grid]\nno_such_key = [1, 2]",
            "'no_such_key' is not a configuration key",
        ),
        ("experiment = 'diffuse'\n[grid]\nresolution = ['a']", 'resolution = "a": expected an integer'),
        ("experiment = 'diffuse'\n[grid]\nresolution = []", "grid.resolution: must be a non-empty list"),
        ("experiment = 'diffuse'\n[[points]]\nresolution = 8\n[[points]]\nresolution = 8", "duplicates"),
        ("experiment = 'diffuse'\nspp = 1", "spp: must be an integer"),
        ("experiment = = 'x'", "not valid TOML"),
    ],
)
def test_bad_sweep_files_are_one_line_errors(tmp_path, capsys, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(SweepError, match=message):
        load_sweep(path)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rtfit: error:") and "\n" not in err and message.split("'")[0] in err
    assert not (tmp_path / "o").exists()


def test_grid_and_points_expand(tmp_path):
    s = load_sweep(_write(tmp_path, SWEEP + "[[points]]\nresolution = 24\n"))
    assert [p["resolution"] for p in s.points] == [16, 20, 24]
    pts = s.resolved_points("llvm_ad_rgb")
    assert pts[0].varying == ("resolution",) and pts[0].label == "resolution = 16"
    assert len({p.key for p in pts}) == 3
    assert (
        pts[0].key
        != load_sweep(_write(tmp_path, SWEEP.replace("spp = 32", "spp = 64"), "b.toml"))
        .resolved_points("llvm_ad_rgb")[0]
        .key
    )


def test_ray_executor_without_ray_names_the_extra(monkeypatch, tmp_path, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "ray" else real(n, *a))
    assert main(["run", "diffuse", "--executor", "ray", "--out", str(tmp_path / "o")]) == 2
    assert "pip install 'rtfit[ray]'" in capsys.readouterr().err


# --------------------------------------------------------------------------------- executors
def _numbers(results: dict) -> list:
    """Every metric value and fitted parameter of a combined sweep document (not timings)."""
    out = []
    for c in results["cases"]:
        for a in c["approximations"]:
            out.append(
                (
                    c["id"],
                    a["method"],
                    sorted((k, m["value"]) for k, m in a["metrics"].items()),
                    sorted((a.get("parameters") or {}).items()),
                )
            )
    return out


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """The same sweep under each executor, each with its own reference cache (so each renders)."""
    root = tmp_path_factory.mktemp("sweeps")
    spec = load_sweep(_write(root, SWEEP))
    out = {}
    for name in ("inline", "process", "ray"):
        if name == "ray":
            pytest.importorskip("ray")
        ex = make_executor(name, workers=2)
        try:
            summary = run_sweep(
                spec,
                root / name,
                variant="llvm_ad_rgb",
                cache_dir=root / f"cache-{name}",
                executor=ex,
                executor_name=name,
            )
        finally:
            ex.close()
        assert not summary.failed
        out[name] = json.loads((root / name / "tiny" / "results.json").read_text())
    return root, spec, out


@pytest.mark.slow
@pytest.mark.ray
def test_executors_give_identical_numbers(sweeps):
    _, _, out = sweeps
    inline = _numbers(out["inline"])
    assert len(inline) == 2 * 2 * 2 * 6  # 2 points × 2 suns × (unshadowed, shadowed) × 6 rows
    assert _numbers(out["process"]) == inline
    if "ray" in out:
        assert _numbers(out["ray"]) == inline
    # (The experiment's statistical checks are not asserted at these tiny sample counts; they
    # are the same under every executor.)
    checks = [(c["name"], c["value"], c["passed"]) for c in out["inline"]["checks"]]
    assert all(
        [(c["name"], c["value"], c["passed"]) for c in doc["checks"]] == checks for doc in out.values()
    )


@pytest.mark.slow
def test_sweep_writes_points_and_resumes(sweeps, capsys):
    root, spec, _ = sweeps
    d = root / "inline" / "tiny"
    points = sorted((d / "points").iterdir())
    assert [p.name[:4] for p in points] == ["p000", "p001"]
    for p in points:
        assert (p / "report.html").is_file() and json.loads((p / "results.json").read_text())["config"][
            "sweep_point"
        ]
    assert (d / "report.html").is_file() and (root / "inline" / "index.html").is_file()
    summary = run_sweep(
        spec,
        root / "inline",
        variant="llvm_ad_rgb",
        cache_dir=root / "cache-inline",
        executor=make_executor("inline"),
        executor_name="inline",
    )
    assert summary.ran == [] and len(summary.resumed) == 2


def _assert_cache_complete(cache: Path):
    files = [p for p in cache.rglob("*") if p.is_file()]
    assert files
    assert not [p for p in files if is_temporary_name(p.name)], "partial files left in the cache"
    for meta in cache.rglob("pass-*.json"):
        assert meta.with_suffix(".exr").is_file() or list(meta.parent.glob(meta.stem + ".*")), meta


def test_process_worker_killed_mid_job_is_retried():
    ex = ProcessExecutor(workers=2)
    try:
        jobs = [Job(diagnostic_job, {"seconds": 2.0}, f"j{i}") for i in range(2)]
        jobs.append(Job(diagnostic_job, {"fail": "this job fails"}, "bad"))

        def kill_one():
            for _ in range(100):
                pids = ex.worker_pids()
                if len(pids) == 2:
                    time.sleep(0.8)
                    os.kill(pids[0], signal.SIGKILL)
                    return
                time.sleep(0.1)

        threading.Thread(target=kill_one, daemon=True).start()
        outcomes = ex.run_all(jobs)
    finally:
        ex.close()
    assert [o.ok for o in outcomes] == [True, True, False]
    assert max(o.attempts for o in outcomes[:2]) == 2
    assert outcomes[2].error == "ValueError: this job fails"


@pytest.mark.slow
@pytest.mark.ray
def test_ray_worker_killed_mid_render_sweep_completes(tmp_path):
    pytest.importorskip("ray")
    from rtfit.experiments.ray_executor import RayExecutor

    spec = load_sweep(_write(tmp_path, SWEEP.replace("spp = 32", "spp = 64")))
    ex = RayExecutor(workers=2)
    killed = []

    def kill_a_busy_worker():
        for _ in range(600):
            busy = ex.busy_pids()
            if busy:
                time.sleep(1.0)  # well inside the point's render
                pid = next(iter(busy))
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.05)

    try:
        threading.Thread(target=kill_a_busy_worker, daemon=True).start()
        summary = run_sweep(
            spec,
            tmp_path / "out",
            variant="llvm_ad_rgb",
            cache_dir=tmp_path / "cache",
            executor=ex,
            executor_name="ray",
        )
    finally:
        ex.close()
    assert killed, "no worker was killed"
    assert not summary.failed and len(summary.ran) == 2
    doc = json.loads((tmp_path / "out" / "tiny" / "results.json").read_text())
    assert not [c for c in doc["checks"] if c["name"].endswith("completed")]
    assert "2 attempts" in (tmp_path / "out" / "tiny" / "report.md").read_text()
    _assert_cache_complete(tmp_path / "cache")
