"""rtfit.fitting: error metrics with Monte Carlo noise floors, z-statistics, and bounded least squares.

* :mod:`.metrics`: `compute_metrics` (RMSE, relative MSE, MAE, max, PSNR, SSIM, FLIP, sMAPE), each beside
  the reference's noise floor; `z_scores`, `z_score_summary`.
* :mod:`.stats`: robust z-spread, the z-test checks every experiment runs (tolerances derived there),
  Šidák thresholds.
* :mod:`.least_squares`: `fit_least_squares` / `fit_curve` (optimistix Levenberg–Marquardt, bounds by
  reparametrisation, standard errors), `covariance_from_jacobian`.
* :mod:`.method_fit`: `fit_method`: fit a `rtfit.realtime.methods.Method`'s parameters through the JAX
  run of its one kernel text (``solver="trf"``: the NumPy run, SciPy TRF, stopped at a noise-derived
  tolerance, `method_fit.noise_ftol`).
* :mod:`.blas_threads`: `one_blas_thread`, one OpenBLAS thread while a TRF fit runs (and through a whole
  ``rtfit`` command: `one_blas_thread_by_default`).
* :mod:`.forked_fits`: `shared_map`, a list of fits shared between the process and one forked helper on two
  cores, the results those of a serial run bit for bit.
* :mod:`.difference_maps`: how a TRF fit's Jacobian points are evaluated (threads, grouped parameters, or
  several points in one kernel call), the same Jacobian bit for bit.
* :mod:`.bounded_lm`: `bounded_lm`, a projected Levenberg–Marquardt for residuals with a user-supplied
  Jacobian (NumPy; residuals JAX cannot trace), `bounded_lm_result` (its `FitResult`), `param_bounds`.

Importing this package does not import JAX (only the fits do). Fits run on the CPU unless
``JAX_PLATFORMS`` says otherwise (they are small, and JAX would otherwise preallocate most of the GPU's
memory beside Dr.Jit)."""

import os as _os

_os.environ.setdefault("JAX_PLATFORMS", "cpu")
_os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

from .bounded_lm import bounded_lm, bounded_lm_result, param_bounds
from .least_squares import (
    AT_BOUND_RTOL,
    FitResult,
    Param,
    covariance_from_jacobian,
    fit_curve,
    fit_least_squares,
)
from .method_fit import concatenated, fit_method, method_model, zero_padded
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
    flip_error_map,
    grey_metrics,
    prime_flip,
    smape,
    tone_map,
    z_score_summary,
    z_scores,
)
from .stats import (
    MAD_TO_SIGMA,
    concat_z_pairs,
    robust_spread,
    sidak_threshold,
    z_checks,
    z_pair,
)

__all__ = [
    "ALL_METRICS",
    "AT_BOUND_RTOL",
    "EXTRA_METRICS",
    "FLIP_MIN_SIZE",
    "MAD_TO_SIGMA",
    "REL_MSE_EPS",
    "SSIM_MIN_SIZE",
    "FitResult",
    "MetricResults",
    "MetricValue",
    "Param",
    "ZScoreSummary",
    "bounded_lm",
    "bounded_lm_result",
    "compute_metrics",
    "concat_z_pairs",
    "concatenated",
    "covariance_from_jacobian",
    "fit_curve",
    "fit_least_squares",
    "fit_method",
    "flip_error_map",
    "grey_metrics",
    "method_model",
    "param_bounds",
    "prime_flip",
    "robust_spread",
    "sidak_threshold",
    "smape",
    "tone_map",
    "z_checks",
    "z_pair",
    "z_score_summary",
    "z_scores",
    "zero_padded",
]
