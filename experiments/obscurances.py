"""Experiment ``obscurances``: Zhukov/Iones obscurances (GameTools D5.3 §2.10, 001:3251-3380) against their
own Monte Carlo definition and against path-traced light under a uniform ambient.

What is compared and why. An engine bakes the obscurance W(x) = (1/π)∫ρ(d(x, ω)) cos θ dω (a lightmap,
`rtfit.realtime.obscurances`) from a few ray-cast hit distances per texel and shades the ambient term as
I_A · s · W. Two questions:

1. **How many rays?** The K-ray estimator (1/K)Σ_k ρ(d_k) (K stratified cosine directions, rotated per
   point) against ground truth (a): the model's own definition, Monte Carlo with Mitsuba ray casts
   (`rtfit.reference.occlusion`, quantity ``obscurance``; exact for the model, its noise known), at the seed's
   ρ = √(d/d_max), d_max = 0.3 (001:3284, 001:3326). Error vs rays per point vs cost.
2. **How good a stand-in for indirect light?** s·W against ground truth (b), quantity ``ambient_global``:
   E(x)/(πL) under a *uniform ambient* — a constant environment of radiance L over the whole sphere — with
   all interreflections between white diffuse surfaces of albedo ``albedo`` (Russian-roulette path tracing on
   Mitsuba's ray tracer). It is 1 at an unoccluded point for any normal, as W is. d_max, the exponent p and
   the ambient scale s are fitted per scene and jointly (`rtfit.fitting.fit_method` through the JAX run of the
   kernel text), for the power ρ = min(d/d_max, 1)^p and the exponential ρ = 1 − e^{−d/d_max}.

Scenes: the ``sdf-occlusion`` scenes (``scenes/library/sdf_*.toml``) at that experiment's resolution, so the
``ao`` references (within R = ``ao_distance``; and R = ∞) come from the same cache entries (`OcclusionCache`
keys: geometry, points, quantity, distance, seed, samples per pass, variant): the p → ∞ identity (step ρ =
AO within d_max) and the d_max → ∞ limit (W → AO(∞)) are checked against them.

Self-checks (closed forms, `rtfit.realtime.obscurances.plane_facing_obscurance`): an open plane gives W = 1
exactly (reference and estimator); a point facing an infinite plane from height h matches the closed forms of
the power, exponential and step ρ (z-test); a point at the centre of a sphere has W = ρ(R) exactly; the
uniform
ambient facing a plane of albedo a is a (white furnace); the d_max → 0 and → ∞ limits; the estimator's bias
against reference (a) is zero within its noise; W_power ≥ AO(d_max) on every point.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import replace

import numpy as np

from rtfit.fitting import fit_method, grey_metrics, zero_padded
from rtfit.fitting.stats import sidak_threshold
from rtfit.realtime import get_default_backend
from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS, backend_float
from rtfit.realtime.obscurances import (
    METHODS,
    SEED_D_MAX,
    SEED_EXPONENT,
    cosine_spiral_directions,
    distance_weight,
    plane_facing_obscurance,
)
from rtfit.reference import load_mitsuba_scene
from rtfit.reference.build import tiled_quad_shape
from rtfit.reference.estimators import gbuffer, gbuffer_points
from rtfit.reference.occlusion import OcclusionCache, hit_distances
from rtfit.scenes import scene_hash

from . import figures
from . import fitted as fitfiles
from .cost import attach_costs, bench_backend, comparison_rows, time_drjit, time_numpy
from .jobs import Job, reference_args
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .sdf_occlusion_scenes import SCENE_NAMES, load_case_scene

# ============================================================================================ configure
METRICS = ("rmse", "rel_mse", "mae", "max_abs", "psnr")
FIT_METHODS = ("power", "exponential")

CONFIG = {
    "scenes": ConfigKey("str", "scenes (sdf-occlusion's)", shape=(None,), choices=SCENE_NAMES),
    "resolution": ConfigKey("int", "image side (pixels)", 8, 4096),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "d_max": ConfigKey("float", "d_max of reference (a) (scene units; seed 0.3)", 1e-4, 1e4),
    "exponent": ConfigKey("float", "exponent p of reference (a) (seed ½)", 0.0, 64.0),
    "rays": ConfigKey("int", "rays per point of the estimator sweep", 1, 4096, (None,)),
    "fit_rays": ConfigKey("int", "rays per point of the fitted estimators", 1, 4096),
    "albedo": ConfigKey("float", "surface albedo of the uniform-ambient reference", 0.0, 0.99),
    "ao_distance": ConfigKey("float", "AO radius shared with sdf-occlusion (scene units)", 1e-6, 1e3),
    "probe_spp": ConfigKey("int", "samples per closed-form probe", 2, SPP_MAX),
    "cost_points": ConfigKey("int", "points per timed launch", 256, 1 << 24),
}


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "scenes": ["crease_90", "sphere_plane", "room", "boxes"] if quick else list(SCENE_NAMES),
            "resolution": 36 if quick else 128,
            "spp": spp or (64 if quick else 1024),
            "pass_spp": 32 if quick else 256,
            "d_max": SEED_D_MAX,
            "exponent": SEED_EXPONENT,
            "rays": [4, 8, 16, 32, 64] if quick else [4, 8, 16, 32, 64, 128, 256],
            "fit_rays": 32 if quick else 256,
            "albedo": 0.8,
            "ao_distance": 1.0,
            "probe_spp": 4096 if quick else 65536,
            "cost_points": 1 << 16 if quick else 1 << 20,
        },
    )


# ================================================================================== reference (a): the model
weight_of = distance_weight
"""(ρ as a callable on Dr.Jit arrays, its cache key) for the ``obscurance`` reference quantity
(`rtfit.realtime.obscurances.distance_weight`)."""


def _ref_dict(r) -> dict:
    return {"mean": r.mean, "stderr": r.stderr, "meta": r.to_dict()}


# ================================================================================================= jobs
def render_case(
    name,
    resolution,
    spp,
    pass_spp,
    seed,
    variant,
    cache_dir,
    d_max,
    exponent,
    rays,
    fit_rays,
    albedo,
    ao_distance,
    identities,
) -> dict:
    """Job: one scene's G-buffer, references (a) and (b), the shared ``ao`` references, and the hit
    distances of the K-ray estimators (plain data out). ``identities``: also the step-ρ and d_max → ∞
    references of the identity checks."""
    scene = load_case_scene(name, resolution)
    mi, mi_scene = load_mitsuba_scene(scene, variant)
    gb = gbuffer(mi, mi_scene)
    mask = gb.mask
    pts, nrm = gbuffer_points(gb, mask)
    cache = OcclusionCache(cache_dir)
    geo = scene_hash(scene)

    def ref(quantity, **kw):
        return cache.get(
            mi,
            mi_scene,
            geo,
            pts,
            nrm,
            spp=spp,
            pass_spp=pass_spp,
            seed=seed,
            variant=variant,
            quantity=quantity,
            **kw,
        )

    fn, key = weight_of("power", d_max, exponent)
    refs = {
        "model": _ref_dict(ref("obscurance", distance_weight=fn, weight_key=key)),
        "ambient": _ref_dict(ref("ambient_global", albedo=albedo)),
        "ao": _ref_dict(ref("ao", max_distance=ao_distance)),  # sdf-occlusion's entry
    }
    if identities:
        fn, key = weight_of("step", ao_distance)
        refs["step"] = _ref_dict(ref("obscurance", distance_weight=fn, weight_key=key))
        fn, key = weight_of("power", 1e30, exponent)
        refs["far"] = _ref_dict(ref("obscurance", distance_weight=fn, weight_key=key))
        refs["ao_inf"] = _ref_dict(ref("ao"))
    dist, ray_seconds = {}, {}
    for k in sorted({*rays, fit_rays}):
        dirs = cosine_spiral_directions(k)
        dist[k] = hit_distances(mi, mi_scene, pts, nrm, dirs, rotate_seed=seed + k)
        t0 = time.perf_counter()  # the second call, timed: the first one compiled the ray-cast kernel
        hit_distances(mi, mi_scene, pts, nrm, dirs, rotate_seed=seed + k)
        ray_seconds[k] = time.perf_counter() - t0
    return {
        "mask": mask,
        "points": pts,
        "normals": nrm,
        "refs": refs,
        "distances": dist,
        "ray_seconds": ray_seconds,
        "scene_hash": geo,
    }


# ------------------------------------------------------------------------------- closed-form probe scenes
PROBE_HEIGHTS = (0.05, 0.15, 0.3)
PLANE_HALF = 5000.0
SPHERE_RADIUS = 0.7


RAY_EPSILON = 1500.0 * 2.0**-24
"""Mitsuba's ``math::RayEpsilon<float>``: ``Interaction::spawn_ray`` starts a ray at p + (1 + max|p|)·ε·n."""


