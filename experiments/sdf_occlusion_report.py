"""Fits, metrics, sweep, figures, fitted files and benchmark of the ``sdf-occlusion`` experiment.

All images are dimensionless occlusion/sky-light values: 1 = unoccluded (AO), E/(πL) = 1 for an
unoccluded upward-facing point under the constant upper-hemisphere sky, E/E_h = 1 under the sunsky sky.

Sunsky targets: every approximation's C is multiplied by the per-point sky factor g(N)
(`rtfit.experiments.sdf_occlusion.sky_factor`; 1 for the other targets). The JAX fits of C keep their
residual functions: (C − y/g)·g = g·C − y, i.e. target y/g with weight g.
"""

from __future__ import annotations

import math
import time

import numpy as np

from rtfit.reference.io import atomic_write_json

from . import figures
from .cost import attach_costs
from .sdf_occlusion import (
    ALPHAS,
    BASES_VOX,
    CONE_KS,
    FIT_POINTS,
    HELD_OUT,
    LABELS,
    METHODS,
    SUNSKY_TARGETS,
    TARGET_LABEL,
    EvansFitData,
    evans_readable,
    fit_evans_continuous,
    grid_of,
    load_case_scene,
)

_ANALYTIC_SCENES = ("sphere_plane", "room", "boxes")  # built from analytic primitives (exact SDF available)
METRICS = ("rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim")
SHORT = {
    "evans-text": "Evans text",
    "evans-listing": "Evans listing",
    "evans-fit": "Evans fit",
    "evans-joint": "Evans joint",
    "curvature": "curvature",
    "cone": "cone DF AO",
    "sdfgrid": "sdfgrid AO",
    "evans-analytic": "Evans fit, exact SDF",
    "evans-on-sdfgrid": "Evans fit on sdfgrid",
}


# =============================================================================== residuals (JAX)
def _res_text(p, args):
    import jax.numpy as jnp

    dsum, target, w = args
    return (jnp.exp(jnp.clip(-p["k"] * dsum, -87.0, 80.0)) - target) * w


def _res_listing(p, args):
    import jax.numpy as jnp

    dsum, target, w = args
    return (jnp.exp(jnp.clip(p["logB"] - p["k"] * dsum, -87.0, 80.0)) - target) * w


def _res_curv(p, args):
    import jax.numpy as jnp

    s_text, target, w = args
    return ((0.5 + jnp.exp(jnp.clip(p["k"] * s_text, -87.0, 80.0))) / 1.5 - target) * w


def _subsample(n_pts: int, seed: int, size: int = FIT_POINTS):
    """Indices of at most ``size`` points and a 0/1 weight vector of length ``size`` (padding)."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(n_pts, size=min(n_pts, size), replace=False))
    w = np.zeros(size)
    w[: len(idx)] = 1.0
    return idx, w


def _pad(a, size):
    a = np.asarray(a, dtype=np.float64)
    out = np.zeros(a.shape[:-1] + (size,))
    out[..., : a.shape[-1]] = a
    return out


# ====================================================================================== the model
class SceneData:
    """Per-scene arrays and memoised Evans terms."""

    def __init__(self, name, r, cfg):
        from rtfit.realtime.sdf_grid import SdfGrid
        from rtfit.realtime.sdf_occlusion import GridSDF

        self.name = name
        self.r = r
        self.mask = r["mask"]
        self.points = r["points"]
        self.normals = r["normals"]
        g = SdfGrid(r["grid"]["values"], tuple(r["grid"]["origin"]), float(r["grid"]["voxel"]))
        self.grid = g
        self.sdf = GridSDF.from_grid(g, levels=8, prefilter=True)
        self.voxel = g.voxel
        self.n = cfg["n_samples"]
        self._terms = {}
        self.cone_cache = {}
        self.fit_idx, self.fit_w = _subsample(len(self.points), sum(map(ord, name)))
        from rtfit.realtime.sdf_occlusion import AnalyticSDF

        from .sdf_occlusion_scenes import build

        prims = build(name)[1] if name in _ANALYTIC_SCENES else None
        self.analytic = AnalyticSDF(prims) if prims else None

    def terms(self, alpha, base_vox, n=None, analytic=False):
        from rtfit.realtime.sdf_occlusion import EvansParams, evans_terms

        n = n or self.n
        key = (alpha, base_vox, n, analytic)
        if key not in self._terms:
            prm = EvansParams(n=n, base=base_vox * self.voxel, k=1.0, alpha=alpha)
            sdf = self.analytic if analytic else self.sdf
            self._terms[key] = evans_terms(self.points, self.normals, sdf, prm)
        return self._terms[key]

    def target(self, t):
        return self.r["refs"][t]["mean"], self.r["refs"][t]["stderr"]

    def factor(self, t):
        """The sky factor g(N) per point for sunsky targets (`sky_factor`), else None (g = 1)."""
        if t in SUNSKY_TARGETS:
            g = self.r.get("sky_factor")
            if g is None:
                raise ValueError(f"{self.name}: target {t} needs the per-point sky factor (render with it)")
            return np.asarray(g, dtype=np.float64)
        return None

    def scaled(self, t, pred):
        """g·pred (the approximation under target t)."""
        g = self.factor(t)
        return pred if g is None else pred * g

    def fit_target(self, t):
        """(target/g, weight g) on the fit subsample, padded to FIT_POINTS: JAX residual (C − y/g)·g = gC − y."""
        ref, _ = self.target(t)
        g = self.factor(t)
        y = ref[self.fit_idx]
        w = self.fit_w.copy()
        if g is not None:
            gs = np.maximum(g[self.fit_idx], 1e-6)
            y = y / gs
            w[: len(gs)] *= gs
        return _pad(y, FIT_POINTS), w

    def fit_data(self, t, analytic=False) -> EvansFitData:
        """The fit subsample as `EvansFitData` for the continuous fit."""
        ref, _ = self.target(t)
        g = self.factor(t)
        i = self.fit_idx
        return EvansFitData(
            self.points[i],
            self.normals[i],
            self.analytic if analytic else self.sdf,
            self.voxel,
            ref[i],
            None if g is None else g[i],
        )

    def image(self, values):
        img = np.zeros(self.mask.shape)
        img[self.mask] = values
        return img


def _fit(res, params, args):
    from rtfit.fitting import fit_least_squares

    return fit_least_squares(res, params, args=args).to_dict()


def _values(fit):
    return {k: v["value"] for k, v in fit["parameters"].items()}


def fit_text(sd: SceneData, t, alpha=0.5, weights=None):
    from rtfit.fitting import Param

    d = sd.terms(alpha, 1.0)
    w = np.asarray(weights or (1.0,) * d.shape[0])
    dsum = w @ d
    y, fw = sd.fit_target(t)
    args = (_pad(dsum[sd.fit_idx], FIT_POINTS), y, fw)
    if weights is None:
        f = _fit(_res_text, {"k": Param(1.0 / (10 * sd.voxel), 0.0, 1e4)}, args)
        pred = np.exp(np.clip(-_values(f)["k"] * dsum, -87, 80))
    else:
        f = _fit(
            _res_listing, {"k": Param(1.0 / (10 * sd.voxel), 0.0, 1e4), "logB": Param(0.0, -5.0, 5.0)}, args
        )
        v = _values(f)
        pred = np.exp(np.clip(v["logB"] - v["k"] * dsum, -87, 80))
    return f, sd.scaled(t, pred)


def fit_free(sds: list[SceneData], t, alphas=ALPHAS, bases=BASES_VOX, analytic=False):
    """Stage 1 (initialisation): at every (α, base) of the grid, fit (log B, c_i) with α and base held (the
    model is then smooth: D_i fixed, C = exp(log B − Σ c_i D_i)) by the same bounded LM (`bounded_lm`,
    analytic Jacobian, no kernel calls); returns the best {values, ssr, alpha, base_vox}."""
    from .sdf_occlusion import FIT_BOUNDS, bounded_lm

    n = sds[0].n
    lo = np.array([FIT_BOUNDS["logB"][0]] + [FIT_BOUNDS["c"][0]] * n)
    hi = np.array([FIT_BOUNDS["logB"][1]] + [FIT_BOUNDS["c"][1]] * n)
    ys, gs = [], []
    for sd in sds:
        ref, _ = sd.target(t)
        g = sd.factor(t)
        ys.append(ref[sd.fit_idx])
        gs.append(np.ones(len(sd.fit_idx)) if g is None else g[sd.fit_idx])
    y, g = np.concatenate(ys), np.concatenate(gs)
    best = None
    for alpha in alphas:
        for base in bases:
            d = np.concatenate(
                [sd.terms(alpha, base, analytic=analytic)[:, sd.fit_idx] for sd in sds], axis=1
            )

            def fun(x, d=d):
                e = x[0] - x[1:] @ d
                pred = g * np.exp(np.clip(e, -87.0, 80.0))
                pl = np.where((e > -87.0) & (e < 80.0), pred, 0.0)
                return pred - y, np.column_stack([pl, -pl[:, None] * d.T])

            x0 = np.array([0.0] + [1.0 / (10 * sds[0].voxel)] * n)
            out = bounded_lm(fun, x0, lo, hi, max_iter=200)
            if best is None or out["ssr"] < best["ssr"]:
                best = {
                    "values": {
                        "logB": float(out["x"][0]),
                        **{f"c{i + 1}": float(out["x"][1 + i]) for i in range(n)},
                    },
                    "ssr": out["ssr"],
                    "alpha": alpha,
                    "base_vox": base,
                    "m": len(y),
                }
    return best


def fit_evans(sds: list[SceneData], t, cfg, analytic=False):
    """The Evans fit: grid profile (`fit_free`), then the continuous LM over (log B, c_i, α, base) from its best
    point (`rtfit.experiments.sdf_occlusion.fit_evans_continuous`). Returns the continuous result with the
    grid's best as ``grid`` ({alpha, base_vox, rms_residual})."""
    g = fit_free(sds, t, cfg["alphas"], cfg["bases_vox"], analytic=analytic)
    init = {**g["values"], "alpha": g["alpha"], "base_voxels": g["base_vox"]}
    data = [sd.fit_data(t, analytic=analytic) for sd in sds]
    b = fit_evans_continuous(data, init, sds[0].n, max_iter=int(cfg.get("lm_max_iter", 100)))
    b["grid"] = {"alpha": g["alpha"], "base_vox": g["base_vox"], "rms_residual": math.sqrt(g["ssr"] / g["m"])}
    return b


