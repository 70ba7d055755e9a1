"""Costs kept across runs: a method's measured cost (`audit_cost.method_cost`) stored in the run's cache
directory (``CACHE/costs/<key>.json``) and read back by a later run that would time the same thing.

The key is a SHA-256 over everything the measurement depends on:
- rtfit's own source text (every ``.py`` file of its five packages: the kernel texts, their helpers and the
  timing protocol; any change to any of them measures again);
- the machine and its software: the device in words (CPU model and Dr.Jit's thread count, or the GPU's
  name), the Dr.Jit backend, the Dr.Jit, Mitsuba and NumPy versions;
- the protocol's sizes (the elements asked for);
- the method: its id, its fixed keyword values and its parameters' declared values (what the cost is
  measured at);
- the inputs the kernel reads, by content: every array's dtype, shape and bytes, every number, and a
  sampler object's own arrays and numbers (its per-backend copies, which the first use makes, are left out:
  `_feed`).

A method whose key cannot be made (your own approximations, whose text is not rtfit's; a fixed value or an
input that is neither an array, a number nor an object holding arrays) is measured every run. A kept cost is
the first run's number and says so (its ``note`` and ``measured_at``): on a machine whose load changed, a
cost measured again may differ by more than its median's ± 3 % (the run-to-run spread here: factors
0.63–2.22, docs/benchmarks.md), and deleting the cache's ``costs/`` (or a fresh ``--cache``) measures it
again (``rtfit cache info`` counts its files; ``prune`` leaves them).

Issue 33 (session 23): a second audit of a scene re-timed its 38 methods, 1.8–2.2 s of a cached 64² Cornell
box audit of 10–12 s (the references themselves 0.5 s).

A row's precompute timing (a bake, `audit_cases.CaseRun.precompute`) is kept the same way
(`CostStore.precompute_key`: its method's key, the case's reference cache key, the step's words, trigger and
pixel count). Session 33: a second 64² audit of Blender's test1 scene re-timed its five light-path-map bakes
(each run 4 times): evaluation 2.9 → 0.5 s."""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib
import json
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime.methods import Method
from rtfit.reference.io import atomic_write_bytes

STORE_FORMAT = 2
"""The layout of a stored record; a change makes every key new."""
_PACKAGES = ("rtfit.scenes", "rtfit.reference", "rtfit.realtime", "rtfit.fitting", "rtfit.experiments")
_MAX_DEPTH = 12
"""How deep `_feed` follows an input object's attributes, dicts and lists before it gives up (no key)."""


@functools.cache
def source_digest() -> str:
    """SHA-256 of the text of every ``.py`` file of rtfit's packages (by their paths under each package)."""
    h = hashlib.sha256()
    for name in _PACKAGES:
        for root in importlib.import_module(name).__path__:
            for path in sorted(Path(root).rglob("*.py")):
                h.update(f"{name}/{path.relative_to(root).as_posix()}\0".encode())
                h.update(path.read_bytes())
    return h.hexdigest()


def _array_digest(a: np.ndarray, digests: dict[int, tuple[np.ndarray, bytes]] | None) -> bytes:
    """SHA-256 of ``a``'s dtype, shape and bytes, kept in ``digests`` by the array's id (the array held
    there, so that its id stays its own) where a dict is given: the methods of one case read the same
    arrays (obscurances' seven, 32 hit distances each), which were hashed once a method."""
    if digests is not None:
        known = digests.get(id(a))
        if known is not None and known[0] is a:
            return known[1]
    c = np.ascontiguousarray(a)
    d = hashlib.sha256(f"{c.dtype.str}:{c.shape}\0".encode())
    d.update(c.reshape(-1).view(np.uint8).data if c.size else b"")
    if digests is not None:
        digests[id(a)] = (a, d.digest())
    return d.digest()


def _feed(h, v: Any, depth: int = 0, digests: dict | None = None) -> int | None:
    """Feed ``v``'s content into the hash ``h``; returns how many arrays and numbers it held, or None where a
    part of it cannot be told by content (no key: `cost_key`). Dr.Jit arrays are passed over: the cost inputs
    are NumPy, and a Dr.Jit array inside a sampler is its per-backend copy of a NumPy table it also holds
    (`rtfit.realtime.arrays.cached_table`), present or not depending on whether it was used yet. An object
    counts only where it holds an array or number of its own."""
    if depth > _MAX_DEPTH:
        return None
    if v is None or isinstance(v, bool | int | float | str | bytes | enum.Enum):
        h.update(f"{type(v).__name__}:{v!r}\0".encode())
        return 1
    if isinstance(v, np.ndarray | np.generic):
        a = np.asarray(v)
        if a.dtype == object:
            return None
        h.update(b"array:" + _array_digest(a, digests if a is v else None))  # (a NumPy scalar: not kept)
        return 1
    if dr.is_array_v(v):
        return 0
    if isinstance(v, Mapping):
        items: list = sorted(v.items(), key=lambda kv: repr(kv[0]))
        h.update(f"map:{len(items)}\0".encode())
    elif isinstance(v, list | tuple):
        items = list(enumerate(v))
        h.update(f"seq:{len(items)}\0".encode())
    elif dataclasses.is_dataclass(v) and not isinstance(v, type):
        # a dict declared compare=False is a cache, a memo of the values it gave (a shadow map's kept NumPy
        # runs, its per-backend tables) or words for a report, not what it is; any other field counts
        # (an environment's lat-long map is compare=False and is content)
        items = [(f.name, getattr(v, f.name)) for f in dataclasses.fields(v)
                 if f.compare or not isinstance(getattr(v, f.name), dict)]  # fmt: skip
        h.update(f"obj:{type(v).__module__}.{type(v).__qualname__}\0".encode())
    elif hasattr(v, "__dict__") and not callable(v):
        items = sorted(vars(v).items())
        h.update(f"obj:{type(v).__module__}.{type(v).__qualname__}\0".encode())
    elif callable(v) and getattr(v, "__module__", "").startswith("rtfit."):
        h.update(f"code:{v.__module__}.{getattr(v, '__qualname__', '?')}\0".encode())  # its text: the source
        return 1
    else:
        return None
    held = 0
    for k, x in items:
        h.update(f"{k!r}=".encode())
        n = _feed(h, x, depth + 1, digests)
        if n is None:
            return None
        held += n
    if isinstance(v, Mapping | list | tuple):
        return held
    return held if held else None  # (an object holding only Dr.Jit arrays: its content is not seen)


