"""The clouds family (docs/clouds.md): the cloud-shadow kernels against closed forms (a constant box:
Beer–Lambert over the chord; a Gaussian blob: its optical depth along a line by erf, and its column depth),
the reference's ratio tracking toward the sun through Mitsuba's own gridvolume against the same closed forms,
extremes without NaN/Inf (the sun at and below the horizon, no cloud, a cloud of 10³⁰ /m), the audit of the
shipped XML scene and ``--list``."""

from __future__ import annotations

import math
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.special import erf

from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_clouds import BOX, blob_grid, cloud_blobs, sun_direction
from rtfit.experiments.audit_run import audit
from rtfit.realtime import NUMPY_OPS, CloudGrid, cloud_transmittance
from rtfit.realtime.arrays import DRJIT_OPS
from rtfit.realtime.clouds import METHODS, RADIANCE_METHODS, _rim_kernel

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

LIBRARY = Path(__file__).resolve().parents[1] / "scenes" / "library"
SCENE = LIBRARY / "clouds_sun.xml"
SKY = LIBRARY / "clouds_sky.xml"
FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "max_abs")}
BLOB = ((0.2, -0.3, 3.0), 0.5, 2.0)  # centre (m), standard deviation (m), peak σ (1/m)


def _given(method: str, lo: float, hi: float, h: float) -> dict:
    return (
        {"h": h}
        if method.startswith("plane")
        else ({"h0": lo, "h1": hi} if method.startswith("slab") else {})
    )


def _blob_cloud(n: int = 48, half: float = 2.5) -> CloudGrid:
    """`BLOB` on an n³ grid over the cube of half-width ``half`` (m) around its centre (5 standard
    deviations: the truncation is e^(−12.5) ≈ 4e-6 of the peak)."""
    c, w, a = BLOB
    lo = np.asarray(c) - half
    axes = [lo[k] + (np.arange(n) + 0.5) / n * 2 * half for k in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    r2 = (x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2
    return CloudGrid(a * np.exp(-0.5 * r2 / w**2), tuple(lo), tuple(lo + 2 * half))


def _blob_depth(p: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Closed form: ∫₀^∞ A·exp(−|p + t·s − c|²/(2w²)) dt = A·e^(−d⊥²/(2w²))·w·√(π/2)·(1 + erf(t_c/(√2·w)))
    with t_c = (c − p)·s the closest approach and d⊥ the line's distance from the centre."""
    c, w, a = BLOB
    q = np.asarray(c) - p
    tc = q @ s
    d2 = np.sum(q * q, axis=-1) - tc * tc
    return a * np.exp(-0.5 * d2 / w**2) * w * math.sqrt(math.pi / 2) * (1.0 + erf(tc / (math.sqrt(2) * w)))


# ------------------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("method", list(METHODS))
def test_constant_box_is_beer_lambert_for_every_row(method):
    """A constant σ = 0.7 /m in [−2, 2]² × [1, 2.5]: each ray from the ground below that crosses the box
    through its bottom and top travels H/μ in it, T = e^(−σH/μ) — exact for every row (the seed's texture:
    D = σH, the slab's and the march's midpoints of a constant) at three points and two suns."""
    cloud = CloudGrid(np.full((5, 7, 6), 0.7), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.5))
    pts = np.array([[0.0, 0.0, 0.0], [-0.4, 0.3, 0.0], [0.2, -0.5, 0.2]])
    for elevation in (75.0, 60.0):
        s = np.asarray(sun_direction(elevation))
        got = cloud_transmittance(pts, s, cloud, method, **_given(method, 1.0, 2.5, 1.7))
        truth = np.exp(-0.7 * 1.5 / s[2])
        assert np.max(np.abs(got - truth)) < 1e-6, (got, truth)


def test_missed_and_behind_rays_see_no_cloud():
    """A ground point whose sun ray passes beside the box, and a point above the cloud: T = 1 in every row."""
    cloud = CloudGrid(np.full((2, 2, 2), 3.0), (-1.0, -1.0, 1.0), (1.0, 1.0, 2.0))
    s = np.asarray(sun_direction(60.0))
    for method in METHODS:
        got = cloud_transmittance(np.array([[0.0, 5.0, 0.0], [0.0, 0.0, 3.0]]), s, cloud, method,
                                  **_given(method, 1.0, 2.0, 1.5))  # fmt: skip
        assert np.all(np.abs(got - 1.0) < 1e-7), (method, got)


def test_march_converges_to_the_blob_erf():
    """A Gaussian blob (σ_w = 0.5 m, peak 2 /m) on a 48³ grid: the 3-D march's T against the erf closed form
    at 5 ground points (through the core, its flank, a miss) and two suns. The trilinear grid is
    (h/w)²/8 ≈ 0.5 % off the Gaussian at its peak (h = 0.104 m): measured |ΔT| = 2.0e-3 (64 samples: the
    grid's error), 2.5e-3 (16), 0.19 (4: the knob matters)."""
    cloud = _blob_cloud()
    errors = {}
    for elevation in (70.0, 45.0):
        s = np.asarray(sun_direction(elevation))
        c = np.asarray(BLOB[0])
        base = c - (c[2] / s[2]) * s  # the ground point whose sun ray runs through the centre
        pts = base + np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.5, 0], [-0.6, 0.4, 0], [0, 3.0, 0]])
        truth = np.exp(-_blob_depth(pts, s))
        for n in (4, 16, 64):
            got = cloud_transmittance(pts, s, cloud, f"march-{n}")
            errors[n] = max(errors.get(n, 0.0), float(np.max(np.abs(got - truth))))
    assert errors[64] < 2.5e-3 and errors[16] < 3.5e-3, errors
    assert errors[4] > 0.1, errors


