"""A pass's moments stay on the device (`rtfit.reference.estimators.PassMoments`, issue 21 §3): checked
against NumPy's own float64 mean and two-pass variance of the same per-lane samples (read back lane by
lane, reduced by NumPy), with passes split into several chunks, and the pass's launches counted in Dr.Jit's
kernel history (one cached sampling kernel per chunk, nothing traced anew)."""

from contextlib import contextmanager

import drjit as dr
import numpy as np
import pytest

from rtfit.reference import estimators, load_mitsuba_scene, radiance_pass
from rtfit.reference.estimators import PassMoments, mean_var, sub_seed

from .conftest import sphere_scene

RES, SPP, CHUNK_LANES = 24, 12, 1 << 11  # 576 pixels × 12 spp in 4 chunks of ≤ 2048 lanes


@pytest.fixture(scope="module", params=PassMoments.REDUCTIONS)
def scene_pass(request):
    """A sphere pass rendered in 4 chunks (`MAX_LANES` lowered) with each `PassMoments` reduction (the CPU's
    ``atomic``, the GPU's ``stored``), and NumPy's statistics of the same lanes."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    _, ms = load_mitsuba_scene(sphere_scene(alpha_deg=10.0, res=RES))
    with _chunked(request.param):
        r = radiance_pass(mi, ms, SPP, seed=5)
    return mi, ms, r, _numpy_statistics(mi, ms, seed=5), request.param


@contextmanager
def _chunked(reduction: str):
    """Passes in chunks of `CHUNK_LANES` lanes whose moments use ``reduction``."""
    mp = pytest.MonkeyPatch()
    mp.setattr(estimators, "MAX_LANES", CHUNK_LANES)
    mp.setattr(estimators, "default_reduction", lambda mi: reduction)
    try:
        yield
    finally:
        mp.undo()


def _numpy_statistics(mi, ms, seed: int):
    """Mean and unbiased variance (NumPy's ``mean`` and two-pass ``var(ddof=1)`` in float64) of the same
    samples `radiance_pass` draws: the same chunks, sampler seeds and pixel-centre rays, every lane's
    value read back to the host."""
    sensor = ms.sensors()[0]
    width, height = sensor.film().crop_size()
    integrator = ms.integrator()
    sampler = mi.load_dict({"type": "independent"})
    per = CHUNK_LANES // SPP
    lanes = []
    for k, a in enumerate(range(0, width * height, per)):
        b = min(width * height, a + per)
        sampler.seed(sub_seed(seed, "chunk", k), (b - a) * SPP)
        pix = dr.arange(mi.UInt32, (b - a) * SPP) // SPP + a
        uv = mi.Point2f((mi.Float(pix % width) + 0.5) / width, (mi.Float(pix // width) + 0.5) / height)
        ray, weight = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5, 0.5))
        value, _, _ = integrator.sample(ms, sampler, ray, None, True)
        lanes.append(np.asarray(value * weight, dtype=np.float64).reshape(3, b - a, SPP))
    v = np.concatenate(lanes, axis=1)  # (3, pixels, spp)
    return v.mean(axis=2).T.reshape(height, width, 3), v.var(axis=2, ddof=1).T.reshape(height, width, 3)


def test_chunked_pass_matches_numpy_statistics_of_the_same_samples(scene_pass):
    _, _, r, (mean, var), _ = scene_pass
    assert r.mean.shape == r.var.shape == (RES, RES, 3) and r.mean.dtype == np.float64
    assert np.all(np.isfinite(r.mean)) and np.all(r.var >= 0)
    lit = mean > 0
    assert lit.sum() > 100  # the test sees the lit sphere, not only background
    # Σv/n against NumPy's pairwise mean: float32 samples, float64 sums of 12: measured max 0 (bit-identical)
    assert np.max(np.abs(r.mean - mean)) <= 1e-15 * np.max(np.abs(mean))
    # one-pass (Σv² − Σv·mean)/(n−1) against NumPy's two-pass variance: measured max 9.5e-17 (0.43 ulp) of
    # the pass's largest E[v²]; the bound is 4 ulp of E[v²] (the one-pass form's cancellation)
    scale = np.max(mean**2 + var)
    assert np.max(np.abs(r.var - var)) <= 4 * np.finfo(np.float64).eps * scale


def test_every_chunk_is_the_same_cached_kernel(scene_pass):
    """Per chunk only the sampling kernel (a cache hit: the chunk's offset and seed are opaque), whose
    atomics sum straight into the pass's arrays (``atomic``), or that kernel storing its samples and the
    reduction kernel of `PassMoments.WARP` lanes per pixel summing them into the pass's arrays (``stored``);
    per pass one kernel packing the mean and variance (one array, one copy), and no block reductions or
    per-thread copies of the sums to clear (CPU)."""
    mi, ms, _, _, reduction = scene_pass
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        with _chunked(reduction):
            dr.kernel_history()  # clear
            radiance_pass(mi, ms, SPP, seed=6)  # other seeds, other chunk offsets than the fixture's pass
            history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    jit = [h for h in history if h["type"] == dr.KernelType.JIT]
    per = CHUNK_LANES // SPP
    chunks = -(-RES * RES // per)
    sizes = [h["size"] for h in jit]
    # per chunk: sampling (+ the reduction); per pass: the mean and variance of every pixel and channel
    if reduction == "atomic":
        assert chunks == 4 and sizes == [per * SPP] * 3 + [(RES * RES - 3 * per) * SPP, 2 * RES * RES * 3]
    else:  # SPP = 12 < WARP: 12 lanes per pixel, each summing one sample
        group = min(PassMoments.WARP, SPP)
        chunk = [(n * SPP, n * group) for n in (per, per, per, RES * RES - 3 * per)]
        assert sizes == [x for pair in chunk for x in pair] + [2 * RES * RES * 3], sizes
    assert all(h.get("cache_hit") for h in jit)  # nothing traced into a new kernel: no literal per chunk
    assert not [h for h in history if h["type"] == dr.KernelType.BlockReduce]
    big_memsets = [h for h in history if h["type"] == dr.KernelType.Memset and h["size"] > RES * RES]
    assert len(big_memsets) == 2, [h["size"] for h in big_memsets]  # Σv and Σv², cleared once per pass


@pytest.mark.parametrize("reduction", PassMoments.REDUCTIONS)
def test_pass_moments_of_known_values(mi, reduction):
    """Chunks added out of order at their offsets, 9 channels, spp = 3 (division by 3 is not exact: the
    divisor must stay a division): sums and statistics equal NumPy's of the same float32 values."""
    rng = np.random.default_rng(1)
    n, c, spp = 50, 9, 3
    vals = rng.lognormal(0.0, 2.0, size=(n, spp, c)).astype(np.float32)
    acc = PassMoments(mi, n, c, spp, reduction)
    for a, b in ((30, 50), (0, 7), (7, 30)):
        acc.add(a, [mi.Float(vals[a:b, :, k].ravel()) for k in range(c)])
    s, q = acc.sums()
    v = vals.astype(np.float64)
    # sums of 3 float64 values (squares of float32 are exact in float64): at most 1 rounding apart
    # (measured: Σv bit-identical, Σv² 2.2e-16 relative)
    np.testing.assert_allclose(s, v.sum(axis=1), rtol=2.3e-16, atol=0)
    np.testing.assert_allclose(q, (v * v).sum(axis=1), rtol=2.3e-16, atol=0)
    mean, var = acc.result()
    # the device's mean and variance are NumPy's `mean_var` of the same sums, bit for bit on the CPU
    m_np, v_np = mean_var(s, q, spp)
    np.testing.assert_array_equal(mean, m_np)
    np.testing.assert_array_equal(var, v_np)
    # and within 1e-12 of NumPy's two-pass variance (measured 2.4e-14: the one-pass form's cancellation)
    np.testing.assert_allclose(var, v.var(axis=1, ddof=1), rtol=1e-12, atol=0)
    # read back in float32 (what the EXR pass cache stores): NumPy's rounding of the float64 results
    mean32, var32 = acc.result(np.float32)
    assert mean32.dtype == var32.dtype == np.float32
    np.testing.assert_array_equal(mean32, mean.astype(np.float32))
    np.testing.assert_array_equal(var32, var.astype(np.float32))
    with pytest.raises(ValueError, match="overruns"):
        acc.add(45, [mi.Float(vals[:10, :, k].ravel()) for k in range(c)])


@pytest.mark.parametrize("spp", [31, 32, 33, 70, 200])
def test_stored_reduction_of_many_samples_per_element(mi, spp):
    """The ``stored`` reduction with more samples than `PassMoments.WARP` lanes per element (each lane sums
    samples t, t + 32, …; spp not a multiple of 32 leaves some lanes one sample short): Σv and Σv² of each
    element within Higham's bound (spp − 1)·u·Σ|v| of NumPy's float64 sums of the same float32 values, as the
    ``atomic`` reduction's are. Measured largest relative difference: Σv 0, Σv² 1.4e-15 at spp = 200 (bound
    2.2e-14 there; 5.6e-16 against 3.3e-15 at spp = 31)."""
    rng = np.random.default_rng(spp)
    n, c = 37, 2
    vals = rng.lognormal(0.0, 2.0, size=(n, spp, c)).astype(np.float32)
    v = vals.astype(np.float64)
    bound = (spp - 1) * np.finfo(np.float64).eps / 2
    for reduction in PassMoments.REDUCTIONS:
        acc = PassMoments(mi, n, c, spp, reduction)
        for a, b in ((20, n), (0, 20)):
            acc.add(a, [mi.Float(vals[a:b, :, k].ravel()) for k in range(c)])
        s, q = acc.sums()
        np.testing.assert_allclose(s, v.sum(axis=1), rtol=bound, atol=0)
        np.testing.assert_allclose(q, (v * v).sum(axis=1), rtol=bound, atol=0)


def test_pass_moments_refuses_an_unknown_reduction(mi):
    with pytest.raises(ValueError, match="reduction must be one of"):
        PassMoments(mi, 4, 1, 2, "warp")


def test_irradiance_pass_on_resident_probes_is_the_same_pass(scene_pass):
    """`irradiance_pass` at `DeviceProbes` (uploaded once, as the reference cache does for a reference's
    passes) and at the same host arrays: the same samples, so bit-identical means and variances."""
    from rtfit.reference.estimators import device_probes, irradiance_pass

    mi, ms, _, _, _ = scene_pass
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    points = 2.0 * normals  # outside the unit sphere, facing away from it
    host = irradiance_pass(mi, ms, points, normals, 8, seed=4)
    resident = irradiance_pass(mi, ms, device_probes(mi, points, normals, normalise=False), None, 8, seed=4)
    assert np.any(host.mean > 0)  # some probes face the light
    np.testing.assert_array_equal(resident.mean, host.mean)
    np.testing.assert_array_equal(resident.var, host.var)
