"""The caustics family (docs/caustics.md): the snippet kernels against independent NumPy sums, extremes
without NaN/Inf, the light tracer's energy against closed-form ray optics of a glass sphere (itself checked
against the normal-incidence closed form), the camera connection against a mirror's closed-form caustic,
and the audit of the shipped XML scene."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from rtfit.experiments.audit_caustics import nearest_photons
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.realtime import NUMPY_OPS, adaptive_splat_irradiance, photon_map_irradiance, splat_irradiance
from rtfit.realtime.caustics import METHODS, NEAREST, NO_PHOTON, PHOTON_COUNTS, RINGS
from rtfit.reference import caustic_pass as cp

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SUN = LIBRARY / "caustics_sphere_sun.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}


def _as_inputs(d, f, g=None, q=None) -> dict:
    """The kernels' per-point inputs: K nearest (d, f) and the rings (g, q; default: empty)."""
    n = len(d)
    g = np.zeros((n, RINGS)) if g is None else g
    q = np.full((n, RINGS), NO_PHOTON) if q is None else q
    near = {f"{v}{k + 1}": a[:, k] for v, a in {"d": d, "f": f}.items() for k in range(NEAREST)}
    return near | {f"{v}{j + 1}": a[:, j] for v, a in {"g": g, "q": q}.items() for j in range(RINGS)}


def _photons(n_points=3, k=NEAREST, seed=0):
    rng = np.random.default_rng(seed)
    d = np.sort(rng.uniform(0.0, 0.4, (n_points, k)), axis=1)
    f = rng.uniform(0.0, 0.01, (n_points, k))
    g = rng.uniform(0.0, 0.05, (n_points, RINGS))
    q = d[:, -1:] * 1.15 ** (np.arange(RINGS) + 0.5)
    return d, f, g, q


# ------------------------------------------------------------------------------------------ kernels
def test_kernels_are_the_sums_by_hand():
    """At 3 points: the seed's constant snippets Σ f e^(−d²/2h²)/(2πh²), the adaptive ones (h = c·d₈) and
    the photon-map gather Σf/(πd_K²), each summed photon by photon in plain Python; the table's rows add
    the rings' Σ g e^(−q²/2h²)/(2πh²)."""
    d, f, g, q = _photons()
    inputs = _as_inputs(d, f, g, q)

    def snip(dist, w):
        return math.exp(-(dist**2) / (2 * w * w)) / (2 * math.pi * w * w)

    h, c = 0.07, 1.3
    for i in range(3):
        seed = sum(f[i, k] * snip(d[i, k], h) for k in range(NEAREST))
        ha = c * d[i, 7]
        adapt = sum(f[i, k] * snip(d[i, k], ha) for k in range(NEAREST))
        gather = sum(f[i]) / (math.pi * d[i, -1] ** 2)
        assert splat_irradiance(d, f, h)[i] == pytest.approx(seed, rel=1e-12)
        assert adaptive_splat_irradiance(d, f, c)[i] == pytest.approx(adapt, rel=1e-12)
        assert photon_map_irradiance(d, f)[i] == pytest.approx(gather, rel=1e-12)
        rings = sum(g[i, j] * snip(q[i, j], h) for j in range(RINGS))
        rings_a = sum(g[i, j] * snip(q[i, j], ha) for j in range(RINGS))
        row = METHODS["splat-seed-n4096"](NUMPY_OPS, inputs, {"width": h})
        assert row[i] == pytest.approx(seed + rings, rel=1e-12)
        row = METHODS["splat-adaptive-n4096"](NUMPY_OPS, inputs, {"scale": c})
        assert row[i] == pytest.approx(adapt + rings_a, rel=1e-12)


def test_methods_table_runs_the_same_text_on_drjit():
    """Each row of `METHODS` (float32 Dr.Jit) equals the float64 NumPy run of the same kernel to float32."""
    d, f, g, q = _photons(5)
    inputs = _as_inputs(d, f, g, q)
    assert len(METHODS) == 3 * len(PHOTON_COUNTS)
    for mid, m in METHODS.items():
        a = np.asarray(m.evaluate({k: v.astype(np.float32) for k, v in inputs.items()}))
        b = np.asarray(m(NUMPY_OPS, inputs))
        assert np.allclose(a, b, rtol=2e-5), mid


