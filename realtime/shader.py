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

Tables (an SH sky's 27 coefficients, a shadow map's texels, a probe's cube-map chain) are *bindings*: an
input named in ``tables`` reaches the kernel as a `SymTable` (indexing it with a Python int reads
``name[k]``, ``ops.gather`` with a traced index reads ``name[int(i)]``); a sampler object named there (an
object whose methods gather from its own NumPy tables) is passed through a proxy under which each table it
gathers from becomes the binding ``name`` (the method call's string and integer arguments appended:
``chains.sample(ops, "pre", 0, like)`` reads ``chains_pre_0``; ``_1``, ``_2``, … for further tables of
one call). The function
text is then preceded by the bindings' declarations, which the engine fills with its own data (its sky, its
shadow map): at most `UNIFORM_FLOATS` floats a uniform array (GLSL ``uniform float name[N];``, HLSL a
``cbuffer``), larger ones a storage buffer (GLSL 4.30 ``buffer``, HLSL ``StructuredBuffer<float>``).

What cannot be traced raises `Untraceable` with the reason: a table gathered from that is not a binding, a
Python branch on a traced value (``if x > 0``), converting one to a number, NumPy calls on it (loops over
arrays).

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

__all__ = [
    "SHADER_OPS",
    "UNIFORM_FLOATS",
    "ShaderFunction",
    "ShaderTable",
    "Sym",
    "SymTable",
    "Untraceable",
    "float_literal",
    "shader_function",
]


class Untraceable(TypeError):
    """The kernel does something a straight-line shader expression cannot (the message says what)."""


_INF = "INF"  # placeholder for +inf in statements: each language writes its own literal


_LITERALS: dict[tuple[float, float], str] = {}
"""`float_literal`'s texts by (value, sign of zero): a kernel's constants recur (a light table's floats in
every statement that reads them: ~10⁵ literals for ibl-samples' seven depth-map shaders)."""


def float_literal(x: float) -> str:
    """Shortest decimal literal that rounds to float32(x), always with a '.' or exponent (GLSL/HLSL float).

    +inf is the placeholder ``INF`` (replaced per language); NaN is refused."""
    x = float(x)
    if math.isnan(x):
        raise Untraceable("a NaN constant has no shader literal")
    key = (x, math.copysign(1.0, x))  # −0.0 == 0.0: the sign keeps "-0.0" apart
    text = _LITERALS.get(key)
    if text is None:
        text = _LITERALS[key] = _float_literal(x)
        if len(_LITERALS) > 1 << 16:
            _LITERALS.clear()
    return text


def _float_literal(x: float) -> str:
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


UNIFORM_FLOATS = 1024
"""A table of at most this many floats is declared a uniform array (a constant buffer: 256 float4, what an
engine binds for SH coefficients), a larger one a storage buffer (a shadow map's or cube map's texels)."""


class _Trace:
    """The statements of the function being traced, a counter for temporaries, and the table bindings
    read so far (name → float count), in the order first read."""

    def __init__(self, prefix: str = "t"):
        self.prefix = prefix  # of the temporaries: t0, t1, … unless an input is named so
        self.lines: list[tuple[str, str, str]] = []  # (type, name, expression)
        self.tables: dict[str, int] = {}
        self.owned: dict[int, SymTable] = {}  # id(NumPy table of a sampler) → its binding
        self.keep: list = []  # the sampler tables themselves: their ids stay theirs while tracing
        self.owner: str | None = None  # the sampler binding whose method is running
        self.owner_tables: dict[str, int] = {}  # tables named after each sampler binding so far

    def emit(self, kind: str, expr: str) -> Sym:
        name = f"{self.prefix}{len(self.lines)}"
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


class SymTable:
    """A table binding of the shader function being traced: ``size`` floats named ``name``."""

    def __init__(self, name: str, size: int, trace: _Trace):
        self.name, self.size, self.trace = name, int(size), trace

    def __repr__(self):
        return f"SymTable({self.name}[{self.size}])"

    def __len__(self):
        return self.size

    def read(self, index) -> Sym:
        """``name[index]``: a Python int index is checked against the size; a traced one is truncated."""
        self.trace.tables.setdefault(self.name, self.size)
        if isinstance(index, Sym):
            return self.trace.emit("float", f"{self.name}[int({index.name})]")
        k = int(index)
        if not 0 <= k < self.size:
            raise Untraceable(f"the kernel reads {self.name}[{k}] outside its {self.size} floats")
        return Sym(f"{self.name}[{k}]", self.trace)

    def __getitem__(self, index):
        return self.read(index)

    def __iter__(self):
        return (self.read(k) for k in range(self.size))


