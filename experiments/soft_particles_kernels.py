"""The soft-particles study's kernel-only parts (a leaf of `soft_particles_study`, which alone imports it):
the kernels on view rays (float32 Dr.Jit and float64 NumPy runs of the one kernel text,
`rtfit.realtime.soft_particles`) and the checks that need no scene — issue 18's claim, the analytic chords
against a midpoint count, every kernel in float32 over its declared domain, and the extremes (camera inside,
s → 0, Δ ≤ 0, huge σ, off-axis)."""

from __future__ import annotations

import math

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.arrays import xyz_columns
from rtfit.realtime.soft_particles import BIG, METHODS, box_chord, linear_underestimate, sphere_chord

from .particle_geometry import RADIUS, billboard_inputs, sigma_of
from .records import Check

__all__ = [
    "chord_checks",
    "claim_checks",
    "evaluate32",
    "exact64",
    "extreme_checks",
    "extreme_values",
    "finite_checks",
    "pixel_dirs",
    "plane_distance",
    "ray_inputs",
]

SHAPES = ("sphere", "box")


# ============================================================================================== kernels
def pixel_dirs(resolution, fov_deg: float = 40.0) -> np.ndarray:
    """Unit pixel-centre view rays (H, W, 3) of a pinhole camera at the origin looking along +z (y up)."""
    w, h = int(resolution[0]), int(resolution[1])
    t = math.tan(math.radians(fov_deg) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * w / h
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t
    x, y = np.meshgrid(xs, ys)
    d = np.stack([x, y, np.ones_like(x)], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def plane_distance(dirs: np.ndarray, point, normal) -> np.ndarray:
    """Ray distance t to the plane (point, normal) along each unit ray from the origin; `BIG` if none."""
    dn = dirs @ np.asarray(normal, np.float64)
    pn = float(np.dot(point, normal))
    ok = np.abs(dn) > 1e-12
    t = np.where(ok, pn / np.where(ok, dn, 1.0), -1.0)
    return np.where(t > 0.0, t, BIG)


def ray_inputs(dirs: np.ndarray, centre, radius: float, sigma: float, t_surface) -> dict:
    """Per-pixel inputs of the exact kernels (rays from the origin)."""
    n = len(dirs)
    c = np.broadcast_to(np.asarray(centre, np.float64), (n, 3))
    return {
        **xyz_columns("d", dirs),
        **xyz_columns("c", c),
        "t_surface": np.asarray(t_surface, np.float64),
        "radius": np.full(n, radius),
        "sigma": np.full(n, sigma),
    }


def evaluate32(method: str, inputs: dict, params: dict | None = None) -> np.ndarray:
    """A method's kernel text on float32 Dr.Jit (the shader's precision), returned as float64."""
    m = METHODS[method]
    x = {k: np.asarray(inputs[k], np.float32) for k in m.input_names}
    return np.asarray(m.evaluate(x, params), np.float64)


def exact64(shape: str, inputs: dict) -> np.ndarray:
    """The exact opacity in float64 (NumPy run of the kernel text)."""
    m = METHODS[f"exact-{shape}"]
    return np.asarray(m(NUMPY_OPS, {k: np.asarray(inputs[k], np.float64) for k in m.input_names}), np.float64)


# ============================================================================================ checks
def claim_checks() -> list[Check]:
    """Issue 18's claim from the kernels: a box of α = 0.95 cut through its centre on the view axis."""
    alpha = 0.95
    linear = float(METHODS["box"].evaluate({"alpha": alpha, "z": 4.0, "delta": 0.0, "radius": 1.0}))
    ex = {"dx": 0.0, "dy": 0.0, "dz": 1.0, "cx": 0.0, "cy": 0.0, "cz": 4.0, "t_surface": 4.0, "radius": 1.0}
    exact = float(METHODS["exact-box"].evaluate({**ex, "sigma": sigma_of(alpha, 1.0)}))
    closed = 1.0 - math.sqrt(1.0 - alpha)
    gap, f_star = linear_underestimate(alpha)
    f = np.linspace(0.0, 1.0, 1001)
    concave = bool(np.all(1.0 - (1.0 - alpha) ** f >= alpha * f - 1e-15))
    return [
        Check.within(
            "claim (issue 18): linear fade at α = 0.95, half the chord = 0.475", linear, "0.475", "1e-12"
        ),
        Check.within(
            "claim (issue 18): exact Beer–Lambert opacity of half the chord = 1 − √0.05 = 0.7764 "
            "(exact-box kernel on the view axis)",
            exact,
            closed,
            "1e-12",
            fmt=".6f",
        ),
        Check.holds(
            f"claim: 1 − (1 − α)^f ≥ α·f on f ∈ [0, 1] (concavity; the largest gap {gap:.3f} at "
            f"f = {f_star:.3f} for α = 0.95)",
            concave,
        ),
    ]


def chord_checks(n: int = 400, steps: int = 20000) -> list[Check]:
    """The analytic chords against an independent count: the ray t ∈ [0, t_s] sampled at ``steps``
    midpoints, each tested for being inside the sphere / box (the count's error ≤ 2 steps)."""
    rng = np.random.default_rng(5)
    out = []
    for shape in SHAPES:
        c = np.stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.5, 6.0, n)], -1)
        d = np.stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 0.4, n), np.ones(n)], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        ts = rng.uniform(0.5, 9.0, n)
        chord_fn = sphere_chord if shape == "sphere" else box_chord
        analytic = np.asarray(chord_fn((d[:, 0], d[:, 1], d[:, 2]), (c[:, 0], c[:, 1], c[:, 2]), ts, RADIUS))
        dt = ts / steps
        counted = np.zeros(n)
        for k0 in range(0, steps, 2000):
            t = (np.arange(k0, min(steps, k0 + 2000)) + 0.5)[None, :] * dt[:, None]
            x = t[..., None] * d[:, None, :] - c[:, None, :]
            inside = np.sum(x * x, -1) <= RADIUS**2 if shape == "sphere" else np.max(np.abs(x), -1) <= RADIUS
            counted += inside.sum(-1) * dt
        err = float(np.max(np.abs(analytic - counted) / (2.0 * dt)))
        out.append(
            Check.at_most(
                f"{shape} chord: analytic clipped chord = midpoint count along the ray ({n} random "
                f"rays, {steps} steps), in units of the step's 2-step bound",
                err,
                "1",
            )
        )
    return out


