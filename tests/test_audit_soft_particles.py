"""The soft-particles family audits a user's scene (issue 30 §2): a medium-filled convex shape cut by opaque
geometry — a sphere of homogeneous medium half sunk into a floor (Mitsuba XML, null BSDF), a rotated box of
medium cutting a floor (rtfit TOML) — and one that cuts nothing.

Expected values are independent of the code: the clipped chord from the ray–sphere quadratic and the
ray–box slab test written here in NumPy, the floor's depth from the plane z = 0, Beer–Lambert with the
scene's declared σ_t, and Mitsuba's free-flight sampling of the scene's own medium as the reference."""

from __future__ import annotations

import math

import numpy as np
from click.testing import CliRunner

import rtfit
from rtfit.experiments.audit_cli import audit as audit_cli

SIGMA = np.array([0.5, 1.0, 2.0])  # 0.25, 0.5, 1.0 × scale 2
ORIGIN = np.array([0.0, -6.0, 2.5])
TOML_ORIGIN = np.array([0.0, -4.5, 2.0])

XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -6, 2.5" target="0, 0, 0.3" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/></transform>
    </shape>
    <shape type="sphere" id="puff">
        <point name="center" x="0" y="0" z="{z}"/>
        <float name="radius" value="1"/>
        <bsdf type="null"/>
        <medium type="homogeneous" name="interior">
            <rgb name="sigma_t" value="0.25, 0.5, 1.0"/>
            <float name="scale" value="2"/>
            <rgb name="albedo" value="0.8"/>
        </medium>
    </shape>
</scene>
"""


def _floor_depth(d: np.ndarray, origin=ORIGIN) -> np.ndarray:
    """Ray distance to the floor z = 0 inside |x|, |y| ≤ 4 from ``origin`` (inf where the ray misses it)."""
    t = np.where(d[:, 2] < 0, -origin[2] / np.minimum(d[:, 2], -1e-30), np.inf)
    p = origin + d * np.where(np.isfinite(t), t, 0.0)[:, None]
    return np.where(np.isfinite(t) & (np.abs(p[:, 0]) <= 4) & (np.abs(p[:, 1]) <= 4), t, np.inf)


def _sphere_chord(d, centre, radius, t_s) -> np.ndarray:
    """|[t0, t1] ∩ [0, t_s]| from the quadratic |o + t·d − c|² = r²."""
    oc = ORIGIN - centre
    b = d @ oc
    disc = b * b - (oc @ oc - radius**2)
    w = np.sqrt(np.maximum(disc, 0.0))
    t0, t1 = -b - w, -b + w
    return np.where(disc > 0, np.maximum(np.minimum(t1, t_s) - np.maximum(t0, 0.0), 0.0), 0.0)


def _audit(path, tmp_path, fit=False, spp=64):
    return rtfit.audit(path, "soft-particles", spp=spp, fit=fit, cache=tmp_path / "c", metrics=("rmse",))


def test_xml_sphere_of_medium_half_sunk_into_a_floor(tmp_path):
    """Mitsuba XML, a null-BSDF sphere of homogeneous medium (σ_t = (0.5, 1, 2) via ``scale``) half sunk into
    a floor, 24×24: the opaque depth passes through the boundary onto the floor; the exact row is the
    clipped Beer–Lambert chord of the quadratic and sits at the path-traced reference's noise; the fades'
    distances are fitted."""
    (tmp_path / "s.xml").write_text(XML.format(z=0.0))
    r = _audit(tmp_path / "s.xml", tmp_path, fit=True)
    (case,) = r.cases
    rows = set(r.outcomes[case.id])
    assert {"exact-sphere", "linear", "linear-fitted", "fitted-fitted", "spherical", "box-beer"} <= rows
    assert "exact-box" not in rows
    assert case.parameters["cut_pixels"] > 10 and case.parameters["blocked_pixels"] > 10
    assert np.allclose(case.parameters["sigma_t"], SIGMA)
    assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]
    inp = case.channel_inputs[0]
    d = np.stack([inp["dx"], inp["dy"], inp["dz"]], axis=1)  # the unit sphere at the origin: world frame
    t_floor = _floor_depth(d)
    assert np.allclose(np.where(np.isfinite(t_floor), inp["t_surface"], 0), np.where(np.isfinite(t_floor),
                       t_floor, 0), rtol=1e-5)  # fmt: skip
    chord = _sphere_chord(d, np.zeros(3), 1.0, t_floor)
    want = -np.expm1(-chord[:, None] * SIGMA)
    assert np.allclose(r.image(case.id, "exact-sphere")[case.mask], want, atol=2e-6)
    assert np.max(want) > 0.9 and np.sum(chord == 0) > 10  # dense where deep, nothing behind the floor
    s = r.fits[f"{case.id}/linear-fitted"]["s"]["value"]
    assert math.isfinite(s)
    assert r.metric_values(case.id, "linear-fitted")["rmse"] <= r.metric_values(case.id, "linear")["rmse"]


def test_a_particle_that_cuts_no_geometry_still_applies_and_says_so(tmp_path):
    """A sphere of medium floating above the floor: still audited (the unclipped opacity), with a note."""
    (tmp_path / "s.xml").write_text(XML.format(z=1.5))
    r = _audit(tmp_path / "s.xml", tmp_path, spp=16)
    (case,) = r.cases
    assert case.parameters["cut_pixels"] == 0
    assert any("the depth fades are not exercised" in n for n in case.notes)


def test_list_names_soft_particles_with_its_reason(tmp_path):
    (tmp_path / "s.xml").write_text(XML.format(z=0.0))
    result = CliRunner().invoke(audit_cli, [str(tmp_path / "s.xml"), "--list"])
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "soft-particles — particle opacity: homogeneous medium in a sphere 'puff'" in out
    assert "is a particle volume the camera sees" in out


TOML = """
name = "particle-box"
[camera]
origin = [0.0, -4.5, 2.0]
target = [0.0, 0.0, 0.3]
fov_deg = 40.0
width = 32
height = 32
[[shapes]]
type = "rectangle"
center = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
size = [8.0, 8.0]
[[media]]
type = "homogeneous"
sigma_t = [0.8, 1.4, 2.0]
albedo = 0.5
[media.boundary]
type = "cube"
center = [0.0, 0.0, 0.2]
size = [2.0, 1.2, 1.0]
rotate_axis = [0.0, 0.0, 1.0]
rotate_deg = 35.0
"""


def test_toml_rotated_box_of_medium_cutting_a_floor(tmp_path):
    """rtfit TOML: a box of dense medium (σ_t up to 2 per unit) turned 35° about z, its bottom 0.3 below the
    floor. The exact row is the slab test in the box's own frame written here, clipped by the floor; it sits
    at the reference's noise; only ``exact-box`` is a row."""
    path = tmp_path / "p.toml"
    path.write_text(TOML)
    r = _audit(path, tmp_path, spp=256)
    (case,) = r.cases
    assert "exact-box" in r.outcomes[case.id] and "exact-sphere" not in r.outcomes[case.id]
    assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]
    assert case.parameters["cut_pixels"] > 10
    # σ_t above 1 (Mitsuba refuses an RGB "reflectance" > 1: rtfit's build passes σ_t/max with scale = max)
    assert np.allclose(case.parameters["sigma_t"], [0.8, 1.4, 2.0], rtol=1e-6)
    a = math.radians(35.0)
    rot = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    half = np.array([1.0, 0.6, 0.5])
    centre = np.array([0.0, 0.0, 0.2])
    assert math.isclose(case.parameters["radius"], float(np.prod(half)) ** (1 / 3), rel_tol=1e-9)
    inp = case.channel_inputs[0]
    u = np.stack([inp["dx"], inp["dy"], inp["dz"]], axis=1)  # the box's frame: world = rot·diag(half)·local
    d = (u * half) @ rot.T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = (TOML_ORIGIN - centre) @ rot  # the ray in the box's rotated (unscaled) frame
    dl = d @ rot
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / dl, (half - o) / dl
    near = np.max(np.minimum(t1, t2), axis=1)
    far = np.min(np.maximum(t1, t2), axis=1)
    chord = np.maximum(np.minimum(far, _floor_depth(d, TOML_ORIGIN)) - np.maximum(near, 0.0), 0.0)
    want = -np.expm1(-chord[:, None] * np.array([0.8, 1.4, 2.0]))
    assert np.allclose(r.image(case.id, "exact-box")[case.mask], want, atol=1e-5)


