"""Experiment ``irradiance-bases``: ambient cube and spherical harmonics against path-traced irradiance.

For each distant environment (constant, disc suns, Mitsuba ``sunsky`` at several sun elevations, a
high-contrast studio map, a low-contrast overcast sky, measured light probes) the ground truth is Mitsuba's
irradiance at a Fibonacci sphere of normals (`rtfit.reference.estimators.irradiance_pass`: emitter
sampling + cosine sampling, MIS) and Mitsuba's point-sampled image of a white diffuse unit sphere under the
environment (`direct` integrator, the integrator rule's choice for one convex reflector). Both are checked
against an independent dense quadrature of the same map (`rtfit.reference.environments`) and the white
furnace (constant environment → π·L).

A sun cannot share a Mitsuba scene with a map (one environment emitter per scene): sun and map are rendered
as two references and added (irradiance is linear in the emitters; means add, variances add).

Bases (`rtfit.realtime.irradiance`), all built from the environment itself as an engine's baker would:

* ``cube-valve``      ambient cube holding the irradiance at the six axes (Valve, seed 000:2471-2501);
* ``cube-nnls``       ambient cube fitted by non-negative least squares to the irradiance over the sphere;
* ``sh-l1``           4 SH coefficients per channel, cosine-convolved (linear in n);
* ``sh-l1-geomerics`` Geomerics' non-negative L1 reconstruction from the same 4 coefficients;
* ``sh-l2``           9 SH coefficients per channel (Ramamoorthi & Hanrahan);
* ``sh-l2-hann``, ``sh-l2-lanczos``  L2 with a fixed ringing window;
* ``sh-l2-lambda``    L2 with Sloan's window 1/(1 + λl²(l + 1)²), λ fitted per environment as the smallest
  value that removes negative irradiance;
* ``quadrature``      the dense quadrature itself (exact up to quadrature error: must sit at the noise floor).

The SH coefficients of a map come from `sh_project_latlong` (the bilinear function Mitsuba sees, 2×
supersampled); a disc sun's from the closed form `sh9_from_disk`; cube-valve's axis irradiance and the
NNLS targets from the quadrature.
"""

from __future__ import annotations

import hashlib
import math
import time

import numpy as np

from .jobs import Job

METHODS = (
    "cube-valve",
    "cube-nnls",
    "sh-l1",
    "sh-l1-geomerics",
    "sh-l2",
    "sh-l2-hann",
    "sh-l2-lanczos",
    "sh-l2-lambda",
    "quadrature",
)
LABELS = {
    "cube-valve": "Ambient cube (Valve: axis samples)",
    "cube-nnls": "Ambient cube (NNLS optimal)",
    "sh-l1": "SH L1 (4)",
    "sh-l1-geomerics": "SH L1, Geomerics non-linear",
    "sh-l2": "SH L2 (9)",
    "sh-l2-hann": "SH L2, Hann window",
    "sh-l2-lanczos": "SH L2, Lanczos window",
    "sh-l2-lambda": "SH L2, fitted λ window",
    "quadrature": "Dense quadrature (exact)",
}
FLOATS = {
    "cube-valve": 18,
    "cube-nnls": 18,
    "sh-l1": 12,
    "sh-l1-geomerics": 12,
    "sh-l2": 27,
    "sh-l2-hann": 27,
    "sh-l2-lanczos": 27,
    "sh-l2-lambda": 27,
    "quadrature": None,
}

SUNSKY_ELEVATIONS_FULL = (2.0, 10.0, 30.0, 60.0, 90.0)
SUNSKY_ELEVATIONS_QUICK = (10.0, 60.0)
SUN_SIZES_FULL = (0.27, 2.0, 10.0, 20.0)
SUN_SIZES_QUICK = (0.27, 10.0)
PROBES_FULL = ("grace", "grace-ict", "uffizi", "ennis", "pisa", "wells")
PROBES_QUICK = ("grace",)


def configure(quick: bool, spp: int | None) -> dict:
    return {
        "environments": environment_names(quick),
        "normals": 384 if quick else 2048,
        "probe_spp": spp or (4096 if quick else 32768),
        "probe_pass_spp": 1024 if quick else 4096,
        "resolution": 40 if quick else 128,
        "spp": 512 if quick else 4096,
        "pass_spp": 128 if quick else 1024,
        "map_height": 32 if quick else 128,
        "probe_height": 64 if quick else None,  # None: the probe file's own resolution
        "quadrature_min_rows": 256 if quick else 512,  # quadrature supersampling s = max(2, ceil(rows / H))
        "map_supersample": 2,
        "sun_elevation_deg": 45.0,
    }


