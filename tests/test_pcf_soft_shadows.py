"""The pcf-soft-shadows family: its kernels against independent values (a half-plane blocker's PCF by the
one-dimensional bilinear weight, the penumbra of a disc light over an edge by quadrature), the shadow map the
audit casts against the scene's known surfaces, the shadowed reference against a quadrature of the sphere
light's visible cap, the extremes without NaN/Inf, ``--list``, an XML and a TOML audit, and the engine run."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime import pcf_soft_shadows as pcf
from rtfit.realtime.pcf_soft_shadows import FAR, POISSON8, POISSON16, ShadowMap, map_frame, pcf_visibility

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SHIPPED = LIBRARY / "pcf_soft_shadows_sphere.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
FAMILY = "pcf-soft-shadows"
PCF_ROWS = ("poisson8", "poisson8-rotated", "poisson16-rotated", "box3", "box5")


# ------------------------------------------------------------------------------------------------ oracles
def _half_plane(w: int = 64, k: int = 32, blocker: float = 2.0, floor: float = 10.0) -> np.ndarray:
    """Texel columns i < k hold the blocker's depth, the rest the floor's."""
    d = np.full((w, w), floor)
    d[:, :k] = blocker
    return d


def _half_plane_pcf(u, offsets, radius, rotation, w=64, k=32):
    """A half-plane blocker (columns < k) seen by bilinear taps: each tap at x = uW − ½ (texels) is lit by
    the fraction of its 2 × 2 footprint right of the edge, clamp(x − (k − 1), 0, 1) — one dimension, no
    gather: the value the 2-D kernel must give."""
    c, s = math.cos(rotation), math.sin(rotation)
    vals = []
    for ox, oy in offsets:
        rx = ox * c - oy * s
        x = (u + rx * radius / w) * w - 0.5
        vals.append(np.clip(x - (k - 1), 0.0, 1.0))
    return np.mean(vals, axis=0)


@pytest.mark.parametrize("method", PCF_ROWS)
def test_pcf_of_a_half_plane_is_the_bilinear_fraction_of_its_taps(method):
    """At ≥ 3 points across the edge (and for the seed's fixed and rotated forms) the kernel equals the 1-D
    closed form of `_half_plane_pcf` to 1e-12; far from the edge 0 (shadowed) or 1 (lit)."""
    m = pcf.METHODS[method]
    offsets, rotate = m.fixed["offsets"], m.fixed["rotate"]
    sm = ShadowMap(_half_plane())
    u = np.array([0.40, 0.47, 0.49, 0.5, 0.51, 0.53, 0.60])
    for radius, rotation in ((1.0, 0.0), (2.5, 0.7), (4.0, 2.1)):
        got = pcf_visibility(method, u, 0.5, 5.0, sm, rotation=rotation, radius=radius, bias=0.0)
        want = _half_plane_pcf(u, offsets, radius, rotation if rotate else 0.0)
        assert np.allclose(got, want, atol=1e-12), (method, radius, got, want)
    assert got[0] == 0.0 and got[-1] == 1.0


@pytest.mark.parametrize("method", PCF_ROWS)
def test_kept_texels_follow_radius_and_bias_on_the_same_arrays(method):
    """The fit's NumPy run on the same input arrays again and again (a scan, TRF steps) keeps the texels of
    each radius (`_kept`): at every (r, b) of a sequence that changes one, then the other, and comes back,
    the row equals `_half_plane_pcf` (b = 3.5 lifts the receiver at 5 above the blocker at 2: all lit)."""
    m = pcf.METHODS[method]
    offsets, rotate = m.fixed["offsets"], m.fixed["rotate"]
    u = np.array([0.40, 0.47, 0.49, 0.5, 0.51, 0.53, 0.60])
    rotation = 0.7
    inputs = {"irradiance": np.ones_like(u), "u": u, "v": np.full_like(u, 0.5), "depth": np.full_like(u, 5.0),
              "rotation": np.full_like(u, rotation), "shadow_map": ShadowMap(_half_plane())}  # fmt: skip
    for radius, bias in ((1.0, 0.0), (2.5, 0.0), (1.0, 3.5), (1.0, 0.0), (2.5, 1.0), (4.0, 3.5), (2.5, 0.0)):
        got = m(NUMPY_OPS, inputs, {"radius": radius, "bias": bias})
        want = 1.0 if bias > 3.0 else _half_plane_pcf(u, offsets, radius, rotation if rotate else 0.0)
        assert np.allclose(got, want, atol=1e-12), (method, radius, bias, got, want)
    hard = pcf.METHODS["hard"]
    for bias, want in ((0.0, u >= 0.5), (3.5, u >= 0.0), (0.0, u >= 0.5)):
        assert np.array_equal(hard(NUMPY_OPS, inputs, {"bias": bias}), want.astype(float)), bias


def test_fits_run_the_kernel_text_on_dr_jit_and_recover_a_known_radius():
    """Every row fits through float64 Dr.Jit (`Method.fit_ops` "drjit", issue 33: the Cornell box's pcf fits
    2.9 s → 1.6 s; values moved ≤ 3e-11, stderr ≤ 1e-8 relative). Data made by each PCF row itself at
    r = 2.7, b = 0 across the half plane's edge (the closed form `_half_plane_pcf` checks the data): the fit
    from the declared start (r 1.5, after the scan) recovers r = 2.7 to 1e-6, and equals the NumPy run's
    fit to 1e-9."""
    import dataclasses

    from rtfit.fitting import fit_method

    u = np.linspace(0.42, 0.58, 97)
    rotation = 0.7
    inputs = {"irradiance": np.ones_like(u), "u": u, "v": np.full_like(u, 0.5), "depth": np.full_like(u, 5.0),
              "rotation": np.full_like(u, rotation), "shadow_map": ShadowMap(_half_plane())}  # fmt: skip
    assert {m.fit_ops for m in pcf.METHODS.values()} == {"drjit"}
    for mid in PCF_ROWS:
        m = pcf.METHODS[mid]
        target = m(NUMPY_OPS, inputs, {"radius": 2.7, "bias": 0.0})
        want = _half_plane_pcf(u, m.fixed["offsets"], 2.7, rotation if m.fixed["rotate"] else 0.0)
        assert np.allclose(target, want, atol=1e-12), mid
        only_r = {"params": {"radius": m.params["radius"]}, "held": {"bias": 0.0}}
        fit = fit_method(m, inputs, target, solver="trf", **only_r)
        assert fit.values["radius"] == pytest.approx(2.7, rel=1e-6), mid
        numpy_m = dataclasses.replace(m, fit_ops="numpy")
        numpy_fit = fit_method(numpy_m, inputs, target, solver="trf", **only_r)
        assert fit.values["radius"] == pytest.approx(numpy_fit.values["radius"], rel=1e-9), mid


def test_bias_and_hard_compare():
    """The hard row is one nearest texel; the bias moves the receiver towards the light: a receiver at depth
    2.05 against a blocker texel at 2 is shadowed at b < 0.05 and lit at b > 0.05."""
    sm = ShadowMap(_half_plane())
    assert pcf_visibility("hard", 0.25, 0.5, 5.0, sm, bias=0.0) == 0.0
    assert pcf_visibility("hard", 0.75, 0.5, 5.0, sm, bias=0.0) == 1.0
    assert pcf_visibility("hard", 0.25, 0.5, 2.05, sm, bias=0.04) == 0.0
    assert pcf_visibility("hard", 0.25, 0.5, 2.05, sm, bias=0.06) == 1.0
    outside = pcf_visibility("box3", np.array([-0.5, 1.5]), 0.5, 5.0, sm, radius=2.0, bias=0.0)
    assert np.all(outside == 1.0)  # the border reads FAR: nothing occludes outside the frustum


def _disc_edge_visibility(t: float, n: int = 2001) -> float:
    """The fraction of a unit disc with x ≥ t, by midpoint quadrature over x of the chord length."""
    x = -1.0 + (np.arange(n) + 0.5) * (2.0 / n)
    chord = 2.0 * np.sqrt(np.clip(1.0 - x * x, 0.0, None))
    return float(np.sum(chord * (x >= t)) * (2.0 / n) / math.pi)


def test_pcss_penumbra_of_a_disc_light_over_an_edge_matches_quadrature():
    """A disc light of radius R at the map's centre facing the receivers, a half-plane blocker (x < 0) at
    axial depth z_b = 2 over a floor at z_r = 5: a receiver at lateral x sees the light through the edge where
    the line to a light point (ℓ, ·) crosses depth z_b at x + (ℓ − x)(z_r − z_b)/z_r ≥ 0, i.e. the disc's part
    ℓ ≥ −x z_b/(z_r − z_b): the fraction by quadrature. PCSS (s = 1) on a 1024² map: within 0.09 of it at
    every point across the penumbra (16 taps: ±1/16 steps; bilinear taps), 0 in the umbra, 1 outside;
    the seed's fixed 8-tap PCF with a 2-texel radius is a near-hard edge there (its penumbra is the map's)."""
    res, tan_half, big_r, z_b, z_r = 1024, 0.5, 0.3, 2.0, 5.0
    c = (np.arange(res) + 0.5) / res * 2.0 - 1.0  # s = 2u − 1 of each texel column
    lateral_at_zb = c * tan_half * z_b
    depth = np.where(lateral_at_zb[None, :] < 0.0, z_b, z_r) * np.ones((res, 1))
    sm = ShadowMap(depth, light_size=big_r / (2.0 * tan_half), near=z_b)
    x = np.linspace(-0.5, 0.5, 21)  # receivers' lateral offsets on the floor
    u = 0.5 + 0.5 * x / (z_r * tan_half)
    got = pcf_visibility("pcss", u, 0.5, z_r, sm, rotation=0.3, light_scale=1.0, bias=1e-3)
    want = np.array([_disc_edge_visibility(-xi * z_b / ((z_r - z_b) * big_r)) for xi in x])
    assert np.max(np.abs(got - want)) < 0.09, np.c_[x, got, want]
    assert got[0] == 0.0 and got[-1] == 1.0
    seed = pcf_visibility("poisson8", u, 0.5, z_r, sm, radius=2.0, bias=1e-3)
    assert np.sum((seed > 0.0) & (seed < 1.0)) <= 1  # 2 texels ≪ the penumbra's 0.2 m width


def test_poisson_discs_are_spread_in_the_unit_disc():
    """Our offsets (the seed prints none): inside the unit disc, no two closer than 0.35 (8) / 0.25 (16)."""
    for pts, gap in ((POISSON8, 0.35), (POISSON16, 0.25)):
        p = np.array(pts)
        assert np.all(np.linalg.norm(p, axis=1) <= 1.0)
        d = np.linalg.norm(p[:, None] - p[None], axis=2) + np.eye(len(p)) * 9
        assert d.min() > gap, d.min()


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=150, deadline=None)
@given(
    u=st.floats(-0.2, 1.2),
    v=st.floats(-0.2, 1.2),
    depth=st.floats(1e-3, 100.0),
    rotation=st.floats(0.0, 2.0 * math.pi),
    radius=st.floats(0.0, 64.0),
    bias=st.floats(0.0, 10.0),
    scale=st.floats(0.0, 20.0),
    light_size=st.sampled_from([0.0, 1e-6, 0.05, 10.0, 1e4]),  # none, tiny … huge light
    near=st.sampled_from([1e-9, 1e-3, 1.0, 50.0]),
    ortho=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_every_row_finite_and_in_range_over_the_domain(
    u, v, depth, rotation, radius, bias, scale, light_size, near, ortho, seed
):
    """Random depth maps (with FAR texels), receivers anywhere (also grazing: depth equal to the texels', or
    outside the map), bias 0, tiny and huge lights: every row finite and in [0, E]."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(1e-3, 60.0, (16, 16))
    d[rng.random((16, 16)) < 0.2] = FAR
    sm = ShadowMap(d, ortho=ortho, light_size=light_size, near=near)
    inputs = {
        "irradiance": np.array([1.0, 2.0]),
        "u": np.array([u, u]),
        "v": np.array([v, v]),
        "depth": np.array([depth, d[8, 8]]),
        "rotation": np.array([rotation, rotation]),
        "shadow_map": sm,
    }
    for mid, m in pcf.METHODS.items():
        params = {"radius": radius, "bias": bias, "light_scale": scale}
        # the fit's NumPy run: no overflow, no 0/0 or x/0 on the way (underflow is harmless)
        with np.errstate(over="raise", divide="raise", invalid="raise", under="ignore"):
            e = m(NUMPY_OPS, inputs, {k: val for k, val in params.items() if k in m.params})
        assert np.all(np.isfinite(e)) and np.all((e >= 0.0) & (e <= inputs["irradiance"])), (mid, e)


