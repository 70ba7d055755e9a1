"""Ground truth for the environment-map family: a closed room with emissive walls, traced by Mitsuba.

The scene is the seed's test room (001:398-431: a box whose walls carry a grid texture with an intensity
falloff): an axis-aligned box [``ROOM_LO``, ``ROOM_HI``] (m) whose inner walls emit a radiance
`room_radiance` (W/(m²·sr), grey) given in closed form of the surface point. Everything else in the room
(a probe point, a mirror or glass sphere) is non-emissive, so every quantity compared here is an integral
or a trace of that one function:

* irradiance E(p, n) = ∫ L(hit(p, ω)) max(n·ω, 0) dω and lobe-filtered radiance
  G(p, a) = ∫ L(hit(p, ω)) (s+1)/(2π) max(a·ω, 0)^s dω: Monte Carlo with directions drawn from the
  lobe (cosine-weighted for E: estimator π·L; the Phong lobe for G: estimator L), each ray's first hit
  from Mitsuba's ``ray_intersect`` on the room mesh, and the per-point standard error from the
  sample variance (`lobe_integral_mc`). This is what a path tracer does at depth 1 with the walls as
  emitters, without the BSDF;
* exact hit points of reflected and refracted rays (`trace_room`, `trace_sphere`): ``ray_intersect``,
  noise-free (float32: ~1e-6 m here).

Independent values the tests and the experiment's checks compare against: a uniform room (E = π,
G = 1 everywhere: the white furnace), and a room whose walls are each uniform, for which
E = Σ_walls L_w·(Lambert's polygon formula of the wall clipped to the hemisphere)
(`polygon_irradiance`, closed form); the slab method for the box (`box_exit`, analytic).
"""

from __future__ import annotations

import math
import time

import drjit as dr
import numpy as np

from .estimators import PassResult, channel_moments, chunk_ranges, mean_var, sub_seed
from .variants import use_variant

__all__ = [
    "EMITTER_TEXEL",
    "REF_POINT",
    "ROOM_HI",
    "ROOM_LO",
    "WALL_LEVELS",
    "box_exit",
    "lobe_integral_mc",
    "path_room_scene",
    "polygon_irradiance",
    "room_radiance",
    "sample_lobe",
    "sphere_radiance_pass",
    "texel_centres",
    "trace_room",
    "trace_sphere",
    "wall_of",
]

ROOM_LO = np.array([-2.0, -1.5, 0.0])
ROOM_HI = np.array([2.0, 1.5, 2.5])
REF_POINT = np.array([0.0, 0.0, 1.25])
"""The room (m) and the environment maps' reference point (the room's centre)."""

WALL_LEVELS = np.array([1.2, 0.45, 0.8, 0.6, 0.25, 1.0])
"""Base radiance of the walls x = hi, x = lo, y = hi, y = lo, z = lo (floor), z = hi (ceiling)."""

GRID_PITCH = 0.5
LAMP_CENTRE = np.array([0.6, 0.3])
LAMP_RADIUS = 0.35
LAMP_RADIANCE = 12.0


def wall_of(p: np.ndarray) -> np.ndarray:
    """Index 0…5 (x hi, x lo, y hi, y lo, z lo, z hi) of the wall nearest each point (…, 3)."""
    p = np.asarray(p, np.float64)
    d = np.stack(
        [
            ROOM_HI[0] - p[..., 0],
            p[..., 0] - ROOM_LO[0],
            ROOM_HI[1] - p[..., 1],
            p[..., 1] - ROOM_LO[1],
            p[..., 2] - ROOM_LO[2],
            ROOM_HI[2] - p[..., 2],
        ],
        -1,
    )
    return np.argmin(np.abs(d), axis=-1)


