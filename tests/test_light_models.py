"""The diffuse family's light models (`rtfit.realtime.light_models`), each against an independent computation.

Oracles: closed forms (the inverse-square law; the windows' and cones' values at chosen points; the
configuration factor of a parallel rectangle, Howell's catalogue B-3), Gauss quadrature of the rectangle's
irradiance over its horizon-clipped area (a 2-D area integral, not the contour sum the polygon row
evaluates), a midpoint quadrature of a sphere light's cap of directions, and Mitsuba's own direct
irradiance of tiny scenes through `rtfit.audit`. Stability at the extremes (d → 0, grazing, below the
horizon, a point on the light) is drawn by hypothesis: no NaN or Inf on NumPy float64 or Dr.Jit float32."""

from __future__ import annotations

import itertools
import math

import drjit as dr
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import rtfit
from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.diffuse import METHODS as DIFFUSE
from rtfit.realtime.light_models import D0, METHODS

POLY = METHODS["polygon"]
AXES = "xyz"


def _poly_inputs(p, n, c, u, v, radiance=1.0):
    out = {}
    for name, vec in (("p", p), ("n", n), ("lc", c), ("lu", u), ("lv", v)):
        vec = np.asarray(vec, np.float64)
        for k, a in enumerate(AXES):
            out[f"{name}{a}"] = vec[..., k]
    out["radiance"] = radiance
    return out


# ---------------------------------------------------------------------------------------- quadrature oracle
def _clip(poly: list[np.ndarray], keep) -> list[np.ndarray]:
    """Sutherland–Hodgman: the part of a convex polygon (3-D points) where the affine ``keep(q)`` ≥ 0."""
    out = []
    for i, a in enumerate(poly):
        b = poly[(i + 1) % len(poly)]
        ka, kb = keep(a), keep(b)
        if ka >= 0:
            out.append(a)
        if (ka >= 0) != (kb >= 0):
            out.append(a + (b - a) * (ka / (ka - kb)))
    return out


def _rect_quadrature(p, n, c, u, v, radiance=1.0, order=24) -> float:
    """E = L ∫_A max(n·ω, 0) cos θ_l / r² dA over the rectangle's part above x's horizon and in front of
    the light (clipped exactly, so the integrand is smooth), fan-triangulated, each triangle by a Duffy
    map of ``order``² Gauss–Legendre points."""
    nl = np.cross(u, v)
    nl /= np.linalg.norm(nl)
    if np.dot(p - c, nl) <= 0:  # behind a one-sided light
        return 0.0
    corners = [c - u - v, c + u - v, c + u + v, c - u + v]
    poly = _clip(corners, lambda q: float(np.dot(n, q - p)))
    if len(poly) < 3:
        return 0.0
    x, w = np.polynomial.legendre.leggauss(order)
    s, ws = (x + 1) / 2, w / 2
    xi, eta = np.meshgrid(s, s, indexing="ij")
    wt = np.outer(ws, ws) * xi
    total = 0.0
    for k in range(1, len(poly) - 1):
        a, b, cc = poly[0], poly[k], poly[k + 1]
        q = a + xi[..., None] * (b - a) + (xi * eta)[..., None] * (cc - b)
        jac = np.linalg.norm(np.cross(b - a, cc - b))
        d = q - p
        r2 = np.sum(d * d, axis=-1)
        r = np.sqrt(r2)
        cos_r = np.maximum(d @ n, 0.0) / r
        cos_l = np.maximum(-(d @ nl), 0.0) / r
        total += jac * float(np.sum(wt * cos_r * cos_l / r2))
    return radiance * total


