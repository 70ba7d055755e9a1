"""Text of the ``ambient-aperture`` report: summary and sections, written from the measured numbers."""

from __future__ import annotations

import math


def _f(x, digits=3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.{digits}g}"


def _cost(cost_rows, method):
    for r in cost_rows:
        if r["method"] == method:
            return r["ns_per_pixel"]
    return float("nan")


def _case_rmse(cases, cid, method):
    for c in cases:
        if c["id"] == cid:
            for a in c["approximations"]:
                if a["method"] == method:
                    return a["metrics"]["rmse"]["value"]
    return float("nan")


def summary(cfg, fl, fit_l, dec, cases, cost_rows) -> str:
    e = fl["errors"]
    s, lin, fit = e["smoothstep"], e["linear"], e["fitted"]
    cap_vs_formula = []
    for row in dec:
        cap_err = row["cap_model_vs_reference"]
        f_err = row["aa-smoothstep-seed_vs_cap_model"]
        larger = "the cap model's error is the larger" if cap_err > f_err else "the seed's formulas err more"
        cap_vs_formula.append(
            f"{row['case']}: cap model {_f(cap_err)} vs the seed's formulas {_f(f_err)}, so {larger} "
            f"(fitted formulas {_f(row['aa-fitted-fitted_vs_cap_model'])}; ignoring occlusion "
            f"{_f(_case_rmse(cases, row['case'], 'unshadowed'))})"
        )
    ex, sm, ft = (_cost(cost_rows, f"omega-{f}") for f in ("exact", "smoothstep", "fitted"))
    return (
        "The exact solid angle of two intersecting spherical caps (a stable half-angle form of Tovchigrechko "
        "& "
        "Vakser 2001, valid for caps larger than a hemisphere, nested, disjoint, covering and tangent caps) "
        "is "
        f"checked against independent quadrature over a {fl['grid']}³ grid (max deviation "
        f"{_f(fl['quad_dev'])} of "
        "the smaller cap). Against it, the seed's smoothstep approximation errs by up to "
        f"**{_f(s['hemisphere']['max'])}** of the smaller cap (RMS {_f(s['hemisphere']['rms'])}) for caps up "
        "to a "
        f"hemisphere, and by up to {_f(s['all']['max'])} over the whole domain (covering caps); a linear "
        "ramp does "
        f"better ({_f(lin['hemisphere']['max'])} max, {_f(lin['hemisphere']['rms'])} RMS). The fitted form "
        "(complement trick + a corrected smoothstep, six optimistix-fitted coefficients) reaches "
        f"**{_f(fit['full']['max'])} max, {_f(fit['full']['rms'])} RMS** over the full domain "
        f"({_f(fit['hemisphere']['max'])} / {_f(fit['hemisphere']['rms'])} for r ≤ π/2) at "
        f"{_f(ft)} ns per evaluation, against {_f(sm)} ns for the smoothstep and {_f(ex)} ns for the exact "
        "form "
        "(same run).\n\n"
        "The seed's Lambert factor (plain average of aperture and light directions) has RMS error "
        f"{_f(fit_l['errors']['seed']['rms'])} of the light cap over random configurations; weighting the "
        "two "
        f"directions by the other cap's size (k = {_f(fit_l['k'])}) brings it to "
        f"{_f(fit_l['errors']['fitted']['rms'])}. On the scenes (RMSE, fraction of the unshadowed peak): "
        + "; ".join(cap_vs_formula)
        + "."
    )


