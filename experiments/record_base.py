"""The base of the ``results.json`` records (`rtfit.experiments.records`): :class:`Record` with its key
order memory, the marked string and JSON types (:data:`JSON`, :data:`RelPath`, :data:`DateTime`), what a
record's type hints say (its JSON fields, which are required, their defaults, the marks and unions the
loader and the schema read), and the writer :func:`to_json`.

A record read from JSON remembers which keys its object had and in which order (``json_keys``; not
compared), so ``to_json(from_json(doc)) == doc`` with the same key order: a null stays a null and an absent
key stays absent (both mean "not available" to readers). A record built in code writes its fields in
declaration order, leaving out optional ones at their default.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any, Union

__all__ = [
    "DATE_TIME_PATTERN",
    "JSON",
    "DateTime",
    "DateTimeMark",
    "JSONMark",
    "Record",
    "RelPath",
    "RelPathMark",
    "field_default",
    "is_record_type",
    "is_required",
    "null_is_empty",
    "record_fields",
    "to_json",
    "type_hints",
    "type_mark",
    "union_args",
]


class JSONMark:
    """Marks :data:`JSON`: any finite JSON value, kept as parsed (dicts, lists, str, numbers, bools, None)."""


class RelPathMark:
    """Marks :data:`RelPath`: a string that is a relative path inside the experiment directory."""


class DateTimeMark:
    """Marks :data:`DateTime`: an ISO 8601 date and time with its time zone (RFC 3339)."""


JSON = Annotated[object, JSONMark()]
"""Any finite JSON value (free-form data: configuration values, a case's parameters, family extras)."""
RelPath = Annotated[str, RelPathMark()]
"""A relative path inside the experiment directory: ``/``-separated, not absolute, no ``..``, no scheme."""
DateTime = Annotated[str, DateTimeMark()]
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
        values = {f.name: getattr(self, f.name) for f in record_fields(type(self))}
        written = [
            f.name
            for f in record_fields(type(self))
            if self.json_keys is None or f.name not in self.json_keys
            if is_required(f) or values[f.name] != field_default(f)
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


# ------------------------------------------------------------------------------------------- hints
def record_fields(cls) -> list[dataclasses.Field]:
    """The JSON fields of a record class (not ``json_keys`` and ``extra``)."""
    return [f for f in dataclasses.fields(cls) if f.name not in _META_FIELDS]


def is_required(f: dataclasses.Field) -> bool:
    """A key the JSON object must have: no default, or marked ``required`` (a default only for code)."""
    no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    return no_default or bool(f.metadata.get("required"))


def field_default(f: dataclasses.Field):
    """The value a record built in code has for field ``f`` when not given (``MISSING``: none)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


_HINTS: dict[type, dict[str, Any]] = {}


def type_hints(cls) -> dict[str, Any]:
    """The resolved type hints of record class ``cls``, marks (``Annotated``) kept; computed once."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls, include_extras=True)
    return _HINTS[cls]


def is_record_type(tp) -> bool:
    """Whether type ``tp`` is a record class (read and described field by field)."""
    return isinstance(tp, type) and issubclass(tp, Record)


def type_mark(tp):
    """The mark of ``tp`` (:class:`JSONMark`, :class:`RelPathMark` or :class:`DateTimeMark`), or None."""
    if typing.get_origin(tp) is Annotated:
        marks = (JSONMark, RelPathMark, DateTimeMark)
        return next((m for m in tp.__metadata__ if isinstance(m, marks)), None)
    return None


def union_args(tp) -> tuple | None:
    """The alternatives of a union type ``tp`` (``float | None``: ``(float, NoneType)``), or None."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        return typing.get_args(tp)
    return None


def null_is_empty(f: dataclasses.Field, tp) -> bool:
    """An optional list or object field (empty by default) also accepts null, meaning empty."""
    return not is_required(f) and f.default_factory is not dataclasses.MISSING and union_args(tp) is None


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
