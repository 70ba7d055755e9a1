"""Experiment ``sdf-occlusion``: Evans' multi-scale SDF skylight/occlusion and cone-traced distance-field
occlusion against Mitsuba ray-cast ambient occlusion and sky light.

What is compared and why: Evans (SIGGRAPH 2006 course, ch. 9) shades sky light and ambient occlusion from a
few samples of a blurred signed distance field along the normal, C = B·exp(−k Σ_i w_i D_i); a game ships it
with k, α and the sample weights tuned by eye. This experiment measures how far that estimator (as the seed
writes it, and with every parameter fitted) and the modern cone-traced variant are from ray-cast ground
truth, where they fail, and what each costs per pixel.

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
Gaussian-prefiltered mip chain). The methods are data: `rtfit.realtime.sdf_occlusion.METHODS` declares
each one (kernel, inputs, parameters with bounds and units); `ROWS` below adds where each row's parameters
come from:

* ``evans-text``    seed text form: α = 0.5, w_i = 1 (000:2946), k fitted per case;
* ``evans-listing`` seed Listing 1: α = 1, w = (1, 1.2, 1.4, 1.8), brightness B fitted with k (000:2982-2987);
* ``evans-fit``     k, α, base distance and per-sample weights fitted per case;
* ``evans-joint``   one parameter set fitted jointly over the training scenes, applied to all (the
  character is held out: its row measures transfer);
* ``curvature``     the seed's crease darkening (0.5 + exp(k S))/1.5 (000:2902-2904), k fitted;
* ``cone``          cone-traced distance-field AO (9 cones, 8 steps), aperture k grid-searched.

All images are dimensionless occlusion/sky-light values: 1 = unoccluded (AO), E/(πL) = 1 for an
unoccluded upward-facing point under the constant upper-hemisphere sky, E/E_h = 1 under the sunsky sky.

Targets ``sunsky`` / ``sunsky-gi``: the same two quantities under Mitsuba's ``sunsky`` sky without its sun
(`rtfit.reference.occlusion.SunskySky`: sun at ``sun_elevation`` / ``sun_azimuth``, turbidity 3; radiance 0
below the horizon), as E/E_h with E_h the unoccluded horizontal sky irradiance (= πL for a constant sky, so
the constant target is the special case). Every approximation C is then multiplied by the unoccluded sky's
directional factor g(N) = E_sky(N)/E_u(N), E_u(N) = E_h (1 + N_z)/2 the irradiance of a constant
upper-hemisphere sky of the same E_h (`sky_factor`): g ≡ 1 for the constant sky, so the ``sky`` rows are
unchanged, and a fit of C fits the occlusion part alone. The JAX fits (`rtfit.fitting.fit_method`, through
the kernel text) fit C to y/g with weight g: (C − y/g)·g = g·C − y.

The Evans fit (``evans-fit``, ``evans-joint``, ``evans-analytic``, ``evans-on-sdfgrid``) runs in two stages:

1. Initialisation (grid profile): for fixed α and base distance C = exp(log B − Σ_i c_i D_i) is linear in
   (log B, c_i = k·w_i) inside the exponent, with D_i = d_i − s_{i−1} computed once by the Dr.Jit kernel;
   those are fitted with α and base held, at every (α, base) of a small grid (α ∈ {0, ¼, ½, ¾, 1},
   base ∈ {½, 1, 2} voxels; quick: {0, ½, 1} × {1}), and the best point is kept.
2. The continuous fit (`fit_evans_continuous`): all of x = (log B, c_1..c_n, α, base in voxels) together.
   Both stages use the bounded Levenberg–Marquardt of `rtfit.fitting.bounded_lm` (NumPy, projected steps
   with an active set at the bounds; not optimistix: the residuals come from Dr.Jit, not JAX), bounded by
   the ``evans-fit`` method's declared parameters. C itself is `evans_from_terms_kernel` (the one text of
   the formula). The continuous fit's Jacobian: the columns of log B and c_i follow from ∂C/∂e = C (e the
   exponent, inside the clamp): ∂r/∂log B = g C, ∂r/∂c_i = −g C D_i; those of α and base come from Dr.Jit
   forward-mode autodiff through the kernel (`rtfit.realtime.sdf_occlusion.evans_terms_jacobian`: each
   sample's position P + base·2^(i−1)·N'(α) moves continuously, its mip level i − 1 stays discrete, so the
   residuals are piecewise smooth with kinks on trilinear cell faces). Standard errors: cov = s²(JᵀJ)⁺ at
   the optimum with s² = SSR/(m − p), the convention of `rtfit.fitting` (`bounded_lm_result`); k = c_1,
   w_i = c_i/c_1 and B = e^{log B} carry delta-method errors. Residuals of neighbouring pixels are
   correlated and the model error dominates the noise, so these are the linearised spread of the fit, not
   a sampling error.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import math
import time
import types
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.fitting import (
    bounded_lm,
    bounded_lm_result,
    fit_method,
    grey_metrics,
    param_bounds,
    zero_padded,
)
from rtfit.realtime import get_default_backend
from rtfit.realtime.arrays import DRJIT_OPS, NUMPY_OPS
from rtfit.realtime.sdf_grid import (
    HalfSpace,
    SdfGrid,
    grid_for_bounds,
    mesh_bounds,
    mesh_sdf_grid,
    quantize_8bit,
)
from rtfit.realtime.sdf_occlusion import (
    CURVATURE_LEVEL,
    EVANS_SAMPLES,
    EXP_MAX,
    EXP_MIN,
    METHODS,
    AnalyticSDF,
    EvansParams,
    GridSDF,
    cone_kernel,
    cone_occlusion,
    evans_exponent_kernel,
    evans_from_terms_kernel,
    evans_kernel,
    evans_occlusion,
    evans_terms,
    evans_terms_jacobian,
)
from rtfit.reference import load_mitsuba_scene
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.estimators import device_probes, gbuffer, gbuffer_points
from rtfit.reference.io import atomic_write_bytes
from rtfit.reference.occlusion import (
    OcclusionCache,
    SunskySky,
    occlusion_pass,
    sdfgrid_scene,
    sunsky_horizontal_irradiance,
    sunsky_irradiance,
    sunsky_sky_nodes,
)
from rtfit.reference.variants import backend_of
from rtfit.scenes import scene_hash

from . import figures
from . import fitted as fitfiles
from .cost import (
    Stock,
    attach_costs,
    cost_row,
    reference_sizes,
    reference_vs_stock_rows,
    stock_render,
    time_drjit,
)
from .jobs import Job, reference_args
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row
from .sdf_occlusion_scenes import SCENE_NAMES, build, load_case_scene, read_ply
from .viewer import save_case_pixels

# ============================================================================================ configure
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
ANALYTIC_SCENES = ("sphere_plane", "room", "boxes")
"""Scenes built from analytic primitives: the exact SDF is available (row ``evans-analytic``)."""
ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0)
BASES_VOX = (0.5, 1.0, 2.0)
CONE_KS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
CREASE_PROBE_X = (0.05, 0.1, 0.2, 0.4)
"""Floor probes (y = 0) of the creases: the finite arms are exact within R = 1 there."""
FIT_POINTS = 2048  # pixels per scene used by the fits (padded: one JAX compile per model size)
METRICS = ("rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim")


CONFIG = {
    "scenes": ConfigKey("str", "scenes", shape=(None,), choices=SCENE_NAMES),
    "targets": ConfigKey("str", "reference targets", shape=(None,), choices=TARGETS_FULL),
    "resolution": ConfigKey("int", "image side (pixels)", 8, 4096),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "grid": ConfigKey("int", "SDF grid side (voxels)", 8, 1024),
    "n_samples": ConfigKey("int", "Evans SDF samples", 1, 16),
    "ao_distance": ConfigKey("float", "AO radius (scene units)", 1e-6, 1e3),
    "albedo": ConfigKey("float", "surface albedo", 0.0, 1.0),
    "sweep_grids": ConfigKey("int", "grid sides of the sweep", 8, 1024, (None,)),
    "sweep_n": ConfigKey("int", "sample counts of the sweep", 1, 16, (None,)),
    "sweep_scenes": ConfigKey("str", "scenes of the sweep", shape=(None,), choices=SCENE_NAMES),
    "alphas": ConfigKey("float", "blend weights α", 0.0, 1.0, (None,)),
    "bases_vox": ConfigKey("float", "base distances (voxels)", 0.01, 64.0, (None,)),
    "map_scenes": ConfigKey("str", "scenes with error maps", shape=(None,), choices=SCENE_NAMES),
    "probe_spp": ConfigKey("int", "samples per probe point", 2, SPP_MAX),
    "cost_points": ConfigKey("int", "points per timed launch", 1024, 1 << 26),
    "cone_count": ConfigKey("int", "cones of the cone tracer", 1, 64),
    "cone_steps": ConfigKey("int", "steps per cone", 1, 256),
    "sun_elevation": ConfigKey("float", "sun elevation (°)", 0.0, 90.0),
    "sun_azimuth": ConfigKey("float", "sun azimuth (°)", -360.0, 360.0),
    "turbidity": ConfigKey("float", "sky turbidity", 1.0, 10.0),
    "lm_max_iter": ConfigKey("int", "Levenberg–Marquardt iterations", 1, 10000),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    cone = METHODS["cone"].fixed
    return checked(
        CONFIG,
        {
            "scenes": list(SCENE_NAMES),
            "targets": list(TARGETS_QUICK if quick else TARGETS_FULL),
            "resolution": 36 if quick else 128,
            "spp": spp or (64 if quick else 1024),
            "pass_spp": 32 if quick else 256,
            "grid": 64 if quick else 128,
            "n_samples": EVANS_SAMPLES,
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
            "cone_count": cone["cones"],
            "cone_steps": cone["steps"],
            "sun_elevation": 30.0,
            "sun_azimuth": 60.0,
            "turbidity": 3.0,
            "lm_max_iter": 100 if quick else 300,
        },
    )


# ============================================================================================== methods
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


def _evans_value_and_slope(d, logb, c):
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
        pred, pl = _evans_value_and_slope(d, logb, c)
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


def _subsample(n_pts: int, seed: int, size: int = FIT_POINTS):
    """Indices of at most ``size`` points and a 0/1 weight vector of length ``size`` (padding)."""
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(n_pts, size=min(n_pts, size), replace=False))
    w = np.zeros(size)
    w[: len(idx)] = 1.0
    return idx, w


class SceneData:
    """One scene's rendered data (G-buffer points, references, voxel grid) with memoised Evans terms."""

    def __init__(self, name, r, cfg):
        self.name = name
        self.r = r
        self.mask = r["mask"]
        self.points = r["points"]
        self.normals = r["normals"]
        g = SdfGrid(r["grid"]["values"], tuple(r["grid"]["origin"]), float(r["grid"]["voxel"]))
        self.grid = g
        self.sdf = GridSDF.from_grid(g, levels=8, prefilter=True)
        self.voxel = g.voxel
        self.n = cfg["n_samples"]
        self._terms = {}
        self.cone_cache = {}
        self.fit_idx, self.fit_w = _subsample(len(self.points), sum(map(ord, name)))
        prims = build(name)[1] if name in ANALYTIC_SCENES else None
        self.analytic = AnalyticSDF(prims) if prims else None

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
        return self.r["refs"][t]["mean"], self.r["refs"][t]["stderr"]

    def factor(self, t):
        """The sky factor g(N) per point for sunsky targets (`sky_factor`), else None (g = 1)."""
        if t in SUNSKY_TARGETS:
            g = self.r.get("sky_factor")
            if g is None:
                raise ValueError(f"{self.name}: target {t} needs the per-point sky factor (render with it)")
            return np.asarray(g, dtype=np.float64)
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
        return EvansFitData(
            self.points[i],
            self.normals[i],
            self.analytic if analytic else self.sdf,
            self.voxel,
            ref[i],
            None if g is None else g[i],
        )

    def image(self, values):
        img = np.zeros(self.mask.shape)
        img[self.mask] = values
        return img


