"""Experiment ``ambient-aperture``: spherical-cap intersection (exact, smoothstep, linear, fitted) and the
ambient-aperture shading of area-light occlusion against Mitsuba.

Part 1 — function level. The intersection solid angle Ω(r1, r2, d) of two caps over a dense grid of
(r1, r2, d) ∈ (0, π)³. Ground truth: the exact closed form (`rtfit.realtime.aperture`), itself checked on
the whole grid against an independent numerical integral (Gauss–Legendre in the polar angle of the smaller
cap of the azimuthal arc inside the other cap, split at the kinks) and at a few points against mpmath.
Errors are fractions of the smaller cap, max and RMS, over the partial-overlap points of two domains:
"hemisphere caps" (r1, r2 ≤ π/2, where the seed's smoothstep is used and its known figures, 0.16 max and
0.05 RMS, live) and the "full domain". The fitted form's six coefficients are fitted with optimistix on the
full-domain grid.

Part 2 — the Lambert factor. The cosine-weighted intersection ∫_{cap_a ∩ cap_l} max(n·ω, 0) dω over random
(aperture, light) configurations, by quadrature over the light's cap, against Ω·max(n·c, 0) with the seed's
centroid (plain average of the two directions) and the fitted cap-size-weighted centroid (exponent k fitted).

Part 3 — scenes (`scenes/library/aperture_*.toml`): a white receiver under a plate with a circular hole, the
floor of a cylindrical well, and a bumpy height field. At a grid of receiver points (irradiance probes, laid
out as an image) Mitsuba gives the direct irradiance from (a) the scene's sphere light and (b) a constant
sky of radiance 1 instead. The bent normal and aperture are baked with Mitsuba ray casts (uniform hemisphere
visibility, `rtfit.reference.visibility`). Compared with the reference:

* ``cap-model``: the exact irradiance *if visibility were the baked cap*, ∫_{cap_a ∩ cap_l} L max(n·ω, 0) dω
  by quadrature (for the sky: the closed-form projected solid angle of the cap). Its error is the cap
  model's own; every shading method below inherits it.
* ``aa-*``: the ambient-aperture shading L·Ω·max(n·c, 0) with each intersection form and Lambert factor;
  the seed's full method is ``aa-smoothstep-seed``; the recommended replacement ``aa-fitted-fitted``.
* ``fill-seed`` / ``fill-projected`` for the sky case (000:2774-2782).
* ``unshadowed``: the exact sphere-light irradiance ignoring all occluders (scale of the shadowing).

Irradiance is reported as a fraction of the unshadowed peak (light case: the largest unshadowed sphere-light
irradiance over the probes; sky case: π L_sky).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .jobs import Job

PI = math.pi
LIGHT_METHODS = (
    "cap-model",
    "aa-exact-seed",
    "aa-smoothstep-seed",
    "aa-linear-seed",
    "aa-fitted-seed",
    "aa-exact-fitted",
    "aa-fitted-fitted",
    "unshadowed",
)
SKY_METHODS = ("cap-model", "fill-seed", "fill-projected", "unoccluded")
LABELS = {
    "cap-model": "Cap model, exact integral",
    "aa-exact-seed": "AA: exact Ω, seed Lambert",
    "aa-smoothstep-seed": "AA: smoothstep Ω, seed Lambert (seed)",
    "aa-linear-seed": "AA: linear Ω, seed Lambert",
    "aa-fitted-seed": "AA: fitted Ω, seed Lambert",
    "aa-exact-fitted": "AA: exact Ω, fitted Lambert",
    "aa-fitted-fitted": "AA: fitted Ω, fitted Lambert",
    "unshadowed": "No occlusion (exact sphere light)",
    "fill-seed": "Seed fill: A(r_a)·cos(n,a)",
    "fill-projected": "Projected-cap fill",
    "unoccluded": "No occlusion (π L_sky)",
}
FORMS = ("exact", "smoothstep", "linear", "fitted")
FORM_LABELS = {
    "exact": "exact (closed form)",
    "smoothstep": "smoothstep (seed)",
    "linear": "linear ramp",
    "fitted": "fitted (complement + corrected smoothstep)",
}


def configure(quick: bool, spp: int | None) -> dict:
    return {
        "grid": 40 if quick else 96,  # (r1, r2, d) grid points per axis
        "fit_grid": 40 if quick else 72,
        "quad_nodes": 48 if quick else 96,  # Gauss–Legendre nodes per sub-interval (function check)
        "lambert_configs": 1500 if quick else 6000,
        "lambert_quad": [24, 96] if quick else [48, 192],
        "probe_n": 32 if quick else 64,  # probe image side
        "spp": spp or (1024 if quick else 8192),
        "sky_spp": 4 * spp if spp else (4096 if quick else 32768),  # the sky is seen through small apertures
        "pass_spp": 512 if quick else 4096,
        "bake_dirs": 4096 if quick else 16384,
        "cap_quad": [24, 96] if quick else [48, 192],
        "cost_elements": 1 << (20 if quick else 24),
        "scenes": ["aperture_hole", "aperture_well", "aperture_bumps"],
        # ꟻLIP costs ~0.15 s per call on a busy 2-core machine (5 calls per metric with its floor draws):
        # the quick run leaves it out to stay within its time budget.
        "metrics": ["rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim"] + ([] if quick else ["flip"]),
    }


# ----------------------------------------------------------------------------------------- function level
def grid_points(n: int):
    """Cell-centred (r1, r2, d) grid over (0, π)³, flattened."""
    g = (np.arange(n) + 0.5) / n * PI
    r1, r2, d = np.meshgrid(g, g, g, indexing="ij")
    return r1.ravel(), r2.ravel(), d.ravel()


def partial_mask(r1, r2, d):
    """Points where the caps partly overlap (neither nested, disjoint nor covering the sphere)."""
    return (d > np.abs(r1 - r2)) & (d < r1 + r2) & (r1 + r2 + d < 2 * PI)


def quadrature_intersection(r1, r2, d, nodes: int = 48, chunk: int = 20000):
    """Independent numerical Ω: ∫_0^{r_s} 2·acos(clip((cos r_b − cos θ cos d)/(sin θ sin d))) sin θ dθ over the
    smaller cap (radius r_s) in its polar angle θ, split at the kinks θ ∈ {|d − r_b|, d + r_b, 2π − d − r_b}
    and on each piece Gauss–Legendre after θ = a + (b − a)(1 − cos πs)/2 (which smooths the √ endpoint
    behaviour of acos at the kinks). float64, vectorised."""
    r1, r2, d = (np.asarray(x, dtype=np.float64).ravel() for x in (r1, r2, d))
    rs, rb = np.minimum(r1, r2), np.maximum(r1, r2)
    x, w = np.polynomial.legendre.leggauss(nodes)
    s = 0.5 * (x + 1.0)
    ws = 0.5 * w
    out = np.empty_like(rs)
    for a0 in range(0, len(rs), chunk):
        sl = slice(a0, a0 + chunk)
        rs_, rb_, d_ = rs[sl], rb[sl], np.maximum(d[sl], 1e-300)
        kinks = np.stack([np.zeros_like(rs_), np.abs(d_ - rb_), d_ + rb_, 2 * PI - d_ - rb_, rs_], axis=1)
        kinks = np.sort(np.clip(kinks, 0.0, rs_[:, None]), axis=1)
        total = np.zeros_like(rs_)
        for k in range(4):
            a, b = kinks[:, k : k + 1], kinks[:, k + 1 : k + 2]
            th = a + (b - a) * 0.5 * (1 - np.cos(PI * s))[None, :]
            jac = (b - a) * 0.5 * PI * np.sin(PI * s)[None, :]
            with np.errstate(divide="ignore", invalid="ignore"):
                kk = (np.cos(rb_)[:, None] - np.cos(th) * np.cos(d_)[:, None]) / (
                    np.sin(th) * np.sin(d_)[:, None]
                )
            kk = np.where(np.isfinite(kk), kk, 1.0)
            f = 2 * np.arccos(np.clip(kk, -1, 1)) * np.sin(th)
            total += np.sum(f * jac * ws[None, :], axis=1)
        out[sl] = total
    return out


def fitted_inputs(r1, r2, d):
    """The quantities of the fitted form that do not depend on its coefficients (NumPy float64)."""
    comp = (r1 + r2) > PI
    q1 = np.where(comp, PI - r1, r1)
    q2 = np.where(comp, PI - r2, r2)
    base = np.where(comp, np.maximum(4 * PI * (np.sin(r1 / 2) ** 2 + np.sin(r2 / 2) ** 2 - 1), 0.0), 0.0)
    qmin, qmax = np.minimum(q1, q2), np.maximum(q1, q2)
    a_q = 4 * PI * np.sin(qmin / 2) ** 2
    t = 1 - np.clip((d - (qmax - qmin)) / np.maximum(2 * qmin, 1e-300), 0, 1)
    rho = qmin / np.maximum(qmax, 1e-300)
    sigma = (qmin + qmax) / PI
    return base, a_q, t, rho, sigma


def _intersection_residual(p, args):
    """(Ω_fit − Ω_exact)/A_min over partial-overlap grid points (JAX; module level: compiled once)."""
    import jax.numpy as jnp

    base, a_q, t, rho, sigma, exact, a_min = args
    u = 1 - 2 * t
    corr = p["c0"] + p["c1"] * u + rho * (p["c2"] + p["c3"] * u) + sigma * (p["c4"] + p["c5"] * u)
    f = jnp.clip(t * t * (3 - 2 * t) + t * (1 - t) * corr, 0.0, 1.0)
    return (base + a_q * f - exact) / a_min


def fit_intersection_job(grid: int) -> dict:
    """Job: fit c0..c5 of the fitted intersection form on a grid³ of the full domain (optimistix)."""
    from rtfit.fitting import Param, fit_least_squares
    from rtfit.realtime import aperture as ap

    r1, r2, d = grid_points(grid)
    m = partial_mask(r1, r2, d)
    r1, r2, d = r1[m], r2[m], d[m]
    exact = ap.cap_intersection_solid_angle(r1, r2, d)
    a_min = 4 * PI * np.sin(np.minimum(r1, r2) / 2) ** 2
    args = (*fitted_inputs(r1, r2, d), exact, a_min)
    params = {f"c{i}": Param(0.0, -4.0, 4.0) for i in range(6)}
    res = fit_least_squares(_intersection_residual, params, args)
    out = res.to_dict()
    out["n_residuals"] = len(r1)
    out["grid"] = grid
    return out


# ----------------------------------------------------------------------------------------- Lambert level
def _frame(v):
    """Two unit tangents orthogonal to unit vectors v (N, 3) (Frisvad / Duff et al. 2017)."""
    sign = np.where(v[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + v[:, 2])
    b = v[:, 0] * v[:, 1] * a
    t1 = np.stack([1 + sign * v[:, 0] ** 2 * a, sign * b, -sign * v[:, 0]], axis=1)
    t2 = np.stack([b, sign + v[:, 1] ** 2 * a, -v[:, 1]], axis=1)
    return t1, t2


def _node_dots(vec, frame, mu, st, cp, sp):
    """vec·ω at the quadrature nodes ω = μ·axis + sin θ'(cos φ u1 + sin φ u2): (m, nt, nphi)."""
    axis, u1, u2 = frame
    return mu[:, :, None] * np.sum(vec * axis, 1)[:, None, None] + st[:, :, None] * (
        cp[None, None, :] * np.sum(vec * u1, 1)[:, None, None]
        + sp[None, None, :] * np.sum(vec * u2, 1)[:, None, None]
    )


