"""The files of ``rtfit compare`` (`rtfit.experiments.compare`): the results record (rtfit.results/1: one case
per reference, i.e. per camera, whose rows are its frames), the temporal stability of a sequence, and the
writing of results.json, the report, figures and the viewer's pixels as an audit writes them
(`audit_output.case_figures`, `save_pixels`, `report.write_report`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .audit_output import case_figures, reference_record, save_pixels
from .compare_aovs import DEPTH_TOLERANCE
from .compare_checks import frame_checks, shape_table, z_figure
from .records import SCHEMA, Check, Results, from_json, plain_json, to_json
from .report import write_report
from .results import write_results
from .runner import created_now, device_description, versions

__all__ = ["FLICKER_FACTOR", "results_record", "temporal_stability", "write_compare"]

CompareResult = Any
"""A `compare.CompareResult` (not imported: compare imports this module)."""
FLICKER_FACTOR = 2.0
"""A step of a sequence flickers when its error changes by more than this many times its noise floor."""


def temporal_stability(r: CompareResult) -> list[dict]:
    """Per step i−1 → i of the frames (in the order given): the RMS change of the error (frame − reference)
    ``error_change``, its noise floor √(mean(σ²ᵢ₋₁ + σ²ᵢ)) (the change two exact frames could show against two
    independent references; an upper bound, as the references share their random numbers), the RMS change of
    the reference ``reference_change`` (the scene's own change) and whether the error's change stays within
    `FLICKER_FACTOR` floors (``stable``)."""
    out = []
    for a, b in zip(r.frames, r.frames[1:], strict=False):
        ra, rb = r.reference_of(a), r.reference_of(b)
        ea, eb = a.image - ra.mean, b.image - rb.mean
        change = float(np.sqrt(np.mean((eb - ea) ** 2)))
        floor = float(np.sqrt(np.mean(ra.sigma() ** 2 + rb.sigma() ** 2)))
        ref_change = float(np.sqrt(np.mean((rb.mean - ra.mean) ** 2)))
        stable = change <= FLICKER_FACTOR * floor
        out.append(
            {
                "from": a.label,
                "to": b.label,
                "error_change": change,
                "noise_floor": floor,
                "reference_change": ref_change,
                "stable": stable,
            }
        )
    return out


def _case_doc(r: CompareResult, case, variant: str, fit_exposure: bool, footprint: str) -> dict:
    info = r.info
    rows = []
    for f in r.outcomes[case.id].values():
        a = f.analysis
        params = {
            "scale": a.scale,
            "scale_stderr": a.scale_stderr,
            "offset_x": float(a.offset[0]),
            "offset_y": float(a.offset[1]),
        }
        split = f.aovs.get("albedo", {}).get("split", {})
        if "error" in split:  # the albedo AOV's split of the error (compare_albedo.albedo_split)
            params.update({f"{k}_error": split[k] for k in ("albedo", "lighting")})
            params["lighting_error_stderr"] = split["lighting_uncertainty"]
        rows.append(
            {
                "method": f.id,
                "label": f.label,
                "fitted": fit_exposure,
                "parameters": params,
                "metrics": a.metrics.to_dict(),
            }
        )
    return {
        "id": case.id,
        "label": case.label,
        "parameters": {
            "width": int(case.mask.shape[1]),
            "height": int(case.mask.shape[0]),
            "footprint": footprint,
            "camera": r.camera_of_case[case.id],
            **({"pose": r.pose_of_case[case.id]} if case.id in r.pose_of_case else {}),
        },
        "scene": {"name": Path(info.source).name, "hash": info.xml.dependencies.digest if info.xml else None},
        "reference": reference_record(case.reference, variant, np.ones(case.mask.shape, bool)),  # every pixel
        "approximations": rows,
    }


def _frame_section(f) -> dict:
    a = f.analysis
    lines = [f"`{f.frame.source}`: {f.frame.encoding}.", "", *a.lines, ""]
    lines += [f"{name.capitalize()} AOV: {al['text']}\n" for name, al in f.aovs.items()]
    lines += shape_table(a.shapes)
    for title, errors in a.groups.items():
        lines += ["", *shape_table(errors, title)]
    return {"id": f"frame-{f.id}", "title": f"Frame: {f.label}", "text": "\n".join(lines)}


def _temporal_section(steps: list[dict]) -> dict:
    rows = [
        "| step | error change (RMS) | its noise floor | reference change (RMS) | |",
        "|---|---:|---:|---:|---|",
    ]
    rows += [
        f"| {s['from']} → {s['to']} | {s['error_change']:.4g} | {s['noise_floor']:.2g} | "
        f"{s['reference_change']:.4g} | {'stable' if s['stable'] else '**flickers**'} |"
        for s in steps
    ]
    text = (
        "The frame-to-frame change of the error (frame − reference) beside its noise floor (the change two "
        "exact frames would show against two independent references) and the change of the reference itself: "
        f"a step whose error changes by more than {FLICKER_FACTOR:g} floors flickers (probes, shadow maps or "
        "temporal filters that do not hold still).\n\n" + "\n".join(rows)
    )
    return {"id": "temporal", "title": "Temporal stability", "text": text}


def _breakdowns(a) -> dict:
    """Each frame's error per shape and per group (BSDF, distance band, n·l band): title → rows."""
    groups = {"shape at the first hit": a.shapes, **a.groups}
    return {
        title: [
            {
                "name": e.name,
                "pixels": e.pixels,
                "reference_mean": e.reference_mean,
                "bias": e.bias,
                "uncertainty": e.uncertainty,
                "z_rms": e.z_rms,
                "within_noise": e.within_noise,
            }
            for e in errors
        ]
        for title, errors in groups.items()
    }


def results_record(r: CompareResult, *, variant, spp, pass_spp, seed, fit_exposure, footprint) -> Results:
    """The `Results` record of a comparison ``r`` (module docstring)."""
    info = r.info
    ref = r.cases[0].reference
    cases = [_case_doc(r, c, variant, fit_exposure, footprint) for c in r.cases]
    scene_text = [
        f"`{info.source}` ({info.format})",
        *info.contents,
        f"Camera: {info.camera}.",
        f"Up: {info.up_reason}.",
    ]
    sections = [{"id": "scene", "title": "Scene", "text": "\n\n".join(scene_text)}]
    sections += [_frame_section(f) for f in r.frames]
    checks = [c for f in r.frames for c in frame_checks(f.label, f.analysis)]
    if r.temporal:
        sections.append(_temporal_section(r.temporal))
        checks += [
            Check(
                name=f"temporal stability {s['from']} → {s['to']}",
                value=s["error_change"],
                expected=f"≤ {FLICKER_FACTOR:g} × {s['noise_floor']:.2g}",
                passed=bool(s["stable"]),
            )
            for s in r.temporal
        ]
    box = "through a uniform point of its pixel (the pixel's area average: a box-filtered or antialiased "
    box += "frame)."
    notes = [
        f"The reference is {ref.quantity}, {ref.spp} spp per pixel in {ref.passes} passes; each sample's ray "
        "goes " + (box if footprint == "box" else "through the pixel centre (a frame without antialiasing)."),
        "Metrics are noise-floored against the reference's standard error and the frame format's own steps: "
        "a frame's own noise (a frame path-traced at few samples) shows as error.",
        "The scale s is the least-squares factor frame ≈ s × reference; "
        + (
            "the metrics are of frame / s (--fit-exposure)."
            if fit_exposure
            else "the metrics are of the frame as given (--fit-exposure compares after the scale)."
        ),
    ]
    summary = "; ".join(f"{f.label}: {f.analysis.verdict}" for f in r.frames)
    flicker = [s for s in r.temporal if not s["stable"]]
    if flicker:
        summary += "; flickers at " + ", ".join(f"{s['from']} → {s['to']}" for s in flicker)
    extra = {
        "scene": info.source,
        "frames": [f.frame.source for f in r.frames],
        "quantity": r.quantity,
        "pass_spp": pass_spp,
        "fit_exposure": bool(fit_exposure),
        "footprint": footprint,
        "camera_path": r.camera_path,
        "depth_tolerance": DEPTH_TOLERANCE,
        "timings_s": {k: round(v, 3) for k, v in r.timings.items()},
    }
    doc = {
        "schema": SCHEMA,
        "experiment": "compare",
        "title": f"Frames against the reference of {Path(info.source).name}",
        "created": created_now(),
        "versions": versions(),
        "device": device_description(variant),
        "summary": summary + ".",
        "config": {"variant": variant, "spp": spp, "seed": int(seed), "extra": extra},
        "sections": sections,
        "cases": cases,
        "checks": [to_json(c) for c in checks],
        "notes": notes,
        "breakdowns": {f.id: _breakdowns(f.analysis) for f in r.frames},
    }
    return from_json(Results, plain_json(doc), f"compare of {info.source}")


def write_compare(directory: Path, r: CompareResult) -> None:
    """Figures (the audit's reference/frame/error and ꟻLIP panels per case, plus each frame's z-score map),
    the viewer's pixels, results.json and the report, into ``directory``."""
    assert r.results is not None
    figs = case_figures(directory, r)
    for f in figs:
        f.pop("_case", None)
    for f in r.frames:
        name = f"figures/{f.id}_z.png"
        z_figure(directory / name, f.analysis, f.label)
        caption = (
            f"{f.label}: z-score (frame − reference)/σ per pixel (mean over RGB), clipped at ±6; black "
            "lines: the outlines of the shapes at the pixels' first hits."
        )
        figs.append({"file": name, "section": "results", "caption": caption})
    doc = plain_json(to_json(r.results))
    assert isinstance(doc, dict)
    doc["figures"] = figs
    r.results = from_json(Results, doc, f"compare of {r.info.source}")
    save_pixels(directory, r)
    write_results(directory, r.results)
    write_report(directory)
