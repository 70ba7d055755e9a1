r"""The sun's transmittance to ground points through a Mitsuba medium, by ratio tracking (the clouds family's
reference).

For ground points pᵢ and one unit direction s towards the sun, T(pᵢ) = exp(−∫₀^∞ σt(pᵢ + t·s) dt) through
the medium's own region (``Medium.intersect_aabb``): `rtfit.reference.medium_transmittance.transmittance_pass`
(Novák, Selle & Jarosz 2014, ratio tracking) with one origin per ray — the sun's rays from the ground are
parallel, not concurrent — and its own random streams ("sun-transmittance").

The density is the loaded medium's own ``get_scattering_coefficients`` (a ``gridvolume``: Mitsuba's own
trilinear lookup), so this estimate shares no code with the real-time march it checks. Grey extinction
(channel 0), three independent estimates per point (one per channel) so that their errors are independent;
at most ``max_steps`` tracking steps, a lane still active then is a one-line RuntimeError.
"""

from __future__ import annotations

import numpy as np

from .medium_transmittance import MAX_STEPS, transmittance_pass

__all__ = ["sun_transmittance_pass"]


def sun_transmittance_pass(mi, medium, points, direction, spp: int, seed: int, max_steps: int = MAX_STEPS):
    """One pass of ``spp`` ratio-tracking samples (×3 channels) of the transmittance of ``medium`` (a loaded
    Mitsuba medium) from each of ``points`` (N, 3) along the unit ``direction`` (3,) towards the sun, over
    the ray's whole stretch in the medium's region. Returns a `PassResult` (mean, variance (N, 3))."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    s = np.asarray(direction, np.float64).reshape(3)
    s = s / np.linalg.norm(s)
    directions = np.broadcast_to(s, pts.shape)
    return transmittance_pass(
        mi, medium, pts, directions, np.full(len(pts), np.inf), spp, seed, max_steps=max_steps,
        tag="sun-transmittance",
    )  # fmt: skip
