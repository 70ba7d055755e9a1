"""rtfit.fitting.metrics against hand-computed values, closed forms and the libraries called directly.

Statistical tolerances are stated where they are used: k standard deviations of the quantity's own
sampling distribution for the sample size at hand (k = 5 unless noted), with fixed seeds."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from rtfit.fitting import (
    ALL_METRICS,
    FLIP_MIN_SIZE,
    SSIM_MIN_SIZE,
    MetricValue,
    compute_metrics,
    smape,
    tone_map,
    z_score_summary,
    z_scores,
)


def _smooth_image(h=64, w=64, seed=0):
    """A smooth positive HDR-ish image (values 0.2 … 3) with a bright square."""
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    img = np.stack([0.2 + xx, 0.3 + 0.5 * yy, 0.7 + 0.2 * xx * yy], axis=-1)
    img[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3] *= 3.0
    return img


# ------------------------------------------------------------------------------- hand-built values
X = np.array([1.0, 2.0])
R = np.array([1.0, 4.0])
S = np.array([0.1, 0.2])


def test_rmse_hand_value():
    m = compute_metrics(X, R, S, names=("rmse",))["rmse"]
    assert m.value == pytest.approx(math.sqrt(2.0), rel=1e-14)  # d = (0, −2): mse = 4/2
    floor = math.sqrt((0.01 + 0.04) / 2)
    assert m.noise_floor == pytest.approx(floor, rel=1e-14)
    assert m.debiased == pytest.approx(math.sqrt(2.0 - floor**2), rel=1e-14)
    assert m.resolved is True


def test_rel_mse_formula():
    m = compute_metrics(X, R, S, names=("rel_mse",))["rel_mse"]
    assert m.value == pytest.approx((0.0 / 1.01 + 4.0 / 16.01) / 2, rel=1e-14)
    floor = (0.01 / 1.01 + 0.04 / 16.01) / 2
    assert m.noise_floor == pytest.approx(floor, rel=1e-14)
    assert m.debiased == pytest.approx(m.value - floor, rel=1e-14)


def test_mae_and_max_abs():
    m = compute_metrics(X, R, S, names=("mae", "max_abs"))
    assert m["mae"].value == pytest.approx(1.0)  # (0 + 2)/2
    assert m["mae"].noise_floor == pytest.approx(math.sqrt(2 / math.pi) * 0.15, rel=1e-14)
    assert m["mae"].debiased is None
    assert m["max_abs"].value == pytest.approx(2.0)
    assert m["max_abs"].debiased is None


def test_psnr_peak_is_max_of_masked_reference():
    m = compute_metrics(X, R, S, names=("psnr",))["psnr"]
    assert m.value == pytest.approx(10 * math.log10(16.0 / 2.0), rel=1e-14)  # peak 4, mse 2
    assert m.noise_floor == pytest.approx(10 * math.log10(16.0 / 0.025), rel=1e-14)  # ceiling
    assert m.resolved is True
    # Masking the 4 out: peak 1, mse 0 → PSNR = +inf, which to_dict() writes as null.
    m2 = compute_metrics(X, R, S, mask=np.array([True, False]), names=("psnr",))["psnr"]
    assert m2.value == math.inf and m2.resolved is False
    assert m2.noise_floor == pytest.approx(10 * math.log10(1.0 / 0.01))
    assert m2.to_dict()["value"] is None


def test_mask_selects_pixels_and_all_their_channels():
    ref = np.zeros((2, 2, 2))
    ap = ref.copy()
    ap[0, 0] = [3.0, 4.0]  # in the mask
    ap[1, 1] = [100.0, 100.0]  # masked out
    mask = np.array([[True, True], [True, False]])
    m = compute_metrics(ap, ref, np.zeros_like(ref), mask=mask, names=("rmse", "mae", "max_abs"))
    assert m["rmse"].value == pytest.approx(math.sqrt((9 + 16) / 6))  # 3 pixels × 2 channels
    assert m["mae"].value == pytest.approx(7 / 6)
    assert m["max_abs"].value == pytest.approx(4.0)
    assert m["rmse"].noise_floor == 0.0 and m["rmse"].resolved is True


def test_smape_hand_value_and_zero_over_zero():
    v = smape(np.array([1.0, 3.0, 0.0]), np.array([1.0, 1.0, 0.0]), np.zeros(3))
    assert v.value == pytest.approx((0.0 + 2.0 / 4.0 + 0.0) / 3)  # 0/0 counts as 0
    assert v.noise_floor == 0.0 and v.resolved is True
    assert "smape" not in ALL_METRICS


def test_rel_mse_resolved_rule_is_2x_in_amplitude():
    # Uniform r = 1, σ = 0.1: floor = 0.01/1.01. An error of 1.9σ is below 2× in amplitude (3.61× in
    # rel_mse) → unresolved; 2.1σ (4.41×) → resolved. rmse makes the same decisions.
    r = np.ones(1000)
    s = np.full(1000, 0.1)
    for k, expect in ((1.9, False), (2.1, True)):
        m = compute_metrics(r + k * 0.1, r, s, names=("rmse", "rel_mse", "psnr"))
        assert (m["rel_mse"].resolved, m["rmse"].resolved, m["psnr"].resolved) == (expect,) * 3


# ---------------------------------------------------------------------------------------- SSIM
def test_tone_map():
    assert tone_map(np.array([0.0, 1.0, 3.0, -1.0])).tolist() == [0.0, 0.5, 0.75, -0.5]


def test_ssim_identical_is_one():
    img = _smooth_image(32, 32)
    m = compute_metrics(img, img, np.zeros_like(img), names=("ssim",))["ssim"]
    assert m.value == pytest.approx(1.0, abs=1e-12)
    assert m.noise_floor == pytest.approx(1.0, abs=1e-12)
    assert m.resolved is False


def test_ssim_matches_scikit_image_on_the_tone_map():
    from skimage.metrics import structural_similarity

    rng = np.random.default_rng(3)
    ref = _smooth_image(40, 48)
    ap = ref * (1 + 0.2 * rng.standard_normal(ref.shape)) + 0.1
    mask = np.zeros(ref.shape[:2], bool)
    mask[5:30, 10:40] = True
    _, smap = structural_similarity(
        ref / (1 + ref),
        ap / (1 + ap),
        data_range=1.0,
        channel_axis=-1,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        full=True,
    )
    expect = smap[mask].mean()
    m = compute_metrics(ap, ref, np.full(ref.shape, 0.01), mask=mask, names=("ssim",))["ssim"]
    assert m.value == pytest.approx(expect, rel=1e-12)
    assert m.value < 0.95 and m.resolved is True


# ---------------------------------------------------------------------------------------- FLIP
FLIP_CODE_TOL = 1e-4
"""|our ꟻLIP map − flip_evaluator's| per pixel (tests/test_hdr_flip.py states why)."""