def _values(fit):
    return {k: v["value"] for k, v in fit["parameters"].items()}


def _fit_kernel(method, sd: SceneData, t, inputs: dict, start: dict):
    """Fit ``method``'s parameters (start values ``start``, the declared bounds) to target t on the fit
    subsample through the JAX run of its kernel (`fit_method`); ``inputs`` are full per-point arrays."""
    y, fw = sd.fit_target(t)
    params = {k: dataclasses.replace(p, initial=start[k]) for k, p in method.params.items()}
    sub = {k: zero_padded(np.asarray(v)[..., sd.fit_idx], FIT_POINTS) for k, v in inputs.items()}
    return fit_method(method, sub, y, weights=fw, params=params).to_dict()


def fit_seed(sd: SceneData, t, method_id: str):
    """The seed's Evans forms (``evans-text``, ``evans-listing``): α, base and weights as the method fixes
    them, k (and B) fitted. Returns (fit dict, g·C at every point, the row's parameters)."""
    m = METHODS[method_id]
    d = sd.terms(m.fixed["alpha"], m.fixed["base_voxels"])
    start = {"k": 1.0 / (10 * sd.voxel), "logB": 0.0}
    f = _fit_kernel(m, sd, t, {"terms": d}, start)
    pred = m(NUMPY_OPS, {"terms": d}, _values(f))
    params = {**_values(f), "alpha": m.fixed["alpha"], "base": m.fixed["base_voxels"] * sd.voxel}
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
                pred, pl = _evans_value_and_slope(d, x[0], x[1:])
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
    v = _values(best["fit"])
    d = sd.terms(best["alpha"], best["base_vox"], analytic=analytic)
    c = np.array([v[f"c{i + 1}"] for i in range(d.shape[0])])
    pred = evans_from_terms_kernel(NUMPY_OPS, d, logB=v["logB"], weights=c)
    return pred if t is None else sd.scaled(t, pred)


def fit_curvature(sd: SceneData, t):
    """The curvature row: k fitted through the kernel on the blurred SDF at the points (level
    `CURVATURE_LEVEL`). Returns (fit dict, g·C at every point)."""
    m = METHODS["curvature"]
    dist = np.asarray(sd.sdf.sample(NUMPY_OPS, CURVATURE_LEVEL, *sd.points.T))
    f = _fit_kernel(m, sd, t, {"distance": dist}, {"k": -1.0 / sd.voxel})
    return f, sd.scaled(t, m(NUMPY_OPS, {"distance": dist}, _values(f)))


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


# ---- rows: each row is a method of the table plus where its parameters come from
def _row_seed(row, sd, t, state):
    _, pred, params = fit_seed(sd, t, row.method)
    return pred, params, None


def _row_case(row, sd, t, state):
    b = fit_evans([sd], t, state["cfg"])
    return predict_free(sd, b, t=t), evans_readable(b, sd.voxel), b


def _row_analytic(row, sd, t, state):
    if sd.analytic is None:
        return None
    b = fit_evans([sd], t, state["cfg"], analytic=True)
    return predict_free(sd, b, analytic=True, t=t), evans_readable(b, sd.voxel), b


def _row_joint(row, sd, t, state):
    b = state["joint"][t]
    return predict_free(sd, b, t=t), evans_readable(b, sd.voxel), None


def _row_curvature(row, sd, t, state):
    f, pred = fit_curvature(sd, t)
    return pred, {"k_text": _values(f)["k"], "level": CURVATURE_LEVEL}, None


def _row_cone(row, sd, t, state):
    cfg = state["cfg"]
    k, pred = cone_best(sd, t, cfg)
    params = {"k": k, "cones": cfg["cone_count"], "steps": cfg["cone_steps"], "t0": sd.voxel}
    return pred, {**params, "t_max": cfg["ao_distance"]}, None


def _evans_timed(method, values):
    """The per-pixel Evans kernel (`evans_kernel`: samples and the one combination text) of ``method`` at
    ``values``, for the cost rows."""

    def make(sd, cfg):
        kw = method.keywords(values)
        weights = kw["weights"] if "weights" in kw else [kw[f"c{i + 1}"] for i in range(EVANS_SAMPLES)]
        prm = EvansParams(
            n=EVANS_SAMPLES, base=kw["base_voxels"] * sd.voxel, k=kw["k"], alpha=kw["alpha"], weights=weights
        )
        return lambda *a: evans_kernel(DRJIT_OPS, sd.sdf, prm, *a)

    return make


def _curvature_timed(sd, cfg):
    m = METHODS["curvature"]
    return lambda *a: m(
        DRJIT_OPS, {"distance": sd.sdf.sample(DRJIT_OPS, CURVATURE_LEVEL, *a[:3])}, {"k": -1.0}
    )


def _cone_timed(sd, cfg):
    k = METHODS["cone"].params["k"].initial
    return lambda *a: cone_kernel(
        DRJIT_OPS, sd.sdf, cfg["cone_count"], cfg["cone_steps"], sd.voxel, cfg["ao_distance"], k, *a
    )


