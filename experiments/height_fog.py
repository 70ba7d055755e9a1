"""Experiment ``height-fog``: exponential height fog (closed-form optical depth, fog colour) vs path-traced
media.

What is compared, and why (docs/height-fog.md):

1. **Reference check** (``scenes/library/fog_transmittance.toml``): an emissive backdrop of radiance 1 seen
   through a purely absorbing exponential fog box (tilted, shifted gradient) must read e^(−τ) per pixel,
   τ from the closed form in float64 — z-scores of unit spread check the Python medium itself (box, and the
   ellipsoid inscribed in it).
2. **Optical-depth forms** (no rendering; `rtfit.realtime.height_fog.METHODS` ``exact``, ``seed``,
   ``taylor``): float32 relative error of the stable form, the seed listing (000:2226-2240) and the engine
   Taylor form against the stable form's NumPy run in float64 (the method marked ``exact``; its own accuracy
   against mpmath quadrature is tested in tests/test_height_fog.py) over the (c·Δz, D) domain (maps, worst
   cases, special inputs), and their cost per ray beside NumPy.
3. **Aerial perspective** (``scenes/library/fog_terrain.toml``): terrain with objects at 10 m–20 km under
   Mitsuba's ``sunsky`` with its own sun, inside scattering height fog (albedo 0.9, HG g = 0.6), single
   (max_depth 2) and multiple scattering (unbounded), per sun elevation; references by
   `rtfit.reference.fog_integrator` (closed-form free flight; ``volpathmis`` where a scene has two fogs).
   The cheap model L = L₀·T + C·(1 − T) on the fog-free image L₀ (the same scene without fog and the same
   transport): the shading methods ``const`` and ``phase`` of `METHODS`, each a row of `ROWS` with its
   parameter source — the true b, c with colours from the sky (seed's horizon average, with and without
   per-pixel phase; a single-scattering estimate), or artist parameters (b, c, C) and (b, c, C₀, C₁, g)
   fitted through the JAX run of the method's kernel (`rtfit.fitting.fit_method`). Residuals vs view
   elevation and distance; fitted parameters as JSON.
4. **Fog volumes** (``scenes/library/fog_volumes.toml``): an ellipsoid and a rotated box of fog with their
   own b, c and oriented gradients over the terrain; the volume model with its true b, c and a fitted
   constant colour per volume (linear least squares).

Sections: configure · methods (rows) · cases (scenes, geometry, inputs) · jobs · run (results) · checks ·
figures · summary (text) · bench (cost rows and ``rtfit bench``).
"""

from __future__ import annotations

import dataclasses
import math

import drjit as dr
import numpy as np

from rtfit.fitting import Param, compute_metrics, fit_method
from rtfit.realtime import (
    NUMPY_OPS,
    FogVolume,
    fog_pass,
    fog_volume_segment,
    fog_volumes_optical_depth,
    fog_volumes_shade,
    height_fog_optical_depth,
    height_fog_transmittance,
)
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.height_fog import METHODS, OPTICAL_DEPTH_FORMS
from rtfit.reference import (
    ReferenceCache,
    ReferenceRequest,
    radiance_pass,
    render_gbuffer,
    use_variant,
)
from rtfit.reference.budget import check_finite
from rtfit.reference.build import light_dicts, load_dict, mitsuba_scene_dict
from rtfit.reference.height_fog import grid_medium_dict, region_matrix, sky_statistics
from rtfit.reference.height_fog import medium_dict as fog_medium_dict
from rtfit.scenes import library_path, load_scene, parse_scene_text, scene_hash, scene_to_toml

from . import figures as F
from . import fitted as fitfiles
from .cost import (
    attach_costs,
    baseline_row,
    bench_backend,
    comparison_row,
    cost_backend,
    cost_row,
    memory_baseline,
    memory_floor_row,
    time_drjit,
    time_numpy,
)
from .jobs import Job
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row
from .viewer import save_case_pixels
from .zchecks import pixel_z_checks

# ============================================================================================ configure
SUN_AZIMUTH_DEG = 50.0  # from the view direction (+y) towards +x: the sun is outside the frame
ELEVATIONS_FULL = (5.0, 15.0, 30.0, 60.0)
ELEVATIONS_QUICK = (10.0, 40.0)
TRANSPORTS = ("single", "multiple")


CONFIG = {
    "sun_elevations_deg": ConfigKey("float", "sun elevations (°), one case each", 0.0, 90.0, (None,)),
    "sun_azimuth_deg": ConfigKey("float", "sun azimuth from the view direction (°)", -360.0, 360.0),
    "resolution": ConfigKey("int", "image (W, H) pixels", 8, 4096, (2,)),
    "spp": ConfigKey("int", "reference samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "check_resolution": ConfigKey("int", "check image side (pixels)", 4, 4096),
    "check_spp": ConfigKey("int", "check samples per pixel", 2, SPP_MAX),
    "volumes": ConfigKey("bool", "run the volume (scene) part"),
    "map_size": ConfigKey("int", "error-map (W, H)", 4, 4096, (2,)),
    "random_samples": ConfigKey("int", "random domain samples", 100, 1 << 26),
    "cost_elements": ConfigKey("int", "elements per timed launch", 1024, 1 << 26),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "sun_elevations_deg": list(ELEVATIONS_QUICK if quick else ELEVATIONS_FULL),
            "sun_azimuth_deg": SUN_AZIMUTH_DEG,
            "resolution": [64, 32] if quick else [256, 128],
            "spp": spp or (256 if quick else 2048),
            "pass_spp": 128 if quick else 256,
            "check_resolution": 24 if quick else 64,
            "check_spp": 256 if quick else 2048,
            "volumes": True,
            "map_size": [48, 36] if quick else [200, 160],
            "random_samples": 20000 if quick else 400000,
            "cost_elements": 1 << (20 if quick else 22),
        },
    )


# ============================================================================================== methods
EXACT_FORM = next(f for f in OPTICAL_DEPTH_FORMS if METHODS[f].exact)
"""The optical-depth form whose float64 NumPy run is the reference of the float32 comparison."""


def _colour(index: str, rgb) -> dict:
    """{r<index>, g<index>, b<index>}: a colour as the shading methods' parameters."""
    return {f"{ch}{index}": float(v) for ch, v in zip("rgb", rgb, strict=True)}


def _true_density(medium) -> dict:
    return {"b": medium.density, "c": medium.falloff}


def horizon_colour(medium, sky: dict, fit: dict | None) -> dict:
    """True b, c; C = the sky's horizon average (the seed's colour without phase, 000:2247-2254)."""
    return {**_true_density(medium), **_colour("0", sky["horizon"])}


def horizon_phase_colour(medium, sky: dict, fit: dict | None) -> dict:
    """True b, c; C = horizon average × 4π·p_HG(θ, g) with the medium's g (the seed's per-pixel phase)."""
    return {
        **_true_density(medium),
        **_colour("0", (0.0, 0.0, 0.0)),
        **_colour("1", sky["horizon"]),
        "g": medium.g,
    }


def single_scatter_colour(medium, sky: dict, fit: dict | None) -> dict:
    """True b, c; in-scatter at optical infinity with an unattenuated sun: albedo·(E_sun·p(θ) + mean sky
    radiance over the sphere, the lower half lit ground of albedo ~0.18 under E_horizontal)."""
    alb = np.asarray(medium.albedo)
    e_h = (
        np.asarray(sky["sky_irradiance_horizontal"])
        + np.asarray(sky["sun_irradiance"]) * sky["sun_direction"][2]
    )
    ambient = 0.5 * np.asarray(sky["upper_mean"]) + 0.5 * 0.18 * e_h / math.pi
    return {
        **_true_density(medium),
        **_colour("0", alb * ambient),
        **_colour("1", alb * np.asarray(sky["sun_irradiance"]) / (4 * math.pi)),
        "g": medium.g,
    }


def fitted_values(medium, sky: dict, fit: dict | None) -> dict:
    """The parameters a fit of the row's method found (`fit_fog_job`)."""
    return {k: v["value"] for k, v in fit["parameters"].items()}


