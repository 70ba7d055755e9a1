"""The study of ``rtfit run irradiance-bases`` (issue 30 §1): what only the irradiance bases have, beside the
engine's audits of the shipped white sphere (`audit_irradiance_bases.SCENES`: constant, sunsky, studio,
overcast).

From the engine's audits (the bases against Mitsuba's irradiance at the visible normals):

* **per environment**: each row's relative RMSE √(Σ(x − r)²/Σr²), sMAPE, max_rel = max |x − r|/max(r, 0.05·r̄)
  and the fraction of pixels with a negative channel (SH ringing), each with the reference's noise floor
  (`with_floor`: the metric of r + σ·N(0, 1) against r, `FLOOR_DRAWS` seeded draws), over the case's pixels;
* **storage budgets** (`budget_winners`): which stored basis wins at 4, 6, 9, 12, 16, 25, 27+ floats per
  channel (mean relative RMSE over the scenes where every candidate is resolved, > 2 floors);
* checks: the **white furnace** (the constant scene's reference against π·L, z-scores); the **sunsky bake**
  (`rtfit.reference.environments.sunsky_environment`: the sky baked into a lat-long map plus a disc sun,
  its dense quadrature at the visible normals against Mitsuba's own sunsky emitter, relative bias of the mean
  ≤ `SUNSKY_BAKE_TOLERANCE`). The engine itself z-checks the exact row (the emitter's own quadrature).

Computed here without rendering (the reference: the dense quadrature of the environment, `irradiance_
quadrature`, which the engine's exact row validates against Mitsuba), on `NORMALS` Fibonacci normals over
the whole sphere (where SH orthogonality holds) for the shipped environments and the **lone disc suns**
``sun-<r>`` (`SUN_SIZES`, 45° elevation, E⊥ = π: no Mitsuba environment emitter, so no shipped scene):

* the ringing/windowing and order checks: SH L4 ≤ L2 ≤ ZH3 ≤ L1, L2 ≤ ZH3-lum ≤ L1 (`ORDER_CHECKS`), L3 = L2
  (Â_3 = 0), the fitted λ windows leave no negative irradiance, the NNLS cube no worse than Valve's, Ambient
  Dice and SG-ambient reproduce a constant; the SG ⊗ clamped-cosine approximation against quadrature;
  Grace Cathedral's L2 against Ramamoorthi & Hanrahan 2001's table (when the probe file is present);
* the **lightmap (hemisphere) bases** over bumped normals (`irradiance_hemisphere`: H-basis, RNM per frame);
* figures: the lone sun's profile against the angle from the sun, error maps over the sphere of normals.
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.fitting import smape
from rtfit.fitting.stats import concat_z_pairs, z_checks, z_pair
from rtfit.realtime.environment_bases import METHODS
from rtfit.realtime.irradiance_bases import fibonacci_sphere, sh_project_samples
from rtfit.realtime.spherical_gaussians import SG_COUNTS, sg_cosine_error, sg_sharpness
from rtfit.reference import environments as envs
from rtfit.reference import probe_maps, use_variant
from rtfit.reference.cache import RELATIVE_PRECISION_FLOOR
from rtfit.reference.variants import backend_of

from . import figures
from . import irradiance_hemisphere as hemisphere
from .audit_environment import ROW, ROWS, build_bases, evaluate_row, supersample_for
from .audit_irradiance_bases import SCENES
from .records import Check, Figure, Headline, Section
from .shipped import Study, StudyContext

__all__ = [
    "ORDER_CHECKS",
    "budget_winners",
    "max_rel",
    "order_checks",
    "rel_rmse",
    "rh2001_coefficients",
    "sphere_environments",
    "study",
    "with_floor",
]

FLOOR_DRAWS = 4
NORMALS = {True: 384, False: 2048}
"""Fibonacci normals of the sphere-of-normals comparison (``--quick``: True)."""
FIT_NORMALS = {True: 512, False: 2048}
MAP_ROWS = {True: 64, False: 128}
"""Rows of the study's own sunsky bakes (× 2 columns; the studio and overcast maps: the shipped 64)."""
CFG = {
    True: {"map_supersample": 2, "quadrature_min_rows": 256},
    False: {"map_supersample": 2, "quadrature_min_rows": 512},
}
SUN_SIZES = {True: (0.27, 10.0), False: (0.27, 2.0, 10.0, 20.0)}
SUN_ELEVATION_DEG = 45.0
SUNSKY_BAKE_TOLERANCE = 0.01
SG_ERROR_LAMBDAS = (1e-3, 0.1, 0.8, 10.0, 1000.0)
SG_ERROR_BOUND = 0.051  # max |S̃ − S|/S(λ, 1) measured over λ ∈ [1e-3, 1e3]: 0.0503 at λ = 0.8
ORDER_SLACK = 1e-3
"""Relative slack of the order checks on the sphere (the Fibonacci set approximates the sphere's integral)."""
ORDER_CHECKS = (
    ("sh-l4", "sh-l2"),
    ("sh-l2", "zh3"),
    ("zh3", "sh-l1"),
    ("sh-l2", "zh3-lum"),
    ("zh3-lum", "sh-l1"),
)
"""(better, worse) pairs that orthogonality guarantees over the sphere of normals: SH L_n is the least-squares
irradiance of its bands, and ZH3 keeps L1 and adds the projection of the L2 band onto one zonal harmonic."""
BASES = tuple(r for r in ROWS if not METHODS[r.method].exact)
STORAGE_BUDGETS = (4, 6, 9, 12, 16, 25, None)
"""Floats per channel of the budget table (None: 27 and more, no limit)."""
SUN_PROFILE_METHODS = (
    "cube-valve",
    "sh-l1",
    "sh-l1-geomerics",
    "sh-l2",
    "sh-l2-hann",
    "sh-l2-lambda",
    "sh-l4",
    "zh3-hallucinated",
)
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
ERROR_MAP_ROWS = 6


