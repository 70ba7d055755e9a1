"""The exponential-fog scene part, its Mitsuba medium, and a tiny ``rtfit run height-fog`` (engine + study).

The Mitsuba check is independent of rtfit's kernels: the expected transmittance per pixel is computed here
from a float64 slab/quadric intersection and the analytic integral b·e^(−c·h₀)·(1 − e^(−c·Δh))/c along the
chord (NumPy expm1), and the render must agree within its binomial noise.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rtfit.scenes import ExponentialFog, SceneError, library_path, load_scene, parse_scene_text, scene_to_toml

FOG_TOML = """
name = "t"
[camera]
origin = [0.0, -7.0, 1.2]
target = [0.0, 0.0, 1.0]
width = 4
height = 4
[[media]]
type = "exponential_fog"
boundary = {{ type = "cube", center = [0.0, 0.0, 1.0], size = [4.0, 4.0, 3.0] }}
density = {density}
falloff = {falloff}
"""


def test_parse_roundtrip_and_defaults():
    s = parse_scene_text(FOG_TOML.format(density=0.5, falloff=1.0))
    m = s.media[0]
    assert isinstance(m, ExponentialFog) and m.gradient == (0.0, 0.0, 1.0) and not m.ellipsoid
    assert parse_scene_text(scene_to_toml(s)) == s
    for name in ("fog_transmittance", "fog_terrain", "fog_volumes"):
        sc = load_scene(library_path(name))
        assert parse_scene_text(scene_to_toml(sc), source=sc.source) == sc


@pytest.mark.parametrize(
    "density,falloff,key",
    [("nan", 1.0, "density"), (-0.1, 1.0, "density"), (0.5, "nan", "falloff"), (0.5, -2.0, "falloff")],
)
def test_bad_fog_parameters_one_line_error(density, falloff, key):
    with pytest.raises(SceneError, match=f"media\\[0\\].{key}") as e:
        parse_scene_text(FOG_TOML.format(density=density, falloff=falloff))
    assert "\n" not in str(e.value)


def test_builder_uses_python_medium_and_volpathmis(mi):
    from rtfit.reference import choose_integrator, mitsuba_scene_dict, plugin_types

    s = load_scene(library_path("fog_terrain"))
    ref = mitsuba_scene_dict(mi, s)  # the reference: rtfit_fogpath, no medium plugin, no boundary shape
    assert ref["integrator"]["type"] == "rtfit_fogpath" and "medium" not in ref["sensor"]
    assert not {"rtfit_expfog", "homogeneous", "heterogeneous"} & plugin_types(ref)
    d = mitsuba_scene_dict(mi, s, fog_path=False)
    types = plugin_types(d)
    assert "rtfit_expfog" in types and "homogeneous" not in types and "heterogeneous" not in types
    assert choose_integrator(s).type == "volpathmis"
    assert d["sensor"]["medium"] == {"type": "ref", "id": "medium0"}  # the camera is inside the fog


def _expected_t(scene, view_dir):
    """Independent float64 transmittance along each pixel ray (see module docstring)."""
    from rtfit.reference.height_fog import region_matrix

    m = scene.media[0]
    mat = region_matrix(m.boundary)
    inv = np.linalg.inv(mat)
    o = np.asarray(scene.camera.origin, dtype=np.float64)
    lo = inv[:3, :3] @ o + inv[:3, 3]
    g = np.asarray(m.gradient) / np.linalg.norm(m.gradient)
    out = np.ones(view_dir.shape[:2])
    for idx in np.ndindex(*view_dir.shape[:2]):
        d = view_dir[idx] / np.linalg.norm(view_dir[idx])
        ld = inv[:3, :3] @ d
        if m.ellipsoid:
            qa, qb, qc = ld @ ld, 2 * lo @ ld, lo @ lo - 1
            disc = qb * qb - 4 * qa * qc
            if disc <= 0:
                continue
            t0, t1 = (-qb - math.sqrt(disc)) / (2 * qa), (-qb + math.sqrt(disc)) / (2 * qa)
        else:
            with np.errstate(divide="ignore"):
                a, b = (-1 - lo) / ld, (1 - lo) / ld
            t0, t1 = np.max(np.minimum(a, b)), np.min(np.maximum(a, b))
        t0 = max(t0, 0.0)
        if t1 <= t0:
            continue
        h0 = (o + t0 * d - np.asarray(m.gradient_origin)) @ g
        dh = (t1 - t0) * (d @ g)
        y = m.falloff * dh
        phi = -np.expm1(-y) / y if y != 0 else 1.0
        out[idx] = math.exp(-m.density * (t1 - t0) * math.exp(-m.falloff * h0) * phi)
    return out


@pytest.mark.parametrize("ellipsoid", [False, True])
def test_mitsuba_transmittance_equals_closed_form(mi, ellipsoid):
    from rtfit.reference import load_mitsuba_scene, radiance_pass
    from rtfit.reference.estimators import gbuffer

    base = load_scene(library_path("fog_transmittance"))
    scene = dataclasses.replace(
        base,
        camera=dataclasses.replace(base.camera, width=16, height=16),
        media=(dataclasses.replace(base.media[0], ellipsoid=ellipsoid),),
    )
    mi_, ms = load_mitsuba_scene(scene)
    spp = 512
    p = radiance_pass(mi_, ms, spp, 3)
    t = _expected_t(scene, gbuffer(mi_, ms).view_dir.astype(np.float64))
    fogged = t < 1 - 1e-9
    assert fogged.sum() > 60
    # Binary estimator (absorbed or not): variance T(1 − T) per sample.
    sig = np.sqrt(t * (1 - t) / spp + 1e-12)
    z = (p.mean[..., 0] - t) / sig
    assert abs(np.std(z[fogged]) - 1) < 0.25
    assert np.max(np.abs(z[fogged])) < 4.5
    assert abs(z[fogged].sum() / math.sqrt(fogged.sum())) < 4
    assert np.all(np.abs(p.mean[~fogged, 0] - 1) < 1e-6)  # outside the medium: the backdrop untouched


def _shipped_audit(tmp_path, name: str, width: int, height: int, spp: int):
    """The engine's audit of one shipped scene, as ``rtfit run height-fog`` makes it (case ids tagged)."""
    from rtfit.experiments import audit_height_fog
    from rtfit.experiments.audit_run import audit
    from rtfit.scenes.parse import LIBRARY_DIR

    shipped = {s.name: s for s in audit_height_fog.SCENES}[name]
    return audit(
        LIBRARY_DIR / shipped.file,
        ["height-fog"],
        spp=spp,
        width=width,
        height=height,
        cache=tmp_path / "cache",
        tag=(f"{name}-", f"{name}: "),
        pass_spp=min(spp, shipped.options["pass_spp"]),
        metrics=("rmse", "rel_mse"),
    )


