"""Methods as data (`rtfit.realtime.methods`) and fits through the kernel text (`rtfit.fitting.fit_method`).

Oracle for the fit: scipy's least_squares on a residual written independently in NumPy (the wrap formula
typed here as the test's own oracle), against the exact sphere-light irradiance as the target."""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
from scipy.optimize import least_squares

from rtfit.fitting import fit_method
from rtfit.fitting.method_fit import NOISE_KAPPA
from rtfit.realtime import Input, Method, Param, diffuse, method_table, sphere_light_irradiance


def _wrap(ops, cos_theta, w, p):
    base = ops.maximum((cos_theta + w) / (1.0 + w), 0.0)
    return ops.power(base, p)


WRAP = Method(
    "wrap-test",
    "Wrap",
    _wrap,
    inputs=(Input("cos_theta", "1", "n·l"),),
    params={"w": Param(0.3, 0.0, 1.0, unit="1"), "p": Param(1.3, 0.25, 8.0, unit="1")},
)


def test_declaration_checks():
    with pytest.raises(ValueError, match="declared twice"):
        Method("m", "M", _wrap, inputs=("w",), params={"w": Param(0.5, 0, 1)})
    with pytest.raises(ValueError, match="method id"):
        Method("bad id", "M", _wrap)
    with pytest.raises(ValueError, match="declared twice"):
        method_table([WRAP, WRAP])
    with pytest.raises(ValueError, match="has no parameter q"):
        WRAP.keywords({"q": 1.0})
    with pytest.raises(ValueError, match="strictly inside"):
        Param(1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="real number"):
        Param(True, 0.0, 2.0)


def test_evaluate_matches_the_public_function_on_numpy_and_floats():
    c = np.linspace(-1, 1, 11)
    got = WRAP.evaluate({"cos_theta": c}, {"w": 0.4, "p": 1.7})
    np.testing.assert_allclose(got, diffuse.wrap(c, 0.4, 1.7), rtol=1e-15)
    assert WRAP.evaluate({"cos_theta": 0.5}) == pytest.approx(((0.5 + 0.3) / 1.3) ** 1.3, rel=1e-15)
    fixed = Method("hl", "Half-Lambert as wrap", _wrap, inputs=("cos_theta",), fixed={"w": 1.0, "p": 2.0})
    np.testing.assert_allclose(fixed.evaluate({"cos_theta": c}), diffuse.half_lambert(c), rtol=1e-15)


