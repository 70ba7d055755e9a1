r"""Path-traced check of the aerial-perspective quadrature: rtfit's height-fog medium under a distant sun.

The quadrature of `rtfit.realtime.aerial_perspective.aerial_scattering` is the experiment's reference for
the atmosphere and the fog together (Mitsuba holds one medium per region, so the two media cannot overlap
in one render). It is checked piecewise against independent values: the atmosphere alone against
`rtfit.reference.nishita_sky.single_scattering_quadrature` (itself checked against Mitsuba in the
nishita-sky experiment), and the **fog alone against this module's path-traced render**:

* units metres, +Z up; rtfit's exponential-fog medium (`rtfit.reference.height_fog`, plugin ``rtfit_expfog``:
  σ_t = b·e^(−c·z), albedo 1, Henyey–Greenstein g) inside a box z ∈ [0, ``height``], x, y ∈ ±``half_width``
  with a ``null`` BSDF; the camera inside it;
* the sun: rtfit's distant disc (`rtfit.reference.emitters`, irradiance E₀ at normal incidence, angular
  radius α) with no sky, so a ray leaving the box sees nothing (directions near the sun are not used);
* ``volpathmis`` with ``max_depth = 2``: single scattering (one scattering event, next-event estimation to
  the sun, ratio tracking through the fog).

Each pixel estimates S = E₀ ∫₀ᴰ T(t) σ_s(t) P_HG(ν, g) T_sun(t) dt with D the box exit, the fog-only case
of the quadrature (there with the box's fog above ``height`` ignored: e^(−c·height) of the sun's optical
depth). Passes: `rtfit.reference.nishita_sky.sky_pass` (rays from a point along given directions).
"""

from __future__ import annotations

import math

import numpy as np

from . import emitters
from . import height_fog as fog_media
from .build import box_boundary_shape
from .cache import PassEntry, array_digest
from .estimators import PassResult
from .nishita_sky import sky_pass
from .variants import use_variant

__all__ = ["box_exit_distance", "fog_sun_scene_dict", "render_fog_sun"]


class _Box:
    kind = "cube"

    def __init__(self, half_width: float, height: float):
        self.center = (0.0, 0.0, 0.5 * height)
        self.size = (2.0 * half_width, 2.0 * half_width, height)
        self.rotate_axis = (0.0, 0.0, 1.0)
        self.rotate_deg = 0.0


class _Fog:
    def __init__(self, density, falloff, g, half_width, height):
        self.boundary = _Box(half_width, height)
        self.density = float(density)
        self.falloff = float(falloff)
        self.gradient = (0.0, 0.0, 1.0)
        self.gradient_origin = (0.0, 0.0, 0.0)
        self.ellipsoid = False
        self.albedo = (1.0, 1.0, 1.0)
        self.g = float(g)


def box_exit_distance(origin, dirs: np.ndarray, half_width: float, height: float) -> np.ndarray:
    """Distance (m) from ``origin`` inside the box to its boundary along unit ``dirs`` (N, 3), float64."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    lo = np.array([-half_width, -half_width, 0.0])
    hi = np.array([half_width, half_width, height])
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    far = np.where(d == 0.0, np.inf, np.maximum(t1, t2))
    return far.min(axis=-1)


def fog_sun_scene_dict(
    mi, density, falloff, g, sun, solar_irradiance, sun_angular_radius, half_width, height
) -> dict:
    """The Mitsuba scene (metres): the fog box (null BSDF, rtfit_expfog inside), the distant-disc sun."""
    fog_media.register(mi)
    emitters.register(mi)
    medium = fog_media.medium_dict(mi, _Fog(density, falloff, g, half_width, height))
    radiance = [e / (math.pi * math.sin(sun_angular_radius) ** 2) for e in solar_irradiance]
    return {
        "type": "scene",
        "integrator": {"type": "volpathmis", "max_depth": 2},
        # The box as the tiled boundary mesh of the height-fog references, not Mitsuba's ``cube``: a
        # null-BSDF face of two km-sized triangles is re-hit forever by OptiX near the world origin (issue
        # 21 §1; session 6: this check's full run on an H200 did not finish its first pass in 170 s).
        "fog": {
            **box_boundary_shape(_Box(half_width, height)),
            "bsdf": {"type": "null"},
            "interior": medium,
        },
        "sun": {
            "type": emitters.PLUGIN,
            "direction": mi.ScalarVector3f(*[float(x) for x in sun]),
            "angular_radius": float(sun_angular_radius),
            "radiance": mi.ScalarVector3f(*radiance),
            "sky": mi.ScalarVector3f(0.0, 0.0, 0.0),
        },
    }


def render_fog_sun(
    variant: str,
    origin,
    dirs: np.ndarray,
    *,
    density: float,
    falloff: float,
    g: float,
    sun,
    solar_irradiance,
    sun_angular_radius: float,
    half_width: float,
    height: float,
    spp: int,
    passes: int,
    seed: int,
    cache_dir=None,
) -> list[PassResult]:
    """``passes`` independent single-scattering passes of ``spp`` along ``dirs`` (N, 3) from ``origin``
    (m, inside the box): a list of `PassResult` (RGB means and variances per direction).

    With ``cache_dir`` the passes go through the pass cache (`rtfit.reference.cache.PassEntry`, namespace
    ``aerial-perspective``): loaded where cached, else rendered under the pass watchdog and saved, so an
    interrupted run resumes and no pass runs without bound. The key holds the physics (fog, sun, box), the
    rays, the integrator, the variant, the seed, ``spp`` per pass and the versions."""
    import drjit as dr
    import mitsuba

    mi = use_variant(variant)
    state: dict = {}

    def load():
        scene = mi.load_dict(
            fog_sun_scene_dict(
                mi, density, falloff, g, sun, solar_irradiance, sun_angular_radius, half_width, height
            )
        )
        emitters.attach(scene)
        state["scene"] = scene
        state["medium"] = next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)

    def render(k: int) -> PassResult:
        if "scene" not in state:
            load()
        return sky_pass(mi, state["scene"], state["medium"], origin, dirs, spp, seed * 7919 + k)

    if cache_dir is None:
        return [render(k) for k in range(passes)]
    ident = {
        "format": "aerial-perspective/fog-sun/1",
        "fog": {"density": float(density), "falloff": float(falloff), "g": float(g)},
        "box": {"half_width": float(half_width), "height": float(height), "mesh": "box_boundary_shape"},
        "sun": {
            "direction": [float(x) for x in sun],
            "irradiance": [float(x) for x in solar_irradiance],
            "angular_radius": float(sun_angular_radius),
        },
        "rays": array_digest(np.asarray(origin, np.float64).reshape(1, 3), np.asarray(dirs, np.float64)),
        "integrator": {"type": "volpathmis", "max_depth": 2},
        "variant": variant,
        "seed": int(seed),
        "pass_spp": int(spp),
        "versions": [mitsuba.__version__, dr.__version__],
    }
    entry = PassEntry(cache_dir, ident, namespace="aerial-perspective", storage="npz")
    out, _ = entry.passes(
        passes, render, shape=(len(np.asarray(dirs).reshape(-1, 3)), 3), label="aerial-perspective fog check"
    )
    return out
