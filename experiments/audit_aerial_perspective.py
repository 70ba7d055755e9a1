r"""The ``aerial-perspective`` family in `rtfit audit`: the fog blend under the scene's own sky.

Where a sky (an environment emitter: a Mitsuba ``sunsky``, an ``envmap`` used as sky, a ``constant``
one; in a Mitsuba XML scene or an rtfit TOML scene) and a medium the camera looks through meet (a
``homogeneous`` medium, or a ``heterogeneous`` one whose ``sigma_t`` is a ``constvolume`` or a
``gridvolume``; an rtfit TOML ``homogeneous`` medium), a renderer draws aerial perspective with the fog blend
L = L₀·T + C·(1 − T), its colour C taken from the sky (CryEngine 2's horizon average, seed 000:2247-2287,
002:224-290: docs/aerial-perspective.md). One case per such medium (`rtfit.experiments.families.RULES`, role
"sky through a medium"), ``mediaK-aerial``, on the pixels whose camera ray crosses the medium over a finite
stretch [t_in, t_out] (`audit_media.medium_intervals`):

* **reference**: the radiance at the camera with this medium alone (the scene's other media switched off),
  lit by every light of the scene and its sky, path traced by Mitsuba's ``volpathmis`` (all bounces), and
  the fog-free image L₀ (every medium switched off; same integrator, spp and seed):
  `audit_media.fogged_radiance_inputs`, the passes the height-fog family's radiance case renders (one
  cache entry for both);
* **the medium as height fog** (the blend's T): constant fog b = σt, c = 0 (σt read from the loaded medium
  at a point inside; a chromatic σt gives the grey extinction of its G channel: the experiment's
  simplification (3)), or a grid fitted with b·exp(−c·(p·ĝ − h₀)) (`rtfit.reference.grid_fit`, the
  stretch clipped to the grid's box); its single-scattering albedo a (σs/σt, RGB) and the mean cosine g of
  its ``hg`` phase function (0 for ``isotropic``);
* **the sky's colours**, from the emitter itself (deterministic or with a fixed seed, not cached):
  H, the **horizon average**: the emitter's radiance (``eval``) averaged over `HORIZON_AZIMUTHS` azimuths at
  the elevations of the two lowest rows of the seed's 64-row sky texture (0–2.8° above the scene's up
  axis's horizon; directions within `SUN_EXCLUSION_DEG` of a sunsky's sun left out: its disc is no part of
  the sky's colour); J(v), the **source function at the camera** of the sky's light, unshadowed and
  unattenuated: J(v) = a·∫ L_sky(ω) p_HG(v·ω, g) dω, estimated with `SOURCE_SAMPLES` directions drawn by
  the emitter's own ``sample_direction`` from the camera (w = L/pdf: a sunsky's sun and an envmap's bright
  texels are importance sampled), J(v) = a·mean_k w_k p_HG(v·ω_k, g) (the phase text of
  `rtfit.realtime.phase`);
* **rows** (`rtfit.realtime.aerial_perspective.METHODS`: the height-fog ``const`` and ``phase`` kernels,
  one text of the blend): ``camera-source`` (C = J(v): the ladder's step (1)), ``horizon-flat`` (C = H),
  ``horizon-phase`` (C = H·4π·p_HG(θ, g), θ the angle between the view and the sun, g held at the medium's:
  a user's sky has no Rayleigh/Mie split, so the seed's H_R·P_R + H_M·P_HG is its Mie part alone), each
  given the medium's b, c, then fitted to this scene (b, c and the colours; g stays held), and your
  approximations of ``fogged_radiance``.

Pixels whose ray never enters the medium, or whose stretch is infinite (an unbounded medium seen against the
sky), are left out; no row is exact (the blend is exact only for a constant source function), so the engine
runs no z-check on them. Where the sky has no sun (an envmap, a constant sky) θ is taken as 90° (cos_sun = 0).
"""

from __future__ import annotations

import dataclasses
import math

import drjit as dr
import numpy as np