def environment_names(quick: bool) -> list[str]:
    """The default environments. Measured probes whose files are absent (no ``../shared/probes``, no
    ``$RTFIT_PROBE_DIR``) are left out here and named in the report's notes (`missing_probes`); asking for
    one explicitly (a sweep override) still fails with the file's path."""
    from rtfit.reference.environments import probe_available

    suns = SUN_SIZES_QUICK if quick else SUN_SIZES_FULL
    els = SUNSKY_ELEVATIONS_QUICK if quick else SUNSKY_ELEVATIONS_FULL
    probes = [p for p in (PROBES_QUICK if quick else PROBES_FULL) if probe_available(p)]
    return (
        ["constant"]
        + [f"sun-{a:g}" for a in suns]
        + [f"sunsky-{e:g}" for e in els]
        + ["studio", "overcast"]
        + [f"probe-{p}" for p in probes]
    )


def missing_probes(quick: bool) -> list[str]:
    """Default probes left out of this run because their files are absent."""
    from rtfit.reference.environments import probe_available

    return [p for p in (PROBES_QUICK if quick else PROBES_FULL) if not probe_available(p)]


def supersample_for(env, cfg: dict) -> int:
    """Quadrature supersampling of a map per axis: at least 2, and at least ``quadrature_min_rows`` rows."""
    if env.radiance_map is None:
        return 1
    return max(2, math.ceil(cfg["quadrature_min_rows"] / env.radiance_map.shape[0]))


def make_environment(name: str, cfg: dict, mi=None):
    """Build (bake or load) the environment ``name`` (see `environment_names`)."""
    from rtfit.reference import environments as envs

    h = int(cfg["map_height"])
    if name == "constant":
        return envs.constant_environment(1.0)
    if name.startswith("sun-"):
        return envs.sun_environment(float(name[4:]), cfg["sun_elevation_deg"])
    if name.startswith("sunsky-"):
        if mi is None:
            from rtfit.reference import use_variant

            mi = use_variant("llvm_ad_rgb")
        return envs.sunsky_environment(mi, float(name[7:]), h, 2 * h)
    if name == "studio":
        return envs.map_environment(
            "studio", "studio (3 softboxes on black)", "studio", envs.studio_map(h, 2 * h)
        )
    if name == "overcast":
        return envs.map_environment(
            "overcast", "overcast (CIE sky, ground ρ = 0.2)", "overcast", envs.overcast_map(h, 2 * h)
        )
    if name.startswith("probe-"):
        return envs.probe_environment(name[6:], cfg["probe_height"])
    raise ValueError(f"unknown environment {name!r}")


# ------------------------------------------------------------------------------------------ scenes
def sky_scene(env, map_file: str | None, resolution: int):
    """The library sphere scene with the environment's map (or constant) as its only light."""
    import dataclasses

    from rtfit.scenes import ConstantEnv, EnvMap, library_path, load_scene

    base = load_scene(library_path("irradiance_sphere"))
    light = ConstantEnv(radiance=env.constant) if env.constant is not None else EnvMap(file=map_file)
    cam = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(base, name=f"{base.name}-{env.name}", camera=cam, lights=(light,))


def sun_scene(env, resolution: int):
    import dataclasses

    from rtfit.scenes import Sun, library_path, load_scene

    base = load_scene(library_path("irradiance_sphere_sun"))
    s = env.sun
    cam = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(
        base,
        name=f"{base.name}-{env.name}",
        camera=cam,
        lights=(
            Sun(direction=s.direction, irradiance=s.irradiance, angular_radius_deg=s.angular_radius_deg),
        ),
    )


def sunsky_scene(env, resolution: int):
    """Mitsuba's own sunsky (sun and sky in one emitter): the check of the baked sky + disc sun."""
    import dataclasses

    from rtfit.scenes import SunSky, library_path, load_scene

    base = load_scene(library_path("irradiance_sphere_sunsky"))
    cam = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(
        base, name=f"{base.name}-{env.name}", camera=cam, lights=(SunSky(sun_direction=env.sun.direction),)
    )


