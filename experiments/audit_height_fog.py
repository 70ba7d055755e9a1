r"""The ``height-fog`` family in `rtfit audit`: one exponential-fog medium along the scene camera's rays.

For an rtfit TOML scene and each of its ``exponential_fog`` media (σt(x) = b·exp(−c·h(x)) inside the
medium's box or ellipsoid, h the height along its gradient; `rtfit.scenes.ExponentialFog`), two cases on the
pixels whose camera ray crosses the medium (the segment from the camera to the visible point, or to where the
ray leaves the medium's region for a sky pixel):

* ``fogK-transmittance``: the medium's transmittance T = exp(−∫σt ds) along the segment (dimensionless,
  grey). Reference: ratio tracking through the scene's own Mitsuba medium
  (`rtfit.reference.medium_transmittance.transmittance_pass`: Mitsuba's free-flight sampling with the
  medium's majorant, the density from the medium plugin), in passes through the pass cache. Rows: the
  optical-depth forms of `rtfit.realtime.height_fog.METHODS` (``exact``, ``seed``, ``taylor``, quantity
  ``fog_optical_depth``) compared as T = e^(−τ) (`transmittance_method`, composing the form's own kernel;
  no formula is copied), evaluated with the medium's true b, c and fitted (b, c) to this scene; and your
  approximations of ``fog_transmittance``.
* ``fogK-radiance``: the radiance at the camera with this medium alone in the scene (the other media
  removed), rendered by rtfit's reference (`ReferenceCache`: ``volpathmis`` with the scene's transport, as
  the height-fog experiment renders its aerial-perspective cases); the in-scattered radiance is what the
  shading models add to the fog-free image L₀ (the same scene without media, same transport and spp). Rows:
  the shading models of `METHODS` (``const``: L = L₀·T + C·(1 − T); ``phase``: C = C₀ + C₁·4π·p_HG(θ, g)),
  evaluated with the medium's true b, c and the colours the experiment derives from the scene's ``sunsky``
  (`rtfit.experiments.height_fog.horizon_colour` for ``const``, `single_scatter_colour` for ``phase``), then
  fitted (b, c and the colours, from those values, within `fit_params`' bounds); and your approximations of
  ``fogged_radiance``.

The segment inputs are the experiment's own (`rtfit.experiments.height_fog.segment_geometry`: the
camera's origin, the G-buffer's view directions and depths, `fog_volume_segment` of the medium's volume):
z0, z1 (heights along the gradient at the segment's ends, m), the length D (m); cos_sun = v·l with l the
sunsky's sun direction. The inputs of the quantities `fog_transmittance` and `fogged_radiance`
(`rtfit.realtime.quantities`) are given alongside: ox, oy, oz (the camera), dx, dy, dz (unit direction),
``length`` (= D), ``density`` b and ``falloff`` c (the medium's, 1/m), l0_r, l0_g, l0_b.

Self-check (the engine's): the ``exact`` form's z-scores against the transmittance reference must be
standard normal — the check that the closed form on the experiment's segment geometry and the Monte Carlo
transmittance of the Mitsuba medium measure the same quantity.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime.height_fog import METHODS, OPTICAL_DEPTH_FORMS, TRANSMITTANCE_METHODS
from rtfit.reference import ReferenceCache, ReferenceRequest
from rtfit.reference.build import light_dicts
from rtfit.reference.cache import array_digest
from rtfit.reference.height_fog import medium_dict, register, sky_statistics
from rtfit.reference.medium_transmittance import transmittance_pass

from .audit import Applicability, Rule
from .audit_family import (
    AuditError,
    AuditFamily,
    AuditReference,
    AuditSetup,
    FamilyCase,
    PooledPasses,
    masked_image,
    pooled_passes,
)
from .height_fog import fit_params, horizon_colour, segment_geometry, single_scatter_colour

__all__ = ["FAMILY", "SHADING_ROWS", "fog_cases"]

# 2: at least MIN_COLLISIONS tentative collisions per ray; 3: independent channels; 4: σ̄ bounds the variance
FORMAT = 4


SHADING_ROWS = {"const": horizon_colour, "phase": single_scatter_colour}
"""The shading models' given parameters: the height-fog experiment's colour from the sky (its public row
functions), with the medium's true b, c."""


def _medium_index(setup: AuditSetup, app: Applicability) -> int:
    scene = setup.source
    if scene is None or not hasattr(scene, "media"):
        raise AuditError(f"height-fog: {app.part}: the audit reads height fog from rtfit TOML scenes")
    index = app.source
    if index is None or not 0 <= index < len(scene.media) or scene.media[index].kind != "exponential_fog":
        raise AuditError(f"height-fog: {app.part} is not an exponential_fog medium of the scene")
    return index


