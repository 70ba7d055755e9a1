"""Hemispherical irradiance bases for lightmaps: the H-basis and Half-Life 2's radiosity normal mapping.

A lightmap texel stores the irradiance E(n) = ∫ L(ω) max(n·ω, 0) dω (W/m² per RGB channel) that a
*bumped* normal n sees, for normals in the upper hemisphere of the texel's surface frame (tangent t,
bitangent b, geometric normal N). Both bases here take the normal in that **tangent frame**:
n_t = (n·t, n·b, n·N), so n_z = cos θ from the geometric normal and n_z ≥ 0 is the hemisphere a normal
map can reach (`surface_frame`, `to_tangent`).

H-basis (Habel & Wimmer 2010, "Efficient irradiance normal mapping", I3D; the basis functions of its
appendix, eqs. H1–H6, as also implemented in Probulator's ``HBasis.h``): an orthonormal basis of
functions on the hemisphere Ω+ = {n_z ≥ 0}, built from the SH bands l ≤ 2 shifted to the hemisphere,
with x = n_x, y = n_y, z = n_z:

    H1 = 1/√(2π)                 H2 = −√(3/(2π)) y        H3 = √(3/(2π)) (2z − 1)
    H4 = −√(3/(2π)) x            H5 = √(15/(2π)) x y      H6 = ½ √(15/(2π)) (x² − y²)

(H2, H4 carry the Condon–Shortley sign of the SH they come from; projection and evaluation use the same
functions, so the sign only matters for exchanging coefficients with other tools.) ``hbasis-4`` stores
H1..H4, ``hbasis-6`` H1..H6 per channel; the coefficients are the projection of the *irradiance*
function over the hemisphere of normals, c_k = ∫_{Ω+} E(n) H_k(n) dn (`hbasis_project`, with the
Gauss–Legendre × uniform-φ rule of `hemisphere_quadrature`), and the texel is evaluated as
E(n) ≈ Σ_k c_k H_k(n). 12 and 18 floats per texel (RGB). Below the horizon (n_z < 0, which a normal map
should not produce) the kernel evaluates the same polynomials (linear extrapolation in n_z).

Radiosity normal mapping (RNM; Valve, McTaggart 2004 "Half-Life 2 / Valve Source shading", GDC; seed
000:2448-2460, whose Figure 3 with the basis was lost in the text conversion): three lightmaps E_i hold
the irradiance at the three tangent-space directions (Valve's ``g_localBumpBasis``)

    b0 = (√(2/3), 0, 1/√3)    b1 = (−1/√6, 1/√2, 1/√3)    b2 = (−1/√6, −1/√2, 1/√3),

an orthonormal basis tilted 54.7° from N, each at 120° of azimuth from the next (so b0 + b1 + b2 = √3 ẑ).
With d_i = max(n·b_i, 0) the bumped irradiance is E(n) ≈ Σ_i w_i E_i with weights (``weighting``):

* ``linear``      w_i = d_i (McTaggart 2004's shader, Probulator's ``ExperimentRNM``). For a constant
  environment (E_i = E) it returns E·Σ d_i = √3 n_z E inside the cone where every d_i > 0: 1.73× too
  bright for the flat normal. Kept because it is the published form;
* ``squared``     w_i = d_i² (Green 2007, "Efficient self-shadowed radiosity normal mapping", SIGGRAPH
  course): Σ d_i² = |n|² = 1 wherever all n·b_i ≥ 0 (orthonormal basis), so a constant is exact there;
  outside that cone the clamped weights sum to less than 1 (too dark near the horizon);
* ``normalized``  w_i = d_i² / Σ_j d_j² (the Source SDK's lightmapped shaders): a constant is exact at
  every normal with n_z ≥ 0 (there Σ_j d_j² ≥ 1/2 > 0).

All three reproduce E_i exactly at n = b_i (d = e_i). 9 floats per texel (RGB).

Methods as data (`METHODS`): ``hbasis-4``, ``hbasis-6``, ``rnm-linear``, ``rnm-squared``,
``rnm-normalized``, each with its kernel, inputs, storage and formula; the RNM rows share one kernel text
with ``weighting`` fixed. Kernels take ``nx, ny, nz`` (tangent frame; normalised by the kernel) and
``coeffs``, the texel's stored floats channel-major (R, G, B). Run them with
`rtfit.realtime.irradiance_bases.basis_irradiance` (which takes a `Method`) or `hemisphere_irradiance`.
A zero-length Dr.Jit normal returns the texel's average (H: c1·H1; RNM: the mean of the three E_i).

Everything here runs on Dr.Jit and NumPy (and JAX) from one kernel text (`rtfit.realtime.arrays`).
"""

from __future__ import annotations

import math

import numpy as np

