"""Experiment ``sdf-occlusion``: Evans' multi-scale SDF skylight/occlusion and cone-traced distance-field
occlusion against Mitsuba ray-cast ambient occlusion and sky light.

Scenes (``scenes/library/sdf_*.toml``, geometry from `rtfit.experiments.sdf_occlusion_scenes`): creases
of 30°/60°/90°/120°, a sphere on a plane, a room with an open window, a city block of boxes and a
procedural character (held out of the joint fit).

Ground truth (`rtfit.reference.occlusion`), at the pixel-centre G-buffer points of each scene's camera:

* ``ao``: cosine-weighted visibility within ``ao_distance`` (scene units);
* ``sky``: irradiance from a constant upper-hemisphere sky (no sun), one bounce, as E/(πL);
* ``sky-gi``: the same with all interreflections between white diffuse surfaces of albedo ``albedo``;
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

The fit: for fixed α and base distance the Evans model is C = exp(log B − Σ_i c_i D_i) with D_i = d_i − s_i
computed once by the Dr.Jit kernel, so (log B, c_i = k·w_i) are fitted by Levenberg–Marquardt
(optimistix, `rtfit.fitting.fit_least_squares`) and α, base are profiled over a grid (α ∈ {0, ¼, ½, ¾, 1},
base ∈ {½, 1, 2} voxels): the reported α and base carry the grid's resolution, not a stderr.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .jobs import Job

TARGETS_QUICK = ("ao", "sky")
TARGETS_FULL = ("ao", "sky", "sky-gi")
TARGET_QUANTITY = {"ao": "ao", "sky": "sky_direct", "sky-gi": "sky_global"}
TARGET_LABEL = {"ao": "AO (cosine-weighted visibility within R)", "sky": "sky light, one bounce (E/πL)",
                "sky-gi": "sky light, global illumination (E/πL)"}
HELD_OUT = "character"
METHODS = ("evans-text", "evans-listing", "evans-fit", "evans-joint", "curvature", "cone")
LABELS = {"evans-text": "Evans, seed text (α=½, w=1; k fit)", "evans-listing": "Evans, seed listing (α=1, w=1…1.8; k, B fit)",
          "evans-fit": "Evans, fitted per case", "evans-joint": "Evans, joint fit", "curvature": "Curvature (seed §9.5; k fit)",
          "cone": "Cone-traced DF AO (k grid-searched)", "sdfgrid": "Mitsuba AO on the sdfgrid (grid error)",
          "evans-analytic": "Evans fitted, exact analytic SDF (no grid, no blur)",
          "evans-on-sdfgrid": "Evans fitted, on the voxelised geometry vs its own AO (model error only)"}
ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0)
BASES_VOX = (0.5, 1.0, 2.0)
CONE_KS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
CREASE_PROBE_X = (0.05, 0.1, 0.2, 0.4)  # floor probes (y = 0) of the creases: the finite arms are exact within R = 1
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
        "sweep_scenes": ["crease_90", "sphere_plane", "boxes"] if quick else ["crease_90", "boxes", "character"],
        "alphas": [0.0, 0.5, 1.0] if quick else list(ALPHAS),
        "bases_vox": [1.0] if quick else list(BASES_VOX),
        "map_scenes": ["crease_90", "room", "boxes", "character"] if quick else list(SCENE_NAMES),
        "probe_spp": 2048 if quick else 16384,
        "cost_points": (1 << 17) if quick else (1 << 22),
        "cone_count": 9,
        "cone_steps": 8,
    }


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
    h = hashlib.sha256(v.astype(np.float32).tobytes() + f.astype(np.int32).tobytes() + str(resolution).encode())
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
def render_case(name: str, resolution: int, spp: int, pass_spp: int, seed: int, variant: str, cache_dir: str,
                targets: list, ao_distance: float, albedo: float, grid: int, probe_spp: int = 2048) -> dict:
    """Job: G-buffer, occlusion references and the sdfgrid AO of one scene (plain data out)."""
    from rtfit.reference import load_mitsuba_scene
    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.occlusion import OcclusionCache, sdfgrid_scene
    from rtfit.scenes import scene_hash

    scene = load_case_scene(name, resolution)
    mi, mi_scene = load_mitsuba_scene(scene, variant)
    gb = gbuffer(mi, mi_scene)
    mask = gb.mask
    pts, nrm = gb.position[mask].astype(np.float64), gb.normal[mask].astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cache = OcclusionCache(cache_dir)
    geo = scene_hash(scene)
    refs = {}
    for t in targets:
        r = cache.get(mi, mi_scene, geo, pts, nrm, spp=spp, pass_spp=pass_spp, seed=seed, variant=variant,
                      quantity=TARGET_QUANTITY[t], max_distance=ao_distance if t == "ao" else math.inf,
                      albedo=albedo)
        refs[t] = {"mean": r.mean, "stderr": r.stderr, "meta": r.to_dict()}
    probes = None
    if name.startswith("crease_"):
        xs = np.array(CREASE_PROBE_X)
        pp = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, 1e-6)])
        pn = np.tile([0.0, 0.0, 1.0], (len(xs), 1))
        r = cache.get(mi, mi_scene, geo, pp, pn, spp=probe_spp, pass_spp=min(probe_spp, 1024), seed=seed,
                      variant=variant, quantity="ao", max_distance=ao_distance)
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
        r2 = cache.get(mi, mi_sdf, "sdfgrid-" + gh, p2[ok], n2[ok], spp=spp, pass_spp=pass_spp, seed=seed,
                       variant=variant, quantity="ao", max_distance=ao_distance)
        img2 = np.full(m2.shape, np.nan)
        idx = np.flatnonzero(m2)[ok]
        img2.reshape(-1)[idx] = r2.mean
        err2 = np.full(m2.shape, np.nan)
        err2.reshape(-1)[idx] = r2.stderr
        meta2 = r2.to_dict()
        sdf_error = None
        sdf_gb = {"mask": np.isfinite(img2), "points": p2[ok], "normals": n2[ok],
                  "refs": {"ao": {"mean": r2.mean, "stderr": r2.stderr, "meta": meta2}}}
    return {"mask": mask, "points": pts, "normals": nrm, "refs": refs, "grid": {"values": g.values,
            "origin": g.origin, "voxel": g.voxel}, "sdfgrid_ao": img2, "sdfgrid_ao_stderr": err2,
            "sdfgrid_meta": meta2, "sdfgrid_error": sdf_error, "sdfgrid_gbuffer": sdf_gb, "scene_hash": geo, "probes": probes, "triangles": int(len(mesh_of(scene)[1]))}


def run(ctx) -> dict:
    from . import sdf_occlusion_report as rep

    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    jobs = [Job("rtfit.experiments.sdf_occlusion:render_case",
                dict(name=n, resolution=cfg["resolution"], spp=cfg["spp"], pass_spp=cfg["pass_spp"], seed=ctx.seed,
                     variant=ctx.variant, cache_dir=str(ctx.cache_dir), targets=cfg["targets"],
                     ao_distance=cfg["ao_distance"], albedo=cfg["albedo"], grid=cfg["grid"],
                     probe_spp=cfg["probe_spp"]), label=n)
            for n in cfg["scenes"]]
    ctx.log(f"rendering references of {len(jobs)} scenes")
    rendered = dict(zip([j.label for j in jobs], ctx.executor.map(jobs, desc="references")))

    from rtfit.realtime import set_default_backend

    set_default_backend("cuda" if ctx.variant.startswith("cuda") else "llvm")
    return rep.assemble(ctx, cfg, rendered)


def bench(ctx) -> list[dict]:
    from . import sdf_occlusion_report as rep

    return rep.bench(ctx)
