r"""SH L2 irradiance in Unity's coefficient layout (issue 37 §3): ``rtfit fitted convert --engine unity-hdrp``
on the irradiance-bases fitted files (``sh-l2-lambda`` and the other ``sh-l*`` windows).

rtfit's SH (`rtfit.realtime.irradiance_bases`): radiance coefficients L_lm = ∫ L Y_lm dω of the real basis
*without* the Condon–Shortley phase, index k = l(l + 1) + m, 27 floats channel-major (R, G, B), world frame
+Z up (right-handed); irradiance E(n) = Σ_l Â_l w_l Σ_m L_lm Y_lm(n), Â = (π, 2π/3, π/4), w_l the window
(Sloan's w_l = 1/(1 + λ l²(l + 1)²) with the fitted λ for ``-lambda``).

Unity (built-in, URP and HDRP light probes and ambient probe: ``UnityEngine.Rendering.SphericalHarmonicsL2``),
documented at https://docs.unity3d.com/Manual/LightProbes-TechnicalInformation.html: 9 coefficients per
channel in the order L00, L1−1 (y), L10 (z), L11 (x), L2−2 (xy), L2−1 (yz), L20 (zz), L21 (xz), L22 (xx − yy),
"the notation and reconstruction method from Peter-Pike Sloan's paper, Stupid Spherical Harmonics (SH)
Tricks" (its appendix A10, ``SetSHEMapConstants``), shader code in ``UnityCG.cginc``. The stored coefficients
have the constants folded in (Sloan's fC0 = 1/(2√π), fC1 = √3/(3√π), fC2 = √15/(8√π), fC3 = √5/(16√π),
fC4 = fC2/2, negative on the odd-m entries k = 1, 3, 5, 7, which undo the Condon–Shortley phase of Sloan's
D3DX basis): in rtfit's convention

    sh[c, k] = κ_k · w_l · L'_k,   κ_k = N_k · Â_l / π   (N_k the basis constant of `SH_C`)

so that the shader's polynomial sh0 + sh1·y + sh2·z + sh3·x + sh4·xy + sh5·yz + sh6·(3z² − 1) + sh7·xz +
sh8·(x² − y²) is E(n)/π: ``ShadeSH9`` returns the outgoing radiance of a white Lambertian surface (a constant
sky of radiance L gives L: ``AddAmbientLight`` adds the colour to sh[c, 0]). The shader reads seven float4
(``unity_SHAr/g/b``, ``unity_SHBr/g/b``, ``unity_SHC``) packed from ``sh`` as (sh3, sh1, sh2, sh0 − sh6),
(sh4, sh5, 3·sh6, sh7) per channel and (sh8 of R, G, B, 1) — the packing of Unity's
``SHToShaderCoefficients`` / the Entities Graphics ``SHProperties`` — and evaluates
dot(SHA, (n, 1)) + dot(SHB, n.xyzz·n.yzzx) + SHC·(x² − y²) (``SHEvalLinearL0L1`` + ``SHEvalLinearL2``).

Frame: Unity's world is +Y up, left-handed; rtfit's (x, y, z) is Unity's (x, z, y) (the usual import of a
+Z-up right-handed scene; a reflection, so the coefficients are mixed within each band, not only reordered:
L'_k = Σ_j M_kj L_j with M from Y(P n) = M Y(n), an orthogonal 9 × 9 matrix per band computed once from the
one basis text `sh_basis`).

What the preset gives: the per-band scale (1, w₁, w₂) to multiply a probe Unity already holds (its own
baked probes are in its convention: the fitted window is the only change), and the 9 × 9 matrix from rtfit's
L_lm (the fitted file's ``coeffs`` table) to Unity's sh[c, ·] with κ, the window and the frame folded in.
Lost: the ×π (Unity's diffuse term is E/π times the albedo); bands above 2 of ``sh-l3``/``sh-l4`` (Â₃ = 0:
nothing for L3; L4's Â₄ = −π/24 band is dropped).

Godot 4 (LightmapGI's probes: the 9 ``Color`` per probe of ``LightmapGIData``'s capture data), from its
source (godotengine/godot, read at commit 000ae031b1c3): the baker ``modules/lightmapper_rd/lm_compute.glsl``
(``MODE_LIGHT_PROBES``) projects the traced radiance on ``c[9]`` = 0.282095, 0.488603·(y, z, x),
1.092548·(xy, yz), 0.315392·(3z² − 1), 1.092548·xz, 0.546274·(x² − y²) — rtfit's basis and order, no
Condon–Shortley phase — and scales the sum by 4/N (not 4π/N): the stored sh[k] is L_k/π. The shader
(``servers/rendering/renderer_rd/shaders/forward_clustered/scene_forward_clustered.glsl``, the
``INSTANCE_FLAGS_USE_LIGHTMAP_CAPTURE`` branch, "has lightmap capture") adds to ``ambient_light`` Ramamoorthi
and Hanrahan's eq. 13 with c1…c5 = 0.429043, 0.511664, 0.743125, 0.886227, 0.247708 on sh[0…8] at the world
normal, times ``scene_data.emissive_exposure_normalization``: E/π. So sh[c, k] = w_l·L'_k/π, L' in Godot's
world frame (+Y up, right-handed, −Z forward: the ``Vector3.UP``/``FORWARD`` constants): rtfit's (x, y, z) is
Godot's (x, z, −y), a rotation. Line numbers are not cited: the repository was read through a search index
that gives the text, not its lines (the shader's branch and the baker's ``#ifdef MODE_LIGHT_PROBES`` name
the places).

Unreal Engine 4/5 (``FSHVectorRGB3`` in C++, ``FThreeBandSHVectorRGB`` in shaders: the volumetric lightmap,
the indirect lighting cache), from its shader source ``Engine/Shaders/Private/SHCommon.ush``:
``SHBasisFunction3`` is V0 = (0.282095, −0.488603·y, 0.488603·z, −0.488603·x), V1 = (1.092548·xy,
−1.092548·yz, 0.315392·(3z² − 1), −1.092548·xz), V2 = 0.546274·(x² − y²) — rtfit's order with the
Condon–Shortley phase (the odd-m entries negated); ``CalcDiffuseTransferSH3(N, 1)`` scales its bands by
2π/2, 2π/3, 2π/8 = Â; ``BasePassPixelShader.usf`` (``PRECOMPUTED_IRRADIANCE_VOLUME_LIGHTING``) shades with
max(0, DotSH3(IrradianceSH, CalcDiffuseTransferSH3(DiffuseDir, 1)))/π: E/π, the SH holding radiance
coefficients. So sh[c, k] = s_k·w_l·L'_k with s = (1, −1, 1, −1, 1, −1, 1, −1, 1). Frame: Unreal is +Z up,
left-handed
(https://dev.epicgames.com/documentation/en-us/unreal-engine/coordinate-system-and-spaces-in-unreal-engine);
rtfit's (x, y, z) is Unreal's (x, −y, z) (the importers' Y flip; a reflection). Epic's repository is
access-restricted: the functions were read in public copies marked "Copy From Unreal Engine SHCommon.ush",
so the functions are cited by name, not by line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtfit.realtime.irradiance_bases import A_HAT, METHODS, SH_C, sh_basis, sh_window

__all__ = [
    "GODOT_AXES",
    "GODOT_C",
    "SH_LAYOUTS",
    "UNITY_AXES",
    "UNITY_SH_SOURCES",
    "UNREAL_AXES",
    "UNREAL_BASIS",
    "ShLayout",
    "godot_capture_irradiance",
    "is_sh",
    "rtfit_to_unity_sh",
    "sh_from_engine",
    "sh_matrix",
    "sh_preset",
    "sh_to_engine",
    "unity_sh_constants",
    "unity_sh_factors",
    "unity_sh_matrix",
    "unity_sh_preset",
    "unity_shade_sh9",
    "unity_to_rtfit_sh",
    "unreal_diffuse_sh3",
]

UNITY_SH_SOURCES = (
    "https://docs.unity3d.com/Manual/LightProbes-TechnicalInformation.html",
    "https://docs.unity3d.com/ScriptReference/Rendering.SphericalHarmonicsL2.html",
    "Sloan 2008, Stupid Spherical Harmonics (SH) Tricks, appendix A10 (SetSHEMapConstants)",
)
UNITY_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
"""rtfit (x, y, z), +Z up right-handed → Unity (x, z, y), +Y up left-handed: n_unity = UNITY_AXES @ n."""

_BAND = (0, 1, 1, 1, 2, 2, 2, 2, 2)
_NORM = (SH_C[0], SH_C[1], SH_C[1], SH_C[1], SH_C[2], SH_C[2], SH_C[3], SH_C[2], SH_C[4])


def is_sh(method_id: str) -> bool:
    """Whether a fitted method is an SH irradiance basis of order ≥ 2 (``sh-l2``, ``sh-l3-lambda``, …)."""
    m = METHODS.get(method_id)
    return m is not None and m.kernel is METHODS["sh-l2"].kernel and int(m.fixed.get("order", 0)) >= 2


def _window(method_id: str, lam: float | None) -> np.ndarray:
    m = METHODS[method_id]
    w = sh_window(m.fixed.get("window", "none"), int(m.fixed["order"]), 0.0 if lam is None else lam)
    return w[:3]


def unity_sh_factors(window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """κ_k·w_l for k = 0..8: κ_k = N_k·Â_l/π (Sloan's fC0..fC4 in rtfit's sign convention)."""
    w = np.asarray(window, np.float64)
    return np.array([_NORM[k] * A_HAT[_BAND[k]] / math.pi * w[_BAND[k]] for k in range(9)])


def _frame_matrix(axes: np.ndarray) -> np.ndarray:
    """M (9, 9) with Y(P n) = M Y(n) (P = ``axes``, orthogonal), by least squares on 64 directions (exact:
    the rotated or reflected basis lies in the span of each band)."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    a, b = sh_basis(d, 2), sh_basis(d @ axes.T, 2)
    mt, *_ = np.linalg.lstsq(a, b, rcond=None)
    mt[np.abs(mt) < 1e-12] = 0.0  # round-off where the band's mixing is exactly 0
    return mt.T