def _random_configs(count: int, seed: int = 7):
    """Random rectangles and points, at least 0.3 × the rectangle's half-diagonal from it (the quadrature's
    integrand stays smooth): ~1/3 of them straddle the point's horizon."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        p = rng.uniform(-1, 1, 3)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        c = rng.uniform(-2, 2, 3)
        u, v = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)
        half = math.sqrt(float(u @ u + v @ v))
        corners = [c - u - v, c + u - v, c + u + v, c - u + v]
        dist = min(np.linalg.norm(q - p) for q in [*corners, c])
        nl = np.cross(u, v)
        if np.linalg.norm(nl) < 0.05 or dist < 0.3 * half or np.dot(p - c, nl) <= 0.05 * np.linalg.norm(nl):
            continue
        out.append((p, n, c, u, v))
    return out


def test_polygon_is_the_quadrature_of_a_rectangle_light_at_200_configurations():
    """The polygon (LTC-diffuse) row, NumPy float64, against the area quadrature at 200 configurations of
    which ≥ 50 are partly below the point's horizon and ≥ 10 wholly below: ≤ 1e-9 of the light's
    unclipped irradiance scale L·(projected solid angle) — measured 6e-11, the quadrature's own error (it
    falls from 2e-4 to 5e-8 to 6e-11 at 24², 48², 96² points per triangle on the clipped cases)."""
    configs = _random_configs(200)
    straddle = below = 0
    worst = 0.0
    for p, n, c, u, v in configs:
        h = [float(n @ (q - p)) for q in (c - u - v, c + u - v, c + u + v, c - u + v)]
        straddle += min(h) < 0 < max(h)
        below += max(h) <= 0
        order = 96 if min(h) < 0 < max(h) else 24  # the clipped region reaches close to x
        want = _rect_quadrature(p, n, c, u, v, radiance=2.5, order=order)
        got = float(POLY(NUMPY_OPS, _poly_inputs(p, n, c, u, v, 2.5)))
        scale = 2.5 * _rect_quadrature(p, -n if max(h) <= 0 else n, c, u, v) + 1e-12
        worst = max(worst, abs(got - want) / scale)
    assert straddle >= 50 and below >= 10, (straddle, below)
    assert worst < 1e-9, worst


def test_polygon_in_drjit_float32_matches_the_quadrature():
    """The same text on Dr.Jit float32 (LLVM): ≤ 2e-5 of the value's scale at these distances (the edge terms
    cancel; module docstring, Accuracy)."""
    configs = _random_configs(120, seed=11)
    ins = _poly_inputs(*(np.array([cfg[k] for cfg in configs]) for k in range(5)), radiance=1.0)
    got = POLY(
        __import__("rtfit.realtime.arrays", fromlist=["DRJIT_OPS"]).DRJIT_OPS,
        {
            k: dr.llvm.Float(np.broadcast_to(np.asarray(x, np.float32), (len(configs),)))
            for k, x in ins.items()
        },
    )
    got = np.asarray(got, np.float64)
    want = np.array([_rect_quadrature(*cfg) for cfg in configs])
    assert np.max(np.abs(got - want)) < 2e-5 * max(want.max(), 1e-3)


def test_polygon_under_a_parallel_rectangle_is_the_configuration_factor():
    """A point under the centre of a parallel rectangle 2a × 2b at height h: E = 4 L F(a/h, b/h) π, with the
    differential-area-to-rectangle factor F(A, B) = (1/2π)[A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²)
    atan(A/√(1+B²))] (Howell, A catalog of radiation configuration factors, B-3)."""

    def factor(a, b):
        sa, sb = math.sqrt(1 + a * a), math.sqrt(1 + b * b)
        return (a / sa * math.atan(b / sa) + b / sb * math.atan(a / sb)) / (2 * math.pi)

    for a, b, h in ((1.0, 1.0, 1.0), (0.3, 2.0, 0.7), (5.0, 0.1, 3.0), (0.01, 0.02, 10.0)):
        # light above the point facing down: u × v = −z
        ins = _poly_inputs((0, 0, 0), (0, 0, 1), (0, 0, h), (0, a, 0), (b, 0, 0), radiance=3.0)
        want = 3.0 * 4.0 * math.pi * factor(a / h, b / h)
        assert float(POLY(NUMPY_OPS, ins)) == pytest.approx(want, rel=1e-12)
        flipped = _poly_inputs((0, 0, 0), (0, 0, 1), (0, 0, h), (a, 0, 0), (0, b, 0), radiance=3.0)
        assert float(POLY(NUMPY_OPS, flipped)) == 0.0  # one-sided: emitting upwards, away from the point


# ------------------------------------------------------------------------------------------------- discs
DISC = METHODS["disc"]


def _disc_inputs(p, n, c, m, radius, radiance=1.0):
    out = {}
    for name, vec in (("p", p), ("n", n), ("dc", c), ("dm", m)):
        vec = np.asarray(vec, np.float64)
        for k, a in enumerate(AXES):
            out[f"{name}{a}"] = vec[..., k]
    return out | {"disc_radius": radius, "radiance": radiance}


def _disc(p, n, c, m, radius, radiance=1.0) -> float:
    return float(DISC(NUMPY_OPS, _disc_inputs(p, n, c, m, radius, radiance)))


def _frame(m):
    a = np.array([1.0, 0.0, 0.0]) if abs(m[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(m, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(m, e1)


def _disc_quadrature(p, n, c, m, radius, radiance=1.0, order=96, vector=False):
    """E = L ∫_disc max(n·ω, 0) cos θ_l / r² dA in polar coordinates (r, φ) about the centre, over the part
    above x's horizon: per φ the clipped radial interval [r₀, r₁] exactly (n·(q − x) is linear in r), φ
    split at the two angles where the horizon crosses the rim, ``order`` Gauss–Legendre points in r and in
    φ on each arc. ``vector``: the unclipped vector form factor ∫ ω dω instead (sr, a 3-vector)."""
    h = float(m @ (p - c))
    if h <= 0:
        return np.zeros(3) if vector else 0.0
    e1, e2 = _frame(m)
    a, b1, b2 = float(n @ (c - p)), float(n @ e1), float(n @ e2)
    cuts = [0.0, 2 * math.pi]
    rn = math.hypot(b1, b2)
    if not vector and rn * radius > abs(a):
        phi0, half = math.atan2(b2, b1), math.acos(-a / (radius * rn))
        cuts = sorted([*cuts, (phi0 + half) % (2 * math.pi), (phi0 - half) % (2 * math.pi)])
    x, w = np.polynomial.legendre.leggauss(order)
    total = np.zeros(3) if vector else 0.0
    for lo, hi in itertools.pairwise(cuts):
        phi = lo + (hi - lo) * (x + 1) / 2
        e = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2  # (φ, 3)
        b = e @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(b != 0, -a / b, np.inf)
        r0 = np.where(b > 0, np.clip(t, 0.0, radius), 0.0)
        r1 = np.where(b < 0, np.clip(t, 0.0, radius), radius)
        if vector:
            r0, r1 = np.zeros_like(b), np.full_like(b, radius)
        r1 = np.where((b == 0) & (a < 0), 0.0, np.maximum(r1, r0))
        r = r0[:, None] + (r1 - r0)[:, None] * (x + 1) / 2  # (φ, r)
        q = c + r[..., None] * e[:, None, :]
        d = q - p
        d2 = np.sum(d * d, axis=-1)
        wt = (w * (hi - lo) / 2)[:, None] * (w[None, :] * (r1 - r0)[:, None] / 2) * r * h / d2**2
        if vector:
            total = total + np.sum(wt[..., None] * d, axis=(0, 1))
        else:
            total += float(np.sum(wt * np.maximum(d @ n, 0.0)))
    return total if vector else radiance * total


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _disc_configs(count: int, where: str, seed: int):
    """Random discs (R ∈ [0.1, 1.5]) and points in front of them, at least 0.3 R from the disc (a smooth
    integrand), with the disc wholly above (``above``) or across (``across``) the point's horizon."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        p, n = rng.uniform(-1, 1, 3), _unit(rng.normal(size=3))
        c, m, radius = rng.uniform(-2, 2, 3), _unit(rng.normal(size=3)), float(rng.uniform(0.1, 1.5))
        h = float(m @ (p - c))
        rho = float(np.linalg.norm(p - c - h * m))
        if h < 0.05 or math.hypot(h, max(rho - radius, 0.0)) < 0.3 * radius:
            continue
        hn, reach = float(n @ (c - p)), radius * float(np.linalg.norm(np.cross(n, m)))
        if (where == "above" and hn >= reach) or (where == "across" and -reach < hn < reach):
            out.append((p, n, c, m, radius))
    return out


def test_disc_is_the_quadrature_of_a_disc_light_wholly_above_the_horizon():
    """The disc row, NumPy float64, against the polar quadrature at 120 random configurations with the disc
    wholly above the point's horizon: ≤ 1e-6 relative (measured 5.6e-10 at 96² points, the quadrature's own
    error: 2.8e-6 at 48²). Dr.Jit float32 (LLVM) at the same configurations: ≤ 5e-6 relative (measured
    1.0e-6: no edge terms cancelling as in the polygon)."""
    from rtfit.realtime.arrays import DRJIT_OPS

    configs = _disc_configs(120, "above", seed=3)
    want = np.array([_disc_quadrature(*cfg, radiance=2.0) for cfg in configs])
    got = np.array([_disc(*cfg, radiance=2.0) for cfg in configs])
    assert np.all(want > 0)
    assert np.max(np.abs(got - want) / want) < 1e-6
    ins = _disc_inputs(*(np.array([cfg[k] for cfg in configs]) for k in range(5)), radiance=2.0)
    e32 = DISC(
        DRJIT_OPS,
        {k: dr.llvm.Float(np.broadcast_to(np.asarray(v, np.float32), len(configs))) for k, v in ins.items()},
    )
    assert np.max(np.abs(np.asarray(e32, np.float64) - want) / want) < 5e-6


