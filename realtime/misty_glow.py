r"""Misty glow: the halo around a light in fog as an iterated Kawase blur of its direct image.

The seed (000:628-652, Tatarchuk 2006, ToyShop; after Narasimhan & Nayar 2003 and Kawase 2003)
---------------------------------------------------------------------------------------------
"To approximate the atmospheric point spread function which can be used to model multiple scattering
around the light sources in the stormy weather" the scene is rendered off-screen, downsampled by 4 in each
dimension, and blurred by the Kawase bloom filter "repeatedly ... performing four feedback ping-pong
passes", each pass "a new, larger kernel"; the blurred result is added to the image (000:640-652).

Errata / what the text conversion lost: the filter's weights and offsets are in figure 13 (from Kawase 2003,
"Frame buffer postprocessing effects in DOUBLE-S.T.E.A.L (Wreckless)", GDC 2003), which the seed's text does
not hold. We use Kawase's published pattern: pass k (k = 0, 1, 2, …) reads four bilinear taps at the
diagonal offsets (±(k + ½), ±(k + ½)) texels, weight ¼ each. A bilinear tap half-way between texels is the
mean of a 2 × 2 block, so pass k is separable with the 1-D weights ¼ at the texel offsets −k−1, −k, k, k+1
(pass 0: ¼, ½, ¼). "Each successive ... larger kernel" is read as k = 0, 1, 2, 3 for the four passes (the
seed's "four passes"). The seed gives no level for the composite ("combined as described in [Kawase03]"):
the amplitude A is a free parameter (below).

The kernel as a point-spread function (rtfit's reading of the shortcut)
----------------------------------------------------------------------
The bright pixels are the light's direct image: a delta of irradiance E_d = I·e^(−σ_t·R)/R² (W/m²) at the
camera (I the light's intensity in W/sr, R its distance, σ_t the extinction). Downsampling by s film pixels
puts it in one texel; N Kawase passes turn it into the separable table w_N (the convolution of the N
passes' 1-D weights, Σ w_N = 1); the bilinear upsample back to the film makes that table the piecewise-linear
function W_N(x) = Σ_j w_N[j]·max(0, 1 − |x − j|). The glow in a pixel offset (Δu, Δv) film pixels from the
light's image is then the radiance

    L = A·E_d/Ω_px · W_N(Δu/s)·W_N(Δv/s)/s²          (W/m²/sr)

with Ω_px the pixel's solid angle (sr): summed over the pixels, L·Ω_px gives A·E_d (W/m²), so A is the
glow's energy in units of the light's direct image. Energy conservation in the forward-scattering limit
(every scattered photon still reaches the camera) gives A = e^(σ_s·R) − 1 (the light lost from the direct
beam by scattering, relative to what is left); the audit starts the fit there. Seed: N = 4, s = 4 (the ¼
downsample). The fitted rows fit s and A per scene (optical depth) for N = 1, 2, 6 and 8 passes (N = 4:
the seed row, fitted): cost
grows with N (N·4 taps per texel of the ¼-size buffer), the error is measured.

Modern comparison: a Gaussian bloom, L = A·E_d/Ω_px · e^(−(Δu² + Δv²)/(2σ²))/(2πσ²) (σ in film pixels),
the kernel that Kawase's iterated blur approximates (Strugar 2014, Intel, "An investigation of fast
real-time GPU-based image blur algorithms": Kawase 0-1-2-2-3 ≈ a 35 × 35 Gaussian; the dual-filter and
Jimenez 2014 CoD:AW bloom chains approximate the same). Narasimhan & Nayar's analytic APSF (Legendre series
in the optical depth T = σ_t·R and g) is left for later (docs/misty-glow.md).

Float32: every term is a product of non-negative factors and a sum of tents; Ω_px and s are floored at
1e-30 and 1e-6 (a reason: no division by zero on a degenerate film or a fitted scale at its bound); E_d = 0
(an infinitely dense medium, e^(−σ_t R) underflows) gives 0; the tents are bounded by 1. No NaN or Inf for
finite inputs (tests/test_misty_glow.py, hypothesis).

Methods as data (`METHODS`)
---------------------------
Inputs per pixel: ``du``, ``dv`` (film pixels from the light's image), ``e_direct`` (W/m², the light's
attenuated irradiance at the camera), ``omega_px`` (sr). ``kawase-seed``: N = 4, s = 4 (A and s may be
fitted); ``kawase-N``: N passes, s and A fitted; ``gaussian``: σ and A fitted; ``single-scattering``: the
quadrature of the light's single scattering along each pixel's ray
(`rtfit.reference.single_scattering.point_single_scattering`, the volumetric-lightning family's exact row)
passed through: the glow's first-order part, a lower bound of the glow for albedo ≤ 1.
"""