# A row of the comparison (`rows.Row`): ``method`` (an id of `METHODS`) plus where its parameters come from
# (``evaluate(row, scene, target, state) -> (g·C per point, parameters, continuous fit or None)``, or None
# where the row does not apply); ``short``: its name in narrow columns. ``timed``: builds the per-pixel
# Dr.Jit kernel for the cost row (None: ``cost_of`` names the row whose measured kernel this row runs, or
# no cost row). Its title: its ``label``, else its method's.
ROWS = (
    *(
        Row(m, method=m, short=short, evaluate=_row_seed, timed=_evans_timed(METHODS[m], {"k": 1.0}))
        for m, short in (("evans-text", "Evans text"), ("evans-listing", "Evans listing"))
    ),
    Row(
        "evans-fit",
        method="evans-fit",
        short="Evans fit",
        evaluate=_row_case,
        # representative fitted values (the cost does not depend on them)
        timed=_evans_timed(METHODS["evans-fit"], {"alpha": 0.3, "c1": 1.0, "c2": 0.9, "c3": 0.8, "c4": 0.7}),
    ),
    Row(
        "evans-joint",
        "Evans, joint fit",
        "evans-fit",
        short="Evans joint",
        evaluate=_row_joint,
        cost_of="evans-fit",
    ),
    Row("curvature", method="curvature", short="curvature", evaluate=_row_curvature, timed=_curvature_timed),
    Row("cone", method="cone", short="cone DF AO", evaluate=_row_cone, timed=_cone_timed),
    Row(
        "evans-analytic",
        "Evans fitted, exact analytic SDF (no grid, no blur)",
        "evans-fit",
        short="Evans fit, exact SDF",
        evaluate=_row_analytic,
    ),
)
"""The model rows, in table order. The AO cases add two rows on Mitsuba's ``sdfgrid`` geometry
(`GRID_ROWS`)."""
GRID_ROWS = {
    "sdfgrid": ("sdfgrid AO", "Mitsuba AO on the sdfgrid (grid error)"),
    "evans-on-sdfgrid": (
        "Evans fit on sdfgrid",
        "Evans fitted, on the voxelised geometry vs its own AO (model error only)",
    ),
}
"""id → (short, label) of the rows on the voxelised geometry: the sdfgrid's own AO (grid error) and Evans
fitted at its surface points against it (model error alone)."""
SHORT = {**{r.id: r.short for r in ROWS}, **{k: v[0] for k, v in GRID_ROWS.items()}}
LABELS = {**{r.id: r.title(METHODS) for r in ROWS}, **{k: v[1] for k, v in GRID_ROWS.items()}}
MAP_ROWS = ("evans-text", "evans-listing", "evans-fit", "evans-joint", "cone")
"""Rows shown in the error-map figures."""


# ================================================================================================ cases
def mesh_of(scene):
    vs, fs, off = [], [], 0
    for sh in scene.shapes:
        v, f = read_ply(sh.file)
        vs.append(v * np.asarray(sh.scale) + np.asarray(sh.translate))  # library meshes: no rotation
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def grid_of(scene, resolution: int, cache_dir=None):
    """The scene mesh's voxel SDF at ``resolution`` cells on the longest axis (cached as .npz by content)."""
    v, f = mesh_of(scene)
    h = hashlib.sha256(
        v.astype(np.float32).tobytes() + f.astype(np.int32).tobytes() + str(resolution).encode()
    )
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / "sdf-grids" / f"{h.hexdigest()[:24]}-{resolution}.npz"
        if path.exists():
            z = np.load(path)
            return SdfGrid(z["values"], tuple(z["origin"]), float(z["voxel"]), meta={"source": "mesh"})
    lo, hi = mesh_bounds(v)
    origin, voxel, shape = grid_for_bounds(lo, hi, resolution, pad_voxels=3.0, cubic=True)
    g = mesh_sdf_grid(v, f, origin, voxel, shape)
    if path is not None:
        buf = io.BytesIO()
        np.savez(buf, values=g.values, origin=np.asarray(g.origin), voxel=g.voxel)
        atomic_write_bytes(path, buf.getvalue())
    return g


def _metrics(img, ref_img, err_img, mask):
    return grey_metrics(img, ref_img, err_img, mask, METRICS)


def _approx_doc(method, label, fitted, parameters, metrics) -> dict:
    return {
        "method": method,
        "label": label,
        "fitted": fitted,
        "parameters": parameters,
        "metrics": metrics,
        "cost": None,
        "figures": [],
    }


def _sdfgrid_doc(sd: SceneData) -> dict:
    """Mitsuba's AO on the sdfgrid shape against the mesh AO: the grid-resolution error (both images are
    noisy: the floor uses the combined standard error)."""
    ref, err = sd.target("ao")
    ref_img, err_img = sd.image(ref), sd.image(err)
    g = sd.r["sdfgrid_ao"]
    both = sd.mask & np.isfinite(g)
    comb = np.sqrt(np.where(both, err_img**2 + np.nan_to_num(sd.r["sdfgrid_ao_stderr"]) ** 2, err_img**2))
    met = _metrics(np.where(both, g, 0.0), np.where(both, ref_img, 0), comb, both)
    return _approx_doc("sdfgrid", LABELS["sdfgrid"], False, {"grid_voxel": sd.voxel}, met)


def _model_only_doc(sd: SceneData, cfg) -> dict:
    """Evans fitted on the sdfgrid's own G-buffer against the AO of the sdfgrid geometry: both sides see the
    same voxelised surface, so what remains is the occlusion model's error alone."""
    sd2 = SceneData(sd.name, {**sd.r, **sd.r["sdfgrid_gbuffer"]}, cfg)
    b = fit_evans([sd2], "ao", cfg)
    ref, err = sd2.target("ao")
    met = _metrics(sd2.image(predict_free(sd2, b)), sd2.image(ref), sd2.image(err), sd2.mask)
    params = _approx_params(evans_readable(b, sd.voxel))
    return _approx_doc("evans-on-sdfgrid", LABELS["evans-on-sdfgrid"], True, params, met)


def _finite(v):
    return v is not None and isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(float(v))


def _approx_params(p: dict) -> dict:
    """An approximation's parameter values for results.json (name → number): stderrs and undefined values are
    left out (they are in the fitted files and the fit table)."""
    return {k: float(v) for k, v in p.items() if not k.endswith("_stderr") and _finite(v)}


def _json_params(p: dict) -> dict:
    """Values and stderrs, undefined ones as None (JSON has no NaN)."""
    return {k: (float(v) if _finite(v) else None) for k, v in p.items()}


def _lm_summary(b: dict) -> dict:
    """The continuous fit in a few numbers: readable parameters with stderrs, RMS residual before (grid) and
    after, LM iterations, convergence."""
    return {
        **_json_params(evans_readable(b, None)),
        "rms_residual": b["fit"]["rms_residual"],
        "rms_residual_grid": b["grid"]["rms_residual"],
        "grid_alpha": b["grid"]["alpha"],
        "grid_base_voxels": b["grid"]["base_vox"],
        "lm_iterations": b["lm"]["iterations"],
        "converged": b["fit"]["converged"],
        "message": b["fit"]["message"],
        "at_bound": [k for k, v in b["fit"]["parameters"].items() if v["at_bound"]],
    }


def case_id(scene: str, target: str) -> str:
    """A case's id: scene and target, e.g. ``"boxes-ao"``."""
    return f"{scene}-{target}".replace("_", "")


def save_pixels(out, cfg, sds, maps) -> None:
    """Each case's reference, stderr and row images (the `ROWS` of `evaluate_cases`, on the scene's mask) for
    the report's image viewer (the sdfgrid rows use their own masks and are left out)."""
    for n in cfg["scenes"]:
        sd = sds[n]
        for t in cfg["targets"]:
            rows = {m: img for (sn, tn, m), img in maps.items() if (sn, tn) == (n, t) and m != "ref"}
            save_case_pixels(
                out, case_id(n, t), maps[(n, t, "ref")], sd.image(sd.target(t)[1]), rows, sd.mask
            )