def test_flip_identical_is_zero():
    img = _smooth_image(32, 32)
    m = compute_metrics(img, img, np.zeros_like(img), names=("flip",))["flip"]
    assert m.value == 0.0 and m.noise_floor == 0.0 and m.resolved is False


def test_flip_without_mask_equals_flip_evaluator_defaults():
    import flip_evaluator

    rng = np.random.default_rng(5)
    ref = _smooth_image(48, 40).astype(np.float32)
    ap = (ref * rng.uniform(0.8, 1.3, ref.shape)).astype(np.float32)
    _, mean, _ = flip_evaluator.evaluate(ref, ap, "HDR", applyMagma=False)
    m = compute_metrics(ap, ref, np.zeros_like(ref), names=("flip",))["flip"]
    assert m.value == pytest.approx(mean, abs=FLIP_CODE_TOL)  # float64 here, float32 there
    assert m.value > 0.01 and m.resolved is True


def test_flip_survives_a_constant_reference():
    # flip_evaluator's own exposure rule gives start == stop here and calls sys.exit(1).
    ref = np.full((FLIP_MIN_SIZE, FLIP_MIN_SIZE, 3), 0.5)
    m = compute_metrics(ref * 1.2, ref, np.zeros_like(ref), names=("flip",))["flip"]
    assert 0.0 < m.value < 1.0


