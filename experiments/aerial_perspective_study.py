"""The aerial-perspective family's own study for ``rtfit run aerial-perspective`` (issue 30 §1): what only
this family has.

The engine (`rtfit.experiments.engine_run`) audits the shipped scenes (`audit_aerial_perspective.SCENES`:
Mitsuba's sunsky over a grey ground seen through a scattering homogeneous fog bank, one scene per sun
elevation) exactly as ``rtfit audit`` audits a user's scene: the fog blend L₀·T + C·(1 − T) with C from the
sky (camera-source, horizon-flat, horizon-phase), given and fitted, against volpathmis, with costs, figures
per case and the fitted file. This study adds what needs no render of the scene (docs/aerial-perspective.md):

* **the error budget per sun elevation under the Nishita atmosphere + height fog**: the single-scattering
  integral through both with the sun attenuated by both
  (`rtfit.realtime.aerial_perspective.aerial_scattering`, float64 quadrature, its noise floor |Q(P) − Q(P/2)|)
  over a terrain view (flat ground and an oblique ridge: surfaces from 0.3 to 40 km), against the ladder of
  simplifications, each row adding one: (1) the source function frozen at the camera (``camera-source``), (2)
  the seed's horizon-averaged colour with the phase per pixel (``horizon-colour``, 000:2247-2254,
  002:224-290), (3) grey extinction (``horizon-grey``: the seed's whole model); the budget's parts are the
  increments (they sum to the total); one-at-a-time rows ``sun-frozen`` (sun attenuation alone) and
  ``grey-quadrature`` (grey extinction alone) show interactions. The sun goes below the horizon here (−2°,
  −4°), which Mitsuba's sunsky cannot;
* **the quadrature checked by independent values**: fog alone against a path-traced Mitsuba render
  (`rtfit.reference.aerial_perspective.render_fog_sun`: volpathmis, rtfit's fog medium and a distant sun)
  within its noise; the atmosphere alone against `rtfit.reference.nishita_sky.single_scattering_quadrature`;
  the limits (no fog, huge fog: in-scatter = the source function at the camera; the planet's shadow);
* **the shipped scenes' rows per sun elevation**: the engine's RMS error of each row over the mean reference.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.aerial_perspective import (
    FogLayer,
    aerial_scattering,
    fog_blend,
    horizon_colour,
    horizon_fog_colour,
    sun_direction,
    sun_transmittance_at,
)
from rtfit.realtime.nishita_sky import AtmosphereParams
from rtfit.reference.aerial_perspective import box_exit_distance, render_fog_sun
from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature

from . import figures as F
from .records import Check, Figure, Headline, Section
from .shipped import Study, StudyContext

__all__ = [
    "BUDGET_PARTS",
    "LADDER",
    "budget_entry",
    "config",
    "extreme_checks",
    "ladder_images",
    "mitsuba_check",
    "quadrature_checks",
    "scene_rows",
    "study",
]


def config(quick: bool) -> dict:
    """The budget's terrain view and quadrature (the experiment before the engine's values)."""
    return {
        "sun_elevations_deg": [60.0, 4.0, -4.0]
        if quick
        else [90.0, 60.0, 30.0, 15.0, 8.0, 4.0, 2.0, 0.0, -2.0, -4.0],
        "sun_azimuth_deg": 120.0,
        "camera_z_m": 50.0,
        "fog": FogLayer(2e-4, 4e-3, 0.6),
        "resolution": (20, 10) if quick else (80, 40),
        "panels": 24 if quick else 32,
        "check_spp": 1024 if quick else 16384,
        "check_passes": 8,
        "check_resolution": (8, 6) if quick else (24, 12),
    }


FOV_DEG = (80.0, (-10.0, 4.0))
"""Horizontal field of view and the elevation range of the view (degrees); the view axis is +y."""
RIDGE = (12000.0, 0.6)
"""The ridge: the vertical plane y = Y₀ + k·x (m), facing the camera (every pixel hits ground or ridge)."""
ALBEDO = 0.25
GREY_LEVEL_FLOOR = 0.01
"""Errors are normalised by the reference's mean radiance at that elevation, floored at this fraction of
the largest mean over the run's elevations (the sun below the horizon leaves a black reference)."""
LADDER = {
    "sun-frozen": "exact integral, sun attenuated as at the camera (1 alone: sun attenuation)",
    "camera-source": "blend, C = source function at the camera per direction (1)",
    "horizon-colour": "blend, C = seed's horizon average × per-pixel phase (1 + 2)",
    "horizon-grey": "blend, horizon colour, grey extinction: the seed's model (1 + 2 + 3)",
    "grey-quadrature": "exact integral with grey extinction (3 alone)",
}
BUDGET_PARTS = ("(1) source frozen at the camera", "(2) horizon-averaged colour", "(3) grey extinction")


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


