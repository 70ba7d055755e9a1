"""The pieces of single scattering from a light in a medium that several modules share: the fits' residual
scale and closed-form level fit (`fit_level`: the volumetric-lightning study's fixed-core models) and the
point light's fit parameters (`fit_params`: start and bounds of the stable form's (i, a) from a case's
physics), which the volumetric-lightning audit reads. (The reference render jobs and reference checks of the
light-cones experiment before the engine went with it: the engine's audit renders and z-checks now.)
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime.volumetric_lightning import METHODS
from rtfit.reference.single_scattering import FOUR_PI

__all__ = ["FIT_METHOD", "FIT_RANGE", "fit_level", "fit_params", "residual_scale"]


def fit_level(model: np.ndarray, ref: np.ndarray) -> float:
    """The level i (closed-form weighted least squares, weights of `fit_data`) of a model F/i = ``model``."""
    w = 1.0 / residual_scale(ref)
    return float(np.sum(w * w * model * ref) / np.sum(w * w * model * model))


def residual_scale(ref: np.ndarray) -> np.ndarray:
    """The fits' residual scale: 2 % of the reference plus 1 % of its mean (relative error, not dominated by
    the pixels next to the light)."""
    return 0.02 * np.abs(ref) + 0.01 * float(np.mean(np.abs(ref)))


# --------------------------------------------------------------------------- the point light's fit
FIT_METHOD = "stable"
"""The method whose (i, a) are fitted per case."""

FIT_RANGE = {"i": (1e-4, 1e4), "a": (1e-3, 1e2)}
"""Fits start at a₀ = 100/D² (core radius D/10) and i₀ = a₀·σ_s·I/(4π) (the far field of the true light),
bounded to these factors of the start: the core radius 1/√a stays within [D/100, 3.2·D]. The physics, a
point light, would take a → ∞; a core below D/100 changes only the few pixels whose rays pass that close
(none in the quick configuration, whose closest ray passes at 0.026·D)."""


def fit_params(case: dict) -> dict[str, Param]:
    a0 = 100.0 / case["distance"] ** 2
    start = {"a": a0, "i": a0 * case["sigma_s"] * case["intensity"] / FOUR_PI}
    spec = METHODS[FIT_METHOD].params
    return {
        k: dataclasses.replace(spec[k], initial=x, lower=x * FIT_RANGE[k][0], upper=x * FIT_RANGE[k][1])
        for k, x in start.items()
    }
