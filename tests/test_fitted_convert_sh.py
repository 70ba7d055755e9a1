"""``rtfit fitted convert --engine unity-hdrp`` on SH irradiance fits (issue 37 §3,
`rtfit.experiments.engine_presets_sh`): rtfit's SH L2 in Unity's SphericalHarmonicsL2 layout.

Independent values: Sloan's appendix-A10 constants fC0…fC4 in closed form (Unity's documented
reconstruction); Unity's ShadeSH9 polynomial (the seven float4 of UnityCG) evaluated with the converted
coefficients, ×π, against rtfit's kernel (`realtime.irradiance_bases.METHODS`) in float64 and float32; a
constant sky (ShadeSH9 = L, i.e. E/π = L) and a light straight up (in Unity's +Y-up frame only the y entry
of band 1 is set; E at the light = 1/4 + 1/2 + 5/16 for unit irradiance, Ramamoorthi & Hanrahan)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.cli import cli
from rtfit.experiments.engine_presets_sh import (
    GODOT_AXES,
    GODOT_C,
    UNITY_AXES,
    UNREAL_AXES,
    UNREAL_BASIS,
    godot_capture_irradiance,
    rtfit_to_unity_sh,
    sh_from_engine,
    sh_to_engine,
    unity_sh_constants,
    unity_sh_factors,
    unity_shade_sh9,
    unity_to_rtfit_sh,
    unreal_diffuse_sh3,
)
from rtfit.experiments.fitted import FittedFile, Provenance, method_entry, write_fitted
from rtfit.realtime.irradiance_bases import (
    METHODS,
    basis_irradiance,
    sh9_from_directional,
    sh_from_constant,
    sh_window,
)

EPS32 = float(np.finfo(np.float32).eps)


def _normals(n=500, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_unity_constants_are_sloans_a10_constants():
    rp = math.sqrt(math.pi)
    c0, c1, c2, c3 = 1 / (2 * rp), math.sqrt(3) / (3 * rp), math.sqrt(15) / (8 * rp), math.sqrt(5) / (16 * rp)
    c4 = 0.5 * c2
    np.testing.assert_allclose(unity_sh_factors(), [c0, c1, c1, c1, c2, c2, c3, c2, c4], rtol=1e-15)


@pytest.mark.parametrize("lam", [0.0, 1e-3, 0.05])
def test_unitys_shader_with_the_converted_coefficients_is_rtfits_kernel(lam):
    rng = np.random.default_rng(1)
    coeffs = rng.normal(size=(9, 3)) * [1.0, 0.5, 0.3]
    coeffs[0] = np.abs(coeffs[0]) + 2.0
    n = _normals()
    kernel = basis_irradiance("sh-l2-lambda", coeffs, n, {"lam": lam})
    consts = unity_sh_constants(rtfit_to_unity_sh(coeffs, sh_window("lambda", 2, lam)))
    n_unity = n @ UNITY_AXES.T
    e64 = math.pi * unity_shade_sh9(consts, n_unity, dtype=np.float64)
    np.testing.assert_allclose(e64, kernel, rtol=0, atol=1e-12 * np.abs(kernel).max())
    # float32, as the shader runs: within a few ulps of the sum of the terms' magnitudes
    e32 = math.pi * unity_shade_sh9(consts.astype(np.float32), n_unity.astype(np.float32))
    bound = 16 * EPS32 * math.pi * (np.abs(consts).sum() + 1.0)
    assert np.abs(e32 - kernel).max() < bound


def test_a_constant_sky_and_a_light_overhead_in_unitys_terms():
    sh = rtfit_to_unity_sh(sh_from_constant([0.7, 0.5, 0.2]))
    np.testing.assert_allclose(sh[:, 0], [0.7, 0.5, 0.2], rtol=1e-14)  # the DC entry is the radiance L
    np.testing.assert_allclose(sh[:, 1:], 0.0, atol=1e-15)
    consts = unity_sh_constants(sh)
    np.testing.assert_allclose(
        unity_shade_sh9(consts, _normals(20), np.float64), np.tile([0.7, 0.5, 0.2], (20, 1)), rtol=1e-14
    )
    # unit irradiance from rtfit's +z (up): Unity's +y. Band 1 holds y only; E(up) = 1/4 + 1/2 + 5/16.
    grey = np.repeat(sh9_from_directional([0.0, 0.0, 1.0])[:, None], 3, axis=1)
    sh = rtfit_to_unity_sh(grey)
    assert sh[0, 1] > 0 and abs(sh[0, 2]) < 1e-15 and abs(sh[0, 3]) < 1e-15
    up = unity_shade_sh9(unity_sh_constants(sh), [0.0, 1.0, 0.0], np.float64)
    np.testing.assert_allclose(math.pi * up, (0.25 + 0.5 + 5 / 16), rtol=1e-14)


def test_round_trip_and_the_stored_layout():
    coeffs = np.random.default_rng(2).normal(size=(9, 3))
    w = sh_window("hann", 2)
    sh = rtfit_to_unity_sh(coeffs, w)
    np.testing.assert_allclose(unity_to_rtfit_sh(sh, w), coeffs, rtol=0, atol=1e-13)
    stored = coeffs.T.reshape(-1)  # the 27 floats of rtfit's coeffs table, channel-major
    np.testing.assert_array_equal(rtfit_to_unity_sh(stored, w), sh)


def test_convert_command_on_an_sh_lambda_file(tmp_path):
    """An irradiance-bases file with sh-l2-lambda (λ fitted) and sh-l4-lambda: the Unity preset's band scale
    is the λ window, its matrix applied to any L and packed as Unity packs it gives rtfit's kernel; L4 names
    its dropped band; the same for Godot's and Unreal's presets with their shaders (their own literals)."""
    lam = 0.02
    entries = [
        method_entry(METHODS[mid], params={"lam": lam}, case="sky", domain={}) for mid in ("sh-l2-lambda",)
    ] + [method_entry(METHODS["sh-l4-lambda"], params={"lam": lam}, case="sky", domain={})]
    doc = FittedFile(
        format="rtfit.fitted/1",
        title="irradiance bases (test)",
        provenance=Provenance(
            rtfit_version="0", experiment="irradiance-bases", date="2026-12-05T00:00:00+00:00"
        ),
        methods=entries,
    )
    path = tmp_path / "ib.json"
    write_fitted(path, doc)
    out = CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", "unity-hdrp"])
    assert out.exit_code == 0, out.output
    l2, l4 = json.loads(out.stdout)["presets"]
    assert l2["method"] == "sh-l2-lambda" and l2["fitted"] == {"lam": lam}
    values = {v["name"]: v["value"] for v in l2["values"]}
    w = sh_window("lambda", 2, lam)
    np.testing.assert_allclose(values["SphericalHarmonicsL2 band scale"], w[[0, 1, 1, 1, 2, 2, 2, 2, 2]])
    (matrix,) = [np.array(v) for k, v in values.items() if k.startswith("rtfit L_lm")]
    coeffs = np.random.default_rng(3).normal(size=(9, 3))
    n = _normals(50)
    e = math.pi * unity_shade_sh9(unity_sh_constants((matrix @ coeffs).T), n @ UNITY_AXES.T, np.float64)
    np.testing.assert_allclose(e, basis_irradiance("sh-l2-lambda", coeffs, n, {"lam": lam}), atol=1e-12)
    assert any("L4's band" in line for line in l4["lost"]) and any("π" in line for line in l2["lost"])
    for engine, axes, shade in (
        ("godot", GODOT_AXES, godot_capture_irradiance),
        ("unreal", UNREAL_AXES, unreal_diffuse_sh3),
    ):
        out = CliRunner().invoke(cli, ["fitted", "convert", str(path), "--engine", engine])
        assert out.exit_code == 0, out.output
        l2, l4 = json.loads(out.stdout)["presets"]
        (matrix,) = [np.array(v["value"]) for v in l2["values"] if v["name"].startswith("rtfit L_lm")]
        e = math.pi * shade((matrix @ coeffs).T, n @ axes.T, np.float64)
        kernel = basis_irradiance("sh-l2-lambda", coeffs, n, {"lam": lam})
        ok = kernel > 0 if engine == "unreal" else np.ones_like(kernel, bool)  # Unreal clamps at 0
        np.testing.assert_allclose(e[ok], kernel[ok], atol=2e-6 * math.pi * np.abs(matrix @ coeffs).sum())
        assert any("L4's band" in line for line in l4["lost"])


# ------------------------------------------------------------------------------ Godot's and Unreal's layouts
RP = math.sqrt(math.pi)
# Sloan's / Ramamoorthi–Hanrahan's constants in closed form: the basis N_k and eq. 13's c1…c5 (c = Â_l·N_k)
BASIS = (1 / (2 * RP), math.sqrt(3) / (2 * RP), math.sqrt(15) / (2 * RP), math.sqrt(5) / (4 * RP),
         math.sqrt(15) / (4 * RP))  # fmt: skip
RH_C = (math.pi / 4 * BASIS[4], math.pi / 3 * BASIS[1], 3 * math.pi / 4 * BASIS[3], math.pi * BASIS[0],
        math.pi / 4 * BASIS[3])  # fmt: skip
SHADERS = {"godot": (GODOT_AXES, godot_capture_irradiance, GODOT_C, RH_C),
           "unreal": (UNREAL_AXES, unreal_diffuse_sh3, UNREAL_BASIS, BASIS)}  # fmt: skip


def test_engine_literals_are_the_closed_forms():
    """Godot's c1…c5 (Ramamoorthi and Hanrahan's published 6-digit values: c2 and c3 are 1.5e-6 off in
    relative terms) and Unreal's basis constants, as their shaders write them, against the closed forms."""
    np.testing.assert_allclose(GODOT_C, RH_C, rtol=2e-6)
    np.testing.assert_allclose(UNREAL_BASIS, BASIS, rtol=2e-6)