def cost_key(
    method: Method,
    inputs: Mapping[str, Any],
    backend: str,
    size: int,
    device: str,
    digests: dict[int, tuple[np.ndarray, bytes]] | None = None,
) -> str | None:
    """The store key of ``method``'s cost on ``inputs`` (the case's channel-0 inputs it reads) at ``size``
    elements on ``backend`` and ``device`` (module docstring); None where it cannot be made. ``digests``: the
    arrays' digests kept by id for the span of one case (`_array_digest`; None: each hashed anew), whose
    arrays are not written meanwhile."""
    import mitsuba

    h = hashlib.sha256()
    head = {
        "format": STORE_FORMAT,
        "source": source_digest(),
        "device": device,
        "backend": backend,
        "versions": [dr.__version__, mitsuba.__version__, np.__version__],
        "size": int(size),
        "method": method.id,
        "declared": {k: [p.initial, p.lower, p.upper] for k, p in sorted(method.params.items())},
    }
    h.update(json.dumps(head, sort_keys=True).encode())
    parts = {"fixed": dict(method.fixed), "inputs": {k: inputs[k] for k in method.input_names}}
    if _feed(h, parts, digests=digests) is None:
        return None
    return h.hexdigest()


@dataclasses.dataclass
class CostStore:
    """The kept costs under ``root`` (the run's cache directory; None: none kept), measured on ``device``
    (`runner.device_description`: the CPU's model and Dr.Jit's threads, or the GPU's name)."""

    root: Path | None
    device: str

    def key(
        self, method: Method, inputs: Mapping[str, Any], backend: str, size: int, digests: dict | None = None
    ) -> str | None:
        """`cost_key` on this store's device; None where nothing is kept (no store)."""
        return None if self.root is None else cost_key(method, inputs, backend, size, self.device, digests)

    def _path(self, key: str) -> Path:
        assert self.root is not None
        return Path(self.root) / "costs" / f"{key[:40]}.json"

    def get(self, key: str | None) -> dict | None:
        """The record kept under ``key``, or None (no key, no store, none kept, or unreadable)."""
        if key is None or self.root is None:
            return None
        try:
            doc = json.loads(self._path(key).read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(doc, dict) or doc.get("key") != key or not isinstance(doc.get("cost"), dict):
            return None
        return doc

    def put(self, key: str | None, cost: Mapping[str, Any]) -> None:
        """Keep ``cost`` under ``key`` (nothing where there is no key or no store)."""
        if key is None or self.root is None:
            return
        doc = {"key": key, "measured_at": datetime.now(UTC).isoformat(timespec="seconds"),
               "cost": dict(cost)}  # fmt: skip
        atomic_write_bytes(self._path(key), json.dumps(doc).encode())

    def cost(self, key: str | None, measure: Callable[[], dict]) -> dict:
        """The cost kept under ``key`` (its ``note`` saying when it was measured), else ``measure()``,
        then kept."""
        kept = self.get(key)
        if kept is not None:
            return {**kept["cost"], "note": f"{COST_NOTE}; measured {kept['measured_at']} by an earlier run "
                    "of the same kernel text on the same inputs and machine (kept in the cache)"}  # fmt: skip
        cost = measure()
        self.put(key, cost)
        return cost

    def precompute_key(self, cost_key: str | None, reference_key: str, what: str, trigger: str,
                       pixels: int) -> str | None:  # fmt: skip
        """The store key of a row's precompute timing (`audit_cases.CaseRun.precompute`): its method's
        `cost_key` (rtfit's source, the machine, the method, the case's inputs by content: what the bake
        produced), the case's reference cache key (the scene it bakes: its files, camera and light), what
        the precompute does and when, and the case's pixels. None where either key is missing."""
        if cost_key is None or not reference_key or self.root is None:
            return None
        head = {"format": STORE_FORMAT, "precompute": what, "trigger": trigger, "pixels": int(pixels),
                "cost_key": cost_key, "reference": reference_key}  # fmt: skip
        return hashlib.sha256(json.dumps(head, sort_keys=True).encode()).hexdigest()

    def precompute(self, key: str | None, measure: Callable[[], float | None]) -> tuple[float | None, str]:
        """(The precompute's ms kept under ``key``, else ``measure()``'s, kept where it is a number; the words
        the cost record's ``precompute_note`` adds: when a kept one was timed, else none)."""
        kept = self.get(key)
        if kept is not None and isinstance(kept["cost"].get("precompute_ms"), int | float):
            return float(kept["cost"]["precompute_ms"]), (
                f"; timed {kept['measured_at']} by an earlier run on the same inputs, scene and machine "
                "(kept in the cache)"
            )
        ms = measure()
        if ms is not None:
            self.put(key, {"precompute_ms": ms})
        return ms, ""


COST_NOTE = "per pixel: the scene's own inputs, tiled, as float32; declared parameters"
"""What an audit's cost row measured (the results' ``note``, `audit_results.results_record`)."""
