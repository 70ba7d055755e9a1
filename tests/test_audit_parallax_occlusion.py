"""The parallax-occlusion family audits a user's scene (issue 30 §2): a floor whose BSDF is a ``bumpmap`` of a
bitmap height texture (tests/data/pom/bumped_floor.xml), against the floor displaced by that height field.

Expected values are independent of the code: the texture lookup against Mitsuba's own ``eval_1``; the
pixels' texture coordinates and tangent-space view vectors from the camera rays meeting the plane z = 0,
written here; the visible depth of a flat height field (h = ½: half the range, wherever the ray looks) and of
a linear ramp (the ray against the tilted plane z = −d·(1 − h(x)), solved here in closed form)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest
from click.testing import CliRunner

import rtfit
from rtfit.experiments.audit import AuditError
from rtfit.experiments.audit_cli import audit as audit_cli
from rtfit.experiments.audit_parallax_occlusion import POM_DEPTH_DEFAULT, check_pom_depth
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.parallax_occlusion import WRAP_MODES, HeightMap

DATA = Path(__file__).parent / "data" / "pom"
SCENE = DATA / "bumped_floor.xml"
EYE = np.array([0.0, -1.1, 1.1])


def _audit(tmp_path, height: str, rows, **kw):
    return rtfit.audit(SCENE, rows, defines={"height": height}, cache=tmp_path / "c",
                       metrics=("rmse", "max_abs"), cost_elements=4096, **kw)  # fmt: skip


def _floor_rays(case):
    """Per masked pixel: the floor point the camera ray meets on z = 0 (from the case's own (u₀, v₀): the
    floor is [−½, ½]², u = x + ½, v = y + ½) and the unit direction of that ray (from the eye)."""
    inp = case.channel_inputs[0]
    p = np.stack([inp["u0"] - 0.5, inp["v0"] - 0.5, np.zeros_like(inp["u0"])], axis=1)
    d = p - EYE
    return p, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_height_map_lookup_is_mitsubas_bitmap():
    """`HeightMap` (the kernel text's texture lookup) against Mitsuba's bitmap ``eval_1``: every wrap mode,
    bilinear and nearest, at coordinates well outside the tile."""
    mi.set_variant("llvm_ad_rgb")
    rng = np.random.default_rng(3)
    texels = rng.random((5, 7))
    uv = rng.uniform(-1.7, 2.4, (2000, 2))
    for wrap in WRAP_MODES:
        for filt in ("bilinear", "nearest"):
            tex = mi.load_dict({"type": "bitmap", "data": mi.TensorXf(texels[..., None].astype(np.float32)),
                                "raw": True, "wrap_mode": wrap, "filter_type": filt})  # fmt: skip
            si = mi.SurfaceInteraction3f()
            si.uv = mi.Point2f(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))
            want = np.array(tex.eval_1(si), np.float64)
            got = HeightMap(texels.astype(np.float32), wrap, filt == "nearest")(NUMPY_OPS, uv[:, 0], uv[:, 1])
            assert np.max(np.abs(got - want)) < 2e-6, (wrap, filt)


def test_flat_height_field_is_half_the_range_deep_for_every_row(tmp_path):
    """h = ½ everywhere: the displaced floor is the plane ½·d below it, so the visible depth is ½ of the range
    at every pixel, whatever the view; the listing and the stable march find it exactly. The inputs are the
    floor's own: (u₀, v₀) where the pixel's ray meets z = 0, V the unit vector to the eye (the floor's tangent
    frame is the world's: ∂p/∂u = x̂, ∂p/∂v = ŷ, one texture unit = one scene unit)."""
    r = _audit(tmp_path, "flat.exr", ["parallax-occlusion:pom-listing", "parallax-occlusion:pom-stable"])
    (case,) = r.cases
    assert set(r.outcomes[case.id]) == {"pom-listing", "pom-stable"}
    assert case.parameters["texel_length"] == pytest.approx(1.0, rel=1e-6)
    assert case.parameters["depth_scene"] == pytest.approx(POM_DEPTH_DEFAULT, rel=1e-6)
    assert case.parameters["pixels"] > 400
    ref = case.reference.mean[case.mask]
    assert np.allclose(ref, 0.5, atol=1e-6)
    for row in ("pom-listing", "pom-stable"):
        assert np.allclose(r.image(case.id, row)[case.mask], 0.5, atol=1e-6), row
    p, _ = _floor_rays(case)
    inp = case.channel_inputs[0]
    w = EYE - p
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    assert np.allclose(np.stack([inp["vx"], inp["vy"], inp["vz"]], axis=1), w, atol=2e-5)
    # every compared pixel's ray does meet the floor inside [−½, ½]²
    assert np.all(np.abs(p[:, :2]) <= 0.5 + 1e-5)


RAMP_DEPTH = 0.2


@pytest.fixture(scope="module")
def ramp(tmp_path_factory):
    """The ramp height field at --pom-depth `RAMP_DEPTH`, audited once for the two tests that read it: the
    shipped stable march (n 16…64) and the user's restatement of it (`my_stable_march`) on one case."""
    from rtfit.realtime.quantities import approximation

    mine = approximation(quantity="parallax_depth")(my_stable_march)
    rows = ["parallax-occlusion:pom-stable-n16-64", mine]
    return _audit(tmp_path_factory.mktemp("ramp"), "ramp.exr", rows, pom_depth=RAMP_DEPTH)


def test_ramp_against_the_closed_form_tilted_plane(ramp):
    """h = 0.1 + 0.8·u (texel centres of a 16-texel ramp along u, clamped beyond them), --pom-depth 0.2: the
    displaced floor is the plane z = −0.2·(0.9 − 0.8·u), u = x + ½. The ray from the eye meets it at the
    closed-form t below; the reference (Mitsuba's hit on the displaced mesh) and the stable march with
    n 16…64 (exact on a linear profile) give its depth −z/0.2 where the ray stays within the ramp."""
    d_range = RAMP_DEPTH
    r = ramp
    (case,) = r.cases
    assert case.parameters["pom_depth"] == d_range
    p, d = _floor_rays(case)
    # EYE + t·d on z = −D·(0.9 − 0.8·(x + ½)) = −D·(0.5 − 0.8·x)
    t = (-d_range * 0.5 + 0.8 * d_range * EYE[0] - EYE[2]) / (d[:, 2] - 0.8 * d_range * d[:, 0])
    hit = EYE + t[:, None] * d
    want = -hit[:, 2] / d_range
    lo, hi = 0.5 / 16, 1.0 - 0.5 / 16  # the texel centres: linear between them
    inside = (hit[:, 0] + 0.5 > lo) & (hit[:, 0] + 0.5 < hi) & (p[:, 0] + 0.5 > lo) & (p[:, 0] + 0.5 < hi)
    assert inside.sum() > 300
    ref = case.reference.mean[case.mask][:, 0]
    assert np.max(np.abs(ref[inside] - want[inside])) < 2e-5
    got = r.image(case.id, "pom-stable-n16-64")[case.mask][:, 0]
    assert np.max(np.abs(got[inside] - want[inside])) < 2e-5
    assert want[inside].min() < 0.3 and want[inside].max() > 0.7  # the ramp spans most of the range


@pytest.mark.parametrize("value", ["0", "5", "-0.1", "deep", "nan"])
def test_bad_pom_depth_is_one_line_and_exit_2(tmp_path, value):
    for extra in (["--list"], ["--out", str(tmp_path / "o")]):
        result = CliRunner().invoke(audit_cli, [str(SCENE), "--pom-depth", value, *extra])
        assert result.exit_code == 2, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("rtfit: error: --pom-depth"), result.output
    assert not (tmp_path / "o").exists()
    with pytest.raises(AuditError, match="--pom-depth"):
        rtfit.audit(SCENE, "parallax-occlusion", pom_depth=value, cache=tmp_path / "c")


def test_default_pom_depth_is_the_familys():
    assert check_pom_depth(None) == POM_DEPTH_DEFAULT == 0.1
    assert check_pom_depth("0.25") == 0.25


def test_list_names_the_family_with_its_reason(tmp_path):
    result = CliRunner().invoke(audit_cli, [str(SCENE), "--list"])
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert (
        "parallax-occlusion — height field: the bumpmap on the rectangle 'floor' (bumped_floor.xml line"
        in out
    )
    assert "marches it on the flat shape instead of displacing the mesh" in out
    assert (
        "methods:    pom-listing, pom-stable, pom-stable-n4-16, pom-stable-n16-64, pom-listing-shadow, "
        "pom-stable-shadow, listing-shadow, stable-shadow, pom-no-shadow" in out
    )


def test_a_normal_map_alone_does_not_apply_and_says_why(tmp_path):
    """A normal map stores normals, not heights: with only the normal-mapped square, the family is listed as
    not applying, with that reason."""
    shutil.copy(DATA / "flat_normals.exr", tmp_path / "flat_normals.exr")
    text = SCENE.read_text()
    start = text.index('<bsdf type="bumpmap">')
    text = text[:start] + text[text.index("</shape>", start) :]  # the floor keeps Mitsuba's default BSDF
    (tmp_path / "s.xml").write_text(text)
    result = CliRunner().invoke(audit_cli, [str(tmp_path / "s.xml"), "--list"])
    assert result.exit_code == 0, result.output
    line = next(x for x in result.stdout.splitlines() if x.strip().startswith("parallax-occlusion:"))
    assert "needs a shape whose BSDF is a bumpmap with a bitmap texture" in line
    assert "the normalmap on the rectangle 'tiles'" in line and "stores normals, not heights" in line


def test_a_one_channel_normal_map_is_refused_in_one_line(tmp_path):
    """A height map given to ``normalmap`` loads in Mitsuba and fails only inside a render (and in any later
    render while the scene lives: CI, stop 51): the audit refuses it before anything runs, exit 2."""
    shutil.copy(DATA / "flat.exr", tmp_path / "flat.exr")
    (tmp_path / "s.xml").write_text(SCENE.read_text().replace("flat_normals.exr", "flat.exr"))
    result = CliRunner().invoke(audit_cli, [str(tmp_path / "s.xml"), "--list"])
    assert result.exit_code == 2, result.output
    (line,) = result.output.strip().splitlines()
    assert line.startswith(f"rtfit: error: {tmp_path / 's.xml'} (line ")
    assert line.endswith(
        '<bsdf type="normalmap">: its texture has 1 channel(s); a normal map is an RGB image '
        "(Mitsuba fails at render time with it)"
    )


def test_toml_scene_with_the_bumped_floor_as_a_mitsuba_xml_shape(tmp_path):
    """rtfit TOML has no bump map of its own (its materials are diffuse); a ``mitsuba_xml`` shape keeps its
    file's BSDFs, so the same floor in a TOML scene (the XML's default height, h = ½) is audited alike: half
    the range deep for the reference and the stable march, the inputs those of the camera's floor rays."""
    toml = DATA / "bumped_floor.toml"
    listing = CliRunner().invoke(audit_cli, [str(toml), "--list"])
    assert listing.exit_code == 0, listing.output
    assert "parallax-occlusion — height field: the bumpmap on shapes[0] (xml0_" in listing.stdout
    r = rtfit.audit(toml, "parallax-occlusion:pom-stable", cache=tmp_path / "c", metrics=("rmse",),
                    cost_elements=4096)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["pixels"] > 400 and case.parameters["texel_length"] == pytest.approx(1.0, rel=1e-6)
    assert np.allclose(case.reference.mean[case.mask], 0.5, atol=1e-6)
    assert np.allclose(r.image(case.id, "pom-stable")[case.mask], 0.5, atol=1e-6)
    p, _ = _floor_rays(case)
    inp = case.channel_inputs[0]
    w = (EYE - p) / np.linalg.norm(EYE - p, axis=1, keepdims=True)
    assert np.allclose(np.stack([inp["vx"], inp["vy"], inp["vz"]], axis=1), w, atol=2e-5)


def test_a_toml_scene_without_a_bump_map_says_why(tmp_path):
    (tmp_path / "s.toml").write_text(
        (DATA / "bumped_floor.toml")
        .read_text()
        .replace(
            'type = "mitsuba_xml"\nfile = "bumped_floor.xml"',
            'type = "rectangle"\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 1.0]\nsize = [1.0, 1.0]',
        )
    )
    result = CliRunner().invoke(audit_cli, [str(tmp_path / "s.toml"), "--list"])
    assert result.exit_code == 0, result.output
    line = next(x for x in result.stdout.splitlines() if x.strip().startswith("parallax-occlusion:"))
    assert "rtfit TOML materials are diffuse" in line


def my_stable_march(ops, g):
    """The stable linear search + piecewise-linear hit, n = ⌊64 + N·V·(16 − 64)⌋ samples, typed through ops:
    P = s·V_xy/max(V_z, 0.05); the first t_i = 1 − i/n with h(uv₀ − P·i/n) > t_i and the sample before it
    give the crossing of the two segments; no crossing: the floor (depth 1)."""
    inv = 1.0 / ops.maximum(g.vz, 0.05)
    px, py = g.scale * g.vx * inv, g.scale * g.vy * inv
    n = ops.floor(64.0 + ops.clip(g.vz, 0.0, 1.0) * (16.0 - 64.0))
    h_prev = g.field(ops, g.u0, g.v0)
    found = h_prev > 2.0
    t1 = h1 = t2 = h2 = 0.0 * h_prev
    for i in range(1, 65):
        bound = 1.0 - i / n
        h = g.field(ops, g.u0 - px * (i / n), g.v0 - py * (i / n))
        active = (n >= i) & (found == False)  # noqa: E712
        hit = active & (h > bound)
        t1, h1 = ops.select(hit, bound, t1), ops.select(hit, h, h1)
        t2, h2 = ops.select(hit, bound + 1.0 / n, t2), ops.select(hit, h_prev, h2)
        found = found | hit
        h_prev = ops.select(active & (hit == False), h, h_prev)  # noqa: E712
    d1, d2 = t1 - h1, t2 - h2
    t = ops.select(found, (t1 * d2 - t2 * d1) / ops.select(found, d2 - d1, 1.0), 0.0)
    return 1.0 - t


def test_a_user_parallax_depth_reads_the_rows_own_height_field(ramp, tmp_path):
    """A user's ``@approximation(quantity="parallax_depth")`` restating the stable march (n 16 … 64) gives the
    shipped ``pom-stable-n16-64`` row's depths on the ramp (the same (u₀, v₀), view vector, height field and
    range through ``g``: measured max difference 2.2e-16, the user's i/n where the kernel writes i·(1/n)) and
    the displaced mesh's within 2e-5 (measured max 1.6e-5: the ramp is linear, the march exact); a user
    depth that takes √(h − ½) (NaN on the example field's lower half) is refused in one line
    before anything renders."""
    from rtfit.realtime.quantities import approximation

    r = ramp  # the ramp audited with the shipped row and the user's `my_stable_march` (fixture)
    (case,) = r.cases
    m = case.mask
    got, want = r.image(case.id, "my_stable_march")[m], r.image(case.id, "pom-stable-n16-64")[m]
    assert r.outcomes[case.id]["my_stable_march"].user
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    ref = case.reference.mean[m]
    assert np.max(np.abs(got - ref)) < 2e-5

    @approximation(quantity="parallax_depth")
    def root_height(ops, g):
        return ops.sqrt(g.field(ops, g.u0, g.v0) - 0.5)

    with pytest.raises(AuditError) as e:
        _audit(tmp_path, "ramp.exr", [root_height])
    msg = str(e.value)
    assert "\n" not in msg
    assert re.match(r"root_height: returned NaN at u0=\S+, v0=\S+ \(first of \d+ of 256 samples\)$", msg)


LIGHT_CENTRE = np.array([-2.0, -1.0, 2.5])


def _lit_scene(tmp_path) -> Path:
    """The test floor with a 1 × 1 square area light added (radiance 5, centred at `LIGHT_CENTRE`, facing the
    floor's centre), the height textures beside it."""
    for f in DATA.glob("*.exr"):
        shutil.copy(f, tmp_path / f.name)
    c = ", ".join(f"{x:g}" for x in LIGHT_CENTRE)
    light = (
        f'<shape type="rectangle" id="lamp"><transform name="to_world"><scale value="0.5"/>'
        f'<lookat origin="{c}" target="0, 0, 0" up="0, 0, 1"/></transform>'
        f'<emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>'
    )
    (tmp_path / "lit.xml").write_text(SCENE.read_text().replace("</scene>", light + "</scene>"))
    return tmp_path / "lit.xml"


def test_flat_height_field_casts_no_shadow(tmp_path):
    """h = ½ everywhere: the displaced floor is a plane, which shadows none of a light above it, so the
    reference visibility is exactly 1 (every light sample reaches the visible point; standard error 0). The
    stable shadow (clamped) is 1 after the march and at the exact point; the printed listing is over-bright:
    1 − max_f (−f·w_f·k) = 1 + k·min_f f·w_f = 1 + 0.5·0.88 before the remap, 0.6·1.44 + 0.4 = 1.264 after;
    no shadow is 1. The inputs are the floor's own: L the unit vector from the floor point under the pixel
    to the light's centre (the floor's tangent frame is the world's), (u, v) the texture coordinates where
    the pixel's ray meets the plane z = −d/2 (closed form). A user's ``parallax_shadow`` approximation reads
    the same inputs through ``g`` (here L_z, times h(u, v)/h(u, v) from the case's height field)."""
    from rtfit.realtime.quantities import approximation

    @approximation(quantity="parallax_shadow")
    def light_height(ops, g):
        return g.lz * g.field(ops, g.u, g.v) / ops.maximum(g.field(ops, g.u, g.v), 0.01)

    rows = ["parallax-occlusion", light_height]
    r = rtfit.audit(_lit_scene(tmp_path), rows, defines={"height": "flat.exr"}, spp=16, cache=tmp_path / "c",
                    metrics=("rmse",), cost_elements=4096, fit=False)  # fmt: skip
    depth_case, shadow = r.cases
    assert shadow.quantity == "parallax_shadow" and shadow.parameters["light"] == "lamp"
    assert shadow.parameters["pixels"] == depth_case.parameters["pixels"] > 400
    assert np.all(shadow.reference.mean[shadow.mask] == 1.0) and not shadow.reference.stderr.any()
    want = {"pom-stable-shadow": 1.0, "stable-shadow": 1.0, "pom-no-shadow": 1.0}
    want |= {"pom-listing-shadow": 1.264, "listing-shadow": 1.264}
    assert set(r.outcomes[shadow.id]) == set(want) | {"light_height"}
    for row, value in want.items():
        assert np.allclose(r.image(shadow.id, row)[shadow.mask], value, atol=1e-6), row
    p, d = _floor_rays(shadow)
    inp = shadow.channel_inputs[0]
    assert np.allclose(r.image(shadow.id, "light_height")[shadow.mask][:, 0], inp["lz"], atol=1e-6)
    to_light = (LIGHT_CENTRE - p) / np.linalg.norm(LIGHT_CENTRE - p, axis=1, keepdims=True)
    assert np.allclose(np.stack([inp["lx"], inp["ly"], inp["lz"]], axis=1), to_light, atol=2e-5)
    t = (-0.5 * POM_DEPTH_DEFAULT - EYE[2]) / d[:, 2]  # the ray from the eye meets z = −d/2
    hit = EYE + t[:, None] * d
    assert np.allclose(inp["u"], hit[:, 0] + 0.5, atol=2e-5) and np.allclose(
        inp["v"], hit[:, 1] + 0.5, atol=2e-5
    )


def test_a_scene_without_an_area_light_audits_no_shadow(tmp_path):
    """The test floor has only a constant sky: the depth case alone, and a note saying why."""
    r = _audit(tmp_path, "flat.exr", ["parallax-occlusion:pom-stable", "parallax-occlusion:stable-shadow"])
    (case,) = r.cases
    assert "the soft self-shadow is not audited: the scene has no area light" in case.notes
