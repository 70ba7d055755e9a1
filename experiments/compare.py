"""``rtfit compare``: audit the frames a user's own engine rendered against the path-traced reference of the
same Mitsuba XML scene (issue 36).

    rtfit compare SCENE.xml FRAME.exr [FRAME2.exr[:layer] | FRAME.png …] [--quantity radiance|direct]
                  [--aov depth=D.exr,normal=N.exr] [--fit-exposure] [--camera-path sensors] [--spp N] …

The reference is the scene's own sensor at the frame's resolution (the film's, or the frame's where the two
differ by an integer factor: the field of view is kept), rendered in passes through the pass cache
(`audit_setup.pooled_passes`), each sample's ray through a uniform point of its pixel (``footprint="box"``:
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
`report.write_report`: `compare_report`). A sequence (``camera_path="sensors"``: frame i through sensor
i, one reference each; ``"static"``: one sensor) has the frame-to-frame change of its error beside its noise
floor (`compare_report.temporal_stability`).
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
from rtfit.reference.estimators import PassResult, first_hit_shapes, gbuffer, radiance_pass
from rtfit.reference.mitsuba_xml import UP_AXES, XMLSceneError, loaded_xml

from .atomic import atomic_directory, writable_problem
from .audit import AuditError, SceneInfo, inspect_scene
from .audit_family import FamilyCase
from .audit_setup import AuditReference, pooled_passes
from .compare_albedo import albedo_split
from .compare_aovs import align_aovs, parse_aovs, read_aovs
from .compare_checks import (
    FrameAnalysis,
    analyse_frame,
    distance_bands,
    group_labels,
    unsampled_outline_sigma,
)
from .compare_frames import Frame, frame_id, read_frame
from .compare_light import main_light, nl_bands
from .compare_poses import Pose, apply_pose, read_poses
from .compare_quantities import SURFACE_QUANTITIES, quantity_reference, refusal
from .compare_report import results_record, temporal_stability, write_compare
from .records import Results
from .registry import LIMITS
from .run_settings import RunSettings

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
    **SURFACE_QUANTITIES,
}
"""The quantities ``--quantity`` renders a reference of (the last three: `compare_quantities`)."""
FOOTPRINTS = ("box", "centre")
NL_QUANTITIES = ("radiance", "direct", "irradiance")
"""The quantities broken down per normal-to-light band (`compare_light`): those lit by the lights."""
FORMAT = 1
"""Part of the reference's cache key: bump it when what a pass holds changes."""


@dataclass
class FrameOutcome:
    """One compared frame (a row of the report): ``id`` (its ``approximations[].method``), ``label``,
    ``frame`` as read, ``image`` as compared (divided by the scale with ``--fit-exposure``), its
    `FrameAnalysis` (scale, offset, metrics, z-scores, per-shape errors, verdict), ``aovs`` (each AOV's
    alignment with the scene's first hits) and ``case``: the id of its reference (its camera's)."""

    id: str
    label: str
    frame: Frame
    image: np.ndarray
    analysis: FrameAnalysis
    aovs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    case: str = ""
    fit: None = None  # (read by audit_output: a frame has no fitted parameters)


