"""Ambient Dice (Iwanicki & Sloan 2017), the spherical-RBF variant: 12 irradiance values on an icosahedron.

Iwanicki & Sloan, "Ambient Dice", Eurographics Symposium on Rendering 2017 (Experimental Ideas &
Implementations), DOI 10.2312/sre.20171191. The paper stores values at the 12 vertices v_i of an
icosahedron and gives three reconstructions; this module implements the third one, which the abstract
describes as exploiting "the partition of unity formed by cos² and cos⁴ restricted to a hemisphere oriented
along the directions of the icosahedron vertices" (18 coefficients read per evaluation: the 6 vertices in
the hemisphere of n, RGB). With c_i = max(v_i·n, 0) the reconstruction is

    E(n) = Σ_{i=1..12} B_i(n) E_i,     B_i(n) = α·½c_i² + (1 − α)·(5/6)c_i⁴,   α = 0.7.

Partition of unity (why the ½ and 5/6): the icosahedron's 12 vertices are 6 antipodal pairs and a spherical
5-design, so Σ_i (v_i·n)² = 12/3 = 4 and Σ_i (v_i·n)⁴ = 12/5 for every unit n; each pair contributes to
exactly one of its two half-spaces, hence Σ_i c_i² = 2 and Σ_i c_i⁴ = 6/5, and Σ_i B_i(n) = α + (1 − α) = 1
(tested to 1e-15). A constant irradiance is therefore reproduced exactly by E_i = E.

Where the text of the paper was not available to us (only its abstract and figure captions were found),
the weights α = 0.7 on ½c² and 0.3 on (5/6)c⁴ and the vertex set are those of the Ambient Dice
implementation in T. Roughton's Probulator fork (``ExperimentAmbientDice.cpp``, ``srbfWeights``; Roughton
co-developed the basis's follow-up, "Spherical Radial Basis Functions for Lighting", 2019). The paper's
equation numbers could not be checked; docs/irradiance-bases.md says so.

The values E_i store **irradiance** (W/m²), not radiance: as in Probulator's Ambient Dice experiments the
basis is fitted to the irradiance over the sphere of normals by least squares (`fit_ambient_dice`:
min Σ_k w_k (E(n_k) − E_k)², a uniform sphere sampling approximating the sphere integral), 36 floats per
probe.

Vertices (unnormalised, as listed by Probulator): (±1, ±τ, 0), (0, ±1, ±τ), (±τ, 0, ±1) with τ = 1/φ =
0.618…, normalised here (`DICE_VERTICES`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .arrays import NUMPY_OPS
from .irradiance_bases import unit_normal
from .methods import Input, Method, method_table

__all__ = ["DICE_ALPHA", "DICE_METHODS", "DICE_VERTICES", "dice_design_matrix", "fit_ambient_dice"]

DICE_ALPHA = 0.7
_TAU = (math.sqrt(5.0) - 1.0) / 2.0  # 1/φ


def _vertices() -> tuple[tuple[float, float, float], ...]:
    t = _TAU
    raw = [
        (1.0, t, 0.0), (-1.0, t, 0.0), (1.0, -t, 0.0), (-1.0, -t, 0.0),
        (0.0, 1.0, t), (0.0, -1.0, t), (0.0, 1.0, -t), (0.0, -1.0, -t),
        (t, 0.0, 1.0), (-t, 0.0, 1.0), (t, 0.0, -1.0), (-t, 0.0, -1.0),
    ]  # fmt: skip
    s = 1.0 / math.sqrt(1.0 + t * t)
    return tuple((x * s, y * s, z * s) for x, y, z in raw)


DICE_VERTICES = _vertices()
"""The 12 unit icosahedron vertices, in Probulator's order."""


