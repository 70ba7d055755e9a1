"""Distant lighting environments for the irradiance experiments: baked, loaded and integrated.

Every environment is a *lat-long radiance map in Mitsuba's envmap file convention* (+Y up in the file;
rtfit's builder rotates it so that the file's +Y is world +Z, `rtfit.reference.build`), optionally plus a
finite sun (a uniform disc at infinity, rendered by rtfit's own emitter). In the world frame (+Z up)
a map node (i, j) of an H × W map sits at u = (i + ½)/W, v = j/(H − 1), i.e. at

    θ = πv (from +Z),  φ = 2πu (from +Y towards +X),  d = (sin θ sin φ, sin θ cos φ, cos θ),

and Mitsuba's ``envmap`` interpolates bilinearly between nodes (periodic in u; rows 0 and H − 1 at the
poles). This was measured on Mitsuba 3.9.1 (``tests/test_environments.py`` checks it with one bright
texel and with midpoints). Radiance in W·m⁻²·sr⁻¹, irradiance in W·m⁻², per linear-sRGB channel.

Mitsuba takes one environment emitter per scene, so a sun cannot share a scene with an envmap. Irradiance
is linear in the emitters: the experiment renders the map and the sun as two references and adds them
(means add, variances add).

Environments (`make_environment`):

* ``constant``   radiance L everywhere (white furnace: E = πL at every normal).
* ``sun``        a disc of angular radius α (0.27° … 20°) of normal-incidence irradiance π, no sky.
* ``sunsky``     Mitsuba's Hosek–Wilkie ``sunsky`` (turbidity 3, ground albedo 0.3): the sky (``sun_scale``
                 0) is baked by evaluating the Mitsuba emitter at the map nodes; the sun (``sky_scale`` 0)
                 becomes a disc sun of the sunsky's aperture (0.5358° diameter) whose normal-incidence
                 irradiance E⊥ is integrated from the emitter's own radiance over the disc (Gauss–Legendre
                 in the polar angle, dense in azimuth). The sun is about 10⁴–10⁵ times brighter than the sky.
* ``studio``     a dark background (0.02) with three small bright softboxes (smooth caps of 4°–8°).
* ``overcast``   the CIE overcast sky L(θ) = L_z (1 + 2 cos θ)/3 over a ground of albedo 0.2.
* ``probe:<name>`` a measured light probe from ``../shared/probes`` resampled into the convention above
                 (its own projection and orientation handled per file, see `PROBES`).

`irradiance_quadrature` is the independent check of Mitsuba's irradiance: a dense midpoint rule over the
bilinear function Mitsuba sees, E(n) = Σ_k w_k L_k max(n·d_k, 0).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .latlong_quadrature import (
    LatLongTable,
    cached_table,
    latlong_irradiance,
    latlong_table,
    table_irradiance,
)

_ROOT = Path(__file__).resolve().parents[1]


def probe_dir() -> Path:
    """Where the measured probes are: ``$RTFIT_PROBE_DIR``, else ``<repo>/shared/probes``, else
    ``<repo>/../shared/probes``."""
    env = os.environ.get("RTFIT_PROBE_DIR")
    if env:
        return Path(env)
    for cand in (_ROOT / "shared" / "probes", _ROOT.parent / "shared" / "probes"):
        if cand.is_dir():
            return cand
    return _ROOT.parent / "shared" / "probes"


# name → (file, projection). pbrt-v2: s = atan2(y, x)/2π, t = acos(z)/π in the file's frame, whose +Z is the
# world's nadir (the floor is on the top row): the file frame is the world rotated by 180° about +X.
# probulator: +Y up, d = (sin φ sin θ, cos φ, −sin φ cos θ), θ = π(2u − 1), φ = πv (README of the probes).
PROBES = {
    "grace": ("pbrt-v2_grace_latlong.exr", "pbrt"),
    "grace-ict": ("probulator_grace.hdr", "probulator"),
    "uffizi": ("probulator_uffizi.hdr", "probulator"),
    "ennis": ("probulator_ennis.hdr", "probulator"),
    "pisa": ("probulator_pisa.hdr", "probulator"),
    "wells": ("probulator_wells.hdr", "probulator"),
}
PROBE_CREDITS = (
    "Light probes: Paul Debevec and USC ICT (Grace Cathedral, Uffizi, Ennis, Pisa), "
    "Bernhard Vogl (Wells); files from pbrt-v2 and kayru/Probulator."
)
SUNSKY_APERTURE_DEG = 0.5358  # Mitsuba's default sun aperture (full angle)


@dataclass(frozen=True)
class DiscSun:
    """A uniform disc at infinity: unit ``direction`` towards it, angular radius (degrees), E⊥ (RGB, W/m²)."""

    direction: tuple[float, float, float]
    angular_radius_deg: float
    irradiance: tuple[float, float, float]


@dataclass(frozen=True)
class Environment:
    """A distant environment: a lat-long map (Mitsuba file convention, (H, W, 3) float32) or a constant
    radiance, plus an optional disc sun. ``params`` are the physical parameters for reports."""

    name: str
    label: str
    kind: str
    radiance_map: np.ndarray | None = field(default=None, compare=False, repr=False)
    constant: tuple[float, float, float] | None = None
    sun: DiscSun | None = None
    params: dict = field(default_factory=dict, compare=False)

    @property
    def has_sky(self) -> bool:
        return self.radiance_map is not None or self.constant is not None


# =========================================================================================== frames
def node_uv(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of the map nodes, each (H, W): u = (i + ½)/W, v = j/(H − 1)."""
    u = (np.arange(width) + 0.5) / width
    v = np.arange(height) / (height - 1)
    return np.meshgrid(u, v)


