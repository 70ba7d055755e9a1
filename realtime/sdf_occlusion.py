r"""SDF occlusion and skylight (Evans 2006) and cone-traced distance-field occlusion, Dr.Jit-vectorized.

Source: A. Evans, "Fast Approximations for Global Illumination on Dynamic Scenes", SIGGRAPH 2006
course *Advanced Real-Time Rendering in 3D Graphics and Games*, ch. 9 (seed ``000_540fc7eee6870c4d.txt``,
cited as 000:LINE).

Sign convention: s(P) > 0 outside, < 0 inside (see `rtfit.realtime.sdf_grid`). The seed's text uses
S = −s (000:2891-2895, "positive inside"), its listings use s (000:3037-3040). Every formula below is
the seed's, rewritten with S_text = −s; the seed's contrast k_text (negative to darken, since
S_text + d ≥ 0 near occluders) is k = −k_text here (positive darkens). Distances are in scene units.

Evans skylight / occlusion (000:2919-2946)
----------------------------------------
With unit surface normal N, sky-up unit vector U, sky weighting α ∈ [0, 1] and the bent normal
N' = N + α U (000:2942), samples i = 1..n at distances d_i = base·2^(i−1) (doubling from one voxel,
000:2938), each read from mip level i − 1 of a Gaussian-prefiltered SDF (000:2936-2938):

    D = Σ_i w_i (d_i − s_{i−1}(P + d_i N'))          (≥ 0 when occluders are near: s ≤ distance)
    C = B · exp(−k D)

* In an empty half-space above a plane, s(P + d N) = d: D = 0 and C = B (000:2919-2929). The text's
  sum starts at d_0 = 0 (the sample at P itself, the curvature term); ``include_d0`` adds it (level 0).
* Text form (000:2946): α = 0.5, w_i = 1, B = 1. Listing 1 (000:2982-2987): delta = 0.03·(N + U), i.e.
  α = 1, weights (1, 1.2, 1.4, 1.8), no "+ d_i" term (a constant factor, absorbed in its
  ``GlobalBrightness``: B here). The seed gives no k: it is always fitted (or set by the user).
* N' is used unnormalised as in the seed (the sample at d_i then lies d_i·|N'| away and the
  expectation d_i is the text's, not the true distance); ``normalize=True`` uses N'/|N'|, for which an
  unoccluded point gives exactly C = B. N' of zero length (α = 1, N = −U) falls back to N.
* Guard (``clamp=True``, default): each sample is limited to the distance of its position from P,
  s_i ← min(s_i, d_i·|N'|) — a true SDF of a surface point obeys it; blurred, out-of-grid or empty-scene
  samples may not. With it an empty scene gives C = B exactly when ``normalize`` or α = 0; the seed's
  unnormalised N' gives exp(k Σ w_i d_i (|N'| − 1)) ≥ B there, the seed form's own bias.
* Overflow: the exponent −kD is clamped to [−87, 80] (float32 exp overflows above 88.7), so k = 0 gives
  C = B, and huge k gives C = 0 (occluded) or B·e^80 at most where D < 0 (documented, finite).

Curvature term (000:2885-2908): C_curv = 0.5 + exp(k_text·S_text(P)) with S the blurred SDF sampled on the
surface (slightly positive in creases in the text's sign). Here ``curvature_term`` returns exactly that
with S_text = −s_L(P) from mip level L; the experiment compares C_curv/1.5 (1 on a flat surface).

Cone-traced distance-field occlusion (the modern variant; e.g. Wright 2015, "Dynamic occlusion with signed
distance fields", SIGGRAPH Advances; Quilez's soft shadows): M cone axes ω_j spread over the cosine-weighted
hemisphere around N (stratified, golden-angle spiral: r_j = √((j+½)/M), φ_j = 2.39996·j), each marched at
S distances t_s growing geometrically from t_0 to t_max; a cone's visibility is
v_j = min_s clamp(k·s(P + t_s ω_j)/t_s, 0, 1) (k = 1/tan of the cone half-angle), read from the mip level
whose voxel matches the cone's width t_s/k; AO = (1/M) Σ_j v_j.

Inputs and outputs
------------------
``points`` and ``normals``: (N, 3) NumPy arrays (evaluated on the default Dr.Jit backend in float32, returned
as NumPy float32, or in float64 NumPy with ``backend="numpy"``) or Dr.Jit Array3f (returned lazily as the
matching Float). Normals are normalised in the kernel (zero normals give C = B: no direction to test).
``sdf``: a `GridSDF` (mip chain of `SdfGrid` levels) or an `AnalyticSDF` (primitives; ``level`` ignored).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from .arrays import (
    DRJIT_OPS,
    NUMPY_OPS,
    backend_type,
    check_scalar,
    get_default_backend,
    is_drjit,
    to_drjit,
)
from .methods import Input, Method, Param, method_table
from .sdf_grid import EMPTY_DISTANCE, SdfGrid, build_mips, primitives_sdf

__all__ = [
    "LISTING_WEIGHTS",
    "AnalyticSDF",
    "EvansParams",
    "GridSDF",
    "cone_kernel",
    "cone_occlusion",
    "curvature_kernel",
    "curvature_term",
    "evans_exponent_kernel",
    "evans_from_terms_kernel",
    "evans_kernel",
    "evans_occlusion",
    "evans_sample_positions",
    "evans_terms",
    "evans_terms_jacobian",
]

LISTING_WEIGHTS = (1.0, 1.2, 1.4, 1.8)
"""Per-sample weights of the seed's Listing 1 (000:2983-2986)."""
EXP_MIN, EXP_MAX = -87.0, 80.0
CONE_LEVEL_K = 2.0
"""The cone march reads the mip level whose voxel matches t/CONE_LEVEL_K (a cone of half-angle atan ½),
whatever k: k then only scales the visibility, so one compiled kernel serves every k."""
_GOLDEN = math.pi * (3.0 - math.sqrt(5.0))


