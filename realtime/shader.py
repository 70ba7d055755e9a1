"""Shader text from kernel text: an ops namespace that *traces* a kernel into GLSL and HLSL.

`SHADER_OPS` defines the names of every ops namespace (`rtfit.realtime.arrays.OP_NAMES`). Its functions
take symbolic values (`Sym`: a named float or bool of the shader function being written) or Python
numbers; arithmetic on a `Sym` appends one statement to the current trace and returns the new temporary,
so a kernel run as ``method(SHADER_OPS, symbolic_inputs, constant_params)`` writes straight-line
single-assignment code (no expression is ever copied, so reused intermediates cost nothing)::

    float t0 = clamp(cos_theta, -1.0, 1.0);
    float t1 = t0 + 0.3;
    ...
    return t5;

Operations on Python numbers only are folded in float64 (a fitted parameter clipped to its range becomes
one literal); literals are written with the shortest decimal that round-trips to the same float32.

What cannot be traced raises `Untraceable` with the reason: ``gather`` (table lookups), a Python branch
on a traced value (``if x > 0``), converting one to a number, NumPy calls on it (loops over arrays).

`shader_function` turns a kernel into a GLSL and an HLSL function (one output: ``float f(...)``; several:
``void f(..., out float o0, ...)``). The two languages differ only in ``atan2`` (GLSL ``atan(y, x)``),
``fma`` (HLSL ``mad``) and the infinity literal.

Imports only the standard library and NumPy (float32 rounding of literals).
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .arrays import OP_NAMES

__all__ = ["SHADER_OPS", "ShaderFunction", "Sym", "Untraceable", "float_literal", "shader_function"]


class Untraceable(TypeError):
    """The kernel does something a straight-line shader expression cannot (the message says what)."""


_INF = "INF"  # placeholder for +inf in statements: each language writes its own literal


def float_literal(x: float) -> str:
    """Shortest decimal literal that rounds to float32(x), always with a '.' or exponent (GLSL/HLSL float).

    +inf is the placeholder ``INF`` (replaced per language); NaN is refused."""
    x = float(x)
    if math.isnan(x):
        raise Untraceable("a NaN constant has no shader literal")
    with np.errstate(over="ignore"):
        f = np.float32(x)  # beyond float32's range: ±inf, as the kernel's float32 run would round it
    if math.isinf(f):
        return _INF if f > 0 else f"(-{_INF})"
    e = int(np.format_float_scientific(f, unique=True).split("e")[1])
    if -4 <= e <= 6:
        text = np.format_float_positional(f, unique=True, trim="0")
        return text + "0" if text.endswith(".") else text
    mant, exp = np.format_float_scientific(f, unique=True, trim="0").split("e")
    mant = mant + "0" if mant.endswith(".") else mant
    return f"{mant}e{int(exp)}"


class _Trace:
    """The statements of the function being traced, and a counter for temporaries."""

    def __init__(self):
        self.lines: list[tuple[str, str, str]] = []  # (type, name, expression)

    def emit(self, kind: str, expr: str) -> Sym:
        name = f"t{len(self.lines)}"
        self.lines.append((kind, name, expr))
        return Sym(name, self, kind)


def _atom(x) -> str:
    if isinstance(x, Sym):
        return x.name
    if isinstance(x, (bool, np.bool_)):
        return "true" if x else "false"
    if isinstance(x, (int, float, np.floating, np.integer)):
        lit = float_literal(float(x))
        return f"({lit})" if lit.startswith("-") else lit
    raise Untraceable(f"cannot trace a value of type {type(x).__name__} into a shader")


def _trace_of(args) -> _Trace | None:
    for a in args:
        if isinstance(a, Sym):
            return a.trace
    return None


class Sym:
    """A symbolic float (or bool) of the shader function being traced: arithmetic writes statements."""

    __array_ufunc__ = None  # NumPy must not treat it as an object scalar: np.float64 * Sym → Sym.__rmul__
    dtype = np.dtype(np.float32)  # kernels that size constants by dtype take the float32 branch

    def __init__(self, name: str, trace: _Trace, kind: str = "float"):
        self.name, self.trace, self.kind = name, trace, kind

    def __repr__(self):
        return f"Sym({self.name})"

    # arithmetic
    def _bin(self, op, other, reverse=False, kind="float"):
        a, b = (other, self) if reverse else (self, other)
        return self.trace.emit(kind, f"{_atom(a)} {op} {_atom(b)}")

    def __add__(self, o):
        return self._bin("+", o)

    def __radd__(self, o):
        return self._bin("+", o, True)

    def __sub__(self, o):
        return self._bin("-", o)

    def __rsub__(self, o):
        return self._bin("-", o, True)

    def __mul__(self, o):
        return self._bin("*", o)

    def __rmul__(self, o):
        return self._bin("*", o, True)

    def __truediv__(self, o):
        return self._bin("/", o)

    def __rtruediv__(self, o):
        return self._bin("/", o, True)

    def __pow__(self, o):
        return self.trace.emit("float", f"pow({_atom(self)}, {_atom(o)})")

    def __rpow__(self, o):
        return self.trace.emit("float", f"pow({_atom(o)}, {_atom(self)})")

    def __neg__(self):
        return self.trace.emit("float", f"-{_atom(self)}")

    def __pos__(self):
        return self

    def __abs__(self):
        return self.trace.emit("float", f"abs({_atom(self)})")

    # comparisons and logic
    def __lt__(self, o):
        return self._bin("<", o, kind="bool")

    def __le__(self, o):
        return self._bin("<=", o, kind="bool")

    def __gt__(self, o):
        return self._bin(">", o, kind="bool")

    def __ge__(self, o):
        return self._bin(">=", o, kind="bool")

    def __eq__(self, o):  # type: ignore[override]
        return self._bin("==", o, kind="bool")

    def __ne__(self, o):  # type: ignore[override]
        return self._bin("!=", o, kind="bool")

    __hash__ = object.__hash__

    def __and__(self, o):
        return self._bin("&&", o, kind="bool")

    __rand__ = __and__

    def __or__(self, o):
        return self._bin("||", o, kind="bool")

    __ror__ = __or__

    def __xor__(self, o):
        return self._bin("!=", o, kind="bool")

    __rxor__ = __xor__

    def __invert__(self):
        return self.trace.emit("bool", f"!{_atom(self)}")

    # what a straight-line shader cannot do
    def __bool__(self):
        raise Untraceable("the kernel branches in Python on a traced value (data-dependent control flow)")

    def __float__(self):
        raise Untraceable("the kernel converts a traced value to a Python number")

    __int__ = __index__ = __float__

    def __iter__(self):
        raise Untraceable("the kernel iterates over a traced value (an array input)")

    def __getitem__(self, _):
        raise Untraceable("the kernel indexes a traced value (an array input)")

    def __array__(self, *args, **kwargs):
        raise Untraceable("the kernel passes a traced value to NumPy (array code, not per-element)")


def _fn(name: str, folded: Callable):
    def op(*args):
        tr = _trace_of(args)
        if tr is None:  # constants only: fold in float64
            return folded(*(float(a) for a in args))
        return tr.emit("float", f"{name}({', '.join(_atom(a) for a in args)})")

    op.__name__ = name
    return op


def _select(cond, a, b):
    if not isinstance(cond, Sym):
        return a if bool(np.all(cond)) else b
    if cond.kind != "bool":
        raise Untraceable("select needs a comparison as its condition")
    kind = "bool" if all(isinstance(x, Sym) and x.kind == "bool" for x in (a, b)) else "float"
    return cond.trace.emit(kind, f"{_atom(cond)} ? {_atom(a)} : {_atom(b)}")


def _gather(table, index):
    raise Untraceable("the kernel reads a table (gather): a shader needs a buffer or texture binding")


def _clip(x, lo, hi):
    tr = _trace_of((x, lo, hi))
    if tr is None:
        return min(max(float(x), float(lo)), float(hi))
    return tr.emit("float", f"clamp({_atom(x)}, {_atom(lo)}, {_atom(hi)})")


def _expm1(x):
    raise Untraceable("expm1 has no GLSL/HLSL built-in (exp(x) − 1 loses the kernel's accuracy near 0)")


def _log1p(x):
    raise Untraceable("log1p has no GLSL/HLSL built-in (log(1 + x) loses the kernel's accuracy near 0)")


def _cbrt(x):
    tr = _trace_of((x,))
    if tr is None:
        return math.copysign(abs(float(x)) ** (1.0 / 3.0), float(x))
    return tr.emit("float", f"sign({_atom(x)}) * pow(abs({_atom(x)}), {float_literal(1.0 / 3.0)})")


def _fma(a, b, c):
    tr = _trace_of((a, b, c))
    if tr is None:
        return float(a) * float(b) + float(c)
    return tr.emit("float", f"fma({_atom(a)}, {_atom(b)}, {_atom(c)})")


SHADER_OPS = types.SimpleNamespace(
    name="shader",
    sqrt=_fn("sqrt", math.sqrt), cbrt=_cbrt, exp=_fn("exp", math.exp), log=_fn("log", math.log),
    expm1=_expm1, log1p=_log1p, power=_fn("pow", math.pow),
    sin=_fn("sin", math.sin), cos=_fn("cos", math.cos), tan=_fn("tan", math.tan), asin=_fn("asin", math.asin),
    acos=_fn("acos", math.acos), atan=_fn("atan", math.atan), atan2=_fn("atan2", math.atan2),
    tanh=_fn("tanh", math.tanh), abs=_fn("abs", abs), floor=_fn("floor", math.floor),
    ceil=_fn("ceil", math.ceil), maximum=_fn("max", max), minimum=_fn("min", min), clip=_clip, fma=_fma,
    select=_select, gather=_gather,
)  # fmt: skip
"""The tracing ops namespace (same names as `rtfit.realtime.arrays.DRJIT_OPS`): builds shader statements."""

assert set(vars(SHADER_OPS)) == {"name", *OP_NAMES}


# ------------------------------------------------------------------------------------------ functions
@dataclass(frozen=True)
class ShaderFunction:
    """A traced kernel as GLSL and HLSL function text: ``name``, argument and output names."""

    name: str
    arguments: tuple[str, ...]
    outputs: tuple[str, ...]
    glsl: str
    hlsl: str


_GLSL_INF = "uintBitsToFloat(0x7F800000u)"
_HLSL_INF = "asfloat(0x7F800000u)"


def _language(expr: str, lang: str) -> str:
    if lang == "glsl":
        return expr.replace("atan2(", "atan(").replace(_INF, _GLSL_INF)
    return expr.replace("fma(", "mad(").replace(_INF, _HLSL_INF)


def _identifier(name: str) -> str:
    out = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in name)
    return out if out and not out[0].isdigit() else f"f_{out}"


def shader_function(
    name: str,
    kernel: Callable,
    arguments: Sequence[str],
    constants: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    comment: str = "",
) -> ShaderFunction:
    """Trace ``kernel(SHADER_OPS, **{a: Sym(a)}, **constants)`` into a GLSL and an HLSL function.

    ``arguments`` become the function's ``float`` parameters; ``constants`` (fitted values) are baked in
    as literals. A kernel returning a tuple writes ``out float`` parameters named ``outputs`` (default
    ``out0``, ``out1``, …). Raises `Untraceable` (with the reason) for kernels a shader cannot express."""
    name = _identifier(name)
    tr = _Trace()
    syms = {a: Sym(_identifier(a), tr) for a in arguments}
    result = kernel(SHADER_OPS, **syms, **dict(constants or {}))
    results = list(result) if isinstance(result, (tuple, list)) else [result]
    if outputs is None:
        outputs = ("result",) if len(results) == 1 else tuple(f"out{i}" for i in range(len(results)))
    if len(outputs) != len(results):
        raise ValueError(f"kernel returns {len(results)} values, {len(outputs)} output names given")
    args = [_identifier(a) for a in arguments]
    texts = {}
    for lang in ("glsl", "hlsl"):
        body = [f"    {kind} {n} = {_language(expr, lang)};" for kind, n, expr in tr.lines]
        vals = [_language(_atom(r), lang) for r in results]
        if len(results) == 1:
            sig = f"float {name}({', '.join(f'float {a}' for a in args)})"
            body.append(f"    return {vals[0]};")
        else:
            params = [f"float {a}" for a in args] + [f"out float {_identifier(o)}" for o in outputs]
            sig = f"void {name}({', '.join(params)})"
            body += [f"    {_identifier(o)} = {v};" for o, v in zip(outputs, vals, strict=True)]
        head = [f"// {line}" for line in comment.splitlines()] if comment else []
        texts[lang] = "\n".join([*head, sig, "{", *body, "}"]) + "\n"
    return ShaderFunction(
        name, tuple(args), tuple(_identifier(o) for o in outputs), texts["glsl"], texts["hlsl"]
    )
