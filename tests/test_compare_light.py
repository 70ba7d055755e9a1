"""The normal-to-light angle breakdown of ``rtfit compare`` (issue 36) on a 24 × 24 scene: a floor and a
ball under a directional light and a dim sky.

Independent values: n·l in closed form — the floor's normal is +z, the ball's (p − c)/r at the closed-form
intersection of Mitsuba's own pixel-centre camera ray (``sensor.sample_ray``) with the sphere, l = −the
light's direction; the frames are ``mi.render`` (box filter), one brightened ×1.5 on the pixels whose closed-
form n·l lies in (0, 0.25].
"""

from __future__ import annotations

import numpy as np
import pytest

from rtfit.experiments.compare import compare
from rtfit.experiments.compare_light import main_light, nl_bands
from rtfit.reference.io import write_exr

N = 24
DIRECTION = np.array([-0.5, 0.3, -0.6])
CENTRE, RADIUS = np.array([0.0, 0.0, 0.6]), 0.6
SCENE = f"""<scene version="3.0.0"><integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -4, 2.2" target="0, 0, 0.4" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="{N}"/><integer name="height" value="{N}"/>
            <rfilter type="box"/></film></sensor>
    <shape type="rectangle" id="floor"><transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></shape>
    <shape type="sphere" id="ball"><point name="center" x="0" y="0" z="0.6"/>
        <float name="radius" value="0.6"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.4"/></bsdf></shape>
    <emitter type="directional" id="sun"><vector name="direction" x="{DIRECTION[0]}" y="{DIRECTION[1]}"
        z="{DIRECTION[2]}"/><rgb name="irradiance" value="3"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="0.05"/></emitter>
</scene>"""


def _closed_form_nl(sensor, mi) -> np.ndarray:
    """n·l at each pixel-centre first hit (NaN: sky): the ball where the ray meets it first, else floor."""
    j, i = np.mgrid[0:N, 0:N]
    pos = mi.Point2f(((i.ravel() + 0.5) / N).astype(np.float32), ((j.ravel() + 0.5) / N).astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    o = np.asarray(ray.o, np.float64).T
    d = np.asarray(ray.d, np.float64).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    light = -DIRECTION / np.linalg.norm(DIRECTION)
    oc = o - CENTRE
    b = np.sum(oc * d, axis=1)
    disc = b * b - (np.sum(oc * oc, axis=1) - RADIUS**2)
    t_ball = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
    p_floor = o + t_floor[:, None] * d
    on_floor = np.isfinite(t_floor) & np.all(np.abs(p_floor[:, :2]) <= 3.0, axis=1)
    n_ball = (o + np.where(np.isfinite(t_ball), t_ball, 0.0)[:, None] * d - CENTRE) / RADIUS
    nl = np.where(
        np.isfinite(t_ball) & (t_ball < t_floor), n_ball @ light, np.where(on_floor, light[2], np.nan)
    )
    return nl.reshape(N, N)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    import mitsuba as mi

    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.variants import scoped_variant

    d = tmp_path_factory.mktemp("nl")
    path = d / "sun_ball.xml"
    path.write_text(SCENE)
    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(str(path))
        nl = _closed_form_nl(scene.sensors()[0], mi)
        light = main_light(mi, scene, gbuffer(mi, scene))
        img = np.array(mi.render(scene, spp=512, seed=5), np.float64)
    grazing = (nl > 0) & (nl <= 0.25)
    frames = {"good": img, "grazing": np.where(grazing[..., None], 1.5 * img, img)}
    for k, v in frames.items():
        write_exr(d / f"{k}.exr", {"RGB": v})
    return d, path, nl, light, grazing


def test_main_light_and_its_nl_match_the_closed_form(setup):
    _, _, nl, light, _ = setup
    assert light is not None and light.name.endswith("sun") and light.share > 0.8, (light.name, light.share)
    both = np.isfinite(nl) & np.isfinite(light.nl)
    assert both.sum() > 0.6 * N * N and np.array_equal(np.isfinite(nl), np.isfinite(light.nl))
    assert np.max(np.abs(light.nl[both] - nl[both])) < 1e-4
    labels, names = nl_bands(light.nl)
    assert len(names) == 5 and names[0].startswith("n·l ≤ 0")
    assert set(np.unique(labels[both])) == {0, 1, 2, 3, 4}  # the ball shows every band


def test_error_on_grazing_pixels_is_found_in_its_band(setup):
    d, path, _, _, grazing = setup
    assert grazing.sum() >= 8
    good = compare(str(path), str(d / "good.exr"), spp=128, cache=d / "cache")
    assert good.frames[0].analysis.within_noise, good.frames[0].analysis.verdict
    r = compare(str(path), str(d / "grazing.exr"), spp=128, cache=d / "cache")
    a = r.frames[0].analysis
    title = next(t for t in a.groups if t.startswith("n·l band"))
    assert "sun" in title
    bands = {e.name.split(" (")[0]: e for e in a.groups[title]}
    hit = bands["n·l 0–0.25"]
    assert not hit.within_noise and 0.3 < hit.bias < 0.6, hit.words()
    for name in ("n·l 0.5–0.75", "n·l 0.75–1"):
        assert bands[name].within_noise, bands[name].words()
    rows = r.results.extra["breakdowns"][r.frames[0].id][title]
    assert {row["name"] for row in rows} == {e.name for e in a.groups[title]}
    assert any(row["name"].startswith("n·l 0–0.25") and not row["within_noise"] for row in rows)
