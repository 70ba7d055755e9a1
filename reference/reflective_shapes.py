"""Reflective shapes of a user's scene: which BSDFs an environment map stands in for, and what the
environment-maps audit needs of them from Mitsuba.

A **reflective shape** is a shape whose BSDF reflects (or transmits) a sharp or glossy image of its
surroundings, so that a real-time renderer shades it from a cube map: Mitsuba's ``conductor``,
``roughconductor``, ``dielectric``, ``thindielectric``, ``roughdielectric``, ``plastic`` and
``roughplastic`` (`REFLECTIVE_BSDFS`). Everything here is Mitsuba; the real-time lookups are
`rtfit.realtime.reflections`.

* `shape_pixels`: which camera rays see a given shape first (its pixels).
* `surface_lobes`: at each of those first hits, what the shape does with light — the mirror direction R
  about the shading normal, the refracted direction T (straight through for thin glass), and the weight of
  each lobe per RGB channel, **from Mitsuba's own BSDF**: delta lobes exactly (one BSDF sample with the
  lobe-selecting sample at 0 or at 1⁻: w = pdf × weight = F·specular_reflectance, (1 − F)·transmittance;
  a thin dielectric's straight-through lobe is Mitsuba's "null" transmission),
  glossy and diffuse lobes as their directional albedo a = E[weight·1{lobe}] by ``samples`` BSDF samples
  (what a split-sum engine reads from its pre-integrated table). Transport mode *importance*, so the
  transmitted weight carries no 1/η² radiance scaling (what a real-time glass shader does: (1 − F)·L(T)).
* `first_hits`: the distance from a point to the first surface along each direction, passing through
  one shape (the shape whose cube map is captured is hidden from its own capture, as an engine does).
* `ray_radiance_pass`: Mitsuba ``path`` radiance along given rays (unbounded depth, Russian roulette:
  unbiased), optionally starting past one shape: one pass's per-ray mean and variance (W/(m²·sr), RGB).
  Used for the reference (the camera's pixel-centre rays) and for the cube map's capture (texel
  directions from the probe point).

Units: scene units for lengths, W/(m²·sr) for radiance, dimensionless weights.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from .device_arrays import device_vectors
from .estimators import PassResult, channel_moments, chunk_ranges, mean_var, pass_max_lanes, sub_seed

__all__ = [
    "MAX_SKIPS",
    "REFLECTIVE_BSDFS",
    "ReflectiveBsdf",
    "SurfaceLobes",
    "bsdf_roughness",
    "first_hits",
    "ray_radiance_pass",
    "reflective_shapes",
    "shape_pixels",
    "shape_plugin",
    "surface_lobes",
]


@dataclass(frozen=True)
class ReflectiveBsdf:
    """One reflective Mitsuba BSDF plugin: the C++ ``class_name`` its object reports, a short ``text``
    ("mirror", "glass", …) and ``rough``: its reflection is glossy (a microfacet lobe), not a delta."""

    class_name: str
    text: str
    rough: bool


REFLECTIVE_BSDFS = {
    "conductor": ReflectiveBsdf("SmoothConductor", "mirror", False),
    "roughconductor": ReflectiveBsdf("RoughConductor", "rough conductor", True),
    "dielectric": ReflectiveBsdf("SmoothDielectric", "glass", False),
    "thindielectric": ReflectiveBsdf("ThinDielectric", "thin glass", False),
    "roughdielectric": ReflectiveBsdf("RoughDielectric", "rough glass", True),
    "plastic": ReflectiveBsdf("SmoothPlastic", "plastic", False),
    "roughplastic": ReflectiveBsdf("RoughPlastic", "rough plastic", True),
}
"""Mitsuba BSDF plugin name → `ReflectiveBsdf`."""
_BY_CLASS = {b.class_name: plugin for plugin, b in REFLECTIVE_BSDFS.items()}

MAX_SKIPS = 16
"""Surfaces of the hidden shape a ray may pass through (a closed mesh: 2 per crossing)."""
_ONE_MINUS = 1.0 - 2.0**-24  # the largest float32 below 1: the last lobe of a BSDF's lobe choice


def shape_plugin(shape) -> str | None:
    """The `REFLECTIVE_BSDFS` plugin name of a Mitsuba shape's BSDF, or None: not a reflective shape, or the
    boundary of a medium (a glass shell holding fog is a medium's container, not a glass object: its pixels
    show the medium, which no environment-map lookup models)."""
    bsdf = shape.bsdf()
    if bsdf is None or shape.is_medium_transition():
        return None
    return _BY_CLASS.get(bsdf.class_name())


def _toml_key(shape_id: str) -> tuple[int, int] | None:
    """(i, j) of a TOML scene's ``xml<i>_<j>`` shape id (`rtfit.reference.build.mitsuba_scene_dict`)."""
    m = re.fullmatch(r"xml(\d+)_(\d+)", shape_id)
    return (int(m.group(1)), int(m.group(2))) if m else None


