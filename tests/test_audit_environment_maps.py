"""The ``environment-maps`` family of `rtfit audit` (`rtfit.experiments.audit_environment_maps`): a mirror,
glass or glossy shape of a user's scene shaded from one cube map captured at its centre, against the
path-traced radiance of the pixels that see it.

Scenes are written here and tiny (≤ 24 × 24 pixels, ≤ 16 spp). The independent check: a mirror sphere (a
conductor of complex index η + ik) alone under a constant environment L, seen by a camera looking at its
centre, has the exact radiance L·F(cos θ) at every pixel, with F the unpolarised conductor Fresnel
reflectance written here from the Fresnel equations (complex arithmetic in NumPy) and cos θ from a
ray–sphere intersection written here. Both the path-traced reference and the classic row must equal it.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.applicability import applicable_families, describe
from rtfit.experiments.audit import inspect_scene
from rtfit.experiments.audit_cli import audit as audit_command
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import METHOD_TABLES

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "rel_mse", "mae", "max_abs")}
ETA = np.array([0.2, 0.9, 1.1])
K = np.array([3.9, 2.4, 2.1])
SKY = np.array([0.8, 0.9, 1.0])
SIZE = 16
FOV = 20.0
ORIGIN = np.array([0.0, -6.0, 1.0])
CENTRE = np.array([0.0, 0.0, 1.0])
RADIUS = 0.8

_CONDUCTOR = (
    '<bsdf type="conductor"><rgb name="eta" value="0.2, 0.9, 1.1"/>'
    '<rgb name="k" value="3.9, 2.4, 2.1"/></bsdf>'
)


def _scene(body: str, size: int = SIZE) -> str:
    return f"""<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="{FOV}"/>
        <transform name="to_world"><lookat origin="0, -6, 1" target="0, 0, 1" up="0, 0, 1"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="{size}"/><integer name="height" value="{size}"/>
        </film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.0"/></emitter>
    {body}
</scene>
"""


MIRROR = f"""<shape type="sphere" id="ball"><point name="center" x="0" y="0" z="1"/>
        <float name="radius" value="{RADIUS}"/>{_CONDUCTOR}</shape>"""
FLOOR = """<shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.4, 0.3"/></bsdf></shape>"""


