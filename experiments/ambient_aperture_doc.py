"""Report of the ``ambient-aperture`` study (`ambient_aperture_study`): its figures and text, written from
the measured numbers, and the intersection forms it compares (`OMEGA`). A leaf: imports no family module."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from rtfit.realtime.ambient_aperture import METHODS, cap_area
from rtfit.realtime.methods import Method

from . import figures
from .records import Figure

__all__ = ["APPROX", "DECOMPOSITION", "EXACT", "OMEGA", "params_of", "report_text", "smaller_cap"]

PI = math.pi
OMEGA = tuple(m for m in METHODS.values() if m.quantity == "cap_intersection_solid_angle")
"""The intersection forms (r1, r2, d in rad → Ω in sr), the exact one first."""
EXACT = next(m for m in OMEGA if m.exact)
APPROX = tuple(m for m in OMEGA if not m.exact)
DECOMPOSITION = (
    "aa-exact-seed",
    "aa-smoothstep-seed",
    "aa-fitted-seed",
    "aa-exact-fitted",
    "aa-fitted-fitted",
)
"""The engine's shading rows (at the shipped c0..c5 and k) compared with the cap-model integral."""


def params_of(method: Method, fitted: Mapping[str, float]) -> dict[str, float]:
    """The values in ``fitted`` of ``method``'s free parameters (c0..c5 and/or k)."""
    return {p: float(fitted[p]) for p in method.params}


def smaller_cap(r1, r2):
    """A(min(r1, r2)) (sr, float64): the unit of every function-level error."""
    return cap_area(np.minimum(r1, r2))


# ============================================================================================== figures
def map_figure(out: Path, fitted) -> Figure:
    """Signed error maps over (d, r1) for r2 = ρ·r1, ρ ∈ {1, 0.5, 0.2}, r1 ∈ (0, π/2]."""
    plt = figures.pyplot()
    k = (np.arange(160) + 0.5) / 160
    R1, D = np.meshgrid(k * PI / 2, k * PI, indexing="ij")
    fig, axes = plt.subplots(3, len(APPROX), figsize=(10, 8.2), squeeze=False)
    im = None
    for i, rho in enumerate((1.0, 0.5, 0.2)):
        caps = {"r1": R1, "r2": rho * R1, "d": D}
        ex, a_min = EXACT.evaluate(caps), smaller_cap(R1, rho * R1)
        for j, m in enumerate(APPROX):
            err = (m.evaluate(caps, params_of(m, fitted)) - ex) / a_min
            err = np.where((D > np.abs(R1 - rho * R1)) & (D < R1 + rho * R1), err, np.nan)
            ax = axes[i, j]
            im = ax.imshow(
                err,
                origin="lower",
                extent=(0, 180, 0, 90),
                aspect="auto",
                cmap="RdBu_r",
                vmin=-0.16,
                vmax=0.16,
            )
            ax.set_title(f"{m.id}, r₂ = {rho:g}·r₁", fontsize=9)
            ax.set_xlabel("d (deg)", fontsize=8)
            ax.set_ylabel("r₁ (deg)", fontsize=8)
    fig.subplots_adjust(hspace=0.5, wspace=0.35)
    assert im is not None
    fig.colorbar(im, ax=axes, shrink=0.6, label="(Ω_approx − Ω_exact) / smaller cap")
    figures.save_figure(fig, out / "figures/error_maps.png")
    return _study_figure(
        "figures/error_maps.png",
        "Signed error of the smoothstep (seed), linear ramp and fitted forms over the centre "
        "distance d and the larger radius r₁, for r₂/r₁ = 1, 0.5, 0.2, as a fraction of the smaller "
        "cap; white outside the partial-overlap band. Colour range ±0.16.",
    )


def curve_figure(out: Path, fitted) -> Figure:
    plt = figures.pyplot()
    d = np.linspace(0, PI, 400)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.3))
    for ax, (r1, r2) in zip(axes, ((0.5, 0.5), (1.2, 0.3), (PI / 2, PI / 2)), strict=True):
        caps = {"r1": np.full_like(d, r1), "r2": np.full_like(d, r2), "d": d}
        for m in OMEGA:
            ax.plot(
                np.degrees(d),
                m.evaluate(caps, params_of(m, fitted)) / cap_area(min(r1, r2)),
                label=m.id,
                lw=1.2,
            )
        ax.set_title(f"r₁ = {math.degrees(r1):.0f}°, r₂ = {math.degrees(r2):.0f}°", fontsize=9)
        ax.set_xlabel("d (deg)")
        ax.set_ylabel("Ω / smaller cap")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    figures.save_figure(fig, out / "figures/intersection_curves.png")
    return _study_figure(
        "figures/intersection_curves.png",
        "Intersection solid angle over the centre distance for three cap pairs, as a fraction "
        "of the smaller cap. Two hemispheres (right): the exact lune 2(π − d) is linear in d; the "
        "smoothstep bends it into an S.",
    )


def _study_figure(file: str, caption: str) -> Figure:
    """The record of a figure of the study's section, written to OUT/``file``."""
    return Figure(file=file, section="study-ambient-aperture", caption=caption)


