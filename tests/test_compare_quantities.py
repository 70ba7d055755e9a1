"""``rtfit compare --quantity irradiance|ao|transmittance`` (issue 36) on 16 × 16 scenes with closed forms.

Independent values: the pixel-centre camera rays are Mitsuba's own ``sensor.sample_ray`` at (i + ½)/W,
(j + ½)/H; the hit on the plane z = 0 is the ray's closed-form intersection; a plane open to a constant
environment of radiance L has irradiance π·L and AO 1; a point light of intensity I at height h gives
E = I·h/r³ on the plane; a homogeneous cube of extinction σ transmits exp(−σ·chord) (slab test).
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.audit import AuditError
from rtfit.experiments.cli import cli
from rtfit.experiments.compare import compare
from rtfit.reference.io import write_exr

SPP = 64
SENSOR = """
    <sensor type="perspective">
        <float name="fov" value="50"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>"""
PLANE = """<shape type="rectangle" id="plane"><transform name="to_world"><scale value="20"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>"""


def _scene(path, body: str, origin="0, -2, 3", target="0, 0, 0") -> str:
    path.write_text(f'<scene version="3.0.0">{SENSOR.format(origin=origin, target=target)}{body}</scene>')
    return str(path)


def _rays(scene_path: str) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's pixel-centre camera rays of the scene's sensor: origins and unit directions (16, 16, 3)
    (the perspective camera starts each ray at its near clip distance)."""
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    with scoped_variant("llvm_ad_rgb"):
        sensor = mi.load_file(scene_path).sensors()[0]
        j, i = np.mgrid[0:16, 0:16]
        pos = mi.Point2f(
            ((i.ravel() + 0.5) / 16).astype(np.float32), ((j.ravel() + 0.5) / 16).astype(np.float32)
        )
        ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        o = np.asarray(ray.o, np.float64).T.reshape(16, 16, 3)
        d = np.asarray(ray.d, np.float64).T.reshape(16, 16, 3)
    return o, d / np.linalg.norm(d, axis=-1, keepdims=True)


def _frame(path, image) -> str:
    img = np.asarray(image, np.float64)
    write_exr(path, {"RGB": np.repeat(img[..., None], 3, axis=-1) if img.ndim == 2 else img})
    return str(path)


@pytest.fixture(scope="module")
def plane_env(tmp_path_factory):
    d = tmp_path_factory.mktemp("cq")
    return d, _scene(
        d / "plane_env.xml", PLANE + '<emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>'
    )


def test_irradiance_of_an_open_plane_is_pi_l(plane_env, tmp_path):
    d, scene = plane_env
    _, dirs = _rays(scene)
    ones = np.ones((16, 16))  # every pixel sees the plane (the camera looks down at it)
    assert np.all(dirs[..., 2] < 0)
    good = compare(scene, _frame(tmp_path / "e.exr", np.pi * 0.5 * ones), quantity="irradiance", spp=SPP,
                   cache=d / "cache")  # fmt: skip
    a = good.frames[0].analysis
    assert a.within_noise, a.verdict
    ref = good.reference
    assert np.all(np.abs(ref.mean - np.pi * 0.5) < 4.5 * ref.sigma())
    assert abs(ref.mean.mean() / (np.pi * 0.5) - 1) < 0.01
    bad = compare(scene, _frame(tmp_path / "s.exr", 1.1 * np.pi * 0.5 * ones), quantity="irradiance",
                  spp=SPP, cache=d / "cache")  # fmt: skip
    b = bad.frames[0].analysis
    assert not b.within_noise and abs(b.scale - 1.1) < 0.02, b.verdict


def test_ao_of_an_open_plane_is_one(plane_env, tmp_path):
    d, scene = plane_env
    good = compare(scene, _frame(tmp_path / "ao.exr", np.ones((16, 16))), quantity="ao", spp=SPP,
                   cache=d / "cache")  # fmt: skip
    assert good.frames[0].analysis.within_noise, good.frames[0].analysis.verdict
    assert np.all(good.reference.mean == 1.0)
    bad = compare(scene, _frame(tmp_path / "ao9.exr", 0.9 * np.ones((16, 16))), quantity="ao", spp=SPP,
                  cache=d / "cache")  # fmt: skip
    assert not bad.frames[0].analysis.within_noise


def test_ao_under_a_wall_matches_the_cosine_fraction(tmp_path):
    """An infinite-ish wall x = 0 (facing −x) beside the plane: a point at distance a from it, radius R ≥
    everything, sees AO = 1 − (1 − cos θ_w)/2 with the wall subtending the half space x > 0 beyond the
    point: the cosine-weighted fraction of the hemisphere on the far side of a vertical plane is 1/2, so
    AO = 1/2 wherever the wall is (practically) infinite: every pixel of the plane left of the wall."""
    wall = """<shape type="rectangle"><transform name="to_world"><scale value="200"/>
        <rotate y="1" angle="-90"/><translate x="0.05"/></transform></shape>"""
    scene = _scene(tmp_path / "wall.xml", PLANE + wall, origin="-3, -1, 2", target="-1, 0, 0")
    o, dirs = _rays(scene)
    t = -o[..., 2] / dirs[..., 2]
    x = o[..., 0] + t * dirs[..., 0]
    on_plane = (dirs[..., 2] < 0) & (x < 0)
    frame = np.where(on_plane, 0.5, 0.0)
    r = compare(scene, _frame(tmp_path / "w.exr", frame), quantity="ao", spp=SPP, cache=tmp_path / "c")
    m = r.mask & on_plane
    assert m.sum() > 100
    # the wall is 4000× wider than the distance to it: AO = 1/2 to within the noise (4σ) and 1e-3
    err = np.abs(r.reference.mean[m, 0] - 0.5)
    assert np.all(err < 4 * r.reference.sigma()[m, 0] + 1e-3)