def cap_model_irradiance(n, a, r_a, l, alpha, nodes=(24, 96), chunk: int = 512):
    """∫_{cap(l, α) ∩ cap(a, r_a)} max(n·ω, 0) dω per row (sr, i.e. irradiance per unit radiance): quadrature
    over the smaller of the two caps (Gauss–Legendre in cos θ' from its axis × midpoint rule in φ), the other
    cap entering as an indicator (first-order convergence at its boundary: the experiment quotes the change
    with doubled nodes)."""
    n, a, l = (np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in (n, a, l))
    r_a = np.asarray(r_a, dtype=np.float64).ravel()
    alpha = np.asarray(alpha, dtype=np.float64).ravel()
    swap = r_a < alpha  # integrate over the smaller cap
    l, a = np.where(swap[:, None], a, l), np.where(swap[:, None], l, a)
    alpha, r_a = np.where(swap, r_a, alpha), np.where(swap, alpha, r_a)
    nt, nphi = nodes
    x, w = np.polynomial.legendre.leggauss(nt)
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * PI
    t1, t2 = _frame(l)
    out = np.empty(len(l))
    for s in range(0, len(l), chunk):
        sl = slice(s, s + chunk)
        ca = np.cos(alpha[sl])[:, None]
        mu = ca + (1 - ca) * 0.5 * (x[None, :] + 1)  # (m, nt)
        wmu = (1 - ca) * 0.5 * w[None, :]
        st = np.sqrt(np.maximum(1 - mu * mu, 0))
        cp, sp = np.cos(phi), np.sin(phi)

        frame = (l[sl], t1[sl], t2[sl])
        dn = _node_dots(n[sl], frame, mu, st, cp, sp)
        da = _node_dots(a[sl], frame, mu, st, cp, sp)
        inside = da >= np.cos(r_a[sl])[:, None, None]
        f = np.where(inside, np.maximum(dn, 0.0), 0.0)
        out[sl] = np.sum(f.sum(axis=2) * wmu, axis=1) * (2 * PI / nphi)
    return out


