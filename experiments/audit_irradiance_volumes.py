"""The ``irradiance-volumes`` family in `rtfit audit`: a regular grid of path-traced probes over the user's
scene, looked up at the visible points, against path-traced irradiance there.

For a Mitsuba XML or rtfit TOML scene with surfaces and a finite bounding box, one case ``volume``:

* **The grid** (`probe_grid`): cubic cells (`rtfit.realtime.irradiance_volumes.ProbeGrid` has one spacing h),
  the nodes centred in the scene's box with h = max over the axes of extent/n (each node the centre of one
  of n equal cells along the longest axis, so that no probe sits on the box's faces, where the walls and the
  floor of a room are). ``--grid NX,NY,NZ`` sets n per axis; the default puts `DEFAULT_NODES` nodes on the
  longest side and round(extent/h) (at least 1) on the others, so the cells follow the box's aspect.
* **The probes** (the family's reference, `rtfit.reference.probe_radiance.probe_radiance_pass` with the
  irradiance-volumes experiment's `probe_features`): at each node, `PROBE_SPP_FACTOR` × ``--spp``
  directions uniform on the sphere, one Mitsuba ``path`` sample of the incident radiance each (unbounded
  depth), projected on SH L2, on the clamped cosines of the six axes (Valve's ambient cube) and of
  `NNLS_NORMALS` Fibonacci normals (the NNLS cube's fit); `probe_bases` turns them into the stored
  coefficients, exactly as the experiment bakes its volume.
* **Reference**: the irradiance at each visible point with the camera-facing normal,
  `rtfit.reference.estimators.irradiance_pass` with ``global`` transport (a cosine-distributed ray, then
  Mitsuba's ``path``: unbounded depth), in independent passes through the pass cache with per-pixel standard
  errors (W/m², RGB). It counts every light a ray can reach, as the probes do: an area light, an
  environment, and all light after one bounce; the *direct* light of a point, spot or directional light
  reaches neither (a ray never hits it: an engine adds it per pixel and keeps the volume for the rest).
* **Total irradiance** (case `TOTAL_CASE`, only where the scene has delta lights: point, spot, directional):
  the reference above plus each delta light's exact direct light at the visible points
  (`rtfit.reference.probe_radiance.delta_light_irradiance`: Mitsuba's emitter sample × cos × a shadow ray),
  against the six rows reading probes with the delta lights *folded* in (`folded_bases`: a distant light from
  the light's direction at each probe, its E⊥ through the probe's own shadow ray; seed 7.4.3) and against
  the six ``direct-…`` rows (`SPLIT_METHODS`: that exact direct light + the unfolded volume's lookup, the
  engine's usual split). Both cases share the probe bake and the global pass.
* **Rows**: `rtfit.realtime.irradiance_volumes.METHODS` — nearest and trilinear lookup × Valve's cube, the
  NNLS cube and SH L2 — each reading its own basis's table (`FamilyCase.row_inputs`); no free parameters.
  A user's ``@approximation(quantity="volume_irradiance")`` reads the same points, normals and grid, with
  the SH L2 table as ``g.table`` and both cubes' as ``g.cube_table`` and ``g.nnls_table``.

What the numbers mean: a probe stores the light at its node, a visible point receives the light at its own
position and normal; the rows' error is the volume's spatial resolution (nearest: popping between cells;
trilinear: blur) plus the basis's angular resolution, plus **leaking**: a probe inside an object or behind a
wall sees darkness (or light) a surface point next to it does not.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import partial

import numpy as np

from rtfit.realtime.irradiance_volumes import (
    METHODS,
    ProbeGrid,
    directional_irradiance,
    fold_directional,
    probe_table,
    with_direct,
)
from rtfit.realtime.methods import Method
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import irradiance_pass
from rtfit.reference.probe_radiance import delta_light_irradiance, probe_radiance_pass

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditSetup, pooled_passes
from .case_inputs import masked_image, vector_text
from .probe_projection import FEATURE_NORMALS, FEATURES_NAME, NNLS_NORMALS, probe_bases, probe_features
from .shipped import ShippedScene, Sizes

__all__ = [
    "DEFAULT_NODES",
    "FAMILY",
    "GRIDS",
    "PROBE_SPP_FACTOR",
    "QUICK_GRIDS",
    "SCENES",
    "TOTAL_CASE",
    "folded_bases",
    "irradiance_volume_cases",
    "on_grid",
    "probe_grid",
]

FORMAT = 1
DEFAULT_NODES = 4
"""Nodes along the longest side of the scene's box by default."""
PROBE_SPP_FACTOR = 64
"""Each probe takes this many times ``--spp`` directions (a probe is baked once, offline, with many)."""
TOTAL_CASE = "volume-total"
"""The case of a scene with delta lights (point, spot, directional): the total irradiance, against the
volume with those lights folded into its probes and against exact direct light + the volume."""