def _const(ops, like, value):
    """A parameter as a kernel input: an opaque Dr.Jit scalar (one compiled kernel serves every value of it:
    grids of the same shape, any k, α, base), or the float itself for NumPy/JAX."""
    if ops.name == "drjit" and is_drjit(like):  # (already one: `rtfit.realtime.arrays.evaluate`'s)
        return value if is_drjit(value) else dr.opaque(type(like), float(value))
    return float(value) if isinstance(value, (int, float, np.number)) else value  # a JAX tracer (a fit) as is


# ===================================================================================== SDF sources
class AnalyticSDF:
    """Union of analytic primitives (`rtfit.realtime.sdf_grid` Sphere, Box, HalfSpace, Capsule)."""

    levels = 1

    def __init__(self, prims):
        self.prims = list(prims)
        self.voxel = 0.0

    def sample(self, ops, level, x, y, z):
        return primitives_sdf(ops, self.prims, x, y, z)

    def level_voxel(self, level):
        return 0.0


class GridSDF:
    """A mip chain of voxel SDFs with trilinear sampling (clamp to the box of cell centres, plus the
    distance to that box outside it). Build with ``GridSDF.from_grid(grid, levels, prefilter=...)``."""

    def __init__(self, levels: list[SdfGrid]):
        if not levels:
            raise ValueError("GridSDF needs at least one level")
        self.grids = list(levels)
        self.levels = len(levels)
        self.voxel = levels[0].voxel
        self._dr_cache: dict = {}

    @classmethod
    def from_grid(cls, grid: SdfGrid, levels: int = 8, *, prefilter: bool = True, sigma: float = 1.0):
        return cls(build_mips(grid, levels, prefilter=prefilter, sigma=sigma))

    def level_voxel(self, level):
        return self.grids[min(level, self.levels - 1)].voxel

    def _arrays(self, ops, Float, level):
        g = self.grids[min(level, self.levels - 1)]
        if ops.name != "drjit":  # the float64 copy made once per level (it was made per sample call)
            hit = self._dr_cache.get(("float64", level))
            if hit is None or hit[0] is not g.values:
                hit = self._dr_cache[("float64", level)] = (g.values, g.values.astype(np.float64).reshape(-1))
            return hit[1]
        key = (Float, level)
        arr = self._dr_cache.get(key)
        if arr is None:
            arr = to_drjit(Float, g.values)
            dr.make_opaque(arr)
            self._dr_cache[key] = arr
        return arr

    def sample(self, ops, level, x, y, z):
        g = self.grids[min(level, self.levels - 1)]
        nx, ny, nz = g.shape
        h = _const(ops, x, g.voxel)
        inv = _const(ops, x, 1.0 / g.voxel)
        ox, oy, oz = (_const(ops, x, c) for c in g.origin)
        ux = (x - ox) * inv - 0.5
        uy = (y - oy) * inv - 0.5
        uz = (z - oz) * inv - 0.5
        cx = ops.clip(ux, 0.0, nx - 1.0)
        cy = ops.clip(uy, 0.0, ny - 1.0)
        cz = ops.clip(uz, 0.0, nz - 1.0)
        ex, ey, ez = (ux - cx) * h, (uy - cy) * h, (uz - cz) * h
        sq = ex * ex + ey * ey + ez * ez
        # 0 inside the box; the select keeps forward-mode autodiff finite there
        # (d√q = dq/(2√q) is 0/0 at q = 0)
        outside = ops.select(sq > 0, ops.sqrt(ops.maximum(sq, 1e-30)), sq * 0.0)
        fx0 = ops.minimum(ops.floor(cx), nx - 2.0)
        fy0 = ops.minimum(ops.floor(cy), ny - 2.0)
        fz0 = ops.minimum(ops.floor(cz), nz - 2.0)
        fx, fy, fz = cx - fx0, cy - fy0, cz - fz0
        if ops.name == "drjit":
            Float = type(x)
            vals = self._arrays(ops, Float, level)
            UInt = dr.uint32_array_t(Float)
            base = UInt(fz0) * (ny * nx) + UInt(fy0) * nx + UInt(fx0)

            def at_drjit(off):
                return dr.gather(Float, vals, base + off)

            at = at_drjit
        else:  # NumPy (float64) or JAX (a fit's trace): integer-valued float indices, exact below 2^53
            vals = self._arrays(ops, None, level)
            base = (fz0 * ny + fy0) * nx + fx0

            def at_table(off):
                return ops.gather(vals, base + off)

            at = at_table

        sxy = nx * ny
        c00 = at(0) * (1 - fx) + at(1) * fx
        c10 = at(nx) * (1 - fx) + at(nx + 1) * fx
        c01 = at(sxy) * (1 - fx) + at(sxy + 1) * fx
        c11 = at(sxy + nx) * (1 - fx) + at(sxy + nx + 1) * fx
        c0 = c00 * (1 - fy) + c10 * fy
        c1 = c01 * (1 - fy) + c11 * fy
        return c0 * (1 - fz) + c1 * fz + outside


