"""A user's own approximation (issue 15 §4): the decorator, loading, validation, fitting, the doc's table.

The fit test is the one of issue 15 §6: wrap lighting with exponent 2 against the exact irradiance of a
sphere light on a lit sphere. `fit_method` fits the user's text (through the decorator and JAX) to the
shipped exact form; the test fits the same formula, typed here, with SciPy to its own quadrature of the
exact irradiance over the light's cap. Both must land on the same w.
"""

from __future__ import annotations

import math
import re
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rtfit.experiments.families import METHOD_TABLES
from rtfit.experiments.user_methods import (
    ENTRY_POINT_GROUP,
    UserMethodError,
    check_approximation,
    load_approximation,
    sample_inputs,
)
from rtfit.fitting import fit_method
from rtfit.realtime import NUMPY_OPS, diffuse, sphere_light_irradiance
from rtfit.realtime.quantities import (
    QUANTITIES,
    QUANTITY_ORDER,
    ApproximationError,
    approximation,
    is_user_approximation,
    quantities_markdown,
)

ROOT = Path(__file__).resolve().parent.parent

MY_WRAP = '''\
# my_wrap.py
from rtfit import approximation, Param


@approximation(quantity="light_irradiance", params={"w": Param(0.5, lower=0.0, upper=1.0)})
def my_wrap(ops, g, *, w):
    """Wrap lighting with exponent 2; g carries the quantity's named inputs."""
    t = ops.maximum((g.cos_theta + w) / (1.0 + w), 0.0)
    return g.irradiance * t * t
'''


def wrap2(c, e, w):
    """The user's formula typed here (the oracle side)."""
    t = np.maximum((c + w) / (1.0 + w), 0.0)
    return e * t * t


@pytest.fixture
def wrap_file(tmp_path):
    p = tmp_path / "my_wrap.py"
    p.write_text(MY_WRAP)
    return p


@pytest.fixture
def wrap_method(wrap_file):
    return load_approximation(f"{wrap_file}:my_wrap")


def light_inputs(c):
    c = np.asarray(c, np.float64)
    return {"cos_theta": c, "irradiance": 2.0 + 0.0 * c, "alpha": 0.1 + 0.0 * c, "distance": 3.0 + 0.0 * c}


# ------------------------------------------------------------------------------------------- the decorator
def test_decorator_makes_a_method_of_the_quantity(wrap_method):
    m = wrap_method
    assert is_user_approximation(m)
    assert m.id == "my_wrap" and m.quantity == "light_irradiance"
    assert m.input_names == ("cos_theta", "irradiance", "alpha", "distance")
    assert m.label == "Wrap lighting with exponent 2; g carries the quantity's named inputs."
    assert (m.params["w"].lower, m.params["w"].upper, m.params["w"].initial) == (0.0, 1.0, 0.5)
    assert m.source.endswith("my_wrap.py:5")
    assert check_approximation(m) is None  # finite, right shape, NumPy = Dr.Jit on the whole domain


def test_loads_from_a_module(tmp_path, monkeypatch):
    pkg = tmp_path / "shading_pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "wraps.py").write_text(MY_WRAP)
    monkeypatch.syspath_prepend(str(tmp_path))
    m = load_approximation("shading_pkg.wraps:my_wrap")
    assert is_user_approximation(m) and m.id == "my_wrap"
    c = np.linspace(-1.0, 1.0, 9)
    np.testing.assert_allclose(m(NUMPY_OPS, light_inputs(c), {"w": 0.25}), wrap2(c, 2.0, 0.25), rtol=1e-15)
    sys.modules.pop("shading_pkg.wraps", None)
    sys.modules.pop("shading_pkg", None)


def test_loads_from_an_entry_point(tmp_path, monkeypatch):
    (tmp_path / "ep_wraps.py").write_text(MY_WRAP)
    dist = tmp_path / "ep_wraps-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ep-wraps\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nstudio_wrap = ep_wraps:my_wrap\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    m = load_approximation("studio_wrap")
    assert is_user_approximation(m) and m.id == "my_wrap"
    with pytest.raises(
        UserMethodError, match=r"^studio_wrapp: .*no entry point 'studio_wrapp'.*studio_wrap\)$"
    ):
        load_approximation("studio_wrapp")
    sys.modules.pop("ep_wraps", None)


