r"""Mitsuba ground truth for a planet's sky: a spherical-shell Rayleigh + Mie atmosphere.

Parameters (`AtmosphereSpec`) are SI — metres, m⁻¹, radians — with the field names of the real-time
`rtfit.realtime.nishita_sky.AtmosphereParams`, read from the scene files ``scenes/library/sky_*.toml``
(`load_atmosphere_scene`). The Mitsuba scene is built in kilometres, from values derived from the spec
(its ``*_km`` properties):

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

Integrator (RGB variants, since session 7): ``rtfit_skypath`` (`rtfit.reference.sky_integrator`: the scene
without the shell sphere and medium plugin, the atmosphere in the integrator: closed-form free flight under
tangent-exponential majorants, spectral MIS over the channels, ratio-tracked sun transmittance); spectral
variants and the benches' "segment"/"box" rows: ``volpathmis`` (unbiased with chromatic extinction) with the
medium below. ``max_depth = 2`` gives single
scattering (camera segment, one scattering event, next-event estimation to the sun), ``-1`` all
orders including the ground bounce.

**Spectral variants** (``llvm_ad_spectral``, ``cuda_ad_spectral``): the same scene over wavelength.
Each path carries the 4 wavelengths Mitsuba sampled (``mei.wavelengths``, nm); the medium and the
phase evaluate, at those wavelengths,

    β_R(λ) = β_R(550)·(550/λ)⁴,   β_M(λ) = β_M(550),   β_M^ext(λ) = β_M^ext(550)

with the 550 nm values the spec's second (G) channel, and the sun's disc radiance is
E₀(λ)/(π sin²α) with E₀ = `solar_spectrum` (a 5778 K blackbody normalised to E₀(550) = the spec's
second solar-irradiance channel: the real-time spectral variant's default, re-derived here), given
to the emitter as a ``regular`` spectrum on 360–830 nm in 1 nm steps. The majorant is grey per path:
max over its 4 wavelengths of β_R(λ) + β_M^ext (the ground-level extinction). Wavelengths are
sampled and converted exactly as Mitsuba's sensor and RGB film do (`sky_pass`): 4 stratified
wavelengths from ``sample_rgb_spectrum`` (importance density ∝ sech²(0.0072(λ − 538)) on
[360, 830] nm, weight 1/pdf), then per path

    XYZ = mean_j x̄(λ_j) L(λ_j)/pdf(λ_j) / 106.7502594,   linear sRGB = M_709 · XYZ,

x̄, ȳ, z̄ Mitsuba's CIE 1931 2° table (5 nm knots, linear interpolation, `cie1931_table`) and M_709
its ``xyz_to_srgb`` matrix (`film_xyz_to_srgb`), both read from the installed Mitsuba. The
expectation is `film_srgb`: M_709 ∫₃₆₀⁸³⁰ (x̄, ȳ, z̄)(λ) L(λ) dλ / 106.7502594 (a flat L = 1 gives
Y = 1.001: Mitsuba's normalisation constant is not quite ∫ȳ = 106.857 of its own table). Measured
against an hdrfilm render of a ``constant`` emitter (flat and 5778 K blackbody spectra): equal within
the render's noise (tests). No white balance: a spectrum maps to the sRGB of its CIE coordinates.

Also here, for the cross-checks of the experiment:

* `single_scattering_quadrature`: an independent float64 quadrature of the single-scattering
  integral (fine trapezoid along the view ray in NumPy, sun optical depth by Gauss–Legendre along
  each sun ray in a float64 Dr.Jit kernel, planet shadow by exact ray–sphere test), to check the
  Mitsuba single-scattering reference and the real-time sky;
* `spectral_single_scattering_quadrature`: the same quadrature per wavelength (1 nm grid on
  360–830 nm by default) with the spectral coefficients above, converted by `film_srgb`: the check
  of the spectral Mitsuba reference;
* `sunsky_radiance`: Mitsuba's Hosek–Wilkie ``sunsky`` evaluated along directions.

This module does not import ``rtfit.realtime`` (layering): parameters are plain numbers.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.scenes import library_path

from . import emitters, sky_integrator
from .budget import ABSORB, ArmedMedia, LaneCounter, check_finite, counters
from .cache import ComputedEntry, PassEntry, array_digest, pool_passes
from .device_arrays import mapped_floats
from .estimators import PassResult, chunk_ranges, mean_var, moments, sub_seed
from .variants import callers_variant, cuda_available, use_variant

__all__ = [
    "DEFAULT_SCENE",
    "MEDIUM_PLUGIN",
    "PHASE_PLUGIN",
    "SPECTRAL_VARIANTS",
    "AtmosphereSpec",
    "cie1931_table",
    "film_srgb",
    "film_xyz_to_srgb",
    "grid_medium_dict",
    "hemisphere_directions",
    "library_atmosphere",
    "load_atmosphere_scene",
    "load_sky",
    "reference_integrator",
    "register",
    "render_sky",
    "scene_dict",
    "single_scattering_quadrature",
    "sky_pass",
    "solar_spectrum",
    "spectral_coefficients",
    "spectral_single_scattering_quadrature",
    "sunsky_radiance",
]

MEDIUM_PLUGIN = "rtfit_atmosphere"
PHASE_PLUGIN = "rtfit_rayleigh_mie"
_CACHE_FORMAT = 3  # 2: passes in PassEntry (namespace "sky"), SI spec; 3: per-segment majorant (issue 21)
SEGMENT_ESTIMATOR = "rtfit_atmosphere/3: volpathmis, per-segment majorant, medium-event cap"
"""The identity of the spectral variants' estimator (`scene_dict` ``"segment"``): part of the cache key."""
SCENE_MEDIA = ("skypath", "segment", "box", "grid", "none")
"""The atmospheres `scene_dict` builds (its docstring)."""
SEGMENT_MARGIN = 2.0**-18
"""δ of the segment majorant per km of coordinate magnitude (`register`'s medium)."""
SPECTRAL_VARIANTS = ("llvm_ad_spectral", "cuda_ad_spectral")
SOLAR_TEMPERATURE_K = 5778.0
"""Blackbody temperature of the spectral sun (the real-time spectral variant's default)."""
REFERENCE_WAVELENGTH_NM = 550.0
"""The wavelength of the spec's second (G) channel: the anchor of the spectral coefficients."""
CIE_MIN_NM, CIE_MAX_NM = 360.0, 830.0
CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625
"""Mitsuba's ``MI_CIE_Y_NORMALIZATION`` (checked against the installed Mitsuba in the tests)."""


