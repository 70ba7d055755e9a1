r"""The ``layered-materials`` family in `rtfit audit`: where the camera sees a base through a smooth
dielectric coat, the lateral offset of the seen point (scene units), as Mitsuba refracts the camera ray,
against the seed's parallax offset without refraction (000:1189-1217) and Snell's refracted offset
(`rtfit.realtime.layered_materials.METHODS`).

For each smooth ``dielectric`` shape of a Mitsuba XML scene, or of an rtfit TOML scene (a ``mitsuba_xml``
shape keeping its file's BSDFs), a ``glass-shape`` part (a smooth ``dielectric``), one case
``coat-<i>`` on the pixels whose camera ray meets that shape first from its outside and whose refracted ray
then meets another shape (the base):

* **reference** (deterministic, `AuditReference.deterministic`: no sampling, noise floor zero): at the
  pixel-centre ray's first hit p₁ on the coat, **Mitsuba's own dielectric BSDF** refracts it (one
  ``bsdf.sample`` with the lobe-selecting sample at 1⁻: the delta-transmission lobe), the refracted ray
  (from p₁ moved off the coat by Mitsuba's ``spawn_ray`` ε) meets the base at distance t₂; the offset is
  t₂·|d₂ − (d₂·n)n|, t₂ times the part of its unit direction d₂ along the coat's tangent plane (n the
  shading normal at p₁). Mitsuba's hit distance, not its hit point: a rectangle's float32 hit point is
  rebuilt from its uv and carried 3e-5 relative error in the offset, the distance 1e-7;
* **inputs** per pixel: ``cos_theta`` = wi·n at p₁ (Mitsuba's shading frame), ``depth`` d = the distance
  from the refracted ray's origin to the base along −n (a second ray, independent of the refraction: the
  coat's thickness there),
  ``eta`` the BSDF's own relative index (``mi.traverse``: int_ior/ext_ior).

Rows: the seed's offset d·tan θ (given, and with its depth scale k fitted), the paraxial apparent depth
(d/η)·tan θ and the exact refracted offset d·tan θ_t (``exact=True``: z-checked against the reference,
equal to float32 precision where the base is parallel to the coat).

Where the scene's only light is a constant sky, a second case ``coat-<i>-radiance`` (quantity
``coated_radiance``) on the pixels whose unrefracted ray also meets the base: the **radiance at the camera**
path traced by Mitsuba (``path``, unbounded depth, pixel centres, through the pass cache) against the seed's
composite (listing 3, 000:1321-1331, with the base's albedo where the seed's straight ray meets it), a
Fresnel lerp and the coated-diffuse closed form (both with the albedo where the refracted ray meets it).
Inputs from Mitsuba: F(θ) (``mi.fresnel``), F̄_ext (64-node Gauss–Legendre of ``mi.fresnel``), F̄_int =
1 − (1 − F̄_ext)/η², the albedos (``eval_diffuse_reflectance`` at the two hits) and the sky's radiance.

Where both rays meet one base, its albedo becomes a kernel input (a `BaseTexture` of texels read by Mitsuba on
the uv window the rays and the largest blur reach, 8 texels per coat thickness) and the case adds the seed's
blurred inner albedo (000:1291-1319: ``seed-blur``; ``coated-blur-1/5/13``, the coated diffuse with the
albedo blurred at the refracted point), their radius scale k fitted from the best point of a 17-point grid
(the error is piecewise in k on a texture). Where the scene holds a medium (``layered_materials_slab.xml``: a
homogeneous scattering slab in a null-BSDF box under the coat, which the offset rays pass through) the
reference is ``volpath``: the blur's exact counterpart.

No case: a rough dielectric is not a trigger (its refraction is a lobe, not one direction; left for later);
a thin dielectric, a conductor or plastic (nothing is seen through them), a dielectric seen from inside
(η < 1: the seed's coat is seen from outside) and pixels whose refracted ray escapes give none. The seed's
light-map blur (000:1221-1290) has its own case on a scattering slab under a delta light
(experiments/layered_lightmap.py: role ``slab over a base``, quantity ``inner_irradiance``).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import drjit as dr
import numpy as np

from rtfit.realtime.layered_materials import (
    BLUR_MAX,
    BLUR_ROWS,
    COMPOSITE_ROWS,
    LIGHTMAP_ROWS,
    METHODS,
    OFFSET_ROWS,
    BaseTexture,
)
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import PassResult, radiance_pass
from rtfit.reference.particle_media import shapes_scene

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import rays, reflective_shape, shape_view, visible_subset
from .audit_setup import AuditReference, AuditSetup, pooled_passes
from .case_inputs import vector_text
from .layered_lightmap import LIGHTMAP_RULE, LIGHTMAP_SCENE, ROLE, lightmap_cases, uv_window
from .records import Check, Section
from .shipped import ShippedScene, Sizes, Study, StudyContext

__all__ = ["ANGLES", "FAMILY", "SCENES", "coat_cases", "offset_ratio", "study"]

FORMAT = 1
_ONE_MINUS = 1.0 - 2.0**-24  # the largest float32 below 1: the dielectric's transmission lobe
ANGLES = (15, 30, 45, 60, 75)
"""The shipped scenes' view angles θ (degrees from the coat's normal) at η = 1.5; 60° also at η = 1.33."""
_DISTANCE = 10.0  # the camera's distance from the coat's centre (scene units)
_THICKNESS = 0.1  # the shipped coat's thickness d (scene units)


_sizes = Sizes(full=(32, 32, 256), quick=(16, 16, 64))


def _scene(theta: int, eta: float) -> ShippedScene:
    t = math.radians(theta)
    cy, cz = -_DISTANCE * math.sin(t), _THICKNESS + _DISTANCE * math.cos(t)
    return _sizes.scene(
        "layered_materials_coat.xml",
        f"a checkerboard base under a smooth coat (η = {eta:g}, d = {_THICKNESS:g}) seen at θ = {theta}°",
        defines={"eta": f"{eta:g}", "d": f"{_THICKNESS:g}", "cy": f"{cy:.6g}", "cz": f"{cz:.6g}"},
        name=f"theta{theta}-eta{eta:g}".replace(".", "p"),
        quick=(theta, eta) in ((30, 1.5), (60, 1.5), (60, 1.33)),
    )


def _slab(theta: int) -> ShippedScene:
    coat = _scene(theta, 1.5)
    return _sizes.scene(
        "layered_materials_slab.xml",
        f"the checkerboard under a smooth coat (η = 1.5, d = {_THICKNESS:g}) filled with a scattering medium "
        f"(σ_t = 10, albedo 0.95, HG g = 0.7; volpath) seen at θ = {theta}°",
        defines=dict(coat.defines),
        name=f"slab-theta{theta}-eta1p5",
        quick=theta == 60,
    )


SCENES = (*(_scene(a, 1.5) for a in ANGLES), _scene(60, 1.33), _slab(30), _slab(60), LIGHTMAP_SCENE)
"""The scenes ``rtfit run layered-materials`` audits (scenes/library/layered_materials_coat.xml,
layered_materials_slab.xml and the light map's layered_materials_lightmap.xml)."""


def offset_ratio(theta_deg, eta):
    """The seed's offset over the refracted one, tan θ/tan θ_t = √(η² − sin²θ)/cos θ (closed form, for the
    study's table; → η at normal incidence)."""
    t = np.radians(np.asarray(theta_deg, np.float64))
    s = np.sin(t)
    return np.sqrt(eta * eta - s * s) / np.cos(t)


def _median_ratio(theta, eta: float) -> float:
    return float(np.median(offset_ratio(theta, eta)))


def _shape(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "layered-materials")


def _np3(v) -> np.ndarray:
    return np.stack([np.array(v.x, np.float64), np.array(v.y, np.float64), np.array(v.z, np.float64)], 1)


def _shape_ids(mi, si) -> np.ndarray:
    return np.array(dr.reinterpret_array(mi.UInt32, si.shape), np.int64)


def _own_id(mi, shape) -> int:
    ids: Any = dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))
    return int(ids[0])


