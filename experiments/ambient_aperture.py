"""Experiment ``ambient-aperture``: spherical-cap intersection (exact, smoothstep, linear, fitted) and the
ambient-aperture shading of area-light occlusion against Mitsuba.

Every compared method is a row of `rtfit.realtime.ambient_aperture.METHODS` (id, label, kernel, inputs
with units, free parameters with defaults and bounds); this module derives its rows, labels, fits, cost
and bench rows and figures from that table, plus the few rows that are not real-time methods (the
cap-model integral and the no-occlusion irradiance, `LIGHTINGS`).

Part 1 — function level. The intersection solid angle Ω(r1, r2, d) of two caps over a dense grid of
(r1, r2, d) ∈ (0, π)³. Ground truth: the exact closed form (method ``exact``), itself checked on the whole
grid against an independent numerical integral (Gauss–Legendre in the polar angle of the smaller cap of
the azimuthal arc inside the other cap, split at the kinks) and at a few hard points (near-tangent tiny
caps) against SciPy's adaptive Gauss–Kronrod quadrature of the same integral (tests/ check it against
mpmath). Errors are fractions of the smaller cap, max and RMS, over the partial-overlap points of two
domains: "hemisphere caps" (r1, r2 ≤ π/2, where the seed's smoothstep is used and its known figures, 0.16
max and 0.05 RMS, live) and the "full domain". The fitted form's six coefficients are fitted through its
kernel text (`rtfit.fitting.fit_method`) on the full-domain grid.

Part 2 — the Lambert factor. The cosine-weighted intersection ∫_{cap_a ∩ cap_l} max(n·ω, 0) dω over random
(aperture, light) configurations, by quadrature over the light's cap, against Ω·max(n·c, 0) with the seed's
centroid (plain average of the two directions) and the fitted cap-size-weighted centroid (exponent k fitted
through the kernel of method ``aa-exact-fitted``).

Part 3 — scenes (`scenes/library/aperture_*.toml`): a white receiver under a plate with a circular hole, the
floor of a cylindrical well, and a bumpy height field. At a grid of receiver points (irradiance probes, laid
out as an image) Mitsuba gives the direct irradiance from (a) the scene's sphere light and (b) a constant
sky of radiance 1 instead. The bent normal and aperture are baked with Mitsuba ray casts (uniform hemisphere
visibility, `rtfit.reference.visibility`). Compared with the reference:

* ``cap-model``: the exact irradiance *if visibility were the baked cap*, ∫_{cap_a ∩ cap_l} L max(n·ω, 0) dω
  by quadrature (for the sky: the closed-form projected solid angle of the cap). Its error is the cap
  model's own; every shading method below inherits it.
* ``aa-*``: the ambient-aperture shading L·Ω·max(n·c, 0) with each intersection form and Lambert factor;
  the seed's full method is ``aa-smoothstep-seed``; the recommended replacement ``aa-fitted-fitted``.
* ``fill-seed`` / ``fill-projected`` for the sky case (000:2774-2782).
* ``unshadowed``: the exact sphere-light irradiance ignoring all occluders (scale of the shadowing).

Irradiance is reported as a fraction of the unshadowed peak (light case: the largest unshadowed sphere-light
irradiance over the probes; sky case: π L_sky).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from rtfit.fitting import Param, compute_metrics, fit_method, robust_spread, z_pair
from rtfit.fitting.stats import Z_MEDIAN_TOLERANCE, Z_SPREAD_TOLERANCE
from rtfit.realtime import (
    NUMPY_OPS,
    cap_area,
    cap_intersection_solid_angle,
    sphere_light_irradiance,
)
from rtfit.realtime.ambient_aperture import METHODS
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.methods import Method
from rtfit.reference import ReferenceCache, ReferenceRequest, load_mitsuba_scene
from rtfit.reference.cache import REFERENCE_PASS_DTYPE
from rtfit.reference.estimators import device_probes, gbuffer, irradiance_pass
from rtfit.reference.variants import backend_of
from rtfit.reference.visibility import bake_visibility, surface_points
from rtfit.scenes import ConstantEnv, library_path, load_scene, scene_hash

from . import figures
from . import fitted as fitfiles
from .ambient_aperture_doc import sections, summary
from .ambient_aperture_scenes import LABELS as SCENE_LABELS
from .ambient_aperture_scenes import PROBE_REGION, probe_grid
from .cost import (
    BASELINE,
    Stock,
    attach_costs,
    bench_backend,
    comparison_rows,
    cost_row,
    memory_floor_row,
    reference_sizes,
    reference_vs_stock_rows,
    stock_render,
    time_drjit,
    time_numpy,
)
from .jobs import Job
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row
from .viewer import save_case_pixels

PI = math.pi


# ============================================================================================ configure
CONFIG = {
    "grid": ConfigKey("int", "(r1, r2, d) grid points per axis", 4, 1024),
    "fit_grid": ConfigKey("int", "fit grid points per axis", 4, 1024),
    "quad_nodes": ConfigKey("int", "Gauss–Legendre nodes per sub-interval", 2, 1024),
    "lambert_configs": ConfigKey("int", "configurations of the Lambert check", 10, 1 << 20),
    "lambert_quad": ConfigKey("int", "quadrature nodes (coarse, fine) of the Lambert check", 2, 4096, (2,)),
    "probe_n": ConfigKey("int", "probe image side (pixels)", 4, 4096),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "sky_spp": ConfigKey("int", "sky reference samples per pixel", 2, 4 * SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "bake_dirs": ConfigKey("int", "directions of the bake", 64, 1 << 22),
    "cap_quad": ConfigKey("int", "cap quadrature nodes (coarse, fine)", 2, 4096, (2,)),
    "cost_elements": ConfigKey("int", "elements per timed launch", 1024, 1 << 26),
    "scenes": ConfigKey(
        "str", "library scenes", shape=(None,), choices=("aperture_hole", "aperture_well", "aperture_bumps")
    ),
    "metrics": ConfigKey(
        "str",
        "image metrics",
        shape=(None,),
        choices=("rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim", "flip"),
    ),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "grid": 40 if quick else 96,  # (r1, r2, d) grid points per axis
            "fit_grid": 40 if quick else 72,
            "quad_nodes": 48 if quick else 96,  # Gauss–Legendre nodes per sub-interval (function check)
            "lambert_configs": 1500 if quick else 6000,
            "lambert_quad": [24, 96] if quick else [48, 192],
            "probe_n": 32 if quick else 64,  # probe image side
            "spp": spp or (1024 if quick else 8192),
            "sky_spp": 4 * spp
            if spp
            else (4096 if quick else 32768),  # the sky is seen through small apertures
            "pass_spp": 512 if quick else 4096,
            "bake_dirs": 4096 if quick else 16384,
            "cap_quad": [24, 96] if quick else [48, 192],
            "cost_elements": 1 << (20 if quick else 24),
            "scenes": ["aperture_hole", "aperture_well", "aperture_bumps"],
            # ꟻLIP costs ~0.15 s per call on a busy 2-core machine (5 calls per metric with its floor draws):
            # the quick run leaves it out to stay within its time budget.
            "metrics": ["rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim"] + ([] if quick else ["flip"]),
        },
    )


# ============================================================================================== methods
OMEGA = tuple(m for m in METHODS.values() if m.quantity == "cap_intersection_solid_angle")
"""The intersection forms (r1, r2, d in rad → Ω in sr), the exact one first."""
EXACT = next(m for m in OMEGA if m.exact)
APPROX = tuple(m for m in OMEGA if not m.exact)
SEED_OMEGA = METHODS["smoothstep"]  # the seed's form: the one the fitted form must beat
FITTED_OMEGA = METHODS["fitted"]  # the form whose coefficients c0..c5 the intersection fit determines
FITTED_LAMBERT = METHODS["aa-exact-fitted"]  # exact Ω, fitted centroid: the Lambert fit determines its k
LAMBERT_ROWS = {"seed": METHODS["aa-exact-seed"], "fitted": FITTED_LAMBERT}
"""The two Lambert factors compared in part 2 (both with the exact intersection)."""
FIT_START = {**{p: 0.0 for p in FITTED_OMEGA.params}, "k": 1.0}
"""Start values of the fits: the plain smoothstep (c = 0) and k = 1, so that a fit never starts at the
shipped values it is meant to reproduce."""
COST_SHADING = ("aa-exact-seed", "aa-smoothstep-seed", "aa-fitted-fitted")
"""Shading methods whose light term is timed (cost rows, scene Pareto plot)."""
DECOMPOSITION = (
    "aa-exact-seed",
    "aa-smoothstep-seed",
    "aa-fitted-seed",
    "aa-exact-fitted",
    "aa-fitted-fitted",
)
"""Shading methods compared with the cap-model integral in the decomposition table."""


def fit_start(method: Method) -> dict[str, Param]:
    """The method's declared parameters (bounds, units) with the start values `FIT_START`."""
    return {p: dataclasses.replace(spec, initial=FIT_START[p]) for p, spec in method.params.items()}


