"""Occluded sky light in `rtfit audit` (issue 15 §2: "an environment (envmap, constant, sunsky) → … occluded
sky light → SDF skylight / AO and ambient aperture on the scene's own geometry"): two roles, one declaration
each, sharing one reference and one bake.

Quantity (`rtfit.realtime.quantities` ``sky_irradiance``, W/m², RGB): the sky's irradiance **with
visibility** at each visible point x with unit normal n,

    E(x) = ∫_{H(n)} L_env(ω) V(x, ω) (n·ω) dω,   V = 1 where the ray x + tω (t > 0) meets no shape,

from the scene's own environment emitter (``envmap``, ``constant``; a ``sunsky``'s sky alone, its
``sun_scale`` set to 0 for the passes: the sun is a spherical light, the occluded-sphere-light role's): a
Mitsuba XML scene's environment emitter or the emitter rtfit builds for an rtfit TOML scene's
``constant_env``, ``envmap`` or ``sunsky`` light (`rtfit.experiments.audit_environment.scene_environment`).
Reference: `rtfit.reference.light_irradiance.environment_irradiance_pass` with the scene's shapes as
occluders (Mitsuba's emitter sampling and the cosine hemisphere by the balance heuristic, each sample times
Mitsuba's shadow ray), in independent passes through the pass cache, with per-pixel standard errors.

What the rows read, on the same masked pixels:

* E_SH(d): the environment's irradiance at a direction d from its SH L2 projection, as the irradiance-bases
  family bakes it (`audit_environment.environment_bases`, evaluated by the ``sh-l2`` row's own kernel)
  — what an engine's probe gives. For a sunsky, the sky's projection without the sun.
* The visibility bake (`rtfit.reference.occlusion.visibility_cap_pass`: unbounded ray casts against the
  scene's shapes, uniform on the hemisphere, pooled passes of their own seed): the visible fraction V_u,
  the cosine-weighted visibility V and the bent normal b (the mean unoccluded direction). The aperture
  (`ambient_aperture.aperture_from_visibility`) is r_a = acos(1 − V_u). This is what an engine bakes per
  vertex or texel; its noise is independent of the reference's.
* The distance field of the ambient-occlusion role (`audit_ambient_occlusion.distance_field_rows`: the
  same 64-cell field over the scene padded by R, the same Evans terms and per-unit k).

Rows:

* **sky occlusion** (family ``sdf-occlusion``, case ``sky<i>``): each distance-field row of the AO role —
  ``evans-text``, ``evans-listing`` (Evans' skylight, k and B fitted), ``cone`` (cone-traced visibility, 9
  cones × 8 steps marched from one voxel to the scene's bounding-box diagonal: the sky is unbounded; its
  aperture k fitted) and ``curvature`` (Evans' crease term) — as a visibility factor times E_SH(n):
  E ≈ C(x)·E_SH(n), what an engine does with an SDF skylight term and an SH probe.
* **aperture fill** (family ``ambient-aperture``, case ``fill<i>``): the ``fill-*`` rows of
  `rtfit.realtime.ambient_aperture.METHODS` (the ambient fill of the whole visibility cap, no light) with
  cos_na = n·b, the aperture r_a and the sky radiance L_sky = E_SH(b)/π per channel (the uniform sky whose
  irradiance along the bent normal is the probe's: exactly L for a constant environment). They have no
  free parameter.

The reference and the visibility bake are `rtfit.experiments.audit_sky.occluded_sky`'s (shared with the
sh-sky-bent-normal family: one set of passes per environment).

A user approximation of ``sky_irradiance`` is a row of both cases; its ``g`` carries n, b, V, r_a, L_sky (per
channel, as above), the point and the distance field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rtfit.realtime.ambient_aperture import METHODS as APERTURE_METHODS
from rtfit.realtime.arrays import NUMPY_OPS, xyz_columns
from rtfit.realtime.irradiance_bases import METHODS as BASIS_METHODS
from rtfit.realtime.methods import Input, Method
from rtfit.reference.estimators import gbuffer_points

from .audit import Applicability, AuditError, Rule
from .audit_ambient_occlusion import DistanceFieldRows, distance_field_rows
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import ao_radius
from .audit_setup import AuditReference, AuditSetup
from .audit_sky import occluded_sky

__all__ = [
    "APERTURE_FILL",
    "FILL_ROLE",
    "SKY_OCCLUSION",
    "SKY_ROLE",
    "SkyInputs",
    "sky_inputs",
    "times_irradiance",
]

SKY_ROLE = "sky occlusion"
FILL_ROLE = "sky occlusion (aperture fill)"
_IRRADIANCE = Input("irradiance_n", "W/m²", "E_SH(n): the environment's SH L2 irradiance at the normal")


def times_irradiance(method: Method) -> Method:
    """``method`` (a visibility factor C: an sdf-occlusion row) as sky irradiance, C·E_SH(n): the same kernel
    times the per-channel input ``irradiance_n`` (W/m²); its parameters unchanged."""
    base = method.kernel

    def kernel(ops, *args, irradiance_n, **kw):
        return base(ops, *args, **kw) * irradiance_n

    return replace(
        method,
        kernel=kernel,
        inputs=(*method.inputs, _IRRADIANCE),
        label=f"{method.label} × E_SH(n)",
        formula=f"({method.formula})·E_SH(n)",
        quantity="sky_irradiance",
        exact=False,
    )


def _sh_irradiance(sh27: np.ndarray, d: np.ndarray) -> np.ndarray:
    """E_SH(d) (N, 3) W/m² at unit directions ``d`` (N, 3): the ``sh-l2`` row's kernel on NumPy."""
    m = BASIS_METHODS["sh-l2"]
    rgb = m.kernel(NUMPY_OPS, d[:, 0], d[:, 1], d[:, 2], sh27, **m.fixed)
    return np.stack([np.broadcast_to(np.asarray(c, np.float64), (len(d),)) for c in rgb], axis=1)