_FRAME = _frame_matrix(UNITY_AXES)


def unity_sh_matrix(window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The 9 × 9 matrix T with sh[c, ·] = T @ L[·, c]: frame, κ and window folded in."""
    return unity_sh_factors(window)[:, None] * _FRAME


def rtfit_to_unity_sh(coeffs, window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """rtfit's SH (9, 3) radiance coefficients (or the 27 stored floats, channel-major) → Unity's
    SphericalHarmonicsL2 as sh[c, k] (3, 9)."""
    c = np.asarray(coeffs, np.float64)
    c = c.reshape(3, 9).T if c.shape == (27,) else c
    return (unity_sh_matrix(window) @ c).T


def unity_to_rtfit_sh(sh, window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The inverse of `rtfit_to_unity_sh`: Unity's sh[c, k] (3, 9) → rtfit's L (9, 3) (w_l > 0)."""
    return np.linalg.solve(unity_sh_matrix(window), np.asarray(sh, np.float64).T)


def unity_sh_constants(sh) -> np.ndarray:
    """The seven float4 ``unity_SHAr, unity_SHAg, unity_SHAb, unity_SHBr, unity_SHBg, unity_SHBb, unity_SHC``
    (7, 4) packed from sh[c, k] (3, 9) as Unity packs them."""
    sh = np.asarray(sh, np.float64)
    a = [[s[3], s[1], s[2], s[0] - s[6]] for s in sh]
    b = [[s[4], s[5], 3.0 * s[6], s[7]] for s in sh]
    return np.array([*a, *b, [sh[0, 8], sh[1, 8], sh[2, 8], 1.0]])


def unity_shade_sh9(constants, normal, dtype: type = np.float32) -> np.ndarray:
    """UnityCG's ShadeSH9 (``SHEvalLinearL0L1`` + ``SHEvalLinearL2``) with the seven float4 ``constants`` at
    unit normals (..., 3) in Unity's frame, in ``dtype`` (the shader's float32 by default) → (..., 3) RGB."""
    k = np.asarray(constants, dtype)
    n = np.asarray(normal, dtype)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    va = np.stack([x, y, z, np.ones_like(x)], axis=-1)
    vb = np.stack([x * y, y * z, z * z, z * x], axis=-1)
    vc = x * x - y * y
    out = [va @ k[c] + vb @ k[3 + c] + k[6, c] * vc for c in range(3)]
    return np.stack(out, axis=-1)


GODOT_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""rtfit (x, y, z), +Z up right-handed → Godot (x, z, −y), +Y up right-handed, −Z forward (a rotation)."""
UNREAL_AXES = np.diag([1.0, -1.0, 1.0])
"""rtfit (x, y, z), +Z up right-handed → Unreal (x, −y, z), +Z up left-handed (a reflection)."""
GODOT_C = (0.429043, 0.511664, 0.743125, 0.886227, 0.247708)
"""c1…c5 as Godot's capture shader writes them (Ramamoorthi and Hanrahan's eq. 13, 6 digits)."""
UNREAL_BASIS = (0.282095, 0.488603, 1.092548, 0.315392, 0.546274)
"""The basis constants of Unreal's ``SHBasisFunction3`` as its shader writes them (6 digits)."""
GODOT_SH_SOURCES = (
    "godotengine/godot servers/rendering/renderer_rd/shaders/forward_clustered/scene_forward_clustered.glsl "
    "(the INSTANCE_FLAGS_USE_LIGHTMAP_CAPTURE branch: Ramamoorthi–Hanrahan eq. 13 on sh[0..8])",
    "godotengine/godot modules/lightmapper_rd/lm_compute.glsl (MODE_LIGHT_PROBES: the basis c[9] and the "
    "4/N scale)",
    "https://docs.godotengine.org/en/stable/classes/class_vector3.html (UP = (0, 1, 0), "
    "FORWARD = (0, 0, −1))",
)
UNREAL_SH_SOURCES = (
    "Unreal Engine Engine/Shaders/Private/SHCommon.ush (SHBasisFunction3, CalcDiffuseTransferSH3, DotSH3)",
    "Unreal Engine Engine/Shaders/Private/BasePassPixelShader.usf (PRECOMPUTED_IRRADIANCE_VOLUME_LIGHTING: "
    "max(0, DotSH3(IrradianceSH, CalcDiffuseTransferSH3(N, 1))) / PI)",
    "https://dev.epicgames.com/documentation/en-us/unreal-engine/coordinate-system-and-spaces-in-unreal-engine",
)
_CS_PHASE = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0])