def evaluate_cases(cfg, sds, joint):
    """Every (scene, target) case: each row of `ROWS` that applies, plus the sdfgrid rows for AO. Returns
    (case docs, per-case parameters, continuous-fit rows, maps {(scene, target, row or "ref"): image})."""
    state = {"cfg": cfg, "joint": joint}
    case_docs, per_case_params, fit_rows, maps = [], {}, [], {}
    for n in cfg["scenes"]:
        sd = sds[n]
        for t in cfg["targets"]:
            ref, err = sd.target(t)
            ref_img, err_img = sd.image(ref), sd.image(err)
            cid = case_id(n, t)
            approx_docs, params, fitted = [], {}, {}
            for row in ROWS:
                got = row.evaluate(row, sd, t, state)
                if got is None:
                    continue
                pred, params[row.id], fitted[row.id] = got
                img = sd.image(pred)
                maps[(n, t, row.id)] = img
                met = _metrics(img, ref_img, err_img, sd.mask)
                row_params = _approx_params(params[row.id])
                approx_docs.append(_approx_doc(row.id, LABELS[row.id], True, row_params, met))
            if t == "ao" and sd.r["sdfgrid_ao"] is not None:
                approx_docs.append(_sdfgrid_doc(sd))
                approx_docs.append(_model_only_doc(sd, cfg))
            per_case_params[cid] = {m: _json_params(v) for m, v in params.items()}
            for m, b in fitted.items():
                if b is not None:
                    per_case_params[cid][f"{m}-lm"] = _lm_summary(b)
            fit_rows.append(
                {"case": cid, "scene": n, "target": t, "voxel": sd.voxel, **_lm_summary(fitted["evans-fit"])}
            )
            sky_meta = (
                {
                    "sun_elevation_deg": cfg["sun_elevation"],
                    "sun_azimuth_deg": cfg["sun_azimuth"],
                    "turbidity": cfg["turbidity"],
                }
                if t in SUNSKY_TARGETS
                else {}
            )
            case_docs.append(
                {
                    "id": cid,
                    "label": f"{n.replace('_', ' ')}: {TARGET_LABEL[t]}",
                    "parameters": {
                        "scene": n,
                        "target": t,
                        "grid_cells": cfg["grid"],
                        "voxel": sd.voxel,
                        "ao_distance": cfg["ao_distance"] if t == "ao" else None,
                        "albedo": cfg["albedo"] if t in ("sky-gi", "sunsky-gi") else None,
                        **sky_meta,
                        "held_out": n == HELD_OUT,
                    },
                    "scene": {"name": f"sdf-{n}", "hash": sd.r["scene_hash"]},
                    "reference": sd.r["refs"][t]["meta"],
                    "approximations": approx_docs,
                }
            )
            maps[(n, t, "ref")] = ref_img
    return case_docs, per_case_params, fit_rows, maps


# ================================================================================================= jobs
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
    scene = load_case_scene(name, resolution)
    mi, mi_scene = load_mitsuba_scene(scene, variant)
    gb = gbuffer(mi, mi_scene)
    mask = gb.mask
    pts, nrm = gbuffer_points(gb, mask)
    cache = OcclusionCache(cache_dir)
    geo = scene_hash(scene)
    sky = SunskySky(sun_elevation, sun_azimuth, turbidity)

    def reference(points, normals, quantity, n_spp, per_pass, *, geometry=(mi_scene, geo), **kw):
        return cache.get(
            mi, *geometry, points, normals, spp=n_spp, pass_spp=per_pass, seed=seed, variant=variant,
            quantity=quantity, **kw
        )  # fmt: skip

    refs = {}
    for t in targets:
        dist = ao_distance if t == "ao" else math.inf
        r = reference(pts, nrm, TARGET_QUANTITY[t], spp, pass_spp, max_distance=dist, albedo=albedo, sky=sky)
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
            per = min(sspp, 1 << 14)
            rd = reference(pp, pn, "sunsky_direct", sspp, per, sky=sky)
            rg = reference(pp[:1], pn[:1], "sunsky_global", sspp, per, albedo=albedo, sky=sky)
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
        r = reference(pp, pn, "ao", probe_spp, min(probe_spp, 1024), max_distance=ao_distance)
        probes = {"x": xs, "mean": r.mean, "stderr": r.stderr}
    g = grid_of(scene, grid, cache_dir)
    try:
        mi_sdf = sdfgrid_scene(mi, g, scene.camera)
    except RuntimeError as exc:  # e.g. "SDFGrid should at least have one non-empty voxel": too coarse a grid
        mi_sdf, sdf_error = None, str(exc).splitlines()[-1][:200]
    img2 = err2 = None
    meta2 = sdf_gb = None
    if mi_sdf is not None:
        gb2 = gbuffer(mi, mi_sdf)
        m2 = gb2.mask
        p2, n2 = gbuffer_points(gb2, m2)
        ok = np.all(np.isfinite(n2), axis=1) & (np.linalg.norm(n2, axis=1) > 0.5)
        gh = hashlib.sha256(g.values.tobytes() + repr((g.origin, g.voxel)).encode()).hexdigest()
        r2 = reference(
            p2[ok], n2[ok], "ao", spp, pass_spp, geometry=(mi_sdf, "sdfgrid-" + gh), max_distance=ao_distance
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
        "triangles": len(mesh_of(scene)[1]),
        "sky_factor": factor,
        "sky_probe": sky_probe_out,
    }


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    jobs = [
        Job(
            render_case,
            dict(
                name=n,
                resolution=cfg["resolution"],
                **reference_args(ctx, cfg),
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
    rendered = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="references"), strict=True))

    out = ctx.out_dir
    t_start = time.perf_counter()
    sds = {n: SceneData(n, rendered[n], cfg) for n in cfg["scenes"]}
    train = [sds[n] for n in cfg["scenes"] if n != HELD_OUT]
    joint = {t: fit_evans(train, t, cfg) for t in cfg["targets"]}
    ctx.log(f"joint fits done ({time.perf_counter() - t_start:.1f} s)")
    case_docs, per_case_params, fit_rows, maps = evaluate_cases(cfg, sds, joint)
    save_pixels(out, cfg, sds, maps)
    ctx.log(f"per-case fits done ({time.perf_counter() - t_start:.1f} s)")
    costs = measure_costs(sds, cfg)
    attach_costs(case_docs, costs)
    sweep = run_sweep(ctx, cfg, sds)
    ctx.log(f"sweep done ({time.perf_counter() - t_start:.1f} s)")
    figs = make_figures(out, cfg, sds, maps, case_docs, sweep, costs)
    fits_out = write_fitted(
        out, cfg, joint, per_case_params, sds, ctx, [sd.r["scene_hash"] for sd in sds.values()]
    )
    checks = make_checks(cfg, sds, case_docs, fit_rows)
    return {
        "summary": summary(cfg, case_docs, joint, sweep, sds),
        "config": dict(cfg),
        "sections": _with_fit_table(_with_sweep_table(sections(cfg), sweep), fit_rows, joint, sds, cfg),
        "cases": case_docs,
        "fits": fits_out,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": notes(cfg),
        "sweep": sweep,
    }


def _fit_k(d, ref):
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


def run_sweep(ctx, cfg, sds) -> list[dict]:
    """Steps (n) × grid resolution × prefilter × 8-bit: Evans as pure occlusion (α = 0, w_i = 1, base = one
    voxel of the grid) with k and B refitted per configuration, error against the AO reference (mean RMSE
    over the sweep scenes) and measured ns per pixel."""
    Float = _dr_float()
    target = "ao"
    rows = []
    configs = []
    for res in cfg["sweep_grids"]:
        for n in cfg["sweep_n"]:
            configs.append((res, n, True, False))
        configs.append((res, 4, False, False))
        configs.append((res, 4, True, True))
    grids = {}
    for name in cfg["sweep_scenes"]:
        sc = load_case_scene(name, cfg["resolution"])
        for res in cfg["sweep_grids"]:
            grids[(name, res)] = grid_of(sc, res, ctx.cache_dir)
    size = int(cfg["cost_points"])
    for res, n, pre, q8 in configs:
        errs, floors = [], []
        timing = None
        for name in cfg["sweep_scenes"]:
            sd = sds[name]
            g = grids[(name, res)]
            if q8:
                g = quantize_8bit(g)
            sdf = GridSDF.from_grid(g, levels=8, prefilter=pre)
            prm = EvansParams(n=n, base=g.voxel, k=1.0, alpha=0.0, prefilter=True)
            d = evans_terms(sd.points, sd.normals, sdf, prm)
            ref, err = sd.target(target)
            k, logb = _fit_k(d, ref)
            pred = evans_from_terms_kernel(NUMPY_OPS, d, logB=logb, k=k)
            errs.append(float(np.sqrt(np.mean((pred - ref) ** 2))))
            floors.append(float(np.sqrt(np.mean(err**2))))
            if timing is None:
                cols = _columns(sd, np.random.default_rng(1).integers(0, len(sd.points), size), Float)
                timing = time_drjit(
                    lambda *a, s=sdf, p=prm: evans_kernel(DRJIT_OPS, s, p, *a),
                    cols,
                    size,
                    repeats=5,
                    min_seconds=0.1,
                )
        rows.append(
            {
                "grid": res,
                "n": n,
                "prefilter": pre,
                "bits": 8 if q8 else 32,
                "target": target,
                "rmse": float(np.mean(errs)),
                "noise_floor": float(np.mean(floors)),
                "ns_per_pixel": timing.ns_per_element,
                "seed_default": bool(res == 128 and n == 4 and pre and q8),
            }
        )
    return rows


