"""Parallax occlusion mapping (rtfit.realtime.parallax_occlusion) against closed forms, and its reference
(rtfit.reference.parallax_occlusion) against independent values.

Oracles: a plane h = c and a linear ramp h = 0.5 + 0.25·u, where the view ray's hit is closed-form and the
piecewise-linear search is exact; the plane at the floor (h = 0), where the hit is the full offset; the ramp's
true self-shadowing (the light ray enters a plane iff n·L < 0); Lambert's polygon irradiance against a
midpoint quadrature; Mitsuba ray_intersect on a flat mesh against the closed-form hit. Every tolerance
states its measured maximum. Each hazard of the listing is a test that confirms it (and that the stable
variant fixes it)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.parallax_occlusion import METHODS, SHADOW_METHODS

S = 0.1  # height-map range used throughout


def method(mid: str, field: str, n=(8, 40), **fixed):
    m = METHODS[mid]
    return dataclasses.replace(
        m, fixed={**m.fixed, "field": field, "scale": S, "n_min": n[0], "n_max": n[1], **fixed}
    )


def view(theta: float, phi: float) -> tuple[float, float, float]:
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


L_DEFAULT = (0.5, 0.0, math.sqrt(0.75))


def run(m, u0, v0, V, L=L_DEFAULT, mip=0.0, dtype: type = np.float64, params=None):
    u0 = np.atleast_1d(np.asarray(u0, dtype))
    v0 = np.broadcast_to(np.asarray(v0, dtype), u0.shape)
    full = {
        k: np.full(u0.shape, x, dtype)
        for k, x in zip(("vx", "vy", "vz", "lx", "ly", "lz"), (*V, *L), strict=True)
    }
    inputs = {"u0": u0, "v0": v0, **full, "mip": np.full(u0.shape, mip, dtype)}
    with np.errstate(all="ignore"):
        return tuple(np.asarray(x) for x in m(NUMPY_OPS, inputs, params))


angles = st.floats(0.0, math.radians(85.0))
azimuths = st.floats(-math.pi, math.pi)
n_ranges = st.tuples(st.integers(1, 16), st.integers(16, 40))


# ------------------------------------------------------------------------------------- plane and ramp
@settings(max_examples=30, deadline=None)
@given(theta=angles, phi=azimuths, n=n_ranges)
def test_plane_hit_is_exact_for_both_variants(theta, phi, n):
    """On the plane h = 0.5 the hit is uv₀ − P/2, P = s·V_xy/V_z, and the piecewise-linear search is exact
    (float64: measured max 2.2e-16 over 200 random cases). The listing is skipped at V_z = 1 (its 0/0,
    tested below) and where its
    first sample is already under the plane (its first-segment erratum, tested below)."""
    V = view(theta, phi)
    u0 = np.linspace(-0.3, 1.3, 7)
    px, py = S * V[0] / V[2], S * V[1] / V[2]
    for mid in METHODS:
        n_here = math.floor(n[1] + V[2] * (n[0] - n[1]))
        if mid == "listing" and (theta < 1e-100 or 1.0 - 1.0 / n_here < 0.5):  # |V_xy|² underflows: 0/0
            continue
        u, v, _ = run(method(mid, "plane", n), u0, 0.2, V)
        np.testing.assert_allclose(u, u0 - px * 0.5, atol=1e-12)
        np.testing.assert_allclose(v, 0.2 - py * 0.5, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(theta=st.floats(math.radians(1.0), math.radians(80.0)), phi=azimuths, n=n_ranges)
def test_ramp_hit_is_exact_for_both_variants(theta, phi, n):
    """h = 0.5 + 0.25·u is linear along the ray, so the profile is exactly piecewise linear: the hit height is
    t* = (0.5 + 0.25·(u₀ − P_x))/(1 − 0.25·P_x) (float64; measured max error 1.7e-16 in u)."""
    V = view(theta, phi)
    u0 = np.linspace(-0.5, 0.5, 5)
    px, py = S * V[0] / V[2], S * V[1] / V[2]
    t = (0.5 + 0.25 * (u0 - px)) / (1.0 - 0.25 * px)
    ok = (t > 0.0) & (t < 1.0 - 1.0 / n[0])  # the crossing exists and is not in the listing's first step
    for mid in METHODS:
        u, v, _ = run(method(mid, "ramp", n), u0, 0.0, V)
        np.testing.assert_allclose(u[ok], (u0 - px * (1.0 - t))[ok], atol=1e-12)
        np.testing.assert_allclose(v[ok], (-py * (1.0 - t))[ok], atol=1e-12)


def test_listing_first_segment_assumes_height_one():
    """Erratum (000:2004, fPrevHeight = 1.0): the first segment's upper end is taken at height 1, not
    h(uv₀). With one sample on the plane h = 0.5 (first sample already below), the listing intersects the
    segment (1, 1)–(0, 0.5): t* = 1, no offset at all; the stable variant samples h(uv₀) and is exact
    (t* = 0.5)."""
    V = view(math.radians(60.0), 0.0)
    px = S * V[0] / V[2]
    u_l, _, _ = run(method("listing", "plane", (1, 1)), 0.3, 0.3, V)
    u_s, _, _ = run(method("stable", "plane", (1, 1)), 0.3, 0.3, V)
    assert u_l[0] == pytest.approx(0.3, abs=1e-15)  # exact answer: 0.3 − P/2
    assert u_s[0] == pytest.approx(0.3 - px * 0.5, abs=1e-15)


# ------------------------------------------------------------------------------------------- hazards
def test_listing_normal_incidence_is_nan_stable_is_exact():
    """Hazard 0/0 at normal incidence (normalize((0, 0)) in listing 1): confirmed, in float32 and float64."""
    for dtype in (np.float32, np.float64):
        u, v, _ = run(method("listing", "bumps"), [0.1, 0.4], 0.3, (0.0, 0.0, 1.0), dtype=dtype)
        assert np.all(np.isnan(u)) and np.all(np.isnan(v))
        u, v, _ = run(method("stable", "bumps"), [0.1, 0.4], 0.3, (0.0, 0.0, 1.0), dtype=dtype)
        np.testing.assert_array_equal(u, np.asarray([0.1, 0.4], dtype))  # P = 0: the hit is uv₀ itself
        np.testing.assert_array_equal(v, np.asarray([0.3, 0.3], dtype))


def test_no_crossing_listing_nan_stable_floor():
    """Hazard NaN when no crossing is found (pt1 = pt2 = 0 → 0/0): on h = 0 with n = 8 (1/8 is exact in
    binary, the running bound ends at exactly 0 and 0 > 0 is false) the listing returns NaN; the stable
    variant returns the floor hit uv₀ − P, which is exact for this surface."""
    V = view(math.radians(50.0), 0.4)
    px = S * V[0] / V[2]
    u, _, _ = run(method("listing", "floor", (8, 8)), [0.2, 0.7], 0.5, V, dtype=np.float32)
    assert np.all(np.isnan(u))
    u, _, _ = run(method("stable", "floor", (8, 8)), [0.2, 0.7], 0.5, V, dtype=np.float32)
    np.testing.assert_allclose(u, np.array([0.2, 0.7]) - px, atol=2e-7)  # measured 3e-8 (float32)


def test_unclamped_offset_at_grazing():
    """Hazard unclamped parallax offsets: V_z = 0 → P infinite → non-finite hit (listing); stable clamps
    V_z to min_cos and stays within s/min_cos of uv₀."""
    V = (1.0, 0.0, 0.0)
    u, _, _ = run(method("listing", "bumps"), [0.3], 0.3, V, dtype=np.float32)
    assert not np.isfinite(u[0])
    m = method("stable", "bumps")
    u, _, _ = run(m, [0.3], 0.3, V, dtype=np.float32)
    assert np.isfinite(u[0]) and abs(u[0] - 0.3) <= S / m.fixed["min_cos"] + 1e-6


@settings(max_examples=30, deadline=None)
@given(theta_l=st.floats(math.radians(2.0), math.radians(88.0)), phi_l=azimuths, u=st.floats(-1.0, 1.0))
def test_shadow_ray_divided_by_lz_matches_true_ramp_shadowing(theta_l, phi_l, u):
    """Hazard: the shadow ray not divided by L_z (000:2086). On the ramp h = 0.5 + 0.25·u the surface is a
    plane with normal ∝ (−0.25·s, 0, 1): a light ray enters it (some sample under the surface) iff n·L < 0.
    The stable samples lie on the true light ray and agree with that for every L; the listing's samples
    rise 1/L_z times too fast and miss the self-shadowing where 0 < elevation < the plane's slope."""
    L = view(theta_l, phi_l)
    n = np.array([-0.25 * S, 0.0, 1.0])
    shadowed_true = float(n @ np.array(L)) < 0.0
    if abs(float(n @ np.array(L))) < 1e-9:
        return
    m = SHADOW_METHODS["stable-shadow"]
    m = dataclasses.replace(m, fixed={**m.fixed, "field": "ramp", "scale": S})
    inputs = {
        "u": np.array([u]),
        "v": np.array([0.0]),
        "lx": np.array([L[0]]),
        "ly": np.array([L[1]]),
        "lz": np.array([L[2]]),
    }
    # the first sample at f = 0.88 decides for a plane (sh_f ∝ f·(0.25·R_x − 1)): shadowed iff vis < 1
    vis = m(NUMPY_OPS, inputs, {"softening": 1.0, "floor": 0.0})
    lifted = max(L[2], m.fixed["min_cos"])
    if lifted == L[2]:
        assert (float(vis[0]) < 1.0) == shadowed_true


