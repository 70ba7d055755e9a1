"""The Python API as a notebook uses it (issue 37 §1): ``rtfit.audit`` of a Mitsuba scene dict (the one
``mi.load_dict`` takes), a loaded ``mi.Scene`` refused in one line, metrics as records with their noise
floor and resolved flag, and the inline HTML summary.

The scene: a diffuse sphere on a floor under a point light, 16 × 16 pixels, 4 samples per pixel (seconds).
Independent values: the dict's audit against the audit of the same scene written as an XML file by hand
(same renderer, same seed: the same reference within the float32 round-off of the two transforms), and
each RMSE record recomputed with NumPy from the arrays the result exposes."""

from __future__ import annotations

import math

import numpy as np
import pytest

import rtfit
from rtfit.experiments.audit import AuditError
from rtfit.fitting import MetricValue

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "mae"), "fit": False, "spp": 4, "pass_spp": 2}

XML = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 1, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
  </sensor>
  <emitter type="point" id="light">
    <point name="position" value="1, 3, 2"/>
    <rgb name="intensity" value="10, 10, 10"/>
  </emitter>
  <shape type="sphere" id="ball">
    <float name="radius" value="0.5"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
  </shape>
  <shape type="rectangle" id="floor">
    <transform name="to_world">
      <scale value="3"/><rotate x="1" angle="-90"/><translate value="0, -0.5, 0"/>
    </transform>
    <bsdf type="diffuse"/>
  </shape>
</scene>
"""


def scene_dict(mi, intensity: float = 10.0) -> dict:
    """The XML scene above, as a notebook writes it for ``mi.load_dict``."""
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "sensor": {
            "type": "perspective",
            "fov": 40,
            "to_world": T().look_at(origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 16, "height": 16},
        },
        "light": {
            "type": "point",
            "position": [1, 3, 2],
            "intensity": {"type": "rgb", "value": [intensity] * 3},
        },
        "ball": {
            "type": "sphere",
            "radius": 0.5,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}},
        },
        "floor": {
            "type": "rectangle",
            "to_world": T().translate([0, -0.5, 0]).rotate([1, 0, 0], -90).scale(3),
            "bsdf": {"type": "diffuse"},
        },
    }


@pytest.fixture(scope="module")
def audited(tmp_path_factory):
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    cache = tmp_path_factory.mktemp("cache")
    d = scene_dict(mi)
    r = rtfit.audit(d, "diffuse", cache=cache, **FAST)
    assert mi.variant() == "scalar_rgb"  # the caller's variant is put back
    return d, r, cache


def test_a_scene_dict_is_audited_as_its_xml_file(audited, tmp_path):
    """The dict's audit and the audit of the same scene written by hand as XML: the same cases, rows and
    reference (same renderer, same seed; the transforms are composed in float32 in another order)."""
    _d, r, cache = audited
    path = tmp_path / "ball.xml"
    path.write_text(XML)
    x = rtfit.audit(path, "diffuse", cache=cache, **FAST)
    assert r.info.source == "scene dict"
    assert [c.id for c in r.cases] == [c.id for c in x.cases] == ["light0-unshadowed", "light0-shadowed"]
    for c in x.cases:
        assert list(r.outcomes[c.id]) == list(x.outcomes[c.id])
        np.testing.assert_allclose(r.reference(c.id), x.reference(c.id), rtol=2e-5, atol=1e-7)


def test_metrics_are_records_with_their_noise_floor(audited):
    """``metrics(case, row)``: `MetricValue` records; the RMSE recomputed with NumPy over the case's mask;
    ``resolved`` is the RMSE above twice its floor; ``metric_values`` the bare floats; ``float(m)``."""
    _d, r, _cache = audited
    case = r.cases[0]
    for row in r.outcomes[case.id]:
        m = r.metrics(case.id, row)
        assert set(m) == {"rmse", "mae"} and all(isinstance(v, MetricValue) for v in m.values())
        diff = (r.image(case.id, row) - r.reference(case.id))[case.mask]
        assert m["rmse"].value == pytest.approx(math.sqrt(np.mean(diff**2)), rel=1e-5)
        assert m["rmse"].noise_floor > 0.0
        assert m["rmse"].resolved == (m["rmse"].value > 2.0 * m["rmse"].noise_floor)
        assert r.metric_values(case.id, row) == {k: v.value for k, v in m.items()}
        assert float(m["mae"]) == m["mae"].value
    # Lambert under a point light is the unshadowed reference itself (I·cos θ/d²): within the noise
    assert not r.metrics(case.id, "lambert")["rmse"].resolved
    assert r.metrics(case.id, "half-lambert")["rmse"].resolved


def test_inline_summary_lists_every_row_with_its_floor(audited):
    """``_repr_html_``: one table row per case × row, with the RMSE and floor of ``summary_rows``."""
    _d, r, _cache = audited
    page = r._repr_html_()
    rows = r.summary_rows()
    assert len(rows) == sum(len(v) for v in r.outcomes.values())
    assert page.count("<tr>") == len(rows) + 1  # + the header
    for s in rows:
        assert f"{s.rmse:.4g}" in page and f"{s.rmse_floor:.2g}" in page
    assert "within the noise" in page and "<script" not in page
    # the images: per case its reference and every row, as PNG data URIs
    assert page.count("data:image/png;base64,") == sum(1 + len(v) for v in r.outcomes.values())


def test_inline_png_decodes_to_the_image():
    """`png_data_uri` read back by Matplotlib's PNG decoder: the 8-bit values (x/scale)^(1/2.2), clipped."""
    import base64
    import io

    from matplotlib.image import imread

    from rtfit.experiments.audit_api import png_data_uri

    img = np.random.default_rng(3).uniform(0.0, 3.0, (5, 7, 3))
    img[0, 0] = np.nan
    uri = png_data_uri(img, 2.0)
    back = imread(io.BytesIO(base64.b64decode(uri.split(",", 1)[1])), format="png")
    expect = np.clip(np.nan_to_num(img) / 2.0, 0.0, 1.0) ** (1 / 2.2)
    assert back.shape == (5, 7, 3)
    np.testing.assert_allclose(back, expect, atol=0.5 / 255 + 1e-6)


