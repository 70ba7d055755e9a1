"""The pooled fit of one method to several cases (`rtfit.experiments.audit_fit.pooled_fit`): the values it
returns are the weighted least-squares solution computed independently here (the normal equations of a
model linear in its parameters), with each case weighted by 1/(rms(reference)·√N) as its docstring states."""

from __future__ import annotations

import numpy as np
import pytest

from rtfit.experiments.audit import AuditError
from rtfit.experiments.audit_family import FamilyCase
from rtfit.experiments.audit_fit import fit_case, pooled_fit
from rtfit.experiments.audit_setup import AuditReference
from rtfit.realtime.methods import Input, Method, Param


def _line(ops, x, a, b):
    return a * x + b


LINE = Method(
    id="line",
    label="a·x + b",
    kernel=_line,
    inputs=(Input("x", "1", "abscissa", domain=(0.0, 10.0)),),
    params={"a": Param(1.0, -10.0, 10.0, unit="1"), "b": Param(0.0, -10.0, 10.0, unit="1")},
    formula="a·x + b",
)


def _case(cid: str, x: np.ndarray, y: np.ndarray) -> FamilyCase:
    """A grey case over a 1 × n image: the same reference in the three channels, read per channel."""
    n = len(x)
    mean = np.repeat(y[None, :, None], 3, axis=2)
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    inputs = ({"x": x},) * 3
    return FamilyCase(cid, cid, ref, np.ones((1, n), bool), inputs)


def test_pooled_values_are_the_weighted_least_squares_solution():
    rng = np.random.default_rng(3)
    x1, x2 = rng.uniform(0, 10, 40), rng.uniform(0, 10, 25)
    y1 = 2.0 * x1 + 1.0 + rng.normal(0, 0.3, x1.size)  # one case bright,
    y2 = 0.2 * x2 + 0.5 + rng.normal(0, 0.05, x2.size)  # one dim: unweighted, the bright one would decide
    c1, c2 = _case("bright", x1, y1), _case("dim", x2, y2)
    own = [fit_case(LINE, c, "line")["parameters"] for c in (c1, c2)]
    pf = pooled_fit(LINE, [(c1, "line", {k: v["value"] for k, v in own[0].items()}),
                           (c2, "line", {k: v["value"] for k, v in own[1].items()})])  # fmt: skip
    assert pf is not None and pf.cases == ("bright", "dim") and not pf.left_out
    # Independent: the normal equations of the weighted problem (three channels: each element 3 times).
    rows, rhs, w = [], [], []
    for x, y in ((x1, y1), (x2, y2)):
        t = np.tile(y, 3)
        weight = 1.0 / (np.sqrt(np.mean(t**2)) * np.sqrt(t.size))
        rows.append(np.stack([np.tile(x, 3), np.ones(t.size)], axis=1))
        rhs.append(t)
        w.append(np.full(t.size, weight))
    A, t, W = np.concatenate(rows), np.concatenate(rhs), np.concatenate(w)
    expected = np.linalg.lstsq(A * W[:, None], t * W, rcond=None)[0]
    got = [pf.fit["parameters"][k]["value"] for k in ("a", "b")]
    assert got == pytest.approx(expected, rel=1e-6, abs=1e-8)


def test_a_case_with_a_zero_reference_is_left_out_and_named():
    x = np.linspace(0, 1, 10)
    cases = [(_case("c1", x, 2 * x + 1), "line", {}), (_case("c2", x, 3 * x), "line", {}),
             (_case("dark", x, 0 * x), "line", {})]  # fmt: skip
    pf = pooled_fit(LINE, cases)
    assert pf is not None and pf.cases == ("c1", "c2")
    assert "zero everywhere" in pf.left_out["dark"]
    assert pooled_fit(LINE, cases[:1]) is None  # one case: nothing to pool


