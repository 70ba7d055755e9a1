"""Fitted-parameter files (rtfit.fitted/1): every family's writer, the JSON Schema, the strict loader, and
the shader text inside the files against the kernels.

Each family's ``write_fitted`` runs on small synthetic fits (the shape `FitResult.to_dict()` returns);
its files must validate against the shipped schema (jsonschema) and load with `load_fitted`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments import ambient_aperture_study as aa
from rtfit.experiments import diffuse_study as df
from rtfit.experiments import sdf_occlusion_fit as so
from rtfit.experiments.fitted import (
    FORMAT,
    FittedError,
    FittedFile,
    FittedMethod,
    Parameter,
    fitted_json_schema,
    load_fitted,
    method_entry,
    provenance,
    write_fit,
    write_fitted,
)
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.realtime.height_fog import METHODS as FOG
from rtfit.realtime.nishita_sky import METHODS as SKY_METHODS
from rtfit.realtime.volumetric_lightning import METHODS as LIGHTNING

from .test_shader import compile_function

SHIPPED = Path(__file__).resolve().parent.parent / "docs" / "fitted.schema.json"


def _fit(values: dict, n: int = 200, method=None) -> dict:
    """A fit in the shape of `FitResult.to_dict()` (bounds from ``method`` where it declares the name)."""
    params = {}
    for k, v in values.items():
        spec = method.params.get(k) if method is not None else None
        lo = spec.lower if spec is not None and math.isfinite(spec.lower) else None
        hi = spec.upper if spec is not None and math.isfinite(spec.upper) else None
        params[k] = {"value": v, "stderr": 1e-3 * (1 + abs(v)), "lower": lo, "upper": hi, "at_bound": False}
    names = list(values)
    return {
        "parameters": params,
        "param_names": names,
        "correlation": np.eye(len(names)).tolist(),
        "rms_residual": 0.0123,
        "ssr": 0.5,
        "n_residuals": n,
        "dof": n - len(names),
        "steps": 7,
        "converged": True,
        "message": "converged",
        "jacobian_rank": len(names),
        "at_bound": [],
    }


def _diffuse(out: Path):
    """The diffuse run's fitted files: the engine's per-α wrap fits (`method_entry` of each fitted row, as
    `audit_output.fitted_entries` writes them into ``fitted/diffuse.json``) and the study's smooth law."""
    alphas = (5.0, 30.0)
    per_case = {f"a{a:g}": _fit({"w": 0.1 + a / 100, "p": 1.0 + a / 50}, method=df.WRAP) for a in alphas}
    entries = [
        method_entry(
            df.WRAP,
            per_case[f"a{a:g}"],
            case=f"a{a:g}",
            residual_units="W/m²",
            domain={"alpha": (math.radians(a), math.radians(a), "rad"), "cos_theta": (-0.9, 0.95)},
            data={"alpha_deg": a},
        )
        for a in alphas
    ]
    prov = provenance(None, "diffuse")
    write_fitted(out / "fitted" / "diffuse.json", FittedFile(FORMAT, "per-α wrap fits", prov, entries))
    smooth = _fit({"w1": -0.07, "w2": 1.37, "p1": -0.05, "p2": 2.0}, n=8, method=df.SMOOTH_LAW)
    df.write_smooth_fitted(out, smooth, alphas, (-0.9, 0.95), prov)
    return per_case


def _height_fog(out: Path):
    fits = {
        ("e5-single", "const"): _fit(
            {"b": 1.1e-3, "c": 6.1e-3, "r0": 0.3, "g0": 0.4, "b0": 0.55}, method=FOG["const"]
        ),
        ("e5-single", "phase"): _fit(
            {
                "b": 1.1e-3,
                "c": 6.1e-3,
                **{"r0": 0.3, "g0": 0.4, "b0": 0.55, "r1": 0.05, "g1": 0.04, "b1": 0.02, "g": 0.7},
            },
            method=FOG["phase"],
        ),
    }
    domain = {"z0": (0.0, 10.0), "z1": (0.0, 300.0), "distance": (10.0, 900.0), "cos_sun": (-1.0, 1.0)}
    for (cid, method), fit in fits.items():
        m = FOG[method]
        entry = method_entry(m, fit, label=f"{m.label}, {cid}", case=cid, domain=domain,
                             residual_units="relative", outputs=("out_r", "out_g", "out_b"))  # fmt: skip
        write_fit(out, f"fitted/fog-{cid}-{method}.json", title=f"height fog, {m.label} ({cid})",
                  provenance=provenance(None, "height-fog", ["ab12"], 8), entry=entry,
                  doc_id=f"fog-{cid}-{method}", label=f"artist parameters, {cid}-{method}", model=m.formula,
                  fit=fit)  # fmt: skip
    return fits