class _BoundSampler:
    """A sampler object whose methods run with ``trace.owner`` set to its binding name, so that the NumPy
    tables they gather from become that binding (`_gather`)."""

    def __init__(self, obj, name: str, trace: _Trace):
        self._obj, self._name, self._trace = obj, name, trace

    def __getattr__(self, attr):
        value = getattr(self._obj, attr)
        if not callable(value):
            return value

        def bound(*args, **kwargs):
            # the call's names and indices name the table it reads (a probe's chains.sample(ops, "pre", 0,
            # like) → chains_pre_0); a nested call keeps the outer call's name
            keys = [str(a) for a in args if isinstance(a, (str, int)) and not isinstance(a, bool)]
            before = self._trace.owner
            if before is None:
                self._trace.owner = "_".join([self._name, *keys])
            try:
                out = value(*args, **kwargs)
                if isinstance(out, np.ndarray) and out.ndim:  # a table handed to the kernel to gather from
                    out = _owned_table(out, self._trace)
                return out
            except (Untraceable, TypeError, AttributeError, ValueError, IndexError) as e:
                # a sampler whose own code is not table reads (a 3-D distance-field texture sampled with
                # trilinear filtering on the array kinds it knows): say which input, and why
                kind = type(self._obj).__name__
                raise Untraceable(f"{self._name} ({kind}.{attr}) is sampled by its own code: {e}") from e
            finally:
                self._trace.owner = before

        return bound


def _owned_table(table, trace: _Trace) -> SymTable:
    key = id(table)
    if key not in trace.owned and trace.owner is not None:
        for seen, kept in zip(trace.owned.values(), trace.keep, strict=True):  # a fresh copy of a table
            if seen.name.startswith(trace.owner) and np.shape(kept) == np.shape(table):
                if np.array_equal(kept, table):
                    trace.owned[key] = seen
                    trace.keep.append(table)
                    return seen
    if key not in trace.owned:
        if trace.owner is None:
            raise Untraceable(
                "the kernel reads a table (gather) that is not a binding: name its input in `tables`"
            )
        taken = trace.owner_tables.get(trace.owner, 0)
        trace.owner_tables[trace.owner] = taken + 1
        name = trace.owner if not taken else f"{trace.owner}_{taken}"
        trace.owned[key] = SymTable(name, np.size(table), trace)
        trace.keep.append(table)
    return trace.owned[key]


def _gather(table, index):
    if isinstance(table, SymTable):
        return table.read(index)
    tr = _trace_of((index,))
    if tr is None:  # a constant table read at a constant index: folded
        return float(np.asarray(table, np.float64).reshape(-1)[int(index)])
    return _owned_table(table, tr).read(index)


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
    tables: tuple[ShaderTable, ...] = ()


@dataclass(frozen=True)
class ShaderTable:
    """A table binding the function reads: its ``name``, its size in ``floats``, and ``kind``: "uniform"
    (a uniform array / constant buffer) or "buffer" (a storage / structured buffer)."""

    name: str
    floats: int
    kind: str

    def declaration(self, lang: str) -> str:
        if self.kind == "uniform":
            if lang == "glsl":
                return f"uniform float {self.name}[{self.floats}];"
            return f"cbuffer rtfit_{self.name}_block {{ float {self.name}[{self.floats}]; }};"
        if lang == "glsl":
            return f"layout(std430) readonly buffer rtfit_{self.name}_block {{ float {self.name}[]; }};"
        return f"StructuredBuffer<float> {self.name};"


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
    tables: Mapping[str, object] | None = None,
) -> ShaderFunction:
    """Trace ``kernel(SHADER_OPS, **{a: Sym(a)}, **constants)`` into a GLSL and an HLSL function.

    ``arguments`` become the function's ``float`` parameters; ``constants`` (fitted values) are baked in
    as literals; ``tables`` (name → a NumPy array, or a sampler object gathering from its own arrays) become
    bindings declared before the function (module docstring). A kernel returning a tuple writes ``out
    float`` parameters named ``outputs`` (default ``out0``, ``out1``, …). Raises `Untraceable` (with the
    reason) for kernels a shader cannot express."""
    name = _identifier(name)
    names = [_identifier(a) for a in (*arguments, *(tables or {}))]
    prefix = "t"
    while any(n.startswith(prefix) and n[len(prefix) :].isdigit() for n in names):
        prefix = f"{prefix}_"  # an input named t0 (a march's start): the temporaries are t_0, t_1, …
    tr = _Trace(prefix)
    syms = {a: Sym(_identifier(a), tr) for a in arguments}
    bound = {}
    for key, value in (tables or {}).items():
        if isinstance(value, (np.ndarray, list, tuple)):
            bound[key] = SymTable(_identifier(key), np.size(value), tr)
        else:
            bound[key] = _BoundSampler(value, _identifier(key), tr)
    result = kernel(SHADER_OPS, **syms, **bound, **dict(constants or {}))
    results = list(result) if isinstance(result, (tuple, list)) else [result]
    if outputs is None:
        outputs = ("result",) if len(results) == 1 else tuple(f"out{i}" for i in range(len(results)))
    if len(outputs) != len(results):
        raise ValueError(f"kernel returns {len(results)} values, {len(outputs)} output names given")
    args = [_identifier(a) for a in arguments]
    used = tuple(
        ShaderTable(n, size, "uniform" if size <= UNIFORM_FLOATS else "buffer")
        for n, size in tr.tables.items()
    )
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
        head += [b.declaration(lang) for b in used]
        texts[lang] = "\n".join([*head, sig, "{", *body, "}"]) + "\n"
    return ShaderFunction(
        name, tuple(args), tuple(_identifier(o) for o in outputs), texts["glsl"], texts["hlsl"], used
    )
