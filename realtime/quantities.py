"""Quantities: what an approximation approximates, and the named inputs its ``g`` carries.

A **quantity** is one thing a reference measures at a visible point (or along a camera ray) — the direct
irradiance of one light, the sky's irradiance with occlusion, ambient occlusion, fog transmittance, sky
radiance — together with the per-element inputs a real-time formula for it may read, each with its unit and
domain. Every shipped method declares its quantity (``Method.quantity``); `QUANTITIES` documents them, and
`Quantity.methods` lists the shipped methods that approximate each (from the registry's method tables,
`rtfit.experiments.families.METHOD_TABLES`, so this module copies no formula).

A user's own approximation is a function ``f(ops, g, **params)`` written against the same ops namespace as
the shipped kernels (`rtfit.realtime.arrays`); `approximation` turns it into a `Method`::

    from rtfit import approximation, Param

    @approximation(quantity="light_irradiance", params={"w": Param(0.5, lower=0.0, upper=1.0)})
    def my_wrap(ops, g, *, w):
        t = ops.maximum((g.cos_theta + w) / (1.0 + w), 0.0)
        return g.irradiance * t * t

The method's inputs are the quantity's inputs; its kernel builds ``g`` (attribute access: ``g.cos_theta``,
and for a vector group ``g.normal`` = ``(g.nx, g.ny, g.nz)``) and calls ``f``. So the same text runs on
Dr.Jit, NumPy and JAX (``method.evaluate``) and `rtfit.fitting.fit_method` fits it through JAX like any
shipped method. Loading from files, modules and entry points, and the validation of a user function on
the quantity's domains, are `rtfit.experiments.user_methods`.

Structured inputs (an SDF sampler, a list of SH coefficients, a probe grid and its table, the K hit
distances of each point) have no scalar domain (``Input.domain`` is None); `Quantity.examples` gives a value
of each for validation: a factory called with the number of samples ``n`` (a per-element structured input,
such as the K hit distances, is a tuple of arrays of ``n`` values).

The table is kept in rooms by domain: `rtfit.realtime.quantity_types` (the `Quantity` record and shared
inputs), ``quantities_lights``, ``quantities_sky``, ``quantities_media``, ``quantities_probes`` and
``quantities_materials``; this module gathers them in `QUANTITY_ORDER` and holds the look-up and the
user-approximation machinery. A family that needs a new quantity declares it in its own realtime module,
``QUANTITIES = (Quantity(...),)`` at the module's top level (`family_quantities` finds it: no edit here),
after the rooms' in `QUANTITIES`, by module name, then in the module's order; its generated section
(`quantities_markdown`) is on the family's own page, docs/<family>.md. Such a module must not import this
one (it is imported from here): `Quantity` and the shared inputs are in `rtfit.realtime.quantity_types`.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable, Mapping
from dataclasses import replace
from importlib import import_module
from pathlib import Path
from types import MappingProxyType
from typing import Any

from . import MODULES
from .methods import Method, Param
from .quantities_lights import LIGHT_QUANTITIES
from .quantities_materials import MATERIAL_QUANTITIES
from .quantities_media import MEDIA_QUANTITIES
from .quantities_probes import EXAMPLE_GRID as EXAMPLE_GRID
from .quantities_probes import PROBE_QUANTITIES
from .quantities_sky import EXAMPLE_RAYS as EXAMPLE_RAYS
from .quantities_sky import SKY_QUANTITIES
from .quantity_types import Quantity

__all__ = [
    "QUANTITIES",
    "QUANTITY_ORDER",
    "UNDECLARED_UNIT",
    "ApproximationError",
    "QuantityInputs",
    "UserCodeExit",
    "UserKernel",
    "approximation",
    "family_quantities",
    "get_quantity",
    "is_user_approximation",
    "quantities_markdown",
]

QUANTITY_ORDER: tuple[str, ...] = (
    "light_irradiance",
    "sky_irradiance",
    "sky_irradiance_sh",
    "sky_irradiance_lights",
    "environment_irradiance",
    "sky_visibility",
    "ambient_occlusion",
    "crease_darkening",
    "cap_intersection_solid_angle",
    "fog_optical_depth",
    "fog_transmittance",
    "cloud_transmittance",
    "cloud_radiance",
    "fog_inscatter",
    "fogged_radiance",
    "particle_opacity",
    "inscattered_radiance",
    "drop_radiance",
    "glow_radiance",
    "spot_inscattered_radiance",
    "sky_radiance",
    "obscurance",
    "parallax_depth",
    "parallax_shadow",
    "reflected_radiance",
    "probe_specular_radiance",
    "volume_irradiance",
    "shadowed_light_irradiance",
    "fresnel_reflectance",
    "layer_offset",
    "coated_radiance",
    "inner_irradiance",
    "bounce_irradiance",
    "path_map_irradiance",
    "caustic_irradiance",
)
"""The order of the rooms' quantities in `QUANTITIES` (and in docs/audit.md's quantity table): each where it
was added. A family module's own ``QUANTITIES`` come after them (`family_quantities`)."""


