"""The environment-maps family on a user's shape: the radiance a real-time renderer gives a mirror, glass or
glossy surface from one cube map captured at the shape's centre.

What an engine stores at a probe point c (the shape's centre; this module's cube layout is
`rtfit.realtime.environment_maps`'): a radiance cube map L(ω) of ``PROBE_RESOLUTION``² texels a face,
the distance cube map dist(ω) from c to the surface seen through each texel (the distance impostor of
GameTools D5.3, seed 001:482-553, 841-866), a glossy pre-filtered map G_s(q) = ∫ L(ω) (s+1)/(2π)
max(q·ω, 0)^s dω of ``GLOSSY_RESOLUTION``² texels a face (the pre-convolved map, 001:569-594, exact
texel solid angles) and an irradiance map E(n) = ∫ L(ω) max(n·ω, 0) dω of ``IRRADIANCE_RESOLUTION``².

At a pixel that sees the shape at x (relative to c), with the mirror direction R, the refracted direction T
and the BSDF's lobe weights per channel (w_r: reflection, w_t: transmission, w_d: diffuse; Fresnel and
albedo included, from the BSDF itself), every row shades

    L ≈ w_r·M(x, R) + w_t·M(x, T) + w_d·E(n)/π        (W/(m²·sr), per RGB channel)

where M is the row's lookup: ``classic`` M = L(R) (the environment at infinity, 001:482-497);
``parallax`` M = L(x + R·(dist(R) − x·R)) (one-lookup distance impostor, 001:547-553); ``iterative``
M = L(hit) of the secant search on |l|/dist(l) = 1 (`ITERATIONS` steps, 001:841-866); ``preconvolved``
M = G_s(R) (the glossy pre-filtered map at the mirror direction: what engines do for rough surfaces);
``preconvolved-parallax`` M = G_s(one-lookup impostor hit). Every lookup is `cube_lookup_kernel` with
bilinear filtering inside a face; the hit searches are `hit_parallax_kernel` and `hit_iterative_kernel`.
The kernels are those texts, called; no formula is restated here.

Domain: unit directions (a zero T where w_t = 0 looks up the +Z face's centre, times 0), finite distances
(the capture stores rays that leave the scene at a far distance, a finite stand-in for infinity).
"""

from __future__ import annotations

import math

from .environment_maps import cube_lookup_kernel, hit_iterative_kernel, hit_parallax_kernel
from .methods import Input, Method, method_table

__all__ = [
    "GLOSSY_RESOLUTION",
    "INPUTS",
    "IRRADIANCE_RESOLUTION",
    "ITERATIONS",
    "PROBE_RESOLUTION",
    "prefiltered_reflection_kernel",
    "probe_reflection_kernel",
]

PROBE_RESOLUTION = 32
"""Texels per face edge of the radiance and distance cube maps."""
GLOSSY_RESOLUTION = 16
"""Texels per face edge of the glossy pre-filtered map."""
IRRADIANCE_RESOLUTION = 8
"""Texels per face edge of the irradiance (cosine pre-convolved) map."""
ITERATIONS = 4
"""Secant steps of the ``iterative`` row."""
_INV_PI = 1.0 / math.pi


def _lookup_point(ops, dist, x, y, z, dx, dy, dz, hit, resolution, iterations):
    """Where a ray x + t·d reads the map: d itself (``classic``) or the impostor's hit point."""
    if hit == "classic":
        return dx, dy, dz
    if hit == "parallax":
        return hit_parallax_kernel(ops, dist, x, y, z, dx, dy, dz, resolution, True)
    return hit_iterative_kernel(ops, dist, x, y, z, dx, dy, dz, resolution, True, iterations)


def _shade(ops, maps, map_resolution, irradiance, irr_resolution, weights, hr, ht, normal):
    """w_r·M(hr) + w_t·M(ht) + w_d·E(n)/π per channel."""
    out = []
    for table, irr, (wr, wt, wd) in zip(maps, irradiance, weights, strict=True):
        lr = cube_lookup_kernel(ops, table, hr[0], hr[1], hr[2], map_resolution, True)
        lt = cube_lookup_kernel(ops, table, ht[0], ht[1], ht[2], map_resolution, True)
        e = cube_lookup_kernel(ops, irr, normal[0], normal[1], normal[2], irr_resolution, True)
        out.append(wr * lr + wt * lt + wd * e * _INV_PI)
    return tuple(out)


def probe_reflection_kernel(
    ops, x, y, z, rx, ry, rz, tx, ty, tz, nx, ny, nz,
    wr_r, wr_g, wr_b, wt_r, wt_g, wt_b, wd_r, wd_g, wd_b,
    rad_r, rad_g, rad_b, irr_r, irr_g, irr_b, dist,
    hit, resolution, irr_resolution, iterations,
):  # fmt: skip
    """(R, G, B) radiance from the radiance cube map ``rad_*`` read at the row's lookup point (module
    docstring); ``dist`` the distance map, both ``resolution``² a face."""
    hr = _lookup_point(ops, dist, x, y, z, rx, ry, rz, hit, resolution, iterations)
    ht = _lookup_point(ops, dist, x, y, z, tx, ty, tz, hit, resolution, iterations)
    weights = ((wr_r, wt_r, wd_r), (wr_g, wt_g, wd_g), (wr_b, wt_b, wd_b))
    return _shade(
        ops, (rad_r, rad_g, rad_b), resolution, (irr_r, irr_g, irr_b), irr_resolution, weights, hr, ht,
        (nx, ny, nz),
    )  # fmt: skip


