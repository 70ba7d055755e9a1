"""Content-addressed, resumable cache of Monte Carlo references.

An entry is identified by a SHA-256 key over everything that determines its samples: the scene's
physics hash (`rtfit.scenes.scene_hash`, which hashes referenced files by content), the quantity
(radiance image or irradiance probes, with the probe points), the integrator chosen by the rule,
the variant, the base seed, the samples per pass, the Mitsuba and Dr.Jit versions and the format
version of this module. The requested total ``spp`` is *not* part of the key: an entry holds
independent passes, pass *i* seeded with ``sub_seed(seed, "pass", i)``, and a request for N samples
uses exactly its first ceil(N / pass_spp) passes, rendering only those not cached yet. So a result
never depends on the cache's history, an interrupted run loses at most the pass in flight, and
asking for more samples later adds passes to the same entry.

Layout: ``ROOT/<key[:2]>/<key>/`` with ``pass-NNNNN.exr`` (per-element mean and unbiased sample
variance, float32 channels ``mean.*`` and ``var.*``), ``pass-NNNNN.json`` (its seed, spp and
timing; a pass counts only once both files exist), ``entry.json`` (what the entry is, for humans
and tools) and ``reference.exr`` (the latest combination: ``R,G,B`` mean and ``stderr.*``). Every
file is written atomically, so two workers finishing the same pass overwrite it with identical
content and never leave half a file.

Combination of passes (sizes n_i, means m_i, variances s_i², N = Σ n_i) is exact pooling:
mean M = Σ n_i m_i / N, variance S² = [Σ (n_i − 1) s_i² + Σ n_i (m_i − M)²] / (N − 1), and the
standard error of M is sqrt(S² / N), computed in float64.

This module holds the reference requests (`ReferenceRequest`, its key) and `ReferenceCache`; the pass store
they are kept in (`PassEntry`, `ComputedEntry`, claims, `entry_key`, `pool_passes`) is
`rtfit.reference.pass_entry`, and ``rtfit cache info``/``prune``'s scanning and removal
`rtfit.reference.cache_prune`; their names are re-exported here (`__all__`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.scenes import Scene, scene_hash, scene_to_dict

from . import fog_integrator
from .build import load_mitsuba_scene
from .cache_prune import (
    CACHE_NAMESPACES,
    CacheEntry,
    CacheSummary,
    leftover_removals,
    prune_plan,
    remove_entry,
    remove_leftover,
    scan_cache,
)
from .estimators import PassResult, device_probes, irradiance_pass, launch_identity, radiance_pass, sub_seed
from .height_fog import ESTIMATOR as FOG_ESTIMATOR
from .integrators import choose_integrator
from .io import write_exr
from .mitsuba_xml import xml_dependencies
from .pass_entry import (
    CLAIM_POLL_SECONDS,
    CLAIM_STALE_SECONDS,
    PASS_COUNTS,
    ComputedEntry,
    PassCounts,
    PassEntry,
    array_digest,
    entry_key,
    pass_size,
    pool_passes,
)
from .variants import callers_variant

__all__ = [
    "CACHE_FORMAT",
    "CACHE_NAMESPACES",
    "CLAIM_POLL_SECONDS",
    "CLAIM_STALE_SECONDS",
    "DEFAULT_PASS_SPP",
    "PASS_COUNTS",
    "QUANTITIES",
    "REFERENCE_PASS_DTYPE",
    "RELATIVE_PRECISION_FLOOR",
    "CacheEntry",
    "CacheSummary",
    "ComputedEntry",
    "PassCounts",
    "PassEntry",
    "PassResult",
    "Reference",
    "ReferenceCache",
    "ReferenceRequest",
    "array_digest",
    "default_cache_dir",
    "entry_key",
    "leftover_removals",
    "pass_size",
    "pool_passes",
    "prune_plan",
    "remove_entry",
    "remove_leftover",
    "scan_cache",
]

CACHE_FORMAT = 1
DEFAULT_PASS_SPP = 256
# Relative resolution of a reference value, whatever its sample count: Mitsuba's and rtfit's
# per-sample weights are float32. Empirical: the largest deviation from a closed form seen with a
# statistical error far below it was 3.6e-6 relative (0.27° sun + constant sky, irradiance probes,
# statistical error 6e-8); 1e-5 leaves margin. Used by `Reference.sigma`.
RELATIVE_PRECISION_FLOOR = 1e-5
QUANTITIES = ("radiance", "irradiance")
REFERENCE_PASS_DTYPE = np.float32
"""The precision `ReferenceCache` stores its radiance and irradiance passes in (EXR, float32), and so the
precision those passes round their float64 mean and variance to on the device before the copy to the host
(``radiance_pass(..., dtype=)``): the values stored are bit-identical to rounding on the host (both round to
nearest even), with half the bytes copied from a GPU. Benchmarks time reference passes with it."""


def default_cache_dir() -> Path:
    """``$RTFIT_CACHE`` if set, else ``$XDG_CACHE_HOME/rtfit`` (``~/.cache/rtfit``)."""
    env = os.environ.get("RTFIT_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rtfit"


@dataclass(frozen=True)
class ReferenceRequest:
    """What to estimate. Plain data only (safe to send to another process or machine).

    ``quantity="radiance"``: point-sampled radiance at every pixel centre of the scene's camera.
    ``quantity="irradiance"``: irradiance at ``points`` (N, 3) with unit ``normals`` (N, 3), with
    ``transport`` "direct" (MIS emitter + cosine sampling) or "global" (path-traced).
    """

    scene: Scene
    spp: int
    quantity: str = "radiance"
    seed: int = 0
    variant: str = "llvm_ad_rgb"
    pass_spp: int = DEFAULT_PASS_SPP
    points: np.ndarray | None = field(default=None, compare=False)
    normals: np.ndarray | None = field(default=None, compare=False)
    transport: str = "direct"

    def __post_init__(self):
        if self.quantity not in QUANTITIES:
            raise ValueError(f"quantity must be one of {QUANTITIES} (got {self.quantity!r})")
        if not isinstance(self.spp, int) or self.spp < 2:
            raise ValueError(f"spp must be an integer >= 2 (got {self.spp!r})")
        if not isinstance(self.pass_spp, int) or self.pass_spp < 2:
            raise ValueError(f"pass_spp must be an integer >= 2 (got {self.pass_spp!r})")
        if self.quantity == "irradiance":
            if self.points is None or self.normals is None:
                raise ValueError("an irradiance request needs points and normals")
            p = np.asarray(self.points, dtype=np.float64)
            n = np.asarray(self.normals, dtype=np.float64)
            if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape:
                raise ValueError(f"points and normals must both be (N, 3) (got {p.shape} and {n.shape})")
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n))):
                raise ValueError("points and normals must be finite")
            norms = np.linalg.norm(n, axis=1)
            if np.any(np.abs(norms - 1.0) > 1e-3):
                raise ValueError("normals must be unit length (normalise them first)")

    @property
    def passes(self) -> int:
        return -(-self.spp // self.pass_spp)

    def integrator(self) -> dict:
        if self.quantity == "radiance":
            return choose_integrator(self.scene).to_dict()
        return {
            "type": f"irradiance-probe-{self.transport}",
            "max_depth": None,
            "reason": "Mitsuba emitter sampling + cosine sampling (MIS)"
            if self.transport == "direct"
            else "path-traced radiance along cosine-sampled directions",
        }

    def key(self) -> str:
        """The cache key: `entry_key` of `identity`."""
        return entry_key(self.identity())

    def identity(self) -> dict:
        """Everything that determines this request's samples (see the module docstring)."""
        import mitsuba  # mitsuba: loaded only where a reference is made (its version is in the key)

        ident = {
            "format": CACHE_FORMAT,
            "scene": scene_hash(self.scene),
            "quantity": self.quantity,
            "integrator": self.integrator(),
            "variant": self.variant,
            "seed": self.seed,
            "pass_spp": self.pass_spp,
            "versions": {"mitsuba": mitsuba.__version__, "drjit": dr.__version__},
            **launch_identity(self.variant),
        }
        if any(m.kind == "exponential_fog" for m in self.scene.media):  # the estimator made the samples
            fog_path = fog_integrator.applies(self.scene, choose_integrator(self.scene).mitsuba_dict())
            ident["medium_estimator"] = fog_integrator.ESTIMATOR if fog_path else FOG_ESTIMATOR
        xml = [sh.file for sh in self.scene.shapes if sh.kind == "mitsuba_xml"]
        if xml:  # every file Mitsuba's parser loads for them (includes, <path> meshes), not only the XML
            ident["xml_files"] = [xml_dependencies(f, variant=self.variant).digest for f in xml]
        if self.quantity == "irradiance":
            ident["probes"] = array_digest(self.points, self.normals)
            ident["transport"] = self.transport
        return ident


