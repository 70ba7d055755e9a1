"""rtfit_fogpath (closed-form free flight through exponential fog) against independent computations.

* the closed forms E(x) = (1 − e^{−x})/x and G(z) = −ln(1 − z)/z (float32 Dr.Jit) against float64 NumPy
  ``expm1``/``log1p``;
* the sampled free-flight distances along fixed rays against the exact distribution
  P(t ≤ s) = 1 − exp(−τ(s)) (τ by float64 closed form): Pearson χ² over equiprobable bins plus the escape
  bin;
* rendered pixels against Mitsuba's ``volpathmis`` with rtfit's fog medium (the previous reference): same
  scene, independent seeds, per-pixel z-scores of unit spread and zero mean.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from rtfit.scenes import library_path, load_scene, parse_scene_text


def test_closed_forms_match_float64(mi):
    import drjit as dr

    from rtfit.reference.fog_integrator import expm1_ratio, log1m_ratio

    x = np.concatenate([-np.logspace(-8, 1.5, 400), [0.0], np.logspace(-8, 1.5, 400)])
    e = np.array(expm1_ratio(dr, mi.Float(x.astype(np.float32))), dtype=np.float64)
    xf = x.astype(np.float32).astype(np.float64)
    e_ref = np.where(xf == 0, 1.0, -np.expm1(-xf) / np.where(xf == 0, 1.0, xf))
    assert np.max(np.abs(e / e_ref - 1)) < 2e-6  # measured 1.3e-6 (closed form just above the cutoff)
    z = np.concatenate([-np.logspace(-8, 1.5, 400), [0.0], np.logspace(-8, np.log10(0.999), 400)])
    gz = np.array(log1m_ratio(dr, mi.Float(z.astype(np.float32))), dtype=np.float64)
    zf = z.astype(np.float32).astype(np.float64)
    g_ref = np.where(zf == 0, 1.0, -np.log1p(-zf) / np.where(zf == 0, 1.0, zf))
    assert np.max(np.abs(gz / g_ref - 1)) < 2e-6  # measured 1.2e-6


def _integrator(mi, medium):
    from rtfit.reference import fog_integrator

    fog_integrator.register(mi)
    return mi.load_dict(fog_integrator.integrator_dict(mi, medium))


def _tau64(medium, o, d, s):
    """float64 optical depth from o along unit d over [0, s] inside the (box) region, region-clipped."""
    from rtfit.reference.height_fog import region_matrix

    inv = np.linalg.inv(region_matrix(medium.boundary))
    lo, ld = inv[:3, :3] @ o + inv[:3, 3], inv[:3, :3] @ d
    with np.errstate(divide="ignore"):
        a, b = (-1 - lo) / ld, (1 - lo) / ld
    t0, t1 = max(np.max(np.minimum(a, b)), 0.0), np.min(np.maximum(a, b))
    g = np.asarray(medium.gradient) / np.linalg.norm(medium.gradient)
    lo_s, hi_s = np.clip(s, t0, t1), t1
    del hi_s
    ell = lo_s - t0
    h0 = (o + t0 * d - np.asarray(medium.gradient_origin)) @ g
    y = medium.falloff * ell * (d @ g)
    phi = np.where(np.abs(y) > 0, -np.expm1(-y) / np.where(y == 0, 1.0, y), 1.0)
    return medium.density * math.exp(-medium.falloff * h0) * ell * phi, t1


TALL_FOG = """
name = "tall"
[camera]
origin = [0.0, 0.0, 10.0]
target = [0.0, 1.0, 10.0]
[[media]]
type = "exponential_fog"
boundary = { type = "cube", center = [0.0, 0.0, 100.0], size = [400.0, 400.0, 200.0] }
density = 50.0
falloff = 1.0
"""


@pytest.mark.parametrize(
    "case,dz", [("terrain", -0.3), ("terrain", 0.0), ("terrain", 0.02), ("terrain", 0.6), ("tall", -0.9)]
)
def test_free_flight_chi2_against_exact_distribution(mi, case, dz):
    """Pearson χ² of 200k sampled distances (20 equiprobable collision bins + escape) along a ray: the
    terrain fog from 2 m height (downward, level, shallow and steep rays), and a fog 200 scale heights
    tall entered at its top (σ there is 50·e^-199 ≈ 1e-85 /m, below float32's range: the log-space path)."""
    if case == "terrain":
        med = load_scene(library_path("fog_terrain")).media[0]
        o = np.array([0.0, 0.0, 2.0])
    else:
        med = parse_scene_text(TALL_FOG).media[0]
        o = np.array([0.0, 0.0, 199.0])
    integ = _integrator(mi, med)
    d = np.array([0.0, math.sqrt(1 - dz * dz), dz])
    t_surf = (o[2] - 0.0) / -dz if (dz < 0 and case == "terrain") else math.inf  # the ground plane z = 0
    n = 200_000
    rng = np.random.default_rng(5)
    u = mi.Float(rng.random(n).astype(np.float32))
    collided, t = integ.free_flight(
        mi.Point3f(*o.tolist()), mi.Vector3f(*d.tolist()), mi.Float(np.float32(t_surf)), u
    )
    collided, t = np.array(collided), np.array(t, dtype=np.float64)
    tau_end, t1 = _tau64(med, o, d, min(t_surf, 1e12))
    p_escape = math.exp(-tau_end)
    # equiprobable bins in τ: edges at τ_k = −ln(1 − k·(1 − p_esc)/20)
    k = np.arange(1, 20)
    tau_edges = -np.log1p(-k * (1 - p_escape) / 20)
    tau_t = _tau64(med, o, d, t[collided])[0]
    counts = np.concatenate(
        [np.bincount(np.searchsorted(tau_edges, tau_t), minlength=20), [np.sum(~collided)]]
    )
    expected = np.concatenate([np.full(20, n * (1 - p_escape) / 20), [n * p_escape]])
    keep = expected > 5
    chi2 = np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep])
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-3, (chi2, counts, expected)
    assert np.all(t[collided] <= min(t_surf, t1) * (1 + 1e-6))


