"""The diffuse family's own study for ``rtfit run diffuse`` (issue 30 §1): what only this family has.

The engine (`rtfit.experiments.engine_run`) audits the shipped scenes (`audit_diffuse.SCENES`: a white unit
sphere side-lit by a sun of angular radius α, E⊥ = π, one file per α) exactly as ``rtfit audit`` audits a
user's scene: each row (Lambert, half-Lambert, wrap at its declared and at its fitted (w, p), the exact
sphere-light form, the representative point) against the sun's direct irradiance at each visible point,
its cost, and wrap's (w, p) fitted per α through the one kernel text. This study reads those audits (it
renders nothing) and adds:

* **the smooth law** w(α) = w1 sin α + w2 sin²α, p(α) = 1 + p1 sin α + p2 sin²α (`SMOOTH_LAW`), fitted to
  the per-α wrap fits (each weighted by 1/stderr, floored at 1e-3, as before the engine), written as
  ``fitted/wrap_smooth.json`` (`SMOOTH_WRAP`: wrap with the law composed, one function for any light size),
  and its own row ``wrap-smooth`` evaluated on every α's pixels against the same reference;
* a table per α of every row's RMSE as a fraction of E⊥ (E⊥ = π: the fraction of the lit peak radiance of
  the white sphere, the scale of the experiment before the engine), the noise floor, and the fitted (w, p);
* figures: error vs α, the wrap parameters per α with the law, and the terminator: the reference
  irradiance E/E⊥ of every visible pixel against its angle θ = acos(n·l) from the light (a disc at infinity
  gives the same E(θ) for every normal, so every pixel is a sample of the one curve), beside the exact form
  and each approximation;
* checks: the law's fit converged, and the per-α fit tends to Lambert (w → 0, p → 1) as α → 0, which the
  closed form requires (E → E⊥·max(cos θ, 0)).

The unshadowed case of each scene is read (the sphere is convex: its shadowed case is the same image).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rtfit.fitting import Param, compute_metrics, concatenated, fit_method
from rtfit.realtime import NUMPY_OPS, Input, Method
from rtfit.realtime.diffuse import METHODS

from . import figures, prose
from . import fitted as fitfiles
from .case_inputs import masked_image
from .records import Check, Figure, Section
from .shipped import Study, StudyContext

__all__ = [
    "SMOOTH_LAW",
    "SMOOTH_WRAP",
    "AlphaCase",
    "alpha_cases",
    "fit_smooth",
    "smooth_law_kernel",
    "smooth_wp",
    "smooth_wrap_kernel",
    "study",
    "write_smooth_fitted",
]

WRAP = METHODS["wrap"]
ROWS = ("lambert", "half-lambert", "wrap-fitted", "wrap-smooth", "exact")
"""The rows of the study's table and figures (engine row ids, and the study's ``wrap-smooth``)."""
TITLES = {
    "lambert": "Lambert",
    "half-lambert": "Half-Lambert",
    "wrap-fitted": "Wrap (fitted per α)",
    "wrap-smooth": "Wrap (smooth w(α), p(α))",
    "exact": "Exact (sphere light)",
}
LAMBERT_LIMIT = {"alpha_deg": 1.0, "w": 0.02, "p": 0.05}
"""The α → 0 check: at every α ≤ ``alpha_deg`` the fitted |w| ≤ ``w`` and |p − 1| ≤ ``p`` (measured at 0.27°
and 1°: |w| < 1e-3, |p − 1| < 3e-3)."""


# ============================================================================================== methods
def smooth_law_kernel(ops, alpha, w1, w2, p1, p2):
    """(w(α), p(α)) = (w1 sin α + w2 sin²α, 1 + p1 sin α + p2 sin²α), α in radians: the wrap parameters
    as smooth functions of the light's angular radius (w → 0, p → 1, i.e. Lambert, as α → 0)."""
    s = ops.sin(alpha)
    return w1 * s + w2 * s * s, 1.0 + p1 * s + p2 * s * s


