"""Aerial perspective (issue 18 §4, issue 30 §1): the single-scattering quadrature through atmosphere + height
fog against closed forms and nishita-sky's independent reference quadrature; extremes; the study's terrain
geometry; ``rtfit run aerial-perspective`` = the engine on the shipped sunsky + fog-bank scenes + the study
(`rtfit.experiments.aerial_perspective_study`), whose path-traced check (fog alone against Mitsuba within its
noise) runs here at the quick size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments import aerial_perspective_study as ap
from rtfit.experiments import audit_aerial_perspective
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import ENGINE, FAMILIES
from rtfit.experiments.shipped import StudyContext
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.aerial_perspective import (
    FogLayer,
    aerial_scattering,
    fog_blend,
    horizon_fog_colour,
    sun_direction,
    sun_transmittance_at,
)
from rtfit.realtime.nishita_sky import AtmosphereParams
from rtfit.reference.nishita_sky import library_atmosphere, single_scattering_quadrature
from rtfit.scenes.parse import LIBRARY_DIR

NO_ATMOSPHERE = AtmosphereParams(rayleigh_scale=0.0, mie_scale=0.0)


def _hg(c, g):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)


def test_level_ray_in_fog_alone_matches_the_closed_form():
    """A level ray (d_z = 0) in fog alone: σ = b e^(−c z₀) and T_sun = exp(−σ/(c sin e)) are constant, so
    S = E₀ P_HG(ν) T_sun (1 − e^(−σ D)) exactly. Measured max relative error 2.9e-9 (the 5e5 m ray, σD = 128,
    24 panels of t = D·u³; 1e-14 on the others), tolerance 1e-8."""
    fog = FogLayer(3e-4, 2e-3, 0.5)
    e, z0 = 25.0, 80.0
    sun = sun_direction(e, 70.0)
    az = np.radians(np.array([-30.0, 0.0, 20.0, 50.0]))
    d = np.stack([np.sin(az), np.cos(az), np.zeros_like(az)], -1)
    dist = np.array([10.0, 1000.0, 30000.0, 5e5])
    q = aerial_scattering(
        NUMPY_OPS, z0, d[:, 0], d[:, 1], d[:, 2], dist, atmosphere=NO_ATMOSPHERE, sun=sun, fog=fog, panels=24
    )
    sigma = fog.density * math.exp(-fog.falloff * z0)
    t_sun = math.exp(-sigma / (fog.falloff * math.sin(math.radians(e))))
    nu = d @ np.asarray(sun)
    for c in range(3):
        e0 = NO_ATMOSPHERE.solar_irradiance[c]
        want = e0 * _hg(nu, fog.g) * t_sun * -np.expm1(-sigma * dist)
        np.testing.assert_allclose(q["S"][c], want, rtol=1e-8)
        np.testing.assert_allclose(q["J_cam"][c], e0 * _hg(nu, fog.g) * t_sun, rtol=1e-12)
        np.testing.assert_allclose(q["T"][c], np.exp(-sigma * dist), rtol=1e-12)
        # grey fog: the grey variant is the same integral (measured: identical)
        np.testing.assert_allclose(q["S_grey"][c], q["S"][c], rtol=1e-14)


def test_atmosphere_alone_matches_nishita_reference_quadrature():
    """Fog b = 0, sky rays to the top of the atmosphere: against
    `rtfit.reference.nishita_sky.single_scattering_quadrature` (trapezoid, 2000 steps; Gauss–Legendre sun
    depths), an independent code checked against Mitsuba. Measured max relative difference 2.0e-6
    (tolerance 2e-5)."""
    atm = AtmosphereParams()
    spec = library_atmosphere(sun_elevation_deg=12.0, viewer_altitude_m=200.0)
    el = np.radians(np.array([1.0, 4.0, 20.0, 70.0]))
    az = np.radians(np.array([120.0]))
    A, E = np.meshgrid(az, el)
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    ref = single_scattering_quadrature(spec, d, steps=2000)
    r0 = atm.planet_radius_m + 200.0
    mu = d[:, 2]
    dist = -r0 * mu + np.sqrt(r0 * r0 * mu * mu + atm.top_radius_m**2 - r0 * r0)
    q = aerial_scattering(
        NUMPY_OPS,
        200.0,
        d[:, 0],
        d[:, 1],
        d[:, 2],
        dist,
        atmosphere=atm,
        sun=sun_direction(12.0, 90.0),
        fog=FogLayer(0.0, 1e-3, 0.0),
        panels=64,
    )
    np.testing.assert_allclose(np.stack(q["S"], -1), ref, rtol=2e-5)


def test_sun_below_the_horizon_gives_no_single_scattering_and_no_nan():
    """Sun at −4°: the planet occludes the sun at every point below ~15 km (T_sun = 0 exactly)."""
    d = np.array([[0.0, 1.0, 0.0], [0.0, 0.9998, -0.02]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    q = aerial_scattering(
        NUMPY_OPS,
        50.0,
        d[:, 0],
        d[:, 1],
        d[:, 2],
        np.array([4e4, 2500.0]),
        atmosphere=AtmosphereParams(),
        sun=sun_direction(-4.0, 0.0),
        fog=FogLayer(),
        panels=8,
    )
    for k, v in q.items():
        arr = np.stack(v)
        assert np.all(np.isfinite(arr)), k
    assert np.all(np.stack(q["S"]) == 0.0)
    assert np.all(np.stack(q["J_cam"]) == 0.0)
    ts = sun_transmittance_at(
        NUMPY_OPS, 0.0, 0.0, 100.0, AtmosphereParams(), sun_direction(-4.0, 0.0), FogLayer()
    )
    assert all(t == 0.0 for t in ts)


@settings(max_examples=12, deadline=None)
@given(
    z0=st.floats(0.0, 3000.0),
    el=st.floats(-89.0, 89.0),
    dist=st.floats(0.0, 2e5),
    b=st.sampled_from([0.0, 1e-6, 2e-4, 1e-2, 1.0]),
    c=st.floats(1e-5, 0.1),
    sun_el=st.floats(-4.0, 90.0),
)
def test_outputs_are_finite_and_bounded_over_the_domain(z0, el, dist, b, c, sun_el):
    """Every output finite; 0 ≤ T ≤ 1; S ≥ 0 (no NaN/Inf for horizontal rays, zero and huge fog, D = 0)."""
    e = math.radians(el)
    d = np.array([[0.0, math.cos(e), math.sin(e)]])
    with np.errstate(all="ignore"):
        q = aerial_scattering(
            NUMPY_OPS,
            z0,
            d[:, 0],
            d[:, 1],
            d[:, 2],
            np.array([dist]),
            atmosphere=AtmosphereParams(),
            sun=sun_direction(sun_el, 40.0),
            fog=FogLayer(b, c, 0.6),
            panels=4,
        )
    for k, v in q.items():
        arr = np.stack(v)
        assert np.all(np.isfinite(arr)), (k, arr)
        assert np.all(arr >= 0.0), (k, arr)
    assert np.all(np.stack(q["T"]) <= 1.0)


def test_blend_and_horizon_colour_are_the_height_fog_texts():
    """fog_blend = L₀T + C(1 − T) per channel; the horizon colour's phase average over the sphere is
    (H_R + H_M)/(4π) (both phase functions integrate to 1): Gauss–Legendre in cos θ, 1e-12."""
    out = fog_blend([np.array([2.0])] * 3, [np.array([0.25])] * 3, [np.array([1.0])] * 3)
    assert all(float(o[0]) == pytest.approx(0.5 + 0.75) for o in out)
    x, w = np.polynomial.legendre.leggauss(64)
    col = horizon_fog_colour([1.0, 2.0, 3.0], [0.5, 0.25, 0.0], x, 0.8)
    for c, want in enumerate((1.5, 2.25, 3.0)):
        assert float(np.sum(w * col[c]) / 2.0) == pytest.approx(want / (4 * math.pi), rel=1e-12)


def test_scene_distances_are_the_ray_plane_intersections():
    """Ground hits at z₀/(−d_z), ridge hits at Y₀/(d_y − k d_x): every pixel hits a surface (no sky)."""
    dirs = ap.view_directions((12, 6))
    geo = ap.surfaces(dirs, 50.0)
    assert np.all(np.isfinite(geo["distance"]))
    y0, k = ap.RIDGE
    p = geo["point"]
    on_ground = ~geo["ridge"]
    np.testing.assert_allclose(p[on_ground][:, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(p[geo["ridge"]][:, 1] - k * p[geo["ridge"]][:, 0], y0, rtol=1e-12)


BOX_LO, BOX_HI = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])
"""The fog bank of scenes/library/aerial_perspective_fog_bank.xml: the unit cube scaled (3, 2, 1.5),
raised 1.5."""


def _slab(o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Each ray's stretch inside the fog bank (the classic slab test, written here)."""
    with np.errstate(divide="ignore"):
        a, b = (BOX_LO - o) / d, (BOX_HI - o) / d
    return np.min(np.maximum(a, b), axis=1) - np.max(np.minimum(a, b), axis=1).clip(min=0.0)


