r"""Soft particles: a particle's opacity where opaque scene geometry cuts through its volume.

The approximations (seed 000:2302-2318, Wenzel 2006; 002:325-347, GDC 2007; 001:1608 names spherical
billboards)
----------------------------------------------------------------------------------------------------
A particle is drawn as a camera-facing billboard at the view depth z of its centre (view space: camera at
the origin looking along +z; z in metres). Its texture holds α, the opacity of the particle seen along the
view axis at that texel. The depth buffer gives the scene's view depth z_s behind the pixel, and
Δ = z_s − z (m). Every method returns the particle pixel's opacity α' ∈ [0, 1]; r is the particle's radius
(half-size of a box), s the fade distance in units of r.

* ``linear`` (000:2302-2318 as engines implement it): α' = α·saturate(Δ/(s·r)). The seed's text measures
  the ray's travel through a camera-aligned volume; the common shader measures Δ from the billboard.
* ``box`` (002:325-347, the 2007 "camera aligned volume box"): the view-z travel ℓ_z through the box's
  depth range [z − r, z + r], clipped by the scene depth and by the camera plane z = 0, over the box's
  depth 2r: α' = α·ℓ_z/(2r), ℓ_z = max(min(z + r, z_s) − max(z − r, 0), 0).
* ``box-beer`` (rtfit): the same travel through Beer–Lambert: α' = 1 − (1 − α)^(ℓ_z/(2r)) — what the
  linear scaling approximates; exact for a ray along the view axis.
* ``spherical`` (Umenhoffer, Szirmay-Kalos & Szijártó, "Spherical billboards and their application to
  rendering explosions", GI 2006): the particle is a sphere of radius r; at the billboard point a lateral
  distance q from the centre the sphere spans the view depths [z − w, z + w], w = √(r² − q²), and the
  visible chord (view z) is ℓ = max(min(z + w, z_s) − max(z − w, 0), 0). The formula used here converts
  it with Beer–Lambert at the particle's density: σ = −ln(1 − α_c)/(2r) from the centre opacity α_c, so
  α' = 1 − (1 − α_c)^(ℓ/(2r)). (Their paper writes α = 1 − exp(−τΔs) for the density τ and the
  travelled distance Δs; this is that formula with τ from α_c.)
* ``box-beer-ray``, ``spherical-ray`` (rtfit): the same with the view-z length converted to ray length,
  ℓ/cos θ, cos θ = d̂_z of the pixel's view ray (the shader has it from the view vector): removes the
  cos θ loss below.
* ``fitted`` (rtfit): α' = α·saturate(Δ/(s·r) + b)^p: the linear fade with an offset b (b = ½, s = 2 is
  the box's on-axis fraction) and an exponent p < 1 that bends the linear ramp towards the concave
  Beer–Lambert curve 1 − (1 − α)^f.

The exact opacity (``exact-sphere``, ``exact-box``)
--------------------------------------------------
A homogeneous particle of extinction σ (1/m) seen along the unit ray x(t) = t·d̂ from the camera, with
the opaque surface at ray distance t_s: T = exp(−σℓ), opacity 1 − T = −expm1(−σℓ), where ℓ is the
length of the ray inside the volume before the surface.

* Sphere (centre c, radius r): b = d̂·c, h² = |c × d̂|² (the squared distance of the centre from the ray,
  a sum of squares: no cancellation), w = √max(r² − h², 0); relative to b the chord is
  [max(−w, −b), min(w, t_s − b)], ℓ = max(min(w, t_s − b) − max(−w, −b), 0) (the camera plane clips the
  front: camera inside the particle).
* Camera-aligned box (centre c, half-size r, faces normal to the view axes): slab intersection,
  t_near = max_k min(t_k⁻, t_k⁺), t_far = min_k max(t_k⁻, t_k⁺), t_k^± = (c_k ± r)/d_k (a ray parallel to a
  slab is inside it for all t when |c_k| ≤ r, else misses), ℓ = max(min(t_far, t_s) − max(t_near, 0), 0).

The particle's α_c is the opacity of its full chord through the centre: α_c = 1 − exp(−2σr). The issue's
claim "α = 0.95, Δ/s = 0.5: 0.48 against 0.78" is the fraction f = ℓ/ℓ_full = ½ of the chord (the surface
through the centre): linear α·f = 0.475, Beer–Lambert 1 − (1 − α)^f = 1 − √0.05 = 0.776. Since
g(f) = 1 − (1 − α)^f is concave in f with g(0) = 0 and g(1) = α, g(f) ≥ α·f for f ∈ [0, 1]: every
linear fade of a texture α that equals the full chord's opacity under-estimates the clipped opacity, by at
most max_f (g(f) − α·f), which grows with α (0.319 at α = 0.95, at f = 0.383; `linear_underestimate`).

Ray length vs view z
--------------------
The depth buffer and all billboard methods measure depth along the view axis; Beer–Lambert needs the
length along the ray. For a ray at angle θ from the view axis through the box's z-range, ℓ_ray = ℓ_z/cos θ,
so the optical depth of every view-z method is short by the factor cos θ (0.87 at 30° off-axis).

Numerics
--------
α, α_c are clamped to [0, 1 − 2⁻²⁴] (float32's largest value below 1; the optical depth of the full chord
stays ≤ 16.7) so that ln(1 − α) is finite; 1 − (1 − α)^f is −expm1(f·log1p(−α)). σ is clamped to
[0, 1e30] /m; σℓ → +∞ gives opacity 1, ℓ = 0 gives 0 (no 0·∞). s·r is floored at 1e-30 m (s → 0: a hard
step at Δ = 0, never 0/0). Every method maps Δ ≤ 0 (surface in front of the billboard) to the right limit
(0 for the fades; the visible part of the volume for the chords). No NaN or Inf for finite inputs.

Methods as data (`METHODS`); each kernel is one text over the ops namespace (Dr.Jit, NumPy, JAX).
"""

