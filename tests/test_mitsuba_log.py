"""Mitsuba's log through rtfit's logging (issue 32): its warnings are one ``rtfit: warning: mitsuba: …``
line on stderr, without colour codes or timestamps, and nothing of them reaches stdout."""

from __future__ import annotations

from rtfit.experiments.cli import main
from rtfit.reference.mitsuba_log import plain_text

NON_UNIFORM = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="sphere"><transform name="to_world"><scale x="1" y="2" z="1"/></transform></shape>
    <emitter type="point"><point name="position" x="0" y="-4" z="4"/><float name="intensity" value="1"/>
    </emitter>
</scene>
"""


def test_plain_text_strips_colour_and_prefix():
    raw = (
        "\x1b[31m2026-12-05 01:19:26 WARN  [Sphere] 'to_world' transform shouldn't contain\n scaling!\x1b[0m"
    )
    assert plain_text(raw) == "[Sphere] 'to_world' transform shouldn't contain scaling!"


def test_mitsuba_warning_is_one_stderr_line_not_stdout(capsys, tmp_path):
    (tmp_path / "s.xml").write_text(NON_UNIFORM)
    assert main(["audit", str(tmp_path / "s.xml"), "--list"]) == 0
    cap = capsys.readouterr()
    assert "\x1b[" not in cap.out and "WARN" not in cap.out and "non-uniform" not in cap.out
    assert "\x1b[" not in cap.err
    warned = [line for line in cap.err.splitlines() if "non-uniform" in line]
    assert warned == [
        "rtfit: warning: mitsuba: [Sphere] 'to_world' transform shouldn't contain non-uniform scaling!"
    ]