# ===================================================================================== parameters
@dataclass(frozen=True)
class EvansParams:
    """Parameters of the Evans skylight. ``base`` in scene units (the seed: one voxel of the finest grid);
    ``weights`` (length n) or None (all 1); ``prefilter``: sample i reads mip level i − 1 (else level 0)."""

    n: int = 4
    base: float = 0.01
    k: float = 10.0
    alpha: float = 0.5
    weights: tuple | None = None
    brightness: float = 1.0
    normalize: bool = False
    include_d0: bool = False
    prefilter: bool = True
    up: tuple = (0.0, 0.0, 1.0)
    clamp: bool = True

    def __post_init__(self):
        if not isinstance(self.n, (int, np.integer)) or not 1 <= self.n <= 16:
            raise ValueError(f"n (samples) must be an integer in [1, 16] (got {self.n!r})")
        check_scalar("base", self.base, 0.0, 1e30, lo_open=True)
        check_scalar("k", self.k, 0.0, 1e30)
        check_scalar("alpha", self.alpha, 0.0, 1.0)
        check_scalar("brightness", self.brightness, 0.0, 1e30)
        if self.weights is not None:
            w = tuple(float(v) for v in self.weights)
            if len(w) != self.n or not all(math.isfinite(v) and v >= 0 for v in w):
                raise ValueError(f"weights must be {self.n} finite numbers >= 0 (got {self.weights!r})")
            object.__setattr__(self, "weights", w)
        u = np.asarray(self.up, dtype=np.float64)
        if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
            raise ValueError(f"up must be a finite non-zero 3-vector (got {self.up!r})")
        object.__setattr__(self, "up", tuple(float(c) for c in u / np.linalg.norm(u)))

    def distances(self) -> list[float]:
        return [self.base * 2.0**i for i in range(self.n)]


def evans_sample_positions(point, normal, params: EvansParams) -> np.ndarray:
    """The n sample positions P + d_i N' (float64, (n, 3)) for one point: for tests and figures."""
    p = np.asarray(point, dtype=np.float64)
    nrm = np.asarray(normal, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm)
    b = nrm + params.alpha * np.asarray(params.up)
    m = np.linalg.norm(b)
    if params.normalize:
        b = b / m if m > 1e-6 else nrm
    elif m <= 1e-6:
        b = nrm
    return np.array([p + d * b for d in params.distances()])


# ===================================================================================== kernels
def _unit(ops, x, y, z):
    m = ops.sqrt(x * x + y * y + z * z)
    inv = 1.0 / ops.maximum(m, 1e-30)
    return x * inv, y * inv, z * inv, m


def _evans_samples(ops, sdf, params: EvansParams, px, py, pz, nx, ny, nz, alpha=None, base=None):
    """The Evans sample terms D_i = d_i − s_i, i = 1..n (s_i read along the skewed normal
    N' = N + α·U, normalised or not, clamped to |N'|·d_i when ``params.clamp``), the unit-normal length
    ``|N|`` (0 marks a degenerate normal) and the base distance. A zero-length N' falls back to N.
    ``alpha``/``base``: kernel inputs replacing ``params.alpha``/``params.base`` (Dr.Jit AD scalars for
    `evans_terms_jacobian`)."""
    nx, ny, nz, nlen = _unit(ops, nx, ny, nz)
    ux, uy, uz = params.up
    a = _const(ops, px, params.alpha) if alpha is None else alpha
    base = _const(ops, px, params.base) if base is None else base
    bx, by, bz = nx + a * ux, ny + a * uy, nz + a * uz
    bm = ops.sqrt(bx * bx + by * by + bz * bz)
    degenerate = bm < 1e-6
    if params.normalize:
        inv = 1.0 / ops.maximum(bm, 1e-30)
        bx, by, bz = bx * inv, by * inv, bz * inv
    bx = ops.select(degenerate, nx, bx)
    by = ops.select(degenerate, ny, by)
    bz = ops.select(degenerate, nz, bz)
    one = px * 0.0 + 1.0
    reach = one if params.normalize else ops.select(degenerate, one, bm)  # |N'| actually used
    terms = []
    for i in range(params.n):
        d = base * float(2**i)
        level = i if params.prefilter else 0
        s = sdf.sample(ops, level, px + d * bx, py + d * by, pz + d * bz)
        if params.clamp:  # a surface point's true SDF obeys s(P + v) ≤ |v|
            s = ops.minimum(s, d * reach)
        terms.append(d - s)
    return terms, nlen


def evans_exponent_kernel(ops, terms, *, logB=0.0, k=1.0, weights=None):
    """The exponent of Evans' estimator before its clamp: log B − k Σ_i w_i D_i (dimensionless).

    ``terms``: the sample terms D_i = d_i − s_{i−1}(P + d_i N') (scene units), a sequence of arrays or an
    (n, N) array (`evans_terms`); ``weights``: n numbers (None: all 1); ``k`` in 1/scene unit; ``logB`` the
    natural log of the brightness B. The sum runs over i in order (D_1 first)."""
    acc: Any = None  # a NumPy or Dr.Jit array after the first term
    for i in range(len(terms)):
        t = terms[i] if weights is None else weights[i] * terms[i]
        acc = t if acc is None else acc + t
    return logB - k * acc