def probe_grid(lo, hi, dims=None) -> ProbeGrid:
    """The probe grid over the box [lo, hi] (module docstring): ``dims`` (n_x, n_y, n_z) nodes, or the
    default by the box's aspect. Refuses a box that is not finite or has no extent (`AuditError`)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = hi - lo
    longest = float(np.max(extent)) if np.all(np.isfinite(extent)) else math.nan
    if not (math.isfinite(longest) and longest > 0.0):
        raise AuditError(
            f"irradiance-volumes: the scene's box {lo}–{hi} has no finite extent for a probe grid"
        )
    if dims is None:
        h = longest / DEFAULT_NODES
        dims = tuple(max(1, round(float(e) / h)) for e in extent)
    else:
        h = max(float(e) / n for e, n in zip(extent, dims, strict=True))
    n = np.asarray(dims, np.float64)
    origin = 0.5 * (lo + hi) - 0.5 * (n - 1.0) * h
    return ProbeGrid(tuple(float(v) for v in origin), h, tuple(int(v) for v in dims))  # type: ignore[arg-type]


def irradiance_volume_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case: the six volume rows against the global irradiance at the visible points."""
    mi, scene = setup.mi, setup.scene
    box = setup.info.bbox
    if box is None:
        b = scene.bbox()
        box = (tuple(b.min), tuple(b.max))
    grid = probe_grid(box[0], box[1], setup.grid)
    positions = grid.positions()
    mask = setup.mask
    points = setup.gbuffer.position[mask].astype(np.float64)
    normals = setup.gbuffer.normal[mask].astype(np.float64)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    k = probe_features(np.array([[0.0, 0.0, 1.0]])).shape[1]
    baking = replace(setup, spp=PROBE_SPP_FACTOR * setup.spp, pass_spp=PROBE_SPP_FACTOR * setup.pass_spp)
    probes = pooled_passes(
        baking,
        {
            "format": FORMAT,
            "quantity": "probe-radiance",
            "features": FEATURES_NAME,
            "positions": array_digest(positions),
        },
        lambda spp, seed: probe_radiance_pass(mi, scene, positions, probe_features, spp, seed),
        (-1, k, 3),
        f"volume: {grid.count} probes",
        seed_label="probes",
    )
    pooled = pooled_passes(
        setup,
        {"format": FORMAT, "quantity": "irradiance-global", "points": array_digest(points, normals)},
        lambda spp, seed: irradiance_pass(mi, scene, points, normals, spp, seed, transport="global"),
        (-1, 3),
        f"volume: irradiance at {len(points)} points",
    )
    bases = probe_bases(probes.mean)
    geometry = {
        **{f"p{c}": np.ascontiguousarray(points[:, j]) for j, c in enumerate("xyz")},
        **{f"n{c}": np.ascontiguousarray(normals[:, j]) for j, c in enumerate("xyz")},
    }
    tables = {b: probe_table(c) for b, c in bases.items()}
    row_inputs = {mid: ({**geometry, "table": tables[m.fixed["basis"].id]},) for mid, m in METHODS.items()}
    # what a user's volume_irradiance reads (rtfit.realtime.quantities): the SH L2 table, and both cubes'
    user_inputs = {**geometry, "table": tables["sh-l2"], "cube_table": tables["cube-valve"],
                   "nnls_table": tables["cube-nnls"]}  # fmt: skip
    methods = {mid: on_grid(m, grid) for mid, m in METHODS.items()}
    ref = pooled.reference(
        mask,
        quantity="irradiance at the visible points (W/m²): every light a ray can reach",
        integrator="global irradiance: a cosine-distributed ray, then path (unbounded depth)",
        integrator_reason=(
            "the light a probe can store: emitters a ray hits and every bounce; the direct light of point, "
            "spot and directional lights reaches neither the probes nor this reference"
        ),
        extra_seconds=probes.seconds,
    )
    lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
    outside = int(np.sum(np.any((positions < lo) | (positions > hi), axis=1)))
    parameters = {
        "grid_dims": list(grid.dims),
        "grid_origin": list(grid.origin),
        "grid_spacing": grid.spacing,
        "grid_from": "--grid" if setup.grid is not None else f"{DEFAULT_NODES} nodes on the longest side",
        "probes": grid.count,
        "probes_outside_the_box": outside,
        "probe_spp": probes.spp,
        "nnls_normals": NNLS_NORMALS,
        "pixels": int(mask.sum()),
    }
    dims = "×".join(str(d) for d in grid.dims)
    notes = (
        f"probe grid {dims} ({parameters['grid_from']}), spacing {grid.spacing:.4g}, centred in the "
        f"scene's box {vector_text(lo)}–{vector_text(hi)}; {outside} probe(s) outside it",
        f"each probe: {probes.spp} path-traced directions, projected on SH L2, Valve's six axes and "
        f"{NNLS_NORMALS} normals (the NNLS cube)",
    )
    volume = FamilyCase(
        id="volume",
        label=f"probe grid {dims}, irradiance at the visible points",
        reference=ref,
        channel_inputs=(user_inputs,),
        parameters=parameters,
        units="W/m²",
        notes=notes,
        methods=methods,
        row_inputs=row_inputs,
        user_rows=partial(on_grid, grid=grid),
    )
    at_probes = delta_light_irradiance(mi, scene, positions)
    if not at_probes:
        return [volume]
    at_pixels = delta_light_irradiance(mi, scene, points, normals)
    direct = np.zeros_like(normals)  # each delta light's E⊥·max(n·d, 0) at the visible points
    for d, e in at_pixels:
        direct += e * np.maximum(np.einsum("ij,ij->i", normals, d), 0.0)[:, None]
    folded = {b: probe_table(c) for b, c in folded_bases(probes.mean, at_probes).items()}
    rows = {**methods, **{f"direct-{mid}": with_direct(m) for mid, m in methods.items()}}  # SPLIT_METHODS
    split = {f"direct-{mid}": ({**v[0], **{f"direct_{c}": direct[:, j] for j, c in enumerate("rgb")}},)
             for mid, v in row_inputs.items()}  # fmt: skip
    folded_inputs = {mid: ({**geometry, "table": folded[m.fixed["basis"].id]},) for mid, m in METHODS.items()}
    n_lights = len(at_probes)
    total_ref = replace(
        ref,
        mean=ref.mean + masked_image(mask, direct),
        quantity="total irradiance at the visible points (W/m²): the delta lights' direct light + every "
        "light a ray can reach",
        integrator=f"{ref.integrator}, plus the direct light of {n_lights} delta light(s): Mitsuba's "
        "emitter sample (I/r², a spot's falloff) × cos × a shadow ray (exact: one direction, no noise)",
        integrator_reason="what an engine shows: a delta light's direct light, which no probe ray hits, "
        "added to the global irradiance",
    )
    lit = np.concatenate([e for _, e in at_probes], axis=1)
    total = FamilyCase(
        id=TOTAL_CASE,
        label=f"probe grid {dims}, total irradiance: {n_lights} delta light(s) folded into the probes, or "
        "exact direct + the volume",
        reference=total_ref,
        channel_inputs=(
            {
                **geometry,
                "table": folded["sh-l2"],
                "cube_table": folded["cube-valve"],
                "nnls_table": folded["cube-nnls"],
            },
        ),
        parameters={
            **parameters,
            "delta_lights": n_lights,
            "probes_seeing_a_delta_light": int(np.sum(np.any(lit > 0.0, axis=1))),
        },
        units="W/m²",
        notes=(
            *notes,
            f"folded rows: each of the {n_lights} delta light(s) added to every probe as a distant light "
            "from its direction at the probe, E⊥ = V·I/r² (V: the probe's own shadow ray; seed 7.4.3, "
            "fold_directional); the NNLS cube refitted on the folded irradiance",
            "direct-… rows: the delta lights' exact direct light per pixel (the reference's own) + the "
            "unfolded volume: the engine's usual split; their cost is the lookup's plus three adds (the "
            "direct light's shadow rays are not timed)",
        ),
        methods=rows,
        row_inputs={**folded_inputs, **split},
        user_rows=partial(on_grid, grid=grid),
    )
    return [volume, total]


