"""GLSL/HLSL traced from the kernels (rtfit.realtime.shader): the text's arithmetic against the kernels.

The generated shader text is evaluated by a small translator (GLSL/HLSL statement subset → NumPy float32,
tested on its own below) and compared with the NumPy run of the same kernel in float64 on random inputs:
agreement to float32 precision. Where glslangValidator (Debian: glslang-tools) is installed, the GLSL
and HLSL functions are also compiled.
"""

from __future__ import annotations

import math
import re
import shutil
import subprocess

import numpy as np
import pytest

from rtfit.realtime import NUMPY_OPS, SHADER_OPS, Untraceable, float_literal, shader_function
from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.realtime.height_fog import METHODS as FOG

F32 = np.float32


# ------------------------------------------------------------------------------- the translator
def _atan(y, x=None):
    return np.arctan(y) if x is None else np.arctan2(y, x)


_FUNCS = {
    "clamp": lambda x, lo, hi: np.minimum(np.maximum(x, lo), hi),
    "mix": lambda a, b, t: a + (b - a) * t,
    "pow": np.power,
    "max": np.maximum,
    "min": np.minimum,
    "exp": np.exp,
    "log": np.log,
    "sqrt": np.sqrt,
    "abs": np.abs,
    "floor": np.floor,
    "ceil": np.ceil,
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "asin": np.arcsin,
    "acos": np.arccos,
    "atan": _atan,
    "atan2": np.arctan2,
    "tanh": np.tanh,
    "sign": np.sign,
    "fma": lambda a, b, c: a * b + c,
    "mad": lambda a, b, c: a * b + c,
}
_NUMBER = re.compile(r"(?<![\w.])(\d+\.\d*(?:e[+-]?\d+)?|\d+e[+-]?\d+)")
_TERNARY = re.compile(r"^(\w+) \? (.+) : (.+)$")


def python_expression(expr: str) -> str:
    """One GLSL/HLSL right-hand side of the emitted subset as a Python expression over float32."""
    expr = expr.replace("uintBitsToFloat(0x7F800000u)", "INF").replace("asfloat(0x7F800000u)", "INF")
    m = _TERNARY.match(expr)
    if m:
        return f"where({m.group(1)}, {python_expression(m.group(2))}, {python_expression(m.group(3))})"
    expr = expr.replace("&&", "&").replace("||", "|")
    expr = re.sub(r"!(?!=)", "~", expr)
    expr = expr.replace("true", "True").replace("false", "False")
    return _NUMBER.sub(r"F(\1)", expr)


