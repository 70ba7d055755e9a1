"""``rtfit run FAMILY`` for a family born on the engine (issue 30 §1): the audit engine on its shipped scenes.

A family declared in the registry with ``module = ENGINE`` (`rtfit.experiments.families`) has no experiment
module of its own. Its run is the same engine that audits a user's scene (`audit_run.audit`), run on each of
the family's shipped scenes (`shipped.ShippedScene`, files of ``scenes/library/``) for that family alone,
then its own study if it declares one (`shipped.Study`):

1. **Each shipped scene audited** at its own size and samples (``--quick``: its quick size and samples;
   ``resolution``/``spp`` override both), through the pass cache of the run: references with their noise,
   every method evaluated, its cost measured, its free parameters fitted through the one kernel text, metrics
   beside the noise floor and the engine's z-checks of the exact rows. Case ids carry the scene
   (``<scene stem>-<case id>``), and so do case labels where the family ships several scenes.
2. **One report** of every scene: the cases, fits, costs (each method timed once, on the inputs of the first
   scene that has it), checks (each named with its scene), figures (reference, rows, signed
   error, ꟻLIP per case), the viewer's pixels and ``fitted/<family>.json`` with every fitted row of every
   scene — the results schema, report and viewer of every run — and, for each method fitted on two or more
   cases, its **pooled fit**: one value for every scene (`engine_pooled`).
3. **The study** (`Family.study`): a leaf module's function given the audits (`shipped.StudyContext`)
   adds its own sections, figures, checks, notes and headline numbers; a failed check fails the run like the
   engine's.

`experiment(name)` is what `registry.ExperimentSpec.load` returns for such a family: an object with the
``configure``, ``CONFIG``, ``run`` and ``bench`` of an experiment module (`registry`). ``rtfit bench FAMILY``
times every method of the family on inputs drawn over their declared domains (`bench`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.realtime.arrays import backend_float, to_drjit
from rtfit.scenes.parse import LIBRARY_DIR

from .audit_output import case_figures, fitted_entries, save_pixels, write_fitted_file
from .audit_run import audit
from .cost import bench_backend, method_bench_rows
from .engine_pooled import pooled_fits
from .families import FAMILIES, Family
from .progress import Stage
from .records import to_json
from .registry import SPP_MAX, ConfigKey, RunContext, checked
from .shipped import StudyContext

__all__ = ["EngineExperiment", "experiment"]

log = logging.getLogger("rtfit.experiments")


@dataclass(frozen=True)
class EngineExperiment:
    """The experiment of one family born on the engine (module docstring)."""

    family: Family

    @property
    def CONFIG(self) -> dict[str, ConfigKey]:
        names = tuple(s.name for s in self.family.scenes)
        return {
            "scenes": ConfigKey("str", "the shipped scenes audited (their names)",
                                shape=(None,), choices=names),
            "spp": ConfigKey("int", "reference samples per pixel (none: each scene's own)", lo=2, hi=SPP_MAX,
                             optional=True),
            "resolution": ConfigKey("int", "image width in pixels, the height by the scene's aspect (none: "
                                    "each scene's own size)", lo=4, hi=4096, optional=True),
            "fit": ConfigKey("bool", "fit every method's free parameters to each scene"),
        }  # fmt: skip

    def configure(self, quick: bool, spp: int | None) -> dict:
        return checked(
            self.CONFIG,
            {
                "scenes": [s.name for s in self.family.scenes if s.quick or not quick],
                "spp": spp,
                "resolution": None,
                "fit": True,
            },
        )

    # ------------------------------------------------------------------------------------------------ run
    def run(self, ctx: RunContext) -> dict:
        cfg = ctx.configured(self.configure(ctx.quick, ctx.spp))
        shipped = {s.name: s for s in self.family.scenes}
        audits, tags = [], []
        costs: dict[str, dict] = {}  # each method timed once, on the first scene that has it
        _check_selections(self.family, [shipped[name] for name in cfg["scenes"]])
        t0 = time.perf_counter()
        scenes = Stage(len(cfg["scenes"]), f"{self.family.name}: scenes", enabled=ctx.progress, say=ctx.log)
        for name in cfg["scenes"]:
            scene = shipped[name]
            roles, quantities = scene.audited(ctx.quick)
            width, height = scene.quick_size if ctx.quick else scene.size
            if cfg["resolution"] is not None:
                width, height = cfg["resolution"], max(1, round(cfg["resolution"] * height / width))
            spp = cfg["spp"] or (scene.quick_spp if ctx.quick else scene.spp)
            scenes.note(f"{self.family.name}: auditing {scene.name} ({width}×{height}, {spp} spp)")
            # Case ids carry the scene's file stem; labels too where the family ships several scenes.
            several = len(cfg["scenes"]) > 1
            tag = (f"{scene.name}-", f"{scene.name}: " if several else "")
            audits.append(
                audit(
                    LIBRARY_DIR / scene.file,
                    [self.family.name],
                    spp=spp,
                    variant=ctx.variant,
                    fit=cfg["fit"],
                    width=width,
                    height=height,
                    seed=ctx.seed,
                    cache=ctx.cache_dir,
                    progress=ctx.progress,
                    say=ctx.log,
                    tag=tag,
                    costs=costs,
                    defines=dict(scene.defines) or None,
                    roles=roles,
                    quantities=quantities,
                    **dict(scene.options),
                )
            )
            tags.append((scene, tag))
            scenes.advance()
        scenes.close()
        engine_seconds = time.perf_counter() - t0
        ctx.log(f"{self.family.name}: figures, viewer pixels and pooled fits of {len(audits)} scene(s)")
        body = self._merged(ctx, audits, tags, cfg)
        body["config"]["extra"]["engine_seconds"] = round(engine_seconds, 3)
        if self.family.study is not None:
            ctx.log(f"{self.family.name}: study")
            study = self.family.study(
                StudyContext(ctx.out_dir, ctx.quick, ctx.variant, ctx.seed, ctx.cache_dir, tuple(audits))
            )
            for key in ("sections", "figures", "checks", "fits", "notes", "headline"):
                body[key] += [to_json(x) if not isinstance(x, str) else x for x in getattr(study, key)]
            body["extra"] = {**body.get("extra", {}), **dict(study.extra)}
        return body

    def _merged(self, ctx: RunContext, audits: list, tags: list, cfg: Mapping) -> dict:
        """One results body (`registry`: without the runner's header) from the audits of every scene, their
        figures, viewer pixels and fitted parameters written under ``ctx.out_dir``."""
        out = Path(ctx.out_dir)
        cases, fits, checks, notes, figs, costs, sections, summary = [], [], [], [], [], {}, [], []
        entries = []
        scene_lines = []
        for r, (scene, _tag) in zip(audits, tags, strict=True):
            doc: Any = to_json(r.results)
            cases += doc["cases"]
            fits += [{**f, "file": f"fitted/{self.family.name}.json"} for f in doc["fits"]]
            checks += doc["checks"]  # (each names its case, whose label names the scene)
            notes += [f"{scene.name}: {n}" if len(audits) > 1 else n for n in doc["notes"]]
            for c in doc["costs"]:
                costs.setdefault(c["method"], {**c, "note": f"{c.get('note') or ''} ({scene.name})".strip()})
            for f in case_figures(out, r):
                f.pop("_case", None)
                figs.append(f)
            save_pixels(out, r)
            entries += fitted_entries(r)
            summary.append(doc["summary"])
            spp = max((c.reference.spp for c in r.cases), default=0)
            defines = "".join(f" -D {k}={v}" for k, v in scene.defines.items())
            scene_lines.append(f"- `{scene.file}{defines}` — {scene.label} ({len(r.cases)} cases, {spp} spp)")
            if not sections:
                sections = [s for s in doc["sections"] if s["id"] != "scene"]
        pooled = pooled_fits(self.family.name, audits)
        fits += pooled.fits
        entries += pooled.entries
        notes += pooled.notes
        if entries:
            write_fitted_file(
                out / "fitted" / f"{self.family.name}.json",
                f"{self.family.name}: parameters fitted to its shipped scenes by the audit engine",
                self.family.name,
                entries,
                audits,
                ctx.variant,
                quick=ctx.quick,
            )
        intro = {
            "id": "scenes",
            "title": "Shipped scenes",
            "text": f"`rtfit run {self.family.name}` is the audit engine (`rtfit audit`) on the family's own "
            "scenes, each audited for this family alone:\n\n" + "\n".join(scene_lines),
            "placement": "before_results",
        }
        return {
            "summary": " ".join(summary),
            "config": {
                "spp": cfg["spp"],
                "extra": {"scenes": list(cfg["scenes"]), "resolution": cfg["resolution"], "fit": cfg["fit"]},
            },
            "sections": [intro, *sections, *([pooled.section] if pooled.section else [])],
            "cases": cases,
            "fits": fits,
            "figures": figs,
            "costs": list(costs.values()),
            "checks": checks,
            "notes": notes,
            "headline": [],
        }

    # ---------------------------------------------------------------------------------------------- bench
    def bench(self, ctx) -> list[dict]:
        """Every method with only declared-domain inputs (`method_bench`), then the family's own rows
        (`Family.bench`: its reference estimators, a texture's build)."""
        own = self.family.bench(ctx) if self.family.bench is not None else []
        return [*self.method_bench(ctx), *own]

    def method_bench(self, ctx) -> list[dict]:
        """Every method with only declared-domain inputs (a table or sampler input is left out): Dr.Jit vs
        NumPy of the same kernel text on ``size`` elements drawn uniformly over each input's domain (a
        fixed seed), at its declared parameters, against the memory floor of its inputs."""
        backend, n = bench_backend(ctx)
        Float = backend_float(backend)
        rng = np.random.default_rng(1)
        methods = {
            k: m
            for k, m in (self.family.methods or {}).items()
            if all(i.domain is not None for i in m.inputs) and not m.fixed
        }
        left = sorted(set(self.family.methods or {}) - set(methods))
        if left:
            log.info(
                "bench %s: %s not timed here (an input without a declared domain: a table, K rays, a "
                "sampler; or fixed values): their cost per pixel on a scene's own inputs is in the report of "
                "rtfit run %s",
                self.family.name,
                ", ".join(left),
                self.family.name,
            )
        if not methods:  # every method reads a table (the SH coefficients of a sky): timed by the audit only
            return []
        names = dict.fromkeys(i.name for m in methods.values() for i in m.inputs)
        domain = {i.name: i.domain for m in methods.values() for i in m.inputs}
        np_inputs: dict[str, Any] = {}
        for name in names:
            lo, hi = domain[name]  # type: ignore[misc]
            np_inputs[name] = rng.uniform(lo, hi, n).astype(np.float32)
        inputs = {k: to_drjit(Float, v) for k, v in np_inputs.items()}
        base = f"memory baseline (fma of the {len(inputs)} inputs)"
        return method_bench_rows(methods, backend, inputs, np_inputs, n, baseline=base)


def _check_selections(family: Family, scenes) -> None:
    """Every role and quantity a shipped scene names is one of the family's (`ShippedScene.roles`), checked
    before anything is rendered."""
    roles = {r for a in family.audits for r in (a.roles or ())}
    quantities = {q for a in family.audits for q in (a.quantity, *a.quantities)}
    for scene in scenes:
        for quick in (False, True):
            named_roles, named_quantities = scene.audited(quick)
            for kind, named, known in (
                ("role", named_roles, roles),
                ("quantity", named_quantities, quantities),
            ):
                stray = sorted(set(named or ()) - known)
                if stray:
                    raise ValueError(
                        f"{family.name}: shipped scene {scene.name} names the {kind} {', '.join(stray)}, "
                        f"not one of the family's ({', '.join(sorted(known))})"
                    )


def experiment(name: str) -> EngineExperiment:
    """The experiment of the family ``name`` (a family of the registry run by the engine)."""
    return EngineExperiment(FAMILIES[name])
