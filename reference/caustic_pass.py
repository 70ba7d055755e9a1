r"""Caustic irradiance on a receiver by light tracing (the ``ptracer`` estimator restricted to caustic paths).

A caustic is the light that reaches a diffuse receiver after one or more specular interactions (a glass
or metal caster): light paths L S+ D. A path tracer gathering from the receiver cannot find them when the
light is a delta (a point, spot or directional light: the specular chain can never be closed towards it),
so the exact counterpart traces from the light, as Mitsuba's ``ptracer`` does:

* **Emission** (`emit_photons`): photons leave a delta light towards the caster's bounding sphere (centre c,
  radius r) only — every other photon has no specular interaction first and carries no caustic. From a
  position light at p (point, spot) the directions are uniform in the cone of half-angle α, sin α = r/|c − p|
  (solid angle Ω = 2π(1 − cos α); the whole sphere when p is inside), photon flux Φ = I(ω)·Ω/N with I(ω)
  (W/sr, RGB) read from Mitsuba's own emitter (``sample_direction`` at unit distance: a spot's falloff
  included). From a directional light (irradiance E⊥, W/m²) the origins are uniform on the disc of radius r
  across the beam, far outside the scene, Φ = E⊥·πr²/N. ``stratified``: the regular grid of N = m² cells'
  centres (the seed's photon hit map, one photon per texel) instead of random numbers.
* **Tracing** (`trace_photons`): Mitsuba ray intersection; at a purely specular (delta) BSDF one Mitsuba
  BSDF sample in *importance* transport (the flux is not scaled by 1/η² across an interface), the flux times
  its weight (a smooth dielectric: 1, choosing reflection or refraction with probability F; a conductor: its
  Fresnel reflectance); at the first BSDF with a non-delta lobe after ≥ 1 specular interaction the photon is
  stored (point, shading normal, flux, incoming direction) and stops; a photon reaching a non-delta surface
  first (direct light), leaving the scene or exceeding `MAX_DEPTH` interactions is dropped (the last: a
  truncation, reported as the dropped flux).
* **The irradiance at the camera's pixels** (`camera_irradiance`): the ``ptracer`` connection. A stored photon
  that the camera sees (a shadow ray to the pinhole; on the side of the surface facing the camera) lands in
  pixel (i, j) by its tangent-plane coordinates; the pixel's footprint there has the area A = Ω_px·d²/|n·v|
  (Ω_px = |Δx·Δy|·cos³θ the pixel's solid angle, Δx, Δy its tangent-plane pitch, d the distance, v the unit
  view direction), and the pixel's irradiance is Σ Φ/A (W/m²): the mean irradiance over the footprint, an
  unbiased estimate of it. N photons are split into ``spp`` batches of ``photons_per_sample`` each; a batch's
  image is one sample (mean and unbiased variance per pixel over the batches, `PassResult`).

**Independent check** (`sphere_flux`): the same emitted rays through a dielectric sphere by closed-form ray
optics in NumPy (ray–sphere intersection, Snell's law, the unpolarised Fresnel reflectance; the Fresnel tree
followed to `SPHERE_ORDERS` internal paths: reflection R, transmission TT, TRT, …), each outgoing ray
intersected with a receiver rectangle: the flux the caster sends onto the receiver. Equal to the traced
photons' flux on it within their noise (energy conservation: nothing is absorbed in clear glass).

**A radial profile** (`caustic_profile`, the raindrops family's droplet shadow): parallel rays from the sun
overhead through `trace_photons` (direct hits kept), binned by distance from the axis on a horizontal floor.

Units: scene units (m) for lengths, W for flux, W/m² for irradiance, RGB channels.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from .estimators import PassResult

__all__ = [
    "MAX_DEPTH",
    "SPHERE_ORDERS",
    "CameraGrid",
    "CausticProfile",
    "PhotonHits",
    "camera_grid",
    "camera_irradiance",
    "caustic_pass",
    "caustic_profile",
    "emit_photons",
    "fresnel_dielectric",
    "light_of",
    "sphere_flux",
    "trace_photons",
]

MAX_DEPTH = 16
"""Specular interactions a photon may have before it is dropped (a sphere's internal paths: F^15 ≈ 1e-21)."""
SPHERE_ORDERS = 8
"""Internal paths of the analytic sphere (p = 0 reflection … 7): the rest carries F^7 < 1e-9 of the flux."""


@dataclass(frozen=True)
class DeltaLight:
    """A delta light as photons leave it: ``position`` (3,) for a point/spot light, or ``direction`` (3,)
    (the unit direction the light travels) for a directional light; ``emitter``: the Mitsuba emitter."""

    emitter: object
    position: np.ndarray | None
    direction: np.ndarray | None


def light_of(mi, emitter, centre) -> DeltaLight | None:
    """The `DeltaLight` of a Mitsuba emitter (None: not a delta light: an area or environment light, whose
    caustics a path tracer finds itself). ``centre``: a point to query the emitter from (the caster)."""
    flags = int(emitter.flags())
    it = dr.zeros(mi.Interaction3f, 1)
    it.p = mi.Point3f(*(float(x) for x in centre))
    ds, _ = emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
    if flags & int(mi.EmitterFlags.DeltaPosition):
        return DeltaLight(emitter, np.array([float(ds.p[k][0]) for k in range(3)]), None)
    if flags & int(mi.EmitterFlags.DeltaDirection):
        d = -np.array([float(ds.d[k][0]) for k in range(3)])
        return DeltaLight(emitter, None, d / np.linalg.norm(d))
    return None


def _frame(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(w, t)
    u /= np.linalg.norm(u)
    return u, np.cross(w, u)


def _unit_square(n: int, rng, stratified: bool) -> np.ndarray:
    if stratified:
        m = max(1, round(math.sqrt(n)))
        g = (np.arange(m) + 0.5) / m
        return np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    return rng.random((n, 2))


def _emitted(mi, light: DeltaLight, p, w) -> np.ndarray:
    """(N, 3): Mitsuba's I(ω) (W/sr) of a position light towards unit directions ``w``, or E⊥ (W/m²)."""
    it = dr.zeros(mi.Interaction3f, len(p))
    it.p = mi.Point3f(*(np.ascontiguousarray(p[:, k], np.float32) for k in range(3)))
    _ds, spec = light.emitter.sample_direction(it, mi.Point2f(0.5, 0.5))  # type: ignore[attr-defined]
    return np.stack([np.broadcast_to(np.asarray(spec[k], np.float64), (len(p),)) for k in range(3)], axis=1)


def emit_photons(mi, light: DeltaLight, centre, radius: float, n: int, seed: int, stratified=False,
                 far: float = 1e3):  # fmt: skip
    """Photons towards the caster's bounding sphere (module docstring): origins, unit directions (N, 3) and
    flux (N, 3) W, the flux summing to the light's flux into the sphere's cone (or beam)."""
    rng = np.random.default_rng(seed)
    c = np.asarray(centre, np.float64)
    u = _unit_square(n, rng, stratified)
    if light.position is not None:
        axis = c - light.position
        dist = float(np.linalg.norm(axis))
        cos_a = math.sqrt(max(0.0, 1.0 - (radius / dist) ** 2)) if dist > radius else -1.0
        e1, e2 = _frame(axis / dist)
        cos_t = 1.0 - u[:, 0] * (1.0 - cos_a)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t**2))
        phi = 2.0 * math.pi * u[:, 1]
        w = (
            (np.cos(phi) * sin_t)[:, None] * e1
            + (np.sin(phi) * sin_t)[:, None] * e2
            + cos_t[:, None] * axis / dist
        )
        omega = 2.0 * math.pi * (1.0 - cos_a)
        origins = np.broadcast_to(light.position, w.shape).copy()
        flux = _emitted(mi, light, origins + w, w) * (omega / len(w))  # I(ω)/1² at unit distance
        return origins, w, flux
    assert light.direction is not None
    w = light.direction
    e1, e2 = _frame(w)
    r = radius * np.sqrt(u[:, 0])
    phi = 2.0 * math.pi * u[:, 1]
    origins = c - far * w + (r * np.cos(phi))[:, None] * e1 + (r * np.sin(phi))[:, None] * e2
    dirs = np.broadcast_to(w, origins.shape).copy()
    flux = _emitted(mi, light, c[None] + 0.0 * origins, dirs) * (math.pi * radius**2 / len(origins))
    return origins, dirs, flux


