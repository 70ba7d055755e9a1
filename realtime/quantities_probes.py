"""The quantities read from captured cube maps and baked probes: a water drop under an environment map,
reflections from a probe's cube maps, pre-convolved probe specular, and irradiance volumes.

One room of the quantity table (`rtfit.realtime.quantities.QUANTITIES`, which gives their order)."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from .irradiance_volumes import ProbeGrid, probe_table
from .methods import Input
from .probe_specular import INPUTS as PROBE_SPECULAR_INPUTS
from .probe_specular import IRRADIANCE_RESOLUTION as PS_IRRADIANCE_RESOLUTION
from .probe_specular import LEVELS as PS_LEVELS
from .probe_specular import PREFILTER_RESOLUTION, ProbeChains
from .quantity_types import NORMAL_INPUTS, POINT_INPUTS, Quantity, example_sh_coefficients, quantity_table
from .raindrops import ENV_RESOLUTION as DROP_ENV_RESOLUTION
from .raindrops import INPUTS as DROP_INPUTS
from .reflections import INPUTS as REFLECTION_INPUTS
from .reflections import IRRADIANCE_RESOLUTION, PROBE_RESOLUTION

__all__ = [
    "PROBE_QUANTITIES",
]


EXAMPLE_GRID = ProbeGrid((-10.0, -10.0, -10.0), 20.0, (2, 2, 2))
"""The ``volume_irradiance`` quantity's example grid: 2 × 2 × 2 probes at the corners of the points'
domain."""


def _example_grid(n: int) -> ProbeGrid:
    return EXAMPLE_GRID


def _example_coefficients(rows: int) -> np.ndarray:
    """Per-probe basis coefficients (count, rows, 3) of the example grid: each probe's light brighter above
    than below (the SH sky of `example_sh_coefficients`; a cube of 1 + the axis's z), scaled by the probe's
    index."""
    count = EXAMPLE_GRID.count
    scale = 1.0 + 0.25 * np.arange(count)[:, None, None]
    if rows == 9:
        one = np.asarray(example_sh_coefficients(), np.float64).reshape(3, 9).T  # (9, RGB)
    else:  # +x, −x, +y, −y, +z, −z (irradiance_bases.CUBE_ORDER)
        one = np.array([1.0, 1.0, 1.0, 1.0, 2.0, 0.5])[:, None] * np.array([1.0, 0.9, 0.8])[None, :]
    return scale * one[None, :, :]


def _example_table(rows: int) -> Callable[[int], np.ndarray]:
    return lambda n: probe_table(_example_coefficients(rows))


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


PROBE_QUANTITIES: Mapping[str, Quantity] = quantity_table(
    Quantity(
        "drop_radiance",
        "W/m²/sr",
        "radiance of a water drop (a dielectric sphere) under a distant environment, per RGB channel",
        DROP_INPUTS,
        vectors={"direction": ("dx", "dy", "dz"), "normal": ("nx", "ny", "nz")},
        unit_vectors=("direction", "normal"),
        channels=3,
        examples={
            f"env_{c}": _example_map(DROP_ENV_RESOLUTION, 0.2, 2.0 - 0.3 * k) for k, c in enumerate("rgb")
        },
        reference="path-traced radiance of the pixels that see the drop (Mitsuba's dielectric, path)",
        note=f"env_r, env_g, env_b: the channels' cube maps of {DROP_ENV_RESOLUTION}² texels a face "
        "(rtfit.realtime.environment_maps' layout)",
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
            *POINT_INPUTS,
            *NORMAL_INPUTS,
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
            Input("nnls_table", "W/m²", "the NNLS-fitted ambient cube of each probe, as g.cube_table"),
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
)
"""The cube-map and probe quantities by name."""
