r"""The ``nishita-sky`` family in `rtfit audit`, role "sky emitter": the Nishita texture fitted to a sunsky.

A Mitsuba ``sunsky`` emitter (Hosek–Wilkie sky + sun; in a Mitsuba XML scene, or a ``sunsky`` light of an
rtfit TOML scene as rtfit builds it for Mitsuba) is a sky the user already has; the question the audit answers
is *which Nishita parameters best match it, and how far the best is from it*. One case, ``sky``,
per sunsky the scene holds (the rule's ``sky`` part, `rtfit.experiments.families.RULES`):

* **sky pixels**: the pixels whose pixel-centre camera ray escapes the scene (``~gbuffer.mask``; their view
  directions ``gbuffer.view_dir``), above the sky's horizon (Mitsuba's sunsky is 0 below it and the Nishita
  texture covers the upper hemisphere) and more than 1° from the sun (`near_sun` of
  `rtfit.experiments.sky_rows`: the sun's disc, 0.27° in radius, is the diffuse family's case of the
  sunsky's sun);
* **the sky's frame**: its zenith z = to_world·(0, 0, 1) (the sunsky's local +Z is up), the sun's direction
  s from the emitter's own ``sun_direction`` (world space, `mi.traverse`), x the horizontal part of s
  (any horizontal axis with the sun at the zenith), y = z × x: a direction d is (d·x, d·y, d·z) in the
  Nishita frame (+Z up, sun at azimuth 0), the sun's elevation asin(s·z);
* **reference**: the emitter's radiance along each sky pixel's ray, ``emitter.eval`` of Mitsuba's own
  sunsky (RGB, its units): a closed-form function of the direction, **deterministic: its noise floor is
  zero** (stderr 0; the metrics keep only the float32 precision floor). It is what Mitsuba's own render of
  those pixels converges to (the camera ray escapes, the integrator adds the environment's ``eval``),
  which the tests check against ``mi.render`` with the ``direct`` integrator;
* **rows**: every RGB method of `rtfit.realtime.nishita_sky.METHODS` (`nishita_rows`; not the spectral one,
  `SPECTRAL_NOTE`) with the published atmosphere (`AtmosphereParams()`: Bruneton's set), the viewer on the
  ground (altitude 0: the sunsky is at infinity) and the sunsky's sun: ``nishita-seed`` and ``nishita-fine``
  are the declared rows (E₀ as published: a sunsky in other units shows here as a scale error);
  ``nishita-fitted`` gets, besides its artist parameters (Rayleigh scale, Mie density scale — the
  turbidity-like knob — Mie g, isotropic ambient), the sun's intensity scale ``solar_scale`` (E₀ → s_E E₀,
  `nishita_sky_kernel`), all fitted to this sky by the audit (its ``nishita-fitted-fitted`` row);
  your approximations of ``sky_radiance`` get dx, dy, dz, sx, sy, sz (the Nishita frame) and altitude 0.

A sun below the horizon: Mitsuba's sunsky is then black (it warns "the sun is below the horizon"), the
reference is 0 and the fit drives ``solar_scale`` to its lower bound; every row stays finite.
"""

from __future__ import annotations

import dataclasses
import math
import time

import drjit as dr
import numpy as np

from rtfit.realtime.methods import Param
from rtfit.realtime.nishita_sky import AtmosphereParams

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditReference, AuditSetup
from .sky_rows import SPECTRAL_NOTE, TEXTURE_UNCOSTED, near_sun, nishita_rows, texture_precomputes

__all__ = ["FAMILY", "ROLE", "SOLAR_SCALE", "emitter_radiance", "sky_emitter_cases", "sky_frame"]

ROLE = "sky emitter"
"""The applicability role (`rtfit.experiments.families.RULES`) this module audits."""

SOLAR_SCALE = Param(
    1.0, 1e-6, 1e6, unit="1", description="multiplies the solar irradiance E0 (the sky's intensity)"
)
"""The sun's intensity scale added to ``nishita-fitted``'s fit: starts at the published E₀ (1); its bounds
span a sky in any units (a sunsky's RGB radiance, ~0.1 at the zenith, against E₀ ≈ 1.5–1.9 W/m²/nm)."""

SUN_EXCLUSION_DEG = 1.0
"""Pixels within this angle of the sun are left out: the disc (0.27° for Mitsuba's default aperture) and its
limb are the sun's own term, not the sky's."""


def emitter_radiance(mi, emitter, dirs: np.ndarray) -> np.ndarray:
    """The emitter's radiance (N, 3) arriving along unit world ``dirs`` (N, 3), i.e. seen looking towards
    ``dirs``: ``emitter.eval`` at an interaction whose ``wi`` is −d (what a path tracer adds for a camera
    ray that escapes in direction d). Float32 inside Mitsuba; returned as float64."""
    si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
    si.wi = mi.Vector3f(np.ascontiguousarray(-dirs.T, dtype=np.float32))
    return np.array(emitter.eval(si), dtype=np.float64).T.reshape(len(dirs), 3)