def predict_free(sd: SceneData, best, analytic=False, t=None):
    """g·C at every point of ``sd`` with the fitted (log B, c_i) at the fit's α and base (g for target t)."""
    v = _values(best["fit"])
    d = sd.terms(best["alpha"], best["base_vox"], analytic=analytic)
    c = np.array([v[f"c{i + 1}"] for i in range(d.shape[0])])
    pred = np.exp(np.clip(v["logB"] - c @ d, -87, 80))
    return pred if t is None else sd.scaled(t, pred)


def free_params_readable(best, voxel):
    """k, w_i, B, α, base (voxels, and scene units with ``voxel``) with standard errors (`evans_readable`)."""
    return evans_readable(best, voxel)


def fit_curvature(sd: SceneData, t, level=1):
    from rtfit.fitting import Param
    from rtfit.realtime.sdf_occlusion import GridSDF, _NP

    s_text = -np.asarray(sd.sdf.sample(_NP, level, *sd.points.T))
    y, fw = sd.fit_target(t)
    args = (_pad(s_text[sd.fit_idx], FIT_POINTS), y, fw)
    f = _fit(_res_curv, {"k": Param(-1.0 / sd.voxel, -1e4, 1e4)}, args)
    k = _values(f)["k"]
    _ = GridSDF
    return f, sd.scaled(t, (0.5 + np.exp(np.clip(k * s_text, -87, 80))) / 1.5)


def cone_best(sd: SceneData, t, cfg):
    from rtfit.realtime.sdf_occlusion import cone_occlusion

    ref, _ = sd.target(t)
    best = None
    for k in CONE_KS:
        if k not in sd.cone_cache:
            sd.cone_cache[k] = np.asarray(
                cone_occlusion(
                    sd.points,
                    sd.normals,
                    sd.sdf,
                    cones=cfg["cone_count"],
                    steps=cfg["cone_steps"],
                    t0=sd.voxel,
                    t_max=cfg["ao_distance"],
                    k=k,
                ),
                dtype=np.float64,
            )
        pred = sd.scaled(t, sd.cone_cache[k])
        e = float(np.sqrt(np.mean((pred - ref) ** 2)))
        if best is None or e < best[0]:
            best = (e, k, pred)
    return best[1], best[2]


