"""Array plumbing shared by the ``rtfit.realtime`` kernels: one kernel text, three array libraries.

Every real-time formula in this package is written **once**, as a function of an *ops namespace*::

    def _half_lambert_kernel(ops, cos_theta, irradiance):
        t = ops.fma(clamp_cos(ops, cos_theta), 0.5, 0.5)
        return irradiance * t * t

``DRJIT_OPS``, ``NUMPY_OPS`` and ``JAX_OPS`` expose the same function names (`OP_NAMES`: ``sqrt``,
``exp``, ``select``, ``gather``, ...), so the same text runs as a fused Dr.Jit kernel (LLVM or CUDA), as
NumPy code (benchmarks: Dr.Jit vs NumPy of one formula) and as JAX code (fits: `rtfit.fitting` takes
derivatives through the kernel text with ``jax``). No formula has a second hand-written copy.
``JAX_OPS`` is built on first use (`jax_ops`), so importing this module does not import jax.

Dispatch rules (`evaluate`), applied to all array-like arguments of a public function together:

* any JAX array or tracer argument → the JAX text runs on the arguments as given (NumPy arrays and floats
  are left to JAX's own promotion); the result is a JAX array. This is how fits differentiate through a
  public function (``jax.jacfwd`` of ``wrap(cos_theta, w, p)``);
* else any Dr.Jit array argument → the Dr.Jit kernel runs on that array type (the type of the *first*
  Dr.Jit argument; other Dr.Jit arguments are cast to it, NumPy arguments are converted to it) and the
  result has that same type (generic: ``Float = type(x)``, e.g. ``drjit.cuda.Float64`` or
  ``drjit.llvm.ad.Float``); nothing is evaluated: the result stays lazy;
* else any NumPy array (0-d included) → the arguments are broadcast, converted to a Dr.Jit array of the
  *default backend* (`set_default_backend`; float64 input → ``Float64``, float32/float16 input →
  ``Float``), computed there and returned as a NumPy array of the broadcast shape and that dtype;
* else (Python floats/ints, NumPy scalars) → the NumPy kernel runs in float64 and a Python ``float`` is
  returned.

NumPy scalars are turned into Python floats at this edge: a NumPy scalar times a Dr.Jit array is an ndarray,
which the next Dr.Jit call would reject. On Dr.Jit a number argument is then an opaque size-1 array (one
kernel for every value; a literal with ``folded=True``, a cost's setting): see `evaluate`.

This module imports only drjit and numpy (jax on first use of `JAX_OPS`) and reads no settings at import
time.
"""

from __future__ import annotations

import math
import sys
import types
from collections.abc import Callable, Sequence
from typing import Any

import drjit as dr
import numpy as np

__all__ = [
    "ATAN_SERIES_LIMIT",
    "DRJIT_OPS",
    "NUMPY_OPS",
    "OP_NAMES",
    "Uniforms",
    "aligned_copy",
    "aligned_empty",
    "atan_minus_x_series",
    "backend_float",
    "backend_type",
    "cached_table",
    "check_range",
    "check_scalar",
    "clamp01",
    "clamp_cos",
    "evaluate",
    "evaluate_numpy",
    "get_default_backend",
    "is_drjit",
    "is_jax",
    "jax_ops",
    "ops_for",
    "release_backend_tables",
    "safe_div",
    "safe_sqrt",
    "same_bits",
    "set_default_backend",
    "sin_from_cos",
    "sincos_first_quadrant",
    "split3",
    "to_drjit",
    "xyz_columns",
]

# ----------------------------------------------------------------------------------------- ops namespaces
OP_NAMES = (
    "sqrt", "cbrt", "exp", "log", "expm1", "log1p", "power",
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "tanh",
    "abs", "floor", "ceil", "maximum", "minimum", "clip", "fma", "select", "gather",
)  # fmt: skip
"""The names every ops namespace defines (besides ``name``), with the same meaning in each library."""


def _np_fma(a, b, c):
    """NumPy has no fused multiply-add: a·b + c with two roundings (the float64 reference tolerates it)."""
    return a * b + c


def _np_gather(table, index):
    """table[index] with a float or integer index array (kernels compute indices in floating point)."""
    return np.asarray(table)[np.asarray(index).astype(np.int64)]


def _dr_gather(table, index):
    """dr.gather of ``table``'s own type at ``index`` (a float index is truncated, as a cast in a shader). A
    table of Python floats (a `Uniforms`) is gathered from as an array of the index's type (a tuple has no
    Dr.Jit type to gather: the LLVM backend crashed on one)."""
    if not dr.is_array_v(table):
        Float = type(index) if dr.is_array_v(index) else dr.llvm.Float
        table = to_drjit(Float, np.asarray(table, np.float64))
    return dr.gather(type(table), table, dr.uint32_array_t(type(table))(index))


