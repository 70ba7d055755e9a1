"""``results.json`` as typed records: frozen dataclasses, a strict loader driven by their type hints,
the writer, and the JSON Schema generated from them.

The document (schema ``rtfit.results/1``, described in ``docs/results-schema.md`` and shipped as
``docs/results.schema.json``) is a :class:`Results` record::

    Results ─ config: Config, versions, sections: [Section], notes: [str], headline: [Headline]
            ├ cases: [Case] ─ scene: Scene, reference: Reference,
            │                 approximations: [Approximation] ─ metrics: {name: Metric}, cost: PixelCost
            ├ fits: [Fit] ─ parameters: {name: FitParameter}
            ├ figures: [Figure], costs: [Cost], checks: [Check]
            └ extra: per-family data (JSON), e.g. ``spectral`` or ``optical_depth_forms``

:func:`from_json` builds a record from parsed JSON, strictly: a bool is not a number, an int is a number,
NaN and infinities are refused, a closed record refuses unknown keys, and every refusal is one
:class:`ResultsError` line naming the file and the key path, e.g.
``out/x/results.json: cases[3].approximations[0].metrics.rmse.value: expected a number, got str 'big'``.
:func:`to_json` writes a record back. A record read from JSON remembers which keys its object had and in
which order (``json_keys``; not compared), so ``to_json(from_json(doc)) == doc`` with the same key order:
a null stays a null and an absent key stays absent (both mean "not available" to readers). A record built
in code writes its fields in declaration order, leaving out optional ones at their default.

Free-form places (``config`` beyond its known keys, a case's ``parameters``, a reference's extra keys, the
per-family top-level data) hold any finite JSON value (:data:`JSON`); every field a report reads is typed.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import re
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Union

__all__ = [
    "JSON",
    "SCHEMA",
    "Approximation",
    "Case",
    "Check",
    "Config",
    "Cost",
    "DateTime",
    "Figure",
    "Fit",
    "FitParameter",
    "Headline",
    "Metric",
    "PixelCost",
    "Record",
    "Reference",
    "RelPath",
    "Results",
    "ResultsError",
    "Scene",
    "Section",
    "amortised_ns",
    "from_json",
    "plain_json",
    "record_json_schema",
    "results_json_schema",
    "to_json",
]

SCHEMA = "rtfit.results/1"


class ResultsError(ValueError):
    """A results document that cannot be reported: one line, ``FILE: KEY.PATH: problem``."""


class _JSONMark:
    """Marks :data:`JSON`: any finite JSON value, kept as parsed (dicts, lists, str, numbers, bools, None)."""


class _RelPathMark:
    """Marks :data:`RelPath`: a string that is a relative path inside the experiment directory."""


class _DateTimeMark:
    """Marks :data:`DateTime`: an ISO 8601 date and time with its time zone (RFC 3339)."""


JSON = Annotated[object, _JSONMark()]
"""Any finite JSON value (free-form data: configuration values, a case's parameters, family extras)."""
RelPath = Annotated[str, _RelPathMark()]
"""A relative path inside the experiment directory: ``/``-separated, not absolute, no ``..``, no scheme."""
DateTime = Annotated[str, _DateTimeMark()]
"""An ISO 8601 date and time with seconds and its time zone (RFC 3339, e.g. ``2026-11-23T10:00:00Z`` or
``…+00:00``): a moment, not a local time; the date must exist (checked by `datetime.fromisoformat`)."""
DATE_TIME_PATTERN = (
    r"^[0-9]{4}-[0-9]{2}-[0-9]{2}T[0-9]{2}:[0-9]{2}:[0-9]{2}(\.[0-9]+)?(Z|[+-][0-9]{2}:[0-9]{2})$"
)
"""The shape of a `DateTime` (the schema's ``pattern``; the loader also checks that the day exists)."""

_META_FIELDS = ("json_keys", "extra")


# ------------------------------------------------------------------------------------------ records
@dataclass(frozen=True)
class Record:
    """Base of every record: JSON-key access and key order memory (see the module docstring).

    ``json_keys``: the keys of the JSON object this record was read from, in their order (``None`` for a
    record built in code). Subclasses that accept unknown keys (``OPEN = True``) keep them in ``extra``.
    """

    OPEN: typing.ClassVar[bool] = False
    json_keys: tuple[str, ...] | None = field(default=None, compare=False, repr=False, kw_only=True)

    def items(self) -> Iterator[tuple[str, Any]]:
        """``(JSON key, value)`` of every key the record writes, in the order :func:`to_json` writes them."""
        extra = getattr(self, "extra", {}) or {}
        values = {f.name: getattr(self, f.name) for f in _fields(type(self))}
        written = [
            f.name
            for f in _fields(type(self))
            if self.json_keys is None or f.name not in self.json_keys
            if _required(f) or values[f.name] != _default(f)
        ]
        order = [k for k in self.json_keys or () if k in values or k in extra]
        order += [k for k in written if k not in order] + [k for k in extra if k not in order]
        for k in order:
            yield k, (values[k] if k in values else extra[k])

    def __getitem__(self, key: str):
        """The value under JSON key ``key`` (a field or an extra key), as the document's dict was read."""
        for k, v in self.items():
            if k == key:
                return v
        raise KeyError(key)

    def get(self, key: str, default=None):
        """``self[key]``, or ``default`` where the record does not write ``key``."""
        try:
            return self[key]
        except KeyError:
            return default

    def problems(self) -> list[tuple[str, str]]:
        """Checks across fields that type hints cannot express: ``(key path relative to this record,
        problem)`` pairs; empty when the record is consistent."""
        return []


NON_NEGATIVE_METRICS = ("rmse", "rel_mse", "mae", "max_abs", "flip", "smape")
"""Metrics that are errors or distances, never negative (`rtfit.fitting.ALL_METRICS`; psnr, ssim may be)."""


@dataclass(frozen=True)
class Metric(Record):
    """One metric of an approximation against the reference (same units as ``value``).

    ``noise_floor``: the value a perfect approximation gets from the reference's Monte Carlo noise alone;
    ``resolved``: False when ``value`` cannot be told apart from the floor (missing means true);
    ``debiased``: the value with the reference-noise contribution removed (stored, not shown).
    """

    value: float | None
    noise_floor: float | None = None
    resolved: bool | None = None
    debiased: float | None = None


def amortised_ns(precompute_ms: float | None, pixels: int | None) -> float | None:
    """ns per pixel of a precompute of ``precompute_ms`` paid every frame of ``pixels`` pixels (None where
    either is missing or the pixels are not positive)."""
    if precompute_ms is None or not pixels or pixels <= 0:
        return None
    return precompute_ms * 1e6 / pixels


@dataclass(frozen=True)
class PixelCost(Record):
    """Measured cost of one approximation: ns per evaluated pixel, its reciprocal, the Dr.Jit backend; where
    the method has a precompute (a bake) an engine pays apart: its ``precompute_ms`` (one whole run), when
    it is paid again (``precompute_trigger``: ``frame``, ``light`` or ``scene``) and the pixels of the case it
    was timed on (``precompute_pixels``: ms × 10⁶ / pixels is its share per pixel if paid every frame)."""

    ns_per_pixel: float | None = None
    pixels_per_second: float | None = None
    backend: str | None = None
    precompute_ms: float | None = None
    precompute_trigger: Literal["frame", "light", "scene"] | None = None
    precompute_pixels: int | None = None

    @property
    def precompute_per_pixel(self) -> float | None:
        """The precompute's share per pixel if paid every frame (ns): ``precompute_ms`` spread over the
        ``precompute_pixels`` of the case it was timed on (None without both)."""
        return amortised_ns(self.precompute_ms, self.precompute_pixels)


@dataclass(frozen=True)
class Approximation(Record):
    """One method evaluated against a case's reference: its parameters, metrics, cost and images."""

    method: str
    label: str | None = None
    fitted: bool = False
    parameters: Mapping[str, float] = field(default_factory=dict)
    metrics: Mapping[str, Metric] = field(default_factory=dict, metadata={"required": True})
    cost: PixelCost | None = None
    figures: list[RelPath] = field(default_factory=list)

    def problems(self) -> list[tuple[str, str]]:
        """A metric that cannot be negative (an error or distance: `NON_NEGATIVE_METRICS`) with a negative
        value or floor: a results file edited or written wrong (issue 32: ``rmse.value = -5`` was shown)."""
        out = []
        for name, m in self.metrics.items():
            if name not in NON_NEGATIVE_METRICS:
                continue
            for key in ("value", "noise_floor"):  # (``debiased`` subtracts the floor: it may be < 0)
                v = getattr(m, key)
                if isinstance(v, int | float) and not isinstance(v, bool) and v < 0:
                    out.append((f"metrics.{name}.{key}", f"must be >= 0 (got {v!r}: {name} is an error)"))
        return out

    @property
    def display(self) -> str:
        """The label, or the method id where there is none."""
        return self.label or self.method


@dataclass(frozen=True)
class Scene(Record):
    """The scene of a case: its name and the sha256 (hex) of its canonical description."""

    name: str | None = None
    hash: str | None = None


@dataclass(frozen=True)
class Reference(Record):
    """The ground truth of a case. Known keys are typed; unknown keys are kept in ``extra`` and shown.

    ``spp``: samples per pixel over all passes; ``passes``: independent passes (the standard error comes
    from their spread); ``mean_rel_stderr``: mean over pixels of stderr/|mean|; ``samples_per_second``:
    rendering throughput (wall clock).
    """

    OPEN: typing.ClassVar[bool] = True
    cache_key: str | None = None
    quantity: str | None = None
    integrator: str | None = None
    max_depth: int | None = None
    integrator_reason: str | None = None
    variant: str | None = None
    spp: int | None = None
    passes: int | None = None
    mean_rel_stderr: float | None = None
    samples_per_second: float | None = None
    extra: Mapping[str, JSON] = field(default_factory=dict)


@dataclass(frozen=True)
class Case(Record):
    """One evaluated scene configuration. ``parameters``: name → value with the unit in the name."""

    id: str
    label: str
    parameters: Mapping[str, JSON] = field(default_factory=dict)
    scene: Scene | None = None
    reference: Reference | None = None
    approximations: list[Approximation] = field(default_factory=list, metadata={"required": True})

    def problems(self) -> list[tuple[str, str]]:
        seen: dict[str, int] = {}
        out = []
        for i, ap in enumerate(self.approximations):
            if ap.method in seen:
                first = f"approximations[{seen[ap.method]}]"
                out.append(
                    (
                        f"approximations[{i}].method",
                        f"duplicate method {ap.method!r} in this case (also {first})",
                    )
                )
            seen.setdefault(ap.method, i)
        return out


@dataclass(frozen=True)
class FitParameter(Record):
    """A fitted parameter: value, standard error from the Jacobian at the optimum (null: none), the
    bounds of its allowed range (null: unbounded), and whether the optimum sits on a bound."""

    value: float
    stderr: float | None = None
    lower: float | None = None
    upper: float | None = None
    at_bound: bool = False


@dataclass(frozen=True)
class Fit(Record):
    """A parameter fit. ``parameters``: name → :class:`FitParameter` (a bare number is the value);
    ``at_bound``: names of the parameters that ended on a bound; ``message``: the optimiser's."""

    id: str | None = None
    label: str | None = None
    model: str | None = None
    parameters: Mapping[str, FitParameter | float] = field(default_factory=dict, metadata={"required": True})
    rms_residual: float | None = None
    n_residuals: int | None = None
    converged: bool | None = None
    at_bound: list[str] | None = None
    message: str | None = None
    file: RelPath | None = None

    @property
    def display(self) -> str:
        """The label, or the id, or ``?``."""
        return self.label or self.id or "?"


@dataclass(frozen=True)
class Figure(Record):
    """A figure: image file, markdown caption, and the section it goes in (a section id or a part name)."""

    file: RelPath
    caption: str | None = None
    section: str | None = None


@dataclass(frozen=True)
class Section(Record):
    """A free-text report section (markdown ``text``), before the results unless ``after_results``."""

    id: str
    title: str
    text: str
    placement: Literal["before_results", "after_results"] | None = None


@dataclass(frozen=True)
class Cost(Record):
    """Measured cost of one method on the run's device: median ns per pixel after warm-up, its
    reciprocal, the backend (``llvm``, ``cuda``, ``numpy``), what was timed (markdown ``note``), the
    kernel size and repetitions, and for stored representations the floats per probe. A method with a
    precompute (a bake an engine pays apart from the per-pixel kernel) also has its median ``precompute_ms``
    (one whole run, timed like the kernel), its ``precompute_trigger`` (paid again every ``frame``, when a
    ``light`` changes, or when the ``scene`` changes), the ``precompute_pixels`` of the case it was timed on
    and ``precompute_note`` (what it does)."""

    method: str
    label: str | None = None
    backend: str | None = None
    ns_per_pixel: float | None = None
    pixels_per_second: float | None = None
    elements: int | None = None
    repeats: int | None = None
    floats_per_probe: int | None = None
    note: str | None = None
    precompute_ms: float | None = None
    precompute_trigger: Literal["frame", "light", "scene"] | None = None
    precompute_pixels: int | None = None
    precompute_note: str | None = None

    @property
    def precompute_per_pixel(self) -> float | None:
        """The precompute's share per pixel if paid every frame (ns): ``precompute_ms`` spread over the
        ``precompute_pixels`` of the case it was timed on (None without both)."""
        return amortised_ns(self.precompute_ms, self.precompute_pixels)

    @property
    def display(self) -> str:
        """The label, or the method id."""
        return self.label or self.method


@dataclass(frozen=True)
class Check(Record):
    """A self-consistency check of the run: the measured value, the accepted range as text, pass/fail."""

    name: str
    value: float | str | None = None
    expected: str | None = None
    passed: bool = field(default=False, metadata={"required": True})


@dataclass(frozen=True)
class Headline(Record):
    """An extra headline number for the suite index."""

    label: str | None = None
    value: float | str | None = None
    unit: str | None = None


@dataclass(frozen=True)
class Config(Record):
    """The run configuration. The runner's keys are typed; the experiment's own keys (any JSON) are kept
    in ``extra``; all are shown in their order."""

    OPEN: typing.ClassVar[bool] = True
    experiment: str | None = None
    quick: bool | None = None
    variant: str | None = None
    spp: int | None = None
    seed: int | None = None
    executor: str | None = None
    overrides: Mapping[str, JSON] | None = None
    sweep_point: str | None = None
    extra: Mapping[str, JSON] = field(default_factory=dict)


@dataclass(frozen=True)
class Results(Record):
    """The whole ``results.json`` document (schema ``rtfit.results/1``).

    Unknown top-level keys are the experiment's own data (any JSON), kept in ``extra``. Case ids are unique.
    """

    OPEN: typing.ClassVar[bool] = True
    schema: Literal[SCHEMA]
    experiment: str
    title: str
    created: DateTime
    versions: Mapping[str, str | None]
    device: str
    summary: str
    config: Config
    sections: list[Section] = field(default_factory=list)
    cases: list[Case] = field(default_factory=list, metadata={"required": True})
    fits: list[Fit] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    costs: list[Cost] = field(default_factory=list)
    checks: list[Check] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    headline: list[Headline] = field(default_factory=list)
    extra: Mapping[str, JSON] = field(default_factory=dict)

    def problems(self) -> list[tuple[str, str]]:
        seen: dict[str, int] = {}
        out = []
        for i, c in enumerate(self.cases):
            if c.id in seen:
                out.append((f"cases[{i}].id", f"duplicate case id {c.id!r} (also cases[{seen[c.id]}])"))
            seen.setdefault(c.id, i)
        return out


# ------------------------------------------------------------------------------------------- hints
def _fields(cls) -> list[dataclasses.Field]:
    """The JSON fields of a record class (not ``json_keys`` and ``extra``)."""
    return [f for f in dataclasses.fields(cls) if f.name not in _META_FIELDS]


def _required(f: dataclasses.Field) -> bool:
    """A key the JSON object must have: no default, or marked ``required`` (a default only for code)."""
    no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    return no_default or bool(f.metadata.get("required"))


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls, include_extras=True)
    return _HINTS[cls]