def _ambient_aperture(out: Path):
    prov = provenance(None, "ambient-aperture")
    fit_i = {**_fit({f"c{i}": 0.01 * i for i in range(6)}, method=aa.FITTED_OMEGA), "errors": {"max": 0.01}}
    aa.write_fit_file("intersection", "intersection form", "Ω ≈ …", fit_i, aa.FITTED_OMEGA, out, prov)
    fit_l = {**_fit({"k": 1.3}, method=aa.FITTED_LAMBERT), "k": 1.3, "errors": {"max": 0.02}}
    aa.write_fit_file("lambert", "Lambert weight", "w = …", fit_l, aa.FITTED_LAMBERT, out, prov)


def _sdf_occlusion(out: Path):
    """The study's fitted files of ``rtfit run sdf-occlusion`` (`sdf_occlusion_fit.write_fitted`)."""
    names = ["logB", "c1", "c2", "alpha", "base_voxels"]
    fit = _fit(dict(zip(names, [0.0, 0.5, 0.3, 0.2, 1.5], strict=True)))
    b = {
        "fit": fit,
        "cov": np.eye(5) * 1e-4,
        "grid": {"alpha": 0.2, "base_vox": 1.5, "rms_residual": 0.05},
        "lm": {"iterations": 5, "evaluations": 9, "message": "ok"},
        "alpha": 0.2,
        "base_vox": 1.5,
    }
    joint = {t: b for t in list(so.TARGET_LABEL)[:2]}
    so.write_fitted(
        out, joint, {"bunny-ao": {"evans-fit": {"k": 0.5}}}, {"bunny": 0.01, "room": 0.01}, None, ["h1"]
    )


def _nishita_sky(out: Path):
    """The engine's fitted file of ``rtfit run nishita-sky``: the artist parameters fitted on one shipped sky
    file (`method_entry` of the fitted row, as `audit_output.fitted_entries` writes it)."""
    m = SKY_METHODS["nishita-fitted"]
    entry = method_entry(
        m,
        _fit({"rayleigh_scale": 1.1, "mie_scale": 0.9, "mie_g": 0.76, "ambient": 0.01}, method=m),
        case="sky_sun_10-sky",
        residual_units="W/m²/sr",
        domain={"sun_elevation": (10.0, 10.0, "deg")},
    )
    prov = provenance(None, "nishita-sky")
    doc = FittedFile(FORMAT, "artist parameters fitted per sky file", prov, [entry])
    write_fitted(out / "fitted" / "nishita-sky.json", doc)


def _volumetric_lightning(out: Path):
    """The engine's fitted file of ``rtfit run volumetric-lightning``: the stable form's (i, a) fitted on one
    shipped scene (`method_entry` of the fitted row, as `audit_output.fitted_entries` writes it)."""
    m = LIGHTNING["stable"]
    entry = method_entry(
        m,
        _fit({"i": 3.0, "a": 600.0}, method=m),
        case="D4-s0p05-light0-inscatter",
        residual_units="W/m²/sr",
        domain={"camera_to_light_m": (4.02, 4.02, "m")},
    )
    prov = provenance(None, "volumetric-lightning")
    doc = FittedFile(FORMAT, "stable form fitted per scene", prov, [entry])
    write_fitted(out / "fitted" / "volumetric-lightning.json", doc)


