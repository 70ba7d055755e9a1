"""Bad input (issue 21 §5): one line on stderr (``rtfit: error: …``), exit status 2, nothing under
``--out``, no cache entry — found before anything renders. A run whose self-checks fail exits 1 with
one summary line. No test here renders: every check happens before the first job."""

from __future__ import annotations

import copy
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
import types
from pathlib import Path

import pytest

from rtfit.experiments import cli_options, families, registry
from rtfit.experiments.cli import main
from rtfit.experiments.registry import SPP_MAX, ConfigKey, ExperimentSpec, apply_overrides, check_value
from rtfit.scenes import SceneError, library_path, parse_scene_text
from rtfit.scenes.model import MitsubaXML

DATA = Path(__file__).parent / "data"
XML_KIND = MitsubaXML.kind


@pytest.fixture
def dirs(tmp_path, monkeypatch):
    """(out, cache) under tmp_path, neither existing yet; probes looked for in an empty directory."""
    monkeypatch.setenv("RTFIT_PROBE_DIR", str(tmp_path / "no-probes"))
    monkeypatch.delenv("RTFIT_CACHE", raising=False)
    return tmp_path / "out", tmp_path / "cache"


def _refused(capsys, argv, out: Path, cache: Path | None, status: int = 2) -> str:
    """Run ``rtfit argv``; assert the status, one ``rtfit: error:`` line on stderr and nothing written."""
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == status, err
    assert len(lines) == 1, err
    assert lines[0].startswith("rtfit: error: "), err
    assert not out.exists()
    if cache is not None:
        assert not cache.exists() or not any(cache.rglob("*"))
    return lines[0]


def _run(out: Path, cache: Path, *extra) -> list[str]:
    return ["run", "diffuse", "--quick", "--out", str(out), "--cache", str(cache), *extra]


def _sweep_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(text)
    return path


def _sweep(spec: Path, out: Path, cache: Path) -> list[str]:
    return ["sweep", str(spec), "--out", str(out), "--cache", str(cache), "--executor", "inline"]


# ------------------------------------------------------------------------------------ paths
UNWRITABLE = Path("/proc/rtfit-test-unwritable")  # nothing can be created under /proc, not even by root


def test_unwritable_out(capsys, dirs):
    _out, cache = dirs
    line = _refused(capsys, _run(UNWRITABLE / "out", cache), UNWRITABLE, cache)
    assert "--out" in line and "cannot create" in line


def test_unwritable_cache(capsys, dirs):
    out, _ = dirs
    line = _refused(capsys, _run(out, UNWRITABLE / "cache"), out, None)
    assert "--cache" in line and "cannot create" in line


@pytest.mark.skipif(sys.platform == "win32" or os.geteuid() == 0, reason="root writes anywhere")
def test_read_only_out_directory(capsys, dirs, tmp_path):
    _out, cache = dirs
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    line = _refused(capsys, _run(locked / "out", cache), locked / "out", cache)
    assert "Permission denied" in line


def test_out_under_a_file(capsys, dirs, tmp_path):
    _, cache = dirs
    (tmp_path / "a-file").write_text("x")
    out = tmp_path / "a-file" / "out"
    line = _refused(capsys, _run(out, cache), out, cache)
    assert "a file, not a directory" in line
    assert (tmp_path / "a-file").read_text() == "x"


def test_rtfit_cache_pointing_at_a_file(capsys, dirs, tmp_path, monkeypatch):
    out, _ = dirs
    (tmp_path / "cache-file").write_text("x")
    monkeypatch.setenv("RTFIT_CACHE", str(tmp_path / "cache-file"))
    argv = ["run", "diffuse", "--quick", "--out", str(out)]
    line = _refused(capsys, argv, out, None)
    assert "$RTFIT_CACHE" in line and "is a file" in line


# ---------------------------------------------------------------------------------- options
def test_scalar_variant_is_not_offered(capsys, dirs):
    out, cache = dirs
    line = _refused(capsys, _run(out, cache, "--variant", "scalar_rgb"), out, cache)
    assert "llvm_ad_rgb" in line and "cuda_ad_rgb" in line
    assert "scalar_rgb" not in cli_options.VARIANT_CHOICES


def test_spp_above_the_bound(capsys, dirs):
    out, cache = dirs
    line = _refused(capsys, _run(out, cache, "--spp", "999999999999"), out, cache)
    assert str(SPP_MAX) in line


def test_sweep_spp_above_the_bound(capsys, dirs, tmp_path):
    out, cache = dirs
    spec = _sweep_file(tmp_path, 'experiment = "diffuse"\nquick = true\nspp = 999999999999\n')
    line = _refused(capsys, _sweep(spec, out, cache), out, cache)
    assert "spp" in line and str(SPP_MAX) in line