def evans_from_terms_kernel(ops, terms, *, logB=0.0, k=1.0, weights=None):
    """Evans' estimator from its sample terms, C = exp(clip(log B − k Σ_i w_i D_i, −87, 80)) (000:2946):
    the one text of B·exp(−Σ_i c_i D_i) (c_i = k·w_i) that the point kernel, every fit and every
    prediction run. Arguments as `evans_exponent_kernel`; the clamp keeps float32 ``exp`` finite (module
    docstring), so its derivative is 0 where the exponent leaves [−87, 80]."""
    e = evans_exponent_kernel(ops, terms, logB=logB, k=k, weights=weights)
    return ops.exp(ops.clip(e, EXP_MIN, EXP_MAX))


def evans_kernel(ops, sdf, params: EvansParams, px, py, pz, nx, ny, nz):
    """Evans skylight/occlusion C at points (px, py, pz) with normals (nx, ny, nz) on ``ops`` (the text
    `evans_occlusion` runs): C = B·exp(clip(−k Σ_i w_i D_i)) with D_i from the sample kernel and, with
    ``params.include_d0``, the term D_0 = −s_0(P) (weight 1) first."""
    terms, nlen = _evans_samples(ops, sdf, params, px, py, pz, nx, ny, nz)
    weights = list(params.weights or (1.0,) * params.n)
    if params.include_d0:
        terms = [-sdf.sample(ops, 0, px, py, pz), *terms]
        weights = [1.0, *weights]
    bright = _const(ops, px, params.brightness)
    c = bright * evans_from_terms_kernel(ops, terms, k=_const(ops, px, params.k), weights=weights)
    return ops.select(nlen > 0, c, bright + px * 0.0)


def _evans_terms_kernel(ops, sdf, params: EvansParams, px, py, pz, nx, ny, nz, alpha=None, base=None):
    """The per-sample terms D_i = d_i − s_i (clamped as in `evans_kernel`), i = 1..n, as a tuple."""
    terms, nlen = _evans_samples(ops, sdf, params, px, py, pz, nx, ny, nz, alpha, base)
    return tuple(ops.select(nlen > 0, t, px * 0.0) for t in terms)


def evans_terms(points, normals, sdf, params: EvansParams, *, backend: str | None = None) -> np.ndarray:
    """D_i = d_i − s_i for i = 1..n as an (n, N) NumPy array, so that C = B·exp(−k Σ_i w_i D_i): the
    linear-in-(k·w_i) form the experiment fits (k and the weights do not change the sample positions)."""
    if is_drjit(points):
        raise ValueError("evans_terms takes NumPy points (it returns NumPy)")
    p = np.asarray(_split_points(points, "points"))  # NumPy input (checked above): an (N, 3) array
    n = np.asarray(_split_points(normals, "normals"))
    if backend == "numpy":
        with np.errstate(all="ignore"):
            out = _evans_terms_kernel(
                NUMPY_OPS,
                sdf,
                params,
                *[p[:, i].astype(np.float64) for i in range(3)],
                *[n[:, i].astype(np.float64) for i in range(3)],
            )
        return np.stack([np.asarray(o, dtype=np.float64) for o in out])
    be = backend or get_default_backend()
    Float = (dr.cuda if be == "cuda" else dr.llvm).Float
    cols = [to_drjit(Float, a[:, i]) for a in (p, n) for i in range(3)]
    out = _evans_terms_kernel(DRJIT_OPS, sdf, params, *cols)
    dr.eval(*out)
    return np.stack([np.array(o, dtype=np.float64) for o in out])


def evans_terms_jacobian(points, normals, sdf, params: EvansParams, *, backend: str | None = None):
    r"""D_i = d_i − s_{i−1}(P + d_i N') and its derivatives with respect to α and the base distance, by
    Dr.Jit forward-mode autodiff through the kernel (``drjit.<llvm|cuda>.ad.Float``, float32).

    Returns ``(D, dD_dalpha, dD_dbase)``, each an (n, N) float64 NumPy array; ∂/∂base is per scene unit.
    With d_i = base·2^(i−1) and N'(α) = N + αU (or N'/|N'| with ``normalize``), the sample position
    x_i = P + d_i N' moves continuously with α and base, so

        ∂D_i/∂α    = −d_i ∇s_{i−1}(x_i)·∂N'/∂α,
        ∂D_i/∂base = 2^(i−1) (1 − ∇s_{i−1}(x_i)·N'),

    with ∇s the gradient of the trilinear (or analytic) SDF; where the guard s_i ← min(s_i, d_i|N'|) is
    active, s_i is replaced by d_i|N'| and differentiated as such. Each sample keeps its discrete mip level
    i − 1, so D is piecewise smooth in (α, base): the trilinear gradient jumps on cell faces (a kink, not a
    jump of D). Degenerate normals give 0 rows as in `evans_terms`. Needs a Dr.Jit backend ("llvm" or
    "cuda"; None: the default backend)."""
    if not isinstance(params, EvansParams):
        raise ValueError("params must be an EvansParams")
    if is_drjit(points):
        raise ValueError("evans_terms_jacobian takes NumPy points (it returns NumPy)")
    be = backend or get_default_backend()
    if be not in ("llvm", "cuda"):
        raise ValueError(f"evans_terms_jacobian needs a Dr.Jit backend, 'llvm' or 'cuda' (got {be!r})")
    p = np.asarray(_split_points(points, "points"))  # NumPy input (checked above): an (N, 3) array
    nrm = np.asarray(_split_points(normals, "normals"))
    if nrm.shape != p.shape:
        raise ValueError(f"points and normals must have the same shape (got {p.shape} and {nrm.shape})")
    if not np.all(np.isfinite(p)) or not np.all(np.isfinite(nrm)):
        raise ValueError("points and normals must be finite")
    Float = backend_type("Float", be, ad=True)
    # One trace and one forward pass for both derivatives: the points twice, the tangent t (0, grad 1) moving
    # α on the first copy and the base on the second (α + t·sel, base + t·(1 − sel): the same values), so
    # that dD/dt is ∂D/∂α on the first half and ∂D/∂base on the second; recorded once per field and sample
    # layout (`drjit.freeze`) and replayed at every (α, base) of a fit (`_frozen_jacobian`).
    m = len(p)
    cols = [to_drjit(Float, np.concatenate([a[:, i], a[:, i]])) for a in (p, nrm) for i in range(3)]
    sel = to_drjit(Float, np.repeat(np.array([1.0, 0.0], np.float32), m))
    tables = []  # every level a sample may ask for (levels past the last read the last)
    if isinstance(sdf, GridSDF):
        tables = [sdf._arrays(DRJIT_OPS, Float, lv) for lv in range(max(sdf.levels, params.n + 1))]
    run = _frozen_jacobian(Float, sdf, params)
    terms, g = run(cols, sel, Float(float(params.alpha)), Float(float(params.base)), tables)
    dr.eval(terms, g)
    values = np.stack([np.array(x, dtype=np.float64)[:m] for x in terms])
    grads = np.stack([np.array(x, dtype=np.float64) for x in g])
    return values, grads[:, :m], grads[:, m:]


