"""Irradiance bases for distant lighting: Valve's ambient cube and spherical harmonics (L1, L2, windowed).

All functions return irradiance E(n) = ∫ L(ω) max(n·ω, 0) dω in W/m² (per RGB channel) for a distant
environment of radiance L (W·m⁻²·sr⁻¹), evaluated at unit normals n (world frame, +Z up).

Ambient cube (seed 000:2471-2501, Valve's listing): six RGB colours C in the order +x, −x, +y, −y, +z, −z,

    E(n) = n_x² C[x sign] + n_y² C[y sign] + n_z² C[z sign]      (sign: n_i < 0 picks the − entry).

Valve fills C with the irradiance at the six axes; `fit_ambient_cube_nnls` gives the cube that minimises
the squared irradiance error over the sphere of normals with C ≥ 0. 18 floats per probe.

Spherical harmonics. **Sign convention: real SH without the Condon–Shortley phase** (the graphics
convention of Ramamoorthi & Hanrahan 2001 and Sloan's "Stupid SH tricks"), index k = l(l + 1) + m:

    Y00 = 0.282095                       Y1,−1 = 0.488603 y   Y10 = 0.488603 z   Y11 = 0.488603 x
    Y2,−2 = 1.092548 xy   Y2,−1 = 1.092548 yz   Y20 = 0.315392 (3z² − 1)   Y21 = 1.092548 xz
    Y22 = 0.546274 (x² − y²)

Dr.Jit's ``dr.sh_eval`` includes the Condon–Shortley phase (−1)^m: its odd-m entries (k = 1, 3, 5, 7)
have the opposite sign (checked in tests). Projection L_lm = ∫ L(ω) Y_lm(ω) dω; irradiance by the
Funk–Hecke convolution with the clamped cosine (R&H): E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n) with
Â0 = π, Â1 = 2π/3, Â2 = π/4, and a window w_l (1 unless windowed). L1 stores 4 coefficients per channel
(12 floats), L2 9 (27 floats).

For a distant light of unit irradiance at normal incidence along d, L_lm = Y_lm(d)
(`sh9_from_directional`), and the L2 irradiance at angle θ from d is
1/4 + cos θ/2 + (5/16)(3cos²θ − 1)/2 (R&H); L1 drops the last term. A uniform disc of angular radius α
and normal-incidence irradiance E⊥ has (Funk–Hecke, ∫_{cos α}^1 P_l) L_00 = 2E⊥/(1 + cos α)·Y00(d),
L_1m = E⊥ Y_1m(d), L_2m = E⊥ cos α Y_2m(d) (`sh9_from_disk`).

Windows against ringing (negative irradiance opposite a bright light): Hann w_l = ½(1 + cos(πl/(L+1))),
Lanczos w_l = sinc(l/(L+1)) = sin(πl/(L+1))/(πl/(L+1)), and Sloan's w_l = 1/(1 + λ l²(l + 1)²) with the
smallest λ that removes the negative irradiance of a given environment (`fit_window_lambda`).

Geomerics L1 (Hazel, "Reconstructing diffuse lighting from SH", as written in Frostbite-style code):
with the linear irradiance E_lin(n) = R0 + 2 R1·n (R0 the sphere-average irradiance, R1 half the
linear coefficient vector), r = |R1|/R0 ∈ [0, 1], q = ½(1 + R̂1·n), p = 1 + 2r, a = (1 − r)/(1 + r):
E(n) = R0 (a + (1 − a)(p + 1) q^p). It keeps the mean R0, is never negative, and matches E_lin to first
order in r (its L1 band is 3R0(1 − a)p/(p + 2), = 2|R1| for small r).

Normals: need not be unit length (they are normalised). A zero-length normal in NumPy/float input raises a
ValueError; in Dr.Jit input (not checked, to avoid a host sync) it returns the basis's sphere-average
irradiance (SH: the DC term; cube: the mean of the six colours; Geomerics: R0). NaN normals raise for NumPy.

Methods as data: `METHODS` holds one `rtfit.realtime.methods.Method` per basis (``cube-valve``,
``cube-nnls``, ``sh-l1``, ``sh-l1-geomerics``, ``sh-l2``, ``sh-l2-hann``, ``sh-l2-lanczos``,
``sh-l2-lambda``, and ``quadrature``, the exact row), each with its kernel, inputs and units, free
parameters (λ), ``storage`` (floats stored per probe, RGB) and formula. A basis kernel takes the normal
components ``nx, ny, nz`` and ``coeffs``, the probe's stored floats channel-major (R, G, B), and applies the
convolution Â_l and the window w_l itself, so the stored floats are what an engine keeps. Run a method
on an ops namespace with ``method(ops, basis_inputs(method, coeffs, normal), params)`` (e.g. the NumPy text,
``NUMPY_OPS``), or validated and dispatched with `basis_irradiance`. The wrappers (`sh_irradiance`,
`ambient_cube_irradiance`, …) are that with a fixed method.

Everything here runs on Dr.Jit (LLVM/CUDA) and NumPy from one kernel text (`rtfit.realtime.arrays`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import drjit as dr
import numpy as np

from .arrays import DRJIT_OPS, NUMPY_OPS, evaluate, is_drjit, safe_div, split3
from .methods import Input, Method, Param, method_table
from .nonnegative_lsq import nnls_columns

__all__ = [
    "A_HAT",
    "CUBE_AXES",
    "CUBE_ORDER",
    "METHODS",
    "SH_C",
    "SH_MAX_ORDER",
    "WINDOWS",
    "ZH3_LUMINANCE",
    "ambient_cube_from_axes",
    "ambient_cube_irradiance",
    "basis_inputs",
    "basis_irradiance",
    "clamped_cosine_band",
    "cube_design_matrix",
    "disk_zonal_factors",
    "fibonacci_sphere",
    "fit_ambient_cube_nnls",
    "fit_ambient_cubes_nnls",
    "fit_window_lambda",
    "latlong_directions",
    "latlong_samples",
    "sh4_irradiance",
    "sh4_irradiance_geomerics",
    "sh9_basis",
    "sh9_from_constant",
    "sh9_from_directional",
    "sh9_from_disk",
    "sh9_irradiance",
    "sh_basis",
    "sh_from_constant",
    "sh_from_directional",
    "sh_from_disk",
    "sh_irradiance",
    "sh_project_latlong",
    "sh_project_samples",
    "sh_window",
    "unit_normal",
    "zh3_from_sh",
]

# Normalisation constants of the real SH basis (no Condon–Shortley phase), in the order `_band_basis` uses.
SH_C = (
    0.28209479177387814,  # 0: 1/(2√π)                       Y00
    0.4886025119029199,  # 1: √3/(2√π)                       Y1m
    1.0925484305920792,  # 2: √15/(2√π)                      Y2,−2 Y2,−1 Y21
    0.31539156525252005,  # 3: √5/(4√π)                      Y20
    0.5462742152960396,  # 4: √15/(4√π)                      Y22
    math.sqrt(35.0 / (2.0 * math.pi)) / 4.0,  # 5: Y3,±3
    math.sqrt(105.0 / math.pi) / 2.0,  # 6: Y3,−2
    math.sqrt(21.0 / (2.0 * math.pi)) / 4.0,  # 7: Y3,±1
    math.sqrt(7.0 / math.pi) / 4.0,  # 8: Y30
    math.sqrt(105.0 / math.pi) / 4.0,  # 9: Y32
    3.0 * math.sqrt(35.0 / math.pi) / 4.0,  # 10: Y4,−4
    3.0 * math.sqrt(35.0 / (2.0 * math.pi)) / 4.0,  # 11: Y4,±3
    3.0 * math.sqrt(5.0 / math.pi) / 4.0,  # 12: Y4,−2
    3.0 * math.sqrt(5.0 / (2.0 * math.pi)) / 4.0,  # 13: Y4,±1
    3.0 / (16.0 * math.sqrt(math.pi)),  # 14: Y40
    3.0 * math.sqrt(5.0 / math.pi) / 8.0,  # 15: Y42
    3.0 * math.sqrt(35.0 / math.pi) / 16.0,  # 16: Y44
)
SH_MAX_ORDER = 4
"""The highest SH band the kernels evaluate (L4: 25 coefficients per channel)."""


def clamped_cosine_band(band: int) -> float:
    """Â_l = 2π ∫₀¹ t P_l(t) dt: the band-l factor of the convolution with the clamped cosine max(cos θ, 0)
    (Funk–Hecke; Ramamoorthi & Hanrahan 2001, eq. 8 with Â_l = √(4π/(2l+1)) A_l of their normalisation).

    Â_0 = π, Â_1 = 2π/3; for odd l > 1, Â_l = 0: t P_l(t) is then even, so ∫₀¹ = ½ ∫₋₁¹ t P_l dt = 0
    (t = P_1 is orthogonal to P_l). For even l ≥ 2, writing t P_l = ((l + 1) P_{l+1} + l P_{l−1})/(2l + 1),
    using ∫₀¹ P_k dt = (P_{k−1}(0) − P_{k+1}(0))/(2k + 1) for odd k and P_{l±2}(0) in terms of P_l(0):

        ∫₀¹ t P_l dt = −P_l(0) / ((l + 2)(l − 1)),   P_l(0) = (−1)^(l/2) l! / (2^l ((l/2)!)²),
        Â_l = 2π (−1)^(l/2 − 1) / ((l + 2)(l − 1)) · l! / (2^l ((l/2)!)²)

    (Â_2 = π/4, Â_4 = −π/24, Â_6 = π/64). Exact binomial arithmetic, any l ≥ 0; tested against scipy
    quadrature of the integral."""
    l = int(band)  # noqa: E741 (l is the band index of every formula here)
    if l < 0:
        raise ValueError(f"band l must be >= 0 (got {band})")
    if l == 0:
        return math.pi
    if l == 1:
        return 2.0 * math.pi / 3.0
    if l % 2:
        return 0.0
    sign = -1.0 if (l // 2) % 2 == 0 else 1.0  # (−1)^(l/2 − 1)
    return 2.0 * math.pi * sign / ((l + 2) * (l - 1)) * (math.comb(l, l // 2) / 2.0**l)


A_HAT = tuple(clamped_cosine_band(b) for b in range(SH_MAX_ORDER + 1))
"""Â_0..Â_4 = (π, 2π/3, π/4, 0, −π/24): the clamped-cosine band factors (`clamped_cosine_band`)."""
CUBE_ORDER = ("+x", "-x", "+y", "-y", "+z", "-z")
CUBE_AXES = (
    (1.0, 0.0, 0.0),
    (-1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0),
    (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
)
"""The unit directions of `CUBE_ORDER` (where Valve's cube samples the irradiance)."""
WINDOWS = ("none", "hann", "lanczos", "lambda")
_BAND = tuple(b for b in range(SH_MAX_ORDER + 1) for _ in range(2 * b + 1))  # band of index k
_TINY = 1e-30
ZH3_LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights of linear sRGB: the shared ZH3 axis is the L1 direction of the weighted sum."""
_SQRT3 = math.sqrt(3.0)  # |L1|/L00 of a single direction: the largest ratio a non-negative environment has
_R1_SCALE = 0.5 * A_HAT[1] * SH_C[1]  # Geomerics: R1 = ½ Â1 Y1 (L11, L1−1, L10)


# =========================================================================================== kernels
def unit_normal(ops, nx, ny, nz):
    """(x, y, z, valid): n/|n| and whether |n|² > 1e-30 (invalid normals become 0); shared by the bases'
    kernels here and in `rtfit.realtime.spherical_gaussians` / `rtfit.realtime.ambient_dice`."""
    n2 = nx * nx + ny * ny + nz * nz
    valid = n2 > _TINY
    inv = 1.0 / ops.sqrt(ops.maximum(n2, _TINY))
    return (
        ops.select(valid, nx * inv, 0.0),
        ops.select(valid, ny * inv, 0.0),
        ops.select(valid, nz * inv, 0.0),
        valid,
    )


def _band_basis(x, y, z, l):  # noqa: E741 (the band index of every formula here)
    """The 2l + 1 real SH basis values Y_lm, m = −l..l, of band ``l`` ≤ 4 at unit (x, y, z) (any array
    type; no Condon–Shortley phase, so every entry is a positive constant times its polynomial). The
    polynomials use x² + y² + z² = 1 (e.g. Y3,±1 ∝ (5z² − 1) instead of (4z² − x² − y²))."""
    c = SH_C
    if l == 0:
        return (c[0] + 0.0 * x,)
    if l == 1:
        return (c[1] * y, c[1] * z, c[1] * x)
    if l == 2:
        return (c[2] * x * y, c[2] * y * z, c[3] * (3.0 * z * z - 1.0), c[2] * x * z, c[4] * (x * x - y * y))
    x2, y2, z2 = x * x, y * y, z * z
    if l == 3:
        return (
            c[5] * y * (3.0 * x2 - y2),
            c[6] * x * y * z,
            c[7] * y * (5.0 * z2 - 1.0),
            c[8] * z * (5.0 * z2 - 3.0),
            c[7] * x * (5.0 * z2 - 1.0),
            c[9] * z * (x2 - y2),
            c[5] * x * (x2 - 3.0 * y2),
        )
    if l == 4:
        return (
            c[10] * x * y * (x2 - y2),
            c[11] * y * z * (3.0 * x2 - y2),
            c[12] * x * y * (7.0 * z2 - 1.0),
            c[13] * y * z * (7.0 * z2 - 3.0),
            c[14] * ((35.0 * z2 - 30.0) * z2 + 3.0),
            c[13] * x * z * (7.0 * z2 - 3.0),
            c[15] * (x2 - y2) * (7.0 * z2 - 1.0),
            c[11] * x * z * (x2 - 3.0 * y2),
            c[16] * (x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2)),
        )
    raise ValueError(f"SH band must be in 0..{SH_MAX_ORDER} (got {l})")


def _basis(x, y, z, order=2):
    """The (order + 1)² real SH basis values Y_k, k = l(l + 1) + m, at unit (x, y, z) (any array type)."""
    return tuple(v for b in range(order + 1) for v in _band_basis(x, y, z, b))


def _hann(order, lam):
    return [0.5 * (1.0 + math.cos(math.pi * band / (order + 1))) for band in range(order + 1)]


def _lanczos(order, lam):
    xs = [math.pi * band / (order + 1) for band in range(order + 1)]
    return [1.0 if x == 0.0 else math.sin(x) / x for x in xs]


def _sloan(order, lam):
    return [1.0 / (1.0 + lam * (b * b * (b + 1.0) ** 2)) for b in map(float, range(order + 1))]


_WINDOW_FACTORS = {
    "none": lambda order, lam: [1.0] * (order + 1),
    "hann": _hann,
    "lanczos": _lanczos,
    "lambda": _sloan,
}
"""Window kind → w_0..w_order as a function of (order, λ); λ may be a float or an array of any ops
namespace (the λ window is computed inside the kernel, so a fit or a bisection can vary it)."""


def _sh_kernel(ops, nx, ny, nz, coeffs, order=2, window="none", lam=0.0):
    """E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n) per channel, l ≤ ``order`` (1..4).

    ``coeffs``: 3·(order + 1)² SH coefficients L_lm (W/m²), channel-major (R then G then B), index
    l(l + 1) + m; ``window`` a kind of `WINDOWS`, ``lam`` Sloan's λ (used by the "lambda" window only).
    Bands with Â_l = 0 (odd l ≥ 3) are skipped: they are stored but cannot change the irradiance."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    w = _WINDOW_FACTORS[window](order, lam)
    per = (order + 1) ** 2
    bands = [band for band in range(1, order + 1) if A_HAT[band] != 0.0]
    ys = {band: _band_basis(x, y, z, band) for band in bands}
    scale = {band: A_HAT[band] * w[band] for band in bands}
    out = []
    for c in range(3):
        base = c * per
        rest = None
        for band in bands:
            for j, yv in enumerate(ys[band]):
                term = (coeffs[base + band * band + j] * scale[band]) * yv
                rest = term if rest is None else rest + term
        dc = (coeffs[base] * (A_HAT[0] * w[0])) * SH_C[0]
        out.append(dc if rest is None else dc + ops.select(valid, rest, 0.0))
    return tuple(out)


