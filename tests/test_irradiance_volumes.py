"""Irradiance volumes (`rtfit.realtime.irradiance_volumes`): lookups against independent computations.

Oracles: a field linear in position (trilinear interpolation reproduces it exactly, clamped outside the
grid); the nearest node computed by rounding; a grid of identical probes evaluated through
`irradiance_bases.basis_irradiance` (the single-probe path); Ramamoorthi & Hanrahan's closed form of the L2
irradiance of a directional light for the folded light. Pure NumPy/Dr.Jit, no rendering (the experiment's
self-checks cover the Mitsuba side).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS, jax_ops
from rtfit.realtime.irradiance_bases import CUBE_AXES, basis_irradiance
from rtfit.realtime.irradiance_volumes import (
    METHODS,
    ProbeGrid,
    fold_point_light,
    probe_table,
    volume_inputs,
    volume_irradiance,
    volume_weights,
)

GRID = ProbeGrid((-1.0, 0.5, 0.25), 0.5, (4, 3, 5))
HI = np.asarray(GRID.origin) + GRID.spacing * (np.asarray(GRID.dims) - 1)


def numpy_run(mid, grid, table, points, normals):
    """The kernel text on NumPy float64 (no Dr.Jit)."""
    with np.errstate(all="ignore"):
        out = METHODS[mid](NUMPY_OPS, volume_inputs(mid, grid, table, points, normals))
    return np.stack(out, axis=-1)


def linear_cube_table(grid, a, b):
    """Every cube entry = a + b·x at the node: the cube then returns a + b·x at every normal."""
    f = a + grid.positions() @ np.asarray(b)
    return probe_table(np.repeat(f[:, None, None], 6, axis=1) * np.ones((1, 1, 3)))


def test_trilinear_is_exact_for_a_linear_field_and_clamps_outside():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-2.5, 3.5, (2000, 3))
    nrm = rng.normal(size=(2000, 3))
    b = (0.3, -0.7, 0.45)
    table = linear_cube_table(GRID, 2.0, b)
    expect = 2.0 + np.clip(pts, GRID.origin, HI) @ np.asarray(b)
    for mid in ("trilinear-cube-valve", "trilinear-cube-nnls"):
        got = numpy_run(mid, GRID, table, pts, nrm)
        # measured max 3.6e-15 (float64 round-off of the weights)
        assert np.max(np.abs(got - expect[:, None])) < 1e-12
    got32 = volume_irradiance(
        "trilinear-cube-valve", GRID, table, pts.astype(np.float32), nrm.astype(np.float32)
    )
    assert np.max(np.abs(got32 - expect[:, None]) / np.abs(expect).max()) < 2e-6  # float32: measured 4.1e-7


def test_nearest_returns_the_rounded_node_near_cell_centres():
    rng = np.random.default_rng(2)
    idx = rng.integers(0, GRID.dims, (500, 3))
    jitter = rng.uniform(-0.49, 0.49, (500, 3)) * GRID.spacing
    pts = np.asarray(GRID.origin) + GRID.spacing * idx + jitter
    values = rng.uniform(0.5, 2.0, GRID.count)
    table = probe_table(np.repeat(values[:, None, None], 6, axis=1) * np.ones((1, 1, 3)))
    node = (idx[:, 2] * GRID.dims[1] + idx[:, 1]) * GRID.dims[0] + idx[:, 0]
    got = numpy_run("nearest-cube-valve", GRID, table, pts, rng.normal(size=(500, 3)))
    # one node, weight 1; n_x² + n_y² + n_z² of the normalised normal is 1 to round-off (measured 2.2e-16)
    assert np.max(np.abs(got[:, 0] - values[node])) < 1e-14
    at_nodes = numpy_run(
        "nearest-cube-valve", GRID, table, GRID.positions(), np.tile([0.0, 0.0, 1.0], (GRID.count, 1))
    )
    assert np.max(np.abs(at_nodes[:, 0] - values)) < 1e-14


@pytest.mark.parametrize("mid", list(METHODS))
def test_identical_probes_give_the_probe_everywhere(mid):
    rng = np.random.default_rng(3)
    basis = METHODS[mid].fixed["basis"].id
    rows = 9 if basis == "sh-l2" else 6
    probe = rng.uniform(0.1, 1.0, (rows, 3))
    table = probe_table(np.repeat(probe[None], GRID.count, axis=0))
    pts = rng.uniform(-3.0, 4.0, (300, 3))
    nrm = rng.normal(size=(300, 3))
    expect = basis_irradiance(basis, probe, nrm)  # the single-probe path of irradiance_bases
    got = numpy_run(mid, GRID, table, pts, nrm)
    assert np.max(np.abs(got - expect)) < 1e-12  # measured 8.9e-16
    if mid == "nearest-sh-l2":  # the Dr.Jit run (one small kernel build: 27 gathers)
        got_dr = volume_irradiance(mid, GRID, table, pts, nrm)
        assert np.max(np.abs(got_dr - expect)) < 1e-12  # float64 Dr.Jit run: measured 8.9e-16


def test_jax_run_matches_numpy():
    import jax.numpy as jnp

    rng = np.random.default_rng(4)
    table = probe_table(rng.uniform(0.0, 1.0, (GRID.count, 9, 3)))
    pts = rng.uniform(-1.5, 2.0, (64, 3))
    nrm = rng.normal(size=(64, 3))
    inputs = volume_inputs("nearest-sh-l2", GRID, table, pts, nrm)
    jin = {k: (jnp.asarray(v) if isinstance(v, np.ndarray) else v) for k, v in inputs.items()}
    got = np.stack([np.asarray(v) for v in METHODS["nearest-sh-l2"](jax_ops(), jin)], axis=-1)
    ref = numpy_run("nearest-sh-l2", GRID, table, pts, nrm)
    assert np.max(np.abs(got - ref)) < 1e-5 * np.abs(ref).max()  # JAX float32 default: measured 2e-7


def test_folded_point_light_matches_the_closed_form():
    """SH L2 of a directional light of irradiance E⊥ along d: E(n) = E⊥ (1/4 + cos θ/2 + (5/16)(3cos²θ − 1)/2)
    (Ramamoorthi & Hanrahan 2001); Valve's cube holds E⊥ max(a·d, 0) at its axes."""
    probe = np.array([[0.2, -0.3, 0.9]])
    light = (1.0, 0.5, 2.0)
    d, e_perp, sh, cube = fold_point_light(probe, light, (2.0, 3.0, 4.0))
    delta = np.asarray(light) - probe[0]
    r2 = float(delta @ delta)
    assert np.allclose(e_perp[0], np.array([2.0, 3.0, 4.0]) / r2, rtol=1e-14)
    n = np.random.default_rng(5).normal(size=(200, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = n @ d[0]
    expect = (0.25 + c / 2 + (5 / 16) * (3 * c * c - 1) / 2)[:, None] * e_perp[0][None]
    assert np.max(np.abs(basis_irradiance("sh-l2", sh[0], n) - expect)) < 1e-12  # measured 2.2e-16
    axes = np.asarray(CUBE_AXES)
    assert np.allclose(cube[0], np.maximum(axes @ d[0], 0.0)[:, None] * e_perp[0][None], rtol=1e-14)
    _, hidden, sh0, _ = fold_point_light(probe, light, 1.0, visible=[0.0])
    assert not hidden.any() and not sh0.any()
    with pytest.raises(ValueError, match="light's position"):
        fold_point_light(np.array([light]), light, 1.0)


def test_subgrid_nodes_are_fine_grid_nodes():
    fine = ProbeGrid((-1.5, -1.5, 0.25), 0.375, (9, 9, 5))
    for step in (1, 2, 4):
        coarse, index = fine.subgrid(step)
        assert coarse.spacing == 0.375 * step
        assert np.allclose(fine.positions()[index], coarse.positions(), atol=0.0)
    with pytest.raises(ValueError, match="does not divide"):
        fine.subgrid(3)


def test_bad_input_is_one_clear_error():
    table = probe_table(np.ones((GRID.count, 6, 3)))
    with pytest.raises(ValueError, match="18 floats per probe"):
        volume_irradiance("nearest-cube-valve", GRID, table[:-1], np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="points must be finite"):
        volume_irradiance("nearest-cube-valve", GRID, table, np.array([[np.nan, 0, 0]]), np.ones((1, 3)))
    with pytest.raises(ValueError, match="unknown volume method"):
        volume_irradiance("bilinear-cube", GRID, table, np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="spacing"):
        ProbeGrid((0, 0, 0), 0.0, (2, 2, 2))
    with pytest.raises(ValueError, match="dims"):
        ProbeGrid((0, 0, 0), 1.0, (0, 2, 2))


def _coordinate(axis: int):
    """Floats along one axis: anywhere (far outside included), exactly on nodes and on cell boundaries."""
    o, h, n = GRID.origin[axis], GRID.spacing, GRID.dims[axis]
    nodes = st.integers(-2, n + 1).map(lambda i: o + h * i)
    bounds = st.integers(-2, n + 1).map(lambda i: o + h * (i + 0.5))
    return st.one_of(st.floats(-1e6, 1e6, allow_nan=False), nodes, bounds)


@settings(max_examples=50, deadline=None)
@given(x=_coordinate(0), y=_coordinate(1), z=_coordinate(2))
def test_lookups_are_finite_and_weights_form_a_partition_of_unity(x, y, z):
    pts = np.array([[x, y, z]])
    table = probe_table(np.linspace(0.1, 2.0, GRID.count * 27).reshape(GRID.count, 9, 3))
    for lookup in ("nearest", "trilinear"):
        idx, w = volume_weights(lookup, GRID, pts)
        assert np.all((w >= 0) & (w <= 1)) and math.isclose(float(w.sum()), 1.0, abs_tol=1e-12)
        assert np.all((idx >= 0) & (idx < GRID.count))
        e = numpy_run(f"{lookup}-sh-l2", GRID, table, pts, np.array([[0.3, -0.4, 0.5]]))
        assert np.all(np.isfinite(e))
    # nearest: a node closest to the clamped point (on a boundary either neighbour is closest)
    idx, _ = volume_weights("nearest", GRID, pts)
    clamped = np.clip(pts[0], GRID.origin, HI)
    dist = np.abs(GRID.positions() - clamped).max(axis=1)
    assert dist[idx[0, 0]] <= dist.min() + 1e-9 * max(1.0, abs(x) + abs(y) + abs(z))


# ------------------------------------------------------------------------------- the probes' reference
@pytest.fixture(scope="module")
def furnace_projections():
    """Two probes in a constant environment of radiance 1 (no geometry), 512 directions each."""
    from rtfit.reference import load_mitsuba_scene
    from rtfit.reference.probe_radiance import probe_radiance_pass
    from rtfit.scenes.model import Camera, ConstantEnv, ReferenceSettings, Scene

    scene = Scene(
        name="furnace",
        camera=Camera(origin=(0.0, -3.0, 0.0), target=(0.0, 0.0, 0.0), width=8, height=8),
        lights=(ConstantEnv(radiance=(1.0, 1.0, 1.0)),),
        reference=ReferenceSettings(transport="direct"),
    )
    mi, ms = load_mitsuba_scene(scene, "llvm_ad_rgb")
    normals = np.asarray(CUBE_AXES)

    def features(d):
        return np.concatenate([np.ones((len(d), 1)), np.maximum(d @ normals.T, 0.0)], axis=1)

    return probe_radiance_pass(mi, ms, np.array([[0.0, 0.0, 0.0], [1.0, 2.0, -3.0]]), features, 512, 7)


def test_probe_projections_match_the_furnace_closed_forms(furnace_projections):
    """∫ 1 dω = 4π exactly (every sample is 4π); ∫ max(n·ω, 0) dω = π within the pass's own noise."""
    r = furnace_projections
    assert r.mean.shape == (2, 7, 3)
    assert np.max(np.abs(r.mean[:, 0] - 4 * np.pi)) < 1e-9  # float64 sums of 4π·1: measured 1.3e-13
    se = np.sqrt(r.var[:, 1:] / r.spp)
    z = np.abs(r.mean[:, 1:] - np.pi) / se
    # 12 distinct values (the 3 channels are equal): Šidák bound at α = 0.01 is 3.3; measured 1.79
    assert np.all(se > 0) and z.max() < 3.3
