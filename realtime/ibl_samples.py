r"""Image-based lighting from N directional light samples of an environment map, each with its own shadow
test (the ``ibl-samples`` family, docs/ibl-samples.md).

Conventions and units
---------------------
* The environment is a lat-long radiance map L(ω) (W·m⁻²·sr⁻¹, RGB) given to the bakes as its **texels**:
  unit directions d_t, solid angles w_t (sr) and radiances L_t, on an (H, W) grid of rows of equal polar
  angle (Mitsuba's lat-long convention, +Z up; `rtfit.reference.environments.quadrature_samples` makes them
  from a map). A texel's **energy** is e_t = w_t·Y(L_t), Y the Rec. 709 luminance (`LUMINANCE`).
* A bake returns N **lights**, a table of 6·N floats, sample-major: for light k its unit direction towards
  the light (d_x, d_y, d_z) and its power P_k (R, G, B, W/m²) = Σ_{t ∈ cell k} w_t L_t, the irradiance at
  normal incidence of the texels it stands for (so Σ_k P_k = ∫ L dω: energy is conserved exactly).
* ``nx, ny, nz``: the surface's unit normal (normalised by the kernel); ``visibility``: N per-pixel arrays
  V_k ∈ [0, 1], light k's visibility at the point (1: lit; here a Mitsuba shadow ray, exact; a shadow map's
  filtered test would give values in between).
* Every row gives an **irradiance** (W/m², per RGB channel, the tuple (R, G, B)): the quantity
  ``sky_irradiance_lights``, compared with E = ∫ V(ω) L(ω) max(n·ω, 0) dω, the environment's irradiance with
  the scene's occlusion. A Lambertian surface of albedo ρ reflects ρE/π.

The kernel (one text for every row; the rows differ in the bake only)
---------------------------------------------------------------------
    E ≈ Σ_k V_k · max(n·d_k, 0) · P_k

the seed's ``renderFinal`` sum (001:3021-3038, the diffuse part of ``COMPUTE_LIGHT_SAMPLE_CONTRIB_SHINY``:
``cosTheta = dot(LightDir, Normal); if (cosTheta > 0) … rcolor += cosTheta · LightPower`` when the depth
test passes; the depth test with its normal-weighted bias, 001:3026-3027, is an exact shadow ray in the
other rows). The Phong term (``as·ShinyKs``) is the glossy part and is not audited; ``ToneScale`` and the
``brdfMap`` albedo are display factors (1 here).

The bakes (the rows), NumPy, offline (what an engine does once per map)
-----------------------------------------------------------------------
The bakes' code is `rtfit.realtime.ibl_bakes`:

* ``seed-lloyd`` — the seed (001:2738-3070, the GameTools image-based lighting module, §2.8.1 at
  001:2742: "The environment map is decomposed into directional samples using Delaunay triangulation and
  Lloyd's relaxation"). Reading: the seed prints neither step; we read it as Kollig & Keller 2003
  ("Efficient illumination by high dynamic range images", EGSR) do: N directions placed by the map's energy
  (systematic sampling of the energy CDF over the texels), then Lloyd's relaxation on the sphere with the
  energy as density (each texel assigned to its nearest direction — the spherical Voronoi cells, dual of
  the Delaunay triangulation the seed draws — and each direction moved to its cell's energy centroid,
  `LLOYD_ITERATIONS` times). Light k sits at its cell's energy centroid with the cell's power. Errata: the
  seed's shader names the light direction ``LightDir`` and tests ``dot(LightDir, Normal) > 0``, so
  ``LightDir`` points **towards** the light (as here), although its ``cosPsi = −dot(Reflect, LightDir)``
  would need the opposite sign; only the diffuse term is audited.
* ``seed-depthmap`` — the seed's lights (``seed-lloyd``) with the seed's shadow test in the kernel
  (`_shadow_test`, `DepthMaps`; the audit's offline `depth_map_visibility` is its NumPy twin): per light an
  orthographic depth-and-normal map of R² texels over the scene's bounding sphere (001:2814-2871: camera
  on the sphere looking at its centre, depth 2r → [0, 1]), filtered linearly, lit where
  z − b·dot(n̂_map, n) < depth (001:3026-3028), b the parameter ``bias`` (the seed's 0.01); knobs R (64,
  128, 256) and a 3×3 PCF (`DEPTH_ROWS`).
* ``importance`` — the same energy-weighted placement without the relaxation (0 iterations): what Lloyd's
  relaxation buys.
* ``median-cut`` — Debevec 2005 ("A median cut algorithm for light probe sampling", SIGGRAPH 2005 poster):
  split the lat-long map recursively into 2ᵏ regions of equal energy,
  each cut across the region's longer side (its width measured with sin θ, the cos-latitude of the
  poster), a light at each region's energy centroid with the region's power. N not a power of two: the
  2^⌊log₂N⌋ regions of the levels, then the most energetic regions split once more.

Guards (reasons): the normal's length is floored at 1e-30 before it is normalised (a zero normal reads
E = 0, not NaN); V_k is clamped to [0, 1] (a filtered shadow test never lights more than the light); n·d_k
is clamped at 0 (light from below the surface's plane is not received: the seed's ``if (cosTheta > 0)``).
A black map gives N lights of zero power (directions on a Fibonacci sphere); a cell with no energy keeps
its direction and gets zero power; negative texels are clamped to 0 (a bake below the horizon).

Float32 rewrite: the same text runs in float32 on Dr.Jit: N multiply-adds per channel, no cancellation
(every term is ≥ 0). Domain: any normal, V ∈ [0, 1], finite non-negative powers, unit light directions.
Dr.Jit arrays are never checked (no host sync); NumPy inputs of the public functions are.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .arrays import DRJIT_OPS, NUMPY_OPS, clamp01, evaluate, is_drjit, split3
from .methods import Input, Method, Param, method_table

__all__ = [
    "BAKES",
    "COUNTS",
    "DEPTH_ROWS",
    "SHADOW_BIAS",
    "SHADOW_RESOLUTION",
    "DepthMaps",
    "lights_irradiance",
    "maps_input",
    "on_lights",
    "on_maps",
    "visibility_names",
]

_TINY = 1e-30
_BATCH = 32  # lights per evaluated Dr.Jit kernel


# ===================================================================================== kernel (ops text)
def _value(t) -> Any:
    """A table entry as a Python float, or as it is (a traced array)."""
    return float(t) if isinstance(t, (float, int, np.floating, np.integer)) else t


_OPAQUE: dict[tuple, tuple] = {}
MEMOS = (_OPAQUE,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _device_table(ops, lights, like) -> list:
    """The light table as the kernel reads it: on Dr.Jit, opaque size-1 arrays (kernel parameters, not
    literals: one compiled kernel serves every bake and map with the same N), made once per table object
    (a row's ``fixed`` tuple: its repeated calls, e.g. a cost measurement, trace no new arrays); else the
    values."""
    if ops is not DRJIT_OPS or not is_drjit(like):
        return [_value(t) for t in lights]
    key = (id(lights), type(like))
    hit = _OPAQUE.get(key)
    if hit is not None and hit[0] is lights:
        return hit[1]
    import drjit as dr  # (the Dr.Jit run only)

    table = [dr.opaque(type(like), _value(t)) if not is_drjit(t) else t for t in lights]
    if isinstance(lights, tuple):
        _OPAQUE.clear()  # one table at a time: a row's calls follow each other
        _OPAQUE[key] = (lights, table)
    return table


def _lights_kernel(ops, nx, ny, nz, visibility, lights, scale=1.0, batch=_BATCH):
    """s·Σ_k clamp(V_k, 0, 1)·max(n̂·d_k, 0)·P_k (R, G, B) over the N = len(visibility) lights of the table
    (``visibility`` a callable: V_k = visibility(k, n̂x, n̂y, n̂z), over every light of the table).
    On Dr.Jit the three sums are evaluated every `_BATCH` lights: one kernel of a fixed size per batch,
    instead of an unrolled graph of all N lights compiled once per channel. They start from three evaluated
    zero arrays, so that the first batch is the kernel of the others (issue 33, session 32: from 0·x, fused
    into it, the first batch was a kernel of its own, ~0.4–0.6 s of compiling a row on a first run)."""
    inv = 1.0 / ops.sqrt(ops.maximum(nx * nx + ny * ny + nz * nz, _TINY))
    x, y, z = nx * inv, ny * inv, nz * inv
    table = _device_table(ops, lights, x)
    device = ops is DRJIT_OPS and is_drjit(x)
    if device:
        import drjit as dr

        acc = [dr.opaque(type(x), 0.0, dr.width(x)) for _ in range(3)]  # (three buffers, as a batch's sums)
    else:
        zero = 0.0 * x
        acc = [zero, zero, zero]
    lazy = callable(visibility)  # V_k made per light (an in-kernel shadow test): one batch's graph at a time
    count = len(table) // 6 if lazy else min(len(visibility), len(table) // 6)
    for k in range(count):
        dx, dy, dz, pr, pg, pb = table[6 * k : 6 * k + 6]
        v = visibility(k, x, y, z) if lazy else visibility[k]
        c = ops.maximum(ops.fma(x, dx, ops.fma(y, dy, z * dz)), 0.0) * clamp01(ops, v)
        acc = [ops.fma(c, pr, acc[0]), ops.fma(c, pg, acc[1]), ops.fma(c, pb, acc[2])]
        if device and ((k + 1) % (batch if lazy else _BATCH) == 0 or k + 1 == count):
            dr.eval(*acc)
    return (acc[0] * scale, acc[1] * scale, acc[2] * scale)


SHADOW_BIAS = 0.01
"""The seed's depth bias (001:3026-3028: ``z − 0.01·dot(normalize(n_map), n) < depth``), in the map's
depth units: the orthographic projection maps the scene's bounding sphere's diameter 2r to [0, 1]
(001:2838-2851)."""
SHADOW_RESOLUTION = 128
"""Texels per edge of each light's depth map (the seed's "Depth map size" slider; its default is not
printed)."""


_CHANNELS = ("depth", "nx", "ny", "nz")


@dataclass(frozen=True, eq=False)
class DepthMaps:
    """The N lights' depth-and-normal maps (001:2814-2871), a sampler of the kernel: ``depth`` (N, R, R)
    (1: no surface), ``normals`` (N, R, R, 3) (0: none), float32 texels, row j along v; ``frames`` (N, 3, 3):
    each map's u axis t, v axis b and the direction d towards the light; the scene's bounding sphere
    (``centre`` c, ``radius`` r), map k's camera at c + r·d (`_project`). Texels reach each ops namespace once
    (``_table``): a shader's tables ``<input>_depth``, ``_nx``, ``_ny``, ``_nz`` (N·R² floats each)."""

    depth: np.ndarray
    normals: np.ndarray
    frames: np.ndarray
    centre: tuple
    radius: float
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        d, n = np.asarray(self.depth, np.float32), np.asarray(self.normals, np.float32)
        f = np.asarray(self.frames, np.float64)
        ok = d.ndim == 3 and d.shape[1:] == d.shape[1:][::-1] and n.shape == (*d.shape, 3)
        if not (ok and f.shape == (len(d), 3, 3) and self.radius > 0 and np.isfinite(d.sum() + n.sum())):
            raise ValueError(f"DepthMaps: finite depth (N, R, R), normals (N, R, R, 3), frames (N, 3, 3), "
                             f"radius > 0 (got {d.shape}, {n.shape}, {f.shape}, {self.radius})")  # fmt: skip
        for name, value in (("depth", d), ("normals", n), ("frames", f)):
            object.__setattr__(self, name, value)

    resolution = property(lambda self: int(self.depth.shape[1]), doc="R: texels per edge of each map")

    def _table(self, ops, channel: str, like):
        """The channel's N·R² texels: on NumPy (and for the shader tracer, which reads a table's size) the
        float32 values themselves (gathered, then widened: the same float64 values as a float64 table, at
        half its memory: 0.5 GiB of the quick suite's maps), a view of the maps (a normal's component strided
        through the (N, R, R, 3) normals: its contiguous copies were 115 MiB of ibl-samples' quick peak,
        issue 33); on Dr.Jit in ``like``'s type, on JAX float64."""
        drjit_kind = type(like) if ops is DRJIT_OPS and is_drjit(like) else None
        key = (ops.name, channel, drjit_kind)
        if key not in self._tables:
            c = _CHANNELS.index(channel)
            narrow = ops.name in (NUMPY_OPS.name, "shader")  # the shader tracer reads only a table's size
            texels = self.normals[..., c - 1] if c else self.depth
            if narrow:
                self._tables[key] = texels.reshape(-1)  # a view (evenly strided): no copy
            else:
                flat = np.ascontiguousarray(texels.reshape(-1), np.float64)
                self._tables[key] = drjit_kind(flat) if drjit_kind is not None else flat
        return self._tables[key]

    def sample(self, ops, channel: str, index, like):
        """Texel ``index`` (k·R² + j·R + i, a float holding an integer) of the channel (`_CHANNELS`): the
        sampler protocol of `rtfit.realtime.arrays.evaluate` (an object with ``sample`` passes as it is)."""
        texels = ops.gather(self._table(ops, channel, like), index)
        return texels.astype(np.float64) if ops is NUMPY_OPS else texels

    def release_backend_tables(self) -> None:
        """Drop the Dr.Jit copies of the texels (made again on the next use): the engine calls it after a
        row's cost run, whose float32 copies of six environments' maps held ~0.6 GiB to the case's end."""
        for key in [k for k in self._tables if isinstance(k, tuple) and k[0] == DRJIT_OPS.name]:
            del self._tables[key]

    def constants(self, ops, like) -> list:
        """Per light k its frame (t, b, d: 9 floats) and texel offset k·R²; then c and r: opaque scalars
        on Dr.Jit (one compiled kernel serves every batch of lights), else floats (a shader's literals)."""
        values = self._tables.get("const")
        if values is None:  # made once: a kernel reads its constants per light and tap (~10⁵ calls a run)
            offset = np.arange(len(self.frames))[:, None] * float(self.resolution) ** 2
            values = self._tables["const"] = [
                float(v)
                for v in (*np.hstack([self.frames.reshape(-1, 9), offset]).ravel(), *self.centre, self.radius)
            ]
        if ops is not DRJIT_OPS or not is_drjit(like):
            return values
        key = ("const", type(like))
        if key not in self._tables:
            import drjit as dr

            self._tables[key] = [dr.opaque(type(like), v) for v in values]
        return self._tables[key]

    def coords(self, points) -> np.ndarray:
        """(N, P, 3): the points' (u, v, z) in each light's map (`_project`, NumPy float64)."""
        p = np.asarray(points, np.float64)
        out = [_project(NUMPY_OPS, self, k, p[:, 0], p[:, 1], p[:, 2]) for k in range(len(self.frames))]
        return np.stack([np.stack(c, axis=-1) for c in out])


