"""What an audit runs: ``--approx`` resolved into families, shipped methods and user approximations
(`Selection`), and the applicabilities of the scene those select (split from `audit_run`, issue 30)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from rtfit.realtime.methods import Method
from rtfit.realtime.quantities import is_user_approximation

from .applicability import applicable_families
from .audit import Applicability, AuditError, SceneInfo
from .families import AUDITED, METHOD_TABLES, RULES
from .registry import ALIASES
from .user_methods import UserMethodError, check_approximation
from .user_sandbox import load_validated


def wrong_format(a: Applicability, scene_format: str) -> bool:
    """True when `AUDITED` audits the applicability's family and role, but not on scenes of
    ``scene_format``."""
    family = AUDITED.get(a.family)
    if family is None or (family.roles is not None and a.role not in family.roles):
        return False
    return not family.audits(a.role, scene_format)


def rule_of(a: Applicability):
    """The `RULES` entry that made the applicability ``a`` (its family and role)."""
    return next(r for r in RULES if r.family == a.family and r.role == a.role)


def audited_here(a: Applicability, scene_format: str) -> bool:
    """True when `AUDITED` audits the applicability ``a`` (its family, role and the scene's format)."""
    family = AUDITED.get(a.family)
    return family is not None and family.audits(a.role, scene_format)


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