# ============================================================================================ metrics
def rel_rmse(x, r) -> float:
    """√(mean (x − r)²) / √(mean r²)."""
    return float(np.sqrt(np.mean((x - r) ** 2)) / max(np.sqrt(np.mean(r**2)), 1e-300))


def max_rel(x, r) -> float:
    """max |x − r| / max(r, 0.05·r̄), r̄ the mean |r| per channel."""
    rbar = np.maximum(np.mean(np.abs(r), axis=0, keepdims=True), 1e-300)
    return float(np.max(np.abs(x - r) / np.maximum(r, 0.05 * rbar)))


def with_floor(fn, x, r, sigma, seed=0) -> dict:
    """``fn(x, r)`` with its noise floor, the mean of ``fn(r, r + σ·N(0, 1))`` over `FLOOR_DRAWS` seeded draws
    (0 for σ = 0); resolved when the value exceeds twice the floor."""
    rng = np.random.default_rng(seed)
    val = fn(x, r)
    floor = float(np.mean([fn(r, r + sigma * rng.standard_normal(r.shape)) for _ in range(FLOOR_DRAWS)]))
    return {"value": val, "noise_floor": floor, "resolved": bool(val > 2 * floor)}


def point_metrics(x, r, sigma) -> dict:
    """rel_rmse, sMAPE, max_rel (with floors) and neg_frac of points (N, 3) against a reference (N, 3)."""
    sm = smape(x, r, sigma)
    return {
        "rel_rmse": with_floor(rel_rmse, x, r, sigma),
        "smape": {"value": sm.value, "noise_floor": sm.noise_floor, "resolved": bool(sm.resolved)},
        "max_rel": with_floor(max_rel, x, r, sigma),
        "neg_frac": {"value": float(np.mean(np.any(x < 0, axis=1))), "noise_floor": 0.0, "resolved": True},
    }


# ======================================================================== the engine's audits, read
def _shipped(ctx: StudyContext) -> list[tuple]:
    """(shipped scene, its audit's main case, that case's outcomes) in declaration order."""
    scenes = [s for s in SCENES if s.quick or not ctx.quick]
    out = []
    for s, audit in zip(scenes, ctx.audits, strict=False):  # a test may pass the first few
        case = next(c for c in audit.cases if not c.id.endswith("-lightmap"))
        out.append((s, case, audit.outcomes[case.id]))
    return out