def params_of(method: Method, fitted: Mapping[str, float]) -> dict[str, float]:
    """The fitted values of ``method``'s free parameters (c0..c5 and/or k)."""
    return {p: float(fitted[p]) for p in method.params}


# A compared row of a scene case (`rows.Row`): ``evaluate(probes, fitted)`` is the irradiance per probe
# (W/m²); ``fit`` names the fitted values it uses (recorded beside its metrics; ``fitted`` when any).


def method_row(method: Method) -> Row:
    """A row that evaluates a method of `METHODS` on the probes with the run's fitted parameters."""

    def value(probes, fitted):
        return np.asarray(method.evaluate(probes, params_of(method, fitted)), dtype=np.float64)

    names = tuple(method.params)
    return Row(method.id, method.label, method.id, evaluate=value, fitted=bool(names), fit=names)


def _cap_model_light(probes, fitted):
    """∫_{cap(a, r_a) ∩ cap(l, α)} L max(n·ω, 0) dω by quadrature (`cap_model_irradiance`)."""
    p = probes
    e = cap_model_irradiance(p["n"], p["a"], p["aperture"], p["l"], p["alpha"], tuple(p["cap_quad"]))
    return e * p["radiance"]


def _unshadowed(probes, fitted):
    """The exact sphere-light irradiance ignoring every occluder (closed form)."""
    return sphere_light_irradiance(probes["cos_nl"], probes["alpha"], probes["radiance"])


def _unoccluded_sky(probes, fitted):
    """π L_sky: a uniform sky over the whole hemisphere."""
    return np.full_like(probes["cos_na"], PI * probes["sky_radiance"])


@dataclass(frozen=True)
class Lighting:
    """One lighting of the scene cases: its rows (the last one is the no-occlusion irradiance, whose
    maximum over the probes is the case's peak), the rows its figure shows, and its case parameters."""

    id: str
    label: str
    scene_suffix: str
    rows: tuple[Row, ...]
    show: tuple[str, ...]
    parameters: Callable[[dict, float], dict]


def _rows(quantity: str) -> tuple[Row, ...]:
    return tuple(method_row(m) for m in METHODS.values() if m.quantity == quantity)


LIGHTINGS = (
    Lighting(
        id="light",
        label="sphere light",
        scene_suffix="",
        rows=(
            Row("cap-model", "Cap model, exact integral", evaluate=_cap_model_light),
            *_rows("light_irradiance"),
            Row("unshadowed", "No occlusion (exact sphere light)", evaluate=_unshadowed),
        ),
        show=("cap-model", "aa-smoothstep-seed", "aa-exact-seed", "aa-fitted-fitted"),
        parameters=lambda probes, peak: {
            "light_alpha_deg_mean": float(np.degrees(probes["alpha"]).mean()),
            "peak_irradiance": peak,
        },
    ),
    Lighting(
        id="sky",
        label="constant sky",
        scene_suffix="-sky",
        rows=(
            # For a uniform sky the exact integral over the baked cap is its projected solid angle: the
            # closed form of the ``fill-projected`` kernel (no light to subtract).
            Row(
                "cap-model",
                "Cap model, exact integral",
                evaluate=method_row(METHODS["fill-projected"]).evaluate,
            ),
            *_rows("sky_irradiance"),
            Row("unoccluded", "No occlusion (π L_sky)", evaluate=_unoccluded_sky),
        ),
        show=("cap-model", "fill-seed", "fill-projected"),
        parameters=lambda probes, peak: {"sky_radiance": probes["sky_radiance"]},
    ),
)


# ================================================================================================ cases
def grid_points(n: int):
    """Cell-centred (r1, r2, d) grid over (0, π)³, flattened."""
    g = (np.arange(n) + 0.5) / n * PI
    r1, r2, d = np.meshgrid(g, g, g, indexing="ij")
    return r1.ravel(), r2.ravel(), d.ravel()


def partial_mask(r1, r2, d):
    """Points where the caps partly overlap (neither nested, disjoint nor covering the sphere)."""
    return (d > np.abs(r1 - r2)) & (d < r1 + r2) & (r1 + r2 + d < 2 * PI)


def smaller_cap(r1, r2):
    """A(min(r1, r2)) = 4π sin²(r_min/2) in float64 NumPy: the unit of every function-level error."""
    return 4 * PI * np.sin(np.minimum(r1, r2) / 2) ** 2


