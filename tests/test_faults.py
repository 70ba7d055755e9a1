"""Fault injection (issue 21 §4): a run killed with SIGKILL at random points and rerun gives the results
of an uninterrupted run, so does a truncated cache pass; what a killed run leaves behind is removed
(its temporary output directory) and the rerun says how much it resumed."""

from __future__ import annotations

import json
import logging
import os
import random
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from rtfit.experiments import atomic
from rtfit.experiments.atomic import atomic_directory, is_temporary_name, owner_file, remove_stale_temporaries
from rtfit.experiments.runner import resumed_line
from rtfit.reference import processes
from rtfit.reference.cache import PASS_COUNTS, PassEntry, PassResult

# A tiny diffuse run (two shipped scenes, the fewest its study takes, at 16² pixels, 8 passes of 32 samples
# per light reference: 16 passes in all, rendered in a few seconds; the fits, costs and study after them take
# longer). Every run here draws its matplotlib figures but does not encode them (matplotlib's savefig was a
# third of a run): those files are written empty, the same in every run, so results.json is compared as
# before; the figures themselves are checked by the runs of the other tests. (The per-case image and ꟻLIP
# mosaics are composed as pixels, `figures.MosaicFigure`, not through savefig: written as they are.)
# Costs are timed on their repeats only (tests/conftest.py; results.json is compared without timings).
DRIVER = textwrap.dedent(
    """
    import logging
    import sys
    from pathlib import Path
    from rtfit.experiments import cost, figures
    from rtfit.reference.io import atomic_write_bytes
    from rtfit.experiments.families import get_experiment

    def unencoded_figure(fig, path):
        figures.pyplot().close(fig)
        return atomic_write_bytes(path, b"")

    figures.save_figure = unencoded_figure
    median_time = cost._median_time
    cost._median_time = lambda call, repeats, min_seconds: median_time(call, repeats, 0.0)  # as conftest.py
    logging.basicConfig(level=logging.INFO, format="rtfit: %(message)s", stream=sys.stderr)
    from rtfit.experiments.run_settings import RunSettings
    from rtfit.experiments.runner import run_experiments

    scenes = ["diffuse_sphere_a5", "diffuse_sphere_a30"]
    overrides = {"scenes": scenes, "resolution": 16}
    run_experiments([get_experiment("diffuse")], Path(sys.argv[1]),
                    RunSettings(Path(sys.argv[2]), "llvm_ad_rgb", spp=256, quick=True), overrides=overrides)
    """
)
KILLS = 3
# Keys whose values are measurements of time (benchmarks, render speed), not results.
TIMINGS = {
    "created",
    "costs",
    "cost",
    "repeats",
    "ns_per_pixel",
    "pixels_per_second",
    "samples_per_second",
    "seconds",
    "render_seconds",
    "engine_seconds",
}


