"""Experiment ``sdf-occlusion``: Evans' multi-scale SDF skylight/occlusion and cone-traced distance-field
occlusion against Mitsuba ray-cast ambient occlusion and sky light.

Scenes (``scenes/library/sdf_*.toml``, geometry from `rtfit.experiments.sdf_occlusion_scenes`): creases
of 30°/60°/90°/120°, a sphere on a plane, a room with an open window, a city block of boxes and a
procedural character (held out of the joint fit).

Ground truth (`rtfit.reference.occlusion`), at the pixel-centre G-buffer points of each scene's camera:

* ``ao``: cosine-weighted visibility within ``ao_distance`` (scene units);
* ``sky``: irradiance from a constant upper-hemisphere sky (no sun), one bounce, as E/(πL);
* ``sky-gi``: the same with all interreflections between white diffuse surfaces of albedo ``albedo``;
* ``sunsky`` / ``sunsky-gi``: one bounce / all bounces under the ``sunsky`` sky without its sun (below);
* ``ao-sdfgrid``: the ``ao`` estimator on Mitsuba's ``sdfgrid`` shape built from the scene's voxel
  grid (its own G-buffer): the grid-resolution error, reported apart from the occlusion-model error.

Approximations (on the mesh G-buffer; SDF = the mesh's voxel grid at ``grid`` cells along the longest axis,
Gaussian-prefiltered mip chain):

* ``evans-text``    seed text form: α = 0.5, w_i = 1 (000:2946), k fitted per case;
* ``evans-listing`` seed Listing 1: α = 1, w = (1, 1.2, 1.4, 1.8), brightness B fitted with k (000:2982-2987);
* ``evans-fit``     k, α, base distance and per-sample weights fitted per case;
* ``evans-joint``   one parameter set fitted jointly over the training scenes, applied to all (the
  character is held out: its row measures transfer);
* ``curvature``     the seed's crease darkening (0.5 + exp(k S))/1.5 (000:2902-2904), k fitted;
* ``cone``          cone-traced distance-field AO (9 cones, 8 steps), aperture k grid-searched.

Targets ``sunsky`` / ``sunsky-gi``: the same two quantities under Mitsuba's ``sunsky`` sky without its sun
(`rtfit.reference.occlusion.SunskySky`: sun at ``sun_elevation`` / ``sun_azimuth``, turbidity 3; radiance 0
below the horizon), as E/E_h with E_h the unoccluded horizontal sky irradiance (= πL for a constant sky, so
the constant target is the special case). Every approximation C is then multiplied by the unoccluded sky's
directional factor g(N) = E_sky(N)/E_u(N), E_u(N) = E_h (1 + N_z)/2 the irradiance of a constant
upper-hemisphere sky of the same E_h (`sky_factor`): g ≡ 1 for the constant sky, so the ``sky`` rows are
unchanged, and a fit of C fits the occlusion part alone.

The Evans fit (``evans-fit``, ``evans-joint``, ``evans-analytic``, ``evans-on-sdfgrid``) runs in two stages:

1. Initialisation (grid profile): for fixed α and base distance C = exp(log B − Σ_i c_i D_i) is linear in
   (log B, c_i = k·w_i) inside the exponent, with D_i = d_i − s_{i−1} computed once by the Dr.Jit kernel; those
   are fitted with α and base held, at every (α, base) of a small grid (α ∈ {0, ¼, ½, ¾, 1}, base ∈ {½, 1, 2}
   voxels; quick: {0, ½, 1} × {1}), and the best point is kept.
2. The continuous fit (`fit_evans_continuous`): all of x = (log B, c_1..c_n, α, base in voxels) together.
   Both stages use the bounded Levenberg–Marquardt loop written here (`bounded_lm`, NumPy, projected steps
   with an active set at the bounds; not optimistix: its residuals come from Dr.Jit, not JAX). The
   continuous fit's Jacobian: the columns of log B and c_i are analytic (∂r/∂log B = g C,
   ∂r/∂c_i = −g C D_i); those of α and base come from Dr.Jit forward-mode autodiff through the kernel
   (`rtfit.realtime.sdf_occlusion.evans_terms_jacobian`: each sample's position P + base·2^(i−1)·N'(α)
   moves continuously, its mip level i − 1 stays discrete, so the residuals are piecewise smooth with kinks
   on trilinear cell faces). Standard errors: cov = s²(JᵀJ)⁺ at the optimum with s² = SSR/(m − p), the
   convention of `rtfit.fitting` (`covariance_from_jacobian`); k = c_1, w_i = c_i/c_1 and B = e^{log B}
   carry delta-method errors. Residuals of neighbouring pixels are correlated and the model error dominates
   the noise, so these are the linearised spread of the fit, not a sampling error.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .jobs import Job

TARGETS_QUICK = ("ao", "sky", "sunsky")
TARGETS_FULL = ("ao", "sky", "sky-gi", "sunsky", "sunsky-gi")
TARGET_QUANTITY = {
    "ao": "ao",
    "sky": "sky_direct",
    "sky-gi": "sky_global",
    "sunsky": "sunsky_direct",
    "sunsky-gi": "sunsky_global",
}
TARGET_LABEL = {
    "ao": "AO (cosine-weighted visibility within R)",
    "sky": "sky light, one bounce (E/πL)",
    "sky-gi": "sky light, global illumination (E/πL)",
    "sunsky": "sunsky sky light without the sun, one bounce (E/E_h)",
    "sunsky-gi": "sunsky sky light without the sun, global illumination (E/E_h)",
}
SUNSKY_TARGETS = ("sunsky", "sunsky-gi")
SKY_FACTOR_HEIGHT = 129
"""Rows of the baked sky map whose quadrature gives the approximation's unoccluded sky factor g(N)
(`sky_factor`): 0.2% from the converged value for vertical normals, far below the occlusion models' error."""
HELD_OUT = "character"
METHODS = ("evans-text", "evans-listing", "evans-fit", "evans-joint", "curvature", "cone")
LABELS = {
    "evans-text": "Evans, seed text (α=½, w=1; k fit)",
    "evans-listing": "Evans, seed listing (α=1, w=1…1.8; k, B fit)",
    "evans-fit": "Evans, fitted per case",
    "evans-joint": "Evans, joint fit",
    "curvature": "Curvature (seed §9.5; k fit)",
    "cone": "Cone-traced DF AO (k grid-searched)",
    "sdfgrid": "Mitsuba AO on the sdfgrid (grid error)",
    "evans-analytic": "Evans fitted, exact analytic SDF (no grid, no blur)",
    "evans-on-sdfgrid": "Evans fitted, on the voxelised geometry vs its own AO (model error only)",
}
ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0)
BASES_VOX = (0.5, 1.0, 2.0)
CONE_KS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
CREASE_PROBE_X = (
    0.05,
    0.1,
    0.2,
    0.4,
)  # floor probes (y = 0) of the creases: the finite arms are exact within R = 1
FIT_POINTS = 2048  # pixels per scene used by the fits (padded: one JAX compile per model size)