# ====================================================================================== assemble
def assemble(ctx, cfg, rendered) -> dict:
    from rtfit.fitting import compute_metrics

    out = ctx.out_dir
    t_start = time.perf_counter()
    sds = {n: SceneData(n, rendered[n], cfg) for n in cfg["scenes"]}
    train = [sds[n] for n in cfg["scenes"] if n != HELD_OUT]
    joint = {t: fit_evans(train, t, cfg) for t in cfg["targets"]}
    ctx.log(f"joint fits done ({time.perf_counter() - t_start:.1f} s)")
    case_docs, fits_out, per_case_params, fit_rows = [], [], {}, []
    maps = {}
    for n in cfg["scenes"]:
        sd = sds[n]
        for t in cfg["targets"]:
            ref, err = sd.target(t)
            preds, params, fitted = {}, {}, {}
            f, preds["evans-text"] = fit_text(sd, t)
            params["evans-text"] = {"k": _values(f)["k"], "alpha": 0.5, "base": sd.voxel}
            f, preds["evans-listing"] = fit_text(sd, t, alpha=1.0, weights=(1.0, 1.2, 1.4, 1.8))
            params["evans-listing"] = {**_values(f), "alpha": 1.0, "base": sd.voxel}
            b = fit_evans([sd], t, cfg)
            preds["evans-fit"] = predict_free(sd, b, t=t)
            params["evans-fit"] = free_params_readable(b, sd.voxel)
            fitted["evans-fit"] = b
            if sd.analytic is not None:
                ba = fit_evans([sd], t, cfg, analytic=True)
                preds["evans-analytic"] = predict_free(sd, ba, analytic=True, t=t)
                params["evans-analytic"] = free_params_readable(ba, sd.voxel)
                fitted["evans-analytic"] = ba
            preds["evans-joint"] = predict_free(sd, joint[t], t=t)
            params["evans-joint"] = free_params_readable(joint[t], sd.voxel)
            f, preds["curvature"] = fit_curvature(sd, t)
            params["curvature"] = {"k_text": _values(f)["k"], "level": 1}
            kc, preds["cone"] = cone_best(sd, t, cfg)
            params["cone"] = {
                "k": kc,
                "cones": cfg["cone_count"],
                "steps": cfg["cone_steps"],
                "t0": sd.voxel,
                "t_max": cfg["ao_distance"],
            }
            ref_img, err_img = sd.image(ref), sd.image(err)
            approx_docs = []
            for m in METHODS + ("evans-analytic",):
                if m not in preds:
                    continue
                img = sd.image(preds[m])
                met = compute_metrics(
                    img[..., None].repeat(3, -1),
                    ref_img[..., None].repeat(3, -1),
                    err_img[..., None].repeat(3, -1),
                    sd.mask,
                    names=METRICS,
                )
                approx_docs.append(
                    {
                        "method": m,
                        "label": LABELS[m],
                        "fitted": True,
                        "parameters": _approx_params(params[m]),
                        "metrics": met.to_dict(),
                        "cost": None,
                        "figures": [],
                    }
                )
                maps[(n, t, m)] = img
            if t == "ao" and sd.r["sdfgrid_ao"] is not None:
                approx_docs.append(_sdfgrid_doc(sd))
                approx_docs.append(_model_only_doc(sd, cfg))
            cid = f"{n}-{t}".replace("_", "")
            per_case_params[cid] = {m: _json_params(v) for m, v in params.items()}
            per_case_params[cid]["evans-fit-lm"] = _lm_summary(b)
            if "evans-analytic" in fitted:
                per_case_params[cid]["evans-analytic-lm"] = _lm_summary(fitted["evans-analytic"])
            fit_rows.append({"case": cid, "scene": n, "target": t, "voxel": sd.voxel, **_lm_summary(b)})
            sky_meta = (
                {
                    "sun_elevation_deg": cfg["sun_elevation"],
                    "sun_azimuth_deg": cfg["sun_azimuth"],
                    "turbidity": cfg["turbidity"],
                }
                if t in SUNSKY_TARGETS
                else {}
            )
            case_docs.append(
                {
                    "id": cid,
                    "label": f"{n.replace('_', ' ')}: {TARGET_LABEL[t]}",
                    "parameters": {
                        "scene": n,
                        "target": t,
                        "grid_cells": cfg["grid"],
                        "voxel": sd.voxel,
                        "ao_distance": cfg["ao_distance"] if t == "ao" else None,
                        "albedo": cfg["albedo"] if t in ("sky-gi", "sunsky-gi") else None,
                        **sky_meta,
                        "held_out": n == HELD_OUT,
                    },
                    "scene": {"name": f"sdf-{n}", "hash": sd.r["scene_hash"]},
                    "reference": sd.r["refs"][t]["meta"],
                    "approximations": approx_docs,
                }
            )
            maps[(n, t, "ref")] = ref_img
    ctx.log(f"per-case fits done ({time.perf_counter() - t_start:.1f} s)")
    costs = measure_costs(sds, cfg)
    attach_costs(case_docs, costs)
    sweep = run_sweep(ctx, cfg, sds)
    ctx.log(f"sweep done ({time.perf_counter() - t_start:.1f} s)")
    figs = make_figures(out, cfg, sds, maps, case_docs, sweep, costs)
    fits_out = write_fitted(out, cfg, joint, per_case_params, sds)
    checks = make_checks(cfg, sds, case_docs, fit_rows)
    return {
        "summary": summary(cfg, case_docs, joint, sweep, sds),
        "config": {k: v for k, v in cfg.items()},
        "sections": _with_fit_table(_with_sweep_table(sections(cfg), sweep), fit_rows, joint, sds, cfg),
        "cases": case_docs,
        "fits": fits_out,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": notes(cfg),
        "sweep": sweep,
    }


def _finite(v):
    return v is not None and isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(float(v))


def _approx_params(p: dict) -> dict:
    """An approximation's parameter values for results.json (name → number): stderrs and undefined values are
    left out (they are in the fitted files and the fit table)."""
    return {k: float(v) for k, v in p.items() if not k.endswith("_stderr") and _finite(v)}


def _json_params(p: dict) -> dict:
    """Values and stderrs, undefined ones as None (JSON has no NaN)."""
    return {k: (float(v) if _finite(v) else None) for k, v in p.items()}


def _lm_summary(b: dict) -> dict:
    """The continuous fit in a few numbers: readable parameters with stderrs, RMS residual before (grid) and
    after, LM iterations, convergence."""
    return {
        **_json_params(evans_readable(b, None)),
        "rms_residual": b["fit"]["rms_residual"],
        "rms_residual_grid": b["grid"]["rms_residual"],
        "grid_alpha": b["grid"]["alpha"],
        "grid_base_voxels": b["grid"]["base_vox"],
        "lm_iterations": b["lm"]["iterations"],
        "converged": b["fit"]["converged"],
        "message": b["fit"]["message"],
        "at_bound": [k for k, v in b["fit"]["parameters"].items() if v["at_bound"]],
    }


def _pm(v, e, fmt="{:.3g}"):
    """'value ± stderr' ('–' for an undefined value or stderr)."""
    if not _finite(v):
        return "–"
    return fmt.format(v) + (f" ± {e:.2g}" if _finite(e) else " ± –")


def _with_fit_table(secs, rows, joint, sds, cfg) -> list[dict]:
    """Append the per-case continuous-fit table (α, base, k, B with stderrs; RMS grid → continuous) to the
    ``fit`` section."""
    lines = [
        "case                      α               base (voxels)    k (1/unit)        B               "
        "RMS grid → LM       iters"
    ]
    for r in rows + [{"case": f"joint-{t}", **_lm_summary(b)} for t, b in joint.items()]:
        lines.append(
            f"{r['case']:<25} {_pm(r['alpha'], r['alpha_stderr']):<15} "
            f"{_pm(r['base_voxels'], r['base_voxels_stderr']):<16} {_pm(r['k'], r['k_stderr']):<17} "
            f"{_pm(r['B'], r['B_stderr']):<15} {r['rms_residual_grid']:.4f} → {r['rms_residual']:.4f}   "
            f"{r['lm_iterations']}{'' if r['converged'] else ' (not converged)'}"
            + (f"  at bound: {', '.join(r['at_bound'])}" if r["at_bound"] else "")
        )
    for sec in secs:
        if sec["id"] == "fit":
            sec["text"] += "\n\n```\n" + "\n".join(lines) + "\n```"
    return secs


