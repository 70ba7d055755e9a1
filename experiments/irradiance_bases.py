"""Experiment ``irradiance-bases``: ambient cube and spherical harmonics against path-traced irradiance.

For each distant environment (constant, disc suns, Mitsuba ``sunsky`` at several sun elevations, a
high-contrast studio map, a low-contrast overcast sky, measured light probes, and the user's own probes,
``--probe FILE[:MAPPING]``, see `rtfit.reference.probe_maps`) the ground truth is Mitsuba's
irradiance at a Fibonacci sphere of normals (`rtfit.reference.estimators.irradiance_pass`: emitter
sampling + cosine sampling, MIS) and Mitsuba's point-sampled image of a white diffuse unit sphere under the
environment (`direct` integrator, the integrator rule's choice for one convex reflector). Both are checked
against an independent dense quadrature of the same map (`rtfit.reference.environments`) and the white
furnace (constant environment → π·L).

A sun cannot share a Mitsuba scene with a map (one environment emitter per scene): sun and map are rendered
as two references and added (irradiance is linear in the emitters; means add, variances add).

The bases are the rows of `rtfit.realtime.irradiance_bases.METHODS` (label, kernel, storage per probe,
formula), all built from the environment itself as an engine's baker would (`ROWS` below names the baked
coefficients each one reads):

* ``cube-valve``      ambient cube holding the irradiance at the six axes (Valve, seed 000:2471-2501);
* ``cube-nnls``       ambient cube fitted by non-negative least squares to the irradiance over the sphere;
* ``sh-l1``           4 SH coefficients per channel, cosine-convolved (linear in n);
* ``sh-l1-geomerics`` Geomerics' non-negative L1 reconstruction from the same 4 coefficients;
* ``sh-l2``           9 SH coefficients per channel (Ramamoorthi & Hanrahan);
* ``sh-l2-hann``, ``sh-l2-lanczos``  L2 with a fixed ringing window;
* ``sh-l2-lambda``    L2 with Sloan's window 1/(1 + λl²(l + 1)²), λ fitted per environment as the smallest
  value that removes negative irradiance;
* ``sh-l3*``, ``sh-l4*`` 16 and 25 SH coefficients per channel, plain and with the same three windows (λ
  fitted per order); L3 equals L2 in irradiance (Â_3 = 0) at 48 floats, a check;
* ``zh3``             ZH3: L1 plus one zonal L2 coefficient about each channel's L1 direction (15 floats);
* ``zh3-lum``         ZH3 with one axis for RGB (the luminance's L1 direction), 15 floats;
* ``zh3-hallucinated`` ZH3 with the zonal coefficient guessed from L1 (12 floats, the cost of L1);
* ``quadrature``      the dense quadrature itself (exact up to quadrature error: must sit at the noise floor).

The SH coefficients (to L4) of a map come from `sh_project_latlong` (the bilinear function Mitsuba sees, 2×
supersampled); a disc sun's from the closed form `sh_from_disk`; ZH3's from them (`zh3_from_sh`); cube-valve's
axis irradiance and the NNLS targets from the quadrature.

Metrics per environment × basis over the Fibonacci normals (all channels), each with the noise floor of
the Mitsuba reference (the value the metric reads for an exact basis, seeded Monte Carlo):

* ``smape``     mean |x − r|/(|x| + |r|) (`rtfit.fitting.smape`);
* ``rel_rmse``  √(mean (x − r)²) / √(mean r²);
* ``max_rel``   max |x − r| / max(r, 0.05·r̄) (r̄: the sphere-mean irradiance of that channel; the floor at
  5% keeps normals facing away from a lone sun from dividing by ~0);
* ``neg_frac``  fraction of normals with a negative channel (SH ringing; deterministic, floor 0);
* ``image_rel_rmse``  rel_rmse of the white sphere's image (radiance E/π at the pixel-centre normals).

Sections: configure · methods · cases · jobs · run · checks · figures · summary · bench.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path

import drjit as dr
import numpy as np

from rtfit.fitting import smape
from rtfit.fitting.stats import concat_z_pairs, z_checks, z_pair
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.ambient_dice import DICE_VERTICES, fit_ambient_dice
from rtfit.realtime.environment_bases import METHODS as ENVIRONMENT_BASES
from rtfit.realtime.irradiance_bases import (
    CUBE_AXES,
    CUBE_ORDER,
    SH_MAX_ORDER,
    ambient_cube_from_axes,
    basis_inputs,
    basis_irradiance,
    fibonacci_sphere,
    fit_ambient_cube_nnls,
    fit_window_lambda,
    latlong_samples,
    sh_from_constant,
    sh_from_disk,
    sh_project_latlong,
    sh_project_samples,
    zh3_from_sh,
)
from rtfit.realtime.spherical_gaussians import (
    SG_COUNTS,
    SG_FITS,
    disc_samples,
    fit_sg_all,
    sg_axes,
    sg_cosine_error,
    sg_sharpness,
)
from rtfit.reference import (
    ReferenceCache,
    ReferenceRequest,
    load_mitsuba_scene,
    probe_maps,
    render_gbuffer,
    use_variant,
)
from rtfit.reference import environments as envs
from rtfit.reference.cache import REFERENCE_PASS_DTYPE, RELATIVE_PRECISION_FLOOR
from rtfit.reference.estimators import device_probes, irradiance_pass, radiance_pass
from rtfit.reference.variants import backend_of
from rtfit.scenes import (
    ConstantEnv,
    EnvMap,
    Sun,
    SunSky,
    library_path,
    load_scene,
    parse_scene_text,
    scene_hash,
    scene_to_toml,
)

from . import figures
from . import fitted as fitfiles
from . import irradiance_hemisphere as hemisphere
from .cost import (
    Stock,
    attach_costs,
    baseline_row,
    bench_backend,
    comparison_row,
    cost_row,
    memory_baseline,
    memory_floor_row,
    numpy_elements,
    reference_sizes,
    reference_vs_stock_rows,
    stock_render,
    time_drjit,
    time_numpy,
)
from .jobs import Job
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked
from .rows import Row, resolved_means
from .viewer import save_case_pixels

# ============================================================================================ configure
SUNSKY_ELEVATIONS_FULL = (2.0, 10.0, 30.0, 60.0, 90.0)
SUNSKY_ELEVATIONS_QUICK = (10.0, 60.0)
SUN_SIZES_FULL = (0.27, 2.0, 10.0, 20.0)
SUN_SIZES_QUICK = (0.27, 10.0)
PROBES_FULL = ("grace", "grace-ict", "uffizi", "ennis", "pisa", "wells")
PROBES_QUICK = ("grace",)
FLOOR_DRAWS = 4  # noise-floor draws per metric (seeded)
SUNSKY_BAKE_TOLERANCE = 0.01  # relative bias of baked sky + disc sun against Mitsuba's own sunsky
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB → luminance (Rec. 709), for the error maps


CONFIG = {
    "environments": ConfigKey(
        "str",
        "constant, sun-<radius °>, sunsky-<elevation °>, studio, overcast, probe-<name>",
        shape=(None,),
        check=lambda name: environment_problem(name),
    ),
    "normals": ConfigKey("int", "normals of the irradiance comparison", 6, 1 << 20),
    "probe_spp": ConfigKey("int", "reference samples per probe normal", 2, SPP_MAX),
    "probe_pass_spp": ConfigKey("int", "samples of one cached probe pass", 2, SPP_MAX),
    "resolution": ConfigKey("int", "sphere image side (pixels)", 8, 4096),
    "spp": ConfigKey("int", "sphere image samples per pixel", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "samples per pixel of one cached pass", 2, SPP_MAX),
    "map_height": ConfigKey("int", "rows of baked maps (2:1 lat-long)", 4, 4096),
    "probe_height": ConfigKey(
        "int", "rows of resampled probes; none: the file's own", 4, 8192, optional=True
    ),
    "quadrature_min_rows": ConfigKey("int", "quadrature supersampling: at least this many rows", 1, 16384),
    "map_supersample": ConfigKey("int", "map supersampling per axis", 1, 16),
    "sun_elevation_deg": ConfigKey("float", "elevation of the sun-<r> environments (°)", 0.0, 90.0),
    "probes": ConfigKey(
        "str",
        "your own light probes, PATH[:MAPPING] (latlong, vcross, hcross, mirrorball, angular; "
        "docs/irradiance-bases.md), run as environments probe-file-<stem>; none: only the built-in ones",
        shape=(None,),
        optional=True,
        check=probe_maps.probe_spec_problem,
    ),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def environment_problem(name: str) -> str | None:
    """What is wrong with an environment name (None: it can be built): an unknown name, a number out of
    range, a measured probe whose file is missing or does not read (checked before anything renders)."""
    if name in ("constant", "studio", "overcast"):
        return None
    for prefix, lo, hi, what in (("sun-", 0.0, 90.0, "angular radius"), ("sunsky-", 0.0, 90.0, "elevation")):
        if name.startswith(prefix):
            try:
                x = float(name[len(prefix) :])
            except ValueError:
                return f"{prefix}<{what} in degrees> expected"
            return None if lo < x <= hi else f"{what} {name[len(prefix) :]}° out of range ({lo:g}, {hi:g}]"
    if name.startswith("probe-"):
        probe = name[6:]
        if probe not in envs.PROBES:
            return f"unknown probe {probe!r} (known: {', '.join(envs.PROBES)})"
        path = envs.probe_dir() / envs.PROBES[probe][0]
        if not path.is_file():
            return f"probe file not found: {path} (set RTFIT_PROBE_DIR)"
        stat = path.stat()
        return _probe_file_problem(probe, str(path), stat.st_size, stat.st_mtime_ns)
    return "unknown environment (constant, sun-<r>, sunsky-<e>, studio, overcast, probe-<name>)"


@functools.lru_cache(maxsize=32)
def _probe_file_problem(probe: str, path: str, _size: int, _mtime: int) -> str | None:
    """Read the probe file once (keyed by its size and time): a truncated or corrupt file is a problem."""
    try:
        env = envs.probe_environment(probe, 8)
    except Exception as e:  # any failure to read the file is the user's bad file
        return f"probe file {path} does not read ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
    if not np.all(np.isfinite(env.radiance_map)):
        return f"probe file {path} has non-finite pixels"
    return None


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "environments": environment_names(quick),
            "normals": 384 if quick else 2048,
            "probe_spp": spp or (4096 if quick else 32768),
            "probe_pass_spp": 1024 if quick else 4096,
            "resolution": 40 if quick else 128,
            "spp": 512 if quick else 4096,
            "pass_spp": 128 if quick else 1024,
            "map_height": 32 if quick else 128,
            "probe_height": 64 if quick else None,  # None: the probe file's own resolution
            "quadrature_min_rows": 256
            if quick
            else 512,  # quadrature supersampling s = max(2, ceil(rows / H))
            "map_supersample": 2,
            "sun_elevation_deg": 45.0,
            "probes": None,
        },
    )


def environment_names(quick: bool) -> list[str]:
    """The default environments. Measured probes whose files are absent (no ``../shared/probes``, no
    ``$RTFIT_PROBE_DIR``) are left out here and named in the report's notes (`missing_probes`); asking for
    one explicitly (a sweep override) still fails with the file's path."""
    suns = SUN_SIZES_QUICK if quick else SUN_SIZES_FULL
    els = SUNSKY_ELEVATIONS_QUICK if quick else SUNSKY_ELEVATIONS_FULL
    probes = [p for p in (PROBES_QUICK if quick else PROBES_FULL) if envs.probe_available(p)]
    return (
        ["constant"]
        + [f"sun-{a:g}" for a in suns]
        + [f"sunsky-{e:g}" for e in els]
        + ["studio", "overcast"]
        + [f"probe-{p}" for p in probes]
    )


