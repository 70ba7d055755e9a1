r"""Sky ambient from the sky's SH along the bent normal: the seed's radiance lookup × AO, the SH irradiance at
the bent normal or at the normal × AO, and the SH irradiance of the visible cone (the ``sh-sky-bent-normal``
family).

Conventions and units
---------------------
* ``coeffs``: the sky's SH L2 projection, 27 floats L_lm = ∫ L_sky Y_lm dω (W/m²), channel-major (R, G, B),
  index k = l(l + 1) + m, real SH without the Condon–Shortley phase: what `rtfit.realtime.irradiance_bases`
  reads (its ``sh-l2`` row) and an engine's sky probe stores (the seed's "3rd order spherical harmonics" are
  these 9 coefficients per channel: bands l = 0, 1, 2).
* ``nx, ny, nz``: the surface's unit normal n; ``bx, by, bz``: its unit **bent normal** b, the mean
  unoccluded direction of the hemisphere (what an engine bakes with the AO); both normalised by the SH
  kernel (a zero vector reads the sphere average, the DC term).
* ``ao`` = V = (1/π)∫_{H(n)} V(ω)(n·ω) dω ∈ [0, 1], the cosine-weighted unoccluded fraction (1: open sky);
  ``aperture`` = r_a ∈ [0, π/2] (rad), the half-angle of the visible cone about b, acos(1 − V_u) with V_u
  the visible fraction of the hemisphere (the ambient-aperture family's cap, 000:2660-2668).
* Every row gives an **irradiance** (W/m², per RGB channel, the tuple (R, G, B)): the quantity
  ``sky_irradiance_sh``, compared with E = ∫ V(ω) L_sky(ω) max(n·ω, 0) dω, the sky's irradiance with the
  scene's occlusion. A Lambertian surface of albedo ρ then reflects ρE/π.

Formulas (L_SH(d) = Σ_{l≤2} Σ_m L_lm Y_lm(d), the radiance of the SH sky; Â = (π, 2π/3, π/4) the clamped
cosine's band factors, E_SH(d) = Σ_l Â_l Σ_m L_lm Y_lm(d) its irradiance, Ramamoorthi & Hanrahan 2001):

* ``seed-radiance-bent`` — the seed (000:425-432, Isidoro & Sander, "Animated skybox rendering and lighting
  techniques", ch. 2 §2.2, line 429): ambient "is achieved by looking up the color of the light coming from
  the sky in the direction of the surface's bent normal": **E ≈ s·π·L_SH(b)·V^p**, s = p = 1 as printed.
  Reading/errata: (1) the seed prints no formula; the "color of the light coming from the sky" in a
  direction is a **radiance** (the SH reconstruction itself, not cosine-convolved): an engine multiplies it
  by the albedo ρ, i.e. its irradiance-equivalent is π·L_SH(b) (ρ·L = ρ(πL)/π), the irradiance of a
  uniform hemisphere of that radiance; (2) the AO factor V is not in the seed's words (Figure 4's lit
  scene is lost): it is the issue's reading (the bent normal is baked with the occlusion, and engines
  multiply the two); (3) "3rd order" = bands 0..2 (9 coefficients). Free knobs an artist tunes: the overall
  scale s and the AO exponent p. Known bias: the radiance lookup keeps the full L2 band (Â_2/π = ¼ of it
  in the irradiance), so a sky varying in band 2 (a bright horizon ring) is over-weighted at the bent
  normal, and a uniform sky is exact only on an open plane.
* ``irradiance-bent`` — the SH **irradiance** at the bent normal × AO, **E ≈ s·E_SH(b)·V^p** (Landis 2002,
  "Production-ready global illumination", SIGGRAPH course 16 §5: the diffuse-convolved environment looked
  up along the bent normal, times the occlusion; the classic bent-normal form of engines).
* ``irradiance-normal`` — the SH irradiance at the plain normal × AO, **E ≈ s·E_SH(n)·V^p** (the classic
  probe × AO of every engine without bent normals).
* ``cone-bent`` — the SH irradiance of the **visible cone**: the clamped cosine about b restricted to the cone
  of half-angle r_a about b, convolved with the SH sky (Funk–Hecke of the zonal kernel h(t) = t on
  t ∈ [cos r_a, 1]): **E ≈ s·Σ_l Â_l f_l(c) Σ_m L_lm Y_lm(b)**, c = cos r_a, with
  f_l(c) = (2π/Â_l)∫_c^1 t P_l(t) dt: f_0 = 1 − c², f_1 = 1 − c³, f_2 = (1 − c²)(1 + 3c²) (`cone_factors`;
  f = 1 at r_a = π/2: ``irradiance-bent`` without AO). The ambient-aperture idea (Oat & Sander 2006,
  000:2620-2800: the visibility as a cap about the bent normal) applied to an SH sky, as Klehm et al.
  2011 ("Bent normals and cones in screen-space", VMV) light a bent cone from a pre-filtered environment.
  Reading: the cosine is taken about b (the cone's axis) so that the kernel stays zonal; the n-vs-b tilt is
  what the audit measures. No AO factor (the cone is the occlusion).

Each row evaluates the irradiance-bases family's ``sh-l2`` kernel itself (`rtfit.realtime.irradiance_bases`,
one text): the radiance reads it on the coefficients L_lm·π/Â_l, the cone on L_lm·f_l(c); nothing here
re-types an SH basis. Float32 rewrite: the same text runs in float32 on Dr.Jit; the band factors are
products of c, no cancellation beyond 1 − c² at c → 1 (an aperture of 0: f → 0, exact).

Guards (reasons): every result is floored at 0 (an SH L2 ring below zero would subtract light; an engine
clamps its ambient the same way); V is clamped to [0, 1] and floored at 1e-30 before V^p (0^p's derivative
ln V is −∞ for a fit: the floor keeps it finite, 1e-30^p ≈ 0); p is floored at 0, s is as given (bounded by
its Param); r_a is clamped to [0, π/2] (a cap wider than the hemisphere is not one).

Domain: unit normals and bent normals (any non-zero vector), V ∈ [0, 1], r_a ∈ [0, π/2], any finite SH
coefficients. Dr.Jit arrays are never checked (no host sync); NumPy and float inputs of the public
functions are.
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import DRJIT_OPS, check_range, clamp01, evaluate, split3
from .irradiance_bases import A_HAT
from .irradiance_bases import METHODS as BASIS_METHODS
from .methods import Input, Method, Param, method_table

__all__ = ["cone_factors", "sh_cone_irradiance", "sh_radiance"]

_TINY = 1e-30
_SH_L2 = BASIS_METHODS["sh-l2"]
_BAND = (0, 1, 1, 1, 2, 2, 2, 2, 2)
_RADIANCE_SCALE = tuple(math.pi / A_HAT[band] for band in range(3))
"""π/Â_l = (1, 3/2, 4): the sh-l2 irradiance kernel on L_lm·π/Â_l is π·L_SH."""


# ===================================================================================== kernels (ops text)
def _sh_l2(ops, x, y, z, coeffs, band_scale):
    """The ``sh-l2`` row's kernel (E = Σ_l Â_l Σ_m L_lm Y_lm) on the coefficients L_lm·band_scale[l] (floats
    or per-element arrays): (R, G, B)."""
    scaled = [coeffs[c * 9 + k] * band_scale[_BAND[k]] for c in range(3) for k in range(9)]
    return _SH_L2.kernel(ops, nx=x, ny=y, nz=z, coeffs=scaled, **_SH_L2.fixed)


def _occlusion(ops, ao, scale, ao_power):
    """s·V^p with V clamped to [0, 1] and floored at 1e-30 (module docstring: guards)."""
    v = ops.maximum(clamp01(ops, ao), _TINY)
    return scale * ops.power(v, ops.maximum(ao_power, 0.0))


def _nonnegative(ops, rgb, factor):
    return tuple(ops.maximum(ch * factor, 0.0) for ch in rgb)


def _radiance_bent_kernel(ops, bx, by, bz, ao, coeffs, scale, ao_power):
    """The seed's s·π·L_SH(b)·V^p (000:429)."""
    return _nonnegative(
        ops, _sh_l2(ops, bx, by, bz, coeffs, _RADIANCE_SCALE), _occlusion(ops, ao, scale, ao_power)
    )


