"""The typed records of ``results.json`` (schema ``rtfit.results/1``; `rtfit.experiments.records` is the
public face and draws their tree): the document :class:`Results` and everything in it, a frozen dataclass
per JSON object. Each field is a key (its type says what the loader accepts, the class docstring is the
schema's description); checks across fields that types cannot say are a record's ``problems``.
"""

from __future__ import annotations

import operator
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, TypedDict, Unpack

from .record_base import JSON, DateTime, Record, RelPath

__all__ = [
    "NON_NEGATIVE_METRICS",
    "SCHEMA",
    "Approximation",
    "Bound",
    "BoundText",
    "Case",
    "Check",
    "Config",
    "Cost",
    "Figure",
    "Fit",
    "FitParameter",
    "Headline",
    "Metric",
    "PixelCost",
    "PrecomputeShare",
    "PrecomputeTrigger",
    "Reference",
    "Relation",
    "Results",
    "Scene",
    "Section",
    "amortised_ns",
    "bound_text",
]

SCHEMA = "rtfit.results/1"


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


PrecomputeTrigger = Literal["frame", "light", "scene"]
"""When a method's precompute is paid again: every ``frame``, when a ``light`` changes, or when the ``scene``
changes."""


class PrecomputeShare:
    """What the two cost records with a precompute (:class:`PixelCost`, :class:`Cost`) derive alike: its
    share per pixel. A plain class, not a record: it adds no JSON key."""

    precompute_ms: float | None
    precompute_pixels: int | None

    @property
    def precompute_per_pixel(self) -> float | None:
        """The precompute's share per pixel if paid every frame (ns): ``precompute_ms`` spread over the
        ``precompute_pixels`` of the case it was timed on (None without both)."""
        return amortised_ns(self.precompute_ms, self.precompute_pixels)


@dataclass(frozen=True)
class PixelCost(Record, PrecomputeShare):
    """Measured cost of one approximation: ns per evaluated pixel, its reciprocal, the Dr.Jit backend; where
    the method has a precompute (a bake) an engine pays apart: its ``precompute_ms`` (one whole run), when
    it is paid again (``precompute_trigger``: ``frame``, ``light`` or ``scene``) and the pixels of the case it
    was timed on (``precompute_pixels``: ms × 10⁶ / pixels is its share per pixel if paid every frame)."""

    ns_per_pixel: float | None = None
    pixels_per_second: float | None = None
    backend: str | None = None
    precompute_ms: float | None = None
    precompute_trigger: PrecomputeTrigger | None = None
    precompute_pixels: int | None = None


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
    ``at_bound``: names of the parameters that ended on a bound; ``message``: the optimiser's;
    ``fitted_on``: where the fit started on a subsample of its case's pixels (the audit's large cases), which
    (e.g. "8192 of 65536 pixels"), before its polish on every pixel: its values, residuals and stderr are
    the full data's."""

    id: str | None = None
    label: str | None = None
    model: str | None = None
    parameters: Mapping[str, FitParameter | float] = field(default_factory=dict, metadata={"required": True})
    rms_residual: float | None = None
    n_residuals: int | None = None
    converged: bool | None = None
    at_bound: list[str] | None = None
    message: str | None = None
    fitted_on: str | None = None
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
class Cost(Record, PrecomputeShare):
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
    precompute_trigger: PrecomputeTrigger | None = None
    precompute_pixels: int | None = None
    precompute_note: str | None = None

    @property
    def display(self) -> str:
        """The label, or the method id."""
        return self.label or self.method


Bound = str | float
"""A check's bound, given once: a string is shown as written and read by ``float()`` for the test (``"1e-6"``
shows ``1e-6`` and tests against 1e-6); a number is tested as it is and shown by ``format(bound, fmt)`` (the
``fmt`` of the constructor: ``""`` writes it as ``str`` does, ``".2f"`` rounds the text, not the test)."""


Relation = Literal["≤", "<", "≥", ">", "="]
"""How a check's value must stand to its bound, written as its ``expected`` text shows it."""

_RELATION_TESTS = {"≤": operator.le, "<": operator.lt, "≥": operator.ge, ">": operator.gt, "=": operator.eq}
"""The test of each `Relation` (value, bound) → bool."""


def bound_text(bound: Bound, fmt: str = "") -> tuple[str, float]:
    """A check's bound as (the text its ``expected`` shows, the number its test uses): see `Bound`."""
    if isinstance(bound, str):
        return bound, float(bound)
    return format(bound, fmt), float(bound)