SMOOTH_LAW = Method(
    "wrap-smooth-law",
    "smooth w(α), p(α)",
    smooth_law_kernel,
    inputs=(Input("alpha", "rad", "angular radius of the light"),),
    params={
        "w1": Param(1.0, -10.0, 10.0, unit="1", description="w(α): coefficient of sin α"),
        "w2": Param(0.0, -10.0, 10.0, unit="1", description="w(α): coefficient of sin²α"),
        "p1": Param(0.0, -20.0, 20.0, unit="1", description="p(α) − 1: coefficient of sin α"),
        "p2": Param(0.0, -20.0, 20.0, unit="1", description="p(α) − 1: coefficient of sin²α"),
    },
    formula="w = w1 sin α + w2 sin²α; p = 1 + p1 sin α + p2 sin²α",
    description="Wrap lighting's (w, p) as smooth functions of the light's angular radius α.",
)


def smooth_wrap_kernel(ops, cos_theta, alpha, irradiance, w1, w2, p1, p2):
    """Wrap lighting with (w, p) = `SMOOTH_LAW` at the light's angular radius α: the one function an
    engine needs for any light size (the two kernel texts composed, nothing re-typed)."""
    w, p = smooth_law_kernel(ops, alpha, w1, w2, p1, p2)
    return WRAP.kernel(ops, cos_theta=cos_theta, w=w, p=p, irradiance=irradiance)


SMOOTH_WRAP = Method(
    "wrap-smooth",
    "wrap lighting, smooth w(α), p(α)",
    smooth_wrap_kernel,
    inputs=(*WRAP.inputs, *SMOOTH_LAW.inputs),
    params=SMOOTH_LAW.params,
    quantity=WRAP.quantity,
    formula=f"{WRAP.formula}; {SMOOTH_LAW.formula}",
    source=WRAP.source,
    description="Wrap lighting for a light of any angular radius α within the fitted range.",
)


# ================================================================================================ cases
@dataclass(frozen=True)
class AlphaCase:
    """One shipped scene's unshadowed case of its sun: ``alpha_deg``, the engine's ``case`` (`FamilyCase`:
    reference, mask, channel inputs) and ``rows`` (row id → `MethodOutcome`), ``e_perp`` (W/m²: the median
    of the reference's own E⊥ over the pixels)."""

    alpha_deg: float
    case: Any
    rows: Mapping[str, Any]
    e_perp: float

    def wp(self) -> dict[str, dict]:
        """The wrap fit's (w, p): name → {"value", "stderr", …} (`FitResult.to_dict()`)."""
        return self.rows["wrap-fitted"].fit["parameters"]


def alpha_cases(audits) -> list[AlphaCase]:
    """The unshadowed case of each audit's distant light of finite size, by increasing α."""
    out = []
    for r in audits:
        for c in r.cases:
            inputs = c.channel_inputs[0]
            alpha = np.asarray(inputs.get("alpha", 0.0), np.float64)
            if c.parameters.get("shadowing") != "unshadowed" or not np.all(np.isinf(inputs["distance"])):
                continue
            if not alpha.size or float(alpha.max()) <= 0.0:
                continue
            e_perp = float(np.median(inputs["irradiance"]))
            out.append(AlphaCase(math.degrees(float(alpha.max())), c, r.outcomes[c.id], e_perp))
    return sorted(out, key=lambda a: a.alpha_deg)


# ================================================================================================== fits
def fit_smooth(alphas_deg, fits: list[Mapping[str, dict]]) -> dict:
    """`SMOOTH_LAW` fitted jointly to the per-α (w, p) ``fits`` (`AlphaCase.wp`, one per α of
    ``alphas_deg``), each weighted by 1/stderr (floored at 1e-3 so that one very precise α does not
    dominate entirely). `FitResult.to_dict()`."""
    alphas = np.radians(np.asarray(alphas_deg, np.float64))
    target = np.concatenate([[f[k]["value"] for f in fits] for k in ("w", "p")])
    weights = np.concatenate(
        [1.0 / np.maximum([f[k]["stderr"] or 1e-3 for f in fits], 1e-3) for k in ("w", "p")]
    )
    return fit_method(
        SMOOTH_LAW, {"alpha": alphas}, target, weights=weights, output=concatenated, solver="trf"
    ).to_dict()


def smooth_wp(smooth: Mapping, alpha_rad) -> dict[str, Any]:
    """(w, p) of the fitted law at ``alpha_rad`` (its NumPy run), clipped to wrap's declared bounds."""
    coeffs = {k: v["value"] for k, v in smooth["parameters"].items()}
    w, p = SMOOTH_LAW(NUMPY_OPS, {"alpha": alpha_rad}, coeffs)
    return {k: np.clip(v, *WRAP.bounds()[k]) for k, v in (("w", w), ("p", p))}


