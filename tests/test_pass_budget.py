"""No reference pass runs without bound (issue 21 §1): the medium-event cap and the per-pass watchdog.

The planted stuck medium is rtfit's exponential fog with its majorant raised to 1e7 per metre in a
4 m box: ~4e7 null collisions per path, 600× the per-lane cap. Unbounded, the pass would run for
hours on two cores; capped, it stops within the cap and fails its job with one line that names the
case and the pass, while the other job of the same run finishes.
"""

from __future__ import annotations

import dataclasses

import pytest

from rtfit.scenes import library_path, load_scene, scene_to_toml


def _tiny(name: str, fog: bool = True):
    base = load_scene(library_path("fog_transmittance"))
    camera = dataclasses.replace(base.camera, width=4, height=4)
    return dataclasses.replace(base, name=name, camera=camera, media=base.media if fog else ())


@pytest.mark.parametrize("reduction", ["atomic", "stored"])
def test_planted_stuck_medium_fails_one_job_with_one_line(tmp_path, monkeypatch, reduction):
    """With either of `PassMoments`' reductions (the CPU's ``atomic``, the GPU's ``stored``, whose sampling
    kernel only stores its samples: the media's event counters must still be evaluated with it)."""
    from rtfit.experiments.height_fog_study import render_job
    from rtfit.experiments.jobs import InlineExecutor, Job
    from rtfit.experiments.run_settings import RunSettings
    from rtfit.reference import estimators, fog_integrator, height_fog

    monkeypatch.setattr(estimators, "default_reduction", lambda mi: reduction)

    # the stuck medium: majorant 1e7 /m for the whole box, σt unchanged (every collision null), rendered
    # by volpathmis (not rtfit_fogpath, whose vertex cap tests/test_fog_integrator.py plants)
    monkeypatch.setattr(fog_integrator, "applies", lambda *a, **k: False)
    monkeypatch.setattr(height_fog, "majorant", lambda *a, **k: 1e7)
    orig = height_fog.medium_dict
    monkeypatch.setattr(height_fog, "medium_dict", lambda mi, m: orig(mi, m, segment_majorant=False))
    height_fog._registered.discard("llvm_ad_rgb")  # re-register: the plugin's class reads the patch
    settings = RunSettings(tmp_path / "cache", "llvm_ad_rgb", spp=4, pass_spp=4, seed=0)
    jobs = [
        Job(
            render_job,
            dict(scene_toml=scene_to_toml(s), settings=settings),
            label=s.name,
        )
        for s in (_tiny("stuck-fog"), _tiny("no-fog", fog=False))
    ]
    try:
        stuck, ok = InlineExecutor().run_all(jobs)
    finally:  # put the real plugin back for the tests after this one
        import mitsuba

        monkeypatch.undo()
        height_fog._registered.discard("llvm_ad_rgb")
        mitsuba.set_variant("llvm_ad_rgb")
        height_fog.register(mitsuba)
    assert ok.ok and ok.value["image"].mean.shape == (4, 4, 3)
    assert not stuck.ok and stuck.error is not None
    assert "\n" not in stuck.error
    assert stuck.error.startswith("PassBudgetExceeded: stuck-fog pass 1 of 1: ")
    assert "lanes took more than 65536 medium events" in stuck.error
    # nothing of the failed pass was stored (the one pass file is the fog-free job's): a rerun renders it
    assert len(list((tmp_path / "cache").rglob("pass-*.exr"))) == 1


def test_lane_counter_counts_per_lane_and_is_inert_unarmed(mi):
    import drjit as dr

    from rtfit.reference.budget import LaneCounter

    c = LaneCounter(cap=2)
    assert c.tick(mi.Float([0.0, 1.0])) is False and c.exhausted() == 0  # unarmed: no effect
    c.arm(mi.UInt32, 3)
    lanes = mi.Float([0.0, 1.0, 1.0, 2.0, 2.0, 2.0])
    over = c.tick(lanes)
    dr.eval(over)
    assert c.exhausted() == 1 and c.peak() == 3  # lane 2 reached the cap (3 events ≥ 2)
    with pytest.raises(ValueError, match="lanes must be in"):
        c.arm(mi.UInt32, 0)


