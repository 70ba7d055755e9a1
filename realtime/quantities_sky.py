"""The quantities of sky and environment light at a surface point, and of what occludes it: the sky's
irradiance (uniform, SH, N directional lights, unoccluded environment), sky visibility, ambient occlusion,
crease darkening, the cap intersection and obscurance.

One room of the quantity table (`rtfit.realtime.quantities.QUANTITIES`, which gives their order)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .ibl_samples import INPUTS as IBL_INPUTS
from .methods import Input
from .obscurances import MISS
from .quantity_types import (
    NORMAL_INPUTS,
    POINT_INPUTS,
    Quantity,
    example_sh_coefficients,
    quantity_table,
    vector_inputs,
)
from .sdf_grid import HalfSpace, Sphere
from .sdf_occlusion import AnalyticSDF
from .sh_sky_bent_normal import INPUTS as SH_SKY_INPUTS

__all__ = [
    "SKY_QUANTITIES",
]


def _example_sdf(n: int):
    """A ground plane with a sphere resting on it: something that occludes, for validation (any ``n``)."""
    return AnalyticSDF([HalfSpace((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)), Sphere((0.0, 0.0, 1.0), 1.0)])


EXAMPLE_RAYS = 8
"""Rays per point of the ``obscurance`` quantity's example (validation)."""


def _example_visibility(n: int) -> tuple:
    """4 lights' visibilities at ``n`` points: lit, shadowed, half (a filtered test) and alternating."""
    return (np.ones(n), np.zeros(n), np.full(n, 0.5), (np.arange(n) % 2).astype(np.float64))


def _example_lights(n: int) -> tuple[float, ...]:
    """4 lights (6 floats each: direction towards it, RGB power) of a sky brighter above (any ``n``)."""
    return (0.0, 0.0, 1.0, 2.0, 2.0, 2.5, 1.0, 0.0, 0.0, 0.5, 0.5, 0.5,
            0.0, -0.6, 0.8, 1.0, 0.9, 0.8, 0.0, 0.0, -1.0, 0.2, 0.2, 0.1)  # fmt: skip


def _example_distances(n: int) -> tuple[np.ndarray, ...]:
    """`EXAMPLE_RAYS` hit distances at each of ``n`` points: an even grid over (0, 10] scene units, shuffled
    per ray, and one ray in four a miss (`rtfit.realtime.obscurances.MISS`, as the audit gives it)."""
    rng = np.random.default_rng(1)
    hits = np.linspace(10.0 / n, 10.0, n)
    out = []
    for _ in range(EXAMPLE_RAYS):
        d = rng.permutation(hits)
        d[rng.random(n) < 0.25] = MISS
        out.append(d)
    return tuple(out)


_SDF = Input("sdf", "m", "the scene's distance field: ``g.sdf.sample(ops, level, x, y, z)`` (level 0 finest)")
_GEOMETRY = (*POINT_INPUTS, *NORMAL_INPUTS, _SDF)
_GEOMETRY_VECTORS = {"point": ("px", "py", "pz"), "normal": ("nx", "ny", "nz")}