def test_drjit_float32_agrees_with_numpy_float64():
    """The audit evaluates with Dr.Jit, the fit with NumPy: on a random map and receivers away from the
    texels' own depths the two runs agree to 1e-6 for every row."""
    rng = np.random.default_rng(3)
    d = rng.uniform(1.0, 3.0, (32, 32))
    sm = ShadowMap(d, light_size=0.05, near=1.0)
    n = 200
    inputs = {
        "irradiance": np.ones(n),
        "u": rng.uniform(0, 1, n),
        "v": rng.uniform(0, 1, n),
        "depth": rng.uniform(3.5, 5.0, n) - 2.0 * (rng.random(n) < 0.5),
        "rotation": rng.uniform(0, 6, n),
        "shadow_map": sm,
    }
    for mid, m in pcf.METHODS.items():
        a = m(NUMPY_OPS, inputs)
        b = np.asarray(m.evaluate({k: (v.astype(np.float32) if isinstance(v, np.ndarray) else v)
                                   for k, v in inputs.items()}), np.float64)  # fmt: skip
        assert np.max(np.abs(a - b)) < 1e-6 or np.mean(np.abs(a - b) > 1e-6) < 0.02, mid


def test_public_functions_say_what_is_wrong_in_one_line():
    with pytest.raises(ValueError, match="unknown method 'pcf9'"):
        pcf_visibility("pcf9", 0.5, 0.5, 1.0, ShadowMap(np.ones((2, 2))))
    with pytest.raises(ValueError, match="positive depths"):
        ShadowMap(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="no parameter radius"):
        pcf_visibility("pcss", 0.5, 0.5, 1.0, ShadowMap(np.ones((2, 2))), radius=1.0)