def configure(quick: bool, spp: int | None) -> dict:
    from .sdf_occlusion_scenes import SCENE_NAMES

    return {
        "scenes": list(SCENE_NAMES),
        "targets": list(TARGETS_QUICK if quick else TARGETS_FULL),
        "resolution": 36 if quick else 128,
        "spp": spp or (64 if quick else 1024),
        "pass_spp": 32 if quick else 256,
        "grid": 64 if quick else 128,
        "n_samples": 4,
        "ao_distance": 1.0,
        "albedo": 0.8,
        "sweep_grids": [32, 64] if quick else [32, 64, 128, 256],
        "sweep_n": [1, 2, 4, 8] if quick else [1, 2, 3, 4, 5, 6, 7, 8],
        "sweep_scenes": ["crease_90", "sphere_plane", "boxes"]
        if quick
        else ["crease_90", "boxes", "character"],
        "alphas": [0.0, 0.5, 1.0] if quick else list(ALPHAS),
        "bases_vox": [1.0] if quick else list(BASES_VOX),
        "map_scenes": ["crease_90", "room", "boxes", "character"] if quick else list(SCENE_NAMES),
        "probe_spp": 2048 if quick else 16384,
        "cost_points": (1 << 17) if quick else (1 << 22),
        "cone_count": 9,
        "cone_steps": 8,
        "sun_elevation": 30.0,
        "sun_azimuth": 60.0,
        "turbidity": 3.0,
        "lm_max_iter": 100 if quick else 300,
    }