def arc_integrand(th, rb, d):
    """2·acos(clip((cos r_b − cos θ cos d)/(sin θ sin d)))·sin θ: the azimuthal arc of the circle of polar
    angle θ about one cap's centre that lies inside the other cap (radius r_b, centre d away), times the
    area element; 0 where the ratio is not finite (θ = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        kk = (np.cos(rb) - np.cos(th) * np.cos(d)) / (np.sin(th) * np.sin(d))
    kk = np.where(np.isfinite(kk), kk, 1.0)
    return 2 * np.arccos(np.clip(kk, -1, 1)) * np.sin(th)


def kinks(rs, rb, d):
    """Polar angles θ ∈ (0, r_s) where the arc inside the other cap starts or ends: |d − r_b|, d + r_b,
    2π − d − r_b (clipped into [0, r_s]; the integral is split there)."""
    return (np.abs(d - rb), d + rb, 2 * PI - d - rb)


def quadrature_intersection(r1, r2, d, nodes: int = 48, chunk: int = 20000):
    """Independent numerical Ω: ∫_0^{r_s} `arc_integrand` dθ over the smaller cap (radius r_s) in its polar
    angle θ, split at the `kinks` and on each piece Gauss–Legendre after θ = a + (b − a)(1 − cos πs)/2
    (which smooths the √ endpoint behaviour of acos at the kinks). float64, vectorised."""
    r1, r2, d = (np.asarray(x, dtype=np.float64).ravel() for x in (r1, r2, d))
    rs, rb = np.minimum(r1, r2), np.maximum(r1, r2)
    x, w = np.polynomial.legendre.leggauss(nodes)
    s = 0.5 * (x + 1.0)
    ws = 0.5 * w
    out = np.empty_like(rs)
    for a0 in range(0, len(rs), chunk):
        sl = slice(a0, a0 + chunk)
        rs_, rb_, d_ = rs[sl], rb[sl], np.maximum(d[sl], 1e-300)
        ends = np.stack([np.zeros_like(rs_), *kinks(rs_, rb_, d_), rs_], axis=1)
        ends = np.sort(np.clip(ends, 0.0, rs_[:, None]), axis=1)
        total = np.zeros_like(rs_)
        for k in range(4):
            a, b = ends[:, k : k + 1], ends[:, k + 1 : k + 2]
            th = a + (b - a) * 0.5 * (1 - np.cos(PI * s))[None, :]
            jac = (b - a) * 0.5 * PI * np.sin(PI * s)[None, :]
            f = arc_integrand(th, rb_[:, None], d_[:, None])
            total += np.sum(f * jac * ws[None, :], axis=1)
        out[sl] = total
    return out


def adaptive_quadrature_intersection(r1: float, r2: float, d: float) -> float:
    """Ω at one point by SciPy's adaptive Gauss–Kronrod quadrature (QUADPACK) of ∫_0^{r_s} `arc_integrand`
    dθ with breakpoints at the `kinks`, relative tolerance 1e-13, float64: an algorithm independent of
    both the closed form and `quadrature_intersection` (tests/ compare it with mpmath at 25 digits)."""
    from scipy import integrate  # scipy: optional-heavy (LAZY_OK), only this check needs it

    rs, rb = min(r1, r2), max(r1, r2)
    breaks = sorted({float(b) for b in kinks(rs, rb, d) if 0 < b < rs})
    value, _ = integrate.quad(
        lambda th: float(arc_integrand(th, rb, d)),
        0.0,
        rs,
        points=breaks or None,
        epsabs=0.0,
        epsrel=1e-13,
        limit=200,
    )
    return float(value)


def _frame(v):
    """Two unit tangents orthogonal to unit vectors v (N, 3) (Frisvad / Duff et al. 2017)."""
    sign = np.where(v[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + v[:, 2])
    b = v[:, 0] * v[:, 1] * a
    t1 = np.stack([1 + sign * v[:, 0] ** 2 * a, sign * b, -sign * v[:, 0]], axis=1)
    t2 = np.stack([b, sign + v[:, 1] ** 2 * a, -v[:, 1]], axis=1)
    return t1, t2


def _node_dots(vec, frame, mu, st, cp, sp):
    """vec·ω at the quadrature nodes ω = μ·axis + sin θ'(cos φ u1 + sin φ u2): (m, nt, nphi)."""
    axis, u1, u2 = frame
    return mu[:, :, None] * np.sum(vec * axis, 1)[:, None, None] + st[:, :, None] * (
        cp[None, None, :] * np.sum(vec * u1, 1)[:, None, None]
        + sp[None, None, :] * np.sum(vec * u2, 1)[:, None, None]
    )


def cap_model_irradiance(n, a, r_a, ld, alpha, nodes=(24, 96), chunk: int = 512):
    """∫_{cap(l, α) ∩ cap(a, r_a)} max(n·ω, 0) dω per row (sr, i.e. irradiance per unit radiance): quadrature
    over the smaller of the two caps (Gauss–Legendre in cos θ' from its axis × midpoint rule in φ), the other
    cap entering as an indicator (first-order convergence at its boundary: the experiment quotes the change
    with doubled nodes)."""
    n, a, ld = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (n, a, ld))
    r_a = np.asarray(r_a, dtype=np.float64).ravel()
    alpha = np.asarray(alpha, dtype=np.float64).ravel()
    swap = r_a < alpha  # integrate over the smaller cap
    ld, a = np.where(swap[:, None], a, ld), np.where(swap[:, None], ld, a)
    alpha, r_a = np.where(swap, r_a, alpha), np.where(swap, alpha, r_a)
    nt, nphi = nodes
    x, w = np.polynomial.legendre.leggauss(nt)
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * PI
    t1, t2 = _frame(ld)
    out = np.empty(len(ld))
    for s in range(0, len(ld), chunk):
        sl = slice(s, s + chunk)
        ca = np.cos(alpha[sl])[:, None]
        mu = ca + (1 - ca) * 0.5 * (x[None, :] + 1)  # (m, nt)
        wmu = (1 - ca) * 0.5 * w[None, :]
        st = np.sqrt(np.maximum(1 - mu * mu, 0))
        cp, sp = np.cos(phi), np.sin(phi)

        frame = (ld[sl], t1[sl], t2[sl])
        dn = _node_dots(n[sl], frame, mu, st, cp, sp)
        da = _node_dots(a[sl], frame, mu, st, cp, sp)
        inside = da >= np.cos(r_a[sl])[:, None, None]
        f = np.where(inside, np.maximum(dn, 0.0), 0.0)
        out[sl] = np.sum(f.sum(axis=2) * wmu, axis=1) * (2 * PI / nphi)
    return out


def lambert_configs(count: int, seed: int = 17):
    """Random (n = +z, a, r_a, l, α) with a in the upper hemisphere, l up to α below the horizon."""
    rng = np.random.default_rng(seed)
    th_a = np.arccos(rng.uniform(0.0, 1.0, count))
    ph_a = rng.uniform(0, 2 * PI, count)
    r_a = rng.uniform(0.05, PI / 2, count)
    alpha = np.exp(rng.uniform(math.log(0.01), math.log(0.6), count))
    th_l = np.arccos(rng.uniform(-0.2, 1.0, count))
    ph_l = rng.uniform(0, 2 * PI, count)

    def vec(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)

    n = np.tile([0.0, 0.0, 1.0], (count, 1))
    return n, vec(th_a, ph_a), r_a, vec(th_l, ph_l), alpha


def light_geometry(points, normals, bent, light):
    """Per probe: cos(n, a), cos(n, l), cos(a, l), α and l for a sphere light (centre, radius)."""
    c = np.asarray(light.center, dtype=np.float64)
    v = c[None, :] - points
    dist = np.linalg.norm(v, axis=1)
    ld = v / dist[:, None]
    alpha = np.arctan2(light.radius, np.sqrt(np.maximum(dist**2 - light.radius**2, 0)))
    cos_na = np.clip(np.sum(normals * bent, 1), -1, 1)
    cos_nl = np.clip(np.sum(normals * ld, 1), -1, 1)
    cos_al = np.clip(np.sum(bent * ld, 1), -1, 1)
    return cos_na, cos_nl, cos_al, alpha, ld


