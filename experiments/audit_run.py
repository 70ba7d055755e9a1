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
   and every row's metrics computed beside the noise floor (`compute_metrics`).
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
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import (
    ALL_METRICS,
    compute_metrics,
    prime_flip,
)
from rtfit.fitting.blas_threads import one_blas_thread
from rtfit.fitting.forked_fits import shared_map, shares
from rtfit.fitting.metric_noise import content_digest
from rtfit.realtime.methods import Method
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.estimators import GBuffer, gbuffer, is_pass_through
from rtfit.reference.mitsuba_xml import XMLSceneError, loaded_xml
from rtfit.reference.nishita_sky import hemisphere_directions, load_atmosphere_scene
from rtfit.reference.variants import scoped_variant
from rtfit.scenes import load_scene, scene_hash

from .audit import SURFACE_FREE_KINDS, Applicability, AuditError, SceneInfo, inspect_scene
from .audit_cost import COST_ELEMENTS, CostInputs, method_cost
from .audit_family import PRECOMPUTE_TRIGGERS, AuditFamily, FamilyCase, Precompute
from .audit_fit import evaluate_case, fit_case
from .audit_options import GRID_MAX, check_ao_distance, check_out, triple
from .audit_parallax_occlusion import check_pom_depth
from .audit_results import AuditResult, MethodOutcome, results_record
from .audit_selection import (
    Selection,
    audited_here,
    resolve_approximations,
    rule_of,
    selected_applicabilities,
    wrong_format,
)
from .cost import time_precompute
from .cost_store import CostStore
from .families import AUDITED, METHOD_TABLES
from .progress import Stage
from .records import Check, to_json
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


def _rows(
    family: AuditFamily, app: Applicability, sel: Selection, case: FamilyCase | None = None
) -> list[tuple[str, Method, bool]]:
    """(row id, method, user?) of one applicability (or of one of its cases, which may carry rows and a
    quantity of its own: `FamilyCase.methods`): its applicable shipped methods (restricted by ``--approx``
    method names) and the user approximations of the quantity (each as the case reads it:
    `FamilyCase.user_rows`)."""
    keep = sel.methods.get(family.name)
    table = METHOD_TABLES[family.name] if case is None or case.methods is None else case.methods
    rows = [
        (r, m, False)
        for r, m in table.items()
        if m.id in app.methods and (keep is None or m.id in keep or r in keep)
    ]
    quantities = {family.quantity, *family.quantities} if case is None else {case.quantity or family.quantity}
    adapt = (lambda m: m) if case is None or case.user_rows is None else case.user_rows
    rows += [(m.id, adapt(m), True) for m in sel.user if m.quantity in quantities]
    return rows


def _given(case: FamilyCase, row: str, method: Method) -> dict[str, float]:
    """The parameter values row ``row`` is evaluated with: the case's (`FamilyCase.params`) over the
    method's declared defaults."""
    own = case.params.get(row, {})
    return {**method.defaults(), **{k: p.initial for k, p in own.items() if k in method.params}}


