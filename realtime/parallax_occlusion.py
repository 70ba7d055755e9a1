"""Parallax occlusion mapping (POM) with approximate soft self-shadowing (Tatarchuk, 000:1372-2148,
appendix listings 1-2 at 000:1723-2147; slides 003:116-205): the seed's listing and a stable variant,
each written once against the ops namespace (`rtfit.realtime.arrays`).

Frame and units (tangent space, texture units = metres of the tile):

* The reference polygon is the plane z = 0; texture coordinates are (u, v) = (x, y).
* A height field h(u, v) ∈ [0, 1] (1 = the reference plane, the peaks; 0 = the deepest valley — the
  listing's convention, see the erratum on 000:1456 in docs/parallax-occlusion.md) describes the surface
  z = −s·(1 − h(u, v)), with s the *height-map range* (``scale``, texture units per unit height).
* ``(vx, vy, vz)``: unit vector from the shaded point towards the eye; ``(lx, ly, lz)``: unit vector
  towards the light; both in tangent space (z along the geometric normal).

The view ray through the pixel's (u₀, v₀) reaches depth 1 − t (height t) at texture offset
P·(1 − t) with P = s·(vx, vy)/vz (the *parallax offset vector*, listing 1). The linear search samples
h at n points t_i = 1 − i/n, i = 1..n, n = n_max + vz·(n_min − n_max) truncated (more samples at grazing
view), stops at the first sample under the surface (h_i > t_i) and intersects the view line with the
segment between the last two samples (the piecewise-linear profile): the hit is at height
t* = (t₁·δ₂ − t₂·δ₁)/(δ₂ − δ₁), δ_k = t_k − h_k, and the displaced texture coordinate is
uv₀ − P·(1 − t*).

Soft shadow (listing 2, 000:2084-2117): from the displaced point with height h₀, seven samples along the
light's offset at fractions f = 0.88, 0.77, …, 0.22 with weights w = 1, 2, 4, 6, 8, 10, 12:
sh_f = (h(uv + f·R) − h₀ − f)·w_f·k (k the softening factor), visibility 1 − max_f sh_f, remapped
0.6·x + 0.4 (``floor`` = 0.4). The listing's light offset is R = s·(lx, ly): not divided by lz.

Methods (`METHODS`, one kernel text `pom_kernel`, variant chosen by the ``fixed`` keyword ``stable``):

* ``listing`` — as printed, hazards included: the 0/0 of normalize((vx, vy)) at normal incidence, 0/0 in
  the intersection when no crossing is found, R not divided by lz, P unclamped (vz → 0: infinite), the
  first segment's upper height assumed 1 instead of sampled, the visibility not clamped before the remap
  (over-bright lit areas), and the LOD transition that lerps the coordinate but switches the shadow off
  at once (and uses the fractional part, so mip = threshold exactly gets full POM).
* ``stable`` — the same search with P = s·(vx, vy)/max(vz, ``min_cos``) (no normalize), t_i = 1 − i/n
  by multiplication, the first segment from the sampled h(uv₀), "no crossing" resolved as the floor
  (t* = 0), R = s·(lx, ly)/max(lz, ``min_cos``), the visibility clamped to [0, 1] before the remap, and
  one LOD weight w = clip(mip − (T − 1), 0, 1) that fades both the coordinate and the shadow.

Height fields (`POM_HEIGHT_FIELDS`, selected by the ``field`` keyword) are procedural kernel texts, so the
Mitsuba reference (`rtfit.reference.parallax_occlusion`) displaces its mesh with the same text. ``field`` may
also be a `HeightMap`: a sampled texture (a user's bump map, `rtfit audit`), looked up bilinearly (or nearest)
with ``ops.gather`` the way Mitsuba's ``bitmap`` texture is: texel centres at ((i + ½)/W, (j + ½)/H), row j
along v, no flip, wrap ``repeat``, ``clamp`` or ``mirror``.

`DEPTH_METHODS`: the march alone, returning the visible point's depth 1 − t* (a fraction of the height
range s) — what `rtfit audit` compares with the displaced mesh's first hit.

`SHADOW_AUDIT_METHODS` (quantity ``parallax_shadow``): the soft shadow alone, as the fraction of an area
light's irradiance the height field lets through — the pixel shader's (the march to the visible (u, v), then
the 7-sample shadow there: `pom_pixel_shadow_kernel`, `pom_kernel`'s third output at mip 0), the shadow
model isolated from the march (`SHADOW_METHODS` at the exact visible point), and POM without the shadow query
(1) — what `rtfit audit` compares with Mitsuba's area-light visibility from the displaced mesh.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .arrays import cached_table, evaluate
from .methods import Input, Method, Param, method_table

__all__ = [
    "DEPTH_METHODS",
    "DEPTH_SAMPLE_RANGES",
    "POM_HEIGHT_FIELDS",
    "POM_SHADOW_FRACTIONS",
    "POM_SHADOW_WEIGHTS",
    "SHADOW_AUDIT_METHODS",
    "HeightMap",
    "pom_depth_kernel",
    "pom_height",
    "pom_kernel",
    "pom_march_kernel",
    "pom_normal_kernel",
    "pom_pixel_shadow_kernel",
    "pom_sample_count",
    "pom_shadow_kernel",
    "pom_unshadowed_kernel",
]

TWO_PI = 2.0 * math.pi


# ------------------------------------------------------------------------------------------ height fields
def _plane(ops, u, v):
    """h = 0.5 everywhere (a flat surface at depth s/2: the exact hit is closed-form)."""
    return u * 0.0 + v * 0.0 + 0.5


def _floor(ops, u, v):
    """h = 0 everywhere: the surface lies on the search's floor (depth s), where the listing's linear
    search finds no sample strictly below the surface."""
    return u * 0.0 + v * 0.0


def _ramp(ops, u, v):
    """h = 0.5 + 0.25·u (a linear ramp along u; tests use |u| ≤ 2 so h stays in [0, 1])."""
    return 0.5 + 0.25 * u + v * 0.0


def _bumps(ops, u, v):
    """Egg crate of period 1: h = 0.5 + 0.5·sin(2πu)·sin(2πv) ∈ [0, 1] (touches 0 and 1)."""
    return 0.5 + 0.5 * ops.sin(TWO_PI * u) * ops.sin(TWO_PI * v)


def _ridges(ops, u, v):
    """Narrow smooth crests along v, period 1/2: h = ((1 + cos 4πu)/2)⁴ ∈ [0, 1] (crests of half-width
    ≈ 0.07, wide flat valleys near h = 0: a brick/groove-like profile that is hard for the linear search)."""
    c = 0.5 + 0.5 * ops.cos(2.0 * TWO_PI * u) + v * 0.0
    c2 = c * c
    return c2 * c2


POM_HEIGHT_FIELDS: dict[str, Callable] = {
    "plane": _plane,
    "floor": _floor,
    "ramp": _ramp,
    "bumps": _bumps,
    "ridges": _ridges,
}
"""Procedural height fields h(u, v) ∈ [0, 1] by name (kernel texts against the ops namespace)."""


WRAP_MODES = ("repeat", "clamp", "mirror")
"""Texture addressing of a `HeightMap` (Mitsuba's ``bitmap`` ``wrap_mode`` values)."""


@dataclass(frozen=True, eq=False)
class HeightMap:
    """A sampled height field: ``texels`` (H, W) ∈ [0, 1] (row j along v), ``wrap`` (`WRAP_MODES`) and
    ``nearest`` (nearest-texel lookup instead of bilinear). Called as a height field, ``h(ops, u, v)``: the
    texture lookup of Mitsuba's ``bitmap`` (module docstring) written against the ops namespace; the texels
    are handed to each namespace once, as its array kind (a Dr.Jit array of the coordinates' own type)."""

    texels: np.ndarray
    wrap: str = "repeat"
    nearest: bool = False
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        t = np.asarray(self.texels, np.float64)
        if t.ndim != 2 or min(t.shape) < 1:
            raise ValueError(f"HeightMap: texels must be a 2-D array (got shape {t.shape})")
        if self.wrap not in WRAP_MODES:
            raise ValueError(f"HeightMap: wrap {self.wrap!r} is not one of {', '.join(WRAP_MODES)}")
        object.__setattr__(self, "texels", t)

    @property
    def shape(self) -> tuple[int, int]:
        return self.texels.shape  # type: ignore[return-value]

    def _table(self, ops, like):
        return cached_table(self._tables, ops, like, (), lambda: self.texels)

    def _wrapped(self, ops, i, n: float):
        if self.wrap == "clamp":
            return ops.clip(i, 0.0, n - 1.0)
        if self.wrap == "repeat":
            return i - n * ops.floor(i / n)
        m = i - 2.0 * n * ops.floor(i / (2.0 * n))
        return ops.select(m >= n, 2.0 * n - 1.0 - m, m)

    def __call__(self, ops, u, v):
        h, w = (float(x) for x in self.shape)
        table = self._table(ops, u)
        if self.nearest:
            i = self._wrapped(ops, ops.floor(u * w), w)
            j = self._wrapped(ops, ops.floor(v * h), h)
            return ops.gather(table, j * w + i)
        x, y = u * w - 0.5, v * h - 0.5
        x0, y0 = ops.floor(x), ops.floor(y)
        fx, fy = x - x0, y - y0
        i0, i1 = self._wrapped(ops, x0, w), self._wrapped(ops, x0 + 1.0, w)
        j0, j1 = self._wrapped(ops, y0, h) * w, self._wrapped(ops, y0 + 1.0, h) * w
        t00, t10 = ops.gather(table, j0 + i0), ops.gather(table, j0 + i1)
        t01, t11 = ops.gather(table, j1 + i0), ops.gather(table, j1 + i1)
        return (t00 * (1.0 - fx) + t10 * fx) * (1.0 - fy) + (t01 * (1.0 - fx) + t11 * fx) * fy


def _height_field(field) -> Callable:
    """The kernel text of ``field``: a name of `POM_HEIGHT_FIELDS`, or a `HeightMap` (itself callable)."""
    return POM_HEIGHT_FIELDS[field] if isinstance(field, str) else field


def pom_height(field, u, v):
    """h(u, v) of the named height field, or of a `HeightMap` (dispatching like every public function of the
    package)."""
    f = _height_field(field)
    return evaluate(lambda ops, a, b: f(ops, a, b), u, v)


def pom_normal_kernel(ops, u, v, *, scale, field, eps=1e-3):
    """Unit normal of the surface z = −s·(1 − h): (−s·∂h/∂u, −s·∂h/∂v, 1)/‖·‖ with central differences of
    step ``eps`` (texture units; what a normal map baked from the height map holds). Returns (nx, ny, nz)."""
    hf = _height_field(field)
    k = -scale / (2.0 * eps)
    gx = (hf(ops, u + eps, v) - hf(ops, u - eps, v)) * k
    gy = (hf(ops, u, v + eps) - hf(ops, u, v - eps)) * k
    inv = 1.0 / ops.sqrt(gx * gx + gy * gy + 1.0)
    return gx * inv, gy * inv, inv


# ----------------------------------------------------------------------------------------------- kernels
POM_SHADOW_FRACTIONS = (0.88, 0.77, 0.66, 0.55, 0.44, 0.33, 0.22)
"""Fractions of the light offset at which the listing samples the height field (000:2090-2111)."""
POM_SHADOW_WEIGHTS = (1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
"""The listing's weight of each sample (closer samples → larger blocker-to-receiver ratio)."""


def pom_sample_count(ops, vz, n_min: float, n_max: float, stable: bool):
    """n = trunc(lerp(n_max, n_min, N·V)) (000:1979; the listing's form, not equation (1) at 000:1529,
    which has n_min and n_max swapped). The stable form clamps N·V to [0, 1] first (a back-facing
    interpolated view vector would otherwise ask for more than n_max samples)."""
    c = ops.clip(vz, 0.0, 1.0) if stable else vz
    return ops.floor(n_max + c * (n_min - n_max))


def pom_march_kernel(ops, u0, v0, vx, vy, vz, *, scale, n_min, n_max, field, stable, min_cos):
    """The linear search and piecewise-linear intersection: displaced (u, v) and the hit height t*.

    ``n_max`` (a Python int) bounds the unrolled loop; lanes stop after their own n samples or at their
    first sample below the surface. Returns (u, v, t*)."""
    hf = _height_field(field)
    if stable:
        inv = 1.0 / ops.maximum(vz, min_cos)
        px, py = scale * vx * inv, scale * vy * inv
    else:  # normalize(V.xy) · sqrt(|V|² − V_z²)/V_z · s (listing 1): 0/0 at normal incidence
        lxy = ops.sqrt(vx * vx + vy * vy)
        length = ops.sqrt(vx * vx + vy * vy + vz * vz)
        plen = ops.sqrt(length * length - vz * vz) / vz
        px, py = vx / lxy * plen * scale, vy / lxy * plen * scale
    n = pom_sample_count(ops, vz, n_min, n_max, stable)
    step = 1.0 / n
    h_prev = hf(ops, u0, v0) if stable else u0 * 0.0 + 1.0
    found = h_prev > 2.0  # all false, of the lanes' mask type
    t1 = h_prev * 0.0
    h1 = t1
    t2 = t1
    h2 = t1
    bound = t1 + 1.0
    cu, cv = u0, v0
    for i in range(1, int(n_max) + 1):
        if stable:
            frac = i * step
            bound = 1.0 - frac
            cu, cv = u0 - px * frac, v0 - py * frac
        else:  # running sums in the shader's precision (000:2024-2030)
            cu, cv = cu - px * step, cv - py * step
            bound = bound - step
        h = hf(ops, cu, cv)
        active = (n >= i) & (found == False)  # noqa: E712 (an array comparison, not a Python bool test)
        hit = active & (h > bound)
        t1 = ops.select(hit, bound, t1)
        h1 = ops.select(hit, h, h1)
        t2 = ops.select(hit, bound + step, t2)
        h2 = ops.select(hit, h_prev, h2)
        found = found | hit
        h_prev = ops.select(active & (hit == False), h, h_prev)  # noqa: E712
    d2 = t2 - h2
    d1 = t1 - h1
    if stable:
        den = ops.select(found, d2 - d1, 1.0)
        t_hit = ops.select(found, (t1 * d2 - t2 * d1) / den, 0.0)
    else:  # no crossing: pt1 = pt2 = 0 → 0/0 (000:2050-2053)
        t_hit = (t1 * d2 - t2 * d1) / (d2 - d1)
    return u0 - px * (1.0 - t_hit), v0 - py * (1.0 - t_hit), t_hit


def pom_shadow_kernel(ops, u, v, lx, ly, lz, *, scale, softening, floor, field, stable, min_cos):
    """Soft self-shadow factor at the displaced (u, v) (000:2084-2117): see the module docstring.

    ``floor``: the remap x·(1 − floor) + floor (0.4 in the listing). The stable form divides the light
    offset by max(lz, ``min_cos``) and clamps 1 − max sh to [0, 1] before the remap."""
    hf = _height_field(field)
    if stable:
        inv = scale / ops.maximum(lz, min_cos)
        rx, ry = lx * inv, ly * inv
    else:
        rx, ry = lx * scale, ly * scale
    h0 = hf(ops, u, v)
    samples = [
        (hf(ops, u + rx * f, v + ry * f) - h0 - f) * (w * softening)
        for f, w in zip(POM_SHADOW_FRACTIONS, POM_SHADOW_WEIGHTS, strict=True)
    ]
    worst = samples[0]
    for sh in samples[1:]:
        worst = ops.maximum(worst, sh)
    vis = 1.0 - worst
    if stable:
        vis = ops.clip(vis, 0.0, 1.0)
    return vis * (1.0 - floor) + floor


def pom_depth_kernel(ops, u0, v0, vx, vy, vz, *, scale, n_min, n_max, field, stable, min_cos):
    """The depth below the reference surface of the visible point the march finds, 1 − t*, as a fraction
    of the height range s (0: on the reference surface, 1: the deepest valley h = 0); the visible point is
    s·(1 − t*) deep on the view ray (`pom_march_kernel`)."""
    _, _, t_hit = pom_march_kernel(
        ops, u0, v0, vx, vy, vz, scale=scale, n_min=n_min, n_max=n_max, field=field, stable=stable,
        min_cos=min_cos,
    )  # fmt: skip
    return 1.0 - t_hit


def pom_pixel_shadow_kernel(
    ops, u0, v0, vx, vy, vz, lx, ly, lz, *, scale, softening, floor, n_min, n_max, field, stable, min_cos,
):  # fmt: skip
    """The pixel shader's soft self-shadow at full POM (mip 0): the march (`pom_march_kernel`) to the visible
    (u, v), then the 7-sample shadow there (`pom_shadow_kernel`) — `pom_kernel`'s third output at mip 0, the
    fraction of the light the shader lets through."""
    u, v, _ = pom_march_kernel(
        ops, u0, v0, vx, vy, vz, scale=scale, n_min=n_min, n_max=n_max, field=field, stable=stable,
        min_cos=min_cos,
    )  # fmt: skip
    return pom_shadow_kernel(
        ops, u, v, lx, ly, lz, scale=scale, softening=softening, floor=floor, field=field, stable=stable,
        min_cos=min_cos,
    )  # fmt: skip


def pom_unshadowed_kernel(ops, u0, *, scale, field):
    """POM without the shadow query: the whole light let through (1) at every pixel — the baseline a shadow
    row improves on. ``scale`` and ``field`` are the case's, as every row's, and unused."""
    return u0 * 0.0 + 1.0


def pom_kernel(
    ops, u0, v0, vx, vy, vz, lx, ly, lz, mip, *, scale, softening, floor, n_min, n_max, lod_threshold,
    field, stable, min_cos,
):  # fmt: skip
    """One pixel of the listing's pixel shader (000:1920-2147) without its Phong shading: the LOD test,
    the march, the soft shadow, the LOD blend. Returns (u, v, shadow factor).

    ``mip``: the pixel's mip level (000:1955, ≥ 0). Listing: full POM and shadow where mip ≤ T; where also
    mip > T − 1 the coordinate is lerped towards (u₀, v₀) by frac(mip) while the shadow stays at full
    strength; beyond T: (u₀, v₀) and no shadow (a jump at mip = T). Stable: w = clip(mip − (T − 1), 0, 1)
    lerps both the coordinate and the shadow (towards 1)."""
    u, v, _ = pom_march_kernel(
        ops, u0, v0, vx, vy, vz, scale=scale, n_min=n_min, n_max=n_max, field=field, stable=stable,
        min_cos=min_cos,
    )  # fmt: skip
    sh = pom_shadow_kernel(
        ops, u, v, lx, ly, lz, scale=scale, softening=softening, floor=floor, field=field, stable=stable,
        min_cos=min_cos,
    )  # fmt: skip
    t = lod_threshold
    if stable:
        w = ops.clip(mip - (t - 1.0), 0.0, 1.0)
        return u + (u0 - u) * w, v + (v0 - v) * w, sh + (1.0 - sh) * w
    pom = mip <= t
    blend = pom & (mip > t - 1.0)
    frac = mip - ops.floor(mip)  # modf's fractional part (mip ≥ 0)
    w = ops.select(blend, frac, 0.0)
    u_b, v_b = u + (u0 - u) * w, v + (v0 - v) * w
    return ops.select(pom, u_b, u0), ops.select(pom, v_b, v0), ops.select(pom, sh, 1.0)


# ----------------------------------------------------------------------------------------------- methods
_VIEW = (
    Input("u0", "texture units", "the pixel's interpolated texture coordinate u"),
    Input("v0", "texture units", "the pixel's interpolated texture coordinate v"),
    Input("vx", "1", "unit view vector (to the eye), tangent space x", (-1.0, 1.0)),
    Input("vy", "1", "unit view vector, tangent space y", (-1.0, 1.0)),
    Input("vz", "1", "unit view vector, tangent space z = N·V", (0.0, 1.0)),
)
_LIGHT = (
    Input("lx", "1", "unit light vector (to the light), tangent space x", (-1.0, 1.0)),
    Input("ly", "1", "unit light vector, tangent space y", (-1.0, 1.0)),
    Input("lz", "1", "unit light vector, tangent space z = N·L", (0.0, 1.0)),
)
_MIP = (Input("mip", "mip levels", "the pixel's mip level of the height map (000:1955)", (0.0, 16.0)),)
SHADOW_PARAMS = {
    "softening": Param(0.5, 0.01, 10.0, unit="1", description="fShadowSoftening k (000:2091)"),
    "floor": Param(0.4, 0.0, 1.0, unit="1", description="the remap x·(1 − floor) + floor (000:2117)"),
}
"""The shadow's free parameters. The seed prints no value for the softening factor; 0.5 is rtfit's
default (the experiment fits it); the floor 0.4 is the listing's remap."""

_DEFAULT_FIXED = {"scale": 0.1, "n_min": 8, "n_max": 40, "lod_threshold": 4.0, "field": "bumps",
                  "min_cos": 0.05}  # fmt: skip
"""Scene settings carried by each method as ``fixed`` keywords; experiments replace them per case
(``dataclasses.replace(m, fixed={...})``). n 8..40: the ToyShop sampling range (000:1595)."""

METHODS = method_table(
    [
        Method(
            "listing",
            "POM as printed (listing 2)",
            pom_kernel,
            inputs=(*_VIEW, *_LIGHT, *_MIP),
            params=SHADOW_PARAMS,
            fixed={**_DEFAULT_FIXED, "stable": False},
            quantity="displaced (u, v) and shadow factor",
            formula="linear search t_i = 1 − i/n, piecewise-linear hit, 7-sample soft shadow ·0.6 + 0.4",
            source="000:1723-2147",
        ),
        Method(
            "stable",
            "POM, stable variant",
            pom_kernel,
            inputs=(*_VIEW, *_LIGHT, *_MIP),
            params=SHADOW_PARAMS,
            fixed={**_DEFAULT_FIXED, "stable": True},
            quantity="displaced (u, v) and shadow factor",
            formula="as listed with P = s·V_xy/max(V_z, c), R = s·L_xy/max(L_z, c), clamped shadow, "
            "floor fallback, continuous LOD",
            source="000:1723-2147 (fixed)",
        ),
    ]
)
"""The two variants of the pixel kernel (`pom_kernel`)."""

SHADOW_METHODS = method_table(
    [
        Method(
            f"{m.id}-shadow",
            f"{m.label}: soft shadow",
            pom_shadow_kernel,
            inputs=(
                Input("u", "texture units", "texture coordinate u of the shaded (visible) point"),
                Input("v", "texture units", "texture coordinate v of the shaded (visible) point"),
                *_LIGHT,
            ),
            params=SHADOW_PARAMS,
            fixed={k: m.fixed[k] for k in ("scale", "field", "stable", "min_cos")},
            quantity="parallax_shadow",
            formula="(1 − max_f (h(uv + f·R) − h₀ − f)·w_f·k)·(1 − floor) + floor",
            source="000:2084-2117",
        )
        for m in METHODS.values()
    ]
)
"""The shadow factor alone at a given (u, v): in `rtfit audit` the exact visible point's (the shadow model
isolated from the march)."""

DEPTH_FORMULAS = {
    "listing": "1 − t*: linear search t_i = 1 − i/n, P = s·normalize(V_xy)·|V_xy|/V_z, piecewise-linear hit",
    "stable": "1 − t*: the same search, P = s·V_xy/max(V_z, c), floor fallback (t* = 0) when nothing is hit",
}

DEPTH_SAMPLE_RANGES = ((4, 16), (16, 64))
"""Further (n_min, n_max) of the stable march in `DEPTH_METHODS` beside the declared (8, 40)."""

DEPTH_METHODS = method_table(
    [
        *(
            Method(
                f"pom-{m.id}",
                f"{m.label}: visible depth",
                pom_depth_kernel,
                inputs=_VIEW,
                fixed={k: m.fixed[k] for k in ("scale", "n_min", "n_max", "field", "stable", "min_cos")},
                quantity="parallax_depth",
                formula=DEPTH_FORMULAS[m.id],
                source="000:1723-2064" + (" (fixed)" if m.fixed["stable"] else ""),
            )
            for m in METHODS.values()
        ),
        *(
            Method(
                f"pom-stable-n{lo}-{hi}",
                f"{METHODS['stable'].label}, n {lo}…{hi}: visible depth",
                pom_depth_kernel,
                inputs=_VIEW,
                fixed={
                    **{k: METHODS["stable"].fixed[k] for k in ("scale", "field", "stable", "min_cos")},
                    "n_min": lo,
                    "n_max": hi,
                },
                quantity="parallax_depth",
                formula=DEPTH_FORMULAS["stable"],
                source="000:1723-2064 (fixed)",
            )
            for lo, hi in DEPTH_SAMPLE_RANGES
        ),
    ]
)
"""The march of each variant alone (`pom_depth_kernel`; ``pom-<id>`` of `METHODS`' ``<id>``: a bare
``stable`` is volumetric lightning's in ``--approx``), and the stable march at the sample ranges
`DEPTH_SAMPLE_RANGES` (``pom-stable-n<lo>-<hi>``): the visible point's depth, a fraction of the height range
(what `rtfit audit` compares with the displaced mesh's first hit)."""

SHADOW_AUDIT_METHODS = method_table(
    [
        *(
            Method(
                f"pom-{m.id}-shadow",
                f"{m.label}: soft shadow at the marched point",
                pom_pixel_shadow_kernel,
                inputs=(*_VIEW, *_LIGHT),
                params=SHADOW_PARAMS,
                fixed={k: m.fixed[k] for k in ("scale", "n_min", "n_max", "field", "stable", "min_cos")},
                quantity="parallax_shadow",
                formula="the march (n 8…40) to (u, v), then "
                + SHADOW_METHODS[f"{m.id}-shadow"].formula
                + (" with R = s·L_xy/max(L_z, c), clamped" if m.fixed["stable"] else " with R = s·L_xy"),
                source="000:1723-2117" + (" (fixed)" if m.fixed["stable"] else ""),
            )
            for m in METHODS.values()
        ),
        *SHADOW_METHODS.values(),
        Method(
            "pom-no-shadow",
            "POM without the shadow query",
            pom_unshadowed_kernel,
            inputs=(_VIEW[0],),
            fixed={"scale": _DEFAULT_FIXED["scale"], "field": _DEFAULT_FIXED["field"]},
            quantity="parallax_shadow",
            formula="1 (the whole light let through)",
            source="000:2084-2117 (the query left out)",
        ),
    ]
)
"""The soft shadow as `rtfit audit` compares it with the area-light visibility from the displaced mesh
(quantity ``parallax_shadow``): the pixel shader's (``pom-listing-shadow``, ``pom-stable-shadow``: march then
shadow, mip 0), the shadow model alone at the exact visible point (``listing-shadow``, ``stable-shadow``:
`SHADOW_METHODS`, reading (u, v)) and the unshadowed baseline (``pom-no-shadow``)."""
