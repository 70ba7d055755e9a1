"""The quantities of participating media along a camera ray: height fog (optical depth, transmittance,
in-scatter, fogged radiance), clouds, soft particles, light scattered from point and spot lights, the glow
around a light, and the clear sky's radiance.

One room of the quantity table (`rtfit.realtime.quantities.QUANTITIES`, which gives their order)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import soft_particles
from .clouds import INPUTS as CLOUD_INPUTS
from .clouds import RADIANCE_INPUTS as CLOUD_RADIANCE_INPUTS
from .clouds import CloudGrid
from .light_cones import INPUTS as CONE_INPUTS
from .methods import Input
from .quantity_types import Quantity, quantity_table, vector_inputs

__all__ = [
    "MEDIA_QUANTITIES",
]


def _example_cloud(n: int) -> CloudGrid:
    """A 6 × 6 × 3 cloud of one blob (peak σ 2 /m) over [−2, 2]² × [1, 2] m (any ``n``)."""
    c = (np.arange(6) + 0.5) / 6.0 * 4.0 - 2.0
    z = 1.0 + (np.arange(3) + 0.5) / 3.0
    zz, yy, xx = np.meshgrid(z, c, c, indexing="ij")
    return CloudGrid(
        2.0 * np.exp(-(xx**2 + yy**2 + 4.0 * (zz - 1.5) ** 2)), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.0)
    )


_FOG = (
    *vector_inputs("o", "ray origin (the camera)", "m", (-100.0, 100.0)),
    *vector_inputs("d", "unit ray direction (from the camera)"),
    Input("length", "m", "segment length along the ray (to the visible point)", (0.0, 1.0e4)),
    Input(
        "z0", "m", "height of the segment's start (the camera end) along the fog gradient", (-100.0, 1000.0)
    ),
    Input("z1", "m", "height of the segment's end", (-100.0, 1000.0)),
    Input("density", "1/m", "the fog's extinction b at height 0", (0.0, 0.2)),
    Input("falloff", "1/m", "the fog's height falloff c (scale height 1/c); 0: homogeneous", (0.0, 0.4)),
)
_FOG_VECTORS = {"origin": ("ox", "oy", "oz"), "direction": ("dx", "dy", "dz")}
_M100 = (-100.0, 100.0)
_CONE_VECTORS = {"origin": ("ox", "oy", "oz"), "direction": ("wx", "wy", "wz"), "apex": ("px", "py", "pz"),
                 "axis": ("ax", "ay", "az")}  # fmt: skip
_MEDIUM_LIGHT = (
    Input("intensity", "W/sr", "the light's radiant intensity I (a spot's, on its axis)", (0.0, 1.0e4)),
    Input("sigma_s", "1/m", "the medium's scattering coefficient σ_s", (0.0, 10.0)),
    Input("sigma_t", "1/m", "the medium's extinction coefficient σ_t", (0.0, 10.0)),
    Input("g", "1", "the medium's Henyey–Greenstein asymmetry", (-0.99, 0.99)),
)
_LIGHT = ("lx", "ly", "lz")
_FOG_REFERENCE = "along the camera's rays through the fog medium (volpathmis)"
# The soft-particle methods' inputs, each once (billboard and exact kernels share `radius`), as declared.
_PARTICLE = tuple({i.name: i for m in soft_particles.METHODS.values() for i in m.inputs}.values())


MEDIA_QUANTITIES: Mapping[str, Quantity] = quantity_table(
    Quantity(
        "fog_optical_depth",
        "1",
        "optical depth τ of an exponential height fog along a segment",
        _FOG,
        vectors=_FOG_VECTORS,
        unit_vectors=("direction",),
        reference=_FOG_REFERENCE,
    ),
    Quantity(
        "fog_transmittance",
        "1",
        "transmittance T = exp(−τ) of an exponential height fog along a segment",
        _FOG,
        vectors=_FOG_VECTORS,
        unit_vectors=("direction",),
        reference=_FOG_REFERENCE,
        note="height-fog's shipped forms approximate τ (fog_optical_depth): T = exp(−τ); "
        "linear-fog's fog factors f(d) read the stretch's length d (`length`) and give T directly",
    ),
    Quantity(
        "cloud_transmittance",
        "1",
        "the sun's transmittance T through a cloud (a density grid) to a ground point",
        CLOUD_INPUTS,
        vectors={"point": ("px", "py", "pz"), "sun": ("sx", "sy", "sz")},
        unit_vectors=("sun",),
        examples={"cloud": _example_cloud},
        reference="ratio tracking from each visible point toward the sun through the scene's own "
        "gridvolume medium",
    ),
    Quantity(
        "cloud_radiance",
        "W/m²/sr",
        "radiance at the camera through a sunlit cloud (a density grid) and what lies behind it, one "
        "channel at a time",
        CLOUD_RADIANCE_INPUTS,
        vectors={
            "origin": ("ox", "oy", "oz"),
            "direction": ("dx", "dy", "dz"),
            "sun": ("sx", "sy", "sz"),
        },
        unit_vectors=("direction", "sun"),
        examples={"cloud": _example_cloud},
        reference="volpathmis radiance of the cloud's pixels with the scene's own gridvolume medium",
    ),
    Quantity(
        "fog_inscatter",
        "W/m²/sr",
        "radiance scattered into the ray by the fog along the segment, per RGB channel",
        (
            *_FOG,
            Input("cos_sun", "1", "v·l: ray direction · direction to the sun", (-1.0, 1.0)),
            *(Input(f"sun_{c}", "W/m²", f"the sun's irradiance, {c} channel", (0.0, 10.0)) for c in "rgb"),
        ),
        vectors=_FOG_VECTORS,
        unit_vectors=("direction",),
        channels=3,
        reference=_FOG_REFERENCE,
        note="the shipped shading models give it as C·(1 − T) inside fogged_radiance",
    ),
    Quantity(
        "fogged_radiance",
        "W/m²/sr",
        "radiance at the camera: fog-free radiance attenuated plus the in-scatter, per RGB channel",
        (
            *_FOG,
            Input("cos_sun", "1", "v·l: ray direction · direction to the sun", (-1.0, 1.0)),
            *(Input(f"l0_{c}", "W/m²/sr", f"fog-free radiance L₀, {c} channel", (0.0, 10.0)) for c in "rgb"),
        ),
        vectors=_FOG_VECTORS,
        unit_vectors=("direction",),
        channels=3,
        reference=_FOG_REFERENCE,
    ),
    Quantity(
        "particle_opacity",
        "1",
        "opacity 1 − T of a particle (a medium-filled convex volume) along a camera ray, clipped by "
        "the opaque surface behind it",
        _PARTICLE,
        vectors={"direction": ("dx", "dy", "dz"), "centre": ("cx", "cy", "cz")},
        unit_vectors=("direction",),
        reference="the particle medium's opacity along the camera's rays, clipped by the depth "
        "buffer (Mitsuba's free-flight sampling)",
    ),
    Quantity(
        "inscattered_radiance",
        "W/m²/sr",
        "radiance a point light scatters into a view segment through a homogeneous medium (per channel)",
        (
            *vector_inputs("o", "segment start o (the camera, or where its ray enters)", "m", _M100),
            *vector_inputs("d", "segment vector d (o → the segment's end: |d| is its length)", "m", _M100),
            *vector_inputs("l", "light position l", "m", (-90.0, 90.0)),
            *_MEDIUM_LIGHT,
        ),
        vectors={"origin": ("ox", "oy", "oz"), "segment": ("dx", "dy", "dz"), "light": _LIGHT},
        reference="single scattering of that light along the camera's rays in the medium "
        "(equiangular sampling, Mitsuba's emitter, phase function and shadow rays)",
    ),
    Quantity(
        "glow_radiance",
        "W/m²/sr",
        "radiance of the glow around a point light in a scattering medium (all orders), per channel",
        (
            Input("du", "px", "film pixels from the light's image, horizontal", (-1e3, 1e3)),
            Input("dv", "px", "film pixels from the light's image, vertical", (-1e3, 1e3)),
            Input("e_direct", "W/m²", "the light's attenuated irradiance at the camera", (0.0, 1e4)),
            Input("omega_px", "sr", "the pixel's solid angle", (1e-8, 1.0)),
            *_MEDIUM_LIGHT,
            Input("distance", "m", "the camera-to-light distance R", (0.0, 1e3)),
        ),
        reference="the radiance at the camera with the light's medium (volpath, all bounces)",
    ),
    Quantity(
        "spot_inscattered_radiance",
        "W/m²/sr",
        "radiance a spot light scatters into a view ray through a homogeneous medium (per channel)",
        (*CONE_INPUTS, *_MEDIUM_LIGHT),
        vectors=_CONE_VECTORS,
        unit_vectors=("direction", "axis"),
        reference="single scattering of that spot along the camera's rays in the medium "
        "(equiangular sampling, Mitsuba's emitter, phase function and shadow rays)",
    ),
    Quantity(
        "sky_radiance",
        "W/m²/sr",
        "radiance of a clear sky (single + multiple scattering) in a view direction, per RGB channel",
        (
            *vector_inputs("d", "unit view direction (+Z up)"),
            *vector_inputs("s", "unit direction to the sun"),
            Input("altitude", "m", "the viewer's altitude above the ground", (0.0, 1.0e4)),
        ),
        vectors={"direction": ("dx", "dy", "dz"), "sun": ("sx", "sy", "sz")},
        unit_vectors=("direction", "sun"),
        channels=3,
        reference="sky radiance along the camera's sky pixels (volpathmis in the shell atmosphere)",
    ),
)
"""The media quantities by name."""
