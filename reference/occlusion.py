r"""Ambient-occlusion and sky-light ground truth by Mitsuba ray casts, with per-element standard errors.

Quantities at surface points x with unit normals n (evaluated on rtfit's own Dr.Jit wavefront with
Mitsuba's ray tracer, ``Scene.ray_test`` / ``Scene.ray_intersect``; one pass = ``spp`` iid samples per
point, float64 moments, so the standard error comes from the pooled sample variance as everywhere in rtfit):

* ``"ao"``: A(x) = (1/π) ∫_{H(n)} V_R(x, ω) (n·ω) dω — cosine-weighted visibility, V_R = 1 when the ray
  x + tω meets nothing for t < R (``max_distance``; ∞ by default). Estimator: V_R(ω) with ω ~ cos/π.
* ``"sky_direct"``: E(x)/(π L) under a constant sky of radiance L on the upper hemisphere ω_z > 0 (no sun,
  black below the horizon): (1/π) ∫_{H(n)} V(x, ω) [ω_z > 0] (n·ω) dω. One bounce: light straight from
  the sky. Unoccluded and facing up it is 1; a vertical wall sees 1/2.
* ``"sky_global"``: the same with all interreflections between white diffuse surfaces of albedo ρ
  (``albedo``): the cosine-sampled path continues from each hit with probability ρ (Russian roulette
  with q = ρ keeps the weight 1: an unbiased estimator of Σ_b ρ^b (escape terms)), up to
  ``MAX_BOUNCES`` (ρ^64 ≤ 6e-7 for ρ ≤ 0.8: the truncation bias is below that fraction).

Geometry: any Mitsuba scene (`rtfit.reference.load_mitsuba_scene` of an rtfit `Scene`: the meshes
themselves), or Mitsuba's ``sdfgrid`` shape built from an rtfit `SdfGrid` (`sdfgrid_scene`), so grid
resolution error and occlusion-model error can be told apart. Mitsuba's ``sdfgrid`` places grid value
(i, j, k) at node i/(n − 1) of its unit cube (measured: a 32³ sphere grid sampled at cell centres
intersects at the cell-centre positions only with this mapping), so `sdfgrid_scene` maps the unit cube
onto the box of rtfit's cell centres: the two trilinear zero sets coincide.

* ``"sunsky_direct"``: E(x)/E_h under Mitsuba's ``sunsky`` sky without its sun (`SunskySky`: the emitter
  with ``sun_scale`` 0, radiance L(ω) ≥ 0 for ω_z > 0 and 0 below the horizon), one bounce:
  E(x) = ∫_{H(n)} V(x, ω) [ω_z > 0] L(ω) (n·ω) dω, with L the luminance Y = 0.2126 R + 0.7152 G + 0.0722 B
  of Mitsuba's linear-sRGB radiance (W m⁻² sr⁻¹) and E_h = ∫_{ω_z > 0} L(ω) ω_z dω the unoccluded
  horizontal irradiance (W m⁻²) from `sunsky_horizontal_irradiance` (quadrature of the baked sky).
  Estimator: π L(ω) V(ω) [ω_z > 0] / E_h, ω ~ cos/π. For a constant L, E_h = πL: the ``sky_direct``
  normalisation is the special case. Unoccluded and facing up it is 1.
* ``"sunsky_global"``: the same sky with all interreflections (Russian roulette as ``sky_global``; an escaping
  path scores π L(ω)/E_h instead of 1).
* ``"ambient_global"``: E(x)/(π L) under a *uniform ambient*: a constant environment of radiance L over the
  whole sphere (no horizon), all interreflections between white diffuse surfaces of albedo ρ (Russian
  roulette as ``sky_global``; every escaping path scores 1). Unoccluded it is 1 for any normal; the one-bounce
  counterpart is ``"ao"`` with R = ∞. What obscurances stand in for (the ``obscurances`` experiment).
* ``"obscurance"``: Zhukov/Iones obscurance W(x) = (1/π) ∫_{H(n)} ρ(d(x, ω)) (n·ω) dω, d the distance to
  the first hit (∞ for a miss). Estimator: ρ(d(ω)), ω ~ cos/π. The distance function ρ is passed in as
  ``distance_weight`` (a callable on Dr.Jit arrays: the one text of `rtfit.realtime.obscurances`, which
  this package may not import) with ``weight_key`` (a JSON-able description: form and parameters) for the
  cache key.

`hit_distances` returns the raw hit distances of K given local directions per point (the inputs of the
real-time obscurance estimator).

Rays start at the points with Mitsuba's ``spawn_ray`` offset (relative epsilon along n). The constant-sky
quantities use no Mitsuba emitter: the sky is defined here (radiance 1 above the horizon), which is exactly
the "constant upper-hemisphere sky without a sun" of the issue. The sunsky quantities evaluate the emitter
itself (``Emitter.eval``) for each escaping ray.

`OcclusionCache` stores passes in the one pass store of rtfit (`rtfit.reference.cache.PassEntry`, namespace
``occlusion``, ``.npz``) under a key of everything that determines the samples.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import numpy as np

from .build import camera_dict
from .cache import PassEntry, array_digest, pool_passes
from .device_arrays import mapped_floats
from .environments import SUNSKY_APERTURE_DEG, quadrature_samples, sunsky_environment
from .estimators import (
    MAX_LANES,
    DeviceProbes,
    PassMoments,
    PassResult,
    as_device_probes,
    check_spp,
    chunk_ranges,
    device_probes,
    device_vectors,
    launch_identity,
    pass_max_lanes,
    point_chunks,
    sub_seed,
)

QUANTITIES = (
    "ao",
    "sky_direct",
    "sky_global",
    "sunsky_direct",
    "sunsky_global",
    "ambient_global",
    "obscurance",
)
GLOBAL_QUANTITIES = ("sky_global", "sunsky_global", "ambient_global")
MAX_BOUNCES = 64
FORMAT = 2
"""Version of the occlusion cache entries (2: `PassEntry` layout, float32 passes with a .json each)."""
LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 / linear-sRGB luminance weights: the scalar the sunsky quantities integrate."""
SKY_BAKE_HEIGHT = 257
"""Rows of the baked sunsky map (`rtfit.reference.environments.sunsky_environment`, 2:1) whose quadrature
(supersample 2, so that quadrature cells end on the horizon) gives E_h: node rows every 0.7°, one on the
horizon. Measured (30° sun, turbidity 3) against a Gauss–Legendre × midpoint quadrature of the emitter
itself: 3e-5 relative for E_h, ≤ 6e-4 for vertical normals (the horizon band); 2e-5 between 257 and 513
rows for E_h."""