def _dr_expm1(x):
    """e^x − 1 without cancellation near 0 (Dr.Jit has no expm1): Kahan's u = e^x; (u − 1)·x / log u.

    The rounding error of u cancels between u − 1 and log u, so the relative error stays a few ulp for
    |x| ≪ 1 (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., §1.14.1). On CUDA,
    float32 exp/log are approximate and this degrades to their accuracy (≈ 2 ulp of e^x, not of e^x − 1)."""
    u = dr.exp(x)
    d = dr.log(u)
    # u − 1 itself where it does not cancel (|x| ≥ 1/2: |u − 1| ≥ 0.39, error ≤ 1 ulp of u) and for x → ±inf
    # or NaN (−1, inf, NaN). Only |x| < 1/2 takes Kahan's ratio: with CUDA's approximate log, the ratio for
    # x = −20 (u − 1 = −1 exactly) came out −1.0000001, so 1 − e^(−σℓ) read 1.0000001 (soft-particles'
    # float32 domain check on an H200, session 6).
    plain = (u == 0.0) | ~dr.isfinite(u) | (dr.abs(x) >= 0.5)
    # Guard: an approximate log (CUDA) may round log u to 0 for u = 1 ± 1 ulp, where (u − 1)·x/0 would be
    # ±inf; e^x − 1 = x to first order there. (Not observed: an H200 sweep of x = ±10^(−45…2) gave no
    # non-finite value with or without it.)
    near_one = (u == 1.0) | (d == 0.0)
    ratio = (u - 1.0) * x / dr.select(plain | near_one, 1.0, d)
    return dr.select(near_one, x, dr.select(plain, u - 1.0, ratio))


def _dr_log1p(x):
    """log(1 + x) without cancellation near 0 (Dr.Jit has no log1p): Kahan's u = 1 + x; log u · x/(u − 1)."""
    u = 1.0 + x
    d = u - 1.0
    plain = (u <= 0.0) | ~dr.isfinite(u)  # x ≤ −1 or ±inf/NaN: log(u) itself (−inf, NaN, inf)
    ratio = dr.log(u) * x / dr.select((d == 0.0) | plain, 1.0, d)
    return dr.select(d == 0.0, x, dr.select(plain, dr.log(u), ratio))


POWER_PRODUCT_BITS = 7
"""`_dr_power` of an array exponent forms x^n by products for a whole |n| < 2^7 = 128, as Dr.Jit's ``power``
does for a whole number exponent (and Phong's 32 or 64, Schlick's 5, half-Lambert's 2 need)."""


def _dr_power(x, y):
    """x^y where the exponent ``y`` may be an array (an opaque parameter: `evaluate`), with the values of
    Dr.Jit's ``power`` of a number exponent, and NumPy's where they meet. Dr.Jit's ``power`` of a whole
    number n is a product of squarings, least significant bit of |n| first (its reciprocal for n < 0), exact
    in sign for x < 0; of an array it is exp2(y·log2 x): a few ulp off the product in float32 (half-Lambert's
    square not bit for bit), NaN for x < 0 and for 0^0. So a whole |y| < 2^`POWER_PRODUCT_BITS` takes the
    same products here, selected bit by bit (the literal's bits: `tests/test_opaque_numbers.py`), and any
    other y exp2(y·log2 |x|), signed as NumPy's for x < 0 (NaN for a fractional y). A number ``y`` is
    ``dr.power``'s own. The selected products are ~4 operations a bit beside exp2 and log2: an evaluation's
    cost, not a method's (its cost folds its parameters as literals: `evaluate`'s ``folded``)."""
    if not dr.is_array_v(y):
        return dr.power(x, y)
    n = dr.abs(y)
    integral = dr.floor(n) == n
    whole = integral & (n < float(1 << POWER_PRODUCT_BITS))
    product, square, rest = 1.0, x, n
    for _ in range(POWER_PRODUCT_BITS):  # least significant bit first: Dr.Jit's order for a literal
        half = dr.floor(0.5 * rest)
        product = dr.select(rest - 2.0 * half == 1.0, product * square, product)
        square, rest = square * square, half
    products = dr.select(y < 0.0, 1.0 / product, product)
    # beyond the products: |x|^y (the bits of dr.power for x > 0), signed as NumPy's for x < 0
    magnitude: Any = dr.power(dr.abs(x), y)
    odd = n - 2.0 * dr.floor(0.5 * n) == 1.0
    signed = dr.select(integral, dr.select(odd, -magnitude, magnitude), dr.nan)
    return dr.select(whole, products, dr.select(x < 0.0, signed, magnitude))