# -------------------------------------------------------------------------------------------- job
def render_environment(
    name: str, cfg: dict, seed: int, variant: str, cache_dir: str, progress: bool = False
) -> dict:
    """Job: bake/load one environment, render its Mitsuba references, integrate its quadrature."""
    from pathlib import Path

    from rtfit.realtime.irradiance import fibonacci_sphere
    from rtfit.reference import ReferenceCache, ReferenceRequest, render_gbuffer, use_variant
    from rtfit.reference import environments as envs
    from rtfit.scenes import parse_scene_text, scene_hash, scene_to_toml

    mi = use_variant(variant)
    t0 = time.perf_counter()
    env = make_environment(name, cfg, mi)
    bake_s = time.perf_counter() - t0
    cache = ReferenceCache(cache_dir)
    normals = fibonacci_sphere(cfg["normals"])
    n32 = normals.astype(np.float32)
    n32 /= np.linalg.norm(n32, axis=1, keepdims=True)
    parts, hashes = [], {}
    scenes = []
    if env.has_sky:
        map_file = None
        if env.radiance_map is not None:
            key = f"{name}-{env.radiance_map.shape[0]}-{hashlib.sha256(env.radiance_map.tobytes()).hexdigest()[:16]}"
            map_file = str(envs.write_map_exr(env.radiance_map, Path(cache_dir) / "envmaps" / f"{key}.exr"))
        scenes.append(("sky", sky_scene(env, map_file, cfg["resolution"])))
    if env.sun is not None:
        scenes.append(("sun", sun_scene(env, cfg["resolution"])))
    for part, scene0 in scenes:
        scene = parse_scene_text(scene_to_toml(scene0))
        hashes[part] = scene_hash(scene)
        probes = cache.get(
            ReferenceRequest(
                scene=scene,
                spp=cfg["probe_spp"],
                pass_spp=cfg["probe_pass_spp"],
                seed=seed,
                variant=variant,
                quantity="irradiance",
                points=n32,
                normals=n32,
            ),
            progress=progress,
            label=f"{name} {part} probes",
        )
        image = cache.get(
            ReferenceRequest(
                scene=scene, spp=cfg["spp"], pass_spp=cfg["pass_spp"], seed=seed, variant=variant
            ),
            progress=progress,
            label=f"{name} {part} image",
        )
        parts.append({"part": part, "probes": probes, "image": image})
    gb = render_gbuffer(scenes[0][1], variant)
    own = None
    if env.kind == "sunsky":  # Mitsuba's own sunsky, one emitter: checks the bake
        scene = parse_scene_text(scene_to_toml(sunsky_scene(env, cfg["resolution"])))
        own = cache.get(
            ReferenceRequest(
                scene=scene,
                spp=cfg["probe_spp"],
                pass_spp=cfg["probe_pass_spp"],
                seed=seed,
                variant=variant,
                quantity="irradiance",
                points=n32,
                normals=n32,
            ),
            progress=progress,
            label=f"{name} mitsuba sunsky probes",
        )
    t0 = time.perf_counter()
    ss = supersample_for(env, cfg)
    qb = quadrature_backend(variant)
    quad = envs.irradiance_quadrature(env, n32, ss, qb)
    mask = gb.mask & ~gb.emitter
    quad_img = envs.irradiance_quadrature(env, gb.normal[mask], ss, qb)
    quad_s = time.perf_counter() - t0
    return {
        "env": env,
        "normals": n32.astype(np.float64),
        "parts": parts,
        "gbuffer": gb,
        "mask": mask,
        "quadrature": quad,
        "quadrature_image": quad_img,
        "sunsky_own": own,
        "hashes": hashes,
        "bake_seconds": bake_s,
        "quadrature_seconds": quad_s,
    }


# ------------------------------------------------------------------------------------------ bases
def quadrature_backend(variant: str) -> str | None:
    """Dense quadrature on the GPU (Dr.Jit CUDA, float64) for CUDA runs, else NumPy (as fast on a CPU)."""
    return "cuda" if variant.startswith("cuda") else None


