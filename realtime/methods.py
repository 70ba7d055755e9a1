"""Methods as data: one declaration per approximation, from which tables, fits, bench rows and reports derive.

A *method* is one row of a family's comparison (Probulator's "one registry line per method"): an id used
in file names, result records and report columns, a label for people, the kernel text it runs (written
once against an ops namespace, see `rtfit.realtime.arrays`), the names and units of the per-element
inputs the kernel takes, and its free parameters with defaults, bounds and units::

    WRAP = Method(
        id="wrap", label="Wrap lighting", kernel=_wrap_kernel,
        inputs=(Input("cos_theta", "1", "n·l"), Input("irradiance", "W/m²", "E⊥")),
        params={"w": Param(0.5, 0.0, 1.0, unit="1"), "p": Param(1.5, 0.25, 8.0, unit="1")},
        formula="E⊥·max((cos θ + w)/(1 + w), 0)^p", source="000:2520-2534")

The kernel is called with keywords, ``kernel(ops, **inputs, **params)``, so its positional signature is
documentation, not an ordering contract. The same declaration evaluates on Dr.Jit, NumPy or JAX
(`Method.evaluate`, dispatched like every public function of this package), and `rtfit.fitting.fit_method`
fits its free parameters through the JAX run of that one text.

Variants are parameters, not subclasses: "half-Lambert" can be its own kernel, or the wrap kernel with
``fixed={"w": 1.0, "p": 2.0}``; "wrap fitted per light size" is the wrap method whose parameters a fit
supplies. ``exact=True`` marks a method that must sit at the reference's noise floor (the check that the
reference and the approximation measure the same quantity). ``storage`` is the number of floats stored
per probe/texel/element (irradiance bases: 9 per channel for SH L2), or None for closed forms.

This module imports nothing outside the standard library and `rtfit.realtime.arrays`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import Any

from .arrays import evaluate

__all__ = ["Input", "Method", "Param", "method_table"]


@dataclass(frozen=True)
class Param:
    """A free parameter: its default (the start value of a fit), optional bounds and its unit.

    ``initial`` must be finite and strictly inside (lower, upper); infinite bounds mean unbounded on that
    side. ``unit`` is a short unit text ("1" for dimensionless, "rad", "1/m", "W/m²"); ``description`` one
    line for tables and fitted-parameter files."""

    initial: float
    lower: float = -math.inf
    upper: float = math.inf
    unit: str = ""
    description: str = ""
    published: bool = True
    """False where the source gives no value (the seed's Evans contrast k): ``initial`` is then only the
    fit's start, and a row evaluated at it is no result of the method (`Method.unpublished`)."""
    scan: int = 0
    """0: the local solver alone. n > 0: the method is a step function of this parameter (a depth compare's
    bias), whose gradient is 0 between steps: the fit first scans n values over the bounds (`scan_values`)
    and starts the solver at the best, which then stays there; its resolution is the scan's step (no
    standard error)."""
    fd_step: float = 0.0
    """0: the ``"trf"`` fits' central differences step this parameter by SciPy's default, ε^{1/3}·max(1, |p|)
    (ε the float64 epsilon). h > 0: by h·|p|, a relative step wider than the spacing of the steps the
    residuals take in p where they depend on p through comparisons with many sampled values (an AO radius
    against each pixel's ray-hit distances: a staircase of ~10⁵ tiny steps). The difference then measures
    the slope of the staircase over ±h·p, not whether a step happens to fall within ±ε^{1/3}·p, along which
    the solver crawled in tens of evaluations (issue 33). The fit resolves p to about h·p."""
    log: bool = False
    """True: the ``"trf"`` fits (`rtfit.fitting.fit_method`) step this parameter in log p, a scale whose
    fit runs along a curved valley in p (colour-bleeding's I·b/D, a straight line in the logs: in p, TRF
    crawled along it in a hundred small steps). Needs lower ≥ 0 (a lower bound 0 is log p = −∞); the
    values, bounds and standard errors reported are p's."""

    def __post_init__(self):
        for f in ("initial", "lower", "upper"):
            v = getattr(self, f)
            if isinstance(v, bool):
                raise ValueError(f"Param.{f} must be a real number, got {v!r}")
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"Param.{f} must be a real number, got {v!r}") from None
            object.__setattr__(self, f, v)
        lo, hi = self.lower, self.upper
        if math.isnan(lo) or math.isnan(hi) or lo == math.inf or hi == -math.inf:
            raise ValueError(f"Param bounds must be finite or -inf/+inf on their side, got ({lo}, {hi})")
        if not self.lower < self.upper:
            raise ValueError(f"Param needs lower < upper, got ({self.lower}, {self.upper})")
        if not math.isfinite(self.initial):
            raise ValueError(f"Param.initial must be finite, got {self.initial}")
        if not self.lower < self.initial < self.upper:
            raise ValueError(
                f"Param.initial {self.initial} must lie strictly inside ({self.lower}, {self.upper})"
            )
        if isinstance(self.scan, bool) or not isinstance(self.scan, int) or self.scan < 0:
            raise ValueError(f"Param.scan must be a non-negative int, got {self.scan!r}")
        if self.log and not self.lower >= 0.0:
            raise ValueError(f"Param.log needs lower ≥ 0, got {self.lower}")
        if isinstance(self.fd_step, bool) or not (
            isinstance(self.fd_step, int | float) and 0.0 <= self.fd_step < 1.0
        ):
            raise ValueError(f"Param.fd_step must be a number in [0, 1), got {self.fd_step!r}")
        if self.log and self.fd_step:
            raise ValueError("Param.fd_step is a step in p: not with Param.log (the solver steps log p)")
        if self.scan and not (math.isfinite(self.lower) and math.isfinite(self.upper)):
            raise ValueError("Param.scan needs finite bounds (the scan covers them)")

    @property
    def default(self) -> float:
        """The start value (an alias of ``initial`` that reads better in method tables)."""
        return self.initial

    def scan_values(self) -> list[float]:
        """The ``scan`` values a step-function fit tries, strictly inside the bounds: geometric from 10⁻³ of
        the upper bound to it where the range is [0, upper] (a bias: relative resolution (10³)^(1/(n−1))),
        else the centres of n equal cells."""
        n, lo, hi = self.scan, self.lower, self.upper
        if n <= 0 or not (math.isfinite(lo) and math.isfinite(hi)):
            return []
        if lo == 0.0 and hi > 0.0:
            return [hi * 10.0 ** (-3.0 * (1.0 - (j + 0.5) / n)) for j in range(n)]
        return [lo + (hi - lo) * (j + 0.5) / n for j in range(n)]

    @property
    def kind(self) -> str:
        """Which bounds are finite: "both", "lower", "upper" or "free"."""
        lo, hi = math.isfinite(self.lower), math.isfinite(self.upper)
        return "both" if lo and hi else "lower" if lo else "upper" if hi else "free"

    def to_internal(self) -> float:
        """z with x(z) = initial under the fit's change of variables (see `rtfit.fitting.least_squares`)."""
        k, x = self.kind, self.initial
        if k == "both":
            u = (x - self.lower) / (self.upper - self.lower)
            return math.log(u) - math.log1p(-u)
        if k in ("lower", "upper"):
            d = x - self.lower if k == "lower" else self.upper - x
            return d + math.log(-math.expm1(-d))  # softplus⁻¹(d), stable for small and large d
        return x