DRJIT_OPS = types.SimpleNamespace(
    name="drjit",
    sqrt=dr.sqrt, cbrt=dr.cbrt, exp=dr.exp, log=dr.log, expm1=_dr_expm1, log1p=_dr_log1p, power=_dr_power,
    sin=dr.sin, cos=dr.cos, tan=dr.tan, asin=dr.asin, acos=dr.acos, atan=dr.atan, atan2=dr.atan2,
    tanh=dr.tanh, abs=dr.abs, floor=dr.floor, ceil=dr.ceil, maximum=dr.maximum, minimum=dr.minimum,
    clip=dr.clip, fma=dr.fma, select=dr.select, gather=_dr_gather,
)  # fmt: skip
"""Dr.Jit functions (work on Python floats too); NaN propagates through maximum/minimum/clip."""

NUMPY_OPS = types.SimpleNamespace(
    name="numpy",
    sqrt=np.sqrt, cbrt=np.cbrt, exp=np.exp, log=np.log, expm1=np.expm1, log1p=np.log1p, power=np.power,
    sin=np.sin, cos=np.cos, tan=np.tan, asin=np.arcsin, acos=np.arccos, atan=np.arctan, atan2=np.arctan2,
    tanh=np.tanh, abs=np.abs, floor=np.floor, ceil=np.ceil, maximum=np.maximum, minimum=np.minimum,
    clip=np.clip, fma=_np_fma, select=np.where, gather=_np_gather,
)  # fmt: skip
"""The same names over NumPy (``select`` is ``np.where``: both branches are evaluated, so kernels must
keep unselected branches finite — see `safe_div`)."""


def _jax_namespace() -> types.SimpleNamespace:
    """The same names over ``jax.numpy`` (imported here, on first use: JAX is heavy and only fits need it).

    Differences that matter for autodiff, not for values:

    * ``power(x, y)`` for x ≥ 0 has the gradient of 0^y = 0 (y > 0) at x = 0 instead of NaN
      (jnp.power's ∂/∂y = log(0)·0^y = NaN, which ``select`` would spread to every element: JAX
      differentiates both branches). Values are those of jnp.power.
    * ``select`` is ``jnp.where`` and, as with NumPy, both branches are evaluated *and differentiated*:
      a kernel's unselected branch must stay finite (`safe_div`, `safe_sqrt`) for gradients too.
    """
    import jax.numpy as jnp

    def power(x, y):
        pos = x > 0
        safe = jnp.where(pos, x, 1.0)
        return jnp.where(pos, safe**y, jnp.where(x == 0, jnp.where(y == 0, 1.0, 0.0), jnp.power(x, y)))

    def gather(table, index):
        return jnp.asarray(table)[jnp.asarray(index).astype(jnp.int32)]

    return types.SimpleNamespace(
        name="jax",
        sqrt=jnp.sqrt, cbrt=jnp.cbrt, exp=jnp.exp, log=jnp.log, expm1=jnp.expm1, log1p=jnp.log1p,
        power=power, sin=jnp.sin, cos=jnp.cos, tan=jnp.tan, asin=jnp.arcsin, acos=jnp.arccos,
        atan=jnp.arctan, atan2=jnp.arctan2, tanh=jnp.tanh, abs=jnp.abs, floor=jnp.floor, ceil=jnp.ceil,
        maximum=jnp.maximum, minimum=jnp.minimum, clip=jnp.clip, fma=lambda a, b, c: a * b + c,
        select=jnp.where, gather=gather,
    )  # fmt: skip


_jax_ops: types.SimpleNamespace | None = None


def jax_ops() -> types.SimpleNamespace:
    """The JAX ops namespace (`JAX_OPS`), built on first use (this imports jax)."""
    global _jax_ops
    if _jax_ops is None:
        _jax_ops = _jax_namespace()
        assert set(vars(_jax_ops)) == set(vars(DRJIT_OPS))
    return _jax_ops


def __getattr__(name: str):
    # PEP 562: ``arrays.JAX_OPS`` imports jax only when it is first asked for.
    if name == "JAX_OPS":
        return jax_ops()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def ops_for(library: str) -> types.SimpleNamespace:
    """The ops namespace of ``library``: "drjit", "numpy" or "jax"."""
    if library == "jax":
        return jax_ops()
    try:
        return {"drjit": DRJIT_OPS, "numpy": NUMPY_OPS}[library]
    except KeyError:
        raise ValueError(f"unknown array library {library!r} (known: drjit, numpy, jax)") from None


