"""Per-pixel inputs of the soft-particle billboard methods (`rtfit.realtime.soft_particles.METHODS`) from view
rays, and the shipped scenes' geometry: shared by the soft-particles audit and its study (neither imports the
other).

A particle of ``radius`` (scene units) at ``centre`` (camera frame, +z forward) is drawn as a billboard at the
centre's view depth z; each pixel's unit view direction d meets the billboard plane at lateral offset
(p_x, p_y) = d_{x,y}·z/d_z − c_{x,y}, q = |p|; the depth buffer's surface at ray distance t_s has view depth
z_s = t_s·d_z, so Δ = z_s − z (a miss: t_s ≥ `BIG`, Δ = `BIG`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rtfit.realtime.soft_particles import BIG, billboard_alpha

__all__ = ["CENTRE", "CENTRE_INSIDE", "CUT_SCENES", "RADIUS", "CutScene", "billboard_inputs", "sigma_of"]

RADIUS = 1.0
CENTRE = (0.3, 0.2, 4.0)
"""The shipped particle's centre (view space) and radius."""
CENTRE_INSIDE = (0.1, 0.0, 0.6)
"""The centre of the camera-inside case: the camera sits 0.6 r behind the centre, inside the sphere."""
TILT_DEG = 35.0
PLANE_OFFSET = 0.15
"""The opaque plane: through the point ``PLANE_OFFSET``·r behind the centre, tilted ``TILT_DEG`` about x."""


def sigma_of(alpha_c: float, radius: float) -> float:
    """σ with 1 − exp(−2σr) = α_c: the particle's α is the opacity of its chord through the centre."""
    return -math.log1p(-alpha_c) / (2.0 * radius)


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


@dataclass(frozen=True)
class CutScene:
    """One shipped soft-particles scene (``scenes/library/soft_particles_<shape>.xml``): a particle of
    radius 1 at view-space ``centre`` (the camera at the origin looking along +z), opacity ``alpha_c``
    through its centre (σ = −ln(1 − α_c)/2), cut by an opaque plane 0.15 r behind the centre tilted
    ``tilt_deg`` about x from facing the camera; ``quick``: audited by ``--quick`` too."""

    shape: str
    alpha_c: float
    inside: bool = False
    quick: bool = True
    tilt_deg: float = TILT_DEG

    @property
    def centre(self) -> tuple[float, float, float]:
        return CENTRE_INSIDE if self.inside else CENTRE

    @property
    def sigma(self) -> float:
        return sigma_of(self.alpha_c, RADIUS)

    @property
    def name(self) -> str:
        return f"{self.shape}-a{self.alpha_c:g}".replace(".", "p") + ("-inside" if self.inside else "")

    def defines(self) -> dict[str, str]:
        """The XML file's ``<default>`` values of this case."""
        cx, cy, cz = self.centre
        return {"sigma": repr(self.sigma), "cx": f"{cx:g}", "cy": f"{cy:g}", "cz": f"{cz:g}",
                "pz": f"{cz + PLANE_OFFSET * RADIUS:g}", "tilt": f"{self.tilt_deg:g}"}  # fmt: skip


CUT_SCENES = (
    CutScene("sphere", 0.95),
    CutScene("box", 0.95),
    CutScene("sphere", 0.95, inside=True),
    CutScene("sphere", 0.5, quick=False),
    CutScene("box", 0.5, quick=False),
)
"""The experiment's canned cases before the engine: both shapes at α_c = 0.95 (``--quick``) and 0.5, and the
sphere with the camera inside it."""