def _sdfgrid_doc(sd: SceneData) -> dict:
    from rtfit.fitting import compute_metrics

    ref, err = sd.target("ao")
    ref_img, err_img = sd.image(ref), sd.image(err)
    g = sd.r["sdfgrid_ao"]
    ge = sd.r["sdfgrid_ao_stderr"]
    both = sd.mask & np.isfinite(g)
    img = np.where(both, g, 0.0)
    # both images are noisy: the floor uses the combined standard error
    comb = np.sqrt(np.where(both, err_img**2 + np.nan_to_num(ge) ** 2, err_img**2))
    met = compute_metrics(
        img[..., None].repeat(3, -1),
        np.where(both, ref_img, 0)[..., None].repeat(3, -1),
        comb[..., None].repeat(3, -1),
        both,
        names=METRICS,
    )
    return {
        "method": "sdfgrid",
        "label": LABELS["sdfgrid"],
        "fitted": False,
        "parameters": {"grid_voxel": sd.voxel},
        "metrics": met.to_dict(),
        "cost": None,
        "figures": [],
    }


def _model_only_doc(sd: SceneData, cfg) -> dict:
    """Evans fitted on the sdfgrid's own G-buffer against the AO of the sdfgrid geometry: both sides see the
    same voxelised surface, so what remains is the occlusion model's error alone."""
    from rtfit.fitting import compute_metrics

    r = dict(sd.r)
    r.update(sd.r["sdfgrid_gbuffer"])
    sd2 = SceneData(sd.name, r, cfg)
    b = fit_evans([sd2], "ao", cfg)
    ref, err = sd2.target("ao")
    img, ref_img, err_img = sd2.image(predict_free(sd2, b)), sd2.image(ref), sd2.image(err)
    met = compute_metrics(
        img[..., None].repeat(3, -1),
        ref_img[..., None].repeat(3, -1),
        err_img[..., None].repeat(3, -1),
        sd2.mask,
        names=METRICS,
    )
    return {
        "method": "evans-on-sdfgrid",
        "label": LABELS["evans-on-sdfgrid"],
        "fitted": True,
        "parameters": _approx_params(free_params_readable(b, sd.voxel)),
        "metrics": met.to_dict(),
        "cost": None,
        "figures": [],
    }


# ===================================================================================== cost
def measure_costs(sds, cfg) -> list[dict]:
    """ns per pixel of each method's Dr.Jit kernel on 2^18 surface points of one scene (the boxes scene if
    present), after warm-up (`rtfit.experiments.cost.time_drjit`)."""
    import drjit as dr

    from rtfit.realtime import get_default_backend
    from rtfit.realtime.sdf_occlusion import (
        LISTING_WEIGHTS,
        EvansParams,
        _cone_kernel,
        _curvature_kernel,
        _DR,
        _evans_kernel,
    )

    from .cost import time_drjit

    sd = sds.get("boxes") or next(iter(sds.values()))
    size = int(cfg["cost_points"])
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(sd.points), size)
    be = get_default_backend()
    Float = (dr.cuda if be == "cuda" else dr.llvm).Float
    cols = tuple(
        Float(np.ascontiguousarray(a[idx, i], dtype=np.float32))
        for a in (sd.points, sd.normals)
        for i in range(3)
    )
    h = sd.voxel
    kernels = {
        "evans-text": lambda *a: _evans_kernel(_DR, sd.sdf, EvansParams(n=4, base=h, k=1.0, alpha=0.5), *a),
        "evans-listing": lambda *a: _evans_kernel(
            _DR, sd.sdf, EvansParams(n=4, base=h, k=1.0, alpha=1.0, weights=LISTING_WEIGHTS), *a
        ),
        "evans-fit": lambda *a: _evans_kernel(
            _DR, sd.sdf, EvansParams(n=4, base=h, k=1.0, alpha=0.3, weights=(1.0, 0.9, 0.8, 0.7)), *a
        ),
        "curvature": lambda *a: _curvature_kernel(_DR, sd.sdf, 1, -1.0, *a[:3]),
        "cone": lambda *a: _cone_kernel(
            _DR, sd.sdf, cfg["cone_count"], cfg["cone_steps"], h, cfg["ao_distance"], 2.0, *a
        ),
    }
    out = []
    for m, fn in kernels.items():
        tm = time_drjit(fn, cols, size, repeats=5, min_seconds=0.1)
        out.append(
            {
                "method": m,
                "label": LABELS[m],
                "backend": be,
                **tm.to_dict(),
                "note": f"Dr.Jit kernel incl. trilinear gathers from the mip chain, {size} surface points "
                f"({cfg['grid']}³ grid), median wall time after warm-up",
            }
        )
    tm = next(c for c in out if c["method"] == "evans-fit")
    out.append(
        {
            "method": "evans-joint",
            "label": LABELS["evans-joint"],
            "backend": be,
            **{k: tm[k] for k in ("ns_per_pixel", "pixels_per_second", "elements", "repeats")},
            "note": "same kernel as evans-fit",
        }
    )
    return out


# ===================================================================================== sweep
def run_sweep(ctx, cfg, sds) -> list[dict]:
    """Steps (n) × grid resolution × prefilter × 8-bit: Evans as pure occlusion (α = 0, w_i = 1, base = one
    voxel of the grid) with k and B refitted per configuration, error against the AO reference (mean RMSE
    over the sweep scenes) and measured ns per pixel."""
    import drjit as dr

    from rtfit.realtime import get_default_backend
    from rtfit.realtime.sdf_grid import quantize_8bit
    from rtfit.realtime.sdf_occlusion import _DR, EvansParams, GridSDF, _evans_kernel, evans_terms

    from .cost import time_drjit

    be = get_default_backend()
    Float = (dr.cuda if be == "cuda" else dr.llvm).Float
    target = "ao"
    rows = []
    configs = []
    for res in cfg["sweep_grids"]:
        for n in cfg["sweep_n"]:
            configs.append((res, n, True, False))
        configs.append((res, 4, False, False))
        configs.append((res, 4, True, True))
    grids = {}
    for name in cfg["sweep_scenes"]:
        sc = load_case_scene(name, cfg["resolution"])
        for res in cfg["sweep_grids"]:
            grids[(name, res)] = grid_of(sc, res, ctx.cache_dir)
    size = int(cfg["cost_points"])
    for res, n, pre, q8 in configs:
        errs, floors = [], []
        timing = None
        for name in cfg["sweep_scenes"]:
            sd = sds[name]
            g = grids[(name, res)]
            if q8:
                g = quantize_8bit(g)
            sdf = GridSDF.from_grid(g, levels=8, prefilter=pre)
            prm = EvansParams(n=n, base=g.voxel, k=1.0, alpha=0.0, prefilter=True)
            d = evans_terms(sd.points, sd.normals, sdf, prm)
            ref, err = sd.target(target)
            k, logb = _fit_k(d.sum(axis=0), ref)
            pred = np.exp(np.clip(logb - k * d.sum(axis=0), -87, 80))
            errs.append(float(np.sqrt(np.mean((pred - ref) ** 2))))
            floors.append(float(np.sqrt(np.mean(err**2))))
            if timing is None:
                idx = np.random.default_rng(1).integers(0, len(sd.points), size)
                cols = tuple(
                    Float(np.ascontiguousarray(a[idx, i], dtype=np.float32))
                    for a in (sd.points, sd.normals)
                    for i in range(3)
                )
                timing = time_drjit(
                    lambda *a, s=sdf, p=prm: _evans_kernel(_DR, s, p, *a),
                    cols,
                    size,
                    repeats=5,
                    min_seconds=0.1,
                )
        rows.append(
            {
                "grid": res,
                "n": n,
                "prefilter": pre,
                "bits": 8 if q8 else 32,
                "target": target,
                "rmse": float(np.mean(errs)),
                "noise_floor": float(np.mean(floors)),
                "ns_per_pixel": timing.ns_per_element,
                "seed_default": bool(res == 128 and n == 4 and pre and q8),
            }
        )
    return rows


