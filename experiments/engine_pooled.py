"""Pooled fits of ``rtfit run FAMILY`` on the engine: one value of each free parameter for every shipped
scene.

The engine fits each method to each case of each scene (`audit_fit.fit_case`): the values that make the
method least wrong *on that scene*. An engine loads one value. So after the scenes are audited, each method
fitted on two or more cases is fitted again to all of them at once (`audit_fit.pooled_fit`: every case
weighted so that each counts alike, its squared relative RMSE), and the report shows, per case, the RMSE of
the declared row, of the case's own fit and of the pooled values, beside the reference's noise floor — how
much a single setting costs against a setting tuned per scene. The pooled values go into
``fitted/<family>.json`` beside the per-scene ones (case ``pooled``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rtfit.fitting import compute_metrics

from . import fitted as fitfiles
from .audit_fit import PooledFit, evaluate_case, pooled_fit

__all__ = ["PooledReport", "pooled_fits"]

_SUFFIX = "-fitted"


@dataclass
class PooledReport:
    """The pooled fits of a run: the report's ``section`` (None without any), results' ``fits`` records,
    ``fitted/<family>.json`` ``entries`` and ``notes`` (cases left out of a pool, with why)."""

    section: dict | None = None
    fits: list[dict] = field(default_factory=list)
    entries: list = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _fmt(v) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.4g}"


def _rmse(case, image) -> tuple[float, float]:
    """RMSE of ``image`` against the case's reference over its mask, and the reference's noise floor."""
    m = compute_metrics(image, case.reference.mean, case.reference.sigma(), case.mask, names=("rmse",))
    return float(m["rmse"].value), float(m["rmse"].noise_floor)


def _metric(outcome, name: str = "rmse"):
    m = None if outcome is None or outcome.metrics is None else outcome.metrics.get(name)
    return None if m is None else float(m.value)


def pooled_fits(family: str, audits: Sequence) -> PooledReport:
    """Fit every method fitted on two or more cases of ``audits`` (the `audit_run.AuditResult` of each
    shipped scene) to all of them at once (module docstring)."""
    by_method: dict[str, list] = {}
    for r in audits:
        for case in r.cases:
            for o in r.outcomes[case.id].values():
                if o.fit and not o.user and o.row.endswith(_SUFFIX):
                    by_method.setdefault(o.method.id, []).append((r, case, o))
    report = PooledReport()
    lines = []
    for found in by_method.values():
        method = found[0][2].method
        pf = pooled_fit(method, [(c, o.row[: -len(_SUFFIX)], o.parameters) for _, c, o in found])
        if pf is None:
            continue
        report.notes += [
            f"{method.id}: {c} left out of the pooled fit: {why}" for c, why in pf.left_out.items()
        ]
        values = {k: v["value"] for k, v in pf.fit["parameters"].items()}
        shown = ", ".join(
            f"{k} = {_fmt(v['value'])} ± {_fmt(v.get('stderr'))}" for k, v in pf.fit["parameters"].items()
        )
        lines.append(f"\n**{method.label}** ({method.id}): {shown} over {len(pf.cases)} cases\n")
        lines.append("| case | declared | own fit | pooled | noise floor |")
        lines.append("| --- | ---: | ---: | ---: | ---: |")
        for r, case, o in found:
            if case.id not in pf.cases:
                continue
            pooled, floor = _rmse(case, evaluate_case(method, case, values))
            declared = _metric(r.outcomes[case.id].get(o.row[: -len(_SUFFIX)]))
            lines.append(
                f"| {case.label} | {_fmt(declared)} | {_fmt(_metric(o))} | {_fmt(pooled)} | {_fmt(floor)} |"
            )
        report.fits.append(_record(family, pf))
        report.entries.append(_entry(pf, [c for _, c, _ in found if c.id in pf.cases]))
    if lines:
        report.section = {
            "id": "pooled-fits",
            "title": "One setting for every scene (pooled fits)",
            "text": "Each method fitted on several cases is fitted again to all of them at once, each "
            "case weighted to count alike (its squared relative RMSE): the one value an engine would ship. "
            "RMSE per case (the quantity's units) of the declared row, the case's own fit and the pooled "
            "values, beside the reference's noise floor; the pooled values are in the fitted file as case "
            "`pooled`.\n" + "\n".join(lines),
            "placement": "after_results",
        }
    return report


def _record(family: str, pf: PooledFit) -> dict:
    f = pf.fit
    return fitfiles.fit_record(
        f"pooled/{pf.method.id}",
        f"{pf.method.label}, pooled over {len(pf.cases)} cases",
        pf.method.formula or pf.method.label,
        f,
        f"fitted/{family}.json",
        at_bound=[k for k, v in f["parameters"].items() if v.get("at_bound")],
        message=f.get("message"),
    )


def _entry(pf: PooledFit, cases: Sequence):
    """The fitted-file entry of a pooled fit: the inputs' domain joined over the pooled cases."""
    dom: dict[str, tuple[float, float]] = {}
    for case in cases:
        for name in pf.method.input_names:
            v = case.channel_inputs[0].get(name)
            if v is None or not np.ndim(v):
                continue
            a = np.asarray(v, np.float64)
            a = a[np.isfinite(a)]
            if a.size:
                lo, hi = dom.get(name, (math.inf, -math.inf))
                dom[name] = (min(lo, float(a.min())), max(hi, float(a.max())))
    return fitfiles.method_entry(
        pf.method,
        pf.fit,
        label=f"{pf.method.label}, pooled over {len(pf.cases)} cases",
        case="pooled",
        domain=dom,
        residual_units="relative: (method − reference) / (RMS of the case's reference × √(its elements))",
        data={"cases": [re.sub(r"[^A-Za-z0-9_.-]", "_", c) for c in pf.cases]},
    )
