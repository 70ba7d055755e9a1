"""Evaluation, figures, fitted-parameter files and benchmark of the ``half-lambert`` experiment.

Split from `half_lambert` (which defines the scenes and jobs) to keep each module small.
All radiance values are relative to the lit peak (E⊥ = π, ρ = 1 ⇒ peak radiance 1).
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.reference.io import atomic_write_json

from . import figures
from .cost import (
    attach_costs,
    baseline_row,
    bench_backend,
    comparison_row,
    memory_baseline,
    time_drjit,
    time_numpy,
)
from .half_lambert import (
    LABELS,
    MODELS,
    _model_irradiance,
    case_id,
    case_scene,
    probe_points,
    smooth_p,
    smooth_w,
    sun_geometry,
)

# Z-test of the exact closed form against the reference, judged as Mitsuba's own tests do: a robust
# spread and a pass rate over elements, because the per-element variance estimate is unreliable where
# an element got only a few light samples (just above the lower horizon boundary, where the light is
# barely visible). Tolerances: the MAD spread of ≥ 500 normal z-scores has a standard deviation
# ≈ 1.17/√n ≤ 0.05, so ±0.15 is a 3σ band; |median| ≤ 0.15 likewise; with normal z-scores only
# 6e-5 of the elements exceed |z| > 4, so 1% leaves room for the few-hit elements alone.
Z_SPREAD_TOLERANCE = 0.15
Z_MEDIAN_TOLERANCE = 0.15
Z_TAIL_FRACTION = 0.01


def _params_for(model: str, cid: str, alpha_rad: float, fits: dict, smooth: dict) -> dict:
    if model == "wrap-fit":
        return {k: v["value"] for k, v in fits[cid]["parameters"].items()}
    if model == "wrap-smooth":
        c = {k: v["value"] for k, v in smooth["parameters"].items()}
        return {
            "w": float(np.clip(smooth_w(alpha_rad, c), 0.0, 1.0)),
            "p": float(np.clip(smooth_p(alpha_rad, c), 0.25, 8.0)),
        }
    if model == "half-lambert":
        return {"w": 1.0, "p": 2.0}
    if model == "lambert":
        return {"w": 0.0, "p": 1.0}
    return {}


def _image(mask, albedo, irradiance, background):
    img = background.copy()
    img[mask] = albedo[mask] * (np.asarray(irradiance)[:, None] / math.pi)
    return img


def assemble(ctx, cfg, cases, scenes, rendered, geom, fits, smooth, hashes) -> dict:
    from rtfit.fitting import compute_metrics

    out = ctx.out_dir
    case_docs, images, exact_z = [], {}, []
    for a, s in cases:
        cid = case_id(a, s)
        ref, gb = rendered[cid]["image"], rendered[cid]["gbuffer"]
        mask, cos_t, alpha, peak = geom[cid]
        approx_docs = []
        for model in MODELS:
            params = _params_for(model, cid, math.radians(a), fits, smooth)
            e = (
                np.asarray(_model_irradiance(model, cos_t, alpha, peak, params), dtype=np.float64)
                + math.pi * s
            )
            img = _image(mask, gb.albedo.astype(np.float64), e, ref.mean)
            images[(cid, model)] = img
            metrics = compute_metrics(img, ref.mean, ref.sigma(), mask)
            if model == "exact":  # channel 0 only: the scene is grey, the channels are one estimate
                exact_z.append(
                    _z_pair(
                        img[..., 0][mask],
                        ref.mean[..., 0][mask],
                        ref.stderr[..., 0][mask],
                        ref.sigma()[..., 0][mask],
                    )
                )
            approx_docs.append(
                {
                    "method": model,
                    "label": LABELS[model],
                    "fitted": model.startswith("wrap"),
                    "parameters": params,
                    "metrics": {k: _metric_dict(v) for k, v in metrics.items()},
                }
            )
        case_docs.append(
            {
                "id": cid,
                "label": f"α = {a:g}°, " + ("no sky" if s == 0 else f"sky radiance {s:g}"),
                "parameters": {"alpha_deg": a, "sky_radiance": s},
                "scene": {"name": scenes[cid].name, "hash": hashes[cid]},
                "reference": ref.to_dict(),
                "approximations": approx_docs,
            }
        )

    costs = _costs(ctx, cfg)
    attach_costs(case_docs, costs)

    figs = _figures(ctx, cfg, cases, rendered, geom, images, fits, smooth, case_docs, costs)
    fitted = _write_fitted(out, cfg, fits, smooth)
    z = _concat_pairs(exact_z)
    probe_z = _concat_pairs(_probe_z(cfg, cases, rendered, scenes))
    checks = _z_checks("exact closed form vs Mitsuba image", *z) + _z_checks(
        "exact closed form vs Mitsuba irradiance probes", *probe_z
    )
    z_std = _robust_spread(z[0])
    return {
        "summary": _summary(cfg, case_docs, smooth, z_std),
        "config": cfg,
        "sections": _sections(cfg),
        "cases": case_docs,
        "fits": fitted,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": [
            "Radiance is relative to the lit peak: E⊥ = π at normal incidence, white albedo, so the "
            "brightest lit point has radiance 1; every error is a fraction of that peak.",
            "Approximations are evaluated at the same pixel centres the reference is point-sampled at "
            "(see `rtfit.reference.estimators`), so an exact formula leaves only the reference noise.",
            "The sky term is exact for every model (π·L_sky on a convex surface), so all differences come "
            "from the light's term.",
        ],
    }


def _metric_dict(v) -> dict:
    d = v.to_dict() if hasattr(v, "to_dict") else dict(v.__dict__)
    return {k: (float(x) if isinstance(x, (np.floating, float)) else x) for k, x in d.items()}


# -------------------------------------------------------------------------------------------- costs
def _cost_inputs(n: int, backend: str, seed: int = 1):
    import drjit as dr

    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(-1, 1, n).astype(np.float32)
    alpha = np.radians(rng.uniform(0.27, 30, n)).astype(np.float32)
    Float = dr.cuda.Float if backend == "cuda" else dr.llvm.Float
    return cos_t, alpha, Float(cos_t), Float(alpha)


def _kernel_for(model: str, params: dict):
    from rtfit.realtime import diffuse

    if model == "lambert":
        return lambda c, a: diffuse.lambert(c, 1.0)
    if model == "half-lambert":
        return lambda c, a: diffuse.half_lambert(c, 1.0)
    if model.startswith("wrap"):
        return lambda c, a: diffuse.wrap(c, params["w"], params["p"], 1.0)
    return lambda c, a: diffuse.sphere_light_irradiance(c, a, 1.0)


def _costs(ctx, cfg) -> list[dict]:
    backend = "cuda" if ctx.variant.startswith("cuda") else "llvm"
    n = 1 << (20 if ctx.quick else 22)
    _, _, c, a = _cost_inputs(n, backend)
    rows = []
    for model in MODELS:
        t = time_drjit(_kernel_for(model, {"w": 0.5, "p": 1.5}), (c, a), n)
        rows.append(
            {
                "method": model,
                "label": LABELS[model],
                "backend": backend,
                **t.to_dict(),
                "note": "per pixel, inputs cos θ and α in memory, one float out",
            }
        )
    base = memory_baseline((c, a), n)
    rows.append(
        {
            "method": "memory-baseline",
            "label": "memory traffic baseline (2 loads, 1 store)",
            "backend": backend,
            **base.to_dict(),
            "note": "the memory-bound floor for these kernels",
        }
    )
    return rows


def bench(ctx) -> list[dict]:
    """Dr.Jit vs NumPy (same kernel text) per model, then reference vs Mitsuba's path integrator."""
    from rtfit.realtime import diffuse

    backend, n = bench_backend(ctx)
    cos_np, alpha_np, c, a = _cost_inputs(n, backend)
    cos64, alpha64 = cos_np.astype(np.float64), alpha_np.astype(np.float64)
    rows = []
    base = memory_baseline((c, a), n)
    for model in MODELS:
        t_dr = time_drjit(_kernel_for(model, {"w": 0.5, "p": 1.5}), (c, a), n)
        np_fn = diffuse.numpy_reference("wrap" if model.startswith("wrap") else model)
        np_args = _numpy_args(model, cos64, alpha64)
        t_np = time_numpy(lambda *xs: np_fn(*xs), np_args, n)
        rows.append(comparison_row(LABELS[model], backend, t_dr, t_np, base))
    rows.append(baseline_row(base, backend))
    rows += _bench_reference(ctx)
    return rows


