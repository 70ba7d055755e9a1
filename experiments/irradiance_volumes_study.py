"""The study of ``rtfit run irradiance-volumes`` (issue 30 §1): what only an irradiance volume has, read from
the engine's audits of the shipped room (`audit_irradiance_volumes.SCENES`, one probe grid each).

* **Error vs probe spacing**: each row's RMSE (W/m²) against the path-traced irradiance at the visible
  points, per grid spacing h, with the reference's noise floor.
* **Popping**: along a line through the room at the middle of the box (y, z at the box's centre), the
  looked-up irradiance at pairs of points ± `BOUNDARY_EPS` around each x cell boundary of the grid (the
  nearest lookup's switch points); the step over the mean there. The trilinear lookup is continuous (its
  step → 0 with ε), the nearest lookup jumps by the difference of two probes.
* **Storage per probe**: each basis's floats per probe (RGB × coefficients: 6 axes for a cube, 9 for SH L2)
  and the bytes of each grid's float32 table.

* **Leak per surface group** (`surface_groups`): each row's sMAPE over the pixels of each surface of the
  room (floor, ceiling, the four walls, the occluder's lit −x face, its shadowed +x face, its other faces),
  for the bounced (``volume``) and the total (``volume-total``) case: where the volume's error sits — light
  leaking through the thin occluder once a probe on its lit side is the nearest.
* **Light folded vs exact direct + volume** (``volume-total``): per spacing, each folded row's RMSE and sMAPE
  beside its ``direct-…`` row's.

Checks (independent values): storage per probe is 3 × 6 (cubes) and 3 × 9 (SH L2) floats; the trilinear
lookup's step at every boundary is below `CONTINUITY_TOL` of the irradiance there (continuity); and the old
experiment's self-checks (`self_checks`):

* **white furnace** (no geometry, a constant environment of radiance 1, rendered here: `FURNACE_SPP`
  directions at 3 probes): the probes' projections equal their closed forms, SH √(4π)·δ_k0 and the
  irradiance π at every normal, within their noise (Šidák, α = 0.01); the noiseless SH DC exactly;
* **constant volume**: identical exact constant probes (π in every cube entry, SH of L = 1) give π at every
  point and normal, inside, on and outside the grid, for every lookup × basis (float32 kernel);
* **direct light**: the ``direct_r/g/b`` the ``direct-…`` rows read (Mitsuba's emitter sample and shadow ray)
  equal I·max(n·d, 0)/r² with an analytic slab test of the occluder box, read from the scene file;
* **two estimators**: at the coarsest grid's nodes × the six axes, the probes' uniform-sphere projection and
  the surface estimator's cosine-sampled paths (`irradiance_pass`, ``global``), rendered here
  (`ESTIMATOR_SPP`), agree within their noise (Šidák) with unit-spread z-scores;
* **the lookups at the nodes** return each node's own probe (the basis's NumPy text in float64);
* every row's image is finite; the bounced reference is resolved (mean relative standard error).
"""

from __future__ import annotations

import math

import numpy as np

from rtfit.fitting import robust_spread, sidak_threshold, smape
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.irradiance_bases import CUBE_AXES, sh9_from_constant
from rtfit.realtime.irradiance_volumes import (
    METHODS,
    ProbeGrid,
    probe_table,
    volume_inputs,
    volume_irradiance,
)
from rtfit.reference import load_mitsuba_scene
from rtfit.reference.estimators import irradiance_pass
from rtfit.reference.probe_radiance import probe_radiance_pass
from rtfit.scenes import library_path, load_scene
from rtfit.scenes.model import ConstantEnv, Cube, PointLight, ReferenceSettings, Scene

from .probe_projection import probe_features
from .records import Check, Headline, Section
from .shipped import Study, StudyContext

__all__ = [
    "BOUNDARY_EPS",
    "CONTINUITY_TOL",
    "ESTIMATOR_SPP",
    "FURNACE_SPP",
    "direct_closed_form",
    "furnace_checks",
    "popping",
    "self_checks",
    "study",
    "surface_groups",
]