def test_to_dataframe_without_pandas_says_so(audited):
    _d, r, _cache = audited
    try:
        import pandas  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="pip install pandas"):
            r.to_dataframe()
    else:
        assert len(r.to_dataframe()) == len(r.summary_rows())


def test_dict_cache_key_follows_its_values(audited, tmp_path):
    """The dict's pass-cache key covers its values: the same dict again is the same key; a brighter light is
    another key (and a reference 2 × brighter, within float32)."""
    import mitsuba as mi

    from rtfit.experiments.audit import inspect_scene

    _d, r, cache = audited
    same = inspect_scene(scene_dict(mi)).xml
    brighter = inspect_scene(scene_dict(mi, 20.0)).xml
    assert same is not None and brighter is not None
    assert same.dependencies.digest == r.info.xml.dependencies.digest != brighter.dependencies.digest
    r2 = rtfit.audit(scene_dict(mi, 20.0), "diffuse:lambert", cache=cache, **FAST)
    np.testing.assert_allclose(
        r2.reference("light0-unshadowed"), 2 * r.reference("light0-unshadowed"), rtol=1e-5
    )


def test_a_loaded_scene_and_objects_are_refused_in_one_line(audited):
    import mitsuba as mi

    d, _r, _cache = audited
    with pytest.raises(AuditError, match=r"a loaded mitsuba Scene cannot be audited: .*pass the dict") as e:
        rtfit.audit(mi.load_dict(d))
    assert "\n" not in str(e.value)
    with pytest.raises(AuditError, match=r"^scene dict: .*not an instantiated object"):
        rtfit.audit({**d, "extra": mi.load_dict({"type": "sphere"})})
    with pytest.raises(AuditError, match=r"^scene dict: -D parameters are for XML files"):
        rtfit.audit(d, defines={"x": "1"})
    with pytest.raises(AuditError, match=r"^int: expected a scene file's path or a scene dict"):
        rtfit.audit(3)