@dataclass(frozen=True)
class AtmosphereSpec:
    """A sky to render, in SI units: lengths in metres, coefficients in m⁻¹ per RGB channel, the sun's
    angular radius in radians, its elevation in degrees, solar irradiance in W·m⁻²·nm⁻¹.

    The field names and units are those of `rtfit.realtime.nishita_sky.AtmosphereParams` (the real-time
    model's parameters), and the values come from a scene file (`load_atmosphere_scene`,
    ``scenes/library/sky_*.toml``): this class has no numeric defaults of its own, so the atmosphere's
    constants live in the scene files (checked against the real-time defaults in the tests). The Mitsuba
    scene and the quadrature work in kilometres: the ``*_km`` properties derive those values.
    """

    sun_elevation_deg: float
    viewer_altitude_m: float
    planet_radius_m: float
    top_radius_m: float
    rayleigh_beta: tuple
    rayleigh_height_m: float
    mie_beta: tuple
    mie_extinction: tuple
    mie_height_m: float
    mie_g: float
    ground_albedo: float
    sun_angular_radius: float
    solar_irradiance: tuple

    def __post_init__(self):
        if not (-90.0 <= self.sun_elevation_deg <= 90.0):
            raise ValueError(f"sun_elevation_deg must be in [-90, 90] (got {self.sun_elevation_deg!r})")
        if not (0.0 < self.planet_radius_m < self.top_radius_m):
            raise ValueError("need 0 < planet_radius_m < top_radius_m")
        if not (0.0 <= self.viewer_altitude_m < self.top_radius_m - self.planet_radius_m):
            raise ValueError(
                f"viewer_altitude_m must be in [0, top - planet) (got {self.viewer_altitude_m!r})"
            )
        if not (-1.0 < self.mie_g < 1.0):
            raise ValueError(f"mie_g must be in (-1, 1) (got {self.mie_g!r})")
        if not (0.0 < self.sun_angular_radius < 0.5 * math.pi):
            raise ValueError(f"sun_angular_radius must be in (0, π/2) rad (got {self.sun_angular_radius!r})")
        for name in ("rayleigh_beta", "mie_beta", "mie_extinction", "solar_irradiance"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"{name} must have 3 channels (got {len(getattr(self, name))})")

    # kilometres (km⁻¹) for the Mitsuba scene and the quadrature: float32 values are those of the
    # former km constants (a km scene keeps the planet's radius and the heights at the same magnitude)
    @property
    def planet_radius_km(self) -> float:
        return self.planet_radius_m / _M_PER_KM

    @property
    def top_radius_km(self) -> float:
        return self.top_radius_m / _M_PER_KM

    @property
    def viewer_altitude_km(self) -> float:
        return self.viewer_altitude_m / _M_PER_KM

    @property
    def rayleigh_height_km(self) -> float:
        return self.rayleigh_height_m / _M_PER_KM

    @property
    def mie_height_km(self) -> float:
        return self.mie_height_m / _M_PER_KM

    @property
    def rayleigh_beta_km(self) -> tuple:
        """β_R in km⁻¹."""
        return tuple(b * _M_PER_KM for b in self.rayleigh_beta)

    @property
    def mie_beta_km(self) -> tuple:
        return tuple(b * _M_PER_KM for b in self.mie_beta)

    @property
    def mie_extinction_km(self) -> tuple:
        return tuple(b * _M_PER_KM for b in self.mie_extinction)

    @property
    def sun_direction(self) -> np.ndarray:
        """Unit vector towards the sun (azimuth 0: the +X side)."""
        e = math.radians(self.sun_elevation_deg)
        return np.array([math.cos(e), 0.0, math.sin(e)])

    def key(self) -> str:
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()


_M_PER_KM = 1000.0
_SCENE_TABLES = ("atmosphere", "sun", "view")
DEFAULT_SCENE = "sky_sun_45"
"""The library scene whose atmosphere `library_atmosphere` reads by default."""


def load_atmosphere_scene(path, **overrides) -> AtmosphereSpec:
    """Read a ``scenes/library/sky_*.toml`` file (format ``rtfit.sky/1``, SI units, see scenes/README.md);
    ``overrides`` replace fields (e.g. ``sun_elevation_deg``). Unknown keys are one-line errors."""
    path = Path(path)
    doc = tomllib.loads(path.read_text())
    if doc.get("format") != "rtfit.sky/1":
        raise ValueError(f'{path}: format: must be "rtfit.sky/1" (got {doc.get("format")!r})')
    allowed = set(AtmosphereSpec.__dataclass_fields__)
    extra = set(doc) - {"format", "name", "description", *_SCENE_TABLES}
    if extra:
        raise ValueError(f"{path}: {sorted(extra)[0]}: unknown key")
    kw = {}
    for table in _SCENE_TABLES:
        for k, v in doc.get(table, {}).items():
            if k not in allowed:
                raise ValueError(f"{path}: {table}.{k}: unknown key")
            kw[k] = tuple(float(x) for x in v) if isinstance(v, list) else float(v)
    missing = sorted(allowed - set(kw) - set(overrides))
    if missing:
        raise ValueError(f"{path}: {missing[0]}: missing key")
    return AtmosphereSpec(**{**kw, **overrides})


def library_atmosphere(name: str = DEFAULT_SCENE, **overrides) -> AtmosphereSpec:
    """`load_atmosphere_scene` of the shipped scene ``name`` (`rtfit.scenes.library_path`)."""
    return load_atmosphere_scene(library_path(name), **overrides)


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
    emitters.register(mi)

    def _vec(props, name):
        v = props.get(name)
        return mi.Color3f(float(v[0]), float(v[1]), float(v[2]))

    spectral = bool(mi.is_spectral)

    class _Profile:
        """Densities and coefficients shared by the medium and its phase function. RGB variants:
        constant Color3f β per channel; spectral variants: β at the path's wavelengths (`coeffs`)."""

        def __init__(self, props):
            self.rg = float(props.get("planet_radius"))
            self.hr = float(props.get("rayleigh_height"))
            self.hm = float(props.get("mie_height"))
            self.br = _vec(props, "rayleigh_beta")
            self.bm = _vec(props, "mie_beta")
            self.bme = _vec(props, "mie_extinction")
            self.g = float(props.get("g"))
            if spectral:  # 550 nm anchors: the G channel (see the module docstring)
                self.br550 = float(props.get("rayleigh_beta")[1])
                self.bm550 = float(props.get("mie_beta")[1])
                self.bme550 = float(props.get("mie_extinction")[1])

        def rho(self, p):
            h = dr.maximum(dr.norm(p) - self.rg, 0.0)
            return dr.exp(-h / self.hr), dr.exp(-h / self.hm)

        def coeffs(self, mei):
            """(β_R, β_M, β_M^ext) per channel (RGB) or at mei.wavelengths (spectral), km⁻¹."""
            if not spectral:
                return self.br, self.bm, self.bme
            x = REFERENCE_WAVELENGTH_NM / mei.wavelengths
            x2 = x * x
            return self.br550 * (x2 * x2), mi.Spectrum(self.bm550), mi.Spectrum(self.bme550)

    class RayleighMiePhase(mi.PhaseFunction):
        def __init__(self, props):
            super().__init__(props)
            self.prof = _Profile(props)
            self.m_flags = mi.PhaseFunctionFlags.Anisotropic

        def _mix(self, mei):
            rr, rm = self.prof.rho(mei.p)
            br, bm, _ = self.prof.coeffs(mei)
            sr = br * rr
            sm = bm * rm
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
            _sr, _sm, w = self._mix(mei)
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
            # False: the ground-level majorant for every segment (the estimator before issue 21; benches)
            self.segment_majorant = bool(props.get("segment_majorant", True))
            self.lane_counter = LaneCounter()
            self._pending = None

        def _segment_densities(self, ray, mint, maxt):
            """(ρ_R, ρ_M) bounds on [t₀, t₁] = [max(mint, 0), min(maxt, ray.maxt)]: the densities at the
            lowest point of the segment (the point nearest the planet centre: t* = −o·d/|d|² clamped to
            the segment), lowered by δ = 2⁻¹⁸·(|o| + t₁ − t₀) km against float32 rounding."""
            t0 = dr.maximum(mint, 0.0)
            t1 = dr.maximum(dr.minimum(maxt, ray.maxt), t0)
            t1 = dr.select(dr.isfinite(t1), t1, t0)
            o, d = mi.Vector3f(ray.o), mi.Vector3f(ray.d)
            t_star = dr.clip(-dr.dot(o, d) / dr.maximum(dr.squared_norm(d), 1e-30), t0, t1)
            r_low = dr.norm(o + t_star * d)
            delta = SEGMENT_MARGIN * (1.0 + dr.norm(o) + (t1 - t0) * dr.norm(d))
            h = dr.maximum(r_low - delta - self.prof.rg, 0.0)
            return dr.exp(-h / self.prof.hr), dr.exp(-h / self.prof.hm)

        def _segment(self):
            pending = self.__dict__.get("_pending")
            return pending if pending is not None else (None, False)

        def _spectral_majorant(self, mei):
            # grey per path: the largest ground-level extinction over its 4 wavelengths
            br, _, bme = self.prof.coeffs(mei)
            return mi.Spectrum(dr.max(br + bme))

        def _majorant(self, mei):
            """Grey majorant of this sample_interaction's segment (module docstring): the largest
            channel (RGB) or sampled wavelength (spectral) of β_R ρ_R + β_M^ext ρ_M at the segment's
            lowest point; the ground-level extinction when no segment is pending; `ABSORB` for a lane
            past its event cap."""
            rho, absorb = self._segment()
            if rho is None:
                m = self._spectral_majorant(mei) if spectral else mi.Spectrum(self.majorant)
            else:
                br, _, bme = self.prof.coeffs(mei)
                m = mi.Spectrum(dr.max(br * rho[0] + bme * rho[1]))
            return dr.select(absorb, ABSORB, m), absorb

        def get_majorant(self, mei, active=True):
            # Mitsuba's sample_interaction calls this before mei.p is set; intersect_aabb, called just
            # before with the ray, left the segment's density bounds (mei.wavelengths are set).
            return self._majorant(mei)[0]

        def get_scattering_coefficients(self, mei, active=True):
            majorant, absorb = self._majorant(mei)
            self._pending = None  # the last call of this sample_interaction
            rr, rm = self.prof.rho(mei.p)
            br, bm, bme = self.prof.coeffs(mei)
            sigma_s = mi.Spectrum(br * rr + bm * rm)
            sigma_t = dr.minimum(mi.Spectrum(br * rr + bme * rm), majorant)
            sigma_s = dr.select(absorb, 0.0, sigma_s)
            sigma_t = dr.select(absorb, majorant, sigma_t)
            return sigma_s, majorant - sigma_t, sigma_t

        def intersect_aabb(self, ray):
            # The slab test of Mitsuba's BoundingBox3f.ray_intersect on [−R_t, R_t]³, written out:
            # BoundingBox3f is one Python type for the RGB and spectral variants but its
            # ray_intersect accepts only the Ray3f of the variant that bound it first, so the
            # bound method fails once both variants were used in one process.
            r = self.rt
            d_rcp = dr.rcp(ray.d)
            ok = mi.Bool(True)
            t1p, t2p = [], []
            for k in range(3):
                o, d = ray.o[k], ray.d[k]
                ok &= (d != 0.0) | ((o > -r) & (o < r))
                t1 = (-r - o) * d_rcp[k]
                t2 = (r - o) * d_rcp[k]
                t1p.append(dr.minimum(t1, t2))
                t2p.append(dr.maximum(t1, t2))
            mint = dr.maximum(dr.maximum(t1p[0], t1p[1]), t1p[2])
            maxt = dr.minimum(dr.minimum(t2p[0], t2p[1]), t2p[2])
            hit = ok & (maxt >= mint)
            absorb = self.lane_counter.tick(ray.time)
            rho = None
            if self.segment_majorant:
                rr, rm = self._segment_densities(ray, mint, maxt)
                rho = (dr.select(hit, rr, 1.0), dr.select(hit, rm, 1.0))
            self._pending = (rho, absorb) if (rho is not None or absorb is not False) else None
            return hit, mint, maxt

    mi.register_phase(PHASE_PLUGIN, lambda props: RayleighMiePhase(props))
    mi.register_medium(MEDIUM_PLUGIN, lambda props: AtmosphereMedium(props))
    _registered.add(variant)


