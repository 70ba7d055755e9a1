"""Spherical Gaussian (SG) irradiance bases: N lobes on a fixed Fibonacci set with one shared sharpness.

A spherical Gaussian of axis μ (unit), sharpness λ > 0 and amplitude a (W·m⁻²·sr⁻¹) is the radiance lobe

    G(ω) = a·exp(λ(μ·ω − 1)),          ∫ G dω = 2πa(1 − e^{−2λ})/λ            (SG integral, closed form).

A probe stores the amplitudes a_k (RGB) of N lobes with fixed axes μ_k = `sg_axes(N)` (the Fibonacci
spiral of `rtfit.realtime.irradiance_bases.fibonacci_sphere`) and one sharpness λ_N shared by all lobes,
optionally plus an ambient radiance c (the "ambient" fit). It models the *radiance*
L(ω) ≈ Σ_k a_k G_k(ω) + c; the irradiance at a normal n is the sum of the lobes' clamped-cosine
convolutions,

    E(n) = Σ_k a_k S(λ, μ_k·n) + π c,      S(λ, t) = ∫ exp(λ(μ·ω − 1)) max(n·ω, 0) dω,  t = μ·n.

**Sharpness rule.** λ_N = ln 2 / (1 − cos θ̄_N), θ̄_N the mean angle from each lobe to its nearest
neighbour: neighbouring lobes cross at half their peak (N = 6, 9, 12 → λ = 0.863, 1.274, 1.641;
`sg_sharpness`). Wider lobes make the Gram matrix ill-conditioned, sharper ones leave gaps between lobes.

**Clamped-cosine convolution S (the one kernel text, `sg_cosine_irradiance`).** S has no elementary closed
form. We use Stephen Hill's fitted shape (as published by M. Pettineo, "SG Series Part 3: Diffuse Lighting
From an SG Light Source", 2016, function ``SGIrradianceFitted``): with c₀ = 0.36, c₁ = 1/(4c₀),

    y(t) = (c₀t + c₁x)²/x   where |c₀t| ≤ c₁x,   else  clamp(t, 0, 1),

a C¹ quadratic blend of the clamped cosine around the terminator of half-width x/(4c₀²). Hill normalises
with "scale = 1 + 2e^{−2λ} − 1/λ" and the approximate integral 2π/λ, which is only valid for sharp lobes
(it diverges as λ → 0: measured 0.35× the peak wrong at λ = 0.7, 12× at λ = 0.3). rtfit instead takes the
**exact** end values e₊ = S(λ, 1)/I, e₋ = S(λ, −1)/I (I = ∫G dω; closed forms below) and sets

    S̃(λ, t) = I·(s·y(t) + e₋ − s·y(−1)),   s = e₊ − e₋,  x = √(1 − s),

so S̃ is exact at t = ±1 (y(1) − y(−1) = 1 for every x), for λ → 0 (the constant lobe: S = π) and for
λ → ∞ (the delta lobe: S = I·max(t, 0)). The end values, with h(λ) = (1 − e^{−λ})/λ:

    e₊ = (1 − h)/(1 − e^{−2λ}),    e₋ = e^{−λ}(h − e^{−λ})/(1 − e^{−2λ}).

**Measured error** of S̃ against the exact convolution (`sg_cosine_quadrature`: the azimuth integral in
closed form, the polar one by adaptive Gauss–Kronrod, float64), as max |S̃ − S| / S(λ, 1) over t ∈ [−1, 1]:
2e-4 at λ = 0.001, 0.015 at 0.1, 0.050 at 0.7, **0.0503 at λ = 0.8 (the maximum over λ ∈ [1e-3, 1e3],
at t ≈ 0)**, 0.048 at 1, 0.042 at 1.274, 0.031 at 1.641, 0.006 at 3, 0.018 at 10, 0.003 at 1000
(`sg_cosine_error`; the experiment re-measures it in its self-checks; docs/irradiance-bases.md has the
table).

**Guards (no NaN/Inf for any λ ≥ 0 and any t).** For λ < 0.1 the ratios e± come from their Taylor series
(e₊ = p/d, e₋ = e^{−λ}q/d with p = (1 − h)/λ = ½ − λ/6 + λ²/24 − …,
q = (h − e^{−λ})/λ = ½ − λ/3 + λ²/8 − …, d = (1 − e^{−2λ})/λ = 2 − 2λ + 4λ²/3 − …, six or seven terms
each: truncation < 1e-9 relative at λ = 0.1), so λ = 0 gives the constant lobe
exactly and no 0/0 is formed (the direct branch sees max(λ, 0.1)); λ < 0 is clamped to 0. For λ → ∞,
e^{−λ} underflows to 0, s → 1, x → 0: the division by x uses max(x, 1e-30) and is only taken inside the
blend region, whose half-width x/(4c₀²) then shrinks to 0 (y = clamp(t, 0, 1)). I = 2πd̃ with
d̃ = (1 − e^{−2λ})/λ from ``expm1`` (series below 1e-3).

**Amplitudes from an environment** (float64 NumPy; `fit_sg`), for radiance samples (directions d_j,
solid-angle weights w_j, radiance L_j) plus an optional constant radiance:

* ``naive``: a_k = ⟨L, G_k⟩ / ⟨S_N, G_k⟩ with S_N = Σ_j G_j — the projection ⟨L, G_k⟩ = Σ_j w_j L_j G_k(d_j)
  normalised so that a lobe's amplitude is the G_k·S_N-weighted mean radiance (a constant environment is
  reproduced where S_N is flat); no linear solve;
* ``ls``: the radiance least squares min ∫(Σ a_k G_k − L)² dω: Gram system M a = b with the closed form
  M_jk = ⟨G_j, G_k⟩ = 4π e^{−2λ} sinh(κ)/κ, κ = λ|μ_j + μ_k| (`sg_gram`), b_k = ⟨L, G_k⟩;
* ``nnls``: the same objective with a ≥ 0 (`rtfit.realtime.nonnegative_lsq` on the Cholesky factor: M = RᵀR,
  min ‖Ra − R⁻ᵀb‖² = aᵀMa − 2aᵀb + const);
* ``ambient``: least squares over the N lobes plus a constant function (⟨1, G_k⟩ = I, ⟨1, 1⟩ = 4π); the
  constant is stored as an extra coefficient (N + 1 per channel). At the rule's λ the constant lies
  almost in the lobes' span (Gram condition number 2.9e4 / 6.0e4 / 8.2e4 for N = 6 / 9 / 12, against
  265 / 248 / 700 without it): the plain solution has large lobes of alternating sign that cancel in
  radiance but not through the approximate S̃ (measured irradiance rel. RMSE 3.5–4.0 on a 10° sun and
  1.8–3.2 on the studio map). The ambient fit therefore adds a Tikhonov term ε Σ_k a_k² with
  ε = `AMBIENT_RIDGE`·⟨G_k, G_k⟩ = 0.03·⟨G_k, G_k⟩, chosen from a sweep ε/⟨G_k, G_k⟩ ∈ {0, 1e-4, 1e-3,
  1e-2, 0.03, 0.1} on those two environments (N = 6 and 12: rel. RMSE 0.33/0.093 on the sun,
  0.17/0.087 on the studio at 0.03; within 10% of the best of the sweep everywhere). The constant itself is
  not penalised, so a constant environment is still stored exactly (a = 0, c = L).

Methods as data: `SG_METHODS` holds ``sg{6,9,12}-{naive,ls,nnls,ambient}``; their ``storage`` is 3N floats
(3(N + 1) for ``ambient``). The kernel takes ``nx, ny, nz`` and the stored floats channel-major (R, G, B),
exactly like the bases of `rtfit.realtime.irradiance_bases` (`basis_irradiance` runs any of them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .arrays import NUMPY_OPS
from .irradiance_bases import fibonacci_sphere, unit_normal
from .methods import Input, Method, method_table
from .nonnegative_lsq import nnls_columns

__all__ = [
    "AMBIENT_RIDGE",
    "SG_COUNTS",
    "SG_FITS",
    "SG_METHODS",
    "disc_samples",
    "fit_sg",
    "fit_sg_all",
    "sg_axes",
    "sg_cosine_error",
    "sg_cosine_irradiance",
    "sg_cosine_quadrature",
    "sg_gram",
    "sg_integral",
    "sg_lobe",
    "sg_sharpness",
]

SG_COUNTS = (6, 9, 12)
SG_FITS = ("naive", "ls", "nnls", "ambient")
HILL_C0 = 0.36
HILL_C1 = 1.0 / (4.0 * HILL_C0)
AMBIENT_RIDGE = 0.03  # Tikhonov weight of the ambient fit, × ⟨G_k, G_k⟩ (module docstring)
_SERIES_LIMIT = 0.1  # below it the end values e± come from their Taylor series
_D_SERIES_LIMIT = 1e-3  # below it (1 − e^{−2λ})/λ from its series
_TINY = 1e-30


# =========================================================================================== kernels
def sg_lobe(ops, lam, cos_angle):
    """Unit-amplitude SG exp(λ(μ·ω − 1)) at cos_angle = μ·ω (1)."""
    return ops.exp(lam * (cos_angle - 1.0))


def _integral_ratio(ops, lam):
    """d(λ) = (1 − e^{−2λ})/λ (→ 2 as λ → 0; ∫G dω = 2π d)."""
    direct = -ops.expm1(-2.0 * ops.maximum(lam, _D_SERIES_LIMIT)) / ops.maximum(lam, _D_SERIES_LIMIT)
    ls = ops.minimum(lam, _D_SERIES_LIMIT)
    series = 2.0 + ls * (-2.0 + ls * (4.0 / 3.0 + ls * (-2.0 / 3.0)))
    return ops.select(lam < _D_SERIES_LIMIT, series, direct)


def sg_integral(ops, lam):
    """∫ exp(λ(μ·ω − 1)) dω = 2π(1 − e^{−2λ})/λ (sr), 4π at λ = 0; λ ≥ 0 (negative values act as 0)."""
    lam = ops.maximum(lam, 0.0)
    return (2.0 * math.pi) * _integral_ratio(ops, lam)


def _end_values(ops, lam):
    """(e₊, e₋): S(λ, ±1)/I of a unit SG (module docstring), series below λ = 0.1."""
    small = lam < _SERIES_LIMIT
    lb = ops.maximum(lam, _SERIES_LIMIT)
    eml = ops.exp(-lb)
    h = -ops.expm1(-lb) / lb
    den = -ops.expm1(-2.0 * lb)
    ep_direct = (1.0 - h) / den
    em_direct = eml * (h - eml) / den
    lam = ops.minimum(lam, _SERIES_LIMIT)  # the series branch never sees large λ (no inf/inf)
    p = 0.5 + lam * (-1 / 6 + lam * (1 / 24 + lam * (-1 / 120 + lam * (1 / 720 + lam * (-1 / 5040)))))
    q = 0.5 + lam * (-1 / 3 + lam * (1 / 8 + lam * (-1 / 30 + lam * (1 / 144 + lam * (-1 / 840)))))
    d = 2.0 + lam * (-2 + lam * (4 / 3 + lam * (-2 / 3 + lam * (4 / 15 + lam * (-4 / 45 + lam * (8 / 315))))))
    return (
        ops.select(small, p / d, ep_direct),
        ops.select(small, ops.exp(-lam) * q / d, em_direct),
    )


def _hill_shape(ops, t, x):
    """Hill's y(t): (c₀t + c₁x)²/x where |c₀t| ≤ c₁x, else clamp(t, 0, 1)."""
    x0 = HILL_C0 * t
    x1 = HILL_C1 * x
    n = x0 + x1
    blend = ops.abs(x0) <= x1
    inv = 1.0 / max(x, _TINY) if isinstance(x, float) else 1.0 / ops.maximum(x, _TINY)
    return ops.select(blend, n * n * inv, ops.clip(t, 0.0, 1.0))


