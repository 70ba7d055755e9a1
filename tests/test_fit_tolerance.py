"""The ``"trf"`` fits' stopping rule from the noise (`method_fit.noise_ftol`) and their one BLAS thread
(`blas_threads.one_blas_thread`)."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

from rtfit.fitting import blas_threads, fit_method
from rtfit.fitting.method_fit import NOISE_KAPPA, noise_ftol
from rtfit.realtime import Input, Method, Param


def _exp_decay(ops, t, a, k):
    return a * ops.exp(-k * t)


DECAY = Method(
    "decay-test",
    "Exponential decay",
    _exp_decay,
    inputs=(Input("t", "s", "time"),),
    params={"a": Param(0.5, 0.0, 10.0, unit="1"), "k": Param(3.0, 0.01, 20.0, unit="1/s")},
)


@pytest.mark.parametrize("sigma", [1e-3, 3e-2])
def test_trf_stops_within_kappa_stderr_of_the_optimum(sigma):
    """Noisy data of a*exp(−k t): the fit stops within NOISE_KAPPA of each value's stderr of the optimum
    that SciPy's own TRF reaches at tolerances 1e-15 on a hand-written residual (an independent fit)."""
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 2.0, 5000)
    y = 2.0 * np.exp(-1.5 * t) + rng.normal(0.0, sigma, t.size)
    ref = least_squares(
        lambda x: x[0] * np.exp(-x[1] * t) - y,
        [0.5, 3.0],
        bounds=([0.0, 0.01], [10.0, 20.0]),
        ftol=1e-15,
        xtol=1e-15,
        gtol=1e-15,
    )
    fit = fit_method(DECAY, {"t": t}, y, solver="trf")
    assert fit.converged
    for i, k in enumerate(("a", "k")):
        assert abs(fit.values[k] - ref.x[i]) <= NOISE_KAPPA * fit.stderr[k]
    # the stderr: the textbook s·√((JᵀJ)⁻¹)ᵢᵢ at the reference optimum, J written by hand
    j = np.stack([np.exp(-ref.x[1] * t), -ref.x[0] * t * np.exp(-ref.x[1] * t)], axis=1)
    s2 = float(ref.fun @ ref.fun) / (t.size - 2)
    se = np.sqrt(s2 * np.diag(np.linalg.inv(j.T @ j)))
    assert [fit.stderr["a"], fit.stderr["k"]] == pytest.approx(se, rel=1e-4)


def test_noise_ftol_is_kappa_squared_over_dof():
    """|δᵢ|/seᵢ < √(ftol·dof) (s² = SSR/dof), so ftol = κ²/dof; with absolute σ (s² = 1), κ²/SSR."""
    assert noise_ftol(10_000, 5.0) == pytest.approx(NOISE_KAPPA**2 / 10_000)
    assert noise_ftol(0, 5.0) == pytest.approx(NOISE_KAPPA**2)
    assert noise_ftol(10_000, 400.0, absolute_sigma=True) == pytest.approx(NOISE_KAPPA**2 / 400.0)
    assert noise_ftol(10_000, 0.0, absolute_sigma=True) == 0.0


def test_one_blas_thread_sets_one_and_restores():
    """Inside the block every loaded OpenBLAS reports one thread; after it, the count it had."""
    import scipy.linalg  # noqa: F401  (loads SciPy's own OpenBLAS beside NumPy's)

    before = blas_threads.blas_thread_counts()
    assert before, "NumPy's and SciPy's OpenBLAS: their thread counts can be read"
    with blas_threads.one_blas_thread():
        assert blas_threads.blas_thread_counts() == [1] * len(before)
    assert blas_threads.blas_thread_counts() == before
    with pytest.raises(RuntimeError), blas_threads.one_blas_thread():
        raise RuntimeError("restored on an exception too")
    assert blas_threads.blas_thread_counts() == before
    with blas_threads.one_blas_thread():  # nested: the outer block's exit restores
        with blas_threads.one_blas_thread():
            pass
        assert blas_threads.blas_thread_counts() == [1] * len(before)
    assert blas_threads.blas_thread_counts() == before