# =============================================================================================== checks
def _check(name: str, value, expected: str, passed) -> Check:
    return Check(name=name, value=value, expected=expected, passed=bool(passed))


def _max_z_check(name: str, z) -> dict:
    """max |z| ≤ 4 (a 4σ tolerance: a handful of probes, no multiple-comparison correction needed)."""
    value = float(np.max(np.abs(z)))
    return _check(name, value, "≤ 4", value <= 4.0)


def make_checks(cfg, sds, case_docs, fit_rows=()) -> list[dict]:
    checks = []
    if fit_rows:
        # The continuous LM starts at the grid's best point and accepts only steps that lower the SSR.
        worse = [
            r["case"] for r in fit_rows if r["rms_residual"] > r["rms_residual_grid"] * (1 + 1e-9) + 1e-12
        ]
        name = (
            "continuous Evans fit (LM, autodiff α/base) never above its grid initialisation "
            "(RMS residual, every case)"
        )
        checks.append(_check(name, len(worse), "0", not worse))
    # Mitsuba AO at floor probes of each crease vs the wedge integral (independent quadrature, `crease_ao`).
    # Within R = ao_distance ≤ 1 the shipped crease (arms 2 long, 2 wide) is exact for probes at y = 0,
    # x ≤ 0.4.
    for n in cfg["scenes"]:
        pr = sds[n].r.get("probes") if n.startswith("crease_") else None
        if pr is None:
            continue
        phi = math.radians(float(n.split("_")[1]))
        expect = np.array([crease_ao(phi, x, cfg["ao_distance"]) for x in pr["x"]])
        z = (pr["mean"] - expect) / np.sqrt(pr["stderr"] ** 2 + 1e-5**2)  # 1e-5: float32 ray precision
        name = (
            f"Mitsuba AO at {len(expect)} floor probes of the {n.split('_')[1]}° crease vs the "
            "wedge integral (max |z|)"
        )
        checks.append(_max_z_check(name, z))
    # Structural: Evans with a normalised bent normal is exactly 1 on an unoccluded plane (analytic SDF).
    pts = np.column_stack([np.linspace(-1, 1, 64), np.zeros(64), np.zeros(64)])
    c = evans_occlusion(
        pts,
        np.tile([0.0, 0.0, 1.0], (64, 1)),
        AnalyticSDF([HalfSpace((0, 0, 0), (0, 0, 1))]),
        EvansParams(n=8, base=0.01, k=50.0, alpha=0.5, normalize=True),
    )
    dev = float(np.max(np.abs(np.asarray(c) - 1.0)))
    name = "Evans on an unoccluded plane (analytic SDF, normalised N') equals 1"
    checks.append(_check(name, dev, "max |C − 1| ≤ 1e-6", dev <= 1e-6))
    # The sunsky reference at an unoccluded point vs the quadrature of the baked sky (an independent
    # integration); rendered for the first scene only.
    pr = next((sds[n].r["sky_probe"] for n in cfg["scenes"] if sds[n].r.get("sky_probe") is not None), None)
    if pr is not None:
        z = (pr["direct_mean"] - pr["expected"]) / np.maximum(pr["direct_stderr"], 1e-12)
        name = (
            "sunsky one bounce at an unoccluded point, facing up (E/E_h = 1) and sideways "
            f"(4 azimuths), vs the sky-irradiance quadrature: max |z| ({pr['spp']} spp)"
        )
        checks.append(_max_z_check(name, z))
        z = (pr["global_mean"][:1] - pr["expected"][:1]) / max(pr["global_stderr"][0], 1e-12)
        checks.append(
            _max_z_check(
                "sunsky global illumination at an unoccluded upward-facing point vs the quadrature (|z|)", z
            )
        )
    # Every row produced finite metrics.
    bad = [
        d["id"]
        for d in case_docs
        if not all(np.isfinite(a["metrics"]["rmse"]["value"] or np.nan) for a in d["approximations"])
    ]
    checks.append(_check("every metric finite", len(bad), "0", not bad))
    return checks


def crease_ao(phi: float, x: float, R: float) -> float:
    """AO within distance R of a floor point at distance x > 0 from the edge of an infinite wedge of interior
    angle φ (floor z = 0 for x > 0, wall from the edge at angle φ), normal +z.

    Directions ω = (cos β cos ψ, sin β, cos β sin ψ) (ψ: projected angle in the xz plane, β: out of it),
    dω = cos β dβ dψ, cos θ = cos β sin ψ. A direction with ψ ∈ (φ, π) meets the wall at in-plane distance
    ρ(ψ) = x sin φ / sin(ψ − φ), i.e. at distance ρ/cos β: it is occluded within R when cos β > ρ/R, so
    |β| < b(ψ) = acos(min(ρ/R, 1)), and ∫_{−b}^{b} cos²β dβ = b + sin b cos b. Hence

        AO = 1 − (1/π) ∫_φ^π sin ψ · (b + sin b cos b) dψ,

    which for R = ∞ (b = π/2) is (1 − cos φ)/2. Integrated with SciPy's adaptive quadrature."""
    from scipy.integrate import quad  # scipy: optional heavy import, only for this check

    if not (0 < phi < math.pi) or not (x > 0) or not (R > 0):
        raise ValueError(f"need 0 < phi < pi, x > 0, R > 0 (got {phi}, {x}, {R})")

    def f(psi):
        rho = x * math.sin(phi) / max(math.sin(psi - phi), 1e-300)
        b = math.acos(min(rho / R, 1.0)) if math.isfinite(R) else math.pi / 2
        return math.sin(psi) * (b + math.sin(b) * math.cos(b))

    val, _ = quad(f, phi, math.pi, epsabs=1e-12, epsrel=1e-10, limit=200)
    return 1.0 - val / math.pi


# ============================================================================================== figures
def make_figures(out, cfg, sds, maps, case_docs, sweep, costs) -> list[dict]:
    figs = []
    for t, n in [
        (t, n)
        for t in cfg["targets"]
        if t in ("ao", "sky", "sunsky")
        for n in cfg.get("map_scenes", cfg["scenes"])
        if n in sds
    ]:
        sd = sds[n]
        name = f"figures/maps_{n}_{t}.png"
        panels = [(SHORT[m], maps[(n, t, m)]) for m in MAP_ROWS]
        figures.image_comparison(
            out / name,
            maps[(n, t, "ref")][..., None].repeat(3, -1),
            [(lab, img[..., None].repeat(3, -1)) for lab, img in panels],
            sd.mask,
            error_scale=1.0,
            exposure=1.0,
            title=f"{n}: {TARGET_LABEL[t]}",
        )
        figs.append(
            {
                "file": name,
                "section": "failures",
                "caption": f"{n.replace('_', ' ')}: reference ({TARGET_LABEL[t]}) and approximations with "
                "signed "
                "error maps (red: too bright, blue: too dark).",
            }
        )
    t = "sky" if "sky" in cfg["targets"] else cfg["targets"][0]
    # Pareto: sweep points
    pts = []
    for r in sweep:
        lab = (
            f"{r['grid']}³ n={r['n']}"
            + ("" if r["prefilter"] else " nofilt")
            + (" 8bit" if r["bits"] == 8 else "")
        )
        if r["seed_default"]:
            lab += " ★seed"
        pts.append({"x": r["ns_per_pixel"], "y": r["rmse"], "label": lab})
    name = "figures/pareto_steps.png"
    figures.pareto_plot(
        out / name,
        pts,
        "cost (ns per pixel, measured)",
        "mean RMSE vs Mitsuba AO",
        floor=float(np.mean([r["noise_floor"] for r in sweep])),
    )
    figs.append(
        {
            "file": name,
            "section": "sweep",
            "caption": "Steps vs error vs cost: Evans occlusion (α = 0, w = 1; k and B refitted per point) "
            "against "
            "the AO reference, over samples n, grid resolution, prefiltering and 8-bit storage; ★ marks "
            "the seed's 4 samples at 128³ in 8 bit.",
        }
    )
    # method Pareto
    err = {}
    for doc in case_docs:
        for ap in doc["approximations"]:
            err.setdefault(ap["method"], []).append(ap["metrics"]["rmse"]["value"])
    cost = {c["method"]: c["ns_per_pixel"] for c in costs}
    pts = [{"x": cost[m], "y": float(np.mean(v)), "label": SHORT[m]} for m, v in err.items() if m in cost]
    name = "figures/pareto_methods.png"
    figures.pareto_plot(out / name, pts, "cost (ns per pixel, measured)", "mean RMSE over all cases")
    figs.append(
        {"file": name, "section": "costs", "caption": "Mean RMSE over all cases vs measured cost per pixel."}
    )
    # crease: AO vs angle
    cre = [n for n in cfg["scenes"] if n.startswith("crease_")]
    if cre:
        name = "figures/crease_profile.png"
        series = []
        for m in ("ref", "evans-fit", "cone"):
            xs, ys = [], []
            for n in cre:
                sd = sds[n]
                v = maps[(n, "ao", m)][sd.mask]
                sel = sd.normals[:, 2] > 0.99  # floor points
                xs.append(float(n.split("_")[1]))
                ys.append(float(np.mean(v[sel])) if np.any(sel) else float("nan"))
            series.append(
                {
                    "x": xs,
                    "y": ys,
                    "label": "Mitsuba AO" if m == "ref" else SHORT[m],
                    "style": "points" if m == "ref" else "line",
                }
            )
        figures.line_plot(out / name, "crease angle φ (degrees)", "mean AO of the floor arm", series)
        figs.append(
            {
                "file": name,
                "section": "failures",
                "caption": "Mean AO over the visible floor arm of each crease against the crease angle.",
            }
        )
    return figs


