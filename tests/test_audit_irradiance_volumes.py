"""The ``irradiance-volumes`` family of `rtfit audit` (`rtfit.experiments.audit_irradiance_volumes`): a probe
grid over a user's scene, looked up at the visible points, against path-traced irradiance there.

Scenes are written here and tiny (16 × 16 pixels, ≤ 32 spp). The independent check: a diffuse floor under a
constant sky L, with only a tiny black sphere (radius 0.05, out of view, 2 above the floor: it gives the
scene's box its height) — every floor point receives E = πL(1 − sin²α·cos θ) from the sky minus that sphere
(α its angular radius, θ its angle from the normal: the closed form of a sphere wholly above the horizon),
within 6·10⁻⁴ of πL; and every probe's ambient-cube entry along +z is the irradiance of its upper hemisphere,
the same sky (the floor lies below), so the Valve-cube rows at the floor's upward normals are πL up to the
probes' noise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from rtfit.experiments.applicability import applicable_families
from rtfit.experiments.audit import inspect_scene
from rtfit.experiments.audit_cli import audit as audit_command
from rtfit.experiments.audit_irradiance_volumes import probe_grid
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import METHOD_TABLES
from rtfit.realtime.irradiance_bases import CUBE_AXES

FAST = {"cost_elements": 1 << 10, "metrics": ("rmse", "rel_mse", "mae", "max_abs")}
SKY = np.array([0.8, 0.9, 1.0])

FLOOR_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -3, 4" target="0, 0, 0" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1.0"/></emitter>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.4, 0.3"/></bsdf></shape>
    <shape type="sphere"><point name="center" x="2.9" y="2.9" z="2"/><float name="radius" value="0.05"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf></shape>
</scene>
"""


def test_probe_grid_is_centred_in_the_box_with_cubic_cells():
    g = probe_grid((-3, -3, 0), (3, 3, 2.05))
    assert g.dims == (4, 4, 1) and g.spacing == pytest.approx(1.5)
    assert np.allclose(g.positions()[:, 0].min(), -2.25) and np.allclose(g.positions()[:, 2], 1.025)
    g = probe_grid((0, 0, 0), (4, 2, 1), (2, 2, 2))  # h = max(4/2, 2/2, 1/2) = 2: centred, x-cells fill
    assert g.spacing == 2.0 and np.allclose(g.origin, (1.0, 0.0, -0.5))


