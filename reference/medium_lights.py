r"""A point or spot light inside a homogeneous medium of a Mitsuba scene: where it is, which stretch of each
camera ray the medium fills, and the light's single-scattered radiance along it by Monte Carlo.

What the volumetric-lightning and light-cone audits compare against (docs/audit.md), on a Mitsuba scene
loaded in a vectorised variant (a Mitsuba XML file, or an rtfit TOML scene built with its media):

* `point_medium` (`rtfit.reference.mitsuba_xml`, re-exported) — the medium a point sits in: the medium on
  the incoming side of the first medium transition (a shape with an ``interior``/``exterior`` medium)
  along a fixed ray from the point; where the ray meets none, the point is outside every bounded medium
  and sits in the scene's unbounded medium: the sensor's own medium when the sensor is outside every
  boundary too, else none. Surfaces that are not medium transitions are passed through.
* `medium_segments` — for each camera ray, the first stretch [s₀, s₁] (m from the camera) inside a given
  medium before the first surface that is not ``null`` (the surface an engine shades): entering the medium
  through a ``null`` boundary starts it, leaving it or meeting an opaque (non-null) surface ends it. Empty
  (s₀ = s₁ = 0) where the ray never enters the medium, and s₁ = +∞ where it leaves the scene inside it.
* `medium_parameters` — σ_t, albedo (RGB, ``scale`` applied) and the Henyey–Greenstein g of a
  ``homogeneous`` medium (None where a parameter is not a constant or the phase is neither ``isotropic`` nor
  ``hg``).
* `inscatter_pass` — one pass of the light's single-scattered radiance along each stretch (W/m²/sr, RGB):

      L = ∫_{s₀}^{s₁} σ_s·p(ω_l, −ω)·I(ω_l)/r²·V(x, l)·e^(−σ_t(s − s₀))·e^(−σ_t r) ds,   x = o + s·ω,

  with the distance s drawn by **equiangular sampling** about the light (Kulla & Fajardo 2012, "Importance
  Sampling Techniques for Path Tracing in Participating Media", EGSR: pdf(s) = h/((θ_b − θ_a)·r²), h the
  light's distance to the ray's line, θ the angle seen from the light), Mitsuba's own emitter sample
  (``Emitter.sample_direction``: I(ω_l)/r², for a spot its falloff), its own phase function
  (``PhaseFunction.eval_pdf``) and its own shadow rays (through ``null`` surfaces, blocked by any other),
  and the homogeneous medium's transmittance in closed form (both legs in the medium: the light-to-point
  segment is taken to stay inside it). Unbiased on the stretch; zero variance for an isotropic point
  light without extinction. Independent of the quadrature `rtfit.reference.single_scattering`
  (Gauss–Legendre in u, no visibility), which the audits' exact rows evaluate and which must sit at this
  pass's noise where nothing shadows the medium.
"""

from __future__ import annotations

import math
import time

import drjit as dr
import numpy as np

from .estimators import PassMoments, PassResult, check_spp, point_chunks
from .mitsuba_xml import MAX_CROSSINGS, camera_origin, point_medium
from .single_scattering import cone_crossings

__all__ = [
    "camera_origin",
    "cone_window",
    "inscatter_pass",
    "medium_parameters",
    "medium_segments",
    "point_medium",
]