def test_density_plane_is_the_blob_column_depth():
    """The seed's texture D(x, y) = ∫σ dz against the Gaussian's column depth A·e^(−r²/(2w²))·w·√(2π) at
    three points (the exact column sum of the trilinear field: only the grid's interpolation error, at most
    Σ_k (h/w)²/8 = 2·(0.104/0.5)²/8 = 1.08 % where the centre falls between 2 × 2 columns, as here: measured
    1.079 %, 0.70 %, 0.11 %)."""
    cloud = _blob_cloud()
    c, w, a = BLOB
    xy = np.array([[c[0], c[1]], [c[0] + 0.4, c[1]], [c[0] - 0.3, c[1] + 0.6]])
    got = cloud.plane(NUMPY_OPS, xy[:, 0], xy[:, 1])
    r2 = np.sum((xy - np.asarray(c[:2])) ** 2, axis=1)
    truth = a * np.exp(-0.5 * r2 / w**2) * w * math.sqrt(2 * math.pi)
    assert np.max(np.abs(got / truth - 1.0)) < 1.1e-2, (got, truth)


def test_texture_mips_are_block_means():
    """The seed texture's mip levels (plane-mip1, -mip2): the shipped grid's 40 × 40 columns averaged over
    2 × 2 and 4 × 4 blocks (NumPy reshape, independent of the split the module uses), read at a coarse texel
    centre; a 5 × 3 plane (not divisible by 2) splits into blocks of 3 and 2 columns."""
    cloud = CloudGrid(blob_grid().astype(np.float64), *BOX)
    d = blob_grid().astype(np.float64).sum(axis=0) * 0.2  # Δz = 2 m / 10
    for level in (1, 2):
        b = 1 << level
        mean = d.reshape(40 // b, b, 40 // b, b).mean(axis=(1, 3))
        assert np.allclose(cloud.columns(level), mean, rtol=1e-12, atol=0)
        w = 8.0 / (40 // b)  # a coarse texel's width (m); texel (3, 5) centre
        x, y = -4.0 + 3.5 * w, -4.0 + 5.5 * w
        got = cloud.plane(NUMPY_OPS, np.array([x]), np.array([y]), level)
        assert math.isclose(float(got[0]), mean[5, 3], rel_tol=1e-12)
    odd = CloudGrid(np.arange(15.0).reshape(1, 3, 5), (0, 0, 0), (5, 3, 1))
    assert odd.plane_resolution(1) == (2, 1) and odd.columns(1).shape == (1, 2)
    full = np.arange(15.0).reshape(3, 5)
    assert np.allclose(odd.columns(1), [[full[:, :3].mean(), full[:, 3:].mean()]])


def test_seed_plane_is_exact_for_a_thin_layer():
    """A layer 2 cm thick of horizontally varying density: the seed's texture at the layer's height with k = 1
    equals the 3-D march (64) to 1e-4 at three points: the form's own limit, Beer–Lambert through a layer."""
    x = (np.arange(16) + 0.5) / 16 * 4 - 2
    yy, xx = np.meshgrid(x, x, indexing="ij")
    layer = 20.0 * (1.2 + np.sin(2 * xx) * np.cos(1.5 * yy))
    cloud = CloudGrid(np.stack([layer, layer]), (-2.0, -2.0, 3.0), (2.0, 2.0, 3.02))
    s = np.asarray(sun_direction(50.0))
    pts = np.array([[-2.0, 0.0, 0.0], [-2.8, 0.7, 0.0], [-1.5, -0.9, 0.0]])
    plane = cloud_transmittance(pts, s, cloud, "plane", k=1.0, h=3.01)
    march = cloud_transmittance(pts, s, cloud, "march-64")
    assert np.all(march < 0.9) and np.max(np.abs(plane - march)) < 1e-4, (plane, march)


# ------------------------------------------------------------------------------------------- Mitsuba
def _medium(mi, cloud: CloudGrid):
    lo, hi = np.asarray(cloud.lo), np.asarray(cloud.hi)
    to_world = mi.ScalarTransform4f().translate(lo.tolist()) @ mi.ScalarTransform4f().scale(
        (hi - lo).tolist()
    )
    return mi.load_dict({
        "type": "heterogeneous",
        "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(cloud.data[..., None].astype(np.float32)),
                    "to_world": to_world},
        "albedo": 0.0,
    })  # fmt: skip


def test_reference_is_the_blob_erf_within_noise():
    """`sun_transmittance_pass` (ratio tracking through Mitsuba's own gridvolume of the 48³ blob) against the
    erf closed form at 6 ground points: |z| < 4 with the grid's interpolation allowance (2e-3) added, and the
    march-64 row on the same points within the same band."""
    import mitsuba as mi

    from rtfit.reference.cloud_shadow import sun_transmittance_pass

    mi.set_variant("llvm_ad_rgb")
    cloud = _blob_cloud()
    s = np.asarray(sun_direction(55.0))
    c = np.asarray(BLOB[0])
    base = c - (c[2] / s[2]) * s
    pts = base + np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.5, 0], [-0.6, 0.4, 0], [0.2, -0.2, 0], [0, 4.0, 0]])
    r = sun_transmittance_pass(mi, _medium(mi, cloud), pts, s, 512, 7)
    mean = r.mean.mean(axis=1)
    err = np.sqrt(r.var.mean(axis=1) / (3 * r.spp))
    truth = np.exp(-_blob_depth(pts, s))
    assert np.all(np.abs(mean - truth) <= 4 * err + 2e-3), (mean, truth, err)
    march = cloud_transmittance(pts, s, cloud, "march-64")
    assert np.all(np.abs(mean - march) <= 4 * err + 2e-3), (mean, march, err)
    assert mean[-1] == 1.0  # the miss: no tracking, T = 1 exactly