def sky_factor(normals, directions, weights, radiance) -> np.ndarray:
    """The unoccluded sky's directional factor g(N) = E_sky(N)/E_u(N) at unit ``normals`` (M, 3), from
    quadrature nodes of the sky above the horizon (``directions`` (K, 3) with d_z > 0, solid-angle
    ``weights`` (K,), ``radiance`` (K,)):

        E_sky(N) = Σ_k w_k L_k max(N·d_k, 0),   E_u(N) = (E_h/π) Σ_k w_k max(N·d_k, 0),   E_h = Σ_k w_k L_k d_k,z

    E_u is the irradiance of a constant upper-hemisphere sky of the same horizontal irradiance E_h
    (→ E_h (1 + N_z)/2 as the nodes refine), on the same nodes, so a constant L gives g ≡ 1 exactly and the
    sky target E/E_h ≈ g(N)·C reduces to the constant-sky model E/(πL) ≈ C. g is the cosine-weighted mean of
    L/L̄ (L̄ = E_h/π) over the part of the upper sky that N faces; g = 1 where N faces none of it (N = −Z)."""
    n = np.asarray(normals, np.float64)
    d = np.asarray(directions, np.float64)
    w = np.asarray(weights, np.float64)
    lum = np.asarray(radiance, np.float64)
    if (
        n.ndim != 2
        or n.shape[1] != 3
        or d.ndim != 2
        or d.shape[1] != 3
        or w.shape != (len(d),)
        or lum.shape != (len(d),)
    ):
        raise ValueError("sky_factor needs normals (M, 3), directions (K, 3), weights (K,), radiance (K,)")
    if len(d) == 0 or np.any(d[:, 2] <= 0) or np.any(w < 0) or np.any(lum < 0):
        raise ValueError("sky_factor needs nodes above the horizon (d_z > 0) with weights and radiance >= 0")
    e_h = float((w * lum) @ d[:, 2])
    if not e_h > 0:
        raise ValueError("sky_factor: the sky has no horizontal irradiance")
    num = np.empty(len(n))
    den = np.empty(len(n))
    per = max(1, (1 << 22) // len(d))
    wl = w * lum
    for a in range(0, len(n), per):
        cos = np.maximum(n[a : a + per] @ d.T, 0.0)
        num[a : a + per] = cos @ wl
        den[a : a + per] = (cos @ w) * (e_h / math.pi)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


# ----------------------------------------------------------------------------------- continuous fit
FIT_BOUNDS = {"logB": (-5.0, 5.0), "c": (0.0, 1e4), "alpha": (0.0, 1.0), "base_voxels": (0.25, 4.0)}
"""Bounds of the continuous Evans fit: c_i = k·w_i ≥ 0 (`EvansParams` needs k, w_i ≥ 0), α ∈ [0, 1], base
from ¼ to 4 voxels of the finest grid."""


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


def evans_fit_residuals(x, data: list, n: int, *, jacobian: bool = True):
    """Residuals r = g·C − y over all scenes of ``data`` (list of `EvansFitData`) at
    x = (log B, c_1..c_n, α, base_voxels), C = exp(clip(log B − Σ c_i D_i, −87, 80)), and (``jacobian``) their
    Jacobian (m, n + 3): analytic in log B and c_i, Dr.Jit forward-mode autodiff in α and base (columns
    are 0 where the exponent is clipped)."""
    from rtfit.realtime.sdf_occlusion import EvansParams, evans_terms, evans_terms_jacobian

    x = np.asarray(x, dtype=np.float64)
    logb, c, alpha, base_v = x[0], x[1 : 1 + n], float(x[1 + n]), float(x[2 + n])
    rs, js = [], []
    for dd in data:
        prm = EvansParams(n=n, base=base_v * dd.voxel, k=1.0, alpha=alpha)
        if jacobian:
            d, da, db = evans_terms_jacobian(dd.points, dd.normals, dd.sdf, prm)
        else:
            d = evans_terms(dd.points, dd.normals, dd.sdf, prm)
        e = logb - c @ d
        live = (e > -87.0) & (e < 80.0)
        pred = np.exp(np.clip(e, -87.0, 80.0))
        if dd.factor is not None:
            pred = pred * dd.factor
        rs.append(pred - dd.target)
        if jacobian:
            pl = np.where(live, pred, 0.0)
            js.append(np.column_stack([pl, -pl[:, None] * d.T, -pl * (c @ da), -pl * (c @ db) * dd.voxel]))
    r = np.concatenate(rs)
    return (r, np.concatenate(js)) if jacobian else r


def bounded_lm(
    fun, x0, lower, upper, *, max_iter: int = 100, ftol: float = 1e-7, xtol: float = 1e-7, gtol: float = 1e-8
) -> dict:
    """Minimise ½‖r(x)‖² subject to lower ≤ x ≤ upper; ``fun(x)`` returns (r, J).

    Levenberg–Marquardt with Marquardt's diagonal scaling (A + λ diag A) δ = −Jᵀr, A = JᵀJ, and Nielsen's
    damping update (λ ← λ·max(⅓, 1 − (2ρ − 1)³) on success, λ ← λν, ν ← 2ν on failure). Bounds: a
    parameter on a bound whose gradient points out of the box is held fixed (active set), the others take the
    step, and the step is projected onto the box. Stops (as MINPACK's lmder) when a successful step lowers the
    SSR by less than ``ftol``·SSR or moves x by less than ``xtol``·(‖x‖ + xtol), or when the projected gradient's cosine
    max_i |g_i|/(‖J_i‖‖r‖) over free parameters is below ``gtol`` (converged), or at ``max_iter`` / when
    λ exceeds 1e16 (not converged: the residuals are piecewise smooth, a kink can stall the step)."""
    lo, hi = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    x = np.clip(np.asarray(x0, np.float64), lo, hi)
    if not np.all(lo < hi):
        raise ValueError("bounded_lm needs lower < upper for every parameter")
    r, jac = fun(x)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
        raise ValueError("bounded_lm: non-finite residuals or Jacobian at the start")
    ssr = float(r @ r)
    a = jac.T @ jac
    lam = 1e-3
    nu = 2.0
    evals, message, converged = 1, "max_iter reached", False
    it = 0
    for it in range(1, max_iter + 1):
        g = jac.T @ r
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
        col = np.linalg.norm(jac, axis=0)
        rn = math.sqrt(ssr)
        cosg = np.where(free & (col > 0), np.abs(g) / np.maximum(col * rn, 1e-300), 0.0)
        if rn == 0.0 or float(cosg.max()) <= gtol:
            converged, message = True, "projected gradient below gtol"
            break
        af = a[np.ix_(free, free)]
        dg = np.maximum(np.diag(af), 1e-12 * max(float(np.diag(af).max()), 1e-300))
        try:
            step_f = np.linalg.solve(af + lam * np.diag(dg), -g[free])
        except np.linalg.LinAlgError:
            lam *= nu
            nu *= 2.0
            continue
        step = np.zeros_like(x)
        step[free] = step_f
        x_new = np.clip(x + step, lo, hi)
        dx = x_new - x
        r_new, j_new = fun(x_new)
        evals += 1
        ssr_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else math.inf
        lin = r + jac @ dx
        pred = ssr - float(lin @ lin)
        if ssr_new < ssr and np.all(np.isfinite(j_new)):
            rho = (ssr - ssr_new) / pred if pred > 0 else 0.0
            small = (ssr - ssr_new) <= ftol * ssr or np.linalg.norm(dx) <= xtol * (np.linalg.norm(x) + xtol)
            x, r, jac, ssr = x_new, r_new, j_new, ssr_new
            a = jac.T @ jac
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if small:
                converged, message = True, "relative SSR change below ftol or step below xtol"
                break
        else:
            lam *= nu
            nu *= 2.0
            if lam > 1e16:
                message = "no descent step (damping above 1e16)"
                break
    return {
        "x": x,
        "r": r,
        "jac": jac,
        "ssr": ssr,
        "iterations": it,
        "evaluations": evals,
        "converged": converged,
        "message": message,
    }


def fit_evans_continuous(data: list, init: dict, n: int, *, max_iter: int = 100) -> dict:
    """The continuous Evans fit (module docstring, stage 2) from ``init`` = {"logB", "c1".."cn", "alpha",
    "base_voxels"} (the grid profile's best point). Returns {"fit": `FitResult.to_dict()` over
    `evans_param_names`, "alpha", "base_vox", "init", "lm": {iterations, evaluations, message}}."""
    from rtfit.fitting import AT_BOUND_RTOL, FitResult, covariance_from_jacobian

    if not data:
        raise ValueError("fit_evans_continuous needs at least one scene")
    names = evans_param_names(n)
    missing = [k for k in names if k not in init]
    if missing:
        raise ValueError(f"init lacks {', '.join(missing)}")
    lo = np.array(
        [FIT_BOUNDS["logB"][0]]
        + [FIT_BOUNDS["c"][0]] * n
        + [FIT_BOUNDS["alpha"][0], FIT_BOUNDS["base_voxels"][0]]
    )
    hi = np.array(
        [FIT_BOUNDS["logB"][1]]
        + [FIT_BOUNDS["c"][1]] * n
        + [FIT_BOUNDS["alpha"][1], FIT_BOUNDS["base_voxels"][1]]
    )
    x0 = np.array([float(init[k]) for k in names])
    out = bounded_lm(lambda x: evans_fit_residuals(x, data, n), x0, lo, hi, max_iter=max_iter)
    x, r, jac = out["x"], out["r"], out["jac"]
    m, p = len(r), len(x)
    cov, rank = covariance_from_jacobian(jac, out["ssr"], m - p)
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(np.diag(cov))
        corr = cov / np.outer(se, se)
    at_bound = {
        nm: bool(
            x[i] - lo[i] <= AT_BOUND_RTOL * (hi[i] - lo[i]) or hi[i] - x[i] <= AT_BOUND_RTOL * (hi[i] - lo[i])
        )
        for i, nm in enumerate(names)
    }
    fr = FitResult(
        values={nm: float(x[i]) for i, nm in enumerate(names)},
        stderr={nm: float(se[i]) for i, nm in enumerate(names)},
        correlation=[[float(v) for v in row] for row in corr],
        param_names=tuple(names),
        rms_residual=math.sqrt(out["ssr"] / m),
        ssr=out["ssr"],
        n_residuals=m,
        dof=m - p,
        steps=out["iterations"],
        converged=out["converged"],
        message=out["message"],
        at_bound=at_bound,
        lower={nm: float(lo[i]) for i, nm in enumerate(names)},
        upper={nm: float(hi[i]) for i, nm in enumerate(names)},
        jacobian_rank=rank,
    )
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
        var = (
            (cv(f"c{i + 1}", f"c{i + 1}") + w * w * cv("c1", "c1") - 2 * w * cv("c1", f"c{i + 1}")) / k**2
            if k
            else math.nan
        )
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


# ------------------------------------------------------------------------------------------- scenes
def load_case_scene(name: str, resolution: int):
    from rtfit.scenes import library_path, load_scene

    sc = load_scene(library_path(f"sdf_{name}"))
    return dataclasses.replace(sc, camera=dataclasses.replace(sc.camera, width=resolution, height=resolution))


def mesh_of(scene):
    from .sdf_occlusion_scenes import read_ply

    vs, fs, off = [], [], 0
    for sh in scene.shapes:
        v, f = read_ply(sh.file)
        vs.append(v * np.asarray(sh.scale) + np.asarray(sh.translate))  # library meshes: no rotation
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def grid_of(scene, resolution: int, cache_dir=None):
    """The scene mesh's voxel SDF at ``resolution`` cells on the longest axis (cached as .npz by content)."""
    import hashlib

    from rtfit.realtime.sdf_grid import SdfGrid, grid_for_bounds, mesh_bounds, mesh_sdf_grid

    v, f = mesh_of(scene)
    h = hashlib.sha256(
        v.astype(np.float32).tobytes() + f.astype(np.int32).tobytes() + str(resolution).encode()
    )
    path = None
    if cache_dir is not None:
        from pathlib import Path

        path = Path(cache_dir) / "sdf-grids" / f"{h.hexdigest()[:24]}-{resolution}.npz"
        if path.exists():
            z = np.load(path)
            return SdfGrid(z["values"], tuple(z["origin"]), float(z["voxel"]), meta={"source": "mesh"})
    lo, hi = mesh_bounds(v)
    origin, voxel, shape = grid_for_bounds(lo, hi, resolution, pad_voxels=3.0, cubic=True)
    g = mesh_sdf_grid(v, f, origin, voxel, shape)
    if path is not None:
        import io

        from rtfit.reference.io import atomic_write_bytes

        buf = io.BytesIO()
        np.savez(buf, values=g.values, origin=np.asarray(g.origin), voxel=g.voxel)
        atomic_write_bytes(path, buf.getvalue())
    return g


# --------------------------------------------------------------------------------------------- jobs
def render_case(
    name: str,
    resolution: int,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    targets: list,
    ao_distance: float,
    albedo: float,
    grid: int,
    probe_spp: int = 2048,
    sun_elevation: float = 30.0,
    sun_azimuth: float = 60.0,
    turbidity: float = 3.0,
    sky_probe: bool = False,
) -> dict:
    """Job: G-buffer, occlusion references and the sdfgrid AO of one scene (plain data out). With sunsky
    targets also the per-point sky factor g(N) (`sky_factor`) and, with ``sky_probe``, the sunsky reference
    at a point 50 units above everything (normals up and four horizontal ones) beside the quadrature."""
    from rtfit.reference import load_mitsuba_scene
    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.occlusion import (
        OcclusionCache,
        SunskySky,
        sdfgrid_scene,
        sunsky_horizontal_irradiance,
        sunsky_irradiance,
        sunsky_sky_nodes,
    )
    from rtfit.scenes import scene_hash

    scene = load_case_scene(name, resolution)
    mi, mi_scene = load_mitsuba_scene(scene, variant)
    gb = gbuffer(mi, mi_scene)
    mask = gb.mask
    pts, nrm = gb.position[mask].astype(np.float64), gb.normal[mask].astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cache = OcclusionCache(cache_dir)
    geo = scene_hash(scene)
    sky = SunskySky(sun_elevation, sun_azimuth, turbidity)
    refs = {}
    for t in targets:
        r = cache.get(
            mi,
            mi_scene,
            geo,
            pts,
            nrm,
            spp=spp,
            pass_spp=pass_spp,
            seed=seed,
            variant=variant,
            quantity=TARGET_QUANTITY[t],
            max_distance=ao_distance if t == "ao" else math.inf,
            albedo=albedo,
            sky=sky,
        )
        refs[t] = {"mean": r.mean, "stderr": r.stderr, "meta": r.to_dict()}
    factor = sky_probe_out = None
    if any(t in SUNSKY_TARGETS for t in targets):
        factor = sky_factor(nrm, *sunsky_sky_nodes(mi, sky, SKY_FACTOR_HEIGHT, 2))
        if sky_probe:
            hs = sky.sun_direction() * np.array([1.0, 1.0, 0.0])
            hs /= np.linalg.norm(hs)
            side = np.array([-hs[1], hs[0], 0.0])
            pn = np.array([[0.0, 0.0, 1.0], hs, -hs, side, -side])
            pp = np.tile([0.0, 0.0, 50.0], (len(pn), 1))
            sspp = max(int(probe_spp), 1 << 16)
            expect = sunsky_irradiance(mi, sky, pn) / sunsky_horizontal_irradiance(mi, sky)
            rd = cache.get(
                mi,
                mi_scene,
                geo,
                pp,
                pn,
                spp=sspp,
                pass_spp=min(sspp, 1 << 14),
                seed=seed,
                variant=variant,
                quantity="sunsky_direct",
                sky=sky,
            )
            rg = cache.get(
                mi,
                mi_scene,
                geo,
                pp[:1],
                pn[:1],
                spp=sspp,
                pass_spp=min(sspp, 1 << 14),
                seed=seed,
                variant=variant,
                quantity="sunsky_global",
                albedo=albedo,
                sky=sky,
            )
            sky_probe_out = {
                "normals": pn,
                "expected": expect,
                "direct_mean": rd.mean,
                "direct_stderr": rd.stderr,
                "global_mean": rg.mean,
                "global_stderr": rg.stderr,
                "spp": sspp,
            }
    probes = None
    if name.startswith("crease_"):
        xs = np.array(CREASE_PROBE_X)
        pp = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, 1e-6)])
        pn = np.tile([0.0, 0.0, 1.0], (len(xs), 1))
        r = cache.get(
            mi,
            mi_scene,
            geo,
            pp,
            pn,
            spp=probe_spp,
            pass_spp=min(probe_spp, 1024),
            seed=seed,
            variant=variant,
            quantity="ao",
            max_distance=ao_distance,
        )
        probes = {"x": xs, "mean": r.mean, "stderr": r.stderr}
    g = grid_of(scene, grid, cache_dir)
    import hashlib

    try:
        mi_sdf = sdfgrid_scene(mi, g, scene.camera)
    except RuntimeError as exc:  # e.g. "SDFGrid should at least have one non-empty voxel": too coarse a grid
        mi_sdf, sdf_error = None, str(exc).splitlines()[-1][:200]
    img2 = err2 = None
    meta2 = sdf_gb = None
    if mi_sdf is not None:
        gb2 = gbuffer(mi, mi_sdf)
        m2 = gb2.mask
        p2, n2 = gb2.position[m2].astype(np.float64), gb2.normal[m2].astype(np.float64)
        n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-30)
        ok = np.all(np.isfinite(n2), axis=1) & (np.linalg.norm(n2, axis=1) > 0.5)
        gh = hashlib.sha256(g.values.tobytes() + repr((g.origin, g.voxel)).encode()).hexdigest()
        r2 = cache.get(
            mi,
            mi_sdf,
            "sdfgrid-" + gh,
            p2[ok],
            n2[ok],
            spp=spp,
            pass_spp=pass_spp,
            seed=seed,
            variant=variant,
            quantity="ao",
            max_distance=ao_distance,
        )
        img2 = np.full(m2.shape, np.nan)
        idx = np.flatnonzero(m2)[ok]
        img2.reshape(-1)[idx] = r2.mean
        err2 = np.full(m2.shape, np.nan)
        err2.reshape(-1)[idx] = r2.stderr
        meta2 = r2.to_dict()
        sdf_error = None
        sdf_gb = {
            "mask": np.isfinite(img2),
            "points": p2[ok],
            "normals": n2[ok],
            "refs": {"ao": {"mean": r2.mean, "stderr": r2.stderr, "meta": meta2}},
        }
    return {
        "mask": mask,
        "points": pts,
        "normals": nrm,
        "refs": refs,
        "grid": {"values": g.values, "origin": g.origin, "voxel": g.voxel},
        "sdfgrid_ao": img2,
        "sdfgrid_ao_stderr": err2,
        "sdfgrid_meta": meta2,
        "sdfgrid_error": sdf_error,
        "sdfgrid_gbuffer": sdf_gb,
        "scene_hash": geo,
        "probes": probes,
        "triangles": int(len(mesh_of(scene)[1])),
        "sky_factor": factor,
        "sky_probe": sky_probe_out,
    }


def run(ctx) -> dict:
    from . import sdf_occlusion_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    jobs = [
        Job(
            "rtfit.experiments.sdf_occlusion:render_case",
            dict(
                name=n,
                resolution=cfg["resolution"],
                spp=cfg["spp"],
                pass_spp=cfg["pass_spp"],
                seed=ctx.seed,
                variant=ctx.variant,
                cache_dir=str(ctx.cache_dir),
                targets=cfg["targets"],
                ao_distance=cfg["ao_distance"],
                albedo=cfg["albedo"],
                grid=cfg["grid"],
                probe_spp=cfg["probe_spp"],
                sun_elevation=cfg["sun_elevation"],
                sun_azimuth=cfg["sun_azimuth"],
                turbidity=cfg["turbidity"],
                sky_probe=(n == cfg["scenes"][0]),
            ),
            label=n,
        )
        for n in cfg["scenes"]
    ]
    ctx.log(f"rendering references of {len(jobs)} scenes")
    rendered = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="references")))

    from rtfit.realtime import set_default_backend

    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")
    return rep.assemble(ctx, cfg, rendered)


def bench(ctx) -> list[dict]:
    from . import sdf_occlusion_report as rep

    return rep.bench(ctx)