BOUNDARY_EPS = 1e-4
"""Half-distance (m) of the point pairs straddling each cell boundary."""
CONTINUITY_TOL = 1e-2
"""Largest relative step of a trilinear lookup across a boundary at ±`BOUNDARY_EPS` (it is ~ε/h · slope)."""
COEFFICIENTS = {"cube-valve": 6, "cube-nnls": 6, "sh-l2": 9}
"""Coefficients per colour channel of each basis (six axes; SH bands 0–2: 1 + 3 + 5)."""
FURNACE_SPP = {True: 1024, False: 8192}
"""Directions per probe of the white furnace (``--quick``: True)."""
ESTIMATOR_SPP = {True: (4096, 1024), False: (16384, 4096)}
"""(directions per probe, cosine paths per point) of the two-estimator check (``--quick``: True)."""
RESOLVED_TOL = 0.1
RESOLVED_SPP = 256
"""The bounced reference's mean relative standard error over the pixels is at most `RESOLVED_TOL` at
`RESOLVED_SPP` samples (the old experiment's bound at its 256 samples per point; the full run's spp), and
`RESOLVED_TOL`·√(`RESOLVED_SPP`/spp) at fewer (``--quick``: 64 spp, 0.2): the same per-sample spread."""
ROOM = "volume_room"
"""The shipped scene file whose light and occluder the direct-light check and the surface groups read."""


def _volume(audit):
    case = audit.cases[0]
    grid = next(iter(case.methods.values())).fixed["grid"]
    return case, grid


def popping(grid, tables: dict, normal=(0.0, 0.0, 1.0)) -> dict[str, float]:
    """Largest relative step of each row's lookup across ``grid``'s x cell boundaries (module docstring)."""
    lo = np.asarray(grid.origin, np.float64)
    mid = lo + 0.5 * (np.asarray(grid.dims, np.float64) - 1.0) * grid.spacing
    xs = [b + s * BOUNDARY_EPS for b in grid.boundaries(0) for s in (-1.0, 1.0)]
    if not xs:
        return {mid_: 0.0 for mid_ in METHODS}
    pts = np.tile(mid, (len(xs), 1))
    pts[:, 0] = xs
    nrm = np.tile(np.asarray(normal, np.float64), (len(xs), 1))
    out = {}
    for mid_, m in METHODS.items():
        e = volume_irradiance(mid_, grid, tables[m.fixed["basis"].id], pts, nrm).mean(axis=1)
        a, b = e[0::2], e[1::2]
        out[mid_] = float(np.max(np.abs(b - a) / np.maximum(0.5 * np.abs(a + b), 1e-12)))
    return out


# ================================================================================== surface groups
def _occluder(room: Scene) -> tuple[np.ndarray, np.ndarray]:
    (box,) = [s for s in room.shapes if isinstance(s, Cube)]
    c, h = np.asarray(box.center, np.float64), 0.5 * np.asarray(box.size, np.float64)
    return c - h, c + h


def surface_groups(room: Scene, points: np.ndarray, normals: np.ndarray, tol: float = 2e-3) -> dict:
    """{group: mask over the points} of the room's surfaces (module docstring) by where each point lies and
    which way its normal faces (the room is [−2, 2]² × [0, 2.5], the occluder an axis-aligned box)."""
    lo, hi = _occluder(room)
    p, n = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    on_box = np.all((p >= lo - tol) & (p <= hi + tol), axis=1)
    x, y, z = p.T
    groups = {
        "occluder, lit −x face": on_box & (np.abs(x - lo[0]) < tol) & (n[:, 0] < -0.9),
        "occluder, shadow +x face": on_box & (np.abs(x - hi[0]) < tol) & (n[:, 0] > 0.9),
    }
    groups["occluder, other faces"] = (
        on_box & ~groups["occluder, lit −x face"] & ~groups["occluder, shadow +x face"]
    )
    rest = ~on_box
    groups.update(
        {
            "floor": rest & (np.abs(z) < tol),
            "ceiling": rest & (np.abs(z - 2.5) < tol),
            "red −x wall": rest & (np.abs(x + 2.0) < tol),
            "green +x wall": rest & (np.abs(x - 2.0) < tol),
            "−y wall": rest & (np.abs(y + 2.0) < tol),
            "+y wall": rest & (np.abs(y - 2.0) < tol),
        }
    )
    return {k: v for k, v in groups.items() if v.any()}


def _geometry(case) -> tuple[np.ndarray, np.ndarray]:
    g = case.channel_inputs[0]
    return (
        np.stack([g[f"p{c}"] for c in "xyz"], 1).astype(np.float64),
        np.stack([g[f"n{c}"] for c in "xyz"], 1).astype(np.float64),
    )


