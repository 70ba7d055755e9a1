"""The files of an audit (`audit_run.audit`, and ``rtfit run`` of a family born on the engine,
`engine_run`): per-case figures, the viewer's pixels, ``fitted/audit.json``, results.json and the report."""

from __future__ import annotations

import re
import threading
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import flip_error_map, prime_flip
from rtfit.fitting.flip_maps import MEMO_MAP_BYTES
from rtfit.fitting.forked_fits import shared_map

from . import figures
from . import fitted as fitfiles
from .records import Results, from_json, plain_json, to_json
from .report import write_report
from .results import write_results
from .viewer import prime_case_flip, save_case_pixels

AuditResult = Any
"""An `audit_run.AuditResult` (not imported: audit_run imports this module)."""

__all__ = [
    "case_figures",
    "fitted_entries",
    "fitted_on_text",
    "reference_record",
    "save_pixels",
    "viewer_flip_thread",
    "write_audit",
    "write_fitted_file",
]


def write_audit(directory: Path, r: AuditResult) -> None:
    """Write an audit into ``directory``: the viewer's pixels, figures, results.json (with the figures),
    fitted/audit.json and the report. The viewer's ꟻLIP maps (of the saved float32 pixels) are the audit's,
    or, where its metrics left ꟻLIP out, computed in a second thread while the figures are drawn
    (`viewer_flip_thread`); the figures' PNGs are encoded and written by another
    (`figures.pngs_in_background`), and the figures of the cases are shared with a forked helper where no
    such thread runs (`case_figures`)."""
    save_pixels(directory, r)
    flip = viewer_flip_thread(directory, r)
    try:
        # (every figure written before the report reads them; shared with a helper where no thread of this
        # process computes ꟻLIP maps meanwhile: a fork must not copy a lock that thread holds; the PNG
        # writer's thread starts at its first figure, after the fork)
        with figures.pngs_in_background():
            figs = case_figures(directory, r, share=flip is None)
        doc = plain_json(to_json(r.results))
        assert isinstance(doc, dict)
        for f in figs:  # (the figures name their case: placed after the case tables, in case order)
            f.pop("_case", None)
        doc["figures"] = figs
        results = from_json(Results, doc, f"audit of {r.info.source}")
        r.results = results
        _write_fitted(directory, r)
        write_results(directory, results)
    finally:
        if flip is not None:
            flip.join()
    write_report(directory, results=r.results)


def viewer_flip_thread(directory: Path, r: AuditResult) -> threading.Thread | None:
    """A started thread computing the ꟻLIP maps the report's viewer will show (`viewer.prime_case_flip`:
    the same maps, found in the memo by content), beside the figures on a second core: they were a third
    of an audit's report time (issue 33). None where the audit itself computed every row's map (its
    metrics hold ``flip``): the viewer's float32 pixels give the audit's own exposures and maps
    (`rtfit.fitting.flip_maps.flip_exposures`), already in the memo, and the thread would only read every
    case's pixels back to find them there. None too (the viewer computes them itself) where the maps of the
    audit and of the viewer, at 8 bytes a pixel, would not fit half of the memo (`MEMO_MAP_BYTES`): the
    thread's maps must not push out the audit's before the figures read them, nor their own before the
    viewer does."""
    if all("flip" in (o.metrics or {}) for c in r.cases for o in r.outcomes[c.id].values()):
        return None
    maps = sum(c.reference.mean[..., 0].size * len(r.outcomes[c.id]) for c in r.cases)
    if 2 * 8 * maps > MEMO_MAP_BYTES // 2:
        return None
    ids = [c.id for c in r.cases]
    thread = threading.Thread(
        target=lambda: [prime_case_flip(directory, i) for i in ids], name="rtfit-viewer-flip", daemon=True
    )
    thread.start()
    return thread


def save_pixels(directory: Path, r: AuditResult) -> None:
    """The report's image viewer data of every case (pixels/CASE.exr + .json, `viewer.save_case_pixels`)."""
    for case in r.cases:
        images = {row: o.image for row, o in r.outcomes[case.id].items()}
        save_case_pixels(directory, case.id, case.reference.mean, case.reference.sigma(), images, case.mask)


def case_figures(directory: Path, r: AuditResult, share: bool = False) -> list[dict]:
    """Per case: the reference beside each row with its signed error, and each row's ꟻLIP map, written under
    ``directory/figures/``; the figure entries of results.json, each with ``_case`` (its case id), in case
    order. ``share``: a case a task, shared with a forked helper process on two cores
    (`rtfit.fitting.forked_fits.shared_map`; each task's PNGs written before it returns), for a caller that
    runs no other thread meanwhile. Issue 33 (session 30): the figures were 4.4 s of the 7.7 s report of
    Mitsuba's `integrator_direct_both` scene (72 cases), on one core."""
    cases = list(r.cases)
    done, _ = shared_map(cases, partial(_figures_of, directory, r), [share] * len(cases))
    return [entry for entries in done for entry in entries]