def test_a_small_table_is_timed_as_distinct_unfoldable_literals():
    """`Uniforms` (the cost's constant buffer): a constant sky's SH table (24 zeros, equal channels) becomes
    27 distinct values none of which is 0 or ±1, each within 2⁻²⁰·(|v| + 1)·27 of its own, and a kernel that
    reads the table by index gives the same values as on the table itself (to that change)."""
    from rtfit.realtime import sh_sky_bent_normal
    from rtfit.realtime.arrays import Uniforms, backend_float

    sky = np.zeros(27)
    sky[[0, 9, 18]] = 3.5
    u = Uniforms.of(sky)
    assert len(set(u)) == 27 and not {0.0, 1.0, -1.0} & set(u)
    assert np.all(np.abs(np.array(u) - sky) <= 2.0**-20 * (np.abs(sky) + 1.0) * 27 + 1e-15)
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    m = sh_sky_bent_normal.METHODS["irradiance-normal"]
    Float = backend_float(None, np.float64)  # (a NumPy table would broadcast against the pixels)
    inputs = {"nx": Float(n[:, 0]), "ny": Float(n[:, 1]), "nz": Float(n[:, 2]), "ao": Float(np.ones(2))}
    exact = np.array([np.asarray(c) for c in m.evaluate({**inputs, "coeffs": Float(sky)})])
    timed = np.array([np.asarray(c) for c in m.evaluate({**inputs, "coeffs": u})])
    assert timed == pytest.approx(exact, rel=1e-4)
    # a constant sky of radiance L lights every normal with E = π L: L00 = 2√π·L, so L = 3.5/(2√π)
    assert exact == pytest.approx(np.pi * 3.5 / (2 * np.sqrt(np.pi)), rel=1e-6)


def test_a_kernel_that_gathers_from_a_uniforms_table_reads_its_values():
    """A `Uniforms` table handed to a kernel that gathers from it (a cube map) is gathered from as an array
    (the LLVM backend crashed gathering from a tuple: the matpreview audit's environment-maps cost timing,
    exit 139)."""
    from rtfit.realtime.arrays import DRJIT_OPS, Uniforms, backend_float

    table = np.linspace(0.5, 3.0, 30)
    Float = backend_float(None, np.float64)
    idx = Float([0.0, 7.9, 29.0])
    u = Uniforms.of(table)
    got = np.asarray(DRJIT_OPS.gather(u, idx))
    assert got == pytest.approx(np.array(u)[[0, 7, 29]], rel=1e-12)  # (each entry within 2⁻²⁰·(|v|+1)·30)


def _scale(ops, x, a):
    return a * x


SCALE = Method(
    id="scale",
    label="a·x",
    kernel=_scale,
    inputs=(Input("x", "1", "abscissa", domain=(0.0, 10.0)),),
    params={"a": Param(1.0, -10.0, 10.0, unit="1")},
    formula="a·x",
)