def test_a_blas_loaded_inside_the_block_is_set_by_the_next_block_and_restored(monkeypatch):
    """SciPy's OpenBLAS, loaded after the outer block began (an audit's first fit), is set to one thread by
    the next block to enter and put back by the outer block's exit with the others."""
    import scipy.linalg  # noqa: F401

    paths = blas_threads._loaded_openblas()
    if len(paths) < 2:
        pytest.skip("one OpenBLAS loaded (NumPy and SciPy share it): nothing loads later")
    before = blas_threads.blas_thread_counts()
    monkeypatch.setattr(blas_threads, "_loaded_openblas", lambda: paths[:1])  # as if only NumPy's were loaded
    with blas_threads.one_blas_thread():
        monkeypatch.setattr(blas_threads, "_loaded_openblas", lambda: paths)  # then SciPy's comes
        assert blas_threads.blas_thread_counts()[1:] == before[1:]
        with blas_threads.one_blas_thread():
            pass
        assert blas_threads.blas_thread_counts() == [1] * len(before)  # and stays so in the outer block
    assert blas_threads.blas_thread_counts() == before


def test_one_blas_thread_by_default_keeps_a_users_setting(monkeypatch):
    """A command's block: one thread in every loaded OpenBLAS and ``OPENBLAS_NUM_THREADS=1`` for those loaded
    inside it, both put back after it; where the user set the variable, nothing changes."""
    import os

    import scipy.linalg  # noqa: F401

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    before = blas_threads.blas_thread_counts()
    with blas_threads.one_blas_thread_by_default():
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        assert blas_threads.blas_thread_counts() == [1] * len(before)
    assert "OPENBLAS_NUM_THREADS" not in os.environ and blas_threads.blas_thread_counts() == before
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "7")
    with blas_threads.one_blas_thread_by_default():
        assert os.environ["OPENBLAS_NUM_THREADS"] == "7" and blas_threads.blas_thread_counts() == before
    assert os.environ["OPENBLAS_NUM_THREADS"] == "7"


def test_the_openblas_scan_is_made_once_per_set_of_blas_modules(monkeypatch):
    """/proc/self/maps is read again only when NumPy's or SciPy's BLAS-loading module set changes; the kept
    paths are the fresh scan's."""
    import sys

    import scipy.linalg  # noqa: F401

    scans = []
    real = blas_threads._scan_openblas
    monkeypatch.setattr(blas_threads, "_SCANNED", {})
    monkeypatch.setattr(blas_threads, "_scan_openblas", lambda: scans.append(1) or real())
    first = blas_threads._loaded_openblas()
    assert blas_threads._loaded_openblas() == first == real() and len(scans) == 1
    monkeypatch.delitem(sys.modules, "scipy.linalg")  # another module set: scanned again
    blas_threads._loaded_openblas()
    assert len(scans) == 2


def _per_channel(ops, channel, t, k, s_r, s_g, s_b):
    """s_c · e^{−k t} on channel c's elements (channel ∈ {0, 1, 2}, Lagrange weights: exact picks)."""
    c = channel
    s = s_r * (c - 1.0) * (c - 2.0) * 0.5 - s_g * c * (c - 2.0) + s_b * c * (c - 1.0) * 0.5
    return s * ops.exp(-k * t)


def _per_channel_data(seed: int, n: int):
    """(t, channel, y, parameter box) of `_per_channel` data: n times a channel, s = (1, 2, 0.5), k = 1.5,
    noise σ = 0.01."""
    rng = np.random.default_rng(seed)
    t = np.tile(rng.uniform(0.0, 2.0, n), 3)
    channel = np.repeat([0.0, 1.0, 2.0], n)
    y = np.repeat([1.0, 2.0, 0.5], n) * np.exp(-1.5 * t) + rng.normal(0.0, 0.01, 3 * n)
    box = {"k": Param(1.0, 0.0, 5.0), **{f"s_{c}": Param(1.0, 0.0, 4.0) for c in "rgb"}}
    return t, channel, y, box


