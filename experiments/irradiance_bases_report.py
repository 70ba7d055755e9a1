"""Metrics, checks, figures, fitted files, costs and benchmark of the ``irradiance-bases`` experiment.

Metrics per environment × basis over the Fibonacci normals (all channels), each with the noise floor of
the Mitsuba reference (the value the metric reads for an exact basis, seeded Monte Carlo):

* ``smape``     mean |x − r|/(|x| + |r|) (`rtfit.fitting.compute_metrics`);
* ``rel_rmse``  √(mean (x − r)²) / √(mean r²);
* ``max_rel``   max |x − r| / max(r, 0.05·r̄) (r̄: the sphere-mean irradiance of that channel; the floor at
  5% keeps normals facing away from a lone sun from dividing by ~0);
* ``neg_frac``  fraction of normals with a negative channel (SH ringing; deterministic, floor 0);
* ``image_rel_rmse``  rel_rmse of the white sphere's image (radiance E/π at the pixel-centre normals).
"""

from __future__ import annotations

import math
import time

import numpy as np

from rtfit.reference.environments import PROBE_CREDITS
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
from .half_lambert_report import _concat_pairs, _z_checks, _z_pair
from .irradiance_bases import (
    FLOATS,
    LABELS,
    METHODS,
    combine,
    evaluate_method,
    quadrature_backend,
    supersample_for,
)

FLOOR_DRAWS = 4
SUNSKY_BAKE_TOLERANCE = 0.01  # relative bias of baked sky + disc sun against Mitsuba's own sunsky


# ------------------------------------------------------------------------------------------ metrics
def _rel_rmse(x, r):
    return float(np.sqrt(np.mean((x - r) ** 2)) / max(np.sqrt(np.mean(r**2)), 1e-300))


def _max_rel(x, r):
    rbar = np.maximum(np.mean(np.abs(r), axis=0, keepdims=True), 1e-300)
    return float(np.max(np.abs(x - r) / np.maximum(r, 0.05 * rbar)))


def _with_floor(fn, x, r, sigma, seed=0):
    rng = np.random.default_rng(seed)
    val = fn(x, r)
    floor = float(np.mean([fn(r, r + sigma * rng.standard_normal(r.shape)) for _ in range(FLOOR_DRAWS)]))
    return {"value": val, "noise_floor": floor, "resolved": bool(val > 2 * floor)}


def point_metrics(x, r, sigma) -> dict:
    from rtfit.fitting import smape

    sm = smape(x, r, sigma).to_dict()
    return {
        "rel_rmse": _with_floor(_rel_rmse, x, r, sigma),
        "smape": {k: sm[k] for k in ("value", "noise_floor", "resolved") if k in sm},
        "max_rel": _with_floor(_max_rel, x, r, sigma),
        "neg_frac": {
            "value": float(np.mean(np.any(x < 0, axis=1))),
            "noise_floor": 0.0,
            "resolved": bool(np.any(x < 0)),
        },
    }


