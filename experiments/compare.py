"""``rtfit compare``: audit the frames a user's own engine rendered against the path-traced reference of the
same Mitsuba XML scene (issue 36).

    rtfit compare SCENE.xml FRAME.exr [FRAME2.exr[:layer] | FRAME.png …] [--quantity radiance|direct]
                  [--aov depth=D.exr] [--fit-exposure] [--spp N] [--out DIR] …

The reference is the scene's own sensor at the frame's resolution (the film's, or the frame's where the two
differ by an integer factor: the field of view is kept), rendered in passes through the pass cache
(`audit_family.pooled_passes`), each sample's ray through a uniform point of its pixel (``footprint="box"``:
the pixel's area average, what an antialiased frame or a box-filtered film holds; ``"centre"``: the pixel
centre, a frame without antialiasing). ``radiance`` is the scene's own integrator, ``direct`` Mitsuba's
``path`` integrator with ``max_depth`` 2 (emission and one bounce of direct light).

Per frame, beside the reference's per-pixel standard error σ: every metric of `rtfit.fitting.compute_metrics`
with its noise floor; the z-scores (frame − reference)/σ; the best global scale s (least squares: frame ≈ s ×
reference) with its standard error, and with ``--fit-exposure`` every metric after dividing the frame by s;
the integer registration offset within ±2 px that minimises the error (after the scale), warned about when it
beats no shift by more than the noise; the error per shape at each pixel's first hit (`first_hit_shapes`).
With a depth AOV, the frame's depth against Mitsuba's first-hit distance (ray distance or planar depth,
whichever the frame holds): the fraction of pixels misaligned, and a one-line refusal when the camera clearly
does not match (the depth matches upside down or mirrored, or not at all). The report, results.json, figures
and the viewer's pixels are written as for ``rtfit audit`` (`audit_output.case_figures`, `save_pixels`,
`report.write_report`).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import ALL_METRICS
from rtfit.reference.cache import default_cache_dir
from rtfit.reference.estimators import PassResult, first_hit_shapes, gbuffer, radiance_pass
from rtfit.reference.mitsuba_xml import XMLSceneError, loaded_xml
from rtfit.reference.variants import resolve_variant

from .atomic import atomic_directory, writable_problem
from .audit import AuditError, SceneInfo, inspect_scene
from .audit_family import AuditReference, AuditSetup, FamilyCase, pooled_passes
from .audit_output import case_figures, save_pixels
from .compare_aovs import DEPTH_TOLERANCE, align_aovs, parse_aovs, read_aovs
from .compare_checks import (
    FrameAnalysis,
    analyse_frame,
    distance_bands,
    frame_checks,
    group_labels,
    shape_table,
    z_figure,
)
from .compare_frames import Frame, frame_id, read_frame
from .records import SCHEMA, Results, from_json, plain_json, to_json
from .registry import LIMITS
from .report import write_report
from .results import write_results
from .runner import created_now, device_description, versions

__all__ = [
    "FOOTPRINTS",
    "QUANTITIES",
    "CompareResult",
    "FrameOutcome",
    "compare",
    "parse_aovs",
    "render_size",
]

log = logging.getLogger(__name__)

QUANTITIES = {
    "radiance": "radiance along each camera ray, W·m⁻²·sr⁻¹ per RGB channel (the scene's own integrator)",
    "direct": "emitted plus directly lit radiance, W·m⁻²·sr⁻¹ (Mitsuba's path integrator, max_depth 2)",
}
"""The quantities ``--quantity`` renders a reference of (issue 36 also names irradiance, AO,
transmittance)."""
FOOTPRINTS = ("box", "centre")
DEFAULT_SPP = 256
DEFAULT_PASS_SPP = 32
FORMAT = 1
"""Part of the reference's cache key: bump it when what a pass holds changes."""


@dataclass
class FrameOutcome:
    """One compared frame (a row of the report): ``id`` (its ``approximations[].method``), ``label``,
    ``frame`` as read, ``image`` as compared (divided by the scale with ``--fit-exposure``), its
    `FrameAnalysis` (scale, offset, metrics, z-scores, per-shape errors, verdict) and ``aovs`` (each AOV's
    alignment with the scene's first hits)."""

    id: str
    label: str
    frame: Frame
    image: np.ndarray
    analysis: FrameAnalysis
    aovs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    fit: None = None  # (read by audit_output: a frame has no fitted parameters)


