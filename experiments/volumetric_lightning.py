"""Experiment ``volumetric-lightning``: the seed's volumetric lightning (a softened point light integrated
along the view segment in closed form) against path-traced single scattering from a point light.

What is compared, and why (docs/volumetric-lightning.md):

1. **The closed form in float32** (no rendering; `rtfit.realtime.volumetric_lightning.METHODS` ``stable`` and
   ``seed``): relative error of rtfit's stable form and of the seed's printed form (000:2360, 002:409) in
   float32 against the stable form's float64 run (itself checked against mpmath quadrature in
   tests/test_volumetric_lightning.py) over the whole domain, near-axial rays at a = 100 and 1e3 included,
   and the limits a = 0, |d| = 0.
2. **Reference check**: an isotropic point light (Mitsuba ``point``) inside a homogeneous, non-absorbing
   (albedo 1) medium box around the camera; ``volpathmis`` with max_depth 2 (single scattering). Each pixel
   must equal σ_s/(4π)·∫ I·e^(−σ_t(s + r))/r² ds along its camera ray to the box's far wall, evaluated by an
   independent quadrature (`rtfit.reference.single_scattering.point_single_scattering`, analytic
   transmittance): z-scores of unit spread,
   on the pixels whose reference resolves the light's 1/r² peak (`CORE_EVENTS_MIN`: free-flight sampling
   needs ≥ 10 scattering events near the ray's closest approach; the same pixels are compared below).
3. **The seed's model against single scattering**, per light distance D and medium density σ_t: rows
   (`ROWS`) ``exact`` (the quadrature), ``inverse-square`` (single scattering without extinction, the seed's
   a → ∞ limit with i/a = σ_s·I/(4π)) and ``seed-fit`` (the stable form with i and a fitted through the JAX
   run of its kernel, `rtfit.fitting.fit_method`), plus the stable form with fixed softening radii and only i
   fitted. Residuals vs the ray's closest approach to the light show where the softening 1/(1 + a r²)
   matters; thin vs dense media show what extinction adds.

Sections: configure · methods (rows) · cases (scenes, geometry, quadrature) · jobs · run (results) · checks ·
figures · summary (text) · bench (cost rows and ``rtfit bench``).
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.fitting import compute_metrics, fit_method
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.volumetric_lightning import METHODS
from rtfit.reference.single_scattering import (
    FOUR_PI,
    box_exit,
    point_estimator_variance,
    point_single_scattering,
)
from rtfit.scenes import scene_hash
from rtfit.scenes.model import (
    Camera,
    Cube,
    HomogeneousMedium,
    PointLight,
    ReferenceSettings,
    Scene,
)

from . import figures as F
from . import fitted as fitfiles
from .cost import attach_costs, bench_backend, cost_backend, method_bench_rows, method_cost_rows
from .jobs import Job
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row
from .scattering_reference import (
    FIT_METHOD,
    fit_level,
    fit_params,
    reference_checks,
    reference_rate_row,
    render_references,
    residual_scale,
)

# ============================================================================================ configure
CONFIG = {
    "distances_m": ConfigKey("float", "camera-to-light distances D (m), one case each", 0.1, 36.0, (None,)),
    "sigma_t_per_m": ConfigKey(
        "float", "medium extinction σ_t (1/m; albedo 1: σ_s = σ_t), one case each", 1e-5, 0.2, (None,)
    ),
    "core_radii": ConfigKey(
        "float",
        "softening radii 1/√a of the seed model over D, each with i fitted alone",
        1e-3,
        10.0,
        (None,),
    ),
    "resolution": ConfigKey("int", "image (W, H) pixels", 4, 4096, (2,)),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "random_samples": ConfigKey("int", "random domain samples of the float32 accuracy table", 100, 1 << 24),
    "image_figures": ConfigKey("int", "cases with an image figure (the first and last ones first)", 0, 1000),
    "cost_elements": ConfigKey("int", "elements per timed launch", 1024, 1 << 26),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "distances_m": [4.0, 16.0] if quick else [1.0, 4.0, 16.0, 32.0],
            "sigma_t_per_m": [0.01, 0.05] if quick else [0.002, 0.01, 0.05],
            "core_radii": [0.03, 0.1, 0.3],
            "resolution": [24, 16] if quick else [96, 64],
            "spp": spp or (2048 if quick else 32768),
            "pass_spp": 1024 if quick else 4096,
            "random_samples": 20000 if quick else 400000,
            "image_figures": 2 if quick else 1000,
            "cost_elements": 1 << (20 if quick else 22),
        },
    )


# ============================================================================================== methods


def true_inverse_square(case: dict, fit: dict | None) -> dict:
    """K = σ_s·I/(4π): single scattering without extinction."""
    return {"k": case["sigma_s"] * case["intensity"] / FOUR_PI}


def fitted_values(case: dict, fit: dict | None) -> dict:
    """The (i, a) a fit of the stable form found (`fit_job`)."""
    assert fit is not None
    return {k: v["value"] for k, v in fit["parameters"].items()}


def physical(case: dict, fit: dict | None) -> dict:
    """The medium's σ_s, σ_t and the light's I (the quadrature's inputs)."""
    return {"sigma_s": case["sigma_s"], "sigma_t": case["sigma_t"], "intensity": case["intensity"]}


# Rows (`rows.Row`): ``params(case, fit or None) -> {name: value}``; ``method`` None for the quadrature.
ROWS = (
    Row("exact", "single scattering with extinction (quadrature)", None, physical),
    Row("inverse-square", "single scattering, no extinction: K·θ/h", "inverse-square", true_inverse_square),
    Row("seed-fit", "seed model (stable form), fitted i, a", "stable", fitted_values, fitted=True),
)
RESULT_NAMES = {"i": "i", "a": "a_per_m2", "k": "K_W_per_m_sr", "sigma_s": "sigma_s_per_m",
                "sigma_t": "sigma_t_per_m", "intensity": "I_W_per_sr"}  # fmt: skip
"""The results' names of each row's parameters."""

FIT_MAX_STEPS = 1024
"""Levenberg–Marquardt steps: a reaches its upper bound through the logistic reparametrisation in ~750."""


# ================================================================================================ cases
FOV_DEG = 60.0
LIGHT_AT = (0.1, 1.0, 0.04)
"""Light position over D: in the frame, between pixel centres (camera at the origin looking along +y)."""
BOX_LO, BOX_HI = (-20.0, -1.0, -20.0), (20.0, 40.0, 20.0)
"""The medium fills this box (m) around the camera; every view segment ends on its far walls (no surfaces)."""


def case_parameters(distance: float, sigma_t: float) -> dict:
    """Physical parameters of one case: σ_s = σ_t (albedo 1), I = D² W/sr (radiance near the light alike
    across D), the light at D·`LIGHT_AT`."""
    return {
        "distance": distance,
        "sigma_t": sigma_t,
        "sigma_s": sigma_t,
        "optical_depth": sigma_t * distance,
        "intensity": distance * distance,
        "light": tuple(distance * x for x in LIGHT_AT),
        "box_lo": BOX_LO,
        "box_hi": BOX_HI,
    }


def case_id(distance: float, sigma_t: float) -> str:
    return f"D{distance:g}-s{sigma_t:g}"


def case_scene(p: dict, resolution) -> Scene:
    """The scene of one case: camera at the origin inside a homogeneous box, a point light, nothing else."""
    lo, hi = np.asarray(p["box_lo"]), np.asarray(p["box_hi"])
    box = Cube(center=tuple((lo + hi) / 2), size=tuple(hi - lo))
    return Scene(
        name=f"volumetric-lightning-{case_id(p['distance'], p['sigma_t'])}",
        camera=Camera(
            origin=(0.0, 0.0, 0.0),
            target=(0.0, 1.0, 0.0),
            up=(0.0, 0.0, 1.0),
            fov_deg=FOV_DEG,
            width=int(resolution[0]),
            height=int(resolution[1]),
        ),
        lights=(PointLight(position=p["light"], intensity=(p["intensity"],) * 3),),
        media=(HomogeneousMedium(boundary=box, sigma_t=(p["sigma_t"],) * 3, albedo=(1.0, 1.0, 1.0)),),
        reference=ReferenceSettings(transport="direct"),  # volpathmis, max_depth 2: single scattering
    )


def segment_inputs(p: dict, dirs: np.ndarray, dtype=np.float64) -> dict:
    """The kernels' per-pixel inputs (o, d, l components): camera → far wall of the medium."""
    s = box_exit((0.0, 0.0, 0.0), dirs, p["box_lo"], p["box_hi"])
    d = dirs * s[..., None]
    names = METHODS[FIT_METHOD].input_names
    comps = [np.zeros_like(s)] * 3 + [d[..., k] for k in range(3)] + [np.full_like(s, x) for x in p["light"]]
    return {n: c.astype(dtype) for n, c in zip(names, comps, strict=True)}


CORE_EVENTS_MIN = 10.0
"""A pixel is compared only where the reference resolves the light's 1/r² peak: Mitsuba samples scattering
points by free flight (density σ_t·e^(−σ_t·s), no equiangular sampling), so it needs on average
n = spp·σ_t·2h·e^(−σ_t·c_∥) ≥ 10 scattering events per pixel within ±h of the ray's closest approach h
(half of ∫ ds/r² lies there). Below that the estimate rests on a few rare, large samples and its standard
error is unreliable: measured (48×32, 4096 spp, D = 1 m, σ_t = 0.002 /m) z spread 5.3 and |z| up to 53
where n < 3, 1.2 where 3 ≤ n < 10, and 0.9–1.04 where n ≥ 10 over all cases."""


def resolved_pixels(p: dict, dirs: np.ndarray, spp: int) -> np.ndarray:
    """The pixels whose reference resolves the light's peak (`CORE_EVENTS_MIN`)."""
    h = closest_approach(p, dirs)
    c_par = dirs @ np.asarray(p["light"], np.float64)
    n = spp * p["sigma_t"] * 2.0 * h * np.exp(-p["sigma_t"] * np.maximum(c_par, 0.0))
    return n >= CORE_EVENTS_MIN


def closest_approach(p: dict, dirs: np.ndarray) -> np.ndarray:
    """Distance h (m) from the light to each camera ray's line (the rays start at the origin)."""
    c = np.asarray(p["light"], np.float64)
    return np.linalg.norm(np.cross(c, dirs), axis=-1)


# ================================================================================================= jobs
def fit_job(inputs: dict, target, scale, case: dict) -> dict:
    """Job: fit the stable form's (i, a) to one reference image (pixel-flattened) through the JAX run of its
    kernel; residuals (model − reference)/scale (`fit_data`)."""
    result = fit_method(
        METHODS[FIT_METHOD],
        inputs,
        target,
        weights=1.0 / np.asarray(scale),
        params=fit_params(case),
        max_steps=FIT_MAX_STEPS,
    )
    return result.to_dict()


def fit_data(p: dict, dirs: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    """Fit inputs of the pixels in ``mask`` (flattened) and their residual scale (`residual_scale`)."""
    scale = residual_scale(ref[mask])
    inputs = {k: v[mask] for k, v in segment_inputs(p, dirs).items()}
    return {"inputs": inputs, "target": ref[mask], "scale": scale}


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    params, scenes = {}, {}
    for dist in cfg["distances_m"]:
        for sigma in cfg["sigma_t_per_m"]:
            cid = case_id(dist, sigma)
            params[cid] = case_parameters(dist, sigma)
            scenes[cid] = case_scene(params[cid], cfg["resolution"])
    rendered = render_references(ctx, cfg, scenes)

    fit_jobs = []
    for cid, p in params.items():
        dirs = rendered[cid]["view_dir"]
        rendered[cid]["mask"] = resolved_pixels(p, dirs, cfg["spp"])
        data = fit_data(p, dirs, rendered[cid]["image"].mean[..., 0], rendered[cid]["mask"])
        fit_jobs.append(Job(fit_job, dict(**data, case=p), label=f"fit-{cid}"))
    ctx.log(f"fitting {len(fit_jobs)} seed models")
    fits = dict(zip(params, ctx.executor.map(fit_jobs, desc="fits"), strict=True))
    hashes = {k: scene_hash(v) for k, v in scenes.items()}
    return assemble(ctx, cfg, params, scenes, rendered, fits, hashes)


def row_image(row: Row, p: dict, dirs: np.ndarray, fit: dict | None) -> np.ndarray:
    """One row's image (H, W): the quadrature in float64, or the method's kernel text on float32 Dr.Jit
    (the shader's precision), returned as float64."""
    values = row.params(p, fit)
    if row.method is None:
        s = box_exit((0.0, 0.0, 0.0), dirs, p["box_lo"], p["box_hi"])
        return point_single_scattering((0.0, 0.0, 0.0), dirs, s, p["light"], **values)
    out = METHODS[row.method].evaluate(segment_inputs(p, dirs, np.float32), values)
    return np.asarray(out, dtype=np.float64)


def _grey(img: np.ndarray) -> np.ndarray:
    return np.repeat(img[..., None], 3, axis=-1)


def assemble(ctx, cfg, params, scenes, rendered, fits, hashes) -> dict:
    """The results document: one case per (distance, density), checks, figures, costs, accuracy table."""
    case_docs, images, checks, softening = [], {}, [], {}
    for cid, p in params.items():
        ref = rendered[cid]["image"]
        dirs = rendered[cid]["view_dir"]
        mask = rendered[cid]["mask"]
        docs = []
        for row in ROWS:
            fit = fits[cid] if row.fitted else None
            img = row_image(row, p, dirs, fit)
            images[(cid, row.id)] = img
            metrics = compute_metrics(_grey(img), ref.mean, ref.sigma(), mask)
            values = row.params(p, fit)
            docs.append(
                {
                    "method": row.id,
                    "label": row.label,
                    "fitted": row.fitted,
                    "parameters": {RESULT_NAMES[k]: float(v) for k, v in values.items()},
                    "metrics": metrics.to_dict(),
                }
            )
        checks += reference_checks(cid, ref, images[(cid, "exact")], mask, model_stderr(p, dirs, ref.spp))
        checks.append(
            Check(
                name=f"reference {cid} resolves the light's peak (n ≥ {CORE_EVENTS_MIN:g} scattering "
                "events near the closest approach) on at least half of the pixels",
                value=float(mask.mean()),
                expected="≥ 0.5",
                passed=bool(mask.mean() >= 0.5),
            )
        )
        cores = core_models(p, dirs, ref.mean[..., 0], cfg["core_radii"], mask)
        models = {row.id: images[(cid, row.id)] for row in ROWS} | {k: v[0] for k, v in cores.items()}
        softening[cid] = softening_profile(p, dirs, ref.mean[..., 0], models, mask)
        softening[cid]["core_levels"] = {k: {"i": v[1], "a_per_m2": v[2]} for k, v in cores.items()}
        case_docs.append(
            {
                "id": cid,
                "label": f"light at D = {p['distance']:g} m, σ_t = {p['sigma_t']:g} /m",
                "parameters": {
                    "distance_m": p["distance"],
                    "optical_depth": p["optical_depth"],
                    "sigma_t_per_m": p["sigma_t"],
                    "sigma_s_per_m": p["sigma_s"],
                    "intensity_W_per_sr": p["intensity"],
                    "core_radius_over_D": core_radius(fits[cid], p),
                    "a_at_upper_bound": bool(fits[cid]["parameters"]["a"]["at_bound"]),
                    "fitted_K_over_true_K": effective_k(fits[cid], p),
                    "pixels": int(mask.size),
                    "pixels_resolved": int(mask.sum()),
                },
                "scene": {"name": scenes[cid].name, "hash": hashes[cid]},
                "reference": ref.to_dict(),
                "approximations": docs,
            }
        )
    accuracy = float32_accuracy(cfg)
    checks += accuracy_checks(accuracy)
    checks += [
        Check(
            name=f"fit {cid} converged",
            value=str(fit["converged"]),
            expected="True",
            passed=bool(fit["converged"]),
        )
        for cid, fit in fits.items()
    ]
    costs = cost_rows(ctx, cfg)
    attach_costs(case_docs, costs, key=lambda ap: COST_KEYS[ap["method"]])
    fitted = write_fitted(ctx.out_dir, fits, params, ctx, cfg, hashes, rendered)
    figs = make_figures(ctx.out_dir, cfg, rendered, images, case_docs, softening)
    return {
        "summary": summary(case_docs, softening, accuracy, checks),
        "config": cfg,
        "sections": sections(accuracy, softening, params),
        "cases": case_docs,
        "fits": fitted,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "float32_accuracy": accuracy["table"],
        "softening": softening,
        "notes": NOTES,
    }


def core_radius(fit: dict, p: dict) -> float:
    """The fitted softening radius 1/√a over the light's distance D."""
    return 1.0 / math.sqrt(fit["parameters"]["a"]["value"]) / p["distance"]


def effective_k(fit: dict, p: dict) -> float:
    """The fitted far-field level i/a over the true σ_s·I/(4π): below 1 where extinction dims the light."""
    par = fit["parameters"]
    return par["i"]["value"] / par["a"]["value"] / (p["sigma_s"] * p["intensity"] / FOUR_PI)


def softening_reach(softening: dict, threshold: float = 0.1) -> dict:
    """Per fixed core radius ρ (over D): the largest upper edge h/D of a closest-approach bin (any case) in
    which that model's mean error exceeds the fitted seed model's by more than ``threshold``, over ρ."""
    out = {}
    for prof in softening.values():
        for key in prof:
            if not key.startswith("core-"):
                continue
            rho = float(key[5:])
            for (_, hi), v, base in zip(prof["h_over_D"], prof[key], prof["seed-fit"], strict=True):
                if abs(v - base) > threshold and hi <= 1.0:
                    out[key] = max(out.get(key, 0.0), hi / rho)
    return out


SOFTENING_BINS = np.array([0.0, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 10.0])
"""Bins of the closest approach h/D of the softening profile."""


def core_models(p: dict, dirs: np.ndarray, ref: np.ndarray, radii, mask: np.ndarray) -> dict:
    """The seed model (stable form, float64) with a fixed softening radius ρ = 1/√a per entry of ``radii``
    (over D) and its level i fitted alone on the pixels in ``mask`` (`fit_level`): {"core-<ρ>": (image, i,
    a)}."""
    out = {}
    inputs = segment_inputs(p, dirs)
    for rho in radii:
        a = 1.0 / (rho * p["distance"]) ** 2
        unit = np.asarray(METHODS[FIT_METHOD].evaluate(inputs, {"i": 1.0, "a": a}), dtype=np.float64)
        i = fit_level(unit[mask], ref[mask])
        out[f"core-{rho:g}"] = (i * unit, i, a)
    return out


def softening_profile(p: dict, dirs: np.ndarray, ref: np.ndarray, models: dict, mask: np.ndarray) -> dict:
    """Mean relative error (model − reference)/reference of each model ({id: image}) per bin of h/D (the
    pixel ray's closest approach to the light over the light's distance), over the pixels in ``mask``."""
    h = closest_approach(p, dirs) / p["distance"]
    idx = np.digitize(h, SOFTENING_BINS) - 1
    out = {"h_over_D": [], "pixels": [], **{k: [] for k in models}}
    for k in range(len(SOFTENING_BINS) - 1):
        sel = (idx == k) & mask
        if not sel.any():
            continue
        out["h_over_D"].append([float(SOFTENING_BINS[k]), float(SOFTENING_BINS[k + 1])])
        out["pixels"].append(int(sel.sum()))
        for key, img in models.items():
            out[key].append(float(np.mean(img[sel] / ref[sel] - 1.0)))
    return out


def model_stderr(p: dict, dirs: np.ndarray, spp: int) -> np.ndarray:
    """The reference's standard error from the estimator's analytic variance (`point_estimator_variance`)."""
    s = box_exit((0.0, 0.0, 0.0), dirs, p["box_lo"], p["box_hi"])
    var = point_estimator_variance(
        (0.0, 0.0, 0.0), dirs, s, p["light"], p["intensity"], p["sigma_s"], p["sigma_t"]
    )
    return np.sqrt(var / spp)


# ------------------------------------------------------------------------------------ float32 accuracy
def random_domain(n: int, seed: int = 7, near_axial: float = 0.3, a_values=None):
    """Random float32 (o, d, l, a) over the whole domain: |c| = |l − o| log-uniform 1e-2…1e4 m, rays
    1e-8…1e-2 rad off ±c (fraction ``near_axial``) or at any angle, |d|/|c| log-uniform 1e-3…3 (|d| ≤ 1e4 m;
    2 % exactly 0), a log-uniform 1e-6…1e3 /m² (5 % exactly 0) or drawn from ``a_values``. o lies on the grid
    of c's ulps, so the float32 subtraction l − o is exact (the kernel sees c exactly). Returns (o, d, l, a),
    each float32; shared with tests/test_volumetric_lightning.py."""
    rng = np.random.default_rng(seed)
    dist = 10 ** rng.uniform(-2, 4, n)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    c = dist[:, None] * axis
    perp = rng.normal(size=(n, 3))
    perp -= np.sum(perp * axis, 1, keepdims=True) * axis
    perp /= np.linalg.norm(perp, axis=1, keepdims=True)
    angle = np.where(rng.random(n) < near_axial, 10 ** rng.uniform(-8, -2, n), rng.uniform(0, math.pi, n))
    sign = np.where(rng.random(n) < 0.5, 1.0, -1.0)
    u = sign[:, None] * (np.cos(angle)[:, None] * axis + np.sin(angle)[:, None] * perp)
    length = np.minimum(dist * 10 ** rng.uniform(-3, 0.5, n), 1e4)
    length[rng.random(n) < 0.02] = 0.0
    d = (length[:, None] * u).astype(np.float32)
    c32 = c.astype(np.float32)
    ulp = np.spacing(np.abs(c32)).astype(np.float64)
    o = np.round(rng.uniform(-10, 10, (n, 3)) / ulp) * ulp
    o = np.clip(o, -(2.0**22) * ulp, 2.0**22 * ulp).astype(np.float32)
    lpos = (o.astype(np.float64) + c32.astype(np.float64)).astype(np.float32)
    if a_values is None:
        a = np.where(rng.random(n) < 0.05, 0.0, 10 ** rng.uniform(-6, 3, n))
    else:
        a = rng.choice(np.asarray(a_values, np.float64), n)
    return o, d, lpos, a.astype(np.float32)


def _method_inputs(o, d, lpos, dtype) -> dict:
    names = METHODS[FIT_METHOD].input_names
    comps = [*np.asarray(o).T, *np.asarray(d).T, *np.asarray(lpos).T]
    return {n: np.ascontiguousarray(c, dtype=dtype) for n, c in zip(names, comps, strict=True)}


ACCURACY_SETS = (
    ("whole domain", dict(near_axial=0.3)),
    ("near-axial rays, a = 100 /m²", dict(near_axial=1.0, a_values=(100.0,))),
    ("near-axial rays, a = 1000 /m²", dict(near_axial=1.0, a_values=(1000.0,))),
)
"""The random input sets of the float32 accuracy table (`random_domain` keywords)."""


def float32_accuracy(cfg) -> dict:
    """Relative error of ``stable`` and ``seed`` in float32 (Dr.Jit) against ``stable`` in float64 (Dr.Jit
    Float64; ≤ 3e-15 from mpmath, tests), and the non-finite counts, per input set."""
    table, worst = [], {}
    for k, (label, kw) in enumerate(ACCURACY_SETS):
        o, d, lpos, a = random_domain(cfg["random_samples"], seed=11 + k, **kw)
        truth = np.asarray(
            METHODS["stable"].evaluate(
                _method_inputs(o, d, lpos, np.float64), {"i": 1.0, "a": a.astype(np.float64)}
            ),
            dtype=np.float64,
        )
        ok = truth > 0
        for form in ("stable", "seed"):
            got = np.asarray(
                METHODS[form].evaluate(
                    _method_inputs(o, d, lpos, np.float32), {"i": np.float32(1.0), "a": a}
                ),
                dtype=np.float64,
            )
            with np.errstate(all="ignore"):
                rel = np.abs(got / truth - 1.0)
            finite = np.isfinite(got)
            rel_f = np.where(ok & finite, rel, 0.0)
            row = {
                "inputs": label,
                "form": form,
                "label": METHODS[form].label,
                "samples": int(ok.sum()),
                "non_finite": int((ok & ~finite).sum()),
                "worst_rel_error": float(rel_f.max()),
                "share_above_1e-3": float(np.mean(rel_f[ok] > 1e-3)),
            }
            table.append(row)
            worst[(label, form)] = row
    limits = limit_values()
    return {"table": table, "worst": worst, "limits": limits}


def limit_values() -> dict:
    """The float32 kernel at the special inputs: a = 0 (→ i|d|), |d| = 0 (→ 0), a light 1e4 m ahead of a 1 m
    segment at a = 1e3 (→ i|d|/(1 + a|c||c − d|))."""
    o = np.zeros((3, 3), np.float32)
    d = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], np.float32)
    lpos = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1e4, 0.0, 0.0]], np.float32)
    a = np.array([0.0, 0.5, 1e3], np.float32)
    expect = [5.0, 0.0, 1.0 / (1.0 + 1e3 * 1e4 * (1e4 - 1.0))]
    out = {}
    for form in ("stable", "seed"):
        v = METHODS[form].evaluate(_method_inputs(o, d, lpos, np.float32), {"i": np.float32(1.0), "a": a})
        out[form] = [float(x) for x in np.asarray(v, np.float64)]
    return {"labels": ["a = 0, |d| = 5", "|d| = 0", "light 1e4 m ahead, a = 1e3"], "expected": expect, **out}


