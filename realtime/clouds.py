r"""Clouds: the sun's transmittance to the ground through a cloud, from a cloud-shadow texture (a 2-D density
plane) against a ray march through the 3-D cloud.

The seed (000:2322-2343, CryEngine 2, Wenzel 2006; 002:349-387, the GDC 2007 revision)
-------------------------------------------------------------------------------------
"Cloud shadows are cast in single full screen pass using the scene depth to recover world space position to
be able to transform into shadow map space" (000:2341; 002:360-362): each visible point x is projected along
the sun into a 2-D cloud texture and darkened by what it reads. The distance clouds of 002:364-381 are the
same texture as "2D planes above the camera" given volume by a nested march: "sample a 2D texture (cloud
density) along the view dir; for each sample point sample along the direction to sun", "use the accumulated
density to calc attenuation". The seed prints no formula (its figures 5 and 6 are lost): the forms below are
Beer–Lambert read onto those sentences, each stated as rtfit's reading.

The cloud (`CloudGrid`)
-----------------------
Extinction σ(p) (1/m) on an axis-aligned box [lo, hi] (m), held at the centres of nx × ny × nz voxels and
interpolated trilinearly, clamped to the outermost voxels inside the box and 0 outside it — Mitsuba's
``gridvolume`` (`rtfit.reference.grid_fit`: voxel centres at (i + ½)/n of the box, trilinear, clamp) so that
the 3-D march below converges to the transmittance of the very medium the reference tracks. The **density
plane** is the column optical depth D(x, y) = ∫ σ dz over the box (1, dimensionless): for the trilinear field
with clamped ends this integral is exactly Δz·Σ_k σ(i, j, k) per column (the half cells at both ends are
constant), a W × H texture at the grid's own xy resolution, bilinear between column centres, 0 outside the
box's footprint. An engine bakes this texture once per cloud layer.

Rows (`METHODS`, quantity ``cloud_transmittance``)
-------------------------------------------------
Inputs per ground point: its position p = (px, py, pz) (m), the unit direction towards the sun
s = (sx, sy, sz) (+z up; μ = s_z the sine of the sun's elevation) and the cloud (a `CloudGrid`).

* ``plane`` — **the seed's cloud-shadow texture**: x_p = p + t·s with t = (h − p_z)/μ (the sun ray meets the
  texture's plane at height h), T = exp(−k·D(x_p)/μ). For a cloud that is a thin layer at height h this is
  Beer–Lambert exactly with k = 1 (the slant path through a layer of vertical optical depth D is D/μ): k = 1
  and h = the cloud's density-weighted mean height are given, then fitted (k ∈ [0, 100], h within the box).
  ``plane-mip1``, ``plane-mip2``: the same at ½ and ¼ of the texture's resolution (the columns box-filtered
  2 × 2, 4 × 4: a mip chain), the seed form's memory knob (4 texel reads each).
* ``slab-N`` — **the 2-D plane with the nested march** (002:367-381): the texture extruded into a slab
  [h₀, h₁] of density k·D(x, y)/(h₁ − h₀), marched with N midpoint samples along the sun ray's stretch in
  the slab: T = exp(−Σᵢ k·D(xᵢ)/(h₁ − h₀)·Δt). Given: k = 1 and the box's bottom and top; then fitted.
  N = 4, 16: the seed's "adjust number of sample ... to fit into shader limits" knob.
* ``march-N`` — the 3-D cloud ray-marched: the sun ray's stretch [t₀, t₁] in the box (slab test) in N
  midpoint samples of the trilinear density, T = exp(−Σᵢ σ(p + tᵢ·s)·Δt), tᵢ = t₀ + (i + ½)·Δt,
  Δt = (t₁ − t₀)/N. N = 4, 8, 16, 64 (the quality knob; N·8 texel reads). It converges to the exact
  transmittance of the trilinear cloud as N → ∞ (midpoint rule: error O(Δt²) where the density is smooth);
  none of the rows is declared exact (finite N).

The cloud's radiance (`RADIANCE_METHODS`, quantity ``cloud_radiance``)
------------------------------------------------------------------
Inputs per pixel: the camera ray o + t·d (m; d unit), the direction s towards the sun, the sun's irradiance
E_sun (W/m², per channel), the medium's single-scattering albedo ϖ and Henyey–Greenstein g (1), the radiance
L_bg behind the cloud (W/m²/sr: the same pixel with the cloud removed) and the cloud. Both rows march the
view ray's stretch in the box with N midpoint samples xᵢ (σᵢ, Δt as in ``march-N``).

* ``gradient-N`` — **the seed's gradient-lit clouds** (000:2324, 002:353: "gradient-based lighting",
  "similar to [Wang03]"; Wang 2003/2004 shades each sprite with artist-set colours by its place in the cloud
  relative to the sun and by altitude, "artist-driven controls rather than a programmatic approach", the
  paper's abstract): the pixel's point x̄ = Σσᵢxᵢ/Σσᵢ (where its density — its sprites — lies), its
  normalised place along the sun u = ½ + (x̄ − c)·s/(2·Σₖ hₖ|sₖ|) ∈ [0, 1] (c, h: the box's centre and
  half-size; 1 on the sun's side), its height v = (x̄_z − lo_z)/(hi_z − lo_z), and
  L = E_sun·(a_shadow + (a_lit − a_shadow)·u)·(b + (1 − b)·v)·(1 − T_view) + T_view·L_bg,
  T_view = exp(−Σσᵢ·Δt). a_shadow, a_lit (1/sr) and b (1) are the artists' colours, fitted (bounded); the
  seed and Wang give no values, so both a start at 1/(4π) (the isotropic, unshadowed single-scattering limit
  of a thin white cloud, rtfit's choice) and b = 1 (no gradient). The exact lerp and
  gradient Wang's text uses was not retrievable (docs/clouds.md, "The radiance case"); this is rtfit's
  reading of "gradient-based" + "shadow/lit by the sun's side". No rim term (the next row adds it).
* ``gradient-N-rim`` — **the seed's back-light** (000:2324 "back lighting with respect to the sun was added
  to achieve the effect of glowing edges when looking at clouds partially covering the sun"; figure 5's
  caption 000:2327 "backlighting threshold (with respect to cloud alpha), and backlighting softness"; 002:356
  "Added rim lighting based on cloud density"). No formula is printed (the figure is lost; Wang's shading
  section was not retrievable): the form is **rtfit's reading of the caption**, every constant fitted:
  L = gradient-N + k·E_sun·(1 − S(α))·p_HG(s·d, g_r), α = 1 − T_view, S = smoothstep(t − w, t + w, α).
  1 − S, not S: the glowing *edges* are a cloud's thin, low-alpha parts (its core, α → 1, stays dark), so
  the glow is 1 below t − w, 0 above t + w, Hermite r²(3 − 2r) between ("softness"); the HG lobe (the one
  text `rtfit.realtime.phase.hg_phase_kernel`, cos = s·d as in ``single-N-M``) is "with respect to the sun".
  Domain: t ∈ [0, 1], w ∈ [0, ½] (w = 0: a hard threshold), g_r ∈ [−0.99, 0.99], k ∈ [0, 10] (1: radiance
  k·E_sun·p_HG at α = 0). None is published (`Param.published` False): t = ½, w = ¼, g_r = 0, k = 1 are
  only the fit's start. At α = 0 (a ray through the box that misses the density) it glows too: the caption
  puts no alpha factor on the glow. ``gradient-N-rim-blended``: the glow is part of the sprite's colour,
  blended by α as the gradient's colour is (+ k·E_sun·(1 − S)·p_HG·α: nothing glows where there is no
  cloud); docs/clouds.md measures both (the blended one fits the sun-behind view 1.8× better).
* ``single-N-M`` — single scattering of the sun, marched: L = Σᵢ Tᵢ·ϖσᵢ·p(s·d)·E_sun·T_sun(xᵢ)·Δt +
  T_view·L_bg, Tᵢ = exp(−Σ_{j<i}σⱼΔt − ½σᵢΔt), T_sun(xᵢ) the ``march-M`` row's text from xᵢ, p the
  Henyey–Greenstein phase of `rtfit.realtime.phase.hg_phase_kernel` (cos ϑ = s·d: light travelling −s
  scattered into −d). Exact for an optically thin cloud as N, M → ∞ (no multiple scattering); no parameter.

Units, domain, float32
----------------------
Positions in m (|p| ≲ 10⁴), σ in 1/m (≥ 0), D and τ dimensionless, T ∈ [0, 1]. No float32 rewrite is
needed: every step is a product of non-negative factors and T = exp(−τ) with τ ≥ 0 underflows to 0, never
to NaN. Guards, each with its reason (none changes a value inside the domain):

* μ ≤ `MU_MIN` (the sun at or below the horizon): ``plane`` and ``slab-N`` give T = 1 — the sun ray never
  climbs to the cloud layer, so no cloud lies on it (whether the ground still sees the sun is the horizon's
  question, not this quantity's); their divisions use max(μ, `MU_MIN`) so that 1/0 is never formed;
* a direction component |s_k| < `DIR_MIN` is replaced by ±`DIR_MIN` in the box's slab test (1/0 → ±inf,
  then 0·inf = NaN on a ray along a face); the replaced t-values are ±1e12·(distance) — outside any box;
* points above the plane (t < 0) read no texture (T = 1: the layer is behind them);
* the tables are clipped at `DENSITY_MAX` = 10³⁰ (1/m, and per column): a float32 inf in a table gives
  inf·0 = NaN in the interpolation's weights, and 10³⁰ /m is opaque over any length beyond 10⁻²⁸ m;
* the rim's smoothstep divides by max(2w, `RIM_WIDTH_MIN` = 10⁻⁷): w = 0 (the hard threshold, inside the
  domain) would form (α − t)/0 = ±inf, and 0/0 = NaN at α = t; floored, the ramp is ≤ 2 float32 ulps of α
  near 1 (2⁻²⁴ ≈ 6·10⁻⁸), i.e. the step itself at float32 resolution, and it changes nothing for w ≥ 5·10⁻⁸;
  the numerator stays within [−1.5, 2], so the quotient (≤ 2·10⁷) is finite and clipped to [0, 1]. α = 1 − T
  in float32 is 0 for τ < 6·10⁻⁸ (cancellation): the glow there is the α = 0 value, which it is to 10⁻⁷;
* the march sums σᵢ·Δt term by term (a ray that misses has Δt = 0: each term 0, never inf·0); k·D/μ ≤
  100·10³⁰/10⁻⁶ stays below float32's 3.4·10³⁸ per term; exp(−τ) is 0 beyond τ ≈ 104 (float32).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from .arrays import cached_table, check_range
from .methods import Input, Method, Param, method_table
from .phase import hg_phase_kernel

__all__ = [
    "DENSITY_MAX",
    "DIR_MIN",
    "MARCH_STEPS",
    "MU_MIN",
    "PLANE_LEVELS",
    "RADIANCE_METHODS",
    "RIM_WIDTH_MIN",
    "SINGLE_STEPS",
    "SLAB_STEPS",
    "CloudGrid",
    "cloud_transmittance",
]

MU_MIN = 1e-6
"""Smallest sine of the sun's elevation the plane rows divide by (module docstring, guards)."""
DENSITY_MAX = 1e30
"""Largest density (1/m) and column depth a table holds (module docstring, guards)."""
DIR_MIN = 1e-12
"""Smallest |direction component| of the slab test (module docstring, guards)."""
MARCH_STEPS = (4, 8, 16, 64)
"""The 3-D march's numbers of samples (the quality knob)."""
PLANE_LEVELS = (1, 2)
"""Mip levels of the texture rows (the texture's resolution halved L times: the seed form's knob)."""
SLAB_STEPS = (4, 16)
"""The nested march's samples through the extruded plane."""
SINGLE_STEPS = ((8, 4), (16, 8))
"""The single-scattering march's (view samples N, sun samples M)."""
GRADIENT_STEPS = (16,)
"""The gradient row's view samples (for T_view and the pixel's point x̄)."""
TAU_MIN = 1e-30
"""Smallest view optical depth x̄ divides by (an empty ray: x̄ is then the stretch's midpoint, unused)."""
RIM_WIDTH_MIN = 1e-7
"""Smallest smoothstep width 2w the rim divides by (module docstring, guards: w = 0 is the hard threshold)."""
_BATCH = 4  # samples per evaluated Dr.Jit kernel (`_midpoints`)


