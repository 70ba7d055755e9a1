r"""Exponential height fog: optical depth, transmittance, fog colour and fog volumes.

Density and units
-----------------
Extinction coefficient σt(p) = b·exp(−c·h(p)) per metre (scene unit), with ``density`` b ≥ 0 (1/m, the
extinction at height h = 0), ``falloff`` c ≥ 0 (1/m; the scale height is 1/c), and h the height: world
z for the global fog, h(p) = (p − p₀)·ĝ for a fog volume with an oriented, shifted gradient.
Heights and distances in metres; optical depth τ dimensionless; transmittance T = e^(−τ) ∈ [0, 1].

Closed form (seed 000:2188-2246, CryEngine 2, Wenzel 2007; 002:166-290)
-----------------------------------------------------------------------
Along a straight segment of length D from height z₀ to height z₁ (Δz = z₁ − z₀, |Δz| ≤ D):

    τ = ∫₀ᴰ b·e^(−c·z(s)) ds = b·D·e^(−c·z₀)·(1 − e^(−c·Δz))/(c·Δz)

The integral is symmetric in its end points, so the kernel uses the lower one, z_min = min(z₀, z₁),
and y = c·|Δz| ≥ 0:

    τ = b·D·e^(−c·z_min)·φ(y),   φ(y) = (1 − e^(−y))/y ∈ (0, 1]

* φ never overflows (the seed's e^(−c·Δz) overflows float32 once c·Δz < −88: a camera 1 km above dense
  ground fog looking down);
* y < 0.5: φ from its Taylor series Σₖ (−y)ᵏ/(k+1)! to k = 13, so Δz = 0 and tiny c·Δz have no
  cancellation and no 0/0. An alternating series with decreasing terms: truncation ≤ 0.5¹⁴/15! = 4.7e-17,
  relative ≤ 6e-17 as φ(0.5) = 0.787, so float64 is at its rounding (measured against mpmath: ≤ 1.5e-16
  below y = 0.5, ≤ 2.9e-16 above) and float32 unchanged (≤ 1.8e-7). Up to session 4 the series stopped at
  k = 9: 3.0e-11 relative for y ∈ [0.285, 0.5), where the float64 claim of 1e-13 did not hold;
* y ≥ 0.5: φ = (1 − e^(−y))/y (a few ulp; for the ray form D·φ = (1 − e^(−y))/(c·|d_z|), which stays
  finite for D = ∞);
* e^(−c·z_min) is applied as (b·D·φ·h)·h with h = e^(−c·z_min/2): one exp, and no intermediate
  overflow while τ itself is in float range (τ = +∞, T = 0 exactly, beyond it);
* b = 0 or D = 0 → τ = 0 exactly (never 0·∞); c = 0 → τ = b·D (homogeneous fog).

Measured float32 relative error against mpmath (tests/test_height_fog.py; the docs/height-fog.md table):
|τ₃₂/τ − 1| ≤ 2e-6 + 2·2⁻²⁴·|c·z_min| over z ∈ [−10⁴, 10⁴] m, D ∈ [0, 10⁶] m, b ∈ [0, 1] /m,
c ∈ [0, 10] /m (the second term is the conditioning of e^(−c·z) itself: float32 inputs carry it).

Comparison forms (same inputs, rows of the experiment; `METHODS` ids ``exact``, ``seed``, ``taylor``):

* ``seed``: the seed's HLSL listing exactly as written (000:2226-2240): ``fogInt = D·e^(−c·z₀)``, multiplied
  by (1 − e^(−t))/t with t = c·Δz only when |Δz| > 0.01 — a threshold on the *raw height difference in
  metres*, not on t, so with small c (tall fog) rays with |Δz| just above 0.01 m evaluate (1 − e^(−t))/t
  with t ~ 1e-5 in float32 (catastrophic cancellation), and with large c rays below the threshold drop
  the height term although c·Δz may be large. No overflow guard: e^(−t) = ∞ for t < −88.7 gives τ = ∞
  (T = 0) and with b = 0 the seed's b·fogInt is 0·∞ = NaN.
* ``taylor``: the form current engines ship (as in Unreal Engine 4's exponential height fog shader,
  quoted from memory, rewritten in base e): x = max(c·Δz, −127·ln 2) (their exp2 overflow clamp),
  φ = (1 − e^(−x))/x when |x| > 0.01·ln 2, else its first-order Taylor polynomial 1 − x/2.

Sky pixels (infinite distance)
------------------------------
`height_fog_optical_depth_ray` takes the ray's unit direction z component d_z and accepts D = +∞:
τ∞ = b·e^(−c·z₀)/(c·d_z) for d_z > 0 and c > 0 (the fog column above the camera seen along the ray),
τ = +∞ (T = 0) for d_z ≤ 0 or c = 0 with b > 0, and 0 for b = 0. Experiments that bound the fog by a
volume (as the reference does) pass the distance to the volume's exit instead.

Fog colour and shading
----------------------
L = L_scene·T + C·(1 − T) (fog composited over the scene, seed 000:2247-2254). C is a constant colour or
the seed's sky-matched colour: the horizon average of the sky's in-scatter H times the per-pixel phase
function of the angle θ between the view ray and the sun, here normalised to mean 1 over the sphere,
C(θ) = H_R·4π·p_R(θ) + H_M·4π·p_HG(θ, g), with p_R = 3(1 + cos²θ)/(16π) and
p_HG = (1 − g²)/(4π(1 + g² − 2g cos θ)^{3/2}) (the one phase text, `rtfit.realtime.phase`).
cos θ = v·l with v the view direction (camera → pixel) and l the direction to the sun.

Methods as data (`METHODS`)
---------------------------
The optical-depth forms (``exact``, ``seed``, ``taylor``: inputs z0, z1, distance in m; params b, c in 1/m)
and the two shading models of the experiment, each L = L₀·T + C·(1 − T) on the fog-free radiance L₀ with T
from the stable form along the segment: ``const`` (C = (r0, g0, b0)) and ``phase``
(C = (r0, g0, b0) + (r1, g1, b1)·4π·p_HG(θ, g)). Each declares its inputs with units and its free
parameters with defaults, bounds and units; `rtfit.fitting.fit_method` fits them through the JAX run of the
same kernel text, and ``method(NUMPY_OPS, inputs, params)`` is its NumPy run.

Fog volumes (seed 000:2255-2301)
--------------------------------
A box or ellipsoid given by its centre, half extents and a rotation (local axes as columns), with its own
b, c and a gradient ĝ through p₀. The view ray is intersected in the volume's local frame (unit cube or
unit sphere, the ray direction transformed but not renormalised, so ray parameters t are world metres);
the segment [max(t_in, 0), min(t_out, t_max)] gives z₀, z₁ = heights along ĝ of its end points and D its
length. Several volumes: optical depths add; their colours are mixed by optical-depth share (exact when
the colours are equal; an approximation of front-to-back order otherwise, as the seed's per-object mix).

Validation
----------
Python/NumPy scalars and NumPy arrays are validated at the entry points (NaN or negative density, falloff
or distance → one-line ValueError). Dr.Jit arrays are not checked (no host sync); negative b, c, D are
clamped to 0. Kernels are written once against the ops namespace (`rtfit.realtime.arrays`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import numpy as np

from .arrays import NUMPY_OPS, check_range, evaluate, is_drjit, safe_div, same_bits, split3
from .methods import Input, Method, Param, method_table
from .phase import hg_phase, hg_phase_kernel, rayleigh_phase

__all__ = [
    "OPTICAL_DEPTH_FORMS",
    "TRANSMITTANCE_METHODS",
    "FogVolume",
    "apply_fog",
    "fog_colour_phase",
    "fog_pass",
    "fog_volume_segment",
    "fog_volumes_optical_depth",
    "fog_volumes_shade",
    "height_fog_optical_depth",
    "height_fog_optical_depth_ray",
    "height_fog_transmittance",
    "optical_depth_form",
    "transmittance_method",
]

_SERIES_LIMIT = 0.5
_PHI_COEFFS = tuple((-1.0) ** k / math.factorial(k + 1) for k in range(14))  # 1, −1/2, 1/6, …, −1/14!
_TINY = 1e-30
_SEED_THRESHOLD = 0.01  # metres of raw height difference (000:2233)
_UE_CLAMP = -127.0 * math.log(2.0)
_UE_EPS = 0.01 * math.log(2.0)
_G_LIMIT = 0.999  # |g| accepted by the public functions (that of `rtfit.realtime.phase`)


# ===================================================================================== kernels (ops text)
def _phi_series(ops, y):
    """φ(y) = (1 − e^(−y))/y for 0 ≤ y ≤ 0.5 by Horner, 14 terms (truncation ≤ 0.5¹⁴/15! = 4.7e-17)."""
    acc = _PHI_COEFFS[-1]
    for coef in reversed(_PHI_COEFFS[:-1]):
        acc = ops.fma(acc, y, coef)
    return acc


def _exp_limit(ops, x) -> float:
    """Largest exponent e for which (pre·e^(e/2))·e^(e/2) cannot overflow before τ itself does: 176 in float32
    (e^88 < 3.4e38; any τ with e > 176 and pre ≥ the smallest normal 1.2e-38 exceeds float32),
    1400 in float64 (NumPy floats and JAX float64 tracers included)."""
    if ops.name == "drjit":
        return 1400.0 if dr.is_array_v(x) and dr.type_v(x) == dr.VarType.Float64 else 176.0
    return 176.0 if getattr(x, "dtype", np.float64) == np.float32 else 1400.0


def _scale_exp(ops, pre, e):
    """pre·e^e for pre ≥ 0 as (pre·h)·h with h = e^(e/2): one exp, no intermediate overflow; 0 when pre = 0
    (even where e^e = ∞), +∞ when e exceeds `_exp_limit` (τ beyond float range)."""
    limit = _exp_limit(ops, e)
    h = ops.exp(0.5 * ops.minimum(e, limit))
    # pre = ∞ (an infinite path, e.g. a horizontal sky ray) stays ∞ even where h underflows to 0 (no ∞·0)
    tau = ops.select((e > limit) | (pre == math.inf), math.inf, (pre * h) * h)
    return ops.select(pre > 0.0, tau, 0.0)


def _core(ops, zmin, y, dist, dist_over_y, b, c):
    """τ = b·e^(−c·z_min)·D·φ(y); ``dist_over_y`` = D/y (or 1/(c|d_z|)) used where y ≥ 0.5."""
    small = y < _SERIES_LIMIT
    ser = dist * _phi_series(ops, ops.minimum(y, _SERIES_LIMIT))
    yl = ops.maximum(y, _SERIES_LIMIT)
    direct = (1.0 - ops.exp(-yl)) * dist_over_y
    d_phi = ops.select(small, ser, direct)
    e = ops.select(c > 0.0, -c * zmin, 0.0)
    return _scale_exp(ops, b * d_phi, e)


def _optical_depth_kernel(ops, z0, z1, distance, b, c):
    """The stable closed form (module docstring): τ = b·D·e^(−c·z_min)·φ(c·|Δz|)."""
    b = ops.maximum(b, 0.0)
    c = ops.maximum(c, 0.0)
    distance = ops.maximum(distance, 0.0)
    zmin = ops.minimum(z0, z1)
    y = c * ops.abs(z1 - z0)
    return _core(ops, zmin, y, distance, safe_div(ops, distance, y), b, c)


def _optical_depth_ray_kernel(ops, z0, dz, distance, b, c):
    b = ops.maximum(b, 0.0)
    c = ops.maximum(c, 0.0)
    distance = ops.maximum(distance, 0.0)
    down = dz < 0.0
    zmin = z0 + ops.select(down, dz * ops.select(down, distance, 0.0), 0.0)
    rate = c * ops.abs(dz)
    y = ops.select(rate > 0.0, rate * ops.select(rate > 0.0, distance, 0.0), 0.0)
    return _core(ops, zmin, y, distance, safe_div(ops, 1.0, rate), b, c)


def _seed_kernel(ops, z0, z1, distance, b, c):
    """000:2226-2240 as written (returns the optical depth b·fogInt, T = e^(−that))."""
    dz = z1 - z0
    fog_int = distance * ops.exp(-c * z0)
    t = c * dz
    fog_int = ops.select(ops.abs(dz) > _SEED_THRESHOLD, fog_int * ((1.0 - ops.exp(-t)) / t), fog_int)
    return b * fog_int


def _taylor_kernel(ops, z0, z1, distance, b, c):
    """Engine form: clamped exponent, first-order Taylor polynomial near horizontal rays."""
    x = ops.maximum(c * (z1 - z0), _UE_CLAMP)
    far = ops.abs(x) > _UE_EPS
    # the division only where it is selected: c = 0 (constant fog) or Δz = 0 would compute 0/0 in the
    # branch the select drops, which is harmless in a shader but poisons a JAX fit's gradient with NaN
    xs = ops.select(far, x, 1.0)
    exact = (1.0 - ops.exp(-xs)) / xs
    taylor = 1.0 - 0.5 * x
    phi = ops.select(far, exact, taylor)
    return b * distance * ops.exp(-c * z0) * phi


def _transmittance_kernel(ops, z0, z1, distance, b, c):
    return ops.exp(-_optical_depth_kernel(ops, z0, z1, distance, b, c))


class _NumpyMemo:
    """The last few results of a NumPy computation by its arguments' exact bytes (dtype, shape and bit
    pattern of each: a stored copy, so an argument changed in place is a miss). A fit's finite-difference
    Jacobian (`rtfit.fitting.fit_method`, ``solver="trf"``) calls a shading kernel once per parameter step
    on the same inputs: the transmittance does not change when only a colour moves, nor the phase weight
    when b, c or a colour does. The cached arrays are read, never written, by the kernels below."""

    def __init__(self, size: int = 2):
        self.size = size
        self.entries: list = []

    def get(self, compute, *args):
        arrs = [np.asarray(a) for a in args]
        for i, (keys, value) in enumerate(self.entries):
            if all(same_bits(k, a) for k, a in zip(keys, arrs, strict=True)):
                self.entries.append(self.entries.pop(i))
                return value
        value = compute(NUMPY_OPS, *args)
        self.entries.append(([np.array(a, copy=True) for a in arrs], value))
        del self.entries[: -self.size]
        return value


_T_MEMO = _NumpyMemo()
_W_MEMO = _NumpyMemo()


def _segment_transmittance(ops, z0, z1, distance, b, c):
    """`_transmittance_kernel` (memoised on NumPy: `_NumpyMemo`)."""
    if ops.name == "numpy":
        return _T_MEMO.get(_transmittance_kernel, z0, z1, distance, b, c)
    return _transmittance_kernel(ops, z0, z1, distance, b, c)


def _phase_weight(ops, cos_sun, g):
    """4π·p_HG(θ, g) (mean 1 over the sphere)."""
    return 4.0 * math.pi * hg_phase_kernel(ops, ops.clip(cos_sun, -1.0, 1.0), g)


def _fog_colour(ops, cos_sun, r0, g0, b0, r1, g1, b1, g):
    """C(θ) = C₀ + C₁·4π·p_HG(θ, g) per channel (4π·p_HG has mean 1 over the sphere)."""
    w = _W_MEMO.get(_phase_weight, cos_sun, g) if ops.name == "numpy" else _phase_weight(ops, cos_sun, g)
    return ops.fma(r1, w, r0), ops.fma(g1, w, g0), ops.fma(b1, w, b0)


def _blend(ops, t, l0_r, l0_g, l0_b, cr, cg, cb):
    """L = L₀·T + C·(1 − T) per channel."""
    one_t = 1.0 - t
    return ops.fma(l0_r, t, cr * one_t), ops.fma(l0_g, t, cg * one_t), ops.fma(l0_b, t, cb * one_t)


def _fog_const_kernel(ops, z0, z1, distance, l0_r, l0_g, l0_b, b, c, r0, g0, b0):
    """Shading model ``const``: T of the stable form along the segment, constant fog colour."""
    t = _segment_transmittance(ops, z0, z1, distance, b, c)
    return _blend(ops, t, l0_r, l0_g, l0_b, r0, g0, b0)


def _fog_phase_kernel(ops, z0, z1, distance, cos_sun, l0_r, l0_g, l0_b, b, c, r0, g0, b0, r1, g1, b1, g):
    """Shading model ``phase``: as ``const`` with the colour C₀ + C₁·4π·p_HG(θ, g)."""
    t = _segment_transmittance(ops, z0, z1, distance, b, c)
    return _blend(ops, t, l0_r, l0_g, l0_b, *_fog_colour(ops, cos_sun, r0, g0, b0, r1, g1, b1, g))


# ===================================================================================== methods (data)
_SEGMENT = (
    Input("z0", "m", "height of the segment's start (the camera end) along the fog gradient"),
    Input("z1", "m", "height of the segment's end along the fog gradient"),
    Input("distance", "m", "segment length D (|z1 − z0| ≤ D)"),
)
_FOG_FREE = tuple(Input(f"l0_{ch}", "W/m²/sr", f"fog-free radiance L₀, {ch} channel") for ch in "rgb")
_COS_SUN = Input("cos_sun", "1", "cos θ = v·l: view direction · direction to the sun")
_DENSITY = {
    "b": Param(2e-4, 2e-7, 0.2, unit="1/m", description="density b: extinction at height 0"),
    "c": Param(4e-3, 4e-6, 0.4, unit="1/m", description="falloff c: the scale height is 1/c"),
}
_COLOUR = {
    f"{ch}0": Param(0.1, 0.0, 100.0, unit="W/m²/sr", description=f"constant fog colour C₀, {ch} channel")
    for ch in "rgb"
}
_PHASE_COLOUR = {
    **{
        f"{ch}1": Param(0.01, 0.0, 100.0, unit="W/m²/sr", description=f"phase-weighted colour C₁, {ch}")
        for ch in "rgb"
    },
    "g": Param(0.5, -0.95, 0.95, unit="1", description="Henyey–Greenstein mean cosine of the colour lobe"),
}

METHODS = method_table(
    [
        Method(
            id="exact",
            label="stable closed form (rtfit)",
            kernel=_optical_depth_kernel,
            inputs=_SEGMENT,
            params=_DENSITY,
            exact=True,
            quantity="fog_optical_depth",
            formula="τ = b·D·e^(−c·z_min)·φ(c·|Δz|), φ(y) = (1 − e^(−y))/y (Taylor series below y = 0.5)",
            source="seed 000:2196-2210 (derivation); rtfit (stable evaluation)",
        ),
        Method(
            id="seed",
            label="seed listing (000:2226-2240)",
            kernel=_seed_kernel,
            inputs=_SEGMENT,
            params=_DENSITY,
            quantity="fog_optical_depth",
            formula="b·D·e^(−c·z₀)·(1 − e^(−cΔz))/(cΔz) where |Δz| > 0.01 m, else b·D·e^(−c·z₀)",
            source="seed 000:2226-2240 (as written)",
        ),
        Method(
            id="taylor",
            label="engine form (clamp + 1st-order Taylor)",
            kernel=_taylor_kernel,
            inputs=_SEGMENT,
            params=_DENSITY,
            quantity="fog_optical_depth",
            formula="x = max(cΔz, −127 ln 2); b·D·e^(−c·z₀)·((1 − e^(−x))/x if |x| > 0.01 ln 2 else 1 − x/2)",
            source="Unreal Engine 4 exponential height fog (quoted from memory, base e)",
        ),
        Method(
            id="const",
            label="fog blend, constant colour",
            kernel=_fog_const_kernel,
            inputs=(*_SEGMENT, *_FOG_FREE),
            params={**_DENSITY, **_COLOUR},
            quantity="fogged_radiance",
            formula="L = L₀·T(b, c) + C·(1 − T)",
            source="seed 000:2247-2254",
        ),
        Method(
            id="phase",
            label="fog blend, colour C₀ + C₁·4π·p_HG(θ, g)",
            kernel=_fog_phase_kernel,
            inputs=(*_SEGMENT, _COS_SUN, *_FOG_FREE),
            params={**_DENSITY, **_COLOUR, **_PHASE_COLOUR},
            quantity="fogged_radiance",
            formula="L = L₀·T(b, c) + (C₀ + C₁·4π·p_HG(θ, g))·(1 − T)",
            source="seed 000:2247-2254 (per-pixel phase-weighted fog colour)",
        ),
    ]
)
"""The family's methods: three optical-depth forms and two shading models (see the module docstring)."""

