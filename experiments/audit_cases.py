"""The audit's cases, one after another and then together (`CaseRun`, issue 33): each case's rows evaluated
and costed on quiet cores (`CaseRun.evaluate`), the fits of every case (`CaseRun.fit_cases`), then each case's
fitted rows and every row's metrics (`CaseRun.finish_cases`), the fits and the metrics shared with a forked
helper process on two cores (`rtfit.fitting.forked_fits.shared_map`: the same results bit for bit). Split
from `audit_run` (session 30)."""

from __future__ import annotations

import contextlib
import sys
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from rtfit.fitting import compute_metrics, prime_flip
from rtfit.fitting.flip_maps import flip_map_keys, maps_since, remember_maps
from rtfit.fitting.forked_fits import shared_map, shares, two_cores
from rtfit.fitting.metric_noise import content_digest
from rtfit.realtime.methods import Method

from .audit import Applicability, AuditError
from .audit_cost import CostInputs, method_cost
from .audit_family import PRECOMPUTE_TRIGGERS, AuditFamily, FamilyCase, Precompute
from .audit_fit import evaluate_case, fit_case
from .audit_results import MethodOutcome
from .audit_selection import Selection
from .cost import time_precompute
from .cost_store import CostStore
from .families import METHOD_TABLES
from .records import Check, to_json

__all__ = ["CaseRun", "EvaluatedCase", "case_rows"]


def case_rows(
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


@dataclass(frozen=True)
class EvaluatedCase:
    """One case between its evaluation and its fits (`CaseRun.evaluate`): the declared rows' outcomes
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


def _shareable(method: Method, user: bool, drjit_beside: bool) -> bool:
    """Whether the forked helper may fit ``method`` (`shared_map`): a fit of a shipped method, on NumPy, or on
    Dr.Jit where ``drjit_beside`` (`_drjit_beside_a_helper`: LLVM, and a pool with no worker thread to copy
    at the fork). A fit on CUDA stays here (a forked child cannot use the parent's CUDA context); a user's
    approximation is fitted here, where its code runs as in a serial run."""
    return not user and (method.fit_ops == "numpy" or drjit_beside)


def _threads_beside_a_helper() -> int:
    """Dr.Jit's threads while the fit helper runs (`_drjit_threads_beside_a_helper`): one fewer than it has,
    at least one (counting the calling thread)."""
    import drjit as dr

    return max(1, dr.thread_count() - 1)


def _drjit_beside_a_helper(backend: str) -> bool:
    """Whether the helper may run fits on Dr.Jit: on the LLVM backend, where the pool beside it has no worker
    thread (`_threads_beside_a_helper` 1: a machine of two cores). A fork copies no thread: a worker the
    parent had would be one the child's kernels wait on for ever. On more cores the pool keeps its other
    workers for the fits here, and the helper takes the NumPy fits only, as before session 34."""
    return backend == "llvm" and _threads_beside_a_helper() == 1


@contextlib.contextmanager
def _drjit_threads_beside_a_helper(sharing: bool) -> Iterator[None]:
    """Dr.Jit's thread pool one thread smaller while the fit helper runs (`CaseRun.fit_cases`;
    `_threads_beside_a_helper`), put back after: a Dr.Jit fit's kernels split over every core waited for the
    worker that the helper's process held off its core (issue 33, session 29: the Cornell box's ten
    shadow-map fits at 64² took 1.7–2.2 s beside the helper with two Dr.Jit threads, against 0.9–1.0 s
    alone). On two cores the pool is then the calling thread alone: nanothread's ``pool_set_size`` joins the
    workers it removes (a size of 1 counts the calling thread only), so the fork copies none, and the helper
    runs Dr.Jit fits too (session 34), every kernel on the thread that waits on it."""
    if not sharing:
        yield
        return
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(_threads_beside_a_helper())
    try:
        yield
    finally:
        dr.set_thread_count(threads)


METRIC_TASKS_MIN = 4
"""The fewest metric tasks `metric_tasks` makes where rows allow: a case a task left the helper idle where an
audit has one case (``--approx ibl-samples`` on Mitsuba's teapot: one case of 26 rows, its metrics on one
core)."""


def metric_tasks(tasks: list[tuple[EvaluatedCase, dict]]) -> list[tuple[EvaluatedCase, dict]]:
    """The metric tasks of `CaseRun._measured` (a case and some of its rows), the largest split in two (its
    rows in order) until there are `METRIC_TASKS_MIN` or none has two rows, where a helper can take some
    (`two_cores`; else as given: a task computes its case's reference ꟻLIP features again, which a process
    running every task in turn would pay once a split). Each row's metrics are its own, so a split changes
    none of them."""
    out = list(tasks)
    while two_cores() and len(out) < METRIC_TASKS_MIN:
        i = max(range(len(out)), key=lambda k: len(out[k][1]), default=None)
        if i is None or len(out[i][1]) < 2:
            break
        ev, rows = out[i]
        items = list(rows.items())
        half = len(items) // 2
        out[i : i + 1] = [(ev, dict(items[:half])), (ev, dict(items[half:]))]
    return out


def _solver_imported() -> bool:
    """Whether the fits' solver (``scipy.optimize``) is in this process already (`CaseRun.fit_cases`)."""
    return "scipy.optimize" in sys.modules


