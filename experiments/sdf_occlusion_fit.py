"""The sdf-occlusion family's fits, sweep and fitted files, read by the study leaf
`rtfit.experiments.sdf_occlusion_study` (issue 30 §1); nothing here renders.

The continuous Evans fit (rows ``evans-fit``, ``evans-joint``, ``evans-analytic``, ``evans-on-sdfgrid``: α and
the base distance fitted too, which the engine's rows cannot, their sample terms moving with them): (1) at
every (α, base) of a small grid C = exp(log B − Σ_i c_i D_i) is linear in (log B, c_i = k·w_i) inside the
exponent and those are fitted (`fit_free`); (2) from the best point, x = (log B, c_i, α, base in voxels)
together (`fit_evans_continuous`), by the bounded Levenberg–Marquardt of `rtfit.fitting.bounded_lm` within the
``evans-fit`` method's declared bounds. C is `evans_from_terms_kernel` (the one text of the formula);
∂r/∂log B = g C, ∂r/∂c_i = −g C D_i, the α and base columns by Dr.Jit forward-mode autodiff through the kernel
(`evans_terms_jacobian`; mip levels stay discrete: piecewise smooth residuals). Standard errors s²(JᵀJ)⁺
(`bounded_lm_result`), the delta method for k = c_1, w_i = c_i/c_1, B = e^{log B}: a linearised spread
(pixel residuals are correlated and model-dominated), not a sampling error. Under the ``sunsky`` sky every
approximation C is multiplied by the unoccluded sky's factor g(N) (`sky_factor`); fits fit C to y/g with
weight g (g·C − y).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from rtfit.fitting import bounded_lm, bounded_lm_result, fit_method, param_bounds, zero_padded
from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS, backend_float, to_drjit
from rtfit.realtime.sdf_grid import quantize_8bit
from rtfit.realtime.sdf_occlusion import (
    CURVATURE_LEVEL,
    EVANS_SAMPLES,
    EXP_MAX,
    EXP_MIN,
    METHODS,
    EvansParams,
    GridSDF,
    cone_occlusion,
    evans_exponent_kernel,
    evans_from_terms_kernel,
    evans_kernel,
    evans_terms,
    evans_terms_jacobian,
)

from . import fitted as fitfiles
from .cost import time_drjit

ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0)
BASES_VOX = (0.5, 1.0, 2.0)
CONE_KS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
FIT_POINTS = 2048  # pixels per scene used by the fits (padded: one JAX compile per model size)
SUNSKY_TARGETS = ("sunsky", "sunsky-gi")
HELD_OUT = "character"
TARGET_LABEL = {
    "ao": "AO (cosine-weighted visibility within R)",
    "sky": "sky light, one bounce (E/πL)",
    "sky-gi": "sky light, global illumination (E/πL)",
    "sunsky": "sunsky sky light without the sun, one bounce (E/E_h)",
    "sunsky-gi": "sunsky sky light without the sun, global illumination (E/E_h)",
}


def sky_factor(normals, directions, weights, radiance) -> np.ndarray:
    """The unoccluded sky's directional factor g(N) = E_sky(N)/E_u(N) at unit ``normals`` (M, 3), from
    quadrature nodes of the sky above the horizon (``directions`` (K, 3) with d_z > 0, solid-angle
    ``weights`` (K,), ``radiance`` (K,)):

        E_sky(N) = Σ_k w_k L_k max(N·d_k, 0),   E_u(N) = (E_h/π) Σ_k w_k max(N·d_k, 0),
        E_h = Σ_k w_k L_k d_k,z

    E_u is the irradiance of a constant upper-hemisphere sky of the same horizontal irradiance E_h
    (→ E_h (1 + N_z)/2 as the nodes refine), on the same nodes, so a constant L gives g ≡ 1 exactly and the
    sky target E/E_h ≈ g(N)·C reduces to the constant-sky model E/(πL) ≈ C. g is the cosine-weighted mean of
    L/L̄ (L̄ = E_h/π) over the part of the upper sky that N faces; g = 1 where N faces none of it (N = −Z)."""
    n_all = np.asarray(normals, np.float64)
    d = np.asarray(directions, np.float64)
    w = np.asarray(weights, np.float64)
    lum = np.asarray(radiance, np.float64)
    shapes = (n_all.shape[1:], d.shape[1:], w.shape, lum.shape)
    if n_all.ndim != 2 or d.ndim != 2 or shapes != ((3,), (3,), (len(d),), (len(d),)):
        raise ValueError("sky_factor needs normals (M, 3), directions (K, 3), weights (K,), radiance (K,)")
    if len(d) == 0 or np.any(d[:, 2] <= 0) or np.any(w < 0) or np.any(lum < 0):
        raise ValueError("sky_factor needs nodes above the horizon (d_z > 0) with weights and radiance >= 0")
    e_h = float((w * lum) @ d[:, 2])
    if not e_h > 0:
        raise ValueError("sky_factor: the sky has no horizontal irradiance")
    # g depends on N alone: computed once per distinct normal (a flat face's pixels share one)
    n, back = np.unique(n_all, axis=0, return_inverse=True) if len(n_all) else (n_all, np.zeros(0, int))
    num = np.empty(len(n))
    den = np.empty(len(n))
    per = max(1, (1 << 22) // len(d))
    wl = w * lum
    for a in range(0, len(n), per):
        cos = np.maximum(n[a : a + per] @ d.T, 0.0)
        num[a : a + per] = cos @ wl
        den[a : a + per] = (cos @ w) * (e_h / math.pi)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)[back.reshape(-1)]


@dataclasses.dataclass(frozen=True)
class EvansFitData:
    """One scene's share of an Evans fit: surface ``points`` and unit ``normals`` (M, 3), its ``sdf``
    (`GridSDF` or `AnalyticSDF`), ``voxel`` (scene units per base-distance voxel), the ``target`` (M,) and the
    per-point sky factor ``factor`` g (M,) (None: 1, for AO and the constant sky). Prediction: g·C."""

    points: np.ndarray
    normals: np.ndarray
    sdf: object
    voxel: float
    target: np.ndarray
    factor: np.ndarray | None = None

    def __post_init__(self):
        m = len(self.target)
        if np.shape(self.points) != (m, 3) or np.shape(self.normals) != (m, 3):
            raise ValueError(
                f"points and normals must be ({m}, 3) like the target (got "
                f"{np.shape(self.points)} and {np.shape(self.normals)})"
            )
        if self.factor is not None and np.shape(self.factor) != (m,):
            raise ValueError(f"factor must have shape ({m},) (got {np.shape(self.factor)})")
        if not (self.voxel > 0):
            raise ValueError(f"voxel must be > 0 (got {self.voxel!r})")


def evans_param_names(n: int) -> list[str]:
    return ["logB"] + [f"c{i + 1}" for i in range(n)] + ["alpha", "base_voxels"]


def evans_fit_bounds(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the continuous Evans fit over `evans_param_names` (n), from the ``evans-fit`` method's
    declared parameters: c_i = k·w_i ≥ 0 (`EvansParams` needs k, w_i ≥ 0; every c_i has c1's bounds),
    |log B| ≤ 5, α ∈ [0, 1], base from ¼ to 4 voxels of the finest grid."""
    params = METHODS["evans-fit"].params
    per = {nm: params.get(nm, params["c1"]) for nm in evans_param_names(n)}
    return param_bounds(per, list(per))


