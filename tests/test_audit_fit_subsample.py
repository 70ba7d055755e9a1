"""A large case's fit started on a deterministic subsample of its pixels and polished on all of them
(`rtfit.experiments.audit_fit.fit_case`,
`fit_subsample`, `FIT_PIXELS`): checked against the closed-form least-squares solution of a linear model with
known truth and noise (`numpy.linalg.lstsq`, computed here on all pixels and on the subsample's), the
subsample's stderr against the full fit's × √(N/n), small cases fitted on every pixel, tables passed whole and
the subsample the same at every call."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.experiments.audit_family import FamilyCase
from rtfit.experiments.audit_fit import (
    FIT_PIXELS,
    SUBSAMPLE_FROM,
    fit_case,
    fit_subsample,
    polish_params,
    subsampled_case,
)
from rtfit.experiments.audit_setup import AuditReference
from rtfit.realtime.methods import Input, Method, Param

from .test_audit_fit import LINE  # y = a·x + b

TRUTH = (2.0, 1.0)  # y = a·x + b + noise
NOISE = 0.3


def _image_case(cid: str, shape: tuple[int, int], seed: int, fraction: float = 0.8):
    """A grey per-channel case over an image ``shape`` with ~``fraction`` of its pixels masked: x uniform on
    [0, 10], each channel's reference a·x + b plus its own Gaussian noise. Returns (case, x, y (n, 3))."""
    rng = np.random.default_rng(seed)
    mask = rng.random(shape) < fraction
    n = int(mask.sum())
    x = rng.uniform(0.0, 10.0, n)
    y = TRUTH[0] * x[:, None] + TRUTH[1] + rng.normal(0.0, NOISE, (n, 3))
    mean = np.zeros((*shape, 3))
    mean[mask] = y
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    return FamilyCase(cid, cid, ref, mask, ({"x": x},) * 3), x, y


def _lstsq(x: np.ndarray, y: np.ndarray):
    """Closed-form least squares of y (n, 3) = a·x + b over the three channels: values and stderrs."""
    A = np.stack([np.tile(x, 3), np.ones(3 * len(x))], axis=1)
    t = y.T.reshape(-1)
    sol, ssr, _, _ = np.linalg.lstsq(A, t, rcond=None)
    s2 = float(ssr[0]) / (len(t) - 2)
    return sol, np.sqrt(np.diag(s2 * np.linalg.inv(A.T @ A)))


def test_a_large_case_is_started_on_its_subsample_and_polished_on_every_pixel():
    case, x, y = _image_case("large", (160, 160), seed=5)
    n = len(x)
    assert n > 2 * FIT_PIXELS
    fit = fit_case(LINE, case, "line")
    assert fit["subsample"] == {"pixels": FIT_PIXELS, "of": n}
    assert fit["n_residuals"] == 3 * n  # the polish reads every pixel
    full, full_se = _lstsq(x, y)
    for i, k in enumerate("ab"):
        got = fit["parameters"][k]
        # the full data's least squares (within the fits' stop, 1e-2 of a stderr: `noise_ftol`), its stderr
        assert abs(got["value"] - full[i]) <= 0.02 * full_se[i]
        assert abs(got["stderr"] - full_se[i]) <= 1e-3 * full_se[i]
        assert abs(got["value"] - TRUTH[i]) <= 4.0 * got["stderr"]


def test_the_subsample_fit_alone_is_the_subsamples_least_squares():
    """The first stage (the subsample's fit, `subsampled_case`): the subsample's own least-squares answer,
    its stderr √(N/n) × the full fit's (within the residual variance's spread), a few of it from the truth."""
    case, x, y = _image_case("large", (160, 160), seed=5)
    n = len(x)
    keep = fit_subsample(case)
    assert keep is not None
    fit = fit_case(LINE, subsampled_case(case, keep), "line")
    assert "subsample" not in fit and fit["n_residuals"] == 3 * FIT_PIXELS
    _, full_se = _lstsq(x, y)
    sub, sub_se = _lstsq(x[keep], y[keep])
    for i, k in enumerate("ab"):
        got = fit["parameters"][k]
        assert abs(got["value"] - sub[i]) <= 0.02 * sub_se[i]
        assert abs(got["stderr"] - sub_se[i]) <= 1e-3 * sub_se[i]
        assert abs(got["stderr"] / (full_se[i] * np.sqrt(n / FIT_PIXELS)) - 1.0) < 0.05
        assert abs(got["value"] - TRUTH[i]) <= 4.0 * got["stderr"]