def _dice_kernel(ops, nx, ny, nz, coeffs, vertices=DICE_VERTICES, alpha=DICE_ALPHA):
    """E(n) = Σ_i (α·½c_i² + (1 − α)(5/6)c_i⁴) E_i, c_i = max(v_i·n, 0); ``coeffs`` 36 floats: the vertex
    irradiance values E_i (W/m²) in `DICE_VERTICES` order, channel-major (R, G, B). A zero-length normal
    returns the mean of the 12 values (the sphere average of the reconstruction)."""
    x, y, z, valid = unit_normal(ops, nx, ny, nz)
    count = len(vertices)
    weights = []
    for vx, vy, vz in vertices:
        c = ops.maximum(vx * x + vy * y + vz * z, 0.0)
        c2 = c * c
        weights.append(c2 * ((0.5 * alpha) + ((5.0 / 6.0) * (1.0 - alpha)) * c2))
    out = []
    for ch in range(3):
        e = coeffs[ch * count : (ch + 1) * count]
        acc = weights[0] * e[0]
        total = e[0] + 0.0
        for i in range(1, count):
            acc = acc + weights[i] * e[i]
            total = total + e[i]
        out.append(ops.select(valid, acc, total * (1.0 / count)))
    return tuple(out)


DICE_METHODS: Mapping[str, Method] = method_table(
    [
        Method(
            id="ambient-dice",
            label="Ambient Dice (12, SRBF)",
            kernel=_dice_kernel,
            inputs=(
                Input("nx", "1", "normal x (world frame, +Z up; normalised by the kernel)"),
                Input("ny", "1", "normal y"),
                Input("nz", "1", "normal z"),
                Input(
                    "coeffs", "W/m²", "36 floats: irradiance at the 12 icosahedron vertices, channel-major"
                ),
            ),
            storage=36,
            quantity="environment_irradiance",
            formula="E(n) = Σ_i (0.7·½c_i² + 0.3·(5/6)c_i⁴) E_i, c_i = max(v_i·n, 0), "
            "12 icosahedron vertices",
            source="Iwanicki & Sloan 2017, Ambient Dice (EGSR EI&I), RBF variant; weights as in Probulator",
            description="least-squares irradiance values at the 12 vertices; exact for a constant "
            "environment",
        )
    ]
)
"""The Ambient Dice basis as data."""


def dice_design_matrix(normals) -> np.ndarray:
    """(N, 12) weights B_i(n) at unit ``normals`` (N, 3): column i is the kernel's red channel with E = e_i
    (the NumPy text of the same kernel)."""
    n = np.asarray(normals, np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals must have shape (N, 3) (got shape {n.shape})")
    m = DICE_METHODS["ambient-dice"]
    eye = np.eye(36)
    cols = [
        m(NUMPY_OPS, {"nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2], "coeffs": tuple(eye[j])})[0]
        for j in range(12)
    ]
    return np.stack(cols, axis=-1)


def fit_ambient_dice(normals, irradiance, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares vertex values (12, 3) minimising Σ_k w_k (E_dice(n_k) − E_k)² over ``normals`` (N, 3),
    ``irradiance`` (N, 3) or (N,) (default uniform weights: with `fibonacci_sphere` normals this is the
    sphere-integrated squared error). Returns (values (12, 3), rms residual per channel (3,))."""
    a = dice_design_matrix(normals)
    e = np.asarray(irradiance, np.float64)
    if e.ndim == 1:
        e = np.repeat(e[:, None], 3, axis=1)
    if e.shape != (len(a), 3) or not np.all(np.isfinite(e)):
        raise ValueError(f"irradiance must be finite with shape ({len(a)}, 3) (got {np.shape(irradiance)})")
    w = np.ones(len(a)) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (len(a),) or np.any(~np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite, >= 0, one per normal")
    sw = np.sqrt(w)
    values, *_ = np.linalg.lstsq(a * sw[:, None], e * sw[:, None], rcond=None)
    rms = np.sqrt(np.sum(w[:, None] * (a @ values - e) ** 2, axis=0) / max(w.sum(), 1e-30))
    return values, rms
