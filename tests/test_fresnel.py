"""The fresnel family (issue 34): `rtfit.realtime.fresnel.METHODS` against the Fresnel equations written here
in mpmath complex arithmetic and against Mitsuba's own ``fresnel``/``fresnel_conductor``; extremes without
NaN/Inf; and the audit of the shipped scene (scenes/library/fresnel_spheres.xml), of a glass sphere seen from
inside (total internal reflection) and of an rtfit TOML scene holding the shipped spheres.

Expected values are independent of the code: the reflectance from Snell's law with a complex index
(cos θ_t = √(1 − sin²θ/η̂²), r_s, r_p as amplitudes, F = ½(|r_s|² + |r_p|²)) in 40-digit mpmath, and
Mitsuba."""

from __future__ import annotations

import math

import mitsuba as mi
import mpmath as mp
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

import rtfit
from rtfit.experiments.audit_cli import audit as audit_cli
from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.arrays import backend_float
from rtfit.realtime.fresnel import F82_COS, METHODS, conductor_fresnel, dielectric_fresnel, schlick
from rtfit.scenes.parse import LIBRARY_DIR

SCENE = LIBRARY_DIR / "fresnel_spheres.xml"
ANGLES = (1.0, 0.9, 0.6, 0.3, 1.0 / 7.0, 0.05, 0.0)  # cos θ
# (η, k): glass, glass seen from inside (TIR below cos θ ≈ 0.745), gold (R), copper (G), a large k
MATERIALS = (
    (1.5, 0.0),
    (1.0 / 1.5, 0.0),
    (0.143, 3.983),
    (0.924, 2.453),
    (2.0, 10.0),
)
mp.mp.dps = 40


def fresnel_mp(c: float, eta: float, k: float) -> float:
    """Unpolarised reflectance of the index η + ik at cos θ = c (Fresnel's equations, complex Snell)."""
    n = mp.mpc(eta, k)
    c = mp.mpf(c)
    cos_t = mp.sqrt(1 - (1 - c * c) / (n * n))
    if mp.im(cos_t) < 0:  # the decaying branch of the transmitted wave
        cos_t = -cos_t
    rs = (c - n * cos_t) / (c + n * cos_t)
    rp = (n * c - cos_t) / (n * c + cos_t)
    return float((abs(rs) ** 2 + abs(rp) ** 2) / 2)


def _eval(mid: str, c, eta, k, params=None, float32=False):
    inputs = {"cos_theta": c, "eta": eta, "k": k}
    m = METHODS[mid]
    if float32:
        Float = backend_float(None)
        args = {
            n: Float(np.asarray(np.broadcast_to(inputs[n], np.shape(c)), np.float32)) for n in m.input_names
        }
        return np.array(m.evaluate(args, params), np.float64)
    return np.asarray(m.evaluate({n: np.asarray(inputs[n], np.float64) for n in m.input_names}, params))


@pytest.mark.parametrize(("eta", "k"), MATERIALS)
def test_exact_rows_are_fresnels_equations(eta, k):
    """The exact conductor row everywhere, the exact dielectric row for k = 0 (TIR included), against
    mpmath: float64 ≤ 1e-13 (measured 4.4e-16), Dr.Jit float32 ≤ 2e-6 absolute (measured 4.0e-7)."""
    c = np.array(ANGLES)
    want = np.array([fresnel_mp(x, eta, k) for x in ANGLES])
    rows = ["exact-conductor"] + (["exact-dielectric"] if k == 0.0 else [])
    for mid in rows:
        got = _eval(mid, c, np.full_like(c, eta), np.full_like(c, k))
        assert np.max(np.abs(got - want)) < 1e-13, mid
        got32 = _eval(mid, c, np.full_like(c, eta), np.full_like(c, k), float32=True)
        assert np.max(np.abs(got32 - want)) < 2e-6, mid
    assert float(conductor_fresnel(0.5, eta, k)) == pytest.approx(fresnel_mp(0.5, eta, k), abs=1e-13)
    if eta < 1.0 and k == 0.0:  # beyond the critical angle (cos θ < 0.745): total internal reflection
        assert np.all(_eval("exact-dielectric", c[c < 0.7], eta, 0.0) == 1.0)