def test_snippet_keeps_the_energy():
    """One photon's snippet integrates to its flux over the plane (midpoint quadrature on a fine grid)."""
    h, phi = 0.05, 2.0
    x = (np.arange(-400, 400) + 0.5) * (h / 40)
    xx, yy = np.meshgrid(x, x)
    e = splat_irradiance(np.hypot(xx, yy).reshape(-1, 1), np.full((xx.size, 1), phi), h)
    assert float(e.sum()) * (h / 40) ** 2 == pytest.approx(phi, rel=1e-6)


def test_public_functions_say_what_is_wrong_in_one_line():
    d, f, _, _ = _photons()
    for call, text in [
        (lambda: splat_irradiance(d, f, 0.0), "width must be in"),
        (lambda: splat_irradiance(d, -f, 0.1), "flux must be in"),
        (lambda: splat_irradiance(d[:, 0], f, 0.1), "(N, K) array"),
        (lambda: adaptive_splat_irradiance(d, f, -1.0), "scale must be in"),
        (lambda: adaptive_splat_irradiance(d[:, :4], f[:, :4], 1.0), "at least the 8 nearest"),
    ]:
        with pytest.raises(ValueError, match=None) as e:
            call()
        assert text in str(e.value) and "\n" not in str(e.value)


@settings(max_examples=25, deadline=None)
@given(
    width=st.one_of(st.just(1e-12), st.just(1e6), st.floats(1e-12, 1e6)),
    scale=st.one_of(st.just(1e-6), st.just(1e4), st.floats(1e-6, 1e4)),
    d=st.one_of(st.just(0.0), st.just(NO_PHOTON), st.floats(0.0, 1e3)),
    flux=st.one_of(st.just(0.0), st.floats(0.0, 1e3)),
    ring=st.one_of(st.just(0.0), st.just(NO_PHOTON), st.floats(0.0, 1e3)),
)
def test_extremes_finite(width, scale, d, flux, ring):
    """Zero photons (d = q = NO_PHOTON, f = g = 0), photons on the point (d = 0: r₈ = 0), tiny and huge
    widths: every row finite and non-negative (float32 Dr.Jit and float64 NumPy)."""
    dd = np.array([[d] * NEAREST, [NO_PHOTON] * NEAREST])
    ff = np.array([[flux] * NEAREST, [0.0] * NEAREST])
    gg = np.array([[flux] * RINGS, [0.0] * RINGS])
    qq = np.array([[ring] * RINGS, [NO_PHOTON] * RINGS])
    inputs = _as_inputs(dd, ff, gg, qq)
    for mid, m in METHODS.items():
        if not mid.endswith(f"-n{PHOTON_COUNTS[0]}"):
            continue  # (the other photon counts run the same three kernels)
        # (the parameters as 1-element arrays: Dr.Jit keeps them opaque, one kernel for every example)
        params = (
            {"width": np.array([width])}
            if "width" in m.params
            else ({"scale": np.array([scale])} if "scale" in m.params else {})
        )
        for x in (m.evaluate({k: v.astype(np.float32) for k, v in inputs.items()}, params),
                  m(NUMPY_OPS, inputs, params)):  # fmt: skip
            x = np.asarray(x)
            assert np.all(np.isfinite(x)) and np.all(x >= 0), (mid, x)
            assert x[1] == 0.0  # no photons: no caustic


def test_nearest_photons_pads_a_short_set():
    """Fewer photons than K: the rest are NO_PHOTON, no flux, and the rings are empty."""
    pts = np.stack([np.arange(12.0), np.zeros(12), np.zeros(12)], axis=1)
    hits = cp.PhotonHits(pts, np.tile([0, 0, 1.0], (12, 1)), np.ones((12, 3)), np.tile([0, 0, -1.0], (12, 1)),
                         np.arange(12), np.zeros(3))  # fmt: skip
    got = nearest_photons(np.array([[0.0, 0.0, 0.0]]), hits)
    d, f = got["d"], got["f"]
    assert np.allclose(d[0, :12], np.arange(12.0)) and np.all(d[0, 12:] == NO_PHOTON)
    assert np.all(f[0, 12:] == 0) and np.all(f[0, :12] == 1)
    assert np.all(got["g"] == 0) and np.all(got["q"] == NO_PHOTON)  # no photon beyond the K nearest