# Rows (`rows.Row`): a shading method of `METHODS` and the source of its parameters,
# ``params(medium, sky statistics, fit result or None) -> {name: value}``.
ROWS = (
    Row("horizon-const", "true b, c; colour = sky horizon average", "const", horizon_colour),
    Row("horizon-phase", "true b, c; horizon average × 4π·HG phase (seed)", "phase", horizon_phase_colour),
    Row("single-scatter", "true b, c; colour = albedo·(E_sun·p + L̄_sky)", "phase", single_scatter_colour),
    Row("fit-const", "fitted b, c, constant colour", "const", fitted_values, fitted=True),
    Row("fit-phase", "fitted b, c, colour C₀ + C₁·4π·HG(g)", "phase", fitted_values, fitted=True),
)
FIT_METHODS = tuple(dict.fromkeys(r.method for r in ROWS if r.fitted))
"""The shading methods fitted per case (one fit each, shared by the rows that use it)."""

VOLUME_ROW = ("volume-true", "fog volumes, true b, c; fitted colour")
"""The row of the fog-volume case (its own procedure: `volume_case`)."""

COST_KEYS = {**{r.id: f"fog-pass-{r.method}" for r in ROWS}, VOLUME_ROW[0]: "volumes-2"}
"""The measured cost row (`costs`) of each approximation row."""

RESULT_NAMES = {
    "b": "b_per_m",
    "c": "c_per_m",
    **{f"{ch}{i}": f"C{i}_{ch}" for i in "01" for ch in "rgb"},
    "g": "g",
}
"""The results' names of the shading methods' parameters (approximation ``parameters``)."""

FIT_RANGE = {"b": (1e-3, 1e3), "c": (1e-3, 1e2)}
"""Fits start at the scene's true b and c with bounds these factors of it; the colour starts at the sky's
horizon average; other start values and bounds are the method's (`METHODS`)."""


def fit_params(method: str, density: float, falloff: float, horizon) -> dict[str, Param]:
    """Start values and bounds of one fit (see `FIT_RANGE`)."""
    start = {
        "b": density,
        "c": falloff,
        **{f"{ch}0": max(float(h), 1e-4) for ch, h in zip("rgb", horizon, strict=True)},
    }
    out = {}
    for name, p in METHODS[method].params.items():
        if name in FIT_RANGE:
            lo, hi = FIT_RANGE[name]
            x = start[name]
            out[name] = Param(x, x * lo, x * hi, unit=p.unit, description=p.description)
        else:
            out[name] = dataclasses.replace(p, initial=start[name]) if name in start else p
    return out


def cost_key(ap: dict) -> str:
    """The measured fog pass that an approximation row runs (`COST_KEYS`)."""
    return COST_KEYS[ap["method"]]


# ================================================================================================ cases
def sun_direction(elevation_deg: float, azimuth_deg: float = SUN_AZIMUTH_DEG) -> tuple:
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))


def terrain_scene(
    elevation_deg: float, transport: str, resolution, fog: bool = True, name: str = "fog_terrain"
):
    """The library terrain at one sun elevation; ``transport`` "single" (direct) or "multiple" (global)."""
    base = load_scene(library_path(name))
    lights = tuple(
        dataclasses.replace(lt, sun_direction=sun_direction(elevation_deg)) if lt.kind == "sunsky" else lt
        for lt in base.lights
    )
    camera = dataclasses.replace(base.camera, width=int(resolution[0]), height=int(resolution[1]))
    ref = dataclasses.replace(
        base.reference, transport="direct" if transport == "single" else "global", max_depth=None
    )
    tag = f"e{elevation_deg:g}-{transport}" + ("" if fog else "-nofog")
    return dataclasses.replace(
        base,
        name=f"{base.name}-{tag}",
        camera=camera,
        lights=lights,
        reference=ref,
        media=base.media if fog else (),
    )


def check_scene(resolution: int):
    base = load_scene(library_path("fog_transmittance"))
    camera = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(base, camera=camera)


def volume_from_medium(medium, colour=(1.0, 1.0, 1.0)) -> FogVolume:
    """The real-time `FogVolume` of a scene `ExponentialFog` (same region, gradient and density)."""
    m = region_matrix(medium.boundary)
    half = np.linalg.norm(m[:3, :3], axis=0)
    rot = m[:3, :3] / half
    return FogVolume(
        center=tuple(m[:3, 3]),
        half_size=tuple(half),
        rotation=tuple(map(tuple, rot)),
        ellipsoid=medium.ellipsoid,
        density=medium.density,
        falloff=medium.falloff,
        gradient=medium.gradient,
        gradient_origin=medium.gradient_origin,
        colour=colour,
    )


