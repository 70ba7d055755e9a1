"""Executors: the same plain-data jobs give identical results in this process and in a spawn pool."""

import numpy as np

from rtfit.experiments.executors import make_executor
from rtfit.experiments.height_fog_study import render_job
from rtfit.experiments.jobs import InlineExecutor, Job, ProcessExecutor
from rtfit.experiments.run_settings import RunSettings
from rtfit.scenes import scene_to_toml

from .conftest import sphere_scene


def _jobs(tmp_path):
    tomls = {a: scene_to_toml(sphere_scene(alpha_deg=a, res=12)) for a in (5.0, 20.0)}
    return [
        Job(
            render_job,
            dict(
                scene_toml=tomls[a],
                settings=RunSettings(tmp_path / f"cache-{tag}", "llvm_ad_rgb", spp=32, pass_spp=16, seed=3),
                gbuffer_of=tomls[a],
            ),
            label=f"a{a}",
        )
        for a, tag in ((5.0, "x"), (20.0, "y"))
    ]


def test_process_pool_matches_inline(tmp_path):
    inline = InlineExecutor().map(_jobs(tmp_path / "inline"))
    pool = ProcessExecutor(workers=2)
    try:
        spawned = pool.map(_jobs(tmp_path / "pool"))
    finally:
        pool.close()
    for a, b in zip(inline, spawned, strict=True):
        np.testing.assert_array_equal(a["image"].mean, b["image"].mean)  # same seeds → same samples
        np.testing.assert_array_equal(a["image"].stderr, b["image"].stderr)
        np.testing.assert_array_equal(a["gbuffer"].normal, b["gbuffer"].normal)


def test_unknown_executor_is_clear():
    import pytest

    with pytest.raises(ValueError, match="unknown executor 'dask'"):
        make_executor("dask")


def _nested_job():
    def inner():
        return 1

    return inner


def test_job_refuses_a_function_no_worker_could_import():
    """A lambda or a nested function has no top-level import path: the process pool refuses the job list
    with one line before any job runs; inline, where nothing is imported back, it just runs."""
    import pytest

    from rtfit.experiments.jobs import diagnostic_job, import_path

    assert import_path(diagnostic_job) == "rtfit.experiments.jobs:diagnostic_job"
    pool = ProcessExecutor(workers=1)
    try:
        for func in (lambda: 1, _nested_job()):
            job = Job(func, {}, "bad")
            assert InlineExecutor().map([job]) == [1]
            with pytest.raises(ValueError, match="not importable at module top level") as err:
                pool.map([Job(diagnostic_job, {}, "ok"), job])
            assert "\n" not in str(err.value)
    finally:
        pool.close()


def test_worker_kernel_caches_one_slot_a_live_process_kept_between_runs(tmp_path):
    """`worker_kernel_cache`: a live process's slot is not handed to another (its ``flock``), a dead one's is
    (the lock dies with it) and keeps what was written there; an unwritable root gives a temporary
    directory of the worker's own."""
    import os
    import subprocess
    import sys
    import tempfile

    from rtfit.experiments import jobs

    claim = (
        "import sys, time; from pathlib import Path; from rtfit.experiments.jobs import worker_kernel_cache; "
        "print(worker_kernel_cache(Path(sys.argv[1])), flush=True); time.sleep(float(sys.argv[2]))"
    )

    def holder(seconds: float):
        args = [sys.executable, "-c", claim, str(tmp_path), str(seconds)]
        p = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
        assert p.stdout is not None
        with p.stdout:
            return p, p.stdout.readline().strip()

    first, slot = holder(60.0)
    try:
        assert slot == str(tmp_path / "slot-0")
        (tmp_path / "slot-0" / "kernel.bin").write_bytes(b"compiled")
        held = len(jobs._HELD_SLOT)
        assert jobs.worker_kernel_cache(tmp_path) == str(tmp_path / "slot-1")  # slot 0 is the live holder's
        os.close(jobs._HELD_SLOT.pop())  # (this process's lock given back)
        assert len(jobs._HELD_SLOT) == held
    finally:
        first.kill()
        first.wait()
    second, slot = holder(0.0)
    second.wait()
    assert slot == str(tmp_path / "slot-0")  # the dead holder's slot, with its kernels
    assert (tmp_path / "slot-0" / "kernel.bin").read_bytes() == b"compiled"
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    private = jobs.worker_kernel_cache(blocked / "slots")
    assert os.path.dirname(private) == tempfile.gettempdir() and "rtfit-drjit-" in private
    os.rmdir(private)
