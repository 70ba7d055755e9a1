"""``rtfit run FAMILY`` of a family born on the engine (issue 30 §1, `rtfit.experiments.engine_run`).

A planted family — the diffuse audit declaration, shipping rtfit's ``sphere_light.toml`` — is run as
``rtfit run`` runs it: the engine audits its shipped scene, and the results document, report, viewer pixels
and ``fitted/<family>.json`` are those of every run. Expected values are independent: the exact row of the
unshadowed case against the reference within its noise (the engine's z-check, which a planted reference bias
makes fail), and a planted study's check failing the run."""

from __future__ import annotations

import json

import pytest

from rtfit.experiments import audit_diffuse, engine_run
from rtfit.experiments.families import ENGINE, FAMILIES, Family
from rtfit.experiments.records import Check, Fit, Section, to_json
from rtfit.experiments.registry import ExperimentSpec
from rtfit.experiments.results import load_results
from rtfit.experiments.run_settings import RunSettings
from rtfit.experiments.runner import failed_checks, run_experiments
from rtfit.experiments.shipped import ShippedScene, Sizes, Study
from rtfit.realtime import diffuse

SCENE = ShippedScene("sphere_light.toml", "sphere light", quick_size=(16, 16), quick_spp=8)


def _planted(monkeypatch, study=None, bench=None) -> ExperimentSpec:
    fam = Family(
        "diffuse",
        ENGINE,
        "planted",
        "the diffuse audit as a family born on the engine",
        methods=diffuse.METHODS,
        audits=(audit_diffuse.FAMILY,),
        scenes=(SCENE,),
        study=study,
        bench=bench,
    )
    monkeypatch.setattr(engine_run, "FAMILIES", {**FAMILIES, "diffuse": fam})
    return ExperimentSpec("diffuse", ENGINE, "planted", "d")


def _run(spec, tmp_path):
    out = tmp_path / "out"
    run_experiments([spec], out, RunSettings(tmp_path / "cache", "llvm_ad_rgb", quick=True))
    return out / "diffuse"


def test_the_engine_runs_a_family_on_its_shipped_scene(tmp_path, monkeypatch):
    seen = []

    def study(ctx):
        seen.append(ctx)
        rows = ctx.audits[0].outcomes["sphere_light-light0-unshadowed"]
        return Study(
            sections=(Section(id="study", title="Its own study", text=f"{len(rows)} rows"),),
            checks=(Check(name="study ran", value=len(rows), expected="> 0", passed=len(rows) > 0),),
            fits=(Fit(id="study-law", label="a law across scenes", parameters={"a": 1.5}),),
            extra={"rows": len(rows)},
        )

    spec = _planted(monkeypatch, study)
    assert isinstance(spec.load(), engine_run.EngineExperiment)
    d = _run(spec, tmp_path)
    doc = json.loads((d / "results.json").read_text())
    ids = [c["id"] for c in doc["cases"]]
    assert ids == ["sphere_light-light0-unshadowed", "sphere_light-light0-shadowed"]
    assert doc["cases"][0]["label"].startswith("sphere light (lights[0])")  # (one scene: no prefix)
    assert doc["config"]["extra"]["scenes"] == ["sphere_light"] and doc["config"]["quick"] is True
    assert doc["cases"][0]["reference"]["spp"] == 8
    # the engine's z-check of the exact row (closed form vs path-traced reference) and the study's check
    names = [c["name"] for c in doc["checks"]]
    assert any(n.startswith("exact vs the reference") for n in names), names
    assert "study ran" in names and not failed_checks(json_results(d))
    assert [s["id"] for s in doc["sections"]][:2] == ["scenes", "method-diffuse"]
    assert doc["sections"][-1]["id"] == "study" and doc["extra"] == {"rows": 9}
    fitted = json.loads((d / "fitted" / "diffuse.json").read_text())
    assert {m["case"] for m in fitted["methods"]} >= {"sphere_light_light0_unshadowed"}
    assert doc["fits"][-1]["id"] == "study-law" and doc["fits"][-1]["parameters"] == {"a": 1.5}
    assert all(f["file"] == "fitted/diffuse.json" for f in doc["fits"][:-1]) and doc["fits"][:-1]
    assert all((d / f["file"]).is_file() for f in doc["figures"])
    assert (d / "pixels").is_dir() and (d / "report.html").is_file()
    assert seen[0].quick and seen[0].out_dir.name != "diffuse"  # (the atomic directory being written)
    gb = seen[0].audits[0].gbuffer  # the G-buffer the cases were computed on, for the study
    case = seen[0].audits[0].cases[0]
    assert gb.mask.shape == (16, 16) and (case.mask <= gb.mask).all() and case.mask.any()