OPTICAL_DEPTH_FORMS = tuple(k for k, m in METHODS.items() if m.quantity == "fog_optical_depth")
"""Optical-depth forms compared by the experiment: rtfit's stable form, the seed listing, the engine form."""


def transmittance_method(form: Method) -> Method:
    """An optical-depth form of `METHODS` (quantity ``fog_optical_depth``) as a transmittance method: the
    form's own kernel τ(z0, z1, D; b, c), then T = e^(−τ) (quantity ``fog_transmittance``; same id, inputs,
    parameters and exactness)."""

    def kernel(ops, **kw):
        return ops.exp(-form.kernel(ops, **kw))

    kernel.__qualname__ = kernel.__name__ = f"transmittance_of_{form.id}"
    return Method(
        id=form.id,
        label=f"{form.label}, T = e^(−τ)",
        kernel=kernel,
        inputs=form.inputs,
        params=form.params,
        fixed=form.fixed,
        exact=form.exact,
        quantity="fog_transmittance",
        formula=f"T = e^(−τ), {form.formula}",
        source=form.source,
        description=form.description,
    )


TRANSMITTANCE_METHODS = {f: transmittance_method(METHODS[f]) for f in OPTICAL_DEPTH_FORMS}
"""The optical-depth forms as transmittance rows (one object each: a fit compiles once per method)."""