def test_runs_on_drjit_numpy_and_jax_alike(wrap_method):
    import drjit as dr  # drjit: the product's backend, imported by the tests that need it
    import jax
    import jax.numpy as jnp  # jax: the fit's backend

    jax.config.update("jax_enable_x64", True)  # as rtfit.fitting does for every fit (process-wide)
    c = np.linspace(-1.0, 1.0, 101)
    want = wrap2(c, 2.0, 0.3)  # the formula typed in this test
    got_np = wrap_method(NUMPY_OPS, light_inputs(c), {"w": 0.3})
    got_dr_from_np = wrap_method.evaluate(light_inputs(c), {"w": 0.3})  # NumPy in → Dr.Jit → NumPy
    F = dr.llvm.Float64
    got_dr = wrap_method.evaluate({k: F(v) for k, v in light_inputs(c).items()}, {"w": 0.3})
    assert isinstance(got_dr, F)
    got_jax = wrap_method.evaluate({k: jnp.asarray(v) for k, v in light_inputs(c).items()}, {"w": 0.3})
    for got in (got_np, got_dr_from_np, np.asarray(got_dr), np.asarray(got_jax)):
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-15)


def test_g_carries_vectors_and_names_what_it_lacks():
    @approximation(quantity="sky_irradiance")
    def up_sky(ops, g):
        nx, ny, nz = g.normal
        return g.sky_radiance * math.pi * g.visibility * (0.75 + 0.25 * nz) + 0.0 * (nx + ny)

    check_approximation(up_sky)
    s = sample_inputs("sky_irradiance", 16)
    out = up_sky(NUMPY_OPS, s)
    np.testing.assert_allclose(out, s["sky_radiance"] * math.pi * s["visibility"] * (0.75 + 0.25 * s["nz"]))

    @approximation(quantity="light_irradiance")
    def typo(ops, g):
        return g.cos * g.irradiance

    with pytest.raises(UserMethodError) as e:
        check_approximation(typo)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(
        "typo: raised AttributeError: light_irradiance carries no input 'cos'"
    )
    assert "cos_theta, irradiance, alpha, distance" in msg


# ------------------------------------------------------------------------- the fit of issue 15 §6
def fibonacci_sphere(n):
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def cap_irradiance_quadrature(cos_theta, alpha, radiance, n_beta=40, n_phi=720):
    """E = L ∫_cap max(n·ω, 0) dω by Gauss–Legendre in the polar angle β ∈ [0, α] about the light's
    centre and the midpoint rule in the azimuth φ ∈ [0, π] (×2 by symmetry);
    n·ω = cos β cos θ + sin β sin θ cos φ."""
    x, wx = np.polynomial.legendre.leggauss(n_beta)
    a = np.asarray(alpha, np.float64)[:, None]
    beta = 0.5 * a * (x[None, :] + 1.0)  # (points, n_beta)
    wb = 0.5 * a * wx[None, :] * np.sin(beta)
    phi = (np.arange(n_phi) + 0.5) * (math.pi / n_phi)
    c = np.asarray(cos_theta, np.float64)[:, None, None]
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    ndotw = np.cos(beta)[:, :, None] * c + np.sin(beta)[:, :, None] * s * np.cos(phi)[None, None, :]
    inner = 2.0 * np.maximum(ndotw, 0.0).sum(axis=2) * (math.pi / n_phi)
    return radiance * (inner * wb).sum(axis=1)