def _irradiance_bent_kernel(ops, bx, by, bz, ao, coeffs, scale, ao_power):
    """s·E_SH(b)·V^p (Landis 2002)."""
    return _nonnegative(
        ops, _sh_l2(ops, bx, by, bz, coeffs, (1.0, 1.0, 1.0)), _occlusion(ops, ao, scale, ao_power)
    )


def _irradiance_normal_kernel(ops, nx, ny, nz, ao, coeffs, scale, ao_power):
    """s·E_SH(n)·V^p: the probe × AO."""
    return _nonnegative(
        ops, _sh_l2(ops, nx, ny, nz, coeffs, (1.0, 1.0, 1.0)), _occlusion(ops, ao, scale, ao_power)
    )


def _cone_factors_kernel(ops, aperture):
    """(f_0, f_1, f_2) of the cosine-weighted cone of half-angle r_a (clamped to [0, π/2])."""
    c = ops.cos(ops.clip(aperture, 0.0, 0.5 * math.pi))
    c = ops.maximum(c, 0.0)  # cos(π/2) rounds to ±6e-17
    c2 = c * c
    return (1.0 - c2, 1.0 - c2 * c, (1.0 - c2) * (1.0 + 3.0 * c2))


def _cone_bent_kernel(ops, bx, by, bz, aperture, coeffs, scale):
    """s·Σ_l Â_l f_l(cos r_a) Σ_m L_lm Y_lm(b): the SH sky through the visible cone about b."""
    f = _cone_factors_kernel(ops, aperture)
    return _nonnegative(ops, _sh_l2(ops, bx, by, bz, coeffs, f), scale)