def function_level(cfg, fitted, seed: int) -> dict:
    """Errors of each approximate form over the grid (fractions of the smaller cap) and the checks of the
    closed form (quadrature on the partial points, closed values on the others)."""
    r1, r2, d = grid_points(cfg["grid"])
    caps = {"r1": r1, "r2": r2, "d": d}
    part = partial_mask(r1, r2, d)
    hemi = part & (r1 <= PI / 2) & (r2 <= PI / 2)
    exact = EXACT.evaluate(caps)
    a_min = smaller_cap(r1, r2)
    # Independent check of the closed form: quadrature on (a random subset of) the partial points, plus
    # the nested / disjoint / covering points against their closed values.
    rng = np.random.default_rng(seed)
    idx = np.flatnonzero(part)
    if len(idx) > 60000:
        idx = rng.choice(idx, 60000, replace=False)
    quad = quadrature_intersection(r1[idx], r2[idx], d[idx], cfg["quad_nodes"])
    quad_dev = float(np.max(np.abs(exact[idx] - quad) / a_min[idx]))
    nested = d <= np.abs(r1 - r2)
    disjoint = d >= r1 + r2
    covering = (r1 + r2 + d >= 2 * PI) & ~nested & ~disjoint
    closed = np.where(
        nested, a_min, np.where(disjoint, 0.0, 4 * PI * (np.sin(r1 / 2) ** 2 + np.sin(r2 / 2) ** 2) - 4 * PI)
    )
    sel = nested | disjoint | covering
    closed_dev = float(np.max(np.abs(exact[sel] - closed[sel]) / a_min[sel]))

    errors = {}
    for m in APPROX:
        approx = m.evaluate(caps, params_of(m, fitted))
        rel = (approx - exact) / a_min
        errors[m.id] = {}
        for dom, mask in (("hemisphere", hemi), ("full", part), ("all", np.ones_like(part))):
            errors[m.id][dom] = {
                "max": float(np.max(np.abs(rel[mask]))),
                "rms": float(np.sqrt(np.mean(rel[mask] ** 2))),
                "mean": float(np.mean(rel[mask])),
                "points": int(mask.sum()),
            }
        errors[m.id]["in_bounds"] = bool(np.all(approx >= 0) and np.all(approx <= a_min * (1 + 1e-9)))
    return {
        "errors": errors,
        "quad_dev": quad_dev,
        "quad_points": len(idx),
        "closed_dev": closed_dev,
        "grid": cfg["grid"],
        "n_partial": int(part.sum()),
        "n_hemi": int(hemi.sum()),
    }


def _as_image(mask, values, fill) -> np.ndarray:
    img = np.repeat(fill.copy()[..., None], 3, axis=-1) if fill.ndim == 2 else fill.copy()
    img[mask] = np.asarray(values, dtype=np.float64)[:, None]
    return img


def scene_cases(cfg, results, fitted) -> tuple[list[dict], dict]:
    """Cases (scene × lighting) with metrics of every row; also returns the images for figures/checks."""
    cases, arrays = [], {}
    for name in cfg["scenes"]:
        r = results[name]
        scene = load_scene(library_path(name))
        light = scene.lights[0]
        mask = r["mask"]
        n, a, r_a = r["normals"], r["bent_normal"], r["aperture"]
        cos_na, cos_nl, cos_al, alpha, ld = light_geometry(r["points"], n, a, light)
        probes = {
            "n": n,
            "a": a,
            "l": ld,
            "cos_na": cos_na,
            "cos_nl": cos_nl,
            "cos_al": cos_al,
            "aperture": r_a,
            "alpha": alpha,
            "radiance": float(light.radiance[0]),
            "sky_radiance": 1.0,
            "cap_quad": cfg["cap_quad"],
        }
        for lighting in LIGHTINGS:
            ref = r["refs"][lighting.id]
            values = {row.id: row.evaluate(probes, fitted) for row in lighting.rows}
            peak = float(np.max(values[lighting.rows[-1].id]))
            ref_img = _as_image(mask, ref["mean"][:, 0] / peak, np.zeros(mask.shape))
            sig_img = _as_image(mask, ref["sigma"][:, 0] / peak, np.zeros(mask.shape))
            approx_docs, imgs = [], {}
            for row in lighting.rows:
                img = _as_image(mask, values[row.id] / peak, ref_img[..., 0])
                imgs[row.id] = img
                met = compute_metrics(img, ref_img, sig_img, mask, names=cfg["metrics"])
                approx_docs.append(
                    {
                        "method": row.id,
                        "label": row.label,
                        "fitted": row.fitted,
                        "parameters": {p: float(fitted[p]) for p in row.fit},
                        "metrics": met.to_dict(),
                    }
                )
            cid = f"{name.removeprefix('aperture_')}-{lighting.id}"
            cases.append(
                {
                    "id": cid,
                    "label": f"{SCENE_LABELS[name]}, {lighting.label}",
                    "parameters": {
                        "probes": int(mask.sum()),
                        "bake_dirs": r["bake"]["n_dirs"],
                        "mean_aperture_deg": float(np.degrees(r_a).mean()),
                        "mean_visible_fraction": float(r["visible_fraction"].mean()),
                        **lighting.parameters(probes, peak),
                    },
                    "scene": {"name": f"{scene.name}{lighting.scene_suffix}", "hash": ref["hash"]},
                    "reference": {**ref["info"], "quantity": "irradiance (direct), probes on the receiver"},
                    "approximations": approx_docs,
                }
            )
            arrays[cid] = {
                "ref": ref_img,
                "sigma": sig_img,
                "mask": mask,
                "images": imgs,
                "peak": peak,
                "show": lighting.show,
            }
    return cases, arrays


def _approx(case, method) -> dict:
    return next(a for a in case["approximations"] if a["method"] == method)


def _rmse(case, method) -> float:
    return float(_approx(case, method)["metrics"]["rmse"]["value"])


def decomposition(cases, arrays) -> list[dict]:
    """Per light case: RMSE of the cap model vs the reference, and of each shading vs the cap model (the
    part of the error that is the formula's, not the cap's)."""
    rows = []
    for c in cases:
        if not c["id"].endswith("-light"):
            continue
        a = arrays[c["id"]]
        m = a["mask"]
        cap = a["images"]["cap-model"][m][:, 0]
        rows.append(
            {
                "case": c["id"],
                "cap_model_vs_reference": _rmse(c, "cap-model"),
                "noise_floor": float(_approx(c, "cap-model")["metrics"]["rmse"]["noise_floor"]),
                **{
                    f"{meth}_vs_cap_model": float(np.sqrt(np.mean((a["images"][meth][m][:, 0] - cap) ** 2)))
                    for meth in DECOMPOSITION
                },
            }
        )
    return rows


# ================================================================================================= jobs
def fit_intersection_job(grid: int) -> dict:
    """Job: fit c0..c5 of the fitted intersection form on a grid³ of the full domain, through its kernel:
    least squares of (Ω_fit − Ω_exact)/A(r_min) over the partial-overlap points."""
    r1, r2, d = grid_points(grid)
    m = partial_mask(r1, r2, d)
    r1, r2, d = r1[m], r2[m], d[m]
    exact = cap_intersection_solid_angle(r1, r2, d)
    res = fit_method(
        FITTED_OMEGA,
        {"r1": r1, "r2": r2, "d": d},
        exact,
        weights=1.0 / smaller_cap(r1, r2),
        params=fit_start(FITTED_OMEGA),
    )
    out = res.to_dict()
    out["n_residuals"] = len(r1)
    out["grid"] = grid
    return out


