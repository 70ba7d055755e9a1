r"""The ``colour-bleeding`` family in `rtfit audit` (and ``rtfit run colour-bleeding`` on its shipped scenes):
real-time stand-ins for one diffuse bounce, per RGB channel, against the path-traced one-bounce indirect
irradiance at the visible points.

Role (its ``rules``): ``one diffuse bounce`` — a scene with geometry and at least one light (Mitsuba XML or
rtfit TOML): every surface a ray from a visible point reaches reflects the lights' direct light once, in its
own colour.

One case ``bounce`` on the visible surface pixels (`rtfit.reference.gbuffer_points`):

* **reference**: E₁,c(x) = ∫ L₁,c(y(x, ω)) (n·ω) dω (W/m², RGB): `rtfit.reference.estimators.irradiance_pass`
  with ``bounce`` transport — a cosine-distributed ray from x, then π × (Mitsuba ``path`` with max_depth 2
  − ``path`` with max_depth 1 on the same ray): the light leaving the first surface after exactly one
  reflection of every light's direct light (next-event estimation and BSDF sampling, MIS, shadow rays),
  without that surface's own emission (the direct light at x, which the max_depth-1 path returns exactly).
  Independent passes through the pass cache, per-pixel standard errors.
* **inputs** (one mapping per channel, `rtfit.realtime.colour_bleeding.INPUTS`): K = `RAYS` rays per point
  along `cosine_spiral_directions`, rotated per point (the real-time bake): each ray's hit distance d_k
  (`MISS` for a miss), the hit's diffuse albedo a_c,k (Mitsuba's ``eval_diffuse_reflectance``) and the
  direct irradiance there E_dir,c,k (`irradiance_pass`, ``direct`` transport, at the hit with its normal
  turned towards x; `HIT_SPP_FACTOR` × spp samples, at least `HIT_SPP_MIN`; kept in the pass cache,
  `cached_pass`): what an engine's direct-light buffer holds.
* **rows**: `rtfit.realtime.colour_bleeding.METHODS` on all K rays and on the first `FEW_RAYS` (``-k4``):
  the seed's per-channel SDF bias (D, b_r, b_g, b_b, I fitted), the seed's RGB obscurance's colour part
  (d_max = R, I fitted) and its fitted form (d_max, p, I), and the one-bounce gather (no parameter). Lengths
  scale with the scene's AO radius R (``--ao-distance``, else 0.1 × the box diagonal); the ambient I starts
  at the mean E_dir over the hits.

A user's ``@approximation(quantity="bounce_irradiance")`` reads the same inputs (``g.channel``, ``g.d1``…,
``g.a1``…, ``g.e1``…) and returns one value per channel.
"""

from __future__ import annotations

import math
from dataclasses import replace

import drjit as dr
import numpy as np

from rtfit.realtime.colour_bleeding import FEW_RAYS, METHODS, MISS, RAYS
from rtfit.realtime.colour_bleeding import INPUTS as CB_INPUTS
from rtfit.realtime.methods import Method, Param
from rtfit.realtime.obscurances import cosine_spiral_directions
from rtfit.reference.cache import array_digest
from rtfit.reference.device_arrays import device_vectors
from rtfit.reference.estimators import gbuffer_points, irradiance_pass, sub_seed

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_fit import length_scaled_params
from .audit_geometry import ao_radius
from .audit_setup import AuditSetup, cached_pass, pooled_passes
from .shipped import Sizes

__all__ = ["FAMILY", "FEW_RAYS", "HIT_SPP_FACTOR", "HIT_SPP_MIN", "SCENES", "bounce_cases", "ray_hits"]

FORMAT = 1
LENGTHS = frozenset({"d_max", "bias_r", "bias_g", "bias_b"})
"""The parameters in scene units: declared in units of R, multiplied by the scene's AO radius here."""
HIT_SPP_FACTOR = 0.25
HIT_SPP_MIN = 8
"""The direct irradiance at the hits: max(`HIT_SPP_MIN`, `HIT_SPP_FACTOR` × spp) samples each."""

_sizes = Sizes(full=(64, 64, 256), quick=(20, 20, 32))
SCENES = (
    _sizes.scene(
        "colour_bleeding_box.xml",
        "a mini Cornell box (red and green walls, white floor, ceiling, back wall and block) lit by a small "
        "rectangle light under the ceiling",
    ),
    _sizes.scene(
        "volume_room.toml",
        "the irradiance-volumes room (red and green side walls, a point light, a thin occluding wall)",
        quick=False,
    ),
)
"""The scenes ``rtfit run colour-bleeding`` audits (scenes/library/); ``--quick``: the box alone."""


