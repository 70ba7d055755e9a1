"""Experiment ``irradiance-volumes``: a grid of ambient cubes / SH L2 probes over a room lit by a bright point
light, looked up nearest and trilinear, against path-traced irradiance at surface points.

What is compared, and why (docs/irradiance-volumes.md; seed 000 chapter 7, 2502-2515):

* **The scene** (`scenes/library/volume_room.toml`): a closed 4 × 4 × 2.5 m room with a red and a green
  side wall, one bright point light and a thin occluding wall between the light and part of the floor.
* **The volume.** Probes on nested grids over the room (`GRID_ORIGIN`, spacing 1.5 m halved per level, every
  coarser grid a subset of the finest one). At each probe Mitsuba path-traces the incident radiance along
  uniformly sampled directions (`rtfit.reference.probe_radiance`); the same samples project onto SH L2
  (L_lm = ∫ L Y_lm dω), Valve's ambient cube (the irradiance at the six axes) and the irradiance at
  `NNLS_NORMALS` Fibonacci normals, to which the NNLS cube is fitted. A point light is never hit by a ray,
  so the probes hold only bounced light — what Valve's irradiance volume stores ("the ambient cube data …
  incorporates only bounced or indirect lighting").
* **Two quantities.** ``indirect``: the volume as stored, against the path-traced *indirect* irradiance at
  surface points (cosine-sampled paths; the point light reaches them only by next-event estimation at the
  first bounce). ``folded``: the point light folded into every probe as a distant light from its direction at
  the probe (seed 7.4.3: lights beyond the two most important are "added into the ambient cube on the fly";
  `rtfit.realtime.irradiance_volumes.fold_point_light`, with the probe's own shadow ray), against the *total*
  irradiance (the point light's exact shadowed I·cos/r² plus the indirect reference). The folded rows are
  next to ``direct + …``: the engine's usual split (exact per-pixel direct light, the volume for the rest).
* **Rows**: `rtfit.realtime.irradiance_volumes.METHODS`, lookup (nearest, trilinear) × basis (Valve cube,
  NNLS cube, SH L2), per grid spacing (the knob: `configure`'s ``levels``).
* **Popping**: the irradiance along a line through the room as a point moves across the nearest lookup's
  cell boundaries (pairs of points ± `BOUNDARY_EPS` around every boundary): the step of the error there.
* **Cost**: ns per lookup of each method (Dr.Jit, float32), the probes' storage per spacing.
* **Self-checks**: a white furnace (constant environment, no geometry: the probes' projections against their
  closed forms within their noise, and a volume of exact constant probes is π everywhere); the direct
  reference against the closed form I·max(n·d, 0)/r² with an analytic shadow test; the probes' irradiance
  against the surface estimator at the same points and normals (two independent estimators); the lookup
  reproduces each probe at its node.

Sections: configure · scene and grids · points · jobs · run · assembly (cases, popping) · checks · figures ·
summary · bench.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from rtfit.fitting import compute_metrics, robust_spread, sidak_threshold, smape
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.arrays import backend_float, backend_type
from rtfit.realtime.irradiance_bases import (
    CUBE_AXES,
    sh9_from_constant,
)
from rtfit.realtime.irradiance_volumes import (
    METHODS,
    VOLUME_BASES,
    ProbeGrid,
    directional_irradiance,
    fold_point_light,
    probe_table,
    volume_inputs,
    volume_irradiance,
)
from rtfit.reference import ReferenceCache, ReferenceRequest, load_mitsuba_scene
from rtfit.reference.probe_radiance import ProbeRadianceCache, point_light_visibility
from rtfit.scenes import library_path, load_scene, parse_scene_text, scene_hash, scene_to_toml
from rtfit.scenes.model import ConstantEnv, Cube, PointLight, ReferenceSettings, Scene

from . import figures as F
from .cost import (
    attach_costs,
    bench_backend,
    comparison_rows,
    cost_backend,
    cost_row,
    memory_floor_row,
    time_drjit,
    time_numpy,
)
from .jobs import Job
from .probe_projection import FEATURE_NORMALS, FEATURES_NAME, probe_bases, probe_features
from .records import Check
from .registry import SPP_MAX, ConfigKey, checked

# ============================================================================================ configure
CONFIG = {
    "levels": ConfigKey(
        "int", "grid spacings 1.5 m / 2^k, k = 0 … levels − 1 (the finest is rendered)", 1, 5
    ),
    "probe_spp": ConfigKey("int", "uniform directions (paths) per probe", 16, SPP_MAX),
    "probe_pass_spp": ConfigKey("int", "directions per probe in one cached pass", 16, SPP_MAX),
    "spp": ConfigKey("int", "reference samples per surface point (indirect and direct)", 2, SPP_MAX),
    "pass_spp": ConfigKey("int", "reference samples per point of one cached pass", 2, SPP_MAX),
    "floor_points": ConfigKey(
        "int", "surface points per side of the floor grid (walls, occluder: half)", 4, 512
    ),
    "line_points": ConfigKey(
        "int", "evenly spaced points of the popping line (plus boundary pairs)", 8, 8192
    ),
    "cost_elements": ConfigKey("int", "lookups per timed launch", 1024, 1 << 26),
}
"""Every key of `configure`: type, range, meaning (`registry.ConfigKey`)."""


def configure(quick: bool, spp: int | None) -> dict:
    return checked(
        CONFIG,
        {
            "levels": 3 if quick else 4,
            "probe_spp": 1024 if quick else 8192,
            "probe_pass_spp": 1024 if quick else 4096,
            "spp": spp or (256 if quick else 4096),
            "pass_spp": 256 if quick else 1024,
            "floor_points": 16 if quick else 40,
            "line_points": 64 if quick else 384,
            "cost_elements": 1 << (18 if quick else 22),
        },
    )


# ================================================================================== scene and grids
SCENE_NAME = "volume_room"
GRID_ORIGIN = (-1.5, -1.5, 0.25)
"""First node of every grid (m). Grids span x, y ∈ [−1.5, 1.5], z ∈ [0.25, 1.75]; the room is
[−2, 2]² × [0, 2.5], so floor and wall points lie outside the grid and are clamped to it (as in a game)."""
COARSE_SPACING = 1.5
COARSE_CELLS = (2, 2, 1)
"""Cells of the coarsest grid per axis; level k has 2^k times as many with spacing 1.5/2^k m."""
BOUNDARY_EPS = 1e-3
"""Half-distance (m) of the point pairs straddling each cell boundary on the popping line."""
LINE_Y, LINE_Z = 1.3, 1.0
LINE_NORMAL = (-0.6, 0.0, 0.8)
"""The popping line: x from −1.9 to 1.9 m at y = 1.3 (beside the occluder, which spans |y| ≤ 1), z = 1.0 (a
node plane of every grid, so only the x boundaries are crossed), normal towards the light's side and up."""
QUANTITIES = ("indirect", "folded")
QUANTITY_LABELS = {"indirect": "indirect irradiance", "folded": "total irradiance, light folded"}