def test_run_is_the_engine_on_its_shipped_scenes_plus_the_study(tmp_path):
    """``rtfit run height-fog`` = the engine's audits of the shipped scenes + `height_fog_study.study`, on
    tiny images. Independent values: the ``absorbing`` row (L₀·e^(−τ) of the kernel) against this file's own
    float64 slab/quadric transmittance per pixel (`_expected_t`), for the box and the ellipsoid (the quick
    run's size and samples); the study's z-checks of that row against rtfit's fog path tracer (the old
    experiment's reference check) and every other study check pass (the float32 scan, the fits); the seed's
    horizon-phase row is given only (not fitted)."""
    from rtfit.experiments import audit_height_fog, height_fog_study
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext

    fam = FAMILIES["height-fog"]
    assert fam.module == ENGINE and fam.scenes == audit_height_fog.SCENES
    assert fam.study.target is height_fog_study.study
    assert [s.name for s in fam.scenes if s.quick] == [
        "fog_transmittance",
        "fog_transmittance_ellipsoid",
        "fog_terrain_e10_single",
        "fog_terrain_e10_multiple",
        "fog_terrain_e40_single",
        "fog_terrain_e40_multiple",
        "fog_volumes_e40",
    ]
    audits = []
    for name in ("fog_transmittance", "fog_transmittance_ellipsoid"):
        r = _shipped_audit(tmp_path, name, 24, 24, 256)  # the quick run's size and samples
        case = next(c for c in r.cases if c.id.endswith("-radiance"))
        row = r.outcomes[case.id]["absorbing"]
        assert row.fit is None and not row.method.params  # given only: the true b, c and colour 0
        t = _expected_t(load_scene(library_path(name)), r.gbuffer.view_dir.astype(np.float64))
        np.testing.assert_allclose(row.image[case.mask][:, 0], t[case.mask], rtol=2e-5)
        assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]
        audits.append(r)
    for name in ("fog_terrain_e10_single", "fog_volumes_e40"):
        audits.append(_shipped_audit(tmp_path, name, 16, 8, 16))
    rows = audits[2].outcomes["fog_terrain_e10_single-fog0-radiance"]
    assert {"const", "phase", "horizon-phase", "const-fitted", "phase-fitted"} <= set(rows)
    assert rows["horizon-phase"].fit is None and "horizon-phase-fitted" not in rows
    assert rows["horizon-phase"].parameters == {}  # every value fixed: the seed's colour, true b, c
    res = height_fog_study.study(
        StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", tuple(audits))
    )
    assert all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    ref_checks = [c.name for c in res.checks if c.name.startswith("reference check")]
    assert len(ref_checks) == 6 and any("(ellipsoid)" in n for n in ref_checks)  # box and ellipsoid, 3 each
    vol = res.extra["fog_volumes"]
    assert vol["fogged_pixels"] > 0 and all(np.isfinite(v) for v in vol["colours"].values())
    assert [f.id for f in res.fits] == ["volume-colours"] and dict(res.fits[0].parameters) == vol["colours"]
    assert {f.file for f in res.figures} >= {
        "figures/optical_depth_error_maps.png",
        "figures/rmse_vs_sun.png",
    }
    assert (tmp_path / "figures" / "residual_vs_elevation.png").is_file()