def _start(out: Path, cache: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", DRIVER, str(out), str(cache)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _run(out: Path, cache: Path) -> str:
    p = _start(out, cache)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err[-3000:]
    return err


def _numbers(results_dir: Path):
    """results.json without its timings."""

    def strip(node):
        if isinstance(node, dict):
            return {k: strip(v) for k, v in node.items() if k not in TIMINGS}
        if isinstance(node, list):
            return [strip(v) for v in node]
        return node

    return strip(json.loads((results_dir / "results.json").read_text()))


def _passes(cache: Path) -> list[Path]:
    """The complete passes: a pass is stored when both its data (EXR, or NPZ for the audit's passes) and
    its record (JSON) are written; a kill between the two leaves data that the rerun rightly renders again,
    so it is not counted."""
    data = [*cache.rglob("pass-*.exr"), *cache.rglob("pass-*.npz")]
    return sorted(p for p in data if p.with_suffix(".json").exists())


def test_killed_runs_and_a_truncated_pass_give_the_uninterrupted_results(tmp_path):
    clean_out, clean_cache = tmp_path / "clean-out", tmp_path / "clean-cache"
    t0 = time.time()
    _run(clean_out, clean_cache)
    expected = _numbers(clean_out / "diffuse")
    done = sorted(p.stat().st_mtime for p in _passes(clean_cache))
    total = len(done)
    assert total == 16
    # Kill while passes are rendered: after the start-up (until the first pass), at a random point of
    # what is left to render (estimated from the uninterrupted run).
    startup, render = done[0] - t0, done[-1] - done[0]

    out, cache = tmp_path / "out", tmp_path / "cache"
    rng = random.Random(21)
    partial = []
    for _ in range(KILLS):
        left = 1.0 - len(_passes(cache)) / total
        p = _start(out, cache)
        time.sleep(startup + rng.uniform(0.0, 1.0) * left * render)
        p.send_signal(signal.SIGKILL)
        p.communicate()
        partial.append(len(_passes(cache)))
    assert not (out / "diffuse").exists()  # every kill came before the swap
    leftovers = [p for p in out.iterdir() if is_temporary_name(p.name)] if out.exists() else []
    err = _run(out, cache)
    for p in leftovers:  # each one removed, in one line
        assert f"rtfit: removed the abandoned temporary directory {p} (its owner, pid " in err
    print(f"passes cached after each kill: {partial} of {total}; leftovers: {len(leftovers)}")
    assert _numbers(out / "diffuse") == expected
    if partial[-1]:
        assert f"diffuse: resumed {partial[-1]} of {total} passes from the cache" in err
    assert not [p for p in out.iterdir() if is_temporary_name(p.name)]
    assert sorted(p.name for p in out.iterdir()) == ["diffuse", "index.html", "index.md"]  # no owner files

    victim = _passes(cache)[len(_passes(cache)) // 2]
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    err = _run(out, cache)
    assert f"diffuse: resumed {total - 1} of {total} passes from the cache" in err
    assert _numbers(out / "diffuse") == expected


# ---------------------------------------------------------------------------- leftover temporaries
def _dead_pid() -> int:
    p = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(p.stdout)


def _leftover(final: Path, owner: dict | None, suffix: str = "tmp") -> Path:
    tmp = final.parent / f".{final.name}.{os.urandom(6).hex()}.{suffix}"
    tmp.mkdir(parents=True)
    (tmp / "results.json").write_text("{}")
    if owner is not None:
        owner_file(tmp).write_text(json.dumps(owner))
    return tmp


def test_a_dead_owners_temporary_directory_is_removed_with_one_line(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="rtfit.experiments")
    final = tmp_path / "diffuse"
    dead = _leftover(final, {"host": socket.gethostname(), "pid": _dead_pid(), "start": None})
    live = _leftover(final, {"host": socket.gethostname(), "pid": os.getpid(), "start": None})
    elsewhere = _leftover(final, {"host": "another-host.invalid", "pid": 1, "start": None})
    unowned = _leftover(final, None)
    other = _leftover(tmp_path / "height-fog", {"host": socket.gethostname(), "pid": _dead_pid()})
    with atomic_directory(final) as tmp:
        assert json.loads(owner_file(tmp).read_text())["pid"] == os.getpid()
        (tmp / "a.txt").write_text("a")
    err = [f"rtfit: {r.getMessage()}" for r in caplog.records if r.name == "rtfit.experiments"]
    assert not dead.exists()
    assert len(err) == 1
    assert err[0].startswith(f"rtfit: removed the abandoned temporary directory {dead} (its owner, pid ")
    assert err[0].endswith(" is gone)")
    assert live.exists() and elsewhere.exists() and unowned.exists() and other.exists()
    assert sorted(os.listdir(final)) == ["a.txt"]
    assert not owner_file(tmp).exists() and not owner_file(dead).exists()


def test_a_reused_pid_or_an_old_unowned_directory_is_stale(tmp_path, monkeypatch):
    final = tmp_path / "x"
    reused = _leftover(final, {"host": socket.gethostname(), "pid": os.getpid(), "start": "not-my-start"})
    unowned = _leftover(final, None, "old")
    torn = _leftover(final, None)
    owner_file(torn).write_text('{"host": ')
    os.utime(owner_file(torn), (time.time() - 60, time.time() - 60))
    orphan = owner_file(final.parent / f".{final.name}.{'ab' * 6}.tmp")
    orphan.write_text("{}")
    assert set(remove_stale_temporaries(final, log=None)) == {reused, torn}
    assert not orphan.exists() and not owner_file(torn).exists()
    monkeypatch.setattr(atomic, "STALE_UNOWNED_SECONDS", -1.0)
    assert remove_stale_temporaries(final, log=None) == [unowned]


def test_the_owner_file_comes_before_its_directory(tmp_path, monkeypatch):
    """`atomic_directory` writes the owner file, then creates the directory, so a kill between the two never
    leaves an ownerless directory (kept an hour: `STALE_UNOWNED_SECONDS`; the kill loop above hit it under
    load). A live builder's owner file whose directory is not there yet is kept; a dead one's goes."""
    final = tmp_path / "diffuse"
    seen = []  # whether the directory existed when its owner file was written
    real_write = atomic._write_owner
    monkeypatch.setattr(atomic, "_write_owner", lambda tmp: seen.append(tmp.exists()) or real_write(tmp))
    with atomic.atomic_directory(final, log=None) as tmp:
        assert seen == [False] and owner_file(tmp).exists()
    monkeypatch.undo()
    me = {"host": socket.gethostname(), "pid": os.getpid(), "start": processes.process_start(os.getpid())}
    mine = owner_file(final.parent / f".{final.name}.{'cd' * 6}.tmp")
    mine.write_text(json.dumps(me))
    dead = owner_file(final.parent / f".{final.name}.{'ef' * 6}.tmp")
    dead.write_text(json.dumps({**me, "pid": _dead_pid(), "start": None}))
    assert remove_stale_temporaries(final, log=None) == []
    assert mine.exists() and not dead.exists()


def test_the_owner_file_is_written_in_place_and_an_old_owner_temporary_goes(tmp_path, monkeypatch, caplog):
    """The owner file is created in place (O_EXCL), never through a temporary file: CI killed a run inside the
    atomic write of one and its ``..NAME.<hex>.tmp.owner.<hex>.tmp`` stayed (stop 51). Such a file left by an
    older rtfit goes once unchanged for `TORN_OWNER_SECONDS`, with one line; a fresh one stays."""
    caplog.set_level(logging.INFO, logger="rtfit.experiments")
    final = tmp_path / "diffuse"
    final.parent.mkdir(parents=True, exist_ok=True)
    made = []
    real_open = os.open
    monkeypatch.setattr(
        atomic.os, "open", lambda path, *a, **k: made.append(Path(path)) or real_open(path, *a, **k)
    )
    with atomic.atomic_directory(final, log=None) as tmp:
        assert made == [owner_file(tmp)] and json.loads(owner_file(tmp).read_text())["pid"] == os.getpid()
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diffuse"]
    old = tmp_path / f"..diffuse.{'ab' * 6}.tmp.owner.{'cd' * 6}.tmp"
    fresh = tmp_path / f"..diffuse.{'ef' * 6}.tmp.owner.{'01' * 6}.tmp"
    foreign = tmp_path / f"..height-fog.{'ab' * 6}.tmp.owner.{'cd' * 6}.tmp"
    for f in (old, fresh, foreign):
        f.write_text('{"host": ')
    for f in (old, foreign):
        os.utime(f, (time.time() - 60, time.time() - 60))
    assert remove_stale_temporaries(final) == []  # (files: the directories' list stays)
    assert not old.exists() and fresh.exists() and foreign.exists()
    (line,) = [r.getMessage() for r in caplog.records if r.name == "rtfit.experiments"]
    assert line == f"removed the abandoned temporary file {old} (an owner file's, from an older rtfit)"


def test_a_live_owners_temporary_directory_is_kept(tmp_path):
    final = tmp_path / "diffuse"
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        start = Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[-1].split()[19]
        live = _leftover(final, {"host": socket.gethostname(), "pid": child.pid, "start": start})
        assert remove_stale_temporaries(final, log=None) == []
        assert live.exists()
        child.kill()
        child.wait()
        assert remove_stale_temporaries(final, log=None) == [live]
    finally:
        child.kill()
        child.wait()


# ------------------------------------------------------------------------------------ resume count
def test_pass_counts_and_the_resumed_line(tmp_path):
    """ "resumed" names only passes that existed before this process: passes it rendered itself and reads
    again (two cases sharing a reference) count as rendered (issue 37: "resumed 2 of 24 passes" on a cache
    the run had just created)."""
    import numpy as np

    def render(i):
        return PassResult(np.full((2, 3), float(i)), np.ones((2, 3)), 4, i, 0.0)

    entry = PassEntry(tmp_path / "ours", {"test": 1}, storage="npz")
    before = PASS_COUNTS.snapshot()
    entry.passes(3, render)
    middle = PASS_COUNTS.snapshot()
    entry.passes(5, render)
    after = PASS_COUNTS.snapshot()
    assert (middle[0] - before[0], middle[1] - before[1]) == (3, 3)
    assert (after[0] - middle[0], after[1] - middle[1]) == (5, 5)
    assert resumed_line("diffuse", before, middle) is None
    assert resumed_line("diffuse", middle, after) is None
    # Passes saved by an earlier process (`save` alone, as a previous run left them) are resumed.
    earlier = PassEntry(tmp_path / "earlier", {"test": 2}, storage="npz")
    for i in range(3):
        earlier.save(i, render(i))
    before = PASS_COUNTS.snapshot()
    PassEntry(tmp_path / "earlier", {"test": 2}, storage="npz").passes(5, render)
    after = PASS_COUNTS.snapshot()
    assert resumed_line("diffuse", before, after) == "diffuse: resumed 3 of 5 passes from the cache"


@pytest.mark.parametrize("suffix", ["tmp", "old"])
def test_only_this_outputs_temporaries_are_considered(tmp_path, suffix):
    final = tmp_path / "diffuse"
    kept = _leftover(tmp_path / "diffuse-2", {"host": socket.gethostname(), "pid": _dead_pid()}, suffix)
    assert remove_stale_temporaries(final, log=None) == []
    assert kept.exists()
