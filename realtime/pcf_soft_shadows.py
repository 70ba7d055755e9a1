r"""Percentage-closer filtering of a shadow map standing in for an area light's penumbra (pcf-soft-shadows).

What is approximated
--------------------
The direct irradiance of one light at a surface point x with the scene's occluders,
E_s(x) = ∫_light L V(x, ω) max(n·ω, 0) dω (W/m², per RGB channel). An engine splits it into the light's
unshadowed irradiance E (a closed form: `rtfit.realtime.diffuse` ``exact`` for a sphere light,
`rtfit.realtime.light_models` ``polygon`` for a rectangle) times a visibility V ∈ [0, 1] read from a **shadow
map**: a depth image rendered from the light's centre. Every row here is E · V_filter.

The shadow map (`ShadowMap`)
----------------------------
A W × H image of depths seen from the light's centre c (the audit casts one ray per texel centre with Dr.Jit,
experiments/audit_pcf_soft_shadows.py): perspective for a local light (axis a, half-angle θ; texel (i, j) at
uv = ((i + ½)/W, (j + ½)/H) looks along a + (2u − 1)·tanθ·e₁ + (2v − 1)·tanθ·e₂), orthographic along the
light's direction for a distant light (extent X scene units). Depth: the first hit's distance along the
map's axis, from the light's centre (perspective: view-space z, the linear depth an engine stores) or from
the map's plane (orthographic), scene units; a texel that sees nothing holds ``FAR``. A receiver x has map
coordinates (u, v) and depth z_r by the same projection (`project`). The seed's map is 1024², 16-bit (DF16);
here depths are float64 (float32 on the cost run) — the 16-bit quantisation is not modelled (an erratum of
scope, not of the formula: with a linear depth over the scene's range, DF16 steps are ≲ 2⁻¹⁶ of it, far
below the fitted biases).

The compare (one tap)
---------------------
lit(u, v) = 1 where z_r − b ≤ depth(texel), else 0, b ≥ 0 the depth bias (scene units). A filtered tap
weights the compares of the 2 × 2 texels around (u, v) bilinearly (what a comparison sampler returns:
``SampleCmp`` / the Fetch4 filtering of Isidoro 2006, which the seed cites): compare *then* filter (Reeves,
Salesin & Cook 1987, "Rendering antialiased shadows with depth maps"). Outside the map every texel is lit
(a border of ``FAR``).

Rows (the seed's and the modern ones)
-------------------------------------
* ``hard`` — one nearest-texel compare: the unfiltered shadow map (Williams 1978). Parameter b.
* ``poisson8`` — the seed's fixed 8-tap Poisson-disc PCF (000:586-594: "a fixed Poisson disk kernel" for dark
  or noisy surfaces): V = ⅛ Σ_k lit(uv + r·p_k/W), p_k the offsets `POISSON8` in the unit disc, r the kernel
  radius in texels. Parameters r, b.
* ``poisson8-rotated`` — the seed's form for bright surfaces: the same 8 taps rotated per pixel by an angle φ
  read from a lookup texture of random rotations (input ``rotation``: a tiled 32 × 32 noise texture of
  angles, one per screen pixel, as the seed's). Parameters r, b.
* ``poisson16-rotated`` — 16 taps (`POISSON16`), rotated: the taps quality knob. Parameters r, b.
* ``box3``, ``box5`` — an n × n grid of bilinear taps evenly spaced over [−r, r]² texels: the box PCF of every
  engine (n = 3, 5: the taps knob). Parameters r, b.
* ``pcss`` — percentage-closer soft shadows (Fernando 2005, "Percentage-closer soft shadows", SIGGRAPH
  sketch; NVIDIA's PCSS sample): (1) blocker search: 16 rotated Poisson taps (nearest texel) over the region
  the light's disc projects through from x onto the map, radius w_s = f(z_n); the mean depth z_b of the taps
  with depth < z_r − b; none → V = 1; (2) penumbra estimate w_p = s·f(z_b); (3) ``poisson16-rotated`` PCF with
  radius w_p. f(z) = ℓ·(z_r − z)/(z·z_r) in uv for a perspective map (ℓ = R/(2 tanθ): the light's radius R
  in uv at unit depth; by similar triangles, the light's disc seen from x through depth z), ℓ·(z_r − z)
  (ℓ = tan α/X) for an orthographic one; z_n the map's nearest depth (the near plane). Parameters s (the
  light-size scale, published value 1: the light's own size) and b.

None is exact: a filter of a single depth per texel cannot tell which part of the light a blocker hides.

Units and domains
-----------------
``irradiance`` E (W/m², ≥ 0), ``u``, ``v`` (map coordinates, [0, 1] inside the map), ``depth`` z_r (scene
units, > 0), ``rotation`` φ (rad), ``shadow_map`` (a `ShadowMap`), r (texels, ≥ 0), b (scene units, ≥ 0),
s (≥ 0). float32 rewrite: none needed; the compare is a difference of depths of the same size.

Guards (each with its reason; none changes a value inside the domain)
--------------------------------------------------------------------
* texel indices outside the map read ``FAR`` (a border: the light's frustum ends there, nothing occludes);
* PCSS: z ≥ `_Z_MIN` in f (z → 0 at the light's centre: f is infinite there); the blocker count ≥ 1 in the
  mean (none found: V = 1 by the select, the mean's value unused); the search and filter radii capped at
  `_MAX_RADIUS_UV` of the map (a blocker at the light's centre would ask for an unbounded region).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .arrays import NUMPY_OPS, cached_table, evaluate, same_bits
from .methods import Input, Method, Param, method_table

__all__ = [
    "FAR",
    "POISSON8",
    "POISSON16",
    "ShadowMap",
    "map_frame",
    "pcf_visibility",
    "poisson_disc",
    "project",
    "texel_directions",
]

FAR = 1e30
"""The depth of a texel that sees nothing (and of the border outside the map)."""
_Z_MIN = 1e-6  # PCSS: the smallest depth f(z) is evaluated at (Guards)
_MAX_RADIUS_UV = 0.25  # PCSS: the largest search / filter radius, a quarter of the map (Guards)


def poisson_disc(n: int, seed: int = 7, candidates: int = 64) -> tuple[tuple[float, float], ...]:
    """``n`` points in the unit disc by Mitchell's best-candidate algorithm (a Poisson-disc pattern: each new
    point the farthest of ``candidates`` uniform candidates from those placed), deterministic for ``seed``.
    The seed prints no offsets (000:586-594 names "an 8-tap Poisson disk kernel"), so these are ours."""
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    for _ in range(n):
        r = np.sqrt(rng.random(candidates))
        a = 2.0 * math.pi * rng.random(candidates)
        c = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
        if pts:
            d = np.min(np.linalg.norm(c[:, None, :] - np.array(pts)[None, :, :], axis=2), axis=1)
            c = c[int(np.argmax(d))]
        else:
            c = c[0]
        pts.append(c)
    return tuple((round(float(x), 4), round(float(y), 4)) for x, y in pts)


POISSON8 = poisson_disc(8)
"""The 8 offsets (unit disc) of the seed's Poisson kernel."""
POISSON16 = poisson_disc(16, seed=11)
"""16 offsets (unit disc): the rotated 16-tap row and PCSS's blocker search and filter."""