def _clamped(p: Param, value: float) -> Param:
    """``p`` with its start at ``value``, moved strictly inside its bounds."""
    lo, hi = p.lower, p.upper
    span = (hi - lo) if math.isfinite(hi - lo) else max(abs(value), 1.0)
    x = min(max(float(value), lo + 1e-6 * span), hi - 1e-6 * span)
    return dataclasses.replace(p, initial=x)


def _row_params(method_id: str, medium, given: dict, horizon) -> dict[str, Param]:
    """Start values and bounds of one row: `fit_params` of the experiment (bounds 10⁻³…10³ × the true b, c)
    where the medium has b, c > 0, else the method's declared bounds; starts at the row's given values."""
    if medium.density > 0 and medium.falloff > 0:
        base = fit_params(method_id, medium.density, medium.falloff, horizon)
    else:
        base = dict(METHODS[method_id].params)
    return {k: _clamped(p, given[k]) if k in given else p for k, p in base.items()}


def _sky(setup: AuditSetup, scene):
    """The sunsky statistics of the experiment (`sky_statistics`: horizon average, sun irradiance, …) and
    the unit sun direction, or (None, None) without a sunsky."""
    env = scene.environment()
    if env is None or getattr(env, "sun_direction", None) is None:
        return None, None
    mi = setup.mi
    stats = sky_statistics(mi, mi.load_dict(light_dicts(mi, env)[""]), env)
    sun = np.asarray(env.sun_direction, np.float64)
    return stats, sun / np.linalg.norm(sun)


def _transmittance(setup: AuditSetup, index: int, medium, origin, dirs, dist, label: str) -> PooledPasses:
    """Pooled ratio-tracking passes of the medium alone: mean and stderr (N, 3), the transmittance (1)."""
    mi = setup.mi
    register(mi)
    med = mi.load_dict(medium_dict(mi, medium))
    what = {
        "format": FORMAT,
        "quantity": "fog-transmittance",
        "medium": index,
        "rays": array_digest(np.asarray(origin), dirs, np.where(np.isfinite(dist), dist, -1.0)),
    }

    def render(spp: int, seed: int):
        return transmittance_pass(mi, med, origin, dirs, dist, spp, seed)

    return pooled_passes(setup, what, render, (-1, 3), label)


def _render(setup: AuditSetup, scene, label: str):
    """rtfit's cached radiance reference of ``scene`` (the run's spp, passes, seed and variant)."""
    request = ReferenceRequest(
        scene=scene, spp=setup.spp, pass_spp=setup.pass_spp, seed=setup.seed, variant=setup.variant
    )
    return ReferenceCache(setup.cache_root).get(request, progress=setup.progress, label=label)