def group_smape(audit, case, groups: dict) -> dict[str, dict[str, float]]:
    """Row → {group: sMAPE over its pixels} (`rtfit.fitting.smape` against the case's reference)."""
    mean, se = case.reference.mean[case.mask], case.reference.stderr[case.mask]
    out = {}
    for row, o in audit.outcomes[case.id].items():
        img = o.image[case.mask]
        out[row] = {g: float(smape(img, mean, se, m).value) for g, m in groups.items()}
    return out


# ===================================================================================== self-checks
def direct_closed_form(room: Scene, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """I·max(n·d, 0)/r² (N, 3) of the room's point light(s) at ``points``, zero where the open segment to the
    light crosses the occluder box (slab test, float64): the closed form of the direct light."""
    lo, hi = _occluder(room)
    out = np.zeros((len(points), 3))
    for light in (x for x in room.lights if isinstance(x, PointLight)):
        q = np.asarray(light.position, np.float64)
        dvec = q[None] - points
        r2 = np.einsum("ij,ij->i", dvec, dvec)
        cos = np.maximum(np.einsum("ij,ij->i", normals, dvec) / np.sqrt(r2), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (lo[None] - points) / dvec, (hi[None] - points) / dvec
        tmin = np.max(np.where(dvec != 0, np.minimum(t0, t1), -np.inf), axis=1)
        tmax = np.min(np.where(dvec != 0, np.maximum(t0, t1), np.inf), axis=1)
        slabs = np.all((dvec != 0) | ((points >= lo) & (points <= hi)), axis=1)
        blocked = slabs & (tmax >= np.maximum(tmin, 1e-6)) & (tmin <= 1.0 - 1e-6)
        out += (cos / r2 * ~blocked)[:, None] * np.asarray(light.intensity, np.float64)[None]
    return out


def _lookups(grid: ProbeGrid, tables: dict, points, normals) -> dict[str, np.ndarray]:
    """Every row's irradiance (N, 3): its kernel text on float32 NumPy arrays (the shader's precision; NumPy,
    not Dr.Jit: a Dr.Jit kernel build per row and call costs seconds on 2 shared cores)."""
    p32, n32 = np.asarray(points, np.float32), np.asarray(normals, np.float32)
    out = {}
    for mid, m in METHODS.items():
        table = np.asarray(tables[m.fixed["basis"].id], np.float32)
        with np.errstate(all="ignore"):  # NumPy evaluates both branches of every select
            values = m(NUMPY_OPS, volume_inputs(m, grid, table, p32, n32))
        out[mid] = np.stack([np.asarray(v, np.float64) for v in values], axis=-1)
    return out


def furnace_checks(ctx: StudyContext, room: Scene, grid: ProbeGrid) -> list[Check]:
    """The white furnace (rendered: no geometry, constant environment of radiance 1) and the constant
    volume (no render): module docstring."""
    furnace = Scene(
        name="volume-furnace",
        camera=room.camera,
        lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),),
        reference=ReferenceSettings(transport="direct"),
    )
    mi, scene = load_mitsuba_scene(furnace, ctx.variant)
    at = np.array([[0.0, 0.0, 0.0], [0.3, -0.7, 1.1], [-1.2, 0.4, 2.0]])
    r = probe_radiance_pass(mi, scene, at, probe_features, FURNACE_SPP[ctx.quick], ctx.seed + 17)
    fs = np.sqrt(r.var / r.spp)
    exact = np.zeros(r.mean.shape[1])
    exact[0], exact[9:] = math.sqrt(4.0 * math.pi), math.pi
    diff = r.mean - exact[None, :, None]
    noisy = fs > 0
    z = np.abs(diff[noisy] / fs[noisy])
    zmax = sidak_threshold(int(noisy.sum()))
    dc = float(np.max(np.abs(diff[~noisy]) / math.sqrt(4 * math.pi))) if (~noisy).any() else 0.0
    rng = np.random.default_rng(5)
    p = rng.uniform(-3.0, 3.0, (4096, 3))
    nodes = grid.positions()[:64]
    p[: len(nodes)] = nodes  # on the nodes, then on cell centres (the boundaries of the nearest lookup)
    p[64 : 64 + len(nodes)] = nodes + 0.5 * grid.spacing
    n = rng.normal(size=(4096, 3))
    const = {
        "sh-l2": np.tile(sh9_from_constant(1.0)[None], (grid.count, 1, 1)),
        "cube-valve": np.full((grid.count, 6, 3), math.pi),
        "cube-nnls": np.full((grid.count, 6, 3), math.pi),
    }
    tables = {b: probe_table(c) for b, c in const.items()}
    worst = max(float(np.max(np.abs(v / math.pi - 1.0))) for v in _lookups(grid, tables, p, n).values())
    return [
        Check.at_most(
            f"white furnace: probe projections (SH, irradiance at {r.mean.shape[1] - 9} normals) = closed "
            f"forms within noise ({r.spp} directions × 3 probes)",
            float(z.max()),
            zmax,
            fmt=".2f",
            quantity="max |z|",
            note=f"(Šidák, α = 0.01, n = {int(noisy.sum())})",
        ),
        Check.at_most("white furnace: the noiseless SH DC projection is exact", dc, "1e-6", note="relative"),
        Check.at_most(
            "constant environment: every lookup × basis of identical exact probes returns π (float32)",
            worst,
            "2e-6",
            note="relative",
        ),
    ]