def spawn_height(h: float) -> float:
    """Height over the plane of the origin the reference's rays leave from, for a probe at (0, 0, h) facing
    down: h − (1 + h)·ε (`RAY_EPSILON`). The closed forms are evaluated there, since that is the point the
    reference measures: at h = d_max the step ρ is 1 on every ray from h itself but 0 on the rays with
    μ > (h − ε)/d_max from the offset origin (W = 0.99923, not 1: z = −6.3 at 65536 spp before, session 6)."""
    return h - (1.0 + abs(h)) * RAY_EPSILON


def _probe_scene(mi, kind: str):
    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    if kind == "plane":  # z = 0, 10⁴ × 10⁴: a ray at μ from a point at height h misses only if μ < h/5000
        # Tiled finely near the origin (`tiled_quad`): as one 10⁴ m rectangle, OptiX's float32 intersection
        # re-hit the plane from the points on it (H200: the open plane's W came out 0.94, not 1).
        a, b = (2 * PLANE_HALF, 0.0, 0.0), (0.0, 2 * PLANE_HALF, 0.0)
        shape = tiled_quad_shape((-PLANE_HALF, -PLANE_HALF, 0.0), a, b)
    else:
        shape = {"type": "sphere", "radius": SPHERE_RADIUS, "flip_normals": True}
    return mi.load_dict({"type": "scene", "shape": {**shape, "bsdf": white}})