def fog_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The transmittance and the radiance case of the medium ``app.source`` (module docstring)."""
    index = _medium_index(setup, app)
    scene = setup.source
    medium = scene.media[index]
    geom = segment_geometry(scene, setup.gbuffer, medium)
    length = np.asarray(geom["length"], np.float64)
    mask = np.isfinite(length) & (length > 0)
    if not mask.any():
        raise AuditError(f"height-fog: no camera ray of {scene.name!r} crosses {app.part}")
    dirs = np.asarray(geom["view_dir"], np.float64)
    dist = np.asarray(geom["distance"], np.float64)
    origin = tuple(float(x) for x in scene.camera.origin)
    stats, sun = _sky(setup, scene)
    n = int(mask.sum())
    d = dirs[mask]
    common = {
        "z0": np.asarray(geom["z0"], np.float64)[mask],
        "z1": np.asarray(geom["z1"], np.float64)[mask],
        "distance": length[mask],
        "length": length[mask],
        **{f"o{a}": np.full(n, origin[k]) for k, a in enumerate("xyz")},
        **{f"d{a}": d[:, k] for k, a in enumerate("xyz")},
        "density": np.full(n, float(medium.density)),
        "falloff": np.full(n, float(medium.falloff)),
        "cos_sun": d @ sun if sun is not None else np.zeros(n),
    }
    tag = f"fog{index}"
    true_bc = {"b": float(medium.density), "c": float(medium.falloff)}
    horizon = stats["horizon"] if stats is not None else (0.1, 0.1, 0.1)
    params = {
        "medium": app.part,
        "density_per_m": float(medium.density),
        "falloff_per_m": float(medium.falloff),
        "ellipsoid": bool(medium.ellipsoid),
        "albedo": [float(x) for x in medium.albedo],
        "g": float(medium.g),
        "pixels": n,
        "length_max_m": float(length[mask].max()),
    }

    # transmittance: ratio tracking through the Mitsuba medium alone
    t_ref = _transmittance(setup, index, medium, origin, d, dist[mask], f"{tag}: transmittance").reference(
        mask,
        quantity="transmittance T of the medium along the camera's rays (1, grey)",
        integrator="ratio tracking (Mitsuba Medium.sample_interaction with the medium's majorant)",
        integrator_reason="unbiased estimate of exp(−∫σt ds) with the medium plugin's own density",
    )
    t_rows = {f: TRANSMITTANCE_METHODS[f] for f in OPTICAL_DEPTH_FORMS}
    t_case = FamilyCase(
        id=f"{tag}-transmittance",
        label=f"{app.part}, transmittance",
        reference=t_ref,
        mask=mask,
        channel_inputs=(common, common, common),
        parameters={**params, "quantity": "transmittance"},
        units="1",
        notes=("the optical-depth forms are compared as T = e^(−τ), with the medium's b, c, then fitted",),
        methods=t_rows,
        quantity="fog_transmittance",
        params={f: _row_params(f, medium, true_bc, horizon) for f in t_rows},
    )

    # radiance: this medium alone vs the fog-free scene (same transport, spp, seed)
    alone = dataclasses.replace(scene, name=f"{scene.name}-{tag}", media=(medium,))
    clear = dataclasses.replace(scene, name=f"{scene.name}-nofog", media=())
    fogged = _render(setup, alone, f"{tag}: radiance with the medium")
    l0 = _render(setup, clear, f"{tag}: fog-free radiance L0")
    radiance_inputs = {**common, **{f"l0_{ch}": l0.mean[mask][:, k] for k, ch in enumerate("rgb")}}
    notes = [
        "L₀ is the fog-free image rendered with the same transport and spp (its noise is part of every "
        "row's error)",
    ]
    given_rows = {}
    for mid, colour in SHADING_ROWS.items():
        given = colour(medium, stats, None) if stats is not None else dict(true_bc)
        given_rows[mid] = _row_params(mid, medium, given, horizon)
    if stats is None:
        notes.append("no sunsky: the given rows use the method's declared colours (and cos_sun = 0)")
    reason = fogged.integrator.get("reason") or "rtfit's reference integrator rule"
    r_ref = AuditReference(
        mean=masked_image(mask, fogged.mean[mask]),
        stderr=masked_image(mask, fogged.stderr[mask]),
        spp=fogged.spp,
        passes=fogged.passes,
        passes_rendered=fogged.passes_rendered + l0.passes_rendered,
        cache_key=fogged.key,
        cache_path=fogged.path,
        seconds=fogged.render_seconds + l0.render_seconds,
        quantity="radiance at the camera with this medium alone (W/m²/sr, RGB)",
        integrator=str(fogged.integrator.get("type", "volpathmis")),
        integrator_reason=str(reason),
    )
    r_case = FamilyCase(
        id=f"{tag}-radiance",
        label=f"{app.part}, fogged radiance",
        reference=r_ref,
        mask=mask,
        channel_inputs=(radiance_inputs,),
        parameters={**params, "quantity": "fogged radiance", "l0_cache_key": l0.key},
        units="W/m²/sr",
        notes=tuple(notes),
        methods={mid: METHODS[mid] for mid in SHADING_ROWS},
        quantity="fogged_radiance",
        params=given_rows,
    )
    return [t_case, r_case]


FAMILY = AuditFamily(
    name="height-fog",
    quantity="fog_transmittance",
    quantities=("fogged_radiance",),
    formats=("rtfit-toml",),
    cases=fog_cases,
    describe=(
        "Per exponential-fog medium, on the pixels whose camera ray crosses it: (1) its transmittance "
        "T = exp(−∫σt ds) along the segment from the camera to the visible point (or to where a sky pixel's "
        "ray leaves the medium), estimated by ratio tracking through the scene's own Mitsuba medium, against "
        "the optical-depth forms as T = e^(−τ) on the height-fog experiment's segment geometry (z0, z1, D), "
        "with the medium's true b, c and fitted; (2) the radiance at the camera with this medium alone "
        "(rtfit's volpathmis reference), against the shading models L₀·T + C·(1 − T) on the fog-free image "
        "L₀ (same transport and spp), with the true b, c and the sky colours of the experiment, and fitted."
    ),
    rules=(
        Rule(
            "height-fog",
            "height fog",
            ("fog",),
            "{part} lies along the camera's rays",
            "transmittance and in-scattered radiance along the camera's rays",
            "volpathmis (unbiased with chromatic extinction; rtfit's exponential-fog medium)",
        ),
    ),
)