@dataclass(frozen=True)
class CloudGrid:
    """A cloud's extinction ``data`` (nz, ny, nx) in 1/m at voxel centres of the axis-aligned box [``lo``,
    ``hi``] (m; each (3,)), trilinear as Mitsuba's ``gridvolume`` (module docstring). Its tables are handed
    to each ops namespace once."""

    data: np.ndarray
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        d = np.asarray(self.data, np.float64)
        if d.ndim != 3 or min(d.shape) < 1 or not np.all(np.isfinite(d)) or np.any(d < 0.0):
            raise ValueError(
                f"CloudGrid: data must be a 3-D array of finite densities >= 0 (shape {d.shape})"
            )
        lo, hi = np.asarray(self.lo, np.float64), np.asarray(self.hi, np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
            raise ValueError(f"CloudGrid: the box needs hi > lo on every axis (got {self.lo}, {self.hi})")
        object.__setattr__(self, "data", d)
        object.__setattr__(self, "lo", tuple(float(x) for x in lo))
        object.__setattr__(self, "hi", tuple(float(x) for x in hi))

    @property
    def resolution(self) -> tuple[int, int, int]:
        """(nx, ny, nz) voxels."""
        nz, ny, nx = self.data.shape
        return nx, ny, nz

    def columns(self, level: int = 0) -> np.ndarray:
        """The density plane D: each column's vertical optical depth Δz·Σ_k σ (dimensionless), (ny, nx) at
        ``level`` 0; at level L the mean over blocks of 2^L × 2^L columns (`plane_resolution`; a block at
        the far edge of a size not divisible by 2^L holds the remainder), as a mip chain's box filter."""
        dz = (self.hi[2] - self.lo[2]) / self.data.shape[0]
        d = self.data.sum(axis=0) * dz
        for axis, n in ((0, self.plane_resolution(level)[1]), (1, self.plane_resolution(level)[0])):
            blocks = np.array_split(np.arange(d.shape[axis]), n)
            d = np.stack([np.take(d, b, axis=axis).mean(axis=axis) for b in blocks], axis=axis)
        return d

    def plane_resolution(self, level: int = 0) -> tuple[int, int]:
        """(W, H) texels of the density plane at mip ``level``: the grid's (nx, ny) halved L times (≥ 1)."""
        nx, ny, _nz = self.resolution
        return max(1, nx >> level), max(1, ny >> level)

    def mean_height(self) -> float:
        """The density-weighted mean height of the cloud (m; the box's centre for an empty grid)."""
        nz = self.data.shape[0]
        z = self.lo[2] + (np.arange(nz) + 0.5) / nz * (self.hi[2] - self.lo[2])
        w = self.data.sum(axis=(1, 2))
        return float(np.sum(w * z) / np.sum(w)) if np.sum(w) > 0 else 0.5 * (self.lo[2] + self.hi[2])

    def _table(self, ops, like, which: str, level: int = 0):
        def values():
            # clipped at `DENSITY_MAX`: a float32 inf in a table would give inf·0 = NaN in the interpolation
            return np.minimum(self.data if which == "grid" else self.columns(level), DENSITY_MAX)

        return cached_table(self._tables, ops, like, (which, level), values)

    def _axis(self, ops, x, k: int, n: int):
        """Texel coordinate along axis k: the two clamped neighbour indices, the weight, inside the box."""
        u = (x - self.lo[k]) / (self.hi[k] - self.lo[k]) * n - 0.5
        f0 = ops.floor(u)
        inside = (x >= self.lo[k]) & (x <= self.hi[k])
        return ops.clip(f0, 0.0, n - 1.0), ops.clip(f0 + 1.0, 0.0, n - 1.0), u - f0, inside

    def sample(self, ops, x, y, z):
        """σ at (x, y, z) (1/m): trilinear at voxel centres, clamped inside the box, 0 outside."""
        nx, ny, nz = self.resolution
        table = self._table(ops, x, "grid")
        i0, i1, fx, ix = self._axis(ops, x, 0, nx)
        j0, j1, fy, iy = self._axis(ops, y, 1, ny)
        k0, k1, fz, iz = self._axis(ops, z, 2, nz)

        def at(k, j, i):
            return ops.gather(table, (k * ny + j) * nx + i)

        def bilinear(k):
            top = at(k, j0, i0) * (1.0 - fx) + at(k, j0, i1) * fx
            bottom = at(k, j1, i0) * (1.0 - fx) + at(k, j1, i1) * fx
            return top * (1.0 - fy) + bottom * fy

        value = bilinear(k0) * (1.0 - fz) + bilinear(k1) * fz
        return ops.select(ix & iy & iz, value, 0.0 * value)

    def plane(self, ops, x, y, level: int = 0):
        """D at (x, y) (dimensionless): the density plane (mip ``level``), bilinear at texel centres, 0 off
        the box's footprint."""
        nx, ny = self.plane_resolution(level)
        table = self._table(ops, x, "plane", level)
        i0, i1, fx, ix = self._axis(ops, x, 0, nx)
        j0, j1, fy, iy = self._axis(ops, y, 1, ny)

        def at(j, i):
            return ops.gather(table, j * nx + i)

        top = at(j0, i0) * (1.0 - fx) + at(j0, i1) * fx
        bottom = at(j1, i0) * (1.0 - fx) + at(j1, i1) * fx
        value = top * (1.0 - fy) + bottom * fy
        return ops.select(ix & iy, value, 0.0 * value)


# ===================================================================================== kernels (ops text)
def _safe_dir(ops, s):
    """±max(|s|, `DIR_MIN`) (module docstring, guards)."""
    return ops.select(s < 0.0, ops.minimum(s, -DIR_MIN), ops.maximum(s, DIR_MIN))


def _box_stretch(ops, p, s, lo, hi):
    """[t₀, t₁] of the ray p + t·s (t ≥ 0) inside the box [lo, hi] (t₁ = t₀ where it misses)."""
    t_near, t_far = 0.0 * p[0], 0.0 * p[0] + 3.0e38
    for k in range(3):
        inv = 1.0 / _safe_dir(ops, s[k])
        a, b = (lo[k] - p[k]) * inv, (hi[k] - p[k]) * inv
        t_near = ops.maximum(t_near, ops.minimum(a, b))
        t_far = ops.minimum(t_far, ops.maximum(a, b))
    return t_near, ops.maximum(t_far, t_near)


def _midpoints(ops, t0, dt, steps, density):
    """Σᵢ density(t₀ + (i + ½)·Δt)·Δt, i < N, the midpoints reached by adding Δt (float32: N ≤ 64 additions,
    relative drift ≤ N·2⁻²⁴). On Dr.Jit the sum is evaluated every `_BATCH` samples: each batch is the same
    kernel (compiled once) instead of one graph of N·8 gathers (march-64 took 38 s to compile unrolled)."""
    device = ops.name == "drjit" and dr.is_array_v(t0)
    total = 0.0 * t0
    t = t0 + 0.5 * dt
    for i in range(int(steps)):
        total = total + density(t) * dt  # each term finite (0 where Δt = 0: a ray that misses)
        t = t + dt
        if device and (i + 1) % _BATCH == 0:
            dr.eval(total, t, dt)
    return total


def _march_kernel(ops, px, py, pz, sx, sy, sz, cloud, steps):
    """T = exp(−Σ σ(p + tᵢ·s)·Δt): N midpoint samples of the sun ray's stretch in the cloud's box."""
    t0, t1 = _box_stretch(ops, (px, py, pz), (sx, sy, sz), cloud.lo, cloud.hi)
    dt = (t1 - t0) * (1.0 / steps)
    tau = _midpoints(ops, t0, dt, steps, lambda t: cloud.sample(ops, px + t * sx, py + t * sy, pz + t * sz))
    return ops.exp(-tau)


def _plane_kernel(ops, px, py, pz, sx, sy, sz, cloud, k, h, level=0):
    """The seed's cloud-shadow texture: T = exp(−k·D(p + t·s)/μ), t = (h − p_z)/μ (D at mip ``level``)."""
    mu = ops.maximum(sz, MU_MIN)
    t = (h - pz) / mu
    d = cloud.plane(ops, px + t * sx, py + t * sy, int(level))
    lit = (sz > MU_MIN) & (t >= 0.0)
    return ops.select(lit, ops.exp(-k * d / mu), 1.0 + 0.0 * d)


def _slab_kernel(ops, px, py, pz, sx, sy, sz, cloud, k, h0, h1, steps):
    """The plane extruded into [h₀, h₁] with density k·D/(h₁ − h₀), marched with N midpoint samples."""
    mu = ops.maximum(sz, MU_MIN)
    bottom, top = ops.minimum(h0, h1), ops.maximum(h0, h1)
    thickness = ops.maximum(top - bottom, 1e-6)  # a collapsed slab: the plane row's limit, not 0/0
    ta = ops.maximum((bottom - pz) / mu, 0.0)
    tb = ops.maximum((top - pz) / mu, ta)
    dt = (tb - ta) * (1.0 / steps)
    tau = _midpoints(ops, ta, dt, steps, lambda t: k * cloud.plane(ops, px + t * sx, py + t * sy) / thickness)
    return ops.select(sz > MU_MIN, ops.exp(-tau), 1.0 + 0.0 * tau)


# ===================================================================================== radiance (ops text)
def _view_samples(ops, ox, oy, oz, dx, dy, dz, cloud, steps):
    """The view ray's N midpoints in the box: yields (tᵢ, σᵢ, Δt) lazily (the `_midpoints` order). On Dr.Jit
    the last tᵢ of each `_BATCH` is scheduled (``dr.schedule``), evaluated with the batch's sums that its
    consumer evaluates there, so that every batch's kernel starts from an evaluated t: a chain of additions
    carried through the batches made each batch a kernel of its own (issue 33, session 32)."""
    t0, t1 = _box_stretch(ops, (ox, oy, oz), (dx, dy, dz), cloud.lo, cloud.hi)
    dt = (t1 - t0) * (1.0 / steps)
    t = t0 + 0.5 * dt
    device = ops.name == "drjit" and dr.is_array_v(t)
    for i in range(int(steps)):
        if device and (i + 1) % _BATCH == 0:
            dr.schedule(t)
        yield t, cloud.sample(ops, ox + t * dx, oy + t * dy, oz + t * dz), dt
        t = t + dt


def _gradient_parts(ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, cloud, a_shadow, a_lit, b, steps):
    """The gradient row's colour (a_shadow + (a_lit − a_shadow)·u)·(b + (1 − b)·v) at the pixel's
    density-weighted point x̄, and T_view = exp(−Σσᵢ·Δt) (module docstring)."""
    device = ops.name == "drjit" and dr.is_array_v(ox)
    tau, wx, wy, wz = 0.0 * ox, 0.0 * ox, 0.0 * ox, 0.0 * ox
    for i, (t, sigma, dt) in enumerate(_view_samples(ops, ox, oy, oz, dx, dy, dz, cloud, steps)):
        w = sigma * dt
        tau, wx, wy, wz = tau + w, wx + w * (ox + t * dx), wy + w * (oy + t * dy), wz + w * (oz + t * dz)
        if device and (i + 1) % _BATCH == 0:
            dr.eval(tau, wx, wy, wz)
    full = tau > TAU_MIN  # an empty ray: x̄ is the stretch's midpoint (its weight 1 − T is 0 anyway)
    inv = 1.0 / ops.maximum(tau, TAU_MIN)
    t0, t1 = _box_stretch(ops, (ox, oy, oz), (dx, dy, dz), cloud.lo, cloud.hi)
    tm = 0.5 * (t0 + t1)
    xb = ops.select(full, wx * inv, ox + tm * dx)
    yb = ops.select(full, wy * inv, oy + tm * dy)
    zb = ops.select(full, wz * inv, oz + tm * dz)
    lo, hi = cloud.lo, cloud.hi
    reach, along = 0.0 * xb, 0.0 * xb
    for k, (q, v) in enumerate(((xb, sx), (yb, sy), (zb, sz))):
        reach = reach + 0.5 * (hi[k] - lo[k]) * ops.abs(v + 0.0 * q)
        along = along + (q - 0.5 * (lo[k] + hi[k])) * v
    u = ops.clip(0.5 + along / (2.0 * ops.maximum(reach, 1e-12)), 0.0, 1.0)  # |s| = 1: reach > 0; the
    # floor only stops 0/0 for a zero s (outside the domain)
    v = ops.clip((zb - lo[2]) / (hi[2] - lo[2]), 0.0, 1.0)
    return (a_shadow + (a_lit - a_shadow) * u) * (b + (1.0 - b) * v), ops.exp(-tau)


def _gradient_kernel(ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, e_sun, albedo, g, l_bg, cloud, a_shadow, a_lit,
                     b, steps):  # fmt: skip
    """The seed's gradient-lit cloud (module docstring): L = E·lerp(a_shadow, a_lit, u)·lerp(b, 1, v)·(1 − T)
    + T·L_bg at the pixel's density-weighted point x̄."""
    colour, t_view = _gradient_parts(
        ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, cloud, a_shadow, a_lit, b, steps
    )
    return e_sun * colour * (1.0 - t_view) + t_view * l_bg


def _rim_kernel(ops, alpha, cos_sd, threshold, softness, g_rim):
    """The back-light's glow per unit k·E_sun (1/sr): (1 − smoothstep(t − w, t + w, α))·p_HG(cos, g_rim),
    smoothstep(e₀, e₁, x) = r²(3 − 2r), r = clip((x − e₀)/max(e₁ − e₀, `RIM_WIDTH_MIN`), 0, 1)."""
    r = ops.clip((alpha - (threshold - softness)) / ops.maximum(2.0 * softness, RIM_WIDTH_MIN), 0.0, 1.0)
    return (1.0 - r * r * (3.0 - 2.0 * r)) * hg_phase_kernel(ops, cos_sd, g_rim)


def _gradient_rim_kernel(ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, e_sun, albedo, g, l_bg, cloud, a_shadow,
                         a_lit, b, threshold, softness, g_rim, k_rim, steps, blended):  # fmt: skip
    """The gradient row plus the seed's back-light (module docstring): + k·E·rim(α, s·d; t, w, g_rim), times α
    where ``blended`` (the glow is part of the sprite's colour, blended by its alpha as the gradient's is)."""
    colour, t_view = _gradient_parts(
        ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, cloud, a_shadow, a_lit, b, steps
    )
    alpha = 1.0 - t_view
    rim = _rim_kernel(ops, alpha, dx * sx + dy * sy + dz * sz, threshold, softness, g_rim)
    return e_sun * colour * alpha + t_view * l_bg + k_rim * e_sun * rim * (alpha if blended else 1.0)


def _single_kernel(ops, ox, oy, oz, dx, dy, dz, sx, sy, sz, e_sun, albedo, g, l_bg, cloud, steps, sun_steps):
    """Single scattering of the sun along the view ray: Σ Tᵢ·ϖσᵢ·p(s·d)·E·T_sun(xᵢ)·Δt + T·L_bg."""
    device = ops.name == "drjit" and dr.is_array_v(ox)
    phase = hg_phase_kernel(ops, dx * sx + dy * sy + dz * sz, g)
    tau, total = 0.0 * ox, 0.0 * ox
    for i, (t, sigma, dt) in enumerate(_view_samples(ops, ox, oy, oz, dx, dy, dz, cloud, steps)):
        w = sigma * dt
        t_sun = _march_kernel(ops, ox + t * dx, oy + t * dy, oz + t * dz, sx, sy, sz, cloud, sun_steps)
        total = total + ops.exp(-(tau + 0.5 * w)) * w * t_sun  # each term finite: w = 0 on a miss
        tau = tau + w
        if device and (i + 1) % _BATCH == 0:
            dr.eval(tau, total)
    t_view = ops.exp(-tau)
    return albedo * phase * e_sun * total + t_view * l_bg


# ===================================================================================== methods (data)
INPUTS = (
    Input("px", "m", "ground point x", (-100.0, 100.0)),
    Input("py", "m", "ground point y", (-100.0, 100.0)),
    Input("pz", "m", "ground point z (height, +z up)", (-10.0, 10.0)),
    Input("sx", "1", "unit direction to the sun, x", (-1.0, 1.0)),
    Input("sy", "1", "unit direction to the sun, y", (-1.0, 1.0)),
    Input("sz", "1", "unit direction to the sun, z: μ, the sine of its elevation", (-1.0, 1.0)),
    Input("cloud", "1/m", "the cloud's extinction grid (`CloudGrid`: g.cloud.sample(ops, x, y, z), "
          "g.cloud.plane(ops, x, y) its column optical depth)"),
)  # fmt: skip
_K = Param(1.0, 0.0, 100.0, unit="1", description="density scale k (1: Beer–Lambert through a thin layer)")
_H = Param(
    0.0, -1e4, 1e4, unit="m", description="the texture plane's height h (given: the cloud's mean height)"
)
_H0 = Param(0.0, -1e4, 1e4, unit="m", description="the slab's bottom h₀ (given: the box's bottom)")
_H1 = Param(1.0, -1e4, 1e4, unit="m", description="the slab's top h₁ (given: the box's top)")
_SEED = "seed 000:2322-2343, 002:349-387 (no formula printed: Beer–Lambert on the texture, rtfit's reading)"

METHODS = method_table(
    [
        Method(
            id="plane",
            label="seed: cloud-shadow texture (2-D density plane, one tap)",
            kernel=_plane_kernel,
            inputs=INPUTS,
            params={"k": _K, "h": _H},
            quantity="cloud_transmittance",
            formula="T = exp(−k·D(p + t·s)/μ), t = (h − p_z)/μ, D = ∫σ dz (the density plane)",
            source=_SEED,
        ),
        *(
            Method(
                id=f"plane-mip{level}",
                label=f"the seed's texture at 1/{1 << level} resolution",
                kernel=_plane_kernel,
                inputs=INPUTS,
                params={"k": _K, "h": _H},
                fixed={"level": level},
                quantity="cloud_transmittance",
                formula=f"T = exp(−k·D_{level}(p + t·s)/μ), D_{level}: the density plane box-filtered "
                f"{1 << level}×{1 << level}",
                source=_SEED,
            )
            for level in PLANE_LEVELS
        ),
        *(
            Method(
                id=f"slab-{n}",
                label=f"2-D plane extruded to a slab, nested march of {n}",
                kernel=_slab_kernel,
                inputs=INPUTS,
                params={"k": _K, "h0": _H0, "h1": _H1},
                fixed={"steps": n},
                quantity="cloud_transmittance",
                formula=f"T = exp(−Σ k·D(xᵢ)/(h₁ − h₀)·Δt), {n} midpoints of the sun ray in [h₀, h₁]",
                source="seed 002:364-381 (distance clouds: 2-D density, samples toward the sun)",
            )
            for n in SLAB_STEPS
        ),
        *(
            Method(
                id=f"march-{n}",
                label=f"3-D ray march, {n} samples",
                kernel=_march_kernel,
                inputs=INPUTS,
                fixed={"steps": n},
                quantity="cloud_transmittance",
                formula=f"T = exp(−Σ σ(p + tᵢ·s)·Δt), {n} midpoints of the sun ray in the cloud's box",
                source="Beer–Lambert, midpoint rule (the ray march every volumetric-cloud engine runs)",
            )
            for n in MARCH_STEPS
        ),
    ]
)
"""The family's rows on ``cloud_transmittance`` (module docstring)."""


RADIANCE_INPUTS = (
    Input("ox", "m", "camera ray origin x", (-100.0, 100.0)),
    Input("oy", "m", "camera ray origin y", (-100.0, 100.0)),
    Input("oz", "m", "camera ray origin z", (-100.0, 100.0)),
    Input("dx", "1", "unit view direction x (camera to scene)", (-1.0, 1.0)),
    Input("dy", "1", "unit view direction y", (-1.0, 1.0)),
    Input("dz", "1", "unit view direction z", (-1.0, 1.0)),
    *INPUTS[3:6],
    Input("e_sun", "W/m²", "the sun's irradiance at normal incidence, per channel", (0.0, 100.0)),
    Input("albedo", "1", "the medium's single-scattering albedo ϖ, per channel", (0.0, 1.0)),
    Input("g", "1", "the medium's Henyey–Greenstein asymmetry", (-0.99, 0.99)),
    Input("l_bg", "W/m²/sr", "radiance behind the cloud (the pixel with the cloud removed)", (0.0, 100.0)),
    INPUTS[6],
)  # fmt: skip
_A = Param(1.0 / (4.0 * math.pi), 0.0, 10.0, unit="1/sr", description="")
_GRADIENT_PARAMS = {
    "a_shadow": dataclasses.replace(_A, description="the shadow side's colour a_shadow (per irradiance)"),
    "a_lit": dataclasses.replace(_A, description="the sun side's colour a_lit (per irradiance)"),
    "b": Param(1.0, 0.0, 2.0, unit="1", description="the cloud base's brightness b (the top's is 1)"),
}
_RIM_PARAMS = {  # no source gives a value (figure 5 is lost): published=False, each start is only the fit's
    "threshold": Param(0.5, 0.0, 1.0, unit="1", published=False,
                       description="the back-light's threshold t on the alpha 1 − T (below it: glow)"),
    "softness": Param(0.25, 0.0, 0.5, unit="1", published=False,
                      description="the back-light's softness w (smoothstep over [t − w, t + w] of alpha)"),
    "g_rim": Param(0.0, -0.99, 0.99, unit="1", published=False,
                   description="the back-light's Henyey–Greenstein g (its closeness to the sun)"),
    "k_rim": Param(1.0, 0.0, 10.0, unit="1", published=False,
                   description="the back-light's strength k (radiance k·E_sun·p_HG at alpha 0)"),
}  # fmt: skip

RADIANCE_METHODS = method_table(
    [
        *(
            Method(
                id=f"gradient-{n}",
                label="seed: gradient-lit cloud (Wang 2003's sun-side and altitude colours), no rim term",
                kernel=_gradient_kernel,
                inputs=RADIANCE_INPUTS,
                params=_GRADIENT_PARAMS,
                fixed={"steps": n},
                quantity="cloud_radiance",
                formula="L = E·(a_s + (a_l − a_s)·u)·(b + (1 − b)·v)·(1 − T) + T·L_bg; u: x̄'s place along "
                "the sun in the box, v: its height, x̄ = Σσᵢxᵢ/Σσᵢ, T = exp(−Σσᵢ·Δt)",
                source='seed 000:2324-2327, 002:353-356 ("gradient-based lighting", after Wang 2003, JGT '
                "9(3) 2004: artists' colours; their lerp is rtfit's reading, the rim term not built)",
            )
            for n in GRADIENT_STEPS
        ),
        *(
            Method(
                id=f"gradient-{n}-rim{'-blended' if blended else ''}",
                label="seed: gradient-lit cloud + back-light (glowing edges; rtfit's reading of a caption)"
                + (", the glow blended by the sprite's alpha" if blended else ""),
                kernel=_gradient_rim_kernel,
                inputs=RADIANCE_INPUTS,
                params={**_GRADIENT_PARAMS, **_RIM_PARAMS},
                fixed={"steps": n, "blended": blended},
                quantity="cloud_radiance",
                formula="L = gradient-N + k·E·(1 − smoothstep(t − w, t + w, α))·p_HG(s·d, g_r)"
                + ("·α" if blended else "")
                + ", α = 1 − T",
                source='seed 000:2324-2327 ("back lighting with respect to the sun ... glowing edges"; '
                "figure 5's caption: a threshold and a softness w.r.t. cloud alpha), 002:356 (rim lighting "
                "based on cloud density); no formula printed: rtfit's reading, every constant fitted",
            )
            for n in GRADIENT_STEPS
            for blended in (False, True)
        ),
        *(
            Method(
                id=f"single-{n}-{m}",
                label=f"single scattering of the sun, {n} view × {m} sun samples (HG phase)",
                kernel=_single_kernel,
                inputs=RADIANCE_INPUTS,
                fixed={"steps": n, "sun_steps": m},
                quantity="cloud_radiance",
                formula="L = Σ Tᵢ·ϖσᵢ·p_HG(s·d)·E·T_sun(xᵢ)·Δt + T·L_bg, T_sun: march-M from xᵢ",
                source="the single-scattering integral (radiative transfer, first order), midpoint rule",
            )
            for n, m in SINGLE_STEPS
        ),
    ]
)
"""The family's rows on ``cloud_radiance`` (module docstring)."""


# ===================================================================================== public API
def cloud_transmittance(point, sun, cloud: CloudGrid, method: str = "march-64", **params):
    """The sun's transmittance T ∈ [0, 1] to ground ``point`` (…, 3) m through ``cloud`` (a `CloudGrid`)
    along the unit direction ``sun`` (3,) towards the sun, by ``method`` (an id of `METHODS`; its free
    parameters as keywords, else their defaults)."""
    if method not in METHODS:
        raise ValueError(f"cloud_transmittance: unknown method {method!r} (known: {', '.join(METHODS)})")
    if not isinstance(cloud, CloudGrid):
        raise ValueError("cloud_transmittance: cloud must be a CloudGrid")
    s = np.asarray(sun, np.float64).reshape(3)
    if not abs(float(np.linalg.norm(s)) - 1.0) < 1e-6:
        raise ValueError(f"cloud_transmittance: sun must be a unit vector (|s| = {np.linalg.norm(s):.6g})")
    p = np.asarray(point, np.float64)
    check_range("point", p, -1e6, 1e6, interval="[-1e6, 1e6] m")
    m = METHODS[method]
    inputs = {"px": p[..., 0], "py": p[..., 1], "pz": p[..., 2], "cloud": cloud}
    inputs.update({f"s{a}": float(s[k]) for k, a in enumerate("xyz")})
    return m.evaluate(inputs, {k: float(v) for k, v in params.items()})
