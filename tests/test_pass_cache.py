"""The one pass store (`rtfit.reference.cache.PassEntry`): resume, corrupt files, claims across processes.

No Mitsuba here: a pass is a deterministic array computed from its index, so "identical results" and
"rendered exactly once" are checked exactly."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import time

import numpy as np
import pytest

from rtfit.reference.cache import ComputedEntry, PassEntry, entry_key, pool_passes
from rtfit.reference.estimators import PassResult
from rtfit.reference.pass_entry import TORN_CLAIM_SECONDS

IDENT = {"what": "test", "format": 1}


def _render(i: int, log_dir: str | None = None, delay: float = 0.0) -> PassResult:
    if delay:
        time.sleep(delay)
    if log_dir:  # one marker file per render: the test counts who rendered what
        with open(os.path.join(log_dir, f"{i}-{os.getpid()}-{time.time_ns()}"), "w"):
            pass
    rng = np.random.default_rng(i)
    mean = rng.uniform(0, 1, (4, 3))
    return PassResult(mean, mean * 0.1, 16, i, 0.01)


def test_resume_renders_only_missing_passes(tmp_path):
    entry = PassEntry(tmp_path, IDENT)
    calls = []
    first, n = entry.passes(3, lambda i: calls.append(i) or _render(i))
    assert n == 3 and calls == [0, 1, 2]
    again = PassEntry(tmp_path, IDENT)
    more, n = again.passes(5, lambda i: calls.append(i) or _render(i))
    assert n == 2 and calls[3:] == [3, 4]
    # A resumed pass equals the fresh one exactly (both are the float32 values as stored).
    for a, b in zip(first, more[:3], strict=True):
        np.testing.assert_array_equal(a.mean, b.mean)
    assert entry.key == entry_key({**IDENT, "pass_store": "npz-float64"})


@pytest.mark.parametrize("damage", ["truncate", "garbage", "meta"])
def test_a_corrupt_pass_is_discarded_and_rendered_again(tmp_path, damage):
    entry = PassEntry(tmp_path, IDENT)
    good, _ = entry.passes(2, _render)
    data, meta = entry.folder / "pass-00001.npz", entry.folder / "pass-00001.json"
    if damage == "truncate":
        data.write_bytes(data.read_bytes()[:50])
    elif damage == "garbage":
        data.write_bytes(b"\x00" * 200)
    else:
        meta.write_text("{not json")
    assert entry.load(1) is None
    again, n = PassEntry(tmp_path, IDENT).passes(2, _render)
    assert n == 1
    np.testing.assert_array_equal(pool_passes(again)[0], pool_passes(good)[0])


def test_a_claim_of_a_dead_process_is_taken_over(tmp_path):
    entry = PassEntry(tmp_path, IDENT)
    entry.folder.mkdir(parents=True)
    dead = mp.get_context("spawn").Process(target=time.sleep, args=(0,))
    dead.start()
    dead.join()
    claim = entry.folder / "pass-00000.claim"
    claim.write_text(json.dumps({"host": os.uname().nodename, "pid": dead.pid, "started": 0}))
    _, n = entry.passes(1, _render)
    assert n == 1 and not claim.exists()


def _worker(root: str, log_dir: str, out: str):
    entry = PassEntry(root, IDENT)
    passes, _ = entry.passes(12, lambda i: _render(i, log_dir, delay=0.05))
    np.save(out, pool_passes(passes)[0])


def test_two_processes_on_one_cache_render_each_pass_once(tmp_path):
    log_dir = tmp_path / "log"
    log_dir.mkdir()
    ctx = mp.get_context("spawn")
    procs = [
        ctx.Process(target=_worker, args=(str(tmp_path / "cache"), str(log_dir), str(tmp_path / f"{k}.npy")))
        for k in range(2)
    ]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    rendered = [name.split("-")[0] for name in os.listdir(log_dir)]
    assert sorted(rendered, key=int) == [str(i) for i in range(12)]  # every pass exactly once
    np.testing.assert_array_equal(np.load(tmp_path / "0.npy"), np.load(tmp_path / "1.npy"))
    assert not list((tmp_path / "cache").rglob("*.claim"))


def test_a_killed_writers_temporary_files_are_removed_by_the_next_claim(tmp_path):
    entry = PassEntry(tmp_path, IDENT)
    entry.folder.mkdir(parents=True)
    leftover = entry.folder / ".pass-00000.npz.0123456789ab.tmp"  # the name atomic writes use
    leftover.write_bytes(b"half a pass")
    other = entry.folder / ".pass-00001.npz.0123456789ab.tmp"
    other.write_bytes(b"another pass's")
    _, n = entry.passes(1, _render)
    assert n == 1 and not leftover.exists() and other.exists()


# ---------------------------------------------------------------- ComputedEntry: one deterministic result
def _quadrature_like(calls: list) -> dict:
    calls.append(1)
    x = np.linspace(0.0, 1.0, 7)
    return {"value": np.exp(-x)[:, None] * np.ones(3), "disc": None, "seconds": np.float64(1.5)}


def test_a_computed_entry_is_computed_once_and_read_back_bit_identical(tmp_path):
    calls: list = []
    first, computed = ComputedEntry(tmp_path, IDENT, namespace="q").get(lambda: _quadrature_like(calls))
    again, computed2 = ComputedEntry(tmp_path, IDENT, namespace="q").get(lambda: _quadrature_like(calls))
    assert computed and not computed2 and calls == [1]
    assert "disc" not in first and "disc" not in again  # None values are not stored
    assert again["value"].dtype == np.float64 and np.array_equal(first["value"], again["value"])
    assert float(again["seconds"]) == 1.5
    # another identity is another entry
    _, computed3 = ComputedEntry(tmp_path, {**IDENT, "format": 2}, namespace="q").get(
        lambda: _quadrature_like(calls)
    )
    assert computed3 and calls == [1, 1]


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_a_corrupt_computed_entry_is_recomputed(tmp_path, damage):
    calls: list = []
    entry = ComputedEntry(tmp_path, IDENT, namespace="q")
    want, _ = entry.get(lambda: _quadrature_like(calls))
    path = entry.folder / ComputedEntry.RESULT
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"\x00junk" * 40, "empty": b""}[damage])
    got, computed = ComputedEntry(tmp_path, IDENT, namespace="q").get(lambda: _quadrature_like(calls))
    assert computed and calls == [1, 1] and np.array_equal(got["value"], want["value"])
    assert ComputedEntry(tmp_path, IDENT, namespace="q").load() is not None  # rewritten whole


def test_a_non_finite_pass_fails_with_one_line_and_is_not_stored(tmp_path):
    """One NaN sample poisons its pixel for every later fit: such a pass is refused, never cached, and the
    passes before it stay (the rerun resumes from them)."""
    from rtfit.reference.budget import NonFinitePass

    def render(i: int) -> PassResult:
        r = _render(i)
        if i == 1:
            r.mean[2, 1] = np.nan
        return r

    entry = PassEntry(tmp_path, IDENT)
    with pytest.raises(NonFinitePass) as err:
        entry.passes(3, render, label="sky-e10-ms")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("sky-e10-ms pass 2 of 3: 1 non-finite values")
    assert "flat indices 7" in msg  # row 2, channel 1 of a (4, 3) pass
    assert entry.load(0) is not None and entry.load(1) is None  # pass 0 kept, pass 1 not written
    assert not list(entry.folder.glob("pass-00001.*"))


def test_an_empty_claim_is_a_live_writers_until_it_is_old(tmp_path):
    """A claim file that does not parse yet is a writer between its create and its write (on a loaded
    machine: CI saw a pass rendered twice when such a claim was taken over at once); it is dead only once
    older than `TORN_CLAIM_SECONDS`."""
    entry = PassEntry(tmp_path, IDENT)
    entry.folder.mkdir(parents=True)
    claim = entry.folder / "pass-00000.claim"
    claim.write_text("")
    assert not PassEntry.claim_is_stale(claim) and not entry.claim(0)
    old = time.time() - TORN_CLAIM_SECONDS - 1
    os.utime(claim, (old, old))
    assert PassEntry.claim_is_stale(claim) and entry.claim(0)
    entry.release(0)