def _fit_k(dsum, ref):
    """Least squares for (k ≥ 0, log B) in B·exp(−k·D): bounded 1-D search over log k with log B solved by
    Gauss–Newton steps inside (SciPy; cheap enough to refit at every sweep point)."""
    from scipy.optimize import minimize_scalar

    scale = max(float(np.percentile(np.abs(dsum), 90)), 1e-9)

    def inner(k):
        e = np.exp(np.clip(-k * dsum, -87, 80))
        b = float(np.dot(e, ref) / max(np.dot(e, e), 1e-300))  # optimal B for this k (linear)
        return b, e

    def f(logk):
        b, e = inner(math.exp(logk))
        return float(np.mean((b * e - ref) ** 2))

    r = minimize_scalar(
        f, bounds=(math.log(1e-3 / scale), math.log(1e3 / scale)), method="bounded", options={"xatol": 1e-4}
    )
    k = math.exp(r.x)
    b, _ = inner(k)
    return k, math.log(max(b, 1e-30))


# ===================================================================================== figures
def make_figures(out, cfg, sds, maps, case_docs, sweep, costs) -> list[dict]:
    figs = []
    for t, n in [
        (t, n)
        for t in cfg["targets"]
        if t in ("ao", "sky", "sunsky")
        for n in cfg.get("map_scenes", cfg["scenes"])
        if n in sds
    ]:
        sd = sds[n]
        name = f"figures/maps_{n}_{t}.png"
        panels = [
            (SHORT[m], maps[(n, t, m)])
            for m in ("evans-text", "evans-listing", "evans-fit", "evans-joint", "cone")
        ]
        figures.image_comparison(
            out / name,
            maps[(n, t, "ref")][..., None].repeat(3, -1),
            [(lab, img[..., None].repeat(3, -1)) for lab, img in panels],
            sd.mask,
            error_scale=1.0,
            exposure=1.0,
            title=f"{n}: {TARGET_LABEL[t]}",
        )
        figs.append(
            {
                "file": name,
                "section": "failures",
                "caption": f"{n.replace('_', ' ')}: reference ({TARGET_LABEL[t]}) and approximations with signed "
                "error maps (red: too bright, blue: too dark).",
            }
        )
    t = "sky" if "sky" in cfg["targets"] else cfg["targets"][0]
    # Pareto: sweep points
    pts = []
    for r in sweep:
        lab = (
            f"{r['grid']}³ n={r['n']}"
            + ("" if r["prefilter"] else " nofilt")
            + (" 8bit" if r["bits"] == 8 else "")
        )
        if r["seed_default"]:
            lab += " ★seed"
        pts.append({"x": r["ns_per_pixel"], "y": r["rmse"], "label": lab})
    name = "figures/pareto_steps.png"
    figures.pareto_plot(
        out / name,
        pts,
        "cost (ns per pixel, measured)",
        "mean RMSE vs Mitsuba AO",
        floor=float(np.mean([r["noise_floor"] for r in sweep])),
    )
    figs.append(
        {
            "file": name,
            "section": "sweep",
            "caption": "Steps vs error vs cost: Evans occlusion (α = 0, w = 1; k and B refitted per point) against "
            "the AO reference, over samples n, grid resolution, prefiltering and 8-bit storage; ★ marks "
            "the seed's 4 samples at 128³ in 8 bit.",
        }
    )
    # method Pareto
    err = {}
    for doc in case_docs:
        for ap in doc["approximations"]:
            err.setdefault(ap["method"], []).append(ap["metrics"]["rmse"]["value"])
    cost = {c["method"]: c["ns_per_pixel"] for c in costs}
    pts = [{"x": cost[m], "y": float(np.mean(v)), "label": SHORT[m]} for m, v in err.items() if m in cost]
    name = "figures/pareto_methods.png"
    figures.pareto_plot(out / name, pts, "cost (ns per pixel, measured)", "mean RMSE over all cases")
    figs.append(
        {"file": name, "section": "costs", "caption": "Mean RMSE over all cases vs measured cost per pixel."}
    )
    # crease: AO vs angle
    cre = [n for n in cfg["scenes"] if n.startswith("crease_")]
    if cre:
        name = "figures/crease_profile.png"
        series = []
        for m in ("ref", "evans-fit", "cone"):
            xs, ys = [], []
            for n in cre:
                sd = sds[n]
                v = maps[(n, "ao", m)][sd.mask]
                sel = sd.normals[:, 2] > 0.99  # floor points
                xs.append(float(n.split("_")[1]))
                ys.append(float(np.mean(v[sel])) if np.any(sel) else float("nan"))
            series.append(
                {
                    "x": xs,
                    "y": ys,
                    "label": "Mitsuba AO" if m == "ref" else SHORT[m],
                    "style": "points" if m == "ref" else "line",
                }
            )
        figures.line_plot(out / name, "crease angle φ (degrees)", "mean AO of the floor arm", series)
        figs.append(
            {
                "file": name,
                "section": "failures",
                "caption": "Mean AO over the visible floor arm of each crease against the crease angle.",
            }
        )
    return figs


# ===================================================================================== fitted files
def write_fitted(out, cfg, joint, per_case, sds) -> list[dict]:
    """fitted/evans_joint_<target>.json (the joint continuous fit: k, w_i, B, α, base in voxels and in each
    training scene's units, all with standard errors; the raw LM parameters and covariance) and
    fitted/per_case.json (every case's parameters of every row, the continuous fits with stderrs)."""
    docs = []
    train = [n for n in cfg["scenes"] if n != HELD_OUT]
    for t, b in joint.items():
        readable = _json_params(evans_readable(b, None))
        fname = f"fitted/evans_joint_{t}.json"
        names = list(b["fit"]["parameters"])
        atomic_write_json(
            out / fname,
            {
                "model": "C = B * exp(-k * sum_i w_i (d_i - s_{i-1}(P + d_i (N + alpha U)))), d_i = base * 2^(i-1)"
                + ("; prediction g(N) * C, g = sunsky factor E_sky(N)/E_u(N)" if t in SUNSKY_TARGETS else ""),
                "target": t,
                "trained_on": train,
                "held_out": HELD_OUT,
                "units": {
                    "k": "1/scene unit",
                    "base_voxels": "voxels of the finest grid (each scene's own)",
                    "base": "scene units",
                    "alpha": "dimensionless",
                    "B": "dimensionless",
                    "w_i": "dimensionless (w_1 = 1)",
                },
                "parameters": readable,
                "base_scene_units": {
                    n: {
                        "value": b["base_vox"] * sds[n].voxel,
                        "stderr": (
                            readable["base_voxels_stderr"] * sds[n].voxel
                            if readable["base_voxels_stderr"] is not None
                            else None
                        ),
                        "voxel": sds[n].voxel,
                    }
                    for n in train
                },
                "grid_cells": cfg["grid"],
                "n": cfg["n_samples"],
                "method": "grid profile (LM of log B, c_i at each (alpha, base) point) as initialisation, then "
                "bounded Levenberg-Marquardt over (log B, c_i, alpha, base_voxels) with the alpha/base Jacobian "
                "columns from Dr.Jit forward-mode autodiff; stderr = sqrt(diag(s^2 (J^T J)^+)), s^2 = SSR/dof",
                "grid_init": {"alphas": cfg["alphas"], "bases_voxels": cfg["bases_vox"], **b["grid"]},
                "lm_fit": b["fit"],
                "lm": b["lm"],
                "covariance": {
                    "names": names,
                    "matrix": [[_json_params({"v": v})["v"] for v in row] for row in b["cov"]],
                },
            },
        )
        docs.append(
            {
                "id": f"evans-joint-{t}",
                "label": f"Evans joint fit ({TARGET_LABEL[t]})",
                "model": "C = exp(log B − Σ c_i D_i(α, base)), c_i = k·w_i; all fitted together (LM, "
                "Dr.Jit autodiff for α and base)",
                "parameters": b["fit"]["parameters"],
                "rms_residual": b["fit"]["rms_residual"],
                "n_residuals": b["fit"]["n_residuals"],
                "converged": b["fit"]["converged"],
                "file": fname,
            }
        )
    atomic_write_json(
        out / "fitted/per_case.json",
        {
            "units": {
                "k": "1/scene unit",
                "base": "scene units",
                "base_voxels": "voxels",
                "alpha": "dimensionless",
            },
            "note": "evans-fit / evans-analytic / evans-joint: continuous fits with standard errors (*_stderr; None: "
            "undetermined); *-lm: the fit's RMS residual before (grid) and after the continuous LM",
            "cases": per_case,
        },
    )
    return docs


