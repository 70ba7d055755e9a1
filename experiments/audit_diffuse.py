"""The ``diffuse`` family in `rtfit audit`: one light's direct irradiance at the scene's visible points.

For each light of the scene — of a Mitsuba XML scene (point, spot, directional, sphere, disk, rectangle, an
area light on any mesh, the sun of a ``sunsky``) or of an rtfit TOML scene (``sun`` directional or of finite
angular radius, ``sphere_light``, ``rect_light``, ``point_light``, ``spot_light``, the sun of a ``sunsky``):
`rtfit.experiments.audit_lights` — and the pixel-centre G-buffer of the scene's own camera (points x,
camera-facing unit normals n):

* reference: the light's direct irradiance E (W/m², RGB) at x for n, **unshadowed** (the light alone) and
  **shadowed** (with the scene's own occluders), two cases reported separately, estimated by
  `rtfit.reference.light_irradiance.light_irradiance_pass` (Mitsuba's emitter sampling and shadow rays:
  the cheapest exact estimator of one light's direct irradiance) in independent passes through the pass
  cache;
* the methods' inputs (`rtfit.realtime.quantities` ``light_irradiance``), per pixel:
  ``cos_theta`` = n·t with t the unit direction from x to the light's centre (a point/spot light's
  position, a sphere's centre, the centre of an area light's bounding box, the direction of a distant
  light); ``irradiance`` E⊥ = the light's unshadowed irradiance on a surface facing t (estimated in the
  same pass from samples of its own, per channel: for a sphere light π·L·sin²α); ``alpha`` = asin(r/d)
  for a sphere light of radius r at distance d, a distant sun's angular radius (0 for every other light);
  ``distance`` d = |c − x| (+inf for a distant light); ``radiance`` L (a sphere light's or a TOML sun's
  declared radiance, else E⊥/(π sin²α));
* the light models' inputs from the light's own parameters (`audit_lights.light_model_inputs`: a point's
  or spot's intensity, a spot's cone angles and axis, a sphere's, rectangle's or disk's radiance and size
  as an intensity towards x, a rectangle's corners), never from the reference; the windows' radius r is
  fitted (`window_params`);
* shadowed case: each method's value times the hard shadow of the light's centre (one shadow ray from x
  towards t: 1 when nothing blocks it), which is what a shadow map gives an engine; so the shadowed case
  measures the formula together with a hard shadow against the true, soft one.
"""

from __future__ import annotations

import numpy as np

from rtfit.realtime.light_models import METHODS as LIGHT_MODELS
from rtfit.realtime.methods import Param
from rtfit.reference.estimators import gbuffer_points

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_lights import (
    hard_shadow,
    light_geometry,
    light_model_inputs,
    light_radiance,
    light_reference,
    scene_light,
    small_sphere_caveat,
    sphere_sampling_precision,
)
from .audit_setup import AuditSetup
from .shipped import Sizes

__all__ = ["ALPHAS_DEG", "FAMILY", "SCENES", "light_geometry", "light_radiance", "light_reference"]

ALPHAS_DEG = (0.27, 1.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0)
"""The sun's angular radii (°) of the shipped scenes, one file each (``diffuse_sphere_a<α>.toml``)."""
QUICK_ALPHAS_DEG = (0.27, 5.0, 15.0, 30.0)
"""Those ``--quick`` audits (the smooth law's four parameters still have four light sizes to fit)."""

_sizes = Sizes(full=(128, 128, 4096), quick=(32, 32, 256))
SCENES = tuple(
    _sizes.scene(
        f"diffuse_sphere_a{a:g}".replace(".", "p") + ".toml",
        f"white unit sphere side-lit by a sun of {a:g}° angular radius (E⊥ = π), seen from −Y",
        quick=a in QUICK_ALPHAS_DEG,
    )
    for a in ALPHAS_DEG
)
"""The scenes ``rtfit run diffuse`` audits (scenes/library/): the half_lambert_sphere scene with its sun
resized to each α of `ALPHAS_DEG`. One rtfit TOML file per α: the finite sun is rtfit's own Mitsuba emitter
(a disc at infinity, `rtfit.reference.emitters`), which a Mitsuba XML file cannot name (``rtfit export-xml``
leaves it out; a far ``sphere`` emitter is biased by +0.39 % at 0.27°), and TOML scenes take no ``-D``
defines. No sky: the family audits each light alone, so a constant sky would change no number."""