def test_grouped_differences_give_scipys_jacobian_with_fewer_evaluations(monkeypatch):
    """Parameters declared to change disjoint residuals (`fit_method` ``param_rows``: s_r, s_g, s_b, one
    channel each) share the central-difference Jacobian's evaluations (`grouped_differences`): the fit
    evaluates the kernel fewer times, and ends where SciPy's own Jacobian (no grouping) ends, bit for bit."""
    import inspect

    from scipy.optimize._numdiff import approx_derivative

    from rtfit.fitting import difference_maps
    from rtfit.fitting.difference_maps import grouped_differences

    if "workers" not in inspect.signature(least_squares).parameters:
        pytest.skip("this SciPy's least_squares takes no workers map (the fits run ungrouped)")
    monkeypatch.setattr(difference_maps, "BATCH_ELEMENTS", 0)  # a kernel call a point: the calls counted

    t, channel, y, box = _per_channel_data(seed=4, n=30)
    calls = []
    method = Method("pc", "per channel", lambda ops, **kw: calls.append(1) or _per_channel(ops, **kw),
                    inputs=(Input("channel"), Input("t")), params=box)  # fmt: skip
    rows = {f"s_{c}": channel == i for i, c in enumerate("rgb")}
    inputs = {"channel": channel, "t": t}
    fits = []
    for declared in (None, rows):
        calls.clear()
        fits.append((fit_method(method, inputs, y, solver="trf", param_rows=declared), len(calls)))
    (plain, n_plain), (grouped, n_grouped) = fits
    assert plain.values == grouped.values and plain.stderr == grouped.stderr and plain.ssr == grouped.ssr
    assert n_grouped < 0.75 * n_plain  # 4 evaluations a Jacobian, not 8

    # One Jacobian against SciPy's dense differences, at a point near a bound (one-sided steps there).
    def residual(v):
        return _per_channel(np, channel, t, *v) - y

    x = np.array([0.3, 4.0 - 1e-9, 2.0, 1e-7])
    centre = {x.tobytes(): residual(x)}
    workers = grouped_differences([None, *(rows[f"s_{c}"] for c in "rgb")], centre)
    assert workers is not None
    bounds = ([0.0] * 4, [5.0, 4.0, 4.0, 4.0])
    dense = approx_derivative(residual, x, method="3-point", bounds=bounds)
    shared = approx_derivative(residual, x, method="3-point", bounds=bounds, workers=workers)
    assert dense.tobytes() == shared.tobytes()


def test_threaded_differences_give_the_serial_fit_bit_for_bit(monkeypatch):
    """A NumPy fit of `difference_maps.PARALLEL_FROM` residuals or more evaluates its Jacobian's points on
    threads (`difference_map`, issue 33): each point alone, so the fit ends where the serial fit ends, bit for
    bit, grouped (`param_rows`) or not; smaller fits, and Dr.Jit fits, get no threads."""
    import inspect

    from rtfit.fitting import difference_maps

    if "workers" not in inspect.signature(least_squares).parameters:
        pytest.skip("this SciPy's least_squares takes no workers map (the fits run serially)")
    assert difference_maps.difference_map(difference_maps.PARALLEL_FROM - 1, "numpy") is None
    assert difference_maps.difference_map(difference_maps.PARALLEL_FROM, "drjit") is None
    monkeypatch.setattr(difference_maps, "_threads", lambda: 2)
    monkeypatch.setattr(difference_maps, "BATCH_ELEMENTS", 0)  # a call a point where no thread runs
    assert difference_maps.difference_map(difference_maps.PARALLEL_FROM, "numpy") is not None

    t, channel, y, box = _per_channel_data(seed=9, n=24)
    threads = []

    def kernel(ops, **kw):
        threads.append(threading.get_ident())
        return _per_channel(ops, **kw)

    method = Method("pc", "per channel", kernel, inputs=(Input("channel"), Input("t")), params=box)
    rows = {f"s_{c}": channel == i for i, c in enumerate("rgb")}
    inputs = {"channel": channel, "t": t}
    for declared in (None, rows):
        monkeypatch.setattr(difference_maps, "PARALLEL_FROM", 10**9)  # serial
        serial = fit_method(method, inputs, y, solver="trf", param_rows=declared)
        monkeypatch.setattr(difference_maps, "PARALLEL_FROM", 1)  # threaded
        threads.clear()
        threaded = fit_method(method, inputs, y, solver="trf", param_rows=declared)
        assert len(set(threads)) > 1  # the points did run on other threads
        assert threaded.values == serial.values and threaded.stderr == serial.stderr
        assert threaded.ssr == serial.ssr and threaded.steps == serial.steps


