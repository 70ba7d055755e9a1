"""Visibility baking (rtfit.reference.visibility), the ambient-aperture scenes and meshes, the cap quadratures
(rtfit.reference.cap_quadrature) and ``rtfit run ambient-aperture`` (the engine on the shipped hole scene plus
the study, tiny).

Independent values: on the axis below a circular hole of radius R at height h (walled in), the visible
directions are exactly a cone of half-angle atan(R/h), so V = 1 − cos(atan(R/h)), the bent normal is the
axis and the aperture is atan(R/h); an open floor sees the whole hemisphere (V = 1, r_a = π/2); the
quadrature of the cap-model irradiance against the closed-form sphere-light irradiance (cap ⊃ light).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rtfit.experiments import ambient_aperture_scenes as sc
from rtfit.experiments import ambient_aperture_study as study
from rtfit.experiments import audit_ambient_aperture
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import ENGINE, FAMILIES
from rtfit.experiments.shipped import StudyContext
from rtfit.realtime import sphere_light_irradiance
from rtfit.reference.cap_quadrature import (
    adaptive_quadrature_intersection,
    cap_model_irradiance,
    quadrature_intersection,
)
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.visibility import bake_visibility, surface_points
from rtfit.scenes import library_path, load_scene
from rtfit.scenes.parse import LIBRARY_DIR
from tests.test_ambient_aperture import HARD_POINTS, quad_intersection

PI = math.pi


@pytest.fixture(scope="module")
def hole():
    return load_scene(library_path("aperture_hole"))


def test_shipped_meshes_are_the_generator_output(tmp_path):
    for path in sc.write_library_meshes(tmp_path):
        shipped = library_path("aperture_hole").parent / "meshes" / path.name
        assert shipped.read_bytes() == path.read_bytes(), path.name


def test_shipped_scenes_are_the_registry_entry_and_parse():
    fam = FAMILIES["ambient-aperture"]
    assert fam.module == ENGINE and fam.scenes == audit_ambient_aperture.SCENES
    assert fam.study.target is study.study
    assert [s.name for s in fam.scenes if s.quick] == ["aperture_hole", "aperture_well", "aperture_bumps"]
    for shipped in fam.scenes:
        s = load_scene(LIBRARY_DIR / shipped.file)
        assert s.reference.transport == "direct"
        assert [lt.kind for lt in s.lights] == ["sphere_light", "constant_env"]
        assert tuple(s.lights[1].radiance) == (1.0, 1.0, 1.0)


def test_bake_on_axis_below_hole_is_the_exact_cone(hole):
    p, n, valid = surface_points(hole, np.array([[0.0, 0.0]]), 0.5)
    assert valid.all() and np.allclose(p, 0.0, atol=1e-6) and np.allclose(n, [[0, 0, 1]])
    b = bake_visibility(hole, p, n, n_dirs=16384, seed=3)
    theta = math.atan(0.6 / 1.0)
    v_exact = 1 - math.cos(theta)
    # Stratified sampling: far below the binomial stderr (0.0027); 4 binomial σ is a loose bound.
    assert abs(b.visible_fraction[0] - v_exact) < 4 * math.sqrt(v_exact * (1 - v_exact) / 16384)
    assert b.aperture[0] == pytest.approx(theta, abs=0.01)
    assert np.degrees(np.arccos(b.bent_normal[0, 2])) < 1.0


def test_bake_open_floor_sees_the_hemisphere(hole):
    floor = dataclasses.replace(hole, shapes=hole.shapes[:1])
    p = np.array([[0.3, -0.2, 0.0], [1.0, 1.0, 0.0]])
    n = np.array([[0.0, 0.0, 1.0]] * 2)
    b = bake_visibility(floor, p, n, n_dirs=256)
    assert np.all(b.visible_fraction == 1.0)
    assert np.allclose(b.aperture, PI / 2) and np.allclose(b.bent_normal, n, atol=0.02)


def test_bake_validation(hole):
    with pytest.raises(ValueError, match="n_dirs"):
        bake_visibility(hole, np.zeros((1, 3)), np.array([[0, 0, 1.0]]), n_dirs=1000)
    with pytest.raises(ValueError, match="unit length"):
        bake_visibility(hole, np.zeros((1, 3)), np.array([[0, 0, 2.0]]), n_dirs=16)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        bake_visibility(hole, np.zeros((2, 3)), np.zeros((1, 3)), n_dirs=16)


def test_cap_model_quadrature_against_closed_forms():
    """Light cap fully inside a hemisphere aperture: the closed-form sphere-light irradiance (horizon
    clipped); nested the other way (aperture inside the light, centred on n): π sin² r_a."""
    th, al = 1.2, 0.4
    ld = np.array([[math.sin(th), 0.0, math.cos(th)]])
    n = np.array([[0.0, 0.0, 1.0]])
    e = cap_model_irradiance(n, n, [PI / 2], ld, [al], (64, 256))[0]
    assert e == pytest.approx(sphere_light_irradiance(math.cos(th), al), rel=2e-3)
    e2 = cap_model_irradiance(n, n, [0.3], n, [0.9], (64, 256))[0]
    assert e2 == pytest.approx(PI * math.sin(0.3) ** 2, rel=2e-3)


def test_quadrature_intersection_against_closed_cases():
    assert quadrature_intersection([PI / 2], [PI / 2], [1.0])[0] == pytest.approx(2 * (PI - 1), rel=1e-9)
    assert quadrature_intersection([0.3], [1.0], [0.2])[0] == pytest.approx(
        2 * PI * (1 - math.cos(0.3)), rel=1e-9
    )


def test_adaptive_quadrature_against_mpmath_at_hard_points():
    """The study's float64 oracle at its hard points (tiny near-tangent caps included) against 25-digit
    mpmath: ≤ 1e-12 of the smaller cap, far below the 1e-10 its check allows the closed form."""
    assert study.HARD_POINTS == HARD_POINTS
    for r1, r2, d in study.HARD_POINTS:
        q = adaptive_quadrature_intersection(r1, r2, d)
        assert abs(q - quad_intersection(r1, r2, d)) <= 1e-12 * 2 * PI * (1 - math.cos(min(r1, r2)))


TINY = {"grid": 16, "fit_grid": 16, "quad_nodes": 32, "lambert_configs": 400, "lambert_quad": (16, 64),
        "cap_quad": (16, 64), "probe_n": 12, "spp": 256, "pass_spp": 256,
        "cost_elements": 1 << 14}  # fmt: skip


def _hole_cap(p: np.ndarray, radius: float = 0.6, h: float = 1.0, n: int = 400) -> tuple[float, float]:
    """(solid angle in sr, tilt from +z in rad of the mean direction) of the hole (a disk of ``radius`` at
    height ``h`` above the floor, centred over the origin) seen from the floor point ``p``: ∫ h/|x − p|³ dA
    and ∫ (x − p)/|x − p| · h/|x − p|³ dA by the midpoint rule in polar coordinates."""
    rr = (np.arange(n) + 0.5) / n * radius
    ph = (np.arange(n) + 0.5) / n * 2 * PI
    r, f = np.meshgrid(rr, ph, indexing="ij")
    dx, dy = r * np.cos(f) - p[0], r * np.sin(f) - p[1]
    dist = np.sqrt(dx * dx + dy * dy + h * h)
    w = h / dist**3 * r * (radius / n) * (2 * PI / n)
    mean = np.array([np.sum(w * dx / dist), np.sum(w * dy / dist), np.sum(w * h / dist)])
    return float(np.sum(w)), math.acos(mean[2] / np.linalg.norm(mean))


def test_run_is_the_engine_on_the_hole_scene_plus_the_study(tmp_path, monkeypatch):
    """``rtfit run ambient-aperture`` = the engine's audit of each shipped scene + the study, on the hole
    scene (14×14 pixels from under the plate, 1024 spp) with a tiny study. Independent values at the four
    pixels next to the image centre (floor points 0.15 off the hole's axis): the baked visible fraction
    against the hole's solid angle / 2π (quadrature over the disk; binomial error of the bake) and the bent
    normal's tilt against the disk's mean direction (the same quadrature; within 3°); the sky's reference
    (L = 1) against π times the configuration factor of a parallel disk, ½(1 − (h² + ρ² − R²)/√((h² + ρ² +
    R²)² − 4ρ²R²)); the light's cap (15° off the axis, α = 7.9°) lies inside the hole's (its rim's rays
    cross the plate's plane inside the hole), so its reference is the unshadowed closed form
    L·π sin²α cos θ_l. The study: the
    seed's known smoothstep figure (≈ 0.16 of the smaller cap for r ≤ π/2), the open-sky erratum (seed /
    exact = cos 30° / cos 60° = √3, exact = Ω·cos 60° with Ω = 2π(1 − cos 0.01)), and every check except
    the z-scores of its 144 unoccluded probes."""
    shipped = audit_ambient_aperture.SCENES[0]
    r = audit(LIBRARY_DIR / shipped.file, ["ambient-aperture"], spp=1024, width=14, height=14,
              cache=tmp_path / "cache", tag=(f"{shipped.name}-", ""), metrics=("rmse",))  # fmt: skip
    cases = {c.id: c for c in r.cases}
    assert set(cases) == {f"aperture_hole-{k}" for k in ("fill1", "caps", "light0-occluded")}
    light, sky = cases["aperture_hole-light0-occluded"], cases["aperture_hole-fill1"]
    assert light.mask.all() and sky.mask.all()  # the floor fills the image
    points, _ = gbuffer_points(r.gbuffer, light.mask)
    g = light.channel_inputs[0]
    for i, j in ((6, 6), (6, 7), (7, 6), (7, 7)):
        k = i * 14 + j
        p = points[k]
        assert abs(p[2]) < 1e-5 and np.hypot(p[0], p[1]) < 0.2
        omega, tilt = _hole_cap(p)
        v = omega / (2 * PI)
        assert 1 - math.cos(g["aperture"][k]) == pytest.approx(v, abs=4 * math.sqrt(v * (1 - v) / 1024))
        assert math.acos(g["cos_na"][k]) == pytest.approx(tilt, abs=math.radians(3.0))
        rho2, h2, r2 = p[0] ** 2 + p[1] ** 2, 1.0, 0.36
        f = 0.5 * (1 - (h2 + rho2 - r2) / math.sqrt((h2 + rho2 + r2) ** 2 - 4 * rho2 * r2))
        e, s_ = sky.reference.mean[i, j, 0], sky.reference.stderr[i, j, 0]
        assert abs(e - PI * f) < 4 * s_ + 1e-3
        to_light = np.array([0.9, 0.3, 3.5]) - p
        dist = float(np.linalg.norm(to_light))
        alpha, cos_nl = math.asin(0.5 / dist), to_light[2] / dist
        # the light's cap inside the hole's: its rim's directions cross z = 1 inside the hole (radius 0.6)
        w = to_light / dist
        t1 = np.cross(w, [1.0, 0.0, 0.0])
        t1 /= np.linalg.norm(t1)
        phi = np.linspace(0, 2 * PI, 360)[:, None]
        rim = math.cos(alpha) * w + math.sin(alpha) * (np.cos(phi) * t1 + np.sin(phi) * np.cross(w, t1))
        cross = p + rim * (1.0 / rim[:, 2:3])
        assert np.all(np.hypot(cross[:, 0], cross[:, 1]) < 0.6)
        exact = 10.0 * PI * math.sin(alpha) ** 2 * cos_nl
        e, s_ = light.reference.mean[i, j, 0], light.reference.stderr[i, j, 0]
        assert abs(e - exact) < 4 * s_ + 2e-3 * exact
    monkeypatch.setitem(study.CONFIG, True, TINY)
    res = study.study(StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", (r,)))
    failed = [c.name for c in res.checks if not c.passed]
    assert all("z-score" in n for n in failed), failed
    fl, fit_l = res.extra["function_level"], res.extra["fit_lambert"]
    assert 0.13 < fl["errors"]["smoothstep"]["hemisphere"]["max"] < 0.17
    o60 = fit_l["open_sky_60"]
    assert o60["exact"] == pytest.approx(2 * PI * (1 - math.cos(0.01)) * 0.5, rel=1e-3)
    assert o60["seed"] / o60["exact"] == pytest.approx(math.sqrt(3), rel=1e-3)
    dec = {d["case"]: d for d in res.extra["decomposition"]}
    assert set(dec) == {"aperture_hole-light0-occluded", "aperture_hole-fill1"}
    peak = dec["aperture_hole-light0-occluded"]["peak"]
    assert 0.5 < peak < 0.8 and dec["aperture_hole-light0-occluded"]["unshadowed_vs_reference"] > 0.3
    for name in ("intersection", "lambert"):
        assert (tmp_path / "fitted" / f"{name}.json").is_file()
    assert {f.id for f in res.fits} == {"intersection", "lambert"}