def ray_hits(setup: AuditSetup, points: np.ndarray, normals: np.ndarray, k: int):
    """The K rays of each point (K, N): hit distance (``MISS`` for a miss), the hit's diffuse albedo (K, N, 3)
    (0 for a miss), its position (K, N, 3) and its unit normal turned towards the point (K, N, 3). Directions:
    `cosine_spiral_directions` in a per-point frame rotated about the normal by a seeded random angle."""
    mi = setup.mi
    n_pts = len(points)
    local = cosine_spiral_directions(k)
    angle = np.random.default_rng(sub_seed(setup.seed, "colour-bleeding-rays", 0)).uniform(
        0, 2 * math.pi, n_pts
    )
    t1 = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normals, t1)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    c, s = np.cos(angle)[None, :, None], np.sin(angle)[None, :, None]
    lx, ly, lz = (local[:, j][:, None, None] for j in range(3))
    dirs = (c * lx - s * ly) * u[None] + (s * lx + c * ly) * v[None] + lz * normals[None]  # (K, N, 3)
    origins = np.broadcast_to(points[None], dirs.shape).reshape(-1, 3)
    flat_n = np.broadcast_to(normals[None], dirs.shape).reshape(-1, 3)
    flat_d = dirs.reshape(-1, 3)

    it = dr.zeros(mi.Interaction3f, len(flat_d))
    it.p, it.n = device_vectors(mi, mi.Point3f, origins), device_vectors(mi, mi.Vector3f, flat_n)
    ray = it.spawn_ray(device_vectors(mi, mi.Vector3f, flat_d))
    si = setup.scene.ray_intersect(ray)
    fields = (si.is_valid(), si.bsdf(ray).eval_diffuse_reflectance(si), si.p, si.sh_frame.n, si.t)
    dr.eval(*fields)  # one kernel for the eleven arrays read below (each read launched its own)
    valid = np.asarray(fields[0], bool)
    albedo = np.stack([np.asarray(x, np.float64) for x in fields[1]], axis=1)
    hit_p = np.stack([np.asarray(x, np.float64) for x in fields[2]], axis=1)
    hit_n = np.stack([np.asarray(x, np.float64) for x in fields[3]], axis=1)
    flip = np.einsum("ij,ij->i", hit_n, flat_d) > 0
    hit_n[flip] *= -1.0
    t = np.where(valid, np.asarray(fields[4], np.float64), MISS)
    albedo = np.where(valid[:, None], np.clip(np.nan_to_num(albedo), 0.0, 1.0), 0.0)
    shape = (k, n_pts)
    return (
        t.reshape(shape),
        albedo.reshape(*shape, 3),
        hit_p.reshape(*shape, 3),
        hit_n.reshape(*shape, 3),
        valid.reshape(shape),
    )


def _rows(radius: float, ambient: float) -> tuple[dict[str, Method], dict]:
    """Row id → method (all K rays and the first `FEW_RAYS`), row id → its scaled parameter bounds."""
    amb = Param(ambient, ambient * 1e-4, ambient * 1e4, unit="W/m²", description="ambient intensity I",
                published=False)  # fmt: skip
    base = dict(METHODS)
    for mid in ("rgb-obscurance-seed", f"rgb-obscurance-seed-k{FEW_RAYS}"):
        base[mid] = replace(base[mid], fixed={**base[mid].fixed, "d_max": radius})
    params = length_scaled_params(base.values(), LENGTHS, radius)
    for m in base.values():
        if "ambient" in m.params:
            params[m.id]["ambient"] = replace(amb, log=m.params["ambient"].log)  # (`Param.log`: as the row's)
    return {m.id: m for m in base.values()}, params


