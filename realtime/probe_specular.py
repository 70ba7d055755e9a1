r"""Specular from the nearest pre-rendered cube map, pre-convolved per roughness (the ``probe-specular``
family, docs/probe-specular.md).

The seed (000:2459-2466, Source engine, "World Specular Lighting")
-------------------------------------------------------------------
Level designers place point entities as sample points; HDR cube maps are pre-rendered from them and stored
with the level; at run time a surface whose material has a specular term uses the cube map of the
*nearest* sample point (or one assigned by hand at boundaries). The text prints no filtering and no
parallax: the cube map is read at the mirror direction R as if it were at infinity. It does not say how
a glossy (rough) surface blurs it; the reading audited here is what engines do with that scheme for glossy
surfaces (stated, not printed): the probe's radiance map is pre-convolved once per roughness level into a
mip chain, and a surface of roughness α reads the level of its α. The seed's ``nearest`` row is that:

    L ≈ w_r·G(α, R) + w_d·E(n)/π        (W/(m²·sr), per RGB channel)

with w_r the glossy lobe's directional albedo (Fresnel and shadowing included: the split-sum's second
factor, here taken from the BSDF itself), w_d the diffuse albedo of a rough plastic's base, E the probe's
irradiance map and G the pre-convolved chain read trilinearly (`chain_lookup_kernel`).

Pre-convolution per roughness (Karis 2013, "Real Shading in Unreal Engine 4", SIGGRAPH course, eq. 3 and
the "n = v = R" assumption): level k of ``LEVELS`` holds, at each texel direction q,

    G_k(q) = Σ_t L_t·w(q·ω_t; α_k)·Ω_t / Σ_t w(q·ω_t; α_k)·Ω_t,
    w(c; α) = D_GGX(cos θ_h; α)·max(c, 0),   cos² θ_h = (1 + c)/2,   D_GGX = α²/(π((α² − 1)cos² θ_h + 1)²)

(`ggx_prefilter_weight_kernel`: the density of light directions l when half vectors are drawn from D·cos θ_h
about n = v = q, times n·l, Karis's weighting), with α_k = (k/(LEVELS − 1))² — levels evenly spaced in the
perceptual roughness r = √α (Burley 2012). A level whose lobe is narrower than a texel (2α below the texel's
angle π/(2N)) is the radiance map's own bilinear value (`prefilter_matrix`): no texel centre lies in it.

Roughness → mip level: m = (LEVELS − 1)·α^(p/2), read trilinearly (bilinear in each of the two levels
around m, linear between them). p = 1 reads the level of α exactly at the levels' α_k (the given mapping);
the ``*-mip-fit`` rows fit p within [0.2, 5] (an engine's tuned mapping).

Parallax correction (Lagarde & Zanuttini 2012, "Local image-based lighting with parallax-corrected
cubemaps", SIGGRAPH talk; Lagarde's blog post of the same name): the reflected ray x + t·R from the shading
point x (relative to the probe) is intersected with a proxy of the surroundings, and the map is read in the
direction of that hit from the probe:

* ``box`` (`box_parallax_kernel`): the axis-aligned box [b0, b1] (relative to the probe), t = min over the
  axes of max((b1 − x)/R, (b0 − x)/R) (the exit distance of a point inside), read at x + t·R;
* ``sphere`` (`sphere_parallax_kernel`): the sphere of radius ρ about the probe,
  t = −x·R + √((x·R)² − |x|² + ρ²).

Domain and guards (each with its reason)
----------------------------------------
* α ∈ [0, 1] (clamped: a fit or a user value outside has no level); α ≤ 0 is level 0 exactly, and α is
  floored at 10⁻⁶ inside α^(p/2) (the JAX gradient of 0^q is NaN).
* R, n unit vectors. A zero component of R: the box's 1/R is taken as ±10³⁰ (its slab is never the exit).
* A shading point outside the box (t ≤ 0) or outside the sphere (negative discriminant, or t ≤ 0) has no
  exit point: the lookup falls back to R (no correction), which is also what an engine does past the
  proxy's influence volume.
* Probe index and level are whole texel offsets into the stacked tables; m is clipped to [0, LEVELS − 1].

Float32: the level interpolation and the slab test are a few operations on O(1) numbers; D_GGX's
denominator is ≥ α⁴ (floored at 10⁻³⁰) and its weights are normalised by their own sum.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .arrays import cached_table, evaluate_numpy
from .environment_maps import cube_lookup, cube_lookup_kernel, cube_texels, texel_solid_angle
from .methods import Input, Method, Param, method_table

__all__ = [
    "LEVELS",
    "PREFILTER_RESOLUTION",
    "PREFILTER_ROWS",
    "ProbeChains",
    "box_parallax_kernel",
    "chain_lookup_kernel",
    "ggx_prefilter_weight_kernel",
    "level_roughness",
    "lobe_within_texel",
    "mip_level_kernel",
    "prefilter",
    "prefilter_many",
    "prefilter_matrix",
    "probe_specular_kernel",
    "sphere_parallax_kernel",
]

PROBE_RESOLUTION = 32
"""Texels per face edge of the captured radiance map (and of the distance map the proxies are sized from)."""
PREFILTER_RESOLUTION = 16
"""Texels per face edge of every level of the pre-convolved chain (one resolution for all levels: the
error measured is the filter's and the mapping's, not a mip's down-sampling)."""
IRRADIANCE_RESOLUTION = 8
"""Texels per face edge of the irradiance map (a rough plastic's diffuse base)."""
LEVELS = 6
"""Roughness levels of the chain: α_k = (k/(LEVELS − 1))², k = 0…LEVELS − 1."""
_INV_PI = 1.0 / math.pi
_BIG = 1e30


def level_roughness(levels: int = LEVELS) -> np.ndarray:
    """The GGX α of each level of the chain: (k/(levels − 1))²."""
    return (np.arange(levels, dtype=np.float64) / max(levels - 1, 1)) ** 2


def ggx_prefilter_weight_kernel(ops, cos_angle, alpha):
    """Karis's pre-convolution weight of a light direction at cos c from the lobe axis (n = v = R):
    D_GGX(cos θ_h; α)·max(c, 0) with cos² θ_h = (1 + c)/2 (module docstring)."""
    c = ops.maximum(cos_angle, 0.0)
    a2 = alpha * alpha
    h2 = 0.5 * (1.0 + c)
    den = (a2 - 1.0) * h2 + 1.0
    return a2 * _INV_PI / ops.maximum(den * den, 1e-30) * c


def lobe_within_texel(source: int, alpha: float) -> bool:
    """Whether the lobe of ``alpha`` is narrower than a texel of a ``source``² map (2α < π/(2·source)): no
    texel centre lies in it, and the level is the map's bilinear value (`prefilter_matrix` is None)."""
    return 2.0 * alpha < 0.5 * math.pi / source


def prefilter_matrix(source: int, target: int, alpha: float, rows: slice = slice(None)) -> np.ndarray | None:
    """The (6·target², 6·source²) matrix W of one level (G = W·L, rows summing to 1): Karis's weights
    (`ggx_prefilter_weight_kernel`) times the exact texel solid angles, normalised per row. None where the
    lobe is narrower than a source texel (2α < π/(2·source)): the level is then the bilinear lookup.
    ``rows``: only those target texels' rows (`prefilter_many` builds a level a block at a time; each row
    is computed alone, so a block's rows are the whole matrix's)."""
    if lobe_within_texel(source, alpha):
        return None
    return _weight_rows(_unit_texels(target)[rows], _unit_texels(source), _solid_angles(source), alpha)


def _unit_texels(resolution: int) -> np.ndarray:
    q = cube_texels(resolution)["point"]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _solid_angles(source: int) -> np.ndarray:
    return texel_solid_angle(source, "exact")[None, :]


def _weight_rows(q: np.ndarray, w: np.ndarray, omega: np.ndarray, alpha: float) -> np.ndarray:
    """Rows of `prefilter_matrix` for the unit target directions ``q`` over the unit source texels ``w``
    (solid angles ``omega``, (1, S))."""
    with np.errstate(all="ignore"):
        weights = evaluate_numpy(ggx_prefilter_weight_kernel, q @ w.T, float(alpha))
    weights = np.asarray(weights) * omega
    return weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)


