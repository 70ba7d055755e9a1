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

`particle_reference` is the form experiments use: independent passes in rtfit's pass store
(`rtfit.reference.cache.PassEntry`, namespace ``soft_particles``, key `particle_identity`), loaded where
cached, rendered under the pass watchdog where not, pooled exactly; `transmittance_pass_particle` renders
one uncached pass (tests, benchmarks).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from .cache import PassEntry, array_digest, pool_passes
from .estimators import PassResult, channel_moments, check_spp, mean_var, sub_seed
from .variants import scoped_variant

__all__ = [
    "ParticleReference",
    "bernoulli_stderr",
    "particle_identity",
    "particle_pass",
    "particle_reference",
    "particle_scene_dict",
    "transmittance_pass_particle",
]

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


def particle_pass(mi, scene, directions, spp: int, seed: int, camera_inside: bool = False) -> PassResult:
    """One pass: ``spp`` volpathmis samples of T along each unit direction (N, 3) from the camera at the
    origin, in a loaded ``scene`` (`particle_scene_dict`). Launches hold at most `MAX_LANES` paths; launch k
    is seeded with ``sub_seed(seed, "soft-particle", k)``. Returns a `PassResult` with mean and unbiased
    sample variance (N, 3) (the three channels are the same samples)."""
    check_spp(spp)
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    n = len(d)
    t0 = time.perf_counter()
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
    """One uncached pass (`particle_pass`) of the scene `particle_scene_dict` describes; `particle_reference`
    is the cached, resumable form of the same samples."""
    check_spp(spp)
    with scoped_variant(variant) as mi:
        scene = mi.load_dict(
            particle_scene_dict(mi, shape, centre, radius, sigma_t, plane_point, plane_normal)
        )
        return particle_pass(mi, scene, directions, spp, seed, camera_inside)


# ======================================================================================= cached reference
CACHE_FORMAT = 1
"""Version of the soft-particle cache entries (namespace ``soft_particles``)."""


def particle_identity(
    shape: str,
    centre,
    radius: float,
    sigma_t: float,
    plane_point,
    plane_normal,
    directions,
    *,
    camera_inside: bool,
    seed: int,
    pass_spp: int,
    variant: str,
) -> dict:
    """Everything that determines a soft-particle reference's samples, and nothing else: the physics (shape,
    centre and size in m, σ_t in 1/m, the plane's point and normal as given), the camera (at the origin,
    inside the particle or not) and its pixels (SHA-256 of the float32 unit directions: resolution and field
    of view), the integrator (``volpathmis``, max_depth 2), the launch size `MAX_LANES` (it splits a pass
    into seeded launches), the variant, the base seed, the samples per pass and the Mitsuba and Dr.Jit
    versions. The total spp is not part of it: a request for N samples uses the entry's first
    ceil(N / pass_spp) passes (`rtfit.reference.cache`)."""
    import mitsuba  # (its version is in the key)

    return {
        "format": CACHE_FORMAT,
        "shape": str(shape),
        "centre_m": [float(x) for x in centre],
        "radius_m": float(radius),
        "sigma_t_per_m": float(sigma_t),
        "plane_point_m": [float(x) for x in plane_point],
        "plane_normal": [float(x) for x in plane_normal],
        "plane_half_size_m": PLANE_HALF_SIZE,
        "camera_inside": bool(camera_inside),
        "directions": array_digest(np.asarray(directions, np.float64).reshape(-1, 3)),
        "integrator": {"type": "volpathmis", "max_depth": 2},
        "max_lanes": MAX_LANES,
        "variant": str(variant),
        "seed": int(seed),
        "pass_spp": int(pass_spp),
        "versions": {"mitsuba": mitsuba.__version__, "drjit": dr.__version__},
    }


@dataclass(frozen=True)
class ParticleReference:
    """A pooled soft-particle reference: per-direction transmittance ``mean`` (N,), the pooled unbiased sample
    variance ``var`` (N,) of its ``spp`` Bernoulli samples and the standard error ``stderr`` = √(var/spp);
    ``passes`` of which ``passes_rendered`` were rendered by this call (the rest came from the cache),
    ``seconds`` of rendering summed over the passes used (whenever they were rendered)."""

    key: str
    mean: np.ndarray
    var: np.ndarray
    stderr: np.ndarray
    spp: int
    passes: int
    passes_rendered: int
    seconds: float


def particle_reference(
    cache_dir,
    shape: str,
    centre,
    radius: float,
    sigma_t: float,
    plane_point,
    plane_normal,
    directions,
    *,
    spp: int,
    pass_spp: int,
    seed: int,
    variant: str = "llvm_ad_rgb",
    camera_inside: bool = False,
    progress: bool = False,
    label: str | None = None,
) -> ParticleReference:
    """The cached, resumable reference: ceil(spp / pass_spp) independent passes of ``pass_spp`` samples, pass
    i seeded with ``sub_seed(seed, "pass", i)``, stored in rtfit's pass store (`PassEntry`, namespace
    ``soft_particles``, key `particle_identity`) and pooled exactly (`pool_passes`). Passes found in the cache
    are loaded, the others rendered (the scene is loaded only then), each under the pass watchdog
    (``RTFIT_PASS_BUDGET_S``); an unreadable or truncated pass is rendered again. The medium is Mitsuba's
    ``homogeneous`` with albedo 0, so a path ends at its first collision: no per-lane event cap is needed."""
    check_spp(pass_spp)
    if spp < 2:
        raise ValueError(f"spp must be >= 2 (got {spp})")
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    count = -(-int(spp) // int(pass_spp))
    with scoped_variant(variant) as mi:
        ident = particle_identity(
            shape,
            centre,
            radius,
            sigma_t,
            plane_point,
            plane_normal,
            d,
            camera_inside=camera_inside,
            seed=seed,
            pass_spp=pass_spp,
            variant=variant,
        )
        entry = PassEntry(cache_dir, ident, namespace="soft_particles", storage="npz")
        loaded = {}

        def load_scene() -> None:
            loaded["scene"] = mi.load_dict(
                particle_scene_dict(mi, shape, centre, radius, sigma_t, plane_point, plane_normal)
            )

        def render(i: int) -> PassResult:
            return particle_pass(mi, loaded["scene"], d, pass_spp, sub_seed(seed, "pass", i), camera_inside)

        results, rendered = entry.passes(
            count,
            render,
            shape=(len(d), 3),
            progress=progress,
            label=label or f"soft particle {shape} {entry.key[:8]}",
            before_render=load_scene,
            spp_of=lambda _i: pass_spp,
        )
    mean, stderr, total = pool_passes(results)
    return ParticleReference(
        key=entry.key,
        mean=mean[:, 0],
        var=stderr[:, 0] ** 2 * total,
        stderr=stderr[:, 0],
        spp=total,
        passes=len(results),
        passes_rendered=rendered,
        seconds=float(sum(r.seconds for r in results)),
    )


def bernoulli_stderr(transmittance, spp: int) -> np.ndarray:
    """√(T(1 − T)/spp): the standard error of a mean of ``spp`` Bernoulli(T) samples."""
    t = np.clip(np.asarray(transmittance, np.float64), 0.0, 1.0)
    return np.sqrt(t * (1.0 - t) / spp)
