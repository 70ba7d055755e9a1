"""Pre-convolved and localised environment maps, and distance-impostor ray search (GameTools D5.3).

Source: seed 001 (GameTools deliverable D5.3, 2006), lines 220-906: the convolution shader
``ConvolutionPS`` (001:569-594), the localised convolution ``EnvMapDiffuseLocalizedPS`` /
``GetContribution`` (001:637-710), the cosine look-up ``GetContributionWithCosLookup`` (001:716-729,
tabulated by ``EnvMap::eval``, 001:453-457) and the distance-impostor ``Hit`` functions (one lookup,
001:547-553; iterative secant search, 001:841-866).

Cube-map layout (this module's, used by every function here). Face f ∈ {+X, −X, +Y, −Y, +Z, −Z} (0…5);
on each face two coordinates a, b ∈ [−1, 1] — (y, z) on the X faces, (x, z) on the Y faces, (x, y) on the
Z faces — and the point on the cube of edge 2 is (±1, a, b), (a, ±1, b), (a, b, ±1). Texel (i, j) of an
N×N face covers a ∈ [−1 + 2i/N, −1 + 2(i+1)/N], b likewise with j; its flat index is f·N² + i·N + j.
A lookup direction d selects the face of its largest |component| (ties: X before Y before Z), exactly as
a GPU's ``texCUBE`` does up to face orientation, which no result here depends on.

Solid angles (sr). A texel's exact solid angle is Ω = F(a₁, b₁) − F(a₀, b₁) − F(a₁, b₀) + F(a₀, b₀) with
F(a, b) = atan2(a·b, √(a² + b² + 1)) (the solid angle of the rectangle [0, a]×[0, b] on the plane at
distance 1). The seed's ``ConvolutionPS`` uses the midpoint rule Ω ≈ h²/(1 + a² + b²)^{3/2} with
h = 2/N ("4/(r³)/N²"), whose bias for a constant environment at N = 4 is +3.57 % for an axis-aligned
normal (`convolve`); ``GetContribution`` uses one constant for every texel,
Ω_seed = 4/(N² + 2/π) (001:688), which is neither the mean 4π/(6N²) nor any texel's solid angle.

Convolution (pre-convolved map). For a query axis q the diffuse map stores the irradiance
E(q) = ∫ L(ω) max(q·ω, 0) dω (W/m² for L in W/(m²·sr)); the glossy map stores the lobe-filtered
radiance G(q) = ∫ L(ω) (s+1)/(2π) max(q·ω, 0)^s dω (normalised Phong lobe about q = the reflection
direction; 1 for L = 1). Both are sums over the texels of a cube map of the product
lobe(q·ω_t)·Ω_t·L_t.

Localised convolution. Each texel also stores the distance d_t from the map's reference point to the
surface seen through it. Seen from a shading point p (relative to the reference point), the texel's
surface patch lies at y_t = ω_t·d_t, at distance Δ = |y_t − p| in direction ω' = (y_t − p)/Δ, and the
seed approximates its solid angle by

    Ω' = d_t²·Ω / (Δ²·(1 − Ω/2π) + d_t²·Ω/2π)            (001:696, "dws localization")

(the solid angle of a cap of the same area moved from d_t to Δ; Ω' = Ω at p = 0 and Ω' → 2π as Δ → 0).
The contribution of the texel is then L_t·lobe(axis·ω')·Ω' ("point": one sample at the patch centre,
001:700-709), or L_t·K(axis·ω', Ω') where K is the integral of the lobe over a cap of solid angle Ω'
about ω' ("cap": the cosine look-up texture of 001:716-729). For the diffuse lobe K is the irradiance of
a unit-radiance sphere light of angular radius α = acos(1 − Ω'/2π): `rtfit.realtime.diffuse`'s
horizon-clipped Snyder form, the same text. For the glossy lobe K is tabulated by quadrature
(`cap_lobe_table`) and read bilinearly at ((c + 1)/2, Ω'/2π), as the seed's texture is.

Distance impostors. ``Hit(x, R)`` finds the point where the ray x + t·R (x relative to the reference
point) meets the surface stored in a distance cube map dist(·): a point l lies on it when
|l| = dist(l), i.e. when the ratio λ(l) = |l|/dist(l) is 1. The one-lookup form (001:547-553) steps
t = dist(R) − x·R; the iterative form (001:841-866) starts from t₀ = dist(R)·(1 − λ(x)) and does a
secant search on λ over the last under- and overshoot, n iterations. The hit point selects the radiance
texel (lookup direction l). "Classic" environment mapping looks up the radiance at R itself.

Units: distances in metres (any unit, consistently), solid angles in sr, radiance and irradiance in the
environment's units. Domain: unit direction vectors (normalised inside the kernels where the seed does),
shininess s ≥ 0 (s = 0 is the uniform lobe 1/(2π) over the hemisphere), cube resolution N ≥ 1.

This module imports only NumPy, Dr.Jit (through `rtfit.realtime.arrays`) and its sibling kernels.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from .arrays import (
    DRJIT_OPS,
    NUMPY_OPS,
    backend_float,
    evaluate,
    evaluate_numpy,
    safe_div,
    safe_sqrt,
    to_drjit,
)
from .light_models import sphere_light_irradiance_kernel
from .methods import Input, Method, Param, method_table

__all__ = [
    "FACE_NAMES",
    "FRESNEL_METHODS",
    "HIT_METHODS",
    "SEED_SOLID_ANGLE",
    "cap_lobe_table",
    "convolution_term_kernel",
    "convolve",
    "cube_lookup",
    "cube_lookup_kernel",
    "cube_texels",
    "dielectric_fresnel_kernel",
    "evaluate_lobe_numpy",
    "fresnel_split_kernel",
    "hit_iterative_kernel",
    "hit_parallax_kernel",
    "impostor_hit",
    "lobe",
    "lobe_kernel",
    "localised_convolve",
    "localised_solid_angle_kernel",
    "localised_term_kernel",
    "midpoint_solid_angle",
    "midpoint_solid_angle_kernel",
    "schlick_fresnel_kernel",
    "seed_solid_angle",
    "texel_solid_angle",
    "texel_solid_angle_kernel",
]

TWO_PI = 2.0 * math.pi
FACE_NAMES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")


# ======================================================================================= cube geometry
def cube_texels(resolution: int) -> dict[str, np.ndarray]:
    """The texels of an N×N-per-face cube map in this module's layout (module docstring), float64.

    Returns ``point`` (6N², 3): texel centres on the cube of edge 2 (not normalised: the seed's L);
    ``a0, a1, b0, b1`` (6N²,): the texel's face-coordinate edges; ``a, b``: its centre coordinates."""
    n = int(resolution)
    if n < 1:
        raise ValueError(f"cube resolution must be ≥ 1, got {resolution}")
    edges = np.linspace(-1.0, 1.0, n + 1)
    lo, hi = (
        np.meshgrid(edges[:-1], edges[:-1], indexing="ij"),
        np.meshgrid(edges[1:], edges[1:], indexing="ij"),
    )
    a0, b0 = (np.tile(x.ravel(), 6) for x in lo)
    a1, b1 = (np.tile(x.ravel(), 6) for x in hi)
    a, b = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
    one = np.ones(n * n)
    face = np.repeat(np.arange(6), n * n)
    sign = np.where(face % 2 == 0, 1.0, -1.0)
    axis = face // 2
    s1 = sign * np.tile(one, 6)
    x = np.where(axis == 0, s1, a)
    y = np.where(axis == 0, a, np.where(axis == 1, s1, b))
    z = np.where(axis == 2, s1, b)
    return {"point": np.stack([x, y, z], -1), "a0": a0, "a1": a1, "b0": b0, "b1": b1, "a": a, "b": b}


def _rect_solid_angle(ops, a, b):
    """F(a, b) = atan2(a·b, √(a² + b² + 1)): solid angle of [0, a]×[0, b] on the plane at distance 1."""
    return ops.atan2(a * b, ops.sqrt(a * a + b * b + 1.0))


def texel_solid_angle_kernel(ops, a0, a1, b0, b1):
    """Exact solid angle (sr) of the cube-face rectangle [a0, a1]×[b0, b1] (face at distance 1)."""
    return (
        _rect_solid_angle(ops, a1, b1)
        - _rect_solid_angle(ops, a0, b1)
        - _rect_solid_angle(ops, a1, b0)
        + _rect_solid_angle(ops, a0, b0)
    )


def midpoint_solid_angle_kernel(ops, a, b, h):
    """The seed's midpoint rule (001:590): h²/(1 + a² + b²)^{3/2} for a texel of side h centred at (a, b)."""
    r2 = 1.0 + a * a + b * b
    return h * h / (r2 * ops.sqrt(r2))


SEED_SOLID_ANGLE = "4/(N² + 2/π)"
"""The seed's constant per-texel solid angle of ``GetContribution`` (001:688), as printed."""


def seed_solid_angle(resolution: int) -> float:
    """Ω_seed = 4/(N² + 4/2/π) (001:688): one solid angle for every texel (sr)."""
    n = float(resolution)
    return 4.0 / (n * n + 4.0 / 2.0 / math.pi)


def texel_solid_angle(resolution: int, rule: str = "exact") -> np.ndarray:
    """Per-texel solid angles (6N²,) of an N×N cube map: ``exact``, ``midpoint`` (seed 001:590),
    ``seed`` (the constant of 001:688) or ``equal`` (4π/6N², the mean)."""
    t = cube_texels(resolution)
    if rule == "exact":
        return np.asarray(evaluate(texel_solid_angle_kernel, t["a0"], t["a1"], t["b0"], t["b1"]))
    if rule == "midpoint":
        return np.asarray(evaluate(midpoint_solid_angle_kernel, t["a"], t["b"], 2.0 / resolution))
    if rule == "seed":
        return np.full(t["a"].shape, seed_solid_angle(resolution))
    if rule == "equal":
        return np.full(t["a"].shape, 4.0 * math.pi / (6 * resolution * resolution))
    raise ValueError(f"unknown solid-angle rule {rule!r} (exact, midpoint, seed, equal)")


def midpoint_solid_angle(resolution: int) -> np.ndarray:
    """`texel_solid_angle` with the seed's midpoint rule."""
    return texel_solid_angle(resolution, "midpoint")


# ============================================================================================== lobes
def lobe_kernel(ops, cos_angle, shininess):
    """The convolution lobe of cos c between the lobe axis and a direction.

    ``shininess`` ≤ 0 → the clamped cosine max(c, 0) (irradiance); s > 0 → the normalised Phong lobe
    (s+1)/(2π)·max(c, 0)^s (filtered radiance, integrates to 1 over the sphere)."""
    c = ops.maximum(cos_angle, 0.0)
    s = ops.maximum(shininess, 0.0)
    phong = (s + 1.0) / TWO_PI * ops.power(c, s)
    return ops.select(shininess > 0.0, phong, c)


def lobe(cos_angle, shininess):
    """`lobe_kernel`, dispatched: the diffuse clamped cosine (s ≤ 0) or the normalised Phong lobe."""
    return evaluate(lobe_kernel, cos_angle, shininess)


def _normalise(ops, x, y, z):
    inv = 1.0 / ops.sqrt(ops.maximum(x * x + y * y + z * z, 1e-30))
    return x * inv, y * inv, z * inv


def convolution_term_kernel(ops, qx, qy, qz, lx, ly, lz, solid_angle, shininess):
    """One texel's term lobe(q·ω)·Ω of the pre-convolution (001:569-594); (lx, ly, lz) the texel point on
    the cube (normalised here), q a unit query axis."""
    wx, wy, wz = _normalise(ops, lx, ly, lz)
    return lobe_kernel(ops, qx * wx + qy * wy + qz * wz, shininess) * solid_angle


def convolve(env: np.ndarray, query: np.ndarray, shininess: float = 0.0, rule: str = "exact") -> np.ndarray:
    """Convolve a cube map ``env`` (6N²,) with the lobe about each unit ``query`` axis (Q, 3) → (Q,).

    ``rule`` picks the texel solid angles (`texel_solid_angle`). The per-texel term is
    `convolution_term_kernel` on the default Dr.Jit backend (float64); the sum over texels is NumPy."""
    env = np.asarray(env, dtype=np.float64).reshape(-1)
    n = round(math.sqrt(env.size / 6))
    if 6 * n * n != env.size:
        raise ValueError(f"env must hold 6·N² texels, got {env.size}")
    q = np.asarray(query, dtype=np.float64).reshape(-1, 3)
    pts = cube_texels(n)["point"]
    dw = texel_solid_angle(n, rule) * env
    out = np.empty(len(q))
    chunk = max(1, (1 << 21) // env.size)
    # Every (query, texel) pair gathered by index inside the kernel from the Q queries and the T texels, not
    # broadcast to Q·T values on the host and copied in (issue 33: 7 copies of 2²¹ floats a chunk were half
    # of probe-specular's captures); the same values per pair, so the same terms bit for bit.
    Float = backend_float(None, np.float64)
    UInt = dr.uint32_array_t(Float)
    texels = [to_drjit(Float, np.ascontiguousarray(a)) for a in (pts[:, 0], pts[:, 1], pts[:, 2], dw)]
    t = env.size
    for s in range(0, len(q), chunk):
        qq = q[s : s + chunk]
        axes = [to_drjit(Float, np.ascontiguousarray(qq[:, k])) for k in range(3)]
        pair = dr.arange(UInt, len(qq) * t)
        i = pair // t
        j = pair - i * t
        qx, qy, qz = (dr.gather(Float, a, i) for a in axes)
        lx, ly, lz, solid_angle = (dr.gather(Float, a, j) for a in texels)
        terms = convolution_term_kernel(DRJIT_OPS, qx, qy, qz, lx, ly, lz, solid_angle, float(shininess))
        out[s : s + chunk] = np.asarray(terms, np.float64).reshape(len(qq), t).sum(axis=1)
    return out


# ================================================================================== cube-map lookups
def _face_coords(ops, dx, dy, dz):
    """(face index 0…5 as a float, a, b ∈ [−1, 1]) of direction d; a zero vector maps to +Z's centre."""
    ax, ay, az = ops.abs(dx), ops.abs(dy), ops.abs(dz)
    isx = (ax >= ay) & (ax >= az)
    isy = ~isx & (ay >= az)
    isz = ~isx & ~isy
    major = ops.select(isx, ax, ops.select(isy, ay, az))
    major = ops.maximum(major, 1e-30)
    u = ops.select(isx, dy, dx)
    v = ops.select(isz, dy, dz)
    face = ops.select(
        isx,
        ops.select(dx >= 0.0, 0.0, 1.0),
        ops.select(isy, ops.select(dy >= 0.0, 2.0, 3.0), ops.select(dz >= 0.0, 4.0, 5.0)),
    )
    a, b = ops.clip(u / major, -1.0, 1.0), ops.clip(v / major, -1.0, 1.0)
    # A NaN direction (an impostor's secant dividing by zero in float32) must not become a texel index: a
    # Dr.Jit gather is unchecked, and the LLVM backend read outside the table and crashed (exit 139 on two
    # real scenes). It reads the face's centre instead (a, b = 0), as the zero vector does.
    return face, ops.select(a == a, a, 0.0), ops.select(b == b, b, 0.0)


def cube_lookup_kernel(ops, table, dx, dy, dz, resolution, bilinear, offset=0.0):
    """Value of a cube map ``table`` (6N², this module's layout) in direction d: nearest texel, or bilinear
    within the face with clamp-to-edge (D3D9 ``texCUBE`` does not filter across faces). ``offset`` (a
    float or a per-element array of texel indices): where the map starts in ``table``, for several maps
    stacked in one table (a mip chain, the probes of a level)."""
    n = float(resolution)
    face, a, b = _face_coords(ops, dx, dy, dz)
    base = offset + face * (n * n)
    if not bilinear:
        i = ops.clip(ops.floor((a + 1.0) * 0.5 * n), 0.0, n - 1.0)
        j = ops.clip(ops.floor((b + 1.0) * 0.5 * n), 0.0, n - 1.0)
        return ops.gather(table, base + i * n + j)
    if resolution == 1:
        return ops.gather(table, base)
    s = ops.clip((a + 1.0) * 0.5 * n - 0.5, 0.0, n - 1.0)
    t = ops.clip((b + 1.0) * 0.5 * n - 0.5, 0.0, n - 1.0)
    i0 = ops.minimum(ops.floor(s), n - 2.0)
    j0 = ops.minimum(ops.floor(t), n - 2.0)
    fs, ft = s - i0, t - j0
    k = base + i0 * n + j0
    t00, t01 = ops.gather(table, k), ops.gather(table, k + 1.0)
    t10, t11 = ops.gather(table, k + n), ops.gather(table, k + n + 1.0)
    return (t00 * (1.0 - ft) + t01 * ft) * (1.0 - fs) + (t10 * (1.0 - ft) + t11 * ft) * fs


def _table_like(ops, table, like):
    """``table`` as the array kind ``ops`` runs on (the kernels gather from it)."""
    if ops.name == "drjit":
        Float = type(like) if dr.is_array_v(like) else dr.llvm.Float64
        return to_drjit(Float, np.reshape(table, -1))  # aligned: one kernel wherever NumPy put the table
    if ops.name == "jax":
        import jax.numpy as jnp

        return jnp.asarray(table)
    return np.asarray(table)


def cube_lookup(table: np.ndarray, directions, bilinear: bool = True, numpy: bool = False):
    """`cube_lookup_kernel` on directions (…, 3); the table's resolution is taken from its size.
    ``numpy``: run the NumPy text in float64 (small batches: no kernel compilation)."""
    table = np.asarray(table, dtype=np.float64).reshape(-1)
    n = _resolution_of(table)
    d = np.asarray(directions, dtype=np.float64)

    def k(ops, dx, dy, dz):
        return cube_lookup_kernel(ops, _table_like(ops, table, dx), dx, dy, dz, n, bilinear)

    run = evaluate_numpy if numpy else evaluate
    with np.errstate(all="ignore"):  # NumPy evaluates both sides of every select
        return run(k, d[..., 0], d[..., 1], d[..., 2])


def _resolution_of(table: np.ndarray) -> int:
    n = round(math.sqrt(table.size / 6))
    if 6 * n * n != table.size or n < 1:
        raise ValueError(f"a cube map holds 6·N² texels, got {table.size}")
    return n


# =========================================================================== localised convolution
def localised_solid_angle_kernel(ops, solid_angle, d_ref, d_point):
    """The seed's "dws localization" (001:696): Ω' = d²Ω / (Δ²(1 − Ω/2π) + d²Ω/2π) (sr), ≤ 2π."""
    w = solid_angle / TWO_PI
    d2 = d_ref * d_ref
    return safe_div(ops, d2 * solid_angle, d_point * d_point * (1.0 - w) + d2 * w)


def _cap_lut_kernel(ops, lut, cos_angle, omega, size):
    """Bilinear read of a (size×size) cap table at x = (c + 1)/2, y = Ω/2π (node-aligned: node k at
    k/(size−1))."""
    m = float(size) - 1.0
    u = ops.clip((cos_angle + 1.0) * 0.5, 0.0, 1.0) * m
    v = ops.clip(omega / TWO_PI, 0.0, 1.0) * m
    u0 = ops.minimum(ops.floor(u), m - 1.0)
    v0 = ops.minimum(ops.floor(v), m - 1.0)
    fu, fv = u - u0, v - v0
    k = u0 * (m + 1.0) + v0
    t00, t01 = ops.gather(lut, k), ops.gather(lut, k + 1.0)
    t10, t11 = ops.gather(lut, k + m + 1.0), ops.gather(lut, k + m + 2.0)
    return (t00 * (1.0 - fv) + t01 * fv) * (1.0 - fu) + (t10 * (1.0 - fv) + t11 * fv) * fu


def localised_term_kernel(
    ops, px, py, pz, nx, ny, nz, lx, ly, lz, dist, solid_angle, shininess, mode, lut, lut_size
):
    """One texel's weight (to multiply its radiance) at shading point p (relative to the reference point)
    with lobe axis n (the normal, or the reflection direction for a glossy lobe); (lx, ly, lz) the texel
    point on the cube, ``dist`` its stored distance, ``solid_angle`` its Ω.

    ``mode``: "point" lobe(n·ω')·Ω' (001:700-709); "cap" the clamped-cosine integral over the cap of
    solid angle Ω' about ω' (exact, diffuse only: Snyder's horizon-clipped sphere-light form);
    "lut" the tabulated cap integral ``lut`` (size×size, `cap_lobe_table`) read bilinearly (001:716-729)."""
    wx, wy, wz = _normalise(ops, lx, ly, lz)
    yx, yy, yz = wx * dist - px, wy * dist - py, wz * dist - pz
    delta = ops.sqrt(yx * yx + yy * yy + yz * yz)
    omega = localised_solid_angle_kernel(ops, solid_angle, dist, delta)
    inv = 1.0 / ops.maximum(delta, 1e-30)
    c = (nx * yx + ny * yy + nz * yz) * inv
    if mode == "point":
        return lobe_kernel(ops, c, shininess) * omega
    if mode == "cap":
        alpha = ops.acos(ops.clip(1.0 - omega / TWO_PI, 0.0, 1.0))
        return sphere_light_irradiance_kernel(ops, c, alpha, 1.0)
    return _cap_lut_kernel(ops, lut, c, omega, lut_size)


def cap_lobe_table(shininess: float, size: int = 32, nodes: int = 48) -> np.ndarray:
    """K(c, Ω) = ∫_cap lobe dω over a cap of solid angle Ω whose axis makes cos c with the lobe axis,
    tabulated at node-aligned c = 2k/(size−1) − 1, Ω = 2π·l/(size−1) (size×size, row-major in c).

    Gauss–Legendre quadrature in the cap's polar angle β ∈ [0, α] (two panels of ``nodes`` points split
    where the rim crosses the lobe's horizon, sin β Jacobian) and
    in azimuth over the part of each ring where the lobe is non-zero, [0, φ*] with
    cos φ* = −cot θ·cot β (twice, by symmetry), so that no rule straddles the clamp's kink; the
    integrand is `lobe_kernel`, the one text. Replaces the seed's
    2M×2M×M regular-sample count of ``EnvMap::eval`` (001:453-457)."""
    if size < 2:
        raise ValueError(f"cap table size must be ≥ 2, got {size}")
    c = np.linspace(-1.0, 1.0, size)
    om = np.linspace(0.0, TWO_PI, size)
    alpha = np.arccos(np.clip(1.0 - om / TWO_PI, -1.0, 1.0))
    x, w = np.polynomial.legendre.leggauss(nodes)
    ct = c[:, None, None, None]
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))
    # β panels split where the cap's rim crosses the lobe's horizon, β* = |π/2 − θ| (a kink in β)
    kink = np.abs(0.5 * math.pi - np.arccos(np.clip(c, -1.0, 1.0)))[:, None]
    split = np.minimum(alpha[None, :], kink)
    total = np.zeros((size, size))
    for lo, hi in ((np.zeros_like(split), split), (split, np.broadcast_to(alpha[None, :], split.shape))):
        half = 0.5 * (hi - lo)
        beta = lo[..., None, None] + half[..., None, None] * (x[None, None, :, None] + 1.0)
        a = ct * np.cos(beta)
        b = st * np.sin(beta)
        # the lobe vanishes where a + b·cos φ < 0: integrate φ over [0, φ*] only (2× by symmetry), so that
        # the Gauss rule never straddles the clamp's kink
        with np.errstate(divide="ignore", invalid="ignore"):
            phi_max = np.where(b > 0, np.arccos(np.clip(-a / b, -1.0, 1.0)), np.where(a > 0, math.pi, 0.0))
        phi = 0.5 * phi_max * (x[None, None, None, :] + 1.0)
        f = evaluate_lobe_numpy(a + b * np.cos(phi), shininess) * np.sin(beta)
        inner = (f * w[None, None, None, :]).sum(axis=3) * phi_max[..., 0]
        total += (inner * w[None, None, :]).sum(axis=2) * half
    return total.reshape(-1)


