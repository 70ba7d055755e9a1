"""Typed results records: the six families' real documents load, round-trip exactly and validate against
the shipped JSON Schema; wrong types, unknown keys, duplicated ids and NaN are one-line errors naming the
key path. No Mitsuba; fast.

``tests/data/results/EXPERIMENT.json`` are the quick-suite results from before the refactor, trimmed to
their first three cases by ``tests/data/results/trim.py``.
"""

from __future__ import annotations

import copy
import json
import re
import sys
import types
from pathlib import Path

import pytest

from rtfit.experiments.records import (
    SCHEMA,
    Case,
    Check,
    Fit,
    Metric,
    Results,
    ResultsError,
    from_json,
    results_json_schema,
    to_json,
)
from rtfit.experiments.registry import ExperimentSpec, RunContext
from rtfit.experiments.report import render_report
from rtfit.experiments.results import load_results, write_results
from rtfit.experiments.runner import run_experiment_into

DATA = Path(__file__).parent / "data" / "results"
SHIPPED_SCHEMA = Path(__file__).resolve().parent.parent / "docs" / "results.schema.json"
FAMILIES = sorted(p.stem for p in DATA.glob("*.json"))


def _doc(family: str) -> dict:
    return json.loads((DATA / f"{family}.json").read_text(encoding="utf-8"))


def _write(directory: Path, doc) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    # json.dumps writes NaN as the bare token NaN (not JSON), as a careless producer would.
    (directory / "results.json").write_text(json.dumps(doc, ensure_ascii=False), encoding="utf-8")
    return directory


def test_all_six_families_are_here():
    assert FAMILIES == [
        "ambient-aperture",
        "half-lambert",
        "height-fog",
        "irradiance-bases",
        "nishita-sky",
        "sdf-occlusion",
    ]


# -------------------------------------------------------------------------------------- loading
@pytest.mark.parametrize("family", FAMILIES)
def test_family_results_load_as_records(family, tmp_path):
    r = load_results(_write(tmp_path / family, _doc(family)))
    assert isinstance(r, Results) and r.schema == SCHEMA and r.experiment == family
    assert r.cases and all(isinstance(c, Case) for c in r.cases)
    for c in r.cases:
        for ap in c.approximations:
            assert ap.metrics and all(isinstance(m, Metric) for m in ap.metrics.values())
            assert all(isinstance(m.resolved, bool) for m in ap.metrics.values())
    assert all(isinstance(f, Fit) and isinstance(f.converged, bool) for f in r.fits)
    assert all(isinstance(c, Check) and isinstance(c.passed, bool) for c in r.checks)
    # The record is read by attribute; the JSON-key reading of the document still works.
    assert r["cases"][0]["id"] == r.cases[0].id and r.get("no such key", 7) == 7


@pytest.mark.parametrize("family", FAMILIES)
def test_round_trip_is_exact(family, tmp_path):
    doc = _doc(family)
    r = load_results(_write(tmp_path / "a", doc))
    write_results(tmp_path / "b", r)
    again = load_results(tmp_path / "b")
    assert again == r
    written = json.loads((tmp_path / "b" / "results.json").read_text(encoding="utf-8"))
    # Same document, same key order everywhere (a null stays null, an absent key stays absent).
    assert json.dumps(written) == json.dumps(doc)


@pytest.mark.parametrize("family", FAMILIES)
def test_report_from_record_equals_report_from_document(family):
    doc = _doc(family)
    assert render_report(doc) == render_report(from_json(Results, doc, "x"))


def test_record_built_in_code_writes_declared_fields_only():
    m = Metric(value=0.5, noise_floor=0.1)
    assert to_json(m) == {"value": 0.5, "noise_floor": 0.1}
    assert to_json(Metric(value=None)) == {"value": None}  # a required key is written even when null


# --------------------------------------------------------------------------------------- errors
def _ap(r, i=0, j=0):
    return r["cases"][i]["approximations"][j]