def room_scene() -> Scene:
    return load_scene(library_path(SCENE_NAME))


def point_light(scene: Scene):
    (light,) = [x for x in scene.lights if isinstance(x, PointLight)]
    return np.asarray(light.position, dtype=np.float64), np.asarray(light.intensity, dtype=np.float64)


def occluder_box(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) corners of the scene's one cube (the occluding wall)."""
    (box,) = [s for s in scene.shapes if isinstance(s, Cube)]
    c, h = np.asarray(box.center), np.asarray(box.size) / 2
    return c - h, c + h


def furnace_scene(room: Scene) -> Scene:
    """The white furnace: no geometry, constant environment of radiance 1 (every probe sees L = 1)."""
    return Scene(
        name="volume-furnace",
        camera=room.camera,
        lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),),
        reference=ReferenceSettings(transport="direct"),
        description="White furnace for the irradiance-volume probes: constant environment of radiance 1.",
    )


def finest_grid(levels: int) -> ProbeGrid:
    k = 2 ** (levels - 1)
    return ProbeGrid(GRID_ORIGIN, COARSE_SPACING / k, tuple(c * k + 1 for c in COARSE_CELLS))  # type: ignore[arg-type]


def level_grids(levels: int) -> list[tuple[ProbeGrid, np.ndarray]]:
    """(grid, indices of its nodes in the finest grid), coarsest first."""
    fine = finest_grid(levels)
    return [fine.subgrid(2 ** (levels - 1 - k)) for k in range(levels)]


# =========================================================================================== points
def _plane_grid(n: int, center, u, v, half_u: float, half_v: float, normal) -> tuple[np.ndarray, np.ndarray]:
    a = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    uu, vv = np.meshgrid(a * half_u, a * half_v, indexing="ij")
    p = np.asarray(center) + uu.reshape(-1, 1) * np.asarray(u) + vv.reshape(-1, 1) * np.asarray(v)
    return p, np.repeat(np.asarray(normal, dtype=np.float64)[None], len(p), axis=0)