def bounce_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The one case (module docstring)."""
    mi, scene, mask = setup.mi, setup.scene, setup.mask
    points, normals = gbuffer_points(setup.gbuffer, mask)
    if not len(points):
        raise AuditError("colour-bleeding: the camera sees no surface")
    radius = ao_radius(setup, "colour-bleeding")
    dist, albedo, hit_p, hit_n, valid = ray_hits(setup, points, normals, RAYS)
    hit_spp = max(HIT_SPP_MIN, int(HIT_SPP_FACTOR * setup.spp))
    direct = np.zeros((*dist.shape, 3))
    seconds = 0.0
    if valid.any():
        hp = hit_p[valid]
        hn = hit_n[valid]
        seed = sub_seed(setup.seed, "colour-bleeding-hits", 0)
        hits = {"format": FORMAT, "quantity": "hit-direct-irradiance", "points": array_digest(hp, hn),
                "spp": hit_spp, "seed_label": "colour-bleeding-hits"}  # fmt: skip
        res = cached_pass(setup, hits, lambda: irradiance_pass(mi, scene, hp, hn, hit_spp, seed), (-1, 3),
                          f"bounce: direct light at {len(hp)} ray hits", hit_spp)  # fmt: skip
        direct[valid] = np.maximum(np.nan_to_num(res.mean), 0.0)
        seconds = res.seconds
    what = {"format": FORMAT, "quantity": "bounce-irradiance", "points": array_digest(points, normals)}

    def render(spp: int, seed: int):
        return irradiance_pass(mi, scene, points, normals, spp, seed, transport="bounce")

    pooled = pooled_passes(
        setup, what, render, (-1, 3), f"bounce: one-bounce irradiance at {len(points)} points"
    )
    ref = pooled.reference(
        mask,
        quantity="one-bounce indirect irradiance at the visible points (W/m², RGB)",
        integrator="a cosine-distributed ray from each visible point, then π × (path max_depth 2 − path "
        "max_depth 1): one reflection of every light's direct light, without the hit's own emission",
        integrator_reason="what one diffuse bounce adds to a surface's irradiance, per channel: what the "
        "colour-bleeding shortcuts stand in for",
        extra_seconds=seconds,
    )
    lit = direct[valid]
    ambient = float(lit.mean()) if lit.size and lit.mean() > 0 else 1.0
    methods, params = _rows(radius, ambient)
    channels = []
    for c in range(3):
        inputs: dict = {"channel": float(c)}
        for k in range(RAYS):
            inputs[f"d{k + 1}"] = np.ascontiguousarray(dist[k])
            inputs[f"a{k + 1}"] = np.ascontiguousarray(albedo[k, :, c])
            inputs[f"e{k + 1}"] = np.ascontiguousarray(direct[k, :, c])
        channels.append(inputs)
    return [
        FamilyCase(
            id="bounce",
            label="one-bounce indirect irradiance at the visible points",
            reference=ref,
            channel_inputs=tuple(channels),
            parameters={
                "rays_per_point": RAYS,
                "few_rays": FEW_RAYS,
                "ao_radius": radius,
                "hit_spp": hit_spp,
                "hits": int(valid.sum()),
                "misses": int((~valid).sum()),
                "ambient_start_w_m2": ambient,
                "pixels": int(mask.sum()),
            },
            units="W/m²",
            notes=(
                f"K = {RAYS} cosine-spiral rays per point (rotated per point), and the first {FEW_RAYS} of "
                f"them in the -k{FEW_RAYS} rows; lengths in units of R = {radius:.4g}",
                f"direct irradiance at each hit: {hit_spp} samples (emitter + cosine sampling, MIS, shadow "
                "rays): the gather row's noise includes it",
                "seed-sdf-bias reads the SDF's occlusion along the rays (rtfit's reading of seed 000's "
                "prose; the SDF lookup itself is the sdf-occlusion family's)",
            ),
            methods=methods,
            params=params,
        )
    ]


FAMILY = AuditFamily(
    name="colour-bleeding",
    quantity="bounce_irradiance",
    cases=bounce_cases,
    describe=(
        "The one-bounce indirect irradiance at each visible point, per channel (W/m², RGB): a cosine ray, "
        "then π × (Mitsuba path with max_depth 2 − max_depth 1), in independent passes with per-pixel "
        "standard errors — against the seed's per-channel SDF biased by the surface colour (the bias "
        "fitted per channel), the seed's RGB obscurances (their colour part, √ transfer function; and its "
        "fitted form) "
        f"and the one-bounce gather reading the direct light at each hit, all on K = {RAYS} (and "
        f"{FEW_RAYS}) cosine-spiral rays per point with the hit distances, albedos and direct irradiance."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "colour-bleeding",
            "one diffuse bounce",
            ("geometry", "light"),
            "{part} reflects {with_} once, in each surface's colour: an engine bleeds colour with a "
            "per-channel SDF bias, RGB obscurances or a one-bounce gather",
            "one-bounce indirect irradiance at the visible points, per channel",
            "a cosine ray from each visible point, then path max_depth 2 minus max_depth 1 (π ×); the rows' "
            "K rays by Dr.Jit ray casts, the direct light at their hits by emitter sampling",
            supplies=frozenset(i.name for i in CB_INPUTS),
        ),
    ),
)