BAD = [
    (
        lambda r: r["fits"][0].update(converged="no"),
        "fits[0].converged: expected true, false or null, got str 'no'",
    ),
    (
        lambda r: _ap(r, 1)["metrics"]["rmse"].update(value="big"),
        "cases[1].approximations[0].metrics.rmse.value: expected a number or null, got str 'big'",
    ),
    (
        lambda r: r["cases"][0]["reference"].update(spp="many"),
        "cases[0].reference.spp: expected an integer or null, got str 'many'",
    ),
    (
        lambda r: r["cases"][0]["reference"].update(spp=True),  # a bool is not a number
        "cases[0].reference.spp: expected an integer or null, got bool True",
    ),
    (
        lambda r: r["cases"][2].update(id=r["cases"][0]["id"]),
        "cases[2].id: duplicate case id 'a0p27-sky0' (also cases[0])",
    ),
    (
        lambda r: _ap(r)["metrics"]["rmse"].update(valeu=1.0),
        "cases[0].approximations[0].metrics.rmse.valeu: unknown key (a Metric has: ",
    ),
    (
        lambda r: _ap(r).update(cots=None),
        "cases[0].approximations[0].cots: unknown key (an Approximation has: ",
    ),
    (
        lambda r: _ap(r)["metrics"]["rmse"].update(value=float("nan")),
        "cases[0].approximations[0].metrics.rmse.value: NaN is not a valid result",
    ),
    (
        lambda r: r["checks"][0].update(value=float("inf")),
        "checks[0].value: Infinity is not a valid result",
    ),
    (lambda r: r.update(schema="rtfit.results/2"), "schema: expected 'rtfit.results/1', got str"),
    (lambda r: r["cases"][0].pop("label"), "cases[0].label: missing required key"),
    (lambda r: r["checks"][0].pop("passed"), "checks[0].passed: missing required key"),
    (
        lambda r: r["fits"][0]["parameters"]["p"].update(at_bound=0),
        "fits[0].parameters.p.at_bound: expected true or false, got int 0",
    ),
    (
        lambda r: r["sections"][0].update(placement="sideways"),
        "sections[0].placement: expected 'before_results', 'after_results' or null, got str 'sideways'",
    ),
    (
        lambda r: r["figures"][0].update(file="/etc/passwd"),
        "figures[0].file: expected a relative path inside the experiment directory",
    ),
    (
        lambda r: r["cases"][0]["approximations"].append(copy.deepcopy(_ap(r))),
        "cases[0].approximations[5].method: duplicate method 'lambert' in this case (also approximations[0])",
    ),
    (lambda r: r.update(notes=["ok", 3]), "notes[1]: expected a string, got int 3"),
    (
        lambda r: r.update(created="yesterday"),  # issue 32: the doc says ISO 8601 UTC
        "created: expected an ISO 8601 date and time with its time zone, got str 'yesterday'",
    ),
    (
        lambda r: r.update(created="2026-11-23T10:00:00"),  # no time zone: which moment is it?
        "created: expected an ISO 8601 date and time with its time zone, got str",
    ),
    (lambda r: r["config"].update(seed=1.5), "config.seed: expected an integer or null, got float 1.5"),
]


@pytest.mark.parametrize("mutate, message", BAD, ids=[m.split(":")[0] for _, m in BAD])
def test_wrong_document_is_one_line_naming_the_key(mutate, message, tmp_path):
    doc = _doc("half-lambert")
    mutate(doc)
    d = _write(tmp_path / "x", doc)
    with pytest.raises(ResultsError) as e:
        load_results(d)
    text = str(e.value)
    assert "\n" not in text
    assert text.startswith(f"{d / 'results.json'}: "), text
    assert message in text, text


def test_fit_parameter_accepts_a_bare_number():
    doc = _doc("half-lambert")
    doc["fits"][0]["parameters"]["p"] = 2.0
    r = from_json(Results, doc, "x")
    assert r.fits[0].parameters["p"] == 2.0
    assert "2.000" in render_report(r)["report.md"]


# ------------------------------------------------------------------------------------- the runner
def _fake_spec(monkeypatch, body: dict) -> ExperimentSpec:
    module = types.ModuleType("rtfit_test_fake_experiment")
    module.run = lambda ctx: copy.deepcopy(body)  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, module.__name__, module)
    return ExperimentSpec("half-lambert", module.__name__, "Fake", "A fake experiment.")


def _ctx(tmp_path) -> RunContext:
    return RunContext(
        out_dir=tmp_path,
        cache_dir=tmp_path / "cache",
        executor=None,
        quick=True,
        variant="scalar_rgb",
        spp=None,
        seed=0,
        progress=False,
    )


def _body() -> dict:
    doc = _doc("half-lambert")
    for key in ("schema", "experiment", "title", "created", "versions", "device"):
        del doc[key]  # the runner writes the header
    return doc


def test_runner_refuses_a_wrong_body_before_writing(monkeypatch, tmp_path):
    body = _body()
    body["fits"][0]["converged"] = "no"
    spec = _fake_spec(monkeypatch, body)
    with pytest.raises(ResultsError, match=re.escape("results of half-lambert: fits[0].converged: expected")):
        run_experiment_into(spec, tmp_path, _ctx(tmp_path), "inline")
    assert not list(tmp_path.iterdir())  # nothing written


def test_runner_writes_the_record(monkeypatch, tmp_path):
    spec = _fake_spec(monkeypatch, _body())
    r = run_experiment_into(spec, tmp_path, _ctx(tmp_path), "inline", extra_config={"sweep_point": "k"})
    assert isinstance(r, Results) and load_results(tmp_path) == r
    assert r.config.executor == "inline" and r.config.sweep_point == "k" and r.config.variant == "scalar_rgb"
    assert (tmp_path / "report.html").is_file()


