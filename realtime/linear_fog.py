r"""Classic distance fog: linear, exponential and exponential-squared fog factors, the seed's linear fog with
its luminance fade, and Beer–Lambert transmittance (the ``linear-fog`` family, docs/linear-fog.md).

Fog factor and units
--------------------
A distance fog attenuates the colour L₀ of a visible point by a factor f(d) ∈ [0, 1] of the view distance d
(scene units; in a bounded medium the stretch of the camera ray inside it) and fills the rest with a fog
colour C (the fixed-function pipeline's fog blend; OpenGL 1.x ``glFog``, Direct3D 9 fixed-function fog):

    L = L₀·f + C·(1 − f)        (per RGB channel; L, L₀, C in the radiance units of the scene, W/m²/sr)

f plays the part of the transmittance T (1: no fog). The classic factors:

* ``fog-linear`` (GL_LINEAR):  f = clamp((end − d)/(end − start), 0, 1)  (start, end in scene units);
* ``fog-exp`` (GL_EXP):        f = e^(−ρ·d)      (density ρ in 1/scene unit);
* ``fog-exp2`` (GL_EXP2):      f = e^(−(ρ·d)²).

The modern form is Beer–Lambert: in a homogeneous medium of extinction σt the transmittance along a
stretch of length d is exactly T = e^(−σt·d) — ``fog-exp`` with ρ = σt (Beer–Lambert–Bouguer law; as in
physically based real-time fog, Hillaire 2015, "Physically Based and Unified Volumetric Rendering in
Frostbite", SIGGRAPH course, §"Participating media"). The fogged radiance of a homogeneous medium whose
in-scattered source S (W/m²/sr per unit length) is constant along the ray is exactly
L = L₀·T + (S/σt)·(1 − T) (Hillaire 2015, the analytic integral of S·T over the stretch): the fog blend
with C = S/σt. ``blend-beer-lambert`` is that form with σt the medium's own (an input) and C fitted.

The seed (000:654-707, the rain demo's fog; Listing 1 at 000:658-673, Listing 2 at 000:683-703)
------------------------------------------------------------------------------------------------
    fFog      = saturate((d − start)/(end − start))          (Listing 1: the fog *amount*, 1 − f)
    fogFactor = fFog·(1 − Y(L₀)/10)                           (Listing 2: the luminance fade)
    fogFactor = min(fogFactor, fog_max)                       (vFogParams.z)
    L         = lerp(L₀, C, fogFactor) = L₀ + (C − L₀)·fogFactor

Errata and readings, each stated where it is used:

* 000:667 the comment says "linear fog = (d - end) / (end - start)"; the code on 000:668-669 computes
  (d − start)/(end − start), which is the fog amount (0 at start, 1 at end). The code is followed; the
  comment's form would saturate to 0 for every d ≤ end.
* 000:693 ``SiGetLuminance`` is not defined in the listing: read as the Rec. 709 luminance
  Y = 0.2126·R + 0.7152·G + 0.0722·B of the linear colour (`LUMINANCE`).
* 000:693 the fade's 10 is in the demo's HDR buffer units (10-10-10-2, before tone mapping, 000:642-644);
  here it is read in the scene's radiance units and declared as the parameter ``y_fade`` (published 10).
  Bright pixels (lights) punch through the fog; for Y > y_fade the printed factor is negative and the lerp
  extrapolates away from C (kept as printed: the audit states it, docs/linear-fog.md).
* 000:700 the alpha (glow) channel is not a colour and is not audited.

On the transmittance quantity (no colour) the seed row is its fog amount without the fade (the fade at
Y = 0): f = 1 − min(fFog, fog_max).

Domain and guards (each with its reason)
----------------------------------------
* d ∈ [0, ∞] (∞: a ray that leaves the scene; every factor is then 0, or 1 for ρ = 0).
* start = end (a fit may pass through it): the ramp's limit as start → end⁻ is a step at end, f = 1 for
  d < end and 0 beyond; the kernels take that step where end − start = 0 exactly (else 0/0 = NaN at d = end,
  and a NaN gradient in a JAX fit). end < start is evaluated as written (a reversed ramp).
* ρ = 0 or d = 0: f = 1 exactly (never 0·∞ for d = ∞); a negative ρ (a Dr.Jit array, which is not
  validated) is clamped to 0.
* |start|, |end| ≤ 1e30 keep end − start finite in float32; ρ·d and (ρ·d)² overflow to +∞, f = 0 exactly.
* y_fade > 0 (clamped at 1e-30).

Float32: every factor is a handful of operations on d: the ramp's relative error is a few ulp of
(end − d)/(end − start) (cancellation in end − d near d = end is exact subtraction of float32 values, so
the absolute error of f is ≤ 2 ulp of 1); e^(−x) carries the float32 rounding of x = ρ·d (relative
2⁻²⁴·x on f). Measured against float64 in tests/test_linear_fog.py.
"""