@pytest.mark.parametrize(("m", "chunk"), [(33, None), (500, None), (500, 3), (5000, None)])
def test_nearest_photons_against_a_brute_force_sort(m, chunk):
    """The K nearest (distances, fluxes) and the rings' flux and flux-weighted RMS distance against a
    plain loop over each point's photons sorted by distance (photons at distinct distances): the K
    nearest the same bits, the rings' sums to 1e-12 relative (their order of summation differs)."""
    from rtfit.realtime.caustics import RING_RATIO

    rng = np.random.default_rng(m)
    pts = rng.normal(0.0, 0.3, (m, 3))
    flux = rng.uniform(0.1, 1.0, (m, 3)) / m
    hits = cp.PhotonHits(pts, np.tile([0, 0, 1.0], (m, 1)), flux, np.tile([0, 0, -1.0], (m, 1)),
                         np.arange(m), np.zeros(3))  # fmt: skip
    x = rng.normal(0.0, 0.4, (7, 3))
    got = nearest_photons(x, hits, chunk=chunk)
    for i, xi in enumerate(x):
        dist = np.linalg.norm(xi[None, :] - pts, axis=1)
        order = np.argsort(dist, kind="stable")
        near, far = order[:NEAREST], order[NEAREST:]
        assert np.array_equal(got["d"][i], dist[near]) and np.array_equal(got["f"][i], flux[near])
        g, wd2, ws = np.zeros((RINGS, 3)), np.zeros(RINGS), np.zeros(RINGS)
        for j in far:
            r = min(
                RINGS - 1,
                max(0, math.floor(math.log(max(dist[j] / dist[near[-1]], 1.0)) / math.log(RING_RATIO))),
            )
            w = flux[j].mean()
            g[r] += flux[j]
            ws[r] += w
            wd2[r] += w * dist[j] ** 2
        q = np.where(ws > 0, np.sqrt(wd2 / np.where(ws > 0, ws, 1.0)), NO_PHOTON)
        assert np.allclose(got["g"][i], g, rtol=1e-12, atol=0.0)
        assert np.allclose(got["q"][i], q, rtol=1e-12, atol=0.0)


@pytest.mark.parametrize("h", [0.003, 0.01, 0.03, 0.1])
def test_rings_give_the_photon_by_photon_splat(h):
    """2000 photons in a Gaussian blob (σ 5 cm) with varied flux: the K nearest plus the rings (the audit's
    inputs) give the constant-width and the adaptive (h = c·d₈) splats summed over every photon within 1.5 %
    at 3 points (centre, flank, tail) and every width (ring ratio 1.15: each ring at its flux-weighted RMS
    distance)."""
    rng = np.random.default_rng(4)
    m = 2000
    pts = np.concatenate([rng.normal(0, 0.05, (m, 2)), np.zeros((m, 1))], axis=1)
    flux = np.tile(rng.uniform(0.5, 1.5, (m, 1)) / m, (1, 3))
    hits = cp.PhotonHits(pts, np.tile([0, 0, 1.0], (m, 1)), flux, np.tile([0, 0, -1.0], (m, 1)),
                         np.arange(m), np.zeros(3))  # fmt: skip
    x = np.array([[0.0, 0.0, 0.0], [0.06, 0.02, 0.0], [0.15, -0.05, 0.0]])
    got = nearest_photons(x, hits)
    inputs = _as_inputs(got["d"], got["f"][..., 0], got["g"][..., 0], got["q"])
    dist = np.linalg.norm(x[:, None, :] - pts[None], axis=2)
    full = (flux[None, :, 0] * np.exp(-(dist**2) / (2 * h * h)) / (2 * np.pi * h * h)).sum(axis=1)
    seed = np.asarray(METHODS["splat-seed-n1024"](NUMPY_OPS, inputs, {"width": h}))
    assert np.allclose(seed, full, rtol=0.015, atol=1e-6 * full.max()), (seed, full)
    c = h / 0.01
    hh = c * np.sort(dist, axis=1)[:, 7:8]  # the point's 8th nearest photon, by brute force
    full_a = (flux[None, :, 0] * np.exp(-(dist**2) / (2 * hh * hh)) / (2 * np.pi * hh * hh)).sum(axis=1)
    adapt = np.asarray(METHODS["splat-adaptive-n1024"](NUMPY_OPS, inputs, {"scale": c}))
    assert np.allclose(adapt, full_a, rtol=0.015, atol=1e-6 * full_a.max()), (adapt, full_a)