def test_flip_clips_negative_values_and_warns():
    ref = _smooth_image(32, 32)
    ap = ref - 1.0  # partly negative
    with pytest.warns(RuntimeWarning, match="clipped to 0"):
        m = compute_metrics(ap, ref, np.zeros_like(ref), names=("flip",))["flip"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m_clipped = compute_metrics(np.maximum(ap, 0.0), ref, np.zeros_like(ref), names=("flip",))["flip"]
    assert m.value == m_clipped.value


def test_inapplicable_metrics_are_skipped_with_reasons():
    pts = np.ones((10, 3))
    m = compute_metrics(pts, pts, np.zeros_like(pts))
    assert set(m) == {"rmse", "rel_mse", "mae", "max_abs", "psnr"}
    assert "point set" in m.skipped["ssim"] and "point set" in m.skipped["flip"]
    small = np.ones((SSIM_MIN_SIZE - 1, 30, 3))
    m = compute_metrics(small, small, np.zeros_like(small))
    assert "ssim" in m.skipped and "flip" in m.skipped and "rmse" in m
    two = np.ones((32, 32, 2))
    m = compute_metrics(two, two, np.zeros_like(two), names=("ssim", "flip"))
    assert "ssim" in m and "3 colour channels" in m.skipped["flip"]
    black = np.zeros((32, 32, 3))
    m = compute_metrics(black + 0.1, black, np.zeros_like(black), names=("psnr", "flip"))
    assert set(m.skipped) == {"psnr", "flip"}
    assert list(compute_metrics(X, R, S, names=("psnr", "rmse"))) == ["psnr", "rmse"]  # requested order


def test_to_dict_is_json_ready():
    img = _smooth_image(32, 32)
    m = compute_metrics(img * 1.1, img, np.full(img.shape, 0.01))
    doc = json.loads(json.dumps(m.to_dict(), allow_nan=False))
    assert list(doc) == list(ALL_METRICS)
    assert set(doc["rmse"]) == {"value", "noise_floor", "resolved", "debiased"}
    assert MetricValue(1.0, 0.5, True).to_dict() == {
        "value": 1.0,
        "noise_floor": 0.5,
        "resolved": True,
        "debiased": None,
    }


# ---------------------------------------------------------------------------------- noise floors
def _truth_and_reference(seed=1, h=64, w=64):
    rng = np.random.default_rng(seed)
    truth = _smooth_image(h, w)
    sigma = 0.02 + 0.03 * rng.uniform(size=truth.shape)  # known, varying per element
    ref = truth + sigma * rng.standard_normal(truth.shape)
    return truth, ref, sigma


def test_analytic_floors_match_measured_noise():
    truth, ref, sigma = _truth_and_reference()
    n = sigma.size
    m = compute_metrics(truth, ref, sigma, names=("rmse", "mae", "rel_mse"))
    # mse = mean σ²ε²: mean σ², sd sqrt(2 Σσ⁴)/n.
    assert abs(m["rmse"].value ** 2 - m["rmse"].noise_floor ** 2) < 5 * math.sqrt(2 * np.sum(sigma**4)) / n
    # mae = mean σ|ε|: mean sqrt(2/π) mean σ, sd sqrt((1 − 2/π) Σσ²)/n.
    sd_mae = math.sqrt((1 - 2 / math.pi) * np.sum(sigma**2)) / n
    assert abs(m["mae"].value - m["mae"].noise_floor) < 5 * sd_mae
    # rel_mse = mean σ²ε²/(r² + 0.01); the floor puts r in the denominator, as the metric does.
    wgt = sigma**2 / (ref**2 + 0.01)
    assert abs(m["rel_mse"].value - m["rel_mse"].noise_floor) < 5 * math.sqrt(2 * np.sum(wgt**2)) / n
    assert not (m["rmse"].resolved or m["mae"].resolved or m["rel_mse"].resolved)


def test_max_abs_floor_matches_the_distribution_of_the_maximum():
    from scipy import integrate, stats

    n, sigma = 500, 0.3
    r = np.ones(n)
    floor = compute_metrics(r, r, np.full(n, sigma), names=("max_abs",), floor_draws=8)["max_abs"].noise_floor
    # M = max of n |N(0, σ²)|: P(M ≤ t) = (2Φ(t/σ) − 1)^n; E[M] and E[M²] by quadrature.
    cdf = lambda t: (2 * stats.norm.cdf(t / sigma) - 1) ** n  # noqa: E731
    e1 = integrate.quad(lambda t: 1 - cdf(t), 0, 10 * sigma)[0]
    e2 = integrate.quad(lambda t: 2 * t * (1 - cdf(t)), 0, 10 * sigma)[0]
    sd_mean_of_8 = math.sqrt(e2 - e1**2) / math.sqrt(8)
    assert abs(floor - e1) < 5 * sd_mean_of_8


def test_debiased_rmse_recovers_a_known_bias():
    truth, ref, sigma = _truth_and_reference(seed=2)
    b = 0.03
    m = compute_metrics(truth + b, ref, sigma, names=("rmse",))["rmse"]
    n = sigma.size
    # debiased² = b² − 2b·mean(σε) + (mean σ²ε² − mean σ²): sd from both terms.
    sd_sq = math.sqrt(4 * b**2 * np.sum(sigma**2) + 2 * np.sum(sigma**4)) / n
    assert abs(m.debiased - b) < 5 * sd_sq / (2 * b)  # ≈ 0.0011 here
    # The raw rmse is far from b (the floor, ≈ 0.037, adds in quadrature); only the debiased value finds b.
    assert m.value > 1.4 * b


def test_mc_floors_are_seeded_and_exact_approximations_are_unresolved():
    truth, ref, sigma = _truth_and_reference(seed=4, h=40, w=40)
    a = compute_metrics(truth, ref, sigma, seed=7)
    b = compute_metrics(truth, ref, sigma, seed=7)
    c = compute_metrics(truth, ref, sigma, seed=8)
    assert a == b
    assert a["max_abs"].noise_floor != c["max_abs"].noise_floor
    assert not any(v.resolved for v in a.values()), {k: v for k, v in a.items() if v.resolved}
    # A clearly wrong approximation with structure (a ±30% ripple) is resolved on every metric.
    xx = np.arange(truth.shape[1])
    d = compute_metrics(truth * (1 + 0.3 * np.sin(xx / 2.0))[None, :, None], ref, sigma)
    assert all(v.resolved for v in d.values()), {k: v for k, v in d.items() if not v.resolved}
    # A uniform 1.5x brightness error is not resolved by SSIM on this smooth, noisy image (the noise
    # dominates SSIM's structure term; see docs/metrics-and-fitting.md), while every other metric sees it.
    e = compute_metrics(truth * 1.5, ref, sigma)
    assert {k for k, v in e.items() if not v.resolved} == {"ssim"}


# -------------------------------------------------------------------------------------- z-scores
def test_z_scores_of_an_exact_approximation_have_unit_spread():
    truth, ref, sigma = _truth_and_reference(seed=6)
    z = z_scores(truth, ref, sigma)
    n = z.size
    # For n normal draws: sd(mean) = 1/√n, sd(std) ≈ 1/√(2n); 5σ tolerances (≈ 0.036, 0.026 here).
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.std() - 1) < 5 / math.sqrt(2 * n)
    s = z_score_summary(truth, ref, sigma)
    assert s.n == n and s.n_zero_stderr == 0 and s.std == pytest.approx(z.std())


