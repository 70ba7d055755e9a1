"""The ambient-aperture family's own study for ``rtfit run ambient-aperture`` (issue 30 §1): what only it has.

The engine (`rtfit.experiments.engine_run`) audits the shipped scenes (`audit_ambient_aperture.SCENES`: a
floor under a plate with a hole, the floor of a well, a bumpy height field, each with a sphere light and a
constant sky of radiance 1) exactly as ``rtfit audit`` audits a user's scene: the occluded sphere light
(every ``aa-*`` row against the light's shadowed irradiance), the aperture fill (``fill-*`` against the
occluded sky) and the aperture caps (against ray-cast AO within R), each point's cap baked by Mitsuba ray
casts, the fitted forms' c0..c5 and k also fitted per scene, costs, figures and the fitted file. This study
adds what needs no scene or is this family's alone:

* **the intersection forms over their whole domain** (no rendering): Ω(r1, r2, d) of the smoothstep (the
  seed's), linear and fitted forms against the exact closed form over a cell-centred (r1, r2, d) grid of
  (0, π)³, as fractions of the smaller cap, on "hemisphere caps" (r ≤ π/2) and the full domain; the closed
  form itself against independent quadrature (`rtfit.reference.cap_quadrature`) on the grid and at hard
  points, and against the closed values of nested, disjoint and covering caps;
* **the two fits of the shipped coefficients**: c0..c5 of the fitted form on the full-domain grid, and the
  Lambert factor's exponent k on random (aperture, light) configurations against the cosine-weighted
  intersection by quadrature (``fitted/intersection.json``, ``fitted/lambert.json``);
* **cap model or formula** on the engine's cases: the exact integral over each pixel's baked cap ∩ the
  light's cap (quadrature) against the reference (the cap model's own error) and each shading row against
  it (the formula's own error), in fractions of the unshadowed peak; the sky's fill likewise against π·L;
* the cost of each intersection form per evaluation, and the check that Mitsuba's probes match the
  closed-form sphere-light irradiance once the hole scene's occluders are removed (a render of its own).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from rtfit.fitting import Param, compute_metrics, fit_method, robust_spread, z_pair
from rtfit.fitting.stats import Z_MEDIAN_TOLERANCE, Z_SPREAD_TOLERANCE
from rtfit.realtime import cap_area, cap_intersection_solid_angle, sphere_light_irradiance
from rtfit.realtime.ambient_aperture import METHODS
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.methods import Method
from rtfit.reference import ReferenceCache, ReferenceRequest
from rtfit.reference.cap_quadrature import (
    adaptive_quadrature_intersection,
    cap_model_irradiance,
    quadrature_intersection,
)
from rtfit.reference.variants import backend_of
from rtfit.scenes import SphereLight, library_path, load_scene

from . import fitted as fitfiles
from .ambient_aperture_doc import (
    APPROX,
    DECOMPOSITION,
    EXACT,
    OMEGA,
    curve_figure,
    map_figure,
    params_of,
    pareto_figure,
    report_text,
    smaller_cap,
)
from .cost import cost_row, memory_floor_row, time_method
from .records import Check, Fit, FitParameter, Headline, Section
from .shipped import Study, StudyContext

__all__ = [
    "CONFIG",
    "HARD_POINTS",
    "fit_intersection",
    "fit_lambert",
    "function_level",
    "study",
    "write_fit_file",
]

PI = math.pi
_SIZES = {  # name: (--quick, the full run)
    "grid": (40, 96),
    "fit_grid": (40, 72),
    "quad_nodes": (48, 96),
    "lambert_configs": (1500, 6000),
    "lambert_quad": ((24, 96), (48, 192)),
    "cap_quad": ((24, 96), (48, 192)),
    "probe_n": (32, 64),
    "spp": (1024, 8192),
    "pass_spp": (512, 4096),
    "cost_elements": (1 << 20, 1 << 24),
}
CONFIG = {quick: {name: both[0 if quick else 1] for name, both in _SIZES.items()} for quick in (True, False)}
"""The study's sizes by ``--quick`` (those of the experiment before the engine): (r1, r2, d) grid points per
axis, fit grid, Gauss–Legendre nodes of the grid's quadrature, Lambert configurations and their quadrature
nodes (coarse, fine), the cap-model nodes, the unoccluded check's probe image side, samples and pass size,
and the elements per timed launch."""
SEED_OMEGA, FITTED_OMEGA, FITTED_LAMBERT = (
    METHODS["smoothstep"],
    METHODS["fitted"],
    METHODS["aa-exact-fitted"],
)
LAMBERT_ROWS = {"seed": METHODS["aa-exact-seed"], "fitted": FITTED_LAMBERT}
FIT_START = {**{p: 0.0 for p in FITTED_OMEGA.params}, "k": 1.0}
"""Start values of the fits: the plain smoothstep (c = 0) and k = 1, not the shipped values they reproduce."""
HARD_POINTS = ((0.5, 0.5, 0.5), (2.0, 1.0, 2.5), (2.6, 2.2, 1.9), (0.01, 1.2, 1.205), (1.4, 0.0003, 1.40025))
"""(r1, r2, d) where the closed form is hardest: equal caps, covering caps, near-tangent tiny caps."""


def _start(method: Method) -> dict[str, Param]:
    return {p: dataclasses.replace(spec, initial=FIT_START[p]) for p, spec in method.params.items()}


# ======================================================================================= function level
def grid_points(n: int):
    """Cell-centred (r1, r2, d) grid over (0, π)³, flattened."""
    g = (np.arange(n) + 0.5) / n * PI
    return tuple(x.ravel() for x in np.meshgrid(g, g, g, indexing="ij"))


def partial_mask(r1, r2, d):
    """Points where the caps partly overlap (neither nested, disjoint nor covering the sphere)."""
    return (d > np.abs(r1 - r2)) & (d < r1 + r2) & (r1 + r2 + d < 2 * PI)


def function_level(cfg: Mapping, fitted: Mapping[str, float], seed: int) -> dict:
    """Errors of each approximate form over the grid (fractions of the smaller cap) and the checks of the
    closed form: quadrature on (≤ 60000 of) the partial points, closed values on the others."""
    r1, r2, d = grid_points(cfg["grid"])
    caps = {"r1": r1, "r2": r2, "d": d}
    part = partial_mask(r1, r2, d)
    hemi = part & (r1 <= PI / 2) & (r2 <= PI / 2)
    exact = EXACT.evaluate(caps)
    a_min = smaller_cap(r1, r2)
    idx = np.flatnonzero(part)
    if len(idx) > 60000:
        idx = np.random.default_rng(seed).choice(idx, 60000, replace=False)
    quad = quadrature_intersection(r1[idx], r2[idx], d[idx], cfg["quad_nodes"])
    nested, disjoint = d <= np.abs(r1 - r2), d >= r1 + r2
    covering = (r1 + r2 + d >= 2 * PI) & ~nested & ~disjoint
    closed = np.where(
        nested, a_min, np.where(disjoint, 0.0, 4 * PI * (np.sin(r1 / 2) ** 2 + np.sin(r2 / 2) ** 2) - 4 * PI)
    )
    sel = nested | disjoint | covering
    errors = {}
    for m in APPROX:
        approx = m.evaluate(caps, params_of(m, fitted))
        rel = (approx - exact) / a_min
        errors[m.id] = {
            dom: {
                "max": float(np.max(np.abs(rel[k]))),
                "rms": float(np.sqrt(np.mean(rel[k] ** 2))),
                "mean": float(np.mean(rel[k])),
                "points": int(k.sum()),
            }
            for dom, k in (("hemisphere", hemi), ("full", part), ("all", np.ones_like(part)))
        }
        errors[m.id]["in_bounds"] = bool(np.all(approx >= 0) and np.all(approx <= a_min * (1 + 1e-9)))
    return {
        "errors": errors,
        "quad_dev": float(np.max(np.abs(exact[idx] - quad) / a_min[idx])),
        "quad_points": len(idx),
        "closed_dev": float(np.max(np.abs(exact[sel] - closed[sel]) / a_min[sel])),
        "grid": cfg["grid"],
        "n_partial": int(part.sum()),
        "n_hemi": int(hemi.sum()),
    }


def hard_point_deviation(points=HARD_POINTS) -> float:
    """max |Ω − Ω_quad| / A_min at `HARD_POINTS`, Ω_quad by SciPy's adaptive quadrature."""
    return max(
        abs(cap_intersection_solid_angle(r1, r2, d) - adaptive_quadrature_intersection(r1, r2, d))
        / float(smaller_cap(r1, r2))
        for r1, r2, d in points
    )


