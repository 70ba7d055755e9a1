"""The light-cones family's own study for ``rtfit run light-cones`` (issue 30 §1): what only this family has.

The engine (`rtfit.experiments.engine_run`) audits the shipped scenes (`audit_light_cones.SCENES`: a street
lamp — a spot 6 m up pointing down, cutoff 30°, beam width 22.5°, I = 100 W/sr — in a non-absorbing
homogeneous medium box whose floor is the cone's base, seen beside, oblique, inside, up and down the axis,
one scene per view and σ_t) exactly as ``rtfit audit`` audits a user's scene: the seed's shell (both faces,
front faces) and §1's integral over the chord with the scene's values and fitted, the quadrature as the
exact row (its z-checks against the reference), costs, figures per case and the fitted file. This study adds:

* **where the shell's error comes from**: per density (the views pooled), the relative bias
  Σ(model − reference)/Σreference and the RMS error over the mean reference per bin of the view ray's chord
  length through the shell's cone over the cone's length L (`CHORD_LENGTH` at θ_½), the RMS error per view,
  and the correlation of each row's log error with log chord length; the fitted exponents (p, q) and the
  fitted chord level K over the physical σ_s·I/(4π) per scene;
* **the kernels at their extremes** (no rendering): non-finite float32 outputs of every method on random
  inputs per extreme set (camera inside the cone, along the axis, grazing the shell, θ_c = 1e-4 and 1.5 rad,
  L = 1e-3 m, anywhere), and the quadrature's limits σ → 0 (linear in σ) and a dense medium;
* its checks: no non-finite output, the quadrature's limits, and Mitsuba's reference exactly 0 on the
  compared pixels whose ray misses the cutoff cone (the quadrature's 0 there: the spot's profile has
  compact support).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.light_cones import CHORD_LENGTH, METHODS
from rtfit.reference.single_scattering import spot_single_scattering

from . import figures
from .records import Check, Figure, Headline, Section
from .shipped import Study, StudyContext

__all__ = [
    "CHORD_BINS",
    "EXTREME_SAMPLES",
    "chord_profile",
    "extreme_inputs",
    "extreme_table",
    "lit_pixels",
    "study",
]

CHORD_BINS = np.array([0.0, 0.1, 0.2, 0.4, 0.7, 1.0, 1.5, 3.0])
"""Bins of the chord length through the cone over the cone's length L."""
EXTREME_SAMPLES = {True: 20000, False: 400000}
"""Random kernel inputs per extreme set (``--quick``: True)."""
ROWS = ("shell", "shell-fitted", "shell-front-fitted", "chord", "chord-fitted")
"""The engine's rows the profile compares (those present): the seed's shell at p = 1, q = 2 and its level
k₀, both shells fitted (k, p, q), the chord integral at the physical K and fitted."""
LAMP = {"apex": (0.0, 0.0, 6.0), "axis": (0.0, 0.0, -1.0), "cutoff_deg": 30.0, "beam_deg": 22.5}
"""The shipped scenes' lamp (scenes/library/light_cones_spot.xml), for the quadrature's limits."""


