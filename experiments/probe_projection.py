"""How an irradiance-volume probe is projected and turned into the basis coefficients an engine stores:
shared by the irradiance-volumes experiment and its audit (neither imports the other).

A probe's radiance L(ω) is projected on the features f_k(ω) (`probe_features`): the 9 real SH basis functions
(∫ L f_k dω is SH L2 coefficient k) and the clamped cosines max(n_k·ω, 0) at `FEATURE_NORMALS` (∫ L f_k dω is
the irradiance at normal n_k, W/m²): the six cube axes (Valve's ambient cube samples) and `NNLS_NORMALS`
Fibonacci normals for the NNLS cube fit. `probe_bases` turns the projections into each stored basis.
"""

from __future__ import annotations

import numpy as np

from rtfit.realtime.irradiance_bases import CUBE_AXES, fibonacci_sphere, fit_ambient_cubes_nnls, sh9_basis

__all__ = ["FEATURES_NAME", "FEATURE_NORMALS", "NNLS_NORMALS", "probe_bases", "probe_features"]

NNLS_NORMALS = 64
"""Fibonacci normals at which each probe's irradiance is estimated for the NNLS cube fit."""
FEATURE_NORMALS = np.concatenate([np.asarray(CUBE_AXES), fibonacci_sphere(NNLS_NORMALS)])
"""The normals whose clamped cosines the probes are projected on: the six cube axes (Valve's samples, in
`CUBE_ORDER`), then the NNLS fit's Fibonacci normals."""
FEATURES_NAME = f"sh9+clampedcos(axes6+fib{NNLS_NORMALS})"


def probe_features(directions: np.ndarray) -> np.ndarray:
    """f_k(ω) of the probe projections (M, 9 + 6 + `NNLS_NORMALS`): the 9 SH basis values, then
    max(n_k·ω, 0) at `FEATURE_NORMALS` (∫ L f_k dω is then SH coefficient k, or the irradiance at n_k)."""
    d = np.asarray(directions, dtype=np.float64)
    return np.concatenate([sh9_basis(d), np.maximum(d @ FEATURE_NORMALS.T, 0.0)], axis=1)


def probe_bases(mean: np.ndarray, extra_irradiance: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-probe coefficients of every `VOLUME_BASES` entry from the projections ``mean`` (P, K, 3):
    SH L2 (P, 9, 3), Valve's cube (the axis irradiance, P, 6, 3), and the NNLS cube fitted to the irradiance
    at the Fibonacci normals (plus ``extra_irradiance`` (P, NNLS_NORMALS, 3) there, for a folded light)."""
    sh = mean[:, :9]
    valve = mean[:, 9:15]
    target = mean[:, 15:] + (0.0 if extra_irradiance is None else extra_irradiance)
    normals = FEATURE_NORMALS[6:]
    nnls = fit_ambient_cubes_nnls(normals, target)
    return {"cube-valve": valve, "cube-nnls": nnls, "sh-l2": sh}