assert set(vars(DRJIT_OPS)) == set(vars(NUMPY_OPS)) == {"name", *OP_NAMES}

# ----------------------------------------------------------------------------------------- small helpers
_TINY = 1e-30  # > float32's smallest normal (1.2e-38) squared-safe floor for denominators


def safe_sqrt(ops, x):
    """√max(x, 0): rounding can push a mathematically non-negative radicand (1 − y², 1 − c²) below 0."""
    return ops.sqrt(ops.maximum(x, 0.0))


def safe_div(ops, a, b):
    """a / max(b, 1e-30) for b ≥ 0: keeps the branch that np.where/dr.select discards finite (no 0/0)."""
    return a / ops.maximum(b, _TINY)


def clamp_cos(ops, c):
    """Clamp to [−1, 1]: a dot product of unit vectors can exceed 1 by rounding, and acos/√(1−c²) need it."""
    return ops.clip(c, -1.0, 1.0)


def clamp01(ops, x):
    """Clamp to [0, 1] (saturate)."""
    return ops.clip(x, 0.0, 1.0)


def sin_from_cos(ops, c):
    """sin θ = √((1 − c)(1 + c)) for θ ∈ [0, π]: the factored form keeps relative accuracy near c = ±1."""
    return safe_sqrt(ops, (1.0 - c) * (1.0 + c))


ATAN_SERIES_LIMIT = 0.3
"""|u| below which kernels may use `atan_minus_x_series` (see there for the truncation error)."""

_ATAN_TERMS = 12
_ATAN_COEFFS = tuple((-1.0) ** k / (2 * k + 1) for k in range(1, _ATAN_TERMS + 1))  # −1/3, 1/5, …, 1/25


def atan_minus_x_series(ops, u):
    """atan(u) − u without cancellation for |u| ≤ 0.3: Σ_{k=1..12} (−1)^k u^(2k+1)/(2k+1) (Horner in u²).

    Alternating series: the truncation error is ≤ |u|²⁷/27, i.e. ≤ 3·u²⁴/27 ≈ 3e-14 relative to the result
    at |u| = 0.3 and ≤ 1e-17 at |u| = 0.125. The caller must select another form for larger |u|
    (and should pass a clamped u so that the discarded branch stays finite).
    """
    u2 = u * u
    acc = _ATAN_COEFFS[-1]
    for coef in reversed(_ATAN_COEFFS[:-1]):
        acc = ops.fma(acc, u2, coef)
    return u * u2 * acc


_SIN_COEFFS = tuple((-1.0) ** k / math.factorial(2 * k + 1) for k in range(11))  # 1, −1/3!, …, 1/21!
_COS_COEFFS = tuple((-1.0) ** k / math.factorial(2 * k) for k in range(12))  # 1, −1/2!, …, −1/22!


def sincos_first_quadrant(ops, a):
    """(sin a, cos a) for a ∈ [0, π/2] from Taylor polynomials in a² (Horner, fma), not the backend's sin/cos.

    Why: on Dr.Jit-CUDA, float32 ``dr.sin``/``dr.cos`` run on the GPU's approximate multi-function unit
    (absolute error ~1e-6), a 1 % relative error of sin α at α = 1e-4. The polynomials give relative accuracy
    at every a, on every backend. Truncation ≤ (π/2)²³/23! ≈ 1e-18 (sin), ≤ (π/2)²⁴/24! ≈ 1e-19 (cos).
    Outside [0, π/2] the result is wrong: callers clamp first.
    """
    a2 = a * a
    s = _SIN_COEFFS[-1]
    for coef in reversed(_SIN_COEFFS[:-1]):
        s = ops.fma(s, a2, coef)
    c = _COS_COEFFS[-1]
    for coef in reversed(_COS_COEFFS[:-1]):
        c = ops.fma(c, a2, coef)
    return a * s, c


# ----------------------------------------------------------------------------------------- validation
def check_scalar(
    name: str, value: float, lo: float, hi: float, lo_open: bool = False, interval: str | None = None
) -> float:
    """Return ``float(value)``; raise a one-line ValueError if it is NaN or outside [lo, hi] ((lo, hi]
    with ``lo_open``). ``interval`` is the text shown for the valid interval (defaults to the numbers)."""
    v = float(value)
    ok = (v > lo if lo_open else v >= lo) and v <= hi  # False for NaN
    if not ok:
        raise ValueError(f"{name} must be in {_interval_text(lo, hi, lo_open, interval)} (got {v!r})")
    return v


