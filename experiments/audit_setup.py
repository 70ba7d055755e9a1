"""What a family's cases are given and make their references with: the run's `AuditSetup` (the scene in
the audit's Mitsuba variant, its G-buffer and mask, the cache and sampling settings), `AuditReference` (an
image with its per-pixel standard error and the mask it was made for) and `pooled_passes` (a family's
reference passes through the pass cache, pooled: `PooledPasses`, whose ``reference`` is the case's
`AuditReference`)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import drjit as dr
import numpy as np

from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR, PassEntry, pass_size, pool_passes
from rtfit.reference.estimators import GBuffer, PassResult, launch_identity, sub_seed

from .audit import SceneInfo
from .case_inputs import masked_image

__all__ = ["AuditReference", "AuditSetup", "PooledPasses", "pooled_passes"]


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
    unchecked: np.ndarray | None = None
    """(H, W) True where the estimator's own sample variance does not measure its error (heavy-tailed
    weights: a ratio tracker past its variance target, `rtfit.reference.medium_transmittance.
    variance_exponents`): those pixels are compared and shown, but the exact row's z-checks leave them out
    (`audit_results._checks`); None: every pixel is judged."""

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
        unchecked: np.ndarray | None = None,
    ) -> AuditReference:
        """The `AuditReference` these passes give on the pixels of ``mask`` (element i is the i-th masked
        pixel, row-major): ``mean`` and ``stderr`` (their ``columns``: three RGB columns, or all of a grey
        (N,) pass) as (H, W, 3) images (`masked_image`), the samples and passes, the cache entry's key and
        folder, the seconds of rendering plus ``extra_seconds`` (another pass the case needed, e.g. a
        bake), and the report's words (``quantity`` with units, ``integrator``, ``integrator_reason``);
        ``precision``: the relative precision floor per masked element ((N,), `AuditReference.precision`);
        ``unchecked``: per masked element, True where its noise is not measured by its sample variance ((N,),
        `AuditReference.unchecked`)."""
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
            unchecked=None if unchecked is None else _masked_flags(mask, unchecked),
        )


def _masked_flags(mask: np.ndarray, flags) -> np.ndarray:
    """(H, W) bool: ``flags`` (one per masked pixel, row-major) on the pixels of ``mask``, False elsewhere."""
    out = np.zeros(mask.shape, bool)
    out[mask] = np.asarray(flags, bool).reshape(-1)
    return out


def _run_identity(setup: AuditSetup, what: Mapping[str, Any]) -> dict:
    """A cache entry's key: the family's part ``what`` and the run's (scene digest, variant, seed, pass size,
    Mitsuba and Dr.Jit versions, and the GPU's launch layout, `launch_identity`)."""
    import mitsuba as mi  # (its version is part of the key)

    return {
        **what,
        "scene": setup.scene_digest,
        "variant": setup.variant,
        "seed": setup.seed,
        "pass_spp": setup.pass_spp,
        "versions": {"mitsuba": mi.__version__, "drjit": dr.__version__},
        **launch_identity(setup.variant),
    }


def cached_pass(
    setup: AuditSetup,
    what: Mapping[str, Any],
    render: Callable[[], PassResult],
    shape: tuple[int, ...],
    label: str,
    spp: int,
) -> PassResult:
    """One Monte Carlo pass of ``spp`` samples through the pass cache (``render()`` where it is not there),
    keyed as `pooled_passes` keys a reference: a family's input that is itself a render (colour-bleeding's
    direct light at its rays' hits, an engine's direct-light buffer), loaded on a second audit of the scene
    instead of rendered again (issue 33: 4 of the ~40 s of a cached 256² Cornell-box audit). ``what`` must
    name everything the pass depends on beyond the run (its points, its spp, its seed's label)."""
    entry = PassEntry(setup.cache_root, _run_identity(setup, what), namespace="audit", storage="npz",
                      info={"label": label})  # fmt: skip
    passes, _ = entry.passes(1, lambda _i: render(), shape=shape, progress=setup.progress, label=label,
                             spp_of=lambda _i: spp)  # fmt: skip
    return passes[0]


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
    entry = PassEntry(setup.cache_root, _run_identity(setup, what), namespace="audit", storage="npz",
                      info={"label": label})  # fmt: skip
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