def json_results(d):
    return load_results(d)


def test_a_failed_study_check_fails_the_run(tmp_path, monkeypatch):
    spec = _planted(monkeypatch, lambda ctx: Study(checks=(Check(name="planted", value=1.0, passed=False),)))
    d = _run(spec, tmp_path)
    assert [c.name for c in failed_checks(json_results(d))] == ["planted"]


def test_configuration_is_declared_and_checked(monkeypatch):
    spec = _planted(monkeypatch)
    exp = spec.load()
    cfg = exp.configure(True, None)
    assert cfg == {"scenes": ["sphere_light"], "spp": None, "resolution": None, "fit": True}
    assert exp.configure(False, 64)["spp"] == 64
    from rtfit.experiments.registry import apply_overrides

    with pytest.raises(ValueError, match="expected one of sphere_light"):
        apply_overrides(cfg, {"scenes": ["other.xml"]}, "diffuse", declared=exp.CONFIG)
    with pytest.raises(ValueError, match=r"out of range \[2, "):
        apply_overrides(cfg, {"spp": 1}, "diffuse", declared=exp.CONFIG)


def test_a_family_run_by_the_engine_ships_scenes():
    with pytest.raises(ValueError, match="ships its scenes"):
        Family("x", ENGINE, "t", "d")
    with pytest.raises(ValueError, match=r"a \.xml or \.toml file name"):
        ShippedScene("../x.xml", "x")


def test_bench_times_every_method_with_declared_domains(monkeypatch):
    from rtfit.experiments.registry import BenchContext

    spec = _planted(monkeypatch)
    rows = spec.load().bench(BenchContext(variant="llvm_ad_rgb", size=1 << 12, quick=True))
    whats = [r["what"] for r in rows]
    assert whats[-1].startswith("memory baseline") and len(whats) >= 3
    assert all(r["ns_per_px"] > 0 for r in rows)


def test_a_family_bench_hook_adds_its_rows_after_the_engine_rows(monkeypatch):
    from rtfit.experiments import nishita_sky_study
    from rtfit.experiments.registry import BenchContext

    given = []

    def own(ctx):
        given.append(ctx)
        return [{"what": "planted reference throughput", "backend": "llvm", "Mray_s": 1.0}]

    ctx = BenchContext(variant="llvm_ad_rgb", size=1 << 10, quick=True)
    plain = [r["what"] for r in _planted(monkeypatch).load().bench(ctx)]
    rows = [r["what"] for r in _planted(monkeypatch, bench=own).load().bench(ctx)]
    assert rows == [*plain, "planted reference throughput"] and given == [ctx]
    with pytest.raises(ValueError, match="ships its scenes"):
        Family("x", "rtfit.experiments.x", "t", "d", bench=own)  # (an old module has its own bench)
    assert FAMILIES["nishita-sky"].bench.target is nishita_sky_study.bench


def test_every_shipped_scene_of_the_registry_is_in_the_library():
    from rtfit.scenes.parse import LIBRARY_DIR

    shipped = [(f.name, s) for f in FAMILIES.values() for s in f.scenes]
    assert shipped, "no family is born on the engine"
    for family, s in shipped:
        assert (LIBRARY_DIR / s.file).is_file(), f"{family}: {s.file}"
    names = [f"{family}/{s.name}" for family, s in shipped]
    assert len(set(names)) == len(names)


def test_defines_name_the_scene_and_reach_the_audit():
    s = ShippedScene("x.xml", "x", defines={"alpha": "5", "sky": "0.2"})
    assert s.name == "x-alpha5-sky0_2"
    with pytest.raises(ValueError, match="defines are for Mitsuba XML"):
        ShippedScene("x.toml", "x", defines={"a": "1"})


def test_sizes_give_a_scene_its_full_and_quick_sizes():
    """`Sizes` writes (width, height, spp) once: its scene is the `ShippedScene` of those fields."""
    s = Sizes(full=(64, 48, 256), quick=(24, 16, 32)).scene("x.xml", "x", quick=False, defines={"a": "1"})
    assert s == ShippedScene(
        "x.xml",
        "x",
        size=(64, 48),
        spp=256,
        quick_size=(24, 16),
        quick_spp=32,
        quick=False,
        defines={"a": "1"},
    )
    for bad in ((64, 64), (64, 64, 0), (64, 64, 2.5)):
        with pytest.raises(ValueError, match=r"\(width, height, spp\)"):
            Sizes(full=bad, quick=(8, 8, 8))  # type: ignore[arg-type]