def test_floor_under_a_constant_sky(tmp_path):
    (tmp_path / "f.xml").write_text(FLOOR_XML)
    info = inspect_scene(tmp_path / "f.xml")
    (app,) = [a for a in applicable_families(info) if a.family == "irradiance-volumes"]
    assert app.methods == tuple(METHOD_TABLES["irradiance-volumes"])
    assert app.part.startswith("a probe grid over the scene's box (-3, -3, 0)–(3, 3, 2.05)")
    r = audit(tmp_path / "f.xml", "irradiance-volumes", spp=32, pass_spp=16, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["grid_dims"] == [4, 4, 1] and case.parameters["probe_spp"] == 64 * 32
    m = case.mask
    ref, se = case.reference.mean[m], case.reference.stderr[m]
    want = math.pi * SKY
    # the closed form within 6e-4 of πL (the tiny sphere's shadow), at the reference's noise
    assert np.all(np.abs(ref - want) <= 5 * se + 1e-3 * want)  # measured max |z| 0 (no ray met the sphere)
    rows = r.outcomes[case.id]  # no delta light: the one (bounced) case, the volume rows alone
    assert [c.id for c in r.cases] == ["volume"]
    assert set(rows) == {m for m in METHOD_TABLES["irradiance-volumes"] if not m.startswith("direct-")}
    for row in rows.values():
        assert np.all(np.isfinite(row.image[m])), row.row
    # Valve's cube at the floor's upward normal reads each probe's +z entry: the sky's πL, probe noise
    # ≈ 1.29/√2048 = 2.9 % per probe (4π·max(ω_z, 0)·L over uniform directions)
    for row in ("nearest-cube-valve", "trilinear-cube-valve"):
        v = rows[row].image[m] / want
        assert abs(np.mean(v) - 1) < 0.03 and np.all(np.abs(v - 1) < 0.12), (
            row
        )  # measured mean +1.5 %, +1.1 %, max 6.6 %


TOML = """
name = "sphere on a floor"

[camera]
origin = [0, -6, 3]
target = [0, 0, 0.5]
fov_deg = 35
width = 16
height = 16

[[lights]]
type = "constant_env"
radiance = [0.8, 0.9, 1.0]

[[shapes]]
type = "rectangle"
center = [0, 0, 0]
normal = [0, 0, 1]
size = [6, 6]

[[shapes]]
type = "sphere"
center = [0, 0, 1]
radius = 0.8
"""


def test_a_toml_scene_with_its_own_grid(tmp_path):
    (tmp_path / "s.toml").write_text(TOML)
    listing = CliRunner().invoke(audit_command, [str(tmp_path / "s.toml"), "--list"])
    assert listing.exit_code == 0
    assert "irradiance-volumes — probe grid: a probe grid over the scene's box" in listing.stdout
    r = audit(tmp_path / "s.toml", "irradiance-volumes", spp=16, pass_spp=8, fit=False, grid="4,4,2",
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["grid_dims"] == [4, 4, 2] and case.parameters["grid_from"] == "--grid"
    rows = r.outcomes[case.id]
    for row in rows.values():
        assert np.all(np.isfinite(row.image))
    # the floor under the sphere is shadowed, the sphere's top is not: every row sees the contrast, the
    # trilinear rows blur it less than a constant would (relative MSE below that of the mean irradiance)
    m = case.mask
    ref = case.reference.mean[m]
    flat = np.mean((ref.mean(0) - ref) ** 2 / np.maximum(ref, 1e-6) ** 2)
    good = rows["trilinear-sh-l2"].metrics["rel_mse"].value
    assert good < flat  # measured 0.035 against 0.052
    # a grid whose cells do not fit the box: h = 2, nodes at z = −0.1 (under the floor, seeing its black
    # back) and 1.9: every probe outside the box, the light leaks (measured relative MSE 0.71)
    r = audit(tmp_path / "s.toml", "irradiance-volumes", spp=16, pass_spp=8, fit=False, grid=(3, 3, 2),
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    assert case.parameters["probes_outside_the_box"] == 18
    assert r.outcomes[case.id]["trilinear-sh-l2"].metrics["rel_mse"].value > 5 * good


def _trilinear(ops, g, table, floats):
    """The probes' ``floats`` stored floats blended trilinearly at g.point (typed here: i₀ = clamp(⌊t⌋, 0,
    n − 2), f = clamp(t − i₀, 0, 1) per axis, an axis of one node weight 1 on it)."""
    grid = g.grid
    axes = []
    for x, o, n in zip(g.point, grid.origin, grid.dims, strict=True):
        if n == 1:
            axes.append([(0.0 * x, 1.0 + 0.0 * x)])
            continue
        t = (x - o) / grid.spacing
        i0 = ops.minimum(ops.maximum(ops.floor(t), 0.0), n - 2.0)
        f = ops.minimum(ops.maximum(t - i0, 0.0), 1.0)
        axes.append([(i0, 1.0 - f), (i0 + 1.0, f)])
    nx, ny, _ = grid.dims
    corners = [
        ((k * ny + j) * nx + i, wk * wj * wi) for k, wk in axes[2] for j, wj in axes[1] for i, wi in axes[0]
    ]
    out = []
    for s in range(floats):
        acc = 0.0
        for node, w in corners:
            acc = acc + w * ops.gather(table, node + float(grid.count * s))
        out.append(acc)
    return out


def my_trilinear_cube(ops, g):
    """Valve's cube blended trilinearly, typed through ops: Σ n_i² C[sign of n_i] per channel."""
    c = _trilinear(ops, g, g.cube_table, 18)
    n = ops.sqrt(g.nx * g.nx + g.ny * g.ny + g.nz * g.nz)
    x, y, z = g.nx / n, g.ny / n, g.nz / n
    return tuple(
        x * x * ops.select(x < 0.0, c[6 * ch + 1], c[6 * ch])
        + y * y * ops.select(y < 0.0, c[6 * ch + 3], c[6 * ch + 2])
        + z * z * ops.select(z < 0.0, c[6 * ch + 5], c[6 * ch + 4])
        for ch in range(3)
    )


def test_a_user_volume_reads_the_rows_own_probes(tmp_path):
    """A user's ``@approximation(quantity="volume_irradiance")`` restating the trilinear Valve-cube lookup
    gives the shipped row's values on the floor (the same points, normals, grid and cube table: measured max
    difference 0), and so does a user row reading the SH L2 table, with the shipped basis text, as
    ``nearest-sh-l2``; both inside the closed form's band of the floor test. A user row that gathers outside
    the table is refused in one line before anything renders."""
    from rtfit.experiments.audit import AuditError
    from rtfit.realtime.irradiance_bases import METHODS as BASES
    from rtfit.realtime.quantities import approximation

    cube = approximation(quantity="volume_irradiance")(my_trilinear_cube)

    @approximation(quantity="volume_irradiance")
    def my_nearest_sh(ops, g):
        """The nearest probe's SH L2 (node clamp(⌊t + ½⌋)), evaluated with the shipped basis text."""
        grid, idx = g.grid, []
        for x, o, n in zip(g.point, grid.origin, grid.dims, strict=True):
            idx.append(ops.minimum(ops.maximum(ops.floor((x - o) / grid.spacing + 0.5), 0.0), n - 1.0))
        node = (idx[2] * grid.dims[1] + idx[1]) * grid.dims[0] + idx[0]
        coeffs = [ops.gather(g.table, node + float(grid.count * s)) for s in range(27)]
        return BASES["sh-l2"](ops, {"nx": g.nx, "ny": g.ny, "nz": g.nz, "coeffs": coeffs})

    (tmp_path / "f.xml").write_text(FLOOR_XML)
    shipped = ["irradiance-volumes:trilinear-cube-valve", "irradiance-volumes:nearest-sh-l2"]
    r = audit(tmp_path / "f.xml", [*shipped, cube, my_nearest_sh], spp=32, pass_spp=16, fit=False,
              cache=tmp_path / "cache", **FAST)  # fmt: skip
    (case,) = r.cases
    m = case.mask
    rows = r.outcomes[case.id]
    assert set(rows) == {"trilinear-cube-valve", "nearest-sh-l2", "my_trilinear_cube", "my_nearest_sh"}
    for mine, shipped in (("my_trilinear_cube", "trilinear-cube-valve"), ("my_nearest_sh", "nearest-sh-l2")):
        assert rows[mine].user and not rows[shipped].user
        np.testing.assert_allclose(rows[mine].image[m], rows[shipped].image[m], rtol=1e-12, atol=1e-12)
    v = rows["my_trilinear_cube"].image[m] / (math.pi * SKY)
    assert abs(np.mean(v) - 1) < 0.03 and np.all(np.abs(v - 1) < 0.12)

    @approximation(quantity="volume_irradiance")
    def past_the_end(ops, g):
        return tuple(ops.gather(g.table, 0.0 * g.px + float(27 * g.grid.count + c)) for c in range(3))

    with pytest.raises(AuditError) as e:
        audit(tmp_path / "f.xml", [past_the_end], spp=4, pass_spp=4, cache=tmp_path / "cache2", **FAST)
    assert "\n" not in str(e.value) and str(e.value).startswith("past_the_end: raised IndexError")


def test_study_popping_against_the_closed_form_of_probes_scaled_along_x():
    """Three probes along x (h = 1 m) holding the same light scaled 1, 2, 3: the irradiance at node k is
    (k + 1)·E₀ for every basis and normal, so the nearest lookup jumps by |2 − 1|/1.5 = 2/3 (first boundary)
    and 1/2.5 (second) of the mean there, the largest 2/3; the trilinear lookup is continuous (~ε)."""
    from rtfit.experiments.irradiance_volumes_study import COEFFICIENTS, popping
    from rtfit.realtime.irradiance_volumes import ProbeGrid, probe_table

    rng = np.random.default_rng(1)
    grid = ProbeGrid((0.0, 0.0, 0.0), 1.0, (3, 1, 1))
    tables = {}
    for basis, k in COEFFICIENTS.items():
        base = rng.uniform(0.5, 1.0, (1, k, 3))
        if basis == "sh-l2":  # a dominant DC term: a positive irradiance for every normal
            base[:, 1:] *= 0.1
        tables[basis] = probe_table(base * np.array([1.0, 2.0, 3.0])[:, None, None])
    steps = popping(grid, tables)
    for mid, step in steps.items():
        if mid.startswith("nearest"):
            assert step == pytest.approx(2.0 / 3.0, rel=1e-4)
        else:
            assert step < 1e-3


def _blocked(points, light, lo, hi):
    """Whether the open segment from each point to ``light`` crosses the box [lo, hi] (dense sampling)."""
    t = np.linspace(1e-3, 1.0 - 1e-3, 4001)[None, :, None]
    seg = points[:, None, :] + t * (np.asarray(light)[None, None, :] - points[:, None, :])
    return np.any(np.all((seg >= lo) & (seg <= hi), axis=2), axis=1)


def test_run_is_the_engine_on_the_shipped_room_plus_the_study(tmp_path):
    """``rtfit run irradiance-volumes`` = the engine's audits of scenes/library/volume_room.toml, one probe
    grid per shipped scene, + `irradiance_volumes_study.study`. Independent values: the room's box is 4 m on
    every side (grid 2×2×2: spacing 2 m, 8 probes); storage 3 × 6 and 3 × 9 floats per probe, a table of
    4 bytes × floats × probes. The room's point light (20 W/sr at (−1, 0.1, 1.6)) makes a second case, the
    total irradiance: its reference is the bounced one plus I·max(n·d, 0)/r² where the segment to the light
    misses the occluder box (x ∈ [−0.35, −0.2], |y| ≤ 1, z ≤ 1.2: sampled densely here); each ``direct-…``
    row is its volume row plus that, so its RMSE equals the bounced case's row's. The study's checks pass
    (white furnace, constant volume, direct light, two estimators, lookups at the nodes, continuity)."""
    from rtfit.experiments import audit_irradiance_volumes as decl
    from rtfit.experiments import irradiance_volumes_study as study
    from rtfit.experiments.families import ENGINE, FAMILIES
    from rtfit.experiments.shipped import StudyContext
    from rtfit.scenes import library_path

    fam = FAMILIES["irradiance-volumes"]
    assert fam.module == ENGINE and fam.scenes == decl.SCENES and fam.study.target is study.study
    assert [s.options["grid"] for s in fam.scenes] == [(2, 2, 2), (4, 4, 4), (8, 8, 8)]
    assert {s.name for s in fam.scenes if s.quick} == {"volume_room-h2", "volume_room-h0p5"}
    shipped = fam.scenes[0]
    r = audit(library_path("volume_room"), "irradiance-volumes", spp=4, pass_spp=4, width=8, height=8,
              fit=False, grid=shipped.options["grid"], cache=tmp_path / "cache", **FAST)  # fmt: skip
    case, total = r.cases
    assert case.parameters["grid_spacing"] == pytest.approx(2.0) and case.parameters["probes"] == 8
    assert total.id == decl.TOTAL_CASE and total.parameters["delta_lights"] == 1
    m = case.mask
    g = case.channel_inputs[0]
    p = np.stack([g["px"], g["py"], g["pz"]], 1).astype(np.float64)
    n = np.stack([g["nx"], g["ny"], g["nz"]], 1).astype(np.float64)
    q = np.array([-1.0, 0.1, 1.6])
    v = q - p
    r2 = np.sum(v * v, axis=1)
    closed = 20.0 * np.maximum(np.sum(n * v, axis=1), 0.0) / r2 / np.sqrt(r2)
    closed *= ~_blocked(p, q, np.array([-0.35, -1.0, 0.0]), np.array([-0.2, 1.0, 1.2]))
    got = total.reference.mean[m] - case.reference.mean[m]
    assert np.max(np.abs(got - closed[:, None]) / (closed.max() + 1e-30)) < 1e-4
    assert np.allclose(total.reference.stderr, case.reference.stderr)
    rows = r.outcomes[total.id]
    assert set(rows) == set(METHOD_TABLES["irradiance-volumes"])
    for mid in decl.METHODS:
        plus = r.outcomes["volume"][mid].image[m] + closed[:, None]
        assert np.allclose(rows[f"direct-{mid}"].image[m], plus, rtol=1e-5, atol=1e-4)
        assert rows[f"direct-{mid}"].metrics["rmse"].value == pytest.approx(
            r.outcomes["volume"][mid].metrics["rmse"].value, rel=1e-5
        )
    res = study.study(StudyContext(tmp_path, True, "llvm_ad_rgb", 0, tmp_path / "cache", (r,)))
    assert all(c.passed for c in res.checks), [c.name for c in res.checks if not c.passed]
    names = " ".join(c.name for c in res.checks)
    for old in ("white furnace", "constant environment", "direct light", "surface estimator", "own probe",
                "resolved"):  # fmt: skip
        assert old in names
    rows = {x["row"]: x for x in res.extra["per_spacing"]}
    assert rows["trilinear-sh-l2"]["table_bytes"] == 4 * 27 * 8
    assert rows["nearest-cube-valve"]["table_bytes"] == 4 * 18 * 8
    assert rows["nearest-sh-l2"]["popping_max_step"] > rows["trilinear-sh-l2"]["popping_max_step"]
    split = {x["row"]: x for x in res.extra["folded_vs_direct"]}
    assert split["trilinear-sh-l2"]["direct_rmse"] == pytest.approx(r.outcomes["volume"]["trilinear-sh-l2"]
                                                                   .metrics["rmse"].value)  # fmt: skip
    leak = res.extra["group_smape"]
    assert {x["case"] for x in leak} == {"bounced", "total"} and "floor" in leak[0]["pixels"]
    assert sum(leak[0]["pixels"].values()) <= int(m.sum())


def test_surface_groups_of_the_room():
    """Points placed on each surface of the room (independent positions and normals) land in their group."""
    from rtfit.experiments.irradiance_volumes_study import surface_groups
    from rtfit.scenes import library_path, load_scene

    pts = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 2.5], [-2.0, 0.3, 1.0], [2.0, 0.3, 1.0], [0.1, -2.0, 1.0],
                    [0.1, 2.0, 1.0], [-0.35, 0.0, 0.6], [-0.2, 0.0, 0.6], [-0.3, 0.0, 1.2]])  # fmt: skip
    nrm = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [-1, 0, 0],
                    [1, 0, 0], [0, 0, 1]], np.float64)  # fmt: skip
    groups = surface_groups(load_scene(library_path("volume_room")), pts, nrm)
    want = ["floor", "ceiling", "red −x wall", "green +x wall", "−y wall", "+y wall", "occluder, lit −x face",
            "occluder, shadow +x face", "occluder, other faces"]  # fmt: skip
    for i, name in enumerate(want):
        assert np.flatnonzero(groups[name]).tolist() == [i], name