def _solid_scene(mi, scene):
    """The scene without its null-BSDF shapes (a medium's container, e.g. the slab's box: the rays here pass
    through it), or the scene itself where it has none; the same shape objects (their ids compare)."""
    shapes = list(scene.shapes())
    solid = [s for s in shapes if not mi.has_flag(s.bsdf().flags(), mi.BSDFFlags.Null)]
    return scene if len(solid) == len(shapes) else shapes_scene(mi, solid)


def _diffuse_albedo(mi, si) -> np.ndarray:
    """(N, 3): the diffuse reflectance of whatever BSDF each interaction hit (Mitsuba's own texture read)."""
    rho = si.bsdf().eval_diffuse_reflectance(si, si.is_valid())
    return np.array(mi.Color3f(rho), np.float64).T.reshape(-1, 3)


def _fdr_ext(mi, eta: float) -> float:
    """F̄_ext = ∫₀¹ F(μ)·2μ dμ: Mitsuba's Fresnel at 64 Gauss–Legendre nodes (float64 sum)."""
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1.0)
    f = np.array(mi.fresnel(mi.Float(mu.astype(np.float32)), mi.Float(eta))[0], np.float64)
    return float(np.sum(0.5 * w * f * 2.0 * mu))


def _uniform_sky(mi, scene) -> np.ndarray | None:
    """The (3,) radiance of the scene's only light where it is a constant sky; None otherwise."""
    env = scene.environment()
    if env is None or len(scene.emitters()) != 1 or env.class_name() != "ConstantBackgroundEmitter":
        return None
    return np.broadcast_to(np.array(mi.traverse(env)["radiance.value"], np.float64).reshape(-1), (3,)).copy()