# ------------------------------------------------------------------------------------------ assemble
def assemble(ctx, cfg, rendered, bases) -> dict:
    out = ctx.out_dir
    names = cfg["environments"]
    cases, z_quad, z_img, furnace, bake = [], [], [], [], []
    per_env = {}
    for name in names:
        r = rendered[name]
        env, b = r["env"], bases[name]
        mean, se, sig = combine(r["parts"], "probes")
        img_mean, img_se, img_sig = combine(r["parts"], "image")
        mask = r["mask"]
        gn = r["gbuffer"].normal[mask].astype(np.float64)
        approx_docs, evals = [], {}
        for m in METHODS:
            x = evaluate_method(m, b, r["normals"], r["quadrature"])
            xi = evaluate_method(m, b, gn, r["quadrature_image"]) / math.pi
            evals[m] = x
            met = point_metrics(x, mean, sig)
            ref_i = img_mean[mask]
            met["image_rel_rmse"] = _with_floor(_rel_rmse, xi, ref_i, img_sig[mask])
            params = _method_params(m, b)
            approx_docs.append(
                {
                    "method": m,
                    "label": LABELS[m],
                    "fitted": m in ("cube-nnls", "sh-l2-lambda"),
                    "parameters": params,
                    "metrics": met,
                    "figures": [],
                }
            )
        per_env[name] = {"evals": evals, "mean": mean, "sig": sig}
        z_quad.append(_z_pair(r["quadrature"][:, 0], mean[:, 0], se[:, 0], sig[:, 0]))
        z_img.append(
            _z_pair(
                r["quadrature_image"][:, 0] / math.pi,
                img_mean[mask][:, 0],
                img_se[mask][:, 0],
                img_sig[mask][:, 0],
            )
        )
        if env.kind == "constant":
            furnace.append(
                _z_pair(np.full(len(mean), math.pi * env.constant[0]), mean[:, 0], se[:, 0], sig[:, 0])
            )
        if r.get("sunsky_own") is not None:
            own = r["sunsky_own"].mean.copy()
            mine = mean.copy()
            for ch in env.params.get("sun_negative_channels", []):
                own[:, ch] = mine[:, ch] = 0.0  # Mitsuba's sun is negative there; rtfit's disc sun clamps it
            ose = r["sunsky_own"].stderr
            keep = np.ones(3, bool)
            keep[env.params.get("sun_negative_channels", [])] = False
            bias = (mine - own).mean(axis=0)[keep] / own.mean(axis=0)[keep]
            bias_se = np.sqrt(np.sum(se**2 + ose**2, axis=0))[keep] / len(own) / own.mean(axis=0)[keep]
            k = int(np.argmax(np.abs(bias)))
            bake.append((name, float(bias[k]), float(bias_se[k])))
        ref_doc = dict(r["parts"][0]["probes"].to_dict())
        ref_doc["parts"] = " + ".join(p["part"] for p in r["parts"])
        ref_doc["image_spp"] = r["parts"][0]["image"].spp
        cases.append(
            {
                "id": name,
                "label": env.label,
                "parameters": {
                    **{k: v for k, v in env.params.items() if not isinstance(v, (list, dict))},
                    **(
                        {
                            "sun_irradiance_g": env.sun.irradiance[1],
                            "sun_angular_radius_deg": env.sun.angular_radius_deg,
                        }
                        if env.sun
                        else {}
                    ),
                    "normals": len(mean),
                    "lambda": b["lambda"],
                    "sh_projection_ms": b["timing_ms"]["sh-projection"],
                    "cube_nnls_fit_ms": b["timing_ms"]["cube-nnls"],
                    "lambda_fit_ms": b["timing_ms"]["lambda-fit"],
                    "bake_s": r["bake_seconds"],
                },
                "scene": {
                    "name": f"irradiance-sphere-{name}",
                    "hash": r["hashes"].get("sky") or r["hashes"].get("sun"),
                },
                "reference": ref_doc,
                "approximations": approx_docs,
            }
        )

    costs = _costs(ctx)
    attach_costs(cases, costs)

    checks = (
        _z_checks(
            "quadrature vs Mitsuba irradiance (all environments, Fibonacci normals)", *_concat_pairs(z_quad)
        )
        + _z_checks("quadrature vs Mitsuba sphere image (all environments)", *_concat_pairs(z_img))
        + (_z_checks("white furnace: π·L vs Mitsuba irradiance", *_concat_pairs(furnace)) if furnace else [])
    )
    for name, bias, bias_se in bake:
        checks.append(
            {
                "name": f"{name}: baked sky + disc sun vs Mitsuba's own sunsky: relative bias of the mean "
                f"irradiance over normals, worst channel (± {bias_se:.2g} statistical)",
                "value": bias,
                "expected": f"|bias| ≤ {SUNSKY_BAKE_TOLERANCE}",
                "passed": abs(bias) <= SUNSKY_BAKE_TOLERANCE,
            }
        )
    neg = max(_metric(cases, n, "sh-l2-lambda", "neg_frac") for n in names)
    checks.append(
        {
            "name": "fitted λ window leaves no negative irradiance (max over environments)",
            "value": neg,
            "expected": "0",
            "passed": neg == 0.0,
        }
    )
    worse = [
        n
        for n in names
        if _metric(cases, n, "cube-nnls", "rel_rmse")
        > _metric(cases, n, "cube-valve", "rel_rmse") + 2 * _floor(cases, n, "cube-valve", "rel_rmse")
    ]
    checks.append(
        {
            "name": "NNLS cube no worse than Valve's cube (rel. RMSE, all environments)",
            "value": ", ".join(worse) or "none worse",
            "expected": "none worse",
            "passed": not worse,
        }
    )

    fits = _write_fitted(out, cfg, rendered, bases)
    figs = _figures(ctx, cfg, rendered, bases, per_env, cases, costs)
    return {
        "summary": _summary(cfg, cases, checks),
        "config": cfg,
        "sections": _sections(cfg),
        "cases": cases,
        "fits": fits,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": [
            "Irradiance in W/m² per linear-sRGB channel; the sphere is white (albedo 1), so its radiance is E/π. "
            "Errors are relative, so environments of different brightness compare directly.",
            "SH convention: real SH without the Condon–Shortley phase (R&H 2001); Dr.Jit's `sh_eval` has the "
            "phase (odd-m signs flipped).",
            "A sun and a lat-long map are rendered as two Mitsuba references (one environment emitter per "
            "scene) and added; the standard errors add in quadrature.",
            'Seed erratum: 000:2497 calls the nine SH colours "the first two orders"; nine coefficients are '
            "bands l = 0, 1, 2 (order 2).",
            "Storage per probe: ambient cube 18 floats, SH L1 12, SH L2 27 (RGB).",
            PROBE_CREDITS,
        ]
        + _missing_probe_notes(ctx),
    }


