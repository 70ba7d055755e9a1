"""The probe-specular family (issue 34): `rtfit.realtime.probe_specular` against values computed here
independently — a constant environment (every pre-convolved lookup is that constant, exactly), a mirror
(α = 0) reading a map of known texel values at a known direction, the parallax proxies' hit points by hand,
and the GGX pre-convolution of a smooth analytic map against a 2-D quadrature of the lobe — extremes without
NaN/Inf, and the audit of the shipped room, of a constant-sky scene (where the reference is the BSDF's
albedo) and of an rtfit TOML scene, and ``--list`` naming the family.

The quadrature writes the GGX normal distribution D(h) = α²/(π((α² − 1)cos²θ_h + 1)²) (Walter et al. 2007,
eq. 33) and Karis's weighting D(h)·(n·l) with n = v = R itself, and integrates over a (θ, φ) grid about the
lobe axis on the analytic map, not on the cube map."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

import rtfit
import rtfit.realtime.probe_specular as probe_specular_module
from rtfit.experiments.audit_cli import audit as audit_cli
from rtfit.realtime.arrays import NUMPY_OPS
from rtfit.realtime.environment_maps import cube_lookup, cube_texels
from rtfit.realtime.probe_specular import (
    LEVELS,
    METHODS,
    PREFILTER_RESOLUTION,
    ProbeChains,
    box_parallax_kernel,
    level_roughness,
    lobe_within_texel,
    mip_level_kernel,
    prefilter,
    prefilter_many,
    prefilter_matrix,
    sphere_parallax_kernel,
)
from rtfit.scenes.parse import LIBRARY_DIR

SCENE = LIBRARY_DIR / "probe_specular_room.xml"
N = PREFILTER_RESOLUTION


def _unit(resolution: int) -> np.ndarray:
    p = cube_texels(resolution)["point"]
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _inputs(rx, ry, rz, *, x=0.0, y=0.0, z=0.0, alpha=0.3, wr=0.8, wd=0.0, box=2.0, radius=2.0):
    """Scalar inputs of every row (one pixel), the proxies a box [−box, box]³ and a sphere of ``radius``."""
    return {
        "x": x, "y": y, "z": z, "rx": rx, "ry": ry, "rz": rz, "nx": 0.0, "ny": 0.0, "nz": 1.0,
        "wr_r": wr, "wr_g": wr, "wr_b": wr, "wd_r": wd, "wd_g": wd, "wd_b": wd, "alpha": alpha,
        "probe": 0.0, "bx0": -box, "by0": -box, "bz0": -box, "bx1": box, "by1": box, "bz1": box,
        "radius": radius,
    }  # fmt: skip


def _row(mid: str, chains: ProbeChains, inp: dict, p: float = 1.0) -> np.ndarray:
    m = METHODS[mid]
    params = {"p": p} if "p" in m.params else {}
    return np.array(m.evaluate({**inp, "chains": chains}, params), np.float64)


def _constant_chains(c: float, e: float, probes: int = 1) -> ProbeChains:
    pre = np.full((probes * LEVELS * 6 * N * N, 3), c)
    irr = np.full((probes * 6 * 8 * 8, 3), e)
    return ProbeChains(pre, irr)


# ------------------------------------------------------------------------------------------ kernels
def test_constant_environment_is_exact():
    """A constant map L = c: every level of `prefilter` is c (weights normalised), and every row gives
    w_r·c + w_d·E/π exactly, whatever the roughness, the direction, the proxy and the probe."""
    chain = prefilter(np.full((6 * 32 * 32, 3), 2.5))
    assert chain.shape == (LEVELS * 6 * N * N, 3)
    assert np.allclose(chain, 2.5, rtol=1e-12)
    chains = _constant_chains(2.5, 7.0, probes=2)
    rng = np.random.default_rng(1)
    for _ in range(8):
        r = rng.normal(size=3)
        r /= np.linalg.norm(r)
        inp = _inputs(*r, x=rng.uniform(-1, 1), z=rng.uniform(-1, 1), alpha=rng.uniform(0, 1), wr=0.7, wd=0.2)
        inp["probe"] = 1.0
        for mid in METHODS:
            assert np.allclose(_row(mid, chains, inp), 0.7 * 2.5 + 0.2 * 7.0 / math.pi, rtol=1e-12), mid


def test_mirror_reads_the_known_direction():
    """α = 0 (a mirror): level 0, read at R = a texel centre, returns that texel's value exactly; between
    centres, the map's smooth function L(ω) = 1 + ω·a within bilinear error; p does not matter at α = 0."""
    a = np.array([0.3, -0.5, 0.8])
    q = _unit(N)
    level0 = 1.0 + q @ a
    pre = np.zeros((LEVELS * 6 * N * N, 3))
    pre[: 6 * N * N] = level0[:, None] * np.array([1.0, 2.0, 3.0])
    chains = ProbeChains(pre, np.zeros((6 * 64, 3)))
    for t in (5, 300, 777, 1500):
        got = _row("nearest", chains, _inputs(*q[t], alpha=0.0, wr=1.0))
        assert np.allclose(got, level0[t] * np.array([1.0, 2.0, 3.0]), rtol=1e-12), t
        got = _row("mip-fit", chains, _inputs(*q[t], alpha=0.0, wr=1.0), p=3.7)
        assert np.allclose(got, level0[t] * np.array([1.0, 2.0, 3.0]), rtol=1e-12), t
    r = np.array([0.2, 0.9, -0.3])
    r /= np.linalg.norm(r)
    got = _row("nearest", chains, _inputs(*r, alpha=0.0, wr=1.0))
    assert got[0] == pytest.approx(1.0 + r @ a, abs=5e-3)
    # the chain's own level 0 of a captured 32² map is that map read bilinearly (the lobe is below a texel)
    src = _unit(32)
    chain = prefilter(np.stack([1.0 + src @ a] * 3, 1))
    assert np.max(np.abs(chain[: 6 * N * N, 0] - level0)) < 5e-3


