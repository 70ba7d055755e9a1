"""Which registered families apply to a scene, and why: `rtfit audit SCENE --list`'s decision and text.

The scene's parts come from `rtfit.experiments.audit.inspect_scene`; when a family applies is its audit
declarations' `audit.Rule` s, gathered by the registry (`rtfit.experiments.families.RULES`). A rule names
the part kinds it needs (the first is the *trigger*: one applicability per such part; the others must be
present in the scene); a method of the family's table (`families.METHOD_TABLES`) applies when every one of
its inputs is provided by those parts (`audit.PROVIDES`) or by the rule itself (``Rule.supplies``). No code
branches on a family's or a method's name.
"""

from __future__ import annotations

from .audit import (
    AO_FRACTION,
    Applicability,
    AuditError,
    SceneInfo,
    alternatives,
    default_ao_distance,
    family_note,
    missing_text,
    scene_summary,
    vec_text,
)
from .families import METHOD_TABLES, RULES
from .registry import ALIASES

__all__ = ["applicable_families", "describe", "needs_overall", "requirement", "resolve_approx"]


def requirement(family: str) -> str:
    return " or ".join(alternatives(r for r in RULES if r.family == family))


def resolve_approx(approx) -> list[str] | None:
    if approx is None:
        return None
    names = [a.strip() for a in (approx.split(",") if isinstance(approx, str) else approx)]
    out = []
    for name in names:
        family = ALIASES.get(name, name.replace("_", "-"))
        if family not in METHOD_TABLES:
            raise AuditError(
                f"--approx {name!r}: unknown approximation family (known: {', '.join(METHOD_TABLES)})"
            )
        if family not in out:
            out.append(family)
    if not out:
        raise AuditError(f"--approx {approx!r}: name at least one family (known: {', '.join(METHOD_TABLES)})")
    return out


def applicable_families(
    scene_info: SceneInfo, *, approx=None, ao_distance: float | None = None
) -> list[Applicability]:
    """Every (family, reason) that applies to ``scene_info`` by `RULES`, in rule order then part order.
    ``approx`` (``"a,b"`` or a list of family names) restricts the families; a named family that does not
    apply, or a scene to which none applies, raises `AuditError` (one line saying why)."""
    wanted = resolve_approx(approx)
    radius = ao_distance if ao_distance is not None else default_ao_distance(scene_info)
    radius_text = f"{radius:.4g}" if radius is not None else "(unknown: pass --ao-distance)"
    out: list[Applicability] = []
    for rule in RULES:
        if wanted is not None and rule.family not in wanted:
            continue
        if not all(scene_info.has(k) for k in rule.needs[1:]):
            continue
        others = [scene_info.first(k) for k in rule.needs[1:] if k != "surface"]
        with_ = " and ".join(p.label for p in others if p is not None) or "the scene"
        for part in scene_info.parts:
            if rule.needs[0] not in part.kinds:
                continue
            available = part.provides.union(*(p.provides for p in others if p is not None), rule.supplies)
            methods, excluded = [], []
            for mid, method in METHOD_TABLES[rule.family].items():
                missing = {i.name for i in method.inputs} - available
                if missing:
                    excluded.append((mid, missing_text(missing)))
                else:
                    methods.append(mid)
            if not methods:
                continue
            fmt = {"part": part.label, "with_": with_, "ao_distance": radius_text}
            out.append(
                Applicability(
                    rule.family,
                    rule.role,
                    part.label,
                    tuple(methods),
                    tuple(excluded),
                    rule.reason.format(**fmt),
                    rule.reference.format(**fmt),
                    rule.integrator.format(**fmt),
                    part.source,
                )
            )
    found = {a.family for a in out}
    for family in wanted or ():
        if family not in found:
            raise AuditError(
                f"{family} does not apply to {scene_info.source}: it needs {requirement(family)}"
                f"; the scene has {scene_summary(scene_info)}{family_note(scene_info, family)}"
            )
    if not out:
        raise AuditError(
            f"no approximation family applies to {scene_info.source}: it has {scene_summary(scene_info)}; "
            f"a family needs {needs_overall()}"
        )
    return out


def needs_overall() -> str:
    return "; or ".join(alternatives(RULES))


# ----------------------------------------------------------------------------------------------- listing
def describe(
    info: SceneInfo, found: list[Applicability], *, ao_distance: float | None = None, restricted: bool = False
) -> list[str]:
    """The ``--list`` text, line by line (``restricted``: ``--approx`` was given, so the families left out
    are not listed as not applying)."""
    lines = [f"scene: {info.source} ({info.format})"]
    lines += [f"  {c}" for c in info.contents]
    lines.append(f"camera: {info.camera}")
    lines.append(f"up: {info.up_reason}")
    if info.bbox is not None:
        auto = default_ao_distance(info)
        if ao_distance is not None:
            lines.append(f"AO distance: {ao_distance:.4g} (--ao-distance)")
        elif auto is not None:
            lines.append(
                f"AO distance: {auto:.4g} = {AO_FRACTION:g} × the bounding-box diagonal {info.diagonal:.4g} "
                f"(box {vec_text(info.bbox[0])}–{vec_text(info.bbox[1])}; --ao-distance overrides)"
            )
    lines.append("")
    lines.append("applies:")
    for a in found:
        lines.append(f"  {a.family} — {a.role}: {a.reason}")
        lines.append(f"      methods:    {', '.join(a.methods)}")
        lines.append(f"      reference:  {a.reference}")
        lines.append(f"      integrator: {a.integrator}")
        elsewhere = {m for b in found if b.family == a.family for m in b.methods} - set(a.methods)
        left: dict[str, list[str]] = {}  # the kind of part each needs → rows (what follows "needs …: ")
        for m, reason in a.excluded:
            if m in elsewhere:  # a row this family runs on another part (a light model of another light)
                left.setdefault(reason.rsplit(": ", 1)[-1], []).append(m)
        if left:
            said = "; ".join(f"{', '.join(ms)} (need {kind})" for kind, ms in left.items())
            lines.append(f"      left out:   {said}")
    for family in dict.fromkeys(a.family for a in found):  # methods of an applying family that none use
        used = {m for a in found if a.family == family for m in a.methods}
        why: dict[str, list[str]] = {}
        for a in found:
            for mid, text in a.excluded:
                if a.family == family and mid not in used and mid not in why.get(text, []):
                    why.setdefault(text, []).append(mid)
        for text, mids in why.items():
            lines.append(f"  {family}, not here: {', '.join(mids)} ({text})")
    missing = [f for f in METHOD_TABLES if f not in {a.family for a in found}]
    if missing and not restricted:
        lines.append("does not apply:")
        for family in missing:
            lines.append(f"  {family}: needs {requirement(family)}{family_note(info, family)}")
    return lines
