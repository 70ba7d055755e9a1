"""The ``sdf-occlusion`` family in `rtfit audit`, role "ambient occlusion": the scene's own geometry occluding
itself, on the scene's own camera.

Quantity (`rtfit.realtime.quantities` ``ambient_occlusion``, dimensionless): the cosine-weighted visibility
within a radius R at each visible point x with unit normal n,

    A(x) = (1/π) ∫_{H(n)} V_R(x, ω) (n·ω) dω,   V_R = 1 when the ray x + tω meets nothing for t < R,

with R = ``--ao-distance`` (default `rtfit.experiments.audit.AO_FRACTION` × the scene's bounding-box
diagonal). Reference: `rtfit.reference.occlusion.occlusion_pass` (quantity ``ao``): cosine-distributed rays
of length R against the scene's own shapes (Mitsuba's ray tracer), the cheapest exact estimator of A, in
independent passes through the pass cache, with per-pixel standard errors.

The approximations read a distance field baked from the scene's own triangles
(`rtfit.experiments.audit_geometry.scene_triangles`: Mitsuba's mesh buffers, analytic shapes tessellated —
the loaded scene of a Mitsuba XML file or rtfit's Mitsuba build of a TOML scene's surfaces, read alike)
on a grid over the scene's bounding box padded by R, `GRID_CELLS` cells along its longest side
(`rtfit.realtime.sdf_grid.mesh_sdf_grid`: the sign by flood fill from outside, since user scenes are rarely
watertight, or unsigned where that fails — both say so in the case's notes), with `MIP_LEVELS` prefiltered
mip levels (`GridSDF.from_grid`). Rows (`rtfit.realtime.sdf_occlusion.METHODS`):

* ``cone``: cone-traced distance-field AO (9 cones × 8 steps from one voxel to R), its aperture k fitted
  to this scene;
* ``curvature``: Evans' crease term from the blurred field s₁(x) (its k fitted), which engines use as a
  cheap AO stand-in;
* ``evans-text`` and ``evans-listing``: Evans' multi-scale skylight C = B·exp(−k Σ w_i D_i) (seed
  000:2919-2987; k, and B for the listing, fitted), with its four samples along N + αU (U: the scene's up
  axis, as `--list` reports it), compared with AO as the sdf-occlusion experiment compares it. The sample
  terms D_i depend only on the geometry and the row's fixed α and base distance, so they are computed once
  per row (`evans_terms`) and given to the row as four per-pixel inputs ``d1``..``d4``; the row's kernel is
  the table's own (`METHODS[id].kernel`) on those terms. ``evans-fit`` (α and the base fitted too) is not
  offered: its terms move with its parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rtfit.realtime.arrays import NUMPY_OPS, xyz_columns
from rtfit.realtime.methods import Input, Method
from rtfit.realtime.sdf_grid import grid_for_bounds, mesh_sdf_grid
from rtfit.realtime.sdf_occlusion import (
    CURVATURE_LEVEL,
    EVANS_SAMPLES,
    METHODS,
    EvansParams,
    GridSDF,
    evans_terms,
)
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.occlusion import occlusion_pass

from .audit import Applicability, Rule
from .audit_family import (
    AuditError,
    AuditFamily,
    AuditSetup,
    FamilyCase,
    PooledPasses,
    pooled_passes,
)
from .audit_geometry import ao_radius, scene_triangles

__all__ = [
    "FAMILY",
    "GRID_CELLS",
    "MIP_LEVELS",
    "DistanceFieldRows",
    "ao_radius",
    "ao_reference",
    "distance_field_rows",
    "scene_distance_field",
]

FORMAT = 1
GRID_CELLS = 64
"""Cells of the distance field along the scene's longest side (a 64³ grid: the sdf-occlusion experiment's
quick resolution)."""
MIP_LEVELS = 5
ROLE = "ambient occlusion"
ROWS = ("cone", "curvature", "evans-text", "evans-listing")
EVANS_ROWS = ("evans-text", "evans-listing")


def _up_vector(up: str) -> tuple[float, float, float]:
    """``"+y"`` → (0, 1, 0): the scene's up axis as `SceneInfo.up` names it."""
    v = [0.0, 0.0, 0.0]
    v["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
    return (v[0], v[1], v[2])


def evans_on_terms(method: Method) -> Method:
    """``method`` (an Evans row of `METHODS`) reading its sample terms as the per-pixel inputs d1..dn: the
    same kernel (``method.kernel``) given the tuple (d1, …, dn) as its ``terms``."""
    names = tuple(f"d{i + 1}" for i in range(EVANS_SAMPLES))
    base = method.kernel

    def kernel(ops, **kw):
        terms = tuple(kw.pop(n) for n in names)
        return base(ops, terms, **kw)

    inputs = tuple(
        Input(n, "scene units", f"sample term D_{i + 1} = d_{i + 1} − s_{i}(P + d_{i + 1} N')")
        for i, n in enumerate(names)
    )
    return replace(method, kernel=kernel, inputs=inputs)


def scene_distance_field(mi, mi_scene, pad: float) -> tuple[GridSDF, str, list[str]]:
    """(mip chain, sign mode used, one line per shape) of the scene's triangles on a grid over their bounding
    box padded by ``pad`` (scene units) and two voxels. The last bake is kept (both sdf-occlusion roles and
    the aperture fill read the same field in one run)."""
    if _LAST_FIELD.get("scene") is mi_scene and _LAST_FIELD.get("pad") == pad:
        return _LAST_FIELD["value"]
    v, f, lines = scene_triangles(mi, mi_scene)
    lo = v.min(axis=0) - pad
    hi = v.max(axis=0) + pad
    origin, voxel, shape = grid_for_bounds(lo, hi, GRID_CELLS)
    for sign in ("flood", "unsigned"):
        try:
            grid = mesh_sdf_grid(v, f, origin, voxel, shape, sign=sign)
            break
        except ValueError:
            if sign == "unsigned":
                raise
    levels = max(1, min(MIP_LEVELS, int(math.log2(max(2, min(shape)))) - 1))
    value = (GridSDF.from_grid(grid, levels), sign, lines)
    _LAST_FIELD.clear()
    _LAST_FIELD.update(scene=mi_scene, pad=pad, value=value)
    return value


_LAST_FIELD: dict = {}


def ao_reference(setup: AuditSetup, points, normals, radius: float, label: str) -> PooledPasses:
    """The pooled AO passes (the ambient-aperture family's caps read the same entry): mean and stderr (N,),
    the AO within ``radius`` of each point (1: unoccluded)."""
    what = {
        "format": FORMAT,
        "quantity": "ao",
        "radius": float(radius),
        "points": array_digest(points, normals),
    }

    def render(spp: int, seed: int):
        return occlusion_pass(
            setup.mi, setup.scene, points, normals, spp, seed, quantity="ao", max_distance=radius
        )

    return pooled_passes(setup, what, render, (-1,), label, seed_label="ao-pass")


@dataclass(frozen=True)
class DistanceFieldRows:
    """The distance-field rows of `METHODS` on one set of visible points, as both sdf-occlusion roles
    evaluate them (ambient occlusion here; sky occlusion in `rtfit.experiments.audit_sky_occlusion`):
    the baked field (``sdf``, its ``sign`` mode, one line per shape in ``shapes``), the per-pixel
    ``inputs`` every row reads, the rows themselves (``methods``: the Evans rows read their sample terms
    as d1..d4, `evans_on_terms`), the Evans rows' own ``row_inputs`` (one mapping: the same for every
    channel) and ``params`` (the per-scene-unit k of the curvature and Evans rows, scaled by 1/R)."""

    sdf: GridSDF
    sign: str
    shapes: list[str]
    inputs: dict
    methods: dict[str, Method]
    row_inputs: dict
    params: dict
    range_notes: tuple[str, ...] = ()

    @property
    def notes(self) -> tuple[str, ...]:
        shape = self.sdf.grids[0].shape
        return (
            *self.range_notes,
            f"distance field: {shape[0]}×{shape[1]}×{shape[2]} cells of {self.sdf.voxel:.4g} over the scene "
            f"padded by R, {self.sdf.levels} mip levels, sign by "
            + ("flood fill from outside" if self.sign == "flood" else "none (unsigned: flood fill failed)"),
            "geometry: " + "; ".join(self.shapes),
        )

    @property
    def parameters(self) -> dict:
        return {"grid": list(self.sdf.grids[0].shape), "voxel": float(self.sdf.voxel), "sign": self.sign}


def distance_field_rows(
    setup: AuditSetup, wanted, points, normals, radius: float, t_max: float | None = None
) -> DistanceFieldRows:
    """The field baked from the scene's triangles over their bounds padded by ``radius`` (the AO radius R,
    so that both roles read the same field), and the rows of `ROWS` among ``wanted`` (method ids) on
    ``points``/``normals`` (float64 (N, 3), unit normals). The cone marches from one voxel to ``t_max``
    (default R)."""
    sdf, sign, shapes = scene_distance_field(setup.mi, setup.scene, radius)
    blurred = sdf.sample(NUMPY_OPS, CURVATURE_LEVEL, *points.T.astype(np.float64))
    inputs = {
        **xyz_columns("p", points),
        **xyz_columns("n", normals),
        "sdf": sdf,
        "t0": float(sdf.voxel),
        "t_max": float(radius if t_max is None else t_max),
        "ao_distance": float(radius),
        "distance": np.asarray(blurred, np.float64),
    }
    methods = {m: METHODS[m] for m in ROWS if m in wanted}
    up = _up_vector(setup.info.up)
    row_inputs = {}
    for rid in EVANS_ROWS:
        if rid not in methods:
            continue
        fixed = methods[rid].fixed
        prm = EvansParams(
            n=EVANS_SAMPLES, base=fixed["base_voxels"] * sdf.voxel, k=1.0, alpha=fixed["alpha"], up=up
        )
        terms = evans_terms(points, normals, sdf, prm)
        methods[rid] = evans_on_terms(methods[rid])
        row_inputs[rid] = ({f"d{i + 1}": terms[i] for i in range(EVANS_SAMPLES)},)
    # The curvature and Evans k are per scene unit (declared for the sdf-occlusion scenes, R = 1 m): scaled by
    # 1/R so that k·s stays of order one in any unit (the Cornell box's millimetre-sized units gave
    # e^(10·s) ~ 1e34 at the declared start, which no fit recovered from).
    per_unit = {}
    for rid in ("curvature", *EVANS_ROWS):
        if rid in methods:
            k = METHODS[rid].params["k"]
            per_unit[rid] = {
                "k": replace(k, initial=k.initial / radius, lower=k.lower / radius, upper=k.upper / radius)
            }
    notes = _bound_to_unit_range(methods, per_unit, inputs["distance"], row_inputs)
    return DistanceFieldRows(sdf, sign, shapes, inputs, methods, row_inputs, per_unit, notes)


def _bound_to_unit_range(methods: dict, params: dict, distance, row_inputs: dict) -> tuple[str, ...]:
    """Bound the fits of the curvature and Evans rows so that each stays in [0, 1] (it approximates AO, a
    visibility) on these pixels, or leave the row out saying why; edits ``methods`` and ``params`` in place.

    The seed clamps neither formula: Evans' C = e^{k Σ SDF(P + d_i N) + d_i} (000:2946; Listing 1,
    000:2982-2987, returns exp(…)·GlobalBrightness) and the crease term 0.5 + exp(k·S) (000:2902) are
    written without saturate, and the seed's claim that the samples make the exponent ≤ 0 (000:2929-2931)
    fails for its own unnormalised bent normal N + αU (a sample lies d_i·|N'| > d_i away). So the bounds are
    the fit's, from each row's terms on this scene: with m = min over pixels of Σ_i w_i D_i,

    * evans-listing: C = b·exp(−k (Σ w_i D_i − m)) with log b ∈ [−5, 0], i.e. Listing 1's brightness
      B = b·e^{k·m} bounded by the scene's least occluded pixel: 0 < C ≤ 1 (the kernel gets log B);
    * evans-text (B = 1 in the text): in range for every k ≥ 0 when m ≥ 0; for m < 0 no darkening k is,
      so the row is left out;
    * curvature ((0.5 + e^{k·S})/1.5, S = −s): k·S ≤ 0 on every pixel bounds k to one sign when S keeps
      one sign; when it takes both, only k = 0 is in range and the row is left out."""
    notes = []
    for rid in EVANS_ROWS:
        if rid not in methods:
            continue
        weights = methods[rid].fixed["weights"] or (1.0,) * EVANS_SAMPLES
        terms = row_inputs[rid][0]
        m = float(np.min(sum(w * terms[f"d{i + 1}"] for i, w in enumerate(weights))))
        if m >= 0:
            if "logB" in methods[rid].params:
                params[rid]["logB"] = replace(methods[rid].params["logB"], initial=-0.05, upper=0.0)
            continue
        if rid == "evans-text":
            del methods[rid], params[rid], row_inputs[rid]
            notes.append(
                f"evans-text: left out: its unnormalised bent normal gives Σ D_i = {m:.4g} < 0 at the least "
                "occluded pixel, where C = e^(−k Σ D_i) > 1 for every darkening k > 0 (the seed has no "
                "clamp)"
            )
            continue
        methods[rid] = _relative_brightness(methods[rid], m)
        params[rid]["logB"] = replace(
            methods[rid].params["logB"],
            initial=-0.05,
            upper=0.0,
            description=f"log b, B = b·e^(k·m) with m = {m:.4g} = min Σ w_i D_i here (b ≤ 1: C ≤ 1)",
        )
        notes.append(
            f"evans-listing: brightness B = b·e^(k·m), m = {m:.4g} the least occluded pixel's Σ w_i D_i, "
            "b ≤ 1, so that C ≤ 1 (the seed does not clamp)"
        )
    if "curvature" in methods:
        s_text = -np.asarray(distance, np.float64)
        k = params["curvature"]["k"]
        if np.max(s_text) <= 0:
            params["curvature"]["k"] = replace(k, initial=abs(k.initial), lower=0.0)
        elif np.min(s_text) >= 0:
            params["curvature"]["k"] = replace(k, initial=-abs(k.initial), upper=0.0)
        else:
            del methods["curvature"], params["curvature"]
            notes.append(
                f"curvature: left out: S = −s₁ spans [{np.min(s_text):.3g}, {np.max(s_text):.3g}] here, so "
                "(0.5 + e^(k·S))/1.5 exceeds 1 somewhere for every k ≠ 0 (the seed does not clamp)"
            )
    return tuple(notes)


def _relative_brightness(method: Method, m: float) -> Method:
    """The Evans listing row with its ``logB`` read as log b, log B = log b + k·m (`_bound_to_unit_range`)."""
    base = method.kernel

    def kernel(ops, *args, logB, k, **kw):
        return base(ops, *args, logB=logB + k * m, k=k, **kw)

    return replace(method, kernel=kernel, formula=f"{method.formula}; B = b·e^(k·m), m = {m:.4g}")


def ao_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case: the ray-cast AO of the visible points against the distance-field rows (module docstring)."""
    if app.role != ROLE:
        raise AuditError(f"sdf-occlusion: the {app.role} role is not audited here")
    radius = ao_radius(setup)
    mask = setup.mask
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    ao = ao_reference(setup, points, normals, radius, f"ao: {app.part}")
    rows = distance_field_rows(setup, app.methods, points, normals, radius)
    ref = ao.reference(
        mask,
        quantity=f"ambient occlusion within R = {radius:.4g} (1: unoccluded)",
        integrator=f"occlusion pass (cosine-distributed rays of length R = {radius:.4g})",
        integrator_reason="V_R(ω) with ω ~ cos/π is the cheapest exact estimator of cosine-weighted AO",
    )
    return [
        FamilyCase(
            id="ao",
            label=f"{app.part}: ambient occlusion within R = {radius:.4g}",
            reference=ref,
            mask=mask,
            channel_inputs=(rows.inputs,) * 3,
            parameters={"ao_distance": float(radius), **rows.parameters, "pixels": int(mask.sum())},
            units="1",
            notes=rows.notes,
            methods=rows.methods,
            quantity="ambient_occlusion",
            params=rows.params,
            row_inputs={rid: v * 3 for rid, v in rows.row_inputs.items()},
        )
    ]


FAMILY = AuditFamily(
    name="sdf-occlusion",
    quantity="ambient_occlusion",
    cases=ao_cases,
    quantities=("crease_darkening",),
    formats=("mitsuba-xml", "rtfit-toml"),
    describe=(
        "Ambient occlusion A = (1/π)∫ V_R (n·ω) dω within the radius R at each visible point, by Mitsuba ray "
        "casts (cosine-distributed rays of length R against the scene's own shapes) in independent passes "
        "with per-pixel standard errors. The rows read a distance field baked from the scene's own "
        "triangles (Mitsuba's mesh buffers; spheres, disks and cylinders tessellated): cone-traced AO and "
        "Evans' curvature term, each with its free parameter fitted to this scene."
    ),
    rules=(
        Rule(
            "sdf-occlusion",
            "ambient occlusion",
            ("geometry",),
            "{part} occludes itself",
            "ray-cast ambient occlusion within R = {ao_distance} (cosine-weighted visibility)",
            "occlusion pass: cosine-distributed rays of length R from the visible points",
        ),
    ),
)
