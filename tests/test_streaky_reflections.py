"""The streaky-reflections family (docs/streaky-reflections.md): the streak rows' energy and moments against
grid quadrature of the mirror image (a uniform disc), the GGX row against Mitsuba's own ``roughplastic`` BSDF
and against a quadrature of it over a small sphere light, extremes without NaN/Inf (hypothesis over the
declared domains), the light-alone switch, the audit of the shipped street, and the audit of an rtfit TOML
street (a ``mitsuba_xml`` plane, TOML point and sphere lights) against its Mitsuba XML twin and the closed
form written here (Mitsuba's own BSDF ``eval`` at each pixel's hit, found here by ray–plane intersection)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments.audit import AuditError
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.experiments.audit_streaky_reflections import emitters_alone, mirror_point
from rtfit.realtime import NUMPY_OPS, ggx_point_radiance, streak_radiance
from rtfit.realtime.streaky_reflections import METHODS

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "library" / "streaky_reflections_street.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}


def _grid(half: float, n: int = 801):
    x = np.linspace(-half, half, n)
    du, dv = np.meshgrid(x, x)
    return du, dv, (x[1] - x[0]) ** 2


# ------------------------------------------------------------------------------------ streak closed forms
@pytest.mark.parametrize(
    "sigma_x, k, sigma_y, rho", [(0.01, 0.004, 0.0, 0.02), (0.03, 0.0, 0.08, 0.0), (0.0, 0.01, 0.02, 0.05)]
)
def test_streak_integrates_to_the_mirror_image_energy_with_its_variances(sigma_x, k, sigma_y, rho):
    """∫∫ L du dv = A·e_mirror, and the second moments are σx² + rho²/4 and (k·D)² + σy² + rho²/4 (grid
    quadrature over ±8 σ, float64)."""
    d, a, e = 12.0, 0.7, 3.0
    vx, vy = sigma_x**2 + rho**2 / 4, (k * d) ** 2 + sigma_y**2 + rho**2 / 4
    du, dv, cell = _grid(8 * math.sqrt(max(vx, vy)))
    L = streak_radiance(du, dv, e, rho, d, a, sigma_x, k, sigma_y)
    energy = float(np.sum(L) * cell)
    assert energy == pytest.approx(a * e, rel=1e-6)
    assert float(np.sum(L * du**2) * cell / energy) == pytest.approx(vx, rel=1e-4)
    assert float(np.sum(L * dv**2) * cell / energy) == pytest.approx(vy, rel=1e-4)


def test_zero_blur_is_the_mirror_image():
    """σ → 0 (σx = k = σy = 0): the row is the mirror image's Gaussian stand-in, of the uniform disc's energy
    L_e·F·π·rho² and variance per axis (a grid quadrature of the disc of radius rho itself)."""
    rho, radiance = 0.03, 2.5  # L_e·F
    du, dv, cell = _grid(0.2)
    disc = np.where(du**2 + dv**2 <= rho**2, radiance, 0.0)
    e_disc = float(np.sum(disc) * cell)
    var_disc = float(np.sum(disc * du**2) * cell / e_disc)
    L = streak_radiance(du, dv, radiance * math.pi * rho**2, rho)
    energy = float(np.sum(L) * cell)
    assert energy == pytest.approx(e_disc, rel=5e-3)
    assert float(np.sum(L * du**2) * cell / energy) == pytest.approx(var_disc, rel=5e-3)


def test_quad_row_stretches_in_units_of_the_mirror_image():
    """streak-quad: variances rho²(w² + ¼) and rho²((k·D)² + ¼); the energy is kept (grid quadrature)."""
    rho, w, k, d = 0.01, 2.0, 0.3, 20.0
    du, dv, cell = _grid(0.6, 1201)
    inputs = {"du": du, "dv": dv, "e_mirror": np.full(du.shape, 1.5), "rho": np.full(du.shape, rho),
              "distance": np.full(du.shape, d)}  # fmt: skip
    L = np.asarray(METHODS["streak-quad"](NUMPY_OPS, inputs, {"amplitude": 1.0, "width": w, "k": k}))
    energy = float(np.sum(L) * cell)
    assert energy == pytest.approx(1.5, rel=1e-6)
    assert float(np.sum(L * du**2) * cell / energy) == pytest.approx(rho**2 * (w * w + 0.25), rel=1e-4)
    assert float(np.sum(L * dv**2) * cell / energy) == pytest.approx(rho**2 * ((k * d) ** 2 + 0.25), rel=1e-4)


def test_mirror_point_by_hand():
    assert np.allclose(mirror_point((1.5, 12.0, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)), (1.5, 12.0, -3.0))
    n = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)  # the plane y + z = 0
    assert np.allclose(mirror_point((0.0, 1.0, 1.0), (0.0, 0.0, 0.0), n), (0.0, -1.0, -1.0))


# ------------------------------------------------------------------------------------ GGX row vs Mitsuba
def _roughplastic(mi, alpha: float):
    return mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": 1.33,
                         "ext_ior": 1.0, "diffuse_reflectance": {"type": "rgb", "value": 0.0}})  # fmt: skip


def _mitsuba_eval(mi, bsdf, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Mitsuba's bsdf.eval (f·cos θ_o, red channel) in the local frame (n = +z), one per row."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.n = mi.Normal3f(0.0, 0.0, 1.0)
    si.wi = mi.Vector3f(*(np.ascontiguousarray(wi[:, i], np.float32) for i in range(3)))
    wo_ = mi.Vector3f(*(np.ascontiguousarray(wo[:, i], np.float32) for i in range(3)))
    return np.array(bsdf.eval(mi.BSDFContext(), si, wo_), np.float64)[0]


def _fresnel(mi, cos) -> np.ndarray:
    return np.array(
        mi.fresnel(mi.Float(np.ascontiguousarray(cos, np.float32)), mi.Float(1.33))[0], np.float64
    )


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("alpha", [0.05, 0.2, 0.6])
def test_ggx_row_is_mitsubas_roughplastic(mi, alpha):
    """With e_perp = 1 the row is f_r·cos θ_l = F·D·G/(4 cos θ_v): Mitsuba's ``roughplastic`` (GGX, black
    diffuse base, η = 1.33) ``eval`` at 400 random direction pairs above the plane (float32 both)."""
    rng = np.random.default_rng(1)
    wi = _unit(rng.normal(size=(400, 3)) * [1, 1, 0.5] + [0, 0, 0.3])
    wo = _unit(rng.normal(size=(400, 3)) * [1, 1, 0.5] + [0, 0, 0.3])
    up = (wi[:, 2] > 0.02) & (wo[:, 2] > 0.02)
    wi, wo = wi[up], wo[up]
    h = _unit(wi + wo)
    want = _mitsuba_eval(mi, _roughplastic(mi, alpha), wi, wo)
    got = ggx_point_radiance(wo[:, 2], wi[:, 2], h[:, 2], _fresnel(mi, np.sum(wi * h, 1)), 1.0, alpha)
    assert np.max(np.abs(got - want) / np.maximum(want, 1e-3)) < 1e-4


def _cap_quadrature(mi, bsdf, v, l0, theta: float, n_mu: int = 128, n_phi: int = 64) -> float:
    """∫_cap f_r(v, ω)·cos θ_ω dω over the cone of half-angle ``theta`` around ``l0``: the midpoint rule in
    (cos ψ, φ) about l0 with Mitsuba's ``eval``."""
    cmin = math.cos(theta)
    mu = 1.0 - (1.0 - cmin) * (np.arange(n_mu) + 0.5) / n_mu
    phi = 2 * math.pi * (np.arange(n_phi) + 0.5) / n_phi
    mm, pp = np.meshgrid(mu, phi)
    t = _unit(np.cross(l0, [0.0, 0.0, 1.0]))
    b = np.cross(l0, t)
    s = np.sqrt((1.0 - mm) * (1.0 + mm))
    w = mm[..., None] * l0 + s[..., None] * (np.cos(pp)[..., None] * t + np.sin(pp)[..., None] * b)
    f_cos = _mitsuba_eval(mi, bsdf, np.tile(v, (w.size // 3, 1)), w.reshape(-1, 3))
    return float(np.sum(f_cos) * 2 * math.pi * (1.0 - cmin) / len(f_cos))


def test_ggx_row_is_the_sphere_light_quadrature_for_a_small_light(mi):
    """L = ∫_cap f_r(v, ω)·L_e·cos θ_ω dω over a sphere light of angular radius θ (Mitsuba's ``eval``,
    `_cap_quadrature`) against the row at its centre with e_perp = L_e·Ω, α = 0.1 … 0.5: the gap is the
    lobe's variation over the light, O((θ/α)²): measured ≤ 2.6e-3 at θ = 0.004 rad and ≤ 6.4e-4 at
    0.002 (a quarter: the second order), the worst case at α = 0.1 near grazing."""
    v = _unit(np.array([0.0, -1.0, 0.25]))
    worst = {}
    for alpha in (0.1, 0.25, 0.5):
        bsdf = _roughplastic(mi, alpha)
        for l0 in (_unit(np.array([0.1, 1.0, 0.2])), _unit(np.array([0.0, 1.0, 0.6]))):
            h = _unit(v + l0)
            f_h = float(_fresnel(mi, [v @ h])[0])
            for theta in (0.004, 0.002):
                omega = 2 * math.pi * (1.0 - math.cos(theta))
                row = float(ggx_point_radiance(l0[2], v[2], h[2], f_h, omega, alpha))
                gap = abs(row / _cap_quadrature(mi, bsdf, v, l0, theta) - 1.0)
                worst[theta] = max(worst.get(theta, 0.0), gap)
    assert worst[0.004] < 3e-3 and worst[0.002] < 8e-4
    assert 3.5 < worst[0.004] / worst[0.002] < 4.5


# ------------------------------------------------------------------------------------------ extremes
def test_extremes_by_hand():
    """Grazing view, light on the horizon, α → 0 and α = 1, a point light with σ = 0: finite, and 0 where
    the light or the viewer is below the plane."""
    assert ggx_point_radiance(0.0, 0.3, 1.0, 0.5, 10.0, 0.1) == 0.0  # light on the horizon: G₁ → 0
    assert ggx_point_radiance(0.3, 0.0, 1.0, 0.5, 10.0, 0.1) == 0.0  # grazing view
    assert ggx_point_radiance(-0.2, 0.3, 0.9, 0.5, 10.0, 0.1) == 0.0  # light below the plane
    for alpha in (0.0, 1e-9, 1.0):
        for nh in (1.0, 0.999, 0.0):
            x = ggx_point_radiance(np.float32([0.3, 1e-7]), np.float32([0.3, 1e-7]), np.float32([nh, nh]),
                                   0.5, 1e4, alpha)  # fmt: skip
            assert np.all(np.isfinite(x)) and np.all(x >= 0)
    x = streak_radiance(np.float32([0.0, 1e-3, 3.0]), np.float32([0.0, 0.0, -3.0]), 1e4, 0.0, 1e3)
    assert np.all(np.isfinite(x)) and np.all(x >= 0)


def test_public_functions_say_what_is_wrong_in_one_line():
    for call, word in (
        (lambda: streak_radiance(0.0, 0.0, -1.0), "e_mirror"),
        (lambda: streak_radiance(0.0, 0.0, 1.0, rho=-0.1), "rho"),
        (lambda: ggx_point_radiance(0.5, 0.5, 2.0, 0.1, 1.0, 0.1), "cos_nh"),
        (lambda: ggx_point_radiance(0.5, 0.5, 1.0, 0.1, 1.0, 1.5), "alpha"),
        (lambda: ggx_point_radiance(0.5, 0.5, 1.0, 1.1, 1.0, 0.1), "fresnel_h"),
    ):
        with pytest.raises(ValueError, match=word) as info:
            call()
        assert "\n" not in str(info.value)


def _draw(draw, domain):
    lo, hi = domain
    return draw(st.one_of(st.just(lo), st.just(hi), st.floats(lo, hi)))


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_every_row_finite_over_its_domain(data):
    """Every row on inputs drawn over their declared domains (bounds included) and parameters over their
    bounds (0 included: σ = 0, k = 0): finite and non-negative in float32 Dr.Jit and float64 NumPy."""
    for mid, m in METHODS.items():
        inputs = {
            i.name: np.array([_draw(data.draw, i.domain), _draw(data.draw, i.domain)]) for i in m.inputs
        }
        params = {k: data.draw(st.one_of(st.just(p.lower), st.floats(p.lower, min(p.upper, 1e3))))
                  for k, p in m.params.items()}  # fmt: skip
        for x in (m.evaluate({k: v.astype(np.float32) for k, v in inputs.items()}, params),
                  m(NUMPY_OPS, inputs, params)):  # fmt: skip
            x = np.asarray(x)
            assert np.all(np.isfinite(x)) and np.all(x >= 0), (mid, inputs, params, x)


# ------------------------------------------------------------------------------------------ the audit
def test_emitters_alone_darkens_the_others_and_puts_them_back(mi):
    scene = mi.load_file(str(SCENE))
    lamps = list(scene.emitters())
    before = [np.array(mi.traverse(e)["radiance.value"]) for e in lamps]
    with emitters_alone(mi, scene, lamps[0]):
        assert np.allclose(np.array(mi.traverse(lamps[0])["radiance.value"]), before[0])
        assert np.all(np.array(mi.traverse(lamps[1])["radiance.value"]) == 0.0)
    assert all(
        np.array_equal(np.array(mi.traverse(e)["radiance.value"]), b)
        for e, b in zip(lamps, before, strict=True)
    )


@pytest.fixture(scope="module")
def street_audit(tmp_path_factory):
    cache = tmp_path_factory.mktemp("streaky") / "c"
    return audit(str(SCENE), ["streaky-reflections"], width=16, height=16, spp=32, pass_spp=16, cache=cache,
                 defines={"alpha": "0.2"}, **FAST)  # fmt: skip


def test_shipped_scene_audit(street_audit):
    """One case per lamp on the street's pixels: the mirror image where the pinhole camera puts the mirrored
    lamp (computed here from the XML's lookat), rho = r/z', D; every row evaluated; each fit beats its
    start; the anisotropic streaks beat the isotropic blur; the GGX row beats every blur."""
    r = street_audit
    assert [c.id for c in r.cases] == ["plane0-light0", "plane0-light1"]
    origin, target = np.array([0.0, 0.0, 1.7]), np.array([0.0, 20.0, -1.0])
    fwd = _unit(target - origin)
    left = _unit(np.cross([0.0, 0.0, 1.0], fwd))
    up = np.cross(fwd, left)
    for case, lamp in zip(r.cases, ((1.5, 12.0, 3.0), (-2.0, 28.0, 3.0)), strict=True):
        m = np.array([lamp[0], lamp[1], -lamp[2]]) - origin
        z = m @ fwd
        assert np.allclose(case.parameters["mirror_image"], [m @ left / z, m @ up / z], atol=1e-6)
        assert case.parameters["rho"] == pytest.approx(0.1 / z, rel=1e-6)
        assert case.parameters["distance"] == pytest.approx(np.linalg.norm(np.array(lamp) - origin), rel=1e-9)
        out = r.outcomes[case.id]
        rmse = {k: o.metrics["rmse"].value for k, o in out.items()}
        for row in ("streak-seed", "streak-fixed", "streak-quad", "isotropic"):
            assert f"{row}-fitted" in rmse
        assert rmse["streak-fixed-fitted"] < rmse["isotropic-fitted"]
        assert rmse["ggx-point"] < min(rmse[f"{row}-fitted"] for row in ("streak-seed", "streak-quad"))
        assert all(np.isfinite(v) for v in rmse.values())


def test_list_names_the_family_with_its_reason():
    result = CliRunner().invoke(audit_cmd, [str(SCENE), "--list"])
    assert result.exit_code == 0, result.output
    assert (
        "streaky-reflections — light streak in a rough plane: rough plastic rectangle 'street'"
        in result.output
    )
    assert "the light's glossy reflection as its mirror image streaked vertically" in result.output
    assert "streak-seed, streak-fixed, streak-quad, isotropic, ggx-point" in result.output


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES["streaky-reflections"]
    assert f.module == ENGINE and f.methods is METHODS
    assert {s.file for s in f.scenes} == {SCENE.name} and SCENE.is_file()


# ------------------------------------------------------------------------------- an rtfit TOML street
PLANE = """<scene version="3.0.0">
  <shape type="rectangle" id="street">
    <transform name="to_world"><scale x="6" y="30.5"/><translate y="29.5"/></transform>
    <bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
      <float name="int_ior" value="1.33"/><rgb name="diffuse_reflectance" value="0"/></bsdf>
  </shape>
</scene>"""
"""The street of the shipped scene (α = 0.2): x ∈ [−6, 6], y ∈ [−1, 60], z = 0."""
POINT, INTENSITY = np.array([1.5, 12.0, 3.0]), np.array([300.0, 240.0, 150.0])
LAMP, LAMP_RADIUS, LAMP_RADIANCE = np.array([-2.0, 28.0, 3.0]), 0.1, np.array([2000.0, 1600.0, 1000.0])
TOML_STREET = """name = "wet street"
[camera]
origin = [0, 0, 1.7]
target = [0, 20, -1]
fov_deg = 40
width = 16
height = 16

[[lights]]
type = "point_light"
position = [1.5, 12, 3]
intensity = [300, 240, 150]

[[lights]]
type = "sphere_light"
center = [-2, 28, 3]
radius = 0.1
radiance = [2000, 1600, 1000]

[[lights]]  # a finite sun (rtfit's own disc emitter) whose reflection the camera sees, and a constant sky
type = "sun"
direction = [0, 1, 0.3]
irradiance = [2, 2, 2]
angular_radius_deg = 0.5

[[lights]]
type = "constant_env"
radiance = [1, 1, 1]

[[shapes]]
type = "mitsuba_xml"
file = "street.xml"
"""
"""The street as an rtfit TOML scene: its plane a ``mitsuba_xml`` shape keeping its BSDF; besides the two
lamps a sun (0.5°, its reflection in view) and a sky, both folded into rtfit's disc emitter: each lamp's
reference must have them dark."""
XML_STREET = f"""<scene version="3.0.0">
  <sensor type="perspective">
    <transform name="to_world"><lookat origin="0, 0, 1.7" target="0, 20, -1" up="0, 0, 1"/></transform>
    <float name="fov" value="40"/>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
  </sensor>
  {PLANE[PLANE.index("<shape") : PLANE.rindex("</scene>")]}
  <emitter type="point"><point name="position" x="1.5" y="12" z="3"/>
    <rgb name="intensity" value="300, 240, 150"/></emitter>
  <shape type="sphere"><point name="center" x="-2" y="28" z="3"/><float name="radius" value="0.1"/>
    <emitter type="area"><rgb name="radiance" value="2000, 1600, 1000"/></emitter>
    <bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf></shape>
</scene>"""
"""Its Mitsuba XML twin: the same camera, plane and lamps, no sun, no sky."""


@pytest.fixture(scope="module")
def street_twins(tmp_path_factory):
    root = tmp_path_factory.mktemp("toml-street")
    (root / "street.xml").write_text(PLANE)
    (root / "s.toml").write_text(TOML_STREET)
    (root / "s.xml").write_text(XML_STREET)
    return root, tuple(
        audit(str(root / name), ["streaky-reflections"], spp=32, pass_spp=16, cache=root / "cache", **FAST)
        for name in ("s.toml", "s.xml")
    )


def _street_closed_form(mi):
    """(hit mask (16, 16), {case id: expected radiance (N, 3)}) of the street: each pixel-centre ray of the
    16² pinhole camera (40° across x; the image's x along the camera's −left, rows downwards) meets the
    plane z = 0 at p; L = f_r(v, l)·cos θ_l·I/d² (the point light) or ·L_e·πr²/d² (the small sphere lamp,
    its solid angle; the lobe's variation over it is O((θ/α)²) ≈ 3e-4), f_r·cos θ_l from Mitsuba's own
    ``roughplastic`` eval (`_mitsuba_eval`)."""
    origin, target = np.array([0.0, 0.0, 1.7]), np.array([0.0, 20.0, -1.0])
    fwd = _unit(target - origin)
    left = _unit(np.cross([0.0, 0.0, 1.0], fwd))
    up = np.cross(fwd, left)
    t = -math.tan(math.radians(20.0)) * (2.0 * (np.arange(16) + 0.5) / 16.0 - 1.0)
    tu, tv = np.meshgrid(t, t)
    d = _unit(fwd + tu[..., None] * left + tv[..., None] * up)
    p = origin + (-origin[2] / np.minimum(d[..., 2], -1e-9))[..., None] * d
    hit = (d[..., 2] < 0) & (np.abs(p[..., 0]) <= 6) & (p[..., 1] >= -1) & (p[..., 1] <= 60)
    bsdf = mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": 0.2, "int_ior": 1.33,
                         "diffuse_reflectance": {"type": "rgb", "value": 0.0}})  # fmt: skip
    out = {}
    lamp = LAMP_RADIANCE * math.pi * LAMP_RADIUS**2
    for tag, centre, scale in (("plane0-light0", POINT, INTENSITY), ("plane0-light1", LAMP, lamp)):
        to_light = centre - p[hit]
        dist = np.linalg.norm(to_light, axis=1)
        f_cos = _mitsuba_eval(mi, bsdf, -d[hit], to_light / dist[:, None])
        out[tag] = f_cos[:, None] * scale[None, :] / (dist * dist)[:, None]
    return hit, out


def test_a_toml_street_is_audited_like_its_xml_twin(street_twins, mi):
    """The TOML street (its plane a ``mitsuba_xml`` shape, TOML point and sphere lamps, a sun and a sky that
    must be dark) and its XML twin: the same cases on the same pixels (the ray–plane hits computed here);
    each lamp's reference equals the closed form (`_street_closed_form`) within its noise (pixel sums,
    |z| < 4: the sun's reflection left lit measured z ≈ 30), the ggx-point row equals it to float32; each
    row of the TOML audit equals the XML audit's within the two references' noise (pixel sums, |z| < 4;
    measured ≤ 1.73)."""
    _, (toml, xml) = street_twins
    hit, want = _street_closed_form(mi)
    assert [c.id for c in toml.cases] == [c.id for c in xml.cases] == list(want)
    for ct, cx, centre in zip(toml.cases, xml.cases, (POINT, LAMP), strict=True):
        assert np.array_equal(ct.mask, hit) and np.array_equal(cx.mask, hit)
        distance = float(np.linalg.norm(centre - [0.0, 0.0, 1.7]))
        for case in (ct, cx):
            assert case.parameters["distance"] == pytest.approx(distance, rel=1e-9)
            assert case.parameters["light_height"] == pytest.approx(3.0, abs=1e-6)
            assert case.parameters["alpha"] == pytest.approx(0.2, rel=1e-6)
        e = want[ct.id]
        for r, case in ((toml, ct), (xml, cx)):
            mean, err = case.reference.mean[hit], case.reference.stderr[hit]
            z = (mean.sum(0) - e.sum(0)) / np.sqrt((err**2).sum(0))
            assert np.all(np.abs(z) < 4.0), (case.id, z)
            ggx = np.asarray(r.outcomes[case.id]["ggx-point"].image)[hit]
            assert np.max(np.abs(ggx - e)) < 1e-4 * np.max(e), case.id
        sigma = np.sqrt((ct.reference.stderr[hit] ** 2).sum(0) + (cx.reference.stderr[hit] ** 2).sum(0))
        assert set(toml.outcomes[ct.id]) == set(xml.outcomes[cx.id])
        for row, out in toml.outcomes[ct.id].items():
            a = np.asarray(out.image)[hit].sum(0)
            b = np.asarray(xml.outcomes[cx.id][row].image)[hit].sum(0)
            assert np.all(np.isfinite(a)) and np.all(np.abs(a - b) < 4.0 * sigma), (ct.id, row, a, b)


def test_list_names_the_family_on_a_toml_scene(street_twins):
    root, _ = street_twins
    result = CliRunner().invoke(audit_cmd, [str(root / "s.toml"), "--list"])
    assert result.exit_code == 0, result.output
    assert (
        "streaky-reflections — light streak in a rough plane: rough plastic shape (shapes[0], xml0_0: "
        "roughplastic) reflects point light (lights[0])" in result.output
    )


def test_emitters_alone_darkens_rtfits_sun_disc_and_puts_it_back(mi, tmp_path):
    """The TOML sun of finite size (rtfit's Python disc emitter, the sky folded in: no `mi.traverse`
    parameters) is dark while another light is alone, and lit again after."""
    from rtfit.reference.build import load_mitsuba_scene
    from rtfit.scenes import load_scene

    (tmp_path / "street.xml").write_text(PLANE)
    (tmp_path / "s.toml").write_text(TOML_STREET)
    _, scene = load_mitsuba_scene(load_scene(tmp_path / "s.toml"))
    emitters = list(scene.emitters())
    (disc,) = [e for e in emitters if str(e).startswith("rtfit_distant_disk")]
    point = next(e for e in emitters if "intensity.value" in mi.traverse(e).keys())
    before = [np.array(getattr(disc, k)) for k in ("radiance", "sky", "weight")]
    assert np.all(before[0] > 0) and np.all(before[1] == 1.0)
    with emitters_alone(mi, scene, point):
        assert all(np.all(np.array(getattr(disc, k)) == 0.0) for k in ("radiance", "sky", "weight"))
        assert np.array_equal(np.array(mi.traverse(point)["intensity.value"]).ravel(), INTENSITY)
    assert all(
        np.array_equal(np.array(getattr(disc, k)), b)
        for k, b in zip(("radiance", "sky", "weight"), before, strict=True)
    )


def test_emitters_alone_refuses_an_emitter_it_cannot_darken(mi):
    """A textured area light has no uniform emission parameter to set to 0: one line, nothing changed."""
    scene = mi.load_dict({
        "type": "scene",
        "lamp": {"type": "sphere", "emitter": {"type": "area", "radiance": 1.0}},
        "panel": {"type": "rectangle", "emitter": {"type": "area", "radiance": {"type": "checkerboard"}}},
    })  # fmt: skip
    lamp = next(e for e in scene.emitters() if "radiance.value" in mi.traverse(e).keys())
    with (
        pytest.raises(AuditError, match="cannot darken the emitter") as info,
        emitters_alone(mi, scene, lamp),
    ):
        pass
    assert "\n" not in str(info.value)
