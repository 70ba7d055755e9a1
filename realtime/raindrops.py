r"""Raindrops: a water drop shaded as a refracted and a reflected environment look-up with a Fresnel blend,
against the ray optics of a sphere (two refractions, internal reflections).

The seed (000:822-887, Tatarchuk 2006, ToyShop, §3.6 "Rain"; 003's rain slides show it without formulas)
---------------------------------------------------------------------------------------------------------
"Each individual drop refracts and reflects the environment" (000:822); "the illumination for rain is
computed using water-air refraction for individual raindrops as well as reflection ... and the Fresnel
effect" (000:826); "For each pixel in the rain pass, we compute reflection based on the individual raindrop
normal and air-to-water refraction. Both are attenuated toward the edges of the raindrop by using the
Fresnel effect" (000:854); the particle drops "only compute specular reflection and air-to-water refraction
effects" (000:875) and their opacity is "attenuat[ed] ... by Fresnel value, scaled and biased by two
artist-specified parameters for droplet edge strength and bias" (000:887). The claim to test (000:852,
after Garg & Nayar 2004, the seed's [Garg04]): "a drop tends to be much brighter than its background (the
portion of the scene it occludes)", because it "refract[s] light from a large solid angle of the
environment (including the sky) towards the camera".

Errata and reading. The seed prints no shader: the rows below are the standard HLSL reading of its words,
named as such. (1) The refraction is one interface, ``refract(d, n, 1/η)`` on the camera ray d at the drop's
normal n, looked up at infinity (the shader has no second surface); η = 1.33 ("air-to-water"). (2) "Both are
attenuated toward the edges ... by the Fresnel effect" is read as the usual blend F·L(R) + (1 − F)·L(T):
the refracted part *is* attenuated toward the edges, the reflected one grows there (physics; the seed's
"both" cannot hold for a reflectance that tends to 1 at grazing incidence). (3) The Fresnel term is
Schlick's with F0 = ((η − 1)/(η + 1))² (0.0201 for water): the seed does not say which; Schlick is what its
era's shaders used (000 ch. 4, 001:494). (4) The particle's opacity α = sat(s·F + b) (edge strength s,
bias b: no values given, so only fitted) blends the shaded drop over its background L(d). (5) "Bias toward
the white spectrum" (000:858) is a brightness factor k on the drop (no value given: only fitted).

Best modern form: the ray optics of a sphere (Descartes 1637; Nussenzveig 1977, "The theory of the
rainbow", Sci. Am. 236(4); the same sum is Garg & Nayar 2004's photometric drop model, §3 of "Detection and
removal of rain from videos", CVPR, and the refracted-ray form of Wyman 2005's two-sided refraction, exact
for a sphere). A camera ray d (unit) hits the drop at the outward unit normal n with c = −d·n:

    t₁ = d/η + (c/η − c_t)·n,   c_t = √(1 − (1 − c²)/η²)          (enter; Snell's law in vector form)
    n₂ = n + 2c_t·t₁                                               (the exit point's normal: the chord
                                                                    of a sphere is 2r·c_t; |n₂| = 1)
    e₀ = η·t₁ − (η·c_t − c)·n₂                                     (leave: the second refraction)
    t_{k+1} = t_k − 2c_t·n_{k+1},  n_{k+2} = n_{k+1} + 2c_t·t_{k+1},  e_k = η·t_k − (η·c_t − c)·n_{k+1}

Every internal incidence has the same cosine c_t (the chord is symmetric), so every interface has the same
Fresnel reflectance F = F(c, η) (reciprocity) and there is no total internal reflection inside a sphere
entered from outside. The radiance is

    L = F·L(R) + (1 − F)²·Σ_{k=0}^{K} F^k·L(e_k),   R = d + 2c·n                       (W/(m²·sr))

(the η² of entering and 1/η² of leaving cancel). Rows: ``two-interface`` K = 0 (the exit direction through
the whole drop), ``two-interface-1`` K = 1 (plus the first internal reflection: the primary rainbow's
path), ``ray-optics`` K = `ORDERS` (the weights left out, (1 − F)·F^{K+1} ≤ 1/(e(K + 2)) ≈ 0.037 at K = 8,
matter only at the rim, where F → 1). Under a constant environment L₀ the sum of the weights is
1 − (1 − F)F^{K+1}: the drop is L₀ up to that rest (energy conservation, the white furnace).

The droplet's shadow (000:1010: "a pseudo-caustic highlight in the middle of the shadow", no formula): with
the sun overhead, a floor point at distance r from the shadow's centre of a drop of radius R gets
E = E⊥·[r ≥ R] (``hard-shadow``, a shadow map), plus a Gaussian spot A·e^(−r²/2σ²) (``seed-spot``: A, σ
only fitted) or a spot carrying the flux that crosses the drop, τ·R²/(2σ²)·e^(−r²/2σ²) with
τ = ∫₀¹ (1 − F(c))²·2c dc (``flux-spot``: energy conservation, σ fitted). These `CAUSTIC_METHODS` are the
family study's (against light tracing: `rtfit.reference.caustic_pass`), not the audit's rows.

Look-ups L(·) read one cube map of the environment (`ENV_RESOLUTION`² texels a face, this module's
neighbour `rtfit.realtime.environment_maps`' layout and `cube_lookup_kernel`, bilinear within a face): what
an engine stores. Fresnel: `dielectric_fresnel_kernel` (exact, unpolarised) and `schlick_fresnel_kernel`
of the same module: one text per formula.

Units and domain: directions are unit vectors (world frame; the look-up does not need them normalised), η =
n_drop/n_outside ∈ [0.25, 4] (water 1.33; η < 1 is an air bubble in water: total internal reflection at the
entry for 1 − (1 − c²)/η² < 0, F = 1); radiance in the environment's units, (R, G, B) from the three
channels' cube maps ``env_r``, ``env_g``, ``env_b`` (6·N² floats each).

Guards (each with its reason): c is clamped to [0, 1] (the G-buffer's float32 normal and ray may give
d·n a hair above 0 at the silhouette); η is floored at 1e-3 (the divisions by η); c_t = √max(·, 0)
(`safe_sqrt`: under total internal reflection the radicand is negative, the transmitted terms are then
weighted by 1 − F = 0 and their look-up directions are finite garbage read from the map, never NaN);
α and k are clamped to [0, 1] and ≥ 0. The cube look-up maps a zero or NaN direction to a face centre.

Float32: all terms are products and sums of bounded values (|t_k|, |n_k|, |e_k| ≤ 1 + rounding; F, weights
in [0, 1]); no exponentials or divisions other than by η ≥ 1e-3. No NaN or Inf for finite inputs
(tests/test_raindrops.py, hypothesis over grazing rays, η → 1 and total internal reflection).
"""