def test_z_scores_drop_and_count_zero_stderr():
    x = np.array([1.0, 2.0, 3.0, 5.0])
    r = np.array([0.0, 2.0, 3.0, 4.0])
    s = np.array([0.5, 0.0, 0.0, 2.0])
    assert z_scores(x, r, s).tolist() == [2.0, 0.5]
    summ = z_score_summary(x, r, s, mask=np.array([True, True, True, False]))
    assert (summ.n, summ.n_zero_stderr, summ.n_zero_stderr_differing) == (1, 2, 0)
    summ = z_score_summary(x + 1, r, s)
    assert summ.n_zero_stderr_differing == 2
    json.dumps(summ.to_dict(), allow_nan=False)


# ----------------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize(
    "case",
    [
        "shape",
        "stderr_shape",
        "nan",
        "inf_ref",
        "neg_stderr",
        "mask_shape",
        "mask_dtype",
        "mask_empty",
        "ndim",
        "unknown",
    ],
)
def test_bad_inputs_raise_one_line_value_errors(case):
    a = np.ones((4, 4, 3))
    r, s, mask, names = a.copy(), np.full(a.shape, 0.1), None, ("rmse",)
    if case == "shape":
        a = np.ones((4, 5, 3))
    elif case == "stderr_shape":
        s = np.full((4, 4), 0.1)
    elif case == "nan":
        a[0, 0, 0] = np.nan
    elif case == "inf_ref":
        r[1, 1, 1] = np.inf
    elif case == "neg_stderr":
        s[2, 2, 0] = -0.1
    elif case == "mask_shape":
        mask = np.ones((4, 4, 3), bool)
    elif case == "mask_dtype":
        mask = np.ones((4, 4))
    elif case == "mask_empty":
        mask = np.zeros((4, 4), bool)
    elif case == "ndim":
        a = r = s = np.ones((2, 2, 2, 2))
    elif case == "unknown":
        names = ("rmse", "lpips")
    with pytest.raises(ValueError) as err:
        compute_metrics(a, r, s, mask=mask, names=names)
    assert "\n" not in str(err.value) and str(err.value)
    if case in ("nan", "neg_stderr", "shape"):
        with pytest.raises(ValueError):
            z_scores(a, r, s)