def pareto_figure(out: Path, fl: Mapping, costs: list[dict]) -> Figure:
    pts = []
    for m in OMEGA:
        c = next(r for r in costs if r["method"] == f"omega-{m.id}")
        y = 1e-7 if m.exact else fl["errors"][m.id]["full"]["max"]  # exact: plotted at its float32 level
        pts.append({"x": c["ns_per_pixel"], "y": y, "label": m.id})
    figures.pareto_plot(
        out / "figures/pareto.png",
        pts,
        "ns per evaluation",
        "max |ΔΩ| / smaller cap (full domain)",
        title="Intersection forms: error vs cost (exact plotted at its float32 level, 1e-7)",
    )
    return _study_figure(
        "figures/pareto.png",
        "Maximum error over the full domain against the measured cost per evaluation, same run.",
    )


# ================================================================================================ text
def _f(x, digits=3) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def report_text(fl, fit_i, fit_l, dec, costs, coeffs) -> str:
    e = fl["errors"]
    func = [
        "| form | max, r ≤ π/2 | RMS, r ≤ π/2 | max, full | RMS, full | max, all points |",
        "|---|---|---|---|---|---|",
    ]
    for form in ("smoothstep", "linear", "fitted"):
        x = e[form]
        func.append(
            f"| {form} | {_f(x['hemisphere']['max'])} | {_f(x['hemisphere']['rms'])} | "
            f"{_f(x['full']['max'])} | {_f(x['full']['rms'])} | {_f(x['all']['max'])} |"
        )
    light = [
        "| case | cap model vs reference | floor | unshadowed | "
        + " | ".join(f"{r} vs ref / vs cap" for r in DECOMPOSITION)
        + " |",
        "|---" * (4 + len(DECOMPOSITION)) + "|",
    ]
    sky = [
        "| case | fill-projected (cap model) | fill-seed | floor | unoccluded (π·L) |",
        "|---|---|---|---|---|",
    ]
    for r in dec:
        if r["kind"] == "light":
            light.append(
                f"| {r['case']} | {_f(r['cap_model_vs_reference'])} | {_f(r['noise_floor'])} | "
                f"{_f(r['unshadowed_vs_reference'])} | "
                + " | ".join(
                    f"{_f(r.get(f'{m}_vs_reference'))} / {_f(r.get(f'{m}_vs_cap_model'))}"
                    for m in DECOMPOSITION
                )
                + " |"
            )
        else:
            sky.append(
                f"| {r['case']} | {_f(r.get('fill-projected_vs_reference'))} | "
                f"{_f(r.get('fill-seed_vs_reference'))} | {_f(r.get('noise_floor'))} | "
                f"{_f(r['unoccluded_vs_reference'])} |"
            )
    ns = {c["method"]: c["ns_per_pixel"] for c in costs}
    o60, le = fit_l["open_sky_60"], fit_l["errors"]
    return (
        "**Intersection forms over the whole domain.** Errors over the partial-overlap points of a "
        f"{fl['grid']}³ cell-centred grid of (r1, r2, d) ∈ (0, π)³ ({fl['n_hemi']} points with r ≤ π/2, "
        f"{fl['n_partial']} in the full domain), as a fraction of the smaller cap; *all points* adds the "
        "covering configurations (r1 + r2 + d ≥ 2π), which the seed's listing treats as partial overlaps. "
        f"The closed form is checked against independent quadrature on {fl['quad_points']} of them (max "
        f"deviation {_f(fl['quad_dev'])}).\n\n"
        + "\n".join(func)
        + f"\n\nFitted c0..c5 = {', '.join(_f(c, 4) for c in coeffs)} (on a {fit_i['grid']}³ grid, "
        f"{fit_i['n_residuals']} residuals, RMS residual {_f(fit_i['rms_residual'])}). Cost per evaluation "
        f"(same run): exact {_f(ns['omega-exact'])} ns, smoothstep {_f(ns['omega-smoothstep'])} ns, linear "
        f"{_f(ns['omega-linear'])} ns, fitted {_f(ns['omega-fitted'])} ns, memory floor "
        f"{_f(ns['memory-baseline'])} ns.\n\n"
        f"**Lambert factor.** Over {fit_l['n_configs']} random (aperture, light) configurations (bent normal "
        "in the upper hemisphere, r_a ∈ [0.05, π/2], α ∈ [0.01, 0.6] log-uniform, light up to 11.5° below "
        "the horizon), the cosine-weighted intersection by quadrature against Ω_exact·max(n·c, 0), errors as "
        f"a fraction of the light cap: seed RMS {_f(le['seed']['rms'])} (max {_f(le['seed']['max'])}, mean "
        f"{_f(le['seed']['mean'])}), fitted k = {_f(fit_l['k'], 4)}: RMS {_f(le['fitted']['rms'])} (max "
        f"{_f(le['fitted']['max'])}). Open sky, light of 0.57° at 60°: exact {_f(o60['exact'], 4)} sr, seed "
        f"{_f(o60['seed'], 4)} ({_f(100 * (o60['seed'] / o60['exact'] - 1), 3)} % too bright), fitted "
        f"{_f(o60['fitted'], 4)}.\n\n"
        "**Cap model or formula.** RMSE over each light case's pixels as a fraction of the unshadowed peak: "
        "the exact integral over the baked cap ∩ the light's cap (quadrature) against the path tracer — the "
        "cap model's own error, the reference's noise floor beside it — then each shading row (shipped "
        "c0..c5 and k) against the reference and against that cap-model integral (the formula's own "
        "error).\n\n"
        + "\n".join(light)
        + "\n\nSky (the aperture fill, fraction of π·L): the projected-cap fill is the cap model's exact "
        "integral.\n\n" + "\n".join(sky)
    )
