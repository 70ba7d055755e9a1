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
_DECLARATIONS = ("uniform ", "layout(", "cbuffer ", "StructuredBuffer<")
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
    expr = re.sub(r"\bint\(", "I(", expr)  # a table read at a computed index: name[int(t3)]
    return _NUMBER.sub(r"F(\1)", expr)


def compile_function(text: str):
    """A Python callable from one emitted function: ``f(*arrays) -> array or tuple of arrays``."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("//")]
    lines = [ln for ln in lines if not ln.startswith(_DECLARATIONS)]  # the table bindings
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

    def run(*args, tables=None):
        env = {"F": F32, "INF": F32(np.inf), "where": np.where, "I": lambda a: np.asarray(a).astype(np.int64)}
        env.update(_FUNCS)
        env.update({n: np.asarray(a, F32) for n, a in zip(ins, args, strict=True)})
        env.update({n: np.asarray(a, F32) for n, a in (tables or {}).items()})
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
    # memoised texts keep the sign of zero (−0.0 == 0.0 as a key) and NaN stays refused on every call
    assert [float_literal(0.0), float_literal(-0.0), float_literal(0.0)] == ["0.0", "-0.0", "0.0"]
    for _ in range(2):
        with pytest.raises(Untraceable, match="NaN"):
            float_literal(math.nan)


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


def test_temporaries_never_take_an_input_name():
    """An input named like a temporary (a march's ``t0``) keeps its name; the temporaries move aside."""
    fn = shader_function("f", lambda ops, t0, t1: ops.sqrt(t0 * t1) + t0, ["t0", "t1"])
    got = compile_function(fn.glsl)(np.array([4.0], F32), np.array([9.0], F32))
    assert got[0] == 10.0 and "float t_0 = t0 * t1;" in fn.glsl


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


# ------------------------------------------------------------------------------- table bindings
def _shadow_map_case(rng, n):
    """A 6 × 5 shadow map of random depths and receivers around it (some outside the map)."""
    from rtfit.realtime.pcf_soft_shadows import FAR, ShadowMap

    sm = ShadowMap(rng.uniform(0.5, 2.0, (5, 6)), light_size=0.2, near=0.1)
    inputs = {
        "irradiance": rng.uniform(0.0, 5.0, n),
        "u": rng.uniform(-0.2, 1.2, n),
        "v": rng.uniform(-0.2, 1.2, n),
        "depth": rng.uniform(0.4, 2.2, n),
        "rotation": rng.uniform(0.0, 2 * math.pi, n),
    }
    flat = np.append(sm.depth.reshape(-1), FAR)  # the layout the docs state: rows, then the border depth
    return sm, {k: v.astype(F32) for k, v in inputs.items()}, flat


@pytest.mark.parametrize("method_id", ["hard", "poisson8-rotated", "pcss"])
def test_a_shadow_map_is_a_buffer_binding_and_the_text_reads_it_as_the_kernel_does(method_id):
    """pcf-soft-shadows' kernels read the map through its object (nearest texel, bilinear compares): the
    text declares one binding ``shadow_map`` of W·H + 1 floats and, fed the same depths, computes what the
    kernel's NumPy runs compute, to float32 precision."""
    from rtfit.realtime.pcf_soft_shadows import METHODS

    method = METHODS[method_id]
    rng = np.random.default_rng(7)
    sm, inputs, flat = _shadow_map_case(rng, 3000)
    names = [n for n in method.input_names if n != "shadow_map"]
    params = method.defaults()
    fn = shader_function("f", method.kernel, names, method.keywords(params), tables={"shadow_map": sm})
    assert [(b.name, b.floats, b.kind) for b in fn.tables] == [("shadow_map", 31, "uniform")]
    assert fn.glsl.startswith("uniform float shadow_map[31];")
    got = compile_function(fn.glsl)(*(inputs[n] for n in names), tables={"shadow_map": flat})
    own = method(NUMPY_OPS, {**inputs, "shadow_map": sm}, {k: F32(v) for k, v in params.items()})
    want = method(
        NUMPY_OPS, {**{k: v.astype(np.float64) for k, v in inputs.items()}, "shadow_map": sm}, params
    )
    # the NumPy run reads the map's depths in float64 (its table), the text in float32: equal to float32
    # rounding of the weights (measured ≤ 2.2e-5 relative), the depth tests the same on these receivers
    np.testing.assert_allclose(got, np.asarray(own, F32), rtol=1e-4, atol=1e-6)
    assert 0 < np.mean(np.asarray(want) > 0) < 1  # lit and shadowed receivers both present
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5 * float(np.max(np.abs(want))))


