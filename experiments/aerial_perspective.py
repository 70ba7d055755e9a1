"""Experiment ``aerial-perspective``: the fog-colour blend L = L₀·T + C·(1 − T) under the Nishita atmosphere
and an exponential height fog together, its error split by simplification per sun elevation.

What is compared (docs/aerial-perspective.md):

* **Reference**: the single-scattering integral through atmosphere + fog with the sun attenuated by both
  (`rtfit.realtime.aerial_perspective.aerial_scattering`, float64 quadrature) over a terrain view (flat
  ground and an oblique ridge: surfaces from 0.3 to 40 km). Its noise floor per pixel is the quadrature's
  own error estimate |Q(P) − Q(P/2)|. Checked by independent values: fog alone against a path-traced
  Mitsuba render (`rtfit.reference.aerial_perspective`, volpathmis, rtfit's fog medium and distant sun)
  within its noise; atmosphere alone against `rtfit.reference.nishita_sky.single_scattering_quadrature`.
* **The ladder of simplifications** (each row adds one; the error budget's parts are its increments, which
  sum to the total exactly): (1) the source function frozen at the camera (C = J(camera, direction), the
  sun attenuated as at the camera: ``camera-source``); (2) the seed's horizon-averaged colour with the phase
  per pixel (``horizon-colour``, 000:2247-2254, 002:224-290); (3) grey instead of per-channel extinction
  (``horizon-grey``: the seed's whole model). One-at-a-time rows show interactions: ``sun-frozen`` (the
  exact integral with T_sun frozen: the sun attenuation alone) and ``grey-quadrature`` (grey extinction
  alone).
* **Fit** per sun elevation: b, c and the colour C₀ + C₁·4π·p_HG(θ, g) of `rtfit.realtime.height_fog`'s
  ``phase`` method, through the JAX run of its kernel (`rtfit.fitting.fit_method`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.fitting import Param, compute_metrics, fit_method
from rtfit.realtime import DRJIT_OPS, NUMPY_OPS
from rtfit.realtime.aerial_perspective import (
    FogLayer,
    aerial_scattering,
    fog_blend,
    horizon_colour,
    horizon_fog_colour,
    sun_direction,
    sun_transmittance_at,
)
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.height_fog import METHODS as FOG_METHODS
from rtfit.realtime.height_fog import fog_pass
from rtfit.realtime.nishita_sky import AtmosphereParams
from rtfit.reference.aerial_perspective import box_exit_distance, render_fog_sun
from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature

from . import figures as F
from . import fitted as fitfiles
from .cost import (
    attach_costs,
    bench_backend,
    comparison_rows,
    cost_backend,
    cost_row,
    memory_floor_row,
    time_drjit,
    time_numpy,
)
from .jobs import Job
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row

# ============================================================================================ configure
CONFIG = {
    "sun_elevations_deg": ConfigKey("float", "sun elevations (degrees), one case each", -4.0, 90.0, (None,)),
    "sun_azimuth_deg": ConfigKey(
        "float", "sun azimuth from the view axis +y towards +x (degrees)", 0.0, 360.0
    ),
    "camera_z_m": ConfigKey("float", "camera height above the ground (m)", 1.0, 2000.0),
    "fog_density": ConfigKey("float", "fog extinction b at z = 0 (1/m)", 0.0, 1.0),
    "fog_falloff": ConfigKey("float", "fog falloff c (1/m; scale height 1/c)", 1e-5, 1.0),
    "fog_g": ConfigKey("float", "fog Henyey–Greenstein g", -0.9, 0.9),
    "resolution": ConfigKey("int", "view (W, H) pixels", 4, 1024, (2,)),
    "panels": ConfigKey("int", "quadrature panels of the reference (4 Gauss nodes each)", 4, 512),
    "check_spp": ConfigKey("int", "samples per direction of one Mitsuba check pass", 16, SPP_MAX),
    "check_passes": ConfigKey("int", "independent Mitsuba check passes (the noise estimate)", 4, 64),
    "check_resolution": ConfigKey("int", "directions (W, H) of the Mitsuba check", 2, 256, (2,)),
    "cost_elements": ConfigKey("int", "elements per timed launch", 1024, 1 << 26),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "sun_elevations_deg": [60.0, 4.0, -4.0]
            if quick
            else [90.0, 60.0, 30.0, 15.0, 8.0, 4.0, 2.0, 0.0, -2.0, -4.0],
            "sun_azimuth_deg": 120.0,
            "camera_z_m": 50.0,
            "fog_density": 2e-4,
            "fog_falloff": 4e-3,
            "fog_g": 0.6,
            "resolution": [20, 10] if quick else [80, 40],
            "panels": 24 if quick else 32,
            "check_spp": spp or (1024 if quick else 16384),
            "check_passes": 8,
            "check_resolution": [8, 6] if quick else [24, 12],
            "cost_elements": 1 << (14 if quick else 18),
        },
    )


# ============================================================================================ the scene
FOV_DEG = (80.0, (-10.0, 4.0))
"""Horizontal field of view and the elevation range of the view (degrees); the view axis is +y."""
RIDGE = (12000.0, 0.6)
"""The ridge: the vertical plane y = Y₀ + k·x (m), facing the camera (every pixel hits ground or ridge)."""
ALBEDO = 0.25
GREY_LEVEL_FLOOR = 0.01
"""Errors are normalised by the reference's mean radiance at that elevation, floored at this fraction of
the largest mean over the run's elevations (the sun below the horizon leaves a black reference)."""
FIT_RANGE = {"b": (1e-2, 1e2), "c": (1e-2, 1e2)}
FIT_MAX_STEPS = 2048


