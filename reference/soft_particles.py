r"""Mitsuba reference of a soft particle's transmittance: a homogeneous medium volume cut by an opaque plane.

The scene (view space: camera at the origin looking along +z; metres)
--------------------------------------------------------------------
* the particle: a ``sphere`` (centre c, radius r) or a ``cube`` (centre c, half-size r, faces normal to
  the view axes) with a ``null`` BSDF and an interior ``homogeneous`` medium of extinction σ_t and albedo 0
  (pure absorption);
* the opaque surface: a large ``rectangle`` through the point p with unit normal n (facing the camera),
  an ``area`` emitter of radiance 1 with a black diffuse BSDF;
* a ``constant`` environment of radiance 1 behind everything.

Along the pixel-centre ray t·d̂ the radiance is then exactly the transmittance T = exp(−σ_t·ℓ) of the
particle's chord ℓ in front of the surface (or of its whole chord where the ray misses the plane): the
opaque plane emits 1, the medium scatters nothing (albedo 0) and the plane reflects nothing. ``volpathmis``
samples a free-flight distance with density σ_t·e^(−σ_t t): a collision before the surface ends the path
(the scattering weight is the albedo, 0), so each sample is Bernoulli(T), with variance T(1 − T) per
sample — the noise is known in closed form (`bernoulli_stderr`) besides the pass's sample variance.

The estimate shares no formula with `rtfit.realtime.soft_particles`: the chord is found by Mitsuba's own
ray–shape intersections (medium boundaries) and the optical depth by free-flight sampling. Rays start at
the camera; a camera inside the particle starts in the particle's medium (``camera_inside``).
"""

from __future__ import annotations

import time

import drjit as dr
import numpy as np

from .estimators import PassResult, channel_moments, check_spp, mean_var, sub_seed
from .variants import scoped_variant

__all__ = ["bernoulli_stderr", "particle_scene_dict", "transmittance_pass_particle"]

MAX_LANES = 1 << 21
"""Paths per launch."""
PLANE_HALF_SIZE = 50.0
"""Half-size (m) of the opaque rectangle: larger than every view the experiment renders."""


def particle_scene_dict(
    mi, shape: str, centre, radius: float, sigma_t: float, plane_point, plane_normal
) -> dict:
    """The Mitsuba scene dictionary (module docstring); ``shape`` is "sphere" or "box"."""
    T = mi.ScalarTransform4f
    c = [float(x) for x in centre]
    medium = {"type": "homogeneous", "albedo": 0.0, "sigma_t": float(sigma_t), "scale": 1.0}
    if shape == "sphere":
        particle = {"type": "sphere", "center": c, "radius": float(radius)}
    elif shape == "box":
        particle = {"type": "cube", "to_world": T().translate(c).scale(float(radius))}
    else:
        raise ValueError(f"shape must be 'sphere' or 'box', got {shape!r}")
    particle |= {"bsdf": {"type": "null"}, "interior": medium}
    p = np.asarray(plane_point, np.float64)
    n = np.asarray(plane_normal, np.float64)
    n = n / np.linalg.norm(n)
    if float(np.dot(n, -p)) <= 0.0:
        raise ValueError("the plane's normal must face the camera (n·(0 − p) > 0)")
    up = [0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [1.0, 0.0, 0.0]
    plane = {
        "type": "rectangle",
        "to_world": T().look_at(origin=p.tolist(), target=(p + n).tolist(), up=up).scale(PLANE_HALF_SIZE),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}},
    }
    return {
        "type": "scene",
        "integrator": {"type": "volpathmis", "max_depth": 2},
        "particle": particle,
        "plane": plane,
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
    }


def transmittance_pass_particle(
    shape: str,
    centre,
    radius: float,
    sigma_t: float,
    plane_point,
    plane_normal,
    directions,
    spp: int,
    seed: int,
    variant: str = "llvm_ad_rgb",
    camera_inside: bool = False,
) -> PassResult:
    """``spp`` volpathmis samples of T along each unit direction (N, 3) from the camera at the origin.
    Returns a `PassResult` with mean and variance (N, 3) (the three channels are the same samples)."""
    check_spp(spp)
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    n = len(d)
    t0 = time.perf_counter()
    with scoped_variant(variant) as mi:
        scene = mi.load_dict(
            particle_scene_dict(mi, shape, centre, radius, sigma_t, plane_point, plane_normal)
        )
        integrator = scene.integrator()
        medium = None
        if camera_inside:
            medium = next(s.interior_medium() for s in scene.shapes() if s.interior_medium() is not None)
        sampler = mi.load_dict({"type": "independent"})
        per = max(1, MAX_LANES // spp)
        s = np.empty((n, 3))
        q = np.empty((n, 3))
        for k, a in enumerate(range(0, n, per)):
            b = min(n, a + per)
            lanes = (b - a) * spp
            sampler.seed(sub_seed(seed, "soft-particle", k), lanes)
            idx = dr.arange(mi.UInt32, lanes) // spp
            dd = mi.Vector3f(d[a:b].T.astype(np.float32))
            ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(0.0, 0.0, 0.0), dr.gather(mi.Vector3f, dd, idx)))
            value, _, _ = integrator.sample(scene, sampler, ray, medium, True)
            v = dr.select(dr.isfinite(value[0]), value[0], 0.0)
            s[a:b], q[a:b] = channel_moments(mi, dr, [v, v, v], spp)
    mean, var = mean_var(s, q, spp)
    return PassResult(mean, var, spp, seed, time.perf_counter() - t0)


def bernoulli_stderr(transmittance, spp: int) -> np.ndarray:
    """√(T(1 − T)/spp): the standard error of a mean of ``spp`` Bernoulli(T) samples."""
    t = np.clip(np.asarray(transmittance, np.float64), 0.0, 1.0)
    return np.sqrt(t * (1.0 - t) / spp)