def test_reference_is_mitsubas_own_sun_irradiance_on_the_ground():
    """E = E_sun·cosθ·T: Mitsuba's volpath (its own shadow-ray transmittance through the gridvolume)
    renders the grey ground (ρ = 0.4) of the shipped scene under the cloud made absorbing (albedo 0), seen
    from a camera below the cloud (8 × 8 pixel centres); πL/ρ/(E_sun·sin 60°) is T at each pixel's ground
    point, against `sun_transmittance_pass` there: |z| < 4 on the combined standard error."""
    import mitsuba as mi

    from rtfit.reference.cloud_shadow import sun_transmittance_pass
    from rtfit.reference.estimators import gbuffer, radiance_pass

    mi.set_variant("llvm_ad_rgb")
    s = np.asarray(sun_direction(60.0))
    scene = mi.load_file(str(SCENE), dx=f"{-s[0]}", dy="0", dz=f"{-s[2]}")
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("albedo.value.value"))
    params[key] = 0.0
    params.update()
    look = mi.ScalarTransform4f().look_at(origin=[-0.9, -1.1, 1.5], target=[-0.9, -1.1, 0.0], up=[0, 1, 0])
    film = {"type": "hdrfilm", "width": 8, "height": 8}
    sensor = mi.load_dict({"type": "perspective", "fov": 90.0, "to_world": look, "film": film})
    r = radiance_pass(
        mi, scene, 256, 11, integrator=mi.load_dict({"type": "volpath", "max_depth": 2}), sensor=sensor
    )
    t_mi = r.mean.reshape(-1, 3)[:, 0] * math.pi / 0.4 / (3.0 * s[2])
    e_mi = np.sqrt(r.var.reshape(-1, 3)[:, 0] / r.spp) * math.pi / 0.4 / (3.0 * s[2])
    gb = gbuffer(mi, scene, sensor)
    pts = gb.position.reshape(-1, 3).astype(np.float64)
    medium = next(sh.interior_medium() for sh in scene.shapes() if sh.interior_medium() is not None)
    t = sun_transmittance_pass(mi, medium, pts, s, 256, 12)
    t_rt, e_rt = t.mean.mean(axis=1), np.sqrt(t.var.mean(axis=1) / (3 * t.spp))
    z = (t_mi - t_rt) / np.sqrt(e_mi**2 + e_rt**2 + 1e-12)
    assert t_rt.min() < 0.5 and t_rt.max() > 0.9, t_rt  # the view holds shadow and sun
    assert np.max(np.abs(z)) < 4.0, (t_mi, t_rt, z)


# ------------------------------------------------------------------------------------ the cloud's radiance
def _hg(c: float, g: float) -> float:
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)


def _radiance(method, o, d, s, cloud, e=2.0, albedo=0.8, g=0.6, l_bg=0.0, **params):
    d = np.atleast_2d(np.asarray(d, np.float64))
    inputs = {"ox": o[0], "oy": o[1], "oz": o[2], "dx": d[:, 0], "dy": d[:, 1], "dz": d[:, 2], "sx": s[0],
              "sy": s[1], "sz": s[2], "e_sun": e, "albedo": albedo, "g": g, "l_bg": l_bg,
              "cloud": cloud}  # fmt: skip
    return np.asarray(RADIANCE_METHODS[method](NUMPY_OPS, inputs, params), np.float64)