# ===================================================================================== validation
def _check(z0, z1, dist, b, c, *, allow_inf_dist=False):
    for name, v in (("camera_z", z0), ("end_z", z1)):
        check_range(name, v, -math.inf, math.inf, interval="finite numbers")
    check_range(
        "distance",
        dist,
        0.0,
        math.inf if allow_inf_dist else 3.4e38,
        interval="[0, inf]" if allow_inf_dist else "[0, 3.4e38] (finite)",
    )
    check_range("density", b, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, 1/m)")
    check_range("falloff", c, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, 1/m)")


def _finite(name, v):
    if isinstance(v, np.ndarray) or not dr.is_array_v(v):
        a = np.asarray(v, dtype=np.float64)
        if a.size and not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite (got {a[~np.isfinite(a)].flat[0]!r})")


# ===================================================================================== public API
def height_fog_optical_depth(camera_z, end_z, distance, density, falloff):
    """Optical depth ∫ b·e^(−c·z) ds over a straight segment of length ``distance`` (m) from height
    ``camera_z`` to ``end_z`` (m); ``density`` b (1/m) and ``falloff`` c (1/m) ≥ 0. Dimensionless.

    Stable in float32 over the whole domain (see module docstring). Python floats → float (float64);
    NumPy → NumPy (the default Dr.Jit backend); Dr.Jit → same type, lazily; JAX → JAX (differentiable).
    """
    _finite("camera_z", camera_z)
    _finite("end_z", end_z)
    _check(camera_z, end_z, distance, density, falloff)
    return evaluate(_optical_depth_kernel, camera_z, end_z, distance, density, falloff)


