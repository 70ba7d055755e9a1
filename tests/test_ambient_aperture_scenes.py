"""Visibility baking (rtfit.reference.visibility), the ambient-aperture scenes and meshes, and a tiny run of
the ``ambient-aperture`` experiment.

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

from rtfit.experiments import ambient_aperture as aa
from rtfit.experiments import ambient_aperture_scenes as sc
from rtfit.experiments.cli import main
from rtfit.experiments.report import load_results
from rtfit.realtime import sphere_light_irradiance
from rtfit.reference.visibility import bake_visibility, surface_points
from rtfit.scenes import library_path, load_scene
from tests.test_ambient_aperture import HARD_POINTS, quad_intersection

PI = math.pi


@pytest.fixture(scope="module")
def hole():
    return load_scene(library_path("aperture_hole"))


def test_shipped_meshes_are_the_generator_output(tmp_path):
    for path in sc.write_library_meshes(tmp_path):
        shipped = library_path("aperture_hole").parent / "meshes" / path.name
        assert shipped.read_bytes() == path.read_bytes(), path.name


def test_library_scenes_parse():
    for name in sc.SCENES:
        s = load_scene(library_path(name))
        assert s.reference.transport == "direct" and s.lights[0].kind == "sphere_light"


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
    e = aa.cap_model_irradiance(n, n, [PI / 2], ld, [al], (64, 256))[0]
    assert e == pytest.approx(sphere_light_irradiance(math.cos(th), al), rel=2e-3)
    e2 = aa.cap_model_irradiance(n, n, [0.3], n, [0.9], (64, 256))[0]
    assert e2 == pytest.approx(PI * math.sin(0.3) ** 2, rel=2e-3)


def test_quadrature_intersection_against_closed_cases():
    assert aa.quadrature_intersection([PI / 2], [PI / 2], [1.0])[0] == pytest.approx(2 * (PI - 1), rel=1e-9)
    assert aa.quadrature_intersection([0.3], [1.0], [0.2])[0] == pytest.approx(
        2 * PI * (1 - math.cos(0.3)), rel=1e-9
    )


def test_adaptive_quadrature_against_mpmath_at_hard_points():
    """The experiment's float64 oracle at its hard points (tiny near-tangent caps included) against 25-digit
    mpmath: ≤ 1e-12 of the smaller cap, far below the 1e-10 its check allows the closed form."""
    assert aa.HARD_POINTS == HARD_POINTS
    for r1, r2, d in aa.HARD_POINTS:
        q = aa.adaptive_quadrature_intersection(r1, r2, d)
        assert abs(q - quad_intersection(r1, r2, d)) <= 1e-12 * 2 * PI * (1 - math.cos(min(r1, r2)))


def test_tiny_run_checks_pass(tmp_path, monkeypatch):
    """A tiny configuration of the whole experiment: results.json loads and every check passes."""
    real = aa.configure

    def tiny(quick, spp):
        cfg = real(True, spp)
        cfg.update(
            {
                "grid": 16,
                "fit_grid": 16,
                "quad_nodes": 32,
                "lambert_configs": 400,
                "probe_n": 12,
                "spp": 256,
                "sky_spp": 512,
                "pass_spp": 256,
                "bake_dirs": 256,
                "cap_quad": [16, 64],
                "cost_elements": 1 << 14,
                "metrics": ["rmse", "mae", "max_abs"],
            }
        )
        return cfg

    monkeypatch.setattr(aa, "configure", tiny)
    out = tmp_path / "out"
    assert (
        main(
            [
                "run",
                "ambient-aperture",
                "--quick",
                "--out",
                str(out),
                "--cache",
                str(tmp_path / "cache"),
                "--no-progress",
            ]
        )
        == 0
    )
    res = load_results(out / "ambient-aperture")
    failed = [c for c in res["checks"] if not c["passed"]]
    # The unoccluded z-score checks need ≥ 500 probes to be tight; at 144 probes allow them to miss.
    assert all("z-score" in c["name"] for c in failed), failed
    assert {c["id"] for c in res["cases"]} == {
        f"{s}-{k}" for s in ("hole", "well", "bumps") for k in ("light", "sky")
    }
    for case in res["cases"]:
        by = {a["method"]: a for a in case["approximations"]}
        # Occlusion matters: ignoring it is far worse than the cap model (not on the open bumps).
        if case["id"].endswith("-light") and not case["id"].startswith("bumps"):
            assert (
                by["unshadowed"]["metrics"]["rmse"]["value"] > 3 * by["cap-model"]["metrics"]["rmse"]["value"]
            )
    assert (out / "ambient-aperture" / "fitted" / "intersection.json").is_file()
