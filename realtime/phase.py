r"""Phase functions of participating media, written once for every family (sky, fog, lights in fog).

All are normalised over the sphere (∫ p dω = 1, unit sr⁻¹) and take ``cos_gamma`` = cos γ, γ the
scattering angle between the direction of propagation and the scattered direction (γ = 0: forward).

* Rayleigh:          p_R(γ) = 3/(16π) · (1 + cos²γ)
* Henyey–Greenstein: p_HG(γ, g) = (1 − g²) / (4π (1 + g² − 2g cos γ)^{3/2}),  g ∈ (−1, 1) the mean cosine
  (Henyey & Greenstein 1941, ApJ 93, 70)
* Cornette–Shanks:   p_CS(γ, g) = 3(1 − g²)(1 + cos²γ) / (8π (2 + g²)(1 + g² − 2g cos γ)^{3/2})
  (Cornette & Shanks 1992, Appl. Opt. 31(16), eq. 4; the Mie form of Nishita 1993 and seed 002)

Guard: the denominator 1 + g² − 2g cos γ = (1 − g)² at γ = 0 vanishes as g → 1; it is floored at 1e-12 so
that the kernels stay finite for every g and cos γ (the value is then 1/(4π·1e-18)·(1 − g²), i.e. exact
down to (1 − g) = 1e-6). Public functions accept g ∈ [−0.999, 0.999] and cos γ ∈ [−1, 1] (±1e-4 rounding
slack, clamped).

The kernels (``*_kernel(ops, c, g)``) are public: the sky, fog and light-cone kernels call them inside
their own kernel text, so one formula serves Dr.Jit, NumPy and JAX.
"""

from __future__ import annotations

import math

from .arrays import check_range, evaluate

__all__ = [
    "cornette_shanks_phase",
    "cornette_shanks_phase_kernel",
    "hg_phase",
    "hg_phase_kernel",
    "rayleigh_phase",
    "rayleigh_phase_kernel",
]

_DEN_FLOOR = 1e-12  # keeps (1 + g² − 2g cos γ)^{3/2} > 0 as g → ±1 (see the module docstring)


def rayleigh_phase_kernel(ops, c):
    """3/(16π)(1 + c²)."""
    return (3.0 / (16.0 * math.pi)) * (1.0 + c * c)


def hg_phase_kernel(ops, c, g):
    """(1 − g²)/(4π d^{3/2}), d = max(1 + g² − 2gc, 1e-12)."""
    den = ops.maximum(1.0 + g * g - 2.0 * g * c, _DEN_FLOOR)
    return (1.0 - g * g) / (4.0 * math.pi * den * ops.sqrt(den))


def cornette_shanks_phase_kernel(ops, c, g):
    """3(1 − g²)(1 + c²)/(8π(2 + g²) d^{3/2}), d = max(1 + g² − 2gc, 1e-12)."""
    den = ops.maximum(1.0 + g * g - 2.0 * g * c, _DEN_FLOOR)
    return 3.0 * (1.0 - g * g) * (1.0 + c * c) / (8.0 * math.pi * (2.0 + g * g) * den * ops.sqrt(den))


def _cos(cos_gamma):
    return check_range("cos_gamma", cos_gamma, -1.0001, 1.0001, interval="[-1, 1]")


def _g(g):
    return check_range("g", g, -0.999, 0.999)


def rayleigh_phase(cos_gamma):
    """p_R(γ) = 3/(16π)(1 + cos²γ) (sr⁻¹)."""
    return evaluate(lambda o, c: rayleigh_phase_kernel(o, o.clip(c, -1.0, 1.0)), _cos(cos_gamma))


def hg_phase(cos_gamma, g):
    """Henyey–Greenstein p_HG(γ, g) (sr⁻¹), g ∈ [−0.999, 0.999]."""
    return evaluate(lambda o, c, gg: hg_phase_kernel(o, o.clip(c, -1.0, 1.0), gg), _cos(cos_gamma), _g(g))


def cornette_shanks_phase(cos_gamma, g):
    """Cornette–Shanks p_CS(γ, g) (sr⁻¹), g ∈ [−0.999, 0.999]."""
    return evaluate(
        lambda o, c, gg: cornette_shanks_phase_kernel(o, o.clip(c, -1.0, 1.0), gg), _cos(cos_gamma), _g(g)
    )
