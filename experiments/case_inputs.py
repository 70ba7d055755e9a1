"""Helpers a family's cases build kernel inputs and report lines with: the per-axis and per-channel
columns of an (N, 3) array as kernel inputs, a point as text, and values on the masked pixels as an
(H, W, 3) image."""

from __future__ import annotations

import numpy as np

__all__ = ["masked_image", "rgb_columns", "vector_text", "xyz_columns"]


def vector_text(v) -> str:
    """A point or vector for a report line: "(x, y, z)", 4 significant digits each."""
    return "(" + ", ".join(f"{float(c):.4g}" for c in v) + ")"


def xyz_columns(prefix: str, v: np.ndarray) -> dict[str, np.ndarray]:
    """Kernel inputs ``<prefix>x``, ``<prefix>y``, ``<prefix>z`` from the columns of an (N, 3) array."""
    return {f"{prefix}{c}": np.ascontiguousarray(v[:, k]) for k, c in enumerate("xyz")}


def rgb_columns(prefix: str, v: np.ndarray) -> dict[str, np.ndarray]:
    """Kernel inputs ``<prefix>_r``, ``<prefix>_g``, ``<prefix>_b`` from the columns of an (N, 3) array."""
    return {f"{prefix}_{c}": np.ascontiguousarray(v[:, k]) for k, c in enumerate("rgb")}


def masked_image(mask: np.ndarray, values) -> np.ndarray:
    """An (H, W, 3) float64 image, zero outside ``mask`` (H, W), holding ``values`` on the masked pixels in
    row-major order: (N, 3) one value per RGB channel, or (N,) one grey value copied to the three channels
    (N = the masked pixels). The units are the values'."""
    img = np.zeros((*mask.shape, 3))
    v = np.asarray(values, np.float64)
    img[mask] = v if v.ndim == 2 else v[:, None]
    return img