# ------------------------------------------------------------------------------------ reference (Mitsuba)
def test_sphere_ray_optics_at_normal_incidence():
    """A thin beam along a glass sphere's axis onto a large plane beyond it: the orders that leave forwards
    (TT, TRRT, …) carry (1 − F₀)²/(1 − F₀²) = (1 − F₀)/(1 + F₀) of the flux, F₀ = ((η − 1)/(η + 1))²."""
    n = 200
    o = np.stack([np.linspace(-1e-4, 1e-4, n), np.zeros(n), np.full(n, 5.0)], axis=1)
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    f = np.ones((n, 3)) / n
    got = cp.sphere_flux(
        o, d, f, [0, 0, 1.0], 0.5, 1.5, np.zeros(3), np.array([50.0, 0, 0]), np.array([0, 50.0, 0])
    )
    f0 = (0.5 / 2.5) ** 2
    assert got[0] == pytest.approx((1 - f0) / (1 + f0), rel=1e-6)


@pytest.fixture(scope="module")
def mi():
    import mitsuba

    mitsuba.set_variant("llvm_ad_rgb")
    return mitsuba


def test_energy_conservation_through_a_glass_sphere(mi):
    """The shipped sun scene: the flux Mitsuba's traced photons put on the floor equals the closed-form ray
    optics of the sphere on the same emitted rays within 4 standard errors (and nothing escapes the depth
    bound); the flux reaching the floor is below what entered the caster (reflections escape upwards)."""
    scene = mi.load_file(str(SUN))
    light = cp.light_of(mi, scene.emitters()[0], [0, 0, 0.9])
    assert light is not None and light.direction is not None
    o, d, f = cp.emit_photons(mi, light, [0, 0, 0.9], 0.5, 4096, 5, stratified=True, far=10.0)
    assert f.sum(axis=0)[0] == pytest.approx(3.0 * math.pi * 0.25, rel=1e-6)  # E⊥ πr²
    hits = cp.trace_photons(mi, scene, o, d, f, 6)
    per = np.zeros(len(o))
    per[hits.index] = hits.flux[:, 0]
    traced, err = per.sum(), math.sqrt(len(per)) * per.std(ddof=1)
    ana = cp.sphere_flux(
        o, d, f, [0, 0, 0.9], 0.5, 1.5, np.zeros(3), np.array([2.0, 0, 0]), np.array([0, 2.0, 0])
    )
    assert abs(traced - ana[0]) < 4 * err and err < 0.01 * ana[0], (traced, ana, err)
    assert np.all(hits.dropped < 1e-6) and ana[0] < f.sum(axis=0)[0]


def test_spot_light_photons_carry_its_falloff(mi):
    """A spot light in place of the point light (same position and I, aimed at the ball): with its cone wider
    than the ball's (cutoff 20°, the ball subtends 11.5°) the photons carry I·Ω as the point light's do;
    with cutoff 10° (Mitsuba's falloff inside the ball's cone) less, and still more than nothing."""
    text = (LIBRARY / "caustics_sphere_point.xml").read_text()
    spot = '<emitter type="spot"><float name="cutoff_angle" value="$cut"/><transform name="to_world">' \
        '<lookat origin="-1.2, 0, 3.2" target="0, 0, 1"/></transform>'  # fmt: skip
    text = text.replace('<emitter type="point">', spot).replace(
        '<point name="position" x="-1.2" y="0" z="3.2"/>', ""
    )
    flux = {}
    for cut in ("20", "10"):
        scene = mi.load_string(text.replace("$cut", cut))
        light = cp.light_of(mi, scene.emitters()[0], [0, 0, 1.0])
        assert light is not None and light.position is not None
        flux[cut] = cp.emit_photons(mi, light, [0, 0, 1.0], 0.5, 1024, 1, stratified=True)[2].sum(axis=0)[0]
    dist = math.hypot(1.2, 2.2)
    omega = 2 * math.pi * (1 - math.sqrt(1 - (0.5 / dist) ** 2))
    assert flux["20"] == pytest.approx(10.0 * omega, rel=1e-5)
    assert 0.2 * flux["20"] < flux["10"] < 0.9 * flux["20"]