def _box(n: int) -> tuple[tuple[float, float], ...]:
    g = np.linspace(-1.0, 1.0, n)
    return tuple((float(x), float(y)) for y in g for x in g)


@dataclass(frozen=True, eq=False)
class ShadowMap:
    """A depth map from the light (module docstring): ``depth`` (H, W) (row j along v), ``ortho`` (an
    orthographic map of a distant light), ``light_size`` ℓ (PCSS: R/(2 tanθ), or tan α/X for ``ortho``) and
    ``near`` z_n (the nearest depth of the map); where it came from (for reports and tests, unused by the
    kernels): ``origin`` (the light's centre, or the orthographic map's centre), ``axis`` (unit) and ``size``
    (tanθ, or the orthographic width X). The depths are handed to each ops namespace once."""

    depth: np.ndarray
    ortho: bool = False
    light_size: float = 0.0
    near: float = 1.0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, -1.0)
    size: float = 1.0
    _tables: dict = field(default_factory=dict, repr=False, compare=False)
    _kept: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        d = np.asarray(self.depth, np.float64)
        if d.ndim != 2 or min(d.shape) < 1 or not np.all(d > 0):
            raise ValueError(f"ShadowMap: depth must be a 2-D array of positive depths (got shape {d.shape})")
        if not (self.light_size >= 0.0 and self.near > 0.0):
            raise ValueError(f"ShadowMap: light_size ≥ 0 and near > 0 (got {self.light_size}, {self.near})")
        object.__setattr__(self, "depth", d)

    @property
    def resolution(self) -> tuple[int, int]:
        """(W, H) texels."""
        return self.depth.shape[1], self.depth.shape[0]

    def _table(self, ops, like):
        # the depths row by row, then the border's (`FAR`)
        return cached_table(self._tables, ops, like, (), lambda: np.append(self.depth.reshape(-1), FAR))

    def texel(self, ops, i, j, like):
        """The depth of texel (i, j) (floats holding integers); ``FAR`` outside the map."""
        w, h = (float(x) for x in self.resolution)
        inside = (i >= 0.0) & (i <= w - 1.0) & (j >= 0.0) & (j <= h - 1.0)
        index = ops.select(inside, ops.clip(j, 0.0, h - 1.0) * w + ops.clip(i, 0.0, w - 1.0), w * h)
        return ops.gather(self._table(ops, like), index)

    def sample(self, ops, u, v):
        """The depth of the texel holding (u, v) (the sampler protocol of `rtfit.realtime.arrays.evaluate`:
        an object with ``sample`` is passed to a kernel as it is)."""
        return self.nearest(ops, u, v)

    def nearest(self, ops, u, v):
        """The depth of the texel holding (u, v)."""
        w, h = (float(x) for x in self.resolution)
        return self.texel(ops, ops.floor(u * w), ops.floor(v * h), u)

    def compare(self, ops, u, v, z):
        """The bilinear compare at (u, v): the 2 × 2 texels' (z ≤ depth), weighted bilinearly."""
        return self.weigh(ops, self.texels(ops, u, v), z)

    def texels(self, ops, u, v) -> tuple:
        """What the compare at (u, v) reads that does not depend on the receiver's depth: ``(depth, fx, fy)``,
        ``depth(di, dj)`` gathering (when called: the compare's order of operations) the depth of the texel
        di, dj ∈ {0, 1} past the 2 × 2 block's corner (``FAR`` outside the map), fx, fy the bilinear
        fractions."""
        w, h = (float(x) for x in self.resolution)
        table = self._table(ops, u)
        x, y = u * w - 0.5, v * h - 0.5
        x0, y0 = ops.floor(x), ops.floor(y)
        fx, fy = x - x0, y - y0
        border = w * h  # the index of the border texel (``FAR``)
        cols = [(x0 >= 0.0) & (x0 <= w - 1.0), (x0 >= -1.0) & (x0 <= w - 2.0)]  # x0 and x0 + 1 inside
        rows = [(y0 >= 0.0) & (y0 <= h - 1.0), (y0 >= -1.0) & (y0 <= h - 2.0)]
        base = y0 * w + x0

        def depth(di, dj):
            inside = cols[di] & rows[dj]
            return ops.gather(table, ops.select(inside, base + (dj * w + di), border))

        return depth, fx, fy

    def fetch(self, ops, u, v) -> tuple:
        """`texels` with the four depths gathered now (a form to keep)."""
        depth, fx, fy = self.texels(ops, u, v)
        gathered = (depth(0, 0), depth(1, 0), depth(0, 1), depth(1, 1))
        return (lambda di, dj: gathered[di + 2 * dj]), fx, fy

    @staticmethod
    def weigh(ops, texels: tuple, z):
        """The bilinear compare of a receiver at depth z from `texels` (or `fetch`)."""
        depth, fx, fy = texels

        def lit(di, dj):
            return ops.select(z <= depth(di, dj), 1.0, 0.0)

        top = lit(0, 0) * (1.0 - fx) + lit(1, 0) * fx
        bottom = lit(0, 1) * (1.0 - fx) + lit(1, 1) * fx
        return top * (1.0 - fy) + bottom * fy


