"""The light-path-maps family (rtfit/realtime/light_path_maps.py, experiments/audit_light_path_maps.py)
against independent values only.

Oracles: the transfer τ by hand (a VPL under a point that faces it: 1/(π h²); the seed's cut: 1/(π d_c²);
behind the VPL: 0); a diffuse disc of albedo a lit uniformly (E₀) under a point facing it at height h: the
entry points' VPL sum against the closed form E = a·E₀/(1 + h²) on the axis and a scipy quadrature of
cos θ cos θ'/(π r²) off it, with every K (uniform light: the cluster means are exact) and with a light that
varies across the disc (K = N entry points: the plain VPL sum term by term); a moved point light against
I·cos θ/d² at its new position (Mitsuba's emitter sampling); and on the shipped box the reference's red/green
bounce following the light towards the red and the green wall, the path maps following it too.
"""

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
from rtfit.realtime import light_path_maps as lpm
from rtfit.realtime.arrays import NUMPY_OPS

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SHIPPED = LIBRARY / "light_path_maps_box.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
FAMILY = "light-path-maps"


def _tau(h, rho2, q, c, cut):
    return float(np.squeeze(lpm.vpl_transfer(NUMPY_OPS, np.float64(h), np.float64(rho2), np.float64(q),
                                              np.float64(c), cut)))  # fmt: skip


# ------------------------------------------------------------------------------------------------ kernels
def test_transfer_by_hand():
    """A VPL at the origin (normal +z), a point at height h facing it (n_x = −z: q = h, c = −1): τ = 1/(π h²)
    above the cut; below it the point is moved up to d_c: 1/(π d_c²); behind the VPL (h < 0): 0; a wall point
    near the corner (n_x = +x, VPL ρ along +x, height h < d_c: q = ρ, c = 0): d_c ρ/(π(ρ² + d_c²)²)."""
    assert _tau(0.5, 0.0, 0.5, -1.0, 0.1) == pytest.approx(1.0 / (math.pi * 0.25), rel=1e-14)
    assert _tau(0.05, 0.0, 0.05, -1.0, 0.2) == pytest.approx(1.0 / (math.pi * 0.04), rel=1e-14)
    assert _tau(-0.3, 0.1, 0.3, 1.0, 0.2) == 0.0
    rho, h, dc = 0.3, 0.01, 0.1
    assert _tau(h, rho * rho, rho, 0.0, dc) == pytest.approx(dc * rho / (math.pi * (rho**2 + dc**2) ** 2))
    # the general pair without the cut: cos θ_y cos θ_x/(π r²) from the vectors
    y, ny = np.zeros(3), np.array([0.0, 0.0, 1.0])
    x, nx = np.array([0.4, -0.2, 0.7]), np.array([-0.3, 0.1, -0.9]) / math.sqrt(0.91)
    v = x - y
    r2 = v @ v
    want = (v @ ny) * (nx @ -v) / (math.pi * r2 * r2)
    got = _tau(v @ ny, r2 - (v @ ny) ** 2, nx @ -v, nx @ ny, 0.0)
    assert got == pytest.approx(want, rel=1e-12)


def test_walk_reads_the_first_k_panes():
    g = {f"pane{k}": float(k) for k in range(1, lpm.KMAX + 1)} | {
        f"w{k}": 0.5 for k in range(1, lpm.KMAX + 1)
    }
    assert float(np.squeeze(lpm.METHODS["path-map-k4"].evaluate(g, {}))) == pytest.approx(0.5 * 10)
    assert float(np.squeeze(lpm.METHODS["seed-path-map"].evaluate(g, {}))) == pytest.approx(0.5 * 32 * 33 / 2)
    with pytest.raises(ValueError, match="clusters must be in"):
        lpm.path_map_rows(lpm.KMAX + 1)


