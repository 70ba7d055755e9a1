r"""Aerial perspective matched to the sky: the Nishita atmosphere and an exponential height fog together.

What is new here (the rest is `rtfit.realtime.height_fog` and `rtfit.realtime.nishita_sky`, imported, not
copied): the single-scattering integral along a view segment through **both** media, with the sun
attenuated by both, and the pieces that the real-time fog blend freezes.

Frame and units
---------------
Metres, 1/m. A local flat frame: the camera at (0, 0, z₀) above flat ground z = 0, +Z up; the fog's height
is world z (as `height_fog`), the atmosphere's altitude is the height above the spherical planet whose
centre is (0, 0, −R_g): for x = (x, y, z),

    h(x) = (x² + y² + z(2R_g + z))/(R_g + r),  r = |x − centre|        (no cancellation in float32)

and the sun's cosine of zenith there μ_s = s·(x − centre)/r. Radiance in the units of the solar
irradiance E₀ per steradian (as `nishita_sky`). The sun is a point of irradiance E₀,c in direction s.

The integral (per channel c)
----------------------------
σ_t,c(x) = β_R,c ρ_R(h) + β^ext_M,c ρ_M(h) + b e^(−c_f z) (fog extinction grey, fog albedo 1);
T_c(t) = exp(−∫₀ᵗ σ_t,c); T_sun,c(x) = exp(−β_R,c τ_R(h, μ_s) − β^ext_M,c τ_M(h, μ_s) − τ_fog(z → sun)),
with τ_R, τ_M from `nishita_sky.atmosphere_optical_depth` (+∞ where the planet occludes the sun: T_sun = 0
exactly, no NaN) and τ_fog from `height_fog.height_fog_optical_depth_ray` (D = ∞; +∞ for a sun at or
below the flat horizon). With ν = v·s,

    L_c = L₀,c T_c(D) + S_c,   S_c = E₀,c ∫₀ᴰ T_c(t) T_sun,c(x(t)) [β_R,c ρ_R P_R(ν) + β_M,c ρ_M P_M(ν)
                                                                  + b e^(−c_f z) P_HG(ν, g_f)] dt.

Written as a source function J_c = E₀,c T_sun,c [σ_s P]_c / σ_t,c, S_c = ∫ σ_t,c T_c J_c dt; if J_c is
constant along the ray, S_c = J_c (1 − T_c(D)) and the fog blend L = L₀ T + C (1 − T) is exact with C = J.

Quadrature: t = D u³ (panels dense at the camera, where a dense fog's integrand lives), ``panels``
uniform panels in u, 4-point Gauss–Legendre per panel. T_c(t): the fog part in closed form
(`height_fog.height_fog_optical_depth`, exact), the atmosphere part from the panels before plus a 4-point
Gauss–Legendre rule on [panel start, t] (the densities are smooth on the 1–8 km scale heights).

Variants (`aerial_scattering`'s outputs, one pass over the same nodes)
---------------------------------------------------------------------
* ``S`` — the integral above (the exact single scattering);
* ``S_sun_frozen`` — T_sun,c(x) replaced by its value at the camera (the sun attenuated as at the camera
  all along the ray: simplification (1) of docs/aerial-perspective.md);
* ``S_grey`` — one extinction for every channel (that of the ``grey_channel``, 550 nm) in the view
  transmittance T (the sun's path stays per channel: its reddening is the sky model's, spectral in the seed
  too); simplification (3) alone;
* ``T``, ``T_grey`` — T_c(D) per channel and with the grey extinction;
* ``J_cam`` — the source function at the camera for the ray's direction (the constant a blend would need).

The real-time blends themselves are `height_fog`'s text: `fog_blend` (L₀ T + C (1 − T) per channel),
and the seed's horizon colour (`horizon_colour`: Nishita sky texture samples of the lowest rows averaged,
the phase per pixel, seed 000:2247-2254, 002:224-290) via `height_fog.fog_colour_phase`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import numpy as np

from .arrays import check_scalar
from .height_fog import METHODS as FOG_METHODS
from .height_fog import (
    apply_fog,
    fog_colour_phase,
    height_fog_optical_depth,
    height_fog_optical_depth_ray,
)
from .methods import Input, Method, method_table
from .nishita_sky import AtmosphereParams, atmosphere_optical_depth, build_sky, lookup_components
from .phase import cornette_shanks_phase_kernel, hg_phase_kernel, rayleigh_phase_kernel

__all__ = [
    "GREY_CHANNEL",
    "FogLayer",
    "aerial_scattering",
    "fog_blend",
    "horizon_colour",
    "horizon_fog_colour",
    "sun_direction",
    "sun_transmittance_at",
]

GREY_CHANNEL = 1
"""The channel whose extinction the grey variant uses for all (G: 550 nm)."""
_GL4_X, _GL4_W = (tuple(float(v) for v in a) for a in np.polynomial.legendre.leggauss(4))
_BIG = 1e30  # stands for an infinite optical depth inside products (0·∞ would be NaN)


@dataclass(frozen=True)
class FogLayer:
    """Exponential height fog: extinction b·e^(−c·z) (1/m), albedo 1, Henyey–Greenstein ``g``."""

    density: float = 2e-4
    falloff: float = 4e-3
    g: float = 0.6

    def __post_init__(self):
        check_scalar("density", self.density, 0.0, 1e3)
        check_scalar("falloff", self.falloff, 0.0, 1e3)
        check_scalar("g", self.g, -0.99, 0.99)


def sun_direction(elevation_deg: float, azimuth_deg: float) -> tuple[float, float, float]:
    """Unit direction to the sun; azimuth from +y (the view axis) towards +x, elevation above z = 0."""
    check_scalar("sun_elevation_deg", elevation_deg, -90.0, 90.0)
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))


def _altitude(ops, x, y, z, rg):
    """(h, r): height above the sphere of radius rg centred at (0, 0, −rg), written without cancellation."""
    rz = rg + z
    r = ops.sqrt(x * x + y * y + rz * rz)
    h = (x * x + y * y + z * (2.0 * rg + z)) / (rg + r)
    return ops.maximum(h, 0.0), r


def _sun_tau(ops, x, y, z, atm: AtmosphereParams, sun, fog: FogLayer):
    """(τ per channel, occluded): the sun's optical depth from x through atmosphere and fog."""
    rg, rt = atm.planet_radius_m, atm.top_radius_m
    h, r = _altitude(ops, x, y, z, rg)
    h = ops.minimum(h, rt - rg)
    mu = ops.clip((sun[0] * x + sun[1] * y + sun[2] * (rg + z)) / r, -1.0, 1.0)
    tr = atmosphere_optical_depth(h, mu, atm.rayleigh_height_m, rg, rt)
    tm = atmosphere_optical_depth(h, mu, atm.mie_height_m, rg, rt)
    occluded = tr > _BIG
    tr = ops.select(occluded, 0.0, tr)
    tm = ops.select(occluded, 0.0, tm)
    tf = height_fog_optical_depth_ray(ops.maximum(z, 0.0), sun[2], math.inf, fog.density, fog.falloff)
    tf = ops.minimum(tf, _BIG)
    br, _, bme = atm.betas()
    return [br[c] * tr + bme[c] * tm + tf for c in range(atm.channels)], occluded