def _is_record(tp) -> bool:
    return isinstance(tp, type) and issubclass(tp, Record)


def _mark(tp):
    if typing.get_origin(tp) is Annotated:
        marks = (_JSONMark, _RelPathMark, _DateTimeMark)
        return next((m for m in tp.__metadata__ if isinstance(m, marks)), None)
    return None


def _union_args(tp) -> tuple | None:
    if typing.get_origin(tp) in (Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _alternatives(tp) -> list[str]:
    """The kinds of value ``tp`` accepts, in words (``["a number", "null"]``)."""
    mark = _mark(tp)
    if isinstance(mark, _JSONMark):
        return ["a JSON value"]
    if isinstance(mark, _RelPathMark):
        return ["a relative path inside the experiment directory"]
    if isinstance(mark, _DateTimeMark):
        return ["an ISO 8601 date and time with its time zone"]
    args = _union_args(tp)
    if args is not None:
        words = [w for a in args if a is not type(None) for w in _alternatives(a)]
        return list(dict.fromkeys(words)) + (["null"] if type(None) in args else [])
    origin = typing.get_origin(tp)
    if origin is Literal:
        return [repr(v) for v in typing.get_args(tp)]
    if origin is list:
        return ["a list"]
    if origin is Mapping or _is_record(tp):
        return ["an object"]
    return {bool: ["true", "false"], int: ["an integer"], float: ["a number"], str: ["a string"]}[tp]


def _describe(tp) -> str:
    """The expected kind of a value, in words: ``a number or null``, ``true or false``…"""
    words = _alternatives(tp)
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]