def _disc_entry_points(n_r=48, n_phi=96):
    """Equal-area midpoint cells of the unit disc at z = 0 (normal +z): positions, normals, area each."""
    r = np.sqrt((np.arange(n_r) + 0.5) / n_r)
    phi = (np.arange(n_phi) + 0.5) * 2 * math.pi / n_phi
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    pos = np.stack([rr * np.cos(pp), rr * np.sin(pp), 0 * rr], axis=-1).reshape(-1, 3)
    return pos, np.tile([0.0, 0.0, 1.0], (len(pos), 1)), math.pi / len(pos)


def _path_map(x, nx, pos, nrm, area, albedo, e, k):
    """The family's pipeline by hand on one point: clusters, τ (cut 0), panes, weights, the walk row."""
    v = x[None] - pos
    h = v @ nrm[0]
    r2 = np.einsum("ij,ij->i", v, v)
    tau = lpm.vpl_transfer(NUMPY_OPS, h, r2 - h * h, -(v @ nx), nrm @ nx, 0.0) * area * albedo
    labels = lpm.cluster_entry_points(pos, nrm, k, 2.0)
    m = lpm.membership(labels, k)
    t, w = tau @ m, (m.T @ e) / m.sum(axis=0)
    g = {f"pane{i + 1}": float(t[i]) for i in range(k)} | {f"w{i + 1}": float(w[i]) for i in range(k)}
    return float(np.squeeze(lpm.walk_kernel(NUMPY_OPS, clusters=k, **g)))


@pytest.mark.parametrize("k", [1, 4, 32])
def test_disc_on_axis_matches_the_closed_form_for_every_k(k):
    """A uniformly lit disc (E₀ = 3, a = 0.6), the point at height h facing it: E = a·E₀/(1 + h²); with a
    uniform light every cluster's mean weight is exact, so every K gives the plain VPL sum."""
    pos, nrm, area = _disc_entry_points(200, 8)  # on the axis: the radial midpoint rule's error ~ 1/n_r²
    a, e0 = 0.6, 3.0
    for h in (0.3, 1.0, 2.5):
        got = _path_map(np.array([0.0, 0.0, h]), np.array([0.0, 0.0, -1.0]), pos, nrm, area, a,
                        np.full(len(pos), e0), k)  # fmt: skip
        assert got == pytest.approx(a * e0 / (1.0 + h * h), rel=2e-3), h


def test_disc_off_axis_matches_quadrature_and_k_equal_n_is_the_vpl_sum():
    """Off the axis, a tilted receiver and a light varying across the disc (E(y) = E₀(1 + 0.8 y_x)): scipy's
    dblquad of a E(y) cos θ cos θ'/(π r²) over the disc against the VPL sum with K = N (every entry point its
    own pane), and K = 4 sits between K = 1 and K = N in error."""
    from scipy.integrate import dblquad

    pos, nrm, area = _disc_entry_points(24, 48)
    a, e0 = 0.5, 2.0
    x = np.array([0.7, 0.2, 0.8])
    nx = np.array([-0.4, 0.0, -1.0]) / math.sqrt(1.16)

    def integrand(r, phi):
        y = np.array([r * math.cos(phi), r * math.sin(phi), 0.0])
        d = y - x
        r2 = d @ d
        cy, cx = max(-d[2], 0.0) / math.sqrt(r2), max(nx @ d, 0.0) / math.sqrt(r2)
        return a * e0 * (1 + 0.8 * y[0]) * cy * cx / (math.pi * r2) * r

    want, _ = dblquad(integrand, 0.0, 2 * math.pi, 0.0, 1.0, epsabs=1e-10, epsrel=1e-8)
    e = e0 * (1 + 0.8 * pos[:, 0])
    full = _path_map(x, nx, pos, nrm, area, a, e, len(pos))
    assert full == pytest.approx(want, rel=5e-3)
    # K = N is the plain VPL sum, term by term: a E_j A cos θ_y cos θ_x/(π r²) from the vectors
    d = pos - x[None]
    r2 = np.einsum("ij,ij->i", d, d)
    vpl = np.sum(a * e * area * np.maximum(-d[:, 2], 0) * np.maximum(d @ nx, 0) / (math.pi * r2 * r2))
    assert full == pytest.approx(float(vpl), rel=1e-12)
    one = _path_map(x, nx, pos, nrm, area, a, e, 1)
    assert abs(one - want) > abs(full - want)