def test_a_users_fade_of_particle_opacity_is_audited_and_fitted(tmp_path):
    """`@approximation(quantity="particle_opacity")`: a user's fade is a row beside the shipped ones, fitted
    to the scene; with the exact row's own formula written by hand it reproduces the exact row."""
    from rtfit import Param, approximation

    @approximation(quantity="particle_opacity", params={"k": Param(1.0, lower=0.1, upper=10.0)})
    def my_fade(ops, g, *, k):
        """The box fade on the depth difference, with its distance scaled by k."""
        return g.alpha * ops.minimum(ops.maximum(g.delta / (k * g.radius), 0.0), 1.0)

    @approximation(quantity="particle_opacity")
    def my_exact(ops, g):
        """1 − exp(−σℓ) of the ray's chord through the unit-radius sphere (the case's own frame)."""
        b = g.dx * g.cx + g.dy * g.cy + g.dz * g.cz
        h2 = g.cx * g.cx + g.cy * g.cy + g.cz * g.cz - b * b
        w = ops.sqrt(ops.maximum(g.radius * g.radius - h2, 0.0))
        chord = ops.maximum(ops.minimum(b + w, g.t_surface) - ops.maximum(b - w, 0.0), 0.0)
        return 1.0 - ops.exp(-g.sigma * chord)

    (tmp_path / "s.xml").write_text(XML.format(z=0.0))
    r = rtfit.audit(tmp_path / "s.xml", ["soft-particles:exact-sphere", my_fade, my_exact], spp=16,
                    cache=tmp_path / "c", metrics=("rmse",))  # fmt: skip
    (case,) = r.cases
    assert {"exact-sphere", "my_fade", "my_fade-fitted", "my_exact"} == set(r.outcomes[case.id])
    assert np.allclose(r.image(case.id, "my_exact"), r.image(case.id, "exact-sphere"), atol=2e-5)
    assert r.metric_values(case.id, "my_fade-fitted")["rmse"] <= r.metric_values(case.id, "my_fade")["rmse"]