@dataclass
class CompareResult:
    """What `compare` returns: ``info`` (the scene's inspection), ``reference`` (`AuditReference`), ``frames``
    (`FrameOutcome` in the order given), ``shapes`` (shape index → name), ``results`` (the `Results` record
    written as results.json), ``out`` (the report's directory, or None) and ``timings`` (seconds)."""

    info: SceneInfo
    reference: AuditReference
    frames: list[FrameOutcome]
    shapes: dict[int, str]
    mask: np.ndarray
    quantity: str
    results: Results | None = None
    out: Path | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def cases(self) -> list[FamilyCase]:  # (the audit's writers read one case: the reference and its rows)
        case = FamilyCase(
            id=self.quantity,
            label=f"{self.quantity} of {Path(self.info.source).name}",
            reference=self.reference,
            mask=self.mask,
            channel_inputs=(),
        )
        return [case]

    @property
    def outcomes(self) -> dict[str, dict[str, FrameOutcome]]:
        return {self.quantity: {f.id: f for f in self.frames}}

    def frame(self, name: str) -> FrameOutcome:
        """The outcome of frame ``name`` (its id, its file name or the text it was given as)."""
        for f in self.frames:
            if name in (f.id, f.frame.source, f.frame.path.name):
                return f
        raise KeyError(f"no frame {name!r}; frames: {[f.id for f in self.frames]}")

    def write_report(self, directory) -> Path:
        """results.json, report.{md,html}, tables.tex, figures and the viewer's pixels into ``directory``
        (replaced atomically)."""
        directory = Path(directory)
        with atomic_directory(directory) as tmp:
            _write(Path(tmp), self)
        self.out = directory
        return directory


def render_size(film: tuple[int, int], frame: tuple[int, int], source: str) -> tuple[int, int]:
    """The (width, height) the reference is rendered at: the film's when the frame has it, else the frame's
    where each side is the film's times or divided by one integer factor; `AuditError` otherwise."""
    (fw, fh), (w, h) = film, frame
    if (w, h) == (fw, fh):
        return fw, fh
    for big, small in (((w, h), (fw, fh)), ((fw, fh), (w, h))):
        if big[0] % small[0] == 0 and big[0] // small[0] == big[1] // small[1] and big[1] % small[1] == 0:
            return w, h
    raise AuditError(
        f"frame {source}: {w}×{h} pixels, the scene's film is {fw}×{fh}: not one integer factor apart "
        "(render the frame at the film's size or an integer multiple of it)"
    )


