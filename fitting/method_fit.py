"""Fit a method's free parameters through its one kernel text (the JAX run of `rtfit.realtime` kernels).

``fit_method(method, inputs, target)`` minimises Σ wᵢ²·(f(xᵢ; p) − yᵢ)² over the method's free
parameters p, where f is ``method.kernel`` evaluated with the JAX ops namespace
(`rtfit.realtime.arrays.JAX_OPS`): the formula the shader runs, the NumPy benchmark times and the Dr.Jit
comparison evaluates is the formula that is differentiated here. No residual is written by hand.

Bounds, the optimiser (optimistix Levenberg–Marquardt in float64) and the uncertainties are those of
:func:`rtfit.fitting.fit_least_squares`. The jitted solve is compiled once per (method, set of fitted
parameter names, set of held parameter names, input names, output transform) and reused for every case:
inputs, targets, weights, start values, bounds and held values are traced arguments.

``solver="trf"`` fits the same kernel text through its NumPy run instead (`rtfit.realtime.arrays.NUMPY_OPS`,
float64) with SciPy's trust-region-reflective least squares (`scipy.optimize.least_squares`, bounds
handled by the method itself, no change of variables) and a central-difference Jacobian (step
ε^(1/3)·max(1, |p|), relative error ≈ 1e-10 on smooth residuals; SciPy steps one-sided at a bound). It
compiles nothing, so a fit costs a few dozen evaluations of the kernel (milliseconds on thousands of
pixels) instead of a JAX trace and an XLA compile per method and input shape (0.5–3 s each on 2 CPU
cores): what `rtfit audit` uses, where every scene gives new shapes. The standard errors come from the
same covariance rule (`covariance_from_jacobian`) on the Jacobian at the solution. It stops when the SSR
change is far below the noise (`noise_ftol`: within 1e-2 of each value's stderr of the optimum) and runs
with one BLAS thread (`blas_threads.one_blas_thread`: TRF's small matrix products on threaded OpenBLAS cost
more CPU than the kernel evaluations). Parameters declared to change disjoint residuals (``param_rows``: a
per-channel parameter of a per-channel fit) share the Jacobian's evaluations (`grouped_differences`), with
the same Jacobian bit for bit.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS, jax_ops
from rtfit.realtime.methods import Method, Param

from .blas_threads import one_blas_thread
from .difference_maps import (
    batched_points,
    difference_map,
    grouped_differences,
    point_batch,
    run_point_batch,
    weighted_residuals,
)
from .drjit_run import DrJitRun, same_prediction
from .held_steps import all_held, flat_scanned, step_message, with_held
from .least_squares import (
    FitResult,
    bound_flags,
    covariance_from_jacobian,
    fit_least_squares,
    near_bounds,
    normalised_svd,
)

__all__ = [
    "CHECK_KAPPA",
    "FD_RCOND",
    "NOISE_KAPPA",
    "concatenated",
    "fit_method",
    "fit_run",
    "gauss_newton_gain_small",
    "method_model",
    "noise_ftol",
    "residual_variance",
    "zero_padded",
]

TRF_TOL_FACTOR = 1e-3
"""SciPy's TRF stops on *relative* changes of the cost, the step and the scaled gradient; at the LM fits'
1e-10 it stopped 1.4e-7 short in the wrap exponent (1e-4 of its stderr) where LM came within 2e-10, so its
tolerances are those × 1e-3 (a few more iterations, milliseconds). Its ``xtol`` and ``gtol`` still are; its
``ftol`` is the larger of that and the noise-derived `noise_ftol` (κ = 1e-2 of a stderr: the wrap
exponent's shift is 2e-5 stderr)."""

NOISE_KAPPA = 1e-2
"""How far (in its own standard error) a ``"trf"`` fit may stop short of the optimum: `noise_ftol`."""

CHECK_KAPPA = 1e-1
"""The bound verified at the stop (`gauss_newton_gain_small`): each value within a tenth of its stderr of the
linearised optimum, or the fit goes on at the fixed tolerance. Looser than ``NOISE_KAPPA`` because the
check's gain is the full Gauss–Newton step's, which ftol's stop leaves of the same order as κ² s²: at κ it
restarted fits of the Cornell audit that had stopped within 7e-4 stderr (power, evans-listing,
poisson16-rotated, seed-sdf-bias: 2–6 evaluations more each)."""


def noise_ftol(dof: int, ssr_start: float, absolute_sigma: bool = False) -> float:
    """SciPy TRF's ``ftol`` (the relative cost reduction of an accepted step below which it stops) that keeps
    every fitted value within ``NOISE_KAPPA`` of its standard error of the optimum.

    Near the optimum θ* the SSR is SSR* + δᵀAδ (δ = θ − θ*, A = JᵀJ) and the standard error of θᵢ is
    seᵢ = s·√(A⁻¹)ᵢᵢ, so |δᵢ| ≤ √(δᵀAδ)·√(A⁻¹)ᵢᵢ = seᵢ·√(ΔSSR / s²) (Cauchy–Schwarz), ΔSSR the SSR still
    to gain. TRF stops when a step lowered the cost ½·SSR by less than ftol·½·SSR; while it converges at
    least as fast as halving, the SSR still to gain is below that step's, so ΔSSR < ftol·SSR and
    |δᵢ|/seᵢ < √(ftol·SSR/s²). With s² = SSR/dof (the fits' covariance rule) that is √(ftol·dof):
    ftol = κ²/dof. With ``absolute_sigma`` (s² = 1) it is κ²/SSR, taken at the start (≥ SSR*: tighter).
    Measured on the Cornell-box audit's 29 fits (64² × 32 spp): the largest shift 7e-4 stderr against
    the former fixed 1e-13, the same Jacobian ranks, 0–58 % fewer evaluations (`audit_fit.FIT_SOLVER`)."""
    if absolute_sigma:
        return NOISE_KAPPA**2 / ssr_start if ssr_start > 0 else 0.0
    return NOISE_KAPPA**2 / max(dof, 1)


def residual_variance(ssr: float, dof: int, absolute_sigma: bool = False) -> float:
    """s², the residuals' variance the fits' stderr scale with (the covariance rule): SSR/dof, or 1 with
    ``absolute_sigma`` (the weights are 1/σ)."""
    return 1.0 if absolute_sigma else ssr / max(dof, 1)


def gauss_newton_gain_small(jac, r, dof: int, absolute_sigma: bool = False, free=None) -> bool:
    """Whether the full Gauss–Newton step from the point (residuals ``r``, Jacobian ``jac``) would lower
    the SSR by at most κ²·s² (``CHECK_KAPPA``; s² = SSR/dof, or 1 with ``absolute_sigma``): that gain is
    ‖P r‖², P the projection on J's column space (directions below ``FD_RCOND`` of the column-normalised
    J's largest singular value left out, as the covariance does), and |δᵢ|/seᵢ ≤ √(‖P r‖²/s²) bounds how
    far each value lies from the linearised optimum in its stderr. The check of `noise_ftol`'s premise:
    TRF stopped by ftol after a step that gained little, but in a flat valley many such steps remain.
    ``free``: the columns the step may move (`held_at_bounds`' complement; None: all): a value a bound
    holds has no gain to give, however large the unbounded step's."""
    jac = np.asarray(jac, np.float64)
    r = np.asarray(r, np.float64)
    if not (np.all(np.isfinite(jac)) and np.all(np.isfinite(r))):
        return False
    if free is not None:
        jac = jac.reshape(r.size, -1)[:, np.asarray(free, bool)]
        if jac.shape[1] == 0:
            return True
    ssr = float(r @ r)
    s2 = residual_variance(ssr, dof, absolute_sigma)
    u, _, _, keep, _, live = normalised_svd(jac, FD_RCOND)  # J's column space, as the covariance takes it
    if not np.any(live) or ssr == 0.0:
        return True
    gain = float(np.sum((u[:, keep].T @ r) ** 2))
    return gain <= CHECK_KAPPA**2 * s2


def held_at_bounds(x, lo, hi, jac, r) -> np.ndarray:
    """Which values of the point ``x`` (the solver's variables, bounds ``lo``, ``hi``) a bound holds: at it
    (`near_bounds`, `bound_flags`' rule) with the cost's descent −Jᵀr pointing out through it. A
    Gauss–Newton step along them would leave the box, so its gain is not there to take.

    Issue 33 (session 23): the check after TRF's ftol stop counted that gain, so fits with values at their
    bounds (the ambient-aperture intersection's coefficients at ±4, seed-sdf-bias) always went on at the
    fixed tolerance, and the polish on every pixel ran a second solve that moved nothing: 2.2 of the 9 s of
    two families' fits at 256²."""
    g = np.asarray(jac, np.float64).reshape(np.size(r), -1).T @ np.asarray(r, np.float64)
    at_lo, at_hi = near_bounds(x, lo, hi)
    return (at_lo & (g >= 0.0)) | (at_hi & (g <= 0.0))


FD_RCOND = 1e-8
"""Rank tolerance of the ``"trf"`` fits' central-difference Jacobian: its entries carry a relative error of
about ε^(2/3) ≈ 4e-11 (truncation h² with h = ε^(1/3), plus rounding ε/h), so singular values of the
column-normalised Jacobian below ~1e-9 of the largest are that error, not information; 1e-8 leaves a
decade of margin. A direction below it is reported as not determined (stderr NaN), as the exact-Jacobian
fits report a rank-deficient one."""

_RESIDUALS: dict[tuple, Callable] = {}
_KEEP_ALIVE: dict[int, Method] = {}
MEMOS = (_RESIDUALS, _KEEP_ALIVE)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def zero_padded(a, size: int) -> np.ndarray:
    """``a`` (float64) with its last axis zero-padded to ``size`` elements: fits of one fixed size (with zero
    weights on the padding) compile once."""
    a = np.asarray(a, dtype=np.float64)
    out = np.zeros((*a.shape[:-1], size))
    out[..., : a.shape[-1]] = a
    return out


def concatenated(parts):
    """A kernel's tuple of arrays as one vector ``[parts[0]…, parts[1]…, …]``: the ``output`` transform
    (module-level, JAX-traceable) for a fit of a method that returns several quantities at once (issue
    32: the experiments each imported ``jax.numpy`` for it; it lives here, once). NumPy parts (the NumPy run
    of a ``solver="trf"`` fit) stay in NumPy: no JAX import."""
    if all(isinstance(p, np.ndarray | np.generic | float | int) for p in parts):
        return np.concatenate([np.ravel(p) for p in parts])
    import jax.numpy as jnp  # jax: heavy, only a JAX fit needs it

    return jnp.concatenate(parts)


def method_model(method: Method, output: Callable[[Any], Any] | None = None) -> Callable:
    """``model(params, inputs) -> prediction``: the method's kernel on JAX ops with ``params`` (a dict of
    parameter values) and the method's fixed keywords; ``output`` (optional, JAX-traceable) maps the
    kernel's result (e.g. picks one of a tuple, or scales it) to the fitted quantity."""
    fixed = dict(method.fixed)

    def model(params, inputs):
        out = method.kernel(jax_ops(), **inputs, **params, **fixed)
        return out if output is None else output(out)

    return model


def _is_sampler(v: Any) -> bool:
    """An input the kernel reads through its own methods (a distance field: ``sdf.sample(ops, …)``), not an
    array: it is closed over by the residual (static to JAX), not traced."""
    return callable(getattr(v, "sample", None))


def _residual(
    method: Method,
    free: tuple[str, ...],
    held: tuple[str, ...],
    names: tuple[str, ...],
    output,
    objects: Mapping[str, Any] | None = None,
):
    objects = dict(objects or {})
    statics = tuple((n, v if isinstance(v, float) else id(v)) for n, v in sorted(objects.items()))
    key = (id(method), free, held, names, output, statics)
    cached = _RESIDUALS.get(key)
    if cached is not None:
        return cached
    model = method_model(method, output)

    def fn(p, args):
        import jax.numpy as jnp  # jax: imported by fits only

        inputs, held_values, target, weights = args
        pred = jnp.asarray(model({**held_values, **p}, {**inputs, **objects}))
        return weights * (pred - target)

    fn.__qualname__ = f"fit_method.<{method.id}>"
    _RESIDUALS[key] = fn
    _KEEP_ALIVE[id(method)] = method  # the method's id is part of the key: keep the object alive
    for v in objects.values():
        _KEEP_ALIVE[id(v)] = v
    return fn


def fit_method(
    method: Method,
    inputs: Mapping[str, Any],
    target,
    *,
    weights=None,
    params: Mapping[str, Param] | None = None,
    held: Mapping[str, float] | None = None,
    output: Callable[[Any], Any] | None = None,
    solver: str = "lm",
    param_rows: Mapping[str, Any] | None = None,
    **kwargs,
) -> FitResult:
    """Fit ``method``'s free parameters to ``target`` through the JAX run of its kernel text.

    ``inputs``: the kernel's per-element inputs by name (NumPy arrays or floats; broadcast against the
    target). ``weights`` (default 1): multiplies each residual (1/σ for data of known noise; then pass
    ``absolute_sigma=True``). ``params``: the parameters to fit with their start values and bounds
    (default: the method's declared ``params``, all of them); parameters of the method that are not fitted
    take the value in ``held`` (default: their declared default). ``output``: a module-level, JAX-traceable
    function applied to the kernel's result before the residual (reuse the same object across calls, or
    each call compiles again). ``solver``: ``"lm"`` (the JAX run, optimistix Levenberg–Marquardt) or
    ``"trf"`` (the NumPy run, SciPy's trust-region reflective solver; module text). ``param_rows`` (``"trf"``
    only): parameter name → boolean mask over the raveled residuals, the only ones that parameter changes
    (the others stay the same bit for bit at any value: a per-channel parameter of a per-channel fit), so
    that parameters of disjoint rows share the Jacobian's evaluations (`grouped_differences`). Other keyword
    arguments go to :func:`fit_least_squares` (``absolute_sigma``, ``max_steps`` for both solvers).
    """
    if solver not in ("lm", "trf"):
        raise ValueError(f"solver must be 'lm' or 'trf' (got {solver!r})")
    params = dict(method.params if params is None else params)
    held = dict(held or {})
    unknown = sorted((set(params) | set(held)) - set(method.params))
    if unknown:
        raise ValueError(
            f"method {method.id!r} has no parameter {', '.join(unknown)} "
            f"(parameters: {', '.join(method.params) or 'none'})"
        )
    if not params:
        raise ValueError(f"method {method.id!r}: nothing to fit (no free parameters)")
    both = sorted(set(params) & set(held))
    if both:
        raise ValueError(f"method {method.id!r}: {', '.join(both)} both fitted and held")
    missing = [n for n in method.input_names if n not in inputs]
    if missing:
        raise ValueError(f"method {method.id!r} needs input(s) {', '.join(missing)}")
    held_values = {
        k: float(held[k] if k in held else p.initial) for k, p in method.params.items() if k not in params
    }
    target = np.asarray(target, dtype=np.float64)
    if target.size == 0 or not np.all(np.isfinite(target)):
        raise ValueError(f"method {method.id!r}: the target must be a non-empty finite array")
    w = (
        np.ones_like(target)
        if weights is None
        else np.broadcast_to(np.asarray(weights, np.float64), target.shape)
    )
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"method {method.id!r}: weights must be finite and non-negative")
    # Scalars and samplers are constants of the fit, closed over by the residual (a kernel may shape its
    # text by them: the cone tracer's march distances come from t0 and t_max); arrays are traced.
    objects = {
        n: (inputs[n] if _is_sampler(inputs[n]) else float(inputs[n]))
        for n in method.input_names
        if _is_sampler(inputs[n]) or np.isscalar(inputs[n])
    }
    x = {n: np.asarray(inputs[n], np.float64) for n in method.input_names if n not in objects}
    # one Dr.Jit run for the scan and the fit (`Method.fit_ops` "drjit": one trace, one recording)
    run = DrJitRun(method, {**x, **objects}) if method.fit_ops == "drjit" and solver == "trf" else None
    if any(p.scan for p in params.values()):
        params = _scanned_starts(method, params, {**x, **objects}, held_values, target, w, output, run)
    if solver == "trf":
        inputs_all = {**x, **objects}
        flat, r0 = flat_scanned(method, params, inputs_all, held_values, target, w, output, run)
        if not flat:
            return _fit_trf(method, params, inputs_all, held_values, target, w, output,
                            param_rows=param_rows, run=run, **kwargs)  # fmt: skip
        # scanned steps (`held_steps`): held at the scan's best while the others are fitted
        steps = {k: params[k].initial for k in flat}
        rest = {k: p for k, p in params.items() if k not in steps}
        rows = None if param_rows is None else {k: v for k, v in param_rows.items() if k in rest}
        if not rest:
            assert r0 is not None
            return with_held(all_held(r0, params), params, steps)
        fitted = _fit_trf(method, rest, inputs_all, {**held_values, **steps}, target, w, output,
                          param_rows=rows, run=run, spent=len(steps), **kwargs)  # fmt: skip
        return with_held(fitted, params, steps)
    fn = _residual(method, tuple(params), tuple(sorted(held_values)), method.input_names, output, objects)
    return fit_least_squares(fn, params, (x, held_values, target, np.ascontiguousarray(w)), **kwargs)


