"""Experiment ``soft-particles``: the seed's soft particles (a particle's opacity faded where opaque geometry
cuts its volume) against the exact Beer–Lambert opacity of the particle's volume clipped by the scene.

What is compared, and why (docs/soft-particles.md):

1. **The claim** of issue 18: the linear fade under-estimates dense particles (α = 0.95, half the chord:
   0.475 against 1 − √0.05 = 0.776), from the exact box kernel on the view axis and the closed form.
2. **Reference check**: Mitsuba ``volpathmis`` through a homogeneous, purely absorbing sphere / box cut by
   an opaque tilted emitting plane (`rtfit.reference.soft_particles`): each pixel-centre ray's estimate is
   Bernoulli(T), checked against the analytic clipped chord (``exact-sphere`` / ``exact-box``) by z-scores
   with the known binomial noise. The approximations are then scored against Mitsuba's opacity 1 − T.
   The references are cached passes (`particle_reference`): a rerun resumes from them.
3. **The methods over their domain** (no rendering): random particles within 25° of the view axis, random
   pixels on their billboards and random scene depths Δ/r ∈ [−1.3, 1.3]; errors per method, shape and
   particle opacity α_c; the fade's (s) and the fitted fade's (s, b, p) fitted per shape and α_c through the
   JAX run of their kernels (`rtfit.fitting.fit_method`).
4. **Extremes**: camera inside the particle, s → 0, Δ ≤ 0, huge σ, and view-z vs ray length off-axis.
5. **A 100-particle scene** straddling a ground plane and a box: composited opacity 1 − Π(1 − α'_i) per
   pixel against the exact 1 − exp(−Σ σ_i ℓ_i), with error maps.

Sections: configure · geometry (rays, billboard inputs) · jobs · run · domain study and fits · extremes ·
100-particle scene · checks · figures · summary · bench.
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.fitting import compute_metrics, fit_method, sidak_threshold
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.arrays import backend_float, xyz_columns
from rtfit.realtime.soft_particles import (
    BIG,
    METHODS,
    billboard_alpha,
    box_chord,
    linear_underestimate,
    sphere_chord,
)
from rtfit.reference.soft_particles import (
    bernoulli_stderr,
    particle_reference,
    transmittance_pass_particle,
)

from . import figures as F
from . import fitted as fitfiles
from .cost import attach_costs, bench_backend, cost_backend, method_bench_rows, method_cost_rows, rate_row
from .jobs import Job, reference_args
from .particle_geometry import billboard_inputs
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .report import markdown_table

# ============================================================================================ configure
CONFIG = {
    "shapes": ConfigKey(
        "str", "particle shapes of the rendered cases", choices=("sphere", "box"), shape=(None,)
    ),
    "alphas": ConfigKey("float", "particle opacities α_c of the rendered cases", 0.01, 0.999, (None,)),
    "fit_alphas": ConfigKey(
        "float", "particle opacities α_c of the domain study and fits", 0.01, 0.999, (None,)
    ),
    "camera_inside": ConfigKey("bool", "also render a sphere case with the camera inside it (last α_c)"),
    "tilt_deg": ConfigKey("float", "tilt of the opaque plane from facing the camera (degrees)", 0.0, 80.0),
    "resolution": ConfigKey("int", "image (W, H) pixels of the rendered cases", 4, 4096, (2,)),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "reference samples per pixel of one cached pass", 2, SPP_MAX),
    "domain_samples": ConfigKey("int", "random pixels per (shape, α_c) of the domain study", 100, 1 << 22),
    "scene_particles": ConfigKey("int", "particles of the composited scene", 1, 10000),
    "scene_resolution": ConfigKey("int", "image (W, H) of the composited scene", 4, 4096, (2,)),
    "cost_elements": ConfigKey("int", "elements per timed launch", 1024, 1 << 26),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    total = spp or (1024 if quick else 16384)
    return checked(
        CONFIG,
        {
            "shapes": ["sphere", "box"],
            "alphas": [0.95] if quick else [0.5, 0.95],
            "fit_alphas": [0.5, 0.95] if quick else [0.3, 0.5, 0.7, 0.9, 0.95],
            "camera_inside": True,
            "tilt_deg": 35.0,
            "resolution": [20, 20] if quick else [64, 64],
            "spp": total,
            "pass_spp": min(total, 256 if quick else 4096),  # a pass never holds more than asked for
            "domain_samples": 4000 if quick else 100000,
            "scene_particles": 100,
            "scene_resolution": [64, 40] if quick else [256, 160],
            "cost_elements": 1 << (20 if quick else 22),
        },
    )


# ============================================================================================= geometry
FOV_DEG = 40.0
RADIUS = 1.0
CENTRE = (0.3, 0.2, 4.0)
"""The rendered particle's centre (m, view space) and radius."""
CENTRE_INSIDE = (0.1, 0.0, 0.6)
"""The centre of the camera-inside case: the camera sits 0.6 r behind the centre, inside the sphere."""


def centre_of(inside: bool):
    return CENTRE_INSIDE if inside else CENTRE


def sigma_of(alpha_c: float, radius: float) -> float:
    """σ with 1 − exp(−2σr) = α_c: the particle's α is the opacity of its chord through the centre."""
    return -math.log1p(-alpha_c) / (2.0 * radius)


