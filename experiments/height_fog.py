"""Experiment ``height-fog``: exponential height fog (closed-form optical depth, fog colour) vs path-traced media.

Parts (docs/height-fog.md):

1. **Reference check** (``scenes/library/fog_transmittance.toml``): an emissive backdrop of radiance 1 seen
   through a purely absorbing exponential fog box (tilted, shifted gradient) must read e^(−τ) per pixel,
   τ from the closed form in float64 — z-scores of unit spread check the Python medium itself.
2. **Optical-depth forms** (no rendering): float32 relative error of the stable form, the seed listing
   (000:2226-2240) and the engine Taylor form against a float64 oracle over the (c·Δz, D) domain (maps,
   worst cases), and their cost per ray beside NumPy.
3. **Aerial perspective** (``scenes/library/fog_terrain.toml``): terrain with objects at 10 m–20 km under
   Mitsuba's ``sunsky`` with its own sun, inside scattering height fog (albedo 0.9, HG g = 0.6), single
   (``volpathmis`` max_depth 2) and multiple scattering (unbounded), per sun elevation. The cheap model
   L = L₀·T + C·(1 − T) on the fog-free image L₀ (the same scene without fog and the same transport) with
   (a) the true b, c and colours from the sky (seed's horizon average, with and without per-pixel phase;
   a single-scattering estimate), (b) fitted artist parameters (b, c, C) and (b, c, C₀, C₁, g) with a
   phase-weighted colour. Residuals vs view elevation and distance; fitted parameters as JSON.
4. **Fog volumes** (``scenes/library/fog_volumes.toml``): an ellipsoid and a rotated box of fog with their
   own b, c and oriented gradients over the terrain; the volume model with its true b, c and a fitted
   constant colour per volume.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .jobs import Job

SUN_AZIMUTH_DEG = 50.0  # from the view direction (+y) towards +x: the sun is outside the frame
ELEVATIONS_FULL = (5.0, 15.0, 30.0, 60.0)
ELEVATIONS_QUICK = (10.0, 40.0)
TRANSPORTS = ("single", "multiple")
MODELS = ("horizon-const", "horizon-phase", "single-scatter", "fit-const", "fit-phase")
LABELS = {
    "horizon-const": "true b, c; colour = sky horizon average",
    "horizon-phase": "true b, c; horizon average × 4π·HG phase (seed)",
    "single-scatter": "true b, c; colour = albedo·(E_sun·p + L̄_sky)",
    "fit-const": "fitted b, c, constant colour",
    "fit-phase": "fitted b, c, colour C₀ + C₁·4π·HG(g)",
    "volume-true": "fog volumes, true b, c; fitted colour",
}


def configure(quick: bool, spp: int | None) -> dict:
    return {
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
    }


# ----------------------------------------------------------------------------------------- scenes
def sun_direction(elevation_deg: float, azimuth_deg: float = SUN_AZIMUTH_DEG) -> tuple:
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))


def terrain_scene(
    elevation_deg: float, transport: str, resolution, fog: bool = True, name: str = "fog_terrain"
):
    """The library terrain at one sun elevation; ``transport`` "single" (direct) or "multiple" (global)."""
    from rtfit.scenes import library_path, load_scene

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
    from rtfit.scenes import library_path, load_scene

    base = load_scene(library_path("fog_transmittance"))
    camera = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(base, camera=camera)


def volume_from_medium(medium, colour=(1.0, 1.0, 1.0)):
    """The real-time `FogVolume` of a scene `ExponentialFog` (same region, gradient and density)."""
    from rtfit.realtime.fog import FogVolume
    from rtfit.reference.fog_media import region_matrix

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


def segment_geometry(scene, gb, medium) -> dict:
    """Per-pixel segment of the camera ray inside ``medium``'s region (float64): heights along the gradient
    at entry and exit, length, and the ray's elevation and hit distance (inf: sky)."""
    vol = volume_from_medium(medium)
    o = np.asarray(scene.camera.origin, dtype=np.float64)
    d = gb.view_dir.astype(np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    dist = np.where(gb.mask, gb.depth.astype(np.float64), np.inf)
    t_in, t_out = _box_interval(o, d, vol)
    t0 = np.maximum(t_in, 0.0)
    t1 = np.minimum(t_out, dist)
    seg = np.maximum(t1 - t0, 0.0)
    t0 = np.where(seg > 0, t0, 0.0)
    t1 = np.where(seg > 0, t1, 0.0)
    g = np.asarray(vol.gradient)
    h_o = (o - np.asarray(vol.gradient_origin)) @ g
    h_d = d @ g
    return {
        "z0": h_o + t0 * h_d,
        "z1": h_o + t1 * h_d,
        "length": seg,
        "elevation_deg": np.degrees(np.arcsin(np.clip(d[..., 2], -1, 1))),
        "distance": dist,
        "view_dir": d,
    }


def _box_interval(o, d, vol):
    """Slab test in the volume's local frame (float64, NumPy): entry and exit ray parameters."""
    rot = np.asarray(vol.rotation)
    half = np.asarray(vol.half_size)
    lo = ((o - np.asarray(vol.center)) @ rot) / half
    ld = (d @ rot) / half
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-1.0 - lo) / ld
        t2 = (1.0 - lo) / ld
    par = np.abs(ld) < 1e-300
    inside = np.abs(lo) <= 1.0
    tmin = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return tmin.max(axis=-1), tmax.min(axis=-1)


