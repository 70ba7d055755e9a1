"""The soft-particles family's own study for ``rtfit run soft-particles`` (issue 30 §1): what only it has.

The engine (`rtfit.experiments.engine_run`) audits the shipped scenes (`audit_soft_particles.SCENES`: a
sphere or a cube of absorbing medium cut by a tilted opaque plane, α_c = 0.95 and 0.5, the camera outside
and inside the sphere) exactly as ``rtfit audit`` audits a user's scene: every fade against the path-traced
clipped opacity, their fade distances fitted to each scene, costs, and the exact row's self-check. This study
renders nothing; it reads those audits and adds (docs/soft-particles.md):

1. **The claim** of issue 18 from the kernels: a linear fade of α = 0.95 over half the chord gives 0.475
   against the exact 1 − √0.05 = 0.776 (Beer–Lambert is concave in the chord).
2. **The reference against the analytic chord** per shipped scene: the engine's reference opacity against
   the ``exact-<shape>`` kernel in float64 (NumPy run of its text) by z-scores with the known binomial noise
   √(T(1 − T)/N) — spread, pooled z, Šidák bound, and exactly 0 where the clipped chord is 0.
3. **The methods over their whole domain** (`random_domain`): random particles within 25° of the view axis,
   random pixels on their billboards, scene depths Δ/r ∈ [−1.3, 1.3]; the error of every row per shape and
   α_c, the mean error profile against Δ/r, and the fades' parameters (``linear``'s s, ``fitted``'s s, b, p)
   fitted per shape and α_c through the JAX run of their kernels, written to
   ``fitted/soft-particles-domain.json`` (the engine's ``fitted/soft-particles.json`` holds the per-scene
   fits).
4. **Chords and float32**: the analytic chords against an independent midpoint count; every kernel in float32
   over its declared domain and parameter bounds (no NaN/Inf, opacity in [0, 1]).
5. **Extremes**: camera inside the particle, s → 0, Δ ≤ 0, huge σ, view-z against ray length off-axis.
6. **A 100-particle scene** straddling a ground plane and a box (closed-form geometry): composited opacity
   1 − Π(1 − α'_i) of every row against the exact 1 − exp(−Σσ_iℓ_i), with error maps.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rtfit.fitting import fit_method, sidak_threshold
from rtfit.realtime.soft_particles import BIG, METHODS, billboard_alpha

from . import figures as F
from . import fitted as fitfiles
from .particle_geometry import RADIUS, billboard_inputs, sigma_of
from .records import Check, Figure, Headline, Section
from .report_text import markdown_table
from .shipped import Study, StudyContext
from .soft_particles_kernels import (
    chord_checks,
    claim_checks,
    evaluate32,
    exact64,
    extreme_checks,
    extreme_values,
    finite_checks,
    pixel_dirs,
    ray_inputs,
)

__all__ = ["DOMAIN", "domain_study", "particle_scene", "reference_checks", "study", "write_fitted"]

DOMAIN = {
    True: {"fit_alphas": (0.5, 0.95), "samples": 4000, "scene": (64, 40)},
    False: {"fit_alphas": (0.3, 0.5, 0.7, 0.9, 0.95), "samples": 100000, "scene": (256, 160)},
}
"""The domain study's and the 100-particle scene's sizes, ``--quick`` (True) and full (False)."""
SHAPES = ("sphere", "box")
ROWS = ("linear", "linear-fit", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray", "fitted")
"""The study's rows: every fade, and the seed's fade with its s fitted over the domain (``linear-fit``)."""
FIT_MAX_STEPS = 400
FIT_RESIDUAL_UNITS = "opacity (model − exact clipped Beer–Lambert), unweighted"


def row_params(row: str, shape: str, alpha_c: float, fits: dict) -> tuple[str, dict]:
    """(kernel id, parameters) of a study row: ``linear-fit`` and ``fitted`` at the parameters fitted for the
    nearest α_c of the domain study on this shape."""
    if row in ("linear-fit", "fitted"):
        key = min((k for k in fits if k[0] == shape and k[1] == row), key=lambda k: abs(k[2] - alpha_c))
        return ("linear" if row == "linear-fit" else "fitted"), {
            n: v["value"] for n, v in fits[key]["parameters"].items()
        }
    return row, {}


# ============================================================================ reference vs the chords
def reference_checks(audits) -> tuple[list[Check], list[list[str]]]:
    """Each shipped scene's reference opacity (the engine's, path-traced) against the analytic clipped chord
    in float64, by z-scores with the binomial noise √(T(1 − T)/N) of N Bernoulli samples (T = 1 − exact);
    and the table of those z statistics."""
    checks, table = [], []
    for r in audits:
        for case in r.cases:
            shape = case.parameters.get("shape")
            if shape not in SHAPES:
                continue
            mask, n = case.mask, int(case.reference.spp)
            exact = exact64(shape, case.channel_inputs[0])
            ref = case.reference.mean[mask][:, 0]
            t = 1.0 - exact
            se = np.sqrt(np.maximum(t * (1.0 - t), 0.0) / n)
            ok = se > 0.0
            z = (ref[ok] - exact[ok]) / se[ok]
            spread, pooled = float(np.std(z)), float(np.sum(z) / math.sqrt(max(z.size, 1)))
            zmax, sidak = float(np.max(np.abs(z), initial=0.0)), sidak_threshold(max(z.size, 1))
            zero = float(np.max(np.abs(ref[~ok] - exact[~ok]), initial=0.0))
            table.append(
                [case.id, str(z.size), f"{spread:.3f}", f"{pooled:+.2f}", f"{zmax:.2f}", f"{sidak:.2f}"]
            )
            head = f"reference {case.id}: path-traced opacity vs the analytic clipped chord"
            checks += [
                Check.within(
                    f"{head}, z-score spread ({z.size} pixels, binomial noise √(T(1 − T)/N))",
                    spread,
                    "1",
                    "0.2",
                ),
                Check.magnitude_at_most(f"{head}, pooled z", pooled, "z", "4"),
                Check.at_most(
                    f"{head}, largest |z|", zmax, sidak, fmt=".2f", note="(Šidák, 1 % family-wise)"
                ),
                Check.zero(
                    f"{head}: exactly the exact value where T is 0 or 1 (no chord, or saturated)", zero
                ),
            ]
    return checks, table


# ====================================================================================== domain study
def random_domain(shape: str, alpha_c: float, n: int, seed: int = 11) -> tuple[dict, dict]:
    """Random pixels of random particles (r = 1): centres at view distance 2–30 r within 25° of the view
    axis, pixels uniform on the billboard's disc (sphere) or square (box), scene depths Δ/r ∈ U(−1.3, 1.3)
    (a surface of constant view depth behind the pixel). Returns (billboard inputs, exact inputs)."""
    rng = np.random.default_rng(seed)
    dist = rng.uniform(2.0, 30.0, n)
    theta = np.radians(25.0) * np.sqrt(rng.uniform(0.0, 1.0, n))
    phi = rng.uniform(0.0, 2 * math.pi, n)
    c = (
        np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
        * dist[:, None]
    )
    if shape == "sphere":
        rad, ang = np.sqrt(rng.uniform(0.0, 1.0, n)), rng.uniform(0.0, 2 * math.pi, n)
        u, v = rad * np.cos(ang), rad * np.sin(ang)
    else:
        u, v = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    p = c + np.stack([u, v, np.zeros(n)], -1) * RADIUS
    dirs = p / np.linalg.norm(p, axis=-1, keepdims=True)
    ts = (c[:, 2] + rng.uniform(-1.3, 1.3, n) * RADIUS) / dirs[:, 2]
    z = c[:, 2]
    px, py = dirs[:, 0] * z / dirs[:, 2] - c[:, 0], dirs[:, 1] * z / dirs[:, 2] - c[:, 1]
    q = np.hypot(px, py)
    if shape == "sphere":
        alpha = np.asarray(billboard_alpha(np.full(n, alpha_c), np.full(n, RADIUS), q), np.float64)
    else:
        alpha = np.where(np.maximum(np.abs(px), np.abs(py)) <= RADIUS * (1 + 1e-9), alpha_c, 0.0)
    bb = {
        "alpha": alpha,
        "alpha_c": np.full(n, alpha_c),
        "z": z,
        "delta": ts * dirs[:, 2] - z,
        "radius": np.full(n, RADIUS),
        "q": q,
        "cos_view": dirs[:, 2].copy(),
    }
    return bb, ray_inputs(dirs, c, RADIUS, sigma_of(alpha_c, RADIUS), ts)


def domain_study(fit_alphas, samples: int) -> dict:
    """Errors of every row per (shape, α_c) over `random_domain`, with the fits of ``linear`` (s) and
    ``fitted`` (s, b, p) to the exact opacity (unweighted least squares), and the mean error per Δ/r bin."""
    table, fits, checks, profiles = [], {}, [], {}
    bins = np.linspace(-1.3, 1.3, 14)
    for shape in SHAPES:
        for alpha_c in fit_alphas:
            bb, ex = random_domain(shape, alpha_c, samples)
            exact = exact64(shape, ex)
            for fid, kernel in (("linear-fit", "linear"), ("fitted", "fitted")):
                m = METHODS[kernel]
                fit = fit_method(
                    m, {k: bb[k] for k in m.input_names}, exact, max_steps=FIT_MAX_STEPS, solver="trf"
                )
                fits[(shape, fid, alpha_c)] = fit.to_dict()
            prof: dict = {"delta_over_r": [float(x) for x in 0.5 * (bins[1:] + bins[:-1])]}
            idx = np.digitize(bb["delta"] / RADIUS, bins) - 1
            for row in ROWS:
                kernel, par = row_params(row, shape, alpha_c, fits)
                err = evaluate32(kernel, bb, par) - exact
                table.append(
                    {
                        "shape": shape,
                        "alpha_c": alpha_c,
                        "method": row,
                        "mean_error": float(np.mean(err)),
                        "mean_abs_error": float(np.mean(np.abs(err))),
                        "rms_error": float(np.sqrt(np.mean(err**2))),
                        "max_abs_error": float(np.max(np.abs(err))),
                        "parameters": {k: float(v) for k, v in par.items()},
                    }
                )
                prof[row] = [float(np.mean(err[idx == b])) if np.any(idx == b) else 0.0 for b in range(13)]
            profiles[(shape, alpha_c)] = prof
            by = {
                t["method"]: t["rms_error"] for t in table if t["shape"] == shape and t["alpha_c"] == alpha_c
            }
            checks.append(
                Check(
                    name=f"domain {shape}, α_c = {alpha_c:g}: the fitted fade's RMS error ≤ the fitted "
                    "linear fade's (it contains it: b = 0, p = 1)",
                    value=by["fitted"],
                    expected=f"≤ {by['linear-fit']:.4g}",
                    passed=by["fitted"] <= by["linear-fit"] * (1 + 1e-6),
                )
            )
    for (shape, fid, alpha_c), res in fits.items():
        checks.append(Check.holds(f"fit {fid} ({shape}, α_c = {alpha_c:g}) converged", res["converged"]))
    return {"table": table, "fits": fits, "checks": checks, "profiles": profiles}


def write_fitted(out: Path, fits: dict, prov) -> str:
    """``fitted/soft-particles-domain.json``: every domain fit (``rtfit.fitted/1``); returns its path."""
    entries = []
    for (shape, fid, alpha_c), fit in fits.items():
        kernel = "linear" if fid == "linear-fit" else "fitted"
        entries.append(
            fitfiles.method_entry(
                METHODS[kernel],
                fit,
                id=fid.replace("-", "_"),
                label=f"{METHODS[kernel].label}, {shape}, α_c = {alpha_c:g}",
                case=f"{shape}_a{alpha_c:g}".replace(".", "_"),
                domain={
                    "delta": (-1.3, 1.3, "m"),
                    "radius": (RADIUS, RADIUS, "m"),
                    "alpha": (0.0, alpha_c, "1"),
                },
                residual_units=FIT_RESIDUAL_UNITS,
            )
        )
    file = "fitted/soft-particles-domain.json"
    title = "soft particles: fade parameters fitted over the domain to the exact clipped Beer–Lambert opacity"
    fitfiles.write_fitted(
        Path(out) / file,
        fitfiles.FittedFile(format=fitfiles.FORMAT, title=title, provenance=prov, methods=entries),
    )
    return file


# ================================================================================ 100-particle scene
GROUND_Y = -1.5
SCENE_BOX = ((1.5, -0.5, 11.0), 1.0)
"""The composited scene's opaque ground plane y = −1.5 and box (centre, half-size) in view space."""