# ------------------------------------------------------------------------------------ chord profile
def bias_nrmse(model: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(Σ(m − r)/Σr, √mean((m − r)²)/mean(r)): the relative bias and the RMS error over the mean radiance
    (per-pixel relative errors are dominated by the few pixels where the reference is near 0)."""
    d = model - ref
    mean = float(np.mean(ref))
    return float(np.sum(d) / np.sum(ref)), float(np.sqrt(np.mean(d * d)) / mean)


def case_chords(case) -> np.ndarray:
    """The chord (m) of each compared pixel's view ray through the shell's cone (`CHORD_LENGTH`, float64)."""
    g = case.channel_inputs[0]
    n = int(case.mask.sum())
    inputs = {k: np.broadcast_to(np.asarray(g[k], np.float64), (n,)) for k in METHODS["shell"].input_names}
    return np.asarray(CHORD_LENGTH(NUMPY_OPS, inputs), np.float64)


def lit_pixels(case, outcomes) -> np.ndarray:
    """Which compared pixels' rays cross the cutoff cone: the quadrature row > 0 (the old experiment's lit
    pixels; the engine's mask also holds the rays that miss the cone, where every row and the reference
    are 0)."""
    if "quadrature" in outcomes:
        return outcomes["quadrature"].image[case.mask][:, 0] > 0.0
    return case.reference.mean[case.mask][:, 0] > 0.0


def chord_profile(items: list[tuple[str, Any, dict]]) -> dict:
    """Per density: bias and RMS error over the mean (`bias_nrmse`) of each row per chord/L bin (views
    pooled), the RMS error per case, and the correlation of log(model/reference) with log chord, on the lit
    pixels (`lit_pixels`). ``items``: (case id, `FamilyCase`, its outcomes)."""
    out = {}
    for sigma in sorted({float(np.mean(c.parameters["sigma_t_per_m"])) for _, c, _ in items}):
        sel_items = [it for it in items if float(np.mean(it[1].parameters["sigma_t_per_m"])) == sigma]
        rows = [r for r in ROWS if all(r in o for _, _, o in sel_items)]
        lits = [lit_pixels(c, o) for _, c, o in sel_items]

        def pooled(get, lits=lits, sel_items=sel_items):
            return np.concatenate([get(c, o)[m] for (_, c, o), m in zip(sel_items, lits, strict=True)])

        chord = pooled(lambda c, o: case_chords(c) / float(c.parameters["cone_length_m"]))
        ref = pooled(lambda c, o: c.reference.mean[c.mask][:, 0])
        model = {r: pooled(lambda c, o, r=r: o[r].image[c.mask][:, 0]) for r in rows}
        idx = np.digitize(chord, CHORD_BINS) - 1
        prof: dict = {"chord_over_L": [], "pixels": [], "rows": {r: {"mean": [], "rms": []} for r in rows}}
        for k in range(len(CHORD_BINS) - 1):
            sel = idx == k
            if not sel.any() or np.sum(ref[sel]) <= 0.0:
                continue
            prof["chord_over_L"].append([float(CHORD_BINS[k]), float(CHORD_BINS[k + 1])])
            prof["pixels"].append(int(sel.sum()))
            for r in rows:
                bias, nrmse = bias_nrmse(model[r][sel], ref[sel])
                prof["rows"][r]["mean"].append(bias)
                prof["rows"][r]["rms"].append(nrmse)
        views = {}
        for (cid, c, o), m in zip(sel_items, lits, strict=True):
            r_ = c.reference.mean[c.mask][:, 0][m]
            views[cid] = {r: bias_nrmse(o[r].image[c.mask][:, 0][m], r_)[1] for r in rows}
        corr = {}
        for r in rows:
            ok = (model[r] > 0.0) & (chord > 0.0) & (ref > 0.0)
            x, y = np.log(chord[ok]), np.log(model[r][ok] / ref[ok])
            good = ok.sum() > 2 and np.std(x) > 0 and np.std(y) > 0
            corr[r] = float(np.corrcoef(x, y)[0, 1]) if good else 0.0
        prof["views_rms"] = views
        prof["log_error_vs_log_chord_correlation"] = corr
        out[f"{sigma:g}"] = prof
    return out


def fitted_table(items) -> list[dict]:
    """Per case: the fitted shells' (k, p, q) and the fitted chord level K over the physical σ_s·I/(4π)."""
    out = []
    for cid, c, o in items:
        row: dict = {"case": cid, "sigma_t_per_m": float(np.mean(c.parameters["sigma_t_per_m"]))}
        for r in ("shell-fitted", "shell-front-fitted"):
            if r in o and o[r].fit is not None:
                row[r] = {k: v["value"] for k, v in o[r].fit["parameters"].items()}
        if "chord-fitted" in o and o["chord-fitted"].fit is not None:
            k = o["chord-fitted"].fit["parameters"]["k"]["value"]
            row["chord_K_over_physical"] = k / float(c.parameters["K_W_per_m_sr"])
        out.append(row)
    return out


