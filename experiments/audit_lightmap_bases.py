r"""The lightmap rows of the ``irradiance-bases`` audit: H-basis and radiosity normal mapping in the visible
surfaces' UV tangent frames.

A lightmap texel stores irradiance in its surface's **tangent frame** (t, b, N), for the bumped normals a
normal map may give it (`rtfit.realtime.hemisphere_bases`). On a user's scene each visible pixel is such a
texel:

* **frame**: N is the G-buffer's shading normal (turned to face the camera), t is Mitsuba's ``dp_du`` at the
  pixel-centre hit (`rtfit.reference.estimators.uv_tangents`) orthonormalised against N (Gram–Schmidt:
  t = (∂p/∂u − (∂p/∂u·N) N)/|…|), b = N × t. Only a shape with a UV parametrisation of its own has a
  ``dp_du`` an artist laid a lightmap out in (a mesh with texture coordinates, Mitsuba's analytic sphere,
  disk, cylinder and rectangle: `shape_has_uv`); pixels of other shapes (a mesh without texcoords, whose
  ``dp_du`` is a triangle edge), a sphere's poles (``dp_du`` = 0) and a ``dp_du`` along N are left out, and
  the case says how many;
* **bake** (what a lightmapper stores per texel, from the environment alone, unoccluded like the rest of the
  family): the H-basis coefficients c_k = ∫_{Ω+} E(n) H_k(n) dn by `hbasis_project` on the hemisphere rule
  `BAKE_RULE` (8 Gauss–Legendre nodes in cos θ × 16 in φ: measured by the irradiance-bases experiment at
  ≤ 1.4e-3 of c₁ against a 32 × 64 rule), and the three RNM lightmaps E(b_i) at Valve's directions
  `RNM_BASIS` in the frame. Texels of equal frames (a flat wall) are baked once;
* **evaluation** at the texel's own normal, n_t = (0, 0, 1): the scene has no normal map for the bases to
  reconstruct, so each row's error is its error at the frame's pole. There H₂, H₄, H₅ and H₆ vanish, so
  ``hbasis-4`` and ``hbasis-6`` give the same value (c₁H₁ + c₃H₃(1)); RNM returns Σ w_i E(b_i) with every
  d_i = 1/√3 (the linear weights: √3 × the mean of the three lightmaps).

The irradiance the bake reads: E(n) of the environment's lat-long bake (`BAKE_ROWS` rows) summed over
coarse cells (`CELL_ROWS` × 2·`CELL_ROWS`), each cell as its **vector irradiance** V_c = Σ_{j∈c} w_j L_j ω_j
per channel (`cell_vectors`), E(n) = Σ_c max(n·V_c, 0): exact (Σ_j w_j L_j n·ω_j) for every cell wholly
above n's horizon, so the only error is in the band of cells the horizon cuts, O(h²); a constant part and
a sunsky's disc sun are added exactly. The case's notes give the measured largest relative difference from
the full quadrature of the bake at a sample of the texels' RNM directions. (The full quadrature at every
direction of every texel was ~50 s for 24² texels on 2 CPU cores; this is ~40× fewer products.)

The rows read their stored floats as per-texel inputs c1..cS (`per_texel`: the table's own kernel given the
tuple), channel-major as the kernels expect.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rtfit.realtime.environment_bases import ALL_METHODS, METHODS
from rtfit.realtime.hemisphere_bases import (
    HEMISPHERE_METHODS,
    RNM_BASIS,
    hbasis_design_matrix,
    hbasis_project,
    hemisphere_quadrature,
)
from rtfit.realtime.methods import Input, Method
from rtfit.reference.environments import (
    direction_to_uv,
    irradiance_quadrature,
    quadrature_samples,
    samples_irradiance,
)
from rtfit.reference.estimators import uv_tangents
from rtfit.reference.variants import backend_of

from .audit_setup import AuditReference, AuditSetup

__all__ = [
    "BAKE_RULE",
    "CELL_ROWS",
    "LIGHTMAP_ROWS",
    "Lightmaps",
    "cell_irradiance",
    "cell_vectors",
    "lightmap_rows",
    "lightmaps",
    "per_texel",
    "texel_frames",
    "texel_reference",
]

BAKE_RULE = (8, 16)
"""Hemisphere rule of the H-basis bake: Gauss–Legendre nodes in cos θ × midpoints in φ (the irradiance-bases
experiment's quick rule)."""
CELL_ROWS = 32
"""Rows of the coarse cells of `cell_vectors` (× 2·CELL_ROWS columns; 5.6° cells)."""
LIGHTMAP_ROWS = tuple(m for m in ALL_METHODS if m not in METHODS)
"""The row ids this module adds: those of `ALL_METHODS` that `METHODS` lacks (`HEMISPHERE_METHODS`)."""
_CHECK_DIRECTIONS = 64  # texel directions at which the cell sum is compared with the full quadrature


def per_texel(method: Method) -> Method:
    """``method`` (a row of `HEMISPHERE_METHODS`) reading its ``coeffs`` (``method.storage`` floats,
    channel-major) as per-texel inputs c1..cS: the same kernel given the tuple (c1, …, cS)."""
    names = tuple(f"c{k + 1}" for k in range(method.storage or 0))
    base = method.kernel

    def kernel(ops, **kw):
        coeffs = tuple(kw.pop(n) for n in names)
        return base(ops, coeffs=coeffs, **kw)

    normal = tuple(i for i in method.inputs if i.name in ("nx", "ny", "nz"))
    stored = tuple(Input(n, "W/m²", f"stored float {k + 1} of the texel (channel-major)") for k, n in
                   enumerate(names))  # fmt: skip
    return replace(method, kernel=kernel, inputs=(*normal, *stored))


def texel_frames(setup: AuditSetup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frames (F, 3, 3) rows t, b, N; index (P,) of each masked pixel's frame, −1 where it has none;
    UV-less pixels (P,) bool) for the masked pixels of the G-buffer (module docstring). Equal frames (to
    1e-6) are one frame."""
    tangent, has_uv = uv_tangents(setup.mi, setup.scene, setup.sensor)
    n = setup.gbuffer.normal[setup.mask].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    du = tangent[setup.mask].astype(np.float64)
    t = du - n * np.sum(du * n, axis=1, keepdims=True)
    length = np.linalg.norm(t, axis=1)
    ok = has_uv[setup.mask] & (length > 1e-6 * np.maximum(np.linalg.norm(du, axis=1), 1e-30))
    t = t / np.maximum(length, 1e-30)[:, None]
    frames = np.stack([t, np.cross(n, t), n], axis=1)
    index = np.full(len(n), -1)
    if not ok.any():
        return np.zeros((0, 3, 3)), index, ~has_uv[setup.mask]
    key = np.round(frames[ok].reshape(-1, 9), 6)
    unique, inverse = np.unique(key, axis=0, return_inverse=True)
    index[ok] = inverse.reshape(-1)
    first = np.zeros(len(unique), np.int64)
    first[inverse.reshape(-1)[::-1]] = np.flatnonzero(ok)[::-1]  # one member of each frame
    return frames[first], index, ~has_uv[setup.mask]


def cell_vectors(env, rows: int = CELL_ROWS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map of ``env`` as vector irradiances of coarse lat-long cells (module docstring): (directions
    (3C, 3), magnitudes (3C,), one-hot channels (3C, 3)) — per channel c, the C cells' V_c/|V_c| and |V_c|
    (W/m²) with V_c = Σ_{j∈cell} w_j L_j,c ω_j over the map's midpoint samples (supersample 1) — the
    arguments of `samples_irradiance`. Empty without a map."""
    if env.radiance_map is None:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    d, w, radiance = quadrature_samples(env.radiance_map, 1)
    u, v = direction_to_uv(d)
    cols = 2 * rows
    cell = np.minimum((v * rows).astype(np.int64), rows - 1) * cols + np.minimum((u * cols).astype(np.int64),
                                                                                   cols - 1)  # fmt: skip
    dirs, mags, chans = [], [], []
    for c in range(3):
        wl = w * radiance[:, c]
        vec = np.stack([np.bincount(cell, wl * d[:, k], rows * cols) for k in range(3)], axis=1)
        mag = np.linalg.norm(vec, axis=1)
        dirs.append(vec / np.maximum(mag, 1e-300)[:, None])
        mags.append(mag)
        chans.append(np.tile(np.eye(3)[c], (len(mag), 1)))
    return np.concatenate(dirs), np.concatenate(mags), np.concatenate(chans)


def cell_irradiance(env, cells, normals, backend: str | None) -> np.ndarray:
    """E (N, 3) (W/m²) of ``env`` at unit ``normals`` (N, 3): the ``cells`` of `cell_vectors`, plus the
    environment's constant part and disc sun exactly (`irradiance_quadrature` without the map)."""
    e = irradiance_quadrature(replace(env, radiance_map=None), normals)
    d, w, channels = cells
    for c in range(3):  # each cell lights one channel: a sum per channel over its own cells, one weight a
        on = channels[:, c] != 0  # product instead of three (issue 33; on Dr.Jit the same sums, bit for bit)
        if on.any():
            e[:, c] = (
                e[:, c] + samples_irradiance(normals, d[on], w[on], channels[on, c : c + 1], backend)[:, 0]
            )
    return e


@dataclass(frozen=True)
class Lightmaps:
    """The baked texels of one environment on the visible pixels (`lightmaps`): ``mask`` (H, W) of the
    texels, ``frames`` (F, 3, 3), ``index`` (P,) frame of each masked pixel (−1: none), ``coeffs`` (row id →
    (S, N) stored floats per texel), ``check`` (largest relative difference of the cell sum from the full
    quadrature at sampled texel directions), ``no_uv`` pixels without a UV parametrisation and ``degenerate``
    pixels with one but no usable ``dp_du``."""

    mask: np.ndarray
    frames: np.ndarray
    index: np.ndarray
    coeffs: dict
    check: float
    no_uv: int
    degenerate: int

    def notes(self) -> tuple[str, ...]:
        texels = int(self.mask.sum())
        left = []
        if self.no_uv:
            left.append(f"{self.no_uv} pixel(s) on shapes without a UV parametrisation")
        if self.degenerate:
            left.append(f"{self.degenerate} with a degenerate ∂p/∂u (a sphere's pole, or along the normal)")
        return (
            f"lightmap texels: {texels} visible pixels in {len(self.frames)} distinct UV tangent frames "
            f"(t = ∂p/∂u orthonormalised against the shading normal)"
            + (f"; left out: {', '.join(left)}" if left else ""),
            f"bake: H-basis by projection on a {BAKE_RULE[0]}×{BAKE_RULE[1]} hemisphere rule, RNM lightmaps "
            "at Valve's three directions; evaluated at each texel's own normal (no normal map: H-4 and H-6 "
            "agree there)",
            f"the bake's irradiance: {CELL_ROWS}×{2 * CELL_ROWS} cells of vector irradiance over the "
            f"environment's bake, largest relative difference from its full quadrature {self.check:.2g} "
            f"(at {_CHECK_DIRECTIONS} sampled texel directions)",
        )


def lightmaps(setup: AuditSetup, env) -> Lightmaps | str:
    """The texels of ``env`` on the visible pixels with a UV tangent frame (module docstring), or the reason
    (one line) why there are none."""
    frames, index, no_uv = texel_frames(setup)
    if not len(frames):
        why = "shows no surface with a UV parametrisation" if no_uv.all() else "has no usable ∂p/∂u"
        return (
            f"{', '.join(LIGHTMAP_ROWS)}: left out: the camera {why} (a mesh with texture coordinates, or "
            "Mitsuba's sphere, disk, cylinder or rectangle) to lay a lightmap's tangent frame in"
        )
    backend = backend_of(setup.variant)
    dirs_t, weights = hemisphere_quadrature(*BAKE_RULE)
    rnm = np.asarray(RNM_BASIS)
    local = np.concatenate([dirs_t, rnm])  # tangent → world: rows of a frame are t, b, N
    world = np.einsum("mk,fkj->fmj", local, frames).reshape(-1, 3)
    cells = cell_vectors(env)
    e = cell_irradiance(env, cells, world, backend).reshape(len(frames), len(local), 3)
    m = len(dirs_t)
    design = hbasis_design_matrix(dirs_t, 6)  # one rule for every texel: its H_k values once (issue 33)
    h6 = np.stack(
        [hbasis_project(dirs_t, weights, e[f, :m], 6, design) for f in range(len(frames))]
    )  # (F, 6, 3)
    lm = e[:, m:]  # (F, 3, 3): rows E_0..E_2, RGB
    sample = world.reshape(len(frames), len(local), 3)[:, m:].reshape(-1, 3)
    sample = sample[np.linspace(0, len(sample) - 1, min(_CHECK_DIRECTIONS, len(sample))).astype(np.int64)]
    full = irradiance_quadrature(env, sample, 1, backend)
    approx = cell_irradiance(env, cells, sample, backend)
    scale = np.maximum(np.abs(full).max(), 1e-30)
    check = float(np.max(np.abs(approx - full)) / scale)
    keep = index >= 0
    f = index[keep]
    coeffs = {}
    for rid in LIGHTMAP_ROWS:
        method = HEMISPHERE_METHODS[rid]
        if rid.startswith("hbasis"):
            count = (method.storage or 0) // 3
            stored = h6[f, :count].transpose(0, 2, 1).reshape(len(f), -1)  # channel-major (R: c1..ck, G, B)
        else:
            stored = lm[f].transpose(0, 2, 1).reshape(len(f), -1)  # channel-major (R: E0 E1 E2, G, B)
        coeffs[rid] = np.ascontiguousarray(stored.T)
    mask = np.zeros_like(setup.mask)
    mask[setup.mask] = keep
    return Lightmaps(mask, frames, index, coeffs, check, int(no_uv.sum()), int((~keep & ~no_uv).sum()))


def lightmap_rows(maps: Lightmaps) -> tuple[dict[str, Method], dict]:
    """(row id → `per_texel` method, row id → its one mapping of inputs over the texels: the tangent-space
    normal (0, 0, 1) and the stored floats)."""
    n = int(maps.mask.sum())
    pole = {"nx": np.zeros(n), "ny": np.zeros(n), "nz": np.ones(n)}
    methods, inputs = {}, {}
    for rid in LIGHTMAP_ROWS:
        methods[rid] = per_texel(HEMISPHERE_METHODS[rid])
        c = maps.coeffs[rid]
        inputs[rid] = ({**pole, **{f"c{k + 1}": c[k] for k in range(len(c))}},)
    return methods, inputs


def texel_reference(ref: AuditReference, mask: np.ndarray) -> AuditReference:
    """The case's reference restricted to the texels' ``mask`` (zero elsewhere, made for ``mask``): no new
    render."""
    keep = mask[..., None].astype(np.float64)
    return replace(ref, mean=ref.mean * keep, stderr=ref.stderr * keep, mask=mask)