def accuracy_checks(acc: dict) -> list[Check]:
    checks = []
    for label, _ in ACCURACY_SETS:
        row = acc["worst"][(label, "stable")]
        checks.append(
            Check(
                name=f"stable form, float32 vs float64: worst relative error, {label} "
                f"({row['samples']} inputs)",
                value=row["worst_rel_error"],
                expected="≤ 1e-5",
                passed=bool(row["worst_rel_error"] <= 1e-5),
            )
        )
        checks.append(
            Check(
                name=f"stable form, float32: non-finite outputs, {label}",
                value=row["non_finite"],
                expected="0",
                passed=row["non_finite"] == 0,
            )
        )
    lim = acc["limits"]
    for label, e, v in zip(lim["labels"], lim["expected"], lim["stable"], strict=True):
        good = v == e if e == 0.0 else abs(v / e - 1.0) <= 1e-6
        checks.append(
            Check(
                name=f"stable form at: {label}", value=v, expected=f"{e:.7g} (±1e-6 rel.)", passed=bool(good)
            )
        )
    return checks


# ------------------------------------------------------------------------------------ fitted files
FIT_RESIDUAL_UNITS = "(model − reference)/(0.02·|reference| + 0.01·mean|reference|) per pixel"


def write_fitted(out, fits, params, ctx, cfg, hashes, rendered) -> list[dict]:
    """fitted/lightning-<case>.json per fit (``rtfit.fitted/1``: parameters with units and bounds, residual,
    domain, GLSL/HLSL of the fitted kernel); returns the results' ``fits`` records."""
    docs = []
    m = METHODS[FIT_METHOD]
    for cid, fit in fits.items():
        p = params[cid]
        dirs = rendered[cid]["view_dir"]
        seg = segment_inputs(p, dirs)
        length = np.sqrt(seg["dx"] ** 2 + seg["dy"] ** 2 + seg["dz"] ** 2)
        file = f"fitted/lightning-{cid}.json"
        entry = fitfiles.method_entry(
            m,
            fit,
            label=f"{m.label}, {cid}",
            case=cid.replace(".", "_"),
            domain={
                "segment_length": (float(length.min()), float(length.max()), "m"),
                "light_distance": (p["distance"], p["distance"], "m"),
                "sigma_t": (p["sigma_t"], p["sigma_t"], "1/m"),
            },
            residual_units=FIT_RESIDUAL_UNITS,
            data={"correlation": fit.get("correlation"), "param_names": fit.get("param_names")},
        )
        prov = fitfiles.provenance(ctx, "volumetric-lightning", [hashes[cid]], cfg["spp"])
        docs.append(
            fitfiles.write_fit(
                out,
                file,
                title=f"volumetric lightning: seed model (i, a) fitted to single scattering ({cid})",
                provenance=prov,
                entry=entry,
                doc_id=f"lightning-{cid}",
                label=f"seed model (i, a), {cid}",
                model=m.formula,
                fit=fit,
            )
        )
    return docs