def evans_value_and_slope(d, logb, c):
    """C = `evans_from_terms_kernel` at (log B, c_i; k = 1) on the terms ``d`` (n, M), and ∂C/∂e (C inside
    the clamp of the exponent e, else 0): the one text of the formula, and the factor of its Jacobian."""
    e = evans_exponent_kernel(NUMPY_OPS, d, logB=logb, weights=c)
    pred = evans_from_terms_kernel(NUMPY_OPS, d, logB=logb, weights=c)
    return pred, np.where((e > EXP_MIN) & (e < EXP_MAX), pred, 0.0)


def evans_fit_residuals(x, data: list, n: int, *, jacobian: bool = True):
    """Residuals r = g·C − y over all scenes of ``data`` (list of `EvansFitData`) at
    x = (log B, c_1..c_n, α, base_voxels), C = exp(clip(log B − Σ c_i D_i, −87, 80)), and (``jacobian``) their
    Jacobian (m, n + 3): from ∂C/∂e in log B and c_i, Dr.Jit forward-mode autodiff in α and base (columns
    are 0 where the exponent is clipped)."""
    x = np.asarray(x, dtype=np.float64)
    logb, c, alpha, base_v = x[0], x[1 : 1 + n], float(x[1 + n]), float(x[2 + n])
    rs, js = [], []
    for dd in data:
        prm = EvansParams(n=n, base=base_v * dd.voxel, k=1.0, alpha=alpha)
        if jacobian:
            d, da, db = evans_terms_jacobian(dd.points, dd.normals, dd.sdf, prm)
        else:
            d = evans_terms(dd.points, dd.normals, dd.sdf, prm)
        pred, pl = evans_value_and_slope(d, logb, c)
        if dd.factor is not None:
            pred, pl = pred * dd.factor, pl * dd.factor
        rs.append(pred - dd.target)
        if jacobian:
            js.append(np.column_stack([pl, -pl[:, None] * d.T, -pl * (c @ da), -pl * (c @ db) * dd.voxel]))
    r = np.concatenate(rs)
    return (r, np.concatenate(js)) if jacobian else r


