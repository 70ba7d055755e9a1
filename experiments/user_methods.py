"""A user's own approximations: loading them by spec or entry point, and validating them before a run.

A user approximation is a `Method` made by `rtfit.realtime.quantities.approximation` (docs/audit.md, "Your
own approximation"). `load_approximation(spec)` finds one:

* ``path/to/file.py:name`` — the file is executed as a fresh module (it may import anything);
* ``package.module:name`` — an importable module;
* ``name`` — an installed package's entry point in the group `ENTRY_POINT_GROUP` (``rtfit.approximations``),
  whose object is an approximation (``my_pkg.shading:my_wrap``).

`check_approximation(method, n=256)` evaluates it on ``n`` samples of its quantity's input domains (each
scalar input on an even grid over its domain, endpoints included, independently shuffled; vector groups on
the unit sphere; structured inputs from the quantity's examples, made for ``n`` samples: a per-element one,
such as the obscurance's K hit distances, is a tuple of arrays of ``n`` values, run on Dr.Jit as Dr.Jit
arrays like the scalar inputs; a table, as the probe grid's, a Dr.Jit array too), at its parameters'
defaults and at their finite bounds, on NumPy and on Dr.Jit. Every failure is a one-line `UserMethodError`
naming the function and the first offending input: an exception, NaN or Inf, a result of the wrong shape,
or a NumPy and a Dr.Jit run that disagree.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import math
import sys
import traceback
import warnings
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS, evaluate, is_drjit, to_drjit
from rtfit.realtime.methods import Method
from rtfit.realtime.quantities import (
    QUANTITIES,
    ApproximationError,
    Quantity,
    UserCodeExit,
    get_quantity,
    is_user_approximation,
)

__all__ = [
    "ENTRY_POINT_GROUP",
    "UserMethodError",
    "check_approximation",
    "entry_point_approximations",
    "load_approximation",
    "sample_inputs",
]

ENTRY_POINT_GROUP = "rtfit.approximations"
"""The entry-point group an installed package registers its approximations in (name → object)."""


class UserMethodError(ValueError):
    """A user approximation that cannot be loaded or fails validation: one line, exit 2. ``stage``:
    ``"missing"`` (no such file, module or entry point: perhaps a misspelt name), ``"loading"`` (found, not
    loadable), ``"checking"`` (loaded, failed validation) or ``""`` (the
    process running the user's code ended or timed out: `rtfit.experiments.user_sandbox`)."""

    def __init__(self, message: str, *, stage: str = ""):
        super().__init__(message)
        self.stage = stage


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _exit_text(e: SystemExit) -> str:
    """A `SystemExit` from user code as a reason: user code must return or raise, never end rtfit's run."""
    return f"called sys.exit({e.code!r}) (an approximation must return values or raise an exception)"


def _looks_like_file(module: str) -> bool:
    return module.endswith(".py") or "/" in module or "\\" in module


def _load_file(spec: str, path_text: str):
    path = Path(path_text).expanduser()
    if not path.is_file():
        raise UserMethodError(f"{spec}: no such file {path_text}", stage="missing")
    path = path.resolve()
    name = "rtfit_user_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    mspec = importlib.util.spec_from_file_location(name, path)
    if mspec is None or mspec.loader is None:
        raise UserMethodError(f"{spec}: {path_text} is not a Python file")
    module = importlib.util.module_from_spec(mspec)
    sys.modules[name] = module  # dataclasses and pickling look the module up while it executes
    try:
        mspec.loader.exec_module(module)
    except (Exception, SystemExit) as e:  # SystemExit: sys.exit at import must not end rtfit
        sys.modules.pop(name, None)
        lines = [f.lineno for f in traceback.extract_tb(e.__traceback__) if Path(f.filename) == path]
        where = f"{path_text} line {lines[-1]}" if lines else path_text
        if isinstance(e, ApproximationError):
            raise UserMethodError(f"{spec}: {e} ({where})") from None
        if isinstance(e, SystemExit):
            raise UserMethodError(f"{spec}: loading {where} {_exit_text(e)}") from None
        raise UserMethodError(f"{spec}: loading {where} failed: {_one_line(e)}") from None
    return module


def _load_module(spec: str, module_name: str):
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name and module_name.startswith(e.name):
            raise UserMethodError(
                f"{spec}: no module named {e.name!r} (and no file {module_name})", stage="missing"
            ) from None
        raise UserMethodError(f"{spec}: importing {module_name} failed: {_one_line(e)}") from None
    except ApproximationError as e:
        raise UserMethodError(f"{spec}: {e} (in {module_name})") from None
    except SystemExit as e:  # sys.exit at import must not end rtfit
        raise UserMethodError(f"{spec}: importing {module_name} {_exit_text(e)}") from None
    except Exception as e:
        raise UserMethodError(f"{spec}: importing {module_name} failed: {_one_line(e)}") from None


def _as_approximation(spec: str, obj: Any) -> Method:
    if is_user_approximation(obj):
        return obj
    if isinstance(obj, Method):
        if obj.quantity not in QUANTITIES:
            known = ", ".join(QUANTITIES)
            raise UserMethodError(
                f"{spec}: method {obj.id!r} has unknown quantity {obj.quantity!r} (known: {known})"
            )
        return obj
    what = type(obj).__name__
    hint = " (decorate it with @rtfit.approximation(quantity=…, params=…))" if callable(obj) else ""
    raise UserMethodError(f"{spec}: {what} is not an approximation{hint}")


def entry_point_approximations() -> dict[str, metadata.EntryPoint]:
    """The installed entry points of `ENTRY_POINT_GROUP`, by name (not yet loaded)."""
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def load_approximation(spec: str) -> Method:
    """The approximation ``spec`` names (module docstring): ``file.py:name``, ``module:name`` or an entry
    point's name. Every failure is one `UserMethodError` line naming ``spec``: no such file or module, no
    such attribute, not an approximation, an unknown quantity, a parameter without bounds (the decorator's
    errors, raised while the file loads), an unknown entry point."""
    if not isinstance(spec, str) or not spec.strip():
        raise UserMethodError(
            f"{spec!r}: an approximation is FILE.py:NAME, MODULE:NAME or an entry-point name"
        )
    spec = spec.strip()
    module_text, sep, attr = spec.rpartition(":")
    if not sep or (len(module_text) == 1 and module_text.isalpha()):  # no ':', or only a drive letter
        eps = entry_point_approximations()
        if spec not in eps:
            known = ", ".join(sorted(eps)) or "none installed"
            raise UserMethodError(
                f"{spec}: not FILE.py:NAME or MODULE:NAME, and no entry point {spec!r} in group "
                f"{ENTRY_POINT_GROUP} ({known})",
                stage="missing",
            )
        try:
            obj = eps[spec].load()
        except SystemExit as e:  # sys.exit at import must not end rtfit
            raise UserMethodError(f"{spec}: loading entry point {eps[spec].value} {_exit_text(e)}") from None
        except Exception as e:
            raise UserMethodError(
                f"{spec}: loading entry point {eps[spec].value} failed: {_one_line(e)}"
            ) from None
        return _as_approximation(spec, obj)
    if not attr or not module_text:
        raise UserMethodError(f"{spec}: an approximation is FILE.py:NAME or MODULE:NAME")
    module = (
        _load_file(spec, module_text) if _looks_like_file(module_text) else _load_module(spec, module_text)
    )
    if not hasattr(module, attr):
        found = sorted(k for k, v in vars(module).items() if is_user_approximation(v))
        listing = (
            f" (approximations there: {', '.join(found)})" if found else " (it defines no approximation)"
        )
        raise UserMethodError(f"{spec}: {module_text} has no attribute {attr!r}{listing}")
    return _as_approximation(spec, getattr(module, attr))


# ------------------------------------------------------------------------------------------- validation
def sample_inputs(quantity: Quantity | str, n: int = 256, seed: int = 0) -> dict[str, Any]:
    """``n`` samples of ``quantity``'s inputs (module docstring): NumPy float64 arrays of shape (n,) for
    the scalar inputs, the quantity's examples for structured ones (each factory called with ``n``)."""
    q = get_quantity(quantity) if isinstance(quantity, str) else quantity
    if not (isinstance(n, int) and n >= 2):
        raise ValueError(f"n must be an integer ≥ 2 (got {n!r})")
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    for i in q.inputs:
        if i.domain is None:
            out[i.name] = q.examples[i.name](n)
        else:
            lo, hi = i.domain
            out[i.name] = rng.permutation(np.linspace(lo, hi, n))
    for group in q.unit_vectors:
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        for k, c in enumerate(q.vectors[group]):
            out[c] = np.ascontiguousarray(v[:, k])
    return out


def _fmt(v: float) -> str:
    return f"{float(v):.6g}"


def _per_element(value: Any, n: int) -> bool:
    """Whether a structured input is per element: a tuple or list of arrays of ``n`` values each (the K hit
    distances of each point)."""
    return (
        isinstance(value, tuple | list)
        and len(value) > 0
        and all(isinstance(v, np.ndarray) and v.shape == (n,) for v in value)
    )


def _at(q: Quantity, inputs: Mapping[str, Any], read: set[str], k: int) -> str:
    parts = []
    for i in q.inputs:
        v = inputs[i.name]
        if read and i.name not in read:
            continue
        if i.domain is not None:
            parts.append(f"{i.name}={_fmt(v[k])}")
        elif (
            isinstance(v, tuple | list) and v and _per_element(v, len(v[0]) if hasattr(v[0], "shape") else -1)
        ):
            shown = ", ".join(_fmt(a[k]) for a in v[:4]) + (", …" if len(v) > 4 else "")
            parts.append(f"{i.name}=({shown})")
    return ", ".join(parts)


def _params_text(method: Method, params: Mapping[str, float]) -> str:
    if not params or params == method.defaults():
        return ""
    return "; " + ", ".join(f"{k}={_fmt(v)}" for k, v in params.items())


def _raising(method: Method, inputs, params, n) -> list[int]:
    """The samples at which the NumPy text raises when run on that sample alone (floats)."""
    kernel = method.kernel
    out = []
    for k in range(n):
        one = {
            name: (
                float(v[k])
                if isinstance(v, np.ndarray) and v.shape == (n,)
                else tuple(float(a[k]) for a in v)
                if _per_element(v, n)
                else v
            )
            for name, v in inputs.items()
        }
        try:
            with np.errstate(all="ignore"):
                kernel.run(NUMPY_OPS, one, params)
        except Exception:
            out.append(k)
    return out


def _is_complex(value: Any) -> bool:
    """Whether ``value`` (an array, a scalar, a Dr.Jit array, a list) holds complex numbers."""
    if isinstance(value, complex | np.complexfloating):
        return True
    if isinstance(value, np.ndarray):
        return np.iscomplexobj(value)
    if is_drjit(value):
        return "Complex" in type(value).__name__
    if isinstance(value, list | tuple):
        return any(_is_complex(v) for v in value)
    return False


def _as_outputs(method: Method, q: Quantity, out: Any, n: int, backend: str, params_text: str) -> list:
    name = method.id
    want = "one array" if q.channels == 1 else f"a tuple of {q.channels} arrays"
    parts = list(out) if isinstance(out, tuple | list) and q.channels > 1 else [out]
    if isinstance(out, tuple | list) and q.channels == 1:
        raise UserMethodError(
            f"{name}: returned a {type(out).__name__} of {len(out)} on {backend} ({q.name} wants {want})"
        )
    if len(parts) != q.channels:
        raise UserMethodError(
            f"{name}: returned {len(parts)} value(s) on {backend} ({q.name} wants {want}{params_text})"
        )
    arrays = []
    for p in parts:
        if _is_complex(p):  # refused before NumPy casts it (a ComplexWarning, the imaginary part dropped)
            raise UserMethodError(
                f"{name}: returned complex numbers on {backend} ({q.name} is real: take .real or abs() "
                f"yourself if that is what you mean{params_text})"
            )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", np.exceptions.ComplexWarning)
                a = np.asarray(p, dtype=np.float64)
        except (TypeError, ValueError, np.exceptions.ComplexWarning) as e:
            raise UserMethodError(
                f"{name}: returned {type(p).__name__} on {backend}, not numbers ({_one_line(e)})"
            ) from None
        if a.shape != (n,):
            first = next((i.name for i in q.inputs if i.domain is not None), f"{q.inputs[0].name}[0]")
            raise UserMethodError(
                f"{name}: returned shape {a.shape} on {backend} for {n} samples (expected ({n},): one value "
                f"per element; a constant needs the inputs' shape, e.g. 0*g.{first} + c{params_text})"
            )
        arrays.append(a)
    return arrays


def check_approximation(method: Method, n: int = 256, *, seed: int = 0, drjit: bool = True) -> None:
    """Validate a user approximation on its quantity's input domains (module docstring); None if it
    passes, else a one-line `UserMethodError` naming it and the first offending input."""
    if not is_user_approximation(method):
        raise UserMethodError(
            f"{getattr(method, 'id', method)!r}: not a user approximation (@rtfit.approximation)"
        )
    q = method.kernel.quantity
    inputs = sample_inputs(q, n, seed)
    scalar = [i.name for i in q.inputs if i.domain is not None]
    structured = {i.name: inputs[i.name] for i in q.inputs if i.domain is None}
    # per-element structured inputs (tuples of arrays of n values) go to Dr.Jit as arrays beside the scalars
    sequences = {k: len(v) for k, v in structured.items() if _per_element(v, n)}
    flat = [a for k in sequences for a in structured[k]]
    name = method.id
    param_sets = [method.defaults()]
    for k, p in method.params.items():
        for b in (p.lower, p.upper):
            if math.isfinite(b):
                param_sets.append({**method.defaults(), k: b})
    for params in param_sets:
        ptext = _params_text(method, params)
        read: set[str] = set()
        try:
            with np.errstate(all="ignore"):
                out_np = method.kernel.run(NUMPY_OPS, inputs, params, read)
        except UserCodeExit as e:  # sys.exit in the function (the kernel turned it into this error)
            raise UserMethodError(f"{e}{ptext}") from None
        except Exception as e:
            raising = _raising(method, inputs, params, n)
            if not raising:  # every sample runs alone: the text does not work on arrays
                raise UserMethodError(
                    f"{name}: raised {_one_line(e)} on arrays of {n} samples, though each sample alone runs "
                    f"(a Python branch on an array? use ops.select, ops.maximum){ptext}"
                ) from None
            if len(raising) == n:
                raise UserMethodError(f"{name}: raised {_one_line(e)} (on every sample{ptext})") from None
            raise UserMethodError(
                f"{name}: raised {_one_line(e)} at {_at(q, inputs, read, raising[0])} "
                f"(first of {len(raising)} of {n} samples{ptext})"
            ) from None
        arrays = _as_outputs(method, q, out_np, n, "NumPy", ptext)
        bad = np.zeros(n, bool)
        for a in arrays:
            bad |= ~np.isfinite(a)
        if bad.any():
            k = int(np.argmax(bad))
            v = next(a[k] for a in arrays if not np.isfinite(a[k]))
            what = "NaN" if math.isnan(v) else "Inf" if v > 0 else "-Inf"
            raise UserMethodError(
                f"{name}: returned {what} at {_at(q, inputs, read, k)} "
                f"(first of {int(bad.sum())} of {n} samples{ptext})"
            )
        if not drjit:
            continue
        keys = scalar + list(params)

        def kernel(ops, *args, _keys=keys, _free=tuple(params)):
            kw = dict(zip(_keys, args[: len(_keys)], strict=True))
            rest = list(args[len(_keys) :])
            Float = next(type(a) for a in args if is_drjit(a))
            values = {**{s: kw[s] for s in scalar}}
            for k, v in structured.items():
                if k in sequences:
                    values[k] = tuple(rest.pop(0) for _ in range(sequences[k]))
                elif isinstance(v, np.ndarray):
                    # a table: an array of the kernel's kind (ops.gather reads it), aligned (`to_drjit`):
                    # one kernel wherever NumPy put it
                    values[k] = to_drjit(Float, np.reshape(v, -1))
                else:
                    values[k] = v
            out = method.kernel.run(ops, values, {p: kw[p] for p in _free})
            for part in out if isinstance(out, tuple | list) else (out,):
                if not is_drjit(part):  # NumPy calls on Dr.Jit arrays: round trips, not one fused kernel
                    raise TypeError(f"returned {type(part).__name__}, not a Dr.Jit array")
            return out

        try:
            out_dr = evaluate(
                kernel, *[inputs[s] for s in scalar], *[float(v) for v in params.values()], *flat
            )
        except UserCodeExit as e:
            raise UserMethodError(f"{e} (on Dr.Jit{ptext})") from None
        except Exception as e:
            raise UserMethodError(
                f"{name}: raised {_one_line(e)} on Dr.Jit (NumPy ran: use ops.* functions, not Python "
                f"branches on arrays{ptext})"
            ) from None
        arrays_dr = _as_outputs(method, q, out_dr, n, "Dr.Jit", ptext)
        for a, b in zip(arrays, arrays_dr, strict=True):
            scale = max(1.0, float(np.max(np.abs(a))))
            diff = ~np.isfinite(b) | (np.abs(a - b) > 1e-6 * scale)
            if diff.any():
                k = int(np.argmax(diff))
                raise UserMethodError(
                    f"{name}: NumPy gives {_fmt(a[k])} and Dr.Jit {_fmt(b[k])} at {_at(q, inputs, read, k)} "
                    f"(first of {int(diff.sum())} of {n} samples{ptext})"
                )
