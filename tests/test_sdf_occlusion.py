"""Evans skylight, curvature term and cone-traced occlusion: closed forms, extremes, properties.

Independent values: the SDF of a plane is the height (so Evans' samples and the cone march have closed
forms), and the seed's text convention is S_text = −s.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rtfit.fitting import fit_method
from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.sdf_grid import HalfSpace, Sphere, seed_text_sdf, union_grid
from rtfit.realtime.sdf_occlusion import (
    CURVATURE_LEVEL,
    EVANS_SAMPLES,
    LISTING_WEIGHTS,
    METHODS,
    AnalyticSDF,
    EvansParams,
    GridSDF,
    cone_kernel,
    cone_occlusion,
    curvature_term,
    evans_occlusion,
    evans_sample_positions,
    evans_terms,
)

PLANE = AnalyticSDF([HalfSpace((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))])
UP = np.array([[0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def plane_grid():
    g = union_grid(PLANE.prims, (-1.6, -1.6, -0.8), 0.1, (32, 32, 32))
    return GridSDF.from_grid(g, levels=1)


@pytest.mark.parametrize("h", [0.0, 0.05, 0.3])
def test_plane_samples_are_minus_h_plus_d_in_seed_convention(h, plane_grid):
    prm = EvansParams(n=5, base=0.1, k=1.0, alpha=0.0)
    pos = evans_sample_positions((0.2, -0.1, h), (0, 0, 1), prm)
    d = np.array(prm.distances())
    s = np.array([PLANE.prims[0].normal[2] * p[2] for p in pos])  # plane SDF = height
    np.testing.assert_allclose(seed_text_sdf(s), -(h + d), atol=1e-15)  # 000:2919-2921: SDF(P + dN) = −d
    # the voxel grid (a linear field is sampled exactly by trilinear interpolation, level 0, inside the grid)
    got = plane_grid.sample(NUMPY_OPS, 0, pos[:, 0], pos[:, 1], pos[:, 2])
    np.testing.assert_allclose(seed_text_sdf(got), -(h + d), atol=1e-6)


@pytest.mark.parametrize("backend", ["numpy", None])
def test_unoccluded_gives_one(backend, plane_grid):
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    for sdf in (PLANE, plane_grid):
        c = evans_occlusion(
            pts, nrm, sdf, EvansParams(n=4, base=0.1, k=7.0, alpha=0.0, prefilter=False), backend=backend
        )
        np.testing.assert_allclose(c, 1.0, atol=1e-6)
        c = evans_occlusion(
            pts,
            nrm,
            sdf,
            EvansParams(n=4, base=0.1, k=7.0, alpha=0.5, normalize=True, prefilter=False),
            backend=backend,
        )
        np.testing.assert_allclose(c, 1.0, atol=1e-6)


def test_empty_scene_is_exactly_one():
    pts = np.random.default_rng(0).normal(size=(64, 3))
    nrm = np.random.default_rng(1).normal(size=(64, 3))
    for be in ("numpy", None):
        c = evans_occlusion(
            pts,
            nrm,
            AnalyticSDF([]),
            EvansParams(n=6, base=0.05, k=100.0, alpha=0.7, normalize=True),
            backend=be,
        )
        assert np.all(c == 1.0)
        assert np.all(
            np.asarray(cone_occlusion(pts, nrm, AnalyticSDF([]), t0=0.01, t_max=1.0, backend=be)) == 1.0
        )


def test_ceiling_closed_form():
    # floor point facing up under a ceiling at height H (slab above): s(P + dN) = min(d, H − d) for the
    # two half-spaces, so D = Σ_i max(0, 2 d_i − H) (α = 0, w = 1, no blur).
    H = 0.5
    sdf = AnalyticSDF([HalfSpace((0, 0, 0), (0, 0, 1)), HalfSpace((0, 0, H), (0, 0, -1))])
    prm = EvansParams(n=5, base=0.05, k=3.0, alpha=0.0)
    d = np.array(prm.distances())
    expect = math.exp(-3.0 * np.sum(np.maximum(0.0, 2 * d - H)))
    for be in ("numpy", None):
        c = evans_occlusion(np.zeros((1, 3)), UP, sdf, prm, backend=be)
        assert c[0] == pytest.approx(expect, rel=1e-5)
    terms = evans_terms(np.zeros((1, 3)), UP, sdf, prm, backend="numpy")[:, 0]
    np.testing.assert_allclose(terms, np.maximum(0.0, 2 * d - H), atol=1e-12)


def test_listing_weights_and_brightness():
    sdf = AnalyticSDF([HalfSpace((0, 0, 0), (0, 0, 1)), Sphere((0, 0, 0.35), 0.15)])
    p = np.array([[0.3, 0.0, 0.0]])
    prm = EvansParams(n=4, base=0.03, k=2.0, alpha=1.0, weights=LISTING_WEIGHTS, brightness=0.7, clamp=False)
    pos = evans_sample_positions(p[0], UP[0], prm)
    s = np.array([min(q[2], np.linalg.norm(q - [0, 0, 0.35]) - 0.15) for q in pos])
    expect = 0.7 * math.exp(-2.0 * np.dot(LISTING_WEIGHTS, np.array(prm.distances()) - s))
    assert evans_occlusion(p, UP, sdf, prm, backend="numpy")[0] == pytest.approx(expect, rel=1e-12)


def test_extremes_are_finite():
    sdf = AnalyticSDF([Sphere((0, 0, 0), 1.0)])
    pts = np.array([[0, 0, 1.0], [0, 0, 0.0], [0, 0, 50.0], [0, 0, 1.0]])  # surface, inside, far, N = −U
    nrm = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, -1.0]])
    for k in (0.0, 1e-8, 1e6, 1e30):
        for be in ("numpy", None):
            c = np.asarray(
                evans_occlusion(pts, nrm, sdf, EvansParams(n=8, base=0.01, k=k, alpha=1.0), backend=be)
            )
            assert np.all(np.isfinite(c)) and np.all(c >= 0) and np.all(c <= math.exp(80) * 1.0001)
            if k == 0.0:
                assert np.all(c == 1.0)
    # zero-length normal: no direction to test → C = B
    c = evans_occlusion(np.zeros((1, 3)), np.zeros((1, 3)), sdf, EvansParams(brightness=0.5), backend="numpy")
    assert c[0] == 0.5


def test_outside_the_grid_is_finite():
    g = GridSDF.from_grid(union_grid([Sphere((0, 0, 0), 0.5)], (-1, -1, -1), 0.1, (20, 20, 20)), levels=3)
    pts = np.array([[5.0, 0, 0], [0, 0, 0.5], [0.99, 0.99, 0.99], [-30, 2, 1]])
    nrm = np.array([[1.0, 0, 0], [0, 0, 1], [1, 1, 1], [0, 1, 0]])
    for be in ("numpy", None):
        c = np.asarray(evans_occlusion(pts, nrm, g, EvansParams(n=6, base=0.1, k=5.0, alpha=0.0), backend=be))
        assert np.all(np.isfinite(c))
        assert c[0] == pytest.approx(1.0, abs=1e-6)  # far outside, facing away: unoccluded


def test_cone_on_a_plane_closed_form():
    # s(P + tω) = t ω_z on a plane: each cone's visibility is min(1, k cos θ_j), cos θ_j = √(1 − (j+½)/M).
    M, k = 9, 1.7
    expect = np.mean([min(1.0, k * math.sqrt(1 - (j + 0.5) / M)) for j in range(M)])
    for be in ("numpy", None):
        c = cone_occlusion(np.zeros((1, 3)), UP, PLANE, cones=M, steps=6, t0=0.01, t_max=1.0, k=k, backend=be)
        assert c[0] == pytest.approx(expect, rel=1e-5)


def test_curvature_flat_is_one_and_a_half():
    c = curvature_term(np.array([[0.1, 0.2, 0.0]]), PLANE, k=-40.0, backend="numpy")
    assert c[0] == pytest.approx(1.5, abs=1e-12)


def test_drjit_input_stays_lazy_and_matches_numpy():
    Float = dr.llvm.Float
    from drjit.llvm import Array3f

    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (100, 3))
    n = rng.normal(size=(100, 3))
    sdf = AnalyticSDF([Sphere((0, 0, 0), 0.4), HalfSpace((0, 0, -0.5), (0, 0, 1))])
    prm = EvansParams(n=4, base=0.05, k=4.0, alpha=0.5)
    ref = evans_occlusion(p, n, sdf, prm, backend="numpy")
    out = evans_occlusion(Array3f(p.T.astype(np.float32)), Array3f(n.T.astype(np.float32)), sdf, prm)
    assert isinstance(out, Float)
    np.testing.assert_allclose(np.array(out), ref, rtol=2e-4, atol=2e-5)


@pytest.mark.parametrize(
    "bad, msg",
    [
        (dict(n=0), "n"),
        (dict(n=17), "n"),
        (dict(base=0.0), "base"),
        (dict(k=-1.0), "k"),
        (dict(alpha=1.5), "alpha"),
        (dict(weights=(1.0, 2.0)), "weights"),
        (dict(up=(0, 0, 0)), "up"),
    ],
)
def test_bad_parameters(bad, msg):
    with pytest.raises(ValueError, match=msg):
        EvansParams(**bad)


def test_bad_points():
    with pytest.raises(ValueError, match="points"):
        evans_occlusion(np.zeros((4, 2)), np.zeros((4, 3)), PLANE, EvansParams())
    with pytest.raises(ValueError, match="finite"):
        evans_occlusion(np.full((1, 3), np.nan), UP, PLANE, EvansParams())
    with pytest.raises(ValueError, match="t_max"):
        cone_occlusion(np.zeros((1, 3)), UP, PLANE, t0=1.0, t_max=0.5)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    k=st.floats(0.0, 1e6),
    alpha=st.floats(0.0, 1.0),
    base=st.floats(1e-4, 10.0),
    n=st.integers(1, 8),
    h=st.floats(-2.0, 2.0),
    nz=st.floats(-1.0, 1.0),
)
def test_property_normalised_evans_in_unit_interval_and_monotone(k, alpha, base, n, h, nz):
    """With a normalised bent normal and the clamp every term D_i ≥ 0: C ∈ [0, 1] and C falls with k."""
    sdf = AnalyticSDF([HalfSpace((0, 0, 0), (0, 0, 1)), Sphere((0.3, 0, 0.6), 0.25)])
    p = np.array([[0.0, 0.0, h]])
    nrm = np.array([[math.sqrt(max(0.0, 1 - nz * nz)), 0.0, nz]])
    prm = EvansParams(n=n, base=base, k=k, alpha=alpha, normalize=True)
    c = evans_occlusion(p, nrm, sdf, prm, backend="numpy")[0]
    c2 = evans_occlusion(
        p, nrm, sdf, EvansParams(n=n, base=base, k=2 * k + 1, alpha=alpha, normalize=True), backend="numpy"
    )[0]
    assert 0.0 <= c <= 1.0 and math.isfinite(c)
    assert c2 <= c + 1e-12


# ============================================================================ the method table
def _sphere_on_plane_points(m=300, seed=0):
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(0.0, 1.2**2, m))
    ph = rng.uniform(0, 2 * np.pi, m)
    return np.column_stack([r * np.cos(ph), r * np.sin(ph), np.zeros(m)]), np.tile([0.0, 0.0, 1.0], (m, 1))


SPHERE_ON_PLANE = AnalyticSDF([HalfSpace((0.0, 0.0, 0.0), (0.0, 0.0, 1.0)), Sphere((0.0, 0.0, 0.5), 0.5)])


@pytest.mark.parametrize("row", ["evans-text", "evans-listing", "evans-fit"])
def test_evans_rows_run_the_point_kernel_text(row):
    # A row of METHODS on the terms of `evans_terms` at its α and base = `evans_occlusion` with the same
    # parameters (both float64 NumPy; the point kernel multiplies by B where the row adds log B).
    m = METHODS[row]
    values = {
        "evans-text": {"k": 3.0},
        "evans-listing": {"k": 2.5, "logB": math.log(0.8)},
        "evans-fit": {"logB": math.log(0.9), "c1": 4.0, "c2": 3.2, "c3": 2.4, "c4": 2.0, "alpha": 0.35},
    }[row]
    kw = m.keywords(values)
    base = 0.04 * kw["base_voxels"]
    weights = kw["weights"] if "weights" in kw else [kw[f"c{i + 1}"] for i in range(EVANS_SAMPLES)]
    prm = EvansParams(
        n=EVANS_SAMPLES,
        base=base,
        k=kw["k"],
        alpha=kw["alpha"],
        weights=weights,
        brightness=math.exp(kw.get("logB", 0.0)),
    )
    pts, nrm = _sphere_on_plane_points()
    d = evans_terms(pts, nrm, SPHERE_ON_PLANE, prm, backend="numpy")
    got = m(NUMPY_OPS, {"terms": d}, values)
    want = evans_occlusion(pts, nrm, SPHERE_ON_PLANE, prm, backend="numpy")
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert np.ptp(want) > 0.05  # the scene occludes: the comparison is not of constants


def test_evans_text_fit_through_the_kernel_recovers_k():
    # fit_method differentiates the row's kernel text with JAX: k of a noise-free synthetic target comes back.
    m = METHODS["evans-text"]
    pts, nrm = _sphere_on_plane_points(400, seed=1)
    d = evans_terms(pts, nrm, SPHERE_ON_PLANE, EvansParams(n=4, base=0.04, k=1.0, alpha=0.5), backend="numpy")
    y = m(NUMPY_OPS, {"terms": d}, {"k": 7.5})
    fit = fit_method(m, {"terms": d}, y)
    assert fit.values["k"] == pytest.approx(7.5, rel=1e-8)


def test_curvature_row_is_the_curvature_term_over_its_norm(plane_grid):
    pts = np.array([[0.1, 0.2, 0.05], [0.3, -0.2, 0.0], [0.0, 0.0, -0.02]])
    s = plane_grid.sample(NUMPY_OPS, CURVATURE_LEVEL, *pts.T)
    got = METHODS["curvature"](NUMPY_OPS, {"distance": s}, {"k": -4.0})
    want = curvature_term(pts, plane_grid, k=-4.0, level=CURVATURE_LEVEL, backend="numpy") / 1.5
    np.testing.assert_allclose(got, want, rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1e4, 1e4), min_size=4, max_size=4),
    st.sampled_from([0.0, 1e-6, 1.0, 1e4]),
    st.sampled_from([-5.0, 0.0, 5.0]),
    st.floats(-1e4, 1e4),
    st.sampled_from([-1e4, -1.0, 0.0, 1.0, 1e4]),
)
def test_evans_and_curvature_kernels_over_their_whole_domain(terms, k, log_b, distance, k_text):
    """The seed's Evans and curvature formulas do not saturate (000:2946, 000:2982-2987, 000:2902), so the
    kernels are not clamped to [0, 1]; over the whole input domain at the parameters' extreme bounds they
    stay finite and non-negative (the exponent clip [−87, 80]) — and within [0, 1] exactly when the audit's
    bounds hold: Σ D_i ≥ 0 with log B ≤ 0 (C = B·e^(−kD) ≤ 1 by closed form), k·S ≤ 0 for the crease term."""
    ev = METHODS["evans-listing"]
    d = tuple(np.array([t], np.float64) for t in terms)
    c = float(np.asarray(ev.kernel(NUMPY_OPS, d, logB=log_b, k=k, weights=ev.fixed["weights"]))[0])
    assert math.isfinite(c) and c >= 0
    if sum(w * t for w, t in zip(ev.fixed["weights"], terms, strict=True)) >= 0 and log_b <= 0:
        assert c <= 1
    cv = METHODS["curvature"]
    v = float(np.asarray(cv.kernel(NUMPY_OPS, np.array([distance]), k_text, **cv.fixed))[0])
    assert math.isfinite(v) and v >= 0.5 / 1.5 - 1e-12
    if k_text * -distance <= 0:
        assert v <= 1 + 1e-12


def test_cone_numpy_runs_of_several_k_and_moved_points():
    # a fit of k calls the NumPy kernel on the same arrays at every k (its march is memoised): each k, and the
    # point moved in place to height h: s(P + tω) = h + t cos θ_j, v_j = min(1, k(h/t_max + cos θ_j))
    M = 9
    p = np.zeros((1, 3))

    def expect(k, h):
        return np.mean([min(1.0, k * (h / 1.0 + math.sqrt(1 - (j + 0.5) / M))) for j in range(M)])

    for h in (0.0, 0.05):
        p[:, 2] = h
        for k in (0.5, 1.0, 1.7, 0.5):
            c = cone_kernel(NUMPY_OPS, PLANE, M, 6, 0.01, 1.0, k, *p.T, *UP.T)
            assert c[0] == pytest.approx(expect(k, h), rel=1e-9)