def test_noise_floors_are_computed_once_per_reference_and_never_stale(monkeypatch):
    """The MC floors depend only on the reference, its stderr, the mask, the seed and the draws: a second row
    against the same reference reuses them (no further ꟻLIP or SSIM call), and any change of the reference
    or the stderr computes them afresh, equal to a computation with the memo emptied."""
    from rtfit.fitting import flip_maps as F
    from rtfit.fitting import metric_noise as N

    rng = np.random.default_rng(7)
    ref = rng.uniform(0.2, 1.0, (32, 32, 3))
    err = np.full_like(ref, 0.01)
    N._floor_memo.clear()
    F._map_memo.clear()
    first = compute_metrics(ref * 1.1, ref, err, seed=3)
    calls = []
    real = F._flip_map_uncached
    monkeypatch.setattr(F, "_flip_map_uncached", lambda *a: calls.append(1) or real(*a))
    second = compute_metrics(ref * 0.9, ref, err, seed=3)
    assert len(calls) == 1  # the row's own map only; the four floor draws are reused
    for k in ("ssim", "flip", "max_abs"):
        assert second[k].noise_floor == first[k].noise_floor
    # a changed stderr: fresh floors, equal to those of an empty memo
    moved = compute_metrics(ref * 0.9, ref, err * 2, seed=3)
    N._floor_memo.clear()
    F._map_memo.clear()
    fresh = compute_metrics(ref * 0.9, ref, err * 2, seed=3)
    for k in ("ssim", "flip", "max_abs"):
        assert moved[k].noise_floor == fresh[k].noise_floor != first[k].noise_floor
        assert moved[k].value == fresh[k].value


def test_prime_flip_gives_the_maps_and_values_of_separate_calls():
    """`prime_flip` computes a reference's ꟻLIP maps together; `compute_metrics` after it gives the same flip
    value and floor as without it, and each map is flip_evaluator's (NVIDIA's float32 code, called directly)
    to `FLIP_CODE_TOL`."""
    import flip_evaluator

    from rtfit.fitting import flip_maps as F
    from rtfit.fitting import metric_noise as N
    from rtfit.fitting import metrics as M

    rng = np.random.default_rng(3)
    ref = rng.uniform(0.05, 2.0, (40, 48, 3))
    sd = 0.02 * ref
    mask = np.ones((40, 48), bool)
    mask[:5] = False
    approxes = [ref * (1 + 0.2 * rng.standard_normal(ref.shape)).clip(0.1) for _ in range(5)]
    F._map_memo.clear()
    N._floor_memo.clear()
    alone = [compute_metrics(a, ref, sd, mask, names=("flip",))["flip"] for a in approxes]
    F._map_memo.clear()
    N._floor_memo.clear()
    assert M.prime_flip(approxes, ref, sd, mask) == 5 + 4  # each approximation's map and 4 floor draws
    primed = [compute_metrics(a, ref, sd, mask, names=("flip",))["flip"] for a in approxes]
    assert [(p.value, p.noise_floor) for p in primed] == [(a.value, a.noise_floor) for a in alone]
    params = F.flip_exposures(ref, mask)
    peak = float(ref[mask].max())
    r32 = F.flip_input(ref, "", peak, False)
    for a in approxes[:2]:
        direct, _, _ = flip_evaluator.evaluate(
            r32, F.flip_input(a, "", peak, False), "HDR", applyMagma=False, computeMeanError=False,
            parameters=dict(params),
        )  # fmt: skip
        ours = M.flip_error_map(a, ref, mask)
        assert np.max(np.abs(np.asarray(direct, np.float64).reshape(40, 48) - ours)) <= FLIP_CODE_TOL
    assert M.prime_flip(approxes, ref, sd, mask) == 0  # all known now