def height_fog_transmittance(camera_z, end_z, distance, density, falloff):
    """T = e^(−τ) of `height_fog_optical_depth` (dimensionless, in [0, 1]; exactly 0 when τ overflows)."""
    _finite("camera_z", camera_z)
    _finite("end_z", end_z)
    _check(camera_z, end_z, distance, density, falloff)
    return evaluate(_transmittance_kernel, camera_z, end_z, distance, density, falloff)


def height_fog_optical_depth_ray(camera_z, dir_z, distance, density, falloff):
    """Optical depth along a ray from height ``camera_z`` (m) with unit-direction z component ``dir_z``
    over ``distance`` (m, may be +inf: sky pixels, see the module docstring)."""
    _finite("camera_z", camera_z)
    check_range("dir_z", dir_z, -1.0001, 1.0001, interval="[-1, 1]")
    _check(camera_z, camera_z, distance, density, falloff, allow_inf_dist=True)
    return evaluate(_optical_depth_ray_kernel, camera_z, dir_z, distance, density, falloff)


def optical_depth_form(form: str, camera_z, end_z, distance, density, falloff):
    """Optical depth with one of `OPTICAL_DEPTH_FORMS` ("exact", "seed", "taylor"): ``METHODS[form]``
    evaluated with the package's dispatch; no validation beyond the form name (the comparison rows must
    see what each form does with any input)."""
    if form not in OPTICAL_DEPTH_FORMS:
        raise ValueError(f"form must be one of {OPTICAL_DEPTH_FORMS} (got {form!r})")
    return METHODS[form].evaluate(
        {"z0": camera_z, "z1": end_z, "distance": distance}, {"b": density, "c": falloff}
    )


