"""HDR-ꟻLIP maps of many pairs that share images, each image's share of the work done once.

ꟻLIP (Andersson et al. 2020, "ꟻLIP: A Difference Evaluator for Alternating Images"; HDR-ꟻLIP: Andersson
et al. 2021, "Visualizing Errors in Rendered High Dynamic Range Images") compares a test image with a
reference at several exposures and keeps, per pixel, the largest LDR-ꟻLIP error. This module follows
NVIDIA's reference code (github.com/NVlabs/flip, ``src/cpp/FLIP.h``, commit 1eb247c; flip_evaluator 1.7 is
the same code) step for step, with one change of arithmetic and one of order:

- per exposure e (``numExposures`` of them, evenly from ``startExposure`` to ``stopExposure``, computed in
  float32 as the reference code does): each image × 2^e, the ACES curve
  (0.9036 x² + 0.018 x) / (0.8748 x² + 0.354 x + 0.14), clamped to [0, 1], to YCxCz;
- colour: the YCxCz channels filtered by the contrast-sensitivity Gaussians (separable: Y and Cx by one
  Gaussian each, Cz by a sum of two, each split into its two 1-D factors), back to linear RGB clamped to
  [0, 1], to CIELAB, Hunt-adjusted (a, b × 0.01 L); the difference of two images is HyAB
  (|ΔL| + ‖Δ(a, b)‖), raised to 0.7 and remapped to [0, 1] (below 0.4 × its maximum, the green–blue
  distance, onto [0, 0.95], above onto (0.95, 1]);
- features: the normalised luminance (Y + 16)/116 filtered by a Gaussian of σ = 0.041 · ppd pixels and its
  first and second derivatives (separable); an image's edge and point strengths are the norms of the
  first- and second-derivative responses; the feature difference of two images is
  (max(|Δedge|, |Δpoint|) / √2)^0.5;
- the LDR-ꟻLIP error is colour^(1 − feature), and the HDR-ꟻLIP map the largest over the exposures.

Every step but the two differences depends on one image only, and both differences are symmetric. So the
maps of several pairs at the same exposures are computed from each distinct image's filtered colour
(L, a', b') and feature strengths (edge, point), once per image (`ImageFeatures`), then combined per pair
(`hdr_flip_maps`): a case's rows share their reference, and the noise floor's noisy references share the
reference as their test; ꟻLIP called per pair filtered the shared image again for every pair (issue 33: half
of a 256² audit's evaluation time).

The arithmetic is float32, as the reference code's (`_DTYPE`; float64 gave maps no closer to its than its
own rounding and took 2.1× as long). The one change is of order: each 1-D filter pass is a product with a
banded matrix (`_filter_axis`, edge-clamped as the reference code's loops, computed by BLAS in blocks), not a
loop over the taps, so the sums round differently. Where a test equals the reference the map is 0 in both.
Where they differ by a few float32 ulps, either map is rounding noise raised to small powers (colour^0.7 and
then ^(1 − feature)). tests/test_hdr_flip.py compares the maps with flip_evaluator's on rendered and
synthetic images (within 1e-4 a pixel).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["FLIP_PPD", "exposures", "hdr_flip_maps", "image_features"]

_F = np.float32
FLIP_PPD = float(_F(0.7) * (_F(3840.0) / _F(0.7)) * (_F(math.pi) / _F(180.0)))
"""ꟻLIP's default pixels per degree: 0.7 m from a 0.7 m wide 3840-pixel display (float32, as ꟻLIP)."""

_ACES = (
    float(_F(0.6) * _F(0.6) * _F(2.51)),
    float(_F(0.6) * _F(0.03)),
    0.0,
    float(_F(0.6) * _F(0.6) * _F(2.43)),
    float(_F(0.6) * _F(0.59)),
    float(_F(0.14)),
)
"""ꟻLIP's ACES tone-mapping coefficients (0.6 cancels a pre-exposure), in float32 as its code holds them."""

_GQC, _GPC, _GPT, _GW, _GQF = 0.7, 0.4, 0.95, 0.082, 0.5
"""ꟻLIP's constants: colour exponent, cutoff fraction and its remapped value, feature filter width (degrees),
feature exponent."""

