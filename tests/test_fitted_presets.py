"""Engine presets inside the fitted files (issue 37 §3): a fitted file written by a run or an audit carries,
in ``engine_presets``, its methods in the properties of every engine with the same effect, made by the one
conversion behind ``rtfit fitted convert`` (`rtfit.experiments.engine_presets.engine_section`); the command
reads that section back; the loader and the shipped schema refuse a malformed section with one line.

Independent values: the presets' Unreal/HDRP/Godot properties read back through each engine's documented
inverse (`Engine.from_engine`) give the file's own b and c; a section edited by hand is noticed."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from rtfit.experiments.audit_output import write_fitted_file
from rtfit.experiments.cli import cli
from rtfit.experiments.engine_presets import ENGINES
from rtfit.experiments.fitted import FittedError, fitted_json_schema, load_fitted, method_entry
from rtfit.experiments.preset_records import ENGINE_NAMES
from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.realtime.height_fog import METHODS as FOG
from rtfit.realtime.irradiance_bases import METHODS as IB
from rtfit.realtime.nishita_sky import METHODS as SKY

HEADER = ("format", "source", "experiment", "engine")
CONST = {"b": 3.164e-4, "c": 3.109e-2, "r0": 0.068, "g0": 0.0466, "b0": 0.0315}
LOBE = {"r1": 0.05, "g1": 0.04, "b1": 0.02, "g": 0.7}
DOMAIN = {"z0": (2.0, 2.0), "z1": (0.5, 5000.0), "distance": (7.0, 7e4), "cos_sun": (-1.0, 1.0)}


def _write(path, entries, experiment="height-fog"):
    """The audit's writer (`audit_output.write_fitted_file`, as ``rtfit audit`` and the engine's runs call
    it) on ``entries``; returns the written JSON."""
    write_fitted_file(path, f"{experiment} (test)", experiment, entries, (), "scalar_rgb", True)
    return json.loads(path.read_text(encoding="utf-8"))


def _fog_file(tmp_path):
    entries = [
        method_entry(FOG["const"], params=CONST, case="fog0", domain=DOMAIN),
        method_entry(FOG["phase"], params={**CONST, **LOBE}, case="fog0", domain=DOMAIN),
    ]
    return tmp_path / "fog.json", _write(tmp_path / "fog.json", entries)


def _convert(path, engine, *args):
    return CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", engine, *args])


def test_written_height_fog_file_carries_what_convert_prints(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    path, doc = _fog_file(tmp_path)
    jsonschema.validate(doc, fitted_json_schema(), cls=jsonschema.Draft202012Validator)
    assert list(doc["engine_presets"]) == list(ENGINE_NAMES)
    for engine in ENGINE_NAMES:
        out = _convert(path, engine)
        assert out.exit_code == 0 and out.stderr == "", out.output
        printed = json.loads(out.stdout)
        assert printed["engine"] == engine and printed["source"] == str(path)
        assert {k: v for k, v in printed.items() if k not in HEADER} == doc["engine_presets"][engine]
        section = doc["engine_presets"][engine]
        assert section["sources"] and all(s.startswith("https://") for s in section["sources"])
        assert [(p["method"], p["case"]) for p in section["presets"]] == [
            ("const", "fog0"),
            ("phase", "fog0"),
        ]
        for p in section["presets"]:
            assert p["lost"] and all(v["unit"] for v in p["values"])
            values = {v["name"]: (tuple(v["value"]) if isinstance(v["value"], list) else v["value"])
                      for v in p["values"]}  # fmt: skip
            b, c, _ = ENGINES[engine].from_engine(values, p["base_height_m"])
            assert b == pytest.approx(CONST["b"], rel=1e-12) and c == pytest.approx(CONST["c"], rel=1e-12)
    # HDRP and Godot anchor at the lowest height the fit saw, Unreal at rtfit's origin
    bases = {e: doc["engine_presets"][e]["presets"][0]["base_height_m"] for e in ENGINE_NAMES}
    assert bases == {"unreal": 0.0, "unity-hdrp": 0.5, "godot": 0.5}


def test_only_engines_with_the_same_effect_are_written(tmp_path):
    """A diffuse fit has no engine section; the Nishita sky's artist fit has Unreal's and HDRP's (Godot's sky
    is not converted: `rtfit fitted convert`'s one line); an SH L2 irradiance fit all three engines'."""
    assert "engine_presets" not in _write(tmp_path / "d.json", [method_entry(DIFFUSE["wrap"])], "diffuse")
    sky = next(m for m in SKY.values() if {"rayleigh_scale", "mie_scale", "mie_g"} <= set(m.params))
    doc = _write(tmp_path / "s.json", [method_entry(sky)], "nishita-sky")
    assert list(doc["engine_presets"]) == ["unreal", "unity-hdrp"]
    doc = _write(tmp_path / "i.json", [method_entry(IB["sh-l2-lambda"], params={"lam": 0.02})], "ib")
    assert list(doc["engine_presets"]) == list(ENGINE_NAMES)


def test_convert_reads_the_section_back(tmp_path):
    """The file's section is what the command prints; a section edited by hand (FogDensity doubled) is said
    on stderr and the conversion of the file's values printed; --base-height converts anew."""
    path, doc = _fog_file(tmp_path)
    edited = json.loads(json.dumps(doc))
    density = edited["engine_presets"]["unreal"]["presets"][0]["values"][0]
    assert density["name"] == "FogDensity"
    density["value"] *= 2.0
    path.write_text(json.dumps(edited), encoding="utf-8")
    out = _convert(path, "unreal")
    assert out.exit_code == 0 and "differs from this rtfit's conversion" in out.stderr
    assert len(out.stderr.splitlines()) == 1
    printed = json.loads(out.stdout)
    assert {k: v for k, v in printed.items() if k not in HEADER} == doc["engine_presets"]["unreal"]
    out = _convert(path, "godot", "--base-height", "3")
    assert out.exit_code == 0 and out.stderr == ""
    assert json.loads(out.stdout)["presets"][0]["base_height_m"] == 3.0