def test_a_polish_starts_strictly_inside_the_bounds_without_a_scan():
    params = {
        "a": Param(1.0, 0.0, 2.0, scan=33),
        "b": Param(0.5, -math.inf, math.inf),
        "c": Param(1.0, 0.0, 5.0),
    }
    fitted = {"a": {"value": 2.0}, "b": {"value": -7.5}, "c": {"value": float("nan")}}
    out = polish_params(params, fitted)
    assert 0.0 < out["a"].initial < 2.0 and out["a"].initial == pytest.approx(2.0, abs=1e-8)
    assert out["b"].initial == -7.5 and out["c"].initial == 1.0
    assert all(p.scan == 0 for p in out.values())


def test_a_small_case_is_fitted_on_every_pixel():
    case, x, y = _image_case("small", (128, 128), seed=7, fraction=1.0)  # exactly SUBSAMPLE_FROM pixels
    assert len(x) == SUBSAMPLE_FROM and fit_subsample(case) is None
    fit = fit_case(LINE, case, "line")
    assert "subsample" not in fit and fit["n_residuals"] == 3 * SUBSAMPLE_FROM
    full, full_se = _lstsq(x, y)
    for i, k in enumerate("ab"):
        assert abs(fit["parameters"][k]["value"] - full[i]) <= 0.02 * full_se[i]
        assert abs(fit["parameters"][k]["stderr"] - full_se[i]) <= 1e-3 * full_se[i]


def test_the_subsample_is_deterministic_stratified_and_the_same_in_every_channel():
    case, x, _ = _image_case("det", (150, 150), seed=9)
    again, _, _ = _image_case("det", (150, 150), seed=9)
    other, _, _ = _image_case("other", (150, 150), seed=9)
    keep = fit_subsample(case)
    assert keep is not None and len(keep) == FIT_PIXELS
    same, moved = fit_subsample(again), fit_subsample(other)
    assert same is not None and moved is not None
    assert np.array_equal(keep, same)  # seeded by the case's id: the same at every call
    assert not np.array_equal(keep, moved)
    n = len(x)
    edges = (np.arange(FIT_PIXELS + 1) * n) // FIT_PIXELS  # one position in each run of consecutive pixels
    assert np.all((keep >= edges[:-1]) & (keep < edges[1:]))
    sub = subsampled_case(case, keep)
    assert sub is not None and int(sub.mask.sum()) == FIT_PIXELS
    assert np.array_equal(np.flatnonzero(sub.mask), np.flatnonzero(case.mask)[keep])
    for inp in sub.channel_inputs:  # the same pixels in every channel, indexed once (one shared array)
        assert inp["x"] is sub.channel_inputs[0]["x"]
        assert np.array_equal(inp["x"], x[keep])


def _rgb_offsets(ops, x, t, a, b):
    """One mapping, (R, G, B): a·x + b·t[c], t a table of three offsets (not one value per pixel)."""
    return tuple(a * x + b * t[c] for c in range(3))


