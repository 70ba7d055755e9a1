"""The extension point of `rtfit audit`: what an audited family declares, and what it is given.

A family joins the audit with **one declaration**, an `AuditFamily` in a module of its own
(``experiments/audit_<family>.py``), listed in its family's entry of the registry (`experiments/families.py`):

* ``name``: the family (its name in the registry, `rtfit.experiments.families.FAMILIES`);
* ``rules``: when it applies (`rtfit.experiments.audit.Rule`, one per role; ``--list`` prints them);
* ``quantity``: the quantity its methods approximate (`rtfit.realtime.quantities.QUANTITIES`): a user's
  approximation of that quantity (``--approx my.py:f``) is audited beside the shipped methods;
* ``cases(setup, applicability) -> list[FamilyCase]``: the references this family needs for one
  applicability (one light, one medium, …) and the methods' inputs on the same pixels.

Everything else — evaluating every method with Dr.Jit, measuring its cost, fitting its free parameters
through the JAX run of the same kernel text, metrics with noise floors, error maps, ``results.json``, the
report and the fitted-parameter file — is the audit's, the same for every family. A family never imports
the audit engine (this module is the only thing both sides share).

A case's reference is an image (H, W, 3) with its per-pixel standard error; the methods are evaluated on the
masked pixels only, once per RGB channel (``channel_inputs``: each input name → an array over the masked
pixels, or a float), and each value is multiplied by ``factor`` where the case has one (e.g. the hard shadow
of the light's centre, what a shadow map gives an engine). A fit uses the elements where the factor is
positive, divided by it. A case whose quantity is RGB-valued (``fogged_radiance``, ``sky_radiance``: the
method returns the tuple (R, G, B)) has **one** mapping in ``channel_inputs``; a float or an array that is
not per pixel (a table) is passed to the method as it is.

A case may compare its own rows and quantity (the media families: the height-fog optical-depth forms are
compared as transmittances T = e^(−τ), the shading models on the fogged image): ``methods`` (row id →
`Method`, replacing the family's table for this case; a row whose ``Method.id`` is not among the
applicability's methods is dropped), ``quantity`` (user approximations of it are its rows) and ``params``
(row id → parameter name → `Param`: the value the row is evaluated with, ``Param.initial``, and the start
and bounds of its fit, e.g. the scene's own fog density) and ``row_inputs`` (row id → that row's own
``channel_inputs``, e.g. the stored coefficients of one irradiance basis).

A row whose method needs a **precompute** that an engine pays apart from its per-pixel kernel (transfers
baked, photons traced and gathered, a texture built) declares it on the case: ``precompute`` (row id →
`Precompute`: a callable doing the whole step on the case's own inputs, what it is, and its ``trigger``:
once per ``frame``, per ``light`` change or per ``scene``). The engine times it with the same loop as the
per-pixel kernel (`rtfit.experiments.cost.time_precompute`) and records ``precompute_ms``, its trigger and
the case's pixel count beside the ns per pixel; a precompute that raises is a failed check of the run (one
line), not a crash.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import drjit as dr
import numpy as np

from rtfit.realtime.methods import Method, Param
from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR, PassEntry, pass_size, pool_passes
from rtfit.reference.estimators import GBuffer, PassResult, launch_identity, sub_seed

from .audit import Applicability, AuditError, Rule, SceneInfo

__all__ = [
    "PRECOMPUTE_TRIGGERS",
    "AuditError",
    "AuditFamily",
    "AuditReference",
    "AuditSetup",
    "FamilyCase",
    "PooledPasses",
    "Precompute",
    "ShippedScene",
    "Study",
    "StudyContext",
    "by_name",
    "masked_image",
    "pooled_passes",
    "rgb_columns",
    "vector_text",
    "xyz_columns",
]


@dataclass(frozen=True)
class AuditSetup:
    """What a family's ``cases`` is given: the scene loaded in the audit's Mitsuba variant (``mi``,
    ``scene``, the chosen ``sensor``, ``emitters`` in `XmlScene.emitters` order), its inspection
    (``info``; ``info.xml`` for an XML scene), the pixel-centre G-buffer and the ``mask`` of pixels that
    show a surface that is not itself a light; the cache and sampling settings; ``scene_digest``: the
    digest over every file the scene loads (`XmlDependencies.digest`) plus the camera and film size — part
    of every cache key. ``ao_distance``: the AO radius (scene units)."""

    mi: Any
    scene: Any
    sensor: Any
    emitters: tuple
    info: SceneInfo
    gbuffer: GBuffer
    mask: np.ndarray
    cache_root: Path
    variant: str
    spp: int
    pass_spp: int
    seed: int
    progress: bool
    scene_digest: str
    ao_distance: float | None = None
    source: Any = None
    """The rtfit `Scene` of a TOML input (its camera at the run's film size), or the `AtmosphereSpec` of an
    rtfit sky file (whose camera is the azimuth × elevation panorama of `sky_view`); None for Mitsuba XML
    (``info.xml``)."""
    probe_at: tuple[float, float, float] | None = None
    """``--probe-at``: where the environment-maps family captures its cube maps (None: each shape's
    centre)."""
    grid: tuple[int, int, int] | None = None
    """``--grid``: the irradiance-volumes probe grid (None: the family's default for the scene's box)."""
    pom_depth: float | None = None
    """``--pom-depth``: the parallax-occlusion height range in texture units (None: the family's default)."""
    quantities: frozenset[str] | None = None
    """The case quantities this run audits (`ShippedScene.quantities`; None: every one): a family asks
    `wants` before it renders a case's reference, and the engine drops the cases of any other quantity."""

    def wants(self, quantity: str) -> bool:
        """Whether this run audits cases of ``quantity`` (render a case's reference only if so)."""
        return self.quantities is None or quantity in self.quantities


@dataclass(frozen=True)
class AuditReference:
    """A reference image: ``mean`` and ``stderr`` (H, W, 3, float64), ``spp`` samples per pixel in
    ``passes`` passes (``passes_rendered`` of them by this run), ``cache_key``/``cache_path`` of its
    `PassEntry`, ``seconds`` of rendering summed over the passes, ``quantity``, ``integrator`` and
    ``integrator_reason`` (words)."""

    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    passes_rendered: int
    cache_key: str
    cache_path: str
    seconds: float
    quantity: str
    integrator: str
    integrator_reason: str
    precision: np.ndarray | None = None
    """The reference's own relative precision floor per pixel (H, W, 3), where its estimator's float32
    arithmetic biases it beyond `RELATIVE_PRECISION_FLOOR` (a very small sphere light's cone sampling:
    `audit_lights.sphere_sampling_precision`); None: `RELATIVE_PRECISION_FLOOR` everywhere."""
    mask: np.ndarray | None = None
    """The (H, W) mask of the pixels it was made for (its constructors set it: `PooledPasses.reference`,
    `deterministic`): a `FamilyCase` that names no mask of its own compares these pixels."""

    def relative_floor(self):
        """The relative precision floor: `RELATIVE_PRECISION_FLOOR`, or per pixel at least ``precision``."""
        if self.precision is None:
            return RELATIVE_PRECISION_FLOOR
        return np.maximum(RELATIVE_PRECISION_FLOOR, self.precision)

    def sigma(self) -> np.ndarray:
        """The standard error combined with the float32 precision floor (as `Reference.sigma`)."""
        return np.sqrt(self.stderr**2 + (self.relative_floor() * self.mean) ** 2)

    @classmethod
    def deterministic(
        cls,
        mask: np.ndarray,
        values,
        key_parts: tuple,
        seconds: float,
        quantity: str,
        integrator: str,
        integrator_reason: str,
    ) -> AuditReference:
        """A reference computed without sampling (Mitsuba's exact first hits, an emitter's closed form): one
        "pass" rendered now, standard error zero, not cached; ``values`` on the masked pixels as
        `masked_image` takes them; ``key_parts`` (the scene digest, the part, the settings) make its
        ``cache_key``, which names the reference in the results."""
        image = masked_image(mask, values)
        key = hashlib.sha256(repr(key_parts).encode()).hexdigest()[:16]
        return cls(
            mean=image,
            stderr=np.zeros_like(image),
            spp=1,
            passes=1,
            passes_rendered=1,
            cache_key=key,
            cache_path="",
            seconds=seconds,
            quantity=quantity,
            integrator=integrator,
            integrator_reason=integrator_reason,
            mask=mask,
        )


def vector_text(v) -> str:
    """A point or vector for a report line: "(x, y, z)", 4 significant digits each."""
    return "(" + ", ".join(f"{float(c):.4g}" for c in v) + ")"


def xyz_columns(prefix: str, v: np.ndarray) -> dict[str, np.ndarray]:
    """Kernel inputs ``<prefix>x``, ``<prefix>y``, ``<prefix>z`` from the columns of an (N, 3) array."""
    return {f"{prefix}{c}": np.ascontiguousarray(v[:, k]) for k, c in enumerate("xyz")}


def rgb_columns(prefix: str, v: np.ndarray) -> dict[str, np.ndarray]:
    """Kernel inputs ``<prefix>_r``, ``<prefix>_g``, ``<prefix>_b`` from the columns of an (N, 3) array."""
    return {f"{prefix}_{c}": np.ascontiguousarray(v[:, k]) for k, c in enumerate("rgb")}


def masked_image(mask: np.ndarray, values) -> np.ndarray:
    """An (H, W, 3) float64 image, zero outside ``mask`` (H, W), holding ``values`` on the masked pixels in
    row-major order: (N, 3) one value per RGB channel, or (N,) one grey value copied to the three channels
    (N = the masked pixels). The units are the values'."""
    img = np.zeros((*mask.shape, 3))
    v = np.asarray(values, np.float64)
    img[mask] = v if v.ndim == 2 else v[:, None]
    return img


@dataclass(frozen=True)
class PooledPasses:
    """A family's reference passes through the pass cache, pooled (`pooled_passes`): the ``mean`` and its
    ``stderr`` per element (point or ray) and pass column, (N,) or (N, C), in the quantity's units; ``spp``
    samples per element in all, in ``passes`` passes, ``passes_rendered`` of them by this run (the rest read
    from the cache); the cache ``entry`` (`PassEntry`) and ``seconds`` of rendering summed over the passes."""

    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    passes_rendered: int
    entry: PassEntry
    seconds: float

    def reference(
        self,
        mask: np.ndarray,
        quantity: str,
        integrator: str,
        integrator_reason: str,
        columns: slice | None = None,
        extra_seconds: float = 0.0,
        precision: np.ndarray | None = None,
    ) -> AuditReference:
        """The `AuditReference` these passes give on the pixels of ``mask`` (element i is the i-th masked
        pixel, row-major): ``mean`` and ``stderr`` (their ``columns``: three RGB columns, or all of a grey
        (N,) pass) as (H, W, 3) images (`masked_image`), the samples and passes, the cache entry's key and
        folder, the seconds of rendering plus ``extra_seconds`` (another pass the case needed, e.g. a
        bake), and the report's words (``quantity`` with units, ``integrator``, ``integrator_reason``);
        ``precision``: the relative precision floor per masked element ((N,), `AuditReference.precision`)."""
        mean, stderr = (
            (self.mean, self.stderr) if columns is None else (self.mean[:, columns], self.stderr[:, columns])
        )
        return AuditReference(
            mean=masked_image(mask, mean),
            stderr=masked_image(mask, stderr),
            spp=self.spp,
            passes=self.passes,
            passes_rendered=self.passes_rendered,
            cache_key=self.entry.key,
            cache_path=str(self.entry.folder),
            seconds=self.seconds + extra_seconds,
            quantity=quantity,
            integrator=integrator,
            integrator_reason=integrator_reason,
            precision=None if precision is None else masked_image(mask, precision),
            mask=mask,
        )


PRECOMPUTE_TRIGGERS = {
    "frame": "every frame",
    "light": "when a light moves or changes",
    "scene": "when the scene's geometry or materials change",
}
"""`Precompute.trigger`: when an engine runs a row's precompute again (key → words for the report)."""


@dataclass(frozen=True)
class Precompute:
    """A row's precompute (module docstring): ``run()`` does the whole step once on the case's inputs (it
    closes over them: the scene, the entry points, the light) and returns its product (what the per-pixel
    kernel reads; Dr.Jit arrays in it are evaluated inside the timing); ``trigger``: a key of
    `PRECOMPUTE_TRIGGERS`; ``what``: one line saying what it does (the cost table's note). Rows sharing one
    step share one `Precompute` (timed once)."""

    run: Callable[[], Any]
    trigger: str
    what: str

    def __post_init__(self):
        if self.trigger not in PRECOMPUTE_TRIGGERS:
            raise AuditError(
                f"precompute {self.what!r}: trigger {self.trigger!r}: one of {', '.join(PRECOMPUTE_TRIGGERS)}"
            )
        if not callable(self.run):
            raise AuditError(f"precompute {self.what!r}: run must be callable")


FIT_WEIGHTS = ("absolute", "relative")
"""`FamilyCase.fit_weight`: how a case's fits weigh each residual."""


@dataclass(frozen=True)
class FamilyCase:
    """One comparison: ``id`` (file-name safe), ``label``, ``parameters`` (free-form, into results.json),
    the ``reference``, the ``mask`` (H, W) of compared pixels (left out: the reference's own,
    `AuditReference.mask`), ``channel_inputs`` (one mapping per RGB channel: input name → array over the
    masked pixels, or a float), ``factor`` (over the masked pixels, or None), ``units`` of the quantity and
    ``notes`` (sentences for the report); ``methods``, ``quantity`` and ``params``: the case's own rows
    (module docstring; empty: the family's)."""

    id: str
    label: str
    reference: AuditReference
    mask: np.ndarray = field(default=cast(np.ndarray, None))
    """The compared pixels; left out (None): the pixels the reference was made for (`AuditReference.mask`).
    Given, it is used as it is (rtfit compare's cases give their own)."""
    channel_inputs: tuple[Mapping[str, Any], ...] = ()
    """Empty only where no row is evaluated (rtfit compare's cases: a reference and its frames)."""
    parameters: Mapping[str, Any] = field(default_factory=dict)
    factor: np.ndarray | None = None
    units: str = ""
    notes: tuple[str, ...] = ()
    methods: Mapping[str, Method] | None = None
    quantity: str = ""
    params: Mapping[str, Mapping[str, Param]] = field(default_factory=dict)
    row_inputs: Mapping[str, tuple[Mapping[str, Any], ...]] = field(default_factory=dict)
    """Row id → ``channel_inputs`` of that row alone, where a row's inputs differ from the case's (each
    irradiance basis reads its own stored coefficients; the exact row one grey value per channel). Rows not
    named here (and every user approximation) get ``channel_inputs``."""
    user_rows: Callable[[Method], Method] | None = None
    """How a user approximation of the case's quantity reads the case's inputs: the same adaptation the
    shipped rows get (obscurances: the K hit distances as the per-pixel inputs d1..dK, `on_rays`; irradiance
    volumes: the probe grid as a fixed keyword), so that the user's ``g`` holds what the shipped rows read.
    None: the user's method reads ``channel_inputs`` by its quantity's input names."""
    uncosted: Mapping[str, str] = field(default_factory=dict)
    """Row id → why its cost is not measured like the others' (a row whose value is computed outside its
    kernel, which only passes it through: timing that kernel would print a cost of nothing)."""
    precompute: Mapping[str, Precompute] = field(default_factory=dict)
    """Row id → the `Precompute` an engine runs before that row's per-pixel kernel (module docstring): timed
    by the engine beside the kernel's ns per pixel (``precompute_ms``, its trigger and this case's pixel
    count in the cost record)."""
    fit_weight: str = "absolute"
    """How the case's fits weigh each element's residual (`audit_fit.fit_data`): ``absolute`` (1: the
    least-squares fit of the RMSE in the quantity's units) or ``relative`` (1 / max(|reference|, σ): the
    relative error, its noise floor σ stopping a dark pixel from dominating; σ = `AuditReference.sigma`)."""

    def __post_init__(self):
        if self.mask is None:
            if self.reference.mask is None:
                raise AuditError(f"{self.id}: no mask: neither the case nor its reference names one")
            object.__setattr__(self, "mask", self.reference.mask)
        if self.fit_weight not in FIT_WEIGHTS:
            raise AuditError(f"{self.id}: fit_weight {self.fit_weight!r}: one of {', '.join(FIT_WEIGHTS)}")


@dataclass(frozen=True)
class AuditFamily:
    """One audited family (module docstring): ``name``, ``quantity``, ``cases``, ``describe``: one
    paragraph for the report's method section, ``quantities``: further quantities its cases compare, and
    ``formats``: the scene formats it reads."""

    name: str
    quantity: str
    cases: Callable[[AuditSetup, Applicability], list[FamilyCase]]
    describe: str = ""
    quantities: tuple[str, ...] = ()
    """Further quantities some of its cases compare (`FamilyCase.quantity`)."""
    roles: tuple[str, ...] | None = None
    """The applicability roles (its ``rules``) its cases audit; None: every role of the
    family. A role not listed is named in the run's notes as not audited yet."""
    formats: tuple[str, ...] = ("mitsuba-xml",)
    """The scene formats (`SceneInfo.format`: ``mitsuba-xml``, ``rtfit-toml``, ``rtfit-sky``) its cases read;
    on another format the family is named in the run's notes as not audited for it."""
    role_formats: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    """Role → the formats that role's declaration reads, where declarations joined by `by_name` read
    different ones (height-fog: rtfit TOML for exponential fog, XML and TOML for a scene's own media;
    nishita-sky: rtfit sky files for an atmosphere, Mitsuba XML for a sky emitter); a role not here reads
    ``formats``."""

    rules: tuple[Rule, ...] = ()
    """When the family applies (`rtfit.experiments.audit.Rule`: the scene parts it needs, the reason, the
    reference and integrator ``--list`` prints), one per applicability role this declaration audits; the
    registry (`rtfit.experiments.families`) gathers every declaration's rules. A declaration with rules and
    no ``roles`` audits exactly its rules' roles."""

    def __post_init__(self):
        stray = [r.role for r in self.rules if r.family != self.name]
        if stray:
            raise AuditError(f"{self.name}: rules of another family ({', '.join(stray)})")
        if self.rules and self.roles is None:
            object.__setattr__(self, "roles", tuple(dict.fromkeys(r.role for r in self.rules)))

    def reads(self, role: str, scene_format: str) -> bool:
        """Whether the declaration of ``role`` reads scenes of ``scene_format``."""
        return scene_format in self.role_formats.get(role, self.formats)

    def audits(self, role: str, scene_format: str) -> bool:
        """True when this declaration audits the applicability role ``role`` on scenes of
        ``scene_format``."""
        return self.reads(role, scene_format) and (self.roles is None or role in self.roles)


@dataclass(frozen=True)
class ShippedScene:
    """A scene a family ships for ``rtfit run FAMILY`` (issue 30 §1): the engine audits it for this family
    alone, exactly as ``rtfit audit`` audits a user's scene. ``file``: a Mitsuba XML or rtfit TOML file in
    rtfit's scene library (``scenes/library/``); ``label``: one line for the report; ``size`` (width,
    height) and ``spp`` of the full run, ``quick_size`` and ``quick_spp`` of ``--quick``; ``options``: the
    audit's keyword options for this scene (``ao_distance``, ``grid``, ``probe_at``, ``pom_depth``)."""

    file: str
    label: str
    size: tuple[int, int] = (128, 128)
    spp: int = 1024
    quick_size: tuple[int, int] = (32, 32)
    quick_spp: int = 64
    options: Mapping[str, Any] = field(default_factory=dict)
    defines: Mapping[str, str] = field(default_factory=dict)
    """Values of the XML file's ``<default name=… value=…/>`` parameters (Mitsuba's ``$name``; ``rtfit audit
    -D name=value``): one scene file, several shipped scenes (a light's angular radius, a sky's radiance)."""
    name: str = ""
    """Its id in case ids (file-name safe); default: the file's stem, then the defines (``name-value``)."""
    quick: bool = True
    """Whether ``--quick`` audits it too (False: the full run only, e.g. the in-between light sizes)."""
    roles: tuple[str, ...] | None = None
    """The applicability roles of the family audited on this scene (None: every role that applies); the
    others are dropped before any reference is rendered, and named in the run's notes."""
    quantities: tuple[str, ...] | None = None
    """The case quantities audited on this scene (`FamilyCase.quantity`, else the family's; None: every
    one): the family's ``cases`` skips the others' references (`AuditSetup.wants`)."""
    quick_roles: tuple[str, ...] | None = None
    """``roles`` of ``--quick`` (None: the same as the full run's)."""
    quick_quantities: tuple[str, ...] | None = None
    """``quantities`` of ``--quick`` (None: the same as the full run's)."""

    def audited(self, quick: bool) -> tuple[tuple[str, ...] | None, tuple[str, ...] | None]:
        """(roles, quantities) audited on this scene by the full run or by ``--quick``."""
        if quick:
            return (
                self.roles if self.quick_roles is None else self.quick_roles,
                self.quantities if self.quick_quantities is None else self.quick_quantities,
            )
        return self.roles, self.quantities

    def __post_init__(self):
        if "/" in self.file or not self.file.endswith((".xml", ".toml")):
            raise ValueError(f"shipped scene {self.file!r}: a .xml or .toml file name in scenes/library/")
        if self.defines and not self.file.endswith(".xml"):
            raise ValueError(f"shipped scene {self.file!r}: defines are for Mitsuba XML files")
        if not self.name:
            parts = [self.file.rsplit(".", 1)[0], *(f"{k}{v}" for k, v in self.defines.items())]
            object.__setattr__(self, "name", re.sub(r"[^A-Za-z0-9_-]", "_", "-".join(parts)))


@dataclass(frozen=True)
class StudyContext:
    """What a family's own study (`Study`) is given: the run's ``out_dir`` (figures go under
    ``out_dir/figures/``), ``quick``, ``variant``, ``seed``, the ``cache_dir`` of reference passes, and
    ``audits``: the engine's `rtfit.experiments.audit_run.AuditResult` of each shipped scene, in
    declaration order (the study may read their references, rows and ``gbuffer``, the camera's pixel-centre
    G-buffer the cases were computed on; it never re-renders them)."""

    out_dir: Path
    quick: bool
    variant: str
    seed: int
    cache_dir: Path
    audits: tuple[Any, ...] = ()


@dataclass(frozen=True)
class Study:
    """The tables and figures only this family has, added to its ``rtfit run`` report after the engine's:
    typed records (`rtfit.experiments.records`) — ``sections`` (text and Markdown tables), ``figures``
    (files under ``figures/``), ``checks`` (its own self-checks: a failed one fails the run), ``fits``,
    ``notes``, ``headline`` numbers and ``extra`` (plain JSON)."""

    sections: tuple[Any, ...] = ()
    figures: tuple[Any, ...] = ()
    checks: tuple[Any, ...] = ()
    fits: tuple[Any, ...] = ()
    """Its own fits (`records.Fit`: a law fitted across the scenes' fits), in the report's fit table and
    tables.tex beside the engine's."""
    notes: tuple[str, ...] = ()
    headline: tuple[Any, ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)


def _merged(family: list[AuditFamily]) -> AuditFamily:
    """One declaration of a family from declarations of its roles (`by_name`)."""
    first = family[0]
    if len(family) == 1:
        return first
    roles: list[str] = []
    for f in family:
        if f.roles is None:
            raise AuditError(f"{f.name}: a family declared more than once must name each declaration's roles")
        clash = set(roles) & set(f.roles)
        if clash:
            raise AuditError(f"{f.name}: role {', '.join(sorted(clash))} declared twice")
        roles += f.roles
    owner = {r: f for f in family for r in f.roles or ()}

    def cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
        return owner[app.role].cases(setup, app)

    quantities = dict.fromkeys(q for f in family for q in (f.quantity, *f.quantities))
    quantities.pop(first.quantity)
    formats = tuple(dict.fromkeys(x for f in family for x in f.formats))  # each role keeps its own
    role_formats = {r: f.formats for f in family for r in f.roles or ()}
    return AuditFamily(
        name=first.name,
        quantity=first.quantity,
        cases=cases,
        describe=" ".join(f.describe for f in family if f.describe),
        quantities=tuple(quantities),
        roles=tuple(roles),
        formats=formats,
        role_formats=role_formats,
        rules=tuple(r for f in family for r in f.rules),
    )


def by_name(families) -> dict[str, AuditFamily]:
    """Family name → one `AuditFamily`, from declarations in order. A family may be declared once per
    role (each declaration's ``roles`` disjoint, e.g. sdf-occlusion's ambient-occlusion and sky-occlusion
    roles in modules of their own): its declarations become one whose ``cases`` dispatches on the
    applicability's role, whose ``quantities`` are all of theirs, whose ``describe`` joins theirs and whose
    ``formats`` are any of theirs (``role_formats``: each role's own, e.g. height-fog's exponential fog on
    rtfit TOML scenes and a scene's own media on Mitsuba XML and TOML)."""
    groups: dict[str, list[AuditFamily]] = {}
    for f in families:
        groups.setdefault(f.name, []).append(f)
    return {name: _merged(group) for name, group in groups.items()}


def pooled_passes(
    setup: AuditSetup,
    what: Mapping[str, Any],
    render_pass: Callable[[int, int], PassResult],
    shape: tuple[int, ...],
    label: str,
    seed_label: str = "pass",
) -> PooledPasses:
    """A family's reference passes through the pass cache, pooled (`PooledPasses`; its ``reference`` is the
    case's `AuditReference`).

    ``what``: the family's own part of the cache key (format, quantity, the emitter or medium, a digest of the
    points or rays); the run's part (scene digest, variant, seed, pass size, Mitsuba and Dr.Jit versions) is
    added here (with the GPU's launch layout, `launch_identity`). ``render_pass(spp, seed)`` renders one
    pass; pass i has ``min(pass_spp, spp − i·pass_spp)`` samples (at least 2: the variance needs two) and the
    seed ``sub_seed(setup.seed, seed_label, i)``."""
    import mitsuba as mi  # (its version is part of the key)

    ident = {
        **what,
        "scene": setup.scene_digest,
        "variant": setup.variant,
        "seed": setup.seed,
        "pass_spp": setup.pass_spp,
        "versions": {"mitsuba": mi.__version__, "drjit": dr.__version__},
        **launch_identity(setup.variant),
    }
    entry = PassEntry(setup.cache_root, ident, namespace="audit", storage="npz", info={"label": label})
    count = -(-setup.spp // setup.pass_spp)

    def size(i: int) -> int:
        return pass_size(setup.spp, setup.pass_spp, i)

    def render(i: int):
        return render_pass(size(i), sub_seed(setup.seed, seed_label, i))

    passes, rendered = entry.passes(
        count, render, shape=shape, progress=setup.progress, label=label, spp_of=size
    )
    mean, stderr, total = pool_passes(passes)
    return PooledPasses(
        mean, stderr, total, len(passes), rendered, entry, float(sum(p.seconds for p in passes))
    )
