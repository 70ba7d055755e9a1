r"""Fresnel reflectance: Schlick (from the IOR, with a fitted exponent, the seeds' slider and rim forms, the
seed's metal shortcut), Hoffman's F82 tint, and the exact unpolarised dielectric and conductor Fresnel.

Conventions and units
---------------------
* ``cos_theta`` = v·n ∈ [0, 1]: the cosine between the direction to the viewer and the surface normal on the
  viewer's side (the mirror direction's half vector is n, so this is also cos θ_h of the specular lobe).
  Clamped to [0, 1] (rounding of dot products).
* ``eta`` = η, the real part of the relative index of refraction n_t/n_i across the surface, seen from the
  viewer's side (glass seen from inside: 1/1.5; η < 1 has total internal reflection beyond the critical
  angle); ``k`` the extinction coefficient (imaginary part; 0 for a dielectric). Per RGB channel.
* The result is the reflectance F ∈ [0, 1] (dimensionless): the fraction of unpolarised light reflected.

Formulas
--------
* Exact dielectric (Fresnel 1823; unpolarised mean of s and p; Born & Wolf §1.5.2; Mitsuba's ``fresnel``):
  cos θ_t = √(1 − (1 − c²)/η²), r_s = (c − η cos θ_t)/(c + η cos θ_t), r_p = (η c − cos θ_t)/(η c + cos θ_t),
  F = ½(r_s² + r_p²). Guards (reasons): 1 − (1 − c²)/η² ≤ 0 is **total internal reflection** (no
  transmitted wave: the square root would be NaN; F = 1 exactly); η = 1 is no interface (F = 0; at c = 0 the
  two ratios are 0/0, Mitsuba's choice); η is floored at 1e-30 (the division by η²).
* Exact conductor (complex η̂ = η + ik; Born & Wolf §14.2, the form of PBRT 3 §8.2.1 and Mitsuba's
  ``fresnel_conductor``): t = η² − k² − sin²θ, a² + b² = √(t² + 4η²k²), a = √(½(a² + b² + t)),
  R_s = (a² + b² + c² − 2ac)/(a² + b² + c² + 2ac),
  R_p = R_s (c²(a² + b²) + sin⁴θ − 2ac sin²θ)/(c²(a² + b²) + sin⁴θ + 2ac sin²θ),
  F = ½(R_s + R_p). With k = 0 it is the dielectric's, TIR included (a = 0 gives R_s = R_p = 1). Guard:
  the denominators vanish only at η = 1, k = 0, c = 0 (no interface, grazing): floored at 1e-30, F = 0 there.
* Schlick 1994 ("An inexpensive BRDF model for physically-based rendering", Eurographics, eq. 24):
  F = F0 + (1 − F0)(1 − c)⁵ with F0 the exact normal-incidence value, ((η − 1)² + k²)/((η + 1)² + k²)
  (((η − 1)/(η + 1))² for a dielectric). Known error: exact at c = 1 and c = 0, largest near grazing
  (θ ≈ 80°); wrong under TIR (η < 1: it uses the incident angle, not the transmitted one).
* Schlick with a fitted exponent p (``schlick-p``): F0 from the IOR, (1 − c)^p, p ∈ [1, 12] (5: Schlick's).
* The seeds' listing (001:494-495, ``EnvMapClassicPS``): ``F = sFresnel + pow(1-cos_theta, 5)·(1-sFresnel)``
  with ``sFresnel`` a GUI slider (001:370): no value is given, so its F0 is only ever fitted
  (``seed-schlick``: p = 5 as printed; ``schlick-fit``: F0 and p fitted).
* The seed's metals (001:330-336, 001:500-504): "the reflectivity is calculated from the wavelength-dependent,
  complex refraction index (see function ``metal_reflectivity``)". Erratum/reading: the function's body is not
  printed in the seed; the GameTools authors' own metal approximation is Lazányi & Szirmay-Kalos 2005
  ("Fresnel term approximations for metals", WSCG short papers, eq. 5):
  F = ((η − 1)² + k² + 4η(1 − c)⁵)/((η + 1)² + k²) per channel (``seed-metal``). Algebraically this *is*
  Schlick with the conductor's F0 (1 − F0 = 4η/((η + 1)² + k²)): the row differs from ``schlick`` only by
  rounding, which the tests check.
* The seed's rim term (000:2537, Valve, "Shading in Valve's Source Engine" §7.4.5): the text describes "a
  Fresnel term (Figure 10b) … to heavily favor rim lighting" but prints no formula (the figure is lost).
  The Source SDK's shader library (``common_ps_fxc.h``, ``Fresnel``) is f = (1 − n·v)² ("square for a more
  subtle look"), and its ``$phongfresnelranges`` form maps f piecewise linearly through (low, mid, high):
  lerp(low, mid, 2f) for f ≤ ½, lerp(mid, high, 2f − 1) above. ``seed-rim`` is f itself (ranges
  (0, ½, 1)); ``seed-rim-ranges`` fits (low, mid, high) ∈ [0, 1]³ (the SDK gives artists' values only).
  It is a rim *mask*, not a reflectance: 0 at normal incidence where F = F0.
* Best modern form: Hoffman 2019 ("Fresnel equations considered harmful", EGSR/MAM 2019) as used by the
  Adobe Standard Material and OpenPBR (Kutz et al. 2021, "Novel aspects of the Adobe Standard Material",
  the "F82-tint" model): F = F_S(c) − a·c·(1 − c)⁶ with F_S Schlick's from F0, and
  a = (F_S(c̄) − F82)/(c̄ (1 − c̄)⁶) at c̄ = 1/7 (θ ≈ 81.8°, where Schlick's metal error peaks). An engine
  stores two colours, F0 and F82; here both come from the exact conductor formula (``f82``), so the row is
  exact at c = 1, c̄ and 0. The result is clamped to [0, 1] (a reflectance; under TIR F82 > F_S(c̄), a < 0).

Domain: c ∈ [0, 1], η ∈ [1e-3, 1e4] (η ≥ 1e4: η⁴ would approach float32's range in the conductor formula),
k ∈ [0, 100]. Dr.Jit arrays are never checked (no host sync); the kernels clamp c to [0, 1] and floor η at
1e-30.

Methods as data: ``METHODS`` (quantity ``fresnel_reflectance``); ``exact-dielectric`` reads η only (k is
ignored: only a dielectric's row), ``exact-conductor`` reads η and k (exact for both).
"""

