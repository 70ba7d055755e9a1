"""rtfit.fitting.hdr_flip against NVIDIA's own ꟻLIP code (flip_evaluator 1.7, float32 C++), on rendered and
synthetic images, and its parts against their definitions.

Tolerance: both are float32 (ours sums each filter pass by BLAS, in another order), so the maps differ by
rounding (≈ 6e-8 relative on CIELAB values up to ~100, i.e. ≈ 6e-6 absolute on a colour difference), which
passes through x^0.7 and x^(1 − feature), whose slopes grow as x → 0. On images that differ by more than
their own rounding the maps agree to ≤ 2.3e-5 a pixel (measured: 4-spp Cornell box 4.0e-6, ×0.7 1.8e-6, a
3-pixel blur 4.4e-6, ×1.0001 2.3e-5). On images one float32 ulp apart either map is rounding noise (means
3.2e-5 and 3.3e-5) and the pixels differ by up to 6.0e-5: `FLIP_CODE_TOL` is 1e-4, above every case."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.fitting import flip_maps as F
from rtfit.fitting import hdr_flip as H

FLIP_CODE_TOL = 1e-4


def _flip_evaluator(r32, t32, params):
    import flip_evaluator

    fmap = flip_evaluator.evaluate(
        r32, t32, "HDR", applyMagma=False, computeMeanError=False, parameters=dict(params)
    )[0]
    return np.asarray(fmap, np.float64).reshape(r32.shape[:2])


@pytest.fixture(scope="module")
def cornell():
    """Mitsuba's Cornell box at 40 × 36 pixels, 64 spp (reference) and 4 spp (a test)."""
    import mitsuba as mi

    from rtfit.reference.variants import use_variant

    use_variant("scalar_rgb")
    scene = mi.load_file("tests/data/mitsuba/cbox/cbox-rgb.xml", res=40)
    ref = np.array(mi.render(scene, spp=64), np.float64)
    low = np.array(mi.render(scene, spp=4, seed=mi.UInt32(3)), np.float64)
    return ref, low


def _cases(ref, low):
    ulp = np.nextafter(ref.astype(np.float32), np.float32(np.inf)).astype(np.float64)
    shifted = (ref + np.roll(ref, 1, 0) + np.roll(ref, 1, 1)) / 3.0
    return {
        "4 spp": low,
        "×0.7": 0.7 * ref,
        "blur": shifted,
        "×1.0001": 1.0001 * ref,
        "1 ulp": ulp,
        "same": ref,
    }


def test_maps_equal_flip_evaluators_on_a_render(cornell):
    ref, low = cornell
    mask = np.ones(ref.shape[:2], bool)
    params = F.flip_exposures(ref, mask)
    peak = float(ref.max())
    r32 = F.flip_input(ref, "", peak, False)
    tests = {k: F.flip_input(t, "", peak, False) for k, t in _cases(ref, low).items()}
    ours = F.flip_maps_shared([(r32, t) for t in tests.values()], params)
    for (name, t32), mine in zip(tests.items(), ours, strict=True):
        theirs = _flip_evaluator(r32, t32, params)
        assert np.max(np.abs(mine - theirs)) <= FLIP_CODE_TOL, name
        assert np.all((mine >= 0) & (mine <= 1)), name
    assert np.all(ours[-1] == 0.0)  # the same image: 0 everywhere, as flip_evaluator
    assert np.mean(ours[0]) > 0.1  # a 4-spp render is far from its reference