_MEMO_FLOATS = 1 << 21
"""The most floats (16 MB) one entry of a map's bias-independent values (`_kept`) may hold (NumPy)."""
_MEMO_ENTRIES = 5
"""The most entries a map keeps (`_kept`, the least recently used dropped first): a TRF Jacobian evaluates
the kernel at r − h, r + h, then at r with b ± h, so the values at r must outlive two others (and the taps'
rotations, a small entry of their own)."""


def _kept(ops, sm: ShadowMap, key: tuple, arrays: tuple, make, size: int = 1, values: tuple = ()):
    """``make(True)`` (its values computed now), on the NumPy run kept in ``sm`` per ``key`` (plain numbers)
    for these very ``arrays`` (identity) and arrays of these very ``values`` (bit for bit), while ``size`` ×
    their length is at most `_MEMO_FLOATS`: a fit's 33-value scan of the bias b and its TRF steps in b
    evaluate the kernel again on the same receivers, and the taps' positions, texels' depths and bilinear
    weights do not depend on b (only the compare does). The same operations on the same arrays: the same
    values. Other runs (Dr.Jit, JAX, a shader; arrays too long) get ``make(False)``: the same values made as
    they are read (generators), so that a trace keeps the kernel's order of operations."""
    if (
        ops is not NUMPY_OPS
        or not all(isinstance(a, np.ndarray) and a.size * size <= _MEMO_FLOATS for a in (*arrays, *values))
        or not all(isinstance(k, str | int | float | tuple | bool) for k in key)
    ):
        return make(False)
    memo = sm._kept
    full = repr(key)  # exact numbers (−0.0 and 0.0 apart)
    hit = memo.pop(full, None)
    if (
        hit is None
        or not all(a is b for a, b in zip(hit[0], arrays, strict=True))
        or not all(same_bits(a, b) for a, b in zip(hit[1], values, strict=True))
    ):
        hit = (arrays, tuple(np.copy(a) for a in values), make(True))
        while len(memo) >= _MEMO_ENTRIES:
            memo.pop(next(iter(memo)))
    memo[full] = hit  # the most recently used last
    return hit[2]