def _project(ops, maps: DepthMaps, k: int, px, py, pz):
    """(u, v, z) of the point in light k's map (`DepthMaps`; 001:2838-2851)."""
    c = maps.constants(ops, px)
    tx, ty, tz, bx, by, bz, dx, dy, dz = c[10 * k : 10 * k + 9]
    cx, cy, cz, r = c[-4:]
    rx, ry, rz = px - cx, py - cy, pz - cz
    u = 0.5 * ((rx * tx + ry * ty + rz * tz) / r + 1.0)
    v = 0.5 * ((rx * bx + ry * by + rz * bz) / r + 1.0)
    return u, v, 0.5 - (rx * dx + ry * dy + rz * dz) / (2.0 * r)


_MEMO_BYTES = 256 << 20
"""The most bytes of bias-independent test values (`_kept`) one map set keeps (NumPy). Issue 33 (session
34): a cap of 4096 points kept nothing at 128² (16384 points), and the teapot's depth-map fits (64 lights,
3×3 taps: 64 × 21 arrays of the points) recomputed every projection and filtered texel at each of their
~50 evaluations: 30 s of fits against 2.5 s of references; 64 × 21 × 16384 float64 are 176 MB."""
_MEMO_KEY = "kept-bytes"  # (the bytes `_kept` holds in a map set's tables)