def _missing_probe_notes(ctx) -> list[str]:
    from rtfit.reference.environments import probe_dir

    from .irradiance_bases import missing_probes

    gone = missing_probes(ctx.quick)
    if not gone:
        return []
    return [
        f"Measured probes not found in {probe_dir()} (set RTFIT_PROBE_DIR): {', '.join(gone)} left out of "
        "this run."
    ]


def _method_params(m, b) -> dict:
    if m == "sh-l2-lambda":
        return {"lambda": b["lambda"]}
    if m in FLOATS and FLOATS[m]:
        return {"floats": FLOATS[m]}
    return {}


def _metric(cases, env, method, key):
    for c in cases:
        if c["id"] == env:
            for ap in c["approximations"]:
                if ap["method"] == method:
                    return ap["metrics"][key]["value"]
    return float("nan")


def _floor(cases, env, method, key):
    for c in cases:
        if c["id"] == env:
            for ap in c["approximations"]:
                if ap["method"] == method:
                    return ap["metrics"][key].get("noise_floor") or 0.0
    return 0.0


# -------------------------------------------------------------------------------------------- costs
def _cost_inputs(n: int, backend: str):
    import drjit as dr

    from rtfit.realtime.irradiance import fibonacci_sphere

    nrm = fibonacci_sphere(n).astype(np.float32)
    mod = dr.cuda if backend == "cuda" else dr.llvm
    return nrm, mod.Array3f(nrm.T)


def _demo_bases():
    from rtfit.realtime import irradiance as ir

    rng = np.random.default_rng(3)
    sh = ir.sh9_from_disk([0.3, 0.4, 0.866], 0.1, np.array([3.0, 2.5, 2.0])) + np.array(
        [[2.0, 2.0, 2.0]] + [[0.0] * 3] * 8
    )
    cube = rng.uniform(0.2, 2.0, (6, 3))
    return {"sh": sh, "cube_valve": cube, "cube_nnls": cube, "lambda": 0.05}