def test_parallax_hits_by_hand():
    """Lagarde's box and sphere proxies: the hit points of x + t·R worked out by hand."""
    ops = NUMPY_OPS
    # box [−1, 1]³: from (0.5, 0, 0) along +x the wall x = 1; from (0, 0, 0.5) along +y the wall y = 1
    assert box_parallax_kernel(ops, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, -1, -1, -1, 1, 1, 1) == pytest.approx(
        (1, 0, 0)
    )
    assert box_parallax_kernel(ops, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, -1, -1, -1, 1, 1, 1) == pytest.approx(
        (0.0, 1.0, 0.5)
    )
    # along the diagonal (1, 1, 0)/√2 from (0.5, 0, 0): the x wall first, at t = 0.5·√2 → (1, 0.5, 0)
    s = 1.0 / math.sqrt(2.0)
    assert box_parallax_kernel(ops, 0.5, 0.0, 0.0, s, s, 0.0, -1, -1, -1, 1, 1, 1) == pytest.approx(
        (1, 0.5, 0)
    )
    # a point outside the box: no exit, R itself
    assert box_parallax_kernel(ops, 3.0, 0.0, 0.0, 1.0, 0.0, 0.0, -1, -1, -1, 1, 1, 1) == pytest.approx(
        (1, 0, 0)
    )
    # sphere ρ = 1 from (0.5, 0, 0) along +y: (0.5, √0.75, 0); from outside: R
    assert sphere_parallax_kernel(ops, 0.5, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0) == pytest.approx(
        (0.5, math.sqrt(0.75), 0)
    )
    assert sphere_parallax_kernel(ops, 0.0, 0.0, 3.0, 0.0, 0.0, 1.0, 1.0) == pytest.approx((0, 0, 1))


def test_mip_level_reads_each_levels_roughness():
    """p = 1 maps each level's α_k = (k/(K − 1))² to level k; α = 0 → 0, α = 1 → K − 1 for any p."""
    for k, a in enumerate(level_roughness()):
        assert mip_level_kernel(NUMPY_OPS, float(a), float(LEVELS), 1.0) == pytest.approx(k, abs=1e-9)
    for p in (0.2, 1.0, 5.0):
        assert mip_level_kernel(NUMPY_OPS, 1.0, float(LEVELS), p) == pytest.approx(LEVELS - 1)
        assert mip_level_kernel(NUMPY_OPS, 0.0, float(LEVELS), p) == 0.0