@pytest.mark.parametrize("with_factor", [False, True])
def test_a_relative_fit_minimises_the_relative_error_over_the_noise_floor(with_factor):
    """``fit_weight="relative"``: the fit of a·x·s to y minimises Σ((a·x·s − y)/m)², m = max(|y|, σ), whose
    minimum is a = Σ(x·s·y/m²) / Σ((x·s)²/m²) (closed form); absolute, a = Σ(x·s·y) / Σ((x·s)²). Dark pixels
    (y below σ, one y = 0) are weighed by σ, not by their own tiny value."""
    rng = np.random.default_rng(5)
    x = rng.uniform(0.5, 10, 30)
    y = np.where(np.arange(30) % 3 == 0, 1e-3 * x, 2.0 * x * rng.uniform(0.8, 1.2, 30))
    y[1] = 0.0
    s = rng.uniform(0.5, 2.0, 30) if with_factor else np.ones(30)
    mean = np.repeat(y[None, :, None], 3, axis=2)
    ref = AuditReference(mean, np.full_like(mean, 0.02), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    sigma = ref.sigma()[0, :, 0]
    assert sigma.min() >= 0.02 and (np.abs(y) < sigma).sum() >= 10  # (the floor matters on the dark third)
    common = dict(reference=ref, mask=np.ones((1, 30), bool), channel_inputs=({"x": x / s},) * 3,
                  factor=s if with_factor else None)  # fmt: skip
    rel = FamilyCase("rel", "rel", fit_weight="relative", **common)
    ab = FamilyCase("abs", "abs", **common)
    m = np.maximum(np.abs(y), sigma)
    xs = x  # x/s·s: the image's value per unit a
    expected_rel = np.sum(xs * y / m**2) / np.sum(xs**2 / m**2)
    expected_abs = np.sum(xs / s * y / s) / np.sum((xs / s) ** 2)  # (absolute: on the target y/s)
    got_rel = fit_case(SCALE, rel, "scale")["parameters"]["a"]["value"]
    got_abs = fit_case(SCALE, ab, "scale")["parameters"]["a"]["value"]
    assert got_rel == pytest.approx(expected_rel, rel=1e-6)
    assert got_abs == pytest.approx(expected_abs, rel=1e-6)
    assert abs(got_rel - got_abs) > 0.05 * abs(got_abs)  # (the weighting changes the answer)


def test_an_unknown_fit_weight_is_refused():
    from rtfit.experiments.audit import AuditError

    with pytest.raises(AuditError, match="fit_weight 'square'"):
        FamilyCase("c", "c", _case("x", np.ones(2), np.ones(2)).reference, np.ones((1, 2), bool),
                   ({"x": 1.0},) * 3, fit_weight="square")  # fmt: skip


def test_a_case_reading_a_table_of_its_scene_is_left_out_of_the_pool():
    """A kernel input that is not one value per pixel (a sky texture's texels: nishita-sky's ``texel_mu``)
    cannot be concatenated across scenes: the case is left out and named (the quick suite's nishita-sky run
    failed on a broadcast of 8,192 texels to 512 pixels)."""

    def _tab(ops, x, table, a):  # a one-mapping kernel: (R, G, B)
        v = a * x + 0.0 * table[0]
        return v, v, v

    tab = Method(id="tab", label="a·x with a table", kernel=_tab,
                 inputs=(Input("x", "1", "abscissa", domain=(0.0, 10.0)), Input("table", "1", "a table")),
                 params={"a": Param(1.0, -10.0, 10.0, unit="1")}, formula="a·x")  # fmt: skip
    x = np.linspace(0, 1, 10)
    cases = []
    for cid, y in (("c1", 2 * x + 1), ("c2", 3 * x)):
        c = _case(cid, x, y)
        c = FamilyCase(c.id, c.label, c.reference, c.mask, ({"x": x, "table": np.ones(37)},))
        cases.append((c, "tab", {}))
    assert pooled_fit(tab, cases) is None  # both left out: nothing to pool


def test_a_case_compares_the_pixels_its_reference_was_made_for():
    mask = np.array([[True, False, True], [False, True, False]])
    ref = AuditReference.deterministic(mask, np.array([1.0, 2.0, 3.0]), ("k",), 0.0, "q", "none", "planted")
    assert ref.mean[..., 0].tolist() == [[1.0, 0.0, 2.0], [0.0, 3.0, 0.0]]  # (row-major over the mask)
    case = FamilyCase("c", "c", ref, channel_inputs=({"x": 1.0},) * 3)
    assert case.mask is mask
    own = ~mask
    assert FamilyCase("d", "d", ref, own, ({"x": 1.0},) * 3).mask is own  # (a case's own mask is kept)
    bare = AuditReference(ref.mean, ref.stderr, 1, 1, 1, "k", "", 0.0, "q", "none", "planted")
    with pytest.raises(AuditError, match=r"^e: no mask"):
        FamilyCase("e", "e", bare, channel_inputs=({"x": 1.0},) * 3)


def _scaled(ops, x, s, a, b):
    return a * x * s + b


def _indexed(ops, x, s, a, b):  # not elementwise: reads each element's place in the array
    return a * x * s + b * np.arange(np.size(x * s)) / np.size(x * s)


@pytest.mark.parametrize("kernel", [_scaled, _indexed])
def test_a_per_channel_fit_computes_shared_inputs_once_where_the_kernel_is_elementwise(kernel):
    """`fit_data` ``stacked`` passes an input the three channels share once (n,), the others (3, n);
    `fit_case` fits on it only where the kernel gives there the concatenation's values (`stacked_agrees`):
    an elementwise kernel does, one reading each element's place in the array does not. Either way the
    values are the least-squares solution of the concatenated model (`lstsq`, computed here), within the
    fits' stop."""
    from rtfit.experiments.audit_fit import fit_data, stacked_agrees

    rng = np.random.default_rng(11)
    n = 20
    x = rng.uniform(0.5, 4.0, n)
    mean = rng.uniform(0.5, 8.0, (1, n, 3))
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    inputs = tuple({"x": x.copy(), "s": float(c + 1)} for c in range(3))  # x: equal values, not one object
    method = Method(id="m", label="m", kernel=kernel, inputs=(Input("x"), Input("s")),
                    params={"a": Param(1.0, -10.0, 10.0), "b": Param(0.0, -10.0, 10.0)})  # fmt: skip
    case = FamilyCase("c", "c", ref, np.ones((1, n), bool), inputs)
    stacked, flat = fit_data(method, case, "m", stacked=True), fit_data(method, case, "m")
    assert stacked.inputs["x"].shape == (n,) and stacked.inputs["s"].shape == (3, n)
    assert stacked.target.shape == (3, n) and flat.target.shape == (3 * n,)
    assert stacked_agrees(method, flat, stacked) == (kernel is _scaled)
    got = fit_case(method, case, "m")["parameters"]
    s = np.repeat([1.0, 2.0, 3.0], n)
    col_b = np.ones(3 * n) if kernel is _scaled else np.arange(3 * n) / (3 * n)
    A = np.stack([np.tile(x, 3) * s, col_b], axis=1)
    expected = np.linalg.lstsq(A, mean[0].T.reshape(-1), rcond=None)[0]
    for k, e in zip("ab", expected, strict=True):  # (the fits stop within 1e-2 of a stderr: `noise_ftol`)
        assert abs(got[k]["value"] - e) <= 0.02 * got[k]["stderr"]


def test_a_drjit_fit_of_a_per_channel_case_runs_shared_inputs_once_with_the_concatenations_values(
    monkeypatch,
):
    """A Dr.Jit fit (`Method.fit_ops` "drjit") of an elementwise kernel runs on the stacked data too (the
    (3, n) inputs as Dr.Jit's ``Array3f64``: `rtfit.fitting.drjit_run.drjit_input`): the same fit, bit for
    bit, as on the concatenated channels (`stacked_agrees` off), and the least-squares solution."""
    import rtfit.experiments.audit_fit as audit_fit
    from rtfit.experiments.audit_fit import fit_data, stacked_agrees

    rng = np.random.default_rng(12)
    n = 24
    x = rng.uniform(0.5, 4.0, n)
    mean = rng.uniform(0.5, 8.0, (1, n, 3))
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    inputs = tuple({"x": x.copy(), "s": float(c + 1)} for c in range(3))
    method = Method(id="m", label="m", kernel=_scaled, inputs=(Input("x"), Input("s")),
                    params={"a": Param(1.0, -10.0, 10.0), "b": Param(0.0, -10.0, 10.0)},
                    fit_ops="drjit")  # fmt: skip
    case = FamilyCase("c", "c", ref, np.ones((1, n), bool), inputs)
    assert stacked_agrees(method, fit_data(method, case, "m"), fit_data(method, case, "m", stacked=True))
    stacked = fit_case(method, case, "m")
    monkeypatch.setattr(audit_fit, "stacked_agrees", lambda *a: False)
    flat = fit_case(method, case, "m")
    assert stacked == flat
    s = np.repeat([1.0, 2.0, 3.0], n)
    A = np.stack([np.tile(x, 3) * s, np.ones(3 * n)], axis=1)
    expected = np.linalg.lstsq(A, mean[0].T.reshape(-1), rcond=None)[0]
    for k, e in zip("ab", expected, strict=True):
        assert abs(stacked["parameters"][k]["value"] - e) <= 0.02 * stacked["parameters"][k]["stderr"]


def _channel_scales(ops, channel, x, s_r, s_g, s_b, leak):
    """s_c·x on channel c (exact Lagrange picks), plus ``leak``·s_g on every channel (0: none)."""
    c = channel
    s = s_r * (c - 1.0) * (c - 2.0) * 0.5 - s_g * c * (c - 2.0) + s_b * c * (c - 1.0) * 0.5
    return s * x + leak * s_g


@pytest.mark.parametrize("leak", [0.0, 0.1])
def test_per_channel_parameters_are_found_by_name_and_checked(leak):
    """`channel_param_rows`: parameters ``<x>_r``, ``<x>_g``, ``<x>_b`` of a stacked per-channel fit, each
    changing only its channel's values (checked at its bounds), get their channel's rows; one that changes
    another channel's values (``leak``) makes none. The fit's values are the least-squares ones either way
    (per channel: s_c = Σ x y_c / Σ x², computed here)."""
    from rtfit.experiments.audit_fit import channel_param_rows, fit_data

    rng = np.random.default_rng(8)
    n = 25
    x = rng.uniform(0.5, 3.0, n)
    mean = x[None, :, None] * np.array([0.5, 1.5, 2.5]) + rng.normal(0, 0.01, (1, n, 3))
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    inputs = tuple({"channel": float(c), "x": x} for c in range(3))
    method = Method(id="cs", label="cs", kernel=_channel_scales, inputs=(Input("channel"), Input("x")),
                    params={f"s_{c}": Param(1.0, 0.0, 4.0) for c in "rgb"},
                    fixed={"leak": leak})  # fmt: skip
    case = FamilyCase("c", "c", ref, np.ones((1, n), bool), inputs)
    rows = channel_param_rows(method, fit_data(method, case, "cs", stacked=True))
    if leak:
        assert rows is None
    else:
        assert rows is not None and sorted(rows) == ["s_b", "s_g", "s_r"]
        for i, c in enumerate("rgb"):
            assert np.array_equal(rows[f"s_{c}"].reshape(3, n), np.arange(3)[:, None] == i + 0 * x)
        got = fit_case(method, case, "cs")["parameters"]
        for i, c in enumerate("rgb"):
            expected = np.sum(x * mean[0, :, i]) / np.sum(x * x)
            assert abs(got[f"s_{c}"]["value"] - expected) <= 0.02 * got[f"s_{c}"]["stderr"]