def check_range(
    name: str, value: Any, lo: float, hi: float, lo_open: bool = False, interval: str | None = None
) -> Any:
    """Validate a parameter that may be a scalar or an array; return it with NumPy scalars made floats.

    * Python/NumPy scalars: `check_scalar`.
    * NumPy arrays: one min and one max pass (NaN fails both comparisons), one-line ValueError.
    * Dr.Jit and JAX arrays: **not checked** (that would force evaluation and a host sync, or is impossible
      on a tracer); kernels clamp into the domain instead, as each public function documents.
    """
    if is_drjit(value) or is_jax(value):
        return value
    if isinstance(value, np.ndarray):
        if value.size == 0:
            return value
        if not np.issubdtype(value.dtype, np.number) or np.iscomplexobj(value):
            raise ValueError(f"{name} must be a real array (got dtype {value.dtype})")
        vmin, vmax = value.min(), value.max()
        ok = (vmin > lo if lo_open else vmin >= lo) and vmax <= hi  # NaN → min/max NaN → False
        if not ok:
            bad = vmin if not (vmin > lo if lo_open else vmin >= lo) else vmax
            raise ValueError(
                f"{name} must be in {_interval_text(lo, hi, lo_open, interval)} (got {float(bad)!r})"
            )
        return value
    return check_scalar(name, value, lo, hi, lo_open, interval)


def _interval_text(lo, hi, lo_open, interval):
    if interval is not None:
        return interval
    return f"{'(' if lo_open else '['}{_num(lo)}, {_num(hi)}]"


def _num(x: float) -> str:
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:g}"


# ----------------------------------------------------------------------------------------- backends
_BACKENDS = ("llvm", "cuda")
_default_backend = "llvm"


def set_default_backend(backend: str) -> None:
    """Backend ("llvm" or "cuda") on which NumPy inputs are evaluated. Default "llvm"."""
    global _default_backend
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS} (got {backend!r})")
    _default_backend = backend


def get_default_backend() -> str:
    """The backend set by `set_default_backend` ("llvm" unless changed)."""
    return _default_backend


def backend_float(backend: str | None = None, dtype: Any = np.float32) -> type:
    """The Dr.Jit floating-point array type of ``backend`` ("llvm" or "cuda"; None: the default backend,
    `set_default_backend`): ``Float64`` for a float64 ``dtype``, else ``Float`` (float32). The one place
    that maps a backend name to Dr.Jit's array types."""
    name = _default_backend if backend is None else backend
    if name not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS} (got {name!r})")
    return backend_type("Float64" if np.dtype(dtype) == np.float64 else "Float", name)


def backend_type(type_name: str, backend: str | None = None, ad: bool = False) -> type:
    """Dr.Jit's array type ``type_name`` (``"Float"``, ``"Array3f"``, …) of ``backend`` ("llvm" or "cuda";
    None: the default backend), differentiable with ``ad``: e.g. ``backend_type("Array3f", "cuda")`` is
    ``dr.cuda.Array3f``. With `backend_float`, the one place that maps a backend name to an array type."""
    name = _default_backend if backend is None else backend
    if name not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS} (got {name!r})")
    mod = dr.cuda if name == "cuda" else dr.llvm
    return getattr(mod.ad if ad else mod, type_name)


def _backend_float(dtype) -> type:
    return backend_float(None, dtype)


_ALIGN = 64
"""Bytes to which `to_drjit` aligns the NumPy memory it gives Dr.Jit (a cache line; AVX-512 vectors)."""


_NUMPY_OF = {
    dr.VarType.Float16: np.float16,
    dr.VarType.Float32: np.float32,
    dr.VarType.Float64: np.float64,
    dr.VarType.Int32: np.int32,
    dr.VarType.UInt32: np.uint32,
    dr.VarType.Int64: np.int64,
    dr.VarType.UInt64: np.uint64,
}


def to_drjit(Float: type, values: Any) -> Any:
    """``values`` (array-like) as a flat Dr.Jit array of type ``Float`` (float32 for ``Float``, float64 for
    ``Float64``, uint32 for ``UInt32``, ...), in a fresh NumPy buffer aligned to 64 bytes.

    Dr.Jit's LLVM backend maps NumPy memory without copying and compiles a load from an input whose
    address is not a multiple of the vector width as an unaligned load (``align 1`` instead of ``align 32``
    in the IR): the same kernel on NumPy inputs then hashes differently from call to call, as NumPy's
    allocator happens to place them (glibc: 16-byte granules), and is compiled again for every pattern
    of alignments — 2^6 variants of a kernel of six point/normal columns. Measured on the cone-traced
    AO kernel (934 ops, 2 loaded cores): every call rebuilt its two kernels, 2.1–2.8 s each, where an
    aligned call reuses them (0.03 s). The copy also keeps a later write to ``values`` out of the kernel
    (a mapped array aliases it)."""
    return Float(aligned_copy(values, _NUMPY_OF[dr.type_v(Float)]))


