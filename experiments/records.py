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

This module is the public face: it re-exports the records and their functions from the rooms that hold
them, `rtfit.experiments.record_base` (:class:`Record`, the marked types, :func:`to_json`),
`rtfit.experiments.record_types` (the record classes), `rtfit.experiments.record_loader` (:func:`from_json`,
:func:`plain_json`, :class:`ResultsError`) and `rtfit.experiments.record_schema` (the JSON Schema).
"""

from __future__ import annotations

from . import record_types
from .record_base import JSON, DateTime, Record, RelPath, to_json
from .record_loader import ResultsError, from_json, plain_json
from .record_schema import record_json_schema, results_json_schema
from .record_types import *  # noqa: F403 (the record classes: record_types.__all__)

__all__ = [
    "JSON",
    "DateTime",
    "Record",
    "RelPath",
    "ResultsError",
    "from_json",
    "plain_json",
    "record_json_schema",
    "results_json_schema",
    "to_json",
]
__all__ += record_types.__all__  # (every record type, re-exported)