def test_fit_through_the_kernel_lands_where_an_independent_fit_lands():
    rng = np.random.default_rng(3)
    c = rng.uniform(-1, 1, 3000)
    alpha = math.radians(25.0)
    target = sphere_light_irradiance(c, alpha, 1.0) / (math.pi * math.sin(alpha) ** 2)

    def resid(x):
        base = np.maximum((c + x[0]) / (1 + x[0]), 0.0)
        return base ** x[1] - target

    ref = least_squares(
        resid, [0.3, 1.3], bounds=([0.0, 0.25], [1.0, 8.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14
    )
    fit = fit_method(WRAP, {"cos_theta": c}, target)
    assert fit.converged
    # Same optimum of the same objective: agreement to the solvers' tolerances (measured 2e-10).
    assert fit.values["w"] == pytest.approx(ref.x[0], abs=1e-7)
    assert fit.values["p"] == pytest.approx(ref.x[1], abs=1e-7)
    held = fit_method(WRAP, {"cos_theta": c}, target, params={"p": Param(1.3, 0.25, 8.0)}, held={"w": 0.2})
    assert set(held.values) == {"p"}
    with pytest.raises(ValueError, match="both fitted and held"):
        fit_method(WRAP, {"cos_theta": c}, target, held={"w": 0.2})
    with pytest.raises(ValueError, match="needs input"):
        fit_method(WRAP, {}, target)


def test_trf_solver_lands_where_an_independent_fit_lands_and_flags_bounds_and_null_directions():
    """``solver="trf"`` (the NumPy run, SciPy TRF, finite-difference Jacobian): the same optimum as the
    independent fit and as the JAX LM fit, within 1e-2 of each stderr (its noise-derived stop); the standard
    errors within 1e-4 relative of LM's exact-Jacobian ones (central differences: ≈ 4e-11 relative error per
    entry, plus the stop's shift: measured 7e-6); an
    optimum on a bound flagged ``at_bound``; a parameter the data cannot determine gets stderr NaN."""
    rng = np.random.default_rng(3)
    c = rng.uniform(-1, 1, 3000)
    alpha = math.radians(25.0)
    target = sphere_light_irradiance(c, alpha, 1.0) / (math.pi * math.sin(alpha) ** 2)

    def resid(x):
        base = np.maximum((c + x[0]) / (1 + x[0]), 0.0)
        return base ** x[1] - target

    ref = least_squares(
        resid, [0.3, 1.3], bounds=([0.0, 0.25], [1.0, 8.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14
    )
    trf = fit_method(WRAP, {"cos_theta": c}, target, solver="trf")
    lm = fit_method(WRAP, {"cos_theta": c}, target)
    assert trf.converged and not any(trf.at_bound.values())
    # TRF stops within NOISE_KAPPA of each stderr of the optimum (`method_fit.noise_ftol`), so its SSR lies
    # within κ²·s² of the optimum's (s² = SSR/dof)
    s2 = 2 * ref.cost / (c.size - 2)
    for i, k in enumerate(("w", "p")):
        assert abs(trf.values[k] - ref.x[i]) <= NOISE_KAPPA * trf.stderr[k]
        assert trf.stderr[k] == pytest.approx(lm.stderr[k], rel=1e-4)
    assert 0 <= trf.ssr - 2 * ref.cost <= NOISE_KAPPA**2 * s2
    # Data made with w = −0.3 (a narrowed lobe, outside w's bounds): the independent bounded fit lands on
    # the bound w = 0, and so does TRF, flagged.
    low = np.maximum((c - 0.3) / 0.7, 0.0)

    def resid_low(x):
        return np.maximum((c + x[0]) / (1 + x[0]), 0.0) ** x[1] - low

    ref_low = least_squares(resid_low, [0.3, 1.3], bounds=([0.0, 0.25], [1.0, 8.0]), xtol=1e-14, ftol=1e-14)
    assert ref_low.x[0] == pytest.approx(0.0, abs=1e-9)
    at = fit_method(WRAP, {"cos_theta": c}, low, solver="trf")
    assert at.converged and at.at_bound["w"] and at.values["w"] == pytest.approx(0.0, abs=1e-9)
    assert abs(at.values["p"] - ref_low.x[1]) <= NOISE_KAPPA * at.stderr["p"]
    # p only scales the exponent of a base that is 1 everywhere (cos θ = 1): w and p are not determined.
    flat = fit_method(WRAP, {"cos_theta": np.ones(50)}, np.ones(50), solver="trf")
    assert math.isnan(flat.stderr["p"]) and flat.jacobian_rank < 2
    # ((1 + w)/(1 + w))^p = 1 for every w, p: neither moves the residuals, which the fit says.
    assert "w, p: the residuals do not change with it" in flat.message
    assert "not fitted" not in trf.message and "not fitted" not in at.message
    with pytest.raises(ValueError, match="solver must be"):
        fit_method(WRAP, {"cos_theta": c}, target, solver="newton")
    with pytest.raises(ValueError, match="non-finite residuals"):
        fit_method(WRAP, {"cos_theta": c * np.nan}, target, solver="trf")


def _saturating(ops, x, scale, length):
    return scale * (1.0 - ops.exp(-x / length))


def test_trf_log_parameters_land_where_an_independent_fit_in_p_lands():
    """`Param.log` (the TRF steps log p): the optimum of an independent fit in p itself, within NOISE_KAPPA of
    each stderr, the same SSR to round-off, the standard errors p's (those of the fit in p within 1e-6
    relative: the Jacobian's chain rule ∂r/∂p = ∂r/∂log p / p); an optimum on an upper bound flagged; a
    lower bound 0 is allowed (log p = −∞), a negative one refused."""
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 5.0, 400)
    target = 2.0 * (1.0 - np.exp(-x / 1.5)) + rng.normal(0.0, 0.01, x.size)

    def method(log: bool, upper: float = 10.0) -> Method:
        return Method("sat-test", "Saturating", _saturating, inputs=(Input("x", "1", "x"),),
                      params={"scale": Param(1.0, 0.0, upper, unit="1", log=log),
                              "length": Param(1.0, 1e-3, 1e3, unit="1", log=log)})  # fmt: skip

    def resid(p):
        return p[0] * (1.0 - np.exp(-x / p[1])) - target

    ref = least_squares(resid, [1.0, 1.0], bounds=([0.0, 1e-3], [10.0, 1e3]), xtol=1e-15, ftol=1e-15)
    logged = fit_method(method(True), {"x": x}, target, solver="trf")
    plain = fit_method(method(False), {"x": x}, target, solver="trf")
    assert logged.converged and not any(logged.at_bound.values())
    for i, k in enumerate(("scale", "length")):
        assert abs(logged.values[k] - ref.x[i]) <= NOISE_KAPPA * logged.stderr[k]
        assert logged.stderr[k] == pytest.approx(plain.stderr[k], rel=1e-6)
    assert logged.ssr == pytest.approx(2 * ref.cost, rel=1e-9)
    capped = fit_method(method(True, upper=1.8), {"x": x}, target, solver="trf")
    assert capped.at_bound["scale"] and capped.values["scale"] == pytest.approx(1.8, rel=1e-9)
    with pytest.raises(ValueError, match="log needs lower"):
        Param(1.0, -1.0, 2.0, log=True)


# ------------------------------------------------------------------- every shipped method, three libraries
def _shipped_methods():
    import importlib

    import rtfit.realtime as realtime

    out = []
    for name in realtime.MODULES:
        table = getattr(importlib.import_module(f"rtfit.realtime.{name}"), "METHODS", None)
        for method in (table or {}).values():
            if method.inputs and all(i.domain is not None for i in method.inputs):
                out.append(pytest.param(method, id=f"{name}:{method.id}"))
    return out


SHIPPED = _shipped_methods()


def test_shipped_methods_declare_domains():
    # Families whose inputs are scalars per element declare their domains (tables, grids and SH
    # coefficients are structured inputs and are exercised by the family's own tests).
    assert len(SHIPPED) >= 14, [p.id for p in SHIPPED]


@pytest.mark.parametrize("method", SHIPPED)
def test_one_text_runs_on_drjit_numpy_and_jax(method):
    """The kernel text of every shipped method gives the same numbers on Dr.Jit (LLVM, float64), NumPy
    and JAX (float64) over its declared input domain, with its default parameters. Oracle: the NumPy
    run; tolerance 1e-9 of the output's scale (measured ≤ 4.4e-16 over the diffuse and ambient-aperture
    tables: libm, LLVM and XLA transcendental functions differ in the last bits; the margin covers
    kernels whose branches on such values may fall the other way at a boundary)."""
    import drjit as dr
    import jax
    import jax.numpy as jnp

    from rtfit.realtime import DRJIT_OPS, NUMPY_OPS, jax_ops

    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(zlib.crc32(method.id.encode()))  # stable across processes (hash() is salted)
    n = 513
    inputs = {}
    for inp in method.inputs:
        lo, hi = inp.domain
        x = rng.uniform(lo, hi, n)
        x[:2] = lo, hi  # the domain's ends are part of it
        inputs[inp.name] = x
    ref = method(NUMPY_OPS, inputs)
    got_jax = method(jax_ops(), {k: jnp.asarray(v) for k, v in inputs.items()})
    got_dr = method(DRJIT_OPS, {k: dr.llvm.Float64(v) for k, v in inputs.items()})
    refs = ref if isinstance(ref, tuple) else (ref,)
    for k, (r, j, d) in enumerate(
        zip(
            refs,
            got_jax if isinstance(got_jax, tuple) else (got_jax,),
            got_dr if isinstance(got_dr, tuple) else (got_dr,),
            strict=True,
        )
    ):
        r = np.broadcast_to(np.asarray(r, np.float64), (n,))
        assert np.all(np.isfinite(r)), f"{method.id}[{k}]: non-finite NumPy output"
        scale = max(float(np.max(np.abs(r))), 1e-300)
        np.testing.assert_allclose(np.broadcast_to(np.asarray(j), (n,)), r, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(np.broadcast_to(np.asarray(d), (n,)), r, rtol=0, atol=1e-9 * scale)


def _depth_test(ops, z, depth, b):
    """A shadow map's compare: lit (1) where z − b < depth — a step function of the bias b."""
    return ops.select(z - b < depth, 1.0 + 0.0 * z, 0.0 * z)


def test_a_scanned_parameter_fits_a_step_function():
    """A depth compare's bias has zero gradient between steps: a local solver started at 0.01 stays there.
    With ``Param.scan`` the fit first tries the scan's values and keeps the one with the least squared
    residual. Receivers whose depth gap is uniform in [0, 0.1] lit by the truth b = 0.05: the fraction lit
    moves by 1/n per 0.1/n of b, so the scan's best value is the scan value nearest 0.05 (independently: the
    residual count |{gap < b} Δ {gap < 0.05}| is smallest there)."""
    rng = np.random.default_rng(2)
    gap = rng.uniform(0.0, 0.1, 4000)
    z, depth = gap, np.zeros_like(gap)
    truth = (gap < 0.05).astype(float)
    plain = Method("step", "Step", _depth_test, inputs=("z", "depth"), params={"b": Param(0.01, 0.0, 0.5)})
    fit = fit_method(plain, {"z": z, "depth": depth}, truth, solver="trf")
    assert fit.values["b"] == pytest.approx(0.01)  # stuck at its start: no gradient
    scanned = Method("step-scan", "Step", _depth_test, inputs=("z", "depth"),
                     params={"b": Param(0.01, 0.0, 0.5, scan=33)})  # fmt: skip
    values = scanned.params["b"].scan_values()
    assert len(values) == 33 and 0.0 < values[0] < values[-1] < 0.5
    assert values[1] / values[0] == pytest.approx(1000.0 ** (1 / 33))
    mismatch = [int(np.sum((gap < v) != (gap < 0.05))) for v in values]
    want = values[int(np.argmin(mismatch))]
    for solver in ("trf", "lm"):
        fit = fit_method(scanned, {"z": z, "depth": depth}, truth, solver=solver)
        assert fit.values["b"] == pytest.approx(want, rel=1e-9), solver
    with pytest.raises(ValueError, match="scan"):
        Param(0.1, 0.0, 1.0, scan=-1)
    with pytest.raises(ValueError, match="finite bounds"):
        Param(0.1, 0.0, scan=3)
