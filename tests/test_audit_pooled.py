"""`rtfit.experiments.audit_setup.pooled_passes` and its `PooledPasses`: through the pass cache, the pooled
mean and standard error are those of all the passes' samples concatenated (NumPy over the raw samples, the
oracle), a rerun reads every pass from the cache, and `PooledPasses.reference` lays the masked elements
(RGB columns, or one grey value) onto the image, zero elsewhere."""

from __future__ import annotations

import types
from typing import cast

import numpy as np

from rtfit.experiments.audit_setup import AuditSetup, PooledPasses, cached_pass, pooled_passes
from rtfit.experiments.case_inputs import masked_image
from rtfit.reference.cache import PassEntry
from rtfit.reference.estimators import PassResult


def test_pooled_passes_are_the_concatenated_samples_and_a_rerun_reads_the_cache(tmp_path):
    rng = np.random.default_rng(7)
    setup = types.SimpleNamespace(  # the fields pooled_passes reads
        scene_digest="d",
        variant="scalar_rgb",
        seed=3,
        pass_spp=4,
        spp=10,
        cache_root=tmp_path,
        progress=False,
    )
    drawn = []

    def render(spp: int, seed: int) -> PassResult:
        x = rng.normal(1.0, 0.5, size=(spp, 5, 3))  # spp samples of 5 elements × 3 columns
        drawn.append(x)
        return PassResult(x.mean(axis=0), x.var(axis=0, ddof=1), spp, seed, 0.25)

    p = pooled_passes(cast(AuditSetup, setup), {"quantity": "test"}, render, (-1, 3), "test")
    samples = np.concatenate(drawn)  # passes of 4, 4 and 2 samples
    assert [len(x) for x in drawn] == [4, 4, 2]
    assert (p.spp, p.passes, p.passes_rendered, p.seconds) == (10, 3, 3, 0.75)
    np.testing.assert_allclose(p.mean, samples.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(p.stderr, samples.std(axis=0, ddof=1) / np.sqrt(10), rtol=1e-12)
    again = pooled_passes(cast(AuditSetup, setup), {"quantity": "test"}, render, (-1, 3), "test")
    assert len(drawn) == 3 and again.passes_rendered == 0 and again.entry.key == p.entry.key
    np.testing.assert_array_equal(again.mean, p.mean)
    np.testing.assert_array_equal(again.stderr, p.stderr)


def test_a_cached_pass_is_rendered_once_and_read_back_bit_for_bit(tmp_path):
    """`cached_pass` (a family's input that is itself a render: colour-bleeding's direct light at its rays'
    hits): the first call renders its one pass of the given spp, the second reads it from the cache, the
    same values bit for bit and the render not called; another ``what`` (other points) renders again."""
    rng = np.random.default_rng(11)
    setup = types.SimpleNamespace(scene_digest="d", variant="scalar_rgb", seed=3, pass_spp=4, spp=10,
                                  cache_root=tmp_path, progress=False)  # fmt: skip
    calls = []

    def render() -> PassResult:
        x = rng.normal(1.0, 0.5, size=(12, 7, 3))
        calls.append(1)
        return PassResult(x.mean(axis=0), x.var(axis=0, ddof=1), 12, 5, 0.5)

    what = {"quantity": "hits", "points": "p1", "spp": 12}
    first = cached_pass(cast(AuditSetup, setup), what, render, (-1, 3), "hits", 12)
    again = cached_pass(cast(AuditSetup, setup), what, render, (-1, 3), "hits", 12)
    assert len(calls) == 1
    assert again.mean.tobytes() == first.mean.tobytes() and again.var.tobytes() == first.var.tobytes()
    assert (again.spp, again.seconds) == (12, 0.5)
    cached_pass(cast(AuditSetup, setup), {**what, "points": "p2"}, render, (-1, 3), "hits", 12)
    assert len(calls) == 2


def test_reference_lays_the_masked_elements_onto_the_image(tmp_path):
    mask = np.array([[True, False, True], [False, True, False]])
    mean = np.arange(27, dtype=np.float64).reshape(3, 9) + 1.0
    entry = PassEntry(tmp_path, {"quantity": "test"}, namespace="audit", storage="npz")
    pooled = PooledPasses(mean, mean / 10, 64, 2, 1, entry, 1.5)
    ref = pooled.reference(mask, "q (W/m²)", "its integrator", "why", columns=slice(3, 6), extra_seconds=0.5)
    want = np.zeros((2, 3, 3))
    want[0, 0], want[0, 2], want[1, 1] = mean[0, 3:6], mean[1, 3:6], mean[2, 3:6]
    np.testing.assert_array_equal(ref.mean, want)
    np.testing.assert_array_equal(ref.stderr, want / 10)
    assert (ref.spp, ref.passes, ref.passes_rendered, ref.cache_key, ref.cache_path, ref.seconds) == (
        64,
        2,
        1,
        entry.key,
        str(entry.folder),
        2.0,
    )
    assert (ref.quantity, ref.integrator, ref.integrator_reason) == ("q (W/m²)", "its integrator", "why")
    grey = PooledPasses(mean[:, 0], mean[:, 1], 64, 2, 1, entry, 1.5).reference(mask, "q", "i", "r")
    np.testing.assert_array_equal(grey.mean[1, 1], [19.0, 19.0, 19.0])
    np.testing.assert_array_equal(grey.stderr[0, 2], [11.0, 11.0, 11.0])
    assert grey.seconds == 1.5 and not grey.mean[~mask].any()
    img = masked_image(
        mask, np.asarray([1, 2, 3], np.float32)
    )  # grey values in row-major pixel order, as float64
    assert img.dtype == np.float64 and img[0, 2].tolist() == [2.0] * 3 and img[1, 0].tolist() == [0.0] * 3


def test_pass_sizes_and_a_short_cached_pass_is_never_pooled_short(tmp_path):
    """--pass-spp and --spp (issue 32): pass i holds min(pass_spp, spp − i·pass_spp) samples, at least 2
    (a remainder of 1 renders one more); pass_spp > spp is one pass of spp. The cache key covers the pass
    size, not the total, so `--spp 33` leaves a 2-sample pass 1 that a later `--spp 64` would have pooled as
    if whole (34 samples instead of 64, a result that depended on the cache's history): it is rendered
    again at 32, and so is a pass whose JSON ``spp`` was edited."""
    import json

    from rtfit.reference.cache import pass_size

    assert [pass_size(10, 4, i) for i in range(3)] == [4, 4, 2]
    assert [pass_size(9, 4, i) for i in range(3)] == [4, 4, 2]  # remainder 1: two samples
    assert pass_size(5, 32, 0) == 5
    rng = np.random.default_rng(1)
    drawn = []

    def render(spp: int, seed: int) -> PassResult:
        x = rng.normal(2.0, 0.5, size=(spp, 4, 3))
        drawn.append(spp)
        return PassResult(x.mean(axis=0), x.var(axis=0, ddof=1), spp, seed, 0.1)

    def setup(spp):
        return cast(
            AuditSetup,
            types.SimpleNamespace(
                scene_digest="d", variant="scalar_rgb", seed=0, pass_spp=32, spp=spp, cache_root=tmp_path,
                progress=False,
            ),
        )  # fmt: skip

    small = pooled_passes(setup(33), {"quantity": "t"}, render, (-1, 3), "t")
    assert drawn == [32, 2] and small.spp == 34
    big = pooled_passes(setup(64), {"quantity": "t"}, render, (-1, 3), "t")
    assert drawn == [32, 2, 32] and (big.spp, big.passes_rendered) == (64, 1)
    meta = big.entry.folder / "pass-00000.json"
    meta.write_text(json.dumps({**json.loads(meta.read_text()), "spp": 320}))
    again = pooled_passes(setup(64), {"quantity": "t"}, render, (-1, 3), "t")
    assert drawn == [32, 2, 32, 32] and (again.spp, again.passes_rendered) == (64, 1)