from __future__ import annotations

from .arrays import check_range, evaluate, safe_sqrt
from .environment_maps import cube_lookup_kernel, dielectric_fresnel_kernel, schlick_fresnel_kernel
from .methods import Input, Method, Param, method_table

__all__ = [  # METHODS, CAUSTIC_METHODS and INPUTS stay out (each family has its own)
    "ENV_RESOLUTION",
    "ORDERS",
    "WATER_ETA",
    "drop_directions",
    "drop_weights",
]

ENV_RESOLUTION = 64
"""Texels per face edge of the environment's cube map the rows read (1.4° texels)."""
ORDERS = 8
"""Internal reflections summed by the ``ray-optics`` row (k = 0 … ORDERS)."""
WATER_ETA = 1.33
"""Water's index of refraction in air (the seed's "air-to-water")."""
_ETA_FLOOR = 1e-3  # the divisions by η


# ===================================================================================== kernels (ops text)
def _cos_in(ops, dx, dy, dz, nx, ny, nz):
    """c = −d·n clamped to [0, 1] (module docstring: guards)."""
    return ops.minimum(ops.maximum(-(dx * nx + dy * ny + dz * nz), 0.0), 1.0)


def _enter(ops, dx, dy, dz, nx, ny, nz, c, eta):
    """(t₁, c_t): the direction inside the drop after the first refraction, and its cosine to −n."""
    inv = 1.0 / eta
    ct = safe_sqrt(ops, 1.0 - (1.0 - c * c) * (inv * inv))  # negative radicand: TIR, weighted by 1 − F = 0
    k = c * inv - ct
    return (dx * inv + k * nx, dy * inv + k * ny, dz * inv + k * nz), ct