def pixel_metrics(ctx: StudyContext) -> dict[str, dict[str, dict]]:
    """Scene → row → `point_metrics` over the case's pixels against the engine's Mitsuba reference."""
    out = {}
    for s, case, outcomes in _shipped(ctx):
        m = case.mask
        r, sig = case.reference.mean[m], case.reference.sigma()[m]
        out[s.name] = {row: point_metrics(o.image[m], r, sig) for row, o in outcomes.items() if row in ROW}
    return out


def budget_winners(metrics: dict[str, dict[str, dict]]) -> list[dict]:
    """Which stored basis wins at each storage budget (`STORAGE_BUDGETS`, floats per channel = storage / 3):
    the lowest mean relative RMSE among the bases that fit in it, and among those that use exactly that much
    (27+: ≥ 27), each mean over the environments where every candidate is resolved."""
    stored = [r.method for r in BASES if METHODS[r.method].storage]

    def means(rows):
        envs_ok = [e for e, per in metrics.items() if all(per[m]["rel_rmse"]["resolved"] for m in rows)]
        if not envs_ok:
            return {}
        return {m: float(np.mean([metrics[e][m]["rel_rmse"]["value"] for e in envs_ok])) for m in rows}

    out = []
    for b in STORAGE_BUDGETS:
        per = {m: METHODS[m].storage / 3 for m in stored}
        within = [m for m in stored if b is None or per[m] <= b + 1e-9]
        exact = [m for m in stored if (per[m] >= 27 if b is None else abs(per[m] - b) < 1e-9)]
        err, at = means(within), means(exact)
        best = min(err, key=err.__getitem__, default=None)
        best_exact = min(at, key=at.__getitem__, default=None)
        out.append(
            {
                "budget": "27+" if b is None else str(b),
                "best": best,
                "floats_per_channel": per[best] if best else None,
                "rel_rmse": err[best] if best else None,
                "best_at_budget": best_exact,
                "candidates": len(within),
            }
        )
    return out


def furnace_checks(ctx: StudyContext) -> list[Check]:
    """The constant scene (radiance 1): Mitsuba's irradiance against π at every visible normal (z-scores)."""
    pairs, spp = [], None
    for s, case, _ in _shipped(ctx):
        if s.name == "constant":
            spp = int(case.reference.spp)
            m = case.mask
            mean, se = case.reference.mean[m][:, 0], case.reference.stderr[m][:, 0]
            sig = case.reference.sigma()[m][:, 0]
            pairs.append(z_pair(np.full(len(mean), math.pi), mean, se, sig, RELATIVE_PRECISION_FLOOR))
    if not pairs:
        return []
    what = "white furnace: π·L vs Mitsuba irradiance"
    return [Check(**d) for d in z_checks(what, *concat_z_pairs(pairs), samples=spp)]


def sunsky_bake_checks(ctx: StudyContext, baked: dict) -> list[Check]:
    """The sky baked into a lat-long map plus a disc sun (the study's bake) against Mitsuba's own sunsky at
    the visible normals: relative bias of the mean irradiance, worst channel (± its standard error)."""
    out = []
    for s, case, _ in _shipped(ctx):
        env = baked.get(s.name)
        if env is None or env.kind != "sunsky":
            continue
        m = case.mask
        own, ose = case.reference.mean[m], case.reference.stderr[m]
        nrm = np.stack([case.channel_inputs[0][k] for k in ("nx", "ny", "nz")], axis=1)
        mine = envs.irradiance_quadrature(
            env, nrm, supersample_for(env, CFG[ctx.quick]), backend_of(ctx.variant)
        )
        keep = np.ones(3, bool)
        keep[env.params.get("sun_negative_channels", [])] = False  # rtfit's disc sun clamps them to 0
        bias = ((mine - own).mean(axis=0) / own.mean(axis=0))[keep]
        bias_se = (np.sqrt(np.sum(ose**2, axis=0)) / len(own) / own.mean(axis=0))[keep]
        k = int(np.argmax(np.abs(bias)))
        out.append(
            Check.magnitude_at_most(
                f"{s.name}: baked sky + disc sun vs Mitsuba's own sunsky: relative bias of the mean "
                f"irradiance over the visible normals, worst channel (± {bias_se[k]:.2g} statistical)",
                float(bias[k]),
                "bias",
                SUNSKY_BAKE_TOLERANCE,
            )
        )
    return out


