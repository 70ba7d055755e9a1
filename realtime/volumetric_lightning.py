r"""Volumetric lightning: light of a point source gathered along the view segment, in closed form.

The seed's model (000:2345-2385, Wenzel 2006; 002:389-420, GDC 2007)
---------------------------------------------------------------------
A point source at ``l`` lights the air around it with the attenuation f(x) = i/(1 + a·|l − x|²); the light
gathered along the view segment x(t) = o + t·d, t ∈ [0, 1] (o the camera, o + d the scene point behind the
pixel, so |d| is the view depth) is

    F = ∫₀¹ i·|d|/(1 + a·|c − t·d|²) dt,     c = l − o,

    F = 2i|d|·[atan((v + 2w)/D) − atan(v/D)]/D,   u = 1 + a c·c,  v = −2a c·d,  w = a d·d,  D = √(4uw − v²)

(000:2360, 002:409). The math of both seeds is right; their notation is not: the scalar v shares its name
with the view ray v(t) (000:2370, 002:416), and 002:415 calls the light's position "I" (it is l). Here the
scalar is v and the ray is x(t).

Units: positions in metres; ``a`` in 1/m² (1/√a is the radius of the softened core); ``i`` is the gathered
quantity per metre at the source, so F has the units of i times metres. Against single scattering from an
isotropic point light of intensity I (W/sr) in a medium of scattering coefficient σ_s (1/m) the radiance is
L = σ_s/(4π)·∫ I·T/r² ds (W/m²/sr): far from the source (a·r² ≫ 1) the seed's f ≈ (i/a)/r², so
i/a ↔ σ_s·I/(4π) (W/m/sr) and i (W/m³/sr) is the softened core's level. As a → ∞ with i/a fixed the seed's
model *is* single scattering without extinction (``inverse-square`` below).

The stable form (rtfit; what `volumetric_lightning` evaluates)
-------------------------------------------------------------
One kernel text evaluates the general integral ∫₀¹ |d|/(k + a·|c − t·d|²) dt for k, a ≥ 0 (seed: k = 1, then
F = i·that; inverse-square: k = 0, a = 1). Write L = |d|, d̂ = d/L, c_∥ = c·d̂ and c_⊥ for c's component
perpendicular to d (|c_⊥| = |c × d|/L, the distance from the light to the ray's line). Then
|c − t d|² = |c_⊥|² + (tL − c_∥)², and with h² = k + a|c_⊥|²

    4uw − v² = 4a L²·(1 + a|c_⊥|²)                       (seed: k = 1; Lagrange: |c|²|d|² − (c·d)² = |c × d|²)

— the printed form computes it as the difference of two terms of size 4a²|c|²|d|², which cancels when the
ray passes near the axis through the light with a|c|² ≫ 1 (D² ≤ 0 → NaN for some rays at a = 100 in
float32). The rewrite never forms the difference: |c × d|² is a sum of squares whose components are each
computed as a difference of products with one rounding (Kahan's fma trick; NumPy/JAX do not fuse a·b + c,
so there the exact product error comes from Dekker's splitting), so |c_⊥| keeps relative accuracy for rays
at 1e-8 rad from the axis.

The two arctangents: atan x₁ − atan x₀ with x₁ = √a(L − c_∥)/h, x₀ = −√a c_∥/h; x₁ − x₀ = √a L/h > 0, so the
identity atan x − atan y = atan((x − y)/(1 + xy)) with its quadrant correction (+π where 1 + xy < 0, the light
between the two end points) is exactly atan2(x − y, 1 + xy), and after multiplying both arguments by h²

    Δ = atan2(Y, X),   Y = √a·L·h = √(a·(k L² + a|c × d|²)),   X = k + a·c·(c − d) = k + a·(l − o)·(l − o − d)

— X is the dot product of the vectors from the segment's two end points to the light (no cancellation:
where it is small the angle Δ is ≈ π/2 and insensitive to it), and for a distant source (X ≫ Y) Δ is
computed from the small ratio instead of as a difference of two nearly equal angles near ±π/2. Finally

    ∫ = L·Δ/Y       (Y > 0.3·X or X ≤ 0),
    ∫ = L·g(Y/X)/X   (X > 0, Y ≤ 0.3·X),  g(z) = atan(z)/z = 1 + (atan z − z)/z   (`atan_minus_x_series`)

so there is no division by √a or by L: a = 0 gives L/k (the seed: F = i|d|), |d| = 0 gives 0 (F/|d| →
i/(1 + a|c|²)), and a ray that points straight at a distant source gives L/X without 0/0. For k = 0 the
value is L·angle/|c × d|: the angle the segment subtends at the light divided by the light's distance to the
line (+∞ for a segment through the light, where the physical integral diverges).

Measured error against mpmath quadrature of the integrand at 40 digits (tests/test_volumetric_lightning.py,
docs/volumetric-lightning.md), over |c|, |d| up to 1e4 m, a ∈ {0} ∪ [1e-6, 1e3] /m², rays from 1e-8 rad off
the light's axis to perpendicular, sources beyond, behind and between the end points, |d| = 0:
float32 (Dr.Jit LLVM) ≤ 7.6e-7 relative (≤ 8.4e-7 against the float64 run over the experiment's 60 000
inputs), float64 ≤ 8e-16 relative. The seed's printed form in float32: NaN for 12 % of the near-axial rays
at a = 100 /m², errors up to 100 % near the axis, 0/0 = NaN at a = 0 and |d| = 0.

Domain: float32 keeps every intermediate finite for a ≤ 1e6 /m² and |c|, |d| ≤ 1e6 m (a²|c × d|² ≤ 1e36);
the result is exact arithmetic on c = l − o, whose float32 rounding is the input's own conditioning
(pass view-space positions, o = 0, for the best accuracy far from the origin).

Methods as data (`METHODS`)
---------------------------
Inputs: the segment's origin o, vector d and the light's position l, per component, in metres. ``stable``
(rtfit's form of the seed's model; params i ≥ 0, a ≥ 0), ``seed`` (the printed form, same params),
``inverse-square`` (k = 0: single scattering without extinction, param K = σ_s·I/(4π) in W/m/sr). The
single-scattering integral *with* extinction has no elementary closed form; the experiment evaluates it
by quadrature (`rtfit.experiments.volumetric_lightning`).

Importing
---------
``from rtfit.realtime import volumetric_lightning`` is the function; it shadows this module's name as an
attribute of the package, so take the table with ``from rtfit.realtime.volumetric_lightning import METHODS``
(``import rtfit.realtime.volumetric_lightning as m`` would bind the function).

Validation
----------
Python/NumPy values are validated at `volumetric_lightning` (non-finite positions, negative or NaN i or a →
one-line ValueError). Dr.Jit arrays are not checked (no host sync); i and a are clamped to ≥ 0.
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import atan_minus_x_series, check_range, evaluate, is_drjit, is_jax, split3
from .methods import Input, Method, Param, method_table

__all__ = ["LIGHTNING_DOMAIN", "inverse_square_airlight", "volumetric_lightning"]

_SERIES_LIMIT = 0.3  # z = Y/X below which g(z) = atan(z)/z comes from its series (truncation ≤ 3e-14)
_SPLIT32 = 4097.0  # Veltkamp splitter 2^12 + 1 (float32: 24-bit significand)
_SPLIT64 = 134217729.0  # 2^27 + 1 (float64: 53-bit significand)
_FUSED = ("drjit", "shader")  # ops namespaces whose fma is fused (Dr.Jit LLVM/CUDA; GLSL fma, HLSL mad)

LIGHTNING_DOMAIN = {"position_m": 1e6, "a_per_m2": 1e6}
"""Where every intermediate of the float32 kernel is finite: |c|, |d| ≤ 1e6 m and a ≤ 1e6 /m²."""


# ===================================================================================== kernels (ops text)
def _is_float32(ops, x) -> bool:
    dtype = getattr(x, "dtype", np.float64)
    return np.dtype(dtype) == np.float32 if ops.name != "jax" else str(dtype) == "float32"


def _product_error(ops, a, b, p):
    """a·b − p exactly, for p = fl(a·b): one fma on Dr.Jit (LLVM and CUDA fuse it); Dekker's splitting on
    NumPy and JAX, which evaluate a·b + c with two roundings (their ``fma`` is not fused)."""
    if ops.name in _FUSED:
        return ops.fma(a, b, -p)
    s = _SPLIT32 if _is_float32(ops, a) or _is_float32(ops, b) else _SPLIT64
    ta, tb = s * a, s * b
    ah = ta - (ta - a)
    bh = tb - (tb - b)
    al, bl = a - ah, b - bh
    return ((ah * bh - p) + ah * bl + al * bh) + al * bl


def _diff_of_products(ops, a, b, c, d):
    """a·b − c·d with one rounding (Kahan): w = c·d, (a·b − w) + (w − c·d) with the exact error of w."""
    w = c * d
    if ops.name in _FUSED:
        return ops.fma(a, b, -w) - _product_error(ops, c, d, w)
    p = a * b
    return (p - w) + _product_error(ops, a, b, p) - _product_error(ops, c, d, w)


def _segment_integral(ops, cx, cy, cz, dx, dy, dz, k, a):
    """∫₀¹ |d|/(k + a·|c − t·d|²) dt by the stable form (module docstring): L·atan2(Y, X)/Y."""
    ex, ey, ez = cx - dx, cy - dy, cz - dz  # l − (o + d): the segment's far end to the light
    px = _diff_of_products(ops, cy, dz, cz, dy)  # c × d, each component with one rounding
    py = _diff_of_products(ops, cz, dx, cx, dz)
    pz = _diff_of_products(ops, cx, dy, cy, dx)
    cross2 = px * px + py * py + pz * pz
    dd = dx * dx + dy * dy + dz * dz
    length = ops.sqrt(dd)
    x = k + a * (cx * ex + cy * ey + cz * ez)
    y2 = a * (k * dd + a * cross2)
    pos = y2 > 0.0
    y = ops.select(
        pos, ops.sqrt(ops.select(pos, y2, 1.0)), 0.0
    )  # √0 has no derivative: keep it off the JAX tape
    series = (x > 0.0) & (y <= _SERIES_LIMIT * x)
    x_s = ops.select(series, x, 1.0)
    z = ops.select(series, y / x_s, 0.0)
    # g(z) = atan(z)/z = 1 + (atan z − z)/z; z is clamped into the series' range, and 0 stays 0 (no 0/0)
    z_c = ops.minimum(z, _SERIES_LIMIT)
    g = 1.0 + atan_minus_x_series(ops, z_c) / ops.select(z_c > 0.0, z_c, 1.0)
    # Y = 0 off the series branch only for k = 0 and a segment through the light (X ≤ 0): the integral of
    # 1/r² diverges there (+∞); with k > 0, Y = 0 implies X ≥ k > 0 (series branch)
    through = (~series) & (y <= 0.0)
    y_s = ops.select(series | through, 1.0, y)
    atan_branch = ops.select(through, math.inf, ops.atan2(y, x) / y_s)
    return length * ops.select(series, g / x_s, atan_branch)


def _components(ox, oy, oz, dx, dy, dz, lx, ly, lz):
    return lx - ox, ly - oy, lz - oz, dx, dy, dz


def _stable_kernel(ops, ox, oy, oz, dx, dy, dz, lx, ly, lz, i, a):
    """The seed's model in rtfit's stable form: F = i·∫₀¹ |d|/(1 + a|c − t d|²) dt."""
    a = ops.maximum(a, 0.0)
    return ops.maximum(i, 0.0) * _segment_integral(
        ops, *_components(ox, oy, oz, dx, dy, dz, lx, ly, lz), 1.0, a
    )


def _seed_kernel(ops, ox, oy, oz, dx, dy, dz, lx, ly, lz, i, a):
    """000:2360 / 002:409 as printed: 2i|d|·[atan((v + 2w)/D) − atan(v/D)]/D, D = √(4uw − v²)."""
    cx, cy, cz = lx - ox, ly - oy, lz - oz
    u = 1.0 + a * (cx * cx + cy * cy + cz * cz)
    v = -2.0 * a * (cx * dx + cy * dy + cz * dz)
    w = a * (dx * dx + dy * dy + dz * dz)
    big_d = ops.sqrt(4.0 * u * w - v * v)  # NaN where rounding makes 4uw − v² < 0 (near-axial rays)
    length = ops.sqrt(dx * dx + dy * dy + dz * dz)
    return 2.0 * i * length * (ops.atan((v + 2.0 * w) / big_d) - ops.atan(v / big_d)) / big_d


def _inverse_square_kernel(ops, ox, oy, oz, dx, dy, dz, lx, ly, lz, k):
    """Single scattering without extinction: K·∫ ds/r² = K·|d|·angle/|c × d| (the k = 0 case of the text)."""
    return k * _segment_integral(ops, *_components(ox, oy, oz, dx, dy, dz, lx, ly, lz), 0.0, 1.0)


# ===================================================================================== methods (data)
_SEGMENT = (
    Input("ox", "m", "segment origin o (the camera), x", (-1e4, 1e4)),
    Input("oy", "m", "segment origin o, y", (-1e4, 1e4)),
    Input("oz", "m", "segment origin o, z", (-1e4, 1e4)),
    Input("dx", "m", "segment vector d (camera → scene point), x", (-1e4, 1e4)),
    Input("dy", "m", "segment vector d, y", (-1e4, 1e4)),
    Input("dz", "m", "segment vector d, z", (-1e4, 1e4)),
    # (the light's interval is narrower than o's only so that the domain's corners never put it on o)
    Input("lx", "m", "light position l, x", (-9e3, 9e3)),
    Input("ly", "m", "light position l, y", (-9e3, 9e3)),
    Input("lz", "m", "light position l, z", (-9e3, 9e3)),
)
_SEED_PARAMS = {
    "i": Param(1.0, 0.0, math.inf, unit="W/m³/sr", description="source level: gathered light per metre at l"),
    "a": Param(1.0, 0.0, 1e6, unit="1/m²", description="attenuation control: core radius 1/√a"),
}

METHODS = method_table(
    [
        Method(
            "stable",
            "seed model, stable form",
            _stable_kernel,
            inputs=_SEGMENT,
            params=_SEED_PARAMS,
            quantity="inscattered_radiance",
            formula="F = i·|d|·atan2(Y, X)/Y, Y = √(a(|d|² + a|c×d|²)), X = 1 + a·c·(c − d)",
            source="seed 000:2345-2385, 002:389-420 (rewritten: module docstring)",
            description="The seed's softened point light integrated along the view segment, float32-stable.",
        ),
        Method(
            "seed",
            "seed model, printed form",
            _seed_kernel,
            inputs=_SEGMENT,
            params=_SEED_PARAMS,
            quantity="inscattered_radiance",
            formula="F = 2i|d|·[atan((v + 2w)/D) − atan(v/D)]/D, D = √(4uw − v²)",
            source="seed 000:2360, 002:409 (as printed)",
            description="NaN where 4uw − v² rounds below 0 (near-axial rays, a|c|² ≫ 1), a = 0, |d| = 0.",
        ),
        Method(
            "inverse-square",
            "single scattering, no extinction",
            _inverse_square_kernel,
            inputs=_SEGMENT,
            params={
                "k": Param(1.0, 0.0, math.inf, unit="W/m/sr", description="σ_s·I/(4π)"),
            },
            quantity="inscattered_radiance",
            formula="L = σ_s·I/(4π)·∫ ds/r² = K·|d|·∠(o, l, o + d)/|c × d|",
            source="isotropic single scattering of a point light, T = 1 (the seed's a → ∞ limit, i/a = K)",
            description="Exact for a non-absorbing thin medium; the seed's model tends to it as a → ∞.",
        ),
    ]
)
"""The family's methods (module docstring): ``METHODS[id](ops, inputs, params)`` runs the kernel text on
one ops namespace, `rtfit.fitting.fit_method` fits ``stable``'s (i, a) through its JAX run."""