# --------------------------------------------------------------------------- configuration values
def test_sweep_resolution_must_be_an_integer(capsys, dirs, tmp_path):
    out, cache = dirs
    spec = _sweep_file(tmp_path, 'experiment = "diffuse"\nquick = true\n[grid]\nresolution = [64.5]\n')
    line = _refused(capsys, _sweep(spec, out, cache), out, cache)
    assert "resolution = 64.5: expected an integer" in line


def test_unknown_shipped_scene(capsys, dirs, tmp_path):
    out, cache = dirs
    spec = _sweep_file(
        tmp_path, 'experiment = "diffuse"\nquick = true\n[fixed]\nscenes = ["diffuse_sphere_a5", "nope"]\n'
    )
    line = _refused(capsys, _sweep(spec, out, cache), out, cache)
    assert "scenes" in line and "nope" in line


def test_unknown_environment(capsys, dirs, tmp_path):
    """irradiance-bases runs on the engine: its environments are its shipped scenes, named in the sweep's
    ``scenes`` key (a name that is none of them is refused before anything runs)."""
    out, cache = dirs
    spec = _sweep_file(
        tmp_path,
        'experiment = "irradiance-bases"\nquick = true\n[grid]\nscenes = [["constant"], ["nowhere"]]\n',
    )
    line = _refused(capsys, _sweep(spec, out, cache), out, cache)
    assert "scenes" in line and "nowhere" in line


def test_every_experiment_declares_every_key():
    for name, spec in families.EXPERIMENTS.items():
        declared = spec.load().CONFIG
        for quick in (True, False):
            cfg = spec.load().configure(quick, None)
            assert set(cfg) == set(declared), name
            assert registry.apply_overrides(cfg, cfg, name, declared=declared) == cfg  # defaults valid


def test_show_config_prints_type_and_range(capsys):
    assert main(["sweep", "--show-config", "diffuse", "--quick"]) == 0
    out = capsys.readouterr().out
    assert "resolution = null  # int in [4, 4096], or none" in out
    assert f"spp = null  # int in [2, {SPP_MAX}], or none" in out


def test_config_key_checks():
    key = ConfigKey("int", lo=8, hi=16, shape=(2,))
    assert check_value("r", key, [8, 16]) == [8, 16]
    for bad, problem in (
        ([8], "list of 2"),
        ([8, 16.0], "integer"),
        ([8, True], "integer"),
        ([8, 17], "range"),
    ):
        with pytest.raises(ValueError, match=problem):
            check_value("r", key, bad)
    f = ConfigKey("float", lo=0.0, hi=1.0)
    assert check_value("x", f, 1) == 1.0 and isinstance(check_value("x", f, 1), float)
    with pytest.raises(ValueError, match="finite"):
        check_value("x", f, float("nan"))
    with pytest.raises(ValueError, match="not a configuration key"):
        apply_overrides({"a": 1}, {"b": 2}, "diffuse")


# -------------------------------------------------------------------------------------- scenes
def _fog_scene(density: str) -> str:
    text = library_path("fog_transmittance").read_text()
    lines = [f"density = {density}" if line.startswith("density =") else line for line in text.splitlines()]
    return "\n".join(lines) + "\n"