# ===================================================================================== kernels (ops text)
def _rotated(ops, offsets, rotation, rotate: bool):
    """The offsets, each rotated by φ per pixel (``rotate``) or as they are."""
    if not rotate:
        return [(ox + 0.0 * rotation, oy + 0.0 * rotation) for ox, oy in offsets]
    c, s = ops.cos(rotation), ops.sin(rotation)
    return [(ox * c - oy * s, ox * s + oy * c) for ox, oy in offsets]


@dataclass(frozen=True)
class _AllTaps:
    """Every tap's values at once (the NumPy run's kept form, `_kept` ``eager``): ``values`` a (taps, N)
    array, or a `ShadowMap.fetch` of (taps, N) arrays. The kernels apply to it the operations they apply
    to one tap's (N,) values, elementwise the same, then add the taps' results row by row in the taps'
    order: the same values bit for bit, in a few NumPy operations instead of a few per tap."""

    values: Any


def _stacked(xs) -> np.ndarray:
    """Per-tap arrays (or numbers) as one (taps, N) array."""
    return np.stack(np.broadcast_arrays(*xs))


def _tap_texels(ops, sm: ShadowMap, u, v, taps, radius_uv_x, radius_uv_y, eager: bool):
    """`ShadowMap.texels` at each tap (uv offsets already rotated, scaled by the radius in uv): one
    `_AllTaps` of `ShadowMap.fetch` (``eager``, NumPy) or a generator."""
    if eager:
        ox, oy = _stacked([o for o, _ in taps]), _stacked([o for _, o in taps])
        return [_AllTaps(sm.fetch(ops, u + ox * radius_uv_x, v + oy * radius_uv_y))]
    return (sm.texels(ops, u + ox * radius_uv_x, v + oy * radius_uv_y) for ox, oy in taps)


def _mean_compare(ops, sm: ShadowMap, u, texels, z):
    """The mean over the taps' `texels` of the bilinear compare at depth z; ``u`` the receivers'. (On the
    map: a shader trace names the table its gathers read after the map's method that runs them.)"""
    acc, n = 0.0 * u, 0
    for t in texels:
        if isinstance(t, _AllTaps):  # NumPy: every tap's compare at once, added in the taps' order
            for lit in sm.weigh(ops, t.values, z):
                acc, n = acc + lit, n + 1
        else:
            acc, n = acc + sm.weigh(ops, t, z), n + 1
    return acc * (1.0 / n)