# ================================================================================================= fits
def fit_intersection(grid: int) -> dict:
    """c0..c5 of the fitted form on a grid³ of the full domain, through its kernel: least squares of
    (Ω_fit − Ω_exact)/A(r_min) over the partial-overlap points (SciPy's TRF on the NumPy run of the kernel:
    the same optimum as Levenberg–Marquardt on JAX to 1e-9, without JAX's compile)."""
    r1, r2, d = grid_points(grid)
    m = partial_mask(r1, r2, d)
    r1, r2, d = r1[m], r2[m], d[m]
    res = fit_method(
        FITTED_OMEGA,
        {"r1": r1, "r2": r2, "d": d},
        cap_intersection_solid_angle(r1, r2, d),
        weights=1.0 / smaller_cap(r1, r2),
        params=_start(FITTED_OMEGA),
        solver="trf",
    )
    return {**res.to_dict(), "n_residuals": len(r1), "grid": grid}


def lambert_configs(count: int, seed: int = 17):
    """Random (n = +z, a, r_a, l, α) with a in the upper hemisphere, l up to α below the horizon."""
    rng = np.random.default_rng(seed)
    th_a, ph_a = np.arccos(rng.uniform(0.0, 1.0, count)), rng.uniform(0, 2 * PI, count)
    r_a = rng.uniform(0.05, PI / 2, count)
    alpha = np.exp(rng.uniform(math.log(0.01), math.log(0.6), count))
    th_l, ph_l = np.arccos(rng.uniform(-0.2, 1.0, count)), rng.uniform(0, 2 * PI, count)

    def vec(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)

    return np.tile([0.0, 0.0, 1.0], (count, 1)), vec(th_a, ph_a), r_a, vec(th_l, ph_l), alpha