def _base_textures(mi, scene, base_id: int, uvs: np.ndarray, si, radius: float, depth: float):
    """The `BaseTexture` (R, G, B) of the base's albedo read by Mitsuba at texel centres on the uv window
    around ``uvs`` padded by ``radius`` (scene units), 8 texels per thickness ``depth`` (≤ 512 a side)."""
    units = (float(np.median(np.linalg.norm(_np3(si.dp_du), axis=1))),
             float(np.median(np.linalg.norm(_np3(si.dp_dv), axis=1))))  # fmt: skip
    window, n, uu, vv = uv_window(uvs, units, radius, depth)
    query = dr.zeros(mi.SurfaceInteraction3f, uu.size)
    query.uv = mi.Point2f(uu.ravel().astype(np.float32), vv.ravel().astype(np.float32))
    shape = next(s for s in scene.shapes() if _own_id(mi, s) == base_id)
    rho = np.array(mi.Color3f(shape.bsdf().eval_diffuse_reflectance(query, True)), np.float64)
    rho = np.broadcast_to(rho.reshape(3, -1), (3, uu.size))  # a constant texture answers one value
    return BaseTexture(rho.reshape(3, n[1], n[0]), window, units)


def coat_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The offset case and, under a uniform sky, the radiance case of one smooth dielectric seen from outside
    with a base under it (module docstring); none otherwise."""
    if app.role == ROLE:  # a scattering slab over a base under a delta light: the light map's case
        return lightmap_cases(setup, app)
    mi, scene = setup.mi, setup.scene
    index, shape, plugin = _shape(setup, app)
    if plugin != "dielectric":
        return []
    t0 = time.perf_counter()
    origins, dirs, sees = shape_view(setup, index)
    if not sees.any():
        return []
    si = scene.ray_intersect(rays(mi, origins[sees], dirs[sees]))
    cos = np.array(si.wi.z, np.float64)
    bsdf = shape.bsdf()
    bs, _ = bsdf.sample(mi.BSDFContext(), si, mi.Float(_ONE_MINUS), mi.Point2f(0.5, 0.5), si.is_valid())
    through = np.array(mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaTransmission), bool)
    ray2 = si.spawn_ray(si.to_world(bs.wo))  # its origin: p₁ moved off the coat by Mitsuba's ε
    solid = _solid_scene(mi, scene)
    si2 = solid.ray_intersect(ray2)
    n = si.sh_frame.n
    si3 = solid.ray_intersect(mi.Ray3f(ray2.o, -n))  # the thickness from the same origin, down the normal
    t2, t3 = np.array(si2.t, np.float64), np.array(si3.t, np.float64)
    own = _own_id(mi, shape)
    ids2, ids3 = _shape_ids(mi, si2), _shape_ids(mi, si3)
    base = np.array(si2.is_valid(), bool) & np.array(si3.is_valid(), bool) & (ids2 != own) & (ids3 != own)
    keep = (cos > 0.0) & through & base
    if not keep.any():
        return []
    d2, nn = _np3(ray2.d), _np3(n)
    lateral = d2 - np.sum(d2 * nn, axis=1, keepdims=True) * nn
    offset = (t2 * np.linalg.norm(lateral, axis=1))[keep]
    depth = t3[keep]
    eta = float(np.array(mi.traverse(bsdf)["eta"]).reshape(-1)[0])
    mask = visible_subset(setup.mask, sees, keep)
    cos_k = cos[keep]
    inputs = {"cos_theta": cos_k, "depth": depth, "eta": np.full(cos_k.shape, eta)}
    reference = AuditReference.deterministic(
        mask,
        offset,
        (FORMAT, setup.scene_digest, app.part, plugin, eta),
        time.perf_counter() - t0,
        "lateral offset of the base point seen through the coat (scene units)",
        "Mitsuba's dielectric BSDF: one bsdf.sample (the delta-transmission lobe) at the pixel-centre ray's "
        "hit on the coat, the refracted ray's hit on the base (no sampling, not cached)",
        "ray geometry and Snell refraction by Mitsuba in float32: deterministic, noise floor zero",
    )
    theta = np.degrees(np.arccos(np.clip(cos_k, 0.0, 1.0)))
    cases = [
        FamilyCase(
            id=f"coat-{app.source}",
            label=f"{app.part}, the base's offset seen through it",
            reference=reference,
            channel_inputs=(inputs, inputs, inputs),
            parameters={
                "shape": app.part,
                "bsdf": plugin,
                "eta": eta,
                "depth_min": float(depth.min()),
                "depth_max": float(depth.max()),
                "theta_min_deg": float(theta.min()),
                "theta_max_deg": float(theta.max()),
                "pixels": int(mask.sum()),
            },
            units="m",
            notes=(
                f"η = {eta:.4g} (the loaded BSDF's int_ior/ext_ior); view angle θ from {theta.min():.3g}° to "
                f"{theta.max():.3g}°; coat thickness d from {depth.min():.4g} to {depth.max():.4g}",
                f"{int(mask.sum())} pixels see the base through the coat; the seed's offset over the "
                f"refracted one at θ = {np.median(theta):.3g}°: {_median_ratio(theta, eta):.3g}×",
            ),
            methods={k: METHODS[k] for k in OFFSET_ROWS},
        )
    ]
    sky = _uniform_sky(mi, scene)
    if sky is None or not setup.wants("coated_radiance"):
        return cases
    straight = solid.ray_intersect(si.spawn_ray(-si.to_world(si.wi)))  # the seed's ray, unrefracted
    seen = np.array(straight.is_valid(), bool) & (_shape_ids(mi, straight) != own)
    keep_r = keep & seen
    if not keep_r.any():
        return cases
    mask_r = visible_subset(setup.mask, sees, keep_r)
    rho_seed = _diffuse_albedo(mi, straight)[keep_r]
    rho_refr = _diffuse_albedo(mi, si2)[keep_r]
    cos_r = cos[keep_r]
    fresnel = np.array(mi.fresnel(mi.Float(cos_r.astype(np.float32)), mi.Float(eta))[0], np.float64)
    fdr_ext = _fdr_ext(mi, eta)
    fdr_int = 1.0 - (1.0 - fdr_ext) / (eta * eta)
    shared = {"cos_theta": cos_r, "eta": np.full(cos_r.shape, eta), "fresnel": fresnel,
              "fdr_ext": fdr_ext, "fdr_int": fdr_int}  # fmt: skip
    channels = tuple(
        {**shared, "albedo_seed": rho_seed[:, c], "albedo_refracted": rho_refr[:, c], "sky": float(sky[c])}
        for c in range(3)
    )
    rows = COMPOSITE_ROWS
    base_ids = np.concatenate([ids2[keep_r], _shape_ids(mi, straight)[keep_r]])
    if np.all(base_ids == base_ids[0]):  # one base: its texture is a kernel input (the blur rows)
        uv_seed, uv_refr = _uv(straight)[keep_r], _uv(si2)[keep_r]
        depth_r = t3[keep_r]
        radius = BLUR_MAX * float(np.max(depth_r / np.maximum(cos_r, 1e-3)))
        texture = _base_textures(mi, scene, int(base_ids[0]), np.concatenate([uv_seed, uv_refr]), si2,
                                  radius, float(depth_r.min()))  # fmt: skip
        blur = {"depth": depth_r, "u_seed": uv_seed[:, 0], "v_seed": uv_seed[:, 1],
                "u_refracted": uv_refr[:, 0], "v_refracted": uv_refr[:, 1]}  # fmt: skip
        channels = tuple(
            {**ch, **blur, "texture": texture, "channel": float(c)} for c, ch in enumerate(channels)
        )
        rows = COMPOSITE_ROWS + BLUR_ROWS
    media = [s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None]
    medium = media[0] if media else None  # a medium in the scene (a slab under the coat): volpath
    reference = _radiance_reference(setup, app, mask_r, medium is not None)
    cases.append(
        FamilyCase(
            id=f"coat-{app.source}-radiance",
            label=f"{app.part}, the coated base's radiance under the sky",
            reference=reference,
            channel_inputs=channels,
            parameters={
                "shape": app.part,
                "eta": eta,
                "sky": [float(v) for v in sky],
                "fdr_ext": fdr_ext,
                "fdr_int": fdr_int,
                "pixels": int(mask_r.sum()),
                "medium": None if medium is None else medium.class_name(),
            },
            units="W/m²/sr",
            notes=(
                f"uniform sky L = {vector_text(sky)}; F̄_ext = {fdr_ext:.4g}, F̄_int = {fdr_int:.4g} "
                "(Mitsuba's fresnel, 64-node Gauss–Legendre)",
                "the base's albedo read by Mitsuba where the seed's straight ray and the refracted ray meet "
                "it",
                "coated-diffuse is exact for a uniform base; on a texture its error is the internal "
                "reflections' lateral mixing (what the seed's blur stands in for)",
                "the coat holds a scattering medium (volpath): the base is seen blurred by it"
                if medium is not None
                else "no medium in the coat (path)",
            ),
            methods={k: METHODS[k] for k in rows},
            quantity="coated_radiance",
            params=_blur_starts(reference.mean[mask_r], channels) if rows != COMPOSITE_ROWS else {},
        )
    )
    return cases


def _inside(x: float, p) -> float:
    """x moved strictly inside the parameter's bounds (a start on a bound is not accepted)."""
    margin = 1e-3 * (p.upper - p.lower)
    return float(np.clip(x, p.lower + margin, p.upper - margin))