_PACKAGE = __name__.rpartition(".")[0]
_DECLARES = re.compile(r"^QUANTITIES\b[^=\n]*=", re.M)


def family_quantities(
    package: str = _PACKAGE, folder: Path | None = None, modules: tuple[str, ...] | None = None
) -> dict[str, tuple[Quantity, ...]]:
    """Module → the quantities it declares in its own ``QUANTITIES`` (a tuple of `Quantity`), for every
    module of ``package`` (default: this one; ``folder``: its directory, ``modules``: its module names, by
    default every module file there) whose source assigns ``QUANTITIES`` at its top level, by module name.
    Only those modules are imported. This module and the rooms (``quantities_*``) are not family modules."""
    folder = Path(__file__).parent if folder is None else folder
    if modules is None:
        modules = MODULES if package == _PACKAGE else tuple(sorted(p.stem for p in folder.glob("[!_]*.py")))
    found: dict[str, tuple[Quantity, ...]] = {}
    for name in sorted(modules):
        if name.startswith(("quantities", "quantity_")):
            continue
        source = folder / f"{name}.py"
        if source.is_file() and not _DECLARES.search(source.read_text(encoding="utf-8")):
            continue  # (no source file, an install of bytecode only: the module itself tells)
        declared = getattr(import_module(f"{package}.{name}"), "QUANTITIES", ())
        if not isinstance(declared, tuple) or not all(isinstance(q, Quantity) for q in declared):
            raise ValueError(f"{package}.{name}.QUANTITIES must be a tuple of Quantity")
        found[name] = declared
    return found


def _in_order(
    tables: tuple[Mapping[str, Quantity], ...],
    order: tuple[str, ...],
    families: Mapping[str, tuple[Quantity, ...]],
) -> Mapping[str, Quantity]:
    by_name: dict[str, Quantity] = {}
    for table in tables:
        for name, q in table.items():
            if name in by_name:
                raise ValueError(f"quantity {name!r} is declared in two rooms")
            by_name[name] = q
    if sorted(order) != sorted(by_name):
        raise ValueError("QUANTITY_ORDER must name every quantity of the rooms once")
    out = {name: by_name[name] for name in order}
    where = dict.fromkeys(out, "the rooms")
    for module, declared in families.items():
        for q in declared:
            if q.name in out:
                raise ValueError(f"quantity {q.name!r} is declared in {where[q.name]} and in {module}")
            out[q.name], where[q.name] = q, module
    return MappingProxyType(out)


QUANTITIES: Mapping[str, Quantity] = _in_order(
    (LIGHT_QUANTITIES, SKY_QUANTITIES, MEDIA_QUANTITIES, PROBE_QUANTITIES, MATERIAL_QUANTITIES),
    QUANTITY_ORDER,
    family_quantities(),
)
"""Every documented quantity by name: the rooms' in `QUANTITY_ORDER`, then each family module's own
``QUANTITIES`` (`family_quantities`: by module name, in the module's order)."""


class ApproximationError(ValueError):
    """A wrong `approximation` declaration or an unknown quantity: one line."""