def pixel_rays(scene, gb):
    """Camera origin, unit view directions (float64) and hit distances (inf: sky) of a G-buffer."""
    d = gb.view_dir.astype(np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    dist = np.where(gb.mask, gb.depth.astype(np.float64), np.inf)
    return tuple(float(x) for x in scene.camera.origin), d, dist


def segment_geometry(scene, gb, medium) -> dict:
    """Per-pixel segment of the camera ray inside ``medium``'s region (float64, `fog_volume_segment`):
    heights along the gradient at entry and exit, length, and the ray's elevation and hit distance."""
    o, d, dist = pixel_rays(scene, gb)
    z0, z1, length = fog_volume_segment(o, d, dist, volume_from_medium(medium))
    return {
        "z0": z0,
        "z1": z1,
        "length": length,
        "elevation_deg": np.degrees(np.arcsin(np.clip(d[..., 2], -1, 1))),
        "distance": dist,
        "view_dir": d,
    }


def pixel_inputs(geom: dict, l0: np.ndarray, dtype=np.float64) -> dict:
    """The shading methods' per-pixel inputs (`METHODS` ``const``/``phase``), shaped like the image."""
    return {
        "z0": geom["z0"].astype(dtype),
        "z1": geom["z1"].astype(dtype),
        "distance": geom["length"].astype(dtype),
        "cos_sun": geom["cos_sun"].astype(dtype),
        **{f"l0_{ch}": l0[..., k].astype(dtype) for k, ch in enumerate("rgb")},
    }


def random_domain(n: int, seed: int = 7, log10_distance: tuple = (-1.0, 6.0)):
    """Random float32 fog inputs over the whole domain (log-uniform): heights |z0| 1e-3..1e4 of either sign,
    distances 10^log10_distance, end heights z1 from nearly horizontal (|Δz| 1e-9 of the path) to vertical,
    density b 1e-6..1 and falloff c 1e-5..10. Returns (z0, z1, dist, b, c); shared with
    tests/test_height_fog.py."""
    rng = np.random.default_rng(seed)
    z0 = (rng.choice([-1, 1], n) * 10 ** rng.uniform(-3, 4, n)).astype(np.float32)
    dist = (10 ** rng.uniform(*log10_distance, n)).astype(np.float32)
    frac = rng.uniform(-1, 1, n) * 10 ** rng.uniform(-9, 0, n)
    z1 = (z0 + frac * np.minimum(dist, 2e4)).astype(np.float32)
    b = (10 ** rng.uniform(-6, 0, n)).astype(np.float32)
    c = (10 ** rng.uniform(-5, 1, n)).astype(np.float32)
    return z0, z1, dist, b, c


SPECIAL_INPUTS = [
    ("horizontal ray, Δz = 0", (10.0, 10.0, 1000.0, 1e-3, 0.01)),
    ("tiny c·Δz = 1e-7", (0.0, 1e-5, 1000.0, 1e-3, 0.01)),
    ("Δz = 0.0125 m, just above the seed's 0.01 m threshold, c = 1e-4", (0.0, 0.0125, 1e4, 1e-3, 1e-4)),
    ("camera 1 km above dense ground fog, looking down (c·Δz = −200)", (1000.0, 0.0, 1500.0, 0.05, 0.2)),
    ("camera in fog looking up (c·Δz = 300)", (0.0, 1500.0, 3000.0, 0.05, 0.2)),
    ("homogeneous c = 0", (5.0, 50.0, 100.0, 1e-3, 0.0)),
    ("no fog b = 0, looking down steeply", (1000.0, 0.0, 1500.0, 0.0, 0.2)),
    ("distance 10⁶ m, horizontal", (0.0, 0.0, 1e6, 1e-4, 1e-3)),
    ("b·D huge: transmittance underflows", (0.0, 0.0, 1e6, 1.0, 0.0)),
]
"""Inputs (z0, z1, D, b, c) where the forms differ most (table of the optical-depth section)."""


# ================================================================================================= jobs
def render_job(
    scene_toml: str,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    gbuffer_of: str | None = None,
    progress: bool = False,
) -> dict:
    """Job: one cached reference image (and, if given, the G-buffer of another scene: the fog-free one)."""
    scene = parse_scene_text(scene_toml)
    ref = ReferenceCache(cache_dir).get(
        ReferenceRequest(scene=scene, spp=spp, pass_spp=pass_spp, seed=seed, variant=variant),
        progress=progress,
        label=scene.name,
    )
    out = {"image": ref}
    if gbuffer_of is not None:
        out["gbuffer"] = render_gbuffer(parse_scene_text(gbuffer_of), variant)
    return out


def sky_job(scene_toml: str, variant: str) -> dict:
    """Job: horizon average, mean sky, sun and sky irradiance of the scene's ``sunsky`` (`sky_statistics`)."""
    sunsky = parse_scene_text(scene_toml).environment()
    mi = use_variant(variant)
    return sky_statistics(mi, mi.load_dict(light_dicts(mi, sunsky)[""]), sunsky)


def stack_rgb(channels):
    """The shading kernels' (r, g, b) tuple as (…, 3): the fitted quantity (module level: one jit)."""
    import jax.numpy as jnp  # jax: only the fits need it (heavy import)

    return jnp.stack(channels, axis=-1)


FIT_MAX_STEPS = 1024
"""Levenberg–Marquardt step cap of the fog fits. The ``const`` fit's b and c correlate at 0.96, and its
optimum is approached slowly: with the fogpath reference (quick run, seed 0) e40-single-const needed 286
steps (the default cap of 256 stopped it unconverged); fits that converge within 256 steps are unchanged."""


def fit_fog_job(method: str, inputs: dict, target, scale, density: float, falloff: float, horizon) -> dict:
    """Job: fit one shading method of `METHODS` to one reference image (pixel-flattened) through the JAX run
    of its kernel; relative residuals (model − reference)/scale (`fit_data`)."""
    result = fit_method(
        METHODS[method],
        inputs,
        target,
        weights=1.0 / np.asarray(scale),
        params=fit_params(method, density, falloff, horizon),
        output=stack_rgb,
        max_steps=FIT_MAX_STEPS,
    )
    return result.to_dict()


def fit_data(geom: dict, l0: np.ndarray, ref: np.ndarray) -> dict:
    """Pixel-flattened fit inputs; residual scale: 2 % of the reference plus 1 % of its mean (relative
    error, not dominated by the bright sky)."""
    scale = 0.02 * np.abs(ref) + 0.01 * float(np.mean(np.abs(ref)))
    inputs = {k: v.reshape(-1) for k, v in pixel_inputs(geom, l0).items()}
    return {"inputs": inputs, "target": ref.reshape(-1, 3), "scale": scale.reshape(-1, 3)}


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    res = cfg["resolution"]
    common = dict(
        pass_spp=cfg["pass_spp"],
        seed=ctx.seed,
        variant=ctx.variant,
        cache_dir=str(ctx.cache_dir),
        progress=ctx.progress,
    )

    def render(label, scene, spp, gbuffer=False):
        scenes[label] = scene
        toml = scene_to_toml(scene)
        args = dict(scene_toml=toml, spp=spp, gbuffer_of=toml if gbuffer else None, **common)
        jobs.append(Job(render_job, args, label=label))

    scenes, jobs = {}, []
    chk = check_scene(cfg["check_resolution"])
    render("check", chk, cfg["check_spp"], gbuffer=True)
    # the same check with the fog restricted to the ellipsoid inscribed in the box (a fog volume)
    chk_e = dataclasses.replace(
        chk, name=f"{chk.name}-ellipsoid", media=(dataclasses.replace(chk.media[0], ellipsoid=True),)
    )
    render("check-ellipsoid", chk_e, cfg["check_spp"], gbuffer=True)
    for e in cfg["sun_elevations_deg"]:
        for tr in TRANSPORTS:
            render(f"e{e:g}-{tr}", terrain_scene(e, tr, res), cfg["spp"])
            # the fog-free single-scattering scene carries the G-buffer of the case
            render(
                f"e{e:g}-{tr}-nofog", terrain_scene(e, tr, res, fog=False), cfg["spp"], gbuffer=tr == "single"
            )
    if cfg["volumes"]:
        e = cfg["sun_elevations_deg"][-1]
        render("volumes", terrain_scene(e, "multiple", res, name="fog_volumes"), cfg["spp"])
        render(
            "volumes-nofog",
            terrain_scene(e, "multiple", res, fog=False, name="fog_volumes"),
            cfg["spp"],
            gbuffer=True,
        )
    sky_jobs = [
        Job(
            sky_job,
            dict(scene_toml=scene_to_toml(scenes[f"e{e:g}-single"]), variant=ctx.variant),
            label=f"sky-e{e:g}",
        )
        for e in cfg["sun_elevations_deg"]
    ]
    ctx.log(f"rendering {len(jobs)} references")
    labels = [j.label for j in jobs + sky_jobs]
    rendered = dict(zip(labels, ctx.executor.map(jobs + sky_jobs, desc="references"), strict=True))
    skies = {f"e{e:g}": rendered.pop(f"sky-e{e:g}") for e in cfg["sun_elevations_deg"]}

    geoms = {}
    for e in cfg["sun_elevations_deg"]:
        sc = scenes[f"e{e:g}-single"]
        geom = segment_geometry(sc, rendered[f"e{e:g}-single-nofog"]["gbuffer"], sc.media[0])
        geom["cos_sun"] = geom["view_dir"] @ np.asarray(sun_direction(e))
        geoms[f"e{e:g}"] = geom

    # Fits (independent jobs): one per case and fitted shading method.
    fit_jobs, fit_keys = [], []
    for e in cfg["sun_elevations_deg"]:
        medium = scenes[f"e{e:g}-single"].media[0]
        for tr in TRANSPORTS:
            cid = f"e{e:g}-{tr}"
            data = fit_data(
                geoms[f"e{e:g}"], rendered[f"{cid}-nofog"]["image"].mean, rendered[cid]["image"].mean
            )
            for method in FIT_METHODS:
                fit_keys.append((cid, method))
                fit_jobs.append(
                    Job(
                        fit_fog_job,
                        dict(
                            method=method,
                            **data,
                            density=medium.density,
                            falloff=medium.falloff,
                            horizon=skies[f"e{e:g}"]["horizon"],
                        ),
                        label=f"{cid}-{method}",
                    )
                )
    ctx.log(f"fitting {len(fit_jobs)} fog models")
    fits = dict(zip(fit_keys, ctx.executor.map(fit_jobs, desc="fits"), strict=True))
    hashes = {k: scene_hash(v) for k, v in scenes.items()}
    return assemble(ctx, cfg, scenes, rendered, skies, geoms, fits, hashes)


def model_image(geom: dict, l0: np.ndarray, method: str, params: dict) -> np.ndarray:
    """One shading method of `METHODS` on the fog-free image: the kernel text on float32 Dr.Jit (the
    shader's precision), returned as float64 (…, 3)."""
    out = METHODS[method].evaluate(pixel_inputs(geom, l0, np.float32), params)
    return np.stack([np.asarray(ch, dtype=np.float64) for ch in out], axis=-1)


def img_t(geom: dict, b: float, c: float) -> np.ndarray:
    """Transmittance of the segment in float64 (for the noise floor of L₀·T)."""
    tau = height_fog_optical_depth(geom["z0"], geom["z1"], geom["length"], float(b), float(c))
    return np.exp(-np.asarray(tau, dtype=np.float64))


def approximation_doc(row_id: str, label: str, fitted: bool, parameters: dict, metrics) -> dict:
    return {
        "method": row_id,
        "label": label,
        "fitted": fitted,
        "parameters": parameters,
        "metrics": metrics.to_dict(),
    }


def assemble(ctx, cfg, scenes, rendered, skies, geoms, fits, hashes) -> dict:
    """The results document: cases (one per sun elevation and transport, plus the fog volumes), fits,
    figures, costs, checks and the optical-depth table."""
    case_docs, images, residuals = [], {}, {}
    for e in cfg["sun_elevations_deg"]:
        geom = geoms[f"e{e:g}"]
        for tr in TRANSPORTS:
            cid = f"e{e:g}-{tr}"
            ref = rendered[cid]["image"]
            clear = rendered[f"{cid}-nofog"]["image"]
            medium = scenes[cid].media[0]
            mask = np.ones(ref.mean.shape[:2], bool)
            approx_docs = []
            for row in ROWS:
                assert row.method is not None  # every fog row is a shading method of METHODS
                p = row.params(medium, skies[f"e{e:g}"], fits.get((cid, row.method)))
                img = model_image(geom, clear.mean, row.method, p)
                images[(cid, row.id)] = img
                t = img_t(geom, p["b"], p["c"])
                sigma = np.sqrt(ref.sigma() ** 2 + (t[..., None] * clear.sigma()) ** 2)
                metrics = compute_metrics(img, ref.mean, sigma, mask)
                residuals[(cid, row.id)] = (img - ref.mean) / np.maximum(np.abs(ref.mean), 1e-12)
                flat = {RESULT_NAMES[k]: float(v) for k, v in p.items()}
                approx_docs.append(approximation_doc(row.id, row.label, row.fitted, flat, metrics))
            # σ of the reference alone (the metrics add the fog-free render's noise through each row's T)
            save_case_pixels(
                ctx.out_dir, cid, ref.mean, ref.sigma(), {r.id: images[(cid, r.id)] for r in ROWS}
            )
            case_docs.append(
                {
                    "id": cid,
                    "label": f"sun elevation {e:g}°, {tr} scattering",
                    "parameters": {
                        "sun_elevation_deg": e,
                        "sun_azimuth_deg": cfg["sun_azimuth_deg"],
                        "scattering": tr,
                        "density_per_m": medium.density,
                        "falloff_per_m": medium.falloff,
                        "albedo": medium.albedo[0],
                        "g": medium.g,
                    },
                    "scene": {"name": scenes[cid].name, "hash": hashes[cid]},
                    "reference": ref.to_dict(),
                    "approximations": approx_docs,
                }
            )

    vol_doc, vol_fit = volume_case(cfg, scenes, rendered, hashes, images) if cfg["volumes"] else (None, None)
    if vol_doc:
        case_docs.append(vol_doc)
        vref = rendered["volumes"]["image"]
        vrow = VOLUME_ROW[0]
        save_case_pixels(ctx.out_dir, "volumes", vref.mean, vref.sigma(), {vrow: images[("volumes", vrow)]})

    checks = transmittance_checks(scenes["check"], rendered["check"], "box")
    checks += transmittance_checks(scenes["check-ellipsoid"], rendered["check-ellipsoid"], "ellipsoid")
    forms = optical_depth_errors(cfg)
    checks += optical_depth_checks(forms)
    costs = cost_rows(ctx, cfg)
    attach_costs(case_docs, costs, key=cost_key)
    fitted = write_fitted(ctx.out_dir, fits, vol_fit, ctx, cfg, geoms, hashes)
    figs = make_figures(ctx.out_dir, cfg, rendered, geoms, images, residuals, case_docs, costs, forms)
    checks += fit_checks(fitted)
    return {
        "summary": summary(case_docs, forms, checks),
        "config": cfg,
        "sections": sections(forms),
        "cases": case_docs,
        "fits": fitted,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "optical_depth_forms": forms["table"],
        "notes": NOTES,
    }


def volume_case(cfg, scenes, rendered, hashes, images):
    """The fog-volume case: true b, c per volume and one constant colour per volume fitted by linear least
    squares (ref − L₀·T = Σᵢ wᵢ Cᵢ, wᵢ = (1 − T)·τᵢ/Σ τ per channel)."""
    sc = scenes["volumes"]
    ref = rendered["volumes"]["image"]
    clear = rendered["volumes-nofog"]["image"]
    gb = rendered["volumes-nofog"]["gbuffer"]
    vols = [volume_from_medium(m) for m in sc.media]
    h, w = gb.mask.shape
    o, d, dist = pixel_rays(sc, gb)
    taus = [np.asarray(t, dtype=np.float64) for t in fog_volumes_optical_depth(o, d, dist, vols)]
    total = np.sum(taus, axis=0)
    t = np.exp(-total)
    wts = np.stack([np.where(total > 0, (1 - t) * ti / np.maximum(total, 1e-300), 0.0) for ti in taus], -1)
    fogged = total > 1e-6
    colours = []
    for ch in range(3):
        y = (ref.mean[..., ch] - clear.mean[..., ch] * t)[fogged]
        sol, *_ = np.linalg.lstsq(wts[fogged], y, rcond=None)
        colours.append(sol)
    colours = np.array(colours).T  # (volumes, 3)
    vols_c = [volume_from_medium(m, colour=tuple(colours[i])) for i, m in enumerate(sc.media)]
    img = fog_volumes_shade(clear.mean, o, d, dist, vols_c)
    row_id, label = VOLUME_ROW
    images[("volumes", row_id)] = img
    sigma = np.sqrt(ref.sigma() ** 2 + (t[..., None] * clear.sigma()) ** 2)
    metrics = compute_metrics(img, ref.mean, sigma, np.ones((h, w), bool))
    params = {f"vol{i}_{c}": float(colours[i, k]) for i in range(len(vols)) for k, c in enumerate("rgb")}
    doc = {
        "id": "volumes",
        "label": f"fog volumes (ellipsoid + box), sun {cfg['sun_elevations_deg'][-1]:g}°, "
        "multiple scattering",
        "parameters": {
            "sun_elevation_deg": cfg["sun_elevations_deg"][-1],
            "volumes": len(vols),
            "fogged_pixels": int(fogged.sum()),
        },
        "scene": {"name": sc.name, "hash": hashes["volumes"]},
        "reference": ref.to_dict(),
        "approximations": [approximation_doc(row_id, label, True, params, metrics)],
    }
    fit = {
        "id": "volume-colours",
        "label": "fog-volume colours (true b, c)",
        "model": "L = L₀·T + Σᵢ (1 − T)·τᵢ/Στ·Cᵢ (linear least squares per channel)",
        "parameters": {
            k: {"value": v, "stderr": None, "lower": None, "upper": None, "at_bound": False}
            for k, v in params.items()
        },
        "n_residuals": int(fogged.sum()) * 3,
        "converged": True,
    }
    return doc, fit


def float64_truth(z0, z1, distance, b, c) -> np.ndarray:
    """τ of the stable form (`EXACT_FORM`) from its NumPy run in float64: the reference of the float32
    comparison. Its own accuracy (≤ 1e-13 relative to mpmath quadrature, also over `random_domain`) is
    tested in tests/test_height_fog.py; NumPy evaluates both branches of a select, hence the errstate."""
    x = [np.asarray(v, dtype=np.float64) for v in (z0, z1, distance, b, c)]
    with np.errstate(all="ignore"):
        tau = METHODS[EXACT_FORM](NUMPY_OPS, dict(z0=x[0], z1=x[1], distance=x[2]), dict(b=x[3], c=x[4]))
    return np.asarray(tau, dtype=np.float64)


def _drjit_float():
    return backend_float()


def _form(form: str, z0, z1, distance, b, c):
    """One optical-depth form of `METHODS` on Dr.Jit (float32 in, float64 NumPy out)."""
    tau = METHODS[form].evaluate(dict(z0=z0, z1=z1, distance=distance), dict(b=b, c=c))
    return np.asarray(tau, dtype=np.float64)


def optical_depth_errors(cfg) -> dict:
    """Float32 relative error of each form against `float64_truth`: random domain, special inputs, maps."""
    Float = _drjit_float()
    z0, z1, dist, b, c = random_domain(cfg["random_samples"])
    truth = float64_truth(z0, z1, dist, b, c)
    ok = np.isfinite(truth) & (truth > 1e-30) & (truth < 1e30)
    cond = np.abs(c.astype(np.float64) * np.minimum(z0, z1))
    table, per_form = [], {}
    for form in OPTICAL_DEPTH_FORMS:
        got = _form(form, *(Float(x) for x in (z0, z1, dist, b, c)))
        with np.errstate(all="ignore"):
            rel = np.abs(got / truth - 1.0)
        rel_ok = np.where(ok, rel, 0.0)
        bad = ok & ~np.isfinite(got)
        worst = float(np.max(np.where(np.isfinite(rel_ok), rel_ok, np.inf)))
        i = int(np.argmax(np.where(np.isfinite(rel_ok), rel_ok, np.inf)))
        specials = {}
        for label, args in SPECIAL_INPUTS:
            v = float(_form(form, *(Float(np.float32(a)) for a in args))[0])
            tv = float(float64_truth(*[np.float32(a) for a in args]))
            specials[label] = (v, tv)
        per_form[form] = {
            "worst": worst,
            "at": [float(x[i]) for x in (z0, z1, dist, b, c)],
            "non_finite": int(bad.sum()),
            "specials": specials,
            "bound_ratio": float(
                np.max(rel_ok[np.isfinite(rel_ok)] / (2e-6 + 2 * 2.0**-24 * cond[np.isfinite(rel_ok)]))
            ),
        }
        table.append(
            {
                "form": form,
                "label": METHODS[form].label,
                "worst_rel_error": worst if math.isfinite(worst) else None,
                "worst_at_z0_z1_D_b_c": per_form[form]["at"],
                "non_finite_where_finite": int(bad.sum()),
                "samples": int(ok.sum()),
            }
        )
    return {"table": table, "per_form": per_form, "maps": error_maps(cfg, Float)}


def error_maps(cfg, Float) -> dict:
    """Relative error over (signed c·Δz, D) for c = 0.01 /m, camera at z = 0, b = 1e-4 /m."""
    nx, ny = cfg["map_size"]
    mag = np.logspace(-8, math.log10(300), nx // 2)
    x = np.concatenate([-mag[::-1], mag])
    dist = np.logspace(0, 6, ny)
    X, D = np.meshgrid(x, dist)
    c, b = 0.01, 1e-4
    dz = X / c
    valid = np.abs(dz) <= D
    z0 = np.zeros_like(X, dtype=np.float32)
    z1 = dz.astype(np.float32)
    d32 = D.astype(np.float32)
    truth = float64_truth(z0, z1, d32, b, c)
    maps = {}
    for form in OPTICAL_DEPTH_FORMS:
        got = _form(form, Float(z0.ravel()), Float(z1.ravel()), Float(d32.ravel()), b, c).reshape(X.shape)
        with np.errstate(all="ignore"):
            rel = np.abs(got / truth - 1.0)
        in_range = np.isfinite(truth) & (truth > 1e-30) & (truth < 1e30)  # τ representable in float32
        maps[form] = np.where(valid & in_range, np.where(np.isfinite(rel), rel, np.inf), np.nan)
    return {"x": x, "distance": dist, "maps": maps, "c": c, "b": b}


FIT_RESIDUAL_UNITS = "(model − reference)/(0.02·|reference| + 0.01·mean|reference|) per pixel and channel"


def _fit_domain(geom: dict) -> dict:
    """The input ranges a fit saw: the finite per-pixel segment inputs of its view."""
    out = {}
    for key, name in (("z0", "z0"), ("z1", "z1"), ("length", "distance"), ("cos_sun", "cos_sun")):
        v = np.asarray(geom[key], np.float64)
        v = v[np.isfinite(v)]
        if v.size:
            out[name] = (float(v.min()), float(v.max()))
    return out


def write_fitted(out, fits: dict, vol_fit: dict | None, ctx=None, cfg=None, geoms=None, hashes=None):
    """fitted/fog-<case>-<method>.json per fit and fitted/fog-volume-colours.json, format
    ``rtfit.fitted/1`` (`rtfit.experiments.fitted`: parameters with units and bounds, residual, domain,
    GLSL/HLSL of the fitted shading function); returns the results' ``fits`` records."""
    docs = []
    spp = (cfg or {}).get("spp")
    for (cid, method), fit in fits.items():
        label = f"{cid}-{method}"
        fid = f"fog-{label}"
        file = f"fitted/{fid}.json"
        m = METHODS[method]
        geom = (geoms or {}).get(cid.split("-")[0])
        entry = fitfiles.method_entry(
            m,
            fit,
            label=f"{m.label}, {cid}",
            case=cid,
            domain=_fit_domain(geom) if geom is not None else None,
            residual_units=FIT_RESIDUAL_UNITS,
            outputs=("out_r", "out_g", "out_b"),
            data={"correlation": fit.get("correlation"), "param_names": fit.get("param_names")},
        )
        prov = fitfiles.provenance(
            ctx, "height-fog", [h for k, h in (hashes or {}).items() if k in (cid, f"{cid}-nofog")], spp
        )
        docs.append(
            fitfiles.write_fit(
                out,
                file,
                title=f"height fog, {m.label}: artist parameters fitted to Mitsuba ({cid})",
                provenance=prov,
                entry=entry,
                doc_id=fid,
                label=f"artist parameters, {label}",
                model=m.formula,
                fit=fit,
            )
        )
    if vol_fit:
        file = "fitted/fog-volume-colours.json"
        entry = fitfiles.FittedMethod(
            id=vol_fit["id"],
            label=vol_fit["label"],
            formula=vol_fit["model"],
            source="rtfit (fog volumes: oriented box / ellipsoid with a shifted height gradient)",
            quantity="fogged_radiance",
            case="volumes",
            parameters=fitfiles.parameters_from_fit(None, vol_fit["parameters"], unit="W/m²/sr"),  # radiances
            residual=fitfiles.Residual(rms=None, n=vol_fit.get("n_residuals"), units="radiance"),
            converged=vol_fit.get("converged"),
            shader=None,
            shader_note=(
                "no shader text: the colours feed fog_volumes_shade, a loop over a list of volumes "
                "(a shader needs the volume buffer); the colours vol<i>_<channel> are the fitted data"
            ),
        )
        prov = fitfiles.provenance(
            ctx, "height-fog", [(hashes or {}).get("volumes", "")] if hashes else [], spp
        )
        fitfiles.write_fitted(
            out / file,
            fitfiles.FittedFile(
                format=fitfiles.FORMAT,
                title="height fog: fog-volume colours fitted by linear least squares (true b, c)",
                provenance=prov,
                methods=[entry],
            ),
        )
        docs.append({**vol_fit, "file": file})
    return docs


# =============================================================================================== checks
def transmittance_checks(scene, rendered, shape: str) -> list[Check]:
    """Mitsuba through a purely absorbing medium against e^(−τ) of the closed form (float64) per pixel.

    The estimator is binary (a camera ray survives the absorbing medium or not): its variance is T(1 − T)
    per sample, so z-scores use max(sample variance, T(1 − T))/N (all-survived pixels have 0)."""
    ref, gb = rendered["image"], rendered["gbuffer"]
    vol = volume_from_medium(scene.media[0])
    h, w = gb.mask.shape
    o, d, _ = pixel_rays(scene, gb)
    tau = np.asarray(fog_volumes_optical_depth(o, d, np.full((h, w), np.inf), [vol])[0], dtype=np.float64)
    t = np.exp(-tau)
    m = gb.mask & (tau > 1e-6)
    sig = np.sqrt(np.maximum(ref.stderr[..., 0] ** 2, t * (1 - t) / ref.spp) + (1e-5 * t) ** 2)
    z = ((ref.mean[..., 0] - t) / sig)[m]
    pooled = float(np.sum(ref.mean[..., 0][m] - t[m]) / math.sqrt(np.sum(sig[m] ** 2)))
    names = (
        f"reference check ({shape}): Mitsuba transmittance through absorbing exponential fog = "
        f"e^(−τ): z-score spread ({int(m.sum())} pixels)",
        f"reference check ({shape}): pooled z-score of (Mitsuba − e^(−τ)) over the fogged pixels",
        f"reference check ({shape}): largest |z| over fogged pixels",
    )
    return pixel_z_checks(z, pooled, names, 0.15)


def optical_depth_checks(forms: dict) -> list[Check]:
    """The stable form in float32: within its error bound everywhere, finite where τ is, right at the
    special inputs, and T = 0 exactly where it underflows."""
    ex = forms["per_form"][EXACT_FORM]
    samples = forms["table"][0]["samples"]
    checks = [
        Check(
            name="stable closed form, float32: worst relative error / (2e-6 + 2·2⁻²⁴·|c·z_min|) over "
            f"{samples} random inputs",
            value=ex["bound_ratio"],
            expected="≤ 1",
            passed=bool(ex["bound_ratio"] <= 1.0),
        ),
        Check(
            name="stable closed form: non-finite outputs where τ is finite",
            value=ex["non_finite"],
            expected="0",
            passed=ex["non_finite"] == 0,
        ),
    ]
    for label, (v, tv) in ex["specials"].items():
        good = (
            (v == tv == 0.0)
            or (math.isinf(tv) and math.isinf(v))
            or (math.isfinite(v) and tv > 0 and abs(v / tv - 1) < 1e-5)
        )
        checks.append(
            Check(
                name=f"stable closed form at: {label}",
                value=v,
                expected=f"{tv:.6g} (±1e-5 rel.)",
                passed=bool(good),
            )
        )
    t_under = float(
        np.asarray(
            height_fog_transmittance(
                np.zeros(1, np.float32), np.zeros(1, np.float32), np.full(1, 1e6, np.float32), 1.0, 0.0
            )
        )[0]
    )
    checks.append(
        Check(
            name="transmittance underflow (b·D = 1e6) is exactly 0",
            value=t_under,
            expected="0",
            passed=t_under == 0.0,
        )
    )
    return checks


def fit_checks(fitted: list[dict]) -> list[Check]:
    return [
        Check(
            name=f"fit {f['id']} converged",
            value=str(f["converged"]),
            expected="True",
            passed=bool(f["converged"]),
        )
        for f in fitted
    ]


# ============================================================================================== figures
def make_figures(out, cfg, rendered, geoms, images, residuals, case_docs, costs, forms) -> list[dict]:
    figs = []
    fdir = out / "figures"
    for doc in case_docs:
        cid = doc["id"]
        ref = rendered[cid]["image"].mean
        panels = [(ap["method"], images[(cid, ap["method"])]) for ap in doc["approximations"]]
        caption = f"{doc['label']}: reference and models; error maps relative to the image's mean radiance."
        scale = float(np.mean(np.abs(ref)))
        figs.append(
            F.case_comparison(
                out, doc, ref, panels, np.ones(ref.shape[:2], bool), error_scale=scale, caption=caption
            )
        )
    figs += _residual_figures(fdir, cfg, geoms, residuals, rendered)
    figs.append(_map_figure(fdir, forms))
    figs.append(_pareto_figure(fdir, case_docs, costs))
    figs.append(_fit_growth_figure(fdir, case_docs))
    return figs


def _binned(x, y, edges):
    idx = np.digitize(x, edges) - 1
    centres, vals = [], []
    for k in range(len(edges) - 1):
        sel = idx == k
        if sel.sum() >= 3:
            centres.append(0.5 * (edges[k] + edges[k + 1]))
            vals.append(float(np.sqrt(np.mean(y[sel] ** 2))))
    return np.array(centres), np.array(vals)


def _residual_figures(fdir, cfg, geoms, residuals, rendered) -> list[dict]:
    figs = []
    e = cfg["sun_elevations_deg"][0]
    geom = geoms[f"e{e:g}"]
    elev = geom["elevation_deg"]
    dist = geom["distance"]
    surf = np.isfinite(dist)
    elev_edges = np.linspace(elev.min(), elev.max(), 13)
    dist_edges = np.linspace(0.5, 4.5, 13)
    series_e, series_d = [], []
    for tr in TRANSPORTS:
        panel = f"{tr} scattering"
        # noise floor: relative standard error of the reference and of the fog-free input L₀
        ref = rendered[f"e{e:g}-{tr}"]["image"]
        clear = rendered[f"e{e:g}-{tr}-nofog"]["image"]
        noise = np.sqrt(
            np.mean((ref.sigma() ** 2 + clear.sigma() ** 2) / np.maximum(ref.mean**2, 1e-24), axis=-1)
        )
        floor = {"label": "noise floor", "panel": panel, "ls": ":", "color": "0.4"}
        x, y = _binned(elev.ravel(), noise.ravel(), elev_edges)
        series_e.append({"x": x, "y": y, **floor})
        x, y = _binned(np.log10(dist[surf]), noise[surf], dist_edges)
        series_d.append({"x": 10**x, "y": y, **floor})
        for row in ROWS:
            r = np.sqrt(np.mean(residuals[(f"e{e:g}-{tr}", row.id)] ** 2, axis=-1))
            x, y = _binned(elev.ravel(), r.ravel(), elev_edges)
            series_e.append({"x": x, "y": y, "label": row.id, "panel": panel})
            x, y = _binned(np.log10(dist[surf]), r[surf], dist_edges)
            series_d.append({"x": 10**x, "y": y, "label": row.id, "panel": panel})
    panels = [f"{tr} scattering" for tr in TRANSPORTS]
    p = F.line_plot(
        fdir / "residual_vs_elevation.png",
        "view elevation (degrees)",
        "RMS relative error",
        series_e,
        title=f"sun elevation {e:g}°",
        y_log=True,
        panels=panels,
    )
    figs.append(
        {
            "file": f"figures/{p.name}",
            "caption": f"RMS relative error per pixel vs view elevation (sun {e:g}°): "
            "sky pixels above 0°, terrain below; dotted: the noise floor (reference and L₀ standard errors).",
            "section": "results",
        }
    )
    p = F.line_plot(
        fdir / "residual_vs_distance.png",
        "distance to the surface (m)",
        "RMS relative error",
        series_d,
        title=f"sun elevation {e:g}°",
        x_log=True,
        y_log=True,
        panels=panels,
    )
    figs.append(
        {
            "file": f"figures/{p.name}",
            "caption": "RMS relative error of surface pixels vs distance (10 m – 20 km objects and terrain).",
            "section": "results",
        }
    )
    return figs


def _map_figure(fdir, forms) -> dict:
    plt = F.pyplot()
    maps = forms["maps"]
    fig, axes = plt.subplots(1, len(OPTICAL_DEPTH_FORMS), figsize=(13, 3.8), squeeze=False)
    x = maps["x"]
    sx = np.sign(x) * (np.log10(np.abs(x)) + 9)  # signed log axis: ±(log10|x| + 9)
    for ax, form in zip(axes[0], OPTICAL_DEPTH_FORMS, strict=True):
        m = np.log10(np.clip(maps["maps"][form], 1e-9, 1e3))
        im = ax.pcolormesh(sx, np.log10(maps["distance"]), m, vmin=-9, vmax=1, cmap="magma", shading="auto")
        ax.set_title(METHODS[form].label, fontsize=9)
        ax.set_xlabel("sign(cΔz)·(log₁₀|cΔz| + 9)")
        ax.set_ylabel("log₁₀ D (m)")
    fig.colorbar(im, ax=axes[0].tolist(), label="log₁₀ relative error of τ (float32)")
    path = F.save_figure(fig, fdir / "optical_depth_error_maps.png")
    return {
        "file": f"figures/{path.name}",
        "caption": "Relative error of the float32 optical depth against a "
        f"float64 oracle over (c·Δz, D), c = {maps['c']} /m, b = {maps['b']} /m, camera at z = 0; grey: "
        "|Δz| > D (impossible) or τ outside float32 range (> 1e30). Values ≥ 10 (including ∞) saturate.",
        "section": "optical-depth",
    }


def _pareto_figure(fdir, case_docs, costs) -> dict:
    cost_of = {c["method"]: c["ns_per_pixel"] for c in costs}
    pts = []
    for row in ROWS:
        vals = [
            ap["metrics"]["rel_mse"]["value"]
            for d in case_docs
            for ap in d["approximations"]
            if ap["method"] == row.id
        ]
        pts.append({"x": cost_of[COST_KEYS[row.id]], "y": float(np.mean(vals)), "label": row.id})
    path = F.pareto_plot(fdir / "pareto.png", pts, "ns per pixel (fog pass)", "mean relMSE over cases")
    return {
        "file": f"figures/{path.name}",
        "caption": "Error (relMSE averaged over sun elevations and "
        "single/multiple scattering) vs measured cost of the fog pass.",
        "section": "costs",
    }


def _fit_growth_figure(fdir, case_docs) -> dict:
    series = []
    for row in ROWS:
        for tr in TRANSPORTS:
            xs, ys = [], []
            for d in case_docs:
                if d["parameters"].get("scattering") != tr:
                    continue
                ap = next(a for a in d["approximations"] if a["method"] == row.id)
                xs.append(d["parameters"]["sun_elevation_deg"])
                ys.append(ap["metrics"]["rmse"]["value"])
            series.append(
                {
                    "x": xs,
                    "y": ys,
                    "label": f"{row.id} ({tr})",
                    "ls": "-" if tr == "single" else "--",
                    "style": "line",
                }
            )
    path = F.line_plot(
        fdir / "rmse_vs_sun.png", "sun elevation (degrees)", "RMSE (sunsky units)", series, y_log=True
    )
    return {
        "file": f"figures/{path.name}",
        "caption": "RMSE per model vs sun elevation; solid: single "
        "scattering reference, dashed: multiple scattering.",
        "section": "results",
    }


# ============================================================================================== summary
NOTES = [
    "Radiance in the units of Mitsuba's `sunsky` (linear sRGB primaries); relative errors are per "
    "pixel and channel.",
    "Every model fogs the fog-free image L₀ of the same scene and transport (rendered separately), "
    "so the noise floors include L₀'s noise times T beside the fogged reference's own.",
    "The global fog of the terrain scene is bounded by a 120 km × 120 km × 5 km box (20 scale "
    "heights); the real-time model integrates over the same segment (sky pixels: to the box exit).",
    "The sun is the `sunsky` emitter's own sun (a finite `Sun` cannot share a scene with `sunsky` in "
    "the builder); it is outside the frame (azimuth 50° from the view direction).",
]


def sections(forms) -> list[dict]:
    rows = ["| form | worst relative error (float32) | non-finite where τ finite |", "|---|---|---|"]
    for t in forms["table"]:
        w = t["worst_rel_error"]
        rows.append(f"| {t['label']} | {'∞' if w is None else f'{w:.3g}'} | {t['non_finite_where_finite']} |")
    spec = [
        "| input | " + " | ".join(METHODS[f].label for f in OPTICAL_DEPTH_FORMS) + " | float64 oracle |",
        "|---|" + "---|" * len(OPTICAL_DEPTH_FORMS) + "---|",
    ]
    for label, _ in SPECIAL_INPUTS:
        vals = [forms["per_form"][f]["specials"][label][0] for f in OPTICAL_DEPTH_FORMS]
        truth = forms["per_form"][EXACT_FORM]["specials"][label][1]
        spec.append(f"| {label} | " + " | ".join(f"{v:.7g}" for v in vals) + f" | {truth:.7g} |")
    return [
        {
            "id": "method",
            "title": "Method",
            "text": (
                "The cheap model is the seed's global volumetric fog (000:2188-2246): optical depth τ = "
                "b·D·e^(−c·z₀)·(1 − e^(−cΔz))/(cΔz) along the view segment, T = e^(−τ), and the fog-free "
                "image L₀ blended with a fog colour: L = L₀·T + C·(1 − T). Colours: the sky's horizon "
                "average (seed 000:2247-2254), the same times the per-pixel phase 4π·p_HG(θ_sun, g), a "
                "single-scattering estimate albedo·(E_sun·p_HG + mean sky/ground radiance), and fitted "
                "artist parameters (b, c, C) or (b, c, C₀, C₁, g), fitted with Levenberg–Marquardt "
                "(optimistix) per sun elevation and per scattering order to relative residuals.\n\nGround "
                "truth: rtfit's path tracer with closed-form free flight through the exponential fog "
                "(`rtfit.reference.fog_integrator`; `volpathmis` with rtfit's Python medium where a scene "
                "has two fogs), "
                "single scattering (max_depth 2) and multiple scattering (unbounded, Russian roulette), "
                "point-sampled at pixel centres. The medium itself is checked first: an emissive backdrop "
                "through a purely absorbing medium equals e^(−τ) within noise (Checks)."
            ),
        },
        {
            "id": "optical-depth",
            "title": "Optical-depth forms in float32",
            "text": (
                f"Worst relative error over {forms['table'][0]['samples']} random inputs "
                "(z ∈ ±[1e-3, 1e4] m, "
                "D ∈ [0.1, 1e6] m, b ∈ [1e-6, 1] /m, c ∈ [1e-5, 10] /m, |Δz| ≤ min(D, 2e4)), against a "
                "float64 oracle (the stable form's NumPy run in float64, itself checked against mpmath "
                "quadrature in the "
                "tests):\n\n" + "\n".join(rows) + "\n\nSpecial inputs (τ):\n\n" + "\n".join(spec)
            ),
        },
        {
            "id": "discussion",
            "title": "Discussion",
            "placement": "after_results",
            "text": (
                "The blend model fogs the fog-free image, so it cannot represent the fog's shadowing of the "
                "light that reaches surfaces (sunlight through τ_sun ≈ b/(c·sin h) at sun elevation h): "
                "below the horizon every model, fitted or not, keeps an error well above the noise floor at "
                "low sun, and multiple scattering partly compensates it with in-scattered skylight (figures "
                "of residual vs elevation and distance). Toward the sun a constant colour cannot follow the "
                "forward-scattering halo; the phase-weighted colour can, and the fitted g lands near the "
                "medium's. The seed's horizon average times the phase, taken literally, counts the "
                "forward-scattered sunlight twice and overshoots toward the sun."
            ),
        },
    ]


def summary(case_docs, forms, checks) -> str:
    def rel(row_id, tr):
        vals = [
            ap["metrics"]["rel_mse"]["value"]
            for d in case_docs
            for ap in d["approximations"]
            if ap["method"] == row_id and d["parameters"].get("scattering") == tr
        ]
        return float(np.mean(vals)) if vals else float("nan")

    ex = forms["per_form"][EXACT_FORM]["worst"]
    sd = forms["per_form"]["seed"]
    tl = forms["per_form"]["taylor"]
    passed = sum(c["passed"] for c in checks)
    return (
        "Exponential height fog against path-traced participating media. The stable closed form keeps a "
        f"float32 relative error of at most {ex:.2g} over the whole domain "
        "(Δz = 0, tiny and huge c·Δz, c = 0, "
        f"b = 0, D up to 10⁶ m); the seed listing reaches {sd['worst']:.3g} (non-finite in "
        f"{sd['non_finite']} cases) and the engine Taylor form {tl['worst']:.3g} ({tl['non_finite']} "
        "non-finite).\n\n"
        f"Aerial perspective (mean relMSE over sun elevations, single / multiple scattering): fitted "
        f"constant colour {rel('fit-const', 'single'):.3g} / {rel('fit-const', 'multiple'):.3g}, fitted "
        f"phase-weighted colour {rel('fit-phase', 'single'):.3g} / {rel('fit-phase', 'multiple'):.3g}, true "
        f"b, c with the seed's horizon colour {rel('horizon-const', 'single'):.3g} / "
        f"{rel('horizon-const', 'multiple'):.3g}. {passed} of {len(checks)} checks passed."
    )


# ================================================================================================ bench
TAU_COST_PARAMS = {"b": 1e-3, "c": 0.01}
"""b, c (1/m) of the optical-depth cost rows (per-ray inputs: z₀, z₁, D of `random_domain`)."""

PASS_COSTS = {
    "const": (
        "fog pass, constant colour",
        "per pixel: RGB, camera z, d_z, distance in; τ, T, blend; RGB out",
    ),
    "phase": ("fog pass, colour + HG phase term", "as above plus cos θ_sun in and the phase-weighted colour"),
}
"""The measured `fog_pass` of each shading method (cost rows ``fog-pass-<method>``)."""


def _cost_inputs(n: int, Float, seed: int = 3):
    z0, z1, dist, _, _ = random_domain(n, seed)
    np_inputs = {"z0": z0, "z1": z1, "distance": dist}
    return np_inputs, {k: Float(v) for k, v in np_inputs.items()}


def _time_form(form: str, inputs: dict, n: int):
    method = METHODS[form]
    return time_drjit(
        lambda z0, z1, d: method.evaluate({"z0": z0, "z1": z1, "distance": d}, TAU_COST_PARAMS),
        tuple(inputs.values()),
        n,
    )


def cost_rows(ctx, cfg) -> list[dict]:
    """ns per ray of each optical-depth form, of the fog pass per shading method and of two fog volumes,
    beside the memory-traffic floor (the results' ``costs``)."""
    backend, Float = cost_backend(ctx.variant)
    n = cfg["cost_elements"]
    _, inputs = _cost_inputs(n, Float)
    note = "per ray: z₀, z₁, D in memory, τ out (float32)"
    rows = [
        cost_row(
            f"tau-{form}", f"optical depth: {METHODS[form].label}", backend, _time_form(form, inputs, n), note
        )
        for form in OPTICAL_DEPTH_FORMS
    ]
    rows += _pass_costs(n, Float, backend)
    floor_note = "the memory-bound floor of the optical-depth kernels"
    return [*rows, memory_floor_row(tuple(inputs.values()), n, backend, floor_note)]


def _pass_inputs(n: int, Float, seed: int = 5):
    rng = np.random.default_rng(seed)
    cols = [rng.uniform(0, 1, n).astype(np.float32) for _ in range(3)]
    z0 = rng.uniform(0, 100, n).astype(np.float32)
    dz = rng.uniform(-1, 1, n).astype(np.float32)
    dist = np.where(rng.random(n) < 0.3, np.inf, 10 ** rng.uniform(0, 5, n)).astype(np.float32)
    cs = rng.uniform(-1, 1, n).astype(np.float32)
    return tuple(Float(a) for a in (*cols, z0, dz, dist, cs))


def _pass_costs(n, Float, backend) -> list[dict]:
    r, g, b, z0, dz, dist, cs = _pass_inputs(n, Float)
    phase_args = {"const": {}, "phase": {"phase_colour": (0.1, 0.1, 0.1), "g": 0.6}}
    rows = []
    for method, (label, note) in PASS_COSTS.items():
        kw = phase_args[method]

        def one_pass(*a, kw=kw):
            cos_sun = a[6] if kw else None
            return fog_pass(a[:3], a[3], a[4], a[5], 2e-4, 0.004, (0.2, 0.25, 0.3), cos_sun=cos_sun, **kw)

        args = (r, g, b, z0, dz, dist, cs) if kw else (r, g, b, z0, dz, dist)
        rows.append(cost_row(f"fog-pass-{method}", label, backend, time_drjit(one_pass, args, n), note))
    # two fog volumes (ray–ellipsoid and ray–box, oriented gradients)
    vols = [
        FogVolume(center=(0, 100, 10), half_size=(50, 30, 20), ellipsoid=True, density=0.01, falloff=0.05),
        FogVolume(
            center=(40, 200, 20),
            half_size=(40, 40, 30),
            density=0.005,
            falloff=0.02,
            gradient=(0.5, 0.0, 1.0),
        ),
    ]
    o = (dr.zeros(Float, n), dr.zeros(Float, n), dr.zeros(Float, n) + 2.0)
    dxy = dr.sqrt(dr.maximum(1.0 - dz * dz, 0.0))
    dirs = (dxy * 0.3, dxy * 0.954, dz)

    def vol_pass(dist_):
        taus = fog_volumes_optical_depth(o, dirs, dist_, vols)
        return dr.exp(-(taus[0] + taus[1]))

    label = "two fog volumes (intersection + τ + T)"
    note = "per pixel, ray–ellipsoid and ray–box in local frames, T out"
    return [*rows, cost_row("volumes-2", label, backend, time_drjit(vol_pass, (dist,), n), note)]


def bench(ctx) -> list[dict]:
    """Rays/s of each optical-depth form on Dr.Jit vs the same kernel text on NumPy
    (``method(NUMPY_OPS, inputs, params)``), then the fog passes and the reference's samples/s
    (rtfit_fogpath, beside volpathmis with the Python fog medium and Mitsuba's grid)."""
    backend, n = bench_backend(ctx)
    Float = backend_float(backend)
    np_inputs, inputs = _cost_inputs(n, Float)
    base = memory_baseline(tuple(inputs.values()), n)
    rows = []
    for form in OPTICAL_DEPTH_FORMS:
        method = METHODS[form]
        t_dr = _time_form(form, inputs, n)
        with np.errstate(all="ignore"):  # NumPy evaluates both branches of every select
            t_np = time_numpy(
                lambda z0, z1, d, method=method: method(
                    NUMPY_OPS, {"z0": z0, "z1": z1, "distance": d}, TAU_COST_PARAMS
                ),
                tuple(np_inputs.values()),
                n,
            )
        rows.append(comparison_row(f"optical depth: {method.label}", backend, t_dr, t_np, base, unit="ray"))
    rows.append(baseline_row(base, backend, "memory baseline (fma of the 3 inputs)", unit="ray"))
    for row in _pass_costs(n, Float, backend):
        rows.append(
            {
                "what": row["label"],
                "backend": backend,
                "elements": n,
                "drjit_Mray_s": row["pixels_per_second"] / 1e6,
                "numpy_Mray_s": None,
                "drjit/numpy": None,
                "ns_per_ray": row["ns_per_pixel"],
                "vs_memory_floor": None,
            }
        )
    rows += _bench_reference(ctx)
    return rows


BENCH_MEDIA = (
    ("reference", "rtfit_fogpath: closed-form free flight and transmittance (the reference)"),
    ("segment", "rtfit fog medium, per-segment majorant (volpathmis; the reference of session 4)"),
    ("box", "rtfit fog medium, box-wide majorant (the estimator before issue 21)"),
    ("grid", "Mitsuba heterogeneous + gridvolume of the same density"),
    ("nofog", "Mitsuba path on the scene without fog (the floor: surfaces and emitters only)"),
)
"""The media of the reference bench rows: rtfit's estimator beside what a user would otherwise run."""


def bench_scene_dict(mi, scene, medium: str) -> dict:
    """The Mitsuba scene of ``scene`` with its fog as one of `BENCH_MEDIA`."""
    if medium == "reference":
        return mitsuba_scene_dict(mi, scene)
    if medium == "nofog":
        depth = mitsuba_scene_dict(mi, scene, fog_path=False)["integrator"]["max_depth"]
        d = mitsuba_scene_dict(mi, dataclasses.replace(scene, media=()))
        d["integrator"] = {"type": "path", "max_depth": depth}
        return d
    d = mitsuba_scene_dict(mi, scene, fog_path=False)
    fog = scene.media[0]
    if medium == "box":
        d["medium0"] = fog_medium_dict(mi, fog, segment_majorant=False)
    elif medium == "grid":
        d["medium0"] = grid_medium_dict(mi, fog)
    return d


def _bench_reference(ctx) -> list[dict]:
    """Samples/s of the terrain reference pass (sun 30°, single and multiple scattering) with each of
    `BENCH_MEDIA`, side by side in one process: one warm-up pass, then the best of two timed passes."""
    res = (64, 32) if ctx.quick else (256, 128)
    spp = 64 if ctx.quick else 256
    samples = res[0] * res[1] * spp
    rows = []
    mi = use_variant(ctx.variant)
    for tr in TRANSPORTS:
        scene = terrain_scene(30.0, tr, res)
        rates = {}
        for medium, label in BENCH_MEDIA:
            ms = load_dict(mi, bench_scene_dict(mi, scene, medium))
            radiance_pass(mi, ms, spp, 0)
            what = f"bench height-fog, {tr} scattering, {medium}, pass"
            t = min(
                check_finite(radiance_pass(mi, ms, spp, k + 1), f"{what} {k + 1}").seconds for k in range(2)
            )
            rates[medium] = samples / t
            rows.append(
                {
                    "what": f"reference pass, {tr} scattering ({res[0]}×{res[1]}, {spp} spp): {label}",
                    "backend": ctx.variant,
                    "elements": samples,
                    "drjit_Mray_s": samples / t / 1e6,
                    "numpy_Mray_s": None,
                    "drjit/numpy": None,
                    "ns_per_ray": t / samples * 1e9,
                    "vs_memory_floor": None,
                }
            )
        for row, (medium, _) in zip(rows[-len(BENCH_MEDIA) :], BENCH_MEDIA, strict=True):
            row["vs_native_grid"] = rates[medium] / rates["grid"]
            row["vs_box_majorant"] = rates[medium] / rates["box"]
            row["vs_no_fog"] = rates[medium] / rates["nofog"]
    return rows