def test_malformed_section_is_refused_with_one_line(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    _, good = _fog_file(tmp_path)

    def refused(change, match, schema_too=True):
        bad = json.loads(json.dumps(good))
        change(bad["engine_presets"])
        target = tmp_path / "bad.json"
        target.write_text(json.dumps(bad), encoding="utf-8")
        with pytest.raises(FittedError, match=match) as e:
            load_fitted(target)
        assert "\n" not in str(e.value) and str(e.value).startswith(f"{target}: engine_presets")
        if schema_too:
            with pytest.raises(jsonschema.ValidationError):
                jsonschema.validate(bad, fitted_json_schema(), cls=jsonschema.Draft202012Validator)

    def value(ps):
        ps["unreal"]["presets"][0]["values"][0]["value"] = "dense"

    def no_lost(ps):
        del ps["godot"]["presets"][1]["lost"]

    def unknown_key(ps):
        ps["unity-hdrp"]["presets"][0]["colour"] = 1

    def matrix_of_text(ps):
        ps["unreal"]["presets"][0]["values"][0]["value"] = [[1.0, "x"]]

    refused(value, r"engine_presets.unreal.presets\[0\].values\[0\].value: expected a number or a list")
    refused(no_lost, r"engine_presets.godot.presets\[1\].lost: missing required key")
    refused(unknown_key, r"presets\[0\].colour: unknown key")
    refused(matrix_of_text, r"values\[0\].value\[0\]\[1\]: expected a number")
    # what the schema cannot say, the loader does
    refused(lambda ps: ps.update(cryengine=ps["godot"]), "engine_presets.cryengine: unknown engine", False)
    refused(lambda ps: ps["godot"].update(sources=[]), "godot.sources: no documentation cited", False)
    refused(
        lambda ps: ps["godot"]["presets"][0].update(case="fog9"), r"presets\[0\].method: no method", False
    )
    refused(
        lambda ps: ps["godot"]["presets"][0].update(engine="unreal"), r"presets\[0\].engine: 'unreal'", False
    )


def test_an_audit_file_of_several_families_carries_every_feature(tmp_path):
    """An audit's fitted file holds fog, sky and SH fits together: each engine's section has the presets of
    every feature it has (each naming its ``feature``), Godot names the sky it cannot hold in ``skipped``,
    and ``rtfit fitted convert`` prints the same section."""
    sky = next(m for m in SKY.values() if {"rayleigh_scale", "mie_scale", "mie_g"} <= set(m.params))
    entries = [
        method_entry(FOG["const"], params=CONST, case="fog0", domain=DOMAIN),
        method_entry(sky, case="sky0"),
        method_entry(IB["sh-l2-lambda"], params={"lam": 0.02}, case="env0"),
    ]
    path = tmp_path / "audit.json"
    doc = _write(path, entries, "audit")
    features = {e: [p["feature"] for p in s["presets"]] for e, s in doc["engine_presets"].items()}
    assert features == {
        "unreal": [
            "Unreal Engine 4/5 Exponential Height Fog",
            "Unreal Engine 4.26+/5 SkyAtmosphere",
            "Unreal Engine 4/5 FSHVectorRGB3 / FThreeBandSHVectorRGB (volumetric lightmap, indirect lighting "
            "cache)",
        ],
        "unity-hdrp": [
            "Unity HDRP Fog volume override",
            "Unity HDRP Physically Based Sky (Type: Custom)",
            "Unity SphericalHarmonicsL2 (light probes, ambient probe; built-in, URP, HDRP)",
        ],
        "godot": [
            "Godot 4 volumetric fog: FogVolume + FogMaterial",
            "Godot 4 LightmapGI probes (LightmapGIData capture data: 9 Colors per probe)",
        ],
    }
    (why,) = doc["engine_presets"]["godot"]["skipped"]
    assert "Godot's sky is not converted yet" in why
    assert doc["engine_presets"]["unreal"]["engine_title"].count(" + ") == 2
    for engine in ENGINE_NAMES:
        out = _convert(path, engine)
        assert out.exit_code == 0 and out.stderr == "", out.output
        printed = json.loads(out.stdout)
        assert {k: v for k, v in printed.items() if k not in HEADER} == doc["engine_presets"][engine]
