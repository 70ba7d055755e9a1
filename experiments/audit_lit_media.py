r"""What the volumetric-lightning and light-cones audits share (neither imports the other): a point or spot
light inside a homogeneous medium of the user's scene, the camera rays' stretches in that medium, and the
light's single-scattered radiance along them as the case's reference.

* `lit_medium` — the light ``app.source`` as a Mitsuba emitter on the scene to trace (a Mitsuba XML file as
  loaded; an rtfit TOML scene built with its media, since the audit's own build of it leaves them out), its
  position, axis and angles (a spot's Mitsuba ``cutoff_angle``/``beam_width``, degrees), its constant
  intensity (W/sr, RGB), the medium it sits in (`rtfit.reference.mitsuba_xml.point_medium`) and the
  medium's σ_t, albedo and Henyey–Greenstein g (`rtfit.reference.medium_lights.medium_parameters`).
* `stretches` — the camera's position (a perspective sensor's ``to_world``), the audit G-buffer's
  pixel-centre view directions and each pixel's first stretch [s₀, s₁] of its ray inside the medium
  (`medium_segments`); pixels whose ray never enters it or leaves the scene inside it are left out.
* `inscatter_reference` — the light's single-scattered radiance along the stretches (W/m²/sr, RGB), by
  `rtfit.reference.medium_lights.inscatter_pass` (equiangular sampling with Mitsuba's emitter, phase
  function and shadow rays; a spot's distances drawn inside its cutoff cone widened by
  `WINDOW_MARGIN_DEG`, `cone_window`) in passes through the pass cache.
* `inscatter` and `inscatter_case` — a family's one case per light: the three above and the shipped rows'
  one level K, then the case itself around the family's own geometry inputs, exact values and parameters.
* `quantity_inputs` — the inputs every in-scattering quantity gives a user's approximation per channel:
  ``intensity``, ``sigma_s``, ``sigma_t`` and ``g``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.cache import array_digest
from rtfit.reference.medium_lights import (
    camera_origin,
    cone_window,
    inscatter_pass,
    medium_parameters,
    medium_segments,
    point_medium,
)
from rtfit.reference.single_scattering import FOUR_PI

from .audit import Applicability, AuditError
from .audit_family import FamilyCase
from .audit_setup import AuditReference, AuditSetup, pooled_passes

__all__ = [
    "NOTES",
    "Inscatter",
    "LitMedium",
    "Stretches",
    "inscatter",
    "inscatter_case",
    "inscatter_reference",
    "light_parameters",
    "lit_medium",
    "quantity_inputs",
    "stretches",
]

FORMAT = 1
WINDOW_MARGIN_DEG = 1.0
"""A spot's distances are drawn inside its cutoff cone widened by this angle (`cone_window`): a margin
against rounding at the cone's edge; the integrand is exactly 0 beyond the cutoff (Mitsuba's ``spot``)."""


@dataclasses.dataclass(frozen=True)
class LitMedium:
    """A light in its medium on a Mitsuba scene: ``scene`` (the one to trace), ``emitter``, ``position`` (m),
    ``axis`` (unit, the way a spot points; None for a point light), ``cutoff_deg``/``beam_deg`` (a spot's),
    ``intensity`` I (3,) W/sr, the ``medium`` and its ``sigma_t`` (3,) 1/m, ``albedo`` (3,) and ``g``."""

    scene: object
    emitter: object
    position: np.ndarray
    axis: np.ndarray | None
    cutoff_deg: float
    beam_deg: float
    intensity: np.ndarray
    medium: object
    sigma_t: np.ndarray
    albedo: np.ndarray
    g: float

    @property
    def sigma_s(self) -> np.ndarray:
        return self.albedo * self.sigma_t


def _emitter_frame(mi, emitter) -> dict | None:
    """A Mitsuba ``point`` or ``spot`` emitter's position (3,), axis (3,) or None, cutoff and beam (degrees)
    and constant intensity (3,) from its parameters; None for anything else (a textured intensity)."""
    params = mi.traverse(emitter)
    keys = set(params.keys())
    if "intensity.value" not in keys:
        return None
    out = {
        "intensity": np.array(np.broadcast_to(np.asarray(params["intensity.value"], np.float64).ravel(), 3)),
        "axis": None,
        "cutoff_deg": 0.0,
        "beam_deg": 0.0,
    }
    if "position" in keys:  # a point light
        return {**out, "position": np.asarray(params["position"], np.float64).ravel()[:3]}
    if {"to_world", "cutoff_angle", "beam_width"} <= keys:  # a spot: local +Z is its axis
        m = np.asarray(params["to_world"].matrix, np.float64).reshape(4, 4, -1)[..., 0]
        axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
        return {
            **out,
            "position": m[:3, 3].copy(),
            "axis": axis,
            "cutoff_deg": float(np.asarray(params["cutoff_angle"]).ravel()[0]),
            "beam_deg": float(np.asarray(params["beam_width"]).ravel()[0]),
        }
    return None


def lit_medium(setup: AuditSetup, app: Applicability, kind: str) -> LitMedium:
    """The light ``app.source`` (a ``point`` or ``spot``: ``kind``) and its medium (`LitMedium`, module
    docstring); a light or medium the audit cannot read is a one-line `AuditError`."""
    mi = setup.mi
    if setup.info.xml is not None:
        scene, emitters = setup.scene, setup.emitters
        emitter = emitters[app.source] if app.source is not None and app.source < len(emitters) else None
    else:  # an rtfit TOML scene: its own Mitsuba build, media included (the audit's scene has none)
        toml = setup.source  # (its homogeneous media only: rtfit's exponential fog plays no part here)
        homogeneous = tuple(m for m in toml.media if m.kind == "homogeneous")
        scene = load_dict(mi, mitsuba_scene_dict(mi, dataclasses.replace(toml, media=homogeneous)))
        at = np.asarray(toml.lights[app.source].position, np.float64)
        emitter = next((e for e in scene.emitters() if _at(_emitter_frame(mi, e), at)), None)
    frame = _emitter_frame(mi, emitter) if emitter is not None else None
    if frame is None or (frame["axis"] is None) != (kind == "point"):
        raise AuditError(f"{app.family}: {app.part}: not a {kind} light of constant intensity")
    medium = point_medium(mi, scene, setup.sensor, frame["position"])
    coeffs = medium_parameters(mi, medium)
    if coeffs is None:
        raise AuditError(
            f"{app.family}: {app.part}: its medium is not homogeneous with constant σ_t, albedo and an "
            "isotropic or Henyey–Greenstein phase function"
        )
    sigma_t, albedo, g = coeffs
    return LitMedium(scene, emitter, medium=medium, sigma_t=sigma_t, albedo=albedo, g=g, **frame)


def _at(frame: dict | None, position: np.ndarray) -> bool:
    return frame is not None and bool(np.allclose(frame["position"], position, rtol=0.0, atol=1e-5))


@dataclasses.dataclass(frozen=True)
class Stretches:
    """The camera rays' stretches in the light's medium: the camera ``origin``, the (H, W) ``mask`` of pixels
    with a bounded stretch, their unit ``dirs`` (N, 3), ``start`` s₀ and ``end`` s₁ (N,) in m from the
    camera, and whether the camera is ``inside`` the medium."""

    origin: tuple[float, float, float]
    mask: np.ndarray
    dirs: np.ndarray
    start: np.ndarray
    end: np.ndarray
    inside: bool

    @property
    def segment_start(self) -> np.ndarray:
        """o_c + s₀·ω (N, 3): where each stretch begins."""
        return np.asarray(self.origin) + self.start[:, None] * self.dirs


def stretches(setup: AuditSetup, app: Applicability, lit: LitMedium) -> Stretches:
    """Each pixel's first stretch of its camera ray in the light's medium (module docstring); no pixel with
    one is a one-line `AuditError`."""
    mi = setup.mi
    origin = camera_origin(mi, setup.sensor)
    view = setup.gbuffer.view_dir.reshape(-1, 3).astype(np.float64)
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-30)
    inside = point_medium(mi, lit.scene, setup.sensor, origin) is lit.medium
    s0, s1 = medium_segments(mi, lit.scene, origin, view, lit.medium, inside)
    keep = np.isfinite(s1) & (s1 > s0)
    if not keep.any():
        raise AuditError(
            f"{app.family}: no camera ray has a bounded stretch in {app.part}'s medium (the camera sees "
            "a medium through null boundaries only: one behind glass refracts, an unbounded one needs walls)"
        )
    mask = keep.reshape(setup.gbuffer.view_dir.shape[:2])
    return Stretches(origin, mask, view[keep], s0[keep], s1[keep], bool(inside))


def inscatter_reference(
    setup: AuditSetup, app: Applicability, lit: LitMedium, rays: Stretches, tag: str
) -> AuditReference:
    """The light's single-scattered radiance along the stretches through the pass cache (module docstring)."""
    mi = setup.mi
    what = {
        "format": FORMAT,
        "quantity": "inscattered-radiance",
        "light": app.source,
        "rays": array_digest(np.asarray(rays.origin), rays.dirs, rays.start, rays.end),
    }

    window = None
    if lit.axis is not None and lit.cutoff_deg + WINDOW_MARGIN_DEG < 89.0:
        # a spot gives nothing outside its cutoff cone: sample inside it (+ a margin); a cone of nearly 90°
        # or more is not convex enough for `cone_window`: the whole stretch is sampled then
        angle = math.radians(lit.cutoff_deg + WINDOW_MARGIN_DEG)
        window = cone_window(rays.origin, rays.dirs, rays.start, rays.end, lit.position, lit.axis, angle)
        what["window"] = array_digest(*window)

    def render(spp: int, seed: int):
        return inscatter_pass(mi, lit.scene, lit.emitter, lit.medium, rays.origin, rays.dirs, rays.start,
                              rays.end, lit.position, lit.sigma_t, lit.albedo, spp, seed, window)  # fmt: skip

    pooled = pooled_passes(setup, what, render, (-1, 3), f"{tag}: {app.part}")
    return pooled.reference(
        rays.mask,
        quantity="single-scattered radiance of that light along the camera's rays in the medium (W/m²/sr)",
        integrator="single scattering: equiangular distance sampling about the light, next-event estimation",
        integrator_reason=(
            "Mitsuba's emitter sample (I(ω)/r²), phase function and shadow rays; the homogeneous medium's "
            "transmittance in closed form on both legs (rtfit.reference.medium_lights.inscatter_pass)"
        ),
    )


def quantity_inputs(lit: LitMedium, c: int) -> dict:
    """Channel ``c``'s light and medium inputs of an in-scattering quantity (module docstring)."""
    return {
        "intensity": float(lit.intensity[c]),
        "sigma_s": float(lit.sigma_s[c]),
        "sigma_t": float(lit.sigma_t[c]),
        "g": lit.g,
    }


def light_parameters(lit: LitMedium, rays: Stretches) -> dict:
    """The case's parameters (results.json) common to both families."""
    return {
        "position_m": [float(x) for x in lit.position],
        "intensity_W_per_sr": [float(x) for x in lit.intensity],
        "sigma_t_per_m": [float(x) for x in lit.sigma_t],
        "albedo": [float(x) for x in lit.albedo],
        "g": lit.g,
        "camera_inside_medium": rays.inside,
        "camera_to_light_m": float(np.linalg.norm(lit.position - np.asarray(rays.origin))),
        "pixels": len(rays.start),
    }


NOTES = (
    "the light-to-point segment is taken to stay inside the medium (its transmittance e^(−σ_t r)); a "
    "shape between a point and the light shadows the reference but not the quadrature or the methods",
    "each pixel's segment is the first stretch of its ray in the medium before an opaque surface",
)
"""Notes every case of both families carries."""


@dataclasses.dataclass(frozen=True)
class Inscatter:
    """A light's in-scattering case in the making: the light in its medium, the camera's stretches, the
    reference along them (`inscatter_reference`), the case's tag and the shipped rows' one level
    ``k`` = K, the channels' mean of σ_s·I/(4π) (W/m/sr)."""

    lit: LitMedium
    rays: Stretches
    reference: AuditReference
    tag: str
    k: float


def inscatter(setup: AuditSetup, app: Applicability, kind: str) -> Inscatter:
    """The light ``app.source`` (a ``kind`` emitter) in its medium, its stretches, reference and level."""
    lit = lit_medium(setup, app, kind)
    rays = stretches(setup, app, lit)
    tag = f"light{app.source}"
    k = float(np.mean(lit.sigma_s * lit.intensity)) / FOUR_PI
    return Inscatter(lit, rays, inscatter_reference(setup, app, lit, rays, tag), tag, k)


QUADRATURE_UNCOSTED = (
    "the exact row's values come from the single-scattering quadrature (rtfit.reference.single_scattering, "
    "float64 NumPy, run once per case outside its kernel, which only passes them through): timing that "
    "kernel would print a cost of nothing"
)
"""Why the ``quadrature`` row has no cost per pixel (`FamilyCase.uncosted`): it measured 0.008 ns a pixel."""


def inscatter_case(
    app: Applicability,
    case: Inscatter,
    suffix: str,
    geometry: dict,
    exact: list,
    parameters: dict,
    notes: tuple[str, ...],
    params: dict,
) -> FamilyCase:
    """The family's case ``<tag>-<suffix>``: per channel the ``geometry`` inputs, `quantity_inputs` and
    ``exact[c]`` as ``single_scattering``; as parameters the light, `light_parameters`, the family's own
    ``parameters`` and K; as notes `NOTES`, the level's, the family's ``notes`` and the pixel count."""
    lit, rays = case.lit, case.rays
    channels = tuple({**geometry, **quantity_inputs(lit, c), "single_scattering": exact[c]} for c in range(3))
    return FamilyCase(
        id=f"{case.tag}-{suffix}",
        label=f"{app.part}, in-scattered radiance",
        reference=case.reference,
        channel_inputs=channels,
        parameters={"light": app.part, **light_parameters(lit, rays), **parameters, "K_W_per_m_sr": case.k},
        units="W/m²/sr",
        notes=(
            *NOTES,
            "the shipped rows carry one level for the three channels (K = the channels' mean of σ_s·I/(4π))",
            *notes,
            f"{len(rays.start)} pixels; camera {'inside' if rays.inside else 'outside'} the medium",
        ),
        params=params,
        uncosted={"quadrature": QUADRATURE_UNCOSTED},
    )