def test_a_value_a_bound_holds_gives_no_gauss_newton_gain():
    """`held_at_bounds`: a value at its bound whose descent −Jᵀr points out of the box is held; one at its
    bound with the descent pointing inward, an interior one and an infinite bound are not. The gain check
    (`gauss_newton_gain_small`) left to the free columns: r lies along the held column alone, so the
    unbounded step's gain (‖r‖², huge against s²) is not there to take."""
    from rtfit.fitting.method_fit import gauss_newton_gain_small, held_at_bounds

    n = 1000
    rng = np.random.default_rng(3)
    j = np.stack([np.ones(n), rng.standard_normal(n)], axis=1)
    j[:, 1] -= j[:, 1].mean()  # orthogonal columns
    r = -np.ones(n)  # −Jᵀr = (n, 0): descent pushes column 0 up
    lo, hi = np.array([0.0, -np.inf]), np.array([4.0, np.inf])
    assert held_at_bounds([4.0, 0.3], lo, hi, j, r).tolist() == [True, False]  # pushed out through 4
    assert held_at_bounds([0.0, 0.3], lo, hi, j, r).tolist() == [False, False]  # pushed inward from 0
    assert held_at_bounds([2.0, 0.3], lo, hi, j, r).tolist() == [False, False]
    assert held_at_bounds([4.0 - 1e-7, 0.3], lo, hi, j, r).tolist() == [True, False]  # within 1e-6 · 4
    dof = n - 2
    assert not gauss_newton_gain_small(j, r, dof)
    assert gauss_newton_gain_small(j, r, dof, free=[False, True])
    assert gauss_newton_gain_small(j, r, dof, free=[False, False])


def _line(ops, t, a, b):
    return a * t + b


LINE = Method(
    "line-test",
    "A line",
    _line,
    inputs=(Input("t", "1", "abscissa"),),
    params={"a": Param(0.5, 0.0, 1.0, unit="1"), "b": Param(0.0, -5.0, 5.0, unit="1")},
)


def test_a_fit_held_at_its_bound_is_solved_once(monkeypatch):
    """y = 3 t + 1 + noise fitted with a ≤ 1: a stops at its bound. The unbounded Gauss–Newton step would
    still gain (it moves a past 1), so before session 23 the fit always went on at the fixed tolerance, a
    second solve that moved nothing; now TRF runs once and the values are those of SciPy's TRF at
    tolerances 1e-15 (an independent fit of the same residual)."""
    import scipy.optimize

    rng = np.random.default_rng(11)
    t = np.linspace(0.0, 1.0, 4000)
    y = 3.0 * t + 1.0 + rng.normal(0.0, 0.01, t.size)
    solves = []
    real = scipy.optimize.least_squares
    monkeypatch.setattr(scipy.optimize, "least_squares", lambda *a, **k: solves.append(1) or real(*a, **k))
    fit = fit_method(LINE, {"t": t}, y, solver="trf")
    assert len(solves) == 1 and fit.at_bound["a"] and not fit.at_bound["b"]
    ref = real(lambda x: x[0] * t + x[1] - y, [0.5, 0.0], bounds=([0.0, -5.0], [1.0, 5.0]), ftol=1e-15,
               xtol=1e-15, gtol=1e-15)  # fmt: skip
    assert fit.values["a"] == pytest.approx(ref.x[0], abs=1e-6) and fit.values["b"] == pytest.approx(
        ref.x[1], abs=1e-4
    )


