"""The experiment registry: one line per experiment (name used on the command line and in paths).

An experiment module exposes:

* ``run(ctx: RunContext) -> dict`` — runs its jobs through ``ctx.executor``, writes figures and
  fitted-parameter files under ``ctx.out_dir`` and returns the results document
  (``docs/results-schema.md``) without the common header, which the runner adds;
* ``bench(ctx: BenchContext) -> list[dict]`` — rows for ``rtfit bench``;
* ``configure(quick: bool, spp: int | None) -> dict`` — its configuration (plain JSON data: case lists,
  resolution, spp, …). ``run`` must take its configuration as ``ctx.configured(configure(ctx.quick,
  ctx.spp))``, so that a sweep (``rtfit sweep``) can override any key per point.
"""

from __future__ import annotations

import importlib
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

log = logging.getLogger("rtfit.experiments")


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
            "diffuse",
            "rtfit.experiments.diffuse",
            "Half-Lambert and wrap lighting vs exact sphere-light irradiance",
            "White diffuse sphere under a spherical light of angular radius 0.27°–30°, with and without "
            "a constant sky: Lambert, half-Lambert and fitted wrap lighting against Mitsuba.",
        ),
        ExperimentSpec(
            "irradiance-bases",
            "rtfit.experiments.irradiance_bases",
            "Irradiance bases: ambient cube vs spherical harmonics against path-traced irradiance",
            "Valve ambient cube (axis-sampled and NNLS-optimal), SH L1/L2 and windowed SH under constant, "
            "sun, sunsky, studio, overcast and measured light probes, with per-probe storage and cost.",
        ),
        ExperimentSpec(
            "ambient-aperture",
            "rtfit.experiments.ambient_aperture",
            "Ambient aperture lighting: spherical-cap intersection, exact vs smoothstep vs fitted",
            "Solid angle of two intersecting spherical caps over the whole domain, and ambient-aperture "
            "shading of area-light occlusion against Mitsuba renders.",
        ),
        ExperimentSpec(
            "sdf-occlusion",
            "rtfit.experiments.sdf_occlusion",
            "SDF occlusion and skylight (Evans) vs path-traced ambient occlusion and sky light",
            "Multi-scale signed-distance sampling and cone-traced soft occlusion against Mitsuba AO and "
            "sky-lit irradiance, with steps-vs-error-vs-cost and fitted contrast.",
        ),
        ExperimentSpec(
            "height-fog",
            "rtfit.experiments.height_fog",
            "Exponential height fog: closed-form optical depth and fog colour vs path-traced media",
            "Closed-form, seed-listing and Taylor optical-depth forms over the whole domain, and fog "
            "shading against Mitsuba transmittance and aerial perspective, with fitted artist parameters.",
        ),
        ExperimentSpec(
            "nishita-sky",
            "rtfit.experiments.nishita_sky",
            "Nishita sky: single-scattering sky texture vs a path-traced spherical-shell atmosphere",
            "The 128×64 Nishita sky texture with per-pixel phase against single- and multiple-scattering "
            "Mitsuba references and sunsky, with layers-vs-error-vs-cost and fitted artist parameters.",
        ),
    ]
}


ALIASES: dict[str, str] = {"half-lambert": "diffuse"}
"""Former experiment names → current ones (``rtfit run half-lambert`` still runs ``diffuse``)."""


class UnknownExperiment(ValueError):
    pass


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


def apply_overrides(defaults: dict, overrides: dict, experiment: str = "") -> dict:
    """A copy of ``defaults`` with ``overrides`` applied; an unknown key, a value of another kind
    (a number for a list, a string for a number, NaN/Inf) is a one-line ``ValueError``."""
    where = f" of {experiment}" if experiment else ""
    out = dict(defaults)
    for key, value in overrides.items():
        if key not in defaults:
            raise ValueError(
                f"{key!r} is not a configuration key{where} (known: {', '.join(sorted(defaults))})"
            )
        if not _same_kind(defaults[key], value):
            raise ValueError(f"{key} = {value!r}: expected a value like {defaults[key]!r}")
        out[key] = type(defaults[key])(value) if isinstance(defaults[key], float) else value
    return out


def get_experiment(name: str) -> ExperimentSpec:
    """The experiment called ``name`` (or an `ALIASES` name of it)."""
    try:
        return EXPERIMENTS[ALIASES.get(name, name)]
    except KeyError:
        raise UnknownExperiment(
            f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)}; or 'all')"
        ) from None


def resolve_names(names: tuple[str, ...] | list[str]) -> list[ExperimentSpec]:
    """Expand ``all`` and validate every name before anything runs."""
    if not names:
        raise UnknownExperiment(f"name an experiment (known: {', '.join(EXPERIMENTS)}; or 'all')")
    specs: list[ExperimentSpec] = []
    for name in names:
        for spec in list(EXPERIMENTS.values()) if name == "all" else [get_experiment(name)]:
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
    overrides: dict = field(default_factory=dict)

    def configured(self, defaults: dict) -> dict:
        """``defaults`` (the experiment's ``configure``) with this run's sweep overrides applied."""
        return apply_overrides(defaults, self.overrides)

    def log(self, message: str):
        """An INFO line of the experiment's progress (logger ``rtfit.experiments``; the command line
        prints it on stderr unless ``-q``; as a library, configure ``logging`` to see it)."""
        log.info("%s", message)


@dataclass
class BenchContext:
    variant: str
    size: int | None
    quick: bool
