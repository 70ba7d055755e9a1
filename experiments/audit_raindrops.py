r"""The ``raindrops`` family in `rtfit audit`: a water drop — a smooth dielectric sphere under a distant
environment — path traced, against the seed's Fresnel blend of a reflected and a once-refracted look-up
and the ray optics of a sphere (`rtfit.realtime.raindrops.METHODS`).

It applies to each smooth glass sphere of the scene (``glass-sphere``) when the scene has an environment; the
case is made only where the shape is what the rows assume, else none (the reason in the rule's words):

* a Mitsuba ``sphere`` (the exit directions are the sphere's: a mesh drop or another shape is left out);
* a smooth ``dielectric`` (a rough or thin one scatters or shifts the transmitted light) with
  η = int_ior/ext_ior in [`ETA_RANGE`] (water 1.33, glass 1.5: a drop, not a bubble or a gem);
* the camera outside it (pixels whose ray would start inside are dropped).

Per case ``drop<i>``:

* **pixels**: the pixel-centre camera rays whose first hit is the sphere (`shape_pixels`);
* **inputs** per pixel: the ray direction d (unit, float64), the outward normal n at the ray's exact
  float64 intersection with the sphere (centre and radius from its bounding box), the BSDF's η (read from
  the loaded plugin) and, per RGB channel, ``env``: the environment's cube map of `ENV_RESOLUTION`² texels a
  face, each texel Mitsuba's own ``emitter.eval`` at the texel's centre direction (what an engine bakes;
  deterministic, no sampling);
* **reference**: Mitsuba's ``path`` (unbounded depth, Russian roulette: every internal reflection) along
  those rays, in passes through the pass cache (`ray_radiance_pass`), W/(m²·sr);
* **the seed's claim** (000:852, "a drop tends to be much brighter than its background"): the case's
  parameters hold the mean of the reference over the drop's pixels, the mean of the background it hides
  (Mitsuba's ``emitter.eval`` along the same rays, the drop removed) and their ratio with its standard
  error; the study tabulates them per scene (reproduced where the ratio exceeds 1 by 3 s.e.).

Rows: ``seed`` (Schlick F, one refraction), ``seed-fitted`` (effective η and brightness), ``seed-opacity``
(the particle's Fresnel opacity over the background, edge strength and bias fitted), ``two-interface``,
``two-interface-1``, ``ray-optics`` (exit directions through the sphere, exact Fresnel, 0, 1 and
`ORDERS` internal reflections) and ``background`` (no drop). The cube map's texels and bilinear filter are
every row's own error floor: ``ray-optics`` is exact up to them and the orders it leaves out.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from rtfit.fitting import fit_method
from rtfit.realtime import NUMPY_OPS, drop_weights
from rtfit.realtime import environment_maps as em
from rtfit.realtime.raindrops import CAUSTIC_METHODS, ENV_RESOLUTION, METHODS, ORDERS, WATER_ETA
from rtfit.reference.cache import array_digest
from rtfit.reference.caustic_pass import caustic_profile
from rtfit.reference.reflective_shapes import ray_radiance_pass
from rtfit.reference.variants import scoped_variant

from .audit import Applicability, AuditError, Rule
from .audit_environment import scene_environment
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import reflective_shape, shape_view, visible_subset
from .audit_setup import AuditSetup, pooled_passes
from .case_inputs import rgb_columns, vector_text, xyz_columns
from .records import Check, Section
from .shipped import Sizes, Study, StudyContext

__all__ = [
    "ETA_RANGE",
    "FAMILY",
    "SCENES",
    "bake_cube",
    "caustic_study",
    "drop_cases",
    "eval_environment",
    "sphere_hits",
    "study",
    "transmitted_fraction",
]

FORMAT = 1
ETA_RANGE = (1.2, 1.6)
"""The relative indices of refraction audited as a drop (water 1.33 … dense glass)."""

_sizes = Sizes(full=(48, 48, 1024), quick=(20, 20, 64))
SCENES = tuple(
    _sizes.scene(
        "raindrops_drop.xml",
        f"a water drop (η = 1.33, r = 1 m) under the {label}, seen 11° from above",
        defines={"map": f"envmaps/{name}.exr"},
        name=f"drop-{name}",
        quick=name == "overcast",
    )
    for name, label in (
        ("overcast", "CIE overcast sky over a ground of albedo 0.2"),
        ("studio", "studio map (three soft boxes on a dark background)"),
    )
)
"""The scenes ``rtfit run raindrops`` audits: scenes/library/raindrops_drop.xml under two of rtfit's maps."""