# ------------------------------------------------------------------------------------------- jobs
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
    from rtfit.reference import ReferenceCache, ReferenceRequest, render_gbuffer
    from rtfit.scenes import parse_scene_text

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
    from rtfit.reference.fog_media import sky_statistics
    from rtfit.scenes import parse_scene_text

    scene = parse_scene_text(scene_toml)
    return sky_statistics(scene.environment(), variant)


# ----------------------------------------------------------------------------------- model (JAX)
def _tau_jax(b, c, z0, z1, length):
    """The stable closed form in JAX float64 (differentiable in b, c): b·D·e^(−c·z_min)·φ(c·|Δz|)."""
    import jax.numpy as jnp

    zmin = jnp.minimum(z0, z1)
    y = c * jnp.abs(z1 - z0)
    ys = jnp.where(y < 1e-4, 1.0, y)
    phi = jnp.where(y < 1e-4, 1.0 - y / 2 + y * y / 6, -jnp.expm1(-ys) / ys)
    return b * length * jnp.exp(-c * zmin) * phi


def _hg_jax(cos_t, g):
    import jax.numpy as jnp

    den = 1.0 + g * g - 2.0 * g * cos_t
    return (1.0 - g * g) / (den * jnp.sqrt(den))  # 4π·p_HG: mean 1 over the sphere


def fog_residual(p, args):
    """Relative residual of L₀·T + C(θ)·(1 − T) against the reference (JAX; module level: jitted once)."""
    import jax.numpy as jnp

    z0, z1, length, cos_sun, l0, ref, scale, phase_on = args
    tau = _tau_jax(p["b"], p["c"], z0, z1, length)
    t = jnp.exp(-tau)[:, None]
    colour = jnp.stack([p["r0"], p["g0"], p["b0"]])[None, :]
    colour1 = jnp.stack([p.get("r1", 0.0), p.get("g1", 0.0), p.get("b1", 0.0)])[None, :]
    gg = p.get("g", 0.0)
    colour = colour + phase_on * colour1 * _hg_jax(cos_sun, gg)[:, None]
    model = l0 * t + colour * (1.0 - t)
    return ((model - ref) / scale).reshape(-1)