# ============================================================================================== figures
def profile_keys(prof: dict) -> list[str]:
    """The models of a softening profile (rows after ``exact`` and the fixed-core models)."""
    return [k for k in prof if k not in ("h_over_D", "pixels", "core_levels", "exact")]


def figure_cases(case_docs: list[dict], count: int) -> list[dict]:
    """The cases with an image figure: the first and the last, then the others in order; ``count`` in all."""
    order = [*case_docs[:1], *case_docs[-1:], *case_docs[1:-1]] if len(case_docs) > 1 else case_docs
    return order[:count]


def make_figures(out, cfg, rendered, images, case_docs, softening) -> list[dict]:
    figs = []
    fdir = out / "figures"
    for doc in figure_cases(case_docs, cfg["image_figures"]):
        cid = doc["id"]
        ref = rendered[cid]["image"].mean
        panels = [(ap["method"], _grey(images[(cid, ap["method"])])) for ap in doc["approximations"]]
        caption = (
            f"{doc['label']}: Mitsuba single scattering and the rows; error maps relative to the image's "
            "mean radiance."
        )
        scale = float(np.mean(np.abs(ref)))
        figs.append(
            F.case_comparison(
                out, doc, ref, panels, rendered[cid]["mask"], error_scale=scale, caption=caption
            )
        )
    series, panels = [], list(softening)
    for cid, prof in softening.items():
        x = [math.sqrt(max(lo, 1e-3) * hi) for lo, hi in prof["h_over_D"]]
        for key in profile_keys(prof):
            series.append(
                {
                    "x": x,
                    "y": [max(abs(v), 1e-4) for v in prof[key]],
                    "label": key,
                    "ls": "--" if key.startswith("core-") else "-",
                    "style": "line",
                    "panel": cid,
                }
            )
    p = F.line_plot(
        fdir / "error_vs_closest_approach.png",
        "closest approach of the view ray to the light, h/D",
        "|mean relative error|",
        series,
        x_log=True,
        y_log=True,
        panels=panels,
    )
    figs.append(
        {
            "file": f"figures/{p.name}",
            "caption": "Mean relative error per bin of the view ray's closest approach to the light (h/D), "
            "one panel per case: the fitted seed model, single scattering without extinction (its error is "
            "the "
            "extinction) and, dashed, the seed model with a fixed softening radius ρ = 1/√a (core-ρ, over D) "
            "and its level i fitted: the softening's error is confined to rays passing within a few ρ.",
            "section": "results",
        }
    )
    return figs


