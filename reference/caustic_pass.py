"""Light tracing of a distant (directional) light through a glass or water caster onto a flat receiver: the
caustic irradiance a path tracer cannot find (a delta light seen through a delta BSDF).

`caustic_profile` shoots parallel light rays of direction −z (the sun overhead) through a disk of radius
``beam`` about the caster's axis, follows each through the loaded Mitsuba scene with the casters' own BSDFs
(`bsdf.sample` in importance transport: the light's direction of travel, Fresnel choosing reflection or
refraction as Mitsuba's dielectric does) for up to ``max_depth`` interactions, and bins the flux that first
meets the receiver — a surface whose BSDF is not a delta (a diffuse floor) — by its distance r from the axis.
Each ray carries the flux E⊥·π·beam²/N (W); a ray absorbed by the receiver stops there (its irradiance is what
arrives, whatever the floor then does). The result per annulus [r_j, r_{j+1}) is the mean irradiance
E_j = Σ Φ_i/A_j (W/m²) with the standard error of that sum from the per-ray contributions (the rays are
independent: Var = N·Var(one ray's deposit)/A_j²).

Assumptions (the caller's scene): the receiver is a horizontal plane seen from above, wider than the bins;
nothing but the casters lies above it. The beam need only cover the casters' disk: beyond it the receiver
gets the unobstructed E⊥, added per annulus (``add_direct``).

Mitsuba only; no pass cache (one call costs about a second at 10⁶ rays on a CPU: it is recomputed).
"""

from __future__ import annotations

import math
import time

import numpy as np

__all__ = ["CausticProfile", "caustic_profile"]


class CausticProfile:
    """``edges`` (J + 1,) annulus radii (m), ``irradiance`` and ``stderr`` (J,) W/m², ``rays``, ``seconds``,
    ``flux_in`` (W: the beam's) and ``flux_receiver`` (W: what reached the receiver inside ``edges[-1]``)."""

    def __init__(self, edges, irradiance, stderr, rays, seconds, flux_in, flux_receiver):
        self.edges = edges
        self.irradiance = irradiance
        self.stderr = stderr
        self.rays = rays
        self.seconds = seconds
        self.flux_in = flux_in
        self.flux_receiver = flux_receiver

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.edges[:-1] + self.edges[1:])


def caustic_profile(
    mi,
    scene,
    e_normal: float,
    beam: float,
    edges: np.ndarray,
    rays: int,
    seed: int,
    top: float = 100.0,
    max_depth: int = 16,
    add_direct: bool = True,
) -> CausticProfile:
    """The receiver's irradiance per annulus (module docstring): light of normal irradiance ``e_normal``
    (W/m²) travelling along −z through the disk of radius ``beam`` at height ``top``, ``rays`` rays;
    ``add_direct``: add E⊥ on the receiver beyond the beam (the light outside it meets nothing: the caller's
    scene has nothing else above the receiver), so a beam just covering the caster gives the whole profile."""
    import drjit as dr

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    u = rng.random((rays, 2))
    rad = beam * np.sqrt(u[:, 0])
    phi = 2.0 * math.pi * u[:, 1]
    o = np.stack([rad * np.cos(phi), rad * np.sin(phi), np.full(rays, top)], axis=1)
    d = np.tile([0.0, 0.0, -1.0], (rays, 1))
    weight = np.ones((rays, 3))
    flux = e_normal * math.pi * beam * beam / rays
    deposit = np.zeros(rays)
    where = np.zeros(rays)
    alive = np.arange(rays)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    for _ in range(max_depth):
        if alive.size == 0:
            break
        ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[alive, k]) for k in range(3))),
                       mi.Vector3f(*(mi.Float(d[alive, k]) for k in range(3))))  # fmt: skip
        si = scene.ray_intersect(ray)
        bsdf = si.bsdf(ray)
        valid_dr = si.is_valid()
        delta_dr = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta) & valid_dr
        xi = rng.random((3, len(alive)))  # NumPy's stream: no seed literal compiled into each kernel
        bs, w_dr = bsdf.sample(
            ctx, si, mi.Float(xi[0]), mi.Point2f(mi.Float(xi[1]), mi.Float(xi[2])), delta_dr
        )
        wo_dr = si.to_world(bs.wo)
        dr.eval(valid_dr, delta_dr, si.p, wo_dr, w_dr)  # one launch; the conversions below only copy
        valid = np.array(valid_dr, bool)
        delta = np.array(delta_dr, bool) & valid
        p = np.array(si.p, np.float64).T.reshape(-1, 3)
        wo = np.array(wo_dr, np.float64).T.reshape(-1, 3)
        w = np.array(w_dr, np.float64).T.reshape(-1, 3)
        hit_floor = valid & ~delta
        idx = alive[hit_floor]
        deposit[idx] = np.mean(weight[idx], axis=1) * flux
        where[idx] = np.hypot(p[hit_floor, 0], p[hit_floor, 1])
        go = delta & np.all(np.isfinite(w), axis=1) & (np.max(w, axis=1) > 0)
        nxt = alive[go]
        o[nxt] = p[go] + 1e-4 * wo[go]
        d[nxt] = wo[go]
        weight[nxt] *= w[go]
        alive = nxt
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    j = np.digitize(where, edges) - 1
    inside = (deposit > 0) & (j >= 0) & (j < len(area))
    sums = np.bincount(j[inside], weights=deposit[inside], minlength=len(area))
    sq = np.bincount(j[inside], weights=deposit[inside] ** 2, minlength=len(area))
    var = np.maximum(sq - sums * sums / rays, 0.0)  # N·Var(one ray's deposit into the bin)
    outside = math.pi * (np.maximum(edges[1:], beam) ** 2 - np.maximum(edges[:-1], beam) ** 2)
    direct = e_normal * outside / area if add_direct else 0.0  # the unobstructed light beyond the beam
    return CausticProfile(
        np.asarray(edges, np.float64),
        sums / area + direct,
        np.sqrt(var) / area,
        rays,
        time.perf_counter() - t0,
        flux * rays,
        float(sums.sum()),
    )