def _pcf_kernel(ops, irradiance, u, v, depth, rotation, shadow_map, radius, bias, offsets, rotate):
    """E · mean_k lit(uv + r·R_φ p_k / (W, H)) with the receiver at z_r − b."""
    w, h = (float(x) for x in shadow_map.resolution)

    def rotated(eager: bool):
        return _rotated(ops, offsets, rotation, rotate)

    taps = _kept(ops, shadow_map, ("taps", offsets, rotate), (rotation,), rotated, size=2 * len(offsets))
    z, radius_uv_x, radius_uv_y = depth - bias, radius / w, radius / h

    def texels(eager: bool):
        return _tap_texels(ops, shadow_map, u, v, taps, radius_uv_x, radius_uv_y, eager)

    key = ("pcf", offsets, rotate, radius)
    kept = _kept(ops, shadow_map, key, (u, v, rotation), texels, size=6 * len(offsets))
    return irradiance * _mean_compare(ops, shadow_map, u, kept, z)


def _hard_kernel(ops, irradiance, u, v, depth, shadow_map, bias):
    """E · (z_r − b ≤ depth of the nearest texel)."""
    z = depth - bias
    nearest = _kept(ops, shadow_map, ("hard",), (u, v), lambda eager: shadow_map.nearest(ops, u, v))
    return irradiance * ops.select(z <= nearest, 1.0, 0.0)


def _penumbra_uv(ops, sm: ShadowMap, z_receiver, z):
    """f(z): the light's disc seen from the receiver through depth z, as a radius in uv (module docstring)."""
    z = ops.maximum(z, _Z_MIN)
    if sm.ortho:
        f = sm.light_size * ops.maximum(z_receiver - z, 0.0)
    else:
        f = sm.light_size * ops.maximum(z_receiver - z, 0.0) / (z * ops.maximum(z_receiver, _Z_MIN))
    return ops.minimum(f, _MAX_RADIUS_UV)


def _pcss_kernel(ops, irradiance, u, v, depth, rotation, shadow_map, light_scale, bias):
    """Fernando 2005: blocker search over f(z_n), penumbra s·f(z_b), 16-tap rotated PCF of that radius."""
    sm = shadow_map
    z = depth - bias

    def searched(eager: bool):
        taps = _rotated(ops, POISSON16, rotation, True)
        search = _penumbra_uv(ops, sm, depth, 0.0 * depth + sm.near) * light_scale
        if eager:  # NumPy: every tap's nearest texel at once (`_AllTaps`)
            ox, oy = _stacked([o for o, _ in taps]), _stacked([o for _, o in taps])
            return taps, [_AllTaps(sm.nearest(ops, u + ox * search, v + oy * search))]
        return taps, (sm.nearest(ops, u + ox * search, v + oy * search) for ox, oy in taps)

    taps, found = _kept(ops, sm, ("pcss-search", light_scale), (u, v, depth, rotation), searched, size=48)
    total, count = 0.0 * u, 0.0 * u
    for d in found:
        if isinstance(d, _AllTaps):  # NumPy: every tap at once, added in the taps' order
            blocker = d.values < z
            for t, c in zip(ops.select(blocker, d.values, 0.0), ops.select(blocker, 1.0, 0.0), strict=True):
                total, count = total + t, count + c
            continue
        blocker = d < z
        total = total + ops.select(blocker, d, 0.0)
        count = count + ops.select(blocker, 1.0, 0.0)
    z_b = total / ops.maximum(count, 1.0)  # none found: unused (Guards)
    radius = _penumbra_uv(ops, sm, depth, z_b) * light_scale

    def texels(eager: bool):
        return _tap_texels(ops, sm, u, v, taps, radius, radius, eager)

    # the filter's taps move with the bias only through the radius: kept while it is the same, bit for bit
    kept = _kept(ops, sm, ("pcss-filter",), (u, v, rotation), texels, size=96, values=(radius,))
    vis = _mean_compare(ops, sm, u, kept, z)
    return irradiance * ops.select(count > 0.0, vis, 1.0)