@dataclass(frozen=True)
class PhotonHits:
    """Stored caustic photons: ``points``, unit shading ``normals``, ``flux`` (W, RGB), ``incoming`` unit
    directions (all (M, 3)), the index of each in the emitted set (``index``, (M,)), and ``dropped``: the
    flux (3,) of photons still specular after `MAX_DEPTH` interactions."""

    points: np.ndarray
    normals: np.ndarray
    flux: np.ndarray
    incoming: np.ndarray
    index: np.ndarray
    dropped: np.ndarray


def _vec(mi, kind, a):
    return kind(*(np.ascontiguousarray(a[:, k], np.float32) for k in range(3)))


def _np3(v) -> np.ndarray:
    return np.stack([np.asarray(v[k], np.float64) for k in range(3)], axis=1)


def trace_photons(mi, scene, origins, dirs, flux, seed: int, direct: bool = False) -> PhotonHits:
    """Trace photons through delta BSDFs to their first non-delta surface (module docstring). One wavefront of
    all photons, the same kernel each interaction (inactive lanes masked), stored hits kept per lane.
    ``direct``: also store a photon whose first surface is non-delta (the light the caster does not touch:
    a shadow's surroundings, `caustic_profile`)."""
    n = len(origins)
    if n == 0:
        z = np.zeros((0, 3))
        return PhotonHits(z, z, z, z, np.zeros(0, np.int64), np.zeros(3))
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    rng = mi.PCG32(size=n, initstate=dr.arange(mi.UInt64, n) + np.uint64(seed) * np.uint64(0x9E3779B9))
    ray = mi.Ray3f(_vec(mi, mi.Point3f, np.asarray(origins)), _vec(mi, mi.Vector3f, np.asarray(dirs)))
    f = _vec(mi, mi.Color3f, np.asarray(flux))
    active = mi.Bool(True) | dr.zeros(mi.Bool, n)
    specular = dr.zeros(mi.Bool, n)
    stored = dr.zeros(mi.Bool, n)
    sp, sn, sd = dr.zeros(mi.Point3f, n), dr.zeros(mi.Vector3f, n), dr.zeros(mi.Vector3f, n)
    sf = dr.zeros(mi.Color3f, n)
    for _ in range(MAX_DEPTH + 1):
        si = scene.ray_intersect(ray, active)
        valid = active & si.is_valid()
        bsdf = si.bsdf(ray)
        smooth = valid & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        store = smooth & (specular | direct)
        sp, sn, sd = (
            dr.select(store, si.p, sp),
            dr.select(store, si.sh_frame.n, sn),
            dr.select(store, ray.d, sd),
        )
        sf = dr.select(store, f, sf)
        stored |= store
        go = valid & ~smooth
        u1, u2 = rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32())
        bs, weight = bsdf.sample(ctx, si, u1, u2, go)
        f = dr.select(go, f * weight, f)
        go &= dr.max(weight) > 0
        ray = dr.select(go, si.spawn_ray(si.to_world(bs.wo)), ray)
        specular |= go
        active = go
        dr.eval(ray, f, active, specular, stored, sp, sn, sd, sf, rng)
        if not dr.any(active):
            break
    keep = np.asarray(stored, bool)
    left = np.asarray(active, bool)
    f_all = _np3(f)
    return PhotonHits(_np3(sp)[keep], _np3(sn)[keep], _np3(sf)[keep], _np3(sd)[keep], np.flatnonzero(keep),
                      dropped=f_all[left].sum(axis=0))  # fmt: skip