# ============================================================================================== summary
NOTES = [
    "Grey light and medium: one channel is compared (the RGB channels of the reference are identical).",
    "The light's intensity is I = D² W/sr, so the in-scattered radiance is alike across distances; the "
    "medium has albedo 1 (σ_s = σ_t) and fills the box y ∈ [−1, 40] m, |x|, |z| ≤ 20 m around the camera.",
    "Single scattering: volpathmis with max_depth 2 (the integrator rule's 'direct' transport with media).",
    "The segment d of every pixel runs from the camera to the medium box's far wall (no surfaces).",
]


def _mean_rel(case_docs, row_id, sigma=None, metric="rel_mse") -> float:
    vals = [
        ap["metrics"][metric]["value"]
        for d in case_docs
        for ap in d["approximations"]
        if ap["method"] == row_id and (sigma is None or d["parameters"]["sigma_t_per_m"] == sigma)
    ]
    return float(np.mean(vals)) if vals else float("nan")


def sections(accuracy, softening, params) -> list[dict]:
    rows = [
        "| inputs | form | worst relative error (float32) | share > 1e-3 | non-finite |",
        "|---|---|---|---|---|",
    ]
    for t in accuracy["table"]:
        rows.append(
            f"| {t['inputs']} | {t['label']} | {t['worst_rel_error']:.3g} | {t['share_above_1e-3']:.3g} | "
            f"{t['non_finite']} of {t['samples']} |"
        )
    lim = accuracy["limits"]
    lim_rows = ["| input | expected | stable | seed (printed) |", "|---|---|---|---|"]
    for k, label in enumerate(lim["labels"]):
        lim_rows.append(
            f"| {label} | {lim['expected'][k]:.7g} | {lim['stable'][k]:.7g} | {lim['seed'][k]:.7g} |"
        )
    keys = profile_keys(next(iter(softening.values())))
    soft = ["| case | h/D bin | pixels | " + " | ".join(keys) + " |", "|---|---|---|" + "---|" * len(keys)]
    for cid, prof in softening.items():
        for k, (lo, hi) in enumerate(prof["h_over_D"]):
            vals = " | ".join(f"{prof[key][k]:+.3f}" for key in keys)
            soft.append(f"| {cid} | {lo:g}–{hi:g} | {prof['pixels'][k]} | {vals} |")
    return [
        {
            "id": "method",
            "title": "Method",
            "text": (
                "The seed's volumetric lightning (000:2345-2385, 002:389-420) integrates f = i/(1 + a·r²) "
                "along the view segment in closed form. rtfit evaluates it in a stable form (the "
                "discriminant 4uw − v² = 4a|d|²(1 + a|c_⊥|²) without cancellation, the arctangent "
                "difference as one atan2, series at small angles; `rtfit.realtime.volumetric_lightning`). "
                "Physical counterpart: single scattering of an isotropic point light of intensity I in a "
                "homogeneous medium, L = σ_s/(4π)∫ I·e^(−σ_t(s + r))/r² ds. Without extinction it is the "
                "seed's model in the limit a → ∞ with i/a = σ_s·I/(4π). Ground truth: Mitsuba `volpathmis` "
                "(max_depth 2) with a `point` emitter, checked per pixel against an independent quadrature "
                "of the integral (Checks). The seed's (i, a) are fitted per light distance and density with "
                "Levenberg–Marquardt through the JAX run of the kernel."
            ),
        },
        {
            "id": "float32",
            "title": "The closed form in float32",
            "text": (
                "Relative error against the stable form in float64:\n\n"
                + "\n".join(rows)
                + "\n\nLimits:\n\n"
                + "\n".join(lim_rows)
            ),
        },
        {
            "id": "softening",
            "title": "Where the softening and the extinction matter",
            "placement": "after_results",
            "text": (
                "Mean relative error (model/reference − 1) per bin of the view ray's closest approach h to "
                "the light, over the light's distance D. core-ρ: the seed model with a fixed softening "
                "radius 1/√a = ρ·D and its level i fitted alone; the softening costs accuracy only for rays "
                "that pass within a few ρ of the source, and the seed model (no transmittance) cannot follow "
                "the extinction e^(−σ_t(s + r)) far from it.\n\n" + "\n".join(soft)
            ),
        },
    ]


