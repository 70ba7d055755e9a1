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
3. **Evaluation**: every applicable method (and each user approximation of the family's quantity) on the
   same pixels with Dr.Jit (`Method.evaluate`), per RGB channel; every metric with its noise floor
   (`compute_metrics`); the cost per pixel measured on the run's backend (`cost.time_drjit`).
4. **Fits**: each method with free parameters fitted to this scene's reference through the JAX run of its
   kernel text (`fit_method`), with standard errors and bound flags, then evaluated and measured again.
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
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np

from rtfit.fitting import (
    ALL_METRICS,
    compute_metrics,
    concat_z_pairs,
    prime_flip,
    z_checks,
    z_pair,
)
from rtfit.fitting.stats import Z_MEDIAN_TOLERANCE, Z_TAIL_FRACTION
from rtfit.realtime.arrays import Uniforms, backend_float, to_drjit
from rtfit.realtime.methods import Method
from rtfit.realtime.quantities import is_user_approximation
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR, default_cache_dir
from rtfit.reference.estimators import GBuffer, gbuffer, is_pass_through
from rtfit.reference.mitsuba_xml import XMLSceneError, loaded_xml
from rtfit.reference.nishita_sky import hemisphere_directions, load_atmosphere_scene
from rtfit.reference.variants import resolve_variant, scoped_variant
from rtfit.scenes import load_scene, scene_hash

from . import audit_api
from . import fitted as fitfiles
from .applicability import applicable_families
from .atomic import atomic_directory
from .audit import SURFACE_FREE_KINDS, Applicability, AuditError, SceneInfo, inspect_scene
from .audit_family import PRECOMPUTE_TRIGGERS, AuditFamily, AuditSetup, FamilyCase, Precompute
from .audit_fit import evaluate_case, fit_case
from .audit_options import GRID_MAX, check_ao_distance, check_out, check_sizes, triple
from .audit_output import reference_record, write_audit
from .audit_parallax_occlusion import check_pom_depth
from .cost import time_drjit, time_precompute
from .families import AUDITED, METHOD_TABLES, RULES
from .progress import Stage
from .records import SCHEMA, Check, Results, from_json, plain_json, to_json
from .registry import ALIASES, LIMITS
from .runner import created_now, device_description, use_variant_backend, versions
from .user_methods import UserMethodError, check_approximation
from .user_sandbox import load_validated

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


def _wrong_format(a: Applicability, scene_format: str) -> bool:
    """True when `AUDITED` audits the applicability's family and role, but not on scenes of
    ``scene_format``."""
    family = AUDITED.get(a.family)
    if family is None or (family.roles is not None and a.role not in family.roles):
        return False
    return not family.audits(a.role, scene_format)


def _rule_of(a: Applicability):
    """The `RULES` entry that made the applicability ``a`` (its family and role)."""
    return next(r for r in RULES if r.family == a.family and r.role == a.role)


def _audits(a: Applicability, scene_format: str) -> bool:
    """True when `AUDITED` audits the applicability ``a`` (its family, role and the scene's format)."""
    family = AUDITED.get(a.family)
    return family is not None and family.audits(a.role, scene_format)


DEFAULT_SPP = 256
DEFAULT_PASS_SPP = 32
_COST_ELEMENTS = 1 << 20  # inputs are tiled to this many elements for the cost measurement
_COST_INPUT_BYTES = 64 << 20
"""At most this many bytes of tiled per-pixel inputs in a cost measurement (float32, every input together):
far beyond any CPU cache, so the memory traffic is still what is timed. The caustics' splats read 112
per-pixel inputs: at 2^20 elements their tiled copies were 0.9 GB (and as much again on the host), which
lifted the quick suite's peak memory to 3.9 GB (issue 33); they are timed on 2^17 elements now."""


# ----------------------------------------------------------------------------------------- approximations
@dataclass(frozen=True)
class Selection:
    """What ``--approx`` asks for: ``families`` (None: all that apply), ``methods`` (family → shipped method
    ids kept; a family absent here keeps all of its methods) and ``user`` approximations."""

    families: tuple[str, ...] | None
    methods: Mapping[str, frozenset[str]]
    user: tuple[Method, ...]


def _shipped(name: str) -> tuple[str, str] | None:
    """``family:id`` or a bare method id of an audited family → (family, id)."""
    fam, sep, mid = name.partition(":")
    if sep:
        fam = ALIASES.get(fam, fam.replace("_", "-"))
        return (fam, mid) if fam in METHOD_TABLES and mid in METHOD_TABLES[fam] else None
    hits = [(f, name) for f in AUDITED if name in METHOD_TABLES[f]]
    return hits[0] if len(hits) == 1 else None


def resolve_approximations(approximations) -> Selection:
    """``approximations``: None, ``"a,b"``, or a sequence of names, specs and `Method` objects made by
    ``@rtfit.approximation``. A name is a family (``diffuse``), a shipped method (``wrap``, ``diffuse:wrap``,
    ``half-lambert``: a method id wins over a former family name), a user approximation spec
    (``file.py:name``, ``module:name``) or an entry point of ``rtfit.approximations``. Family and method names
    restrict the audit; user approximations are added beside the shipped methods of their quantity's
    families. Each user approximation is validated here. Raises `AuditError` (one line)."""
    if approximations is None:
        return Selection(None, {}, ())
    items = approximations.split(",") if isinstance(approximations, str) else list(approximations)
    if not any(isinstance(i, Method) or str(i).strip() for i in items):  # '' or ',,,': not "everything"
        raise AuditError(
            f"--approx {approximations!r}: names no approximation (leave --approx out to audit everything)"
        )
    families: list[str] = []
    methods: dict[str, set[str]] = {}
    user: list[Method] = []
    validated: set[int] = set()  # user approximations validated already (in a child process)
    for item in items:
        if isinstance(item, Method):
            if not is_user_approximation(item):
                raise AuditError(
                    f"{item.id!r}: not a user approximation (decorate it with @rtfit.approximation)"
                )
            user.append(item)
            continue
        name = str(item).strip()
        if not name:
            continue
        family = name.replace("_", "-")
        if family in METHOD_TABLES:
            families.append(family)
            continue
        # A shipped method before a former family name: "half-lambert" is the diffuse method (a user asking
        # for that row), not the whole diffuse family that the experiment was once called.
        shipped = _shipped(name)
        if shipped is not None:
            methods.setdefault(shipped[0], set()).add(shipped[1])
            continue
        if ALIASES.get(name) in METHOD_TABLES:
            families.append(ALIASES[name])
            continue
        try:
            m = load_validated(name)  # user code: loaded and checked in a child process first
        except UserMethodError as e:
            if e.stage == "missing":  # no such file, module or entry point: maybe a misspelt family
                known = ", ".join(METHOD_TABLES)
                raise AuditError(
                    f"--approx {name!r}: not a family ({known}), a shipped method (e.g. diffuse:wrap) or a "
                    f"user approximation ({e})"
                ) from None
            raise AuditError(str(e)) from None
        user.append(m)
        validated.add(id(m))
    for m in user:
        try:
            if id(m) not in validated:
                check_approximation(m)
        except UserMethodError as e:
            raise AuditError(str(e)) from None
        if not any(m.quantity in (f.quantity, *f.quantities) for f in AUDITED.values()):
            raise AuditError(
                f"{m.id}: approximates {m.quantity}; the audit of that quantity is not built yet "
                f"(audited: {', '.join(f'{f.quantity} ({f.name})' for f in AUDITED.values())})"
            )
    ids = [m.id for m in user]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise AuditError(f"--approx: approximation id {', '.join(dup)} given twice")
    for m in user:
        for fam in AUDITED.values():
            if m.quantity in (fam.quantity, *fam.quantities) and m.id in METHOD_TABLES[fam.name]:
                raise AuditError(f"{m.id}: the id of a shipped {fam.name} method; give it id=… of its own")
    named = list(dict.fromkeys([*families, *methods]))
    if not named and user:
        named = [
            f.name for f in AUDITED.values() if any(m.quantity in (f.quantity, *f.quantities) for m in user)
        ]
    return Selection(tuple(named) or None, {k: frozenset(v) for k, v in methods.items()}, tuple(user))


def selected_applicabilities(
    info: SceneInfo, sel: Selection, ao_distance: float | None
) -> list[Applicability]:
    """What applies to the scene (`applicable_families`) restricted to the selection's families, each
    keeping only the shipped methods ``--approx`` names (where it names any of that family). A named method
    that applies nowhere in the scene is an `AuditError` saying why. The same for ``--list`` and the run."""
    found = applicable_families(info, approx=sel.families, ao_distance=ao_distance)
    for fam, ids in sel.methods.items():
        for mid in sorted(ids):
            if not any(a.family == fam and mid in a.methods for a in found):
                why = next((w for a in found if a.family == fam for m, w in a.excluded if m == mid), "")
                raise AuditError(
                    f"--approx {fam}:{mid} does not apply to {info.source}" + (f": it {why}" if why else "")
                )
    out = []
    for a in found:
        keep = sel.methods.get(a.family)
        if keep is None:
            out.append(a)
        elif any(m in keep for m in a.methods):
            methods = tuple(m for m in a.methods if m in keep)
            out.append(replace(a, methods=methods, excluded=tuple(e for e in a.excluded if e[0] in keep)))
    return out


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
    (`audit_family.StudyContext`)."""
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


_UNIFORM_FLOATS = 1024
"""A table of at most this many floats, where the kernel reads it by index (coefficients: SH L2's 27, L4's
75), is timed as a shader's constant buffer (`rtfit.realtime.arrays.Uniforms`): 256 float4, a uniform array
an engine declares; a larger table (a cube map's 6·16² texels) is a texture, gathered from as it is."""
_COST_PROBE = 1 << 12  # elements of the first, sizing call of a cost measurement
_COST_CALL_SECONDS = 0.05  # the sized call's target duration: a slow kernel is timed on fewer elements
_COST_MIN_SECONDS = 0.05
"""The least time the measured call is repeated for (and at least 7 times; the median is the cost): a kernel
at ~1 ns a pixel is one 1 ms call at 2^20 elements, so 50 ms is ~50 repeats; a slow kernel sized to
`_COST_CALL_SECONDS` a call runs its 7. At 0.2 s, 23 methods spent ~4.6 s of a Cornell-box audit here."""


def _cost(
    method: Method,
    case: FamilyCase,
    backend: str,
    size: int = _COST_ELEMENTS,
    min_seconds: float = _COST_MIN_SECONDS,
) -> dict:
    """ns per pixel of ``method`` (declared parameters) on the backend, its per-pixel inputs (channel 0 of the
    case) tiled to ``size`` float32 elements; a table (an array that is not per pixel) is passed as it is.

    A kernel that would take longer than `_COST_CALL_SECONDS` a call at ``size`` (timed first on
    `_COST_PROBE` elements) is timed on proportionally fewer, never fewer than `_COST_PROBE`: a cone tracer at
    ~10 µs a pixel on 2 CPU cores took 10 s a call on 2^20 elements, 80 s for its 7 repeats + warm-up. The
    sizing call is the median of 7 repeats with no minimum duration (``min_seconds`` 0: it only sizes the
    measured call, which keeps its `_COST_MIN_SECONDS`): 15 methods' sizing calls took 2.9 s of a
    Cornell-box audit's evaluation at 0.2 s each."""
    n = int(case.mask.sum())
    per_pixel = sum(
        1
        for name in method.input_names
        if isinstance(v := case.channel_inputs[0][name], (np.ndarray, np.generic)) and np.size(v) == n > 0
    )
    size = min(size, max(_COST_PROBE, _COST_INPUT_BYTES // (4 * max(per_pixel, 1))))
    if size > _COST_PROBE:
        probe = _cost(method, case, backend, _COST_PROBE, min_seconds=0.0)
        per_element = probe["ns_per_pixel"] * 1e-9
        size = int(min(size, max(_COST_PROBE, _COST_CALL_SECONDS / max(per_element, 1e-15))))
    Float = backend_float(backend)
    reps = max(1, -(-size // max(n, 1)))
    args, host, keys, consts, uniforms = [], [], [], {}, {}
    for name in method.input_names:
        v = case.channel_inputs[0][name]
        if not isinstance(v, (int, float, np.ndarray, np.generic)):  # a sampler object (a distance field)
            consts[name] = v
        elif np.ndim(v) and np.size(v) != n:
            table = np.ascontiguousarray(v, np.float32).reshape(-1)
            consts[name] = to_drjit(Float, table)
            if table.size <= _UNIFORM_FLOATS:
                uniforms[name] = Uniforms.of(table)
        elif np.ndim(v):
            a = np.tile(np.asarray(v, np.float64), reps)[:size]
            a = np.where(np.isfinite(a), a, np.finfo(np.float32).max).astype(np.float32)
            host.append(a[:_COST_PROBE])  # the trial below reads no more
            args.append(to_drjit(Float, a))  # aligned: one compiled kernel whatever NumPy's addresses
            keys.append(name)
        else:
            consts[name] = float(v)
    elements = min(n * reps, size) if keys else 1
    if uniforms:  # a small table read by index, as a shader's constant buffer (`Uniforms`: nothing folded)
        trial = [to_drjit(Float, a) for a in host]  # reads the table by index? (small)
        try:
            dr.eval(method.evaluate({**consts, **uniforms, **dict(zip(keys, trial, strict=True))}))
            consts.update(uniforms)
        except (TypeError, IndexError, AttributeError, RuntimeError):  # a kernel that gathers from it
            pass

    def call(*xs):
        return method.evaluate({**consts, **dict(zip(keys, xs, strict=True))})

    t = time_drjit(call, tuple(args), elements, min_seconds=min_seconds)
    return {**t.to_dict(), "backend": backend}


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
    cost_elements: int = _COST_ELEMENTS,
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
    try:
        variant = resolve_variant(variant or "llvm_ad_rgb")
    except ValueError as e:
        raise AuditError(f"--variant: {e}") from None
    spp = int(spp or DEFAULT_SPP)
    pass_spp = int(pass_spp or min(DEFAULT_PASS_SPP, spp))
    if spp < 2 or pass_spp < 2:
        raise AuditError(f"--spp {spp}: at least 2 samples per pixel (the variance needs two)")
    if variant.startswith("scalar"):
        raise AuditError(
            f"--variant {variant}: the audit needs a vectorised variant (llvm_ad_rgb, cuda_ad_rgb)"
        )
    check_sizes(spp, pass_spp, width, height)
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
    audited = [a for a in found if _audits(a, info.format) and (roles is None or a.role in roles)]
    skipped = [
        f"{a.family} ({a.role}: {a.part}): "
        + (
            "not audited in this run (not a role it asks for)"
            if _audits(a, info.format)
            else "listed by --list, not audited yet"
            + (f" on {info.format} scenes" if _wrong_format(a, info.format) else "")
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
    check_out(Path(cache) if cache is not None else default_cache_dir(), "--cache")
    say(f"camera: {info.camera}; up: {info.up_reason}")  # (after every refusal: one line, then progress)
    cache_root = Path(cache) if cache is not None else default_cache_dir()
    backend = use_variant_backend(variant)

    timings = {"reference": 0.0, "evaluation": 0.0, "fit": 0.0}
    by_family: dict[str, dict[str, float]] = {}
    outcomes: dict[str, dict[str, MethodOutcome]] = {}
    costs = {} if costs is None else costs
    plan: list[tuple[AuditFamily, Applicability, FamilyCase]] = []  # the finished cases, in order
    done: list[Applicability] = []
    run = _CaseRun(
        sel, bool(fit), tuple(metrics), int(seed), backend, cost_elements, costs, timings, by_family
    )
    settings = {"variant": variant, "spp": spp, "pass_spp": pass_spp, "seed": int(seed), "sel": sel}
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
                kept = [a for a in audited if _rule_of(a).needs[0] in SURFACE_FREE_KINDS]
                if not kept:
                    raise AuditError(f"{info.source}: {why}")
                skipped += [
                    f"{a.family} ({a.role}: {a.part}): not audited: {why}" for a in audited if a not in kept
                ]
                audited = kept
            setup = AuditSetup(
                mi=mi,
                scene=mi_scene,
                sensor=sensor,
                emitters=emitters,
                info=info,
                gbuffer=gb,
                mask=mask,
                cache_root=cache_root,
                variant=variant,
                spp=spp,
                pass_spp=pass_spp,
                seed=int(seed),
                progress=progress,
                scene_digest=scene_digest,
                ao_distance=ao_distance,
                source=source,
                probe_at=probe_at,
                grid=grid,
                pom_depth=pom_depth,
                quantities=None if quantities is None else frozenset(quantities),
            )
            timings["reference"] += time.perf_counter() - t0
            # Family by family, each case evaluated and fitted as soon as its references are made: an
            # interrupted run has every finished case to report (`_partial_report`).
            parts = Stage(len(audited), "references", enabled=progress, say=say)  # a bar on a terminal
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
                rows = Stage(len(cases), f"{a.family}: cases", enabled=progress, say=say)
                for case in cases:
                    outcomes[case.id] = run.case(family, a, case)
                    plan.append((family, a, case))
                    rows.advance(f"{case.id}: {len(outcomes[case.id])} rows evaluated")
                rows.close()
                parts.advance()
                done.append(a)
            parts.close()
    except XMLSceneError as e:
        raise AuditError(str(e)) from None
    except KeyboardInterrupt as e:
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
    result.results = _results(result, plan, **settings)
    if interrupted is not None:
        result.results = replace(result.results, summary="Partial (interrupted). " + result.results.summary)
    return result


@dataclass
class _CaseRun:
    """Evaluates, measures and fits the rows of one case after another (`case`), adding to the run's
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

    def metrics_of(self, img: np.ndarray, case: FamilyCase, sigma: np.ndarray, row: str):
        """The row's metrics beside the noise floor. A metric's warning about the row's values (ꟻLIP clips
        an approximation's negative radiance to 0: an SH L2 ring below zero) is the row's property, not a
        fault of the run: it becomes a note of the report naming the row and the case."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            m = compute_metrics(
                img, case.reference.mean, sigma, case.mask, names=self.metrics, seed=self.seed
            )
        for w in caught:
            note = f"{row} ({case.label}): {str(w.message).splitlines()[0]}"
            if note not in self.notes:
                self.notes.append(note)
        return m

    def case(self, family: AuditFamily, a: Applicability, base: FamilyCase) -> dict[str, MethodOutcome]:
        """Every row of ``base`` (`_rows`): evaluated, its metrics beside the noise floor, its cost measured
        once per method, and, where it has free parameters, fitted and evaluated again."""
        rows: dict[str, MethodOutcome] = {}
        sigma = base.reference.sigma()
        spent = self.by_family[family.name]
        for row_id, method, user in _rows(family, a, self.sel, base):
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
                rows[row_id] = MethodOutcome(
                    case.id, row_id, method, method.label, img, None, given, user=user
                )
            if method.id not in self.costs and row_id in case.uncosted:
                self.costs[method.id] = {
                    "label": method.label, "ns_per_pixel": None, "pixels_per_second": None,
                    "backend": self.backend, "elements": None, "repeats": None,
                    "note": f"cost not measured like the others: {case.uncosted[row_id]}",
                }  # fmt: skip
            if method.id not in self.costs:
                cost = _cost(method, case, self.backend, self.cost_elements)
                self.costs[method.id] = {"label": method.label, **cost}
            if row_id in case.precompute and "precompute_trigger" not in self.costs[method.id]:
                self.precompute(method, case, case.precompute[row_id])
            self.timings["evaluation"] += time.perf_counter() - t1
            spent["evaluation"] += time.perf_counter() - t1
            if self.fit and method.params:
                t2 = time.perf_counter()
                result = fit_case(method, case, row_id)
                values = {k: v["value"] for k, v in result["parameters"].items()}
                img_f = evaluate_case(method, case, values)
                rows[f"{row_id}-fitted"] = MethodOutcome(
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
        # Every row's metrics beside the noise floor, once all are evaluated: their ꟻLIP maps (and the
        # floor's) in one tiled call (`prime_flip`: the same maps, ~0.1 s a call saved per row on a CPU).
        t3 = time.perf_counter()
        if "flip" in self.metrics:
            images = [o.image for o in rows.values()]
            prime_flip(images, base.reference.mean, sigma, base.mask, seed=self.seed)
        for row_id, o in rows.items():
            o.metrics = self.metrics_of(o.image, base, sigma, row_id)
        self.timings["evaluation"] += time.perf_counter() - t3
        spent["evaluation"] += time.perf_counter() - t3
        return rows


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
            pair = z_pair(
                row.image[case.mask],
                ref.mean[case.mask],
                ref.stderr[case.mask],
                ref.sigma()[case.mask],
                precision_floor=(
                    RELATIVE_PRECISION_FLOOR
                    if ref.precision is None
                    # A bias bound b of the reference (not noise) shifts an element's z by up to b/stderr:
                    # only elements whose noise is ≥ b / Z_MEDIAN_TOLERANCE judge the spread and median
                    # (one bias in every element then moves the median by at most its tolerance).
                    else np.maximum(RELATIVE_PRECISION_FLOOR, ref.precision[case.mask] / Z_MEDIAN_TOLERANCE)
                ),
            )
            what = f"{row.row} vs the reference, {case.label}"
            if not pair[0].size and pair[1].size:  # no element's noise above the reference's own precision
                checks.append(_within_precision_check(what, pair[1]))
                continue
            checks += z_checks(what, *concat_z_pairs([pair]), samples=int(ref.spp))
    return checks


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
    )


_PRECOMPUTE_KEYS = ("precompute_ms", "precompute_trigger", "precompute_pixels", "precompute_note")
"""A cost record's precompute columns (`_CaseRun.precompute`; the first three also on each approximation)."""


def _results(r: AuditResult, plan, *, variant, spp, pass_spp, seed, sel: Selection) -> Results:
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
         "note": c.get("note", "per pixel: the scene's own inputs, tiled, as float32; declared parameters"),
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
