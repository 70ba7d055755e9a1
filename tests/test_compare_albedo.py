"""``rtfit compare --aov albedo=A.exr`` (issue 36) on the 24 × 24 scene tests/data/compare/two_shapes.xml.

Independent values: the albedo AOV is Mitsuba's ``aov`` integrator (``albedo``) and the frames ``mi.render``
(box filter), of the scene and of the scene with the ball's reflectance halved (an engine's wrong material:
its error is the albedo's, by construction); the frame with the ball's shadow removed keeps every albedo (its
error is lighting, by construction); the flipped and sRGB-encoded AOVs are ``[::-1]`` and the closed-form
sRGB transfer function of the good one.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.audit import AuditError
from rtfit.experiments.compare import compare
from rtfit.reference.io import write_exr

SCENE = Path(__file__).parent / "data" / "compare" / "two_shapes.xml"
SPP = 128
FRAME_SPP = 512
BALL = '<rgb name="reflectance" value="0.7, 0.2, 0.15"/>'


def _srgb(v):
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    d = tmp_path_factory.mktemp("albedo")
    text = SCENE.read_text()
    assert text.count(BALL) == 1
    dark = text.replace(BALL, '<rgb name="reflectance" value="0.35, 0.1, 0.075"/>')
    with scoped_variant("llvm_ad_rgb"):
        aov = mi.load_dict({"type": "aov", "aovs": "aa:albedo"})
        scene, dark_scene = mi.load_file(str(SCENE)), mi.load_string(dark)
        img = np.array(mi.render(scene, spp=FRAME_SPP, seed=3), np.float64)
        albedo = np.array(mi.render(scene, integrator=aov, spp=64), np.float64)
        dark_img = np.array(mi.render(dark_scene, spp=FRAME_SPP, seed=4), np.float64)
        dark_albedo = np.array(mi.render(dark_scene, integrator=aov, spp=64), np.float64)
        normal = mi.load_dict({"type": "aov", "aovs": "nn:geo_normal"})
        n = np.array(mi.render(scene, integrator=normal, spp=16), np.float64)
        floor = np.all(np.abs(n - [0.0, 0.0, 1.0]) < 1e-5, axis=-1)
        no_ball = re.sub(r'<shape type="sphere" id="ball">.*?</shape>', "", text, flags=re.S)
        no_ball_img = np.array(mi.render(mi.load_string(no_ball), spp=FRAME_SPP, seed=5), np.float64)
    images = {
        "good": img,
        "albedo": albedo,
        "dark": dark_img,
        "dark_albedo": dark_albedo,
        "no_shadow": np.where(floor[..., None], no_ball_img, img),
        "flipped": albedo[::-1],
        "srgb": _srgb(albedo),
    }
    paths = {}
    for k, v in images.items():
        paths[k] = d / f"{k}.exr"
        write_exr(paths[k], {"RGB": v})
    return d, paths


def _run(frames, frame: str, albedo: str):
    d, p = frames
    return compare(
        SCENE, str(p[frame]), spp=SPP, cache=d / "cache", aov=f"albedo={p[albedo]}", metrics=("rmse",)
    )


def test_aligned_albedo_and_a_faithful_frame(frames):
    r = _run(frames, "good", "albedo")
    al = r.frames[0].aovs["albedo"]
    assert al["misaligned_fraction"] < 0.15 and not al["shapes_off"], al["text"]  # outlines: area vs centre
    split = al["split"]
    assert abs(split["albedo"]) < 0.01 and abs(split["lighting"]) <= 3 * split["lighting_uncertainty"] + 0.01
    params = r.results.cases[0].approximations[0].parameters  # results.json
    assert params["albedo_error"] == pytest.approx(split["albedo"])
    assert params["lighting_error"] == pytest.approx(split["lighting"])


def test_wrong_material_is_albedo_error(frames):
    r = _run(frames, "dark", "dark_albedo")
    al = r.frames[0].aovs["albedo"]
    assert list(al["shapes_off"]) == ["ball"], al["text"]
    ball = al["split"]["shapes"]["ball"]
    # The ball's radiance is half the reference's (direct light ∝ albedo): the albedo part ≈ −50 %, and its
    # lighting (the same lights, a little less of its own interreflection) within a few %.
    assert -0.55 < ball["albedo"] < -0.45, ball
    assert abs(ball["lighting"]) < 0.03, ball
    assert not r.frames[0].analysis.within_noise


def test_removed_shadow_is_lighting_error(frames):
    r = _run(frames, "no_shadow", "albedo")
    floor = r.frames[0].aovs["albedo"]["split"]["shapes"]["floor"]
    assert floor["lighting"] > 5 * floor["lighting_uncertainty"] and floor["lighting"] > 0.03, floor
    assert abs(floor["albedo"]) < 0.2 * floor["lighting"], floor


@pytest.mark.parametrize(("aov", "needle"), [("flipped", "upside down"), ("srgb", "sRGB-encoded")])
def test_misaligned_or_encoded_albedo_is_refused(frames, aov, needle):
    with pytest.raises(AuditError, match=needle) as e:
        _run(frames, "good", aov)
    assert "\n" not in str(e.value)


def test_an_unrelated_albedo_is_refused(frames, tmp_path):
    d, p = frames
    grey = tmp_path / "grey.exr"
    write_exr(grey, {"RGB": np.full((24, 24, 3), 0.05)})
    with pytest.raises(AuditError, match="not the scene's BSDF reflectance"):
        compare(SCENE, str(p["good"]), spp=SPP, cache=d / "cache", aov=f"albedo={grey}")
