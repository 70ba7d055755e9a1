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

__all__ = ["Row", "no_params", "resolved_means"]


def resolved_means(cases, methods, key: str = "rel_rmse") -> dict[str, float]:
    """Each of ``methods``' mean ``key`` over the case documents of ``cases`` (``results.json`` form) where
    every one of them is resolved (its value above 2× its noise floor, the metric's ``resolved``), so that a
    ranking of the means never ranks noise (issue 32: a quick run's SH L4 read 2.4–2.7× its true error where
    the reference's noise dominated). Empty when no case qualifies; a method absent from a kept case is left
    out."""
    ms = set(methods)
    kept = [
        {
            a["method"]: a["metrics"][key]
            for a in d["approximations"]
            if a["method"] in ms and key in a["metrics"]
        }
        for d in cases
    ]
    kept = [k for k in kept if all(m.get("resolved", True) for m in k.values())]
    vals = {m: [k[m]["value"] for k in kept if m in k] for m in ms}
    return {m: sum(v) / len(v) for m, v in vals.items() if v}


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

    Optional, for the families that need them (defaults: not used):
    ``short``: a short name for narrow table columns and figure panels;
    ``evaluate``: the family's own evaluation of the row (its signature is the family's, its docstring says);
    ``timed``: builds the Dr.Jit kernel the row's cost row times; ``cost_of``: the id of the row whose
    measured cost this row shares (None: its own, or none);
    ``source``: the key of the family's inputs the row reads (e.g. which baked coefficients);
    ``fitted_keys``: kernel parameter → the key of the family's fitted value it takes;
    ``reported``: values reported as the row's parameters though nothing is fitted (e.g. the (w, p) a
    fixed formula equals);
    ``in_figures``: shown in the family's image figures;
    ``options``: the family's own switches of the row (its docstring says which).
    """

    id: str
    label: str = ""
    method: str | None = None
    params: Callable[..., dict[str, Any]] = no_params
    fitted: bool = False
    fit: tuple[str, ...] = ()
    held: Mapping[str, float] = dataclasses.field(default_factory=dict, hash=False)
    short: str = ""
    evaluate: Callable | None = None
    timed: Callable | None = None
    cost_of: str | None = None
    source: str | None = None
    fitted_keys: Mapping[str, str] = dataclasses.field(default_factory=dict, hash=False)
    reported: Mapping[str, float] = dataclasses.field(default_factory=dict, hash=False)
    in_figures: bool = True
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict, hash=False)

    def title(self, methods: Mapping) -> str:
        """The row's name: its ``label``, else the label of its method in the family's ``methods``."""
        return self.label or methods[self.method].label