def fog_colour_phase(cos_theta, rayleigh_colour, mie_colour, g):
    """Sky-matched fog colour C(θ) = H_R·4π·p_R(θ) + H_M·4π·p_HG(θ, g) per channel (radiance units of H).

    ``rayleigh_colour`` and ``mie_colour`` are RGB triples (the horizon-averaged in-scatter without phase,
    seed 000:2247-2254); returns a tuple of three channels shaped like ``cos_theta``.
    """
    pr = rayleigh_phase(cos_theta)
    pm = hg_phase(cos_theta, g)
    return tuple(
        4.0 * math.pi * (float(rayleigh_colour[i]) * pr + float(mie_colour[i]) * pm) for i in range(3)
    )


def apply_fog(radiance, transmittance, fog_colour):
    """L·T + C·(1 − T): ``radiance`` (…, 3), ``transmittance`` (…), ``fog_colour`` (3,) or (…, 3)."""
    t = np.asarray(transmittance)[..., None]
    return np.asarray(radiance) * t + np.asarray(fog_colour) * (1.0 - t)


# ===================================================================================== fog volumes
@dataclass(frozen=True)
class FogVolume:
    """A box or ellipsoid fog volume (metres; density and falloff in 1/m; colour RGB radiance).

    ``rotation`` is the 3×3 world-from-local rotation (rows of a nested tuple), ``half_size`` the half
    extents (box) or semi-axes (ellipsoid) along the local axes.
    Density b·e^(−c·(p − gradient_origin)·gradient).
    """

    center: tuple
    half_size: tuple
    rotation: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    ellipsoid: bool = False
    density: float = 0.0
    falloff: float = 0.0
    gradient: tuple = (0.0, 0.0, 1.0)
    gradient_origin: tuple = (0.0, 0.0, 0.0)
    colour: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        # Python floats only: a NumPy scalar times a Dr.Jit array becomes an ndarray (facts note §12).
        set_ = object.__setattr__
        set_(self, "center", tuple(float(x) for x in self.center))
        set_(self, "half_size", tuple(float(x) for x in self.half_size))
        set_(self, "rotation", tuple(tuple(float(x) for x in row) for row in self.rotation))
        set_(self, "gradient_origin", tuple(float(x) for x in self.gradient_origin))
        set_(self, "colour", tuple(float(x) for x in self.colour))
        set_(self, "density", float(self.density))
        set_(self, "falloff", float(self.falloff))
        set_(self, "ellipsoid", bool(self.ellipsoid))
        if len(self.center) != 3 or len(self.rotation) != 3 or any(len(r) != 3 for r in self.rotation):
            raise ValueError("center must have 3 components and rotation must be 3×3")
        check_range("density", self.density, 0.0, 3.4e38)
        check_range("falloff", self.falloff, 0.0, 3.4e38)
        if len(self.half_size) != 3 or not all(h > 0 and math.isfinite(h) for h in self.half_size):
            raise ValueError(f"half_size must be 3 finite numbers > 0 (got {self.half_size!r})")
        n = math.sqrt(sum(float(x) ** 2 for x in self.gradient))
        if not (n > 0 and math.isfinite(n)):
            raise ValueError(f"gradient must be a non-zero finite vector (got {self.gradient!r})")
        object.__setattr__(self, "gradient", tuple(float(x) / n for x in self.gradient))