def _blur_starts(ref: np.ndarray, channels) -> dict:
    """The fits' starts for the blurred rows: the radius scale k of a 17-point grid over [0, BLUR_MAX] with
    the least squared error against the reference ``ref`` (N, 3) (seed-blur: with its best alpha per k,
    linear); on a textured base the error is piecewise in k: a local fit from k = 1 stays near 1."""
    grid = np.linspace(0.0, BLUR_MAX, 17)
    n, reps = len(ref), len(grid)
    target = np.tile(ref.T.reshape(-1), reps)
    out = {}
    for row in ("seed-blur", "coated-blur-5", "coated-blur-13"):
        m = METHODS[row]
        inputs = {
            name: channels[0][name]
            if name == "texture"
            else np.tile(np.concatenate([np.broadcast_to(ch[name], (n,)) for ch in channels]), reps)
            for name in m.input_names
        }
        k = np.repeat(grid, 3 * n)
        f = np.asarray(m.evaluate(inputs, {"blur": k, **({"alpha": 1.0} if "alpha" in m.params else {})}))
        f, t = f.reshape(reps, -1), target.reshape(reps, -1)
        a = np.ones(reps)
        if "alpha" in m.params:  # L_o is a times its value at a = 1: the least-squares a per k
            a = np.clip(np.sum(f * t, 1) / np.maximum(np.sum(f * f, 1), 1e-30), 0.0, 1.0)
        best = int(np.argmin(np.sum((a[:, None] * f - t) ** 2, 1)))
        start = {"blur": grid[best], "alpha": a[best]}
        out[row] = {k: replace(p, initial=_inside(start[k], p)) for k, p in m.params.items()}
    return out