def uv_to_direction(u, v) -> np.ndarray:
    """World direction (+Z up) of Mitsuba lat-long (u, v), see the module docstring."""
    th, ph = np.pi * np.asarray(v, np.float64), 2.0 * np.pi * np.asarray(u, np.float64)
    return np.stack([np.sin(th) * np.sin(ph), np.sin(th) * np.cos(ph), np.cos(th)], axis=-1)


def direction_to_uv(d) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of `uv_to_direction` (u in [0, 1), v in [0, 1])."""
    d = np.asarray(d, np.float64)
    u = np.mod(np.arctan2(d[..., 0], d[..., 1]) / (2.0 * np.pi), 1.0)
    v = np.arccos(np.clip(d[..., 2], -1.0, 1.0)) / np.pi
    return u, v


def node_directions(height: int, width: int) -> np.ndarray:
    """World directions of the map nodes, (H, W, 3)."""
    return uv_to_direction(*node_uv(height, width))


def bilinear(img: np.ndarray, u, v) -> np.ndarray:
    """Mitsuba's envmap lookup at (u, v): bilinear between nodes u_i = (i + ½)/W (periodic),
    v_j = j/(H − 1)."""
    h, w = img.shape[:2]
    x = np.asarray(u, np.float64) * w - 0.5
    i0 = np.floor(x).astype(np.int64)
    fx = (x - i0)[..., None]
    ia, ib = np.mod(i0, w), np.mod(i0 + 1, w)
    y = np.clip(np.asarray(v, np.float64), 0.0, 1.0) * (h - 1)
    j0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fy = (y - j0)[..., None]
    top = img[j0, ia] * (1 - fx) + img[j0, ib] * fx
    bot = img[j0 + 1, ia] * (1 - fx) + img[j0 + 1, ib] * fx
    return top * (1 - fy) + bot * fy


# =========================================================================================== quadrature
def quadrature_samples(img: np.ndarray, supersample: int):
    """Midpoint samples of the bilinear map on an (sH × sW) grid: directions (M, 3), solid-angle weights
    (M,), radiance (M, 3)."""
    img = np.asarray(img, np.float64)
    h, w = img.shape[:2]
    s = int(supersample)
    u = (np.arange(s * w) + 0.5) / (s * w)
    v = (np.arange(s * h) + 0.5) / (s * h)
    uu, vv = np.meshgrid(u, v)
    wgt = (2.0 * np.pi / (s * w)) * (np.pi / (s * h)) * np.sin(np.pi * vv)
    return uv_to_direction(uu, vv).reshape(-1, 3), wgt.reshape(-1), bilinear(img, uu, vv).reshape(-1, 3)


def irradiance_quadrature(
    env: Environment, normals, supersample: int = 4, backend: str | None = None, include_sun: bool = True
) -> np.ndarray:
    """Irradiance (N, 3) of ``env`` at unit ``normals`` (N, 3): dense midpoint quadrature of the map
    (error O(h²) away from the horizon kink), π·L for a constant, plus the sun's exact disc irradiance.

    The map's sum is `latlong_irradiance`'s (prefix sums along the grid's rows, float64 NumPy, O(rows) per
    normal: issue 33), whatever ``backend`` (kept for the callers; `samples_irradiance` still takes it)."""
    n = np.asarray(normals, np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    e = np.zeros((len(n), 3))
    if env.constant is not None:
        e += math.pi * np.asarray(env.constant, np.float64)[None, :]
    if env.radiance_map is not None and len(n):
        e += table_irradiance(n, map_table(env.radiance_map, supersample))
    if include_sun and env.sun is not None:
        e += disc_irradiance(env.sun, n)
    return e


def map_table(img: np.ndarray, supersample: int) -> LatLongTable:
    """`quadrature_samples` of ``img`` as the prefix sums of `latlong_irradiance`, kept per content of the
    map and ``supersample`` (`cached_table`)."""
    img = np.ascontiguousarray(img)
    s = int(supersample)
    key = (hashlib.blake2b(img.tobytes(), digest_size=20).hexdigest(), img.shape, img.dtype.str, s)

    def build() -> LatLongTable:
        d, w, L = quadrature_samples(img, s)
        return latlong_table(d, L * w[:, None], s * img.shape[0], s * img.shape[1])

    return cached_table(key, build)


def samples_irradiance(normals, d, w, L, backend: str | None = None) -> np.ndarray:
    """Σ_k w_k L_k max(n·d_k, 0) (N, 3) at unit ``normals`` (N, 3) over samples: directions ``d`` (M, 3),
    solid-angle weights ``w`` (M,), radiance ``L`` (M, 3) (or (M, C): C channels, (N, C)). ``backend``: None
    sums in NumPy (float64, blocks of at most 2²¹ products), "llvm"/"cuda" with a Dr.Jit float64 kernel."""
    n = np.asarray(normals, np.float64)
    wl = np.asarray(L, np.float64) * np.asarray(w, np.float64)[:, None]
    keep = np.any(wl != 0, axis=1)
    d, wl = np.asarray(d, np.float64)[keep], wl[keep]
    e = np.zeros((len(n), wl.shape[1]))
    if backend is None:
        chunk = max(256, (1 << 21) // max(len(n), 1))
        for a in range(0, len(d), chunk):
            e += np.maximum(n @ d[a : a + chunk].T, 0.0) @ wl[a : a + chunk]
    elif len(d) and len(n):
        e += _quadrature_drjit(n, d, wl, backend)
    return e


def _quadrature_drjit(n: np.ndarray, d: np.ndarray, wl: np.ndarray, backend: str) -> np.ndarray:
    """`samples_irradiance`'s sum on Dr.Jit, float64: one lane per normal looping over the samples (a
    symbolic loop, the sample count opaque: one compiled kernel for every size), each lane summing
    max(n·d_k, 0)·w_k L_k in sample order. (One lane per normal × sample product reduced by ``block_sum``
    cost 3× the CPU time on 2 cores; the sums agree to ~10⁻¹⁴ relative: issue 33.)"""
    import drjit as dr

    if backend not in ("llvm", "cuda"):
        raise ValueError(f"backend must be None, 'llvm' or 'cuda' (got {backend!r})")
    mod: Any = dr.cuda if backend == "cuda" else dr.llvm
    F, U = mod.Float64, mod.UInt32
    dx, dy, dz = (F(np.ascontiguousarray(d[:, k])) for k in range(3))
    ws = [F(np.ascontiguousarray(wl[:, k])) for k in range(wl.shape[1])]
    nx, ny, nz = (F(np.ascontiguousarray(n[:, k])) for k in range(3))
    m = dr.opaque(U, len(d))

    def body(i, *acc):
        c = dr.maximum(nx * dr.gather(F, dx, i) + ny * dr.gather(F, dy, i) + nz * dr.gather(F, dz, i), 0.0)
        return i + 1, *(a + c * dr.gather(F, wk, i) for a, wk in zip(acc, ws, strict=True))

    state = (dr.zeros(U, len(n)), *(dr.zeros(F, len(n)) for _ in ws))
    _, *sums = dr.while_loop(state=state, cond=lambda i, *_: i < m, body=body)
    dr.eval(sums)
    return np.stack([np.asarray(x, np.float64) for x in sums], axis=-1)


def disc_irradiance(sun: DiscSun, normals) -> np.ndarray:
    """Exact irradiance (N, 3) of a uniform disc at infinity (horizon-clipped), from the closed form of a
    spherical cap (Snyder 1996; the same formula `rtfit.realtime.diffuse.sphere_light_irradiance` uses),
    re-derived here independently in float64."""
    n = np.asarray(normals, np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    d = np.asarray(sun.direction, np.float64)
    d = d / np.linalg.norm(d)
    a = math.radians(sun.angular_radius_deg)
    ct = np.clip(n @ d, -1.0, 1.0)
    e_unit = _cap_irradiance(ct, a) / (math.pi * math.sin(a) ** 2) if a > 0 else np.maximum(ct, 0.0)
    return e_unit[:, None] * np.asarray(sun.irradiance, np.float64)[None, :]


def _cap_irradiance(cos_t, alpha):
    """∫_cap max(n·ω, 0) dω for a cap of angular radius α whose axis makes angle θ with n (unit radiance):
    π sin²α cos θ where the cap is wholly above the horizon of n, 0 wholly below, numerical in between."""
    cos_t = np.asarray(cos_t, np.float64)
    t = np.arccos(cos_t)
    out = np.where(t <= math.pi / 2 - alpha, math.pi * math.sin(alpha) ** 2 * cos_t, 0.0)
    mid = (t > math.pi / 2 - alpha) & (t < math.pi / 2 + alpha)
    if np.any(mid):
        out[mid] = _cap_numeric(cos_t[mid], alpha)
    return out


def _cap_numeric(cos_t, alpha, n_r: int = 64, n_phi: int = 256):
    """∫_cap max(n·ω, 0) dω by Gauss–Legendre in the cap's polar angle and the midpoint rule in azimuth
    (used only where the cap straddles the horizon)."""
    x, wx = np.polynomial.legendre.leggauss(n_r)
    ca = math.cos(alpha)
    mu = 0.5 * (1 - ca) * x + 0.5 * (1 + ca)  # cos of the polar angle about the cap axis, in [cos α, 1]
    wmu = 0.5 * (1 - ca) * wx
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    s = np.sqrt(np.maximum(1 - mu * mu, 0.0))
    ct = np.asarray(cos_t)[:, None, None]
    st = np.sqrt(np.maximum(1 - ct * ct, 0.0))
    # axis along z' ; normal at angle t in the x'z' plane: n·ω = cos t · μ + sin t · s cos φ
    dot = ct * mu[None, :, None] + st * s[None, :, None] * np.cos(phi)[None, None, :]
    return np.sum(np.maximum(dot, 0.0) * wmu[None, :, None], axis=(1, 2)) * (2 * math.pi / n_phi)


# =========================================================================================== synthetic maps
def constant_environment(radiance=1.0) -> Environment:
    r = tuple(float(x) for x in np.broadcast_to(np.asarray(radiance, np.float64), (3,)))
    return Environment(
        "constant", f"constant L = {r[0]:g}", "constant", constant=r, params={"radiance": r[0]}
    )


def sun_environment(
    angular_radius_deg: float,
    elevation_deg: float = 45.0,
    azimuth_deg: float = 30.0,
    irradiance: float = math.pi,
) -> Environment:
    a = float(angular_radius_deg)
    if not (0.0 < a < 90.0):
        raise ValueError(f"angular_radius_deg must be in (0, 90) (got {angular_radius_deg!r})")
    d = _direction(elevation_deg, azimuth_deg)
    return Environment(
        f"sun-{a:g}",
        f"sun α = {a:g}°, elevation {elevation_deg:g}°",
        "sun",
        sun=DiscSun(d, a, (irradiance,) * 3),
        params={"angular_radius_deg": a, "sun_elevation_deg": float(elevation_deg)},
    )


def _direction(elevation_deg, azimuth_deg) -> tuple[float, float, float]:
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))


def _smooth_cap(d: np.ndarray, axis, radius_deg: float) -> np.ndarray:
    """1 inside a cap, smooth (cosine) falloff over its outer 30%: a softbox without aliasing."""
    ax = np.asarray(axis, np.float64)
    ax = ax / np.linalg.norm(ax)
    ang = np.degrees(np.arccos(np.clip(d @ ax, -1, 1)))
    r0, r1 = 0.7 * radius_deg, radius_deg
    t = np.clip((ang - r0) / (r1 - r0), 0.0, 1.0)
    return 0.5 * (1 + np.cos(np.pi * t))


STUDIO_LIGHTS = (  # (elevation°, azimuth°, radius°, RGB radiance)
    (35.0, 40.0, 8.0, (60.0, 58.0, 55.0)),  # key
    (20.0, -70.0, 6.0, (12.0, 14.0, 18.0)),  # fill (cool)
    (60.0, 170.0, 4.0, (120.0, 110.0, 90.0)),  # rim (warm, small)
)


def studio_map(height: int, width: int, background: float = 0.02) -> np.ndarray:
    d = node_directions(height, width)
    img = np.full((height, width, 3), background, np.float64)
    for el, az, rad, rgb in STUDIO_LIGHTS:
        img += _smooth_cap(d, _direction(el, az), rad)[..., None] * np.asarray(rgb)[None, None, :]
    return img.astype(np.float32)


def overcast_map(height: int, width: int, zenith: float = 1.0, ground_albedo: float = 0.2) -> np.ndarray:
    """CIE standard overcast sky L = L_z (1 + 2 cos θ)/3 above the horizon; below it a Lambertian ground lit
    by that sky: L_g = ρ E_h/π with E_h = (7π/9) L_z."""
    d = node_directions(height, width)
    cz = d[..., 2]
    sky = zenith * (1 + 2 * np.maximum(cz, 0.0)) / 3.0
    ground = ground_albedo * 7.0 * zenith / 9.0
    lum = np.where(cz >= 0, sky, ground)
    tint = np.where(cz[..., None] >= 0, np.array([0.95, 1.0, 1.05]), np.array([1.0, 0.95, 0.85]))
    return (lum[..., None] * tint).astype(np.float32)


def map_environment(name: str, label: str, kind: str, img: np.ndarray, **params) -> Environment:
    img = np.asarray(img, np.float32)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2:
        raise ValueError(f"{name}: radiance map must be (H >= 2, W, 3) (got {img.shape})")
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise ValueError(f"{name}: radiance map must be finite and >= 0")
    return Environment(name, label, kind, radiance_map=img, params=dict(params))


# =========================================================================================== sunsky
def sunsky_environment(
    mi, elevation_deg: float, height: int, width: int, turbidity: float = 3.0, azimuth_deg: float = 30.0
) -> Environment:
    """Mitsuba ``sunsky`` as a baked sky map (sun_scale 0) plus a disc sun (sky_scale 0) whose E⊥ is
    integrated from the emitter's radiance (``mi``: the mitsuba module with an RGB variant set)."""
    import drjit as dr

    el = float(elevation_deg)
    if not (0.0 < el <= 90.0):
        raise ValueError(f"sun elevation_deg must be in (0, 90] for the baked sunsky (got {elevation_deg!r})")
    d_sun = np.array(_direction(el, azimuth_deg))
    base = {
        "type": "sunsky",
        "sun_direction": d_sun.tolist(),
        "turbidity": float(turbidity),
        "albedo": 0.3,
        "sun_aperture": SUNSKY_APERTURE_DEG,
    }
    sky = mi.load_dict({**base, "sun_scale": 0.0})
    dirs = node_directions(height, width).reshape(-1, 3)
    img = _eval_emitter(mi, dr, sky, dirs).reshape(height, width, 3)
    img = np.maximum(img, 0.0)  # Hosek–Wilkie can go slightly negative at invalid elevations (mitsuba3 #1777)
    sun_only = mi.load_dict({**base, "sky_scale": 0.0})
    e_perp, e_eval = sunsky_sun_irradiance(mi, sun_only, d_sun)
    # Hosek–Wilkie's sun goes negative in blue near the horizon (−0.004 W/m² at 2°; mitsuba3 #1777): a light
    # cannot emit negative power, so such channels are set to 0 (and excluded from the bake check).
    negative = [int(c) for c in np.nonzero(e_perp < 0)[0]]
    e_perp = np.maximum(e_perp, 0.0)
    sun = DiscSun(tuple(float(v) for v in d_sun), SUNSKY_APERTURE_DEG / 2, tuple(float(v) for v in e_perp))
    return Environment(
        f"sunsky-{el:g}",
        f"sunsky, sun elevation {el:g}°",
        "sunsky",
        radiance_map=img.astype(np.float32),
        sun=sun,
        params={
            "sun_elevation_deg": el,
            "turbidity": float(turbidity),
            "sun_irradiance_rgb": list(sun.irradiance),
            "sun_irradiance_eval_rgb": [float(v) for v in e_eval],
            "sun_negative_channels": negative,
        },
    )