def _scanned_starts(method, params, inputs, held, target, weights, output, run=None) -> dict[str, Param]:
    """``params`` with each scanned parameter's start (`Param.scan`) moved to the value of its scan (or its
    declared start) with the least weighted squared residual, the other parameters at their starts, one
    parameter after another in declaration order (NumPy or Dr.Jit run, as the fit's `Method.fit_ops`;
    ``run``: the fit's `DrJitRun`, made here where None). A Dr.Jit run evaluates a parameter's candidates in
    one replay (`scan_predictions`)."""
    if run is None and method.fit_ops == "drjit":
        run = DrJitRun(method, inputs)
    values = {**held, **{k: p.initial for k, p in params.items()}}
    out = dict(params)
    for k, p in params.items():
        best, cost = p.initial, math.inf
        trials = [{**values, k: v} for v in (p.initial, *p.scan_values())]  # the start too: never worse
        batch = scan_predictions(run, trials) if run is not None and output is None else None
        for i, trial in enumerate(trials):
            v = trial[k]
            with np.errstate(all="ignore"):
                if batch is not None:
                    pred = batch[i]
                else:
                    pred = method(NUMPY_OPS, inputs, trial) if run is None else run(trial)
                pred = output(pred) if output is not None else pred
                r = np.ravel(weights * (np.asarray(pred, np.float64) - target))  # (stacked: the same order)
                c = float(np.sum(r * r))
            if np.isfinite(c) and c < cost:
                best, cost = v, c
        values[k] = best
        out[k] = replace(p, initial=best)
    return out