@dataclass(frozen=True)
class Input:
    """A per-element kernel input: its keyword name, unit text, one line of meaning and, where it is a
    scalar per element, its valid domain [lo, hi] (tests draw inputs from it to check that the Dr.Jit,
    NumPy and JAX runs of the kernel agree; None for tables, grids and other structured inputs)."""

    name: str
    unit: str = ""
    description: str = ""
    domain: tuple[float, float] | None = None


def _as_input(x: Input | str) -> Input:
    return x if isinstance(x, Input) else Input(str(x))


@dataclass(frozen=True)
class Method:
    """One approximation (or exact form) as data; see the module docstring.

    ``kernel(ops, **inputs, **params)`` returns one array (or a tuple of arrays for multi-output kernels).
    ``params``: the free parameters a fit may adjust; ``fixed``: constant keyword arguments this method
    passes to its kernel (a variant of a shared kernel). ``quantity`` names what the method approximates
    (e.g. "light_irradiance", "fog_transmittance"), ``formula`` the formula in one line (Unicode math),
    ``source`` where it comes from (seed file and lines, or paper and equation)."""

    id: str
    label: str
    kernel: Callable[..., Any]
    inputs: tuple[Input, ...] = ()
    params: Mapping[str, Param] = field(default_factory=dict)
    fixed: Mapping[str, Any] = field(default_factory=dict)
    exact: bool = False
    storage: int | None = None
    quantity: str = ""
    formula: str = ""
    source: str = ""
    description: str = ""
    fit_ops: str = "numpy"
    """The run of the kernel text a ``solver="trf"`` fit (`rtfit.fitting.fit_method`) evaluates: ``"numpy"``
    (float64 NumPy), or ``"drjit"`` (float64 Dr.Jit of the default backend, inputs converted once, the free
    parameters opaque so that one compiled kernel serves every evaluation): for a kernel whose NumPy run is a
    long Python loop over large arrays (the Nishita sky's texture rebuild: 68 steps over 8192 texels)."""

    def __post_init__(self):
        if self.fit_ops not in ("numpy", "drjit"):
            raise ValueError(f"method {self.id!r}: fit_ops must be 'numpy' or 'drjit' (got {self.fit_ops!r})")
        if not self.id or not all(ch.isalnum() or ch in "-_." for ch in self.id):
            raise ValueError(f"method id {self.id!r}: use letters, digits, '-', '_' or '.'")
        object.__setattr__(self, "inputs", tuple(_as_input(i) for i in self.inputs))
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))
        object.__setattr__(self, "fixed", MappingProxyType(dict(self.fixed)))
        names = [i.name for i in self.inputs] + list(self.params) + list(self.fixed)
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"method {self.id!r}: {', '.join(dup)} declared twice (inputs, params, fixed)")

    @cached_property
    def input_names(self) -> tuple[str, ...]:
        """The inputs' names in declaration order (made once: a fit calls the kernel ~10⁴ times an audit)."""
        return tuple(i.name for i in self.inputs)

    @property
    def unpublished(self) -> tuple[str, ...]:
        """The free parameters whose source gives no value (`Param.published` False): the method means
        something only once they are fitted (or set by the user)."""
        return tuple(k for k, p in self.params.items() if not p.published)

    @property
    def fitted(self) -> bool:
        """True when the method has free parameters."""
        return bool(self.params)

    def defaults(self) -> dict[str, float]:
        """Each free parameter's default value."""
        return {k: p.initial for k, p in self.params.items()}

    def bounds(self) -> dict[str, tuple[float, float]]:
        return {k: (p.lower, p.upper) for k, p in self.params.items()}

    def keywords(self, params: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The kernel's non-input keywords: defaults, overridden by ``params``, then the fixed values.

        An unknown parameter name is a one-line ValueError naming the method and its parameters."""
        params = dict(params or {})
        unknown = sorted(set(params) - set(self.params))
        if unknown:
            known = ", ".join(self.params) or "none"
            raise ValueError(
                f"method {self.id!r} has no parameter {', '.join(unknown)} (parameters: {known})"
            )
        return {**self.defaults(), **params, **self.fixed}

    def __call__(self, ops, inputs: Mapping[str, Any], params: Mapping[str, Any] | None = None):
        """The kernel text on ``ops`` (no dispatch, no conversion): ``kernel(ops, **inputs, **keywords)``."""
        missing = [n for n in self.input_names if n not in inputs]
        if missing:
            raise ValueError(f"method {self.id!r} needs input(s) {', '.join(missing)}")
        return self.kernel(ops, **{n: inputs[n] for n in self.input_names}, **self.keywords(params))

    def evaluate(
        self, inputs: Mapping[str, Any], params: Mapping[str, Any] | None = None, *, folded: bool = False
    ):
        """Evaluate with the package's dispatch (`rtfit.realtime.arrays.evaluate`): JAX arrays → JAX,
        Dr.Jit arrays → that Dr.Jit type (lazy), NumPy arrays → the default Dr.Jit backend, back to NumPy;
        floats → float64 NumPy text. Parameters may be floats or arrays of the inputs' kind; on Dr.Jit a
        number is an opaque value (one kernel for every value), or a literal where ``folded`` (a cost)."""
        names = self.input_names
        missing = [n for n in names if n not in inputs]
        if missing:
            raise ValueError(f"method {self.id!r} needs input(s) {', '.join(missing)}")
        kw = self.keywords(params)
        free = [k for k in kw if k not in self.fixed]  # arrays or floats: dispatched with the inputs
        keys = list(names) + free
        values = [inputs[n] for n in names] + [kw[k] for k in free]
        fixed = dict(self.fixed)  # any constant (a mode string, a table): passed to the kernel as given

        def kernel(ops, *args):
            return self.kernel(ops, **dict(zip(keys, args, strict=True)), **fixed)

        return evaluate(kernel, *values, folded=folded)


def method_table(methods: Iterable[Method]) -> Mapping[str, Method]:
    """A read-only ``{id: method}`` in declaration order; a repeated id is a ValueError."""
    out: dict[str, Method] = {}
    for m in methods:
        if m.id in out:
            raise ValueError(f"method id {m.id!r} declared twice")
        out[m.id] = m
    return MappingProxyType(out)
