"""The records of an engine preset (issue 37 §3): what `rtfit.experiments.engine_presets` writes, both into a
fitted file's ``engine_presets`` section (``rtfit.fitted/1``, `rtfit.experiments.fitted`) and as the
``rtfit.engine-preset/1`` document of ``rtfit fitted convert``: one text for both, and the schema of both
(``docs/fitted.schema.json``, generated from these records)::

    FittedFile.engine_presets ─ {engine: EnginePresets} ─ engine_title, anchor, sources (the documentation),
                                                          skipped (fits the engine cannot hold, each with why)
                                                        └ presets: [Preset] ─ engine, method, case, feature,
                                                                     base_height_m, fitted {name: value},
                                                                     values: [EngineValue], lost: [str]

The fitted-file side reads files structurally (`FittedLike`, `MethodLike`): this module and the conversions
do not import `rtfit.experiments.fitted`, which imports them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from .record_base import Record

__all__ = [
    "ENGINE_NAMES",
    "PRESET_FORMAT",
    "ConvertError",
    "EnginePresets",
    "EngineValue",
    "FittedLike",
    "MethodLike",
    "Preset",
    "plain_value",
]

PRESET_FORMAT = "rtfit.engine-preset/1"
ENGINE_NAMES = ("unreal", "unity-hdrp", "godot")
"""The engines ``rtfit fitted convert --engine`` knows (the keys of ``engine_presets``)."""


class ConvertError(ValueError):
    """A fitted file that cannot be converted (one line)."""


def plain_value(v) -> Any:
    """A property's value as JSON holds it: a number, or a list (of numbers or lists of numbers)."""
    if isinstance(v, (tuple, list)):
        return [plain_value(x) for x in v]
    return v if isinstance(v, int) and not isinstance(v, bool) else float(v)


@dataclass(frozen=True)
class EngineValue(Record):
    """One engine property: ``name`` as the engine's editor (or API) shows it, its ``value`` (a number, a
    colour or vector as a list, a matrix as a list of rows), its ``unit`` ("1": dimensionless) and a
    ``note``."""

    name: str
    value: float | list[float | list[float]]
    unit: str = field(default="", metadata={"required": True})
    note: str = ""


@dataclass(frozen=True)
class Preset(Record):
    """One fitted method (``method``, ``case`` as the file names them) in one engine's properties
    (``values``) of its engine ``feature`` (e.g. Unreal's Exponential Height Fog): the height its fog is
    anchored at (``base_height_m``, rtfit's metres; 0 where none), the fitted values converted (``fitted``),
    and what the engine's model does not hold (``lost``)."""

    engine: str
    method: str
    case: str | None = field(metadata={"required": True})
    feature: str = ""
    base_height_m: float = field(default=0.0, metadata={"required": True})
    fitted: Mapping[str, float] = field(default_factory=dict, metadata={"required": True})
    values: list[EngineValue] = field(default_factory=list, metadata={"required": True})
    lost: list[str] = field(default_factory=list, metadata={"required": True})

    def problems(self) -> list[tuple[str, str]]:
        if self.engine not in ENGINE_NAMES:
            return [("engine", f"unknown engine {self.engine!r} (known: {', '.join(ENGINE_NAMES)})")]
        return [] if self.values else [("values", "a preset without engine properties")]


@dataclass(frozen=True)
class EnginePresets(Record):
    """The presets of one engine: its title (the engine feature, e.g. Unreal's Exponential Height Fog), what
    rtfit's origin is in it (``anchor``), the documentation the conversion cites (``sources``), one
    `Preset` per converted method, and the fits it cannot hold, each with why (``skipped``)."""

    engine_title: str
    anchor: str
    sources: list[str]
    presets: list[Preset]
    skipped: list[str] = field(default_factory=list)

    def problems(self) -> list[tuple[str, str]]:
        if not self.sources:
            return [("sources", "no documentation cited for the conversion")]
        return [] if self.presets else [("presets", "an engine section without presets")]


# --------------------------------------------------------------- a fitted file, as the conversions read it
class ParameterLike(Protocol):
    @property
    def value(self) -> float: ...
    @property
    def unit(self) -> str: ...


class RangeLike(Protocol):
    @property
    def lower(self) -> float: ...


class MethodLike(Protocol):
    """What the conversions read of a `rtfit.experiments.fitted.FittedMethod`."""

    @property
    def id(self) -> str: ...
    @property
    def case(self) -> str | None: ...
    @property
    def parameters(self) -> Mapping[str, ParameterLike]: ...
    @property
    def domain(self) -> Mapping[str, RangeLike]: ...


class ProvenanceLike(Protocol):
    @property
    def experiment(self) -> str: ...


class FittedLike(Protocol):
    """What the conversions read of a `rtfit.experiments.fitted.FittedFile`."""

    @property
    def title(self) -> str: ...
    @property
    def provenance(self) -> ProvenanceLike: ...
    @property
    def methods(self) -> Sequence[MethodLike]: ...