def test_dielectric_known_values():
    """Glass η = 1.5: F(0°) = 0.04 exactly, Brewster's angle (tan θ_B = η) zeroes r_p only, F(90°) = 1; η = 1
    is no interface (0, even at grazing incidence, as Mitsuba)."""
    assert float(dielectric_fresnel(1.0, 1.5)) == pytest.approx(0.04, abs=1e-15)
    cb = 1.0 / math.sqrt(1.0 + 1.5**2)
    rs = (cb - 1.5 * math.sqrt(1 - (1 - cb * cb) / 2.25)) / (cb + 1.5 * math.sqrt(1 - (1 - cb * cb) / 2.25))
    assert float(dielectric_fresnel(cb, 1.5)) == pytest.approx(rs * rs / 2, rel=1e-12)
    assert float(dielectric_fresnel(0.0, 1.5)) == 1.0
    assert np.all(dielectric_fresnel(np.array([0.0, 0.5, 1.0]), 1.0) == 0.0)


@pytest.mark.parametrize(("eta", "k"), MATERIALS)
def test_schlick_forms(eta, k):
    """Schlick is exact at normal incidence (F0 of the complex index) and at grazing (1); the seed's metal
    form (Lazányi–Szirmay-Kalos) is Schlick with the conductor's F0 (equal to 1e-15); F82 is exact at 0°,
    81.8° and 90° (outside TIR); the seed's slider form with sFresnel = F0 is Schlick; the rim term is
    (1 − c)², and with ranges (0, ½, 1) the same."""
    c = np.linspace(0.0, 1.0, 101)
    e, kk = np.full_like(c, eta), np.full_like(c, k)
    f0 = fresnel_mp(1.0, eta, k)
    s = _eval("schlick", c, e, kk)
    assert s[-1] == pytest.approx(f0, abs=1e-14) and s[0] == pytest.approx(1.0, abs=1e-15)
    assert float(schlick(0.3, eta, k)) == pytest.approx(f0 + (1 - f0) * 0.7**5, abs=1e-14)
    assert np.max(np.abs(_eval("seed-metal", c, e, kk) - s)) < 1e-15
    assert np.max(np.abs(_eval("schlick-p", c, e, kk, {"p": 5.0}) - s)) < 1e-15
    assert np.max(np.abs(_eval("seed-schlick", c, e, kk, {"f0": f0}) - s)) < 1e-14
    f82 = _eval("f82", np.array([1.0, F82_COS, 0.0]), np.full(3, eta), np.full(3, k))
    if eta >= 1.0:
        assert f82 == pytest.approx([f0, fresnel_mp(F82_COS, eta, k), 1.0], abs=1e-13)
    rim = _eval("seed-rim", c, e, kk)
    assert np.allclose(rim, (1 - c) ** 2, atol=1e-15)
    ranges = {"low": 0.0, "mid": 0.5, "high": 1.0}
    assert np.allclose(_eval("seed-rim-ranges", c, e, kk, ranges), rim, atol=1e-15)


def test_schlick_error_is_largest_near_grazing():
    """Schlick's known error for glass (η = 1.5): 0 at normal and grazing incidence, largest near grazing
    (measured: +0.0357, Schlick above the exact, at cos θ = 0.09, θ ≈ 85°)."""
    c = np.linspace(0.0, 1.0, 2001)
    exact = np.array([fresnel_mp(x, 1.5, 0.0) for x in c[::10]])
    err = _eval("schlick", c[::10], np.full(201, 1.5), np.zeros(201)) - exact
    assert abs(err[-1]) < 1e-15 and abs(err[0]) < 1e-15
    worst = c[::10][np.argmax(np.abs(err))]
    assert 0.03 < worst < 0.35, worst
    assert 0.02 < np.max(np.abs(err)) < 0.05


def test_mitsubas_own_fresnel_is_the_exact_rows():
    """Mitsuba's ``fresnel`` (signed cos: negative is the inside, 1/η) and ``fresnel_conductor`` against the
    exact rows in float32: ≤ 1e-6 absolute (measured 1.2e-7: one float32 ulp near F = 1)."""
    mi.set_variant("llvm_ad_rgb")
    c = np.linspace(0.0, 1.0, 257).astype(np.float32)
    for eta, k in MATERIALS:
        want = _eval("exact-conductor", c, np.full(c.shape, eta), np.full(c.shape, k), float32=True)
        if k == 0.0 and eta > 1.0:
            got = np.array(mi.fresnel(mi.Float(c), mi.Float(eta))[0])
            inside = np.array(mi.fresnel(mi.Float(-c), mi.Float(1.0 / eta))[0])  # the same interface
            assert np.max(np.abs(inside - got)) < 1e-6
        else:
            got = np.array(mi.fresnel_conductor(mi.Float(c), mi.Complex2f(eta, k)))
        assert np.max(np.abs(got - want)) < 1e-6, (eta, k)