def evaluate_lobe_numpy(cos_angle: np.ndarray, shininess: float) -> np.ndarray:
    """`lobe_kernel` on NumPy in float64 (table building)."""
    with np.errstate(all="ignore"):
        return np.asarray(lobe_kernel(NUMPY_OPS, np.asarray(cos_angle, np.float64), float(shininess)))


def localised_convolve(
    env: np.ndarray,
    dist: np.ndarray,
    points: np.ndarray,
    axes: np.ndarray,
    *,
    shininess: float = 0.0,
    rule: str = "seed",
    mode: str = "point",
    lut: np.ndarray | None = None,
    float32: bool = False,
) -> np.ndarray:
    """The localised convolution (001:637-729) at shading points (P, 3) (relative to the map's reference
    point) with lobe axes (P, 3) → (P,): Σ_t L_t · weight_t (`localised_term_kernel`).

    ``rule``: the base texel solid angle Ω (`texel_solid_angle`: "seed" is the listing's constant);
    ``mode``: "point", "cap" (diffuse only) or "lut" (``lut`` from `cap_lobe_table`). ``float32`` runs the
    kernel in float32 (the shader's precision)."""
    env = np.asarray(env, np.float64).reshape(-1)
    dist = np.asarray(dist, np.float64).reshape(-1)
    n = _resolution_of(env)
    if mode == "cap" and shininess > 0:
        raise ValueError("mode 'cap' is the clamped-cosine cap integral: diffuse (shininess 0) only")
    if mode == "lut" and lut is None:
        raise ValueError("mode 'lut' needs a cap table (cap_lobe_table)")
    lut_arr = np.zeros(4) if lut is None else np.asarray(lut, np.float64).reshape(-1)
    lut_size = round(math.sqrt(lut_arr.size))
    pts = cube_texels(n)["point"]
    dw = texel_solid_angle(n, rule)
    dtype = np.float32 if float32 else np.float64
    p = np.asarray(points, np.float64).reshape(-1, 3)
    ax = np.asarray(axes, np.float64).reshape(-1, 3)

    def k(ops, px, py, pz, nx, ny, nz, lx, ly, lz, d, w):
        table = _table_like(ops, lut_arr.astype(dtype), px)
        return localised_term_kernel(
            ops, px, py, pz, nx, ny, nz, lx, ly, lz, d, w, float(shininess), mode, table, lut_size
        )

    out = np.empty(len(p))
    chunk = max(1, (1 << 20) // env.size)
    for s in range(0, len(p), chunk):
        pp, aa = p[s : s + chunk].astype(dtype), ax[s : s + chunk].astype(dtype)
        w = evaluate(
            k,
            pp[:, 0:1],
            pp[:, 1:2],
            pp[:, 2:3],
            aa[:, 0:1],
            aa[:, 1:2],
            aa[:, 2:3],
            pts[None, :, 0].astype(dtype),
            pts[None, :, 1].astype(dtype),
            pts[None, :, 2].astype(dtype),
            dist[None, :].astype(dtype),
            dw[None, :].astype(dtype),
        )
        out[s : s + chunk] = (np.asarray(w, np.float64) * env[None, :]).sum(axis=1)
    return out


# ================================================================================ distance impostors
def hit_parallax_kernel(ops, dist_map, x, y, z, rx, ry, rz, resolution, bilinear):
    """The one-lookup ``Hit`` (001:547-553): t = dist(R) − x·R, hit = x + t·R (x relative to the
    reference point)."""
    r1 = cube_lookup_kernel(ops, dist_map, rx, ry, rz, resolution, bilinear)
    t = r1 - (x * rx + y * ry + z * rz)
    return x + rx * t, y + ry * t, z + rz * t


def _ratio(ops, dist_map, x, y, z, resolution, bilinear):
    """λ(l) = |l|/dist(l): < 1 in front of the stored surface, > 1 behind it."""
    d = cube_lookup_kernel(ops, dist_map, x, y, z, resolution, bilinear)
    return safe_sqrt(ops, x * x + y * y + z * z) / ops.maximum(d, 1e-30)


def hit_iterative_kernel(
    ops, dist_map, x, y, z, rx, ry, rz, resolution, bilinear, iterations, tolerance=1e-3
):
    """The iterative ``Hit`` (001:841-866): secant search on λ(x + t·R) = 1, ``iterations`` steps.

    As printed except for two guards, both inert where the listing is finite: the secant denominators
    (λ − λ_over, λ − λ_under) are kept away from 0 (the listing divides 0/0 when two lookups return the same
    texel, a plateau of nearest filtering), and "no overshoot yet" is a flag, not ``dov == 0``."""
    r1 = cube_lookup_kernel(ops, dist_map, rx, ry, rz, resolution, bilinear)
    ppp = _ratio(ops, dist_map, x, y, z, resolution, bilinear)
    t = r1 * (1.0 - ppp)
    t_un, p_un = t * 0.0, ppp
    t_ov, p_ov, have_ov = t * 0.0, ppp, t < -1e30
    for _ in range(int(iterations)):
        lam = _ratio(ops, dist_map, x + rx * t, y + ry * t, z + rz * t, resolution, bilinear)
        under = lam < 1.0 - tolerance
        over = lam > 1.0 + tolerance
        den_o = lam - p_ov
        den_o = ops.select(ops.abs(den_o) < 1e-12, 1e-12, den_o)
        den_u = lam - p_un
        den_u = ops.select(ops.abs(den_u) < 1e-12, 1e-12, den_u)
        step_u = ops.select(have_ov, (t - t_ov) * (1.0 - lam) / den_o, r1 * (1.0 - lam))
        step_o = (t - t_un) * (1.0 - lam) / den_u
        t_un = ops.select(under, t, t_un)
        p_un = ops.select(under, lam, p_un)
        t_ov = ops.select(over, t, t_ov)
        p_ov = ops.select(over, lam, p_ov)
        have_ov = have_ov | over
        t = t + ops.select(under, step_u, ops.select(over, step_o, 0.0))
    return x + rx * t, y + ry * t, z + rz * t


def impostor_hit(
    dist_map: np.ndarray,
    origins,
    directions,
    *,
    iterations: int | None = None,
    bilinear: bool = True,
    numpy: bool = False,
) -> np.ndarray:
    """Approximate hit points (…, 3) of rays (origins relative to the reference point, unit directions) on
    the surface stored in ``dist_map``: the one-lookup form when ``iterations`` is None, else the secant
    search with that many iterations. Runs on the default Dr.Jit backend in the arrays' precision, or
    the NumPy text (``numpy``: small batches, where compiling the unrolled search would dominate)."""
    table = np.asarray(dist_map).reshape(-1)
    n = _resolution_of(table)
    o = np.asarray(origins)
    d = np.asarray(directions)

    def k(ops, x, y, z, rx, ry, rz):
        tab = _table_like(ops, table.astype(np.asarray(o).dtype), x)
        if iterations is None:
            return hit_parallax_kernel(ops, tab, x, y, z, rx, ry, rz, n, bilinear)
        return hit_iterative_kernel(ops, tab, x, y, z, rx, ry, rz, n, bilinear, iterations)

    run = evaluate_numpy if numpy else evaluate
    with np.errstate(all="ignore"):
        out = run(k, o[..., 0], o[..., 1], o[..., 2], d[..., 0], d[..., 1], d[..., 2])
    return np.stack([np.asarray(c) for c in out], -1)


# ====================================================================================== method tables
_SHININESS = Param(6.0, -1.0, 1e4, unit="1", description="Phong exponent s; s ≤ 0 selects the clamped cosine")

_P = tuple(
    Input(f"p{c}", "m", f"shading point {c}, relative to the reference point", (-1.5, 1.5)) for c in "xyz"
)
_N = tuple(Input(f"n{c}", "1", f"lobe axis {c} (normal or reflection direction)", (-1.0, 1.0)) for c in "xyz")
_L = (
    *(Input(f"l{c}", "1", f"texel point {c} on the cube of edge 2", (-1.0, 1.0)) for c in "xyz"),
    Input("dist", "m", "distance stored in the texel", (0.05, 5.0)),
    Input("solid_angle", "sr", "the texel's base solid angle Ω", (1e-4, 1.0)),
)


# ================================================================================ Fresnel split
def schlick_fresnel_kernel(ops, cos_i, f0):
    """Schlick's approximation F = F₀ + (1 − F₀)(1 − cos θᵢ)⁵ of the unpolarised Fresnel reflectance of a
    dielectric seen from outside; F₀ = ((n − 1)/(n + 1))² (1.5: 0.04). cos θᵢ is clamped to [0, 1]: F → 1
    at grazing incidence (cos θᵢ → 0), F₀ head-on. Dimensionless."""
    m = 1.0 - ops.minimum(ops.maximum(cos_i, 0.0), 1.0)
    m2 = m * m
    return f0 + (1.0 - f0) * (m2 * m2 * m)


def dielectric_fresnel_kernel(ops, cos_i, eta):
    """Exact unpolarised Fresnel reflectance F = ½(r_s² + r_p²) of a smooth interface, light arriving at
    cos θᵢ from the side of index n₁ onto index n₂, eta = n₂/n₁ (outside→glass 1.5; inside→out 1/1.5):
    r_s = (cos θᵢ − η cos θₜ)/(cos θᵢ + η cos θₜ), r_p = (η cos θᵢ − cos θₜ)/(η cos θᵢ + cos θₜ),
    cos θₜ = √(1 − sin²θᵢ/η²). Total internal reflection (sin²θᵢ/η² ≥ 1): F = 1. Dimensionless; cos θᵢ
    clamped to [0, 1] (F(0) = 1)."""
    c = ops.minimum(ops.maximum(cos_i, 0.0), 1.0)
    s2t = (1.0 - c * c) / (eta * eta)
    ct = safe_sqrt(ops, 1.0 - s2t)
    rs = safe_div(ops, c - eta * ct, c + eta * ct)
    rp = safe_div(ops, eta * c - ct, eta * c + ct)
    f = 0.5 * (rs * rs + rp * rp)
    return ops.select(s2t >= 1.0, 1.0 + 0.0 * c, ops.minimum(f, 1.0))


def fresnel_split_kernel(ops, l_reflect, l_refract, fresnel):
    """What a real-time glass shader outputs from its two lookups: F·L_reflect + (1 − F)·L_refract (the
    seed's ``F·reflect + (1 − F)·refract``); radiance in the lookups' units."""
    return fresnel * l_reflect + (1.0 - fresnel) * l_refract


METHODS = method_table(
    [
        Method(
            "localised-seed",
            "Localised, seed (constant Ω, point sample)",
            localised_term_kernel,
            inputs=_P + _N + _L,
            params={"shininess": _SHININESS},
            fixed={"mode": "point", "lut": None, "lut_size": 2},
            quantity="per-texel weight",
            formula="L_t·lobe(n·ω')·Ω', Ω' = d²Ω/(Δ²(1−Ω/2π) + d²Ω/2π), Ω = 4/(N² + 2/π)",
            source="001:637-710",
            description="solid_angle input: seed_solid_angle(N) for every texel",
        ),
        Method(
            "localised-exact-omega",
            "Localised, exact texel Ω (point sample)",
            localised_term_kernel,
            inputs=_P + _N + _L,
            params={"shininess": _SHININESS},
            fixed={"mode": "point", "lut": None, "lut_size": 2},
            quantity="per-texel weight",
            formula="L_t·lobe(n·ω')·Ω', Ω exact (atan2 form)",
            source="001:637-710, Ω corrected",
            description="solid_angle input: texel_solid_angle(N, 'exact')",
        ),
        Method(
            "localised-cap",
            "Localised, cap integral (cosine look-up, exact)",
            localised_term_kernel,
            inputs=_P + _N + _L,
            params={"shininess": _SHININESS},
            fixed={"mode": "cap", "lut": None, "lut_size": 2},
            quantity="per-texel weight",
            formula="L_t·∫_cap(Ω') max(n·ω, 0) dω (Snyder's horizon-clipped form)",
            source="001:716-729",
        ),
    ]
)
"""The localised convolution's per-texel weights as data (the experiment's rows add the knobs: cube
resolution, solid-angle rule, look-up size)."""

HIT_METHODS = method_table(
    [
        Method(
            "classic",
            "Classic environment map (lookup at R)",
            cube_lookup_kernel,
            inputs=(Input("dx", "1"), Input("dy", "1"), Input("dz", "1")),
            fixed={"table": None, "resolution": 1, "bilinear": True},
            formula="L(R)",
            source="001:482-497",
        ),
        Method(
            "parallax",
            "Distance impostor, one lookup",
            hit_parallax_kernel,
            inputs=(Input("x", "m"), Input("y", "m"), Input("z", "m"), Input("rx"), Input("ry"), Input("rz")),
            fixed={"dist_map": None, "resolution": 1, "bilinear": True},
            formula="x + R·(dist(R) − x·R)",
            source="001:547-553",
        ),
        Method(
            "iterative",
            "Distance impostor, secant search",
            hit_iterative_kernel,
            inputs=(Input("x", "m"), Input("y", "m"), Input("z", "m"), Input("rx"), Input("ry"), Input("rz")),
            fixed={"dist_map": None, "resolution": 1, "bilinear": True, "iterations": 4},
            formula="secant search on |l|/dist(l) = 1",
            source="001:841-866",
        ),
    ]
)
"""The impostor search methods as data; their knobs (cube resolution, filtering, iterations) are set
per row by the experiment."""

_COS_I = Input("cos_i", "1", "cosine of the incidence angle (outside, against the normal)", (0.0, 1.0))
FRESNEL_METHODS = method_table(
    [
        Method(
            "schlick",
            "Schlick's Fresnel (F₀ = ((n − 1)/(n + 1))²)",
            schlick_fresnel_kernel,
            inputs=(_COS_I,),
            params={"f0": Param(0.04, 0.0, 1.0, unit="1", description="reflectance at normal incidence")},
            quantity="Fresnel reflectance",
            formula="F₀ + (1 − F₀)(1 − cos θᵢ)⁵",
            source="Schlick 1994 (the usual real-time form)",
        ),
        Method(
            "exact",
            "Exact dielectric Fresnel (unpolarised)",
            dielectric_fresnel_kernel,
            inputs=(_COS_I,),
            params={"eta": Param(1.5, 1.0, 4.0, unit="1", description="n_inside/n_outside")},
            quantity="Fresnel reflectance",
            formula="½(r_s² + r_p²), 1 on total internal reflection",
            source="Fresnel equations",
        ),
    ]
)
"""The Fresnel weights of the glass sphere's reflection/refraction split, as data (the experiment's radiance
rows combine each with a hit-point method by `fresnel_split_kernel`)."""