WRITERS = {
    "diffuse": (_diffuse, ["diffuse.json", "wrap_smooth.json"]),
    "height-fog": (
        _height_fog,
        ["fog-e5-single-const.json", "fog-e5-single-phase.json"],
    ),
    "ambient-aperture": (_ambient_aperture, ["intersection.json", "lambert.json"]),
    "sdf-occlusion": (_sdf_occlusion, ["evans_joint_ao.json", "evans_joint_sky.json", "per_case.json"]),
    "nishita-sky": (_nishita_sky, ["nishita-sky.json"]),
    "volumetric-lightning": (_volumetric_lightning, ["volumetric-lightning.json"]),
}


def _validate(doc):
    jsonschema = pytest.importorskip("jsonschema")
    schema = fitted_json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(doc, schema, cls=jsonschema.Draft202012Validator)


def test_shipped_schema_is_current():
    shipped = json.loads(SHIPPED.read_text(encoding="utf-8"))
    assert shipped == fitted_json_schema(), (
        "docs/fitted.schema.json is stale: regenerate it with "
        "python -c 'import json; from rtfit.experiments.fitted import fitted_json_schema as s; "
        "print(json.dumps(s(), indent=2, ensure_ascii=False))' > docs/fitted.schema.json"
    )


@pytest.mark.parametrize("family", list(WRITERS))
def test_every_family_writes_files_that_validate(family, tmp_path):
    write, files = WRITERS[family]
    write(tmp_path)
    written = sorted(p.name for p in (tmp_path / "fitted").glob("*.json"))
    for f in files:
        assert f in written, (f, written)
    for name in written:
        doc = json.loads((tmp_path / "fitted" / name).read_text(encoding="utf-8"))
        assert doc["format"] == FORMAT
        _validate(doc)
        loaded = load_fitted(tmp_path / "fitted" / name)
        for m in loaded.methods:
            assert (m.shader is None) == bool(m.shader_note), (name, m.id)
            for p in m.parameters.values():
                assert math.isfinite(p.value)


def test_diffuse_files_carry_the_fits_and_shaders_that_reproduce_the_kernel(tmp_path):
    per_case = _diffuse(tmp_path)
    doc = load_fitted(tmp_path / "fitted" / "diffuse.json")
    assert {m.case for m in doc.methods} == set(per_case)
    rng = np.random.default_rng(5)
    c = rng.uniform(-1, 1, 1000).astype(np.float32)
    e = rng.uniform(0, 4, 1000).astype(np.float32)
    for m in doc.methods:
        want = per_case[m.case]["parameters"]
        assert m.parameters["w"].value == want["w"]["value"]
        assert m.parameters["p"].stderr == want["p"]["stderr"]
        assert m.parameters["w"].lower == 0.0 and m.parameters["w"].upper == 1.0
        assert m.residual.rms == 0.0123 and m.residual.n == 200 and m.residual.dof == 198
        assert m.domain["alpha"].lower == m.domain["alpha"].upper == math.radians(m.data["alpha_deg"])
        assert m.domain["cos_theta"].lower == pytest.approx(-0.9)
        params = {k: p.value for k, p in m.parameters.items()}
        ref = DIFFUSE["wrap"](
            NUMPY_OPS, {"cos_theta": c.astype(np.float64), "irradiance": e.astype(np.float64)}, params
        )
        for lang in ("glsl", "hlsl"):
            got = compile_function(getattr(m.shader, lang))(c, e)
            np.testing.assert_allclose(got, ref, rtol=2e-6, atol=1e-6)
    smooth = load_fitted(tmp_path / "fitted" / "wrap_smooth.json").methods[0]
    assert smooth.shader.arguments == ["cos_theta", "irradiance", "alpha"]
    a = rng.uniform(0.005, 0.5, 1000).astype(np.float32)
    coeffs = {k: p.value for k, p in smooth.parameters.items()}
    w, p = df.SMOOTH_LAW(NUMPY_OPS, {"alpha": a.astype(np.float64)}, coeffs)
    ref = DIFFUSE["wrap"].kernel(
        NUMPY_OPS, cos_theta=c.astype(np.float64), w=w, p=p, irradiance=e.astype(np.float64)
    )
    got = compile_function(smooth.shader.glsl)(c, e, a)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)