def _costs(ctx) -> list[dict]:
    backend = "cuda" if ctx.variant.startswith("cuda") else "llvm"
    n = 1 << (20 if ctx.quick else 24 if backend == "cuda" else 22)
    _, nd = _cost_inputs(n, backend)
    b = _demo_bases()
    rows = []
    for m in METHODS:
        if m == "quadrature":
            continue
        t = time_drjit(lambda v, m=m: evaluate_method(m, b, v), (nd,), n)
        rows.append(
            {
                "method": m,
                "label": LABELS[m],
                "backend": backend,
                **t.to_dict(),
                "floats_per_probe": FLOATS[m],
                "note": f"per normal (pixel): unit normal in memory, RGB out; {FLOATS[m]} floats per probe",
            }
        )
    base = memory_baseline((nd.x, nd.y, nd.z), n)
    rows.append(
        {
            "method": "memory-baseline",
            "label": "memory traffic baseline (3 loads, 1 store)",
            "backend": backend,
            **base.to_dict(),
            "note": "the memory-bound floor (one output channel)",
        }
    )
    return rows


def bench(ctx) -> list[dict]:
    """Dr.Jit vs NumPy (same kernel text) per basis in normals/s, then projection time per environment."""
    from rtfit.realtime import irradiance as ir

    from .irradiance_bases import build_bases, configure, make_environment

    backend, n = bench_backend(ctx)
    nrm, nd = _cost_inputs(n, backend)
    n64 = nrm.astype(np.float64)
    b = _demo_bases()
    base = memory_baseline((nd.x, nd.y, nd.z), n)
    rows = []
    kernel_of = {
        "cube-valve": ("ambient_cube", "ambient-cube", b["cube_valve"], None),
        "sh-l1": ("sh", "sh-l1", b["sh"], None),
        "sh-l1-geomerics": ("geomerics", "sh-l1-geomerics", b["sh"], None),
        "sh-l2": ("sh", "sh-l2", b["sh"], None),
        "sh-l2-lambda": ("sh", "sh-l2", b["sh"], ir.sh_window("lambda", 2, b["lambda"])),
    }
    for m, (kname, kmethod, coeffs, window) in kernel_of.items():
        t_dr = time_drjit(lambda v, m=m: evaluate_method(m, b, v), (nd,), n)
        np_fn = ir.numpy_reference(kname)
        args = (n64[:, 0], n64[:, 1], n64[:, 2], *ir.kernel_args(kmethod, coeffs, window))
        t_np = time_numpy(lambda *xs: np_fn(*xs), args, n)
        rows.append(comparison_row(LABELS[m], backend, t_dr, t_np, base, unit="normals", per="normal"))
    rows.append(baseline_row(base, backend, "memory baseline", unit="normals", per="normal"))
    from rtfit.reference import use_variant

    mi = use_variant(ctx.variant)
    cfg = configure(ctx.quick, None)
    for name in ("studio", "sunsky-60", "probe-grace"):
        t0 = time.perf_counter()
        env = make_environment(name, cfg, mi)
        bake = time.perf_counter() - t0
        bb = build_bases(env, cfg, 512, quadrature_backend(ctx.variant))
        shape = None if env.radiance_map is None else list(env.radiance_map.shape[:2])
        rows.append(
            {
                "what": f"projection: {name} map {shape}",
                "backend": "numpy",
                "elements": None,
                "bake_or_load_ms": 1e3 * bake,
                **{f"{k}_ms": v for k, v in bb["timing_ms"].items()},
            }
        )
    return rows