def test_clusters_are_never_empty():
    """k-means with the seed's rule: K non-empty clusters, also when many points coincide; K ≥ N is one point
    per cluster."""
    rng = np.random.default_rng(1)
    pos = np.vstack([np.zeros((40, 3)), rng.uniform(size=(8, 3))])
    nrm = np.tile([0.0, 0.0, 1.0], (48, 1))
    for k in (1, 4, 16, 32):
        labels = lpm.cluster_entry_points(pos, nrm, k, 1.0)
        assert sorted(set(labels.tolist())) == list(range(k)), k
    assert lpm.cluster_entry_points(pos, nrm, 100, 1.0).tolist() == list(range(48))
    with pytest.raises(ValueError, match="clusters must be"):
        lpm.cluster_entry_points(pos, nrm, 0, 1.0)


@pytest.mark.parametrize("height", [0.0, 1e-6, 1e-3])
def test_a_light_on_the_surface_gives_finite_weights_and_bounce(height):
    """A point light (I = 10) on the lit disc itself (height 0: every entry point sees it at grazing
    incidence, E = I h/r³ = 0) or just above it (E up to I/h² near it): the weights and the walk on K = 1 and
    32 are finite, and exactly 0 with the light in the disc's plane (float32: the hypothesis test below)."""
    pos, nrm, area = _disc_entry_points(16, 32)
    lamp = np.array([0.05, 0.0, height])
    d = lamp[None] - pos
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    e = 10.0 * np.maximum(d[:, 2], 0.0) / r**3
    assert np.all(np.isfinite(e))
    for k in (1, 32):
        v = _path_map(np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, -1.0]), pos, nrm, area, 0.7, e, k)
        assert math.isfinite(v) and v >= 0.0
        if height == 0.0:
            assert v == 0.0


@settings(max_examples=150, deadline=None)
@given(
    h=st.floats(-10.0, 10.0),
    rho2=st.floats(0.0, 100.0),
    q=st.floats(-10.0, 10.0),
    c=st.floats(-1.0, 1.0),
    cut=st.floats(0.0, 4.0),
    w=st.floats(0.0, 1e4),
    albedo=st.sampled_from([0.0, 0.5, 1.0]),
    k=st.sampled_from(lpm.CLUSTERS),
)
def test_extremes_are_finite(h, rho2, q, c, cut, w, albedo, k):
    """The light on a surface (an entry point at distance 0: h = ρ = 0), cut 0, zero albedo, K = 1: τ and the
    walk finite and ≥ 0, in float64 and float32; zero albedo gives exactly 0."""
    for dt in (np.float64, np.float32):
        tau = lpm.vpl_transfer(NUMPY_OPS, dt(h), dt(rho2), dt(q), dt(c), dt(cut))
        assert np.isfinite(tau) and tau >= 0.0, (dt, tau)
        t = dt(albedo) * tau * dt(0.01)
        g = {f"pane{i}": t for i in range(1, k + 1)} | {f"w{i}": dt(w) for i in range(1, k + 1)}
        v = lpm.walk_kernel(NUMPY_OPS, clusters=k, **g)
        assert np.isfinite(v) and v >= 0.0
        if albedo == 0.0:
            assert v == 0.0