def _kept(ops, maps: DepthMaps, key: tuple, points: tuple, make):
    """``make()``, on the NumPy run kept in ``maps`` per ``key`` for these very point arrays (identity), up to
    `_MEMO_BYTES` a map set (the entry that would pass it is computed and not kept): the fit's 33-value scan
    of b and its TRF steps evaluate the kernel again on the same points, and the projection and filtered
    texels do not depend on b (only the test does). The same operations on the same arrays: the same
    values. Other runs (Dr.Jit, a shader) trace it."""
    if ops is not NUMPY_OPS or not all(isinstance(a, np.ndarray) for a in points):
        return make()
    hit = maps._tables.get(key)
    if hit is not None and all(a is b for a, b in zip(hit[0], points, strict=True)):
        return hit[1]
    value = make()
    size = sum(np.asarray(v).nbytes for v in value)
    held = maps._tables.get(_MEMO_KEY, 0)
    if hit is not None:  # (other points' entry under this key: replaced)
        held -= sum(np.asarray(v).nbytes for v in hit[1])
    if held + size <= _MEMO_BYTES:
        maps._tables[key] = (points, value)
        maps._tables[_MEMO_KEY] = held + size
    elif hit is not None:
        del maps._tables[key]
        maps._tables[_MEMO_KEY] = held
    return value


