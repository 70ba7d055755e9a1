r"""The ``linear-fog`` family on a scene's homogeneous media (`rtfit audit`, and ``rtfit run linear-fog`` on
its shipped scene): classic distance fog against Beer–Lambert and the path-traced fogged radiance.

Role (its ``rules``): ``homogeneous fog`` — a Mitsuba ``homogeneous`` medium (bounded by a shape, or around
the sensor), a ``heterogeneous`` one whose ``sigma_t`` is a ``constvolume``, or an rtfit TOML
``homogeneous`` medium. Its extinction σt is read from the loaded medium (``get_scattering_coefficients`` at a
point inside; a chromatic σt gives one transmittance case per channel).

The view distance d of every row is the camera ray's first stretch inside the medium, t_out − t_in
(`audit_media.medium_intervals`, walked as Mitsuba's volumetric path tracers walk it): for a medium around the
camera that is the distance to the visible surface, the seed's ``fDepth`` (000:662); for a bounded medium it
is the length a fog volume's shader integrates over. Pixels whose ray never enters, or leaves the scene inside
the medium (T = 0 exactly), are left out.

Two cases per medium, on the pixels whose camera ray crosses it:

* ``linfogK-transmittance`` (``linfogK-r-transmittance``, … per channel of a chromatic σt): the transmittance
  T = exp(−∫σt ds) along the stretch by ratio tracking through the loaded medium
  (`rtfit.reference.medium_transmittance.transmittance_pass`; the same passes as the height-fog family's
  constant-fog case: one cache key), against the fog factors ``fog-linear``, ``fog-exp``, ``fog-exp2``,
  ``fog-seed`` of `rtfit.realtime.linear_fog.METHODS`. Given: ρ = σt (``fog-exp`` is then Beer–Lambert,
  exact: its z-check is the engine's self-check), start = 0 and end = 2/σt (the ramp with Beer–Lambert's mean
  free path, ∫₀^∞ f dd = 1/σt), no cap; then fitted to the scene.
* ``linfogK-radiance`` (grey media in a scene with a light): the radiance at the camera with this medium
  alone, path traced by ``volpathmis`` (`audit_media.radiance_passes`), against the fog blends
  L = L₀·f + C·(1 − f) on the fog-free image L₀ (every medium off; same integrator, spp and seed). The fog
  colour C has no value to give (the seed's ``cFogColor`` is not published), so these rows are fitted only:
  C per channel plus each factor's own parameters, ``blend-beer-lambert`` C alone with σt the medium's.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rtfit.realtime.linear_fog import METHODS, RADIANCE_ROWS, TRANSMITTANCE_ROWS
from rtfit.realtime.methods import Param
from rtfit.reference.cache import array_digest
from rtfit.reference.medium_transmittance import transmittance_pass
from rtfit.reference.mitsuba_xml import UP_AXES

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_media import (
    RADIANCE_INTEGRATOR,
    MediumChannel,
    finite_stretch,
    fogged_radiance_inputs,
    opened_medium,
    past_variance_target,
    sigma_t_at,
    transmittance_case,
    transmittance_reference,
)
from .audit_setup import AuditSetup, pooled_passes
from .shipped import Sizes

__all__ = ["FAMILY", "SCENES", "homogeneous_fog_cases"]

SCENES = (
    Sizes(full=(64, 64, 256), quick=(24, 24, 32)).scene(
        "linear_fog_box.xml",
        "a rotated cube of scattering homogeneous fog (σt = 0.8, albedo 0.9/0.85/0.7) in front of a blue "
        "diffuse wall lit by a point light and a constant sky; the camera looks through the cube",
    ),
)
"""The scene ``rtfit run linear-fog`` audits (scenes/library/)."""

TRANSMITTANCE_FORMAT = 1
"""The key format of the transmittance and radiance passes: that of `audit_fog_media` (``FORMAT``), so both
families read one set of passes for one medium (the same rays, the same estimator)."""


def given_params(sigma: float, span: float) -> dict[str, dict[str, Param]]:
    """Row → given values and fit bounds for a medium of extinction ``sigma`` seen over stretches up to
    ``span`` long: ρ = σt within 10⁻³…10³ × σt; start = 0 and end = 2/σt (equal mean free path) within
    ±10·max(span, 2/σt); fog_max 1 (no cap) within (0, 2)."""
    end = 2.0 / sigma
    reach = 10.0 * max(span, end)
    ramp = {
        "start": Param(0.0, -reach, reach, unit="scene unit", description="fog start (given: 0)"),
        "end": Param(end, -reach, reach, unit="scene unit", description="fog end (given: 2/σt)"),
    }
    rho = {
        "density": Param(sigma, 1e-3 * sigma, 1e3 * sigma, unit="1/scene unit", description="ρ (given σt)")
    }
    cap = {"fog_max": Param(1.0, 0.0, 2.0, unit="1", description="largest fog amount (given: 1, no cap)")}
    by_kind = {"linear": ramp, "exp": rho, "exp2": rho, "seed": {**ramp, **cap}, "beer-lambert": {}}
    return {row: by_kind[row.split("-", 1)[1]] for row in (*TRANSMITTANCE_ROWS, *RADIANCE_ROWS)}


def _inputs(med, dirs, t_in, t_out, ok, up, sigma: float) -> dict:
    """The per-pixel inputs of both quantities (every input a user's ``fog_transmittance`` approximation
    may read): the stretch's start point and direction, its length d (``length``, and ``distance``), its end
    heights along the scene's up axis, ``density`` σt and ``falloff`` 0."""
    d = dirs[ok]
    start = med.origin + t_in[ok, None] * d
    end = med.origin + t_out[ok, None] * d
    length = t_out[ok] - t_in[ok]
    n = len(length)
    return {
        **{f"o{a}": start[:, k] for k, a in enumerate("xyz")},
        **{f"d{a}": d[:, k] for k, a in enumerate("xyz")},
        "length": length,
        "distance": length,
        "z0": start @ up,
        "z1": end @ up,
        "density": np.full(n, sigma),
        "falloff": np.zeros(n),
    }