@dataclass(frozen=True)
class Reference:
    """A combined Monte Carlo reference: ``mean`` and its per-element standard error ``stderr``.

    Arrays are float64, (H, W, 3) for radiance images and (N, 3) for irradiance probes.
    """

    key: str
    path: str
    quantity: str
    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    passes_rendered: int  # how many of ``passes`` this call rendered (the rest came from the cache)
    integrator: dict
    variant: str
    render_seconds: float  # summed over all passes used, whenever they were rendered

    def sigma(self) -> np.ndarray:
        """Uncertainty to compare against: the standard error combined with the float32 precision
        floor, sqrt(stderr² + (RELATIVE_PRECISION_FLOOR·|mean|)²). Use it for z-scores and noise floors."""
        return np.sqrt(self.stderr**2 + (RELATIVE_PRECISION_FLOOR * self.mean) ** 2)

    @property
    def samples_per_second(self) -> float:
        n = self.mean.shape[0] * (self.mean.shape[1] if self.mean.ndim == 3 else 1)
        return n * self.spp / self.render_seconds if self.render_seconds > 0 else math.nan

    def to_dict(self) -> dict:
        """Metadata for results files (no arrays)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = self.stderr / np.abs(self.mean)
        rel = rel[np.isfinite(rel) & (np.abs(self.mean) > 0)]
        return {
            "cache_key": self.key,
            "quantity": self.quantity,
            "integrator": self.integrator.get("type"),
            "max_depth": self.integrator.get("max_depth"),
            "integrator_reason": self.integrator.get("reason"),
            "variant": self.variant,
            "spp": self.spp,
            "passes": self.passes,
            "mean_rel_stderr": float(np.mean(rel)) if rel.size else 0.0,
            "samples_per_second": float(self.samples_per_second) if self.render_seconds > 0 else None,
        }


class ReferenceCache:
    """The cache rooted at ``root`` (created on first write)."""

    def __init__(self, root=None):
        self.root = Path(root) if root is not None else default_cache_dir()

    def entry_dir(self, key: str) -> Path:
        return self.root / key[:2] / key

    def get(
        self, request: ReferenceRequest, *, progress: bool = False, label: str | None = None
    ) -> Reference:
        """Return the reference for ``request``, rendering only the passes not cached yet."""
        entry = PassEntry(self.root, request.identity(), storage="exr", info=self._entry_info(request))
        key = entry.key
        as_points = request.quantity == "irradiance"
        loaded: dict = {}

        def load_scene():
            loaded["mi"], loaded["scene"] = load_mitsuba_scene(request.scene, request.variant)
            if as_points:  # on the device once for all the passes rendered
                loaded["probes"] = device_probes(
                    loaded["mi"], request.points, request.normals, normalise=False
                )

        def render(i: int) -> PassResult:
            pass_spp = pass_size(request.spp, request.pass_spp, i)
            seed = sub_seed(request.seed, "pass", i)
            mi, mi_scene = loaded["mi"], loaded["scene"]
            if as_points:
                return irradiance_pass(
                    mi,
                    mi_scene,
                    loaded["probes"],
                    None,
                    pass_spp,
                    seed,
                    request.transport,
                    REFERENCE_PASS_DTYPE,
                )
            return radiance_pass(mi, mi_scene, pass_spp, seed, REFERENCE_PASS_DTYPE)

        with callers_variant():  # rendering activates request.variant; the caller's comes back
            passes, rendered = entry.passes(
                request.passes,
                render,
                shape=(-1, 3) if as_points else None,
                progress=progress,
                label=label or f"reference {key[:8]}",
                before_render=load_scene,
                spp_of=lambda i: pass_size(request.spp, request.pass_spp, i),
            )
        mean, stderr, total = pool_passes(passes)
        if rendered:
            shape = (1, -1, 3) if as_points else mean.shape
            write_exr(
                entry.folder / "reference.exr", {"RGB": mean.reshape(shape), "stderr": stderr.reshape(shape)}
            )
        return Reference(
            key=key,
            path=str(entry.folder),
            quantity=request.quantity,
            mean=mean,
            stderr=stderr,
            spp=total,
            passes=len(passes),
            passes_rendered=rendered,
            integrator=request.integrator(),
            variant=request.variant,
            render_seconds=float(sum(p.seconds for p in passes)),
        )

    def _entry_info(self, request: ReferenceRequest) -> dict:
        """What entry.json adds to the identity, for humans and tools: the whole scene."""
        return {"scene_dict": scene_to_dict(request.scene), "scene_hash": scene_hash(request.scene)}