_FROZEN: dict = {}
_FROZEN_MAX = 64


def _frozen_jacobian(Float, sdf, params: EvansParams):
    """The Jacobian pass of `evans_terms_jacobian` as a frozen Dr.Jit function (`drjit.freeze`: the kernels
    recorded at the first call and replayed at the next, with the inputs swapped in; re-recorded by Dr.Jit
    when an input's size changes), one per Float type, field and everything of ``params`` that shapes the
    kernel (n, normalize, prefilter, clamp, up: α and the base are its inputs). The field's level arrays are
    inputs too (a frozen function may read no array it is not given); its grid shapes, origin and voxel are
    part of the recording, hence the field in the key (held, so that its id is not reused). Replaying
    skips the Python-side tracing of ~1,000 operations and their forward-mode graph: 0.7 ms a call
    against 2.7 ms for 2,048 points, the same values bit for bit."""
    key = (Float, id(sdf), params.n, params.normalize, params.prefilter, params.clamp, params.up)
    hit = _FROZEN.get(key)
    if hit is not None and hit[1] is sdf:
        return hit[0]

    def run(cols, sel, alpha, base, tables):
        if tables:  # the recording reads the given level arrays (the field's own cache is put back after)
            saved = dict(sdf._dr_cache)
            sdf._dr_cache.update({(Float, lv): t for lv, t in enumerate(tables)})
        try:
            t = dr.zeros(Float, 1)
            dr.enable_grad(t)
            a = alpha + t * sel
            b = base + t * (1.0 - sel)
            terms = _evans_terms_kernel(DRJIT_OPS, sdf, params, *cols, alpha=a, base=b)
            dr.forward_from(t)
            return [dr.detach(x) for x in terms], [dr.grad(x) for x in terms]
        finally:
            if tables:
                sdf._dr_cache.clear()
                sdf._dr_cache.update(saved)

    frozen = dr.freeze(run)
    if len(_FROZEN) >= _FROZEN_MAX:
        _FROZEN.pop(next(iter(_FROZEN)))
    _FROZEN[key] = (frozen, sdf)
    return frozen


def curvature_kernel(ops, distance, k, norm=1.0):
    """The seed's curvature shading from the blurred SDF at the point,
    (0.5 + exp(clip(k·S_text, −87, 80)))/norm with S_text = −``distance`` (000:2902-2904; ``k`` in
    1/scene unit, the text's sign: negative darkens creases). ``norm`` = 1.5: 1 when flat."""
    s_text = -distance
    return (0.5 + ops.exp(ops.clip(k * s_text, EXP_MIN, EXP_MAX))) / norm


def _curvature_point_kernel(ops, sdf, level, k, px, py, pz):
    return curvature_kernel(ops, sdf.sample(ops, level, px, py, pz), _const(ops, px, k))


def _cone_axes(m: int):
    out = []
    for j in range(m):
        r = math.sqrt((j + 0.5) / m)
        phi = _GOLDEN * j
        out.append((r * math.cos(phi), r * math.sin(phi), math.sqrt(max(0.0, 1.0 - r * r))))
    return out