def fit_lambert_job(count: int, nodes) -> dict:
    """Job: ground truth of the cosine-weighted intersection by quadrature; seed vs fitted centroid; fit k
    through the kernel of `FITTED_LAMBERT`: least squares of (E − E_true)/A(α) at unit radiance."""
    n, a, r_a, ld, alpha = lambert_configs(count)
    target = cap_model_irradiance(n, a, r_a, ld, alpha, tuple(nodes))
    cos_al = np.clip(np.sum(a * ld, 1), -1, 1)
    omega = cap_intersection_solid_angle(r_a, alpha, np.arccos(cos_al))
    keep = omega > 1e-3 * cap_area(np.minimum(r_a, alpha))  # configurations with a real overlap
    n, a, r_a, ld, alpha, target, cos_al = (x[keep] for x in (n, a, r_a, ld, alpha, target, cos_al))
    inputs = {
        "cos_na": a[:, 2],
        "cos_nl": ld[:, 2],
        "cos_al": cos_al,
        "aperture": r_a,
        "alpha": alpha,
        "radiance": 1.0,
    }
    scale = cap_area(alpha)
    res = fit_method(FITTED_LAMBERT, inputs, target, weights=1.0 / scale, params=fit_start(FITTED_LAMBERT))
    out = res.to_dict()
    k = float(res.values["k"])
    errs = {}
    for name, method in LAMBERT_ROWS.items():
        rel = (method.evaluate(inputs, params_of(method, {"k": k})) - target) / scale
        errs[name] = {
            "rms": float(np.sqrt(np.mean(rel**2))),
            "max": float(np.max(np.abs(rel))),
            "mean": float(np.mean(rel)),
        }
    # Open sky, small light at 60°: the erratum's 73 %.
    sky60 = {"cos_na": 1.0, "cos_nl": 0.5, "cos_al": 0.5, "aperture": PI / 2, "alpha": 0.01, "radiance": 1.0}
    exact60 = float(
        cap_model_irradiance(
            [[0, 0, 1]], [[0, 0, 1]], [PI / 2], [[math.sqrt(0.75), 0, 0.5]], [0.01], tuple(nodes)
        )[0]
    )
    # Quadrature resolution: the same configurations with twice the nodes in each direction (first 300).
    m = min(300, len(target))
    fine = cap_model_irradiance(n[:m], a[:m], r_a[:m], ld[:m], alpha[:m], (2 * nodes[0], 2 * nodes[1]))
    out.update(
        {
            "errors": errs,
            "n_configs": len(target),
            "k": k,
            "open_sky_60": {
                "exact": exact60,
                **{
                    name: method.evaluate(sky60, params_of(method, {"k": k}))
                    for name, method in LAMBERT_ROWS.items()
                },
            },
            "quad_resolution": float(np.max(np.abs(fine - target[:m]) / scale[:m])),
        }
    )
    return out


def _reference(cache, scene, points, normals, spp, pass_spp, seed, variant, progress, label):
    """Mitsuba's direct irradiance at the probes (cached, content-addressed)."""
    return cache.get(
        ReferenceRequest(
            scene=scene,
            spp=spp,
            pass_spp=min(pass_spp, spp),
            seed=seed,
            variant=variant,
            quantity="irradiance",
            points=points,
            normals=normals,
            transport="direct",
        ),
        progress=progress,
        label=label,
    )


def scene_job(
    name: str,
    probe_n: int,
    spp: int,
    sky_spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    bake_dirs: int,
    progress: bool = False,
) -> dict:
    """Job: probe points on the receiver, baked visibility, and light / sky irradiance references."""
    scene = load_scene(library_path(name))
    xy, inside = probe_grid(name, probe_n)
    pts, nrm, valid = surface_points(scene, xy, PROBE_REGION[name][4], variant)
    mask = inside & valid
    p, n = pts[mask], nrm[mask]
    bake = bake_visibility(scene, p, n, bake_dirs, seed, variant)
    cache = ReferenceCache(cache_dir)
    sky_scene = dataclasses.replace(
        scene, lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),), name=f"{scene.name}-sky"
    )
    refs = {}
    for label, sc, n_spp in (("light", scene, spp), ("sky", sky_scene, sky_spp)):
        r = _reference(cache, sc, p, n, n_spp, pass_spp, seed, variant, progress, f"{sc.name} probes")
        refs[label] = {
            "mean": r.mean,
            "stderr": r.stderr,
            "sigma": r.sigma(),
            "info": r.to_dict(),
            "hash": scene_hash(sc),
        }
    return {
        "name": name,
        "mask": mask.reshape(probe_n, probe_n),
        "points": p,
        "normals": n,
        "visible_fraction": bake.visible_fraction,
        "bake_stderr": bake.stderr,
        "bent_normal": bake.bent_normal,
        "aperture": bake.aperture,
        "bake": bake.to_dict(),
        "refs": refs,
        "scene_hash": scene_hash(scene),
    }


def unoccluded_job(
    probe_n: int, spp: int, pass_spp: int, seed: int, variant: str, cache_dir: str, progress: bool = False
) -> dict:
    """Job: the hole scene with every occluder removed: Mitsuba vs the closed-form sphere-light irradiance
    (validates the probes, the light's geometry and the units of the whole comparison)."""
    scene = load_scene(library_path("aperture_hole"))
    floor = dataclasses.replace(scene, shapes=scene.shapes[:1], name=f"{scene.name}-unoccluded")
    xy, _ = probe_grid("aperture_hole", probe_n)
    p = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    r = _reference(
        ReferenceCache(cache_dir), floor, p, n, spp, pass_spp, seed, variant, progress, "unoccluded probes"
    )
    return {
        "points": p,
        "normals": n,
        "mean": r.mean,
        "stderr": r.stderr,
        "sigma": r.sigma(),
        "info": r.to_dict(),
    }


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    common = {
        "spp": cfg["spp"],
        "pass_spp": cfg["pass_spp"],
        "seed": ctx.seed,
        "variant": ctx.variant,
        "cache_dir": str(ctx.cache_dir),
        "progress": ctx.progress,
    }
    jobs = [
        Job(
            scene_job,
            {
                "name": name,
                "probe_n": cfg["probe_n"],
                "sky_spp": cfg["sky_spp"],
                "bake_dirs": cfg["bake_dirs"],
                **common,
            },
            label=name,
        )
        for name in cfg["scenes"]
    ]
    jobs.append(Job(unoccluded_job, {"probe_n": cfg["probe_n"], **common}, label="unoccluded"))
    jobs.append(Job(fit_intersection_job, {"grid": cfg["fit_grid"]}, label="fit-intersection"))
    jobs.append(
        Job(
            fit_lambert_job,
            {"count": cfg["lambert_configs"], "nodes": cfg["lambert_quad"]},
            label="fit-lambert",
        )
    )
    ctx.log(f"running {len(jobs)} jobs (3 scenes, validation, 2 fits)")
    outcomes = ctx.executor.map(jobs, desc="ambient-aperture")
    return assemble(ctx, cfg, dict(zip([j.label for j in jobs], outcomes, strict=True)))