def test_listing_shadow_misses_the_ramps_self_shadow():
    """The listing's light offset s·L_xy: with the light 10° above the horizon facing down the ramp's slope
    (tan 10° = 0.176 < ... the plane rises 0.025 per unit, so the light is above the plane: lit) and 1° above
    (below the plane's horizon, tan 1° = 0.017 < 0.025: shadowed). The stable variant shadows the second; the
    listing's ray, not divided by L_z = sin 1°, rises ~57× too fast and reports it lit."""
    for mid, expect in (("stable", True), ("listing", False)):
        m = SHADOW_METHODS[f"{mid}-shadow"]
        m = dataclasses.replace(m, fixed={**m.fixed, "field": "ramp", "scale": S, "min_cos": 1e-3})
        L = (math.cos(math.radians(1.0)), 0.0, math.sin(math.radians(1.0)))
        inputs = {
            "u": np.array([0.0]),
            "v": np.array([0.0]),
            "lx": np.array([L[0]]),
            "ly": np.array([0.0]),
            "lz": np.array([L[2]]),
        }
        vis = float(m(NUMPY_OPS, inputs, {"softening": 1.0, "floor": 0.0})[0])
        assert (vis < 1.0) == expect, mid


def test_unclamped_visibility_overbrightens_flat_surfaces():
    """Erratum: 1 − max sh is not clamped before the 0.6/0.4 remap (000:2113-2117). On a flat field the
    largest sample is the first (−0.88·k), so the listing returns 0.6·(1 + 0.88·k) + 0.4 = 1 + 0.528·k > 1;
    the stable variant returns exactly 1."""
    for k in (0.25, 0.5, 2.0):
        _, _, s_l = run(method("listing", "plane"), [0.3], 0.3, view(0.5, 0.1), params={"softening": k})
        _, _, s_s = run(method("stable", "plane"), [0.3], 0.3, view(0.5, 0.1), params={"softening": k})
        assert s_l[0] == pytest.approx(1.0 + 0.528 * k, rel=1e-12)
        assert s_s[0] == 1.0


