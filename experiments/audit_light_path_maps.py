r"""The ``light-path-maps`` family in `rtfit audit` (and ``rtfit run light-path-maps`` on its shipped scene):
the seed's path maps (one diffuse bounce from a moving light as clustered virtual lights) against the
path-traced one-bounce indirect irradiance at the visible points, for several positions of the light.

Role (its ``rules``): ``indirect light from a moving light`` — a scene with geometry and a local light (point,
spot, sphere, disk or rectangle): the light's bounce off every surface lights the others, and changes as the
light moves.

**The bake** (light-independent, once per scene; `rtfit.realtime.light_path_maps`): `ENTRY_POINTS` entry
points sampled uniformly by area on every surface that is not a light (stratified over the shapes by area,
Mitsuba's ``sample_position``), their diffuse albedo (``eval_diffuse_reflectance`` at a ray hit) and normal;
their clusters for each K (`cluster_entry_points`); the visibility of every (visible point, entry point) pair
by a Mitsuba shadow ray; and the transfer τ with the seed's cut (`vpl_transfer`), summed per cluster into
T_k,c at each visible point. The cut d_c: the default √(A_S/(π N)) for the rows, and fitted over `CUT_GRID`
(× that radius) across the light positions for the ``seed-path-map-cut-fit`` row (one bake serves every
position: the fit is one number for the scene; it is fitted on the same pixels it is compared on, said in
the notes).

**One case per light position** ``light<i>-at<p>``: the light where the scene puts it (p = 0) and moved by
± `MOVE` × the scene's widest bounding-box extent along that axis (p = 1, 2; kept `MARGIN` of the extent
inside the box). A point light moves by its ``position``, a spot by its ``to_world``; an area light (its shape
is scene geometry, moving it rebuilds the scene) is audited where it is, one case, said in its notes.

* **reference**: E₁,c(x) (W/m², RGB) with the light at that position: `irradiance_pass` with ``bounce``
  transport — a cosine ray from x, then π × (Mitsuba ``path`` max_depth 2 − max_depth 1): exactly one
  reflection of every light's direct light (the colour-bleeding family's transport, reused). Independent
  passes through the pass cache (the light's position is part of the key), per-pixel standard errors.
* **inputs** (per channel; each row its own, ``row_inputs``): pane_k = T_k,c at the point and
  w_k = mean over the cluster's entry points of the light's direct irradiance E_dir,c (`irradiance_pass`,
  ``direct`` transport, at the entry point with its normal: the seed's ``ComputeWeights``).
* **rows**: `rtfit.realtime.light_path_maps.METHODS` (K = 1, 4, 16 and the seed's 32), and the seed's 32
  with the fitted cut.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import replace
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS, to_drjit
from rtfit.realtime.light_path_maps import (
    CLUSTERS,
    CUT,
    CUT_FIT_ROW,
    ENTRY_POINTS,
    INPUTS,
    METHODS,
    SEED_CLUSTERS,
    cluster_entry_points,
    default_cut,
    membership,
    vpl_transfer,
)
from rtfit.realtime.methods import Method
from rtfit.reference.cache import array_digest
from rtfit.reference.device_arrays import device_vectors
from rtfit.reference.estimators import gbuffer_points, irradiance_pass, sub_seed

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase, Precompute
from .audit_lights import scene_light
from .audit_setup import AuditSetup, pooled_passes
from .case_inputs import vector_text
from .records import Check, Headline, Section
from .shipped import Sizes, Study, StudyContext

__all__ = [
    "CUT_GRID",
    "FAMILY",
    "MOVE",
    "SCENES",
    "bake_path_maps",
    "entry_points",
    "path_map_cases",
    "study",
    "transfer_terms",
]

FORMAT = 1
MOVE = 0.3
"""The light moves by ± this × the scene's widest bounding-box extent (cases p = 1, 2)."""
MARGIN = 0.05
"""A moved light stays this × the extent inside the scene's bounding box."""
CUT_GRID = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
"""The cut d_c tried by the fit, in entry-point disc radii (within `CUT`'s bounds)."""
ENTRY_SPP_FACTOR = 0.25
ENTRY_SPP_MIN = 8
"""The direct irradiance at the entry points: max(`ENTRY_SPP_MIN`, `ENTRY_SPP_FACTOR` × spp) samples each."""
FIT_ROW = CUT_FIT_ROW
ENTRY_SWEEP = (128, 256, 512)
"""The entry-point counts the study compares (every (N/n)-th of the bake, on the seed's 32 panes, the fitted
cut): 4, 8, 16 (and at N, 32) entry points per cluster."""