from rtfit.realtime.aerial_perspective import METHODS
from rtfit.realtime.phase import hg_phase
from rtfit.reference.cache import array_digest
from rtfit.reference.grid_fit import fit_height_density, grid_of_medium
from rtfit.reference.mitsuba_xml import UP_AXES

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_media import (
    RADIANCE_INTEGRATOR,
    box_interval,
    density_params,
    finite_stretch,
    fogged_radiance_inputs,
    opened_medium,
)
from .audit_setup import AuditSetup
from .shipped import ShippedScene, Sizes

__all__ = [
    "FAMILY",
    "HORIZON_ELEVATIONS_DEG",
    "MEDIA",
    "SCENES",
    "SUN_ELEVATIONS_DEG",
    "aerial_cases",
    "horizon_average",
    "source_function",
]

NAME = "aerial-perspective"
FORMAT = 1
"""The radiance passes' key format: the height-fog media family's (`audit_fog_media.FORMAT`), so that both
families read one cache entry for one medium."""
HORIZON_ELEVATIONS_DEG = (0.703125, 2.109375)
"""The mid-elevations of the two lowest rows of the seed's 64-row sky texture over 0–90° (its horizon
average, 000:2247-2254: `rtfit.realtime.aerial_perspective.horizon_colour` with rows = 2)."""
HORIZON_AZIMUTHS = 256
SUN_EXCLUSION_DEG = 1.0
SOURCE_SAMPLES = 1 << 14
"""Directions drawn from the sky emitter for J(v) (seed `SOURCE_SEED`): its relative noise is ~1/√N of the
weights' spread (a sunsky's sun is one sampling technique of its own)."""
SOURCE_SEED = 11
COLOUR_FLOOR = 1e-6
"""The smallest colour a row starts from (W/m²/sr): horizon-phase's C₀ (0 in the seed's model) and a black
sky's H."""
_CHUNK = 512
SUN_ELEVATIONS_DEG = (60.0, 30.0, 15.0, 8.0, 4.0, 2.0)
"""The sun elevations of the shipped scenes (degrees above the horizon; Mitsuba's sunsky has no sun below
it, so the experiment's −2° and −4° are the study's quadrature alone)."""
SUN_AZIMUTH_DEG = 120.0
"""The sun's azimuth from the view axis +y towards +x (the experiment's)."""
MEDIA = {
    "fog_bank": "a homogeneous fog bank of σt = 0.35 /unit",
    "height_fog": "an exponential height fog (grid) of σt = 0.6·exp(−0.96·z) /unit",
}
"""The shipped media (scenes/library/aerial_perspective_<medium>.xml), each albedo 0.9, hg g = 0.6."""
QUICK = (("fog_bank", 60.0), ("height_fog", 4.0))
"""The ``--quick`` scenes: a high sun through the constant fog, a low sun through the height fog."""


_sizes = Sizes(full=(96, 64, 1024), quick=(24, 16, 64))


_QUANTITY = "radiance at the camera with this medium alone, under the scene's sky (W/m²/sr, RGB)"
"""The words of the fog-blend case's reference."""


def _sun_scene(medium: str, elevation: float) -> ShippedScene:
    e, a = math.radians(elevation), math.radians(SUN_AZIMUTH_DEG)
    sun = (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))
    return _sizes.scene(
        f"aerial_perspective_{medium}.xml",
        f"sunsky (turbidity 3), sun at {elevation:g}° elevation, through {MEDIA[medium]}",
        defines={k: f"{v:.6f}" for k, v in zip(("sx", "sy", "sz"), sun, strict=True)},
        name=f"{medium}-sun{elevation:g}",
        quick=(medium, elevation) in QUICK,
    )