def test_irradiance_of_a_point_light_on_a_plane(tmp_path):
    body = PLANE + '<emitter type="point"><point name="position" x="0.3" y="0.2" z="1.5"/>' \
        '<rgb name="intensity" value="2.0"/></emitter>'  # fmt: skip
    scene = _scene(tmp_path / "point.xml", body)
    o, dirs = _rays(scene)
    p = o + (-o[..., 2] / dirs[..., 2])[..., None] * dirs
    r = np.linalg.norm(p - [0.3, 0.2, 1.5], axis=-1)
    e = 2.0 * 1.5 / r**3  # indirect: 0 (the plane sees nothing but the dark sky)
    good = compare(scene, _frame(tmp_path / "e.exr", e), quantity="irradiance", spp=SPP, cache=tmp_path / "c")
    assert good.frames[0].analysis.within_noise, good.frames[0].analysis.verdict
    assert np.allclose(good.reference.mean[..., 0], e, rtol=1e-4)
    bad = compare(scene, _frame(tmp_path / "s.exr", 1.05 * e), quantity="irradiance", spp=SPP,
                  cache=tmp_path / "c")  # fmt: skip
    assert not bad.frames[0].analysis.within_noise


CUBE = """<shape type="cube"><transform name="to_world"><scale value="0.5"/><translate z="0.8"/></transform>
        <bsdf type="null"/><medium type="homogeneous" name="interior">
        <rgb name="albedo" value="0.5"/><float name="sigma_t" value="1.4"/></medium></shape>"""


def test_transmittance_through_a_homogeneous_cube(tmp_path):
    body = PLANE + CUBE + '<emitter type="constant"/>'
    scene = _scene(tmp_path / "cube.xml", body, origin="0.3, -2.5, 2.5", target="0, 0, 0.4")
    o, dirs = _rays(scene)
    lo, hi = np.array([-0.5, -0.5, 0.3]), np.array([0.5, 0.5, 1.3])
    with np.errstate(divide="ignore"):
        a, b = (lo - o) / dirs, (hi - o) / dirs
    t0 = np.max(np.minimum(a, b), axis=-1)
    t1 = np.min(np.maximum(a, b), axis=-1)
    chord = np.maximum(t1 - np.maximum(t0, 0.0), 0.0)
    assert (chord > 0).sum() > 20 and (chord == 0).sum() > 20
    t = np.exp(-1.4 * chord)
    good = compare(
        scene, _frame(tmp_path / "t.exr", t), quantity="transmittance", spp=SPP, cache=tmp_path / "c"
    )
    a = good.frames[0].analysis
    assert a.within_noise, a.verdict
    ref = good.reference
    assert np.all(np.abs(ref.mean[..., 0] - t) < 4 * ref.sigma()[..., 0] + 1e-6)
    bad = compare(scene, _frame(tmp_path / "s.exr", 0.95 * t), quantity="transmittance", spp=SPP,
                  cache=tmp_path / "c")  # fmt: skip
    assert not bad.frames[0].analysis.within_noise


def test_transmittance_without_a_medium_is_refused_in_one_line(plane_env, tmp_path):
    d, scene = plane_env
    frame = _frame(tmp_path / "t.exr", np.ones((16, 16)))
    with pytest.raises(AuditError, match="no medium"):
        compare(scene, frame, quantity="transmittance", cache=d / "cache")
    res = CliRunner().invoke(cli, ["compare", scene, frame, "--quantity", "transmittance", "--cache",
                                   str(d / "cache"), "--no-progress"])  # fmt: skip
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "no medium" in lines[0], res.output
    res = CliRunner().invoke(cli, ["compare", scene, frame, "--quantity", "ao", "--ao-radius", "-1"])
    assert res.exit_code == 2 and "--ao-radius" in res.output, res.output


def test_radiance_of_a_scene_without_an_integrator(plane_env, tmp_path):
    """No <integrator>: Mitsuba's default path tracer. The diffuse plane (ρ = 0.5) under the constant sky
    (L = 0.5) has radiance ρ·E/π = ρ·L = 0.25 (it sees nothing but the sky)."""
    d, scene = plane_env
    r = compare(scene, _frame(tmp_path / "l.exr", np.full((16, 16), 0.25)), spp=SPP, cache=d / "cache")
    assert r.frames[0].analysis.within_noise, r.frames[0].analysis.verdict
    assert "default" in r.reference.integrator