def aligned_empty(size: int, dtype: Any, offset: int = 0, period: int = _ALIGN) -> np.ndarray:
    """A fresh, flat NumPy array of ``size`` elements of ``dtype`` (uninitialised) whose first element's
    address is ``offset`` bytes past a multiple of ``period`` (a multiple of the item size; NumPy's buffers
    are at least 16-byte aligned): 64-byte aligned by default (`aligned_copy`), or staggered in a 4 KiB
    page (`rtfit.experiments.audit_cost.CostInputs`)."""
    item = np.dtype(dtype).itemsize
    buf = np.empty(size + period // item, dtype)
    start = (offset - buf.ctypes.data) % period // item
    return buf[start : start + size]


def aligned_copy(values: Any, dtype: Any) -> np.ndarray:
    """``values`` (array-like) as a flat, fresh NumPy array of ``dtype`` whose first element is aligned to 64
    bytes (`to_drjit`'s buffer). Dr.Jit maps such an array (and any prefix of it) without copying."""
    arr = np.asarray(values)
    out = aligned_empty(arr.size, dtype)
    # one pass in C order, straight from ``values`` (a broadcast view is not flattened into a copy first:
    # issue 33, ~half of the time of this copy for the kernels' broadcast (texels × samples) inputs)
    out.reshape(arr.shape)[...] = arr
    return out


def cached_table(cache: dict, ops, like: Any, key: tuple, values: Callable[[], Any]) -> Any:
    """A sampler's table (a shadow map's depths, a height field, probe chains, a cloud grid) as the array
    kind ``ops`` runs on, made once per (``key``, ops kind, Dr.Jit type) and kept in ``cache``: on Dr.Jit the
    type of ``like`` (float32 or float64, LLVM or CUDA; `dr.llvm.Float64` where ``like`` is a plain number),
    on JAX a device array, else the flat NumPy array ``values()`` returns (made only on a miss). The shader
    tracer gets the NumPy array too: it names it a binding (`rtfit.realtime.shader`)."""
    kind = type(like) if ops.name == "drjit" and dr.is_array_v(like) else None
    full = (*key, ops.name, kind)
    if full not in cache:
        flat = np.ascontiguousarray(values()).reshape(-1)
        if ops.name == "drjit":  # aligned (`to_drjit`): a gather's kernel depends on its table's alignment
            cache[full] = to_drjit(kind or dr.llvm.Float64, flat)
        elif ops.name == "jax":
            import jax.numpy as jnp

            cache[full] = jnp.asarray(flat)
        else:
            cache[full] = flat
    return cache[full]


def same_bits(stored: np.ndarray, a: np.ndarray) -> bool:
    """``stored`` and ``a`` hold the same values bit for bit: the same dtype and shape and equal bytes
    (−0.0 ≠ 0.0, a NaN equal to its copy). A kernel's NumPy-run memo (kept values of a fit's repeated
    evaluations: pcf-soft-shadows, height fog) reuses a result only on this test, so a hit gives the values
    a fresh computation would."""
    if stored.dtype != a.dtype or stored.shape != a.shape:
        return False
    return np.array_equal(
        np.ascontiguousarray(stored).reshape(-1).view(np.uint8),
        np.ascontiguousarray(a).reshape(-1).view(np.uint8),
    )


def release_backend_tables(objects) -> None:
    """Let each sampler among ``objects`` drop the per-backend copies of its tables (an object with a
    ``release_backend_tables()`` method; others are passed over): the engine calls it once a row's Dr.Jit
    evaluation or cost run is done, so that large tables (ibl-samples' depth maps: ~0.6 GiB in float32 and
    float64 copies) are not held to the case's end. The next use makes them again."""
    for obj in objects:
        release = getattr(obj, "release_backend_tables", None)
        if callable(release):
            release()


# ----------------------------------------------------------------------------------------- dispatch
def is_drjit(x: Any) -> bool:
    """True for a Dr.Jit array (any backend, scalar-valued or nested)."""
    return dr.is_array_v(x)


def is_jax(x: Any) -> bool:
    """True for a JAX array or tracer (checked without importing jax: only if jax is already loaded)."""
    jax = sys.modules.get("jax")
    return jax is not None and isinstance(x, jax.Array)


class Uniforms(tuple):
    """A small table a kernel reads with Python indices (``coeffs[c * 9 + k]``, ``coeffs[a:b]``: SH and
    hemisphere-basis coefficients) as a shader reads its constant buffer, for timing that shader: values the
    compiler cannot fold or merge. Dr.Jit bakes a table entry read by index into the kernel as a literal,
    folds a literal 0 or ±1, and merges the equal work of equal literals: 24 of a constant sky's 27 SH
    coefficients are 0 and its three channels equal, and its SH L2 kernel timed 0.55 ns a pixel against
    3.4 ns for the same kernel on a textured sky (this machine's LLVM backend). A shader does not know its
    coefficients when it is compiled, so every entry is timed as a distinct literal that cannot be folded:
    v_i + 2⁻²⁰·(|v_i| + 1)·(i + 1) (relative change ≤ 2⁻²⁰·(n + 1): nothing a timing sees). Opaque Dr.Jit
    scalars (`drjit.opaque`: a kernel parameter, as a uniform is) would be exact in spirit, but the LLVM
    backend reads each one per element: 30 ns a pixel for the same 27 coefficients, 9× the literal kernel —
    a cost of the backend, not of the shader. `evaluate` passes a `Uniforms` to the kernel as it is; never
    use it for values, only for timing."""

    @classmethod
    def of(cls, values) -> Uniforms:
        """The table ``values`` as distinct floats none of which folds (class docstring)."""
        v = np.asarray(values, np.float64).reshape(-1)
        return cls(float(x) for x in v + 2.0**-20 * (np.abs(v) + 1.0) * np.arange(1, v.size + 1))


def _as_float_scalar(x: Any) -> Any:
    """A number as a float; a sampler object (anything with a ``sample`` method, e.g. a distance field that
    the kernel reads with ``sdf.sample(ops, level, x, y, z)``) or a `Uniforms` table is passed to the kernel
    as it is."""
    if isinstance(x, (bool, np.bool_)):
        raise TypeError(f"expected a real number (got {x!r})")
    if callable(getattr(x, "sample", None)) or isinstance(x, Uniforms):
        return x
    return float(x)


def _is_numpy_array(x: Any) -> bool:
    return isinstance(x, np.ndarray)


def _numpy_dtype(args: Sequence[Any]) -> np.dtype:
    """float64 if any NumPy array is float64 (or integer); float32 if all arrays are float32/float16."""
    dts = [a.dtype for a in args if _is_numpy_array(a)]
    for d in dts:
        if not (np.issubdtype(d, np.floating) and np.dtype(d).itemsize <= 4):
            return np.dtype(np.float64)
    return np.dtype(np.float32)


def _on_drjit(kernel: Callable, Float: type, args: Sequence[Any], folded: bool) -> Any:
    """``kernel`` on ``DRJIT_OPS``, its number arguments opaque size-1 ``Float`` arrays holding the values
    literals would hold (`evaluate`), or literals where ``folded``; a sampler object or `Uniforms` table as
    it is. A text that needs a number as a Python number (a mip level chosen by ``math.log2`` of a distance:
    a TypeError on an array) is traced again with literals, as before session 32: a kernel per value."""

    def run(opaque: bool) -> Any:
        conv = []
        for a in args:
            v = a if is_drjit(a) else _as_float_scalar(a)
            conv.append(dr.opaque(Float, v) if opaque and isinstance(v, float) else v)
        return kernel(DRJIT_OPS, *conv)

    if folded:
        return run(False)
    try:
        return run(True)
    except TypeError:
        return run(False)


def evaluate(kernel: Callable, *args: Any, folded: bool = False) -> Any:
    """Run ``kernel(ops, *args)`` following the dispatch rules of this module (see module docstring).

    ``kernel`` may return one array or a tuple of arrays; the result has the same structure.

    On Dr.Jit a number argument (a free parameter, a scalar input) is an opaque size-1 array, not a
    literal folded into the kernel, so that one compiled kernel serves every value: a method's declared
    values and its fitted ones, its cost measurement, another scene's light. Issue 33 (session 32): an
    audit of the Cornell box on a machine whose kernel cache was empty compiled 49 kernels (8.4 s of its
    34 s) evaluating methods at literal values, one for each set of values, and 36 more (4.6 s) for their
    costs. The values are a literal's, or nearer NumPy's: Dr.Jit divides by a literal as a product by its
    rounded reciprocal (1 ulp off in a third of the elements), by an opaque value as a division; a power
    takes a literal's products for a whole exponent (`_dr_power`). ``folded``: the numbers as literals,
    folded into the kernel as a shader's compile-time constants are (a method's cost: an engine ships
    Schlick's x^5 as products). The kernel text's own constants stay literals, and so do a method's
    ``fixed`` keywords (its variant).
    """
    if any(is_jax(a) for a in args):  # traced by JAX (a fit's residual, jax.grad, jax.jit): the JAX text
        return kernel(
            jax_ops(), *[a if is_jax(a) or _is_numpy_array(a) else _as_float_scalar(a) for a in args]
        )
    dr_args = [a for a in args if is_drjit(a)]
    if dr_args:
        Float = type(dr_args[0])
        conv = []
        for a in args:
            if is_drjit(a):
                conv.append(a if type(a) is Float else Float(a))
            elif _is_numpy_array(a):  # size 1 broadcasts; kept an array (a literal would recompile per value)
                conv.append(to_drjit(Float, a))
            else:
                conv.append(a)
        return _on_drjit(kernel, Float, conv, folded)

    np_args = [a for a in args if _is_numpy_array(a)]
    if not np_args:
        with np.errstate(all="ignore"):
            out = kernel(NUMPY_OPS, *[_as_float_scalar(a) for a in args])
        return tuple(float(o) for o in out) if isinstance(out, tuple) else float(out)

    shape = np.broadcast_shapes(*[a.shape for a in np_args])
    dtype = _numpy_dtype(np_args)
    size = math.prod(shape)
    if size == 0:
        out = kernel(
            NUMPY_OPS, *[np.zeros(shape, dtype) if _is_numpy_array(a) else _as_float_scalar(a) for a in args]
        )
        if isinstance(out, tuple):
            return tuple(np.zeros(shape, dtype) for _ in out)
        return np.zeros(shape, dtype)
    Float = _backend_float(dtype)
    conv = []
    for a in args:
        if not _is_numpy_array(a):
            conv.append(a)
        else:  # size-1 arrays stay size-1 Dr.Jit arrays (broadcast by Dr.Jit, no per-value recompilation)
            same = a.shape == shape or a.size == 1
            flat = a.reshape(-1) if same else np.broadcast_to(a, shape).reshape(-1)
            conv.append(to_drjit(Float, flat))
    out = _on_drjit(kernel, Float, conv, folded)

    def back(o):  # an owned NumPy copy (never a view of Dr.Jit memory); size-1 results are broadcast
        arr = np.array(o, dtype=dtype).reshape(-1)
        if arr.size != size:
            arr = np.full(size, arr[0], dtype)
        return arr.reshape(shape)

    return tuple(back(o) for o in out) if isinstance(out, tuple) else back(out)


def evaluate_numpy(kernel: Callable, *args: Any) -> Any:
    """Run the NumPy text of ``kernel`` directly on NumPy arrays/floats (no Dr.Jit, no validation).

    NumPy scalars become Python floats; arrays are used as given (their dtype decides the precision).
    For benchmarks and references, not hot paths.
    """
    conv = [a if _is_numpy_array(a) else _as_float_scalar(a) for a in args]
    return kernel(NUMPY_OPS, *conv)


def split3(v: Any, name: str) -> tuple:
    """Split a 3-vector argument into components (x, y, z).

    Accepts a Dr.Jit Array3f-like (components are its ``.x/.y/.z`` Float arrays, or floats for a scalar
    Array3f), a NumPy array of shape (..., 3) (components are views of shape (...)), or a length-3
    sequence of floats.
    """
    if is_drjit(v):
        if dr.depth_v(v) >= 2 or (dr.size_v(v) == 3 and not dr.is_dynamic_v(v)):
            return v[0], v[1], v[2]
        raise ValueError(f"{name} must be a 3-vector (Dr.Jit Array3f-like), got {type(v).__name__}")
    a = np.asarray(v) if not _is_numpy_array(v) else v
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) (got shape {a.shape})")
    if a.ndim == 1 and not _is_numpy_array(v):
        return tuple(_as_float_scalar(c) for c in a)
    return a[..., 0], a[..., 1], a[..., 2]


def xyz_columns(prefix: str, a) -> dict[str, Any]:
    """The columns of an (N, 3) array as the kernel inputs ``{prefix}x``, ``{prefix}y``, ``{prefix}z``
    (views of ``a``, no copy)."""
    return {f"{prefix}{c}": a[:, k] for k, c in enumerate("xyz")}
