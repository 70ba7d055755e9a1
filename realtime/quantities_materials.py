"""The quantities of a surface's material and relief: parallax depth and self-shadow of a height field,
Fresnel reflectance, and the layered materials (a clear coat's offset and radiance, the irradiance an inner
layer receives).

One room of the quantity table (`rtfit.realtime.quantities.QUANTITIES`, which gives their order)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .fresnel import INPUTS as FRESNEL_INPUTS
from .layered_materials import COMPOSITE_INPUTS as COAT_INPUTS
from .layered_materials import INPUTS as LAYER_INPUTS
from .layered_materials import LIGHTMAP_INPUTS, BaseTexture
from .methods import Input
from .parallax_occlusion import HeightMap
from .quantity_types import Quantity, quantity_table

__all__ = [
    "MATERIAL_QUANTITIES",
]


def _example_field(n: int) -> HeightMap:
    """An egg-crate height field h = ½ + ½·sin 2πu·sin 2πv on 16 × 16 texels (bilinear, repeating)."""
    c = (np.arange(16) + 0.5) / 16.0
    return HeightMap(0.5 + 0.5 * np.outer(np.sin(2.0 * math.pi * c), np.sin(2.0 * math.pi * c)))


def _example_lightmap(n: int) -> BaseTexture:
    """A 3-channel 8 × 8 light map (W/m²) with a shadow edge at u = 0.5 over the uv square (any ``n``)."""
    u = (np.arange(8) + 0.5) / 8.0
    return BaseTexture(np.broadcast_to(np.where(u > 0.5, 2.0, 0.1), (3, 8, 8)).copy())


# The parallax quantities' shared inputs: the pixel's texture coordinates and view vector (x, y), and the
# height field with its range.
_PIXEL_VIEW = (
    Input("u0", "texture units", "the pixel's texture coordinate u (on the surface)", (-2.0, 2.0)),
    Input("v0", "texture units", "the pixel's texture coordinate v", (-2.0, 2.0)),
    *(Input(f"v{c}", "1", f"unit view vector (to the eye), tangent space {c}", (-1.0, 1.0)) for c in "xy"),
)
_HEIGHT_FIELD = (
    Input(
        "scale",
        "texture units",
        "the height range s (--pom-depth): h = 0 lies s·L below the surface",
        (1.0e-3, 1.0),
    ),
    Input(
        "field",
        "1",
        "the height field h(u, v) ∈ [0, 1]: g.field(ops, u, v) (the bump map's texture as "
        "Mitsuba looks it up)",
    ),
)


MATERIAL_QUANTITIES: Mapping[str, Quantity] = quantity_table(
    Quantity(
        "parallax_depth",
        "1",
        "depth below a height-mapped surface of the point a view ray sees, as a fraction of the "
        "height range (0: on the surface, 1: the deepest valley h = 0)",
        (
            *_PIXEL_VIEW,
            Input(
                "vz",
                "1",
                "unit view vector, tangent space z = N·V (the audit leaves out pixels below 10⁻³; "
                "validation draws vx, vy, vz independently)",
                (1.0e-3, 1.0),
            ),
            *_HEIGHT_FIELD,
        ),
        examples={"field": _example_field},
        reference="Mitsuba ray_intersect of the pixel-centre rays with the shape displaced by the "
        "height field",
    ),
    Quantity(
        "parallax_shadow",
        "1",
        "fraction of an area light's irradiance at the visible point of a height-mapped surface that "
        "the height field itself lets through (its soft self-shadow; 1: unshadowed)",
        (
            *_PIXEL_VIEW,
            Input("vz", "1", "unit view vector, tangent space z = N·V", (1.0e-3, 1.0)),
            *(
                Input(f"l{c}", "1", f"unit vector to the light's centre, tangent space {c}", (-1.0, 1.0))
                for c in "xy"
            ),
            Input(
                "lz",
                "1",
                "unit vector to the light's centre, tangent space z = N·L (the audit leaves out "
                "pixels below 10⁻³)",
                (1.0e-3, 1.0),
            ),
            Input(
                "u",
                "texture units",
                "texture coordinate u of the exact visible point (the displaced mesh's first hit): "
                "what a shadow model isolated from the march reads; an engine has only its march's",
                (-2.0, 2.0),
            ),
            Input("v", "texture units", "texture coordinate v of the exact visible point", (-2.0, 2.0)),
            *_HEIGHT_FIELD,
        ),
        vectors={"view": ("vx", "vy", "vz"), "light": ("lx", "ly", "lz")},
        examples={"field": _example_field},
        reference="Mitsuba ray_test from the displaced mesh's first hit to samples of the area light "
        "(the light's own sampling): unoccluded-weighted fraction with its standard error",
    ),
    Quantity(
        "fresnel_reflectance",
        "1",
        "Fresnel reflectance F of a smooth interface at the viewing angle (the mirror direction's), "
        "per RGB channel through η and k",
        FRESNEL_INPUTS,
        reference="Mitsuba's own Fresnel of the visible conductor or dielectric: the smooth BSDF's "
        "delta-reflection weight, fresnel()/fresnel_conductor() on a rough BSDF's η, k",
    ),
    Quantity(
        "layer_offset",
        "m",
        "lateral offset (scene units) at which the inner layer is seen through a smooth dielectric "
        "coat of thickness d, from the point where the view ray enters the coat",
        LAYER_INPUTS,
        reference="Mitsuba: the camera ray's first hit on the coat, its refracted direction from the "
        "dielectric BSDF's transmission sample, and that ray's hit on the base",
    ),
    Quantity(
        "coated_radiance",
        "W/m²/sr",
        "radiance of a clear dielectric coat over a diffuse base under a uniform sky, per channel",
        COAT_INPUTS,
        reference="Mitsuba path tracing (path, unbounded depth) at the pixel centres: the coat's "
        "reflection, refraction and the base's internal reflections",
    ),
    Quantity(
        "inner_irradiance",
        "W/m²",
        "irradiance E_in the inner layer of a two-layer material (a diffuse surface under a "
        "scattering slab) receives at a point, per channel: all light arriving at its upper side "
        "(the light's beam attenuated through the slab, and the light the slab scatters down, "
        "any number of scatterings, with light the inner layer reflected and the slab sent back)",
        LIGHTMAP_INPUTS,
        examples={"lightmap": _example_lightmap},
        reference="Mitsuba: the beam's transmittance exp(−σ_t·ℓ) with shadow rays, plus π × volpath "
        "(unbounded depth) along cosine-distributed rays from the inner layer's point",
    ),
)
"""The material and relief quantities by name."""
