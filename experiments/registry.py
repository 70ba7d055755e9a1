"""What an experiment module provides, and the shared limits and configuration checks of every run.

The families themselves (name, experiment module, methods, audit declarations) are listed once, in
`rtfit.experiments.families`.

An experiment module exposes:

* ``run(ctx: RunContext) -> dict`` — runs its jobs through ``ctx.executor``, writes figures and
  fitted-parameter files under ``ctx.out_dir`` and returns the results document
  (``docs/results-schema.md``) without the common header, which the runner adds;
* ``bench(ctx: BenchContext) -> list[dict]`` — rows for ``rtfit bench``;
* ``configure(quick: bool, spp: int | None) -> dict`` — its configuration (plain JSON data: case lists,
  resolution, spp, …). ``run`` must take its configuration as ``ctx.configured(configure(ctx.quick,
  ctx.spp))``, so that a sweep (``rtfit sweep``) can override any key per point;
* ``CONFIG: dict[str, ConfigKey]`` — every key of ``configure`` declared with its type, range and meaning.
  ``configure`` returns ``checked(CONFIG, {...})``; `apply_overrides` checks each override against it,
  and `validate_config` every value (with the deeper checks, e.g. probe files) before a run or sweep
  starts; ``rtfit sweep --show-config`` prints it (`describe_config`).
"""

from __future__ import annotations

import importlib
import json
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("rtfit.experiments")


@dataclass(frozen=True)
class ExperimentSpec:
    name: str
    module: str
    title: str
    description: str

    def load(self) -> Any:
        """Its experiment: the module, or for a family born on the engine (a module with ``experiment``,
        `rtfit.experiments.engine_run`) the experiment that module makes for this family."""
        module = importlib.import_module(self.module)
        make = getattr(module, "experiment", None)
        return make(self.name) if callable(make) else module

    @property
    def config(self) -> dict[str, ConfigKey] | None:
        """Its module's ``CONFIG`` declaration (None: it declares none)."""
        return getattr(self.load(), "CONFIG", None)


ALIASES: dict[str, str] = {"half-lambert": "diffuse"}
"""Former experiment names → current ones (``rtfit run half-lambert`` still runs ``diffuse``)."""


class UnknownExperiment(ValueError):
    pass


SPP_MAX = 1 << 20
"""The most reference samples per pixel a run or sweep may ask for (``--spp``, a sweep's ``spp``, every
``*spp`` key): 2^20 = 1,048,576, 32× the largest default (a 128² image at that rate is ~17 G samples,
hours on a GPU). Above it is a one-line error before anything runs."""

RESOLUTION_MAX = 4096
"""The largest image side in pixels a run, sweep or audit renders (an experiment's ``resolution`` keys, the
audit's ``--width``/``--height`` and an audited scene's own film): 4096² = 16.8 M pixels, a G-buffer of
~1 GB in Dr.Jit; a 100000² film overflows Dr.Jit's 2^32 variable counter (issue 32)."""
PASSES_MAX = 65536
"""The most cached passes one reference may be split into (spp / pass-spp): each pass is a render, a
cache file and its JSON; 2^16 of them is days of work, and 2^24 spp in passes of 2 (8 M passes) a hang."""
SWEEP_POINTS_MAX = 10_000
"""The most points one sweep may hold (its grid's product plus its listed points), counted before the grid
is expanded: a 10^6-point grid otherwise spends minutes expanding before it prints anything."""
BENCH_SIZE_MAX = 1 << 28
"""The most elements per kernel launch of ``rtfit bench --size``: 2^28 float32 inputs are 1 GiB each;
``--size 1099511627776`` asked for an 8 TiB allocation."""


@dataclass(frozen=True)
class Limit:
    """One entry of `LIMITS`: the closed range of an integer option and what it counts."""

    lo: int
    hi: int
    what: str

    def check(self, option: str, value: int) -> None:
        """A one-line ``ValueError`` when ``value`` is outside [lo, hi]."""
        if isinstance(value, bool) or not isinstance(value, int) or not self.lo <= value <= self.hi:
            raise ValueError(
                f"{option} {value!r}: {self.what} must be in [{self.lo}, {self.hi}] (registry.LIMITS)"
            )


LIMITS: dict[str, Limit] = {
    "spp": Limit(2, SPP_MAX, "samples per pixel"),
    "resolution": Limit(1, RESOLUTION_MAX, "an image side in pixels"),
    "passes": Limit(1, PASSES_MAX, "the number of cached passes (spp / pass-spp, rounded up)"),
    "sweep_points": Limit(1, SWEEP_POINTS_MAX, "the number of sweep points"),
    "bench_size": Limit(1024, BENCH_SIZE_MAX, "the elements per kernel launch"),
}
"""The one table of size limits shared by ``run``, ``audit``, ``sweep`` and ``bench`` (issue 32): each
command's options take their ranges from here; a value outside is a one-line error before anything runs."""