def diffuse_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The unshadowed and the shadowed case of the light ``app.source`` (module docstring)."""
    if app.source is None:
        raise AuditError(f"diffuse: {app.part} is not a light of the scene")
    light = scene_light(setup, app.source)
    mask = setup.mask
    points, normals = gbuffer_points(setup.gbuffer, mask)
    towards, dist, alpha, _centre, radius = light_geometry(setup, app.source, points)
    tag = f"light{app.source}"
    pooled = light_reference(setup, app.source, points, normals, towards, f"{tag}: {app.part}")
    cos = np.clip(np.sum(normals * towards, axis=1), -1.0, 1.0)
    e_perp = pooled.mean[:, 6:9]
    radiance = light_radiance(setup, app.source, e_perp, alpha)
    own = light_model_inputs(setup, app.source, points, normals, towards, dist)
    inputs = tuple(
        {
            "cos_theta": cos,
            "irradiance": e_perp[:, c],
            "alpha": alpha,
            "distance": dist,
            "radiance": radiance[c],
            **own[c],  # the light models' inputs, from the light's own parameters (a rectangle's L too)
        }
        for c in range(3)
    )
    shape = light.emitter.get_shape() if light.emitter is not None else None  # point, spot, sun: None
    shadow = hard_shadow(setup, points, normals, towards, dist, radius, shape)
    caveat = small_sphere_caveat(alpha, pooled.mean[:, 0], pooled.stderr[:, 0]) if radius > 0 else ()
    caveat = (*caveat, *_left_out(app))
    params = {
        "light": app.part,
        "kind": light.kind,
        "alpha_max_deg": float(np.degrees(alpha.max())) if alpha.size else 0.0,
        "pixels": int(mask.sum()),
    }
    reason = (
        f"{light.kind} light: Mitsuba emitter sampling of this light alone (Emitter.sample_direction), "
        "white Lambertian receiver at each visible point"
    )
    cases = []
    for k, (what, note, factor) in enumerate(
        (
            ("unshadowed", "the light alone: no occluder between it and the point", None),
            (
                "shadowed",
                "with the scene's own occluders (shadow rays); each method × the hard shadow of the "
                "light's centre, as a shadow map gives it",
                shadow,
            ),
        )
    ):
        ref = pooled.reference(
            mask,
            quantity=f"direct irradiance of one light, {what} (W/m²)",
            integrator="light-irradiance (emitter sampling" + (", shadow rays)" if k else ")"),
            integrator_reason=reason,
            columns=slice(3 * k, 3 * k + 3),
            precision=sphere_sampling_precision(alpha) if radius > 0 else None,
        )
        cases.append(
            FamilyCase(
                id=f"{tag}-{what}",
                label=f"{app.part}, {what}",
                reference=ref,
                channel_inputs=inputs,
                parameters={**params, "shadowing": what},
                factor=factor,
                units="W/m²",
                notes=(note, *caveat),
                params=window_params(dist),
            )
        )
    return cases


def _left_out(app: Applicability) -> tuple[str, ...]:
    """One note naming the light-model rows that do not apply to this light, each with the kind of light it
    needs (`Applicability.excluded`)."""
    left: dict[str, list[str]] = {}
    for m, why in app.excluded:
        if m in LIGHT_MODELS:
            left.setdefault(why.rsplit(": ", 1)[-1], []).append(m)
    if not left:
        return ()
    text = "; ".join(f"{', '.join(ms)} (need {kind})" for kind, ms in left.items())
    return (f"light models left out for this light: {text}",)


def window_params(dist: np.ndarray) -> dict[str, dict[str, Param]]:
    """The windowed falloffs' radius r for this light (`rtfit.realtime.light_models`): no published value
    (an artist sets it per light), so only its fit is shown; the fit starts at 2 × the largest distance from
    the light to a visible point (every pixel inside the window), bounded by [10⁻³, 10³] × that distance."""
    finite = dist[np.isfinite(dist)]
    if not finite.size or float(finite.max()) <= 0.0:
        return {}
    far = float(finite.max())
    r = Param(2.0 * far, 1e-3 * far, 1e3 * far, unit="scene units", published=False,
              description="window radius r: the falloff reaches 0 at d = r")  # fmt: skip
    return {"unreal-window": {"r": r}, "frostbite-window": {"r": r}}


FAMILY = AuditFamily(
    name="diffuse",
    quantity="light_irradiance",
    cases=diffuse_cases,
    describe=(
        "Per light: its direct irradiance E (W/m², RGB) at each visible point, for the point's normal, "
        "unshadowed and shadowed (separate cases), estimated with Mitsuba's emitter sampling of that light "
        "alone and Mitsuba's shadow rays, in independent passes with per-pixel standard errors. Each method "
        "gets cos θ = n·t (t: towards the light's centre), E⊥ (the light's irradiance on a surface facing "
        "t, from independent samples of the same pass), the light's angular radius α (sphere lights; 0 "
        "otherwise) and distance. The light models (punctual inverse square, the Unreal and Frostbite "
        "windows with a fitted radius, the representative point of a sphere, the LTC polygon of a rectangle, "
        "the spot cones) read the light's own parameters instead of E⊥: its intensity or radiance and size, "
        "its rectangle, its cone angles (`rtfit.experiments.audit_lights.light_model_inputs`); a row whose "
        "light lacks them is left out, saying what it needs. "
        "In the shadowed case each method is multiplied by the hard shadow of the light's centre (one "
        "shadow ray), as a shadow map would give it. A sun of finite size (a TOML sun, the sun of a "
        "sunsky) is sampled alone (without its sky) and has α = its angular radius."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "diffuse",
            "direct light",
            ("light", "surface"),
            "{part} lights the visible surfaces directly",
            "that light's direct irradiance at the visible points, unshadowed and shadowed (reported "
            "separately)",
            "direct, that light alone (emitter sampling; shadow rays for the shadowed pass)",
        ),
    ),
)