from __future__ import annotations

import math

from .arrays import check_range, evaluate
from .methods import Input, Method, Param, method_table

__all__ = [
    "ALPHA_MAX",
    "beer_fraction",
    "billboard_alpha",
    "box_chord",
    "linear_underestimate",
    "soft_particle_opacity",
    "sphere_chord",
]

ALPHA_MAX = 1.0 - 2.0**-24
"""Largest opacity used in ln(1 − α): float32's largest value below 1."""
SIGMA_MAX = 1e30
"""Largest extinction (1/m) the exact kernels use (σ·ℓ stays finite in float32 for ℓ ≤ 1e8 m)."""
BIG = 1e30
"""A distance beyond every scene (m): a ray parallel to a slab, a surface at infinity."""
_S_MIN = 1e-30


# ===================================================================================== kernels (ops text)
def _saturate(ops, x):
    return ops.minimum(ops.maximum(x, 0.0), 1.0)


def _beer(ops, alpha, fraction):
    """1 − (1 − α)^f = −expm1(f·log1p(−α)), α clamped to [0, `ALPHA_MAX`], f ≥ 0."""
    a = ops.minimum(ops.maximum(alpha, 0.0), ALPHA_MAX)
    return -ops.expm1(ops.maximum(fraction, 0.0) * ops.log1p(-a))


def _view_travel(ops, front, back, z_surface):
    """View-z length of [front, back] ∩ [0, z_surface] (m): the camera plane and the depth buffer clip."""
    return ops.maximum(ops.minimum(back, z_surface) - ops.maximum(front, 0.0), 0.0)


def _box_fraction(ops, z, delta, radius):
    """ℓ_z/(2r): the view-z travel through the box's depth range [z − r, z + r] over its depth."""
    r = ops.maximum(radius, _S_MIN)
    return _saturate(ops, _view_travel(ops, z - r, z + r, z + delta) / (2.0 * r))  # rounding: ≤ 1


def _linear_kernel(ops, alpha, delta, radius, s):
    """α·saturate(Δ/(s·r))."""
    scale = ops.maximum(s * radius, _S_MIN)
    return ops.maximum(alpha, 0.0) * _saturate(ops, delta / scale)


def _box_kernel(ops, alpha, z, delta, radius):
    """α·ℓ_z/(2r) (002:325-347)."""
    return ops.maximum(alpha, 0.0) * _box_fraction(ops, z, delta, radius)


def _box_beer_kernel(ops, alpha, z, delta, radius):
    """1 − (1 − α)^(ℓ_z/(2r))."""
    return _beer(ops, alpha, _box_fraction(ops, z, delta, radius))


def _ray_scale(ops, cos_view):
    """1/cos θ of the pixel's view ray (d̂_z), floored at cos θ = 1e-3 (a ray in the view plane)."""
    return 1.0 / ops.maximum(cos_view, 1e-3)


def _box_beer_ray_kernel(ops, alpha, z, delta, radius, cos_view):
    """1 − (1 − α)^(ℓ_z/(2r cos θ)): the box's travel along the ray (ℓ_ray = ℓ_z/cos θ)."""
    return _beer(ops, alpha, _box_fraction(ops, z, delta, radius) * _ray_scale(ops, cos_view))