# ------------------------------------------------------------------------------------------------ audits
PLATE_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -4, 5" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="20"/></film>
    </sensor>
    <shape type="sphere">
        <point name="center" x="0" y="0" z="3"/>
        <float name="radius" value="0.3"/>
        <emitter type="area"><rgb name="radiance" value="30"/></emitter>
    </shape>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    <shape type="rectangle" id="plate">
        <transform name="to_world"><scale value="0.5"/><translate z="1"/></transform>
        <bsdf type="diffuse"/>
    </shape>
</scene>
"""
"""A floor (z = 0, ±3), a square plate (z = 1, ±0.5) and a sphere light (radius 0.3, L = 30) 3 m above."""


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    d = tmp_path_factory.mktemp("pcfplate")
    path = d / "plate.xml"
    path.write_text(PLATE_XML)
    return path, audit(str(path), approximations=[FAMILY], spp=256, cache=d / "c", **FAST)


def _cap_visibility(points: np.ndarray, n: int = 96) -> np.ndarray:
    """E_s/L at floor points (z = 0, normal +z) under the sphere light (c = (0, 0, 3), r = 0.3) with the plate
    (|x|, |y| ≤ 0.5 at z = 1) as the only occluder: midpoint quadrature over the cap's (cos θ', φ) — the cone
    of half-angle α = asin(r/d) about the direction to the centre — of max(n·ω, 0) for the unblocked ω."""
    c = np.array([0.0, 0.0, 3.0])
    out = np.empty(len(points))
    for i, x in enumerate(points):
        t = c - x
        dist = np.linalg.norm(t)
        t /= dist
        cos_a = math.sqrt(1.0 - (0.3 / dist) ** 2)
        mu = cos_a + (1.0 - cos_a) * (np.arange(n) + 0.5) / n
        phi = 2.0 * math.pi * (np.arange(n) + 0.5) / n
        mu, phi = np.meshgrid(mu, phi)
        sin = np.sqrt(1.0 - mu * mu)
        e1, e2 = map_frame(t)
        w = mu[..., None] * t + sin[..., None] * (np.cos(phi)[..., None] * e1 + np.sin(phi)[..., None] * e2)
        s = (1.0 - x[2]) / w[..., 2]  # the ray's parameter at the plate's height
        hx, hy = x[0] + s * w[..., 0], x[1] + s * w[..., 1]
        blocked = (s > 0) & (np.abs(hx) <= 0.5) & (np.abs(hy) <= 0.5)
        cos_n = np.clip(w[..., 2], 0.0, None)
        out[i] = np.sum(cos_n * ~blocked) * 2.0 * math.pi * (1.0 - cos_a) / mu.size
    return out


def test_plate_audit_reference_map_and_rows(plate):
    """The shadow map's texels reconstruct to points on the floor or the plate (its depth along the axis);
    the receivers on the floor read their own depth; the shadowed reference at floor points equals the
    quadrature of the cap's unblocked part (`_cap_visibility`, × L) within its noise (|z| mean < 0.5, max
    < 4.5); every row finite, PCSS the best and the hard shadow map the worst on the 1024² map."""
    _path, r = plate
    assert [c.id for c in r.cases] == ["light0-map1024", "light0-map256"]
    case = r.cases[0]
    g = case.channel_inputs[0]
    sm = g["shadow_map"]
    assert sm.resolution == (1024, 1024) and not sm.ortho
    axis, origin = np.array(sm.axis), np.array(sm.origin)
    assert np.allclose(origin, [0, 0, 3])
    e1, e2 = map_frame(axis)
    cs = ((np.arange(1024) + 0.5) / 1024 * 2.0 - 1.0) * sm.size
    sx, sy = np.meshgrid(cs, cs)
    hit = sm.depth < FAR
    p = origin + sm.depth[..., None] * (axis + sx[..., None] * e1 + sy[..., None] * e2)
    tol = 1e-3  # float32 ray casts 3–6 m long: measured ≤ 3.3e-4 off the surfaces
    on_floor = np.abs(p[..., 2]) < tol
    on_plate = (
        (np.abs(p[..., 2] - 1.0) < tol) & (np.abs(p[..., 0]) <= 0.5 + tol) & (np.abs(p[..., 1]) <= 0.5 + tol)
    )
    assert np.all(on_floor[hit] | on_plate[hit]) and on_plate.sum() > 1000
    # the reference on the floor against the cap quadrature
    points = np.asarray(r.gbuffer.position)[case.mask].astype(np.float64)
    floor = np.abs(points[:, 2]) < 1e-4
    assert floor.sum() > 100
    want = 30.0 * _cap_visibility(points[floor])
    ref = case.reference.mean[case.mask][floor, 0]
    err = case.reference.stderr[case.mask][floor, 0]
    ok = err > 0
    z = (ref[ok] - want[ok]) / err[ok]
    assert abs(float(np.mean(z))) < 0.5 and float(np.max(np.abs(z))) < 4.5, (np.mean(z), np.max(np.abs(z)))
    assert np.any(want < 0.5 * want.max())  # some floor pixels are in the plate's shadow
    # receivers read their own depth (lit floor: within a texel's slope of the texel's own)
    assert np.all(g["depth"] > 0) and np.all((g["u"] >= 0) & (g["u"] <= 1))
    rows = r.outcomes[case.id]
    assert set(rows) == {f"{m}-fitted" for m in pcf.METHODS}
    for row in rows.values():
        assert np.all(np.isfinite(row.image[case.mask]))
    # the bias is a step (zero derivative): scanned, not left at its start without a word
    for fit in r.results.fits:
        assert "left at its start" not in (fit.message or ""), (fit.id, fit.message)
    rmse = {k: row.metrics["rmse"].value for k, row in rows.items()}
    assert rmse["pcss-fitted"] == min(rmse.values()) and rmse["hard-fitted"] == max(rmse.values()), rmse
    low = r.outcomes["light0-map256"]
    assert set(low) == {"hard-fitted", "poisson8-rotated-fitted", "pcss-fitted"}


def test_list_names_the_family_with_its_reason():
    result = CliRunner().invoke(audit_cmd, [str(SHIPPED), "--list"])
    assert result.exit_code == 0, result.output
    assert "pcf-soft-shadows — soft shadows (shadow-map filtering): sphere area light" in result.output
    assert "hard, poisson8, poisson8-rotated, poisson16-rotated, box3, box5, pcss" in result.output


def test_toml_sphere_light_scene_audits(tmp_path):
    """rtfit's own TOML sphere_light scene (a sphere on a floor under a sphere light): both cases, every row
    finite (the seed's row and PCSS, fitted), the sphere's shadow on the floor (some pixels' reference well
    below the unshadowed E)."""
    rows = [f"{FAMILY}:poisson8-rotated", f"{FAMILY}:pcss"]
    r = audit(str(LIBRARY / "sphere_light.toml"), approximations=rows, width=16, height=16, spp=32,
              cache=tmp_path / "c", **FAST)  # fmt: skip
    assert [c.id for c in r.cases] == ["light0-map1024", "light0-map256"]
    case = r.cases[0]
    e = case.channel_inputs[0]["irradiance"]
    ref = case.reference.mean[case.mask][:, 0]
    assert np.any(ref < 0.3 * e) and np.all(e >= 0)
    assert set(r.outcomes[case.id]) == {"poisson8-rotated-fitted", "pcss-fitted"}
    for row in r.outcomes[case.id].values():
        assert np.all(np.isfinite(row.image[case.mask]))


def test_registry_entry_is_born_on_the_engine_and_runs(tmp_path):
    """``rtfit run pcf-soft-shadows --quick`` through the engine: the large sphere light's two cases, the
    fitted-parameter file, no failed check."""
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.registry import ExperimentSpec
    from rtfit.experiments.results import load_results
    from rtfit.experiments.run_settings import RunSettings
    from rtfit.experiments.runner import failed_checks, run_experiments

    f = FAMILIES[FAMILY]
    assert f.module == ENGINE and f.methods is pcf.METHODS
    assert {s.file for s in f.scenes} == {SHIPPED.name, "pcf_soft_shadows_rect.xml"}
    assert all((LIBRARY / s.file).is_file() for s in f.scenes)
    spec = ExperimentSpec(FAMILY, ENGINE, f.title, f.description)
    run_experiments([spec], tmp_path / "out", RunSettings(tmp_path / "c", "llvm_ad_rgb", spp=8, quick=True))
    d = tmp_path / "out" / FAMILY
    res = load_results(d)
    assert [c.id for c in res.cases] == ["sphere-r0p4-light0-map1024", "sphere-r0p4-light0-map256"]
    assert not failed_checks(res) and (d / "fitted" / f"{FAMILY}.json").is_file()
    # every row's shader text reads the case's map from one binding of its W·H depths plus the border
    from rtfit.experiments.fitted import load_fitted

    methods = load_fitted(d / "fitted" / f"{FAMILY}.json").methods
    sizes = {m.case: {(b.name, b.floats, b.kind) for b in m.shader.tables} for m in methods if m.shader}
    assert len(sizes) == 2 and all(m.shader is not None for m in methods), [m.shader_note for m in methods]
    assert sizes["sphere_r0p4_light0_map256"] == {("shadow_map", 256 * 256 + 1, "buffer")}