def conductor_fresnel(cos_i: np.ndarray, eta: float, k: float) -> np.ndarray:
    """Unpolarised reflectance ½(|r_s|² + |r_p|²) of a conductor of index n = η + ik seen from vacuum:
    cos θ_t = √(1 − sin²θ_i/n²) (complex), r_s = (cos θ_i − n cos θ_t)/(cos θ_i + n cos θ_t),
    r_p = (n cos θ_i − cos θ_t)/(n cos θ_i + cos θ_t)."""
    n = eta + 1j * k
    c = cos_i.astype(complex)
    ct = np.sqrt(1.0 - (1.0 - c * c) / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def sphere_cosines(size: int) -> np.ndarray:
    """cos θ_i (size, size) of each pixel-centre ray of the pinhole at ORIGIN looking at CENTRE (fov along x)
    where it meets the sphere, NaN elsewhere. The sphere sits on the optical axis, so the pattern is
    symmetric under flips of the image axes (no orientation convention can change it)."""
    f = (CENTRE - ORIGIN) / np.linalg.norm(CENTRE - ORIGIN)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    h = math.tan(math.radians(FOV) / 2)
    c = ((np.arange(size) + 0.5) / size * 2 - 1) * h
    x, y = np.meshgrid(c, -c)
    d = f + x[..., None] * r + y[..., None] * u
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = ORIGIN - CENTRE
    b = np.sum(d * oc, -1)
    disc = b * b - (oc @ oc - RADIUS**2)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    n = (ORIGIN + t[..., None] * d - CENTRE) / RADIUS
    return np.where(disc > 0, -np.sum(d * n, -1), np.nan)


def test_mirror_sphere_under_a_constant_sky_is_l_times_fresnel(tmp_path):
    (tmp_path / "m.xml").write_text(_scene(MIRROR))
    r = audit(tmp_path / "m.xml", "environment-maps", spp=8, pass_spp=4, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    cos = sphere_cosines(SIZE)
    inside = np.isfinite(cos) & (cos > 0.05)  # off the silhouette: a pixel centre near it may miss in float32
    assert np.array_equal(case.mask & inside, inside) and case.mask.sum() <= np.isfinite(cos).sum()
    want = SKY * np.stack([conductor_fresnel(cos[inside], e, k) for e, k in zip(ETA, K, strict=True)], -1)
    ref = case.reference.mean[inside]
    # camera → delta reflection → the constant sky: every path is the same, the reference is exact
    assert np.abs(ref / want - 1).max() < 2e-4  # measured 1.0e-6 (float32 cos θ)
    rows = r.outcomes[case.id]
    assert set(rows) == {"classic", "parallax", "iterative"}  # no glossy map for a smooth conductor
    for row in rows.values():  # a constant map: every lookup is L, the weight Mitsuba's Fresnel
        assert np.abs(row.image[inside] / want - 1).max() < 2e-4, row.row  # measured 1.0e-6
    assert case.parameters["probe"] == pytest.approx(CENTRE.tolist(), abs=1e-6)
    assert case.parameters["texels_missing_the_scene"] == 6 * case.parameters["resolution"] ** 2


@pytest.mark.parametrize("bsdf", ["dielectric", "thindielectric"])
def test_glass_under_a_constant_sky_is_the_sky(tmp_path, bsdf):
    """White furnace: a non-absorbing glass sphere alone under a constant sky L shows L at every pixel (a
    path leaves with weight 1, except where Russian roulette from depth 5 reweights a long path inside: the
    reference's noise there), and so does every row: F·L + (1 − F)·L."""
    ball = f"""<shape type="sphere"><point name="center" x="0" y="0" z="1"/>
        <float name="radius" value="{RADIUS}"/><bsdf type="{bsdf}"/></shape>"""
    (tmp_path / "g.xml").write_text(_scene(ball, 12))
    r = audit(tmp_path / "g.xml", "environment-maps", spp=8, pass_spp=4, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    m = case.mask
    err = np.abs(case.reference.mean[m] - SKY)
    assert np.all(err <= 5 * case.reference.stderr[m] + 1e-4 * SKY)  # measured 2.6e-8 where se = 0, |z| ≤ 1.3
    for row in r.outcomes[case.id].values():
        assert np.abs(row.image[m] / SKY - 1).max() < 1e-4, row.row  # measured 6e-8


def test_a_floor_a_glass_and_a_rough_shape(tmp_path):
    """Glass and a rough conductor beside a mirror on a floor: each shape is a case with its rows, all finite;
    on the rough conductor the glossy pre-filtered map is far closer than the unfiltered lookups."""
    glass = """<shape type="sphere"><point name="center" x="-1.0" y="-1.5" z="0.4"/>
        <float name="radius" value="0.35"/><bsdf type="dielectric"/></shape>
        <shape type="sphere"><point name="center" x="1.0" y="-1.5" z="0.4"/>
        <float name="radius" value="0.35"/>
        <bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf></shape>"""
    (tmp_path / "f.xml").write_text(_scene(MIRROR + FLOOR + glass, 24).replace('value="20"', 'value="36"'))
    info = inspect_scene(tmp_path / "f.xml")
    found = [a for a in applicable_families(info) if a.family == "environment-maps"]
    assert [(a.role, a.part.split(" (")[0]) for a in found] == [
        ("reflections", "mirror sphere 'ball'"),
        ("reflections", "glass sphere"),
        ("glossy reflections", "rough conductor sphere"),
    ]
    assert found[2].methods == tuple(METHOD_TABLES["environment-maps"])
    r = audit(tmp_path / "f.xml", "environment-maps", spp=16, pass_spp=8, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    by = {c.parameters["bsdf"]: c for c in r.cases}
    assert set(by) == {"conductor", "dielectric", "roughconductor"}
    for case in r.cases:
        for row in r.outcomes[case.id].values():
            assert np.all(np.isfinite(row.image)), (case.id, row.row)
    rough = by["roughconductor"]
    assert rough.parameters["alpha"] == pytest.approx(0.2)
    rows = r.outcomes[rough.id]
    assert set(rows) == set(METHOD_TABLES["environment-maps"])
    # measured (24², 16 spp): rel. MSE 0.65 unfiltered (classic), 0.15 pre-filtered
    assert rows["preconvolved"].metrics["rel_mse"].value < 0.5 * rows["classic"].metrics["rel_mse"].value
    glass_ref = by["dielectric"].reference.mean[by["dielectric"].mask]
    assert np.all(glass_ref > 0)


TOML = """
name = "mirror on a floor"

[camera]
origin = [0, -6, 1]
target = [0, 0, 1]
fov_deg = 30
width = 16
height = 16

[[lights]]
type = "constant_env"
radiance = [0.8, 0.9, 1.0]

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [8, 8]

[[shapes]]
type = "mitsuba_xml"
file = "ball.xml"
"""


def test_a_toml_scene_with_a_mirror_from_an_xml_shape(tmp_path):
    (tmp_path / "ball.xml").write_text(f'<scene version="3.0.0">{MIRROR}</scene>')
    (tmp_path / "s.toml").write_text(TOML)
    info = inspect_scene(tmp_path / "s.toml")
    found = [a for a in applicable_families(info) if a.family == "environment-maps"]
    assert [a.part for a in found] == ["mirror shape (shapes[1], xml1_0: conductor)"]
    lines = describe(info, applicable_families(info))
    assert any(line.startswith("  environment-maps — reflections: mirror shape") for line in lines)
    r = audit(tmp_path / "s.toml", "environment-maps", spp=16, pass_spp=8, fit=False, probe_at=(0, 0, 1.2),
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["probe"] == [0.0, 0.0, 1.2]
    assert case.parameters["probe_from"] == "--probe-at"
    rows = r.outcomes[case.id]
    assert set(rows) == {"classic", "parallax", "iterative"}
    for row in rows.values():
        assert np.all(np.isfinite(row.image))
    # beside the floor the probe sees geometry at a finite distance: the distance impostors correct the
    # parallax the classic lookup ignores
    # (measured at 16², 16 spp: relative MSE classic 0.029, one lookup 0.022, secant 0.020, noise floor 0.003)
    mse = {k: rows[k].metrics["rel_mse"] for k in rows}
    for k in ("parallax", "iterative"):
        assert mse[k].value < mse["classic"].value - mse["classic"].noise_floor, k


def test_probe_at_and_grid_are_checked_before_anything_runs(tmp_path):
    (tmp_path / "m.xml").write_text(_scene(MIRROR))
    for option, value in (("--probe-at", "1,2"), ("--probe-at", "1,2,nan"), ("--grid", "4,4,0"),
                          ("--grid", "4,4,2.5"), ("--grid", "a,b,c")):  # fmt: skip
        out = tmp_path / "out"
        argv = [str(tmp_path / "m.xml"), option, value, "--out", str(out)]
        result = CliRunner().invoke(audit_command, argv)
        assert result.exit_code == 2, (option, value)
        assert result.stderr.startswith(f"rtfit: error: {option} ") and result.stderr.count("\n") == 1
        assert not out.exists()
    listing = CliRunner().invoke(audit_command, [str(tmp_path / "m.xml"), "--list"])
    assert listing.exit_code == 0
    assert "environment-maps — reflections: mirror sphere 'ball'" in listing.stdout
    assert "environment-maps, not here: preconvolved, preconvolved-parallax (needs glossy_b" in listing.stdout
    json.dumps(listing.stdout)


def test_the_rows_run_one_text_on_drjit_numpy_and_jax():
    """Every row's kernel gives the same (R, G, B) on NumPy, Dr.Jit (LLVM, float64) and JAX on random cube
    maps and pixels; with constant maps every row is w_r·L + w_t·L + w_d·E/π (closed form)."""
    import jax
    import jax.numpy as jnp

    from rtfit.realtime import DRJIT_OPS, NUMPY_OPS, jax_ops
    from rtfit.realtime.arrays import backend_float
    from rtfit.realtime.reflections import GLOSSY_RESOLUTION, IRRADIANCE_RESOLUTION, PROBE_RESOLUTION

    jax.config.update("jax_enable_x64", True)
    Float = backend_float("llvm", np.float64)
    rng = np.random.default_rng(3)
    n = 257

    def unit(m):
        v = rng.normal(size=(m, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    inputs = {}
    for name, v in (("", rng.uniform(-0.5, 0.5, (n, 3))), ("r", unit(n)), ("t", unit(n)), ("n", unit(n))):
        inputs.update({f"{name}{c}" if name else c: v[:, k] for k, c in enumerate("xyz")})
    for w in ("wr", "wt", "wd"):
        inputs.update({f"{w}_{c}": rng.uniform(0, 1, n) for c in "rgb"})
    sizes = (("rad", PROBE_RESOLUTION), ("glossy", GLOSSY_RESOLUTION), ("irr", IRRADIANCE_RESOLUTION))
    for table, res in sizes:
        inputs.update({f"{table}_{c}": rng.uniform(0.1, 2.0, 6 * res * res) for c in "rgb"})
    inputs["dist"] = rng.uniform(1.0, 3.0, 6 * PROBE_RESOLUTION**2)
    const = {**inputs, **{k: np.full_like(v, 0.7) for k, v in inputs.items() if k[:3] in ("rad", "glo")}}
    const.update({f"irr_{c}": np.full_like(inputs["irr_r"], 2.0) for c in "rgb"})
    for method in METHOD_TABLES["environment-maps"].values():
        mine = {k: inputs[k] for k in method.input_names}
        ref = method(NUMPY_OPS, mine)
        dr_out = method(DRJIT_OPS, {k: Float(v) for k, v in mine.items()})
        jx = method(jax_ops(), {k: jnp.asarray(v) for k, v in mine.items()})
        for a, b, c in zip(ref, dr_out, jx, strict=True):
            assert np.allclose(np.asarray(b, np.float64), a, rtol=1e-9, atol=1e-12), method.id
            assert np.allclose(np.asarray(c), a, rtol=1e-9, atol=1e-12), method.id
        flat = method(NUMPY_OPS, {k: const[k] for k in method.input_names})
        for ch, out in zip("rgb", flat, strict=True):
            want = (const[f"wr_{ch}"] + const[f"wt_{ch}"]) * 0.7 + const[f"wd_{ch}"] * 2.0 / math.pi
            assert np.allclose(out, want, rtol=1e-12), method.id


def test_a_medium_boundary_is_not_a_glass_object(tmp_path):
    """A thin-dielectric shell holding a homogeneous medium is the medium's container (issue 31): only the
    mirror is listed, and the ordinals of the listing and the loaded scene agree (the audit runs it)."""
    shell = """<medium type="homogeneous" id="fog"><float name="sigma_t" value="1"/></medium>
        <shape type="sphere"><point name="center" x="-1.5" y="0" z="1"/><float name="radius" value="0.5"/>
        <bsdf type="thindielectric"/><ref name="interior" id="fog"/></shape>"""
    (tmp_path / "s.xml").write_text(_scene(shell + MIRROR, 8))
    found = [
        a for a in applicable_families(inspect_scene(tmp_path / "s.xml")) if a.family == "environment-maps"
    ]
    assert [a.part.split(" (")[0] for a in found] == ["mirror sphere 'ball'"]
    r = audit(tmp_path / "s.xml", "environment-maps", spp=2, pass_spp=2, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    assert [c.parameters["bsdf"] for c in r.cases] == ["conductor"]


def test_filtered_maps_keep_the_lobes_energy():
    """The irradiance and glossy maps are normalised by the lobe's own discrete sum: a constant map L gives
    πL and L exactly at any exponent, even one far narrower than a texel (s = 10⁴, α ≈ 0.01)."""
    from rtfit.experiments.audit_environment_maps import filtered_tables, phong_exponent
    from rtfit.realtime.reflections import PROBE_RESOLUTION

    rad = np.tile(SKY, (6 * PROBE_RESOLUTION**2, 1))
    for s, integral in ((0.0, math.pi), (phong_exponent(0.2), 1.0), (phong_exponent(0.01), 1.0)):
        maps = filtered_tables("m", rad, 4, s)
        for k, c in enumerate("rgb"):
            assert np.allclose(maps[f"m_{c}"], integral * SKY[k], rtol=1e-9), (s, c)
    assert phong_exponent(0.2) == pytest.approx(12.0) and phong_exponent(0.001) == 1e4


def my_classic(ops, g):
    """The classic environment map typed through ops: w_r·L(R) + w_t·L(T) + w_d·E(n)/π per channel, each map
    read with the family's cube lookup (bilinear within a face)."""
    from rtfit.realtime.environment_maps import cube_lookup_kernel

    out = []
    for c in "rgb":
        rad, irr = getattr(g, f"rad_{c}"), getattr(g, f"irr_{c}")
        lr = cube_lookup_kernel(ops, rad, g.rx, g.ry, g.rz, g.resolution, True)
        lt = cube_lookup_kernel(ops, rad, g.tx, g.ty, g.tz, g.resolution, True)
        e = cube_lookup_kernel(ops, irr, g.nx, g.ny, g.nz, g.irr_resolution, True)
        out.append(
            getattr(g, f"wr_{c}") * lr + getattr(g, f"wt_{c}") * lt + getattr(g, f"wd_{c}") * e / math.pi
        )
    return tuple(out)


def test_a_user_reflection_reads_the_rows_own_maps(tmp_path):
    """A user's ``@approximation(quantity="reflected_radiance")`` restating the classic row's shading gives
    the shipped ``classic`` row's values on a mirror sphere over a floor (the same lobes, radiance,
    irradiance and distance maps and resolutions through ``g``: measured max difference 0, the red channel
    spanning 0.55 between floor and sky); one that takes a square root of R_z (NaN below the horizon) is
    refused in one line before anything renders."""
    from rtfit.experiments.audit import AuditError
    from rtfit.realtime.quantities import approximation

    mine = approximation(quantity="reflected_radiance")(my_classic)
    (tmp_path / "m.xml").write_text(_scene(MIRROR + FLOOR))
    r = audit(tmp_path / "m.xml", ["environment-maps:classic", mine], spp=8, pass_spp=4, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    m = case.mask
    rows = r.outcomes[case.id]
    assert set(rows) == {"classic", "my_classic"} and rows["my_classic"].user
    np.testing.assert_allclose(rows["my_classic"].image[m], rows["classic"].image[m], rtol=1e-12, atol=1e-12)
    assert np.ptp(rows["classic"].image[m][:, 0]) > 0.05  # the floor and the sky: a map that varies

    @approximation(quantity="reflected_radiance")
    def root_rz(ops, g):
        v = ops.sqrt(g.rz) * g.wr_r
        return v, v, v

    with pytest.raises(AuditError) as e:
        audit(tmp_path / "m.xml", [root_rz], spp=2, pass_spp=2, cache=tmp_path / "c2", **FAST)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("root_rz: returned NaN at rz=")
