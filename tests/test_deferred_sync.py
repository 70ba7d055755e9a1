"""`rtfit.reference.io.deferred_sync`: files written inside an output directory under construction skip their
own fsyncs, and one sync of the file system before the swap makes them durable (issue 33, session 20)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rtfit.experiments.atomic import atomic_directory
from rtfit.reference import io as rio


@pytest.fixture
def syncs(monkeypatch):
    """Counts of os.fsync calls and of whole-file-system syncs."""
    counts = {"fsync": 0, "syncfs": 0}
    real = os.fsync

    def fsync(fd):
        counts["fsync"] += 1
        real(fd)

    def sync_fs(directory):
        counts["syncfs"] += 1

    monkeypatch.setattr(rio.os, "fsync", fsync)
    monkeypatch.setattr(rio, "_sync_file_system", sync_fs)
    return counts


def test_outside_a_block_each_write_syncs_its_file_and_directory(tmp_path, syncs):
    rio.atomic_write_text(tmp_path / "a.txt", "x")
    assert syncs == {"fsync": 2, "syncfs": 0}


def test_inside_a_block_writes_wait_for_one_sync_at_its_end(tmp_path, syncs):
    with rio.deferred_sync(tmp_path / "out") as d:
        rio.atomic_write_text(d / "a.txt", "x")
        rio.atomic_write_json(d / "sub" / "b.json", {"v": 1})
        rio.write_exr(d / "c.exr", {"RGB": np.ones((2, 2, 3))})
        rio.atomic_write_text(tmp_path / "elsewhere.txt", "y")  # outside the block's directory: synced
        assert syncs == {"fsync": 2, "syncfs": 0}
    assert syncs == {"fsync": 2, "syncfs": 1}
    assert (tmp_path / "out" / "a.txt").read_text() == "x"
    assert rio.read_exr(tmp_path / "out" / "c.exr")["R"].shape == (2, 2)


def test_a_nested_block_leaves_the_sync_to_the_outer_one(tmp_path, syncs):
    with rio.deferred_sync(tmp_path) as outer:
        with rio.deferred_sync(outer / "inner") as inner:
            rio.atomic_write_text(inner / "a.txt", "x")
        assert syncs["syncfs"] == 0
    assert syncs == {"fsync": 0, "syncfs": 1}


def test_a_failing_block_syncs_nothing_and_later_writes_sync_again(tmp_path, syncs):
    with pytest.raises(RuntimeError), rio.deferred_sync(tmp_path):
        rio.atomic_write_text(tmp_path / "a.txt", "x")
        raise RuntimeError("boom")
    assert syncs == {"fsync": 0, "syncfs": 0}
    rio.atomic_write_text(tmp_path / "b.txt", "y")
    assert syncs["fsync"] == 2


def test_an_atomic_directory_syncs_once_before_its_swap(tmp_path, syncs):
    with atomic_directory(tmp_path / "exp", log=None) as tmp:
        for k in range(5):
            rio.atomic_write_text(tmp / f"f{k}.txt", str(k))
    assert syncs["syncfs"] == 1
    # the parent after the rename (the owner file beside it is not synced: it only tells a later run whether
    # its builder still lives; lost in a power cut, its directory counts as unowned and goes an hour later:
    # `atomic.STALE_UNOWNED_SECONDS`)
    assert syncs["fsync"] == 1
    assert sorted(p.name for p in (tmp_path / "exp").iterdir()) == [f"f{k}.txt" for k in range(5)]


def test_the_fallback_fsyncs_every_file_and_directory(tmp_path, monkeypatch):
    (tmp_path / "d").mkdir()
    for name in ("a", "d/b"):
        (tmp_path / name).write_text(name)
    calls = []
    real = os.fsync
    monkeypatch.setattr(rio.os, "fsync", lambda fd: (calls.append(fd), real(fd)))
    monkeypatch.setattr(rio.ctypes, "CDLL", lambda *a, **k: (_ for _ in ()).throw(OSError("no libc")))
    rio._sync_file_system(tmp_path)
    assert len(calls) == 4  # two files, two directories