def summary(case_docs, softening, accuracy, checks) -> str:
    sigmas = sorted({d["parameters"]["sigma_t_per_m"] for d in case_docs})
    st = max(accuracy["worst"][(lab, "stable")]["worst_rel_error"] for lab, _ in ACCURACY_SETS)
    sd = accuracy["worst"][(ACCURACY_SETS[1][0], "seed")]
    core = [d["parameters"]["core_radius_over_D"] for d in case_docs]
    bound = sum(d["parameters"]["a_at_upper_bound"] for d in case_docs)
    keff = {
        t: [
            d["parameters"]["fitted_K_over_true_K"]
            for d in case_docs
            if d["parameters"]["sigma_t_per_m"] == t
        ]
        for t in sigmas
    }
    reach = softening_reach(softening)
    passed = sum(c["passed"] for c in checks)
    parts = [
        f"σ_t = {t:g} /m: inverse square (no extinction) relMSE "
        f"{_mean_rel(case_docs, 'inverse-square', t):.3g}, fitted seed model "
        f"{_mean_rel(case_docs, 'seed-fit', t):.3g} (fitted i/a = {min(keff[t]):.2f}–{max(keff[t]):.2f} of "
        "σ_s·I/(4π))"
        for t in sigmas
    ]
    reach_text = (
        ", ".join(
            f"ρ = {k[5:]}·D: h ≲ {v:.1f}ρ" for k, v in sorted(reach.items(), key=lambda kv: float(kv[0][5:]))
        )
        or "none resolved"
    )
    return (
        "The seed's volumetric lightning against path-traced single scattering of a point light. The stable "
        f"closed form keeps a float32 relative error of at most {st:.2g} over the whole domain (near-axial "
        f"rays at a up to 1e3, a = 0, |d| = 0); the printed form is non-finite for {sd['non_finite']} of "
        f"{sd['samples']} near-axial rays at a = 100 /m². "
        + "; ".join(parts)
        + f". {bound} of {len(core)} fits put a on its upper bound, the finest core allowed (fitted 1/√a = "
        f"{min(core):.2g}–{max(core):.2g}·D): a point light wants no softening; a fixed core ρ costs more "
        "than 10 % over the fitted model "
        f"for rays passing within {reach_text}; what remains in dense media is the extinction, which the "
        f"seed's model (no transmittance) cannot follow. {passed} of {len(checks)} checks passed."
    )