def cone_kernel(ops, sdf, cones, steps, t0, t_max, k, px, py, pz, nx, ny, nz):
    """Cone-traced distance-field AO in [0, 1] at points (px, py, pz) with normals (nx, ny, nz) on ``ops``
    (the text `cone_occlusion` runs; module docstring): ``cones`` axes, ``steps`` march distances from
    ``t0`` to ``t_max`` (scene units), aperture ``k`` = 1/tan(half-angle)."""
    total = px * 0.0
    kk = _const(ops, px, k)
    if ops.name == "numpy":  # k only scales the march's samples: a fit of k reuses them (`_numpy_cone_march`)
        nlen, marches = _numpy_cone_march(sdf, cones, steps, t0, t_max, px, py, pz, nx, ny, nz)
    else:
        nlen, marches = _cone_march(ops, sdf, cones, steps, t0, t_max, px, py, pz, nx, ny, nz)
    for march in marches:
        vis = px * 0.0 + 1.0
        for tt, s in march:
            vis = ops.minimum(vis, ops.clip(kk * s / tt, 0.0, 1.0))
        if ops.name in ("numpy", "jax"):  # (cones, N): the cones' sum in the loop's order
            for j in range(cones):
                total = total + vis[j]
        else:  # Dr.Jit (one cone a kernel) or the shader tracer (the cones unrolled)
            total = total + vis
            if ops.name == "drjit":
                dr.eval(total)
    ao = total * (1.0 / cones)
    return ops.select(nlen > 0, ao, 1.0 + px * 0.0)


def _cone_march(ops, sdf, cones, steps, t0, t_max, px, py, pz, nx, ny, nz):
    """The part of `cone_kernel` that does not depend on k: the normals' length and, per cone axis (NumPy/JAX:
    one batch of every axis), the march's (t_s, s(P + t_s ω)) pairs, an iterator that traces each axis as it
    is read (Dr.Jit: one kernel a cone, evaluated before the next is traced)."""
    nx, ny, nz, nlen = _unit(ops, nx, ny, nz)
    # Branchless orthonormal basis (Duff et al. 2017, "Building an orthonormal basis, revisited").
    sgn = ops.select(nz >= 0, 1.0 + nz * 0.0, -1.0 + nz * 0.0)
    a = -1.0 / (sgn + nz)
    b = nx * ny * a
    t1x, t1y, t1z = 1.0 + sgn * nx * nx * a, sgn * b, -sgn * nx
    t2x, t2y, t2z = b, sgn + ny * ny * a, -ny
    ratio = (t_max / t0) ** (1.0 / max(steps - 1, 1))
    ts = [t0 * ratio**s for s in range(steps)]
    t_scale = _const(ops, px, t0)  # t_s = t0 · ratio^s: the geometric ratio is structural, t0 is an input
    axes = _cone_axes(cones)
    if ops.name in ("numpy", "jax"):
        # NumPy/JAX: every cone at once, the axes as a leading (cones, 1) dimension broadcast against the
        # points — the same arithmetic as one cone at a time, traced once: a JAX fit compiles `steps` field
        # samples instead of cones × steps (9 × 8 cones: a fit of k on 4096 points took 175 s on 2 loaded
        # cores, the compile of 72 inlined trilinear samples; session 6).
        axes = [tuple(np.asarray([a[i] for a in axes], dtype=np.float64)[:, None] for i in range(3))]

    def march(axis):
        # Dr.Jit: the axis enters as kernel inputs and each cone is evaluated on its own: LLVM's build time
        # grows about quadratically with kernel size (measured on one core under load: 929 ops 2.5 s,
        # 2,605 ops 13 s, 7,615 ops = 9 cones × 8 steps 147 s), so nine identical one-cone kernels compile
        # once (2.5 s) where the fused kernel took minutes.
        lx, ly, lz = (_const(ops, px, c) for c in axis)
        wx = lx * t1x + ly * t2x + lz * nx
        wy = lx * t1y + ly * t2y + lz * ny
        wz = lx * t1z + ly * t2z + lz * nz
        out = []
        for t in ts:
            width = t / CONE_LEVEL_K  # level choice independent of k: one compiled kernel serves every k
            tt = t_scale * (t / t0)
            level = 0
            if sdf.voxel > 0:
                level = max(0, min(sdf.levels - 1, math.floor(math.log2(max(width / sdf.voxel, 1.0)))))
            out.append((tt, sdf.sample(ops, level, px + tt * wx, py + tt * wy, pz + tt * wz)))
        return out

    return nlen, (march(axis) for axis in axes)


_CONE_MARCHES: list = []
"""`_numpy_cone_march`'s memo: (key, sdf, nlen, marches), the last few, newest last."""
_CONE_MARCHES_MAX = 2
MEMOS = (_FROZEN, _CONE_MARCHES)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def _numpy_cone_march(sdf, cones, steps, t0, t_max, *cols):
    """`_cone_march` on NumPy, memoised on the field (its identity), the march settings and the points' and
    normals' bytes: a fit of k (the engine's ``cone`` row, SciPy's trf) calls the kernel on the same inputs
    at every step, and only k changes (the same arrays: identical results)."""
    h = hashlib.blake2b(digest_size=16)
    for c in (t0, t_max, *cols):
        c = np.asarray(c)
        h.update(repr((c.dtype.str, c.shape)).encode())
        h.update(np.ascontiguousarray(c).tobytes())
    key = (id(sdf), int(cones), int(steps), h.digest())
    for i, (k, s, nlen, marches) in enumerate(_CONE_MARCHES):
        if k == key and s is sdf:
            _CONE_MARCHES.append(_CONE_MARCHES.pop(i))
            return nlen, marches
    nlen, gen = _cone_march(NUMPY_OPS, sdf, cones, steps, t0, t_max, *cols)
    marches = [list(m) for m in gen]
    _CONE_MARCHES.append((key, sdf, nlen, marches))
    del _CONE_MARCHES[:-_CONE_MARCHES_MAX]
    return nlen, marches


# ===================================================================================== dispatch
def _split_points(v, name):
    if is_drjit(v):
        return v[0], v[1], v[2]
    a = np.asarray(v)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) (got {a.shape})")
    return a