def smooth_rmse(ac: AlphaCase, smooth: Mapping) -> tuple[float, float]:
    """(RMSE, its noise floor) in W/m² of wrap at the law's (w, p) on the case's pixels (every channel),
    against the case's reference, as the engine measures its rows (`compute_metrics`)."""
    c = ac.case
    params = {k: float(v) for k, v in smooth_wp(smooth, math.radians(ac.alpha_deg)).items()}
    values = np.stack([np.asarray(WRAP.evaluate(ch, params), np.float64) for ch in c.channel_inputs], -1)
    img = masked_image(c.mask, values)
    m = compute_metrics(img, c.reference.mean, c.reference.sigma(), c.mask, names=("rmse",))["rmse"]
    return float(m.value), float(m.noise_floor)


# =========================================================================================== fitted file
RESIDUAL_UNITS = "the per-α fits' stderr (floored at 1e-3): residual = (law − per-α fit)/stderr"


def write_smooth_fitted(out: Path, smooth: Mapping, alphas_deg, cos_range, prov) -> str:
    """``fitted/wrap_smooth.json`` (format ``rtfit.fitted/1``, `rtfit.experiments.fitted`): `SMOOTH_WRAP` at
    the fitted law, its domain α over ``alphas_deg`` and cos θ over ``cos_range``. Returns its path
    relative to ``out``."""
    alphas = [math.radians(a) for a in alphas_deg]
    entry = fitfiles.method_entry(
        SMOOTH_WRAP,
        smooth,
        domain={"alpha": (min(alphas), max(alphas)), "cos_theta": tuple(cos_range)},
        residual_units=RESIDUAL_UNITS,
        data={"alpha_deg": [min(alphas_deg), max(alphas_deg)]},
    )
    name = "fitted/wrap_smooth.json"
    fitfiles.write_fitted(
        Path(out) / name,
        fitfiles.FittedFile(
            format=fitfiles.FORMAT,
            title="wrap lighting with smooth w(α), p(α), fitted to the per-α wrap fits of rtfit run diffuse",
            provenance=prov,
            methods=[entry],
        ),
    )
    return name


# =============================================================================================== figures
def _row_curve(row: str, ac: AlphaCase, smooth: Mapping, cos_t: np.ndarray) -> np.ndarray:
    """E/E⊥ of ``row`` on a grid of cos θ for the case's α (the row's kernel text on NumPy, E⊥ = 1)."""
    alpha = math.radians(ac.alpha_deg)
    inputs = {
        "cos_theta": cos_t,
        "irradiance": 1.0,
        "alpha": alpha,
        "radiance": 1.0 / (math.pi * math.sin(alpha) ** 2),
    }
    if row == "wrap-fitted":
        return np.asarray(WRAP(NUMPY_OPS, inputs, {k: v["value"] for k, v in ac.wp().items()}))
    if row == "wrap-smooth":
        return np.asarray(WRAP(NUMPY_OPS, inputs, smooth_wp(smooth, alpha)))
    return np.asarray(METHODS[row](NUMPY_OPS, inputs, {}))


