"""Occluded sky light in `rtfit audit` (issue 15 §2: "an environment → … occluded sky light → SDF skylight /
AO and ambient aperture on the scene's own geometry"): the sky-occlusion role of ``sdf-occlusion`` and the
aperture-fill role of ``ambient-aperture`` (`rtfit.experiments.audit_sky_occlusion`).

Oracle (independent of the code): a constant environment of radiance L over a floor (z = 0) beside a wall of
height h (the plane y = 0, 200 long, so infinite for points within 2 of it). A floor point at distance d
from the wall sees the sky except the wall; in the cross-section the wall spans the angles from the
horizon up to θ with tan θ = d/h from the normal, so the wall's view factor is ½(1 − sin θ) and

    E(d) = π L (1 − ½(1 − d/√(d² + h²))) = ½ π L (1 + d/√(d² + h²)),

the cosine-weighted visibility V(d) = E/(πL). (The wall's ends, ≥ 100 away, change it by < 10⁻⁴
relative.) A floor point far from everything sees the whole sky: E = πL, V = 1, bent normal n, aperture π/2,
where the projected-cap fill is exact (πL) and the seed fill reads A(π/2)·L = 2πL (its missing cosine)."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest
from click.testing import CliRunner

from rtfit import Param, approximation
from rtfit.experiments.audit_cli import audit as audit_cmd
from rtfit.experiments.audit_run import audit
from rtfit.experiments.families import AUDITED
from rtfit.reference.light_irradiance import environment_irradiance_pass
from rtfit.reference.occlusion import visibility_cap_pass
from rtfit.reference.variants import scoped_variant

H = 1.0
L = (0.5, 1.0, 2.0)
WALL = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="20"/>
    <transform name="to_world">
      <lookat origin="0, {cy}, 6" target="0, {cy}, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="10"/><integer name="height" value="10"/></film>
  </sensor>
  <shape type="rectangle" id="floor"><transform name="to_world"><scale value="1000"/></transform></shape>
  <shape type="rectangle" id="wall">
    <transform name="to_world"><matrix value="100 0 0 0  0 0 1 0  0 {hh} 0 {hh}  0 0 0 1"/></transform>
  </shape>
  <emitter type="constant"><rgb name="radiance" value="{l0}, {l1}, {l2}"/></emitter>
</scene>
"""


@approximation(quantity="sky_irradiance", params={"s": Param(0.7, lower=0.0, upper=2.0)})
def visible_probe(ops, g, *, s):
    """Probe along the bent normal × visibility, scaled."""
    return s * math.pi * g.sky_radiance * g.visibility


FAST = {"cost_elements": 1 << 12, "metrics": ("rmse", "rel_mse", "mae", "max_abs", "psnr")}


def _wall(tmp_path, cy: float = -1.3):
    text = WALL.format(cy=cy, hh=H / 2, l0=L[0], l1=L[1], l2=L[2])
    path = tmp_path / ("wall.xml" if cy == -1.3 else "open.xml")
    path.write_text(text)
    return path


def _closed_form(d):
    return 0.5 * (1.0 + d / np.sqrt(d * d + H * H))


def test_occluded_sky_pass_and_visibility_bake_match_the_closed_form(tmp_path):
    """At d = 0.05…2 from the wall: the occluded environment pass is ½πL(1 + d/√(d²+h²)) per channel and the
    bake's cosine-weighted visibility its 1/(πL), within 4.5 standard errors (measured max |z| 2.9 over
    8 × 3 + 8 values at 2048 spp); the bent normal leans away from the wall (b_y < 0)."""
    with scoped_variant("llvm_ad_rgb"):
        scene = mi.load_file(str(_wall(tmp_path)))
        env = next(e for e in scene.emitters() if e.is_environment())
        d = np.array([0.05, 0.1, 0.2, 0.35, 0.5, 0.8, 1.2, 2.0])
        points = np.c_[np.zeros_like(d), -d, np.zeros_like(d)]
        normals = np.tile([0.0, 0.0, 1.0], (len(d), 1))
        sky = environment_irradiance_pass(mi, env, normals, 2048, 7, mi_scene=scene, points=points)
        caps = visibility_cap_pass(mi, scene, points, normals, 2048, 8)
    want = _closed_form(d)[:, None] * math.pi * np.asarray(L)[None, :]
    z = np.abs(sky.mean - want) / np.sqrt(sky.var / sky.spp)
    assert z.max() < 4.5, z.max()
    zv = np.abs(caps.mean[:, 1] - _closed_form(d)) / np.sqrt(caps.var[:, 1] / caps.spp)
    assert zv.max() < 4.5, zv.max()
    bent = caps.mean[:, 2:5]
    assert np.all(bent[:, 1] < 0) and np.all(bent[:, 2] > 0)
    # the visible fraction (uniform measure): the wall hides elevations e < atan((h/d) sin φ), φ ∈ (0, π),
    # so V_u = 1 − (1/2π) ∫_0^π sin(atan((h/d) sin φ)) dφ (midpoint rule, 20 000 nodes: converged to 1e-9)
    phi = (np.arange(20000) + 0.5) * math.pi / 20000
    k = H / d[:, None]
    v_u = 1.0 - np.sin(np.arctan(k * np.sin(phi)[None, :])).mean(axis=1) / 2.0
    zu = np.abs(caps.mean[:, 0] - v_u) / np.sqrt(caps.var[:, 0] / caps.spp)
    assert zu.max() < 4.5, zu.max()