def probe_job(
    variant: str, cache_dir: str, seed: int, probe_spp: int, d_max: float, exponent: float, albedo: float
) -> dict:
    """Job: the closed-form configurations (plain data out)."""
    import mitsuba as mi  # (heavy: only inside the job)

    mi.set_variant(variant)
    cache = OcclusionCache(cache_dir)
    out = {}
    plane = _probe_scene(mi, "plane")
    per = min(probe_spp, 1024)

    def ref(scene, tag, pts, nrm, quantity, **kw):
        return cache.get(
            mi,
            scene,
            f"obscurance-probe-{tag}",
            pts,
            nrm,
            spp=probe_spp,
            pass_spp=per,
            seed=seed,
            variant=variant,
            quantity=quantity,
            **kw,
        )

    # open plane: points on it facing up, nothing above
    op = np.column_stack([np.linspace(-2, 2, 16), np.linspace(-1, 1, 16), np.zeros(16)])
    on = np.tile([0.0, 0.0, 1.0], (16, 1))
    fn, key = weight_of("power", d_max, exponent)
    out["open_model"] = ref(plane, "plane", op, on, "obscurance", distance_weight=fn, weight_key=key).mean
    out["open_ambient"] = ref(plane, "plane", op, on, "ambient_global", albedo=albedo).mean
    out["open_distances"] = hit_distances(mi, plane, op, on, cosine_spiral_directions(64), rotate_seed=seed)
    # a point facing the plane from height h
    hp = np.column_stack([np.zeros(len(PROBE_HEIGHTS)), np.zeros(len(PROBE_HEIGHTS)), PROBE_HEIGHTS])
    hn = np.tile([0.0, 0.0, -1.0], (len(PROBE_HEIGHTS), 1))
    facing = {}
    for form, p in (("power", exponent), ("exponential", None), ("step", None)):
        fn, key = weight_of(form, d_max, p)
        r = ref(plane, "plane", hp, hn, "obscurance", distance_weight=fn, weight_key=key)
        expect = [plane_facing_obscurance(spawn_height(h), d_max, p, form) for h in PROBE_HEIGHTS]
        facing[form] = {"mean": r.mean, "stderr": r.stderr, "expected": np.asarray(expect)}
    out["facing"] = facing
    r = ref(plane, "plane", hp, hn, "ambient_global", albedo=albedo)
    out["furnace"] = {"mean": r.mean, "stderr": r.stderr}
    # centre of a sphere (seen from inside): every ray hits at R
    sphere = _probe_scene(mi, "sphere")
    sp = np.zeros((6, 3))
    sn = np.vstack([np.eye(3), -np.eye(3)])
    fn, key = weight_of("power", d_max * 4.0, exponent)
    out["sphere_model"] = ref(sphere, "sphere", sp, sn, "obscurance", distance_weight=fn, weight_key=key).mean
    out["sphere_distances"] = hit_distances(
        mi, sphere, sp, sn, cosine_spiral_directions(32), rotate_seed=seed
    )
    return out


# ================================================================================================= fits


FIT_POINTS = 4096
"""Residual points of every fit: a fixed random subsample of each scene's pixels for a per-scene fit, and
FIT_POINTS/len(scenes) of each scene for the joint fit, so every fit has the same size (one JAX compile per
method) and its cost does not grow with the resolution or the scene count (`fit_rows`)."""
FIT_MAX_STEPS = 48
"""Levenberg–Marquardt steps of a fit before a parameter crawling to its bound (d_max → 10³ of the power
form) is pinned on it and the rest re-solved (`rtfit.fitting.fit_least_squares`)."""
FIT_RETRY_STEPS = 256
"""Further steps, from where the first solve stopped, for a fit that has not converged after those."""


def _fit_inputs(r, fit_rays, seed_key: str, size: int):
    """The fit subsample (≤ ``size`` points, fixed per scene), its distances and target."""
    n = r["points"].shape[0]
    rng = np.random.default_rng(int(hashlib.sha256(seed_key.encode()).hexdigest()[:8], 16))
    idx = np.sort(rng.choice(n, size, replace=False)) if n > size else np.arange(n)
    d = np.minimum(r["distances"][fit_rays][:, idx], 1e30)  # a miss as 1e30: finite float64 for JAX
    return d, r["refs"]["ambient"]["mean"][idx]