SCENES = (
    Sizes(full=(48, 48, 256), quick=(16, 16, 32)).scene(
        "light_path_maps_box.xml",
        "the colour-bleeding mini Cornell box (red and green walls, a white block) lit by a point light "
        "under the ceiling, moved towards each coloured wall",
    ),
)
"""The scene ``rtfit run light-path-maps`` audits (scenes/library/)."""


def _np3(v) -> np.ndarray:
    return np.stack([np.asarray(x, np.float64).ravel() for x in v], axis=-1)


def _scene_box(scene) -> tuple[np.ndarray, np.ndarray]:
    box = scene.bbox()
    return (np.array([float(box.min[i]) for i in range(3)]), np.array([float(box.max[i]) for i in range(3)]))


def _surface_shapes(scene) -> tuple[list, np.ndarray, list[str]]:
    """The shapes entry points go on (not lights, not sensors), their areas (m²), and the shapes left out:
    an ``instance`` (Mitsuba implements neither its area nor position sampling on it: its bounce is missing
    from the map, said in the case's parameters; found on mitsuba-data's instancing scene)."""
    shapes, areas, left = [], [], []
    for s in scene.shapes():
        if s.is_emitter() or s.is_sensor():
            continue
        try:
            area = float(np.asarray(s.surface_area()).ravel()[0])
        except RuntimeError:  # Shape::surface_area(): not implemented (an instance)
            left.append(str(s.id()) or "an unnamed shape")
            continue
        shapes.append(s)
        areas.append(area)
    return shapes, np.asarray(areas, np.float64), left


def entry_points(setup: AuditSetup, n: int):
    """N entry points on the surfaces that are not lights (module docstring): positions (N, 3), unit normals
    (N, 3), diffuse albedo (N, 3), the area each stands for (m²), the surfaces' total area A_S and the shapes
    left out (`_surface_shapes`); None where no surface can take them (every one an instance)."""
    mi, scene = setup.mi, setup.scene
    shapes, areas, left = _surface_shapes(scene)
    total = float(areas.sum())
    if not shapes or not total > 0.0:
        return None  # only instances (mitsuba-data's instancing scene): no map, no case (not an error)
    rng = np.random.default_rng(sub_seed(setup.seed, "light-path-maps-entries", 0))
    u = (np.arange(n) + rng.uniform(size=n)) / n  # stratified over the shapes by area
    which = np.minimum(np.searchsorted(np.cumsum(areas) / total, u, side="right"), len(shapes) - 1)
    pos, nrm = np.zeros((n, 3)), np.zeros((n, 3))
    for i, shape in enumerate(shapes):
        sel = np.flatnonzero(which == i)
        if not len(sel):
            continue
        uv = rng.uniform(size=(len(sel), 2))
        ps = shape.sample_position(0.0, mi.Point2f(mi.Float(uv[:, 0]), mi.Float(uv[:, 1])))
        pos[sel], nrm[sel] = _np3(ps.p), _np3(ps.n)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    lo, hi = _scene_box(scene)
    eps = 1e-4 * float(np.linalg.norm(hi - lo))
    ray = mi.Ray3f(device_vectors(mi, mi.Point3f, pos + eps * nrm), device_vectors(mi, mi.Vector3f, -nrm))
    ray.maxt = 4 * eps
    si = scene.ray_intersect(ray)
    reflectance, hit = si.bsdf(ray).eval_diffuse_reflectance(si), si.is_valid()
    dr.eval(reflectance, hit)  # one launch: each conversion below would trace the rays again
    albedo = _np3(reflectance)
    valid = np.asarray(hit, bool)
    albedo = np.where(valid[:, None], np.clip(np.nan_to_num(albedo), 0.0, 1.0), 0.0)
    return pos, nrm, albedo, total / n, total, left


