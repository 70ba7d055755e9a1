"""Experiment ``half-lambert``: wrap-style diffuse lighting vs the exact irradiance of a sphere light.

Scene (``scenes/library/half_lambert_sphere.toml``): a white Lambertian unit sphere lit from the
side by a distant spherical light (a sun: a uniform disc of angular radius α, the same from every
point), so the terminator runs down the middle of the image. The irradiance at normal incidence is
E⊥ = π W/m² for every α (radiance 1/sin²α), so the lit peak of the sphere's radiance is 1 and
every radiance error reads as a fraction of that peak. An optional constant sky of radiance s adds
E_sky = π·s on every point of the (convex) sphere.

Ground truth: Mitsuba (`direct` integrator, chosen by the integrator rule: one convex reflector),
point-sampled at pixel centres; irradiance probes along the equator for the terminator plot.
Approximations, evaluated on the pixel-centre G-buffer (cos θ = n·l per pixel, α is the same
everywhere for a distant light), each plus the exact sky term:

* ``lambert``      E⊥·max(cos θ, 0)
* ``half-lambert`` E⊥·(½ cos θ + ½)²       (Valve; seed 000:2520-2534)
* ``wrap-fit``     E⊥·max((cos θ + w)/(1 + w), 0)^p, (w, p) least-squares fitted per light size
* ``wrap-smooth``  the same with w(α), p(α) from one smooth fit over all light sizes
* ``exact``        the closed-form sphere-light irradiance (horizon-clipped): must sit at the
  reference's noise floor — the check that reference and approximation measure the same thing.

Radiance of a white Lambertian surface is L = ρ E / π with ρ = 1.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .jobs import Job

MODELS = ("lambert", "half-lambert", "wrap-fit", "wrap-smooth", "exact")
LABELS = {
    "lambert": "Lambert",
    "half-lambert": "Half-Lambert",
    "wrap-fit": "Wrap (fitted per α)",
    "wrap-smooth": "Wrap (smooth w(α), p(α))",
    "exact": "Exact closed form",
}

# Cases: light angular radius (degrees) × sky radiance (relative to the lit peak radiance, 1).
ALPHAS_FULL = (0.27, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0)
ALPHAS_QUICK = (0.27, 5.0, 15.0, 30.0)
SKIES = (0.0, 0.2)


def configure(quick: bool, spp: int | None) -> dict:
    return {
        "alphas_deg": list(ALPHAS_QUICK if quick else ALPHAS_FULL),
        "sky_radiances": list(SKIES),
        "resolution": 64 if quick else 160,
        "spp": spp or (256 if quick else 4096),
        "pass_spp": 128 if quick else 512,
        "probe_count": 61 if quick else 181,
        "probe_spp": 2048 if quick else 32768,
    }


# ------------------------------------------------------------------------------------------- scenes
def case_scene(alpha_deg: float, sky: float, resolution: int):
    """The library scene with the light resized to ``alpha_deg`` (E⊥ = π) and a sky of radiance ``sky``."""
    from rtfit.scenes import ConstantEnv, library_path, load_scene

    base = load_scene(library_path("half_lambert_sphere"))
    sun = dataclasses.replace(base.lights[0], angular_radius_deg=float(alpha_deg), irradiance=(math.pi,) * 3)
    lights = (sun,) + ((ConstantEnv(radiance=(sky,) * 3),) if sky > 0 else ())
    camera = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(
        base, name=f"{base.name}-a{alpha_deg:g}-s{sky:g}", camera=camera, lights=lights
    )


def case_id(alpha_deg: float, sky: float) -> str:
    return f"a{alpha_deg:g}-sky{sky:g}".replace(".", "p")


def probe_points(count: int):
    """Points on the unit sphere's equator with normals at θ = 0…180° from the light direction,
    on the camera's side (−y). Returns (theta_rad, points, normals)."""
    theta = np.linspace(0.0, math.pi, count)
    normals = np.stack([np.cos(theta), -np.sin(theta), np.zeros_like(theta)], axis=-1)
    return theta, normals.copy(), normals