def _given_kernel(ops, single_scattering):
    """The exact row: single scattering with extinction and the medium's phase function along the segment,
    integrated by `rtfit.reference.single_scattering` (the reference layer is not importable from here),
    passed through."""
    return single_scattering


QUADRATURE = Method(
    "quadrature",
    "single scattering with extinction (quadrature, exact)",
    _given_kernel,
    inputs=(Input("single_scattering", "W/m²/sr", "the quadrature of the segment's single scattering"),),
    exact=True,
    quantity="inscattered_radiance",
    formula="L = σ_s ∫ I·p(cos ϑ)·e^(−σ_t(s − s₀ + r))/r² ds (Gauss–Legendre in u, s = c_∥ + h sinh u)",
    source="rtfit.reference.single_scattering.point_single_scattering",
    description="The exact row of `rtfit audit`: must sit at the reference's noise where nothing shadows "
    "the medium (not one of `METHODS`: the experiment compares its quadrature on its own).",
)
"""The exact row the audit adds to `METHODS` in the registry (``experiments.families.METHOD_TABLES``)."""


# ===================================================================================== public API
def _vec(v, name):
    if isinstance(v, (tuple, list)) and len(v) == 3 and all(is_drjit(x) or is_jax(x) for x in v):
        return tuple(v)
    comps = split3(v, name)
    for cpt in comps:
        if not (is_drjit(cpt) or is_jax(cpt)):
            arr = np.asarray(cpt, dtype=np.float64)
            if arr.size and not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be finite (got {arr[~np.isfinite(arr)].flat[0]!r})")
    return comps