def _zh3_axis(ops, lx, ly, lz):
    """(âx, ây, âz, |l|): the unit vector of the L1 vector l = (lx, ly, lz), +z where |l| ≤ 1e-30."""
    length = ops.sqrt(lx * lx + ly * ly + lz * lz)
    has_axis = length > _TINY
    inv = 1.0 / ops.maximum(length, _TINY)
    return (
        ops.select(has_axis, lx * inv, 0.0),
        ops.select(has_axis, ly * inv, 0.0),
        ops.select(has_axis, lz * inv, 1.0),
        length,
    )


def _zh3_kernel(ops, nx, ny, nz, coeffs, hallucinate=False, shared_axis=False):
    """ZH3 (Roughton et al. 2024): linear SH plus one zonal L2 harmonic about an L1 direction â.

    E(n) = Â_0 Y00 L00 + Â_1 Y1(n)·L1 + Â_2 z Y20(â·n),  Y20(t) = √5/(4√π) (3t² − 1),
    â = (L11, L1−1, L10)/|L1| of the channel, or with ``shared_axis`` of the luminance-weighted L1
    (`ZH3_LUMINANCE`, one â for RGB); +z where that L1 is 0.

    ``coeffs`` per channel, channel-major: (L00, L1−1, L10, L11, z) (15 floats) with z stored, or
    (L00, L1−1, L10, L11) (12 floats) with ``hallucinate`` (per-channel axis): z = L00 r (0.08 + 0.6 r),
    r = |L1|/L00 clamped to [0, √3] (the range of a non-negative environment; the paper's curve fit)."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    per = 4 if hallucinate else 5
    chans = [coeffs[ch * per : ch * per + 4] for ch in range(3)]
    if shared_axis:
        w = ZH3_LUMINANCE
        shared = _zh3_axis(
            ops,
            *(w[0] * chans[0][k] + w[1] * chans[1][k] + w[2] * chans[2][k] for k in (3, 1, 2)),
        )
    out = []
    for ch in range(3):
        l00, l1m1, l10, l11 = chans[ch]
        ax, ay, az, length = shared if shared_axis else _zh3_axis(ops, l11, l1m1, l10)
        if hallucinate:
            r = ops.clip(safe_div(ops, length, ops.maximum(l00, 0.0)), 0.0, _SQRT3)
            zc = l00 * r * (0.08 + 0.6 * r)
        else:
            zc = coeffs[ch * per + 4]
        t = ax * x + ay * y + az * z
        dc = l00 * (A_HAT[0] * SH_C[0])
        lin = (A_HAT[1] * SH_C[1]) * (l11 * x + l1m1 * y + l10 * z)
        quad = (zc * (A_HAT[2] * SH_C[3])) * (3.0 * t * t - 1.0)
        out.append(dc + ops.select(valid, lin + quad, 0.0))
    return tuple(out)


def _cube_kernel(ops, nx, ny, nz, coeffs):
    """Σ n_i² C[sign of n_i]; ``coeffs``: 18 floats (W/m²), channel-major, each channel in `CUBE_ORDER`."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    x2, y2, z2 = x * x, y * y, z * z
    out = []
    for ch in range(3):
        cc = coeffs[ch * 6 : (ch + 1) * 6]
        e = (
            x2 * ops.select(x < 0.0, cc[1], cc[0])
            + y2 * ops.select(y < 0.0, cc[3], cc[2])
            + z2 * ops.select(z < 0.0, cc[5], cc[4])
        )
        mean = (cc[0] + cc[1] + cc[2] + cc[3] + cc[4] + cc[5]) * (1.0 / 6.0)
        out.append(ops.select(valid, e, mean))
    return tuple(out)