def _shadow_test(ops, maps: DepthMaps, k: int, x, y, z, px, py, pz, bias, taps: int, normals: tuple):
    """Light k's seed test at the point (unit normal x, y, z): depth and normal filtered linearly (clamped
    addressing, texel centres at (i + ½)/R), lit where z − b·dot(n̂_map, n) < depth
    (001:3026-3028; a filtered normal shorter than 1e-6 reads a bias of 0: HLSL's normalize(0) is NaN), the
    mean over taps × taps compares one texel apart (taps = 1: the seed's single test; 3: a 3×3 PCF).
    ``normals``: the arrays (x, y, z) were normalised from, by which (with the points) the NumPy run keeps
    each tap's depth and cos θ (`_kept`: neither depends on the bias; a scan of b and the TRF steps pay the
    comparison alone)."""
    res = float(maps.resolution)
    points = (px, py, pz)
    u, v, zp = _kept(ops, maps, ("project", k), points, lambda: _project(ops, maps, k, px, py, pz))
    lit = 0.0 * zp
    offsets = [(a - (taps - 1) / 2) / res for a in range(taps)]
    for ov in offsets:
        for ou in offsets:

            def filtered(ou=ou, ov=ov) -> list:
                fx_ = ops.clip((u + ou) * res - 0.5, 0.0, res - 1.0)
                fy_ = ops.clip((v + ov) * res - 0.5, 0.0, res - 1.0)
                i0 = ops.minimum(ops.floor(fx_), max(res - 2.0, 0.0))
                j0 = ops.minimum(ops.floor(fy_), max(res - 2.0, 0.0))
                i1, j1 = ops.minimum(i0 + 1.0, res - 1.0), ops.minimum(j0 + 1.0, res - 1.0)
                fx, fy = fx_ - i0, fy_ - j0
                base = maps.constants(ops, zp)[10 * k + 9]
                val = []
                for ch in _CHANNELS:
                    t00, t01 = (maps.sample(ops, ch, base + j0 * res + i, zp) for i in (i0, i1))
                    t10, t11 = (maps.sample(ops, ch, base + j1 * res + i, zp) for i in (i0, i1))
                    top, bottom = t00 * (1 - fx) + t01 * fx, t10 * (1 - fx) + t11 * fx
                    val.append(top * (1 - fy) + bottom * fy)
                return val

            def compared(texels=filtered) -> tuple:
                depth, mx, my, mz = texels()
                length = ops.sqrt(mx * mx + my * my + mz * mz)
                cos = ops.select(length > 1e-6, (mx * x + my * y + mz * z) / ops.maximum(length, 1e-30), 0.0)
                return depth, cos

            depth, cos = _kept(ops, maps, ("compared", k, ou, ov), (*points, *normals), compared)
            lit = lit + ops.select(zp - bias * cos < depth, 1.0, 0.0)
    return lit * (1.0 / (taps * taps))