def dark_check(items) -> Check:
    """Mitsuba's reference on the compared pixels whose ray misses the cutoff cone (quadrature row 0)."""
    worst, count = 0.0, 0
    for _, c, o in items:
        if "quadrature" not in o:
            continue
        dark = o["quadrature"].image[c.mask][:, 0] <= 0.0
        count += int(dark.sum())
        if dark.any():
            worst = max(worst, float(np.max(np.abs(c.reference.mean[c.mask][dark]))))
    return Check.zero(f"reference is exactly 0 where the ray misses the cutoff cone ({count} pixels)", worst)


# ------------------------------------------------------------------------------------ extremes
def extreme_inputs(n: int, seed: int = 5) -> dict[str, dict]:
    """Random float32 kernel inputs per extreme set: the camera inside the cone, rays along the axis
    (±1e-6…1e-2 rad), rays grazing the shell (along a generator, ±1e-6 rad), θ_c = 1e-4 rad and 1.5 rad,
    L = 1e-3 m, depth 0, anywhere (cameras up to 100 m away)."""
    rng = np.random.default_rng(seed)

    def unit(v):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    apex = rng.uniform(-10, 10, (n, 3))
    axis = unit(rng.normal(size=(n, 3)))
    theta = rng.uniform(0.05, 1.4, n)
    length = 10 ** rng.uniform(-1, 1.5, n)
    perp = unit(np.cross(axis, rng.normal(size=(n, 3))))
    sets = {}

    def pack(o, w, th=theta, ln=length, depth=None):
        depth = np.full(n, 1e4) if depth is None else depth
        cols = [*o.T, *unit(w).T, *apex.T, *axis.T, th, ln, depth]
        return {k: np.asarray(c, np.float32) for k, c in zip(METHODS["shell"].input_names, cols, strict=True)}

    t = rng.uniform(0.01, 1.0, n) * length
    o_in = apex + t[:, None] * axis + (rng.uniform(0, 0.99, n) * t * np.tan(theta))[:, None] * perp
    sets["camera inside the cone"] = pack(o_in, rng.normal(size=(n, 3)))
    eps = 10 ** rng.uniform(-6, -2, n)
    back = apex - rng.uniform(0.1, 50, n)[:, None] * axis
    sets["view along the axis (from behind the apex)"] = pack(
        back + eps[:, None] * perp, axis + eps[:, None] * perp
    )
    gen = unit(np.cos(theta)[:, None] * axis + np.sin(theta)[:, None] * perp)
    shift = 10 ** rng.uniform(-6, -1, n) * np.where(rng.random(n) < 0.5, 1.0, -1.0)
    o_gr = apex - 20.0 * gen + shift[:, None] * unit(np.cross(gen, np.cross(axis, gen)))
    sets["grazing the shell (along a generator)"] = pack(o_gr, gen + 1e-6 * rng.normal(size=(n, 3)))
    o_any = rng.uniform(-100, 100, (n, 3))
    w_any = rng.normal(size=(n, 3))
    sets["θ_c = 1e-4 rad"] = pack(o_any, w_any, th=np.full(n, 1e-4))
    sets["θ_c = 1.5 rad"] = pack(o_any, w_any, th=np.full(n, 1.5))
    sets["L = 1e-3 m, depth 0…1 m"] = pack(o_any, w_any, ln=np.full(n, 1e-3), depth=rng.uniform(0, 1, n))
    sets["anywhere"] = pack(o_any, w_any)
    return sets


