"""The ``ambient-aperture`` family in `rtfit audit`, roles "ambient occlusion (aperture caps)" and "occluded
sphere light": each visible point's visibility cap, on the scene's own geometry and camera.

Ambient aperture lighting (Oat & Sander 2007; `rtfit.realtime.ambient_aperture`) stores a point's visibility
as one spherical cap: a unit bent normal a and an aperture r_a. Here the cap of every visible pixel is baked
as an engine bakes it (seed 000:2660-2670) and as the aperture-fill role bakes its own
(`rtfit.reference.occlusion.visibility_cap_pass`, the same function), with
Mitsuba ray casts against the scene's own shapes (`bake_caps`): ``--spp`` directions ω uniform over the
hemisphere of the pixel's normal n, V(ω) = 1 where the ray escapes,

    V̂ = mean V(ω),   a = normalize(mean V(ω) ω),   r_a = acos(1 − V̂)   (`aperture_from_visibility`),

a = n where nothing escapes, in passes through the pass cache (a rerun reads them back). The caps are baked
by rays of their own, not from the references' rays: the pass cache keeps only each reference's pooled
mean, and a bent normal needs the directions. The distance field is not used (its 64³ voxels blur the
creases that decide the cap). The bake's own noise (binomial: ≤ 0.031 in V̂ at 256 spp) is part of what is
compared, as an engine's bake's is.

Case ``caps`` (role "ambient occlusion (aperture caps)"): the cap against ray-cast AO within R.

* Reference: the sdf-occlusion AO role's ray-cast ambient occlusion A = (1/π)∫ V_R (n·ω) dω within
  R = ``--ao-distance`` (`audit_ambient_occlusion.ao_reference`: the same cache entry, rendered once for
  both families). The caps are baked with rays of length R (every shape occludes, the lights' too, as in
  the reference).
* Rows: the second cap is the point's own hemisphere (centre n, radius π/2) and its "radiance" is 1/π, so
  that every irradiance form of the table reads AO:

  - ``aa-<form>-<lambert>``: A ≈ (1/π)·Ω_form(r_a, π/2, ∠(a, n))·max(n·c, 0), the light term of the table
    (`METHODS` rows, their kernel text) with l = n, α = π/2: the four intersection forms (``exact``,
    ``smoothstep``, ``linear``, ``fitted``: c0..c5 fitted to this scene) and the two Lambert factors (the
    seed's plain average, the fitted cap-size weight: k fitted). Under an open sky (a = n, r_a = π/2) they
    read 2, not 1: the Lambert factor treats the intersection as a small cap around its centroid, which the
    hemisphere is not (Ω·cos = 2π·1 where ∫cos dω = π). The rows show how far that is on a real scene.
  - ``fill-projected``: A_cap = P(n·a, r_a)/π, the exact projected solid angle of the cap, clipped at the
    horizon: what AO would be if visibility were exactly the baked cap. Its error is the cap model's own.
  - ``fill-seed``: A ≈ A(r_a)·max(n·a, 0)/π, the seed's fill (000:2774-2782): 2 under an open sky.

  The bare intersection forms (r1, r2, d → Ω in sr) are compared at the function level by the
  family's study (`ambient_aperture_study`, in ``rtfit run ambient-aperture``); here each is a part of its
  ``aa-<form>-*`` rows. A user approximation of ``ambient_occlusion`` is evaluated here too (the AO role's
  inputs, the scene's distance field included).

Case ``light<i>-occluded`` (role "occluded sphere light", per spherical light): that light's direct
irradiance with the scene's occluders against the ambient-aperture light term.

* Reference: the diffuse family's **shadowed** irradiance of that light (`audit_lights.light_reference`:
  Mitsuba's emitter sampling of the light alone with shadow rays; the same cache entry as the diffuse
  family's, rendered once for both). W/m², RGB. The light is a Mitsuba XML emitter or an rtfit TOML light
  (a ``sphere_light``, a ``sun`` of finite angular radius, a ``sunsky``'s sun: `audit_lights.scene_light`).
* Caps: baked with unbounded rays, the emitters' own shapes seen through (a light does not occlude itself;
  the experiment bakes the scene without its lights).
* Rows: every ``aa-*`` row of `METHODS`: E ≈ L·Ω(r_a, α, ∠(a, l))·max(n·c, 0) with l towards the light's
  centre, α = asin(r/d), L the light's radiance (the diffuse family's inputs, `light_geometry`,
  `light_radiance`); the fitted forms' c0..c5 and k fitted to this scene. A user approximation of
  ``light_irradiance`` is a row here only when ``--approx`` names this family too (alone it runs the diffuse
  family, whose shadowed case gives it the hard shadow it lacks); it gets cos_theta = n·l, E⊥, α and the
  distance, as in the diffuse family, and is compared with the shadowed irradiance as it is.

Neither case has an exact row (the cap is a model of the visibility), so neither has a z-score self-check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rtfit.realtime.ambient_aperture import METHODS, aperture_from_visibility
from rtfit.realtime.arrays import NUMPY_OPS, xyz_columns
from rtfit.realtime.sdf_occlusion import CURVATURE_LEVEL
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.occlusion import visibility_cap_pass

from .audit import Applicability, AuditError, Rule
from .audit_ambient_occlusion import ao_reference, scene_distance_field
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import ao_radius
from .audit_lights import light_geometry, light_radiance, light_reference, scene_light
from .audit_setup import AuditSetup, pooled_passes
from .shipped import Sizes

__all__ = ["CAPS_ROLE", "FAMILY", "LIGHT_ROLE", "SCENES", "BakedCaps", "bake_caps"]

CAPS_ROLE = "ambient occlusion (aperture caps)"
LIGHT_ROLE = "occluded sphere light"
FORMAT = 1
LIGHT_ROWS = tuple(m for m in METHODS if m.startswith("aa-"))
CAP_ROWS = tuple(m for m in METHODS if m.startswith(("aa-", "fill-")))
_CAP_LABELS = {
    "fill-projected": "Cap model: projected solid angle of the cap / π (exact for a cap)",
    "fill-seed": "Seed fill: A(r_a)·max(n·a, 0) / π",
}


@dataclass(frozen=True)
class BakedCaps:
    """Per point: the visible fraction V̂ of uniform hemisphere directions, its standard error, the unit bent
    normal a (N, 3) and the aperture r_a = acos(1 − V̂) (rad, [0, π/2]); ``n_dirs`` rays per point, in
    ``passes`` passes (``passes_rendered`` by this run) taking ``seconds``."""

    visible_fraction: np.ndarray
    stderr: np.ndarray
    bent_normal: np.ndarray
    aperture: np.ndarray
    n_dirs: int
    passes: int = 0
    passes_rendered: int = 0
    seconds: float = 0.0


def bake_caps(
    setup: AuditSetup,
    points,
    normals,
    *,
    max_distance: float = math.inf,
    see_through_emitters: bool = False,
    label: str = "caps",
) -> BakedCaps:
    """The visibility cap of each point (module docstring): `visibility_cap_pass` (uniform hemisphere rays
    against the scene's own shapes, of length ``max_distance``; ``see_through_emitters``: a ray that hits an
    emitter's shape escapes) in `setup.spp` samples per point through the pass cache (`pooled_passes`)."""
    p = np.ascontiguousarray(points, np.float64)
    n = np.ascontiguousarray(normals, np.float64)
    what: dict = {"format": FORMAT, "quantity": "visibility-caps", "points": array_digest(p, n)}
    if math.isfinite(max_distance):
        what["max_distance"] = float(max_distance)
    if see_through_emitters:
        what["see_through_emitters"] = True

    def render(spp: int, seed: int):
        return visibility_cap_pass(
            setup.mi, setup.scene, p, n, spp, seed, max_distance, see_through_emitters=see_through_emitters
        )

    bake = pooled_passes(setup, what, render, (-1, 5), label, seed_label="cap-pass")
    visible = np.clip(bake.mean[:, 0], 0.0, 1.0)
    bent = bake.mean[:, 2:5]
    norm = np.linalg.norm(bent, axis=1, keepdims=True)
    bent = np.where(norm > 1e-12, bent / np.maximum(norm, 1e-300), n)
    aperture = np.asarray(aperture_from_visibility(visible), np.float64)
    return BakedCaps(
        visible, bake.stderr[:, 0], bent, aperture, bake.spp, bake.passes, bake.passes_rendered, bake.seconds
    )


def _cap_parameters(caps: BakedCaps) -> dict:
    return {
        "bake_dirs": caps.n_dirs,
        "mean_visible_fraction": float(caps.visible_fraction.mean()) if caps.aperture.size else 0.0,
        "mean_aperture_deg": float(np.degrees(caps.aperture).mean()) if caps.aperture.size else 0.0,
        "max_bake_stderr": float(caps.stderr.max()) if caps.aperture.size else 0.0,
    }


def _bake_note(caps: BakedCaps, reach: str) -> str:
    p = _cap_parameters(caps)
    return (
        f"caps baked per pixel by {caps.n_dirs} Mitsuba ray casts ({reach}) uniform over the hemisphere, "
        f"in {caps.passes} passes: mean visible fraction {p['mean_visible_fraction']:.3f}, "
        f"mean aperture {p['mean_aperture_deg']:.1f}°, bake standard error ≤ {p['max_bake_stderr']:.3f}"
    )


def caps_case(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The ``caps`` case: the baked caps against the AO role's ray-cast AO within R (module docstring)."""
    radius = ao_radius(setup, "ambient-aperture")
    mask = setup.mask
    points, normals = gbuffer_points(setup.gbuffer, mask)
    ao = ao_reference(setup, points, normals, radius, f"ao: {app.part}")
    caps = bake_caps(setup, points, normals, max_distance=radius, label=f"caps: {app.part}")
    cos_na = np.clip(np.sum(normals * caps.bent_normal, axis=1), -1.0, 1.0)
    # The AO role's inputs, for a user approximation of ambient_occlusion (the same distance field).
    sdf, sign, _shapes = scene_distance_field(setup.mi, setup.scene, radius, setup.cache_root)
    blurred = sdf.sample(NUMPY_OPS, CURVATURE_LEVEL, *points.T)
    inputs = {
        "cos_na": cos_na,
        "cos_nl": np.ones(len(points)),
        "cos_al": cos_na,
        "aperture": caps.aperture,
        "alpha": 0.5 * math.pi,
        "radiance": 1.0 / math.pi,
        "sky_radiance": 1.0 / math.pi,
        **xyz_columns("p", points),
        **xyz_columns("n", normals),
        "sdf": sdf,
        "t0": float(sdf.voxel),
        "t_max": radius,
        "ao_distance": radius,
        "distance": np.asarray(blurred, np.float64),
    }
    methods = {}
    for rid in CAP_ROWS:
        if rid not in app.methods:
            continue
        m = METHODS[rid]
        label = _CAP_LABELS.get(rid, f"{m.label}, cap ∩ hemisphere")
        formula = (
            f"(1/π)·{m.formula}" if rid.startswith("aa-") else f"(1/π)·{m.formula.replace('L_sky·', '')}"
        )
        methods[rid] = replace(m, label=label, formula=formula, exact=False)
    ref = ao.reference(
        mask,
        quantity=f"ambient occlusion within R = {radius:.4g} (1: unoccluded)",
        integrator=f"occlusion pass (cosine-distributed rays of length R = {radius:.4g})",
        integrator_reason="the sdf-occlusion AO role's reference (same cache entry): V_R(ω) with ω ~ cos/π",
        extra_seconds=caps.seconds,
    )
    return [
        FamilyCase(
            id="caps",
            label=f"{app.part}: visibility caps against ambient occlusion within R = {radius:.4g}",
            reference=ref,
            channel_inputs=(inputs,) * 3,
            parameters={"ao_distance": radius, "pixels": int(mask.sum()), **_cap_parameters(caps)},
            units="1",
            notes=(
                _bake_note(caps, f"of length R = {radius:.4g}, every shape occluding"),
                "second cap: the point's own hemisphere (centre n, radius π/2) with radiance 1/π, so that "
                "the light terms read AO; under an open sky the aa-* rows and the seed fill read 2 (the "
                "centroid's Lambert factor on a hemisphere), the projected-cap row 1",
                f"distance field for your ambient_occlusion approximations: sign by {sign}",
            ),
            methods=methods,
            quantity="ambient_occlusion",
        )
    ]


def light_case(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The ``light<i>-occluded`` case of the spherical light ``app.source`` (module docstring)."""
    if app.source is None:
        raise AuditError(f"ambient-aperture: {app.part} is not a light of the scene")
    light = scene_light(setup, app.source)  # either format; an environment (not a light) → AuditError
    mask = setup.mask
    points, normals = gbuffer_points(setup.gbuffer, mask)
    towards, dist, alpha, _centre, _radius = light_geometry(setup, app.source, points)
    tag = f"light{app.source}"
    pooled = light_reference(setup, app.source, points, normals, towards, f"{tag}: {app.part}")
    caps = bake_caps(setup, points, normals, see_through_emitters=True, label=f"caps: {app.part}")
    a = caps.bent_normal
    e_perp = pooled.mean[:, 6:9]
    radiance = light_radiance(setup, app.source, e_perp, alpha)
    cos_nl = np.clip(np.sum(normals * towards, axis=1), -1.0, 1.0)
    common = {
        "cos_na": np.clip(np.sum(normals * a, axis=1), -1.0, 1.0),
        "cos_nl": cos_nl,
        "cos_al": np.clip(np.sum(a * towards, axis=1), -1.0, 1.0),
        "aperture": caps.aperture,
        "alpha": alpha,
        "cos_theta": cos_nl,
        "distance": dist,
    }
    inputs = tuple({**common, "irradiance": e_perp[:, c], "radiance": radiance[c]} for c in range(3))
    methods = {rid: METHODS[rid] for rid in LIGHT_ROWS if rid in app.methods}
    ref = pooled.reference(
        mask,
        quantity="direct irradiance of one sphere light with the scene's occluders (W/m²)",
        integrator="light-irradiance (emitter sampling, shadow rays)",
        integrator_reason=(
            f"{light.kind} light: the diffuse family's shadowed reference (same cache entry): Mitsuba "
            "emitter sampling of this light alone with shadow rays, white Lambertian receiver"
        ),
        columns=slice(3, 6),
        extra_seconds=caps.seconds,
    )
    return [
        FamilyCase(
            id=f"{tag}-occluded",
            label=f"{app.part}, occluded: visibility cap ∩ light cap",
            reference=ref,
            channel_inputs=inputs,
            parameters={
                "light": app.part,
                "kind": light.kind,
                "alpha_max_deg": float(np.degrees(alpha.max())) if alpha.size else 0.0,
                "pixels": int(mask.sum()),
                **_cap_parameters(caps),
            },
            units="W/m²",
            notes=(
                _bake_note(caps, "unbounded, the emitters' shapes seen through"),
                "reference: the light's shadowed irradiance (soft shadows of the scene's occluders)",
            ),
            methods=methods,
            quantity="light_irradiance",
        )
    ]


_CASES = {CAPS_ROLE: caps_case, LIGHT_ROLE: light_case}


def ambient_aperture_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The cases of one applicability: by its role (`CAPS_ROLE`, `LIGHT_ROLE`)."""
    if app.role not in _CASES:
        raise AuditError(f"ambient-aperture: the {app.role} role is not audited by this module")
    return _CASES[app.role](setup, app)


FAMILY = AuditFamily(
    name="ambient-aperture",
    # The caps case compares AO, so a user's ambient_occlusion approximation brings this family in beside
    # sdf-occlusion. The occluded-light case compares light_irradiance, but it is not listed in
    # ``quantities``: a user's light formula (a wrap) reads no visibility, so `--approx my_wrap.py:f` alone
    # runs the diffuse family (with its hard-shadow case) and not this one; named together with
    # ``ambient-aperture`` it is a row of the occluded-light case too.
    quantity="ambient_occlusion",
    cases=ambient_aperture_cases,
    describe=(
        "Each visible pixel's visibility cap (bent normal and aperture r_a = acos(1 − V), V the visible "
        "fraction of --spp uniform hemisphere directions cast with Mitsuba against the scene's own "
        "shapes). Aperture caps: the cap intersected with the pixel's own hemisphere (each intersection form "
        "and Lambert factor, read as AO with radiance 1/π), the exact projected solid angle of the cap and "
        "the seed's fill, against the sdf-occlusion role's ray-cast AO within R (the same reference). "
        "Occluded sphere light: the cap intersected with the light's cap, L·Ω·max(n·c, 0), against that "
        "light's shadowed direct irradiance (the diffuse family's reference). The fitted forms' "
        "coefficients and the Lambert exponent are fitted to this scene."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "ambient-aperture",
            "ambient occlusion (aperture caps)",
            ("sdf-geometry",),
            "{part} occludes itself: each point's visible cap (bent normal, aperture) against its hemisphere",
            "ray-cast ambient occlusion within R = {ao_distance}, and each point's visibility cap baked by "
            "ray casts of length R",
            "occlusion pass: cosine-distributed rays of length R = {ao_distance}",
            # The caps are intersected with the point's own hemisphere (the second cap: centre n, radius π/2,
            # radiance 1/π, so that the light terms read AO), and the fills read 1/π as their sky.
            frozenset({"cos_nl", "cos_al", "alpha", "radiance", "sky_radiance"}),
        ),
        Rule(
            "ambient-aperture",
            "occluded sphere light",
            ("spherical-light", "geometry"),
            "{part} is partly hidden by {with_}",
            "that light's direct irradiance with visibility at the visible points",
            "direct, that light alone (shadow rays)",
        ),
    ),
)


QUICK_ROLES = ("sky occlusion (aperture fill)", LIGHT_ROLE)
"""The roles ``--quick`` audits (the fill's role is declared by `audit_sky_occlusion`; `engine_run` checks
every name): not the AO caps (their bake and AO reference), which the full run audits."""

_sizes = Sizes(full=(64, 64, 8192), quick=(24, 24, 1024))
SCENES = (
    _sizes.scene(
        "aperture_hole.toml",
        "white floor under a plate with a circular hole (radius 0.6, 1 up), seen from under the plate; a "
        "sphere light above, offset, and a constant sky of radiance 1",
        quick_roles=QUICK_ROLES,
    ),
    _sizes.scene(
        "aperture_well.toml",
        "white floor of an open cylindrical well (radius 0.7, depth 1.2), seen down its axis; a sphere light "
        "above, offset, and a constant sky of radiance 1",
        quick_roles=QUICK_ROLES,
    ),
    _sizes.scene(
        "aperture_bumps.toml",
        "white height field of six Gaussian bumps under a low sphere light (soft shadows of the bumps on "
        "each other) and a constant sky of radiance 1",
        quick_roles=QUICK_ROLES,
    ),
)
"""The scenes ``rtfit run ambient-aperture`` audits (scenes/library/aperture_*.toml): the three receivers of
the experiment before the engine (a hole in a plate, a well, bumps), each with its sphere light and a
constant sky of radiance 1, the camera on the receiver. Every role applies to each: the occluded sphere
light (the cap ∩ the light's cap against the shadowed irradiance), the aperture fill (the cap's fill against
the occluded sky) and the aperture caps (against ray-cast AO within R)."""