@pytest.mark.parametrize("engine", ["godot", "unreal"])
@pytest.mark.parametrize("lam", [0.0, 1e-3, 0.05])
def test_engine_shader_with_the_converted_coefficients_is_rtfits_kernel(engine, lam):
    """The engine's evaluation (written from its source) with the converted coefficients, ×π: with the
    closed-form constants rtfit's kernel to float64 round-off; with the engine's own literals within their
    rounding (2e-6 relative per term); in float32 within a few ulps of the terms' magnitudes on top."""
    axes, shade, literals, exact = SHADERS[engine]
    rng = np.random.default_rng(4)
    coeffs = rng.normal(size=(9, 3)) * [1.0, 0.5, 0.3]
    coeffs[0] = np.abs(coeffs[0]) + 3.0
    n = _normals()
    kernel = basis_irradiance("sh-l2-lambda", coeffs, n, {"lam": lam})
    assert kernel.min() > 0  # Unreal's max(0, ·) is then the identity
    sh = sh_to_engine(engine, coeffs, sh_window("lambda", 2, lam))
    n_engine = n @ axes.T
    e64 = math.pi * shade(sh, n_engine, np.float64, exact)
    np.testing.assert_allclose(e64, kernel, rtol=0, atol=1e-12 * np.abs(kernel).max())
    terms = math.pi * 2.0 * np.abs(sh).sum(axis=1).max()  # Σ|sh_k|·max|basis·Â| bounds every term's sum
    lit = math.pi * shade(sh, n_engine, np.float64, literals)
    assert np.abs(lit - kernel).max() < 2e-6 * terms
    e32 = math.pi * shade(sh.astype(np.float32), n_engine.astype(np.float32), np.float32, literals)
    assert np.abs(e32 - kernel).max() < 2e-6 * terms + 16 * EPS32 * terms