def _cosine_terms(ops, lam):
    """(I·s, I·(e₋ − s·y(−1)), I, x) of S̃(λ, t) = I·s·y(t) + I·(e₋ − s·y(−1))."""
    lam = ops.maximum(lam, 0.0)
    ep, em = _end_values(ops, lam)
    s = ep - em
    x = ops.sqrt(ops.maximum(1.0 - s, 0.0))
    integral = sg_integral(ops, lam)
    y_m1 = _hill_shape(ops, -1.0 + 0.0 * x, x)
    return integral * s, integral * (em - s * y_m1), integral, x


def sg_cosine_irradiance(ops, lam, t):
    """S̃(λ, t) ≈ ∫ exp(λ(μ·ω − 1)) max(n·ω, 0) dω (W/m² per unit amplitude W·m⁻²·sr⁻¹), t = μ·n ∈ [−1, 1]:
    Hill's fitted shape with exact end values (module docstring); max error 5.03% of S(λ, 1) (at λ ≈ 0.8)."""
    lam = lam + 0.0 * t  # an array of t's kind (constants then go through the same ops)
    scale, bias, _, x = _cosine_terms(ops, lam)
    return scale * _hill_shape(ops, t, x) + bias


def _sg_kernel(ops, nx, ny, nz, coeffs, axes, lam, ambient=False):
    """E(n) = Σ_k a_k S̃(λ, μ_k·n) (+ π c): ``coeffs`` 3·K floats channel-major, per channel the N lobe
    amplitudes a_k (W·m⁻²·sr⁻¹) and, with ``ambient``, the constant radiance c last; ``axes`` the N unit
    lobe axes (fixed), ``lam`` the shared sharpness."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    if isinstance(lam, (int, float)):  # a fixed λ: its constants by the same text in float64, as literals
        scale, bias, integral, width = (float(v) for v in _cosine_terms(NUMPY_OPS, float(lam)))
    else:
        scale, bias, integral, width = _cosine_terms(ops, lam + 0.0 * x)
    shapes = [_hill_shape(ops, ax * x + ay * y + az * z, width) for ax, ay, az in axes]
    count = len(axes)
    per = count + (1 if ambient else 0)
    out = []
    for ch in range(3):
        a = coeffs[ch * per : ch * per + count]
        acc = a[0] * shapes[0]
        total = a[0] + 0.0
        for k in range(1, count):
            acc = acc + a[k] * shapes[k]
            total = total + a[k]
        e = scale * acc + bias * total
        mean = 0.25 * integral * total  # the sphere-average irradiance (zero-length normals)
        if ambient:
            e = e + math.pi * coeffs[ch * per + count]
            mean = mean + math.pi * coeffs[ch * per + count]
        out.append(ops.select(valid, e, mean))
    return tuple(out)


# =========================================================================================== geometry
def sg_axes(count: int) -> np.ndarray:
    """The N fixed lobe axes (N, 3): the Fibonacci spiral of `fibonacci_sphere`."""
    return fibonacci_sphere(count)


def sg_sharpness(count: int) -> float:
    """λ_N = ln 2/(1 − cos θ̄): neighbouring lobes cross at half peak (θ̄: mean nearest-neighbour angle)."""
    a = sg_axes(count)
    if len(a) < 2:
        raise ValueError(f"count must be >= 2 (got {count})")
    c = a @ a.T
    np.fill_diagonal(c, -2.0)
    theta = float(np.mean(np.arccos(np.clip(c.max(axis=1), -1.0, 1.0))))
    return math.log(2.0) / (1.0 - math.cos(theta))


# =========================================================================================== methods
_NORMAL = (
    Input("nx", "1", "normal x (world frame, +Z up; normalised by the kernel)"),
    Input("ny", "1", "normal y"),
    Input("nz", "1", "normal z"),
)
_HILL = (
    "Pettineo 2016, SG Series Part 3 (Hill's fitted SG irradiance, end values made exact); "
    "Probulator (SG bases)"
)


def _sg_method(count: int, fit: str) -> Method:
    lam = sg_sharpness(count)
    ambient = fit == "ambient"
    per = count + (1 if ambient else 0)
    how = {
        "naive": "naive projection ⟨L,G_k⟩/⟨Σ_j G_j, G_k⟩",
        "ls": "radiance least squares (Gram matrix, closed form)",
        "nnls": "radiance least squares with a ≥ 0 (NNLS)",
        "ambient": "radiance least squares with an extra constant term c",
    }[fit]
    formula = f"E(n) = Σ_k a_k S̃(λ, μ_k·n){' + πc' if ambient else ''}, N = {count}, λ = {lam:.4g}"
    return Method(
        id=f"sg{count}-{fit}",
        label=f"SG {count} lobes, {fit}",
        kernel=_sg_kernel,
        inputs=(
            *_NORMAL,
            Input("coeffs", "W·m⁻²·sr⁻¹", f"{3 * per} floats: lobe amplitudes (+ ambient), channel-major"),
        ),
        fixed={
            "axes": tuple(tuple(float(v) for v in a) for a in sg_axes(count)),
            "lam": lam,
            "ambient": ambient,
        },
        storage=3 * per,
        quantity="environment_irradiance",
        formula=f"{formula}; {how}",
        source=_HILL,
        description=f"λ by the half-peak neighbour rule; amplitudes by {how}",
    )


SG_METHODS: Mapping[str, Method] = method_table([_sg_method(n, f) for n in SG_COUNTS for f in SG_FITS])
"""The SG bases as data: ``sg{N}-{fit}`` for N in `SG_COUNTS`, fit in `SG_FITS`."""


# =========================================================================================== fits
def sg_gram(axes, lam: float, ambient: bool = False) -> np.ndarray:
    """⟨G_j, G_k⟩ = ∫ G_j G_k dω = 4π e^{−2λ} sinh(κ)/κ, κ = λ|μ_j + μ_k| (K, K); with ``ambient`` a last
    row/column for the constant function (⟨1, G_k⟩ = ∫G dω, ⟨1, 1⟩ = 4π). Computed as
    e^{κ−2λ}·`sg_integral`(κ) (G_j G_k = e^{−2λ} e^{κ ν·ω}, ν the unit bisector; κ ≤ 2λ: no overflow)."""
    a = np.asarray(axes, np.float64)
    kappa = float(lam) * np.linalg.norm(a[:, None, :] + a[None, :, :], axis=-1)
    # ∫ e^{κ ν·ω} dω = 4π sinh(κ)/κ = e^{κ}·2π(1 − e^{−2κ})/κ = e^{κ}·∫exp(κ(ν·ω − 1)) dω
    g = np.exp(kappa - 2.0 * float(lam)) * sg_integral(NUMPY_OPS, kappa)
    if ambient:
        i = float(sg_integral(NUMPY_OPS, float(lam)))
        k = len(a)
        out = np.empty((k + 1, k + 1))
        out[:k, :k] = g
        out[:k, k] = out[k, :k] = i
        out[k, k] = 4.0 * math.pi
        return out
    return g


def disc_samples(direction, angular_radius: float, irradiance, rings: int = 16, azimuths: int = 32):
    """Midpoint samples of a uniform disc at infinity (angular radius ``angular_radius`` rad ∈ (0, π/2],
    normal-incidence irradiance ``irradiance`` W/m², RGB): directions (M, 3), solid-angle weights (M,)
    (uniform in cos θ' and φ about the disc centre), radiance (M, 3) = E⊥/(π sin²α)."""
    alpha = float(angular_radius)
    if not (0.0 < alpha <= math.pi / 2):
        raise ValueError(f"angular_radius must be in (0, pi/2] radians (got {angular_radius!r})")
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(d, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(d, t1)
    ca = math.cos(alpha)
    u = 1.0 - (1.0 - ca) * (np.arange(rings) + 0.5) / rings  # cos θ'
    phi = 2.0 * math.pi * (np.arange(azimuths) + 0.5) / azimuths
    uu, pp = np.meshgrid(u, phi, indexing="ij")
    st = np.sqrt(np.maximum(0.0, 1.0 - uu * uu))
    dirs = (
        uu[..., None] * d + (st * np.cos(pp))[..., None] * t1 + (st * np.sin(pp))[..., None] * t2
    ).reshape(-1, 3)
    w = np.full(len(dirs), 2.0 * math.pi * (1.0 - ca) / (rings * azimuths))
    e = np.broadcast_to(np.asarray(irradiance, np.float64), (3,))
    radiance = np.repeat((e / (math.pi * math.sin(alpha) ** 2))[None, :], len(dirs), axis=0)
    return dirs, w, radiance


def _projections(axes, lam, directions, weights, radiance, constant, ambient):
    """b_k = ⟨L, G_k⟩ (K, 3) (+ ⟨L, 1⟩ with ``ambient``)."""
    a = np.asarray(axes, np.float64)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    wl = (
        np.asarray(radiance, np.float64).reshape(-1, 3) * np.asarray(weights, np.float64).reshape(-1)[:, None]
    )
    b = sg_lobe(NUMPY_OPS, float(lam), d @ a.T).T @ wl if len(d) else np.zeros((len(a), 3))
    c = np.zeros(3) if constant is None else np.broadcast_to(np.asarray(constant, np.float64), (3,))
    b = b + float(sg_integral(NUMPY_OPS, float(lam))) * c[None, :]
    if ambient:
        b = np.concatenate([b, (wl.sum(axis=0) + 4.0 * math.pi * c)[None, :]])
    return b


def fit_sg(
    count: int,
    fit: str,
    directions=(),
    weights=(),
    radiance=(),
    constant=None,
    lam: float | None = None,
    ridge: float = AMBIENT_RIDGE,
) -> np.ndarray:
    """Amplitudes (K, 3) of the ``sg{count}-{fit}`` basis (K = count, + 1 for ``ambient``: the constant
    radiance last) for an environment given as radiance samples (directions (M, 3), solid-angle weights
    (M,), radiance (M, 3), e.g. `latlong_samples` and `disc_samples` concatenated) plus an optional
    constant radiance (RGB). ``lam``: the sharpness (default `sg_sharpness`); ``ridge``: the ambient fit's
    Tikhonov weight in units of ⟨G_k, G_k⟩ (0: plain least squares). See the module docstring."""
    if fit not in SG_FITS:
        raise ValueError(f"fit must be one of {SG_FITS} (got {fit!r})")
    return fit_sg_all(count, directions, weights, radiance, constant, lam, (fit,), ridge)[fit]


def fit_sg_all(
    count: int,
    directions=(),
    weights=(),
    radiance=(),
    constant=None,
    lam: float | None = None,
    fits: tuple[str, ...] = SG_FITS,
    ridge: float = AMBIENT_RIDGE,
) -> dict[str, np.ndarray]:
    """`fit_sg` for several ``fits`` at once ({fit: amplitudes}); the projections ⟨L, G_k⟩ (the expensive
    part: one exponential per sample and lobe) are computed once."""
    bad = [f for f in fits if f not in SG_FITS]
    if bad:
        raise ValueError(f"fit must be one of {SG_FITS} (got {bad[0]!r})")
    axes = sg_axes(count)
    lam = sg_sharpness(count) if lam is None else float(lam)
    if not (math.isfinite(lam) and lam > 0.0):
        raise ValueError(f"lam must be a finite number > 0 (got {lam!r})")
    b_all = _projections(axes, lam, directions, weights, radiance, constant, True)
    g_all = sg_gram(axes, lam, True)
    if not (math.isfinite(ridge) and ridge >= 0.0):
        raise ValueError(f"ridge must be a finite number >= 0 (got {ridge!r})")
    return {f: _solve(f, g_all, b_all, count, ridge) for f in fits}


def _solve(fit: str, g_all: np.ndarray, b_all: np.ndarray, count: int, ridge: float) -> np.ndarray:
    """Amplitudes of one fit from the Gram matrix and projections with the constant function appended."""
    k = count + 1 if fit == "ambient" else count
    gram, b = g_all[:k, :k].copy(), b_all[:k]
    if (
        fit == "ambient"
    ):  # Tikhonov on the lobe amplitudes (module docstring: the constant is near their span)
        gram[np.arange(count), np.arange(count)] += ridge * g_all[0, 0]
    if fit == "naive":
        return b / gram.sum(axis=0)[:, None]
    if fit in ("ls", "ambient"):
        return np.linalg.solve(gram, b)
    r = np.linalg.cholesky(gram).T  # gram = rᵀr
    rhs = np.linalg.solve(r.T, b)
    return nnls_columns(r, rhs)


# =========================================================================================== oracle
def sg_cosine_quadrature(lam: float, t: float) -> float:
    """The exact S(λ, t) = ∫ exp(λ(μ·ω − 1)) max(n·ω, 0) dω by quadrature (float64, scipy): in the frame of μ
    the azimuth integral is closed form, ∫₀^{2π} max(a + b cos φ, 0) dφ = 2aφ₀ + 2b sin φ₀ with
    cos φ₀ = −a/b (a = t u, b = √(1 − t²)√(1 − u²), u = μ·ω), and the polar one runs over s = λ(1 − u) ∈
    [0, 2λ] with weight e^{−s}/λ (adaptive Gauss–Kronrod, breakpoints at the terminator kinks)."""
    from scipy import integrate

    lam, t = float(lam), float(t)
    st = math.sqrt(max(0.0, 1.0 - t * t))

    def azimuth(u):
        a = t * u
        b = st * math.sqrt(max(0.0, 1.0 - u * u))
        if a >= b:
            return 2.0 * math.pi * a
        if a <= -b:
            return 0.0
        phi0 = math.acos(-a / b)
        return 2.0 * a * phi0 + 2.0 * b * math.sin(phi0)

    if lam == 0.0:
        return math.pi
    hi = 2.0 * lam
    kinks = [p for p in (lam * (1.0 - st), lam * (1.0 + st)) if 0.0 < p < hi]
    val, _ = integrate.quad(
        lambda s: math.exp(-s) * azimuth(1.0 - s / lam) / lam,
        0.0,
        hi,
        points=kinks or None,
        limit=400,
        epsabs=0.0,
        epsrel=1e-11,
    )
    return val


def sg_cosine_error(lams, ts=None) -> dict:
    """Max |S̃ − S|/S(λ, 1) of the kernel text (NumPy, float64) against `sg_cosine_quadrature`, per λ of
    ``lams`` over ``ts`` (default 81 cosines in [−1, 1]): {"lam": [...], "max_rel": [...],
    "worst_t": [...]}."""
    ts = np.linspace(-1.0, 1.0, 81) if ts is None else np.asarray(ts, np.float64)
    out: dict = {"lam": [], "max_rel": [], "worst_t": []}
    for lam in lams:
        exact = np.array([sg_cosine_quadrature(lam, t) for t in ts])
        approx = np.asarray(sg_cosine_irradiance(NUMPY_OPS, float(lam), ts), np.float64)
        err = np.abs(approx - exact) / sg_cosine_quadrature(lam, 1.0)
        i = int(np.argmax(err))
        out["lam"].append(float(lam))
        out["max_rel"].append(float(err[i]))
        out["worst_t"].append(float(ts[i]))
    return out