@pytest.fixture(scope="module")
def wall_audit(tmp_path_factory):
    """One audit of the wall scene, both roles (and the AO role sdf-occlusion brings) and a user approximation
    of sky_irradiance, with fits (the curvature and Evans rows, whose k the seed leaves open, exist only
    fitted); the distance-field rows restricted to the cheap curvature and Evans rows (the cone's LLVM compile
    and cost take ~10 s a case; `rtfit audit` runs it: docs/audit.md)."""
    d = tmp_path_factory.mktemp("wall")
    return audit(
        _wall(d), ["ambient-aperture", "sdf-occlusion:curvature", "sdf-occlusion:evans-text", visible_probe],
        spp=64, pass_spp=32, ao_distance=0.5, cache=d / "cache", **FAST,
    )  # fmt: skip


def test_sky_cases_rows_and_reference_against_the_closed_form(wall_audit):
    """The sky-occlusion and fill cases share one reference (rendered once, same cache entry); it matches the
    closed form at every floor pixel (d from the G-buffer's own positions is not returned, so the check is
    on the reference's range: between ½πL at the wall and πL far from it, and increasing away from it). The
    distance-field rows (× E_SH(n)) and the fill rows are finite; E_SH(n) of a constant sky is πL."""
    r = wall_audit
    ids = [c.id for c in r.cases]
    assert ids[:2] == ["fill0", "caps"] and {"sky0", "ao"} <= set(ids)  # registry order: aperture first
    sky, fill = r.cases[ids.index("sky0")], r.cases[ids.index("fill0")]
    assert sky.reference.cache_key == fill.reference.cache_key
    assert {"curvature-fitted", "evans-text-fitted", "visible_probe"} <= set(r.outcomes["sky0"])
    assert not {"curvature", "evans-text"} & set(r.outcomes["sky0"])
    assert {"fill-seed", "fill-projected", "visible_probe"} <= set(r.outcomes["fill0"])
    for case in ("sky0", "fill0"):
        for o in r.outcomes[case].values():
            assert np.all(np.isfinite(o.image))
    ref = sky.reference.mean[sky.mask]
    for c in range(3):
        lo, hi = 0.5 * math.pi * L[c], math.pi * L[c]
        se = sky.reference.stderr[sky.mask][:, c]
        assert np.all(ref[:, c] > lo - 5 * se) and np.all(ref[:, c] < hi + 5 * se)
    e_n = np.asarray(sky.channel_inputs[0]["irradiance_n"])
    np.testing.assert_allclose(e_n, math.pi * L[0], rtol=2e-6)  # float32 SH kernel: measured 4e-7
    family = AUDITED["sdf-occlusion"]
    assert "sky_irradiance" in (family.quantity, *family.quantities)


def test_a_user_formula_on_the_bake_agrees_with_the_reference(wall_audit):
    """Under a constant sky E = πL·V exactly (V the cosine-weighted visibility), so the user row
    s·π·L_sky·V (L_sky = E_SH(b)/π = L), evaluated at its declared s = 0.7, has the least-squares scale
    s* = 0.7·Σ(E·f)/Σ f² = 1 over the case's pixels and channels: the bake's V and the reference are
    independent estimates of the same thing. Within 2 % (measured 0.7 % at 64 spp; 1.1 %, 0.002 % at
    seeds 1, 2)."""
    case = next(c for c in wall_audit.cases if c.id == "fill0")
    f = wall_audit.outcomes["fill0"]["visible_probe"].image[case.mask]
    e = case.reference.mean[case.mask]
    s_star = 0.7 * float((e * f).sum() / (f * f).sum())
    assert abs(s_star - 1.0) < 2e-2, s_star


def test_fill_rows_on_an_open_floor(tmp_path):
    """500 m from the wall (it hides < 10⁻³ of the sky): V ≈ 1, b ≈ n, r_a ≈ π/2, so the projected fill is πL
    and the seed fill twice that (its missing cosine); the reference is πL within 4.5 standard errors
    (measured max |z| 2.6). The fills read the bake (256 uniform rays a point: its bent normal is off n by
    ~0.07 rad, up to 0.25 at 3σ): the projected fill is πL to 2.5 % (measured max 1.8 %, median 0.1 %: second
    order in that angle), the seed fill 2πL to 5 % (measured max 3.6 %: first order, its cos(n, b))."""
    r = audit(
        _wall(tmp_path, cy=-500.0), "ambient-aperture", spp=256, pass_spp=128, ao_distance=0.5,
        cache=tmp_path / "cache", fit=False, **FAST,
    )  # fmt: skip
    (fill,) = [c for c in r.cases if c.id == "fill0"]
    ref = fill.reference.mean[fill.mask]
    se = fill.reference.stderr[fill.mask]
    proj = r.outcomes["fill0"]["fill-projected"].image[fill.mask]
    seed = r.outcomes["fill0"]["fill-seed"].image[fill.mask]
    want = math.pi * np.asarray(L)[None, :] * np.ones_like(proj)
    z = np.abs(ref - want) / np.maximum(se, 1e-9)
    assert z.max() < 4.5, z.max()
    np.testing.assert_allclose(proj, want, rtol=2.5e-2)
    np.testing.assert_allclose(seed, 2.0 * want, rtol=5e-2)