@dataclass(frozen=True)
class CameraGrid:
    """A pinhole camera's pixel grid: ``origin`` (3,), ``frame`` (3, 3) columns x, y, z (view), the tangent
    coordinates of pixel (0, 0)'s centre ``t0`` (2,), the signed pitch ``pitch`` (2,) per column and row, and
    the film ``shape`` (H, W)."""

    origin: np.ndarray
    frame: np.ndarray
    t0: np.ndarray
    pitch: np.ndarray
    shape: tuple[int, int]


def camera_grid(sensor, view_dir: np.ndarray) -> CameraGrid:
    """The `CameraGrid` of a perspective sensor whose G-buffer has unit pixel-centre ``view_dir`` (H,W,3)."""
    m = np.asarray(sensor.world_transform().matrix, np.float64).reshape(4, 4, -1)[..., 0]
    frame = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    local = view_dir.astype(np.float64) @ frame
    t = local[..., :2] / local[..., 2:3]
    h, w = view_dir.shape[:2]
    px = (t[0, -1, 0] - t[0, 0, 0]) / max(w - 1, 1)
    py = (t[-1, 0, 1] - t[0, 0, 1]) / max(h - 1, 1)
    return CameraGrid(m[:3, 3].copy(), frame, t[0, 0].copy(), np.array([px, py]), (h, w))


