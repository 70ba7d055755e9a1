"""Fitted-parameter files an engine loads: ``fitted/*.json`` in format ``rtfit.fitted/1``.

One format for every experiment (and audit), described in ``docs/fitted-parameters.md`` and shipped as
the JSON Schema ``docs/fitted.schema.json`` (generated from the records below by `fitted_json_schema`,
with the machinery of `rtfit.experiments.records`)::

    FittedFile ─ format "rtfit.fitted/1", title, provenance: Provenance, data (family extras, JSON)
               └ methods: [FittedMethod] ─ id, label, formula, source, case, quantity, inputs {name: unit}
                                          ├ parameters: {name: Parameter} (value, stderr, unit, bounds)
                                          ├ residual: Residual (rms, n, dof, units), converged
                                          ├ domain: {input: Range} (the input ranges the fit saw)
                                          └ shader: Shader (GLSL and HLSL with the constants baked in)
                                            or null with shader_note (why no shader text)
               └ engine_presets: {engine: EnginePresets} (`rtfit.experiments.preset_records`: the
                                 methods an engine has the same effect for, in its own properties)

`method_entry` builds a `FittedMethod` from a `rtfit.realtime.Method` and its fit
(`rtfit.fitting.FitResult.to_dict()`), tracing the kernel with `rtfit.realtime.shader.SHADER_OPS`;
`write_fitted` validates a `FittedFile` (the loader's own checks) and writes it atomically;
`write_fit` writes the usual one-method file of one fit and returns its results' ``fits`` record
(`fit_record`, which files of several methods use alone);
`load_fitted` reads one back strictly (one ``FILE: KEY.PATH: problem`` line on a bad file).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from rtfit import __version__
from rtfit.realtime import Method, Untraceable, shader_function
from rtfit.reference.io import atomic_write_json

from .engine_presets import engine_presets_of
from .preset_records import ENGINE_NAMES, EnginePresets
from .records import JSON, Record, ResultsError, from_json, plain_json, record_json_schema, to_json

__all__ = [
    "FORMAT",
    "FittedError",
    "FittedFile",
    "FittedMethod",
    "Parameter",
    "Provenance",
    "Range",
    "Residual",
    "Shader",
    "fit_record",
    "fitted_json_schema",
    "load_fitted",
    "method_entry",
    "parameters_from_fit",
    "provenance",
    "shader_entry",
    "write_fit",
    "write_fitted",
]

FORMAT = "rtfit.fitted/1"


class FittedError(ValueError):
    """A fitted-parameter document that is not ``rtfit.fitted/1``: one line, ``FILE: KEY.PATH: problem``."""


# ------------------------------------------------------------------------------------------ records
@dataclass(frozen=True)
class Parameter(Record):
    """A parameter's value, its standard error (null: not estimated, e.g. a bound-limited or
    non-least-squares fit), its unit ("1": dimensionless), the bounds of its allowed range (null:
    unbounded) and whether the fit ended on a bound (then the stderr does not describe the uncertainty)."""

    value: float
    stderr: float | None = field(default=None, metadata={"required": True})
    unit: str = field(default="", metadata={"required": True})
    lower: float | None = field(default=None, metadata={"required": True})
    upper: float | None = field(default=None, metadata={"required": True})
    at_bound: bool = field(default=False, metadata={"required": True})
    description: str = ""


@dataclass(frozen=True)
class Residual(Record):
    """The fit's residual: root mean square ``rms`` over ``n`` residuals with ``dof`` degrees of freedom
    (n − number of parameters), in ``units`` (what each residual is divided by)."""

    rms: float | None
    n: int | None = field(default=None, metadata={"required": True})
    dof: int | None = field(default=None, metadata={"required": True})
    units: str = ""


@dataclass(frozen=True)
class Range(Record):
    """A closed interval [lower, upper] of one input that the fit saw (its domain of validity)."""

    lower: float
    upper: float
    unit: str = field(default="", metadata={"required": True})
    description: str = ""

    def problems(self) -> list[tuple[str, str]]:
        return [("upper", f"upper {self.upper} < lower {self.lower}")] if self.upper < self.lower else []


@dataclass(frozen=True)
class ShaderTable(Record):
    """A table the shader function reads, declared before it and filled by the engine with its own data
    (its sky's SH coefficients, its shadow map's depths): ``name``, size in ``floats``, ``kind`` "uniform"
    (a uniform array / constant buffer) or "buffer" (a storage / structured buffer), and ``description``
    (the input it stands for; its layout is the method's, `rtfit.realtime.shader`)."""

    name: str
    floats: int
    kind: str
    description: str = ""

    def problems(self) -> list[tuple[str, str]]:
        out = [] if self.floats > 0 else [("floats", f"a table of {self.floats} floats")]
        return out + ([] if self.kind in ("uniform", "buffer") else [("kind", f"unknown kind {self.kind!r}")])


@dataclass(frozen=True)
class Shader(Record):
    """A ready shader function with the fitted constants baked in: its name, ``float`` arguments (the
    method's inputs, in this order), outputs (one: the return value; several: ``out float`` arguments
    after the inputs), the GLSL (4.00+, for ``fma``; 4.30 where it reads a storage buffer) and HLSL (SM 5)
    text, and the ``tables`` it reads (declared at the head of both texts)."""

    function: str
    arguments: list[str]
    outputs: list[str]
    glsl: str
    hlsl: str
    tables: list[ShaderTable] = field(default_factory=list)


@dataclass(frozen=True)
class FittedMethod(Record):
    """One method with fitted (or declared) parameters.

    ``id``/``label``: the method as the experiment names it; ``case``: the case the fit belongs to (null:
    all cases); ``formula`` in one line and ``source`` (paper, seed lines); ``inputs``: the shader
    arguments' units; ``domain``: the input ranges the fit saw; ``shader`` null with ``shader_note``
    saying why where the kernel cannot be written as a straight-line shader; ``data``: method extras."""

    id: str
    label: str
    formula: str
    parameters: Mapping[str, Parameter] = field(default_factory=dict, metadata={"required": True})
    source: str = ""
    quantity: str = ""
    case: str | None = None
    inputs: Mapping[str, str] = field(default_factory=dict)
    residual: Residual | None = field(default=None, metadata={"required": True})
    converged: bool | None = None
    domain: Mapping[str, Range] = field(default_factory=dict, metadata={"required": True})
    shader: Shader | None = field(default=None, metadata={"required": True})
    shader_note: str | None = field(default=None, metadata={"required": True})
    data: JSON = None

    def problems(self) -> list[tuple[str, str]]:
        if self.shader is None and not self.shader_note:
            return [("shader_note", "a method without shader text must say why (shader_note)")]
        return []


@dataclass(frozen=True)
class Provenance(Record):
    """Where the numbers come from: rtfit version, experiment, UTC date (ISO 8601), the scenes' hashes
    (`rtfit.scenes.scene_hash`; empty where no scene is rendered), the reference's samples per pixel, the
    Mitsuba variant and whether the run was ``--quick``."""

    rtfit_version: str
    experiment: str
    date: str
    scene_hashes: list[str] = field(default_factory=list)
    reference_spp: int | None = None
    variant: str | None = None
    quick: bool | None = None


@dataclass(frozen=True)
class FittedFile(Record):
    """A ``fitted/*.json`` document (``rtfit.fitted/1``): one or more fitted methods and their provenance;
    ``data``: family-specific tables (e.g. per-case coefficient arrays) that are not one method's;
    ``engine_presets``: per engine (unreal, unity-hdrp, godot) that has the same effect as one of the
    methods, those methods' fitted values in the engine's own properties (``rtfit fitted convert``'s
    conversion; each preset names a method and case of this file)."""

    format: Literal["rtfit.fitted/1"]
    title: str
    provenance: Provenance
    methods: list[FittedMethod] = field(default_factory=list, metadata={"required": True})
    data: JSON = None
    engine_presets: Mapping[str, EnginePresets] = field(default_factory=dict)

    def problems(self) -> list[tuple[str, str]]:
        seen = set()
        for i, m in enumerate(self.methods):
            key = (m.id, m.case)
            if key in seen:
                return [(f"methods[{i}]", f"method {m.id!r} (case {m.case!r}) listed twice")]
            seen.add(key)
        for engine, section in self.engine_presets.items():
            if engine not in ENGINE_NAMES:
                return [(f"engine_presets.{engine}", f"unknown engine (known: {', '.join(ENGINE_NAMES)})")]
            for i, p in enumerate(section.presets):
                where = f"engine_presets.{engine}.presets[{i}]"
                if p.engine != engine:
                    return [(f"{where}.engine", f"{p.engine!r} under engine_presets.{engine}")]
                if (p.method, p.case) not in seen:
                    return [(f"{where}.method", f"no method {p.method!r} (case {p.case!r}) in this file")]
        return []


# ------------------------------------------------------------------------------------------ builders
def provenance(
    ctx,
    experiment: str,
    scene_hashes: Sequence[str] = (),
    reference_spp: int | None = None,
    *,
    variant: str | None = None,
    quick: bool | None = None,
) -> Provenance:
    """The provenance of this run: ``ctx`` the `RunContext` (its Mitsuba ``variant`` and ``quick``), or
    None outside an experiment's run (the audit), which then gives ``variant`` and ``quick`` itself;
    given values win over the context's."""
    return Provenance(
        rtfit_version=__version__,
        experiment=experiment,
        date=datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat(),
        scene_hashes=sorted(set(scene_hashes)),
        reference_spp=None if reference_spp is None else int(reference_spp),
        variant=variant if variant is not None else getattr(ctx, "variant", None),
        quick=quick if quick is not None else getattr(ctx, "quick", None),
    )


def _num(x) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def parameters_from_fit(
    method: Method | None, fit_params: Mapping[str, object], unit: str = ""
) -> dict[str, Parameter]:
    """`Parameter` records from a fit's ``parameters`` ({name: {value, stderr, lower, upper, at_bound}}
    or {name: value}), units and descriptions from ``method``'s declaration where it has the name, else
    the parameter's own ``unit``, else ``unit`` (the unit of every undeclared parameter)."""
    out = {}
    for name, p in fit_params.items():
        spec = method.params.get(name) if method is not None else None
        d = p if isinstance(p, Mapping) else {"value": p}
        lower = d.get("lower", spec.lower if spec else None)
        upper = d.get("upper", spec.upper if spec else None)
        out[name] = Parameter(
            value=float(d["value"]),
            stderr=_num(d.get("stderr")),
            unit=spec.unit if spec else str(d.get("unit", unit)),
            lower=_num(lower),
            upper=_num(upper),
            at_bound=bool(d.get("at_bound", False)),
            description=spec.description if spec else str(d.get("description", "")),
        )
    return out


def shader_entry(
    name: str,
    kernel: Callable,
    arguments: Sequence[str],
    constants: Mapping[str, object],
    outputs: Sequence[str] | None = None,
    comment: str = "",
    tables: Mapping[str, object] | None = None,
    descriptions: Mapping[str, str] | None = None,
) -> tuple[Shader | None, str | None]:
    """(`Shader`, None) for a kernel the tracer can write, else (None, why not). ``tables``: inputs that
    are tables or sampler objects (`rtfit.realtime.shader_function`), described by ``descriptions``."""
    try:
        fn = shader_function(
            name, kernel, arguments, constants, outputs=outputs, comment=comment, tables=tables
        )
    except Untraceable as e:
        return None, f"no shader text: {e}"
    except TypeError as e:  # an operation the tracer does not define (Untraceable covers the known ones)
        return None, f"no shader text: the kernel uses an operation the shader tracer lacks ({e})"
    except AttributeError as e:  # an input read through its own methods (a distance field's sample())
        return None, f"no shader text: an input is a sampler object, not a value ({e})"
    descriptions = descriptions or {}
    used = [
        ShaderTable(
            b.name, b.floats, b.kind, next((d for k, d in descriptions.items() if b.name.startswith(k)), "")
        )
        for b in fn.tables
    ]
    return Shader(fn.name, list(fn.arguments), list(fn.outputs), fn.glsl, fn.hlsl, used), None


def method_entry(
    method: Method,
    fit: Mapping | None = None,
    *,
    params: Mapping[str, float] | None = None,
    id: str | None = None,
    label: str | None = None,
    case: str | None = None,
    domain: Mapping[str, Range | tuple] | None = None,
    residual_units: str = "",
    outputs: Sequence[str] | None = None,
    baked: Mapping[str, object] | None = None,
    data=None,
    tables: Mapping[str, object] | None = None,
) -> FittedMethod:
    """The `FittedMethod` of ``method`` with the parameters of ``fit`` (a `FitResult.to_dict()`; None: the
    given ``params``, or the declared defaults), its residual, domain and traced shader text.

    ``baked``: inputs given as constants (e.g. a basis' stored coefficients): written into the shader as
    literals instead of arguments. ``tables``: inputs that are tables or sampler objects (a sky's SH
    coefficients, a shadow map): the shader reads them from bindings it declares (`ShaderTable`), which an
    engine fills with its own; their sizes and any constants the objects carry (a map's resolution) are
    this case's."""
    baked = dict(baked or {})
    tables = dict(tables or {})
    fit = fit or {}
    raw = fit.get("parameters") or {k: v for k, v in {**method.defaults(), **(params or {})}.items()}
    parameters = parameters_from_fit(method, raw)
    values = {k: p.value for k, p in parameters.items() if k in method.params}
    ranges = {}
    units = {i.name: i.unit for i in method.inputs if i.name not in baked and i.name not in tables}
    for k, r in (domain or {}).items():
        if not isinstance(r, Range):  # (lower, upper) or (lower, upper, unit)
            r = Range(float(r[0]), float(r[1]), unit=r[2] if len(r) > 2 else units.get(k, ""))
        ranges[k] = r
    fn = "rtfit_" + (id or method.id) + (f"_{case}" if case else "")
    shader, note = shader_entry(
        fn,
        method.kernel,
        [n for n in method.input_names if n not in baked and n not in tables],
        {**baked, **method.keywords(values)},
        outputs=outputs,
        comment=f"{label or method.label}: {method.formula}",
        tables=tables,
        descriptions={i.name: f"{i.name}: {i.description}" for i in method.inputs if i.name in tables},
    )
    residual = None
    if "rms_residual" in fit:
        residual = Residual(
            rms=_num(fit.get("rms_residual")),
            n=fit.get("n_residuals"),
            dof=fit.get("dof"),
            units=residual_units,
        )
    return FittedMethod(
        id=id or method.id,
        label=label or method.label,
        formula=method.formula,
        source=method.source,
        quantity=method.quantity,
        case=case,
        inputs=units,
        parameters=parameters,
        residual=residual,
        converged=fit.get("converged"),
        domain=ranges,
        shader=shader,
        shader_note=note,
        data=plain_json(data) if data is not None else None,
    )


# ------------------------------------------------------------------------------------------ I/O
def _check(doc, where: str) -> FittedFile:
    try:
        return from_json(FittedFile, doc, where)
    except ResultsError as e:
        raise FittedError(str(e)) from None


def write_fitted(path: Path, document: FittedFile) -> dict:
    """Validate ``document`` as the loader would (schema types, no NaN, shader or note), refuse a parameter
    without a unit (a `FittedError` naming it; "1" is the unit of a dimensionless one) and write it
    atomically as JSON, with its ``engine_presets`` (`rtfit.experiments.engine_presets.engine_presets_of`:
    the conversion of ``rtfit fitted convert``, made again from the methods' values here, never kept from
    the given document); returns the written JSON."""
    for i, m in enumerate(document.methods):
        for name, p in m.parameters.items():
            if not p.unit.strip():  # a number without its unit cannot be loaded into an engine safely
                raise FittedError(
                    f"{path}: methods[{i}].parameters.{name}.unit: no unit for {m.id!r} parameter {name!r} "
                    '(declare it: Param(unit=…), "1" if dimensionless)'
                )
    document = dataclasses.replace(document, engine_presets=engine_presets_of(document))
    doc = plain_json(to_json(document))
    _check(doc, str(path))
    atomic_write_json(Path(path), doc)
    return doc


def fit_record(doc_id: str, label: str, model: str, fit: Mapping, file: str, **extra) -> dict:
    """The results' ``fits`` record of one fit (what the report's fit table and ``results.json`` list):
    ``id``, ``label``, ``model`` (the formula as the report names it), the fit's ``parameters`` as fitted,
    its ``rms_residual``, ``n_residuals`` and ``converged`` (None where the fit lacks one), then a family's
    own keys ``extra`` (e.g. ``at_bound``, ``message``), and the fitted-parameter ``file`` (relative to
    the run folder) that carries it. One text for the record every experiment writes beside its file."""
    return {
        "id": doc_id,
        "label": label,
        "model": model,
        "parameters": fit["parameters"],
        "rms_residual": fit.get("rms_residual"),
        "n_residuals": fit.get("n_residuals"),
        "converged": fit.get("converged"),
        **extra,
        "file": file,
    }


def write_fit(
    out: Path,
    file: str,
    *,
    title: str,
    provenance: Provenance,
    entry: FittedMethod,
    doc_id: str,
    label: str,
    model: str,
    fit: Mapping,
    **extra,
) -> dict:
    """Write ``out / file``, a fitted-parameter file (``rtfit.fitted/1``, `write_fitted`) holding the one
    method ``entry`` under ``title`` and ``provenance``, and return the results' ``fits`` record of
    ``fit`` (`fit_record`; ``extra``: the family's own record keys).

    Most experiments write one such file per fit (per case, per variant); this is that pair of steps
    once, so the file and its record cannot drift apart (same ``file`` path in both)."""
    write_fitted(
        Path(out) / file, FittedFile(format=FORMAT, title=title, provenance=provenance, methods=[entry])
    )
    return fit_record(doc_id, label, model, fit, file, **extra)


def load_fitted(path: Path) -> FittedFile:
    """Read a ``rtfit.fitted/1`` file strictly; a `FittedError` line names the file and key path."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: float(c))
    except (OSError, json.JSONDecodeError) as e:
        raise FittedError(f"{path}: cannot read: {e}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else None
        raise FittedError(f"{path}: format: expected {FORMAT!r}, got {got!r}")
    return _check(doc, str(path))


def fitted_json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of ``rtfit.fitted/1``, generated from the records.

    Not expressible here and checked by the loader: a method without shader text has a shader_note, a
    (method, case) pair appears once, a range has lower ≤ upper; NaN and infinities are not JSON."""
    top, defs = record_json_schema(FittedFile)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://rtfit.invalid/fitted.schema.json",
        "title": f"rtfit fitted parameters ({FORMAT})",
        "description": (
            "Generated by rtfit.experiments.fitted.fitted_json_schema() from the record classes; "
            "docs/fitted-parameters.md describes every key. Checked by the loader, not here: a method "
            "without shader text has a shader_note; a (method, case) pair appears once; lower <= upper."
        ),
        **top,
        "$defs": defs,
    }