from .arrays import NUMPY_OPS, safe_div
from .irradiance_bases import basis_inputs, basis_irradiance, unit_normal
from .methods import Input, Method, method_table

__all__ = [
    "HBASIS_C",
    "HEMISPHERE_METHODS",
    "RNM_BASIS",
    "RNM_WEIGHTINGS",
    "hbasis_design_matrix",
    "hbasis_project",
    "hemisphere_irradiance",
    "hemisphere_quadrature",
    "rnm_lightmaps_from",
    "surface_frame",
    "to_tangent",
]

HBASIS_C = (
    1.0 / math.sqrt(2.0 * math.pi),  # H1
    math.sqrt(3.0 / (2.0 * math.pi)),  # H2, H3, H4
    math.sqrt(15.0 / (2.0 * math.pi)),  # H5 (H6 has half of it)
)
"""Normalisation constants of the H-basis (Habel & Wimmer 2010, appendix)."""
_S6, _S2, _S3 = math.sqrt(1.0 / 6.0), math.sqrt(0.5), math.sqrt(1.0 / 3.0)
RNM_BASIS = (
    (math.sqrt(2.0 / 3.0), 0.0, _S3),
    (-_S6, _S2, _S3),
    (-_S6, -_S2, _S3),
)
"""Valve's radiosity normal mapping basis in tangent space (b0, b1, b2), orthonormal, b_i·ẑ = 1/√3."""
RNM_WEIGHTINGS = ("linear", "squared", "normalized")


# =========================================================================================== kernels
def _hbasis_values(x, y, z, count):
    """H1..H_count at unit tangent-space (x, y, z) (any array type)."""
    c1, c3, c15 = HBASIS_C
    h = [c1 + 0.0 * x, -c3 * y, c3 * (2.0 * z - 1.0), -c3 * x]
    if count == 6:
        h += [c15 * x * y, 0.5 * c15 * (x * x - y * y)]
    return h


def _hbasis_kernel(ops, nx, ny, nz, coeffs, count=4):
    """E(n) = Σ_k c_k H_k(n) per channel; ``coeffs``: 3·count H-basis coefficients of the irradiance
    (W/m²·sr^½: c_k = ∫_{Ω+} E H_k dn), channel-major; ``count`` 4 or 6."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    h = _hbasis_values(x, y, z, count)
    out = []
    for ch in range(3):
        c = coeffs[ch * count : (ch + 1) * count]
        e = c[0] * h[0]
        for k in range(1, count):
            e = e + c[k] * h[k]
        out.append(ops.select(valid, e, c[0] * HBASIS_C[0]))
    return tuple(out)


def _rnm_kernel(ops, nx, ny, nz, coeffs, weighting="normalized"):
    """E(n) = Σ_i w_i E_i per channel with d_i = max(n·b_i, 0) and w_i = d_i, d_i² or d_i²/Σ_j d_j²
    (``weighting``); ``coeffs``: 9 floats, per channel the lightmaps (E0, E1, E2) (W/m²), channel-major."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    d = [ops.maximum(b[0] * x + b[1] * y + b[2] * z, 0.0) for b in RNM_BASIS]
    if weighting == "linear":
        w = d
    else:
        w = [di * di for di in d]
        if weighting == "normalized":
            s = w[0] + w[1] + w[2]
            w = [safe_div(ops, wi, s) for wi in w]
    out = []
    for ch in range(3):
        e0, e1, e2 = coeffs[ch * 3 : (ch + 1) * 3]
        e = w[0] * e0 + w[1] * e1 + w[2] * e2
        out.append(ops.select(valid, e, (e0 + e1 + e2) * (1.0 / 3.0)))
    return tuple(out)


# =========================================================================================== methods
_NORMAL_T = (
    Input("nx", "1", "bumped normal x in the tangent frame (along the tangent; normalised by the kernel)"),
    Input("ny", "1", "bumped normal y (along the bitangent)"),
    Input("nz", "1", "bumped normal z (along the geometric normal; ≥ 0 on the hemisphere)"),
)
_HABEL = "Habel & Wimmer 2010, Efficient irradiance normal mapping (I3D), appendix H1–H6"
_H_FORMULA = "E(n) = Σ_k c_k H_k(n), c_k = ∫_{Ω+} E(n) H_k(n) dn (tangent frame, n_z ≥ 0)"
_RNM_SOURCE = "McTaggart 2004 (Half-Life 2 / Valve Source shading); seed 000:2448-2460 (basis figure lost)"
_RNM_COEFFS = Input("coeffs", "W/m²", "9 floats: lightmaps E_i = E(b_i), i = 0..2, channel-major (R, G, B)")
_RNM_D = "d_i = max(n·b_i, 0), b = (√⅔, 0, 1/√3), (−1/√6, ±1/√2, 1/√3)"