def fit_rows(cfg, rendered) -> dict:
    """Per scene and joint fits of each `FIT_METHODS` method to the uniform-ambient reference (b), each on
    `FIT_POINTS` residuals (padded with zero weight where a scene has fewer pixels): a per-scene fit on a
    fixed subsample of its pixels, the joint fit on FIT_POINTS/len(scenes) of each scene's. One compiled
    residual per method serves every fit (the data are traced arguments)."""
    out = {}
    per_joint = max(1, FIT_POINTS // len(cfg["scenes"]))
    for mid in FIT_METHODS:
        m = METHODS[mid]
        per = {}
        parts = []
        for n in cfg["scenes"]:
            d, y = _fit_inputs(rendered[n], cfg["fit_rays"], n, FIT_POINTS)
            parts.append(_fit_inputs(rendered[n], cfg["fit_rays"], f"{n}/joint", per_joint))
            per[n] = _fit(m, d, y)
        d = np.concatenate([p[0] for p in parts], axis=1)
        y = np.concatenate([p[1] for p in parts])
        out[mid] = {"per_scene": per, "joint": _fit(m, d, y)}
    return out


def _fit(m, d, y) -> dict:
    """One fit on ≤ `FIT_POINTS` residuals: `FIT_MAX_STEPS` steps (a parameter crawling to a bound is pinned
    there by `fit_least_squares`), then, if still not converged, up to `FIT_RETRY_STEPS` more from where
    it stopped."""
    w = zero_padded(np.ones_like(y), FIT_POINTS)
    x, yy = {"distances": zero_padded(d, FIT_POINTS)}, zero_padded(y, FIT_POINTS)
    res = fit_method(m, x, yy, weights=w, max_steps=FIT_MAX_STEPS)
    steps = res.steps
    if not res.converged:
        start = {}
        for k, p in m.params.items():
            eps = 1e-9 * (p.upper - p.lower)
            start[k] = replace(p, initial=min(max(res.values[k], p.lower + eps), p.upper - eps))
        res = fit_method(m, x, yy, weights=w, params=start, max_steps=FIT_RETRY_STEPS)
        steps += res.steps
    fit = res.to_dict()
    fit["steps"] = int(steps)
    # The padding carries zero weight: the statistics count the real residuals only.
    n, k = int(y.size), len(fit["param_names"])
    pad_dof = fit["dof"]
    fit["n_residuals"], fit["dof"] = n, n - k
    if fit.get("ssr") is not None:
        fit["rms_residual"] = math.sqrt(fit["ssr"] / n)
    if n > k:
        for v in fit["parameters"].values():  # s² = SSR/dof: the padded fit divided by the padded dof
            if v.get("stderr") is not None:
                v["stderr"] *= math.sqrt(pad_dof / (n - k))
    return fit


def _values(fit: dict) -> dict:
    return {k: v["value"] for k, v in fit["parameters"].items()}


# ================================================================================================ cases
def _metrics(img, ref_img, err_img, mask):
    return grey_metrics(img, ref_img, err_img, mask, METRICS)


def _image(mask, values):
    img = np.zeros(mask.shape)
    img[mask] = values
    return img


def _float():
    return backend_float()


def _eval(method_id: str, distances, params: dict | None = None):
    """A method of the table on (K, N) distances (misses as +∞): its kernel text on NumPy in float64 (the
    report's predictions; a Dr.Jit run would compile one kernel per parameter value — the product's Dr.Jit
    run is what `measure_costs` times)."""
    d = np.asarray(distances, dtype=np.float64)
    return np.asarray(METHODS[method_id](NUMPY_OPS, {"distances": d}, params), dtype=np.float64)


def ambient_rows(cfg, r, fits, name):
    """(row id, label, fitted, parameters, prediction) of the uniform-ambient case of scene ``name``."""
    d = r["distances"][cfg["fit_rays"]]
    rows = [
        (
            "seed",
            METHODS["seed"].label,
            False,
            {"d_max": SEED_D_MAX, "exponent": SEED_EXPONENT},
            _eval("seed", d),
        )
    ]
    for mid in FIT_METHODS:
        for which, fit in (("", fits[mid]["per_scene"][name]), ("-joint", fits[mid]["joint"])):
            p = _values(fit)
            label = METHODS[mid].label + (" — one joint set" if which else " — fitted per scene")
            rows.append((mid + which, label, True, p, _eval(mid, d, p)))
    rows.append(
        (
            "ao",
            f"AO within {cfg['ao_distance']:g} (step ρ)",
            False,
            {"d_max": cfg["ao_distance"]},
            _eval("ao", d, {"d_max": cfg["ao_distance"]}),
        )
    )
    return rows


def model_rows(cfg, r):
    """The seed estimator with K rays (each K of ``rays``) against reference (a)."""
    out = []
    for k in cfg["rays"]:
        p = {"d_max": cfg["d_max"], "exponent": cfg["exponent"]}
        out.append(
            (
                f"rays-{k}",
                f"{k} rays per point",
                False,
                {"rays": k},
                _eval("power", r["distances"][k], {**p, "scale": 1.0}),
            )
        )
    return out


def evaluate_cases(cfg, rendered, fits):
    docs, errors = [], {}
    for n in cfg["scenes"]:
        r = rendered[n]
        mask = r["mask"]
        for target, rows in (("model", model_rows(cfg, r)), ("ambient", ambient_rows(cfg, r, fits, n))):
            ref = r["refs"][target]
            ref_img, err_img = _image(mask, ref["mean"]), _image(mask, ref["stderr"])
            approx = []
            for rid, label, fitted, params, pred in rows:
                met = _metrics(_image(mask, pred), ref_img, err_img, mask)
                errors[(n, target, rid)] = met["rmse"]["value"]
                approx.append(
                    {
                        "method": rid,
                        "label": label,
                        "fitted": fitted,
                        "parameters": {k: float(v) for k, v in params.items()},
                        "metrics": met,
                        "cost": None,
                        "figures": [],
                    }
                )
            docs.append(
                {
                    "id": f"{n}-{target}".replace("_", ""),
                    "label": f"{n.replace('_', ' ')}: "
                    + (
                        f"obscurance W (ρ = min(d/{cfg['d_max']:g}, 1)^{cfg['exponent']:g}), "
                        "Monte Carlo of the model"
                        if target == "model"
                        else f"uniform ambient with interreflections (albedo {cfg['albedo']:g}), E/πL"
                    ),
                    "parameters": {
                        "scene": n,
                        "target": target,
                        "d_max": cfg["d_max"],
                        "exponent": cfg["exponent"],
                        "albedo": cfg["albedo"] if target == "ambient" else None,
                        "fit_rays": cfg["fit_rays"] if target == "ambient" else None,
                    },
                    "scene": {"name": f"sdf-{n}", "hash": r["scene_hash"]},
                    "reference": ref["meta"],
                    "approximations": approx,
                }
            )
    return docs, errors


# ============================================================================================== checks
def _check(name, value, expected, passed) -> Check:
    return Check(name=name, value=value, expected=expected, passed=bool(passed))


def _z_max(name, a, sa, b, sb, floor=1e-6):
    """max |a − b|/√(sa² + sb² + floor²) against the Šidák threshold of the element count (α = 1 %);
    ``floor``: float32 ray-distance precision."""
    z = (np.asarray(a) - np.asarray(b)) / np.sqrt(np.asarray(sa) ** 2 + np.asarray(sb) ** 2 + floor**2)
    thr = max(4.0, sidak_threshold(z.size))
    v = float(np.max(np.abs(z)))
    return _check(name, v, f"≤ {thr:.2f}", v <= thr)


def make_checks(cfg, rendered, probes, errors) -> list[dict]:
    checks = []
    # open plane: exactly 1 (all rays escape: zero variance)
    for key, what in (("open_model", "reference (a)"), ("open_ambient", "reference (b)")):
        dev = float(np.max(np.abs(probes[key] - 1.0)))
        checks.append(
            _check(f"open plane: {what} is exactly 1 (16 points)", dev, "max |W − 1| = 0", dev == 0.0)
        )
    w = _eval("power", probes["open_distances"], {"d_max": cfg["d_max"], "exponent": cfg["exponent"]})
    dev = float(np.max(np.abs(w - 1.0)))
    checks.append(_check("open plane: 64-ray estimator is exactly 1", dev, "max |W − 1| = 0", dev == 0.0))
    # point facing an infinite plane: closed forms
    for form, f in probes["facing"].items():
        checks.append(
            _z_max(
                f"point facing a plane at h = {', '.join(f'{h:g}' for h in PROBE_HEIGHTS)}: "
                f"Monte Carlo W ({form} ρ) "
                "vs closed form (max |z|)",
                f["mean"],
                f["stderr"],
                f["expected"],
                0.0,
            )
        )
    fur = probes["furnace"]
    checks.append(
        _z_max(
            f"uniform ambient facing a plane of albedo {cfg['albedo']:g} equals the albedo (max |z|)",
            fur["mean"],
            fur["stderr"],
            np.full(len(fur["mean"]), cfg["albedo"]),
            0.0,
        )
    )
    # sphere centre: W = ρ(R) exactly
    rho_r = min(SPHERE_RADIUS / (4.0 * cfg["d_max"]), 1.0) ** cfg["exponent"]  # every ray hits at R
    est = _eval(
        "power", probes["sphere_distances"], {"d_max": 4.0 * cfg["d_max"], "exponent": cfg["exponent"]}
    )
    dev = float(max(np.max(np.abs(probes["sphere_model"] - rho_r)), np.max(np.abs(est - rho_r))))
    # rays start at Mitsuba's spawn offset (≈ 9e-5 along n for |p| ≈ 0): |Δd| ≤ 1e-4, ρ'(0.7) = 0.48/unit
    checks.append(
        _check(
            "centre of a sphere: W = ρ(R) (reference and estimator)",
            dev,
            "≤ 1e-4 (spawn offset × ρ′)",
            dev <= 1e-4,
        )
    )
    # identities on the first scene: step ρ = AO within R (sdf-occlusion's shared reference),
    # d_max → ∞ = AO(∞)
    first = rendered[cfg["scenes"][0]]["refs"]
    # Both quantities draw the same cosine directions from the same streams (common random numbers: same
    # seed, points and pass layout), so the identities hold sample by sample: a difference can come only from
    # a hit at exactly t = R (one sample: 1/spp) or from ρ(d) = √(d/1e30) ≤ 1e-14 at finite d.
    dev = float(np.max(np.abs(first["step"]["mean"] - first["ao"]["mean"])))
    checks.append(
        _check(
            f"step ρ at d_max = {cfg['ao_distance']:g} equals sdf-occlusion's AO within R, sample by "
            f"sample ({cfg['scenes'][0]}, shared cache entry)",
            dev,
            f"≤ 1/spp = {1 / cfg['spp']:.3g}",
            dev <= 1.0 / cfg["spp"],
        )
    )
    dev = float(np.max(np.abs(first["far"]["mean"] - first["ao_inf"]["mean"])))
    checks.append(
        _check(
            f"d_max = 1e30 (→ ∞) equals AO with R = ∞, sample by sample ({cfg['scenes'][0]})",
            dev,
            "≤ 1e-12",
            dev <= 1e-12,
        )
    )
    # kernel limits and inequalities on the rendered distances
    worst_far = worst_zero = worst_order = 0.0
    for n in cfg["scenes"]:
        d = rendered[n]["distances"][cfg["fit_rays"]]
        big = _eval("power", d, {"d_max": 1e30, "exponent": cfg["exponent"], "scale": 1.0})
        aoinf = np.mean(np.isinf(d), axis=0)
        worst_far = max(worst_far, float(np.max(np.abs(big - aoinf))))
        zero = _eval("power", d, {"d_max": 1e-30, "exponent": cfg["exponent"], "scale": 1.0})
        worst_zero = max(worst_zero, float(np.max(np.abs(zero - 1.0))))
        wp = _eval("power", d, {"exponent": cfg["exponent"], "scale": 1.0, "d_max": cfg["ao_distance"]})
        ao = _eval("ao", d, {"d_max": cfg["ao_distance"]})
        worst_order = max(worst_order, float(np.max(ao - wp)))
    checks.append(
        _check(
            "estimator at d_max = 1e30 equals the escaping fraction (every scene)",
            worst_far,
            "≤ 1e-12",
            worst_far <= 1e-12,
        )
    )
    checks.append(
        _check("estimator at d_max = 1e-30 is 1 (every scene)", worst_zero, "= 0", worst_zero == 0.0)
    )
    checks.append(
        _check(
            "W_power(d_max) ≥ AO within d_max on every point (max AO − W)",
            worst_order,
            "≤ 1e-6",
            worst_order <= 1e-6,
        )
    )
    # the estimator is unbiased for the model: mean difference to reference (a) within its noise, every K
    zs = []
    for n in cfg["scenes"]:
        r = rendered[n]
        for k in cfg["rays"]:
            w = _eval("power", r["distances"][k], {"d_max": cfg["d_max"], "exponent": cfg["exponent"]})
            diff = w - r["refs"]["model"]["mean"]
            zs.append(float(np.mean(diff) / (np.std(diff, ddof=1) / math.sqrt(diff.size))))
    thr = max(4.0, sidak_threshold(len(zs)))
    v = float(np.max(np.abs(zs)))
    checks.append(
        _check(
            "K-ray estimator unbiased against reference (a): |mean difference|/its stderr, every scene and K",
            v,
            f"≤ {thr:.2f}",
            v <= thr,
        )
    )
    # error falls with rays
    bad = [
        n
        for n in cfg["scenes"]
        if errors[(n, "model", f"rays-{max(cfg['rays'])}")]
        >= errors[(n, "model", f"rays-{min(cfg['rays'])}")]
    ]
    checks.append(
        _check(
            f"RMSE at {max(cfg['rays'])} rays below {min(cfg['rays'])} rays (scenes failing)",
            len(bad),
            "0",
            not bad,
        )
    )
    # fits never worse than the seed
    bad = [n for n in cfg["scenes"] if errors[(n, "ambient", "power")] > errors[(n, "ambient", "seed")]]
    checks.append(
        _check(
            "fitted power obscurance no worse than the seed's (uniform ambient, scenes failing)",
            len(bad),
            "0",
            not bad,
        )
    )
    return checks


# ============================================================================================== figures
def make_figures(out, cfg, rendered, errors, costs) -> list[dict]:
    figs = []
    series = []
    for n in cfg["scenes"]:
        series.append(
            {
                "x": list(cfg["rays"]),
                "y": [errors[(n, "model", f"rays-{k}")] for k in cfg["rays"]],
                "label": n.replace("_", " "),
                "style": "line",
            }
        )
    k = np.array(cfg["rays"], dtype=float)
    series.append(
        {
            "x": k.tolist(),
            "y": (series[0]["y"][0] * np.sqrt(k[0] / k)).tolist(),
            "label": "∝ 1/√K",
            "style": "line",
        }
    )
    p = figures.line_plot(
        out / "rays_error.png",
        "rays per point K",
        "RMSE vs reference (a)",
        series,
        "Obscurance estimator: error vs rays",
        x_log=True,
        y_log=True,
    )
    figs.append(
        {
            "file": p.name,
            "caption": "RMSE of the K-ray seed estimator against the model's Monte Carlo "
            "reference (a) for each scene, beside a 1/√K slope; where a curve flattens it has reached the "
            "reference's own noise floor (see the case tables).",
            "section": "rays",
        }
    )
    cs = [c for c in costs if c["method"].startswith("rays-")]
    if cs:
        mean_err = [float(np.mean([errors[(n, "model", c["method"])] for n in cfg["scenes"]])) for c in cs]
        p = figures.line_plot(
            out / "rays_cost.png",
            "ns per point (ray casts + kernel, CPU)",
            "mean RMSE",
            [
                {
                    "x": [c["ns_per_pixel"] for c in cs],
                    "y": mean_err,
                    "label": "seed estimator",
                    "style": "line",
                }
            ],
            "Error vs cost",
            x_log=True,
            y_log=True,
        )
        figs.append(
            {
                "file": p.name,
                "caption": "Mean RMSE over the scenes against the measured cost per point.",
                "section": "rays",
            }
        )
    n0 = cfg["scenes"][-1]
    r = rendered[n0]
    return figs + _maps(out, cfg, r, n0)


def _maps(out, cfg, r, name) -> list[dict]:
    mask = r["mask"]
    ref = _image(mask, r["refs"]["ambient"]["mean"])
    d = r["distances"][cfg["fit_rays"]]
    panels = [
        ("seed", _image(mask, _eval("seed", d))),
        ("AO R=1", _image(mask, _eval("ao", d, {"d_max": 1.0}))),
    ]
    p = figures.image_comparison(
        out / f"maps_{name}.png", ref, panels, mask, 0.5, f"{name}: uniform ambient (E/πL) vs obscurance"
    )
    return [
        {
            "file": p.name,
            "caption": f"{name}: reference (b) and two estimators with their signed error.",
            "section": "fits",
        }
    ]


# ================================================================================================= cost
def measure_costs(cfg, rendered) -> list[dict]:
    """Per K: the measured ray-cast time per point (Mitsuba ray_intersect on this backend, from the render
    job) plus the kernel's own time per point (`time_drjit`)."""

    rows = []
    Float = _float()
    n = int(cfg["cost_points"])
    rng = np.random.default_rng(1)
    kern = METHODS["power"].kernel
    for k in cfg["rays"]:
        secs = sum(rendered[s]["ray_seconds"][k] for s in cfg["scenes"])
        pts = sum(rendered[s]["points"].shape[0] for s in cfg["scenes"])
        rows_d = [Float(rng.exponential(0.5, n).astype(np.float32)) for _ in range(k)]
        t = time_drjit(
            lambda *x: kern(DRJIT_OPS, list(x), d_max=cfg["d_max"], exponent=cfg["exponent"]),
            tuple(rows_d),
            n,
            repeats=3,
            min_seconds=0.05,
        )
        ns = secs / pts * 1e9 + t.ns_per_element
        rows.append(
            {
                "method": f"rays-{k}",
                "label": f"{k} rays: ray casts + ρ kernel",
                "backend": get_default_backend(),
                "ns_per_pixel": ns,
                "pixels_per_second": 1e9 / ns,
                "elements": n,
                "repeats": t.repeats,
                "note": f"ray casts {secs / pts * 1e9:.0f} ns/point (Mitsuba, inside the render job, "
                f"wall clock), kernel {t.ns_per_element:.1f} ns/point",
            }
        )
    return rows


# ================================================================================================== run
def run(ctx) -> dict:

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    common = dict(
        resolution=cfg["resolution"],
        **reference_args(ctx, cfg),
        d_max=cfg["d_max"],
        exponent=cfg["exponent"],
        rays=list(cfg["rays"]),
        fit_rays=cfg["fit_rays"],
        albedo=cfg["albedo"],
        ao_distance=cfg["ao_distance"],
    )
    jobs = [
        Job(
            render_case,
            dict(name=n, identities=(n == cfg["scenes"][0]), **common),
            label=n,
        )
        for n in cfg["scenes"]
    ]
    jobs.append(
        Job(
            probe_job,
            dict(
                variant=ctx.variant,
                cache_dir=str(ctx.cache_dir),
                seed=ctx.seed,
                probe_spp=cfg["probe_spp"],
                d_max=cfg["d_max"],
                exponent=cfg["exponent"],
                albedo=cfg["albedo"],
            ),
            label="probes",
        )
    )
    ctx.log(f"rendering references of {len(jobs) - 1} scenes and the closed-form probes")
    done = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="references"), strict=True))
    probes = done.pop("probes")
    rendered = done
    t0 = time.perf_counter()
    fits = fit_rows(cfg, rendered)
    ctx.log(f"fits done ({time.perf_counter() - t0:.1f} s)")
    case_docs, errors = evaluate_cases(cfg, rendered, fits)
    costs = measure_costs(cfg, rendered)

    attach_costs(case_docs, costs)
    out = ctx.out_dir
    figs = make_figures(out, cfg, rendered, errors, costs)
    checks = make_checks(cfg, rendered, probes, errors)
    fit_docs = write_fitted(out, cfg, fits, ctx, [rendered[n]["scene_hash"] for n in cfg["scenes"]])
    return {
        "summary": summary(cfg, errors, fits),
        "config": dict(cfg),
        "sections": sections(cfg, errors, fits),
        "cases": case_docs,
        "fits": fit_docs,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": NOTES,
    }