def _got(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, (dict, list)):
        return type(value).__name__
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 60 else text[:57] + '…'}"


# ------------------------------------------------------------------------------------------- loader
class _Refusal(Exception):
    """A value that does not fit its type: the key path and the problem (made into a ResultsError)."""

    def __init__(self, where: str, problem: str):
        super().__init__(where, problem)
        self.where, self.problem = where, problem


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


_REL_PATH_REFUSED = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def _check_json(value, where: str):
    """``value`` itself if it is plain, finite JSON (dict keys are strings)."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise _Refusal(where, f"{value!r} is not a valid result (NaN and infinities are refused)")
        return value
    if isinstance(value, list):
        return [_check_json(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        for k in value:
            if not isinstance(k, str):
                raise _Refusal(where, f"expected string keys, got {_got(k)}")
        return {k: _check_json(v, _join(where, k)) for k, v in value.items()}
    raise _Refusal(where, f"expected a JSON value, got {type(value).__name__}")


def _build(tp, value, where: str):
    """``value`` (parsed JSON) as type ``tp``, or :class:`_Refusal`."""
    mark = _mark(tp)
    if isinstance(mark, _JSONMark):
        return _check_json(value, where)
    if isinstance(mark, _RelPathMark):
        if not isinstance(value, str) or not _is_relative_path(value):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    if isinstance(mark, _DateTimeMark):
        if not isinstance(value, str) or not _is_date_time(value):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    args = _union_args(tp)
    if args is not None:
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is not type(None) and _fits_kind(a, value):
                try:
                    return _build(a, value, where)
                except _Refusal as e:
                    if e.where != where or not e.problem.startswith("expected"):
                        raise  # a problem inside the value, or NaN: its own message says more
                    break
        raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
    origin = typing.get_origin(tp)
    if origin is Literal:
        if not any(value == v and type(value) is type(v) for v in typing.get_args(tp)):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    if origin is list:
        if not isinstance(value, list):
            raise _Refusal(where, f"expected a list, got {_got(value)}")
        (item,) = typing.get_args(tp)
        return [_build(item, v, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is Mapping:
        if not isinstance(value, dict):
            raise _Refusal(where, f"expected an object, got {_got(value)}")
        _, item = typing.get_args(tp)
        return {k: _build(item, v, _join(where, k)) for k, v in value.items()}
    if _is_record(tp):
        return _build_record(tp, value, where)
    if tp is float:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise _Refusal(where, f"expected a number, got {_got(value)}")
        if not math.isfinite(value):
            raise _Refusal(where, f"{value!r} is not a valid result (NaN and infinities are refused)")
        return value
    if tp is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise _Refusal(where, f"expected an integer, got {_got(value)}")
        return value
    if tp in (bool, str):
        if not isinstance(value, tp):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    raise TypeError(f"records: no JSON reading for type {tp!r}")


def _fits_kind(tp, value) -> bool:
    """Whether ``value`` has the JSON kind of ``tp`` (chooses the alternative of a union to read as)."""
    if isinstance(_mark(tp), _JSONMark):
        return True
    tp = tp.__origin__ if typing.get_origin(tp) is Annotated else tp
    origin = typing.get_origin(tp)
    if origin is Literal:
        return any(type(value) is type(v) for v in typing.get_args(tp))
    if origin is list:
        return isinstance(value, list)
    if origin is Mapping or _is_record(tp):
        return isinstance(value, dict)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, tp)


def _build_record(cls, value, where: str):
    if not isinstance(value, dict):
        raise _Refusal(where or "top level", f"expected an object, got {_got(value)}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for f in _fields(cls):
        if f.name not in value:
            if _required(f):
                raise _Refusal(_join(where, f.name), "missing required key")
            continue
        if value[f.name] is None and _null_is_empty(f, hints[f.name]):
            kwargs[f.name] = _default(f)  # an optional list or object given as null: empty
            continue
        kwargs[f.name] = _build(hints[f.name], value[f.name], _join(where, f.name))
    names = {f.name for f in _fields(cls)}
    unknown = [k for k in value if k not in names]
    if unknown and not cls.OPEN:
        allowed = ", ".join(sorted(names))
        article = "an" if cls.__name__[0] in "AEIOU" else "a"
        raise _Refusal(_join(where, unknown[0]), f"unknown key ({article} {cls.__name__} has: {allowed})")
    if cls.OPEN:
        kwargs["extra"] = {k: _check_json(value[k], _join(where, k)) for k in unknown}
    record = cls(**kwargs, json_keys=tuple(value))
    for sub, problem in record.problems():
        raise _Refusal(_join(where, sub), problem)
    return record


def _null_is_empty(f: dataclasses.Field, tp) -> bool:
    """An optional list or object field (empty by default) also accepts null, meaning empty."""
    return not _required(f) and f.default_factory is not dataclasses.MISSING and _union_args(tp) is None


def _is_relative_path(p: str) -> bool:
    return bool(p) and not (
        p.startswith(("/", "\\")) or ".." in re.split(r"[/\\]", p) or _REL_PATH_REFUSED.match(p)
    )


def _is_date_time(text: str) -> bool:
    """Whether ``text`` has the `DATE_TIME_PATTERN` shape and names a real moment (no 30 February)."""
    if not re.match(DATE_TIME_PATTERN, text):
        return False
    try:  # Python 3.11 reads "Z" and any fraction of a second
        datetime.datetime.fromisoformat(text)
    except ValueError:  # the shape is right, the values are not (month 13, hour 25, 30 February)
        return False
    return True


def from_json(cls, obj, path) -> Any:
    """Build record class ``cls`` (e.g. :class:`Results`) from parsed JSON ``obj``.

    ``path`` names the source in the error (a file, or e.g. ``"<experiment half-lambert>"``). Raises
    :class:`ResultsError` with one line, ``PATH: KEY.PATH: problem``.
    """
    try:
        return _build_record(cls, obj, "")
    except _Refusal as e:
        raise ResultsError(f"{path}: {e.where}: {e.problem}") from None


def plain_json(obj):
    """``obj`` as plain parsed JSON: records become their JSON objects (:func:`to_json`), NumPy scalars and
    arrays numbers and lists, tuples lists.

    NaN and infinities pass through as floats (for :func:`from_json` to refuse with the key path)."""

    def default(o):
        if isinstance(o, Record):  # e.g. an experiment's checks, built as `Check` records
            return to_json(o)
        if hasattr(o, "tolist"):
            return o.tolist()
        raise TypeError(f"{type(o).__name__} is not JSON")

    return json.loads(json.dumps(obj, default=default))


# ------------------------------------------------------------------------------------------- writer
def to_json(value):
    """A record (or a value inside one) as plain JSON, keys in the order described in the module docstring."""
    if isinstance(value, Record):
        return {k: to_json(v) for k, v in value.items()}
    if isinstance(value, Mapping):
        return {k: to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    return value


# ------------------------------------------------------------------------------------------- schema
def _schema_of(tp, defs: dict) -> dict:
    mark = _mark(tp)
    if isinstance(mark, _JSONMark):
        return {}
    if isinstance(mark, _RelPathMark):
        return {
            "type": "string",
            "minLength": 1,
            "pattern": r"^(?![/\\])(?![A-Za-z][A-Za-z0-9+.-]*:)(?!(.*[/\\])?\.\.([/\\]|$))",
            "description": "relative path inside the experiment directory (no leading /, no .., no scheme)",
        }
    if isinstance(mark, _DateTimeMark):
        return {
            "type": "string",
            "format": "date-time",
            "pattern": DATE_TIME_PATTERN,
            "description": "ISO 8601 date and time with its time zone (RFC 3339), e.g. 2026-11-23T10:00:00Z",
        }
    args = _union_args(tp)
    if args is not None:
        return {"anyOf": [_schema_of(a, defs) for a in args]}
    origin = typing.get_origin(tp)
    if origin is Literal:
        values = list(typing.get_args(tp))
        return {"const": values[0]} if len(values) == 1 else {"enum": values}
    if origin is list:
        return {"type": "array", "items": _schema_of(typing.get_args(tp)[0], defs)}
    if origin is Mapping:
        return {"type": "object", "additionalProperties": _schema_of(typing.get_args(tp)[1], defs)}
    if _is_record(tp):
        if tp.__name__ not in defs:
            defs[tp.__name__] = {}  # placeholder against recursion
            hints = _hints(tp)
            fields = _fields(tp)
            defs[tp.__name__] = {
                "type": "object",
                "description": " ".join((tp.__doc__ or "").split()),
                "properties": {f.name: _field_schema(f, hints[f.name], defs) for f in fields},
                "required": [f.name for f in fields if _required(f)],
                "additionalProperties": {} if tp.OPEN else False,
            }
        return {"$ref": f"#/$defs/{tp.__name__}"}
    return {"type": {bool: "boolean", int: "integer", float: "number", str: "string", type(None): "null"}[tp]}


def _field_schema(f: dataclasses.Field, tp, defs: dict) -> dict:
    schema = _schema_of(tp, defs)
    return {"anyOf": [schema, {"type": "null"}]} if _null_is_empty(f, tp) else schema


def record_json_schema(cls) -> tuple[dict, dict]:
    """``(schema, defs)`` of record class ``cls``: its ``$ref`` and the ``$defs`` it needs (for documents
    other than ``results.json`` built from records, e.g. `rtfit.experiments.fitted`)."""
    defs: dict = {}
    top = _schema_of(cls, defs)
    return top, dict(sorted(defs.items()))


def results_json_schema() -> dict:
    """The JSON Schema (draft 2020-12) of ``results.json``, generated from the records.

    What it cannot say: case ids are unique, and a case lists each method once (the loader checks both);
    NaN and infinities are not JSON at all.
    """
    defs: dict = {}
    top = _schema_of(Results, defs)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://rtfit.invalid/results.schema.json",
        "title": f"rtfit results.json ({SCHEMA})",
        "description": (
            "Generated by rtfit.experiments.records.results_json_schema() from the record classes; "
            "docs/results-schema.md describes every key. Not expressible here and checked by the loader: "
            "case ids are unique, and a case lists each method once."
        ),
        **top,
        "$defs": dict(sorted(defs.items())),
    }
