"""SDF sources: analytic primitives, point–triangle distance, mesh → grid, mips, 8-bit storage.

Expected values come from independent computations: brute-force closest points (dense sampling or
clipping), closed forms of the distance to a sphere, box and plane.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.experiments.sdf_occlusion_scenes import box_mesh, icosphere
from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.sdf_grid import (
    Box,
    Capsule,
    HalfSpace,
    SdfGrid,
    Sphere,
    build_mips,
    grid_for_bounds,
    mesh_bounds,
    mesh_sdf_grid,
    point_triangle_distance,
    primitives_sdf,
    quantize_8bit,
    sample_grid_numpy,
    seed_text_sdf,
    union_grid,
)

RNG = np.random.default_rng(12345)


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def test_box_sdf_matches_clipping_closest_point():
    r = _rot((1, 2, 3), 37.0)
    box = Box((0.2, -0.1, 0.3), (0.5, 0.2, 0.3), tuple(map(tuple, r)))
    p = RNG.uniform(-1.5, 1.5, (2000, 3))
    local = (p - np.array(box.center)) @ r  # R^T (p − c) as row vectors
    b = np.array(box.half)
    q = np.clip(local, -b, b)
    inside = np.all(np.abs(local) < b, axis=1)
    expect = np.where(inside, -np.min(b - np.abs(local), axis=1), np.linalg.norm(local - q, axis=1))
    got = primitives_sdf(NUMPY_OPS, [box], p[:, 0], p[:, 1], p[:, 2])
    np.testing.assert_allclose(got, expect, atol=1e-12)


def test_sphere_capsule_halfspace_union():
    prims = [
        Sphere((0, 0, 0.5), 0.3),
        Capsule((-1, 0, 0), (1, 0.5, 0.2), 0.1),
        HalfSpace((0, 0, -1), (0, 0, 2)),
    ]
    p = RNG.uniform(-2, 2, (500, 3))
    t = np.linspace(0, 1, 20001)
    seg = np.array([-1, 0, 0]) + t[:, None] * np.array([2, 0.5, 0.2])
    cap = np.array([np.min(np.linalg.norm(seg - x, axis=1)) for x in p]) - 0.1  # dense segment samples
    sph = np.linalg.norm(p - [0, 0, 0.5], axis=1) - 0.3
    plane = p[:, 2] + 1
    got = primitives_sdf(NUMPY_OPS, prims, p[:, 0], p[:, 1], p[:, 2])
    np.testing.assert_allclose(
        got, np.minimum(np.minimum(sph, cap), plane), atol=2e-4
    )  # segment spacing 1e-4·|b−a|


def test_empty_union_and_seed_sign():
    assert primitives_sdf(NUMPY_OPS, [], 0.0, 0.0, 0.0) >= 1e29
    assert seed_text_sdf(0.25) == -0.25


def test_point_triangle_distance_vs_dense_sampling():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0.2, 0]), np.array([0.3, 0.9, 0.4])
    u, v = np.meshgrid(np.linspace(0, 1, 401), np.linspace(0, 1, 401))
    keep = u + v <= 1
    samples = a + u[keep, None] * (b - a) + v[keep, None] * (c - a)
    p = RNG.uniform(-1, 2, (200, 3))
    _, d = point_triangle_distance(p, np.tile(a, (200, 1)), np.tile(b, (200, 1)), np.tile(c, (200, 1)))
    brute = np.array([np.min(np.linalg.norm(samples - x, axis=1)) for x in p])
    assert np.all(d <= brute + 1e-12)
    assert np.all(brute - d <= 4e-3)  # sample spacing ≈ 1.2/400
    # degenerate (collinear) triangle stays finite and equals the segment distance
    _, d2 = point_triangle_distance(
        np.array([[0.5, 1.0, 0]]), a[None], b[None] * 0 + [[2, 0, 0]], [[1, 0, 0]]
    )
    assert np.isfinite(d2).all() and abs(d2[0] - 1.0) < 1e-12


@pytest.fixture(scope="module")
def sphere_box_grids():
    v1, f1 = icosphere((0.1, -0.05, 0.0), 0.5, 4)
    v2, f2 = box_mesh((0.9, 0.0, 0.1), (0.2, 0.3, 0.25), _rot((0, 0, 1), 20))
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f2 + len(v1)])
    origin, voxel, shape = grid_for_bounds(*mesh_bounds(v), 40, pad_voxels=4)
    prims = [
        Sphere((0.1, -0.05, 0.0), 0.5),
        Box((0.9, 0.0, 0.1), (0.2, 0.3, 0.25), tuple(map(tuple, _rot((0, 0, 1), 20)))),
    ]
    return mesh_sdf_grid(v, f, origin, voxel, shape), union_grid(prims, origin, voxel, shape), (v, f)


def test_mesh_grid_matches_analytic_within_half_voxel(sphere_box_grids):
    g, ga, _ = sphere_box_grids
    err = np.abs(g.values.astype(np.float64) - ga.values)
    assert err.max() <= 0.5 * g.voxel
    # the band is exact: near the surface the error is only the icosphere's chord error
    # (≤ r(1 − cos(edge/2r)))
    near = np.abs(ga.values) < 1.5 * g.voxel
    assert err[near].max() <= 2e-3
    assert g.meta["odd_columns"] == 0


def test_open_mesh_errors_and_flood_fallback(sphere_box_grids):
    _, ga, (v, f) = sphere_box_grids
    g0 = ga
    bv, bf = box_mesh((0, 0, 0), (0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="not watertight"):  # a box without its top face
        mesh_sdf_grid(bv, bf[[0, 1, 4, 5, 6, 7, 8, 9, 10, 11]], (-1, -1, -1), 0.1, (20, 20, 20))
    f_open = f[1:]  # one small triangle of the sphere removed: the flood fill still finds the inside
    g = mesh_sdf_grid(v, f_open, g0.origin, g0.voxel, g0.shape, sign="flood")
    far = np.abs(ga.values) > g0.voxel
    assert np.mean(np.sign(g.values[far]) == np.sign(ga.values[far])) > 0.999
    gu = mesh_sdf_grid(v, f, g0.origin, g0.voxel, g0.shape, sign="unsigned")
    assert gu.values.min() >= 0


@pytest.mark.parametrize(
    "bad, msg",
    [
        (dict(faces=np.array([[0, 1, 99]])), "outside"),
        (dict(vertices=np.full((3, 3), np.nan)), "finite"),
        (dict(sign="maybe"), "sign"),
        (dict(band=0.5), "band"),
    ],
)
def test_mesh_bad_input(bad, msg):
    v, f = box_mesh((0, 0, 0), (1, 1, 1))
    args = dict(vertices=v, faces=f, origin=(-2, -2, -2), voxel=0.5, shape=(8, 8, 8))
    args.update(bad)
    with pytest.raises(ValueError, match=msg):
        mesh_sdf_grid(
            args.pop("vertices"),
            args.pop("faces"),
            args.pop("origin"),
            args.pop("voxel"),
            args.pop("shape"),
            **args,
        )


def test_grid_bounds_and_bad_resolution():
    _, h, sh = grid_for_bounds((0, 0, 0), (2, 1, 1), 32, pad_voxels=2, cubic=True)
    assert sh == (32, 32, 32) and abs(h - 2 / 28) < 1e-12
    with pytest.raises(ValueError, match="resolution"):
        grid_for_bounds((0, 0, 0), (1, 1, 1), 3)
    with pytest.raises(ValueError, match="extent"):
        grid_for_bounds((0, 0, 0), (0, 0, 0), 8)


def test_mips_preserve_a_linear_field_and_double_the_voxel():
    origin, voxel, shape = (0.0, 0.0, 0.0), 0.1, (32, 32, 32)
    g = union_grid([HalfSpace((0, 0, 1.6), (0.3, 0.2, 1.0))], origin, voxel, shape)
    mips = build_mips(g, 4)
    assert [m.voxel for m in mips] == pytest.approx([0.1, 0.2, 0.4, 0.8])
    for m in mips:
        p = m.points()
        inner = (slice(4, -4),) * 3 if m.values.shape[0] > 8 else (slice(1, -1),) * 3
        expect = (
            np.asarray([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]) @ (p - [0, 0, 1.6])[..., None]
        )[..., 0]
        np.testing.assert_allclose(
            m.values[inner], expect[inner], atol=2e-6 if m is g else 1e-5 + 0.02 * (m.voxel > 0.2)
        )


def test_quantize_8bit_error_bound():
    g = union_grid([Sphere((0.8, 0.8, 0.8), 0.4)], (0, 0, 0), 0.05, (32, 32, 32))
    q = quantize_8bit(g)
    assert q.quantized and np.max(np.abs(q.values - g.values)) <= 0.5 * g.voxel + 1e-6
    with pytest.raises(ValueError, match="step_voxels"):
        quantize_8bit(g, 0.0)


def test_sample_outside_grid_adds_distance():
    g = union_grid([HalfSpace((0, 0, 0.5), (0, 0, 1))], (0, 0, 0), 0.1, (10, 10, 10))
    # above the top cell centre (z = 0.95) by 1.0: clamped value 0.45 plus 1.0
    v = sample_grid_numpy(g, np.array([[0.5, 0.5, 1.95]]))
    assert v[0] == pytest.approx(1.45, abs=1e-6)
    with pytest.raises(ValueError, match="finite"):
        SdfGrid(np.full((4, 4, 4), np.inf), (0, 0, 0), 1.0)


def _ply_arrays(path):
    """Header, vertex records (V, 3 or 6) float32 and face records of a `write_ply` file."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode()
    nv = int(head.split("element vertex ")[1].split()[0])
    k = 6 if "property float nx" in head else 3
    verts = np.frombuffer(data, dtype="<f4", count=k * nv, offset=end).reshape(nv, k)
    return head, verts, data[end + 4 * k * nv :]


