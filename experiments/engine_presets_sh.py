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
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.realtime.irradiance_bases import A_HAT, METHODS, SH_C, sh_basis, sh_window

__all__ = [
    "UNITY_AXES",
    "UNITY_SH_SOURCES",
    "is_sh",
    "rtfit_to_unity_sh",
    "unity_sh_constants",
    "unity_sh_factors",
    "unity_sh_matrix",
    "unity_sh_preset",
    "unity_shade_sh9",
    "unity_to_rtfit_sh",
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


def _frame_matrix() -> np.ndarray:
    """M (9, 9) with Y(P n) = M Y(n) (P = `UNITY_AXES`), by least squares on 64 directions (exact: the
    permuted basis lies in the span of each band)."""
    rng = np.random.default_rng(0)
    d = rng.normal(size=(64, 3))
    a, b = sh_basis(d, 2), sh_basis(d @ UNITY_AXES.T, 2)
    mt, *_ = np.linalg.lstsq(a, b, rcond=None)
    mt[np.abs(mt) < 1e-12] = 0.0  # round-off where the band's mixing is exactly 0
    return mt.T


_FRAME = _frame_matrix()


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


def unity_shade_sh9(constants, normal, dtype=np.float32) -> np.ndarray:
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


def unity_sh_preset(method_id: str, lam: float | None) -> tuple[dict, list[str]]:
    """(values, lost) of one SH method for Unity: the band scale and the rtfit → Unity matrix."""
    w = _window(method_id, lam)
    order = int(METHODS[method_id].fixed["order"])
    values = {
        "SphericalHarmonicsL2 band scale": tuple(float(w[b]) for b in _BAND),
        "rtfit L_lm → SphericalHarmonicsL2 (sh[c, k] = Σ_j T[k][j]·L_j)": tuple(
            tuple(float(v) for v in row) for row in unity_sh_matrix(w)
        ),
    }
    lost = [
        "the factor π: Unity's ShadeSH9 returns E/π (the outgoing radiance of a white Lambertian surface), "
        "rtfit's kernel the irradiance E",
        "the frame: rtfit's (x, y, z) (+Z up, right-handed) is Unity's (x, z, y) (+Y up, left-handed), "
        "folded into the matrix",
    ]
    if order >= 3:
        lost.append(
            "bands 3 and up: SphericalHarmonicsL2 holds l ≤ 2 (Â₃ = 0: nothing lost for L3"
            + ("; L4's band, Â₄ = −π/24, is dropped" if order >= 4 else "")
            + ")"
        )
    return values, lost