def test_render_matches_volpathmis(mi):
    """fog_terrain at 24×12, sun 30°, single and multiple scattering: rtfit_fogpath against volpathmis +
    rtfit's segment-majorant medium, independent seeds; per-pixel z over RGB (measured: mean −0.01 to
    0.03, spread 0.97–1.03 at 64×32 × 64 spp)."""
    from rtfit.reference.build import load_dict, mitsuba_scene_dict
    from rtfit.reference.estimators import radiance_pass

    for transport in ("single", "multiple"):
        base = load_scene(library_path(f"fog_terrain_e30_{transport}"))
        scene = dataclasses.replace(base, camera=dataclasses.replace(base.camera, width=24, height=12))
        new = mitsuba_scene_dict(mi, scene)
        old = mitsuba_scene_dict(mi, scene, fog_path=False)
        assert new["integrator"]["type"] == "rtfit_fogpath" and old["integrator"]["type"] == "volpathmis"
        a = radiance_pass(mi, load_dict(mi, old), 64, 1)
        b = radiance_pass(mi, load_dict(mi, new), 64, 2)
        z = (a.mean - b.mean) / np.sqrt(a.var / a.spp + b.var / b.spp + 1e-30)
        z = z[(a.var + b.var) > 0]
        # 864 values (288 pixels × RGB, channels correlated): |mean| < 0.25 (≈ 4 SE of 288 pixels),
        # spread within 15 %, Šidák 1 % bound over 864 values ≈ 4.2
        assert abs(z.mean()) < 0.25, (transport, z.mean())
        assert abs(z.std() - 1) < 0.15, (transport, z.std())
        assert np.max(np.abs(z)) < 5.0, (transport, np.max(np.abs(z)))