@dataclass(frozen=True)
class SunskySky:
    """Mitsuba's Hosek–Wilkie ``sunsky`` without its sun (``sun_scale`` 0; ground albedo 0.3 as in
    `rtfit.reference.environments.sunsky_environment`), +Z up. The sun direction (which shapes the sky) is
    (cos e sin a, cos e cos a, sin e): elevation e above the horizon, azimuth a from +Y towards +X (the
    convention of `rtfit.reference.environments`)."""

    elevation_deg: float = 30.0
    azimuth_deg: float = 60.0
    turbidity: float = 3.0

    def __post_init__(self):
        for f in ("elevation_deg", "azimuth_deg", "turbidity"):
            v = getattr(self, f)
            if not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
                raise ValueError(f"SunskySky.{f} must be a finite number (got {v!r})")
            object.__setattr__(self, f, float(v))
        if not 0.0 < self.elevation_deg <= 90.0:
            raise ValueError(f"sun elevation_deg must be in (0, 90] (got {self.elevation_deg!r})")
        if not 1.0 <= self.turbidity <= 10.0:
            raise ValueError(f"turbidity must be in [1, 10] (got {self.turbidity!r})")

    def sun_direction(self) -> np.ndarray:
        e, a = math.radians(self.elevation_deg), math.radians(self.azimuth_deg)
        return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])

    def to_dict(self) -> dict:
        return {
            "emitter": "sunsky (Mitsuba), sun_scale 0",
            "sun_elevation_deg": self.elevation_deg,
            "sun_azimuth_deg": self.azimuth_deg,
            "turbidity": self.turbidity,
            "ground_albedo": 0.3,
            "sun_direction": [float(v) for v in self.sun_direction()],
            "scalar": "luminance Y (Rec. 709)",
        }