def test_flip_maps_of_float32_copies_are_the_audits_maps():
    """The report viewer reads an audit's images back as float32 (its EXR pixels): `flip_exposures` rounds
    the reference to float32, as ꟻLIP sees it, so the copies give the same exposures, the same ꟻLIP inputs
    and the maps the audit computed, found in the memo (issue 33); the values are ꟻLIP's own on either."""
    from rtfit.fitting import flip_maps as F
    from rtfit.fitting import metric_noise as N
    from rtfit.fitting import metrics as M

    rng = np.random.default_rng(11)
    ref = rng.uniform(0.0, 2.0, (30, 34, 3)) ** 3 + 1e-3 * rng.uniform(size=(30, 34, 3))
    approxes = [ref * rng.uniform(0.5, 1.5, ref.shape) for _ in range(3)]
    mask = np.ones(ref.shape[:2], bool)
    assert F.flip_exposures(ref, mask) == F.flip_exposures(ref.astype(np.float32), mask)
    F._map_memo.clear()
    N._floor_memo.clear()
    audit = [compute_metrics(a, ref, 0.01 * ref, mask, names=("flip",))["flip"].value for a in approxes]
    copies = [a.astype(np.float32) for a in approxes]
    assert M.prime_flip(copies, ref.astype(np.float32), 0.01 * ref, mask, floor_draws=0) == 0
    viewer = [float(np.mean(M.flip_error_map(c, ref.astype(np.float32), mask))) for c in copies]
    assert viewer == audit


def test_shared_flip_maps_are_each_pairs_map_alone(monkeypatch):
    """`flip_maps_shared` filters each distinct image once however many pairs hold it (a case's rows share
    their reference; the noise floor's draws hold it as their test): each map equals its pair's map computed
    alone, bit for bit; a copy of an image (another object, the same content) is found as that image, and at
    one exposure range the map of (a, b) is that of (b, a) (both differences are symmetric)."""
    from rtfit.fitting import flip_maps as F

    rng = np.random.default_rng(5)
    ref = rng.uniform(0.0, 3.0, (24, 30, 3)) ** 3
    params = F.flip_exposures(ref, np.ones((24, 30), bool))
    r32 = F.flip_input(ref, "", float(ref.max()), False)
    tests = [F.flip_input(ref * rng.uniform(0, 2, ref.shape), "", float(ref.max()), False) for _ in range(3)]
    pairs = [(r32, t) for t in tests] + [(tests[0], r32.copy()), (tests[1], tests[2])]
    alone = [F.flip_maps_shared([pair], params)[0] for pair in pairs]
    seen, real = [], F.hdr_flip_maps
    monkeypatch.setattr(F, "hdr_flip_maps", lambda images, *a: seen.append(len(images)) or real(images, *a))
    shared = F.flip_maps_shared(pairs, params)
    assert seen == [4]  # the reference (and its copy) and the three tests
    assert all(np.array_equal(s, a) for s, a in zip(shared, alone, strict=True))
    assert np.array_equal(shared[3], shared[0])  # at one exposure range a map is symmetric (module text)


def test_ssim_value_and_floor_are_scikit_image_s_bit_for_bit():
    """The SSIM written once for all channels and noise draws (the reference's filtered tone map kept per
    reference) gives scikit-image's per-channel values exactly, and its noise floor exactly: the mean of
    `floor_draws` draws of scikit-image's SSIM of the noisy reference against the reference."""
    from skimage.metrics import structural_similarity

    from rtfit.fitting.metric_noise import noise_rng

    def ssim(a, b, m):
        smap = structural_similarity(
            tone_map(a), tone_map(b), data_range=1.0, channel_axis=-1, gaussian_weights=True, sigma=1.5,
            use_sample_covariance=False, full=True,
        )[1]  # fmt: skip
        return float(np.mean(smap[m]))

    rng = np.random.default_rng(11)
    for h, w in ((11, 11), (23, 37)):
        ref = rng.gamma(1.0, 2.0, (h, w, 3))
        ap = ref * (1 + 0.3 * rng.standard_normal(ref.shape)) - 0.05  # partly negative
        s = 0.05 * ref
        mask = rng.random((h, w)) > 0.3
        m = compute_metrics(ap, ref, s, mask=mask, names=("ssim",), seed=4)["ssim"]
        g = noise_rng(4, "ssim")
        floor = float(np.mean([ssim(ref + s * g.standard_normal(ref.shape), ref, mask) for _ in range(4)]))
        assert m.value == ssim(ref, ap, mask)
        assert m.noise_floor == floor