def test_ellipsoid_and_budget(mi):
    """The ellipsoid region: no collision outside the inscribed ellipsoid; the lane counter is the
    integrator's and is found by `counters`."""
    from rtfit.reference.budget import counters
    from rtfit.reference.build import load_dict, mitsuba_scene_dict

    scene = load_scene(library_path("fog_transmittance"))
    med = dataclasses.replace(scene.media[0], ellipsoid=True)
    integ = _integrator(mi, med)
    from rtfit.reference.height_fog import region_matrix

    m = region_matrix(med.boundary)
    # a ray through a box corner region that misses the ellipsoid: never collides
    corner = m[:3, :3] @ np.array([0.95, 0.95, -2.0]) + m[:3, 3]
    d = m[:3, :3] @ np.array([0.0, 0.0, 1.0])
    d = d / np.linalg.norm(d)
    u = mi.Float(np.linspace(0.0, 0.999999, 1000).astype(np.float32))
    collided, _ = integ.free_flight(mi.Point3f(*corner.tolist()), mi.Vector3f(*d.tolist()), mi.Float(1e30), u)
    assert not np.any(np.array(collided))
    ms = load_dict(mi, mitsuba_scene_dict(mi, dataclasses.replace(scene, media=(med,))))
    assert any(c is ms.integrator().lane_counter for c in counters(ms))


def test_vertex_cap_fails_the_pass(mi, monkeypatch):
    """A planted cap of 1 loop iteration per lane: every lane that needs a second vertex is stopped and
    the pass raises `PassBudgetExceeded` with one line (the integrator's bound on a pass)."""
    from rtfit.reference import fog_integrator
    from rtfit.reference.budget import LaneCounter, PassBudgetExceeded
    from rtfit.reference.build import load_dict, mitsuba_scene_dict
    from rtfit.reference.estimators import radiance_pass

    scene = load_scene(library_path("fog_transmittance"))
    scene = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, width=4, height=4))
    monkeypatch.setattr(fog_integrator, "LaneCounter", lambda: LaneCounter(cap=1))
    fog_integrator._registered.discard(mi.variant())  # re-register: the class reads the patch
    try:
        ms = load_dict(mi, mitsuba_scene_dict(mi, scene))
        with pytest.raises(PassBudgetExceeded) as e:
            radiance_pass(mi, ms, 4, 0)
        assert "\n" not in str(e.value) and "lanes took more than 1" in str(e.value)
    finally:
        monkeypatch.undo()
        fog_integrator._registered.discard(mi.variant())
        fog_integrator.register(mi)


def test_free_flight_at_the_extreme_samples(mi):
    """u ∈ {0, 2⁻²³, ½, 1 − 2⁻²³} (PCG32's smallest and largest floats) on every kind of ray — up, level,
    down, straight down onto the ground, grazing — in the terrain fog from 0 m (on the ground), 2 m and 300 m,
    and through the tall fog from inside its top (σ below float32's range): a collision distance is finite,
    in [0, surface], and a larger u goes no shorter than a smaller one."""
    med = load_scene(library_path("fog_terrain")).media[0]
    tall = parse_scene_text(TALL_FOG).media[0]
    us = np.array([0.0, 2.0**-23, 0.5, 1.0 - 2.0**-23], dtype=np.float32)
    dzs = [-1.0, -0.9, -0.3, -1e-4, 0.0, 1e-4, 0.02, 0.6, 1.0]
    for m, heights in ((med, (0.0, 2.0, 300.0)), (tall, (199.0, 150.0))):
        integ = _integrator(mi, m)
        for h in heights:
            for dz in dzs:
                d = np.array([0.0, math.sqrt(1 - dz * dz), dz])
                t_surf = h / -dz if (dz < 0 and m is med and h > 0) else 1e30
                n = us.size
                o = mi.Point3f(*[mi.Float(np.full(n, x, np.float32)) for x in (0.0, 0.0, h)])
                collided, t = integ.free_flight(
                    o, mi.Vector3f(*d.tolist()), mi.Float(np.full(n, t_surf, np.float32)), mi.Float(us)
                )
                c, t = np.array(collided), np.array(t, dtype=np.float64)
                assert np.all(np.isfinite(t[c])), (h, dz, t)
                assert np.all((t[c] >= 0.0) & (t[c] <= t_surf * (1 + 1e-6))), (h, dz, t)
                # τ* = −ln(1 − u) rises with u: collisions are a prefix of the u's, at non-decreasing t
                assert np.all(np.diff(c.astype(int)) <= 0), (h, dz, c)
                assert np.all(np.diff(t[c]) >= -1e-6 * max(1.0, float(np.max(t[c], initial=0.0)))), (h, dz, t)