def lambert_configs(count: int, seed: int = 17):
    """Random (n = +z, a, r_a, l, α) with a in the upper hemisphere, l up to α below the horizon."""
    rng = np.random.default_rng(seed)
    th_a = np.arccos(rng.uniform(0.0, 1.0, count))
    ph_a = rng.uniform(0, 2 * PI, count)
    r_a = rng.uniform(0.05, PI / 2, count)
    alpha = np.exp(rng.uniform(math.log(0.01), math.log(0.6), count))
    th_l = np.arccos(rng.uniform(-0.2, 1.0, count))
    ph_l = rng.uniform(0, 2 * PI, count)

    def vec(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)

    n = np.tile([0.0, 0.0, 1.0], (count, 1))
    return n, vec(th_a, ph_a), r_a, vec(th_l, ph_l), alpha


def _lambert_residual(p, args):
    """(Ω·max(n·c(k), 0) − E_true)/A(α) with c = normalize(w l + (1 − w) a), w = sigmoid(k ln(A_a/A_l))."""
    import jax
    import jax.numpy as jnp

    omega, cos_na, cos_nl, cos_al, log_ratio, target, scale = args
    w = jax.nn.sigmoid(p["k"] * log_ratio)
    v = 1 - w
    norm = jnp.sqrt(jnp.maximum(w * w + v * v + 2 * w * v * cos_al, 1e-30))
    lam = jnp.maximum((w * cos_nl + v * cos_na) / norm, 0.0)
    return (omega * lam - target) / scale


