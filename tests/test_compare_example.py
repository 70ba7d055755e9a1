"""The worked example of docs/compare.md, "A frame from real-time approximations" (issue 36): the frame that
``examples/realtime_frame.py`` composes from rtfit's own approximations (light-model rows, hard shadow rays,
SH L2 sky) of tests/data/compare/two_shapes.xml, judged by ``rtfit compare`` (24 × 24, reference 64 spp).

Independent values: each pixel's first hit in closed form (Mitsuba's own pixel-centre camera ray,
``sensor.sample_ray``, met with the floor z = 0 and the ball |p − c| = r), and which of those points see the
whole lamp, none of it, or part of it (segments to a 9 × 9 grid over the lamp's square against the ball and
the ball's own tangent plane): where the whole lamp is seen, the polygon row with a hard shadow is Lambert's
exact irradiance, so the frame equals the direct reference within its noise; where none is seen, both are 0;
the frame holds no bounce light, so the ball's underside, lit in the reference by the floor, is too dark.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.audit import AuditError
from rtfit.experiments.compare import compare
from rtfit.reference.io import write_exr

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "compare" / "two_shapes.xml"
N = 24
CENTRE, RADIUS = np.array([0.0, 0.0, 0.6]), 0.6
LAMP_X, LAMP_Y, LAMP_Z = (0.3, 1.3), (-1.0, 0.0), 3.0  # the lamp: scale 0.5, turned to face −z, moved


def _example():
    spec = importlib.util.spec_from_file_location("realtime_frame", ROOT / "examples" / "realtime_frame.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("realtime_frame", module)  # (its dataclass looks its module up)
    spec.loader.exec_module(module)
    return module


def _hits(scene_path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points (N, N, 3), normals, shape: 0 floor, 1 ball, −1 sky) of the pixel-centre rays, closed form."""
    import mitsuba as mi

    from rtfit.reference.variants import scoped_variant

    with scoped_variant("llvm_ad_rgb"):
        sensor = mi.load_file(str(scene_path)).sensors()[0]
        j, i = np.mgrid[0:N, 0:N]
        pos = mi.Point2f(
            ((i.ravel() + 0.5) / N).astype(np.float32), ((j.ravel() + 0.5) / N).astype(np.float32)
        )
        ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        o, d = np.asarray(ray.o, np.float64).T, np.asarray(ray.d, np.float64).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    oc = o - CENTRE
    b = np.sum(oc * d, axis=1)
    disc = b * b - (np.sum(oc * oc, axis=1) - RADIUS**2)
    t_ball = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t_floor = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
    on_floor = np.isfinite(t_floor) & np.all(np.abs((o + np.nan_to_num(t_floor)[:, None] * d)[:, :2]) <= 3, 1)
    t_floor = np.where(on_floor, t_floor, np.inf)
    ball = t_ball < t_floor
    t = np.where(ball, t_ball, t_floor)
    p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    n = np.where(ball[:, None], (p - CENTRE) / RADIUS, [0.0, 0.0, 1.0])
    shape = np.where(ball, 1, np.where(on_floor, 0, -1))
    return p.reshape(N, N, 3), n.reshape(N, N, 3), shape.reshape(N, N)


def _lamp_seen(p, n, shape) -> np.ndarray:
    """The fraction of a 9 × 9 grid over the lamp seen from each point (NaN: sky): a segment to a lamp point
    is blocked by the ball (floor points: it passes within r of the centre) or by the ball's own tangent
    plane (ball points); a margin of 10⁻³ counts a grazing segment as blocked."""
    gx, gy = np.meshgrid(np.linspace(*LAMP_X, 9), np.linspace(*LAMP_Y, 9))
    q = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, LAMP_Z)], axis=1)
    seg = q[None, :, :] - p.reshape(-1, 1, 3)  # (pixels, 81, 3)
    s = np.clip(np.sum((CENTRE - p.reshape(-1, 1, 3)) * seg, -1) / np.sum(seg * seg, -1), 0.0, 1.0)
    gap = np.linalg.norm(p.reshape(-1, 1, 3) + s[..., None] * seg - CENTRE, axis=-1)
    above = np.sum(seg * n.reshape(-1, 1, 3), -1) > 1e-3
    on_ball = (shape.reshape(-1) == 1)[:, None]
    seen = np.where(on_ball, above, (gap > RADIUS + 1e-3) & above)
    return np.where(shape.reshape(-1) >= 0, seen.mean(axis=1), np.nan).reshape(N, N)