# ============================================================================================== summary
def sections(cfg) -> list[dict]:
    return [
        {
            "id": "method",
            "title": "Method",
            "text": "Every scene is a closed triangle mesh (generated procedurally, "
            "`experiments/sdf_occlusion_scenes.py`). "
            f"Its voxel SDF ({cfg['grid']}³ cells, exact Euclidean distance in a narrow band, closest-point "
            "propagation "
            "beyond, sign by ray parity) is prefiltered into a Gaussian mip chain; Evans' estimator samples "
            f"n = {cfg['n_samples']} points at d_i = base·2^(i−1) along the bent normal N + αU, sample i "
            "from mip "
            "level i − 1, and returns C = B·exp(−k Σ w_i (d_i − s_i)). Ground truth is rtfit's ray-cast "
            "estimator "
            f"through Mitsuba at the same pixel-centre points: AO within R = {cfg['ao_distance']:g}, and "
            "upper-hemisphere sky light with one bounce and (full run) all bounces at albedo "
            f"{cfg['albedo']:g} under two skies: a constant one (E/πL) and Mitsuba's `sunsky` without its "
            "sun "
            f"(sun at {cfg['sun_elevation']:g}° elevation, {cfg['sun_azimuth']:g}° azimuth from +Y towards "
            "+X, "
            f"turbidity {cfg['turbidity']:g}; luminance, as E/E_h with E_h the unoccluded horizontal "
            "irradiance). Under "
            "the sunsky every approximation is multiplied by the unoccluded sky's directional factor "
            "g(N) = E_sky(N)/E_u(N), E_u(N) the irradiance of a constant upper-hemisphere sky of the same "
            "E_h "
            "(quadrature of the baked sky; g ≡ 1 for a constant sky, so the constant-sky rows are the "
            "special case); "
            f"{cfg['spp']} samples per point in passes of {cfg['pass_spp']}. Mitsuba's `sdfgrid` "
            "shape built from the same grid gives the AO of the voxelised geometry: its difference from the "
            "mesh AO "
            "is the grid-resolution error (row *sdfgrid* in the AO cases), and Evans fitted at that "
            "geometry's own "
            "surface points against its own AO is the occlusion-model error alone (row *evans-on-sdfgrid*). "
            "Row *evans-analytic* fits Evans on the exact SDF of the primitives (sphere on plane, room, "
            "boxes).",
        },
        {
            "id": "fit",
            "title": "The continuous Evans fit",
            "placement": "after_results",
            "text": "Rows *evans-fit*, *evans-joint*, *evans-analytic* and *evans-on-sdfgrid* fit log B, "
            "c_i = k·w_i "
            f"(i = 1..{cfg['n_samples']}), α and the base distance together. Initialisation: for each (α, "
            "base) of "
            f"the grid α ∈ {{{', '.join(f'{a:g}' for a in cfg['alphas'])}}} × base ∈ "
            f"{{{', '.join(f'{b:g}' for b in cfg['bases_vox'])}}} voxels the model is linear in (log B, "
            "c_i) inside "
            "the exponent and those are fitted with α and base held; the best point starts the bounded "
            "Levenberg–Marquardt over all parameters (α ∈ [0, 1], base ∈ [¼, 4] voxels, c_i ≥ 0, |log B| ≤ "
            "5) whose "
            "Jacobian columns for α and base come from Dr.Jit forward-mode autodiff through the kernel (each "
            "sample's position P + base·2^(i−1)·(N + αU) moves continuously; its mip level stays i − 1, so "
            "the "
            "residuals have kinks on trilinear cell faces). Standard errors: s²(JᵀJ)⁺ at the optimum, "
            "s² = SSR/dof (the `rtfit.fitting` convention); k = c_1, w_i = c_i/c_1 and B by the delta "
            "method. "
            f"Fits use at most {FIT_POINTS} pixels per scene. Pixel residuals are spatially correlated and "
            "dominated by "
            "model error, so the stderrs measure how sharply the data pin a parameter, not a sampling error. "
            "Table: per case α, base (voxels), k (1/scene unit), B with stderrs; RMS residual of the grid's "
            "best "
            "point → the continuous fit; LM iterations; parameters on a bound (their stderr is unreliable).",
        },
        {
            "id": "sweep",
            "title": "Steps vs error vs cost",
            "placement": "after_results",
            "text": "Evans' estimator as pure occlusion (α = 0, w = 1) with k and B refitted per "
            "configuration over "
            "samples n, grid resolution, with and without the Gaussian prefilter (without: plain 2×2×2 "
            "averages), "
            "and with the seed's 8-bit storage (one voxel per code). Error: mean RMSE over the sweep scenes "
            "against "
            "the AO reference; cost: the Dr.Jit kernel per pixel on this run's device. The `sweep` key of "
            "results.json holds the table.",
        },
        {
            "id": "failures",
            "title": "Where it fails",
            "placement": "after_results",
            "text": "Error maps per scene. Expected failure modes, visible there: thin occluders (thinner "
            "than a voxel of "
            "the mip level a sample reads: the blurred SDF never reaches 0, so the room's walls and the "
            "character's "
            "limbs occlude too little), occluders behind the normal direction (the samples march only along "
            "N'; a "
            "wall beside a point at grazing angles is never sampled), and distant large occluders (beyond "
            "Σ d_i = base·(2^n − 1): the room's ceiling and the sky hidden by the window wall, which Evans "
            "cannot see).",
        },
    ]


def _with_sweep_table(secs, sweep) -> list[dict]:
    lines = ["grid  n  prefilter  bits   RMSE     floor    ns/pixel"]
    for r in sweep:
        lines.append(
            f"{r['grid']:>4}  {r['n']}  {'yes' if r['prefilter'] else 'no ':9}  {r['bits']:>4}   "
            f"{r['rmse']:.4f}   {r['noise_floor']:.4f}   {r['ns_per_pixel']:.3g}"
            + ("   <- seed (n = 4, 128³, 8 bit)" if r["seed_default"] else "")
        )
    for sec in secs:
        if sec["id"] == "sweep":
            sec["text"] += "\n\n```\n" + "\n".join(lines) + "\n```"
    return secs


def _pm(v, e, fmt="{:.3g}"):
    """'value ± stderr' ('–' for an undefined value or stderr)."""
    if not _finite(v):
        return "–"
    return fmt.format(v) + (f" ± {e:.2g}" if _finite(e) else " ± –")


def _with_fit_table(secs, rows, joint, sds, cfg) -> list[dict]:
    """Append the per-case continuous-fit table (α, base, k, B with stderrs; RMS grid → continuous) to the
    ``fit`` section."""
    lines = [
        "case                      α               base (voxels)    k (1/unit)        B               "
        "RMS grid → LM       iters"
    ]
    for r in rows + [{"case": f"joint-{t}", **_lm_summary(b)} for t, b in joint.items()]:
        lines.append(
            f"{r['case']:<25} {_pm(r['alpha'], r['alpha_stderr']):<15} "
            f"{_pm(r['base_voxels'], r['base_voxels_stderr']):<16} {_pm(r['k'], r['k_stderr']):<17} "
            f"{_pm(r['B'], r['B_stderr']):<15} {r['rms_residual_grid']:.4f} → {r['rms_residual']:.4f}   "
            f"{r['lm_iterations']}{'' if r['converged'] else ' (not converged)'}"
            + (f"  at bound: {', '.join(r['at_bound'])}" if r["at_bound"] else "")
        )
    for sec in secs:
        if sec["id"] == "fit":
            sec["text"] += "\n\n```\n" + "\n".join(lines) + "\n```"
    return secs