def reflective_shapes(mi_scene) -> list[tuple[int, str]]:
    """(index in ``mi_scene.shapes()``, plugin name) of every shape whose BSDF is in `REFLECTIVE_BSDFS`, in
    the order the audit numbers them: the shapes' own order (an XML scene's document order), except that a
    scene built from an rtfit TOML file (every id ``xml<i>_<j>``) is ordered by (i, j), its dict's order
    (Mitsuba lists the shapes of a scene dict in an order of its own)."""
    found = [(i, p) for i, s in enumerate(mi_scene.shapes()) if (p := shape_plugin(s)) is not None]
    keys = [_toml_key(mi_scene.shapes()[i].id()) for i, _ in found]
    if found and all(k is not None for k in keys):
        order = sorted(range(len(found)), key=lambda n: keys[n] or (0, 0))
        found = [found[n] for n in order]
    return found


def bsdf_roughness(mi, shape) -> float:
    """The microfacet roughness α of ``shape``'s BSDF (the mean of α_u, α_v where anisotropic; 0 for a
    smooth BSDF or where Mitsuba exposes no uniform α)."""
    params: Any = mi.traverse(shape.bsdf())
    names = ("alpha", "alpha_u", "alpha_v")
    vals = [float(np.mean(np.array(params[k]))) for k in params.keys() if k.split(".")[0] in names]
    return float(np.mean(vals)) if vals else 0.0


def _shape_id(mi, shape):
    """The shape's registry id, as Dr.Jit's pointer arrays hold it (compared with ``si.shape``)."""
    ids: Any = dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))
    return ids[0]