from __future__ import annotations

from .arrays import check_range, clamp01, evaluate, safe_div, safe_sqrt
from .methods import Input, Method, Param, method_table

__all__ = [  # METHODS and INPUTS stay out: every family has its own (not re-exported by rtfit.realtime)
    "F82_COS",
    "conductor_fresnel",
    "dielectric_fresnel",
    "f0_from_ior",
    "schlick",
]

_TINY = 1e-30
F82_COS = 1.0 / 7.0
"""c̄ of Hoffman's F82 model: cos 81.8°, where Schlick's error for metals is largest."""
ETA_MAX = 1e4
K_MAX = 100.0


# ===================================================================================== kernels (ops text)
def _pow5(m):
    m2 = m * m
    return m2 * m2 * m


def _f0(ops, eta, k):
    """((η − 1)² + k²)/((η + 1)² + k²): the denominator is ≥ 1 for η ≥ 0."""
    k2 = k * k
    return ((eta - 1.0) * (eta - 1.0) + k2) / ((eta + 1.0) * (eta + 1.0) + k2)


def _f0_kernel(ops, eta, k):
    return _f0(ops, ops.maximum(eta, 0.0), k)


def _schlick_kernel(ops, cos_theta, eta, k):
    """F0 + (1 − F0)(1 − c)⁵ with F0 from the complex IOR (Schlick 1994)."""
    f0 = _f0(ops, ops.maximum(eta, 0.0), k)
    return f0 + (1.0 - f0) * _pow5(1.0 - clamp01(ops, cos_theta))


def _schlick_p_kernel(ops, cos_theta, eta, k, p):
    """F0 + (1 − F0)(1 − c)^p, F0 from the IOR. 1 − c is floored at 1e-30 so that the fit's derivative
    (1 − c)^p·ln(1 − c) stays finite at normal incidence."""
    f0 = _f0(ops, ops.maximum(eta, 0.0), k)
    m = ops.maximum(1.0 - clamp01(ops, cos_theta), _TINY)
    return f0 + (1.0 - f0) * ops.power(m, ops.maximum(p, 0.0))


