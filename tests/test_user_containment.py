"""User code contained (issue 32): `--approx my.py:f` loads and validates the user's code in a child
process under a time limit first (`rtfit.experiments.user_sandbox`). Whatever that code does to end the
process — ``sys.exit``, ``os._exit``, ``raise KeyboardInterrupt``, an endless loop, at import or in the
function — is one ``rtfit: error:`` line naming it, exit 2 (never 0, never 130), nothing written; its
warnings are one line each; complex results are refused without NumPy's ComplexWarning. No test here
renders (``audit --list``: inspection only)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.cli import main
from rtfit.experiments.user_methods import UserMethodError, check_approximation, load_approximation
from rtfit.experiments.user_sandbox import TIMEOUT_ENV, load_validated
from rtfit.realtime.quantities import Param, approximation

SCENE = "half_lambert_sphere"  # a library TOML scene: inspected in well under a second


def user_file(tmp_path: Path, body: str, prelude: str = "", name: str = "mine.py") -> Path:
    """A user approximation ``f`` of light_irradiance whose body is ``body`` (after ``prelude`` at import)."""
    text = textwrap.dedent(
        """\
        import os, sys, warnings
        from rtfit import approximation, Param
        {prelude}

        @approximation(quantity="light_irradiance", params={{"w": Param(0.5, lower=0.0, upper=1.0)}})
        def f(ops, g, *, w):
            {body}
        """
    ).format(prelude=prelude, body=body)
    path = tmp_path / name
    path.write_text(text)
    return path


def audit_list(capsys, tmp_path, approx: str) -> tuple[int, list[str], str]:
    out = tmp_path / "out"
    rc = main(["audit", SCENE, "--list", "--approx", approx, "--out", str(out)])
    cap = capsys.readouterr()
    assert not out.exists()
    return rc, cap.err.strip().splitlines(), cap.out


def refused(capsys, tmp_path, approx: str) -> str:
    rc, err, _ = audit_list(capsys, tmp_path, approx)
    assert rc == 2, err
    assert len(err) == 1, err
    assert err[0].startswith("rtfit: error: "), err
    assert "Traceback" not in err[0]
    return err[0]


CASES = [
    # (id, body, prelude, what the line says)
    ("sys.exit(0) in f", "sys.exit(0)", "", "called sys.exit(0)"),
    ("sys.exit(3) in f", "sys.exit(3)", "", "called sys.exit(3)"),
    ("sys.exit() at import", "return g.irradiance", "sys.exit()", "line 3 called sys.exit(None)"),
    ("sys.exit('bye') at import", "return g.irradiance", "sys.exit('bye')", "called sys.exit('bye')"),
    ("os._exit(0) in f", "os._exit(0)", "", "exited with status 0 while checking it"),
    ("os._exit(0) at import", "return g.irradiance", "os._exit(0)", "exited with status 0 while loading it"),
    ("os._exit(7) at import", "return g.irradiance", "os._exit(7)", "exited with status 7 while loading it"),
    ("SIGKILL itself", "os.kill(os.getpid(), 9)", "", "was killed by SIGKILL while checking it"),
    ("KeyboardInterrupt in f", "raise KeyboardInterrupt", "", "raised KeyboardInterrupt while checking"),
    ("KeyboardInterrupt at import", "return g.irradiance", "raise KeyboardInterrupt", "while loading"),
    ("GeneratorExit in f", "raise GeneratorExit('x')", "", "GeneratorExit while checking it: x"),
    ("complex result", "return g.irradiance * (1 + 1j)", "", "returned complex numbers on NumPy"),
    ("complex scalar", "return 0 * g.irradiance + 1j", "", "returned complex numbers"),
]


@pytest.mark.parametrize(("body", "prelude", "says"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_user_code_ending_the_process_is_one_line(capsys, tmp_path, body, prelude, says):
    path = user_file(tmp_path, body, prelude)
    line = refused(capsys, tmp_path, f"{path}:f")
    assert says in line
    assert "f" in line.split(": ")[2] or f"{path}:f" in line  # names the function (or its spec)
    assert "ComplexWarning" not in line


@pytest.mark.parametrize("where", ["import", "function"])
def test_endless_loop_is_stopped_by_the_time_limit(capsys, tmp_path, monkeypatch, where):
    monkeypatch.setenv(TIMEOUT_ENV, "2")
    body, prelude = (
        ("while True: pass", "") if where == "function" else ("return g.irradiance", "while 1: pass")
    )
    path = user_file(tmp_path, body, prelude)
    t0 = time.monotonic()
    line = refused(capsys, tmp_path, f"{path}:f")
    assert "did not finish within 2 s" in line and TIMEOUT_ENV in line
    assert ("checking" if where == "function" else "loading") in line
    assert time.monotonic() - t0 < 60  # 2 s of user code, plus the child's start on a loaded machine


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "1e9", "soon"])
def test_bad_timeout_variable(capsys, tmp_path, monkeypatch, value):
    monkeypatch.setenv(TIMEOUT_ENV, value)
    path = user_file(tmp_path, "return g.irradiance")
    line = refused(capsys, tmp_path, f"{path}:f")
    assert f"${TIMEOUT_ENV}=" in line and "expected seconds" in line


@pytest.mark.parametrize("approx", ["", ",", ",,,", " , "])
def test_approx_naming_nothing(capsys, tmp_path, approx):
    assert "names no approximation" in refused(capsys, tmp_path, approx)


def test_a_warning_is_one_line_and_the_audit_goes_on(capsys, tmp_path):
    path = user_file(tmp_path, "warnings.warn('careful'); return g.irradiance")
    rc, err, out = audit_list(capsys, tmp_path, f"{path}:f")
    assert rc == 0, err
    assert err == [f"rtfit: warning: {path}:f: mine.py line 7: UserWarning: careful"]
    assert "yours: f (light_irradiance)" in out


def test_a_valid_approximation_loads_in_process(tmp_path):
    path = user_file(tmp_path, "return g.irradiance * ops.maximum(g.cos_theta + 0 * w, 0.0)")
    m = load_validated(f"{path}:f")
    c = np.linspace(-1.0, 1.0, 5)
    g = {"cos_theta": c, "irradiance": 2.0 + 0 * c, "alpha": 0.1 + 0 * c, "distance": 3.0 + 0 * c}
    np.testing.assert_array_equal(m(np_ops(), g, {"w": 0.5}), 2.0 * np.maximum(c, 0.0))


def np_ops():
    from rtfit.realtime import NUMPY_OPS

    return NUMPY_OPS


def test_in_process_sys_exit_is_a_user_method_error(tmp_path):
    """The library functions, called in the caller's process: sys.exit is a one-line error there too."""
    with pytest.raises(UserMethodError, match=r"line 3 called sys.exit\(4\)"):
        load_approximation(f"{user_file(tmp_path, 'return g.irradiance', 'sys.exit(4)')}:f")

    @approximation(quantity="light_irradiance", params={"w": Param(0.5, lower=0.0, upper=1.0)})
    def quits(ops, g, *, w):
        sys.exit(0)

    with pytest.raises(UserMethodError, match=r"^quits: called sys.exit\(0\)"):
        check_approximation(quits)


