"""The Nishita-sky study's report: its Markdown tables and figures (a leaf of `nishita_sky_study`, which
computes every number; nothing here computes one)."""

from __future__ import annotations

import numpy as np

from rtfit.realtime.nishita_sky import METHODS
from rtfit.reference.nishita_sky import DISC_MAX_DEG

from . import figures as F
from .records import Figure, Section

__all__ = ["figures", "sections"]


def _v(d, key="rel_mae") -> float:
    return d[key]["value"] if d and key in d else float("nan")


def _vf(d, key) -> str:
    return f"{d[key]['value']:.3g} ({d[key]['noise_floor']:.2g})" if d and key in d else "—"


def _f3(v) -> str:
    return ", ".join(f"{x:.3g}" for x in v)


def _table(head: list[str], rows: list[list]) -> str:
    return "\n".join(
        ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        + ["| " + " | ".join(map(str, r)) + " |" for r in rows]
    )


def _pv(P: dict, k: str) -> str:
    """A fitted value ± its stderr (none shown at a bound: a constrained optimum)."""
    if k not in P:
        return "—"
    se = P[k]["stderr"]
    return f"{P[k]['value']:.3g}" + (f" ± {se:.2g}" if se is not None and not P[k]["at_bound"] else "")


def sections(cfg, sks, parts) -> list[Section]:
    """The study's sections from its parts (`nishita_sky_study.study`)."""
    main, alt, spectral, sweep, costs, bench = (
        parts[k] for k in ("main", "alt", "spectral", "sweep", "costs", "bench")
    )
    rows = [
        [
            f"{r['sun']:g}°",
            r["row"],
            _vf(r.get("ss"), "rel_mae"),
            _vf(r.get("ss"), "tonemapped_rmse"),
            _vf(r.get("ms"), "rel_mae"),
            _vf(r.get("ms"), "tonemapped_rmse"),
        ]
        for r in main["rows"]
        if r["row"] != "quadrature" and ("ms" in r or "ss" in r)
    ] + [
        [f"{r['sun']:g}°, viewer {r['altitude_m']:g} m", r["row"], _vf(r["ss"], "rel_mae"), "—", "—", "—"]
        for r in alt["rows"]
    ]
    by = {(r["sun"], r["row"]): r for r in main["rows"]}
    irr = {r["sun"]: r for r in main["irradiance"]}
    fits = []
    for s in sks:
        P, i = (s.fit or {}).get("parameters", {}), irr[s.elev]
        at = ", ".join(k for k, p in P.items() if p["at_bound"]) or "—"
        seed, fitted = (
            _v(by[(s.elev, "nishita-seed")].get("ms")),
            _v(by.get((s.elev, "nishita-fitted"), {}).get("ms")),
        )
        fits.append(
            [
                f"{s.elev:g}°",
                *(_pv(P, k) for k in ("rayleigh_scale", "mie_scale", "mie_g", "ambient")),
                at,
                f"{seed:.3g} → {fitted:.3g}",
                _f3(np.asarray(i["ms"]) / np.maximum(i["ss"], 1e-30)),
                _f3(np.asarray(i["seed"]) / np.maximum(i["ss"], 1e-30)),
            ]
        )
    out = [
        Section(
            "ss-reference",
            "Single scattering, the quadrature, sunsky and the spectral sky",
            "The engine compares every row with the multiple-scattering sky (all orders: the model's "
            "physical "
            "error). The study renders the same directions with single scattering (max_depth 2, the same "
            "samples: "
            "the texture's numerical error), checked by the independent float64 quadrature on every "
            f"{cfg['quadrature_stride'][0]}×{cfg['quadrature_stride'][1]}th pixel ({cfg['quadrature_steps']} "
            f"steps; robust z spread {parts['spread']:.2f}). Mitsuba's sunsky (Hosek–Wilkie, turbidity 3, "
            "sun "
            "above the horizon) is scaled by one least-squares factor against the MS sky; nishita-spectral "
            "(16 λ "
            "→ sRGB) is the seed setting's spectral sky; nishita-fitted is the engine's fitted row. "
            "Relative MAE "
            "Σ|Δ|/Σ|ref| and the tone-mapped RMSE (t(10x) = 10x/(1 + 10x)), each with its noise floor:\n\n"
            + _table(
                [
                    "sun",
                    "row",
                    "vs SS rel. MAE",
                    "vs SS tone-mapped RMSE",
                    "vs MS rel. MAE",
                    "vs MS tone-mapped RMSE",
                ],
                rows,
            ),
            "after_results",
        ),
        Section(
            "twilight",
            "Artist fits and twilight",
            "The engine's fits of nishita-fitted (unweighted least squares of the image through the kernel "
            "text) with the horizontal sky irradiance ratios of this run's references: all orders / single "
            "scattering (the physics the ambient term stands for) and seed texture / single scattering (its "
            "numerical error). A parameter on a bound is a constrained optimum (its stderr means nothing). "
            "In "
            "twilight the seed's 32 layers put the Earth's shadow inside thick layers and the Mie layer "
            "lies in "
            "the shadow (g undetermined): use n ≥ 128 there (docs/nishita-sky.md).\n\n"
            + _table(
                [
                    "sun",
                    "s_R",
                    "s_M",
                    "g",
                    "A",
                    "at a bound",
                    "rel. MAE vs MS: seed → fitted",
                    "E_MS / E_SS (R, G, B)",
                    "E_seed / E_SS",
                ],
                fits,
            ),
            "after_results",
        ),
        Section(
            "sweep",
            "Layers, texture and table against the quadrature",
            "Σ|Δ|/Σ|q| against the point-sun quadrature (noise-free) and the measured whole-texture build "
            "time "
            "on this run's backend: the layer count, not the texture size, sets the error.\n\n"
            + _table(
                ["sun", "setting", "rel. MAE vs quadrature", "build (ms)"],
                [
                    [f"{r['sun_elevation_deg']:g}°", _conf(r), f"{r['rel_mae']:.3g}", f"{r['build_ms']:.3g}"]
                    for r in sweep
                ],
            )
            + "\n\nPer-pixel lookup (texture + phase + sun disc) and whole-texture build of each setting, "
            "as an "
            "engine runs them (the engine's cost of a row times its kernel, which rebuilds the texture):\n\n"
            + _table(
                ["setting", "lookup (ns/pixel)", "build (ms, Dr.Jit)", "build (ms, NumPy; full runs)"],
                [
                    [
                        METHODS[c["method"]].label,
                        f"{c['lookup_ns_per_pixel']:.3g}",
                        f"{c['build_ms']:.3g}",
                        f"{c.get('numpy_build_ms', float('nan')):.4g}",
                    ]
                    for c in costs
                ],
            ),
            "after_results",
        ),
    ]
    if main["disc"]:
        out.append(
            Section(
                "disc-sun",
                "The sun's disc as its own term",
                "The real-time sky is a point-sun model; Mitsuba renders the 4.675 mrad disc. On the "
                "quadrature's pixels (noise-free): Σ|Q_point − Q_disc| / Σ Q_disc (G), the same on the low "
                "anti-solar sky (< 15°, > 90° from the sun's azimuth), each model's error against the "
                "disc-sun SS with the disc's share, and the disc's effect in σ of this run's SS sum (≥ 4 σ "
                f"resolves it); sun ≤ {DISC_MAX_DEG:g}°.\n\n"
                + _table(
                    ["sun", "disc term (G)", "low anti-solar (G)", "model error vs disc SS", "disc effect"],
                    main["disc"],
                ),
                "after_results",
            )
        )
    if spectral:
        out.append(_spectral_section(spectral))
    if bench:
        out.append(
            Section(
                "reference-bench",
                "The reference estimators side by side",
                "\n".join(
                    f"- {b['what']}: {b['drjit_Mray_s']:.3g} Mray/s, × {b['vs_native_grid']:.3g} of "
                    "Mitsuba's grid, "
                    f"efficiency × {b.get('efficiency_vs_box', float('nan')):.3g} of the box majorant's"
                    for b in bench
                ),
                "after_results",
            )
        )
    return out


