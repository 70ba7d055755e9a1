r"""Obscurances (Zhukov, Iones, Kronin 1998; Iones, Krupkin, Sbert, Zhukov 2003): ambient light as a
function of the distance to the nearest surface in each direction.

The obscurance of a surface point x with unit normal n is

    W(x) = (1/π) ∫_{H(n)} ρ(d(x, ω)) (n·ω) dω                                   (dimensionless, in [0, 1])

where d(x, ω) is the distance (scene units) from x to the first surface along ω (∞ when the ray escapes)
and ρ is the *distance function*, increasing from ρ(0) = 0 to ρ(∞) = 1: a close occluder takes light
away, a distant one (farther than d_max) does not. The shading term an engine adds is I_A · s · W(x)
(ambient intensity I_A, albedo, and the ambient scale s of the fits).

Seed (GameTools D5.3, `001_c6d9ab41e424018a.txt`, §2.10, lines 3251-3380): the transfer function at
001:3284 is ρ(d) = √(d/d_max) for d < d_max and 1 otherwise, d_max = 0.3 by default (001:3326, scene units
of the seed's meshes), 180 global directions (001:3324). rtfit generalises the square root to an exponent:

* ``power``:        ρ(d) = min(d/d_max, 1)^p   (the seed: p = ½; p → 0 gives ρ ≡ 1 for d > 0, p → ∞ the step)
* ``exponential``:  ρ(d) = 1 − e^{−d/d_max}    (no cut-off; d_max is the decay length)
* ``step``:         ρ(d) = [d ≥ d_max]          (then W is the ambient occlusion within R = d_max, the
  ``ao`` quantity of `rtfit.reference.occlusion` and of the ``sdf-occlusion`` experiment)

Limits (each checked by tests/test_obscurances.py and the experiment): d_max → ∞ with p fixed (power) or
any form: ρ(d) → 0 for every finite d, so W → the unbounded AO (cosine-weighted fraction of escaping rays);
d_max → 0 (or p → 0): W → 1; a point whose hemisphere is empty (an open plane) has W = 1 exactly.
Convention at d = 0: ρ(0) = 0 for p > 0, 1 for p = 0 (0⁰ = 1); ray casts never return 0. Dr.Jit's LLVM
backend flushes subnormal inputs to zero, so there ρ(d) = ρ(0) for subnormal d (NumPy/JAX: the true value).

The estimator: with directions ω_k distributed as cos θ/π (random or stratified), W ≈ (1/K) Σ_k ρ(d_k): the
real-time bake (the seed's depth-peeled global lines, a ray-traced light-map baker or a screen-space
variant all reduce to this sum over ray-cast hit distances). The same kernel text
(`power_obscurance_kernel`, …) runs on Dr.Jit (the product), NumPy (benchmarks) and JAX (fits), and its
``rho`` functions are what the Mitsuba reference of the model scores per ray
(`rtfit.reference.occlusion`, quantity ``"obscurance"``, which receives the ρ text as a callable).

Inputs: ``distances`` is a sequence of K per-point arrays (or a (K, N) array): the hit distance of ray k at
each point, +∞ (or any value ≥ d_max) for a miss. Stable at the extremes: misses (∞) and d_max up to 1e30
give finite values and finite JAX derivatives (the ratio is formed as min(d, d_max)/d_max, the exponential
from min(d, 100 d_max)).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from .arrays import DRJIT_OPS, evaluate
from .methods import Input, Method, Param, method_table
from .numpy_memo import KeptValues

__all__ = [
    "D_MAX_LIMIT",
    "MISS",
    "RAY_CHUNK",
    "SEED_D_MAX",
    "SEED_EXPONENT",
    "cosine_spiral_directions",
    "distance_weight",
    "exponential_obscurance_kernel",
    "obscurance",
    "plane_facing_obscurance",
    "power_obscurance_kernel",
    "rho_exponential",
    "rho_power",
    "rho_step",
    "step_obscurance_kernel",
]

SEED_D_MAX = 0.3
"""The seed's default d_max (001:3326), scene units."""
SEED_EXPONENT = 0.5
"""The seed's square root (001:3284)."""
D_MAX_LIMIT = 1e30
"""Largest d_max the public functions accept (d_max → ∞ is reached by 1e30: ρ(d) ≤ (d/1e30)^p)."""
MISS = 1e30
"""A ray that escapes, as the hit distance the audit gives a row (finite, so that JAX fits and float32 costs
stay finite: every ρ is 1 there for d_max ≤ 10²⁸)."""
AO_FD_STEP = 1e-2
"""The AO row's relative finite-difference step in d_max (`Param.fd_step`)."""
RAY_CHUNK = 64
"""Rays per fused Dr.Jit kernel in `obscurance` (more rays: several launches, their means combined)."""
_TINY = 1e-300  # log guard of ρ_power below every ratio that matters (float32: 0, the branch is unselected)
_EXP_CUT = 100.0  # e^{-100} = 3.7e-44: ρ_exp is 1 to float64 beyond 100 d_max