SCENES = tuple(_sun_scene(m, e) for m in MEDIA for e in SUN_ELEVATIONS_DEG)
"""The scenes ``rtfit run aerial-perspective`` audits: Mitsuba's sunsky over a grey ground seen through each
of `MEDIA` (scenes/library/aerial_perspective_<medium>.xml), one scene per sun elevation in
`SUN_ELEVATIONS_DEG` (azimuth `SUN_AZIMUTH_DEG`, the sun's direction by ``defines``); ``--quick``: `QUICK`."""


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane perpendicular to ``up``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, a)
    x /= np.linalg.norm(x)
    return x, np.cross(up, x)


def _rgb(values, n: int) -> np.ndarray:
    """A Dr.Jit RGB value as (n, 3) float64 (a value that does not vary, e.g. a constant emitter's, has
    width 1 and is broadcast)."""
    a = np.array(values, dtype=np.float64).reshape(3, -1)
    return np.ascontiguousarray(np.broadcast_to(a, (3, n)).T)


def sky_radiance(mi, emitter, dirs: np.ndarray) -> np.ndarray:
    """The emitter's radiance (N, 3) arriving along unit world ``dirs`` (``eval`` with wi = −d)."""
    si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
    si.wi = mi.Vector3f(np.ascontiguousarray(-np.asarray(dirs).T, dtype=np.float32))
    return _rgb(emitter.eval(si), len(dirs))