def _numpy_args(model: str, cos64, alpha64):
    if model in ("lambert", "half-lambert"):
        return (cos64, 1.0)
    if model.startswith("wrap"):
        return (cos64, 0.5, 1.5, 1.0)
    return (cos64, alpha64, 1.0)


def _bench_reference(ctx) -> list[dict]:
    """Samples/s of rtfit's point-sampled reference vs ``mi.render`` with Mitsuba's ``path`` integrator."""
    import time

    from rtfit.reference import load_mitsuba_scene, radiance_pass

    res = 128 if ctx.quick else 256
    spp = 64 if ctx.quick else 256
    scene = case_scene(5.0, 0.2, res)
    mi, ms = load_mitsuba_scene(scene, ctx.variant)
    radiance_pass(mi, ms, spp, 0)  # warm-up (kernel compile / cache load)
    t_ref = min(radiance_pass(mi, ms, spp, k + 1).seconds for k in range(3))
    from rtfit.reference import mitsuba_scene_dict
    from rtfit.reference.build import load_dict

    d = mitsuba_scene_dict(mi, scene)
    d["integrator"] = {"type": "path"}
    ms_path = load_dict(mi, d)

    def render_path(seed):
        t0 = time.perf_counter()
        np.asarray(mi.render(ms_path, spp=spp, seed=seed))
        return time.perf_counter() - t0

    render_path(0)
    t_path = min(render_path(k + 1) for k in range(3))
    samples = res * res * spp
    return [
        {
            "what": f"reference: rtfit direct, point-sampled ({res}², {spp} spp)",
            "backend": ctx.variant,
            "elements": samples,
            "drjit_Mpx_s": samples / t_ref / 1e6,
            "numpy_Mpx_s": None,
            "drjit/numpy": None,
            "ns_per_px": t_ref / samples * 1e9,
            "vs_memory_floor": None,
        },
        {
            "what": f"Mitsuba path integrator, mi.render ({res}², {spp} spp)",
            "backend": ctx.variant,
            "elements": samples,
            "drjit_Mpx_s": samples / t_path / 1e6,
            "numpy_Mpx_s": None,
            "drjit/numpy": None,
            "ns_per_px": t_path / samples * 1e9,
            "vs_memory_floor": None,
        },
        {
            "what": "ratio: rtfit reference / Mitsuba path (samples/s)",
            "backend": ctx.variant,
            "elements": None,
            "drjit_Mpx_s": t_path / t_ref,
            "numpy_Mpx_s": None,
            "drjit/numpy": None,
            "ns_per_px": None,
            "vs_memory_floor": None,
        },
    ]


