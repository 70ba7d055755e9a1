"""Soft-particle references through rtfit's pass cache (`rtfit.reference.soft_particles.particle_reference`):
a second call loads every pass without rendering, the key follows the physics and nothing else, a truncated
pass is discarded and rendered again, every pass runs under the pass watchdog, and the pooled result still
agrees with the analytic clipped chord within the binomial noise √(T(1 − T)/N)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

import rtfit.reference.pass_entry as pass_entry
import rtfit.reference.soft_particles as sp
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.soft_particles import METHODS
from rtfit.reference.cache import entry_key

CENTRE = (0.2, 0.1, 4.0)
TILT = math.radians(35.0)
NORMAL = (0.0, math.sin(TILT), -math.cos(TILT))
POINT = (0.2, 0.1, 4.15)
SPP, PASS_SPP = 256, 128


@pytest.fixture(scope="module")
def dirs():
    from rtfit.experiments.soft_particles_kernels import pixel_dirs

    return pixel_dirs((6, 6), 40.0).reshape(-1, 3)


@pytest.fixture(scope="module")
def sigma():
    from rtfit.experiments.particle_geometry import sigma_of

    return sigma_of(0.9, 1.0)


class Counter:
    """Wraps `particle_pass` (what `particle_reference` renders each missing pass with) and counts calls."""

    def __init__(self, monkeypatch):
        self.calls: list[int] = []
        inner = sp.particle_pass

        def counted(mi, scene, directions, spp, seed, camera_inside=False):
            self.calls.append(seed)
            return inner(mi, scene, directions, spp, seed, camera_inside)

        monkeypatch.setattr(sp, "particle_pass", counted)


def _reference(root, dirs, sigma, **kw):
    args: dict[str, Any] = dict(spp=SPP, pass_spp=PASS_SPP, seed=5, variant="llvm_ad_rgb") | kw
    return sp.particle_reference(root, "sphere", CENTRE, 1.0, sigma, POINT, NORMAL, dirs, **args)


@pytest.fixture(scope="module")
def first(tmp_path_factory, dirs, sigma):
    """One cached reference (2 passes of 128 samples) shared by the tests below."""
    root = tmp_path_factory.mktemp("softcache")
    mp = pytest.MonkeyPatch()
    try:
        counter = Counter(mp)
        ref = _reference(root, dirs, sigma)
    finally:
        mp.undo()
    return root, ref, counter.calls


def test_first_call_renders_every_pass_with_its_own_seed(first):
    _, ref, calls = first
    assert ref.passes == 2 and ref.passes_rendered == 2 and ref.spp == SPP
    assert len(calls) == 2 and len(set(calls)) == 2  # pass i: sub_seed(seed, "pass", i)


def test_second_call_loads_from_the_cache_without_rendering(first, dirs, sigma, monkeypatch):
    root, ref, _ = first
    counter = Counter(monkeypatch)
    again = _reference(root, dirs, sigma, label="another label", progress=False)
    assert counter.calls == [] and again.passes_rendered == 0 and again.key == ref.key
    np.testing.assert_array_equal(again.mean, ref.mean)
    np.testing.assert_array_equal(again.var, ref.var)
    # More samples later: the same entry, only the new pass is rendered.
    more = _reference(root, dirs, sigma, spp=3 * PASS_SPP)
    assert len(counter.calls) == 1 and more.passes == 3 and more.passes_rendered == 1 and more.key == ref.key


def test_a_truncated_pass_is_discarded_and_rendered_again(first, dirs, sigma, monkeypatch, tmp_path):
    root, ref, _ = first
    import shutil

    copy = tmp_path / "cache"
    shutil.copytree(root, copy)
    (data,) = copy.glob("soft_particles/*/*/pass-00001.npz")
    data.write_bytes(data.read_bytes()[:40])
    counter = Counter(monkeypatch)
    again = _reference(copy, dirs, sigma)
    assert len(counter.calls) == 1 and again.passes_rendered == 1
    # The re-rendered pass has the same seed, so the same samples: sums of float32 weights accumulated in
    # float64 in another order (`channel_moments`); measured difference 0.
    np.testing.assert_allclose(again.mean, ref.mean, rtol=0, atol=1e-12)
    with np.load(data) as z:
        assert z["mean"].shape == (len(dirs), 3)


def test_an_interrupted_reference_resumes_from_its_cache(tmp_path, dirs, sigma, monkeypatch, first):
    """A run stopped during its second pass keeps the first; the rerun renders only the second and gives the
    uninterrupted result."""
    _, ref, _ = first
    counter = Counter(monkeypatch)
    counted = sp.particle_pass

    def interrupted(mi, scene, directions, spp, seed, camera_inside=False):
        if counter.calls:
            raise KeyboardInterrupt  # Ctrl-C (or a kill) while the second pass renders
        return counted(mi, scene, directions, spp, seed, camera_inside)

    monkeypatch.setattr(sp, "particle_pass", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _reference(tmp_path, dirs, sigma)
    assert len(counter.calls) == 1
    (entry,) = tmp_path.glob("soft_particles/*/*")
    assert sorted(f.name for f in entry.glob("pass-*")) == ["pass-00000.json", "pass-00000.npz"]
    monkeypatch.setattr(sp, "particle_pass", counted)
    again = _reference(tmp_path, dirs, sigma)
    assert len(counter.calls) == 2 and again.passes_rendered == 1 and again.passes == 2
    np.testing.assert_allclose(again.mean, ref.mean, rtol=0, atol=1e-12)  # measured difference 0


def test_key_follows_the_physics_and_nothing_else(dirs, sigma):
    def key(**kw):
        base: dict[str, Any] = dict(
            shape="sphere",
            centre=CENTRE,
            radius=1.0,
            sigma_t=sigma,
            plane_point=POINT,
            plane_normal=NORMAL,
            directions=dirs,
            camera_inside=False,
            seed=5,
            pass_spp=PASS_SPP,
            variant="llvm_ad_rgb",
        )
        return entry_key(sp.particle_identity(**(base | kw)))

    k = key()
    # Not the key: the same values as other types (arrays, lists), a copy of the directions.
    assert key(centre=np.array(CENTRE), plane_normal=list(NORMAL), directions=dirs.copy()) == k
    moved = [
        key(sigma_t=sigma * 1.001),
        key(plane_point=(0.2, 0.1, 4.16)),
        key(plane_normal=(0.0, math.sin(TILT + 1e-3), -math.cos(TILT + 1e-3))),
        key(shape="box"),
        key(radius=1.1),
        key(centre=(0.2, 0.1, 4.01)),
        key(camera_inside=True),
        key(directions=dirs[:-1]),  # resolution / field of view
        key(seed=6),
        key(pass_spp=2 * PASS_SPP),
        key(variant="scalar_rgb"),
    ]
    assert len({k, *moved}) == len(moved) + 1


def test_every_pass_runs_under_the_watchdog(tmp_path, dirs, sigma, monkeypatch):
    """No pass without bound: `PassEntry.passes` wraps each render in `PassWatchdog` naming case and pass."""
    seen = []
    real = pass_entry.PassWatchdog

    def recording(what, *a, **kw):
        seen.append(what)
        return real(what, *a, **kw)

    monkeypatch.setattr(pass_entry, "PassWatchdog", recording)
    _reference(tmp_path, dirs, sigma, label="case-x")  # a fresh cache: both passes render
    assert seen == ["case-x pass 1 of 2", "case-x pass 2 of 2"]


def test_pooled_reference_matches_the_chord_and_the_binomial_noise(first, dirs, sigma):
    """z-scores of the pooled mean against exp(−σℓ) of the analytic chord with √(T(1 − T)/N), and the pooled
    sample variance equal to N/(N − 1)·T̂(1 − T̂) (every sample is 0 or 1 up to float32 rounding)."""
    from rtfit.experiments.soft_particles_kernels import plane_distance, ray_inputs

    _, ref, _ = first
    ts = plane_distance(dirs, np.asarray(POINT), np.asarray(NORMAL))
    t = 1.0 - np.asarray(METHODS["exact-sphere"](NUMPY_OPS, ray_inputs(dirs, CENTRE, 1.0, sigma, ts)))
    se = sp.bernoulli_stderr(t, ref.spp)
    ok = se > 0
    assert ok.sum() >= 6
    z = (ref.mean[ok] - t[ok]) / se[ok]
    assert np.max(np.abs(z)) < 4.5  # Šidák 1 % over 36 pixels: 3.6
    assert np.all(ref.mean[~ok] == 1.0)
    n = ref.spp
    gap = np.abs(ref.var - n / (n - 1) * ref.mean * (1.0 - ref.mean))
    assert np.max(gap) < 1e-6  # float32 weights; measured ≤ 1.1e-7 (quick run)
    np.testing.assert_allclose(ref.stderr, np.sqrt(ref.var / n), rtol=1e-12)
