r"""The ``nishita-sky`` family in `rtfit audit`: the sky of an rtfit sky file along its camera's sky pixels.

An rtfit sky file (``format = "rtfit.sky/1"``, `rtfit.reference.nishita_sky.load_atmosphere_scene`: planet,
spherical-shell Rayleigh + Mie atmosphere, sun, viewer altitude) has no camera of its own; the audit's camera
is the azimuth × elevation panorama of the upper hemisphere the Nishita-sky experiment renders
(`rtfit.experiments.audit_run.sky_view`, `hemisphere_directions`: the sun at azimuth 0, every pixel a sky
pixel; ``--width``/``--height`` set its size). One case, ``sky``:

* reference: the sky radiance L (W/m²/sr per the file's solar irradiance, RGB: the file's three
  wavelengths) along each pixel's direction from the viewer, single and multiple scattering with the ground
  bounce (`rtfit.reference.nishita_sky.render_sky`, ``rtfit_skypath`` in the shell atmosphere, ``max_depth``
  −1, its own pass cache), the experiment's multiple-scattering reference; pixels within 1° of the sun are
  left out (`rtfit.experiments.sky_rows.near_sun`: the disc is a separate term);
* rows (`rtfit.experiments.sky_rows.nishita_rows`, shared with the sunsky role): every RGB method of
  `rtfit.realtime.nishita_sky.METHODS` (the seed setting, the fine setting, the fitted artist parameters;
  not the spectral variant, ``SPECTRAL_NOTE``) with the file's atmosphere and
  viewer altitude in its fixed keywords (`atmosphere_params_of`), each on the kernel inputs of its own
  texture setting (`sky_kernel_inputs`: texel directions and sun optical-depth tables; a setting other than
  the seed's gets those inputs under names of its own, `setting_method`); ``nishita-fitted``'s artist
  parameters (Rayleigh scale, Mie density scale, Mie g, isotropic ambient) are fitted to this sky through
  the JAX run of the same kernel; and your approximations of ``sky_radiance`` (inputs dx, dy, dz: the unit
  view direction; sx, sy, sz: the unit direction to the sun; altitude: the viewer's, m).

``rtfit run nishita-sky`` is this audit on the sky files the family ships (`SCENES`: one per sun elevation)
plus its study (`rtfit.experiments.nishita_sky_study`: single-scattering references and the independent
quadrature, viewer altitude, the spectral reference, the layer/texture/table sweep, the sun's disc).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rtfit.realtime.nishita_sky import AtmosphereParams
from rtfit.reference.nishita_sky import render_sky

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditReference, AuditSetup
from .case_inputs import masked_image
from .shipped import ShippedScene
from .sky_rows import SPECTRAL_NOTE, TEXTURE_UNCOSTED, near_sun, nishita_rows, texture_precomputes

__all__ = ["FAMILY", "ROLE", "SCENES", "SUN_ELEVATIONS_DEG", "atmosphere_params_of", "sky_cases"]

SUN_ELEVATIONS_DEG = (90.0, 45.0, 10.0, 2.0, 0.0, -4.0)
"""The sun elevations of the shipped sky files (scenes/library/sky_sun_<e>.toml, ``m4`` for −4°)."""
QUICK = (45.0, 10.0, -4.0)
TWILIGHT_SPP_FACTOR = 4
"""The quick run's samples below the horizon: at 256 spp the −4° multiple-scattering reference has 65 %
per-pixel noise and the artist fit ended on the bound ambient = 0; at 1024 spp its optimum is interior
(docs/nishita-sky.md)."""


def _sky_scene(e: float) -> ShippedScene:
    stem = f"sky_sun_{e:g}".replace("-", "m")
    return ShippedScene(
        f"{stem}.toml",
        f"Bruneton's atmosphere (no ozone), viewer 10 m, sun at {e:g}°",
        size=(128, 64),
        spp=4096,
        quick_size=(32, 16),
        quick_spp=256 * (TWILIGHT_SPP_FACTOR if e < 0 else 1),
        name=stem,
        quick=e in QUICK,
    )


SCENES = tuple(_sky_scene(e) for e in SUN_ELEVATIONS_DEG)
"""The sky files ``rtfit run nishita-sky`` audits (the azimuth × elevation panorama of each, 128×64 at 4096
spp; ``--quick``: 45°, 10°, −4° at 32×16, 256 spp and 4× that below the horizon)."""


def atmosphere_params_of(spec) -> AtmosphereParams:
    """The real-time model's atmosphere for a reference `AtmosphereSpec` (any sky file): the fields both
    carry, by name (the viewer and the sun are not atmosphere parameters)."""
    shared = {f.name for f in dataclasses.fields(AtmosphereParams)} & set(vars(spec))
    return AtmosphereParams(**{k: getattr(spec, k) for k in sorted(shared)})


def sky_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The sky case of the file's atmosphere (module docstring)."""
    spec = setup.source
    if spec is None or not hasattr(spec, "sun_elevation_deg"):
        raise AuditError(
            f"nishita-sky: {app.part}: the audit reads the sky from rtfit sky files (rtfit.sky/1)"
        )
    elev = float(spec.sun_elevation_deg)
    alt = float(spec.viewer_altitude_m)
    dirs = setup.gbuffer.view_dir.astype(np.float64)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    mask = ~setup.gbuffer.mask & ~near_sun(dirs, elev)
    if not mask.any():
        raise AuditError("nishita-sky: every pixel of the panorama lies within 1° of the sun")
    d = dirs[mask]
    ref = render_sky(
        spec, d, setup.spp, setup.pass_spp, setup.seed, setup.variant, -1, cache_dir=setup.cache_root
    )
    inputs, rows = nishita_rows(atmosphere_params_of(spec), elev, d, alt)
    reference = AuditReference(
        mean=masked_image(mask, ref["mean"]),
        stderr=masked_image(mask, ref["stderr"]),
        spp=int(ref["spp"]),
        passes=int(ref["passes"]),
        passes_rendered=int(ref["passes"]),
        cache_key=str(ref["cache_key"]),
        cache_path=str(setup.cache_root),
        seconds=float(ref["seconds"]),
        quantity="sky radiance along the panorama's directions, single + multiple scattering (RGB)",
        integrator="rtfit_skypath (max_depth −1) in the spherical-shell atmosphere",
        integrator_reason="media with chromatic extinction; all scattering orders and the ground bounce",
        mask=mask,
    )
    return [
        FamilyCase(
            id="sky",
            label=f"sky, sun {elev:g}°, viewer {alt:g} m",
            reference=reference,
            channel_inputs=(inputs,),
            parameters={
                "sun_elevation_deg": elev,
                "viewer_altitude_m": alt,
                "pixels": int(mask.sum()),
                "panorama": [int(mask.shape[1]), int(mask.shape[0])],
            },
            units="W/m²/sr",
            notes=(
                "pixels within 1° of the sun are left out (the sun disc is a separate term)",
                SPECTRAL_NOTE,
            ),
            methods=rows,
            uncosted=dict.fromkeys(rows, TEXTURE_UNCOSTED),
            precompute=texture_precomputes(atmosphere_params_of(spec), elev, alt, rows, setup.variant),
        )
    ]


ROLE = "sky"
"""The applicability role (`rtfit.experiments.families.RULES`) this module audits: an rtfit sky file's
atmosphere (a Mitsuba sky emitter's role is `rtfit.experiments.audit_sky_emitter`'s)."""

FAMILY = AuditFamily(
    name="nishita-sky",
    quantity="sky_radiance",
    cases=sky_cases,
    describe=(
        "The sky radiance (RGB) of the file's atmosphere along the directions of an azimuth × elevation "
        "panorama of the upper hemisphere (sun at azimuth 0), seen from the file's viewer: Mitsuba's "
        "rtfit_skypath in the spherical-shell Rayleigh + Mie atmosphere with all scattering orders (the "
        "Nishita-sky experiment's multiple-scattering reference), pixels within 1° of the sun left out. "
        "Every Nishita method runs with the file's atmosphere and altitude on its own texture setting; the "
        "fitted method's artist parameters are fitted to this sky."
    ),
    formats=("rtfit-sky",),
    rules=(
        Rule(
            "nishita-sky",
            "sky",
            ("atmosphere",),
            "{part} fills the camera's sky pixels",
            "sky radiance along the camera's sky pixels (single and multiple scattering)",
            "volpathmis in the spherical-shell atmosphere",
        ),
    ),
)