# ------------------------------------------------------------------------------------------ figures
def _figures(ctx, cfg, cases, rendered, geom, images, fits, smooth, case_docs, costs) -> list[dict]:
    out = ctx.out_dir
    figs = []
    alphas = cfg["alphas_deg"]
    show = [(alphas[1], 0.0), (alphas[-1], 0.0), (alphas[-1], cfg["sky_radiances"][-1])]
    for a, s in show:
        cid = case_id(a, s)
        ref = rendered[cid]["image"]
        mask = geom[cid][0]
        panels = [(LABELS[m], images[(cid, m)]) for m in ("lambert", "half-lambert", "wrap-fit", "exact")]
        name = f"figures/{cid}_images.png"
        figures.image_comparison(
            out / name,
            ref.mean,
            panels,
            mask,
            error_scale=1.0,
            title=f"α = {a:g}°, sky {s:g}: reference, approximations, signed error "
            "(fraction of the lit peak radiance)",
            exposure=1.0 + s,
        )
        figs.append(
            {
                "file": name,
                "section": "results",
                "caption": f"α = {a:g}°, sky radiance {s:g}. Top: Mitsuba reference and each approximation "
                "(same exposure). Bottom: signed error as a fraction of the lit peak radiance "
                "(red: too bright, blue: too dark).",
            }
        )
    figs.append(_terminator_figure(out, cfg, rendered, fits))
    figs.append(_params_figure(out, cfg, fits, smooth))
    figs.append(_error_vs_alpha_figure(out, cfg, case_docs))
    figs.append(_pareto_figure(out, case_docs, costs))
    return figs