def _bad_values(method: Method, img: np.ndarray, case: FamilyCase) -> str | None:
    bad = ~np.isfinite(img[case.mask])
    if not bad.any():
        return None
    k = int(np.argmax(bad.any(axis=1)))
    inputs = {n: (np.asarray(v)[k] if np.ndim(v) else v) for n, v in case.channel_inputs[0].items()}
    at = ", ".join(f"{n}={float(v):.6g}" for n, v in inputs.items() if n in method.input_names)
    return f"{method.id}: returned a non-finite value on {case.label} at {at}"


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
        if not _rows(AUDITED[a.family], a, sel):
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
    evaluated: list[tuple[AuditFamily, Applicability, _EvaluatedCase]] = []  # every case evaluated so far
    done: list[Applicability] = []
    store = CostStore(run_settings.cache_dir, device_description(run_settings.variant))
    run = _CaseRun(
        sel, bool(fit), tuple(metrics), run_settings.seed, backend, cost_elements, costs, timings, by_family,
        store,
    )  # fmt: skip
    variant, spp, pass_spp = run_settings.variant, run_settings.spp, run_settings.pass_spp
    if fit:  # the fits' solver, imported first and counted as theirs (a probe grid's NNLS bake shares it)
        t = time.perf_counter()
        import scipy.optimize  # noqa: F401

        timings["fit"] += time.perf_counter() - t
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
            # every case together (`_CaseRun.fit_cases`: shared with a helper process on two cores); then
            # each case's fitted rows and metrics. An interrupted run reports every evaluated case (its
            # declared rows where its fits did not run). (A bar on a terminal.)
            parts = Stage(len(audited), "references", enabled=run_settings.progress, say=say)
            for a in audited:
                family = AUDITED[a.family]
                spent = by_family.setdefault(a.family, {"reference": 0.0, "evaluation": 0.0, "fit": 0.0})
                parts.note(f"{a.family}: references for {a.part} ({spp} spp in passes of {pass_spp})")
                tf = time.perf_counter()
                cases = [
                    c
                    for c in family.cases(setup, a)
                    if _rows(family, a, sel, c) and setup.wants(c.quantity or family.quantity)
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
            for family, a, ev in evaluated:
                outcomes[ev.base.id] = run.finish(ev, fits)
                plan.append((family, a, ev.base))
    except XMLSceneError as e:
        raise AuditError(str(e)) from None
    except KeyboardInterrupt as e:
        for family, a, ev in evaluated[len(plan) :]:  # evaluated, not fitted: their declared rows
            outcomes[ev.base.id] = run.finish(ev, {})
            plan.append((family, a, ev.base))
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
    run: _CaseRun,
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


@dataclass(frozen=True)
class _EvaluatedCase:
    """One case between its evaluation and its fits (`_CaseRun.evaluate`): the declared rows' outcomes
    (their metrics still to come) and the rows to fit, each with the case as that row reads it."""

    family: str
    base: FamilyCase
    sigma: np.ndarray
    order: list[tuple[str, Method, bool]]
    declared: dict[str, MethodOutcome]
    fitted: list[tuple[str, Method, bool, FamilyCase]]

    @property
    def count(self) -> int:
        """The case's rows: those evaluated, and those to fit."""
        return len(self.declared) + len(self.fitted)


def _shareable(method: Method, user: bool) -> bool:
    """Whether the forked helper may fit ``method`` (`shared_map`): a fit on NumPy of a shipped method. A fit
    on Dr.Jit needs the thread pool that a fork does not copy; a user's approximation is fitted here, where
    its code runs as in a serial run."""
    return method.fit_ops == "numpy" and not user


@contextlib.contextmanager
def _drjit_threads_beside_a_helper(sharing: bool) -> Iterator[None]:
    """Dr.Jit's thread pool one thread smaller while the fit helper runs (`_CaseRun.fit_cases`), put back
    after: a Dr.Jit fit's kernels split over every core wait for the worker that the helper's process holds
    off its core. Issue 33 (session 29): the Cornell box's ten shadow-map fits (64²) took 1.7–2.2 s beside
    the helper with two Dr.Jit threads, against 0.9–1.0 s alone."""
    if not sharing:
        yield
        return
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(max(1, threads - 1))
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def _fit_task(task: tuple[str, str, Method, FamilyCase]) -> dict:
    """`fit_case` of one (case id, row, method, case) of `_CaseRun.fit_cases`: what `shared_map` runs, in
    either process."""
    _case_id, row_id, method, case = task
    return fit_case(method, case, row_id)


@dataclass
class _CaseRun:
    """Evaluates and measures the rows of one case after another (`evaluate`), fits those of every case
    together (`fit_cases`) and finishes each case (`finish`: fitted rows, metrics), adding to the run's
    ``costs`` (one per method), ``timings`` and ``by_family`` seconds."""

    sel: Selection
    fit: bool
    metrics: tuple[str, ...]
    seed: int
    backend: str
    cost_elements: int
    costs: dict[str, dict]
    timings: dict[str, float]
    by_family: dict[str, dict[str, float]]
    store: CostStore
    """The costs kept across runs (`cost_store`): a method timed by an earlier run on the same inputs and
    machine is not timed again."""
    notes: list[str] = field(default_factory=list)
    failed: list[dict] = field(default_factory=list)
    """Checks of this audit that failed while it ran (a precompute that raised: `precompute`)."""
    timed: dict[Precompute, dict] = field(default_factory=dict)
    """Each precompute timed so far (its cost columns): rows sharing one are timed once."""

    def precompute(self, method: Method, case: FamilyCase, pre: Precompute) -> None:
        """Time the row's precompute (`cost.time_precompute`) into its method's cost record:
        ``precompute_ms``, its ``precompute_trigger``, the case's ``precompute_pixels`` and
        ``precompute_note``. One that raises leaves ``precompute_ms`` None and becomes a failed check (one
        line: the exception's type and first line), not a crash of the run. Rows sharing one `Precompute`
        get one timing."""
        if pre in self.timed:  # rows sharing one step (the three photon forms at one N): timed once
            self.costs[method.id].update(self.timed[pre])
            return
        pixels = int(case.mask.sum())
        record = {"precompute_trigger": pre.trigger, "precompute_pixels": pixels,
                  "precompute_note": f"{pre.what} ({PRECOMPUTE_TRIGGERS[pre.trigger]})"}  # fmt: skip
        try:
            t = time_precompute(pre.run)
            record["precompute_ms"] = t.seconds * 1e3
        except Exception as e:  # the family's own code: a failure is the run's finding, not its crash
            line = (str(e).strip().splitlines() or [""])[0]
            record["precompute_ms"] = None
            self.failed.append(
                to_json(
                    Check(
                        name=f"{method.id} ({case.label}): its precompute ({pre.what}) runs",
                        value=f"{type(e).__name__}: {line}"[:300],
                        expected="no error",
                        passed=False,
                    )
                )  # type: ignore[arg-type]
            )
        self.timed[pre] = record
        self.costs[method.id].update(record)

    def metrics_of(self, img: np.ndarray, case: FamilyCase, sigma: np.ndarray, row: str, key: tuple):
        """The row's metrics beside the noise floor (``key``: the `content_digest` of the case's reference
        mean, ``sigma`` and mask, made once for its rows). A metric's warning about the row's values (ꟻLIP
        clips an approximation's negative radiance to 0: an SH L2 ring below zero) is the row's property, not
        a fault of the run: it becomes a note of the report naming the row and the case."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            m = compute_metrics(
                img, case.reference.mean, sigma, case.mask, names=self.metrics, seed=self.seed,
                reference_key=key,
            )  # fmt: skip
        for w in caught:
            note = f"{row} ({case.label}): {str(w.message).splitlines()[0]}"
            if note not in self.notes:
                self.notes.append(note)
        return m

    def evaluate(self, family: AuditFamily, a: Applicability, base: FamilyCase) -> _EvaluatedCase:
        """Every row of ``base`` (`_rows`) evaluated and its cost measured once per method (on quiet cores:
        no fit runs yet); the rows with free parameters listed for `fit_cases`. The case's tiled cost inputs
        (`CostInputs`, shared by its methods) are let go at its end."""
        declared: dict[str, MethodOutcome] = {}
        sigma = base.reference.sigma()
        spent = self.by_family[family.name]
        tiles = CostInputs()  # the case's inputs tiled once for all its methods' cost measurements
        fitted: list[tuple[str, Method, bool, FamilyCase]] = []
        order = _rows(family, a, self.sel, base)
        for row_id, method, user in order:
            case = (
                replace(base, channel_inputs=base.row_inputs[row_id]) if row_id in base.row_inputs else base
            )
            t1 = time.perf_counter()
            given = _given(case, row_id, method)
            # A parameter the source gives no value for, and the case does not set, makes the declared row no
            # result of the method (the Evans k at its fit start read AO of 1e3…1e15 on real scenes): only
            # its fitted row is shown, and with --no-fit the row is left out, saying why.
            own = case.params.get(row_id, {})
            unset = [k for k in method.unpublished if k not in own or not own[k].published]
            if unset and not self.fit:
                self.notes.append(
                    f"{row_id} ({case.label}): left out with --no-fit: its source gives no value for "
                    f"{', '.join(unset)}, which only a fit to the scene sets"
                )
                continue
            if not unset:
                img = evaluate_case(method, case, given)
                bad = _bad_values(method, img, case)
                if bad:
                    raise AuditError(bad)
                declared[row_id] = MethodOutcome(
                    case.id, row_id, method, method.label, img, None, given, user=user
                )
            if method.id not in self.costs and row_id in case.uncosted:
                self.costs[method.id] = {
                    "label": method.label, "ns_per_pixel": None, "pixels_per_second": None,
                    "backend": self.backend, "elements": None, "repeats": None,
                    "note": f"cost not measured like the others: {case.uncosted[row_id]}",
                }  # fmt: skip
            if method.id not in self.costs:
                key = None if user else self.store.key(method, case.channel_inputs[0], self.backend,
                                                       self.cost_elements, tiles.digests)  # fmt: skip
                cost = self.store.cost(
                    key, partial(method_cost, method, case, self.backend, self.cost_elements, tiles=tiles)
                )
                self.costs[method.id] = {"label": method.label, **cost}
            if row_id in case.precompute and "precompute_trigger" not in self.costs[method.id]:
                self.precompute(method, case, case.precompute[row_id])
            self.timings["evaluation"] += time.perf_counter() - t1
            spent["evaluation"] += time.perf_counter() - t1
            if self.fit and method.params:
                fitted.append((row_id, method, user, case))
        del tiles  # (up to 128 MiB of tiled inputs: not held through the fits)
        return _EvaluatedCase(family.name, base, sigma, order, declared, fitted)

    def fit_cases(self, cases: Sequence[_EvaluatedCase], say) -> dict[tuple[str, str], dict]:
        """The fits of every evaluated case ((case id, row) → `fit_case`'s dict), shared between this process
        and a forked helper on a machine of two cores (`shared_map`: the same results bit for bit; a fit on
        Dr.Jit, or of a user's approximation, runs here). Their wall time is the fit time, shared among the
        families by their fits' own seconds."""
        tasks = [(c.base.id, row_id, method, case) for c in cases for row_id, method, _u, case in c.fitted]
        if not tasks:
            return {}
        may = [_shareable(method, user) for c in cases for _r, method, user, _c in c.fitted]
        families = [c.family for c in cases for _ in c.fitted]
        sharing = shares(may)
        helper = " (on two processes)" if sharing else ""
        say(f"fits: {len(tasks)} rows of {sum(1 for c in cases if c.fitted)} case(s){helper}")
        t = time.perf_counter()
        with _drjit_threads_beside_a_helper(sharing):
            done, seconds = shared_map(tasks, _fit_task, may)
        wall = time.perf_counter() - t
        self.timings["fit"] += wall
        total = sum(seconds) or 1.0
        for name, took in zip(families, seconds, strict=True):
            self.by_family[name]["fit"] += wall * took / total
        return {(cid, row_id): r for (cid, row_id, _m, _c), r in zip(tasks, done, strict=True)}

    def finish(self, ev: _EvaluatedCase, fits: Mapping[tuple[str, str], dict]) -> dict[str, MethodOutcome]:
        """The case's outcomes in row order (each declared row, then its fitted row, evaluated at the fitted
        values), each with its metrics beside the noise floor. A row whose fit is not in ``fits`` (an
        interrupted run's) has no fitted row, and the report says so."""
        base, sigma, declared = ev.base, ev.sigma, ev.declared
        spent = self.by_family[ev.family]
        refits: dict[str, MethodOutcome] = {}
        unfitted = [row_id for row_id, *_ in ev.fitted if (base.id, row_id) not in fits]
        if unfitted:
            names = ", ".join(unfitted)
            self.notes.append(f"{base.label}: not fitted (the run was interrupted first): {names}")
        for row_id, method, user, case in ev.fitted:
            t2 = time.perf_counter()
            result = fits.get((base.id, row_id))
            if result is None:
                continue
            values = {k: v["value"] for k, v in result["parameters"].items()}
            img_f = evaluate_case(method, case, values)
            refits[row_id] = MethodOutcome(
                case.id,
                f"{row_id}-fitted",
                method,
                f"{method.label} (fitted to this scene)",
                img_f,
                None,
                values,
                fit=result,
                user=user,
            )
            self.timings["fit"] += time.perf_counter() - t2
            spent["fit"] += time.perf_counter() - t2
        rows: dict[str, MethodOutcome] = {}
        for row_id, _method, _user in ev.order:
            if row_id in declared:
                rows[row_id] = declared[row_id]
            if row_id in refits:
                rows[f"{row_id}-fitted"] = refits[row_id]
        # Every row's metrics beside the noise floor, once all are evaluated: their ꟻLIP maps (and the
        # floor's) together (`prime_flip`: the same maps, the reference's share of the work done once).
        t3 = time.perf_counter()
        if "flip" in self.metrics:
            images = [o.image for o in rows.values()]
            prime_flip(images, base.reference.mean, sigma, base.mask, seed=self.seed)
        key = content_digest(base.reference.mean, sigma, base.mask)  # every row's reference: once a case
        for row_id, o in rows.items():
            o.metrics = self.metrics_of(o.image, base, sigma, row_id, key)
        self.timings["evaluation"] += time.perf_counter() - t3
        spent["evaluation"] += time.perf_counter() - t3
        return rows
