r"""Nishita sky: single-scattering sky texture with the phase function applied per pixel.

Source: Nishita et al. 1993 ("Display of the Earth taking into account atmospheric scattering"),
as CryEngine 2 used it (seed 000:2178-2187, 002:130-164): the viewer on the ground, parallel sun
light, a 2-D optical-depth table (sun angle × layer height), n = 32 exponentially distributed
atmosphere layers, Rayleigh and Mie in-scattering solved for 128×64 directions of the sky
hemisphere and stored **without** the phase function, the phase function applied per pixel on the
GPU. Beyond the seed: viewer altitude ≠ 0 (also above the atmosphere), a spectral variant, and
aerial perspective to a point (transmittance + in-scatter) for fog.

Units: **metres** for lengths, m⁻¹ for coefficients, radiance in the units of the solar
irradiance E₀ per steradian (E₀ in W·m⁻²·nm⁻¹ ⇒ radiance in W·m⁻²·sr⁻¹·nm⁻¹). Frame: the viewer
above the planet's north pole, +Z up; directions as (cos of zenith angle μ, azimuth from the sun).

Model (per wavelength / channel c)
----------------------------------
Densities ρ_R(h) = e^{−h/H_R}, ρ_M(h) = e^{−h/H_M}; scattering β_R,c ρ_R, β_M,c ρ_M; extinction
β_R,c ρ_R + β_M,c^ext ρ_M. For a view ray x(t) = o + t·v from the viewer o to its exit (top of the
atmosphere) or the ground:

    S_k,c(v) = β_k,c ∫ ρ_k(x) exp(−τ_c(o→x) − τ_c(x→sun)) dt,   k ∈ {R, M}
    L_c(v)   = E₀,c [P_R(v·s) S_R,c(v) + P_M(v·s) S_M,c(v)]  (+ the sun disc)

with τ_c = β_R,c ∫ρ_R + β_M,c^ext ∫ρ_M. The seed's eq. (1) (002:145) writes one phase F(θ, g)
in front of the integral: that holds for each of the two terms separately (the phase is constant
along a ray for parallel sun light), which is why S_R and S_M are stored apart. P_R = 3/(16π)(1 + cos²γ);
P_M Henyey–Greenstein or Cornette–Shanks with asymmetry g.

Numerics (the quantities the experiment sweeps):

* **Layers**: n + 1 sphere radii R_g + h_k with h_k = −H_R ln(1 − (k/n)(1 − e^{−h_top/H_R}))
  (equal Rayleigh mass between consecutive layers: "exponentially distributed according to the
  characteristics of the atmosphere", 000:2180). A view ray is sampled at its start, at every
  layer crossing (down-going and up-going legs), at its lowest point or its ground hit; the
  integrands are combined by the trapezoid rule between consecutive samples, and the view-ray
  optical depth is accumulated by the same rule (as Nishita does).
* **Optical-depth table**: τ_R, τ_M from each layer height to the top of the atmosphere along
  the sun direction, for ``table_size`` sun zenith angles θ uniform in [0, θ_max] (θ_max = 90° +
  the horizon dip at the top + 2°); bilinear lookup in (continuous layer index, θ); rays into the
  ground store a large finite depth (transmittance 0), so the planet's shadow is resolved to one
  table cell. Built with `atmosphere_optical_depth`.
* **Texture**: W × H texels, azimuth φ ∈ [0, 2π) from the sun (texel centres), elevation from
  el_lo (the horizon: 0 on the ground, −dip above it) to 90°, linear in elevation (``mapping=
  "linear"``, the seed's uniform hemisphere sampling) or in √ of the elevation fraction
  (``"sqrt"``, more texels near the horizon). Per pixel: bilinear lookup (azimuth wraps), phase
  evaluated at the pixel's exact angle to the sun, sun disc added.

`atmosphere_optical_depth` (the exact transmittance integral)
-------------------------------------------------------------
∫₀^{t_exit} e^{−h(t)/H} dt along a ray from altitude h with cos zenith μ to the top radius,
+inf where the ray hits the ground (μ < 0 and impact parameter d = r sin θ < R_g). With d the
impact parameter, the substitution r = d + x² removes the 1/√(r − d) singularity at the tangent
point: ∫ e^{−(r−R_g)/H} r/√(r² − d²) dr = ∫ 2 e^{−(h + x² − x_a²)/H} (d + x²)/√(2d + x²) dx with
x_a² = r − d = r μ²/(1 + sin θ) (no cancellation). Up-going legs run x ∈ [x_a, x_b],
x_b² − x_a² = h_top − h; a down-going ray adds twice the leg x ∈ [0, x_a] (down to the tangent
point and back up). Each leg is truncated where the integrand has fallen by e^{−40} and
integrated by 24-point Gauss–Legendre in x: relative error < 1e-12 in float64 against mpmath
(tests), exact at the top (zero-length leg) and for horizontal rays (x_a = 0, no singularity).
Vertical: H (e^{−h/H} − e^{−h_top/H}).

Methods as data
---------------
`METHODS` (`rtfit.realtime.methods`) declares the approximations the experiment compares: one kernel text,
`nishita_sky_kernel` (the in-scatter kernel over the texels, then the per-pixel lookup and phase, the
pieces `build_sky` and `shade_sky` run), with the numerical setting as data (`SkySetting`: layers, texture
and table size, row mapping, spectral wavelengths) and the artist parameters of ``nishita-fitted`` as
`Param`s with bounds. Its JAX run is what `rtfit.fitting.fit_method` differentiates. The shared ops
namespaces of `rtfit.realtime.arrays` run every kernel here on Dr.Jit, NumPy and JAX.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import drjit as dr
import numpy as np

from .arrays import DRJIT_OPS, NUMPY_OPS, check_range, check_scalar, evaluate, is_drjit, to_drjit
from .methods import Input, Method, Param, method_table
from .phase import cornette_shanks_phase_kernel, hg_phase_kernel, rayleigh_phase_kernel

__all__ = [
    "FINE_SETTING",
    "SEED_SETTING",
    "XYZ_TO_SRGB",
    "AtmosphereParams",
    "NishitaSky",
    "SkySetting",
    "aerial_perspective",
    "atmosphere_optical_depth",
    "blackbody",
    "build_optical_depth_table",
    "build_sky",
    "cie_xyz_fit",
    "layer_heights",
    "lookup_components",
    "nishita_sky_kernel",
    "shade_sky",
    "sky_kernel_inputs",
    "spectral_to_srgb",
    "sun_transmittance",
    "texture_arrays",
]

_FAR = 1e12  # "infinite" optical depth stored in tables (m of density-weighted path)
_TRUNC = 40.0  # truncate each leg where the integrand has fallen by e^-40
_GL_N = 24
_GL_X, _GL_W = (tuple(float(v) for v in a) for a in np.polynomial.legendre.leggauss(_GL_N))


# ====================================================================================== parameters
@dataclass(frozen=True)
class AtmosphereParams:
    """Physical parameters (SI: metres, m⁻¹). Defaults: Bruneton 2017's shared set without ozone
    (Bruneton & Neyret 2008): β_R at 680/550/440 nm, Mie scattering/extinction 3.996e-6/4.44e-6 m⁻¹,
    g = 0.8, H_R = 8 km, H_M = 1.2 km, planet 6360 km, top 6420 km, ground albedo 0.1, sun angular
    radius 4.675 mrad, solar irradiance at 680/550/440 nm in W·m⁻²·nm⁻¹.

    ``wavelengths_nm``: the wavelength of each channel (used by the spectral variant to scale
    Rayleigh as λ⁻⁴). Artist controls: ``rayleigh_scale``, ``mie_scale`` (multiply β_R and
    β_M, β_M^ext), ``mie_g``, ``ambient`` (an isotropic multiple-scattering term added to the
    Rayleigh phase: P_R → P_R + ambient/(4π)), ``mie_phase`` ("hg" or "cs")."""

    planet_radius_m: float = 6360e3
    top_radius_m: float = 6420e3
    rayleigh_height_m: float = 8000.0
    mie_height_m: float = 1200.0
    rayleigh_beta: tuple = (5.802e-6, 13.558e-6, 33.1e-6)
    mie_beta: tuple = (3.996e-6, 3.996e-6, 3.996e-6)
    mie_extinction: tuple = (4.440e-6, 4.440e-6, 4.440e-6)
    mie_g: float = 0.8
    ground_albedo: float = 0.1
    sun_angular_radius: float = 0.004675
    solar_irradiance: tuple = (1.474, 1.8504, 1.91198)
    wavelengths_nm: tuple = (680.0, 550.0, 440.0)
    rayleigh_scale: float = 1.0
    mie_scale: float = 1.0
    ambient: float = 0.0
    mie_phase: str = "hg"

    def __post_init__(self):
        check_scalar("planet_radius_m", self.planet_radius_m, 0.0, 1e12, lo_open=True)
        if not self.top_radius_m > self.planet_radius_m:
            raise ValueError(f"top_radius_m must be > planet_radius_m (got {self.top_radius_m!r})")
        check_scalar("rayleigh_height_m", self.rayleigh_height_m, 0.0, 1e9, lo_open=True)
        check_scalar("mie_height_m", self.mie_height_m, 0.0, 1e9, lo_open=True)
        check_scalar("mie_g", self.mie_g, -0.999, 0.999, interval="[-0.999, 0.999]")
        check_scalar("sun_angular_radius", self.sun_angular_radius, 0.0, 0.5, lo_open=True)
        check_scalar("rayleigh_scale", self.rayleigh_scale, 0.0, 1e3)
        check_scalar("mie_scale", self.mie_scale, 0.0, 1e3)
        check_scalar("ambient", self.ambient, 0.0, 1e3)
        if self.mie_phase not in ("hg", "cs"):
            raise ValueError(f"mie_phase must be 'hg' or 'cs' (got {self.mie_phase!r})")
        n = len(self.rayleigh_beta)
        for name in ("mie_beta", "mie_extinction", "solar_irradiance", "wavelengths_nm"):
            if len(getattr(self, name)) != n:
                raise ValueError(
                    f"{name} must have {n} channels like rayleigh_beta (got {len(getattr(self, name))})"
                )
        for name in ("rayleigh_beta", "mie_beta", "mie_extinction", "solar_irradiance"):
            for v in getattr(self, name):
                check_scalar(name, v, 0.0, 1e3)
        for b, e in zip(self.mie_beta, self.mie_extinction, strict=True):
            if e < b:
                raise ValueError(f"mie_extinction must be >= mie_beta per channel (got {e!r} < {b!r})")

    @property
    def channels(self) -> int:
        return len(self.rayleigh_beta)

    @property
    def top_m(self) -> float:
        return self.top_radius_m - self.planet_radius_m

    def betas(self):
        """(β_R, β_M, β_M^ext) per channel with the artist scales applied (floats)."""
        return (
            [b * self.rayleigh_scale for b in self.rayleigh_beta],
            [b * self.mie_scale for b in self.mie_beta],
            [b * self.mie_scale for b in self.mie_extinction],
        )

    def spectral(self, wavelengths_nm, solar=None) -> AtmosphereParams:
        """The same atmosphere sampled at ``wavelengths_nm``: β_R ∝ λ⁻⁴ (from its 550 nm value),
        Mie grey; ``solar`` the solar irradiance per wavelength (default: 5778 K blackbody
        normalised to this set's 550 nm value)."""
        lam = np.asarray(wavelengths_nm, dtype=np.float64)
        ref = 13.558e-6 * (self.rayleigh_beta[1] / 13.558e-6)
        br = ref * (550.0 / lam) ** 4
        if solar is None:
            solar = (
                blackbody(lam, 5778.0) / blackbody(np.array([550.0]), 5778.0)[0] * self.solar_irradiance[1]
            )
        n = lam.size
        return replace(
            self,
            rayleigh_beta=tuple(br.tolist()),
            mie_beta=(self.mie_beta[1],) * n,
            mie_extinction=(self.mie_extinction[1],) * n,
            solar_irradiance=tuple(np.asarray(solar).tolist()),
            wavelengths_nm=tuple(lam.tolist()),
        )


def blackbody(lam_nm, temperature):
    """Planck spectral radiance (arbitrary scale) at wavelengths in nm."""
    lam = np.asarray(lam_nm, dtype=np.float64) * 1e-9
    c2 = 1.4387769e-2
    return lam**-5 / np.expm1(c2 / (lam * temperature))


# ====================================================================================== optical depth
def _optical_depth_kernel(ops, h, mu, H, rg, rt):
    """∫ e^{−h/H} ds to the top (see module docstring); +inf (or _FAR when ``far`` given) into the ground."""
    top = rt - rg
    h = ops.clip(h, 0.0, top)
    mu = ops.clip(mu, -1.0, 1.0)
    r = rg + h
    sin_t = ops.sqrt(ops.maximum((1.0 - mu) * (1.0 + mu), 0.0))
    xa2 = r * mu * mu / (1.0 + sin_t)  # r − d, d = r sin θ the impact parameter
    d = r - xa2
    xa = ops.sqrt(xa2)
    base = h - xa2  # altitude of the tangent point (may be < 0: ground hit)
    hits = (mu < 0.0) & (base < 0.0)

    def leg(x0, dx):
        acc = 0.0
        for xn, wn in zip(_GL_X, _GL_W, strict=True):
            x = x0 + 0.5 * dx * (xn + 1.0)
            x2 = x * x
            alt = ops.maximum(base + x2, 0.0)
            num = d + x2
            den = ops.sqrt(ops.maximum(2.0 * d + x2, 1e-30))
            acc = acc + wn * ops.exp(-alt / H) * num / den
        return acc * dx  # Σ w_n f · (dx/2) · 2

    # up-going leg from x_a: x_b² − x_a² = top − h, truncated at Δ(x²) = 40 H
    span2 = ops.minimum(top - h, _TRUNC * H)
    dx_up = span2 / (xa + ops.sqrt(xa2 + span2) + 1e-30)
    up = leg(xa, dx_up)
    # down-going part (μ < 0): twice the leg x ∈ [0, x_a] (integrand largest at x = 0)
    dx_dn = ops.minimum(xa, math.sqrt(_TRUNC) * ops.sqrt(H))
    down = leg(0.0 * xa, dx_dn)
    total = up + ops.select(mu < 0.0, 2.0 * down, 0.0)
    return ops.select(hits, math.inf, total)


def atmosphere_optical_depth(
    altitude_m, cos_zenith, scale_height_m, planet_radius_m=6360e3, top_radius_m=6420e3
):
    """∫ e^{−h/H} ds (metres) from a point at ``altitude_m`` along a direction with cosine
    ``cos_zenith`` to the top of the atmosphere; +inf where the ray hits the ground.

    Domain: altitude ∈ [0, top − planet] (Dr.Jit inputs are clamped), cos_zenith ∈ [−1, 1],
    H > 0. Exact (24-point Gauss–Legendre in x with r = d + x², see module docstring) for
    horizontal rays and at the top (→ 0). Vertical: H(e^{−h/H} − e^{−top/H})."""
    top = float(top_radius_m) - float(planet_radius_m)
    check_scalar("planet_radius_m", planet_radius_m, 0.0, 1e12, lo_open=True)
    check_scalar("top_radius_m", top_radius_m, float(planet_radius_m), 1e12, lo_open=True)
    altitude_m = check_range("altitude_m", altitude_m, 0.0, top)
    cos_zenith = check_range("cos_zenith", cos_zenith, -1.0, 1.0)
    scale_height_m = check_range("scale_height_m", scale_height_m, 0.0, 1e9, lo_open=True)
    rg, rt = float(planet_radius_m), float(top_radius_m)
    return evaluate(
        lambda o, h, m, H: _optical_depth_kernel(o, h, m, H, rg, rt), altitude_m, cos_zenith, scale_height_m
    )


def sun_transmittance(params: AtmosphereParams, altitude_m, cos_zenith):
    """Per-channel transmittance exp(−β_R τ_R − β_M^ext τ_M) to space: list of arrays/floats."""
    br, _, bme = params.betas()
    if isinstance(altitude_m, float) and isinstance(cos_zenith, float):
        # scalar fast path (one value per texture build): the NumPy text on floats, no device round trip
        h = min(max(altitude_m, 0.0), params.top_m)
        mu = min(max(cos_zenith, -1.0), 1.0)
        tr, tm = (
            float(_optical_depth_kernel(NUMPY_OPS, h, mu, H, params.planet_radius_m, params.top_radius_m))
            for H in (params.rayleigh_height_m, params.mie_height_m)
        )
    else:
        tr = atmosphere_optical_depth(
            altitude_m, cos_zenith, params.rayleigh_height_m, params.planet_radius_m, params.top_radius_m
        )
        tm = atmosphere_optical_depth(
            altitude_m, cos_zenith, params.mie_height_m, params.planet_radius_m, params.top_radius_m
        )
    if isinstance(tr, float):
        return [
            math.exp(-(a * tr + b * tm)) if math.isfinite(tr) else 0.0 for a, b in zip(br, bme, strict=True)
        ]
    ex = dr.exp if is_drjit(tr) else np.exp
    return [ex(-(a * tr + b * tm)) for a, b in zip(br, bme, strict=True)]


# ====================================================================================== layers and table
def layer_heights(n: int, params: AtmosphereParams) -> np.ndarray:
    """h_k = −H_R ln(1 − (k/n)(1 − e^{−top/H_R})), k = 0..n (m): equal Rayleigh mass per layer."""
    if int(n) != n or n < 1:
        raise ValueError(f"layers must be an integer >= 1 (got {n!r})")
    k = np.arange(n + 1, dtype=np.float64)
    q = -math.expm1(-params.top_m / params.rayleigh_height_m)
    h = -params.rayleigh_height_m * np.log1p(-(k / n) * q)
    h[-1] = params.top_m
    return h


def _theta_max(params: AtmosphereParams) -> float:
    return 0.5 * math.pi + math.acos(params.planet_radius_m / params.top_radius_m) + math.radians(2.0)


def build_optical_depth_table(params: AtmosphereParams, layers: int, table_size: int, backend: str = "numpy"):
    """Sun optical-depth tables τ_R, τ_M (each (layers + 1) × table_size, metres), rows = layer
    heights, columns = sun zenith angle θ_j = θ_max j/(table_size − 1). Ground-hitting entries hold
    1e12 (transmittance 0). ``backend``: "numpy" (float64 NumPy arrays) or "llvm"/"cuda" (Dr.Jit
    Float arrays, flattened row-major)."""
    if int(table_size) != table_size or table_size < 2:
        raise ValueError(f"table_size must be an integer >= 2 (got {table_size!r})")
    h = layer_heights(layers, params)
    theta = np.linspace(0.0, _theta_max(params), table_size)
    H2, T2 = np.meshgrid(h, theta, indexing="ij")
    out = []
    for H in (params.rayleigh_height_m, params.mie_height_m):
        if backend == "numpy":
            od = np.asarray(
                _optical_depth_kernel(
                    NUMPY_OPS, H2, np.cos(T2), H, params.planet_radius_m, params.top_radius_m
                )
            )
            out.append(np.where(np.isfinite(od), od, _FAR))
        else:
            Float = (dr.cuda if backend == "cuda" else dr.llvm).Float
            od = _optical_depth_kernel(
                DRJIT_OPS,
                Float(H2.ravel()),
                dr.cos(Float(T2.ravel())),
                H,
                params.planet_radius_m,
                params.top_radius_m,
            )
            out.append(dr.select(dr.isfinite(od), od, _FAR))
    return out[0], out[1]


# ====================================================================================== texture kernel
def _bilerp_table(ops, table, u, v, nu, nv):
    """Bilinear lookup in a row-major (nu × nv) table at continuous indices u ∈ [0, nu−1], v."""
    u = ops.clip(u, 0.0, nu - 1.0)
    v = ops.clip(v, 0.0, nv - 1.0)
    u0 = ops.minimum(ops.floor(u), nu - 2.0)
    v0 = ops.minimum(ops.floor(v), nv - 2.0)
    fu, fv = u - u0, v - v0
    i00 = u0 * nv + v0
    t00 = ops.gather(table, i00)
    t01 = ops.gather(table, i00 + 1.0)
    t10 = ops.gather(table, i00 + nv)
    t11 = ops.gather(table, i00 + nv + 1.0)
    return (t00 * (1.0 - fv) + t01 * fv) * (1.0 - fu) + (t10 * (1.0 - fv) + t11 * fv) * fu


def _inscatter_kernel(ops, mu, nu_, h0, sz, cfg, tab_r, tab_m, betas):
    """In-scatter integrals (S_R,c, S_M,c per channel, without phase) along view rays (μ, ν = v·s).

    ``cfg``: dict of floats (n layers, table size, radii, scale heights, θ_max); ``betas``:
    (β_R, β_M, β_M^ext) lists per channel (floats or arrays). The loop over the path slots follows
    the ops namespace: Dr.Jit a symbolic loop (one kernel for every n), JAX ``jax.lax.fori_loop``
    (one traced body: fast to compile, differentiable, used by the fits), NumPy a Python loop."""
    loop = ops.name
    n_int = int(cfg["n"])
    n = cfg["n"]
    rg, top, HR, HM = cfg["rg"], cfg["top"], cfg["HR"], cfg["HM"]
    m, th_max = cfg["m"], cfg["th_max"]
    if loop == "drjit":  # opaque: one compiled kernel for every layer count and table size
        n = dr.opaque(type(mu), n)
        m = dr.opaque(type(mu), m)
    br, bm, bme = betas
    C = len(br)
    q = -math.expm1(-top / HR)
    r0 = rg + h0
    mu = ops.clip(mu, -1.0, 1.0)
    sin_t = ops.sqrt(ops.maximum((1.0 - mu) * (1.0 + mu), 0.0))
    xa2 = r0 * mu * mu / (1.0 + sin_t)  # r0 − d, d = r0 sin θ the impact parameter
    tc = -r0 * mu
    hit = (mu < 0.0) & (xa2 > h0)
    inside = h0 <= top

    def sample(i):
        """(valid, t, h) of path slot i (see module docstring)."""
        i_f = i
        # layer index for crossing slots
        k_dn = n + 1.0 - i_f
        k_up = i_f - (n + 3.0)
        k = ops.select(i_f < n + 2.0, k_dn, k_up)
        k = ops.clip(k, 0.0, n)
        hk = -HR * ops.log(ops.maximum(1.0 - (k / n) * q, 1e-30))
        hk = ops.select(k >= n, top, hk)
        Dk = (hk - h0) + xa2  # r_k − d
        root = ops.sqrt(ops.maximum(Dk, 0.0) * ops.maximum(2.0 * r0 + (hk - h0) - xa2, 0.0))
        t_dn = tc - root
        t_up = tc + root
        is_start = i_f < 0.5
        is_dn = (i_f > 0.5) & (i_f < n + 1.5)
        is_turn = (i_f > n + 1.5) & (i_f < n + 2.5)
        v_start = is_start & inside
        v_dn = is_dn & (mu < 0.0) & (hk < h0) & (Dk >= 0.0)
        v_turn = is_turn & (mu < 0.0) & ~hit
        v_up = (i_f > n + 2.5) & ~hit & (Dk >= 0.0) & ((mu < 0.0) | (hk > h0))
        t = ops.select(is_start, 0.0, ops.select(is_dn, t_dn, ops.select(is_turn, tc, t_up)))
        h = ops.select(is_start, h0, ops.select(is_turn, h0 - xa2, hk))
        valid = v_start | v_dn | v_turn | v_up
        t = ops.maximum(t, 0.0)
        h = ops.clip(h, 0.0, top)
        return valid, t, h

    def integrand(t, h):
        rr = ops.exp(-h / HR)
        rm = ops.exp(-h / HM)
        cs = (r0 * sz + t * nu_) / (rg + h)
        th = ops.acos(ops.clip(cs, -1.0, 1.0))
        u = n * (1.0 - ops.exp(-h / HR)) / q
        v = th / th_max * (m - 1.0)
        far = th > th_max
        sr = ops.select(far, _FAR, _bilerp_table(ops, tab_r, u, v, n + 1.0, m))
        sm = ops.select(far, _FAR, _bilerp_table(ops, tab_m, u, v, n + 1.0, m))
        return rr, rm, sr, sm

    def step(state, i):
        (have, tp, rrp, rmp, odr, odm, fr, fm, S_r, S_m) = state
        valid, t, h = sample(i)
        rr, rm, sr, sm = integrand(t, h)
        pair = valid & have
        dt = ops.select(pair, t - tp, 0.0)
        odr2 = odr + 0.5 * (rr + rrp) * dt
        odm2 = odm + 0.5 * (rm + rmp) * dt
        nfr, nfm, nSr, nSm = [], [], [], []
        for c in range(C):
            tau = br[c] * (odr2 + sr) + bme[c] * (odm2 + sm)
            e = ops.exp(-ops.minimum(tau, 80.0)) * ops.select(tau < 80.0, 1.0, 0.0)
            a_r, a_m = rr * e, rm * e
            nSr.append(S_r[c] + 0.5 * (a_r + fr[c]) * dt)
            nSm.append(S_m[c] + 0.5 * (a_m + fm[c]) * dt)
            nfr.append(ops.select(valid, a_r, fr[c]))
            nfm.append(ops.select(valid, a_m, fm[c]))
        return (
            have | valid,
            ops.select(valid, t, tp),
            ops.select(valid, rr, rrp),
            ops.select(valid, rm, rmp),
            ops.select(valid, odr2, odr),
            ops.select(valid, odm2, odm),
            nfr,
            nfm,
            nSr,
            nSm,
        )

    z = 0.0 * mu
    state = (mu != mu, z, z, z, z, z, [z] * C, [z] * C, [z] * C, [z] * C)
    slots = 2 * n_int + 4
    if loop == "drjit":
        Float = type(mu)
        UInt = dr.uint32_array_t(Float)
        i = UInt(0)
        slots = dr.opaque(UInt, slots)

        def body(i, have, tp, rrp, rmp, odr, odm, fr, fm, S_r, S_m):
            st = step((have, tp, rrp, rmp, odr, odm, fr, fm, S_r, S_m), Float(i))
            return (i + 1, *st)

        out = dr.while_loop(state=(i, *state), cond=lambda i, *rest: i < slots, body=body)
        S_r, S_m = out[-2], out[-1]
        # Every output in one launch: evaluated one at a time (the texture lookup gathers from each), each
        # would run the whole loop again (2·C launches of 2n + 4 steps: 6 for RGB, measured; issue 33).
        dr.eval(S_r, S_m)
    elif loop == "jax":  # one traced body (lax.fori_loop): fast to compile, differentiable (forward mode)
        import jax  # jax: heavy, only the fits run this branch

        state = jax.lax.fori_loop(0, slots, lambda i, st: step(st, i * 1.0), state)
        S_r, S_m = state[-2], state[-1]
    else:
        for i in range(slots):
            state = step(state, float(i))
        S_r, S_m = state[-2], state[-1]
    return [S_r[c] * br[c] for c in range(C)], [S_m[c] * bm[c] for c in range(C)]


# ====================================================================================== the sky
@dataclass
class NishitaSky:
    """A built sky texture. ``rayleigh``/``mie``: per channel, arrays of shape (H, W) (NumPy) or
    flat Dr.Jit arrays (row-major H × W): S_R,c and S_M,c without phase (units of 1/E₀ sr…: the
    radiance is E₀ · P · S). ``el_lo``/``el_hi`` (radians) and ``mapping`` define rows."""

    params: AtmosphereParams
    sun_elevation: float
    altitude_m: float
    width: int
    height: int
    layers: int
    table_size: int
    mapping: str
    el_lo: float
    el_hi: float
    rayleigh: list
    mie: list
    sun_transmittance: list = field(default_factory=list)
    backend: str = "numpy"

    @property
    def sun_direction(self):
        return (math.cos(self.sun_elevation), 0.0, math.sin(self.sun_elevation))


def _texel_directions(width, height, el_lo, el_hi, mapping):
    j = (np.arange(height) + 0.5) / height
    f = j * j if mapping == "sqrt" else j
    el = el_lo + (el_hi - el_lo) * f
    az = 2.0 * math.pi * (np.arange(width) + 0.5) / width
    A, E = np.meshgrid(az, el)
    return A, E


def _horizon_elevation(params, h0):
    """Elevation of the geometric horizon (≤ 0) seen from altitude h0."""
    return -math.acos(min(1.0, params.planet_radius_m / (params.planet_radius_m + h0)))


def build_sky(
    params: AtmosphereParams,
    sun_elevation_deg: float,
    altitude_m: float = 0.0,
    *,
    layers: int = 32,
    width: int = 128,
    height: int = 64,
    table_size: int = 128,
    mapping: str = "linear",
    backend: str = "llvm",
    tables=None,
) -> NishitaSky:
    """Build the Nishita sky texture (the seed's CPU step).

    ``backend``: "llvm"/"cuda" (Dr.Jit: texel directions, both sun tables and one fused kernel over
    all texels with a symbolic loop over the path samples, built on the device by the frozen
    function `_device_build`, so a rebuild replays three kernel launches without re-tracing;
    results stay on the device as flat Float arrays) or "numpy" (the same kernel
    text, float64 NumPy, a Python loop over path samples: the bench's comparison). ``tables``:
    optional prebuilt (τ_R, τ_M) (from `build_optical_depth_table` with the same backend).
    Rows of the texture run from el_lo (the horizon: 0° on the ground, −dip from altitude) to 90°."""
    check_scalar("sun_elevation_deg", sun_elevation_deg, -90.0, 90.0)
    check_scalar("altitude_m", altitude_m, 0.0, 1e6)
    for name, v in (("layers", layers), ("width", width), ("height", height)):
        if int(v) != v or v < 1:
            raise ValueError(f"{name} must be an integer >= 1 (got {v!r})")
    if mapping not in ("linear", "sqrt"):
        raise ValueError(f"mapping must be 'linear' or 'sqrt' (got {mapping!r})")
    if backend not in ("llvm", "cuda", "numpy"):
        raise ValueError(f"backend must be 'llvm', 'cuda' or 'numpy' (got {backend!r})")
    el_s = math.radians(sun_elevation_deg)
    el_lo = _horizon_elevation(params, altitude_m)
    el_hi = 0.5 * math.pi
    cfg = _cfg(params, layers, table_size)
    betas = params.betas()
    h0, sz = float(altitude_m), math.sin(el_s)
    if backend != "numpy" and tables is None:
        Float = (dr.cuda if backend == "cuda" else dr.llvm).Float
        static = (
            int(layers),
            int(width),
            int(height),
            int(table_size),
            mapping == "sqrt",
            el_hi,
            tuple(sorted(cfg.items())),
        )
        # every per-build value in one device array (one upload, no value baked into a kernel)
        values = np.array([h0, sz, math.cos(el_s), el_lo, *betas[0], *betas[1], *betas[2]], dtype=np.float32)
        S_r, S_m = _device_build((*static, params.channels), to_drjit(Float, values))
    else:
        A, E = _texel_directions(width, height, el_lo, el_hi, mapping)
        mu = np.sin(E)
        nu = np.cos(E) * math.cos(el_s) * np.cos(A) + np.sin(E) * math.sin(el_s)
        if tables is None:
            tables = build_optical_depth_table(params, layers, table_size, backend)
        if backend == "numpy":
            S_r, S_m = _inscatter_kernel(
                NUMPY_OPS, mu.ravel(), nu.ravel(), h0, sz, cfg, tables[0].ravel(), tables[1].ravel(), betas
            )
            S_r = [np.asarray(s).reshape(height, width) for s in S_r]
            S_m = [np.asarray(s).reshape(height, width) for s in S_m]
        else:  # prebuilt Dr.Jit tables: the same kernel, traced here (not the frozen device build)
            Float = (dr.cuda if backend == "cuda" else dr.llvm).Float
            S_r, S_m = _inscatter_kernel(
                DRJIT_OPS,
                Float(mu.ravel()),
                Float(nu.ravel()),
                dr.opaque(Float, h0),  # pyright: ignore[reportArgumentType]  # llvm|cuda union
                dr.opaque(Float, sz),  # pyright: ignore[reportArgumentType]  # llvm|cuda union
                cfg,
                tables[0],
                tables[1],
                betas,
            )
    sky = NishitaSky(
        params,
        el_s,
        float(altitude_m),
        int(width),
        int(height),
        int(layers),
        int(table_size),
        mapping,
        el_lo,
        el_hi,
        list(S_r),
        list(S_m),
        backend=backend,
    )
    sky.sun_transmittance = (
        sun_transmittance(params, float(min(altitude_m, params.top_m)), math.sin(el_s))
        if altitude_m <= params.top_m
        else [1.0] * params.channels
    )
    return sky


# One recording per static configuration (sweeps hold many); LRU beyond 64. (The drjit stubs type
# freeze's keyword form without a positional function: a stub limitation.)
@dr.freeze(limit=64, warn_after=1000)  # pyright: ignore[reportCallIssue]
def _device_build(static, values):
    """The whole texture on the device, as one frozen Dr.Jit function (`dr.freeze`): texel
    directions from `dr.arange`, the two sun optical-depth tables and the in-scatter loop.

    The first call per ``static`` configuration (layer count, texture and table size, mapping,
    atmosphere geometry) traces and compiles; later calls replay the recorded kernel launches
    without re-tracing Python, which is what brings a rebuild (a new sun angle, altitude or set of
    scattering coefficients: all device inputs) to the kernels' own run time. ``values``: one Float
    array (h0 in m, sin and cos of the sun elevation, the horizon elevation in radians, then β_R,
    β_M, β_M^ext per channel in m⁻¹); the channel count is part of ``static`` (a frozen function
    replays widths it has not seen, so no size may be read from an input)."""
    layers, width, height, table_size, sqrt_map, el_hi, cfg_items, C = static
    cfg = dict(cfg_items)
    Float = type(values)
    UInt = dr.uint32_array_t(Float)

    def value(i):
        return dr.gather(Float, values, UInt(i))

    h0, sz, cz, el_lo = (value(i) for i in range(4))
    br, bm, bme = ([value(4 + k * C + c) for c in range(C)] for k in range(3))
    # texel directions (as `_texel_directions`): azimuth φ from the sun at texel centres, elevation rows
    idx = dr.arange(UInt, width * height)
    col = Float(idx % width)
    row = Float(idx // width)
    az = (2.0 * math.pi / width) * (col + 0.5)
    f = (row + 0.5) / height
    f = f * f if sqrt_map else f
    el = el_lo + (el_hi - el_lo) * f
    s_el, c_el = dr.sincos(el)
    mu = s_el
    nu = c_el * cz * dr.cos(az) + s_el * sz
    # sun optical-depth tables (as `build_optical_depth_table`): rows = layer heights, columns = θ
    n, m = layers, table_size
    tidx = dr.arange(UInt, (n + 1) * m)
    k = Float(tidx // m)
    j = Float(tidx % m)
    q = -math.expm1(-cfg["top"] / cfg["HR"])
    hk = -cfg["HR"] * dr.log(dr.maximum(1.0 - (k / n) * q, 1e-30))
    hk = dr.select(k >= n, cfg["top"], hk)
    cos_th = dr.cos(j * (cfg["th_max"] / (m - 1)))
    tables = []
    for H in (cfg["HR"], cfg["HM"]):
        od = _optical_depth_kernel(DRJIT_OPS, hk, cos_th, H, cfg["rg"], cfg["rg"] + cfg["top"])
        tables.append(dr.select(dr.isfinite(od), od, _FAR))
    return _inscatter_kernel(DRJIT_OPS, mu, nu, h0, sz, cfg, tables[0], tables[1], (br, bm, bme))


def _cfg(params, layers, table_size):
    return {
        "n": float(layers),
        "m": float(table_size),
        "rg": params.planet_radius_m,
        "top": params.top_m,
        "HR": params.rayleigh_height_m,
        "HM": params.mie_height_m,
        "th_max": _theta_max(params),
    }


# ====================================================================================== per-pixel shading
def _texture_lookup(ops, tex, x, y, W, H):
    """Bilinear lookup, texel centres at (i + ½, j + ½); x wraps (azimuth), y clamps."""
    xf = x - 0.5
    x0 = ops.floor(xf)
    fx = xf - x0
    x0 = x0 - W * ops.floor(x0 / W)
    x1 = ops.select(x0 + 1.0 >= W, 0.0, x0 + 1.0)
    yf = ops.clip(y - 0.5, 0.0, H - 1.0)
    y0 = ops.minimum(ops.floor(yf), max(H - 2.0, 0.0))
    fy = yf - y0
    y1 = ops.minimum(y0 + 1.0, H - 1.0)
    a = ops.gather(tex, y0 * W + x0)
    b = ops.gather(tex, y0 * W + x1)
    c = ops.gather(tex, y1 * W + x0)
    d = ops.gather(tex, y1 * W + x1)
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + d * fx) * fy


def _shade_kernel(ops, dx, dy, dz, tex_r, tex_m, cfg, sun, consts):
    """Per-pixel sky radiance for unit directions (dx, dy, dz) (sun at azimuth 0)."""
    W, H, el_lo, el_hi, sqrt_map = cfg
    sx, sy, sz = sun
    E0, Tsun, g, alpha, ambient, cs = consts
    el = ops.asin(ops.clip(dz, -1.0, 1.0))
    az = ops.atan2(dy, dx)
    az = ops.select(az < 0.0, az + 2.0 * math.pi, az)
    x = az / (2.0 * math.pi) * W
    f = ops.clip((el - el_lo) / (el_hi - el_lo), 0.0, 1.0)
    f = ops.sqrt(f) if sqrt_map else f
    y = f * H
    c = ops.clip(dx * sx + dy * sy + dz * sz, -1.0, 1.0)
    pr = rayleigh_phase_kernel(ops, c) + ambient / (4.0 * math.pi)
    pm = cornette_shanks_phase_kernel(ops, c, g) if cs else hg_phase_kernel(ops, c, g)
    # sun disc: |ω − s|² ≤ 2(1 − cos α)
    d2 = (dx - sx) ** 2 + (dy - sy) ** 2 + (dz - sz) ** 2
    in_sun = d2 <= 4.0 * math.sin(alpha / 2.0) ** 2
    below = el < el_lo
    out = []
    for ch in range(len(E0)):
        sr = _texture_lookup(ops, tex_r[ch], x, y, W, H)
        sm = _texture_lookup(ops, tex_m[ch], x, y, W, H)
        L = E0[ch] * (pr * sr + pm * sm)
        L = L + ops.select(in_sun & ~below, E0[ch] * Tsun[ch] / (math.pi * math.sin(alpha) ** 2), 0.0)
        out.append(ops.select(below, 0.0, ops.maximum(L, 0.0)))
    return out


def shade_sky(sky: NishitaSky, directions, include_sun: bool = True):
    """Per-pixel sky radiance along unit ``directions`` (…, 3) (sun at azimuth 0, +Z up): texture
    lookup + phase + sun disc. NumPy input → NumPy (…, C) on the sky's backend; Dr.Jit Array3f →
    list of C Float arrays. Directions below the texture's horizon give 0 (the ground is not
    modelled)."""
    p = sky.params
    cfg = (float(sky.width), float(sky.height), sky.el_lo, sky.el_hi, sky.mapping == "sqrt")
    sun = sky.sun_direction
    Tsun = list(sky.sun_transmittance) if include_sun else [0.0] * p.channels
    consts = (list(p.solar_irradiance), Tsun, p.mie_g, p.sun_angular_radius, p.ambient, p.mie_phase == "cs")
    if is_drjit(directions):
        return _shade_kernel(
            DRJIT_OPS, directions[0], directions[1], directions[2], sky.rayleigh, sky.mie, cfg, sun, consts
        )
    d = np.asarray(directions, dtype=np.float64)
    shape = d.shape[:-1]
    flat = d.reshape(-1, 3)
    if sky.backend == "numpy":
        out = _shade_kernel(
            NUMPY_OPS,
            flat[:, 0],
            flat[:, 1],
            flat[:, 2],
            [t.ravel() for t in sky.rayleigh],
            [t.ravel() for t in sky.mie],
            cfg,
            sun,
            consts,
        )
        return np.stack([np.asarray(o) for o in out], axis=-1).reshape(*shape, -1)
    Float = type(sky.rayleigh[0])
    out = _shade_kernel(
        DRJIT_OPS,
        Float(flat[:, 0]),
        Float(flat[:, 1]),
        Float(flat[:, 2]),
        sky.rayleigh,
        sky.mie,
        cfg,
        sun,
        consts,
    )
    return np.stack([np.asarray(o, dtype=np.float64) for o in out], axis=-1).reshape(*shape, -1)


def texture_arrays(sky: NishitaSky):
    """The texture as NumPy arrays (C, H, W) for S_R and S_M."""
    if sky.backend == "numpy":
        return np.stack(sky.rayleigh), np.stack(sky.mie)
    shp = (sky.height, sky.width)
    return (
        np.stack([np.asarray(t, dtype=np.float64).reshape(shp) for t in sky.rayleigh]),
        np.stack([np.asarray(t, dtype=np.float64).reshape(shp) for t in sky.mie]),
    )


# ====================================================================================== aerial perspective
def aerial_perspective(
    params: AtmosphereParams,
    sun_elevation_deg: float,
    altitude_m,
    cos_zenith,
    cos_sun,
    distance_m,
    steps: int = 16,
    tables=None,
    layers: int = 32,
    table_size: int = 128,
):
    """Transmittance and single-scattered in-scatter from the viewer (altitude ``altitude_m``) to a
    point at ``distance_m`` along a ray with cosine of zenith angle ``cos_zenith`` and cosine to the
    sun ``cos_sun``: returns (T, L) lists per channel, with L in radiance units (E₀ · …).

    Midpoint rule with ``steps`` equal steps along the segment; the view optical depth is
    accumulated by the midpoint rule; the sun's optical depth comes from the Nishita table
    (``tables`` or a new one with ``layers``/``table_size``), so fog can reuse the sky's table.
    Arrays: NumPy (float64, evaluated through NumPy) or Dr.Jit Floats (lazily)."""
    check_scalar("sun_elevation_deg", sun_elevation_deg, -90.0, 90.0)
    if int(steps) != steps or steps < 1:
        raise ValueError(f"steps must be an integer >= 1 (got {steps!r})")
    distance_m = check_range("distance_m", distance_m, 0.0, 1e9)
    cos_zenith = check_range("cos_zenith", cos_zenith, -1.0001, 1.0001)
    cos_sun = check_range("cos_sun", cos_sun, -1.0001, 1.0001)
    altitude_m = check_range("altitude_m", altitude_m, 0.0, params.top_m)
    args = (altitude_m, cos_zenith, cos_sun, distance_m)
    dr_in = any(is_drjit(a) for a in args)
    backend = "numpy"
    if dr_in:
        Float = type(next(a for a in args if is_drjit(a)))
        backend = "cuda" if dr.backend_v(Float) == dr.JitBackend.CUDA else "llvm"
        altitude_m, cos_zenith, cos_sun, distance_m = (
            a
            if type(a) is Float
            else to_drjit(Float, np.ravel(a))
            if isinstance(a, np.ndarray)
            else Float(float(a))
            for a in args
        )
    if tables is None:
        tables = build_optical_depth_table(params, layers, table_size, backend)
        n_layers, m = layers, table_size
    else:
        n_layers = (
            (np.asarray(tables[0]).size // table_size) - 1
            if not dr_in
            else dr.width(tables[0]) // table_size - 1
        )
        m = table_size
    if not dr_in:
        tables = tuple(np.asarray(t, dtype=np.float64).ravel() for t in tables)
    cfg = _cfg(params, n_layers, m)
    sz = math.sin(math.radians(sun_elevation_deg))
    ops = DRJIT_OPS if dr_in else NUMPY_OPS
    if not dr_in:
        altitude_m, cos_zenith, cos_sun, distance_m = np.broadcast_arrays(
            *[np.asarray(a, dtype=np.float64) for a in (altitude_m, cos_zenith, cos_sun, distance_m)]
        )
    return _aerial_kernel(
        ops, altitude_m, cos_zenith, cos_sun, distance_m, sz, cfg, tables, params, int(steps)
    )


def _aerial_kernel(ops, h0, mu, nu_, dist, sz, cfg, tables, params, steps):
    rg, top, HR, HM = cfg["rg"], cfg["top"], cfg["HR"], cfg["HM"]
    n, m, th_max = cfg["n"], cfg["m"], cfg["th_max"]
    q = -math.expm1(-top / HR)
    br, bm, bme = params.betas()
    C = len(br)
    g = params.mie_g
    mu = ops.clip(mu, -1.0, 1.0)
    nu_ = ops.clip(nu_, -1.0, 1.0)
    r0 = rg + h0
    pr = rayleigh_phase_kernel(ops, nu_) + params.ambient / (4.0 * math.pi)
    pm = (
        cornette_shanks_phase_kernel(ops, nu_, g)
        if params.mie_phase == "cs"
        else hg_phase_kernel(ops, nu_, g)
    )
    dt = dist / steps
    odr = 0.0 * mu
    odm = 0.0 * mu
    L = [0.0 * mu for _ in range(C)]
    for k in range(steps):
        t = (k + 0.5) * dt
        r = ops.sqrt(ops.maximum(r0 * r0 + t * t + 2.0 * r0 * t * mu, 0.0))
        h = ops.clip(r - rg, 0.0, top)
        rr, rm = ops.exp(-h / HR), ops.exp(-h / HM)
        odr_mid = odr + 0.5 * rr * dt
        odm_mid = odm + 0.5 * rm * dt
        cs = (r0 * sz + t * nu_) / ops.maximum(r, 1.0)
        th = ops.acos(ops.clip(cs, -1.0, 1.0))
        u = n * (1.0 - ops.exp(-h / HR)) / q
        v = th / th_max * (m - 1.0)
        far = th > th_max
        sr = ops.select(far, _FAR, _bilerp_table(ops, tables[0], u, v, n + 1.0, m))
        sm = ops.select(far, _FAR, _bilerp_table(ops, tables[1], u, v, n + 1.0, m))
        for c in range(C):
            tau = br[c] * (odr_mid + sr) + bme[c] * (odm_mid + sm)
            e = ops.exp(-ops.minimum(tau, 80.0)) * ops.select(tau < 80.0, 1.0, 0.0)
            L[c] = L[c] + (br[c] * rr * pr + bm[c] * rm * pm) * e * dt
        odr = odr + rr * dt
        odm = odm + rm * dt
    E0 = params.solar_irradiance
    T = [ops.exp(-(br[c] * odr + bme[c] * odm)) for c in range(C)]
    return T, [E0[c] * L[c] for c in range(C)]


# ====================================================================================== spectral → RGB
def _lobe(lam, mu, s1, s2):
    s = np.where(lam < mu, s1, s2)
    return np.exp(-0.5 * ((lam - mu) / s) ** 2)


def cie_xyz_fit(lam_nm):
    """CIE 1931 2° colour-matching functions, multi-lobe Gaussian fit of Wyman, Sloan & Shirley 2013
    ("Simple analytic approximations to the CIE XYZ color matching functions", JCGT 2(2)); (N, 3)."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    x = (
        1.056 * _lobe(lam, 599.8, 37.9, 31.0)
        + 0.362 * _lobe(lam, 442.0, 16.0, 26.7)
        - 0.065 * _lobe(lam, 501.1, 20.4, 26.2)
    )
    y = 0.821 * _lobe(lam, 568.8, 46.9, 40.5) + 0.286 * _lobe(lam, 530.9, 16.3, 31.1)
    z = 1.217 * _lobe(lam, 437.0, 11.8, 36.0) + 0.681 * _lobe(lam, 459.0, 26.0, 13.8)
    return np.stack([x, y, z], axis=-1)


XYZ_TO_SRGB = np.array(
    [[3.240479, -1.537150, -0.498535], [-0.969256, 1.875991, 0.041556], [0.055648, -0.204043, 1.057311]]
)
"""CIE XYZ → linear sRGB (ITU-R BT.709 primaries, D65 white), to Mitsuba's digits (its ``xyz_to_srgb``,
which the reference's film conversion uses: tests/test_nishita_sky_reference.py checks the two agree)."""


def spectral_to_srgb(spectra: np.ndarray, lam_nm, white=None, white_rgb=None) -> np.ndarray:
    """Linear sRGB of spectra (…, N) sampled at ``lam_nm`` (rectangle rule over the samples).
    With ``white`` (N,) and ``white_rgb`` (3,): channels are rescaled so that the spectrum
    ``white`` maps to ``white_rgb`` (von Kries in sRGB), which puts a spectral sky in the same
    units as the 3-wavelength RGB sky lit by ``white_rgb``."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    w = np.gradient(lam) if lam.size > 1 else np.ones(1)
    M = XYZ_TO_SRGB @ (cie_xyz_fit(lam) * w[:, None]).T  # (3, N)
    rgb = np.asarray(spectra, dtype=np.float64) @ M.T
    if white is not None and white_rgb is not None:
        wr = M @ np.asarray(white, dtype=np.float64)
        rgb = rgb * (np.asarray(white_rgb) / wr)
    return rgb


def lookup_components(sky: NishitaSky, directions):
    """The texture's (S_R, S_M) at unit ``directions`` (…, 3) NumPy, bilinear, as NumPy (…, C) each
    (no phase, no E₀): the inputs of a per-pixel shader, e.g. for fitting artist parameters."""
    d = np.asarray(directions, dtype=np.float64)
    shape = d.shape[:-1]
    flat = d.reshape(-1, 3)
    el = np.arcsin(np.clip(flat[:, 2], -1, 1))
    az = np.mod(np.arctan2(flat[:, 1], flat[:, 0]), 2 * math.pi)
    W, H = float(sky.width), float(sky.height)
    f = np.clip((el - sky.el_lo) / (sky.el_hi - sky.el_lo), 0.0, 1.0)
    f = np.sqrt(f) if sky.mapping == "sqrt" else f
    x, y = az / (2 * math.pi) * W, f * H
    R, M = texture_arrays(sky)
    outr = [_texture_lookup(NUMPY_OPS, R[c].ravel(), x, y, W, H) for c in range(R.shape[0])]
    outm = [_texture_lookup(NUMPY_OPS, M[c].ravel(), x, y, W, H) for c in range(M.shape[0])]
    below = (el < sky.el_lo)[:, None]
    return (
        np.where(below, 0.0, np.stack(outr, -1)).reshape(*shape, -1),
        np.where(below, 0.0, np.stack(outm, -1)).reshape(*shape, -1),
    )


# ====================================================================================== methods
@dataclass(frozen=True)
class SkySetting:
    """The numerical setting of a Nishita sky texture (what the experiment sweeps).

    ``layers`` n (atmosphere layers), texture ``width`` × ``height`` (azimuth × elevation texels),
    sun optical-depth ``table_size``, row ``mapping`` ("linear": the seed's uniform elevation rows;
    "sqrt": more rows near the horizon) and ``wavelengths``: 0 for the atmosphere's own channels (the
    3-wavelength RGB sky), N > 0 for the spectral variant (N wavelengths uniform on 400–700 nm, β_R ∝ λ⁻⁴,
    converted by `spectral_to_srgb` and white-balanced so that the sun maps to the RGB set's E₀)."""

    layers: int = 32
    width: int = 128
    height: int = 64
    table_size: int = 128
    mapping: str = "linear"
    wavelengths: int = 0

    def build_keywords(self) -> dict:
        """The keywords of `build_sky` for this setting."""
        return {
            "layers": self.layers,
            "width": self.width,
            "height": self.height,
            "table_size": self.table_size,
            "mapping": self.mapping,
        }

    def spectral_wavelengths(self) -> np.ndarray:
        """The spectral variant's wavelengths in nm (N uniform on 400–700 nm; empty for RGB)."""
        return np.linspace(400.0, 700.0, self.wavelengths) if self.wavelengths else np.zeros(0)

    def radiance(
        self,
        atmosphere: AtmosphereParams,
        sun_elevation_deg: float,
        directions,
        *,
        altitude_m: float = 0.0,
        backend: str = "llvm",
    ) -> np.ndarray:
        """Sky radiance (…, C) along NumPy unit ``directions`` (…, 3): `build_sky` with this setting,
        then `shade_sky`. RGB settings include the sun disc; the spectral variant excludes it and returns
        linear sRGB (von Kries-balanced: the solar spectrum ↦ ``atmosphere.solar_irradiance``), clipped
        at 0 as a display would (twilight colours can leave the sRGB gamut)."""
        if not self.wavelengths:
            sky = build_sky(
                atmosphere, sun_elevation_deg, altitude_m, backend=backend, **self.build_keywords()
            )
            return np.asarray(shade_sky(sky, directions))  # NumPy directions: a NumPy array (…, C)
        lam = self.spectral_wavelengths()
        spectral = atmosphere.spectral(lam)
        sky = build_sky(spectral, sun_elevation_deg, altitude_m, backend=backend, **self.build_keywords())
        L = np.asarray(shade_sky(sky, directions, include_sun=False))
        rgb = spectral_to_srgb(
            L, lam, white=np.asarray(spectral.solar_irradiance), white_rgb=atmosphere.solar_irradiance
        )
        return np.maximum(rgb, 0.0)


def nishita_sky_kernel(
    ops,
    dx,
    dy,
    dz,
    texel_mu,
    texel_nu,
    tau_r,
    tau_m,
    sun_x,
    sun_z,
    *,
    atmosphere: AtmosphereParams,
    setting: SkySetting,
    altitude_m: float,
    rayleigh_scale=1.0,
    mie_scale=1.0,
    mie_g=None,
    ambient=None,
    solar_scale=1.0,
):
    """The sky radiance along unit directions (dx, dy, dz), the texture rebuilt from its inputs, sun excluded.

    The texture step of `build_sky` (`_inscatter_kernel` over the texels with cosines ``texel_mu``
    (zenith) and ``texel_nu`` (to the sun), sun optical-depth tables ``tau_r``, ``tau_m`` from
    `build_optical_depth_table`, flattened) followed by the per-pixel step of `shade_sky` (bilinear
    lookup, Rayleigh + Mie phase, no sun disc): L_c = E₀,c [(P_R + A/(4π)) S_R,c + P_M(g) S_M,c] with
    β_R → s_R β_R and β_M, β_M^ext → s_M β_M, s_M β_M^ext. Artist parameters ``rayleigh_scale`` s_R,
    ``mie_scale`` s_M (multiplying ``atmosphere``'s own scales), ``mie_g`` g and ``ambient`` A (None:
    ``atmosphere``'s value) and ``solar_scale`` s_E (E₀ → s_E E₀: the sun's intensity, e.g. a user's sky in
    other units); they may be arrays (JAX tracers in a fit). (``sun_x``, 0, ``sun_z``): the
    unit sun direction. ``setting`` (layers, table and texture size, mapping) and ``altitude_m`` (the
    viewer) are static. Returns a tuple of C arrays (one per channel).

    Inputs have different lengths (pixels, texels, table entries): run it on an ops namespace
    (``METHODS[id](ops, inputs)``, or `rtfit.fitting.fit_method`), not through `Method.evaluate`, which
    broadcasts NumPy inputs to one shape. `sky_kernel_inputs` computes the inputs."""
    p = atmosphere
    cfg = _cfg(p, setting.layers, setting.table_size)
    br, bm, bme = p.betas()
    betas = (
        [b * rayleigh_scale for b in br],
        [b * mie_scale for b in bm],
        [b * mie_scale for b in bme],
    )
    S_r, S_m = _inscatter_reused(
        ops,
        (texel_mu, texel_nu, tau_r, tau_m),
        (altitude_m, sun_z, rayleigh_scale, mie_scale, setting, p),
        lambda: _inscatter_kernel(ops, texel_mu, texel_nu, altitude_m, sun_z, cfg, tau_r, tau_m, betas),
    )
    el_lo = _horizon_elevation(p, altitude_m)
    shape = (float(setting.width), float(setting.height), el_lo, 0.5 * math.pi, setting.mapping == "sqrt")
    consts = (
        list(p.solar_irradiance),
        [0.0] * p.channels,
        p.mie_g if mie_g is None else mie_g,
        p.sun_angular_radius,
        p.ambient if ambient is None else ambient,
        p.mie_phase == "cs",
    )
    L = _shade_kernel(ops, dx, dy, dz, S_r, S_m, shape, (sun_x, 0.0, sun_z), consts)
    return tuple(c * solar_scale for c in L)  # L is linear in E₀


INSCATTER_KEEP = 8
"""In-scatter textures `_inscatter_reused` keeps for one set of array inputs (least recently used dropped).
SciPy's 3-point Jacobian evaluates x ± h per parameter in declaration order (``rayleigh_scale``,
``mie_scale``, ``mie_g``, ``ambient``): by ``mie_g``'s turn the last texture is x + h of ``mie_scale``, and
only a store holding the centre's (five distinct textures: x, x ± h twice) serves ``mie_g`` and ``ambient``
from it. A seed texture in float64 is 8192 texels × 6 channels × 8 bytes (0.4 MB)."""

_INSCATTER_HELD: list = []
"""[array inputs, {scalar key: (S_R, S_M)}]: the Dr.Jit in-scatters of `nishita_sky_kernel` on the last array
inputs it saw (`_inscatter_reused`), oldest first."""
MEMOS = (_INSCATTER_HELD,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _scalar_key(v):
    """``v`` as a float for `_inscatter_reused`'s key (a Python number, a dataclass or setting as itself, an
    evaluated Dr.Jit array of width 1 — a fit's ``dr.opaque`` parameter — by its value); None otherwise."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v)
    if dr.is_array_v(v):
        a: Any = v
        ok = dr.width(a) == 1 and a.state in (dr.VarState.Evaluated, dr.VarState.Literal)
        return float(a[0]) if ok else None
    return v if isinstance(v, (AtmosphereParams, SkySetting)) else None


def _inscatter_reused(ops, arrays: tuple, scalars: tuple, compute):
    """``compute()`` (the in-scatter texture: all of the kernel's cost), or on Dr.Jit an earlier call's result
    when the array inputs are the same objects and the scalars (viewer, sun, ``rayleigh_scale``,
    ``mie_scale``, setting, atmosphere) the same values (up to `INSCATTER_KEEP` of them per array inputs). A
    fit's Dr.Jit run (`Method.fit_ops`) converts its inputs once, and SciPy's Jacobian changes one parameter
    at a time: ``mie_g`` and ``ambient`` only shade the texture, so 4 of every 9 evaluations reuse the
    centre's — the same evaluated arrays, bit-identical results (issue 33). The inputs are held (no object
    id is reused while they are); new array inputs drop the textures of the old."""
    if ops.name != "drjit":
        return compute()
    key = tuple(_scalar_key(v) for v in scalars)
    if any(k is None for k in key):
        return compute()
    same = (
        bool(_INSCATTER_HELD)
        and len(_INSCATTER_HELD[0]) == len(arrays)
        and all(a is b for a, b in zip(_INSCATTER_HELD[0], arrays, strict=True))
    )
    if not same:
        _INSCATTER_HELD[:] = [arrays, {}]
    held: dict = _INSCATTER_HELD[1]
    if key in held:
        S_r, S_m = held[key] = held.pop(key)  # most recently used last
        return [*S_r], [*S_m]
    S_r, S_m = compute()
    held[key] = ([*S_r], [*S_m])
    while len(held) > INSCATTER_KEEP:
        del held[next(iter(held))]
    return S_r, S_m


def sky_kernel_inputs(
    atmosphere: AtmosphereParams,
    sun_elevation_deg: float,
    directions,
    setting: SkySetting,
    altitude_m: float = 0.0,
) -> dict:
    """The inputs of `nishita_sky_kernel` (NumPy float64) for NumPy unit ``directions`` (…, 3) (flattened):
    pixel directions, the texel cosines of ``setting``'s texture seen from ``altitude_m``, the sun tables
    and the sun direction at ``sun_elevation_deg``."""
    check_scalar("sun_elevation_deg", sun_elevation_deg, -90.0, 90.0)
    el_s = math.radians(sun_elevation_deg)
    el_lo = _horizon_elevation(atmosphere, altitude_m)
    A, E = _texel_directions(setting.width, setting.height, el_lo, 0.5 * math.pi, setting.mapping)
    tau_r, tau_m = build_optical_depth_table(atmosphere, setting.layers, setting.table_size)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    return {
        "dx": d[:, 0],
        "dy": d[:, 1],
        "dz": d[:, 2],
        "texel_mu": np.sin(E).ravel(),
        "texel_nu": (np.cos(E) * math.cos(el_s) * np.cos(A) + np.sin(E) * math.sin(el_s)).ravel(),
        "tau_r": np.asarray(tau_r).ravel(),
        "tau_m": np.asarray(tau_m).ravel(),
        "sun_x": math.cos(el_s),
        "sun_z": math.sin(el_s),
    }


SEED_SETTING = SkySetting()
"""The seed's setting (000:2178-2187): n = 32 layers, 128×64 texture, 128-entry sun table, linear rows."""
FINE_SETTING = SkySetting(layers=128, width=512, height=256, table_size=512, mapping="sqrt")
"""The converged model of the sweep: n = 128, 512×256 with √ horizon rows, 512-entry table."""

_SKY_INPUTS = (
    Input("dx", "1", "pixel direction x (sun at azimuth 0, +Z up)"),
    Input("dy", "1", "pixel direction y"),
    Input("dz", "1", "pixel direction z (sin of the elevation)"),
    Input("texel_mu", "1", "cos of the zenith angle of each texel centre (flattened H×W)"),
    Input("texel_nu", "1", "cos of each texel centre's angle to the sun"),
    Input("tau_r", "m", "Rayleigh sun optical-depth table ((n + 1) × table_size, flattened)"),
    Input("tau_m", "m", "Mie sun optical-depth table"),
    Input("sun_x", "1", "sun direction x = cos(sun elevation)"),
    Input("sun_z", "1", "sun direction z = sin(sun elevation)"),
)
_SKY_FORMULA = "L_c = E₀,c [(P_R + A/4π) S_R,c + P_M(g) S_M,c], S from n layers (trapezoid), bilinear texture"


def _sky_method(id, label, setting, description, **kw) -> Method:
    return Method(
        id=id,
        label=label,
        kernel=nishita_sky_kernel,
        inputs=_SKY_INPUTS,
        fixed={
            "atmosphere": AtmosphereParams(),
            "setting": setting,
            "altitude_m": 0.0,
            **kw.pop("fixed", {}),
        },
        storage=2 * (setting.wavelengths or 3),  # floats per texel: S_R and S_M per channel
        # the fits' residual: the Dr.Jit run (one compiled loop) instead of NumPy's 2n + 4 Python steps over
        # every texel per evaluation (issue 33; the same text, float64)
        fit_ops="drjit",
        quantity="sky_radiance",
        formula=_SKY_FORMULA,
        source="Nishita et al. 1993; CryEngine 2 (seed 000:2178-2187, 002:130-164)",
        description=description,
        **kw,
    )


METHODS = method_table(
    [
        _sky_method(
            "nishita-seed",
            "Nishita, seed setting (n=32, 128×64)",
            SEED_SETTING,
            "the seed's texture: 32 layers, 128×64 texels, 128-entry sun table",
        ),
        _sky_method(
            "nishita-fine",
            "Nishita, n=128, 512×256",
            FINE_SETTING,
            "the converged texture: 128 layers, 512×256 texels (√ horizon rows), 512-entry table",
        ),
        _sky_method(
            "nishita-spectral",
            "Nishita spectral (16 λ → sRGB)",
            replace(SEED_SETTING, wavelengths=16),
            "the seed setting over 16 wavelengths (λ⁻⁴ Rayleigh), CIE 1931 → linear sRGB",
        ),
        _sky_method(
            "nishita-fitted",
            "Nishita, fitted artist parameters",
            SEED_SETTING,
            "the seed setting with artist parameters fitted to the multiple-scattering sky",
            # ambient ≥ 0: a negative isotropic term would make dark pixels negative (docs/nishita-sky.md)
            params={
                "rayleigh_scale": Param(1.0, 0.3, 3.0, unit="1", description="multiplies beta_R"),
                "mie_scale": Param(
                    1.0, 0.05, 20.0, unit="1", description="multiplies beta_M and beta_M_ext (Mie density)"
                ),
                "mie_g": Param(0.8, 0.0, 0.95, unit="1", description="Henyey-Greenstein asymmetry"),
                "ambient": Param(
                    0.3,
                    0.0,
                    10.0,
                    unit="1",
                    description="isotropic multiple-scattering term: P_R -> P_R + ambient/(4 pi)",
                ),
            },
        ),
    ]
)
"""The family's methods (`rtfit.realtime.methods`): one kernel text (`nishita_sky_kernel`), the setting as
data. Fixed keywords ``atmosphere`` (the Bruneton set, `AtmosphereParams()`), ``setting`` and
``altitude_m``: replace them (``dataclasses.replace(method, fixed={...})``) for another atmosphere or
viewer. The artist parameters of ``nishita-fitted`` are `AtmosphereParams` fields of the same names, so a
fitted set is ``replace(atmosphere, **values)``."""