def _probe_sun_geometry(count: int, sun):
    """θ (rad), cos θ, α and E⊥ of the equator probes for a distant light."""
    theta, _, normals = probe_points(count)
    return (theta, *sun_geometry(normals, sun))


def _robust_spread(z: np.ndarray) -> float:
    """1.4826 · median |z − median z|: the standard deviation of the normal core, blind to outliers."""
    if z.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(z - np.median(z))))


def _z_pair(approx, mean, stderr, sigma) -> tuple[np.ndarray, np.ndarray]:
    """(z of elements whose statistical error exceeds the precision floor, z of every element with σ > 0).

    Elements whose standard error is below float32 resolution (e.g. lit by the constant sky alone:
    zero variance on the CPU, 1-ulp variance on CUDA) carry no statistics; they enter only the tail
    check, through the precision floor in σ."""
    from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR

    d = np.asarray(approx, np.float64) - np.asarray(mean, np.float64)
    stat = stderr > RELATIVE_PRECISION_FLOOR * np.abs(mean)
    ok = sigma > 0
    return d[stat] / sigma[stat], d[ok] / sigma[ok]


def _concat_pairs(pairs) -> tuple[np.ndarray, np.ndarray]:
    if not pairs:
        return np.zeros(0), np.zeros(0)
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


def _z_checks(what: str, z: np.ndarray, z_all: np.ndarray) -> list[dict]:
    if z.size == 0:
        return [
            {"name": f"{what}: z-scores", "value": 0.0, "expected": "at least one element", "passed": False}
        ]
    spread, median = _robust_spread(z), float(np.median(z))
    tail = float(np.mean(np.abs(z_all) > 4))
    return [
        {
            "name": f"{what}: robust z spread (1.4826·MAD, {z.size} elements)",
            "value": spread,
            "expected": f"1 ± {Z_SPREAD_TOLERANCE}",
            "passed": abs(spread - 1) <= Z_SPREAD_TOLERANCE,
        },
        {
            "name": f"{what}: median z",
            "value": median,
            "expected": f"0 ± {Z_MEDIAN_TOLERANCE}",
            "passed": abs(median) <= Z_MEDIAN_TOLERANCE,
        },
        {
            "name": f"{what}: fraction with |z| > 4 ({z_all.size} elements)",
            "value": tail,
            "expected": f"≤ {Z_TAIL_FRACTION}",
            "passed": tail <= Z_TAIL_FRACTION,
        },
    ]


def _probe_z(cfg, cases, rendered, scenes) -> list:
    zs = []
    for a, s in cases:
        cid = case_id(a, s)
        pr = rendered[cid]["probes"]
        _, cos_t, alpha, peak = _probe_sun_geometry(cfg["probe_count"], scenes[cid].lights[0])
        exact = np.asarray(_model_irradiance("exact", cos_t, alpha, peak, {}), np.float64) + math.pi * s
        zs.append(_z_pair(exact, pr.mean[:, 0], pr.stderr[:, 0], pr.sigma()[:, 0]))
    return zs