def _depth_kernel(ops, nx, ny, nz, px, py, pz, maps, lights, bias, taps=1):
    """The seed as printed: the one sum (`_lights_kernel`) with V_k its depth-map test in the kernel."""
    test = lambda k, x, y, z: _shadow_test(ops, maps, k, x, y, z, px, py, pz, bias, taps, (nx, ny, nz))  # noqa: E731
    return _lights_kernel(ops, nx, ny, nz, test, lights, batch=max(1, 4 // (taps * taps)))


# ===================================================================================== public API
def lights_irradiance(lights, normals, visibility=None):
    """E = Σ_k V_k max(n̂·d_k, 0) P_k (W/m², RGB, (..., 3)) of the light table ``lights`` (6·N floats) at
    ``normals`` (..., 3); ``visibility`` (N, ...) in [0, 1], None: every light visible (unoccluded)."""
    table = np.asarray(lights, np.float64).reshape(-1)
    if table.size % 6 or not table.size or not np.all(np.isfinite(table)):
        raise ValueError(f"lights must be 6·N finite floats (got {table.size})")
    x, y, z = split3(normals, "normals")
    count = table.size // 6
    shape = np.shape(np.asarray(x))
    vis = np.ones((count, *shape)) if visibility is None else np.asarray(visibility, np.float64)
    if vis.shape != (count, *shape):
        raise ValueError(f"visibility must be (N, ...) = {(count, *shape)} (got {vis.shape})")
    floats = [float(v) for v in table]

    def kernel(ops, x, y, z, *v):
        return _lights_kernel(ops, x, y, z, v, floats)

    out = evaluate(kernel, x, y, z, *vis)
    return np.stack([np.asarray(c, np.float64) for c in out], axis=-1)


# ===================================================================================== methods as data
COUNTS = (4, 16, 64, 256)
"""The quality knob: N lights per bake (one row per bake and N; the seed's slider "Num of samples")."""
_NORMAL = tuple(
    Input(f"n{c}", "1", f"surface normal {c} (world frame, +Z up; normalised by the kernel)", (-1.0, 1.0))
    for c in "xyz"
)
VISIBILITY = Input(
    "visibility",
    "1",
    "a tuple of N per-pixel arrays V_k ∈ [0, 1]: light k's visibility at the point (a shadow ray: 0 or 1)",
)
LIGHTS = Input(
    "lights",
    "W/m²",
    "6·N floats, per light k: its unit direction towards the light (x, y, z) and its power P_k (R, G, B: "
    "the irradiance at normal incidence of its cell of the map)",
)
_POINT = tuple(
    Input(f"p{c}", "m", f"visible point {c} (world frame; the depth-map rows project it)", (-1e3, 1e3))
    for c in "xyz"
)
INPUTS = (*_NORMAL, VISIBILITY, LIGHTS, *_POINT)
"""The quantity ``sky_irradiance_lights``'s inputs (the point: the depth-map rows' and a user's formula)."""


def visibility_names(n: int) -> tuple[str, ...]:
    """The per-pixel inputs v1..vN a row of N lights reads its visibilities from."""
    return tuple(f"v{k + 1}" for k in range(n))


def on_lights(kernel, n: int):
    """``kernel(ops, …, visibility=…)`` reading its N visibilities as the keywords v1..vN (one text: the
    tuple is handed to the same kernel)."""
    names = visibility_names(n)

    def on_inputs(ops, **kw):
        visibility = tuple(kw.pop(v) for v in names)
        return kernel(ops, visibility=visibility, **kw)

    return on_inputs


_Q = "sky_irradiance_lights"
_FORMULA = "E ≈ Σ_k V_k·max(n·d_k, 0)·P_k, P_k = Σ_{t∈cell k} w_t L_t"
_KERNEL_SOURCE = "001:3021-3038 (renderFinalShiny's diffuse sum)"
_BAKES = (
    (
        "seed-lloyd",
        "Seed: energy samples + Lloyd",
        "d_k: Lloyd-relaxed energy centroids of the spherical Voronoi cells",
        f"GameTools D5.3 §2.8 (seed 001:2738-3070, 001:2742); Kollig & Keller 2003; {_KERNEL_SOURCE}",
        "N lights by the map's energy, relaxed (Lloyd) over the sphere; an exact shadow ray per light",
    ),
    (
        "importance",
        "Energy samples, no relaxation",
        "d_k: energy-CDF picks (no Lloyd step)",
        f"the seed's placement before its relaxation; {_KERNEL_SOURCE}",
        "what Lloyd's relaxation buys: the same placement, the cells not relaxed",
    ),
    (
        "seed-depthmap",
        "Seed lights, depth-map shadows",
        "d_k: the seed-lloyd lights; V_k: each light's depth map (seed's bias, linear filtering)",
        f"seed 001:2738-3070, depth maps 001:2814-2871, test 001:3026-3028; {_KERNEL_SOURCE}",
        "the seed as printed: its Lloyd lights, each shadowed by an orthographic depth-and-normal map",
    ),
    (
        "median-cut",
        "Median cut (Debevec 2005)",
        "cells: 2ᵏ lat-long regions of equal energy, d_k their energy centroids",
        "Debevec 2005, A median cut algorithm for light probe sampling (SIGGRAPH 2005 poster)",
        "recursive equal-energy splits across the longer side; an exact shadow ray per light",
    ),
)
BAKES = tuple(b[0] for b in _BAKES)
"""The bakes, each a row per N of `COUNTS`: row id ``<bake>-<N>``."""


DEPTH_ROWS = {
    **{f"seed-depthmap-{n}": (n, SHADOW_RESOLUTION, 1) for n in COUNTS},
    "seed-depthmap-64-pcf3": (64, SHADOW_RESOLUTION, 3),
    "seed-depthmap-64-map64": (64, 64, 1),
    "seed-depthmap-64-map256": (64, 256, 1),
}
"""The depth-map rows (the test in the kernel): row id → (N, map resolution R, PCF taps per side)."""
BIAS = Param(SHADOW_BIAS, 0.0, 0.5, unit="1 (map depth, 2r = 1)", scan=33,
             description="depth bias b: lit where z − b·dot(n̂_map, n) < depth (the seed's 0.01; a step in b: "
             "fitted by a 33-value scan, 24 % apart)")  # fmt: skip
MAPS = Input("maps", "1", "the N lights' depth-and-normal maps (`DepthMaps`: a sampler of 4 tables)")


def on_maps(kernel, name: str):
    """``kernel`` reading its `DepthMaps` from the input ``name`` (one per row: each row's own maps)."""
    return lambda ops, **kw: kernel(ops, maps=kw.pop(name), **kw)


def maps_input(rid: str) -> str:
    """The input a depth-map row reads its maps from (``maps_<N>_<R>``: rows of the same maps share it)."""
    return "maps_{}_{}".format(*DEPTH_ROWS[rid][:2])


def _depth_rows(label, where, source, words):
    for rid, (n, res, taps) in DEPTH_ROWS.items():
        knob = f", {res}² maps" + (f", {taps}×{taps} PCF" if taps > 1 else "")
        yield Method(rid, f"{label}, N = {n}{knob}", on_maps(_depth_kernel, maps_input(rid)),
                     inputs=(*_NORMAL, *_POINT, replace(MAPS, name=maps_input(rid)), LIGHTS),
                     params={"bias": BIAS}, fixed={"taps": taps}, storage=6 * n + 4 * n * res**2, quantity=_Q,
                     formula=f"{_FORMULA}; {where}; V_k = mean of {taps}×{taps} taps [z − b·n̂_map·n < depth]",
                     source=source, description=f"{words} ({res}² texels, {taps}×{taps} taps)")  # fmt: skip


def _rows():
    for bake, label, where, source, words in _BAKES:
        if bake == "seed-depthmap":
            yield from _depth_rows(label, where, source, words)
            continue
        for n in COUNTS:
            vis = tuple(
                Input(v, "1", f"visibility of light {k + 1} of {n} (1: lit)", (0.0, 1.0))
                for k, v in enumerate(visibility_names(n))
            )
            yield Method(
                f"{bake}-{n}",
                f"{label}, N = {n}",
                on_lights(_lights_kernel, n),
                inputs=(*_NORMAL, *vis, LIGHTS),
                storage=6 * n,
                quantity=_Q,
                formula=f"{_FORMULA}; {where}",
                source=source,
                description=words,
            )


METHODS = method_table(_rows())
"""The ibl-samples rows: one kernel text, three bakes × N = 4, 16, 64, 256 lights, and the depth-map rows
(`DEPTH_ROWS`: the seed's test in the kernel, its bias b a parameter) (module docstring)."""