_SKY_CACHE: dict = {}
MEMOS = (_SKY_CACHE,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def sunsky_emitter(mi, sky: SunskySky):
    """The Mitsuba ``sunsky`` emitter of ``sky`` with ``sun_scale`` 0 (the same dictionary as the sky part of
    `rtfit.reference.environments.sunsky_environment`)."""
    key = ("emitter", mi.variant(), sky)
    if key not in _SKY_CACHE:
        _SKY_CACHE[key] = mi.load_dict(
            {
                "type": "sunsky",
                "sun_direction": sky.sun_direction().tolist(),
                "turbidity": sky.turbidity,
                "albedo": 0.3,
                "sun_aperture": SUNSKY_APERTURE_DEG,
                "sun_scale": 0.0,
            }
        )
    return _SKY_CACHE[key]


def sunsky_sky_nodes(mi, sky: SunskySky, height: int = SKY_BAKE_HEIGHT, supersample: int = 2):
    """Quadrature nodes of the sky above the horizon: (directions (M, 3), solid-angle weights (M,),
    luminance (M,) in W m⁻² sr⁻¹) — the midpoint rule over the bilinear map baked by
    `rtfit.reference.environments.sunsky_environment` (``sun_scale`` 0; its sun is dropped), keeping the
    nodes with ω_z > 0 (the map has a node row on the horizon when ``height`` is odd)."""
    if not isinstance(height, (int, np.integer)) or height < 3 or height % 2 == 0:
        raise ValueError(f"height must be an odd integer >= 3 (a node row on the horizon; got {height!r})")
    key = ("nodes", mi.variant(), sky, int(height), int(supersample))
    if key not in _SKY_CACHE:
        env = sunsky_environment(
            mi, sky.elevation_deg, int(height), 2 * (int(height) - 1), sky.turbidity, sky.azimuth_deg
        )
        d, w, rgb = quadrature_samples(env.radiance_map, int(supersample))
        up = d[:, 2] > 0
        _SKY_CACHE[key] = (d[up], w[up], rgb[up] @ np.asarray(LUMINANCE))
    return _SKY_CACHE[key]


def sunsky_irradiance(mi, sky: SunskySky, normals, height: int = SKY_BAKE_HEIGHT, supersample: int = 2):
    """Unoccluded luminance irradiance E(n) = Σ_k w_k L_k max(n·d_k, 0) (W m⁻²) of the sky above the horizon
    at unit ``normals`` (N, 3), by quadrature (`sunsky_sky_nodes`)."""
    n = np.asarray(normals, np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or not np.all(np.isfinite(n)) or np.any(np.linalg.norm(n, axis=1) == 0):
        raise ValueError(f"normals must be finite non-zero (N, 3) vectors (got shape {n.shape})")
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    d, w, lum = sunsky_sky_nodes(mi, sky, height, supersample)
    wl = w * lum
    out = np.empty(len(n))
    per = max(1, (1 << 22) // max(len(d), 1))
    for a in range(0, len(n), per):
        out[a : a + per] = np.maximum(n[a : a + per] @ d.T, 0.0) @ wl
    return out


def sunsky_horizontal_irradiance(mi, sky: SunskySky) -> float:
    """E_h = ∫_{ω_z > 0} L(ω) ω_z dω (W m⁻², luminance): the normaliser of the sunsky quantities."""
    key = ("E_h", mi.variant(), sky)
    if key not in _SKY_CACHE:
        _SKY_CACHE[key] = float(sunsky_irradiance(mi, sky, np.array([[0.0, 0.0, 1.0]]))[0])
    return _SKY_CACHE[key]


def _check(quantity, spp, max_distance, albedo):
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {QUANTITIES} (got {quantity!r})")
    if not isinstance(spp, (int, np.integer)) or spp < 2:
        raise ValueError(f"spp must be an integer >= 2 (got {spp!r})")
    if not (max_distance > 0):
        raise ValueError(f"max_distance must be > 0 (got {max_distance!r})")
    if not (0.0 <= albedo < 1.0):
        raise ValueError(f"albedo must be in [0, 1) (got {albedo!r})")


def occlusion_pass(
    mi,
    mi_scene,
    points,
    normals,
    spp: int,
    seed: int,
    *,
    quantity: str = "ao",
    max_distance: float = math.inf,
    albedo: float = 0.8,
    sky: SunskySky | None = None,
    distance_weight=None,
) -> PassResult:
    """One pass of ``spp`` samples per point (``points`` and ``normals`` (N, 3) arrays, the normals normalised
    here, or `DeviceProbes` made with ``normalise=True`` as ``points`` and None as ``normals``: the passes of
    one reference share one upload); mean/var arrays of shape (N,) (float64). ``sky``: the sky of
    the sunsky quantities (None: ``SunskySky()``, 30° elevation, 60° azimuth, turbidity 3).
    ``distance_weight``: ρ(d) of the ``obscurance`` quantity (a callable on Dr.Jit Float arrays)."""
    _check(quantity, spp, max_distance, albedo)
    if (quantity == "obscurance") != (distance_weight is not None):
        raise ValueError("distance_weight is required by (and only by) the obscurance quantity")
    if sky is not None and not isinstance(sky, SunskySky):
        raise ValueError(f"sky must be a SunskySky (got {type(sky).__name__})")
    skyfn = _sunsky_escape_value(mi, dr, sky or SunskySky()) if quantity.startswith("sunsky") else None
    if mi.variant().startswith("scalar"):
        raise ValueError("occlusion references need a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    # Normalised in float64 on the device, then rounded to float32 (`device_probes`): NumPy's norm along
    # axis 1 and the copies took most of a 1024² G-buffer's AO pass on the H200 machine's CPU.
    probes = as_device_probes(mi, points, normals, normalise=True)
    t0 = time.perf_counter()
    acc = PassMoments(mi, probes.count, 1, spp)
    p_all, n_all = probes.points, probes.normals
    for c, (a, b) in enumerate(chunk_ranges(probes.count, spp, pass_max_lanes(mi))):
        lanes = (b - a) * spp
        idx = dr.arange(mi.UInt32, lanes) // spp + dr.opaque(mi.UInt32, a)
        p = dr.gather(mi.Point3f, p_all, idx)
        n = dr.gather(mi.Vector3f, n_all, idx)
        # Per-lane initial state hashed with TEA (as Mitsuba's independent sampler does): PCG32 streams
        # that share an initial state and differ only in their increment are correlated.
        lane = dr.arange(mi.UInt32, lanes)
        # The seed is opaque (a device value, not a literal in the kernel text): as a literal every pass
        # compiled its own kernel (~1 s on 2 cores, 5× the ray casting of a 64² × 64 spp pass; issue 21).
        h0, h1 = mi.sample_tea_32(dr.opaque(mi.UInt32, sub_seed(seed, "chunk", c)), lane)
        rng = mi.PCG32(lanes, (mi.UInt64(h0) << 32) | mi.UInt64(h1), mi.UInt64(lane))
        v = _estimate(
            mi, dr, mi_scene, rng, p, n, quantity, float(max_distance), float(albedo), skyfn, distance_weight
        )
        acc.add(a, [v])
    mean, var = acc.result()
    return PassResult(mean[:, 0], var[:, 0], spp, seed, time.perf_counter() - t0)


def _sunsky_escape_value(mi, dr, sky: SunskySky):
    """d ↦ π L(d)/E_h (luminance, ≥ 0: Hosek–Wilkie can dip below 0, mitsuba3 #1777) for escaping rays."""
    emitter = sunsky_emitter(mi, sky)
    scale = math.pi / sunsky_horizontal_irradiance(mi, sky)
    lum = LUMINANCE

    def value(d):
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
        si.wi = -d
        rgb = emitter.eval(si)
        return dr.maximum(lum[0] * rgb[0] + lum[1] * rgb[1] + lum[2] * rgb[2], 0.0) * scale

    return value


def _spawn(mi, dr, p, n, d, maxt=math.inf):
    it = dr.zeros(mi.Interaction3f, dr.width(p))
    it.p = p
    it.n = n
    ray = it.spawn_ray(d)
    if math.isfinite(maxt):
        ray.maxt = maxt
    return ray


def _cos_dir(mi, rng, n):
    u = mi.Point2f(rng.next_float32(), rng.next_float32())
    return mi.Frame3f(n).to_world(mi.warp.square_to_cosine_hemisphere(u))


def _estimate(mi, dr, mi_scene, rng, p, n, quantity, max_distance, albedo, skyfn=None, weight=None):
    """One sample per lane. ``skyfn(d)``: the escape value π L(d)/E_h of the sunsky quantities (None: 1);
    ``weight(t)``: the obscurance's ρ of the hit distance t (∞ for a miss)."""
    d = _cos_dir(mi, rng, n)
    if quantity == "obscurance":
        si = mi_scene.ray_intersect(_spawn(mi, dr, p, n, d))
        return weight(dr.select(si.is_valid(), si.t, dr.inf))
    if quantity == "ao":
        hit = mi_scene.ray_test(_spawn(mi, dr, p, n, d, max_distance))
        return dr.select(hit, 0.0, 1.0)
    if quantity in ("sky_direct", "sunsky_direct"):
        hit = mi_scene.ray_test(_spawn(mi, dr, p, n, d))
        sky = 1.0 if skyfn is None else skyfn(d)
        return dr.select(hit | (d.z <= 0), 0.0, sky)
    # sky_global / sunsky_global / ambient_global: Russian roulette with q = albedo (weight stays 1).
    upper_only = quantity != "ambient_global"
    value = dr.zeros(mi.Float, dr.width(p))
    alive = dr.full(mi.Bool, True, dr.width(p))
    for _ in range(MAX_BOUNCES):
        si = mi_scene.ray_intersect(_spawn(mi, dr, p, n, d), alive)
        escaped = alive & ~si.is_valid()
        lit = escaped & (d.z > 0) if upper_only else escaped
        value = dr.select(lit, value + (1.0 if skyfn is None else skyfn(d)), value)
        cont = rng.next_float32() < albedo
        alive = alive & si.is_valid() & cont
        ng = dr.select(dr.dot(si.n, d) > 0, -si.n, si.n)
        p = dr.select(alive, si.p, p)
        n = dr.select(alive, ng, n)
        d = dr.select(alive, _cos_dir(mi, rng, n), d)
        dr.eval(value, alive, p, n, d, rng)
        if not dr.any(alive):
            break
    return value


CAP_CHANNELS = ("visible_fraction", "visibility", "bent_x", "bent_y", "bent_z")
"""The five values of a `visibility_cap_pass`, in order."""


def visibility_cap_pass(
    mi,
    mi_scene,
    points,
    normals,
    spp: int,
    seed: int,
    max_distance: float = math.inf,
    see_through_emitters: bool = False,
) -> PassResult:
    """What an engine bakes per point for sky occlusion, by unbounded ray casts against the scene's shapes
    (``max_distance``: rays of that length instead, for a cap of occlusion within R; ``see_through_emitters``:
    a ray that hits a shape carrying an emitter counts as escaping, for the cap a light is seen through):
    with ω uniform on the hemisphere of n (pdf 1/(2π)) and V(ω) = 1 where the ray x + tω (t > 0) meets
    nothing, per sample the five values (`CAP_CHANNELS`)

    * V(ω): its mean is the visible **fraction** of the hemisphere V_u = (1/2π)∫ V dω (the aperture of
      equal solid angle: r_a = acos(1 − V_u), `rtfit.realtime.ambient_aperture`, 000:2660-2668);
    * 2 V(ω)(n·ω): its mean is the cosine-weighted visibility (1/π)∫ V (n·ω) dω (1: unoccluded);
    * V(ω) ω: its mean is the unnormalised bent normal (1/2π)∫ V ω dω (normalise it: the mean unoccluded
      direction; n itself where nothing blocks).

    Mean and variance (N, 5) of ``spp`` iid samples per point; rays start at ``spawn_ray``'s offset."""
    check_spp(spp)
    if not max_distance > 0:
        raise ValueError(f"max_distance must be > 0 (got {max_distance!r})")
    t0 = time.perf_counter()
    acc = PassMoments(mi, len(points), 5, spp)
    for a, sampler, (p, n) in point_chunks(mi, spp, seed, [(mi.Point3f, points), (mi.Vector3f, normals)]):
        d = mi.Frame3f(n).to_world(mi.warp.square_to_uniform_hemisphere(sampler.next_2d()))
        ray = _spawn(mi, dr, p, n, d, max_distance)
        if see_through_emitters:
            si = mi_scene.ray_intersect(ray)
            blocked = si.is_valid() & ~si.shape.is_emitter()
        else:
            blocked = mi_scene.ray_test(ray)
        v = dr.select(blocked, 0.0, 1.0)
        values = [v, 2.0 * v * dr.maximum(dr.dot(n, d), 0.0), v * d.x, v * d.y, v * d.z]
        acc.add(a, values)
    mean, var = acc.result()
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def hit_distances(mi, mi_scene, points, normals, directions, rotate_seed: int | None = None) -> np.ndarray:
    """Hit distances (K, N) (scene units, float64; +∞ for a miss) of the rays from each point along the K
    local ``directions`` (K, 3) (z = normal, Mitsuba's ``Frame3f(n)``), spawned as the references spawn
    theirs. ``rotate_seed``: rotate each point's direction set about its normal by a per-point random angle
    (uniform; a Cranley–Patterson rotation of the stratified set: banding becomes noise); None: none."""
    if mi.variant().startswith("scalar"):
        raise ValueError("hit_distances needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    pts = np.ascontiguousarray(points, dtype=np.float32)
    nrm = np.asarray(normals, dtype=np.float64)
    dirs = np.asarray(directions, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape:
        raise ValueError(f"points and normals must both be (N, 3) (got {pts.shape} and {nrm.shape})")
    if dirs.ndim != 2 or dirs.shape[1] != 3 or len(dirs) < 1 or np.any(dirs[:, 2] < 0):
        raise ValueError("directions must be (K, 3) local unit vectors with z >= 0")
    nrm = np.ascontiguousarray(nrm / np.linalg.norm(nrm, axis=1, keepdims=True), dtype=np.float32)
    n_pts, k = len(pts), len(dirs)
    angle = (
        np.zeros(n_pts)
        if rotate_seed is None
        else np.random.default_rng(sub_seed(rotate_seed, "rotate", 0)).uniform(0, 2 * math.pi, n_pts)
    )
    out = np.empty((k, n_pts))
    per = max(1, MAX_LANES // k)
    for a in range(0, n_pts, per):
        b = min(n_pts, a + per)
        lanes = (b - a) * k
        idx = dr.arange(mi.UInt32, lanes) // k
        kk = dr.arange(mi.UInt32, lanes) % k
        c, s = np.cos(angle[a:b]), np.sin(angle[a:b])
        lx = dr.gather(mi.Float, mapped_floats(mi.Float, dirs[:, 0]), kk)
        ly = dr.gather(mi.Float, mapped_floats(mi.Float, dirs[:, 1]), kk)
        lz = dr.gather(mi.Float, mapped_floats(mi.Float, dirs[:, 2]), kk)
        cc = dr.gather(mi.Float, mapped_floats(mi.Float, c), idx)
        ss = dr.gather(mi.Float, mapped_floats(mi.Float, s), idx)
        local = mi.Vector3f(cc * lx - ss * ly, ss * lx + cc * ly, lz)
        p = dr.gather(mi.Point3f, device_vectors(mi, mi.Point3f, pts[a:b]), idx)
        n = dr.gather(mi.Vector3f, device_vectors(mi, mi.Vector3f, nrm[a:b]), idx)
        d = mi.Frame3f(n).to_world(local)
        si = mi_scene.ray_intersect(_spawn(mi, dr, p, n, d))
        t = np.asarray(dr.select(si.is_valid(), si.t, dr.inf), dtype=np.float64)
        out[:, a:b] = t.reshape(b - a, k).T
    return out


# ------------------------------------------------------------------------------------ sdfgrid scene
def sdfgrid_dict(mi, grid) -> dict:
    """Mitsuba ``sdfgrid`` shape of an rtfit `SdfGrid` (node box = rtfit's cell-centre box)."""
    nx, ny, nz = grid.shape
    h = grid.voxel
    o = np.asarray(grid.origin, dtype=np.float64) + 0.5 * h
    scale = np.array([(nx - 1) * h, (ny - 1) * h, (nz - 1) * h])
    m = np.eye(4)
    m[:3, :3] = np.diag(scale)
    m[:3, 3] = o
    return {
        "type": "sdfgrid",
        "grid": mi.TensorXf(np.ascontiguousarray(grid.values, dtype=np.float32)[..., None]),
        "to_world": mi.ScalarTransform4f(m.tolist()),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
    }


def sdfgrid_scene(mi, grid, camera=None):
    """A Mitsuba scene holding only the ``sdfgrid`` shape (and the camera of an rtfit Scene, if given)."""
    d = {"type": "scene", "sdf": sdfgrid_dict(mi, grid)}
    if camera is not None:
        d["sensor"] = camera_dict(mi, camera)
    return mi.load_dict(d)


# ------------------------------------------------------------------------------------------- cache
@dataclass(frozen=True)
class OcclusionReference:
    mean: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    seconds: float
    key: str
    quantity: str
    sky: dict | None = None

    @property
    def samples_per_second(self) -> float:
        return self.mean.size * self.spp / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict:
        return {
            "integrator": f"rtfit ray-cast {self.quantity} (Mitsuba ray_test/ray_intersect)",
            "quantity": self.quantity,
            "spp": self.spp,
            "passes": self.passes,
            "cache_key": self.key,
            "mean_rel_stderr": float(np.mean(self.stderr[self.mean > 0] / self.mean[self.mean > 0]))
            if np.any(self.mean > 0)
            else 0.0,
            "samples_per_second": float(self.samples_per_second) if self.seconds > 0 else None,
            **({"sky": self.sky} if self.sky is not None else {}),
        }


class OcclusionCache:
    """Resumable pass cache for `occlusion_pass`: one `rtfit.reference.cache.PassEntry` per request
    (namespace ``occlusion``, ``.npz`` passes), keyed by everything that determines the samples (geometry
    hash, probe points and normals, quantity, distance, albedo, sky, seed, samples per pass, variant,
    versions). Pass i is seeded with ``sub_seed(seed, "pass", i)``."""

    def __init__(self, root):
        self.root = Path(root)

    def get(
        self,
        mi,
        mi_scene,
        geometry_hash: str,
        points,
        normals,
        *,
        spp: int,
        pass_spp: int,
        seed: int,
        variant: str,
        quantity: str = "ao",
        max_distance: float = math.inf,
        albedo: float = 0.8,
        sky: SunskySky | None = None,
        distance_weight=None,
        weight_key: dict | None = None,
    ) -> OcclusionReference:
        import mitsuba  # (only for its version; imported where Mitsuba is already in use)

        _check(quantity, pass_spp, max_distance, albedo)
        if quantity.startswith("sunsky"):
            sky = sky or SunskySky()
        ident = {
            "format": FORMAT,
            "geometry": geometry_hash,
            "points": array_digest(points, normals),
            "quantity": quantity,
            "max_distance": None if not math.isfinite(max_distance) else float(max_distance),
            "albedo": float(albedo) if quantity in GLOBAL_QUANTITIES else None,
            "seed": int(seed),
            "pass_spp": int(pass_spp),
            "variant": variant,
            "versions": [mitsuba.__version__, dr.__version__],
            **launch_identity(variant),
        }
        if quantity == "obscurance":  # ρ's form and parameters (absent elsewhere: other keys unchanged)
            if not isinstance(weight_key, dict) or not weight_key:
                raise ValueError("the obscurance quantity needs weight_key (ρ's form and parameters)")
            ident["distance_weight"] = weight_key
        if quantity.startswith("sunsky"):  # (absent for the other quantities: their keys are unchanged)
            ident["sky"] = {**sky.to_dict(), "bake_height": SKY_BAKE_HEIGHT}
        entry = PassEntry(self.root, ident, namespace="occlusion", storage="npz")
        resident: list[DeviceProbes] = []  # the probes on the device, once for all the passes rendered

        def render(i: int) -> PassResult:
            if not resident:
                resident.append(device_probes(mi, points, normals, normalise=True))
            return occlusion_pass(
                mi,
                mi_scene,
                resident[0],
                None,
                int(pass_spp),
                sub_seed(seed, "pass", i),
                quantity=quantity,
                max_distance=max_distance,
                albedo=albedo,
                sky=sky,
                distance_weight=distance_weight,
            )

        results, _ = entry.passes(-(-int(spp) // int(pass_spp)), render, spp_of=lambda _i: int(pass_spp))
        mean, stderr, total = pool_passes(results)
        return OcclusionReference(
            mean,
            stderr,
            total,
            len(results),
            float(sum(r.seconds for r in results)),
            entry.key,
            quantity,
            sky.to_dict() | {"horizontal_irradiance": sunsky_horizontal_irradiance(mi, sky)}
            if quantity.startswith("sunsky")
            else None,
        )