def fit_fog_job(z0, z1, length, cos_sun, l0, ref, scale, phase: bool, b0: float, c0: float, colour0) -> dict:
    """Job: fit (b, c, C) or (b, c, C₀, C₁, g) to one reference image (arrays flattened to pixels)."""
    from rtfit.fitting import Param, fit_least_squares

    params = {"b": Param(b0, b0 * 1e-3, b0 * 1e3), "c": Param(c0, c0 * 1e-3, c0 * 1e2)}
    for k, name in enumerate(("r0", "g0", "b0")):
        params[name] = Param(max(float(colour0[k]), 1e-4), 0.0, 100.0)
    if phase:
        for name in ("r1", "g1", "b1"):
            params[name] = Param(0.01, 0.0, 100.0)
        params["g"] = Param(0.5, -0.95, 0.95)
    result = fit_least_squares(
        fog_residual, params, args=(z0, z1, length, cos_sun, l0, ref, scale, 1.0 if phase else 0.0)
    )
    return result.to_dict()


def model_image(geom, l0, b, c, colour0, colour1=None, g=0.0) -> np.ndarray:
    """L₀·T + C(θ)·(1 − T) with the real-time kernels (rtfit.realtime.fog, float32 Dr.Jit)."""
    from rtfit.realtime import fog

    tau = np.asarray(
        fog.height_fog_optical_depth(
            geom["z0"].astype(np.float32),
            geom["z1"].astype(np.float32),
            geom["length"].astype(np.float32),
            b,
            c,
        ),
        dtype=np.float64,
    )
    t = np.exp(-tau)
    colour = np.broadcast_to(np.asarray(colour0, dtype=np.float64), l0.shape).copy()
    if colour1 is not None:
        ph = 4 * math.pi * np.asarray(fog.phase_hg(geom["cos_sun"].astype(np.float32), g), dtype=np.float64)
        colour = colour + np.asarray(colour1)[None, None, :] * ph[..., None]
    return fog.apply_fog(l0, t, colour)