def medium_parameters(mi, medium) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(σ_t (3,) in 1/m, albedo (3,), g) of a ``homogeneous`` medium with constant parameters (``scale``
    applied to σ_t), or None (module docstring)."""
    if medium is None or not medium.is_homogeneous():
        return None
    params = mi.traverse(medium)
    keys = set(params.keys())
    sigma_key, albedo_key = "sigma_t.value.value", "albedo.value.value"
    if sigma_key not in keys or albedo_key not in keys:
        return None  # a textured or spectral-curve parameter
    phase = medium.phase_function()
    kind = phase.class_name() if hasattr(phase, "class_name") else type(phase).__name__
    if "HG" in kind or "phase_function.g" in keys:
        g = float(np.asarray(params["phase_function.g"]).ravel()[0])
    elif "Isotropic" in kind:
        g = 0.0
    else:
        return None
    scale = float(np.asarray(params["scale"]).ravel()[0]) if "scale" in keys else 1.0
    sigma = np.broadcast_to(np.asarray(params[sigma_key], np.float64).ravel(), 3) * scale
    albedo = np.broadcast_to(np.asarray(params[albedo_key], np.float64).ravel(), 3)
    return np.array(sigma), np.array(albedo), g


def medium_segments(mi, scene, origin, dirs: np.ndarray, medium, inside: bool):
    """(s₀, s₁) (N,) float64, m: the first stretch of each ray from ``origin`` along unit ``dirs`` (N, 3)
    inside ``medium`` before the first non-``null`` surface (module docstring); ``inside``: the origin sits
    in the medium."""
    n = len(dirs)
    ray = mi.Ray3f(mi.Point3f(*(float(x) for x in origin)), mi.Vector3f(*(dirs[:, k] for k in range(3))))
    target = mi.MediumPtr(medium)
    null_flag = mi.BSDFFlags.Null
    travelled = dr.zeros(mi.Float, n)
    inside_now = dr.full(mi.Bool, inside, n)
    found = dr.full(mi.Bool, inside, n)
    active = dr.full(mi.Bool, True, n)
    s0 = dr.select(inside_now, 0.0, dr.inf)
    s1 = dr.full(mi.Float, dr.inf, n)
    ended = dr.full(mi.Bool, False, n)
    for _ in range(MAX_CROSSINGS):
        si = scene.ray_intersect(ray, active)
        valid = active & si.is_valid()
        t_hit = travelled + si.t
        null = mi.has_flag(si.bsdf().flags(), null_flag)
        crossing = valid & si.is_medium_transition()
        into = crossing & (si.target_medium(ray.d) == target)
        leave = inside_now & crossing & ~into
        opaque = valid & ~null
        stop = inside_now & (opaque | leave)
        s1 = dr.select(stop, t_hit, s1)
        ended |= stop
        start = into & ~found & ~opaque
        s0 = dr.select(start, t_hit, s0)
        found |= start
        inside_now = (inside_now | start) & ~stop
        active &= valid & ~opaque & ~stop
        travelled = dr.select(active, t_hit, travelled)
        ray = si.spawn_ray(ray.d)
        if not bool(dr.any(active)):
            break
    s0n, s1n = np.asarray(s0, np.float64), np.asarray(s1, np.float64)
    hit = np.asarray(found, bool) & np.isfinite(s0n)
    return np.where(hit, s0n, 0.0), np.where(hit, s1n, 0.0)


SHADOW_CROSSINGS = 4
"""``null`` surfaces (medium boundaries) a shadow ray passes through before it counts as blocked."""


def _unblocked(mi, scene, it, target, active):
    """True where the segment from ``it.p`` to ``target`` meets no surface but ``null`` ones (medium
    boundaries let light through; up to `SHADOW_CROSSINGS` of them)."""
    null_flag = mi.BSDFFlags.Null
    ray = it.spawn_ray_to(target)
    clear = mi.Bool(active)
    pending = mi.Bool(active)
    for _ in range(SHADOW_CROSSINGS + 1):
        si = scene.ray_intersect(ray, pending)
        hit = pending & si.is_valid()
        passes = hit & mi.has_flag(si.bsdf().flags(), null_flag)
        clear &= ~(hit & ~passes)
        pending = passes
        if not bool(dr.any(pending)):
            return clear
        ray = si.spawn_ray_to(target)
    return clear & ~pending


def cone_window(origin, dirs: np.ndarray, s0: np.ndarray, s1: np.ndarray, apex, axis, angle_rad: float):
    """(lo, hi) (N,): the part of each stretch [s0, s1] inside the forward cone of half-angle ``angle_rad``
    about ``axis`` at ``apex`` (one interval: the cone is convex below 90°), lo = hi where there is none.
    The sub-intervals between the double cone's crossings (`cone_crossings`) are tested at their middles."""
    a = np.asarray(axis, np.float64)
    cuts = cone_crossings(origin, dirs, apex, a, angle_rad)
    cuts = np.where(np.isfinite(cuts), np.clip(cuts, s0[:, None], s1[:, None]), s1[:, None])
    edges = np.sort(np.concatenate([s0[:, None], cuts, s1[:, None]], axis=1), axis=1)
    lo, hi = np.full_like(s0, np.inf), np.full_like(s0, -np.inf)
    cos_c = math.cos(angle_rad)
    for j in range(edges.shape[1] - 1):
        mid = 0.5 * (edges[:, j] + edges[:, j + 1])
        v = np.asarray(origin, np.float64) + mid[:, None] * dirs - np.asarray(apex, np.float64)
        inside = (edges[:, j + 1] > edges[:, j]) & (v @ a > cos_c * np.linalg.norm(v, axis=1))
        lo = np.where(inside, np.minimum(lo, edges[:, j]), lo)
        hi = np.where(inside, np.maximum(hi, edges[:, j + 1]), hi)
    empty = ~(hi > lo)
    return np.where(empty, s0, lo), np.where(empty, s0, hi)