def view_directions(resolution) -> np.ndarray:
    """Unit pixel directions (H, W, 3), rows from the top (elevation 4°) down to −10°."""
    w, h = resolution
    az = np.radians((np.arange(w) + 0.5) / w * FOV_DEG[0] - 0.5 * FOV_DEG[0])
    lo, hi = FOV_DEG[1]
    el = np.radians(hi - (np.arange(h) + 0.5) / h * (hi - lo))
    A, E = np.meshgrid(az, el)
    return np.stack([np.cos(E) * np.sin(A), np.cos(E) * np.cos(A), np.sin(E)], -1)


def surfaces(dirs: np.ndarray, z0: float) -> dict:
    """Distance (m), hit point and unit normal of the ground z = 0 and the ridge (`RIDGE`), nearest hit."""
    y0, k = RIDGE
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(dirs[..., 2] < 0, -z0 / dirs[..., 2], np.inf)
        den = dirs[..., 1] - k * dirs[..., 0]
        t_ridge = np.where(den > 0, y0 / den, np.inf)
    ridge = t_ridge < t_ground
    t = np.where(ridge, t_ridge, t_ground)
    n_ridge = np.array([k, -1.0, 0.0]) / math.hypot(k, 1.0)
    normal = np.where(ridge[..., None], n_ridge, np.array([0.0, 0.0, 1.0]))
    p = dirs * t[..., None] + np.array([0.0, 0.0, z0])
    p[..., 2] = np.maximum(p[..., 2], 0.0)
    return {"distance": t, "point": p, "normal": normal, "ridge": ridge}


def surface_radiance(geo: dict, atm: AtmosphereParams, sun, fog: FogLayer) -> np.ndarray:
    """Fog-free surface radiance L₀ (H, W, 3): Lambert, albedo `ALBEDO`, lit by the sun attenuated by
    atmosphere and fog to the surface point (the same in every row: only the view path differs)."""
    p = geo["point"]
    ts = sun_transmittance_at(NUMPY_OPS, p[..., 0], p[..., 1], p[..., 2], atm, sun, fog)
    cos_i = np.maximum(geo["normal"] @ np.asarray(sun), 0.0)
    return np.stack([ALBEDO / math.pi * atm.solar_irradiance[c] * ts[c] * cos_i for c in range(3)], -1)


# ============================================================================================== methods
# Rows (`rows.Row`; ``method`` None: `row_images` computes every row's image): the ladder's steps (1),
# (1 + 2), (1 + 2 + 3) add one simplification each, as their labels say.
ROWS = (
    Row("sun-frozen", "exact integral, sun attenuated as at the camera (1 alone: sun attenuation)"),
    Row("camera-source", "blend, C = source function at the camera per direction (1)"),
    Row("horizon-colour", "blend, C = seed's horizon average × per-pixel phase (1 + 2)"),
    Row("horizon-grey", "blend, horizon colour, grey extinction: the seed's model (1 + 2 + 3)"),
    Row("grey-quadrature", "exact integral with grey extinction (3 alone)"),
    Row("fitted", "height-fog phase blend, b, c, C₀, C₁, g fitted per elevation", fitted=True),
)
BUDGET_PARTS = ("(1) source frozen at the camera", "(2) horizon-averaged colour", "(3) grey extinction")