def _slider_kernel(ops, cos_theta, f0, p):
    """The seed's ``sFresnel + pow(1 − cos θ, 5)·(1 − sFresnel)`` (001:495) with sFresnel = f0 and the
    exponent p (5 as printed); f0 clamped to [0, 1], 1 − c floored as in `_schlick_p_kernel`."""
    f0 = clamp01(ops, f0)
    m = ops.maximum(1.0 - clamp01(ops, cos_theta), _TINY)
    return f0 + (1.0 - f0) * ops.power(m, ops.maximum(p, 0.0))


def _seed_metal_kernel(ops, cos_theta, eta, k):
    """Lazányi & Szirmay-Kalos 2005 eq. 5 as printed: ((η − 1)² + k² + 4η(1 − c)⁵)/((η + 1)² + k²)."""
    e = ops.maximum(eta, 0.0)
    k2 = k * k
    m5 = _pow5(1.0 - clamp01(ops, cos_theta))
    return ((e - 1.0) * (e - 1.0) + k2 + 4.0 * e * m5) / ((e + 1.0) * (e + 1.0) + k2)


def _rim(ops, cos_theta):
    m = 1.0 - clamp01(ops, cos_theta)
    return m * m


def _rim_kernel(ops, cos_theta):
    """Source SDK ``Fresnel``: (1 − n·v)²."""
    return _rim(ops, cos_theta)


def _rim_ranges_kernel(ops, cos_theta, low, mid, high):
    """Source SDK ``Fresnel(n, v, ranges)``: f = (1 − n·v)², lerp(low, mid, 2f) for f ≤ ½ else
    lerp(mid, high, 2f − 1)."""
    f = _rim(ops, cos_theta)
    lower = low + (mid - low) * (2.0 * f)
    upper = mid + (high - mid) * (2.0 * f - 1.0)
    return ops.select(f > 0.5, upper, lower)


def _dielectric_kernel(ops, cos_theta, eta):
    """Exact unpolarised dielectric Fresnel (module docstring: formula and guards)."""
    c = clamp01(ops, cos_theta)
    e = ops.maximum(eta, _TINY)
    ct2 = 1.0 - (1.0 - c) * (1.0 + c) / (e * e)
    ct = safe_sqrt(ops, ct2)  # the TIR branch's radicand is negative: kept finite, selected away below
    ect, ec = e * ct, e * c
    rs = safe_div(ops, c - ect, c + ect)
    rp = safe_div(ops, ec - ct, ec + ct)
    r = 0.5 * (rs * rs + rp * rp)
    r = ops.select(ct2 <= 0.0, 1.0, r)  # total internal reflection: no transmitted wave
    return ops.select(eta == 1.0, 0.0, r)  # index matched: no interface


def _conductor(ops, c, eta, k):
    """Exact conductor Fresnel for c already in [0, 1] (c may be a Python float: F82's c̄)."""
    c2 = c * c
    s2 = 1.0 - c2
    e = ops.maximum(eta, 0.0)
    t = e * e - k * k - s2
    ab = safe_sqrt(ops, t * t + 4.0 * (e * e) * (k * k))  # a² + b²
    a = safe_sqrt(ops, 0.5 * (ab + t))
    t1 = ab + c2
    t2 = 2.0 * c * a
    rs = safe_div(ops, t1 - t2, t1 + t2)  # 0/0 only at η = 1, k = 0, c = 0: F = 0 (no interface)
    t3 = ab * c2 + s2 * s2
    t4 = t2 * s2
    rp = rs * safe_div(ops, t3 - t4, t3 + t4)
    return 0.5 * (rs + rp)


def _conductor_kernel(ops, cos_theta, eta, k):
    """Exact conductor Fresnel for η̂ = η + ik (module docstring)."""
    return _conductor(ops, clamp01(ops, cos_theta), eta, k)