PREFILTER_ROWS = 256
"""Target texels (rows of a level's matrix) `prefilter_many` builds and applies at a time. The whole
matrix at 16² from 32² is 1536 × 6144 float64 (75 MB) and its build held several temporaries of that size;
a block of 256 rows is 12.6 MB (issue 33: the quick suite's peak memory was probe-specular's matrices)."""


def prefilter_many(
    radiances: Sequence[np.ndarray], target: int = PREFILTER_RESOLUTION, levels: int = LEVELS
) -> list[np.ndarray]:
    """The chains of several probes (each as `prefilter`), every level's matrix built once for all of them
    and never whole: a block of `PREFILTER_ROWS` rows at a time (`prefilter_matrix`'s rows), times the
    probes' maps side by side in one product (an element of W·L is its row's dot product with its column,
    the same in a block, and beside other columns, as alone, to the rounding of that dot product: BLAS picks
    its kernel, and so the order of the additions, by the matrices' shapes)."""
    rads = [np.asarray(r, np.float64) for r in radiances]
    rads = [r.reshape(r.shape[0], -1) for r in rads]
    sources = {round(math.sqrt(r.shape[0] / 6)) for r in rads}
    if len(sources) > 1:
        raise ValueError(f"the probes' maps have different resolutions: {sorted(sources)}")
    source = sources.pop() if sources else 1
    q = cube_texels(target)["point"]
    chains: list[list[np.ndarray]] = [[] for _ in rads]
    if not rads:
        return []
    qn, wn, omega = _unit_texels(target), _unit_texels(source), _solid_angles(source)
    stacked = np.hstack(rads)
    columns = np.cumsum([0] + [r.shape[1] for r in rads])
    for alpha in level_roughness(levels):
        if lobe_within_texel(source, float(alpha)):
            for chain, rad in zip(chains, rads, strict=True):
                lookups = [np.asarray(cube_lookup(rad[:, c], q, numpy=True)) for c in range(rad.shape[1])]
                chain.append(np.stack(lookups, 1))
            continue
        level = np.empty((len(q), stacked.shape[1]))
        for start in range(0, len(q), PREFILTER_ROWS):
            block = slice(start, start + PREFILTER_ROWS)
            level[block] = _weight_rows(qn[block], wn, omega, float(alpha)) @ stacked
        for chain, a, b in zip(chains, columns[:-1], columns[1:], strict=True):
            chain.append(level[:, a:b])
    return [np.concatenate(chain, axis=0) for chain in chains]