@dataclass(frozen=True)
class ShLayout:
    """One engine's SH L2 layout: sh[c, k] = factor_k·w_l·(M L)_k with M the frame change of ``axes``;
    ``title`` and ``target`` name the engine's container, ``lost`` what the conversion does not keep."""

    engine: str
    title: str
    anchor: str
    target: str
    axes: np.ndarray
    factors: np.ndarray
    sources: tuple[str, ...]
    lost: tuple[str, ...]


SH_LAYOUTS: dict[str, ShLayout] = {
    "unity-hdrp": ShLayout(
        "unity-hdrp",
        "Unity SphericalHarmonicsL2 (light probes, ambient probe; built-in, URP, HDRP)",
        "Unity's world frame: rtfit's (x, y, z) is Unity's (x, z, y)",
        "SphericalHarmonicsL2",
        UNITY_AXES,
        unity_sh_factors(),
        UNITY_SH_SOURCES,
        (
            "the factor π: Unity's ShadeSH9 returns E/π (the outgoing radiance of a white Lambertian "
            "surface), rtfit's kernel the irradiance E",
            "the frame: rtfit's (x, y, z) (+Z up, right-handed) is Unity's (x, z, y) (+Y up, left-handed), "
            "folded into the matrix",
        ),
    ),
    "godot": ShLayout(
        "godot",
        "Godot 4 LightmapGI probes (LightmapGIData capture data: 9 Colors per probe)",
        "Godot's world frame: rtfit's (x, y, z) is Godot's (x, z, −y)",
        "LightmapGI probe SH",
        GODOT_AXES,
        np.full(9, 1.0 / math.pi),
        GODOT_SH_SOURCES,
        (
            "the factor π: Godot's probe SH holds L_lm/π (its baker scales by 4/N, not 4π/N) and its capture "
            "shader returns E/π, rtfit's kernel the irradiance E",
            "the frame: rtfit's (x, y, z) (+Z up) is Godot's (x, z, −y) (+Y up, right-handed: a rotation), "
            "folded into the matrix",
            "Godot's constants: its shader writes Ramamoorthi and Hanrahan's published c1…c5 (6 digits, "
            "relative error ≤ 1.6e-6 per term), and "
            "multiplies by the camera's emissive_exposure_normalization",
        ),
    ),
    "unreal": ShLayout(
        "unreal",
        "Unreal Engine 4/5 FSHVectorRGB3 / FThreeBandSHVectorRGB (volumetric lightmap, indirect lighting "
        "cache)",
        "Unreal's world frame: rtfit's (x, y, z) is Unreal's (x, −y, z)",
        "FSHVectorRGB3",
        UNREAL_AXES,
        _CS_PHASE,
        UNREAL_SH_SOURCES,
        (
            "the factor π: Unreal's base pass divides DotSH3(SH, CalcDiffuseTransferSH3(N, 1)) = E by π",
            "the Condon–Shortley phase of Unreal's SHBasisFunction3 (the odd-m entries negated), folded into "
            "the matrix",
            "the frame: rtfit's (x, y, z) (+Z up, right-handed) is Unreal's (x, −y, z) (+Z up, "
            "left-handed: a reflection), folded into the matrix",
            "Unreal's constants: SHBasisFunction3 writes the basis constants to 6 digits (relative error "
            "≤ 1.4e-6 per term)",
        ),
    ),
}
_FRAMES = {e: _FRAME if e == "unity-hdrp" else _frame_matrix(lay.axes) for e, lay in SH_LAYOUTS.items()}