def _reflect(dx, dy, dz, nx, ny, nz, c):
    """R = d + 2c·n (the mirror direction; c = −d·n)."""
    return dx + 2.0 * c * nx, dy + 2.0 * c * ny, dz + 2.0 * c * nz


def _paths(ops, dx, dy, dz, nx, ny, nz, eta, orders: int):
    """[(weight factor index k, exit direction e_k)] for k = 0 … orders, plus c, c_t (module docstring)."""
    e = ops.maximum(eta, _ETA_FLOOR)
    c = _cos_in(ops, dx, dy, dz, nx, ny, nz)
    t, ct = _enter(ops, dx, dy, dz, nx, ny, nz, c, e)
    m = (nx + 2.0 * ct * t[0], ny + 2.0 * ct * t[1], nz + 2.0 * ct * t[2])  # n₂
    g = e * ct - c
    out = []
    for _ in range(orders + 1):
        out.append((e * t[0] - g * m[0], e * t[1] - g * m[1], e * t[2] - g * m[2]))
        t = (t[0] - 2.0 * ct * m[0], t[1] - 2.0 * ct * m[1], t[2] - 2.0 * ct * m[2])  # internal reflection
        m = (m[0] + 2.0 * ct * t[0], m[1] + 2.0 * ct * t[1], m[2] + 2.0 * ct * t[2])  # the next hit's normal
    return out, c, e


def _look(ops, env_r, env_g, env_b, v, resolution):
    """(R, G, B) of the cube maps in direction v."""
    return tuple(
        cube_lookup_kernel(ops, t, v[0], v[1], v[2], resolution, True) for t in (env_r, env_g, env_b)
    )


def _mix(a, wa, b, wb):
    """wa·a + wb·b per channel (a, b: RGB tuples)."""
    return tuple(wa * x + wb * y for x, y in zip(a, b, strict=True))


def _ray_optics_kernel(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution, orders):
    """F·L(R) + (1 − F)²·Σ_{k ≤ orders} F^k·L(e_k) with the exact Fresnel F (module docstring)."""
    exits, c, e = _paths(ops, dx, dy, dz, nx, ny, nz, eta, orders)
    f = dielectric_fresnel_kernel(ops, c, e)
    total = tuple(
        f * x for x in _look(ops, env_r, env_g, env_b, _reflect(dx, dy, dz, nx, ny, nz, c), resolution)
    )
    w = (1.0 - f) * (1.0 - f)
    for v in exits:
        total = _mix(total, 1.0, _look(ops, env_r, env_g, env_b, v, resolution), w)
        w = w * f
    return total


def _seed_shade(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution):
    """(the seed's F·L(R) + (1 − F)·L(T₁), F): Schlick's F from η, one refraction (module docstring)."""
    e = ops.maximum(eta, _ETA_FLOOR)
    c = _cos_in(ops, dx, dy, dz, nx, ny, nz)
    r0 = (e - 1.0) / (e + 1.0)
    f = schlick_fresnel_kernel(ops, c, r0 * r0)
    t, _ = _enter(ops, dx, dy, dz, nx, ny, nz, c, e)
    refl = _look(ops, env_r, env_g, env_b, _reflect(dx, dy, dz, nx, ny, nz, c), resolution)
    return _mix(refl, f, _look(ops, env_r, env_g, env_b, t, resolution), 1.0 - f), f


