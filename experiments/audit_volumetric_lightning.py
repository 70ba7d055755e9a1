r"""The ``volumetric-lightning`` family in `rtfit audit`: a point light inside a homogeneous medium, the light
it scatters into the camera's rays.

For each point light of the scene that sits inside a homogeneous medium (`rtfit.experiments.audit`: a Mitsuba
XML ``point`` emitter in the sensor's medium or inside a shape that bounds one, `XmlEmitter.medium`; an rtfit
TOML ``point_light`` inside a ``homogeneous`` medium's boundary), one case ``lightK-inscatter`` on the pixels
whose camera ray has a stretch in that medium:

* **Geometry** (`rtfit.reference.medium_lights`, on the Mitsuba scene: the XML file as loaded, a TOML scene
  built with its media): the camera's position o_c (a perspective sensor's ``to_world``), the pixel-centre
  view directions ω of the audit's G-buffer, and per pixel the first stretch [s₀, s₁] of the ray inside the
  light's medium before the first surface that is not ``null`` (`medium_segments`); pixels whose ray never
  enters the medium, or leaves the scene inside it (an unbounded stretch), are left out.
* **Reference**: the light's single-scattered radiance along the stretch (W/m²/sr, RGB), by equiangular
  sampling about the light with Mitsuba's own emitter sample (``I(ω)/r²``), phase function and shadow rays,
  the homogeneous transmittance of both legs in closed form (`inscatter_pass`), in passes through the pass
  cache with per-pixel standard errors.
* **Rows**: the methods of `rtfit.realtime.volumetric_lightning.METHODS` (``stable``, ``seed``: the seed's
  softened light, parameters i, a; ``inverse-square``: single scattering without extinction, K), each on the
  segment o = o_c + s₀ω, d = (s₁ − s₀)ω and the light's position l, evaluated with the scene's values —
  K = σ_s·I/(4π) (the channels' mean), and for the seed's model the experiment's start a₀ = 100/D²
  (core radius D/10, D the camera-to-light distance), i₀ = a₀·K — then fitted to this scene
  (`rtfit.experiments.scattering_reference.fit_params`' bounds for (i, a)). The shipped rows carry one level
  for the three channels: a coloured light or medium leaves them a colour error. The exact row
  ``quadrature`` (`QUADRATURE`) is `rtfit.reference.single_scattering.point_single_scattering` per channel
  with the medium's σ_s, σ_t and Henyey–Greenstein g over the same stretch, no visibility: the engine's
  self-check requires its z-scores against the reference to be standard normal — true where nothing
  shadows the medium from the light (a shape between them darkens the reference only).
* Your approximations of ``inscattered_radiance`` get ox…dz (the segment), lx, ly, lz, ``intensity``,
  ``sigma_s``, ``sigma_t`` (per channel) and ``g``.

Assumptions (named in each case's notes): the light-to-point segment stays inside the medium (a convex
boundary around the light, or the sensor's unbounded medium); a medium seen through a non-null boundary
(glass) has no stretch here (its rays refract).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime.arrays import xyz_columns
from rtfit.realtime.volumetric_lightning import METHODS
from rtfit.reference.single_scattering import point_single_scattering

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_lit_media import (
    LitMedium,
    Stretches,
    inscatter,
    inscatter_case,
    light_parameters,
)
from .audit_setup import AuditSetup
from .scattering_reference import fit_params
from .shipped import ShippedScene, Sizes

__all__ = ["DISTANCES_M", "FAMILY", "SCENES", "SIGMAS_T", "lightning_cases"]

DISTANCES_M = (1.0, 4.0, 16.0, 32.0)
"""The light's distance scale D (m) of the shipped scenes: the light at D·(0.1, 1, 0.04), I = D² W/sr."""
SIGMAS_T = (0.002, 0.01, 0.05)
"""The media's extinction σ_t = σ_s (1/m, albedo 1) of the shipped scenes: thin to dense."""
QUICK = {"D": (4.0, 16.0), "sigma_t": (0.01, 0.05)}
"""Those ``--quick`` audits (as the experiment before the engine)."""


_sizes = Sizes(full=(96, 64, 4096), quick=(24, 16, 512))