def test_disc_across_the_horizon_is_the_sphere_cap_stand_in_with_its_error_bounded():
    """Across the horizon the row is the published sphere-cap stand-in (approximate): against the quadrature
    of the clipped disc at 150 configurations its error is ≤ 9 % of L|F| (measured here 5.1 %, rms 1.3 %;
    8.4 %, rms 1.3 % over 400), |F| the unclipped vector form factor by quadrature; and it is exactly the
    exact sphere-light row at the cap sin²α = |F|/π, cos ω = n·F/|F| (the one text it reads). At the seam
    (the rim touching the horizon) the row jumps by ≤ 1.1 % of L|F| (measured 1.0 % over 200)."""
    configs = _disc_configs(150, "across", seed=4)
    errs, exact_rows = [], []
    for p, n, c, m, radius in configs:
        f = _disc_quadrature(p, n, c, m, radius, vector=True)
        ff = float(np.linalg.norm(f))
        got = _disc(p, n, c, m, radius, radiance=1.5)
        errs.append((got - _disc_quadrature(p, n, c, m, radius, radiance=1.5)) / (1.5 * ff))
        alpha = math.asin(math.sqrt(ff / math.pi))
        exact_rows.append(
            (
                got,
                float(
                    DIFFUSE["exact"](
                        NUMPY_OPS, {"cos_theta": float(n @ f) / ff, "alpha": alpha, "radiance": 1.5}
                    )
                ),
            )
        )
    errs = np.abs(np.array(errs))
    assert errs.max() < 0.09 and np.sqrt(np.mean(errs**2)) < 0.02, (errs.max(), np.sqrt(np.mean(errs**2)))
    assert errs.max() > 0.01  # an approximation: it is not the clipped disc
    got, cap = np.array(exact_rows).T
    assert np.allclose(got, cap, rtol=1e-6, atol=1e-9 * cap.max())
    rng = np.random.default_rng(5)
    jumps = []
    while len(jumps) < 60:
        p, n = rng.uniform(-1, 1, 3), _unit(rng.normal(size=3))
        c, m, radius = rng.uniform(-2, 2, 3), _unit(rng.normal(size=3)), float(rng.uniform(0.1, 1.5))
        p = p + (float(n @ (c - p)) - radius * float(np.linalg.norm(np.cross(n, m)))) * n  # on the seam
        if float(m @ (p - c)) < 0.05:
            continue
        ff = float(np.linalg.norm(_disc_quadrature(p, n, c, m, radius, order=48, vector=True)))
        jumps.append(abs(_disc(p + 1e-9 * n, n, c, m, radius) - _disc(p - 1e-9 * n, n, c, m, radius)) / ff)
    assert max(jumps) < 0.011, max(jumps)


def test_disc_on_its_axis_and_as_a_point():
    """On the axis, facing the disc: E = πL R²/(h² + R²) (exact, ≤ 1e-14 relative); facing away, behind the
    light, or tilted so the disc is wholly below: 0. R → 0: the punctual row with I = L·πR²·cos θ_l, with a
    relative difference of order (R/d)² (≤ 2 (R/d)² here)."""
    for h, radius in ((1.0, 1.0), (0.01, 3.0), (50.0, 0.2), (1e-3, 1e3)):
        want = math.pi * radius**2 / (h * h + radius * radius)
        got = _disc((0, 0, 0), (0, 0, 1), (0, 0, h), (0, 0, -1), radius, radiance=1.0)
        assert got == pytest.approx(want, rel=1e-14)
        assert _disc((0, 0, 0), (0, 0, -1), (0, 0, h), (0, 0, -1), radius) == 0.0  # facing away
        assert _disc((0, 0, 0), (0, 0, 1), (0, 0, h), (0, 0, 1), radius) == 0.0  # behind a one-sided light
    assert _disc((0, 0, 0), (1, 0, 0), (-1, 0, 1), (0, 0, -1), 0.5) == 0.0  # wholly below
    p, n, c, m = np.zeros(3), _unit([0.3, -0.2, 1.0]), np.array([0.7, 0.4, 2.0]), _unit([-0.2, 0.1, -1.0])
    d = float(np.linalg.norm(c - p))
    t = (c - p) / d
    for radius in (1e-1, 1e-2, 1e-3):
        punct = float(
            METHODS["punctual"](
                NUMPY_OPS,
                {
                    "cos_theta": float(n @ t),
                    "distance": d,
                    "intensity": 2.0 * math.pi * radius**2 * float(-m @ t),
                },
            )
        )
        assert abs(_disc(p, n, c, m, radius, 2.0) / punct - 1) < 2 * (radius / d) ** 2


# ------------------------------------------------------------------------------------------- closed forms
def test_punctual_and_windows_closed_forms():
    """Inverse square: I cos θ/d²; the windows at d = r/2: (1 − 1/16)² = 0.87890625 times the inverse
    square (Unreal with d² + (1 cm)², Frostbite with max(d², (1 cm)²)), 0 for d ≥ r; the two windows are one
    function of d/r."""
    ev = {k: METHODS[k] for k in ("punctual", "unreal-window", "frostbite-window")}
    base = {"cos_theta": 0.6, "distance": 2.0, "intensity": 5.0}
    assert float(ev["punctual"](NUMPY_OPS, base)) == pytest.approx(5.0 * 0.6 / 4.0, rel=1e-15)
    w = (1 - 1 / 16) ** 2
    assert float(ev["unreal-window"](NUMPY_OPS, base, {"r": 4.0})) == pytest.approx(
        5.0 * 0.6 * w / (4.0 + D0**2), rel=1e-14
    )
    assert float(ev["frostbite-window"](NUMPY_OPS, base, {"r": 4.0})) == pytest.approx(
        5.0 * 0.6 * w / 4.0, rel=1e-14
    )
    for k in ("unreal-window", "frostbite-window"):
        assert float(ev[k](NUMPY_OPS, base, {"r": 2.0})) == 0.0
        assert float(ev[k](NUMPY_OPS, {**base, "cos_theta": -0.2}, {"r": 4.0})) == 0.0
    near = {"cos_theta": 1.0, "distance": 0.001, "intensity": 1.0}
    assert float(ev["frostbite-window"](NUMPY_OPS, near, {"r": 1.0})) == pytest.approx(1e4, rel=1e-9)
    assert float(ev["unreal-window"](NUMPY_OPS, near, {"r": 1.0})) == pytest.approx(
        1 / (1e-6 + 1e-4), rel=1e-9
    )