def assemble(ctx, cfg, results) -> dict:
    """results.json of the experiment from the jobs' results (see the module docstring)."""
    out = ctx.out_dir
    fit_i = results["fit-intersection"]
    fit_l = results["fit-lambert"]
    fitted = {**{p: float(v["value"]) for p, v in fit_i["parameters"].items()}, "k": float(fit_l["k"])}

    fl = function_level(cfg, fitted, ctx.seed)
    cases, arrays = scene_cases(cfg, results, fitted)
    for cid, a in arrays.items():  # the report's image viewer (probe grids as images, / peak)
        save_case_pixels(out, cid, a["ref"], a["sigma"], a["images"], a["mask"])
    dec = decomposition(cases, arrays)
    cost_rows = costs(ctx, cfg, fitted)
    attach_costs(cases, cost_rows)

    figs = [curve_figure(out, fitted), map_figure(out, fitted)]
    figs += scene_figures(out, cases, arrays)
    figs.append(pareto_figure(out, fl, cost_rows))
    figs.append(scene_pareto_figure(out, cases, cost_rows))
    coeffs = [fitted[p] for p in FITTED_OMEGA.params]
    return {
        "summary": summary(cfg, fl, fit_l, dec, cases, cost_rows),
        "config": cfg,
        "sections": sections(cfg, fl, fit_i, fit_l, dec, coeffs, fitted["k"]),
        "cases": cases,
        "fits": write_fitted(out, fit_i, fit_l, fl, ctx, cfg, cases),
        "figures": figs,
        "costs": cost_rows,
        "checks": checks(fl, fit_i, fit_l, results["unoccluded"], arrays),
        "function_level": fl,
        "decomposition": dec,
        "headline": headline(fl),
        "notes": NOTES,
    }


# =============================================================================================== checks
HARD_POINTS = ((0.5, 0.5, 0.5), (2.0, 1.0, 2.5), (2.6, 2.2, 1.9), (0.01, 1.2, 1.205), (1.4, 0.0003, 1.40025))
"""(r1, r2, d) where the closed form is hardest: equal caps, covering caps, near-tangent tiny caps."""


def hard_point_deviation(points=HARD_POINTS) -> float:
    """max |Ω − Ω_quad| / A_min at `HARD_POINTS`, Ω_quad by `adaptive_quadrature_intersection`."""
    worst = 0.0
    for r1, r2, d in points:
        q = adaptive_quadrature_intersection(r1, r2, d)
        a = float(smaller_cap(r1, r2))
        worst = max(worst, abs(cap_intersection_solid_angle(r1, r2, d) - q) / a)
    return worst


def unoccluded_check(res) -> list[Check]:
    """Mitsuba vs the closed-form sphere-light irradiance with every occluder removed: the z-scores must
    be standard normal (tolerances: `rtfit.fitting.stats`)."""
    light = load_scene(library_path("aperture_hole")).lights[0]
    p, n = res["points"], res["normals"]
    _, cos_nl, _, alpha, _ = light_geometry(p, n, n, light)
    exact = sphere_light_irradiance(cos_nl, alpha, float(light.radiance[0]))
    _, z = z_pair(exact, res["mean"][:, 0], res["stderr"][:, 0], res["sigma"][:, 0], 0.0)  # every σ > 0
    spread, med = robust_spread(z), float(np.median(z))
    return [
        Check(
            name="reference vs closed-form sphere-light irradiance, occluders removed: z-score robust spread",
            value=spread,
            expected=f"1 ± {Z_SPREAD_TOLERANCE}",
            passed=bool(abs(spread - 1) <= Z_SPREAD_TOLERANCE),
        ),
        Check(
            name="same: z-score median",
            value=med,
            expected=f"|median| ≤ {Z_MEDIAN_TOLERANCE}",
            passed=bool(abs(med) <= Z_MEDIAN_TOLERANCE),
        ),
    ]


def checks(fl, fit_i, fit_l, unoccluded, arrays) -> list[Check]:
    hard = hard_point_deviation()
    fitted_errors = fl["errors"][FITTED_OMEGA.id]
    seed_max = fl["errors"][SEED_OMEGA.id]["full"]["max"]
    finite = all(np.all(np.isfinite(img)) for a in arrays.values() for img in a["images"].values())
    return [
        Check(
            name="closed form vs independent quadrature over the grid (max |ΔΩ| / smaller cap)",
            value=fl["quad_dev"],
            expected="≤ 1e-4",
            passed=fl["quad_dev"] <= 1e-4,
        ),
        Check(
            name="closed form vs adaptive quadrature (SciPy, float64) at 5 points incl. near-tangent tiny "
            "caps (max |ΔΩ| / smaller cap)",
            value=hard,
            expected="≤ 1e-10",
            passed=hard <= 1e-10,
        ),
        Check(
            name="closed form on nested / disjoint / covering grid points vs their closed values",
            value=fl["closed_dev"],
            expected="≤ 1e-12",
            passed=fl["closed_dev"] <= 1e-12,
        ),
        Check(
            name="fitted form stays within [0, smaller cap] on the grid",
            value=str(fitted_errors["in_bounds"]),
            expected="True",
            passed=fitted_errors["in_bounds"],
        ),
        Check(
            name="fitted form beats the smoothstep: max error, full domain",
            value=fitted_errors["full"]["max"],
            expected=f"< {seed_max:.4g}",
            passed=fitted_errors["full"]["max"] < seed_max,
        ),
        Check(
            name="intersection fit converged",
            value=str(fit_i["converged"]),
            expected="True",
            passed=bool(fit_i["converged"]),
        ),
        Check(
            name="Lambert-weight fit converged",
            value=str(fit_l["converged"]),
            expected="True",
            passed=bool(fit_l["converged"]),
        ),
        Check(
            name="Lambert-factor quadrature: change with doubled nodes (max, fraction of the light cap)",
            value=fit_l["quad_resolution"],
            expected="≤ 0.01",
            passed=fit_l["quad_resolution"] <= 0.01,
        ),
        *unoccluded_check(unoccluded),
        Check(
            name="every shaded probe finite (no NaN/Inf)", value=str(finite), expected="True", passed=finite
        ),
    ]


# ============================================================================================== figures
def map_figure(out, fitted) -> dict:
    """Signed error maps over (d, r1) for r2 = ρ·r1, ρ ∈ {1, 0.5, 0.2}, r1 ∈ (0, π/2]."""
    plt = figures.pyplot()
    n = 160
    r1 = (np.arange(n) + 0.5) / n * (PI / 2)
    d = (np.arange(n) + 0.5) / n * PI
    R1, D = np.meshgrid(r1, d, indexing="ij")
    ratios = (1.0, 0.5, 0.2)
    fig, axes = plt.subplots(len(ratios), len(APPROX), figsize=(10, 8.2), squeeze=False)
    im = None
    for i, rho in enumerate(ratios):
        R2 = rho * R1
        caps = {"r1": R1, "r2": R2, "d": D}
        ex = EXACT.evaluate(caps)
        a_min = smaller_cap(R1, R2)
        for j, m in enumerate(APPROX):
            err = (m.evaluate(caps, params_of(m, fitted)) - ex) / a_min
            err = np.where((D > np.abs(R1 - R2)) & (D < R1 + R2), err, np.nan)
            im = axes[i, j].imshow(
                err,
                origin="lower",
                extent=[0, 180, 0, 90],
                aspect="auto",
                cmap="RdBu_r",
                vmin=-0.16,
                vmax=0.16,
            )
            axes[i, j].set_title(f"{m.id}, r₂ = {rho:g}·r₁", fontsize=9)
            axes[i, j].set_xlabel("d (deg)", fontsize=8)
            axes[i, j].set_ylabel("r₁ (deg)", fontsize=8)
    fig.subplots_adjust(hspace=0.5, wspace=0.35)
    fig.colorbar(im, ax=axes, shrink=0.6, label="(Ω_approx − Ω_exact) / smaller cap")
    name = "figures/error_maps.png"
    figures.save_figure(fig, out / name)
    return {
        "file": name,
        "section": "function-level",
        "caption": "Signed error of the smoothstep (seed), linear ramp and fitted forms over the centre "
        "distance d and the larger radius r₁, for cap ratios r₂/r₁ = 1, 0.5, 0.2, as a fraction "
        "of the smaller cap; white outside the partial-overlap band. Colour range ±0.16.",
    }