# ----------------------------------------------------------------------------------- the experiment
def run(ctx) -> dict:
    from rtfit.realtime import set_default_backend
    from rtfit.scenes import scene_hash, scene_to_toml

    from . import height_fog_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")
    res = cfg["resolution"]
    common = dict(
        pass_spp=cfg["pass_spp"],
        seed=ctx.seed,
        variant=ctx.variant,
        cache_dir=str(ctx.cache_dir),
        progress=ctx.progress,
    )

    scenes, jobs = {}, []
    chk = check_scene(cfg["check_resolution"])
    scenes["check"] = chk
    jobs.append(
        Job(
            "rtfit.experiments.height_fog:render_job",
            dict(
                scene_toml=scene_to_toml(chk), spp=cfg["check_spp"], gbuffer_of=scene_to_toml(chk), **common
            ),
            label="check",
        )
    )
    # the same check with the fog restricted to the ellipsoid inscribed in the box (a fog volume)
    chk_e = dataclasses.replace(
        chk, name=f"{chk.name}-ellipsoid", media=(dataclasses.replace(chk.media[0], ellipsoid=True),)
    )
    scenes["check-ellipsoid"] = chk_e
    jobs.append(
        Job(
            "rtfit.experiments.height_fog:render_job",
            dict(
                scene_toml=scene_to_toml(chk_e),
                spp=cfg["check_spp"],
                gbuffer_of=scene_to_toml(chk_e),
                **common,
            ),
            label="check-ellipsoid",
        )
    )
    for e in cfg["sun_elevations_deg"]:
        for tr in TRANSPORTS:
            fogged = terrain_scene(e, tr, res)
            clear = terrain_scene(e, tr, res, fog=False)
            scenes[f"e{e:g}-{tr}"] = fogged
            scenes[f"e{e:g}-{tr}-nofog"] = clear
            jobs.append(
                Job(
                    "rtfit.experiments.height_fog:render_job",
                    dict(scene_toml=scene_to_toml(fogged), spp=cfg["spp"], **common),
                    label=f"e{e:g}-{tr}",
                )
            )
            jobs.append(
                Job(
                    "rtfit.experiments.height_fog:render_job",
                    dict(
                        scene_toml=scene_to_toml(clear),
                        spp=cfg["spp"],
                        gbuffer_of=scene_to_toml(clear) if tr == "single" else None,
                        **common,
                    ),
                    label=f"e{e:g}-{tr}-nofog",
                )
            )
    if cfg["volumes"]:
        e = cfg["sun_elevations_deg"][-1]
        vol = terrain_scene(e, "multiple", res, name="fog_volumes")
        vclear = terrain_scene(e, "multiple", res, fog=False, name="fog_volumes")
        scenes["volumes"], scenes["volumes-nofog"] = vol, vclear
        jobs.append(
            Job(
                "rtfit.experiments.height_fog:render_job",
                dict(scene_toml=scene_to_toml(vol), spp=cfg["spp"], **common),
                label="volumes",
            )
        )
        jobs.append(
            Job(
                "rtfit.experiments.height_fog:render_job",
                dict(
                    scene_toml=scene_to_toml(vclear),
                    spp=cfg["spp"],
                    gbuffer_of=scene_to_toml(vclear),
                    **common,
                ),
                label="volumes-nofog",
            )
        )
    sky_jobs = [
        Job(
            "rtfit.experiments.height_fog:sky_job",
            dict(scene_toml=scene_to_toml(scenes[f"e{e:g}-single"]), variant=ctx.variant),
            label=f"sky-e{e:g}",
        )
        for e in cfg["sun_elevations_deg"]
    ]
    ctx.log(f"rendering {len(jobs)} references")
    rendered = dict(
        zip([j.label for j in jobs + sky_jobs], ctx.executor.map(jobs + sky_jobs, desc="references"))
    )
    skies = {f"e{e:g}": rendered.pop(f"sky-e{e:g}") for e in cfg["sun_elevations_deg"]}

    # Geometry per sun elevation (the fog-free single-scattering scene carries the G-buffer).
    geoms = {}
    for e in cfg["sun_elevations_deg"]:
        sc = scenes[f"e{e:g}-single"]
        gb = rendered[f"e{e:g}-single-nofog"]["gbuffer"]
        geom = segment_geometry(sc, gb, sc.media[0])
        geom["cos_sun"] = geom["view_dir"] @ np.asarray(sun_direction(e))
        geoms[f"e{e:g}"] = geom

    # Fits (independent jobs).
    fit_jobs = []
    for e in cfg["sun_elevations_deg"]:
        geom = geoms[f"e{e:g}"]
        medium = scenes[f"e{e:g}-single"].media[0]
        for tr in TRANSPORTS:
            ref = rendered[f"e{e:g}-{tr}"]["image"]
            l0 = rendered[f"e{e:g}-{tr}-nofog"]["image"].mean
            flat = _flat_args(geom, l0, ref.mean)
            for phase in (False, True):
                fit_jobs.append(
                    Job(
                        "rtfit.experiments.height_fog:fit_fog_job",
                        dict(
                            **flat,
                            phase=phase,
                            b0=medium.density,
                            c0=medium.falloff,
                            colour0=skies[f"e{e:g}"]["horizon"],
                        ),
                        label=f"e{e:g}-{tr}-{'phase' if phase else 'const'}",
                    )
                )
    ctx.log(f"fitting {len(fit_jobs)} fog models")
    fits = dict(zip([j.label for j in fit_jobs], ctx.executor.map(fit_jobs, desc="fits")))
    hashes = {k: scene_hash(v) for k, v in scenes.items()}
    return rep.assemble(ctx, cfg, scenes, rendered, skies, geoms, fits, hashes)


def _flat_args(geom, l0, ref) -> dict:
    """Pixel-flattened fit inputs; residual scale: 2 % of the reference plus 1 % of its mean (relative
    error, not dominated by the bright sky)."""
    scale = 0.02 * np.abs(ref) + 0.01 * float(np.mean(np.abs(ref)))
    return dict(
        z0=geom["z0"].reshape(-1),
        z1=geom["z1"].reshape(-1),
        length=geom["length"].reshape(-1),
        cos_sun=geom["cos_sun"].reshape(-1),
        l0=l0.reshape(-1, 3),
        ref=ref.reshape(-1, 3),
        scale=scale.reshape(-1, 3),
    )


def bench(ctx) -> list[dict]:
    from . import height_fog_report as rep

    return rep.bench(ctx)