def test_delta_lights_against_their_closed_form():
    """A point light I = (2, 3, 4) W/sr at (0, 0, 2) and a directional light of irradiance (1, 1, 1) W/m²
    shining down (−z), a 0.4 × 0.4 m square at z = 1 above the origin: at (1, 0, 0) E⊥ = I/5 from
    d = (−1, 0, 2)/√5 and 1 from +z; at the origin both are blocked by the square. Folded into a probe, the
    cube's +z entry is E⊥·d_z summed over the lights (`fold_directional`)."""
    import mitsuba as mi

    from rtfit.realtime.irradiance_volumes import fold_directional
    from rtfit.reference.probe_radiance import delta_light_irradiance

    mi.set_variant("llvm_ad_rgb")
    rgb = {"type": "rgb", "value": [2.0, 3.0, 4.0]}
    scene = mi.load_dict({
        "type": "scene",
        "point": {"type": "point", "position": [0.0, 0.0, 2.0], "intensity": rgb},
        "sun": {"type": "directional", "direction": [0, 0, -1.0], "irradiance": {"type": "rgb", "value": 1}},
        "square": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 1]).scale(0.2)},
    })  # fmt: skip
    pts = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    for normals in (None, np.array([[0.0, 0.0, 1.0]] * 2)):
        (dp, ep), (ds, es) = delta_light_irradiance(mi, scene, pts, normals)
        assert np.allclose(dp[0], np.array([-1.0, 0.0, 2.0]) / math.sqrt(5.0), atol=1e-6)
        assert np.allclose(ep[0], np.array([2.0, 3.0, 4.0]) / 5.0, rtol=1e-5)
        assert np.allclose(ds[0], [0.0, 0.0, 1.0], atol=1e-6) and np.allclose(es[0], 1.0, rtol=1e-6)
        assert not ep[1].any() and not es[1].any()
    _, cube = fold_directional(np.concatenate([dp, ds]), np.concatenate([ep, es]))
    up = list(CUBE_AXES).index((0.0, 0.0, 1.0))
    assert np.allclose(cube[0, up], ep[0] * 2.0 / math.sqrt(5.0), rtol=1e-5)
    assert np.allclose(cube[2, up], 1.0) and not cube[1].any() and not cube[3].any()