def fit_lambert_job(count: int, nodes) -> dict:
    """Job: ground truth of the cosine-weighted intersection by quadrature; seed vs fitted centroid; fit k."""
    from rtfit.fitting import Param, fit_least_squares
    from rtfit.realtime import aperture as ap

    n, a, r_a, l, alpha = lambert_configs(count)
    target = cap_model_irradiance(n, a, r_a, l, alpha, tuple(nodes))
    cos_al = np.clip(np.sum(a * l, 1), -1, 1)
    omega = ap.cap_intersection_solid_angle(r_a, alpha, np.arccos(cos_al))
    keep = omega > 1e-3 * ap.cap_area(np.minimum(r_a, alpha))
    n, a, r_a, l, alpha, target, omega, cos_al = (
        x[keep] for x in (n, a, r_a, l, alpha, target, omega, cos_al)
    )
    cos_na, cos_nl = a[:, 2], l[:, 2]
    scale = ap.cap_area(alpha)
    log_ratio = np.log(ap.cap_area(r_a) / scale)
    res = fit_least_squares(
        _lambert_residual,
        {"k": Param(1.0, 0.05, 8.0)},
        (omega, cos_na, cos_nl, cos_al, log_ratio, target, scale),
    )
    out = res.to_dict()
    k = float(res.values["k"])
    errs = {}
    for name, lam in (("seed", "seed"), ("fitted", "fitted")):
        e, _ = ap.ambient_aperture_irradiance(
            cos_na, cos_nl, cos_al, r_a, alpha, 1.0, 0.0, intersection="exact", lambert=lam, k=k
        )
        rel = (e - target) / scale
        errs[name] = {
            "rms": float(np.sqrt(np.mean(rel**2))),
            "max": float(np.max(np.abs(rel))),
            "mean": float(np.mean(rel)),
        }
    # Open sky, small light at 60°: the erratum's 73 %.
    e_seed, _ = ap.ambient_aperture_irradiance(1.0, 0.5, 0.5, PI / 2, 0.01, 1.0, 0.0)
    e_fit, _ = ap.ambient_aperture_irradiance(1.0, 0.5, 0.5, PI / 2, 0.01, 1.0, 0.0, lambert="fitted", k=k)
    exact60 = float(
        cap_model_irradiance(
            [[0, 0, 1]], [[0, 0, 1]], [PI / 2], [[math.sqrt(0.75), 0, 0.5]], [0.01], tuple(nodes)
        )[0]
    )
    # Quadrature resolution: the same configurations with twice the nodes in each direction (first 300).
    m = min(300, len(target))
    fine = cap_model_irradiance(n[:m], a[:m], r_a[:m], l[:m], alpha[:m], (2 * nodes[0], 2 * nodes[1]))
    out.update(
        {
            "errors": errs,
            "n_configs": len(target),
            "k": k,
            "open_sky_60": {"exact": exact60, "seed": e_seed, "fitted": e_fit},
            "quad_resolution": float(np.max(np.abs(fine - target[:m]) / scale[:m])),
        }
    )
    return out