MIRROR = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="20"/>
    <transform name="to_world"><lookat origin="1.73, 0, 4" target="1.73, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>
  <emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/>
    <rgb name="irradiance" value="2"/></emitter>
  <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate x="1.5"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate y="1" angle="60"/>
    <translate z="1"/></transform><bsdf type="conductor"><string name="material" value="none"/></bsdf></shape>
</scene>"""


def test_camera_connection_against_a_mirror_caustic(mi):
    """A perfect mirror tilted 60° under a vertical directional light (E⊥ = 2 W/m²) sends a uniform beam
    along (sin 120°, 0, cos 120°) onto the floor: its caustic irradiance there is E⊥·|cos 120°| = 1 W/m²
    on a patch of area 0.6²·cos 60°/|cos 120°| = 0.36 m² (closed form); the light tracer connected to the
    camera gives that inside the patch, 0 outside."""
    from rtfit.reference.estimators import gbuffer

    scene = mi.load_string(MIRROR)
    sensor = scene.sensors()[0]
    gb = gbuffer(mi, scene, sensor)
    pixels = np.flatnonzero(gb.mask.ravel())
    centre = np.array([0.0, 0.0, 1.0])
    light = cp.light_of(mi, scene.emitters()[0], centre)
    res = cp.caustic_pass(mi, scene, sensor, gb.view_dir, pixels, light, centre, 0.43, 32, 4096, 11, far=10.0)
    pos = gb.position.reshape(-1, 3)[pixels].astype(np.float64)
    # the patch: floor points whose ray back along −r meets the mirror square (closed form)
    r = np.array([math.sin(math.radians(120)), 0.0, math.cos(math.radians(120))])
    nm = np.array([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))])
    t = ((centre - pos) @ nm) / (-r @ nm)
    q = pos - t[:, None] * r - centre
    u, v = np.array([math.cos(math.radians(60)), 0, -math.sin(math.radians(60))]), np.array([0, 1.0, 0])
    a, b = np.abs(q @ u), np.abs(q @ v)
    inside, outside = (a < 0.25) & (b < 0.25), (a > 0.36) | (b > 0.36)
    e = res.mean[:, 0]
    assert inside.sum() > 10 and outside.sum() > 10
    assert np.median(e[inside]) == pytest.approx(1.0, rel=0.05), e[inside]
    assert np.all(e[outside] == 0.0)


# ------------------------------------------------------------------------------------------ the audit
@pytest.fixture(scope="module")
def caustic_audit(tmp_path_factory):
    cache = tmp_path_factory.mktemp("caustics") / "c"
    return audit(str(SUN), ["caustics"], width=12, height=12, spp=8, pass_spp=8, cache=cache, **FAST)


def test_shipped_scene_audit(caustic_audit):
    """One case (the sun through the ball); every row at every photon count evaluated, finite, the fitted
    widths no worse than their starts; the energy balance recorded and within its noise."""
    r = caustic_audit
    (case,) = r.cases
    assert case.id == "caster0-light0" and case.mask.any()
    outcomes = r.outcomes[case.id]
    for n in PHOTON_COUNTS:
        assert {f"splat-seed-n{n}-fitted", f"splat-adaptive-n{n}-fitted", f"photon-map-n{n}"} <= set(outcomes)
    for o in outcomes.values():
        assert np.all(np.isfinite(o.image)) and np.all(o.image >= 0)
    radius = case.parameters["bounding_radius_m"]
    assert radius == pytest.approx(0.5, rel=1e-6)
    for n in PHOTON_COUNTS:  # the width is declared in units of the caster's radius, fitted in metres
        h = float(outcomes[f"splat-seed-n{n}-fitted"].parameters["width"])
        assert 0.002 * radius <= h <= 2.0 * radius
    e = case.parameters["energy"]
    assert abs(e["traced_on_receiver_w"] - e["analytic_on_receiver_w"]) < 4 * e["traced_stderr_w"]
    assert float(case.reference.mean[case.mask].max()) > 1.0  # the focused caustic (E⊥ = 3 W/m² in)


def test_shipped_scene_reports_the_photons_beside_the_gather(caustic_audit):
    """Each row's precompute (its N photons traced and gathered, every frame) is timed by the engine, shared
    by the three forms at one N, and is at least the kernel's whole per-pixel total (ns/pixel × pixels)."""
    r = caustic_audit
    pixels = int(r.cases[0].mask.sum())
    costs = {c.method: c for c in r.results.costs}
    for n in PHOTON_COUNTS:
        rows = [costs[f"{form}-n{n}"] for form in ("splat-seed", "splat-adaptive", "photon-map")]
        assert len({c.precompute_ms for c in rows}) == 1  # one step, timed once
        for c in rows:
            assert c.precompute_trigger == "frame" and c.precompute_pixels == pixels
            assert c.precompute_ms is not None and c.ns_per_pixel is not None
            assert c.precompute_ms * 1e6 >= c.ns_per_pixel * pixels, c
            assert c.precompute_note and c.precompute_note.startswith(f"{n} photons traced")