def eval_environment(mi, emitter, dirs: np.ndarray) -> np.ndarray:
    """Mitsuba's radiance (N, 3) of the environment ``emitter`` towards the unit directions ``dirs`` (N, 3)
    (``emitter.eval`` with wi = −d: the radiance arriving from d), W/(m²·sr)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(dirs))
    si.wi = mi.Vector3f(np.ascontiguousarray(-np.asarray(dirs, np.float64).T, np.float32))
    value = np.array(emitter.eval(si), np.float64).reshape(3, -1).T
    if len(value) == 1:  # a constant emitter returns one colour for every direction
        return np.broadcast_to(value, (len(dirs), 3)).copy()
    return value


def bake_cube(mi, emitter, resolution: int = ENV_RESOLUTION) -> np.ndarray:
    """The environment's cube map (6N², 3) in `rtfit.realtime.environment_maps`' layout: Mitsuba's radiance
    at each texel's centre direction."""
    p = em.cube_texels(resolution)["point"]
    return eval_environment(mi, emitter, p / np.linalg.norm(p, axis=1, keepdims=True))


def sphere_hits(origins: np.ndarray, dirs: np.ndarray, centre, radius: float):
    """(hit points, outward unit normals, hit) of rays (origins, unit dirs: (N, 3)) against a sphere, in
    float64: the nearer root t = −b − √(b² − c) of |o + t·d − centre|² = r² where it is positive (``hit``
    False where the ray misses or starts inside)."""
    oc = origins - np.asarray(centre, np.float64)
    b = np.einsum("ij,ij->i", oc, dirs)
    c = np.einsum("ij,ij->i", oc, oc) - radius * radius
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    hit = (disc >= 0.0) & (c > 0.0) & (t > 0.0)
    p = origins + t[:, None] * dirs
    n = (p - np.asarray(centre, np.float64)) / radius
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return p, n, hit


def _shape(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "raindrops", check_label=False)


def _environment(setup: AuditSetup):
    part = setup.info.first("environment")
    if part is None or part.source is None:
        raise AuditError("raindrops: the scene has no environment")
    return scene_environment(setup, part.source, "raindrops")


def _sphere(mi, shape) -> tuple[np.ndarray, float] | None:
    """(centre, radius) of a Mitsuba sphere from its bounding box; None for another shape or a box that is
    not a cube (a sphere scaled unevenly is not one)."""
    if shape.shape_type() != int(mi.ShapeType.Sphere):
        return None
    box = shape.bbox()
    lo, hi = np.array(box.min, np.float64), np.array(box.max, np.float64)
    half = 0.5 * (hi - lo)
    if not np.allclose(half, half[0], rtol=1e-5):
        return None
    return 0.5 * (lo + hi), float(half[0])


def _eta(mi, shape, plugin: str) -> float | None:
    if plugin != "dielectric":
        return None
    params = mi.traverse(shape.bsdf())
    if "eta" not in params.keys():
        return None
    return float(np.array(params["eta"], np.float64).reshape(-1)[0])


def _brightness(ref, err, background) -> dict:
    """The drop's mean radiance over its pixels (channels' mean) against the background it hides."""
    drop = float(np.mean(ref))
    se = float(np.sqrt(np.sum(err**2)) / err.size)
    back = float(np.mean(background))
    ratio = drop / back if back > 0.0 else math.inf
    return {
        "drop_mean": drop,
        "drop_mean_stderr": se,
        "background_mean": back,
        "brightness_ratio": ratio,
        "brightness_ratio_stderr": se / back if back > 0.0 else math.inf,
    }