def _uv(si) -> np.ndarray:
    return np.stack([np.array(si.uv.x, np.float64), np.array(si.uv.y, np.float64)], 1)


def _radiance_reference(
    setup: AuditSetup, app: Applicability, mask: np.ndarray, medium: bool
) -> AuditReference:
    """The radiance at the camera (Mitsuba ``path``, or ``volpath`` where the coat holds a medium, unbounded
    depth) at the pixel centres of ``mask``."""
    mi = setup.mi
    kind = "volpath" if medium else "path"
    integrator = mi.load_dict({"type": kind, "max_depth": -1})
    keep = mask.ravel()
    what = {"format": FORMAT, "quantity": "coated-radiance", "part": app.part, "mask": array_digest(mask),
            "integrator": kind}  # fmt: skip

    def render(spp: int, seed: int):
        r = radiance_pass(mi, setup.scene, spp, seed, integrator=integrator, sensor=setup.sensor)
        return PassResult(r.mean.reshape(-1, 3)[keep], r.var.reshape(-1, 3)[keep], r.spp, r.seed, r.seconds)

    pooled = pooled_passes(setup, what, render, (-1, 3), f"coat{app.source}: {app.part} radiance")
    return pooled.reference(
        mask,
        quantity="radiance at the camera of the coat over its base (W/m²/sr)",
        integrator=kind,
        integrator_reason="unbiased for the coat's refraction and the base's internal reflections "
        "(unbounded depth, Russian roulette)"
        + ("; volpath: the coat's homogeneous medium" if medium else ""),
    )