# ===================================================================================== public API
def _table(coeffs) -> list[float]:
    c = np.asarray(coeffs, np.float64)
    if c.shape == (9, 3):
        c = c.T.reshape(-1)
    if c.shape != (27,) or not np.all(np.isfinite(c)):
        raise ValueError(f"coeffs must be 27 finite floats (channel-major) or (9, 3) (got shape {c.shape})")
    return [float(v) for v in c]


def _rgb(out):
    if isinstance(out[0], np.ndarray):
        return np.stack(out, axis=-1)
    if isinstance(out[0], float):
        return np.array(out, dtype=np.float64)
    return out


def _opaque(ops, table, like):
    if ops is not DRJIT_OPS:
        return table
    import drjit as dr  # (the Dr.Jit run only: opaque size-1 arrays, one compiled kernel per call shape)

    return [dr.opaque(type(like), v) for v in table]


def sh_radiance(coeffs, direction):
    """L_SH(d) = Σ_{l≤2} Σ_m L_lm Y_lm(d) (W·m⁻²·sr⁻¹, RGB) of the SH L2 sky ``coeffs`` ((9, 3), or 27 floats
    channel-major) at ``direction`` (..., 3): the seed's lookup (without π and AO). (..., 3) for NumPy input,
    a length-3 array for one direction, (R, G, B) lazy arrays for Dr.Jit input."""
    table = _table(coeffs)
    x, y, z = split3(direction, "direction")

    def kernel(ops, x, y, z):
        rgb = _sh_l2(ops, x, y, z, _opaque(ops, table, x), _RADIANCE_SCALE)
        return tuple(ch * (1.0 / math.pi) for ch in rgb)

    return _rgb(evaluate(kernel, x, y, z))


def cone_factors(aperture):
    """(f_0, f_1, f_2) with Σ_l Â_l f_l Σ_m L_lm Y_lm(b) the irradiance through the cone of half-angle
    ``aperture`` (rad, [0, π/2]) about b, cosine about b: 1 − c², 1 − c³, (1 − c²)(1 + 3c²), c = cos r_a."""
    a = check_range("aperture", aperture, 0.0, 0.5 * math.pi + 1e-6, interval="[0, π/2]")
    return evaluate(_cone_factors_kernel, a)


def sh_cone_irradiance(coeffs, direction, aperture):
    """The ``cone-bent`` row at s = 1 (W/m², RGB): the SH L2 sky ``coeffs`` through the cone of half-angle
    ``aperture`` (rad, [0, π/2]) about ``direction`` (..., 3), cosine about the axis; floored at 0."""
    table = _table(coeffs)
    a = check_range("aperture", aperture, 0.0, 0.5 * math.pi + 1e-6, interval="[0, π/2]")
    x, y, z = split3(direction, "direction")

    def kernel(ops, x, y, z, a):
        return _cone_bent_kernel(ops, x, y, z, a, _opaque(ops, table, x), 1.0)

    return _rgb(evaluate(kernel, x, y, z, a))