def test_spot_profiles_at_their_defining_points():
    """Mitsuba's profile is 1 at the beam, 0 at the cutoff, ½ half-way in angle; smoothstep is ½ and the
    squared ramp ¼ half-way in cosine; all are 1 inside the beam and 0 outside the cutoff."""
    cut, beam = math.radians(40), math.radians(30)
    base = {"cos_theta": 1.0, "distance": 1.0, "axis_intensity": 2.0, "cutoff": cut, "beam": beam}

    def f(mid, cos_axis):
        return float(METHODS[mid](NUMPY_OPS, {**base, "cos_axis": cos_axis})) / 2.0

    assert f("spot-linear", math.cos(math.radians(35))) == pytest.approx(0.5, rel=1e-12)
    mid_cos = (math.cos(cut) + math.cos(beam)) / 2
    assert f("spot-smoothstep", mid_cos) == pytest.approx(0.5, rel=1e-12)
    assert f("spot-squared", mid_cos) == pytest.approx(0.25, rel=1e-12)
    for mid in ("spot-linear", "spot-smoothstep", "spot-squared"):
        assert f(mid, math.cos(math.radians(10))) == 1.0
        assert f(mid, math.cos(math.radians(45))) == 0.0
    hard = {**base, "beam": cut}  # no transition: a hard cone
    for mid in ("spot-linear", "spot-smoothstep", "spot-squared"):
        assert float(METHODS[mid](NUMPY_OPS, {**hard, "cos_axis": math.cos(math.radians(39))})) == 2.0
        assert float(METHODS[mid](NUMPY_OPS, {**hard, "cos_axis": math.cos(math.radians(41))})) == 0.0


def _cap(cos_theta: float, alpha: float, n: int = 400) -> float:
    """∫_cap max(n·ω, 0) dω by the midpoint rule on (γ, φ) in the cap's frame (radiance 1)."""
    g = (np.arange(n) + 0.5) * alpha / n
    phi = (np.arange(2 * n) + 0.5) * math.pi / n
    gg, pp = np.meshgrid(g, phi, indexing="ij")
    s = math.sqrt(max(1.0 - cos_theta**2, 0.0))
    ndotw = s * np.sin(gg) * np.cos(pp) + cos_theta * np.cos(gg)
    return float(np.sum(np.maximum(ndotw, 0.0) * np.sin(gg)) * (alpha / n) * (math.pi / n))


@pytest.mark.parametrize("alpha_deg", [2.0, 15.0, 40.0])
def test_representative_point_is_the_sphere_irradiance_above_the_horizon(alpha_deg):
    """Above the horizon (cos θ ≥ sin α) the representative point (and the punctual row with I = π r² L)
    is the cap quadrature; across the horizon band its smooth wrap errs by ≤ 13 % of π sin²α L (measured:
    0.6 %, 4.6 %, 12 % at α = 2°, 15°, 40°); below, both are 0."""
    a = math.radians(alpha_deg)
    rep = METHODS["representative-point"]
    peak = math.pi * math.sin(a) ** 2
    worst_band = 0.0
    for theta in np.radians(np.linspace(0, 180, 91)):
        c = math.cos(theta)
        got = float(rep(NUMPY_OPS, {"cos_theta": c, "alpha": a, "radiance": 1.0}))
        want = _cap(c, a)
        d, r = 1.0, math.sin(a)  # a sphere of radius sin α at distance 1
        punct = float(
            METHODS["punctual"](NUMPY_OPS, {"cos_theta": c, "distance": d, "intensity": math.pi * r * r})
        )
        if c >= math.sin(a) + 1e-9:
            assert got == pytest.approx(want, rel=2e-4)
            assert punct == pytest.approx(want, rel=2e-4)
        elif c <= -math.sin(a):
            assert got == 0.0 and want == pytest.approx(0.0, abs=1e-12)
        else:
            worst_band = max(worst_band, abs(got - want) / peak)
    assert worst_band < 0.13


# ---------------------------------------------------------------------------------- stability (hypothesis)
_F = st.floats(-3.0, 3.0, allow_nan=False, allow_subnormal=False)


@settings(max_examples=150, deadline=None)
@given(
    p=st.tuples(_F, _F, _F),
    n=st.tuples(_F, _F, _F),
    u=st.tuples(_F, _F, _F),
    v=st.tuples(_F, _F, _F),
    on=st.sampled_from(["free", "centre", "corner", "edge", "plane"]),
)
def test_polygon_is_finite_and_non_negative_everywhere(p, n, u, v, on):
    """A point anywhere — on the light's centre, a corner, an edge, in its plane — with any normal (zero
    included) and any (degenerate) rectangle: finite, ≥ 0, on NumPy float64 and Dr.Jit float32."""
    c = np.array([0.1, -0.2, 0.3])
    u_, v_ = np.array(u), np.array(v)
    x = {
        "free": np.array(p),
        "centre": c,
        "corner": c + u_ + v_,
        "edge": c + u_ * 0.3 - v_,
        "plane": c + 0.7 * u_ + 2.0 * v_,
    }[on]
    ins = _poly_inputs(x, n, c, u_, v_, radiance=1.0)
    e64 = float(POLY(NUMPY_OPS, ins))
    from rtfit.realtime.arrays import DRJIT_OPS

    e32 = POLY(DRJIT_OPS, {k: dr.llvm.Float(float(val)) for k, val in ins.items()})
    assert math.isfinite(e64) and e64 >= 0.0
    assert all(math.isfinite(float(t)) and float(t) >= 0.0 for t in np.asarray(e32).ravel())
    assert e64 <= math.pi + 1e-9  # never more than a whole hemisphere of radiance 1


_BIG = st.floats(-1e30, 1e30, allow_nan=False, allow_subnormal=False)