def test_list_names_caustics():
    result = CliRunner().invoke(audit_cmd, [str(SUN), "--list"])
    assert result.exit_code == 0, result.output
    assert "caustics — caustic caster: glass sphere 'ball'" in result.output
    assert "splat-seed-n1024, splat-adaptive-n1024, photon-map-n1024" in result.output


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES["caustics"]
    assert f.module == ENGINE and f.methods is METHODS and f.study is not None
    assert {s.file for s in f.scenes} == {"caustics_sphere_sun.xml", "caustics_sphere_point.xml"}
    assert all((LIBRARY / s.file).is_file() for s in f.scenes)


BALL = """<scene version="3.0.0"><shape type="sphere"><point name="center" x="0" y="0" z="1"/>
  <float name="radius" value="0.5"/><bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
</shape></scene>"""

TOML = """
name = "glass ball on a floor"

[camera]
origin = [2.4, -1.2, 1.9]
target = [0.45, 0, 0]
fov_deg = 30
width = 10
height = 10

[[lights]]
type = "point_light"
position = [-1.2, 0.0, 3.2]
intensity = 10.0

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [4, 4]

[[shapes]]
type = "mitsuba_xml"
file = "ball.xml"
"""


def test_a_toml_scene_with_a_glass_ball_from_an_xml_shape(tmp_path):
    """An rtfit TOML scene (a floor, a point light) holding the glass ball as a Mitsuba XML shape: the
    family applies, its case runs and conserves energy through the ball (the same geometry as the shipped
    point-light scene)."""
    (tmp_path / "ball.xml").write_text(BALL)
    (tmp_path / "s.toml").write_text(TOML)
    r = audit(tmp_path / "s.toml", "caustics", spp=4, pass_spp=4, fit=False, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    assert case.parameters["caster_bsdf"] == "dielectric"
    assert float(case.reference.mean[case.mask].max()) > 0.5
    e = case.parameters["energy"]  # (the TOML floor reaches Mitsuba as a rectangle)
    assert abs(e["traced_on_receiver_w"] - e["analytic_on_receiver_w"]) < 4 * e["traced_stderr_w"]


def test_an_orthographic_camera_is_refused_in_one_line(tmp_path):
    """The reference connects photons to a pinhole: another sensor gets one clear line (the audit's own)."""
    from rtfit.experiments.audit import AuditError

    text = SUN.read_text().replace('<sensor type="perspective">\n        <float name="fov" value="30"/>',
                                   '<sensor type="orthographic">')  # fmt: skip
    assert '<sensor type="orthographic">' in text
    (tmp_path / "o.xml").write_text(text)
    with pytest.raises(AuditError, match="perspective") as e:
        audit(tmp_path / "o.xml", "caustics", spp=2, pass_spp=2, fit=False, cache=tmp_path / "c", **FAST)
    assert "\n" not in str(e.value)