def _seed_kernel(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution):
    """The seed's blend at the drop's own η."""
    return _seed_shade(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution)[0]


def _seed_fitted_kernel(ops, dx, dy, dz, nx, ny, nz, env_r, env_g, env_b, resolution, eta_eff, brightness):
    """k·(F·L(R) + (1 − F)·L(T₁)) at an effective η (the refraction's strength); k ≥ 0."""
    shade = _seed_shade(ops, dx, dy, dz, nx, ny, nz, eta_eff, env_r, env_g, env_b, resolution)[0]
    k = ops.maximum(brightness, 0.0)
    return tuple(k * x for x in shade)


def _seed_opacity_kernel(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution, strength, bias):
    """α·(F·L(R) + (1 − F)·L(T₁)) + (1 − α)·L(d), α = sat(s·F + b): the particle over its background."""
    shade, f = _seed_shade(ops, dx, dy, dz, nx, ny, nz, eta, env_r, env_g, env_b, resolution)
    alpha = ops.minimum(ops.maximum(strength * f + bias, 0.0), 1.0)
    return _mix(shade, alpha, _look(ops, env_r, env_g, env_b, (dx, dy, dz), resolution), 1.0 - alpha)


def _background_kernel(ops, dx, dy, dz, env_r, env_g, env_b, resolution):
    """L(d): the environment the drop hides (no drop)."""
    return _look(ops, env_r, env_g, env_b, (dx, dy, dz), resolution)


# ===================================================================================== methods (data)
def _vec(prefix: str, what: str) -> tuple[Input, Input, Input]:
    return tuple(Input(f"{prefix}{c}", "1", f"{what}, {c} component", (-1.0, 1.0)) for c in "xyz")  # type: ignore[return-value]


_D = _vec("d", "unit camera-ray direction (from the camera into the drop)")
_N = _vec("n", "outward unit normal of the drop at the ray's hit")
_ETA = Input("eta", "1", "η = n_drop/n_outside (water in air: 1.33)", (0.25, 4.0))
_ENV = tuple(
    Input(f"env_{c}", "W/m²/sr", f"the environment's cube map, channel {c} (6·{ENV_RESOLUTION}² texels)")
    for c in "rgb"
)
INPUTS = (*_D, *_N, _ETA, *_ENV)
"""The quantity ``drop_radiance``'s inputs."""
_FIXED = {"resolution": ENV_RESOLUTION}
_SEED = "seed 000:822-887 (words only: 826, 852-854, 875; reading and errata in the module docstring)"
_OPTICS = "Nussenzveig 1977 (ray optics of a sphere); Garg & Nayar 2004 (CVPR, photometric drop model)"


def _optics(orders: int, mid: str, label: str) -> Method:
    return Method(
        mid,
        label,
        _ray_optics_kernel,
        inputs=INPUTS,
        fixed={**_FIXED, "orders": orders},
        quantity="drop_radiance",
        formula=f"F·L(R) + (1 − F)²·Σ_(k≤{orders}) F^k·L(e_k), e_k: two refractions, k internal reflections",
        source=_OPTICS,
    )