def sky_frame(mi, emitter) -> tuple[np.ndarray, float]:
    """(3, 3) rows x, y, z of the sky's frame in world space and the sun's elevation in degrees (module
    docstring): z the sunsky's zenith (its ``to_world`` applied to local +Z), x towards the sun's azimuth."""
    params = mi.traverse(emitter)
    m = np.array(params["to_world"].matrix, np.float64).reshape(4, 4)
    z = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    z /= np.linalg.norm(z)
    s = np.array(params["sun_direction"], np.float64).reshape(-1)[:3]
    s /= np.linalg.norm(s)
    h = s - (s @ z) * z
    if np.linalg.norm(h) < 1e-9:  # the sun at the zenith: every azimuth is the sun's; take any horizontal
        h = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = h / np.linalg.norm(h)
    y = np.cross(z, x)
    elev = math.degrees(math.asin(float(np.clip(s @ z, -1.0, 1.0))))
    return np.stack([x, y, z]), elev


def _sunsky(setup: AuditSetup, app: Applicability):
    """The Mitsuba sunsky the applicability names (`Part.source`: its index in the XML scene's emitters), else
    the scene's environment (a TOML scene: rtfit's Mitsuba build has one); an `AuditError` where it is not a
    sunsky."""
    k = app.source
    emitter = setup.emitters[k] if k is not None and 0 <= k < len(setup.emitters) else None
    if emitter is None and setup.scene is not None:
        emitter = setup.scene.environment()
    if emitter is None or "sun_direction" not in setup.mi.traverse(emitter):
        raise AuditError(f"nishita-sky: {app.part} is not a sunsky emitter of the loaded scene")
    return emitter


def sky_emitter_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The sky case of the scene's sunsky (module docstring); none where the camera sees no sky pixel
    above its horizon and away from its sun."""
    mi = setup.mi
    emitter = _sunsky(setup, app)
    frame, elev = sky_frame(mi, emitter)
    world = setup.gbuffer.view_dir.astype(np.float64)
    world /= np.maximum(np.linalg.norm(world, axis=-1, keepdims=True), 1e-30)
    local = world @ frame.T  # (H, W, 3) in the Nishita frame
    mask = ~setup.gbuffer.mask & (local[..., 2] > 0.0) & ~near_sun(local, elev, SUN_EXCLUSION_DEG)
    if not mask.any():
        return []
    t0 = time.perf_counter()
    ref = emitter_radiance(mi, emitter, world[mask])
    seconds = time.perf_counter() - t0
    d = local[mask]
    inputs, rows = nishita_rows(AtmosphereParams(), elev, d, 0.0)
    fitted = rows["nishita-fitted"]
    rows["nishita-fitted"] = dataclasses.replace(fitted, params={**fitted.params, "solar_scale": SOLAR_SCALE})
    params = mi.traverse(emitter)
    knobs = {k: float(np.asarray(params[k]).reshape(-1)[0]) for k in ("turbidity", "sky_scale", "sun_scale")}
    reference = AuditReference.deterministic(
        mask,
        ref,
        (setup.scene_digest, app.part, knobs, elev),
        seconds,
        "the sunsky's sky radiance along the camera's sky pixels (RGB, the emitter's units)",
        "emitter.eval of the scene's sunsky along each pixel-centre ray (no sampling, not cached)",
        "the emitter is a closed-form function of direction: deterministic, noise floor "
        "zero; what any integrator's render of an escaping camera ray converges to",
    )
    return [
        FamilyCase(
            id="sky-emitter" if app.source is None else f"sky-emitter-{app.source}",
            label=f"sunsky sky, sun {elev:.3g}°",
            reference=reference,
            channel_inputs=(inputs,),
            parameters={"sun_elevation_deg": elev, "pixels": int(mask.sum()), **knobs},
            units="W/m²/sr",
            notes=(
                "the reference is Mitsuba's emitter.eval along each ray: deterministic, its noise floor is "
                "zero (only the float32 precision floor remains)",
                f"pixels within {SUN_EXCLUSION_DEG:g}° of the sun and below the sky's horizon are left out",
                "nishita-fitted also fits solar_scale (E0 → s·E0): the sunsky's units are not the Nishita "
                "sky's; the declared rows keep the published E0",
                SPECTRAL_NOTE,
            ),
            methods=rows,
            uncosted=dict.fromkeys(rows, TEXTURE_UNCOSTED),
            precompute=texture_precomputes(AtmosphereParams(), elev, 0.0, rows, setup.variant),
        )
    ]


FAMILY = AuditFamily(
    name="nishita-sky",
    quantity="sky_radiance",
    cases=sky_emitter_cases,
    describe=(
        "A Mitsuba sunsky's sky radiance (RGB) along the camera's sky pixels (rays that escape the scene, "
        "above the sky's horizon, more than 1° from its sun), from the emitter's own eval: deterministic, "
        "noise floor zero. Every RGB Nishita method runs with the published atmosphere, the viewer on the "
        "ground and the sunsky's own sun direction; nishita-fitted's artist parameters and the sun's "
        "intensity scale (solar_scale) are fitted to this sky: which Nishita parameters best match it."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "nishita-sky",
            "sky emitter",
            ("sky",),
            "{part} fills the camera's sky pixels: which Nishita parameters best match it",
            "the emitter's own sky radiance along the camera's sky pixels above its horizon (RGB; pixels "
            "within 1° of its sun left out: the sun's disc is the diffuse family's)",
            "none: Mitsuba's emitter evaluated along each pixel-centre ray (emitter.eval, deterministic: "
            "noise floor zero)",
        ),
    ),
)