# ===================================================================================== checks
def make_checks(cfg, sds, case_docs, fit_rows=()) -> list[dict]:
    checks = []
    if fit_rows:
        # The continuous LM starts at the grid's best point and accepts only steps that lower the SSR.
        worse = [
            r["case"] for r in fit_rows if r["rms_residual"] > r["rms_residual_grid"] * (1 + 1e-9) + 1e-12
        ]
        checks.append(
            {
                "name": "continuous Evans fit (LM, autodiff α/base) never above its grid initialisation "
                "(RMS residual, every case)",
                "value": len(worse),
                "expected": "0",
                "passed": not worse,
            }
        )
    # Mitsuba AO at floor probes of each crease vs the wedge integral (independent quadrature, `crease_ao`).
    # Within R = ao_distance ≤ 1 the shipped crease (arms 2 long, 2 wide) is exact for probes at y = 0, x ≤ 0.4.
    for n in cfg["scenes"]:
        pr = sds[n].r.get("probes") if n.startswith("crease_") else None
        if pr is None:
            continue
        phi = math.radians(float(n.split("_")[1]))
        expect = np.array([crease_ao(phi, x, cfg["ao_distance"]) for x in pr["x"]])
        z = (pr["mean"] - expect) / np.sqrt(pr["stderr"] ** 2 + 1e-5**2)  # 1e-5: float32 ray precision
        checks.append(
            {
                "name": f"Mitsuba AO at {len(expect)} floor probes of the {n.split('_')[1]}° crease vs the "
                "wedge integral (max |z|)",
                "value": float(np.max(np.abs(z))),
                "expected": "≤ 4",
                "passed": bool(np.max(np.abs(z)) <= 4.0),
            }
        )
    # Structural: Evans with a normalised bent normal is exactly 1 on an unoccluded plane (analytic SDF).
    from rtfit.realtime.sdf_grid import HalfSpace
    from rtfit.realtime.sdf_occlusion import AnalyticSDF, EvansParams, evans_occlusion

    pts = np.column_stack([np.linspace(-1, 1, 64), np.zeros(64), np.zeros(64)])
    c = evans_occlusion(
        pts,
        np.tile([0.0, 0.0, 1.0], (64, 1)),
        AnalyticSDF([HalfSpace((0, 0, 0), (0, 0, 1))]),
        EvansParams(n=8, base=0.01, k=50.0, alpha=0.5, normalize=True),
    )
    dev = float(np.max(np.abs(np.asarray(c) - 1.0)))
    checks.append(
        {
            "name": "Evans on an unoccluded plane (analytic SDF, normalised N') equals 1",
            "value": dev,
            "expected": "max |C − 1| ≤ 1e-6",
            "passed": dev <= 1e-6,
        }
    )
    # The sunsky reference at an unoccluded point vs the quadrature of the baked sky (independent integration).
    for n in cfg["scenes"]:
        pr = sds[n].r.get("sky_probe")
        if pr is None:
            continue
        z = (pr["direct_mean"] - pr["expected"]) / np.maximum(pr["direct_stderr"], 1e-12)
        checks.append(
            {
                "name": "sunsky one bounce at an unoccluded point, facing up (E/E_h = 1) and sideways "
                f"(4 azimuths), vs the sky-irradiance quadrature: max |z| ({pr['spp']} spp)",
                "value": float(np.max(np.abs(z))),
                "expected": "≤ 4",
                "passed": bool(np.max(np.abs(z)) <= 4.0),
            }
        )
        zg = float(abs(pr["global_mean"][0] - pr["expected"][0]) / max(pr["global_stderr"][0], 1e-12))
        checks.append(
            {
                "name": "sunsky global illumination at an unoccluded upward-facing point vs the quadrature "
                "(|z|)",
                "value": zg,
                "expected": "≤ 4",
                "passed": zg <= 4.0,
            }
        )
        break
    # The fits converged.
    bad = [
        d["id"]
        for d in case_docs
        if not all(np.isfinite(a["metrics"]["rmse"]["value"] or np.nan) for a in d["approximations"])
    ]
    checks.append({"name": "every metric finite", "value": len(bad), "expected": "0", "passed": not bad})
    return checks


def crease_ao(phi: float, x: float, R: float) -> float:
    """AO within distance R of a floor point at distance x > 0 from the edge of an infinite wedge of interior
    angle φ (floor z = 0 for x > 0, wall from the edge at angle φ), normal +z.

    Directions ω = (cos β cos ψ, sin β, cos β sin ψ) (ψ: projected angle in the xz plane, β: out of it),
    dω = cos β dβ dψ, cos θ = cos β sin ψ. A direction with ψ ∈ (φ, π) meets the wall at in-plane distance
    ρ(ψ) = x sin φ / sin(ψ − φ), i.e. at distance ρ/cos β: it is occluded within R when cos β > ρ/R, so
    |β| < b(ψ) = acos(min(ρ/R, 1)), and ∫_{−b}^{b} cos²β dβ = b + sin b cos b. Hence

        AO = 1 − (1/π) ∫_φ^π sin ψ · (b + sin b cos b) dψ,

    which for R = ∞ (b = π/2) is (1 − cos φ)/2. Integrated with SciPy's adaptive quadrature."""
    from scipy.integrate import quad

    if not (0 < phi < math.pi) or not (x > 0) or not (R > 0):
        raise ValueError(f"need 0 < phi < pi, x > 0, R > 0 (got {phi}, {x}, {R})")

    def f(psi):
        rho = x * math.sin(phi) / max(math.sin(psi - phi), 1e-300)
        b = math.acos(min(rho / R, 1.0)) if math.isfinite(R) else math.pi / 2
        return math.sin(psi) * (b + math.sin(b) * math.cos(b))

    val, _ = quad(f, phi, math.pi, epsabs=1e-12, epsrel=1e-10, limit=200)
    return 1.0 - val / math.pi