def test_exact_direct_plus_a_constant_volume():
    """``direct-<row>`` = the exact direct light + the row's lookup: identical probes of a constant
    environment (π in every cube entry, SH of L = 1) give π + E_direct at any point and normal."""
    from rtfit.realtime import NUMPY_OPS
    from rtfit.realtime.irradiance_bases import sh9_from_constant
    from rtfit.realtime.irradiance_volumes import METHODS, SPLIT_METHODS, ProbeGrid, probe_table

    grid = ProbeGrid((0.0, 0.0, 0.0), 0.5, (3, 2, 2))
    rng = np.random.default_rng(2)
    p, n = rng.uniform(-1.0, 2.0, (50, 3)), rng.normal(size=(50, 3))
    direct = rng.uniform(0.0, 5.0, (50, 3))
    tables = {"sh-l2": probe_table(np.tile(sh9_from_constant(1.0)[None], (grid.count, 1, 1))),
              "cube-valve": probe_table(np.full((grid.count, 6, 3), math.pi))}  # fmt: skip
    tables["cube-nnls"] = tables["cube-valve"]
    assert set(SPLIT_METHODS) == {f"direct-{m}" for m in METHODS}
    for mid, m in SPLIT_METHODS.items():
        inputs = {f"p{c}": p[:, j] for j, c in enumerate("xyz")}
        inputs.update({f"n{c}": n[:, j] for j, c in enumerate("xyz")})
        inputs.update({f"direct_{c}": direct[:, j] for j, c in enumerate("rgb")})
        inputs.update(table=tables[METHODS[mid.removeprefix("direct-")].fixed["basis"].id], grid=grid)
        got = np.stack(m(NUMPY_OPS, inputs), axis=-1)
        assert np.allclose(got, direct + math.pi, rtol=1e-12), mid