def _run(kernel, points, normals, backend, *extra):
    """Evaluate ``kernel(ops, px, py, pz[, nx, ny, nz])`` on NumPy float64 (backend='numpy'), or Dr.Jit."""
    if is_drjit(points):
        p = (points[0], points[1], points[2])
        n = (normals[0], normals[1], normals[2]) if normals is not None else ()
        return kernel(DRJIT_OPS, *p, *n)
    p = np.asarray(_split_points(points, "points"))  # NumPy input (Dr.Jit returned above): an (N, 3) array
    n = np.asarray(_split_points(normals, "normals")) if normals is not None else None
    if n is not None and n.shape != p.shape:
        raise ValueError(f"points and normals must have the same shape (got {p.shape} and {n.shape})")
    if not np.all(np.isfinite(p)) or (n is not None and not np.all(np.isfinite(n))):
        raise ValueError("points and normals must be finite")
    if len(p) == 0:
        return np.zeros(0, np.float32 if backend != "numpy" else np.float64)
    if backend == "numpy":
        cols = [p[:, i].astype(np.float64) for i in range(3)]
        if n is not None:
            cols += [n[:, i].astype(np.float64) for i in range(3)]
        with np.errstate(all="ignore"):
            return np.asarray(kernel(NUMPY_OPS, *cols), dtype=np.float64)
    be = backend or get_default_backend()
    Float = (dr.cuda if be == "cuda" else dr.llvm).Float
    cols = [to_drjit(Float, p[:, i]) for i in range(3)]
    if n is not None:
        cols += [to_drjit(Float, n[:, i]) for i in range(3)]
    out = kernel(DRJIT_OPS, *cols)
    return np.array(out, dtype=np.float32).reshape(-1)


def evans_occlusion(points, normals, sdf, params: EvansParams, *, backend: str | None = None):
    """Evans skylight/occlusion C (dimensionless; 1 = unoccluded for B = 1) at each point. See the module
    docstring. ``backend``: None (the default Dr.Jit backend), "llvm", "cuda" or "numpy" (float64)."""
    if not isinstance(params, EvansParams):
        raise ValueError("params must be an EvansParams")
    return _run(lambda ops, *a: evans_kernel(ops, sdf, params, *a), points, normals, backend)


def curvature_term(points, sdf, *, k: float, level: int = 0, backend: str | None = None):
    """The seed's curvature shading 0.5 + exp(k·S_text(P)), S_text = −s_level(P) (000:2902-2904)."""
    k = check_scalar("k", k, -1e30, 1e30)
    if not isinstance(level, (int, np.integer)) or level < 0:
        raise ValueError(f"level must be an integer >= 0 (got {level!r})")
    return _run(
        lambda ops, x, y, z: _curvature_point_kernel(ops, sdf, int(level), k, x, y, z), points, None, backend
    )


def cone_occlusion(
    points,
    normals,
    sdf,
    *,
    cones: int = 9,
    steps: int = 8,
    t0: float,
    t_max: float,
    k: float = 2.0,
    backend: str | None = None,
):
    """Cone-traced distance-field AO in [0, 1] (module docstring). ``t0`` < ``t_max`` in scene units;
    ``k`` = 1/tan(cone half-angle) > 0."""
    if not isinstance(cones, (int, np.integer)) or not 1 <= cones <= 64:
        raise ValueError(f"cones must be an integer in [1, 64] (got {cones!r})")
    if not isinstance(steps, (int, np.integer)) or not 1 <= steps <= 64:
        raise ValueError(f"steps must be an integer in [1, 64] (got {steps!r})")
    t0 = check_scalar("t0", t0, 0.0, 1e30, lo_open=True)
    t_max = check_scalar("t_max", t_max, t0, 1e30)
    k = check_scalar("k", k, 0.0, 1e30, lo_open=True)
    return _run(
        lambda ops, *a: cone_kernel(ops, sdf, int(cones), int(steps), t0, t_max, k, *a),
        points,
        normals,
        backend,
    )


_ = EMPTY_DISTANCE  # re-exported meaning: an empty AnalyticSDF samples as 'very far' (C = B exactly)


# ===================================================================================== methods
EVANS_SAMPLES = 4
"""n of the Evans rows of `METHODS`: the seed's four samples (000:2938; Listing 1 has four weights)."""
CURVATURE_LEVEL = 1
"""Mip level whose blurred SDF the curvature row reads (one Gaussian step: creases show, noise does not)."""
_EVANS_INPUT = Input(
    "terms",
    "scene units",
    "the sample terms D_i = d_i − s_{i−1}(P + d_i N'), (n, N) (`evans_terms` at the row's α and base)",
)
# The seed gives no contrast k, no per-sample c_i and no Listing-1 brightness (000:2946, 000:2982-2987): their
# defaults are starts of the fit, not values of the method (`Param.published`).
_K = Param(
    10.0, 0.0, 1e4, unit="1/scene unit", description="contrast k (the seed's −k_text)", published=False
)
_LOG_B = Param(
    0.0,
    -5.0,
    5.0,
    unit="1",
    description="log B, B the brightness (Listing 1's GlobalBrightness)",
    published=False,
)
_ALPHA = Param(0.5, 0.0, 1.0, unit="1", description="sky weighting α of the bent normal N + αU")
_BASE = Param(1.0, 0.25, 4.0, unit="voxels", description="base distance d_1 in voxels of the finest grid")
_C = Param(
    10.0, 0.0, 1e4, unit="1/scene unit", description="per-sample coefficient c_i = k·w_i", published=False
)