def terminator_figure(out: Path, cases: list[AlphaCase], smooth: Mapping) -> Figure:
    """E/E⊥ of every visible pixel against θ (reference, ±2σ) beside each row's curve, at the smallest,
    middle and largest α."""
    picks = [cases[i] for i in sorted({0, len(cases) // 2, len(cases) - 1})]
    series, panels = [], []
    grid = np.linspace(0.0, math.pi, 361)
    rng = np.random.default_rng(0)
    for ac in picks:
        panel = f"α = {ac.alpha_deg:g}°"
        panels.append(panel)
        c = ac.case
        theta = np.degrees(
            np.arccos(np.clip(np.asarray(c.channel_inputs[0]["cos_theta"], np.float64), -1, 1))
        )
        ref, err = c.reference.mean[c.mask][:, 0] / ac.e_perp, c.reference.stderr[c.mask][:, 0] / ac.e_perp
        keep = np.sort(rng.choice(theta.size, min(theta.size, 300), replace=False))
        series.append({"x": theta[keep], "y": ref[keep], "yerr": 2 * err[keep], "style": "points",
                       "label": "reference pixels (±2σ)", "panel": panel, "color": "k"})  # fmt: skip
        for k, row in enumerate(ROWS):
            style = {"color": "0.4"} if row == "exact" else {"color": f"C{k}", "ls": "--"}
            y = _row_curve(row, ac, smooth, np.cos(grid))
            series.append({"x": np.degrees(grid), "y": y, "label": TITLES[row], "panel": panel, **style})
    name = "figures/terminator.png"
    figures.line_plot(
        out / name, "angle θ between normal and light direction (°)", "E / E⊥", series, panels=panels
    )
    return Figure(
        file=name,
        section="results",
        caption="Irradiance across the terminator: the reference at every visible pixel (300 drawn, ±2σ) "
        "against the angle θ between its normal and the sun's direction (a disc at infinity gives one E(θ) "
        "for every normal), the exact closed form and each approximation. The exact irradiance reaches "
        "past 90° by α (the light is partly below the horizon there).",
    )


def params_figure(out: Path, cases: list[AlphaCase], smooth: Mapping) -> Figure:
    alphas = np.array([ac.alpha_deg for ac in cases])
    fine = np.linspace(alphas.min(), alphas.max(), 200)
    coeffs = {k: v["value"] for k, v in smooth["parameters"].items()}
    law = dict(zip(("w", "p"), SMOOTH_LAW(NUMPY_OPS, {"alpha": np.radians(fine)}, coeffs), strict=True))
    series = []
    for name in ("w", "p"):
        vals = [ac.wp()[name] for ac in cases]
        err = [2 * (v["stderr"] or 0.0) for v in vals]
        series.append({"x": alphas, "y": [v["value"] for v in vals], "yerr": err,
                       "label": f"{name}: per-α fit (±2σ)", "style": "points", "panel": name})  # fmt: skip
        series.append({"x": fine, "y": law[name], "label": f"{name}(α): smooth fit", "panel": name})
    file = "figures/wrap_parameters.png"
    figures.line_plot(out / file, "light angular radius α (°)", "parameter value", series, panels=["w", "p"])
    return Figure(
        file=file,
        section="fits",
        caption="Wrap parameters fitted per light size by the engine (points) and the smooth functions "
        "w(α) = w1·sin α + w2·sin²α, p(α) = 1 + p1·sin α + p2·sin²α fitted to them (lines).",
    )


def error_figure(out: Path, table: list[dict]) -> Figure:
    series = [
        {"x": [t["alpha_deg"] for t in table], "y": [t["rmse"][row] for t in table], "label": TITLES[row]}
        for row in ROWS
    ]
    series.append({"x": [t["alpha_deg"] for t in table], "y": [t["floor"] for t in table],
                   "label": "reference noise floor", "ls": ":", "color": "0.5"})  # fmt: skip
    file = "figures/error_vs_alpha.png"
    y_label = "RMSE / E⊥ (fraction of the lit peak)"
    figures.line_plot(out / file, "light angular radius α (°)", y_label, series, x_log=True, y_log=True)
    return Figure(
        file=file,
        section="results",
        caption="RMSE of each row against the reference irradiance, as a fraction of E⊥, vs the sun's "
        "angular radius, with the reference's own noise floor: values near the floor are not resolved.",
    )


# ================================================================================================= study
def _table(cases: list[AlphaCase], smooth: Mapping) -> list[dict]:
    """Per α: each row's RMSE / E⊥, the noise floor / E⊥ and the fitted (w, p) with their stderr."""
    table = []
    for ac in cases:
        rmse = {r: float(ac.rows[r].metrics["rmse"].value) / ac.e_perp for r in ROWS if r in ac.rows}
        s_rmse, _ = smooth_rmse(ac, smooth)
        rmse["wrap-smooth"] = s_rmse / ac.e_perp
        floor = float(ac.rows["exact"].metrics["rmse"].noise_floor) / ac.e_perp
        wp = {k: {"value": v["value"], "stderr": v["stderr"]} for k, v in ac.wp().items()}
        table.append({"alpha_deg": ac.alpha_deg, "case": ac.case.id, "rmse": rmse, "floor": floor, "wp": wp})
    return table


def _markdown(table: list[dict]) -> str:
    head = "| α | " + " | ".join(TITLES[r] for r in ROWS) + " | noise floor | w (fit) | p (fit) |"
    lines = [head, "|" + "---|" * (len(ROWS) + 4)]
    for t in table:
        w, p = t["wp"]["w"], t["wp"]["p"]
        cells = [f"{t['rmse'][r]:.3g}" for r in ROWS]
        lines.append(
            f"| {t['alpha_deg']:g}° | " + " | ".join(cells) + f" | {t['floor']:.3g} | "
            f"{w['value']:.4g} ± {w['stderr'] or 0:.2g} | {p['value']:.4g} ± {p['stderr'] or 0:.2g} |"
        )
    return "\n".join(lines)


def _summary(table: list[dict], smooth: Mapping) -> str:
    small, large = table[0], table[-1]
    c = {k: v["value"] for k, v in smooth["parameters"].items()}
    return (
        "Half-Lambert is far from any physical sphere light: its RMSE is "
        f"{small['rmse']['half-lambert']:.3g}·E⊥ at α = {small['alpha_deg']:g}° and "
        f"{large['rmse']['half-lambert']:.3g}·E⊥ at α = {large['alpha_deg']:g}°, "
        f"against {small['rmse']['lambert']:.3g} and {large['rmse']['lambert']:.3g} for plain Lambert. Wrap "
        f"lighting with (w, p) fitted per light size brings the error at α = {large['alpha_deg']:g}° to "
        f"{large['rmse']['wrap-fitted']:.3g}; one smooth law w(α) = "
        f"{prose.law_text((c['w1'], 'sin α'), (c['w2'], 'sin²α'))}, p(α) = "
        f"{prose.law_text((1, ''), (c['p1'], 'sin α'), (c['p2'], 'sin²α'))} gives "
        f"{large['rmse']['wrap-smooth']:.3g}. The exact closed form's {large['rmse']['exact']:.3g} is the "
        f"reference's noise floor ({large['floor']:.3g})."
    )


def _checks(cases: list[AlphaCase], smooth: Mapping) -> list[Check]:
    checks = [
        Check(name="smooth law w(α), p(α): fit converged", value=str(smooth.get("message", "")),
              expected="converged", passed=bool(smooth.get("converged"))),
    ]  # fmt: skip
    lim = LAMBERT_LIMIT
    for ac in (a for a in cases if a.alpha_deg <= lim["alpha_deg"]):
        w, p = ac.wp()["w"]["value"], ac.wp()["p"]["value"]
        dev = max(abs(w) / lim["w"], abs(p - 1.0) / lim["p"])
        checks.append(
            Check(
                name=f"wrap fit at α = {ac.alpha_deg:g}° tends to Lambert (w = {w:.3g}, p = {p:.4g})",
                value=dev,
                expected=f"|w| ≤ {lim['w']} and |p − 1| ≤ {lim['p']} (value: the larger ratio, ≤ 1)",
                passed=dev <= 1.0,
            )
        )
    return checks


def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run diffuse`` (module docstring), from the engine's audits of its scenes."""
    cases = alpha_cases(ctx.audits)
    if len(cases) < 2:
        raise ValueError(
            "diffuse study: the smooth law w(α), p(α) needs the suns of at least two shipped scenes"
        )
    out = Path(ctx.out_dir)
    smooth = fit_smooth([ac.alpha_deg for ac in cases], [ac.wp() for ac in cases])
    table = _table(cases, smooth)
    cos = np.concatenate([np.asarray(ac.case.channel_inputs[0]["cos_theta"], np.float64) for ac in cases])
    spp = max(ac.case.reference.spp for ac in cases)
    prov = fitfiles.provenance(None, "diffuse", [], reference_spp=spp, variant=ctx.variant, quick=ctx.quick)
    file = write_smooth_fitted(
        out, smooth, [ac.alpha_deg for ac in cases], (float(cos.min()), float(cos.max())), prov
    )
    coeffs = {k: v["value"] for k, v in smooth["parameters"].items()}
    text = (
        _summary(table, smooth)
        + "\n\nRMSE of each row as a fraction of E⊥ = π (the lit peak radiance of the "
        "white sphere is 1, so this is the error in the image's units), per sun size, on the unshadowed case "
        "(the sphere is convex); `wrap-smooth` is wrap at the smooth law's (w, p), fitted here to the "
        f"engine's per-α fits (`{file}`: the law composed with wrap, one shader for any α).\n\n"
        + _markdown(table)
    )
    return Study(
        sections=(
            Section(id="study-diffuse", title="Light size: the smooth law and the terminator", text=text),
        ),
        figures=(
            error_figure(out, table),
            terminator_figure(out, cases, smooth),
            params_figure(out, cases, smooth),
        ),
        checks=tuple(_checks(cases, smooth)),
        extra={"per_alpha": table, "smooth_law": coeffs, "smooth_law_file": file},
    )