def prefiltered_reflection_kernel(
    ops, x, y, z, rx, ry, rz, tx, ty, tz, nx, ny, nz,
    wr_r, wr_g, wr_b, wt_r, wt_g, wt_b, wd_r, wd_g, wd_b,
    glossy_r, glossy_g, glossy_b, irr_r, irr_g, irr_b, dist,
    hit, resolution, glossy_resolution, irr_resolution, iterations,
):  # fmt: skip
    """(R, G, B) radiance from the glossy pre-filtered map ``glossy_*`` (``glossy_resolution``² a face) read
    at the row's lookup point, found on the distance map ``dist`` (``resolution``² a face)."""
    hr = _lookup_point(ops, dist, x, y, z, rx, ry, rz, hit, resolution, iterations)
    ht = _lookup_point(ops, dist, x, y, z, tx, ty, tz, hit, resolution, iterations)
    weights = ((wr_r, wt_r, wd_r), (wr_g, wt_g, wd_g), (wr_b, wt_b, wd_b))
    return _shade(
        ops, (glossy_r, glossy_g, glossy_b), glossy_resolution, (irr_r, irr_g, irr_b), irr_resolution,
        weights, hr, ht, (nx, ny, nz),
    )  # fmt: skip


def _vec(prefix: str, what: str, unit: str = "1", domain=(-1.0, 1.0)) -> tuple[Input, ...]:
    return tuple(Input(f"{prefix}{c}", unit, f"{what}, {c} component", domain) for c in "xyz")


def _rgb(prefix: str, what: str, unit: str, domain) -> tuple[Input, ...]:
    return tuple(Input(f"{prefix}_{c}", unit, f"{what}, {c} channel", domain) for c in "rgb")


_GEOMETRY = (
    *(Input(c, "m", f"shading point {c}, relative to the probe point", (-10.0, 10.0)) for c in "xyz"),
    *_vec("r", "unit mirror direction about the shading normal"),
    *_vec("t", "unit refracted direction (0 where the BSDF transmits nothing)"),
    *_vec("n", "unit shading normal, facing the camera"),
    *_rgb("wr", "reflection weight (Fresnel × reflectance, or the glossy lobe's albedo)", "1", (0.0, 1.0)),
    *_rgb("wt", "transmission weight ((1 − F) × transmittance, or the glossy lobe's)", "1", (0.0, 1.0)),
    *_rgb("wd", "diffuse albedo of the BSDF's diffuse lobe", "1", (0.0, 1.0)),
)
_RADIANCE = tuple(
    Input(f"rad_{c}", "W/m²/sr", f"radiance cube map, {c} channel (6·N² texels)") for c in "rgb"
)
_GLOSSY = tuple(
    Input(f"glossy_{c}", "W/m²/sr", f"glossy pre-filtered cube map, {c} channel (6·N² texels)") for c in "rgb"
)
_TABLES = (
    *(Input(f"irr_{c}", "W/m²", f"irradiance cube map, {c} channel (6·N² texels)") for c in "rgb"),
    Input("dist", "m", "distance cube map: from the probe point to the surface seen (6·N² texels)"),
)
INPUTS = (*_GEOMETRY, *_RADIANCE, *_TABLES)
"""The inputs of the ``classic``, ``parallax`` and ``iterative`` rows: the pixel's geometry and lobe weights,
the radiance, irradiance and distance cube maps (the ``reflected_radiance`` quantity's, with the maps'
resolutions: `rtfit.realtime.quantities`)."""
_FIXED = {"resolution": PROBE_RESOLUTION, "irr_resolution": IRRADIANCE_RESOLUTION, "iterations": ITERATIONS}
_QUANTITY = "reflected_radiance"


def _row(mid: str, label: str, hit: str, glossy: bool, formula: str, source: str) -> Method:
    fixed = {**_FIXED, "hit": hit}
    if glossy:
        fixed["glossy_resolution"] = GLOSSY_RESOLUTION
    return Method(
        mid,
        label,
        prefiltered_reflection_kernel if glossy else probe_reflection_kernel,
        inputs=(*_GEOMETRY, *(_GLOSSY if glossy else _RADIANCE), *_TABLES),
        fixed=fixed,
        quantity=_QUANTITY,
        formula=f"w_r·{formula.format(d='R')} + w_t·{formula.format(d='T')} + w_d·E(n)/π",
        source=source,
    )


METHODS = method_table(
    [
        _row("classic", "Classic environment map (L at R, T)", "classic", False, "L({d})", "001:482-497"),
        _row(
            "parallax",
            "Distance impostor, one lookup",
            "parallax",
            False,
            "L(x + {d}·(dist({d}) − x·{d}))",
            "001:547-553",
        ),
        _row(
            "iterative",
            f"Distance impostor, secant search ({ITERATIONS} steps)",
            "iterative",
            False,
            "L(secant hit of x + t·{d})",
            "001:841-866",
        ),
        _row(
            "preconvolved",
            "Pre-convolved glossy map (G_s at R, T)",
            "classic",
            True,
            "G_s({d})",
            "001:569-594",
        ),
        _row(
            "preconvolved-parallax",
            "Pre-convolved glossy map, one-lookup impostor",
            "parallax",
            True,
            "G_s(x + {d}·(dist({d}) − x·{d}))",
            "001:547-594",
        ),
    ]
)
"""The rows the audit evaluates on a reflective shape of a user's scene (quantity ``reflected_radiance``,
RGB). The ``preconvolved`` rows need a glossy lobe (a rough BSDF) to have a shininess to filter with."""