FIT_RESIDUAL_UNITS = "s·W − E/πL (uniform ambient, albedo as configured), per pixel"


def write_fitted(out, cfg, fits, ctx, hashes) -> list[dict]:
    """fitted/obscurances.json (``rtfit.fitted/1``): every per-scene and joint fit with parameters, bounds,
    units and residual (no shader text: the tracer has no loop over a ray array); returns the results'
    ``fits`` records."""
    file = "fitted/obscurances.json"
    entries, docs = [], []
    for mid, f in fits.items():
        m = METHODS[mid]
        for case, fit in [*f["per_scene"].items(), ("joint", f["joint"])]:
            entries.append(
                fitfiles.method_entry(
                    m,
                    fit,
                    id=f"{mid}-{case}".replace("_", "-"),
                    label=f"{m.label}: {case}",
                    residual_units=FIT_RESIDUAL_UNITS,
                )
            )
            docs.append(
                fitfiles.fit_record(
                    f"{mid}-{case}",
                    f"{m.label}: {case}",
                    m.formula,
                    fit,
                    file,
                    message=str(fit.get("message", ""))[:200],
                )
            )
    fitfiles.write_fitted(
        out / file,
        fitfiles.FittedFile(
            format=fitfiles.FORMAT,
            title=f"obscurances fitted to a uniform ambient with interreflections (albedo {cfg['albedo']:g})",
            provenance=fitfiles.provenance(ctx, "obscurances", hashes, cfg["spp"]),
            methods=entries,
        ),
    )
    return docs