def test_single_scattering_constant_box_closed_forms():
    """σ = 0.7 /m in [−2, 2]² × [1, 2.5], the sun at the zenith. Looking straight up from below: every point
    sees e^(−σ(z − z₀))·e^(−σ(z₁ − z)) = e^(−σH), so L = ϖ·p(1)·E·σH·e^(−σH) + e^(−σH)·L_bg (exact for the
    midpoint rule). Looking straight down from above (ϑ = 180°): L = ϖ·p(−1)·E·(1 − e^(−2σH))/2 + e^(−σH)·L_bg
    (the midpoint rule's error (2σΔt)²/24 ≈ 4e-4 at N = 16, 2e-3 at N = 8). Three rays each."""
    cloud = CloudGrid(np.full((5, 7, 6), 0.7), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.5))
    s, tau = (0.0, 0.0, 1.0), 0.7 * 1.5
    for x, y in ((0.0, 0.0), (-0.7, 0.4), (1.1, -1.3)):
        for method, tol in (("single-16-8", 1e-9), ("single-8-4", 1e-9)):
            up = _radiance(method, (x, y, 0.0), (0, 0, 1.0), s, cloud, l_bg=0.5)
            truth = 0.8 * _hg(1.0, 0.6) * 2.0 * tau * math.exp(-tau) + math.exp(-tau) * 0.5
            assert abs(up[0] / truth - 1) < tol, (method, up, truth)
        for method, tol in (("single-16-8", 1e-3), ("single-8-4", 3e-3)):
            down = _radiance(method, (x, y, 4.0), (0, 0, -1.0), s, cloud, l_bg=0.5)
            truth = 0.8 * _hg(-1.0, 0.6) * 2.0 * (1 - math.exp(-2 * tau)) / 2 + math.exp(-tau) * 0.5
            assert abs(down[0] / truth - 1) < tol, (method, down, truth)


def test_single_scattering_blob_against_quadrature():
    """The 48³ Gaussian blob: single scattering along three view rays (through the core, a flank, a miss)
    against a 4000-point trapezoid of the analytic σ with the erf form of the sun's optical depth
    (`_blob_depth`) and the cumulative view depth: within the grid's and the march's error (3 %); the miss
    gives L_bg (measured: +0.40 %, +0.25 %)."""
    cloud = _blob_cloud()
    s = np.asarray(sun_direction(50.0))
    c = np.asarray(BLOB[0])
    o = c + np.array([-4.0, -1.0, -1.5])
    targets = c + np.array([[0.0, 0.0, 0.0], [0.0, 0.4, 0.2], [0.0, 9.0, 0.0]])
    d = (targets - o) / np.linalg.norm(targets - o, axis=1, keepdims=True)
    got = _radiance("single-16-8", o, d, s, cloud, l_bg=0.25)
    t = np.linspace(0.0, 12.0, 4001)
    for k in range(3):
        x = o + t[:, None] * d[k]
        sig = BLOB[2] * np.exp(-0.5 * np.sum((x - c) ** 2, axis=1) / BLOB[1] ** 2)
        tau_v = np.concatenate([[0.0], np.cumsum(0.5 * (sig[1:] + sig[:-1]) * np.diff(t))])
        f = sig * np.exp(-tau_v - _blob_depth(x, s))
        truth = 0.8 * _hg(float(d[k] @ s), 0.6) * 2.0 * np.trapezoid(f, t) + math.exp(-tau_v[-1]) * 0.25
        tol = 0.03 * truth if k < 2 else 1e-9  # the miss: the Gaussian's tail beyond the grid, e^(−160)
        assert abs(got[k] - truth) <= tol, (k, got[k], truth)


def test_gradient_row_against_numpy():
    """The seed's gradient-lit row on a constant box (σ = 0.7 /m, [−2, 2]² × [1, 2.5]) looking straight up at
    three points, the sun at 60°: x̄ is the column's midpoint (x, y, 1.75), u = ½ + ((x̄ − c)·s)/(2Σhₖ|sₖ|),
    v = ½, L = E·(a_s + (a_l − a_s)u)·(b + (1 − b)v)·(1 − e^(−σH)) + e^(−σH)·L_bg, written out here."""
    cloud = CloudGrid(np.full((5, 7, 6), 0.7), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.5))
    s = np.asarray(sun_direction(60.0))
    params = {"a_shadow": 0.02, "a_lit": 0.3, "b": 0.4}
    for x, y in ((0.0, 0.0), (-1.5, 0.4), (1.9, -1.3)):
        got = _radiance("gradient-16", (x, y, 0.0), (0, 0, 1.0), s, cloud, l_bg=0.5, **params)
        u = 0.5 + (x * s[0] + (1.75 - 1.75) * s[2]) / (2 * (2.0 * abs(s[0]) + 0.75 * abs(s[2])))
        t = math.exp(-0.7 * 1.5)
        truth = 2.0 * (0.02 + 0.28 * u) * (0.4 + 0.6 * 0.5) * (1 - t) + t * 0.5
        assert abs(got[0] - truth) < 1e-9, (got, truth)


def _hermite(x: float) -> float:
    """smoothstep's ramp written out: 0 below 0, 1 above 1, 3x² − 2x³ between."""
    x = min(max(x, 0.0), 1.0)
    return 3 * x * x - 2 * x**3