def test_fd_step_fits_a_staircase_that_the_default_step_leaves_at_its_start():
    """An AO radius fitted to AO data: W = (1/K) Σ_k [d_k ≥ r] is a staircase in r (a step at each of the
    N·K sampled distances). SciPy's default central difference (±6e-6 r) mostly falls between two steps:
    the fit stays near its start. With `Param.fd_step` 1e-2 the difference spans ~10² steps and the fit
    reaches the brute-force optimum (SSR over a grid of 4001 radii, computed here in NumPy) within 1 % of r
    and 1 % of the SSR."""
    from rtfit.realtime.obscurances import METHODS as OBSCURANCE

    rng = np.random.default_rng(3)
    n, k = 4000, 16
    d = rng.exponential(1.0, (n, k))
    truth = 0.7
    y = np.mean(d >= truth, axis=1) + rng.normal(0.0, 0.02, n)
    inputs = {"distances": np.ascontiguousarray(d.T)}  # (K, N): the rays along the first axis
    method = OBSCURANCE["ao"]
    assert method.params["d_max"].fd_step == 1e-2
    start = Param(1.2, 1e-3, 1e3)
    radii = np.linspace(0.3, 1.5, 4001)
    ssr = np.array([np.sum((np.mean(d >= r, axis=1) - y) ** 2) for r in radii])
    best = radii[np.argmin(ssr)]

    def ssr_at(r):
        return float(np.sum((np.mean(d >= r, axis=1) - y) ** 2))

    stepped = fit_method(method, inputs, y, params={"d_max": replace(start, fd_step=1e-2)}, solver="trf")
    assert abs(stepped.values["d_max"] - best) <= 0.01 * best
    assert ssr_at(stepped.values["d_max"]) <= 1.01 * ssr.min()
    plain = fit_method(method, inputs, y, params={"d_max": start}, solver="trf")
    assert ssr_at(plain.values["d_max"]) > 1.5 * ssr.min()  # the default step: far from the optimum


@pytest.mark.parametrize("bad", [-0.1, 1.0, True, float("nan")])
def test_fd_step_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="fd_step"):
        Param(1.0, 0.0, 2.0, fd_step=bad)


def test_fd_step_with_log_is_refused():
    with pytest.raises(ValueError, match="fd_step"):
        Param(1.0, 0.0, 2.0, fd_step=1e-2, log=True)


def test_a_trf_fit_evaluates_its_start_once():
    """`fit_method` (TRF) checks the residuals at the start, then SciPy asks for them again: the kernel runs
    once at the start (issue 33: one kernel evaluation of every fit, ~2 % of a 256² audit's fit calls)."""
    seen = []

    def kernel(ops, x, a=1.0, b=0.0):
        seen.append((float(a), float(b)))
        return a * ops.exp(-b * x)

    method = Method("decay", "decay", kernel, inputs=(Input("x"),),
                    params={"a": Param(1.0, 0.0, 10.0), "b": Param(0.1, 0.0, 10.0)})  # fmt: skip
    x = np.linspace(0.0, 3.0, 1000)
    y = 2.0 * np.exp(-0.7 * x) + np.random.default_rng(1).normal(0.0, 0.01, x.size)
    fit = fit_method(method, {"x": x}, y, solver="trf")
    assert seen.count((1.0, 0.1)) == 1
    assert fit.values["a"] == pytest.approx(2.0, abs=0.01) and fit.values["b"] == pytest.approx(0.7, abs=0.01)