@dataclass(frozen=True)
class SkyInputs:
    """The shared reference, bake and inputs of one environment (module docstring)."""

    reference: AuditReference
    kind: str
    channel_inputs: tuple[dict[str, Any], ...]
    rows: DistanceFieldRows
    radius: float
    march: float
    mean_visibility: float
    notes: tuple[str, ...]


_MEMO: dict[str, Any] = {}
MEMOS = (_MEMO,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def sky_inputs(setup: AuditSetup, app: Applicability, family: str) -> SkyInputs:
    """The reference, the bake and the rows' inputs for the environment ``app.source`` (module docstring;
    the reference and the bake are `audit_sky.occluded_sky`'s, shared with the sh-sky-bent-normal family);
    computed once per run and environment (both roles read them)."""
    sky = occluded_sky(setup, app, family)
    key = (id(setup), app.source)
    if _MEMO.get("key") == key and _MEMO.get("setup") is setup:
        return _MEMO["value"]
    radius = ao_radius(setup, family)
    points, normals, bent = sky.points, sky.normals, sky.bent
    e_n = _sh_irradiance(sky.sh, normals)
    e_b = _sh_irradiance(sky.sh, bent)
    diagonal = setup.info.diagonal or radius
    rows = distance_field_rows(setup, (), points, normals, radius, t_max=diagonal)
    common = {
        **xyz_columns("p", points),
        **xyz_columns("n", normals),
        **xyz_columns("b", bent),
        "visibility": sky.visibility,
        "aperture": sky.aperture,
        "cos_na": np.clip(np.sum(normals * bent, axis=1), -1.0, 1.0),
        "sdf": rows.sdf,
    }
    channel_inputs = tuple(
        {**common, "sky_radiance": np.maximum(e_b[:, c], 0.0) / math.pi, "irradiance_n": e_n[:, c]}
        for c in range(3)
    )
    value = SkyInputs(
        sky.reference,
        sky.kind,
        channel_inputs,
        rows,
        radius,
        float(diagonal),
        float(sky.visibility.mean()),
        (*sky.notes, *rows.notes),
    )
    _MEMO.clear()
    _MEMO.update(key=key, setup=setup, value=value)
    return value


def _parameters(app: Applicability, s: SkyInputs, setup: AuditSetup) -> dict:
    return {
        "environment": app.part,
        "kind": s.kind,
        "ao_distance": s.radius,
        "cone_t_max": s.march,
        **s.rows.parameters,
        "mean_visibility": s.mean_visibility,
        "pixels": int(setup.mask.sum()),
    }


def sky_occlusion_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """sdf-occlusion, sky occlusion: the distance-field rows × E_SH(n) against the occluded sky irradiance."""
    s = sky_inputs(setup, app, "sdf-occlusion")
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    rows = distance_field_rows(setup, app.methods, points, normals, s.radius, t_max=s.march)
    methods = {rid: times_irradiance(m) for rid, m in rows.methods.items()}
    row_inputs = {
        rid: tuple({**ch, **terms[0]} for ch in s.channel_inputs) for rid, terms in rows.row_inputs.items()
    }
    inputs = tuple({**rows.inputs, **ch} for ch in s.channel_inputs)
    return [
        FamilyCase(
            id=f"sky{app.source}",
            label=f"{app.part}: sky irradiance with visibility, distance-field skylight × SH L2",
            reference=s.reference,
            channel_inputs=inputs,
            parameters=_parameters(app, s, setup),
            units="W/m²",
            notes=s.notes,
            methods=methods,
            quantity="sky_irradiance",
            params=rows.params,
            row_inputs=row_inputs,
        )
    ]


def aperture_fill_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """ambient-aperture, aperture fill: the fill-* rows on the baked caps against the occluded sky
    irradiance."""
    s = sky_inputs(setup, app, "ambient-aperture")
    methods = {rid: APERTURE_METHODS[rid] for rid in app.methods if rid.startswith("fill-")}
    if not methods:
        raise AuditError(f"ambient-aperture: no fill row applies to {app.part}")
    return [
        FamilyCase(
            id=f"fill{app.source}",
            label=f"{app.part}: sky irradiance with visibility, ambient-aperture fill",
            reference=s.reference,
            channel_inputs=s.channel_inputs,
            parameters=_parameters(app, s, setup),
            units="W/m²",
            notes=(
                *s.notes,
                "L_sky = E_SH(b)/π per channel: the uniform sky the probe gives along the bent normal",
            ),
            methods=methods,
            quantity="sky_irradiance",
        )
    ]


_REFERENCE_TEXT = (
    "Sky irradiance with visibility E = ∫ L_env V (n·ω) dω (W/m², RGB) at each visible point from "
    "the scene's environment (a sunsky's sky without its sun), by Mitsuba's emitter sampling and the "
    "cosine hemisphere (balance heuristic) with Mitsuba's shadow rays against the scene's shapes, in "
    "independent passes with per-pixel standard errors. "
)
SKY_OCCLUSION = AuditFamily(
    name="sdf-occlusion",
    quantity="sky_irradiance",
    cases=sky_occlusion_cases,
    describe=(
        "Sky occlusion: "
        + _REFERENCE_TEXT
        + "Each distance-field row of the ambient-occlusion role (Evans' skylight, cone-traced "
        "visibility marched to the scene's diagonal, the curvature term; the same field) is a "
        "visibility factor times the environment's SH L2 irradiance at the normal, with its free "
        "parameters fitted to this scene."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "sdf-occlusion",
            "sky occlusion",
            ("environment", "sdf-geometry"),
            "{part} is occluded by {with_}",
            "sky irradiance with visibility at the visible points (the environment's direct light, "
            "shadowed; a sunsky's sky alone)",
            "the environment alone: emitter + cosine sampling (MIS) with shadow rays against the scene's "
            "shapes",
        ),
    ),
)
APERTURE_FILL = AuditFamily(
    name="ambient-aperture",
    quantity="sky_irradiance",
    cases=aperture_fill_cases,
    describe=(
        "Aperture fill: "
        + _REFERENCE_TEXT
        + "The fill rows read each point's visibility cap as an engine bakes it by ray casts (the "
        "bent normal b, the aperture acos(1 − V) of the visible fraction V) and the uniform sky "
        "radiance E_SH(b)/π of the environment's SH L2 projection."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "ambient-aperture",
            "sky occlusion (aperture fill)",
            ("environment", "sdf-geometry"),  # (`sky_inputs` builds the distance field for both roles)
            "{part} is occluded by {with_}: the visible cap of sky",
            "sky irradiance with visibility at the visible points, and each point's visible cap (bent "
            "normal, aperture)",
            "the environment alone: emitter + cosine sampling (MIS) with shadow rays; the caps by unbounded "
            "ray casts",
        ),
    ),
)
