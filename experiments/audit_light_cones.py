r"""The ``light-cones`` family in `rtfit audit`: a spot light inside a homogeneous medium, the light its beam
scatters into the camera's rays.

For each spot light of the scene that sits inside a homogeneous medium (a Mitsuba XML ``spot`` in the sensor's
medium or inside a shape that bounds one; an rtfit TOML ``spot_light`` inside a ``homogeneous`` medium's
boundary), one case ``lightK-beam`` on the pixels whose camera ray has a stretch in that medium
(`rtfit.experiments.audit_lit_media`: the same stretches and reference as the volumetric-lightning audit):

* **Reference**: the spot's single-scattered radiance along each stretch (W/m²/sr, RGB), equiangular
  sampling with Mitsuba's own ``spot`` emitter — its falloff linear in the angle between ``beam_width`` and
  ``cutoff_angle``, which the light-cones experiment found — phase function and shadow rays.
* **Rows** (`rtfit.realtime.light_cones.METHODS`) on each pixel's view ray o = o_c + s₀ω, ω, with the depth
  test at the stretch's end (depth = s₁ − s₀), the spot's apex P and axis a (Mitsuba's ``to_world``), the
  shell's half-angle θ_½ = (θ_b + θ_c)/2 (the experiment's: the half-intensity angle of the linear ramp,
  where an artist puts the mesh) and the cone length L: the distance from the apex along the axis to the
  first opaque surface or the medium's end (else the scene's bounding-box diagonal), clipped to the
  methods' domain [1e-3, 100] m. ``chord`` (§1's integral over the chord, hard edge, no extinction) with the
  physical K = σ_s·I/(4π) (the channels' mean); the shells (``shell``: both faces, ``shell-front``) with
  the seed's p = 1, q = 2 and the level k₀ = 8K·tan θ_½/L at which a ray crossing the beam perpendicularly at
  mid-length gets the chord's radiance (two fragments of |n·ω| ≈ 1, v² = 1/4); each then fitted to this
  scene (k; k, p, q). The exact row ``quadrature`` (`rtfit.realtime.light_cones.QUADRATURE`) is
  `rtfit.reference.single_scattering.spot_single_scattering` per channel with Mitsuba's profile, the
  medium's σ_s, σ_t and Henyey–Greenstein g over the same stretch (no visibility): it must sit at the
  reference's noise where nothing shadows the medium.
* Your approximations of ``spot_inscattered_radiance`` get the methods' inputs plus ``intensity`` (on the
  axis), ``sigma_s``, ``sigma_t`` (per channel) and ``g``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime.arrays import xyz_columns
from rtfit.realtime.light_cones import METHODS
from rtfit.reference.medium_lights import medium_segments
from rtfit.reference.single_scattering import spot_single_scattering

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_lit_media import (
    LitMedium,
    Stretches,
    inscatter,
    inscatter_case,
)
from .audit_setup import AuditSetup
from .shipped import ShippedScene, Sizes

__all__ = ["FAMILY", "SCENES", "SIGMAS_T", "VIEWS", "cone_cases"]

VIEWS = {
    "beside": ("0, -9, 3", "0, 0, 3", "0, 0, 1"),
    "oblique": ("-5, -8, 1", "0, 0, 3.5", "0, 0, 1"),
    "inside": ("0.5, -0.5, 1", "0.5, 6, 1.5", "0, 0, 1"),
    "up-axis": ("0, 0, 0.4", "0, 0, 6", "0, 1, 0"),
    "down-axis": ("0, 0, 10", "0, 0, 0", "0, 1, 0"),
}
"""The shipped scenes' cameras (origin, target, up; m) in scenes/library/light_cones_spot.xml, whose lamp
hangs at (0, 0, 6) pointing down: beside the cone (view ⟂ axis), oblique from below, inside the cone looking
out through the shell, up the axis at the lamp from inside, down the axis through the apex."""
SIGMAS_T = (0.01, 0.05, 0.2)
"""The media's extinction σ_t = σ_s (1/m, albedo 1) of the shipped scenes: thin to dense."""
QUICK = {"views": ("beside", "inside", "up-axis"), "sigma_t": (0.05,)}
"""Those ``--quick`` audits (as the experiment before the engine)."""


_sizes = Sizes(full=(96, 72, 4096), quick=(24, 18, 1024))


def _scene(view: str, sigma_t: float) -> ShippedScene:
    origin, target, up = VIEWS[view]
    return _sizes.scene(
        "light_cones_spot.xml",
        f"street lamp (spot, cutoff 30°, beam 22.5°, 100 W/sr, 6 m up) seen {view}, σ_t = {sigma_t:g} /m, "
        "albedo 1",
        defines={"origin": origin, "target": target, "up": up, "sigma_t": f"{sigma_t:g}"},
        name=f"{view}-s{sigma_t:g}".replace(".", "p"),
        quick=view in QUICK["views"] and sigma_t in QUICK["sigma_t"],
    )


SCENES = tuple(_scene(v, s) for s in SIGMAS_T for v in VIEWS)
"""The scenes ``rtfit run light-cones`` audits (scenes/library/light_cones_spot.xml, one per view and σ_t): a
street lamp in a non-absorbing homogeneous medium that fills a 24 × 24 × 12 m box around the camera, its
floor the cone's base, nothing else (the cases of the experiment before the engine)."""