# ================================================================================================ bench
COST_PARAMS = {"stable": {"i": 1.0, "a": 4.0}, "seed": {"i": 1.0, "a": 4.0}, "inverse-square": {"k": 1.0}}
"""Parameters of the timed kernels (per-pixel inputs: `random_domain`)."""

COST_KEYS = {"exact": None, "inverse-square": "inverse-square", "seed-fit": "stable"}
"""The measured cost row of each approximation row (the quadrature is not a real-time method)."""


def _cost_inputs(n: int, Float):
    o, d, lpos, _ = random_domain(n, seed=3)
    np_inputs = _method_inputs(o, d, lpos, np.float32)
    return np_inputs, {k: Float(v) for k, v in np_inputs.items()}


def cost_rows(ctx, cfg) -> list[dict]:
    """ns per pixel of each closed form beside the memory-traffic floor (the results' ``costs``)."""
    backend, Float = cost_backend(ctx.variant)
    n = cfg["cost_elements"]
    _, inputs = _cost_inputs(n, Float)
    note = "per pixel: o, d, l (9 floats) in, F out (float32)"
    floor = "the memory-bound floor of the closed forms"
    return method_cost_rows(METHODS, backend, inputs, n, note, floor, COST_PARAMS)


def bench(ctx) -> list[dict]:
    """Pixels/s of each closed form on Dr.Jit vs the same kernel text on NumPy (``method(NUMPY_OPS, …)``),
    then the reference's samples/s (volpathmis, point light, homogeneous medium)."""
    backend, n = bench_backend(ctx)
    Float = backend_float(backend)
    np_inputs, inputs = _cost_inputs(n, Float)
    baseline = "memory baseline (fma of the 9 inputs)"
    rows = method_bench_rows(METHODS, backend, inputs, np_inputs, n, COST_PARAMS, baseline=baseline)
    res, spp = ((32, 24), 256) if ctx.quick else ((128, 96), 1024)
    what = "reference: volpathmis + point light, homogeneous medium, single scattering"
    rows.append(reference_rate_row(what, case_scene(case_parameters(8.0, 0.5), res), spp, ctx.variant))
    return rows