@settings(max_examples=150, deadline=None)
@given(
    p=st.tuples(_F, _F, _F),
    n=st.tuples(_F, _F, _F),
    m=st.tuples(_F, _F, _F),
    radius=st.one_of(st.just(0.0), st.floats(0.0, 1e30, allow_subnormal=False)),
    on=st.sampled_from(["free", "centre", "rim", "rim-plane", "plane-inside", "far"]),
    far=_BIG,
)
def test_disc_is_finite_and_bounded_everywhere(p, n, m, radius, on, far):
    """A point anywhere — at the centre, on the rim, in the disc's plane outside or inside it, 1e30 away —
    with any normal (zero included), any disc normal (zero included) and any radius from 0 to 1e30: finite,
    0 ≤ E ≤ πL, on NumPy float64 and Dr.Jit float32."""
    from rtfit.realtime.arrays import DRJIT_OPS

    c = np.array([0.1, -0.2, 0.3])
    m_ = np.array(m)
    e1 = _frame(_unit(m_))[0] if np.linalg.norm(m_) > 1e-6 else np.array([1.0, 0.0, 0.0])
    x = {
        "free": np.array(p),
        "centre": c,
        "rim": c + radius * e1,
        "rim-plane": c + 2.0 * radius * e1,
        "plane-inside": c + 0.5 * radius * e1,
        "far": c + np.array([far, 0.5 * far, -far]),
    }[on]
    if not np.all(np.isfinite(x)):
        return
    ins = _disc_inputs(x, n, c, m_, radius, radiance=1.0)
    e64 = float(DISC(NUMPY_OPS, ins))
    e32 = DISC(DRJIT_OPS, {k: dr.llvm.Float(float(val)) for k, val in ins.items()})
    assert math.isfinite(e64) and 0.0 <= e64 <= math.pi * (1 + 1e-12)
    v32 = float(np.asarray(e32).ravel()[0])
    assert math.isfinite(v32) and 0.0 <= v32 <= math.pi * (1 + 1e-6)


@settings(max_examples=150, deadline=None)
@given(
    cos_theta=st.floats(-1.0, 1.0),
    distance=st.one_of(st.just(0.0), st.floats(0.0, 1e4, allow_subnormal=False)),
    alpha=st.floats(0.0, math.pi / 2),
    cos_axis=st.floats(-1.0, 1.0),
    r=st.one_of(st.just(0.0), st.floats(0.0, 1e4, allow_subnormal=False)),
    beam=st.floats(0.0, 1.5),
)
def test_point_models_are_finite_at_the_extremes(cos_theta, distance, alpha, cos_axis, r, beam):
    """d → 0 (at the light's centre), grazing and below-horizon cosines, r = 0, a beam filling the cone:
    every light model except the polygon is finite and ≥ 0 on NumPy float64 and Dr.Jit float32."""
    from rtfit.realtime.arrays import DRJIT_OPS

    inputs = {
        "cos_theta": cos_theta, "distance": distance, "intensity": 10.0, "axis_intensity": 10.0,
        "alpha": alpha, "radiance": 1.0, "cos_axis": cos_axis, "cutoff": 0.8, "beam": min(beam, 0.8),
    }  # fmt: skip
    for mid, m in METHODS.items():
        if mid in ("polygon", "disc", "tube"):  # their own tests below/above
            continue
        params = {"r": r} if m.params else None
        ins = {k: inputs[k] for k in m.input_names}
        e64 = float(m(NUMPY_OPS, ins, params))
        e32 = m(DRJIT_OPS, {k: dr.llvm.Float(val) for k, val in ins.items()}, params)
        assert math.isfinite(e64) and e64 >= 0.0, (mid, e64)
        v32 = float(np.asarray(e32).ravel()[0])
        assert math.isfinite(v32) and v32 >= 0.0, (mid, v32)


# --------------------------------------------------------------------------------------------- Mitsuba
_SCENE = """
name = "light-models"
[camera]
origin = [0.0, -0.01, 6.0]
target = [0.0, 0.0, 0.0]
fov_deg = 30.0
width = 8
height = 8
[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [6.0, 6.0]
{lights}
"""


def _audit(tmp_path, name: str, lights: str, spp: int = 16):
    path = tmp_path / f"{name}.toml"
    path.write_text(_SCENE.format(lights=lights))
    return rtfit.audit(path, "diffuse", spp=spp, cache=tmp_path / "c", metrics=("rmse",), fit=False)


def _rect(h: float) -> str:
    return f"""[[lights]]
type = "rect_light"
center = [1.0, 0.5, {h}]
normal = [0.2, 0.0, -1.0]
size = [0.8, 0.4]
radiance = 4.0
"""


def test_mitsuba_rectangle_light_inverse_square_converges_and_polygon_is_exact(tmp_path):
    """Mitsuba's direct irradiance of a rectangle light (one-sided, emitter sampling) at h = 0.6 and 12: the
    polygon row is the area quadrature at the case's own points (inputs from the light's parameters), the
    reference's mean difference from it is within 4 standard errors (no bias), and the punctual row's
    relative error falls as (size/d)²: > 1 % at h = 0.6, < 0.1 % at h = 12."""
    errors = {}
    for h in (0.6, 12.0):
        r = _audit(tmp_path, f"rect{h}", _rect(h))
        case = r.cases[0]
        assert {"punctual", "polygon"} <= set(r.outcomes[case.id])
        ci = case.channel_inputs[0]
        pts = np.stack([ci[f"p{a}"] for a in AXES], 1)
        nrm = np.stack([ci[f"n{a}"] for a in AXES], 1)
        c, u, v = (np.array([ci[f"{k}{a}"] for a in AXES]) for k in ("lc", "lu", "lv"))
        half = sorted([float(np.linalg.norm(u)), float(np.linalg.norm(v))])
        assert np.allclose(half, [0.2, 0.4], rtol=1e-6) and np.allclose(c, [1.0, 0.5, h], rtol=1e-6)
        quad = np.array(
            [_rect_quadrature(pts[i], nrm[i], c, u, v, ci["radiance"], 48) for i in range(len(pts))]
        )
        poly = r.image(case.id, "polygon")[case.mask][:, 0]
        assert np.max(np.abs(poly - quad)) < 1e-5 * quad.max()
        ref = case.reference.mean[case.mask][:, 0]
        err = case.reference.stderr[case.mask][:, 0]
        assert abs(float(np.mean(ref - poly))) < 4 * float(np.sqrt(np.sum(err**2))) / len(ref)
        punct = r.image(case.id, "punctual")[case.mask][:, 0]
        errors[h] = float(np.sqrt(np.mean((punct - poly) ** 2)) / np.sqrt(np.mean(poly**2)))
    assert errors[0.6] > 0.01 and errors[12.0] < 1e-3, errors