def pixel_dirs(resolution, fov_deg: float = FOV_DEG) -> np.ndarray:
    """Unit pixel-centre view rays (H, W, 3) of a pinhole camera at the origin looking along +z (y up)."""
    w, h = int(resolution[0]), int(resolution[1])
    t = math.tan(math.radians(fov_deg) / 2.0)
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * t * w / h
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * t
    x, y = np.meshgrid(xs, ys)
    d = np.stack([x, y, np.ones_like(x)], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def plane_distance(dirs: np.ndarray, point, normal) -> np.ndarray:
    """Ray distance t to the plane (point, normal) along each unit ray from the origin; `BIG` if none."""
    dn = dirs @ np.asarray(normal, np.float64)
    pn = float(np.dot(point, normal))
    ok = np.abs(dn) > 1e-12
    t = np.where(ok, pn / np.where(ok, dn, 1.0), -1.0)
    return np.where(t > 0.0, t, BIG)


def tilted_plane(tilt_deg: float, centre=CENTRE, offset: float = 0.15):
    """A plane through the particle (its point ``offset``·r behind the centre), its normal tilted by
    ``tilt_deg`` about x from facing the camera: the clip depth varies across the particle."""
    a = math.radians(tilt_deg)
    normal = np.array([0.0, math.sin(a), -math.cos(a)])
    point = np.asarray(centre, np.float64) + np.array([0.0, 0.0, offset * RADIUS])
    return point, normal


def ray_inputs(dirs: np.ndarray, centre, radius: float, sigma: float, t_surface) -> dict:
    """Per-pixel inputs of the exact kernels."""
    n = len(dirs)
    c = np.asarray(centre, np.float64)
    return {
        **xyz_columns("d", dirs),
        "cx": np.full(n, c[0]),
        "cy": np.full(n, c[1]),
        "cz": np.full(n, c[2]),
        "t_surface": np.asarray(t_surface, np.float64),
        "radius": np.full(n, radius),
        "sigma": np.full(n, sigma),
    }


def evaluate32(method: str, inputs: dict, params: dict | None = None) -> np.ndarray:
    """A method's kernel text on float32 Dr.Jit (the shader's precision), returned as float64."""
    m = METHODS[method]
    x = {k: np.asarray(inputs[k], np.float32) for k in m.input_names}
    return np.asarray(m.evaluate(x, params), np.float64)


def exact64(shape: str, inputs: dict) -> np.ndarray:
    """The exact opacity in float64 (NumPy run of the kernel text)."""
    m = METHODS[f"exact-{shape}"]
    return np.asarray(m(NUMPY_OPS, inputs), np.float64)


# ================================================================================================= jobs
def render_job(
    shape: str,
    alpha_c: float,
    tilt_deg: float,
    resolution,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    inside: bool = False,
    progress: bool = False,
) -> dict:
    """Job: Mitsuba's transmittance of one particle case at pixel centres, from the pass cache
    (`particle_reference`: passes loaded where cached, the rest rendered): pooled mean and variance per
    pixel, total samples, passes (rendered by this job / in all), rendering seconds and the cache key."""
    dirs = pixel_dirs(resolution).reshape(-1, 3)
    centre = centre_of(inside)
    point, normal = tilted_plane(tilt_deg, centre)
    ref = particle_reference(
        cache_dir,
        shape,
        centre,
        RADIUS,
        sigma_of(alpha_c, RADIUS),
        point,
        normal,
        dirs,
        spp=spp,
        pass_spp=pass_spp,
        seed=seed,
        variant=variant,
        camera_inside=inside,
        progress=progress,
        label=f"soft-particles {case_id(shape, alpha_c, inside)}",
    )
    return {
        "mean": ref.mean,
        "var": ref.var,
        "spp": ref.spp,
        "passes": ref.passes,
        "passes_rendered": ref.passes_rendered,
        "seconds": ref.seconds,
        "cache_key": ref.key,
    }


def bench_job(shape: str, alpha_c: float, tilt_deg: float, resolution, spp: int, seed: int, variant: str):
    """One uncached pass of a particle case (for `bench`: a timing must render, not read the cache)."""
    dirs = pixel_dirs(resolution).reshape(-1, 3)
    point, normal = tilted_plane(tilt_deg, CENTRE)
    return transmittance_pass_particle(
        shape, CENTRE, RADIUS, sigma_of(alpha_c, RADIUS), point, normal, dirs, spp, seed, variant
    )


def case_id(shape: str, alpha_c: float, inside: bool = False) -> str:
    return f"{shape}-a{alpha_c:g}" + ("-inside" if inside else "")


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    cases = [(s, a, False) for s in cfg["shapes"] for a in cfg["alphas"]]
    if cfg["camera_inside"]:
        cases.append(("sphere", cfg["alphas"][-1], True))
    jobs = [
        Job(
            render_job,
            dict(
                shape=s,
                alpha_c=a,
                tilt_deg=cfg["tilt_deg"],
                resolution=list(cfg["resolution"]),
                **reference_args(ctx, cfg),
                inside=i,
                progress=ctx.progress,
            ),
            label=case_id(s, a, i),
        )
        for s, a, i in cases
    ]
    ctx.log(f"rendering {len(jobs)} references")
    rendered = dict(zip(cases, ctx.executor.map(jobs, desc="references"), strict=True))
    n_pass = sum(r["passes"] for r in rendered.values())
    n_new = sum(r["passes_rendered"] for r in rendered.values())
    ctx.log(f"references: resumed {n_pass - n_new} of {n_pass} passes from the cache")
    ctx.log("domain study and fits")
    study = domain_study(cfg)
    checks = claim_checks() + chord_checks() + finite_checks()
    case_docs, images = [], {}
    for (shape, alpha_c, inside), ref in rendered.items():
        doc, imgs, cks = reference_case(cfg, shape, alpha_c, ref, study["fits"], inside)
        case_docs.append(doc)
        images[doc["id"]] = imgs
        checks += cks
    extremes = extreme_values()
    checks += extreme_checks(extremes)
    scene = particle_scene(cfg, study["fits"])
    case_docs.append(scene["doc"])
    checks += study["checks"] + scene["checks"]
    costs = cost_rows(ctx, cfg)
    attach_costs(case_docs, costs, key=lambda ap: ap["method"].removesuffix("-fit"))
    fits = write_fitted(ctx, study)
    figs = make_figures(ctx.out_dir, cfg, case_docs, images, study, scene)
    return {
        "summary": summary(study, scene, extremes, checks),
        "config": cfg,
        "sections": sections(study, extremes, scene),
        "cases": case_docs,
        "fits": fits,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "domain_study": study["table"],
        "extremes": extremes,
        "notes": NOTES,
    }


# ------------------------------------------------------------------------------------ rendered cases
def _grey(img: np.ndarray) -> np.ndarray:
    return np.repeat(img[..., None], 3, axis=-1)


def row_params(method: str, shape: str, alpha_c: float, fits: dict) -> tuple[str, dict, bool]:
    """(kernel id, parameters, fitted) of a report row: ``linear`` at its default s = 1, ``linear-fit`` and
    ``fitted`` with the parameters fitted for the nearest α_c of the study on this shape."""
    if method in ("linear-fit", "fitted"):
        key = min((k for k in fits if k[0] == shape and k[1] == method), key=lambda k: abs(k[2] - alpha_c))
        par = {n: v["value"] for n, v in fits[key]["parameters"].items()}
        return ("linear" if method == "linear-fit" else "fitted"), par, True
    return method, {}, False


ROWS = ("linear", "linear-fit", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray", "fitted")
"""The report's rows: every approximation, and the seed's fade with its s fitted."""


RAY_EPSILON = 1500.0 * 2.0**-24
"""Mitsuba's ``math::RayEpsilon<float>``: a ray leaving a surface point p starts (1 + max|p|)·ε off it."""


def spawn_offset_band(
    dirs: np.ndarray, centre, radius: float = RADIUS, tolerance: float = 0.01
) -> np.ndarray:
    """Pixels whose ray passes so close to the sphere's silhouette that Mitsuba's spawn offset changes the
    chord by more than ``tolerance`` (relative): at the grazing entry and exit the ray restarts
    δ = (1 + max|p|)·`RAY_EPSILON` off the surface along its normal, nearly across the ray, which moves the
    impact parameter b by ~δ, and ℓ = 2√(r² − b²) by |Δℓ/ℓ| ≈ b·δ/(r² − b²). Measured (session 6, full
    run, 16384 spp, CPU and H200 alike): at b = 0.99964 r Mitsuba's T was 0.9054 against the exact 0.9226
    (z = −8.3), a chord 23 % long; at b = 0.9990 and 0.9989, z = −4.6 and −4.2. These pixels (67 of 1601 in
    the full run) are left out of the exact z-tests (then max |z| 3.06, spread 1.00); the rows are still
    scored against Mitsuba on them."""
    c = np.asarray(centre, dtype=np.float64)
    b = np.linalg.norm(np.cross(dirs, c), axis=-1)
    delta = (1.0 + float(np.max(np.abs(c))) + radius) * RAY_EPSILON
    gap = radius * radius - b * b
    return (gap > 0.0) & (b * delta > tolerance * gap)


def reference_case(cfg, shape: str, alpha_c: float, ref: dict, fits: dict, inside: bool = False):
    """One rendered case: Mitsuba against the analytic chord (z-scores), and each row against Mitsuba."""
    w, h = cfg["resolution"]
    dirs = pixel_dirs(cfg["resolution"]).reshape(-1, 3)
    centre = centre_of(inside)
    point, normal = tilted_plane(cfg["tilt_deg"], centre)
    ts = plane_distance(dirs, point, normal)
    sigma = sigma_of(alpha_c, RADIUS)
    exact = exact64(shape, ray_inputs(dirs, centre, RADIUS, sigma, ts))
    t_exact = 1.0 - exact
    spp = int(ref["spp"])  # pooled over the passes: ceil(spp / pass_spp) · pass_spp samples
    se = bernoulli_stderr(t_exact, spp)
    covered = se > 0.0
    band = spawn_offset_band(dirs, centre) if shape == "sphere" else np.zeros(len(dirs), bool)
    tested = covered & ~band  # (the band's pixels stay in every error table; `spawn_offset_band` says why)
    z = (ref["mean"][tested] - t_exact[tested]) / se[tested]
    sample_se = np.sqrt(ref["var"] / spp)
    bern_gap = bernoulli_variance_gap(ref["mean"], ref["var"], spp)
    cid = case_id(shape, alpha_c, inside)
    sidak = sidak_threshold(max(z.size, 1))
    checks = [
        Check(
            name=f"reference {cid}: Mitsuba T = exp(−σℓ) of the analytic clipped chord, z-score spread "
            f"({z.size} pixels, {int(np.sum(covered & band))} at the silhouette left out; binomial noise "
            "√(T(1 − T)/spp))",
            value=float(np.std(z)),
            expected="1 ± 0.2",
            passed=bool(abs(np.std(z) - 1.0) <= 0.2),
        ),
        Check(
            name=f"reference {cid}: pooled z-score of (Mitsuba − analytic)",
            value=float(np.sum(z) / math.sqrt(z.size)),
            expected="|z| ≤ 4",
            passed=bool(abs(np.sum(z) / math.sqrt(z.size)) <= 4.0),
        ),
        Check(
            name=f"reference {cid}: largest |z|",
            value=float(np.max(np.abs(z))),
            expected=f"≤ {sidak:.2f} (Šidák, 1 % family-wise)",
            passed=bool(np.max(np.abs(z)) <= sidak),
        ),
        Check(
            name=f"reference {cid}: rays that miss the particle see T = 1 exactly",
            value=float(np.max(np.abs(ref["mean"][~covered] - t_exact[~covered]), initial=0.0)),
            expected="0",
            passed=bool(np.all(ref["mean"][~covered] == t_exact[~covered])),
        ),
        Check(
            name=f"reference {cid}: the pooled sample variance of the {ref['passes']} passes is the "
            "Bernoulli variance N/(N − 1)·T̂(1 − T̂) of the pooled mean (largest gap)",
            value=bern_gap,
            expected=f"≤ {BERNOULLI_VARIANCE_TOL:g}",
            passed=bool(bern_gap <= BERNOULLI_VARIANCE_TOL),
        ),
    ]
    bb = billboard_inputs(dirs, centre, RADIUS, alpha_c, shape, ts)
    ref_op = (1.0 - ref["mean"]).reshape(h, w)
    ref_se = np.sqrt(np.maximum(sample_se**2, se**2)).reshape(h, w)
    mask = ((bb["alpha"] > 0.0) | (exact > 0.0)).reshape(h, w)
    docs, imgs = [], {"reference": ref_op, "exact": exact.reshape(h, w)}
    for row in ROWS:
        kernel, par, fitted = row_params(row, shape, alpha_c, fits)
        img = evaluate32(kernel, bb, par).reshape(h, w)
        imgs[row] = img
        metrics = compute_metrics(_grey(img), _grey(ref_op), _grey(ref_se), mask)
        docs.append(
            {
                "method": row,
                "label": METHODS[kernel].label + (" (s fitted)" if row == "linear-fit" else ""),
                "fitted": fitted,
                "parameters": {k: float(v) for k, v in par.items()},
                "metrics": metrics.to_dict(),
            }
        )
    exact_metrics = compute_metrics(_grey(imgs["exact"]), _grey(ref_op), _grey(ref_se), mask)
    docs.append(
        {
            "method": f"exact-{shape}",
            "label": METHODS[f"exact-{shape}"].label + " (analytic; at the noise floor)",
            "fitted": False,
            "parameters": {"sigma": sigma},
            "metrics": exact_metrics.to_dict(),
        }
    )
    rmse = exact_metrics["rmse"]
    checks.append(
        Check(
            name=f"reference {cid}: the analytic exact row sits at Mitsuba's noise floor (RMSE)",
            value=rmse.value,
            expected=f"not resolved above the noise floor {rmse.noise_floor:.3g}",
            passed=not rmse.resolved,
        )
    )
    doc = {
        "id": cid,
        "label": f"{shape}, α_c = {alpha_c:g}, opaque plane tilted {cfg['tilt_deg']:g}° through it"
        + (", camera inside" if inside else ""),
        "parameters": {
            "alpha_c": alpha_c,
            "sigma_per_m": sigma,
            "radius_m": RADIUS,
            "centre_m": list(centre),
            "camera_inside": inside,
            "tilt_deg": cfg["tilt_deg"],
            "pixels": int(mask.size),
            "particle_pixels": int(mask.sum()),
            "reference_seconds": float(ref["seconds"]),
            "reference_passes_rendered": int(ref["passes_rendered"]),
        },
        "scene": None,
        "reference": {
            "quantity": "particle_opacity",
            "integrator": "volpathmis (albedo 0: Bernoulli transmittance) at pixel centres",
            "max_depth": 2,
            "spp": spp,
            "passes": int(ref["passes"]),
            "cache_key": ref["cache_key"],
            "samples_per_second": float(mask.size * spp / max(ref["seconds"], 1e-9)),
        },
        "approximations": docs,
    }
    return doc, imgs, checks


# ------------------------------------------------------------------------------ domain study and fits
BERNOULLI_VARIANCE_TOL = 1e-6
"""Bound on |pooled variance − N/(N − 1)·T̂(1 − T̂)| (the variance itself is ≤ 0.25): each sample is 0 or 1
up to float32 rounding of the volpathmis weight (the transmittance over its free-flight probability, 1 within
a few ulp); measured maximum 1.1e-7 (quick run, 4 passes of 256 and 1 pass of 1024 samples)."""


def bernoulli_variance_gap(mean: np.ndarray, var: np.ndarray, n: int) -> float:
    """Largest |S² − N/(N − 1)·M(1 − M)| over pixels, S² the pooled unbiased sample variance of N samples of
    pooled mean M. Zero (to rounding) iff every sample is 0 or 1: then Σv² = Σv and the unbiased variance of
    each pass, and the exact pooling of them (`rtfit.reference.cache.pool_passes`), is that expression, so the
    known binomial noise √(T(1 − T)/N) the z-tests use and the pooled standard error agree."""
    m = np.asarray(mean, np.float64)
    return float(np.max(np.abs(np.asarray(var, np.float64) - n / (n - 1) * m * (1.0 - m)), initial=0.0))


def random_domain(shape: str, alpha_c: float, n: int, seed: int = 11) -> tuple[dict, dict]:
    """Random pixels of random particles (r = 1 m): centres at view distance 2–30 r within 25° of the view
    axis, pixels uniform on the billboard's disc (sphere) or square (box), scene depths Δ/r ∈ U(−1.3, 1.3)
    (the depth buffer: a surface of constant view depth behind the pixel). Returns (billboard inputs,
    exact inputs)."""
    rng = np.random.default_rng(seed)
    dist = rng.uniform(2.0, 30.0, n)
    theta = np.radians(25.0) * np.sqrt(rng.uniform(0.0, 1.0, n))
    phi = rng.uniform(0.0, 2 * math.pi, n)
    axis = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    c = axis * dist[:, None]
    if shape == "sphere":
        rad = np.sqrt(rng.uniform(0.0, 1.0, n))
        ang = rng.uniform(0.0, 2 * math.pi, n)
        u, v = rad * np.cos(ang), rad * np.sin(ang)
    else:
        u, v = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    p = c + np.stack([u, v, np.zeros(n)], -1) * RADIUS
    dirs = p / np.linalg.norm(p, axis=-1, keepdims=True)
    delta = rng.uniform(-1.3, 1.3, n) * RADIUS
    ts = (c[:, 2] + delta) / dirs[:, 2]
    bb = _per_sample_billboard(dirs, c, alpha_c, shape, ts)
    ex = {
        **xyz_columns("d", dirs),
        **xyz_columns("c", c),
        "t_surface": ts,
        "radius": np.full(n, RADIUS),
        "sigma": np.full(n, sigma_of(alpha_c, RADIUS)),
    }
    return bb, ex


def _per_sample_billboard(dirs, centres, alpha_c, shape, ts) -> dict:
    """`billboard_inputs` with one particle centre per ray (vectorised over both)."""
    z = centres[:, 2]
    dz = np.maximum(dirs[:, 2], 1e-12)
    px, py = dirs[:, 0] * z / dz - centres[:, 0], dirs[:, 1] * z / dz - centres[:, 1]
    q = np.hypot(px, py)
    n = len(dirs)
    if shape == "sphere":
        alpha = np.asarray(billboard_alpha(np.full(n, alpha_c), np.full(n, RADIUS), q), np.float64)
    else:
        alpha = np.where(np.maximum(np.abs(px), np.abs(py)) <= RADIUS * (1 + 1e-9), alpha_c, 0.0)
    return {
        "alpha": alpha,
        "alpha_c": np.full(n, alpha_c),
        "z": z,
        "delta": ts * dirs[:, 2] - z,
        "radius": np.full(n, RADIUS),
        "q": q,
        "cos_view": dirs[:, 2].copy(),
    }


FIT_MAX_STEPS = 400


def domain_study(cfg) -> dict:
    """Errors of every row per (shape, α_c) over `random_domain`, with the fits of ``linear`` (s) and
    ``fitted`` (s, b, p) to the exact opacity (unweighted least squares on the opacity)."""
    table, fits, checks, profiles = [], {}, [], {}
    bins = np.linspace(-1.3, 1.3, 14)
    for shape in cfg["shapes"]:
        for alpha_c in cfg["fit_alphas"]:
            bb, ex = random_domain(shape, alpha_c, cfg["domain_samples"])
            exact = exact64(shape, ex)
            for fid, kernel in (("linear-fit", "linear"), ("fitted", "fitted")):
                m = METHODS[kernel]
                res = fit_method(
                    m, {k: bb[k] for k in m.input_names}, exact, max_steps=FIT_MAX_STEPS
                ).to_dict()
                fits[(shape, fid, alpha_c)] = res
            prof = {"delta_over_r": [float(x) for x in 0.5 * (bins[1:] + bins[:-1])]}
            idx = np.digitize(bb["delta"] / RADIUS, bins) - 1
            for row in ROWS:
                kernel, par, _ = row_params(row, shape, alpha_c, fits)
                val = evaluate32(kernel, bb, par)
                err = val - exact
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
    for (shape, fid, alpha_c), res in fits.items():
        checks.append(
            Check(
                name=f"fit {fid} ({shape}, α_c = {alpha_c:g}) converged",
                value=str(res["converged"]),
                expected="True",
                passed=bool(res["converged"]),
            )
        )
    for shape in cfg["shapes"]:
        for alpha_c in cfg["fit_alphas"]:
            by = {t["method"]: t for t in table if t["shape"] == shape and t["alpha_c"] == alpha_c}
            checks.append(
                Check(
                    name=f"domain {shape}, α_c = {alpha_c:g}: the fitted fade's RMS error ≤ the fitted "
                    "linear fade's (it contains it: b = 0, p = 1)",
                    value=by["fitted"]["rms_error"],
                    expected=f"≤ {by['linear-fit']['rms_error']:.4g}",
                    passed=bool(by["fitted"]["rms_error"] <= by["linear-fit"]["rms_error"] * (1 + 1e-6)),
                )
            )
    return {"table": table, "fits": fits, "checks": checks, "profiles": profiles}


# ============================================================================================== checks
def claim_checks() -> list[Check]:
    """Issue 18's claim from the kernels: a box of α = 0.95 cut through its centre on the view axis."""
    alpha = 0.95
    bb = {"alpha": 0.95, "z": 4.0, "delta": 0.0, "radius": 1.0}
    linear = float(METHODS["box"].evaluate(bb))
    ex = {"dx": 0.0, "dy": 0.0, "dz": 1.0, "cx": 0.0, "cy": 0.0, "cz": 4.0, "t_surface": 4.0, "radius": 1.0}
    exact = float(METHODS["exact-box"].evaluate({**ex, "sigma": sigma_of(alpha, 1.0)}))
    closed = 1.0 - math.sqrt(1.0 - alpha)
    gap, f_star = linear_underestimate(alpha)
    f = np.linspace(0.0, 1.0, 1001)
    concave_ok = bool(np.all(1.0 - (1.0 - alpha) ** f >= alpha * f - 1e-15))
    return [
        Check(
            name="claim (issue 18): linear fade at α = 0.95, half the chord = 0.475",
            value=linear,
            expected="0.475 ± 1e-12",
            passed=bool(abs(linear - 0.475) <= 1e-12),
        ),
        Check(
            name="claim (issue 18): exact Beer–Lambert opacity of half the chord = 1 − √0.05 = 0.7764 "
            "(exact-box kernel on the view axis)",
            value=exact,
            expected=f"{closed:.6f} ± 1e-12",
            passed=bool(abs(exact - closed) <= 1e-12),
        ),
        Check(
            name="claim: 1 − (1 − α)^f ≥ α·f on f ∈ [0, 1] (concavity; the largest gap "
            f"{gap:.3f} at f = {f_star:.3f} for α = 0.95)",
            value=str(concave_ok),
            expected="True",
            passed=concave_ok,
        ),
    ]


def chord_checks(n: int = 400, steps: int = 20000) -> list[Check]:
    """The analytic chords against an independent count: the ray t ∈ [0, t_s] sampled at ``steps``
    midpoints, each tested for being inside the sphere / box (the count's error ≤ 2 steps)."""
    rng = np.random.default_rng(5)
    out = []
    for shape in ("sphere", "box"):
        c = np.stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-0.5, 6.0, n)], -1)
        d = np.stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.4, 0.4, n), np.ones(n)], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        ts = rng.uniform(0.5, 9.0, n)
        chord_fn = sphere_chord if shape == "sphere" else box_chord
        analytic = np.asarray(chord_fn((d[:, 0], d[:, 1], d[:, 2]), (c[:, 0], c[:, 1], c[:, 2]), ts, RADIUS))
        dt = ts / steps
        counted = np.zeros(n)
        for k0 in range(0, steps, 2000):
            t = (np.arange(k0, min(steps, k0 + 2000)) + 0.5)[None, :] * dt[:, None]
            x = t[..., None] * d[:, None, :] - c[:, None, :]
            inside = np.sum(x * x, -1) <= RADIUS**2 if shape == "sphere" else np.max(np.abs(x), -1) <= RADIUS
            counted += inside.sum(-1) * dt
        err = np.max(np.abs(analytic - counted) / (2.0 * dt))
        out.append(
            Check(
                name=f"{shape} chord: analytic clipped chord = midpoint count along the ray ({n} random "
                f"rays, {steps} steps), in units of the step's 2-step bound",
                value=float(err),
                expected="≤ 1",
                passed=bool(err <= 1.0),
            )
        )
    return out