def scan_predictions(run: DrJitRun, trials: Sequence[Mapping[str, float]]) -> list | None:
    """The predictions at each of ``trials`` from batched replays (`DrJitRun.many`) where the first one's
    is, bit for bit, what a call at that point gives (the scan's start, evaluated alone: the check that the
    batched text is the kernel's, element for element); else None (a call a point, `_scanned_starts`).
    Issue 33 (session 30): a 33-value scan of a shadow map's bias was 34 replays of ~0.3 ms, most of each
    Dr.Jit's call overhead."""
    alone = run(trials[0])  # (first: a traced call fills the samplers' tables the replays take as inputs)
    batch = run.many(trials)
    if batch is None:
        return None
    return batch if same_prediction(alone, batch[0]) else None


def fit_run(method: Method, inputs: Mapping[str, Any]) -> Callable[[Mapping[str, float]], Any]:
    """``run(values) -> prediction``: ``method``'s kernel on ``inputs`` where its TRF fit evaluates it (its
    `Method.fit_ops`: the NumPy run, or the Dr.Jit run `DrJitRun`), NumPy arrays out; non-finite values
    pass silently (``errstate``), as in the fit."""
    if method.fit_ops == "drjit":
        return DrJitRun(method, inputs)

    def numpy_run(values: Mapping[str, float]):
        with np.errstate(all="ignore"):
            return method(NUMPY_OPS, inputs, values)

    return numpy_run


