"""The ``ibl-samples`` family on a scene's environment (`rtfit audit`, and ``rtfit run ibl-samples`` on its
shipped scene): the environment map split into N directional lights, each with its own shadow test, as the
GameTools image-based lighting module renders it (seed 001:2738-3070), against the environment's irradiance
with the scene's occlusion.

Role (its ``rules``): ``image-based lighting (N directional samples)`` — every environment of the scene (a
Mitsuba XML ``envmap``, ``constant`` or ``sunsky`` emitter, or an rtfit TOML ``constant_env``, ``envmap``
or ``sunsky`` light) together with geometry that can occlude it: the parts the sky-occlusion role needs.

One case ``ibl<i>`` per environment, on the visible surface pixels:

* **reference** (the sky families' passes, `rtfit.experiments.audit_sky.sky_reference`: one set of
  passes per environment, without their visibility bake and SH): E = ∫ V(ω) L_env(ω) max(n·ω, 0) dω
  (W/m², RGB) with the scene's shapes as occluders, by Mitsuba's emitter sampling and the cosine hemisphere
  (balance heuristic) with shadow rays, in independent passes with per-pixel standard errors (a sunsky's
  sky without its sun: the sun is the sphere-light roles');
* **the bakes** (`rtfit.realtime.ibl_samples`, NumPy, once per environment): the environment emitter baked
  to a lat-long map of `BAKE_ROWS` × 2·`BAKE_ROWS` nodes (`audit_environment.environment_of`; a constant
  as its radiance), its texels (`quadrature_samples`: midpoints, solid angles) split into N lights by each
  bake — the seed's energy samples with Lloyd's relaxation, the same without it, Debevec's median cut — for
  N in `COUNTS`;
* **the depth maps** (``seed-depthmap`` rows: the seed's lights with the seed's shadow test,
  `depth_map_visibility_rows`): per light an orthographic depth-and-normal map of `SHADOW_RESOLUTION`²
  texels over the scene's bounding sphere, by Mitsuba rays from its texel centres, then the seed's linearly
  filtered comparison with its normal-weighted bias 0.01;
* **inputs** per row (``row_inputs``: each bake and N has its own lights): n (the G-buffer's unit normal)
  and v1..vN, each light's visibility at the point by one Mitsuba shadow ray towards it (`light_visibility`:
  exact, spawned as the reference spawns its rays; 0 where the light is below the surface's plane), or by
  its depth map (``seed-depthmap``). The
  light table (6·N floats) is a constant of the row (``Method.fixed``: literals of the compiled kernel). So
  a row's error is the sampling of the map alone; its cost is the N multiply-adds of the blend, without
  the shadow test (a depth-map lookup per light in an engine, here a ray cast). The three bakes run the same
  kernel on tables of the same size: the cost is measured once per N, on the seed's row (``uncosted``
  names the others').

A user approximation of ``sky_irradiance_lights`` reads the seed bake at N = `USER_COUNT`: ``g.normal``,
``g.visibility`` (N per-pixel arrays), ``g.lights`` (its 6·N floats) and the point ``g.point``.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import drjit as dr
import numpy as np

from rtfit.realtime.arrays import to_drjit, xyz_columns
from rtfit.realtime.ibl_bakes import bake_lights
from rtfit.realtime.ibl_samples import (
    BAKES,
    COUNTS,
    DEPTH_ROWS,
    METHODS,
    SHADOW_BIAS,
    DepthMaps,
    maps_input,
    on_lights,
    visibility_names,
)
from rtfit.realtime.methods import Input, Method
from rtfit.reference.environments import quadrature_samples
from rtfit.reference.estimators import device_vectors

from .audit import Applicability, Rule
from .audit_environment import environment_of
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditSetup
from .audit_sky import sky_reference
from .shipped import Sizes

__all__ = [
    "BAKE_ROWS",
    "FAMILY",
    "SCENES",
    "USER_COUNT",
    "depth_map_visibility",
    "depth_map_visibility_rows",
    "depth_maps",
    "ibl_cases",
    "light_visibility",
    "scene_texels",
]

BAKE_ROWS = 64
"""Rows of the lat-long bake the lights are made from (× 2 columns: 8192 texels)."""
USER_COUNT = 64
"""N of the seed bake a user's approximation reads."""
_MAX_LANES = 1 << 22  # shadow rays per launch
_MAP_LANES = 1 << 20  # depth-map rays per launch (a surface interaction per lane: ~0.1 GB a launch)