def finite_checks(n: int = 20000) -> list[Check]:
    """Every method in float32 over its inputs' whole declared domains (log-spread magnitudes, signs,
    zeros) and parameters at their bounds: no NaN or Inf, opacity in [0, 1]."""
    rng = np.random.default_rng(9)
    out = []
    for mid, m in METHODS.items():
        x = {}
        for inp in m.inputs:
            lo, hi = inp.domain or (0.0, 1.0)
            u = rng.uniform(lo, hi, n)
            if hi > 10.0:  # magnitudes spread over decades, zeros included
                mag = 10.0 ** rng.uniform(-6.0, math.log10(hi), n)
                u = np.where(rng.uniform(size=n) < 0.5, mag, u)
                u[: n // 50] = 0.0
            x[inp.name] = np.clip(u, lo, hi)
        worst_bad, lo_v, hi_v = 0, 1.0, 0.0
        for par in [m.defaults()] + [
            {k: (p.lower if j == 0 else min(p.upper, 1e3)) for k, p in m.params.items()} for j in range(2)
        ]:
            v = evaluate32(mid, x, par)
            worst_bad += int(np.sum(~np.isfinite(v)))
            fin = v[np.isfinite(v)]
            lo_v, hi_v = min(lo_v, float(fin.min())), max(hi_v, float(fin.max()))
        out.append(
            Check(
                name=f"{mid}: float32 over the whole input domain and parameter bounds: non-finite values "
                f"(opacity range [{lo_v:.3g}, {hi_v:.3g}])",
                value=worst_bad,
                expected="0, opacity in [0, 1]",
                passed=bool(worst_bad == 0 and lo_v >= 0.0 and hi_v <= 1.0),
            )
        )
    return out


# ============================================================================================ extremes
def _axis_case(z: float, delta: float, alpha_c: float, theta_deg: float = 0.0, shape: str = "box") -> dict:
    """One pixel: a particle of radius 1 on the ray at angle θ from the view axis, its centre at view depth
    z, the ray through its centre, the depth buffer Δ behind the centre. Values of every row."""
    th = math.radians(theta_deg)
    d = np.array([[math.sin(th), 0.0, math.cos(th)]])
    c = d[0] * z / math.cos(th)
    ts = np.array([(z + delta) / math.cos(th)])
    bb = billboard_inputs(d, c, RADIUS, alpha_c, shape, ts)
    ex = ray_inputs(d, c, RADIUS, sigma_of(alpha_c, RADIUS), ts)
    row = {"exact": float(exact64(shape, ex)[0])}
    for m in ("linear", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray"):
        row[m] = float(evaluate32(m, bb)[0])
    return row


def extreme_values() -> dict:
    """The extremes' table (module docstring item 4)."""
    a = 0.95
    inside = {f"z = {z:g} r": _axis_case(z, 5.0, a, shape="sphere") for z in (0.75, 0.5, 0.25, 0.05)}
    behind = {f"Δ = {dl:g} r": _axis_case(4.0, dl, a, shape="sphere") for dl in (-2.0, -0.9, -0.5, 0.0, 0.5)}
    s_small = {}
    for s in (1.0, 1e-3, 1e-6, 1e-12, 0.0):
        vals = [
            float(METHODS["linear"].evaluate({"alpha": 0.95, "delta": dl, "radius": 1.0}, {"s": s}))
            for dl in (-1e-3, 0.0, 1e-9, 1e-3)
        ]
        s_small[f"s = {s:g} r"] = vals
    off = {}
    for th in (0.0, 10.0, 20.0, 30.0, 40.0):
        row = _axis_case(10.0, 0.0, a, th, shape="box")
        tau = {k: -math.log1p(-min(v, 1 - 1e-15)) for k, v in row.items()}
        off[f"{th:g}°"] = {
            **row,
            "tau_ratio_box_beer": tau["box-beer"] / tau["exact"],
            "cos": math.cos(math.radians(th)),
        }
    huge = {}
    for sigma in (1e3, 1e10, 1e30, 1e38):
        ex = ray_inputs(np.array([[0.0, 0.0, 1.0]]), (0, 0, 4), 1.0, sigma, np.array([4.0]))
        huge[f"σ = {sigma:g} /m"] = float(evaluate32("exact-sphere", ex)[0])
    ex0 = ray_inputs(np.array([[0.0, 0.0, 1.0]]), (0, 0, 4), 1.0, 1e38, np.array([3.0]))
    huge["σ = 1e38 /m, ℓ = 0"] = float(evaluate32("exact-sphere", ex0)[0])
    return {
        "camera_inside": inside,
        "delta": behind,
        "s_to_zero": s_small,
        "off_axis": off,
        "huge_sigma": huge,
    }


def extreme_checks(ext: dict) -> list[Check]:
    out = []
    ins = ext["camera_inside"]
    ok = all(abs(v["spherical"] - v["exact"]) <= 1e-6 for v in ins.values())
    out.append(
        Check(
            name="camera inside the sphere (view axis): the spherical billboard clips at the camera "
            "plane and equals the exact opacity",
            value=max(abs(v["spherical"] - v["exact"]) for v in ins.values()),
            expected="≤ 1e-6",
            passed=bool(ok),
        )
    )
    lin_err = max(v["linear"] - v["exact"] for v in ins.values())
    out.append(
        Check(
            name="camera inside the sphere: the linear fade ignores the camera plane and over-estimates",
            value=lin_err,
            expected="> 0",
            passed=bool(lin_err > 0),
        )
    )
    s0 = ext["s_to_zero"]
    step_ok = all(v[0] == 0.0 and v[1] == 0.0 for v in s0.values()) and s0["s = 0 r"][2] == 0.95
    out.append(
        Check(
            name="s → 0: the linear fade becomes a hard step at Δ = 0 (0 at Δ ≤ 0, α above), never NaN",
            value=str(step_ok),
            expected="True",
            passed=bool(step_ok),
        )
    )
    behind = ext["delta"]
    fade_zero = all(behind[k]["linear"] == 0.0 for k in behind if not k.startswith("Δ = 0.5"))
    chord_zero = behind["Δ = -2 r"]["exact"] == 0.0 and behind["Δ = -2 r"]["spherical"] == 0.0
    out.append(
        Check(
            name="Δ ≤ 0: the linear fade is 0; the chords are 0 once the surface is in front of it",
            value=str(fade_zero and chord_zero),
            expected="True",
            passed=bool(fade_zero and chord_zero),
        )
    )
    ray_err = max(abs(v["box-beer-ray"] - v["exact"]) for v in ext["off_axis"].values())
    out.append(
        Check(
            name="off-axis: box-beer-ray (view-z travel over cos θ) equals the exact opacity",
            value=ray_err,
            expected="≤ 1e-6",
            passed=bool(ray_err <= 1e-6),
        )
    )
    ratios = [abs(v["tau_ratio_box_beer"] - v["cos"]) for v in ext["off_axis"].values()]
    out.append(
        Check(
            name="off-axis (box, ray through the centre, surface at the centre's depth): the view-z "
            "methods' optical depth is the exact one times cos θ",
            value=max(ratios),
            expected="≤ 1e-5",
            passed=bool(max(ratios) <= 1e-5),
        )
    )
    hv = list(ext["huge_sigma"].values())
    out.append(
        Check(
            name="huge σ: opacity 1 where the chord is positive, 0 where it is 0 (no 0·∞)",
            value=str(hv),
            expected="[1, 1, 1, 1, 0]",
            passed=bool(hv[:-1] == [1.0] * (len(hv) - 1) and hv[-1] == 0.0),
        )
    )
    return out


# ================================================================================ 100-particle scene
GROUND_Y = -1.5
SCENE_BOX = ((1.5, -0.5, 11.0), 1.0)
"""The composited scene's opaque ground plane y = −1.5 m and box (centre, half-size) in view space."""


def scene_surface(dirs: np.ndarray) -> np.ndarray:
    """Ray distance to the first opaque surface (ground plane, box); `BIG` for the sky."""
    t_ground = np.where(dirs[:, 1] < -1e-9, GROUND_Y / np.minimum(dirs[:, 1], -1e-9), BIG)
    (cx, cy, cz), h = SCENE_BOX
    lo = np.full(len(dirs), -np.inf)
    hi = np.full(len(dirs), np.inf)
    for k, c in enumerate((cx, cy, cz)):
        dk = dirs[:, k]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (c - h) / dk, (c + h) / dk
        par = np.abs(dk) < 1e-12
        lo = np.maximum(lo, np.where(par, np.where(abs(c) <= h, -np.inf, np.inf), np.minimum(t1, t2)))
        hi = np.minimum(hi, np.where(par, np.where(abs(c) <= h, np.inf, -np.inf), np.maximum(t1, t2)))
    t_box = np.where((hi >= lo) & (lo > 0), lo, BIG)
    return np.minimum(t_ground, t_box)


def scene_particles(n: int, seed: int = 21) -> dict:
    """``n`` spherical particles near the geometry: centres x ∈ [−7, 7], y ∈ [−2.3, −0.3], z ∈ [6, 20] m,
    radii 0.3–1 m, opacities α_c 0.2–0.9 (many straddle the ground or the box; sparse enough that the
    composite is not saturated everywhere)."""
    rng = np.random.default_rng(seed)
    return {
        "centre": np.stack([rng.uniform(-7, 7, n), rng.uniform(-2.3, -0.3, n), rng.uniform(6, 20, n)], -1),
        "radius": rng.uniform(0.3, 1.0, n),
        "alpha_c": rng.uniform(0.2, 0.9, n),
    }


def particle_scene(cfg, fits: dict) -> dict:
    """Composited opacity 1 − Π(1 − α'_i) of every row against the exact 1 − Π(1 − α_exact,i) =
    1 − exp(−Σσ_iℓ_i) (optical depths add: exact for overlapping homogeneous particles)."""
    w, h = cfg["scene_resolution"]
    dirs = pixel_dirs(cfg["scene_resolution"], 50.0).reshape(-1, 3)
    ts = scene_surface(dirs)
    parts = scene_particles(cfg["scene_particles"])
    log_t = {row: np.zeros(len(dirs)) for row in ("exact", *ROWS)}
    straddle, silhouette, silhouette_max = 0, 0, 0.0
    for c, r, a in zip(parts["centre"], parts["radius"], parts["alpha_c"], strict=True):
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
            kernel, par, _ = row_params(row, "sphere", float(a), fits)
            op = evaluate32(kernel, bb, par)
            log_t[row] += np.log1p(-np.minimum(op, 1 - 1e-16))
    exact = (1.0 - np.exp(log_t["exact"])).reshape(h, w)
    images = {row: (1.0 - np.exp(log_t[row])).reshape(h, w) for row in ROWS}
    mask = exact > 1e-6
    docs, finite = [], True
    for row in ROWS:
        err = images[row] - exact
        finite &= bool(np.all(np.isfinite(images[row])))
        kernel, par, fitted = row_params(row, "sphere", 0.95, fits)
        docs.append(
            {
                "method": row,
                "label": METHODS[kernel].label + (" (s fitted)" if row == "linear-fit" else ""),
                "fitted": fitted,
                "parameters": {},
                "metrics": {
                    "rmse": {"value": float(np.sqrt(np.mean(err[mask] ** 2)))},
                    "mae": {"value": float(np.mean(np.abs(err[mask])))},
                    "max_abs": {"value": float(np.max(np.abs(err[mask])))},
                    "mean_error": {"value": float(np.mean(err[mask]))},
                },
            }
        )
    doc = {
        "id": "scene-100",
        "label": f"{cfg['scene_particles']} spherical particles straddling a ground plane and a box "
        "(composited opacity; exact: 1 − exp(−Σσℓ))",
        "parameters": {
            "particles": cfg["scene_particles"],
            "particles_cut_by_geometry": straddle,
            "pixels": int(mask.size),
            "covered_pixels": int(mask.sum()),
            "silhouette_pairs": silhouette,
            "silhouette_max_opacity": silhouette_max,
        },
        "scene": None,
        "reference": None,
        "approximations": docs,
    }
    checks = [
        Check(
            name="100-particle scene: composited opacity of every row finite",
            value=str(finite),
            expected="True",
            passed=finite,
        ),
        Check(
            name="100-particle scene: at least a fifth of the particles are cut by the geometry",
            value=straddle,
            expected=f"≥ {cfg['scene_particles'] // 5}",
            passed=bool(straddle >= cfg["scene_particles"] // 5),
        ),
    ]
    return {"doc": doc, "exact": exact, "images": images, "mask": mask, "checks": checks}


# ============================================================================================ fitted
FIT_RESIDUAL_UNITS = "opacity (model − exact clipped Beer–Lambert), unweighted"


def write_fitted(ctx, study) -> list[dict]:
    """fitted/soft-particles.json: every fit (``rtfit.fitted/1``); returns the results' ``fits`` records."""
    entries, docs = [], []
    for (shape, fid, alpha_c), fit in study["fits"].items():
        kernel = "linear" if fid == "linear-fit" else "fitted"
        case = f"{shape}_a{alpha_c:g}".replace(".", "_")
        entries.append(
            fitfiles.method_entry(
                METHODS[kernel],
                fit,
                id=fid.replace("-", "_"),
                label=f"{METHODS[kernel].label}, {shape}, α_c = {alpha_c:g}",
                case=case,
                domain={
                    "delta": (-1.3, 1.3, "m"),
                    "radius": (RADIUS, RADIUS, "m"),
                    "alpha": (0.0, alpha_c, "1"),
                },
                residual_units=FIT_RESIDUAL_UNITS,
            )
        )
        docs.append(
            fitfiles.fit_record(
                f"{fid}-{shape}-a{alpha_c:g}",
                f"{METHODS[kernel].label}, {shape}, α_c = {alpha_c:g}",
                METHODS[kernel].formula,
                fit,
                "fitted/soft-particles.json",
            )
        )
    fitfiles.write_fitted(
        ctx.out_dir / "fitted/soft-particles.json",
        fitfiles.FittedFile(
            format=fitfiles.FORMAT,
            title="soft particles: fade parameters fitted to the exact clipped Beer–Lambert opacity",
            provenance=fitfiles.provenance(ctx, "soft-particles", [], None),
            methods=entries,
        ),
    )
    return docs


# ============================================================================================ figures
def make_figures(out, cfg, case_docs, images, study, scene) -> list[dict]:
    figs = []
    fdir = out / "figures"
    for cid, imgs in images.items():
        ref = _grey(imgs["reference"])
        mask = (imgs["exact"] > 0) | (imgs["linear"] > 0)
        path = F.image_comparison(
            fdir / f"{cid}.png",
            ref,
            [(row, _grey(imgs[row])) for row in ROWS],
            mask,
            error_scale=1.0,
            title=f"{cid}: Mitsuba opacity 1 − T and the rows",
            exposure=1.0,
        )
        figs.append(
            {
                "file": f"figures/{path.name}",
                "caption": f"{cid}: the particle's opacity (Mitsuba, pixel centres) and each row; signed "
                "error in opacity units.",
                "section": "results",
            }
        )
    path = F.image_comparison(
        fdir / "scene-100.png",
        _grey(scene["exact"]),
        [(row, _grey(scene["images"][row])) for row in ROWS],
        scene["mask"],
        error_scale=1.0,
        title="100 particles straddling a ground plane and a box: composited opacity",
        exposure=1.0,
    )
    figs.append(
        {
            "file": f"figures/{path.name}",
            "caption": "The 100-particle scene: exact composited opacity 1 − exp(−Σσℓ) and each row's "
            "1 − Π(1 − α'); the error maps (opacity units) show where each fade fails: linear fades lose "
            "the dense particles' cores near contact, the view-z methods the slanted rays at the edges.",
            "section": "results",
        }
    )
    series, panels = [], []
    for (shape, alpha_c), prof in study["profiles"].items():
        panel = f"{shape}, α_c = {alpha_c:g}"
        panels.append(panel)
        for row in ROWS:
            series.append(
                {"x": prof["delta_over_r"], "y": prof[row], "label": row, "style": "line", "panel": panel}
            )
    p = F.line_plot(
        fdir / "error_vs_delta.png", "Δ/r (scene depth − particle depth)", "mean error", series, panels=panels
    )
    figs.append(
        {
            "file": f"figures/{p.name}",
            "caption": "Mean signed opacity error against the exact clipped Beer–Lambert opacity per bin of "
            "Δ/r over the domain study, per shape and α_c.",
            "section": "results",
        }
    )
    return figs


# ============================================================================================ summary
NOTES = [
    "View space: camera at the origin looking along +z; the billboard sits at the particle centre's depth.",
    "Mitsuba reference: volpathmis, albedo-0 homogeneous medium inside a null-BSDF sphere/cube, opaque "
    "emitting rectangle (radiance 1) and constant environment 1: the pixel value is the transmittance.",
    "The rendered cases' rows run in float32 Dr.Jit; the exact kernels in float64 NumPy (same text).",
    "The box's texture α is α_c on its square; the sphere's is the opacity of its view-axis chord.",
]


def sections(study, extremes, scene) -> list[dict]:
    head = ["shape", "α_c", "method", "mean error", "mean |error|", "RMS", "max |error|"]
    keys = "shape alpha_c method mean_error mean_abs_error rms_error max_abs_error".split()
    fmts = ("", "g", "", "+.4f", ".4f", ".4f", ".3f")
    domain = markdown_table(
        head, [[f"{t[k]:{f}}" for k, f in zip(keys, fmts, strict=True)] for t in study["table"]]
    )
    fit_rows = ["| fit | shape | α_c | parameters | RMS residual |", "|---|---|---|---|---|"]
    for (shape, fid, alpha_c), f in study["fits"].items():
        par = ", ".join(f"{k} = {v['value']:.4g}" for k, v in f["parameters"].items())
        fit_rows.append(f"| {fid} | {shape} | {alpha_c:g} | {par} | {f['rms_residual']:.4g} |")
    cols = ("linear", "box", "box-beer", "box-beer-ray", "spherical", "spherical-ray")
    ext = ["| case | exact | " + " | ".join(cols) + " |", "|---|---" + "|---" * len(cols) + "|"]
    for group in ("camera_inside", "delta", "off_axis"):
        for k, v in extremes[group].items():
            ext.append(
                f"| {group}: {k} | {v['exact']:.4f} | " + " | ".join(f"{v[c]:.4f}" for c in cols) + " |"
            )
    m_fmt = (("rmse", ".4f"), ("mae", ".4f"), ("max_abs", ".3f"), ("mean_error", "+.4f"))
    sc_rows = [
        [ap["method"], *(f"{ap['metrics'][k]['value']:{f}}" for k, f in m_fmt)]
        for ap in scene["doc"]["approximations"]
    ]
    sc = markdown_table(["row", "RMS", "mean |error|", "max |error|", "mean error"], sc_rows)
    return [
        {
            "id": "method",
            "title": "Method",
            "text": (
                "A soft particle fades its opacity where opaque geometry cuts its volume (000:2302-2318, "
                "002:325-347). Ground truth: a homogeneous particle of extinction σ (α_c = 1 − e^(−2σr) "
                "through its centre) has opacity 1 − exp(−σℓ), ℓ the ray's chord through the volume in "
                "front of the opaque surface (analytic chords: `rtfit.realtime.soft_particles`; checked "
                "against Mitsuba volpathmis renders by z-tests). The linear fade scales α by a fraction of "
                "the chord, but Beer–Lambert is concave in the chord: 1 − (1 − α)^f ≥ α·f, so every linear "
                "fade under-estimates a dense particle (α = 0.95, half the chord: 0.475 against 0.776)."
            ),
        },
        {"id": "domain", "title": "Errors over the domain", "text": domain},
        {"id": "fits", "title": "Fitted fade parameters", "text": "\n".join(fit_rows)},
        {
            "id": "extremes",
            "title": "Extremes",
            "placement": "after_results",
            "text": (
                "Sphere of α_c = 0.95, r = 1 (camera inside: centre at z < r; Δ: centre at z = 4 r) and a "
                "box off-axis (ray at θ through its centre, surface at the centre's depth: the view-z "
                "methods' optical depth is cos θ of the ray's):\n\n" + "\n".join(ext)
            ),
        },
        {
            "id": "scene",
            "title": "100 particles straddling geometry",
            "placement": "after_results",
            "text": "Composited opacity error per covered pixel:\n\n"
            + sc
            + f"\n\n{scene['doc']['parameters']['silhouette_pairs']} (pixel, particle) pairs lie inside a "
            "sphere's perspective silhouette but outside its view-plane billboard of radius r (α = 0): "
            "every billboard method misses them, exact opacity up to "
            f"{scene['doc']['parameters']['silhouette_max_opacity']:.2f} (particles far off-axis; the "
            "largest errors of every row).",
        },
    ]


def summary(study, scene, extremes, checks) -> str:
    def rms(method, alpha):
        vals = [
            t["rms_error"]
            for t in study["table"]
            if t["method"] == method and t["alpha_c"] == alpha and t["shape"] == shape
        ]
        return float(np.mean(vals)) if vals else float("nan")

    shape = "sphere" if any(t["shape"] == "sphere" for t in study["table"]) else "box"

    alphas = sorted({t["alpha_c"] for t in study["table"]})
    hi = alphas[-1]
    sc = {ap["method"]: ap["metrics"]["rmse"]["value"] for ap in scene["doc"]["approximations"]}
    passed = sum(c["passed"] for c in checks)
    off = extremes["off_axis"]["40°"]
    return (
        "Soft particles against the exact Beer–Lambert opacity of the particle's volume clipped by the "
        "scene. "
        "The issue's claim holds: a linear fade of α = 0.95 over half the chord gives 0.475 where the exact "
        "opacity is 1 − √0.05 = 0.776 (Beer–Lambert is concave in the chord, so every linear fade "
        f"under-estimates). Over random {shape} particles and depths (α_c = {hi:g}) the RMS opacity error is "
        f"{rms('linear', hi):.3f} for the seed's fade (s = r), {rms('linear-fit', hi):.3f} with s fitted, "
        f"{rms('box', hi):.3f} for the 2007 box, {rms('box-beer', hi):.3f} for the box through Beer–Lambert, "
        f"{rms('spherical', hi):.3f} for spherical billboards and {rms('fitted', hi):.3f} for the fitted "
        f"fade α·saturate(Δ/s + b)^p. Off-axis the view-z methods lose optical depth by cos θ (40°: exact "
        f"{off['exact']:.3f}, box-beer {off['box-beer']:.3f}); dividing the view-z length by cos θ of the "
        f"pixel's ray (box-beer-ray, spherical-ray) restores it. In the 100-particle scene the composited "
        f"opacity's RMS error is {sc['linear']:.3f} (linear), {sc['box']:.3f} (box), {sc['spherical']:.3f} "
        f"(spherical), {sc['spherical-ray']:.3f} (spherical-ray), {sc['fitted']:.3f} (fitted); its largest "
        "errors are the spheres' perspective silhouettes beyond their view-plane billboards. "
        f"{passed} of {len(checks)} checks passed."
    )


# ================================================================================================ bench
COST_INPUTS = ("alpha", "alpha_c", "z", "delta", "radius", "q", "cos_view")


def _cost_inputs(n: int, Float):
    bb, ex = random_domain("sphere", 0.9, n, seed=3)
    np_inputs = {k: v.astype(np.float32) for k, v in {**bb, **ex}.items()}
    return np_inputs, {k: Float(v) for k, v in np_inputs.items()}


def cost_rows(ctx, cfg) -> list[dict]:
    """ns per pixel of each method (the results' ``costs``) beside the memory-traffic floor."""
    backend, Float = cost_backend(ctx.variant)
    n = cfg["cost_elements"]
    _, inputs = _cost_inputs(n, Float)

    def note(m) -> str:
        return f"per pixel: {len(m.inputs)} floats in, opacity out (float32)"

    floor_inputs = tuple(inputs[k] for k in COST_INPUTS)
    floor = "the memory-bound floor of the billboard methods"
    return method_cost_rows(METHODS, backend, inputs, n, note, floor, floor_inputs=floor_inputs)


def bench(ctx) -> list[dict]:
    """Pixels/s of each method on Dr.Jit vs the same kernel text on NumPy, then the reference's samples/s."""
    backend, n = bench_backend(ctx)
    Float = backend_float(backend)
    np_inputs, inputs = _cost_inputs(n, Float)
    floor = tuple(inputs[k] for k in COST_INPUTS)
    base = "memory baseline (fma of the 7 billboard inputs)"
    rows = method_bench_rows(METHODS, backend, inputs, np_inputs, n, floor_inputs=floor, baseline=base)
    res = (32, 32) if ctx.quick else (128, 128)
    spp = 256 if ctx.quick else 1024
    bench_job("sphere", 0.95, 35.0, list(res), spp, 1, ctx.variant)  # warm-up: kernel compile
    out = min(
        (bench_job("sphere", 0.95, 35.0, list(res), spp, k + 2, ctx.variant) for k in range(2)),
        key=lambda o: o.seconds,
    )
    samples = res[0] * res[1] * spp
    what = f"reference: volpathmis, absorbing sphere cut by a plane ({res[0]}×{res[1]}, {spp} spp)"
    rows.append(rate_row(what, ctx.variant, samples, out.seconds))
    return rows