def test_fit_lands_where_a_quadrature_fit_lands(wrap_method):
    from scipy.optimize import minimize_scalar  # scipy: the oracle's optimiser

    # A unit sphere lit by a sphere light of radiance L whose centre is D = 10 away: α = 20° seen from the
    # sphere's centre; every surface point has its own distance, α and cos θ.
    L, D = 3.0, 10.0
    r_light = D * math.sin(math.radians(20.0))
    p = fibonacci_sphere(600)
    v = np.array([0.0, 0.0, D]) - p
    d = np.linalg.norm(v, axis=1)
    cos_t = np.sum(p * v, axis=1) / d  # the normal of a unit sphere at p is p
    alpha = np.arcsin(r_light / d)
    e_perp = math.pi * L * np.sin(alpha) ** 2
    inputs = {"cos_theta": cos_t, "irradiance": e_perp, "alpha": alpha, "distance": d}

    # rtfit's side: the shipped exact form as the target, the user's text fitted through the decorator.
    target = np.asarray(sphere_light_irradiance(cos_t, alpha, L))
    fit = fit_method(wrap_method, inputs, target)
    assert fit.converged and not fit.at_bound["w"]

    # The oracle's side: its own quadrature of the cap, the formula typed above, SciPy's bounded search.
    quad = cap_irradiance_quadrature(cos_t, alpha, L)
    assert np.max(np.abs(quad - target)) < 1e-5  # the two exact irradiances agree (measured: 1.8e-6, L = 3)
    res = minimize_scalar(
        lambda w: float(np.sum((wrap2(cos_t, e_perp, w) - quad) ** 2)),
        bounds=(0.0, 1.0),
        method="bounded",
        options={"xatol": 1e-10},
    )
    assert 0.05 < res.x < 0.95
    assert abs(fit.values["w"] - res.x) < 1e-6, (fit.values["w"], res.x)  # measured: 2.1e-8 (w = 0.54216)
    assert abs(fit.values["w"] - res.x) < 3.0 * fit.stderr["w"] + 1e-5


# ---------------------------------------------------------------------------------------- bad input
def one_line_error(spec, pattern):
    with pytest.raises(UserMethodError) as e:
        load_approximation(spec)
    msg = str(e.value)
    assert "\n" not in msg, msg
    assert re.search(pattern, msg), msg
    return msg


def test_loading_errors_are_one_line_naming_the_spec(tmp_path, wrap_file):
    one_line_error(f"{tmp_path}/nope.py:my_wrap", r"^.*nope\.py:my_wrap: no such file .*nope\.py$")
    one_line_error(
        f"{wrap_file}:my_wrapp",
        r"my_wrap\.py:my_wrapp: .* has no attribute 'my_wrapp' \(approximations there: my_wrap\)$",
    )
    one_line_error("json:dumps", r"^json:dumps: function is not an approximation \(decorate it")
    one_line_error("no_such_module_xyz:f", r"^no_such_module_xyz:f: no module named 'no_such_module_xyz'")
    bad_q = tmp_path / "bad_q.py"
    bad_q.write_text(MY_WRAP.replace('"light_irradiance"', '"light_irradience"'))
    msg = one_line_error(
        f"{bad_q}:my_wrap", r"unknown quantity 'light_irradience' \(known: light_irradiance, "
    )
    assert all(q in msg for q in QUANTITIES) and "bad_q.py line 5" in msg
    no_bounds = tmp_path / "no_bounds.py"
    no_bounds.write_text(MY_WRAP.replace("Param(0.5, lower=0.0, upper=1.0)", "0.5"))
    one_line_error(
        f"{no_bounds}:my_wrap", r"my_wrap: parameter 'w' = 0\.5 has no bounds; declare it as Param\("
    )
    raising = tmp_path / "raising.py"
    raising.write_text("import math\nx = 1 / 0\n")
    one_line_error(f"{raising}:x", r"raising\.py:x: loading .*raising\.py line 2 failed: ZeroDivisionError")