def get_quantity(name: str) -> Quantity:
    """The quantity ``name``; an unknown name is a one-line `ApproximationError` listing the known ones."""
    q = QUANTITIES.get(name) if isinstance(name, str) else None
    if q is None:
        raise ApproximationError(f"unknown quantity {name!r} (known: {', '.join(QUANTITIES)})")
    return q


class QuantityInputs:
    """The ``g`` a user function receives: attribute access to the quantity's named inputs, and to its
    vector groups as 3-tuples. ``record`` (a set, optional) collects the names the function reads."""

    __slots__ = ("_q", "_record", "_values")

    def __init__(self, quantity: Quantity, values: Mapping[str, Any], record: set[str] | None = None):
        object.__setattr__(self, "_q", quantity)
        object.__setattr__(self, "_values", dict(values))
        object.__setattr__(self, "_record", record)

    def __getattr__(self, name: str):
        q, values, record = self._q, self._values, self._record
        if name in values:
            if record is not None:
                record.add(name)
            return values[name]
        if name in q.vectors:
            comps = q.vectors[name]
            if record is not None:
                record.update(comps)
            return tuple(values[c] for c in comps)
        known = ", ".join([*q.input_names, *q.vectors])
        raise AttributeError(f"{q.name} carries no input {name!r} (it carries: {known})")

    def __setattr__(self, name, value):
        raise AttributeError("g is read-only")

    def __dir__(self):
        return [*self._q.input_names, *self._q.vectors]

    def __repr__(self):
        return f"<g of {self._q.name}: {', '.join(self._q.input_names)}>"


class UserCodeExit(ValueError):
    """A user approximation called ``sys.exit`` (or raised `SystemExit`) while it ran: one line naming it.
    User code must never end the process that evaluates it: a CI job would read the exit status 0 of
    ``sys.exit(0)`` as success, with no report written (issue 32)."""


class UserKernel:
    """The kernel of a user approximation: ``kernel(ops, **inputs, **params)`` builds ``g`` from the
    quantity's inputs and returns ``function(ops, g, **params)``. ``run`` does the same with a record of
    the inputs read (validation)."""

    def __init__(self, function: Callable[..., Any], quantity: Quantity):
        self.function = function
        self.quantity = quantity
        self.__name__ = getattr(function, "__name__", "approximation")
        self.__doc__ = function.__doc__

    def run(self, ops, values: Mapping[str, Any], params: Mapping[str, Any], record: set[str] | None = None):
        try:
            return self.function(ops, QuantityInputs(self.quantity, values, record), **params)
        except SystemExit as e:  # wherever it runs (validation, the audit, a fit): never the process's exit
            raise UserCodeExit(
                f"{self.__name__}: called sys.exit({e.code!r}) (an approximation must return values or raise "
                "an exception)"
            ) from None

    def __call__(self, ops, **kw):
        values = {n: kw.pop(n) for n in self.quantity.input_names if n in kw}
        return self.run(ops, values, kw)

    def __repr__(self):
        return f"<user kernel {self.__name__} ({self.quantity.name})>"


def is_user_approximation(obj: Any) -> bool:
    """True for a `Method` made by `approximation`."""
    return isinstance(obj, Method) and isinstance(obj.kernel, UserKernel)


def _where(function) -> str:
    try:
        file = inspect.getsourcefile(function) or "?"
        line = inspect.getsourcelines(function)[1]
    except (OSError, TypeError):
        return ""
    return f"{file}:{line}"


UNDECLARED_UNIT = "undeclared"
"""The unit of a user approximation's parameter declared without ``unit=`` (in reports and fitted files:
the number's unit is not known to rtfit)."""