def _volume_segment_kernel(ops, ox, oy, oz, dx, dy, dz, tmax, vol):
    """(z0, z1, D): heights along the volume's gradient at the entry and exit of the ray's segment inside
    ``vol`` (clipped to t ∈ [0, tmax]) and its length; (0, 0, 0) where the ray misses."""
    r = vol.rotation
    cx, cy, cz = vol.center
    hx, hy, hz = vol.half_size
    px, py, pz = ox - cx, oy - cy, oz - cz
    # local = Rᵀ (p − c) / h ; direction likewise (not renormalised: t stays in world metres)
    lo = [(r[0][k] * px + r[1][k] * py + r[2][k] * pz) / h for k, h in enumerate((hx, hy, hz))]
    ld = [(r[0][k] * dx + r[1][k] * dy + r[2][k] * dz) / h for k, h in enumerate((hx, hy, hz))]
    inf = math.inf
    if vol.ellipsoid:
        a = ld[0] * ld[0] + ld[1] * ld[1] + ld[2] * ld[2]
        bq = lo[0] * ld[0] + lo[1] * ld[1] + lo[2] * ld[2]
        cq = lo[0] * lo[0] + lo[1] * lo[1] + lo[2] * lo[2] - 1.0
        disc = bq * bq - a * cq
        hit = disc >= 0.0
        sq = ops.sqrt(ops.maximum(disc, 0.0))
        q = -(bq + ops.select(bq >= 0.0, sq, -sq))
        qs = ops.select(ops.abs(q) > 0.0, q, 1.0)
        ta = q / ops.maximum(a, _TINY)
        tb = ops.select(ops.abs(q) > 0.0, cq / qs, 0.0)
        t_in = ops.select(hit, ops.minimum(ta, tb), inf)
        t_out = ops.select(hit, ops.maximum(ta, tb), -inf)
    else:
        t_in, t_out = -inf, inf
        for k in range(3):
            par = ops.abs(ld[k]) < 1e-30
            dd = ops.select(par, 1.0, ld[k])
            t1 = (-1.0 - lo[k]) / dd
            t2 = (1.0 - lo[k]) / dd
            inside = ops.abs(lo[k]) <= 1.0
            t_in = ops.maximum(t_in, ops.select(par, ops.select(inside, -inf, inf), ops.minimum(t1, t2)))
            t_out = ops.minimum(t_out, ops.select(par, ops.select(inside, inf, -inf), ops.maximum(t1, t2)))
    t0 = ops.maximum(t_in, 0.0)
    t1_ = ops.minimum(t_out, tmax)
    seg = ops.maximum(t1_ - t0, 0.0)
    valid = seg > 0.0
    t0 = ops.select(valid, t0, 0.0)
    t1_ = ops.select(valid, t1_, 0.0)
    gx, gy, gz = vol.gradient
    qx, qy, qz = vol.gradient_origin
    h_o = (ox - qx) * gx + (oy - qy) * gy + (oz - qz) * gz
    h_d = dx * gx + dy * gy + dz * gz
    return h_o + t0 * h_d, h_o + t1_ * h_d, ops.select(valid, seg, 0.0)


