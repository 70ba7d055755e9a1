"""The experiment registry: one line per experiment (name used on the command line and in paths).

An experiment module exposes:

* ``run(ctx: RunContext) -> dict`` — runs its jobs through ``ctx.executor``, writes figures and
  fitted-parameter files under ``ctx.out_dir`` and returns the results document
  (``docs/results-schema.md``) without the common header, which the runner adds;
* ``bench(ctx: BenchContext) -> list[dict]`` — rows for ``rtfit bench``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType


@dataclass(frozen=True)
class ExperimentSpec:
    name: str
    module: str
    title: str
    description: str

    def load(self) -> ModuleType:
        return importlib.import_module(self.module)


EXPERIMENTS: dict[str, ExperimentSpec] = {
    spec.name: spec
    for spec in [
        ExperimentSpec(
            "half-lambert", "rtfit.experiments.half_lambert",
            "Half-Lambert and wrap lighting vs exact sphere-light irradiance",
            "White diffuse sphere under a spherical light of angular radius 0.27°–30°, with and without "
            "a constant sky: Lambert, half-Lambert and fitted wrap lighting against Mitsuba."),
    ]
}


class UnknownExperiment(ValueError):
    pass


def get_experiment(name: str) -> ExperimentSpec:
    try:
        return EXPERIMENTS[name]
    except KeyError:
        raise UnknownExperiment(
            f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)}; or 'all')") from None


def resolve_names(names: tuple[str, ...] | list[str]) -> list[ExperimentSpec]:
    """Expand ``all`` and validate every name before anything runs."""
    if not names:
        raise UnknownExperiment(f"name an experiment (known: {', '.join(EXPERIMENTS)}; or 'all')")
    specs: list[ExperimentSpec] = []
    for name in names:
        for spec in (list(EXPERIMENTS.values()) if name == "all" else [get_experiment(name)]):
            if spec not in specs:
                specs.append(spec)
    return specs


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

    def log(self, message: str):
        if self.progress:
            import sys

            print(f"[rtfit] {message}", file=sys.stderr, flush=True)


@dataclass
class BenchContext:
    variant: str
    size: int | None
    quick: bool