@pytest.mark.parametrize("engine", ["godot", "unreal"])
def test_constant_sky_light_overhead_and_round_trip(engine):
    """A constant sky of radiance L: every normal gets E/π = L; unit irradiance from rtfit's +z (Godot's +y,
    Unreal's +z): E at that normal = 1/4 + 1/2 + 5/16 (Ramamoorthi & Hanrahan), and only that axis' band-1
    entry is set (Godot index 1: y; Unreal index 2: z); converting and back is the identity."""
    axes, shade, _, exact = SHADERS[engine]
    sh = sh_to_engine(engine, sh_from_constant([0.7, 0.5, 0.2]))
    np.testing.assert_allclose(shade(sh, _normals(20), np.float64, exact), np.tile([0.7, 0.5, 0.2], (20, 1)),
                               rtol=1e-14)  # fmt: skip
    grey = np.repeat(sh9_from_directional([0.0, 0.0, 1.0])[:, None], 3, axis=1)
    sh = sh_to_engine(engine, grey)
    up = axes @ [0.0, 0.0, 1.0]
    axis = 1 if engine == "godot" else 2
    assert sh[0, axis] > 0 and all(abs(sh[0, k]) < 1e-15 for k in (1, 2, 3) if k != axis)
    np.testing.assert_allclose(math.pi * shade(sh, up, np.float64, exact), 0.25 + 0.5 + 5 / 16, rtol=1e-14)
    coeffs = np.random.default_rng(5).normal(size=(9, 3))
    w = sh_window("hann", 2)
    np.testing.assert_allclose(sh_from_engine(engine, sh_to_engine(engine, coeffs, w), w), coeffs, atol=1e-13)
    np.testing.assert_array_equal(
        sh_to_engine(engine, coeffs.T.reshape(-1), w), sh_to_engine(engine, coeffs, w)
    )