def fit_lambert(count: int, nodes) -> dict:
    """k of the fitted centroid through `FITTED_LAMBERT`'s kernel: least squares of (E − E_true)/A(α) at unit
    radiance, E_true the cosine-weighted intersection by quadrature; the seed's and fitted factor's errors,
    the open sky with a small light at 60° (the erratum's 73 %) and the quadrature's change with doubled
    nodes (first 300 configurations)."""
    n, a, r_a, ld, alpha = lambert_configs(count)
    target = cap_model_irradiance(n, a, r_a, ld, alpha, tuple(nodes))
    cos_al = np.clip(np.sum(a * ld, 1), -1, 1)
    keep = cap_intersection_solid_angle(r_a, alpha, np.arccos(cos_al)) > 1e-3 * cap_area(
        np.minimum(r_a, alpha)
    )
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
    res = fit_method(
        FITTED_LAMBERT, inputs, target, weights=1.0 / scale, params=_start(FITTED_LAMBERT), solver="trf"
    )
    k = float(res.values["k"])
    errs = {}
    for name, method in LAMBERT_ROWS.items():
        rel = (method.evaluate(inputs, params_of(method, {"k": k})) - target) / scale
        errs[name] = {
            "rms": float(np.sqrt(np.mean(rel**2))),
            "max": float(np.max(np.abs(rel))),
            "mean": float(np.mean(rel)),
        }
    sky60 = {"cos_na": 1.0, "cos_nl": 0.5, "cos_al": 0.5, "aperture": PI / 2, "alpha": 0.01, "radiance": 1.0}
    z = [[0.0, 0.0, 1.0]]
    exact60 = float(
        cap_model_irradiance(z, z, [PI / 2], [[math.sqrt(0.75), 0, 0.5]], [0.01], tuple(nodes))[0]
    )
    m = min(300, len(target))
    fine = cap_model_irradiance(n[:m], a[:m], r_a[:m], ld[:m], alpha[:m], (2 * nodes[0], 2 * nodes[1]))
    open60 = {
        name: float(meth.evaluate(sky60, params_of(meth, {"k": k}))) for name, meth in LAMBERT_ROWS.items()
    }
    return {
        **res.to_dict(),
        "errors": errs,
        "n_configs": len(target),
        "n_residuals": len(target),
        "k": k,
        "open_sky_60": {"exact": exact60, **open60},
        "quad_resolution": float(np.max(np.abs(fine - target[:m]) / scale[:m])),
    }