def folded_bases(mean: np.ndarray, lights) -> dict[str, np.ndarray]:
    """`probe_bases` of the probes' projections ``mean`` (P, K, 3) with ``lights`` folded in: per light
    (d (P, 3), E⊥ (P, 3)) as `delta_light_irradiance` gives them at the probes (`fold_directional`; the
    NNLS cube refitted on the folded irradiance at its normals)."""
    normals = FEATURE_NORMALS[6:]
    extra = np.zeros((len(mean), len(normals), 3))
    sh = np.zeros((len(mean), 9, 3))
    cube = np.zeros((len(mean), 6, 3))
    for d, e in lights:
        for k in range(len(mean)):
            if np.any(e[k]):
                extra[k] += directional_irradiance(d[k], e[k], normals)
        dsh, dcube = fold_directional(d, e)
        sh, cube = sh + dsh, cube + dcube
    bases = probe_bases(mean, extra)
    return {**bases, "sh-l2": bases["sh-l2"] + sh, "cube-valve": bases["cube-valve"] + cube}


def on_grid(method: Method, grid: ProbeGrid) -> Method:
    """``method`` (a row of `METHODS`, or a user's approximation of ``volume_irradiance``) with the grid as
    a fixed keyword: the grid is this scene's constant, not a per-pixel input."""
    return replace(
        method,
        inputs=tuple(i for i in method.inputs if i.name != "grid"),
        fixed={**method.fixed, "grid": grid},
    )


