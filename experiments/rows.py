"""The row of a family's comparison table: one approximation (or the exact quantity) evaluated on every
case, written as one ``Approximation`` of each case in ``results.json`` (``method`` = the row's ``id``).

A family declares its rows as a ``ROWS`` tuple of :class:`Row` and evaluates each on each case; what a
row's ``params`` receives is the family's own signature (its docstring says which), so the type is shared
while every family keeps its own parameter sources. Shared by the families; imports none of them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["Row", "no_params"]


def no_params(*_inputs) -> dict[str, Any]:
    """The parameter source of a row whose family computes its values itself: none."""
    return {}


@dataclasses.dataclass(frozen=True)
class Row:
    """One row of a comparison.

    ``id``: the row's id (the approximation's ``method`` key in ``results.json``, figure panels, costs);
    ``label``: its name in tables and figures;
    ``method``: the id in the family's ``METHODS`` table the row evaluates, or None for a row the family
    computes itself (the exact quantity by quadrature, a study's intermediate model);
    ``params``: the source of its parameter values, ``params(...) -> {name: value}`` with the family's
    arguments (default `no_params`: the family computes them, e.g. from ``fit`` and ``held``);
    ``fitted``: its values come from a fit to the reference;
    ``fit``: the names of the parameters that fit frees (empty: the family's fit decides);
    ``held``: parameters held at fixed values during the fit and reported beside the fitted ones.
    """

    id: str
    label: str = ""
    method: str | None = None
    params: Callable[..., dict[str, Any]] = no_params
    fitted: bool = False
    fit: tuple[str, ...] = ()
    held: Mapping[str, float] = dataclasses.field(default_factory=dict, hash=False)
