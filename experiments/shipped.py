"""What a family ships for ``rtfit run FAMILY`` beside its audit declaration
(`rtfit.experiments.audit_family`): its scenes (`ShippedScene`, audited by the engine exactly as
``rtfit audit`` audits a user's scene) and its own study (`Study`: the tables and figures only this
family has, given a `StudyContext`), and the render sizes a family's scenes share (`Sizes`)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["ShippedScene", "Sizes", "Study", "StudyContext"]


@dataclass(frozen=True)
class ShippedScene:
    """A scene a family ships for ``rtfit run FAMILY`` (issue 30 §1): the engine audits it for this family
    alone, exactly as ``rtfit audit`` audits a user's scene. ``file``: a Mitsuba XML or rtfit TOML file in
    rtfit's scene library (``scenes/library/``); ``label``: one line for the report; ``size`` (width,
    height) and ``spp`` of the full run, ``quick_size`` and ``quick_spp`` of ``--quick`` (a family writes
    them once for its scenes: `Sizes`); ``options``: the audit's keyword options for this scene
    (``ao_distance``, ``grid``, ``probe_at``, ``pom_depth``)."""

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
class Sizes:
    """The render sizes a family's shipped scenes share, written once: ``full`` = (width, height, spp) of
    ``rtfit run FAMILY``, ``quick`` = (width, height, spp) of ``--quick``. ``scene(file, label, …)`` is the
    `ShippedScene` at these sizes (its ``size``, ``spp``, ``quick_size``, ``quick_spp``)."""

    full: tuple[int, int, int]
    quick: tuple[int, int, int]

    def __post_init__(self):
        for what, v in (("full", self.full), ("quick", self.quick)):
            if len(v) != 3 or not all(isinstance(n, int) and n > 0 for n in v):
                raise ValueError(f"sizes: {what} = {v!r}: (width, height, spp), three positive whole numbers")

    def scene(self, file: str, label: str, **keywords: Any) -> ShippedScene:
        """The `ShippedScene` of ``file`` and ``label`` at these sizes; ``keywords``: its other fields."""
        (w, h, spp), (qw, qh, qspp) = self.full, self.quick
        return ShippedScene(
            file, label, size=(w, h), spp=spp, quick_size=(qw, qh), quick_spp=qspp, **keywords
        )


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