def row_images(q: dict, l0: np.ndarray, cos_sun: np.ndarray, horizon, g_mie: float) -> dict:
    """The rows' images (H, W, 3) from one quadrature pass ``q`` (channel lists shaped like the image)."""
    L0 = [l0[..., c] for c in range(3)]
    col_h = horizon_fog_colour(horizon[0], horizon[1], cos_sun, g_mie)
    out = {
        "exact": [L0[c] * q["T"][c] + q["S"][c] for c in range(3)],
        "sun-frozen": [L0[c] * q["T"][c] + q["S_sun_frozen"][c] for c in range(3)],
        "camera-source": fog_blend(L0, q["T"], q["J_cam"]),
        "horizon-colour": fog_blend(L0, q["T"], list(col_h)),
        "horizon-grey": fog_blend(L0, q["T_grey"], list(col_h)),
        "grey-quadrature": [L0[c] * q["T_grey"][c] + q["S_grey"][c] for c in range(3)],
    }
    return {k: np.stack(v, -1) for k, v in out.items()}


def relative_error(img: np.ndarray, ref: np.ndarray, norm: float) -> float:
    """RMS over pixels and channels of (img − ref), over ``norm`` (module constant `GREY_LEVEL_FLOOR`)."""
    return float(np.sqrt(np.mean((img - ref) ** 2)) / norm)