def write_fit_file(fid: str, label: str, model: str, fit: Mapping, method: Method, out: Path, prov) -> Fit:
    """``fitted/<fid>.json`` (``rtfit.fitted/1``: the method at its fitted parameters, GLSL/HLSL) and its
    record for the report's fit table."""
    own = {k: v for k, v in fit["parameters"].items() if k in method.params}
    data = {"model": model, **{k: v for k, v in fit.items() if k != "parameters"}}
    entry = fitfiles.method_entry(
        method,
        {**fit, "parameters": own},
        id=fid,
        label=label,
        data=data,
        residual_units="fraction of the smaller cap"
        if fid == "intersection"
        else "fraction of the light cap's solid angle",
    )
    rec = fitfiles.write_fit(
        out,
        f"fitted/{fid}.json",
        title=f"ambient aperture: {label}",
        provenance=prov,
        entry=entry,
        doc_id=fid,
        label=label,
        model=model,
        fit=fit,
    )
    params = {
        k: FitParameter(**{f: v[f] for f in ("value", "stderr", "lower", "upper", "at_bound") if f in v})
        for k, v in own.items()
    }
    return Fit(
        id=fid,
        label=label,
        model=model,
        parameters=params,
        rms_residual=rec["rms_residual"],
        n_residuals=rec["n_residuals"],
        converged=rec["converged"],
        file=rec["file"],
    )


# ============================================================================= cap model or formula
def _vectors(cos_na, cos_nl, cos_al):
    """Unit n = +z, a and l with the given cosines (the integral depends on nothing else)."""
    sa = np.sqrt(np.maximum(1 - cos_na**2, 0.0))
    sl = np.sqrt(np.maximum(1 - cos_nl**2, 0.0))
    lx = np.clip(np.where(sa > 1e-9, (cos_al - cos_na * cos_nl) / np.maximum(sa, 1e-9), sl), -sl, sl)
    ly = np.sqrt(np.maximum(sl**2 - lx**2, 0.0))
    n = np.tile([0.0, 0.0, 1.0], (len(cos_na), 1))
    return n, np.stack([sa, 0 * sa, cos_na], 1), np.stack([lx, ly, cos_nl], 1)


def _rmse(x, ref, sigma) -> tuple[float, float]:
    """(RMSE, its noise floor) of rows x against ref (N, 3) (`rtfit.fitting.compute_metrics`)."""
    v = compute_metrics(x, ref, sigma, np.ones(len(ref), bool), names=("rmse",))["rmse"]
    return float(v.value), float(v.noise_floor)


def decomposition(ctx: StudyContext, nodes) -> tuple[list[dict], bool]:
    """Per light case: the cap model's RMSE against the reference (and the floor), the unshadowed sphere
    light's, each `DECOMPOSITION` row's against the reference and against the cap model, all over the
    unshadowed peak; per fill case: the fills' and the unoccluded sky's (π·L) over π·L. Also whether every
    engine row and the cap model are finite."""
    rows, finite = [], True
    for audit in ctx.audits:
        for case in audit.cases:
            out = audit.outcomes[case.id]
            finite &= all(bool(np.all(np.isfinite(o.image))) for o in out.values())
            m, g = case.mask, case.channel_inputs
            ref, sig = case.reference.mean[m], case.reference.sigma()[m]
            img = {r: out[r].image[m] for r in out}
            if case.id.endswith("-occluded"):
                cols = {
                    k: np.broadcast_to(np.asarray(g[0][k], np.float64), (len(ref),))
                    for k in ("cos_na", "cos_nl", "cos_al", "aperture", "alpha")
                }
                n, a, ld = _vectors(cols["cos_na"], cols["cos_nl"], cols["cos_al"])
                unit = cap_model_irradiance(n, a, cols["aperture"], ld, cols["alpha"], tuple(nodes))
                rad = [float(np.mean(g[c]["radiance"])) for c in range(3)]
                cap = np.stack([unit * rad[c] for c in range(3)], 1)
                unsh = np.stack(
                    [sphere_light_irradiance(cols["cos_nl"], cols["alpha"], rad[c]) for c in range(3)], 1
                )
                peak = float(unsh.max())
                finite &= bool(np.all(np.isfinite(cap)))
                rmse, floor = _rmse(cap / peak, ref / peak, sig / peak)
                row = {
                    "case": case.id,
                    "kind": "light",
                    "peak": peak,
                    "cap_model_vs_reference": rmse,
                    "noise_floor": floor,
                    "unshadowed_vs_reference": _rmse(unsh / peak, ref / peak, sig / peak)[0],
                }
                for r in DECOMPOSITION:
                    if r in img:
                        row[f"{r}_vs_reference"] = _rmse(img[r] / peak, ref / peak, sig / peak)[0]
                        row[f"{r}_vs_cap_model"] = float(np.sqrt(np.mean((img[r] - cap) ** 2)) / peak)
                rows.append(row)
            elif "-fill" in case.id:
                peak = PI * float(np.max([np.max(g[c]["sky_radiance"]) for c in range(3)]))
                row = {
                    "case": case.id,
                    "kind": "sky",
                    "peak": peak,
                    "unoccluded_vs_reference": _rmse(np.full_like(ref, peak) / peak, ref / peak, sig / peak)[
                        0
                    ],
                }
                for r in ("fill-projected", "fill-seed"):
                    if r in img:
                        row[f"{r}_vs_reference"], row["noise_floor"] = _rmse(
                            img[r] / peak, ref / peak, sig / peak
                        )
                rows.append(row)
    return rows, finite