RIM = {"threshold": 0.8, "softness": 0.1, "g_rim": 0.7, "k_rim": 0.6}


def test_rim_rows_against_numpy():
    """The back-light rows on the constant box of `test_gradient_row_against_numpy` (α = 1 − e^(−σH) = 0.650,
    the gradient part written out there): with t = 0.8, w = 0.1 the pixel is below the glow's ramp, so the row
    adds k·E·p_HG(s·d, g_r) (× α blended); with t = 0.4 it is above t + w (opaque to the glow): the row is the
    gradient's value; looking away from the sun (d = −s, s·d = −1) the HG lobe is (1 − g²)/(4π(1 + g)³),
    0.55 % of its forward value; an empty cloud (α = 0): L_bg + k·E·p_HG (the plain row), L_bg (blended)."""
    cloud = CloudGrid(np.full((5, 7, 6), 0.7), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.5))
    s = np.asarray(sun_direction(60.0))
    grad = {"a_shadow": 0.02, "a_lit": 0.3, "b": 0.4}
    t = math.exp(-0.7 * 1.5)
    alpha = 1 - t
    for x, y in ((0.0, 0.0), (-1.5, 0.4), (1.9, -1.3)):
        u = 0.5 + x * s[0] / (2 * (2.0 * abs(s[0]) + 0.75 * abs(s[2])))
        gradient = 2.0 * (0.02 + 0.28 * u) * (0.4 + 0.6 * 0.5) * alpha + t * 0.5
        for blended, weight in (("", 1.0), ("-blended", alpha)):
            row = f"gradient-16-rim{blended}"
            glow = _radiance(row, (x, y, 0.0), (0, 0, 1.0), s, cloud, l_bg=0.5, **grad, **RIM)
            truth = gradient + 0.6 * 2.0 * _hg(s[2], 0.7) * weight  # α = 0.65 < t − w = 0.7: glow 1
            assert abs(glow[0] - truth) < 1e-9, (row, glow, truth)
            opaque = _radiance(
                row, (x, y, 0.0), (0, 0, 1.0), s, cloud, l_bg=0.5, **grad, **{**RIM, "threshold": 0.4}
            )
            assert abs(opaque[0] - gradient) < 1e-9, (row, opaque, gradient)  # α = 0.65 > t + w = 0.5
    # facing away from the sun: from above the box looking down along −s
    o = np.array([0.0, 0.0, 1.75]) + 3.0 * s
    empty = CloudGrid(np.zeros((2, 2, 2)), (-2.0, -2.0, 1.0), (2.0, 2.0, 2.5))
    away = _radiance("gradient-16-rim", o, -s, s, empty, l_bg=0.5, **grad, **RIM)
    lobe = (1 - 0.49) / (4 * math.pi * 1.7**3)
    assert abs(away[0] - (0.5 + 0.6 * 2.0 * lobe)) < 1e-12 and lobe < 6e-3 * _hg(1.0, 0.7), (away, lobe)
    # α = 0 (an empty cloud), looking straight up, the sun at 60°: k·E·p_HG(sin 60°) over L_bg
    for row, extra in (("gradient-16-rim", 0.6 * 2.0 * _hg(s[2], 0.7)), ("gradient-16-rim-blended", 0.0)):
        got = _radiance(row, (0.3, 0.2, 0.0), (0, 0, 1.0), s, empty, l_bg=0.5, **grad, **RIM)
        assert abs(got[0] - (0.5 + extra)) < 1e-12, (row, got)


def test_rim_smoothstep_edges_are_exact():
    """1 − smoothstep(t − w, t + w, α): exactly 1 at α = t − w and below, exactly 0 at α = t + w and above, ½
    at t, 1 − (3·¼² − 2·¼³) a quarter into the ramp; w = 0 is the hard step (1 at α ≤ t, 0 above); times the
    HG lobe (`_hg`)."""
    for t, w in ((0.5, 0.25), (0.3, 0.125), (0.75, 0.0)):
        alpha = np.array([0.0, t - w, t - w + 0.5 * w, t, t + w, t + w + 1e-3, 1.0])
        got = np.asarray(_rim_kernel(NUMPY_OPS, alpha, 0.4, t, w, -0.3)) / _hg(0.4, -0.3)
        ramp = [(a - (t - w)) / (2 * w) if w else float(a > t) for a in alpha]
        truth = [1.0 - _hermite(r) for r in ramp]
        assert np.allclose(got, truth, rtol=0, atol=1e-12), (t, w, got, truth)
        assert got[1] == 1.0 and got[-1] == 0.0 and got[0] == 1.0, got
        if w:
            assert got[4] == 0.0, got
            assert abs(got[3] - 0.5) < 1e-12 and abs(got[2] - (1 - _hermite(0.25))) < 1e-12, got