HEMISPHERE_METHODS = method_table(
    [
        Method(
            id="hbasis-4",
            label="H-basis (4)",
            kernel=_hbasis_kernel,
            inputs=(*_NORMAL_T, Input("coeffs", "W/m²", "12 floats: H1..H4 coefficients, channel-major")),
            fixed={"count": 4},
            storage=12,
            quantity="environment_irradiance",
            formula=f"{_H_FORMULA}, k = 1..4",
            source=_HABEL,
            description="linear in n on the hemisphere",
        ),
        Method(
            id="hbasis-6",
            label="H-basis (6)",
            kernel=_hbasis_kernel,
            inputs=(*_NORMAL_T, Input("coeffs", "W/m²", "18 floats: H1..H6 coefficients, channel-major")),
            fixed={"count": 6},
            storage=18,
            quantity="environment_irradiance",
            formula=f"{_H_FORMULA}, k = 1..6",
            source=_HABEL,
            description="adds the two quadratic functions xy and x² − y²",
        ),
        Method(
            id="rnm-linear",
            label="RNM, linear weights (HL2 2004)",
            kernel=_rnm_kernel,
            inputs=(*_NORMAL_T, _RNM_COEFFS),
            fixed={"weighting": "linear"},
            storage=9,
            quantity="environment_irradiance",
            formula=f"E(n) = Σ_i d_i E_i, {_RNM_D}",
            source=_RNM_SOURCE,
            description="a constant environment comes out √3·n_z times too bright",
        ),
        Method(
            id="rnm-squared",
            label="RNM, squared weights",
            kernel=_rnm_kernel,
            inputs=(*_NORMAL_T, _RNM_COEFFS),
            fixed={"weighting": "squared"},
            storage=9,
            quantity="environment_irradiance",
            formula=f"E(n) = Σ_i d_i² E_i, {_RNM_D}",
            source="Green 2007, Efficient self-shadowed radiosity normal mapping; " + _RNM_SOURCE,
            description="weights sum to 1 where every n·b_i ≥ 0",
        ),
        Method(
            id="rnm-normalized",
            label="RNM, normalised squared weights",
            kernel=_rnm_kernel,
            inputs=(*_NORMAL_T, _RNM_COEFFS),
            fixed={"weighting": "normalized"},
            storage=9,
            quantity="environment_irradiance",
            formula=f"E(n) = Σ_i d_i² E_i / Σ_j d_j², {_RNM_D}",
            source="Source SDK lightmapped shaders; " + _RNM_SOURCE,
            description="a constant environment is exact at every normal of the hemisphere",
        ),
    ]
)
"""The hemispherical (lightmap) bases as data: id → `Method` (module docstring)."""


# =========================================================================================== frames
def surface_frame(normal, tangent=None) -> np.ndarray:
    """The orthonormal surface frame (3, 3), rows (t, b, N), of geometric normal ``normal`` (3,).

    ``tangent``: a direction not parallel to the normal (default: world +X, or +Y when the normal is
    within 1e-3 of ±X); t is its component orthogonal to N, b = N × t (right-handed)."""
    nrm = np.asarray(normal, dtype=np.float64)
    if nrm.shape != (3,) or not np.all(np.isfinite(nrm)) or np.linalg.norm(nrm) <= 0:
        raise ValueError(f"normal must be 3 finite numbers of non-zero length (got {normal!r})")
    nrm = nrm / np.linalg.norm(nrm)
    if tangent is None:
        tangent = (0.0, 1.0, 0.0) if abs(nrm[0]) > 1.0 - 1e-3 else (1.0, 0.0, 0.0)
    t = np.asarray(tangent, dtype=np.float64)
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"tangent must be 3 finite numbers (got {tangent!r})")
    t = t - nrm * float(t @ nrm)
    if np.linalg.norm(t) <= 1e-9:
        raise ValueError("tangent must not be parallel to the normal")
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(nrm, t), nrm])


def to_tangent(frame, directions) -> np.ndarray:
    """World ``directions`` (..., 3) in the tangent frame of ``frame`` (rows t, b, N): (d·t, d·b, d·N)."""
    f = np.asarray(frame, dtype=np.float64)
    if f.shape != (3, 3):
        raise ValueError(f"frame must be (3, 3) rows t, b, N (got shape {f.shape})")
    return np.asarray(directions, dtype=np.float64) @ f.T