# ====================================================================== the sphere of normals (no render)
def sphere_environments(ctx: StudyContext) -> dict:
    """Name → `Environment`: the shipped scenes' environments (the constant, the sunsky baked as map + disc
    sun, the shipped studio and overcast maps) and the lone disc suns."""
    out = {}
    mi = None
    for s, _, _ in _shipped(ctx):
        if s.name == "constant":
            out[s.name] = envs.constant_environment(1.0)
        elif s.name.startswith("sunsky-"):
            mi = mi or use_variant(ctx.variant)
            rows = MAP_ROWS[ctx.quick]
            out[s.name] = envs.sunsky_environment(mi, float(s.name[7:]), rows, 2 * rows)
        elif s.name in ("studio", "overcast"):
            img = (envs.studio_map if s.name == "studio" else envs.overcast_map)(64, 128)
            out[s.name] = envs.map_environment(s.name, s.label, s.name, img)
    for a in SUN_SIZES[ctx.quick]:
        out[f"sun-{a:g}"] = envs.sun_environment(a, SUN_ELEVATION_DEG)
    return out


def sphere_results(ctx: StudyContext, environments: dict) -> dict:
    """Name → {bases, normals, quadrature, evals: row → (N, 3), metrics: row → `point_metrics`}."""
    normals = fibonacci_sphere(NORMALS[ctx.quick])
    cfg = CFG[ctx.quick]
    backend = backend_of(ctx.variant)  # the dense quadratures on Dr.Jit (issue 33)
    out = {}
    for name, env in environments.items():
        b = build_bases(env, cfg, FIT_NORMALS[ctx.quick], backend)
        quad = envs.irradiance_quadrature(env, normals, supersample_for(env, cfg), backend)
        evals = {r.method: evaluate_row(r, b, normals, quad) for r in ROWS}
        zero = np.zeros_like(quad)
        out[name] = {
            "env": env,
            "bases": b,
            "normals": normals,
            "quadrature": quad,
            "evals": evals,
            "metrics": {m: point_metrics(x, quad, zero) for m, x in evals.items()},
        }
    return out


def _v(res: dict, name: str, method: str, key: str = "rel_rmse") -> float:
    return float(res[name]["metrics"][method][key]["value"])


def order_checks(res: dict) -> list[Check]:
    """`ORDER_CHECKS` on the sphere of normals, L3 = L2, NNLS ≤ Valve, λ leaves no ringing, the constant."""
    names = list(res)
    checks = []
    pairs = (*ORDER_CHECKS, ("cube-nnls", "cube-valve"))
    for better, than in pairs:
        bad = [n for n in names if _v(res, n, better) > _v(res, n, than) * (1 + ORDER_SLACK) + 1e-12]
        checks.append(
            Check(
                name=f"{better} no worse than {than} (rel. RMSE over the sphere of normals, every "
                f"environment, slack {ORDER_SLACK:g})",
                value=", ".join(bad) or "none worse",
                expected="none worse",
                passed=not bad,
            )
        )
    diff = max(abs(_v(res, n, "sh-l3") - _v(res, n, "sh-l2")) for n in names)
    checks.append(
        Check.at_most(
            "SH L3 irradiance equals L2 (Â_3 = 0: odd bands above 1 vanish): max |Δ rel. RMSE|", diff, "1e-12"
        )
    )
    lam_rows = [r.method for r in ROWS if "lam" in r.fitted_keys]
    neg = max(_v(res, n, m, "neg_frac") for n in names for m in lam_rows)
    checks.append(
        Check.zero(
            f"fitted λ window leaves no negative irradiance ({', '.join(lam_rows)}; max over "
            "environments, sphere of normals)",
            neg,
        )
    )
    if "constant" in res:
        for method in ("ambient-dice", *(f"sg{n}-ambient" for n in SG_COUNTS)):
            gap = abs(_v(res, "constant", method) - _v(res, "constant", "quadrature"))
            checks.append(
                Check.at_most(
                    f"{method} reproduces a constant environment (rel. RMSE equal to the exact row's)",
                    gap,
                    "1e-9",
                )
            )
    return checks


