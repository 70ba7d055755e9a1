"""Per-pixel inputs of the soft-particle billboard methods (`rtfit.realtime.soft_particles.METHODS`) from view
rays: shared by the soft-particles experiment and its audit (neither imports the other).

A particle of ``radius`` (scene units) at ``centre`` (camera frame, +z forward) is drawn as a billboard at the
centre's view depth z; each pixel's unit view direction d meets the billboard plane at lateral offset
(p_x, p_y) = d_{x,y}·z/d_z − c_{x,y}, q = |p|; the depth buffer's surface at ray distance t_s has view depth
z_s = t_s·d_z, so Δ = z_s − z (a miss: t_s ≥ `BIG`, Δ = `BIG`).
"""

from __future__ import annotations

import numpy as np

from rtfit.realtime.soft_particles import BIG, billboard_alpha

__all__ = ["billboard_inputs"]


def billboard_inputs(dirs: np.ndarray, centre, radius: float, alpha_c: float, shape: str, t_surface) -> dict:
    """Per-pixel inputs of the billboard methods for a particle at ``centre``: the billboard at the centre's
    view depth z, Δ = z_s − z (z_s = t_s·d_z the depth buffer), the lateral distance q of the ray's point on
    the billboard plane, and the texture α (sphere: `billboard_alpha`; box: α_c on its square)."""
    c = np.asarray(centre, np.float64)
    z = c[2]
    dz = np.maximum(dirs[:, 2], 1e-12)
    px, py = dirs[:, 0] * z / dz - c[0], dirs[:, 1] * z / dz - c[1]
    q = np.hypot(px, py)
    z_s = np.where(np.asarray(t_surface) >= BIG, BIG, np.asarray(t_surface) * dirs[:, 2])
    n = len(dirs)
    if shape == "sphere":
        alpha = np.asarray(billboard_alpha(np.full(n, alpha_c), np.full(n, radius), q), np.float64)
    else:
        alpha = np.where(np.maximum(np.abs(px), np.abs(py)) <= radius, alpha_c, 0.0)
    return {
        "alpha": alpha,
        "alpha_c": np.full(n, alpha_c),
        "z": np.full(n, z),
        "delta": np.minimum(z_s - z, BIG),
        "radius": np.full(n, radius),
        "q": q,
        "cos_view": dirs[:, 2].copy(),
    }