# ===================================================================================== public functions
def project(origin, axis, tan_half, points, ortho_extent: float | None = None):
    """(u, v, depth) of ``points`` (N, 3) in the map of a light at ``origin`` looking along the unit ``axis``
    (perspective of half-angle atan(``tan_half``); or orthographic of width ``ortho_extent`` centred on
    ``origin``'s line, ``origin`` then on the map's plane); the map's frame e₁, e₂ is `map_frame`. Depth:
    (x − c)·a, along the axis, for both. Points behind a perspective light (depth ≤ 0) get coordinates as
    they fall (the caller masks them)."""
    p = np.asarray(points, np.float64) - np.asarray(origin, np.float64)
    a = np.asarray(axis, np.float64)
    e1, e2 = map_frame(a)
    za = p @ a
    if ortho_extent is not None:
        return 0.5 + (p @ e1) / ortho_extent, 0.5 + (p @ e2) / ortho_extent, za
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (p @ e1) / (za * tan_half)
        t = (p @ e2) / (za * tan_half)
    return 0.5 + 0.5 * s, 0.5 + 0.5 * t, za


def map_frame(axis) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors e₁, e₂ completing the unit ``axis`` to a right-handed frame (e₁ × e₂ = axis)."""
    a = np.asarray(axis, np.float64)
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def texel_directions(axis, tan_half: float, resolution: int) -> np.ndarray:
    """Unit directions (W·H, 3) through the texel centres of a square perspective map (row-major, j along
    v): the rays the audit casts from the light's centre."""
    e1, e2 = map_frame(axis)
    c = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    s, t = np.meshgrid(c * tan_half, c * tan_half)
    d = np.asarray(axis, np.float64)[None, :] + s.reshape(-1, 1) * e1 + t.reshape(-1, 1) * e2
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def pcf_visibility(method: str, u, v, depth, shadow_map: ShadowMap, rotation=0.0, **params):
    """V ∈ [0, 1] of row ``method`` (`METHODS`) at receivers (u, v, depth): the row at E = 1."""
    if method not in METHODS:
        raise ValueError(f"pcf_visibility: unknown method {method!r} (known: {', '.join(METHODS)})")
    m = METHODS[method]
    u = np.asarray(u, np.float64)
    inputs = {
        "irradiance": np.ones_like(u),
        "u": u,
        "v": np.asarray(v, np.float64) + 0.0 * u,
        "depth": np.asarray(depth, np.float64) + 0.0 * u,
        "rotation": np.asarray(rotation, np.float64) + 0.0 * u,
    }
    kw = m.keywords(params)
    names = [n for n in m.input_names if n != "shadow_map"]
    return evaluate(
        lambda ops, *xs: m.kernel(ops, **dict(zip(names, xs, strict=True)), shadow_map=shadow_map, **kw),
        *(inputs[n] for n in names),
    )


# ===================================================================================== methods as data
INPUTS = (
    Input(
        "irradiance", "W/m²", "E: the light's unshadowed irradiance at the point (closed form)", (0.0, 10.0)
    ),
    Input("u", "1", "the point's shadow-map coordinate along the map's first axis", (-0.1, 1.1)),
    Input("v", "1", "the point's shadow-map coordinate along the map's second axis", (-0.1, 1.1)),
    Input("depth", "m", "z_r: the point's depth from the light (the map's measure)", (0.01, 100.0)),
    Input(
        "rotation",
        "rad",
        "φ: the per-pixel rotation of the Poisson kernel (a tiled noise texture)",
        (0.0, 2.0 * math.pi),
    ),
    Input("shadow_map", "m", "the depth map from the light (`ShadowMap`: depth, ortho, light_size, near)"),
)
_IN = {i.name: i for i in INPUTS}
# Every parameter moves taps or the compare across texels of a nearest-texel depth test: the residuals are
# steps in it, their derivative 0 almost everywhere (on a real scene the fits left the bias, and on the plate
# the box filter's radius, at their starts), so each is scanned over 33 values before the solver
# (`Param.scan`: geometric over (10⁻³·upper, upper), 24 % apart).
_RADIUS = Param(1.5, 0.0, 64.0, unit="texels", published=False, scan=33,
                description="PCF kernel radius r (an artist's setting per light)")  # fmt: skip
_BIAS = Param(0.02, 0.0, 10.0, unit="m", published=False, scan=33,
              description="depth bias b: the receiver compared at z_r − b")  # fmt: skip