def _rays(mi, origins, dirs):
    """Rays from (N, 3) float64 origins and directions, rounded to float32 on the device (`device_vectors`:
    one kernel whatever the host arrays' alignment; strided columns mapped as they were gave up to 3 variants
    of each kernel reading them, compiled again from run to run, issue 33)."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    return mi.Ray3f(device_vectors(mi, mi.Point3f, o), device_vectors(mi, mi.Vector3f, d))


def _skip(mi, mi_scene, ray, skip):
    """``ray`` with its origin moved past every surface of the shape ``skip`` that it meets first (at most
    `MAX_SKIPS`), so that the first thing it hits is another shape (or nothing)."""
    if skip is None:
        return ray
    sid = _shape_id(mi, skip)
    ray = mi.Ray3f(ray)
    active = mi.Bool(True)
    for _ in range(MAX_SKIPS):
        si = mi_scene.ray_intersect(ray, active)
        own = active & si.is_valid() & (dr.reinterpret_array(mi.UInt32, si.shape) == sid)
        nxt = si.spawn_ray(ray.d)
        ray.o = dr.select(own, nxt.o, ray.o)
        active = own
        dr.eval(ray.o, active)
        if not dr.any(active):
            break
    return ray


def shape_pixels(mi, mi_scene, shape_index: int, origins, dirs) -> np.ndarray:
    """Boolean (N,): the rays (origins, unit dirs: (N, 3)) whose first hit is ``mi_scene.shapes()[i]``."""
    ray = _rays(mi, origins, dirs)
    si = mi_scene.ray_intersect(ray)
    sid = _shape_id(mi, mi_scene.shapes()[shape_index])
    hit = si.is_valid() & (dr.reinterpret_array(mi.UInt32, si.shape) == sid)
    return np.array(hit, bool)


def first_hits(mi, mi_scene, origin, dirs, skip=None) -> np.ndarray:
    """Distance (N,) from ``origin`` (3,) to the first surface along each unit direction (N, 3), passing
    through the shape ``skip`` (a Mitsuba shape, or None); +inf where the ray leaves the scene."""
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    origin = np.asarray(origin, np.float64).reshape(1, 3)
    ray = _skip(mi, mi_scene, _rays(mi, np.broadcast_to(origin, dirs.shape), dirs), skip)
    si = mi_scene.ray_intersect(ray)
    p = np.array(si.p, np.float64).T.reshape(-1, 3)
    t = np.linalg.norm(p - origin, axis=1)
    return np.where(np.array(si.is_valid(), bool), t, math.inf)


@dataclass(frozen=True)
class SurfaceLobes:
    """Per ray (N,): ``reflect`` and ``refract`` (N, 3) unit world directions (refract zero where the BSDF
    transmits nothing), ``normal`` (N, 3) the shading normal facing the camera, and the lobe weights (N, 3)
    per RGB channel: ``w_reflect`` (delta or glossy reflection), ``w_refract`` (delta or glossy
    transmission), ``w_diffuse`` (diffuse reflection); dimensionless."""

    reflect: np.ndarray
    refract: np.ndarray
    normal: np.ndarray
    w_reflect: np.ndarray
    w_refract: np.ndarray
    w_diffuse: np.ndarray


def _rgb(v) -> np.ndarray:
    return np.array(v, np.float64).T.reshape(-1, 3)


def surface_lobes(mi, mi_scene, origins, dirs, samples: int, seed: int) -> SurfaceLobes:
    """The lobes of the first hit of each ray (module docstring): delta lobes from one BSDF sample each,
    glossy and diffuse albedos as the mean of ``samples`` BSDF samples (independent sampler, ``seed``)."""
    n = len(np.asarray(dirs).reshape(-1, 3))
    ray = _rays(mi, origins, dirs)
    si = mi_scene.ray_intersect(ray)
    valid = si.is_valid()
    bsdf = si.bsdf(ray)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    flags = mi.BSDFFlags
    centre = mi.Point2f(0.5, 0.5)

    def delta(sample1, *kinds):
        bs, w = bsdf.sample(ctx, si, mi.Float(sample1), centre, valid)
        ok = mi.Bool(False)
        for kind in kinds:
            ok |= mi.has_flag(bs.sampled_type, kind)
        ok &= valid
        return dr.select(ok, w * bs.pdf, 0.0), dr.select(ok, si.to_world(bs.wo), 0.0), ok, bs.eta

    n_sh = si.sh_frame.n
    n_sh = dr.select(dr.dot(n_sh, ray.d) > 0, -n_sh, n_sh)
    cos_i = -dr.dot(ray.d, n_sh)
    refl = ray.d + 2.0 * cos_i * n_sh
    w_r, _, _, _ = delta(0.0, flags.DeltaReflection)
    # a thin dielectric's straight-through lobe is Mitsuba's null transmission
    w_t, t_dir, _, _ = delta(_ONE_MINUS, flags.DeltaTransmission, flags.Null)
    # a rough dielectric: Snell's refraction about the shading normal with the BSDF's relative index η
    _, _, glossy, eta = delta(_ONE_MINUS, flags.GlossyTransmission)
    inv = 1.0 / dr.maximum(eta, 1e-6)
    k = 1.0 - inv * inv * (1.0 - cos_i * cos_i)
    snell = inv * ray.d + (inv * cos_i - dr.sqrt(dr.maximum(k, 0.0))) * n_sh
    t_dir = dr.select(glossy & (k > 0.0), snell, t_dir)
    dr.eval(w_r, w_t, t_dir, n_sh, refl)
    out = {"r": _rgb(w_r), "t": _rgb(w_t), "d": np.zeros((n, 3))}
    sampler = mi.load_dict({"type": "independent"})
    lanes = pass_max_lanes(mi)
    for a, b in chunk_ranges(n, samples, lanes):
        m = b - a
        el = dr.arange(mi.UInt32, m * samples) // samples + a
        sampler.seed(sub_seed(seed, "lobes", a), m * samples)
        r = mi.Ray3f(dr.gather(mi.Point3f, ray.o, el), dr.gather(mi.Vector3f, ray.d, el))
        s = mi_scene.ray_intersect(r)
        bs, w = s.bsdf(r).sample(ctx, s, sampler.next_1d(), sampler.next_2d(), s.is_valid())
        for key, kind in (
            ("r", flags.GlossyReflection),
            ("t", flags.GlossyTransmission),
            ("d", flags.DiffuseReflection),
        ):
            v = dr.select(s.is_valid() & mi.has_flag(bs.sampled_type, kind), w, 0.0)
            sums, _ = channel_moments(mi, dr, [v[c] for c in range(3)], samples)
            out[key][a:b] += sums / samples
    length = np.linalg.norm(_rgb(t_dir), axis=1, keepdims=True)
    refract = np.where(length > 0, _rgb(t_dir) / np.maximum(length, 1e-30), 0.0)
    return SurfaceLobes(_rgb(refl), refract, _rgb(n_sh), out["r"], out["t"], out["d"])


def ray_radiance_pass(mi, mi_scene, origins, dirs, spp: int, seed: int, skip=None) -> PassResult:
    """One pass of Mitsuba's ``path`` integrator (unbounded depth, Russian roulette from depth 5: unbiased)
    along the rays (origins, unit dirs: (N, 3)), each moved past the shape ``skip`` first where given
    (`first_hits`): per-ray mean and unbiased variance (N, 3) of ``spp`` samples, W/(m²·sr)."""
    if spp < 2:
        raise ValueError("spp must be >= 2 (the variance needs two samples)")
    t0 = time.perf_counter()
    dirs = np.asarray(dirs, np.float64).reshape(-1, 3)
    origins = np.broadcast_to(np.asarray(origins, np.float64), dirs.shape)
    base = _skip(mi, mi_scene, _rays(mi, origins, dirs), skip)
    integrator = mi.load_dict({"type": "path", "max_depth": -1})
    n = len(dirs)
    s = np.zeros((n, 3))
    q = np.zeros((n, 3))
    sampler = mi.load_dict({"type": "independent"})
    for a, b in chunk_ranges(n, spp, pass_max_lanes(mi)):
        el = dr.arange(mi.UInt32, (b - a) * spp) // spp + a
        ray = mi.Ray3f(dr.gather(mi.Point3f, base.o, el), dr.gather(mi.Vector3f, base.d, el))
        sampler.seed(sub_seed(seed, "rays", a), (b - a) * spp)
        value, _, _ = integrator.sample(mi_scene, sampler, ray)
        s[a:b], q[a:b] = channel_moments(mi, dr, [value[c] for c in range(3)], spp)
    mean, var = mean_var(s, q, spp)
    return PassResult(mean, var, int(spp), int(seed), time.perf_counter() - t0)