# ===================================================================================== text
def sections(cfg) -> list[dict]:
    return [
        {
            "id": "method",
            "title": "Method",
            "text": "Every scene is a closed triangle mesh (generated procedurally, `experiments/sdf_occlusion_scenes.py`). "
            f"Its voxel SDF ({cfg['grid']}³ cells, exact Euclidean distance in a narrow band, closest-point propagation "
            "beyond, sign by ray parity) is prefiltered into a Gaussian mip chain; Evans' estimator samples "
            f"n = {cfg['n_samples']} points at d_i = base·2^(i−1) along the bent normal N + αU, sample i from mip "
            "level i − 1, and returns C = B·exp(−k Σ w_i (d_i − s_i)). Ground truth is rtfit's ray-cast estimator "
            f"through Mitsuba at the same pixel-centre points: AO within R = {cfg['ao_distance']:g}, and "
            "upper-hemisphere sky light with one bounce and (full run) all bounces at albedo "
            f"{cfg['albedo']:g} under two skies: a constant one (E/πL) and Mitsuba's `sunsky` without its sun "
            f"(sun at {cfg['sun_elevation']:g}° elevation, {cfg['sun_azimuth']:g}° azimuth from +Y towards +X, "
            f"turbidity {cfg['turbidity']:g}; luminance, as E/E_h with E_h the unoccluded horizontal irradiance). Under "
            "the sunsky every approximation is multiplied by the unoccluded sky's directional factor "
            "g(N) = E_sky(N)/E_u(N), E_u(N) the irradiance of a constant upper-hemisphere sky of the same E_h "
            "(quadrature of the baked sky; g ≡ 1 for a constant sky, so the constant-sky rows are the special case); "
            f"{cfg['spp']} samples per point in passes of {cfg['pass_spp']}. Mitsuba's `sdfgrid` "
            "shape built from the same grid gives the AO of the voxelised geometry: its difference from the mesh AO "
            "is the grid-resolution error (row *sdfgrid* in the AO cases), and Evans fitted at that geometry's own "
            "surface points against its own AO is the occlusion-model error alone (row *evans-on-sdfgrid*). "
            "Row *evans-analytic* fits Evans on the exact SDF of the primitives (sphere on plane, room, boxes).",
        },
        {
            "id": "fit",
            "title": "The continuous Evans fit",
            "placement": "after_results",
            "text": "Rows *evans-fit*, *evans-joint*, *evans-analytic* and *evans-on-sdfgrid* fit log B, c_i = k·w_i "
            f"(i = 1..{cfg['n_samples']}), α and the base distance together. Initialisation: for each (α, base) of "
            f"the grid α ∈ {{{', '.join(f'{a:g}' for a in cfg['alphas'])}}} × base ∈ "
            f"{{{', '.join(f'{b:g}' for b in cfg['bases_vox'])}}} voxels the model is linear in (log B, c_i) inside "
            "the exponent and those are fitted with α and base held; the best point starts the bounded "
            "Levenberg–Marquardt over all parameters (α ∈ [0, 1], base ∈ [¼, 4] voxels, c_i ≥ 0, |log B| ≤ 5) whose "
            "Jacobian columns for α and base come from Dr.Jit forward-mode autodiff through the kernel (each "
            "sample's position P + base·2^(i−1)·(N + αU) moves continuously; its mip level stays i − 1, so the "
            "residuals have kinks on trilinear cell faces). Standard errors: s²(JᵀJ)⁺ at the optimum, "
            "s² = SSR/dof (the `rtfit.fitting` convention); k = c_1, w_i = c_i/c_1 and B by the delta method. "
            f"Fits use at most {FIT_POINTS} pixels per scene. Pixel residuals are spatially correlated and dominated by "
            "model error, so the stderrs measure how sharply the data pin a parameter, not a sampling error. "
            "Table: per case α, base (voxels), k (1/scene unit), B with stderrs; RMS residual of the grid's best "
            "point → the continuous fit; LM iterations; parameters on a bound (their stderr is unreliable).",
        },
        {
            "id": "sweep",
            "title": "Steps vs error vs cost",
            "placement": "after_results",
            "text": "Evans' estimator as pure occlusion (α = 0, w = 1) with k and B refitted per configuration over "
            "samples n, grid resolution, with and without the Gaussian prefilter (without: plain 2×2×2 averages), "
            "and with the seed's 8-bit storage (one voxel per code). Error: mean RMSE over the sweep scenes against "
            "the AO reference; cost: the Dr.Jit kernel per pixel on this run's device. The `sweep` key of "
            "results.json holds the table.",
        },
        {
            "id": "failures",
            "title": "Where it fails",
            "placement": "after_results",
            "text": "Error maps per scene. Expected failure modes, visible there: thin occluders (thinner than a voxel of "
            "the mip level a sample reads: the blurred SDF never reaches 0, so the room's walls and the character's "
            "limbs occlude too little), occluders behind the normal direction (the samples march only along N'; a "
            "wall beside a point at grazing angles is never sampled), and distant large occluders (beyond "
            "Σ d_i = base·(2^n − 1): the room's ceiling and the sky hidden by the window wall, which Evans cannot see).",
        },
    ]


def _with_sweep_table(secs, sweep) -> list[dict]:
    lines = ["grid  n  prefilter  bits   RMSE     floor    ns/pixel"]
    for r in sweep:
        lines.append(
            f"{r['grid']:>4}  {r['n']}  {'yes' if r['prefilter'] else 'no ':9}  {r['bits']:>4}   "
            f"{r['rmse']:.4f}   {r['noise_floor']:.4f}   {r['ns_per_pixel']:.3g}"
            + ("   <- seed (n = 4, 128³, 8 bit)" if r["seed_default"] else "")
        )
    for sec in secs:
        if sec["id"] == "sweep":
            sec["text"] += "\n\n```\n" + "\n".join(lines) + "\n```"
    return secs


def notes(cfg) -> list[str]:
    return [
        "Sign convention: s > 0 outside (the seed's listings, 000:3037-3040; Mitsuba's sdfgrid); the seed's text "
        "says positive inside (000:2891-2895). Its contrast k_text is −k here.",
        "The seed's text (000:2946) uses α = 0.5 and no weights; its Listing 1 (000:2982-2987) uses α = 1 and "
        "weights 1, 1.2, 1.4, 1.8 with no '+ d_i' term (a constant factor, fitted as B). Both are rows.",
        "The seed gives no value of k: every Evans row fits it.",
        "Images are dimensionless: AO ∈ [0, 1]; sky light as E/(πL) (constant sky) or E/E_h (sunsky, E_h the "
        "unoccluded horizontal irradiance), 1 for an unoccluded upward-facing point.",
        "Sunsky targets use Mitsuba's `sunsky` emitter with sun_scale 0 (the sun removed; its circumsolar sky "
        "stays), radiance 0 below the horizon, reduced to luminance Y = 0.2126 R + 0.7152 G + 0.0722 B. E_h comes "
        "from a quadrature of the sky baked by `rtfit.reference.environments.sunsky_environment`.",
        "Mitsuba 3.9's sdfgrid shape misses every hit on non-cubic grids (measured); all grids here are cubic.",
    ]