def emitter_environment(
    mi, emitter, kind: str, height: int, sun: tuple | None = None, name: str = ""
) -> Environment:
    """An `Environment` of a loaded Mitsuba environment emitter (``mi``: the mitsuba module in an RGB
    variant), for a scene's own ``envmap``, ``constant`` or ``sunsky``:

    * ``constant``: its radiance (the emitter evaluated in one direction), E = πL at every normal;
    * otherwise a lat-long map of ``height`` × 2·``height`` nodes (the module's convention) holding the
      emitter's own ``eval`` at the node directions (its ``to_world`` and ``scale`` included), bilinear in
      between — the quadrature then integrates that bake, whose error against the emitter is O(h²) in the
      node spacing h = π/(height − 1) for a smooth map (a sharper file is smoothed at that scale);
    * ``sunsky`` with ``sun`` = (unit direction towards the sun, angular radius in degrees): the sky is
      baked with the emitter's ``sun_scale`` set to 0 and the sun becomes a `DiscSun` whose E⊥ is
      `sunsky_sun_irradiance` of the emitter with ``sky_scale`` 0 (the scales are put back afterwards).

    Negative values of the bake (Hosek–Wilkie below the horizon, mitsuba3 #1777) are clamped to 0."""
    import drjit as dr

    if kind == "constant":
        value = _eval_emitter(mi, dr, emitter, np.array([[0.0, 0.0, 1.0]]))[0]
        return constant_environment(value)
    dirs = node_directions(height, 2 * height).reshape(-1, 3)
    if kind == "sunsky" and sun is not None:
        with emitter_scales(mi, emitter, sun_scale=0.0):
            img = _eval_emitter(mi, dr, emitter, dirs)
        d_sun = np.asarray(sun[0], np.float64)
        with emitter_scales(mi, emitter, sky_scale=0.0):
            e_perp, _e_eval = sunsky_sun_irradiance(mi, emitter, d_sun / np.linalg.norm(d_sun))
        u = d_sun / np.linalg.norm(d_sun)
        e = np.maximum(e_perp, 0.0)
        disc = DiscSun(
            (float(u[0]), float(u[1]), float(u[2])), float(sun[1]), (float(e[0]), float(e[1]), float(e[2]))
        )
    else:
        img, disc = _eval_emitter(mi, dr, emitter, dirs), None
    img = np.maximum(img, 0.0).reshape(height, 2 * height, 3).astype(np.float32)
    return Environment(
        name or kind, name or kind, kind, radiance_map=img, sun=disc, params={"bake_rows": height}
    )