def sun_transmittance_at(ops, x, y, z, atm: AtmosphereParams, sun, fog: FogLayer):
    """T_sun,c at points (x, y, z) (m, the local frame): a list per channel, 0 where the planet occludes."""
    tau, occ = _sun_tau(ops, x, y, z, atm, sun, fog)
    return [ops.select(occ, 0.0, ops.exp(-t)) for t in tau]


def _densities(ops, x, y, z, atm):
    h, _ = _altitude(ops, x, y, z, atm.planet_radius_m)
    return ops.exp(-h / atm.rayleigh_height_m), ops.exp(-h / atm.mie_height_m)


def aerial_scattering(
    ops,
    z0,
    dx,
    dy,
    dz,
    distance,
    *,
    atmosphere: AtmosphereParams,
    sun: tuple,
    fog: FogLayer,
    panels: int = 32,
    grey_channel: int = GREY_CHANNEL,
) -> dict:
    """The single-scattering integral and its variants along rays from (0, 0, z₀) in unit directions
    (dx, dy, dz) over ``distance`` (m, finite): a dict of per-channel lists ``S``, ``S_sun_frozen``,
    ``S_grey``, ``T``, ``T_grey``, ``J_cam`` (module docstring). ``ops``: `NUMPY_OPS` (float64 reference)
    or `DRJIT_OPS` (Dr.Jit Floats: the same text on the device; inputs must then be Dr.Jit arrays)."""
    if int(panels) != panels or panels < 1:
        raise ValueError(f"panels must be an integer >= 1 (got {panels!r})")
    atm = atmosphere
    C = atm.channels
    br, bm, bme = atm.betas()
    gc = grey_channel
    E0 = atm.solar_irradiance
    nu = ops.clip(dx * sun[0] + dy * sun[1] + dz * sun[2], -1.0, 1.0)
    p_r = rayleigh_phase_kernel(ops, nu) + atm.ambient / (4.0 * math.pi)
    p_m = (
        cornette_shanks_phase_kernel(ops, nu, atm.mie_g)
        if atm.mie_phase == "cs"
        else hg_phase_kernel(ops, nu, atm.mie_g)
    )
    p_f = hg_phase_kernel(ops, nu, fog.g)
    zero = 0.0 * z0 + 0.0 * dz
    b, cf = fog.density, fog.falloff

    # at the camera: T_sun and the source function per direction
    cam_tau, cam_occ = _sun_tau(ops, zero, zero, z0 + zero, atm, sun, fog)
    cam_sun = [ops.select(cam_occ, 0.0, ops.exp(-t)) for t in cam_tau]
    rr0, rm0 = _densities(ops, zero, zero, z0 + zero, atm)
    sf0 = b * ops.exp(-cf * z0) + zero
    j_cam = []
    for c in range(C):
        st = br[c] * rr0 + bme[c] * rm0 + sf0
        ss = br[c] * rr0 * p_r + bm[c] * rm0 * p_m + sf0 * p_f
        j_cam.append(E0[c] * cam_sun[c] * ss / ops.maximum(st, 1e-30))

    acc_r = zero  # ∫₀^{panel start} ρ_R dt
    acc_m = zero
    S = [zero for _ in range(C)]
    S_frozen = [zero for _ in range(C)]
    S_grey = [zero for _ in range(C)]
    device = ops.name == "drjit"
    for k in range(panels):
        ua, ub = k / panels, (k + 1) / panels
        if device:  # one compiled kernel for every panel: the panel bounds as opaque values, not literals
            ua, ub = dr.opaque(type(zero), ua), dr.opaque(type(zero), ub)
        ta = distance * ua * ua * ua
        tb = distance * ub * ub * ub
        half = 0.5 * (tb - ta)
        pr_sum, pm_sum = zero, zero
        for xn, wn in zip(_GL4_X, _GL4_W, strict=True):
            t = ta + half * (xn + 1.0)
            px, py, pz = t * dx, t * dy, z0 + t * dz
            pz = ops.maximum(pz, 0.0)
            rr, rm = _densities(ops, px, py, pz, atm)
            pr_sum = pr_sum + wn * rr
            pm_sum = pm_sum + wn * rm
            # atmosphere optical depth from the panel start to t (4-point rule on [ta, t])
            hh = 0.5 * (t - ta)
            part_r, part_m = zero, zero
            for xm, wm in zip(_GL4_X, _GL4_W, strict=True):
                s = ta + hh * (xm + 1.0)
                qr, qm = _densities(ops, s * dx, s * dy, ops.maximum(z0 + s * dz, 0.0), atm)
                part_r = part_r + wm * qr
                part_m = part_m + wm * qm
            od_r = acc_r + hh * part_r
            od_m = acc_m + hh * part_m
            od_f = height_fog_optical_depth(z0 + zero, pz, t + zero, b, cf)
            tau_sun, occ = _sun_tau(ops, px, py, pz, atm, sun, fog)
            sf = b * ops.exp(-cf * pz)
            w = wn * half
            for c in range(C):
                tv = ops.exp(-(br[c] * od_r + bme[c] * od_m + od_f))
                tvg = ops.exp(-(br[gc] * od_r + bme[gc] * od_m + od_f))
                ts = ops.select(occ, 0.0, ops.exp(-tau_sun[c]))
                ss = br[c] * rr * p_r + bm[c] * rm * p_m + sf * p_f
                S[c] = S[c] + w * E0[c] * tv * ts * ss
                S_frozen[c] = S_frozen[c] + w * E0[c] * tv * cam_sun[c] * ss
                S_grey[c] = S_grey[c] + w * E0[c] * tvg * ts * ss
        acc_r = acc_r + half * pr_sum
        acc_m = acc_m + half * pm_sum
        if device:  # evaluate panel by panel: one mid-size kernel instead of a graph of all panels
            dr.eval(acc_r, acc_m, S, S_frozen, S_grey)
    end_z = ops.maximum(z0 + distance * dz, 0.0)
    od_f = height_fog_optical_depth(z0 + zero, end_z, distance + zero, b, cf)
    T = [ops.exp(-(br[c] * acc_r + bme[c] * acc_m + od_f)) for c in range(C)]
    T_grey = [ops.exp(-(br[gc] * acc_r + bme[gc] * acc_m + od_f)) for _ in range(C)]
    return {"S": S, "S_sun_frozen": S_frozen, "S_grey": S_grey, "T": T, "T_grey": T_grey, "J_cam": j_cam}


