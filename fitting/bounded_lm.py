"""Bounded Levenberg–Marquardt for residuals with a user-supplied Jacobian (NumPy).

`fit_least_squares` differentiates its residuals with JAX; some residuals cannot be traced by JAX (the
sdf-occlusion family's come from Dr.Jit kernels, with Jacobian columns from Dr.Jit forward-mode autodiff).
`bounded_lm` minimises ½‖r(x)‖² over a box for any ``fun(x) -> (r, J)``; `bounded_lm_result` turns its
optimum into the same `FitResult` (values, standard errors, correlations, at-bound flags) as every other
fit in rtfit, with the covariance convention of `covariance_from_jacobian`.

Bounds come as `Param` declarations (`rtfit.realtime.methods.Param`: finite lower and upper bounds), so a
method table's parameter bounds are the fit's bounds: `param_bounds`.

Why not SciPy's ``least_squares(method="trf", x_scale="jac", bounds=…, jac=…)`` (issue 37), measured by
``scripts/bench-bounded-lm.py`` (2-core machine under load, 2026-12-05; wall seconds, best of 3) on the
problems this loop solves — the sdf-occlusion Evans fits on the synthetic sphere-on-plane targets of
tests/test_sdf_fit.py (stage 1, `fit_free`: (log B, c_i) on fixed D_i; stage 2, `fit_evans_continuous`:
through the Dr.Jit kernel) and the problems of tests/test_bounded_lm.py:

* the same optimum: ½‖r‖² equal to ≤ 6e-9 relative on every stage-1 and bounded test problem, 1e-7 on the
  noisy kernel fits (exact targets: both at the kernel's float32 floor, ½‖r‖² ≈ 5e-11); parameters equal to
  ≤ 1e-4 except along the flat direction of α = 0, base = ½ voxel (same cost, c_i differ by up to 14);
  `tests/test_bounded_lm.py` asserts both on a bound-active exponential fit against its closed form;
* calls of ``fun``: trf needs fewer on the kernel fit (11–12 against 15–16), about as many on stage 1
  (9–46 against 6–42);
* wall time: slower. Stage 1: 1.0–7.4× (m = 1382: 0.012 s against 0.003 s; m = 8705, the study's 4 scenes ×
  2048 points: 0.089 s against 0.030 s per grid point, 15 grid points per fit). Stage 2 (the kernel fit):
  with NumPy's default threaded BLAS 0.31–0.63 s against 0.04–0.07 s (6–9×: trf takes an SVD of the
  scaled (m + p) × p Jacobian every iteration, ≈ 25 ms each when the BLAS threads contend for 2 cores);
  with OPENBLAS_NUM_THREADS=1, 0.042–0.083 s against 0.039–0.071 s (0.9–1.2×).

So `bounded_lm` stays: the same optima, SciPy's trf no faster anywhere that matters and up to 9× slower
in the default configuration, and rtfit's `FitResult` fields (steps, converged,
message) from its own stopping rules. Rerun the script after changing this loop or SciPy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from rtfit.realtime.methods import Param

from .least_squares import AT_BOUND_RTOL, FitResult, covariance_from_jacobian

__all__ = ["bounded_lm", "bounded_lm_result", "param_bounds"]


def param_bounds(params: Mapping[str, Param], names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) arrays for the parameters ``names`` (in that order) from their `Param` declarations.
    Every bound must be finite (the projected step needs a box)."""
    missing = [n for n in names if n not in params]
    if missing:
        raise ValueError(f"no bounds declared for {', '.join(missing)}")
    lo = np.array([params[n].lower for n in names], dtype=np.float64)
    hi = np.array([params[n].upper for n in names], dtype=np.float64)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("bounded_lm needs finite lower and upper bounds for every parameter")
    return lo, hi


