"""Rigid and affine transforms of scene parts (float64 NumPy), shared by the scene builder and the media.

`rotation_matrix` (Rodrigues), `frame_from_normal` (a deterministic tangent frame) and `affine` (a 4×4
world-from-local matrix). `rtfit.reference.build` places shapes and lights with them and
`rtfit.reference.height_fog` places its fog region with them; both import this module, neither the other's
(the builder imports the fog medium, never the reverse).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["affine", "frame_from_normal", "rotation_matrix"]


def rotation_matrix(axis, angle_deg: float) -> np.ndarray:
    """3×3 rotation about ``axis`` (normalised here) by ``angle_deg`` (right-handed), Rodrigues."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = math.radians(angle_deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)


def frame_from_normal(normal, rotation_deg: float = 0.0) -> np.ndarray:
    """3×3 matrix whose columns (t, b, n) form a right-handed frame with n = ``normal``.

    The tangent is the world axis least aligned with n projected onto the plane, turned by
    ``rotation_deg`` about n: deterministic, so a rectangle's orientation is reproducible.
    """
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    hint = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    t = np.cross(hint, n)
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    r = rotation_matrix(n, rotation_deg)
    return np.column_stack([r @ t, r @ b, n])


def affine(linear: np.ndarray, translate) -> np.ndarray:
    """4×4 matrix [[linear, translate], [0, 0, 0, 1]] (world from local; metres)."""
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = np.asarray(translate, dtype=np.float64)
    return m