def horizon_colour(
    atmosphere: AtmosphereParams,
    sun_elevation_deg: float,
    *,
    altitude_m: float = 0.0,
    rows: int = 2,
    width: int = 128,
    height: int = 64,
    layers: int = 32,
) -> tuple[list[float], list[float]]:
    """The seed's horizon average (000:2247-2254, 002:224-290): the Nishita sky texture's in-scatter
    without phase (S_R, S_M per channel, times E₀) averaged over all azimuths of its ``rows`` lowest rows
    (elevations from the horizon up to ``rows``/``height`` of 90°). Returns (H_R, H_M), RGB lists in
    radiance·sr units: the per-pixel colour is ``fog_colour_phase(cos θ, H_R/(4π), H_M/(4π), g)``."""
    check_scalar("rows", rows, 1, height)
    sky = build_sky(
        atmosphere,
        sun_elevation_deg,
        altitude_m,
        layers=layers,
        width=width,
        height=height,
        table_size=128,
        mapping="linear",
        backend="numpy",
    )
    el = sky.el_lo + (np.arange(rows) + 0.5) / height * (sky.el_hi - sky.el_lo)
    az = (np.arange(width) + 0.5) / width * 2.0 * math.pi
    A, E = np.meshgrid(az, el)
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1)
    s_r, s_m = lookup_components(sky, dirs)
    E0 = np.asarray(atmosphere.solar_irradiance)
    return (
        (s_r.reshape(-1, s_r.shape[-1]).mean(0) * E0).tolist(),
        (s_m.reshape(-1, s_m.shape[-1]).mean(0) * E0).tolist(),
    )