def test_cli_list_then_audit_then_bad_input(tmp_path):
    """The scene → --list → audit path through the CLI: --list names both roles; the audit writes the
    report; ``--approx ambient-aperture:fill-projected`` on a scene without an environment, and
    ``--approx sdf-occlusion`` on a lone floor (no environment, nothing to occlude it), are one line each
    saying what is missing, exit 2, nothing written."""
    scene = _wall(tmp_path)
    run = CliRunner().invoke(audit_cmd, [str(scene), "--list", "--ao-distance", "0.5"])
    assert run.exit_code == 0, run.stderr
    assert "sdf-occlusion — sky occlusion" in run.stdout and "aperture fill" in run.stdout
    out = tmp_path / "out"
    run = CliRunner().invoke(
        audit_cmd,
        [str(scene), "--approx", "ambient-aperture:fill-projected", "--spp", "8", "--pass-spp", "4",
         "--no-fit", "--no-progress", "--ao-distance", "0.5", "--out", str(out),
         "--cache", str(tmp_path / "c")],
    )  # fmt: skip
    assert run.exit_code in (0, 1), run.stderr
    assert (out / "audit-wall" / "report.html").exists()
    text = (out / "audit-wall" / "report.md").read_text()
    assert "Projected-cap fill" in text
    dark = tmp_path / "dark.xml"
    point = '<point name="position" x="0" y="-1" z="3"/><rgb name="intensity"'
    text = scene.read_text().replace('<emitter type="constant">', '<emitter type="point">')
    dark.write_text(text.replace('<rgb name="radiance"', point))
    out2 = tmp_path / "out2"
    # (the fill rows themselves also apply to geometry alone, read as AO by the aperture-caps role with a
    # unit sky of radiance 1/π: experiments/audit_ambient_aperture.py; the environment's own family does not)
    run = CliRunner().invoke(audit_cmd, [str(dark), "--approx", "irradiance-bases", "--out", str(out2)])
    assert run.exit_code == 2 and run.stdout == "" and run.stderr.count("\n") == 1, run.stderr
    assert (
        run.stderr.startswith("rtfit: error: irradiance-bases does not apply")
        and "an environment" in run.stderr
    )
    assert not out2.exists()
    # a lone floor under a point light: neither an environment nor self-occluding geometry
    lone = tmp_path / "lone.xml"
    text = dark.read_text()
    lone.write_text(text.split('<shape type="rectangle" id="wall">')[0] + text.split("</shape>")[-1])
    run = CliRunner().invoke(audit_cmd, [str(lone), "--approx", "sdf-occlusion", "--out", str(out2)])
    assert run.exit_code == 2 and run.stderr.count("\n") == 1, run.stderr
    assert "sdf-occlusion does not apply" in run.stderr and "geometry that can occlude itself" in run.stderr
    assert not out2.exists()


def test_a_family_declared_once_per_role_is_one_audited_family():
    """`by_name` joins declarations of one family by role: `cases` dispatches on the applicability's role,
    the quantities are all of theirs; a role declared twice, or a declaration without roles beside another,
    is refused."""
    from dataclasses import replace

    from rtfit.experiments.audit import AuditError
    from rtfit.experiments.audit_family import AuditFamily, by_name
    from rtfit.experiments.audit_parts import Applicability

    def case_of(tag):
        return lambda setup, app: [tag]

    a = AuditFamily("fam", "q1", case_of("a"), roles=("r1",), quantities=("q3",))
    b = AuditFamily("fam", "q2", case_of("b"), roles=("r2",))
    other = AuditFamily("other", "q1", case_of("o"))
    joined = by_name([a, other, b])
    assert list(joined) == ["fam", "other"] and joined["other"] is other
    fam = joined["fam"]
    assert fam.roles == ("r1", "r2") and fam.quantity == "q1" and set(fam.quantities) == {"q2", "q3"}
    app = Applicability("fam", "r2", "part", (), (), "", "", "")
    assert fam.cases(None, app) == ["b"]  # type: ignore[arg-type]
    assert fam.cases(None, replace(app, role="r1")) == ["a"]  # type: ignore[arg-type]
    with pytest.raises(AuditError, match="declared twice"):
        by_name([a, replace(b, roles=("r1",))])
    with pytest.raises(AuditError, match="must name each declaration's roles"):
        by_name([a, replace(b, roles=None)])