def _terminator_figure(out, cfg, rendered, fits) -> dict:
    alphas = cfg["alphas_deg"]
    pick = [alphas[0], alphas[len(alphas) // 2], alphas[-1]]
    series, panels = [], []
    for a in pick:
        cid = case_id(a, 0.0)
        panel = f"α = {a:g}°"
        panels.append(panel)
        theta, cos_t, alpha, peak = _probe_sun_geometry(cfg["probe_count"], case_scene(a, 0.0, 8).lights[0])
        deg = np.degrees(theta)
        pr = rendered[cid]["probes"]
        series.append(
            {
                "x": deg,
                "y": pr.mean[:, 0] / math.pi,
                "yerr": 2 * pr.stderr[:, 0] / math.pi,
                "label": "Mitsuba (±2σ)",
                "style": "points",
                "panel": panel,
                "color": "k",
            }
        )
        exact = _model_irradiance("exact", cos_t, alpha, peak, {})
        series.append(
            {
                "x": deg,
                "y": np.asarray(exact) / math.pi,
                "label": "exact closed form",
                "panel": panel,
                "color": "0.4",
            }
        )
        w = fits[cid]["parameters"]
        for model, params, color in (
            ("lambert", {}, "C0"),
            ("half-lambert", {}, "C1"),
            ("wrap-fit", {"w": w["w"]["value"], "p": w["p"]["value"]}, "C2"),
        ):
            e = _model_irradiance(model, cos_t, alpha, peak, params)
            series.append(
                {
                    "x": deg,
                    "y": np.asarray(e) / math.pi,
                    "label": LABELS[model],
                    "panel": panel,
                    "color": color,
                    "ls": "--",
                }
            )
    name = "figures/terminator.png"
    figures.line_plot(
        out / name, "angle θ between normal and light direction (°)", "E / E⊥", series, panels=panels
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Irradiance across the terminator along the sphere's equator: Mitsuba irradiance probes "
        "(points, ±2σ), the exact closed form, and each approximation. The exact irradiance "
        "reaches past 90° by α (the light is partly below the horizon there).",
    }


def _params_figure(out, cfg, fits, smooth) -> dict:
    alphas = np.array(cfg["alphas_deg"])
    c = {k: v["value"] for k, v in smooth["parameters"].items()}
    fine = np.linspace(alphas.min(), alphas.max(), 200)
    series = []
    for name, fn in (("w", smooth_w), ("p", smooth_p)):
        vals = [fits[case_id(a, 0.0)]["parameters"][name] for a in alphas]
        series.append(
            {
                "x": alphas,
                "y": [v["value"] for v in vals],
                "yerr": [2 * (v["stderr"] or 0.0) for v in vals],
                "label": f"{name}: per-α fit (±2σ)",
                "style": "points",
                "panel": name,
            }
        )
        series.append(
            {"x": fine, "y": fn(np.radians(fine), c), "label": f"{name}(α): smooth fit", "panel": name}
        )
    name = "figures/wrap_parameters.png"
    figures.line_plot(out / name, "light angular radius α (°)", "parameter value", series, panels=["w", "p"])
    return {
        "file": name,
        "section": "fits",
        "caption": "Wrap parameters fitted per light size (points) and the smooth functions "
        "w(α) = w1·sin α + w2·sin²α, p(α) = 1 + p1·sin α + p2·sin²α fitted to them (lines).",
    }


def _error_vs_alpha_figure(out, cfg, case_docs) -> dict:
    series = []
    by_model: dict[str, list] = {}
    floor = []
    for doc in case_docs:
        if doc["parameters"]["sky_radiance"] != 0.0:
            continue
        for ap in doc["approximations"]:
            by_model.setdefault(ap["method"], []).append(
                (doc["parameters"]["alpha_deg"], ap["metrics"]["rmse"]["value"])
            )
        floor.append(
            (doc["parameters"]["alpha_deg"], doc["approximations"][0]["metrics"]["rmse"]["noise_floor"])
        )
    for model, pts in by_model.items():
        series.append({"x": [p[0] for p in pts], "y": [p[1] for p in pts], "label": LABELS[model]})
    series.append(
        {
            "x": [p[0] for p in floor],
            "y": [p[1] for p in floor],
            "label": "reference noise floor",
            "ls": ":",
            "color": "0.5",
        }
    )
    name = "figures/error_vs_alpha.png"
    figures.line_plot(
        out / name,
        "light angular radius α (°)",
        "RMSE (fraction of lit peak)",
        series,
        x_log=True,
        y_log=True,
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Image RMSE of each approximation against the Mitsuba reference vs light size (no sky), "
        "with the reference's own noise floor: values near the floor are not resolved.",
    }


def _pareto_figure(out, case_docs, costs) -> dict:
    cost = {c["method"]: c["ns_per_pixel"] for c in costs}
    err: dict[str, list] = {}
    floors = []
    for doc in case_docs:
        for ap in doc["approximations"]:
            err.setdefault(ap["method"], []).append(ap["metrics"]["rmse"]["value"])
        floors.append(doc["approximations"][0]["metrics"]["rmse"]["noise_floor"])
    pts = [{"x": cost[m], "y": float(np.mean(v)), "label": LABELS[m]} for m, v in err.items() if m in cost]
    name = "figures/pareto.png"
    figures.pareto_plot(
        out / name, pts, "cost (ns per pixel, measured)", "mean RMSE over cases", floor=float(np.mean(floors))
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Error vs measured cost per pixel on this run's backend (mean image RMSE over all cases).",
    }


# ------------------------------------------------------------------------------------- fitted files
def _write_fitted(out, cfg, fits, smooth) -> list[dict]:
    per_alpha = []
    for s in cfg["sky_radiances"]:
        for a in cfg["alphas_deg"]:
            f = fits[case_id(a, s)]
            per_alpha.append(
                {
                    "alpha_deg": a,
                    "sky_radiance": s,
                    **{k: v["value"] for k, v in f["parameters"].items()},
                    **{f"{k}_stderr": v["stderr"] for k, v in f["parameters"].items()},
                    "rms_residual": f["rms_residual"],
                }
            )
    atomic_write_json(
        out / "fitted" / "wrap_per_alpha.json",
        {
            "model": "wrap",
            "formula": "E = E_perp * max((cos_theta + w) / (1 + w), 0) ** p",
            "units": {
                "alpha_deg": "degrees (light angular radius)",
                "E_perp": "irradiance at normal incidence",
            },
            "fitted_to": "Mitsuba point-sampled radiance of a white sphere, residual normalised by E_perp",
            "cases": per_alpha,
        },
    )
    coeffs = {k: v["value"] for k, v in smooth["parameters"].items()}
    atomic_write_json(
        out / "fitted" / "wrap_smooth.json",
        {
            "model": "wrap with smooth w(alpha), p(alpha)",
            "formula": "E = E_perp * max((cos_theta + w) / (1 + w), 0) ** p",
            "w": "w1 * sin(alpha) + w2 * sin(alpha)**2",
            "p": "1 + p1 * sin(alpha) + p2 * sin(alpha)**2",
            "alpha_units": "radians",
            "valid_alpha_deg": [min(cfg["alphas_deg"]), max(cfg["alphas_deg"])],
            "coefficients": coeffs,
            "stderr": {k: v["stderr"] for k, v in smooth["parameters"].items()},
        },
    )
    first = fits[case_id(cfg["alphas_deg"][-1], 0.0)]
    return [
        {
            "id": f"wrap-{case_id(cfg['alphas_deg'][-1], 0.0)}",
            "label": f"wrap (w, p) at α = {cfg['alphas_deg'][-1]:g}°",
            "model": "max((cos θ + w)/(1 + w), 0)^p",
            "parameters": first["parameters"],
            "rms_residual": first["rms_residual"],
            "n_residuals": first["n_residuals"],
            "converged": first["converged"],
            "file": "fitted/wrap_per_alpha.json",
        },
        {
            "id": "wrap-smooth",
            "label": "smooth w(α), p(α)",
            "model": "w = w1 sin α + w2 sin²α; p = 1 + p1 sin α + p2 sin²α",
            "parameters": smooth["parameters"],
            "rms_residual": smooth["rms_residual"],
            "n_residuals": smooth["n_residuals"],
            "converged": smooth["converged"],
            "file": "fitted/wrap_smooth.json",
        },
    ]


# ------------------------------------------------------------------------------------------- text
def _sections(cfg) -> list[dict]:
    return [
        {
            "id": "method",
            "title": "Method",
            "text": "A white Lambertian unit sphere is lit from the side by a distant uniform spherical light (a sun) "
            f"whose angular radius α ranges over {', '.join(f'{a:g}°' for a in cfg['alphas_deg'])}; "
            "its radiance is 1/sin²α so the irradiance at normal incidence is π and the lit peak radiance is 1. "
            "The light is rendered by rtfit's own Mitsuba emitter for a disc at infinity: Mitsuba's sphere "
            "emitter computes its pdf with float32 cancellation and is biased by +0.39% at 0.27° "
            "(see `rtfit.reference.emitters`). "
            "The reference is Mitsuba 3's `direct` integrator (the integrator rule's choice for one convex "
            "reflector), point-sampled at pixel centres, "
            f"{cfg['spp']} samples per pixel in independent passes of {cfg['pass_spp']}; irradiance probes along "
            f"the equator use {cfg['probe_spp']} MIS samples each. Approximations are evaluated on the pixel-centre "
            "G-buffer, as a shader would: cos θ = n·l per pixel. Wrap lighting's (w, p) are fitted per light size by Levenberg–Marquardt "
            "(optimistix) to the reference image, then w(α) and p(α) are fitted as smooth functions of α.",
        },
    ]


def _summary(cfg, case_docs, smooth, z_std) -> str:
    def rmse(alpha, sky, model):
        for d in case_docs:
            if d["parameters"]["alpha_deg"] == alpha and d["parameters"]["sky_radiance"] == sky:
                for ap in d["approximations"]:
                    if ap["method"] == model:
                        return ap["metrics"]["rmse"]["value"]
        return float("nan")

    small, large = cfg["alphas_deg"][0], cfg["alphas_deg"][-1]
    c = {k: v["value"] for k, v in smooth["parameters"].items()}
    return (
        f"Half-Lambert is far from any physical sphere light: its image RMSE is {rmse(small, 0.0, 'half-lambert'):.3g} "
        f"of the lit peak at α = {small:g}° and {rmse(large, 0.0, 'half-lambert'):.3g} at α = {large:g}°, against "
        f"{rmse(small, 0.0, 'lambert'):.3g} and {rmse(large, 0.0, 'lambert'):.3g} for plain Lambert. Wrap lighting "
        f"with (w, p) fitted per light size brings the error at α = {large:g}° to {rmse(large, 0.0, 'wrap-fit'):.3g}; "
        f"one smooth law w(α) = {c['w1']:.3g}·sin α + {c['w2']:.3g}·sin²α, p(α) = 1 + {c['p1']:.3g}·sin α + "
        f"{c['p2']:.3g}·sin²α gives {rmse(large, 0.0, 'wrap-smooth'):.3g}. The exact closed form sits at the "
        f"reference's noise floor (robust z-score spread {z_std:.3f}), which validates both the formula and the "
        "ground truth."
    )