def finite_checks(n: int = 20000) -> list[Check]:
    """Every method in float32 over its inputs' whole declared domains (log-spread magnitudes, signs,
    zeros) and parameters at their bounds: no NaN or Inf, opacity in [0, 1]."""
    rng = np.random.default_rng(9)
    out = []
    for mid, m in METHODS.items():
        x = {}
        for inp in m.inputs:
            lo, hi = inp.domain or (0.0, 1.0)
            u = rng.uniform(lo, hi, n)
            if hi > 10.0:  # magnitudes spread over decades, zeros included
                u = np.where(rng.uniform(size=n) < 0.5, 10.0 ** rng.uniform(-6.0, math.log10(hi), n), u)
                u[: n // 50] = 0.0
            x[inp.name] = np.clip(u, lo, hi)
        bad, lo_v, hi_v = 0, 1.0, 0.0
        bounds = [
            {k: (p.lower if j == 0 else min(p.upper, 1e3)) for k, p in m.params.items()} for j in range(2)
        ]
        for par in [m.defaults(), *bounds]:
            v = evaluate32(mid, x, par)
            bad += int(np.sum(~np.isfinite(v)))
            fin = v[np.isfinite(v)]
            lo_v, hi_v = min(lo_v, float(fin.min())), max(hi_v, float(fin.max()))
        out.append(
            Check(
                name=f"{mid}: float32 over the whole input domain and parameter bounds: non-finite "
                f"values (opacity range [{lo_v:.3g}, {hi_v:.3g}])",
                value=bad,
                expected="0, opacity in [0, 1]",
                passed=bad == 0 and lo_v >= 0.0 and hi_v <= 1.0,
            )
        )
    return out


# =========================================================================================== extremes
def _axis_case(z: float, delta: float, alpha_c: float, theta_deg: float = 0.0, shape: str = "box") -> dict:
    """One pixel: a particle of radius 1 on the ray at angle θ from the view axis, its centre at view depth
    z, the ray through its centre, the depth buffer Δ behind the centre. Values of every row."""
    th = math.radians(theta_deg)
    d = np.array([[math.sin(th), 0.0, math.cos(th)]])
    c = d[0] * z / math.cos(th)
    ts = np.array([(z + delta) / math.cos(th)])
    bb = billboard_inputs(d, c, RADIUS, alpha_c, shape, ts)
    row = {"exact": float(exact64(shape, ray_inputs(d, c, RADIUS, sigma_of(alpha_c, RADIUS), ts))[0])}
    for m in ("linear", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray"):
        row[m] = float(evaluate32(m, bb)[0])
    return row


def extreme_values() -> dict:
    """The extremes' table (module docstring item 5)."""
    a = 0.95
    inside = {f"z = {z:g} r": _axis_case(z, 5.0, a, shape="sphere") for z in (0.75, 0.5, 0.25, 0.05)}
    behind = {f"Δ = {dl:g} r": _axis_case(4.0, dl, a, shape="sphere") for dl in (-2.0, -0.9, -0.5, 0.0, 0.5)}
    s_small = {
        f"s = {s:g} r": [
            float(METHODS["linear"].evaluate({"alpha": 0.95, "delta": dl, "radius": 1.0}, {"s": s}))
            for dl in (-1e-3, 0.0, 1e-9, 1e-3)
        ]
        for s in (1.0, 1e-3, 1e-6, 1e-12, 0.0)
    }
    off = {}
    for th in (0.0, 10.0, 20.0, 30.0, 40.0):
        row = _axis_case(10.0, 0.0, a, th, shape="box")
        tau = {k: -math.log1p(-min(v, 1 - 1e-15)) for k, v in row.items()}
        off[f"{th:g}°"] = {
            **row,
            "tau_ratio_box_beer": tau["box-beer"] / tau["exact"],
            "cos": math.cos(math.radians(th)),
        }
    axis = np.array([[0.0, 0.0, 1.0]])
    huge = {
        f"σ = {s:g} /m": float(evaluate32("exact-sphere", ray_inputs(axis, (0, 0, 4), 1.0, s, [4.0]))[0])
        for s in (1e3, 1e10, 1e30, 1e38)
    }
    huge["σ = 1e38 /m, ℓ = 0"] = float(
        evaluate32("exact-sphere", ray_inputs(axis, (0, 0, 4), 1.0, 1e38, [3.0]))[0]
    )
    return {
        "camera_inside": inside,
        "delta": behind,
        "s_to_zero": s_small,
        "off_axis": off,
        "huge_sigma": huge,
    }


def extreme_checks(ext: dict) -> list[Check]:
    ins, s0, behind, off = ext["camera_inside"], ext["s_to_zero"], ext["delta"], ext["off_axis"]
    sph = max(abs(v["spherical"] - v["exact"]) for v in ins.values())
    lin = max(v["linear"] - v["exact"] for v in ins.values())
    step = all(v[0] == 0.0 and v[1] == 0.0 for v in s0.values()) and s0["s = 0 r"][2] == 0.95
    fade0 = all(behind[k]["linear"] == 0.0 for k in behind if not k.startswith("Δ = 0.5"))
    chord0 = behind["Δ = -2 r"]["exact"] == 0.0 and behind["Δ = -2 r"]["spherical"] == 0.0
    ray = max(abs(v["box-beer-ray"] - v["exact"]) for v in off.values())
    ratio = max(abs(v["tau_ratio_box_beer"] - v["cos"]) for v in off.values())
    hv = list(ext["huge_sigma"].values())
    return [
        Check.at_most(
            "camera inside the sphere (view axis): the spherical billboard clips at the camera plane and "
            "equals the exact opacity",
            sph,
            "1e-6",
        ),
        Check.above(
            "camera inside the sphere: the linear fade ignores the camera plane and over-estimates", lin, "0"
        ),
        Check.holds(
            "s → 0: the linear fade becomes a hard step at Δ = 0 (0 at Δ ≤ 0, α above), never NaN", step
        ),
        Check.holds(
            "Δ ≤ 0: the linear fade is 0; the chords are 0 once the surface is in front of it",
            fade0 and chord0,
        ),
        Check.at_most(
            "off-axis: box-beer-ray (view-z travel over cos θ) equals the exact opacity", ray, "1e-6"
        ),
        Check.at_most(
            "off-axis (box, ray through the centre, surface at the centre's depth): the view-z methods' "
            "optical depth is the exact one times cos θ",
            ratio,
            "1e-5",
        ),
        Check(
            name="huge σ: opacity 1 where the chord is positive, 0 where it is 0 (no 0·∞)",
            value=str(hv),
            expected="[1, 1, 1, 1, 0]",
            passed=hv[:-1] == [1.0] * (len(hv) - 1) and hv[-1] == 0.0,
        ),
    ]