def ladder_images(cfg: dict, elevation: float) -> dict:
    """The reference quadrature and every ladder row's image (H, W, 3) at one sun elevation (float64), the
    quadrature's error estimate |Q(P) − Q(P/2)| (``stderr``)."""
    atm, fog = AtmosphereParams(), cfg["fog"]
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
    L0 = [l0[..., c] for c in range(3)]
    horizon = horizon_colour(atm, max(elevation, -4.0))
    col_h = list(horizon_fog_colour(horizon[0], horizon[1], dirs @ np.asarray(sun), atm.mie_g))
    rows = {
        "exact": [L0[c] * q["T"][c] + q["S"][c] for c in range(3)],
        "sun-frozen": [L0[c] * q["T"][c] + q["S_sun_frozen"][c] for c in range(3)],
        "camera-source": fog_blend(L0, q["T"], q["J_cam"]),
        "horizon-colour": fog_blend(L0, q["T"], col_h),
        "horizon-grey": fog_blend(L0, q["T_grey"], col_h),
        "grey-quadrature": [L0[c] * q["T_grey"][c] + q["S_grey"][c] for c in range(3)],
    }
    images = {k: np.stack(v, -1) for k, v in rows.items()}
    half = np.stack([L0[c] * q_half["T"][c] + q_half["S"][c] for c in range(3)], -1)
    return {"images": images, "stderr": np.abs(images["exact"] - half), "T_mean": float(np.mean(q["T"][1]))}


def budget_entry(elevation: float, images: dict, norm: float) -> dict:
    """The error budget at one elevation: each row's RMS error over ``norm``, the ladder's increments."""
    ref = images["exact"]
    errs = {k: float(np.sqrt(np.mean((images[k] - ref) ** 2)) / norm) for k in LADDER}
    ladder = [errs["camera-source"], errs["horizon-colour"], errs["horizon-grey"]]
    parts = [ladder[0], ladder[1] - ladder[0], ladder[2] - ladder[1]]
    return {
        "sun_elevation_deg": elevation,
        "rel_rms": errs,
        "parts": dict(zip(BUDGET_PARTS, parts, strict=True)),
        "total": ladder[2],
        "sun_attenuation_alone": errs["sun-frozen"],
        "grey_alone": errs["grey-quadrature"],
        "grey_interaction": parts[2] - errs["grey-quadrature"],
    }


def ladder_checks(elevation: float, lad: dict, level: float) -> list[Check]:
    """Every row finite; the quadrature converged; below −2° the planet's shadow leaves the view black."""
    ref = lad["images"]["exact"]
    finite = all(bool(np.all(np.isfinite(v))) for v in lad["images"].values())
    conv = float(np.max(lad["stderr"]) / level)
    out = [
        Check.holds(f"sun {elevation:g}°: every row finite (no NaN/Inf)", finite),
        Check.at_most(
            f"sun {elevation:g}°: quadrature converged, max |Q(P) − Q(P/2)| / mean level", conv, "1e-3"
        ),
    ]
    if elevation <= -2.0:
        dark = float(np.max(np.abs(ref)))
        name = f"sun {elevation:g}°: the planet occludes the sun at every scattering point and surface"
        out.append(Check.exactly(name, dark, "0"))
    return out


