"""rtfit's rendering entry points put the caller's Mitsuba variant back: a notebook working in
``scalar_rgb`` keeps it after `render_gbuffer`, a reference render through the cache, and a whole
experiment run (Mitsuba's variant is process-wide state)."""

from __future__ import annotations

import pytest

from rtfit.reference import ReferenceCache, ReferenceRequest, render_gbuffer

from .conftest import sphere_scene


@pytest.fixture
def scalar_caller():
    mitsuba = pytest.importorskip("mitsuba")
    before = mitsuba.variant()
    mitsuba.set_variant("scalar_rgb")
    yield mitsuba
    if before:
        mitsuba.set_variant(before)


def test_render_gbuffer_keeps_the_callers_variant(scalar_caller):
    gb = render_gbuffer(sphere_scene(res=4), "llvm_ad_rgb")
    assert gb.mask.any()
    assert scalar_caller.variant() == "scalar_rgb"


def test_reference_render_keeps_the_callers_variant(scalar_caller, tmp_path):
    ref = ReferenceCache(tmp_path).get(
        ReferenceRequest(scene=sphere_scene(res=4), spp=16, pass_spp=8, seed=1)
    )
    assert ref.passes_rendered == 2
    assert scalar_caller.variant() == "scalar_rgb"


def test_scenes_are_read_in_the_active_rgb_variant_with_what_scalar_rgb_reads(tmp_path):
    """`inspection_variant` reads a scene in the active variant where it is one of `INSPECTION_VARIANTS`
    (issue 33: switching back into a JIT variant re-imports Mitsuba's Python integrators, 0.12 s each): no
    switch happens (the integrator classes stay the same objects), and ``rtfit audit --list`` of Mitsuba's
    Cornell box and of a library TOML scene says the same words as when ``scalar_rgb`` reads them."""
    import sys
    from pathlib import Path

    from click.testing import CliRunner

    from rtfit.experiments.audit_cli import audit as audit_cmd
    from rtfit.reference.variants import inspection_variant

    mitsuba = pytest.importorskip("mitsuba")
    before = mitsuba.variant()
    cbox = Path(__file__).parent / "data" / "mitsuba" / "cbox" / "cbox-rgb.xml"
    scenes = [[str(cbox), "-D", "res=32"], ["pcf_soft_shadows_sphere"]]

    def listed() -> list[str]:
        outs = []
        for args in scenes:
            res = CliRunner().invoke(audit_cmd, [*args, "--list"])
            assert res.exit_code == 0, res.output
            outs.append(res.output)
        return outs

    try:
        mitsuba.set_variant("scalar_rgb")
        assert inspection_variant() == "scalar_rgb"
        in_scalar = listed()
        mitsuba.set_variant("llvm_ad_rgb")
        prb = sys.modules["mitsuba.python.ad.integrators.prb"].PRBIntegrator
        assert inspection_variant() == "llvm_ad_rgb"
        in_llvm = listed()
        assert mitsuba.variant() == "llvm_ad_rgb"
        assert sys.modules["mitsuba.python.ad.integrators.prb"].PRBIntegrator is prb  # not re-imported
    finally:
        if before:
            mitsuba.set_variant(before)
    assert in_llvm == in_scalar