def _volume_kernel(ops, ox, oy, oz, dx, dy, dz, tmax, vol):
    z0, z1, seg = _volume_segment_kernel(ops, ox, oy, oz, dx, dy, dz, tmax, vol)
    return _optical_depth_kernel(ops, z0, z1, seg, vol.density, vol.falloff)


def _ray_components(origin, direction, max_distance):
    def comps(v, name):  # a tuple of three component arrays is taken as is (Dr.Jit wavefronts)
        if (
            isinstance(v, (tuple, list))
            and len(v) == 3
            and all(is_drjit(x) or isinstance(x, np.ndarray) for x in v)
        ):
            return tuple(v)
        return split3(v, name)

    check_range("max_distance", max_distance, 0.0, math.inf, interval="[0, inf]")
    return (*comps(origin, "origin"), *comps(direction, "direction"))


def fog_volume_segment(origin, direction, max_distance, volume):
    """The segment of rays ``origin`` + t·``direction`` (unit), t ∈ [0, max_distance] (m; inf: sky), inside
    ``volume``: a tuple (z0, z1, D) of heights along its gradient at entry and exit (m) and the length (m),
    zeros where a ray misses it. With (z0, z1, D) the volume's optical depth is
    ``height_fog_optical_depth(z0, z1, D, volume.density, volume.falloff)``."""
    ray = _ray_components(origin, direction, max_distance)

    def kernel(ops, *a):
        return _volume_segment_kernel(ops, *a, vol=volume)

    return evaluate(kernel, *ray, max_distance)