def build_bases(env, cfg: dict, fit_normals: int = 2048, backend: str | None = None) -> dict:
    """Every basis's coefficients for ``env`` (what an engine would bake), with the time each took."""
    from rtfit.realtime import irradiance as ir
    from rtfit.reference import environments as envs

    out: dict = {"timing_ms": {}}
    t0 = time.perf_counter()
    sh = np.zeros((9, 3))
    if env.constant is not None:
        sh[0] = np.asarray(env.constant) * math.sqrt(4 * math.pi)  # ∫ L Y00 = L·4π·Y00 = L·√(4π)
    if env.radiance_map is not None:
        sh += ir.sh_project_latlong(env.radiance_map, cfg["map_supersample"])
    if env.sun is not None:
        s = env.sun
        sh += ir.sh9_from_disk(s.direction, math.radians(s.angular_radius_deg), np.asarray(s.irradiance))
    out["timing_ms"]["sh-projection"] = 1e3 * (time.perf_counter() - t0)
    out["sh"] = sh
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
    t0 = time.perf_counter()
    ss = supersample_for(env, cfg)
    out["cube_valve"] = ir.ambient_cube_from_axes(envs.irradiance_quadrature(env, axes, ss))
    out["timing_ms"]["cube-valve"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    fn = ir.fibonacci_sphere(fit_normals)
    target = envs.irradiance_quadrature(env, fn, ss, backend)
    out["cube_nnls"], out["cube_nnls_rms"] = ir.fit_ambient_cube_nnls(fn, target)
    out["timing_ms"]["cube-nnls"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    out["lambda"] = ir.fit_window_lambda(sh)
    out["timing_ms"]["lambda-fit"] = 1e3 * (time.perf_counter() - t0)
    return out


def evaluate_method(method: str, bases: dict, normals, quadrature=None):
    """Irradiance (N, 3) of ``method`` at ``normals`` (N, 3)."""
    from rtfit.realtime import irradiance as ir

    if method == "cube-valve":
        return ir.ambient_cube_irradiance(bases["cube_valve"], normals)
    if method == "cube-nnls":
        return ir.ambient_cube_irradiance(bases["cube_nnls"], normals)
    if method == "sh-l1":
        return ir.sh4_irradiance(bases["sh"], normals)
    if method == "sh-l1-geomerics":
        return ir.sh4_irradiance_geomerics(bases["sh"], normals)
    if method == "sh-l2":
        return ir.sh9_irradiance(bases["sh"], normals)
    if method == "sh-l2-hann":
        return ir.sh9_irradiance(bases["sh"], normals, ir.sh_window("hann"))
    if method == "sh-l2-lanczos":
        return ir.sh9_irradiance(bases["sh"], normals, ir.sh_window("lanczos"))
    if method == "sh-l2-lambda":
        return ir.sh9_irradiance(bases["sh"], normals, ir.sh_window("lambda", 2, bases["lambda"]))
    if method == "quadrature":
        return np.asarray(quadrature, np.float64)
    raise ValueError(method)


def combine(parts: list, key: str):
    """Sum of the parts' references (independent renders): (mean, stderr, sigma)."""
    mean = sum(p[key].mean for p in parts)
    se = np.sqrt(sum(p[key].stderr ** 2 for p in parts))
    sig = np.sqrt(sum(p[key].sigma() ** 2 for p in parts))
    return mean, se, sig


def run(ctx) -> dict:
    from . import irradiance_bases_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    jobs = [
        Job(
            "rtfit.experiments.irradiance_bases:render_environment",
            dict(
                name=n,
                cfg=cfg,
                seed=ctx.seed,
                variant=ctx.variant,
                cache_dir=str(ctx.cache_dir),
                progress=ctx.progress,
            ),
            label=n,
        )
        for n in cfg["environments"]
    ]
    if missing_probes(ctx.quick):
        ctx.log(
            f"measured probes not found, left out: {', '.join(missing_probes(ctx.quick))} (set RTFIT_PROBE_DIR)"
        )
    ctx.log(f"rendering references for {len(jobs)} environments")
    rendered = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="environments")))

    from rtfit.realtime import set_default_backend

    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")
    ctx.log("projecting and fitting the bases")
    qb = quadrature_backend(ctx.variant)
    bases = {
        n: build_bases(rendered[n]["env"], cfg, 512 if ctx.quick else 2048, qb) for n in cfg["environments"]
    }
    return rep.assemble(ctx, cfg, rendered, bases)


def bench(ctx) -> list[dict]:
    from . import irradiance_bases_report as rep

    return rep.bench(ctx)