def test_fog_file_shader_reproduces_the_fitted_shading(tmp_path):
    fits = _height_fog(tmp_path)
    m = load_fitted(tmp_path / "fitted" / "fog-e5-single-phase.json").methods[0]
    assert m.shader.outputs == ["out_r", "out_g", "out_b"]
    assert set(m.domain) == {"z0", "z1", "distance", "cos_sun"}
    params = {k: v["value"] for k, v in fits[("e5-single", "phase")]["parameters"].items()}
    rng = np.random.default_rng(6)
    n = 500
    z0, z1 = (rng.uniform(0, 300, n).astype(np.float32) for _ in range(2))
    inputs = {
        "z0": z0,
        "z1": z1,
        "distance": (np.abs(z1 - z0) * rng.uniform(1, 10, n)).astype(np.float32),
        "cos_sun": rng.uniform(-1, 1, n).astype(np.float32),
        **{f"l0_{ch}": rng.uniform(0, 2, n).astype(np.float32) for ch in "rgb"},
    }
    ref = FOG["phase"](NUMPY_OPS, {k: v.astype(np.float64) for k, v in inputs.items()}, params)
    got = compile_function(m.shader.glsl)(*(inputs[a] for a in m.shader.arguments))
    for g, r in zip(got, ref, strict=True):
        np.testing.assert_allclose(g, r, rtol=1e-5, atol=1e-6)


def test_loader_refuses_bad_files_with_one_line(tmp_path):
    _diffuse(tmp_path)
    path = tmp_path / "fitted" / "wrap_smooth.json"
    good = json.loads(path.read_text(encoding="utf-8"))

    def refused(doc, match):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(doc), encoding="utf-8")
        with pytest.raises(FittedError, match=match) as e:
            load_fitted(bad)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)

    refused({**good, "format": "rtfit.fitted/0"}, "format: expected 'rtfit.fitted/1'")
    m = {**good["methods"][0], "shader": None, "shader_note": None}
    refused({**good, "methods": [m]}, r"methods\[0\].shader_note: a method without shader text")
    m = json.loads(json.dumps(good["methods"][0]))
    m["parameters"]["w1"]["value"] = "big"
    refused({**good, "methods": [m]}, r"methods\[0\].parameters.w1.value: expected a number")
    refused({**good, "extra_key": 1}, "extra_key: unknown key")
    m = dict(good["methods"][0])
    m.pop("shader")
    refused({**good, "methods": [m]}, r"methods\[0\].shader: missing required key")


def test_write_fit_writes_one_method_and_returns_its_record(tmp_path):
    """`write_fit`: the file holds the one method under the title; the record carries the fit's numbers,
    the family's extra keys before ``file``, and the same relative path the file was written at."""
    fit = _fit({"w": 0.2, "p": 1.5}, method=df.WRAP)
    entry = method_entry(df.WRAP, fit, case="c1", residual_units="1")
    rec = write_fit(
        tmp_path,
        "fitted/one.json",
        title="one fit",
        provenance=provenance(None, "test"),
        entry=entry,
        doc_id="wrap-c1",
        label="wrap, c1",
        model="the model as the report names it",
        fit=fit,
        at_bound=["w"],
    )
    assert list(rec) == [
        "id", "label", "model", "parameters", "rms_residual", "n_residuals", "converged", "at_bound", "file",
    ]  # fmt: skip
    assert rec["file"] == "fitted/one.json" and rec["parameters"] is fit["parameters"]
    assert (rec["rms_residual"], rec["n_residuals"], rec["converged"]) == (0.0123, 200, True)
    loaded = load_fitted(tmp_path / rec["file"])
    assert loaded.title == "one fit" and [m.id for m in loaded.methods] == [entry.id]


@pytest.mark.parametrize("name", ["intersection", "lambert"])
def test_ambient_aperture_shaders_are_the_kernels_in_float32(name, tmp_path):
    _ambient_aperture(tmp_path)
    entry = load_fitted(tmp_path / "fitted" / f"{name}.json").methods[0]
    method = {"intersection": aa.FITTED_OMEGA, "lambert": aa.FITTED_LAMBERT}[name]
    rng = np.random.default_rng(8)
    inputs = {i.name: rng.uniform(*i.domain, 2000).astype(np.float32) for i in method.inputs}
    params = {k: p.value for k, p in entry.parameters.items()}
    own = method(NUMPY_OPS, inputs, {k: np.float32(v) for k, v in params.items()})  # float32 NumPy run
    got = compile_function(entry.shader.glsl)(*(inputs[a] for a in entry.shader.arguments))
    np.testing.assert_array_equal(got, np.asarray(own, np.float32))
    ref = method(NUMPY_OPS, {k: v.astype(np.float64) for k, v in inputs.items()}, params)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6 * float(np.max(np.abs(ref))))