def estimator_checks(ctx: StudyContext, room: Scene, grid: ProbeGrid) -> list[Check]:
    """Two independent estimators of the bounced irradiance at ``grid``'s nodes × the six axes (rendered
    here): the probes' uniform-sphere projection on the clamped cosines of the axes, and the surface
    estimator's cosine-sampled paths (module docstring)."""
    mi, scene = load_mitsuba_scene(room, ctx.variant)
    nodes = grid.positions()
    probe_spp, surface_spp = ESTIMATOR_SPP[ctx.quick]
    pr = probe_radiance_pass(mi, scene, nodes, probe_features, probe_spp, ctx.seed + 23)
    pm, ps = pr.mean[:, 9:15], np.sqrt(pr.var[:, 9:15] / pr.spp)
    pts, nrm = np.repeat(nodes, 6, axis=0), np.tile(np.asarray(CUBE_AXES, np.float64), (len(nodes), 1))
    sr = irradiance_pass(mi, scene, pts, nrm, surface_spp, ctx.seed + 29, transport="global")
    sm, ss = sr.mean.reshape(len(nodes), 6, 3), np.sqrt(sr.var / sr.spp).reshape(len(nodes), 6, 3)
    zz = ((pm - sm) / np.sqrt(ps**2 + ss**2 + 1e-30)).ravel()
    zlim, spread = sidak_threshold(zz.size), robust_spread(zz)
    what = f"{grid.count} nodes × 6 axes, {probe_spp} directions / {surface_spp} paths"
    return [
        Check.at_most(
            f"probe projection (uniform sphere) = surface estimator (cosine paths), {what}",
            float(np.abs(zz).max()),
            zlim,
            fmt=".2f",
            quantity="max |z|",
            note=f"(Šidák, α = 0.01, n = {zz.size})",
        ),
        Check(
            "  … and the z-scores have unit spread",
            spread,
            "robust spread in [0.6, 1.5]",
            bool(0.6 <= spread <= 1.5),
        ),
    ]


