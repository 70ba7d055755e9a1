"""The quantities of a light's irradiance at a surface point: direct (unshadowed, and through a shadow map)
and one bounce of indirect light (colour bleeding, light path maps, caustics).

One room of the quantity table (`rtfit.realtime.quantities.QUANTITIES`, which gives their order)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .caustics import CAUSTIC_INPUTS, NEAREST
from .colour_bleeding import INPUTS as BLEED_INPUTS
from .light_path_maps import INPUTS as PATH_MAP_INPUTS
from .methods import Input
from .pcf_soft_shadows import INPUTS as PCF_INPUTS
from .pcf_soft_shadows import ShadowMap
from .quantity_types import Quantity, quantity_table

__all__ = [
    "LIGHT_QUANTITIES",
]


def _example_shadow_map(n: int) -> ShadowMap:
    """A 64² perspective shadow map of a half-plane blocker at depth 2 over a floor at depth 5 (any ``n``)."""
    depth = np.full((64, 64), 5.0)
    depth[:, :32] = 2.0
    return ShadowMap(depth, light_size=0.05, near=2.0)


LIGHT_QUANTITIES: Mapping[str, Quantity] = quantity_table(
    Quantity(
        "light_irradiance",
        "W/m²",
        "direct irradiance E of one light at a surface point",
        (
            Input("cos_theta", "1", "n·l: the normal · the direction to the light (centre)", (-1.0, 1.0)),
            Input(
                "irradiance",
                "W/m²",
                "E⊥: the light's irradiance at normal incidence (π·L·sin²α for a sphere light)",
                (0.0, 10.0),
            ),
            Input(
                "alpha",
                "rad",
                "angular radius of the light seen from the point (0: point or directional light)",
                (0.0, 0.5 * math.pi),
            ),
            Input(
                "distance",
                "m",
                "distance to the light's centre (+inf for a directional light; checks draw finite)",
                (0.01, 100.0),
            ),
        ),
        reference="that light's direct irradiance at the visible points, unshadowed and shadowed",
    ),
    Quantity(
        "shadowed_light_irradiance",
        "W/m²",
        "direct irradiance of one light at a surface point with the scene's occluders, from its "
        "unshadowed irradiance and a shadow map",
        PCF_INPUTS,
        examples={"shadow_map": _example_shadow_map},
        reference="that light's shadowed direct irradiance at the visible points (emitter sampling, "
        "shadow rays)",
        note="g.shadow_map.compare(ops, u, v, z): the bilinear compare; .nearest(ops, u, v): a depth",
    ),
    Quantity(
        "bounce_irradiance",
        "W/m²",
        "one-bounce indirect irradiance at a surface point in one colour channel, from K = 16 "
        "cosine-distributed rays: each hit's distance, albedo and direct irradiance",
        BLEED_INPUTS,
        reference="one-bounce indirect irradiance at the visible points, per channel: a cosine ray, "
        "then π × (path max_depth 2 − path max_depth 1)",
        note="called once per channel (g.channel 0, 1, 2); a miss has d = 1e30, a = e = 0",
    ),
    Quantity(
        "path_map_irradiance",
        "W/m²",
        "one-bounce indirect irradiance at a surface point in one channel from a moving light, "
        "from K = 32 baked cluster transfers and the light's mean direct irradiance per cluster",
        PATH_MAP_INPUTS,
        reference="one-bounce indirect irradiance at the visible points per light position: a cosine "
        "ray, then π × (path max_depth 2 − path max_depth 1)",
        note="called once per channel; g.pane<k> is per point, g.w<k> one number per light position",
    ),
    Quantity(
        "caustic_irradiance",
        "W/m²",
        f"caustic irradiance at a receiver point in one colour channel, from its K = {NEAREST} "
        "nearest photon hits traced through the caster: each one's distance, flux and neighbour "
        "distance",
        CAUSTIC_INPUTS,
        reference="caustic irradiance at the visible receivers (light paths L S+ D): light tracing "
        "through the caster, connected to the camera (ptracer's estimator)",
        note="called once per channel; a missing photon has d = 1e15, f = 0",
    ),
)
"""The light quantities by name."""