def test_sh_coefficients_are_a_uniform_array_read_at_fixed_indices():
    """sh-sky-bent-normal reads its 27 coefficients at fixed indices: ``coeffs[k]`` of a uniform array; the
    text fed a random sky equals the kernel's float32 run, and a changed sky changes the result (nothing of
    the tracing-time table was baked in)."""
    from rtfit.realtime.sh_sky_bent_normal import METHODS

    method = METHODS["seed-radiance-bent"]
    rng = np.random.default_rng(9)
    names = [n for n in method.input_names if n != "coeffs"]
    inputs = {n: rng.uniform(-1.0, 1.0, 500).astype(F32) for n in ("bx", "by", "bz")}
    inputs["ao"] = rng.uniform(0.0, 1.0, 500).astype(F32)
    fn = shader_function(
        "f", method.kernel, names, method.keywords(method.defaults()), tables={"coeffs": np.zeros(27)}
    )
    assert "uniform float coeffs[27];" in fn.glsl and "float coeffs[27]; };" in fn.hlsl
    assert "coeffs[int(" not in fn.glsl  # fixed indices only
    for sky in (rng.uniform(0.0, 2.0, 27), rng.uniform(0.0, 2.0, 27)):
        got = compile_function(fn.glsl)(*(inputs[n] for n in names), tables={"coeffs": sky})
        own = method(
            NUMPY_OPS,
            {**inputs, "coeffs": sky.astype(F32)},
            {k: F32(v) for k, v in method.defaults().items()},
        )
        for g, o in zip(got, own, strict=True):
            np.testing.assert_array_equal(g, np.asarray(o, F32))


def test_a_sampler_returning_its_tables_names_each_after_the_call():
    """A sampler handing its tables to the kernel (probe chains: ``sample(ops, "pre", channel, like)``) gets
    one binding per table named after the call; over `UNIFORM_FLOATS` floats a storage buffer."""
    from rtfit.realtime.shader import UNIFORM_FLOATS

    class Chains:
        def sample(self, ops, name, channel, like):
            return np.arange(2000.0) if name == "pre" else np.arange(8.0) + channel

    def kernel(ops, i, chains):
        return ops.gather(chains.sample(ops, "pre", 1, i), i) + ops.gather(
            chains.sample(ops, "irr", 1, i), 3.0
        )

    fn = shader_function("f", kernel, ["i"], tables={"chains": Chains()})
    assert [(b.name, b.floats, b.kind) for b in fn.tables] == [
        ("chains_pre_1", 2000, "buffer"),
        ("chains_irr_1", 8, "uniform"),
    ]
    assert 2000 > UNIFORM_FLOATS >= 8
    assert "layout(std430) readonly buffer rtfit_chains_pre_1_block { float chains_pre_1[]; };" in fn.glsl
    assert "StructuredBuffer<float> chains_pre_1;" in fn.hlsl
    got = compile_function(fn.glsl)(
        np.array([5.0, 7.0], F32),
        tables={"chains_pre_1": np.arange(2000.0), "chains_irr_1": np.arange(8.0) + 1},
    )
    np.testing.assert_array_equal(got, [9.0, 11.0])
    with pytest.raises(Untraceable, match="outside its 8 floats"):
        shader_function("g", lambda ops, t: t[8], [], tables={"t": np.zeros(8)})


@pytest.mark.skipif(
    GLSLANG is None, reason="glslangValidator not installed (Debian: apt-get install glslang-tools)"
)
def test_table_bindings_compile_with_glslang(tmp_path):
    """A uniform array and a storage buffer read at fixed and computed indices: GLSL 4.50 and HLSL (SPIR-V)
    both compile."""
    from rtfit.realtime.pcf_soft_shadows import METHODS

    def kernel(ops, i, small, big):
        return ops.gather(big, i * 2.0) + small[3] * ops.gather(small, i)

    fn = shader_function("f", kernel, ["i"], tables={"small": np.zeros(27), "big": np.zeros(5000)})
    pcf = METHODS["poisson8-rotated"]
    rng = np.random.default_rng(1)
    sm, _, _ = _shadow_map_case(rng, 4)
    names = [n for n in pcf.input_names if n != "shadow_map"]
    fp = shader_function("g", pcf.kernel, names, pcf.keywords(pcf.defaults()), tables={"shadow_map": sm})
    frag = tmp_path / "f.frag"
    call = f"float w = g({', '.join(['0.5'] * len(names))});"
    frag.write_text(
        f"#version 450\n{fn.glsl}\n{fp.glsl}\nlayout(location = 0) out vec4 colour;\n"
        f"void main() {{ float v = f(0.5); {call} colour = vec4(v + w); }}\n"
    )
    r = subprocess.run([GLSLANG, str(frag)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    hlsl = tmp_path / "f.hlsl"
    hlsl.write_text(
        f"{fn.hlsl}\n{fp.hlsl}\n"
        f"float4 main() : SV_Target {{ float v = f(0.5); {call} return float4(v + w, 0, 0, 1); }}\n"
    )
    r = subprocess.run(
        [GLSLANG, "-V", "-D", "-e", "main", "-S", "frag", "-o", str(tmp_path / "h.spv"), str(hlsl)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stdout + r.stderr