def drop_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per smooth dielectric sphere of η in `ETA_RANGE` the camera sees (module docstring)."""
    mi, scene = setup.mi, setup.scene
    index, shape, plugin = _shape(setup, app)
    sphere = _sphere(mi, shape)
    eta = _eta(mi, shape, plugin)
    if sphere is None or eta is None or not ETA_RANGE[0] <= eta <= ETA_RANGE[1]:
        return []
    centre, radius = sphere
    env = _environment(setup)
    origins, dirs, sees = shape_view(setup, index)
    _, normals, hit = sphere_hits(origins, dirs, centre, radius)
    keep = sees & hit
    if not keep.any():
        return []
    mask = visible_subset(setup.mask, keep)
    origins, dirs, normals = origins[keep], dirs[keep], normals[keep]
    t0 = time.perf_counter()
    cube = bake_cube(mi, env.emitter)
    background = eval_environment(mi, env.emitter, dirs)
    bake_seconds = time.perf_counter() - t0
    tag = f"drop{index}"
    pooled = pooled_passes(
        setup,
        {"format": FORMAT, "quantity": "drop-radiance", "shape": index, "rays": array_digest(origins, dirs)},
        lambda spp, seed: ray_radiance_pass(mi, scene, origins, dirs, spp, seed),
        (-1, 3),
        f"{tag}: {app.part}",
    )
    ref = pooled.reference(
        mask,
        quantity="radiance of the pixels that see the drop (W/m²/sr)",
        integrator="path (unbounded depth, Russian roulette) along the pixel-centre camera rays",
        integrator_reason="Mitsuba's dielectric BSDF: every reflection and refraction through the drop",
        extra_seconds=bake_seconds,
    )
    geometry = {**xyz_columns("d", dirs), **xyz_columns("n", normals)}
    channels = ({**geometry, "eta": eta, **rgb_columns("env", cube)},)
    bright = _brightness(pooled.mean, pooled.stderr, background)
    cos_in = -np.einsum("ij,ij->i", dirs, normals)
    eta_eff = dataclasses.replace(METHODS["seed-fitted"].params["eta_eff"], initial=eta)
    verdict = (
        "brighter"
        if bright["brightness_ratio"] > 1.0 + 3.0 * bright["brightness_ratio_stderr"]
        else "not brighter"
    )
    return [
        FamilyCase(
            id=tag,
            label=f"{app.part}, drop radiance",
            reference=ref,
            channel_inputs=channels,
            parameters={
                "shape": app.part,
                "eta": eta,
                "centre": [float(c) for c in centre],
                "radius": radius,
                "environment": f"{env.kind} ({env.where})",
                "env_resolution": ENV_RESOLUTION,
                "pixels": int(mask.sum()),
                **bright,
            },
            units="W/m²/sr",
            notes=(
                f"sphere at {vector_text(centre)}, r = {radius:.4g}, η = {eta:.4g}; cos θ_i from "
                f"{cos_in.min():.3g} to {cos_in.max():.3g} over {int(mask.sum())} pixels",
                f"environment: {env.kind} ({env.where}) baked into a cube map of {ENV_RESOLUTION}² texels a "
                "face (Mitsuba's emitter.eval at texel centres); the rows read it bilinearly",
                f"the seed's claim (000:852): drop mean {bright['drop_mean']:.4g} ± "
                f"{bright['drop_mean_stderr']:.2g} vs the background it hides "
                f"{bright['background_mean']:.4g} (ratio {bright['brightness_ratio']:.3g}): {verdict}",
                f"ray-optics sums {ORDERS} internal reflections; two-interface(-1) 0 (1)",
            ),
            params={"seed-fitted": {"eta_eff": eta_eff}},
        )
    ]


FAMILY = AuditFamily(
    name="raindrops",
    quantity="drop_radiance",
    cases=drop_cases,
    describe=(
        "Per smooth dielectric sphere (η 1.2–1.6: a water or glass drop) under the scene's environment: the "
        "radiance of the pixels that see it, path traced (unbounded depth), against the seed's Fresnel blend "
        "of a reflected and a once-refracted environment look-up (000:822-887: Schlick F, one refraction; "
        "fitted effective η and brightness; the particle's Fresnel opacity over its background), the ray "
        "optics of a sphere (exit directions after two refractions, exact Fresnel, 0, 1 and "
        f"{ORDERS} internal reflections) and the background the drop hides; every row reads one cube map of "
        f"the environment ({ENV_RESOLUTION}² a face). The seed's claim that a drop is brighter than its "
        "background is measured per case."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "raindrops",
            "drop",
            ("glass-sphere", "environment"),
            "{part} under {with_}: a drop where its η is 1.2–1.6 (water 1.33, glass 1.5; other η give no "
            "case), an engine shades it as a refracted and a reflected "
            "environment look-up with a Fresnel blend",
            "path-traced radiance of the pixels that see the drop (W/m²/sr, RGB)",
            "path (unbounded depth, Russian roulette) along the pixel-centre camera rays; the environment's "
            "cube map from Mitsuba's emitter",
            supplies=frozenset({"dx", "dy", "dz", "nx", "ny", "nz", "eta", "env_r", "env_g", "env_b"}),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ study
def study(ctx: StudyContext) -> Study:
    """Per scene: the drop's brightness against the background it hides (the seed's claim, 000:852), and
    each row's RMSE over the reference's noise floor beside its measured cost."""
    claim = [
        "| case | drop mean | background mean | ratio | verdict (3 s.e.) |",
        "|---|---|---|---|---|",
    ]
    rows = [
        "| case | row | RMSE | RMSE / floor | mean / background mean | ns/px |",
        "|---|---|---|---|---|---|",
    ]
    for result in ctx.audits:
        for case in result.cases:
            p = case.parameters
            if "brightness_ratio" not in p:
                continue
            ratio, se = p["brightness_ratio"], p["brightness_ratio_stderr"]
            verdict = "reproduced" if ratio > 1.0 + 3.0 * se else "refuted" if ratio < 1.0 - 3.0 * se else "—"
            claim.append(
                f"| {case.id} | {p['drop_mean']:.4g} ± {p['drop_mean_stderr']:.2g} | "
                f"{p['background_mean']:.4g} | {ratio:.3g} ± {se:.2g} | {verdict} |"
            )
            for row_id, out in result.outcomes.get(case.id, {}).items():
                rmse = out.metrics["rmse"]
                floor = rmse.value / rmse.noise_floor if rmse.noise_floor else float("nan")
                cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
                ns = f"{cost:.3g}" if cost else "—"
                mean = (
                    float(np.mean(out.image[case.mask])) / p["background_mean"]
                    if p["background_mean"]
                    else 0.0
                )
                rows.append(f"| {case.id} | {row_id} | {rmse.value:.4g} | {floor:.3g} | {mean:.3g} | {ns} |")
    text_claim = (
        'The seed (000:852): "a drop tends to be much brighter than its background (the portion of the '
        "scene it occludes)\". Mean path-traced radiance over the drop's pixels against the mean of the "
        "environment along the same rays without the drop (channels' mean).\n\n" + "\n".join(claim)
    )
    text_rows = (
        "Each row's RMSE, its ratio to the reference's noise floor, its mean over the drop against the "
        "background's (does the shortcut make the drop brighter?) and the kernel's ns/px.\n\n"
    )
    caustic, checks = caustic_study(ctx.variant, ctx.quick, ctx.seed)
    return Study(
        sections=(
            Section("drop-brightness", "Is the drop brighter than its background?", text_claim),
            Section("error-cost", "Error beside cost", text_rows + "\n".join(rows)),
            caustic,
        ),
        checks=checks,
    )


# ------------------------------------------------------------------------- the droplet's shadow (000:1010)
CAUSTIC_RAYS = {True: 100_000, False: 1_000_000}
"""Light rays of the shadow's light tracing (--quick, full)."""
FLOOR_GAP = 0.05
"""The drop's lowest point above the floor (in radii)."""
_EDGES = np.linspace(0.0, 1.5, 31)  # annuli of R/20 out to 1.5 R