# ------------------------------------------------------------------------------------ distance functions
def rho_power(ops, d, d_max, exponent):
    """ρ(d) = min(d/d_max, 1)^p (001:3284 with p = ½). ``d`` ≥ 0 (∞ allowed), d_max > 0 finite, p ≥ 0.
    Written as exp(p·log t) on t > 0 so that JAX derivatives stay finite at t = 0 and t = 1."""
    t = ops.minimum(d, d_max) / d_max
    inside = ops.exp(exponent * ops.log(ops.maximum(t, _TINY)))
    at_zero = ops.select(exponent > 0.0, 0.0 * t, 1.0 + 0.0 * t)
    return ops.select(t > 0.0, inside, at_zero)


def rho_exponential(ops, d, d_max):
    """ρ(d) = 1 − e^{−d/d_max} (no cut-off). ``d`` ≥ 0 (∞ allowed), d_max > 0."""
    x = ops.minimum(d, _EXP_CUT * d_max) / d_max
    return -ops.expm1(-x)


def rho_step(ops, d, d_max):
    """ρ(d) = [d ≥ d_max]: W becomes the ambient occlusion within R = d_max."""
    zero = 0.0 * ops.minimum(d, d_max)  # (0·∞ would be NaN)
    return ops.select(d >= d_max, zero + 1.0, zero)


def _one_array(distances) -> bool:
    """Whether ``distances`` is one (K, N) array (NumPy/JAX), not a sequence of K arrays."""
    return getattr(distances, "ndim", 0) == 2


def _ray_mean(distances, rho) -> Any:
    """(1/K) Σ_k ρ(d_k) over the K rows of ``distances``: a sequence of K arrays (Dr.Jit: one fused kernel),
    or a (K, N) NumPy/JAX array (ρ on the whole array, then its mean over the rays: a small JAX graph for
    the fits whatever K is)."""
    if _one_array(distances):
        return rho(distances).mean(axis=0)
    k = len(distances)
    acc: Any = None
    for i in range(k):
        r = rho(distances[i])
        acc = r if acc is None else acc + r
    return acc * (1.0 / k)