def prefilter(radiance: np.ndarray, target: int = PREFILTER_RESOLUTION, levels: int = LEVELS) -> np.ndarray:
    """The chain of one probe: ``radiance`` (6N², C) → (levels·6·target², C), level after level
    (`prefilter_matrix`; a level narrower than a texel is the map's bilinear value at the texel centres)."""
    return prefilter_many([radiance], target, levels)[0]


def mip_level_kernel(ops, alpha, levels, p):
    """The level m = (levels − 1)·α^(p/2) ∈ [0, levels − 1] of a GGX roughness α: 0 for α ≤ 0 (a mirror
    reads level 0 exactly), α clamped to [10⁻⁶, 1] inside the power (module docstring)."""
    a = ops.clip(alpha, 1e-6, 1.0)
    m = ops.select(alpha > 0.0, (levels - 1.0) * ops.power(a, 0.5 * p), 0.0)
    return ops.clip(m, 0.0, levels - 1.0)


def chain_lookup_kernel(ops, table, dx, dy, dz, level, resolution, levels, probe):
    """Trilinear read of the chain of probe ``probe`` in ``table`` (probes × levels × 6N², stacked) at the
    fractional ``level``: bilinear in the two levels around it, linear between them."""
    size = 6.0 * resolution * resolution
    lo = ops.minimum(ops.floor(level), levels - 2.0) if levels > 1 else level * 0.0
    hi = ops.minimum(lo + 1.0, levels - 1.0)
    f = ops.clip(level - lo, 0.0, 1.0)
    start = probe * (levels * size)
    g0 = cube_lookup_kernel(ops, table, dx, dy, dz, resolution, True, start + lo * size)
    g1 = cube_lookup_kernel(ops, table, dx, dy, dz, resolution, True, start + hi * size)
    return g0 * (1.0 - f) + g1 * f


def _safe_inv(ops, r):
    return ops.select(ops.abs(r) > 1e-30, 1.0 / ops.select(ops.abs(r) > 1e-30, r, 1.0), _BIG)