def test_lod_switch_pops_in_the_listing_only():
    """Hazard the LOD switch that pops (000:1960-2078): the listing keeps the shadow at full strength up to
    mip = T and drops it beyond; the stable variant's blend weight is continuous (measured max step over
    Δmip = 2e-3 across mip = T: listing > 0.05 (the shadow is dropped, and where the listing over-brightens
    it drops from > 1), stable ≤ 1e-3·|1 − raw shadow| ≤ 1e-3)."""
    T = METHODS["listing"].fixed["lod_threshold"]
    V, L = view(math.radians(50.0), 0.5), view(math.radians(75.0), math.radians(200.0))
    u0 = np.linspace(0.05, 0.95, 10)
    for mid in METHODS:
        m = method(mid, "bumps")
        below = run(m, u0, 0.3, V, L, mip=T - 1e-3)
        above = run(m, u0, 0.3, V, L, mip=T + 1e-3)
        jump = np.max(np.abs(above[2] - below[2]))
        if mid == "listing":
            assert jump > 0.05  # the pop: confirmed
        else:
            assert jump <= 1e-3 + 1e-7  # w moves by 1e-3 and |1 − raw shadow| ≤ 1 (float64)


def test_drjit_run_matches_numpy_run():
    """The Dr.Jit run (product) and the NumPy run of the same text, float32, bumps field: measured max
    |Δu| = |Δv| = 6e-8 (one ulp near 1), |Δshadow| = 0; the tolerance leaves room for other CPUs' sin."""
    rng = np.random.default_rng(1)
    n = 256
    th = rng.uniform(0.0, 1.3, n)
    ph = rng.uniform(-3, 3, n)
    V = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    inputs = {
        "u0": rng.random(n),
        "v0": rng.random(n),
        "vx": V[0],
        "vy": V[1],
        "vz": V[2],
        "lx": np.full(n, 0.5),
        "ly": np.full(n, 0.0),
        "lz": np.full(n, math.sqrt(0.75)),
        "mip": rng.uniform(0, 5, n),
    }
    inputs = {k: v.astype(np.float32) for k, v in inputs.items()}
    m = method("stable", "bumps", (4, 12))  # a short unrolled loop: the Dr.Jit compilation dominates
    a = m.evaluate(inputs)
    with np.errstate(all="ignore"):
        b = m(NUMPY_OPS, inputs)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=2e-5)