def notes(cfg) -> list[str]:
    return [
        "Sign convention: s > 0 outside (the seed's listings, 000:3037-3040; Mitsuba's sdfgrid); the seed's "
        "text "
        "says positive inside (000:2891-2895). Its contrast k_text is −k here.",
        "The seed's text (000:2946) uses α = 0.5 and no weights; its Listing 1 (000:2982-2987) uses α = 1 "
        "and "
        "weights 1, 1.2, 1.4, 1.8 with no '+ d_i' term (a constant factor, fitted as B). Both are rows.",
        "The seed gives no value of k: every Evans row fits it.",
        "Images are dimensionless: AO ∈ [0, 1]; sky light as E/(πL) (constant sky) or E/E_h (sunsky, E_h the "
        "unoccluded horizontal irradiance), 1 for an unoccluded upward-facing point.",
        "Sunsky targets use Mitsuba's `sunsky` emitter with sun_scale 0 (the sun removed; its circumsolar "
        "sky "
        "stays), radiance 0 below the horizon, reduced to luminance Y = 0.2126 R + 0.7152 G + 0.0722 B. E_h "
        "comes "
        "from a quadrature of the sky baked by `rtfit.reference.environments.sunsky_environment`.",
        "Mitsuba 3.9's sdfgrid shape misses every hit on non-cubic grids (measured); all grids here are "
        "cubic.",
    ]


def summary(cfg, case_docs, joint, sweep, sds) -> str:
    def mean_rmse(method, target):
        v = [
            a["metrics"]["rmse"]["value"]
            for d in case_docs
            if d["parameters"]["target"] == target
            for a in d["approximations"]
            if a["method"] == method
        ]
        return float(np.mean(v)) if v else float("nan")

    t = "sky" if "sky" in cfg["targets"] else cfg["targets"][0]
    jp = evans_readable(joint[t], 1.0)
    best = min(sweep, key=lambda r: r["rmse"])

    def held_rmse(target):
        held = [d for d in case_docs if d["parameters"]["held_out"] and d["parameters"]["target"] == target]
        if not held:
            return None
        return {a["method"]: a["metrics"]["rmse"]["value"] for a in held[0]["approximations"]}

    held_txt = ""
    ap = held_rmse(t)
    if ap:
        held_txt = (
            f" On the held-out character the joint set gives RMSE {ap['evans-joint']:.3g} against "
            f"{ap['evans-fit']:.3g} for a per-scene fit."
        )
    sun_txt = ""
    if "sunsky" in cfg["targets"]:
        sp = evans_readable(joint["sunsky"], 1.0)
        hs = held_rmse("sunsky")
        sun_txt = (
            f" Under the sunsky sky without its sun ({cfg['sun_elevation']:g}° elevation; E/E_h, "
            f"approximations × the unoccluded sky factor g(N)): seed listing "
            f"{mean_rmse('evans-listing', 'sunsky'):.3g}, fitted per scene "
            f"{mean_rmse('evans-fit', 'sunsky'):.3g}, "
            f"joint {mean_rmse('evans-joint', 'sunsky'):.3g} (α = {_pm(sp['alpha'], sp['alpha_stderr'])}, "
            f"base = {_pm(sp['base_voxels'], sp['base_voxels_stderr'])} voxels)"
            + (f", held-out character {hs['evans-joint']:.3g} vs {hs['evans-fit']:.3g}" if hs else "")
            + "."
        )
    grid_err = [
        a["metrics"]["rmse"]["value"]
        for d in case_docs
        for a in d["approximations"]
        if a["method"] == "sdfgrid"
    ]
    return (
        f"Evans' 2006 SDF skylight against Mitsuba ray-cast sky light ({TARGET_LABEL[t]}), mean RMSE over "
        f"{len(cfg['scenes'])} scenes: seed text form {mean_rmse('evans-text', t):.3g}, seed listing "
        f"{mean_rmse('evans-listing', t):.3g}, fitted per scene (k, α, base, w_i, B continuous) "
        f"{mean_rmse('evans-fit', t):.3g}, one joint set "
        f"{mean_rmse('evans-joint', t):.3g} (k = {_pm(jp['k'], jp['k_stderr'])}/unit, "
        f"α = {_pm(jp['alpha'], jp['alpha_stderr'])}, base = "
        f"{_pm(jp['base_voxels'], jp['base_voxels_stderr'])} "
        f"voxels), cone-traced DF AO {mean_rmse('cone', t):.3g}, curvature term "
        f"{mean_rmse('curvature', t):.3g}.{held_txt}{sun_txt} Against AO within R = {cfg['ao_distance']:g}: "
        "Evans fitted "
        f"{mean_rmse('evans-fit', 'ao'):.3g}, cone {mean_rmse('cone', 'ao'):.3g}; the voxelisation alone "
        "(Mitsuba AO on the sdfgrid shape vs the mesh) costs "
        f"{np.mean(grid_err) if grid_err else float('nan'):.3g}. "
        f"Best swept configuration: {best['grid']}³, n = {best['n']} (RMSE {best['rmse']:.3g} at "
        f"{best['ns_per_pixel']:.3g} ns/pixel)."
    )


_EVANS_UNITS = {
    "k": "1/scene unit",
    "base_voxels": "voxel",
    "base": "scene unit",
    "alpha": "1",
    "B": "1",
    "w": "1",
}


def write_fitted(out, cfg, joint, per_case, sds, ctx=None, hashes=()) -> list[dict]:
    """fitted/evans_joint_<target>.json (the joint continuous fit: k, w_i, B, α, base in voxels and in each
    training scene's units, all with standard errors; the raw LM parameters and covariance) and
    fitted/per_case.json (every case's parameters of every row, the continuous fits with stderrs)."""
    docs = []
    prov = fitfiles.provenance(ctx, "sdf-occlusion", hashes, cfg.get("spp"))
    train = [n for n in cfg["scenes"] if n != HELD_OUT]
    for t, b in joint.items():
        readable = _json_params(evans_readable(b, None))
        fname = f"fitted/evans_joint_{t}.json"
        names = list(b["fit"]["parameters"])
        doc = {
            "model": "C = B * exp(-k * sum_i w_i (d_i - s_{i-1}(P + d_i (N + alpha U)))), d_i = base * "
            "2^(i-1)"
            + ("; prediction g(N) * C, g = sunsky factor E_sky(N)/E_u(N)" if t in SUNSKY_TARGETS else ""),
            "target": t,
            "trained_on": train,
            "held_out": HELD_OUT,
            "units": {
                "k": "1/scene unit",
                "base_voxels": "voxels of the finest grid (each scene's own)",
                "base": "scene units",
                "alpha": "dimensionless",
                "B": "dimensionless",
                "w_i": "dimensionless (w_1 = 1)",
            },
            "parameters": readable,
            "base_scene_units": {
                n: {
                    "value": b["base_vox"] * sds[n].voxel,
                    "stderr": (
                        readable["base_voxels_stderr"] * sds[n].voxel
                        if readable["base_voxels_stderr"] is not None
                        else None
                    ),
                    "voxel": sds[n].voxel,
                }
                for n in train
            },
            "grid_cells": cfg["grid"],
            "n": cfg["n_samples"],
            "method": "grid profile (LM of log B, c_i at each (alpha, base) point) as initialisation, "
            "then "
            "bounded Levenberg-Marquardt over (log B, c_i, alpha, base_voxels) with the alpha/base "
            "Jacobian "
            "columns from Dr.Jit forward-mode autodiff; stderr = sqrt(diag(s^2 (J^T J)^+)), s^2 = "
            "SSR/dof",
            "grid_init": {"alphas": cfg["alphas"], "bases_voxels": cfg["bases_vox"], **b["grid"]},
            "lm_fit": b["fit"],
            "lm": b["lm"],
            "covariance": {
                "names": names,
                "matrix": [[_json_params({"v": v})["v"] for v in row] for row in b["cov"]],
            },
        }
        entry = fitfiles.FittedMethod(
            id=f"evans-joint-{t}",
            label=f"Evans joint fit ({TARGET_LABEL[t]})",
            formula=doc["model"],
            source="Evans 2006, Fast approximations for global illumination on dynamic scenes (SIGGRAPH)",
            quantity=t,
            parameters={
                name: fitfiles.Parameter(
                    value=float(v),
                    stderr=readable.get(f"{name}_stderr"),
                    unit=_EVANS_UNITS.get(name.split("_")[0] if name.startswith("w") else name, "1"),
                )
                for name, v in readable.items()
                if not name.endswith("_stderr") and v is not None
            },
            residual=fitfiles.Residual(
                rms=b["fit"]["rms_residual"],
                n=b["fit"]["n_residuals"],
                dof=b["fit"].get("dof"),
                units="occlusion / sky visibility (dimensionless)",
            ),
            converged=b["fit"]["converged"],
            shader=None,
            shader_note=(
                "no shader text: the estimator samples the SDF grid at each step (gather on a 3D table); "
                "a shader needs the volume texture binding — the parameters above are its constants"
            ),
            data={k: v for k, v in doc.items() if k not in ("model", "parameters")},
        )
        docs.append(
            fitfiles.write_fit(
                out,
                fname,
                title=f"SDF occlusion: Evans multi-scale estimator, joint fit ({TARGET_LABEL[t]})",
                provenance=prov,
                entry=entry,
                doc_id=f"evans-joint-{t}",
                label=f"Evans joint fit ({TARGET_LABEL[t]})",
                model="C = exp(log B − Σ c_i D_i(α, base)), c_i = k·w_i; all fitted together (LM, "
                "Dr.Jit autodiff for α and base)",
                fit=b["fit"],
            )
        )
    fitfiles.write_fitted(
        out / "fitted/per_case.json",
        fitfiles.FittedFile(
            format=fitfiles.FORMAT,
            title="SDF occlusion: every case's parameters of every row (continuous fits with stderrs)",
            provenance=prov,
            methods=[],
            data={
                "units": {
                    "k": "1/scene unit",
                    "base": "scene units",
                    "base_voxels": "voxels",
                    "alpha": "dimensionless",
                },
                "note": "evans-fit / evans-analytic / evans-joint: continuous fits with standard errors "
                "(*_stderr; None: "
                "undetermined); *-lm: the fit's RMS residual before (grid) and after the continuous LM",
                "cases": per_case,
            },
        ),
    )
    return docs


