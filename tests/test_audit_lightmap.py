"""RNM and the H-basis in the ``irradiance-bases`` audit (`rtfit.experiments.audit_lightmap_bases`, issue 30
§2): lightmap texels in the UV tangent frames of the visible surfaces (Mitsuba's ``dp_du``).

Expected values come from independent computations:

* a constant environment of radiance L: E = πL at every normal, which the H-basis (its span holds the
  constants), RNM with squared and with normalised weights (at the pole every d_i = 1/√3, Σ d_i² = 1)
  reproduce exactly; RNM's linear weights give √3·πL (McTaggart 2004's overshoot, Σ d_i = √3);
* the frames: a rectangle's ∂p/∂u is its local +x (world +x here), a sphere's the azimuthal direction
  (−(p − c)_y, (p − c)_x, 0) (Mitsuba's sphere parametrisation: u the longitude about its z axis), an OBJ
  wall's the direction its texture coordinate u runs in (+z, written so here);
* an envmap on a floor facing +z with t = +x: the texel's RNM lightmaps are E at Valve's three directions
  themselves, and its H-basis value at the pole is c₁H₁ + c₃H₃(1) with c_k = ∫_{Ω+} E H_k — each E computed
  here by a Gauss–Legendre × offset-midpoint quadrature of Mitsuba's own ``Emitter.eval`` (not rtfit's
  bake or its quadrature), and H₁ = 1/√(2π), H₃ = √(3/(2π))(2z − 1) typed from Habel & Wimmer 2010.
"""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from rtfit.experiments.audit_lightmap_bases import texel_frames
from rtfit.experiments.audit_run import audit
from rtfit.experiments.audit_setup import AuditSetup
from rtfit.reference.estimators import gbuffer
from rtfit.reference.variants import scoped_variant

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "mae", "max_abs")}
TRI = "tri.obj"
_CAMERA = """<sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0, -4, 3" target="0, 0, 0.3" up="0, 0, 1"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
  </sensor>"""
_FLOOR = (
    '<shape type="rectangle" id="floor"><transform name="to_world"><scale value="2"/></transform></shape>'
)
_BALL = (
    '<shape type="sphere" id="ball"><point name="center" x="0.8" y="0" z="0.5"/>'
    '<float name="radius" value="0.5"/></shape>'
)
_TRI = """<shape type="obj" id="tri"><string name="filename" value="tri.obj"/>
    <transform name="to_world"><rotate x="1" angle="90"/><translate x="-1.2" z="0.1"/></transform></shape>"""
_CONSTANT = '<emitter type="constant"><rgb name="radiance" value="0.5, 1.0, 2.0"/></emitter>'
OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
# A wall at y = 1 facing the camera (−y), with texture coordinates: u runs up (+z), v along +x.
WALL = """v -0.5 1 0.2\nv 0.5 1 0.2\nv 0.5 1 1.2\nv -0.5 1 1.2
vt 0 0\nvt 0 1\nvt 1 1\nvt 1 0\nf 1/1 2/2 3/3 4/4\n"""
_WALL = '<shape type="obj" id="wall"><string name="filename" value="wall.obj"/></shape>'


def _write(tmp_path, name, body):
    (tmp_path / TRI).write_text(OBJ)
    (tmp_path / "wall.obj").write_text(WALL)
    (tmp_path / name).write_text(f'<scene version="3.0.0">{_CAMERA}{body}</scene>')
    return tmp_path / name