def mitsuba_check(cfg: dict, variant: str, seed: int, cache_dir) -> dict:
    """The fog-only Mitsuba render (independent passes) and the quadrature of the same rays."""
    atm0 = AtmosphereParams(rayleigh_scale=0.0, mie_scale=0.0)
    fog = cfg["fog"]
    sun = sun_direction(30.0, cfg["sun_azimuth_deg"])
    w, h = cfg["check_resolution"]
    A, E = np.meshgrid(np.radians(np.linspace(-40.0, 40.0, w)), np.radians(np.linspace(-8.0, 8.0, h)))
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
    return {
        "mean": means.mean(0),
        "stderr": means.std(0, ddof=1) / math.sqrt(len(passes)),
        "quadrature": np.stack(q["S"], -1),
    }


def quadrature_checks(check: dict) -> list[Check]:
    """The fog-only quadrature against the Mitsuba render (z-scores), and the atmosphere-only quadrature
    against `rtfit.reference.nishita_sky.single_scattering_quadrature`."""
    m, se, q = check["mean"], np.maximum(check["stderr"], 1e-30), check["quadrature"]
    bias = float(np.sum(m - q) / math.sqrt(float(np.sum(se**2))))
    med = float(np.median(np.abs((m - q) / se)))
    atm = AtmosphereParams()
    spec = library_atmosphere(sun_elevation_deg=20.0, viewer_altitude_m=50.0)
    A, E = np.meshgrid(np.radians([0.0, 150.0]), np.radians([2.0, 10.0, 60.0]))
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    ref = single_scattering_quadrature(spec, d, steps=2000)
    r0 = atm.planet_radius_m + 50.0
    mu = d[:, 2]
    dist = -r0 * mu + np.sqrt(r0 * r0 * mu * mu + atm.top_radius_m**2 - r0 * r0)
    s = aerial_scattering(
        NUMPY_OPS, 50.0, d[:, 0], d[:, 1], d[:, 2], dist,
        atmosphere=atm, sun=sun_direction(20.0, 90.0), fog=FogLayer(0.0, 1e-3, 0.0), panels=32,
    )["S"]  # fmt: skip
    rel = float(np.max(np.abs(np.stack(s, -1) / ref - 1.0)))
    return [
        Check.magnitude_at_most(
            "fog-only quadrature vs path-traced Mitsuba (volpathmis, rtfit_expfog, distant sun): "
            "summed bias in units of its standard error",
            bias,
            "z",
            "4",
        ),
        Check.at_most(
            "fog-only quadrature vs Mitsuba: median |z| per direction (t with passes − 1 dof: ≈ 0.7)",
            med,
            "1.2",
        ),
        Check.at_most(
            "atmosphere-only quadrature (fog b = 0, sky rays to the top) vs nishita-sky's reference "
            "quadrature, max relative difference",
            rel,
            "2e-3",
        ),
    ]


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
            huge = name.startswith("huge") and e > 0
            # 4× the panels where the limit is compared (t = D·u³ must resolve a 1 m mean free path)
            q = aerial_scattering(
                NUMPY_OPS, cfg["camera_z_m"], dirs[:, 0], dirs[:, 1], dirs[:, 2], dist,
                atmosphere=atm, sun=sun, fog=fog, panels=4 * cfg["panels"] if huge else 8,
            )  # fmt: skip
            ok = bool(np.all(np.isfinite(np.concatenate([np.ravel(v) for k in q for v in q[k]]))))
            out.append(Check.holds(f"{name}, sun {e:g}°, horizontal rays: finite", ok))
            if huge:
                s, j = np.stack(q["S"])[:, :2], np.stack(q["J_cam"])[:, :2]  # the level rays: J constant
                rel = float(np.max(np.abs(s / j - 1.0)))
                out.append(
                    Check.at_most(
                        "huge fog, level rays: in-scatter = the source function at the camera", rel, "1e-3"
                    )
                )
            if e < 0:
                mx = float(np.max(np.abs(np.stack(q["S"]))))
                out.append(
                    Check.exactly(f"{name}, sun {e:g}°: no single scattering (planet shadow)", mx, "0")
                )
    return out


