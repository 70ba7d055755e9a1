"""rtfit.fitting: error metrics with Monte Carlo noise floors, z-scores, and bounded least squares.

Importing this package does not import JAX (only :func:`fit_least_squares` / :func:`fit_curve` do).
Fits run on the CPU unless ``JAX_PLATFORMS`` says otherwise (they are small, and JAX would otherwise
preallocate most of the GPU's memory beside Dr.Jit)."""

import os as _os

_os.environ.setdefault("JAX_PLATFORMS", "cpu")
_os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

from .least_squares import (
    AT_BOUND_RTOL,
    FitResult,
    Param,
    covariance_from_jacobian,
    fit_curve,
    fit_least_squares,
)
from .metrics import (
    ALL_METRICS,
    EXTRA_METRICS,
    FLIP_MIN_SIZE,
    REL_MSE_EPS,
    SSIM_MIN_SIZE,
    MetricResults,
    MetricValue,
    ZScoreSummary,
    compute_metrics,
    smape,
    tone_map,
    z_score_summary,
    z_scores,
)

__all__ = [
    "ALL_METRICS",
    "AT_BOUND_RTOL",
    "EXTRA_METRICS",
    "FLIP_MIN_SIZE",
    "REL_MSE_EPS",
    "SSIM_MIN_SIZE",
    "FitResult",
    "MetricResults",
    "MetricValue",
    "Param",
    "ZScoreSummary",
    "compute_metrics",
    "covariance_from_jacobian",
    "fit_curve",
    "fit_least_squares",
    "smape",
    "tone_map",
    "z_score_summary",
    "z_scores",
]