def _fit_task(task: tuple[str, str, Method, FamilyCase]) -> dict:
    """`fit_case` of one (case id, row, method, case) of `CaseRun.fit_cases`: what `shared_map` runs, in
    either process."""
    _case_id, row_id, method, case = task
    return fit_case(method, case, row_id)


@dataclass
class CaseRun:
    """Evaluates and measures the rows of one case after another (`evaluate`), fits those of every case
    together (`fit_cases`) and finishes every case (`finish_cases`: fitted rows, metrics), adding to the run's
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
    shared_ms: dict[Precompute, float] = field(default_factory=dict)
    """Each shared step timed so far (`Precompute.shared`, ms)."""
    shared_products: dict[Precompute, Any] = field(default_factory=dict)
    """The shared steps' products while the case being evaluated times its rows (emptied at its end: a
    light-path-map bake's transfer terms are ~160 MB at 64²)."""
    measured: dict[str, dict[str, dict]] = field(default_factory=dict)
    """Metrics taken before the fits (`fit_cases`: the declared rows', beside the solver's import), by case
    id and row id; `finish_cases` measures the rest."""

    def precompute(self, method: Method, case: FamilyCase, pre: Precompute, cost_key: str | None) -> None:
        """Time the row's precompute (`cost.time_precompute`) into its method's cost record:
        ``precompute_ms``, its ``precompute_trigger``, the case's ``precompute_pixels`` and
        ``precompute_note``. One that raises leaves ``precompute_ms`` None and becomes a failed check (one
        line: the exception's type and first line), not a crash of the run. Rows sharing one `Precompute`
        get one timing. A timing an earlier run kept (`CostStore.precompute`: the method's ``cost_key``, the
        case's reference and the step) is not taken again: issue 33 (session 33), a second 64² audit of
        Blender's test1 scene re-timed its five light-path-map bakes, 1.7 of its 2.0 s of evaluation."""
        if pre in self.timed:  # rows sharing one step (the three photon forms at one N): timed once
            self.costs[method.id].update(self.timed[pre])
            return
        pixels = int(case.mask.sum())
        record = {"precompute_trigger": pre.trigger, "precompute_pixels": pixels,
                  "precompute_note": f"{pre.what} ({PRECOMPUTE_TRIGGERS[pre.trigger]})"}  # fmt: skip
        key = self.store.precompute_key(cost_key, case.reference.cache_key, pre.what, pre.trigger, pixels)
        try:
            record["precompute_ms"], kept = self.store.precompute(key, lambda: self._precompute_ms(pre))
            record["precompute_note"] += kept
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

    def _precompute_ms(self, pre: Precompute) -> float:
        """``pre``'s time (ms, `cost.time_precompute`): its own ``run`` and, where it has one, its shared
        step, timed once for every row that shares it (`Precompute.shared`) and added. Issue 33 (session 33):
        the five light-path-map rows each ran the whole bake, the K-independent 4 million shadow rays too
        (6.3 s of a 64² audit of Mitsuba's integrator_direct_both scene)."""
        if pre.shared is None:
            return time_precompute(pre.run).seconds * 1e3
        product = self._shared_product(pre.shared)
        return time_precompute(lambda: pre.run(product)).seconds * 1e3 + self.shared_ms[pre.shared]

    def _shared_product(self, shared: Precompute) -> Any:
        """What the shared step ``shared`` returns, made once for the case being evaluated: timed the first
        time (`shared_ms`), run again untimed where another case timed it."""
        if shared not in self.shared_products:
            made: list = []

            def once():
                made[:] = [shared.run()]
                return made[0]

            if shared in self.shared_ms:
                once()
            else:
                self.shared_ms[shared] = time_precompute(once).seconds * 1e3
            self.shared_products[shared] = made[0]
        return self.shared_products[shared]

    def metrics_of(
        self, img: np.ndarray, case: FamilyCase, sigma: np.ndarray, row: str, key: tuple, notes: list[str]
    ):
        """The row's metrics beside the noise floor (``key``: the `content_digest` of the case's reference
        mean, ``sigma`` and mask, made once for its rows). A metric's warning about the row's values (ꟻLIP
        clips an approximation's negative radiance to 0: an SH L2 ring below zero) is the row's property, not
        a fault of the run: it becomes a note of the report naming the row and the case (added to
        ``notes``)."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            m = compute_metrics(
                img, case.reference.mean, sigma, case.mask, names=self.metrics, seed=self.seed,
                reference_key=key,
            )  # fmt: skip
        for w in caught:
            note = f"{row} ({case.label}): {str(w.message).splitlines()[0]}"
            if note not in notes:
                notes.append(note)
        return m

    def evaluate(self, family: AuditFamily, a: Applicability, base: FamilyCase) -> EvaluatedCase:
        """Every row of ``base`` (`case_rows`) evaluated and its cost measured once per method (on quiet
        cores: no fit runs yet); the rows with free parameters listed for `fit_cases`. The case's tiled cost
        inputs (`CostInputs`, shared by its methods) are let go at its end."""
        declared: dict[str, MethodOutcome] = {}
        sigma = base.reference.sigma()
        spent = self.by_family[family.name]
        tiles = CostInputs()  # the case's inputs tiled once for all its methods' cost measurements
        fitted: list[tuple[str, Method, bool, FamilyCase]] = []
        order = case_rows(family, a, self.sel, base)
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
            key = None
            if method.id not in self.costs or row_id in case.precompute:
                key = None if user else self.store.key(method, case.channel_inputs[0], self.backend,
                                                       self.cost_elements, tiles.digests)  # fmt: skip
            if method.id not in self.costs:
                cost = self.store.cost(
                    key, partial(method_cost, method, case, self.backend, self.cost_elements, tiles=tiles)
                )
                self.costs[method.id] = {"label": method.label, **cost}
            if row_id in case.precompute and "precompute_trigger" not in self.costs[method.id]:
                self.precompute(method, case, case.precompute[row_id], key)
            self.timings["evaluation"] += time.perf_counter() - t1
            spent["evaluation"] += time.perf_counter() - t1
            if self.fit and method.params:
                fitted.append((row_id, method, user, case))
        del tiles  # (up to 128 MiB of tiled inputs: not held through the fits)
        self.shared_products.clear()  # (a shared precompute's product: not held past its case either)
        return EvaluatedCase(family.name, base, sigma, order, declared, fitted)

    def fit_cases(self, cases: Sequence[EvaluatedCase], say) -> dict[tuple[str, str], dict]:
        """The fits of every evaluated case ((case id, row) → `fit_case`'s dict), shared between this process
        and a forked helper on a machine of two cores (`shared_map`: the same results bit for bit; a fit on
        Dr.Jit, or of a user's approximation, runs here). Their wall time is the fit time, shared among the
        families by their fits' own seconds."""
        tasks = [(c.base.id, row_id, method, case) for c in cases for row_id, method, _u, case in c.fitted]
        if not tasks:
            return {}
        beside = _drjit_beside_a_helper(self.backend)
        may = [_shareable(method, user, beside) for c in cases for _r, method, user, _c in c.fitted]
        families = [c.family for c in cases for _ in c.fitted]
        sharing = shares(may)
        helper = " (on two processes)" if sharing else ""
        say(f"fits: {len(tasks)} rows of {sum(1 for c in cases if c.fitted)} case(s){helper}")
        self._solver_beside_metrics(cases)
        with _drjit_threads_beside_a_helper(sharing):
            done = self._shared("fit", tasks, _fit_task, may, families)
        return {(cid, row_id): r for (cid, row_id, _m, _c), r in zip(tasks, done, strict=True)}

    def _solver_beside_metrics(self, cases: Sequence[EvaluatedCase]) -> None:
        """The fits' solver (SciPy's ``scipy.optimize``: 0.35–0.42 s to import on the 2-core machine of issue
        33, SciPy 1.17 rewriting ~280 docstrings) imported here while a forked helper takes the declared rows'
        metrics, which need no fit (`_measure_rows` with ``before``; the metrics of the rows fitted next come
        in `finish_cases`). Before session 34 the audit imported it first, alone, one core idle. The phase's
        wall time is shared between the fits (the import's part) and the evaluation (the metrics'), by their
        own seconds."""
        if _solver_imported():
            return

        def import_solver() -> None:
            import scipy.optimize  # noqa: F401

        self._measure_rows([(ev, ev.declared) for ev in cases if ev.declared], True, before=import_solver)

    def _measure_rows(self, tasks: list[tuple[EvaluatedCase, dict]], share: bool, before=None) -> None:
        """The metrics of each (case, rows) of ``tasks`` (`_measured`, split by `metric_tasks`) into
        `measured`, shared with a helper where ``share`` (`_shared`, as evaluation time; ``before``: this
        process's own work meanwhile, counted as fit time); the helper's notes and ꟻLIP maps (which the
        report's figures read: `rtfit.fitting.flip_maps.remember_maps`) come back with its metrics."""
        tasks = metric_tasks(tasks)
        families = [ev.family for ev, _rows in tasks]
        done = self._shared(
            "evaluation", tasks, self._measured, [share] * len(tasks), families, before, "fit"
        )
        for (ev, _rows), (metrics, notes, maps) in zip(tasks, done, strict=True):
            remember_maps(maps)
            self.measured.setdefault(ev.base.id, {}).update(metrics)
            self.notes.extend(n for n in notes if n not in self.notes)

    def _shared(
        self,
        phase: str,
        tasks: list,
        run,
        may: Sequence[bool],
        families: Sequence[str],
        before=None,
        before_phase: str = "",
    ) -> list:
        """`shared_map` of ``tasks`` (the helper may run those ``may`` marks, this process ``before`` first),
        its wall time shared by own seconds: ``before``'s to the run's ``before_phase`` seconds, the tasks'
        to ``phase``'s and, among them, to the tasks' ``families``."""
        spent = [0.0]

        def timed_before() -> None:
            t0 = time.perf_counter()
            before()
            spent[0] = time.perf_counter() - t0

        t = time.perf_counter()
        done, seconds = shared_map(tasks, run, may, before=None if before is None else timed_before)
        wall = time.perf_counter() - t
        own = spent[0] + sum(seconds) or 1.0
        before_part = wall * spent[0] / own  # (0 where there is no ``before``)
        if before is not None:
            self.timings[before_phase] += before_part
        self.timings[phase] += wall - before_part
        for name, took in zip(families, seconds, strict=True):
            self.by_family[name][phase] += wall * took / own
        return done

    def with_fits(self, ev: EvaluatedCase, fits: Mapping[tuple[str, str], dict]) -> dict[str, MethodOutcome]:
        """The case's outcomes in row order, their metrics still to come (`finish_cases`): each declared row,
        then its fitted row, evaluated here at the fitted values. A row whose fit is not in ``fits`` (an
        interrupted run's) has no fitted row, and the report says so."""
        base, declared = ev.base, ev.declared
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
        return rows

    def finish_cases(
        self,
        cases: Sequence[EvaluatedCase],
        fits: Mapping[tuple[str, str], dict],
        share: bool = True,
    ) -> list[dict[str, MethodOutcome]]:
        """Each case's outcomes (`with_fits`: its fitted rows evaluated here), then every row's metrics beside
        the noise floor (`_measured`, a case a task), shared with a forked helper on two cores (``share``;
        `shared_map`: NumPy only, the same values bit for bit): issue 33 (session 30), the metrics were a
        third of a 64² Cornell-box audit's evaluation (0.4–0.6 s), on one core. Their wall time is
        evaluation time, shared among the families by the tasks' own seconds; the helper's notes and ꟻLIP
        maps (which the report's figures read: `rtfit.fitting.flip_maps.remember_maps`) come back with its
        metrics."""
        outcomes = [self.with_fits(ev, fits) for ev in cases]
        rest = []  # each case's rows not measured yet (`measured`: the declared rows, where fits ran)
        for ev, rows in zip(cases, outcomes, strict=True):
            known = self.measured.get(ev.base.id, {})
            todo = {row_id: o for row_id, o in rows.items() if row_id not in known}
            if todo:
                rest.append((ev, todo))
        self._measure_rows(rest, share)  # (``share`` False: an interrupted run's report, here in turn)
        for ev, rows in zip(cases, outcomes, strict=True):
            for row_id, o in rows.items():
                o.metrics = self.measured[ev.base.id][row_id]
        return outcomes

    def _measured(self, task: tuple[EvaluatedCase, dict[str, MethodOutcome]]) -> tuple[dict, list[str], list]:
        """One case's metrics (`finish_cases`' task, in either process): row id → its metrics, the notes
        its metrics' warnings made (`metrics_of`), and the ꟻLIP maps computed (`maps_since`). Every row's
        ꟻLIP maps (and the floor's) together (`prime_flip`: the same maps, the reference's share of the work
        done once)."""
        ev, rows = task
        base, sigma = ev.base, ev.sigma
        known = flip_map_keys()
        notes: list[str] = []
        if "flip" in self.metrics:
            images = [o.image for o in rows.values()]
            prime_flip(images, base.reference.mean, sigma, base.mask, seed=self.seed)
        key = content_digest(base.reference.mean, sigma, base.mask)  # every row's reference: once a case
        metrics = {r: self.metrics_of(o.image, base, sigma, r, key, notes) for r, o in rows.items()}
        return metrics, notes, maps_since(known)