LENGTH_DOMAIN = (1e-3, 100.0)
"""The cone length's interval (m): the methods' declared domain of ``length``."""


def cone_length(setup: AuditSetup, lit: LitMedium) -> float:
    """The shell mesh's length L (module docstring): from the apex along the axis to the first opaque
    surface or the medium's end, else the bounding-box diagonal; clipped to `LENGTH_DOMAIN`."""
    axis = np.asarray(lit.axis, np.float64)[None, :]
    _, end = medium_segments(setup.mi, lit.scene, lit.position, axis, lit.medium, True)
    length = float(end[0])
    if not (math.isfinite(length) and length > 0.0):
        length = setup.info.diagonal or LENGTH_DOMAIN[1]
    return min(max(length, LENGTH_DOMAIN[0]), LENGTH_DOMAIN[1])


def _quadrature(lit: LitMedium, rays: Stretches, c: int) -> np.ndarray:
    """The exact row's values on channel ``c`` (W/m²/sr; `spot_single_scattering` over each stretch)."""
    return spot_single_scattering(
        rays.origin, rays.dirs, rays.end, lit.position, lit.axis, math.radians(lit.cutoff_deg),
        math.radians(lit.beam_deg), float(lit.intensity[c]), float(lit.sigma_s[c]), float(lit.sigma_t[c]),
        start=rays.start, g=lit.g,
    )  # fmt: skip


def _row_params(k: float, half_angle: float, length: float) -> dict[str, dict[str, Param]]:
    """The rows' given values (module docstring) as the starts of their fits, within the declared bounds."""
    shell = METHODS["shell"].params
    k0 = 8.0 * k * math.tan(half_angle) / length
    shells = {
        "k": dataclasses.replace(shell["k"], initial=k0),
        "p": dataclasses.replace(shell["p"], initial=1.0),
        "q": dataclasses.replace(shell["q"], initial=2.0),
    }
    chord = {"k": dataclasses.replace(METHODS["chord"].params["k"], initial=k)}
    return {"shell": shells, "shell-front": shells, "chord": chord}


def cone_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case: the spot's in-scattered radiance along the camera's stretches in its medium (module
    docstring)."""
    case = inscatter(setup, app, "spot")
    lit, rays = case.lit, case.rays
    half_angle = math.radians(0.5 * (lit.cutoff_deg + lit.beam_deg))
    length = cone_length(setup, lit)
    start = rays.segment_start
    n = len(rays.start)
    axis = np.asarray(lit.axis, np.float64)
    geometry = {
        **xyz_columns("o", start),
        **xyz_columns("w", rays.dirs),
        **{f"p{x}": np.full(n, lit.position[k]) for k, x in enumerate("xyz")},
        **{f"a{x}": np.full(n, axis[k]) for k, x in enumerate("xyz")},
        "half_angle": np.full(n, half_angle),
        "length": np.full(n, length),
        "depth": rays.end - rays.start,
    }
    parameters = {
        "axis": [float(x) for x in axis],
        "cutoff_deg": lit.cutoff_deg,
        "beam_width_deg": lit.beam_deg,
        "shell_half_angle_deg": math.degrees(half_angle),
        "cone_length_m": length,
    }
    notes = (
        f"the shell mesh: half-angle θ_½ = {math.degrees(half_angle):.4g}° (between beam width "
        f"{lit.beam_deg:.4g}° and cutoff {lit.cutoff_deg:.4g}°), length {length:.4g} m",
    )
    exact = [_quadrature(lit, rays, c) for c in range(3)]
    params = _row_params(case.k, half_angle, length)
    return [inscatter_case(app, case, "beam", geometry, exact, parameters, notes, params)]


FAMILY = AuditFamily(
    name="light-cones",
    quantity="spot_inscattered_radiance",
    cases=cone_cases,
    describe=(
        "Per spot light inside a homogeneous medium, on the pixels whose camera ray has a stretch in that "
        "medium (the first one, before an opaque surface): the spot's single-scattered radiance along the "
        "stretch (W/m²/sr, RGB), estimated by equiangular sampling about the light with Mitsuba's own spot "
        "emitter (falloff linear in the angle), phase function and shadow rays, against the seed's "
        "pseudo-volumetric cone shell (both faces and front faces: k, p, q) and §1's integral over the "
        "chord (K) on the view ray with the stretch's end as its depth, the shell at the half-intensity "
        "angle, with the scene's values and fitted; the exact row is the quadrature of the spot's single "
        "scattering with extinction and the medium's phase function (rtfit.reference.single_scattering), "
        "which must sit at the reference's noise where nothing shadows the medium."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "light-cones",
            "spot light in a medium",
            ("spot-in-medium",),
            "{part}: its beam scatters into the camera's rays",
            "that spot's single-scattered radiance along the camera's rays in the medium (W/m²/sr, RGB)",
            "equiangular sampling about the light with Mitsuba's emitter (its linear-in-angle falloff), "
            "phase function and shadow rays; the quadrature of rtfit.reference.single_scattering as the "
            "exact row",
        ),
    ),
)