def fit_evans_continuous(data: list, init: dict, n: int, *, max_iter: int = 100) -> dict:
    """The continuous Evans fit (module docstring, stage 2) from ``init`` = {"logB", "c1".."cn", "alpha",
    "base_voxels"} (the grid profile's best point). Returns {"fit": `FitResult.to_dict()` over
    `evans_param_names`, "alpha", "base_vox", "init", "cov", "lm": {iterations, evaluations, message}}."""
    if not data:
        raise ValueError("fit_evans_continuous needs at least one scene")
    names = evans_param_names(n)
    missing = [k for k in names if k not in init]
    if missing:
        raise ValueError(f"init lacks {', '.join(missing)}")
    lo, hi = evans_fit_bounds(n)
    x0 = np.array([float(init[k]) for k in names])
    out = bounded_lm(lambda x: evans_fit_residuals(x, data, n), x0, lo, hi, max_iter=max_iter)
    fr, cov = bounded_lm_result(names, out, lo, hi)
    x = out["x"]
    return {
        "fit": fr.to_dict(),
        "alpha": float(x[1 + n]),
        "base_vox": float(x[2 + n]),
        "init": {k: float(v) for k, v in init.items()},
        "cov": cov,
        "lm": {"iterations": out["iterations"], "evaluations": out["evaluations"], "message": out["message"]},
    }


def evans_readable(best: dict, voxel: float | None) -> dict:
    """k, w_i, B, α, base (voxels and, with ``voxel``, scene units) and their standard errors from a fit of
    (log B, c_i[, α, base_voxels]): k = c_1, w_i = c_i/c_1, B = e^{log B}; delta method with the fit's
    covariance (``best["cov"]``, else the diagonal stderr only). Values and stderrs as floats (NaN: none)."""
    f = best["fit"]["parameters"]
    n = len([k for k in f if k.startswith("c") and k[1:].isdigit()])
    v = {k: p["value"] for k, p in f.items()}
    se = {k: (p["stderr"] if p["stderr"] is not None else math.nan) for k, p in f.items()}
    names = list(f)
    cov = best.get("cov")

    def cv(a, b):
        if cov is not None and a in names and b in names:
            return float(cov[names.index(a), names.index(b)])
        return se[a] ** 2 if a == b else 0.0

    k = v["c1"]
    out = {
        "k": k,
        "k_stderr": se["c1"],
        "B": math.exp(v["logB"]),
        "B_stderr": math.exp(v["logB"]) * se["logB"],
    }
    for i in range(1, n):
        ci = v[f"c{i + 1}"]
        w = ci / k if k != 0 else 0.0
        c = f"c{i + 1}"
        var = (cv(c, c) + w * w * cv("c1", "c1") - 2 * w * cv("c1", c)) / k**2 if k else math.nan
        out[f"w{i + 1}"] = w
        out[f"w{i + 1}_stderr"] = math.sqrt(var) if var >= 0 else math.nan
    a = f["alpha"]["value"] if "alpha" in f else best["alpha"]
    b = f["base_voxels"]["value"] if "base_voxels" in f else best["base_vox"]
    out["alpha"] = a
    out["alpha_stderr"] = se.get("alpha", math.nan)
    out["base_voxels"] = b
    out["base_voxels_stderr"] = se.get("base_voxels", math.nan)
    if voxel is not None:
        out["base"] = b * voxel
        out["base_stderr"] = out["base_voxels_stderr"] * voxel
    return out