def scene_rows(audits) -> list[dict]:
    """Per shipped scene's aerial case: the sun's elevation and each row's RMS error over the mean reference
    (the engine's images on the case's pixels)."""
    out = []
    for r in audits:
        for c in r.cases:
            sun = c.parameters.get("sun_direction")
            if sun is None or not c.mask.any():
                continue
            ref = c.reference.mean[c.mask]
            level = max(float(np.mean(np.abs(ref))), 1e-30)
            errs = {
                row: float(np.sqrt(np.mean((o.image[c.mask] - ref) ** 2)) / level)
                for row, o in r.outcomes[c.id].items()
                if o.image is not None
            }
            out.append({"case": c.id, "sun_elevation_deg": math.degrees(math.asin(sun[2])), "rel_rms": errs})
    return sorted(out, key=lambda s: -s["sun_elevation_deg"])


def budget_figure(out: Path, budget: list[dict]) -> Figure:
    plt = F.pyplot()
    fig, ax = plt.subplots(figsize=(max(6.0, 0.7 * len(budget) + 2), 4.0))
    x = np.arange(len(budget))
    pos, neg = np.zeros(len(budget)), np.zeros(len(budget))
    for k, part in enumerate(BUDGET_PARTS):
        v = np.array([b["parts"][part] for b in budget])
        ax.bar(x, v, bottom=np.where(v >= 0, pos, neg), color=("tab:orange", "tab:blue", "tab:green")[k],
               label=part)  # fmt: skip
        pos, neg = pos + np.maximum(v, 0), neg + np.minimum(v, 0)
    ax.plot(x, [b["total"] for b in budget], "k_", markersize=18, mew=2, label="total (= sum of the parts)")
    ax.plot(
        x, [b["sun_attenuation_alone"] for b in budget], "v", color="tab:red", label="sun attenuation alone"
    )
    ax.plot(x, [b["grey_alone"] for b in budget], "^", color="tab:purple", label="grey extinction alone")
    ax.axhline(0.0, color="grey", lw=0.5)
    ax.set_ylim(top=3.0 * max([b["total"] for b in budget] + [float(np.max(pos)), 1e-3]))
    ax.set_xticks(x, [f"{b['sun_elevation_deg']:g}°" for b in budget])
    ax.set_xlabel("sun elevation")
    ax.set_ylabel("RMS error / mean reference radiance")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title("aerial perspective: error budget of the fog blend per sun elevation")
    (out / "figures").mkdir(parents=True, exist_ok=True)
    path = F.save_figure(fig, out / "figures" / "error_budget.png")
    return Figure(
        file=f"figures/{path.name}",
        section="budget",
        caption="Stacked error budget per sun elevation (Nishita atmosphere + height fog, quadrature): the "
        "increments of the ladder (1) source function frozen at the camera → (2) the seed's horizon-averaged "
        "colour → (3) grey extinction; the parts sum to the total (bar), negative increments below 0. "
        "Markers: each simplification alone (sun attenuation, grey extinction).",
    )


def _budget_table(budget: list[dict]) -> str:
    head = "| sun | " + " | ".join(BUDGET_PARTS) + " | total | sun alone | grey alone |\n"
    head += "|---" * (len(BUDGET_PARTS) + 4) + "|\n"
    return head + "\n".join(
        f"| {b['sun_elevation_deg']:g}° | " + " | ".join(f"{v:.3g}" for v in b["parts"].values())
        + f" | {b['total']:.3g} | {b['sun_attenuation_alone']:.3g} | {b['grey_alone']:.3g} |"
        for b in budget
    )  # fmt: skip