def scene_surface(dirs: np.ndarray) -> np.ndarray:
    """Ray distance to the first opaque surface (ground plane, box); `BIG` for the sky."""
    t_ground = np.where(dirs[:, 1] < -1e-9, GROUND_Y / np.minimum(dirs[:, 1], -1e-9), BIG)
    centre, h = SCENE_BOX
    lo, hi = np.full(len(dirs), -np.inf), np.full(len(dirs), np.inf)
    for k, c in enumerate(centre):
        dk = dirs[:, k]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (c - h) / dk, (c + h) / dk
        par = np.abs(dk) < 1e-12
        lo = np.maximum(lo, np.where(par, np.where(abs(c) <= h, -np.inf, np.inf), np.minimum(t1, t2)))
        hi = np.minimum(hi, np.where(par, np.where(abs(c) <= h, np.inf, -np.inf), np.maximum(t1, t2)))
    return np.minimum(t_ground, np.where((hi >= lo) & (lo > 0), lo, BIG))


def particle_scene(resolution, fits: dict, n: int = 100, seed: int = 21) -> dict:
    """``n`` spherical particles (centres x ∈ [−7, 7], y ∈ [−2.3, −0.3], z ∈ [6, 20], radii 0.3–1, α_c
    0.2–0.9: many straddle the ground or the box). Composited opacity 1 − Π(1 − α'_i) of every row against
    the exact 1 − Π(1 − α_exact,i) = 1 − exp(−Σσ_iℓ_i) (optical depths add)."""
    w, h = resolution
    dirs = pixel_dirs(resolution, 50.0).reshape(-1, 3)
    ts = scene_surface(dirs)
    rng = np.random.default_rng(seed)
    centres = np.stack([rng.uniform(-7, 7, n), rng.uniform(-2.3, -0.3, n), rng.uniform(6, 20, n)], -1)
    radii, alphas = rng.uniform(0.3, 1.0, n), rng.uniform(0.2, 0.9, n)
    log_t = {row: np.zeros(len(dirs)) for row in ("exact", *ROWS)}
    straddle, silhouette, silhouette_max = 0, 0, 0.0
    for c, r, a in zip(centres, radii, alphas, strict=True):
        sig = sigma_of(float(a), float(r))
        ex = exact64("sphere", ray_inputs(dirs, c, float(r), sig, ts))
        full = exact64("sphere", ray_inputs(dirs, c, float(r), sig, np.full(len(dirs), BIG)))
        straddle += int(np.any((ex < full - 1e-9) & (ex > 0)))
        log_t["exact"] += np.log1p(-np.minimum(ex, 1 - 1e-16))
        bb = billboard_inputs(dirs, c, float(r), float(a), "sphere", ts)
        missed = (bb["alpha"] <= 0.0) & (ex > 0.0)  # the sphere's perspective silhouette beyond the billboard
        silhouette += int(missed.sum())
        silhouette_max = max(silhouette_max, float(np.max(ex[missed], initial=0.0)))
        for row in ROWS:
            kernel, par = row_params(row, "sphere", float(a), fits)
            log_t[row] += np.log1p(-np.minimum(evaluate32(kernel, bb, par), 1 - 1e-16))
    exact = (1.0 - np.exp(log_t["exact"])).reshape(h, w)
    images = {row: (1.0 - np.exp(log_t[row])).reshape(h, w) for row in ROWS}
    mask = exact > 1e-6
    metrics = {}
    for row in ROWS:
        err = images[row][mask] - exact[mask]
        metrics[row] = {
            "rmse": float(np.sqrt(np.mean(err**2))),
            "mae": float(np.mean(np.abs(err))),
            "max_abs": float(np.max(np.abs(err))),
            "mean_error": float(np.mean(err)),
        }
    finite = all(bool(np.all(np.isfinite(images[row]))) for row in ROWS)
    checks = [
        Check.holds(f"{n}-particle scene: composited opacity of every row finite", finite),
        Check.at_least(
            f"{n}-particle scene: at least a fifth of the particles are cut by the geometry", straddle, n // 5
        ),
    ]
    return {
        "exact": exact,
        "images": images,
        "mask": mask,
        "metrics": metrics,
        "checks": checks,
        "n": n,
        "straddle": straddle,
        "silhouette": silhouette,
        "silhouette_max": silhouette_max,
    }