@contextlib.contextmanager
def emitter_scales(mi, emitter, **scales):
    """The emitter with its ``sun_scale``/``sky_scale`` set as given (a sunsky), put back afterwards."""
    params = mi.traverse(emitter)
    old = {k: float(params[k]) for k in scales}
    try:
        for k, v in scales.items():
            params[k] = v
        params.update()
        yield emitter
    finally:
        for k, v in old.items():
            params[k] = v
        params.update()


def emitter_irradiance_quadrature(
    mi, emitter, kind: str, normals, rows: int, sun: DiscSun | None = None, backend: str | None = None
) -> np.ndarray:
    """Irradiance (N, 3) of a loaded Mitsuba environment emitter at unit ``normals``: the midpoint rule over
    ``rows`` × 2·``rows`` lat-long cells (θ = π(j + ½)/rows, the module's frame) with the emitter's own
    ``eval`` at each cell centre — no bake, no interpolation, so a radiance cut on a cell boundary (a
    sunsky's horizon, with ``rows`` even) is integrated without smearing — plus, for a ``sunsky`` with
    ``sun``, its sky alone (``sun_scale`` 0) and the disc sun's exact irradiance (`disc_irradiance`).
    A ``constant``: πL. The cells' sum is `latlong_irradiance`'s, whatever ``backend`` (kept for callers)."""
    import drjit as dr

    n = np.asarray(normals, np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    if kind == "constant":
        value = _eval_emitter(mi, dr, emitter, np.array([[0.0, 0.0, 1.0]]))[0]
        return np.tile(math.pi * value, (len(n), 1))
    r = int(rows)
    u = (np.arange(2 * r) + 0.5) / (2 * r)
    v = (np.arange(r) + 0.5) / r
    uu, vv = np.meshgrid(u, v)
    d = uv_to_direction(uu, vv).reshape(-1, 3)
    w = ((2.0 * np.pi / (2 * r)) * (np.pi / r) * np.sin(np.pi * vv)).reshape(-1)
    if kind == "sunsky" and sun is not None:
        with emitter_scales(mi, emitter, sun_scale=0.0):
            L = _eval_emitter(mi, dr, emitter, d)
    else:
        L = _eval_emitter(mi, dr, emitter, d)
    e = latlong_irradiance(n, d, np.maximum(L, 0.0) * w[:, None], r, 2 * r)
    if sun is not None:
        e += disc_irradiance(sun, n)
    return e


def sunsky_sun_irradiance(mi, sun_only, d_sun: np.ndarray, samples: int = 1 << 18):
    """Normal-incidence irradiance of a sunsky emitter with ``sky_scale`` 0, two ways (RGB W/m² each):

    * Mitsuba's emitter-sampling estimator, mean of w·cos γ over ``sample_direction`` (w = L/pdf): what
      Mitsuba's renders of the sun converge to (MIS gives a sun of 0.27° to emitter sampling);
    * the integral of ``eval`` over the disc (midpoint rule, 400 rings out to 0.3°, 256 azimuths).

    Measured on Mitsuba 3.9.1: ``eval`` is non-zero out to 0.2694° while ``sample_direction`` stays inside
    0.2674°, so the eval integral is about 0.8% higher. rtfit's disc sun takes the first value (the
    irradiance Mitsuba's own sunsky delivers); the second is kept in the environment's parameters."""
    import drjit as dr

    d = np.asarray(d_sun, np.float64)
    it = dr.zeros(mi.Interaction3f, samples)
    it.n = mi.Vector3f(*[float(v) for v in d])
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(7, samples)
    ds, w = sun_only.sample_direction(it, sampler.next_2d())
    cos = dr.maximum(dr.dot(ds.d, it.n), 0.0)
    e_sampled = np.array(w * cos, dtype=np.float64).reshape(3, -1).mean(axis=1)
    r_max, n_r, n_phi = math.radians(0.3), 400, 256
    g = (np.arange(n_r) + 0.5) * r_max / n_r
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    gg, pp = np.meshgrid(g, phi, indexing="ij")
    local = np.stack([np.sin(gg) * np.cos(pp), np.sin(gg) * np.sin(pp), np.cos(gg)], -1).reshape(-1, 3)
    L = _eval_emitter(mi, dr, sun_only, local @ _frame(d).T).reshape(n_r, n_phi, 3)
    wts = (np.sin(g) * np.cos(g) * r_max / n_r)[:, None] * (2 * math.pi / n_phi)
    e_eval = np.sum(L * wts[..., None], axis=(0, 1))
    return e_sampled, e_eval


def _frame(n: np.ndarray) -> np.ndarray:
    n = n / np.linalg.norm(n)
    hint = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t = np.cross(hint, n)
    t /= np.linalg.norm(t)
    return np.column_stack([t, np.cross(n, t), n])


def _eval_emitter(mi, dr, emitter, dirs: np.ndarray) -> np.ndarray:
    si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
    si.wi = mi.Vector3f(np.ascontiguousarray(-dirs.T, dtype=np.float32))
    val = emitter.eval(si)
    return np.array(val, dtype=np.float64).T.reshape(len(dirs), 3)


# =========================================================================================== probes
def read_image(path: Path) -> np.ndarray:
    """The RGB pixels (H, W, 3) float32 of an image file Mitsuba's ``Bitmap`` reads (EXR, Radiance HDR, PFM,
    …); alpha and further channels are dropped. A file that does not read raises (Mitsuba's message)."""
    import mitsuba as mi

    arr = np.array(mi.Bitmap(str(path)), dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] < 3:
        raise ValueError(f"{path}: expected an RGB image (got shape {arr.shape})")
    return arr[..., :3]


def _box_down(img: np.ndarray, factor: int) -> np.ndarray:
    if factor <= 1:
        return img
    h, w = img.shape[:2]
    h2, w2 = h // factor, w // factor
    return img[: h2 * factor, : w2 * factor].reshape(h2, factor, w2, factor, 3).mean(axis=(1, 3))


def source_lookup(src: np.ndarray, fu: np.ndarray, fv: np.ndarray, periodic_u: bool = True) -> np.ndarray:
    """Bilinear lookup with texel centres at ((i + ½)/W, (j + ½)/H), periodic in u (``periodic_u``; else
    clamped to the edge texels like v), clamped in v. Needs W, H ≥ 2."""
    h, w = src.shape[:2]
    x = fu * w - 0.5
    if not periodic_u:
        x = np.clip(x, 0.0, w - 1.0 - 1e-9)
    y = np.clip(fv * h - 0.5, 0.0, h - 1.0)
    i0 = np.floor(x).astype(np.int64)
    j0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fx, fy = (x - i0)[..., None], (y - j0)[..., None]
    ia, ib = np.mod(i0, w), np.mod(i0 + 1, w)
    top = src[j0, ia] * (1 - fx) + src[j0, ib] * fx
    bot = src[j0 + 1, ia] * (1 - fx) + src[j0 + 1, ib] * fx
    return top * (1 - fy) + bot * fy


def probe_source_uv(projection: str, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) in the *source file* of world direction(s) ``d`` (+Z up) for a probe projection."""
    if projection == "pbrt":  # file frame = world rotated 180° about +X: f = (x, −y, −z)
        fx, fy, fz = d[..., 0], -d[..., 1], -d[..., 2]
        return np.mod(np.arctan2(fy, fx) / (2 * np.pi), 1.0), np.arccos(np.clip(fz, -1, 1)) / np.pi
    if projection == "probulator":  # world = (sin φ sin θ, sin φ cos θ, cos φ) after +Y → +Z
        theta = np.arctan2(d[..., 0], d[..., 1])
        return np.mod((theta / np.pi + 1.0) / 2.0, 1.0), np.arccos(np.clip(d[..., 2], -1, 1)) / np.pi
    raise ValueError(f"unknown probe projection {projection!r}")


_probe_dir = probe_dir


def probe_available(name: str, probe_dir: Path | None = None) -> bool:
    """True when the file of the measured probe ``name`` is present (see `probe_dir`)."""
    return name in PROBES and (Path(probe_dir or _probe_dir()) / PROBES[name][0]).is_file()


def probe_environment(name: str, height: int | None = None, probe_dir: Path | None = None) -> Environment:
    """A measured probe resampled into Mitsuba's lat-long convention with ``height`` rows (2:1 aspect;
    default: the file's own height). The file is box-filtered first when ``height`` is much smaller."""
    if name not in PROBES:
        raise ValueError(f"unknown probe {name!r} (known: {', '.join(PROBES)})")
    fname, projection = PROBES[name]
    path = Path(probe_dir or _probe_dir()) / fname
    if not path.is_file():
        raise ValueError(f"probe file not found: {path} (set RTFIT_PROBE_DIR)")
    src = read_image(path).astype(np.float64)
    h = int(height or src.shape[0])
    factor = max(1, src.shape[0] // h)
    src = _box_down(src, factor)
    d = node_directions(h, 2 * h)
    img = source_lookup(src, *probe_source_uv(projection, d))
    img = np.maximum(img, 0.0)
    return map_environment(
        f"probe-{name}",
        f"probe: {name}",
        "probe",
        img,
        probe=name,
        file=fname,
        source_shape=list(src.shape[:2]),
    )


def write_map_exr(img: np.ndarray, path) -> Path:
    """Write a float32 RGB lat-long map as EXR (atomic rename)."""
    import mitsuba as mi

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.exr")
    mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32)).write(str(tmp))
    os.replace(tmp, path)
    return path