# ----------------------------------------------------------------------------------- JSON Schema
def _validate(schema: dict, value, root: dict, where: str = "$") -> list[str]:
    """A small JSON Schema validator for the keywords results_json_schema() uses."""
    if "$ref" in schema:
        return _validate(root["$defs"][schema["$ref"].rsplit("/", 1)[1]], value, root, where)
    if "anyOf" in schema:
        if any(not _validate(s, value, root, where) for s in schema["anyOf"]):
            return []
        return [f"{where}: matches none of anyOf"]
    if "const" in schema and value != schema["const"]:
        return [f"{where}: not {schema['const']!r}"]
    if "enum" in schema and value not in schema["enum"]:
        return [f"{where}: not one of {schema['enum']}"]
    kind = schema.get("type")
    checks = {
        "null": value is None,
        "boolean": isinstance(value, bool),
        "integer": isinstance(value, int) and not isinstance(value, bool),
        "number": isinstance(value, (int, float)) and not isinstance(value, bool),
        "string": isinstance(value, str),
        "array": isinstance(value, list),
        "object": isinstance(value, dict),
    }
    if kind is not None and not checks[kind]:
        return [f"{where}: not {kind}"]
    out = []
    if kind == "string":
        if len(value) < schema.get("minLength", 0):
            out.append(f"{where}: too short")
        if "pattern" in schema and not re.search(schema["pattern"], value):
            out.append(f"{where}: does not match {schema['pattern']}")
    if kind == "array":
        for i, v in enumerate(value):
            out += _validate(schema.get("items", {}), v, root, f"{where}[{i}]")
    if kind == "object":
        props = schema.get("properties", {})
        out += [f"{where}.{k}: required" for k in schema.get("required", []) if k not in value]
        for k, v in value.items():
            if k in props:
                out += _validate(props[k], v, root, f"{where}.{k}")
            elif schema.get("additionalProperties", True) is False:
                out.append(f"{where}.{k}: not allowed")
            elif isinstance(schema.get("additionalProperties"), dict):
                out += _validate(schema["additionalProperties"], v, root, f"{where}.{k}")
    return out


def test_shipped_schema_is_the_generated_one():
    shipped = json.loads(SHIPPED_SCHEMA.read_text(encoding="utf-8"))
    assert shipped == results_json_schema(), (
        "docs/results.schema.json is stale: regenerate it with "
        "python -c 'import json; from rtfit.experiments.records import results_json_schema as s; "
        "print(json.dumps(s(), indent=2, ensure_ascii=False))' > docs/results.schema.json"
    )


@pytest.mark.parametrize("family", FAMILIES)
def test_family_results_validate_against_the_schema(family):
    schema = results_json_schema()
    assert _validate(schema, _doc(family), schema) == []
    try:
        import jsonschema
    except ImportError:  # the hand validator above has already checked it
        return
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(_doc(family), schema, cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize(
    "mutate",
    [mut for mut, msg in BAD if "duplicate" not in msg and "valid result" not in msg],
    ids=[m.split(":")[0] for _, m in BAD if "duplicate" not in m and "valid result" not in m],
)
def test_schema_refuses_what_the_loader_refuses(mutate):
    """Everything the loader refuses, except what JSON Schema cannot say (unique ids; NaN is not JSON)."""
    schema = results_json_schema()
    doc = _doc("half-lambert")
    mutate(doc)
    assert _validate(schema, doc, schema)


@pytest.mark.parametrize(
    "created", ["2026-11-23T10:00:00Z", "2026-11-23T10:00:00.25+01:30", "2026-12-01T22:31:40+00:00"]
)
def test_created_accepts_iso_8601_with_a_time_zone(created, tmp_path):
    """What `created_now` writes (``+00:00``), the doc's example (``Z``) and fractions of a second load,
    and the shipped schema accepts them."""
    doc = _doc("half-lambert")
    doc["created"] = created
    assert load_results(_write(tmp_path / "x", doc)).created == created
    schema = results_json_schema()
    assert _validate(schema, doc, schema) == []


def test_created_must_be_a_real_day(tmp_path):
    """30 February has the pattern's shape (so JSON Schema passes it); the loader refuses it."""
    doc = _doc("half-lambert")
    doc["created"] = "2026-02-30T10:00:00Z"
    with pytest.raises(ResultsError, match="created: expected an ISO 8601 date and time"):
        load_results(_write(tmp_path / "x", doc))


def test_report_of_a_results_file_created_yesterday(capsys, tmp_path):
    """`rtfit report` on ``created: "yesterday"``: one line, exit 2, nothing written (issue 32)."""
    from rtfit.experiments.cli import main

    doc = _doc("half-lambert")
    doc["created"] = "yesterday"
    d = _write(tmp_path / "exp", doc)
    rc = main(["report", str(d)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("rtfit: error: "), err
    assert "created: expected an ISO 8601 date and time" in err[0], err
    assert sorted(p.name for p in d.iterdir()) == ["results.json"]