# ------------------------------------------------------------------------------------------------ reference
def test_a_moved_point_light_is_where_the_case_says():
    """The audit's move of a point light: the direct irradiance at a point under it is I cos θ/d² at the new
    position (Mitsuba's emitter sampling), and the light is back afterwards."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from rtfit.experiments.audit_light_path_maps import _light_moved
    from rtfit.reference.estimators import irradiance_pass

    lamp = {"type": "point", "position": [0, 0, 2], "intensity": 5.0}
    floor = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(4)}
    scene = mi.load_dict({"type": "scene", "lamp": lamp, "floor": floor})
    (lamp,) = scene.emitters()
    pts, nrm = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])

    def direct():
        return float(irradiance_pass(mi, scene, pts, nrm, 8, 1).mean[0, 0])

    assert direct() == pytest.approx(5.0 / 4.0, rel=1e-5)
    with _light_moved(mi, lamp, np.array([1.5, 0.0, 0.0])):
        d2 = 1.5**2 + 2.0**2
        assert direct() == pytest.approx(5.0 * (2.0 / math.sqrt(d2)) / d2, rel=1e-5)
    assert direct() == pytest.approx(5.0 / 4.0, rel=1e-5)


def test_a_moved_spot_light_keeps_its_direction():
    """A spot (I = 5, cutoff 60°, beam 50°) looking down from (0, 0, 2), moved by 1.5 along x by its
    ``to_world``: the point under its old position is 36.9° off its axis, inside the beam: I cos θ/d²."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    from rtfit.experiments.audit_light_path_maps import _light_moved
    from rtfit.reference.estimators import irradiance_pass

    frame = mi.ScalarTransform4f().look_at(origin=[0, 0, 2], target=[0, 0, 0], up=[0, 1, 0])
    spot = {"type": "spot", "to_world": frame, "intensity": 5.0, "cutoff_angle": 60.0, "beam_width": 50.0}
    floor = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(4)}
    scene = mi.load_dict({"type": "scene", "lamp": spot, "floor": floor})
    (lamp,) = scene.emitters()
    pts, nrm = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]])

    def direct():
        return float(irradiance_pass(mi, scene, pts, nrm, 8, 1).mean[0, 0])

    with _light_moved(mi, lamp, np.array([1.5, 0.0, 0.0])):
        assert direct() == pytest.approx(5.0 * (2.0 / 2.5) / 6.25, rel=1e-5)
    assert direct() == pytest.approx(5.0 / 4.0, rel=1e-5)


# ------------------------------------------------------------------------------------------------ the audit
@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    cache = tmp_path_factory.mktemp("lpm") / "c"
    return audit(str(SHIPPED), approximations=[FAMILY], width=12, height=12, spp=32, cache=cache, **FAST)


def test_shipped_box_follows_the_light(shipped):
    """Three positions (as declared, towards the red wall, towards the green wall): every row finite; the
    reference's red/green bounce is higher with the light by the red wall than by the green one, and the
    seed's path map follows it; its image mean within 25 % of the reference's per channel."""
    cases = {c.id: c for c in shipped.cases}
    assert sorted(cases) == ["light0-at0", "light0-at1", "light0-at2"]
    ratio, pm_ratio = {}, {}
    for cid, case in cases.items():
        rows = shipped.outcomes[cid]
        assert set(lpm.METHODS) <= set(rows), sorted(rows)
        for row in rows.values():
            assert np.all(np.isfinite(row.image[case.mask]))
        ref = case.reference.mean[case.mask].mean(axis=0)
        pm = rows["seed-path-map"].image[case.mask].mean(axis=0)
        assert np.all(np.abs(pm - ref) < 0.25 * ref), (cid, pm, ref)
        ratio[cid], pm_ratio[cid] = ref[0] / ref[1], pm[0] / pm[1]
    x = {cid: c.parameters["light_position"][0] for cid, c in cases.items()}
    assert x["light0-at1"] < x["light0-at0"] < x["light0-at2"]
    assert ratio["light0-at1"] > ratio["light0-at2"] and pm_ratio["light0-at1"] > pm_ratio["light0-at2"]


def test_shipped_box_reports_the_bake_beside_the_walk(shipped):
    """Each row's precompute (its K's bake, once per scene) is timed by the engine and is at least the walk's
    whole per-pixel total (ns/pixel × pixels): the map is not free; it is in the results' cost records."""
    pixels = int(shipped.cases[0].mask.sum())
    costs = {c.method: c for c in shipped.results.costs}
    for mid in lpm.METHODS:
        c = costs[mid]
        assert c.precompute_trigger == "scene" and c.precompute_pixels == pixels
        assert c.precompute_ms is not None and c.ns_per_pixel is not None
        assert c.precompute_ms * 1e6 >= c.ns_per_pixel * pixels, c
        assert f"clustered into {lpm.METHODS[mid].fixed.get('clusters', '')}" in (c.precompute_note or "")
    assert all(ch.passed for ch in shipped.results.checks if "precompute" in ch.name)