def test_tables_are_passed_whole():
    rng = np.random.default_rng(13)
    shape = (150, 150)  # > SUBSAMPLE_FROM pixels
    mask = np.ones(shape, bool)
    n = mask.size
    x = rng.uniform(0.0, 10.0, n)
    t = np.array([0.5, 1.0, 2.0])
    y = TRUTH[0] * x[:, None] + TRUTH[1] * t[None, :] + rng.normal(0.0, NOISE, (n, 3))
    ref = AuditReference(
        y.reshape(*shape, 3), np.full((*shape, 3), 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted"
    )
    method = Method(id="rgb", label="rgb", kernel=_rgb_offsets, inputs=(Input("x"), Input("t")),
                    params={"a": Param(1.0, -10.0, 10.0), "b": Param(0.0, -10.0, 10.0)})  # fmt: skip
    case = FamilyCase("tabled", "tabled", ref, mask, ({"x": x, "t": t},))
    keep = fit_subsample(case)
    assert keep is not None
    sub = subsampled_case(case, keep)
    assert sub is not None and sub.channel_inputs[0]["t"] is t
    fit = fit_case(method, case, "rgb")
    assert fit["subsample"] == {"pixels": FIT_PIXELS, "of": n}
    A = np.stack([np.tile(x, 3), np.repeat(t, n)], axis=1)  # the polish: every pixel, the table whole
    sol = np.linalg.lstsq(A, y.T.reshape(-1), rcond=None)[0]
    for i, k in enumerate("ab"):
        got = fit["parameters"][k]
        assert abs(got["value"] - sol[i]) <= 0.02 * got["stderr"]


def _per_channel_offsets(ops, x, channel, a=1.0, b_r=0.0, b_g=0.0, b_b=0.0):
    """a·x + b_c in channel c (``channel``: 0, 1, 2 per pixel): one slope, one offset per channel (the
    layout of colour-bleeding's SDF biases)."""
    return a * x + ops.select(channel < 0.5, b_r, ops.select(channel < 1.5, b_g, b_b))


def test_the_channel_layout_is_checked_once_on_the_subsample_and_kept_for_the_polish(monkeypatch):
    """A per-channel case with per-channel parameters ``b_r``, ``b_g``, ``b_b``: whether its channels are
    stacked (`stacked_agrees`) and which parameters own which rows (`channel_param_rows`) are checked once,
    on the subsample's data, and the polish on every pixel uses that layout (issue 33: the checks evaluated
    the kernel ~8 times on every pixel); the fit is the closed-form least squares (a shared, b a channel)."""
    import rtfit.experiments.audit_fit as AF

    rng = np.random.default_rng(17)
    shape = (160, 160)
    mask = rng.random(shape) < 0.8
    n = int(mask.sum())
    x = rng.uniform(0.0, 10.0, n)
    offsets = np.array([0.5, 1.0, 2.0])
    y = TRUTH[0] * x[:, None] + offsets + rng.normal(0.0, NOISE, (n, 3))
    mean = np.zeros((*shape, 3))
    mean[mask] = y
    ref = AuditReference(mean, np.full_like(mean, 0.01), 16, 1, 1, "k", "p", 0.0, "q", "none", "planted")
    inputs = tuple({"x": x, "channel": np.full(n, float(c))} for c in range(3))
    case = FamilyCase("layout", "layout", ref, mask, inputs)
    params = {"a": Param(1.0, -10.0, 10.0), **{f"b_{c}": Param(0.0, -10.0, 10.0) for c in "rgb"}}
    method = Method(
        id="offsets", label="offsets", kernel=_per_channel_offsets, inputs=(Input("x"), Input("channel")),
        params=params,
    )  # fmt: skip
    calls = {"stacked_agrees": 0, "channel_param_rows": 0}
    for name in calls:
        real = getattr(AF, name)
        monkeypatch.setattr(
            AF, name, lambda *a, _r=real, _n=name: calls.__setitem__(_n, calls[_n] + 1) or _r(*a)
        )
    fit = fit_case(method, case, "offsets")
    assert fit["subsample"] == {"pixels": FIT_PIXELS, "of": n}
    assert calls == {"stacked_agrees": 1, "channel_param_rows": 1}
    A = np.zeros((3 * n, 4))
    A[:, 0] = np.tile(x, 3)
    for c in range(3):
        A[c * n : (c + 1) * n, 1 + c] = 1.0
    sol = np.linalg.lstsq(A, y.T.reshape(-1), rcond=None)[0]
    for i, k in enumerate(("a", "b_r", "b_g", "b_b")):
        got = fit["parameters"][k]
        assert abs(got["value"] - sol[i]) <= 0.02 * got["stderr"]