def _f82_kernel(ops, cos_theta, eta, k):
    """Hoffman 2019's F82 tint with F0 and F82 from the exact conductor Fresnel (module docstring)."""
    f0 = _f0(ops, ops.maximum(eta, 0.0), k)
    cb = F82_COS
    mb = 1.0 - cb
    schlick_b = f0 + (1.0 - f0) * mb**5
    a = (schlick_b - _conductor(ops, cb, eta, k)) / (cb * mb**6)
    c = clamp01(ops, cos_theta)
    m = 1.0 - c
    m5 = _pow5(m)
    return clamp01(ops, f0 + (1.0 - f0) * m5 - a * c * (m5 * m))


# ===================================================================================== public API
def _cos(cos_theta):
    return check_range("cos_theta", cos_theta, -1e-4, 1.0 + 1e-4, interval="[0, 1]")


def _eta(eta):
    return check_range("eta", eta, 1e-3, ETA_MAX, interval=f"[0.001, {ETA_MAX:g}]")


def _k(k):
    return check_range("k", k, 0.0, K_MAX, interval=f"[0, {K_MAX:g}]")


def f0_from_ior(eta, k=0.0):
    """Normal-incidence reflectance ((η − 1)² + k²)/((η + 1)² + k²) (dimensionless)."""
    return evaluate(_f0_kernel, _eta(eta), _k(k))


def schlick(cos_theta, eta, k=0.0):
    """Schlick's F0 + (1 − F0)(1 − cos θ)⁵ with F0 from the IOR (dimensionless)."""
    return evaluate(_schlick_kernel, _cos(cos_theta), _eta(eta), _k(k))


def dielectric_fresnel(cos_theta, eta):
    """Exact unpolarised dielectric Fresnel reflectance (1 under total internal reflection)."""
    return evaluate(_dielectric_kernel, _cos(cos_theta), _eta(eta))


def conductor_fresnel(cos_theta, eta, k=0.0):
    """Exact unpolarised Fresnel reflectance for the complex index η + ik (the dielectric's for k = 0)."""
    return evaluate(_conductor_kernel, _cos(cos_theta), _eta(eta), _k(k))


# ===================================================================================== methods as data
_COS = Input(
    "cos_theta", "1", "v·n: cosine between the view direction and the normal (viewer's side)", (0.0, 1.0)
)
_ETA = Input(
    "eta", "1", "η: real part of the relative index of refraction n_t/n_i, per channel", (1e-3, ETA_MAX)
)
_KAPPA = Input(
    "k", "1", "k: extinction coefficient (imaginary part of the index; 0: dielectric)", (0.0, K_MAX)
)
_IOR = (_COS, _ETA, _KAPPA)
INPUTS = _IOR
"""The quantity ``fresnel_reflectance``'s inputs: cos θ, η and k (per channel)."""
_EXPONENT = Param(5.0, 1.0, 12.0, unit="1", description="exponent of (1 − cos θ) (Schlick: 5)")
_F0 = Param(0.04, 0.0, 1.0, unit="1", description="F0: the seed's sFresnel slider", published=False)
_SEED_SCHLICK = "GameTools D5.3 EnvMapClassicPS (seed 001:494-495, sFresnel 001:370)"
_RIM = "Valve 2006 §7.4.5 (seed 000:2537, words only); Source SDK common_ps_fxc.h Fresnel()"