def transfer_terms(setup: AuditSetup, points, normals, pos, nrm):
    """Per (visible point, entry point) pair (N_px, N): h, ρ², q, c of `vpl_transfer` and the visibility V
    (a Mitsuba shadow ray between the two, each lifted off its surface by 10⁻⁴ of the scene diagonal)."""
    mi = setup.mi
    v = points[:, None, :] - pos[None, :, :]
    h = np.einsum("pjk,jk->pj", v, nrm)
    r2 = np.einsum("pjk,pjk->pj", v, v)
    rho2 = np.maximum(r2 - h * h, 0.0)
    q = -np.einsum("pjk,pk->pj", v, normals)
    c = normals @ nrm.T
    lo, hi = _scene_box(setup.scene)
    eps = 1e-4 * float(np.linalg.norm(hi - lo))
    o = (points + eps * normals)[:, None, :] + 0.0 * v
    t = (pos + eps * nrm)[None, :, :] + 0.0 * v
    d = (t - o).reshape(-1, 3)
    dist = np.maximum(np.linalg.norm(d, axis=1), 1e-30)
    ray = mi.Ray3f(
        device_vectors(mi, mi.Point3f, o.reshape(-1, 3)), device_vectors(mi, mi.Vector3f, d / dist[:, None])
    )
    ray.maxt = to_drjit(mi.Float, dist * (1.0 - 1e-4))
    vis = ~np.asarray(setup.scene.ray_test(ray), bool)
    return h, rho2, q, c, vis.reshape(h.shape).astype(np.float64)


def _positions(setup: AuditSetup, light) -> list[np.ndarray]:
    """The light's offsets: 0 and ± `MOVE` × the widest extent (point and spot lights); 0 alone otherwise."""
    params = setup.mi.traverse(light.emitter)
    if light.centre is None or ("position" not in params and "to_world" not in params):
        return [np.zeros(3)]
    lo, hi = _scene_box(setup.scene)
    ext = hi - lo
    axis = int(np.argmax(ext))
    out = [np.zeros(3)]
    for sign in (-1.0, 1.0):
        target = light.centre.copy()
        target[axis] += sign * MOVE * ext[axis]
        target = np.clip(target, lo + MARGIN * ext, hi - MARGIN * ext)
        out.append(target - light.centre)
    return out


@contextlib.contextmanager
def _light_moved(mi, emitter, offset: np.ndarray):
    """The emitter moved by ``offset`` (its ``position`` or its ``to_world``), put back afterwards."""
    if not np.any(offset):
        yield
        return
    params = mi.traverse(emitter)
    key = "position" if "position" in params else "to_world"
    old = params[key]
    saved = mi.Point3f(old) if key == "position" else mi.AffineTransform4f(old)
    if key == "position":
        params[key] = saved + mi.Vector3f(*(float(x) for x in offset))
    else:
        params[key] = mi.AffineTransform4f().translate(mi.Vector3f(*(float(x) for x in offset))) @ saved
    params.update()
    try:
        yield
    finally:
        params[key] = saved
        params.update()


def _bake(tau_parts, cut: float, area_each: float, albedo: np.ndarray, groups: dict) -> dict:
    """K → per channel the (N_px, K) transfer T_k,c at cut d_c."""
    h, rho2, q, c, vis = tau_parts
    g = vpl_transfer(NUMPY_OPS, h, rho2, q, c, cut) * vis * area_each
    return {k: [(g * albedo[None, :, ch]) @ m for ch in range(3)] for k, (m, _) in groups.items()}


def _weights(groups: dict, e_entry: np.ndarray) -> dict:
    """K → per channel the (K,) cluster means of the entry points' direct irradiance."""
    return {k: [(m.T @ e_entry[:, ch]) / count for ch in range(3)] for k, (m, count) in groups.items()}


def _rmse_over(positions: list, baked: dict, groups: dict, idx=None) -> float:
    """RMSE (W/m², all channels and positions) of the walk on the one K of ``groups`` against the references;
    ``idx``: the entry points the bake used (None: all)."""
    ((k, t),) = baked.items()
    sse, count = 0.0, 0
    for _, e_entry, _, pooled in positions:
        w = _weights(groups, e_entry if idx is None else e_entry[idx])[k]
        for ch in range(3):
            sse += float(np.sum((t[ch] @ w[ch] - pooled.mean[:, ch]) ** 2))
            count += len(t[ch])
    return math.sqrt(sse / max(count, 1))


def _inputs(t: list, w: list, k: int) -> tuple[dict, ...]:
    out = []
    for ch in range(3):
        d: dict = {f"pane{i + 1}": np.ascontiguousarray(t[ch][:, i]) for i in range(k)}
        d.update({f"w{i + 1}": float(w[ch][i]) for i in range(k)})
        out.append(d)
    return tuple(out)