# ======================================================================================= report parts
def _grey(img: np.ndarray) -> np.ndarray:
    return np.repeat(img[..., None], 3, axis=-1)


def _figures(out: Path, dom: dict, scene: dict) -> list[Figure]:
    fdir = out / "figures"
    F.image_comparison(
        fdir / "scene-100.png",
        _grey(scene["exact"]),
        [(row, _grey(scene["images"][row])) for row in ROWS],
        scene["mask"],
        error_scale=1.0,
        title="100 particles straddling a ground plane and a box: composited opacity",
        exposure=1.0,
    )
    series, panels = [], []
    for (shape, alpha_c), prof in dom["profiles"].items():
        panels.append(panel := f"{shape}, α_c = {alpha_c:g}")
        series += [
            {"x": prof["delta_over_r"], "y": prof[row], "label": row, "style": "line", "panel": panel}
            for row in ROWS
        ]
    F.line_plot(
        fdir / "error_vs_delta.png", "Δ/r (scene depth − particle depth)", "mean error", series, panels=panels
    )
    return [
        Figure(
            file="figures/scene-100.png",
            section="study-soft-particles",
            caption="The 100-particle scene: exact composited opacity 1 − exp(−Σσℓ) and each row's "
            "1 − Π(1 − α'); the error maps (opacity units) show where each fade fails: linear fades lose the "
            "dense particles' cores near contact, the view-z methods the slanted rays at the edges.",
        ),
        Figure(
            file="figures/error_vs_delta.png",
            section="study-soft-particles",
            caption="Mean signed opacity error against the exact clipped Beer–Lambert opacity per bin of Δ/r "
            "over the domain study, per shape and α_c.",
        ),
    ]