def test_mitsuba_point_spot_and_sphere_lights_from_their_own_parameters(tmp_path):
    """A point light: the punctual row is Mitsuba's reference (one emitter sample is exact) to float32; a
    spot: Mitsuba's linear profile is its reference to float32 while smoothstep and the squared ramp differ
    inside the transition; a far sphere light (α ≤ 0.6°): the punctual row with I = π r² L is within the
    reference's noise. Rows of other lights' kinds are left out, and the case says so."""
    lights = """
[[lights]]
type = "point_light"
position = [0.5, 0.0, 2.0]
intensity = 3.0
[[lights]]
type = "spot_light"
position = [0.0, 0.0, 3.0]
axis = [0.0, 0.0, -1.0]
intensity = 5.0
cutoff_angle_deg = 30
beam_width_deg = 10
[[lights]]
type = "sphere_light"
center = [30.0, 10.0, 40.0]
radius = 0.5
radiance = 100.0
"""
    r = _audit(tmp_path, "mixed", lights)
    by = {c.id: c for c in r.cases}

    def rel(case_id, row):
        case = by[case_id]
        ref = case.reference.mean[case.mask][:, 0]
        img = r.image(case_id, row)[case.mask][:, 0]
        return float(np.max(np.abs(img - ref)) / ref.max())

    assert rel("light0-unshadowed", "punctual") < 1e-5
    assert rel("light1-unshadowed", "spot-linear") < 1e-5
    assert (
        rel("light1-unshadowed", "spot-smoothstep") > 1e-3 and rel("light1-unshadowed", "spot-squared") > 1e-3
    )
    assert "punctual" not in r.outcomes["light1-unshadowed"]
    assert "polygon" not in r.outcomes["light0-unshadowed"]
    assert any(
        "light models left out for this light" in n and "spot" in n for n in by["light0-unshadowed"].notes
    )
    sphere = by["light2-unshadowed"]
    ref = sphere.reference.mean[sphere.mask][:, 0]
    err = sphere.reference.stderr[sphere.mask][:, 0]
    punct = r.image(sphere.id, "punctual")[sphere.mask][:, 0]
    assert np.sqrt(np.mean((punct - ref) ** 2)) < 4 * np.sqrt(np.mean(err**2)) + 1e-6 * ref.max()
    assert np.allclose(sphere.channel_inputs[0]["intensity"], math.pi * 0.25 * 100.0)


