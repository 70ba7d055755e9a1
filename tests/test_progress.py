"""Progress through a run's stages (issue 37, `rtfit.experiments.progress.Stage`): on a terminal a tqdm bar
on stderr, without one the lines unchanged; the audit's stages (references per part, rows per case)
through it; ``rtfit audit … --json -`` with stderr on a pseudo-terminal keeps stdout pure JSON while the
bars are drawn. Oracles: the text written to (fake or pseudo) terminals and the lines said."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from rtfit.experiments.audit_run import audit
from rtfit.experiments.progress import Stage

CBOX = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
SMALL = {"width": 16, "height": 16, "spp": 4, "pass_spp": 2, "fit": False, "cost_elements": 1 << 12}


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_stage_draws_a_bar_on_a_terminal_and_says_lines_otherwise(monkeypatch):
    tty = _Terminal()
    monkeypatch.setattr(sys, "stderr", tty)
    said: list[str] = []
    with Stage(3, "cases", enabled=True, say=said.append) as st:
        assert st.drawn
        st.note("first: starting")
        for i in range(3):
            st.advance(f"case{i}: 2 rows evaluated")
    text = tty.getvalue()
    assert said == [] and "cases" in text and "1/3" in text and "3/3" in text, text
    assert "case1: 2 rows evaluated" in text  # the step's line is the bar's postfix

    # enabled but stderr is not a terminal, or a terminal without the flag: the lines, unchanged
    for stream, enabled in ((io.StringIO(), True), (_Terminal(), False)):
        monkeypatch.setattr(sys, "stderr", stream)
        said.clear()
        with Stage(2, "cases", enabled=enabled, say=said.append) as st:
            assert not st.drawn
            st.note("a: starting")
            st.advance("a: 2 rows evaluated")
            st.advance()
        assert said == ["a: starting", "a: 2 rows evaluated"] and stream.getvalue() == ""


def test_the_audit_draws_its_stages_on_a_terminal_and_says_its_lines_without_one(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    said: list[str] = []
    audit(CBOX, ["diffuse"], cache=cache, say=said.append, progress=True, metrics=("rmse",), **SMALL)
    assert said[1].startswith("diffuse: references for area light") and said[2:] == [
        "light0-unshadowed: 3 rows evaluated",
        "light0-shadowed: 3 rows evaluated",
    ], said  # stderr is not a terminal under pytest: the lines as before
    tty = _Terminal()
    monkeypatch.setattr(sys, "stderr", tty)
    said.clear()
    audit(CBOX, ["diffuse"], cache=cache, say=said.append, progress=True, metrics=("rmse",), **SMALL)
    text = tty.getvalue()
    assert len(said) == 1 and said[0].startswith("camera:"), said  # the stage lines became bars
    assert "references" in text and "diffuse: cases" in text and "2/2" in text, text
    assert "light0-shadowed: 3 rows evaluated" in text


@pytest.mark.skipif(sys.platform == "win32", reason="needs a pseudo-terminal")
def test_audit_json_to_stdout_stays_json_with_bars_on_a_terminal(tmp_path):
    """stderr on a pseudo-terminal (bars drawn), stdout a pipe: stdout holds exactly the JSON summary."""
    import fcntl
    import struct
    import termios

    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 160, 0, 0))  # a new pty is 0 columns wide
    cmd = [sys.executable, "-m", "rtfit", "audit", str(CBOX), "--approx", "diffuse", "--width", "16",
           "--height", "16", "--spp", "4", "--pass-spp", "2", "--no-fit", "--json", "-", "--cache",
           str(tmp_path / "cache")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, text=True, cwd=tmp_path)
    os.close(slave)
    chunks: list[bytes] = []

    def drain():
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    out, _ = proc.communicate(timeout=300)
    reader.join(timeout=10)
    os.close(master)
    err = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 0, err
    summary = json.loads(out)  # nothing but the JSON on stdout
    assert summary and "rows evaluated" not in out
    assert "references" in err and "diffuse: cases" in err and "%|" in err, err