def _scene(distance: float, sigma_t: float) -> ShippedScene:
    return _sizes.scene(
        "volumetric_lightning_point.xml",
        f"point light at D = {distance:g} m (I = D² W/sr) in a medium of σ_t = {sigma_t:g} /m, albedo 1",
        defines={"D": f"{distance:g}", "intensity": f"{distance * distance:g}", "sigma_t": f"{sigma_t:g}"},
        name=f"D{distance:g}-s{sigma_t:g}".replace(".", "p"),
        quick=distance in QUICK["D"] and sigma_t in QUICK["sigma_t"],
    )


SCENES = tuple(_scene(d, s) for d in DISTANCES_M for s in SIGMAS_T)
"""The scenes ``rtfit run volumetric-lightning`` audits (scenes/library/volumetric_lightning_point.xml, one
per (D, σ_t)): an isotropic point light in a non-absorbing homogeneous medium that fills a 40 × 41 × 40 m box
around the camera, nothing else (the cases of the experiment before the engine). Each view ray's stretch
runs from the camera to the box's far wall."""


def _quadrature(lit: LitMedium, rays: Stretches, c: int) -> np.ndarray:
    """The exact row's values on channel ``c`` (W/m²/sr; `point_single_scattering` over each stretch)."""
    return point_single_scattering(
        rays.origin, rays.dirs, rays.end, lit.position, float(lit.intensity[c]), float(lit.sigma_s[c]),
        float(lit.sigma_t[c]), start=rays.start, g=lit.g,
    )  # fmt: skip


def _row_params(k: float, distance: float, sigma_s: float, intensity: float) -> dict[str, dict[str, Param]]:
    """The rows' given values and fit bounds (module docstring)."""
    # (a camera on the light: the start's core radius D/10 needs some D)
    seed_model = fit_params({"distance": max(distance, 1e-3), "sigma_s": sigma_s, "intensity": intensity})
    k_param = dataclasses.replace(METHODS["inverse-square"].params["k"], initial=k)
    return {"stable": seed_model, "seed": seed_model, "inverse-square": {"k": k_param}}


def lightning_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case: the light's in-scattered radiance along the camera's stretches in its medium (module
    docstring)."""
    case = inscatter(setup, app, "point")
    lit, rays = case.lit, case.rays
    start = rays.segment_start
    seg = (rays.end - rays.start)[:, None] * rays.dirs
    n = len(rays.start)
    geometry = {
        **xyz_columns("o", start),
        **xyz_columns("d", seg),
        **{f"l{x}": np.full(n, lit.position[k]) for k, x in enumerate("xyz")},
    }
    exact = [_quadrature(lit, rays, c) for c in range(3)]
    distance = light_parameters(lit, rays)["camera_to_light_m"]
    params = _row_params(case.k, distance, float(np.mean(lit.sigma_s)), float(np.mean(lit.intensity)))
    return [inscatter_case(app, case, "inscatter", geometry, exact, {}, (), params)]


FAMILY = AuditFamily(
    name="volumetric-lightning",
    quantity="inscattered_radiance",
    cases=lightning_cases,
    describe=(
        "Per point light inside a homogeneous medium, on the pixels whose camera ray has a stretch in "
        "that medium (the first one, before an opaque surface): the light's single-scattered radiance "
        "along the stretch (W/m²/sr, RGB), estimated by equiangular sampling about the light with "
        "Mitsuba's own emitter, phase function and shadow rays, against the seed's softened point light "
        "(stable and printed forms, i and a) and single scattering without extinction (K) on the "
        "stretch's segment, with the scene's values and fitted; the exact row is the Gauss–Legendre "
        "quadrature of single scattering with extinction and the medium's phase function "
        "(rtfit.reference.single_scattering), which must sit at the reference's noise where nothing "
        "shadows the medium."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "volumetric-lightning",
            "point light in a medium",
            ("point-in-medium",),
            "{part}: its light scatters into the camera's rays",
            "that light's single-scattered radiance along the camera's rays in the medium (W/m²/sr, RGB)",
            "equiangular sampling about the light with Mitsuba's emitter, phase function and shadow rays; "
            "the quadrature of rtfit.reference.single_scattering as the exact row",
        ),
    ),
)
