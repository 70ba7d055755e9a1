r"""The ``obscurances`` family in `rtfit audit`: Zhukov/Iones obscurances of the scene's own geometry, on the
scene's own camera (Mitsuba XML or rtfit TOML).

At each visible point x with unit normal n (the pixel-centre G-buffer, `rtfit.reference.gbuffer_points`) the
obscurance with distance function ρ is

    W(x) = (1/π) ∫_{H(n)} ρ(d(x, ω)) (n·ω) dω,   d = distance to the first surface along ω (∞: a miss),

the quantity of `rtfit.realtime.obscurances` (GameTools D5.3 §2.10, 001:3251-3380). The scale is the scene's
AO radius R (``--ao-distance``, else `rtfit.experiments.audit.AO_FRACTION` × the bounding-box diagonal, as
the sdf-occlusion audit uses it): the seed's d_max = 0.3 (001:3326) is in the units of the seed's meshes, so
here d_max = R wherever a row declares it, and the fitted d_max starts at R with bounds [10⁻³ R, 10³ R].

Two references per scene, each by Mitsuba ray casts from the visible points (`rtfit.reference.occlusion`,
cosine-distributed directions, independent passes through the pass cache, per-pixel standard errors):

* ``obscurance`` — the model itself: W with the seed's ρ = min(d/R, 1)^½ (`distance_weight`, the kernel
  text's own ρ). Exact for the model: the rows' error against it is the K-ray estimator's error (and, for
  the other ρ, the difference of the forms);
* ``ambient_global`` — what obscurances stand in for: E(x)/(πL) under a uniform ambient of radiance L (the
  whole sphere, no horizon) with every interreflection between white diffuse surfaces of albedo
  `AMBIENT_ALBEDO` (Russian roulette): 1 at an unoccluded point, as W is.

Rows (`rtfit.realtime.obscurances.METHODS`), all on the same K = `RAYS` hit distances per point
(`hit_distances` along `cosine_spiral_directions`, rotated per point: the real-time bake): ``seed`` (ρ = √,
d_max = R), ``power`` (d_max, p, s fitted), ``exponential`` (d_max, s fitted), ``ao`` (the step ρ: AO within
d_max, d_max fitted). A row reads its K distances as K per-pixel inputs d1..dK (`on_rays`: the table's own
kernel given the tuple); a miss is given as `MISS` (finite, so that JAX fits and float32 costs stay finite:
every ρ is 1 there for d_max ≤ 10²⁸). A user's ``@approximation(quantity="obscurance")`` reads the same
K distances as ``g.distances`` (a tuple of K per-pixel arrays: `on_rays` adapts it as it adapts the rows).
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import numpy as np

from rtfit.realtime.methods import Input, Method
from rtfit.realtime.obscurances import (
    METHODS,
    MISS,
    SEED_D_MAX,
    SEED_EXPONENT,
    cosine_spiral_directions,
    distance_weight,
)
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.occlusion import hit_distances, occlusion_pass

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import ao_radius, sdf_scene
from .audit_setup import AuditSetup, pooled_passes

__all__ = ["AMBIENT_ALBEDO", "FAMILY", "MISS", "RAYS", "SCENES", "obscurance_cases", "on_rays"]

FORMAT = 1
RAYS = 32
"""Rays per point of the rows' estimator (the obscurances experiment's quick ``fit_rays``)."""
AMBIENT_ALBEDO = 0.8
"""Albedo of every surface in the uniform-ambient reference (the obscurances experiment's ``albedo``)."""
ROLE = "obscurance"
DRJIT_FITS = ("power", "ao")
"""Rows whose fits evaluate the kernel text on Dr.Jit's float64 arrays (`Method.fit_ops` ``"drjit"``), not
NumPy's: K = `RAYS` values of ρ a point each evaluation, and NumPy's float64 ``exp`` and ``log`` are scalar
calls on a CPU without AVX-512 (13.7 ns each on the 2-core AVX2 machine of issue 33, against ~4 ns on
Dr.Jit's vectorised LLVM code). Issue 33 (session 34), Cornell box 64² × 32 spp, each fit's seconds in the
helper or beside it, kernels cached: power 0.08 → 0.04 s and 0.38 → 0.19 s (the ambient case, 22 steps to its
bound), AO 0.10 → 0.05 s and 0.09 → 0.04 s; the exponential ρ (one ``expm1``, and the kernel's NumPy memo of
ρ(d_k) at the previous d_max) was as fast on NumPy (0.05–0.06 s both ways) and stays there. The fitted
values move by the last bits of float64 (Dr.Jit's exp and log against NumPy's: ~1e-12 relative)."""

SCENE_LABELS = {
    "crease_90": "thick V of interior angle 90° (a crease)",
    "sphere_plane": "sphere of radius 0.5 resting on a 4 × 4 slab (smooth normals)",
    "room": "closed 2 × 2 × 1.4 room with an open window, seen from inside",
    "boxes": "city block: a 4 × 4 grid of boxes of seeded heights on a 5 × 5 slab",
    "crease_30": "thick V of interior angle 30°, seen from the open side",
    "crease_60": "thick V of interior angle 60°",
    "crease_120": "thick V of interior angle 120°",
    "character": "procedural character standing on a slab (smooth normals)",
}
"""The sdf-occlusion scenes (``scenes/library/sdf_<name>.toml``, geometry by
`rtfit.experiments.sdf_occlusion_scenes`) the family ships, the first four ``--quick``."""
QUICK_SCENES = ("crease_90", "sphere_plane", "room", "boxes")

SCENES = tuple(
    sdf_scene(
        name,
        f"{label}; white diffuse, R = d_max = {SEED_D_MAX:g} (the seed's)",
        options={"ao_distance": SEED_D_MAX},
        quick=name in QUICK_SCENES,
    )
    for name, label in SCENE_LABELS.items()
)
"""The scenes ``rtfit run obscurances`` audits (scenes/library/): the sdf-occlusion scenes at the seed's
d_max = 0.3 (001:3326) as the AO radius R (``ao_distance``), so the model reference is the seed's W and the
``seed`` row is the seed's estimator; sizes and samples those of the experiment before the engine (quick:
36², 64 spp; full: 128², 1024 spp)."""


def on_rays(method: Method, rays: int, **fixed) -> Method:
    """``method`` (a row of `METHODS`) reading its ``distances`` as the ``rays`` per-pixel inputs d1..dK: the
    same kernel (``method.kernel``) given the tuple (d1, …, dK), with ``fixed`` keywords over its own."""
    names = tuple(f"d{k + 1}" for k in range(rays))
    base = method.kernel

    def kernel(ops, **kw):
        distances = tuple(kw.pop(n) for n in names)
        return base(ops, distances=distances, **kw)

    inputs = tuple(Input(n, "scene units", f"hit distance of ray {k + 1} (a miss: {MISS:g})") for k, n in
                   enumerate(names))  # fmt: skip
    return replace(method, kernel=kernel, inputs=inputs, fixed={**method.fixed, **fixed})


def _rows(radius: float) -> tuple[dict[str, Method], dict]:
    """(row id → method on `RAYS` rays, row id → parameter → `Param` scaled to R): the seed row with
    d_max = R; every fitted d_max starting at R within [10⁻³ R, 10³ R]."""
    methods = {mid: on_rays(m, RAYS, **({"d_max": radius} if "d_max" in m.fixed else {}))
               for mid, m in METHODS.items()}  # fmt: skip
    for mid in DRJIT_FITS:
        methods[mid] = replace(methods[mid], fit_ops="drjit")
    methods["seed"] = replace(
        methods["seed"],
        label=f"Seed obscurance (√(d/d_max), d_max = R = {radius:.4g})",
        formula=f"W = (1/K) Σ_k min(d_k/R, 1)^½, R = {radius:.4g}",
    )
    params = {}
    for mid, m in METHODS.items():
        if "d_max" in m.params:
            p = m.params["d_max"]
            params[mid] = {"d_max": replace(p, initial=radius, lower=1e-3 * radius, upper=1e3 * radius)}
    return methods, params


def _reference(setup: AuditSetup, points, normals, quantity: str, radius: float, label: str):
    """Pooled passes of ``quantity`` (``obscurance`` with the seed's ρ at d_max = R, or ``ambient_global``)
    at the visible points: mean and stderr (N,), dimensionless."""
    what: dict = {"format": FORMAT, "quantity": quantity, "points": array_digest(points, normals)}
    kw: dict = {"quantity": quantity}
    if quantity == "obscurance":
        fn, key = distance_weight("power", radius, SEED_EXPONENT)
        what["distance_weight"] = key
        kw["distance_weight"] = fn
    else:
        what["albedo"] = AMBIENT_ALBEDO
        kw["albedo"] = AMBIENT_ALBEDO

    def render(spp: int, seed: int):
        return occlusion_pass(setup.mi, setup.scene, points, normals, spp, seed, **kw)

    return pooled_passes(setup, what, render, (-1,), label, seed_label=f"{quantity}-pass")


def obscurance_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """Two cases on the visible points: the model's own W (seed ρ, d_max = R) and the uniform ambient with
    interreflections (module docstring)."""
    if app.role != ROLE:
        raise AuditError(f"obscurances: the {app.role} role is not audited here")
    radius = ao_radius(setup, "obscurances")
    mask = setup.mask
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    dist = hit_distances(setup.mi, setup.scene, points, normals, cosine_spiral_directions(RAYS),
                         rotate_seed=setup.seed + RAYS)  # fmt: skip
    dist = np.minimum(dist, MISS)
    inputs = {f"d{k + 1}": np.ascontiguousarray(dist[k]) for k in range(RAYS)}
    methods, params = _rows(radius)
    escaped = float(np.mean(dist >= MISS))
    notes = (
        f"rows: the K-ray estimator on K = {RAYS} stratified cosine directions per point (a golden-angle "
        f"spiral rotated per point), {100 * escaped:.3g} % of the rays escaping; d_max in scene units, "
        f"R = {radius:.4g}",
    )
    parameters = {"ao_distance": radius, "rays": RAYS, "pixels": int(mask.sum())}
    cases = []
    for quantity, tag, what, words in (
        ("obscurance", "model", f"obscurance W with ρ = min(d/R, 1)^½, R = {radius:.4g}",
         "ρ(d(ω)) with ω ~ cos/π is the exact estimator of W (the model's own definition)"),
        ("ambient_global", "ambient", f"uniform ambient E/(πL), albedo {AMBIENT_ALBEDO:g}, all bounces",
         "cosine-sampled paths with Russian roulette (q = albedo) score 1 when they escape"),
    ):  # fmt: skip
        pooled = _reference(setup, points, normals, quantity, radius, f"obscurances {tag}: {app.part}")
        ref = pooled.reference(
            mask,
            quantity=f"{what} (1: unoccluded)",
            integrator=f"occlusion pass ({quantity}: Mitsuba ray casts from the visible points)",
            integrator_reason=words,
        )
        cases.append(
            FamilyCase(
                id=f"obscurance-{tag}",
                label=f"{app.part}: {what}",
                reference=ref,
                channel_inputs=(inputs,) * 3,
                parameters={**parameters, "reference_quantity": quantity},
                units="1",
                notes=notes,
                methods=methods,
                params=params,
                user_rows=partial(on_rays, rays=RAYS),  # a user's g.distances: the rows' own K distances
            )
        )
    return cases


FAMILY = AuditFamily(
    name="obscurances",
    quantity="obscurance",
    cases=obscurance_cases,
    describe=(
        "Obscurances W = (1/π)∫ρ(d)(n·ω)dω of the scene's own geometry at each visible point, the distance "
        "scale being the AO radius R. Two references by Mitsuba ray casts from the visible points in "
        "independent passes: the model itself (the seed's ρ = √(d/R)) and the uniform ambient with every "
        f"interreflection (albedo {AMBIENT_ALBEDO:g}) that obscurances stand in for. The rows are the K-ray "
        f"estimator an engine bakes (K = {RAYS} stratified cosine rays per point) with the seed's, power, "
        "exponential and step ρ, their d_max, exponent and ambient scale fitted to this scene."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "obscurances",
            "obscurance",
            ("geometry",),
            "{part} occludes itself: ambient light as a function of the distance to the nearest surface",
            "ray-cast obscurance W = (1/π)∫ρ(d)(n·ω)dω with ρ = √(d/R), R = {ao_distance}, and the uniform "
            "ambient with interreflections it stands in for",
            "occlusion passes: cosine-distributed rays from the visible points (hit distances; paths with "
            "Russian roulette for the ambient)",
            # The rule's own ray casts give every row its K hit distances per point.
            frozenset({"distances"}),
        ),
    ),
)