def test_complex_refused_without_complex_warning():
    @approximation(quantity="light_irradiance")
    def cplx(ops, g):
        return g.irradiance * (1 + 2j)

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a leaked ComplexWarning would fail here
        with pytest.raises(UserMethodError, match=r"^cplx: returned complex numbers on NumPy"):
            check_approximation(cplx)


def test_exit_status_of_the_real_command(tmp_path):
    """The installed command, end to end: sys.exit(0) in the function is exit 2 and one line, not 0."""
    path = user_file(tmp_path, "sys.exit(0)")
    proc = subprocess.run(
        [sys.executable, "-m", "rtfit", "audit", SCENE, "--list", "--approx", f"{path}:f"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "rtfit: error: f: called sys.exit(0) (an approximation must return values or raise an exception)"
    ]


def test_module_spec_and_entry_point_are_found_by_the_child(capsys, tmp_path, monkeypatch):
    """The child process gets rtfit's sys.path: a module on it, and an entry point of an installed
    distribution found through it, load there as in rtfit's own process."""
    (tmp_path / "studio_wraps_rtfit.py").write_text(
        "from rtfit import approximation\n\n"
        "@approximation(quantity='light_irradiance')\n"
        "def soft(ops, g):\n    return g.irradiance * ops.maximum(g.cos_theta, 0.0)\n"
    )
    dist = tmp_path / "studio_wraps_rtfit-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: studio-wraps-rtfit\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[rtfit.approximations]\nstudio_soft = studio_wraps_rtfit:soft\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        for spec in ("studio_wraps_rtfit:soft", "studio_soft"):
            rc, err, out = audit_list(capsys, tmp_path, spec)
            assert rc == 0, err
            assert "yours: soft (light_irradiance)" in out
    finally:
        sys.modules.pop("studio_wraps_rtfit", None)


_SPHERE_POINT_XML = (
    '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="30"/>'
    '<transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>'
    '<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>'
    '</sensor><shape type="sphere"/><emitter type="point"><point name="position" x="0" y="-4" z="4"/>'
    '<float name="intensity" value="10"/></emitter></scene>'
)
"""A unit sphere lit by a point light, 8² pixels: the smallest scene a user approximation is audited on."""


def test_sys_exit_after_validation_is_still_one_line(capsys, tmp_path):
    """A function that passes validation (256 samples) and calls sys.exit on the scene's own pixels (here:
    any other count): the kernel turns the SystemExit into a one-line error, exit 2 — not rtfit's exit 0."""
    scene = tmp_path / "s.xml"
    scene.write_text(_SPHERE_POINT_XML)
    path = user_file(tmp_path, "return g.irradiance if len(g.cos_theta) == 256 else sys.exit(0)")
    out = tmp_path / "out"
    argv = ["-q", "audit", str(scene), "--approx", f"{path}:f", "--spp", "4", "--pass-spp", "2", "--no-fit"]
    rc = main([*argv, "--out", str(out), "--cache", str(tmp_path / "cache")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert err == [
        "rtfit: error: f: called sys.exit(0) (an approximation must return values or raise an exception)"
    ]
    assert not out.exists()


def test_prints_of_user_code_do_not_spoil_json_on_stdout(tmp_path):
    """``--json -``: stdout holds the JSON document alone. An approximation that prints (at import and on
    every call) put its lines first on stdout and the document did not parse (the re-check of issue 32);
    now they go to stderr. The installed command, end to end (a print reaches file descriptor 1)."""
    import json

    scene = tmp_path / "s.xml"
    scene.write_text(_SPHERE_POINT_XML)
    path = user_file(tmp_path, "print('in f'); return g.irradiance", "print('at import')")
    argv = ["audit", str(scene), "--approx", f"{path}:f", "--spp", "4", "--pass-spp", "2", "--no-fit"]
    argv += ["--out", str(tmp_path / "out"), "--cache", str(tmp_path / "cache"), "--json", "-"]
    proc = subprocess.run(
        [sys.executable, "-m", "rtfit", "-q", *argv], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["format"] == "rtfit.audit-summary/1"
    assert "at import" in proc.stderr and "in f" in proc.stderr