def _profile_props(spec: AtmosphereSpec, mi) -> dict:
    v = mi.ScalarVector3f
    return {
        "planet_radius": spec.planet_radius_km,
        "rayleigh_height": spec.rayleigh_height_km,
        "mie_height": spec.mie_height_km,
        "rayleigh_beta": v(*spec.rayleigh_beta_km),
        "mie_beta": v(*spec.mie_beta_km),
        "mie_extinction": v(*spec.mie_extinction_km),
        "g": spec.mie_g,
    }


def scene_dict(mi, spec: AtmosphereSpec, max_depth: int, medium: str = "segment") -> dict:
    """The Mitsuba scene (km units): planet, atmosphere shell with the medium, distant-disc sun.

    ``medium``: ``"skypath"`` (planet and sun only, the atmosphere in rtfit's integrator
    `rtfit.reference.sky_integrator`: the reference of the RGB variants since session 7),
    ``"segment"`` (rtfit's medium with the per-segment majorant under ``volpathmis``: session 4's
    reference, still the spectral variants' reference), ``"box"`` (the same medium with the ground-level
    majorant for every segment: the estimator before issue 21), ``"grid"`` (Mitsuba's native
    ``heterogeneous`` medium on a ``gridvolume`` of the extinction over the shell's bounding cube,
    `grid_medium_dict`: what a user would otherwise render; for benches, not a reference) or ``"none"``
    (Mitsuba's ``path`` on planet and sun without any atmosphere: the floor of the benches)."""
    register(mi)
    props = _profile_props(spec, mi)
    if medium not in SCENE_MEDIA:
        raise ValueError(f"medium must be one of {', '.join(SCENE_MEDIA)} (got {medium!r})")
    medium_d = {
        "type": MEDIUM_PLUGIN,
        "top_radius": spec.top_radius_km,
        **props,
        "segment_majorant": medium == "segment",
        "phase": {"type": PHASE_PLUGIN, **props},
    }
    if medium == "grid":
        medium_d = grid_medium_dict(mi, spec)
    alpha = spec.sun_angular_radius
    radiance = [e / (math.pi * math.sin(alpha) ** 2) for e in spec.solar_irradiance]
    d = {
        "type": "scene",
        "integrator": {"type": "volpathmis", "max_depth": int(max_depth)},
        "planet": {
            "type": "sphere",
            "center": [0, 0, 0],
            "radius": spec.planet_radius_km,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [spec.ground_albedo] * 3}},
        },
        "atmosphere": {
            "type": "sphere",
            "center": [0, 0, 0],
            "radius": spec.top_radius_km,
            "bsdf": {"type": "null"},
            "interior": medium_d,
        },
        "sun": {
            "type": emitters.PLUGIN,
            "direction": mi.ScalarVector3f(*spec.sun_direction.tolist()),
            "angular_radius": alpha,
            "radiance": mi.ScalarVector3f(*radiance),
            "sky": mi.ScalarVector3f(0.0, 0.0, 0.0),
        },
    }
    if medium == "skypath":
        sky_integrator.register(mi)
        d["integrator"] = sky_integrator.integrator_dict(
            props, spec.top_radius_km, max_depth, {"type": PHASE_PLUGIN, **props}, nee_only=True
        )  # the sun's sky radiance is 0 (below): NEE samples all of the emitter
    if medium in ("skypath", "none"):
        del d["atmosphere"]
    if medium == "none":
        d["integrator"] = {"type": "path", "max_depth": int(max_depth)}
    if mi.is_spectral:
        # grey ground; the sun's disc radiance E₀(λ)/(π sin²α) on a 1 nm grid over Mitsuba's range
        d["planet"]["bsdf"]["reflectance"] = {"type": "uniform", "value": float(spec.ground_albedo)}
        lam = np.arange(CIE_MIN_NM, CIE_MAX_NM + 0.5, 1.0)
        disc = solar_spectrum(lam, spec.solar_irradiance[1]) / (math.pi * math.sin(alpha) ** 2)
        d["sun"]["radiance_spectrum"] = {
            "type": "regular",
            "wavelength_min": float(lam[0]),
            "wavelength_max": float(lam[-1]),
            "values": ", ".join(f"{v:.9g}" for v in disc),
        }
    return d