from __future__ import annotations

import math

from .arrays import check_range, clamp01, evaluate
from .methods import Input, Method, Param, method_table

__all__ = [
    "LUMINANCE",
    "exponential2_fog_factor",
    "exponential_fog_factor",
    "linear_fog_factor",
    "seed_fog_amount",
]

LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights: the reading of the seed's undefined ``SiGetLuminance`` (000:693)."""
_SEED_FADE = 10.0  # 000:693: fFog·(1 − Y/10)
_TINY = 1e-30


# ===================================================================================== kernels (ops text)
def _ramp(ops, num, start, end, below_end):
    """clamp(num/(end − start), 0, 1), and where end − start = 0 exactly the limit start → end⁻: the step
    ``below_end`` (1 or 0 for d < end, the other beyond). The division runs on a safe denominator so that
    the dropped branch stays finite (no 0/0, no NaN gradient in a JAX fit)."""
    w = end - start
    flat = w == 0.0
    # num is clipped to ±|w| first: the same clamp (|num/w| ≥ 1 either way, same sign), and no float32
    # overflow of the quotient (d = 3e38 over w = 0.5: inf, a NumPy overflow warning found by hypothesis).
    aw = ops.abs(w)
    ramp = clamp01(ops, ops.clip(num, -aw, aw) / ops.select(flat, 1.0, w))
    return ops.select(flat, below_end, ramp)


def _linear_kernel(ops, length, start, end):
    """GL_LINEAR: f = clamp((end − d)/(end − start), 0, 1); a step at end where start = end."""
    return _ramp(ops, end - length, start, end, ops.select(length < end, 1.0, 0.0))


def _optical(ops, length, density):
    """ρ·d with ρ clamped at 0 and d read as 0 where ρ = 0 (0·∞ = NaN otherwise, for d = ∞)."""
    rho = ops.maximum(density, 0.0)
    return rho * ops.select(rho > 0.0, length, 0.0)


def _exp_kernel(ops, length, density):
    """GL_EXP, and Beer–Lambert with density = σt: f = e^(−ρ·d)."""
    return ops.exp(-_optical(ops, length, density))


def _exp2_kernel(ops, length, density):
    """GL_EXP2: f = e^(−(ρ·d)²)."""
    x = _optical(ops, length, density)
    return ops.exp(-(x * x))


def _seed_amount(ops, length, start, end):
    """000:668-670 as printed: fFog = saturate((d − start)/(end − start)) (the fog amount); the step at
    end where start = end (guarded: the listing divides 0/0 there)."""
    return _ramp(ops, length - start, start, end, ops.select(length < end, 0.0, 1.0))


def _seed_kernel(ops, length, start, end, fog_max):
    """The seed on transmittance: f = 1 − min(fFog, fog_max) (its fade needs the colour: at Y = 0 it is 1)."""
    return 1.0 - ops.minimum(_seed_amount(ops, length, start, end), fog_max)


def _blend(ops, f, l0_r, l0_g, l0_b, c_r, c_g, c_b):
    """L = L₀·f + C·(1 − f) per channel."""
    g = 1.0 - f
    return ops.fma(l0_r, f, c_r * g), ops.fma(l0_g, f, c_g * g), ops.fma(l0_b, f, c_b * g)


def _blend_linear_kernel(ops, length, l0_r, l0_g, l0_b, start, end, c_r, c_g, c_b):
    return _blend(ops, _linear_kernel(ops, length, start, end), l0_r, l0_g, l0_b, c_r, c_g, c_b)


def _blend_exp_kernel(ops, length, l0_r, l0_g, l0_b, density, c_r, c_g, c_b):
    return _blend(ops, _exp_kernel(ops, length, density), l0_r, l0_g, l0_b, c_r, c_g, c_b)