TYPES = ("int", "float", "bool", "str", "table")


@dataclass(frozen=True)
class ConfigKey:
    """One configuration key of an experiment, declared beside its ``configure``: its type, range and
    meaning. ``rtfit sweep --show-config`` prints it, and every value (the defaults and each override)
    is checked against it before anything runs (`check_value`).

    ``type``: ``int`` (a bool or a float such as 64.5 is refused), ``float`` (an int is taken as a float;
    NaN and ±Inf are refused), ``bool``, ``str``, ``table`` (a dict with exactly the default's keys, each of
    the default's kind). ``shape``: ``()`` a single value; ``(None,)`` a non-empty list of them; ``(2,)`` a
    list of exactly 2; ``(None, 2)`` a non-empty list of pairs. ``lo``/``hi``: inclusive bounds of each
    number. ``choices``: the allowed values of each element. ``optional``: ``None`` is allowed (its meaning
    in ``doc``). ``check``: a deeper test of each element (e.g. that a probe file reads), returning a
    problem or None; run by `validate_config` (before a run), not by ``configure``."""

    type: str
    doc: str = ""
    lo: float | None = None
    hi: float | None = None
    shape: tuple = ()
    choices: tuple | None = None
    optional: bool = False
    check: Callable[[Any], str | None] | None = None

    def describe(self) -> str:
        """``int in [2, 1048576]``, ``list of float in [0, 90]``, ``one of a, b``, … (for --show-config)."""
        base = self.type
        if self.choices is not None:
            base = f"{base}, one of {', '.join(map(str, self.choices))}"
        elif self.lo is not None or self.hi is not None:
            base = f"{base} in {_interval(self)}"
        for n in reversed(self.shape):
            base = f"list of {base}" if n is None else f"[{n} × {base}]"
        return base + (", or none" if self.optional else "")


def _interval(decl: ConfigKey) -> str:
    def num(x, inf):
        return inf if x is None else str(int(x)) if float(x).is_integer() else f"{x:g}"

    return f"[{num(decl.lo, '-inf')}, {num(decl.hi, 'inf')}]"


def _problem(decl: ConfigKey, value, shape: tuple, default) -> str | None:
    """What is wrong with ``value`` (None: nothing)."""
    if shape:
        n, rest = shape[0], shape[1:]
        if not isinstance(value, (list, tuple)):
            return f"expected a list (of {n or 'one or more'} values)"
        if (n is None and not value) or (n is not None and len(value) != n):
            return f"expected a list of {n or 'one or more'} values (got {len(value)})"
        for x in value:
            p = _problem(decl, x, rest, default)
            if p:
                return f"{_brief(x)}: {p}"
        return None
    if decl.type == "bool":
        return None if isinstance(value, bool) else "expected true or false"
    if decl.type == "str":
        if not isinstance(value, str):
            return "expected a string"
    elif decl.type == "table":
        if not isinstance(value, dict) or not isinstance(default, dict) or set(value) != set(default):
            keys = ", ".join(sorted(default)) if isinstance(default, dict) else ""
            return f"expected a table with keys {keys}"
        for k, v in value.items():
            d = default[k]
            if isinstance(d, bool) or isinstance(v, bool):
                ok = isinstance(d, bool) and isinstance(v, bool)
            elif isinstance(d, int):
                ok = isinstance(v, int) and v > 0
            elif isinstance(d, float):
                ok = isinstance(v, (int, float)) and math.isfinite(v)
            else:
                ok = type(v) is type(d)
            if not ok:
                return f"{k} = {v!r}: expected a value like {d!r}"
        return None
    elif isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"expected {'an integer' if decl.type == 'int' else 'a number'}"
    elif decl.type == "int" and not isinstance(value, int):
        return "expected an integer"
    elif not math.isfinite(value):
        return "expected a finite number"
    if decl.choices is not None and value not in decl.choices:
        return f"expected one of {', '.join(map(str, decl.choices))}"
    if decl.type in ("int", "float"):
        if (decl.lo is not None and value < decl.lo) or (decl.hi is not None and value > decl.hi):
            return f"out of range {_interval(decl)}"
    return None


def _deep_problem(decl: ConfigKey, value, shape: tuple) -> str | None:
    if decl.check is None or value is None:
        return None
    if shape:
        for x in value:
            p = _deep_problem(decl, x, shape[1:])
            if p:
                return f"{_brief(x)}: {p}"
        return None
    return decl.check(value)


