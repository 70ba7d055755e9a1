r"""The ``height-fog`` family on a scene's own media: constant fog and fitted grid fog (`rtfit audit`).

The second declaration of the height-fog family (`audit_height_fog` audits rtfit's ``exponential_fog``; the
two are joined by `audit_family.by_name`). Its roles (its ``rules``):

* ``constant fog``: a Mitsuba ``homogeneous`` medium (bounded by a shape, or around the sensor: unbounded),
  a ``heterogeneous`` one whose ``sigma_t`` is a ``constvolume``, or an rtfit TOML ``homogeneous`` medium.
  It is height fog with falloff c = 0 and density b = σt (1/scene unit), the medium's own, read from the
  loaded medium (``get_scattering_coefficients``) — an RGB σt whose channels differ gives one case per
  channel (b = that channel's σt; the reference tracks that channel).
* ``grid fog``: a Mitsuba ``heterogeneous`` medium whose ``sigma_t`` is a ``gridvolume``. Its grid (data ×
  ``scale``, box from the volume's transform) is fitted with σ(p) = b·exp(−c·(p·ĝ − h₀))
  (`rtfit.reference.grid_fit.fit_height_density`: b, c, ĝ, h₀ = the box's lowest corner along ĝ), and the
  case states how far the grid is from that model (RMS and largest relative residual, empty voxels, the
  trilinear interpolation error (c·h)²/8 of the fitted model over one cell) **before** its rows' errors:
  in its label, its first note and its parameters. A grid far from exponential is audited all the same; where
  its largest residual or the interpolation error exceeds `MODEL_TOLERANCE` it is not the model, so its rows
  are not marked exact (no z-check runs on them) and their errors are the model's.

Two cases per medium, on the pixels whose camera ray crosses it:

* ``mediaK-transmittance`` (one per channel of a chromatic σt: ``mediaK-r-transmittance``, …): the
  transmittance T = exp(−∫σt ds) (dimensionless) along each camera ray's first interval inside the medium,
  against the optical-depth forms of `rtfit.realtime.height_fog.METHODS` as T = e^(−τ)
  (`rtfit.realtime.height_fog.TRANSMITTANCE_METHODS`), with the medium's b, c (given) and fitted, and your
  approximations of ``fog_transmittance``;
* ``mediaK-radiance`` (grey media in a scene with a light): the radiance at the camera with this medium alone
  (the scene's other media switched off: ``scale`` 0), path traced by Mitsuba's ``volpathmis`` through the
  run's sensor, against the shading models ``const`` and ``phase`` on the fog-free image L₀ (every medium
  switched off; same integrator, spp and seed), given the medium's b, c and the models' declared colours,
  then fitted (b, c and the colours), and your approximations of ``fogged_radiance``.

The interval (`medium_intervals`): each pixel-centre ray from the camera is walked through the scene as
Mitsuba's volumetric path tracers walk it: a medium-transition shape (``interior``/``exterior``) switches
the current medium to ``SurfaceInteraction3f.target_medium`` (a medium is entered where its shape's
interior is the target), a shape with only a ``null`` BSDF is passed, any other surface ends the ray; the
camera ray starts in the sensor's medium. [t_in, t_out] is the first stretch spent in the audited medium.
Straight lines: a dielectric boundary does not bend the ray here (a real-time fog does not either); pixels
whose ray never enters, or whose interval is infinite (an unbounded medium seen against the sky: T = 0
exactly), are left out. A grid's rows take the interval clipped to the grid's box (its heights z0, z1 along
ĝ and its length); the reference is the medium as Mitsuba renders it over [t_in, t_out] (its
``intersect_aabb``: the grid's axis-aligned bounds, where a rotated grid's texture clamps to its faces).

Reference: ratio tracking through the loaded Mitsuba medium over [t_in, t_out]
(`rtfit.reference.medium_transmittance.transmittance_pass`), in passes through the pass cache. Self-check
(the engine's): the ``exact`` row's z-scores are standard normal — on a grid filled from the model, within
the interpolation error above.

Rows left out: the ``seed`` listing on constant fog (its (1 − e^(−cΔz))/(cΔz) is 0/0 = NaN at c = 0 for every
ray with |Δz| > 0.01 m: docs/height-fog.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rtfit.realtime.height_fog import METHODS, TRANSMITTANCE_METHODS
from rtfit.reference.cache import array_digest
from rtfit.reference.grid_fit import GridDensity, HeightFit, fit_height_density, grid_of_medium
from rtfit.reference.medium_transmittance import transmittance_pass
from rtfit.reference.mitsuba_xml import UP_AXES

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_media import (
    MAX_SURFACES,
    RADIANCE_INTEGRATOR,
    Medium,
    MediumChannel,
    box_interval,
    density_params,
    finite_stretch,
    fogged_radiance_inputs,
    medium_intervals,
    opened_medium,
    past_variance_target,
    sigma_t_at,
    transmittance_case,
    transmittance_reference,
)
from .audit_setup import AuditSetup, pooled_passes

__all__ = ["FAMILY", "MAX_SURFACES", "media_cases", "medium_intervals"]

FORMAT = 1
CONSTANT_ROWS = ("exact", "taylor")
"""The optical-depth forms audited on constant fog (the seed listing is NaN at c = 0)."""
GRID_ROWS = ("exact", "seed", "taylor")
SHADING_ROWS = ("const", "phase")
MODEL_TOLERANCE = 1e-3
"""A grid holds the exponential model where its largest relative residual and the model's trilinear
interpolation error over a cell are both within this: then the exact form's z-check is run on it."""