@settings(max_examples=60, deadline=None)
@given(
    c=st.one_of(st.sampled_from([0.0, 1.0, 1e-7, 1.0 - 1e-7]), st.floats(0.0, 1.0)),
    eta=st.one_of(st.sampled_from([1.0, 1e-3, 1e4, 0.5, 1.0 + 1e-6]), st.floats(1e-3, 1e4)),
    k=st.one_of(st.sampled_from([0.0, 10.0, 100.0]), st.floats(0.0, 100.0)),
)
def test_extremes_are_finite_and_in_range(c, eta, k):
    """Every row at cos θ = 0 and 1, η = 1, η up to 10⁴, η < 1 (TIR), k up to 100: finite, in [0, 1]
    (float64 NumPy and Dr.Jit float32), with every free parameter at its start and at its bounds."""
    cs = np.array([c])
    for mid, m in METHODS.items():
        sets = [{}] + [{p: getattr(v, side) for p, v in m.params.items()} for side in ("lower", "upper")]
        for params in sets:
            for f32 in (False, True):
                v = _eval(mid, cs, np.array([eta]), np.array([k]), params, float32=f32)
                assert np.all(np.isfinite(v)), (mid, params, f32)
                assert np.all((v >= -1e-6) & (v <= 1.0 + 1e-6)), (mid, params, f32, v)


def test_kernel_text_runs_on_numpy_ops():
    """One text: the NumPy run of the table equals `Method.evaluate` (float64)."""
    c = np.linspace(0, 1, 11)
    for mid, m in METHODS.items():
        direct = m(NUMPY_OPS, {"cos_theta": c, "eta": np.full(11, 1.3), "k": np.full(11, 0.5)})
        assert np.allclose(direct, _eval(mid, c, np.full(11, 1.3), np.full(11, 0.5)), atol=1e-15), mid


# ------------------------------------------------------------------------------------------------ audits
def _audit(tmp_path, scene, **kw):
    return rtfit.audit(scene, ["fresnel"], width=16, height=16, spp=4, cache=tmp_path / "c",
                       metrics=("rmse", "max_abs"), cost_elements=4096, **kw)  # fmt: skip


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    return _audit(tmp_path_factory.mktemp("fresnel"), SCENE)


def _case(r, bsdf):
    (case,) = [c for c in r.cases if c.parameters["bsdf"] == bsdf]
    return case


def test_shipped_scene_reference_is_fresnels_equations(shipped):
    """One case per material; each reference pixel equals mpmath's Fresnel of the loaded index at the
    pixel's cos θ (≤ 2e-6: float32), per channel; gold and glass through the BSDF's own sample, copper
    (rough) through Mitsuba's fresnel_conductor."""
    assert sorted(c.parameters["bsdf"] for c in shipped.cases) == [
        "conductor",
        "dielectric",
        "roughconductor",
    ]
    assert _case(shipped, "conductor").parameters["eta"] == pytest.approx(
        [0.143036, 0.375307, 1.44205], rel=1e-5
    )
    assert _case(shipped, "dielectric").parameters["eta"] == pytest.approx([1.5042] * 3, rel=1e-4)
    for case in shipped.cases:
        assert case.parameters["pixels"] >= 6
        ref = case.reference.mean[case.mask]
        assert np.all(case.reference.stderr == 0.0)
        for ch, inp in enumerate(case.channel_inputs):
            want = [
                fresnel_mp(c, e, k) for c, e, k in zip(inp["cos_theta"], inp["eta"], inp["k"], strict=True)
            ]
            assert np.max(np.abs(ref[:, ch] - want)) < 2e-6, (case.id, ch)
    assert _case(shipped, "conductor").parameters["reference"] == "bsdf.sample"
    assert _case(shipped, "roughconductor").parameters["reference"] == "fresnel formula"


def test_shipped_scene_rows(shipped):
    """The exact rows equal the reference to float32 precision (≤ 1e-5 relative, the engine's precision
    floor); exact-dielectric is left out on metals; Schlick is nearly exact at normal incidence and worst
    near grazing; the fitted exponent improves Schlick's RMSE on every material."""
    for case in shipped.cases:
        rows = shipped.outcomes[case.id]
        ref = case.reference.mean[case.mask]
        exact = ["exact-conductor"] + (
            ["exact-dielectric"] if case.parameters["bsdf"] == "dielectric" else []
        )
        assert ("exact-dielectric" in rows) == (case.parameters["bsdf"] == "dielectric")
        for row in exact:
            assert np.max(np.abs(rows[row].image[case.mask] - ref) / ref) < 1e-5, (case.id, row)
        err = np.abs(rows["schlick"].image[case.mask] - ref).max(axis=1)
        cos = case.channel_inputs[0]["cos_theta"]
        assert err[np.argmax(cos)] < 0.25 * err.max()
        assert cos[np.argmax(err)] < 0.6
        fitted = [r for r in rows if r.startswith("schlick-p") and rows[r].fit]
        rmse = {r: shipped.metrics(case.id, r)["rmse"].value for r in (*fitted[:1], "schlick")}
        assert fitted and rmse[fitted[0]] < rmse["schlick"]