_FLOOR_SCENE = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -0.01, 5" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    {lights}
</scene>
"""
"""A 6 × 6 m diffuse floor seen from 5 m above (16² pixels) with the ``lights`` given as shape XML."""
_DISC_XML = _FLOOR_SCENE.replace(
    "{lights}",
    """<shape type="disk" id="lamp">
        <transform name="to_world">
            <scale value="0.4"/><rotate x="1" angle="160"/><translate x="0.3" y="0.2" z="0.5"/>
        </transform>
        <emitter type="area"><rgb name="radiance" value="5, 4, 3"/></emitter>
    </shape>
    {extra}""",
)
_OVAL = """<shape type="disk" id="oval">
        <transform name="to_world">
            <scale x="0.4" y="0.2"/><rotate x="1" angle="180"/><translate z="2"/>
        </transform>
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter>
    </shape>"""


def test_mitsuba_disk_light_audit_runs_the_disc_row(tmp_path):
    """A disk emitter (radius 0.4, tilted 20°, 0.5 above a floor) in a Mitsuba XML scene, 16² × 32 spp: the
    audit runs the disc row from the disk's own to_world (centre, normal, radius) and radiance; it is the
    polar quadrature at the case's points (≤ 1e-5 of the peak: float32), and the reference's mean difference
    from it is within 4 standard errors (no bias); the punctual row is off by > 1 % this close. An
    elliptical disk (scale x ≠ y) gets the punctual rows but not the disc row (left out, saying so)."""
    from rtfit.experiments.applicability import applicable_families
    from rtfit.experiments.audit import inspect_scene

    path = tmp_path / "disc.xml"
    path.write_text(_DISC_XML.format(extra=""))
    r = rtfit.audit(path, "diffuse", spp=32, cache=tmp_path / "c", metrics=("rmse",), fit=False)
    case = next(c for c in r.cases if c.id.endswith("unshadowed"))
    assert {"punctual", "disc"} <= set(r.outcomes[case.id]) and "polygon" not in r.outcomes[case.id]
    ci = case.channel_inputs[0]
    pts = np.stack([ci[f"p{a}"] for a in AXES], 1)
    nrm = np.stack([ci[f"n{a}"] for a in AXES], 1)
    c, m = (np.array([ci[f"{k}{a}"] for a in AXES]) for k in ("dc", "dm"))
    assert np.allclose(c, [0.3, 0.2, 0.5], atol=1e-6) and ci["disc_radius"] == pytest.approx(0.4, rel=1e-6)
    tilt = math.radians(160)
    assert np.allclose(m, [0.0, -math.sin(tilt), math.cos(tilt)], atol=1e-6) and ci["radiance"] == 5.0
    quad = np.array([_disc_quadrature(pts[i], nrm[i], c, m, 0.4, 5.0, order=64) for i in range(len(pts))])
    disc = r.image(case.id, "disc")[case.mask][:, 0]
    assert np.max(np.abs(disc - quad)) < 1e-5 * quad.max()
    ref = case.reference.mean[case.mask][:, 0]
    err = case.reference.stderr[case.mask][:, 0]
    assert abs(float(np.mean(ref - disc))) < 4 * float(np.sqrt(np.sum(err**2))) / len(ref)
    punct = r.image(case.id, "punctual")[case.mask][:, 0]
    assert np.sqrt(np.mean((punct - disc) ** 2)) / np.sqrt(np.mean(disc**2)) > 0.01
    path.write_text(_DISC_XML.format(extra=_OVAL))
    lamp, oval = (a for a in applicable_families(inspect_scene(path), approx="diffuse") if "disk" in a.part)
    assert "disc" in lamp.methods and "disc" not in oval.methods
    assert "punctual" in oval.methods and "circular disk" in dict(oval.excluded)["disc"]


def test_the_diffuse_table_carries_the_light_models_once():
    """`diffuse.METHODS` ends with the light models (one kernel text each, the same objects)."""
    assert [DIFFUSE[k] for k in METHODS] == list(METHODS.values())
    assert METHODS["unreal-window"].unpublished == ("r",) and METHODS["frostbite-window"].unpublished == (
        "r",
    )


def test_mitsubas_various_emitters_get_the_models_their_parameters_allow():
    """Mitsuba's own various-emitters test scene (tests/data/real): a rectangle of uniform radiance gets the
    inverse square, the windows and the polygon; a rectangle whose radiance is a texture, a textured OBJ, a
    spot projecting a texture get none (left out, saying which light each needs); a plain spot gets the
    cones, a point light the inverse square. No rendering: `applicable_families` only."""
    from pathlib import Path

    from rtfit.experiments.applicability import applicable_families
    from rtfit.experiments.audit import inspect_scene

    xml = Path(__file__).parent / "data/real/mitsuba-data/tests/scenes/various_emitters"
    info = inspect_scene(xml / "test_various_emitters_ptracer.xml")
    rows = {a.part.split("'")[1]: a for a in applicable_families(info, approx="diffuse")}
    models = set(METHODS)
    assert models & set(rows["light_1"].methods) == {
        "punctual",
        "unreal-window",
        "frostbite-window",
        "polygon",
    }
    for textured in ("light_1_mesh", "light_2_mesh", "light_2", "light_4"):
        assert not models & set(rows[textured].methods), textured
        assert "polygon" in dict(rows[textured].excluded)
    assert models & set(rows["light_3"].methods) == {"spot-linear", "spot-smoothstep", "spot-squared"}
    assert models & set(rows["light_6"].methods) == {"punctual", "unreal-window", "frostbite-window"}


# ------------------------------------------------------------------------------------------ the tube row
TUBE = METHODS["tube"]


def _tube_inputs(p, n, a, b, r, radiance=1.0):
    out = {"tube_radius": r, "radiance": radiance}
    for name, vec in (("p", p), ("n", n), ("ta", a), ("tb", b)):
        for k, ax in enumerate(AXES):
            out[f"{name}{ax}"] = np.asarray(vec, np.float64)[..., k]
    return out


def _tube_quadrature(p, n, a, b, r, radiance=1.0, ns=96, nphi=128) -> float:
    """E = L ∫ max(cos θ_l, 0) max(cos θ_x, 0)/d² dA over the open cylinder's side (outward normals),
    Gauss–Legendre along the axis × the midpoint rule around it (periodic); visibility ignored."""
    w = b - a
    length = float(np.linalg.norm(w))
    t = w / length
    e1 = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t, e1)
    x, ws = np.polynomial.legendre.leggauss(ns)
    phi = (np.arange(nphi) + 0.5) * 2 * math.pi / nphi
    m = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    q = a + ((x + 1) / 2)[:, None, None] * w + r * m[None]
    d = q - p
    d2 = np.sum(d * d, -1)
    cos_l = np.maximum(-np.sum(d * m[None], -1), 0.0) / np.sqrt(d2)
    cos_x = np.maximum(d @ n, 0.0) / np.sqrt(d2)
    weight = (ws / 2 * length)[:, None] * (2 * math.pi * r / nphi)
    return radiance * float(np.sum(weight * cos_l * cos_x / d2))


def _tube_configs(count: int, seed: int = 3):
    """Tubes of length ℓ ∈ [0.2, 2], r ∈ [0.005, 0.05]ℓ, points at d ∈ [0.3, 30]ℓ (log-uniform) from the
    centre, ≥ 5r from the axis segment, the whole tube above the point's horizon; with d/ℓ and sin ψ (ψ
    between the axis and the direction from the centre to the point)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        length = rng.uniform(0.2, 2.0)
        r = rng.uniform(0.005, 0.05) * length
        a = rng.uniform(-1, 1, 3)
        w = rng.normal(size=3)
        w *= length / np.linalg.norm(w)
        b = a + w
        t = rng.normal(size=3)
        t /= np.linalg.norm(t)
        d = length * math.exp(rng.uniform(math.log(0.3), math.log(30.0)))
        p = (a + b) / 2 + d * t
        s = np.clip((p - a) @ w / length**2, 0.0, 1.0)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        if np.linalg.norm(p - (a + s * w)) < 5 * r or min(n @ (a - p), n @ (b - p)) <= 2 * r:
            continue
        out.append((p, n, a, b, r, d / length, float(np.linalg.norm(np.cross(w / length, t)))))
    return out


def test_tube_is_the_segments_inverse_square_integral():
    """Karis's NoL·falloff is ∫₀¹ n·L(t)/|L(t)|³ dt exactly (1-D Gauss–Legendre, 400 nodes), times 2rLℓ: at
    100 random segments and points, any side of the horizon where the signed integral is positive."""
    rng = np.random.default_rng(11)
    x, ws = np.polynomial.legendre.leggauss(400)
    checked = 0
    for _ in range(100):
        p, n, a, b = (rng.normal(size=3) for _ in range(4))
        n /= np.linalg.norm(n)
        pts = (a - p) + ((x + 1) / 2)[:, None] * (b - a)
        integral = float(np.sum(ws / 2 * (pts @ n) / np.linalg.norm(pts, axis=1) ** 3))
        expect = 2 * 0.01 * 3.0 * np.linalg.norm(b - a) * max(integral, 0.0)
        got = float(TUBE(NUMPY_OPS, _tube_inputs(p, n, a, b, 0.01, 3.0)))
        assert got == pytest.approx(expect, rel=1e-9, abs=1e-12)
        checked += integral > 0
    assert checked > 30


def test_tube_against_quadrature_over_the_cylinder_at_100_configurations():
    """The row against the cylinder's surface quadrature, whole tube above the horizon (docs/diffuse.md, the
    tube row). Its element intensity is the side-on 2rL, a real tube's 2rL|sin ψ|, so tube·sin ψ/E → 1 in
    the thin far field where r ≪ d sin ψ (measured max |·| − 1, sin ψ ≥ 0.3: 0.19 at d/ℓ < 1, 0.043 at 1–3,
    0.012 at 3–10, 0.006 at 10–30; nearly end-on, sin ψ = 0.05 at d = 12ℓ: 0.099, the tube's thickness);
    seen side-on (sin ψ ≥ 0.95) tube/E − 1 ∈ [−0.3 %, +14.5 %] (≤ 4.0 % at d ≥ ℓ); tube/E itself is
    unbounded end-on (max 20.4 here)."""
    rel, far, side = [], [], []
    for p, n, a, b, r, d_l, sin_psi in _tube_configs(100):
        e = _tube_quadrature(p, n, a, b, r)
        k = float(TUBE(NUMPY_OPS, _tube_inputs(p, n, a, b, r)))
        rel.append(abs(k * sin_psi / e - 1))
        if sin_psi >= 0.3 and d_l >= 3:
            far.append((d_l, rel[-1]))
        if sin_psi >= 0.95:
            side.append((d_l, k / e - 1))
    assert max(rel) < 0.25 and all(x < (0.01 if d >= 10 else 0.02) for d, x in far) and len(far) > 20
    assert all(-0.005 < x < 0.16 for _, x in side) and all(x < 0.055 for d, x in side if d >= 1)