# ------------------------------------------------------------------------------------------ fitted files
def _write_fitted(out, cfg, rendered, bases) -> list[dict]:
    fits = []
    for name in cfg["environments"]:
        b = bases[name]
        doc = {
            "environment": name,
            "label": rendered[name]["env"].label,
            "units": "irradiance W/m^2 per linear-sRGB channel (cube); SH radiance coefficients L_lm (W/m^2/sr·sr)",
            "cube_order": ["+x", "-x", "+y", "-y", "+z", "-z"],
            "cube_valve": b["cube_valve"].tolist(),
            "cube_nnls": b["cube_nnls"].tolist(),
            "cube_nnls_rms_residual": b["cube_nnls_rms"].tolist(),
            "sh_convention": "real SH, no Condon-Shortley phase, index l(l+1)+m",
            "sh_l2": b["sh"].tolist(),
            "lambda_window": b["lambda"],
            "lambda_window_formula": "w_l = 1 / (1 + lambda * l^2 (l+1)^2)",
        }
        atomic_write_json(out / "fitted" / f"{name}.json", doc)
        fits.append(
            {
                "id": f"lambda-{name}",
                "label": f"{name}: λ window and NNLS cube",
                "model": "w_l = 1/(1 + λ l²(l+1)²); cube ≥ 0 by NNLS",
                "parameters": {
                    "lambda": {
                        "value": b["lambda"],
                        "stderr": None,
                        "lower": 0.0,
                        "upper": None,
                        "at_bound": False,
                    },
                    **{
                        f"nnls_{ax}_g": {
                            "value": float(b["cube_nnls"][i, 1]),
                            "stderr": None,
                            "lower": 0.0,
                            "upper": None,
                            "at_bound": bool(b["cube_nnls"][i, 1] == 0.0),
                        }
                        for i, ax in enumerate(("px", "nx", "py", "ny", "pz", "nz"))
                    },
                },
                "rms_residual": float(np.mean(b["cube_nnls_rms"])),
                "converged": True,
                "file": f"fitted/{name}.json",
            }
        )
    return fits


# ------------------------------------------------------------------------------------------ figures
def _figures(ctx, cfg, rendered, bases, per_env, cases, costs) -> list[dict]:
    out = ctx.out_dir
    figs = [
        _error_map_figure(ctx, cfg, rendered, bases),
        *_sphere_figures(out, cfg, rendered, bases),
        *_pareto_figures(out, cases, costs),
        _smape_figure(out, cfg, cases),
        _elevation_figure(out, cases),
        _sun_profile_figure(out, cfg, rendered, bases, per_env),
    ]
    return [f for f in figs if f]