_ILLUMINANT = np.array([0.950428545, 1.0, 1.088900371])
_INV_ILLUMINANT = np.array([1.052156925, 1.0, 0.918357670])
_RGB_TO_XYZ = np.array(
    [
        [10135552.0 / 24577794.0, 8788810.0 / 24577794.0, 4435075.0 / 24577794.0],
        [2613072.0 / 12288897.0, 8788810.0 / 12288897.0, 887015.0 / 12288897.0],
        [1425312.0 / 73733382.0, 8788810.0 / 73733382.0, 70074185.0 / 73733382.0],
    ]
)
_XYZ_TO_RGB = np.array(
    [
        [3.241003275, -1.537398934, -0.498615861],
        [-0.969224334, 1.875930071, 0.041554224],
        [0.055639423, -0.204011202, 1.057148933],
    ]
)
_DELTA = 6.0 / 29.0


def _lab_f(t):
    """CIELAB's f(t): t^(1/3) above δ³, else t / (3δ²) + 4/29 (δ = 6/29)."""
    return np.where(t > _DELTA**3, np.cbrt(t), t / (3.0 * _DELTA**2) + 4.0 / 29.0)


def _linear(m: np.ndarray, planes) -> list[np.ndarray]:
    """The three planes m · (p₀, p₁, p₂) of a 3 × 3 matrix ``m`` applied to three planes."""
    c = [[float(v) for v in row] for row in m]  # Python floats: the planes keep their precision
    return [c[i][0] * planes[0] + c[i][1] * planes[1] + c[i][2] * planes[2] for i in range(3)]


def _hunt_lab(rgb) -> tuple:
    """Three planes of linear RGB → Hunt-adjusted CIELAB (L, 0.01·L·a, 0.01·L·b), three planes of their
    precision."""
    xyz = _linear(_RGB_TO_XYZ, rgb)
    fx, fy, fz = (_lab_f(p * float(k)) for p, k in zip(xyz, _INV_ILLUMINANT, strict=True))
    lum = 116.0 * fy - 16.0
    return lum, (0.01 * 500.0) * lum * (fx - fy), (0.01 * 200.0) * lum * (fy - fz)


def _cmax() -> float:
    """ꟻLIP's c_max: the Hunt-adjusted HyAB distance of pure green and pure blue, raised to 0.7."""
    lum, a, b = _hunt_lab([np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0])])
    return float((abs(lum[0] - lum[1]) + math.hypot(a[0] - a[1], b[0] - b[1])) ** _GQC)


_CMAX = _cmax()
_PCCMAX = _GPC * _CMAX


def _gaussian(x2, a, b):
    """ꟻLIP's CSF Gaussian a·√(π/b)·exp(−π² x²/b)."""
    return a * math.sqrt(math.pi / b) * np.exp(-(math.pi**2) * x2 / b)


def _spatial_filters(ppd: float) -> np.ndarray:
    """The four 1-D colour filters (4, 2r + 1): Y's, Cx's, and the two factors of Cz's sum of Gaussians,
    normalised as ꟻLIP normalises them (Y and Cx to sum 1; Cz's 2-D filter g₁g₁ᵀ + g₂g₂ᵀ to sum 1)."""
    radius = math.ceil(3.0 * math.sqrt(0.04 / (2.0 * math.pi**2)) * ppd)
    x2 = ((np.arange(2 * radius + 1) - radius) / ppd) ** 2
    gy, gcx = _gaussian(x2, 1.0, 0.0047), _gaussian(x2, 1.0, 0.0053)
    gz1 = np.sqrt(34.1 * math.sqrt(math.pi / 0.04)) * np.exp(-(math.pi**2) * x2 / 0.04)
    gz2 = np.sqrt(13.5 * math.sqrt(math.pi / 0.025)) * np.exp(-(math.pi**2) * x2 / 0.025)
    nz = 1.0 / math.hypot(gz1.sum(), gz2.sum())
    return np.stack([gy / gy.sum(), gcx / gcx.sum(), gz1 * nz, gz2 * nz])


def _feature_filters(ppd: float) -> np.ndarray:
    """The Gaussian of σ = ½·0.082·ppd pixels and its first and second derivatives (3, 2r + 1), r = ⌈3σ⌉:
    the Gaussian normalised to sum 1, each derivative's positive and negative weights to ±1."""
    sd = 0.5 * _GW * ppd
    radius = math.ceil(3.0 * sd)
    x = np.arange(2 * radius + 1, dtype=np.float64) - radius
    g = np.exp(-(x * x) / (2.0 * sd * sd))
    dg = -x * g
    ddg = (x * x / (sd * sd) - 1.0) * g

    def signed(w):
        pos, neg = w[w > 0].sum(), -w[w < 0].sum()
        return np.where(w > 0, w / pos, w / neg)

    return np.stack([g / g.sum(), signed(dg), signed(ddg)])