def summary(cfg, case_docs, joint, sweep, sds) -> str:
    def mean_rmse(method, target):
        v = [
            a["metrics"]["rmse"]["value"]
            for d in case_docs
            if d["parameters"]["target"] == target
            for a in d["approximations"]
            if a["method"] == method
        ]
        return float(np.mean(v)) if v else float("nan")

    t = "sky" if "sky" in cfg["targets"] else cfg["targets"][0]
    jp = free_params_readable(joint[t], 1.0)
    best = min(sweep, key=lambda r: r["rmse"])

    def held_rmse(target):
        held = [d for d in case_docs if d["parameters"]["held_out"] and d["parameters"]["target"] == target]
        if not held:
            return None
        return {a["method"]: a["metrics"]["rmse"]["value"] for a in held[0]["approximations"]}

    held_txt = ""
    ap = held_rmse(t)
    if ap:
        held_txt = (
            f" On the held-out character the joint set gives RMSE {ap['evans-joint']:.3g} against "
            f"{ap['evans-fit']:.3g} for a per-scene fit."
        )
    sun_txt = ""
    if "sunsky" in cfg["targets"]:
        sp = free_params_readable(joint["sunsky"], 1.0)
        hs = held_rmse("sunsky")
        sun_txt = (
            f" Under the sunsky sky without its sun ({cfg['sun_elevation']:g}° elevation; E/E_h, "
            f"approximations × the unoccluded sky factor g(N)): seed listing "
            f"{mean_rmse('evans-listing', 'sunsky'):.3g}, fitted per scene {mean_rmse('evans-fit', 'sunsky'):.3g}, "
            f"joint {mean_rmse('evans-joint', 'sunsky'):.3g} (α = {_pm(sp['alpha'], sp['alpha_stderr'])}, "
            f"base = {_pm(sp['base_voxels'], sp['base_voxels_stderr'])} voxels)"
            + (f", held-out character {hs['evans-joint']:.3g} vs {hs['evans-fit']:.3g}" if hs else "")
            + "."
        )
    grid_err = [
        a["metrics"]["rmse"]["value"]
        for d in case_docs
        for a in d["approximations"]
        if a["method"] == "sdfgrid"
    ]
    return (
        f"Evans' 2006 SDF skylight against Mitsuba ray-cast sky light ({TARGET_LABEL[t]}), mean RMSE over "
        f"{len(cfg['scenes'])} scenes: seed text form {mean_rmse('evans-text', t):.3g}, seed listing "
        f"{mean_rmse('evans-listing', t):.3g}, fitted per scene (k, α, base, w_i, B continuous) "
        f"{mean_rmse('evans-fit', t):.3g}, one joint set "
        f"{mean_rmse('evans-joint', t):.3g} (k = {_pm(jp['k'], jp['k_stderr'])}/unit, "
        f"α = {_pm(jp['alpha'], jp['alpha_stderr'])}, base = {_pm(jp['base_voxels'], jp['base_voxels_stderr'])} "
        f"voxels), cone-traced DF AO {mean_rmse('cone', t):.3g}, curvature term "
        f"{mean_rmse('curvature', t):.3g}.{held_txt}{sun_txt} Against AO within R = {cfg['ao_distance']:g}: Evans fitted "
        f"{mean_rmse('evans-fit', 'ao'):.3g}, cone {mean_rmse('cone', 'ao'):.3g}; the voxelisation alone "
        f"(Mitsuba AO on the sdfgrid shape vs the mesh) costs {np.mean(grid_err) if grid_err else float('nan'):.3g}. "
        f"Best swept configuration: {best['grid']}³, n = {best['n']} (RMSE {best['rmse']:.3g} at "
        f"{best['ns_per_pixel']:.3g} ns/pixel)."
    )


# ===================================================================================== bench
def bench(ctx) -> list[dict]:
    """Pixels/s of Evans (n = 4, 128³) and the cone-traced variant beside the Mitsuba AO estimator's
    samples/s, in the same run."""
    import drjit as dr

    from rtfit.realtime import set_default_backend
    from rtfit.realtime.sdf_occlusion import _DR, EvansParams, GridSDF, _cone_kernel, _evans_kernel
    from rtfit.reference import load_mitsuba_scene
    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.occlusion import occlusion_pass

    from .cost import time_drjit

    variant = ctx.variant
    set_default_backend("cuda" if variant.startswith("cuda") else "llvm")
    res = 64 if ctx.quick else 256
    grid_res = 64 if ctx.quick else 128
    sc = load_case_scene("boxes", res)
    mi, mi_scene = load_mitsuba_scene(sc, variant)
    gb = gbuffer(mi, mi_scene)
    pts, nrm = gb.position[gb.mask].astype(np.float64), gb.normal[gb.mask].astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    g = grid_of(sc, grid_res)
    sdf = GridSDF.from_grid(g, levels=8)
    size = ctx.size or (1 << 18 if ctx.quick else 1 << 22)
    Float = (dr.cuda if variant.startswith("cuda") else dr.llvm).Float
    idx = np.random.default_rng(0).integers(0, len(pts), size)
    cols = tuple(
        Float(np.ascontiguousarray(a[idx, i], dtype=np.float32)) for a in (pts, nrm) for i in range(3)
    )
    rows = []
    be = "cuda" if variant.startswith("cuda") else "llvm"
    prm = EvansParams(n=4, base=g.voxel, k=10.0, alpha=0.5)
    t = time_drjit(lambda *a: _evans_kernel(_DR, sdf, prm, *a), cols, size)
    rows.append(
        {
            "what": f"Evans n=4, {grid_res}³ grid",
            "backend": be,
            "elements": size,
            "Mpx_s": t.elements_per_second / 1e6,
            "ns_per_px": t.ns_per_element,
            "Msamples_s": None,
        }
    )
    t = time_drjit(lambda *a: _cone_kernel(_DR, sdf, 9, 8, g.voxel, 1.0, 2.0, *a), cols, size)
    rows.append(
        {
            "what": f"cone-traced DF AO (9 cones × 8 steps), {grid_res}³",
            "backend": be,
            "elements": size,
            "Mpx_s": t.elements_per_second / 1e6,
            "ns_per_px": t.ns_per_element,
            "Msamples_s": None,
        }
    )
    spp = 64 if ctx.quick else 256
    occlusion_pass(mi, mi_scene, pts[:1024], nrm[:1024], 4, 0, quantity="ao", max_distance=1.0)  # warm-up
    r = occlusion_pass(mi, mi_scene, pts, nrm, spp, 1, quantity="ao", max_distance=1.0)
    rows.append(
        {
            "what": f"Mitsuba ray-cast AO reference ({spp} spp)",
            "backend": be,
            "elements": len(pts),
            "Mpx_s": len(pts) / r.seconds / 1e6,
            "ns_per_px": r.seconds / len(pts) * 1e9,
            "Msamples_s": len(pts) * spp / r.seconds / 1e6,
        }
    )
    return rows
