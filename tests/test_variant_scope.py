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