def test_a_shipped_xml_scene_is_named_like_a_toml_one():
    """`rtfit audit NAME` finds the library's Mitsuba XML scenes by name, as it finds its TOML ones."""
    from rtfit.experiments.audit import AuditError, inspect_scene
    from rtfit.scenes.parse import LIBRARY_DIR

    info = inspect_scene("fresnel_spheres")
    assert info.format == "mitsuba-xml" and info.source == str(LIBRARY_DIR / "fresnel_spheres.xml")
    assert inspect_scene("fresnel-spheres.xml").source == info.source
    with pytest.raises(AuditError, match="no such scene file"):
        inspect_scene("no_such_shipped_scene")


def test_a_shipped_scene_audits_only_the_roles_it_names(tmp_path, monkeypatch):
    """``quick_roles``: the roles left out are never asked for their cases (so nothing of theirs is
    rendered) and are named in the notes; the full run audits every role."""
    from rtfit.experiments import audit_ambient_aperture as aa

    def refused(setup, app):
        raise AssertionError(f"{app.role}: rendered although the scene does not audit it")

    monkeypatch.setitem(aa._CASES, aa.CAPS_ROLE, refused)
    scene = ShippedScene("aperture_hole.toml", "hole", quick_roles=(aa.LIGHT_ROLE,))
    assert scene.audited(True) == ((aa.LIGHT_ROLE,), None) and scene.audited(False) == (None, None)
    roles, quantities = scene.audited(True)
    r = engine_run.audit(
        engine_run.LIBRARY_DIR / scene.file, ["ambient-aperture"], spp=8, width=8, height=8, fit=False,
        cache=tmp_path / "cache", roles=roles, quantities=quantities, metrics=("rmse",),
    )  # fmt: skip
    assert [c.id for c in r.cases] == ["light0-occluded"]
    notes = " ".join(to_json(r.results)["notes"])
    assert f"({aa.CAPS_ROLE}: " in notes and "not audited in this run" in notes


def test_a_shipped_scene_audits_only_the_quantities_it_names(tmp_path, monkeypatch):
    """``quick_quantities``: height fog's terrain without its transmittance case, whose ratio-tracking
    reference is then never rendered."""
    from rtfit.experiments import audit_height_fog as hf

    def refused(*args, **kwargs):
        raise AssertionError("the transmittance reference was rendered")

    monkeypatch.setattr(hf, "_transmittance", refused)
    r = engine_run.audit(
        engine_run.LIBRARY_DIR / "fog_terrain_e40_single.toml", ["height-fog"], spp=4, width=8, height=4,
        fit=False, cache=tmp_path / "cache", quantities=("fogged_radiance",), metrics=("rmse",),
    )  # fmt: skip
    assert [c.id for c in r.cases] == ["fog0-radiance"]


def test_a_shipped_scene_names_only_its_family_roles_and_quantities():
    fam = FAMILIES["height-fog"]
    for bad, word in (
        ({"quick_roles": ("no such role",)}, "role"),
        ({"quantities": ("radiance",)}, "quantity"),
    ):
        scene = ShippedScene("fog_transmittance.toml", "x", **bad)
        with pytest.raises(ValueError, match=f"names the {word}"):
            engine_run._check_selections(fam, [scene])
    engine_run._check_selections(fam, fam.scenes)  # (the shipped ones are right)


def test_a_failing_family_does_not_stop_the_others(tmp_path, monkeypatch):
    """``rtfit run all`` goes on past a family that fails (the quick suite's nishita-sky failure left 15
    families unrun): the others' reports and the index are written, then one RunFailed names the failure."""
    from rtfit.experiments.runner import RunFailed

    good = _planted(monkeypatch)
    bad = ExperimentSpec("broken", ENGINE, "planted", "d")

    class _Broken:
        def run(self, ctx):
            raise ValueError("planted failure")

    monkeypatch.setattr(ExperimentSpec, "load", lambda self: _Broken() if self.name == "broken" else
                        engine_run.experiment(self.name))  # fmt: skip
    out = tmp_path / "out"
    with pytest.raises(RunFailed, match=r"1 of 2 experiment\(s\) failed: broken: .*planted failure"):
        run_experiments([bad, good], out, RunSettings(tmp_path / "cache", "llvm_ad_rgb", quick=True))
    assert (out / "diffuse" / "report.html").exists() and (out / "index.html").exists()
    assert not (out / "broken").exists()