# --------------------------------------------------------------------------------------------- jobs
def render_case(
    scene_toml: str,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    probe_count: int,
    probe_spp: int,
    progress: bool = False,
) -> dict:
    """Job: reference image, G-buffer and irradiance probes of one case (plain data out)."""
    from rtfit.reference import ReferenceCache, ReferenceRequest, render_gbuffer
    from rtfit.scenes import parse_scene_text

    scene = parse_scene_text(scene_toml)
    cache = ReferenceCache(cache_dir)
    image = cache.get(
        ReferenceRequest(scene=scene, spp=spp, pass_spp=pass_spp, seed=seed, variant=variant),
        progress=progress,
        label=scene.name,
    )
    gb = render_gbuffer(scene, variant)
    _, points, normals = probe_points(probe_count)
    probes = cache.get(
        ReferenceRequest(
            scene=scene,
            spp=probe_spp,
            pass_spp=min(probe_spp, 4096),
            seed=seed,
            variant=variant,
            quantity="irradiance",
            points=points,
            normals=normals,
        ),
        progress=progress,
        label=f"{scene.name} probes",
    )
    return {"image": image, "gbuffer": gb, "probes": probes}


def _wrap_residual(p, args):
    """Residual of wrap lighting against irradiance normalised by E⊥ (JAX; module level so that
    the jitted solve is compiled once, not per case)."""
    import jax.numpy as jnp

    c, t, s = args
    base = jnp.maximum((c + p["w"]) / (1.0 + p["w"]), 0.0)
    safe = jnp.where(base > 0, base, 1.0)  # keeps the gradient of base**p finite at base = 0
    model = jnp.where(base > 0, safe ** p["p"], 0.0)
    return (model - t) * s


def fit_wrap_job(cos_theta, target, peak) -> dict:
    """Job: fit (w, p) of wrap lighting to target irradiance (both normalised by ``peak``)."""
    from rtfit.fitting import Param, fit_least_squares

    cos_theta = np.asarray(cos_theta, dtype=np.float64)
    peak = np.asarray(peak, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64) / peak
    scale = peak / np.mean(peak)
    result = fit_least_squares(
        _wrap_residual,
        {"w": Param(0.3, 0.0, 1.0), "p": Param(1.3, 0.25, 8.0)},
        args=(cos_theta, target, scale),
    )
    return result.to_dict()