def _scene_table(rows: list[dict]) -> str:
    names = sorted({k for s in rows for k in s["rel_rms"]})
    head = "| scene | sun | " + " | ".join(names) + " |\n" + "|---" * (len(names) + 2) + "|\n"
    return head + "\n".join(
        f"| {s['case']} | {s['sun_elevation_deg']:.3g}° | "
        + " | ".join(f"{s['rel_rms'][n]:.3g}" if n in s["rel_rms"] else "–" for n in names) + " |"
        for s in rows
    )  # fmt: skip


def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run aerial-perspective`` (module docstring), beside the engine's audits."""
    cfg = config(ctx.quick)
    ladders = {e: ladder_images(cfg, e) for e in cfg["sun_elevations_deg"]}
    norms = {e: float(np.mean(lad["images"]["exact"])) for e, lad in ladders.items()}
    floor = GREY_LEVEL_FLOOR * max(max(norms.values()), 1e-30)
    budget, checks = [], []
    for e, lad in ladders.items():
        b = budget_entry(e, lad["images"], max(norms[e], floor))
        budget.append({**b, "mean_reference_radiance": norms[e], "mean_transmittance_G": lad["T_mean"]})
        checks += ladder_checks(e, lad, max(norms[e], floor))
    checks += quadrature_checks(mitsuba_check(cfg, ctx.variant, ctx.seed, ctx.cache_dir))
    checks += extreme_checks(cfg)
    scenes = scene_rows(ctx.audits)
    sections = [
        Section(
            id="budget",
            title="What each simplification of the fog blend costs (Nishita atmosphere + height fog)",
            text="L = L₀·T + C·(1 − T) is exact when the source function J = E₀·T_sun·σ_s·P/σ_t is constant "
            "along the view ray. Under the Nishita atmosphere and a height fog (b = "
            f"{cfg['fog'].density:g} /m, c = {cfg['fog'].falloff:g} /m, g = {cfg['fog'].g:g}; camera at "
            f"{cfg['camera_z_m']:g} m over a terrain view) it is not: the sun is attenuated differently at "
            "each point (strongly near sunset), the atmosphere/fog mixture changes with height, and the "
            "extinction is chromatic. The ladder adds one simplification per row; the parts are its "
            "increments (RMS error over the mean reference radiance, floored at 1 % of the largest mean: a "
            "sun below the horizon leaves a black view). Reference: float64 quadrature (Gauss–Legendre "
            "panels, t = D·u³), its noise floor |Q(P) − Q(P/2)|.\n\n" + _budget_table(budget),
        )
    ]
    if scenes:
        sections.append(
            Section(
                id="scenes-by-sun",
                title="The shipped scenes' rows per sun elevation",
                placement="after_results",
                text="RMS error over the mean reference radiance of each row on the fog bank's pixels (the "
                "engine's images, Mitsuba's sunsky, volpathmis reference):\n\n" + _scene_table(scenes),
            )
        )
    worst = max(budget, key=lambda b: b["total"])
    notes = (
        f"{sum(c.passed for c in checks)}/{len(checks)} study checks pass. "
        + " ".join(
            f"sun {b['sun_elevation_deg']:g}°: total {b['total']:.3g} ("
            + ", ".join(f"{k.split(')')[0]})={v:.3g}" for k, v in b["parts"].items()) + ")."
            for b in budget
        ),
    )  # fmt: skip
    return Study(
        sections=tuple(sections),
        figures=(budget_figure(Path(ctx.out_dir), budget),),
        checks=tuple(checks),
        notes=notes,
        headline=(
            Headline(
                label=f"seed's fog blend, worst total error (sun {worst['sun_elevation_deg']:g}°)",
                value=worst["total"],
            ),
        ),
        extra={"error_budget": budget, "scenes_by_sun": scenes},
    )
