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

Checks (independent values): storage per probe is 3 × 6 (cubes) and 3 × 9 (SH L2) floats; the trilinear
lookup's step at every boundary is below `CONTINUITY_TOL` of the irradiance there (continuity).
"""

from __future__ import annotations

import numpy as np

from rtfit.realtime.irradiance_volumes import METHODS, volume_irradiance

from .audit_family import Study, StudyContext
from .records import Check, Section

__all__ = ["BOUNDARY_EPS", "CONTINUITY_TOL", "popping", "study"]

BOUNDARY_EPS = 1e-4
"""Half-distance (m) of the point pairs straddling each cell boundary."""
CONTINUITY_TOL = 1e-2
"""Largest relative step of a trilinear lookup across a boundary at ±`BOUNDARY_EPS` (it is ~ε/h · slope)."""
COEFFICIENTS = {"cube-valve": 6, "cube-nnls": 6, "sh-l2": 9}
"""Coefficients per colour channel of each basis (six axes; SH bands 0–2: 1 + 3 + 5)."""


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
                    Check(
                        f"trilinear lookup continuous at h = {grid.spacing:g} m ({mid}): largest step at "
                        f"a cell boundary (±{BOUNDARY_EPS:g} m)",
                        pops[mid],
                        f"< {CONTINUITY_TOL:g}",
                        pops[mid] < CONTINUITY_TOL,
                    )
                )
    for mid, m in METHODS.items():
        want = 3 * COEFFICIENTS[m.fixed["basis"].id]
        checks.append(Check(f"storage of {mid}: floats per probe", m.storage, f"= 3 × coefficients = {want}",
                            m.storage == want))  # fmt: skip
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
    return Study(
        sections=(
            Section(id="study-irradiance-volumes", title="Probe spacing, popping, storage", text=text),
        ),
        checks=tuple(checks),
        extra={"per_spacing": rows},
    )