# ============================================================================================ figures
def figures(ctx, sks, irr, sweep) -> list[Figure]:
    out, figs = ctx.out_dir, []
    for s in sks:
        name = f"figures/{s.case}-ss.png"
        F.image_comparison(
            out / name,
            s.ss[0],
            [(METHODS[m].label, s.images[m]) for m in ("nishita-seed", "nishita-fine")],
            s.mask,
            error_scale=float(s.ss[0].mean()),
            title=f"sun {s.elev:g}°, SS reference",
        )
        figs.append(
            Figure(
                name,
                f"Sun {s.elev:g}°: Mitsuba single-scattering sky, the RGB textures, their signed "
                "error over the mean sky radiance.",
                "results",
            )
        )
    plt = F.pyplot()
    cols = [
        ("ss", "nishita-seed", "seed vs SS"),
        ("ss", "nishita-fine", "fine vs SS"),
        ("ms", "nishita-seed", "seed vs MS"),
        ("ms", "nishita-fitted", "fitted vs MS"),
    ]
    fig, axes = plt.subplots(len(sks), 4, figsize=(10.4, 2.0 * len(sks) + 0.6), squeeze=False)
    im = None
    for i, s in enumerate(sks):
        for j, (kind, m, title) in enumerate(cols):
            ref = getattr(s, kind)[0].mean(axis=-1)
            rel = np.where(s.mask, (s.images[m].mean(axis=-1) - ref) / np.maximum(np.abs(ref), 1e-12), 0.0)
            im = axes[i, j].imshow(
                rel, cmap="RdBu_r", vmin=-0.5, vmax=0.5, aspect="auto", extent=(0, 360, 0, 90)
            )
            axes[i, j].set_title(f"sun {s.elev:g}°: {title}", fontsize=8)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.8, label="relative error")
    F.save_figure(fig, out / "figures/relative_error_maps.png")
    figs.append(
        Figure(
            "figures/relative_error_maps.png",
            "Relative error (approximation − reference)/reference "
            "(x: azimuth from the sun, y: elevation; RGB mean, ±50 %).",
            "results",
        )
    )
    prof, hor = [], []
    for s in sks:
        el, az, p = (
            np.degrees(np.arcsin(s.dirs[:, 0, 2])),
            np.degrees(np.arctan2(s.dirs[-1, :, 1], s.dirs[-1, :, 0])),
            f"sun {s.elev:g}°",
        )
        for kind in ("ss", "ms"):
            mean, se = getattr(s, kind)
            prof.append(
                {
                    "x": el,
                    "y": mean[:, 0, 1],
                    "yerr": 2 * se[:, 0, 1],
                    "style": "points",
                    "label": f"Mitsuba {kind.upper()}",
                    "panel": p,
                }
            )
            hor.append(
                {
                    "x": az,
                    "y": mean[-1, :, 1],
                    "yerr": 2 * se[-1, :, 1],
                    "style": "points",
                    "label": f"Mitsuba {kind.upper()}",
                    "panel": p,
                }
            )
        prof.append({"x": el, "y": s.images["nishita-seed"][:, 0, 1], "label": "Nishita seed", "panel": p})
        hor.append({"x": az, "y": s.images["nishita-seed"][-1, :, 1], "label": "Nishita seed", "panel": p})
        hor.append(
            {
                "x": az,
                "y": s.images["nishita-fitted"][-1, :, 1],
                "label": "Nishita fitted",
                "panel": p,
                "ls": "--",
            }
        )
    panels = [f"sun {s.elev:g}°" for s in sks]
    F.line_plot(
        out / "figures/profiles.png",
        "elevation (°), towards the sun",
        "radiance (G)",
        prof,
        panels=panels,
        y_log=True,
    )
    F.line_plot(
        out / "figures/horizon_profiles.png",
        "azimuth from the sun (°)",
        "radiance (G)",
        hor,
        panels=panels,
        y_log=True,
    )
    ser = [
        {
            "x": [r["sun"] for r in irr],
            "y": [r[k][1] for r in irr],
            "style": "points",
            "label": f"Mitsuba {k.upper()}",
        }
        for k in ("ss", "ms")
    ]
    ser.append({"x": [r["sun"] for r in irr], "y": [r["seed"][1] for r in irr], "label": "Nishita seed"})
    F.line_plot(
        out / "figures/irradiance.png",
        "sun elevation (°)",
        "sky irradiance on a horizontal plane (G)",
        ser,
        y_log=True,
    )
    figs += [
        Figure(
            "figures/profiles.png",
            "Zenith-to-horizon profile towards the sun (G): Mitsuba SS/MS (±2σ), the seed sky.",
            "results",
        ),
        Figure(
            "figures/horizon_profiles.png",
            "Horizon row (G) around the azimuth: Mitsuba (±2σ), seed and fitted.",
            "results",
        ),
        Figure(
            "figures/irradiance.png",
            "Sky irradiance on a horizontal plane (sun excluded) vs sun elevation.",
            "results",
        ),
    ]
    for e in sorted({r["sun_elevation_deg"] for r in sweep}, reverse=True):
        pts = [
            {"x": r["build_ms"], "y": r["rel_mae"], "label": _conf(r)}
            for r in sweep
            if r["sun_elevation_deg"] == e
        ]
        name = f"figures/pareto_build_e{e:g}.png".replace("-", "m")
        F.pareto_plot(
            out / name,
            pts,
            "whole-texture build time (ms, measured)",
            "relative MAE vs SS quadrature",
            title=f"sun {e:g}°",
        )
        figs.append(
            Figure(
                name,
                f"Sun {e:g}°: layers / texture / table / √ mapping vs Σ|Δ|/Σ|q| against the "
                "independent single-scattering quadrature and the measured build time.",
                "results",
            )
        )
    return figs