# ================================================================================================= jobs
def reference_job(cfg: dict, elevation: float) -> dict:
    """Job: the reference quadrature and every row's image at one sun elevation (NumPy float64)."""
    atm = AtmosphereParams()
    fog = FogLayer(cfg["fog_density"], cfg["fog_falloff"], cfg["fog_g"])
    sun = sun_direction(elevation, cfg["sun_azimuth_deg"])
    dirs = view_directions(cfg["resolution"])
    z0 = cfg["camera_z_m"]
    geo = surfaces(dirs, z0)
    args = (z0, dirs[..., 0], dirs[..., 1], dirs[..., 2], geo["distance"])
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        q = aerial_scattering(NUMPY_OPS, *args, atmosphere=atm, sun=sun, fog=fog, panels=cfg["panels"])
        q_half = aerial_scattering(
            NUMPY_OPS, *args, atmosphere=atm, sun=sun, fog=fog, panels=max(cfg["panels"] // 2, 1)
        )
    l0 = surface_radiance(geo, atm, sun, fog)
    cos_sun = dirs @ np.asarray(sun)
    horizon = horizon_colour(atm, max(elevation, -4.0))
    images = row_images(q, l0, cos_sun, horizon, atm.mie_g)
    half = np.stack([l0[..., c] * q_half["T"][c] + q_half["S"][c] for c in range(3)], -1)
    return {
        "images": images,
        "stderr": np.abs(images["exact"] - half),
        "l0": l0,
        "geometry": {"z1": geo["point"][..., 2], "distance": geo["distance"], "cos_sun": cos_sun},
        "horizon": horizon,
        "T_mean": float(np.mean(q["T"][1])),
    }


def fit_job(inputs: dict, target, scale, params: dict, g: float) -> dict:
    """Job: fit the height-fog ``phase`` method to one reference image (pixel-flattened, JAX); the lobe's g
    is held at the fog's (with C₁ → 0 a free g is undetermined and the solver wanders)."""
    result = fit_method(
        FOG_METHODS["phase"],
        inputs,
        target,
        weights=1.0 / np.asarray(scale),
        params=params,
        held={"g": g},
        output=stack_rgb,
        max_steps=FIT_MAX_STEPS,
    )
    return result.to_dict()


def stack_rgb(channels):
    """The shading kernel's (r, g, b) as (…, 3) (module level: one jit)."""
    import jax.numpy as jnp  # jax: only the fits need it (heavy import)

    return jnp.stack(channels, axis=-1)


def fit_params(cfg: dict, horizon) -> dict[str, Param]:
    """Start at the scene's b, c (bounds `FIT_RANGE` factors), the colour at the horizon average."""
    meth = FOG_METHODS["phase"].params
    out = {}
    for name, p in meth.items():
        if name == "g":
            continue
        if name in FIT_RANGE:
            x = cfg["fog_density"] if name == "b" else cfg["fog_falloff"]
            x = max(x, 1e-6)
            out[name] = Param(
                x, x * FIT_RANGE[name][0], x * FIT_RANGE[name][1], unit=p.unit, description=p.description
            )
        elif name.endswith("0"):
            h = (horizon[0][("rgb").index(name[0])] + horizon[1][("rgb").index(name[0])]) / (4 * math.pi)
            out[name] = dataclasses.replace(p, initial=float(min(max(h, 1e-3), 50.0)))
        else:
            out[name] = p
    return out


def fit_inputs(ref: dict, cfg: dict) -> dict:
    g = ref["geometry"]
    return {
        "z0": np.full(g["z1"].size, cfg["camera_z_m"]),
        "z1": g["z1"].reshape(-1),
        "distance": g["distance"].reshape(-1),
        "cos_sun": g["cos_sun"].reshape(-1),
        **{f"l0_{ch}": ref["l0"][..., k].reshape(-1) for k, ch in enumerate("rgb")},
    }


def fitted_image(ref: dict, cfg: dict, fit: dict) -> np.ndarray:
    values = {k: v["value"] for k, v in fit["parameters"].items()} | {"g": cfg["fog_g"]}
    out = FOG_METHODS["phase"](NUMPY_OPS, fit_inputs(ref, cfg), values)
    return np.stack([np.asarray(c) for c in out], -1).reshape(ref["l0"].shape)


def check_job(cfg: dict, variant: str, seed: int, cache_dir: str | None = None) -> dict:
    """Job: the fog-only Mitsuba check (passes) and the quadrature of the same rays."""
    atm0 = AtmosphereParams(rayleigh_scale=0.0, mie_scale=0.0)
    fog = FogLayer(cfg["fog_density"], cfg["fog_falloff"], cfg["fog_g"])
    sun = sun_direction(30.0, cfg["sun_azimuth_deg"])
    w, h = cfg["check_resolution"]
    az = np.radians(np.linspace(-40.0, 40.0, w))
    el = np.radians(np.linspace(-8.0, 8.0, h))
    A, E = np.meshgrid(az, el)
    dirs = np.stack([np.cos(E) * np.sin(A), np.cos(E) * np.cos(A), np.sin(E)], -1).reshape(-1, 3)
    origin = (0.0, 0.0, cfg["camera_z_m"])
    half_width, height = 40000.0, 3000.0
    dist = box_exit_distance(origin, dirs, half_width, height)
    q = aerial_scattering(
        NUMPY_OPS, cfg["camera_z_m"], dirs[:, 0], dirs[:, 1], dirs[:, 2], dist,
        atmosphere=atm0, sun=sun, fog=fog, panels=cfg["panels"],
    )  # fmt: skip
    passes = render_fog_sun(
        variant, origin, dirs, density=fog.density, falloff=fog.falloff, g=fog.g, sun=sun,
        solar_irradiance=atm0.solar_irradiance, sun_angular_radius=atm0.sun_angular_radius,
        half_width=half_width, height=height, spp=cfg["check_spp"], passes=cfg["check_passes"], seed=seed,
        cache_dir=cache_dir,
    )  # fmt: skip
    means = np.stack([p.mean for p in passes])
    seconds = sum(p.seconds for p in passes)
    return {
        "mean": means.mean(0),
        "stderr": means.std(0, ddof=1) / math.sqrt(len(passes)),
        "quadrature": np.stack(q["S"], -1),
        "samples_per_second": dirs.shape[0] * cfg["check_spp"] * len(passes) / max(seconds, 1e-9),
    }


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    jobs = [
        Job(
            reference_job,
            {"cfg": cfg, "elevation": e},
            label=f"sun {e:g}°",
        )
        for e in cfg["sun_elevations_deg"]
    ]
    jobs.append(
        Job(
            check_job,
            {"cfg": cfg, "variant": ctx.variant, "seed": ctx.seed, "cache_dir": str(ctx.cache_dir)},
            label="mitsuba check",
        )
    )
    ctx.log(f"{len(jobs) - 1} reference quadratures and one path-traced check")
    out = ctx.executor.map(jobs, desc="references")
    refs = dict(zip(cfg["sun_elevations_deg"], out[:-1], strict=True))
    check = out[-1]
    norms = {e: float(np.mean(r["images"]["exact"])) for e, r in refs.items()}
    floor = GREY_LEVEL_FLOOR * max(max(norms.values()), 1e-30)
    lit = {e: norms[e] > floor for e in refs}
    fit_jobs, fit_keys = [], []
    for e, r in refs.items():
        if not lit[e]:
            continue
        target = r["images"]["exact"].reshape(-1, 3)
        scale = 0.02 * np.abs(target) + 0.01 * float(np.mean(np.abs(target)))
        fit_jobs.append(
            Job(
                fit_job,
                {
                    "inputs": fit_inputs(r, cfg),
                    "target": target,
                    "scale": scale,
                    "params": fit_params(cfg, r["horizon"]),
                    "g": cfg["fog_g"],
                },
                label=f"fit sun {e:g}°",
            )
        )
        fit_keys.append(e)
    fits = dict(zip(fit_keys, ctx.executor.map(fit_jobs, desc="fits"), strict=True)) if fit_jobs else {}
    return assemble(ctx, cfg, refs, check, fits, norms, floor)


def case_id(e: float) -> str:
    return f"sun{e:+g}".replace("+", "p").replace("-", "m").replace(".", "_")


def assemble(ctx, cfg, refs, check, fits, norms, floor) -> dict:
    case_docs, checks, budget = [], [], []
    for e, r in refs.items():
        ref = r["images"]["exact"]
        se = np.maximum(r["stderr"], 1e-12 * max(float(np.abs(ref).max()), 1e-30))
        norm = max(norms[e], floor)
        images = dict(r["images"])
        if e in fits:
            images["fitted"] = fitted_image(r, cfg, fits[e])
        errs, docs = {}, []
        for row in ROWS:
            if row.id not in images:
                continue
            img = images[row.id]
            errs[row.id] = relative_error(img, ref, norm)
            m = compute_metrics(img, ref, se, names=("rmse", "rel_mse", "mae"))
            params = (
                {k: float(v["value"]) for k, v in fits[e]["parameters"].items()} if row.id == "fitted" else {}
            )
            docs.append(
                {
                    "method": row.id,
                    "label": row.label,
                    "fitted": row.fitted,
                    "parameters": params,
                    "metrics": {**m.to_dict(), "rel_rms": {"value": errs[row.id]}},
                }
            )
        ladder = [errs["camera-source"], errs["horizon-colour"], errs["horizon-grey"]]
        parts = [ladder[0], ladder[1] - ladder[0], ladder[2] - ladder[1]]
        budget.append(
            {
                "sun_elevation_deg": e,
                "parts": dict(zip(BUDGET_PARTS, parts, strict=True)),
                "total": ladder[2],
                "sun_attenuation_alone": errs["sun-frozen"],
                "grey_alone": errs["grey-quadrature"],
                "grey_interaction": parts[2] - errs["grey-quadrature"],
                "fitted": errs.get("fitted"),
            }
        )
        finite = all(np.all(np.isfinite(v)) for v in images.values())
        checks.append(
            Check(
                name=f"sun {e:g}°: every row finite (no NaN/Inf)",
                value=str(finite),
                expected="True",
                passed=bool(finite),
            )
        )
        conv = float(np.max(r["stderr"]) / max(float(np.mean(ref)), floor))
        checks.append(
            Check(
                name=f"sun {e:g}°: quadrature converged, max |Q(P) − Q(P/2)| / mean level",
                value=conv,
                expected="≤ 1e-3",
                passed=bool(conv <= 1e-3),
            )
        )
        if e <= -2.0:
            dark = float(np.max(np.abs(ref)))
            checks.append(
                Check(
                    name=f"sun {e:g}°: the planet occludes the sun at every scattering point and surface",
                    value=dark,
                    expected="= 0",
                    passed=bool(dark == 0.0),
                )
            )
        case_docs.append(
            {
                "id": case_id(e),
                "label": f"sun at {e:g}°",
                "parameters": {
                    "sun_elevation_deg": e,
                    "mean_reference_radiance": norms[e],
                    "error_norm": norm,
                    "mean_transmittance_G": r["T_mean"],
                    "horizon_rayleigh_rgb": [float(x) for x in r["horizon"][0]],
                    "horizon_mie_rgb": [float(x) for x in r["horizon"][1]],
                },
                "reference": {
                    "quantity": "single scattering through atmosphere + height fog, plus the surface",
                    "integrator": "quadrature (float64, Gauss–Legendre panels, t = D·u³)",
                    "panels": cfg["panels"],
                },
                "approximations": docs,
            }
        )
        if e in fits:
            checks.append(
                Check(
                    name=f"sun {e:g}°: fit converged",
                    value=str(fits[e]["converged"]),
                    expected="True",
                    passed=bool(fits[e]["converged"]),
                )
            )
    checks += reference_checks(check)
    checks += extreme_checks(cfg)
    figs = make_figures(ctx.out_dir, cfg, refs, fits, budget)
    fit_docs = write_fitted(ctx, cfg, refs, fits)
    costs = cost_rows(ctx, cfg)
    # the blend rows cost one fog pass per pixel; the integral rows have no real-time cost (see `bench`)
    blend_rows = {"camera-source", "horizon-colour", "horizon-grey", "fitted"}
    attach_costs(case_docs, costs, key=lambda ap: "horizon-grey" if ap["method"] in blend_rows else None)
    return {
        "summary": summary(budget, checks),
        "config": cfg,
        "sections": sections(),
        "cases": case_docs,
        "fits": fit_docs,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "error_budget": budget,
        "mitsuba_check": {
            "samples_per_second": float(check["samples_per_second"]),
            "mean_rel_stderr": float(np.mean(check["stderr"] / np.maximum(check["mean"], 1e-30))),
        },
        "notes": NOTES,
    }


FIT_RESIDUAL_UNITS = "(model − reference)/(0.02·|reference| + 0.01·mean|reference|) per pixel and channel"


def write_fitted(ctx, cfg, refs, fits) -> list[dict]:
    """fitted/fog-<case>.json per fitted elevation (``rtfit.fitted/1``: b, c, C₀, C₁ with units, bounds and
    the held g, the residual, the domain and the GLSL/HLSL of the height-fog ``phase`` kernel); returns the
    results' ``fits`` records."""
    m = FOG_METHODS["phase"]
    docs = []
    for e, fit in fits.items():
        cid = case_id(e)
        full = dict(fit, parameters={**fit["parameters"], "g": {"value": float(cfg["fog_g"])}})
        g = refs[e]["geometry"]
        file = f"fitted/fog-{cid}.json"
        entry = fitfiles.method_entry(
            m,
            full,
            label=f"{m.label}, sun {e:g}°",
            case=cid,
            domain={
                "distance": (float(g["distance"].min()), float(g["distance"].max()), "m"),
                "z1": (float(g["z1"].min()), float(g["z1"].max()), "m"),
            },
            residual_units=FIT_RESIDUAL_UNITS,
            data={"sun_elevation_deg": e, "held": {"g": cfg["fog_g"]}},
        )
        docs.append(
            fitfiles.write_fit(
                ctx.out_dir,
                file,
                title=f"aerial perspective: height-fog blend fitted to atmosphere + fog at sun {e:g}°",
                provenance=fitfiles.provenance(ctx, "aerial-perspective"),
                entry=entry,
                doc_id=f"fog-{cid}",
                label=f"height-fog phase blend fitted at sun {e:g}° (g held at {cfg['fog_g']:g})",
                model=m.formula,
                fit=fit,
                at_bound=fit.get("at_bound"),
            )
        )
    return docs


# =============================================================================================== checks
def reference_checks(check: dict) -> list[Check]:
    """The fog-only quadrature against the Mitsuba render (z-scores), and the atmosphere-only quadrature
    against `rtfit.reference.nishita_sky.single_scattering_quadrature`."""
    m, se, q = check["mean"], np.maximum(check["stderr"], 1e-30), check["quadrature"]
    z = (m - q) / se
    bias = float(np.sum(m - q) / math.sqrt(float(np.sum(se**2))))
    med = float(np.median(np.abs(z)))
    out = [
        Check(
            name="fog-only quadrature vs path-traced Mitsuba (volpathmis, rtfit_expfog, distant sun): "
            "summed bias in units of its standard error",
            value=bias,
            expected="|z| ≤ 4",
            passed=bool(abs(bias) <= 4.0),
        ),
        Check(
            name="fog-only quadrature vs Mitsuba: median |z| per direction (t with passes − 1 dof: ≈ 0.7)",
            value=med,
            expected="≤ 1.2",
            passed=bool(med <= 1.2),
        ),
    ]
    atm = AtmosphereParams()
    spec = library_atmosphere(sun_elevation_deg=20.0, viewer_altitude_m=50.0)
    el = np.radians(np.array([2.0, 10.0, 60.0]))
    az = np.radians(np.array([0.0, 150.0]))
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    ref = single_scattering_quadrature(spec, d, steps=2000)
    r0 = atm.planet_radius_m + 50.0
    mu = d[:, 2]
    dist = -r0 * mu + np.sqrt(r0 * r0 * mu * mu + atm.top_radius_m**2 - r0 * r0)
    q = aerial_scattering(
        NUMPY_OPS, 50.0, d[:, 0], d[:, 1], d[:, 2], dist,
        atmosphere=atm, sun=sun_direction(20.0, 90.0), fog=FogLayer(0.0, 1e-3, 0.0), panels=32,
    )  # fmt: skip
    mine = np.stack(q["S"], -1)
    rel = float(np.max(np.abs(mine / ref - 1.0)))
    out.append(
        Check(
            name="atmosphere-only quadrature (fog b = 0, sky rays to the top) vs nishita-sky's reference "
            "quadrature, max relative difference",
            value=rel,
            expected="≤ 2e-3",
            passed=bool(rel <= 2e-3),
        )
    )
    return out


def extreme_checks(cfg: dict) -> list[Check]:
    """Horizontal rays, zero and huge fog, the sun at −4°: finite values and the known limits."""
    atm = AtmosphereParams()
    dirs = np.array([[0.0, 1.0, 0.0], [0.3, 0.95393920141, 0.0], [0.0, 0.99984769515, -0.01745240644]])
    dist = np.array([40000.0, 25000.0, 2864.0])
    out = []
    for e in (30.0, -4.0):
        sun = sun_direction(e, cfg["sun_azimuth_deg"])
        for name, fog in (
            ("zero fog", FogLayer(0.0, 4e-3, 0.6)),
            ("huge fog b = 1/m", FogLayer(1.0, 4e-3, 0.6)),
        ):
            q = aerial_scattering(
                NUMPY_OPS,
                cfg["camera_z_m"],
                dirs[:, 0],
                dirs[:, 1],
                dirs[:, 2],
                dist,
                atmosphere=atm,
                sun=sun,
                fog=fog,
                # 4× the panels where the limit is compared (t = D·u³ must resolve a 1 m mean free path)
                panels=4 * cfg["panels"] if name.startswith("huge") and e > 0 else 8,
            )
            vals = np.concatenate([np.ravel(v) for k in q for v in q[k]])
            ok = bool(np.all(np.isfinite(vals)))
            out.append(
                Check(
                    name=f"{name}, sun {e:g}°, horizontal rays: finite",
                    value=str(ok),
                    expected="True",
                    passed=ok,
                )
            )
            if name.startswith("huge") and e > 0:
                s, j = np.stack(q["S"])[:, :2], np.stack(q["J_cam"])[:, :2]  # the level rays: J constant
                rel = float(np.max(np.abs(s / j - 1.0)))
                out.append(
                    Check(
                        name="huge fog, level rays: in-scatter = the source function at the camera",
                        value=rel,
                        expected="≤ 1e-3",
                        passed=bool(rel <= 1e-3),
                    )
                )
            if e < 0:
                mx = float(np.max(np.abs(np.stack(q["S"]))))
                out.append(
                    Check(
                        name=f"{name}, sun {e:g}°: no single scattering (planet shadow)",
                        value=mx,
                        expected="= 0",
                        passed=bool(mx == 0.0),
                    )
                )
    return out


# ============================================================================================== figures
def make_figures(out, cfg, refs, fits, budget) -> list[dict]:
    fdir = out / "figures"
    fdir.mkdir(parents=True, exist_ok=True)
    plt = F.pyplot()
    figs = []
    fig, ax = plt.subplots(figsize=(max(6.0, 0.7 * len(budget) + 2), 4.0))
    x = np.arange(len(budget))
    colours = ("tab:orange", "tab:blue", "tab:green")
    pos = np.zeros(len(budget))
    neg = np.zeros(len(budget))
    for k, part in enumerate(BUDGET_PARTS):
        v = np.array([b["parts"][part] for b in budget])
        bottom = np.where(v >= 0, pos, neg)
        ax.bar(x, v, bottom=bottom, color=colours[k], label=part, hatch=None)
        pos = pos + np.maximum(v, 0)
        neg = neg + np.minimum(v, 0)
    ax.plot(x, [b["total"] for b in budget], "k_", markersize=18, mew=2, label="total (= sum of the parts)")
    ax.plot(
        x, [b["sun_attenuation_alone"] for b in budget], "v", color="tab:red", label="sun attenuation alone"
    )
    ax.plot(x, [b["grey_alone"] for b in budget], "^", color="tab:purple", label="grey extinction alone")
    fitted = [b["fitted"] if b["fitted"] is not None else np.nan for b in budget]
    ax.plot(x, fitted, "o", color="black", mfc="none", label="fitted b, c, colour")
    ax.axhline(0.0, color="grey", lw=0.5)
    top = max([b["total"] for b in budget] + [float(np.max(pos))] + [1e-3])
    ax.set_ylim(top=3.0 * top)
    ax.set_xticks(x, [f"{b['sun_elevation_deg']:g}°" for b in budget])
    ax.set_xlabel("sun elevation")
    ax.set_ylabel("RMS error / mean reference radiance")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title("aerial perspective: error budget of the fog blend per sun elevation")
    path = F.save_figure(fig, fdir / "error_budget.png")
    figs.append(
        {
            "file": f"figures/{path.name}",
            "caption": "Stacked error budget per sun elevation: the increments of the ladder (1) source "
            "function frozen at the camera → (2) the seed's horizon-averaged colour → (3) grey extinction; "
            "the parts sum to the total (bar), negative increments (an error cancelling) are drawn below 0. "
            "Markers: each simplification alone (sun attenuation, grey extinction) — their difference to the "
            "ladder's increment is the interaction — and the fitted blend.",
            "section": "budget",
        }
    )
    e_show = [e for e in refs if np.mean(refs[e]["images"]["exact"]) > 0][:2]
    for e in e_show:
        r = refs[e]
        panels = [(row.id, r["images"][row.id]) for row in ROWS if row.id in r["images"]]
        p = F.image_comparison(
            fdir / f"view_{case_id(e)}.png",
            r["images"]["exact"],
            panels[1:4],
            np.ones(r["images"]["exact"].shape[:2], bool),
            float(np.mean(r["images"]["exact"])),
            title=f"sun {e:g}°",
        )
        figs.append(
            {
                "file": f"figures/{p.name}",
                "caption": f"Reference and ladder rows at sun {e:g}°.",
                "section": "budget",
            }
        )
    return figs


NOTES = [
    "Radiance in units of the solar irradiance E₀ per steradian (W·m⁻²·sr⁻¹·nm⁻¹ with Bruneton's E₀).",
    "rel_rms: RMS over pixels and channels of (row − reference) over the mean reference radiance at that "
    "elevation, floored at 1 % of the largest mean of the run (a sun below the horizon leaves a black view).",
    "The reference's stderr is the quadrature's own error estimate |Q(P) − Q(P/2)| (deterministic).",
]


def sections() -> list[dict]:
    return [
        {
            "id": "budget",
            "title": "What each simplification of the fog blend costs",
            "text": "L = L₀·T + C·(1 − T) is exact when the source function J = E₀·T_sun·σ_s·P/σ_t is "
            "constant along the view ray. Under the Nishita atmosphere and a height fog it is not: the sun "
            "is "
            "attenuated differently at each point (strongly near sunset), the atmosphere/fog mixture changes "
            "with height, and the extinction is chromatic. The ladder adds one simplification per row; the "
            "stacked bars are its increments. See docs/aerial-perspective.md.",
        }
    ]


def summary(budget, checks) -> str:
    ok = sum(c["passed"] for c in checks)
    lines = [f"{ok}/{len(checks)} checks pass."]
    for b in budget:
        parts = ", ".join(f"{k.split(')')[0]})={v:.3g}" for k, v in b["parts"].items())
        fit = f"; fitted {b['fitted']:.3g}" if b["fitted"] is not None else ""
        lines.append(f"sun {b['sun_elevation_deg']:g}°: total {b['total']:.3g} ({parts}){fit}")
    return " ".join(lines)


# ================================================================================================ costs
def _cost_inputs(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    el = np.radians(rng.uniform(-10.0, 4.0, n))
    az = np.radians(rng.uniform(-40.0, 40.0, n))
    d = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    dist = np.where(d[:, 2] < 0, 50.0 / np.maximum(-d[:, 2], 1e-3), 20000.0).clip(1.0, 40000.0)
    return d, dist


def _quadrature_fn(ops, panels):
    atm, fog, sun = AtmosphereParams(), FogLayer(), sun_direction(20.0, 120.0)

    def fn(z0, dx, dy, dz, dist):
        q = aerial_scattering(ops, z0, dx, dy, dz, dist, atmosphere=atm, sun=sun, fog=fog, panels=panels)
        return q["S"][0] + q["S"][1] + q["S"][2]

    return fn


def cost_rows(ctx, cfg) -> list[dict]:
    """ns per pixel of the seed's per-pixel fog pass (`height_fog.fog_pass` with the horizon colour and
    phase, Dr.Jit) beside the memory floor. The reference quadrature's cost is in ``rtfit bench``."""
    backend, Float = cost_backend(ctx.variant)
    n = cfg["cost_elements"]
    d, dist = _cost_inputs(n)
    args = (
        Float(np.full(n, 0.2)), Float(np.full(n, 0.3)), Float(np.full(n, 0.4)),
        Float(np.full(n, 50.0)), Float(d[:, 2]), Float(dist), Float(d[:, 1]),
    )  # fmt: skip

    def blend(r, g, b, z0, dz, dist, cos_sun):
        return fog_pass(
            (r, g, b), z0, dz, dist, 2e-4, 4e-3, (0.0, 0.0, 0.0),
            cos_sun=cos_sun, phase_colour=(0.1, 0.1, 0.1), g=0.8,
        )  # fmt: skip

    label = "the seed's fog pass (T + horizon colour × phase)"
    return [
        cost_row("horizon-grey", label, backend, time_drjit(blend, args, n), "per pixel"),
        memory_floor_row(args, n, backend, "7 loads, 1 store", label="memory traffic baseline"),
    ]


def bench(ctx) -> list[dict]:
    """Rays/s of the quadrature kernel text on Dr.Jit vs NumPy, side by side."""
    backend, n = bench_backend(ctx)
    Float = backend_float(backend)
    n = min(n, 1 << 16)
    d, dist = _cost_inputs(n)
    np_args = (np.full(n, 50.0), d[:, 0], d[:, 1], d[:, 2], dist)
    args = tuple(Float(a) for a in np_args)

    def timed():
        for panels in (4, 16):
            t_dr = time_drjit(_quadrature_fn(DRJIT_OPS, panels), args, n, repeats=3, min_seconds=0.05)
            with np.errstate(all="ignore"):
                t_np = time_numpy(_quadrature_fn(NUMPY_OPS, panels), np_args, n, repeats=2, min_seconds=0.05)
            yield f"aerial quadrature, {panels} panels", t_dr, t_np

    return comparison_rows(backend, args, n, timed(), unit="ray", baseline="memory baseline")