METHODS = method_table(
    [
        Method(
            "seed",
            "seed: Fresnel blend of L(R) and one refraction",
            _seed_kernel,
            inputs=INPUTS,
            fixed=_FIXED,
            quantity="drop_radiance",
            formula="F_S·L(R) + (1 − F_S)·L(refract(d, n, 1/η)), F_S Schlick, F0 = ((η − 1)/(η + 1))²",
            source=_SEED,
            description="The camera ray bent once and looked up at infinity: no exit surface.",
        ),
        Method(
            "seed-fitted",
            "seed, effective η and brightness fitted",
            _seed_fitted_kernel,
            inputs=(*_D, *_N, *_ENV),
            params={
                "eta_eff": Param(
                    WATER_ETA, 1.0, 4.0, unit="1", description="effective η of the one refraction"
                ),
                "brightness": Param(
                    1.0, 0.0, 4.0, unit="1", description="the seed's bias toward white", published=False
                ),
            },
            fixed=_FIXED,
            quantity="drop_radiance",
            formula="k·(F_S·L(R) + (1 − F_S)·L(refract(d, n, 1/η_eff)))",
            source=_SEED + "; 000:858 (brightness bias, no value)",
        ),
        Method(
            "seed-opacity",
            "seed particle: Fresnel opacity over the background",
            _seed_opacity_kernel,
            inputs=INPUTS,
            params={
                "strength": Param(
                    1.0, 0.0, 20.0, unit="1", description="droplet edge strength s", published=False
                ),
                "bias": Param(0.0, -1.0, 1.0, unit="1", description="droplet bias b", published=False),
            },
            fixed=_FIXED,
            quantity="drop_radiance",
            formula="α·(F_S·L(R) + (1 − F_S)·L(T₁)) + (1 − α)·L(d), α = sat(s·F_S + b)",
            source="seed 000:887 (edge strength and bias: artists' values, not given)",
        ),
        _optics(0, "two-interface", "two refractions (exit direction), exact Fresnel"),
        _optics(1, "two-interface-1", "two refractions + first internal reflection"),
        _optics(ORDERS, "ray-optics", f"ray optics of a sphere, {ORDERS} internal reflections"),
        Method(
            "background",
            "no drop: the background it hides",
            _background_kernel,
            inputs=(*_D, *_ENV),
            fixed=_FIXED,
            quantity="drop_radiance",
            formula="L(d)",
            source="the seed's comparison (000:852): the portion of the scene the drop occludes",
            description="A baseline: where the drop is brighter than this, the seed's claim holds.",
        ),
    ]
)
"""The raindrops family's rows on ``drop_radiance`` (module docstring)."""


# ======================================================================== the droplet's shadow (study)
def _shadow(ops, r, radius):
    """[r ≥ R]: lit outside the drop's shadow disk (the sun overhead)."""
    return ops.select(r >= radius, 1.0, 0.0) + 0.0 * r


def _hard_shadow_kernel(ops, r, radius, e_sun):
    """E = E⊥·[r ≥ R]: the shadow map's hard shadow, no caustic."""
    return e_sun * _shadow(ops, r, radius)


def _spot(ops, r, sigma):
    s = ops.maximum(sigma, _MIN_SPOT)
    return ops.exp(-0.5 * (r * r) / (s * s)), s


def _seed_spot_kernel(ops, r, radius, e_sun, amplitude, sigma):
    """E = E⊥·([r ≥ R] + A·e^(−r²/2σ²)): the seed's pseudo-caustic highlight in the shadow's middle."""
    g, _ = _spot(ops, r, sigma)
    return e_sun * (_shadow(ops, r, radius) + ops.maximum(amplitude, 0.0) * g)


def _flux_spot_kernel(ops, r, radius, e_sun, sigma, transmitted):
    """E = E⊥·([r ≥ R] + τ·R²/(2σ²)·e^(−r²/2σ²)): the spot carries the flux τ·πR²·E⊥ that crosses the drop."""
    g, s = _spot(ops, r, sigma)
    return e_sun * (_shadow(ops, r, radius) + transmitted * (radius * radius) / (2.0 * s * s) * g)


_MIN_SPOT = 1e-4  # σ floor (m): a fitted width at its bound keeps the spot finite