def camera_irradiance(mi, scene, grid: CameraGrid, hits: PhotonHits, batch: np.ndarray, batches: int,
                      pixels: np.ndarray) -> np.ndarray:  # fmt: skip
    """(batches, P, 3) W/m²: Σ Φ/A of each batch's photons in each of the ``pixels`` (flat pixel indices,
    row-major) that the camera sees (module docstring); ``batch`` (M,): each hit's batch."""
    out = np.zeros((batches, len(pixels), 3))
    if not len(hits.points):
        return out
    v = grid.origin[None] - hits.points
    dist = np.linalg.norm(v, axis=1)
    vh = v / np.maximum(dist, 1e-30)[:, None]
    facing = np.einsum("ij,ij->i", vh, hits.normals) * np.einsum("ij,ij->i", hits.incoming, hits.normals) < 0
    local = -v @ grid.frame
    front = local[:, 2] > 1e-9
    t = local[:, :2] / np.where(front, local[:, 2], 1.0)[:, None]
    col = np.rint((t[:, 0] - grid.t0[0]) / grid.pitch[0]).astype(np.int64)
    row = np.rint((t[:, 1] - grid.t0[1]) / grid.pitch[1]).astype(np.int64)
    h, w = grid.shape
    inside = facing & front & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    it = dr.zeros(mi.Interaction3f, len(v))
    it.p, it.n = _vec(mi, mi.Point3f, hits.points), _vec(mi, mi.Vector3f, hits.normals)
    seen = inside & ~np.asarray(scene.ray_test(it.spawn_ray_to(_vec(mi, mi.Point3f, grid.origin[None]
                                                                       + 0.0 * v))), bool)  # fmt: skip
    cos3 = (local[:, 2] / np.maximum(dist, 1e-30)) ** 3
    area = (
        abs(grid.pitch[0] * grid.pitch[1])
        * cos3
        * dist**2
        / np.maximum(np.abs(np.einsum("ij,ij->i", vh, hits.normals)), 1e-6)
    )
    where = np.full(h * w, -1, np.int64)
    where[pixels] = np.arange(len(pixels))
    slot = np.where(seen, where[np.clip(row * w + col, 0, h * w - 1)], -1)
    ok = slot >= 0
    e = hits.flux[ok] / area[ok, None]
    for c in range(3):
        np.add.at(out[:, :, c], (batch[ok], slot[ok]), e[:, c])
    return out