def _residual_text(fit: HeightFit) -> str:
    return (
        f"grid vs the exponential height model: RMS relative residual {fit.rms_relative:.3g}, largest "
        f"{fit.max_relative:.3g}, {100.0 * fit.empty_fraction:.3g} % empty voxels ({fit.voxels} voxels; "
        f"trilinear interpolation error of the model over a cell ≈ {fit.interpolation_error:.2g})"
    )


def _cases(
    setup: AuditSetup,
    app: Applicability,
    med: Medium,
    t_in: np.ndarray,
    t_out: np.ndarray,
    rows_span: tuple[np.ndarray, np.ndarray],
    height,
    b: float,
    c: float,
    channel: int | None,
    extra: dict,
    notes: list[str],
    rows: tuple[str, ...],
    label_tail: str,
    radiance: bool,
    exact: bool = True,
) -> list[FamilyCase]:
    """The transmittance case: the reference over [t_in, t_out] of the pixels whose row interval is a
    finite non-empty stretch, rows on ``rows_span`` (heights from ``height``), given (b, c); and where
    ``radiance`` and the scene has a light, the radiance case (`_radiance_case`) on the same pixels.
    ``exact`` False: the medium is not the model, so no row is exact (the engine runs no z-check on it)."""
    mi = setup.mi
    h, w = setup.gbuffer.view_dir.shape[:2]
    dirs = np.asarray(setup.gbuffer.view_dir, np.float64).reshape(-1, 3)
    r0, r1 = rows_span
    ok = finite_stretch(t_in, t_out) & finite_stretch(r0, r1)
    mask = ok.reshape(h, w)
    if not mask.any():
        raise AuditError(f"height-fog: no camera ray crosses {app.part} over a finite stretch")
    d = dirs[ok]
    o = med.origin
    start, end = o + r0[ok, None] * d, o + r1[ok, None] * d
    length = r1[ok] - r0[ok]
    n = int(ok.sum())
    common = {
        "z0": height(start),
        "z1": height(end),
        "distance": length,
        "length": length,
        **{f"o{a}": start[:, k] for k, a in enumerate("xyz")},
        **{f"d{a}": d[:, k] for k, a in enumerate("xyz")},
        "density": np.full(n, b),
        "falloff": np.full(n, c),
    }
    tracked = med.medium if channel is None else MediumChannel(med.medium, channel)
    suffix = "" if channel is None else f"-{'rgb'[channel]}"
    tag = f"media{app.source}{suffix}"
    what = {
        "format": FORMAT,
        "quantity": "medium-transmittance",
        "medium": app.source,
        "channel": channel,
        "rays": array_digest(o, d, t_in[ok], t_out[ok]),
    }

    def render(spp: int, seed: int):
        return transmittance_pass(mi, tracked, o, d, t_out[ok], spp, seed, min_distance=t_in[ok])

    ref = transmittance_reference(
        pooled_passes(setup, what, render, (-1, 3), f"{tag}: transmittance"),
        mask,
        "ratio tracking (Mitsuba Medium.get_scattering_coefficients with the medium's majorant)",
        unchecked=past_variance_target(mi, tracked, o, d, t_out[ok], t_in[ok]),
    )
    given = density_params(b, c, float(length.max()))
    parameters = {
        "medium": app.part,
        "density": b,
        "falloff": c,
        "channel": None if channel is None else "rgb"[channel],
        "pixels": n,
        "length_max": float(length.max()),
        **extra,
    }
    t_case = transmittance_case(
        tag,
        f"{app.part}{label_tail}",
        ref,
        common,
        parameters,
        notes=tuple(notes),
        methods={f: _as_exact(TRANSMITTANCE_METHODS[f], exact) for f in rows},
        params={f: given for f in rows},
    )
    if not radiance:
        return [t_case]
    if not len(med.scene.emitters()):
        no_light = "no light in the scene: no fogged-radiance case"
        return [dataclasses.replace(t_case, notes=(*t_case.notes, no_light))]
    what = {**what, "quantity": "medium-radiance", "integrator": RADIANCE_INTEGRATOR}
    r_case = _radiance_case(setup, med, ok, mask, common, what, given, tag)
    label = f"{app.part}{label_tail}, fogged radiance"
    r_notes = (*notes, *r_case.notes)
    return [t_case, dataclasses.replace(r_case, label=label, parameters={**parameters, **r_case.parameters},
                                        notes=r_notes)]  # fmt: skip