def subsample(n_pts: int, seed: int, size: int = FIT_POINTS):
    """Indices of at most ``size`` points and a 0/1 weight vector of length ``size`` (padding)."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(n_pts, size=min(n_pts, size), replace=False))
    w = np.zeros(size)
    w[: len(idx)] = 1.0
    return idx, w


class SceneData:
    """One audited scene as the fits read it: ``name`` (e.g. ``boxes``), the engine's visible
    ``points``/``normals`` (N, 3) and ``mask``, the distance field ``sdf`` (`GridSDF`: the engine's), the
    references ``refs`` (target → (mean, stderr) over the points), the sunsky factor g (``factor``, None for
    none) and ``analytic`` (the primitives' exact `AnalyticSDF`, or None). Memoises the Evans terms."""

    def __init__(self, name, points, normals, mask, sdf, refs, factor=None, analytic=None):
        self.name = name
        self.points = np.asarray(points, np.float64)
        self.normals = np.asarray(normals, np.float64)
        self.mask = mask
        self.sdf = sdf
        self.voxel = float(sdf.voxel)
        self.refs = refs
        self.sky_factor = factor
        self.analytic = analytic
        self.n = EVANS_SAMPLES
        self._terms = {}
        self.cone_cache = {}
        self.fit_idx, self.fit_w = subsample(len(self.points), sum(map(ord, name)))

    def terms(self, alpha, base_vox, n=None, analytic=False):
        """D_i (n, N) at every point (`evans_terms`, Dr.Jit) for α and base (voxels), memoised."""
        n = n or self.n
        key = (alpha, base_vox, n, analytic)
        if key not in self._terms:
            prm = EvansParams(n=n, base=base_vox * self.voxel, k=1.0, alpha=alpha)
            sdf = self.analytic if analytic else self.sdf
            self._terms[key] = evans_terms(self.points, self.normals, sdf, prm)
        return self._terms[key]

    def target(self, t):
        return self.refs[t]

    def factor(self, t):
        """The sky factor g(N) per point for sunsky targets (`sky_factor`), else None (g = 1)."""
        if t in SUNSKY_TARGETS:
            if self.sky_factor is None:
                raise ValueError(f"{self.name}: target {t} needs the per-point sky factor")
            return np.asarray(self.sky_factor, dtype=np.float64)
        return None

    def scaled(self, t, pred):
        """g·pred (the approximation under target t)."""
        g = self.factor(t)
        return pred if g is None else pred * g

    def fit_target(self, t):
        """(target/g, weight g) on the fit subsample, padded to FIT_POINTS: residual (C − y/g)·g = gC − y."""
        ref, _ = self.target(t)
        g = self.factor(t)
        y = ref[self.fit_idx]
        w = self.fit_w.copy()
        if g is not None:
            gs = np.maximum(g[self.fit_idx], 1e-6)
            y = y / gs
            w[: len(gs)] *= gs
        return zero_padded(y, FIT_POINTS), w

    def fit_data(self, t, analytic=False) -> EvansFitData:
        """The fit subsample as `EvansFitData` for the continuous fit."""
        ref, _ = self.target(t)
        g = self.factor(t)
        i = self.fit_idx
        sdf = self.analytic if analytic else self.sdf
        return EvansFitData(
            self.points[i], self.normals[i], sdf, self.voxel, ref[i], None if g is None else g[i]
        )

    def image(self, values):
        img = np.zeros(self.mask.shape)
        img[self.mask] = values
        return img


def values_of(fit):
    return {k: v["value"] for k, v in fit["parameters"].items()}


def fit_kernel(method, sd: SceneData, t, inputs: dict, start: dict):
    """Fit ``method``'s parameters (start values ``start``, the declared bounds) to target t on the fit
    subsample through the JAX run of its kernel (`fit_method`); ``inputs`` are full per-point arrays."""
    y, fw = sd.fit_target(t)
    params = {k: dataclasses.replace(p, initial=start[k]) for k, p in method.params.items()}
    sub = {k: zero_padded(np.asarray(v)[..., sd.fit_idx], FIT_POINTS) for k, v in inputs.items()}
    # SciPy's trust-region reflective solver on the kernel's NumPy run, as the engine fits these rows
    # (`audit_fit.FIT_SOLVER`): nothing is compiled per method and shape (the JAX run compiled each)
    return fit_method(method, sub, y, weights=fw, params=params, solver="trf").to_dict()


def fit_seed(sd: SceneData, t, method_id: str):
    """The seed's Evans forms (``evans-text``, ``evans-listing``): α, base and weights as the method fixes
    them, k (and B) fitted. Returns (fit dict, g·C at every point, the row's parameters)."""
    m = METHODS[method_id]
    d = sd.terms(m.fixed["alpha"], m.fixed["base_voxels"])
    start = {"k": 1.0 / (10 * sd.voxel), "logB": 0.0}
    f = fit_kernel(m, sd, t, {"terms": d}, start)
    pred = m(NUMPY_OPS, {"terms": d}, values_of(f))
    params = {**values_of(f), "alpha": m.fixed["alpha"], "base": m.fixed["base_voxels"] * sd.voxel}
    return f, sd.scaled(t, pred), params


def fit_free(sds: list[SceneData], t, alphas=ALPHAS, bases=BASES_VOX, analytic=False):
    """Stage 1 (initialisation): at every (α, base) of the grid, fit (log B, c_i) with α and base held (the
    model is then smooth: D_i fixed, C = exp(log B − Σ c_i D_i)) by the same bounded LM (`bounded_lm`,
    Jacobian from ∂C/∂e, no kernel calls); returns the best {values, ssr, alpha, base_vox}."""
    n = sds[0].n
    lo, hi = evans_fit_bounds(n)
    lo, hi = lo[: 1 + n], hi[: 1 + n]
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
                pred, pl = evans_value_and_slope(d, x[0], x[1:])
                pred, pl = g * pred, g * pl
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
    """The Evans fit: grid profile (`fit_free`), then the continuous LM over (log B, c_i, α, base) from its
    best point (`fit_evans_continuous`). Returns the continuous result with the grid's best as ``grid``
    ({alpha, base_vox, rms_residual})."""
    g = fit_free(sds, t, cfg["alphas"], cfg["bases_vox"], analytic=analytic)
    init = {**g["values"], "alpha": g["alpha"], "base_voxels": g["base_vox"]}
    data = [sd.fit_data(t, analytic=analytic) for sd in sds]
    b = fit_evans_continuous(data, init, sds[0].n, max_iter=int(cfg.get("lm_max_iter", 100)))
    b["grid"] = {"alpha": g["alpha"], "base_vox": g["base_vox"], "rms_residual": math.sqrt(g["ssr"] / g["m"])}
    return b


def predict_free(sd: SceneData, best, analytic=False, t=None):
    """g·C at every point of ``sd`` with the fitted (log B, c_i) at the fit's α and base (g for target t)."""
    v = values_of(best["fit"])
    d = sd.terms(best["alpha"], best["base_vox"], analytic=analytic)
    c = np.array([v[f"c{i + 1}"] for i in range(d.shape[0])])
    pred = evans_from_terms_kernel(NUMPY_OPS, d, logB=v["logB"], weights=c)
    return pred if t is None else sd.scaled(t, pred)


def fit_curvature(sd: SceneData, t):
    """The curvature row: k fitted through the kernel on the blurred SDF at the points (level
    `CURVATURE_LEVEL`). Returns (fit dict, g·C at every point)."""
    m = METHODS["curvature"]
    dist = np.asarray(sd.sdf.sample(NUMPY_OPS, CURVATURE_LEVEL, *sd.points.T))
    f = fit_kernel(m, sd, t, {"distance": dist}, {"k": -1.0 / sd.voxel})
    return f, sd.scaled(t, m(NUMPY_OPS, {"distance": dist}, values_of(f)))


def cone_best(sd: SceneData, t, cfg):
    """The cone row: aperture k grid-searched over `CONE_KS` (lowest RMSE against target t)."""
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


def fit_k(d, ref):
    """Least squares for (k ≥ 0, log B) in C = B·exp(−k Σ_i D_i) on the terms ``d`` (n, N): bounded 1-D
    search over log k with the optimal B solved in closed form inside (SciPy; cheap enough to refit at every
    sweep point). C is `evans_from_terms_kernel`."""
    from scipy.optimize import minimize_scalar  # scipy: optional heavy import, only for the sweep

    dsum = -evans_exponent_kernel(NUMPY_OPS, d)  # Σ_i D_i
    scale = max(float(np.percentile(np.abs(dsum), 90)), 1e-9)

    def inner(k):
        e = evans_from_terms_kernel(NUMPY_OPS, d, k=k)
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


def run_sweep(cfg, sds, grids) -> list[dict]:
    """Steps (n) × grid resolution × prefilter × 8-bit: Evans as pure occlusion (α = 0, w_i = 1, base = one
    voxel of the grid) with k and B refitted per configuration, error against the AO reference (mean RMSE
    over the sweep scenes ``cfg["sweep_scenes"]``, `SceneData` in ``sds``) and measured ns per pixel.
    ``grids``: (scene, cells) → the scene mesh's `SdfGrid` (`grid_of`)."""
    Float = backend_float()
    target = "ao"
    rows = []
    configs = []
    for res in cfg["sweep_grids"]:
        for n in cfg["sweep_n"]:
            configs.append((res, n, True, False))
        configs.append((res, 4, False, False))
        configs.append((res, 4, True, True))
    size = int(cfg["cost_points"])
    fields = {}  # (scene, res, prefilter, 8 bit) → GridSDF: built once for every n
    for res, n, pre, q8 in configs:
        errs, floors = [], []
        timing = None
        for name in cfg["sweep_scenes"]:
            sd = sds[name]
            if (name, res, pre, q8) not in fields:
                g = quantize_8bit(grids[(name, res)]) if q8 else grids[(name, res)]
                fields[(name, res, pre, q8)] = g, GridSDF.from_grid(g, levels=8, prefilter=pre)
            g, sdf = fields[(name, res, pre, q8)]
            prm = EvansParams(n=n, base=g.voxel, k=1.0, alpha=0.0, prefilter=True)
            d = evans_terms(sd.points, sd.normals, sdf, prm)
            ref, err = sd.target(target)
            k, logb = fit_k(d, ref)
            pred = evans_from_terms_kernel(NUMPY_OPS, d, logB=logb, k=k)
            errs.append(float(np.sqrt(np.mean((pred - ref) ** 2))))
            floors.append(float(np.sqrt(np.mean(err**2))))
            if timing is None:
                cols = columns(sd, np.random.default_rng(1).integers(0, len(sd.points), size), Float)
                timing = time_drjit(
                    lambda *a, s=sdf, p=prm: evans_kernel(DRJIT_OPS, s, p, *a),
                    cols,
                    size,
                    repeats=5,
                    min_seconds=0.1,
                )
        seed = bool(res == 128 and n == 4 and pre and q8)
        rows.append({"grid": res, "n": n, "prefilter": pre, "bits": 8 if q8 else 32, "target": target,
                     "rmse": float(np.mean(errs)), "noise_floor": float(np.mean(floors)),
                     "ns_per_pixel": timing.ns_per_element, "seed_default": seed})  # fmt: skip
    return rows


def columns(sd, idx, Float) -> tuple:
    """(px, py, pz, nx, ny, nz) of the points ``idx`` of ``sd`` as Dr.Jit ``Float`` arrays (timing inputs)."""
    return tuple(to_drjit(Float, a[idx, i]) for a in (sd.points, sd.normals) for i in range(3))


def finite(v) -> bool:
    """A finite number."""
    return isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(float(v))


def write_fitted(out: Path, joint: dict, per_case: dict, train: dict, ctx=None, hashes=()) -> None:
    """fitted/evans_joint_<target>.json (the joint continuous fit: k, w_i, B, α, base in voxels and in each
    training scene's units (``train``: scene → voxel), with standard errors, the LM's covariance) and
    fitted/per_case.json (every case's continuous fits)."""
    prov = fitfiles.provenance(ctx, "sdf-occlusion", hashes)
    units = {"k": "1/scene unit", "base_voxels": "voxel", "base": "scene unit"}
    for t, b in joint.items():
        readable = {k: (float(v) if finite(v) else None) for k, v in evans_readable(b, None).items()}
        model = "C = B * exp(-k * sum_i w_i (d_i - s_{i-1}(P + d_i (N + alpha U)))), d_i = base * 2^(i-1)" + (
            "; prediction g(N) * C, g = sunsky factor E_sky(N)/E_u(N)" if t.startswith("sunsky") else ""
        )
        se = readable["base_voxels_stderr"]
        data = {
            "target": t,
            "trained_on": list(train),
            "held_out": HELD_OUT,
            "base_scene_units": {
                n: {"value": b["base_vox"] * v, "stderr": None if se is None else se * v, "voxel": v}
                for n, v in train.items()
            },
            "grid_init": b["grid"],
            "lm": b["lm"],
            "covariance": {
                "names": list(b["fit"]["parameters"]),
                "matrix": [[float(v) if finite(v) else None for v in row] for row in b["cov"]],
            },
        }
        entry = fitfiles.FittedMethod(
            id=f"evans-joint-{t}",
            label=f"Evans joint fit ({TARGET_LABEL[t]})",
            formula=model,
            source="Evans 2006, Fast approximations for global illumination on dynamic scenes (SIGGRAPH)",
            quantity=t,
            parameters={
                k: fitfiles.Parameter(value=v, stderr=readable.get(f"{k}_stderr"), unit=units.get(k, "1"))
                for k, v in readable.items()
                if not k.endswith("_stderr") and v is not None
            },
            residual=fitfiles.Residual(
                rms=b["fit"]["rms_residual"],
                n=b["fit"]["n_residuals"],
                dof=b["fit"].get("dof"),
                units="occlusion / sky visibility (dimensionless)",
            ),
            converged=b["fit"]["converged"],
            shader=None,
            shader_note="no shader text: the estimator samples the SDF grid at each step (a 3D texture)",
            data=data,
        )
        fitfiles.write_fit(
            out,
            f"fitted/evans_joint_{t}.json",
            title=f"SDF occlusion: Evans joint fit ({TARGET_LABEL[t]})",
            provenance=prov,
            entry=entry,
            doc_id=entry.id,
            label=entry.label,
            model=model,
            fit=b["fit"],
        )
    fitfiles.write_fitted(
        Path(out) / "fitted/per_case.json",
        fitfiles.FittedFile(
            format=fitfiles.FORMAT,
            title="SDF occlusion: every case's continuous fits (with stderrs)",
            provenance=prov,
            methods=[],
            data={"cases": per_case},
        ),
    )