def sg_check() -> Check:
    """The SG ⊗ clamped-cosine approximation (Hill's shape, exact end values) against quadrature."""
    lams = sorted({*SG_ERROR_LAMBDAS, *(sg_sharpness(n) for n in SG_COUNTS)})
    err = sg_cosine_error(lams, np.linspace(-1.0, 1.0, 41))
    worst = int(np.argmax(err["max_rel"]))
    return Check.at_most(
        "SG ⊗ clamped cosine: Hill's shape with exact end values vs quadrature, max |S̃ − S|/S(λ, 1) "
        f"over λ ∈ {{{', '.join(f'{v:.3g}' for v in lams)}}} × 41 cosines "
        f"(worst λ = {err['lam'][worst]:.3g})",
        float(err["max_rel"][worst]),
        SG_ERROR_BOUND,
    )


def rh2001_coefficients(radiance_map, supersample: int = 2, frame=None) -> tuple[np.ndarray, float]:
    """The L2 radiance coefficients (9, 3) of a lat-long map of Grace Cathedral (rtfit's convention) in
    Ramamoorthi & Hanrahan 2001's frame (``frame``: the 3 × 3 map from world directions, default
    `probe_maps.RH2001_FROM_WORLD`), scaled by the one exposure s that fits `probe_maps.RH2001_GRACE_L2` best
    in least squares; returns (s·L, s)."""
    m = probe_maps.RH2001_FROM_WORLD if frame is None else np.asarray(frame, np.float64)
    d, w, L = envs.quadrature_samples(radiance_map, supersample)
    c = sh_project_samples(d @ m.T, w, L)
    s = float(np.sum(c * probe_maps.RH2001_GRACE_L2) / np.sum(c * c))
    return s * c, s


def published_checks(quick: bool) -> list[Check]:
    """Grace Cathedral's L2 coefficients against R&H 2001's table (when the probe file is present)."""
    if not envs.probe_available("grace"):
        return []
    try:
        grace = envs.probe_environment("grace", 64 if quick else None)
    except Exception as e:  # a file that does not read: the check fails, naming the file and why
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        return [
            Check(
                name="probe-grace: L2 vs Ramamoorthi & Hanrahan 2001",
                value=f"{envs.probe_dir() / envs.PROBES['grace'][0]}: does not read ({why})",
                expected="a probe that reads",
            )
        ]
    coeffs, scale = rh2001_coefficients(grace.radiance_map)
    diff = float(np.max(np.abs(coeffs - probe_maps.RH2001_GRACE_L2)))
    tol = probe_maps.RH2001_TOLERANCE
    return [
        Check.at_most(
            "probe-grace: L2 radiance coefficients vs Ramamoorthi & Hanrahan 2001's table (their frame "
            f"(x, y, z) = (w_y, w_z, −w_x), one fitted exposure ×{scale:.4g}): max |ΔL_lm| over 9 × RGB",
            diff,
            tol,
            note="(the table's 2-decimal rounding 0.005 + 0.005)",
        )
    ]


# ============================================================================================== figures
def sun_profile_figure(ctx: StudyContext, res: dict) -> Figure | None:
    """Irradiance against the angle between normal and sun for the smallest lone sun: the closed form (the
    quadrature of the disc) and each basis of `SUN_PROFILE_METHODS` at the same Fibonacci normals."""
    suns = [n for n in res if n.startswith("sun-")]
    if not suns:
        return None
    r = res[suns[0]]
    env = r["env"]
    ang = np.degrees(np.arccos(np.clip(r["normals"] @ np.asarray(env.sun.direction), -1, 1)))
    order = np.argsort(ang)
    peak = float(env.sun.irradiance[0])
    series = [
        {
            "x": ang[order],
            "y": r["quadrature"][order, 0] / peak,
            "label": "exact (disc quadrature)",
            "color": "k",
        }
    ]
    series += [
        {"x": ang[order], "y": r["evals"][m][order, 0] / peak, "label": m} for m in SUN_PROFILE_METHODS
    ]
    name = "figures/sun_profile.png"
    figures.line_plot(ctx.out_dir / name, "angle between normal and sun (°)", "E / E⊥", series)
    return Figure(
        file=name,
        section="study-irradiance-bases",
        caption=f"Irradiance under a lone sun ({env.label}) against the angle from the sun: the exact disc "
        "irradiance and each basis at the Fibonacci normals. SH ringing shows as negative values opposite "
        "the sun; the cube's curve depends on the normal's azimuth too (the spread of its points).",
    )