def bounded_lm(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0,
    lower,
    upper,
    *,
    max_iter: int = 100,
    ftol: float = 1e-7,
    xtol: float = 1e-7,
    gtol: float = 1e-8,
) -> dict:
    """Minimise ½‖r(x)‖² subject to lower ≤ x ≤ upper; ``fun(x)`` returns (r (m,), J (m, p)).

    Levenberg–Marquardt with Marquardt's diagonal scaling (A + λ diag A) δ = −Jᵀr, A = JᵀJ, and Nielsen's
    damping update (λ ← λ·max(⅓, 1 − (2ρ − 1)³) on success, λ ← λν, ν ← 2ν on failure), λ₀ = 10⁻³.
    Bounds: a parameter on a bound whose gradient points out of the box is held fixed (active set), the
    others take the step, and the step is projected onto the box. Stops (as MINPACK's lmder) when a
    successful step lowers the SSR by less than ``ftol``·SSR or moves x by less than ``xtol``·(‖x‖ + xtol),
    or when the projected gradient's cosine max_i |g_i|/(‖J_i‖‖r‖) over free parameters is below ``gtol``
    (converged), or at ``max_iter`` / when λ exceeds 1e16 (not converged: piecewise smooth residuals can
    stall the step at a kink).

    Returns a dict: ``x``, ``r``, ``jac`` (at x), ``ssr``, ``iterations``, ``evaluations`` (calls of
    ``fun``), ``converged`` (bool), ``message``. x0 is clipped into the box first."""
    lo, hi = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    x = np.clip(np.asarray(x0, np.float64), lo, hi)
    if not np.all(lo < hi):
        raise ValueError("bounded_lm needs lower < upper for every parameter")
    r, jac = fun(x)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        raise ValueError("bounded_lm: non-finite residuals or Jacobian at the start")
    ssr = float(r @ r)
    a = jac.T @ jac
    lam = 1e-3
    nu = 2.0
    evals, message, converged = 1, "max_iter reached", False
    it = 0
    while it < max_iter:
        it += 1
        g = jac.T @ r
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        col = np.linalg.norm(jac, axis=0)
        rn = math.sqrt(ssr)
        cosg = np.where(free & (col > 0), np.abs(g) / np.maximum(col * rn, 1e-300), 0.0)
        if rn == 0.0 or float(cosg.max()) <= gtol:
            converged, message = True, "projected gradient below gtol"
            break
        af = a[np.ix_(free, free)]
        # floor of the scaling: a zero column (a parameter the data do not see) keeps a solvable system
        dg = np.maximum(np.diag(af), 1e-12 * max(float(np.diag(af).max()), 1e-300))
        try:
            step_f = np.linalg.solve(af + lam * np.diag(dg), -g[free])
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2.0
            continue
        step = np.zeros_like(x)
        step[free] = step_f
        x_new = np.clip(x + step, lo, hi)
        dx = x_new - x
        r_new, j_new = fun(x_new)
        evals += 1
        ssr_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else math.inf
        lin = r + jac @ dx
        pred = ssr - float(lin @ lin)
        if ssr_new < ssr and np.all(np.isfinite(j_new)):
            rho = (ssr - ssr_new) / pred if pred > 0 else 0.0
            small = (ssr - ssr_new) <= ftol * ssr or np.linalg.norm(dx) <= xtol * (np.linalg.norm(x) + xtol)
            x, r, jac, ssr = x_new, r_new, j_new, ssr_new
            a = jac.T @ jac
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small:
                converged, message = True, "relative SSR change below ftol or step below xtol"
                break
        else:
            lam *= nu
            nu *= 2.0
            if lam > 1e16:
                message = "no descent step (damping above 1e16)"
                break
    return {
        "x": x,
        "r": r,
        "jac": jac,
        "ssr": ssr,
        "iterations": it,
        "evaluations": evals,
        "converged": converged,
        "message": message,
    }


def bounded_lm_result(names: Sequence[str], out: dict, lower, upper) -> tuple[FitResult, np.ndarray]:
    """The `FitResult` of a `bounded_lm` optimum ``out`` over parameters ``names`` with bounds
    (``lower``, ``upper``), and its covariance matrix (p, p).

    Covariance cov = s²(JᵀJ)⁺ at the optimum with s² = SSR/(m − p) (`covariance_from_jacobian`, the
    convention of every rtfit fit); standard errors √diag(cov), correlations cov_ij/(se_i se_j) (NaN where a
    standard error is 0); a parameter is at a bound when within ``AT_BOUND_RTOL`` of the bound's range."""
    x, r, jac = out["x"], out["r"], out["jac"]
    lo, hi = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    names = list(names)
    m, p = len(r), len(x)
    if len(names) != p:
        raise ValueError(f"{len(names)} names for {p} parameters")
    cov, rank = covariance_from_jacobian(jac, out["ssr"], m - p)
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(np.diag(cov))
        corr = cov / np.outer(se, se)
    tol = AT_BOUND_RTOL * (hi - lo)
    fr = FitResult(
        values={nm: float(x[i]) for i, nm in enumerate(names)},
        stderr={nm: float(se[i]) for i, nm in enumerate(names)},
        correlation=[[float(v) for v in row] for row in corr],
        param_names=tuple(names),
        rms_residual=math.sqrt(out["ssr"] / m),
        ssr=out["ssr"],
        n_residuals=m,
        dof=m - p,
        steps=out["iterations"],
        converged=out["converged"],
        message=out["message"],
        at_bound={nm: bool(x[i] - lo[i] <= tol[i] or hi[i] - x[i] <= tol[i]) for i, nm in enumerate(names)},
        lower={nm: float(lo[i]) for i, nm in enumerate(names)},
        upper={nm: float(hi[i]) for i, nm in enumerate(names)},
        jacobian_rank=rank,
    )
    return fr, cov