@pytest.mark.parametrize("shape", [(21, 21), (33, 70), (130, 67)])
def test_maps_equal_flip_evaluators_at_odd_sizes(shape):
    """Sizes around the filters' block (64 outputs) and at ꟻLIP's least (21: its widest filter)."""
    rng = np.random.default_rng(sum(shape))
    ref = rng.uniform(0.0, 2.0, (*shape, 3)) ** 4
    ref[: shape[0] // 3, : shape[1] // 4] = 30.0  # a light in view: many exposures
    params = F.flip_exposures(ref, np.ones(shape, bool))
    assert params["numExposures"] >= 4
    r32 = F.flip_input(ref, "", float(ref.max()), False)
    t32 = F.flip_input(ref * rng.uniform(0.5, 1.5, ref.shape), "", float(ref.max()), False)
    mine = F.flip_maps_shared([(r32, t32)], params)[0]
    assert np.max(np.abs(mine - _flip_evaluator(r32, t32, params))) <= FLIP_CODE_TOL


def test_filter_axis_is_the_clamped_correlation():
    """`_filter_axis` against the correlation written out with clamped indices, along both axes, for sizes
    below, at and above a block."""
    rng = np.random.default_rng(2)
    filters = rng.normal(size=(2, 7))
    for n in (5, 64, 150):
        a = rng.normal(size=(3, n, n + 3))
        r = 3
        for axis in (-1, -2):
            moved = np.moveaxis(a, axis, -1)
            idx = np.clip(
                np.arange(moved.shape[-1])[:, None] + np.arange(7)[None, :] - r, 0, moved.shape[-1] - 1
            )
            expect = np.einsum("fk,...jk->f...j", filters, moved[..., idx])
            got = np.moveaxis(H._filter_axis(a, filters, axis), axis, -1)
            np.testing.assert_allclose(got, expect, rtol=1e-12, atol=1e-12)


def test_filters_are_normalised_as_flip_defines_them():
    spatial = H._spatial_filters(H.FLIP_PPD)
    assert spatial.shape == (4, F.FLIP_MIN_SIZE)  # radius 10 at 67 ppd
    assert spatial[0].sum() == pytest.approx(1.0, abs=1e-14) and spatial[1].sum() == pytest.approx(
        1.0, abs=1e-14
    )
    assert spatial[2].sum() ** 2 + spatial[3].sum() ** 2 == pytest.approx(1.0, abs=1e-14)  # Cz's 2-D sum
    g, dg, ddg = H._feature_filters(H.FLIP_PPD)
    assert g.size == 2 * math.ceil(3 * 0.5 * 0.082 * H.FLIP_PPD) + 1 == 19
    assert g.sum() == pytest.approx(1.0, abs=1e-14)
    for d in (dg, ddg):
        assert d[d > 0].sum() == pytest.approx(1.0, abs=1e-14) and d[d < 0].sum() == pytest.approx(
            -1.0, abs=1e-14
        )


def test_exposures_follow_flips_float32_steps():
    """2^e for e = start + i·(stop − start)/(n − 1), as ꟻLIP computes them (float32), to its rounding."""
    params = {"startExposure": -2.5066912, "stopExposure": 5.8820877, "numExposures": 9}
    got = H.exposures(params)
    expect = 2.0 ** np.linspace(params["startExposure"], params["stopExposure"], 9)
    np.testing.assert_allclose(got, expect, rtol=1e-6)
    assert got.dtype == np.float64 and got.size == 9


def test_max_colour_distance_is_green_to_blue():
    """c_max: Hunt-adjusted HyAB of pure green and pure blue, ^0.7 (ꟻLIP's `computeMaxDistance`), written
    out here from CIELAB's definition."""

    def lab(rgb):
        xyz = np.array(H._RGB_TO_XYZ) @ np.array(rgb) / np.array([0.950428545, 1.0, 1.088900371])
        f = [t ** (1 / 3) if t > (6 / 29) ** 3 else t / (3 * (6 / 29) ** 2) + 4 / 29 for t in xyz]
        lum = 116 * f[1] - 16
        return lum, 0.01 * lum * 500 * (f[0] - f[1]), 0.01 * lum * 200 * (f[1] - f[2])

    g, b = lab([0, 1, 0]), lab([0, 0, 1])
    hyab = abs(g[0] - b[0]) + math.hypot(g[1] - b[1], g[2] - b[2])
    assert H._CMAX == pytest.approx(hyab**0.7, rel=1e-6)  # (1/1.0889 vs ꟻLIP's 0.918357670: 1e-9 apart)