def _spherical_ray_kernel(ops, alpha_c, z, delta, radius, q, cos_view):
    """The spherical billboard with its view-z chord converted to ray length: ℓ/cos θ."""
    r = ops.maximum(radius, _S_MIN)
    w = ops.sqrt(ops.maximum((r - q) * (r + q), 0.0))
    chord = _view_travel(ops, z - w, z + w, z + delta) * _ray_scale(ops, cos_view)
    return _beer(ops, alpha_c, chord / (2.0 * r))


def _spherical_kernel(ops, alpha_c, z, delta, radius, q):
    """1 − (1 − α_c)^(ℓ/(2r)), ℓ the view-z chord of the sphere at lateral distance q, clipped."""
    r = ops.maximum(radius, _S_MIN)
    w2 = (r - q) * (r + q)
    w = ops.sqrt(ops.maximum(w2, 0.0))
    chord = _view_travel(ops, z - w, z + w, z + delta)
    return _beer(ops, alpha_c, chord / (2.0 * r))


def _fitted_kernel(ops, alpha, delta, radius, s, b, p):
    """α·saturate(Δ/(s·r) + b)^p (0 where the base is 0: no 0^p in the JAX derivative)."""
    scale = ops.maximum(s * radius, _S_MIN)
    f = _saturate(ops, delta / scale + b)
    pos = f > 0.0
    return ops.maximum(alpha, 0.0) * ops.select(pos, ops.power(ops.select(pos, f, 1.0), p), 0.0)


def _sphere_chord_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius):
    """Length (m) of the unit ray t·d̂, t ∈ [0, t_s], inside the sphere |x − c| ≤ r."""
    b = dx * cx + dy * cy + dz * cz
    px, py, pz = cy * dz - cz * dy, cz * dx - cx * dz, cx * dy - cy * dx
    h2 = px * px + py * py + pz * pz
    w = ops.sqrt(ops.maximum((radius - ops.sqrt(h2)) * (radius + ops.sqrt(h2)), 0.0))
    back = ops.minimum(w, t_surface - b)
    front = ops.maximum(-w, -b)
    return ops.maximum(back - front, 0.0)


def _slab(ops, c, d, radius):
    """(t_lo, t_hi) of the slab |x − c| ≤ r along t·d (one axis); ±`BIG` or an empty interval if d = 0."""
    par = ops.abs(d) < 1e-30
    ds = ops.select(par, 1.0, d)
    t1 = (c - radius) / ds
    t2 = (c + radius) / ds
    inside = ops.abs(c) <= radius
    lo = ops.select(par, ops.select(inside, -BIG, BIG), ops.minimum(t1, t2))
    hi = ops.select(par, ops.select(inside, BIG, -BIG), ops.maximum(t1, t2))
    return lo, hi


def _box_chord_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius):
    """Length (m) of the unit ray t·d̂, t ∈ [0, t_s], inside the view-aligned cube |x − c|_∞ ≤ r."""
    lx, hx = _slab(ops, cx, dx, radius)
    ly, hy = _slab(ops, cy, dy, radius)
    lz, hz = _slab(ops, cz, dz, radius)
    near = ops.maximum(ops.maximum(lx, ly), lz)
    far = ops.minimum(ops.minimum(hx, hy), hz)
    return ops.maximum(ops.minimum(far, t_surface) - ops.maximum(near, 0.0), 0.0)


def _opacity(ops, sigma, chord):
    """1 − exp(−σℓ), σ clamped to [0, `SIGMA_MAX`]."""
    return -ops.expm1(-ops.minimum(ops.maximum(sigma, 0.0), SIGMA_MAX) * chord)


def _exact_sphere_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius, sigma):
    """Beer–Lambert opacity of a homogeneous sphere along the ray, clipped by the surface."""
    return _opacity(ops, sigma, _sphere_chord_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius))


def _exact_box_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius, sigma):
    """Beer–Lambert opacity of a homogeneous view-aligned cube along the ray, clipped by the surface."""
    return _opacity(ops, sigma, _box_chord_kernel(ops, dx, dy, dz, cx, cy, cz, t_surface, radius))


def _billboard_alpha_kernel(ops, alpha_c, radius, q):
    """A sphere's billboard texture: the opacity of its full view-axis chord 2√(r² − q²),
    1 − (1 − α_c)^√(1 − (q/r)²)."""
    r = ops.maximum(radius, _S_MIN)
    u = ops.minimum(ops.abs(q) / r, 1.0)
    return _beer(ops, alpha_c, ops.sqrt((1.0 - u) * (1.0 + u)))