def box_parallax_kernel(ops, x, y, z, rx, ry, rz, bx0, by0, bz0, bx1, by1, bz1):
    """Lagarde 2012's box-corrected lookup direction: x + t·R with t the exit distance of the box [b0, b1]
    (relative to the probe), or R where x is outside the box (t ≤ 0)."""
    ix, iy, iz = _safe_inv(ops, rx), _safe_inv(ops, ry), _safe_inv(ops, rz)
    tx = ops.maximum((bx1 - x) * ix, (bx0 - x) * ix)
    ty = ops.maximum((by1 - y) * iy, (by0 - y) * iy)
    tz = ops.maximum((bz1 - z) * iz, (bz0 - z) * iz)
    t = ops.minimum(ops.minimum(tx, ty), tz)
    ok = t > 0.0
    return (
        ops.select(ok, x + t * rx, rx),
        ops.select(ok, y + t * ry, ry),
        ops.select(ok, z + t * rz, rz),
    )


def sphere_parallax_kernel(ops, x, y, z, rx, ry, rz, radius):
    """Lagarde 2012's sphere-corrected lookup direction: x + t·R on the sphere of ``radius`` about the probe,
    or R where x is outside it (no exit point)."""
    b = x * rx + y * ry + z * rz
    disc = b * b - (x * x + y * y + z * z) + radius * radius
    t = -b + ops.sqrt(ops.maximum(disc, 0.0))
    ok = (disc >= 0.0) & (t > 0.0)
    return (
        ops.select(ok, x + t * rx, rx),
        ops.select(ok, y + t * ry, ry),
        ops.select(ok, z + t * rz, rz),
    )


@dataclass(frozen=True, eq=False)
class ProbeChains:
    """The tables of a case's probes, stacked probe after probe: ``pre`` (P·levels·6·N², 3) the chains
    (`prefilter`), ``irr`` (P·6·N_E², 3) the irradiance maps; N = ``resolution``, N_E = ``irr_resolution``.
    The tables are handed to each ops namespace once (a scene object: a fit reads it per scene only)."""

    pre: np.ndarray
    irr: np.ndarray
    resolution: int = PREFILTER_RESOLUTION
    irr_resolution: int = IRRADIANCE_RESOLUTION
    levels: int = LEVELS
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        pre = np.asarray(self.pre, np.float64).reshape(-1, 3)
        irr = np.asarray(self.irr, np.float64).reshape(-1, 3)
        size, irr_size = self.levels * 6 * self.resolution**2, 6 * self.irr_resolution**2
        if len(pre) % size or len(irr) % irr_size or len(pre) // size != len(irr) // irr_size or not len(pre):
            raise ValueError(
                f"ProbeChains: {len(pre)} chain texels and {len(irr)} irradiance texels are not whole probes "
                f"of {size} and {irr_size}"
            )
        object.__setattr__(self, "pre", pre)
        object.__setattr__(self, "irr", irr)

    @property
    def probes(self) -> int:
        """How many probes the tables hold."""
        return len(self.irr) // (6 * self.irr_resolution**2)

    def sample(self, ops, name: str, channel: int, like):
        """Channel ``channel`` of table ``name`` ("pre" or "irr") as the array kind ``ops`` runs on (the
        sampler protocol of `rtfit.realtime.arrays.evaluate`: the object reaches the kernel as it is)."""
        return cached_table(self._tables, ops, like, (name, channel), lambda: getattr(self, name)[:, channel])


def probe_specular_kernel(
    ops, x, y, z, rx, ry, rz, nx, ny, nz, wr_r, wr_g, wr_b, wd_r, wd_g, wd_b, alpha, probe,
    bx0, by0, bz0, bx1, by1, bz1, radius, chains, proxy, p,
):  # fmt: skip
    """(R, G, B) = w_r·G(m(α), d) + w_d·E(n)/π from probe ``probe``'s chain in ``chains`` (`ProbeChains`), d
    the row's lookup direction (``proxy``: "none" → R, "box", "sphere"; module docstring)."""
    if proxy == "box":
        d = box_parallax_kernel(ops, x, y, z, rx, ry, rz, bx0, by0, bz0, bx1, by1, bz1)
    elif proxy == "sphere":
        d = sphere_parallax_kernel(ops, x, y, z, rx, ry, rz, radius)
    else:
        d = (rx, ry, rz)
    n, ne, levels = chains.resolution, chains.irr_resolution, chains.levels
    level = mip_level_kernel(ops, alpha, float(levels), p)
    irr_start = probe * (6.0 * ne * ne)
    out = []
    for c, (wr, wd) in enumerate(((wr_r, wd_r), (wr_g, wd_g), (wr_b, wd_b))):
        g = chain_lookup_kernel(
            ops, chains.sample(ops, "pre", c, x), d[0], d[1], d[2], level, n, levels, probe
        )
        e = cube_lookup_kernel(ops, chains.sample(ops, "irr", c, x), nx, ny, nz, ne, True, irr_start)
        out.append(wr * g + wd * e * _INV_PI)
    return tuple(out)


