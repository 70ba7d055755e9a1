"""An audit's typed records: the self-checks (exact forms vs the references, deterministic rows), the fit
records, the `Results` written as results.json and the summary line (split from `audit_run`, issue 30)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import concat_z_pairs, z_checks, z_pair
from rtfit.fitting.stats import Z_MEDIAN_TOLERANCE, Z_TAIL_FRACTION
from rtfit.realtime.methods import Method
from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR
from rtfit.reference.estimators import GBuffer

from . import audit_api
from . import fitted as fitfiles
from .atomic import atomic_directory
from .audit import SceneInfo
from .audit_family import FamilyCase
from .audit_output import fitted_on_text, reference_record, write_audit
from .audit_selection import Selection
from .cost_store import COST_NOTE
from .families import AUDITED
from .records import SCHEMA, Check, Results, from_json, plain_json, to_json
from .runner import created_now, device_description, versions


# ------------------------------------------------------------------------------------------------ result
@dataclass
class MethodOutcome:
    """One method on one case: ``image`` (H, W, 3; 0 outside the mask), ``metrics`` (name → `MetricValue`),
    ``parameters`` used, ``fit`` (`FitResult.to_dict()` of a fitted row, else None), ``user`` (a user
    approximation)."""

    case: str
    row: str
    method: Method
    label: str
    image: np.ndarray
    metrics: Any
    parameters: dict
    fit: dict | None = None
    user: bool = False


@dataclass
class AuditResult:
    """What `audit` returns. ``cases`` (`FamilyCase`, with their references: ``case.reference.mean`` and
    ``.stderr``), ``outcomes`` (case id → row id → `MethodOutcome`), ``costs`` (method id → ns per pixel
    and the backend), ``timings`` (seconds: reference, evaluation, fit), ``results`` (the typed
    `Results` record written as results.json), ``out`` (the report directory, if written), ``skipped``
    (families that apply but are not audited yet, with why)."""

    info: SceneInfo
    cases: list[FamilyCase]
    outcomes: dict[str, dict[str, MethodOutcome]]
    costs: dict[str, dict]
    timings: dict[str, float]
    results: Results
    skipped: list[str] = field(default_factory=list)
    out: Path | None = None
    partial: str | None = None
    """Set on the result of an interrupted run: the note saying what is missing (the report's first)."""
    by_family: dict[str, dict[str, float]] = field(default_factory=dict)
    """Family → seconds of its ``reference`` (its cases' passes; the scene's load and G-buffer, shared by
    all, are the rest of ``timings["reference"]``), ``evaluation`` and ``fit`` (`profile_lines`)."""
    gbuffer: GBuffer | None = None
    """The pixel-centre G-buffer of the scene's camera the cases were computed on (its ``mask``, points,
    normals, depths): what a family's study reads instead of tracing it again
    (`shipped.StudyContext`)."""
    failed: list[dict] = field(default_factory=list)
    """Checks that failed while the cases ran (a precompute that raised), in results.json's ``checks``."""
    _figures: list = field(default_factory=list, repr=False)

    def reference(self, case: str) -> np.ndarray:
        return self._case(case).reference.mean

    def stderr(self, case: str) -> np.ndarray:
        return self._case(case).reference.stderr

    def image(self, case: str, row: str) -> np.ndarray:
        return self.outcomes[case][row].image

    def metrics(self, case: str, row: str) -> dict:
        """Metric name → `MetricValue` (``value``, ``noise_floor``, ``resolved``, ``debiased``; ``float(m)``
        is the value). `metric_values` gives the bare floats."""
        return dict(self.outcomes[case][row].metrics)

    def metric_values(self, case: str, row: str) -> dict[str, float]:
        """Metric name → its value alone (`metrics` without the noise floor and resolved flag)."""
        return {k: v.value for k, v in self.outcomes[case][row].metrics.items()}

    def summary_rows(self) -> list:
        """One `audit_api.SummaryRow` per case × row (RMSE, noise floor, resolved, fitted, cost)."""
        return audit_api.summary_rows(self)

    def to_dataframe(self):
        """`summary_rows` as a ``pandas.DataFrame`` (needs pandas, which rtfit does not depend on)."""
        return audit_api.to_dataframe(self)

    def _repr_html_(self) -> str:
        """Jupyter's inline view: the summary table (`audit_api.summary_html`)."""
        return audit_api.summary_html(self)

    @property
    def fits(self) -> dict[str, dict]:
        """``"case/row"`` → the fit's parameters ({name: {value, stderr, lower, upper, at_bound}})."""
        return {
            f"{c}/{r}": o.fit["parameters"]
            for c, rows in self.outcomes.items()
            for r, o in rows.items()
            if o.fit
        }

    def _case(self, case: str) -> FamilyCase:
        for c in self.cases:
            if c.id == case:
                return c
        raise KeyError(f"no case {case!r} (cases: {', '.join(c.id for c in self.cases)})")

    def write_report(self, directory) -> Path:
        """Write results.json, the report, figures and fitted parameters into ``directory`` (atomically:
        the directory is replaced only once everything is written). Returns the directory."""
        directory = Path(directory)
        t0 = time.perf_counter()
        with atomic_directory(directory) as tmp:
            write_audit(Path(tmp), self)
        self.out = directory
        self.timings["report"] = time.perf_counter() - t0
        return directory

    def profile_lines(self) -> list[str]:
        """Where the run's time went (``rtfit audit --profile``): seconds of reference, evaluation and fit per
        family, the scene's own set-up (load, G-buffer), the report, and each phase's share of the whole."""
        phases = ("reference", "evaluation", "fit")
        shared = self.timings.get("reference", 0.0) - sum(
            f.get("reference", 0.0) for f in self.by_family.values()
        )
        total = sum(self.timings.get(k, 0.0) for k in (*phases, "report"))
        width = max([len(k) for k in self.by_family] + [len("scene load + G-buffer")])
        lines = [f"{'':{width}}  {'reference':>10}  {'evaluation':>10}  {'fit':>10}"]
        for name, t in self.by_family.items():
            lines.append(f"{name:{width}}  " + "  ".join(f"{t.get(k, 0.0):9.2f}s" for k in phases))
        lines.append(f"{'scene load + G-buffer':{width}}  {shared:9.2f}s")
        if "report" in self.timings:
            lines.append(f"{'report (figures, viewer)':{width}}  {self.timings['report']:9.2f}s")
        if total > 0:
            share = ", ".join(
                f"{k} {100 * self.timings.get(k, 0.0) / total:.0f} %"
                for k in (*phases, "report")
                if k in self.timings
            )
            lines.append(f"total {total:.2f} s: {share}")
        return lines


# ---------------------------------------------------------------------------------------------- results
def _checks(plan, outcomes) -> list[dict]:
    """z-scores of the exact methods (``Method.exact``) against the unfactored references: an exact closed
    form must sit at the reference's noise (the check that reference and inputs measure the same thing)."""
    checks = []
    for _family, _a, case in plan:
        if case.factor is not None:
            continue
        for row in outcomes[case.id].values():
            if not row.method.exact or row.fit:
                continue
            ref = case.reference
            if not np.any(ref.stderr[case.mask]):  # computed without sampling: no z-scores to judge
                checks.append(_deterministic_check(row, case))
                continue
            what = f"{row.row} vs the reference, {case.label}"
            # pixels whose sample variance does not measure the reference's error are not judged
            judged = case.mask if ref.unchecked is None else case.mask & ~ref.unchecked
            if not judged.any():
                checks.append(_unjudged_check(what, int(case.mask.sum())))
                continue
            pair = z_pair(
                row.image[judged],
                ref.mean[judged],
                ref.stderr[judged],
                ref.sigma()[judged],
                precision_floor=(
                    RELATIVE_PRECISION_FLOOR
                    if ref.precision is None
                    # A bias bound b of the reference (not noise) shifts an element's z by up to b/stderr:
                    # only elements whose noise is ≥ b / Z_MEDIAN_TOLERANCE judge the spread and median
                    # (one bias in every element then moves the median by at most its tolerance).
                    else np.maximum(RELATIVE_PRECISION_FLOOR, ref.precision[judged] / Z_MEDIAN_TOLERANCE)
                ),
            )
            if not pair[0].size and pair[1].size:  # no element's noise above the reference's own precision
                checks.append(_within_precision_check(what, pair[1]))
                continue
            checks += z_checks(what, *concat_z_pairs([pair]), samples=int(ref.spp))
    return checks


def _unjudged_check(what: str, pixels: int) -> dict:
    """The exact row's check where every pixel's reference is one whose sample variance does not measure its
    error (`AuditReference.unchecked`): nothing to judge; reported as such, passed."""
    return {
        "name": f"{what}: z-scores ({pixels} elements)",
        "value": 0.0,
        "expected": "not judged: no element's sample variance measures its error (the case's notes say why)",
        "passed": True,
    }


def _within_precision_check(what: str, z_all: np.ndarray) -> dict:
    """The exact row's check where no element's standard error exceeds the reference's precision floor (a
    very small sphere light: `audit_lights.sphere_sampling_precision`): no z-scores to judge a spread or a
    median by, only that the row sits within that floor (σ includes it): at most `Z_TAIL_FRACTION` of the
    elements beyond |z| = 4."""
    tail = float(np.mean(np.abs(z_all) > 4.0))
    return {
        "name": f"{what}: fraction with |z| > 4 ({z_all.size} elements; every one's noise is below the "
        "reference's precision floor)",
        "value": tail,
        "expected": f"≤ {Z_TAIL_FRACTION}",
        "passed": bool(tail <= Z_TAIL_FRACTION),
    }


DETERMINISTIC_TOLERANCE = 4.0
"""An exact row against a reference computed without sampling (`AuditReference.deterministic`: Mitsuba's own
BSDF or first hits): every element within 4 precision floors, 4·`RELATIVE_PRECISION_FLOOR`·|reference|
(float32 evaluation of both sides: measured ≤ 1.2e-7 relative for the Fresnel rows), or within 1e-6 of
the masked reference's peak where the reference is 0 (a relative floor is 0 there)."""


def _deterministic_check(row: MethodOutcome, case: FamilyCase) -> dict:
    """The check of an exact row on a deterministic reference (`DETERMINISTIC_TOLERANCE`): the largest
    |row − reference| in units of its allowance; passed at ≤ 1."""
    x, r = row.image[case.mask], case.reference.mean[case.mask]
    peak = float(np.max(np.abs(r))) if r.size else 0.0
    allowed = np.maximum(DETERMINISTIC_TOLERANCE * RELATIVE_PRECISION_FLOOR * np.abs(r), 1e-6 * peak)
    worst = float(np.max(np.abs(x - r) / np.where(allowed > 0, allowed, 1.0))) if r.size else 0.0
    return to_json(
        Check(
            name=f"{row.row} vs the reference, {case.label}: exact (a reference without sampling)",
            value=worst,
            expected=f"≤ 1 (|Δ| ≤ {DETERMINISTIC_TOLERANCE:g}·{RELATIVE_PRECISION_FLOOR:g}·|r| or 1e-6·peak)",
            passed=bool(worst <= 1.0),
        )
    )  # type: ignore[return-value]


def _case_notes(plan) -> list[str]:
    """The cases' own notes (`FamilyCase.notes`: how a reference was made, a caveat such as a very small
    sphere light's biased reference), each text once with the cases it belongs to."""
    by_text: dict[str, list[str]] = {}
    for _family, _a, case in plan:
        for note in case.notes:
            by_text.setdefault(note, []).append(case.label)
    return [f"{', '.join(labels)}: {text}" for text, labels in by_text.items()]


def _fit_record(case: FamilyCase, row: MethodOutcome) -> dict:
    f = {"parameters": {}, **(row.fit or {})}  # a row without a fit still gets its (empty) record
    return fitfiles.fit_record(
        f"{case.id}/{row.row}",
        f"{row.method.label}, {case.label}",
        row.method.formula or row.method.label,
        f,
        "fitted/audit.json",
        at_bound=[k for k, v in f["parameters"].items() if v.get("at_bound")],
        message=f.get("message"),
        **({"fitted_on": fitted_on_text(f["subsample"])} if "subsample" in f else {}),
    )


_PRECOMPUTE_KEYS = ("precompute_ms", "precompute_trigger", "precompute_pixels", "precompute_note")
"""A cost record's precompute columns (`audit_cases.CaseRun.precompute`; the first three also on each
approximation)."""


def results_record(r: AuditResult, plan, *, variant, spp, pass_spp, seed, sel: Selection) -> Results:
    info = r.info
    case_docs = []
    for _family, _a, case in plan:
        approx = []
        for row in r.outcomes[case.id].values():
            c = r.costs.get(row.method.id)
            approx.append(
                {
                    "method": row.row,
                    "label": row.label + (" [yours]" if row.user else ""),
                    "fitted": row.fit is not None,
                    "parameters": {k: float(v) for k, v in row.parameters.items()},
                    "metrics": row.metrics.to_dict(),
                    "cost": {
                        "ns_per_pixel": c["ns_per_pixel"],
                        "pixels_per_second": c["pixels_per_second"],
                        "backend": c["backend"],
                        **{k: c.get(k) for k in _PRECOMPUTE_KEYS[:3]},
                    }
                    if c
                    else None,
                }
            )
        case_docs.append(
            {
                "id": case.id,
                "label": case.label,
                "parameters": dict(case.parameters),
                "scene": {
                    "name": Path(info.source).name,
                    "hash": info.xml.dependencies.digest if info.xml else None,
                },
                "reference": reference_record(case.reference, variant, case.mask),
                "approximations": approx,
            }
        )
    figs = r._figures
    fits = [_fit_record(c, row) for _f, _a, c in plan for row in r.outcomes[c.id].values() if row.fit]
    costs = [
        {"method": mid, "label": c["label"], "backend": c["backend"], "ns_per_pixel": c["ns_per_pixel"],
         "pixels_per_second": c["pixels_per_second"], "elements": c["elements"], "repeats": c["repeats"],
         "note": c.get("note", COST_NOTE),
         **{k: c.get(k) for k in _PRECOMPUTE_KEYS}}
        for mid, c in r.costs.items()
    ]  # fmt: skip
    families = sorted({f.name for f, _a, _c in plan})
    sections = [
        {
            "id": "scene",
            "title": "Scene",
            "text": "\n\n".join(
                [
                    f"`{info.source}` ({info.format})",
                    *info.contents,
                    f"Camera: {info.camera}.",
                    f"Up: {info.up_reason}.",
                ]
            ),
        },
        *({"id": f"method-{f}", "title": f"Method: {f}", "text": AUDITED[f].describe} for f in families),
    ]
    notes = [
        *([r.partial] if r.partial else []),
        "Every approximation is evaluated at the pixel centres the reference is point-sampled at, so an "
        "exact formula leaves only the reference's noise; metrics below their noise floor are not resolved.",
        "Rows '… (fitted to this scene)' have their free parameters least-squares fitted to this scene's "
        "reference (all compared pixels and channels); the fitted values are in fitted/audit.json.",
        *r.skipped,
        *_case_notes(plan),
    ]
    if sel.user:
        notes.append(
            "Your approximations: " + ", ".join(f"{m.id} ({m.source or m.quantity})" for m in sel.user) + "."
        )
    best = _summary(r, plan)
    doc = {
        "schema": SCHEMA,
        "experiment": "audit",
        "title": f"Audit of {Path(info.source).name}",
        "created": created_now(),
        "versions": versions(),
        "device": device_description(variant),
        "summary": best,
        "config": {
            "variant": variant,
            "spp": spp,
            "seed": seed,
            "extra": {
                "scene": info.source,
                "families": families,
                "pass_spp": pass_spp,
                "approximations": [m.id for m in sel.user],
                "timings_s": {k: round(v, 3) for k, v in r.timings.items()},
            },
        },
        "sections": sections,
        "cases": case_docs,
        "fits": fits,
        "figures": figs,
        "costs": costs,
        "checks": [*_checks(plan, r.outcomes), *r.failed],
        "notes": notes,
    }
    return from_json(Results, plain_json(doc), f"audit of {info.source}")


def _summary(r: AuditResult, plan) -> str:
    """One sentence per case. Rows whose RMSE is not resolved above the reference's noise floor cannot be
    told from exact at this sample count: when the smallest RMSE is among them, the case names them "within
    the noise" and names no best; otherwise the best row is named, with the rows whose RMSE lies within one
    noise floor of its own (the noise cannot order those) as tied."""
    lines = []
    for _f, _a, case in plan:
        rows = [o for o in r.outcomes[case.id].values() if "rmse" in o.metrics]
        if not rows:
            continue
        ranked = sorted(rows, key=lambda o: o.metrics["rmse"].value)
        b = ranked[0]
        m = b.metrics["rmse"]
        unit = "" if case.units in ("", "1") else f" {case.units}"
        if not m.resolved:
            quiet = [o.label for o in ranked if not o.metrics["rmse"].resolved]
            lines.append(
                f"{case.label}: {', '.join(quiet)} within the reference's noise (RMSE ≤ 2 × its floor "
                f"{m.noise_floor:.2g}{unit}): more samples are needed to rank them"
            )
            continue
        tied = [o.label for o in ranked[1:] if o.metrics["rmse"].value - m.value <= m.noise_floor]
        lines.append(
            f"{case.label}: best {b.label} (RMSE {m.value:.4g}{unit}, noise floor {m.noise_floor:.2g})"
            + (f", tied within the noise floor with {', '.join(tied)}" if tied else "")
        )
    return "; ".join(lines) + "."