def with_user_probes(cfg: dict) -> dict:
    """``cfg`` with the user's probes (``probes``, `rtfit.reference.probe_maps`) appended to its
    environments as ``probe-file-<stem>``."""
    ids = probe_maps.user_probe_ids(cfg.get("probes"))
    return {
        **cfg,
        "environments": list(cfg["environments"]) + [i for i in ids if i not in cfg["environments"]],
    }


def rh2001_coefficients(radiance_map, supersample: int = 2, frame=None) -> tuple[np.ndarray, float]:
    """The L2 radiance coefficients (9, 3) of a lat-long map of Grace Cathedral (rtfit's convention, e.g.
    ``probe-grace``) in Ramamoorthi & Hanrahan 2001's frame (``frame``: the 3 × 3 map from world
    directions, default `probe_maps.RH2001_FROM_WORLD`), scaled by the one exposure s that fits
    `probe_maps.RH2001_GRACE_L2` best in least squares; returns (s·L, s)."""
    m = probe_maps.RH2001_FROM_WORLD if frame is None else np.asarray(frame, np.float64)
    d, w, L = envs.quadrature_samples(radiance_map, supersample)
    c = sh_project_samples(d @ m.T, w, L)
    s = float(np.sum(c * probe_maps.RH2001_GRACE_L2) / np.sum(c * c))
    return s * c, s


def missing_probes(quick: bool) -> list[str]:
    """Default probes left out of this run because their files are absent."""
    return [p for p in (PROBES_QUICK if quick else PROBES_FULL) if not envs.probe_available(p)]


def supersample_for(env, cfg: dict) -> int:
    """Quadrature supersampling of a map per axis: at least 2, and at least ``quadrature_min_rows`` rows."""
    if env.radiance_map is None:
        return 1
    return max(2, math.ceil(cfg["quadrature_min_rows"] / env.radiance_map.shape[0]))


def quadrature_backend(variant: str) -> str | None:
    """Dense quadrature on the GPU (Dr.Jit CUDA, float64) for CUDA runs, else NumPy (as fast on a CPU)."""
    return "cuda" if variant.startswith("cuda") else None


# ============================================================================================== methods
METHODS = ENVIRONMENT_BASES
"""Every basis of this experiment: cube and SH (`rtfit.realtime.irradiance_bases`), spherical Gaussians
(`rtfit.realtime.spherical_gaussians`) and Ambient Dice (`rtfit.realtime.ambient_dice`), joined once in
`rtfit.realtime.environment_bases` (the table `rtfit audit` reads too)."""
SG_ERROR_LAMBDAS = (1e-3, 0.1, 0.8, 10.0, 1000.0)  # the self-check's λ grid (plus each basis's own λ)
SG_ERROR_BOUND = 0.051  # max |S̃ − S|/S(λ, 1) measured over λ ∈ [1e-3, 1e3]: 0.0503 at λ = 0.8


def basis_row(
    method: str, coeffs: str | None, params: Mapping[str, str] | None = None, fitted_coeffs: bool = False
) -> Row:
    """One row of the comparison (`rows.Row`, its id the method's): a method of `METHODS` and where its
    inputs come from. ``coeffs`` (the row's ``source``): the key of `build_bases`'s result holding the baked
    coefficients the basis reads (None for the exact row, which reads the quadrature); ``params`` (the row's
    ``fitted_keys``): kernel parameter → key of the per-environment value fitted by `build_bases` (also the
    parameter's name in the results); ``fitted_coeffs``: the coefficients themselves are fitted (NNLS)
    rather than sampled or projected. The row is ``fitted`` when either is."""
    keys = dict(params or {})
    return Row(method, method=method, source=coeffs, fitted_keys=keys, fitted=bool(keys) or fitted_coeffs)


ROWS = (
    basis_row("cube-valve", "cube_valve"),
    basis_row("cube-nnls", "cube_nnls", fitted_coeffs=True),
    basis_row("sh-l1", "sh"),
    basis_row("sh-l1-geomerics", "sh"),
    basis_row("sh-l2", "sh"),
    basis_row("sh-l2-hann", "sh"),
    basis_row("sh-l2-lanczos", "sh"),
    basis_row("sh-l2-lambda", "sh", params={"lam": "lambda"}),
    basis_row("sh-l3", "sh"),
    basis_row("sh-l3-hann", "sh"),
    basis_row("sh-l3-lanczos", "sh"),
    basis_row("sh-l3-lambda", "sh", params={"lam": "lambda_l3"}),
    basis_row("sh-l4", "sh"),
    basis_row("sh-l4-hann", "sh"),
    basis_row("sh-l4-lanczos", "sh"),
    basis_row("sh-l4-lambda", "sh", params={"lam": "lambda_l4"}),
    basis_row("zh3", "zh3"),
    basis_row("zh3-lum", "zh3_lum"),
    basis_row("zh3-hallucinated", "sh"),
    *(basis_row(f"sg{n}-{f}", f"sg{n}_{f}", fitted_coeffs=f != "naive") for n in SG_COUNTS for f in SG_FITS),
    basis_row("ambient-dice", "ambient_dice", fitted_coeffs=True),
    basis_row("quadrature", None),
)
ROW = {r.method: r for r in ROWS}
UP = np.array([[0.0, 0.0, 1.0]])
"""The one normal at which a fitted file's baked coefficients are read (they do not depend on it)."""
BASES = tuple(r for r in ROWS if not METHODS[r.method].exact)  # the rows an engine would store and evaluate
SPHERE_FIGURE_METHODS = ("cube-valve", "sh-l1", "sh-l2", "sh-l2-lambda")
SUN_PROFILE_METHODS = (
    "cube-valve",
    "sh-l1",
    "sh-l1-geomerics",
    "sh-l2",
    "sh-l2-hann",
    "sh-l2-lambda",
    "sh-l4",
    "zh3-hallucinated",
)
NOISE_FLOOR_METHOD = "sh-l2"  # whose noise floor the per-environment figures draw (any row's is the same)


def row_params(row: Row, bases: dict) -> dict[str, float]:
    """The kernel parameters of ``row`` for one environment's ``bases``."""
    return {p: bases[key] for p, key in row.fitted_keys.items()}


def evaluate_row(row: Row, bases: dict, normals, quadrature=None):
    """Irradiance (N, 3) of ``row`` at ``normals`` (N, 3) (or a tuple of Dr.Jit arrays for Dr.Jit normals);
    the exact row passes ``quadrature`` (the irradiance at the same normals) through its method."""
    m = METHODS[row.method]
    if m.exact:
        return np.asarray(m(NUMPY_OPS, {"irradiance": quadrature}), np.float64)
    return basis_irradiance(m, bases[row.source], normals, row_params(row, bases))