def grid_medium_dict(mi, spec: AtmosphereSpec, resolution: int = 256) -> dict:
    """Mitsuba's ``heterogeneous`` medium with ``gridvolume``s of the atmosphere's extinction and albedo
    (RGB, km⁻¹) at the voxel centres of a ``resolution``³ grid over the cube [−R_t, R_t]³, trilinear,
    HG phase with the Mie g: a bench stand-in for "the same density on a grid" (a 50 km voxel cannot
    resolve an 8 km scale height: not a reference). Its majorant is the grid's maximum, as Mitsuba
    computes it, over the whole cube."""
    rt = spec.top_radius_km
    axis = ((np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0) * rt
    z, y, x = np.meshgrid(axis, axis, axis, indexing="ij")
    h = np.maximum(np.sqrt(x * x + y * y + z * z) - spec.planet_radius_km, 0.0)
    rr, rm = np.exp(-h / spec.rayleigh_height_km)[..., None], np.exp(-h / spec.mie_height_km)[..., None]
    br, bm, bme = (np.asarray(v) for v in (spec.rayleigh_beta_km, spec.mie_beta_km, spec.mie_extinction_km))
    sigma_t = br * rr + bme * rm
    albedo = np.where(sigma_t > 0, (br * rr + bm * rm) / np.maximum(sigma_t, 1e-30), 0.0)
    to_world = mi.ScalarTransform4f().translate([-rt, -rt, -rt]).scale(2.0 * rt)
    return {
        "type": "heterogeneous",
        "sigma_t": {
            "type": "gridvolume",
            "grid": mi.VolumeGrid(sigma_t.astype(np.float32)),
            "to_world": to_world,
        },
        "albedo": {
            "type": "gridvolume",
            "grid": mi.VolumeGrid(albedo.astype(np.float32)),
            "to_world": to_world,
        },
        "scale": 1.0,
        "phase": {"type": "hg", "g": spec.mie_g},
    }


def reference_medium(mi) -> str:
    """The `scene_dict` medium of the reference in the active variant: ``"skypath"`` (RGB) or
    ``"segment"`` (spectral: `rtfit.reference.sky_integrator` is RGB only)."""
    return "segment" if mi.is_spectral else "skypath"


def reference_integrator(variant: str) -> str:
    """The Mitsuba integrator of `render_sky` in ``variant``: ``rtfit_skypath`` (RGB variants) or
    ``volpathmis`` (spectral variants, rtfit's medium with the per-segment majorant)."""
    return "volpathmis" if "spectral" in variant else sky_integrator.PLUGIN


def load_sky(mi, spec, max_depth, medium: str | None = None):
    """The loaded Mitsuba scene of `scene_dict` (``mi``: variant set; ``medium`` None: the reference's,
    `reference_medium`) and its atmosphere medium (None without a medium plugin)."""
    medium = reference_medium(mi) if medium is None else medium
    scene = mi.load_dict(scene_dict(mi, spec, max_depth, medium))
    emitters.attach(scene)
    medium = None
    for shape in scene.shapes():
        if shape.interior_medium() is not None:
            medium = shape.interior_medium()
    return scene, medium


def sky_pass(mi, scene, medium, origin, dirs: np.ndarray, spp: int, seed: int, events=None) -> PassResult:
    """Radiance along rays from ``origin`` (km) in directions ``dirs`` (N, 3): one pass of ``spp``.

    ``events``: a list to which each launch appends its `LaneCounter.means` (events per lane at each
    counted call site of each counter, zero sites dropped: Dr.Jit traces a loop more than once) — the
    work per sample the benches report."""
    t0 = time.perf_counter()
    d = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    n = d.shape[0]
    s = np.empty((n, 3))
    q = np.empty((n, 3))
    integrator = scene.integrator()
    sampler = mi.load_dict({"type": "independent"})
    dx, dy, dz = (mapped_floats(mi.Float, d[:, k]) for k in range(3))
    media = counters(scene)
    for k, (a, b) in enumerate(chunk_ranges(n, spp)):
        sampler.seed(sub_seed(seed, "sky", k), (b - a) * spp)
        idx = dr.arange(mi.UInt32, (b - a) * spp) // spp + a
        direction = mi.Vector3f(
            dr.gather(mi.Float, dx, idx), dr.gather(mi.Float, dy, idx), dr.gather(mi.Float, dz, idx)
        )
        # the lane index rides in ray.time for the medium's event cap (rtfit.reference.budget)
        lanes = mi.Float(dr.arange(mi.UInt32, (b - a) * spp))
        with ArmedMedia(media, mi.UInt32, (b - a) * spp) as armed:
            if mi.is_spectral:
                value = _spectral_sample(
                    mi, dr, scene, sampler, integrator, medium, origin, dr.normalize(direction), lanes
                )
            else:
                ray = mi.Ray3f(mi.Point3f(*[float(x) for x in origin]), dr.normalize(direction))
                ray.time = lanes
                value, _, _ = integrator.sample(scene, sampler, ray, medium, True)
            s[a:b], q[a:b] = moments(mi, dr, value, spp)
            armed.check()
            if events is not None:
                events.append([[m for m in c.means() if m > 0.0] for c in media])
    mean, var = mean_var(s, q, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def _spectral_sample(mi, dr, scene, sampler, integrator, medium, origin, direction, time=0.0):
    """One spectral sample per lane, as Mitsuba's sensor + RGB film do it: 4 stratified
    wavelengths u_j = (u + j/4) mod 1 through ``sample_rgb_spectrum`` (weight 1/pdf), the
    integrator's radiance at those wavelengths, then ``spectrum_to_xyz`` (mean over the 4 of
    x̄ L/pdf, Mitsuba's CIE normalisation) and ``xyz_to_srgb``: linear sRGB per lane."""
    u = sampler.next_1d()
    lams, weights = [], []
    for j in range(4):
        uj = u + 0.25 * j
        uj = dr.select(uj >= 1.0, uj - 1.0, uj)
        lam, w = mi.sample_rgb_spectrum(uj)
        lams.append(lam)
        weights.append(w)
    wavelengths = mi.Spectrum(*lams)
    ray = mi.Ray3f(mi.Point3f(*[float(x) for x in origin]), direction, time, wavelengths)
    value, _, _ = integrator.sample(scene, sampler, ray, medium, True)
    return mi.xyz_to_srgb(mi.spectrum_to_xyz(value * mi.Spectrum(*weights), wavelengths))


def _use_variant(variant: str):
    """Activate an RGB variant through `rtfit.reference.variants`, or a spectral one
    (``llvm_ad_spectral``, ``cuda_ad_spectral``) here (one-line ValueError otherwise)."""
    if "spectral" not in variant:
        return use_variant(variant)
    if variant not in SPECTRAL_VARIANTS:
        raise ValueError(f"spectral variant must be one of {', '.join(SPECTRAL_VARIANTS)} (got {variant!r})")
    if variant.startswith("cuda") and not cuda_available():
        raise ValueError(f"variant {variant!r} needs a CUDA GPU, and none was found")
    import mitsuba as mi  # mitsuba: lazy, it selects a variant process-wide (set just below)

    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


@callers_variant()  # the caller's variant comes back (issue 33: the spectral one was left active)
def render_sky(
    spec: AtmosphereSpec,
    dirs: np.ndarray,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    max_depth: int,
    cache_dir=None,
) -> dict:
    """Point-sampled radiance along ``dirs`` from the viewer, pooled over independent passes.

    Returns ``{"mean", "stderr"}`` (shape of ``dirs`` with last axis RGB, float64, W·m⁻²·sr⁻¹·nm⁻¹
    when E₀ is in W·m⁻²·nm⁻¹), ``spp``, ``passes``, ``seconds``, ``cache_key``. ceil(spp / pass_spp)
    passes of ``pass_spp`` samples, pass i seeded with ``sub_seed(seed, "pass", i)``; with ``cache_dir``
    they are stored in the one pass store (`rtfit.reference.cache.PassEntry`, namespace "sky", .npz:
    a rerun renders only missing passes). npz passes keep their float64 moments, so a cached and an
    uncached call give the same numbers.

    ``variant``: an llvm_*/cuda_* RGB variant (channels = the spec's three wavelengths), or
    ``llvm_ad_spectral``/``cuda_ad_spectral``: the spectral atmosphere (module docstring), the
    channels then being Mitsuba's film linear sRGB (`film_srgb` of the radiance spectrum: no
    white balance)."""
    if spp < 2 or pass_spp < 2:
        raise ValueError(f"spp and pass_spp must be >= 2 (got {spp}, {pass_spp})")
    if not (variant.startswith("llvm_") or variant.startswith("cuda_")):
        raise ValueError(
            f"variant must be an llvm_*/cuda_* variant for the atmosphere reference (got {variant!r})"
        )
    shape = np.asarray(dirs).shape
    mi = _use_variant(variant)
    ident = {
        "format": _CACHE_FORMAT,
        "spec": asdict(spec),
        "max_depth": int(max_depth),
        "variant": variant,
        "seed": int(seed),
        "pass_spp": int(pass_spp),
        "versions": {"mitsuba": mi.__version__, "drjit": dr.__version__},
        "directions": array_digest(dirs),
        "estimator": sky_integrator.ESTIMATOR if reference_medium(mi) == "skypath" else SEGMENT_ESTIMATOR,
    }
    entry = PassEntry(cache_dir or ".", ident, namespace="sky", storage="npz")
    origin = (0.0, 0.0, spec.planet_radius_km + spec.viewer_altitude_km)
    loaded: dict = {}

    def load_scene():
        loaded["scene"], loaded["medium"] = load_sky(mi, spec, max_depth)

    def render(i: int) -> PassResult:
        scene, medium = loaded["scene"], loaded["medium"]
        return sky_pass(mi, scene, medium, origin, dirs, pass_spp, sub_seed(seed, "pass", i))

    n_pass = -(-spp // pass_spp)
    if cache_dir is not None:
        passes, _ = entry.passes(n_pass, render, before_render=load_scene, spp_of=lambda _i: pass_spp)
    else:  # no store: the passes as rendered (the npz store keeps the same float64 values)
        load_scene()
        passes = [render(i) for i in range(n_pass)]
    mean, stderr, n = pool_passes(passes)
    seconds = float(sum(p.seconds for p in passes))
    return {
        "mean": mean.reshape(shape),
        "stderr": stderr.reshape(shape),
        "spp": n,
        "passes": len(passes),
        "seconds": seconds,
        "cache_key": entry.key,
        "samples_per_second": float(n * mean.shape[0] / max(seconds, 1e-9)),
    }


# ------------------------------------------------------------------------ independent quadrature
def _gl(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def _sun_optical_depth(p: np.ndarray, s: np.ndarray, spec: AtmosphereSpec, nodes: int = 64):
    """(τ_R, τ_M) density integrals (km) from points p (N, 3) to the top along s ((3,), or (N, 3): one
    unit direction per point); inf if the planet blocks. Gauss–Legendre on the arc length split at 8
    geometric sub-intervals [0, 1/128, …, 1/2, 1]·t_top (the density falls fast).

    A float64 Dr.Jit kernel on the CPU (LLVM): one lane per point looping over the 8·``nodes`` nodes (a
    symbolic loop over opaque node tables: one compiled kernel for every size and node count), each lane
    summing in node order. Issue 33: the same sums in NumPy over (N, nodes) arrays were 87 % of the quick
    nishita-sky study's quadratures (4.3 s); a lane's value does not depend on the other lanes (no
    reduction across them), so a point gives the same bits alone or in any batch."""
    rg, rt = spec.planet_radius_km, spec.top_radius_km
    F, U = dr.llvm.Float64, dr.llvm.UInt32
    p = np.asarray(p, np.float64)
    s = np.broadcast_to(np.asarray(s, np.float64), p.shape)
    px, py, pz = (F(np.ascontiguousarray(p[:, k])) for k in range(3))
    sx, sy, sz = (F(np.ascontiguousarray(s[:, k])) for k in range(3))
    b = dr.fma(px, sx, dr.fma(py, sy, pz * sz))
    pp = dr.fma(px, px, dr.fma(py, py, pz * pz))
    ss = dr.fma(sx, sx, dr.fma(sy, sy, sz * sz))
    t_top = -b + dr.sqrt(dr.maximum(b * b - (pp - rt * rt), 0.0))
    # The planet blocks if the ray towards the sun meets the ground sphere ahead: its perigee lies ahead
    # (p·s < 0) and below the ground (b² − |p|² + rg² > 0). Before issue 33 the test was that the nearer
    # root −b − √disc be > 0, which let a point on the ground (a ground-hit view ray's end, a viewer at 0 m)
    # with the sun below its horizon through (the root is 0 there): its ray then crossed the planet, where
    # the Rayleigh density e^{−h/H} of a negative h grows; its transmittance came out ~0 all the same.
    disc = b * b - (pp - rg * rg)
    blocked = (disc > 0) & (b < 0)
    # node k of sub-interval [a0, a1]: t = t_top·u_k, weight t_top·c_k (u, c the interval's Gauss–Legendre
    # abscissae and weights mapped onto it)
    x, w = _gl(nodes)
    edges = np.concatenate([[0.0], 2.0 ** np.arange(-7, 1)])
    u = np.concatenate([0.5 * (a0 + a1) + 0.5 * (a1 - a0) * x for a0, a1 in itertools.pairwise(edges)])
    c = np.concatenate([0.5 * (a1 - a0) * w for a0, a1 in itertools.pairwise(edges)])
    u_t, c_t, count = F(u), F(c), dr.opaque(U, u.size)
    inv_hr, inv_hm = 1.0 / spec.rayleigh_height_km, 1.0 / spec.mie_height_km

    def body(i, tr, tm):
        t = t_top * dr.gather(F, u_t, i)
        jw = t_top * dr.gather(F, c_t, i)
        # |p + t·s|² = |p|² + 2t(p·s) + t²|s|²; ≥ rg² on the rays that are kept (a blocked ray is inf
        # below), the max only keeps a rounding below 0 out of the root
        h = dr.sqrt(dr.maximum(pp + t * (2.0 * b + t * ss), 0.0)) - rg
        return i + 1, tr + jw * dr.exp(-h * inv_hr), tm + jw * dr.exp(-dr.maximum(h, 0.0) * inv_hm)

    n = p.shape[0]
    _, tr, tm = dr.while_loop(  # (a blocked lane's sums are not read: it stops at once)
        state=(dr.zeros(U, n), dr.zeros(F, n), dr.zeros(F, n)),
        cond=lambda i, *_: (i < count) & ~blocked,
        body=body,
    )
    tr, tm = dr.select(blocked, dr.inf, tr), dr.select(blocked, dr.inf, tm)
    dr.eval(tr, tm)
    return np.asarray(tr, np.float64), np.asarray(tm, np.float64)


SUN_RAY_LANES = 1 << 20
"""`_ss_quadrature` hands the sun rays of this many points (at most; at least one row's) to one
`_sun_optical_depth` kernel: enough lanes for every core, and 48 MiB of points and directions."""


DISC_NODES = 8
"""Nodes across the sun's disc of the disc-sun quadrature (`single_scattering_quadrature`)."""


def single_scattering_quadrature(
    spec: AtmosphereSpec, dirs: np.ndarray, steps: int = 2000, point_sun: bool = True
) -> np.ndarray:
    """Single-scattered sky radiance along ``dirs`` (…, 3) by direct float64 quadrature.

    L = E₀ ∫₀^{t_max} Σ_{k∈{R,M}} β_k ρ_k(x) P_k(cos γ) T(o→x) T_sun(x) dt, with t_max the exit
    through the top or the ground hit; trapezoid on a grid in u = t/t_max squared-spaced near the
    viewer (u = v², ``steps`` points) plus exact cumulative view transmittance by the same rule;
    T_sun by `_sun_optical_depth`. Ground-reflected light is not included (it needs two scattering
    events for a sky pixel).

    ``point_sun=True``: the sun is a point of irradiance E₀ along ``spec.sun_direction`` (the real-time
    model's sun). ``point_sun=False``: the sun is the uniform disc of angular radius α =
    ``spec.sun_angular_radius`` and radiance E₀/(π sin²α) that the Mitsuba reference renders
    (`rtfit.reference.emitters`): E₀ P T_sun is replaced by L_d ∫_disc P(v·ω) T_sun(x, ω) dω. T_sun
    depends on ω through the sun's elevation seen from x, which varies across the disc along the great
    circle through s and x's zenith only (across it, at second order: α² = 2e-5), so the disc is
    integrated along that diameter with the chord-length weight 2√(α² − δ²) (Gauss–Chebyshev of the
    second kind, `DISC_NODES` nodes, at exact directions; phase included), times the disc's solid
    angle 2π(1 − cos α). The disc matters where the planet's shadow edge crosses it: measured
    Σ|disc − point| / Σ disc over a 16×8 sky (G channel; tests/test_nishita_sky_reference.py):
    6e-5 at sun +10°, 6e-4 at +2°, 1.3e-3 at 0°, 6.1e-3 at −4°, and 6–24 % on the low anti-solar sky
    at −4° (before session 4 this docstring claimed < 1e-4 everywhere: true only well above the horizon).
    """
    d = np.asarray(dirs, dtype=np.float64)
    shape = d.shape
    br, bm, bme = (
        np.asarray(v, dtype=np.float64)
        for v in (spec.rayleigh_beta_km, spec.mie_beta_km, spec.mie_extinction_km)
    )
    out = _ss_quadrature(spec, d.reshape(-1, 3), steps, br, bm, bme, 0 if point_sun else DISC_NODES)
    out *= np.asarray(spec.solar_irradiance)[None, :]
    return out.reshape(shape)


def _disc_rule(alpha: float, nodes: int):
    """Offsets δ_i (rad) across a disc of angular radius α and weights ŵ_i (sum 1) of the chord-length
    average (1/(πα²))∫_{−α}^{α} f(δ) 2√(α² − δ²) dδ: Gauss–Chebyshev of the second kind."""
    th = np.arange(1, nodes + 1) * math.pi / (nodes + 1)
    w = np.sin(th) ** 2
    return alpha * np.cos(th), w / w.sum()


def _phases(cos_g: np.ndarray, g: float):
    """Rayleigh and Henyey–Greenstein (Mie) phase functions (1/sr) of cos γ."""
    pr = 3.0 / (16.0 * math.pi) * (1.0 + cos_g**2)
    pm = (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_g) ** 1.5)
    return pr, pm


def _ss_quadrature(
    spec: AtmosphereSpec, d: np.ndarray, steps: int, br, bm, bme, disc_nodes: int = 0
) -> np.ndarray:
    """The integral of `single_scattering_quadrature` per unit E₀ for (N, 3) directions and C
    channels with coefficient arrays br, bm, bme of shape (C,) (km⁻¹): returns (N, C). ``disc_nodes``:
    0 for a point sun, else the nodes across the sun's disc (`_disc_rule`)."""
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
    g = spec.mie_g
    pr, pm = _phases(d @ s, g)
    alpha = spec.sun_angular_radius
    # L_d·Ω_disc / E₀ = 2π(1 − cos α)/(π sin²α) = 2/(1 + cos α)
    deltas, wts = _disc_rule(alpha, disc_nodes) if disc_nodes else (None, None)
    disc_scale = 2.0 / (1.0 + math.cos(alpha))
    u = np.linspace(0.0, 1.0, steps) ** 2

    def disc_directions(x: np.ndarray) -> np.ndarray:
        """The K sun directions (K, n, 3) across the disc's diameter through each point's zenith."""
        # unit vector ⊥ s towards x's zenith: the disc diameter along which the sun's elevation varies
        up = x / np.linalg.norm(x, axis=1, keepdims=True)
        perp = up - (up @ s)[:, None] * s[None, :]
        pn = np.linalg.norm(perp, axis=1, keepdims=True)
        fallback = np.cross(s, [1.0, 0.0, 0.0] if abs(s[0]) < 0.9 else [0.0, 1.0, 0.0])
        perp = np.where(pn > 1e-12, perp / np.maximum(pn, 1e-300), fallback / np.linalg.norm(fallback))
        return np.cos(deltas)[:, None, None] * s[None, None, :] + np.sin(deltas)[:, None, None] * perp[None]

    def sun_rays(i: int) -> tuple[np.ndarray, np.ndarray]:
        """Row i's sun rays: (points, directions), one per point of its view ray (point sun), or K per point
        (disc: the points repeated K times, the first `steps` rows the view ray's points)."""
        x = o[None, :] + (u * t_max[i])[:, None] * d[i][None, :]
        if deltas is None:
            return x, np.broadcast_to(s, x.shape)
        om = disc_directions(x)
        return np.broadcast_to(x, om.shape).reshape(-1, 3), om.reshape(-1, 3)

    def row(i: int, rays: tuple[np.ndarray, np.ndarray], sr: np.ndarray, sm: np.ndarray) -> np.ndarray:
        """Row i's integral, given its sun rays (`sun_rays`) and their optical depths."""
        t = u * t_max[i]
        x = rays[0][:steps]  # the view ray's points (`sun_rays`)
        h = np.maximum(np.linalg.norm(x, axis=1) - rg, 0.0)
        rr, rm = np.exp(-h / spec.rayleigh_height_km), np.exp(-h / spec.mie_height_km)
        dt = np.diff(t)
        odr = np.concatenate([[0.0], np.cumsum(0.5 * (rr[1:] + rr[:-1]) * dt)])
        odm = np.concatenate([[0.0], np.cumsum(0.5 * (rm[1:] + rm[:-1]) * dt)])
        t_view = np.exp(-(odr[:, None] * br[None, :] + odm[:, None] * bme[None, :]))
        t_sun = np.exp(-(sr[:, None] * br[None, :] + sm[:, None] * bme[None, :]))
        if deltas is None:
            f = (br[None, :] * rr[:, None] * pr[i] + bm[None, :] * rm[:, None] * pm[i]) * t_sun
        else:
            k, n = len(deltas), len(x)
            om = rays[1].reshape(k, n, 3)
            prk, pmk = _phases(om @ d[i], g)  # (K, n)
            dens = br[None, None, :] * rr[None, :, None] * prk[..., None]
            dens = dens + bm[None, None, :] * rm[None, :, None] * pmk[..., None]
            f = np.einsum("k,knc->nc", wts, dens * t_sun.reshape(k, n, -1))
            f *= disc_scale
        f = f * t_view
        return np.sum(0.5 * (f[1:] + f[:-1]) * dt[:, None], axis=0)

    # The sun rays of a batch of rows in one Dr.Jit kernel (`_sun_optical_depth`: every core), then each
    # row's NumPy work (exp, norms and sums over ~10⁴–10⁶ values, which release the GIL) on threads: the
    # same numbers, row for row, as a row computed alone.
    per_row = steps * (len(deltas) if deltas is not None else 1)
    batch = max(1, SUN_RAY_LANES // per_row)
    workers = max(1, min(d.shape[0], len(os.sched_getaffinity(0))))
    rows: list[np.ndarray] = []
    with ThreadPoolExecutor(workers) as pool:
        for a in range(0, d.shape[0], batch):
            todo = range(a, min(d.shape[0], a + batch))
            rays = [sun_rays(i) for i in todo]
            sr, sm = _sun_optical_depth(
                np.concatenate([r[0] for r in rays]), np.concatenate([r[1] for r in rays]), spec
            )
            cuts = np.cumsum([len(r[0]) for r in rays])[:-1]
            rows += pool.map(row, todo, rays, np.split(sr, cuts), np.split(sm, cuts))
    return np.array(rows, dtype=np.float64).reshape(d.shape[0], br.size)


# ----------------------------------------------------------------------------- spectral helpers
def solar_spectrum(lam_nm, e550: float = 1.8504, temperature_k: float = SOLAR_TEMPERATURE_K) -> np.ndarray:
    """Solar irradiance E₀(λ) = E₀(550)·B(λ, T)/B(550, T) (W·m⁻²·nm⁻¹ when E₀(550) is), B the
    Planck law ∝ λ⁻⁵/(exp(c₂/(λT)) − 1), c₂ = 1.4387769e-2 m·K, λ in nm.

    The real-time spectral variant's default (``rtfit.realtime.nishita_sky.AtmosphereParams.spectral``:
    5778 K blackbody normalised to that set's 550 nm value), re-derived here because the reference
    must not import the real-time code; a test checks that the two agree."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    if np.any(~np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError("lam_nm must be finite and > 0")
    if not (temperature_k > 0 and math.isfinite(temperature_k)):
        raise ValueError(f"temperature_k must be finite and > 0 (got {temperature_k!r})")

    def planck(x):
        x = x * 1e-9
        return x**-5 / np.expm1(1.4387769e-2 / (x * temperature_k))

    return float(e550) * planck(lam) / planck(np.array(REFERENCE_WAVELENGTH_NM))


def spectral_coefficients(spec: AtmosphereSpec, lam_nm):
    """(β_R, β_M, β_M^ext, E₀) at wavelengths ``lam_nm`` (arrays, km⁻¹ and W·m⁻²·nm⁻¹):
    β_R(550)(550/λ)⁴, grey Mie, `solar_spectrum` — exactly what the spectral Mitsuba scene uses,
    anchored at the spec's 550 nm (second) channel."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    if np.any(~np.isfinite(lam)) or np.any(lam <= 0):
        raise ValueError("lam_nm must be finite and > 0")
    br = spec.rayleigh_beta_km[1] * (REFERENCE_WAVELENGTH_NM / lam) ** 4
    ones = np.ones_like(lam)
    return (
        br,
        spec.mie_beta_km[1] * ones,
        spec.mie_extinction_km[1] * ones,
        solar_spectrum(lam, spec.solar_irradiance[1]),
    )


_CIE_TABLE: dict = {}


def cie1931_table():
    """Mitsuba's CIE 1931 2° colour-matching table as used by its film: (λ knots (95,) nm, 360–830
    in 5 nm steps; x̄ȳz̄ (95, 3)), read from the installed Mitsuba (``mi.cie1931_xyz`` at the knots;
    between knots Mitsuba interpolates linearly, outside [360, 830] it returns 0)."""
    _read_film_tables()
    return _CIE_TABLE["table"]


def film_xyz_to_srgb() -> np.ndarray:
    """Mitsuba's XYZ → linear sRGB matrix (3, 3) as its film applies it (``mi.xyz_to_srgb`` of the unit
    vectors, float32 values): read from the installed Mitsuba, not typed in, so the reference has no
    copy of the matrix (the real-time `spectral_to_srgb` has the one typed copy, ``XYZ_TO_SRGB``, to the
    same digits; a test checks that they agree)."""
    _read_film_tables()
    return _CIE_TABLE["xyz_to_srgb"]


def _read_film_tables() -> None:
    if "table" in _CIE_TABLE:
        return
    import mitsuba as mi  # mitsuba: selects a variant process-wide (restored below)

    prev = mi.variant()
    if prev is None or prev.startswith("scalar"):
        mi.set_variant("llvm_ad_rgb")
    knots = np.linspace(CIE_MIN_NM, CIE_MAX_NM, 95)
    xyz = np.asarray(mi.cie1931_xyz(mi.Float(knots.astype(np.float32))), dtype=np.float64)
    cols = [
        np.asarray(mi.xyz_to_srgb(mi.Color3f(*(float(x) for x in e))), dtype=np.float64).ravel()
        for e in np.eye(3)
    ]
    if prev is not None and prev != mi.variant():
        mi.set_variant(prev)
    _CIE_TABLE["table"] = (knots, xyz.reshape(3, -1).T.copy())
    _CIE_TABLE["xyz_to_srgb"] = np.stack(cols, axis=1)  # column j: the image of the j-th unit vector


def film_srgb(spectra, lam_nm) -> np.ndarray:
    """Linear sRGB that Mitsuba's RGB film gives a radiance spectrum: M_709 ∫ (x̄, ȳ, z̄) L dλ ×
    `CIE_Y_NORMALIZATION`, over the samples ``lam_nm`` (N,) (ascending, inside [360, 830]; the
    trapezoid rule, with x̄ȳz̄ Mitsuba's piecewise-linear table: use a grid containing the 5 nm knots,
    e.g. 1 nm steps, to make the only error the trapezoid's on L). ``spectra`` (…, N) → (…, 3)."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    L = np.asarray(spectra, dtype=np.float64)
    if lam.ndim != 1 or lam.size < 2 or np.any(np.diff(lam) <= 0):
        raise ValueError("lam_nm must be 1-D, ascending, with at least 2 samples")
    if lam[0] < CIE_MIN_NM - 1e-9 or lam[-1] > CIE_MAX_NM + 1e-9:
        raise ValueError(f"lam_nm must lie in [{CIE_MIN_NM:g}, {CIE_MAX_NM:g}] nm")
    if L.shape[-1] != lam.size:
        raise ValueError(f"spectra's last axis must have {lam.size} samples (got {L.shape[-1]})")
    knots, table = cie1931_table()
    cmf = np.stack([np.interp(lam, knots, table[:, k]) for k in range(3)], axis=-1)  # (N, 3)
    w = np.zeros(lam.size)
    dl = np.diff(lam)
    w[:-1] += 0.5 * dl
    w[1:] += 0.5 * dl
    xyz = L @ (cmf * w[:, None]) * CIE_Y_NORMALIZATION
    return xyz @ film_xyz_to_srgb().T


def spectral_single_scattering_quadrature(
    spec: AtmosphereSpec, dirs: np.ndarray, steps: int = 2000, step_nm: float = 1.0
) -> dict:
    """The spectral single-scattered sky along ``dirs`` (…, 3): `single_scattering_quadrature`'s
    integral per wavelength on λ = 360, 360 + step_nm, …, 830 nm with `spectral_coefficients`,
    then Mitsuba's film conversion (`film_srgb`). Returns ``{"srgb": (…, 3), "wavelengths_nm":
    (N,), "spectra": (…, N) in W·m⁻²·sr⁻¹·nm⁻¹}``. ``step_nm`` must divide 5 nm (the CIE knots)."""
    k = 5.0 / step_nm
    if not (step_nm > 0 and abs(k - round(k)) < 1e-9):
        raise ValueError(f"step_nm must divide 5 nm (got {step_nm!r})")
    lam = np.linspace(CIE_MIN_NM, CIE_MAX_NM, round((CIE_MAX_NM - CIE_MIN_NM) / step_nm) + 1)
    d = np.asarray(dirs, dtype=np.float64)
    br, bm, bme, e0 = spectral_coefficients(spec, lam)
    L = _ss_quadrature(spec, d.reshape(-1, 3), steps, br, bm, bme) * e0[None, :]
    L = L.reshape(*d.shape[:-1], lam.size)
    return {"srgb": film_srgb(L, lam), "wavelengths_nm": lam, "spectra": L}


# ------------------------------------------------------------------------------------ sunsky
def sunsky_radiance(
    sun_elevation_deg: float,
    dirs: np.ndarray,
    variant: str = "llvm_ad_rgb",
    turbidity: float = 3.0,
    albedo: float = 0.1,
) -> dict:
    """Mitsuba's Hosek–Wilkie ``sunsky``: sky radiance along ``dirs`` (sun excluded) and the sun's
    irradiance at normal incidence (disc radiance at its centre × its solid angle), in sunsky's
    own units (facts note §6: W·m⁻²·sr⁻¹·nm⁻¹ in RGB). Only for sun elevation > 0."""
    if not (0.0 < sun_elevation_deg <= 90.0):
        raise ValueError(f"sunsky needs sun_elevation_deg in (0, 90] (got {sun_elevation_deg!r})")
    mi = use_variant(variant)
    e = math.radians(sun_elevation_deg)
    sd = [math.cos(e), 0.0, math.sin(e)]
    aperture = 0.5358

    def emitter(sun_scale, sky_scale):
        sc = mi.load_dict(
            {
                "type": "scene",
                "sky": {
                    "type": "sunsky",
                    "sun_direction": sd,
                    "turbidity": turbidity,
                    "albedo": albedo,
                    "sun_scale": sun_scale,
                    "sky_scale": sky_scale,
                    "sun_aperture": aperture,
                },
            }
        )
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


# ====================================================================== cached quadratures, bench
DISC_MAX_DEG = 2.0
"""Sun elevations (°) up to which `cached_quadrature` also integrates over the sun's disc: Σ|disc − point| /
Σ disc is 6e-4 at +2° and 6e-5 at +10° (`single_scattering_quadrature`), far below any reference's noise
above 2°, and the disc costs `DISC_NODES`× the point sun's time."""
QUADRATURE_FORMAT = 2
"""Version of the stored quadratures (`ComputedEntry`, namespace "sky-quadrature"): bump it when
`single_scattering_quadrature`, `spectral_single_scattering_quadrature` or what is stored changes."""


def cached_quadrature(spec: AtmosphereSpec, dirs, steps: int, cache_dir=None, spectral: bool = False) -> dict:
    """The float64 single-scattering quadrature along unit ``dirs`` (…, 3), through the cache when
    ``cache_dir`` is given (keyed on the atmosphere, the exact directions, the steps, the disc rule and the
    versions; the full run's twilight quadratures take minutes each). Single scattering: ``value`` for a
    point sun (the real-time model's), ``disc`` for the sun's disc (the Mitsuba reference's; None above
    `DISC_MAX_DEG`); ``spectral``: `spectral_single_scattering_quadrature`'s arrays plus ``rgb`` (the
    3-wavelength point-sun quadrature). ``seconds`` it took to compute, ``cached`` whether it was read."""
    sub = np.asarray(dirs, dtype=np.float64)
    elev = float(spec.sun_elevation_deg)

    def compute() -> dict:
        t0 = time.perf_counter()
        if spectral:
            out = dict(spectral_single_scattering_quadrature(spec, sub, steps=steps))
            out["rgb"] = single_scattering_quadrature(spec, sub, steps=steps)
        else:
            out = {"value": single_scattering_quadrature(spec, sub, steps=steps)}
            if elev <= DISC_MAX_DEG:
                out["disc"] = single_scattering_quadrature(spec, sub, steps=steps, point_sun=False)
        return {**out, "seconds": np.float64(time.perf_counter() - t0)}

    if cache_dir is None:
        return {"disc": None, **compute(), "cached": False}
    ident = {
        "format": f"nishita-sky/{'spectral' if spectral else 'ss'}-quadrature/{QUADRATURE_FORMAT}",
        "spec": asdict(spec),
        "directions": array_digest(sub),
        "count": int(sub.size // 3),
        "steps": int(steps),
        "disc": {"nodes": DISC_NODES, "max_elevation_deg": DISC_MAX_DEG},
        "versions": {"numpy": np.__version__, "mitsuba": metadata.version("mitsuba")},
    }
    arrays, computed = ComputedEntry(cache_dir, ident, namespace="sky-quadrature").get(compute)
    return {"disc": None, **arrays, "seconds": float(arrays["seconds"]), "cached": not computed}


BENCH_MEDIA = (
    ("skypath", "rtfit_skypath: tangent-exponential majorants, spectral MIS, marched sun (the reference)"),
    ("segment", "rtfit atmosphere medium, per-segment majorant (volpathmis; the reference of session 4)"),
    ("box", "rtfit atmosphere medium, ground-level majorant (the estimator before issue 21)"),
    ("grid", "Mitsuba heterogeneous + gridvolume (256³) of the same extinction"),
    ("none", "Mitsuba path on planet and sun without atmosphere (the floor)"),
)
"""The media of `bench_media`: rtfit's estimator beside what a user would otherwise run."""
BENCH_ROUNDS = 3


def bench_media(variant: str, spec: AtmosphereSpec, res=(32, 16), spp: int = 128) -> list[dict]:
    """Samples/s of the sky reference pass (single and multiple scattering) with each of `BENCH_MEDIA`,
    side by side in one process: one warm-up pass each, then `BENCH_ROUNDS` interleaved rounds (a change of
    load hits every row alike), the best pass per medium. Each row also gives the mean per-sample variance
    (G) of its timed passes (``variance_vs_box``: its ratio to the ground-level majorant's; efficiency =
    samples/s ÷ variance: ``efficiency_vs_box``) and the events per lane of the warm-up pass
    (`LaneCounter.means` per counted call site)."""
    dirs = hemisphere_directions(*res)[0].reshape(-1, 3)
    samples = dirs.shape[0] * spp
    origin = (0.0, 0.0, spec.planet_radius_km + spec.viewer_altitude_km)
    mi = use_variant(variant)
    rows = []
    for depth, transport in ((2, "single"), (-1, "multiple")):
        loaded, events = {}, {}
        for medium, _ in BENCH_MEDIA:
            scene, med = loaded[medium] = load_sky(mi, spec, depth, medium)
            events[medium] = []
            sky_pass(mi, scene, med, origin, dirs, spp, 0, events=events[medium])
        timed: dict = {medium: [] for medium in loaded}
        for k in range(BENCH_ROUNDS):
            for medium, (scene, med) in loaded.items():
                what = f"bench nishita-sky, {transport} scattering, {medium}, round {k + 1}"
                timed[medium].append(check_finite(sky_pass(mi, scene, med, origin, dirs, spp, k + 1), what))
        rates = {m: samples / min(p.seconds for p in ps) for m, ps in timed.items()}
        var = {m: float(np.mean([p.var[:, 1].mean() for p in ps])) for m, ps in timed.items()}
        for medium, label in BENCH_MEDIA:
            row = {
                "what": f"reference pass, {transport} scattering ({res[0]}×{res[1]}, {spp} spp): {label}",
                "backend": variant,
                "elements": samples,
                "drjit_Mray_s": rates[medium] / 1e6,
                "ns_per_ray": 1e9 / rates[medium],
                "sample_variance_g": var[medium],
                "events_per_lane": [m for launch in events[medium][:1] for site in launch for m in site],
                "vs_native_grid": rates[medium] / rates["grid"],
                "vs_box_majorant": rates[medium] / rates["box"],
                "vs_segment": rates[medium] / rates["segment"],
                "vs_no_atmosphere": rates[medium] / rates["none"],
            }
            if var["box"] > 0 and var[medium] > 0:
                row["variance_vs_box"] = var[medium] / var["box"]
                row["efficiency_vs_box"] = row["vs_box_majorant"] / row["variance_vs_box"]
            rows.append(row)
    return rows