METHODS = method_table(
    [
        Method(
            "schlick",
            "Schlick (F0 from IOR)",
            _schlick_kernel,
            inputs=_IOR,
            quantity="fresnel_reflectance",
            formula="F = F0 + (1 − F0)(1 − cos θ)⁵, F0 = ((η − 1)² + k²)/((η + 1)² + k²)",
            source="Schlick 1994, Eurographics 13(3), eq. 24",
            description="Exact at normal and grazing incidence; largest error near 80°; no TIR.",
        ),
        Method(
            "schlick-p",
            "Schlick, fitted exponent",
            _schlick_p_kernel,
            inputs=_IOR,
            params={"p": _EXPONENT},
            quantity="fresnel_reflectance",
            formula="F = F0 + (1 − F0)(1 − cos θ)^p, F0 from the IOR",
            source="Schlick 1994 with the exponent fitted per material (modern practice)",
        ),
        Method(
            "seed-schlick",
            "Seed Schlick (sFresnel slider)",
            _slider_kernel,
            inputs=(_COS,),
            params={"f0": _F0},
            fixed={"p": 5.0},
            quantity="fresnel_reflectance",
            formula="F = sFresnel + (1 − cos θ)⁵·(1 − sFresnel)",
            source=_SEED_SCHLICK,
            description="The seed's listing: F0 is a GUI slider with no value given, so only fitted.",
        ),
        Method(
            "schlick-fit",
            "Schlick, fitted F0 and exponent",
            _slider_kernel,
            inputs=(_COS,),
            params={"f0": _F0, "p": _EXPONENT},
            quantity="fresnel_reflectance",
            formula="F = F0 + (1 − F0)(1 − cos θ)^p, F0 and p fitted (one grey F0 per material)",
            source=_SEED_SCHLICK + " with the exponent freed",
        ),
        Method(
            "seed-metal",
            "Seed metal (Lazányi–Szirmay-Kalos)",
            _seed_metal_kernel,
            inputs=_IOR,
            quantity="fresnel_reflectance",
            formula="F = ((η − 1)² + k² + 4η(1 − cos θ)⁵)/((η + 1)² + k²)",
            source="seed 001:330-336, 001:500-504 (metal_reflectivity, body not printed); Lazányi & "
            "Szirmay-Kalos 2005, WSCG, eq. 5",
            description="Schlick with the conductor's F0, written as the GameTools authors print it.",
        ),
        Method(
            "seed-rim",
            "Seed rim term (Valve)",
            _rim_kernel,
            inputs=(_COS,),
            quantity="fresnel_reflectance",
            formula="F = (1 − cos θ)²",
            source=_RIM,
            description="A rim mask, not a reflectance: 0 at normal incidence.",
        ),
        Method(
            "seed-rim-ranges",
            "Seed rim term, fitted ranges",
            _rim_ranges_kernel,
            inputs=(_COS,),
            params={
                "low": Param(0.02, 0.0, 1.0, unit="1", description="value at f = 0", published=False),
                "mid": Param(0.5, 0.0, 1.0, unit="1", description="value at f = ½", published=False),
                "high": Param(0.98, 0.0, 1.0, unit="1", description="value at f = 1", published=False),
            },
            quantity="fresnel_reflectance",
            formula="f = (1 − cos θ)²; F = lerp(low, mid, 2f) (f ≤ ½), lerp(mid, high, 2f − 1)",
            source=_RIM + " with $phongfresnelranges",
        ),
        Method(
            "f82",
            "F82 tint (Hoffman 2019)",
            _f82_kernel,
            inputs=_IOR,
            quantity="fresnel_reflectance",
            formula="F = F0 + (1 − F0)(1 − c)⁵ − a·c(1 − c)⁶, a from F82 = F_exact(1/7)",
            source="Hoffman 2019, Fresnel equations considered harmful (EGSR/MAM); Kutz et al. 2021 "
            "(Adobe Standard Material, OpenPBR)",
            description="Two colours per material (F0, F82): exact at 0°, 81.8° and 90°.",
        ),
        Method(
            "exact-dielectric",
            "Exact dielectric Fresnel",
            _dielectric_kernel,
            inputs=(_COS, _ETA),
            exact=True,
            quantity="fresnel_reflectance",
            formula="F = ½(r_s² + r_p²), TIR → 1",
            source="Fresnel 1823; Born & Wolf §1.5.2; Mitsuba 3 fresnel()",
            description="A dielectric's only (k ignored).",
        ),
        Method(
            "exact-conductor",
            "Exact conductor Fresnel",
            _conductor_kernel,
            inputs=_IOR,
            exact=True,
            quantity="fresnel_reflectance",
            formula="F = ½(R_s + R_p) for η̂ = η + ik",
            source="Born & Wolf §14.2; PBRT 3 §8.2.1; Mitsuba 3 fresnel_conductor()",
            description="Exact for conductors and (k = 0) dielectrics, TIR included.",
        ),
    ]
)
"""The Fresnel family's methods (module docstring); quantity ``fresnel_reflectance``."""
