"""``rtfit compare`` (issue 36): frames of the 24 × 24 test scene tests/data/compare/two_shapes.xml rendered
by plain Mitsuba (``mi.render``, box filter: each pixel's area average) against rtfit's reference of the same
scene.

Independent values: the frame is Mitsuba's own renderer at 4× the reference's samples (not rtfit's passes);
the ×1.1 frame's scale is known by construction; the shifted frame is ``np.roll`` by one pixel;
the depth AOV is Mitsuba's ``aov`` integrator; the PNG decode is the closed-form sRGB transfer function.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.audit import AuditError
from rtfit.experiments.cli import cli
from rtfit.experiments.compare import compare, render_size
from rtfit.experiments.compare_frames import read_frame
from rtfit.reference.io import write_exr

SCENE = Path(__file__).parent / "data" / "compare" / "two_shapes.xml"
SPP = 128
FRAME_SPP = 512


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    d = tmp_path_factory.mktemp("compare")
    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(str(SCENE))
        depth_aov = mi.load_dict({"type": "aov", "aovs": "dd:depth"})
        img = np.array(mi.render(scene, spp=FRAME_SPP, seed=7), dtype=np.float64)
        depth = np.array(mi.render(scene, integrator=depth_aov, spp=16))
        # Shadows removed: the floor's pixels (every sample on the floor: Mitsuba's geo_normal AOV is
        # exactly the floor's +z there) from the scene without the ball, every other pixel from the full one.
        normal = mi.load_dict({"type": "aov", "aovs": "nn:geo_normal"})
        n = np.array(mi.render(scene, integrator=normal, spp=16), dtype=np.float64)
        floor = np.all(np.abs(n - [0.0, 0.0, 1.0]) < 1e-5, axis=-1)
        text = re.sub(r'<shape type="sphere" id="ball">.*?</shape>', "", SCENE.read_text(), flags=re.S)
        no_ball = np.array(mi.render(mi.load_string(text), spp=FRAME_SPP, seed=8), dtype=np.float64)
        no_shadow = np.where(floor[..., None], no_ball, img)
        big = np.array(mi.render(mi.load_string(SCENE.read_text().replace('value="24"', 'value="48"')),
                                 spp=FRAME_SPP, seed=9), dtype=np.float64)  # fmt: skip
        wide = SCENE.read_text().replace('name="fov" value="40"', 'name="fov" value="50"')
        wide_depth = np.array(mi.render(mi.load_string(wide), integrator=depth_aov, spp=16))
        normals = np.array(
            mi.render(scene, integrator=mi.load_dict({"type": "aov", "aovs": "nn:sh_normal"}), spp=16)
        )
        # Half a pixel lower: each pixel the mean of 2×2 depths of the 48×48 film one fine row down.
        fine_text = SCENE.read_text().replace('value="24"', 'value="48"')
        fine = np.array(mi.render(mi.load_string(fine_text), integrator=depth_aov, spp=16))[..., 0]
        fine = np.pad(fine, ((0, 1), (0, 0)), mode="edge")
        half_depth = fine[1:49].reshape(24, 2, 24, 2).mean(axis=(1, 3))
    padded = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    blurred = sum(padded[1 + dy : 25 + dy, 1 + dx : 25 + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9
    paths = {
        "good": d / "good.exr",
        "bright": d / "bright.exr",
        "shift": d / "shift.exr",
        "depth": d / "depth.exr",
        "flipped": d / "flipped.exr",
        "no_shadow": d / "no_shadow.exr",
        "blurred": d / "blurred.exr",
        "big": d / "big.exr",
        "wide_depth": d / "wide_depth.exr",
        "half_depth": d / "half_depth.exr",
    }
    # The normal AOV in the conventions engines use; the camera's axes from the XML's lookat.
    f = np.array([0.0, 4.0, -1.8]) / np.linalg.norm([0.0, 4.0, -1.8])
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, f)
    n = normals.astype(np.float64)
    conventions = {
        "n_world": n,
        "n_encoded": 0.5 * n + 0.5,
        "n_yup": np.stack([n[..., 0], n[..., 2], -n[..., 1]], axis=-1),
        "n_view_gl": np.stack([n @ right, n @ up, -(n @ f)], axis=-1),
        "n_random": np.random.default_rng(1).normal(size=n.shape),
    }
    conventions["n_random"] /= np.linalg.norm(conventions["n_random"], axis=-1, keepdims=True)
    for name, v in conventions.items():
        paths[name] = d / f"{name}.exr"
        write_exr(paths[name], {"RGB": v})
    write_exr(paths["good"], {"RGB": img})
    write_exr(paths["bright"], {"RGB": 1.1 * img})
    write_exr(paths["shift"], {"RGB": np.roll(img, 1, axis=1)})  # frame[y, x] = image[y, x − 1]
    write_exr(paths["depth"], {"Z": depth[..., 0]})
    write_exr(paths["flipped"], {"Z": depth[::-1, :, 0].copy()})
    write_exr(paths["no_shadow"], {"RGB": no_shadow})
    write_exr(paths["blurred"], {"RGB": blurred})
    write_exr(paths["big"], {"RGB": big})
    write_exr(paths["wide_depth"], {"Z": wide_depth[..., 0]})
    write_exr(paths["half_depth"], {"Z": half_depth})
    return d, paths


@pytest.fixture(scope="module")
def result(frames):
    d, p = frames
    return compare(SCENE, [str(p["good"]), str(p["bright"]), str(p["shift"])], spp=SPP, cache=d / "cache",
                   aov=f"depth={p['depth']}", metrics=("rmse", "rel_mse", "ssim"))  # fmt: skip


def test_mitsuba_frame_is_within_noise(result):
    a = result.frame("good.exr").analysis
    assert a.within_noise, a.verdict
    assert abs(a.scale - 1.0) <= 4 * a.scale_stderr
    assert not a.misaligned
    assert not a.metrics["rmse"].resolved
    assert 0.8 < a.z["std"] < 1.4  # the frame's own noise (4× the samples) adds ≈ 12 %
    assert all(e.within_noise for e in a.shapes), [e.words() for e in a.shapes]
    assert {e.name for e in a.shapes} == {"floor", "ball", "no surface (background)"}


def test_scaled_frame_is_flagged_with_its_scale(result):
    a = result.frame("bright.exr").analysis
    assert not a.within_noise
    assert a.scale == pytest.approx(1.1, abs=0.01)
    assert abs(a.scale - 1.1) <= 4 * a.scale_stderr
    assert not a.scale_consistent
    assert f"scale ×{a.scale:.4g}" in a.verdict
    assert all(e.bias == pytest.approx(0.1, abs=0.03) for e in a.shapes if e.index >= 0)


def test_shifted_frame_gives_registration_offset(result):
    a = result.frame("shift.exr").analysis
    assert a.offset == (1, 0) and a.misaligned
    assert "misaligned" in a.verdict


def test_removed_shadows_are_on_the_floor(frames):
    d, p = frames
    r = compare(SCENE, str(p["no_shadow"]), spp=SPP, cache=d / "cache", metrics=("rmse",))
    a = r.frames[0].analysis
    assert not a.within_noise and not a.misaligned
    by = {e.name: e for e in a.shapes}
    assert not by["floor"].within_noise and by["floor"].bias > 0  # brighter where its shadow was
    assert by["ball"].within_noise, by["ball"].words()
    assert "error on floor" in a.verdict
    bsdfs = {e.name: e for e in a.groups["BSDF at the first hit"]}
    assert not bsdfs["SmoothDiffuse of floor"].within_noise and bsdfs["SmoothDiffuse of ball"].within_noise
    bands = a.groups["first-hit distance band"]
    assert sum(e.pixels for e in bands) == 24 * 24 and len(bands) == 4  # near, middle, far, no surface


def test_blurred_frame_has_structured_error_at_outlines(frames):
    d, p = frames
    r = compare(SCENE, str(p["blurred"]), spp=SPP, cache=d / "cache", metrics=("rmse",))
    a = r.frames[0].analysis
    assert not a.within_noise and not a.misaligned
    assert a.edge_share >= 0.5 and "structured error at shape outlines" in a.verdict


def test_frame_at_twice_the_film_size(frames):
    d, p = frames
    r = compare(SCENE, str(p["big"]), spp=4 * SPP, cache=d / "cache", metrics=("rmse",))
    assert r.reference.mean.shape == (48, 48, 3)
    assert r.frames[0].analysis.within_noise, r.frames[0].analysis.verdict


@pytest.mark.parametrize(
    ("aov", "convention", "encoding"),
    [
        ("n_world", "world space with the scene's axes", "stored as they are"),
        ("n_encoded", "world space with the scene's axes", "encoded as n/2 + ½"),
        ("n_yup", "world space with Y up (the scene's z)", "stored as they are"),
        ("n_view_gl", "view space looking down −z (OpenGL)", "stored as they are"),
    ],
)
def test_normal_aov_conventions(frames, aov, convention, encoding):
    d, p = frames
    r = compare(SCENE, str(p["good"]), spp=SPP, cache=d / "cache", aov=f"normal={p[aov]}", metrics=("rmse",))
    a = r.frames[0].aovs["normal"]
    assert (a["convention"], a["encoding"]) == (convention, encoding)
    assert a["median_angle_deg"] < 1.0 and a["misaligned_fraction"] < 0.1  # edge pixels: blended normals


def test_random_normals_are_refused(frames):
    d, p = frames
    with pytest.raises(AuditError, match="normals do not match the scene's in any convention"):
        compare(SCENE, str(p["good"]), spp=SPP, cache=d / "cache", aov=f"normal={p['n_random']}")


def test_depth_aov_alignment(result):
    dep = result.frames[0].aovs["depth"]
    assert dep["convention"] == "ray distance"
    assert (
        dep["misaligned_fraction"] < 0.15
    )  # edge pixels: the AOV averages over the pixel, Mitsuba's hit is central


def test_fit_exposure_separates_the_scale(frames):
    d, p = frames
    r = compare(SCENE, str(p["bright"]), spp=SPP, cache=d / "cache", fit_exposure=True, metrics=("rmse",))
    a = r.frames[0].analysis
    assert a.within_noise, a.verdict
    assert a.scale == pytest.approx(1.1, abs=0.01)
    assert np.allclose(r.frames[0].image, r.frames[0].frame.image / a.scale)


def test_flipped_depth_is_refused(frames):
    d, p = frames
    with pytest.raises(AuditError, match="upside down"):
        compare(SCENE, str(p["good"]), spp=SPP, cache=d / "cache", aov=f"depth={p['flipped']}")


def test_other_fov_is_refused_in_one_line(frames):
    d, p = frames
    args = [str(SCENE), str(p["good"]), "--aov", f"depth={p['wide_depth']}", "--cache", str(d / "cache")]
    _one_line_exit_2(args, "its field of view differs")


def test_half_pixel_offset_is_refused(frames):
    d, p = frames
    with pytest.raises(
        AuditError, match=r"offset by half a pixel \(its depth matches at \(\+0\.0, -0\.5\) px\)"
    ):
        compare(SCENE, str(p["good"]), spp=SPP, cache=d / "cache", aov=f"depth={p['half_depth']}")


def test_cli_writes_the_report_and_exits_1_on_a_flagged_frame(frames):
    d, p = frames
    out = d / "out"
    runner = CliRunner()
    common = [str(SCENE), "--spp", str(SPP), "--cache", str(d / "cache"), "--out", str(out), "--no-progress"]
    res = runner.invoke(cli, ["compare", *common[:1], str(p["good"]), *common[1:]])
    assert res.exit_code == 0, res.output
    assert "within the reference's noise" in res.output
    doc = json.loads((out / "compare-two_shapes" / "results.json").read_text())
    assert doc["schema"] == "rtfit.results/1" and doc["experiment"] == "compare"
    assert doc["cases"][0]["approximations"][0]["method"] == "good"
    for name in ("report.html", "report.md", "tables.tex", "pixels/radiance.exr", "figures/good_z.png"):
        assert (out / "compare-two_shapes" / name).is_file(), name
    res = runner.invoke(cli, ["compare", *common[:1], str(p["bright"]), *common[1:]])
    assert res.exit_code == 1, res.output
    assert "differs: scale ×1.0" in res.output or "differs: scale ×1.1" in res.output


def _one_line_exit_2(args, needle):
    res = CliRunner().invoke(cli, ["compare", *args])
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("rtfit: error:") and needle in lines[0], res.output


def test_bad_frames_are_one_line_exit_2(frames, tmp_path):
    d, p = frames
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr at all")
    small = tmp_path / "small.exr"
    write_exr(small, {"RGB": np.ones((24, 25, 3))})
    nan = tmp_path / "nan.exr"
    write_exr(nan, {"RGB": np.full((24, 24, 3), np.nan)})
    cache = ["--cache", str(d / "cache")]
    _one_line_exit_2([str(SCENE), str(tmp_path / "missing.exr"), *cache], "no such file")
    _one_line_exit_2([str(SCENE), str(junk), *cache], "not a readable OpenEXR file")
    _one_line_exit_2([str(SCENE), str(small), *cache], "not one integer factor apart")
    _one_line_exit_2([str(SCENE), str(nan), *cache], "not finite")
    _one_line_exit_2([str(SCENE), f"{p['good']}:beauty", *cache], "no layer 'beauty'")
    _one_line_exit_2([str(SCENE), str(tmp_path / "frame.jpg"), *cache], "no such file")
    _one_line_exit_2([str(SCENE), *cache], "no frame to compare")
    _one_line_exit_2([str(SCENE), str(p["good"]), "--aov", "motion=a.exr", *cache], "not read yet")


def test_render_size_integer_factors():
    assert render_size((24, 24), (48, 48), "f") == (48, 48)
    assert render_size((48, 32), (24, 16), "f") == (24, 16)
    with pytest.raises(AuditError, match="integer factor"):
        render_size((24, 24), (48, 24), "f")


def test_8bit_png_frame_is_within_noise_with_its_steps(frames):
    """An 8-bit sRGB PNG of the faithful frame: its steps (≈ 0.4 % at mid-grey, more than the sky's
    noiseless reference allows) join σ, so it is within noise; its encoding is stated."""
    from matplotlib import image as mpimg

    d, p = frames
    img = read_frame(str(p["good"])).image
    code = np.where(img <= 0.0031308, 12.92 * img, 1.055 * np.clip(img, 0, 1) ** (1 / 2.4) - 0.055)
    mpimg.imsave(d / "good.png", np.round(np.clip(code, 0, 1) * 255).astype(np.uint8))
    r = compare(SCENE, str(d / "good.png"), spp=SPP, cache=d / "cache", metrics=("rmse",))
    f = r.frames[0]
    assert f.frame.encoding.startswith("PNG 8-bit, sRGB") and f.frame.precision is not None
    assert f.analysis.within_noise, f.analysis.verdict


def test_radiance_hdr_frame(tmp_path):
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    values = np.full((4, 5, 3), [0.5, 2.0, 8.0], np.float32)  # powers of two: exact in RGBE
    with scoped_variant("scalar_rgb"):
        mi.Bitmap(values).write(str(tmp_path / "f.hdr"))
    f = read_frame(str(tmp_path / "f.hdr"))
    assert "RGBE" in f.encoding and f.image.shape == (4, 5, 3)
    assert np.allclose(f.image, values)


def test_png_srgb_decoded(tmp_path):
    from matplotlib import image as mpimg

    png = tmp_path / "f.png"
    mpimg.imsave(png, np.full((4, 4, 3), 128, np.uint8))
    f = read_frame(str(png))
    assert "sRGB" in f.encoding
    assert f.image[0, 0, 0] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4, rel=1e-6)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """The test scene with a second sensor beside the first, and a faithful frame through each."""
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    d = tmp_path_factory.mktemp("sequence")
    text = SCENE.read_text()
    first = text[text.index("<sensor") : text.index("</sensor>") + len("</sensor>")]
    second = first.replace('origin="0, -4, 2.2"', 'origin="0.3, -4, 2.2"')
    xml = d / "two_views.xml"
    xml.write_text(text.replace(first, first + "\n    " + second))
    paths = []
    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(str(xml))
        for i in range(2):
            img = np.array(mi.render(scene, sensor=i, spp=FRAME_SPP, seed=20 + i), dtype=np.float64)
            paths.append(d / f"view{i}.exr")
            write_exr(paths[-1], {"RGB": img})
            if i == 1:
                paths.append(d / "view1_flicker.exr")  # a probe that pops: 30 % brighter for one frame
                write_exr(paths[-1], {"RGB": 1.3 * img})
    return d, xml, paths


def test_sequence_through_each_sensor_is_stable(sequence):
    d, xml, (v0, v1, _) = sequence
    r = compare(xml, [str(v0), str(v1)], spp=SPP, cache=d / "cache", camera_path="sensors", metrics=("rmse",))
    assert [r.camera_of_case[f.case] for f in r.frames] == [0, 1]
    assert len(r.references) == 2 and all(f.analysis.within_noise for f in r.frames)
    (step,) = r.temporal
    assert step["stable"] and step["reference_change"] > 0  # the view moved, the error held still


def test_sequence_flicker_is_flagged(sequence):
    d, xml, (v0, _, bright) = sequence
    r = compare(
        xml, [str(v0), str(bright)], spp=SPP, cache=d / "cache", camera_path="sensors", metrics=("rmse",)
    )
    (step,) = r.temporal
    assert not step["stable"] and step["error_change"] > 2 * step["noise_floor"]
    assert "flickers" in r.results.summary


def test_static_sequence_flicker_and_plain_frames_without_one(frames):
    d, p = frames
    r = compare(SCENE, [str(p["good"]), str(p["bright"])], spp=SPP, cache=d / "cache", camera_path="static",
                metrics=("rmse",))  # fmt: skip
    assert len(r.references) == 1 and len(r.temporal) == 1  # one view, a frame that pops by 10 %
    r = compare(SCENE, [str(p["good"]), str(p["bright"])], spp=SPP, cache=d / "cache", metrics=("rmse",))
    assert r.temporal == []  # frames given without --camera-path are not a sequence


def test_sequence_with_more_frames_than_sensors_is_one_line(sequence):
    d, xml, (v0, v1, bright) = sequence
    args = [str(xml), str(v0), str(v1), str(bright), "--camera-path", "sensors", "--cache", str(d / "cache")]
    _one_line_exit_2(args, "--camera 2")


def test_each_cameras_case_holds_its_own_mask():
    """Two cameras that see different pixels (a surface quantity's mask is the pixels on a surface): each
    case of the result is compared on its own camera's pixels, not on the last camera's (the case used to
    take ``CompareResult.mask``, the last one's, for every camera)."""
    from types import SimpleNamespace

    from rtfit.experiments.audit_setup import AuditReference
    from rtfit.experiments.compare import CompareResult

    masks = [np.zeros((4, 5), bool) for _ in range(2)]
    masks[0][:2] = True  # camera 0 sees the top rows' surface, camera 1 the bottom ones
    masks[1][2:] = True
    refs = {
        f"cam{i}": AuditReference.deterministic(m, np.full((m.sum(), 3), 1.0 + i), (i,), 0, "q", "i", "r")
        for i, m in enumerate(masks)
    }
    info = SimpleNamespace(source="two_views.xml")
    result = CompareResult(info, refs, [], {}, masks[-1], "irradiance", camera_of_case={"cam0": 0, "cam1": 1})
    for case, mask in zip(result.cases, masks, strict=True):
        assert np.array_equal(case.mask, mask)
        assert np.all(case.reference.mean[mask] == case.reference.mean[mask][0])  # its own pixels hold values
