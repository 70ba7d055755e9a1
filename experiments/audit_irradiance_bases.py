"""The ``irradiance-bases`` family in `rtfit audit`: the environment's irradiance at the visible normals.

For a scene with an environment — a Mitsuba XML ``envmap``, ``constant`` or ``sunsky`` emitter, or an rtfit
TOML ``constant_env``, ``envmap`` or ``sunsky`` light (the Mitsuba emitter rtfit builds for it:
`rtfit.experiments.audit_environment.scene_environment`) — and the pixel-centre G-buffer of the scene's own
camera (camera-facing unit normals n at the visible points):

* reference: the environment's irradiance E(n) = ∫ L(ω) max(n·ω, 0) dω (W/m², RGB) at each visible
  normal, **unoccluded** (the environment alone; the scene's shapes do not block it — occluded sky light
  is the sdf-occlusion / ambient-aperture families' question), estimated by
  `rtfit.reference.light_irradiance.environment_irradiance_pass`: multiple importance sampling of Mitsuba's
  own sampling of that emitter and the cosine-weighted hemisphere (emitter sampling alone misses the
  near-horizon sky of Mitsuba's sunsky), in independent passes through the pass cache, with per-pixel
  standard errors;
* the environment as the bases see it: `rtfit.reference.environments.emitter_environment` bakes the
  loaded emitter (its ``to_world`` and ``scale`` included; `audit_environment.environment_of`) into a
  lat-long map of ``BAKE_ROWS`` rows (a sunsky's sun as an exact disc, its E⊥ from the emitter itself; a
  constant as its radiance); from that environment `audit_environment.build_bases` bakes
  what an engine stores: SH L2 by projection (the L1 bases read its first four coefficients), Valve's
  ambient cube (irradiance at the six axes), the NNLS-optimal cube (fitted over a Fibonacci sphere of
  normals) and Sloan's λ (the smallest window strength without negative irradiance);
* rows: every method of `rtfit.realtime.environment_bases.METHODS` — the cube and SH table
  (`rtfit.realtime.irradiance_bases`: Valve's and the NNLS cube, SH L1/L2/L3/L4 plain and windowed, ZH3),
  spherical Gaussians (``sg{6,9,12}-{naive,ls,nnls,ambient}``: lobe amplitudes fitted to the baked radiance,
  `rtfit.realtime.spherical_gaussians`) and Ambient Dice (12 vertex values, least squares over the Fibonacci
  normals, `rtfit.realtime.ambient_dice`), the same table and the same bake (`build_bases`) for
  every scene — each with its own stored coefficients
  (`FamilyCase.row_inputs`), evaluated on Dr.Jit at the visible normals; the exact row ``quadrature`` is
  the midpoint quadrature of the emitter itself at the same normals (`QUADRATURE_ROWS` rows of cells, the
  emitter's ``eval`` at each cell centre, a sunsky's sun as the exact disc:
  `environments.emitter_irradiance_quadrature`), which must sit at the reference's noise (the run's
  self-check that Mitsuba's sampling and a deterministic integral of the same emitter agree).
  ``sh-l2-lambda`` is evaluated with the environment's own λ and then refitted to this scene's pixels by
  the audit (least squares over the visible normals: it weights the normals the camera sees rather than
  the whole sphere).

The lightmap (hemisphere) bases of `rtfit.realtime.hemisphere_bases` (H-basis, Half-Life 2's radiosity
normal mapping) store irradiance in a surface's tangent frame: they are a second case on the pixels whose
shape has a UV parametrisation (`rtfit.experiments.audit_lightmap_bases`: the frame from Mitsuba's
``dp_du``, each texel baked from the same environment, evaluated at the texel's own normal), with the same
reference restricted to those pixels. Where the camera sees no such pixel (a mesh without texture
coordinates), the main case's notes say why those rows are left out.

A user approximation of ``environment_irradiance`` gets ``nx, ny, nz`` and ``sh`` (the 27 SH L2
coefficients, channel-major) and returns (R, G, B).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from rtfit.realtime.environment_bases import METHODS
from rtfit.reference.cache import array_digest
from rtfit.reference.environments import emitter_irradiance_quadrature
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.light_irradiance import environment_irradiance_pass
from rtfit.reference.variants import backend_of

from .audit import Applicability, AuditError, Rule
from .audit_environment import (
    BAKE_ROWS,
    QUADRATURE_MIN_ROWS,
    ROW,
    environment_bases,
    environment_of,
    row_params,
    scene_environment,
    sh_l2_table,
)
from .audit_family import AuditFamily, FamilyCase
from .audit_lightmap_bases import lightmap_rows, lightmaps, texel_reference
from .audit_setup import AuditSetup, PooledPasses, pooled_passes
from .shipped import Sizes

__all__ = [
    "BAKE_ROWS",
    "FAMILY",
    "QUADRATURE_MIN_ROWS",
    "QUADRATURE_ROWS",
    "SCENES",
    "SUNSKY_ELEVATIONS",
    "environment_bases",
    "environment_of",
    "irradiance_bases_cases",
    "sh_l2_table",
]

SUNSKY_ELEVATIONS = (2.0, 10.0, 30.0, 60.0, 90.0)
"""Sun elevations (°) of the shipped sunsky scenes (azimuth 30° from +Y towards +X); ``--quick``: 10°, 60°."""
QUICK_SUNSKY_ELEVATIONS = (10.0, 60.0)


def _sun_defines(elevation_deg: float) -> dict[str, str]:
    e, a = math.radians(elevation_deg), math.radians(30.0)
    d = (math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e))
    return {k: f"{v:.9f}" for k, v in zip(("sx", "sy", "sz"), d, strict=True)}


METRICS = ("rmse", "rel_mse", "mae", "max_abs", "psnr", "ssim")
"""The engine's metrics on the shipped scenes: `rtfit.fitting.ALL_METRICS` but ꟻLIP (~0.4 s a row on the CPU,
43 rows a scene: 60 of the quick run's 155 s, for a perceptual metric of an irradiance image the study's
relative errors already cover; the experiment before the engine had none). ``rtfit audit`` keeps all."""
_sphere, _options = Sizes(full=(128, 128, 4096), quick=(32, 32, 1024)), {"metrics": METRICS}
SCENES = (
    _sphere.scene(
        "irradiance_sphere.toml",
        "white unit sphere in a constant environment of radiance 1 (white furnace: E = π at every normal)",
        name="constant",
        options=_options,
    ),
    *(
        _sphere.scene(
            "irradiance_sphere_sunsky.xml",
            f"white unit sphere under Mitsuba's sunsky, sun at {e:g}° elevation",
            defines=_sun_defines(e),
            name=f"sunsky-{e:g}",
            quick=e in QUICK_SUNSKY_ELEVATIONS,
            options=_options,
        )
        for e in SUNSKY_ELEVATIONS
    ),
    *(
        _sphere.scene(
            "irradiance_sphere_envmap.xml",
            f"white unit sphere under the {label} map (envmaps/{m}.exr, 64 × 128)",
            defines={"map": f"envmaps/{m}.exr"},
            name=m,
            options=_options,
        )
        for m, label in (("studio", "studio (3 softboxes on black)"), ("overcast", "overcast (CIE sky)"))
    ),
)
"""The scenes ``rtfit run irradiance-bases`` audits (scenes/library/): the white unit sphere of the
experiment before the engine under each of its environments that a Mitsuba scene can hold as one emitter:
the constant (white furnace), Mitsuba's own sunsky at `SUNSKY_ELEVATIONS` (the bases baked from the emitter,
the reference the emitter itself) and the procedural studio and overcast maps, shipped as EXR files. The
lone disc suns (``sun-<r>``) are no environment emitter (the family does not apply to a lone sun): the study
keeps them, against their closed-form irradiance (`irradiance_bases_study`)."""

FORMAT = 2  # 2: MIS of emitter and cosine sampling (`environment_irradiance_pass`)
QUADRATURE_ROWS = 256
"""Rows (even: a cell boundary on the horizon) of the exact row's midpoint rule over the emitter itself."""


