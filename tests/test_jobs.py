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