# ------------------------------------------------------------------------------------------ reference
def test_square_irradiance_matches_quadrature():
    """Lambert's polygon formula against a 400×400 midpoint quadrature of L·cos·cos′/r² over the square
    (measured relative difference 2.8e-7)."""
    from rtfit.reference.parallax_occlusion import rectangle_light, square_irradiance

    light = rectangle_light(np.array(view(0.7, 2.0)), 3.0, 1.0, 2.0)
    c = np.asarray(light["center"])
    nl = np.asarray(light["normal_to"]) - c
    nl /= np.linalg.norm(nl)
    a = np.cross(nl, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(nl, a)
    k = 400
    g = (np.arange(k) + 0.5) / k - 0.5
    A, B = np.meshgrid(g, g)
    y = c + A.reshape(-1, 1) * a + B.reshape(-1, 1) * b
    x = np.array([0.2, 0.9, 0.0])
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    d = y - x
    r2 = np.sum(d * d, -1)
    w = d / np.sqrt(r2)[:, None]
    e = 2.0 * np.sum(np.maximum(w @ n, 0) * np.maximum(-(w @ nl), 0) / r2) / k**2
    assert square_irradiance(x, n, light) == pytest.approx(e, rel=2e-5)


def test_exact_hits_on_a_flat_mesh_match_the_closed_form():
    """Mitsuba ray_intersect on a flat displaced mesh (h = 0.5) against the closed-form hit (float32
    positions: measured max 3.7e-8)."""
    from rtfit.reference import parallax_occlusion as ref
    from rtfit.reference.variants import use_variant

    mi = use_variant("auto")
    grid = ref.HeightFieldMesh(np.full((5, 5), 0.5), -2.0, 3.0, -2.0, 3.0, S)
    scene = ref.height_field_scene(mi, grid)
    V = np.array(view(math.radians(70.0), 0.3))
    o = np.array([[0.2, 0.4, 0.0], [0.8, 0.1, 0.0]]) + 1e-3 * V
    p, n, valid = ref.exact_hits(mi, scene, o, np.tile(-V, (2, 1)))
    assert valid.all()
    t = (o[:, 2] + 0.5 * S) / V[2]
    np.testing.assert_allclose(p, o - t[:, None] * V, atol=1e-6)
    np.testing.assert_allclose(n, np.tile([0.0, 0.0, 1.0], (2, 1)), atol=1e-6)


def _square_light(mi, light: dict):
    """A Mitsuba rectangle shape with an area emitter for a `rectangle_light` dict (side ``size``, facing
    ``normal_to``); keep the shape alive while its ``emitter()`` is used."""
    c, t = [float(x) for x in light["center"]], [float(x) for x in light["normal_to"]]
    half = 0.5 * light["size"]
    return mi.load_dict({
        "type": "rectangle",
        "to_world": mi.ScalarTransform4f().look_at(origin=c, target=t, up=[0.0, 0.0, 1.0])
        @ mi.ScalarTransform4f().scale([half, half, 1.0]),
        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": light["radiance"]}},
    })  # fmt: skip


def test_emitter_visibility_against_lambert_and_a_blocker():
    """`emitter_visibility` (Mitsuba's own light sampling) on a flat field: the unoccluded irradiance against
    Lambert's closed-form polygon irradiance (4096 samples: relative σ ≈ 2e-3; measured max 3e-3), nothing
    occluded (V = 1, σ 0); under a plane between the points and the light, nothing arrives (V = 0)."""
    from rtfit.reference import parallax_occlusion as ref
    from rtfit.reference.variants import use_variant

    mi = use_variant("auto")
    light = ref.rectangle_light(np.array(view(math.radians(60.0), 0.5)), 3.0, 1.0, 4.0)
    shape = _square_light(mi, light)
    emitter = shape.emitter()
    pts = np.array([[0.5, 0.5, 0.0], [0.1, 0.9, 0.0], [0.8, 0.3, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (3, 1))
    flat = ref.height_field_scene(mi, ref.HeightFieldMesh(np.ones((3, 3)), -5.0, 5.0, -5.0, 5.0, S))
    lv = ref.emitter_visibility(mi, emitter, flat, pts, nrm, 4096, seed=1)
    exact = np.array([ref.square_irradiance(p, n, light) for p, n in zip(pts, nrm, strict=True)])
    np.testing.assert_allclose(lv.e_unoccluded, exact, rtol=1e-2)
    assert np.all(lv.visibility == 1.0) and not lv.visibility_stderr.any()
    lid = ref.mesh_scene(mi, np.array([[-9, -9, 0.5], [9, -9, 0.5], [9, 9, 0.5], [-9, 9, 0.5]], float),
                         np.array([[0, 1, 2], [0, 2, 3]]))  # fmt: skip
    lv = ref.emitter_visibility(mi, emitter, lid, pts, nrm, 256, seed=2)
    assert np.all(lv.e_occluded == 0.0) and np.all(lv.visibility == 0.0) and np.all(lv.e_unoccluded > 0)


def test_displaced_hits_give_the_texture_coordinates_of_the_hit():
    """`displaced_hits` on a grid over UV [0, 1]² laid out as the plane z = −0.05 over [−½, ½]² (u = x + ½,
    v = y + ½): the hit's (u, v) from its barycentric coordinates equals the closed-form ray-plane hit's."""
    from rtfit.reference import parallax_occlusion as ref
    from rtfit.reference.variants import use_variant

    mi = use_variant("auto")
    n = 8
    xs = np.linspace(-0.5, 0.5, n + 1)
    X, Y = np.meshgrid(xs, xs)
    pos = np.stack([X.ravel(), Y.ravel(), np.full(X.size, -0.05)], axis=1)
    faces = ref._grid_faces(n + 1, n + 1)
    shape = ref.DisplacedShape(pos, faces, (n, n), (0.0, 1.0, 0.0, 1.0), 1.0 / n)
    rng = np.random.default_rng(4)
    o = np.column_stack([rng.uniform(-0.3, 0.3, (50, 2)), np.full(50, 1.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, (50, 2)), np.full(50, -1.0)])
    p, _, uv, valid = ref.displaced_hits(mi, shape, shape.scene(mi), o, d)
    assert valid.all()
    t = (o[:, 2] + 0.05) / -d[:, 2]
    want = o[:, :2] + t[:, None] * d[:, :2] + 0.5
    np.testing.assert_allclose(uv, want, atol=2e-6)
    np.testing.assert_allclose(p[:, :2] + 0.5, want, atol=2e-6)


def test_shipped_scenes_and_study_through_the_engine(tmp_path):
    """``rtfit run parallax-occlusion`` on the engine (issue 30 §1): the registry entry, the shipped floor
    (one texture unit = one scene unit: L = 1, so the carved depth in scene units is --pom-depth), its audit
    against Mitsuba's first hits on the displaced mesh, and the study's checks."""
    import rtfit
    from rtfit.experiments import audit_parallax_occlusion, parallax_occlusion_study
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes.parse import LIBRARY_DIR as lib

    fam = FAMILIES["parallax-occlusion"]
    assert fam.module == ENGINE and fam.scenes == audit_parallax_occlusion.SCENES
    assert fam.study.target is parallax_occlusion_study.study
    assert len(fam.scenes) == 6 and [s.name for s in fam.scenes if s.quick] == ["45deg-d0p15"]
    assert all((lib / s.file).is_file() for s in fam.scenes)
    assert (lib / "parallax_occlusion_bumps.exr").is_file()
    scene = next(s for s in fam.scenes if s.quick)
    r = rtfit.audit(lib / scene.file, "parallax-occlusion", defines=dict(scene.defines), cache=tmp_path / "c",
                    width=12, height=12, spp=64, metrics=("rmse",), cost_elements=4096,
                    tag=(f"{scene.name}-", ""), **dict(scene.options))  # fmt: skip
    case, shadow = r.cases
    p = case.parameters
    assert p["texel_length"] == pytest.approx(1.0, rel=1e-4)
    assert p["depth_scene"] == pytest.approx(0.15, rel=1e-4)
    assert p["lookup"] == "32×32 texels, bilinear, wrap clamp"
    rmse = {k: o.metrics["rmse"].value for k, o in r.outcomes[case.id].items()}
    assert rmse["pom-stable-n16-64"] < rmse["pom-stable"] < rmse["pom-listing"] < 0.05
    assert rmse["pom-stable-n16-64"] < 2e-3  # against Mitsuba's hits on the displaced mesh
    # the soft shadow toward the scene's area light: the stable form fitted beats its declared form, no shadow
    assert shadow.quantity == "parallax_shadow" and shadow.parameters["light"] == "light"
    assert 0.5 < shadow.parameters["mean_visibility"] < 0.95  # the egg crate shadows itself at θ_l = 70°
    sh = {k: o.metrics["rmse"].value for k, o in r.outcomes[shadow.id].items()}
    assert sh["pom-stable-shadow-fitted"] < sh["pom-stable-shadow"] < sh["pom-listing-shadow"]
    assert sh["pom-stable-shadow-fitted"] < sh["pom-no-shadow"]
    res = parallax_occlusion_study.study(StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "c", (r,)))
    assert res.checks and all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    assert (
        len(res.checks) == 9
    )  # samples, mesh vs root finder, mesh's own error, Lambert, R hazard, 4 hazards
    # normalize((0, 0)) is 0/0 at every pixel for the printed listing; the stable form clamps it
    assert res.extra["hazards"]["normal_incidence"] == {"listing": 64, "stable": 0}
    assert [row["row"] for row in res.extra["samples"]] == list(parallax_occlusion_study.SAMPLE_ROWS)