def fog_volumes_optical_depth(origin, direction, max_distance, volumes):
    """Per-volume optical depths (a list, one per volume, each shaped like ``max_distance``) along rays
    ``origin`` + t·``direction`` (unit), t ∈ [0, max_distance] (metres; inf allowed: sky)."""
    ray = _ray_components(origin, direction, max_distance)
    out = []
    for vol in volumes:

        def kernel(ops, *a, vol=vol):
            return _volume_kernel(ops, *a, vol=vol)

        out.append(evaluate(kernel, *ray, max_distance))
    return out


def fog_volumes_shade(radiance, origin, direction, max_distance, volumes):
    """Composite several fog volumes over ``radiance`` (…, 3): T = e^(−Σ τᵢ), colour mixed by τᵢ/Σ τ."""
    taus = [
        np.asarray(t, dtype=np.float64)
        for t in fog_volumes_optical_depth(origin, direction, max_distance, volumes)
    ]
    total = np.sum(taus, axis=0)
    trans = np.exp(-total)
    colour = np.zeros((*total.shape, 3))
    for tau, vol in zip(taus, volumes, strict=True):
        colour += tau[..., None] * np.asarray(vol.colour)
    colour = np.where(total[..., None] > 0, colour / np.maximum(total, 1e-300)[..., None], 0.0)
    return apply_fog(radiance, trans, colour)


# ===================================================================================== the fog pass
def _fog_pass_kernel(
    ops, r, g_, b_, z0, dz, dist, cos_sun, density, falloff, c0r, c0g, c0b, c1r, c1g, c1b, g, phase
):
    t = ops.exp(-_optical_depth_ray_kernel(ops, z0, dz, dist, density, falloff))
    colour = _fog_colour(ops, cos_sun, c0r, c0g, c0b, c1r, c1g, c1b, g) if phase else (c0r, c0g, c0b)
    return _blend(ops, t, r, g_, b_, *colour)


def fog_pass(
    radiance, camera_z, dir_z, distance, density, falloff, colour, *, cos_sun=None, phase_colour=None, g=0.0
):
    """The whole per-pixel fog pass: T along the view ray (`height_fog_optical_depth_ray`, sky pixels with
    ``distance`` = inf), then L·T + C·(1 − T) with C = ``colour`` + ``phase_colour``·4π·p_HG(cos_sun, g)
    when ``phase_colour`` is given (the seed's per-pixel phase-weighted fog colour; g ∈ [−0.999, 0.999]).

    ``radiance``: three channel arrays (r, g, b) or an (…, 3) NumPy array; returns a tuple (r, g, b).
    """
    if isinstance(radiance, np.ndarray):
        r, gg, bb = radiance[..., 0], radiance[..., 1], radiance[..., 2]
    else:
        r, gg, bb = radiance
    check_range("density", density, 0.0, 3.4e38)
    check_range("falloff", falloff, 0.0, 3.4e38)
    phase = phase_colour is not None
    if phase:
        check_range("g", g, -_G_LIMIT, _G_LIMIT)
        if cos_sun is None:
            raise ValueError("cos_sun is required with phase_colour")
    c1 = phase_colour if phase else (0.0, 0.0, 0.0)
    cs = cos_sun if cos_sun is not None else 0.0

    def kernel(ops, *a):
        return _fog_pass_kernel(ops, *a, phase=phase)

    return evaluate(
        kernel,
        r,
        gg,
        bb,
        camera_z,
        dir_z,
        distance,
        cs,
        float(density),
        float(falloff),
        *[float(x) for x in colour],
        *[float(x) for x in c1],
        float(g),
    )