SCENES = (
    Sizes(full=(64, 64, 256), quick=(24, 24, 32)).scene(
        "ibl_samples_museum.xml",
        "a sphere and two boxes on a grey ground plane under a museum light probe (32 × 64 lat-long, "
        "Mitsuba's test data): bright windows, soft indoor light, contact shadows",
    ),
)
"""The scene ``rtfit run ibl-samples`` audits (scenes/library/)."""


def scene_texels(env, rows: int = BAKE_ROWS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texels of the environment ``env`` (`Environment`, its sun left out) on their (rows, 2·rows)
    grid: directions (H, W, 3), solid angles (H, W) sr, radiance (H, W, 3): the bilinear map's midpoints
    (`quadrature_samples`), a constant as that radiance everywhere."""
    if env.radiance_map is not None:
        img = np.asarray(env.radiance_map, np.float64)
    else:
        value = np.asarray(env.constant if env.constant is not None else (0.0, 0.0, 0.0), np.float64)
        img = np.broadcast_to(value, (rows, 2 * rows, 3))
    h, w = img.shape[:2]
    d, wt, radiance = quadrature_samples(img, 1)
    return d.reshape(h, w, 3), wt.reshape(h, w), radiance.reshape(h, w, 3)


def light_visibility(setup: AuditSetup, points, normals, directions) -> np.ndarray:
    """(K, N) visibility in {0, 1} of the K unit world ``directions`` (towards each light) at the N visible
    ``points`` with unit ``normals``: one Mitsuba shadow ray each (``Interaction3f.spawn_ray``, as the
    reference spawns its own), 0 where the light is at or below the surface's plane."""
    import drjit as dr

    mi = setup.mi
    dirs = np.asarray(directions, np.float64).reshape(-1, 3)
    pts = np.ascontiguousarray(points, np.float32)
    nrm = np.ascontiguousarray(normals, np.float32)
    k, n = len(dirs), len(pts)
    out = np.zeros((k, n))
    if not k or not n:
        return out
    per = max(1, _MAX_LANES // k)
    d_dev = [to_drjit(mi.Float, dirs[:, c]) for c in range(3)]  # aligned: one kernel (`to_drjit`)
    for a in range(0, n, per):
        b = min(n, a + per)
        lanes = (b - a) * k
        idx = dr.arange(mi.UInt32, lanes) // k
        kk = dr.arange(mi.UInt32, lanes) % k
        it = dr.zeros(mi.Interaction3f, lanes)
        it.p = dr.gather(mi.Point3f, device_vectors(mi, mi.Point3f, pts[a:b]), idx)
        it.n = dr.gather(mi.Vector3f, device_vectors(mi, mi.Vector3f, nrm[a:b]), idx)
        d = mi.Vector3f(*(dr.gather(mi.Float, c, kk) for c in d_dev))
        up = dr.dot(it.n, d) > 0.0
        lit = up & ~setup.scene.ray_test(it.spawn_ray(d), up)
        out[:, a:b] = np.asarray(lit, dtype=bool).reshape(b - a, k).T
    return out


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Linear filtering of an (R, R, C) texture at (u, v) ∈ [0, 1]² with clamped addressing (the seed's
    ``MinFilter = LINEAR``, ``AddressU = Clamp``): texel centres at (i + ½)/R."""
    res = img.shape[0]
    x = np.clip(np.asarray(u) * res - 0.5, 0.0, res - 1.0)
    y = np.clip(np.asarray(v) * res - 0.5, 0.0, res - 1.0)
    i0 = np.minimum(np.floor(x).astype(np.int64), res - 2) if res > 1 else np.zeros_like(x, np.int64)
    j0 = np.minimum(np.floor(y).astype(np.int64), res - 2) if res > 1 else np.zeros_like(y, np.int64)
    i1, j1 = np.minimum(i0 + 1, res - 1), np.minimum(j0 + 1, res - 1)
    fx, fy = (x - i0)[:, None], (y - j0)[:, None]
    top = img[j0, i0] * (1 - fx) + img[j0, i1] * fx
    bottom = img[j1, i0] * (1 - fx) + img[j1, i1] * fx
    return top * (1 - fy) + bottom * fy


def depth_map_visibility(depth, map_normals, coords, normals, bias: float = SHADOW_BIAS) -> np.ndarray:
    """The seed's shadow test of one light (001:3026-3028), NumPy, per point: 1 where lit, else 0.

    ``depth`` (R, R): the map's normalised depth (0 at the light's end of the bounding sphere, 1 at the far
    end; 1 where no surface); ``map_normals`` (R, R, 3): the surface normal stored beside it (0 where none);
    ``coords`` (P, 3): each point's (u, v, z) in the map's texture space; ``normals`` (P, 3): the points' unit
    normals. Depth and normal are filtered linearly (the seed's float render target), the normal normalised
    (a filtered normal of length < 1e-6, between opposite faces or at the map's empty background, reads a
    bias of 0: HLSL's normalize(0) is NaN), and the point is lit where z − bias·dot(n̂_map, n) < depth."""
    c = np.asarray(coords, np.float64)
    d = _bilinear(np.asarray(depth, np.float64)[..., None], c[:, 0], c[:, 1])[:, 0]
    nm = _bilinear(np.asarray(map_normals, np.float64), c[:, 0], c[:, 1])
    length = np.linalg.norm(nm, axis=1)
    cos = np.where(length > 1e-6, np.sum(nm * normals, axis=1) / np.maximum(length, 1e-30), 0.0)
    return (c[:, 2] - bias * cos < d).astype(np.float64)


def _frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit ``d`` to an orthonormal frame (the depth map's u and v axes)."""
    t = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    t /= np.linalg.norm(t)
    return t, np.cross(d, t)


def depth_maps(setup: AuditSetup, directions, resolution: int) -> DepthMaps:
    """The K lights' seed depth maps (001:2814-2871) as the kernel's sampler (`DepthMaps`).

    Per light, an orthographic map of ``resolution``² texels over the scene's bounding sphere (centre c,
    radius r: Mitsuba's scene box), its camera on the sphere at c + r·d looking at c. Each texel's depth (the
    first hit's distance along −d over 2r, 1 for a miss) and shading normal (0 for a miss) come from one
    Mitsuba ray from its centre (every light's rays in launches of at most `_MAP_LANES`, directions as
    per-lane arrays: one compiled kernel)."""
    mi = setup.mi
    box = setup.scene.bbox()
    lo, hi = np.array(box.min, np.float64), np.array(box.max, np.float64)
    centre, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    grid = (np.arange(resolution) + 0.5) / resolution * 2.0 - 1.0
    gu, gv = (g.reshape(-1) for g in np.meshgrid(grid, grid))  # row j: v, column i: u
    dirs = np.asarray(directions, np.float64).reshape(-1, 3)
    frames = np.array([_frame(d) for d in dirs]).reshape(-1, 2, 3)  # (K, 2, 3): u and v axes
    eyes = centre + radius * dirs
    texels = resolution * resolution
    depth = np.ones((len(dirs), texels), np.float32)
    map_n = np.zeros((len(dirs), texels, 3), np.float32)
    offsets = radius * np.stack([gu, gv], axis=-1).astype(np.float32)  # (T, 2)
    per = max(1, _MAP_LANES // texels)
    for a in range(0, len(dirs), per):
        b = min(len(dirs), a + per)
        o = (eyes[a:b, None, :] + offsets[None] @ frames[a:b]).reshape(-1, 3)  # (K·T, 3)
        w = np.repeat(-dirs[a:b], texels, axis=0)
        ray = mi.Ray3f(
            device_vectors(mi, mi.Point3f, o),  # (aligned on the device: one kernel, `device_vectors`)
            device_vectors(mi, mi.Vector3f, w),
        )
        si = setup.scene.ray_intersect(ray)
        valid, n = si.is_valid(), si.sh_frame.n
        dr.eval(valid, si.t, n)  # one launch: each conversion below traced the rays again
        hit = np.asarray(valid, dtype=bool).reshape(b - a, texels)
        t = np.asarray(si.t, np.float64).reshape(b - a, texels)
        depth[a:b] = np.where(hit, t / (2.0 * radius), 1.0)
        sn = np.stack([np.asarray(getattr(n, c), np.float32) for c in "xyz"], axis=-1)
        map_n[a:b] = np.where(hit[..., None], sn.reshape(b - a, texels, 3), 0.0)
    res = (len(dirs), resolution, resolution)
    return DepthMaps(depth.reshape(res), map_n.reshape(*res, 3), np.concatenate([frames, dirs[:, None]], 1),
                     tuple(float(c) for c in centre), radius)  # fmt: skip


def depth_map_visibility_rows(setup: AuditSetup, points, normals, directions, resolution: int,
                              maps: DepthMaps | None = None) -> np.ndarray:  # fmt: skip
    """(K, N) visibility of the K lights at the N points by the seed's depth maps (`depth_maps`, or
    ``maps``), made offline: each point's (u, v, z) in each map (`DepthMaps.coords`) through
    `depth_map_visibility` (the seed's filtered test and bias 0.01). 0 where the light is at or below the
    surface's plane."""
    maps = depth_maps(setup, directions, resolution) if maps is None else maps
    nrm = np.asarray(normals, np.float64)
    coords = maps.coords(points)
    out = np.zeros((len(maps.frames), len(nrm)))
    for k, d in enumerate(maps.frames[:, 2]):
        lit = depth_map_visibility(maps.depth[k], maps.normals[k], coords[k], nrm)
        out[k] = np.where(nrm @ d > 0.0, lit, 0.0)
    return out


def _row(method: Method, lights: np.ndarray) -> Method:
    """A row with its light table as a constant (``fixed``): the kernel's literals."""
    inputs = tuple(i for i in method.inputs if i.name != "lights")
    return replace(method, inputs=inputs, fixed={**method.fixed, "lights": tuple(float(v) for v in lights)})


def _user_row(method: Method, n: int, lights: tuple[float, ...]) -> Method:
    """A user approximation of ``sky_irradiance_lights`` reading the visibilities v1..vN as ``g.visibility``
    and the seed bake's table as ``g.lights``."""
    vis = tuple(Input(v, "1", f"visibility of light {k + 1}", (0.0, 1.0)) for k, v in
                enumerate(visibility_names(n)))  # fmt: skip
    inputs = tuple(i for i in method.inputs if i.name not in ("visibility", "lights")) + vis
    return replace(
        method,
        kernel=on_lights(method.kernel, n),
        inputs=inputs,
        fixed={**method.fixed, "lights": lights},
    )


def ibl_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per environment: each bake × N against the occluded environment irradiance (module
    docstring)."""
    sky = sky_reference(setup, app, "ibl-samples")  # an AuditError where app.source is None
    assert app.source is not None
    env = replace(environment_of(setup, app.source, rows=BAKE_ROWS, family="ibl-samples"), sun=None)
    grid = scene_texels(env)
    base = {**xyz_columns("n", sky.normals), **xyz_columns("p", sky.points)}
    methods: dict[str, Method] = {}
    row_inputs: dict[str, tuple] = {}
    tables: dict[str, np.ndarray] = {}
    lit: dict[str, float] = {}
    maps: dict[str, DepthMaps] = {}
    for rid in app.methods:
        if rid in DEPTH_ROWS:  # the seed's lights, their depth maps as the kernel's sampler
            count, res, _taps = DEPTH_ROWS[rid]
            same = f"seed-lloyd-{count}"
            table = tables[same] if same in tables else bake_lights("seed-lloyd", *grid, count)
            name = maps_input(rid)
            if name not in maps:
                maps[name] = depth_maps(setup, table.reshape(-1, 6)[:, :3], res)
                vis = depth_map_visibility_rows(setup, sky.points, sky.normals, None, res, maps[name])
                lit[name] = float(vis.mean())
            tables[rid] = table
            methods[rid] = _row(METHODS[rid], table)
            row_inputs[rid] = ({**base, name: maps[name]},)
            continue
        bake, count = rid.rsplit("-", 1)
        table = tables[rid] if rid in tables else bake_lights(bake, *grid, int(count))
        vis = light_visibility(setup, sky.points, sky.normals, table.reshape(-1, 6)[:, :3])
        tables[rid] = table
        lit[rid] = float(vis.mean())
        methods[rid] = _row(METHODS[rid], table)
        row_inputs[rid] = ({**base, **dict(zip(visibility_names(int(count)), vis, strict=True))},)
    rays = [r for r in row_inputs if r not in DEPTH_ROWS]
    user = f"seed-lloyd-{USER_COUNT}" if f"seed-lloyd-{USER_COUNT}" in row_inputs else (rays or [""])[0]
    if not user:  # depth-map rows only: a user's formula reads the seed bake's shadow rays all the same
        user_n = DEPTH_ROWS[next(iter(row_inputs))][0]
        user = f"seed-lloyd-{user_n}"
        tables[user] = tables[next(iter(row_inputs))]
        vis = light_visibility(setup, sky.points, sky.normals, tables[user].reshape(-1, 6)[:, :3])
        row_inputs[user] = ({**base, **dict(zip(visibility_names(user_n), vis, strict=True))},)
    user_n = int(user.rsplit("-", 1)[1])
    user_lights = tuple(float(v) for v in tables[user])
    # the maps ride on the case's own inputs too: its cost runs and shader texts read each row's sampler there
    channel = ({**row_inputs[user][0], **maps},)
    power = np.asarray(grid[1])[..., None] * np.asarray(grid[2])
    return [
        FamilyCase(
            id=f"ibl{app.source}",
            label=f"{app.part}: environment irradiance with visibility, N directional lights with shadows",
            reference=sky.reference(setup.mask),
            channel_inputs=channel,
            parameters={
                "environment": app.part,
                "kind": sky.kind,
                "bake_rows": BAKE_ROWS,
                "counts": list(COUNTS),
                "bakes": list(BAKES),
                "map_power_w_m2": [float(v) for v in power.reshape(-1, 3).sum(axis=0)],
                "lit_fraction": lit,
                "pixels": int(setup.mask.sum()),
            },
            units="W/m²",
            notes=(
                "occluded: the scene's shapes block the environment (one bounce: no interreflection)",
                f"lights: baked from the environment's lat-long bake of {BAKE_ROWS} × {2 * BAKE_ROWS} nodes "
                "(texel midpoints); each light's power is its cell's ∫L dω, so Σ_k P_k = ∫L dω exactly",
                "visibility: one exact Mitsuba shadow ray per light and point (no depth map): the error is "
                "the sampling of the map; the cost is the blend of N lights without their shadow tests",
                "seed-depthmap rows: the seed's depth-and-normal map test in the kernel (maps of R² texels "
                "made by Mitsuba rays; the lookups, filtering and compare are timed), its bias b fitted",
            ),
            methods=methods,
            row_inputs=row_inputs,
            user_rows=partial(_user_row, n=user_n, lights=user_lights),
            uncosted={
                rid: f"the kernel of seed-lloyd-{rid.rsplit('-', 1)[1]} (one text; only the bake differs, "
                "offline): its cost is that row's"
                for rid in methods
                if rid not in DEPTH_ROWS
                and not rid.startswith("seed-lloyd-")
                and f"seed-lloyd-{rid.rsplit('-', 1)[1]}" in methods
            },
        )
    ]


FAMILY = AuditFamily(
    name="ibl-samples",
    quantity="sky_irradiance_lights",
    cases=ibl_cases,
    describe=(
        "Per environment with occluding geometry: the environment's irradiance with visibility "
        "E = ∫ L_env V (n·ω) dω (W/m², RGB; a sunsky's sky without its sun) at each visible point, by "
        "Mitsuba's emitter sampling and the cosine hemisphere (balance heuristic) with shadow rays against "
        "the scene's shapes, in independent passes with per-pixel standard errors — against the map split "
        "into N = 4, 16, 64, 256 directional lights, each with an exact shadow ray: the seed's energy "
        "samples with Lloyd's relaxation on the sphere (GameTools D5.3 §2.8), the same lights shadowed by "
        "the seed's depth maps instead, the samples without relaxation, and Debevec's median cut. Error "
        "and cost per N."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "ibl-samples",
            "image-based lighting (N directional samples)",
            ("environment", "geometry"),
            "{part} lights the scene's surfaces, occluded by {with_}: an engine splits it into N directional "
            "lights, each with its own shadow",
            "environment irradiance with visibility at the visible points (the environment's direct light, "
            "shadowed; a sunsky's sky alone)",
            "the environment alone: emitter + cosine sampling (MIS) with shadow rays against the scene's "
            "shapes; the lights' visibility by one shadow ray each",
            supplies=frozenset({"lights", *visibility_names(max(COUNTS)), *map(maps_input, DEPTH_ROWS)}),
        ),
    ),
)