def compare(
    scene,
    frames: Sequence[str] | str,
    *,
    quantity: str = "radiance",
    spp: int | None = None,
    pass_spp: int | None = None,
    variant: str | None = None,
    out=None,
    cache=None,
    seed: int = 0,
    defines: Mapping[str, str] | None = None,
    camera: int = 0,
    fit_exposure: bool = False,
    aov: Sequence[str] | str | None = None,
    footprint: str = "box",
    metrics: Sequence[str] = ALL_METRICS,
    progress: bool = False,
    say=None,
) -> CompareResult:
    """Compare ``frames`` (paths, ``FRAME.exr:layer``) with the reference of ``quantity`` for the Mitsuba XML
    ``scene``'s sensor ``camera`` (module docstring). Returns a `CompareResult`; with ``out`` also writes the
    report to ``out/compare-<scene>``. Bad input raises `AuditError` (one line) before anything renders."""
    say = say or log.info
    t0 = time.perf_counter()
    if quantity not in QUANTITIES:
        raise AuditError(f"--quantity {quantity}: expected one of {', '.join(QUANTITIES)} (others: issue 36)")
    if footprint not in FOOTPRINTS:
        raise AuditError(f"--footprint {footprint}: expected one of {', '.join(FOOTPRINTS)}")
    try:
        variant = resolve_variant(variant or "llvm_ad_rgb")
    except ValueError as e:
        raise AuditError(f"--variant: {e}") from None
    if variant.startswith("scalar"):
        raise AuditError(
            f"--variant {variant}: compare needs a vectorised variant (llvm_ad_rgb, cuda_ad_rgb)"
        )
    spp = int(spp or DEFAULT_SPP)
    pass_spp = int(pass_spp or min(DEFAULT_PASS_SPP, spp))
    if spp < 2 or pass_spp < 2:
        raise AuditError(f"--spp {spp}: at least 2 samples per pixel (the variance needs two)")
    try:
        LIMITS["spp"].check("--spp", spp)
        LIMITS["passes"].check(f"--spp {spp} / --pass-spp {pass_spp} =", -(-spp // pass_spp))
    except ValueError as e:
        raise AuditError(str(e)) from None
    texts = [frames] if isinstance(frames, str | Path) else list(frames)
    if not texts:
        raise AuditError("no frame to compare (rtfit compare SCENE.xml FRAME.exr …)")
    read = [read_frame(str(t)) for t in texts]
    size = read[0].image.shape[1::-1]
    for f in read[1:]:
        if f.image.shape[1::-1] != size:
            raise AuditError(
                f"frame {f.source}: {f.image.shape[1]}×{f.image.shape[0]}, the first frame is "
                f"{size[0]}×{size[1]} (one size per comparison)"
            )
    aovs = parse_aovs(aov)
    aov_data = read_aovs(aovs, read[0].image.shape[:2])
    path = Path(str(scene))
    if path.suffix.lower() != ".xml":
        raise AuditError(
            f"{scene}: rtfit compare reads a Mitsuba XML scene (.xml), whose sensor the frame shows"
        )
    info = inspect_scene(str(path), defines=defines, camera=camera)
    cam = info.xml.camera if info.xml is not None else None
    if cam is None:
        raise AuditError(f"{scene}: the scene has no <sensor> (the frame must show the scene's own view)")
    width, height = render_size(
        (int(cam.width), int(cam.height)), (int(size[0]), int(size[1])), read[0].source
    )
    try:
        for side in (width, height):
            LIMITS["resolution"].check(f"frame {read[0].source}: its size", side)
    except ValueError as e:
        raise AuditError(str(e)) from None
    target = None
    if out is not None:
        target = Path(out) / f"compare-{re.sub(r'[^A-Za-z0-9_.-]+', '-', path.stem) or 'scene'}"
        _writable(target, "--out")
    cache_root = Path(cache) if cache is not None else default_cache_dir()
    _writable(cache_root, "--cache")
    timings: dict[str, float] = {}
    try:
        with loaded_xml(path, defines, variant, camera=camera, width=width, height=height) as loaded:
            mi, mi_scene, sensor = loaded.mi, loaded.scene, loaded.sensor
            gb = gbuffer(mi, mi_scene, sensor)
            hits = first_hit_shapes(mi, mi_scene, sensor)
            names = {i: _shape_name(s) for i, s in enumerate(mi_scene.shapes())}
            groups = {
                "BSDF at the first hit": group_labels(hits, _bsdf_names(list(mi_scene.shapes()), names)),
                "first-hit distance band": distance_bands(gb.depth),
            }
            alignment = align_aovs(aovs, aov_data, gb, cam.x_fov_deg)  # refused here, before rendering
            timings["setup"] = time.perf_counter() - t0
            plan = f"{width}×{height}, {spp} spp in passes of {pass_spp}"
            say(f"camera: {info.camera}; reference {quantity} at {plan}")
            t1 = time.perf_counter()
            reference = _reference(
                mi,
                mi_scene,
                sensor,
                info,
                gb,
                quantity,
                footprint,
                cache_root,
                variant,
                spp,
                pass_spp,
                seed,
                progress,
                camera,
                (width, height),
            )
            timings["reference"] = time.perf_counter() - t1
    except XMLSceneError as e:
        raise AuditError(str(e)) from None
    t2 = time.perf_counter()
    mask = np.ones(gb.mask.shape, bool)
    taken: set[str] = set()
    outcomes = []
    for f in read:
        sigma = reference.sigma()
        if f.precision is not None:  # the frame format's own rounding joins the reference's noise
            sigma = np.sqrt(sigma**2 + f.precision**2)
        a = analyse_frame(
            f.image,
            reference.mean,
            sigma,
            mask,
            hits,
            names,
            fit_exposure,
            tuple(metrics),
            seed,
            groups,
        )
        image = f.image / a.scale if fit_exposure and a.scale > 0 else f.image
        outcomes.append(
            FrameOutcome(
                frame_id(f, taken), f.path.name + (f":{f.layer}" if f.layer else ""), f, image, a, alignment
            )
        )
    timings["comparison"] = time.perf_counter() - t2
    result = CompareResult(info, reference, outcomes, names, mask, quantity, timings=timings)
    result.results = _results(
        result,
        variant=variant,
        spp=spp,
        pass_spp=pass_spp,
        seed=seed,
        fit_exposure=fit_exposure,
        footprint=footprint,
    )
    if target is not None:
        result.write_report(target)
    return result


def _writable(path: Path, option: str) -> None:
    problem = writable_problem(path)
    if problem is not None:
        raise AuditError(f"{option} {path}: {problem}")


def _shape_name(shape) -> str:
    sid = str(shape.id())
    bsdf = shape.bsdf()
    b = str(bsdf.id()) if bsdf is not None else ""
    if sid and not sid.startswith("_unnamed"):
        name = sid
    else:  # unnamed: its type and the centre of its bounding box (stable; the shapes' order is not)
        c = shape.bbox().center()
        name = f"{_class_name(shape)} at ({float(c[0]):.3g}, {float(c[1]):.3g}, {float(c[2]):.3g})"
    return name + (f" [bsdf {b}]" if b and not b.startswith("_unnamed") else "")


def _class_name(obj) -> str:
    name = getattr(obj, "class_name", None)
    return str(name()) if callable(name) else type(obj).__name__


def _bsdf_names(shapes, names: dict[int, str]) -> dict[int, str]:
    """Shape index → its BSDF's name: the XML id, or (unnamed) its type and the shapes sharing one such BSDF
    (equal type and parameters)."""
    keys: dict[int, object] = {}
    for i, shape in enumerate(shapes):
        bsdf = shape.bsdf()
        b = "" if bsdf is None else str(bsdf.id())
        keys[i] = b if b and not b.startswith("_unnamed") else ("", str(bsdf) if bsdf is not None else "none")
    out = {}
    for i, key in keys.items():
        kind = "none" if shapes[i].bsdf() is None else _class_name(shapes[i].bsdf())
        if isinstance(key, str):
            out[i] = f"{key} ({kind})"
        else:
            users = [names[k].split(" [bsdf")[0] for k, other in keys.items() if other == key]
            out[i] = f"{kind} of {', '.join(users)}"
    return out


def _reference(
    mi,
    mi_scene,
    sensor,
    info,
    gb,
    quantity,
    footprint,
    cache_root,
    variant,
    spp,
    pass_spp,
    seed,
    progress,
    camera,
    size,
) -> AuditReference:
    """The reference of ``quantity`` through the pass cache (`pooled_passes`), every pixel an element."""
    integrator = None
    name, reason = "the scene's own", "the scene's integrator: radiance as the scene declares it"
    if quantity == "direct":
        integrator = mi.load_dict({"type": "path", "max_depth": 2})
        name, reason = "path (max_depth 2)", "direct light only: emission and one bounce"
    xml = info.xml
    digest = f"{xml.dependencies.digest}:camera{camera}:{size[0]}x{size[1]}"
    mask = np.ones(gb.mask.shape, bool)
    setup = AuditSetup(
        mi=mi,
        scene=mi_scene,
        sensor=sensor,
        emitters=(),
        info=info,
        gbuffer=gb,
        mask=mask,
        cache_root=cache_root,
        variant=variant,
        spp=spp,
        pass_spp=pass_spp,
        seed=int(seed),
        progress=progress,
        scene_digest=digest,
    )

    def render(n: int, s: int) -> PassResult:
        p = radiance_pass(mi, mi_scene, n, s, integrator=integrator, sensor=sensor, footprint=footprint)
        return PassResult(p.mean.reshape(-1, 3), p.var.reshape(-1, 3), p.spp, p.seed, p.seconds)

    what = {"format": FORMAT, "kind": "compare", "quantity": quantity, "footprint": footprint}
    pooled = pooled_passes(setup, what, render, (-1, 3), f"compare: {quantity}")
    return pooled.reference(mask, QUANTITIES[quantity], name, reason + f"; pixel footprint: {footprint}")


def _results(r: CompareResult, *, variant, spp, pass_spp, seed, fit_exposure, footprint) -> Results:
    info, ref = r.info, r.reference
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = ref.stderr / np.abs(ref.mean)
    rel = rel[np.isfinite(rel)]
    rows = []
    for f in r.frames:
        a = f.analysis
        rows.append(
            {
                "method": f.id,
                "label": f.label,
                "fitted": fit_exposure,
                "parameters": {
                    "scale": a.scale,
                    "scale_stderr": a.scale_stderr,
                    "offset_x": float(a.offset[0]),
                    "offset_y": float(a.offset[1]),
                },
                "metrics": a.metrics.to_dict(),
            }
        )
    case = {
        "id": r.quantity,
        "label": f"{r.quantity} of {Path(info.source).name}",
        "parameters": {"width": int(r.mask.shape[1]), "height": int(r.mask.shape[0]), "footprint": footprint},
        "scene": {"name": Path(info.source).name, "hash": info.xml.dependencies.digest if info.xml else None},
        "reference": {
            "cache_key": ref.cache_key,
            "quantity": ref.quantity,
            "integrator": ref.integrator,
            "integrator_reason": ref.integrator_reason,
            "variant": variant,
            "spp": ref.spp,
            "passes": ref.passes,
            "mean_rel_stderr": float(np.mean(rel)) if rel.size else 0.0,
            "samples_per_second": float(r.mask.size * ref.spp / ref.seconds) if ref.seconds > 0 else None,
        },
        "approximations": rows,
    }
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
        }
    ]
    for f in r.frames:
        a = f.analysis
        lines = [f"`{f.frame.source}`: {f.frame.encoding}.", "", *a.lines, ""]
        lines += [f"{name.capitalize()} AOV: {a['text']}\n" for name, a in f.aovs.items()]
        lines += shape_table(a.shapes)
        for title, errors in a.groups.items():
            lines += ["", *shape_table(errors, title)]
        sections.append({"id": f"frame-{f.id}", "title": f"Frame: {f.label}", "text": "\n".join(lines)})
    notes = [
        f"The reference is {ref.quantity}, {ref.spp} spp per pixel in {ref.passes} passes; each sample's "
        "ray goes "
        + (
            "through a uniform point of its pixel (the pixel's area average: a box-filtered or antialiased "
            "frame)."
            if footprint == "box"
            else "through the pixel centre (a frame without antialiasing)."
        ),
        "Metrics are noise-floored against the reference's standard error only: a frame's own noise (a "
        "frame path-traced at few samples) shows as error.",
        "The scale s is the least-squares factor frame ≈ s × reference; "
        + (
            "the metrics are of frame / s (--fit-exposure)."
            if fit_exposure
            else "the metrics are of the frame as given (--fit-exposure compares after the scale)."
        ),
    ]
    checks = [c for f in r.frames for c in frame_checks(f.label, f.analysis)]
    summary = "; ".join(f"{f.label}: {f.analysis.verdict}" for f in r.frames) + "."
    doc = {
        "schema": SCHEMA,
        "experiment": "compare",
        "title": f"Frames against the reference of {Path(info.source).name}",
        "created": created_now(),
        "versions": versions(),
        "device": device_description(variant),
        "summary": summary,
        "config": {
            "variant": variant,
            "spp": spp,
            "seed": int(seed),
            "extra": {
                "scene": info.source,
                "frames": [f.frame.source for f in r.frames],
                "quantity": r.quantity,
                "pass_spp": pass_spp,
                "fit_exposure": bool(fit_exposure),
                "footprint": footprint,
                "depth_tolerance": DEPTH_TOLERANCE,
                "timings_s": {k: round(v, 3) for k, v in r.timings.items()},
            },
        },
        "sections": sections,
        "cases": [case],
        "checks": checks,
        "notes": notes,
    }
    return from_json(Results, plain_json(doc), f"compare of {info.source}")


def _write(directory: Path, r: CompareResult) -> None:
    """Figures (the audit's reference/frame/error and ꟻLIP panels, plus each frame's z-score map), the
    viewer's pixels, results.json and the report."""
    assert r.results is not None
    figs = case_figures(directory, r)
    for f in figs:
        f.pop("_case", None)
    for f in r.frames:
        name = f"figures/{f.id}_z.png"
        z_figure(directory / name, f.analysis, f.label)
        figs.append(
            {
                "file": name,
                "section": "results",
                "caption": f"{f.label}: z-score (frame − reference)/σ per pixel (mean over RGB), clipped at "
                "±6; black lines: the outlines of the shapes at the pixels' first hits.",
            }
        )
    doc = plain_json(to_json(r.results))
    assert isinstance(doc, dict)
    doc["figures"] = figs
    r.results = from_json(Results, doc, f"compare of {r.info.source}")
    save_pixels(directory, r)
    write_results(directory, r.results)
    write_report(directory)