def test_decorator_errors():
    with pytest.raises(ApproximationError, match="declared but not taken"):
        approximation(quantity="light_irradiance", params={"k": __import__("rtfit").Param(1.0, 0.0, 2.0)})(
            lambda ops, g, *, w=0.5: g.irradiance
        )
    with pytest.raises(ApproximationError, match=r"keyword\(s\) w .* are not declared"):
        approximation(quantity="light_irradiance")(lambda ops, g, *, w: g.irradiance * w)
    with pytest.raises(ApproximationError, match=r"takes \(ops, g, \*, params…\)"):
        approximation(quantity="light_irradiance")(lambda g: g)


def check_error(method, pattern):
    with pytest.raises(UserMethodError) as e:
        check_approximation(method)
    msg = str(e.value)
    assert "\n" not in msg, msg
    assert re.search(pattern, msg), msg
    return msg


def test_validation_names_the_first_offending_input():
    @approximation(quantity="light_irradiance")
    def nan_below(ops, g):
        return g.irradiance * ops.sqrt(g.cos_theta)  # NaN for cos θ < 0 (NumPy and Dr.Jit sqrt)

    n = 256
    s = sample_inputs("light_irradiance", n)
    first = int(np.argmax(s["cos_theta"] < 0))
    count = int(np.sum(s["cos_theta"] < 0))
    check_error(
        nan_below,
        rf"^nan_below: returned NaN at cos_theta={s['cos_theta'][first]:.6g}, "
        rf"irradiance={s['irradiance'][first]:.6g} \(first of {count} of {n} samples\)$",
    )

    @approximation(quantity="fog_transmittance")
    def naive_fog(ops, g):  # the textbook closed form: 0/0 where the fog is homogeneous (falloff 0)
        dz = g.z1 - g.z0
        k = g.falloff * dz
        return ops.exp(-g.density * g.length * ops.exp(-g.falloff * g.z0) * (1.0 - ops.exp(-k)) / k)

    s = sample_inputs("fog_transmittance", n)
    with np.errstate(all="ignore"):  # the same formula typed here: 0/0 at falloff 0, 0·∞ where it overflows
        dz = s["z1"] - s["z0"]
        k = s["falloff"] * dz
        t = np.exp(-s["density"] * s["length"] * np.exp(-s["falloff"] * s["z0"]) * -np.expm1(-k) / k)
    bad = np.flatnonzero(np.isnan(t))
    assert s["falloff"][bad].min() == 0.0
    i = bad[0]
    at = ", ".join(f"{k}={s[k][i]:.6g}" for k in ("length", "z0", "z1", "density", "falloff"))
    check_error(
        naive_fog, rf"^naive_fog: returned NaN at {re.escape(at)} \(first of {bad.size} of {n} samples\)$"
    )

    @approximation(quantity="light_irradiance", params={"w": __import__("rtfit").Param(0.5, 0.0, 1.0)})
    def inf_at_bound(ops, g, *, w):
        return g.irradiance / w  # finite at the default, Inf at the lower bound

    check_error(inf_at_bound, r"^inf_at_bound: returned Inf at irradiance=.* of 256 samples; w=0\)$")

    @approximation(quantity="light_irradiance")
    def raises(ops, g):
        if float(np.min(g.cos_theta)) < -0.5:
            raise RuntimeError("too dark")
        return g.irradiance

    c = sample_inputs("light_irradiance", n)["cos_theta"]
    first = int(np.argmax(c < -0.5))
    check_error(
        raises,
        rf"^raises: raised RuntimeError: too dark at cos_theta={c[first]:.6g} "
        rf"\(first of {int(np.sum(c < -0.5))} of {n} samples\)$",
    )

    @approximation(quantity="light_irradiance")
    def scalar(ops, g):
        return 1.0

    check_error(scalar, r"^scalar: returned shape \(\) on NumPy for 256 samples \(expected \(256,\)")

    @approximation(quantity="light_irradiance")
    def branchy(ops, g):
        return g.irradiance if g.cos_theta > 0 else 0.0 * g.irradiance

    check_error(
        branchy, r"^branchy: raised ValueError: .* each sample alone runs \(a Python branch on an array"
    )

    @approximation(quantity="environment_irradiance")
    def one_channel(ops, g):
        return g.sh[0] + 0.0 * g.nx

    check_error(
        one_channel,
        r"^one_channel: returned 1 value\(s\) on NumPy \(environment_irradiance wants a tuple of 3",
    )