def _shipped_audit(tmp_path, name: str):
    shipped = {s.name: s for s in audit_aerial_perspective.SCENES}[name]
    tag = (f"{shipped.name}-", f"{shipped.name}: ")
    return audit(LIBRARY_DIR / shipped.file, ["aerial-perspective"], spp=32, pass_spp=32, width=12, height=8,
                 defines=shipped.defines, cache=tmp_path / "cache", tag=tag, metrics=("rmse",), fit=False,
                 cost_elements=1 << 10)  # fmt: skip


def test_run_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path):
    """``rtfit run aerial-perspective`` = the engine's audits of the shipped scenes (two XML files: a sunsky
    over a ground seen through a homogeneous fog bank or a height-fog grid, the sun's direction per scene by
    ``-D``) + the study, on the quick two (fog bank, sun at 60°; height fog, sun at 4°; 12×8 pixels, 32 spp).
    Independent values: the sun's direction as Mitsuba's sunsky loaded it (cos e·sin 120°, cos e·cos 120°, sin
    e); the medium's b, c (the bank's σt; the grid's exp(−1.2·z) over 2.4 units stretched over 3, times its
    scale 0.6), albedo and g as written in the files; each pixel's stretch by the slab test; the study's error
    budget (its parts sum to the total; the sun below the horizon: a black reference); every study check (the
    fog-only quadrature against Mitsuba within its noise, the atmosphere-only quadrature against
    nishita-sky's) passes."""
    fam = FAMILIES["aerial-perspective"]
    assert fam.module == ENGINE and fam.scenes == audit_aerial_perspective.SCENES
    assert fam.study.target is ap.study
    assert len(fam.scenes) == 12 and [s.name for s in fam.scenes if s.quick] == [
        "fog_bank-sun60",
        "height_fog-sun4",
    ]
    audits = tuple(_shipped_audit(tmp_path, n) for n in ("fog_bank-sun60", "height_fog-sun4"))
    # (b, c): the fog bank's σt; the grid's exp(−1.2·z) over 2.4 units stretched over 3: c = 1.2·2.4/3
    for r, e, (b, c) in zip(audits, (60.0, 4.0), ((0.35, 0.0), (0.6, 0.96)), strict=True):
        (case,) = r.cases
        p = case.parameters
        el, az = math.radians(e), math.radians(120.0)
        want = [math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)]
        np.testing.assert_allclose(p["sun_direction"], want, atol=1e-5)
        assert p["density"] == pytest.approx(b, rel=1e-5) and p["falloff"] == pytest.approx(c, rel=1e-5)
        assert p["albedo"] == pytest.approx([0.9] * 3, rel=1e-6) and p["g"] == pytest.approx(0.6, rel=1e-6)
        g = case.channel_inputs[0]
        o = np.array([0.031, -7.0, 1.217])
        d = np.stack([g["dx"], g["dy"], g["dz"]], 1)
        np.testing.assert_allclose(g["distance"], _slab(np.broadcast_to(o, d.shape), d), atol=1e-4)
        for row, out in r.outcomes[case.id].items():
            assert np.all(np.isfinite(out.image[case.mask])), row
    ctx = StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", audits)
    res = ap.study(ctx)
    assert all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    budget = {b["sun_elevation_deg"]: b for b in res.extra["error_budget"]}
    assert set(budget) == {60.0, 4.0, -4.0}
    for b in budget.values():
        assert sum(b["parts"].values()) == pytest.approx(b["total"], rel=1e-12)
    assert budget[-4.0]["sun_attenuation_alone"] == 0.0  # the planet's shadow: no sun anywhere
    assert [s["case"] for s in res.extra["scenes_by_sun"]] == [a.cases[0].id for a in audits]
    assert (tmp_path / "figures" / "error_budget.png").is_file()


def test_audit_list_names_the_family_on_the_shipped_scene():
    scene = LIBRARY_DIR / "aerial_perspective_fog_bank.xml"
    out = CliRunner().invoke(audit_cmd, [str(scene), "--list", "-D", "sz=0.25882"])
    assert out.exit_code == 0, out.output
    line = next(x for x in out.output.splitlines() if x.strip().startswith("aerial-perspective"))
    assert "sky through a medium" in line and "sunsky" in line
