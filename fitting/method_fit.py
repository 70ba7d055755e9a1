"""Fit a method's free parameters through its one kernel text (the JAX run of `rtfit.realtime` kernels).

``fit_method(method, inputs, target)`` minimises Σ wᵢ²·(f(xᵢ; p) − yᵢ)² over the method's free
parameters p, where f is ``method.kernel`` evaluated with the JAX ops namespace
(`rtfit.realtime.arrays.JAX_OPS`): the formula the shader runs, the NumPy benchmark times and the Dr.Jit
comparison evaluates is the formula that is differentiated here. No residual is written by hand.

Bounds, the optimiser (optimistix Levenberg–Marquardt in float64) and the uncertainties are those of
:func:`rtfit.fitting.fit_least_squares`. The jitted solve is compiled once per (method, set of fitted
parameter names, set of held parameter names, input names, output transform) and reused for every case:
inputs, targets, weights, start values, bounds and held values are traced arguments.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from rtfit.realtime.arrays import jax_ops
from rtfit.realtime.methods import Method, Param

from .least_squares import FitResult, fit_least_squares

__all__ = ["fit_method", "method_model"]

_RESIDUALS: dict[tuple, Callable] = {}
_KEEP_ALIVE: dict[int, Method] = {}


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
    **kwargs,
) -> FitResult:
    """Fit ``method``'s free parameters to ``target`` through the JAX run of its kernel text.

    ``inputs``: the kernel's per-element inputs by name (NumPy arrays or floats; broadcast against the
    target). ``weights`` (default 1): multiplies each residual (1/σ for data of known noise; then pass
    ``absolute_sigma=True``). ``params``: the parameters to fit with their start values and bounds
    (default: the method's declared ``params``, all of them); parameters of the method that are not fitted
    take the value in ``held`` (default: their declared default). ``output``: a module-level, JAX-traceable
    function applied to the kernel's result before the residual (reuse the same object across calls, or
    each call compiles again). Other keyword arguments go to :func:`fit_least_squares`.
    """
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
    fn = _residual(method, tuple(params), tuple(sorted(held_values)), method.input_names, output, objects)
    return fit_least_squares(fn, params, (x, held_values, target, np.ascontiguousarray(w)), **kwargs)