def _vec(prefix: str, what: str, unit: str = "1", domain=(-1.0, 1.0)) -> tuple[Input, ...]:
    return tuple(Input(f"{prefix}{c}", unit, f"{what}, {c} component", domain) for c in "xyz")


def _rgb(prefix: str, what: str, unit: str, domain=None) -> tuple[Input, ...]:
    return tuple(Input(f"{prefix}_{c}", unit, f"{what}, {c} channel", domain) for c in "rgb")


INPUTS = (
    *_vec("", "shading point relative to its probe", "m", (-10.0, 10.0)),
    *_vec("r", "unit mirror direction about the shading normal"),
    *_vec("n", "unit shading normal, facing the camera"),
    *_rgb("wr", "glossy lobe's directional albedo (Fresnel and shadowing included)", "1", (0.0, 1.0)),
    *_rgb("wd", "diffuse albedo of the BSDF's diffuse base (0 on a conductor)", "1", (0.0, 1.0)),
    Input("alpha", "1", "the BSDF's GGX roughness α", (0.0, 1.0)),
    Input(
        "probe",
        "1",
        "index of the pixel's probe (nearest or assigned) in the stacked tables (a whole number)",
    ),
    *(
        Input(f"b{c}0", "m", f"proxy box's lower {c} bound, relative to the probe", (-20.0, -10.0))
        for c in "xyz"
    ),
    *(
        Input(f"b{c}1", "m", f"proxy box's upper {c} bound, relative to the probe", (10.0, 20.0))
        for c in "xyz"
    ),
    Input("radius", "m", "proxy sphere's radius about the probe", (10.0, 40.0)),
    Input(
        "chains",
        "W/m²/sr",
        "the probes' tables (`ProbeChains`): chains pre-convolved per roughness and irradiance maps (W/m²); "
        "read with `chain_lookup_kernel` on chains.sample(ops, 'pre', channel, like)",
    ),
)
"""The per-pixel inputs and tables of every row (quantity ``probe_specular_radiance``)."""
_P = Param(1.0, 0.2, 5.0, unit="1", description="roughness → mip exponent: m = (levels − 1)·α^(p/2)")
_QUANTITY = "probe_specular_radiance"
_LOOKUP = {"none": "R", "box": "box hit of x + t·R", "sphere": "sphere hit of x + t·R"}


def _row(mid: str, label: str, proxy: str, fitted: bool, source: str) -> Method:
    fixed: dict = {"proxy": proxy}
    if not fitted:
        fixed["p"] = 1.0
    return Method(
        mid,
        label,
        probe_specular_kernel,
        inputs=INPUTS,
        params={"p": _P} if fitted else {},
        fixed=fixed,
        quantity=_QUANTITY,
        formula=f"w_r·G(m(α), {_LOOKUP[proxy]}) + w_d·E(n)/π, m = (K − 1)·α^({'p' if fitted else '1'}/2)",
        source=source,
    )


_LAGARDE = "Lagarde & Zanuttini 2012, parallax-corrected cubemaps"
METHODS = method_table(
    [
        _row("nearest", "Nearest probe, pre-convolved per roughness (seed)", "none", False, "000:2459-2466"),
        _row("nearest-box", "Nearest probe, box parallax correction", "box", False, _LAGARDE + " (box)"),
        _row(
            "nearest-sphere",
            "Nearest probe, sphere parallax correction",
            "sphere",
            False,
            _LAGARDE + " (sphere)",
        ),
        _row(
            "mip-fit", "Nearest probe, fitted roughness → mip exponent", "none", True, "Karis 2013; p fitted"
        ),
        _row("box-mip-fit", "Box parallax + fitted mip exponent", "box", True, _LAGARDE + "; p fitted"),
    ]
)
"""The rows on a glossy shape (quantity ``probe_specular_radiance``, RGB)."""