def horizon_fog_colour(h_r, h_m, cos_sun, g: float):
    """C_c(θ) = H_R,c P_R(θ) + H_M,c P_HG(θ, g) per channel (the seed's per-pixel phase on the horizon
    average): `height_fog.fog_colour_phase` with colours H/(4π)."""
    return fog_colour_phase(
        cos_sun, [v / (4.0 * math.pi) for v in h_r], [v / (4.0 * math.pi) for v in h_m], g
    )


def fog_blend(l0, t, colour):
    """L = L₀ T + C (1 − T) per channel with a per-channel T: `height_fog.apply_fog` (the one text of the
    blend) channel by channel; ``l0``, ``t``, ``colour``: lists of channel arrays (NumPy)."""
    return [
        apply_fog(np.asarray(l0[c])[..., None], np.asarray(t[c]), np.asarray(colour[c])[..., None])[..., 0]
        for c in range(len(l0))
    ]


# ============================================================================= methods (data): the audit
# The blends a renderer draws aerial perspective with, as rows of `rtfit audit` on a scene where a sky
# (an environment emitter) and a medium meet (`rtfit.experiments.audit_aerial_perspective`): the height-fog
# shading models' kernels (`height_fog.METHODS`, the one text of the blend), each with its fog colour taken
# from the scene's sky as the experiment's ladder takes it (docs/aerial-perspective.md).
_CONST, _PHASE = FOG_METHODS["const"], FOG_METHODS["phase"]
DOMAINS = {
    "z0": (0.0, 100.0),
    "z1": (0.0, 100.0),
    "distance": (100.0, 1000.0),
    "cos_sun": (-1.0, 1.0),
    **{f"{k}_{ch}": (0.0, 10.0) for k in ("l0", "j") for ch in "rgb"},
}
"""The blends' input domains (units of the inputs; ``rtfit bench`` and the three-library test draw from them):
heights within 100 below stretches of 100–1000, so that |z1 − z0| ≤ D always holds when drawn apart."""