def _as_exact(method, exact: bool):
    """``method``, or a copy of it that is not exact (the medium is not the model it is exact for)."""
    return method if exact or not method.exact else dataclasses.replace(method, exact=False)


def _radiance_case(setup, med: Medium, ok, mask, common, what, given, tag) -> FamilyCase:
    """The radiance at the camera with this medium alone (the scene's other media switched off), path
    traced with `RADIANCE_INTEGRATOR` through the run's sensor, against the shading models on the fog-free
    image L₀ (every medium switched off; same integrator, spp and seed); given: the medium's b, c and the
    models' declared colours; fitted: b, c and the colours."""
    ref, inputs, l0_key, sun = fogged_radiance_inputs(setup, med, ok, mask, common, what, tag)
    return FamilyCase(
        id=f"{tag}-radiance",
        label="",
        reference=ref,
        channel_inputs=(inputs,),
        parameters={"quantity": "fogged radiance", "l0_cache_key": l0_key},
        units="W/m²/sr",
        notes=(
            "L₀: the same scene with every medium switched off (scale 0), same integrator and spp (its noise "
            "is part of every row's error); given rows: the medium's b, c and the models' declared colours "
            "(the scene's sky is not sampled for them), then fitted",
        )
        + (() if sun is not None else ("no sunsky: cos_sun = 0",)),
        methods={mid: METHODS[mid] for mid in SHADING_ROWS},
        quantity="fogged_radiance",
        params={mid: given for mid in SHADING_ROWS},
    )


def constant_fog_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """Constant fog (c = 0, b = σt): one case, or one per channel of a chromatic σt (module docstring)."""
    med, dirs, t_in, t_out = opened_medium(setup, app, "height-fog")
    ok = finite_stretch(t_in, t_out)
    if not ok.any():
        raise AuditError(f"height-fog: no camera ray crosses {app.part} over a finite stretch")
    k = int(np.argmax(ok))
    mid = med.origin + 0.5 * (t_in[k] + t_out[k]) * dirs[k]
    sigma = sigma_t_at(setup.mi, med.medium, mid[None, :])[0]
    up = np.asarray(UP_AXES.get(setup.info.up, (0.0, 0.0, 1.0)), np.float64)

    def height(p):
        return p @ up

    notes = [
        f"constant fog: falloff c = 0, density b = σt = {', '.join(f'{s:.4g}' for s in sigma)} /scene unit "
        f"(the medium's, at a point inside); heights along the scene's up axis {setup.info.up}",
        "the seed listing is left out: at c = 0 its (1 − e^(−cΔz))/(cΔz) is 0/0 = NaN (docs/height-fog.md)",
    ]
    if med.on_sensor:
        notes.append("the camera sits in this medium: rays that leave the scene (T = 0 exactly) are left out")
    grey = bool(np.allclose(sigma, sigma[0], rtol=1e-6, atol=0.0))
    channels: list[int | None] = [None] if grey else [0, 1, 2]
    out = []
    for ch in channels:
        b = float(sigma[0 if ch is None else ch])
        if not b > 0.0:
            continue  # σt = 0 in this channel: no fog (T = 1 exactly)
        tail = "" if ch is None else f" ({'rgb'[ch]} channel)"
        extra = {"model": "constant fog (c = 0)", "up": setup.info.up}
        out += _cases(setup, app, med, t_in, t_out, (t_in, t_out), height, b, 0.0, ch, extra, notes,
                      CONSTANT_ROWS, tail, grey)  # fmt: skip
    if not out:
        raise AuditError(f"height-fog: {app.part} has σt = 0: no fog to audit")
    return out


