"""The strict loader of the ``results.json`` records (`rtfit.experiments.records`): :func:`from_json` builds
a record from parsed JSON by its type hints, :func:`plain_json` makes any result body plain JSON first.

Strictly: a bool is not a number, an int is a number, NaN and infinities are refused, a closed record refuses
unknown keys, an optional list or object given as null is empty, and every refusal is one
:class:`ResultsError` line naming the file and the key path, e.g.
``out/x/results.json: cases[3].approximations[0].metrics.rmse.value: expected a number, got str 'big'``.
Checks across fields (a record's ``problems``) run once its fields are read.
"""

from __future__ import annotations

import datetime
import json
import math
import re
import typing
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from .record_base import (
    DATE_TIME_PATTERN,
    DateTimeMark,
    JSONMark,
    Record,
    RelPathMark,
    field_default,
    is_record_type,
    is_required,
    null_is_empty,
    record_fields,
    to_json,
    type_hints,
    type_mark,
    union_args,
)

__all__ = ["ResultsError", "from_json", "plain_json"]


class ResultsError(ValueError):
    """A results document that cannot be reported: one line, ``FILE: KEY.PATH: problem``."""


# ------------------------------------------------------------------------------------------- words
def _alternatives(tp) -> list[str]:
    """The kinds of value ``tp`` accepts, in words (``["a number", "null"]``)."""
    mark = type_mark(tp)
    if isinstance(mark, JSONMark):
        return ["a JSON value"]
    if isinstance(mark, RelPathMark):
        return ["a relative path inside the experiment directory"]
    if isinstance(mark, DateTimeMark):
        return ["an ISO 8601 date and time with its time zone"]
    args = union_args(tp)
    if args is not None:
        words = [w for a in args if a is not type(None) for w in _alternatives(a)]
        return list(dict.fromkeys(words)) + (["null"] if type(None) in args else [])
    origin = typing.get_origin(tp)
    if origin is Literal:
        return [repr(v) for v in typing.get_args(tp)]
    if origin is list:
        return ["a list"]
    if origin is Mapping or is_record_type(tp):
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
    mark = type_mark(tp)
    if isinstance(mark, JSONMark):
        return _check_json(value, where)
    if isinstance(mark, RelPathMark):
        if not isinstance(value, str) or not _is_relative_path(value):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    if isinstance(mark, DateTimeMark):
        if not isinstance(value, str) or not _is_date_time(value):
            raise _Refusal(where, f"expected {_describe(tp)}, got {_got(value)}")
        return value
    args = union_args(tp)
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
    if is_record_type(tp):
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
    if isinstance(type_mark(tp), JSONMark):
        return True
    tp = tp.__origin__ if typing.get_origin(tp) is Annotated else tp
    origin = typing.get_origin(tp)
    if origin is Literal:
        return any(type(value) is type(v) for v in typing.get_args(tp))
    if origin is list:
        return isinstance(value, list)
    if origin is Mapping or is_record_type(tp):
        return isinstance(value, dict)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, tp)


def _build_record(cls, value, where: str):
    if not isinstance(value, dict):
        raise _Refusal(where or "top level", f"expected an object, got {_got(value)}")
    hints = type_hints(cls)
    kwargs: dict[str, Any] = {}
    for f in record_fields(cls):
        if f.name not in value:
            if is_required(f):
                raise _Refusal(_join(where, f.name), "missing required key")
            continue
        if value[f.name] is None and null_is_empty(f, hints[f.name]):
            kwargs[f.name] = field_default(f)  # an optional list or object given as null: empty
            continue
        kwargs[f.name] = _build(hints[f.name], value[f.name], _join(where, f.name))
    names = {f.name for f in record_fields(cls)}
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