def surface_points(cfg: dict, scene: Scene) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Surface point groups {name: (points, normals)}: floor, the occluder's two large faces, the green wall
    and the +y wall, the ceiling (cell-centred grids, 1 cm inside each face's edges)."""
    n = cfg["floor_points"]
    m = max(n // 2, 2)
    lo, hi = occluder_box(scene)
    oc, oh = (lo + hi) / 2, (hi - lo) / 2
    return {
        "floor": _plane_grid(n, (0, 0, 0), (1, 0, 0), (0, 1, 0), 1.99, 1.99, (0, 0, 1)),
        "occluder, light side": _plane_grid(
            m, (lo[0], oc[1], oc[2]), (0, 1, 0), (0, 0, 1), oh[1] - 0.01, oh[2] - 0.01, (-1, 0, 0)
        ),
        "occluder, shadow side": _plane_grid(
            m, (hi[0], oc[1], oc[2]), (0, 1, 0), (0, 0, 1), oh[1] - 0.01, oh[2] - 0.01, (1, 0, 0)
        ),
        "green wall": _plane_grid(m, (2.0, 0, 1.25), (0, 1, 0), (0, 0, 1), 1.99, 1.24, (-1, 0, 0)),
        "+y wall": _plane_grid(m, (0, 2.0, 1.25), (1, 0, 0), (0, 0, 1), 1.99, 1.24, (0, -1, 0)),
        "ceiling": _plane_grid(m, (0, 0, 2.5), (1, 0, 0), (0, 1, 0), 1.99, 1.99, (0, 0, -1)),
    }


def line_points(cfg: dict, grids: list[ProbeGrid]) -> np.ndarray:
    """x of the popping line: evenly spaced, plus x = b ± `BOUNDARY_EPS` around every x cell boundary b of
    every grid (sorted)."""
    xs = [np.linspace(-1.9, 1.9, cfg["line_points"])]
    for g in grids:
        b = g.boundaries(0)
        xs += [b - BOUNDARY_EPS, b + BOUNDARY_EPS]
    return np.unique(np.concatenate(xs))


def check_points(grid: ProbeGrid) -> tuple[np.ndarray, np.ndarray]:
    """Each node of ``grid`` with the six axis normals (count·6 points): where the probes' cube entries and
    the surface estimator measure the same irradiance."""
    p = np.repeat(grid.positions(), 6, axis=0)
    n = np.tile(np.asarray(CUBE_AXES), (grid.count, 1))
    return p, n


# ============================================================================================= jobs
def probe_job(
    scene_toml: str, positions, spp: int, pass_spp: int, seed: int, variant: str, cache_dir: str
) -> dict:
    """Job: the probes' projections (`probe_features`) at ``positions`` (cached), and whether each probe
    sees the scene's point light (1/0; 1 where the scene has none)."""
    scene = parse_scene_text(scene_toml)
    mi, ms = load_mitsuba_scene(scene, variant)
    pos = np.asarray(positions, dtype=np.float64)
    ref = ProbeRadianceCache(cache_dir).get(
        mi,
        ms,
        scene_hash(scene),
        pos,
        probe_features,
        FEATURES_NAME,
        spp=spp,
        pass_spp=pass_spp,
        seed=seed,
        variant=variant,
    )
    lights = [x for x in scene.lights if isinstance(x, PointLight)]
    visible = point_light_visibility(mi, ms, pos, lights[0].position) if lights else np.ones(len(pos))
    return {"mean": ref.mean, "stderr": ref.stderr, "reference": ref.to_dict(), "visible": visible}


def surface_job(
    scene_toml: str,
    points,
    normals,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str,
    cache_dir: str,
    progress: bool = False,
) -> dict:
    """Job: indirect (path-traced along cosine directions) and direct (the point light, emitter sampling +
    shadow ray) irradiance at ``points`` with ``normals``, cached `ReferenceCache` entries."""
    scene = parse_scene_text(scene_toml)
    out = {}
    for name, transport in (("indirect", "global"), ("direct", "direct")):
        ref = ReferenceCache(cache_dir).get(
            ReferenceRequest(
                scene=scene,
                spp=spp,
                quantity="irradiance",
                seed=seed,
                variant=variant,
                pass_spp=pass_spp,
                points=np.asarray(points),
                normals=np.asarray(normals),
                transport=transport,
            ),
            progress=progress,
            label=f"{scene.name} {name}",
        )
        out[name] = {"mean": ref.mean, "stderr": ref.stderr, "reference": ref.to_dict()}
    return out


# ============================================================================================== run
def run(ctx) -> dict:
    cfg = ctx.configured(configure(ctx.quick, ctx.spp))
    room = room_scene()
    furnace = furnace_scene(room)
    grids = level_grids(cfg["levels"])
    fine = grids[-1][0]
    groups = surface_points(cfg, room)
    xs = line_points(cfg, [g for g, _ in grids])
    line_p = np.stack([xs, np.full_like(xs, LINE_Y), np.full_like(xs, LINE_Z)], axis=1)
    line_n = np.repeat(np.asarray(LINE_NORMAL)[None] / np.linalg.norm(LINE_NORMAL), len(xs), axis=0)
    chk_p, chk_n = check_points(grids[0][0])
    pts = np.concatenate([g[0] for g in groups.values()] + [line_p, chk_p])
    nrm = np.concatenate([g[1] for g in groups.values()] + [line_n, chk_n])
    common = dict(seed=ctx.seed, variant=ctx.variant, cache_dir=str(ctx.cache_dir))
    furnace_pos = np.array([[0.0, 0.0, 0.0], [0.3, -0.7, 1.1], [-1.2, 0.4, 2.0]])
    jobs = [
        Job(
            probe_job,
            dict(
                scene_toml=scene_to_toml(room),
                positions=fine.positions(),
                spp=cfg["probe_spp"],
                pass_spp=cfg["probe_pass_spp"],
                **common,
            ),
            label=f"probes ({fine.count})",
        ),
        Job(
            probe_job,
            dict(
                scene_toml=scene_to_toml(furnace),
                positions=furnace_pos,
                spp=cfg["probe_spp"],
                pass_spp=cfg["probe_pass_spp"],
                **common,
            ),
            label="furnace probes",
        ),
        Job(
            surface_job,
            dict(
                scene_toml=scene_to_toml(room),
                points=pts,
                normals=nrm,
                spp=cfg["spp"],
                pass_spp=cfg["pass_spp"],
                progress=ctx.progress,
                **common,
            ),
            label=f"surface references ({len(pts)} points)",
        ),
    ]
    ctx.log(f"rendering {fine.count} probes and {len(pts)} surface references")
    probes, furnace_probes, surface = ctx.executor.map(jobs, desc="references")
    sizes = [len(g[0]) for g in groups.values()] + [len(line_p), len(chk_p)]
    cut = np.cumsum([0, *sizes])
    data = {
        "points": pts,
        "normals": nrm,
        "cut": cut,
        "groups": list(groups),
        "line_x": xs,
        "light": point_light(room),
        "occluder": occluder_box(room),
    }
    return assemble(ctx, cfg, room, grids, probes, furnace_probes, surface, data)


# ========================================================================================= assembly


def folded_bases(
    mean: np.ndarray, positions: np.ndarray, light, visible: np.ndarray
) -> dict[str, np.ndarray]:
    """`probe_bases` with the point light folded into each probe (`fold_point_light`, visibility from the
    probe's shadow ray); the NNLS cube is refitted on the folded irradiance."""
    q, intensity = light
    d, e_perp, sh, cube = fold_point_light(positions, q, intensity, visible)
    normals = FEATURE_NORMALS[6:]
    extra = np.stack([directional_irradiance(d[i], e_perp[i], normals) for i in range(len(d))])
    bases = probe_bases(mean, extra)
    bases["sh-l2"] = bases["sh-l2"] + sh
    bases["cube-valve"] = bases["cube-valve"] + cube
    return bases


def evaluate_rows(grid: ProbeGrid, bases: dict[str, np.ndarray], points, normals) -> dict[str, np.ndarray]:
    """Every method's irradiance (N, 3) as float64 arrays of the kernel text run on float32 NumPy arrays (the
    shader's precision; NumPy rather than Dr.Jit here because this run evaluates 6 methods × spacings ×
    quantities on ~10³ points each, where Dr.Jit's per-call kernel builds would dominate: measured 0.15-2 s
    per call on 2 shared cores. The Dr.Jit run of the same text is what `cost_rows` times)."""
    out = {}
    p32, n32 = np.asarray(points, np.float32), np.asarray(normals, np.float32)
    for mid, m in METHODS.items():
        table = probe_table(bases[m.fixed["basis"].id]).astype(np.float32)
        with np.errstate(all="ignore"):  # NumPy evaluates both branches of every select
            values = m(NUMPY_OPS, volume_inputs(m, grid, table, p32, n32))
        out[mid] = np.stack([np.asarray(v, dtype=np.float64) for v in values], axis=-1)
    return out


METRICS = ("rmse", "rel_mse", "mae", "max_abs", "smape")


def popping(x, approx: np.ndarray, ref: np.ndarray, grid: ProbeGrid) -> dict:
    """The error step where the line crosses ``grid``'s x cell boundaries: for each boundary b, the change
    of (approx − reference) between b − ε and b + ε over the mean reference there (grey: RGB mean)."""
    a, r = approx.mean(axis=1), ref.mean(axis=1)
    steps, ref_steps = [], []
    for b in grid.boundaries(0):
        i0 = int(np.argmin(np.abs(x - (b - BOUNDARY_EPS))))
        i1 = int(np.argmin(np.abs(x - (b + BOUNDARY_EPS))))
        scale = max(abs(0.5 * (r[i0] + r[i1])), 1e-12)
        steps.append(abs((a[i1] - r[i1]) - (a[i0] - r[i0])) / scale)
        ref_steps.append(abs(r[i1] - r[i0]) / scale)
    return {
        "max_step": float(max(steps)) if steps else 0.0,
        "mean_step": float(np.mean(steps)) if steps else 0.0,
        "reference_max_step": float(max(ref_steps)) if ref_steps else 0.0,
        "boundaries": len(steps),
    }


def assemble(ctx, cfg, room, grids, probes, furnace_probes, surface, data) -> dict:
    fine = grids[-1][0]
    cut, pts, nrm = data["cut"], data["points"], data["normals"]
    n_surf = cut[len(data["groups"])]
    line = slice(cut[-3], cut[-2])
    chk = slice(cut[-2], cut[-1])
    indirect = surface["indirect"]
    direct = surface["direct"]
    total_mean = indirect["mean"] + direct["mean"]
    total_se = np.sqrt(indirect["stderr"] ** 2 + direct["stderr"] ** 2)
    refs = {
        "indirect": (indirect["mean"], indirect["stderr"]),
        "folded": (total_mean, total_se),
    }
    bases = {
        "indirect": probe_bases(probes["mean"]),
        "folded": folded_bases(probes["mean"], fine.positions(), data["light"], probes["visible"]),
    }
    eval_p = np.concatenate([pts[:n_surf], pts[line]])
    eval_n = np.concatenate([nrm[:n_surf], nrm[line]])
    case_docs, curves, pops, finite, indirect_values = [], {}, {}, True, {}
    for q in QUANTITIES:
        mean, se = refs[q]
        for level, (grid, index) in enumerate(grids):
            sub = {b: c[index] for b, c in bases[q].items()}
            values = evaluate_rows(grid, sub, eval_p, eval_n)
            docs = []
            for mid, v in values.items():
                finite &= bool(np.all(np.isfinite(v)))
                surf = v[:n_surf]
                metrics = compute_metrics(surf, mean[:n_surf], se[:n_surf], names=METRICS)
                per_group = group_smape(surf, mean[:n_surf], se[:n_surf], cut, data["groups"])
                pop = popping(data["line_x"], v[n_surf:], mean[line], grid)
                pops[(q, level, mid)] = pop
                curves[(q, level, mid)] = v[n_surf:]
                docs.append(
                    {
                        "method": mid,
                        "label": METHODS[mid].label,
                        "parameters": {
                            "spacing_m": grid.spacing,
                            "popping_max_step": pop["max_step"],
                            "popping_mean_step": pop["mean_step"],
                            **per_group,
                        },
                        "metrics": metrics.to_dict(),
                    }
                )
            if q == "indirect":
                indirect_values[level] = values
            else:
                docs += direct_plus_rows(indirect_values[level], direct["mean"][:n_surf], n_surf, mean, se)
            case_docs.append(
                {
                    "id": f"{q}-h{grid.spacing:g}",
                    "label": f"{QUANTITY_LABELS[q]}, grid spacing {grid.spacing:g} m ({grid.count} probes)",
                    "parameters": {
                        "quantity": q,
                        "spacing_m": grid.spacing,
                        "probes": grid.count,
                        "dims": list(grid.dims),
                        "surface_points": int(n_surf),
                        "probe_directions": int(probes["reference"]["spp"]),
                        "floats_cube": 18 * grid.count,
                        "floats_sh_l2": 27 * grid.count,
                    },
                    "scene": {"name": room.name, "hash": scene_hash(room)},
                    "reference": {
                        **indirect["reference"],
                        "quantity": "indirect irradiance"
                        if q == "indirect"
                        else "direct + indirect irradiance",
                    },
                    "approximations": docs,
                }
            )
    checks = self_checks(cfg, fine, grids, probes, furnace_probes, surface, data, bases, chk, finite)
    costs = cost_rows(ctx, cfg, fine)
    attach_costs(case_docs, costs, key=lambda ap: ap["method"].removeprefix("direct+"))
    table = error_table(case_docs)
    figs = make_figures(ctx.out_dir, data, grids, refs, curves, table, costs, line)
    return {
        "summary": summary(table, pops, checks, grids),
        "config": cfg,
        "sections": sections(cfg, grids, probes),
        "cases": case_docs,
        "figures": figs,
        "costs": costs,
        "checks": checks,
        "error_vs_spacing": table,
        "popping": [
            {"quantity": q, "spacing_m": grids[lv][0].spacing, "method": mid, **pop}
            for (q, lv, mid), pop in pops.items()
        ],
        "notes": NOTES,
    }


def group_slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name).strip("_").replace("__", "_")


def group_smape(
    values: np.ndarray, ref: np.ndarray, se: np.ndarray, cut, groups: list[str]
) -> dict[str, float]:
    """`rtfit.fitting.smape` (|a − r|/(|a| + |r|), mean over points and channels) per surface group, keyed
    ``smape_<group>``: where the volume's error sits (e.g. light leaking through the occluder)."""
    out = {}
    for k, name in enumerate(groups):
        mask = np.zeros(len(values), dtype=bool)
        mask[cut[k] : cut[k + 1]] = True
        out[f"smape_{group_slug(name)}"] = float(smape(values, ref, se, mask).value)
    return out


def direct_plus_rows(indirect_values: dict, direct_mean, n_surf: int, mean, se) -> list[dict]:
    """Rows ``direct+<method>``: the exact shadowed direct light plus the volume's indirect irradiance
    (``indirect_values``: each method's lookup of the unfolded probes; the engine's usual split), against the
    total irradiance."""
    return [
        {
            "method": f"direct+{mid}",
            "label": f"exact direct + {METHODS[mid].label}",
            "metrics": compute_metrics(
                direct_mean + v[:n_surf], mean[:n_surf], se[:n_surf], names=METRICS
            ).to_dict(),
        }
        for mid, v in indirect_values.items()
    ]


def error_table(case_docs: list[dict]) -> list[dict]:
    """Rows (quantity, spacing, method, relative RMSE = RMSE / mean |reference|, sMAPE, noise floors)."""
    rows = []
    for doc in case_docs:
        for ap in doc["approximations"]:
            m = ap["metrics"]
            rel = math.sqrt(m["rel_mse"]["value"]) if m["rel_mse"]["value"] is not None else None
            floor = m["rel_mse"].get("noise_floor")
            rows.append(
                {
                    "quantity": doc["parameters"]["quantity"],
                    "spacing_m": doc["parameters"]["spacing_m"],
                    "method": ap["method"],
                    "rel_rmse": rel,
                    "rel_rmse_floor": math.sqrt(floor) if floor is not None else None,
                    "smape": m["smape"]["value"] if "smape" in m else None,
                    "smape_floor": m["smape"].get("noise_floor") if "smape" in m else None,
                }
            )
    return rows


# =========================================================================================== checks
def _check(name: str, value, expected: str, passed: bool) -> Check:
    return Check(name=name, value=value, expected=expected, passed=bool(passed))


def segment_blocked(points: np.ndarray, light: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Whether the open segment from each point to the light crosses the box [lo, hi] (slab test, float64)."""
    d = light[None, :] - points
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo[None, :] - points) / d
        t1 = (hi[None, :] - points) / d
    tmin = np.nanmax(np.where(d != 0, np.minimum(t0, t1), -np.inf), axis=1)
    tmax = np.nanmin(np.where(d != 0, np.maximum(t0, t1), np.inf), axis=1)
    inside_slabs = np.all((d != 0) | ((points >= lo) & (points <= hi)), axis=1)
    return inside_slabs & (tmax >= np.maximum(tmin, 1e-6)) & (tmin <= 1.0 - 1e-6)


def self_checks(cfg, fine, grids, probes, furnace_probes, surface, data, bases, chk, finite) -> list[dict]:
    checks = []
    # 1. White furnace: the probes' projections against their closed forms (SH: √(4π) δ_k0; irradiance: π).
    fm, fs = furnace_probes["mean"], furnace_probes["stderr"]
    exact = np.zeros(fm.shape[1])
    exact[0] = math.sqrt(4.0 * math.pi)
    exact[9:] = math.pi
    diff = fm - exact[None, :, None]
    noisy = fs > 0
    z = np.abs(diff[noisy] / fs[noisy])
    zmax = sidak_threshold(int(noisy.sum()))
    checks.append(
        _check(
            "white furnace: probe projections (SH, irradiance at 70 normals) = closed forms within noise",
            float(z.max()),
            f"max |z| ≤ {zmax:.2f} (Šidák, α = 0.01, n = {int(noisy.sum())})",
            z.max() <= zmax,
        )
    )
    exact_dc = float(np.max(np.abs(diff[~noisy]) / math.sqrt(4 * math.pi))) if (~noisy).any() else 0.0
    checks.append(
        _check(
            "white furnace: the noiseless SH DC projection is exact",
            exact_dc,
            "≤ 1e-6 relative",
            exact_dc <= 1e-6,
        )
    )
    # 2. A volume of identical exact constant probes is π everywhere (inside, on boundaries, outside).
    rng = np.random.default_rng(5)
    p = rng.uniform(-3.0, 3.0, (4096, 3))
    p[:64] = fine.positions()[:64] + 0.5 * fine.spacing
    n = rng.normal(size=(4096, 3))
    const = {
        "sh-l2": np.repeat(sh9_from_constant(1.0)[None], fine.count, 0),
        "cube-valve": np.full((fine.count, 6, 3), math.pi),
        "cube-nnls": np.full((fine.count, 6, 3), math.pi),
    }
    worst = max(float(np.max(np.abs(v / math.pi - 1.0))) for v in evaluate_rows(fine, const, p, n).values())
    checks.append(
        _check(
            "constant environment: every lookup × basis of identical exact probes returns π (float32)",
            worst,
            "≤ 2e-6 relative (measured 4.8e-7)",
            worst <= 2e-6,
        )
    )
    # 3. The direct reference is I·max(n·d, 0)/r² with an analytic shadow test of the occluder.
    q, intensity = data["light"]
    lo, hi = data["occluder"]
    n_surf = data["cut"][len(data["groups"])]
    pts, nrm = data["points"][:n_surf], data["normals"][:n_surf]
    dvec = q[None] - pts
    r2 = np.einsum("ij,ij->i", dvec, dvec)
    cos = np.maximum(np.einsum("ij,ij->i", nrm, dvec) / np.sqrt(r2), 0.0)
    closed = (cos / r2 * (~segment_blocked(pts, q, lo, hi)))[:, None] * intensity[None]
    got = surface["direct"]["mean"][:n_surf]
    scale = np.maximum(np.abs(closed), 1e-3 * float(np.max(closed)))
    rel = np.abs(got - closed) / scale
    agree = float(np.mean(np.all(rel <= 1e-4, axis=1)))
    checks.append(
        _check(
            "direct reference = I·max(n·d, 0)/r² × analytic occluder shadow (points off shadow edges)",
            agree,
            "≥ 0.99 of the points within 1e-4 relative",
            agree >= 0.99,
        )
    )
    # 4. Two independent estimators of the indirect irradiance at the coarsest grid's nodes: the probes'
    #    uniform-sphere projection onto the six axes, and the surface estimator's cosine-sampled paths.
    coarse, cidx = grids[0]
    pm, ps = probes["mean"][cidx, 9:15], probes["stderr"][cidx, 9:15]
    sm = surface["indirect"]["mean"][chk].reshape(coarse.count, 6, 3)
    ss = surface["indirect"]["stderr"][chk].reshape(coarse.count, 6, 3)
    zz = ((pm - sm) / np.sqrt(ps**2 + ss**2 + 1e-30)).ravel()
    zlim = sidak_threshold(zz.size)
    spread = robust_spread(zz)
    checks.append(
        _check(
            "probe projection (uniform sphere) = surface estimator (cosine paths), coarse nodes × 6 axes",
            float(np.abs(zz).max()),
            f"max |z| ≤ {zlim:.2f} (Šidák, α = 0.01, n = {zz.size})",
            np.abs(zz).max() <= zlim,
        )
    )
    checks.append(
        _check(
            "  … and the z-scores have unit spread",
            spread,
            "robust spread in [0.6, 1.5]",
            0.6 <= spread <= 1.5,
        )
    )
    # 5. The lookups reproduce each probe at its node (finest grid, indirect bases, float32).
    nodes = fine.positions()
    normals = rng.normal(size=(fine.count, 3))
    worst = 0.0
    for mid, v in evaluate_rows(fine, bases["indirect"], nodes, normals).items():
        basis = METHODS[mid].fixed["basis"]
        stored = probe_table(bases["indirect"][basis.id]).reshape(-1, fine.count)  # (floats, probes)
        own = np.stack(
            basis(
                NUMPY_OPS,
                {"nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2], "coeffs": list(stored)},
            ),
            axis=-1,
        )  # each node's own probe, the basis's NumPy text in float64
        worst = max(worst, float(np.max(np.abs(v - own) / (np.abs(own) + 1e-3 * np.abs(own).max()))))
    checks.append(
        _check(
            "nearest and trilinear lookups at the nodes return the node's own probe",
            worst,
            "≤ 1e-5 relative (float32 weights; measured ≤ 1e-6)",
            worst <= 1e-5,
        )
    )
    checks.append(_check("every lookup is finite", str(finite), "True", finite))
    rel_se = float(np.mean(surface["indirect"]["stderr"] / np.maximum(surface["indirect"]["mean"], 1e-12)))
    checks.append(
        _check("indirect reference resolved (mean relative standard error)", rel_se, "≤ 0.1", rel_se <= 0.1)
    )
    return checks


# ========================================================================================== figures
def make_figures(out, data, grids, refs, curves, table, costs, line) -> list[dict]:
    figs = []
    series = []
    for q in QUANTITIES:
        for mid in METHODS:
            rows = [r for r in table if r["quantity"] == q and r["method"] == mid]
            series.append(
                {
                    "x": [r["spacing_m"] for r in rows],
                    "y": [r["smape"] for r in rows],
                    "label": mid,
                    "panel": q,
                    "ls": "-" if mid.startswith("trilinear") else "--",
                }
            )
    path = F.line_plot(
        out / "error_vs_spacing.png",
        "grid spacing h (m)",
        "sMAPE (surface points)",
        series,
        x_log=True,
        y_log=True,
        panels=list(QUANTITIES),
    )
    figs.append(
        {
            "file": path.name,
            "caption": "sMAPE over the surface points against grid spacing, "
            "per lookup × basis; left: indirect irradiance, right: total with the light folded.",
        }
    )
    x = data["line_x"]
    mean, se = refs["indirect"]
    pop_series = [
        {
            "x": x,
            "y": mean[line].mean(axis=1),
            "yerr": se[line].mean(axis=1),
            "label": "reference",
            "style": "points",
            "panel": f"h = {g.spacing:g} m",
        }
        for g, _ in grids
    ]
    for level, (g, _) in enumerate(grids):
        for mid in ("nearest-sh-l2", "trilinear-sh-l2", "nearest-cube-valve"):
            pop_series.append(
                {
                    "x": x,
                    "y": curves[("indirect", level, mid)].mean(axis=1),
                    "label": mid,
                    "panel": f"h = {g.spacing:g} m",
                }
            )
    path = F.line_plot(
        out / "popping_line.png",
        f"x (m) along the line y = {LINE_Y:g}, z = {LINE_Z:g}",
        "indirect irradiance (W/m², RGB mean)",
        pop_series,
        panels=[f"h = {g.spacing:g} m" for g, _ in grids],
    )
    figs.append(
        {
            "file": path.name,
            "caption": "Popping: indirect irradiance along a line crossing the cells "
            "(normal (−0.6, 0, 0.8)); the nearest lookup steps at every cell boundary, trilinear is "
            "continuous.",
        }
    )
    finest = grids[-1][0].spacing
    pts = [
        {"x": c["ns_per_pixel"], "y": r["rel_rmse"], "label": c["method"]}
        for c in costs
        if c["method"] in METHODS
        for r in table
        if r["method"] == c["method"] and r["quantity"] == "indirect" and r["spacing_m"] == finest
    ]
    floor = next((r["rel_rmse_floor"] for r in table if r["quantity"] == "indirect"), None)
    path = F.pareto_plot(
        out / "error_vs_cost.png",
        pts,
        "ns per lookup (Dr.Jit, float32)",
        f"relative RMSE, indirect, h = {finest:g} m",
        floor=floor,
    )
    figs.append({"file": path.name, "caption": "Error against cost per lookup at the finest spacing."})
    return figs


# ========================================================================================== summary
NOTES = [
    "Probes hold bounced light only (a point light is never hit by a sampled ray); the `folded` quantity "
    "adds "
    "the point light to each probe as a distant light from its direction at the probe, with the probe's own "
    "shadow ray, and is compared with the total irradiance.",
    "Floor, wall and ceiling points lie outside the grid (x, y ∈ [−1.5, 1.5], z ∈ [0.25, 1.75]) and are "
    "clamped to it, as an engine's volume lookup would.",
    "Each probe's coefficients carry Monte Carlo noise of its own (probe_directions per probe): the finest "
    "spacing's error includes it.",
]


METHOD_TEXT = (
    "Valve's irradiance volume (seed 000:2502-2515) stores ambient cubes of *bounced* light on a coarse "
    "grid and looks up the nearest one per model, without filtering; local lights beyond the two most "
    "important are folded into the cube on the fly. Here the probes are path-traced in a room with a bright "
    "point light and an occluder, stored as Valve's cube, the NNLS cube and SH L2, and looked up nearest or "
    "trilinear at surface points. Where the error sits: `smape_<group>` per surface group (the occluder's "
    "shadow side gets light leaking through the thin wall once a probe on the lit side is the nearest)."
)


def sections(cfg, grids, probes) -> list[dict]:
    grid_rows = "\n".join(
        f"| {g.spacing:g} | {' × '.join(map(str, g.dims))} | {g.count} | {18 * g.count} | {27 * g.count} |"
        for g, _ in grids
    )
    return [
        {
            "id": "method",
            "title": "Irradiance volumes: what is measured",
            "text": METHOD_TEXT
            + "\n\n| spacing (m) | nodes | probes | floats (cube) | floats (SH L2) |\n|---|---|---|---|---|\n"
            + grid_rows
            + f"\n\nProbe directions per probe: {probes['reference']['spp']}.",
        }
    ]


def summary(table, pops, checks, grids) -> str:
    finest, coarsest = grids[-1][0].spacing, grids[0][0].spacing

    def rel(q, h, mid):
        r = next(r for r in table if r["quantity"] == q and r["spacing_m"] == h and r["method"] == mid)
        return r["smape"]

    floor = next(r["smape_floor"] for r in table if r["quantity"] == "indirect")
    lv = len(grids) - 1
    passed = sum(c["passed"] for c in checks)
    return (
        f"Indirect irradiance, sMAPE over the surface points (noise floor {floor:.3f}) at h = {coarsest:g} → "
        f"{finest:g} m: nearest SH L2 "
        f"{rel('indirect', coarsest, 'nearest-sh-l2'):.3f} → {rel('indirect', finest, 'nearest-sh-l2'):.3f}, "
        f"trilinear SH L2 {rel('indirect', coarsest, 'trilinear-sh-l2'):.3f} → "
        f"{rel('indirect', finest, 'trilinear-sh-l2'):.3f}, trilinear Valve cube "
        f"{rel('indirect', finest, 'trilinear-cube-valve'):.3f} at {finest:g} m. Popping at h = {finest:g} "
        f"m: nearest SH L2 steps by up to {100 * pops[('indirect', lv, 'nearest-sh-l2')]['max_step']:.1f} "
        "% of the "
        f"irradiance at a cell boundary, trilinear by "
        f"{100 * pops[('indirect', lv, 'trilinear-sh-l2')]['max_step']:.2f} % (the reference's own step: "
        f"{100 * pops[('indirect', lv, 'nearest-sh-l2')]['reference_max_step']:.2f} %). With the light "
        "folded "
        f"(total irradiance): trilinear SH L2 {rel('folded', finest, 'trilinear-sh-l2'):.3f} against "
        f"{rel('folded', finest, 'direct+trilinear-sh-l2'):.3f} for exact direct light plus the volume. "
        f"{passed} of {len(checks)} checks passed."
    )


# ============================================================================================ bench
def _cost_inputs(grid: ProbeGrid, n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    lo = np.asarray(grid.origin) - 0.25
    hi = np.asarray(grid.origin) + grid.spacing * (np.asarray(grid.dims) - 1) + 0.25
    p = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    tables = {
        b: rng.uniform(0.0, 1.0, grid.count * (18 if b.startswith("cube") else 27)).astype(np.float32)
        for b in VOLUME_BASES
    }
    return p, nrm, tables


def _time(mid: str, grid: ProbeGrid, table, p, nrm, n: int):
    Array3f = backend_type("Array3f", "cuda" if dr.backend_v(p[0]) == dr.JitBackend.CUDA else "llvm")

    def call(px, py, pz, nx, ny, nz):
        return volume_irradiance(mid, grid, table, Array3f(px, py, pz), Array3f(nx, ny, nz))

    return time_drjit(lambda *a: call(*a), tuple(p) + tuple(nrm), n)


def cost_rows(ctx, cfg, grid: ProbeGrid) -> list[dict]:
    """ns per lookup of each method (Dr.Jit, float32, random points in and around ``grid``) beside the
    memory-traffic floor."""
    backend, Float = cost_backend(ctx.variant)
    n = cfg["cost_elements"]
    p, nrm, tables = _cost_inputs(grid, n)
    P = [Float(p[:, k]) for k in range(3)]
    N = [Float(nrm[:, k]) for k in range(3)]
    note = f"per lookup: position and normal in, RGB out; {grid.count} probes, h = {grid.spacing:g} m"
    rows = [
        cost_row(
            mid,
            m.label,
            backend,
            _time(mid, grid, tables[m.fixed["basis"].id], P, N, n),
            note,
            floats_per_probe=m.storage,
        )
        for mid, m in METHODS.items()
    ]
    return [*rows, memory_floor_row(tuple(P + N), n, backend, "the memory-bound floor")]


def bench(ctx) -> list[dict]:
    """Lookups/s of each method on Dr.Jit vs the same kernel text on NumPy, on the finest quick grid."""
    backend, n = bench_backend(ctx)
    Float = backend_float(backend)
    grid = finest_grid(3 if ctx.quick else 4)
    p, nrm, tables = _cost_inputs(grid, n)
    P = [Float(p[:, k]) for k in range(3)]
    N = [Float(nrm[:, k]) for k in range(3)]

    def timed():
        for mid, m in METHODS.items():
            table = tables[m.fixed["basis"].id]
            t_dr = _time(mid, grid, table, P, N, n)
            inputs = volume_inputs(m, grid, table, p, nrm)
            yield m.label, t_dr, time_numpy(lambda inputs=inputs, m=m: m(NUMPY_OPS, inputs), (), n)

    baseline = "memory baseline (fma of the 6 inputs)"
    return comparison_rows(backend, tuple(P + N), n, timed(), unit="lookup", baseline=baseline)