SKY_QUANTITIES: Mapping[str, Quantity] = quantity_table(
    Quantity(
        "sky_irradiance",
        "W/m²",
        "irradiance from a uniform sky at a surface point, with the scene's occlusion",
        (
            *NORMAL_INPUTS,
            *vector_inputs("b", "unit bent normal: the mean unoccluded direction (what an engine bakes)"),
            Input("visibility", "1", "cosine-weighted unoccluded fraction of the hemisphere", (0.0, 1.0)),
            Input(
                "aperture",
                "rad",
                "half-angle of the visibility cap around the bent normal",
                (0.0, 0.5 * math.pi),
            ),
            Input("sky_radiance", "W/m²/sr", "radiance L_sky of the uniform sky", (0.0, 10.0)),
            *POINT_INPUTS,
            _SDF,
        ),
        vectors={
            "normal": ("nx", "ny", "nz"),
            "bent_normal": ("bx", "by", "bz"),
            "point": ("px", "py", "pz"),
        },
        unit_vectors=("normal", "bent_normal"),
        examples={"sdf": _example_sdf},
        reference="sky irradiance with visibility at the visible points (direct, environment only)",
    ),
    Quantity(
        "sky_irradiance_sh",
        "W/m²",
        "irradiance from the sky at a surface point, with the scene's occlusion, from the sky's SH "
        "L2 projection and a visibility bake (AO, bent normal, visible cone), per RGB channel",
        SH_SKY_INPUTS,
        vectors={
            "normal": ("nx", "ny", "nz"),
            "bent_normal": ("bx", "by", "bz"),
            "point": ("px", "py", "pz"),
        },
        unit_vectors=("normal", "bent_normal"),
        channels=3,
        examples={"coeffs": example_sh_coefficients},
        reference="sky irradiance with visibility at the visible points (direct, environment only)",
    ),
    Quantity(
        "sky_irradiance_lights",
        "W/m²",
        "irradiance from the environment at a surface point, with the scene's occlusion, from N "
        "directional lights baked from the map, each with its own visibility, per RGB channel",
        IBL_INPUTS,
        vectors={"normal": ("nx", "ny", "nz"), "point": ("px", "py", "pz")},
        unit_vectors=("normal",),
        channels=3,
        examples={"visibility": _example_visibility, "lights": _example_lights},
        reference="environment irradiance with visibility at the visible points (direct, environment "
        "only, shadow rays)",
        note="the audit gives each N its own visibilities and table: a user's row reads the seed "
        "bake's N = 64 (`g.visibility`: N per-pixel arrays; `g.lights`: 6·N floats)",
    ),
    Quantity(
        "environment_irradiance",
        "W/m²",
        "irradiance E(n) of the environment at a normal, unoccluded, per RGB channel",
        (
            *NORMAL_INPUTS,
            Input(
                "sh",
                "W/m²",
                "27 floats: the environment's SH coefficients L_lm, l ≤ 2, channel-major",
            ),
        ),
        vectors={"normal": ("nx", "ny", "nz")},
        unit_vectors=("normal",),
        channels=3,
        examples={"sh": example_sh_coefficients},
        reference="environment irradiance at the visible normals (quadrature of the environment)",
    ),
    Quantity(
        "sky_visibility",
        "1",
        "sky light reaching a point as a fraction of the unoccluded sky (an SDF skylight term)",
        _GEOMETRY,
        vectors=_GEOMETRY_VECTORS,
        unit_vectors=("normal",),
        examples={"sdf": _example_sdf},
        reference="ray-cast sky visibility at the visible points",
    ),
    Quantity(
        "ambient_occlusion",
        "1",
        "cosine-weighted ambient occlusion within a radius R (1: unoccluded)",
        (*_GEOMETRY, Input("ao_distance", "m", "the AO radius R", (0.01, 10.0))),
        vectors=_GEOMETRY_VECTORS,
        unit_vectors=("normal",),
        examples={"sdf": _example_sdf},
        reference="ray-cast ambient occlusion within R (cosine-distributed rays of length R)",
    ),
    Quantity(
        "crease_darkening",
        "1",
        "a darkening factor in creases from the blurred distance field (Evans' curvature term)",
        (Input("distance", "m", "the blurred SDF s(P) at the point", (-1.0, 1.0)), *_GEOMETRY),
        vectors=_GEOMETRY_VECTORS,
        unit_vectors=("normal",),
        examples={"sdf": _example_sdf},
        reference="ray-cast ambient occlusion (as for ambient_occlusion)",
    ),
    Quantity(
        "cap_intersection_solid_angle",
        "sr",
        "solid angle of the intersection of two spherical caps",
        (
            Input("r1", "rad", "angular radius of the first cap", (0.0, math.pi)),
            Input("r2", "rad", "angular radius of the second cap", (0.0, math.pi)),
            Input("d", "rad", "angle between the cap centres", (0.0, math.pi)),
        ),
        reference="the closed form (Tovchigrechko & Vakser 2001)",
    ),
    Quantity(
        "obscurance",
        "1",
        "obscurance W = (1/π)∫ρ(d)(n·ω)dω at a surface point, from the hit distances of K "
        "cosine-distributed rays (1: unoccluded)",
        (
            Input(
                "distances",
                "scene units",
                f"the K rays' hit distances: a tuple of K arrays, g.distances[k] per point (a miss: "
                f"{MISS:g}); validation draws K = {EXAMPLE_RAYS}",
            ),
        ),
        examples={"distances": _example_distances},
        reference="ray-cast obscurance with the seed's ρ = √(d/R), and the uniform ambient with "
        "interreflections (E/(πL)) it stands in for",
    ),
)
"""The sky and occlusion quantities by name."""
