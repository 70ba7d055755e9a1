"""The `Quantity` record (what an approximation approximates, and the named inputs its ``g`` carries) and
the pieces several rooms of the quantity table share: the x/y/z inputs of a vector, a surface point's and
a normal's inputs, and an SH sky as an example input.

The quantities themselves live in the rooms ``quantities_lights``, ``quantities_sky``, ``quantities_media``,
``quantities_probes`` and ``quantities_materials``; `rtfit.realtime.quantities` gathers them in order
(`QUANTITIES`) and turns a user's function into a `Method` (`approximation`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from .methods import Input, Method

__all__ = [
    "Quantity",
    "example_sh_coefficients",
    "quantity_table",
    "vector_inputs",
]


@dataclass(frozen=True)
class Quantity:
    """One approximated quantity: ``name``, ``unit`` of the result, ``description`` (one line), the
    ``inputs`` its ``g`` carries (scalar inputs with a ``domain``; structured ones without), ``vectors``
    (group name → its three component inputs, e.g. ``normal`` → ``(nx, ny, nz)``), ``unit_vectors`` (the
    groups that are unit vectors: validation samples them on the sphere), ``channels`` (1: one array
    per element; 3: a tuple of R, G, B arrays), ``examples`` (structured input → a factory ``f(n)`` of a
    value for validation on ``n`` samples), ``reference`` (what the audit compares an approximation of it
    with) and ``note``."""

    name: str
    unit: str
    description: str
    inputs: tuple[Input, ...]
    vectors: Mapping[str, tuple[str, str, str]] = field(default_factory=dict)
    unit_vectors: tuple[str, ...] = ()
    channels: int = 1
    examples: Mapping[str, Callable[[int], Any]] = field(default_factory=dict)
    reference: str = ""
    note: str = ""

    def __post_init__(self):
        object.__setattr__(self, "vectors", MappingProxyType(dict(self.vectors)))
        object.__setattr__(self, "examples", MappingProxyType(dict(self.examples)))
        names = self.input_names
        for group, comps in self.vectors.items():
            missing = [c for c in comps if c not in names]
            if missing or group in names:
                raise ValueError(f"quantity {self.name!r}: vector {group!r} is not three of its inputs")
        structured = {i.name for i in self.inputs if i.domain is None}
        if structured != set(self.examples):
            raise ValueError(f"quantity {self.name!r}: give an example of each structured input")

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(i.name for i in self.inputs)

    def methods(self, tables: Mapping[str, Mapping[str, Method]]) -> tuple[str, ...]:
        """The shipped methods of this quantity, as ``family:id``, from ``tables`` (family → its ``METHODS``
        table: the registry's, `rtfit.experiments.families.METHOD_TABLES`)."""
        return tuple(
            f"{family}:{mid}"
            for family, table in tables.items()
            for mid, m in table.items()
            if m.quantity == self.name
        )


def quantity_table(*quantities: Quantity) -> Mapping[str, Quantity]:
    """The ``quantities`` by name (read-only), in the order given: one room of the quantity table."""
    return MappingProxyType({q.name: q for q in quantities})


def vector_inputs(prefix: str, what: str, unit: str = "1", domain=(-1.0, 1.0)) -> tuple[Input, Input, Input]:
    """The three inputs ``<prefix>x``, ``<prefix>y``, ``<prefix>z`` of a vector: ``what`` with its x, y, z
    component, each of ``unit`` and ``domain``."""
    return tuple(Input(f"{prefix}{c}", unit, f"{what}, {c} component", domain) for c in "xyz")  # type: ignore[return-value]


def example_sh_coefficients(n: int = 0):
    """SH L2 coefficients (27, channel-major) of a sky brighter above than below: L00 and L10 only (any
    ``n``)."""
    out = [0.0] * 27
    for c, scale in enumerate((1.0, 0.9, 0.8)):
        out[c * 9 + 0] = 2.0 * math.sqrt(math.pi) * scale  # L00 of a constant radiance 1 (× scale)
        out[c * 9 + 2] = 0.8 * scale  # L10: brighter towards +Z
    return out


NORMAL_INPUTS = vector_inputs("n", "unit surface normal (world frame, +Z up)")
"""The unit surface normal's inputs nx, ny, nz."""
POINT_INPUTS = vector_inputs("p", "surface point", "m", (-10.0, 10.0))
"""The surface point's inputs px, py, pz."""