def _evans_row_kernel(
    ops, terms, *, logB=0.0, k=1.0, weights=None, alpha=0.5, base_voxels=1.0, **coefficients
):
    """`evans_from_terms_kernel` under the names of the Evans rows. ``alpha`` and ``base_voxels`` place
    the samples: they enter through ``terms`` (computed at them by `evans_terms`), not here; the row
    declares them so that its whole parameter set, bounds and units sit in one place. The weights are
    ``weights`` (None: all 1), or the coefficients ``c1``..``cn`` with k = 1 (the continuous fit)."""
    del alpha, base_voxels  # (see the docstring: already in ``terms``)
    if coefficients:
        names = [f"c{i + 1}" for i in range(len(terms))]
        if sorted(coefficients) != sorted(names):
            raise ValueError(f"Evans coefficients must be {', '.join(names)} (got {', '.join(coefficients)})")
        weights = [coefficients[c] for c in names]
    return evans_from_terms_kernel(ops, terms, logB=logB, k=k, weights=weights)


def _cone_row_kernel(ops, px, py, pz, nx, ny, nz, *, sdf, t0, t_max, k, cones, steps):
    return cone_kernel(ops, sdf, cones, steps, t0, t_max, k, px, py, pz, nx, ny, nz)


_POINTS = (
    Input("px", "scene units", "surface point x"),
    Input("py", "scene units", "surface point y"),
    Input("pz", "scene units", "surface point z"),
    Input("nx", "1", "unit normal x"),
    Input("ny", "1", "unit normal y"),
    Input("nz", "1", "unit normal z"),
)
_EVANS_FORMULA = "C = B·exp(−k Σ_i w_i (d_i − s_{i−1}(P + d_i (N + αU)))), d_i = base·2^(i−1)"

METHODS = method_table(
    [
        Method(
            id="evans-text",
            label="Evans, seed text (α=½, w=1; k fit)",
            kernel=_evans_row_kernel,
            inputs=(_EVANS_INPUT,),
            params={"k": _K},
            fixed={"alpha": 0.5, "base_voxels": 1.0, "weights": None},
            quantity="sky_visibility",
            formula=_EVANS_FORMULA + "; α = ½, w_i = 1, B = 1",
            source="000:2919-2946",
            description="the seed's text form; it gives no k, so k is fitted per case",
        ),
        Method(
            id="evans-listing",
            label="Evans, seed listing (α=1, w=1…1.8; k, B fit)",
            kernel=_evans_row_kernel,
            inputs=(_EVANS_INPUT,),
            params={"k": _K, "logB": _LOG_B},
            fixed={"alpha": 1.0, "base_voxels": 1.0, "weights": LISTING_WEIGHTS},
            quantity="sky_visibility",
            formula=_EVANS_FORMULA + "; α = 1, w = (1, 1.2, 1.4, 1.8)",
            source="000:2982-2987",
            description="Listing 1; its missing '+ d_i' is a constant factor, fitted as B with k",
        ),
        Method(
            id="evans-fit",
            label="Evans, fitted per case",
            kernel=_evans_row_kernel,
            inputs=(_EVANS_INPUT,),
            params={
                "logB": _LOG_B,
                **{f"c{i + 1}": _C for i in range(EVANS_SAMPLES)},
                "alpha": _ALPHA,
                "base_voxels": _BASE,
            },
            fixed={"k": 1.0},
            quantity="sky_visibility",
            formula="C = exp(log B − Σ_i c_i D_i(α, base)); k = c_1, w_i = c_i/c_1",
            source="000:2919-2946",
            description="every parameter fitted: B, c_i = k·w_i, α and the base distance",
        ),
        Method(
            id="curvature",
            label="Curvature (seed §9.5; k fit)",
            kernel=curvature_kernel,
            inputs=(
                Input("distance", "scene units", f"s_{CURVATURE_LEVEL}(P), the blurred SDF at the point"),
            ),
            params={
                "k": Param(
                    -10.0, -1e4, 1e4, unit="1/scene unit", description="the text's k_text", published=False
                )
            },
            fixed={"norm": 1.5},
            quantity="crease_darkening",
            formula="(0.5 + exp(k_text·S_text(P)))/1.5, S_text = −s",
            source="000:2885-2908",
        ),
        Method(
            id="cone",
            label="Cone-traced DF AO (k grid-searched)",
            kernel=_cone_row_kernel,
            inputs=(
                *_POINTS,
                Input("sdf", "scene units", "the distance field (GridSDF or AnalyticSDF)"),
                Input("t0", "scene units", "first march distance"),
                Input("t_max", "scene units", "last march distance"),
            ),
            params={"k": Param(2.0, 0.0, math.inf, unit="1", description="1/tan(cone half-angle)")},
            fixed={"cones": 9, "steps": 8},
            quantity="ambient_occlusion",
            formula="AO = (1/M) Σ_j min_s clamp(k·s(P + t_s ω_j)/t_s, 0, 1)",
            source="Wright 2015; Quilez",
        ),
    ]
)
"""The approximations of the sdf-occlusion family as data (`rtfit.realtime.methods`): id, label, kernel,
inputs with units, free parameters with bounds and units, fixed values. The Evans rows share one kernel
(`evans_from_terms_kernel` on the sample terms of `evans_terms`); the experiment derives its rows, fits,
labels and cost rows from this table."""