@dataclass
class CompareResult:
    """What `compare` returns: ``info`` (the scene's inspection, first camera), ``references`` (case id →
    `AuditReference`: one per camera), ``frames`` (`FrameOutcome` in the order given), ``shapes`` (shape
    index → name), ``temporal`` (`compare_report.temporal_stability` of two frames or more), ``results`` (the
    `Results` record written as results.json), ``out`` (the report's directory, or None) and ``timings``;
    ``mask``: the compared pixels of the last camera (the only one without ``camera_path``; each case's own
    are its reference's, `AuditReference.mask`)."""

    info: SceneInfo
    references: dict[str, AuditReference]
    frames: list[FrameOutcome]
    shapes: dict[int, str]
    mask: np.ndarray
    quantity: str
    camera_of_case: dict[str, int] = field(default_factory=dict)
    camera_path: str | None = None
    pose_of_case: dict[str, int] = field(default_factory=dict)
    """Case id → the index of its pose in ``--camera-path poses.json`` (`compare_poses`)."""
    temporal: list[dict] = field(default_factory=list)
    results: Results | None = None
    out: Path | None = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def reference(self) -> AuditReference:
        """The reference of the first camera (the only one without ``camera_path``)."""
        return next(iter(self.references.values()))

    def reference_of(self, frame: FrameOutcome) -> AuditReference:
        return self.references[frame.case]

    @property
    def cases(self) -> list[FamilyCase]:  # (the audit's writers read cases: a reference and its rows)
        name = Path(self.info.source).name
        return [
            FamilyCase(
                id=cid,
                label=f"{self.quantity} of {name}"
                + (
                    f", pose {self.pose_of_case[cid]}"
                    if cid in self.pose_of_case
                    else f", camera {self.camera_of_case[cid]}"
                    if len(self.references) > 1
                    else ""
                ),
                reference=ref,  # with its own camera's mask (each camera sees its own pixels)
                channel_inputs=(),
            )
            for cid, ref in self.references.items()
        ]

    @property
    def outcomes(self) -> dict[str, dict[str, FrameOutcome]]:
        return {cid: {f.id: f for f in self.frames if f.case == cid} for cid in self.references}

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
            write_compare(Path(tmp), self)
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
    camera_path: str | None = None,
    ao_radius: float = float("inf"),
    progress: bool = False,
    say=None,
) -> CompareResult:
    """Compare ``frames`` (paths, ``FRAME.exr:layer``) with the reference of ``quantity`` for the Mitsuba XML
    ``scene``'s sensor ``camera`` (module docstring). ``camera_path``: the frames are a sequence, with its
    temporal stability: ``"sensors"``: frame i through the scene's sensor i (one reference per
    frame); ``"static"``: every frame through ``camera`` (one reference). Returns a `CompareResult`; with
    ``out`` also writes the report to ``out/compare-<scene>``. Bad input raises `AuditError` (one line) before
    anything renders."""
    say = say or log.info
    t0 = time.perf_counter()
    if quantity not in QUANTITIES:
        raise AuditError(f"--quantity {quantity}: expected one of {', '.join(QUANTITIES)}")
    if footprint not in FOOTPRINTS:
        raise AuditError(f"--footprint {footprint}: expected one of {', '.join(FOOTPRINTS)}")
    run = RunSettings.checked(
        variant=variant, spp=spp, pass_spp=pass_spp, seed=seed, cache=cache, progress=progress,
        needs="compare needs",
    )  # fmt: skip
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
    posed = camera_path not in (None, "sensors", "static")
    if posed and not str(camera_path).lower().endswith(".json"):
        raise AuditError(
            f"--camera-path {camera_path}: expected 'sensors' (frame i through sensor i), 'static' (every "
            "frame through --camera) or a JSON file of camera poses (poses.json)"
        )
    moving = camera_path == "sensors"
    if (moving or posed) and aovs:
        raise AuditError("--aov with --camera-path: not read yet (one AOV per frame of a sequence)")
    path = Path(str(scene))
    if path.suffix.lower() != ".xml":
        raise AuditError(
            f"{scene}: rtfit compare reads a Mitsuba XML scene (.xml), whose sensor the frame shows"
        )
    cams = list(range(len(read))) if moving else [camera]
    infos = {c: inspect_scene(str(path), defines=defines, camera=c) for c in cams}
    info = infos[cams[0]]
    poses: list[Pose] = []
    if posed:
        up = UP_AXES.get(info.xml.up, (0.0, 0.0, 1.0)) if info.xml is not None else (0.0, 0.0, 1.0)
        poses = read_poses(str(camera_path), len(read), np.asarray(up, np.float64))
    why = refusal(quantity, info, float(ao_radius))
    if why is not None:
        raise AuditError(why)
    if quantity in SURFACE_QUANTITIES:
        footprint = "centre"  # the G-buffer's pixel-centre points and rays
    sizes = set()
    for inf in infos.values():
        cam = inf.xml.camera if inf.xml is not None else None
        if cam is None:
            raise AuditError(f"{scene}: the scene has no <sensor> (the frame must show the scene's own view)")
        sizes.add(
            render_size((int(cam.width), int(cam.height)), (int(size[0]), int(size[1])), read[0].source)
        )
    if len(sizes) > 1:
        raise AuditError(
            f"--camera-path: the sensors' films render the frames at {sorted(sizes)}: one size only"
        )
    width, height = sizes.pop()
    try:
        for side in (width, height):
            LIMITS["resolution"].check(f"frame {read[0].source}: its size", side)
    except ValueError as e:
        raise AuditError(str(e)) from None
    target = None
    if out is not None:
        target = Path(out) / f"compare-{re.sub(r'[^A-Za-z0-9_.-]+', '-', path.stem) or 'scene'}"
        _writable(target, "--out")
    _writable(run.cache_dir, "--cache")
    timings: dict[str, float] = {"setup": 0.0, "reference": 0.0, "comparison": 0.0}
    references: dict[str, AuditReference] = {}
    camera_of_case: dict[str, int] = {}
    pose_of_case: dict[str, int] = {}
    outcomes: list[FrameOutcome] = []
    taken: set[str] = set()
    names: dict[int, str] = {}
    views = list(enumerate(cams)) if moving else [(i, camera) for i in range(len(poses))] or [(None, camera)]
    for vi, c in views:
        pose = poses[vi] if poses and vi is not None else None
        case = quantity if vi is None else f"{quantity}-camera{c}" if moving else f"{quantity}-pose{vi}"
        mine = read if vi is None else [read[vi]]
        t0 = time.perf_counter()
        try:
            with loaded_xml(path, defines, run.variant, camera=c, width=width, height=height) as loaded:
                mi, mi_scene, sensor = loaded.mi, loaded.scene, loaded.sensor
                if pose is not None:
                    apply_pose(mi, sensor, pose, f"--camera-path {camera_path}: {pose.text}")
                    pose_of_case[case] = int(vi)
                gb = gbuffer(mi, mi_scene, sensor)
                hits = first_hit_shapes(mi, mi_scene, sensor)
                shapes = list(mi_scene.shapes())
                names = {i: _shape_name(sh) for i, sh in enumerate(shapes)}
                groups = {
                    "BSDF at the first hit": group_labels(hits, _bsdf_names(shapes, names)),
                    "first-hit distance band": distance_bands(gb.depth),
                }
                light = None
                if quantity in NL_QUANTITIES:
                    emitter_names = _emitter_names(loaded.emitters, infos[c])
                    light = main_light(mi, mi_scene, gb, run.seed, emitter_names)
                if light is not None:
                    share = f"{light.share:.0%} of the unshadowed irradiance"
                    groups[f"n·l band (to the main light: {light.name}, {share})"] = nl_bands(light.nl)
                cam = infos[c].xml.camera
                # refused here, before rendering
                alignment = align_aovs(aovs, aov_data, gb, cam.x_fov_deg, hits, names)
                timings["setup"] += time.perf_counter() - t0
                plan = f"{width}×{height}, {run.spp} spp in passes of {run.pass_spp}"
                view = infos[c].camera if pose is None else f"sensor {c} at {pose.text} of {camera_path}"
                say(f"camera: {view}; reference {quantity} at {plan}")
                t1 = time.perf_counter()
                key = c if pose is None else f"{c}-pose-{pose.digest}"
                references[case], mask = _reference(
                    mi, mi_scene, sensor, infos[c], gb, key, (width, height), quantity, footprint, run,
                    float(ao_radius),
                )  # fmt: skip
                camera_of_case[case] = c
                timings["reference"] += time.perf_counter() - t1
        except XMLSceneError as e:
            raise AuditError(str(e)) from None
        t2 = time.perf_counter()
        reference = references[case]
        base_sigma = reference.sigma()
        if footprint == "box":  # a sliver of another shape that no sample of an outline pixel met
            base_sigma = np.sqrt(base_sigma**2 + unsampled_outline_sigma(reference, hits) ** 2)
        for f in mine:
            sigma = base_sigma
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
                run.seed,
                groups,
            )
            image = f.image / a.scale if fit_exposure and a.scale > 0 else f.image
            label = f.path.name + (f":{f.layer}" if f.layer else "")
            mine_aovs = alignment
            if "albedo" in aov_data and quantity in ("radiance", "direct"):
                split = albedo_split(
                    image, reference.mean, sigma, aov_data["albedo"], gb.albedo, mask, hits, names
                )
                text = alignment["albedo"]["text"] + " Albedo/lighting split: " + split["text"]
                mine_aovs = {**alignment, "albedo": {**alignment["albedo"], "split": split, "text": text}}
            outcomes.append(FrameOutcome(frame_id(f, taken), label, f, image, a, mine_aovs, case))
        timings["comparison"] += time.perf_counter() - t2
    result = CompareResult(
        info, references, outcomes, names, mask, quantity, camera_of_case, camera_path, timings=timings,
        pose_of_case=pose_of_case,
    )  # fmt: skip
    result.temporal = temporal_stability(result) if camera_path and len(outcomes) > 1 else []
    result.results = results_record(
        result, variant=run.variant, spp=run.spp, pass_spp=run.pass_spp, seed=run.seed,
        fit_exposure=fit_exposure, footprint=footprint,
    )  # fmt: skip
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