@settings(max_examples=30, deadline=None)
@given(
    alpha=st.floats(0.0, 1.0),
    cos=st.floats(-1.0, 1.0),
    t=st.floats(0.0, 1.0),
    w=st.floats(0.0, 0.5),
    g=st.floats(-0.99, 0.99),
)
@example(alpha=0.0, cos=1.0, t=0.0, w=0.0, g=0.99)
@example(alpha=1.0, cos=-1.0, t=1.0, w=0.0, g=-0.99)
@example(alpha=0.0, cos=-1.0, t=0.0, w=0.0, g=-0.99)
@example(alpha=1.0, cos=1.0, t=1.0, w=0.0, g=0.99)
@example(alpha=0.5, cos=1.0, t=0.5, w=0.0, g=0.99)  # α = t with w = 0: the guard's 0/0
def test_rim_extremes_finite(alpha, cos, t, w, g):
    """The back-light's glow over its whole domain (w = 0 the hard threshold, t at 0 and 1, g at ±0.99, α at
    0 and 1): finite, in [0, p_HG], on float64 (NumPy) and float32 (Dr.Jit)."""
    lobe = _hg(cos, g)
    a = np.array([alpha, 0.0, 1.0])
    f32 = dr.llvm.Float
    for got in (_rim_kernel(NUMPY_OPS, a, cos, t, w, g), _rim_kernel(DRJIT_OPS, f32(a), cos, t, w, g)):
        got = np.asarray(got, np.float64)
        assert np.all(np.isfinite(got)) and np.all(got >= 0.0) and np.all(got <= lobe * (1 + 1e-5)), got


def _sky_render(mi, density: float, depth: int, spp: int):
    from rtfit.reference.estimators import gbuffer, radiance_pass

    s = np.asarray(sun_direction(60.0))
    scene = mi.load_file(str(SKY), res="8", density=str(density), dx=f"{-s[0]}", dy="0", dz=f"{-s[2]}")
    r = radiance_pass(mi, scene, spp, 3, integrator=mi.load_dict({"type": "volpath", "max_depth": depth}))
    d = gbuffer(mi, scene, scene.sensors()[0]).view_dir.reshape(-1, 3).astype(np.float64)
    cloud = CloudGrid(blob_grid().astype(np.float64) * density, *BOX)
    row = _radiance("single-16-8", (-9.0, -1.3, 0.7), d, s, cloud, e=3.0, albedo=0.9, g=0.8)
    return r.mean.reshape(-1, 3)[:, 0], np.sqrt(r.var.reshape(-1, 3)[:, 0] / r.spp), row