def sections(cfg, fl, fit_i, fit_l, dec, coeffs, k) -> list[dict]:
    e = fl["errors"]
    rows = [
        "| form | max, r ≤ π/2 | RMS, r ≤ π/2 | max, full | RMS, full | max, all points |",
        "|---|---|---|---|---|---|",
    ]
    for form in ("smoothstep", "linear", "fitted"):
        x = e[form]
        rows.append(
            f"| {form} | {_f(x['hemisphere']['max'])} | {_f(x['hemisphere']['rms'])} | "
            f"{_f(x['full']['max'])} "
            f"| {_f(x['full']['rms'])} | {_f(x['all']['max'])} |"
        )
    func_table = "\n".join(rows)
    drows = [
        (
            "| case | cap model vs reference | floor | exact Ω + seed Lambert | smoothstep + seed (seed) | "
            "fitted Ω + seed Lambert | exact Ω + fitted Lambert | fitted + fitted |"
        ),
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in dec:
        drows.append(
            f"| {r['case']} | {_f(r['cap_model_vs_reference'])} | {_f(r['noise_floor'])} | "
            f"{_f(r['aa-exact-seed_vs_cap_model'])} | {_f(r['aa-smoothstep-seed_vs_cap_model'])} | "
            f"{_f(r['aa-fitted-seed_vs_cap_model'])} | {_f(r['aa-exact-fitted_vs_cap_model'])} | "
            f"{_f(r['aa-fitted-fitted_vs_cap_model'])} |"
        )
    dec_table = "\n".join(drows)
    o60 = fit_l["open_sky_60"]
    return [
        {
            "id": "method",
            "title": "Method",
            "text": (
                "**Exact intersection.** For two caps of radii r1, r2 whose centres are d apart, the "
                "triangle of the "
                "two centres and one boundary crossing P has sides r1, r2, d, angles β1, β2 at the centres "
                "and excess "
                "E; the lens is two sectors minus the kite: Ω = 2[β1(1 − cos r1) + β2(1 − cos r2) − E] = "
                "2[π − γ − β1 cos r1 − β2 cos r2]. The angles come from half-angle forms with s = (r1 + r2 + "
                "d)/2 "
                "(each difference s − x summed in the order that is exact in floating point), E from "
                "tan(E/2) = tan(r1/2)tan(r2/2) sin γ/(1 + tan(r1/2)tan(r2/2) cos γ), and caps larger than a "
                "hemisphere are replaced by their complements. Nested: the smaller cap; disjoint: 0; "
                "covering "
                "(r1 + r2 + d ≥ 2π): A1 + A2 − 4π.\n\n"
                "**Seed erratum** (000:2672-2687): the printed IntersectArea has the wrong sign on its third "
                "term "
                "(−2 arccos(…) must be +2 arccos(…)); it returns −7.92 for r0 = r1 = d = 0.5 where the truth "
                "is "
                "0.3075.\n\n"
                "**Approximations.** With t = 1 − saturate((d − |r1 − r2|)/(r1 + r2 − |r1 − r2|)): "
                "smoothstep "
                "A_min·t²(3 − 2t) (the seed's Listing 1), linear A_min·t, and the fitted form (complement "
                "trick, "
                "then t²(3 − 2t) + t(1 − t)·[c0 + c1u + ρ(c2 + c3u) + σ(c4 + c5u)], u = 1 − 2t, ρ = "
                "r_min/r_max, "
                "σ = (r_min + r_max)/π, saturated): exact at t = 0 and 1 whatever the coefficients, never "
                "outside "
                "[0, A_min].\n\n"
                "**Shading.** E = L·Ω·max(n·c, 0) with c the estimated centroid of the intersection: the "
                "seed's "
                "plain average of the bent normal a and light direction l, or the fitted weights "
                "w = A(r_a)^k/(A(r_a)^k + A(α)^k) on l. Ambient fill: the seed's L_sky(A(r_a) − Ω)·max(n·a, "
                "0) (the "
                "seed gives no cosine weighting; a solid angle is not a projected solid angle) vs the "
                "closed-form "
                "projected solid angle of the aperture cap (horizon-clipped) minus the light's share.\n\n"
                "**Scenes.** Mitsuba irradiance probes (direct light) on a grid of receiver points; the bent "
                "normal "
                "and aperture baked at the same points with Mitsuba ray casts (uniform stratified hemisphere "
                f"directions, {cfg['bake_dirs']} per point). The *cap model* row integrates the light "
                "exactly over "
                "the baked cap ∩ the light's cap (quadrature), so its error is the cap model's alone."
            ),
        },
        {
            "id": "function-level",
            "title": "Intersection forms over the whole domain",
            "text": (
                f"Errors over the partial-overlap points of a {fl['grid']}³ cell-centred grid of (r1, r2, d) "
                "∈ (0, π)³ "
                f"({fl['n_hemi']} points with r ≤ π/2, {fl['n_partial']} in the full domain), as a fraction "
                "of the "
                "smaller cap; *all points* also includes the covering configurations (r1 + r2 + d ≥ 2π), "
                "which the "
                "seed's listing treats as partial overlaps.\n\n" + func_table + "\n\n"
                f"Fitted coefficients c0..c5 = {', '.join(_f(c, 4) for c in coeffs)} (fit on a "
                f"{fit_i['grid']}³ grid, "
                f"{fit_i['n_residuals']} residuals, RMS residual {_f(fit_i['rms_residual'])})."
            ),
        },
        {
            "id": "lambert",
            "title": "Lambert factor",
            "text": (
                f"Over {fit_l['n_configs']} random (aperture, light) configurations (bent normal in the "
                "upper "
                "hemisphere, r_a ∈ [0.05, π/2], α ∈ [0.01, 0.6] log-uniform, light up to 11.5° below the "
                "horizon), "
                "the cosine-weighted intersection by quadrature against Ω_exact·max(n·c, 0), errors as a "
                "fraction of "
                f"the light cap: seed RMS {_f(fit_l['errors']['seed']['rms'])} (max "
                f"{_f(fit_l['errors']['seed']['max'])}, "
                f"mean {_f(fit_l['errors']['seed']['mean'])}), fitted k = {_f(k, 4)}: RMS "
                f"{_f(fit_l['errors']['fitted']['rms'])} (max {_f(fit_l['errors']['fitted']['max'])}). Open "
                "sky, light "
                f"of 0.57° at 60°: exact {_f(o60['exact'], 4)} sr, seed {_f(o60['seed'], 4)} "
                f"({_f(100 * (o60['seed'] / o60['exact'] - 1), 3)} % too bright), fitted "
                f"{_f(o60['fitted'], 4)}."
            ),
        },
        {
            "id": "decomposition",
            "title": "Cap model or formula: which error is larger",
            "text": (
                "RMSE over the receiver probes, fraction of the unshadowed peak. The first column compares "
                "the exact "
                "integral over the baked cap with the path tracer (the cap model's error, with the "
                "reference's noise "
                "floor beside it); the others compare each shading formula with that cap-model integral (the "
                "formulas' own error).\n\n" + dec_table
            ),
            "placement": "after_results",
        },
    ]