def room_radiance(p, kind: str = "textured") -> np.ndarray:
    """Radiance (W/(m²·sr)) leaving the wall at points p (…, 3) on the room's boundary.

    ``textured``: the wall's level × (1 − 0.6·g) with g = thin grid lines of pitch 0.5 m
    (cos^16 profile), × a smooth falloff 0.55 + 0.45·exp(−r²/2) from the wall's centre, plus a round
    ceiling lamp of radiance 12 (radius 0.35 m, smooth 2 cm edge); ``texels``: the textured radiance at
    the centre of the `EMITTER_TEXEL` texel that contains p (what the Mitsuba room of
    `sphere_radiance_pass` emits: one bitmap per wall, nearest filtering); ``walls``: each wall its uniform
    level (the polygon-formula check); ``uniform``: 1 everywhere (the white furnace)."""
    p = np.asarray(p, np.float64)
    if kind == "texels":
        return room_radiance(texel_centres(p), "textured")
    w = wall_of(p)
    level = WALL_LEVELS[w]
    if kind == "uniform":
        return np.ones(p.shape[:-1])
    if kind == "walls":
        return level
    if kind != "textured":
        raise ValueError(f"unknown room radiance {kind!r} (textured, texels, walls, uniform)")
    centre = 0.5 * (ROOM_LO + ROOM_HI)
    axis = np.array([0, 0, 1, 1, 2, 2])[w]
    q = p - centre
    u = np.where(axis == 0, q[..., 1], q[..., 0])
    v = np.where(axis == 2, q[..., 1], q[..., 2])
    g = np.cos(math.pi * u / GRID_PITCH) ** 16 + np.cos(math.pi * v / GRID_PITCH) ** 16
    grid = 1.0 - 0.3 * np.minimum(g, 2.0)
    fall = 0.55 + 0.45 * np.exp(-0.5 * (u * u + v * v))
    lamp_r = np.hypot(p[..., 0] - LAMP_CENTRE[0], p[..., 1] - LAMP_CENTRE[1])
    lamp = LAMP_RADIANCE / (1.0 + np.exp((lamp_r - LAMP_RADIUS) / 0.02 * 4.0))
    return level * grid * fall + np.where(w == 5, lamp, 0.0)


EMITTER_TEXEL = 1.0 / 32.0
"""Edge (m) of the square texels of the emitting walls of the path-traced room (`sphere_radiance_pass`):
every wall's extent is a whole number of them (4, 3, 2.5 m: 128, 96, 80 texels)."""
_WALL_SIDES = ((0, 1), (0, 0), (1, 1), (1, 0), (2, 0), (2, 1))  # (normal axis, 1: the hi side), wall_of order


def _in_plane(axis: int) -> tuple[int, int]:
    a, b = (k for k in range(3) if k != axis)
    return a, b


def texel_centres(p) -> np.ndarray:
    """The centre of the `EMITTER_TEXEL` texel of the wall nearest each point p (…, 3), on that wall."""
    p = np.asarray(p, np.float64)
    q = p.copy()
    w = wall_of(p)
    for k, (axis, hi) in enumerate(_WALL_SIDES):
        m = w == k
        for a in _in_plane(axis):
            n = round((ROOM_HI[a] - ROOM_LO[a]) / EMITTER_TEXEL)
            i = np.clip(np.floor((p[m, a] - ROOM_LO[a]) / EMITTER_TEXEL), 0, n - 1)
            q[m, a] = ROOM_LO[a] + (i + 0.5) * EMITTER_TEXEL
        q[m, axis] = ROOM_HI[axis] if hi else ROOM_LO[axis]
    return q


