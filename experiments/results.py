"""``results.json`` on disk: reading it into a typed :class:`~.records.Results` and writing one.

Every experiment (and sweep) writes one ``results.json`` (schema ``rtfit.results/1``, described in
``docs/results-schema.md``; the records are in :mod:`.records`). Reports, the suite index and sweeps read
it with :func:`load_results`, which refuses anything a report could not show faithfully: a missing file,
invalid JSON, NaN or infinities, another schema version, a missing, mistyped or (in a closed record)
unknown key, a duplicated case id, a figure path outside the directory. Each refusal is a
:class:`ResultsError` with one line naming the file and the key path.
"""

from __future__ import annotations

import json
from pathlib import Path

from .atomic import atomic_write_json
from .records import SCHEMA, Results, ResultsError, from_json, to_json

__all__ = ["RESULTS_FILE", "SCHEMA", "ResultsError", "load_results", "write_results"]

RESULTS_FILE = "results.json"


class _NonFinite:
    """What ``json.loads`` makes of ``NaN``/``Infinity`` here, so the loader can name the key."""

    def __init__(self, token: str):
        self.token = token


def _find_non_finite(obj, where: str):
    if isinstance(obj, _NonFinite):
        return where, obj.token
    if isinstance(obj, int) and not isinstance(obj, bool) and obj.bit_length() > 1023:  # beyond a float
        return where, f"an integer of {obj.bit_length()} bits"
    if isinstance(obj, dict):
        for k, v in obj.items():
            hit = _find_non_finite(v, f"{where}.{k}" if where else str(k))
            if hit:
                return hit
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            hit = _find_non_finite(v, f"{where}[{i}]")
            if hit:
                return hit
    return None


def load_results(directory) -> Results:
    """Read and validate ``DIRECTORY/results.json`` into a :class:`~.records.Results`.

    Raises :class:`ResultsError` (a ``ValueError``) with one line naming the file and the key path for a
    missing file, invalid JSON, NaN/Infinity, a wrong schema version, or a key the schema does not allow.
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
    except RecursionError:  # arrays or objects nested thousands deep: no results file is
        raise ResultsError(f"{file}: invalid results: nested too deeply") from None
    except ValueError as e:  # an integer of more than 4300 digits (Python's int-parsing limit)
        raise ResultsError(f"{file}: invalid JSON: {' '.join(str(e).split())[:120]}") from None
    hit = _find_non_finite(doc, "")
    if hit:
        raise ResultsError(
            f"{file}: {hit[0]}: {hit[1]} is not a valid result (NaN, infinities and numbers beyond a float "
            "are refused)"
        )
    return from_json(Results, doc, file)


def write_results(directory, results: Results) -> Path:
    """Write ``results`` as ``DIRECTORY/results.json`` (atomically). Returns the path."""
    return atomic_write_json(Path(directory) / RESULTS_FILE, to_json(results))