@settings(max_examples=150, deadline=None)
@given(
    st.tuples(*[st.floats(-2, 2)] * 3),
    st.tuples(*[st.floats(-1, 1)] * 3),
    st.tuples(*[st.floats(-2, 2)] * 3),
    st.tuples(*[st.floats(-2, 2)] * 3),
    st.floats(0.0, 0.5),
    st.sampled_from(["free", "on-axis", "on-end", "zero-length", "away"]),
)
def test_tube_is_finite_and_non_negative_everywhere(p, n, a, b, r, where):
    """On the axis line, at an end, a zero-length tube, facing away: finite and ≥ 0 (NumPy and Dr.Jit
    float32); facing away from the whole tube gives 0."""
    from rtfit.realtime.arrays import DRJIT_OPS

    p, n, a, b = (np.array(v) for v in (p, n, a, b))
    if where == "on-axis":
        p = a + 1.7 * (b - a)
    elif where == "on-end":
        p = a.copy()
    elif where == "zero-length":
        b = a.copy()
    elif where == "away" and np.linalg.norm(n) > 1e-3:
        below = p - (np.linalg.norm(a - p) + np.linalg.norm(b - p) + 1.0) * _unit(np.array(n))
        a, b = below + 0.1 * (a - p), below - 0.1 * (b - p)
    ins = _tube_inputs(p, n, a, b, r, 2.0)
    e64 = float(TUBE(NUMPY_OPS, ins))
    v32 = float(np.asarray(TUBE(DRJIT_OPS, {k: dr.llvm.Float(float(v)) for k, v in ins.items()})).ravel()[0])
    assert math.isfinite(e64) and e64 >= 0.0 and math.isfinite(v32) and v32 >= 0.0
    if where == "away" and np.linalg.norm(n) > 1e-3:
        assert e64 == 0.0 and v32 == 0.0


_TUBE_XML = _FLOOR_SCENE.replace(
    "{lights}",
    """<shape type="cylinder" id="tube">
        <point name="p0" x="-0.6" y="0.3" z="0.7"/>
        <point name="p1" x="0.6" y="-0.1" z="0.7"/>
        <float name="radius" value="0.04"/>
        <emitter type="area"><rgb name="radiance" value="20, 16, 12"/></emitter>
    </shape>""",
)


def test_mitsuba_cylinder_light_audit_runs_the_tube_row(tmp_path):
    """A cylinder area light (ℓ = 1.26, r = 0.04, 0.7 above a floor) in a Mitsuba XML scene, 16² × 16 spp: the
    audit runs the tube row and the punctual rows from the cylinder's own to_world and radiance; the
    reference agrees with the surface quadrature (pooled mean within 4 standard errors), and the tube row
    is within its measured bound of it (tube·sin ψ/E − 1 ≤ 0.25 at d ≥ 0.3ℓ)."""
    path = tmp_path / "tube.xml"
    path.write_text(_TUBE_XML)
    r = rtfit.audit(path, "diffuse", spp=16, cache=tmp_path / "c", metrics=("rmse",), fit=False)
    case = next(c for c in r.cases if c.id.endswith("unshadowed"))
    assert {"punctual", "tube"} <= set(r.outcomes[case.id]) and "disc" not in r.outcomes[case.id]
    ci = case.channel_inputs[0]
    pts = np.stack([ci[f"p{a}"] for a in AXES], 1)
    nrm = np.stack([ci[f"n{a}"] for a in AXES], 1)
    a, b = (np.array([ci[f"{k}{x}"] for x in AXES]) for k in ("ta", "tb"))
    assert np.allclose(a, [-0.6, 0.3, 0.7], atol=1e-5) and np.allclose(b, [0.6, -0.1, 0.7], atol=1e-5)
    assert ci["tube_radius"] == pytest.approx(0.04, rel=1e-5) and ci["radiance"] == 20.0
    quad = np.array([_tube_quadrature(pts[i], nrm[i], a, b, 0.04, 20.0) for i in range(len(pts))])
    ref = case.reference.mean[case.mask][:, 0]
    err = case.reference.stderr[case.mask][:, 0]
    assert abs(float(np.mean(ref - quad))) < 4 * float(np.sqrt(np.sum(err**2))) / len(ref)
    tube = r.image(case.id, "tube")[case.mask][:, 0]
    w = (b - a) / np.linalg.norm(b - a)
    t = (a + b) / 2 - pts
    sin_psi = np.linalg.norm(np.cross(w, t / np.linalg.norm(t, axis=1)[:, None]), axis=1)
    assert np.max(np.abs(tube * sin_psi / quad - 1)) < 0.25
    punct = r.image(case.id, "punctual")[case.mask][:, 0]
    assert np.all(np.isfinite(punct)) and np.all(punct >= 0)
    rms = [float(np.sqrt(np.mean((x - quad) ** 2) / np.mean(quad**2))) for x in (tube, punct)]
    assert 0.1 < rms[0] < rms[1] < 0.3  # measured: tube 0.166, punctual 0.214 (relative rms)


def test_an_elliptical_cylinder_gets_no_light_model_row(tmp_path):
    """A cylinder whose to_world scales x ≠ y (`XmlEmitter.elliptical`) is not a tube: neither the tube row
    nor the punctual rows (its projected width depends on the view), saying what they need."""
    from rtfit.experiments.applicability import applicable_families
    from rtfit.experiments.audit import inspect_scene

    oval = """<shape type="cylinder" id="oval">
        <transform name="to_world"><scale x="0.1" y="0.05" z="1"/><translate z="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="1, 1, 1"/></emitter>
    </shape></scene>"""
    path = tmp_path / "oval.xml"
    path.write_text(_TUBE_XML.replace("</scene>", oval))
    tube, ellipse = (
        a for a in applicable_families(inspect_scene(path), approx="diffuse") if "cylinder" in a.part
    )
    assert {"tube", "punctual"} <= set(tube.methods) and not {"tube", "punctual"} & set(ellipse.methods)
    assert "circular cylinder" in dict(ellipse.excluded)["tube"]
