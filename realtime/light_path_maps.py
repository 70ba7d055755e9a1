r"""Light path maps: one diffuse bounce from a moving light as a weighted sum of clustered virtual lights.

The exact quantity (``path_map_irradiance``, W/m², one value per RGB channel c) is the one-bounce indirect
irradiance at a surface point x with unit normal n_x, for the light where it is now:

    E₁,c(x) = ∫_S (a_c(y)/π) E_dir,c(y) · V(x, y) cos θ_y cos θ_x / |x − y|² dA(y)

(S: the scene's surfaces, a_c their diffuse albedo, E_dir,c the light's direct irradiance with its shadows,
θ_y and θ_x the angles of x − y to n_y and of y − x to n_x).

**The seed** (001:2523-2538, 2562-2736: GameTools D5.3 §2.7, the "Path Map" tool, after Szécsi, Szirmay-Kalos
& Sbert 2006, "Light path maps"). A precompute samples N *entry points* y_j uniformly by area on the surfaces
(``sampleSurfaceRadion``, 001:2674; each stands for A_j = A_S/N of surface), clusters them by position and
orientation into K clusters (a balanced kd-tree, then k-means; an empty cluster takes half of another's
points, 001:2675-2677: `cluster_entry_points`), and renders, per cluster k, each entry point as a virtual
point light (VPL) into that cluster's atlas pane (``BushToAtlas``, 001:2646): the **transfer**

    T_k,c(x) = Σ_{j ∈ k} a_c(y_j) A_j V(x, y_j) · τ(x, y_j),   τ = cos θ_y cos θ_x / (π r²)  (`vpl_transfer`)

(irradiance at x per unit irradiance at the entry points; unit 1). At run time (``ComputeWeights`` and
``Walk``, 001:2660-2666, 2710) the light's direct irradiance at every entry point is read with a shadow
map, averaged per cluster (w_k,c = mean_{j ∈ k} E_dir,c(y_j), W/m²), and the panes are blended:

    E₁,c(x) ≈ Σ_{k=1}^{K} w_k,c T_k,c(x)                                                    (``walk_kernel``)

Exact (up to the N-point quadrature of the integral) when every entry point of a cluster receives the same
irradiance; with K = N (one entry point per cluster) it **is** the plain VPL sum (instant radiosity, Keller
1997) of those N points. Rows: K = 1, 4, 16 and the seed's 32 panes per object (``NCLUSTERSPERENTITY``,
001:2538, 001:2716); cost per pixel: K texture reads and multiply-adds (the precompute's N shadow-mapped VPLs
per texel are paid once, offline).

**The seed's cut** (``cutNearness2``, 001:2646): a VPL's 1/r² is singular at its own surface; a shaded point
closer than d_c to the VPL's plane is projected onto the plane at height d_c along n_y (001:2646: "projected
onto the cutting plane perpendicular to the surface normal at the virtual light source"), so that a wall
meeting the VPL's floor is lit uniformly near the corner. With h = (x − y)·n_y (height over the VPL's plane),
ρ² = |x − y|² − h² (lateral), q = n_x·(y − x) and c = n_x·n_y, the cut moves x by δ = max(h, d_c) − h along
n_y: h' = h + δ, r'² = ρ² + h'², n_x·(y − x') = q − δc, and

    τ = h' · max(q − δc, 0) / (π r'⁴)     for h > 0;   0 for h ≤ 0 (x behind the VPL's surface).

The seed gives no value ("should be set according to the sampling probability", 001:2646); rtfit's default
is the radius of the disc each entry point stands for, d_c = √(A_S/(π N)) (`default_cut`); the audit fits
d_c ∈ [0, 8] × that radius (`CUT`) across the light positions (one bake serves every position).

Units: h, ρ², q, d_c in scene units (m, m²); a_c and c dimensionless; τ in 1/m², A_j in m², T in 1, w and E
in W/m². Domain: n_x, n_y unit; q ∈ [−r, r]; c ∈ [−1, 1]; d_c ≥ 0.

Float32: r'² ≥ `R2_MIN` (guard: d_c = 0 and x on the VPL itself would divide by 0; the guarded term is then
bounded by h'·q/r'⁴ ≤ 1/r'² at r' = 10⁻⁶, finite in float32 at 10¹²), and r'⁴ is formed as (r'²)² with
r'² ≥ 10⁻¹² (≥ 10⁻²⁴ > float32's smallest normal 1.2·10⁻³⁸: no underflow to 0). The walk is a sum of K
products of values ≤ 10⁴ · 10³: no overflow.

Extremes (tests): K = 1 (one average weight), the light on a surface (entry points at distance 0 get
E_dir = 0 behind or a large finite one in front: finite), zero albedo (T = 0 → 0), d_c = 0 and x on the VPL:
finite. Errata: none in the seed's text; its bush of further bounces (``shootRadionBush``, 001:2679: each
entry point also shoots VPLs of later bounces into its pane) is left out here, as the reference is exactly
one bounce (π × (path depth 2 − depth 1)); the seed's spotlight form factor for the weights (001:2662) is
the scene's own light here (its direct irradiance at each entry point, with shadows).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .methods import Input, Method, Param, method_table

__all__ = [
    "CLUSTERS",
    "CUT",
    "CUT_FIT_ROW",
    "ENTRY_POINTS",
    "KMAX",
    "SEED_CLUSTERS",
    "cluster_entry_points",
    "default_cut",
    "membership",
    "path_map_rows",
    "vpl_transfer",
    "walk_kernel",
]

ENTRY_POINTS = 1024
"""Entry points N of the bake (the seed's ``NRADIONS`` is a multiple of 4096, 001:2716: rtfit's scenes are a
room, and the audit's test images small)."""
SEED_CLUSTERS = 32
"""The seed's panes per object (``NCLUSTERSPERENTITY`` = 32, 001:2538 and 001:2716)."""
CLUSTERS = (1, 4, 16, SEED_CLUSTERS)
"""The K of the rows (``path-map-k<K>``; K = 32 is the seed's ``seed-path-map``)."""
KMAX = max(CLUSTERS)
R2_MIN = 1e-12
"""Smallest r'² (m²) the transfer divides by (module docstring, float32)."""
NORMAL_WEIGHT = 0.25
"""k-means distance: position plus this × the scene diagonal × the normal (001:2675: "clustered according to
their position and orientation"; the seed gives no weight: a quarter of the scene keeps a floor's and a
wall's points apart near their corner)."""
KMEANS_ITERATIONS = 12


# ---------------------------------------------------------------------------------------------- kernels
def vpl_transfer(ops, h, rho2, q, c, cut):
    """τ = h'·max(q − δc, 0)/(π r'⁴) with the seed's cut (module docstring), 0 behind the VPL (h ≤ 0)."""
    h_cut = ops.maximum(h, cut)
    delta = h_cut - h
    r2 = ops.maximum(rho2 + h_cut * h_cut, R2_MIN)  # guard: d_c = 0 and x on the VPL (float32 note)
    cos_term = ops.maximum(q - delta * c, 0.0)  # guard: the moved point may face away from the VPL
    tau = h_cut * cos_term / (np.pi * r2 * r2)
    return ops.select(h > 0.0, tau, 0.0 * tau)  # guard: x behind the VPL's surface gets nothing


def walk_kernel(ops, *, clusters=KMAX, **kw):
    """Σ_{k ≤ K} w_k T_k (inputs ``w<k>``, ``pane<k>``): the run-time blend of the K cluster panes (``Walk``,
    001:2664-2666). (Not ``t<k>``: the shader tracer names its temporaries t0, t1, …)"""
    acc = kw["w1"] * kw["pane1"]
    for k in range(2, clusters + 1):
        acc = ops.fma(kw[f"w{k}"], kw[f"pane{k}"], acc)
    return acc


# ---------------------------------------------------------------------------------------------- precompute
def default_cut(area: float, entry_points: int) -> float:
    """d_c = √(A_S/(π N)): the radius of the disc each entry point stands for (scene units)."""
    return float(np.sqrt(max(area, 0.0) / (np.pi * max(entry_points, 1))))


def _kd_split(points: np.ndarray, index: np.ndarray, k: int) -> list[np.ndarray]:
    """A balanced kd-tree over ``index`` into ``k`` leaves (the seed's ``clusterRadions``): split at the
    median along the widest axis, the leaf counts proportional to the sizes."""
    if k <= 1 or len(index) <= 1:
        return [index]
    p = points[index]
    axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
    order = index[np.argsort(p[:, axis], kind="stable")]
    k_lo = k // 2
    cut = round(len(order) * k_lo / k)
    return _kd_split(points, order[:cut], k_lo) + _kd_split(points, order[cut:], k - k_lo)


def cluster_entry_points(positions: np.ndarray, normals: np.ndarray, k: int, scale: float) -> np.ndarray:
    """The cluster (0…K−1) of each of N entry points: a balanced kd-tree, then `KMEANS_ITERATIONS` Lloyd
    steps on (position, `NORMAL_WEIGHT` × ``scale`` × normal) (001:2675-2677). A cluster left empty takes
    half of the largest cluster's points (the seed's rule), so every cluster of K ≤ N has a point; K ≥ N
    gives each point its own cluster (the plain VPL sum)."""
    n = len(positions)
    if k < 1:
        raise ValueError(f"clusters must be >= 1 (got {k!r})")
    if k >= n:
        return np.arange(n)
    feat = np.hstack([positions, NORMAL_WEIGHT * scale * normals]).astype(np.float64)
    label = np.empty(n, np.int64)
    for i, leaf in enumerate(_kd_split(feat[:, :3], np.arange(n), k)):
        label[leaf] = i
    for _ in range(KMEANS_ITERATIONS):
        centres = np.stack([feat[label == i].mean(axis=0) for i in range(k)])
        d2 = ((feat[:, None, :] - centres[None]) ** 2).sum(axis=2)
        new = np.argmin(d2, axis=1)
        for i in range(k):  # the seed's rule: an empty cluster takes half of the largest one's points
            if not np.any(new == i):
                big = int(np.argmax(np.bincount(new, minlength=k)))
                members = np.flatnonzero(new == big)
                new[members[: len(members) // 2]] = i
        if np.array_equal(new, label):
            break
        label = new
    return label


def membership(labels: np.ndarray, k: int) -> np.ndarray:
    """The (N, K) 0/1 matrix of entry point j in cluster k: T = τ·M sums each pane, w = M̄ᵀE averages."""
    m = np.zeros((len(labels), k))
    m[np.arange(len(labels)), labels] = 1.0
    return m


# ---------------------------------------------------------------------------------------------- rows
_T = tuple(
    Input(f"pane{k}", "1", f"cluster {k}'s baked transfer at the point (per unit entry-point irradiance)",
          (0.0, 1.0e3))
    for k in range(1, KMAX + 1)
)  # fmt: skip
_W = tuple(
    Input(f"w{k}", "W/m²", f"cluster {k}'s weight: the light's mean direct irradiance at its entry points",
          (0.0, 1.0e4))
    for k in range(1, KMAX + 1)
)  # fmt: skip
INPUTS = (*_T, *_W)
"""The quantity ``path_map_irradiance``'s inputs (`rtfit.realtime.quantities`)."""
CUT = Param(1.0, 0.0, 8.0, unit="× √(A_S/(π N))",
            description="the seed's cut distance d_c (cutNearness), in entry-point disc radii",
            published=False)  # fmt: skip
"""The bake's free parameter d_c (module docstring): fitted by the audit over its light positions."""
_Q = "path_map_irradiance"


def path_map_rows(k: int) -> Method:
    """The walk on K clusters: id ``path-map-k<K>`` (``seed-path-map`` for the seed's 32), its inputs t1…tK,
    w1…wK."""
    if not 1 <= k <= KMAX:
        raise ValueError(f"clusters must be in [1, {KMAX}] (got {k!r})")
    seed = k == SEED_CLUSTERS
    base = Method(
        "seed-path-map" if seed else f"path-map-k{k}",
        f"{'Seed: ' if seed else ''}light path map, K = {k} cluster panes",
        walk_kernel,
        inputs=(*_T[:k], *_W[:k]),
        fixed={"clusters": k},
        quantity=_Q,
        formula="Σ_k w_k T_k,  T_k = Σ_{j∈k} a_j A_j V τ(d_c),  w_k = mean_{j∈k} E_dir(y_j)",
        source="GameTools D5.3 §2.7, seed 001:2646 (BushToAtlas), 001:2660-2666 (ComputeWeights, Walk)",
    )
    return replace(base, description=f"{ENTRY_POINTS} entry points, d_c = √(A_S/(π N))")


CUT_FIT_ROW = "seed-path-map-cut-fit"
"""The seed's K = 32 baked with the cut d_c fitted (`CUT`) across the light positions (the audit's bake)."""
METHODS = method_table(
    [
        *(path_map_rows(k) for k in CLUSTERS),
        replace(
            path_map_rows(SEED_CLUSTERS),
            id=CUT_FIT_ROW,
            label=f"Seed light path map, K = {SEED_CLUSTERS}, cut d_c fitted",
            description=f"{ENTRY_POINTS} entry points, d_c fitted across the light positions (CUT)",
        ),
    ]
)
"""The light-path-map rows as data (`rtfit.realtime.methods`): the run-time blend on K = 1, 4, 16 and the
seed's 32 cluster panes, baked from `ENTRY_POINTS` entry points with the default cut; and the seed's 32 baked
with the fitted cut (`CUT_FIT_ROW`: the same kernel, its panes baked at another d_c)."""