def _geomerics_kernel(ops, nx, ny, nz, coeffs):
    """Geomerics' L1 reconstruction (module docstring); ``coeffs``: 12 floats, per channel the SH
    coefficients (L00, L1−1, L10, L11) (W/m²), channel-major."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    out = []
    for ch in range(3):
        l00, l1m1, l10, l11 = coeffs[ch * 4 : (ch + 1) * 4]
        r0 = l00 * (A_HAT[0] * SH_C[0])  # the sphere-average irradiance
        ax, ay, az = l11 * _R1_SCALE, l1m1 * _R1_SCALE, l10 * _R1_SCALE
        r0p = ops.maximum(r0, 0.0)
        length = ops.sqrt(ax * ax + ay * ay + az * az)
        r = ops.clip(safe_div(ops, length, r0p), 0.0, 1.0)
        q = ops.clip(0.5 * (1.0 + safe_div(ops, ax * x + ay * y + az * z, length)), 0.0, 1.0)
        p = 1.0 + 2.0 * r
        a = (1.0 - r) / (1.0 + r)
        e = r0p * (a + (1.0 - a) * (p + 1.0) * ops.power(q, p))
        out.append(ops.select(valid, e, r0p))
    return tuple(out)


def _given_kernel(ops, irradiance):
    """The exact row: the irradiance a dense quadrature of the environment gives at the normals
    (integrated by `rtfit.reference.environments.irradiance_quadrature`; the reference layer is not
    importable from here), passed through."""
    return irradiance


# =========================================================================================== methods
_NORMAL = (
    Input("nx", "1", "normal x (world frame, +Z up; normalised by the kernel)"),
    Input("ny", "1", "normal y"),
    Input("nz", "1", "normal z"),
)
_CUBE = Input("coeffs", "W/m²", "18 floats: irradiance colours C in CUBE_ORDER, channel-major (R, G, B)")
_SH1 = Input("coeffs", "W/m²", "12 floats: SH coefficients L_lm = ∫ L Y_lm dω, l ≤ 1, channel-major")
_SH2 = Input("coeffs", "W/m²", "27 floats: SH coefficients L_lm = ∫ L Y_lm dω, l ≤ 2, channel-major")
_CUBE_FORMULA = "E(n) = n_x² C[±x] + n_y² C[±y] + n_z² C[±z] (the sign of n_i picks the entry)"
_SH_FORMULA = "E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n), Â = (π, 2π/3, π/4)"
_RH = "Ramamoorthi & Hanrahan 2001, An efficient representation for irradiance environment maps"
_SLOAN = "Sloan 2008, Stupid spherical harmonics (SH) tricks (windowing)"
_ZH3 = (
    "Roughton, Sloan, Silvennoinen, Iwanicki, Shirley 2024, ZH3: Quadratic Zonal Harmonics (i3D 2024, "
    "PACMCGIT 7(1)); hallucination curve as in the authors' published code (Probulator ZH3Solver.h "
    "zh3Coefficient, SHforHLSL CalculateIrradianceL1ZH3Hallucinate)"
)
_ZH3_FORMULA = "E(n) = Â_0 Y00 L00 + Â_1 Y1(n)·L1 + Â_2 z Y20(â·n), â = L1/|L1|"


def _sh_order_methods(order: int) -> list[Method]:
    """The four SH methods of one order ≥ 3 (plain, Hann, Lanczos, fitted λ): one kernel, four windows."""
    per = (order + 1) ** 2
    coeffs = Input(
        "coeffs", "W/m²", f"{3 * per} floats: SH coefficients L_lm = ∫ L Y_lm dω, l ≤ {order}, channel-major"
    )
    a_hat = ", ".join(("π", "2π/3", "π/4", "0", "−π/24")[: order + 1])
    formula = f"E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n), l ≤ {order}, Â = ({a_hat})"
    note = "band 3 stored but Â_3 = 0: the irradiance equals the same window's L2 form at l ≤ 2"

    def fmt(kind):
        return "(" + ", ".join(f"{v:.3g}" for v in _WINDOW_FACTORS[kind](order, 0.0)) + ")"

    def method(suffix, label, fixed, formula_tail, params=None):
        return Method(
            id=f"sh-l{order}{suffix}",
            label=f"SH L{order} ({per}){label}",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, coeffs),
            params=params or {},
            fixed={"order": order, **fixed},
            storage=3 * per,
            quantity="environment_irradiance",
            formula=f"{formula}, {formula_tail}",
            source=_SLOAN if fixed else _RH,
            description=note if order == 3 else "",
        )

    lam = Param(
        1e-6,
        0.0,
        math.inf,
        unit="1",
        description="window strength λ of w_l = 1/(1 + λ l²(l + 1)²); fitted per environment as the "
        f"smallest λ without negative L{order} irradiance (fit_window_lambda(order={order}))",
    )
    return [
        method("", "", {}, "w_l = 1"),
        method(
            "-hann", ", Hann window", {"window": "hann"}, f"w_l = ½(1 + cos(πl/{order + 1})) = {fmt('hann')}"
        ),
        method(
            "-lanczos",
            ", Lanczos window",
            {"window": "lanczos"},
            f"w_l = sinc(l/{order + 1}) = {fmt('lanczos')}",
        ),
        method(
            "-lambda", ", fitted λ window", {"window": "lambda"}, "w_l = 1/(1 + λ l²(l + 1)²)", {"lam": lam}
        ),
    ]


METHODS = method_table(
    [
        Method(
            id="cube-valve",
            label="Ambient cube (Valve: axis samples)",
            kernel=_cube_kernel,
            inputs=(*_NORMAL, _CUBE),
            storage=18,
            quantity="environment_irradiance",
            formula=f"{_CUBE_FORMULA}; C = E at the six axes",
            source="Valve (McTaggart 2004, Half-Life 2 shading); seed 000:2471-2501",
            description="exact at the six axes and for a constant environment",
        ),
        Method(
            id="cube-nnls",
            label="Ambient cube (NNLS optimal)",
            kernel=_cube_kernel,
            inputs=(*_NORMAL, _CUBE),
            storage=18,
            quantity="environment_irradiance",
            formula=f"{_CUBE_FORMULA}; C ≥ 0 minimising Σ_k (E_cube(n_k) − E(n_k))² (fit_ambient_cube_nnls)",
            source="Lawson & Hanson NNLS (rtfit.realtime.nonnegative_lsq); seed 000:2471-2501",
            description="the least-squares cube over a uniform sphere of normals",
        ),
        Method(
            id="sh-l1",
            label="SH L1 (4)",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, _SH1),
            fixed={"order": 1},
            storage=12,
            quantity="environment_irradiance",
            formula=f"{_SH_FORMULA}, l ≤ 1, w_l = 1 (linear in n)",
            source=_RH,
        ),
        Method(
            id="sh-l1-geomerics",
            label="SH L1, Geomerics non-linear",
            kernel=_geomerics_kernel,
            inputs=(*_NORMAL, _SH1),
            storage=12,
            quantity="environment_irradiance",
            formula="E(n) = R0 (a + (1 − a)(p + 1) q^p), r = |R1|/R0, q = ½(1 + R̂1·n), p = 1 + 2r, "
            "a = (1 − r)/(1 + r)",
            source="Hazel (Geomerics), Reconstructing diffuse lighting from SH",
            description="keeps the mean R0, never negative",
        ),
        Method(
            id="sh-l2",
            label="SH L2 (9)",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, _SH2),
            fixed={"order": 2},
            storage=27,
            quantity="environment_irradiance",
            formula=f"{_SH_FORMULA}, l ≤ 2, w_l = 1",
            source=_RH,
        ),
        Method(
            id="sh-l2-hann",
            label="SH L2, Hann window",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, _SH2),
            fixed={"order": 2, "window": "hann"},
            storage=27,
            quantity="environment_irradiance",
            formula=f"{_SH_FORMULA}, w_l = ½(1 + cos(πl/3)) = (1, 0.75, 0.25)",
            source=_SLOAN,
        ),
        Method(
            id="sh-l2-lanczos",
            label="SH L2, Lanczos window",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, _SH2),
            fixed={"order": 2, "window": "lanczos"},
            storage=27,
            quantity="environment_irradiance",
            formula=f"{_SH_FORMULA}, w_l = sinc(l/3) = (1, 0.827, 0.413)",
            source=_SLOAN,
        ),
        Method(
            id="sh-l2-lambda",
            label="SH L2, fitted λ window",
            kernel=_sh_kernel,
            inputs=(*_NORMAL, _SH2),
            params={
                "lam": Param(
                    1e-6,
                    0.0,
                    math.inf,
                    unit="1",
                    description="window strength λ of w_l = 1/(1 + λ l²(l + 1)²); fitted per "
                    "environment as the smallest λ without negative irradiance (fit_window_lambda)",
                )
            },
            fixed={"order": 2, "window": "lambda"},
            storage=27,
            quantity="environment_irradiance",
            formula=f"{_SH_FORMULA}, w_l = 1/(1 + λ l²(l + 1)²)",
            source=_SLOAN,
        ),
        *_sh_order_methods(3),
        *_sh_order_methods(4),
        Method(
            id="zh3",
            label="ZH3 (L1 + zonal L2)",
            kernel=_zh3_kernel,
            inputs=(
                *_NORMAL,
                Input(
                    "coeffs",
                    "W/m²",
                    "15 floats: per channel L00, L1−1, L10, L11 and the zonal L2 coefficient z about the "
                    "channel's L1 direction (zh3_from_sh), channel-major",
                ),
            ),
            storage=15,
            quantity="environment_irradiance",
            formula=f"{_ZH3_FORMULA}, z = ∫ L Y20(â·ω) dω = √(4π/5) Σ_m L_2m Y_2m(â) (stored)",
            source=_ZH3,
            description="exact for an L2 environment whose quadratic band is zonal about its L1 direction",
        ),
        Method(
            id="zh3-lum",
            label="ZH3, shared luminance axis",
            kernel=_zh3_kernel,
            inputs=(
                *_NORMAL,
                Input(
                    "coeffs",
                    "W/m²",
                    "15 floats: per channel L00, L1−1, L10, L11 and the zonal L2 coefficient z about the "
                    "luminance's L1 direction (zh3_from_sh(shared_axis=True)), channel-major",
                ),
            ),
            fixed={"shared_axis": True},
            storage=15,
            quantity="environment_irradiance",
            formula=f"{_ZH3_FORMULA} of the luminance (Rec. 709 weights), z_c = √(4π/5) Σ_m L_2m,c Y_2m(â)",
            source=_ZH3,
            description="one axis for RGB: one normalisation and one (â·n)² per pixel instead of three",
        ),
        Method(
            id="zh3-hallucinated",
            label="ZH3 hallucinated (L1 only)",
            kernel=_zh3_kernel,
            inputs=(*_NORMAL, _SH1),
            fixed={"hallucinate": True},
            storage=12,
            quantity="environment_irradiance",
            formula=f"{_ZH3_FORMULA}, z = L00 r (0.08 + 0.6 r), r = min(|L1|/L00, √3) (curve fit)",
            source=_ZH3,
            description="L1 storage; the zonal L2 coefficient is guessed from the L1 length",
        ),
        Method(
            id="quadrature",
            label="Dense quadrature (exact)",
            kernel=_given_kernel,
            inputs=(Input("irradiance", "W/m²", "dense quadrature of the environment at the normals"),),
            exact=True,
            quantity="environment_irradiance",
            formula="E(n) = Σ_k w_k L_k max(n·d_k, 0) over the bilinear map (+ the disc sun's closed form)",
            source="rtfit.reference.environments.irradiance_quadrature",
            description="must sit at the reference's noise floor",
        ),
    ]
)
"""The irradiance bases as data (module docstring): id → `Method`."""


# =========================================================================================== helpers
def _method(method: str | Method) -> Method:
    if isinstance(method, Method):
        return method
    if method not in METHODS:
        raise ValueError(f"unknown irradiance basis {method!r}; known: {', '.join(METHODS)}")
    return METHODS[method]


def _normal_args(normal, name="normal"):
    """Split a normal argument; NumPy/float input is checked (finite, non-zero length)."""
    if not is_drjit(normal):
        a = np.asarray(normal)
        if a.ndim == 0 or a.shape[-1] != 3:
            raise ValueError(f"{name} must have shape (..., 3) (got shape {a.shape})")
        if a.size:
            a64 = a.astype(np.float64, copy=False)
            if not np.all(np.isfinite(a64)):
                raise ValueError(f"{name} must be finite (got NaN or inf)")
            if np.any(np.sum(a64 * a64, axis=-1) <= _TINY):
                raise ValueError(
                    f"{name} must have non-zero length (normals are normalised; a zero vector "
                    "has no direction)"
                )
    return split3(normal, name)


def _coeff_array(coeffs, n: int, name: str) -> np.ndarray:
    """(n, 3) float64 coefficients; a (n,) vector is taken as grey (the same for R, G, B)."""
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim == 1 and c.shape[0] >= n:
        c = np.repeat(c[:n, None], 3, axis=1)
    elif c.ndim == 2 and c.shape[1] == 1:
        c = np.repeat(c, 3, axis=1)
    if c.ndim != 2 or c.shape[0] < n or c.shape[1] != 3:
        raise ValueError(
            f"{name} must have shape ({n}, 3) or ({n},) (at least {n} rows; got {np.shape(coeffs)})"
        )
    c = c[:n]
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} must be finite")
    return c


def _stored(m: Method, coeffs, name: str = "coeffs") -> tuple[float, ...]:
    """The ``storage`` floats of basis ``m`` from coefficients (rows, 3), channel-major (R, G, B): SH
    (9, 3) arrays give their first 4 rows to the L1 bases."""
    if m.storage is None:
        raise ValueError(f"method {m.id!r} is not a basis (it stores no coefficients)")
    c = _coeff_array(coeffs, m.storage // 3, name)
    return tuple(float(v) for v in c.T.reshape(-1))


def basis_inputs(method: str | Method, coeffs, normal) -> dict[str, Any]:
    """The kernel inputs of basis ``method`` at NumPy ``normal`` (..., 3): ``nx, ny, nz`` (views, no
    normalisation: the kernel normalises) and ``coeffs`` (the stored floats, Python floats, from
    coefficients (rows, 3) or (rows,) grey). Run the NumPy text with ``method(NUMPY_OPS, inputs, params)``."""
    m = _method(method)
    nx, ny, nz = _normal_args(normal)
    return {"nx": nx, "ny": ny, "nz": nz, "coeffs": _stored(m, coeffs)}


def basis_irradiance(method: str | Method, coeffs, normal, params: Mapping[str, float] | None = None):
    """Irradiance (W/m², RGB) of basis ``method`` (an id of `METHODS` or a `Method`) with coefficients
    ``coeffs`` (rows, 3) (or (rows,) grey; SH (9, 3) serves every SH basis) at ``normal``.

    ``params``: the method's free parameters (``{"lam": λ}`` for ``sh-l2-lambda``; defaults otherwise).
    Returns (..., 3) for NumPy input (its dtype), a length-3 float64 array for a single normal, a tuple
    (R, G, B) of lazy arrays for Dr.Jit input.

    On Dr.Jit the coefficients and free parameters enter the kernel as *opaque* size-1 arrays
    (``dr.opaque``): one compiled kernel for every coefficient value. (Measured: size-1 arrays freshly made
    from NumPy are folded into the kernel as literals and recompile it on every call, 16 ms per launch on
    2 CPU cores.)"""
    m = _method(method)
    stored = _stored(m, coeffs)
    keywords = m.keywords(params)
    nx, ny, nz = _normal_args(normal)

    def kernel(ops, nx, ny, nz):
        c, kw = stored, keywords
        if ops is DRJIT_OPS:
            Float = type(nx)
            c = [dr.opaque(Float, v) for v in stored]
            kw = {k: dr.opaque(Float, float(v)) if k in m.params else v for k, v in keywords.items()}
        return m.kernel(ops, nx=nx, ny=ny, nz=nz, coeffs=c, **kw)

    out = evaluate(kernel, nx, ny, nz)
    if isinstance(out[0], np.ndarray):
        return np.stack(out, axis=-1)
    if isinstance(out[0], float):  # one normal given as floats: the NumPy text in float64
        return np.array(out, dtype=np.float64)
    return out


# ====================================================================================== SH: windows
def _check_order(order) -> int:
    if isinstance(order, bool) or order not in range(1, SH_MAX_ORDER + 1):
        raise ValueError(f"order must be an integer in 1..{SH_MAX_ORDER} (got {order!r})")
    return int(order)


def sh_window(kind: str, order: int = 2, lam: float = 0.0) -> np.ndarray:
    """Per-band window factors w_0..w_order for ``kind`` in {"none", "hann", "lanczos", "lambda"} (the text
    the SH kernel applies), L = ``order`` ∈ 1..4: Hann ½(1 + cos(πl/(L+1))), Lanczos sinc(l/(L+1)),
    λ 1/(1 + λ l²(l + 1)²)."""
    _check_order(order)
    if kind not in _WINDOW_FACTORS:
        raise ValueError(f"window kind must be one of {WINDOWS} (got {kind!r})")
    if kind == "lambda":  # guard: λ < 0 makes w_l grow with l (and divide by zero at λ = −1/4)
        lam = float(lam)
        if not (lam >= 0.0 and math.isfinite(lam)):
            raise ValueError(f"lam must be a finite number >= 0 (got {lam!r})")
    return np.array(_WINDOW_FACTORS[kind](order, lam), dtype=np.float64)


# ====================================================================================== SH: public
def sh_basis(direction, order: int = 2) -> np.ndarray:
    """The (order + 1)² real SH basis values (no Condon–Shortley phase, index l(l + 1) + m) at
    ``direction`` (..., 3) (normalised here; zero length raises) → (..., (order + 1)²), float64."""
    _check_order(order)
    d = np.asarray(direction, dtype=np.float64)
    _normal_args(d, "direction")
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return np.stack(_basis(d[..., 0], d[..., 1], d[..., 2], order), axis=-1)


def sh9_basis(direction) -> np.ndarray:
    """The 9 real SH basis values (no Condon–Shortley phase) at unit ``direction`` (..., 3) → (..., 9)."""
    return sh_basis(direction, 2)


def sh_from_constant(radiance, order: int = 2) -> np.ndarray:
    """SH coefficients ((order + 1)², 3) of a constant environment of radiance ``radiance`` (W·m⁻²·sr⁻¹,
    scalar or RGB): L_00 = ∫ L Y00 dω = L·4π·Y00 = L√(4π), every other coefficient 0."""
    sh = np.zeros(((_check_order(order) + 1) ** 2, 3))
    sh[0] = np.asarray(radiance, dtype=np.float64) * math.sqrt(4 * math.pi)
    return sh


def sh9_from_constant(radiance) -> np.ndarray:
    """`sh_from_constant` at order 2 → (9, 3)."""
    return sh_from_constant(radiance, 2)


def sh_from_directional(direction, order: int = 2) -> np.ndarray:
    """SH coefficients ((order + 1)²,) of a distant light of unit irradiance at normal incidence towards
    ``direction`` (a delta in direction: L_lm = Y_lm(d)); normalised here, zero length raises."""
    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,):
        raise ValueError(f"direction must be 3 numbers (got shape {d.shape})")
    return sh_basis(d, order)


def sh9_from_directional(direction) -> np.ndarray:
    """`sh_from_directional` at order 2 → (9,)."""
    return sh_from_directional(direction, 2)


def disk_zonal_factors(angular_radius: float, order: int = 2) -> np.ndarray:
    """f_0..f_order with L_lm = E⊥ f_l Y_lm(d) for a uniform disc of angular radius α about d and
    normal-incidence irradiance E⊥ (radiance E⊥/(π sin²α)).

    Funk–Hecke with the cap's indicator: L_lm = L_disc 2π ∫_{cos α}^1 P_l(t) dt Y_lm(d), and
    ∫_c^1 P_l = (P_{l−1}(c) − P_{l+1}(c))/(2l + 1) = (1 − c²) P_l'(c)/(l(l + 1)) (l ≥ 1), so

        f_0 = 2/(1 + cos α),   f_l = 2 P_l'(cos α)/(l(l + 1))   (f_1 = 1, f_2 = cos α, f_3 = (5c² − 1)/4,
        f_4 = c(7c² − 3)/4),

    free of the 0/0 of the first form as α → 0 (f_l → 1: the directional light)."""
    alpha = float(angular_radius)
    if not (0.0 <= alpha <= math.pi / 2):
        raise ValueError(f"angular_radius must be in [0, pi/2] radians (got {angular_radius!r})")
    c = math.cos(alpha)
    out = [2.0 / (1.0 + c)]
    for band in range(1, _check_order(order) + 1):
        deriv = np.polynomial.legendre.Legendre.basis(band).deriv()
        out.append(2.0 * float(deriv(c)) / (band * (band + 1)))
    return np.array(out)


def sh_from_disk(direction, angular_radius: float, irradiance=1.0, order: int = 2) -> np.ndarray:
    """SH coefficients of a uniform disc light at infinity (angular radius ``angular_radius`` in radians,
    [0, π/2]; irradiance ``irradiance`` W/m² at normal incidence, scalar or RGB) → ((order + 1)²,) or
    ((order + 1)², 3); L_lm = E⊥ f_l Y_lm(d) (`disk_zonal_factors`)."""
    f = disk_zonal_factors(angular_radius, order)
    y = sh_from_directional(direction, order)
    e = np.asarray(irradiance, dtype=np.float64)
    if not np.all(np.isfinite(e)) or np.any(e < 0):
        raise ValueError(f"irradiance must be finite and >= 0 (got {irradiance!r})")
    base = y * f[list(_BAND[: len(y)])]
    return base * e if e.ndim == 0 else base[:, None] * e[None, :]


def sh9_from_disk(direction, angular_radius: float, irradiance=1.0) -> np.ndarray:
    """`sh_from_disk` at order 2 → (9,) or (9, 3)."""
    return sh_from_disk(direction, angular_radius, irradiance, 2)


def zh3_from_sh(coeffs, shared_axis: bool = False) -> np.ndarray:
    """The ZH3 probe (5, 3) of SH coefficients (≥ 9, 3) (or grey (≥ 9,)): per channel L00, L1−1, L10, L11 and
    z = ∫ L Y20(â·ω) dω = √(4π/5) Σ_m L_2m Y_2m(â), the projection of the channel's L2 band onto the zonal
    harmonic about â: the channel's L1 direction, or with ``shared_axis`` the L1 direction of the
    luminance (`ZH3_LUMINANCE`) for all three channels (+z where that L1 = 0, as the kernel). For a given
    axis this z has the least squared error over the sphere (Y20(â·ω) = √(4π/5) Σ_m Y_2m(â) Y_2m(ω), the
    addition theorem)."""
    c = _coeff_array(coeffs, 9, "coeffs")
    out = np.zeros((5, 3))
    out[:4] = c[:4]
    lin = c[[3, 1, 2], :].T  # (channel, xyz)
    if shared_axis:
        lin = np.repeat((np.asarray(ZH3_LUMINANCE) @ lin)[None, :], 3, axis=0)
    length = np.linalg.norm(lin, axis=1)
    axis = np.where((length > _TINY)[:, None], lin / np.maximum(length, _TINY)[:, None], [0.0, 0.0, 1.0])
    y2 = np.stack(_band_basis(axis[:, 0], axis[:, 1], axis[:, 2], 2), axis=-1)  # (channel, 5)
    out[4] = math.sqrt(4.0 * math.pi / 5.0) * np.sum(y2 * c[4:9].T, axis=1)
    return out


def sh_irradiance(coeffs, normal, order: int = 2, window=None):
    """E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n), l ≤ ``order`` (1..4), for coefficients ((order + 1)², 3) or more
    rows (or grey; lower orders use the first rows).

    ``window``: per-band factors (see `sh_window`) or None; they scale the coefficients (w_l L_lm) before
    the ``sh-l<order>`` kernel. Returns (..., 3) for NumPy input, a length-3 array for a single normal,
    a tuple (R, G, B) of lazy arrays for Dr.Jit input (see `basis_irradiance`)."""
    method = METHODS[f"sh-l{_check_order(order)}"]
    c = _coeff_array(coeffs, (order + 1) ** 2, "coeffs")
    if window is not None:
        w = np.asarray(window, dtype=np.float64)
        if w.shape != (order + 1,) or not np.all(np.isfinite(w)):
            raise ValueError(f"window must be {order + 1} finite band factors (got {np.shape(window)})")
        c = c * w[list(_BAND[: len(c)]), None]
    return basis_irradiance(method, c, normal)


def sh9_irradiance(coeffs, normal, window=None):
    """L2 (9-coefficient) SH irradiance; see `sh_irradiance`."""
    return sh_irradiance(coeffs, normal, 2, window)


def sh4_irradiance(coeffs, normal):
    """L1 (4-coefficient) SH irradiance (linear in n); see `sh_irradiance`."""
    return sh_irradiance(coeffs, normal, 1)


def sh4_irradiance_geomerics(coeffs, normal):
    """Geomerics' non-negative L1 reconstruction (see the module docstring) from SH coefficients (≥ 4, 3)."""
    return basis_irradiance("sh-l1-geomerics", coeffs, normal)


