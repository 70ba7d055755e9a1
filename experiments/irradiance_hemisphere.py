"""The hemisphere (lightmap) section of ``irradiance-bases``: H-basis and radiosity normal mapping.

A lightmap texel sees bumped normals only in the upper hemisphere of its surface frame. For each
environment and each surface frame of `FRAMES` (z up, and one tilted frame) this section bakes, as an
engine's lightmapper would, the hemispherical bases of `rtfit.realtime.hemisphere_bases`:

* ``hbasis-4``, ``hbasis-6``: the projection c_k = ∫_{Ω+} E(n) H_k(n) dn of the irradiance over the
  hemisphere of normals (Gauss–Legendre × uniform-φ rule, `BAKE_RULE`, irradiance by the experiment's
  dense quadrature of the environment);
* ``rnm-linear``, ``rnm-squared``, ``rnm-normalized``: the three lightmaps E(b_i) at Valve's tangent-space
  basis directions (the same quadrature), reconstructed with the three weightings;

and compares them, with SH L1/L2 of the whole-sphere probe evaluated at the same normals (what a probe
would give the texel), against the reference the caller passes at its Fibonacci normals that lie in the
frame's upper hemisphere (n·N > 0): since the family runs on the audit engine
(`irradiance_bases_study`), the dense quadrature of the environment (noise floor 0; the engine's exact row
validates it against Mitsuba), so the section adds no Mitsuba pass. (The engine's own lightmap case,
`audit_lightmap_bases`, evaluates these rows at each visible texel's own normal against Mitsuba.)

The truth is the unoccluded irradiance of the distant environment at n (the quantity of the rest of the
experiment): light from below the surface plane reaches a tilted bumped normal. A lightmapper on a real
plane would block it (the surface's own occlusion), which this section leaves out so that every row
approximates one function of n.

This module never imports the study (it receives the metric function and the baked SH).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.hemisphere_bases import (
    HEMISPHERE_METHODS,
    RNM_BASIS,
    hbasis_project,
    hemisphere_irradiance,
    hemisphere_quadrature,
    surface_frame,
    to_tangent,
)
from rtfit.realtime.irradiance_bases import METHODS, basis_inputs, basis_irradiance
from rtfit.reference import environments as envs

from . import fitted as fitfiles
from .records import Check

_TILT = math.radians(60.0)
_AZ = math.radians(30.0)
FRAMES = (
    ("up", (0.0, 0.0, 1.0)),
    ("tilted-60", (math.sin(_TILT) * math.cos(_AZ), math.sin(_TILT) * math.sin(_AZ), math.cos(_TILT))),
)
"""Surface frames: name → geometric normal N (world); the tangent is world +X made orthogonal to N."""
BAKE_RULE = {True: (8, 16), False: (16, 32)}
"""Hemisphere rule of the H-basis bake by ``quick``: Gauss–Legendre nodes in cos θ × midpoints in φ (128 /
512 normals). Measured against a 32 × 64 rule (quick run's environments): the largest coefficient change is
1.4e-3 of c1 at 8 × 16 (a lone 0.27° sun, z up; ≤ 8e-4 elsewhere), 2.4e-4 at 16 × 32, an order of
magnitude below the smallest resolved H-basis error (1.3e-2, overcast)."""
HEMI_ROWS = (
    "hbasis-4",
    "hbasis-6",
    "rnm-linear",
    "rnm-squared",
    "rnm-normalized",
    "sh-l1",
    "sh-l2",
    "quadrature",
)
"""The rows of the section: the hemispherical bases, SH L1/L2 of the sphere probe, and the exact row."""
EXACT_ON_CONSTANT = ("hbasis-4", "hbasis-6", "rnm-normalized", "sh-l1", "sh-l2", "quadrature")
"""Rows that reproduce a constant environment exactly at every normal of the hemisphere."""


def _spec(method: str):
    return HEMISPHERE_METHODS[method] if method in HEMISPHERE_METHODS else METHODS[method]


def bake_frame(
    frame: np.ndarray,
    irradiance_at: Callable[[np.ndarray], np.ndarray],
    rule: tuple[int, int] = BAKE_RULE[False],
) -> dict:
    """The lightmap texel of ``env`` in ``frame`` (rows t, b, N): H-basis coefficients (6, 3) (the first 4
    rows are the 4-term projection: the basis is orthonormal) and the RNM lightmaps (3, 3).
    ``irradiance_at(world_normals (M, 3)) → (M, 3)`` is the environment's dense quadrature; ``rule`` the
    hemisphere rule of the projection (`BAKE_RULE`)."""
    dirs_t, weights = hemisphere_quadrature(*rule)
    e = irradiance_at(dirs_t @ frame)  # tangent → world: rows of the frame are t, b, N
    h6 = hbasis_project(dirs_t, weights, e, 6)
    rnm = np.asarray(irradiance_at(np.asarray(RNM_BASIS) @ frame), np.float64)
    return {"hbasis-4": h6[:4], "hbasis-6": h6, "rnm": rnm}


def evaluate_rows(texel: dict, sh: np.ndarray, normals_world, frame, quadrature) -> dict[str, np.ndarray]:
    """Irradiance (M, 3) of every row of `HEMI_ROWS` at ``normals_world`` (M, 3) in the upper hemisphere
    of ``frame``; ``quadrature`` (M, 3) is the exact row's value there."""
    nt = to_tangent(frame, normals_world)
    out = {}
    for m in HEMI_ROWS:
        spec = _spec(m)
        if spec.exact:
            out[m] = np.asarray(spec(NUMPY_OPS, {"irradiance": quadrature}), np.float64)
        elif m in METHODS:  # the sphere probe, in the world frame
            out[m] = np.asarray(basis_irradiance(spec, sh, normals_world), np.float64)
        else:
            coeffs = texel["rnm"] if m.startswith("rnm") else texel[m]
            out[m] = np.asarray(hemisphere_irradiance(spec, coeffs, nt), np.float64)
    return out


def environment_section(
    name: str,
    env,
    normals: np.ndarray,
    mean: np.ndarray,
    sigma: np.ndarray,
    quadrature: np.ndarray,
    sh: np.ndarray,
    supersample: int,
    backend: str | None,
    metrics: Callable[[np.ndarray, np.ndarray, np.ndarray], dict],
    quick: bool = False,
) -> list[dict]:
    """One record per frame of `FRAMES`: the frame, the number of hemisphere normals, the baked texel
    (and the time its bake took) and, per row, ``metrics(x, reference mean, reference σ)`` over the
    normals with n·N > 0."""

    def irradiance_at(world):
        return envs.irradiance_quadrature(env, world, supersample, backend)

    out = []
    for frame_name, geo in FRAMES:
        frame = surface_frame(geo)
        keep = normals @ frame[2] > 0.0
        t0 = time.perf_counter()
        texel = bake_frame(frame, irradiance_at, BAKE_RULE[quick])
        bake_ms = 1e3 * (time.perf_counter() - t0)
        evals = evaluate_rows(texel, sh, normals[keep], frame, quadrature[keep])
        rows = []
        for m in HEMI_ROWS:
            spec = _spec(m)
            rows.append(
                {
                    "method": m,
                    "label": spec.label,
                    "floats": spec.storage,
                    "metrics": metrics(evals[m], mean[keep], sigma[keep]),
                }
            )
        out.append(
            {
                "environment": name,
                "frame": frame_name,
                "geometric_normal": [float(v) for v in geo],
                "normals": int(keep.sum()),
                "bake_rule": list(BAKE_RULE[quick]),
                "bake_ms": bake_ms,
                "hbasis_6": texel["hbasis-6"].tolist(),
                "rnm_lightmaps": texel["rnm"].tolist(),
                "rows": rows,
            }
        )
    return out


def value(rec: dict, method: str, key: str = "rel_rmse") -> float:
    """The metric ``key`` of row ``method`` in a frame record."""
    for r in rec["rows"]:
        if r["method"] == method:
            return float(r["metrics"][key]["value"])
    return float("nan")


def floor(rec: dict, method: str, key: str = "rel_rmse") -> float:
    for r in rec["rows"]:
        if r["method"] == method:
            return float(r["metrics"][key].get("noise_floor") or 0.0)
    return 0.0


def checks(records: list[dict]) -> list[Check]:
    """The section's self-checks: the rows exact for a constant environment sit at the noise floor there;
    H6 is no worse than H4 (both are projections onto nested subspaces of L²(Ω+), and the Fibonacci normals
    sample the hemisphere uniformly). (The normalised RNM is *not* always better than the squared one:
    measured, see docs/irradiance-bases.md.)"""
    out = []
    const = [r for r in records if r["environment"] == "constant"]
    if const:
        bad = [
            f"{r['frame']}/{m}"
            for r in const
            for m in EXACT_ON_CONSTANT
            if value(r, m) > 2.0 * floor(r, m) + 1e-9
        ]
        out.append(
            Check(
                name="hemisphere: constant environment reproduced at the noise floor (H4, H6, normalised "
                "RNM, SH, quadrature; rel. RMSE ≤ 2× floor)",
                value=", ".join(bad) or "all at the floor",
                expected="all at the floor",
                passed=not bad,
            )
        )
    for better, worse in (("hbasis-6", "hbasis-4"),):
        bad = [
            f"{r['environment']}/{r['frame']}"
            for r in records
            if value(r, better) > value(r, worse) + 2.0 * floor(r, worse)
        ]
        out.append(
            Check(
                name=f"hemisphere: {better} no worse than {worse} (rel. RMSE within 2× floor, every "
                "environment and frame)",
                value=", ".join(bad) or "none worse",
                expected="none worse",
                passed=not bad,
            )
        )
    return out


def section_text(records: list[dict], costs: list[dict] | None = None) -> str:
    """Markdown: what was compared, and a table of the relative RMSE per environment × frame × row
    (the noise floor of the first row in the last column), then floats per texel and, from ``costs``
    (the experiment's cost rows), ns per normal."""
    head = "| environment | frame | normals | " + " | ".join(HEMI_ROWS) + " | floor |"
    sep = "|" + "---|" * (len(HEMI_ROWS) + 4)
    lines = [head, sep]
    for r in records:
        vals = " | ".join(f"{value(r, m):.3g}" for m in HEMI_ROWS)
        lines.append(
            f"| {r['environment']} | {r['frame']} | {r['normals']} | {vals} | {floor(r, HEMI_ROWS[0]):.2g} |"
        )
    means = " | ".join(f"{np.mean([value(r, m) for r in records]):.3g}" for m in HEMI_ROWS)
    lines.append(f"| **mean** | | | {means} | |")
    floats = " | ".join(str(_spec(m).storage or "—") for m in HEMI_ROWS)
    lines.append(f"| floats per texel (RGB) | | | {floats} | |")
    if costs:
        ns = {c["method"]: c.get("ns_per_pixel") for c in costs}
        cells = " | ".join(f"{ns[m]:.2g}" if ns.get(m) is not None else "—" for m in HEMI_ROWS)
        lines.append(f"| ns per normal ({costs[0].get('backend', '')}) | | | {cells} | |")
    rule = records[0]["bake_rule"] if records else BAKE_RULE[False]
    intro = (
        "Lightmap texels see bumped normals only in the upper hemisphere of their surface frame. Per "
        "environment and frame (z up; tilted 60° at azimuth 30°), the H-basis is the projection of the "
        f"irradiance over the hemisphere of normals ({rule[0]}×{rule[1]} Gauss–Legendre × φ rule), "
        "the RNM lightmaps are the irradiance at Valve's three tangent-space directions, reconstructed with "
        "linear, squared and normalised-squared weights; SH L1/L2 are the sphere probe's. All are compared "
        "with Mitsuba's irradiance at the run's Fibonacci normals with n·N > 0 (unoccluded: light from "
        f"below the surface plane counts). Relative RMSE (floor: the reference's noise)."
    )
    return intro + "\n\n" + "\n".join(lines)


def figure(out, records: list[dict], line_plot) -> dict:
    """Relative RMSE per environment for every row (log scale), one panel per frame, with the noise floor."""
    envs_ = list(dict.fromkeys(r["environment"] for r in records))
    frames = [f for f, _ in FRAMES]
    series = []
    for fr in frames:
        recs = [next(r for r in records if r["environment"] == e and r["frame"] == fr) for e in envs_]
        x = list(range(len(recs)))
        for m in HEMI_ROWS:
            series.append(
                {
                    "x": x,
                    "y": [max(value(r, m), 1e-6) for r in recs],
                    "label": m,
                    "panel": fr,
                    "style": "points" if _spec(m).exact else "line",
                }
            )
        series.append(
            {
                "x": x,
                "y": [max(floor(r, HEMI_ROWS[0]), 1e-6) for r in recs],
                "label": "noise floor",
                "panel": fr,
                "ls": ":",
                "color": "0.5",
            }
        )
    name = "figures/hemisphere_error.png"
    line_plot(
        out / name, "environment (numbered in the caption)", "relative RMSE (upper hemisphere)", series,
        y_log=True, panels=frames,
    )  # fmt: skip
    return {
        "file": name,
        "section": "hemisphere",
        "caption": "Relative RMSE of the lightmap bases (H-basis 4/6, RNM with three weightings) and of the "
        "sphere probe's SH L1/L2 over the normals of each frame's upper hemisphere (panels: frames), against "
        "Mitsuba, with the reference noise floor. Environments: "
        + ", ".join(f"{i} {e}" for i, e in enumerate(envs_))
        + ".",
    }


def _texel_coeffs(texel: dict, method: str):
    return texel["rnm"] if method.startswith("rnm") else texel[method]


# ============================================================================================== fitted
def write_fitted(out, records: list[dict], ctx=None, scene_hashes=None, reference_spp=None) -> list[str]:
    """One ``fitted/<environment>-lightmap.json`` per environment (``rtfit.fitted/1``): per frame and
    hemispherical basis the baked texel as shader literals (GLSL/HLSL taking the tangent-space normal),
    and the frames, H6 coefficients and RNM lightmaps as data. Returns the written files (relative)."""
    written = []
    for env in dict.fromkeys(r["environment"] for r in records):
        recs = [r for r in records if r["environment"] == env]
        methods = []
        for r in recs:
            texel = {"hbasis-6": np.asarray(r["hbasis_6"]), "rnm": np.asarray(r["rnm_lightmaps"])}
            texel["hbasis-4"] = texel["hbasis-6"][:4]
            for m, spec in HEMISPHERE_METHODS.items():
                coeffs = basis_inputs(spec, _texel_coeffs(texel, m), np.array([[0.0, 0.0, 1.0]]))["coeffs"]
                methods.append(
                    fitfiles.method_entry(
                        spec,
                        None,
                        id=f"{m}-{r['frame']}".replace(".", "_"),
                        label=f"{spec.label}, frame {r['frame']}",
                        case=env,
                        baked={"coeffs": coeffs},
                        outputs=("out_r", "out_g", "out_b"),
                    )
                )
        data = {
            "environment": env,
            "units": "H-basis coefficients of the irradiance (W/m^2 per channel, c_k = integral of E H_k "
            "over the hemisphere of normals); RNM lightmaps: irradiance W/m^2 at the basis directions",
            "normal_frame": "tangent space: (n.t, n.b, n.N), frame rows t, b, N; t = world +X made "
            "orthogonal to N, b = N x t",
            "hbasis": "H1 = 1/sqrt(2pi), H2 = -sqrt(3/2pi) y, H3 = sqrt(3/2pi)(2z-1), H4 = -sqrt(3/2pi) x, "
            "H5 = sqrt(15/2pi) xy, H6 = 0.5 sqrt(15/2pi)(x^2-y^2)",
            "rnm_basis": [list(b) for b in RNM_BASIS],
            "frames": [
                {
                    "frame": r["frame"],
                    "geometric_normal": r["geometric_normal"],
                    "hbasis_6": r["hbasis_6"],
                    "rnm_lightmaps": r["rnm_lightmaps"],
                }
                for r in recs
            ],
        }
        name = f"fitted/{env}-lightmap.json"
        fitfiles.write_fitted(
            out / name,
            fitfiles.FittedFile(
                format=fitfiles.FORMAT,
                title=f"lightmap texels (H-basis, RNM) baked for environment {env}",
                provenance=fitfiles.provenance(
                    ctx, "irradiance-bases", list((scene_hashes or {}).get(env, [])), reference_spp
                ),
                methods=methods,
                data=data,
            ),
        )
        written.append(name)
    return written