# ----------------------------------------------------------------------------------- the experiment
def sun_geometry(normals, sun):
    """cos θ = n·l, α and E⊥ per normal (N, 3) for a distant light (α and E⊥ are the same everywhere)."""
    nrm = np.asarray(normals, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    cos_t = np.clip(nrm @ np.asarray(sun.direction, dtype=np.float64), -1.0, 1.0)
    return (
        cos_t,
        np.full_like(cos_t, math.radians(sun.angular_radius_deg)),
        np.full_like(cos_t, sun.irradiance[0]),
    )


def _light_geometry(gb, scene):
    """The comparison mask and per-pixel cos θ, α, E⊥ from the G-buffer."""
    mask = gb.mask & ~gb.emitter
    return (mask, *sun_geometry(gb.normal[mask], scene.lights[0]))


def _model_irradiance(model: str, cos_t, alpha, peak, params: dict):
    from rtfit.realtime import diffuse

    if model == "lambert":
        return diffuse.lambert(cos_t, peak)
    if model == "half-lambert":
        return diffuse.half_lambert(cos_t, peak)
    if model in ("wrap-fit", "wrap-smooth"):
        return diffuse.wrap(cos_t, params["w"], params["p"], peak)
    if model == "exact":
        radiance = float(peak[0] / (math.pi * math.sin(alpha[0]) ** 2))  # E⊥ = π sin²α L
        return diffuse.sphere_light_irradiance(cos_t, alpha, radiance)
    raise ValueError(model)


def smooth_w(alpha_rad, c):
    s = np.sin(alpha_rad)
    return c["w1"] * s + c["w2"] * s * s


def smooth_p(alpha_rad, c):
    s = np.sin(alpha_rad)
    return 1.0 + c["p1"] * s + c["p2"] * s * s


def run(ctx) -> dict:
    from rtfit.scenes import scene_hash, scene_to_toml

    from . import half_lambert_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    if 0.0 not in cfg["sky_radiances"] or len(set(cfg["alphas_deg"])) < 2:
        raise ValueError(
            "half-lambert: sky_radiances must include 0 and alphas_deg must hold at least two "
            "light sizes (the smooth w(α), p(α) fit uses the no-sky cases)"
        )
    cases = [(a, s) for s in cfg["sky_radiances"] for a in cfg["alphas_deg"]]
    scenes = {case_id(a, s): case_scene(a, s, cfg["resolution"]) for a, s in cases}

    # Stage 1: references, G-buffers and probes (independent jobs).
    jobs = [
        Job(
            "rtfit.experiments.half_lambert:render_case",
            dict(
                scene_toml=scene_to_toml(scenes[case_id(a, s)]),
                spp=cfg["spp"],
                pass_spp=cfg["pass_spp"],
                seed=ctx.seed,
                variant=ctx.variant,
                cache_dir=str(ctx.cache_dir),
                probe_count=cfg["probe_count"],
                probe_spp=cfg["probe_spp"],
                progress=ctx.progress,
            ),
            label=case_id(a, s),
        )
        for a, s in cases
    ]
    ctx.log(f"rendering {len(jobs)} references")
    rendered = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="references")))

    from rtfit.realtime import set_default_backend

    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")

    # Stage 2: per-case geometry and the per-α wrap fits (independent jobs).
    geom = {}
    fit_jobs = []
    for a, s in cases:
        cid = case_id(a, s)
        r = rendered[cid]
        mask, cos_t, alpha, peak = _light_geometry(r["gbuffer"], scenes[cid])
        ref_e = math.pi * (r["image"].mean[mask][:, 0] - s)  # irradiance from the light only (ρ = 1)
        geom[cid] = (mask, cos_t, alpha, peak)
        fit_jobs.append(
            Job(
                "rtfit.experiments.half_lambert:fit_wrap_job",
                dict(cos_theta=cos_t, target=ref_e, peak=peak),
                label=cid,
            )
        )
    ctx.log(f"fitting wrap lighting for {len(fit_jobs)} cases")
    fits = dict(zip([j.label for j in fit_jobs], ctx.executor.map(fit_jobs, desc="fits")))

    # Stage 3: w(α), p(α) as smooth functions, fitted to the per-α fits of the no-sky cases.
    smooth = _fit_smooth(cfg, fits)
    return rep.assemble(
        ctx,
        cfg,
        cases,
        scenes,
        rendered,
        geom,
        fits,
        smooth,
        {cid: scene_hash(sc) for cid, sc in scenes.items()},
    )


def _fit_smooth(cfg, fits) -> dict:
    from rtfit.fitting import Param, fit_least_squares

    import jax.numpy as jnp

    alphas = np.radians(np.array(cfg["alphas_deg"], dtype=np.float64))
    rows = [fits[case_id(a, 0.0)]["parameters"] for a in cfg["alphas_deg"]]
    w = np.array([r["w"]["value"] for r in rows])
    p = np.array([r["p"]["value"] for r in rows])
    # Weights: 1/stderr, floored at 1e-3 so that one very precise case does not dominate entirely.
    ws = 1.0 / np.maximum([r["w"]["stderr"] or 1e-3 for r in rows], 1e-3)
    ps = 1.0 / np.maximum([r["p"]["stderr"] or 1e-3 for r in rows], 1e-3)

    def residual(c, args):
        a, w_, p_, ws_, ps_ = args
        s = jnp.sin(a)
        rw = (c["w1"] * s + c["w2"] * s * s - w_) * ws_
        rp = (1.0 + c["p1"] * s + c["p2"] * s * s - p_) * ps_
        return jnp.concatenate([rw, rp])

    result = fit_least_squares(
        residual,
        {
            "w1": Param(1.0, -10.0, 10.0),
            "w2": Param(0.0, -10.0, 10.0),
            "p1": Param(0.0, -20.0, 20.0),
            "p2": Param(0.0, -20.0, 20.0),
        },
        args=(alphas, w, p, ws, ps),
    )
    return result.to_dict()


def bench(ctx) -> list[dict]:
    from . import half_lambert_report as rep

    return rep.bench(ctx)