def error_map_figure(ctx: StudyContext, res: dict) -> Figure:
    """Relative error of every basis over the sphere of normals (lat-long) for up to `ERROR_MAP_ROWS`
    environments, against the dense quadrature: one mosaic image (`figures.mosaic_axes`; one axes per map
    drew 186 axes, ~20 CPU s of the quick run: issue 33)."""
    plt = figures.pyplot()
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    h, w = 24, 48
    uu, vv = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
    nrm = envs.uv_to_direction(uu, vv).reshape(-1, 3)
    show = list(res)[:ERROR_MAP_ROWS]
    backend = backend_of(ctx.variant)
    fig, ax, gap, band = figures.mosaic_axes(plt, len(BASES) + 1, h, w, len(show), 1.1 * (len(BASES) + 1), "")
    mosaic = np.ones(
        (len(show) * (h + band) + (len(show) - 1) * gap, (len(BASES) + 1) * w + len(BASES) * gap, 3)
    )
    cmap = plt.get_cmap("RdBu_r")
    norm = Normalize(vmin=-1, vmax=1)
    for i, name in enumerate(show):
        env, b = res[name]["env"], res[name]["bases"]
        lum_r = (
            envs.irradiance_quadrature(env, nrm, supersample_for(env, CFG[ctx.quick]), backend) @ LUMINANCE
        )
        y, x = figures.tile_origin(i, 0, h, w, gap, band)
        ax.text(x + w / 2, y + h / 2, name, ha="center", va="center", fontsize=6)
        for j, row in enumerate(BASES, start=1):
            xr = evaluate_row(row, b, nrm) @ LUMINANCE
            err = (xr - lum_r) / np.maximum(np.abs(lum_r), 0.05 * np.mean(np.abs(lum_r)))
            y, x = figures.tile_origin(i, j, h, w, gap, band)
            mosaic[y : y + h, x : x + w] = cmap(norm(err.reshape(h, w)))[..., :3]
            if i == 0:
                ax.text(x + w / 2, y - 1, row.method, ha="center", va="bottom", fontsize=5, clip_on=False)
    ax.imshow(mosaic, interpolation="nearest")
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, label="relative error (luminance)")
    name = "figures/error_maps.png"
    figures.save_figure(fig, ctx.out_dir / name)
    return Figure(
        file=name,
        section="study-irradiance-bases",
        caption="Relative irradiance error over the sphere of normals (lat-long: normal elevation vertical, "
        "azimuth horizontal, +Z up at the top) for each basis and environment (" + ", ".join(show) + "), "
        "against the dense quadrature; red too bright, blue too dark; relative to max(E, 5% of the mean E).",
    )


# ============================================================================================== tables
KEY_ROWS = ("cube-valve", "cube-nnls", "sh-l1", "sh-l1-geomerics", "sh-l2", "sh-l2-lambda", "sh-l4", "zh3")


def _table(metrics: dict[str, dict[str, dict]], rows=KEY_ROWS) -> str:
    head = "| environment | " + " | ".join(rows) + " | floor | neg. frac. sh-l2 |"
    lines = [head, "|" + "---|" * (len(rows) + 3)]
    for e, per in metrics.items():
        vals = " | ".join(f"{per[m]['rel_rmse']['value']:.3g}" for m in rows)
        floor = per["sh-l2"]["rel_rmse"]["noise_floor"]
        lines.append(f"| {e} | {vals} | {floor:.2g} | {per['sh-l2']['neg_frac']['value']:.3g} |")
    return "\n".join(lines)