_R = Input("r", "m", "distance on the floor from the shadow's centre (the sun overhead)", (0.0, 10.0))
_RADIUS = Input("radius", "m", "the drop's radius R (its shadow disk's)", (1e-3, 10.0))
_E_SUN = Input("e_sun", "W/m²", "the sun's irradiance on the floor without the drop", (0.0, 1e5))
_SIGMA = Param(0.3, 1e-3, 10.0, unit="m", description="the spot's Gaussian width σ", published=False)
CAUSTIC_METHODS = method_table(
    [
        Method(
            "hard-shadow",
            "shadow map, no caustic",
            _hard_shadow_kernel,
            inputs=(_R, _RADIUS, _E_SUN),
            quantity="receiver_irradiance",
            formula="E = E⊥·[r ≥ R]",
            source="a shadow map (the droplet's projected mass as an opaque shadow, 000:1010)",
        ),
        Method(
            "seed-spot",
            "seed: pseudo-caustic spot in the shadow (A, σ fitted)",
            _seed_spot_kernel,
            inputs=(_R, _RADIUS, _E_SUN),
            params={
                "amplitude": Param(
                    2.0, 0.0, 100.0, unit="1", description="the spot's peak / E⊥", published=False
                ),
                "sigma": _SIGMA,
            },
            quantity="receiver_irradiance",
            formula="E = E⊥·([r ≥ R] + A·e^(−r²/(2σ²)))",
            source="seed 000:1010, 1018 (a bright pseudo-caustic highlight mid-shadow; no formula)",
        ),
        Method(
            "flux-spot",
            "spot carrying the drop's transmitted flux (σ fitted)",
            _flux_spot_kernel,
            inputs=(
                _R,
                _RADIUS,
                _E_SUN,
                Input("transmitted", "1", "τ: the disk's light crossing the drop", (0.0, 1.0)),
            ),
            params={"sigma": _SIGMA},
            quantity="receiver_irradiance",
            formula="E = E⊥·([r ≥ R] + τR²/(2σ²)·e^(−r²/(2σ²))), τ from the ray optics' (1 − F)²",
            source="energy conservation: the flux πR²E⊥τ through the drop lands in its shadow",
        ),
    ]
)
"""The droplet shadow's rows (the study's, on light-traced caustics: `rtfit.reference.caustic_pass`)."""


# ===================================================================================== public API
def _unit(name: str, v) -> None:
    check_range(name, v, -1.0 - 1e-4, 1.0 + 1e-4, interval="[-1, 1] (unit-vector components)")


def drop_directions(d, n, eta, orders: int = ORDERS):
    """The exit directions e_0 … e_orders (each a tuple of three arrays) of a ray d (unit, (3,) or
    (3, N)) entering a sphere at its outward unit normal n with relative index ``eta`` (module docstring:
    two refractions and k internal reflections), and R, its mirror direction."""
    _unit("d", d)
    _unit("n", n)
    check_range("eta", eta, 0.25, 4.0, interval="[0.25, 4]")
    if isinstance(orders, bool) or int(orders) != orders or not 0 <= int(orders) <= 64:
        raise ValueError(f"drop_directions: orders must be an integer in [0, 64], got {orders!r}")

    def kernel(ops, dx, dy, dz, nx, ny, nz, e):
        exits, c, _ = _paths(ops, dx, dy, dz, nx, ny, nz, e, int(orders))
        return (*_reflect(dx, dy, dz, nx, ny, nz, c), *(x for v in exits for x in v))

    out = evaluate(kernel, d[0], d[1], d[2], n[0], n[1], n[2], eta)
    return tuple(out[3 * k + 3 : 3 * k + 6] for k in range(int(orders) + 1)), tuple(out[:3])


def drop_weights(cos_in, eta, orders: int = ORDERS):
    """(F, [(1 − F)²F^k for k = 0 … orders]): the weights of the reflected and the k-th transmitted path
    (exact Fresnel at cos θ_i = ``cos_in`` ∈ [0, 1], relative index ``eta``; dimensionless)."""
    check_range("cos_in", cos_in, -1e-4, 1.0 + 1e-4, interval="[0, 1]")
    check_range("eta", eta, 0.25, 4.0, interval="[0.25, 4]")

    def kernel(ops, c, e):
        f = dielectric_fresnel_kernel(ops, ops.minimum(ops.maximum(c, 0.0), 1.0), ops.maximum(e, _ETA_FLOOR))
        return (f, *((1.0 - f) * (1.0 - f) * f**k for k in range(int(orders) + 1)))

    out = evaluate(kernel, cos_in, eta)
    return out[0], list(out[1:])
