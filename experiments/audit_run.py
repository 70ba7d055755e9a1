"""`rtfit audit SCENE` and `rtfit.audit(...)`: errors, fits, costs and a report on a user's own scene.

The run (issue 15 §3), for every applicable family that is audited (`AUDITED`; `rtfit audit --list` lists
the families that apply, `rtfit.experiments.families.RULES`):

1. **Inputs checked first.** The scene is inspected (`audit.inspect_scene`: Mitsuba's own parser for XML),
   ``--approx`` resolved (families, shipped methods, user approximations by spec or entry point) and every
   user approximation validated (`user_methods.check_approximation`) — all before anything is rendered or
   written; each refusal is one `AuditError` line.
2. **References** (`AuditFamily.cases`): the scene is instantiated once in the run's Mitsuba variant
   (scoped: the caller's variant is put back), the pixel-centre G-buffer of its own camera is traced, and
   each family renders its references in independent passes through the pass cache (`PassEntry`, keyed on
   the digest of every file Mitsuba's parser loaded, the camera and the film size): resumable, and
   rendered once.
3. **Evaluation**, case by case as its references are made: every applicable method (and each user
   approximation of the family's quantity) on the same pixels with Dr.Jit (`Method.evaluate`), per RGB
   channel; the cost per pixel measured on the run's backend (`cost.time_drjit`), on cores no fit shares.
4. **Fits**, of every case together once all are evaluated: each method with free parameters fitted to this
   scene's reference by SciPy's TRF on the NumPy (or Dr.Jit) run of its kernel text (`fit_method`), with
   standard errors and bound flags; on two cores the NumPy-run fits are shared with a forked helper process
   (`rtfit.fitting.forked_fits`: the same results bit for bit). Then each case's fitted rows are evaluated,
   and every row's metrics computed beside the noise floor (`compute_metrics`), a case a task, shared the
   same way (`audit_cases.CaseRun.finish_cases`).
5. **Output** (with ``out``): ``results.json`` (schema ``rtfit.results/1``), ``report.html``/``.md``,
   ``tables.tex``, figures (images with signed error, FLIP maps) and ``fitted/audit.json``
   (``rtfit.fitted/1``), written atomically into ``OUT/audit-<scene>``.

`audit` returns an `AuditResult` with the arrays, metrics, fits, costs and timings.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import re
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import (
    ALL_METRICS,
)
from rtfit.fitting.blas_threads import one_blas_thread
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.estimators import GBuffer, gbuffer, is_pass_through
from rtfit.reference.mitsuba_xml import XMLSceneError, loaded_xml
from rtfit.reference.nishita_sky import hemisphere_directions, load_atmosphere_scene
from rtfit.reference.variants import scoped_variant
from rtfit.scenes import load_scene, scene_hash

from .audit import SURFACE_FREE_KINDS, Applicability, AuditError, SceneInfo, inspect_scene
from .audit_cases import CaseRun, EvaluatedCase, case_rows
from .audit_cost import COST_ELEMENTS
from .audit_family import AuditFamily, FamilyCase
from .audit_options import GRID_MAX, check_ao_distance, check_out, triple
from .audit_parallax_occlusion import check_pom_depth
from .audit_results import AuditResult, MethodOutcome, results_record
from .audit_selection import (
    audited_here,
    resolve_approximations,
    rule_of,
    selected_applicabilities,
    wrong_format,
)
from .cost_store import CostStore
from .families import AUDITED
from .progress import Stage
from .registry import LIMITS
from .run_settings import DEFAULT_PASS_SPP, DEFAULT_SPP, RunSettings
from .runner import device_description, use_variant_backend

__all__ = [
    "AUDITED",
    "DEFAULT_PASS_SPP",
    "DEFAULT_SPP",
    "GRID_MAX",
    "AuditResult",
    "MethodOutcome",
    "audit",
    "check_ao_distance",
    "resolve_approximations",
    "selected_applicabilities",
    "triple",
]

log = logging.getLogger("rtfit.audit")


# -------------------------------------------------------------------------------------------------- run
def _scene_name(path: str) -> str:
    stem = Path(path).stem
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", stem) or "scene"


SKY_VIEW = (64, 32)
"""Default (W, H) of an rtfit sky file's camera: the azimuth × elevation panorama of the upper hemisphere
(`rtfit.reference.nishita_sky.hemisphere_directions`: column i at azimuth 2π(i + ½)/W from the sun's, row j
at elevation 90°·(1 − (j + ½)/H)); ``--width``/``--height`` override."""


def sky_view(width: int, height: int) -> GBuffer:
    """The G-buffer of a sky file's panorama camera: every pixel a sky pixel (``mask`` False) with its view
    direction (`SKY_VIEW`)."""
    dirs, _az, _el = hemisphere_directions(width, height)
    zero = np.zeros((height, width, 3), np.float32)
    none = np.zeros((height, width), bool)
    return GBuffer(zero, zero, np.full((height, width), np.inf, np.float32), zero, none, none,
                   dirs.astype(np.float32))  # fmt: skip


@contextlib.contextmanager
def _opened(info: SceneInfo, defines, variant: str, camera: int, width, height) -> Iterator[tuple]:
    """The scene instantiated in ``variant`` (scoped: the caller's variant is put back): yields ``(mi,
    Mitsuba scene, sensor, emitters, G-buffer, source, digest)``. Mitsuba XML: `loaded_xml`. An rtfit TOML
    scene: rtfit's own Mitsuba build of its surfaces and lights (without its media, whose boundary shapes
    are not surfaces; a family renders them itself), ``source`` the `Scene` at the run's film size. An
    rtfit sky file: no Mitsuba scene (the family renders its own atmosphere), the panorama `sky_view`,
    ``source`` the `AtmosphereSpec`. ``digest`` covers the content and the film size."""
    if info.xml is not None:
        xml = info.xml
        cam = xml.camera
        digest = (
            f"{xml.dependencies.digest}:camera{camera}:{cam.width if cam else 0}x{cam.height if cam else 0}"
        )
        with loaded_xml(xml.source, defines, variant, camera=camera, width=width, height=height) as loaded:
            gb = gbuffer(loaded.mi, loaded.scene, loaded.sensor)
            yield loaded.mi, loaded.scene, loaded.sensor, loaded.emitters, gb, None, digest
        return
    if info.format == "rtfit-sky":
        spec = load_atmosphere_scene(info.source)
        w, h = int(width or SKY_VIEW[0]), int(height or SKY_VIEW[1])
        digest = hashlib.sha256(repr((sorted(asdict(spec).items()), w, h)).encode()).hexdigest()
        with scoped_variant(variant) as mi:
            yield mi, None, None, (), sky_view(w, h), spec, digest
        return
    toml = load_scene(info.source)
    if width or height:
        size = {"width": int(width or toml.camera.width), "height": int(height or toml.camera.height)}
        toml = replace(toml, camera=replace(toml.camera, **size))
    digest = f"{scene_hash(toml)}:{toml.camera.width}x{toml.camera.height}"
    with scoped_variant(variant) as mi:  # surfaces only: a medium's boundary shape is not a surface
        mi_scene = load_dict(mi, mitsuba_scene_dict(mi, replace(toml, media=())))
        sensor = mi_scene.sensors()[0]
        yield mi, mi_scene, sensor, (), gbuffer(mi, mi_scene, sensor), toml, digest


@one_blas_thread()  # (called from Python, not only through the command: see `one_blas_thread_by_default`)
def audit(
    scene_or_path,
    approximations=None,
    *,
    spp: int | None = None,
    variant: str | None = None,
    fit: bool = True,
    out=None,
    defines: Mapping[str, str] | None = None,
    camera: int = 0,
    width: int | None = None,
    height: int | None = None,
    up: str | None = None,
    seed: int = 0,
    cache=None,
    pass_spp: int | None = None,
    progress: bool = False,
    ao_distance: float | None = None,
    probe_at=None,
    grid=None,
    pom_depth: float | None = None,
    say=None,
    cost_elements: int = COST_ELEMENTS,
    metrics: Sequence[str] = ALL_METRICS,
    tag: tuple[str, str] | None = None,
    costs: dict[str, dict] | None = None,
    roles: Sequence[str] | None = None,
    quantities: Sequence[str] | None = None,
) -> AuditResult:
    """Audit the scene ``scene_or_path`` (a Mitsuba ``.xml`` or rtfit ``.toml`` path, or a Mitsuba scene
    dict as ``mi.load_dict`` takes it; a loaded ``mi.Scene`` is refused: `inspect_scene`) and return an
    `AuditResult`; with ``out`` (a directory) also write the report there. ``approximations``: see
    `resolve_approximations`. ``spp``: reference samples per pixel (default `DEFAULT_SPP`), in passes of
    ``pass_spp``; ``variant``: the Mitsuba variant (default ``llvm_ad_rgb``; the caller's own variant is put
    back afterwards); ``fit``: fit free parameters to this scene. Bad input raises `AuditError` (one line)
    before anything is rendered or written. ``say``: a function taking one progress line (default: log).
    ``cost_elements``: how many elements each method's cost is measured on (the scene's inputs, tiled);
    ``metrics``: the metric names (`rtfit.fitting.ALL_METRICS`; ꟻLIP costs ~0.4 s per call on the CPU).
    ``probe_at``: (x, y, z) where the environment-maps family captures its cube maps (default: each shape's
    centre); ``grid``: (nx, ny, nz) probes of the irradiance-volumes grid (default: by the scene's box);
    ``pom_depth``: the parallax-occlusion height range in texture units (`check_pom_depth`). ``tag``: (id
    prefix, label prefix) put before every case's id and label, where one report holds the audits of
    several scenes (``rtfit run`` of a family born on the engine, `engine_run`). ``costs``: the costs already
    measured by the audits of the same run (method id → record; filled in place): a method is timed once per
    run, not once per scene. ``roles``, ``quantities``: only the applicabilities of these roles and the cases
    of these quantities (`ShippedScene.roles`; None: all)."""
    say = say or log.info
    probe_at = triple("--probe-at", probe_at, float)
    grid = triple("--grid", grid, int)
    pom_depth = check_pom_depth(pom_depth)
    run_settings = RunSettings.checked(
        variant=variant, spp=spp, pass_spp=pass_spp, seed=seed, cache=cache, progress=progress,
        needs="the audit needs", width=width, height=height,
    )  # fmt: skip
    check_ao_distance(ao_distance)
    info = inspect_scene(scene_or_path, defines=defines, camera=camera, width=width, height=height, up=up)
    film = info.xml.camera if info.xml is not None else None
    if film is not None and width is None and height is None:
        try:
            for side in (film.width, film.height):
                LIMITS["resolution"].check(f"{info.source}: the sensor's film", side)
        except ValueError as e:
            raise AuditError(f"{e} (--width/--height render it smaller)") from None
    sel = resolve_approximations(approximations)
    found = selected_applicabilities(info, sel, ao_distance)
    audited = [a for a in found if audited_here(a, info.format) and (roles is None or a.role in roles)]
    skipped = [
        f"{a.family} ({a.role}: {a.part}): "
        + (
            "not audited in this run (not a role it asks for)"
            if audited_here(a, info.format)
            else "listed by --list, not audited yet"
            + (f" on {info.format} scenes" if wrong_format(a, info.format) else "")
        )
        for a in found
        if a not in audited
    ]
    if not audited:
        raise AuditError(
            f"the audit of {', '.join(dict.fromkeys(a.family for a in found))} is not built yet for "
            f"{info.format} scenes (audited families: "
            + ", ".join(k + " (" + "/".join(f.formats) + ")" for k, f in AUDITED.items())
            + "); rtfit audit --list shows what applies"
        )
    for a in audited:
        if not case_rows(AUDITED[a.family], a, sel):
            raise AuditError(f"{a.family}: none of the methods named in --approx applies to {a.part}")
    if info.xml is not None and info.xml.camera is None:  # refused here, before the camera line
        raise AuditError(f"{info.source}: the scene has no <sensor> (the audit renders the scene's own view)")
    target = None
    if out is not None:
        target = Path(out) / f"audit-{_scene_name(info.source)}"
        check_out(target)
    check_out(run_settings.cache_dir, "--cache")
    say(f"camera: {info.camera}; up: {info.up_reason}")  # (after every refusal: one line, then progress)
    backend = use_variant_backend(run_settings.variant)

    timings = {"reference": 0.0, "evaluation": 0.0, "fit": 0.0}
    by_family: dict[str, dict[str, float]] = {}
    outcomes: dict[str, dict[str, MethodOutcome]] = {}
    costs = {} if costs is None else costs
    plan: list[tuple[AuditFamily, Applicability, FamilyCase]] = []  # the finished cases, in order
    evaluated: list[tuple[AuditFamily, Applicability, EvaluatedCase]] = []  # every case evaluated so far
    done: list[Applicability] = []
    fits: dict[tuple[str, str], dict] = {}  # (case id, row) → its fit, once every case's fits ran
    store = CostStore(run_settings.cache_dir, device_description(run_settings.variant))
    run = CaseRun(
        sel, bool(fit), tuple(metrics), run_settings.seed, backend, cost_elements, costs, timings, by_family,
        store,
    )  # fmt: skip
    variant, spp, pass_spp = run_settings.variant, run_settings.spp, run_settings.pass_spp
    # (the fits' solver is imported when they start, beside the declared rows' metrics: `CaseRun.fit_cases`)

    def finish(part: list, share: bool = True) -> None:
        """The evaluated cases ``part`` finished (`CaseRun.finish_cases`, with the fits that ran) into the
        outcomes and the plan."""
        finished = run.finish_cases([ev for _f, _a, ev in part], fits, share)
        for (family, a, ev), rows in zip(part, finished, strict=True):
            outcomes[ev.base.id] = rows
            plan.append((family, a, ev.base))

    settings = {"variant": variant, "spp": spp, "pass_spp": pass_spp, "seed": run_settings.seed, "sel": sel}
    t0 = time.perf_counter()
    try:
        with _opened(info, defines, variant, camera, width, height) as opened:
            mi, mi_scene, sensor, emitters, gb, source, scene_digest = opened
            mask = gb.mask & ~gb.emitter
            if info.xml is not None and not mask.any():
                n = sum(is_pass_through(mi, s) for s in mi_scene.shapes())  # (seen through: issue 31)
                seen = f" (it sees through {n} medium boundaries: null or dielectric)" if n else ""
                why = f"the camera sees no surface that is not itself a light{seen}"
                # The media and sky families audit the camera's rays, not its surfaces: they still run.
                kept = [a for a in audited if rule_of(a).needs[0] in SURFACE_FREE_KINDS]
                if not kept:
                    raise AuditError(f"{info.source}: {why}")
                skipped += [
                    f"{a.family} ({a.role}: {a.part}): not audited: {why}" for a in audited if a not in kept
                ]
                audited = kept
            setup = run_settings.setup(
                mi, mi_scene, sensor, emitters, info, gb, mask, scene_digest, ao_distance=ao_distance,
                source=source, probe_at=probe_at, grid=grid, pom_depth=pom_depth,
                quantities=None if quantities is None else frozenset(quantities),
            )  # fmt: skip
            timings["reference"] += time.perf_counter() - t0
            # Family by family, each case evaluated as soon as its references are made; then the fits of
            # every case together (`CaseRun.fit_cases`: shared with a helper process on two cores); then
            # each case's fitted rows and every row's metrics (`CaseRun.finish_cases`: shared too). An
            # interrupted run reports every evaluated case (its declared rows where its fits did not run).
            parts = Stage(len(audited), "references", enabled=run_settings.progress, say=say)
            for a in audited:
                family = AUDITED[a.family]
                spent = by_family.setdefault(a.family, {"reference": 0.0, "evaluation": 0.0, "fit": 0.0})
                parts.note(f"{a.family}: references for {a.part} ({spp} spp in passes of {pass_spp})")
                tf = time.perf_counter()
                cases = [
                    c
                    for c in family.cases(setup, a)
                    if case_rows(family, a, sel, c) and setup.wants(c.quantity or family.quantity)
                ]
                if tag is not None:
                    cases = [replace(c, id=f"{tag[0]}{c.id}", label=f"{tag[1]}{c.label}") for c in cases]
                spent["reference"] += time.perf_counter() - tf
                timings["reference"] += time.perf_counter() - tf
                rows = Stage(len(cases), f"{a.family}: cases", enabled=run_settings.progress, say=say)
                for case in cases:
                    evaluated.append((family, a, run.evaluate(family, a, case)))
                    rows.advance(f"{case.id}: {evaluated[-1][2].count} rows evaluated")
                rows.close()
                parts.advance()
                done.append(a)
            parts.close()
            fits = run.fit_cases([ev for _f, _a, ev in evaluated], say)
            finish(evaluated)
    except XMLSceneError as e:
        raise AuditError(str(e)) from None
    except KeyboardInterrupt as e:
        finish(evaluated[len(plan) :], share=False)  # evaluated, not finished: fitted where the fits ran
        missing = [f"{a.family} ({a.role}: {a.part})" for a in audited if a not in done]
        result = _assemble(info, plan, outcomes, run, skipped, settings, interrupted=missing)
        if target is not None and plan:
            result.write_report(target)
            e.partial_report = target  # type: ignore[attr-defined]  (read by rtfit's entry point)
        raise
    result = _assemble(info, plan, outcomes, run, skipped, settings)
    result.gbuffer = gb
    if target is not None:
        say(f"writing the report: figures, viewer pixels and fitted parameters of {len(plan)} case(s)")
        result.write_report(target)
    return result


def _assemble(
    info: SceneInfo,
    plan: list,
    outcomes: dict[str, dict[str, MethodOutcome]],
    run: CaseRun,
    skipped: list[str],
    settings: Mapping[str, Any],
    interrupted: list[str] | None = None,
) -> AuditResult:
    """The `AuditResult` of the finished cases, with its typed ``results``; ``interrupted``: the
    applicabilities left unfinished by an interruption (named in the notes and the summary)."""
    partial = (
        None
        if interrupted is None
        else f"PARTIAL REPORT: the run was interrupted; {len(plan)} case(s) finished, not audited: "
        + (", ".join(interrupted) or "none")
        + ". Rerun the same command to complete it: every rendered pass is kept in the cache."
    )
    result = AuditResult(
        info=info,
        cases=[c for _, _, c in plan],
        outcomes={c.id: outcomes[c.id] for _, _, c in plan},
        costs=run.costs,
        timings=run.timings,
        results=None,  # type: ignore[arg-type]  (built next)
        skipped=[*skipped, *run.notes],
        by_family=run.by_family,
        partial=partial,
        failed=list(run.failed),
    )
    result.results = results_record(result, plan, **settings)
    if interrupted is not None:
        result.results = replace(result.results, summary="Partial (interrupted). " + result.results.summary)
    return result