def sh_matrix(engine: str, window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The 9 × 9 matrix T with sh[c, ·] = T @ L[·, c] in ``engine``'s layout: frame, factors, window."""
    w = np.asarray(window, np.float64)
    lay = SH_LAYOUTS[engine]
    return (lay.factors * np.array([w[b] for b in _BAND]))[:, None] * _FRAMES[engine]


def sh_to_engine(engine: str, coeffs, window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """rtfit's SH (9, 3) radiance coefficients (or the 27 stored floats, channel-major) → ``engine``'s
    sh[c, k] (3, 9)."""
    c = np.asarray(coeffs, np.float64)
    c = c.reshape(3, 9).T if c.shape == (27,) else c
    return (sh_matrix(engine, window) @ c).T


def sh_from_engine(engine: str, sh, window=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The inverse of `sh_to_engine`: ``engine``'s sh[c, k] (3, 9) → rtfit's L (9, 3) (w_l > 0)."""
    return np.linalg.solve(sh_matrix(engine, window), np.asarray(sh, np.float64).T)


def godot_capture_irradiance(sh, normal, dtype: type = np.float32, c=GODOT_C) -> np.ndarray:
    """Godot's capture shader (module docstring) with probe SH ``sh`` (3, 9) at world normals (..., 3) in
    Godot's frame, in ``dtype`` → ``ambient_light`` (..., 3), E/π (exposure normalisation 1). ``c``: c1…c5
    (Godot's 6-digit literals by default)."""
    k = np.asarray(sh, dtype)
    n = np.asarray(normal, dtype)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    c1, c2, c3, c4, c5 = (dtype(v) for v in c)
    two = dtype(2.0)
    out = [
        c1 * s[8] * (x * x - y * y) + c3 * s[6] * z * z + c4 * s[0] - c5 * s[6]
        + two * c1 * s[4] * x * y + two * c1 * s[7] * x * z + two * c1 * s[5] * y * z
        + two * c2 * s[3] * x + two * c2 * s[1] * y + two * c2 * s[2] * z
        for s in k
    ]  # fmt: skip
    return np.stack(out, axis=-1)


def unreal_diffuse_sh3(sh, normal, dtype: type = np.float32, basis=UNREAL_BASIS) -> np.ndarray:
    """Unreal's max(0, DotSH3(SH, CalcDiffuseTransferSH3(N, 1)))/π (module docstring) with ``sh`` (3, 9) as
    V0 = sh[0:4], V1 = sh[4:8], V2 = sh[8] per channel, at normals (..., 3) in Unreal's frame, in ``dtype``
    → (..., 3). ``basis``: SHBasisFunction3's constants (Unreal's literals by default)."""
    k = np.asarray(sh, dtype)
    n = np.asarray(normal, dtype)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    b0, b1, b2, b3, b4 = (dtype(v) for v in basis)
    pi = dtype(math.pi)
    l0, l1, l2 = dtype(2) * pi / dtype(2), dtype(2) * pi / dtype(3), dtype(2) * pi / dtype(8)
    v0 = np.stack([np.full_like(x, b0) * l0, -b1 * y * l1, b1 * z * l1, -b1 * x * l1], axis=-1)
    v1 = np.stack([b2 * x * y * l2, -b2 * y * z * l2, b3 * (dtype(3) * z * z - dtype(1)) * l2,
                   -b2 * x * z * l2], axis=-1)  # fmt: skip
    v2 = b4 * (x * x - y * y) * l2
    out = [np.maximum(dtype(0), v0 @ s[0:4] + v1 @ s[4:8] + s[8] * v2) / pi for s in k]
    return np.stack(out, axis=-1)


def sh_preset(engine: str, method_id: str, lam: float | None) -> tuple[dict, list[str]]:
    """(values, lost) of one SH method for ``engine``: the band scale and the rtfit → engine matrix."""
    lay = SH_LAYOUTS[engine]
    w = _window(method_id, lam)
    order = int(METHODS[method_id].fixed["order"])
    values = {
        f"{lay.target} band scale": tuple(float(w[b]) for b in _BAND),
        f"rtfit L_lm → {lay.target} (sh[c, k] = Σ_j T[k][j]·L_j)": tuple(
            tuple(float(v) for v in row) for row in sh_matrix(engine, w)
        ),
    }
    lost = list(lay.lost)
    if order >= 3:
        lost.append(
            f"bands 3 and up: {lay.target} holds l ≤ 2 (Â₃ = 0: nothing lost for L3"
            + ("; L4's band, Â₄ = −π/24, is dropped" if order >= 4 else "")
            + ")"
        )
    return values, lost


def unity_sh_preset(method_id: str, lam: float | None) -> tuple[dict, list[str]]:
    """(values, lost) of one SH method for Unity: `sh_preset` of ``unity-hdrp``."""
    return sh_preset("unity-hdrp", method_id, lam)