def _beside_quadrature(sigma_t: float) -> np.ndarray:
    """The quadrature along 25 rays of the beside view's centre row (camera (0, −9, 3)) to 30 m."""
    origin = (0.0, -9.0, 3.0)
    dirs = np.array([[x, 1.0, 0.0] for x in np.linspace(-0.6, 0.6, 25)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lamp = (LAMP["apex"], LAMP["axis"], math.radians(LAMP["cutoff_deg"]), math.radians(LAMP["beam_deg"]))
    return spot_single_scattering(origin, dirs, np.full(25, 30.0), *lamp, 100.0, sigma_t, sigma_t)


def medium_limits() -> list[dict]:
    """The quadrature at σ_t = 1e-6 vs 1e-9 /m (L/σ_t: linear in σ) and σ_t = 2 /m (dense: finite, ≥ 0)."""
    thin = _beside_quadrature(1e-6) / 1e-6
    thinner = _beside_quadrature(1e-9) / 1e-9
    lit = thinner > 0
    dense = _beside_quadrature(2.0)
    return [
        {
            "what": "σ_t = 1e-6 vs 1e-9 /m: L/σ_t (linear in σ)",
            "worst_rel_difference": float(np.max(np.abs(thin[lit] / thinner[lit] - 1.0))),
            "finite": bool(np.all(np.isfinite(thin))),
        },
        {
            "what": "σ_t = 2 /m (optical depth 18 to the axis): L finite, ≥ 0",
            "max_radiance": float(np.max(dense)),
            "finite": bool(np.all(np.isfinite(dense)) and np.all(dense >= 0.0)),
        },
    ]


def extreme_table(samples: int) -> dict:
    """Non-finite outputs of every method in float32 (Dr.Jit) per extreme set, and the quadrature's limits."""
    rows = []
    for label, inputs in extreme_inputs(samples).items():
        for mid, m in METHODS.items():
            out = np.asarray(m.evaluate(inputs, {}), np.float64)
            finite = np.isfinite(out)
            rows.append(
                {
                    "inputs": label,
                    "method": mid,
                    "samples": int(out.size),
                    "non_finite": int((~finite).sum()),
                    "nonzero_share": float(np.mean(out[finite] != 0.0)) if finite.any() else 0.0,
                }
            )
    return {"kernels": rows, "medium": medium_limits()}


def extreme_checks(ext: dict) -> list[Check]:
    checks = [
        Check.zero(
            f"{r['method']} float32, {r['inputs']}: non-finite outputs ({r['samples']} inputs)",
            r["non_finite"],
        )
        for r in ext["kernels"]
    ]
    thin, dense = ext["medium"]
    checks.append(
        Check(
            name="quadrature, σ → 0: L/σ_t at σ_t = 1e-6 vs 1e-9 /m (worst relative difference)",
            value=thin["worst_rel_difference"],
            expected="≤ 1e-4 (e^(−σ_t·s) ≈ 1 − σ_t·s, s ≤ 30 m)",
            passed=bool(thin["finite"] and thin["worst_rel_difference"] <= 1e-4),
        )
    )
    checks.append(
        Check.holds("quadrature, dense medium σ_t = 2 /m: finite and non-negative", dense["finite"])
    )
    return checks


# ------------------------------------------------------------------------------------------------ text
def _profile_tables(profile: dict) -> str:
    out = []
    for sig, p in profile.items():
        rows = list(p["rows"])
        out += [f"σ_t = {sig} /m, all views pooled (bias / RMS over the mean):", ""]
        out += ["| chord/L | pixels | " + " | ".join(rows) + " |", "|---|---|" + "---|" * len(rows)]
        for k, (lo, hi) in enumerate(p["chord_over_L"]):
            vals = " | ".join(f"{p['rows'][r]['mean'][k]:+.2f} / {p['rows'][r]['rms'][k]:.2f}" for r in rows)
            out.append(f"| {lo:g}–{hi:g} | {p['pixels'][k]} | {vals} |")
        out += ["", "RMS error over the mean reference, per case:", ""]
        out += ["| case | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
        for cid, vals in p["views_rms"].items():
            out.append(f"| {cid} | " + " | ".join(f"{vals[r]:.3f}" for r in rows) + " |")
        corr = p["log_error_vs_log_chord_correlation"]
        out += ["", "Correlation of log(model/reference) with log chord: "
                + ", ".join(f"{r} {v:+.2f}" for r, v in corr.items()), ""]  # fmt: skip
    return "\n".join(out)


def _fitted_text(table: list[dict]) -> str:
    out = ["| case | shell (k, p, q) | front faces (k, p, q) | chord K / (σ_s I/4π) |", "|---|---|---|---|"]

    def kpq(d):
        return ", ".join(f"{k} = {v:.3g}" for k, v in d.items()) if d else "–"

    for r in table:
        kc = r.get("chord_K_over_physical")
        ktext = f"{kc:.3f}" if kc is not None else "–"
        out.append(
            f"| {r['case']} | {kpq(r.get('shell-fitted'))} | {kpq(r.get('shell-front-fitted'))} | {ktext} |"
        )
    return "\n".join(out)


def _extremes_text(ext: dict) -> str:
    out = ["| inputs | method | non-finite | share ≠ 0 |", "|---|---|---|---|"]
    for r in ext["kernels"]:
        out.append(
            f"| {r['inputs']} | {r['method']} | {r['non_finite']} of {r['samples']} | "
            f"{r['nonzero_share']:.3f} |"
        )
    return "\n".join(out)


def _summary(profile: dict, table: list[dict]) -> str:
    parts = []
    for sig, p in profile.items():
        v = p["views_rms"].values()

        def span(r, v=v):
            vals = [x[r] for x in v if r in x]
            return f"{min(vals):.2f}–{max(vals):.2f}" if vals else "–"

        parts.append(
            f"σ_t = {sig} /m: RMS error over the mean radiance per view, seed shell {span('shell')}, fitted "
            f"shell {span('shell-fitted')}, front faces fitted {span('shell-front-fitted')}, §1 chord "
            f"integral at the physical K {span('chord')}, fitted {span('chord-fitted')}"
        )
    kc = [r["chord_K_over_physical"] for r in table if "chord_K_over_physical" in r]
    ktext = f" The fitted chord level is {min(kc):.2f}–{max(kc):.2f} of σ_s·I/(4π)." if kc else ""
    return (
        "; ".join(parts) + "." + ktext + " The shell's one fragment per face knows the view angle and the "
        "distance from the lamp, not how long the ray stays in the beam nor how close it passes the lamp."
    )


def _chord_figure(out: Path, profile: dict) -> Figure:
    series = []
    for sig, prof in profile.items():
        x = [math.sqrt(max(lo, 0.03) * hi) for lo, hi in prof["chord_over_L"]]
        for rid, vals in prof["rows"].items():
            y = [max(v, 1e-4) for v in vals["rms"]]
            series.append({"x": x, "y": y, "label": rid, "style": "line", "panel": f"σ_t = {sig} /m"})
    file = "figures/error_vs_chord.png"
    figures.line_plot(
        out / file, "chord length through the cone / L", "RMS error / mean reference", series,
        x_log=True, y_log=True, panels=[f"σ_t = {s} /m" for s in profile],
    )  # fmt: skip
    return Figure(
        file=file,
        section="results",
        caption="RMS error over the bin's mean reference radiance per bin of the view ray's chord length "
        "through the cone (over the cone's length L), all views of a density pooled: the shell's single "
        "fragment cannot follow the chord; §1's integral over the chord can, up to the extinction and the "
        "beam's soft edge.",
    )


def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run light-cones`` (module docstring), from the engine's audits."""
    out = Path(ctx.out_dir)
    items = [
        (c.id, c, r.outcomes[c.id])
        for r in ctx.audits
        for c in r.cases
        if "cone_length_m" in c.parameters and c.mask.any()
    ]
    ext = extreme_table(EXTREME_SAMPLES[ctx.quick])
    checks = extreme_checks(ext)
    sections = [Section(id="extremes", title="Extremes (float32 kernels)", text=_extremes_text(ext))]
    figs = []
    profile, table = {}, []
    if items:
        profile = chord_profile(items)
        table = fitted_table(items)
        checks.append(dark_check(items))
        sections += [
            Section(
                id="chord",
                title="Error against the chord length",
                placement="after_results",
                text="Relative bias Σ(model − reference)/Σreference / RMS error over the mean reference per "
                "bin of the view ray's chord length through the shell's cone over the cone's length L, on "
                "the pixels whose ray crosses the cutoff cone (the quadrature > 0):\n\n"
                + _profile_tables(profile),
            ),
            Section(
                id="cone-fits", title="Fitted shells and chord level per scene", text=_fitted_text(table)
            ),
        ]
        figs.append(_chord_figure(out, profile))
    worst = max(r["non_finite"] for r in ext["kernels"])
    return Study(
        sections=tuple(sections),
        figures=tuple(figs),
        checks=tuple(checks),
        notes=(_summary(profile, table),) if items else (),
        headline=(Headline(label="float32 kernels at the extremes: non-finite outputs", value=worst),),
        extra={"chord_profile": profile, "fitted": table, "extremes": ext},
    )