def transmitted_fraction(eta: float, nodes: int = 200) -> float:
    """τ = (1/πR²)∫(1 − F)² dA over the drop's disk with the sun overhead = ∫₀¹ (1 − F(c))²·2c dc (the
    order-0 weight of `drop_weights`, Gauss–Legendre in c = cos θ_i): the light crossing the drop."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    c = 0.5 * (x + 1.0)
    _, weights = drop_weights(c, eta, 0)
    return float(np.sum(0.5 * w * np.asarray(weights[0]) * 2.0 * c))


def caustic_study(variant: str, quick: bool, seed: int) -> tuple[Section, tuple[Check, ...]]:
    """The seed's pseudo-caustic (000:1010): a water drop (R = 1 m, η = 1.33) resting `FLOOR_GAP` R above a
    diffuse floor under the sun overhead (E⊥ = 1 W/m²); the floor's irradiance by light tracing
    (`caustic_profile`, Mitsuba's dielectric) per annulus about the shadow's centre, against a shadow map
    alone, the seed's spot (A, σ fitted) and a spot carrying the drop's transmitted flux τπR²E⊥ (σ fitted).
    Check: the flux landing in the shadow is τπR²E⊥ within 3 s.e. (energy conservation; the first internal
    reflection leaves upwards: the rainbow)."""
    with scoped_variant(variant) as mi:
        scene = mi.load_dict(
            {
                "type": "scene",
                "drop": {
                    "type": "sphere",
                    "radius": 1.0,
                    "bsdf": {"type": "dielectric", "int_ior": WATER_ETA},
                },
                "floor": {
                    "type": "rectangle",
                    "to_world": mi.ScalarTransform4f().translate([0.0, 0.0, -1.0 - FLOOR_GAP]).scale(20.0),
                    "bsdf": {"type": "diffuse"},
                },
            }
        )
        prof = caustic_profile(mi, scene, 1.0, 1.0, _EDGES, CAUSTIC_RAYS[quick], seed)
    tau = transmitted_fraction(WATER_ETA)
    r, target, err = prof.centres, prof.irradiance, prof.stderr
    area = math.pi * (_EDGES[1:] ** 2 - _EDGES[:-1] ** 2)
    shade = _EDGES[1:] <= 1.0
    flux = float(np.sum(target[shade] * area[shade])) / math.pi
    flux_se = float(np.sqrt(np.sum((err[shade] * area[shade]) ** 2))) / math.pi
    inputs = {"r": r, "radius": 1.0, "e_sun": 1.0, "transmitted": tau}
    lines = ["| row | fitted | RMSE (W/m²) | RMSE / floor |", "|---|---|---|---|"]
    floor = float(np.sqrt(np.mean(err**2)))
    for mid, m in CAUSTIC_METHODS.items():
        g = {k: inputs[k] for k in m.input_names}
        values = {}
        if m.params:
            fit = fit_method(m, g, target, solver="trf")
            values = dict(fit.values)
        model = np.asarray(m(NUMPY_OPS, g, values), np.float64) * np.ones_like(r)
        rmse = float(np.sqrt(np.mean((model - target) ** 2)))
        text = ", ".join(f"{k} = {v:.3g}" for k, v in values.items()) or "—"
        lines.append(f"| {mid} | {text} | {rmse:.3g} | {rmse / floor:.3g} |")
    peak = int(np.argmax(np.where(shade, target, 0.0)))
    dark = shade & (target < 0.05)
    text = (
        f"A water drop (R = 1 m, η = {WATER_ETA}) {FLOOR_GAP:g} R above a diffuse floor, the sun overhead "
        f"(E⊥ = 1 W/m²); the floor's irradiance per annulus of R/20 by light tracing through Mitsuba's "
        f"dielectric ({prof.rays} rays, {prof.seconds:.3g} s; reference/caustic_pass.py). The pseudo-caustic "
        f"is real: the drop focuses the light crossing it (τ = {tau:.4f} of its disk, (1 − F)² of the ray "
        f"optics) into a spot of radius {float(_EDGES[peak + 1]):.2g} R peaking at "
        f"{float(target[peak]):.3g} × E⊥ at its rim (r = {float(r[peak]):.3g} R: the caustic's edge), "
        f"dark ({int(dark.sum())} annuli below 0.05 E⊥) out to the shadow's edge. Flux in the shadow: "
        f"{flux:.4f} ± {flux_se:.1g} πR²E⊥ against τ = {tau:.4f}.\n\n" + "\n".join(lines)
    )
    check = Check(
        name="the flux landing in the drop's shadow is the flux crossing it, τπR²E⊥ (3 s.e.)",
        value=flux,
        expected=f"{tau:.4f} ± {3 * flux_se:.2g}",
        passed=abs(flux - tau) <= 3.0 * flux_se,
    )
    return Section("pseudo-caustic", "The droplet's pseudo-caustic (000:1010)", text), (check,)
