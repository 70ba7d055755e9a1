"""Irradiance volumes: a regular grid of irradiance probes over a scene, looked up at a surface point.

A volume stores one irradiance basis per grid node (a *probe*): Valve's ambient cube (18 floats, RGB) or
SH L2 (27 floats), in the conventions and with the evaluation kernels of `rtfit.realtime.irradiance_bases`
(imported through its ``METHODS`` table; the basis formulas live there once). At a point x with unit
normal n the volume returns

    E(x, n) = Σ_c w_c(x) · B(n; coeffs_c)        (W/m² per RGB channel)

where the sum runs over the probes c the lookup picks and B is the basis's irradiance at n. Because every
basis here is linear in its stored floats, the kernel blends the stored floats first and evaluates the
basis once (Σ_c w_c B(n; k_c) = B(n; Σ_c w_c k_c)).

Grid (`ProbeGrid`): nodes at o + h·(i, j, k), 0 ≤ i < n_x, 0 ≤ j < n_y, 0 ≤ k < n_z, spacing h (m), node
index (k·n_y + j)·n_x + i (x fastest). With t = (x − o)/h per axis:

* ``nearest`` (seed 000:2502-2515, Valve's irradiance volume: "the nearest sample point … without any
  spatial filtering"): the node i = clamp(⌊t + ½⌋, 0, n − 1) per axis, weight 1. Piecewise constant: the
  looked-up irradiance jumps where x crosses a cell boundary t = i + ½ (the *popping* the seed mentions).
* ``trilinear``: i₀ = clamp(⌊t⌋, 0, n − 2), f = clamp(t − i₀, 0, 1), the 8 corner nodes with weights
  Π_axes (1 − f or f). Continuous in x, exact for fields linear in x (tests).

Points outside the grid are clamped to its boundary (the nearest node; trilinear: the boundary face's
bilinear value). A NaN coordinate is looked up as the grid's first node along that axis (no NaN index
reaches the gather, so no out-of-bounds read); normals follow `rtfit.realtime.irradiance_bases` (normalised
by the kernel, a zero normal gives the basis's sphere average). An axis of one node has weight 1 on it.

Light folding (seed 000:2502-2515, 7.4.3): a local light is added to a probe as a distant light from its
direction at the probe, so the probe's basis carries it (`fold_point_light`): for a point light of intensity
I (W/sr) at q, the probe at p gets a directional light of irradiance E⊥ = V·I/|q − p|² at normal incidence
from d = (q − p)/|q − p| (V: 1 when the probe sees the light). In the bases' own projections: SH L2
coefficients L_lm += E⊥ Y_lm(d) (`irradiance_bases.sh9_from_directional`); Valve's cube samples the
irradiance at its six axes, C[±a] += E⊥ max(±d_a, 0). (The NNLS cube is refitted on the folded probe's
irradiance by the family's audit, not here.) `fold_directional` folds any light given per probe as
(direction, E⊥), e.g. every delta light of a Mitsuba scene (`rtfit.reference.probe_radiance
.delta_light_irradiance`); `fold_point_light` is its closed form for one point light.

The engine's usual split (`with_direct`): the direct light of the local lights computed exactly per pixel,
the volume only for the bounced rest: E = E_direct + E_volume(x, n), the row ``direct-<method>``.

Methods as data: `METHODS` holds one `rtfit.realtime.methods.Method` per lookup × basis
(``nearest-cube-valve``, ``trilinear-sh-l2``, …); the lookup is the ``lookup`` keyword (`LOOKUPS`), the
basis a ``basis`` keyword holding the `irradiance_bases.METHODS` entry. Grid spacing is the volume's data,
not a kernel parameter: an experiment compares methods × spacings. Run a method with `volume_irradiance`
(dispatched like every public function of this package: NumPy → the default Dr.Jit backend and back,
Dr.Jit → lazy, JAX arrays → the JAX text) or on an ops namespace with ``method(ops, volume_inputs(...))``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from .arrays import DRJIT_OPS, NUMPY_OPS, evaluate, is_drjit, is_jax, split3, to_drjit
from .irradiance_bases import CUBE_AXES, sh9_from_directional
from .irradiance_bases import METHODS as BASIS_METHODS
from .methods import Input, Method, method_table

__all__ = [
    "LOOKUPS",
    "VOLUME_BASES",
    "ProbeGrid",
    "cube_from_directional",
    "directional_irradiance",
    "fold_directional",
    "fold_point_light",
    "probe_table",
    "volume_inputs",
    "volume_irradiance",
    "volume_weights",
    "with_direct",
]

VOLUME_BASES = ("cube-valve", "cube-nnls", "sh-l2")
"""The bases a volume stores (ids of `rtfit.realtime.irradiance_bases.METHODS`)."""


# ============================================================================================= the grid
@dataclass(frozen=True)
class ProbeGrid:
    """A regular probe grid: first node ``origin`` (m), node ``spacing`` h (m) and ``dims`` (n_x, n_y, n_z)
    nodes per axis (each ≥ 1). Node (i, j, k) sits at origin + h·(i, j, k), index (k·n_y + j)·n_x + i."""

    origin: tuple[float, float, float]
    spacing: float
    dims: tuple[int, int, int]

    def __post_init__(self):
        o = tuple(float(v) for v in self.origin)
        d = tuple(int(v) for v in self.dims)
        if len(o) != 3 or not all(math.isfinite(v) for v in o):
            raise ValueError(f"origin must be 3 finite numbers (got {self.origin!r})")
        if len(d) != 3 or min(d) < 1 or math.prod(d) >= 1 << 24:
            raise ValueError(f"dims must be 3 integers >= 1 with fewer than 2^24 nodes (got {self.dims!r})")
        h = float(self.spacing)
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"spacing must be a finite number > 0 (got {self.spacing!r})")
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "dims", d)
        object.__setattr__(self, "spacing", h)

    @property
    def count(self) -> int:
        """Number of probes n_x·n_y·n_z."""
        return math.prod(self.dims)

    def positions(self) -> np.ndarray:
        """Node positions (count, 3) in index order (x fastest), float64 metres."""
        nx, ny, nz = self.dims
        k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
        idx = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=-1).astype(np.float64)
        return np.asarray(self.origin) + self.spacing * idx

    def boundaries(self, axis: int) -> np.ndarray:
        """Coordinates along ``axis`` where the nearest node changes (cell boundaries t = i + ½)."""
        n = self.dims[axis]
        return self.origin[axis] + self.spacing * (np.arange(n - 1) + 0.5)

    def subgrid(self, step: int) -> tuple[ProbeGrid, np.ndarray]:
        """The grid of every ``step``-th node (spacing step·h) and the indices of its nodes in this grid.
        Each axis must have (n − 1) divisible by ``step``, so that both grids span the same box."""
        step = int(step)
        if step < 1 or any((n - 1) % step for n in self.dims):
            raise ValueError(
                f"step {step} does not divide the grid's cells {tuple(n - 1 for n in self.dims)}"
            )
        dims = tuple((n - 1) // step + 1 for n in self.dims)
        nx, ny, _ = self.dims
        k, j, i = np.meshgrid(*(np.arange(d) * step for d in dims[::-1]), indexing="ij")
        index = ((k * ny + j) * nx + i).ravel()
        return ProbeGrid(self.origin, self.spacing * step, dims), index  # type: ignore[arg-type]


# ============================================================================================= kernels
def _axis(ops, x, origin, inv_spacing):
    """t = (x − o)/h with NaN mapped to 0 (x ≠ x only for NaN), so that no NaN index reaches a gather."""
    t = (x - origin) * inv_spacing
    return ops.select(t == t, t, 0.0)


def _nearest_axis(ops, t, n, last):
    """[(node index, weight)] of the nearest node along one axis: clamp(⌊t + ½⌋, 0, n − 1), weight 1
    (``last`` = n − 1 as a number of the kernel's kind)."""
    return [(ops.clip(ops.floor(t + 0.5), 0.0, last), 1.0)]


def _trilinear_axis(ops, t, n, last):
    """[(node, weight)] of the two bracketing nodes: i₀ = clamp(⌊t⌋, 0, n − 2), f = clamp(t − i₀, 0, 1)."""
    if n == 1:
        return [(0.0 * t, 1.0)]
    i0 = ops.clip(ops.floor(t), 0.0, last - 1.0)
    f = ops.clip(t - i0, 0.0, 1.0)
    return [(i0, 1.0 - f), (i0 + 1.0, f)]


LOOKUPS = {"nearest": _nearest_axis, "trilinear": _trilinear_axis}
"""Lookup kind → per-axis rule giving the nodes and weights along one axis (the 3-D lookup is their
tensor product: 1 node for ``nearest``, 8 for ``trilinear``)."""


def _constants(grid: ProbeGrid, wrap: Callable[[float], Any] = float) -> dict:
    """The grid's numbers the kernel reads, each passed through ``wrap`` (Dr.Jit: ``dr.opaque``, so that one
    compiled kernel serves every grid of the same shape class)."""
    nx, ny, nz = grid.dims
    values = {
        "ox": grid.origin[0], "oy": grid.origin[1], "oz": grid.origin[2], "inv_h": 1.0 / grid.spacing,
        "lx": nx - 1.0, "ly": ny - 1.0, "lz": nz - 1.0, "sy": float(nx), "sz": float(nx * ny),
        "count": float(grid.count),
    }  # fmt: skip
    return {k: wrap(v) for k, v in values.items()}


def _corners(ops, px, py, pz, grid: ProbeGrid, lookup: str, c: dict | None = None):
    """[(node index as a float, weight)] of the nodes the lookup blends at (px, py, pz); ``c``: the grid's
    `_constants` (default: Python floats)."""
    c = c or _constants(grid)
    rule = LOOKUPS[lookup]
    nx, ny, nz = grid.dims
    ax = rule(ops, _axis(ops, px, c["ox"], c["inv_h"]), nx, c["lx"])
    ay = rule(ops, _axis(ops, py, c["oy"], c["inv_h"]), ny, c["ly"])
    az = rule(ops, _axis(ops, pz, c["oz"], c["inv_h"]), nz, c["lz"])
    return [(k * c["sz"] + j * c["sy"] + i, wk * wj * wi) for k, wk in az for j, wj in ay for i, wi in ax]


def _volume_kernel(
    ops, px, py, pz, nx, ny, nz, table, grid: ProbeGrid, lookup="trilinear", basis=None, constants=None
):
    """E(x, n) = B(n; Σ_c w_c k_c) per channel (module docstring).

    ``table``: the probes' stored floats, float-major: table[s·count + node] is stored float s of the node
    (`probe_table`), an array of the ops namespace's kind; ``grid`` the `ProbeGrid`; ``lookup`` a key of
    `LOOKUPS`; ``basis`` an `irradiance_bases.METHODS` entry (whose kernel reads ``storage`` floats);
    ``constants``: the grid's `_constants` as numbers of the kernel's kind (default: Python floats)."""
    assert basis is not None and basis.storage is not None
    c = constants or _constants(grid)
    corners = _corners(ops, px, py, pz, grid, lookup, c)
    coeffs = []
    for s in range(basis.storage):
        acc = None
        for node, w in corners:
            v = ops.gather(table, node + c["count"] * float(s))
            acc = v * w if acc is None else acc + v * w
        coeffs.append(acc)
    return basis(ops, {"nx": nx, "ny": ny, "nz": nz, "coeffs": coeffs})


# ============================================================================================= methods
_POSITION = (
    Input("px", "m", "lookup position x (world frame; outside the grid: clamped to it)"),
    Input("py", "m", "lookup position y"),
    Input("pz", "m", "lookup position z"),
)
_NORMAL = (
    Input("nx", "1", "surface normal x (normalised by the kernel)"),
    Input("ny", "1", "surface normal y"),
    Input("nz", "1", "surface normal z"),
)
_TABLE = Input("table", "W/m²", "probes' stored floats, float-major (probe_table): table[s·count + node]")
_GRID = Input("grid", "m", "the ProbeGrid (origin, spacing h, dims)")
_LOOKUP_TEXT = {
    "nearest": ("nearest probe", "node clamp(⌊(x − o)/h + ½⌋), no filtering", "Valve; seed 000:2502-2515"),
    "trilinear": (
        "trilinear",
        "8 nodes, weights Π(1 − f or f), f = frac((x − o)/h)",
        "standard 3-D texture filter",
    ),
}


def _volume_method(lookup: str, basis_id: str) -> Method:
    basis = BASIS_METHODS[basis_id]
    what, formula, source = _LOOKUP_TEXT[lookup]
    return Method(
        id=f"{lookup}-{basis_id}",
        label=f"{basis.label} volume, {what}",
        kernel=_volume_kernel,
        inputs=(*_POSITION, *_NORMAL, _TABLE, _GRID),
        fixed={"lookup": lookup, "basis": basis},
        storage=basis.storage,
        quantity="volume_irradiance",
        formula=f"E = B(n; Σ_c w_c k_c), {formula}; B: {basis.formula}",
        source=f"{source}; basis: {basis.source}",
        description=f"{basis.storage} floats per probe ({basis_id})",
    )


METHODS = method_table(_volume_method(lookup, b) for lookup in LOOKUPS for b in VOLUME_BASES)
"""One method per lookup × basis (ids ``<lookup>-<basis>``), in that order."""


_DIRECT = tuple(Input(f"direct_{c}", "W/m²", f"exact direct irradiance of the local lights, {c} channel")
                for c in "rgb")  # fmt: skip


def _direct_kernel(ops, direct_r, direct_g, direct_b, volume: Method, **inputs):
    """E = E_direct + E_volume per channel: the volume row's own kernel text, plus the exact direct light."""
    return tuple(e + v for e, v in zip((direct_r, direct_g, direct_b), volume(ops, inputs), strict=True))


def with_direct(method: Method) -> Method:
    """The row ``direct-<id>`` of a volume ``method`` (`METHODS` entry, with its grid fixed or as an input):
    the exact direct light of the local lights per pixel (inputs ``direct_r/g/b``, W/m²) plus the volume's
    lookup for the bounced rest (module docstring: the engine's usual split)."""
    return Method(
        id=f"direct-{method.id}",
        label=f"exact direct + {method.label}",
        kernel=_direct_kernel,
        inputs=(*_DIRECT, *method.inputs),
        fixed={"volume": method},
        storage=method.storage,
        quantity=method.quantity,
        formula=f"E = E_direct + E_volume; E_volume: {method.formula}",
        source=f"the usual real-time split (exact local lights, the volume for the rest); {method.source}",
        description=f"{method.description}; the direct light evaluated per pixel, not stored",
    )


SPLIT_METHODS = method_table(with_direct(m) for m in METHODS.values())
"""`with_direct` of every `METHODS` entry (ids ``direct-<lookup>-<basis>``): exact direct + the volume."""


# ============================================================================================= public
def probe_table(coeffs) -> np.ndarray:
    """The float-major table of a volume from per-probe basis coefficients ``coeffs`` (count, rows, 3):
    rows 6 (ambient cube in `irradiance_bases.CUBE_ORDER`) or 9 (SH L2), RGB last. Stored float s of a
    probe is channel-major (s = c·rows + row, as `irradiance_bases` stores one probe), and the table is
    table[s·count + node] (float64)."""
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 3 or c.shape[2] != 3 or c.shape[1] not in (6, 9) or c.shape[0] < 1:
        raise ValueError(f"coeffs must have shape (count, 6 or 9, 3) (got {c.shape})")
    if not np.all(np.isfinite(c)):
        raise ValueError("coeffs must be finite")
    per_probe = np.transpose(c, (0, 2, 1)).reshape(len(c), -1)  # (count, 3·rows), channel-major
    return np.ascontiguousarray(per_probe.T).reshape(-1)


def _method(method) -> Method:
    if isinstance(method, Method):
        return method
    try:
        return METHODS[method]
    except KeyError:
        raise ValueError(f"unknown volume method {method!r} (known: {', '.join(METHODS)})") from None


def _checked_table(m: Method, grid: ProbeGrid, table) -> np.ndarray:
    t = np.asarray(table, dtype=np.float64).reshape(-1)
    need = grid.count * int(m.storage or 0)
    if t.size != need:
        raise ValueError(
            f"table of method {m.id!r} must hold {m.storage} floats per probe × {grid.count} probes = {need} "
            f"values (got {t.size}); build it with probe_table"
        )
    return t


def volume_inputs(method, grid: ProbeGrid, table, points, normals) -> dict[str, Any]:
    """The kernel inputs of ``method`` for NumPy ``points`` and ``normals`` (N, 3): components as views,
    the table as a NumPy array of its own dtype, the grid. Run the NumPy text with
    ``method(NUMPY_OPS, inputs)``."""
    m = _method(method)
    px, py, pz = split3(np.asarray(points), "points")
    nx, ny, nz = split3(np.asarray(normals), "normals")
    _checked_table(m, grid, table)
    return {
        "px": px, "py": py, "pz": pz, "nx": nx, "ny": ny, "nz": nz,
        "table": np.asarray(table).reshape(-1), "grid": grid,  # the caller's dtype (float32: a shader's)
    }  # fmt: skip


def volume_irradiance(method, grid: ProbeGrid, table, points, normals):
    """Irradiance (W/m², RGB) of volume ``method`` (an id of `METHODS` or a `Method`) with probes ``table``
    (`probe_table`) on ``grid``, at ``points`` (..., 3) (m) with ``normals`` (..., 3).

    Returns (..., 3) for NumPy input (its dtype: float32 input runs the Dr.Jit kernel in float32, the
    shader's precision), a tuple (R, G, B) of lazy arrays for Dr.Jit input (3-vectors of Dr.Jit floats),
    JAX arrays for JAX input. NaN/Inf in NumPy points or normals raise (Dr.Jit input is not checked:
    NaN coordinates look up the first node, ±Inf the boundary)."""
    m = _method(method)
    t = _checked_table(m, grid, table)
    pts = split3(points, "points")
    nrm = split3(normals, "normals")
    for name, comps in (("points", pts), ("normals", nrm)):
        if not any(is_drjit(c) or is_jax(c) for c in comps) and not all(
            np.all(np.isfinite(c)) for c in comps
        ):
            raise ValueError(f"{name} must be finite")
    keywords = m.keywords()

    def kernel(ops, px, py, pz, nx, ny, nz):
        if ops is DRJIT_OPS:  # the grid as opaque arrays, the table aligned: one kernel for every grid
            Float = type(px)
            tab, c = to_drjit(Float, t), _constants(grid, lambda v: dr.opaque(Float, v))
        else:
            tab, c = t, None
        return m.kernel(
            ops, px=px, py=py, pz=pz, nx=nx, ny=ny, nz=nz, table=tab, grid=grid, constants=c, **keywords
        )

    out = evaluate(kernel, *pts, *nrm)
    if isinstance(out[0], np.ndarray):
        return np.stack(out, axis=-1)
    if isinstance(out[0], float):
        return np.array(out, dtype=np.float64)
    return out


def volume_weights(lookup: str, grid: ProbeGrid, points) -> tuple[np.ndarray, np.ndarray]:
    """The nodes and weights the ``lookup`` kind blends at NumPy ``points`` (N, 3): (index (N, K) int64,
    weight (N, K) float64), K = 1 (nearest) or 8 (trilinear); the kernel's own text on NumPy, float64."""
    if lookup not in LOOKUPS:
        raise ValueError(f"unknown lookup {lookup!r} (known: {', '.join(LOOKUPS)})")
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3) (got {p.shape})")
    corners = _corners(NUMPY_OPS, p[:, 0], p[:, 1], p[:, 2], grid, lookup)
    idx = np.stack([np.broadcast_to(c, len(p)) for c, _ in corners], axis=-1).astype(np.int64)
    w = np.stack([np.broadcast_to(np.asarray(wt, dtype=np.float64), len(p)) for _, wt in corners], axis=-1)
    return idx, w