def grid_fog_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """Grid fog: the grid fitted with the exponential height density, then one transmittance case."""
    med, dirs, t_in, t_out = opened_medium(setup, app, "height-fog")
    try:
        grid: GridDensity = grid_of_medium(setup.mi, med.medium)
    except ValueError as e:
        raise AuditError(f"height-fog: {app.part}: {e}") from None
    up = UP_AXES.get(setup.info.up, (0.0, 0.0, 1.0))
    fit = fit_height_density(grid, up=up)
    if not fit.b > 0.0:
        raise AuditError(f"height-fog: {app.part}: its grid is empty (zero density everywhere)")
    r0, r1 = box_interval(grid.to_world, med.origin, dirs, t_in, t_out)
    residual = _residual_text(fit)
    holds = fit.max_relative <= MODEL_TOLERANCE and fit.interpolation_error <= MODEL_TOLERANCE
    notes = [
        residual
        + (
            ""
            if holds
            else f": the grid is not the model (beyond {MODEL_TOLERANCE:g}), so the exact form is not exact "
            "for this medium and its z-check is not run; its error is the model's"
        ),
        f"fitted model: σ(p) = b·exp(−c·(p·ĝ − h₀)), b = {fit.b:.6g}, c = {fit.c:.6g} /scene unit, "
        f"ĝ = ({', '.join(f'{x:.4g}' for x in fit.gradient)}), h₀ = {fit.h0:.6g} (the box's lowest corner)",
        "rows: the stretch inside the grid's box; reference: the medium as Mitsuba renders it (ratio "
        "tracking)",
    ]
    nx, ny, nz = grid.resolution
    extra = {
        "model": "exponential height density fitted to the grid",
        "gradient": list(fit.gradient),
        "h0": fit.h0,
        "grid_resolution": [nx, ny, nz],
        "fit_rms_relative_residual": fit.rms_relative,
        "fit_max_relative_residual": fit.max_relative,
        "fit_empty_fraction": fit.empty_fraction,
        "fit_interpolation_error": fit.interpolation_error,
    }
    tail = f" (grid fit: RMS relative residual {fit.rms_relative:.2g})"
    return _cases(setup, app, med, t_in, t_out, (r0, r1), fit.height, fit.b, fit.c, None, extra, notes,
                  GRID_ROWS, tail, True, holds)  # fmt: skip


ROLES = {"constant fog": constant_fog_cases, "grid fog": grid_fog_cases}


def media_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The cases of one applicability (its role: `ROLES`)."""
    return ROLES[app.role](setup, app)


FAMILY = AuditFamily(
    name="height-fog",
    quantity="fog_transmittance",
    cases=media_cases,
    describe=(
        "Per medium of the scene that is not rtfit's exponential fog: a homogeneous medium is constant fog "
        "(c = 0, b = σt), a heterogeneous grid is fitted with the exponential height density "
        "b·exp(−c·(p·ĝ − h₀)) and the fit's residual is stated first; the transmittance along each camera "
        "ray's first stretch inside the medium, by ratio tracking through the loaded Mitsuba medium, against "
        "the optical-depth forms as T = e^(−τ) with the medium's (or the fitted) b, c, and fitted."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "height-fog",
            "constant fog",
            ("constant-fog",),
            "{part} is constant fog (falloff c = 0, density b = its σt) along the camera's rays",
            "transmittance along each camera ray's stretch inside the medium, and the radiance with this "
            "medium alone",
            "ratio tracking through the scene's own medium; volpathmis for the radiance",
        ),
        Rule(
            "height-fog",
            "grid fog",
            ("grid-fog",),
            "{part}: its grid is fitted with the exponential height density b·exp(−c·(p·ĝ − h₀)) (the fit's "
            "residual is reported first)",
            "transmittance along each camera ray's stretch inside the medium, and the radiance with this "
            "medium alone",
            "ratio tracking through the scene's own medium (its grid, trilinear); volpathmis for the "
            "radiance",
        ),
    ),
)