@pytest.mark.parametrize(("density", "depth", "spp"), [(0.05, -1, 2048), (0.3, 2, 1024)])
def test_single_scattering_is_volpath_in_a_thin_cloud(density, depth, spp):
    """Mitsuba's volpath renders the shipped sky scene (8², the backlit view, albedo 0.9, HG 0.8): with the
    cloud made thin (× 0.05: column depths ≤ 0.2) and all bounces, and with the cloud × 0.3 and one
    scattering only (max_depth 2), the single-16-8 row equals it within noise: |z| < 4 per pixel and on the
    pixels' sum (measured at 1024 and 256 spp: +0.2 % ± 9 % thin, −4 % ± 7 % one scattering, summed)."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    ref, err, row = _sky_render(mi, density, depth, spp)
    seen = err > 0  # a pixel no sample scattered in has no error bar (the row is small there: in the sum)
    assert seen.sum() > 10, seen
    assert np.all(np.abs(ref - row)[seen] <= 4 * err[seen]), (ref, row, err)
    total = np.sqrt(np.sum(err**2))
    assert abs(ref.sum() - row.sum()) < 4 * total, (ref.sum(), row.sum(), total)


# ------------------------------------------------------------------------------------------- extremes
@settings(max_examples=12, deadline=None)
@given(
    elevation=st.floats(-90.0, 90.0),
    azimuth=st.floats(0.0, 6.3),
    scale=st.sampled_from([0.0, 1e-30, 1.0, 1e6, 1e30]),
    x=st.floats(-100.0, 100.0),
    z=st.floats(-10.0, 10.0),
    k=st.floats(0.0, 100.0),
    h=st.floats(-1e4, 1e4),
)
@example(elevation=0.0, azimuth=0.0, scale=1e30, x=-4.0, z=3.0, k=0.0, h=3.0)  # at the horizon, in the cloud
@example(elevation=-90.0, azimuth=0.0, scale=1.0, x=0.0, z=0.0, k=1.0, h=3.0)  # sun straight below
def test_extremes_finite(elevation, azimuth, scale, x, z, k, h):
    """Every row in [0, 1] without NaN/Inf: the sun at/below the horizon, no cloud, a cloud of 10³⁰ /m, the
    point inside the cloud or far away, the plane anywhere, on float64 (NumPy) and float32 (Dr.Jit)."""
    e, a = math.radians(elevation), azimuth
    s = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    s /= np.linalg.norm(s)
    cloud = CloudGrid(blob_grid().astype(np.float64) * scale, *BOX)
    pts = np.array([[x, 0.5 * x, z], [0.0, 0.0, 0.0], [1.0, -1.0, 3.0]])
    for method in METHODS:
        params = (
            {"k": k, "h": h}
            if method.startswith("plane")
            else ({"k": k, "h0": h, "h1": 3.0} if "slab" in method else {})
        )
        inputs = {"px": pts[:, 0], "py": pts[:, 1], "pz": pts[:, 2], "sx": s[0], "sy": s[1], "sz": s[2],
                  "cloud": cloud}  # fmt: skip
        runs = [METHODS[method](NUMPY_OPS, inputs, params)]  # float64, no compile
        if method in ("plane", "slab-4", "march-4"):  # float32 Dr.Jit (the other N: the same text, longer)
            runs.append(cloud_transmittance(pts.astype(np.float32), s, cloud, method, **params))
        for got in runs:
            got = np.asarray(got, np.float64)
            assert np.all(np.isfinite(got)) and np.all((got >= 0.0) & (got <= 1.0)), (method, got)


@settings(max_examples=10, deadline=None)
@given(
    elevation=st.floats(-90.0, 90.0),
    azimuth=st.floats(0.0, 6.3),
    scale=st.sampled_from([0.0, 1e-30, 1.0, 1e6, 1e30]),
    view=st.floats(-1.0, 1.0),
    g=st.floats(-0.99, 0.99),
    a=st.floats(0.0, 10.0),
    b=st.floats(0.0, 2.0),
)
@example(elevation=-90.0, azimuth=0.0, scale=1e30, view=1.0, g=0.99, a=10.0, b=0.0)  # sun below, opaque
def test_radiance_extremes_finite(elevation, azimuth, scale, view, g, a, b):
    """The radiance rows without NaN/Inf and ≥ 0: the sun from straight up to straight below the horizon, no
    cloud to 10³⁰ /m, rays through, beside and from inside the cloud, g and the colours anywhere in their
    bounds, float64 (NumPy) and float32 (Dr.Jit)."""
    e, az = math.radians(elevation), azimuth
    s = np.array([math.cos(e) * math.cos(az), math.cos(e) * math.sin(az), math.sin(e)])
    s /= np.linalg.norm(s)
    cloud = CloudGrid(blob_grid().astype(np.float64) * scale, *BOX)
    d = np.array([[1.0, 0.0, view], [0.0, 1.0, 0.3], [0.2, -0.1, -1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for o in ((-9.0, -1.3, 0.7), (0.0, 0.0, 3.0)):
        for method in RADIANCE_METHODS:
            params = {"a_shadow": a, "a_lit": 10.0 - a, "b": b} if method.startswith("gradient") else {}
            if "rim" in method:  # the hard threshold at t = 1, the lobe at its narrowest
                params |= {"threshold": 1.0, "softness": 0.0, "g_rim": g, "k_rim": 10.0}
            runs = [_radiance(method, o, d, s, cloud, e=100.0, albedo=1.0, g=g, l_bg=100.0, **params)]
            if method in ("gradient-16", "gradient-16-rim-blended", "single-8-4"):
                f32 = dr.llvm.Float
                inputs = {"ox": o[0], "oy": o[1], "oz": o[2], "dx": f32(d[:, 0]), "dy": f32(d[:, 1]),
                          "dz": f32(d[:, 2]), "sx": float(s[0]), "sy": float(s[1]), "sz": float(s[2]),
                          "e_sun": 100.0, "albedo": 1.0, "g": g, "l_bg": 100.0, "cloud": cloud}  # fmt: skip
                runs.append(np.asarray(RADIANCE_METHODS[method](DRJIT_OPS, inputs, params), np.float64))
            for got in runs:
                assert np.all(np.isfinite(got)) and np.all(got >= 0.0), (method, got)


def test_public_function_says_what_is_wrong_in_one_line():
    cloud = CloudGrid(np.ones((2, 2, 2)), (0, 0, 0), (1, 1, 1))
    for bad, text in [
        (lambda: cloud_transmittance(np.zeros(3), (0, 0, 2.0), cloud), "unit vector"),
        (lambda: cloud_transmittance(np.zeros(3), (0, 0, 1.0), cloud, "nope"), "unknown method"),
        (lambda: CloudGrid(-np.ones((2, 2, 2)), (0, 0, 0), (1, 1, 1)), "densities >= 0"),
        (lambda: CloudGrid(np.ones((2, 2, 2)), (0, 0, 0), (1, 0, 1)), "hi > lo"),
    ]:
        with pytest.raises(ValueError, match=text) as e:
            bad()
        assert "\n" not in str(e.value)


# ------------------------------------------------------------------------------------------ the audit
def test_shipped_grid_is_the_blobs():
    """The shipped .vol holds `blob_grid` (so the docs' σ formula is the scene's), read back by Mitsuba."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    grid = mi.VolumeGrid(str(LIBRARY / "volumes" / "clouds_blobs.vol"))
    assert list(grid.size()) == [40, 40, 10] and grid.channel_count() == 1
    assert np.array_equal(np.asarray(grid).reshape(10, 40, 40), blob_grid())
    assert math.isclose(float(cloud_blobs(np.array([-1.5, -1.0, 3.0]))), 3.0, rel_tol=0.02)