# --------------------------------------------------------------------------------------------- scenes
def scene_job(
    name: str,
    probe_n: int,
    spp: int,
    sky_spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    bake_dirs: int,
    progress: bool = False,
) -> dict:
    """Job: probe points on the receiver, baked visibility, and light / sky irradiance references."""
    from rtfit.reference import ReferenceCache, ReferenceRequest
    from rtfit.reference.visibility import bake_visibility, surface_points
    from rtfit.scenes import ConstantEnv, library_path, load_scene, scene_hash

    from .ambient_aperture_scenes import PROBE_REGION, probe_grid

    scene = load_scene(library_path(name))
    xy, inside = probe_grid(name, probe_n)
    pts, nrm, valid = surface_points(scene, xy, PROBE_REGION[name][4], variant)
    mask = inside & valid
    p, n = pts[mask], nrm[mask]
    bake = bake_visibility(scene, p, n, bake_dirs, seed, variant)
    cache = ReferenceCache(cache_dir)
    sky_scene = dataclasses.replace(
        scene, lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),), name=f"{scene.name}-sky"
    )
    refs = {}
    for label, sc, n_spp in (("light", scene, spp), ("sky", sky_scene, sky_spp)):
        r = cache.get(
            ReferenceRequest(
                scene=sc,
                spp=n_spp,
                pass_spp=min(pass_spp, n_spp),
                seed=seed,
                variant=variant,
                quantity="irradiance",
                points=p,
                normals=n,
                transport="direct",
            ),
            progress=progress,
            label=f"{sc.name} probes",
        )
        refs[label] = {
            "mean": r.mean,
            "stderr": r.stderr,
            "sigma": r.sigma(),
            "info": r.to_dict(),
            "hash": scene_hash(sc),
        }
    return {
        "name": name,
        "mask": mask.reshape(probe_n, probe_n),
        "points": p,
        "normals": n,
        "visible_fraction": bake.visible_fraction,
        "bake_stderr": bake.stderr,
        "bent_normal": bake.bent_normal,
        "aperture": bake.aperture,
        "bake": bake.to_dict(),
        "refs": refs,
        "scene_hash": scene_hash(scene),
    }


def unoccluded_job(
    probe_n: int, spp: int, pass_spp: int, seed: int, variant: str, cache_dir: str, progress: bool = False
) -> dict:
    """Job: the hole scene with every occluder removed: Mitsuba vs the closed-form sphere-light irradiance
    (validates the probes, the light's geometry and the units of the whole comparison)."""
    from rtfit.reference import ReferenceCache, ReferenceRequest
    from rtfit.scenes import library_path, load_scene

    from .ambient_aperture_scenes import probe_grid

    scene = load_scene(library_path("aperture_hole"))
    floor = dataclasses.replace(scene, shapes=scene.shapes[:1], name=f"{scene.name}-unoccluded")
    xy, _ = probe_grid("aperture_hole", probe_n)
    p = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
    n = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    r = ReferenceCache(cache_dir).get(
        ReferenceRequest(
            scene=floor,
            spp=spp,
            pass_spp=min(pass_spp, spp),
            seed=seed,
            variant=variant,
            quantity="irradiance",
            points=p,
            normals=n,
            transport="direct",
        ),
        progress=progress,
        label="unoccluded probes",
    )
    return {
        "points": p,
        "normals": n,
        "mean": r.mean,
        "stderr": r.stderr,
        "sigma": r.sigma(),
        "info": r.to_dict(),
    }