def _normalised(decl: ConfigKey, value, shape: tuple):
    """Ints of a float key as floats (``alphas_deg = [1, 5]`` → [1.0, 5.0]); lists stay lists."""
    if value is None:
        return None
    if shape:
        return [_normalised(decl, x, shape[1:]) for x in value]
    return float(value) if decl.type == "float" else value


def check_value(key: str, decl: ConfigKey, value, default=None, deep: bool = False):
    """``value`` of ``key`` normalised (`_normalised`), or a one-line ``ValueError`` naming the key, the
    value and the declared type and range. ``deep``: also run the declaration's ``check``."""
    problem = None if (value is None and decl.optional) else _problem(decl, value, decl.shape, default)
    if problem is None and deep:
        problem = _deep_problem(decl, value, decl.shape)
    if problem:
        raise ValueError(f"{key} = {_brief(value)}: {problem} ({key}: {decl.describe()})")
    return _normalised(decl, value, decl.shape)


def _brief(value) -> str:
    text = json.dumps(value) if not isinstance(value, float) or math.isfinite(value) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def checked(declared: dict[str, ConfigKey], config: dict) -> dict:
    """``config`` (an experiment's ``configure`` result) checked against its declaration: the same keys,
    each value of its declared type and range (a ``ValueError`` otherwise: a default outside its own
    declaration, or an out-of-range ``spp``). Returns ``config``."""
    if set(declared) != set(config):
        raise ValueError(
            f"configuration keys {sorted(set(config) ^ set(declared))} are declared but not configured, "
            "or configured but not declared"
        )
    for key, value in config.items():
        check_value(key, declared[key], value, value)
    return config


def _same_kind(default, value) -> bool:
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, (int, float)):
        return isinstance(value, (int, float)) and (isinstance(value, int) or math.isfinite(value))
    if isinstance(default, (list, tuple)):
        return isinstance(value, (list, tuple)) and all(
            not isinstance(v, float) or math.isfinite(v) for v in value
        )
    return type(default) is type(value) or default is None


def apply_overrides(
    defaults: dict,
    overrides: dict,
    experiment: str = "",
    deep: bool = False,
    declared: Mapping[str, ConfigKey] | None = None,
) -> dict:
    """A copy of ``defaults`` with ``overrides`` applied; an unknown key, or a value outside the key's
    declaration (`ConfigKey`: ``resolution = 64.5``, a negative radiance, an unknown environment) is a
    one-line ``ValueError``. With ``declared`` (the experiment module's ``CONFIG``; ``experiment``: its name
    for the messages) every override is checked against its declaration (``deep``: also every value's
    deeper ``check``, defaults included, as `families.validate_config` does); without one, a value must
    only be of the default's kind (a number for a number, …)."""
    where = f" of {experiment}" if experiment else ""
    out = dict(defaults)
    for key, value in overrides.items():
        if key not in defaults:
            raise ValueError(
                f"{key!r} is not a configuration key{where} (known: {', '.join(sorted(defaults))})"
            )
        if declared is not None and key in declared:
            out[key] = check_value(key, declared[key], value, defaults[key])
            continue
        if not _same_kind(defaults[key], value):
            raise ValueError(f"{key} = {value!r}: expected a value like {defaults[key]!r}")
        out[key] = type(defaults[key])(value) if isinstance(defaults[key], float) else value
    if deep and declared is not None:
        for key, value in out.items():
            if key in declared:
                check_value(key, declared[key], value, defaults[key], deep=True)
    return out


@dataclass
class RunContext:
    """Everything an experiment's ``run`` needs; plain attributes, set by the runner."""

    out_dir: Path
    cache_dir: Path
    executor: object
    quick: bool
    variant: str
    spp: int | None
    seed: int
    progress: bool
    overrides: dict = field(default_factory=dict)
    experiment: str = ""  # the running experiment's name (set by the runner)
    config: Mapping[str, ConfigKey] | None = None  # its module's CONFIG (set by the runner): checks overrides

    def configured(self, defaults: dict) -> dict:
        """``defaults`` (the experiment's ``configure``) with this run's sweep overrides applied."""
        return apply_overrides(defaults, self.overrides, self.experiment, declared=self.config)

    def log(self, message: str):
        """An INFO line of the experiment's progress (logger ``rtfit.experiments``; the command line
        prints it on stderr unless ``-q``; as a library, configure ``logging`` to see it)."""
        log.info("%s", message)


@dataclass
class BenchContext:
    variant: str
    size: int | None
    quick: bool
