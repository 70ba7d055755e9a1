r"""Mitsuba ground truth for a planet's sky: a spherical-shell Rayleigh + Mie atmosphere.

Scene (units: **kilometres**, +Z up, planet centre at the origin):

* a planet ``sphere`` of radius R_g with a diffuse BSDF (the ground albedo);
* an atmosphere ``sphere`` of radius R_t with a ``null`` BSDF and the Python medium
  ``rtfit_atmosphere`` inside; the camera sits inside the medium at altitude h₀ above the north
  pole, (0, 0, R_g + h₀);
* the sun: rtfit's distant-disc emitter (`rtfit.reference.emitters`, a uniform disc of angular
  radius α at infinity, irradiance E₀ at normal incidence, radiance E₀/(π sin²α)).

Medium: with h = |p| − R_g the altitude of a point,

    σ_s(p) = β_R ρ_R(h) + β_M ρ_M(h),   σ_t(p) = β_R ρ_R(h) + β_M^ext ρ_M(h),
    ρ_R = exp(−h/H_R),  ρ_M = exp(−h/H_M),

per RGB channel (β in km⁻¹). Rayleigh and Mie scatter with different phase functions, and
Mitsuba allows one phase function per medium (two overlapping media are not supported: a ray is
inside one medium at a time). The mixture is represented **exactly** by the Python phase function
``rtfit_rayleigh_mie``: at a scattering point its value per channel c is

    p_c(ω) = (β_R,c ρ_R P_R(ω) + β_M,c ρ_M P_M(ω)) / (β_R,c ρ_R + β_M,c ρ_M),

(the scattering-weighted mixture; Mitsuba 3 phase functions return a Spectrum value), directions
are sampled from the channel-averaged mixture w·P_M + (1 − w)·P_R with
w = Σ_c β_M,c ρ_M / Σ_c (β_R,c ρ_R + β_M,c ρ_M), and the pdf returned is that mixture's, so the
sample weight p_c/pdf is exact and MIS with emitter sampling stays unbiased. ``blendphase`` would
use one scalar weight for all channels, which is wrong for a chromatic Rayleigh/Mie ratio.
P_R(cos θ) = 3/(16π)(1 + cos²θ); P_M is Henyey–Greenstein with asymmetry g (Mitsuba's
convention: cos θ = −wi·wo, wi pointing back along the incoming ray).

Integrator: ``volpathmis`` (unbiased with chromatic extinction); ``max_depth = 2`` gives single
scattering (camera segment, one scattering event, next-event estimation to the sun), ``-1`` all
orders including the ground bounce.

Also here, for the cross-checks of the experiment:

* `single_scattering_quadrature`: an independent float64 NumPy quadrature of the single-scattering
  integral (fine trapezoid along the view ray, sun optical depth by Gauss–Legendre along each
  sun ray, planet shadow by exact ray–sphere test), to check the Mitsuba single-scattering
  reference and the real-time sky;
* `sunsky_radiance`: Mitsuba's Hosek–Wilkie ``sunsky`` evaluated along directions.

This module does not import ``rtfit.realtime`` (layering): parameters are plain numbers.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .estimators import PassResult, _chunks, _mean_var, _moments, sub_seed
from .io import atomic_write_bytes

__all__ = [
    "AtmosphereSpec", "MEDIUM_PLUGIN", "PHASE_PLUGIN", "hemisphere_directions", "load_atmosphere_scene",
    "register", "render_sky", "scene_dict", "single_scattering_quadrature", "sky_pass",
    "sunsky_radiance",
]

MEDIUM_PLUGIN = "rtfit_atmosphere"
PHASE_PLUGIN = "rtfit_rayleigh_mie"
_CACHE_FORMAT = 1


@dataclass(frozen=True)
class AtmosphereSpec:
    """A sky to render. Lengths in km, coefficients in km⁻¹ per RGB channel, angles in degrees.

    Defaults: Bruneton & Neyret 2008 / Bruneton 2017's shared parameter set (no ozone), sun of
    angular radius 0.2679° (4.675 mrad), solar irradiance at 680/550/440 nm in W·m⁻²·nm⁻¹.
    """

    sun_elevation_deg: float = 45.0
    viewer_altitude_km: float = 0.01
    planet_radius_km: float = 6360.0
    top_radius_km: float = 6420.0
    rayleigh_beta: tuple = (5.802e-3, 13.558e-3, 33.1e-3)
    rayleigh_height_km: float = 8.0
    mie_beta: tuple = (3.996e-3, 3.996e-3, 3.996e-3)
    mie_extinction: tuple = (4.440e-3, 4.440e-3, 4.440e-3)
    mie_height_km: float = 1.2
    mie_g: float = 0.8
    ground_albedo: float = 0.1
    sun_angular_radius_deg: float = 0.2679
    solar_irradiance: tuple = (1.474, 1.8504, 1.91198)

    def __post_init__(self):
        if not (-90.0 <= self.sun_elevation_deg <= 90.0):
            raise ValueError(f"sun_elevation_deg must be in [-90, 90] (got {self.sun_elevation_deg!r})")
        if not (0.0 <= self.viewer_altitude_km < self.top_radius_km - self.planet_radius_km):
            raise ValueError("viewer_altitude_km must be in [0, top - planet) "
                             f"(got {self.viewer_altitude_km!r})")
        if not (0.0 < self.planet_radius_km < self.top_radius_km):
            raise ValueError("need 0 < planet_radius_km < top_radius_km")
        if not (-1.0 < self.mie_g < 1.0):
            raise ValueError(f"mie_g must be in (-1, 1) (got {self.mie_g!r})")
        if not (0.0 < self.sun_angular_radius_deg < 90.0):
            raise ValueError(f"sun_angular_radius_deg must be in (0, 90) (got {self.sun_angular_radius_deg!r})")

    @property
    def sun_direction(self) -> np.ndarray:
        """Unit vector towards the sun (azimuth 0: the +X side)."""
        e = math.radians(self.sun_elevation_deg)
        return np.array([math.cos(e), 0.0, math.sin(e)])

    def key(self) -> str:
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()


def load_atmosphere_scene(path) -> AtmosphereSpec:
    """Read a ``scenes/library/sky_*.toml`` file (format ``rtfit.sky/1``, see scenes/README.md)."""
    import tomllib

    path = Path(path)
    doc = tomllib.loads(path.read_text())
    if doc.get("format") != "rtfit.sky/1":
        raise ValueError(f"{path}: format: must be \"rtfit.sky/1\" (got {doc.get('format')!r})")
    allowed = set(AtmosphereSpec.__dataclass_fields__)
    extra = set(doc) - {"format", "name", "description", "atmosphere", "sun", "view"}
    if extra:
        raise ValueError(f"{path}: {sorted(extra)[0]}: unknown key")
    kw = {}
    for table in ("atmosphere", "sun", "view"):
        for k, v in doc.get(table, {}).items():
            if k not in allowed:
                raise ValueError(f"{path}: {table}.{k}: unknown key")
            kw[k] = tuple(float(x) for x in v) if isinstance(v, list) else float(v)
    return AtmosphereSpec(**kw)


def hemisphere_directions(width: int, height: int, el_lo_deg: float = 0.0, el_hi_deg: float = 90.0):
    """Pixel-centre directions of an azimuth × elevation image (sun at azimuth 0).

    Column i: azimuth φ = 2π(i + ½)/W measured from the sun's azimuth (+X) towards +Y; row j (top
    row first): elevation el_hi − (el_hi − el_lo)(j + ½)/H. Returns (dirs (H, W, 3), az (H, W),
    el (H, W)) in radians."""
    if width < 1 or height < 1:
        raise ValueError(f"width and height must be >= 1 (got {width}, {height})")
    az = 2.0 * math.pi * (np.arange(width) + 0.5) / width
    el = np.radians(el_hi_deg - (el_hi_deg - el_lo_deg) * (np.arange(height) + 0.5) / height)
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)
    return d, A, E


# ------------------------------------------------------------------------------------- plugins
_registered: set = set()


def register(mi) -> None:
    """Register ``rtfit_atmosphere`` (medium) and ``rtfit_rayleigh_mie`` (phase) for the active variant."""
    variant = mi.variant()
    if variant in _registered:
        return
    import drjit as dr

    from . import emitters

    emitters.register(mi)

    def _vec(props, name):
        v = props.get(name)
        return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))

    class _Profile:
        """Densities and coefficients shared by the medium and its phase function."""

        def __init__(self, props):
            self.rg = float(props.get("planet_radius"))
            self.hr = float(props.get("rayleigh_height"))
            self.hm = float(props.get("mie_height"))
            self.br = _vec(props, "rayleigh_beta")
            self.bm = _vec(props, "mie_beta")
            self.bme = _vec(props, "mie_extinction")
            self.g = float(props.get("g"))

        def rho(self, p):
            h = dr.maximum(dr.norm(p) - self.rg, 0.0)
            return dr.exp(-h / self.hr), dr.exp(-h / self.hm)

    class RayleighMiePhase(mi.PhaseFunction):
        def __init__(self, props):
            super().__init__(props)
            self.prof = _Profile(props)
            self.m_flags = mi.PhaseFunctionFlags.Anisotropic

        def _mix(self, mei):
            rr, rm = self.prof.rho(mei.p)
            sr = self.prof.br * rr
            sm = self.prof.bm * rm
            w = dr.sum(sm) / dr.maximum(dr.sum(sr) + dr.sum(sm), 1e-30)
            return sr, sm, w

        def _values(self, mei, wo):
            c = -dr.dot(wo, mei.wi)
            pr = (3.0 / (16.0 * dr.pi)) * (1.0 + c * c)
            g = self.prof.g
            pm = (1.0 - g * g) / (4.0 * dr.pi * dr.power(dr.maximum(1.0 + g * g - 2.0 * g * c, 1e-12), 1.5))
            return pr, pm

        def eval_pdf(self, ctx, mei, wo, active=True):
            sr, sm, w = self._mix(mei)
            pr, pm = self._values(mei, wo)
            value = (sr * pr + sm * pm) / dr.maximum(sr + sm, 1e-30)
            pdf = w * pm + (1.0 - w) * pr
            return value, pdf

        def sample(self, ctx, mei, s1, s2, active=True):
            sr, sm, w = self._mix(mei)
            g = self.prof.g
            # HG, cos θ about the forward direction −wi
            if abs(g) > 1e-4:
                q = (1.0 - g * g) / (1.0 - g + 2.0 * g * s2.x)
                c_hg = (1.0 + g * g - q * q) / (2.0 * g)
            else:
                c_hg = 1.0 - 2.0 * s2.x
            # Rayleigh: invert (3c + c³ + 4)/8 = u: c = A − 1/A, A = cbrt(z + √(z² + 1)), z = 4u − 2
            z = 4.0 * s2.x - 2.0
            a = dr.cbrt(z + dr.sqrt(z * z + 1.0))
            c_r = a - 1.0 / a
            c = dr.clip(dr.select(s1 < w, c_hg, c_r), -1.0, 1.0)
            sin_t = dr.sqrt(dr.maximum(1.0 - c * c, 0.0))
            phi = 2.0 * dr.pi * s2.y
            local = mi.Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi), c)
            wo = mi.Frame3f(-mei.wi).to_world(local)
            value, pdf = self.eval_pdf(ctx, mei, wo, active)
            return wo, value / dr.maximum(pdf, 1e-30), pdf

    class AtmosphereMedium(mi.Medium):
        def __init__(self, props):
            super().__init__(props)
            self.prof = _Profile(props)
            self.rt = float(props.get("top_radius"))
            self.majorant = mi.Color3f(dr.max(self.prof.br + self.prof.bme))  # density ≤ 1 above ground
            self.m_is_homogeneous = False
            self.m_has_spectral_extinction = True

        def get_majorant(self, mei, active=True):
            # Constant (the ground-level extinction). Mitsuba's sample_interaction calls this
            # before mei.p is set, so an altitude-adaptive bound cannot be used here.
            return mi.Spectrum(self.majorant)

        def get_scattering_coefficients(self, mei, active=True):
            rr, rm = self.prof.rho(mei.p)
            sigma_s = self.prof.br * rr + self.prof.bm * rm
            sigma_t = self.prof.br * rr + self.prof.bme * rm
            sigma_n = self.majorant - sigma_t
            return mi.Spectrum(sigma_s), mi.Spectrum(sigma_n), mi.Spectrum(sigma_t)

        def intersect_aabb(self, ray):
            r = self.rt
            return mi.BoundingBox3f(mi.ScalarPoint3f(-r, -r, -r), mi.ScalarPoint3f(r, r, r)).ray_intersect(ray)

    mi.register_phase(PHASE_PLUGIN, lambda props: RayleighMiePhase(props))
    mi.register_medium(MEDIUM_PLUGIN, lambda props: AtmosphereMedium(props))
    _registered.add(variant)


def _profile_props(spec: AtmosphereSpec, mi) -> dict:
    v = mi.ScalarVector3f
    return {"planet_radius": spec.planet_radius_km, "rayleigh_height": spec.rayleigh_height_km,
            "mie_height": spec.mie_height_km, "rayleigh_beta": v(*spec.rayleigh_beta),
            "mie_beta": v(*spec.mie_beta), "mie_extinction": v(*spec.mie_extinction), "g": spec.mie_g}


def scene_dict(mi, spec: AtmosphereSpec, max_depth: int) -> dict:
    """The Mitsuba scene (km units): planet, atmosphere shell with the medium, distant-disc sun."""
    from . import emitters

    register(mi)
    props = _profile_props(spec, mi)
    medium = {"type": MEDIUM_PLUGIN, "top_radius": spec.top_radius_km, **props,
              "phase": {"type": PHASE_PLUGIN, **props}}
    alpha = math.radians(spec.sun_angular_radius_deg)
    radiance = [e / (math.pi * math.sin(alpha) ** 2) for e in spec.solar_irradiance]
    return {
        "type": "scene",
        "integrator": {"type": "volpathmis", "max_depth": int(max_depth)},
        "planet": {"type": "sphere", "center": [0, 0, 0], "radius": spec.planet_radius_km,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [spec.ground_albedo] * 3}}},
        "atmosphere": {"type": "sphere", "center": [0, 0, 0], "radius": spec.top_radius_km,
                       "bsdf": {"type": "null"}, "interior": medium},
        "sun": {"type": emitters.PLUGIN, "direction": mi.ScalarVector3f(*spec.sun_direction.tolist()),
                "angular_radius": alpha, "radiance": mi.ScalarVector3f(*radiance),
                "sky": mi.ScalarVector3f(0.0, 0.0, 0.0)},
    }


def _load(mi, spec, max_depth):
    from . import emitters

    scene = mi.load_dict(scene_dict(mi, spec, max_depth))
    emitters.attach(scene)
    medium = None
    for shape in scene.shapes():
        if shape.interior_medium() is not None:
            medium = shape.interior_medium()
    return scene, medium


def sky_pass(mi, scene, medium, origin, dirs: np.ndarray, spp: int, seed: int) -> PassResult:
    """Radiance along rays from ``origin`` (km) in directions ``dirs`` (N, 3): one pass of ``spp``."""
    import drjit as dr

    t0 = time.perf_counter()
    d = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    n = d.shape[0]
    s = np.empty((n, 3))
    q = np.empty((n, 3))
    integrator = scene.integrator()
    sampler = mi.load_dict({"type": "independent"})
    dx, dy, dz = (mi.Float(d[:, k].astype(np.float32)) for k in range(3))
    for k, (a, b) in enumerate(_chunks(n, spp)):
        sampler.seed(sub_seed(seed, "sky", k), (b - a) * spp)
        idx = dr.arange(mi.UInt32, (b - a) * spp) // spp + a
        direction = mi.Vector3f(dr.gather(mi.Float, dx, idx), dr.gather(mi.Float, dy, idx),
                                dr.gather(mi.Float, dz, idx))
        ray = mi.Ray3f(mi.Point3f(*[float(x) for x in origin]), dr.normalize(direction))
        value, _, _ = integrator.sample(scene, sampler, ray, medium, True)
        s[a:b], q[a:b] = _moments(mi, dr, value, spp)
    mean, var = _mean_var(s, q, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def render_sky(spec: AtmosphereSpec, dirs: np.ndarray, spp: int, pass_spp: int, seed: int,
               variant: str, max_depth: int, cache_dir=None) -> dict:
    """Point-sampled radiance along ``dirs`` from the viewer, pooled over independent passes.

    Returns ``{"mean", "stderr"}`` (shape of ``dirs`` with last axis RGB, float64, W·m⁻²·sr⁻¹·nm⁻¹
    when E₀ is in W·m⁻²·nm⁻¹), ``spp``, ``passes``, ``seconds``, ``cache_key``. Passes are cached
    as .npz under ``cache_dir`` (one file per pass; a rerun renders only missing passes)."""
    from .variants import use_variant

    if spp < 2 or pass_spp < 2:
        raise ValueError(f"spp and pass_spp must be >= 2 (got {spp}, {pass_spp})")
    if not (variant.startswith("llvm_") or variant.startswith("cuda_")) or "spectral" in variant:
        raise ValueError(f"variant must be an llvm_*/cuda_* RGB variant for the atmosphere reference (got {variant!r})")
    shape = np.asarray(dirs).shape
    mi = use_variant(variant)
    h = hashlib.sha256()
    h.update(json.dumps({"f": _CACHE_FORMAT, "spec": asdict(spec), "depth": max_depth, "variant": variant,
                         "seed": seed, "pass_spp": pass_spp, "mi": mi.__version__}, sort_keys=True).encode())
    h.update(np.ascontiguousarray(dirs, dtype=np.float32).tobytes())
    key = h.hexdigest()
    folder = Path(cache_dir) / "atmosphere" / key[:2] / key if cache_dir else None
    passes = []
    n_pass = -(-spp // pass_spp)
    scene = medium = None
    origin = (0.0, 0.0, spec.planet_radius_km + spec.viewer_altitude_km)
    for p in range(n_pass):
        f = folder / f"pass{p:04d}.npz" if folder else None
        if f is not None and f.exists():
            z = np.load(f)
            passes.append(PassResult(z["mean"], z["var"], int(z["spp"]), p, float(z["seconds"])))
            continue
        if scene is None:
            scene, medium = _load(mi, spec, max_depth)
        r = sky_pass(mi, scene, medium, origin, dirs, pass_spp, sub_seed(seed, "pass", p))
        passes.append(r)
        if f is not None:
            import io

            buf = io.BytesIO()
            np.savez(buf, mean=r.mean, var=r.var, spp=r.spp, seconds=r.seconds)
            atomic_write_bytes(f, buf.getvalue())
    n = sum(p.spp for p in passes)
    mean = sum(p.mean * p.spp for p in passes) / n
    # pooled variance of the per-sample values (within + between passes), then stderr of the mean
    ss = sum((p.spp - 1) * p.var + p.spp * (p.mean - mean) ** 2 for p in passes)
    var = ss / max(n - 1, 1)
    stderr = np.sqrt(var / n)
    return {"mean": mean.reshape(shape), "stderr": stderr.reshape(shape), "spp": n, "passes": len(passes),
            "seconds": float(sum(p.seconds for p in passes)), "cache_key": key,
            "samples_per_second": float(n * mean.shape[0] / max(sum(p.seconds for p in passes), 1e-9))}


# ------------------------------------------------------------------------ independent quadrature
def _gl(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def _sun_optical_depth(p: np.ndarray, s: np.ndarray, spec: AtmosphereSpec, nodes: int = 64):
    """(τ_R, τ_M) density integrals (km) from points p (N, 3) to the top along s; inf if the
    planet blocks. Gauss–Legendre on the arc length split at 8 geometric sub-intervals."""
    rg, rt = spec.planet_radius_km, spec.top_radius_km
    b = p @ s
    c_top = np.einsum("ij,ij->i", p, p) - rt * rt
    t_top = -b + np.sqrt(np.maximum(b * b - c_top, 0.0))
    # planet blocks if the ray towards the sun meets the ground sphere ahead
    c_g = np.einsum("ij,ij->i", p, p) - rg * rg
    disc = b * b - c_g
    blocked = (disc > 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0)
    x, w = _gl(nodes)
    # split [0, t_top] geometrically (density falls fast): edges t_top·(0, 1/128, …, 1/2, 1)
    edges = np.concatenate([[0.0], 2.0 ** np.arange(-7, 1)])
    tr = np.zeros(p.shape[0])
    tm = np.zeros(p.shape[0])
    for a0, a1 in zip(edges[:-1], edges[1:]):
        ta, tb = a0 * t_top, a1 * t_top
        t = 0.5 * (ta + tb)[:, None] + 0.5 * (tb - ta)[:, None] * x[None, :]
        q = p[:, None, :] + t[..., None] * s[None, None, :]
        h = np.linalg.norm(q, axis=-1) - rg
        jw = 0.5 * (tb - ta)[:, None] * w[None, :]
        tr += np.sum(jw * np.exp(-h / spec.rayleigh_height_km), axis=1)
        tm += np.sum(jw * np.exp(-np.maximum(h, 0) / spec.mie_height_km), axis=1)
    tr[blocked] = np.inf
    tm[blocked] = np.inf
    return tr, tm


def single_scattering_quadrature(spec: AtmosphereSpec, dirs: np.ndarray, steps: int = 2000,
                                 point_sun: bool = True) -> np.ndarray:
    """Single-scattered sky radiance along ``dirs`` (…, 3) by direct float64 quadrature.

    L = E₀ ∫₀^{t_max} Σ_{k∈{R,M}} β_k ρ_k(x) P_k(cos γ) T(o→x) T_sun(x) dt, with t_max the exit
    through the top or the ground hit; trapezoid on a grid in u = t/t_max squared-spaced near the
    viewer (u = v², ``steps`` points) plus exact cumulative view transmittance by the same rule;
    T_sun by `_sun_optical_depth`. The sun is a point (its 0.27° size changes the phase-weighted
    sum by < 1e-4 outside the aureole). Ground-reflected light is not included (it needs two
    scattering events for a sky pixel)."""
    d = np.asarray(dirs, dtype=np.float64)
    shape = d.shape
    d = d.reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    rg, rt = spec.planet_radius_km, spec.top_radius_km
    o = np.array([0.0, 0.0, rg + spec.viewer_altitude_km])
    s = spec.sun_direction
    b = d @ o
    cc = o @ o
    t_top = -b + np.sqrt(np.maximum(b * b - (cc - rt * rt), 0.0))
    disc = b * b - (cc - rg * rg)
    hit = (disc > 0) & (b < 0)
    t_g = -b - np.sqrt(np.maximum(disc, 0.0))
    t_max = np.where(hit, t_g, t_top)
    br, bm, bme = (np.asarray(v, dtype=np.float64) for v in (spec.rayleigh_beta, spec.mie_beta, spec.mie_extinction))
    g = spec.mie_g
    cos_g = d @ s
    pr = 3.0 / (16.0 * math.pi) * (1.0 + cos_g ** 2)
    pm = (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_g) ** 1.5)
    u = np.linspace(0.0, 1.0, steps) ** 2
    out = np.zeros((d.shape[0], 3))
    for i in range(d.shape[0]):
        t = u * t_max[i]
        x = o[None, :] + t[:, None] * d[i][None, :]
        h = np.maximum(np.linalg.norm(x, axis=1) - rg, 0.0)
        rr, rm = np.exp(-h / spec.rayleigh_height_km), np.exp(-h / spec.mie_height_km)
        dt = np.diff(t)
        odr = np.concatenate([[0.0], np.cumsum(0.5 * (rr[1:] + rr[:-1]) * dt)])
        odm = np.concatenate([[0.0], np.cumsum(0.5 * (rm[1:] + rm[:-1]) * dt)])
        sr, sm = _sun_optical_depth(x, s, spec)
        tau = (odr + sr)[:, None] * br[None, :] + (odm + sm)[:, None] * bme[None, :]
        f = (br[None, :] * rr[:, None] * pr[i] + bm[None, :] * rm[:, None] * pm[i]) * np.exp(-tau)
        out[i] = np.sum(0.5 * (f[1:] + f[:-1]) * dt[:, None], axis=0)
    out *= np.asarray(spec.solar_irradiance)[None, :]
    return out.reshape(shape)


# ------------------------------------------------------------------------------------ sunsky
def sunsky_radiance(sun_elevation_deg: float, dirs: np.ndarray, variant: str = "llvm_ad_rgb",
                    turbidity: float = 3.0, albedo: float = 0.1) -> dict:
    """Mitsuba's Hosek–Wilkie ``sunsky``: sky radiance along ``dirs`` (sun excluded) and the sun's
    irradiance at normal incidence (disc radiance at its centre × its solid angle), in sunsky's
    own units (facts note §6: W·m⁻²·sr⁻¹·nm⁻¹ in RGB). Only for sun elevation > 0."""
    from .variants import use_variant

    if not (0.0 < sun_elevation_deg <= 90.0):
        raise ValueError(f"sunsky needs sun_elevation_deg in (0, 90] (got {sun_elevation_deg!r})")
    import drjit as dr

    mi = use_variant(variant)
    e = math.radians(sun_elevation_deg)
    sd = [math.cos(e), 0.0, math.sin(e)]
    aperture = 0.5358

    def emitter(sun_scale, sky_scale):
        sc = mi.load_dict({"type": "scene", "sky": {"type": "sunsky", "sun_direction": sd, "turbidity": turbidity,
                                                     "albedo": albedo, "sun_scale": sun_scale,
                                                     "sky_scale": sky_scale, "sun_aperture": aperture}})
        return sc.environment()

    def evaluate(em, d):
        d = np.ascontiguousarray(d, dtype=np.float32).reshape(-1, 3)
        si = dr.zeros(mi.SurfaceInteraction3f, d.shape[0])
        si.wi = -mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])
        value = em.eval(si)
        return np.stack([np.asarray(value[c], dtype=np.float64) for c in range(3)], axis=-1)

    sky = evaluate(emitter(0.0, 1.0), dirs).reshape(np.asarray(dirs).shape)
    sun_l = evaluate(emitter(1.0, 0.0), np.array([sd]))[0]
    omega = 2.0 * math.pi * (1.0 - math.cos(math.radians(aperture / 2.0)))
    return {"sky": sky, "sun_irradiance": sun_l * omega, "turbidity": turbidity, "albedo": albedo}