def _text(dom: dict, ext: dict, scene: dict, ref_table: list) -> str:
    keys = ("mean_error", "mean_abs_error", "rms_error", "max_abs_error")
    fmts = ("+.4f", ".4f", ".4f", ".3f")
    domain = markdown_table(
        ["shape", "α_c", "row", "mean error", "mean |error|", "RMS", "max |error|"],
        [
            [
                t["shape"],
                f"{t['alpha_c']:g}",
                t["method"],
                *(f"{t[k]:{f}}" for k, f in zip(keys, fmts, strict=True)),
            ]
            for t in dom["table"]
        ],
    )
    fit_rows = [
        [
            fid,
            shape,
            f"{a:g}",
            ", ".join(f"{k} = {v['value']:.4g}" for k, v in f["parameters"].items()),
            f"{f['rms_residual']:.4g}",
        ]
        for (shape, fid, a), f in dom["fits"].items()
    ]
    cols = ("linear", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray")
    ext_rows = [
        [f"{g}: {k}", f"{v['exact']:.4f}", *(f"{v[c]:.4f}" for c in cols)]
        for g in ("camera_inside", "delta", "off_axis")
        for k, v in ext[g].items()
    ]
    sc = markdown_table(
        ["row", "RMS", "mean |error|", "max |error|", "mean error"],
        [
            [
                row,
                *(
                    f"{m[k]:{f}}"
                    for k, f in (("rmse", ".4f"), ("mae", ".4f"), ("max_abs", ".3f"), ("mean_error", "+.4f"))
                ),
            ]
            for row, m in scene["metrics"].items()
        ],
    )
    return "\n\n".join(
        [
            "**The claim.** A homogeneous particle of extinction σ (α_c = 1 − e^(−2σr) through its centre) "
            "has opacity 1 − exp(−σℓ), ℓ the chord in front of the opaque surface. A linear fade scales α by "
            "a fraction of the chord, but Beer–Lambert is concave in it: 1 − (1 − α)^f ≥ α·f, so every "
            "linear fade under-estimates a dense particle (α = 0.95, half the chord: 0.475 against 0.776).",
            "**The reference against the analytic chord** (each shipped scene; z = (reference − exact)"
            "/√(T(1 − T)/N)):\n\n"
            + markdown_table(["case", "pixels", "z spread", "pooled z", "max |z|", "Šidák"], ref_table),
            "**Errors over the domain** (random particles within 25° of the view axis, Δ/r ∈ [−1.3, 1.3]; "
            "`linear-fit` and `fitted` at the domain fits below):\n\n" + domain,
            "**Fade parameters fitted over the domain** (`fitted/soft-particles-domain.json`; the engine's "
            "fits to each shipped scene are in `fitted/soft-particles.json`):\n\n"
            + markdown_table(["fit", "shape", "α_c", "parameters", "RMS residual"], fit_rows),
            "**Extremes** (sphere of α_c = 0.95, r = 1: camera inside with its centre at z < r; Δ with its "
            "centre at z = 4 r; a box off-axis, the ray at θ through its centre and the surface at the "
            "centre's depth: the view-z methods' optical depth is cos θ of the ray's):\n\n"
            + markdown_table(["case", "exact", *cols], ext_rows),
            f"**{scene['n']} particles straddling geometry** ({scene['straddle']} cut by it): composited "
            f"opacity error per covered pixel:\n\n{sc}\n\n{scene['silhouette']} (pixel, particle) pairs "
            "lie inside a sphere's perspective silhouette but outside its view-plane billboard of radius r "
            "(α = 0): every billboard method misses them, exact opacity up to "
            f"{scene['silhouette_max']:.2f} (the largest errors of every row).",
        ]
    )


def study(ctx: StudyContext) -> Study:
    """The study of ``rtfit run soft-particles`` (module docstring), from the engine's audits."""
    out = Path(ctx.out_dir)
    size = DOMAIN[bool(ctx.quick)]
    ref_checks, ref_table = reference_checks(ctx.audits)
    dom = domain_study(size["fit_alphas"], size["samples"])
    ext = extreme_values()
    scene = particle_scene(size["scene"], dom["fits"])
    prov = fitfiles.provenance(None, "soft-particles", [], variant=ctx.variant, quick=ctx.quick)
    file = write_fitted(out, dom["fits"], prov)
    checks = (
        claim_checks()
        + ref_checks
        + chord_checks()
        + finite_checks()
        + extreme_checks(ext)
        + dom["checks"]
        + scene["checks"]
    )
    hi = max(size["fit_alphas"])
    rms = {t["method"]: t["rms_error"] for t in dom["table"] if t["shape"] == "sphere" and t["alpha_c"] == hi}
    headline = (
        Headline(label=f"domain RMS opacity error, sphere α_c = {hi:g}: linear (s = r)", value=rms["linear"]),
        Headline(
            label=f"domain RMS opacity error, sphere α_c = {hi:g}: spherical billboard",
            value=rms["spherical"],
        ),
        Headline(
            label="100-particle scene RMS: spherical-ray", value=scene["metrics"]["spherical-ray"]["rmse"]
        ),
    )
    return Study(
        sections=(
            Section(
                id="study-soft-particles",
                title="The family's own study: claim, chords, domain, extremes, 100 particles",
                text=_text(dom, ext, scene, ref_table),
                placement="after_results",
            ),
        ),
        figures=tuple(_figures(out, dom, scene)),
        checks=tuple(checks),
        headline=headline,
        extra={
            "domain_study": dom["table"],
            "domain_fits_file": file,
            "extremes": ext,
            "scene_100": {k: scene[k] for k in ("metrics", "straddle", "silhouette", "silhouette_max")},
        },
    )