def test_constant_environment_rows_and_frames(tmp_path):
    """On a floor, a sphere, an OBJ wall with texture coordinates and an OBJ without them under a constant
    sky: the lightmap case
    holds the UV pixels only (the OBJ's are named as left out), its rows match the closed forms to 1e-9
    relative (measured 2e-15), and each texel's tangent is the shape's own ∂p/∂u direction (to 1e-5)."""
    xml = _write(tmp_path, "c.xml", _FLOOR + _BALL + _TRI + _WALL + _CONSTANT)
    r = audit(xml, "irradiance-bases", spp=8, pass_spp=4, fit=False, cache=tmp_path / "cache", **FAST)
    main, texels = r.cases
    assert texels.id == "env0-lightmap"
    assert np.all(texels.mask <= main.mask) and 0 < texels.mask.sum() < main.mask.sum()
    assert any("left out" in n and "without a UV parametrisation" in n for n in texels.notes)
    assert not {"hbasis-4", "rnm-linear"} & set(r.outcomes[main.id])
    want = math.pi * np.array([0.5, 1.0, 2.0])
    rows = r.outcomes[texels.id]
    assert set(rows) == {"hbasis-4", "hbasis-6", "rnm-linear", "rnm-squared", "rnm-normalized"}
    m = texels.mask
    for row in ("hbasis-4", "hbasis-6", "rnm-squared", "rnm-normalized"):
        np.testing.assert_allclose(rows[row].image[m], np.broadcast_to(want, (m.sum(), 3)), rtol=1e-9)
    linear = np.broadcast_to(math.sqrt(3) * want, (m.sum(), 3))
    np.testing.assert_allclose(rows["rnm-linear"].image[m], linear, rtol=1e-9)
    # the frames, against each shape's own parametrisation
    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(str(xml))
        gb = gbuffer(mi, scene)
        mask = gb.mask & ~gb.emitter
        setup = AuditSetup(
            mi, scene, scene.sensors()[0], (), r.info, gb, mask, tmp_path, "llvm_ad_rgb", 2, 2, 0, False, ""
        )
        frames, index, no_uv = texel_frames(setup)
    p = gb.position[mask].astype(np.float64)
    n = gb.normal[mask].astype(np.float64)
    t = np.where(index[:, None] >= 0, frames[np.maximum(index, 0), 0], np.nan)
    on_floor = np.abs(p[:, 2]) < 1e-4
    on_ball = np.abs(np.linalg.norm(p - [0.8, 0.0, 0.5], axis=1) - 0.5) < 1e-4
    on_wall = (np.abs(p[:, 1] - 1.0) < 1e-4) & (np.abs(p[:, 0]) < 0.5)
    assert on_floor.any() and on_ball.any() and on_wall.any() and no_uv.any()
    np.testing.assert_allclose(t[on_floor], np.broadcast_to([1.0, 0.0, 0.0], t[on_floor].shape), atol=1e-5)
    np.testing.assert_allclose(t[on_wall], np.broadcast_to([0.0, 0.0, 1.0], t[on_wall].shape), atol=1e-5)
    q = p[on_ball] - [0.8, 0.0, 0.5]
    az = np.column_stack([-q[:, 1], q[:, 0], np.zeros(len(q))])
    az /= np.linalg.norm(az, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.sum(t[on_ball] * az, axis=1)), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.sum(t[index >= 0] * n[index >= 0], axis=1), 0.0, atol=1e-6)


def test_a_mesh_without_texcoords_leaves_the_rows_out_with_a_reason(tmp_path):
    """Only the OBJ triangle (no texture coordinates: Mitsuba's ``dp_du`` is then a triangle edge) under a
    constant sky: one case, no lightmap rows, and its notes say why."""
    body = _TRI.replace('<translate x="-1.2" z="0.1"/>', '<translate x="-0.3" z="0.1"/>') + _CONSTANT
    xml = _write(tmp_path, "t.xml", body)
    r = audit(xml, "irradiance-bases", spp=4, pass_spp=2, fit=False, cache=tmp_path / "cache", **FAST)
    (case,) = r.cases
    reason = [n for n in case.notes if n.startswith("hbasis-4, hbasis-6, rnm-linear")]
    assert reason and "no surface with a UV parametrisation" in reason[0]