# ========================================================================================== unoccluded
def unoccluded_checks(ctx: StudyContext, n: int, spp: int, pass_spp: int) -> tuple[list[Check], dict]:
    """The hole scene's floor alone under its sphere light: Mitsuba's direct irradiance at an n×n grid of
    floor points over [−1.5, 1.5]² against the closed form; the z-scores must be standard normal."""
    scene = load_scene(library_path("aperture_hole"))
    light = next(lt for lt in scene.lights if isinstance(lt, SphereLight))
    floor = dataclasses.replace(
        scene, shapes=scene.shapes[:1], lights=(light,), name=f"{scene.name}-unoccluded"
    )
    x, y = np.meshgrid(np.linspace(-1.5, 1.5, n), np.linspace(1.5, -1.5, n), indexing="xy")
    p = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    nrm = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    req = ReferenceRequest(
        scene=floor,
        spp=spp,
        pass_spp=min(pass_spp, spp),
        seed=ctx.seed,
        variant=ctx.variant,
        quantity="irradiance",
        points=p,
        normals=nrm,
        transport="direct",
    )
    r = ReferenceCache(ctx.cache_dir).get(req, label="unoccluded probes")
    v = np.asarray(light.center, np.float64)[None, :] - p
    dist = np.linalg.norm(v, axis=1)
    alpha = np.arctan2(light.radius, np.sqrt(np.maximum(dist**2 - light.radius**2, 0)))
    exact = sphere_light_irradiance(v[:, 2] / dist, alpha, float(light.radiance[0]))
    _, z = z_pair(exact, r.mean[:, 0], r.stderr[:, 0], r.sigma()[:, 0], 0.0)
    spread, med = robust_spread(z), float(np.median(z))
    name = "reference vs closed-form sphere-light irradiance, hole scene's occluders removed"
    return [
        Check.within(f"{name}: z-score robust spread", spread, "1", Z_SPREAD_TOLERANCE),
        Check.magnitude_at_most(f"{name}: z-score median", med, "median", Z_MEDIAN_TOLERANCE),
    ], {"probes": len(p), "spp": spp, "z_spread": spread, "z_median": med}


# ================================================================================================ costs
def omega_costs(variant: str, fitted: Mapping[str, float], elements: int) -> list[dict]:
    """ns per evaluation of each intersection form (random r1, r2 ∈ [0, π/2], d ∈ [0, π], float32) and the
    memory floor of its three inputs, same run."""
    backend = backend_of(variant)
    rng = np.random.default_rng(1)
    Float = backend_float(backend)
    hi = {"r1": PI / 2, "r2": PI / 2, "d": PI}
    inputs = {k: Float(rng.uniform(0, h, elements).astype(np.float32)) for k, h in hi.items()}
    note = "per evaluation: r1, r2, d in memory (float32), one float out"
    rows = [
        cost_row(
            f"omega-{m.id}", m.label, backend, time_method(m, inputs, elements, params_of(m, fitted)), note
        )
        for m in OMEGA
    ]
    return [*rows, memory_floor_row(tuple(inputs.values()), elements, backend, "the floor for these kernels")]