_KEPT_MEANS = KeptValues(max_floats=1 << 22, max_entries=8)
"""The NumPy run's ray means by (ρ, its parameters) and distance arrays (`_kept_mean`)."""
MEMOS = (_KEPT_MEANS,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _kept_mean(ops, key: tuple, distances, rho) -> Any:
    """`_ray_mean` of ``rho``, kept on the NumPy run for ``key`` (ρ's name and parameters) and these distance
    arrays (`KeptValues`): a fit's Jacobian steps the scale s alone at two of its points (and a 3-parameter
    power fit: 2 of its 7 evaluations an iteration), where the mean is the one of the point before, bit for
    bit. Issue 33 (session 27): the power ρ was the quick suite's largest kernel cost in its fits (2.2 s)."""
    rays = [distances] if _one_array(distances) else list(distances)
    return _KEPT_MEANS.get(ops, key, rays, lambda _: _ray_mean(distances, rho))


# ---------------------------------------------------------------------------------------------- kernels
def power_obscurance_kernel(ops, distances, d_max=SEED_D_MAX, exponent=SEED_EXPONENT, scale=1.0):
    """s · (1/K) Σ_k min(d_k/d_max, 1)^p: the obscurance estimator with the seed's (generalised) ρ."""
    rho = lambda d: rho_power(ops, d, d_max, exponent)  # noqa: E731
    return scale * _kept_mean(ops, ("power", d_max, exponent), distances, rho)


def exponential_obscurance_kernel(ops, distances, d_max=1.0, scale=1.0):
    """s · (1/K) Σ_k (1 − e^{−d_k/d_max})."""
    rho = lambda d: rho_exponential(ops, d, d_max)  # noqa: E731
    return scale * _kept_mean(ops, ("exponential", d_max), distances, rho)


def step_obscurance_kernel(ops, distances, d_max=1.0, scale=1.0):
    """s · (1/K) Σ_k [d_k ≥ d_max]: ambient occlusion within d_max (the p → ∞ limit of the power form)."""
    return scale * _kept_mean(ops, ("step", d_max), distances, lambda d: rho_step(ops, d, d_max))


DISTANCES = Input("distances", "scene units", "hit distance of each of K cosine-distributed rays (∞: miss)")
_D_MAX = Param(
    1.0, 1e-3, 1e3, unit="scene units", description="distance beyond which a hit no longer occludes"
)
_AO_D_MAX = replace(_D_MAX, fd_step=AO_FD_STEP)
"""The AO row's d_max: the step ρ makes W a staircase in d_max (a step at every ray-hit distance): its
central differences span ±1 % of d_max (`Param.fd_step`)."""
_EXPONENT = Param(0.5, 1e-2, 16.0, unit="1", description="exponent p of ρ = min(d/d_max, 1)^p")
_SCALE = Param(1.0, 1e-2, 10.0, unit="1", description="ambient scale s (W is multiplied by it)")

METHODS = method_table(
    [
        Method(
            "seed",
            "Seed obscurance (√(d/d_max), d_max = 0.3)",
            power_obscurance_kernel,
            inputs=(DISTANCES,),
            fixed={"d_max": SEED_D_MAX, "exponent": SEED_EXPONENT, "scale": 1.0},
            quantity="obscurance",
            formula="W = (1/K) Σ_k min(d_k/0.3, 1)^½",
            source="001:3284, 001:3326",
        ),
        Method(
            "power",
            "Power obscurance (d_max, p, s fitted)",
            power_obscurance_kernel,
            inputs=(DISTANCES,),
            params={"d_max": _D_MAX, "exponent": _EXPONENT, "scale": _SCALE},
            quantity="obscurance",
            formula="s · (1/K) Σ_k min(d_k/d_max, 1)^p",
            source="001:3284 (p generalised)",
        ),
        Method(
            "exponential",
            "Exponential obscurance (d_max, s fitted)",
            exponential_obscurance_kernel,
            inputs=(DISTANCES,),
            params={"d_max": _D_MAX, "scale": _SCALE},
            quantity="obscurance",
            formula="s · (1/K) Σ_k (1 − e^{−d_k/d_max})",
            source="exponential distance function (not in the seed)",
        ),
        Method(
            "ao",
            "Ambient occlusion within d_max (step ρ)",
            step_obscurance_kernel,
            inputs=(DISTANCES,),
            params={"d_max": _AO_D_MAX},
            fixed={"scale": 1.0},
            quantity="obscurance",
            formula="(1/K) Σ_k [d_k ≥ d_max]",
            source="p → ∞ limit of 001:3284",
        ),
    ]
)
"""The obscurance estimators as data (`rtfit.realtime.methods`)."""


# ---------------------------------------------------------------------------------------- public helpers
def distance_weight(form: str, d_max: float, exponent: float | None = None):
    """(ρ as a callable on Dr.Jit arrays — this module's kernel text on `DRJIT_OPS` —, its cache key): the
    ``distance_weight`` and ``weight_key`` of the ``obscurance`` reference quantity
    (`rtfit.reference.occlusion`, which may not import this package). ``form``: ``power`` (with
    ``exponent``), ``exponential`` or ``step``; ``d_max`` in scene units."""
    table = {
        "power": (lambda t: rho_power(DRJIT_OPS, t, d_max, exponent), {"exponent": exponent}),
        "exponential": (lambda t: rho_exponential(DRJIT_OPS, t, d_max), {}),
        "step": (lambda t: rho_step(DRJIT_OPS, t, d_max), {}),
    }
    if form not in table:
        raise ValueError(f"form must be one of {', '.join(table)} (got {form!r})")
    fn, extra = table[form]
    return fn, {"form": form, "d_max": float(d_max), **extra, "text": "rtfit.realtime.obscurances"}


def _check_params(d_max, exponent):
    if not (isinstance(d_max, (int, float)) and 0.0 < d_max <= D_MAX_LIMIT):
        raise ValueError(f"d_max must be in (0, {D_MAX_LIMIT:g}] scene units (got {d_max!r})")
    if not (isinstance(exponent, (int, float)) and 0.0 <= exponent <= 1e6):
        raise ValueError(f"exponent must be in [0, 1e6] (got {exponent!r})")


def obscurance(distances, d_max: float = SEED_D_MAX, exponent: float = SEED_EXPONENT, form: str = "power"):
    """W from hit distances ``distances`` (K, N) (scene units, ≥ 0, +∞ for a miss) with the distance function
    ``form`` ("power", "exponential" or "step"). NumPy input runs the Dr.Jit kernel of the default backend
    (`rtfit.realtime.arrays.evaluate`); returns (N,)."""
    _check_params(d_max, exponent)
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 2 or d.shape[0] < 1 or d.shape[1] < 1:
        raise ValueError(f"distances must be a non-empty (K, N) array (got shape {d.shape})")
    if np.any(np.isnan(d)) or np.any(d < 0):
        raise ValueError("distances must be >= 0 (+inf for a miss), not NaN")
    kernels = {
        "power": lambda ops, *rows: power_obscurance_kernel(ops, rows, d_max, exponent),
        "exponential": lambda ops, *rows: exponential_obscurance_kernel(ops, rows, d_max),
        "step": lambda ops, *rows: step_obscurance_kernel(ops, rows, d_max),
    }
    if form not in kernels:
        raise ValueError(f"form must be one of {', '.join(kernels)} (got {form!r})")
    # Rays in chunks of ≤ RAY_CHUNK rows (one fused kernel each; a kernel with thousands of inputs takes
    # minutes to compile): W = Σ_c (K_c/K)·W_c, the mean of the chunk means weighted by their ray counts.
    k = d.shape[0]
    out = np.zeros(d.shape[1])
    for a in range(0, k, RAY_CHUNK):
        rows = list(d[a : a + RAY_CHUNK])
        out += (len(rows) / k) * np.asarray(evaluate(kernels[form], *rows), dtype=np.float64)
    return out


def cosine_spiral_directions(k: int) -> np.ndarray:
    """K stratified cosine-distributed directions in the local frame (z = normal), (K, 3): a golden-angle
    spiral on the unit disc (r_j = √((j + ½)/K), φ_j = j·π(3 − √5)) lifted to the hemisphere (Malley):
    each direction stands for an equal cosine-weighted solid angle π/K."""
    if not isinstance(k, (int, np.integer)) or not 1 <= k <= 1 << 16:
        raise ValueError(f"k must be an integer in [1, 65536] (got {k!r})")
    j = np.arange(k, dtype=np.float64)
    r = np.sqrt((j + 0.5) / k)
    phi = j * math.pi * (3.0 - math.sqrt(5.0))
    x, y = r * np.cos(phi), r * np.sin(phi)
    return np.column_stack([x, y, np.sqrt(np.maximum(1.0 - r * r, 0.0))])


def plane_facing_obscurance(
    height: float, d_max: float, exponent: float | None = SEED_EXPONENT, form="power"
):
    """Closed form of W at a point at ``height`` h > 0 above an infinite plane, its normal facing the plane
    (ray at angle θ from the normal hits at d = h/μ, μ = cos θ; W = 2∫₀¹ ρ(h/μ) μ dμ). With a = h/d_max:

    * power, a ≥ 1: 1; a < 1: a² + 2a^p (1 − a^{2−p})/(2 − p)  (p = 2: a² + 2a² ln(1/a));
    * step: min(a, 1)²;  * exponential (b = h/d_max): 1 − 2 E₃(b), E₃ the exponential integral
      (SciPy's ``expn``). Independent of the kernels (a test compares both with quadrature)."""
    if not (height > 0 and d_max > 0):
        raise ValueError("height and d_max must be > 0")
    a = height / d_max
    if form == "step":
        return min(a, 1.0) ** 2
    if form == "exponential":
        from scipy.special import expn  # scipy: only for this closed form

        return float(1.0 - 2.0 * expn(3, a))
    if form != "power" or exponent is None or exponent < 0:
        raise ValueError(f"unknown form {form!r} or bad exponent {exponent!r}")
    if a >= 1.0:
        return 1.0
    p = float(exponent)
    if abs(p - 2.0) < 1e-12:
        return a * a + 2.0 * a * a * math.log(1.0 / a)
    return a * a + 2.0 * a**p * (1.0 - a ** (2.0 - p)) / (2.0 - p)