def approximation(
    *,
    quantity: str,
    params: Mapping[str, Param] | None = None,
    label: str | None = None,
    id: str | None = None,
) -> Callable[[Callable[..., Any]], Method]:
    """Decorator: ``f(ops, g, **params)`` → a `Method` of ``quantity`` (module docstring).

    ``params``: the free parameters, each a `Param` (start value and bounds: a fit stays within them; one
    declared without ``unit=`` gets `UNDECLARED_UNIT`, so a fitted file says the unit is not known);
    ``label`` (default: the first line of ``f``'s docstring, else its name); ``id`` (default ``f``'s name).
    A wrong declaration is a one-line `ApproximationError` naming the function: an unknown quantity (listing
    the known ones), a parameter given as a bare number (no bounds), a parameter ``f`` does not take as a
    keyword, a keyword ``f`` requires that is not declared."""
    q = get_quantity(quantity)
    declared = dict(params or {})

    def wrap(f: Callable[..., Any]) -> Method:
        name = id or getattr(f, "__name__", "approximation")
        if not callable(f):
            raise ApproximationError(f"{name}: @approximation decorates a function f(ops, g, **params)")
        for k, p in declared.items():
            if not isinstance(p, Param):
                raise ApproximationError(
                    f"{name}: parameter {k!r} = {p!r} has no bounds; declare it as "
                    f"Param(initial, lower=…, upper=…)"
                )
        try:
            sig = inspect.signature(f)
        except (TypeError, ValueError):
            sig = None
        if sig is not None:
            ps = list(sig.parameters.values())
            var_kw = any(p.kind is p.VAR_KEYWORD for p in ps)
            positional = [p for p in ps if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
            if len(positional) < 2 and not any(p.kind is p.VAR_POSITIONAL for p in ps):
                raise ApproximationError(f"{name}: an approximation takes (ops, g, *, params…); got {sig}")
            keywords = {p.name for p in ps[2:] if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
            extra = sorted(set(declared) - keywords) if not var_kw else []
            if extra:
                raise ApproximationError(
                    f"{name}: parameter(s) {', '.join(extra)} declared but not taken by {name}{sig}"
                )
            required = sorted(
                p.name
                for p in ps[2:]
                if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
                and p.default is p.empty
                and p.name not in declared
            )
            if required:
                raise ApproximationError(
                    f"{name}: keyword(s) {', '.join(required)} of {name}{sig} are not declared in params="
                )
        doc = inspect.getdoc(f) or ""
        first = doc.splitlines()[0].strip() if doc else ""
        try:
            return Method(
                id=name,
                label=label or first or name,
                kernel=UserKernel(f, q),
                inputs=q.inputs,
                # a unit the user left out is said to be so (fitted files refuse an empty unit)
                params={k: p if p.unit else replace(p, unit=UNDECLARED_UNIT) for k, p in declared.items()},
                quantity=q.name,
                formula=first,
                source=_where(f),
                description=doc,
            )
        except ValueError as e:
            raise ApproximationError(f"{name}: {e}") from None

    return wrap


def quantities_markdown(names: tuple[str, ...] | None = None) -> str:
    """The generated quantity sections of ``names``, from `QUANTITIES` (default: the rooms' `QUANTITY_ORDER`,
    docs/audit.md's "Your own approximation"; a family module's own quantities: its page, docs/<family>.md).
    No registry is read, so a family added changes no generated text: which shipped methods approximate a
    quantity is ``rtfit list --json`` (each family's methods and quantities)."""
    lines = []
    for q in (get_quantity(n) for n in (QUANTITY_ORDER if names is None else names)):
        out = "one array" if q.channels == 1 else f"a tuple of {q.channels} arrays (R, G, B)"
        lines.append(f"#### `{q.name}` [{q.unit}]")
        lines.append("")
        lines.append(f"{q.description[0].upper()}{q.description[1:]}; `f` returns {out}.")
        lines.append(f"Reference: {q.reference}." if q.reference else "")
        if q.note:
            lines.append(f"Note: {q.note}.")
        lines.append("")
        lines.append("| input | unit | domain | meaning |")
        lines.append("|---|---|---|---|")
        for i in q.inputs:
            dom = "structured" if i.domain is None else f"[{i.domain[0]:g}, {i.domain[1]:g}]"
            lines.append(f"| `{i.name}` | {i.unit} | {dom} | {i.description} |")
        if q.vectors:
            groups = "; ".join(
                f"`g.{k}` = `({', '.join('g.' + c for c in v)})`" + (" (unit)" if k in q.unit_vectors else "")
                for k, v in q.vectors.items()
            )
            lines.append("")
            lines.append(f"Vectors: {groups}.")
        lines.append("")
    return "\n".join(line for line in lines).rstrip() + "\n"
