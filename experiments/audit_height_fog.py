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
  evaluated with the medium's true b, c and the colours derived from the scene's ``sunsky``
  (`horizon_colour` for ``const``, `single_scatter_colour` for ``phase``), then fitted (b, c and the colours,
  from those values, within `fit_params`' bounds); the seed's own colour, the horizon average × 4π·p_HG
  with the medium's g (`horizon_phase_colour`), as the row ``horizon-phase`` (given only: the fit of
  ``phase`` covers it); on a purely absorbing medium (albedo 0) the row ``absorbing``, L₀·e^(−τ) with the
  true b, c (exact there, with the reference's standard error that of a survival per sample; ``rtfit run
  height-fog``'s study z-checks it: rtfit's fog path tracer must render e^(−τ)); and your approximations of
  ``fogged_radiance``.

The segment inputs (`segment_geometry`: the camera's origin, the G-buffer's view directions and depths,
`fog_volume_segment` of the medium's volume):
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
import hashlib
import math

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime import FogVolume, fog_volume_segment
from rtfit.realtime.height_fog import METHODS, OPTICAL_DEPTH_FORMS, TRANSMITTANCE_METHODS
from rtfit.reference import ReferenceCache, ReferenceRequest
from rtfit.reference.build import light_dicts
from rtfit.reference.cache import array_digest
from rtfit.reference.height_fog import medium_dict, region_matrix, register, sky_statistics
from rtfit.reference.medium_transmittance import transmittance_pass

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_media import past_variance_target, transmittance_case, transmittance_reference
from .audit_setup import AuditReference, AuditSetup, PooledPasses, pooled_passes
from .case_inputs import masked_image
from .shipped import ShippedScene, Sizes

__all__ = [
    "FAMILY",
    "SCENES",
    "SHADING_ROWS",
    "fit_params",
    "fog_cases",
    "horizon_colour",
    "horizon_phase_colour",
    "pixel_rays",
    "segment_geometry",
    "single_scatter_colour",
    "volume_from_medium",
]

SUN_ELEVATIONS_DEG = (5.0, 10.0, 15.0, 30.0, 40.0, 60.0)
QUICK_ELEVATIONS_DEG = (10.0, 40.0)
TRANSPORTS = ("single", "multiple")
PASSES = {"pass_spp": 128}
"""The shipped scenes' passes of 128 samples (the engine's default 32 costs ~1 s more per pass here)."""


_box = Sizes(full=(64, 64, 2048), quick=(24, 24, 256))
_field = Sizes(full=(256, 128, 2048), quick=(64, 32, 256))


def _terrain(e: float, transport: str) -> ShippedScene:
    # --quick audits the terrain's radiance alone (the transmittance is checked on the fog boxes)
    return _field.scene(
        f"fog_terrain_e{e:g}_{transport}.toml",
        f"terrain with objects at 10 m–20 km under sunsky (sun {e:g}°, azimuth 50° from the view) in "
        f"scattering height fog (b = 2e-4 /m, c = 0.004 /m, albedo 0.9, g = 0.6), {transport} scattering",
        quick=e in QUICK_ELEVATIONS_DEG,
        quick_quantities=("fogged_radiance",),
        options=PASSES,
    )


SCENES = (
    _box.scene(
        "fog_transmittance.toml",
        "an emissive backdrop (radiance 1) through a purely absorbing exponential-fog box (tilted, shifted "
        "gradient): the fog path tracer must render e^(−τ)",
        options=PASSES,
    ),
    _box.scene(
        "fog_transmittance_ellipsoid.toml",
        "the same check with the fog in the ellipsoid inscribed in the box (a fog volume)",
        options=PASSES,
    ),
    *(_terrain(e, tr) for e in SUN_ELEVATIONS_DEG for tr in TRANSPORTS),
    _field.scene(
        "fog_volumes_e40.toml",
        "the terrain with two local fog volumes (an ellipsoid and a rotated box with a tilted gradient), "
        "sun 40°, multiple scattering",
        options=PASSES,
    ),
)
"""The scenes ``rtfit run height-fog`` audits (scenes/library/): the reference checks (an absorbing box and
ellipsoid of fog before an emitter), the terrain under sunsky in global height fog at `SUN_ELEVATIONS_DEG`
(``--quick``: `QUICK_ELEVATIONS_DEG`) in single and multiple scattering, and the two fog volumes."""


# ------------------------------------------------------------------------------ parameter sources
def _colour(index: str, rgb) -> dict:
    """{r<index>, g<index>, b<index>}: a colour as the shading methods' parameters."""
    return {f"{ch}{index}": float(v) for ch, v in zip("rgb", rgb, strict=True)}


def _true_density(medium) -> dict:
    return {"b": medium.density, "c": medium.falloff}


def horizon_colour(medium, sky: dict, fit: dict | None = None) -> dict:
    """True b, c; C = the sky's horizon average (the seed's colour without phase, 000:2247-2254)."""
    return {**_true_density(medium), **_colour("0", sky["horizon"])}


def horizon_phase_colour(medium, sky: dict, fit: dict | None = None) -> dict:
    """True b, c; C = horizon average × 4π·p_HG(θ, g) with the medium's g (the seed's per-pixel phase)."""
    return {
        **_true_density(medium),
        **_colour("0", (0.0, 0.0, 0.0)),
        **_colour("1", sky["horizon"]),
        "g": medium.g,
    }


def single_scatter_colour(medium, sky: dict, fit: dict | None = None) -> dict:
    """True b, c; in-scatter at optical infinity with an unattenuated sun: albedo·(E_sun·p(θ) + mean sky
    radiance over the sphere, the lower half lit ground of albedo ~0.18 under E_horizontal)."""
    alb = np.asarray(medium.albedo)
    e_h = (
        np.asarray(sky["sky_irradiance_horizontal"])
        + np.asarray(sky["sun_irradiance"]) * sky["sun_direction"][2]
    )
    ambient = 0.5 * np.asarray(sky["upper_mean"]) + 0.5 * 0.18 * e_h / math.pi
    return {
        **_true_density(medium),
        **_colour("0", alb * ambient),
        **_colour("1", alb * np.asarray(sky["sun_irradiance"]) / (4 * math.pi)),
        "g": medium.g,
    }


FIT_RANGE = {"b": (1e-3, 1e3), "c": (1e-3, 1e2)}
"""Fits start at the scene's true b and c with bounds these factors of it; the colour starts at the sky's
horizon average; other start values and bounds are the method's (`METHODS`)."""


def fit_params(method: str, density: float, falloff: float, horizon) -> dict[str, Param]:
    """Start values and bounds of one fit (see `FIT_RANGE`)."""
    start = {
        "b": density,
        "c": falloff,
        **{f"{ch}0": max(float(h), 1e-4) for ch, h in zip("rgb", horizon, strict=True)},
    }
    out = {}
    for name, p in METHODS[method].params.items():
        if name in FIT_RANGE:
            lo, hi = FIT_RANGE[name]
            x = start[name]
            out[name] = Param(x, x * lo, x * hi, unit=p.unit, description=p.description)
        else:
            out[name] = dataclasses.replace(p, initial=start[name]) if name in start else p
    return out


# ------------------------------------------------------------------------------------ segments
def volume_from_medium(medium, colour=(1.0, 1.0, 1.0)) -> FogVolume:
    """The real-time `FogVolume` of a scene `ExponentialFog` (same region, gradient and density)."""
    m = region_matrix(medium.boundary)
    half = np.linalg.norm(m[:3, :3], axis=0)
    rot = m[:3, :3] / half
    return FogVolume(
        center=tuple(m[:3, 3]),
        half_size=tuple(half),
        rotation=tuple(map(tuple, rot)),
        ellipsoid=medium.ellipsoid,
        density=medium.density,
        falloff=medium.falloff,
        gradient=medium.gradient,
        gradient_origin=medium.gradient_origin,
        colour=colour,
    )


def pixel_rays(scene, gb):
    """Camera origin, unit view directions (float64) and hit distances (inf: sky) of a G-buffer."""
    d = gb.view_dir.astype(np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    dist = np.where(gb.mask, gb.depth.astype(np.float64), np.inf)
    return tuple(float(x) for x in scene.camera.origin), d, dist


def segment_geometry(scene, gb, medium) -> dict:
    """Per-pixel segment of the camera ray inside ``medium``'s region (float64, `fog_volume_segment`):
    heights along the gradient at entry and exit, length, and the ray's elevation and hit distance."""
    o, d, dist = pixel_rays(scene, gb)
    z0, z1, length = fog_volume_segment(o, d, dist, volume_from_medium(medium))
    return {
        "z0": z0,
        "z1": z1,
        "length": length,
        "elevation_deg": np.degrees(np.arcsin(np.clip(d[..., 2], -1, 1))),
        "distance": dist,
        "view_dir": d,
    }


# 2: at least MIN_COLLISIONS tentative collisions per ray; 3: independent channels; 4: σ̄ bounds the variance;
# 5: keyed by the medium and the rays alone (not the whole scene: `_transmittance`)
FORMAT = 5


SHADING_ROWS = {"const": horizon_colour, "phase": single_scatter_colour}
"""The shading models' given parameters: the colour from the sky, the medium's true b, c (then fitted)."""

GIVEN_ROWS = {"horizon-phase": ("phase", horizon_phase_colour, "seed: horizon average × 4π·HG phase")}
"""Rows evaluated with given values only (their method's fit is that of `SHADING_ROWS`): row → (method,
parameter source, label)."""


def _given_only(method_id: str, values: dict, label: str):
    """``METHODS[method_id]`` with every parameter fixed at ``values`` (the same kernel text): a row the
    engine evaluates and does not fit."""
    return dataclasses.replace(METHODS[method_id], label=label, params={}, fixed=values)


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


def _transmittance(
    setup: AuditSetup, index: int, medium, origin, dirs, dist, label: str
) -> tuple[PooledPasses, np.ndarray]:
    """Pooled ratio-tracking passes of the medium alone: mean and stderr (N, 3), the transmittance (1); and
    per ray whether the tracker runs past its variance target (`audit_media.past_variance_target`)."""
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

    # The medium alone along these rays (their ends are in ``rays``): the rest of the scene (its lights, the
    # sun, the transport) does not change it, so scenes that differ only there share these passes (the
    # shipped terrain at each sun elevation and scattering order).
    alone = hashlib.sha256(repr(medium).encode()).hexdigest()
    pooled = pooled_passes(dataclasses.replace(setup, scene_digest=alone), what, render, (-1, 3), label)
    return pooled, past_variance_target(mi, med, origin, dirs, dist, None)


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

    # transmittance: ratio tracking through the Mitsuba medium alone (also the absorbing radiance's noise)
    absorbing = not any(medium.albedo)
    t_ref = None
    if absorbing or setup.wants("fog_transmittance"):
        pooled, thick = _transmittance(setup, index, medium, origin, d, dist[mask], f"{tag}: transmittance")
        t_ref = transmittance_reference(
            pooled,
            mask,
            "ratio tracking (Mitsuba Medium.sample_interaction with the medium's majorant)",
            unchecked=thick,
        )
    t_rows = {f: TRANSMITTANCE_METHODS[f] for f in OPTICAL_DEPTH_FORMS}
    t_cases = []
    if t_ref is not None:  # not where the run audits the radiance alone (the terrain's --quick)
        t_cases.append(
            transmittance_case(
                tag,
                app.part,
                t_ref,
                common,
                params,
                notes=(
                    "the optical-depth forms are compared as T = e^(−τ), with the medium's b, c, then fitted",
                ),
                methods=t_rows,
                params={f: _row_params(f, medium, true_bc, horizon) for f in t_rows},
            )
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
    methods = {mid: METHODS[mid] for mid in SHADING_ROWS}
    for mid, colour in SHADING_ROWS.items():
        given = colour(medium, stats, None) if stats is not None else dict(true_bc)
        given_rows[mid] = _row_params(mid, medium, given, horizon)
    if stats is None:
        notes.append("no sunsky: the given rows use the method's declared colours (and cos_sun = 0)")
    else:
        for row, (mid, colour, label) in GIVEN_ROWS.items():
            methods[row] = _given_only(mid, colour(medium, stats), f"{label} (true b, c)")
    if not any(medium.albedo):
        black = {**true_bc, **_colour("0", (0.0, 0.0, 0.0))}
        methods["absorbing"] = _given_only("const", black, "L₀·e^(−τ), true b, c (exact at albedo 0)")
        notes.append(
            "albedo 0: the row absorbing (L₀·e^(−τ)) is exact here (rtfit run height-fog z-checks it)"
        )
    reason = fogged.integrator.get("reason") or "rtfit's reference integrator rule"
    stderr = fogged.stderr[mask]
    if t_ref is not None and absorbing:
        # A camera ray through a purely absorbing medium survives (with probability T) or not, independently
        # of the radiance L behind it: per sample the variance is T·Var L + L₀²·T(1 − T), which the sample
        # variance of a pixel whose samples all survived (or none) misses (0). Its value under the hypothesis
        # of the exact row, with T by ratio tracking (the transmittance case's reference, not a row) and L₀'s
        # own standard error (the experiment's reference check).
        t_rt = np.clip(t_ref.mean[mask], 0.0, 1.0)
        l0_mean, l0_err = l0.mean[mask], l0.stderr[mask]
        stderr = np.sqrt(t_rt * l0_err**2 + l0_mean**2 * t_rt * (1.0 - t_rt) / fogged.spp)
        notes.append(
            "albedo 0: the reference's standard error is that of a survival per sample, "
            "√(T·σ(L₀)² + L₀²·T(1 − T)/N), T by ratio tracking (a pixel's sample variance is 0 where all its "
            "samples agreed by chance)"
        )
    r_ref = AuditReference(
        mean=masked_image(mask, fogged.mean[mask]),
        stderr=masked_image(mask, stderr),
        spp=fogged.spp,
        passes=fogged.passes,
        passes_rendered=fogged.passes_rendered + l0.passes_rendered,
        cache_key=fogged.key,
        cache_path=fogged.path,
        seconds=fogged.render_seconds + l0.render_seconds,
        quantity="radiance at the camera with this medium alone (W/m²/sr, RGB)",
        integrator=str(fogged.integrator.get("type", "volpathmis")),
        integrator_reason=str(reason),
        mask=mask,
    )
    r_case = FamilyCase(
        id=f"{tag}-radiance",
        label=f"{app.part}, fogged radiance",
        reference=r_ref,
        channel_inputs=(radiance_inputs,),
        parameters={**params, "quantity": "fogged radiance", "l0_cache_key": l0.key},
        units="W/m²/sr",
        notes=tuple(notes),
        methods=methods,
        quantity="fogged_radiance",
        params=given_rows,
        fit_weight="relative",  # (the height-fog experiment's fits: near and far pixels alike)
    )
    return [*t_cases, r_case]


FAMILY = AuditFamily(
    name="height-fog",
    quantity="fog_transmittance",
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
    quantities=("fogged_radiance",),
    formats=("rtfit-toml",),
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