def box_exit(origins, dirs) -> np.ndarray:
    """Distance t ≥ 0 from points inside the room along unit directions to its boundary (slab method)."""
    o = np.asarray(origins, np.float64)
    d = np.asarray(dirs, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_hi = np.where(d > 0, (ROOM_HI - o) / d, np.inf)
        t_lo = np.where(d < 0, (ROOM_LO - o) / d, np.inf)
    return np.min(np.minimum(t_hi, t_lo), axis=-1)


# ========================================================================================== Mitsuba
_SCENES: dict = {}
MEMOS = (_SCENES,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _room_scene(variant: str):
    """(mi, scene) with the room as one cube mesh (geometry only: radiance is `room_radiance`)."""
    mi = use_variant(variant)
    key = ("room", mi.variant())
    if key not in _SCENES:
        c = 0.5 * (ROOM_LO + ROOM_HI)
        h = 0.5 * (ROOM_HI - ROOM_LO)
        T = mi.ScalarTransform4f
        to_world = T().translate(mi.ScalarPoint3f(*c)) @ T().scale(mi.ScalarPoint3f(*h))
        _SCENES[key] = mi.load_dict({"type": "scene", "room": {"type": "cube", "to_world": to_world}})
    return mi, _SCENES[key]


def _sphere_scene(variant: str, centre, radius: float):
    mi = use_variant(variant)
    key = ("sphere", mi.variant(), tuple(float(c) for c in centre), float(radius))
    if key not in _SCENES:
        _SCENES[key] = mi.load_dict(
            {
                "type": "scene",
                "s": {"type": "sphere", "center": [float(c) for c in centre], "radius": float(radius)},
            }
        )
    return mi, _SCENES[key]


def _intersect(mi, scene, o: np.ndarray, d: np.ndarray):
    ray = mi.Ray3f(
        mi.Point3f(*[np.ascontiguousarray(o[:, k], np.float32) for k in range(3)]),
        mi.Vector3f(*[np.ascontiguousarray(d[:, k], np.float32) for k in range(3)]),
    )
    si = scene.ray_intersect(ray)
    n = si.sh_frame.n
    dr.eval(si.t, si.p, n)
    valid = np.asarray(si.is_valid(), bool).reshape(-1)
    t = np.asarray(si.t, np.float64).reshape(-1)
    p = np.asarray(si.p, np.float64).reshape(3, -1).T
    nn = np.asarray(n, np.float64).reshape(3, -1).T
    return t, p, nn, valid


def trace_room(origins, dirs, variant: str = "llvm_ad_rgb") -> tuple[np.ndarray, np.ndarray]:
    """First hits of rays from inside the room on its walls: (t (N,), points (N, 3)) from Mitsuba's
    ``ray_intersect`` (float32). A ray that slips through a shared edge of the mesh's triangles (float32;
    a handful in a million) takes the slab method's hit instead; an origin outside the room is a
    ValueError."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    if len(o) == 0:
        return np.zeros(0), np.zeros((0, 3))
    mi, scene = _room_scene(variant)
    t, p, _, valid = _intersect(mi, scene, o, d)
    if not valid.all():  # a float32 ray through a shared triangle edge of the mesh can slip through it
        miss = ~valid
        inside = np.all((o[miss] > ROOM_LO - 1e-6) & (o[miss] < ROOM_HI + 1e-6), axis=1)
        if not inside.all():
            raise ValueError(f"{int((~inside).sum())} ray origins lie outside the room")
        t[miss] = box_exit(o[miss], d[miss])
        p[miss] = o[miss] + t[miss, None] * d[miss]
    return t, p


def trace_sphere(origins, dirs, centre, radius: float, variant: str = "llvm_ad_rgb"):
    """(t, points, outward normals, valid) of rays against a sphere (Mitsuba ``ray_intersect``)."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    mi, scene = _sphere_scene(variant, centre, radius)
    t, p, _, valid = _intersect(mi, scene, o, d)
    n = (p - np.asarray(centre, np.float64)) / float(radius)  # geometric normal, float64 from the hit point
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return t, p, n, valid


# ================================================================================= lobe integrals
def _frame(a: np.ndarray):
    """Orthonormal (t, b) with a (Duff et al. 2017, branchless)."""
    sign = np.where(a[..., 2] >= 0, 1.0, -1.0)
    k = -1.0 / (sign + a[..., 2])
    m = a[..., 0] * a[..., 1] * k
    t = np.stack([1.0 + sign * a[..., 0] ** 2 * k, sign * m, -sign * a[..., 0]], -1)
    b = np.stack([m, sign + a[..., 1] ** 2 * k, -a[..., 1]], -1)
    return t, b


def sample_lobe(axes: np.ndarray, u1: np.ndarray, u2: np.ndarray, shininess: float) -> np.ndarray:
    """Directions about unit ``axes`` (…, 3) from uniforms u1, u2: cosine-weighted (s ≤ 0) or the Phong
    lobe pdf (s+1)/(2π)·cos^s (s > 0); broadcasting over the leading dimensions."""
    a = np.asarray(axes, np.float64)
    if shininess > 0:
        ct = u1 ** (1.0 / (shininess + 1.0))
    else:
        ct = np.sqrt(u1)
    st = np.sqrt(np.maximum(1.0 - ct * ct, 0.0))
    phi = 2.0 * math.pi * u2
    t, b = _frame(a)
    return t * (st * np.cos(phi))[..., None] + b * (st * np.sin(phi))[..., None] + a * ct[..., None]


def lobe_integral_mc(
    points,
    axes,
    *,
    shininess: float = 0.0,
    samples: int = 4096,
    kind: str = "textured",
    seed: int = 0,
    variant: str = "llvm_ad_rgb",
    batch: int = 1 << 20,
) -> tuple[np.ndarray, np.ndarray]:
    """Monte Carlo E(p, n) (s ≤ 0) or G(p, a) (s > 0) at points (P, 3) with axes (P, 3): (mean, standard
    error) per point, from ``samples`` lobe-sampled rays each (stratified in u1 over ``samples`` strata,
    scrambled per point), first hits by Mitsuba, radiance `room_radiance` (``kind``)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    a = np.asarray(axes, np.float64).reshape(-1, 3)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    scale = math.pi if shininess <= 0 else 1.0
    per = max(1, batch // samples)
    s1 = np.zeros(len(p))
    s2 = np.zeros(len(p))
    for s in range(0, len(p), per):
        pp, aa = p[s : s + per], a[s : s + per]
        k = len(pp)
        u1 = (rng.permuted(np.tile(np.arange(samples), (k, 1)), axis=1) + rng.random((k, samples))) / samples
        u2 = rng.random((k, samples))
        d = sample_lobe(aa[:, None, :], u1, u2, shininess)
        o = np.broadcast_to(pp[:, None, :], d.shape)
        _, hit = trace_room(o.reshape(-1, 3), d.reshape(-1, 3), variant)
        f = scale * room_radiance(hit, kind).reshape(k, samples)
        s1[s : s + k] = f.sum(1)
        s2[s : s + k] = (f * f).sum(1)
    mean = s1 / samples
    var = np.maximum(s2 / samples - mean * mean, 0.0) * samples / max(samples - 1, 1)
    return mean, np.sqrt(var / samples)


# ============================================================================= polygon irradiance
def _walls() -> list[np.ndarray]:
    lo, hi = ROOM_LO, ROOM_HI
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    return [
        np.array([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]]),
        np.array([[x0, y0, z0], [x0, y1, z0], [x0, y1, z1], [x0, y0, z1]]),
        np.array([[x0, y1, z0], [x1, y1, z0], [x1, y1, z1], [x0, y1, z1]]),
        np.array([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]]),
        np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]),
        np.array([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]),
    ]


def _clip(poly: np.ndarray, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Sutherland–Hodgman: the part of a convex polygon with n·(x − p) ≥ 0."""
    out = []
    m = len(poly)
    for i in range(m):
        a, b = poly[i], poly[(i + 1) % m]
        da, db = float(np.dot(n, a - p)), float(np.dot(n, b - p))
        if da >= 0:
            out.append(a)
        if (da >= 0) != (db >= 0):
            out.append(a + (b - a) * (da / (da - db)))
    return np.array(out) if out else np.zeros((0, 3))


def polygon_irradiance(point, normal, levels=WALL_LEVELS) -> float:
    """Irradiance at ``point`` with unit ``normal`` inside the room whose walls have uniform radiances
    ``levels``: Σ_w L_w·(1/2)·|Σ_i θ_i n·Γ_i| over each wall clipped to the upper half-space (Lambert's
    polygon formula; θ_i the angle the edge i subtends, Γ_i the unit normal of its plane through p)."""
    p = np.asarray(point, np.float64)
    n = np.asarray(normal, np.float64)
    n = n / np.linalg.norm(n)
    total = 0.0
    for level, wall in zip(levels, _walls(), strict=True):
        poly = _clip(wall, p, n)
        if len(poly) < 3:
            continue
        v = poly - p
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        acc = 0.0
        for i in range(len(v)):
            a, b = v[i], v[(i + 1) % len(v)]
            c = np.cross(a, b)
            s = np.linalg.norm(c)
            if s < 1e-15:
                continue
            acc += math.atan2(s, float(np.dot(a, b))) * float(np.dot(n, c / s))
        total += float(level) * 0.5 * abs(acc)
    return total


# ============================================================== path-traced spheres (Mitsuba `path`)
SPHERE_MATERIALS = {
    "mirror": {"type": "conductor", "material": "none"},
    "glass": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
}
"""The sphere BSDFs of `sphere_radiance_pass`: a perfect mirror (``conductor``, material "none": reflectance 1
at every angle) and smooth glass of index 1.5 in air (``dielectric``: Mitsuba chooses reflection or
refraction with the exact Fresnel probability at every interface, internal reflections included)."""


def _wall_emitter(mi, k: int, kind: str) -> dict:
    """Wall k as a Mitsuba ``rectangle`` facing into the room, emitting the `EMITTER_TEXEL` bitmap of
    `room_radiance` (``kind``) at its texel centres (nearest filtering: piecewise constant, exactly
    ``room_radiance(p, "texels")`` for kind textured), black (non-reflecting)."""
    axis, hi = _WALL_SIDES[k]
    ua, va = _in_plane(axis)
    nu, nv = (round((ROOM_HI[a] - ROOM_LO[a]) / EMITTER_TEXEL) for a in (ua, va))
    u = ROOM_LO[ua] + (np.arange(nu) + 0.5) * EMITTER_TEXEL
    v = ROOM_LO[va] + (np.arange(nv) + 0.5) * EMITTER_TEXEL
    uu, vv = np.meshgrid(u, v)  # rows: v (the rectangle's uv.y), columns: u
    pts = np.zeros((nv, nu, 3))
    pts[..., ua], pts[..., va] = uu, vv
    pts[..., axis] = ROOM_HI[axis] if hi else ROOM_LO[axis]
    lum = room_radiance(pts.reshape(-1, 3), "textured" if kind == "texels" else kind).reshape(nv, nu)
    m = np.eye(4)
    m[:3, :3] = 0.0
    m[ua, 0] = 0.5 * (ROOM_HI[ua] - ROOM_LO[ua])
    m[va, 1] = 0.5 * (ROOM_HI[va] - ROOM_LO[va])
    m[axis, 2] = -1.0 if hi else 1.0  # the rectangle's +z normal points into the room
    c = 0.5 * (ROOM_LO + ROOM_HI)
    c[axis] = ROOM_HI[axis] if hi else ROOM_LO[axis]
    m[:3, 3] = c
    bitmap = mi.Bitmap(np.repeat(lum[..., None], 3, -1).astype(np.float32))
    texture = {
        "type": "bitmap",
        "bitmap": bitmap,
        "raw": True,
        "filter_type": "nearest",
        "wrap_mode": "clamp",
    }
    return {
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f(m.tolist()),
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
        "emitter": {"type": "area", "radiance": texture},
    }


def path_room_scene(variant: str, centre, radius: float, material: str, kind: str):
    """(mi, scene): the room's six walls as `EMITTER_TEXEL` bitmap emitters (`room_radiance` ``kind``) and a
    ``material`` sphere (`SPHERE_MATERIALS`); cached per arguments."""
    mi = use_variant(variant)
    key = ("path", mi.variant(), tuple(float(c) for c in centre), float(radius), material, kind)
    if key not in _SCENES:
        if material not in SPHERE_MATERIALS:
            raise ValueError(f"unknown sphere material {material!r} ({', '.join(SPHERE_MATERIALS)})")
        d: dict = {"type": "scene"}
        for k in range(6):
            d[f"wall{k}"] = _wall_emitter(mi, k, kind)
        d["sphere"] = {
            "type": "sphere",
            "center": [float(c) for c in centre],
            "radius": float(radius),
            "bsdf": dict(SPHERE_MATERIALS[material]),
        }
        _SCENES[key] = mi.load_dict(d)
    return mi, _SCENES[key]


def sphere_radiance_pass(
    origins,
    dirs,
    centre,
    radius: float,
    material: str,
    spp: int,
    seed: int,
    *,
    kind: str = "texels",
    max_depth: int = 64,
    variant: str = "llvm_ad_rgb",
):
    """One pass of Mitsuba's ``path`` integrator along the given rays (pixel-centre camera rays, (P, 3) each)
    in the room whose walls emit `room_radiance` (``kind``; textured → the ``texels`` bitmap) and reflect
    nothing, with a ``material`` sphere (`SPHERE_MATERIALS`): a `rtfit.reference.estimators.PassResult` of
    the per-ray mean radiance and its unbiased sample variance over ``spp`` independent samples
    (W/(m²·sr), grey: channel R). ``max_depth`` counts interfaces (camera → sphere is 1); Russian roulette is
    off below it (``rr_depth = max_depth``), so every path has weight 1 and the noise is only the choice
    between reflection and refraction at each glass interface (none for the mirror)."""
    o = np.ascontiguousarray(np.broadcast_to(np.asarray(origins, np.float64), np.shape(dirs)), np.float32)
    d = np.ascontiguousarray(np.asarray(dirs, np.float64), np.float32).reshape(-1, 3)
    o = o.reshape(-1, 3)
    if spp < 2:
        raise ValueError("spp must be >= 2 (the variance needs two samples)")
    mi, scene = path_room_scene(variant, centre, radius, material, kind)
    integrator = mi.load_dict({"type": "path", "max_depth": int(max_depth), "rr_depth": int(max_depth)})
    t0 = time.perf_counter()
    s = np.zeros((len(d), 1))
    q = np.zeros((len(d), 1))
    for a, b in chunk_ranges(len(d), spp):
        n = b - a
        el = dr.arange(mi.UInt32, n * spp) // spp
        og = dr.gather(mi.Point3f, mi.Point3f(*(o[a:b, k] for k in range(3))), el)
        dg = dr.gather(mi.Vector3f, mi.Vector3f(*(d[a:b, k] for k in range(3))), el)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(sub_seed(seed, "sphere", a), n * spp)
        value, _, _ = integrator.sample(scene, sampler, mi.Ray3f(og, dg))
        ss, qq = channel_moments(mi, dr, [value[0]], spp)
        s[a:b], q[a:b] = ss, qq
    mean, var = mean_var(s[:, 0], q[:, 0], spp)
    return PassResult(mean, var, int(spp), int(seed), time.perf_counter() - t0)