def light_geometry(points, normals, bent, light):
    """Per probe: cos(n, a), cos(n, l), cos(a, l), α and l for a sphere light (centre, radius)."""
    c = np.asarray(light.center, dtype=np.float64)
    v = c[None, :] - points
    dist = np.linalg.norm(v, axis=1)
    l = v / dist[:, None]
    alpha = np.arctan2(light.radius, np.sqrt(np.maximum(dist**2 - light.radius**2, 0)))
    cos_na = np.clip(np.sum(normals * bent, 1), -1, 1)
    cos_nl = np.clip(np.sum(normals * l, 1), -1, 1)
    cos_al = np.clip(np.sum(bent * l, 1), -1, 1)
    return cos_na, cos_nl, cos_al, alpha, l


def shade(method: str, geo, aperture, radiance: float, k: float, coeffs) -> np.ndarray:
    """Irradiance of one light-case method per probe (W/m²) from the baked caps (NumPy in, NumPy out)."""
    from rtfit.realtime import aperture as ap
    from rtfit.realtime import diffuse

    cos_na, cos_nl, cos_al, alpha, _ = geo
    if method == "unshadowed":
        return diffuse.sphere_light_irradiance(cos_nl, alpha, radiance)
    _, form, lam = method.split("-")
    e, _ = ap.ambient_aperture_irradiance(
        cos_na,
        cos_nl,
        cos_al,
        aperture,
        alpha,
        radiance,
        0.0,
        intersection=form,
        lambert=lam,
        coeffs=coeffs,
        k=k,
    )
    return e


def shade_sky(method: str, cos_na, aperture, sky: float) -> np.ndarray:
    from rtfit.realtime import aperture as ap

    zero = np.zeros_like(cos_na)
    if method == "unoccluded":
        return np.full_like(cos_na, PI * sky)
    fill = "seed" if method == "fill-seed" else "projected"
    _, e = ap.ambient_aperture_irradiance(
        cos_na, zero, -np.ones_like(cos_na), aperture, zero, 0.0, sky, intersection="exact", fill=fill
    )
    return e


# ------------------------------------------------------------------------------------------ experiment
def run(ctx) -> dict:
    from . import ambient_aperture_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    from rtfit.realtime import set_default_backend

    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")
    jobs = [
        Job(
            "rtfit.experiments.ambient_aperture:scene_job",
            {
                "name": name,
                "probe_n": cfg["probe_n"],
                "spp": cfg["spp"],
                "sky_spp": cfg["sky_spp"],
                "pass_spp": cfg["pass_spp"],
                "seed": ctx.seed,
                "variant": ctx.variant,
                "cache_dir": str(ctx.cache_dir),
                "bake_dirs": cfg["bake_dirs"],
                "progress": ctx.progress,
            },
            label=name,
        )
        for name in cfg["scenes"]
    ]
    jobs.append(
        Job(
            "rtfit.experiments.ambient_aperture:unoccluded_job",
            {
                "probe_n": cfg["probe_n"],
                "spp": cfg["spp"],
                "pass_spp": cfg["pass_spp"],
                "seed": ctx.seed,
                "variant": ctx.variant,
                "cache_dir": str(ctx.cache_dir),
                "progress": ctx.progress,
            },
            label="unoccluded",
        )
    )
    jobs.append(
        Job(
            "rtfit.experiments.ambient_aperture:fit_intersection_job",
            {"grid": cfg["fit_grid"]},
            label="fit-intersection",
        )
    )
    jobs.append(
        Job(
            "rtfit.experiments.ambient_aperture:fit_lambert_job",
            {"count": cfg["lambert_configs"], "nodes": cfg["lambert_quad"]},
            label="fit-lambert",
        )
    )
    ctx.log(f"running {len(jobs)} jobs (3 scenes, validation, 2 fits)")
    results = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="ambient-aperture")))
    return rep.assemble(ctx, cfg, results)


def bench(ctx) -> list[dict]:
    from . import ambient_aperture_report as rep

    return rep.bench(ctx)