def test_shipped_meshes_regenerate(tmp_path):
    """The shipped meshes are what `write_library_meshes` makes: header, positions and faces byte for
    byte; the stored vertex normals to float32 round-off. Normals are not compared bit for bit: NumPy's
    SIMD arccos/norm differ by ulps between CPUs (AVX2 vs AVX-512), which moves a component that is 0 in
    exact arithmetic between ±2e-18 and 0 (measured: 33 of 4068 values of sdf_sphere_plane, |Δ| ≤ 1.8e-17).
    Cache keys hash the shipped files, never a regenerated one, so they do not depend on the CPU."""
    from rtfit.experiments.sdf_occlusion_scenes import SCENE_NAMES, write_library_meshes
    from rtfit.scenes.parse import LIBRARY_DIR

    for p in write_library_meshes(tmp_path):
        head, verts, faces = _ply_arrays(p)
        head0, verts0, faces0 = _ply_arrays(LIBRARY_DIR / "meshes" / p.name)
        assert head == head0 and faces == faces0, p.name
        assert np.array_equal(verts[:, :3], verts0[:, :3]), p.name
        np.testing.assert_allclose(verts[:, 3:], verts0[:, 3:], rtol=0, atol=1e-6, err_msg=p.name)
    assert len(SCENE_NAMES) == 8
