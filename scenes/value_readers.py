"""Readers of a scene file's values: each checks one TOML value (a number, an integer, a vector, a unit
vector, an RGB value, a string, a table) against its `rtfit.scenes.schema.Bounds` and returns it as the
model stores it, or raises `KeyProblem` with the key path and a one-line reason; `show_value` writes a
value back as TOML-ish text for those reasons, and `xml_problem` checks a Mitsuba XML file before it is
used. `rtfit.scenes.parse` turns a `KeyProblem` into a `SceneError` naming the file.
"""

from __future__ import annotations

import json
import math
from typing import Any
from xml.parsers import expat

from .schema import COORDINATE, Bounds

UNIT_TOLERANCE = 1e-12  # a vector this close to unit length is kept as written


class KeyProblem(Exception):
    """A problem at ``key`` of a scene file (the key path, e.g. ``lights[0].radius``) with its one-line
    ``reason``; `rtfit.scenes.parse` turns it into a :class:`~rtfit.scenes.parse.SceneError` naming the
    file."""

    def __init__(self, key: str, reason: str):
        super().__init__(key, reason)
        self.key, self.reason = key, reason


def show_value(v: Any, limit: int = 80) -> str:
    """A value as TOML-ish text for messages (booleans ``true``, strings double-quoted), truncated."""
    if isinstance(v, bool):
        s = "true" if v else "false"
    elif isinstance(v, str):
        s = json.dumps(v)
    elif isinstance(v, (list, tuple)):
        s = "[" + ", ".join(show_value(x, limit) for x in v) + "]"
    elif isinstance(v, dict):
        s = "{ " + ", ".join(f"{k} = {show_value(x, limit)}" for k, x in v.items()) + " }"
    else:
        s = repr(v)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def join_key(key: str, name: str) -> str:
    """The key path of ``name`` inside the table at ``key`` (``key.name``; ``name`` at the top level)."""
    return f"{key}.{name}" if key else name


def xml_problem(path: str) -> str | None:
    """What makes ``path`` unusable as a Mitsuba XML scene before anything renders (None: nothing
    found): not well-formed XML (with its line), an entity declaration (refused: entity expansion is an
    XXE / billion-laughs vector, and Mitsuba scenes use ``$name`` parameters instead), or a root element
    other than ``<scene>``. Mitsuba's own loader still checks plugins and properties at render time."""
    parser = expat.ParserCreate()
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    root: list[str] = []

    def refuse_entity(name, *_):
        raise ValueError(f"entity declaration {name!r} (not allowed in a scene file)")

    def start(name, _attrs):
        if not root:
            root.append(name)

    parser.EntityDeclHandler = refuse_entity
    parser.StartElementHandler = start
    try:
        with open(path, "rb") as f:
            parser.ParseFile(f)
    except expat.ExpatError as e:
        return f"not well-formed XML (line {e.lineno}, column {e.offset}: {expat.ErrorString(e.code)})"
    except ValueError as e:
        return str(e)
    except OSError as e:
        return f"cannot read ({e.strerror or e})"
    if root and root[0] != "scene":
        return f"the root element is <{root[0]}>, not <scene>"
    return None


def read_number(v: Any, key: str, bounds: Bounds | None = None) -> float:
    """A TOML number (not a boolean) at ``key``, finite and within ``bounds``, as a float."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise KeyProblem(key, f"must be a number (got {show_value(v)})")
    try:
        x = float(v)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise KeyProblem(key, f"must be finite (got {show_value(v)})")
    if bounds is not None and not bounds.contains(x):
        raise KeyProblem(key, f"{bounds.problem(x)} (got {show_value(v)})")
    return x


def read_integer(v: Any, key: str, bounds: Bounds | None = None) -> int:
    """A TOML integer (not a boolean, not a float) at ``key``, within ``bounds``."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise KeyProblem(key, f"must be an integer (got {show_value(v)})")
    if bounds is not None and not bounds.contains(v):
        raise KeyProblem(key, f"{bounds.problem(v)} (got {show_value(v)})")
    return v


def read_vector(v: Any, key: str, n: int, bounds: Bounds | None = None) -> tuple[float, ...]:
    """An array of ``n`` numbers at ``key``, each as `read_number` reads it, as a tuple of floats."""
    if not isinstance(v, list) or len(v) != n:
        raise KeyProblem(key, f"must be an array of {n} numbers (got {show_value(v)})")
    return tuple(read_number(x, f"{key}[{i}]", bounds) for i, x in enumerate(v))


def normalised(v: tuple[float, ...]) -> tuple[float, ...] | None:
    """``v`` scaled to unit length (``v`` itself if already within ``UNIT_TOLERANCE``); None if zero."""
    m = max(abs(c) for c in v)
    if m == 0.0:
        return None
    if abs(math.sqrt(sum(c * c for c in v)) - 1.0) <= UNIT_TOLERANCE:
        return tuple(v)
    s = [c / m for c in v]  # pre-scaled so huge or tiny components neither overflow nor underflow
    n = math.sqrt(sum(c * c for c in s))
    return tuple(c / n for c in s)


def read_unit(v: Any, key: str) -> tuple[float, ...]:
    """A non-zero 3-vector at ``key``, `normalised`."""
    u = normalised(read_vector(v, key, 3, COORDINATE))
    if u is None:
        raise KeyProblem(key, f"must be non-zero (got {show_value(v)})")
    return u


def read_rgb(v: Any, key: str, bounds: Bounds | None) -> tuple[float, float, float]:
    """An RGB value at ``key``: a number (grey) or an array of 3 numbers, each within ``bounds``."""
    if isinstance(v, list) and len(v) == 3:
        r, g, b = read_vector(v, key, 3, bounds)
        return (r, g, b)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        x = read_number(v, key, bounds)
        return (x, x, x)
    raise KeyProblem(key, f"must be a number or an array of 3 numbers (got {show_value(v)})")


def read_string(v: Any, key: str) -> str:
    """A TOML string at ``key``."""
    if not isinstance(v, str):
        raise KeyProblem(key, f"must be a string (got {show_value(v)})")
    return v


def read_table(v: Any, key: str) -> dict:
    """A TOML table at ``key``."""
    if not isinstance(v, dict):
        raise KeyProblem(key, f"must be a table (got {show_value(v)})")
    return v