_DTYPE = np.float32
"""The working precision: the reference code's."""
_BLOCK = 64
"""Outputs per block of a filter pass (`_filter_axis`): a block reads BLOCK + 2r inputs."""


@functools.lru_cache(maxsize=16)
def _band(filters_bytes: bytes, n_filters: int, b: int, dtype: str) -> np.ndarray:
    """The banded (B + 2r, F·B) matrix of F 1-D filters (their float64 bytes), of ``dtype``: column f·B + j
    holds filter f at rows j … j + 2r."""
    filters = np.frombuffer(filters_bytes).reshape(n_filters, -1)
    width = filters.shape[1]
    band = np.zeros((b + width - 1, n_filters, b))
    cols = np.arange(b)
    for k in range(width):
        band[cols + k, :, cols] = filters[:, k]
    band = band.reshape(b + width - 1, n_filters * b).astype(dtype)
    band.flags.writeable = False
    return band


def _filter_axis(a: np.ndarray, filters: np.ndarray, axis: int) -> np.ndarray:
    """Correlate ``a`` along ``axis`` (-1: x, -2: y) with each 1-D filter of ``filters`` (F, 2r + 1), indices
    clamped at the edges as ꟻLIP's loops clamp them:
    out[f, …, j, …] = Σ_k filters[f, k]·a[…, clamp(j + k − r), …].
    Returns (F, *a.shape). One matrix product with a banded matrix (`_band`): the edge-padded axis cut into
    overlapping windows of B + 2r inputs for B = min(N, `_BLOCK`) outputs each."""
    n_filters, width = filters.shape
    r = width // 2
    n = a.shape[axis]
    b = min(n, _BLOCK)
    blocks = -(-n // b)
    # edge-padded by r before and r + blocks·b − n after: index i of the padded axis reads clamp(i − r)
    # (NumPy's ``pad(mode="edge")`` gives the same array, with ~0.1 ms of Python a call: issue 33)
    clamped = np.clip(np.arange(-r, blocks * b + r), 0, n - 1)
    padded = np.take(a, clamped, axis=axis)
    band = _band(np.ascontiguousarray(filters, np.float64).tobytes(), n_filters, b, a.dtype.str)
    st = padded.strides
    if axis == -1:
        windows = np.lib.stride_tricks.as_strided(
            padded, (*padded.shape[:-1], blocks, b + 2 * r), (*st[:-1], b * st[-1], st[-1]), writeable=False
        )
        out = (windows.reshape(-1, b + 2 * r) @ band).reshape(*a.shape[:-1], blocks, n_filters, b)
        out = np.moveaxis(out, -2, 0).reshape(n_filters, *a.shape[:-1], blocks * b)
        return out[..., :n]
    windows = np.lib.stride_tricks.as_strided(
        padded,
        (*padded.shape[:-2], blocks, b + 2 * r, padded.shape[-1]),
        (*st[:-2], b * st[-2], st[-2], st[-1]),
        writeable=False,
    )
    out = band.T @ windows  # (…, blocks, F·B, W)
    out = out.reshape(*a.shape[:-2], blocks, n_filters, b, a.shape[-1])
    out = np.moveaxis(out, -3, 0).reshape(n_filters, *a.shape[:-2], blocks * b, a.shape[-1])
    return out[..., :n, :]


def exposures(params) -> np.ndarray:
    """The exposure multipliers 2^e of ꟻLIP's parameters (``startExposure``, ``stopExposure``,
    ``numExposures``), with e computed in float32 as ꟻLIP computes it."""
    start, stop, count = _F(params["startExposure"]), _F(params["stopExposure"]), int(params["numExposures"])
    step = _F((stop - start) / _F(count - 1))
    return np.array([float(np.power(_F(2.0), _F(start + _F(i) * step))) for i in range(count)])


@dataclass(frozen=True)
class ImageFeatures:
    """One image's share of LDR-ꟻLIP at each exposure (E, H, W) arrays: Hunt-adjusted CIELAB of the
    filtered colour (``lum``, ``a``, ``b``), and the edge and point strengths of its luminance."""

    lum: np.ndarray
    a: np.ndarray
    b: np.ndarray
    edge: np.ndarray
    point: np.ndarray


_YCXCZ = np.stack(
    [
        116.0 * _RGB_TO_XYZ[1] * _INV_ILLUMINANT[1],
        500.0 * (_RGB_TO_XYZ[0] * _INV_ILLUMINANT[0] - _RGB_TO_XYZ[1] * _INV_ILLUMINANT[1]),
        200.0 * (_RGB_TO_XYZ[1] * _INV_ILLUMINANT[1] - _RGB_TO_XYZ[2] * _INV_ILLUMINANT[2]),
    ]
)
"""Linear RGB → (Y + 16, Cx, Cz): ꟻLIP's RGB → XYZ → YCxCz, one linear map."""


def image_features(image: np.ndarray, scales: np.ndarray, ppd: float = FLIP_PPD) -> ImageFeatures:
    """`ImageFeatures` of ``image`` (H, W, 3, linear RGB, non-negative) at each exposure multiplier of
    ``scales`` (E,)."""
    img = np.asarray(image, _DTYPE)
    scales = np.asarray(scales, _DTYPE)[:, None, None]
    a0, a1, _, a3, a4, a5 = _ACES  # (a2 = 0)
    planes = []
    for ch in range(3):
        c = img[None, :, :, ch] * scales
        planes.append(np.clip((a0 * c + a1) * c / ((a3 * c + a4) * c + a5), 0.0, 1.0))
    y16, cx, cz = _linear(_YCXCZ, planes)  # y16 = Y + 16
    spatial = _spatial_filters(ppd)
    fy = _filter_axis(_filter_axis(y16, spatial[0:1], -1)[0], spatial[0:1], -2)[0]
    fcx = _filter_axis(_filter_axis(cx, spatial[1:2], -1)[0], spatial[1:2], -2)[0]
    z1, z2 = _filter_axis(cz, spatial[2:4], -1)
    fcz = _filter_axis(z1, spatial[2:3], -2)[0] + _filter_axis(z2, spatial[3:4], -2)[0]
    yn = fy / 116.0
    x_ill, z_ill = float(_ILLUMINANT[0]), float(_ILLUMINANT[2])  # (Python floats: float32 stays)
    filtered_xyz = [(yn + fcx / 500.0) * x_ill, yn, (yn - fcz / 200.0) * z_ill]
    lum, a, b = _hunt_lab([np.clip(p, 0.0, 1.0) for p in _linear(_XYZ_TO_RGB, filtered_xyz)])
    feature = _feature_filters(ppd)
    dx_, ddx_, gx_ = _filter_axis(y16 / 116.0, feature[[1, 2, 0]], -1)  # along x: d/dx, d²/dx², Gaussian
    dx = _filter_axis(dx_, feature[0:1], -2)[0]
    ddx = _filter_axis(ddx_, feature[0:1], -2)[0]
    dy, ddy = _filter_axis(gx_, feature[1:3], -2)
    return ImageFeatures(lum, a, b, np.sqrt(dx * dx + dy * dy), np.sqrt(ddx * ddx + ddy * ddy))


def ldr_errors(p: ImageFeatures, q: ImageFeatures) -> np.ndarray:
    """The LDR-ꟻLIP error (E, H, W) between two images' features: colour^(1 − feature)."""
    colour = (np.abs(p.lum - q.lum) + np.hypot(p.a - q.a, p.b - q.b)) ** _GQC
    above = _GPT + (colour - _PCCMAX) / (_CMAX - _PCCMAX) * (1.0 - _GPT)
    colour = np.where(colour < _PCCMAX, colour * (_GPT / _PCCMAX), above)
    feature = (np.maximum(np.abs(p.edge - q.edge), np.abs(p.point - q.point)) / math.sqrt(2.0)) ** _GQF
    return colour ** (1.0 - feature)


_CHUNK_ELEMENTS = 1 << 19
"""At most this many pixels × exposures per image in one `image_features` call (its ~30 float32
temporaries then stay near 2 MiB each)."""


def hdr_flip_maps(images: Sequence[np.ndarray], pairs: Sequence[tuple[int, int]], params) -> list[np.ndarray]:
    """The HDR-ꟻLIP map (H, W) of each pair (i, j) of ``images`` (reference ``images[i]``, test
    ``images[j]``; linear RGB (H, W, 3), non-negative, one shape) at ꟻLIP's exposure ``params``; each
    image's features computed once per exposure (module text)."""
    scales = exposures(params)
    h, w = images[0].shape[:2]
    maps = [np.zeros((h, w), _DTYPE) for _ in pairs]
    used = sorted({k for pair in pairs for k in pair})
    step = max(1, _CHUNK_ELEMENTS // (h * w))
    for e in range(0, len(scales), step):
        feats = {k: image_features(images[k], scales[e : e + step]) for k in used}
        for out, (i, j) in zip(maps, pairs, strict=True):
            np.maximum(out, ldr_errors(feats[i], feats[j]).max(axis=0), out=out)
    return [m.astype(np.float64) for m in maps]