def _with_domains(inputs) -> tuple[Input, ...]:
    """The height-fog kernels' inputs with `DOMAINS` (the height-fog family's own table leaves them open)."""
    return tuple(replace(i, domain=DOMAINS[i.name]) for i in inputs)


_SOURCE = tuple(
    Input(f"j_{ch}", "W/m²/sr", f"the sky's single-scattering source function at the camera, {ch} channel")
    for ch in "rgb"
)


def _camera_source_kernel(ops, z0, z1, distance, l0_r, l0_g, l0_b, j_r, j_g, j_b, b, c):
    """``const``'s blend with the colour the source function J(camera, v) per pixel (step (1))."""
    return _CONST.kernel(ops, z0, z1, distance, l0_r, l0_g, l0_b, b, c, j_r, j_g, j_b)


METHODS = method_table(
    [
        Method(
            id="camera-source",
            label="fog blend, C = the sky's source function at the camera per direction (1)",
            kernel=_camera_source_kernel,
            inputs=_with_domains((*_CONST.inputs, *_SOURCE)),
            params={k: _CONST.params[k] for k in ("b", "c")},
            quantity="fogged_radiance",
            formula="L = L₀·T(b, c) + J(v)·(1 − T), J(v) = a·∫ L_sky(ω) p(v·ω) dω (unshadowed, unattenuated)",
            source="rtfit (the experiment's camera-source step; height_fog const kernel)",
        ),
        Method(
            id="horizon-flat",
            label="fog blend, C = the sky's horizon average (1 + 2, no phase)",
            kernel=_CONST.kernel,
            inputs=_with_domains(_CONST.inputs),
            params=_CONST.params,
            quantity="fogged_radiance",
            formula="L = L₀·T(b, c) + H·(1 − T), H the sky's radiance averaged over its horizon band",
            source="seed 000:2247-2254 (the horizon average; height_fog const kernel)",
        ),
        Method(
            id="horizon-phase",
            label="fog blend, C = the sky's horizon average × 4π·p_HG(θ, g) per pixel (1 + 2)",
            kernel=_PHASE.kernel,
            inputs=_with_domains(_PHASE.inputs),
            params=_PHASE.params,
            quantity="fogged_radiance",
            formula="L = L₀·T(b, c) + (C₀ + H·4π·p_HG(θ, g))·(1 − T), C₀ = 0, g the medium's",
            source="seed 000:2247-2254, 002:224-290 (per-pixel phase on the horizon average; height_fog "
            "phase kernel)",
        ),
    ]
)
"""The aerial-perspective blends on a scene's own sky and medium (`rtfit audit`): ``camera-source`` (the
source function of the sky's light at the camera, step (1) of the ladder), ``horizon-flat`` and
``horizon-phase`` (the seed's horizon average, without and with the per-pixel phase). A user's sky has no
Rayleigh/Mie split, so the seed's H_R·P_R + H_M·P_HG becomes H·4π·p_HG (the medium is the Mie part)."""
