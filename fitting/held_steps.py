"""Scanned parameters that are steps where the scan left them: held there while the solver fits the others.

A parameter declared with a scan (`rtfit.realtime.methods.Param.scan`) may be a step function of the
residuals: a depth compare's bias changes a pixel only where it crosses one of the compared depth
differences, and between those steps the residuals do not change with it at all. The fit scans its bounds
and starts the solver at the best value (`rtfit.fitting.method_fit._scanned_starts`); a central difference
there (SciPy's 3-point rule, ±ε^{1/3}·max(1, |p|)) that gives the same residuals bit for bit at every
element says that the solver's Jacobian has a zero column for it, along which TRF never steps: it stays at
the scan's best, and its stderr is undefined.

`flat_scanned` finds such parameters with two evaluations each at the start; the fit then holds them at
their scanned values and fits the others (`rtfit.fitting.method_fit._fit_trf` with ``spent``: the held
ones still count in the degrees of freedom, n − k for all k parameters, as before), and `with_held` puts
them back into the result in declaration order: their value the scan's, their stderr and correlations NaN,
their bound flags as any parameter's, and the message that says so. The solver's path in the others is
the one it took with the zero column (which added nothing to a step), so the fitted values are those of
the fit that carried it.

Issue 33 (session 33): each Jacobian of a shadow-map row (radius or light scale, and the bias) spent half
its evaluations on the bias's zero column: the Cornell box's ten shadow-map fits made 616 evaluations.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.methods import Method, Param

from .difference_maps import weighted_residuals
from .least_squares import FitResult, bound_flags

__all__ = ["all_held", "flat_scanned", "step_message", "with_held"]

_EPS_CBRT = float(np.finfo(np.float64).eps) ** (1.0 / 3.0)


def step_message(name: str, param: Param) -> str:
    """The result's words for a scanned parameter that is a step at its value."""
    return f"{name}: a step (zero derivative), the best of a {param.scan}-value scan"


def _difference_points(p: Param, value: float) -> tuple[float, float]:
    """The two points of SciPy's 3-point difference of ``p`` at ``value`` (in p, or in log p for a
    `Param.log` parameter, as the solver steps it): ±h, h = ε^{1/3}·max(1, |x|) (``fd_step``: h = that·|x|),
    taken one-sided (+h, +2h or −h, −2h) where a side crosses a bound."""
    if p.log:
        x, lo, hi = math.log(value) if value > 0 else -math.inf, math.log(p.lower), math.log(p.upper)
    else:
        x, lo, hi = value, p.lower, p.upper
    if not math.isfinite(x):
        return value, value
    h = (p.fd_step or _EPS_CBRT) * (abs(x) if p.fd_step else max(1.0, abs(x)))
    a, b = x - h, x + h
    if a < lo:
        a, b = x + h, x + 2.0 * h
    elif b > hi:
        a, b = x - h, x - 2.0 * h
    return (math.exp(a), math.exp(b)) if p.log else (a, b)


def flat_scanned(
    method: Method,
    params: Mapping[str, Param],
    inputs: Mapping[str, Any],
    held: Mapping[str, float],
    target: np.ndarray,
    weights: np.ndarray,
    output: Callable[[Any], Any] | None,
    run: Callable[[Mapping[str, float]], Any] | None = None,
) -> tuple[list[str], np.ndarray | None]:
    """(the scanned parameters of ``params`` (`Param.scan`; their ``initial`` the scan's best) whose 3-point
    difference at the start leaves every weighted residual the same bit for bit (module text), the weighted
    residuals at the start). ``run``: the fit's Dr.Jit run (None: the NumPy run of the kernel text)."""
    scanned = [k for k, p in params.items() if p.scan]
    if not scanned:
        return [], None
    start = {**held, **{k: p.initial for k, p in params.items()}}

    def residuals(values: Mapping[str, float]) -> np.ndarray:
        with np.errstate(all="ignore"):
            pred = method(NUMPY_OPS, inputs, values) if run is None else run(values)
            pred = output(pred) if output is not None else pred
            return weighted_residuals(pred, weights, target)

    r0 = residuals(start)
    flat = []
    for k in scanned:
        points = [v for v in _difference_points(params[k], params[k].initial) if v != params[k].initial]
        if points and all(np.array_equal(residuals({**start, k: v}), r0) for v in points):
            flat.append(k)
    return flat, r0


def all_held(r0: np.ndarray, params: Mapping[str, Param]) -> FitResult:
    """The result of a fit with nothing left to fit (every parameter a held step, `flat_scanned`): the
    residuals ``r0`` at the scanned values, no step taken; `with_held` fills in the parameters."""
    ssr = float(r0 @ r0)
    return FitResult(
        values={}, stderr={}, correlation=[], param_names=(), rms_residual=math.sqrt(ssr / max(r0.size, 1)),
        ssr=ssr, n_residuals=int(r0.size), dof=int(r0.size - len(params)), steps=1, converged=True,
        message="", at_bound={}, lower={}, upper={}, jacobian_rank=0,
    )  # fmt: skip


def with_held(result: FitResult, params: Mapping[str, Param], held: Mapping[str, float]) -> FitResult:
    """``result`` (the fit of the parameters not in ``held``) with the ``held`` steps put back, every
    parameter of ``params`` in its declared order: a held value its scan's, stderr and correlations NaN,
    its bound flags as any value's, and `step_message` added to the message."""
    names = tuple(params)
    x = [held[n] if n in held else result.values[n] for n in names]
    at_lower, at_upper = bound_flags(names, [params[n] for n in names], x)
    index = {n: i for i, n in enumerate(result.param_names)}
    corr = [
        [result.correlation[index[a]][index[b]] if a in index and b in index else math.nan for b in names]
        for a in names
    ]
    words = [step_message(n, params[n]) for n in names if n in held]
    fitted_words = [w for w in result.message.split("; ") if w] if result.message else []
    return FitResult(
        values={n: float(v) for n, v in zip(names, x, strict=True)},
        stderr={n: math.nan if n in held else result.stderr[n] for n in names},
        correlation=corr,
        param_names=names,
        rms_residual=result.rms_residual,
        ssr=result.ssr,
        n_residuals=result.n_residuals,
        dof=result.dof,
        steps=result.steps,
        converged=result.converged,
        message="; ".join([*fitted_words, *words]),
        at_bound={n: at_lower[n] or at_upper[n] for n in names},
        lower={n: params[n].lower for n in names},
        upper={n: params[n].upper for n in names},
        jacobian_rank=result.jacobian_rank,
    )