def build_bases(env, cfg: dict, fit_normals: int = 2048, backend: str | None = None) -> dict:
    """Every basis's coefficients for ``env`` (what an engine would bake), with the time each took."""
    out: dict = {"timing_ms": {}}
    t0 = time.perf_counter()
    order = (
        SH_MAX_ORDER  # one projection to L4 (25 rows) serves every SH row: lower orders read its first rows
    )
    sh = np.zeros(((order + 1) ** 2, 3))
    if env.constant is not None:
        sh += sh_from_constant(env.constant, order)
    if env.radiance_map is not None:
        sh += sh_project_latlong(env.radiance_map, cfg["map_supersample"], order)
    if env.sun is not None:
        s = env.sun
        sh += sh_from_disk(s.direction, math.radians(s.angular_radius_deg), np.asarray(s.irradiance), order)
    out["timing_ms"]["sh-projection"] = 1e3 * (time.perf_counter() - t0)
    out["sh"] = sh
    out["zh3"] = zh3_from_sh(sh)
    out["zh3_lum"] = zh3_from_sh(sh, shared_axis=True)
    t0 = time.perf_counter()
    ss = supersample_for(env, cfg)
    out["cube_valve"] = ambient_cube_from_axes(envs.irradiance_quadrature(env, np.array(CUBE_AXES), ss))
    out["timing_ms"]["cube-valve"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    fn = fibonacci_sphere(fit_normals)
    target = envs.irradiance_quadrature(env, fn, ss, backend)
    out["cube_nnls"], out["cube_nnls_rms"] = fit_ambient_cube_nnls(fn, target)
    out["timing_ms"]["cube-nnls"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    out["lambda"] = fit_window_lambda(sh)
    out["timing_ms"]["lambda-fit"] = 1e3 * (time.perf_counter() - t0)
    out["lambda_l3"] = out["lambda"]  # Â_3 = 0 and w_l does not depend on the order: the L2 answer
    out["lambda_l4"] = fit_window_lambda(sh, order=4)
    t0 = time.perf_counter()
    out["ambient_dice"], out["ambient_dice_rms"] = fit_ambient_dice(fn, target)
    out["timing_ms"]["ambient-dice"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    samples = _radiance_samples(env, cfg)
    for n in SG_COUNTS:
        for f, amplitudes in fit_sg_all(n, *samples, constant=env.constant).items():
            out[f"sg{n}_{f}"] = amplitudes
    out["timing_ms"]["sg-fits"] = 1e3 * (time.perf_counter() - t0)
    return out


def _radiance_samples(env, cfg: dict):
    """The environment's radiance as samples (directions, solid-angle weights, radiance) for the SG fits: the
    bilinear map as `sh_project_latlong` sees it, plus the disc sun (`disc_samples`); the constant part is
    passed to `fit_sg` separately (closed form)."""
    parts = []
    if env.radiance_map is not None:
        parts.append(latlong_samples(env.radiance_map, cfg["map_supersample"]))
    if env.sun is not None:
        s = env.sun
        parts.append(disc_samples(s.direction, math.radians(s.angular_radius_deg), np.asarray(s.irradiance)))
    if not parts:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))


# ================================================================================================ cases
def make_environment(name: str, cfg: dict, mi=None):
    """Build (bake or load) the environment ``name`` (see `environment_names`)."""
    h = int(cfg["map_height"])
    if name == "constant":
        return envs.constant_environment(1.0)
    if name.startswith("sun-"):
        return envs.sun_environment(float(name[4:]), cfg["sun_elevation_deg"])
    if name.startswith("sunsky-"):
        if mi is None:
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
    user = dict(zip(probe_maps.user_probe_ids(cfg.get("probes")), cfg.get("probes") or (), strict=True))
    if name in user:
        return probe_maps.user_probe_environment(name, user[name], cfg["probe_height"])
    if name.startswith("probe-"):
        return envs.probe_environment(name[6:], cfg["probe_height"])
    raise ValueError(f"unknown environment {name!r}")


def _sphere_scene(library_name: str, env, resolution: int, light):
    """The library scene ``library_name`` (the white unit sphere) at ``resolution``² with ``light`` alone."""
    base = load_scene(library_path(library_name))
    cam = dataclasses.replace(base.camera, width=resolution, height=resolution)
    return dataclasses.replace(base, name=f"{base.name}-{env.name}", camera=cam, lights=(light,))


def sky_scene(env, map_file: str | None, resolution: int):
    """The sphere with the environment's map (or constant) as its only light."""
    light = ConstantEnv(radiance=env.constant) if env.constant is not None else EnvMap(file=map_file)
    return _sphere_scene("irradiance_sphere", env, resolution, light)


def sun_scene(env, resolution: int):
    """The sphere lit by the environment's disc sun alone."""
    s = env.sun
    light = Sun(direction=s.direction, irradiance=s.irradiance, angular_radius_deg=s.angular_radius_deg)
    return _sphere_scene("irradiance_sphere_sun", env, resolution, light)


def sunsky_scene(env, resolution: int):
    """Mitsuba's own sunsky (sun and sky in one emitter): the check of the baked sky + disc sun."""
    return _sphere_scene("irradiance_sphere_sunsky", env, resolution, SunSky(sun_direction=env.sun.direction))


# ================================================================================================= jobs
def _probe_request(scene, cfg: dict, seed: int, variant: str, n32: np.ndarray) -> ReferenceRequest:
    return ReferenceRequest(
        scene=scene,
        spp=cfg["probe_spp"],
        pass_spp=cfg["probe_pass_spp"],
        seed=seed,
        variant=variant,
        quantity="irradiance",
        points=n32,
        normals=n32,
    )


def render_environment(
    name: str, cfg: dict, seed: int, variant: str, cache_dir: str, progress: bool = False
) -> dict:
    """Job: bake/load one environment, render its Mitsuba references, integrate its quadrature."""
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
            digest = hashlib.sha256(env.radiance_map.tobytes()).hexdigest()[:16]
            key = f"{name}-{env.radiance_map.shape[0]}-{digest}"
            map_file = str(envs.write_map_exr(env.radiance_map, Path(cache_dir) / "envmaps" / f"{key}.exr"))
        scenes.append(("sky", sky_scene(env, map_file, cfg["resolution"])))
    if env.sun is not None:
        scenes.append(("sun", sun_scene(env, cfg["resolution"])))
    for part, scene0 in scenes:
        scene = parse_scene_text(scene_to_toml(scene0))
        hashes[part] = scene_hash(scene)
        probes = cache.get(
            _probe_request(scene, cfg, seed, variant, n32), progress=progress, label=f"{name} {part} probes"
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
            _probe_request(scene, cfg, seed, variant, n32),
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


# ================================================================================================== run
def run(ctx) -> dict:
    cfg = with_user_probes(ctx.configured(configure(ctx.quick, ctx.spp)))
    jobs = [
        Job(
            render_environment,
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
            f"measured probes not found, left out: {', '.join(missing_probes(ctx.quick))} (set "
            "RTFIT_PROBE_DIR)"
        )
    ctx.log(f"rendering references for {len(jobs)} environments")
    labels = [j.label for j in jobs]
    rendered = dict(zip(labels, ctx.executor.map(jobs, desc="environments"), strict=True))

    ctx.log("projecting and fitting the bases")
    qb = quadrature_backend(ctx.variant)
    bases = {
        n: build_bases(rendered[n]["env"], cfg, 512 if ctx.quick else 2048, qb) for n in cfg["environments"]
    }
    return assemble(ctx, cfg, rendered, bases)


def combine(parts: list, key: str):
    """Sum of the parts' references (independent renders): (mean, stderr, sigma)."""
    mean = sum(p[key].mean for p in parts)
    se = np.sqrt(sum(p[key].stderr ** 2 for p in parts))
    sig = np.sqrt(sum(p[key].sigma() ** 2 for p in parts))
    return mean, se, sig


def rel_rmse(x, r) -> float:
    """√(mean (x − r)²) / √(mean r²)."""
    return float(np.sqrt(np.mean((x - r) ** 2)) / max(np.sqrt(np.mean(r**2)), 1e-300))


def max_rel(x, r) -> float:
    """max |x − r| / max(r, 0.05·r̄), r̄ the mean |r| per channel."""
    rbar = np.maximum(np.mean(np.abs(r), axis=0, keepdims=True), 1e-300)
    return float(np.max(np.abs(x - r) / np.maximum(r, 0.05 * rbar)))


def with_floor(fn, x, r, sigma, seed=0) -> dict:
    """The metric ``fn(x, r)`` with its noise floor: the mean of ``fn(r, r + σ·N(0, 1))`` over
    `FLOOR_DRAWS` seeded draws; resolved when the value exceeds twice the floor."""
    rng = np.random.default_rng(seed)
    val = fn(x, r)
    floor = float(np.mean([fn(r, r + sigma * rng.standard_normal(r.shape)) for _ in range(FLOOR_DRAWS)]))
    return {"value": val, "noise_floor": floor, "resolved": bool(val > 2 * floor)}


def point_metrics(x, r, sigma) -> dict:
    sm = smape(x, r, sigma).to_dict()
    return {
        "rel_rmse": with_floor(rel_rmse, x, r, sigma),
        "smape": {k: sm[k] for k in ("value", "noise_floor", "resolved") if k in sm},
        "max_rel": with_floor(max_rel, x, r, sigma),
        "neg_frac": {
            "value": float(np.mean(np.any(x < 0, axis=1))),
            "noise_floor": 0.0,
            "resolved": bool(np.any(x < 0)),
        },
    }


def _row_parameters(row: Row, b: dict) -> dict:
    """The approximation record's parameters: the fitted values, else the storage per probe."""
    if row.fitted_keys:
        return {key: b[key] for key in row.fitted_keys.values()}
    return {"floats": METHODS[row.method].storage} if METHODS[row.method].storage else {}


def _sunsky_bias(name: str, env, r: dict, mean, se) -> tuple[str, float, float]:
    """Relative bias of the baked sky + disc sun against Mitsuba's own sunsky, worst channel, ± its se."""
    own = r["sunsky_own"].mean.copy()
    mine = mean.copy()
    for ch in env.params.get("sun_negative_channels", []):
        own[:, ch] = mine[:, ch] = 0.0  # Mitsuba's sun is negative there; rtfit's disc sun clamps it
    ose = r["sunsky_own"].stderr
    keep = np.ones(3, bool)
    keep[env.params.get("sun_negative_channels", [])] = False
    bias = (mine - own).mean(axis=0)[keep] / own.mean(axis=0)[keep]
    bias_se = np.sqrt(np.sum(se**2 + ose**2, axis=0))[keep] / len(own) / own.mean(axis=0)[keep]
    k = int(np.argmax(np.abs(bias)))
    return name, float(bias[k]), float(bias_se[k])


def assemble(ctx, cfg, rendered, bases) -> dict:
    out = ctx.out_dir
    names = cfg["environments"]
    cases, z_quad, z_img, furnace, bake = [], [], [], [], []
    per_env, hemi = {}, []
    for name in names:
        r = rendered[name]
        env, b = r["env"], bases[name]
        mean, se, sig = combine(r["parts"], "probes")
        img_mean, img_se, img_sig = combine(r["parts"], "image")
        mask = r["mask"]
        gn = r["gbuffer"].normal[mask].astype(np.float64)
        approx_docs, evals, sphere = [], {}, {}
        for row in ROWS:
            x = evaluate_row(row, b, r["normals"], r["quadrature"])
            xi = evaluate_row(row, b, gn, r["quadrature_image"]) / math.pi
            evals[row.method] = x
            sphere[row.method] = img_mean.copy()
            sphere[row.method][mask] = xi
            met = point_metrics(x, mean, sig)
            met["image_rel_rmse"] = with_floor(rel_rmse, xi, img_mean[mask], img_sig[mask])
            approx_docs.append(
                {
                    "method": row.method,
                    "label": METHODS[row.method].label,
                    "fitted": row.fitted,
                    "parameters": _row_parameters(row, b),
                    "metrics": met,
                    "figures": [],
                }
            )
        per_env[name] = {"evals": evals, "mean": mean, "sig": sig}
        hemi += hemisphere.environment_section(
            name, env, r["normals"], mean, sig, r["quadrature"], b["sh"], supersample_for(env, cfg),
            quadrature_backend(ctx.variant), point_metrics, ctx.quick,
        )  # fmt: skip
        save_case_pixels(out, name, img_mean, img_sig, sphere, mask)  # the report's viewer: the sphere image
        floor = RELATIVE_PRECISION_FLOOR
        z_quad.append(z_pair(r["quadrature"][:, 0], mean[:, 0], se[:, 0], sig[:, 0], floor))
        z_img.append(
            z_pair(
                r["quadrature_image"][:, 0] / math.pi,
                img_mean[mask][:, 0],
                img_se[mask][:, 0],
                img_sig[mask][:, 0],
                floor,
            )
        )
        if env.kind == "constant":
            exact = np.full(len(mean), math.pi * env.constant[0])
            furnace.append(z_pair(exact, mean[:, 0], se[:, 0], sig[:, 0], floor))
        if r.get("sunsky_own") is not None:
            bake.append(_sunsky_bias(name, env, r, mean, se))
        ref_doc = dict(r["parts"][0]["probes"].to_dict())
        ref_doc["parts"] = " + ".join(p["part"] for p in r["parts"])
        ref_doc["image_spp"] = r["parts"][0]["image"].spp
        sun = (
            {"sun_irradiance_g": env.sun.irradiance[1], "sun_angular_radius_deg": env.sun.angular_radius_deg}
            if env.sun
            else {}
        )
        cases.append(
            {
                "id": name,
                "label": env.label,
                "parameters": {
                    **{k: v for k, v in env.params.items() if not isinstance(v, (list, dict))},
                    **sun,
                    "normals": len(mean),
                    "lambda": b["lambda"],
                    "sh_projection_ms": b["timing_ms"]["sh-projection"],
                    "cube_nnls_fit_ms": b["timing_ms"]["cube-nnls"],
                    "lambda_fit_ms": b["timing_ms"]["lambda-fit"],
                    "sg_fits_ms": b["timing_ms"]["sg-fits"],
                    "ambient_dice_fit_ms": b["timing_ms"]["ambient-dice"],
                    "bake_s": r["bake_seconds"],
                },
                "scene": {
                    "name": f"irradiance-sphere-{name}",
                    "hash": r["hashes"].get("sky") or r["hashes"].get("sun"),
                },
                "reference": ref_doc,
                "approximations": approx_docs,
            }
        )

    costs = _costs(ctx)
    attach_costs(cases, costs)
    checks = (
        _checks(names, cases, z_quad, z_img, furnace, bake)
        + hemisphere.checks(hemi)
        + _published_checks(rendered)
    )
    fits = write_fitted(out, cfg, rendered, bases, ctx)
    hashes = {n: list(rendered[n]["hashes"].values()) for n in names}
    hemisphere.write_fitted(out, hemi, ctx, hashes, cfg.get("spp"))  # fitted/<env>-lightmap.json
    figs = _figures(ctx, cfg, rendered, bases, per_env, cases, costs)
    figs.append(hemisphere.figure(out, hemi, figures.line_plot))
    hemi_text = hemisphere.section_text(hemi, costs)
    hemi_section = {"id": "hemisphere", "title": "Lightmap bases on the hemisphere", "text": hemi_text}
    return {
        "summary": _summary(cfg, cases, checks),
        "config": cfg,
        "sections": [
            *_sections(cfg),
            *_probe_sections(cfg, rendered),
            *_budget_sections(cases, costs),
            hemi_section,
        ],
        "cases": cases,
        "fits": fits,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "notes": _notes(ctx),
        "hemisphere": hemi,  # per environment × surface frame: the lightmap bases' texel and metrics
    }


def _approximation(cases, env, method) -> dict | None:
    """The approximation record of ``method`` in case ``env`` (None if absent)."""
    for c in cases:
        if c["id"] == env:
            for ap in c["approximations"]:
                if ap["method"] == method:
                    return ap
    return None


def _metric(cases, env, method, key) -> float:
    ap = _approximation(cases, env, method)
    return ap["metrics"][key]["value"] if ap else float("nan")


def _floor(cases, env, method, key) -> float:
    ap = _approximation(cases, env, method)
    return (ap["metrics"][key].get("noise_floor") or 0.0) if ap else 0.0


def _fit_parameter(value: float, lower: float, upper: float, at_bound: bool) -> dict:
    return {
        "value": value,
        "stderr": None,
        "lower": lower,
        "upper": upper if math.isfinite(upper) else None,
        "at_bound": at_bound,
    }


def _row_fit(row: Row, b: dict) -> dict:
    """A row's free parameters as a fit's ``parameters`` (λ is at a bound only where the bisection stopped
    at its upper end: λ = 0 is an answer, "no window needed")."""
    out = {}
    for p, key in row.fitted_keys.items():
        spec = METHODS[row.method].params[p]
        out[p] = _fit_parameter(b[key], spec.lower, spec.upper, bool(b[key] >= spec.upper))
    return {"parameters": out}


def write_fitted(out, cfg, rendered, bases, ctx=None) -> list[dict]:
    """One fitted file per environment (the cubes, the SH coefficients, λ) and its fit record: the fitted
    parameters of every row with parameters (bounds from `METHODS`), then the NNLS cube's green channel."""
    fitted_rows = [r for r in ROWS if r.fitted_keys]
    axes = [ax.replace("+", "p").replace("-", "n") for ax in CUBE_ORDER]  # "+x" → "px", "-x" → "nx"
    fits = []
    for name in cfg["environments"]:
        b = bases[name]
        doc = {
            "environment": name,
            "label": rendered[name]["env"].label,
            "units": "irradiance W/m^2 per linear-sRGB channel (cube); SH radiance coefficients L_lm "
            "(W/m^2/sr·sr)",
            "cube_order": list(CUBE_ORDER),
            "cube_valve": b["cube_valve"].tolist(),
            "cube_nnls": b["cube_nnls"].tolist(),
            "cube_nnls_rms_residual": b["cube_nnls_rms"].tolist(),
            "sh_convention": "real SH, no Condon-Shortley phase, index l(l+1)+m",
            "sh_l2": b["sh"][:9].tolist(),
            "sh_l4": b["sh"].tolist(),
            "zh3": b["zh3"].tolist(),
            "zh3_lum": b["zh3_lum"].tolist(),
            "zh3_layout": "per channel: L00, L1-1, L10, L11, zonal L2 coefficient about the L1 direction "
            "(zh3: the channel's, zh3_lum: the Rec. 709 luminance's)",
            "lambda_window": b["lambda"],
            "lambda_window_l4": b["lambda_l4"],
            "lambda_window_formula": "w_l = 1 / (1 + lambda * l^2 (l+1)^2)",
            "sg_lobes": {
                str(n): {"sharpness": sg_sharpness(n), "axes": sg_axes(n).tolist()} for n in SG_COUNTS
            },
            "sg_formula": "L(w) = sum_k a_k exp(lambda (mu_k . w - 1)) (+ c for the ambient fits)",
            "ambient_dice_vertices": [list(v) for v in DICE_VERTICES],
            "ambient_dice": b["ambient_dice"].tolist(),
            **{f"sg{n}_{f}": b[f"sg{n}_{f}"].tolist() for n in SG_COUNTS for f in SG_FITS},
        }
        methods = [
            fitfiles.method_entry(
                METHODS[row.method],
                _row_fit(row, b),
                case=name,
                baked={"coeffs": basis_inputs(METHODS[row.method], b[row.source], UP)["coeffs"]},
                outputs=("out_r", "out_g", "out_b"),
            )
            for row in BASES
        ]
        fitfiles.write_fitted(
            out / "fitted" / f"{name}.json",
            fitfiles.FittedFile(
                format=fitfiles.FORMAT,
                title=f"irradiance bases baked for environment {name} ({doc['label']})",
                provenance=fitfiles.provenance(
                    ctx, "irradiance-bases", list(rendered[name]["hashes"].values()), cfg.get("spp")
                ),
                methods=methods,
                data=doc,
            ),
        )
        params = {}
        for row in fitted_rows:
            for p, key in row.fitted_keys.items():
                spec = METHODS[row.method].params[p]
                # λ = 0 is an answer ("no window needed"), not a bound the search ran into: at the bound
                # only if the bisection stopped at its upper end
                params[key] = _fit_parameter(b[key], spec.lower, spec.upper, bool(b[key] >= spec.upper))
        for i, ax in enumerate(axes):
            v = float(b["cube_nnls"][i, 1])
            params[f"nnls_{ax}_g"] = _fit_parameter(v, 0.0, math.inf, bool(v == 0.0))
        fits.append(
            {
                "id": f"lambda-{name}",
                "label": f"{name}: λ window and NNLS cube",
                "model": "w_l = 1/(1 + λ l²(l+1)²); cube ≥ 0 by NNLS",
                "parameters": params,
                "rms_residual": float(np.mean(b["cube_nnls_rms"])),
                "converged": True,
                "file": f"fitted/{name}.json",
            }
        )
    return fits


# =============================================================================================== checks
def _checks(names, cases, z_quad, z_img, furnace, bake) -> list[Check | dict]:
    """Quadrature and furnace z-tests against Mitsuba, the sunsky bake, λ leaves no ringing, NNLS ≤ Valve."""
    checks = (
        z_checks(
            "quadrature vs Mitsuba irradiance (all environments, Fibonacci normals)", *concat_z_pairs(z_quad)
        )
        + z_checks("quadrature vs Mitsuba sphere image (all environments)", *concat_z_pairs(z_img))
        + (z_checks("white furnace: π·L vs Mitsuba irradiance", *concat_z_pairs(furnace)) if furnace else [])
    )
    for name, bias, bias_se in bake:
        checks.append(
            Check(
                name=f"{name}: baked sky + disc sun vs Mitsuba's own sunsky: relative bias of the mean "
                f"irradiance over normals, worst channel (± {bias_se:.2g} statistical)",
                value=bias,
                expected=f"|bias| ≤ {SUNSKY_BAKE_TOLERANCE}",
                passed=abs(bias) <= SUNSKY_BAKE_TOLERANCE,
            )
        )
    lam_rows = [r.method for r in ROWS if "lam" in r.fitted_keys]
    neg = max(_metric(cases, n, m, "neg_frac") for n in names for m in lam_rows)
    checks.append(
        Check(
            name=f"fitted λ window leaves no negative irradiance ({', '.join(lam_rows)}; max over "
            "environments)",
            value=neg,
            expected="0",
            passed=neg == 0.0,
        )
    )
    checks += _sg_dice_checks(names, cases)
    worse = [
        n
        for n in names
        if _metric(cases, n, "cube-nnls", "rel_rmse")
        > _metric(cases, n, "cube-valve", "rel_rmse") + 2 * _floor(cases, n, "cube-valve", "rel_rmse")
    ]
    checks.append(
        Check(
            name="NNLS cube no worse than Valve's cube (rel. RMSE, all environments)",
            value=", ".join(worse) or "none worse",
            expected="none worse",
            passed=not worse,
        )
    )
    return checks + _order_checks(names, cases)


ORDER_CHECKS = (
    ("sh-l4", "sh-l2"),
    ("sh-l2", "zh3"),
    ("zh3", "sh-l1"),
    ("sh-l2", "zh3-lum"),
    ("zh3-lum", "sh-l1"),
)
"""(better, worse) pairs that orthogonality guarantees over the sphere of normals: SH L_n is the least-squares
irradiance of its bands (adding bands never raises the error), and ZH3 keeps L1 and adds the projection of the
L2 band onto one zonal harmonic, about any axis (between L1 and L2)."""


def _order_checks(names, cases) -> list[Check]:
    """Error does not grow with the SH order (`ORDER_CHECKS`, within 2 noise floors); L3 = L2 (Â_3 = 0)."""
    checks = []
    for better, than in ORDER_CHECKS:
        bad = [
            n
            for n in names
            if _metric(cases, n, better, "rel_rmse")
            > _metric(cases, n, than, "rel_rmse") + 2 * _floor(cases, n, than, "rel_rmse")
        ]
        checks.append(
            Check(
                name=f"{better} no worse than {than} (rel. RMSE, all environments, within 2 noise floors)",
                value=", ".join(bad) or "none worse",
                expected="none worse",
                passed=not bad,
            )
        )
    diff = max(
        abs(_metric(cases, n, "sh-l3", "rel_rmse") - _metric(cases, n, "sh-l2", "rel_rmse")) for n in names
    )
    checks.append(
        Check(
            name="SH L3 irradiance equals L2 (Â_3 = 0: odd bands above 1 vanish): max |Δ rel. RMSE|",
            value=diff,
            expected="≤ 1e-12",
            passed=diff <= 1e-12,
        )
    )
    return checks


def _sg_dice_checks(names, cases) -> list[Check]:
    """The SG clamped-cosine approximation against quadrature, and Ambient Dice / SG-ambient exact for a
    constant environment (their bases contain the constant)."""
    lams = sorted({*SG_ERROR_LAMBDAS, *(sg_sharpness(n) for n in SG_COUNTS)})
    err = sg_cosine_error(lams, np.linspace(-1.0, 1.0, 41))
    worst = int(np.argmax(err["max_rel"]))
    out = [
        Check(
            name="SG ⊗ clamped cosine: Hill's shape with exact end values vs quadrature, "
            "max |S̃ − S|/S(λ, 1) "
            f"over λ ∈ {{{', '.join(f'{v:.3g}' for v in lams)}}} × 41 cosines (worst λ = "
            f"{err['lam'][worst]:.3g})",
            value=err["max_rel"][worst],
            expected=f"≤ {SG_ERROR_BOUND}",
            passed=err["max_rel"][worst] <= SG_ERROR_BOUND,
        )
    ]
    const = [n for n in names if n == "constant"]
    for method in ("ambient-dice", *(f"sg{n}-ambient" for n in SG_COUNTS)):
        if not const:
            break
        ap = _approximation(cases, "constant", method)
        q = _approximation(cases, "constant", "quadrature")
        if ap is None or q is None:
            continue
        gap = abs(ap["metrics"]["rel_rmse"]["value"] - q["metrics"]["rel_rmse"]["value"])
        out.append(
            Check(
                name=f"{method} reproduces a constant environment (rel. RMSE equal to the exact row's)",
                value=gap,
                expected="≤ 1e-9",
                passed=gap <= 1e-9,
            )
        )
    return out


def _published_checks(rendered) -> list[Check]:
    """Grace Cathedral's L2 coefficients against Ramamoorthi & Hanrahan 2001's table (if probe-grace ran)."""
    r = rendered.get("probe-grace")
    if r is None:
        return []
    coeffs, scale = rh2001_coefficients(r["env"].radiance_map)
    diff = float(np.max(np.abs(coeffs - probe_maps.RH2001_GRACE_L2)))
    tol = probe_maps.RH2001_TOLERANCE
    return [
        Check(
            name="probe-grace: L2 radiance coefficients vs Ramamoorthi & Hanrahan 2001's table (their "
            "frame "
            f"(x, y, z) = (w_y, w_z, −w_x), one fitted exposure ×{scale:.4g}): max |ΔL_lm| over 9 × RGB",
            value=diff,
            expected=f"≤ {tol} (the table's 2-decimal rounding 0.005 + 0.005)",
            passed=diff <= tol,
        )
    ]


# ============================================================================================== figures
def _figures(ctx, cfg, rendered, bases, per_env, cases, costs) -> list[dict]:
    out = ctx.out_dir
    figs = [
        *_error_map_figures(ctx, cfg, rendered, bases),
        *_sphere_figures(out, cfg, rendered, bases),
        _pareto_figure(out, cases, costs),
        _smape_figure(out, cfg, cases),
        _elevation_figure(out, cases),
        _sun_profile_figure(out, cfg, rendered, bases, per_env),
    ]
    return [f for f in figs if f]


def _pick(names, *wanted) -> list[str]:
    """Up to k names per prefix, in the run's order (sunsky: the middle elevations first)."""
    out = []
    for prefix, k in wanted:
        found = [n for n in names if n.startswith(prefix)]
        if prefix == "sunsky-" and len(found) > k:
            mid = len(found) // 2
            found = found[mid - k // 2 :] + found[: mid - k // 2]
        out += found[:k]
    return out


ERROR_MAP_ROWS = 6  # environments per error-map figure


def _error_map_figures(ctx, cfg, rendered, bases) -> list[dict]:
    """Error maps of every basis over the sphere of normals for every environment (the user's probes first),
    `ERROR_MAP_ROWS` environments per figure."""
    names = list(cfg["environments"])
    user = [n for n in names if n in probe_maps.user_probe_ids(cfg.get("probes"))]
    names = user + [n for n in names if n not in user]
    chunks = [names[i : i + ERROR_MAP_ROWS] for i in range(0, len(names), ERROR_MAP_ROWS)]
    return [
        _error_map_figure(
            ctx,
            cfg,
            rendered,
            bases,
            show,
            "figures/error_maps.png" if k == 0 else f"figures/error_maps_{k + 1}.png",
        )
        for k, show in enumerate(chunks)
    ]


def _error_map_figure(ctx, cfg, rendered, bases, show, name) -> dict:
    plt = figures.pyplot()
    h, w = 24, 48
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    uu, vv = np.meshgrid(u, v)
    nrm = envs.uv_to_direction(uu, vv).reshape(-1, 3)
    fig, axes = plt.subplots(
        len(show), len(BASES), figsize=(2.2 * len(BASES), 1.3 * len(show) + 0.6), squeeze=False
    )
    im = None
    for i, env_name in enumerate(show):
        env = rendered[env_name]["env"]
        ref = envs.irradiance_quadrature(env, nrm, supersample_for(env, cfg), quadrature_backend(ctx.variant))
        lum_r = ref @ LUMINANCE
        for j, row in enumerate(BASES):
            x = evaluate_row(row, bases[env_name], nrm) @ LUMINANCE
            err = (x - lum_r) / np.maximum(np.abs(lum_r), 0.05 * np.mean(np.abs(lum_r)))
            im = axes[i, j].imshow(
                err.reshape(h, w), cmap="RdBu_r", vmin=-1, vmax=1, extent=(0, 360, -90, 90)
            )
            axes[i, j].set_xticks([])
            axes[i, j].set_yticks([])
            if i == 0:
                axes[i, j].set_title(row.method, fontsize=8)
            if j == 0:
                axes[i, j].set_ylabel(env_name, fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.6, label="relative error (luminance)")
    figures.save_figure(fig, ctx.out_dir / name)
    return {
        "file": name,
        "section": "results",
        "caption": "Relative irradiance error over the sphere of normals (lat-long: normal elevation "
        "vertical, azimuth horizontal, +Z up at the top) for each basis and environment ("
        + ", ".join(show)
        + "), against the dense quadrature (validated against Mitsuba, see Checks); red too bright, blue "
        "too dark; errors are relative to max(E, 5% of the mean E).",
    }


def _sphere_figures(out, cfg, rendered, bases) -> list[dict]:
    figs = []
    show = _pick(cfg["environments"], ("sunsky-", 1), ("studio", 1), ("probe-", 2))
    for name in show:
        r = rendered[name]
        img_mean, _, _ = combine(r["parts"], "image")
        mask = r["mask"]
        gn = r["gbuffer"].normal[mask].astype(np.float64)
        panels = []
        for m in SPHERE_FIGURE_METHODS:
            img = np.zeros_like(img_mean)
            img[mask] = evaluate_row(ROW[m], bases[name], gn) / math.pi
            panels.append((METHODS[m].label, img))
        peak = float(np.percentile(img_mean[mask], 99))
        fname = f"figures/sphere_{name}.png"
        figures.image_comparison(
            out / fname,
            img_mean,
            panels,
            mask,
            error_scale=max(peak, 1e-12),
            title=f"{name}: Mitsuba reference, bases, signed error",
            exposure=max(peak, 1e-12),
        )
        figs.append(
            {
                "file": fname,
                "section": "results",
                "caption": f"White diffuse sphere under *{r['env'].label}*: the Mitsuba reference "
                "(point-sampled, direct light) and each basis evaluated at the pixel-centre normals "
                "(top, exposed so the 99th-percentile radiance is white), signed error as a fraction of that "
                "radiance (bottom).",
            }
        )
    return figs


def _mean_errors(cases, key: str = "rel_rmse") -> tuple[dict[str, float], float]:
    """Each method's mean ``key`` over the environments, and the mean noise floor of that metric."""
    err: dict[str, list] = {}
    floors = []
    for doc in cases:
        for ap in doc["approximations"]:
            err.setdefault(ap["method"], []).append(ap["metrics"][key]["value"])
            floors.append(ap["metrics"][key].get("noise_floor") or 0.0)
    return {m: float(np.mean(v)) for m, v in err.items()}, float(np.mean(floors)) if floors else 0.0


def _pareto_figure(out, cases, costs) -> dict:
    """One figure across every stored basis: mean relative RMSE against floats per channel (left) and
    against the measured ns per normal (right), each with its Pareto front and the noise floor."""
    plt = figures.pyplot()
    cost = {c["method"]: c["ns_per_pixel"] for c in costs}
    mean_err, floor = _mean_errors(cases)
    fig, axes = plt.subplots(1, 2, figsize=(10.4, 4.0), sharey=True)
    panels = (
        (
            "floats stored per channel (storage / 3)",
            {m: METHODS[m].storage / 3 for m in mean_err if METHODS[m].storage},
        ),
        ("evaluation cost (ns per normal, measured)", {m: cost[m] for m in mean_err if m in cost}),
    )
    for ax, (xlabel, xs) in zip(axes, panels, strict=True):
        pts = sorted(((x, mean_err[m], m) for m, x in xs.items()), key=lambda p: (p[0], p[1]))
        for x, y, m in pts:
            ax.scatter([x], [y], s=26, zorder=3)
            ax.annotate(m, (x, y), textcoords="offset points", xytext=(4, 3), fontsize=6.5)
        front, best = [], np.inf
        for x, y, _ in pts:
            if y < best:
                front.append((x, y))
                best = y
        if front:
            ax.plot(*zip(*front, strict=True), "k--", lw=0.8, label="Pareto front")
        if floor > 0:
            ax.axhline(floor, color="0.5", lw=0.8, ls=":", label="reference noise floor")
        ax.set_xlabel(xlabel)
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("mean relative RMSE over environments")
    name = "figures/pareto.png"
    figures.save_figure(fig, out / name)
    return {
        "file": name,
        "section": "results",
        "caption": "Every stored basis: error (relative RMSE of the irradiance, mean over all environments) "
        "against floats stored per channel (left) and against the measured evaluation cost per normal "
        "(right, see Cost), with each panel's Pareto front and the reference noise floor.",
    }


def _smape_figure(out, cfg, cases) -> dict:
    series = []
    env_ids = [c["id"] for c in cases]
    x = list(range(len(env_ids)))
    panels = ["relative RMSE", "sMAPE"]
    for key, panel in zip(("rel_rmse", "smape"), panels, strict=True):
        for row in ROWS:
            series.append(
                {
                    "x": x,
                    "y": [max(_metric(cases, e, row.method, key), 1e-6) for e in env_ids],
                    "label": row.method,
                    "panel": panel,
                    "style": "points" if METHODS[row.method].exact else "line",
                }
            )
        series.append(
            {
                "x": x,
                "y": [max(_floor(cases, e, NOISE_FLOOR_METHOD, key), 1e-6) for e in env_ids],
                "label": "noise floor",
                "ls": ":",
                "color": "0.5",
                "panel": panel,
            }
        )
    name = "figures/error_by_environment.png"
    figures.line_plot(
        out / name,
        "environment: " + ", ".join(f"{i}={e}" for i, e in enumerate(env_ids)),
        "error",
        series,
        y_log=True,
        panels=panels,
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Relative RMSE and sMAPE of each basis per environment (log scale) with the reference "
        "noise "
        "floor. sMAPE saturates where the reference is 0 (the dark side of a lone sun).",
    }


def _sun_profile_figure(out, cfg, rendered, bases, per_env) -> dict | None:
    """Irradiance against the angle between normal and sun, for the smallest lone sun (a clean 1-D
    function)."""
    suns = [n for n in cfg["environments"] if n.startswith("sun-")]
    if not suns:
        return None
    name = suns[0]
    env = rendered[name]["env"]
    nrm = rendered[name]["normals"]
    ang = np.degrees(np.arccos(np.clip(nrm @ np.asarray(env.sun.direction), -1, 1)))
    order = np.argsort(ang)
    peak = float(env.sun.irradiance[0])
    pe = per_env[name]
    series = [
        {
            "x": ang[order],
            "y": pe["mean"][order, 0] / peak,
            "yerr": 2 * pe["sig"][order, 0] / peak,
            "label": "Mitsuba (±2σ)",
            "style": "points",
            "color": "k",
        }
    ]
    for m in SUN_PROFILE_METHODS:
        series.append({"x": ang[order], "y": pe["evals"][m][order, 0] / peak, "label": m})
    fname = "figures/sun_profile.png"
    figures.line_plot(out / fname, "angle between normal and sun (°)", "E / E⊥", series)
    return {
        "file": fname,
        "section": "results",
        "caption": f"Irradiance under a lone sun ({env.label}) against the angle from the sun: Mitsuba at "
        "the "
        "Fibonacci normals and each basis at the same normals. SH ringing shows as negative values "
        "opposite the sun; the cube's curve depends on the normal's azimuth too (the spread of its "
        "points).",
    }


def _elevation_figure(out, cases) -> dict | None:
    sky = sorted(
        (c["parameters"]["sun_elevation_deg"], c["id"]) for c in cases if c["id"].startswith("sunsky-")
    )
    if len(sky) < 2:
        return None
    series = []
    for key, panel in (("smape", "sMAPE"), ("rel_rmse", "relative RMSE")):
        for row in BASES:
            series.append(
                {
                    "x": [e for e, _ in sky],
                    "y": [_metric(cases, cid, row.method, key) for _, cid in sky],
                    "label": row.method,
                    "panel": panel,
                }
            )
        series.append(
            {
                "x": [e for e, _ in sky],
                "y": [_floor(cases, cid, NOISE_FLOOR_METHOD, key) for _, cid in sky],
                "label": "noise floor",
                "panel": panel,
                "ls": ":",
                "color": "0.5",
            }
        )
    name = "figures/error_vs_sun_elevation.png"
    figures.line_plot(
        out / name, "sun elevation (°)", "error", series, panels=["sMAPE", "relative RMSE"], y_log=True
    )
    return {
        "file": name,
        "section": "results",
        "caption": "Error of each basis under Mitsuba's sunsky (baked sky + disc sun) as the sun rises.",
    }


# ============================================================================================== summary
def _sections(cfg) -> list[dict]:
    return [
        {
            "id": "method",
            "title": "Method",
            "text": "Each environment is a distant lat-long radiance map in Mitsuba's envmap "
            "convention (rotated +Y → +Z), optionally with a finite disc sun. Ground truth: Mitsuba "
            f"irradiance at {cfg['normals']} Fibonacci normals on a white unit sphere ({cfg['probe_spp']} "
            f"MIS samples each) and the point-sampled image of the sphere ({cfg['resolution']}², "
            f"{cfg['spp']} spp, `direct`). A sun is rendered as a second reference and added (one "
            "environment emitter per Mitsuba scene). The bases are built from the environment as an "
            "engine's baker would: SH by quadrature of the map's bilinear function (a disc sun in closed "
            "form), Valve's cube from the irradiance at the six axes, the NNLS cube by non-negative least "
            "squares against the irradiance at a dense Fibonacci set, λ by bisection (smallest λ without "
            "negative irradiance on 4096 + 26 normals). `sunsky` is baked from Mitsuba's emitter (sky: "
            "sun_scale 0; sun: its disc irradiance integrated from the emitter's radiance).",
        }
    ]


STORAGE_BUDGETS = (4, 6, 9, 12, 16, 25, None)
"""Floats per channel of the budget table (None: 27 and more, no limit)."""


def budget_winners(cases, costs) -> list[dict]:
    """Which stored basis wins at each storage budget (`STORAGE_BUDGETS`, floats per channel = ``storage``/3):
    the lowest mean relative RMSE among the bases that fit in it, and among those that use exactly that much
    (27+: ≥ 27), each mean over the environments where every candidate is resolved (`resolved_means`)."""
    sm, _ = _mean_errors(cases, "smape")
    cost = {c["method"]: c.get("ns_per_pixel") for c in costs}
    stored = [r for r in BASES if METHODS[r.method].storage and r.method in _mean_errors(cases)[0]]

    def per_channel(r):
        return METHODS[r.method].storage / 3

    out = []
    for b in STORAGE_BUDGETS:
        within = [r for r in stored if b is None or per_channel(r) <= b + 1e-9]
        exact = [r for r in stored if (per_channel(r) >= 27 if b is None else abs(per_channel(r) - b) < 1e-9)]
        err, at = (resolved_means(cases, [r.method for r in rs]) for rs in (within, exact))
        best = min((r for r in within if r.method in err), key=lambda r: err[r.method], default=None)
        best_exact = min((r for r in exact if r.method in at), key=lambda r: at[r.method], default=None)
        out.append(
            {
                "budget": "27+" if b is None else str(b),
                "best": best.method if best else None,
                "floats_per_channel": per_channel(best) if best else None,
                "rel_rmse": err[best.method] if best else None,
                "smape": sm.get(best.method) if best else None,
                "ns_per_normal": cost.get(best.method) if best else None,
                "best_at_budget": best_exact.method if best_exact else None,
                "candidates": len(within),
            }
        )
    return out


def _budget_sections(cases, costs) -> list[dict]:
    rows = budget_winners(cases, costs)

    def num(x, fmt="{:.3g}"):
        return "–" if x is None else fmt.format(x)

    lines = [
        "| floats per channel | best basis within the budget | its floats per channel | mean rel. RMSE "
        "| mean sMAPE | ns per normal | best basis using exactly this budget |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        lines.append(
            f"| {r['budget']} | {r['best'] or 'none fits'} | {num(r['floats_per_channel'], '{:g}')} | "
            f"{num(r['rel_rmse'])} | {num(r['smape'])} | {num(r['ns_per_normal'])} | "
            f"{r['best_at_budget'] or '–'} |"
        )
    return [
        {
            "id": "storage-budgets",
            "title": "Which basis wins at each storage budget",
            "text": "Derived from the method table (floats per channel = each method's stored floats per "
            "probe / 3) and this run's metrics: the basis with the lowest relative RMSE of the irradiance, "
            "mean over the environments where every candidate is resolved (errors within 2× the noise "
            "floor are not ranked), among those that fit in the budget, and among those that use "
            "exactly that many floats (27+: 27 or more). sMAPE and the cost (see Cost) of the winner "
            "beside it.\n\n" + "\n".join(lines),
            "placement": "after_results",
        }
    ]


def _probe_sections(cfg, rendered) -> list[dict]:
    """The user's probes: file, mapping (named or read off the aspect ratio), size, resampled rows."""
    ids = [n for n in probe_maps.user_probe_ids(cfg.get("probes")) if n in rendered]
    if not ids:
        return []
    lines = [
        "| environment | file | mapping | source (rows × columns) | resampled lat-long |",
        "| --- | --- | --- | --- | --- |",
    ]
    for n in ids:
        p = rendered[n]["env"].params
        how = "from the aspect ratio" if p.get("mapping_detected") else "named"
        h, w = p["source_shape"]
        m = rendered[n]["env"].radiance_map.shape
        lines.append(
            f"| {n} | `{Path(p['file']).name}` | {probe_maps.MAPPING_LABELS[p['mapping']]} ({how}) | "
            f"{h} × {w} | {m[0]} × {m[1]} |"
        )
    return [
        {
            "id": "your-probes",
            "title": "Your probes",
            "text": "Probes given with `--probe FILE[:MAPPING]`, resampled into rtfit's lat-long map (solid-"
            "angle weighted footprints, `rtfit.reference.probe_maps`). Their frame is the light-probe "
            "convention, +Y up (lat-long: the top row is the zenith, the image centre looks along −Z; "
            "angular and mirror-ball maps: the image centre is +Z, towards the camera; crosses: the "
            "front face −Z in the middle), turned so that +Y is rtfit's +Z. They are evaluated like "
            "every other environment (Mitsuba references, noise floors, error maps).\n\n" + "\n".join(lines),
        }
    ]


def _notes(ctx) -> list[str]:
    storage = {m.id: m.storage for m in METHODS.values()}
    notes = [
        "Irradiance in W/m² per linear-sRGB channel; the sphere is white (albedo 1), so its radiance is E/π. "
        "Errors are relative, so environments of different brightness compare directly.",
        "SH convention: real SH without the Condon–Shortley phase (R&H 2001); Dr.Jit's `sh_eval` has the "
        "phase (odd-m signs flipped).",
        "sMAPE is Probulator's irradiance error, |x − r|/(x + r) per texel and channel (its Image.cpp "
        "`imageSymmetricAbsolutePercentageError`: no factor 2, range [0, 1]); Probulator shows it as an "
        "image over lat-long texels, here it is averaged over uniformly spread normals, with |x| + |r| in "
        "the denominator so that ringing (x < 0) stays in [0, 1] (the same value wherever x ≥ 0).",
        "A sun and a lat-long map are rendered as two Mitsuba references (one environment emitter per "
        "scene) and added; the standard errors add in quadrature.",
        'Seed erratum: 000:2497 calls the nine SH colours "the first two orders"; nine coefficients are '
        "bands l = 0, 1, 2 (order 2).",
        f"Storage per probe: ambient cube {storage['cube-valve']} floats, SH L1 {storage['sh-l1']}, "
        f"SH L2 {storage['sh-l2']} (RGB).",
        envs.PROBE_CREDITS,
    ]
    gone = missing_probes(ctx.quick)
    if gone:
        notes.append(
            f"Measured probes not found in {envs.probe_dir()} (set RTFIT_PROBE_DIR): {', '.join(gone)} left "
            "out of this run."
        )
    return notes


def _summary(cfg, cases, checks) -> str:
    def mean_of(m, key="rel_rmse"):
        return float(np.mean([_metric(cases, c["id"], m, key) for c in cases]))

    probes = [c["id"] for c in cases if c["id"].startswith("probe")]
    prb = (
        f" On the measured probes ({', '.join(p[6:] for p in probes)}) SH L2 reaches "
        f"{np.mean([_metric(cases, p, 'sh-l2', 'rel_rmse') for p in probes]):.3g} against "
        f"{np.mean([_metric(cases, p, 'cube-valve', 'rel_rmse') for p in probes]):.3g} for Valve's cube and "
        f"{np.mean([_metric(cases, p, 'sh-l1-geomerics', 'rel_rmse') for p in probes]):.3g} for Geomerics L1."
        if probes
        else ""
    )
    passed = sum(c["passed"] for c in checks)
    return (
        f"Over {len(cases)} environments, the mean relative RMSE of the irradiance against Mitsuba is: "
        f"Valve ambient cube {mean_of('cube-valve'):.3g}, NNLS-optimal cube {mean_of('cube-nnls'):.3g}, SH "
        f"L1 {mean_of('sh-l1'):.3g}, Geomerics L1 {mean_of('sh-l1-geomerics'):.3g}, SH L2 "
        f"{mean_of('sh-l2'):.3g}, L2 with the fitted λ window {mean_of('sh-l2-lambda'):.3g}; the dense "
        f"quadrature sits at the noise floor ({mean_of('quadrature'):.3g}, floor "
        f"{float(np.mean([_floor(cases, c['id'], 'quadrature', 'rel_rmse') for c in cases])):.3g}).{prb} "
        f"Plain L2 goes negative on a fraction {mean_of('sh-l2', 'neg_frac'):.3g} of the normals on "
        f"average (opposite suns and bright softboxes) and L1 on {mean_of('sh-l1', 'neg_frac'):.3g}; the "
        "fitted λ window removes it at a large cost in accuracy, Geomerics' L1 never rings. sMAPE (mean "
        f"over environments): cube {mean_of('cube-valve', 'smape'):.3g}, L1 "
        f"{mean_of('sh-l1', 'smape'):.3g}, L2 {mean_of('sh-l2', 'smape'):.3g}. Higher orders: SH L4 (75 "
        f"floats) {mean_of('sh-l4'):.3g}, L3 (48) the same as L2 (Â_3 = 0); ZH3 (15 floats) "
        f"{mean_of('zh3'):.3g}, hallucinated ZH3 (12) {mean_of('zh3-hallucinated'):.3g}. "
        "Spherical Gaussians "
        "(rel. RMSE, least squares / ambient): "
        + ", ".join(
            f"{n} lobes {mean_of(f'sg{n}-ls'):.3g} / {mean_of(f'sg{n}-ambient'):.3g}" for n in SG_COUNTS
        )
        + " (the SG-cosine approximation alone errs by up to 5% of a lobe's peak); Ambient Dice (36 floats) "
        f"{mean_of('ambient-dice'):.3g}. {passed} of {len(checks)} checks passed."
    )


# ================================================================================================ bench
def _cost_inputs(n: int, backend: str):
    """``n`` Fibonacci normals as float32 NumPy (n, 3) and as a Dr.Jit Array3f on ``backend``."""
    nrm = fibonacci_sphere(n).astype(np.float32)
    mod = dr.cuda if backend == "cuda" else dr.llvm
    return nrm, mod.Array3f(nrm.T)


def _demo_bases() -> dict:
    """Fixed coefficients for the timings (a disc sun over a constant sky, a random cube, λ = 0.05)."""
    rng = np.random.default_rng(3)
    sh = sh_from_disk([0.3, 0.4, 0.866], 0.1, np.array([3.0, 2.5, 2.0]), SH_MAX_ORDER)
    sh += sh_from_constant(2.0 / math.sqrt(4 * math.pi), SH_MAX_ORDER)
    cube = rng.uniform(0.2, 2.0, (6, 3))
    sg = {f"sg{n}_{f}": rng.uniform(0.2, 2.0, (n + 1, 3)) for n in SG_COUNTS for f in SG_FITS}
    dice = rng.uniform(0.2, 2.0, (12, 3))
    return {
        "sh": sh,
        "zh3": zh3_from_sh(sh),
        "zh3_lum": zh3_from_sh(sh, shared_axis=True),
        "cube_valve": cube,
        "cube_nnls": cube,
        "lambda": 0.05,
        "lambda_l3": 0.05,
        "lambda_l4": 0.05,
        "ambient_dice": dice,
        **sg,
    }


def _costs(ctx) -> list[dict]:
    """Dr.Jit evaluation cost of every basis per normal, and the memory-traffic floor."""
    backend = backend_of(ctx.variant)
    n = 1 << (20 if ctx.quick else 24 if backend == "cuda" else 22)
    _, nd = _cost_inputs(n, backend)
    b = _demo_bases()
    rows = [
        cost_row(
            row.method,
            METHODS[row.method].label,
            backend,
            time_drjit(lambda v, row=row: evaluate_row(row, b, v), (nd,), n),
            f"per normal (pixel): unit normal in memory, RGB out; {METHODS[row.method].storage} floats "
            "per probe",
            floats_per_probe=METHODS[row.method].storage,
        )
        for row in BASES
    ]
    rows += hemisphere.cost_rows(nd, n, backend)  # the lightmap bases (hemisphere section)
    return [
        *rows,
        memory_floor_row((nd.x, nd.y, nd.z), n, backend, "the memory-bound floor (one output channel)"),
    ]


def _bench_rows() -> list[Row]:
    """One row per distinct kernel and signature (kernel, storage, free parameters): the cube bakes share a
    kernel, and Hann/Lanczos are L2 with constant factors (the cost of plain L2)."""
    seen, out = set(), []
    for row in BASES:
        key = (METHODS[row.method].kernel, METHODS[row.method].storage, tuple(METHODS[row.method].params))
        if key not in seen:
            seen.add(key)
            out.append(row)
    return out


def bench_reference(ctx, mi, cfg: dict) -> list[dict]:
    """The references' samples/s beside ``mi.render`` of the same scene (the white sphere under the studio
    map) with the same integrator, side by side (`reference_vs_stock_rows`): the sphere image (radiance
    pass, the same estimator as ``mi.render``) and the irradiance probes (the same direct estimator per
    sample, emitter + cosine sampling with MIS; ``mi.render`` also traces a camera ray per sample; the probes
    on the device before the timing, `device_probes`: a reference's passes share one upload), at each of
    `reference_sizes` (non-quick: 256² × 256 spp and the pixel-bound 1024² × 64 spp)."""
    env = make_environment("studio", cfg, mi)
    rows = []
    with tempfile.TemporaryDirectory(prefix="rtfit-bench-") as tmp:
        map_file = None
        if env.radiance_map is not None:
            map_file = str(envs.write_map_exr(env.radiance_map, Path(tmp) / "studio.exr"))
        for res, spp in reference_sizes(ctx.quick, (64, 64), (256, 256)):
            scene = sky_scene(env, map_file, res)
            _, ms = load_mitsuba_scene(scene, ctx.variant)
            n = fibonacci_sphere(res * res).astype(np.float32)
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            samples = res * res * spp
            stock = [
                Stock(
                    f"mi.render, same scene and integrator ({res}², {spp} spp)",
                    stock_render(mi, ms, spp),
                    samples,
                )
            ]
            rounds = 3 if ctx.quick else 5
            # the probes on the device once per reference, as the reference cache does
            probes = device_probes(mi, n, n, normalise=False)
            rows += reference_vs_stock_rows(
                f"rtfit sphere image reference ({res}², {spp} spp)",
                lambda seed, ms=ms, spp=spp: radiance_pass(mi, ms, spp, seed, REFERENCE_PASS_DTYPE),
                samples,
                stock,
                ctx.variant,
                rounds,
            ) + reference_vs_stock_rows(
                f"rtfit irradiance probes, direct MIS ({res * res} normals on the device, {spp} spp)",
                lambda seed, ms=ms, probes=probes, spp=spp: irradiance_pass(
                    mi, ms, probes, None, spp, seed, dtype=REFERENCE_PASS_DTYPE
                ),
                samples,
                stock,
                ctx.variant,
                rounds,
            )
    return rows


def bench(ctx) -> list[dict]:
    """Dr.Jit vs NumPy (same kernel text) per basis in normals/s, then projection time per environment."""
    backend, n = bench_backend(ctx)
    nrm, nd = _cost_inputs(n, backend)
    n64 = nrm[: numpy_elements(n)].astype(np.float64)  # NumPy's rows: at most 2^22 normals
    b = _demo_bases()
    base = memory_baseline((nd.x, nd.y, nd.z), n)
    rows = []
    for row in _bench_rows():
        m = METHODS[row.method]
        t_dr = time_drjit(lambda v, row=row: evaluate_row(row, b, v), (nd,), n)
        inputs, params = basis_inputs(m, b[row.source], n64), row_params(row, b)
        t_np = time_numpy(
            lambda m=m, inputs=inputs, params=params: m(NUMPY_OPS, inputs, params), (), len(n64)
        )
        rows.append(comparison_row(m.label, backend, t_dr, t_np, base, unit="normals", per="normal"))
    rows += hemisphere.bench_rows(nd, n64, n, backend, base)  # the lightmap bases
    rows.append(baseline_row(base, backend, "memory baseline", unit="normals", per="normal"))
    mi = use_variant(ctx.variant)
    cfg = configure(ctx.quick, None)
    for name in ("studio", "sunsky-60", "probe-grace"):
        t0 = time.perf_counter()
        env = make_environment(name, cfg, mi)
        bake = time.perf_counter() - t0
        bb = build_bases(env, cfg, 512, quadrature_backend(ctx.variant))
        shape = None if env.radiance_map is None else list(env.radiance_map.shape[:2])
        rows.append(
            {
                "what": f"projection: {name} map {shape}",
                "backend": "numpy",
                "elements": None,
                "bake_or_load_ms": 1e3 * bake,
                **{f"{k}_ms": v for k, v in bb["timing_ms"].items()},
            }
        )
    rows += bench_reference(ctx, mi, cfg)
    return rows