def test_validation_runs_drjit_too():
    @approximation(quantity="light_irradiance")
    def numpy_only(ops, g):
        return np.clip(g.cos_theta, 0.0, 1.0) * g.irradiance  # np.clip is not an ops function

    check_error(numpy_only, r"^numpy_only: raised .* on Dr\.Jit \(NumPy ran: use ops\.\* functions")


def test_a_shipped_style_formula_passes_validation_for_every_quantity():
    for q in QUANTITIES.values():
        scalar = [i.name for i in q.inputs if i.domain is not None]
        # per-element structured inputs (the obscurance's K hit distances): a tuple of arrays, each summed too
        per_element = [
            i.name for i in q.inputs if i.domain is None and isinstance(q.examples[i.name](4), tuple)
        ]

        def f(ops, g, _names=tuple(scalar), _seqs=tuple(per_element), _ch=q.channels):
            terms = [getattr(g, name) for name in _names] + [d for s in _seqs for d in getattr(g, s)]
            total = 0.0 * terms[0]
            for t in terms:
                total = total + ops.minimum(ops.maximum(t, -1.0), 1.0)
            return total if _ch == 1 else (total,) * _ch

        f.__name__ = f"sum_{q.name}"
        check_approximation(approximation(quantity=q.name)(f), n=32)


# ------------------------------------------------------------------------------------ quantities table
NOT_USER_QUANTITIES: set[str] = set()
"""Quantities of shipped rows that a user's ``@approximation`` cannot approximate yet (issue 30 §4): the
list may only shrink."""


def test_every_shipped_method_has_a_documented_quantity():
    seen = set()
    for family, table in METHOD_TABLES.items():
        for mid, m in table.items():
            seen.add(m.quantity)
            if m.quantity in NOT_USER_QUANTITIES:
                continue
            assert m.quantity in QUANTITIES, (family, mid, m.quantity)
            assert f"{family}:{mid}" in QUANTITIES[m.quantity].methods(METHOD_TABLES)
    assert NOT_USER_QUANTITIES <= seen - set(QUANTITIES), "a quantity became user-approximable: drop it"
    shipped = tuple(f"diffuse:{k}" for k in diffuse.METHODS)  # the formulas and the light models
    assert QUANTITIES["light_irradiance"].methods(METHOD_TABLES)[: len(shipped)] == shipped
    assert [i.name for i in QUANTITIES["light_irradiance"].inputs] == [
        "cos_theta",
        "irradiance",
        "alpha",
        "distance",
    ]
    for q in QUANTITIES.values():
        for i in q.inputs:
            assert i.unit and i.description, (q.name, i.name)
            if i.domain is not None:
                assert i.domain[0] < i.domain[1] and all(math.isfinite(v) for v in i.domain)


def test_doc_lists_the_table():
    """docs/audit.md holds the rooms' quantities (`QUANTITY_ORDER`), generated; each quantity a family
    declares in its own module is on that family's page (tests/test_family_files.py)."""
    doc = (ROOT / "docs" / "audit.md").read_text()
    assert quantities_markdown() in doc
    section = doc.split("## Your own approximation", 1)[1]
    listed = re.findall(r"^#### `([a-z_]+)`", section, flags=re.M)
    assert listed == list(QUANTITY_ORDER)
    assert list(QUANTITIES)[: len(QUANTITY_ORDER)] == list(QUANTITY_ORDER)
    assert textwrap.dedent(MY_WRAP).split("\n", 1)[1].strip() in section


def test_import_rtfit_stays_cheap():
    import subprocess

    code = (
        "import sys, rtfit; assert 'drjit' not in sys.modules and 'rtfit.realtime' not in sys.modules; "
        "from rtfit import approximation, Param; import rtfit.realtime.methods as m; "
        "assert Param is m.Param and callable(approximation)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