NOTES = [
    "Seed ρ (001:3284): √(d/d_max) below d_max, 1 beyond; default d_max = 0.3 (001:3326) in the seed's scene "
    "units — the sdf-occlusion scenes are about 4 units wide, so it is a short reach here.",
    "Seed erratum/omission: the text gives ρ without its domain at d = 0 and never states the cosine weight; "
    "the obscurance integral W = (1/π)∫ρ(d) cos θ dω (Zhukov et al. 1998) is what its global-line sampling "
    "estimates (uniformly distributed global lines hit a patch with density ∝ cos θ).",
    "Reference (b) is E/πL under a constant environment over the whole sphere with interreflections between "
    "white diffuse surfaces of the configured albedo: it exceeds the one-bounce AO where walls face each "
    "other.",
]


def _mean_err(cfg, errors, target, rid):
    return float(np.mean([errors[(n, target, rid)] for n in cfg["scenes"]]))


def sections(cfg, errors, fits) -> list[dict]:
    lines = ["| rays K | mean RMSE vs (a) |", "|---|---|"]
    lines += [f"| {k} | {_mean_err(cfg, errors, 'model', f'rays-{k}'):.4f} |" for k in cfg["rays"]]
    rows = ["| row | mean RMSE vs (b) |", "|---|---|"]
    for rid in ("seed", "power", "power-joint", "exponential", "exponential-joint", "ao"):
        rows.append(f"| {rid} | {_mean_err(cfg, errors, 'ambient', rid):.4f} |")
    jp = {k: v["value"] for k, v in fits["power"]["joint"]["parameters"].items()}
    return [
        {"id": "rays", "title": "Rays per point", "text": "\n".join(lines)},
        {
            "id": "fits",
            "title": "Obscurance as uniform-ambient light",
            "text": "\n".join(rows)
            + "\n\nJoint power fit: "
            + json.dumps({k: round(v, 4) for k, v in jp.items()}),
        },
    ]