# ================================================================================================ study
def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run ambient-aperture`` (module docstring), from the engine's audits."""
    cfg = CONFIG[bool(ctx.quick)]
    out = Path(ctx.out_dir)
    fit_i = fit_intersection(cfg["fit_grid"])
    fit_l = fit_lambert(cfg["lambert_configs"], cfg["lambert_quad"])
    fitted = {**{p: float(v["value"]) for p, v in fit_i["parameters"].items()}, "k": fit_l["k"]}
    fl = function_level(cfg, fitted, ctx.seed)
    hard = hard_point_deviation()
    dec, finite = decomposition(ctx, cfg["cap_quad"])
    unocc, unocc_info = unoccluded_checks(ctx, cfg["probe_n"], cfg["spp"], cfg["pass_spp"])
    costs = omega_costs(ctx.variant, fitted, cfg["cost_elements"])
    prov = fitfiles.provenance(
        None, "ambient-aperture", [], reference_spp=None, variant=ctx.variant, quick=ctx.quick
    )
    fits = (
        write_fit_file(
            "intersection",
            "Fitted cap-intersection form",
            "f = sat(t²(3−2t) + t(1−t)[c0 + c1u + ρ(c2 + c3u) + σ(c4 + c5u)]), u = 1 − 2t, after the "
            "complement trick",
            {**fit_i, "errors": fl["errors"][FITTED_OMEGA.id]},
            FITTED_OMEGA,
            out,
            prov,
        ),
        write_fit_file(
            "lambert",
            "Centroid weight of the Lambert factor",
            "c = normalize(w l + (1 − w) a), w = A(r_a)^k / (A(r_a)^k + A(α)^k)",
            fit_l,
            FITTED_LAMBERT,
            out,
            prov,
        ),
    )
    fe, seed_max = fl["errors"][FITTED_OMEGA.id], fl["errors"][SEED_OMEGA.id]["full"]["max"]
    checks = (
        Check.at_most(
            "closed form vs independent quadrature over the grid (max |ΔΩ| / smaller cap)",
            fl["quad_dev"],
            "1e-4",
        ),
        Check.at_most(
            "closed form vs adaptive quadrature (SciPy, float64) at 5 points incl. near-tangent tiny "
            "caps (max |ΔΩ| / smaller cap)",
            hard,
            "1e-10",
        ),
        Check.at_most(
            "closed form on nested / disjoint / covering grid points vs their closed values",
            fl["closed_dev"],
            "1e-12",
        ),
        Check.holds("fitted form stays within [0, smaller cap] on the grid", fe["in_bounds"]),
        Check.below(
            "fitted form beats the smoothstep: max error, full domain", fe["full"]["max"], seed_max, fmt=".4g"
        ),
        Check.holds("intersection fit converged", fit_i["converged"]),
        Check.holds("Lambert-weight fit converged", fit_l["converged"]),
        Check.at_most(
            "Lambert-factor quadrature: change with doubled nodes (max, fraction of the light cap)",
            fit_l["quad_resolution"],
            "0.01",
        ),
        *unocc,
        Check.holds("every row of every case and the cap model finite (no NaN/Inf)", finite),
    )
    coeffs = [fitted[p] for p in FITTED_OMEGA.params]
    return Study(
        sections=(
            Section(
                id="study-ambient-aperture",
                title="Intersection forms, Lambert factor, cap model or formula",
                text=report_text(fl, fit_i, fit_l, dec, costs, coeffs),
                placement="after_results",
            ),
        ),
        figures=(curve_figure(out, fitted), map_figure(out, fitted), pareto_figure(out, fl, costs)),
        checks=checks,
        fits=fits,
        headline=(
            Headline(
                label="smoothstep max error, r ≤ π/2 (fraction of smaller cap)",
                value=fl["errors"][SEED_OMEGA.id]["hemisphere"]["max"],
                unit="of smaller cap",
            ),
            Headline(label="fitted max error, full domain", value=fe["full"]["max"], unit="of smaller cap"),
        ),
        notes=(
            "Function level: errors are (Ω_approx − Ω_exact) / A(min(r1, r2)) over the partial-overlap "
            "points of the (r1, r2, d) grid; the fitted form's c0..c5 and k are this run's fits "
            "(fitted/*.json), the engine's rows use the shipped values (and fit their own per scene).",
        ),
        extra={
            "function_level": fl,
            "fit_lambert": {k: v for k, v in fit_l.items() if k != "parameters"},
            "decomposition": dec,
            "omega_costs": costs,
            "unoccluded": unocc_info,
        },
    )
