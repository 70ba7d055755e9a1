r"""Incident radiance at free-space probe positions, projected onto caller-given direction functions.

For a probe at p and direction functions f_k(ω) (e.g. the 9 SH basis functions, or clamped cosines
max(n·ω, 0) that give the irradiance at normal n), one pass estimates per probe, per function and per RGB
channel

    P_k(p) = ∫_{S²} L_i(p, ω) f_k(ω) dω          (L_i: path-traced incident radiance, W·m⁻²·sr⁻¹)

with ``spp`` iid directions ω_j uniform on the sphere (density 1/(4π)) and one Mitsuba ``path`` sample of
L_i(p, ω_j) each (unbounded depth, Russian roulette: unbiased): the sample mean of 4π L_i(p, ω_j) f_k(ω_j)
and its unbiased sample variance. All functions share the same directions and paths, so their estimates are
correlated (as the projections of one baked probe are). A point light is never hit by a ray, so in a scene
lit by point lights only, L_i is the bounced (indirect) light: what Valve's irradiance volume stores
(seed 000:2502-2515; the point light's direct part is folded in analytically, see
`rtfit.realtime.irradiance_volumes.fold_point_light`).

The functions come from the caller (``features(directions (M, 3)) -> (M, K)``, NumPy float64): this layer
does not import the real-time bases. Radiance is reduced against them in float64 NumPy per chunk of probes.

`ProbeRadianceCache` stores passes in rtfit's one pass store (`rtfit.reference.cache.PassEntry`, namespace
``probe_radiance``, ``.npz``), keyed by the scene's physics hash, the probe positions, the functions (their
name and values at fixed directions), seed, samples per pass, variant and versions.

`point_light_visibility` tests, with Mitsuba's shadow rays, whether each probe sees a point light (for
folding the light into the probe); `delta_light_irradiance` gives, for every delta light of a scene (point,
spot, directional), its direction and shadowed irradiance at normal incidence at given points, from
Mitsuba's own emitter sampling (exact: a delta light has one direction, no noise).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import numpy as np

from .cache import PassEntry, array_digest, pool_passes
from .device_arrays import mapped_floats
from .estimators import PassResult, check_spp, device_vectors, mean_var, sub_seed

__all__ = ["FORMAT", "ProbeRadiance", "ProbeRadianceCache", "point_light_visibility", "probe_radiance_pass"]

FORMAT = 1
"""Version of the probe-radiance cache entries."""
MAX_LANES = 1 << 18
"""Paths per launch: the per-lane NumPy arrays (K function values and their squares, float64) stay at
2 · 2^18 · K · 8 bytes (≈ 330 MB for the experiment's K = 79)."""
_CHECK_DIRECTIONS = np.array(
    [[0.0, 0.0, 1.0], [0.6, 0.0, -0.8], [0.36, -0.48, 0.8], [-0.8, 0.36, 0.48], [0.0, -1.0, 0.0]]
)


def probe_radiance_pass(
    mi, mi_scene, positions, features: Callable[[np.ndarray], np.ndarray], spp: int, seed: int
) -> PassResult:
    """P_k(p) (module docstring) at ``positions`` (P, 3): mean and variance (P, K, 3) of ``spp`` samples."""
    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("the probe-radiance pass needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    t0 = time.perf_counter()
    pts = np.ascontiguousarray(positions, dtype=np.float32)
    n_probes = len(pts)
    k = np.asarray(features(_CHECK_DIRECTIONS)).shape[1]
    s = np.zeros((n_probes, k, 3))
    q = np.zeros((n_probes, k, 3))
    integrator = mi.load_dict({"type": "path", "max_depth": -1})
    sampler = mi.load_dict({"type": "independent"})
    per_launch = max(1, MAX_LANES // spp)
    for c, a in enumerate(range(0, n_probes, per_launch)):
        b = min(n_probes, a + per_launch)
        lanes = (b - a) * spp
        sampler.seed(sub_seed(seed, "chunk", c), lanes)
        idx = dr.arange(mi.UInt32, lanes) // spp
        o = dr.gather(mi.Point3f, device_vectors(mi, mi.Point3f, pts[a:b]), idx)
        d = mi.warp.square_to_uniform_sphere(sampler.next_2d())
        radiance, _, _ = integrator.sample(mi_scene, sampler, mi.Ray3f(o, d), None, True)
        dr.eval(radiance, d)
        lv = np.stack([np.asarray(radiance[ch], dtype=np.float64) for ch in range(3)], axis=-1)
        dv = np.stack([np.asarray(d[ch], dtype=np.float64) for ch in range(3)], axis=-1)
        lv = 4.0 * math.pi * np.where(np.isfinite(lv), lv, 0.0).reshape(b - a, spp, 3)
        f = np.asarray(features(dv), dtype=np.float64).reshape(b - a, spp, k)
        # Σ_s f_k·L_c per probe as a batched matrix product (P, K, S) @ (P, S, 3): one BLAS product per probe,
        # ~10× NumPy's einsum loop of the same sums (issue 33: 4 s of the quick suite); the order of the
        # additions differs, ~1e-16 relative
        ft = f.transpose(0, 2, 1)
        s[a:b] = np.matmul(ft, lv)
        q[a:b] = np.matmul(ft * ft, lv * lv)
    mean, var = mean_var(s, q, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def point_light_visibility(mi, mi_scene, positions, light_position) -> np.ndarray:
    """1.0 where the segment from each position (P, 3) to ``light_position`` meets no surface (Mitsuba
    ``Scene.ray_test`` over the open segment, 1e-4 relative margin at the light's end), else 0.0 (P,)."""
    p = np.asarray(positions, dtype=np.float64)
    q = np.asarray(light_position, dtype=np.float64)
    delta = q[None, :] - p
    dist = np.linalg.norm(delta, axis=1)
    if np.any(dist <= 0.0):
        raise ValueError("a position coincides with the light")
    d = delta / dist[:, None]
    ray = mi.Ray3f(mi.Point3f(p.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    ray.maxt = mapped_floats(mi.Float, dist * (1.0 - 1e-4))
    blocked = mi_scene.ray_test(ray)
    return np.where(np.asarray(blocked, dtype=bool), 0.0, 1.0)


def delta_light_irradiance(mi, mi_scene, points, normals=None) -> list[tuple[np.ndarray, np.ndarray]]:
    """For every delta emitter of ``mi_scene`` (Mitsuba ``EmitterFlags.Delta``: point, spot, directional) in
    ``mi_scene.emitters()`` order: (d (N, 3) unit direction towards the light, E⊥ (N, 3) W/m² RGB) at
    ``points`` (N, 3): the emitter's ``sample_direction`` (for a delta light its one direction, weight
    I/r² with a spot's falloff), times 1/0 from a Mitsuba shadow ray (``ray_test``, 1e-4 relative margin at
    the light's end). With ``normals`` (N, 3) the points are on a surface: the shadow ray leaves it as
    Mitsuba spawns rays (offset along the normal). The irradiance at normal n is Σ E⊥·max(n·d, 0)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) (got {p.shape})")
    if normals is None:
        it = dr.zeros(mi.Interaction3f, len(p))
    else:
        it = dr.zeros(mi.SurfaceInteraction3f, len(p))
        it.n = mi.Normal3f(np.asarray(normals, dtype=np.float64).T.astype(np.float32))
    it.p = mi.Point3f(p.T.astype(np.float32))
    out = []
    for emitter in mi_scene.emitters():
        if not mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta):
            continue
        ds, weight = emitter.sample_direction(it, mi.Point2f(0.5, 0.5), True)
        ray = it.spawn_ray_to(ds.p) if normals is not None else mi.Ray3f(it.p, ds.d)
        dist = np.asarray(ds.dist, dtype=np.float64)
        if normals is None:
            ray.maxt = mapped_floats(mi.Float, np.where(np.isfinite(dist), dist * (1.0 - 1e-4), np.inf))
        else:
            ray.maxt = ray.maxt * (1.0 - 1e-4)
        visible = ~np.asarray(mi_scene.ray_test(ray), dtype=bool)
        # (a directional light's direction and weight come back as one value for every point: broadcast)
        d = np.broadcast_to(np.asarray(ds.d, dtype=np.float64).reshape(3, -1).T, p.shape)
        e = np.broadcast_to(np.asarray(weight, dtype=np.float64).reshape(3, -1).T, p.shape) * visible[:, None]
        out.append((np.ascontiguousarray(d), np.ascontiguousarray(e)))
    return out


@dataclass(frozen=True)
class ProbeRadiance:
    """Pooled probe projections: ``mean`` and ``stderr`` (P, K, 3) over ``spp`` directions per probe."""

    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    seconds: float
    key: str

    @property
    def samples_per_second(self) -> float:
        return self.mean.shape[0] * self.spp / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict:
        return {
            "integrator": "path (max_depth -1) along uniform sphere directions from each probe",
            "quantity": "probe_radiance_projections",
            "spp": self.spp,
            "passes": self.passes,
            "cache_key": self.key,
            "samples_per_second": float(self.samples_per_second) if self.seconds > 0 else None,
        }


class ProbeRadianceCache:
    """Resumable pass cache of `probe_radiance_pass` (one `PassEntry` per request, namespace
    ``probe_radiance``). Pass i is seeded with ``sub_seed(seed, "pass", i)``."""

    def __init__(self, root):
        self.root = Path(root)

    def get(
        self,
        mi,
        mi_scene,
        scene_hash: str,
        positions,
        features: Callable[[np.ndarray], np.ndarray],
        features_name: str,
        *,
        spp: int,
        pass_spp: int,
        seed: int,
        variant: str,
    ) -> ProbeRadiance:
        import mitsuba  # (its version; Mitsuba is already in use by the caller)

        check_spp(pass_spp)
        pos = np.ascontiguousarray(positions, dtype=np.float64)
        ident = {
            "format": FORMAT,
            "scene": scene_hash,
            "positions": array_digest(pos),
            "features": features_name,
            "features_at": array_digest(np.asarray(features(_CHECK_DIRECTIONS), dtype=np.float64)),
            "seed": int(seed),
            "pass_spp": int(pass_spp),
            "variant": variant,
            "versions": [mitsuba.__version__, dr.__version__],
        }
        entry = PassEntry(self.root, ident, namespace="probe_radiance", storage="npz")

        def render(i: int) -> PassResult:
            return probe_radiance_pass(mi, mi_scene, pos, features, int(pass_spp), sub_seed(seed, "pass", i))

        results, _ = entry.passes(-(-int(spp) // int(pass_spp)), render, spp_of=lambda _i: int(pass_spp))
        mean, stderr, total = pool_passes(results)
        return ProbeRadiance(
            mean, stderr, total, len(results), float(sum(r.seconds for r in results)), entry.key
        )