def summary(cfg, errors, fits) -> str:
    jp = {k: v["value"] for k, v in fits["power"]["joint"]["parameters"].items()}
    k0, k1 = min(cfg["rays"]), max(cfg["rays"])
    e0, e1 = (_mean_err(cfg, errors, "model", f"rays-{k}") for k in (k0, k1))
    seed, power, joint, expo = (
        _mean_err(cfg, errors, "ambient", r) for r in ("seed", "power", "power-joint", "exponential")
    )
    return (
        f"Obscurance estimator with {k0}→{k1} rays: mean RMSE against the model's Monte Carlo "
        f"{e0:.3f}→{e1:.3f}. As uniform-ambient light (albedo {cfg['albedo']:g}): seed {seed:.3f}, "
        f"power fitted per scene {power:.3f}, joint {joint:.3f} (d_max {jp['d_max']:.3g}, "
        f"p {jp['exponent']:.3g}, s {jp['scale']:.3g}), exponential per scene {expo:.3f}."
    )


# ================================================================================================ bench
def bench(ctx) -> list[dict]:
    """The ρ kernel (power, 16 rays) on Dr.Jit vs NumPy, one run."""

    backend, n = bench_backend(ctx)
    n = min(n, 1 << 20)
    rng = np.random.default_rng(0)
    rows_np = [rng.exponential(0.5, n).astype(np.float32) for _ in range(16)]
    Float = backend_float(backend)
    rows_dr = tuple(Float(r) for r in rows_np)
    kern = METHODS["power"].kernel

    def timed():
        t_dr = time_drjit(lambda *x: kern(DRJIT_OPS, list(x)), rows_dr, n)
        yield (
            "obscurance ρ kernel (power, 16 rays)",
            t_dr,
            time_numpy(lambda *x: kern(NUMPY_OPS, list(x)), tuple(rows_np), n),
        )

    return comparison_rows(backend, rows_dr, n, timed(), unit="pt")