def _mixing(ops, channel, t, k, s_r, s_g, s_b):
    """`_per_channel` less its mean over every element: not elementwise (a batch's points mixed)."""
    v = _per_channel(ops, channel, t, k, s_r, s_g, s_b)
    return v - np.mean(v) + np.mean(_per_channel(ops, channel, t, 1.5, 1.0, 2.0, 0.5))


def _numbered(ops, channel, t, k, s_r, s_g, s_b):
    """`_per_channel` with its rate read as a number (a batch's array of rates cannot be)."""
    return _per_channel(ops, channel, t, float(k), s_r, s_g, s_b)


def _reduced(ops, channel, t, k, s_r, s_g, s_b):
    """`_per_channel` on a 2-D input whose first axis it reduces: one point's shape, not a batch's."""
    return _per_channel(ops, channel, np.stack([t, t]), k, s_r, s_g, s_b).mean(axis=0)


@pytest.mark.parametrize("grouped", [False, True])
def test_batched_points_give_the_fit_of_a_call_a_point_bit_for_bit(monkeypatch, grouped):
    """A NumPy fit may evaluate its Jacobian's points in one call of the kernel, each fitted parameter an
    array over the points (`batched_points`, `point_batch`; issue 33): its first Jacobian runs a call a point,
    its second batched, and the faster way runs the rest. Either way the fit ends where the fit of a call a
    point ends, bit for bit (values, stderr, SSR, steps), grouped or not. A kernel whose batched run is not
    its run at one point falls back to a call a point and ends there too: one that mixes the points keeping
    the shapes (caught by the centre evaluated again in each batch), one that reads a parameter as a number
    (an exception), one that reduces an axis (the shape). Here a call a point is made slow (2 ms, a sleep) so
    that batches are faster; a kernel whose batches are slower (a 50 ms sleep) goes back to a call a point."""
    import inspect
    import time

    from rtfit.fitting import difference_maps

    if "workers" not in inspect.signature(least_squares).parameters:
        pytest.skip("this SciPy's least_squares takes no workers map (the fits run serially)")
    t, channel, y, box = _per_channel_data(seed=11, n=40)
    rows = {f"s_{c}": channel == i for i, c in enumerate("rgb")} if grouped else None
    inputs = {"channel": channel, "t": t}
    texts = ((_per_channel, True, 0.002), (_mixing, False, 0.002), (_numbered, False, 0.002),
             (_reduced, False, 0.002), (_per_channel, False, 0.0))  # fmt: skip
    calls: list[bool] = []
    for text, batches, serial_sleep in texts:

        def kernel(ops, _text=text, _sleep=serial_sleep, **kw):
            batch = np.ndim(kw["k"]) > 0
            calls.append(batch)
            time.sleep(0.05 if batch and not _sleep else 0.0 if batch else _sleep)
            return _text(ops, **kw)

        method = Method("pc", "per channel", kernel, inputs=(Input("channel"), Input("t")), params=box)
        monkeypatch.setattr(difference_maps, "BATCH_ELEMENTS", 0)
        calls.clear()
        serial = fit_method(method, inputs, y, solver="trf", param_rows=rows)
        n_serial = len(calls)
        monkeypatch.setattr(difference_maps, "BATCH_ELEMENTS", 1 << 16)
        calls.clear()
        batched = fit_method(method, inputs, y, solver="trf", param_rows=rows)
        assert batched.values == serial.values and batched.stderr == serial.stderr, text.__name__
        assert batched.ssr == serial.ssr and batched.steps == serial.steps
        if batches:
            assert len(calls) < 0.75 * n_serial and sum(calls) > 1  # whole Jacobians a call
        else:
            assert sum(calls) <= 1  # one batch tried, then a call a point