# ===================================================================================== methods (data)
_ALPHA = Input(
    "alpha", "1", "the billboard texture's opacity at the pixel (unclipped, along the view axis)", (0, 1)
)
_ALPHA_C = Input("alpha_c", "1", "the particle's opacity through its centre, 1 − exp(−2σr)", (0.0, 1.0))
_Z = Input("z", "m", "view depth of the particle's centre (the billboard)", (-1e3, 1e3))
_DELTA = Input("delta", "m", "Δ = scene view depth − particle view depth", (-1e3, 1e3))
_RADIUS = Input("radius", "m", "particle radius (box half-size)", (1e-3, 1e2))
_Q = Input("q", "m", "lateral distance of the pixel's billboard point from the centre", (0.0, 1e2))
_COS = Input("cos_view", "1", "cos θ of the pixel's view ray from the view axis (d̂_z)", (0.0, 1.0))
_RAY = (
    Input("dx", "1", "unit view ray d̂ (view space, camera at the origin), x", (-1.0, 1.0)),
    Input("dy", "1", "unit view ray, y", (-1.0, 1.0)),
    Input("dz", "1", "unit view ray, z", (-1.0, 1.0)),
    Input("cx", "m", "particle centre c (view space), x", (-1e3, 1e3)),
    Input("cy", "m", "particle centre, y", (-1e3, 1e3)),
    Input("cz", "m", "particle centre, z", (-1e3, 1e3)),
    Input("t_surface", "m", "ray distance to the opaque surface (BIG: none)", (0.0, 1e4)),
    _RADIUS,
    Input("sigma", "1/m", "extinction σ of the particle's medium", (0.0, 1e4)),
)
_S = Param(1.0, 0.0, 1e3, unit="r", description="fade distance s in particle radii")

METHODS = method_table(
    [
        Method(
            "linear",
            "depth fade α·saturate(Δ/s)",
            _linear_kernel,
            inputs=(_ALPHA, _DELTA, _RADIUS),
            params={"s": _S},
            quantity="particle_opacity",
            formula="α' = α·saturate(Δ/(s·r))",
            source="seed 000:2302-2318 (the depth fade as engines implement it)",
            description="Linear fade from the billboard plane; ignores the camera plane and the ray's slant.",
        ),
        Method(
            "box",
            "camera-aligned box (2007)",
            _box_kernel,
            inputs=(_ALPHA, _Z, _DELTA, _RADIUS),
            quantity="particle_opacity",
            formula="α' = α·ℓ_z/(2r), ℓ_z = max(min(z + r, z_s) − max(z − r, 0), 0)",
            source="seed 002:325-347 (camera aligned volume box); 000:2302-2318 (text)",
            description="View-z travel through the box's depth range over its depth, times α (linear).",
        ),
        Method(
            "box-beer",
            "camera-aligned box, Beer–Lambert",
            _box_beer_kernel,
            inputs=(_ALPHA, _Z, _DELTA, _RADIUS),
            quantity="particle_opacity",
            formula="α' = 1 − (1 − α)^(ℓ_z/(2r))",
            source="rtfit: the box's travel through Beer–Lambert",
            description="Exact on the view axis; short by cos θ in optical depth at θ off-axis.",
        ),
        Method(
            "spherical",
            "spherical billboard",
            _spherical_kernel,
            inputs=(_ALPHA_C, _Z, _DELTA, _RADIUS, _Q),
            quantity="particle_opacity",
            formula="α' = 1 − (1 − α_c)^(ℓ/(2r)), ℓ = view-z chord of the sphere at q, clipped",
            source="Umenhoffer, Szirmay-Kalos, Szijártó, GI 2006 (named in seed 001:1608)",
            description="The sphere's chord along the view axis at the billboard point, Beer–Lambert.",
        ),
        Method(
            "box-beer-ray",
            "camera-aligned box, Beer–Lambert along the ray",
            _box_beer_ray_kernel,
            inputs=(_ALPHA, _Z, _DELTA, _RADIUS, _COS),
            quantity="particle_opacity",
            formula="α' = 1 − (1 − α)^(ℓ_z/(2r·cos θ))",
            source="rtfit: box-beer with the view-z travel converted to ray length",
            description="Removes the cos θ loss of optical depth off-axis (exact in the box's slab regime).",
        ),
        Method(
            "spherical-ray",
            "spherical billboard along the ray",
            _spherical_ray_kernel,
            inputs=(_ALPHA_C, _Z, _DELTA, _RADIUS, _Q, _COS),
            quantity="particle_opacity",
            formula="α' = 1 − (1 − α_c)^(ℓ/(2r·cos θ))",
            source="rtfit: the spherical billboard's chord converted to ray length",
            description="The spherical billboard with the 1/cos θ of the pixel's ray.",
        ),
        Method(
            "fitted",
            "fitted fade α·saturate(Δ/s + b)^p",
            _fitted_kernel,
            inputs=(_ALPHA, _DELTA, _RADIUS),
            params={
                "s": Param(2.0, 0.0, 1e3, unit="r", description="fade distance s in particle radii"),
                "b": Param(0.5, -2.0, 2.0, unit="1", description="offset of the fade ramp"),
                "p": Param(1.0, 0.05, 8.0, unit="1", description="exponent of the fade"),
            },
            quantity="particle_opacity",
            formula="α' = α·saturate(Δ/(s·r) + b)^p",
            source="rtfit (the seed's fade with an offset and an exponent)",
            description="Three artist parameters fitted to the exact clipped Beer–Lambert opacity.",
        ),
        Method(
            "exact-sphere",
            "exact: homogeneous sphere, clipped chord",
            _exact_sphere_kernel,
            inputs=_RAY,
            exact=True,
            quantity="particle_opacity",
            formula="1 − exp(−σℓ), ℓ = |[b − w, b + w] ∩ [0, t_s]|, w = √(r² − |c × d̂|²)",
            source="Beer–Lambert; ray–sphere chord",
            description="The ground truth for a spherical particle (module docstring).",
        ),
        Method(
            "exact-box",
            "exact: homogeneous view-aligned cube, clipped chord",
            _exact_box_kernel,
            inputs=_RAY,
            exact=True,
            quantity="particle_opacity",
            formula="1 − exp(−σℓ), ℓ = |[t_near, t_far] ∩ [0, t_s]| (slabs)",
            source="Beer–Lambert; ray–box slab test",
            description="The ground truth for a box particle (module docstring).",
        ),
    ]
)
"""The family's methods (module docstring): ``METHODS[id](ops, inputs, params)``."""

