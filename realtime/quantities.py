"""Quantities: what an approximation approximates, and the named inputs its ``g`` carries.

A **quantity** is one thing a reference measures at a visible point (or along a camera ray) — the direct
irradiance of one light, the sky's irradiance with occlusion, ambient occlusion, fog transmittance, sky
radiance — together with the per-element inputs a real-time formula for it may read, each with its unit and
domain. Every shipped method declares its quantity (``Method.quantity``); `QUANTITIES` documents them, and
`Quantity.methods` lists the shipped methods that approximate each (from the registry's method tables,
`rtfit.experiments.families.METHOD_TABLES`, so this module copies no formula).

A user's own approximation is a function ``f(ops, g, **params)`` written against the same ops namespace as
the shipped kernels (`rtfit.realtime.arrays`); `approximation` turns it into a `Method`::

    from rtfit import approximation, Param

    @approximation(quantity="light_irradiance", params={"w": Param(0.5, lower=0.0, upper=1.0)})
    def my_wrap(ops, g, *, w):
        t = ops.maximum((g.cos_theta + w) / (1.0 + w), 0.0)
        return g.irradiance * t * t

The method's inputs are the quantity's inputs; its kernel builds ``g`` (attribute access: ``g.cos_theta``,
and for a vector group ``g.normal`` = ``(g.nx, g.ny, g.nz)``) and calls ``f``. So the same text runs on
Dr.Jit, NumPy and JAX (``method.evaluate``) and `rtfit.fitting.fit_method` fits it through JAX like any
shipped method. Loading from files, modules and entry points, and the validation of a user function on
the quantity's domains, are `rtfit.experiments.user_methods`.

Structured inputs (an SDF sampler, a list of SH coefficients, a probe grid and its table, the K hit
distances of each point) have no scalar domain (``Input.domain`` is None); `Quantity.examples` gives a value
of each for validation: a factory called with the number of samples ``n`` (a per-element structured input,
such as the K hit distances, is a tuple of arrays of ``n`` values).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from . import soft_particles
from .caustics import CAUSTIC_INPUTS, NEAREST
from .clouds import INPUTS as CLOUD_INPUTS
from .clouds import RADIANCE_INPUTS as CLOUD_RADIANCE_INPUTS
from .clouds import CloudGrid
from .colour_bleeding import INPUTS as BLEED_INPUTS
from .fresnel import INPUTS as FRESNEL_INPUTS
from .ibl_samples import INPUTS as IBL_INPUTS
from .irradiance_volumes import ProbeGrid, probe_table
from .layered_materials import COMPOSITE_INPUTS as COAT_INPUTS
from .layered_materials import INPUTS as LAYER_INPUTS
from .layered_materials import LIGHTMAP_INPUTS, BaseTexture
from .light_cones import INPUTS as CONE_INPUTS
from .light_path_maps import INPUTS as PATH_MAP_INPUTS
from .methods import Input, Method, Param
from .obscurances import MISS
from .parallax_occlusion import HeightMap
from .pcf_soft_shadows import INPUTS as PCF_INPUTS
from .pcf_soft_shadows import ShadowMap
from .probe_specular import INPUTS as PROBE_SPECULAR_INPUTS
from .probe_specular import IRRADIANCE_RESOLUTION as PS_IRRADIANCE_RESOLUTION
from .probe_specular import LEVELS as PS_LEVELS
from .probe_specular import PREFILTER_RESOLUTION, ProbeChains
from .raindrops import ENV_RESOLUTION as DROP_ENV_RESOLUTION
from .raindrops import INPUTS as DROP_INPUTS
from .reflections import INPUTS as REFLECTION_INPUTS
from .reflections import IRRADIANCE_RESOLUTION, PROBE_RESOLUTION
from .sdf_grid import HalfSpace, Sphere
from .sdf_occlusion import AnalyticSDF
from .sh_sky_bent_normal import INPUTS as SH_SKY_INPUTS

__all__ = [
    "QUANTITIES",
    "UNDECLARED_UNIT",
    "ApproximationError",
    "Quantity",
    "QuantityInputs",
    "UserCodeExit",
    "UserKernel",
    "approximation",
    "get_quantity",
    "is_user_approximation",
    "quantities_markdown",
]


@dataclass(frozen=True)
class Quantity:
    """One approximated quantity: ``name``, ``unit`` of the result, ``description`` (one line), the
    ``inputs`` its ``g`` carries (scalar inputs with a ``domain``; structured ones without), ``vectors``
    (group name → its three component inputs, e.g. ``normal`` → ``(nx, ny, nz)``), ``unit_vectors`` (the
    groups that are unit vectors: validation samples them on the sphere), ``channels`` (1: one array
    per element; 3: a tuple of R, G, B arrays), ``examples`` (structured input → a factory ``f(n)`` of a
    value for validation on ``n`` samples), ``reference`` (what the audit compares an approximation of it
    with) and ``note``."""

    name: str
    unit: str
    description: str
    inputs: tuple[Input, ...]
    vectors: Mapping[str, tuple[str, str, str]] = field(default_factory=dict)
    unit_vectors: tuple[str, ...] = ()
    channels: int = 1
    examples: Mapping[str, Callable[[int], Any]] = field(default_factory=dict)
    reference: str = ""
    note: str = ""

    def __post_init__(self):
        object.__setattr__(self, "vectors", MappingProxyType(dict(self.vectors)))
        object.__setattr__(self, "examples", MappingProxyType(dict(self.examples)))
        names = self.input_names
        for group, comps in self.vectors.items():
            missing = [c for c in comps if c not in names]
            if missing or group in names:
                raise ValueError(f"quantity {self.name!r}: vector {group!r} is not three of its inputs")
        structured = {i.name for i in self.inputs if i.domain is None}
        if structured != set(self.examples):
            raise ValueError(f"quantity {self.name!r}: give an example of each structured input")

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(i.name for i in self.inputs)

    def methods(self, tables: Mapping[str, Mapping[str, Method]]) -> tuple[str, ...]:
        """The shipped methods of this quantity, as ``family:id``, from ``tables`` (family → its ``METHODS``
        table: the registry's, `rtfit.experiments.families.METHOD_TABLES`)."""
        return tuple(
            f"{family}:{mid}"
            for family, table in tables.items()
            for mid, m in table.items()
            if m.quantity == self.name
        )


def _vec(prefix: str, what: str, unit: str = "1", domain=(-1.0, 1.0)) -> tuple[Input, Input, Input]:
    return tuple(Input(f"{prefix}{c}", unit, f"{what}, {c} component", domain) for c in "xyz")  # type: ignore[return-value]


def _example_sdf(n: int):
    """A ground plane with a sphere resting on it: something that occludes, for validation (any ``n``)."""
    return AnalyticSDF([HalfSpace((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)), Sphere((0.0, 0.0, 1.0), 1.0)])


def _example_sh(n: int = 0):
    """SH L2 coefficients (27, channel-major) of a sky brighter above than below: L00 and L10 only (any
    ``n``)."""
    out = [0.0] * 27
    for c, scale in enumerate((1.0, 0.9, 0.8)):
        out[c * 9 + 0] = 2.0 * math.sqrt(math.pi) * scale  # L00 of a constant radiance 1 (× scale)
        out[c * 9 + 2] = 0.8 * scale  # L10: brighter towards +Z
    return out


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


EXAMPLE_GRID = ProbeGrid((-10.0, -10.0, -10.0), 20.0, (2, 2, 2))
"""The ``volume_irradiance`` quantity's example grid: 2 × 2 × 2 probes at the corners of the points'
domain."""


def _example_grid(n: int) -> ProbeGrid:
    return EXAMPLE_GRID


def _example_coefficients(rows: int) -> np.ndarray:
    """Per-probe basis coefficients (count, rows, 3) of the example grid: each probe's light brighter above
    than below (the SH sky of `_example_sh`; a cube of 1 + the axis's z), scaled by the probe's index."""
    count = EXAMPLE_GRID.count
    scale = 1.0 + 0.25 * np.arange(count)[:, None, None]
    if rows == 9:
        one = np.asarray(_example_sh(), np.float64).reshape(3, 9).T  # (9, RGB)
    else:  # +x, −x, +y, −y, +z, −z (irradiance_bases.CUBE_ORDER)
        one = np.array([1.0, 1.0, 1.0, 1.0, 2.0, 0.5])[:, None] * np.array([1.0, 0.9, 0.8])[None, :]
    return scale * one[None, :, :]


def _example_table(rows: int) -> Callable[[int], np.ndarray]:
    return lambda n: probe_table(_example_coefficients(rows))


def _example_field(n: int) -> HeightMap:
    """An egg-crate height field h = ½ + ½·sin 2πu·sin 2πv on 16 × 16 texels (bilinear, repeating)."""
    c = (np.arange(16) + 0.5) / 16.0
    return HeightMap(0.5 + 0.5 * np.outer(np.sin(2.0 * math.pi * c), np.sin(2.0 * math.pi * c)))


def _example_shadow_map(n: int) -> ShadowMap:
    """A 64² perspective shadow map of a half-plane blocker at depth 2 over a floor at depth 5 (any ``n``)."""
    depth = np.full((64, 64), 5.0)
    depth[:, :32] = 2.0
    return ShadowMap(depth, light_size=0.05, near=2.0)


def _example_map(resolution: int, low: float, high: float) -> Callable[[int], np.ndarray]:
    """A cube map of 6·N² texels rising from ``low`` to ``high`` through the texel order (any ``n``)."""
    return lambda n: np.linspace(low, high, 6 * resolution * resolution)


def _example_resolution(resolution: int) -> Callable[[int], int]:
    return lambda n: resolution


_REFLECTION_MAPS = {
    **{f"rad_{c}": _example_map(PROBE_RESOLUTION, 0.2, 2.0 - 0.3 * k) for k, c in enumerate("rgb")},
    **{f"irr_{c}": _example_map(IRRADIANCE_RESOLUTION, 0.5, 5.0 - k) for k, c in enumerate("rgb")},
    "dist": _example_map(PROBE_RESOLUTION, 20.0, 40.0),  # a room around the points' domain [-10, 10]³
    "resolution": _example_resolution(PROBE_RESOLUTION),
    "irr_resolution": _example_resolution(IRRADIANCE_RESOLUTION),
}


def _example_chains(n: int) -> ProbeChains:
    """One probe's tables rising through the texel order (any ``n``)."""
    pre = np.linspace(0.2, 2.0, PS_LEVELS * 6 * PREFILTER_RESOLUTION**2)
    irr = np.linspace(0.5, 5.0, 6 * PS_IRRADIANCE_RESOLUTION**2)
    return ProbeChains(np.stack([pre, 0.9 * pre, 0.8 * pre], 1), np.stack([irr, 0.9 * irr, 0.8 * irr], 1))


_PROBE_SPECULAR_TABLES = {"chains": _example_chains, "probe": lambda n: np.zeros(n)}


def _example_lightmap(n: int) -> BaseTexture:
    """A 3-channel 8 × 8 light map (W/m²) with a shadow edge at u = 0.5 over the uv square (any ``n``)."""
    u = (np.arange(8) + 0.5) / 8.0
    return BaseTexture(np.broadcast_to(np.where(u > 0.5, 2.0, 0.1), (3, 8, 8)).copy())


def _example_cloud(n: int) -> CloudGrid:
    """A 6 × 6 × 3 cloud of one blob (peak σ 2 /m) over [−2, 2]² × [1, 2] m (any ``n``)."""
    c = (np.arange(6) + 0.5) / 6.0 * 4.0 - 2.0
    z = 1.0 + (np.arange(3) + 0.5) / 3.0
    zz, yy, xx = np.meshgrid(z, c, c, indexing="ij")
    return CloudGrid(
        2.0 * np.exp(-(xx**2 + yy**2 + 4.0 * (zz - 1.5) ** 2)), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.0)
    )


