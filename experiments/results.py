"""``results.json``: the schema name, and reading it back with validation.

Every experiment (and sweep) writes one ``results.json`` (schema ``rtfit.results/1``, described in
``docs/results-schema.md``); reports, the suite index and sweeps read it with :func:`load_results`,
which refuses anything a report could not show faithfully: a missing file, invalid JSON, NaN or
infinities, another schema version, a missing or mistyped key, a figure path outside the directory.
Each refusal is a :class:`ResultsError` with one line naming the file and the key.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

__all__ = ["RESULTS_FILE", "SCHEMA", "ResultsError", "load_results"]

SCHEMA = "rtfit.results/1"
RESULTS_FILE = "results.json"


class ResultsError(ValueError):
    """A results file that cannot be reported: a one-line message naming the file and the key."""


class _NonFinite:
    def __init__(self, token: str):
        self.token = token


def _find_sentinel(obj, where: str):
    if isinstance(obj, _NonFinite):
        return where, obj.token
    if isinstance(obj, dict):
        for k, v in obj.items():
            hit = _find_sentinel(v, f"{where}.{k}" if where else str(k))
            if hit:
                return hit
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            hit = _find_sentinel(v, f"{where}[{i}]")
            if hit:
                return hit
    return None


def _require(file, obj, where: str, key: str, kind, kind_name: str, optional: bool = False):
    if not isinstance(obj, dict):
        raise ResultsError(f"{file}: {where or 'top level'}: expected an object")
    if key not in obj or obj[key] is None:
        if optional:
            return None
        raise ResultsError(f"{file}: {where + '.' if where else ''}{key}: missing required key")
    if not isinstance(obj[key], kind):
        raise ResultsError(
            f"{file}: {where + '.' if where else ''}{key}: expected {kind_name}, "
            f"got {type(obj[key]).__name__}"
        )
    return obj[key]


def _validate(file, doc) -> None:
    if not isinstance(doc, dict):
        raise ResultsError(f"{file}: top level: expected an object")
    schema = doc.get("schema")
    if schema != SCHEMA:
        raise ResultsError(f"{file}: schema: expected {SCHEMA!r}, got {schema!r}")
    for key in ("experiment", "title", "summary", "created", "device"):
        _require(file, doc, "", key, str, "a string")
    for key in ("config", "versions"):
        _require(file, doc, "", key, dict, "an object")
    cases = _require(file, doc, "", "cases", list, "a list")
    for key in ("sections", "fits", "figures", "costs", "checks", "notes"):
        _require(file, doc, "", key, list, "a list", optional=True)
    for i, case in enumerate(cases):
        w = f"cases[{i}]"
        _require(file, case, w, "id", str, "a string")
        _require(file, case, w, "label", str, "a string")
        for key in ("parameters", "scene", "reference"):
            _require(file, case, w, key, dict, "an object", optional=True)
        for j, ap in enumerate(_require(file, case, w, "approximations", list, "a list")):
            wa = f"{w}.approximations[{j}]"
            _require(file, ap, wa, "method", str, "a string")
            _require(file, ap, wa, "parameters", dict, "an object", optional=True)
            _require(file, ap, wa, "figures", list, "a list", optional=True)
            for k, fig in enumerate(ap.get("figures") or []):
                _check_rel_path(file, f"{wa}.figures[{k}]", fig)
            for name, m in _require(file, ap, wa, "metrics", dict, "an object").items():
                if not isinstance(m, dict) or "value" not in m:
                    raise ResultsError(f"{file}: {wa}.metrics.{name}: expected an object with 'value'")
    for i, s in enumerate(doc.get("sections") or []):
        for key in ("id", "title", "text"):
            _require(file, s, f"sections[{i}]", key, str, "a string")
    for i, f in enumerate(doc.get("fits") or []):
        _require(file, f, f"fits[{i}]", "parameters", dict, "an object")
    for i, f in enumerate(doc.get("figures") or []):
        _check_rel_path(
            file, f"figures[{i}].file", _require(file, f, f"figures[{i}]", "file", str, "a string")
        )
    for i, c in enumerate(doc.get("costs") or []):
        _require(file, c, f"costs[{i}]", "method", str, "a string")
    for i, c in enumerate(doc.get("checks") or []):
        _require(file, c, f"checks[{i}]", "name", str, "a string")
        _require(file, c, f"checks[{i}]", "passed", bool, "true or false")
    for i, n in enumerate(doc.get("notes") or []):
        if not isinstance(n, str):
            raise ResultsError(f"{file}: notes[{i}]: expected a string")


def _check_rel_path(file, where: str, p) -> None:
    if (
        not isinstance(p, str)
        or not p
        or p.startswith(("/", "\\"))
        or ".." in re.split(r"[/\\]", p)
        or re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:", p)
    ):
        raise ResultsError(
            f"{file}: {where}: expected a relative path inside the experiment directory, got {p!r}"
        )


def load_results(directory) -> dict:
    """Read and validate ``DIRECTORY/results.json``.

    Raises :class:`ResultsError` (a ``ValueError``) with one line naming the file and the key for a
    missing file, invalid JSON, NaN/Infinity, a wrong schema version, or a missing or mistyped key.
    """
    file = Path(directory) / RESULTS_FILE
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ResultsError(f"{file}: not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ResultsError(f"{file}: cannot read: {e}") from None
    try:
        doc = json.loads(text, parse_constant=_NonFinite)
    except json.JSONDecodeError as e:
        raise ResultsError(f"{file}: invalid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    hit = _find_sentinel(doc, "")
    if hit:
        raise ResultsError(
            f"{file}: {hit[0]}: {hit[1]} is not a valid result (NaN and infinities are refused)"
        )
    _validate(file, doc)
    return doc