def test_scene_value_1e308_is_refused(capsys, dirs, tmp_path):
    with pytest.raises(SceneError, match=r"density: must be within ±1e\+06"):
        parse_scene_text(_fog_scene("1e308"))
    scene = tmp_path / "huge.toml"
    scene.write_text(_fog_scene("1e308"))
    _out, _ = dirs
    rc = main(["audit", str(scene), "--list"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: ") and "density" in err[0]


def test_library_scenes_are_within_the_bounds():
    parse_scene_text(_fog_scene("0.6"))  # the file's own value
    for name in ("fog_terrain", "fog_volumes", "half_lambert_sphere", "aperture_bumps", "sdf_character"):
        parse_scene_text(library_path(name).read_text(), base_dir=library_path(name).parent)


def _with_xml_shape(name: str) -> str:
    """The half-Lambert library scene with one more shape: the Mitsuba XML file ``name``."""
    base = library_path("half_lambert_sphere").read_text()
    return base + f'\n[[shapes]]\ntype = "{XML_KIND}"\nfile = "{name}"\n'


@pytest.mark.parametrize(
    ("xml", "problem"),
    [
        ('<scene version="3.0.0"><shape type="sphere"></scene>', "not well-formed XML"),
        (
            '<?xml version="1.0"?><!DOCTYPE s [<!ENTITY a "aaaa">]><scene version="3.0.0"/>',
            "entity declaration",
        ),
        ('<shape type="sphere"/>', "root element is <shape>"),
    ],
)
def test_xml_scene_errors_are_found_at_parse(tmp_path, xml, problem):
    (tmp_path / "bad.xml").write_text(xml)
    text = _with_xml_shape("bad.xml")
    with pytest.raises(SceneError, match=problem):
        parse_scene_text(text, base_dir=tmp_path)


def test_xml_scene_well_formed_is_accepted(tmp_path):
    shutil.copy(DATA / "tiny.xml", tmp_path / "tiny.xml")
    shutil.copy(DATA / "tri.obj", tmp_path / "tri.obj")
    parse_scene_text(_with_xml_shape("tiny.xml"), base_dir=tmp_path)


# ---------------------------------------------------------------------------------- failed checks
def test_failed_self_checks_exit_1(capsys, dirs, monkeypatch):
    """A stand-in experiment (no rendering) whose run reports 2 failed checks of 3."""
    out, cache = dirs
    body = json.loads((DATA / "results" / "half-lambert.json").read_text(encoding="utf-8"))
    for key in ("schema", "experiment", "title", "created", "versions", "device"):
        body.pop(key, None)
    body["checks"] = [
        {"name": "energy", "value": 1.25, "expected": "≤ 1.01", "passed": False},
        {"name": "symmetry", "value": 0.0, "expected": "= 0", "passed": True},
        {"name": "furnace", "value": None, "expected": None, "passed": False},
    ]
    module = types.ModuleType("rtfit_test_bad_input_checks")
    module.configure = lambda quick, spp: {}  # type: ignore[attr-defined]
    module.CONFIG = {}  # type: ignore[attr-defined]
    module.run = lambda ctx: copy.deepcopy(body)  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setitem(
        families.EXPERIMENTS, "fake-checks", ExperimentSpec("fake-checks", module.__name__, "Fake", "A fake.")
    )
    rc = main(["run", "fake-checks", "--quick", "--out", str(out), "--cache", str(cache), "--no-progress"])
    err = [line for line in capsys.readouterr().err.splitlines() if "checks failed" in line]
    assert rc == 1
    assert len(err) == 1
    assert err[0].startswith(
        "rtfit: fake-checks: 2 of 3 checks failed: energy (1.25, expected ≤ 1.01); furnace"
    )
    assert (out / "fake-checks" / "results.json").is_file()  # the results are kept: the work ran


# ------------------------------------------------------------------------------------------ Ray
def test_bad_ray_address_refused_port(capsys, dirs):
    pytest.importorskip("ray", reason="Ray is not installed (rtfit[ray])")
    out, cache = dirs
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    line = _refused(
        capsys, _run(out, cache, "--executor", "ray", "--address", f"127.0.0.1:{port}"), out, cache
    )
    assert "cannot connect" in line and time.perf_counter() - t0 < 10


def test_bad_ray_address_that_never_answers(dirs, tmp_path):
    """Something accepts the TCP connection but never speaks Ray: ray.init would retry for minutes;
    here it gives up after 3 × $RTFIT_RAY_TIMEOUT seconds with one line."""
    pytest.importorskip("ray", reason="Ray is not installed (rtfit[ray])")
    out, cache = dirs
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    port = server.getsockname()[1]
    held: list = []

    def accept():
        while True:
            try:
                held.append(server.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "rtfit",
                *_run(out, cache, "--executor", "ray", "--address", f"127.0.0.1:{port}"),
            ],
            capture_output=True,
            text=True,
            timeout=90,
            env={**os.environ, "RTFIT_RAY_TIMEOUT": "1"},
        )
    finally:
        server.close()
        for c in held:
            c.close()
    lines = [line for line in proc.stderr.splitlines() if line.startswith("rtfit: ")]
    assert proc.returncode == 2, proc.stderr
    assert lines == [f"rtfit: error: --address 127.0.0.1:{port}: Ray did not connect within 3 s"], proc.stderr
    assert time.perf_counter() - t0 < 60
    assert not out.exists() and not cache.exists()


def test_corrupt_probe_file(tmp_path, monkeypatch):
    """A corrupt measured probe under ``$RTFIT_PROBE_DIR`` (issue 32: reported as "not found"): the
    published check fails, naming the file and that it does not read; nothing else is printed."""
    from rtfit.experiments.irradiance_bases_study import published_checks
    from rtfit.reference import environments as envs

    path = tmp_path / envs.PROBES["grace"][0]
    path.write_bytes(os.urandom(4096))
    monkeypatch.setenv("RTFIT_PROBE_DIR", str(tmp_path))
    (check,) = published_checks(quick=True)
    assert not check.passed
    assert str(path) in str(check.value) and "does not read" in str(check.value)
    assert "not found" not in str(check.value)