class BoundText(TypedDict, total=False):
    """How a relation's ``expected`` text is written around its bound (`Check.compare`): ``fmt``, the
    format of a number bound (`Bound`); ``quantity``, the text before the relation (``"max |z|"`` gives
    ``max |z| ≤ 4``); ``note``, the text after the bound (``"relative"`` gives ``≤ 1e-6 relative``)."""

    fmt: str
    quantity: str
    note: str


def _relation_constructor(relation: Relation, doc: str):
    """A constructor of `Check` for one `Relation` (``Check.at_most`` is ``≤``): ``(name, value, bound,
    **text)`` → `Check.compare` with that relation; ``doc`` its docstring."""

    def make(cls: type[Check], name: str, value: float, bound: Bound, **text: Unpack[BoundText]) -> Check:
        return cls.compare(name, value, relation, bound, **text)

    make.__doc__ = f"Passed when {doc} (`Check.compare`)."
    return classmethod(make)


@dataclass(frozen=True)
class Check(Record):
    """A self-consistency check of the run: the measured value, the accepted range as text, pass/fail."""

    # (The docstring above is the schema's description: docs/results.schema.json.) The constructors below
    # write ``expected`` and ``passed`` from one bound (a `Bound`: the text shown, or a number and its
    # ``fmt``), so the two cannot disagree; a NaN value passes none of them (every comparison with NaN is
    # false).

    name: str
    value: float | str | None = None
    expected: str | None = None
    passed: bool = field(default=False, metadata={"required": True})

    @classmethod
    def compare(
        cls, name: str, value: float, relation: Relation, bound: Bound, **text: Unpack[BoundText]
    ) -> Check:
        """Passed when ``value relation bound`` holds; expected ``[quantity ]relation bound[ note]``
        (`BoundText`: ``fmt``, ``quantity``, ``note``, each optional)."""
        shown, limit = bound_text(bound, text.get("fmt", ""))
        parts = (text.get("quantity", ""), relation, shown, text.get("note", ""))
        expected = " ".join(part for part in parts if part)
        passed = bool(_RELATION_TESTS[relation](value, limit))
        return cls(name=name, value=value, expected=expected, passed=passed)

    at_most = _relation_constructor(
        "≤", 'value ≤ bound, e.g. ``Check.at_most(name, err, "1e-6")``: ``≤ 1e-6``'
    )
    below = _relation_constructor("<", "value < bound: expected ``< bound``")
    at_least = _relation_constructor("≥", "value ≥ bound: expected ``≥ bound``")
    above = _relation_constructor(">", "value > bound: expected ``> bound``")
    exactly = _relation_constructor("=", "value == bound: expected ``= bound`` (`zero` writes a bare ``0``)")

    @classmethod
    def magnitude_at_most(cls, name: str, value: float, symbol: str, bound: Bound, *, fmt: str = "") -> Check:
        """Passed when ``|value| ≤ bound``; the signed value is kept, expected ``|symbol| ≤ bound`` (e.g.
        ``Check.magnitude_at_most(n, pooled, "z", "4")`` shows ``|z| ≤ 4``)."""
        text, limit = bound_text(bound, fmt)
        return cls(name=name, value=value, expected=f"|{symbol}| ≤ {text}", passed=bool(abs(value) <= limit))

    @classmethod
    def within(cls, name: str, value: float, centre: Bound, tolerance: Bound, *, fmt: str = "") -> Check:
        """Passed when ``|value − centre| ≤ tolerance``; expected ``centre ± tolerance`` (each a `Bound`,
        ``fmt`` for whichever is a number)."""
        (c_text, c), (t_text, t) = bound_text(centre, fmt), bound_text(tolerance, fmt)
        return cls(name=name, value=value, expected=f"{c_text} ± {t_text}", passed=bool(abs(value - c) <= t))

    @classmethod
    def zero(cls, name: str, value: float) -> Check:
        """Passed when ``value == 0`` (a count of failures, or a value that must vanish); expected ``0``."""
        return cls(name=name, value=value, expected="0", passed=bool(value == 0))

    @classmethod
    def holds(cls, name: str, flag: object) -> Check:
        """A claim that is true or false: value ``str(flag)`` (``True``/``False``), expected ``True``, passed
        ``bool(flag)``."""
        return cls(name=name, value=str(flag), expected="True", passed=bool(flag))


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