def _sky(h: int = 32, w: int = 64) -> np.ndarray:
    """A smooth, non-linear sky (a soft patch off the zenith): RNM's result depends on the tangent."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    uu, vv = np.meshgrid(u, v)
    patch = 2.0 * np.exp(-(((uu - 0.3) / 0.12) ** 2 + ((vv - 0.3) / 0.12) ** 2))
    base = 0.3 + 0.5 * np.cos(0.5 * np.pi * vv) ** 2
    return np.stack([base + patch, base + 0.5 * patch, base], axis=-1).astype(np.float32)


def _emitter_irradiance(emitter, normals, n_mu=160, n_phi=320):
    """E(n) = Σ L(ω) max(n·ω, 0) ΔΩ: Gauss–Legendre in cos θ × midpoints in φ offset by a third of a cell,
    L from Mitsuba's ``Emitter.eval``."""
    import drjit as dr

    mu, wmu = np.polynomial.legendre.leggauss(n_mu)
    ph = (np.arange(n_phi) + 1.0 / 3.0) * 2 * np.pi / n_phi
    m, p = np.meshgrid(mu, ph, indexing="ij")
    st = np.sqrt(1 - m * m)
    d = np.stack([st * np.cos(p), st * np.sin(p), m], -1).reshape(-1, 3)
    dw = (wmu[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = mi.Vector3f(np.ascontiguousarray(-d.T, np.float32))
    L = np.array(emitter.eval(si), np.float64).T.reshape(-1, 3)
    return np.maximum(np.asarray(normals) @ d.T, 0.0) @ (L * dw[:, None])


def test_envmap_floor_texels_match_an_independent_bake(tmp_path):
    """A floor (t = +x, N = +z) under a non-linear envmap: RNM-normalised = the mean of E at Valve's three
    directions, RNM-linear = √3 × it, H-basis = c₁H₁ + c₃H₃(1) by an independent hemisphere quadrature —
    to 2e-3 relative (measured: RNM 7.1e-4, H 8.3e-4: the bake's 128-row map of the emitter, its 5.6°
    cells and the 8 × 16 hemisphere rule)."""
    with scoped_variant("llvm_ad_rgb"):
        mi.Bitmap(_sky()).write(str(tmp_path / "sky.exr"))
    camera = _CAMERA.replace('origin="0, -4, 3"', 'origin="0, -0.2, 3"').replace('value="16"', 'value="6"')
    body = f'{_FLOOR}<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>'
    (tmp_path / "e.xml").write_text(f'<scene version="3.0.0">{camera}{body}</scene>')
    r = audit(
        tmp_path / "e.xml", "irradiance-bases", spp=4, pass_spp=2, fit=False, cache=tmp_path / "c", **FAST
    )
    texels = r.cases[1]
    m = texels.mask
    assert m.sum() == 36
    rows = r.outcomes[texels.id]
    with scoped_variant("llvm_ad_rgb"):
        emitter = mi.load_dict({"type": "envmap", "filename": str(tmp_path / "sky.exr")})
        s6, s2, s3 = math.sqrt(1 / 6), math.sqrt(0.5), math.sqrt(1 / 3)
        b = np.array([[math.sqrt(2 / 3), 0, s3], [-s6, s2, s3], [-s6, -s2, s3]])
        e_b = _emitter_irradiance(emitter, b)
        mu, wmu = np.polynomial.legendre.leggauss(24)
        mu, wmu = 0.5 * (mu + 1), 0.5 * wmu
        ph = (np.arange(48) + 0.5) * 2 * np.pi / 48
        mm, pp = np.meshgrid(mu, ph, indexing="ij")
        st = np.sqrt(1 - mm * mm)
        hemi = np.stack([st * np.cos(pp), st * np.sin(pp), mm], -1).reshape(-1, 3)
        w = (wmu[:, None] * np.full(48, 2 * np.pi / 48)[None, :]).reshape(-1)
        e_h = _emitter_irradiance(emitter, hemi)
    h1 = 1 / math.sqrt(2 * math.pi)
    h3 = math.sqrt(3 / (2 * math.pi)) * (2 * hemi[:, 2] - 1)
    c1, c3 = (w * h1) @ e_h, (w * h3) @ e_h
    want_h = c1 * h1 + c3 * math.sqrt(3 / (2 * math.pi))
    want_rnm = e_b.mean(axis=0)
    wants = {"rnm-normalized": want_rnm, "rnm-squared": want_rnm, "rnm-linear": math.sqrt(3) * want_rnm,
             "hbasis-4": want_h, "hbasis-6": want_h}  # fmt: skip
    for row, want in wants.items():
        np.testing.assert_allclose(rows[row].image[m], np.broadcast_to(want, (36, 3)), rtol=2e-3, err_msg=row)