def curve_figure(out, fitted) -> dict:
    d = np.linspace(0, PI, 400)
    series = []
    for r1, r2 in ((0.5, 0.5), (1.2, 0.3), (PI / 2, PI / 2)):
        caps = {"r1": np.full_like(d, r1), "r2": np.full_like(d, r2), "d": d}
        for m in OMEGA:
            series.append(
                {
                    "x": np.degrees(d),
                    "y": m.evaluate(caps, params_of(m, fitted)) / cap_area(min(r1, r2)),
                    "label": m.id,
                    "panel": f"r₁ = {math.degrees(r1):.0f}°, r₂ = {math.degrees(r2):.0f}°",
                }
            )
    path = out / "figures/intersection_curves.png"
    _panels(path, series, "d (deg)", "Ω / smaller cap")
    return {
        "file": "figures/intersection_curves.png",
        "section": "function-level",
        "caption": "Intersection solid angle over the centre distance for three cap pairs, as a fraction "
        "of the smaller cap. Two hemispheres (right): the exact lune 2(π − d) is linear in d; "
        "the smoothstep bends it into an S.",
    }


def _panels(path, series, xl, yl):
    plt = figures.pyplot()
    panels = list(dict.fromkeys(s["panel"] for s in series))
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.3), squeeze=False)
    for k, p in enumerate(panels):
        ax = axes[0, k]
        for s in series:
            if s["panel"] == p:
                ax.plot(s["x"], s["y"], label=s["label"], lw=1.2)
        ax.set_title(p, fontsize=9)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    figures.save_figure(fig, path)


def scene_figures(out, cases, arrays) -> list[dict]:
    figs = []
    for c in cases:
        a = arrays[c["id"]]
        panels = [(m, a["images"][m]) for m in a["show"]]  # row ids: short enough for panel titles
        name = f"figures/{c['id']}.png"
        figures.image_comparison(
            out / name,
            a["ref"],
            panels,
            a["mask"],
            error_scale=1.0,
            title=f"{c['label']}: reference, methods, signed error (fraction of peak)",
            exposure=1.0,
        )
        figs.append(
            {
                "file": name,
                "section": "results",
                "caption": f"{c['label']}. Top: Mitsuba irradiance probes on the receiver (as an image) and "
                "each method; bottom: signed error as a fraction of the unshadowed peak "
                "(red: too bright). Grey: outside the receiver.",
            }
        )
    return figs


def pareto_figure(out, fl, cost_rows) -> dict:
    pts = []
    for m in OMEGA:
        c = next(r for r in cost_rows if r["method"] == f"omega-{m.id}")
        y = 1e-7 if m.exact else fl["errors"][m.id]["full"]["max"]  # exact: plotted at its float32 level
        pts.append({"x": c["ns_per_pixel"], "y": y, "label": m.id})
    name = "figures/pareto.png"
    figures.pareto_plot(
        out / name,
        pts,
        "ns per evaluation",
        "max |ΔΩ| / smaller cap (full domain)",
        title="Intersection forms: error vs cost (exact plotted at its float32 level, 1e-7)",
    )
    return {
        "file": name,
        "section": "costs",
        "caption": "Maximum error over the full domain against the measured cost per evaluation, same run.",
    }


def scene_pareto_figure(out, cases, cost_rows) -> dict:
    """Mean RMSE over the light cases (vs the path tracer) against the measured shading cost."""
    light = [c for c in cases if c["id"].endswith("-light")]
    floor = float(np.mean([_approx(c, "cap-model")["metrics"]["rmse"]["noise_floor"] for c in light]))
    pts = []
    for method in COST_SHADING:
        c = next(r for r in cost_rows if r["method"] == method)
        y = float(np.mean([_rmse(case, method) for case in light]))
        pts.append({"x": c["ns_per_pixel"], "y": y, "label": method})
    name = "figures/pareto_scenes.png"
    figures.pareto_plot(
        out / name,
        pts,
        "ns per pixel (light term)",
        "mean RMSE over the light cases",
        title="Ambient-aperture shading: error vs cost",
        floor=floor,
    )
    return {
        "file": name,
        "section": "costs",
        "caption": "Scene level: RMSE against the path tracer (mean over the three light cases, fraction of "
        "the unshadowed peak) against the measured cost of the light term per pixel; the dotted "
        "line is the reference's noise floor. The cap model's own error bounds what any formula "
        "can reach.",
    }


# ============================================================================================== summary
FITS = (
    (
        "intersection",
        "Fitted cap-intersection form",
        "f = sat(t²(3−2t) + t(1−t)[c0 + c1u + ρ(c2 + c3u) + σ(c4 + c5u)]), u = 1 − 2t, "
        "after the complement trick",
        "fit-intersection",
        "fraction of the smaller cap",
    ),
    (
        "lambert",
        "Centroid weight of the Lambert factor",
        "c = normalize(w l + (1 − w) a), w = A(r_a)^k / (A(r_a)^k + A(α)^k)",
        "fit-lambert",
        "fraction of the light cap's solid angle",
    ),
)
"""The two fits: (id, label, model, job label, residual units)."""


FIT_METHODS = {"fit-intersection": FITTED_OMEGA, "fit-lambert": FITTED_LAMBERT}
"""The method of `METHODS` whose parameters each fit determines (its shader text carries them)."""


def write_fitted(out, fit_i, fit_l, fl, ctx=None, cfg=None, cases=()) -> list[dict]:
    """fitted/<id>.json of each fit in format ``rtfit.fitted/1`` (`rtfit.experiments.fitted`: the fitted
    method's parameters, residual, GLSL/HLSL; the fit's errors as data) and the results' fit rows."""
    fits = {"fit-intersection": fit_i, "fit-lambert": fit_l}
    errors = {"fit-intersection": fl["errors"][FITTED_OMEGA.id], "fit-lambert": fit_l["errors"]}
    hashes = [
        c["scene"]["hash"] for c in cases if isinstance(c.get("scene"), dict) and c["scene"].get("hash")
    ]
    prov = fitfiles.provenance(ctx, "ambient-aperture", hashes, (cfg or {}).get("spp"))
    docs = []
    for fid, label, model, job, units in FITS:
        fit = fits[job]
        file = f"fitted/{fid}.json"
        m = FIT_METHODS[job]
        own = {k: v for k, v in fit["parameters"].items() if k in m.params}
        entry = fitfiles.method_entry(
            m,
            {**fit, "parameters": own},
            id=fid,
            label=label,
            residual_units=units,
            data={
                "model": model,
                "errors": errors[job],
                **{k: v for k, v in fit.items() if k not in ("parameters", "errors")},
            },
        )
        docs.append(
            fitfiles.write_fit(
                out,
                file,
                title=f"ambient aperture: {label}",
                provenance=prov,
                entry=entry,
                doc_id=fid,
                label=label,
                model=model,
                fit=fit,
            )
        )
    return docs