@pytest.fixture(scope="module")
def cloud_audit(tmp_path_factory):
    cache = tmp_path_factory.mktemp("clouds") / "c"
    return audit(str(SCENE), ["clouds"], width=12, height=12, spp=64, pass_spp=64, cache=cache, **FAST)


def test_shipped_scene_audit(cloud_audit):
    """The shadow case on the ground pixels: the reference is ratio tracking toward the sun; the shadowed
    points are dark and the unshadowed ones 1; the 3-D march sits near the noise floor, the seed's plane is
    evaluated and fitted (the fit not worse than the given start). The radiance case beside it (the camera
    looks down through the cloud) has its own rows only."""
    shadow, radiance = cloud_audit.cases
    rows = {f"{k}-fitted" if m.unpublished else k for k, m in RADIANCE_METHODS.items()}  # rim: fitted only
    assert set(cloud_audit.outcomes[radiance.id]) >= rows and radiance.quantity == "cloud_radiance"
    case = shadow
    assert case.id == "cloud0-shadow" and case.mask.sum() > 100
    ref = case.reference.mean[case.mask][:, 0]
    assert ref.min() < 0.3 and ref.max() > 0.99
    outcomes = cloud_audit.outcomes[case.id]
    assert {"plane", "plane-fitted", "slab-4-fitted", "march-4", "march-64"} <= set(outcomes)
    rmse = {k: o.metrics["rmse"] for k, o in outcomes.items()}
    assert rmse["march-64"].value < 3 * rmse["march-64"].noise_floor
    assert rmse["plane-fitted"].value <= rmse["plane"].value * (1 + 1e-9)


def test_sky_scene_radiance_audit(tmp_path):
    """The cloud against a black sky (clouds_sky.xml, 10², 32 spp): one radiance case on the pixels whose ray
    crosses the cloud (no surface faces the sun: no shadow case); L_bg is 0 there; the gradient row is
    evaluated and fitted (not worse than its start), the single-scattering rows evaluated, every value
    finite."""
    r = audit(str(SKY), ["clouds"], width=10, height=10, spp=32, pass_spp=32, cache=tmp_path / "c", **FAST)
    (case,) = r.cases
    assert case.id == "cloud0-radiance" and case.mask.sum() > 20
    assert np.all(case.channel_inputs[0]["l_bg"] == 0.0) and case.reference.mean[case.mask].mean() > 0.01
    outcomes = r.outcomes[case.id]
    assert {"gradient-16", "gradient-16-fitted", "single-8-4", "single-16-8"} <= set(outcomes)
    rmse = {k: o.metrics["rmse"].value for k, o in outcomes.items()}
    assert all(np.isfinite(v) for v in rmse.values()), rmse
    assert rmse["gradient-16-fitted"] <= rmse["gradient-16"] * (1 + 1e-9)
    for row in ("gradient-16-rim", "gradient-16-rim-blended"):  # unpublished constants: fitted rows only
        assert row not in outcomes and f"{row}-fitted" in outcomes, set(outcomes)
        fitted = outcomes[f"{row}-fitted"].parameters
        for name, p in RADIANCE_METHODS[row].params.items():
            assert np.isfinite(fitted[name]) and p.lower <= fitted[name] <= p.upper, (row, name, fitted)


def test_no_distant_light_no_case(tmp_path):
    """The shipped scene with its sun swapped for a point light: the family gives no case (a cloud shadow is
    the sun's), without stopping the audit."""
    text = SCENE.read_text()
    start, end = text.index('<emitter type="directional">'), text.index("</emitter>") + len("</emitter>")
    point = (
        '<emitter type="point"><point name="position" x="0" y="0" z="8"/>'
        '<rgb name="intensity" value="5"/></emitter>'
    )
    (tmp_path / "volumes").mkdir()
    (tmp_path / "volumes" / "clouds_blobs.vol").write_bytes(
        (LIBRARY / "volumes" / "clouds_blobs.vol").read_bytes()
    )
    (tmp_path / "point.xml").write_text(text[:start] + point + text[end:])
    r = audit(str(tmp_path / "point.xml"), ["clouds"], width=8, height=8, spp=8, pass_spp=8,
              cache=tmp_path / "c", **FAST)  # fmt: skip
    assert r.cases == []


def test_list_names_clouds():
    result = CliRunner().invoke(audit_cmd, [str(SCENE), "--list"])
    assert result.exit_code == 0, result.output
    assert "clouds — cloud shadow: heterogeneous medium 'cloud'" in result.output
    assert (
        "plane, plane-mip1, plane-mip2, slab-4, slab-16, march-4, march-8, march-16, march-64, gradient-16, "
        "gradient-16-rim, gradient-16-rim-blended, single-8-4, single-16-8" in result.output
    )


def test_registry_entry_is_born_on_the_engine():
    from rtfit.experiments.families import ENGINE, FAMILIES

    f = FAMILIES["clouds"]
    assert f.module == ENGINE and dict(f.methods) == {**METHODS, **RADIANCE_METHODS}
    assert {s.file for s in f.scenes} == {"clouds_sun.xml", "clouds_sky.xml"} and SKY.is_file()