def horizon_average(mi, emitter, up, sun=None) -> np.ndarray:
    """H (RGB): the sky's radiance averaged over `HORIZON_AZIMUTHS` azimuths at `HORIZON_ELEVATIONS_DEG`
    above the horizon of the unit ``up`` axis, directions within `SUN_EXCLUSION_DEG` of ``sun`` left out."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    x, y = _frame(up)
    az = (np.arange(HORIZON_AZIMUTHS) + 0.5) / HORIZON_AZIMUTHS * 2.0 * math.pi
    el = np.radians(np.asarray(HORIZON_ELEVATIONS_DEG))
    a, e = np.meshgrid(az, el)
    local = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    dirs = local @ np.stack([x, y, up])
    if sun is not None:
        dirs = dirs[dirs @ sun < math.cos(math.radians(SUN_EXCLUSION_DEG))]
    return sky_radiance(mi, emitter, dirs).mean(axis=0)


def source_function(mi, emitter, origin, view: np.ndarray, albedo: np.ndarray, g: float) -> np.ndarray:
    """J(v) (N, 3) = a·∫ L_sky(ω) p_HG(v·ω, g) dω for unit view directions ``view`` (N, 3) at ``origin``:
    `SOURCE_SAMPLES` directions from the emitter's ``sample_direction`` (weights L/pdf, seed
    `SOURCE_SEED`), J = a·mean_k w_k p_HG(v·ω_k, g)."""
    n = SOURCE_SAMPLES
    it = dr.zeros(mi.Interaction3f, n)
    it.p = mi.Point3f(*[float(v) for v in origin])
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(SOURCE_SEED, n)
    ds, w = emitter.sample_direction(it, sampler.next_2d())
    omega, weight = _rgb(ds.d, n), _rgb(w, n)
    weight[~np.isfinite(weight)] = 0.0
    out = np.empty((len(view), 3))
    for k in range(0, len(view), _CHUNK):
        p = hg_phase(np.clip(view[k : k + _CHUNK] @ omega.T, -1.0, 1.0), g)
        out[k : k + _CHUNK] = p @ weight / n
    return out * albedo


def _phase_g(mi, medium) -> float:
    """The mean cosine of the medium's phase function: ``hg``'s g, 0 for ``isotropic``; another phase
    function is an `AuditError` (the blend's phase is Henyey–Greenstein)."""
    phase = medium.phase_function()
    params = mi.traverse(phase)
    if "g" in params.keys():
        return float(np.asarray(params["g"]).reshape(-1)[0])
    if str(phase).startswith("IsotropicPhaseFunction"):
        return 0.0
    raise AuditError(
        f"{NAME}: the medium's phase function ({str(phase).split('[')[0]}) is not hg or isotropic"
    )


def _coefficients(mi, medium, point) -> tuple[np.ndarray, np.ndarray]:
    """(σt, a) at ``point``: the extinction (RGB, 1/scene unit) and the single-scattering albedo σs/σt."""
    mei = dr.zeros(mi.MediumInteraction3f, 1)
    mei.p = mi.Point3f(*[float(v) for v in point])
    s, _, t = medium.get_scattering_coefficients(mei)
    s, t = (np.asarray(x, np.float64).reshape(-1) for x in (s, t))
    return t, np.divide(s, t, out=np.zeros(3), where=t > 0.0)


def _colour(param, value: float):
    """``param`` starting at ``value`` (at least `COLOUR_FLOOR`: a start must lie inside the bounds, and a
    colour's lower bound is 0), its upper bound raised to 10× that value where it is lower."""
    value = max(float(value), COLOUR_FLOOR)
    return dataclasses.replace(param, initial=value, upper=max(param.upper, 10.0 * value))


def aerial_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The ``mediaK-aerial`` case of one medium under the scene's sky (module docstring)."""
    mi = setup.mi
    med, dirs, t_in, t_out = opened_medium(setup, app, NAME)
    emitter = med.scene.environment()
    if emitter is None:
        raise AuditError(f"{NAME}: {app.part}: the loaded scene has no environment emitter (no sky)")
    up = np.asarray(UP_AXES.get(setup.info.up, (0.0, 0.0, 1.0)), np.float64)
    enter = finite_stretch(t_in, t_out)
    if not enter.any():
        raise AuditError(f"{NAME}: no camera ray crosses {app.part} over a finite stretch")
    k = int(np.argmax(enter))
    sigma, albedo = _coefficients(mi, med.medium, med.origin + 0.5 * (t_in[k] + t_out[k]) * dirs[k])
    try:
        grid = grid_of_medium(mi, med.medium)
    except ValueError:
        grid = None
    if grid is None:  # constant fog: c = 0, b = σt (grey: the G channel's)
        b, c, r0, r1 = float(sigma[1]), 0.0, t_in, t_out

        def height(p):
            return p @ up

        model = f"constant fog: b = σt = {b:.4g} /scene unit (G channel), c = 0"
    else:
        fit = fit_height_density(grid, up=UP_AXES.get(setup.info.up, (0.0, 0.0, 1.0)))
        b, c, height = fit.b, fit.c, fit.height
        r0, r1 = box_interval(grid.to_world, med.origin, dirs, t_in, t_out)
        model = (
            f"grid fitted with b·exp(−c·(p·ĝ − h₀)): b = {b:.4g}, c = {c:.4g} /scene unit (RMS relative "
            f"residual {fit.rms_relative:.2g})"
        )
    if not b > 0.0:
        raise AuditError(f"{NAME}: {app.part} has σt = 0: no fog to audit")
    g = _phase_g(mi, med.medium)
    ok = enter & finite_stretch(r0, r1)
    h, w = setup.gbuffer.view_dir.shape[:2]
    mask = ok.reshape(h, w)
    if not mask.any():
        raise AuditError(f"{NAME}: no camera ray crosses {app.part} over a finite stretch")
    d, o = dirs[ok], med.origin
    tag = f"media{app.source}"
    what = {"format": FORMAT, "quantity": "medium-radiance", "medium": app.source, "channel": None,
            "rays": array_digest(o, d, t_in[ok], t_out[ok]), "integrator": RADIANCE_INTEGRATOR}  # fmt: skip
    start, end = o + r0[ok, None] * d, o + r1[ok, None] * d
    length = r1[ok] - r0[ok]
    common = {
        "z0": height(start),
        "z1": height(end),
        "distance": length,
        "length": length,
        **{f"o{a}": start[:, i] for i, a in enumerate("xyz")},
        **{f"d{a}": d[:, i] for i, a in enumerate("xyz")},
        "density": np.full(len(d), b),
        "falloff": np.full(len(d), c),
    }
    fogged = fogged_radiance_inputs(setup, med, ok, mask, common, what, tag, quantity=_QUANTITY)
    sun = fogged.sun
    horizon = horizon_average(mi, emitter, up, sun)
    source = source_function(mi, emitter, o, d, albedo, g)
    inputs = {**fogged.inputs, **{f"j_{ch}": source[:, i] for i, ch in enumerate("rgb")}}
    given = density_params(b, c, float(length.max()))
    flat = METHODS["horizon-flat"].params
    phase = METHODS["horizon-phase"]
    rows = {
        "camera-source": METHODS["camera-source"],
        "horizon-flat": METHODS["horizon-flat"],
        "horizon-phase": dataclasses.replace(
            phase, params={n: p for n, p in phase.params.items() if n != "g"}, fixed={"g": g}
        ),
    }
    params = {
        "camera-source": given,
        "horizon-flat": {
            **given,
            **{f"{ch}0": _colour(flat[f"{ch}0"], horizon[i]) for i, ch in enumerate("rgb")},
        },
        "horizon-phase": {
            **given,
            **{f"{ch}0": _colour(phase.params[f"{ch}0"], 0.0) for ch in "rgb"},
            **{f"{ch}1": _colour(phase.params[f"{ch}1"], horizon[i]) for i, ch in enumerate("rgb")},
        },
    }
    sky = str(emitter).split("[")[0]
    return [
        FamilyCase(
            id=f"{tag}-aerial",
            label=f"{app.part} under the {sky}, fog blend",
            reference=fogged.reference,
            channel_inputs=(inputs,),
            parameters={
                "medium": app.part,
                "sky": sky,
                "density": b,
                "falloff": c,
                "albedo": albedo.tolist(),
                "g": g,
                "horizon_average": horizon.tolist(),
                "sun_direction": None if sun is None else sun.tolist(),
                "pixels": int(ok.sum()),
                "length_max": float(length.max()),
                "l0_cache_key": fogged.l0_cache_key,
            },
            units="W/m²/sr",
            notes=(
                model,
                f"the sky's horizon average H = ({', '.join(f'{v:.4g}' for v in horizon)}) over elevations "
                f"0–2.8° above the {setup.info.up} horizon; J(v): {SOURCE_SAMPLES} directions sampled from "
                f"the sky, times the medium's albedo ({', '.join(f'{v:.3g}' for v in albedo)}), g = {g:.3g}",
                "L₀: the same scene with every medium switched off (scale 0), same integrator and spp (its "
                "noise is part of every row's error); no row is exact, so no z-check runs",
                *(() if sun is not None else ("the sky has no sun: cos_sun = 0 (θ = 90°)",)),
            ),
            methods=rows,
            params=params,
        )
    ]


FAMILY = AuditFamily(
    name=NAME,
    quantity="fogged_radiance",
    cases=aerial_cases,
    describe=(
        "Per medium the camera looks through under the scene's sky (sunsky, envmap or constant "
        "environment): the radiance at the camera with that medium alone, path traced by volpathmis, "
        "against the fog blend L₀·T + C·(1 − T) on the fog-free image L₀, T from the medium as height fog "
        "(constant: b = σt, c = 0; a grid fitted with the exponential height density) and C from the sky: "
        "its source function at the camera (camera-source), its horizon average (horizon-flat) and that "
        "average times the medium's phase per pixel (horizon-phase), given, then fitted to this scene."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "aerial-perspective",
            "sky through a medium",
            ("fog-medium", "environment"),
            "{part} stands between the camera and what it sees under {with_}: the fog blend with its colour "
            "taken from that sky",
            "the radiance at the camera with this medium alone, lit by the scene's lights and sky, against "
            "the fog-free image L₀ (W/m²/sr, RGB)",
            "volpathmis (the scene's own medium, all bounces), and without any medium for L₀; the sky's "
            "horizon average and source function from the emitter itself (eval, sample_direction)",
            # the camera-source row's colour: the sky's source function at the camera, from the emitter
            frozenset({"j_r", "j_g", "j_b"}),
        ),
    ),
)