def test_glass_seen_from_inside_is_total_internal_reflection(tmp_path):
    """A camera inside a glass sphere (radius 5, BK7): every pixel sees the sphere from inside (η → 1/η);
    beyond the critical angle the reference and the exact rows are 1, Schlick is not."""
    xml = tmp_path / "inside.xml"
    xml.write_text("""<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="70"/>
        <transform name="to_world"><lookat origin="0, 0, 3.5" target="0, 5, 3.5" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="sphere"><float name="radius" value="5"/><bsdf type="dielectric"/></shape>
</scene>""")
    r = _audit(tmp_path, xml)
    (case,) = r.cases
    inp = case.channel_inputs[0]
    assert np.allclose(inp["eta"], 1.0 / case.parameters["eta"][0])
    ref = case.reference.mean[case.mask][:, 0]
    tir = inp["cos_theta"] ** 2 < 1.0 - inp["eta"] ** 2
    assert tir.sum() >= 10 and (~tir).sum() >= 10
    assert np.all(ref[tir] == 1.0)
    for row in ("exact-dielectric", "exact-conductor"):
        assert np.allclose(r.image(case.id, row)[case.mask][:, 0], ref, rtol=1e-5, atol=1e-7), row
    assert np.max(1.0 - r.image(case.id, "schlick")[case.mask][tir, 0]) > 0.3


def test_toml_scene_holds_the_shipped_spheres(tmp_path):
    """rtfit TOML holds a conductor through a ``mitsuba_xml`` shape that keeps its file's BSDFs: the same
    three materials, the exact conductor row at the reference."""
    toml = tmp_path / "spheres.toml"
    toml.write_text(f"""name = "fresnel-spheres"
[camera]
origin = [0.0, -7.0, 1.2]
target = [0.0, 0.0, 0.0]
fov_deg = 40.0
width = 16
height = 16
[[shapes]]
type = "mitsuba_xml"
file = "{SCENE.as_posix()}"
[[lights]]
type = "constant_env"
radiance = 1.0
""")
    r = _audit(tmp_path, toml)
    assert sorted(c.parameters["bsdf"] for c in r.cases) == ["conductor", "dielectric", "roughconductor"]
    for case in r.cases:
        ref = case.reference.mean[case.mask]
        assert np.max(np.abs(r.image(case.id, "exact-conductor")[case.mask] - ref) / ref) < 1e-5


def test_list_names_fresnel_with_its_reason():
    out = CliRunner().invoke(audit_cli, [str(SCENE), "--list"])
    assert out.exit_code == 0, out.output
    lines = [ln for ln in out.output.splitlines() if ln.strip().startswith("fresnel —")]
    assert len(lines) == 3
    assert all("Fresnel approximation (Schlick)" in ln for ln in lines)
    assert any("gold" in ln for ln in lines) and any("copper" in ln for ln in lines)


def test_plastic_rough_glass_and_thin_glass(tmp_path):
    """A plastic's coating and a rough dielectric are audited through Mitsuba's ``fresnel`` on their own η
    (each pixel at mpmath's Fresnel within 2e-6); a thin dielectric (two interfaces) gives no case."""
    spheres = "".join(
        f'<shape type="sphere"><point name="center" x="{x}" y="0" z="0"/><float name="radius" value="0.9"/>'
        f"{bsdf}</shape>"
        for x, bsdf in (
            (-2.0, '<bsdf type="plastic"/>'),
            (0.0, '<bsdf type="roughdielectric"><float name="alpha" value="0.3"/></bsdf>'),
            (2.0, '<bsdf type="thindielectric"/>'),
        )
    )
    xml = tmp_path / "coated.xml"
    xml.write_text(f"""<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="60"/>
        <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"/>{spheres}
</scene>""")
    r = _audit(tmp_path, xml)
    assert sorted(c.parameters["bsdf"] for c in r.cases) == ["plastic", "roughdielectric"]
    for case in r.cases:
        assert case.parameters["reference"] == "fresnel formula"
        inp = case.channel_inputs[0]
        want = [fresnel_mp(c, e, 0.0) for c, e in zip(inp["cos_theta"], inp["eta"], strict=True)]
        assert np.max(np.abs(case.reference.mean[case.mask][:, 0] - want)) < 2e-6, case.id