def _blend_exp2_kernel(ops, length, l0_r, l0_g, l0_b, density, c_r, c_g, c_b):
    return _blend(ops, _exp2_kernel(ops, length, density), l0_r, l0_g, l0_b, c_r, c_g, c_b)


def _blend_seed_kernel(ops, length, l0_r, l0_g, l0_b, start, end, fog_max, y_fade, c_r, c_g, c_b):
    """000:690-697: fogFactor = min(fFog·(1 − Y(L₀)/y_fade), fog_max); L = lerp(L₀, C, fogFactor)."""
    y = LUMINANCE[0] * l0_r + LUMINANCE[1] * l0_g + LUMINANCE[2] * l0_b
    factor = _seed_amount(ops, length, start, end) * (1.0 - y / ops.maximum(y_fade, _TINY))
    factor = ops.minimum(factor, fog_max)
    return tuple(ops.fma(c - l0, factor, l0) for l0, c in ((l0_r, c_r), (l0_g, c_g), (l0_b, c_b)))


# ===================================================================================== methods (data)
_LENGTH = Input(
    "length", "scene unit", "view distance d: the camera ray's stretch inside the medium", (0.0, 1e4)
)
_SIGMA_T = Input("density", "1/scene unit", "the medium's extinction σt", (0.0, 10.0))
_FOG_FREE = tuple(
    Input(f"l0_{ch}", "W/m²/sr", f"fog-free radiance L₀, {ch} channel", (0.0, 10.0)) for ch in "rgb"
)
_RAMP = {
    "start": Param(0.0, -1e4, 1e4, unit="scene unit", description="fog start: f = 1 for d ≤ start",
                   published=False),
    "end": Param(100.0, -1e4, 1e4, unit="scene unit", description="fog end: f = 0 for d ≥ end",
                 published=False),
}  # fmt: skip
_DENSITY = {
    "density": Param(0.1, 0.0, 1e4, unit="1/scene unit", description="fog density ρ", published=False),
}
_SEED = {
    **_RAMP,
    "fog_max": Param(1.0, 0.0, 2.0, unit="1", description="largest fog amount (vFogParams.z; ≥ 1: no cap)",
                     published=False),
}  # fmt: skip
_FADE = {
    "y_fade": Param(_SEED_FADE, 1e-3, 1e6, unit="W/m²/sr",
                    description="luminance at which the seed's fade removes the fog (000:693: 10)"),
}  # fmt: skip
_COLOUR = {
    f"c_{ch}": Param(
        0.1, 0.0, 100.0, unit="W/m²/sr", description=f"fog colour C, {ch} channel", published=False
    )
    for ch in "rgb"
}
_GL = "OpenGL 1.x glFog (fixed-function fog); Direct3D 9 fixed-function fog"
_BEER = "Beer–Lambert law; Hillaire 2015 (Frostbite physically based volumetric rendering)"