def test_audit_fitted_file_names_its_variant_and_that_it_is_not_quick(tmp_path):
    """The audit's ``fitted/audit.json`` (issue 32): its provenance carries the Mitsuba variant it rendered
    with and ``quick: false`` (an audit has no quick mode), like every experiment's fitted file, and the file
    validates against the shipped schema. A 32² lit sphere, 4 spp, lambert/half-lambert/wrap rows fitted."""
    from rtfit.experiments.audit_run import audit

    from .test_audit_run import FAST, SPHERE_XML

    (tmp_path / "sphere.xml").write_text(SPHERE_XML)
    r = audit(
        tmp_path / "sphere.xml", "diffuse", spp=4, pass_spp=2, variant="llvm_ad_rgb",
        cache=tmp_path / "cache", out=tmp_path / "out", **FAST,
    )  # fmt: skip
    path = r.out / "fitted" / "audit.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    _validate(doc)
    prov = doc["provenance"]
    assert prov["experiment"] == "audit" and prov["variant"] == "llvm_ad_rgb" and prov["quick"] is False, prov
    assert load_fitted(path).provenance.variant == "llvm_ad_rgb"


def test_a_parameter_without_a_unit_is_refused_at_write_time(tmp_path):
    """A fitted file whose parameter has ``unit: ""`` (issue 32: fog-volume-colours.json's 6 colours) is not
    written: one line naming the method and parameter; with its unit it is."""
    entry = FittedMethod(
        id="vol",
        label="volume colours",
        formula="c",
        parameters={"vol0_r": Parameter(value=0.5, unit="")},
        shader_note="data only",
    )
    doc = FittedFile(
        format=FORMAT, title="t", provenance=provenance(None, "test", variant="llvm_ad_rgb"), methods=[entry]
    )
    path = tmp_path / "fitted" / "x.json"
    with pytest.raises(FittedError) as e:
        write_fitted(path, doc)
    assert "\n" not in str(e.value) and "methods[0].parameters.vol0_r.unit: no unit" in str(e.value)
    assert not path.exists()
    good = dataclasses.replace(entry, parameters={"vol0_r": Parameter(value=0.5, unit="W/m²/sr")})
    write_fitted(path, dataclasses.replace(doc, methods=[good]))
    assert load_fitted(path).methods[0].parameters["vol0_r"].unit == "W/m²/sr"


def test_a_user_parameter_declared_without_a_unit_is_written_as_undeclared(tmp_path):
    """A user's ``Param`` without ``unit=`` (the audit's ``--approx`` files) is not refused: its fitted file
    says the unit is ``undeclared``; one with a unit keeps it."""
    from rtfit import Param, approximation
    from rtfit.realtime.quantities import UNDECLARED_UNIT

    @approximation(
        quantity="light_irradiance",
        params={"w": Param(0.2, lower=0.0, upper=1.0), "k": Param(1.0, lower=0.0, upper=2.0, unit="1")},
    )
    def my_wrap(ops, g, *, w, k):
        """Wrap lighting, scaled."""
        return k * g.irradiance * ops.maximum((g.cos_theta + w) / (1.0 + w), 0.0)

    assert UNDECLARED_UNIT == "undeclared"
    entry = method_entry(my_wrap, params={"w": 0.5, "k": 1.0})
    path = tmp_path / "user.json"
    prov = provenance(None, "t")
    write_fitted(path, FittedFile(format=FORMAT, title="t", provenance=prov, methods=[entry]))
    units = {k: p.unit for k, p in load_fitted(path).methods[0].parameters.items()}
    assert units == {"w": "undeclared", "k": "1"}