def volumetric_lightning(origin, segment, light_position, intensity, a):
    """Light gathered along the view segment from a softened point light (the seed's F, module docstring):
    F = ∫₀¹ i·|d|/(1 + a·|l − (o + t·d)|²) dt.

    ``origin`` o (the camera), ``segment`` d (camera → scene point) and ``light_position`` l: 3-vectors in
    metres — Dr.Jit Array3f-likes, NumPy arrays of shape (..., 3), or length-3 sequences. ``intensity`` i ≥ 0
    (the gathered quantity per metre at the source) and ``a`` ≥ 0 (1/m²): floats or arrays. Returns F in the
    units of i times metres; i·|d| at a = 0 and 0 at |d| = 0. Stable in float32 over the whole domain
    (module docstring). Dispatch as every public function (`rtfit.realtime.arrays`).
    """
    o, d, lp = _vec(origin, "origin"), _vec(segment, "segment"), _vec(light_position, "light_position")
    check_range("intensity", intensity, 0.0, 3.4e38, interval="[0, 3.4e38] (finite)")
    check_range("a", a, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, 1/m²)")
    return evaluate(_stable_kernel, *o, *d, *lp, intensity, a)


def inverse_square_airlight(origin, segment, light_position, k=1.0):
    """Single scattering from an isotropic point light without extinction, K·∫ ds/r² along the segment
    (K = σ_s·I/(4π) in W/m/sr gives radiance in W/m²/sr): K·|d|·θ/|c × d| with θ the angle the segment
    subtends at the light. +∞ for a segment through the light (the integral diverges there). Arguments as
    for `volumetric_lightning`."""
    o, d, lp = _vec(origin, "origin"), _vec(segment, "segment"), _vec(light_position, "light_position")
    check_range("k", k, 0.0, 3.4e38, interval="[0, 3.4e38] (finite, W/m/sr)")
    return evaluate(_inverse_square_kernel, *o, *d, *lp, k)