_RULE_WORDS = (
    "{part}: seen through as a clear coat, an engine offsets the layer under it by parallax without "
    "refraction (the seed's goopy materials)",
    "the lateral offset at which the camera sees the surface under the coat (scene units) where a smooth "
    "dielectric is seen from outside with another shape under it (no case otherwise); under a constant sky "
    "as the only light, also the coated base's radiance at the camera (W/m²/sr)",
    "none for the offset: Mitsuba's dielectric BSDF refracts each pixel-centre ray (deterministic); path "
    "(unbounded depth) at the pixel centres for the radiance",
)

FAMILY = AuditFamily(
    name="layered-materials",
    quantity="layer_offset",
    cases=coat_cases,
    describe=(
        "Per smooth dielectric shape seen from outside with a surface under it (a clear coat over a base): "
        "the lateral offset at which each pixel sees the base, from Mitsuba's own refraction of the "
        "pixel-centre ray (the dielectric BSDF's transmission sample) and the refracted ray's hit, against "
        "the seed's parallax offset without refraction (d·tan θ, 000:1189-1217; given and with its depth "
        "fitted), the paraxial apparent depth and the exact refracted offset d·tan θ_t (z-checked). Under a "
        "constant sky, also the coated base's radiance path traced by Mitsuba against the seed's layer "
        "composite (000:1321-1331), a Fresnel lerp and the coated-diffuse closed form."
    ),
    quantities=("coated_radiance", "inner_irradiance"),
    formats=("mitsuba-xml", "rtfit-toml"),
    role_formats={ROLE: ("mitsuba-xml",)},
    rules=(
        Rule(
            "layered-materials",
            "coat over a base",
            ("glass-shape",),
            *_RULE_WORDS,
            # the coat's rows only: the light-map rows are the slab role's (`LIGHTMAP_RULE`)
            supplies=frozenset(
                i.name for k, m in METHODS.items() if k not in LIGHTMAP_ROWS for i in m.inputs
            ),
        ),
        LIGHTMAP_RULE,
    ),
)


# ------------------------------------------------------------------------------------------------ study
def _measured(ctx: StudyContext) -> list[tuple[float, float, float, float]]:
    """(median θ°, η, seed/reference, refracted/reference) per audited case: median over its pixels."""
    rows = []
    for result in ctx.audits:
        for case in result.cases:
            outs = result.outcomes.get(case.id, {})
            if case.quantity == "coated_radiance" or "seed" not in outs or "refracted" not in outs:
                continue
            ref = case.reference.mean[case.mask][:, 0]
            ok = ref > 0.0
            theta = np.degrees(np.arccos(np.clip(case.channel_inputs[0]["cos_theta"], 0.0, 1.0)))
            seed = outs["seed"].image[case.mask][:, 0]
            exact = outs["refracted"].image[case.mask][:, 0]
            eta = float(case.parameters["eta"])
            seed_ratio, exact_ratio = np.median(seed[ok] / ref[ok]), np.median(exact[ok] / ref[ok])
            rows.append((float(np.median(theta)), eta, float(seed_ratio), float(exact_ratio)))
    return rows