def _reference(setup: AuditSetup, source: int, emitter, normals: np.ndarray, label: str) -> PooledPasses:
    """Pooled passes of the emitter's unoccluded irradiance at ``normals``: mean and stderr (N, 3), W/m²."""
    what = {
        "format": FORMAT,
        "quantity": "environment-irradiance",
        "emitter": source,
        "normals": array_digest(normals),
    }

    def render(spp: int, seed: int):
        return environment_irradiance_pass(setup.mi, emitter, normals, spp, seed)

    return pooled_passes(setup, what, render, (-1, 3), label)


def _inside(p, value: float) -> float:
    """``value`` where strictly inside the parameter's bounds, else its declared start (a λ of 0 — an
    environment without negative irradiance — is evaluated at the declared 10⁻⁶, the same image to
    within 10⁻⁵ relative)."""
    return value if p.lower < value < p.upper else p.initial


def irradiance_bases_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case: every basis and the exact quadrature against the environment's irradiance (module
    docstring)."""
    if app.source is None:
        raise AuditError(f"irradiance-bases: {app.part} is not an environment of the scene")
    mask = setup.mask
    _, normals = gbuffer_points(setup.gbuffer, mask)
    scene_env = scene_environment(setup, app.source, "irradiance-bases")
    env = environment_of(setup, app.source)
    tag = f"env{app.source}"
    emitter = scene_env.emitter
    pooled = _reference(setup, app.source, emitter, normals, f"{tag}: {app.part}")
    backend = backend_of(setup.variant)  # the dense quadratures on Dr.Jit (issue 33: 3× less CPU than NumPy)
    bases = environment_bases(env, backend)
    kind = scene_env.kind
    quad = emitter_irradiance_quadrature(
        setup.mi, emitter, kind, normals, QUADRATURE_ROWS, sun=env.sun, backend=backend
    )
    nx, ny, nz = (np.ascontiguousarray(normals[:, k]) for k in range(3))
    sh = sh_l2_table(bases)  # a table: 27 floats
    default = ({"nx": nx, "ny": ny, "nz": nz, "sh": sh},)
    row_inputs: dict = {}
    params: dict = {}
    for row_id, method in METHODS.items():
        row = ROW[row_id]
        if method.exact:
            row_inputs[row_id] = tuple({"irradiance": quad[:, c]} for c in range(3))
            continue
        stored_rows = method.storage // 3 if method.storage else 0
        coeffs = np.asarray(bases[row.source], np.float64)[:stored_rows]
        stored = np.ascontiguousarray(coeffs.T.reshape(-1))  # what an engine stores, channel-major
        row_inputs[row_id] = ({"nx": nx, "ny": ny, "nz": nz, "coeffs": stored},)
        own = row_params(row, bases)
        if own:
            params[row_id] = {
                k: replace(method.params[k], initial=_inside(method.params[k], float(v)))
                for k, v in own.items()
            }
    ref = pooled.reference(
        mask,
        quantity="environment irradiance E(n) at the visible normals, unoccluded (W/m²)",
        integrator="environment irradiance (MIS: emitter + cosine sampling, no scene rays)",
        integrator_reason=(
            f"{kind}: the environment emitter alone, Mitsuba's Emitter.sample_direction and the cosine "
            "hemisphere combined by the balance heuristic, white Lambertian receiver at each visible normal"
        ),
    )
    sun = env.sun
    parameters = {
        "environment": app.part,
        "kind": env.kind,
        "bake_rows": BAKE_ROWS if env.radiance_map is not None else 0,
        "quadrature_rows": QUADRATURE_ROWS if env.radiance_map is not None else 0,
        "sun_angular_radius_deg": sun.angular_radius_deg if sun else 0.0,
        "lambda": float(bases["lambda"]),
        "cube_nnls_rms_rgb": [float(v) for v in np.ravel(bases["cube_nnls_rms"])],
        "pixels": int(mask.sum()),
    }
    notes = (
        "unoccluded: the environment alone, as an engine's probe gives it (no shadowing by the scene)",
        f"bases baked from the emitter: {BAKE_ROWS}×{2 * BAKE_ROWS} lat-long nodes"
        + (f" plus a disc sun of {sun.angular_radius_deg:.4g}°" if sun else "")
        + f"; Sloan's λ of this environment {bases['lambda']:.4g} (row sh-l2-lambda, then refitted)",
    )
    maps = lightmaps(setup, env)
    main = FamilyCase(
        id=tag,
        label=f"{app.part}, irradiance at the visible normals",
        reference=ref,
        channel_inputs=default,
        parameters=parameters,
        units="W/m²",
        notes=notes + ((maps,) if isinstance(maps, str) else ()),
        methods=dict(METHODS),
        params=params,
        row_inputs=row_inputs,
        uncosted={
            row_id: "its value, a dense quadrature of the environment at each normal, is computed outside "
            "the kernel (by the reference layer), which only passes it through"
            for row_id, method in METHODS.items()
            if method.exact
        },
    )
    if isinstance(maps, str):
        return [main]
    methods, texel_inputs = lightmap_rows(maps)
    sub = maps.mask[mask]
    return [
        main,
        FamilyCase(
            id=f"{tag}-lightmap",
            label=f"{app.part}, lightmap bases in the UV tangent frames",
            reference=texel_reference(ref, maps.mask),
            channel_inputs=({"nx": nx[sub], "ny": ny[sub], "nz": nz[sub], "sh": sh},),
            parameters={**parameters, "pixels": int(maps.mask.sum()), "frames": len(maps.frames)},
            units="W/m²",
            notes=maps.notes(),
            methods=methods,
            row_inputs=texel_inputs,
        ),
    ]


FAMILY = AuditFamily(
    name="irradiance-bases",
    quantity="environment_irradiance",
    cases=irradiance_bases_cases,
    describe=(
        "Per environment (envmap, constant, sunsky): its irradiance E(n) (W/m², RGB) at each visible "
        "normal, unoccluded, estimated by multiple importance sampling of that emitter alone (Mitsuba's "
        "sampling of it and the cosine hemisphere) in independent passes with per-pixel standard errors. "
        f"The emitter is baked into a lat-long map ({BAKE_ROWS} rows; a sunsky's sun as an exact disc) "
        "from which each basis bakes what an engine "
        "stores (SH projection to L4, the lower orders and ZH3 from it, Valve's axis cube, the NNLS "
        "cube, Sloan's λ per order, spherical-Gaussian lobe amplitudes, Ambient Dice's vertex values); each "
        "basis is evaluated on Dr.Jit at the visible normals. The exact row is the "
        "midpoint quadrature of the emitter itself (its eval at 256 × 512 cell centres; a sunsky's sun as an "
        "exact disc) at the same normals: it must sit at the reference's noise."
        f" ({math.pi:.4f}·L for a constant environment.)"
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "irradiance-bases",
            "environment irradiance",
            ("environment", "surface"),
            "{part} lights the visible normals from every direction",
            "the environment's irradiance E(n) at the visible normals, unoccluded",
            "emitter sampling of the environment alone (no scene rays); its dense quadrature as the exact "
            "row",
        ),
    ),
)