def caustic_pass(mi, scene, sensor, view_dir, pixels, light: DeltaLight, centre, radius: float, spp: int,
                 photons_per_sample: int, seed: int, far: float = 1e3) -> PassResult:  # fmt: skip
    """One pass of the caustic irradiance at the camera's ``pixels`` (flat indices): ``spp`` batches of
    ``photons_per_sample`` photons each (module docstring); mean and unbiased variance over the batches."""
    t0 = time.perf_counter()
    n = spp * photons_per_sample
    o, d, f = emit_photons(mi, light, centre, radius, n, seed, far=far)
    f = f * spp  # each photon's flux as one of a batch of photons_per_sample
    hits = trace_photons(mi, scene, o, d, f, seed + 1)
    grid = camera_grid(sensor, view_dir)
    per = camera_irradiance(mi, scene, grid, hits, hits.index // photons_per_sample, spp, pixels)
    mean = per.mean(axis=0)
    var = per.var(axis=0, ddof=1) if spp > 1 else np.zeros_like(mean)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------- the sphere check
def fresnel_dielectric(cos_i, eta: float):
    """Unpolarised Fresnel reflectance of a smooth interface, relative index ``eta`` (transmitted over
    incident side), |cos θ_i| given; 1 at total internal reflection."""
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    sin_t2 = (1.0 - cos_i**2) / eta**2
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin_t2))
    rs = (cos_i - eta * cos_t) / np.maximum(cos_i + eta * cos_t, 1e-300)
    rp = (eta * cos_i - cos_t) / np.maximum(eta * cos_i + cos_t, 1e-300)
    return np.where(tir, 1.0, 0.5 * (rs**2 + rp**2))


def _refract(d, n, eta):
    """Refracted unit direction of unit ``d`` through a surface of unit normal ``n`` (against d), index ratio
    ``eta`` = n_incident / n_transmitted."""
    c = -np.einsum("ij,ij->i", d, n)
    k = np.maximum(0.0, 1.0 - eta**2 * (1.0 - c**2))
    return eta * d + (eta * c - np.sqrt(k))[:, None] * n


def _sphere_exit(o, d, c, r):
    """The far intersection of rays (inside the sphere) with it."""
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b**2 - (np.einsum("ij,ij->i", oc, oc) - r * r)
    return o + (-b + np.sqrt(np.maximum(disc, 0.0)))[:, None] * d


def _on_rectangle(o, d, q, half_u, half_v) -> np.ndarray:
    n = np.cross(half_u, half_v)
    n /= np.linalg.norm(n)
    den = d @ n
    t = ((q - o) @ n) / np.where(np.abs(den) > 1e-15, den, np.inf)
    p = o + t[:, None] * d - q
    a = p @ half_u / (half_u @ half_u)
    b = p @ half_v / (half_v @ half_v)
    return (t > 1e-9) & (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0)


def sphere_flux(origins, dirs, flux, centre, radius: float, eta: float, q, half_u, half_v) -> np.ndarray:
    """(3,) W: the flux the rays (origins, unit dirs, flux: (N, 3)) put on the rectangle q ± half_u ± half_v
    after ≥ 1 interaction with a clear dielectric sphere (closed-form ray optics, module docstring); rays
    that miss the sphere give nothing. Nothing else in the scene is assumed (no occluder)."""
    c = np.asarray(centre, np.float64)
    o, d, f = (np.asarray(a, np.float64) for a in (origins, dirs, flux))
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b**2 - (np.einsum("ij,ij->i", oc, oc) - radius**2)
    hit = (disc > 0) & (-b - np.sqrt(np.maximum(disc, 0.0)) > 0)
    o, d, f = o[hit], d[hit], f[hit]
    p = o + (-b[hit] - np.sqrt(disc[hit]))[:, None] * d
    n = (p - c) / radius
    cos_i = -np.einsum("ij,ij->i", d, n)
    fr = fresnel_dielectric(cos_i, eta)
    total = np.zeros(3)
    refl = d + 2.0 * cos_i[:, None] * n
    on = _on_rectangle(p, refl, q, half_u, half_v)
    total += (f[on] * fr[on, None]).sum(axis=0)
    w = f * (1.0 - fr)[:, None]
    d_in = _refract(d, n, 1.0 / eta)
    pos = p
    for _ in range(SPHERE_ORDERS - 1):
        pos = _sphere_exit(pos, d_in, c, radius)
        n_out = (pos - c) / radius
        cos_o = np.einsum("ij,ij->i", d_in, n_out)
        fi = fresnel_dielectric(cos_o, 1.0 / eta)
        out = _refract(d_in, -n_out, eta)
        on = _on_rectangle(pos, out, q, half_u, half_v)
        total += (w[on] * (1.0 - fi[on])[:, None]).sum(axis=0)
        w = w * fi[:, None]
        d_in = d_in - 2.0 * cos_o[:, None] * n_out
    return total