def _pick(names, *wanted) -> list[str]:
    """Up to k names per prefix, in the run's order (sunsky: the middle elevations first)."""
    out = []
    for prefix, k in wanted:
        found = [n for n in names if n.startswith(prefix)]
        if prefix == "sunsky-" and len(found) > k:
            mid = len(found) // 2
            found = found[mid - k // 2 :] + found[: mid - k // 2]
        out += found[:k]
    return out


_MAP_METHODS = tuple(m for m in METHODS if m != "quadrature")


def _error_map_figure(ctx, cfg, rendered, bases) -> dict:
    from rtfit.reference.environments import irradiance_quadrature

    plt = figures.pyplot()
    show = _pick(
        cfg["environments"], ("sun-", 1), ("sunsky-", 2), ("studio", 1), ("overcast", 1), ("probe-", 3)
    )
    h, w = 24, 48
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    uu, vv = np.meshgrid(u, v)
    from rtfit.reference.environments import uv_to_direction

    nrm = uv_to_direction(uu, vv).reshape(-1, 3)
    fig, axes = plt.subplots(
        len(show), len(_MAP_METHODS), figsize=(2.2 * len(_MAP_METHODS), 1.3 * len(show) + 0.6), squeeze=False
    )
    for i, name in enumerate(show):
        ref = irradiance_quadrature(
            rendered[name]["env"],
            nrm,
            supersample_for(rendered[name]["env"], cfg),
            quadrature_backend(ctx.variant),
        )
        lum_r = ref @ np.array([0.2126, 0.7152, 0.0722])
        for j, m in enumerate(_MAP_METHODS):
            x = evaluate_method(m, bases[name], nrm) @ np.array([0.2126, 0.7152, 0.0722])
            err = (x - lum_r) / np.maximum(np.abs(lum_r), 0.05 * np.mean(np.abs(lum_r)))
            im = axes[i, j].imshow(
                err.reshape(h, w), cmap="RdBu_r", vmin=-1, vmax=1, extent=(0, 360, -90, 90)
            )
            axes[i, j].set_xticks([])
            axes[i, j].set_yticks([])
            if i == 0:
                axes[i, j].set_title(m, fontsize=8)
            if j == 0:
                axes[i, j].set_ylabel(name, fontsize=7)
    fig.colorbar(im, ax=axes, shrink=0.6, label="relative error (luminance)")
    name = "figures/error_maps.png"
    figures.save_figure(fig, ctx.out_dir / name)
    return {
        "file": name,
        "section": "results",
        "caption": "Relative irradiance error over the sphere of normals (lat-long: normal elevation vertical, "
        "azimuth horizontal, +Z up at the top) for each basis, against the dense quadrature "
        "(validated against Mitsuba, see Checks); red too bright, blue too dark; errors are relative "
        "to max(E, 5% of the mean E).",
    }


def _sphere_figures(out, cfg, rendered, bases) -> list[dict]:
    figs = []
    show = _pick(cfg["environments"], ("sunsky-", 1), ("studio", 1), ("probe-", 2))
    for name in show:
        r = rendered[name]
        img_mean, _, _ = combine(r["parts"], "image")
        mask = r["mask"]
        gn = r["gbuffer"].normal[mask].astype(np.float64)
        panels = []
        for m in ("cube-valve", "sh-l1", "sh-l2", "sh-l2-lambda"):
            img = np.zeros_like(img_mean)
            img[mask] = evaluate_method(m, bases[name], gn) / math.pi
            panels.append((LABELS[m], img))
        peak = float(np.percentile(img_mean[mask], 99))
        fname = f"figures/sphere_{name}.png"
        figures.image_comparison(
            out / fname,
            img_mean,
            panels,
            mask,
            error_scale=max(peak, 1e-12),
            title=f"{name}: Mitsuba reference, bases, signed error",
            exposure=max(peak, 1e-12),
        )
        figs.append(
            {
                "file": fname,
                "section": "results",
                "caption": f"White diffuse sphere under *{rendered[name]['env'].label}*: the Mitsuba reference "
                "(point-sampled, direct light) and each basis evaluated at the pixel-centre normals "
                "(top, exposed so the 99th-percentile radiance is white), signed error as a fraction of that "
                "radiance (bottom).",
            }
        )
    return figs


def _pareto_figures(out, cases, costs) -> list[dict]:
    cost = {c["method"]: c["ns_per_pixel"] for c in costs}
    err: dict[str, list] = {}
    floors = []
    for doc in cases:
        for ap in doc["approximations"]:
            err.setdefault(ap["method"], []).append(ap["metrics"]["rel_rmse"]["value"])
            floors.append(ap["metrics"]["rel_rmse"]["noise_floor"])
    mean_err = {m: float(np.mean(v)) for m, v in err.items()}
    pts_f = [{"x": FLOATS[m], "y": e, "label": m} for m, e in mean_err.items() if FLOATS.get(m)]
    pts_c = [{"x": cost[m], "y": e, "label": m} for m, e in mean_err.items() if m in cost]
    figures.pareto_plot(
        out / "figures/pareto_floats.png",
        pts_f,
        "floats stored per probe (RGB)",
        "mean relative RMSE over environments",
        floor=float(np.mean(floors)),
    )
    figures.pareto_plot(
        out / "figures/pareto_cost.png",
        pts_c,
        "evaluation cost (ns per normal, measured)",
        "mean relative RMSE over environments",
        floor=float(np.mean(floors)),
    )
    return [
        {
            "file": "figures/pareto_floats.png",
            "section": "results",
            "caption": "Error (relative RMSE of the irradiance, mean over all environments) vs storage per probe.",
        },
        {
            "file": "figures/pareto_cost.png",
            "section": "costs",
            "caption": "Error (relative RMSE, mean over all environments) vs measured evaluation cost per normal.",
        },
    ]


def _smape_figure(out, cfg, cases) -> dict:
    series = []
    envs = [c["id"] for c in cases]
    x = list(range(len(envs)))
    panels = ["relative RMSE", "sMAPE"]
    for key, panel in zip(("rel_rmse", "smape"), panels):
        for m in METHODS:
            series.append(
                {
                    "x": x,
                    "y": [max(_metric(cases, e, m, key), 1e-6) for e in envs],
                    "label": m,
                    "panel": panel,
                    "style": "points" if m == "quadrature" else "line",
                }
            )
        series.append(
            {
                "x": x,
                "y": [max(_floor(cases, e, "sh-l2", key), 1e-6) for e in envs],
                "label": "noise floor",
                "ls": ":",
                "color": "0.5",
                "panel": panel,
            }
        )
    name = "figures/error_by_environment.png"
    figures.line_plot(
        out / name,
        "environment: " + ", ".join(f"{i}={e}" for i, e in enumerate(envs)),
        "error",
        series,
        y_log=True,
        panels=panels,
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Relative RMSE and sMAPE of each basis per environment (log scale) with the reference noise "
        "floor. sMAPE saturates where the reference is 0 (the dark side of a lone sun).",
    }


def _sun_profile_figure(out, cfg, rendered, bases, per_env) -> dict | None:
    """Irradiance against the angle between normal and sun, for the smallest lone sun (a clean 1-D function)."""
    suns = [n for n in cfg["environments"] if n.startswith("sun-")]
    if not suns:
        return None
    name = suns[0]
    env = rendered[name]["env"]
    nrm = rendered[name]["normals"]
    ang = np.degrees(np.arccos(np.clip(nrm @ np.asarray(env.sun.direction), -1, 1)))
    order = np.argsort(ang)
    peak = float(env.sun.irradiance[0])
    pe = per_env[name]
    series = [
        {
            "x": ang[order],
            "y": pe["mean"][order, 0] / peak,
            "yerr": 2 * pe["sig"][order, 0] / peak,
            "label": "Mitsuba (±2σ)",
            "style": "points",
            "color": "k",
        }
    ]
    for m in ("cube-valve", "sh-l1", "sh-l1-geomerics", "sh-l2", "sh-l2-hann", "sh-l2-lambda"):
        series.append({"x": ang[order], "y": pe["evals"][m][order, 0] / peak, "label": m})
    fname = "figures/sun_profile.png"
    figures.line_plot(out / fname, "angle between normal and sun (°)", "E / E⊥", series)
    return {
        "file": fname,
        "section": "results",
        "caption": f"Irradiance under a lone sun ({env.label}) against the angle from the sun: Mitsuba at the "
        "Fibonacci normals and each basis at the same normals. SH ringing shows as negative values "
        "opposite the sun; the cube's curve depends on the normal's azimuth too (the spread of its "
        "points).",
    }


def _elevation_figure(out, cases) -> dict | None:
    sky = sorted(
        (c["parameters"]["sun_elevation_deg"], c["id"]) for c in cases if c["id"].startswith("sunsky-")
    )
    if len(sky) < 2:
        return None
    series = []
    for key, panel in (("smape", "sMAPE"), ("rel_rmse", "relative RMSE")):
        for m in METHODS:
            if m == "quadrature":
                continue
            series.append(
                {
                    "x": [e for e, _ in sky],
                    "y": [_metric(cases, cid, m, key) for _, cid in sky],
                    "label": m,
                    "panel": panel,
                }
            )
        series.append(
            {
                "x": [e for e, _ in sky],
                "y": [_floor(cases, cid, "sh-l2", key) for _, cid in sky],
                "label": "noise floor",
                "panel": panel,
                "ls": ":",
                "color": "0.5",
            }
        )
    name = "figures/error_vs_sun_elevation.png"
    figures.line_plot(
        out / name, "sun elevation (°)", "error", series, panels=["sMAPE", "relative RMSE"], y_log=True
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Error of each basis under Mitsuba's sunsky (baked sky + disc sun) as the sun rises.",
    }


# ------------------------------------------------------------------------------------------ text
def _sections(cfg) -> list[dict]:
    return [
        {
            "id": "method",
            "title": "Method",
            "text": "Each environment is a distant lat-long radiance map in Mitsuba's envmap convention (rotated +Y → +Z), "
            "optionally with a finite disc sun. Ground truth: Mitsuba irradiance at "
            f"{cfg['normals']} Fibonacci normals on a white unit sphere ({cfg['probe_spp']} MIS samples each) and "
            f"the point-sampled image of the sphere ({cfg['resolution']}², {cfg['spp']} spp, `direct`). A sun is "
            "rendered as a second reference and added (one environment emitter per Mitsuba scene). The bases are "
            "built from the environment as an engine's baker would: SH by quadrature of the map's bilinear "
            "function (a disc sun in closed form), Valve's cube from the irradiance at the six axes, the NNLS "
            "cube by non-negative least squares against the irradiance at a dense Fibonacci set, λ by bisection "
            "(smallest λ without negative irradiance on 4096 + 26 normals). `sunsky` is baked from Mitsuba's "
            "emitter (sky: sun_scale 0; sun: its disc irradiance integrated from the emitter's radiance).",
        }
    ]


def _summary(cfg, cases, checks) -> str:
    def mean_of(m, key="rel_rmse"):
        return float(np.mean([_metric(cases, c["id"], m, key) for c in cases]))

    probes = [c["id"] for c in cases if c["id"].startswith("probe")]
    prb = (
        f" On the measured probes ({', '.join(p[6:] for p in probes)}) SH L2 reaches "
        f"{np.mean([_metric(cases, p, 'sh-l2', 'rel_rmse') for p in probes]):.3g} against "
        f"{np.mean([_metric(cases, p, 'cube-valve', 'rel_rmse') for p in probes]):.3g} for Valve's cube and "
        f"{np.mean([_metric(cases, p, 'sh-l1-geomerics', 'rel_rmse') for p in probes]):.3g} for Geomerics L1."
        if probes
        else ""
    )
    passed = sum(c["passed"] for c in checks)
    return (
        f"Over {len(cases)} environments, the mean relative RMSE of the irradiance against Mitsuba is: Valve ambient "
        f"cube {mean_of('cube-valve'):.3g}, NNLS-optimal cube {mean_of('cube-nnls'):.3g}, SH L1 {mean_of('sh-l1'):.3g}, "
        f"Geomerics L1 {mean_of('sh-l1-geomerics'):.3g}, SH L2 {mean_of('sh-l2'):.3g}, L2 with the fitted λ window "
        f"{mean_of('sh-l2-lambda'):.3g}; the dense quadrature sits at the noise floor ({mean_of('quadrature'):.3g}, "
        f"floor {float(np.mean([_floor(cases, c['id'], 'quadrature', 'rel_rmse') for c in cases])):.3g}).{prb} "
        f"Plain L2 goes negative on a fraction {mean_of('sh-l2', 'neg_frac'):.3g} of the normals on average (opposite "
        f"suns and bright softboxes) and L1 on {mean_of('sh-l1', 'neg_frac'):.3g}; the fitted λ window removes it at a "
        f"large cost in accuracy, Geomerics' L1 never rings. sMAPE (mean over environments): cube "
        f"{mean_of('cube-valve', 'smape'):.3g}, L1 {mean_of('sh-l1', 'smape'):.3g}, L2 {mean_of('sh-l2', 'smape'):.3g}. "
        f"{passed} of {len(checks)} checks passed."
    )