# =========================================================================================== H-basis
def hemisphere_quadrature(n_mu: int = 32, n_phi: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """A product rule on the hemisphere n_z ≥ 0: Gauss–Legendre in μ = cos θ ∈ [0, 1] (``n_mu`` nodes) ×
    midpoints in φ (``n_phi``). Returns (unit directions (M, 3) in the tangent frame, weights (M,)
    summing to 2π); exact for polynomials of degree ≤ 2·n_mu − 1 in μ and < n_phi in cos φ, sin φ."""
    n_mu, n_phi = int(n_mu), int(n_phi)
    if n_mu < 1 or n_phi < 1:
        raise ValueError(f"n_mu and n_phi must be >= 1 (got {n_mu}, {n_phi})")
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2.0 * math.pi / n_phi)
    s = np.sqrt(np.maximum(0.0, (1.0 - mu) * (1.0 + mu)))
    d = np.stack(
        [
            s[:, None] * np.cos(phi)[None, :],
            s[:, None] * np.sin(phi)[None, :],
            np.repeat(mu[:, None], n_phi, axis=1),
        ],
        axis=-1,
    )
    wt = wmu[:, None] * np.full(n_phi, 2.0 * math.pi / n_phi)[None, :]
    return d.reshape(-1, 3), wt.reshape(-1)


def hbasis_design_matrix(normals, count: int = 6) -> np.ndarray:
    """(N, count) values H_k(n) at tangent-space ``normals`` (N, 3): column k is the H-basis kernel's
    red channel with c = e_k (the NumPy text of the same kernel)."""
    m = HEMISPHERE_METHODS[_hbasis_id(count)]
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 2:
        raise ValueError(f"normals must have shape (N, 3) (got shape {n.shape})")
    eye = np.eye(count)
    cols = [m(NUMPY_OPS, basis_inputs(m, eye[k], n))[0] for k in range(count)]
    return np.stack(cols, axis=-1)


def hbasis_project(normals, weights, irradiance, count: int = 6, design=None) -> np.ndarray:
    """H-basis coefficients (count, 3): c_k = Σ_j w_j E_j H_k(n_j), the projection of the irradiance
    ``irradiance`` (N, 3) (or (N,)) at tangent-space ``normals`` (N, 3) with quadrature ``weights`` (N,)
    over the hemisphere (e.g. `hemisphere_quadrature`). ``design``: `hbasis_design_matrix` of these
    ``normals`` and ``count``, when the caller projects many texels on one rule (computed here if None)."""
    a = hbasis_design_matrix(normals, count) if design is None else np.asarray(design, np.float64)
    w = np.asarray(weights, dtype=np.float64)
    e = np.asarray(irradiance, dtype=np.float64)
    if e.ndim == 1:
        e = np.repeat(e[:, None], 3, axis=1)
    if w.shape != (len(a),) or e.shape != (len(a), 3):
        raise ValueError(f"weights ({len(a)},) and irradiance ({len(a)}, 3) expected")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(e))):
        raise ValueError("weights and irradiance must be finite")
    return a.T @ (e * w[:, None])


def _hbasis_id(count: int) -> str:
    if count not in (4, 6):
        raise ValueError(f"count must be 4 or 6 (got {count!r})")
    return f"hbasis-{count}"


# =========================================================================================== RNM
def rnm_lightmaps_from(irradiance_at) -> np.ndarray:
    """The three RNM lightmaps (3, 3) (rows E_0..E_2, RGB): ``irradiance_at`` evaluated at the tangent
    basis directions `RNM_BASIS`, e.g. ``lambda d: envs.irradiance_quadrature(env, to_world(d))``.
    ``irradiance_at`` takes (3, 3) tangent-space directions and returns (3, 3) or (3,) irradiance."""
    e = np.asarray(irradiance_at(np.array(RNM_BASIS)), dtype=np.float64)
    if e.ndim == 1:
        e = np.repeat(e[:, None], 3, axis=1)
    if e.shape != (3, 3) or not np.all(np.isfinite(e)):
        raise ValueError(f"irradiance_at must return 3 finite RGB values (got shape {e.shape})")
    return e


# =========================================================================================== public
def hemisphere_irradiance(method: str | Method, coeffs, normal):
    """Irradiance (W/m², RGB) of hemispherical basis ``method`` (an id of `HEMISPHERE_METHODS` or a
    `Method`) with ``coeffs`` (H-basis: (count, 3); RNM: the lightmaps (3, 3); or grey (rows,)) at
    tangent-space ``normal`` (..., 3). Returns (..., 3) for NumPy input, a length-3 array for one normal,
    a tuple (R, G, B) of lazy arrays for Dr.Jit input (see `basis_irradiance`)."""
    if not isinstance(method, Method):
        if method not in HEMISPHERE_METHODS:
            raise ValueError(f"unknown hemisphere basis {method!r}; known: {', '.join(HEMISPHERE_METHODS)}")
        method = HEMISPHERE_METHODS[method]
    return basis_irradiance(method, coeffs, normal)