def test_realtime_frame_direct_light_is_exact_where_the_whole_lamp_is_seen(tmp_path):
    """The scene without its sky (the lamp alone): the frame against ``--quantity direct`` is within the
    reference's noise on every pixel that sees the whole lamp, and 0 like the reference where none of it is
    seen; its depth and normal AOVs are accepted as aligned (none off)."""
    scene = tmp_path / "lamp_only.xml"
    scene.write_text(re.sub(r'<emitter type="constant">.*?</emitter>', "", SCENE.read_text(), flags=re.S))
    frame = _example().realtime_frame(scene)
    write_exr(tmp_path / "f.exr", {"RGB": frame.radiance})
    write_exr(tmp_path / "d.exr", {"Z": frame.depth})
    write_exr(tmp_path / "n.exr", {"RGB": frame.normal})
    aov = f"depth={tmp_path / 'd.exr'},normal={tmp_path / 'n.exr'}"
    r = compare(scene, str(tmp_path / "f.exr"), quantity="direct", spp=64, pass_spp=32, footprint="centre",
                aov=aov, cache=tmp_path / "cache", seed=1)  # fmt: skip
    (out,) = r.frames
    ref = next(iter(r.references.values()))
    mean, sigma = ref.mean.reshape(N, N, 3), ref.stderr.reshape(N, N, 3)
    assert out.aovs["depth"]["misaligned_fraction"] == 0.0
    assert out.aovs["normal"]["median_angle_deg"] < 0.01
    p, n, shape = _hits(scene)
    seen = _lamp_seen(p, n, shape)
    full, none = seen == 1.0, seen == 0.0
    assert full.sum() > 200 and none.sum() >= 5  # the lit floor and ball; the umbra and the ball's night side
    f = out.frame.image
    z = (f[full] - mean[full]) / sigma[full]
    assert abs(float(z.mean())) < 0.3 and float(np.sqrt(np.mean(z**2))) < 1.5
    assert abs(float(np.sum(f[full] - mean[full]) / np.sum(mean[full]))) < 0.01
    np.testing.assert_array_equal(f[none], 0.0)
    np.testing.assert_array_equal(mean[none], 0.0)
    black = next(s for s in out.analysis.shapes if s.index == -1)  # no sky: black in both (was a NaN bias)
    assert black.bias == 0.0 and black.within_noise


def test_realtime_frame_lacks_bounce_light_on_the_balls_underside(tmp_path):
    """The scene as it is (lamp + sky, the scene's path integrator): the frame, without bounce light, is too
    dark on the ball's underside (normals pointing down, n_z < −0.3: lit by the floor in the reference) far
    beyond the noise, the sky it shows is the reference's exactly, and compare names the ball's error."""
    frame = _example().realtime_frame(SCENE)
    write_exr(tmp_path / "f.exr", {"RGB": frame.radiance})
    r = compare(SCENE, str(tmp_path / "f.exr"), spp=64, pass_spp=32, footprint="centre",
                cache=tmp_path / "cache", seed=0)  # fmt: skip
    (out,) = r.frames
    ref = next(iter(r.references.values()))
    mean, sigma = ref.mean.reshape(N, N, 3), ref.stderr.reshape(N, N, 3)
    _p, n, shape = _hits(SCENE)
    under = (shape == 1) & (n[..., 2] < -0.3)
    assert under.sum() >= 5
    f = out.frame.image
    deficit = np.sum(f[under] - mean[under]) / np.sqrt(np.sum(sigma[under] ** 2))
    assert deficit < -5.0  # the missing bounce, in standard errors of the summed reference
    assert np.sum(f[under]) < 0.8 * np.sum(mean[under])
    sky = shape == -1
    np.testing.assert_allclose(f[sky], mean[sky], rtol=1e-6)
    ball = next(s for s in out.analysis.shapes if s.name.startswith("ball"))
    assert ball.bias < 0 and not ball.within_noise
    assert out.analysis.verdict.startswith("differs")


# ------------------------------------------------ image flips told from the normals alone (--aov normal only)
@pytest.mark.parametrize(
    ("turn", "needle"),
    [
        (np.s_[::-1, :], "its image is upside down"),
        (np.s_[:, ::-1], "its image is mirrored"),
        (np.s_[::-1, ::-1], "its image is rotated by 180°"),
    ],
)
def test_a_flipped_normal_aov_is_refused_naming_the_flip(tmp_path, turn, needle):
    """The closed-form normals of the scene's pixel-centre hits, turned: refused in one line naming the flip,
    before anything renders. (The mirrored image of this nearly symmetric view differs only on the ball's
    pixels, about a sixth of the surface: its median angle alone would have accepted it.)"""
    _p, n, shape = _hits(SCENE)
    normals = np.where((shape >= 0)[..., None], n, 0.0)
    write_exr(tmp_path / "n.exr", {"RGB": normals[turn]})
    write_exr(tmp_path / "f.exr", {"RGB": np.zeros((N, N, 3))})
    with pytest.raises(AuditError, match=f"--aov normal .*does not match the scene's sensor: {needle}") as e:
        compare(SCENE, str(tmp_path / "f.exr"), aov=f"normal={tmp_path / 'n.exr'}", spp=4, pass_spp=2,
                cache=tmp_path / "cache")  # fmt: skip
    assert "\n" not in str(e.value)
    assert not (tmp_path / "cache").exists() or not any((tmp_path / "cache").rglob("*.npz"))


@pytest.mark.parametrize(
    ("convert", "convention"),
    [
        (lambda n: n, "world space with the scene's axes"),
        (lambda n: np.stack([n[..., 0], n[..., 2], -n[..., 1]], axis=-1), "world space with Y up"),
    ],
)
def test_an_unflipped_normal_aov_is_accepted_in_its_convention(tmp_path, convert, convention):
    """The same normals as they are, or in a Y-up engine's world axes: accepted, the convention named, the
    median angle to Mitsuba's shading normals under 0.5° (float32 ray hits against the closed form)."""
    _p, n, shape = _hits(SCENE)
    write_exr(tmp_path / "n.exr", {"RGB": np.where((shape >= 0)[..., None], convert(n), 0.0)})
    write_exr(tmp_path / "f.exr", {"RGB": np.zeros((N, N, 3))})
    r = compare(SCENE, str(tmp_path / "f.exr"), aov=f"normal={tmp_path / 'n.exr'}", spp=4, pass_spp=2,
                cache=tmp_path / "cache")  # fmt: skip
    got = r.frames[0].aovs["normal"]
    assert got["convention"].startswith(convention)
    assert got["median_angle_deg"] < 0.5 and got["misaligned_fraction"] < 0.05