def _budget_text(rows: list[dict]) -> str:
    def num(x, fmt="{:.3g}"):
        return "–" if x is None else fmt.format(x)

    lines = [
        "| floats per channel | best basis within the budget | its floats per channel | mean rel. RMSE "
        "| best basis using exactly this budget |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [
        f"| {r['budget']} | {r['best'] or 'none fits'} | {num(r['floats_per_channel'], '{:g}')} | "
        f"{num(r['rel_rmse'])} | {r['best_at_budget'] or '–'} |"
        for r in rows
    ]
    return (
        "From the method table (floats per channel = stored floats per probe / 3) and the audits' errors at "
        "the visible normals: the basis with the lowest relative RMSE, mean over the shipped scenes where "
        "every candidate is resolved (above 2 noise floors), among those that fit in the budget and among "
        "those using exactly that many floats (27+: 27 or more). Costs: the engine's cost table.\n\n"
        + "\n".join(lines)
    )


# ================================================================================================ study
def study(ctx: StudyContext) -> Study:
    """The irradiance-bases study (module docstring)."""
    pix = pixel_metrics(ctx)
    budgets = budget_winners(pix)
    environments = sphere_environments(ctx)
    res = sphere_results(ctx, environments)
    sph = {n: r["metrics"] for n, r in res.items()}
    hemi = []
    for n, r in res.items():
        ss = supersample_for(r["env"], CFG[ctx.quick])
        sigma = RELATIVE_PRECISION_FLOOR * np.abs(r["quadrature"])  # float32's floor: round-off ties
        hemi += hemisphere.environment_section(
            n, r["env"], r["normals"], r["quadrature"], sigma, r["quadrature"], r["bases"]["sh"], ss,
            backend_of(ctx.variant), point_metrics, ctx.quick,
        )  # fmt: skip
    checks = [
        *furnace_checks(ctx),
        *sunsky_bake_checks(ctx, environments),
        *order_checks(res),
        sg_check(),
        *hemisphere.checks(hemi),
        *published_checks(ctx.quick),
    ]
    lightmaps = hemisphere.write_fitted(ctx.out_dir, hemi, ctx)  # fitted/<environment>-lightmap.json
    figs = [f for f in (sun_profile_figure(ctx, res), error_map_figure(ctx, res)) if f]
    hfig = hemisphere.figure(ctx.out_dir, hemi, figures.line_plot)
    figs.append(
        Figure(file=hfig["file"], caption=hfig["caption"], section="study-irradiance-bases-hemisphere")
    )
    text = (
        "Relative RMSE of the irradiance at the visible normals against Mitsuba (the engine's references), "
        "per shipped scene, with the reference's noise floor and the fraction of pixels where plain SH L2 "
        "goes negative:\n\n" + _table(pix) + "\n\nThe same bases over the whole sphere of normals "
        f"({NORMALS[ctx.quick]} Fibonacci normals) against the dense quadrature of each environment (exact: "
        f"floor 0), with the lone disc suns ({', '.join(f'{a:g}°' for a in SUN_SIZES[ctx.quick])} angular "
        f"radius, {SUN_ELEVATION_DEG:g}° elevation, E⊥ = π) that no Mitsuba environment emitter holds:\n\n"
        + _table(sph)
    )

    def mean_of(m, where=pix):
        return float(np.mean([where[e][m]["rel_rmse"]["value"] for e in where]))

    headline = [
        Headline(label=f"{m}: mean rel. RMSE over the shipped scenes", value=mean_of(m))
        for m in ("cube-valve", "sh-l1", "sh-l2", "sh-l2-lambda")
    ] + [
        Headline(
            label="sh-l2 over the sphere under a lone 0.27° sun: rel. RMSE",
            value=_v(res, "sun-0.27", "sh-l2"),
        )
    ]
    return Study(
        sections=(
            Section(
                id="study-irradiance-bases", title="Bases per environment, whole sphere, lone suns", text=text
            ),
            Section(
                id="study-irradiance-bases-budgets",
                title="Which basis wins at each storage budget",
                text=_budget_text(budgets),
            ),
            Section(
                id="study-irradiance-bases-hemisphere",
                title="Lightmap bases on the hemisphere",
                text=hemisphere.section_text(hemi),
            ),
        ),
        figures=tuple(figs),
        checks=tuple(checks),
        headline=tuple(headline),
        notes=(
            "The lightmap texels baked per environment (H-basis, RNM; as shader literals): "
            + ", ".join(lightmaps),
            envs.PROBE_CREDITS,
        ),
        extra={"pixel_metrics": pix, "sphere_metrics": sph, "budgets": budgets, "hemisphere": hemi},
    )