# ------------------------------------------------------------------------------ a radial profile (raindrops)
@dataclass(frozen=True)
class CausticProfile:
    """``edges`` (J + 1,) annulus radii (m), ``irradiance`` and ``stderr`` (J,) W/m², ``rays``, ``seconds``,
    ``flux_in`` (W: the beam's) and ``flux_receiver`` (W: what reached the receiver inside ``edges[-1]``)."""

    edges: np.ndarray
    irradiance: np.ndarray
    stderr: np.ndarray
    rays: int
    seconds: float
    flux_in: float
    flux_receiver: float

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.edges[:-1] + self.edges[1:])


def caustic_profile(
    mi, scene, e_normal: float, beam: float, edges, rays: int, seed: int, top: float = 100.0,
    add_direct: bool = True,
) -> CausticProfile:  # fmt: skip
    """The irradiance of a horizontal receiver per annulus [r_j, r_{j+1}) about the z axis under the sun
    overhead (the raindrops family's droplet shadow): ``rays`` parallel rays of direction −z through the disk
    of radius ``beam`` at height ``top``, each carrying Φ = E⊥·π·beam²/N (``e_normal`` = E⊥, W/m²), traced by
    `trace_photons` (``direct``: the floor's unobstructed light within the beam counts too) to the first
    non-delta surface — the receiver, which must be the only non-delta surface under the beam. E_j = ΣΦ_i/A_j
    with the standard error of that sum from the per-ray deposits (independent rays: N·Var(one deposit)/A_j²);
    ``add_direct``: E⊥ added on the receiver beyond the beam (the light outside it meets nothing: nothing
    else above the receiver), so a beam just covering the caster gives the whole profile."""
    t0 = time.perf_counter()
    edges = np.asarray(edges, np.float64)
    rng = np.random.default_rng(seed)
    u = rng.random((rays, 2))
    rad, phi = beam * np.sqrt(u[:, 0]), 2.0 * math.pi * u[:, 1]
    origins = np.stack([rad * np.cos(phi), rad * np.sin(phi), np.full(rays, top)], axis=1)
    dirs = np.tile([0.0, 0.0, -1.0], (rays, 1))
    flux = e_normal * math.pi * beam * beam / rays
    hits = trace_photons(mi, scene, origins, dirs, np.full((rays, 3), flux), seed, direct=True)
    deposit = hits.flux.mean(axis=1)
    where = np.hypot(hits.points[:, 0], hits.points[:, 1])
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    j = np.digitize(where, edges) - 1
    inside = (deposit > 0) & (j >= 0) & (j < len(area))
    sums = np.bincount(j[inside], weights=deposit[inside], minlength=len(area))
    sq = np.bincount(j[inside], weights=deposit[inside] ** 2, minlength=len(area))
    var = np.maximum(sq - sums * sums / rays, 0.0)  # N·Var(one ray's deposit into the bin)
    outside = math.pi * (np.maximum(edges[1:], beam) ** 2 - np.maximum(edges[:-1], beam) ** 2)
    beyond = e_normal * outside / area if add_direct else 0.0  # the unobstructed light beyond the beam
    return CausticProfile(
        edges, sums / area + beyond, np.sqrt(var) / area, rays, time.perf_counter() - t0, flux * rays,
        float(sums.sum()),
    )  # fmt: skip