def self_checks(ctx: StudyContext, room: Scene) -> list[Check]:
    """The old experiment's self-checks (module docstring) on the engine's audits of the room."""
    grids = [_volume(a)[1] for a in ctx.audits]
    coarse = min(grids, key=lambda g: g.count)
    checks = furnace_checks(ctx, room, coarse) + estimator_checks(ctx, room, coarse)
    agree, worst, finite, rel_se, spp_ = [], 0.0, True, [], []
    rng = np.random.default_rng(11)
    for audit in ctx.audits:
        case, grid = _volume(audit)
        tables = {m.fixed["basis"].id: case.row_inputs[mid][0]["table"] for mid, m in METHODS.items()}
        normals = rng.normal(size=(grid.count, 3))
        for mid, v in _lookups(grid, tables, grid.positions(), normals).items():
            basis = METHODS[mid].fixed["basis"]
            stored = np.asarray(tables[basis.id], np.float32).reshape(-1, grid.count)  # (floats, probes)
            n32 = normals.astype(np.float32)
            own = np.stack(
                basis(NUMPY_OPS, {"nx": n32[:, 0], "ny": n32[:, 1], "nz": n32[:, 2], "coeffs": list(stored)}),
                axis=-1,
            ).astype(np.float64)  # each node's own probe, the basis's text in float32 as the lookup's
            worst = max(worst, float(np.max(np.abs(v - own) / (np.abs(own) + 1e-3 * np.abs(own).max()))))
        for c in audit.cases:
            finite &= all(bool(np.all(np.isfinite(o.image))) for o in audit.outcomes[c.id].values())
            if "direct-trilinear-sh-l2" in c.row_inputs:
                pts, nrm = _geometry(c)
                got = np.stack([c.row_inputs["direct-trilinear-sh-l2"][0][f"direct_{k}"] for k in "rgb"], 1)
                closed = direct_closed_form(room, pts, nrm)
                rel = np.abs(got - closed) / np.maximum(np.abs(closed), 1e-3 * float(np.max(closed)))
                agree.append(np.all(rel <= 1e-4, axis=1))
        ref = case.reference
        rel_se.append(float(np.mean(ref.stderr[case.mask] / np.maximum(ref.mean[case.mask], 1e-12))))
        spp_.append(ref.spp)
    if agree:
        share = float(np.mean(np.concatenate(agree)))
        checks.append(
            Check.at_least(
                "direct light of the direct-… rows = I·max(n·d, 0)/r² × analytic occluder shadow "
                "(pixels off shadow edges)",
                share,
                "0.99",
                note="of the pixels within 1e-4 relative",
            )
        )
    checks.append(
        Check.at_most(
            "nearest and trilinear lookups at the nodes return the node's own probe",
            worst,
            "1e-5",
            note="relative (the same float32 basis text: only the lookup's node and weights differ)",
        )
    )
    checks.append(Check.holds("every row's image is finite", finite))
    spp = min(spp_)
    tol = RESOLVED_TOL * math.sqrt(max(RESOLVED_SPP / spp, 1.0))
    se = max(rel_se)
    checks.append(
        Check.at_most(
            f"bounced reference resolved (mean relative standard error over the pixels, {spp} spp)",
            se,
            tol,
            fmt=".3g",
            note=f"({RESOLVED_TOL:g} at {RESOLVED_SPP} spp, × √({RESOLVED_SPP}/spp) below)",
        )
    )
    return checks


def study(ctx: StudyContext) -> Study:
    """The irradiance-volumes study (module docstring), from the engine's audits of its shipped grids."""
    rows, checks = [], []
    for audit in ctx.audits:
        case, grid = _volume(audit)
        tables = {m.fixed["basis"].id: case.row_inputs[mid][0]["table"] for mid, m in METHODS.items()}
        outcomes = audit.outcomes[case.id]
        pops = popping(grid, tables)
        for mid, m in METHODS.items():
            rmse = outcomes[mid].metrics["rmse"]
            rows.append(
                {
                    "spacing_m": grid.spacing,
                    "probes": grid.count,
                    "row": mid,
                    "rmse": float(rmse.value),
                    "noise_floor": float(rmse.noise_floor),
                    "popping_max_step": pops[mid],
                    "floats_per_probe": int(m.storage or 0),
                    "table_bytes": 4 * int(m.storage or 0) * grid.count,
                }
            )
            if m.fixed["lookup"].startswith("trilinear"):
                checks.append(
                    Check.below(
                        f"trilinear lookup continuous at h = {grid.spacing:g} m ({mid}): largest step at "
                        f"a cell boundary (±{BOUNDARY_EPS:g} m)",
                        pops[mid],
                        CONTINUITY_TOL,
                        fmt="g",
                    )
                )
    for mid, m in METHODS.items():
        want = 3 * COEFFICIENTS[m.fixed["basis"].id]
        checks.append(
            Check(
                f"storage of {mid}: floats per probe",
                m.storage,
                f"= 3 × coefficients = {want}",
                m.storage == want,
            )
        )
    head = (
        "| h (m) | probes | row | RMSE (W/m²) | noise floor | popping (max step) | floats/probe "
        "| table (bytes) |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    lines += [
        f"| {r['spacing_m']:g} | {r['probes']} | {r['row']} | {r['rmse']:.4g} | {r['noise_floor']:.4g} | "
        f"{r['popping_max_step']:.3g} | {r['floats_per_probe']} | {r['table_bytes']} |"
        for r in rows
    ]
    text = (
        "Each row's error against the path-traced irradiance at the visible points per probe spacing; the "
        "popping step: the largest change of the looked-up irradiance across an x cell boundary "
        f"(±{BOUNDARY_EPS:g} m, along the box's centre line, normal +z) over its mean; storage: float32 RGB "
        "coefficients.\n\n" + "\n".join(lines)
    )
    room = load_scene(library_path(ROOM))
    leak, split = _leak_and_split(ctx, room)
    checks += self_checks(ctx, room)
    headline = [
        Headline(
            label=f"h = {r['spacing_m']:g} m, {r['row']} folded vs exact direct + volume: sMAPE",
            value=f"{r['smape']:.3f} vs {r['direct_smape']:.3f}",
        )
        for r in split
        if r["row"] == "trilinear-sh-l2"
    ]
    return Study(
        sections=(
            Section(id="study-irradiance-volumes", title="Probe spacing, popping, storage", text=text),
            Section(
                id="study-irradiance-volumes-split",
                title="Light folded vs exact direct + volume",
                text=_split_text(split),
            ),
            Section(
                id="study-irradiance-volumes-leak",
                title="Error per surface group (leaking)",
                text=_leak_text(leak),
            ),
        ),
        checks=tuple(checks),
        headline=tuple(headline),
        extra={"per_spacing": rows, "folded_vs_direct": split, "group_smape": leak},
    )