from __future__ import annotations

import math

from .arrays import check_range, evaluate
from .methods import Input, Method, Param, method_table

__all__ = [
    "KAWASE_PASSES",
    "KAWASE_SEED_PASSES",
    "KAWASE_SEED_SCALE",
    "kawase_glow",
    "kawase_table",
    "kawase_weight",
]

KAWASE_SEED_PASSES = 4
"""The seed's four ping-pong passes (000:646)."""
KAWASE_SEED_SCALE = 4.0
"""The seed's downsample: one blurred texel is 4 × 4 film pixels (000:645)."""
KAWASE_PASSES = (1, 2, 6, 8)
"""The fitted rows' numbers of passes."""
_TINY = 1e-30  # Ω_px floor: a degenerate film gives 0, not 0/0
_MIN_SCALE = 1e-6  # s floor: a fitted scale at its lower bound keeps W finite


def _pass_weights(k: int) -> dict[int, float]:
    """Pass k's 1-D weights (module docstring): ¼ at −k−1, −k, k, k+1 (pass 0: ¼, ½, ¼)."""
    w: dict[int, float] = {}
    for j in (-k - 1, -k, k, k + 1):
        w[j] = w.get(j, 0.0) + 0.25
    return w


def kawase_table(passes: int) -> tuple[tuple[int, float], ...]:
    """The 1-D composite of ``passes`` Kawase passes, k = 0 … passes − 1: (texel offset, weight) pairs,
    weights summing to 1 (exact binary fractions)."""
    if passes < 1:
        raise ValueError(f"kawase_table: passes must be >= 1, got {passes}")
    acc = {0: 1.0}
    for k in range(passes):
        out: dict[int, float] = {}
        for i, a in acc.items():
            for j, b in _pass_weights(k).items():
                out[i + j] = out.get(i + j, 0.0) + a * b
        acc = out
    return tuple(sorted(acc.items()))


def _tents(ops, x, table):
    """W(x) = Σ_j w_j·max(0, 1 − |x − j|): the bilinear upsample of the table (x in texels)."""
    total = 0.0 * x
    for j, w in table:
        total = total + w * ops.maximum(1.0 - ops.abs(x - float(j)), 0.0)
    return total


def _kawase_kernel(ops, du, dv, e_direct, omega_px, amplitude, scale, passes):
    s = ops.maximum(scale, _MIN_SCALE)
    table = kawase_table(int(passes))
    wx = _tents(ops, du / s, table)
    wy = _tents(ops, dv / s, table)
    return amplitude * e_direct / ops.maximum(omega_px, _TINY) * (wx * wy) / (s * s)


def _gaussian_kernel(ops, du, dv, e_direct, omega_px, amplitude, sigma):
    s = ops.maximum(sigma, _MIN_SCALE)
    r2 = (du * du + dv * dv) / (s * s)
    return amplitude * e_direct / ops.maximum(omega_px, _TINY) * ops.exp(-0.5 * r2) / (2.0 * math.pi * s * s)


def _pass_through_kernel(ops, single_scattering):
    return single_scattering + 0.0 * single_scattering


# ===================================================================================== methods (data)
_INPUTS = (
    Input("du", "px", "film pixels from the light's image, horizontal", (-1e3, 1e3)),
    Input("dv", "px", "film pixels from the light's image, vertical", (-1e3, 1e3)),
    Input("e_direct", "W/m²", "the light's attenuated irradiance at the camera I·e^(−σt·R)/R²", (0.0, 1e4)),
    Input("omega_px", "sr", "the pixel's solid angle", (1e-8, 1.0)),
)
_AMPLITUDE = Param(
    1.0, 0.0, 1e6, unit="1", description="glow energy / the light's direct image (seed: not given)",
    published=False,
)  # fmt: skip


def _scale(initial: float) -> Param:
    return Param(initial, 0.05, 512.0, unit="px", description="film pixels per blurred texel s")