def _emitter_names(emitters, info) -> dict[str, str]:
    """A loaded emitter's Mitsuba id (`loaded_xml` tags them) → its XML ``id`` and kind (e.g. ``sun
    (directional)``), or its kind and where the file declares it."""
    out = {}
    xml = info.xml.emitters if info.xml is not None else ()
    for em, x in zip(emitters, xml, strict=False):
        if em is None:
            continue
        own = x.id and not x.id.startswith("_unnamed")
        out[str(em.id())] = f"{x.id} ({x.kind})" if own else f"{x.kind} light ({x.location})"
    return out


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
    camera,
    size,
    quantity,
    footprint,
    run: RunSettings,
    ao_radius,
) -> tuple[AuditReference, np.ndarray]:
    """The reference of ``quantity`` through the pass cache (`pooled_passes`) and the mask of the pixels it
    holds: every pixel an element for radiance (`compare_quantities.quantity_reference` for the others)."""
    integrator = None
    name, reason = "the scene's own", "the scene's integrator: radiance as the scene declares it"
    if quantity == "direct":
        integrator = mi.load_dict({"type": "path", "max_depth": 2})
        name, reason = "path (max_depth 2)", "direct light only: emission and one bounce"
    elif mi_scene.integrator() is None:  # no <integrator> in the file: Mitsuba's default, path
        integrator = mi.load_dict({"type": "path"})
        name, reason = "path (Mitsuba's default)", "the scene declares no integrator: Mitsuba's default"
    xml = info.xml
    digest = f"{xml.dependencies.digest}:camera{camera}:{size[0]}x{size[1]}"
    mask = np.ones(gb.mask.shape, bool)
    setup = run.setup(mi, mi_scene, sensor, (), info, gb, mask, digest)

    if quantity in SURFACE_QUANTITIES:
        return quantity_reference(setup, quantity, ao_radius)

    def render(n: int, s: int) -> PassResult:
        p = radiance_pass(mi, mi_scene, n, s, integrator=integrator, sensor=sensor, footprint=footprint)
        return PassResult(p.mean.reshape(-1, 3), p.var.reshape(-1, 3), p.spp, p.seed, p.seconds)

    what = {"format": FORMAT, "kind": "compare", "quantity": quantity, "footprint": footprint}
    pooled = pooled_passes(setup, what, render, (-1, 3), f"compare: {quantity}")
    return pooled.reference(
        mask, QUANTITIES[quantity], name, reason + f"; pixel footprint: {footprint}"
    ), mask