def _cost_lines(ctx: StudyContext) -> list[str]:
    """One line per scene, case and row: θ, η, the case's quantity, the row's RMSE and largest error (in the
    case's units: m for the offset, W/m²/sr for the radiance), its fitted parameters and its kernel cost."""
    lines = [
        "| θ (median) | η | quantity | row | RMSE | max abs | fitted | kernel ns/px |",
        "|---" * 8 + "|",
    ]
    for result in ctx.audits:
        for case in result.cases:
            g = case.channel_inputs[0]
            where = "— (light map) | —"  # the light-map case has no view angle or coat
            if "cos_theta" in g:
                theta = float(np.median(np.degrees(np.arccos(np.clip(g["cos_theta"], 0.0, 1.0)))))
                where = f"{theta:.3g}° | {case.parameters['eta']:.3g}"
            what = f"{case.quantity or 'layer_offset'} ({case.units})"
            for row_id, out in result.outcomes.get(case.id, {}).items():
                cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
                mx = out.metrics["max_abs"].value if "max_abs" in out.metrics else float("nan")
                ns = f"{cost:.3g}" if cost else "—"
                fit = (
                    ", ".join(f"{k} = {float(v):.3g}" for k, v in out.parameters.items()) if out.fit else "—"
                )
                rmse = out.metrics["rmse"].value
                lines.append(f"| {where} | {what} | {row_id} | {rmse:.3g} | {mx:.3g} | {fit} | {ns} |")
    return lines


def study(ctx: StudyContext) -> Study:
    """The seed's offset error against view angle: the closed-form ratio tan θ/tan θ_t at η = 1.33 and 1.5
    over 0°–85°, the ratio measured on each shipped scene (seed and refracted rows over Mitsuba's offset),
    the check of the issue's claim "≈ 2× at 60°", and each row's error beside its cost."""
    angles = (0, 15, 30, 45, 60, 75, 85)
    table = ["| θ | seed/refracted, η = 1.33 | seed/refracted, η = 1.5 |", "|---|---|---|"]
    for a in angles:
        table.append(f"| {a}° | {float(offset_ratio(a, 1.33)):.3g} | {float(offset_ratio(a, 1.5)):.3g} |")
    measured = _measured(ctx)
    mtab = ["| θ (median) | η | seed / Mitsuba | refracted / Mitsuba |", "|---|---|---|---|"]
    mtab += [f"| {t:.3g}° | {e:.3g} | {s:.4g} | {r:.6g} |" for t, e, s, r in measured]
    checks = []
    for t, e, s, r in measured:
        checks.append(
            Check(
                name=f"θ = {t:.3g}°, η = {e:.3g}: refracted offset / Mitsuba's (median over pixels)",
                value=r,
                expected="1 within 1e-3 (float32 ray geometry)",
                passed=abs(r - 1.0) < 1e-3,
            )
        )
        if abs(t - 60.0) < 2.0:
            want = float(offset_ratio(t, e))
            checks.append(
                Check(
                    name=f"θ = {t:.3g}°, η = {e:.3g}: the seed's offset / Mitsuba's (issue: ≈ 2× at 60°)",
                    value=s,
                    expected=f"the closed form tan θ/tan θ_t = {want:.3g} within 2 %",
                    passed=abs(s / want - 1.0) < 0.02,
                )
            )
    text = (
        "The seed continues the view ray straight into the coat (offset d·tan θ); Snell bends it toward the "
        "normal (d·tan θ_t). Their ratio in closed form:\n\n" + "\n".join(table) + "\n\nMeasured on the "
        "shipped scenes (median over each scene's pixels, Mitsuba's refraction as the reference):\n\n"
        + "\n".join(mtab)
        + '\n\nThe issue\'s "≈ 2× at 60°" holds for a water-like coat (η = 1.33: 2.02×); for glass (η = 1.5) '
        "the seed's offset is 2.45× the true one. At normal incidence the ratio is η, not 1: the seed's "
        "offset is 0 there, as is the true one, so the ratio matters only away from the normal.\n\n"
        "Error beside cost (the engine's metrics; kernel ns per pixel as measured). The radiance case "
        "compares the seed's composite (listing 3 with a clear outer layer: no coat reflection) with a "
        "Fresnel lerp and the coated-diffuse closed form, all at Mitsuba's albedo where the seed's or the "
        "refracted ray meets the base:\n\n" + "\n".join(_cost_lines(ctx))
    )
    return Study(
        sections=(Section("offset-vs-angle", "The seed's offset error against view angle", text),),
        checks=tuple(checks),
    )