def test_a_non_uniformly_scaled_xml_sphere_is_audited_as_the_sphere_mitsuba_renders(tmp_path):
    """Mitsuba's ``sphere`` ignores a non-uniform ``to_world`` scale (it intersects the sphere of radius
    |A·x̂|): the exact row follows what Mitsuba renders, so it stays at the reference's noise."""
    text = XML.format(z=0.0).replace(
        '<point name="center" x="0" y="0" z="0.0"/>\n        <float name="radius" value="1"/>',
        '<transform name="to_world"><scale x="1" y="0.5" z="0.8"/></transform>',
    )
    assert "scale x=" in text
    (tmp_path / "s.xml").write_text(text)
    r = _audit(tmp_path / "s.xml", tmp_path, spp=64)
    (case,) = r.cases
    assert case.parameters["radius"] == 1.0
    assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]


def _obj(vertices, faces) -> str:
    return "".join(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in vertices) + "".join(
        f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces
    )


MESH_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -6, 2.5" target="0, 0, 0.3" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="20"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform></shape>
    <shape type="obj">
        <string name="filename" value="{mesh}"/>
        <bsdf type="thindielectric"/>
        <medium type="homogeneous" name="interior"><rgb name="sigma_t" value="1"/></medium>
    </shape>
</scene>
"""


def test_a_convex_mesh_of_medium_is_a_particle_and_a_non_convex_one_is_not(tmp_path):
    """Mitsuba's own medium test scenes bound their media by OBJ spheres with null or thin-dielectric BSDFs:
    a convex mesh is a particle (no exact row: the reference is compared with the fades alone), and its
    reference is the clipped chord of the sphere it approximates (an icosphere of 1280 faces, radius 1, half
    sunk) within noise and tessellation; two disjoint tetrahedra in one mesh are not convex: no particle."""
    from rtfit.experiments.applicability import applicable_families
    from rtfit.experiments.audit import inspect_scene
    from rtfit.experiments.sdf_occlusion_scenes import icosphere

    v, f = icosphere((0.0, 0.0, 0.0), 1.0, 3)
    (tmp_path / "ball.obj").write_text(_obj(v, f))
    (tmp_path / "s.xml").write_text(MESH_XML.replace("{mesh}", "ball.obj"))
    found = applicable_families(inspect_scene(tmp_path / "s.xml"), approx="soft-particles")
    assert [a.part for a in found] == ["homogeneous medium in a convex obj mesh (s.xml line 8)"]
    r = _audit(tmp_path / "s.xml", tmp_path, spp=256)
    (case,) = r.cases
    assert not {"exact-sphere", "exact-box"} & set(r.outcomes[case.id]) and not r.results.checks
    assert any("a convex mesh" in n for n in case.notes)
    inp = case.channel_inputs[0]
    assert math.isclose(inp["radius"][0], 1.0, rel_tol=0.01)  # the sphere of its volume (a 3 % smaller mesh)
    d = np.stack([inp["dx"], inp["dy"], inp["dz"]], axis=1)  # the sphere of its volume, centred at 0: world
    want = -np.expm1(-_sphere_chord(d, np.zeros(3), 1.0, _floor_depth(d)))
    ref, err = case.reference.mean[case.mask][:, 0], case.reference.stderr[case.mask][:, 0]
    assert np.mean(np.abs(ref - want)) < 0.02 and np.median(np.abs(ref - want) / np.maximum(err, 1e-3)) < 2

    tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    two = np.concatenate([tet, tet + np.array([3.0, 0, 0])])
    (tmp_path / "two.obj").write_text(_obj(two, faces + [(a + 4, b + 4, c + 4) for a, b, c in faces]))
    (tmp_path / "t.xml").write_text(MESH_XML.replace("{mesh}", "two.obj"))
    assert "soft-particles" not in {a.family for a in applicable_families(inspect_scene(tmp_path / "t.xml"))}


def test_camera_inside_a_sphere_of_medium(tmp_path):
    """The camera inside the particle (a sphere of radius 8 around it, cut by the floor): chords start at the
    camera, the exact row stays at the reference's noise."""
    text = (
        XML.format(z=0.0)
        .replace('x="0" y="0" z="0.0"/>', 'x="0" y="-5" z="2"/>')
        .replace('<float name="radius" value="1"/>', '<float name="radius" value="8"/>')
        .replace('value="0.25, 0.5, 1.0"', 'value="0.02, 0.05, 0.1"')
    )
    (tmp_path / "s.xml").write_text(text)
    r = _audit(tmp_path / "s.xml", tmp_path, spp=64)
    (case,) = r.cases
    assert any("the camera is inside" in n for n in case.notes) and case.mask.all()
    assert all(c.passed for c in r.results.checks), [c.name for c in r.results.checks if not c.passed]