def headline(fl) -> list[dict]:
    return [
        {
            "label": "smoothstep max error, r ≤ π/2 (fraction of smaller cap)",
            "value": fl["errors"][SEED_OMEGA.id]["hemisphere"]["max"],
            "unit": "of smaller cap",
        },
        {
            "label": "fitted max error, full domain",
            "value": fl["errors"][FITTED_OMEGA.id]["full"]["max"],
            "unit": "of smaller cap",
        },
    ]


NOTES = [
    (
        "Function level: errors are (Ω_approx − Ω_exact) / A(min(r1, r2)), over the partial-overlap points "
        "of the (r1, r2, d) grid (nested, disjoint and covering points are exact for the seed's cases and "
        "for the fitted form)."
    ),
    (
        "Scene level: irradiance as a fraction of the unshadowed peak — for the light cases the largest "
        "unshadowed sphere-light irradiance over the probes, for the sky cases π·L_sky with L_sky = 1. "
        "Probes are points on the receiver laid out as an image; the reference is Mitsuba's direct "
        "irradiance (emitter sampling + cosine sampling, MIS)."
    ),
    (
        "The bent normal and aperture are baked with Mitsuba ray casts (uniformly distributed, stratified "
        "hemisphere directions, lights removed), as a baker would; their own Monte Carlo noise is part of "
        "the cap model's error."
    ),
    (
        "ꟻLIP is computed in the full run only (its cost on a busy 2-core machine would exceed the quick "
        "run's budget)."
    ),
]


# ================================================================================================ bench
def cost_inputs(n: int, backend: str, seed: int = 1):
    """Random (r1, r2, d) ∈ [0, π/2]² × [0, π], float32: NumPy arrays and the same on Dr.Jit."""
    rng = np.random.default_rng(seed)
    r1 = rng.uniform(0, PI / 2, n).astype(np.float32)
    r2 = rng.uniform(0, PI / 2, n).astype(np.float32)
    d = rng.uniform(0, PI, n).astype(np.float32)
    Float = backend_float(backend)
    return (r1, r2, d), (Float(r1), Float(r2), Float(d))


def shading_inputs(n: int, backend: str, seed: int = 2):
    """Random cos(n,a), cos(n,l), cos(a,l), r_a, α (float32 Dr.Jit arrays) for the shading cost rows."""
    rng = np.random.default_rng(seed)
    arrs = (
        rng.uniform(0, 1, n),
        rng.uniform(-0.2, 1, n),
        rng.uniform(-1, 1, n),
        rng.uniform(0, PI / 2, n),
        rng.uniform(0.005, 0.3, n),
    )
    Float = backend_float(backend)
    return tuple(Float(x.astype(np.float32)) for x in arrs)


def drjit_call(method: Method, params=None, **constants) -> Callable:
    """``f(*arrays)``: the method on Dr.Jit arrays given in its input order (``constants``: inputs held
    fixed)."""
    names = [n for n in method.input_names if n not in constants]

    def call(*xs):
        return method.evaluate({**dict(zip(names, xs, strict=True)), **constants}, params)

    return call


def numpy_call(method: Method, params=None) -> Callable:
    """``f(*arrays)``: the same kernel text on NumPy (`NUMPY_OPS`, no conversion, no validation)."""

    def call(*xs):
        with np.errstate(all="ignore"):  # the kernels' guarded branches (select) evaluate both sides
            return method(NUMPY_OPS, dict(zip(method.input_names, xs, strict=True)), params)

    return call


def costs(ctx, cfg, fitted) -> list[dict]:
    """Cost rows (same run): each intersection form, the memory floor, the timed shading methods."""
    backend = backend_of(ctx.variant)
    n = cfg["cost_elements"]
    _, dr_args = cost_inputs(n, backend)
    note = "per evaluation: r1, r2, d in memory (float32), one float out"
    rows = [
        cost_row(
            f"omega-{m.id}",
            m.label,
            backend,
            time_drjit(drjit_call(m, params_of(m, fitted)), dr_args, n),
            note,
        )
        for m in OMEGA
    ]
    rows.append(memory_floor_row(dr_args, n, backend, "the memory-bound floor for these kernels"))
    sh = shading_inputs(n, backend)
    note = "per pixel: cos(n,a), cos(n,l), cos(a,l), r_a, α in memory; light term only"
    for m in (METHODS[mid] for mid in COST_SHADING):
        t = time_drjit(drjit_call(m, params_of(m, fitted), radiance=1.0), sh, n)
        rows.append(cost_row(m.id, m.label, backend, t, note))
    return rows


def bench_reference(ctx) -> list[dict]:
    """The probe reference's samples/s (direct irradiance: emitter + cosine sampling with MIS, as
    `scene_job` renders it) beside ``mi.render`` of the same scene (``aperture_hole``, its sphere light)
    with the same ``direct`` estimator, side by side (`reference_vs_stock_rows`). The probes are the
    camera's first hits, so both estimate the same points; ``mi.render`` also traces the camera ray. The
    probes are on the device before the timing (`device_probes`: a reference's passes share one upload). At
    each of `reference_sizes` (non-quick: 256² × 256 spp and the pixel-bound 1024² × 64 spp)."""
    rows = []
    for res, spp in reference_sizes(ctx.quick, (64, 64), (256, 256)):
        scene = load_scene(library_path("aperture_hole"))
        scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, width=res, height=res))
        mi, ms = load_mitsuba_scene(scene, ctx.variant)
        gb = gbuffer(mi, ms)
        keep = gb.mask & ~gb.emitter
        p, n = gb.position[keep], gb.normal[keep]
        # the probes on the device once per reference, as the reference cache does
        probes = device_probes(mi, p, n, normalise=False)
        rows += reference_vs_stock_rows(
            f"rtfit irradiance probes, direct MIS ({len(p)} first hits on the device, {spp} spp)",
            lambda seed, mi=mi, ms=ms, probes=probes, spp=spp: irradiance_pass(
                mi, ms, probes, None, spp, seed, dtype=REFERENCE_PASS_DTYPE
            ),
            len(p) * spp,
            [
                Stock(
                    f"mi.render, same scene and integrator ({res}², {spp} spp)",
                    stock_render(mi, ms, spp),
                    res * res * spp,
                )
            ],
            ctx.variant,
            rounds=3 if ctx.quick else 5,
        )
    return rows


def bench(ctx) -> list[dict]:
    """Evaluations/s of each intersection form, Dr.Jit vs NumPy (same kernel text, default parameters),
    then the reference beside ``mi.render`` (`bench_reference`)."""
    backend, n = bench_backend(ctx)
    np_args, dr_args = cost_inputs(n, backend)
    np64 = tuple(x.astype(np.float64) for x in np_args)
    timed = (
        (m.label, time_drjit(drjit_call(m), dr_args, n), time_numpy(numpy_call(m), np64, n)) for m in OMEGA
    )
    return comparison_rows(backend, dr_args, n, timed, baseline=BASELINE) + bench_reference(ctx)