def test_watchdog_ends_a_pass_past_its_budget_with_one_line(capsys, monkeypatch):
    import threading

    from rtfit.reference.budget import PassWatchdog, pass_budget_seconds

    fired = threading.Event()
    codes = []

    def fake_exit(code):
        codes.append(code)
        fired.set()

    with PassWatchdog("case-x pass 2 of 8", seconds=0.05, exit_fn=fake_exit):
        assert fired.wait(5.0)
    err = capsys.readouterr().err
    assert codes == [1]
    assert err.count("\n") == 1
    assert err.startswith("rtfit: error: case-x pass 2 of 8 ran past its budget of 0.05 s")
    with PassWatchdog("quick pass", seconds=5.0, exit_fn=fake_exit):
        pass  # finished in time: the watchdog never fires
    assert codes == [1]
    monkeypatch.setenv("RTFIT_PASS_BUDGET_S", "-3")
    with pytest.raises(ValueError, match="RTFIT_PASS_BUDGET_S must be a positive number"):
        pass_budget_seconds()
    monkeypatch.setenv("RTFIT_PASS_BUDGET_S", "120")
    assert pass_budget_seconds() == 120.0


def test_a_bad_budget_is_refused_before_anything_runs(monkeypatch, tmp_path, capsys):
    """``RTFIT_PASS_BUDGET_S=abc rtfit run …``: one line naming the variable, exit 2, nothing written (the
    check runs before any command, not when the first pass arms its watchdog)."""
    from rtfit.experiments.cli import main

    for bad in ("abc", "0", "-3", "nan"):
        monkeypatch.setenv("RTFIT_PASS_BUDGET_S", bad)
        out = tmp_path / f"out-{bad}"
        code = main(["run", "diffuse", "--quick", "--out", str(out), "--cache", str(tmp_path / "cache")])
        err = capsys.readouterr().err
        assert code == 2, bad
        assert err.count("\n") == 1 and err.startswith("rtfit: error: ") and "RTFIT_PASS_BUDGET_S" in err
        assert not out.exists() and not (tmp_path / "cache").exists()


def _run_quick_diffuse(tmp_path, capsys):
    """``rtfit run diffuse --quick`` into ``tmp_path``: (out folder, exit status, stderr lines)."""
    from rtfit.experiments.cli import main

    out = tmp_path / "out"
    code = main(
        ["run", "diffuse", "--quick", "--out", str(out), "--cache", str(tmp_path / "c"), "--no-progress"]
    )
    return out, code, capsys.readouterr().err.splitlines()


def test_a_run_whose_reference_fails_exits_1_with_one_line(monkeypatch, tmp_path, capsys):
    """A reference pass that cannot be stored (here a planted non-finite pass; a pass past its budget takes
    the same path) ends ``rtfit run`` with one line naming the case and pass and exit status 1 (a failed
    self-check, not bad input), no traceback and no half-written output folder."""
    from rtfit.reference import budget, pass_entry

    def planted(result, what):
        raise budget.NonFinitePass(f"{what}: 3 non-finite values (planted)")

    monkeypatch.setattr(pass_entry, "check_finite", planted)
    out, code, err = _run_quick_diffuse(tmp_path, capsys)
    err = [ln for ln in err if ln.startswith("rtfit: failed")]
    assert code == 1
    assert len(err) == 1 and "NonFinitePass: " in err[0] and " pass 1 of " in err[0] and "planted" in err[0]
    assert not out.exists() or not any(out.iterdir())


def test_a_value_error_inside_a_started_run_is_a_failure_not_bad_input(monkeypatch, tmp_path, capsys):
    """Exit status 2 is for bad input found before anything runs. A ValueError raised inside an experiment
    (the first full GPU sky run ended in "method 'nishita-fitted': the target must be a non-empty finite
    array", exit 2) is the run failing: one line naming the experiment, exit 1."""
    from rtfit.experiments import runner

    def planted(spec, *a, **k):
        raise ValueError("the target must be a non-empty finite array (planted)")

    monkeypatch.setattr(runner, "run_experiment_into", planted)
    out, code, err = _run_quick_diffuse(tmp_path, capsys)
    err = [ln for ln in err if ln.startswith("rtfit: ")]
    assert code == 1
    assert (
        err[-1].startswith("rtfit: failed: diffuse: ValueError: the target must be") and "planted" in err[-1]
    )
    assert not (out / "diffuse").exists()