FAMILY = AuditFamily(
    name="irradiance-volumes",
    quantity="volume_irradiance",
    cases=irradiance_volume_cases,
    describe=(
        "A regular grid of probes over the scene's bounding box (cubic cells, nodes centred in the box; "
        f"--grid NX,NY,NZ, default {DEFAULT_NODES} nodes on the longest side), each path-traced along "
        "uniform sphere directions and projected on SH L2, Valve's ambient cube and the NNLS cube's normals, "
        "as the irradiance-volumes experiment bakes them; the nearest and trilinear lookups of each basis at "
        "the visible points and camera-facing normals, against the path-traced irradiance there (a "
        "cosine-distributed ray, then unbounded path tracing: every light a ray can reach, as the probes)."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "irradiance-volumes",
            "probe grid",
            ("volume", "geometry"),
            "{part}: probes baked there stand in for the light that {with_} shapes over the visible points",
            "path-traced irradiance at the visible points (every light a ray can reach, as the probes store "
            "it)",
            "a cosine-distributed ray from each visible point, then path (unbounded depth); the probes: "
            "uniform sphere directions from each node, the same integrator",
            supplies=frozenset({"direct_r", "direct_g", "direct_b"}),  # the delta lights' exact direct light
        ),
    ),
)


GRIDS = ((2, 2, 2), (4, 4, 4), (8, 8, 8))
"""The probe grids of the shipped scenes: the room's box is 4 m on every side (its bounding box, the camera
and the light included), so spacings 2, 1 and 0.5 m (each grid's nodes are not a subset of the next: nodes
sit at cell centres)."""


QUICK_GRIDS = (GRIDS[0], GRIDS[-1])
"""Those ``--quick`` audits: the coarsest and the finest (the engine times every row's cost per scene: ~7 s a
scene on 2 CPU cores, so the middle grid is the full run's)."""


_sizes = Sizes(full=(64, 64, 256), quick=(24, 24, 64))


def _room(dims: tuple[int, int, int]) -> ShippedScene:
    h = 4.0 / dims[0]
    return _sizes.scene(
        "volume_room.toml",
        f"the room with a bright point light and an occluder, probe grid {'×'.join(map(str, dims))} "
        f"(spacing {h:g} m)",
        options={"grid": dims},
        name=f"volume_room-h{h:g}".replace(".", "p"),
        quick=dims in QUICK_GRIDS,
    )


SCENES = tuple(_room(d) for d in GRIDS)
"""The scenes ``rtfit run irradiance-volumes`` audits: scenes/library/volume_room.toml (the experiment's
closed 4 × 4 × 2.5 m room, red and green side walls, a 20 W/sr point light and a thin occluding wall) once
per probe grid of `GRIDS`; `QUICK_GRIDS` in ``--quick`` (probes: `PROBE_SPP_FACTOR` × spp directions each)."""