# ===================================================================================== methods as data
_BENT = tuple(
    Input(
        f"b{c}",
        "1",
        f"bent normal {c}: the mean unoccluded direction (normalised by the kernel)",
        (-1.0, 1.0),
    )
    for c in "xyz"
)
_NORMAL = tuple(
    Input(f"n{c}", "1", f"surface normal {c} (world frame, +Z up; normalised by the kernel)", (-1.0, 1.0))
    for c in "xyz"
)
_AO = Input("ao", "1", "V: cosine-weighted unoccluded fraction of the hemisphere (1: open sky)", (0.0, 1.0))
_APERTURE = Input(
    "aperture",
    "rad",
    "r_a = acos(1 − V_u): half-angle of the visible cone about the bent normal",
    (0.0, 0.5 * math.pi),
)
_SH = Input("coeffs", "W/m²", "27 floats: the sky's SH coefficients L_lm = ∫ L Y_lm dω, l ≤ 2, channel-major")
_POINT = tuple(
    Input(f"p{c}", "m", f"visible point {c} (world frame; no row reads it)", (-1e3, 1e3)) for c in "xyz"
)
INPUTS = (*_NORMAL, *_BENT, _AO, _APERTURE, _SH, *_POINT)
"""The quantity ``sky_irradiance_sh``'s inputs (the point for a user's formula: no shipped row reads it)."""
_SCALE = Param(1.0, 1e-3, 100.0, unit="1", description="overall scale s (1: the form as printed)")
_POWER = Param(1.0, 0.05, 8.0, unit="1", description="AO exponent p of V^p (1: as printed)")
_AO_PARAMS = {"scale": _SCALE, "ao_power": _POWER}
_Q = "sky_irradiance_sh"
_SEED = "Isidoro & Sander 2006, animated skybox ch. 2 §2.2 (seed 000:425-432, the lookup 000:429)"

METHODS = method_table(
    [
        Method(
            "seed-radiance-bent",
            "Seed: SH radiance at the bent normal × AO",
            _radiance_bent_kernel,
            inputs=(*_BENT, _AO, _SH),
            params=_AO_PARAMS,
            storage=27,
            quantity=_Q,
            formula="E ≈ s·π·L_SH(b)·V^p, L_SH(b) = Σ_{l≤2} L_lm Y_lm(b); s = p = 1 as printed",
            source=_SEED,
            description="the radiance (not irradiance) of the SH sky along b; π·L: its irradiance-equivalent",
        ),
        Method(
            "irradiance-bent",
            "SH irradiance at the bent normal × AO",
            _irradiance_bent_kernel,
            inputs=(*_BENT, _AO, _SH),
            params=_AO_PARAMS,
            storage=27,
            quantity=_Q,
            formula="E ≈ s·E_SH(b)·V^p, E_SH = Σ_l Â_l L_lm Y_lm, Â = (π, 2π/3, π/4)",
            source="Landis 2002, Production-ready global illumination (SIGGRAPH course 16 §5); R&H 2001",
        ),
        Method(
            "irradiance-normal",
            "SH irradiance at the normal × AO",
            _irradiance_normal_kernel,
            inputs=(*_NORMAL, _AO, _SH),
            params=_AO_PARAMS,
            storage=27,
            quantity=_Q,
            formula="E ≈ s·E_SH(n)·V^p",
            source="Ramamoorthi & Hanrahan 2001 (the probe) × AO",
        ),
        Method(
            "cone-bent",
            "SH irradiance through the visible cone",
            _cone_bent_kernel,
            inputs=(*_BENT, _APERTURE, _SH),
            params={"scale": _SCALE},
            storage=27,
            quantity=_Q,
            formula="E ≈ s·Σ_l Â_l f_l(cos r_a) L_lm Y_lm(b), f = (1 − c², 1 − c³, (1 − c²)(1 + 3c²))",
            source="Oat & Sander 2006 (000:2620-2800, the visible cap) on an SH sky; Klehm et al. 2011 "
            "(bent cones)",
            description="the clamped cosine about b inside the cone r_a = acos(1 − V_u); no AO factor",
        ),
    ]
)