def test_the_notebook_example_runs(tmp_path):
    """``examples/notebook_audit.py`` (the notebook's cells as a script) runs to the end in a fresh
    interpreter: a metric with its floor, and the inline summary's table."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).parents[1] / "examples" / "notebook_audit.py"
    done = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "cache")], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "half-Lambert RMSE" in done.stdout and "noise floor" in done.stdout
    assert "<table>" in done.stdout and "within the noise" in done.stdout


# ---------------------------------------------------------------------------------------------- the CLI
def test_audit_json_to_stdout_is_the_document_alone(tmp_path):
    """``rtfit audit SCENE --json -`` (the real command in a child process): stdout parses as one JSON
    document (rtfit.audit-summary/1) with every case × row, its metrics as records with their floor; the
    human lines are on stderr."""
    import json
    import subprocess
    import sys

    path = tmp_path / "ball.xml"
    path.write_text(XML)
    done = subprocess.run(
        [sys.executable, "-m", "rtfit", "audit", str(path), "--approx", "diffuse", "--spp", "4",
         "--pass-spp", "2", "--no-fit", "--out", str(tmp_path / "out"), "--cache", str(tmp_path / "cache"),
         "--json", "-"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    doc = json.loads(done.stdout)
    assert doc["format"] == "rtfit.audit-summary/1" and doc["scene"].endswith("ball.xml")
    assert [c["id"] for c in doc["cases"]] == ["light0-unshadowed", "light0-shadowed"]
    rmse = {r["row"]: r["metrics"]["rmse"] for r in doc["cases"][0]["rows"]}
    assert set(rmse["lambert"]) == {"value", "noise_floor", "resolved", "debiased"}
    assert rmse["lambert"]["resolved"] is False and rmse["half-lambert"]["resolved"] is True
    assert doc["report"].endswith("report.html") and "summary: " in done.stderr


def test_list_json_and_name_completion():
    """``rtfit list --json``: every family once with its methods and quantities (the registry's own); shell
    completion of experiment names, ``--approx`` items after a comma, and library scene names."""
    import json

    from click.shell_completion import ShellComplete
    from click.testing import CliRunner

    from rtfit.experiments.cli import cli
    from rtfit.experiments.families import AUDITED, FAMILIES, METHOD_TABLES

    out = CliRunner().invoke(cli, ["list", "--json"])
    assert out.exit_code == 0, out.output
    fams = {f["name"]: f for f in json.loads(out.stdout)["families"]}
    assert list(fams) == list(FAMILIES)
    assert fams["diffuse"]["audited"] is True and fams["diffuse"]["quantities"][0] == "light_irradiance"
    assert fams["diffuse"]["methods"] == list(METHOD_TABLES["diffuse"])
    assert {n for n, f in fams.items() if f["audited"]} == set(AUDITED)

    def complete(args, incomplete):
        return [
            c.value
            for c in ShellComplete(cli, {}, "rtfit", "_RTFIT_COMPLETE").get_completions(args, incomplete)
        ]

    assert complete(["run"], "dif") == ["diffuse"]
    assert "height-fog" in complete(["run", "diffuse"], "he") and "all" in complete(["bench"], "a")
    assert complete(["audit", "x.xml", "--approx"], "diffuse,diffuse:wr") == ["diffuse,diffuse:wrap"]
    assert "sphere_light" in complete(["audit"], "sphere_l")


def test_audit_json_bad_targets_are_one_line(tmp_path):
    """``--json`` into a folder, into a missing folder, or with ``--list``: one line, exit 2, nothing run."""
    from click.testing import CliRunner

    from rtfit.experiments.cli import cli

    path = tmp_path / "ball.xml"
    path.write_text(XML)
    for args, text in (
        (["--json", str(tmp_path)], "a folder"),
        (["--json", str(tmp_path / "no" / "x.json")], "no folder"),
        (["--list", "--json", "-"], "--list prints"),
    ):
        out = CliRunner().invoke(cli, ["audit", str(path), *args])
        assert out.exit_code == 2 and text in out.stderr and len(out.stderr.strip().splitlines()) == 1, (
            out.output
        )