# ================================================================================================ bench
def _dr_float():
    """The Dr.Jit Float of the default backend (the kernels' timing type)."""
    return (dr.cuda if get_default_backend() == "cuda" else dr.llvm).Float


def _columns(sd, idx, Float) -> tuple:
    """(px, py, pz, nx, ny, nz) of the points ``idx`` of scene data ``sd`` as Dr.Jit ``Float`` arrays."""
    return tuple(
        Float(np.ascontiguousarray(a[idx, i], dtype=np.float32))
        for a in (sd.points, sd.normals)
        for i in range(3)
    )


def measure_costs(sds, cfg) -> list[dict]:
    """ns per pixel of each row's Dr.Jit kernel (`Row.timed`) on ``cost_points`` surface points of one
    scene (the boxes scene if present), after warm-up (`rtfit.experiments.cost.time_drjit`); rows that run
    another row's kernel (`Row.cost_of`) share its timing."""
    sd = sds.get("boxes") or next(iter(sds.values()))
    size = int(cfg["cost_points"])
    be = get_default_backend()
    cols = _columns(sd, np.random.default_rng(0).integers(0, len(sd.points), size), _dr_float())
    out = []
    for row in ROWS:
        if row.timed is None:
            continue
        tm = time_drjit(row.timed(sd, cfg), cols, size, repeats=5, min_seconds=0.1)
        note = (
            f"Dr.Jit kernel incl. trilinear gathers from the mip chain, {size} surface points "
            f"({cfg['grid']}³ grid), median wall time after warm-up"
        )
        out.append(cost_row(row.id, row.title(METHODS), be, tm, note))
    measured = {c["method"]: c for c in out}
    shared = [row for row in ROWS if row.cost_of is not None]
    return out + [
        {
            **measured[row.cost_of],
            "method": row.id,
            "label": row.title(METHODS),
            "note": f"same kernel as {row.cost_of}",
        }
        for row in shared
    ]


def ao_stock_dict(mi, scene) -> dict:
    """The stock Mitsuba way to render ambient occlusion (R = ∞) of ``scene``: its shapes with a white
    diffuse BSDF (reflectance 1), no lights but a constant environment of radiance 1, and the ``direct``
    integrator with one emitter sample and no BSDF sample, so a pixel's value is
    (1/π)∫ V(ω) max(n·ω, 0) dω — the AO of rtfit's ray-cast reference at the first hit. Used by `bench`
    as the equivalent a user would otherwise run."""
    d = mitsuba_scene_dict(mi, scene)
    out = {k: v for k, v in d.items() if not k.startswith("light")}
    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 1.0}}
    for k, v in out.items():
        if isinstance(v, dict) and "bsdf" in v:
            out[k] = {**{kk: vv for kk, vv in v.items() if kk != "emitter"}, "bsdf": white}
    out["integrator"] = {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}
    out["ao_sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}
    return out


def bench(ctx) -> list[dict]:
    """Pixels/s of Evans (the ``evans-text`` row at its defaults: n = 4, k = 10) and the cone-traced row
    (their cost-row kernels, `Row.timed`) beside the Mitsuba AO estimator's samples/s, in the same run."""
    variant = ctx.variant
    be = backend_of(variant)
    cfg = configure(ctx.quick, None)
    res = 64 if ctx.quick else 256
    grid_res = 64 if ctx.quick else 128
    sc = load_case_scene("boxes", res)
    mi, mi_scene = load_mitsuba_scene(sc, variant)
    gb = gbuffer(mi, mi_scene)
    pts, nrm = gbuffer_points(gb)
    g = grid_of(sc, grid_res)
    scene = types.SimpleNamespace(points=pts, normals=nrm, sdf=GridSDF.from_grid(g, levels=8), voxel=g.voxel)
    size = ctx.size or (1 << 18 if ctx.quick else 1 << 22)
    cols = _columns(scene, np.random.default_rng(0).integers(0, len(pts), size), _dr_float())
    kernels = (
        (f"Evans n={EVANS_SAMPLES}, {grid_res}³ grid", _evans_timed(METHODS["evans-text"], {})),
        (
            f"cone-traced DF AO ({cfg['cone_count']} cones × {cfg['cone_steps']} steps), {grid_res}³",
            _cone_timed,
        ),
    )
    rows = []
    for what, timed in kernels:
        t = time_drjit(timed(scene, cfg), cols, size)
        rows.append(
            {
                "what": what,
                "backend": be,
                "elements": size,
                "Mpx_s": t.elements_per_second / 1e6,
                "ns_per_px": t.ns_per_element,
                "Msamples_s": None,
            }
        )
    spp = 64 if ctx.quick else 256
    occlusion_pass(mi, mi_scene, pts[:1024], nrm[:1024], 4, 0, quantity="ao", max_distance=1.0)  # warm-up
    r = occlusion_pass(mi, mi_scene, pts, nrm, spp, 1, quantity="ao", max_distance=1.0)
    rows.append(
        {
            "what": f"Mitsuba ray-cast AO reference ({spp} spp)",
            "backend": be,
            "elements": len(pts),
            "Mpx_s": len(pts) / r.seconds / 1e6,
            "ns_per_px": r.seconds / len(pts) * 1e9,
            "Msamples_s": len(pts) * spp / r.seconds / 1e6,
        }
    )
    for r_res, r_spp in reference_sizes(ctx.quick, (res, spp), (res, spp)):  # + the pixel-bound size
        r_sc, r_mi_scene, r_pts, r_nrm = sc, mi_scene, pts, nrm
        if r_res != res:
            r_sc = load_case_scene("boxes", r_res)
            _, r_mi_scene = load_mitsuba_scene(r_sc, variant)
            r_gb = gbuffer(mi, r_mi_scene)
            r_pts, r_nrm = gbuffer_points(r_gb)
        stock = load_dict(mi, ao_stock_dict(mi, r_sc))

        # the points on the device once per reference, as the occlusion cache does
        probes = device_probes(mi, r_pts, r_nrm, normalise=True)

        def run_ao(seed, s=r_mi_scene, probes=probes, k=r_spp):
            return occlusion_pass(mi, s, probes, None, k, seed, quantity="ao")

        rows += reference_vs_stock_rows(
            f"rtfit AO reference, R = ∞ (1 shadow ray per sample, {len(r_pts)} G-buffer points on the "
            f"device, {r_spp} spp)",
            run_ao,
            len(r_pts) * r_spp,
            [
                Stock(
                    "mi.render, direct: white diffuse under a constant sky of 1 = AO (R = ∞; camera + "
                    f"shadow ray per sample; {r_res}², {r_spp} spp)",
                    stock_render(mi, stock, r_spp),
                    r_res * r_res * r_spp,
                )
            ],
            variant,
            rounds=3 if ctx.quick else 5,
        )
    return rows