def _row_id(k: int) -> str:
    return "seed-path-map" if k == SEED_CLUSTERS else f"path-map-k{k}"


def bake_path_maps(setup: AuditSetup, points, normals, clusters=CLUSTERS, cut_factor: float = CUT.initial):
    """The seed's precompute (module docstring, light-independent): `ENTRY_POINTS` entry points, their
    clusters for each K of ``clusters``, the transfer terms of every (visible point, entry point) pair with a
    shadow ray, and the panes T_k,c at the cut ``cut_factor`` × √(A_S/(π N)). Returns None where no surface
    takes entry points, else (entries, groups, transfer terms, cut radius, K → per channel T_k,c). The
    audit's own bake; each row's timed precompute does its two halves apart (`_shared_precompute`, then
    `_precompute`'s clusters and panes for one K)."""
    entries = entry_points(setup, ENTRY_POINTS)
    if entries is None:  # no surface Mitsuba can sample (every one an instance)
        return None
    pos, nrm, albedo, area_each, area, _left = entries
    groups = _groups(setup, pos, nrm, clusters)
    parts = transfer_terms(setup, points, normals, pos, nrm)
    radius = default_cut(area, ENTRY_POINTS)
    return entries, groups, parts, radius, _bake(parts, cut_factor * radius, area_each, albedo, groups)


def _groups(setup: AuditSetup, pos, nrm, clusters) -> dict:
    """K → (membership (N, K), the clusters' sizes, at least 1) of the entry points for each K of
    ``clusters``."""
    lo, hi = _scene_box(setup.scene)
    groups = {}
    for k in clusters:
        labels = cluster_entry_points(pos, nrm, k, float(np.linalg.norm(hi - lo)))
        m = membership(labels, k)
        groups[k] = (m, np.maximum(m.sum(axis=0), 1.0))
    return groups


def _shared_precompute(setup: AuditSetup, points, normals) -> Precompute:
    """The K-independent part of every row's bake (`Precompute.shared`): (the entry points, the transfer
    terms of every (pixel, entry point) pair, a shadow ray each), timed once for the rows."""

    def run():
        entries = entry_points(setup, ENTRY_POINTS)
        return entries, transfer_terms(setup, points, normals, entries[0], entries[1])

    what = "the entry points and every pair's shadow ray and transfer"
    return Precompute(run=run, trigger="scene", what=what)


def _precompute(setup: AuditSetup, k: int, cut_factor: float, shared: Precompute) -> Precompute:
    """Row K's precompute as an engine pays it once per scene (`bake_path_maps` for that K alone): after the
    ``shared`` step that every row runs alike, its clusters and panes from that step's product (the engine
    hands it over: the case holds no transfer terms)."""

    def run(product):
        (pos, nrm, albedo, area_each, area, _left), parts = product
        radius = default_cut(area, ENTRY_POINTS)
        return _bake(parts, cut_factor * radius, area_each, albedo, _groups(setup, pos, nrm, (k,)))

    return Precompute(
        run=run,
        trigger="scene",
        what=f"bake: {ENTRY_POINTS} entry points clustered into {k}, a shadow ray and a transfer per "
        "(pixel, entry point)",
        shared=shared,
    )


def _scene_bake(setup: AuditSetup, points, normals, digest: str) -> tuple[Any, float, bool]:
    """(`bake_path_maps` of the visible points, its seconds, whether it was baked by this call). The bake is
    light-independent: the scene's other lights (their applicabilities) take the last one made for the same
    scene, seed and points (`_LAST_BAKE`). Issue 33 (session 33): a 64² audit of Mitsuba's
    integrator_direct_both scene (five lights) baked the same 4 075 520 shadow rays and transfers five times,
    ~10 s of its 23 s of references."""
    key = (setup.seed, digest)
    if _LAST_BAKE.get("scene") is setup.scene and _LAST_BAKE.get("key") == key:
        return _LAST_BAKE["bake"], _LAST_BAKE["seconds"], False
    _LAST_BAKE.clear()
    t0 = time.perf_counter()
    bake = bake_path_maps(setup, points, normals)
    seconds = time.perf_counter() - t0
    if bake is not None and sum(np.asarray(a).nbytes for a in bake[2]) <= BAKE_KEEP_BYTES:
        _LAST_BAKE.update(scene=setup.scene, key=key, bake=bake, seconds=seconds)
    return bake, seconds, True