METHODS = method_table(
    [
        Method(
            id="fog-linear",
            label="linear fog (GL_LINEAR)",
            kernel=_linear_kernel,
            inputs=(_LENGTH,),
            params=_RAMP,
            quantity="fog_transmittance",
            formula="f = clamp((end − d)/(end − start), 0, 1)",
            source=_GL,
        ),
        Method(
            id="fog-exp",
            label="exponential fog (GL_EXP; Beer–Lambert at ρ = σt)",
            kernel=_exp_kernel,
            inputs=(_LENGTH,),
            params=_DENSITY,
            exact=True,
            quantity="fog_transmittance",
            formula="f = e^(−ρ·d); exact (Beer–Lambert) in a homogeneous medium with ρ = σt",
            source=f"{_GL}; {_BEER}",
        ),
        Method(
            id="fog-exp2",
            label="exponential-squared fog (GL_EXP2)",
            kernel=_exp2_kernel,
            inputs=(_LENGTH,),
            params=_DENSITY,
            quantity="fog_transmittance",
            formula="f = e^(−(ρ·d)²)",
            source=_GL,
        ),
        Method(
            id="fog-seed",
            label="seed linear fog (000:658-673), capped",
            kernel=_seed_kernel,
            inputs=(_LENGTH,),
            params=_SEED,
            quantity="fog_transmittance",
            formula="f = 1 − min(saturate((d − start)/(end − start)), fog_max)",
            source="seed 000:658-673, 000:693-694 (its fade needs the colour: fogged_radiance)",
        ),
        Method(
            id="blend-linear",
            label="linear fog blend",
            kernel=_blend_linear_kernel,
            inputs=(_LENGTH, *_FOG_FREE),
            params={**_RAMP, **_COLOUR},
            quantity="fogged_radiance",
            formula="L = L₀·f + C·(1 − f), f = clamp((end − d)/(end − start), 0, 1)",
            source=_GL,
        ),
        Method(
            id="blend-exp",
            label="exponential fog blend",
            kernel=_blend_exp_kernel,
            inputs=(_LENGTH, *_FOG_FREE),
            params={**_DENSITY, **_COLOUR},
            quantity="fogged_radiance",
            formula="L = L₀·f + C·(1 − f), f = e^(−ρ·d)",
            source=_GL,
        ),
        Method(
            id="blend-exp2",
            label="exponential-squared fog blend",
            kernel=_blend_exp2_kernel,
            inputs=(_LENGTH, *_FOG_FREE),
            params={**_DENSITY, **_COLOUR},
            quantity="fogged_radiance",
            formula="L = L₀·f + C·(1 − f), f = e^(−(ρ·d)²)",
            source=_GL,
        ),
        Method(
            id="blend-seed",
            label="seed fog with luminance fade (000:683-703)",
            kernel=_blend_seed_kernel,
            inputs=(_LENGTH, *_FOG_FREE),
            params={**_SEED, **_FADE, **_COLOUR},
            quantity="fogged_radiance",
            formula="k = min(saturate((d − start)/(end − start))·(1 − Y(L₀)/y_fade), fog_max); "
            "L = L₀ + (C − L₀)·k",
            source="seed 000:658-673 and 000:683-703 (Y: Rec. 709 luminance)",
        ),
        Method(
            id="blend-beer-lambert",
            label="Beer–Lambert blend, medium's σt",
            kernel=_blend_exp_kernel,
            inputs=(_LENGTH, *_FOG_FREE, _SIGMA_T),
            params=_COLOUR,
            quantity="fogged_radiance",
            formula="L = L₀·T + C·(1 − T), T = e^(−σt·d) (exact for a constant source S: C = S/σt)",
            source=_BEER,
        ),
    ]
)
"""The family's rows: four fog factors on ``fog_transmittance`` and five fog blends on ``fogged_radiance``."""

TRANSMITTANCE_ROWS = tuple(k for k, m in METHODS.items() if m.quantity == "fog_transmittance")
RADIANCE_ROWS = tuple(k for k, m in METHODS.items() if m.quantity == "fogged_radiance")


# ===================================================================================== public API
def _check_distance(distance):
    check_range("distance", distance, 0.0, math.inf, interval="[0, inf] (scene units)")


def _check_ramp(start, end):
    check_range("start", start, -1e30, 1e30, interval="[-1e30, 1e30] (finite, scene units)")
    check_range("end", end, -1e30, 1e30, interval="[-1e30, 1e30] (finite, scene units)")


def linear_fog_factor(distance, start, end):
    """f = clamp((end − d)/(end − start), 0, 1) at view distance ``distance`` ≥ 0 (may be inf); a step at
    ``end`` where start = end (the module docstring). Dimensionless."""
    _check_distance(distance)
    _check_ramp(start, end)
    return evaluate(_linear_kernel, distance, start, end)


def exponential_fog_factor(distance, density):
    """f = e^(−ρ·d) (Beer–Lambert with ρ = σt); ``density`` ρ in [0, 3.4e38] 1/scene unit; 1 where ρ = 0."""
    _check_distance(distance)
    check_range("density", density, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, 1/scene unit)")
    return evaluate(_exp_kernel, distance, density)


def exponential2_fog_factor(distance, density):
    """f = e^(−(ρ·d)²); ``density`` ρ in [0, 3.4e38] 1/scene unit; 1 where ρ = 0."""
    _check_distance(distance)
    check_range("density", density, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, 1/scene unit)")
    return evaluate(_exp2_kernel, distance, density)


def seed_fog_amount(distance, start, end):
    """The seed's fFog = saturate((d − start)/(end − start)) (000:668-670: the fog amount, 1 − f)."""
    _check_distance(distance)
    _check_ramp(start, end)
    return evaluate(_seed_amount, distance, start, end)