INSCATTER_TOML = """
name = "inscatter"
[camera]
origin = [0.3, -7.0, 1.1]
target = [0.0, 0.0, 1.0]
fov_deg = 30.0
width = 4
height = 4
[reference]
transport = "direct"
[[lights]]
type = "sun"
direction = [0.35, -0.25, 0.9]
irradiance = 3.0
[[media]]
type = "exponential_fog"
boundary = { type = "cube", center = [0.0, 0.0, 1.0], size = [4.0, 4.0, 3.0] }
density = 0.6
falloff = 1.5
gradient = [0.2, 0.1, 1.0]
albedo = 0.8
g = 0.0
"""


def _box_exit(lo, ld):
    """Entry and exit t of the line lo + t·ld with the box [−1, 1]³ (local frame, float64)."""
    with np.errstate(divide="ignore"):
        a, b = (-1 - lo) / ld, (1 - lo) / ld
    return np.max(np.minimum(a, b), axis=-1), np.min(np.maximum(a, b), axis=-1)


def test_single_scattering_equals_gauss_legendre_quadrature(mi):
    """In-scattered radiance of the segment-majorant medium (single scattering, isotropic phase, point
    sun) against an independent float64 quadrature of L = ∫ σs(x) T(o→x) E T_sun(x) / (4π) dt along each
    pixel ray: 256 Gauss–Legendre nodes over the chord, each transmittance in closed form,
    b·e^(−c·h₀)·ℓ·(1 − e^(−c·Δh))/(c·Δh)."""
    from rtfit.reference import load_mitsuba_scene, radiance_pass
    from rtfit.reference.estimators import gbuffer
    from rtfit.reference.height_fog import region_matrix

    scene = parse_scene_text(INSCATTER_TOML)
    m, sun = scene.media[0], scene.lights[0]
    mi_, ms = load_mitsuba_scene(scene)
    spp = 2048
    p = radiance_pass(mi_, ms, spp, 11)
    view = gbuffer(mi_, ms).view_dir.astype(np.float64)
    inv = np.linalg.inv(region_matrix(m.boundary))
    g = np.asarray(m.gradient) / np.linalg.norm(m.gradient)
    s = np.asarray(sun.direction) / np.linalg.norm(sun.direction)
    q0 = np.asarray(m.gradient_origin) @ g

    def tau(x, d, length):  # optical depth from points x (N, 3) along unit d over length (N,)
        y = m.falloff * length * (d @ g)
        phi = np.where(np.abs(y) > 1e-12, -np.expm1(-y) / np.where(y == 0, 1, y), 1.0)
        return m.density * np.exp(-m.falloff * (x @ g - q0)) * length * phi

    o = np.asarray(scene.camera.origin, dtype=np.float64)
    nodes, weights = np.polynomial.legendre.leggauss(256)
    expected = np.zeros(view.shape[:2])
    for idx in np.ndindex(*view.shape[:2]):
        d = view[idx] / np.linalg.norm(view[idx])
        t0, t1 = _box_exit(inv[:3, :3] @ o + inv[:3, 3], inv[:3, :3] @ d)
        t0 = max(float(t0), 0.0)
        if t1 <= t0:
            continue
        t = 0.5 * (t0 + t1) + 0.5 * (t1 - t0) * nodes
        x = o + t[:, None] * d
        _, ts = _box_exit(x @ inv[:3, :3].T + inv[:3, 3], inv[:3, :3] @ s)  # to the box exit towards the sun
        sigma_s = m.albedo[0] * m.density * np.exp(-m.falloff * (x @ g - q0))
        f = sigma_s * np.exp(-tau(np.broadcast_to(o + t0 * d, x.shape), d, t - t0) - tau(x, s, ts))
        expected[idx] = 0.5 * (t1 - t0) * np.sum(weights * f) * sun.irradiance[0] / (4 * math.pi)
    assert np.all(expected > 0.005)  # every pixel looks through the fog
    z = (p.mean[..., 0] - expected) / np.sqrt(p.var[..., 0] / spp)
    # 16 pixels: Šidák 1 % bound 3.4 (measured max |z| 2.07); the pooled z has unit spread (measured −0.06)
    assert np.max(np.abs(z)) < 4.0, z
    assert abs(z.sum() / 4.0) < 4.0