def _ggx_quadrature(f, axis: np.ndarray, alpha: float, n: int = 800) -> float:
    """∫ f(ω) D(h)(axis·ω) dω / ∫ D(h)(axis·ω) dω over the hemisphere about ``axis`` (midpoint rule in
    θ, φ)."""
    t = axis / np.linalg.norm(axis)
    u = np.cross(t, [1.0, 0.0, 0.0] if abs(t[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(t, u)
    theta = (np.arange(n) + 0.5) * (0.5 * math.pi / n)
    phi = (np.arange(2 * n) + 0.5) * (math.pi / n)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    c = np.cos(th)
    w = np.sin(th) * c
    h2 = 0.5 * (1.0 + c)
    d = alpha**2 / (math.pi * ((alpha**2 - 1.0) * h2 + 1.0) ** 2)
    w = w * d
    dirs = np.sin(th)[..., None] * (np.cos(ph)[..., None] * u + np.sin(ph)[..., None] * v) + c[..., None] * t
    return float(np.sum(f(dirs) * w) / np.sum(w))


def test_ggx_prefilter_matches_quadrature():
    """Each rough level of `prefilter` of the smooth map L(ω) = 1 + ω_z² + 0.5·ω_x, at texel centres of the
    chain, against the lobe integrated on the analytic map (a 800 × 1600 grid about the axis): within 1 %
    (the 32² capture's texels)."""

    def f(d):
        return 1.0 + d[..., 2] ** 2 + 0.5 * d[..., 0]

    src = _unit(32)
    chain = prefilter(np.stack([f(src)] * 3, 1))
    q = _unit(N)
    alphas = level_roughness()
    for k in (1, 3, LEVELS - 1):
        for t in (10, 700, 1234):
            want = _ggx_quadrature(f, q[t], float(alphas[k]))
            got = chain[k * 6 * N * N + t, 0]
            assert got == pytest.approx(want, rel=1e-2), (k, t)
    # roughness blurs: at α = 1 the lobe's mean of ω_z² over the upper hemisphere about +z is below 1
    top = int(np.argmax(q[:, 2]))
    assert chain[(LEVELS - 1) * 6 * N * N + top, 0] < chain[top, 0]


def test_prefilter_many_builds_each_level_by_blocks(monkeypatch):
    """`prefilter_many` builds a level's matrix a block of rows at a time and applies it to several probes
    (issue 33: the whole matrices were the quick suite's peak memory): each probe's chain is the whole
    matrix `prefilter_matrix` times its map at the rough levels, to the rounding of a dot product of K
    positive terms ((K − 1)·ε relative: BLAS picks its kernel, and so the order of a dot product's additions,
    by the matrices' shapes; on this project's CI machine the blocks' products and the whole's differ by
    ≤ 1.4e-15), and the map's own bilinear value (`cube_lookup`), bit for bit, at the levels narrower than a
    texel. Blocks of 40 rows of 96: the last one is short."""
    monkeypatch.setattr(probe_specular_module, "PREFILTER_ROWS", 40)
    rng = np.random.default_rng(7)
    maps = [rng.random((6 * 8 * 8, 3)) for _ in range(3)]
    chains = prefilter_many(maps, target=4)
    q, size = cube_texels(4)["point"], 6 * 4 * 4
    dot_eps = (6 * 8 * 8 - 1) * np.finfo(float).eps  # K = 384 source texels a dot product
    for rad, chain in zip(maps, chains, strict=True):
        assert chain.shape == (LEVELS * size, 3)
        for k, alpha in enumerate(level_roughness()):
            level = chain[k * size : (k + 1) * size]
            if lobe_within_texel(8, float(alpha)):
                want = np.stack([np.asarray(cube_lookup(rad[:, c], q, numpy=True)) for c in range(3)], 1)
                np.testing.assert_array_equal(level, want)
            else:
                want = prefilter_matrix(8, 4, float(alpha)) @ rad
                np.testing.assert_allclose(level, want, rtol=dot_eps, atol=0)
    np.testing.assert_allclose(prefilter(maps[1], target=4), chains[1], rtol=dot_eps)


@settings(max_examples=60, deadline=None)
@given(
    alpha=st.sampled_from([0.0, 1e-6, 0.5, 1.0, 1.3, -0.1]),
    rz=st.sampled_from([1.0, 1e-7, 0.0, -1e-7, 0.3]),
    x=st.floats(-5.0, 5.0),
    p=st.sampled_from([0.2, 1.0, 5.0]),
)
def test_extremes_are_finite(alpha, rz, x, p):
    """Roughness 0 and 1 (and outside), a grazing or axis-aligned R (zero components), shading points outside
    the proxies: every row finite and inside the map's range."""
    rng = np.random.default_rng(7)
    pre = rng.uniform(0.0, 3.0, (2 * LEVELS * 6 * N * N, 3))
    chains = ProbeChains(pre, rng.uniform(0.0, 1.0, (2 * 6 * 64, 3)))
    s = math.sqrt(max(1.0 - rz * rz, 0.0))
    inp = _inputs(s, 0.0, rz, x=x, alpha=alpha, wr=1.0, box=1.0, radius=1.0)
    inp["probe"] = 1.0
    for mid in METHODS:
        v = _row(mid, chains, inp, p)
        assert np.all(np.isfinite(v)) and np.all(v >= 0.0) and np.all(v <= 3.0 + 1e-9), mid


# ------------------------------------------------------------------------------------------- audits
def _audit(tmp_path, scene, spp=4):
    return rtfit.audit(scene, ["probe-specular"], width=12, height=12, spp=spp, cache=tmp_path / "c",
                       metrics=("rmse",), cost_elements=4096)  # fmt: skip


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    return _audit(tmp_path_factory.mktemp("ps"), SCENE)


def test_shipped_room(shipped):
    """Two glossy shapes × (assigned probe, 2×2×2 grid); every row finite; on the floor the box proxy (the
    room itself) beats the seed's lookup at infinity."""
    ids = sorted(c.id for c in shipped.cases)
    assert ids == ["shape0-assigned", "shape0-grid2", "shape7-assigned", "shape7-grid2"]
    for case in shipped.cases:
        assert case.parameters["probe_count"] == (1 if case.id.endswith("assigned") else 8)
        assert case.parameters["distribution"] == "ggx"
        for row, o in shipped.outcomes[case.id].items():
            assert np.all(np.isfinite(o.image[case.mask])), (case.id, row)
    for case in shipped.cases:
        if case.parameters["bsdf"] == "roughconductor":
            rmse = {r: shipped.metrics(case.id, r)["rmse"].value for r in ("nearest", "nearest-box")}
            assert rmse["nearest-box"] < rmse["nearest"], case.id


CONSTANT_SKY = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -6, 0" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="12"/><integer name="height" value="12"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="2"/></emitter>
    <shape type="sphere"><bsdf type="roughconductor"><string name="material" value="Au"/>
        <string name="distribution" value="ggx"/><float name="alpha" value="{alpha}"/></bsdf></shape>
</scene>"""


@pytest.mark.parametrize("alpha", [0.05, 0.6])
def test_constant_sky_reference_is_the_albedo(tmp_path, alpha):
    """A rough gold sphere alone under a constant sky of radiance 2: the path-traced radiance is 2 × the
    BSDF's directional albedo; every row (the probe sees the constant sky) gives 2·w_r, within the two
    estimates' noise (the albedo from 128 BSDF samples a pixel, the reference from 16 paths)."""
    xml = tmp_path / "sky.xml"
    xml.write_text(CONSTANT_SKY.format(alpha=alpha))
    r = _audit(tmp_path, xml, spp=16)
    assert {c.id for c in r.cases} == {"shape0-assigned", "shape0-grid2"}
    for case in r.cases:
        ref = case.reference.mean[case.mask]
        wr = np.stack([case.channel_inputs[0][f"wr_{c}"] for c in "rgb"], 1)
        assert np.allclose(ref.mean(0), 2.0 * wr.mean(0), rtol=0.05)
        for row in METHODS:
            img = r.image(case.id, row)[case.mask]
            assert np.allclose(img, 2.0 * wr, rtol=1e-4), (case.id, row)


def test_toml_scene_holds_the_room(tmp_path):
    """rtfit TOML holds the room through a ``mitsuba_xml`` shape keeping its file's BSDFs."""
    toml = tmp_path / "room.toml"
    toml.write_text(f"""name = "probe-room"
[camera]
origin = [0.0, -2.8, 2.2]
target = [0.0, 0.8, 0.4]
fov_deg = 70.0
width = 12
height = 12
[[shapes]]
type = "mitsuba_xml"
file = "{SCENE.as_posix()}"
""")
    r = _audit(tmp_path, toml)
    assert {c.parameters["bsdf"] for c in r.cases} == {"roughconductor", "roughplastic"}


def test_list_names_probe_specular():
    out = CliRunner().invoke(audit_cli, [str(SCENE), "--list"])
    assert out.exit_code == 0, out.output
    lines = [ln for ln in out.output.splitlines() if ln.strip().startswith("probe-specular —")]
    assert len(lines) == 2
    assert all("nearest pre-rendered cube map" in ln for ln in lines)