def directional_irradiance(direction, irradiance, normals) -> np.ndarray:
    """Irradiance (M, 3) of a distant light at unit ``normals`` (M, 3): E⊥·max(n·d, 0) (``irradiance``: E⊥
    (3,) W/m² at normal incidence; ``direction`` d towards the light, normalised here)."""
    d = np.asarray(direction, dtype=np.float64)
    n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
    if not (n > 0.0 and math.isfinite(n)):
        raise ValueError(f"direction must be 3 finite numbers, not all zero (got {direction!r})")
    cos = np.maximum(np.asarray(normals, dtype=np.float64) @ (d / n), 0.0)
    return cos[:, None] * (np.asarray(irradiance, dtype=np.float64) * np.ones(3))[None, :]


def cube_from_directional(direction, irradiance) -> np.ndarray:
    """Valve's cube (6, 3) of a distant light: the irradiance at each of the six axes a (`CUBE_AXES`),
    C[a] = E⊥·max(a·d, 0) (`directional_irradiance` at the axes)."""
    return directional_irradiance(direction, irradiance, np.asarray(CUBE_AXES))


def fold_directional(directions, irradiance) -> tuple[np.ndarray, np.ndarray]:
    """The additions to probes of lights given per probe as a direction d (count, 3) towards the light and
    its irradiance E⊥ (count, 3) W/m² at normal incidence (module docstring, light folding): SH L2
    (count, 9, 3) L_lm = E⊥ Y_lm(d) and Valve's cube (count, 6, 3) C[a] = E⊥ max(a·d, 0)."""
    d = np.asarray(directions, dtype=np.float64)
    e = np.asarray(irradiance, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3 or e.shape != d.shape:
        raise ValueError(f"directions and irradiance must both be (count, 3) (got {d.shape}, {e.shape})")
    sh = np.zeros((len(d), 9, 3))
    cube = np.zeros((len(d), 6, 3))
    for k in range(len(d)):
        if not np.any(e[k]):
            continue
        sh[k] = sh9_from_directional(d[k])[:, None] * e[k][None, :]
        cube[k] = cube_from_directional(d[k], e[k])
    return sh, cube


def fold_point_light(
    positions, light_position: Sequence[float], intensity, visible=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fold a point light into probes at ``positions`` (count, 3) (module docstring): per probe the
    direction d (count, 3) to the light, E⊥ = V·I/r² (count, 3) (``intensity`` I RGB in W/sr, ``visible``
    V (count,) in [0, 1], default 1), and the light's additions to the probe's bases: SH L2 (count, 9, 3)
    and Valve's cube (count, 6, 3). A probe at the light's position is refused (E⊥ is infinite there)."""
    p = np.asarray(positions, dtype=np.float64)
    q = np.asarray(light_position, dtype=np.float64)
    i = np.asarray(intensity, dtype=np.float64) * np.ones(3)
    if p.ndim != 2 or p.shape[1] != 3 or q.shape != (3,):
        raise ValueError(
            f"positions must be (count, 3) and light_position 3 numbers (got {p.shape}, {q.shape})"
        )
    v = np.ones(len(p)) if visible is None else np.asarray(visible, dtype=np.float64)
    delta = q[None, :] - p
    r2 = np.einsum("ij,ij->i", delta, delta)
    if np.any(r2 <= 1e-12):
        raise ValueError("a probe sits at the light's position (E⊥ = I/r² is infinite there)")
    d = delta / np.sqrt(r2)[:, None]
    e_perp = (v / r2)[:, None] * i[None, :]
    sh, cube = fold_directional(d, e_perp)
    return d, e_perp, sh, cube
