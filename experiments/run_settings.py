"""The settings a run samples and renders with, as one object: `RunSettings` (the Mitsuba variant, the
reference samples per pixel and per cached pass, the seed, the reference cache, progress bars and the quick
configuration).

A command builds one (``rtfit run`` from its options, ``rtfit sweep`` from its sweep file) and the Python
API builds one from its keywords (`rtfit.audit`, `rtfit.compare`: `RunSettings.checked`, the one place
their values are validated); the engine takes it whole: an experiment's `RunContext`
(`RunSettings.context`), an audited scene's `AuditSetup` (`RunSettings.setup`), a sweep point's job.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rtfit.reference.cache import default_cache_dir
from rtfit.reference.variants import resolve_variant

from .audit import AuditError
from .audit_options import check_sizes
from .audit_setup import AuditSetup
from .registry import RunContext

__all__ = ["DEFAULT_PASS_SPP", "DEFAULT_SPP", "RunSettings"]

DEFAULT_SPP = 256
"""Reference samples per pixel of an audit or a comparison when none are given."""
DEFAULT_PASS_SPP = 32
"""Samples per cached pass of an audit or a comparison when none are given (at most ``spp``)."""


@dataclass(frozen=True)
class RunSettings:
    """How one run samples and renders: ``cache_dir`` the reference cache, ``variant`` the Mitsuba variant
    (its Dr.Jit backend runs the approximations), ``spp`` the reference samples per pixel (None: each
    experiment's own) in passes of ``pass_spp`` (None: the experiment's own), ``seed``, ``progress``
    (draw progress bars) and ``quick`` (an experiment's quick configuration). Plain data: it crosses a
    job boundary (a sweep point's job) as it is."""

    cache_dir: Path
    variant: str = "llvm_ad_rgb"
    spp: int | None = None
    pass_spp: int | None = None
    seed: int = 0
    progress: bool = False
    quick: bool = False

    @classmethod
    def checked(
        cls,
        *,
        variant: str | None,
        spp: int | None,
        pass_spp: int | None,
        seed: int,
        cache,
        progress: bool,
        needs: str,
        width: int | None = None,
        height: int | None = None,
    ) -> RunSettings:
        """The settings of an audit or a comparison from the Python API's keywords, validated: ``variant``
        resolved (None: ``llvm_ad_rgb``; a scalar variant is refused, the line saying who needs a
        vectorised one: ``needs``, e.g. "the audit needs"), ``spp`` (None: `DEFAULT_SPP`) and ``pass_spp``
        (None: `DEFAULT_PASS_SPP`, at most ``spp``) at least 2 and within the limits (`registry.LIMITS`,
        with the film's ``width`` and ``height`` where given), ``cache`` (None: `default_cache_dir`). Each
        bad value is one `AuditError` line, before anything is read or rendered."""
        try:
            variant = resolve_variant(variant or "llvm_ad_rgb")
        except ValueError as e:
            raise AuditError(f"--variant: {e}") from None
        spp = int(spp or DEFAULT_SPP)
        pass_spp = int(pass_spp or min(DEFAULT_PASS_SPP, spp))
        if spp < 2 or pass_spp < 2:
            raise AuditError(f"--spp {spp}: at least 2 samples per pixel (the variance needs two)")
        if variant.startswith("scalar"):
            raise AuditError(f"--variant {variant}: {needs} a vectorised variant (llvm_ad_rgb, cuda_ad_rgb)")
        check_sizes(spp, pass_spp, width, height)
        cache_dir = Path(cache) if cache is not None else default_cache_dir()
        return cls(cache_dir, variant, spp, pass_spp, int(seed), progress)

    def samples(self) -> tuple[int, int]:
        """``(spp, pass_spp)`` of a reference rendered with these settings: both must be given (an audit's
        are, `checked`), else a ValueError."""
        if self.spp is None or self.pass_spp is None:
            raise ValueError(f"run settings without spp or pass_spp: {self} (a reference needs both)")
        return self.spp, self.pass_spp

    def context(self, out_dir: Path, executor, overrides: Mapping | None = None) -> RunContext:
        """The `RunContext` of one experiment run with these settings into ``out_dir`` on ``executor``,
        with the sweep ``overrides`` of its configuration keys (none: its defaults)."""
        return RunContext(
            out_dir=Path(out_dir),
            cache_dir=Path(self.cache_dir),
            executor=executor,
            quick=self.quick,
            variant=self.variant,
            spp=self.spp,
            seed=self.seed,
            progress=self.progress,
            overrides=dict(overrides or {}),
        )

    def setup(
        self, mi, scene, sensor, emitters: tuple, info, gbuffer, mask, scene_digest: str, **optional: Any
    ) -> AuditSetup:
        """The `AuditSetup` of one audited scene with these (`checked`) settings: the loaded scene (``mi``,
        ``scene``, ``sensor``, ``emitters``), its ``info``, ``gbuffer``, ``mask`` and ``scene_digest``, and
        ``optional`` its optional fields (``ao_distance``, ``source``, ``probe_at``, …)."""
        spp, pass_spp = self.samples()
        return AuditSetup(
            mi=mi, scene=scene, sensor=sensor, emitters=emitters, info=info, gbuffer=gbuffer, mask=mask,
            cache_root=self.cache_dir, variant=self.variant, spp=spp, pass_spp=pass_spp, seed=self.seed,
            progress=self.progress, scene_digest=scene_digest, **optional,
        )  # fmt: skip