def compile_function(text: str):
    """A Python callable from one emitted function: ``f(*arrays) -> array or tuple of arrays``."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("//")]
    sig = re.match(r"^(float|void) (\w+)\((.*)\)$", lines[0])
    assert sig, lines[0]
    params = [p.strip().split() for p in sig.group(3).split(",") if p.strip()]
    ins = [p[-1] for p in params if p[0] != "out"]
    outs = [p[-1] for p in params if p[0] == "out"]
    assert lines[1] == "{" and lines[-1] == "}"
    body = []
    for ln in lines[2:-1]:
        assert ln.endswith(";"), ln
        ln = ln[:-1]
        if m := re.match(r"^(?:float|bool) (\w+) = (.+)$", ln):
            body.append(f"{m.group(1)} = {python_expression(m.group(2))}")
        elif m := re.match(r"^return (.+)$", ln):
            body.append(f"__out = {python_expression(m.group(1))}")
        elif m := re.match(r"^(\w+) = (.+)$", ln):
            body.append(f"{m.group(1)} = {python_expression(m.group(2))}")
        else:
            raise AssertionError(f"statement outside the subset: {ln}")
    code = compile("\n".join(body), "<shader>", "exec")

    def run(*args):
        env = {"F": F32, "INF": F32(np.inf), "where": np.where, **_FUNCS}
        env.update({n: np.asarray(a, F32) for n, a in zip(ins, args, strict=True)})
        with np.errstate(all="ignore"):
            exec(code, env)
        if outs:
            return tuple(np.asarray(env[o], F32) for o in outs)
        return np.asarray(env["__out"], F32)

    return run


def test_translator_on_hand_written_glsl():
    text = """float f(float x, float y)
{
    float t0 = clamp(x, (-1.0), 1.0);
    bool t1 = t0 > 0.5;
    bool t2 = !t1;
    float t3 = t2 ? t0 : 2.5e-1;
    float t4 = fma(t3, y, 1.0);
    float t5 = pow(abs(t4), 2.0);
    float t6 = atan(t5, 2.0);
    return t6;
}"""
    x = np.array([-3.0, 0.25, 0.75], F32)
    y = np.array([2.0, 4.0, 1.0], F32)
    t0 = np.clip(x, -1, 1)
    t3 = np.where(t0 > 0.5, 0.25, t0)
    want = np.arctan2(np.abs(t3 * y + 1) ** 2, 2.0)
    got = compile_function(text)(x, y)
    assert got.dtype == F32
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_float_literals_round_trip_in_float32():
    rng = np.random.default_rng(3)
    values = [0.0, 1.0, -1.0, 0.5, 1e-30, 3.4e38, math.pi, 1 / 3, 176.0, *rng.normal(0, 1e3, 50)]
    for v in values:
        lit = float_literal(v)
        assert "." in lit or "e" in lit, lit
        assert F32(float(lit.strip("()"))) == F32(v), (v, lit)
    assert float_literal(math.inf) == "INF"
    assert float_literal(1e39) == "INF" and float_literal(-1e39) == "(-INF)"  # beyond float32: rounds to inf
    assert float_literal(0.5) == "0.5" and float_literal(1.0) == "1.0" and float_literal(1e-30) == "1.0e-30"


# ------------------------------------------------------------------------------- tracing rules
def test_untraceable_kernels_say_why():
    def branchy(ops, x):
        return x if x > 0 else -x

    def table(ops, x):
        return ops.gather([1.0, 2.0], x)

    with pytest.raises(Untraceable, match="branches in Python"):
        shader_function("f", branchy, ["x"])
    with pytest.raises(Untraceable, match="gather"):
        shader_function("f", table, ["x"])
    with pytest.raises(Untraceable, match="expm1"):
        shader_function("f", lambda ops, x: ops.expm1(x), ["x"])


def test_constants_fold_and_every_op_is_defined():
    assert SHADER_OPS.clip(2.0, 0.0, 1.0) == 1.0  # parameters clipped to their range become literals
    fn = shader_function("f", lambda ops, x, k: x * ops.maximum(k, 0.0), ["x"], {"k": -3.0})
    assert "t0 = x * 0.0;" in fn.glsl
    assert "atan(" in shader_function("g", lambda ops, x: ops.atan2(x, 1.0), ["x"]).glsl
    assert "atan2(" in shader_function("g", lambda ops, x: ops.atan2(x, 1.0), ["x"]).hlsl
    assert "mad(" in shader_function("g", lambda ops, x: ops.fma(x, 2.0, 1.0), ["x"]).hlsl


# ------------------------------------------------------------------------------- against the kernels
def _inputs(rng, n, names):
    draw = {
        "cos_theta": lambda: rng.uniform(-1.0, 1.0, n),
        "irradiance": lambda: rng.uniform(0.0, 10.0, n),
        "alpha": lambda: rng.uniform(0.0, 0.5 * math.pi, n),
        "radiance": lambda: rng.uniform(0.0, 10.0, n),
        "z0": lambda: rng.uniform(-50.0, 500.0, n),
        "z1": lambda: rng.uniform(-50.0, 500.0, n),
        "cos_sun": lambda: rng.uniform(-1.0, 1.0, n),
    }
    out = {k: draw[k]() for k in names if k in draw}
    for ch in "rgb":
        if f"l0_{ch}" in names:
            out[f"l0_{ch}"] = rng.uniform(0.0, 2.0, n)
    if "distance" in names:  # a segment: D ≥ |z1 − z0|
        out["distance"] = np.abs(out["z1"] - out["z0"]) * rng.uniform(1.0, 20.0, n)
    return {k: v.astype(F32) for k, v in out.items()}  # float32-representable inputs


CASES = [
    (DIFFUSE["wrap"], {"w": 0.3127, "p": 1.4421}),
    (DIFFUSE["wrap"], {"w": 0.0, "p": 1.0}),
    (DIFFUSE["exact"], {}),
    (FOG["exact"], {"b": 2.3e-3, "c": 3.7e-3}),
    (FOG["const"], {"b": 1.1e-3, "c": 6.1e-3, "r0": 0.3, "g0": 0.4, "b0": 0.55}),
    (
        FOG["phase"],
        {
            "b": 1.1e-3,
            "c": 6.1e-3,
            "r0": 0.3,
            "g0": 0.4,
            "b0": 0.55,
            "r1": 0.05,
            "g1": 0.04,
            "b1": 0.02,
            "g": 0.7,
        },
    ),
]


@pytest.mark.parametrize("method, params", CASES, ids=[f"{m.id}-{i}" for i, (m, _) in enumerate(CASES)])
@pytest.mark.parametrize("lang", ["glsl", "hlsl"])
def test_shader_text_agrees_with_the_kernel_to_float32_precision(method, params, lang):
    rng = np.random.default_rng(16)
    inputs = _inputs(rng, 4000, method.input_names)
    fn = shader_function(f"rtfit_{method.id}", method.kernel, method.input_names, method.keywords(params))
    got = compile_function(getattr(fn, lang))(*(inputs[n] for n in method.input_names))
    want = method(NUMPY_OPS, {k: v.astype(np.float64) for k, v in inputs.items()}, params)
    own = method(NUMPY_OPS, inputs, {k: F32(v) for k, v in params.items()})  # the kernel run in float32
    got, want, own = ((x if isinstance(x, tuple) else (x,)) for x in (got, want, own))
    assert len(got) == len(want) == len(own)
    for g, w, o in zip(got, want, own, strict=True):
        w = np.broadcast_to(np.asarray(w, np.float64), g.shape)
        o = np.broadcast_to(np.asarray(o, np.float64), g.shape)
        scale = max(float(np.max(np.abs(w))), 1e-30)
        err = np.abs(g.astype(np.float64) - w)
        # float32 precision: a few ulp (2^-23 ≈ 1.2e-7) of the value, or of the output's scale where a
        # difference of nearly equal terms ends near 0, or no worse than the kernel's own float32 run
        # (ill-conditioned spots: the horizon-clipped sphere light near cos θ = ±sin α)
        ulp = 2.0**-23 * np.maximum(np.abs(w), 1e-3 * scale)
        tol = 8 * ulp + 4 * np.abs(o - w)
        bad = err > tol
        assert not bad.any(), (
            f"{lang} {method.id}: {int(bad.sum())} of {g.size} values differ beyond float32 precision, "
            f"worst {float(np.max(err / ulp)):.3g} ulp"
        )
        assert float(np.max(err / ulp)) < 64 or method.id == "exact", float(np.max(err / ulp))
        # the text is the kernel: the same float32 operations in the same order as its NumPy float32 run
        np.testing.assert_array_equal(g, np.asarray(o, F32))


GLSLANG = shutil.which("glslangValidator")


@pytest.mark.skipif(
    GLSLANG is None, reason="glslangValidator not installed (Debian: apt-get install glslang-tools)"
)
@pytest.mark.parametrize(
    "method, params", CASES[:1] + CASES[3:], ids=["wrap", "fog-exact", "fog-const", "fog-phase"]
)
def test_shader_text_compiles_with_glslang(method, params, tmp_path):
    fn = shader_function(f"rtfit_{method.id}", method.kernel, method.input_names, method.keywords(params))
    n_in, n_out = len(fn.arguments), len(fn.outputs)
    args = ", ".join(["0.5"] * n_in)
    if n_out == 1:
        call_glsl, call_hlsl = f"float v = {fn.name}({args});", f"float v = {fn.name}({args});"
        use = "v"
    else:
        outs = ", ".join(f"o{i}" for i in range(n_out))
        decl = f"float {outs};"
        call_glsl = call_hlsl = f"{decl} {fn.name}({args}, {outs});"
        use = " + ".join(f"o{i}" for i in range(n_out))
    frag = tmp_path / "f.frag"
    frag.write_text(
        f"#version 450\n{fn.glsl}\nlayout(location = 0) out vec4 colour;\n"
        f"void main() {{ {call_glsl} colour = vec4({use}); }}\n"
    )
    r = subprocess.run([GLSLANG, str(frag)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    hlsl = tmp_path / "f.hlsl"
    hlsl.write_text(
        f"{fn.hlsl}\nfloat4 main() : SV_Target {{ {call_hlsl} return float4({use}, {use}, {use}, 1.0); }}\n"
    )
    r = subprocess.run(
        [GLSLANG, "-V", "-D", "-e", "main", "-S", "frag", "-o", str(tmp_path / "h.spv"), str(hlsl)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stdout + r.stderr