def _figures_of(directory: Path, r: AuditResult, case) -> list[dict]:
    """`case_figures` of one case, its PNGs encoded and written beside the next figure's composition
    (`figures.pngs_in_background`: the caller's writer in the caller's process; in a forked helper its own,
    every PNG written before the task returns)."""
    out = []
    with figures.pngs_in_background():
        rows = list(r.outcomes[case.id].values())
        name = f"figures/{case.id}_images.png"
        figures.image_comparison(
            directory / name,
            case.reference.mean,
            [(o.label, o.image) for o in rows],
            case.mask,
            error_scale=float(np.max(case.reference.mean[case.mask])) or 1.0,
            title=f"{case.label}: reference, each approximation, signed error (fraction of the peak)",
        )
        caption = (
            f"{case.label}. Top: the reference and each approximation (same exposure). Bottom: signed error "
            "as a fraction of the reference's peak (red: too bright)."
        )
        out.append({"file": name, "section": "results", "_case": case.id, "caption": caption})
        maps = []
        # every row's ꟻLIP map together (`prime_flip`, no noise-floor draws: the reference filtered once for
        # all rows, the same maps as one call per row; issue 33)
        prime_flip(
            [o.image for o in rows], case.reference.mean, case.reference.stderr, case.mask, floor_draws=0
        )
        for o in rows:
            try:
                maps.append((o.label, flip_error_map(o.image, case.reference.mean, case.mask)))
            except ValueError:
                break
        if maps:
            name = f"figures/{case.id}_flip.png"
            figures.flip_maps_figure(directory / name, maps, case.mask, f"{case.label}: ꟻLIP")
            out.append({"file": name, "section": "results", "_case": case.id,
                        "caption": f"{case.label}: HDR-ꟻLIP error map of each approximation (0: no visible "
                        "difference, 1: largest)."})  # fmt: skip
    return out


def fitted_on_text(subsample: dict) -> str:
    """The subsample a fit started on, in words (`audit_fit.fit_case`'s ``subsample``): "8192 of 65536
    pixels"."""
    return f"{subsample['pixels']} of {subsample['of']} pixels"


def fitted_entries(r: AuditResult) -> list:
    """One `fitted.method_entry` per fitted row of every case (kernel text, values with their uncertainties,
    the inputs' domain on this scene)."""
    entries = []
    for case in r.cases:
        n = int(case.mask.sum())
        for o in r.outcomes[case.id].values():
            if not o.fit:
                continue
            dom, tables = {}, {}
            for name in o.method.input_names:
                v = case.channel_inputs[0].get(name)
                if v is not None and not isinstance(v, (int, float, np.ndarray, np.generic)):
                    tables[name] = v  # a sampler object (a shadow map, probe chains): bindings it reads
                elif v is not None and np.ndim(v) and np.size(v) != n:
                    tables[name] = np.ravel(v)  # a table (a sky's SH coefficients): one binding
                elif v is not None and np.ndim(v):
                    a = np.asarray(v, np.float64)
                    a = a[np.isfinite(a)]
                    if a.size:
                        dom[name] = (float(a.min()), float(a.max()))
            entries.append(
                fitfiles.method_entry(
                    o.method,
                    o.fit,
                    label=f"{o.method.label}, {case.label}",
                    case=re.sub(r"[^A-Za-z0-9_]", "_", case.id),
                    domain=dom,
                    residual_units=f"{case.units}: residual = method − reference per pixel and channel",
                    data={
                        "scene": r.info.source,
                        "case": case.id,
                        **({"fitted_on": fitted_on_text(o.fit["subsample"])} if "subsample" in o.fit else {}),
                    },
                    tables=tables,
                )
            )
    return entries


def _write_fitted(directory: Path, r: AuditResult) -> None:
    entries = fitted_entries(r)
    if entries:
        write_fitted_file(
            directory / "fitted" / "audit.json",
            f"parameters fitted to {Path(r.info.source).name} by rtfit audit",
            "audit",
            entries,
            [r],
            r.results.config.variant,
            quick=False,
        )


def write_fitted_file(
    path: Path, title: str, experiment: str, entries: list, audits, variant: str, quick: bool
) -> None:
    """``rtfit.fitted/1`` file at ``path`` of ``entries`` (`fitted_entries`) from ``audits``: its provenance
    names every XML scene's digest and the largest reference spp of their cases."""
    digests = [r.info.xml.dependencies.digest for r in audits if r.info.xml is not None]
    spp = max((c.reference.spp for r in audits for c in r.cases), default=0)
    prov = fitfiles.provenance(None, experiment, digests, reference_spp=spp, variant=variant, quick=quick)
    fitfiles.write_fitted(
        path, fitfiles.FittedFile(format=fitfiles.FORMAT, title=title, provenance=prov, methods=entries)
    )


def reference_record(ref, variant: str, mask: np.ndarray) -> dict:
    """The results' ``reference`` record of an `audit_setup.AuditReference` compared on ``mask``: its cache
    key, quantity, integrator and why, variant, spp and passes, the mean relative standard error over the
    compared pixels, and samples per second of rendering (None when no time was spent)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = ref.stderr[mask] / np.abs(ref.mean[mask])
    rel = rel[np.isfinite(rel)]
    return {
        "cache_key": ref.cache_key,
        "quantity": ref.quantity,
        "integrator": ref.integrator,
        "integrator_reason": ref.integrator_reason,
        "variant": variant,
        "spp": ref.spp,
        "passes": ref.passes,
        "mean_rel_stderr": float(np.mean(rel)) if rel.size else 0.0,
        "samples_per_second": float(mask.sum() * ref.spp / ref.seconds) if ref.seconds > 0 else None,
    }