_NORMAL = _vec("n", "unit surface normal (world frame, +Z up)")
_POINT = _vec("p", "surface point", "m", (-10.0, 10.0))
_SDF = Input("sdf", "m", "the scene's distance field: ``g.sdf.sample(ops, level, x, y, z)`` (level 0 finest)")
_GEOMETRY = (*_POINT, *_NORMAL, _SDF)
_GEOMETRY_VECTORS = {"point": ("px", "py", "pz"), "normal": ("nx", "ny", "nz")}
_FOG = (
    *_vec("o", "ray origin (the camera)", "m", (-100.0, 100.0)),
    *_vec("d", "unit ray direction (from the camera)"),
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

QUANTITIES: Mapping[str, Quantity] = MappingProxyType(
    {
        q.name: q
        for q in (
            Quantity(
                "light_irradiance",
                "W/m²",
                "direct irradiance E of one light at a surface point",
                (
                    Input(
                        "cos_theta", "1", "n·l: the normal · the direction to the light (centre)", (-1.0, 1.0)
                    ),
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
                "sky_irradiance",
                "W/m²",
                "irradiance from a uniform sky at a surface point, with the scene's occlusion",
                (
                    *_NORMAL,
                    *_vec("b", "unit bent normal: the mean unoccluded direction (what an engine bakes)"),
                    Input(
                        "visibility", "1", "cosine-weighted unoccluded fraction of the hemisphere", (0.0, 1.0)
                    ),
                    Input(
                        "aperture",
                        "rad",
                        "half-angle of the visibility cap around the bent normal",
                        (0.0, 0.5 * math.pi),
                    ),
                    Input("sky_radiance", "W/m²/sr", "radiance L_sky of the uniform sky", (0.0, 10.0)),
                    *_POINT,
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
                examples={"coeffs": _example_sh},
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
                    *_NORMAL,
                    Input(
                        "sh",
                        "W/m²",
                        "27 floats: the environment's SH coefficients L_lm, l ≤ 2, channel-major",
                    ),
                ),
                vectors={"normal": ("nx", "ny", "nz")},
                unit_vectors=("normal",),
                channels=3,
                examples={"sh": _example_sh},
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
                    *(
                        Input(f"sun_{c}", "W/m²", f"the sun's irradiance, {c} channel", (0.0, 10.0))
                        for c in "rgb"
                    ),
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
                    *(
                        Input(f"l0_{c}", "W/m²/sr", f"fog-free radiance L₀, {c} channel", (0.0, 10.0))
                        for c in "rgb"
                    ),
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
                "radiance a point light scatters into a view segment through a homogeneous medium "
                "(per channel)",
                (
                    *_vec("o", "segment start o (the camera, or where its ray enters)", "m", _M100),
                    *_vec("d", "segment vector d (o → the segment's end: |d| is its length)", "m", _M100),
                    *_vec("l", "light position l", "m", (-90.0, 90.0)),
                    *_MEDIUM_LIGHT,
                ),
                vectors={"origin": ("ox", "oy", "oz"), "segment": ("dx", "dy", "dz"), "light": _LIGHT},
                reference="single scattering of that light along the camera's rays in the medium "
                "(equiangular sampling, Mitsuba's emitter, phase function and shadow rays)",
            ),
            Quantity(
                "drop_radiance",
                "W/m²/sr",
                "radiance of a water drop (a dielectric sphere) under a distant environment, per RGB channel",
                DROP_INPUTS,
                vectors={"direction": ("dx", "dy", "dz"), "normal": ("nx", "ny", "nz")},
                unit_vectors=("direction", "normal"),
                channels=3,
                examples={
                    f"env_{c}": _example_map(DROP_ENV_RESOLUTION, 0.2, 2.0 - 0.3 * k)
                    for k, c in enumerate("rgb")
                },
                reference="path-traced radiance of the pixels that see the drop (Mitsuba's dielectric, path)",
                note=f"env_r, env_g, env_b: the channels' cube maps of {DROP_ENV_RESOLUTION}² texels a face "
                "(rtfit.realtime.environment_maps' layout)",
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
                    *_vec("d", "unit view direction (+Z up)"),
                    *_vec("s", "unit direction to the sun"),
                    Input("altitude", "m", "the viewer's altitude above the ground", (0.0, 1.0e4)),
                ),
                vectors={"direction": ("dx", "dy", "dz"), "sun": ("sx", "sy", "sz")},
                unit_vectors=("direction", "sun"),
                channels=3,
                reference="sky radiance along the camera's sky pixels (volpathmis in the shell atmosphere)",
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
            Quantity(
                "parallax_depth",
                "1",
                "depth below a height-mapped surface of the point a view ray sees, as a fraction of the "
                "height range (0: on the surface, 1: the deepest valley h = 0)",
                (
                    Input(
                        "u0",
                        "texture units",
                        "the pixel's texture coordinate u (on the surface)",
                        (-2.0, 2.0),
                    ),
                    Input("v0", "texture units", "the pixel's texture coordinate v", (-2.0, 2.0)),
                    *(
                        Input(f"v{c}", "1", f"unit view vector (to the eye), tangent space {c}", (-1.0, 1.0))
                        for c in "xy"
                    ),
                    Input(
                        "vz",
                        "1",
                        "unit view vector, tangent space z = N·V (the audit leaves out pixels below 10⁻³; "
                        "validation draws vx, vy, vz independently)",
                        (1.0e-3, 1.0),
                    ),
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
                    Input(
                        "u0",
                        "texture units",
                        "the pixel's texture coordinate u (on the surface)",
                        (-2.0, 2.0),
                    ),
                    Input("v0", "texture units", "the pixel's texture coordinate v", (-2.0, 2.0)),
                    *(
                        Input(f"v{c}", "1", f"unit view vector (to the eye), tangent space {c}", (-1.0, 1.0))
                        for c in "xy"
                    ),
                    Input("vz", "1", "unit view vector, tangent space z = N·V", (1.0e-3, 1.0)),
                    *(
                        Input(
                            f"l{c}", "1", f"unit vector to the light's centre, tangent space {c}", (-1.0, 1.0)
                        )
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
                    Input(
                        "v", "texture units", "texture coordinate v of the exact visible point", (-2.0, 2.0)
                    ),
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
                ),
                vectors={"view": ("vx", "vy", "vz"), "light": ("lx", "ly", "lz")},
                examples={"field": _example_field},
                reference="Mitsuba ray_test from the displaced mesh's first hit to samples of the area light "
                "(the light's own sampling): unoccluded-weighted fraction with its standard error",
            ),
            Quantity(
                "reflected_radiance",
                "W/m²/sr",
                "radiance of a mirror, glass or glossy surface from cube maps captured at a probe point, "
                "per RGB channel",
                (
                    *REFLECTION_INPUTS,
                    Input(
                        "resolution",
                        "texels",
                        "texels per face edge N of the radiance and distance maps (a Python int; the maps' "
                        "layout: `rtfit.realtime.environment_maps`, read with its cube_lookup_kernel)",
                    ),
                    Input("irr_resolution", "texels", "texels per face edge of the irradiance map (an int)"),
                ),
                vectors={
                    "point": ("x", "y", "z"),
                    "reflect": ("rx", "ry", "rz"),
                    "refract": ("tx", "ty", "tz"),
                    "normal": ("nx", "ny", "nz"),
                },
                unit_vectors=("reflect", "normal"),
                channels=3,
                examples=_REFLECTION_MAPS,
                reference="path-traced radiance of the pixels that see the shape (Mitsuba's own BSDF)",
                note="the glossy pre-filtered map of the preconvolved rows is not in g",
            ),
            Quantity(
                "probe_specular_radiance",
                "W/m²/sr",
                "radiance of a glossy surface from the nearest (or assigned) probe's cube map pre-convolved "
                "per roughness, per RGB channel",
                (*PROBE_SPECULAR_INPUTS,),
                vectors={
                    "point": ("x", "y", "z"),
                    "reflect": ("rx", "ry", "rz"),
                    "normal": ("nx", "ny", "nz"),
                },
                unit_vectors=("reflect", "normal"),
                channels=3,
                examples=_PROBE_SPECULAR_TABLES,
                reference="path-traced radiance of the pixels that see the glossy shape (Mitsuba's own BSDF)",
            ),
            Quantity(
                "volume_irradiance",
                "W/m²",
                "irradiance at a surface point looked up in a regular grid of baked probes, per RGB channel",
                (
                    *_POINT,
                    *_NORMAL,
                    Input(
                        "table",
                        "W/m²",
                        "SH L2 probes, float-major: g.table[s·count + node], s = channel·9 + lm "
                        "(`irradiance_volumes.probe_table`; read with ops.gather)",
                    ),
                    Input(
                        "cube_table",
                        "W/m²",
                        "Valve's ambient cube (six axes sampled) of each probe, float-major as g.table: 18 "
                        "floats (channel·6 + face, faces +x −x +y −y +z −z)",
                    ),
                    Input(
                        "nnls_table", "W/m²", "the NNLS-fitted ambient cube of each probe, as g.cube_table"
                    ),
                    Input(
                        "grid",
                        "m",
                        "the ProbeGrid: g.grid.origin, g.grid.spacing h, g.grid.dims (n_x, n_y, n_z), "
                        "g.grid.count; node (i, j, k) at origin + h·(i, j, k), index (k·n_y + j)·n_x + i",
                    ),
                ),
                vectors={"point": ("px", "py", "pz"), "normal": ("nx", "ny", "nz")},
                unit_vectors=("normal",),
                channels=3,
                examples={
                    "table": _example_table(9),
                    "cube_table": _example_table(6),
                    "nnls_table": _example_table(6),
                    "grid": _example_grid,
                },
                reference="path-traced irradiance at the visible points (every light a ray can reach, as "
                "the probes store it)",
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
    }
)
"""Every documented quantity by name (docs/audit.md, "Your own approximation", is generated from it)."""


class ApproximationError(ValueError):
    """A wrong `approximation` declaration or an unknown quantity: one line."""


def get_quantity(name: str) -> Quantity:
    """The quantity ``name``; an unknown name is a one-line `ApproximationError` listing the known ones."""
    q = QUANTITIES.get(name) if isinstance(name, str) else None
    if q is None:
        raise ApproximationError(f"unknown quantity {name!r} (known: {', '.join(QUANTITIES)})")
    return q


class QuantityInputs:
    """The ``g`` a user function receives: attribute access to the quantity's named inputs, and to its
    vector groups as 3-tuples. ``record`` (a set, optional) collects the names the function reads."""

    __slots__ = ("_q", "_record", "_values")

    def __init__(self, quantity: Quantity, values: Mapping[str, Any], record: set[str] | None = None):
        object.__setattr__(self, "_q", quantity)
        object.__setattr__(self, "_values", dict(values))
        object.__setattr__(self, "_record", record)

    def __getattr__(self, name: str):
        q, values, record = self._q, self._values, self._record
        if name in values:
            if record is not None:
                record.add(name)
            return values[name]
        if name in q.vectors:
            comps = q.vectors[name]
            if record is not None:
                record.update(comps)
            return tuple(values[c] for c in comps)
        known = ", ".join([*q.input_names, *q.vectors])
        raise AttributeError(f"{q.name} carries no input {name!r} (it carries: {known})")

    def __setattr__(self, name, value):
        raise AttributeError("g is read-only")

    def __dir__(self):
        return [*self._q.input_names, *self._q.vectors]

    def __repr__(self):
        return f"<g of {self._q.name}: {', '.join(self._q.input_names)}>"


class UserCodeExit(ValueError):
    """A user approximation called ``sys.exit`` (or raised `SystemExit`) while it ran: one line naming it.
    User code must never end the process that evaluates it: a CI job would read the exit status 0 of
    ``sys.exit(0)`` as success, with no report written (issue 32)."""


class UserKernel:
    """The kernel of a user approximation: ``kernel(ops, **inputs, **params)`` builds ``g`` from the
    quantity's inputs and returns ``function(ops, g, **params)``. ``run`` does the same with a record of
    the inputs read (validation)."""

    def __init__(self, function: Callable[..., Any], quantity: Quantity):
        self.function = function
        self.quantity = quantity
        self.__name__ = getattr(function, "__name__", "approximation")
        self.__doc__ = function.__doc__

    def run(self, ops, values: Mapping[str, Any], params: Mapping[str, Any], record: set[str] | None = None):
        try:
            return self.function(ops, QuantityInputs(self.quantity, values, record), **params)
        except SystemExit as e:  # wherever it runs (validation, the audit, a fit): never the process's exit
            raise UserCodeExit(
                f"{self.__name__}: called sys.exit({e.code!r}) (an approximation must return values or raise "
                "an exception)"
            ) from None

    def __call__(self, ops, **kw):
        values = {n: kw.pop(n) for n in self.quantity.input_names if n in kw}
        return self.run(ops, values, kw)

    def __repr__(self):
        return f"<user kernel {self.__name__} ({self.quantity.name})>"


def is_user_approximation(obj: Any) -> bool:
    """True for a `Method` made by `approximation`."""
    return isinstance(obj, Method) and isinstance(obj.kernel, UserKernel)


def _where(function) -> str:
    try:
        file = inspect.getsourcefile(function) or "?"
        line = inspect.getsourcelines(function)[1]
    except (OSError, TypeError):
        return ""
    return f"{file}:{line}"


UNDECLARED_UNIT = "undeclared"
"""The unit of a user approximation's parameter declared without ``unit=`` (in reports and fitted files:
the number's unit is not known to rtfit)."""


def approximation(
    *,
    quantity: str,
    params: Mapping[str, Param] | None = None,
    label: str | None = None,
    id: str | None = None,
) -> Callable[[Callable[..., Any]], Method]:
    """Decorator: ``f(ops, g, **params)`` → a `Method` of ``quantity`` (module docstring).

    ``params``: the free parameters, each a `Param` (start value and bounds: a fit stays within them; one
    declared without ``unit=`` gets `UNDECLARED_UNIT`, so a fitted file says the unit is not known);
    ``label`` (default: the first line of ``f``'s docstring, else its name); ``id`` (default ``f``'s name).
    A wrong declaration is a one-line `ApproximationError` naming the function: an unknown quantity (listing
    the known ones), a parameter given as a bare number (no bounds), a parameter ``f`` does not take as a
    keyword, a keyword ``f`` requires that is not declared."""
    q = get_quantity(quantity)
    declared = dict(params or {})

    def wrap(f: Callable[..., Any]) -> Method:
        name = id or getattr(f, "__name__", "approximation")
        if not callable(f):
            raise ApproximationError(f"{name}: @approximation decorates a function f(ops, g, **params)")
        for k, p in declared.items():
            if not isinstance(p, Param):
                raise ApproximationError(
                    f"{name}: parameter {k!r} = {p!r} has no bounds; declare it as "
                    f"Param(initial, lower=…, upper=…)"
                )
        try:
            sig = inspect.signature(f)
        except (TypeError, ValueError):
            sig = None
        if sig is not None:
            ps = list(sig.parameters.values())
            var_kw = any(p.kind is p.VAR_KEYWORD for p in ps)
            positional = [p for p in ps if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
            if len(positional) < 2 and not any(p.kind is p.VAR_POSITIONAL for p in ps):
                raise ApproximationError(f"{name}: an approximation takes (ops, g, *, params…); got {sig}")
            keywords = {p.name for p in ps[2:] if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
            extra = sorted(set(declared) - keywords) if not var_kw else []
            if extra:
                raise ApproximationError(
                    f"{name}: parameter(s) {', '.join(extra)} declared but not taken by {name}{sig}"
                )
            required = sorted(
                p.name
                for p in ps[2:]
                if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
                and p.default is p.empty
                and p.name not in declared
            )
            if required:
                raise ApproximationError(
                    f"{name}: keyword(s) {', '.join(required)} of {name}{sig} are not declared in params="
                )
        doc = inspect.getdoc(f) or ""
        first = doc.splitlines()[0].strip() if doc else ""
        try:
            return Method(
                id=name,
                label=label or first or name,
                kernel=UserKernel(f, q),
                inputs=q.inputs,
                # a unit the user left out is said to be so (fitted files refuse an empty unit)
                params={k: p if p.unit else replace(p, unit=UNDECLARED_UNIT) for k, p in declared.items()},
                quantity=q.name,
                formula=first,
                source=_where(f),
                description=doc,
            )
        except ValueError as e:
            raise ApproximationError(f"{name}: {e}") from None

    return wrap


def quantities_markdown(tables: Mapping[str, Mapping[str, Method]]) -> str:
    """The quantity table of docs/audit.md ("Your own approximation"), generated from `QUANTITIES`; the
    shipped methods from ``tables`` (family → method table, `rtfit.experiments.families.METHOD_TABLES`)."""
    lines = []
    for q in QUANTITIES.values():
        out = "one array" if q.channels == 1 else f"a tuple of {q.channels} arrays (R, G, B)"
        lines.append(f"#### `{q.name}` [{q.unit}]")
        lines.append("")
        lines.append(f"{q.description[0].upper()}{q.description[1:]}; `f` returns {out}.")
        lines.append(f"Reference: {q.reference}." if q.reference else "")
        shipped = ", ".join(f"`{m}`" for m in q.methods(tables)) or "none"
        lines.append(f"Shipped methods: {shipped}." + (f" ({q.note}.)" if q.note else ""))
        lines.append("")
        lines.append("| input | unit | domain | meaning |")
        lines.append("|---|---|---|---|")
        for i in q.inputs:
            dom = "structured" if i.domain is None else f"[{i.domain[0]:g}, {i.domain[1]:g}]"
            lines.append(f"| `{i.name}` | {i.unit} | {dom} | {i.description} |")
        if q.vectors:
            groups = "; ".join(
                f"`g.{k}` = `({', '.join('g.' + c for c in v)})`" + (" (unit)" if k in q.unit_vectors else "")
                for k, v in q.vectors.items()
            )
            lines.append("")
            lines.append(f"Vectors: {groups}.")
        lines.append("")
    return "\n".join(line for line in lines).rstrip() + "\n"