APPROXIMATIONS = ("linear", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray", "fitted")
"""The real-time methods (the rest are the exact references)."""


# ===================================================================================== public API
def soft_particle_opacity(method: str, inputs: dict, params: dict | None = None):
    """Opacity α' of one particle pixel by ``method`` (a `METHODS` id) on the inputs it declares
    (`METHODS[method].inputs`); dispatch as every public function (`rtfit.realtime.arrays`)."""
    if method not in METHODS:
        raise ValueError(f"unknown soft-particle method {method!r} (known: {', '.join(METHODS)})")
    return METHODS[method].evaluate(inputs, params)


def sphere_chord(direction, centre, t_surface, radius):
    """Length (m) of the unit ray t·d̂ (camera at the origin), t ∈ [0, t_s], inside the sphere (c, r)."""
    check_range("radius", radius, 0.0, 3.4e38, interval="[0, 3.4e38] (m)")
    return evaluate(_sphere_chord_kernel, *direction, *centre, t_surface, radius)


def box_chord(direction, centre, t_surface, radius):
    """Length (m) of the unit ray t·d̂, t ∈ [0, t_s], inside the view-aligned cube of centre c, half-size r."""
    check_range("radius", radius, 0.0, 3.4e38, interval="[0, 3.4e38] (m)")
    return evaluate(_box_chord_kernel, *direction, *centre, t_surface, radius)


def beer_fraction(alpha, fraction):
    """1 − (1 − α)^f: the opacity of the fraction f of a chord whose full opacity is α."""
    check_range("alpha", alpha, 0.0, 1.0, interval="[0, 1]")
    return evaluate(_beer, alpha, fraction)


def billboard_alpha(alpha_c, radius, q):
    """A spherical particle's texture α at lateral distance q: 1 − (1 − α_c)^√(1 − (q/r)²)."""
    check_range("alpha_c", alpha_c, 0.0, 1.0, interval="[0, 1]")
    return evaluate(_billboard_alpha_kernel, alpha_c, radius, q)


def linear_underestimate(alpha: float) -> tuple[float, float]:
    """max_f (1 − (1 − α)^f − α·f) over f ∈ [0, 1] and its f: f* = ln(−α/ln(1 − α))/ln(1 − α)."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
    lg = math.log1p(-alpha)
    f = math.log(-alpha / lg) / lg
    return 1.0 - math.exp(f * lg) - alpha * f, f