def homogeneous_fog_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The transmittance case (one per channel of a chromatic σt) and, for a grey medium in a lit scene,
    the fogged-radiance case (module docstring)."""
    mi = setup.mi
    med, dirs, t_in, t_out = opened_medium(setup, app, "linear-fog")
    ok = finite_stretch(t_in, t_out)
    if not ok.any():
        raise AuditError(f"linear-fog: no camera ray crosses {app.part} over a finite stretch")
    h, w = setup.gbuffer.view_dir.shape[:2]
    mask = ok.reshape(h, w)
    k = int(np.argmax(ok))
    sigma = sigma_t_at(mi, med.medium, (med.origin + 0.5 * (t_in[k] + t_out[k]) * dirs[k])[None, :])[0]
    if not np.max(sigma) > 0.0:
        raise AuditError(f"linear-fog: {app.part} has σt = 0: no fog to audit")
    up = np.asarray(UP_AXES.get(setup.info.up, (0.0, 0.0, 1.0)), np.float64)
    span = float(np.max(t_out[ok] - t_in[ok]))
    grey = bool(np.allclose(sigma, sigma[0], rtol=1e-6, atol=0.0))
    notes = [
        f"σt = {', '.join(f'{s:.4g}' for s in sigma)} /scene unit (the medium's, at a point inside); d = the "
        "camera ray's stretch inside the medium (t_out − t_in)",
        "given: ρ = σt (fog-exp is then Beer–Lambert, exact), start = 0, end = 2/σt (the linear ramp with "
        "Beer–Lambert's mean free path ∫f dd = 1/σt), fog_max = 1 (no cap); then fitted",
    ]
    if med.on_sensor:
        notes.append("the camera sits in this medium: rays that leave the scene (T = 0 exactly) are left out")
    if not grey:
        notes.append("chromatic σt: one transmittance case per channel, no fogged-radiance case (a fog blend "
                     "takes one density for the three channels)")  # fmt: skip
    out = []
    for ch in [None] if grey else [0, 1, 2]:
        s = float(sigma[0 if ch is None else ch])
        if not s > 0.0:
            continue  # σt = 0 in this channel: T = 1 exactly, no fog
        common = _inputs(med, dirs, t_in, t_out, ok, up, s)
        suffix = "" if ch is None else f"-{'rgb'[ch]}"
        tag = f"linfog{app.source}{suffix}"
        given = given_params(s, span)
        # the key of audit_fog_media's constant-fog passes (`TRANSMITTANCE_FORMAT`): one render for both
        what = {
            "format": TRANSMITTANCE_FORMAT,
            "quantity": "medium-transmittance",
            "medium": app.source,
            "channel": ch,
            "rays": array_digest(med.origin, dirs[ok], t_in[ok], t_out[ok]),
        }
        tracked = med.medium if ch is None else MediumChannel(med.medium, ch)

        def render(spp: int, seed: int, tracked=tracked):
            return transmittance_pass(
                mi, tracked, med.origin, dirs[ok], t_out[ok], spp, seed, min_distance=t_in[ok]
            )

        ref = transmittance_reference(
            pooled_passes(setup, what, render, (-1, 3), f"{tag}: transmittance"),
            mask,
            "ratio tracking (Mitsuba Medium.get_scattering_coefficients, the medium's majorant)",
            unchecked=past_variance_target(mi, tracked, med.origin, dirs[ok], t_out[ok], t_in[ok]),
        )
        parameters = {"medium": app.part, "sigma_t": s, "channel": None if ch is None else "rgb"[ch],
                      "pixels": int(ok.sum()), "length_max": span}  # fmt: skip
        tail = "" if ch is None else f" ({'rgb'[ch]} channel)"
        out.append(
            transmittance_case(
                tag,
                f"{app.part}{tail}",
                ref,
                common,
                parameters,
                notes=tuple(notes),
                methods={r: METHODS[r] for r in TRANSMITTANCE_ROWS},
                params={r: given[r] for r in TRANSMITTANCE_ROWS},
            )
        )
        if ch is not None:
            continue
        if not len(med.scene.emitters()):
            no_light = "no light in the scene: no radiance case"
            out[-1] = dataclasses.replace(out[-1], notes=(*out[-1].notes, no_light))
            continue
        out.append(_radiance_case(setup, app, med, ok, mask, common, what, given, tag, parameters, notes))
    if not out:
        raise AuditError(f"linear-fog: {app.part} has σt = 0: no fog to audit")
    return out


def _radiance_case(setup, app, med, ok, mask, common, what, given, tag, parameters, notes) -> FamilyCase:
    """The radiance at the camera with this medium alone against the fog blends on the fog-free L₀."""
    what = {**what, "quantity": "medium-radiance", "integrator": RADIANCE_INTEGRATOR}
    ref, inputs, l0_key, _sun = fogged_radiance_inputs(setup, med, ok, mask, common, what, tag)
    return FamilyCase(
        id=f"{tag}-radiance",
        label=f"{app.part}, fogged radiance",
        reference=ref,
        channel_inputs=(inputs,),
        parameters={**parameters, "quantity": "fogged radiance", "l0_cache_key": l0_key},
        units="W/m²/sr",
        notes=(
            *notes,
            "L₀: the same scene with every medium switched off (scale 0), same integrator and spp (its noise "
            "is part of every row's error); the fog colour C has no published value: rows fitted only",
        ),
        methods={r: METHODS[r] for r in RADIANCE_ROWS},
        quantity="fogged_radiance",
        params={r: given[r] for r in RADIANCE_ROWS},
    )


FAMILY = AuditFamily(
    name="linear-fog",
    quantity="fog_transmittance",
    cases=homogeneous_fog_cases,
    describe=(
        "Per homogeneous medium of the scene: the classic fog factors f(d) on the view distance d through "
        "it (linear, exp, exp², the seed's capped linear fog) against the transmittance by ratio tracking "
        "through the loaded medium, given ρ = σt (Beer–Lambert, exact), start 0, end 2/σt, then fitted; and "
        "the fog blends L₀·f + C·(1 − f) (the seed's with its luminance fade) against the radiance path "
        "traced with this medium alone, fitted (C per channel and the factor's parameters)."
    ),
    quantities=("fogged_radiance",),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "linear-fog",
            "homogeneous fog",
            ("constant-fog",),
            "{part} is homogeneous: classic distance fog f(d) on the view distance d through it, exact as "
            "Beer–Lambert e^(−σt·d)",
            "transmittance along each camera ray's stretch inside the medium, and the radiance with this "
            "medium alone",
            "ratio tracking through the scene's own medium; volpathmis for the radiance",
            supplies=frozenset({"length", "density"}),
        ),
    ),
)