def _leak_and_split(ctx: StudyContext, room: Scene) -> tuple[list[dict], list[dict]]:
    """Per audit and case: each row's sMAPE per surface group (`group_smape`); and for ``volume-total``,
    each folded row's RMSE and sMAPE beside its ``direct-…`` row's."""
    leak, split = [], []
    for audit in ctx.audits:
        grid = _volume(audit)[1]
        for case in audit.cases:
            groups = surface_groups(room, *_geometry(case))
            kind = "total" if any(r.startswith("direct-") for r in audit.outcomes[case.id]) else "bounced"
            for row, per in group_smape(audit, case, groups).items():
                leak.append(
                    {
                        "spacing_m": grid.spacing,
                        "case": kind,
                        "row": row,
                        **per,
                        "pixels": {g: int(m.sum()) for g, m in groups.items()},
                    }
                )
            if kind != "total":
                continue
            out = audit.outcomes[case.id]
            mean, se = case.reference.mean, case.reference.stderr
            for mid in METHODS:
                a, b = out[mid], out[f"direct-{mid}"]
                split.append(
                    {
                        "spacing_m": grid.spacing,
                        "row": mid,
                        "rmse": float(a.metrics["rmse"].value),
                        "direct_rmse": float(b.metrics["rmse"].value),
                        "smape": float(smape(a.image, mean, se, case.mask).value),
                        "direct_smape": float(smape(b.image, mean, se, case.mask).value),
                    }
                )
    return leak, split


def _split_text(split: list[dict]) -> str:
    if not split:
        return "No audited scene has a delta light: nothing to fold."
    lines = [
        "| h (m) | row | folded: RMSE (W/m²) | sMAPE | exact direct + volume: RMSE | sMAPE |",
        "|---|---|---|---|---|---|",
    ]
    cells = "{spacing_m:g} | {row} | {rmse:.4g} | {smape:.3f} | {direct_rmse:.4g} | {direct_smape:.3f}"
    lines += ["| " + cells.format(**r) + " |" for r in split]
    return (
        "Total irradiance (the point light's direct light + the bounced light): the light folded into every "
        "probe as a distant light from its direction there (seed 7.4.3), against the usual split, the exact "
        "direct light per pixel plus the unfolded volume (whose RMSE is the bounced case's: the direct part "
        "is exact on both sides).\n\n" + "\n".join(lines)
    )


def _leak_text(leak: list[dict]) -> str:
    if not leak:
        return "No pixels."
    groups = list(leak[0]["pixels"])
    head = "| h (m) | case | row | " + " | ".join(f"{g} ({leak[0]['pixels'][g]} px)" for g in groups) + " |"
    lines = [head, "|" + "---|" * (3 + len(groups))]
    for r in leak:
        cells = [
            f"{r['spacing_m']:g}",
            r["case"],
            r["row"],
            *(f"{r[g]:.3f}" if g in r else "–" for g in groups),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return (
        "sMAPE |a − r|/(|a| + |r|) of each row over the pixels of each surface of the room: where the "
        "volume's error sits. A probe on the occluder's lit side that is nearest to a pixel of its shadowed "
        "side leaks the light through the thin wall.\n\n" + "\n".join(lines)
    )