_SCALE = Param(
    1.0, 0.0, 20.0, unit="1", scan=33, description="PCSS light-size scale s (1: the light's own size)"
)
_SEED = "000:586-594 (ToyShop: 8-tap Poisson PCF, random rotation from a lookup texture, 1024² DF16 map)"


# Every row's fit evaluates the kernel text on float64 Dr.Jit (`Method.fit_ops` "drjit", issue 33): one
# compiled kernel replayed per scan value and TRF step. On the Cornell box at 64² the ten fits took 1.6 s
# instead of 2.9 s through NumPy (even with `_kept`'s texels); values moved ≤ 3e-11 relative (Dr.Jit's and
# NumPy's sin/cos of the rotation differ in the last bits), stderr ≤ 1e-8. `_kept` serves the NumPy runs.
def _pcf(mid, label, offsets, rotate, source, description):
    ins = tuple(_IN[n] for n in ("irradiance", "u", "v", "depth", "rotation", "shadow_map"))
    return Method(mid, label, _pcf_kernel, inputs=ins, params={"radius": _RADIUS, "bias": _BIAS},
                  fixed={"offsets": offsets, "rotate": rotate}, quantity="shadowed_light_irradiance",
                  fit_ops="drjit",
                  formula=f"E·(1/{len(offsets)}) Σ_k lit(uv + r·{'R_φ ' if rotate else ''}p_k/W; z_r − b)",
                  source=source, description=description)  # fmt: skip


METHODS = method_table(
    [
        Method(
            "hard",
            "Hard shadow map (1 tap)",
            _hard_kernel,
            inputs=tuple(_IN[n] for n in ("irradiance", "u", "v", "depth", "shadow_map")),
            params={"bias": _BIAS},
            quantity="shadowed_light_irradiance",
            fit_ops="drjit",
            formula="E·[z_r − b ≤ depth(nearest texel)]",
            source="Williams 1978, Casting curved shadows on curved surfaces",
            description="The unfiltered shadow map: a hard shadow of the light's centre.",
        ),
        _pcf(
            "poisson8",
            "Seed: 8-tap Poisson PCF, fixed",
            POISSON8,
            False,
            _SEED,
            "The seed's fixed Poisson disc (dark, noisy surfaces), bilinear compares.",
        ),
        _pcf(
            "poisson8-rotated",
            "Seed: 8-tap Poisson PCF, rotated",
            POISSON8,
            True,
            _SEED,
            "The seed's Poisson disc rotated per pixel by a noise texture (bright surfaces).",
        ),
        _pcf(
            "poisson16-rotated",
            "16-tap Poisson PCF, rotated",
            POISSON16,
            True,
            "Isidoro 2006, Shadow mapping: GPU-based tips and techniques (GDC): rotated Poisson PCF",
            "Twice the seed's taps: the taps quality knob.",
        ),
        _pcf(
            "box3",
            "Box PCF 3×3",
            _box(3),
            False,
            "Reeves, Salesin & Cook 1987 (percentage-closer filtering), n × n box of bilinear taps",
            "An even 3 × 3 grid of bilinear compares over [−r, r]² texels.",
        ),
        _pcf(
            "box5",
            "Box PCF 5×5",
            _box(5),
            False,
            "Reeves, Salesin & Cook 1987 (percentage-closer filtering), n × n box of bilinear taps",
            "An even 5 × 5 grid of bilinear compares over [−r, r]² texels.",
        ),
        Method(
            "pcss",
            "PCSS (blocker search + penumbra)",
            _pcss_kernel,
            inputs=tuple(_IN[n] for n in ("irradiance", "u", "v", "depth", "rotation", "shadow_map")),
            params={"light_scale": _SCALE, "bias": _BIAS},
            quantity="shadowed_light_irradiance",
            fit_ops="drjit",
            formula="E·PCF16(r = s·f(z_b)), z_b = mean blocker depth over f(z_n), f(z) = ℓ(z_r − z)/(z z_r)",
            source="Fernando 2005, Percentage-closer soft shadows (SIGGRAPH sketch; NVIDIA PCSS sample)",
            description="The modern row: the filter radius from the light's size and the blockers' depth.",
        ),
    ]
)
"""The family's rows (module docstring); ``fixed`` carries each PCF row's offsets and rotation switch."""
