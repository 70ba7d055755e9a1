"""The Dr.Jit point–triangle distance used by the mesh → grid band, against independent computations."""

import numpy as np

from rtfit.realtime.sdf_grid import _point_triangle_distance_drjit, point_triangle_distance


def _segment_distance(p, a, b):
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * e, axis=1)


def test_generic_triangles_match_voronoi_region_form():
    rng = np.random.default_rng(3)
    p, a, b, c = (rng.normal(size=(50_000, 3)) for _ in range(4))
    q1, d1 = point_triangle_distance(p, a, b, c)  # Ericson's region tests (NumPy)
    q2, d2 = _point_triangle_distance_drjit(p, a, b, c)
    assert np.max(np.abs(d1 - d2)) < 1e-12
    assert np.max(np.abs(q1 - q2)) < 1e-9


def test_degenerate_triangles_are_their_edges():
    """Collinear, needle and point triangles: the distance is the nearest edge's (segment) distance."""
    rng = np.random.default_rng(4)
    n = 3000
    p, a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    c = a + rng.uniform(-0.5, 1.5, size=(n, 1)) * (b - a)  # collinear (rounded: nearly degenerate)
    c[:500] += 1e-9 * rng.normal(size=(500, 3))  # needles
    b[2500:], c[2500:] = a[2500:], a[2500:]  # points
    want = np.minimum(
        np.minimum(_segment_distance(p, a, b), _segment_distance(p, b, c)), _segment_distance(p, c, a)
    )
    _, got = _point_triangle_distance_drjit(p, a, b, c)
    assert np.max(np.abs(got - want)) < 1e-9


def test_against_dense_sampling_of_the_triangle():
    rng = np.random.default_rng(5)
    u, v = np.meshgrid(np.linspace(0, 1, 601), np.linspace(0, 1, 601))
    keep = u + v <= 1.0
    u, v = u[keep], v[keep]
    for _ in range(5):
        a, b, c = rng.normal(size=(3, 3))
        pts = a + u[:, None] * (b - a) + v[:, None] * (c - a)
        p = rng.normal(size=(20, 3)) * 2.0
        brute = np.min(np.linalg.norm(p[:, None, :] - pts[None], axis=2), axis=1)
        _, d = _point_triangle_distance_drjit(p, *[np.tile(x, (20, 1)) for x in (a, b, c)])
        spacing = max(np.linalg.norm(b - a), np.linalg.norm(c - a)) / 600
        assert np.all(d <= brute + 1e-12) and np.all(brute - d <= spacing)


def test_band_pairs_are_each_triangles_box_of_cells_with_numpys_distances():
    """`_BandTriangles.pairs` (the band's enumeration and gathers in one kernel): for random triangles and
    boxes of cells, the voxel index, cell centre distance and closest point of every pair equal those of the
    pairs enumerated in NumPy (x fastest in each triangle's box) and measured by Ericson's region tests; a
    last packet of odd length (lanes past the end) traps no division by zero."""
    from rtfit.realtime.sdf_grid import _BandTriangles

    rng = np.random.default_rng(6)
    shape, o, h = (9, 7, 5), np.array([-1.0, 0.5, 2.0]), 0.25
    tri = rng.normal(size=(13, 3, 3))
    lo = np.stack([rng.integers(0, s, 13) for s in shape], axis=1)
    ext = np.stack([rng.integers(1, s - lo[:, k] + 1) for k, s in enumerate(shape)], axis=1)
    cnt = ext.prod(axis=1)
    t_id = np.repeat(np.arange(13), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    e = ext[t_id]
    ijk = np.stack([local % e[:, 0], (local // e[:, 0]) % e[:, 1], local // (e[:, 0] * e[:, 1])], axis=1)
    ijk += lo[t_id]
    vox, cp, d = _BandTriangles(tri, lo, ext).pairs(t_id, local, o, h, shape)
    assert t_id.size % 16 and np.array_equal(vox, (ijk[:, 2] * shape[1] + ijk[:, 1]) * shape[0] + ijk[:, 0])
    q, want = point_triangle_distance(o + (ijk + 0.5) * h, tri[t_id, 0], tri[t_id, 1], tri[t_id, 2])
    assert np.max(np.abs(d - want)) < 1e-12 and np.max(np.abs(cp - q)) < 1e-9