def _kawase(passes: int, row_id: str, label: str, source: str, scale: float) -> Method:
    return Method(
        id=row_id,
        label=label,
        kernel=_kawase_kernel,
        inputs=_INPUTS,
        params={"amplitude": _AMPLITUDE, "scale": _scale(scale)},
        fixed={"passes": passes},
        quantity="glow_radiance",
        formula=f"L = A·E_d/Ω_px·W_{passes}(Δu/s)·W_{passes}(Δv/s)/s², W_N: {passes} Kawase passes, bilinear",
        source=source,
    )


_KAWASE = "Kawase 2003 (GDC, DOUBLE-S.T.E.A.L bloom: taps at ±(k+½) texels)"
METHODS = method_table(
    [
        _kawase(
            KAWASE_SEED_PASSES,
            "kawase-seed",
            "seed: 4 Kawase passes on the ¼-size image",
            f"seed 000:628-652 (figure 13 lost: {_KAWASE})",
            KAWASE_SEED_SCALE,
        ),
        *(
            _kawase(n, f"kawase-{n}", f"{n} Kawase pass{'es' if n > 1 else ''}, scale fitted", _KAWASE, 4.0)
            for n in KAWASE_PASSES
        ),
        Method(
            id="gaussian",
            label="Gaussian bloom (σ fitted)",
            kernel=_gaussian_kernel,
            inputs=_INPUTS,
            params={
                "amplitude": _AMPLITUDE,
                "sigma": Param(8.0, 0.05, 512.0, unit="px", description="the Gaussian's σ in film pixels"),
            },
            quantity="glow_radiance",
            formula="L = A·E_d/Ω_px·e^(−(Δu²+Δv²)/(2σ²))/(2πσ²)",
            source="Strugar 2014 (Intel, fast GPU blur: Kawase ≈ Gaussian); Jimenez 2014 (CoD:AW bloom)",
        ),
        Method(
            id="single-scattering",
            label="single scattering only (quadrature)",
            kernel=_pass_through_kernel,
            inputs=(
                Input("single_scattering", "W/m²/sr", "the light's single-scattered radiance on the ray"),
            ),
            quantity="glow_radiance",
            formula="L₁ = σ_s/(4π)·∫ I·p_HG·e^(−σt(s+r))/r² ds (Gauss–Legendre)",
            source="rtfit.reference.single_scattering (the volumetric-lightning family's quadrature)",
        ),
    ]
)
"""The family's rows on ``glow_radiance`` (module docstring)."""


# ===================================================================================== public API
def _check(name: str, passes: int, scale) -> None:
    if isinstance(passes, bool) or int(passes) != passes or not 1 <= int(passes) <= 64:
        raise ValueError(f"{name}: passes must be an integer in [1, 64], got {passes!r}")
    check_range("scale", scale, 1e-6, 1e6, interval="[1e-6, 1e6] (film pixels per texel)")


def kawase_weight(du, dv, passes: int = KAWASE_SEED_PASSES, scale: float = KAWASE_SEED_SCALE):
    """W_N(Δu/s)·W_N(Δv/s)/s² (1/px²): the fraction of the light's direct image that N Kawase passes at
    scale s put into one film pixel at offset (``du``, ``dv``) film pixels (sums to 1 over the film)."""
    _check("kawase_weight", passes, scale)

    def kernel(ops, u, v, s):
        return _kawase_kernel(ops, u, v, 1.0, 1.0, 1.0, s, int(passes))

    return evaluate(kernel, du, dv, scale)


def kawase_glow(
    du, dv, e_direct, omega_px, amplitude=1.0, passes: int = KAWASE_SEED_PASSES, scale=KAWASE_SEED_SCALE
):
    """The glow radiance L (W/m²/sr) of the module docstring's formula: ``e_direct`` W/m² ≥ 0, ``omega_px``
    sr > 0, ``amplitude`` ≥ 0, ``passes`` N, ``scale`` s film pixels per texel."""
    _check("kawase_glow", passes, scale)
    check_range("e_direct", e_direct, 0.0, 3.4e38, interval="[0, 3.4e38] (W/m²)")
    check_range("omega_px", omega_px, 1e-30, 4.0 * math.pi, interval="[1e-30, 4π] (sr)")
    check_range("amplitude", amplitude, 0.0, 1e30, interval="[0, 1e30]")

    def kernel(ops, u, v, e, om, a, s):
        return _kawase_kernel(ops, u, v, e, om, a, s, int(passes))

    return evaluate(kernel, du, dv, e_direct, omega_px, amplitude, scale)