def inscatter_pass(
    mi, scene, emitter, medium, origin, dirs: np.ndarray, s0: np.ndarray, s1: np.ndarray, light,
    sigma_t: np.ndarray, albedo: np.ndarray, spp: int, seed: int, window=None,
) -> PassResult:  # fmt: skip
    """One pass of the single-scattered radiance (W/m²/sr, RGB) of ``emitter`` (at ``light``) along each
    stretch [``s0``, ``s1``] (N,) of the rays from ``origin`` along unit ``dirs`` (N, 3) (module docstring):
    mean and variance (N, 3). ``medium`` gives the phase function; ``sigma_t``, ``albedo`` (3,) its
    homogeneous coefficients. Finite stretches only. ``window``: (lo, hi) (N,) within the stretch outside
    which the light gives nothing (a spot's cone, `cone_window`): the distances are drawn there only."""
    check_spp(spp)
    if mi.variant().startswith("scalar"):
        raise ValueError("the in-scattering pass needs a vectorised variant (llvm_ad_rgb or cuda_ad_rgb)")
    t0 = time.perf_counter()
    n = len(dirs)
    acc = PassMoments(mi, n, 3, spp)
    lo, hi = (s0, s1) if window is None else window
    seg = np.stack([s0, lo, hi], axis=-1)
    lp = mi.Point3f(*(float(x) for x in light))
    o = mi.Point3f(*(float(x) for x in origin))
    sig_t = mi.Color3f(*(float(x) for x in sigma_t))
    sig_s = mi.Color3f(*(float(x) for x in np.asarray(albedo) * np.asarray(sigma_t)))
    phase = medium.phase_function()
    ctx = mi.PhaseFunctionContext(None)
    for a, sampler, (w, ab) in point_chunks(mi, spp, seed, [(mi.Vector3f, dirs), (mi.Vector3f, seg)]):
        c = lp - o
        c_par = dr.dot(c, w)
        # the light's distance to the ray's line (floored: a ray through the light diverges there)
        h = dr.maximum(dr.norm(c - c_par * w), 1e-6 * dr.norm(c) + 1e-12)
        th_a = dr.atan2(ab.y - c_par, h)
        th_b = dr.atan2(ab.z - c_par, h)
        span = th_b - th_a
        s = c_par + h * dr.tan(th_a + sampler.next_1d() * span)
        s = dr.clip(s, ab.y, ab.z)
        x = o + s * w
        it = dr.zeros(mi.SurfaceInteraction3f, dr.width(w))
        it.p = x
        ds, weight = emitter.sample_direction(it, sampler.next_2d(), True)
        ok = (ds.pdf > 0.0) & (span > 0.0)
        visible = _unblocked(mi, scene, it, ds.p, ok)
        mei = dr.zeros(mi.MediumInteraction3f, dr.width(w))
        mei.p = x
        mei.wi = -w
        mei.sh_frame = mi.Frame3f(mei.wi)
        p_val, _ = phase.eval_pdf(ctx, mei, ds.d, ok)
        r2 = dr.squared_norm(x - lp)
        trans = dr.exp(-sig_t * ((s - ab.x) + ds.dist))
        value = sig_s * p_val * weight * trans * (span * r2 / h)
        acc.add(a, [dr.select(visible, value[k], 0.0) for k in range(3)])
    mean, var = acc.result()
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)