TOML = """
name = "red wall over a floor"

[camera]
origin = [0, -4, 2.5]
target = [0, 0, 0.3]
fov_deg = 50
width = 8
height = 8

[[lights]]
type = "point_light"
position = [0, -0.5, 1.5]
intensity = 20

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [4, 4]
material = { type = "diffuse", reflectance = 0.7 }

[[shapes]]
type = "rectangle"
center = [0, 1, 1]
normal = [0, -1, 0]
size = [4, 2]
material = { type = "diffuse", reflectance = [0.8, 0.1, 0.1] }
"""


def test_toml_scene_audits_three_positions(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(TOML)
    r = audit(path, FAMILY, spp=16, cache=tmp_path / "c", **FAST)
    assert len(r.cases) == 3
    for case in r.cases:
        ref = case.reference.mean[case.mask]
        assert np.all(np.isfinite(ref)) and ref[:, 0].mean() > ref[:, 1].mean()
        assert all(np.all(np.isfinite(o.image)) for o in r.outcomes[case.id].values())


def test_an_area_light_is_audited_where_it_is(tmp_path):
    """The colour-bleeding box's rectangle light is scene geometry: one case, not moved, said in its notes."""
    box = str(LIBRARY / "colour_bleeding_box.xml")
    r = audit(box, FAMILY, width=8, height=8, spp=8, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    assert any("not moved" in n for n in case.notes)


INSTANCED = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, -4, 3" target="0, 0, 0.3" up="0, 0, 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
  <emitter type="point"><point name="position" x="0" y="0" z="2"/><rgb name="intensity" value="10"/></emitter>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="3"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="shapegroup" id="ball"><shape type="sphere"><float name="radius" value="0.3"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.1, 0.1"/></bsdf></shape></shape>
  <shape type="instance" id="ball1"><ref id="ball"/>
    <transform name="to_world"><translate x="0.6" y="0" z="0.3"/></transform></shape>
</scene>"""


def test_an_instance_is_left_out_of_the_entry_points_and_said(tmp_path):
    """Mitsuba implements neither area nor position sampling on an ``instance`` (the audit of mitsuba-data's
    instancing scene stopped with "Shape::surface_area(): not implemented"): the map's entry points go on the
    other surfaces, and each case names the instance left out."""
    scene = tmp_path / "instanced.xml"
    scene.write_text(INSTANCED)
    r = audit(str(scene), FAMILY, spp=4, cache=tmp_path / "c", **FAST)
    assert r.cases and all(c.parameters["entry_shapes_left_out"] == ["ball1"] for c in r.cases)
    assert all(np.all(np.isfinite(o.image)) for c in r.cases for o in r.outcomes[c.id].values())
    # every surface an instance (the instancing scene's case): no map and no case, not an error
    only = INSTANCED.replace(
        '<shape type="rectangle" id="floor">', '<shape type="shapegroup" id="g"><shape type="rectangle">'
    )
    only = only.replace(
        '<bsdf type="diffuse"/></shape>',
        '<bsdf type="diffuse"/></shape></shape><shape type="instance"><ref id="g"/></shape>',
        1,
    )
    scene.write_text(only)
    assert audit(str(scene), FAMILY, spp=4, cache=tmp_path / "c2", **FAST).cases == []


def test_list_names_the_family_with_its_reason():
    result = CliRunner().invoke(audit_cmd, [str(SHIPPED), "--list"])
    assert result.exit_code == 0, result.output
    assert "light-path-maps — indirect light from a moving light: point light 'lamp'" in result.output
    assert "path-map-k1, path-map-k4, path-map-k16, seed-path-map, seed-path-map-cut-fit" in result.output


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES[FAMILY]
    assert f.module == ENGINE and f.methods is lpm.METHODS
    assert [s.file for s in f.scenes] == [SHIPPED.name] and SHIPPED.is_file()