def _conf(r) -> str:
    sqrt = " √" if r["mapping"] == "sqrt" else ""
    lab = f"n{r['layers']} {r['width']}×{r['height']} t{r['table_size']}{sqrt}"
    return lab + (" (seed)" if r["seed"] else "")


def _spectral_section(sp) -> Section:
    wb = sp["white_balance"]
    f3 = lambda v: ", ".join(f"{x:.4g}" for x in v)  # noqa: E731
    pct = lambda v: " / ".join(f"{100 * x:.2g}" for x in v[:3]) + f" ({100 * v[3]:.2g})"  # noqa: E731
    lines = [
        "| sun | quadrature vs Mitsuba, z of Σ | Nishita spectral vs ref. rel. MAE (floor) | Nishita "
        "spectral vs "
        "quadrature, % | of which the 16-λ conversion, % | RGB Nishita vs RGB quadrature, % | RGB (3 λ) vs "
        "spectral "
        "model, % | Σ RGB / Σ spectral |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sp["rows"]:
        rm = r["spectral_vs_reference"]["rel_mae"]
        lines.append(
            f"| {r['sun']:g}° | {', '.join(f'{v:.2f}' for v in r['zsum_quadrature_vs_reference'])} | "
            f"{rm['value']:.3g} ({rm['noise_floor']:.3g}) | {pct(r['nishita_spectral_vs_quadrature'])} | "
            f"{pct(r['conversion_16_lambda_vs_film'])} | {pct(r['nishita_rgb_vs_rgb_quadrature'])} | "
            f"{pct(r['rgb_model_vs_spectral_model'])} | {f3(r['rgb_over_spectral_sum'])} |"
        )
    return Section(
        "spectral",
        "Spectral reference",
        f"Mitsuba's spectral variant ({sp['size'][0]}×{sp['size'][1]}: "
        "β_R ∝ λ⁻⁴, grey Mie, 5778 K sun, CIE 1931 → linear sRGB as its film) against the spectral "
        "quadrature; "
        f"the film does not white-balance (the sun becomes {f3(wb['mitsuba_film_srgb_of_sun'])}), so the "
        "reference "
        "and the quadrature are multiplied by the von Kries factors E₀/film(sun) = "
        f"({f3(wb['von_kries_factors'])}) "
        "of the real-time `spectral_to_srgb` (real-time ÷ 106.75 over Mitsuba before the balance: "
        f"{f3(wb['realtime_over_mitsuba_unbalanced'])}).\n\n" + "\n".join(lines) + "\n\nRobust per-pixel z "
        f"spread, spectral quadrature vs Mitsuba: {sp['robust_z_spread']:.2f}.",
        "after_results",
    )