# ====================================================================================== ambient cube
def ambient_cube_irradiance(cube, normal):
    """Valve's ambient cube: Σ n_i² C[sign of n_i] for ``cube`` (6, 3) in the order +x, −x, +y, −y, +z, −z."""
    return basis_irradiance("cube-valve", _coeff_array(cube, 6, "cube"), normal)


def ambient_cube_from_axes(irradiance_at_axes) -> np.ndarray:
    """Valve's cube: the irradiance sampled at the six axes (`CUBE_AXES`, already in cube order) → (6, 3)."""
    return _coeff_array(irradiance_at_axes, 6, "irradiance_at_axes").copy()


def cube_design_matrix(normals) -> np.ndarray:
    """(N, 6) weights of the six cube colours at ``normals`` (N, 3): n_i² on the side of its sign, i.e.
    column j is the cube kernel's red channel with C = e_j (the NumPy text of the same kernel)."""
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 2:
        raise ValueError(f"normals must have shape (N, 3) (got shape {n.shape})")
    m = METHODS["cube-valve"]
    eye = np.eye(18)
    cols = [m(NUMPY_OPS, basis_inputs(m, eye[j].reshape(3, 6).T, n))[0] for j in range(6)]
    return np.stack(cols, axis=-1)


def fit_ambient_cube_nnls(normals, irradiance, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares cube with C ≥ 0 (`rtfit.realtime.nonnegative_lsq`, per channel) minimising
    Σ_k w_k (E_cube(n_k) − E_k)².

    ``normals`` (N, 3), ``irradiance`` (N, 3) or (N,), optional ``weights`` (N,) ≥ 0 (default uniform:
    a uniform sphere sampling such as `fibonacci_sphere` then minimises the sphere-integrated error).
    Returns (cube (6, 3), rms residual per channel (3,))."""
    a, sw, w = _weighted_cube_design(normals, weights)
    e = np.asarray(irradiance, dtype=np.float64)
    if e.ndim == 1:
        e = np.repeat(e[:, None], 3, axis=1)
    if e.shape != (len(a), 3) or not np.all(np.isfinite(e)):
        raise ValueError(f"irradiance must be finite with shape ({len(a)}, 3) (got {np.shape(irradiance)})")
    b = e * sw[:, None]
    cube = nnls_columns(a, b)
    rms = np.linalg.norm(a @ cube - b, axis=0) / math.sqrt(max(w.sum(), _TINY))
    return cube, rms


def fit_ambient_cubes_nnls(normals, irradiance, weights=None) -> np.ndarray:
    """`fit_ambient_cube_nnls`'s cubes (P, 6, 3) of P probes at once, ``irradiance`` (P, N, 3) at the same
    ``normals`` (N, 3): every probe's channels solved together (`nnls_columns`: one design matrix)."""
    a, sw, _w = _weighted_cube_design(normals, weights)
    e = np.asarray(irradiance, dtype=np.float64)
    if e.ndim != 3 or e.shape[1:] != (len(a), 3) or not np.all(np.isfinite(e)):
        shape = np.shape(irradiance)
        raise ValueError(f"irradiance must be finite with shape (P, {len(a)}, 3) (got {shape})")
    b = (e * sw[None, :, None]).transpose(1, 0, 2).reshape(len(a), -1)  # (N, P·3), probe-major columns
    return nnls_columns(a, b).reshape(6, len(e), 3).transpose(1, 0, 2)


def _weighted_cube_design(normals, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(√w_k-weighted `cube_design_matrix` (N, 6), √w (N,), w (N,)) of the NNLS cube fits."""
    a = cube_design_matrix(normals)
    w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(a),) or np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite, >= 0, one per normal")
    sw = np.sqrt(w)
    return a * sw[:, None], sw, w


# ====================================================================================== λ window fit
def fit_window_lambda(
    coeffs, normals=None, tolerance: float = 0.0, lam_max: float = 1e6, order: int = 2
) -> float:
    """Smallest λ ≥ 0 such that the λ-windowed L``order`` irradiance (``sh-l<order>-lambda``, order 2..4) is
    ≥ −tolerance·E_DC at every normal of ``normals`` (default: 4096 Fibonacci normals plus the 26
    axis/edge/corner directions), every channel.

    Bisection on λ (60 steps, relative precision ~1e-6 of the bracket); λ → ∞ leaves the DC term, which is
    ≥ 0 for a non-negative environment. Returns 0.0 when the plain reconstruction is already non-negative,
    and ``lam_max`` if even that does not remove the negative values. At order 3 the answer is the order-2
    one (Â_3 = 0 and w_l does not depend on the order)."""
    if _check_order(order) < 2:
        raise ValueError(f"the λ window is declared for orders 2..{SH_MAX_ORDER} (got {order})")
    c = _coeff_array(coeffs, (order + 1) ** 2, "coeffs")
    n = _default_check_normals() if normals is None else np.asarray(normals, dtype=np.float64)
    lin = c[[3, 1, 2], :].T  # (3 channels, xyz): the L1 direction of each channel, where ringing peaks
    ln = np.linalg.norm(lin, axis=1)
    extra = lin[ln > 0] / ln[ln > 0, None]
    n = np.concatenate([n, extra, -extra]) if len(extra) else n
    dc = A_HAT[0] * SH_C[0] * c[0]
    # −tolerance·DC, and a positive margin of 1e-4·DC at tolerance 0 so that normals between the check
    # set's points, and float32 evaluation on the GPU, stay non-negative too (with 1e-6 a CUDA run of
    # the experiment found 2 of 4096 normals slightly negative).
    thr = (-float(tolerance) if tolerance > 0 else 1e-4) * np.maximum(dc, 0.0)

    method = METHODS[f"sh-l{order}-lambda"]
    inputs = basis_inputs(method, c, n)

    def ok(lam):  # the NumPy text of the λ-window kernel, float64
        e = np.stack(method(NUMPY_OPS, inputs, {"lam": lam}), axis=-1)
        return bool(np.all(e >= thr[None, :]))

    if ok(0.0):
        return 0.0
    if not ok(lam_max):
        return float(lam_max)
    lo, hi = 0.0, method.params["lam"].initial  # 1e-6: the bracket grows ×4 from λ's start value
    while not ok(hi):
        lo, hi = hi, hi * 4.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ok(mid):
            hi = mid
        else:
            lo = mid
        if hi - lo <= 1e-7 * hi:
            break
    return float(hi)


def _default_check_normals() -> np.ndarray:
    grid = np.array(
        [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)],
        dtype=np.float64,
    )
    grid /= np.linalg.norm(grid, axis=1, keepdims=True)
    return np.concatenate([fibonacci_sphere(4096), grid])


# ====================================================================================== sampling
def fibonacci_sphere(count: int) -> np.ndarray:
    """``count`` near-uniform unit vectors (N, 3): z_k = 1 − (2k + 1)/N, φ_k = k·π(3 − √5)."""
    count = int(count)
    if count < 1:
        raise ValueError(f"count must be >= 1 (got {count})")
    k = np.arange(count, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / count
    r = np.sqrt(np.maximum(0.0, (1.0 - z) * (1.0 + z)))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def latlong_directions(u, v) -> np.ndarray:
    """World direction (+Z up) of lat-long coordinates (u, v) ∈ [0, 1]² of a Mitsuba ``envmap`` file as
    rtfit places it (rotated +Y → +Z, `rtfit.reference.build`): θ = πv from +Z, φ = 2πu from +Y towards
    +X, d = (sin θ sin φ, sin θ cos φ, cos θ)."""
    th = np.pi * np.asarray(v, dtype=np.float64)
    ph = 2.0 * np.pi * np.asarray(u, dtype=np.float64)
    return np.stack([np.sin(th) * np.sin(ph), np.sin(th) * np.cos(ph), np.cos(th)], axis=-1)


def latlong_samples(radiance, supersample: int = 2):
    """Quadrature samples of the radiance function Mitsuba's ``envmap`` makes of a lat-long map.

    Mitsuba interpolates bilinearly between nodes at u_i = (i + ½)/W (periodic) and v_j = j/(H − 1)
    (rows 0 and H − 1 at the poles; measured, see tests). This evaluates that function at the
    midpoints of an (sH × sW) grid in (u, v) with weights (2π/(sW))(π/(sH)) sin(πv) (solid angle).
    Returns (directions (M, 3), weights (M,), radiance (M, 3)), float64."""
    img = np.asarray(radiance, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2 or img.shape[1] < 1:
        raise ValueError(f"radiance must be an (H >= 2, W, 3) lat-long map (got shape {img.shape})")
    if not np.all(np.isfinite(img)):
        raise ValueError("radiance must be finite")
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1 (got {supersample})")
    h, w = img.shape[:2]
    u = (np.arange(s * w) + 0.5) / (s * w)
    v = (np.arange(s * h) + 0.5) / (s * h)
    x = u * w - 0.5
    i0 = np.floor(x).astype(int)
    fx = x - i0
    ia, ib = i0 % w, (i0 + 1) % w
    y = v * (h - 1)
    j0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fy = y - j0
    rows = img[j0] * (1 - fy)[:, None, None] + img[j0 + 1] * fy[:, None, None]  # (sH, W, 3)
    vals = rows[:, ia] * (1 - fx)[None, :, None] + rows[:, ib] * fx[None, :, None]
    uu, vv = np.meshgrid(u, v)
    wgt = (2.0 * np.pi / (s * w)) * (np.pi / (s * h)) * np.sin(np.pi * vv)
    return latlong_directions(uu, vv).reshape(-1, 3), wgt.reshape(-1), vals.reshape(-1, 3)


_PROJECT_CHUNK = 1 << 17  # samples per block of the projection: (block, 25) float64 basis values, 26 MB


def sh_project_samples(directions, weights, radiance, order: int = 2) -> np.ndarray:
    """L_lm ≈ Σ_k w_k L_k Y_lm(d_k) → ((order + 1)², 3), accumulated in blocks of samples (memory stays
    bounded for full-resolution probes)."""
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    wl = (
        np.asarray(radiance, np.float64).reshape(-1, 3) * np.asarray(weights, np.float64).reshape(-1)[:, None]
    )
    out = np.zeros(((_check_order(order) + 1) ** 2, 3))
    for i in range(0, len(d), _PROJECT_CHUNK):
        out += sh_basis(d[i : i + _PROJECT_CHUNK], order).T @ wl[i : i + _PROJECT_CHUNK]
    return out


def sh_project_latlong(radiance, supersample: int = 2, order: int = 2) -> np.ndarray:
    """SH coefficients ((order + 1)², 3) of a Mitsuba-convention lat-long radiance map (see
    `latlong_samples`)."""
    return sh_project_samples(*latlong_samples(radiance, supersample), order=order)