def _takes_workers(least_squares) -> bool:
    """Whether SciPy's ``least_squares`` takes ``workers`` (the map its finite differences run through)."""
    try:
        return "workers" in inspect.signature(least_squares).parameters
    except (TypeError, ValueError):
        return False


def _fit_trf(
    method: Method,
    params: Mapping[str, Param],
    inputs: Mapping[str, Any],
    held: Mapping[str, float],
    target: np.ndarray,
    weights: np.ndarray,
    output: Callable[[Any], Any] | None,
    *,
    max_steps: int = 256,
    absolute_sigma: bool = False,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    param_rows: Mapping[str, Any] | None = None,
    run: DrJitRun | None = None,
    spent: int = 0,
) -> FitResult:
    """`fit_method` with ``solver="trf"`` (module text): the NumPy run of the kernel (or its Dr.Jit run
    ``run``, made here where None, for `Method.fit_ops` "drjit"), SciPy's TRF with a central-difference
    Jacobian; the result in the same form (and at-bound rule) as `fit_least_squares`. ``spent``: parameters
    fitted before and held here (`held_steps`), counted in the degrees of freedom."""
    import scipy.optimize

    names = tuple(params)
    ps = [params[n] for n in names]
    lo = np.array([p.lower for p in ps], np.float64)
    hi = np.array([p.upper for p in ps], np.float64)
    x0 = np.clip(np.array([p.initial for p in ps], np.float64), lo, hi)
    logs = np.array([p.log for p in ps], bool)  # `Param.log`: the solver steps log p (p = e^y)
    if np.any(logs):
        with np.errstate(divide="ignore"):
            lo, hi, x0 = (np.where(logs, np.log(a), a) for a in (lo, hi, x0))

    def values_of(v: np.ndarray) -> np.ndarray:
        """The parameters' values at the solver's point ``v``."""
        return np.where(logs, np.exp(v), v) if np.any(logs) else v

    if run is None and method.fit_ops == "drjit":
        run = DrJitRun(method, inputs)

    last: dict[bytes, np.ndarray] = {}  # the latest residuals (a Jacobian's centre: `grouped_differences`)
    shapes: list[tuple[int, ...]] = []  # the kernel's output shapes at one point (`point_batch`)

    def residual(v: np.ndarray) -> np.ndarray:
        key = np.asarray(v, np.float64).tobytes()
        kept = last.get(key)
        if kept is not None:  # the point just evaluated (SciPy's start is ours, `r0` below): the same array,
            return kept  # as every evaluation hands out the array it keeps (nothing writes into residuals)
        values = {**held, **dict(zip(names, (float(a) for a in values_of(v)), strict=True))}
        pred = method(NUMPY_OPS, inputs, values) if run is None else run(values)
        if not shapes:
            shapes.extend(np.shape(p) for p in (pred if isinstance(pred, tuple | list) else (pred,)))
        if output is not None:
            pred = output(pred)
        out = weighted_residuals(pred, weights, target)
        last.clear()
        last[key] = out
        return out

    rows = [None if param_rows is None else param_rows.get(n) for n in names]
    workers = None
    if _takes_workers(scipy.optimize.least_squares):
        mapper = difference_map(target.size, method.fit_ops)
        if mapper is None and output is None:  # its points in one call: NumPy's, or one Dr.Jit replay
            batch = (
                point_batch(method, inputs, held, names, values_of, weights, target, shapes)
                if run is None
                else run_point_batch(run.many, held, names, values_of, weights, target)
            )
            mapper = batched_points(batch, last, target.size)
        workers = grouped_differences(rows, last, mapper) or mapper
    extra: dict[str, Any] = {} if workers is None else {"workers": workers}
    if any(p.fd_step for p in ps):
        # `Param.fd_step`: h·|p| for such a parameter; the others ε^{1/3}·|p| (SciPy's default relative step,
        # which SciPy applies as ε^{1/3}·max(1, |p|) only where no step is given at all; at least 1 ulp)
        extra["diff_step"] = np.array([p.fd_step or np.finfo(np.float64).eps ** (1 / 3) for p in ps])

    with np.errstate(all="ignore"), one_blas_thread():
        r0 = residual(x0)
        if not np.all(np.isfinite(r0)):
            raise ValueError(
                f"method {method.id!r}: {int(np.sum(~np.isfinite(r0)))} non-finite residuals at the initial "
                "parameters"
            )
        dof = target.size - len(names) - spent

        def solve(start: np.ndarray, ftol: float):
            return scipy.optimize.least_squares(
                residual,
                start,
                jac="3-point",
                bounds=(lo, hi),
                method="trf",
                x_scale="jac",
                ftol=ftol,
                xtol=rtol * TRF_TOL_FACTOR,
                gtol=atol * TRF_TOL_FACTOR,
                max_nfev=int(max_steps) * (2 * len(names) + 1),
                **extra,
            )

        tight = rtol * TRF_TOL_FACTOR
        sol = solve(x0, max(noise_ftol(dof, float(r0 @ r0), absolute_sigma), tight))
        nfev = int(sol.nfev)
        if sol.status == 2 and not gauss_newton_gain_small(
            sol.jac, sol.fun, dof, absolute_sigma, ~held_at_bounds(sol.x, lo, hi, sol.jac, sol.fun)
        ):
            # Stopped on ftol with a Gauss–Newton gain left: possibly crawling along a flat valley (each
            # step gains little, many remain). Go on at the fixed tolerance, and keep where that ends if it
            # gained more than CHECK_KAPPA² s² (a value moved by more than that fraction of its stderr);
            # an undetermined direction's gain is the linearisation's only, and the first stop stands.
            more = solve(np.asarray(sol.x, np.float64), tight)
            nfev += int(more.nfev)
            ssr, ssr_more = float(sol.fun @ sol.fun), float(more.fun @ more.fun)
            if ssr - ssr_more > CHECK_KAPPA**2 * residual_variance(ssr, dof, absolute_sigma):
                sol = more
    x = values_of(np.asarray(sol.x, np.float64))
    r = np.asarray(sol.fun, np.float64)
    jac = np.asarray(sol.jac, np.float64).reshape(r.size, len(names))
    if np.any(logs):
        jac = jac / np.where(logs, x, 1.0)  # ∂r/∂p = ∂r/∂(log p) / p
    n, k = r.size, len(names)  # (r spans the whole target: n − k is the dof above)
    ssr = float(r @ r)
    if np.all(np.isfinite(jac)):
        cov, rank = covariance_from_jacobian(jac, ssr, dof, absolute_sigma=absolute_sigma, rcond=FD_RCOND)
    else:
        cov, rank = np.full((k, k), np.nan), 0
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(np.diag(cov))
        corr = cov / np.outer(se, se)
    at_lower, at_upper = bound_flags(names, ps, x)
    at_bound = {nm: at_lower[nm] or at_upper[nm] for nm in names}
    converged = bool(sol.status > 0 and np.all(np.isfinite(r)))
    message = "" if converged else f"scipy least_squares (trf): {sol.message}"
    # A parameter the residuals do not change with at the solution (every central difference exactly 0: a
    # step such as an AO radius, between the samples' distances) was not fitted, only left at its start.
    # A scanned parameter (`Param.scan`) is such a step by declaration: its value is the scan's best.
    flat = [nm for i, nm in enumerate(names) if np.all(np.isfinite(jac[:, i])) and not np.any(jac[:, i])]
    stuck = [nm for nm in flat if not params[nm].scan]
    scanned = [step_message(nm, params[nm]) for nm in flat if params[nm].scan]
    if stuck:
        scanned.append(f"{', '.join(stuck)}: the residuals do not change with it (zero derivative at every "
                       "element): left at its start, not fitted")  # fmt: skip
    if scanned:
        message = "; ".join([*([message] if message else []), *scanned])
    return FitResult(
        values={nm: float(x[i]) for i, nm in enumerate(names)},
        stderr={nm: float(se[i]) for i, nm in enumerate(names)},
        correlation=[[float(c) for c in row] for row in corr],
        param_names=names,
        rms_residual=float(np.sqrt(ssr / n)),
        ssr=ssr,
        n_residuals=int(n),
        dof=int(dof),
        steps=nfev,
        converged=converged,
        message=message,
        at_bound=at_bound,
        lower={nm: p.lower for nm, p in zip(names, ps, strict=True)},
        upper={nm: p.upper for nm, p in zip(names, ps, strict=True)},
        jacobian_rank=int(rank),
    )
