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
the audit engine: this module, `rtfit.experiments.audit_setup` (what its cases are given and make their
references with), `rtfit.experiments.case_inputs` (kernel-input helpers) and `rtfit.experiments.shipped` (its
scenes and study for ``rtfit run``) are all both sides share.

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

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from rtfit.realtime.methods import Method, Param

from .audit import Applicability, AuditError, Rule
from .audit_setup import AuditReference, AuditSetup

__all__ = [
    "FIT_WEIGHTS",
    "PRECOMPUTE_TRIGGERS",
    "AuditFamily",
    "FamilyCase",
    "Precompute",
    "by_name",
]


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
    step share one `Precompute` (timed once). ``shared``: a step the row's precompute does first that other
    rows do too (light-path-maps' entry points and shadow rays, before each K's clusters): timed once for
    all of them and added to each row's own ``run``, which then takes that step's product (what
    ``shared.run()`` returned) as its one argument and does the rest alone (so that no case holds the
    product: the engine keeps it while it times the case's rows)."""

    run: Callable[..., Any]
    trigger: str
    what: str
    shared: Precompute | None = None

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