BAKE_KEEP_BYTES = 256 << 20
"""The largest bake's transfer terms `_scene_bake` keeps for the scene's next light (a 64² audit's: ~160 MB of
float64 for 4 million pairs); a larger one (a 256² audit's: 16×) is made again for each light rather than
held through the rest of the audit."""
_LAST_BAKE: dict = {}
MEMOS = (_LAST_BAKE,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def path_map_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per light position (module docstring)."""
    mi, scene, mask = setup.mi, setup.scene, setup.mask
    if app.source is None:
        raise AuditError(f"light-path-maps: {app.part} is not a light of the scene")
    points, normals = gbuffer_points(setup.gbuffer, mask)
    if not len(points):
        raise AuditError("light-path-maps: the camera sees no surface")
    light = scene_light(setup, app.source)
    digest = array_digest(points, normals)
    bake, bake_seconds, baked_here = _scene_bake(setup, points, normals, digest)
    if bake is None:  # no surface Mitsuba can sample (every one an instance): the other families go on
        return []
    entries, groups, parts, radius, baked = bake
    pos, nrm, albedo, area_each, area, left_out = entries
    lo, hi = _scene_box(scene)
    entry_spp = max(ENTRY_SPP_MIN, int(ENTRY_SPP_FACTOR * setup.spp))
    tag = f"light{app.source}"
    positions = []
    for p, offset in enumerate(_positions(setup, light)):
        with _light_moved(mi, light.emitter, offset):
            seed = sub_seed(setup.seed, "light-path-maps-entry-light", p)
            res = irradiance_pass(mi, scene, pos, nrm, entry_spp, seed)
            e_entry = np.maximum(np.nan_to_num(res.mean), 0.0)
            what = {"format": FORMAT, "quantity": "path-map-bounce", "points": digest, "light": app.source,
                    "offset": [round(float(x), 9) for x in offset]}  # fmt: skip

            def render(spp: int, s: int):
                return irradiance_pass(mi, scene, points, normals, spp, s, transport="bounce")

            pooled = pooled_passes(setup, what, render, (-1, 3), f"{tag}-at{p}: one-bounce irradiance")
        positions.append((offset, e_entry, res.seconds, pooled))
    # the cut fitted across the positions (one bake serves them all): SSE of the seed's K over a grid
    seed_group = {SEED_CLUSTERS: groups[SEED_CLUSTERS]}
    sweep = {
        f: _rmse_over(positions, _bake(parts, f * radius, area_each, albedo, seed_group), seed_group)
        for f in CUT_GRID
    }
    best = min(sweep, key=lambda f: sweep[f])
    at = CUT_GRID.index(best)  # the fit's bracket: the grid values either side of the best
    bracket = (CUT_GRID[max(at - 1, 0)], CUT_GRID[min(at + 1, len(CUT_GRID) - 1)])
    fitted_t = _bake(parts, best * radius, area_each, albedo, seed_group)
    # the entry points per cluster: every (N/n)-th entry point (still stratified by area), the fitted cut
    diag = float(np.linalg.norm(hi - lo))
    entry_sweep = {}
    for n_sub in ENTRY_SWEEP:
        idx = np.arange(0, ENTRY_POINTS, ENTRY_POINTS // n_sub)
        m = membership(cluster_entry_points(pos[idx], nrm[idx], SEED_CLUSTERS, diag), SEED_CLUSTERS)
        sub = {SEED_CLUSTERS: (m, np.maximum(m.sum(axis=0), 1.0))}
        cut = best * default_cut(area, len(idx))
        t_sub = _bake(tuple(a[:, idx] for a in parts), cut, area / len(idx), albedo[idx], sub)
        entry_sweep[len(idx)] = _rmse_over(positions, t_sub, sub, idx)
    entry_sweep[ENTRY_POINTS] = sweep[best]
    methods: dict[str, Method] = {
        **METHODS,
        FIT_ROW: replace(METHODS[FIT_ROW], description=f"d_c = {best:g} × √(A_S/(π N)), the best of "
                         f"{len(CUT_GRID)} values across the light positions"),
    }  # fmt: skip
    cases = []
    shared = _shared_precompute(setup, points, normals)
    for p, (offset, e_entry, e_seconds, pooled) in enumerate(positions):
        where = vector_text(light.centre + offset) if light.centre is not None else light.kind
        ref = pooled.reference(
            mask,
            quantity=f"one-bounce indirect irradiance at the visible points, light at {where} (W/m², RGB)",
            integrator="a cosine-distributed ray from each visible point, then π × (path max_depth 2 − path "
            "max_depth 1): one reflection of every light's direct light",
            integrator_reason="the indirect light a path map stands in for, with the light at this position",
            extra_seconds=e_seconds + (bake_seconds if p == 0 and baked_here else 0.0),
        )
        weights = _weights(groups, e_entry)
        rows = {_row_id(k): _inputs(baked[k], weights[k], k) for k in CLUSTERS}
        rows[FIT_ROW] = _inputs(fitted_t[SEED_CLUSTERS], weights[SEED_CLUSTERS], SEED_CLUSTERS)
        precompute = {_row_id(k): _precompute(setup, k, CUT.initial, shared) for k in CLUSTERS}
        precompute[FIT_ROW] = _precompute(setup, SEED_CLUSTERS, best, shared)
        cases.append(
            FamilyCase(
                id=f"{tag}-at{p}",
                label=f"one bounce with the light at {where}" + (" (as declared)" if p == 0 else " (moved)"),
                reference=ref,
                channel_inputs=rows["seed-path-map"],
                parameters={
                    "light_position": [float(x) for x in (light.centre + offset)]
                    if light.centre is not None
                    else None,
                    "offset": [float(x) for x in offset],
                    "entry_points": ENTRY_POINTS,
                    "entry_shapes_left_out": left_out,
                    "clusters": list(CLUSTERS),
                    "cut_radius": radius,
                    "cut_default": CUT.initial * radius,
                    "cut_fitted_factor": best,
                    "cut_fitted_bracket": list(bracket),
                    "cut_sweep_rmse": {f"{f:g}": v for f, v in sweep.items()},
                    "entry_sweep_rmse": {str(n): v for n, v in entry_sweep.items()},
                    "bake_seconds": bake_seconds,
                    "bake_pairs": int(parts[0].size),
                    "entry_spp": entry_spp,
                    "entry_irradiance_mean": float(e_entry.mean()),
                    "pixels": int(mask.sum()),
                },
                units="W/m²",
                notes=(
                    f"{ENTRY_POINTS} entry points (area each {area_each:.4g} m²), clusters K = "
                    f"{', '.join(map(str, CLUSTERS))}; cut d_c = {CUT.initial:g} × {radius:.4g} (the disc "
                    "each entry point stands for)",
                    f"{FIT_ROW}: d_c = {best:g} × {radius:.4g} (bracket {bracket[0]:g}–{bracket[1]:g}), the "
                    f"best of {len(CUT_GRID)} values over all {len(positions)} light positions (fitted on "
                    "the same pixels it is compared on)",
                    f"bake: {parts[0].size} shadow rays and transfers in {bake_seconds:.3g} s (paid once); "
                    f"the walk reads K panes per pixel",
                    *(
                        ()
                        if len(positions) > 1
                        else (
                            f"{light.kind}: not moved (an area light's shape is scene "
                            "geometry): audited where the scene puts it",
                        )
                    ),
                ),
                methods=methods,
                row_inputs=rows,
                precompute=precompute,
            )
        )
    return cases


FAMILY = AuditFamily(
    name="light-path-maps",
    quantity="path_map_irradiance",
    cases=path_map_cases,
    describe=(
        "The one-bounce indirect irradiance at each visible point, per channel (W/m², RGB), for the light "
        "where the scene puts it and moved towards either side (π × (Mitsuba path max_depth 2 − 1) "
        "along cosine rays, independent passes) — against the seed's light path maps: "
        f"{ENTRY_POINTS} entry points on the surfaces, clustered by position and orientation into K = "
        f"{', '.join(map(str, CLUSTERS))} panes, each pane the baked one-bounce transfer of its entry points "
        "as virtual lights (shadow rays, the seed's cut), blended at run time by the light's mean direct "
        "irradiance at each cluster's entry points; and the seed's K = 32 with the cut fitted across the "
        "light's positions."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "light-path-maps",
            "indirect light from a moving light",
            ("punctual-light", "geometry"),
            "{part} bounces off {with_}; as the light moves, an engine blends path maps baked from "
            "clustered entry points by the light's irradiance at each cluster",
            "one-bounce indirect irradiance at the visible points, per light position",
            "a cosine ray from each visible point, then path max_depth 2 minus max_depth 1 (π ×), the light "
            "moved; the bake's visibility by Mitsuba shadow rays, the weights by emitter sampling",
            supplies=frozenset(i.name for i in INPUTS),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ study
def _clusters_of(row: str) -> int | None:
    if row in ("seed-path-map", FIT_ROW):
        return SEED_CLUSTERS
    if row.startswith("path-map-k"):
        return int(row.removeprefix("path-map-k"))
    return None


def study(ctx: StudyContext) -> Study:
    """Error against K and the light's position, the per-pixel cost beside it and the bake's cost; the cut's
    sweep (RMSE of the seed's K = 32 across the positions per d_c)."""
    lines = [
        "| case | light at | row | K | RMSE (W/m²) | RMSE / mean | RMSE / floor | walk ns/px |",
        "|---|---|---|---|---|---|---|---|",
    ]
    bake, sweep, entries, checks = [], [], [], []
    relative: dict[str, list[float]] = {}
    for result in ctx.audits:
        for case in result.cases:
            par = case.parameters
            if "cut_sweep_rmse" not in par:
                continue
            ref = case.reference.mean[case.mask]
            mean = float(np.mean(ref)) if ref.size else float("nan")
            where = vector_text(par["light_position"]) if par.get("light_position") else "—"
            for row_id, out in result.outcomes.get(case.id, {}).items():
                k = _clusters_of(row_id)
                rmse = out.metrics["rmse"]
                ratio = rmse.value / rmse.noise_floor if rmse.noise_floor else float("nan")
                cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
                finite = bool(np.all(np.isfinite(out.image)))
                if mean > 0:
                    relative.setdefault(row_id, []).append(rmse.value / mean)
                checks.append(Check(name=f"{case.id} {row_id}: finite", value=str(finite), expected="True",
                                    passed=finite))  # fmt: skip
                lines.append(
                    f"| {case.id} | {where} | {row_id} | {k or '—'} | {rmse.value:.4g} | "
                    f"{rmse.value / mean if mean > 0 else float('nan'):.3g} | {ratio:.3g} | "
                    f"{f'{cost:.3g}' if cost else '—'} |"
                )
            if case.id.endswith("-at0"):
                pairs = par["bake_pairs"]
                bake.append(
                    f"| {case.id.removesuffix('-at0')} | {par['entry_points']} | {pairs} | "
                    f"{par['bake_seconds']:.3g} | {1e9 * par['bake_seconds'] / max(pairs, 1):.3g} |"
                )
                sweep += [f"| {case.id.removesuffix('-at0')} | {f} | {v:.4g} |" for f, v in
                          par["cut_sweep_rmse"].items()]  # fmt: skip
                entries += [
                    f"| {case.id.removesuffix('-at0')} | {n} | {int(n) / SEED_CLUSTERS:g} | "
                    f"{par['bake_seconds'] * int(n) / par['entry_points']:.3g} | {v:.4g} |"
                    for n, v in par.get("entry_sweep_rmse", {}).items()
                ]
    text = (
        "Each row's error per light position beside its run-time cost (the walk: K pane reads and "
        "multiply-adds per pixel; the kernel text's measured ns per pixel), and the bake's one-off cost "
        "(a shadow ray and a transfer per visible point and entry point, on this machine's Mitsuba).\n\n"
        + "\n".join(lines)
        + "\n\n| scene light | entry points | pairs (points × entry points) | bake s | bake ns / pair |\n"
        "|---|---|---|---|---|\n"
        + "\n".join(bake)
        + "\n\nThe cut d_c (in entry-point disc radii √(A_S/(π N))) against the RMSE of the seed's K = 32 "
        "over every light position (W/m²):\n\n| scene light | d_c factor | RMSE |\n|---|---|---|\n"
        + "\n".join(sweep)
        + "\n\nThe entry points N of the bake (every (1024/N)-th, on the seed's 32 panes, the fitted cut): "
        "the bake's cost (∝ N, scaled from the measured bake) beside the RMSE over every light position "
        "(W/m²):\n\n"
        "| scene light | N | entry points per pane | bake s (∝ N) | RMSE |\n|---|---|---|---|---|\n"
        + "\n".join(entries)
    )
    headline = tuple(
        Headline(label=f"{row} RMSE / mean, over the light positions", value=float(np.mean(v)))
        for row, v in relative.items()
        if row in ("path-map-k1", "seed-path-map", FIT_ROW)
    )
    return Study(
        sections=(Section("path-map-cost", "Error against K and light position, beside cost", text),),
        checks=tuple(checks),
        headline=headline,
    )
