"""scripts/bootstrap.sh is sourceable: it leaves the caller's shell options alone, and a failing step
returns 1 to the caller instead of closing its shell (no ``set -e`` inside a sourced file)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BOOTSTRAP = ROOT / "scripts" / "bootstrap.sh"
pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash is not installed")


def _bash(script: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", "-c", script],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        env={**os.environ, **env},
        check=False,
    )


def test_sourcing_keeps_the_callers_options_and_puts_rtfit_on_path():
    venv = str(Path(sys.prefix))  # the environment running these tests: already set up
    for opts in ("", "set -euo pipefail"):
        r = _bash(
            f'{opts}\nbefore="$(set +o; shopt -p)"\nsource scripts/bootstrap.sh\necho "rc=$?"\n'
            'after="$(set +o; shopt -p)"\n[ "$before" = "$after" ] && echo same\ncommand -v rtfit',
            RTFIT_VENV=venv,
        )
        lines = r.stdout.split()
        assert r.returncode == 0 and "rc=0" in lines and "same" in lines, (opts, r.stdout, r.stderr)
        assert lines[-1] == str(Path(venv) / "bin" / "rtfit")


def test_a_failing_step_returns_1_and_the_callers_shell_goes_on(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    r = _bash(
        'before="$(set +o; shopt -p)"\nsource scripts/bootstrap.sh\necho "rc=$?"\n'
        'after="$(set +o; shopt -p)"\n[ "$before" = "$after" ] && echo same\necho still-here',
        RTFIT_VENV=str(blocker / "venv"),  # cannot be created: its parent is a file
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["rc=1", "same", "still-here"], r.stdout
    assert "rtfit setup: could not create the virtual environment" in r.stderr
