"""Statistics of reference checks: robust z-spreads, z-test checks with their tolerances, Šidák thresholds.

A reference (Mitsuba Monte Carlo) element has a mean r and a standard error s; an approximation that is
exact for the quantity gives z = (x − r)/σ with σ the per-element standard deviation of the estimate, and
the z-scores are then standard normal. Every experiment checks its exact forms (closed forms,
quadratures) that way, as Mitsuba's own tests do: a robust spread and a pass rate over elements, because
the per-element variance estimate is unreliable where an element got only a few light samples.

Tolerances of `z_checks` (defaults, each derived):

* robust spread 1.4826·MAD of n ≥ 500 normal z-scores has a standard deviation ≈ 1.17/√n ≤ 0.05, so
  |spread − 1| ≤ 0.15 is a 3σ band; with fewer elements the band widens to k·(that standard deviation)
  (`z_spread_tolerance`: k = Φ⁻¹(1 − α/2), α = 1 %, the false-alarm rate of the largest-|z| check), never
  narrower than 0.15 (a 6×6-pixel case's 36 values: ± 0.50);
* |median| ≤ 0.15 likewise (the median of n normal values has standard deviation 1.2533/√n ≤ 0.056),
  widened the same way where n is small (`z_median_tolerance`);
* with normal z-scores only 6.3e-5 of the elements exceed |z| > 4, so a tail fraction ≤ 1 % leaves room
  for the few-hit elements alone.

Few samples per element (``samples`` = n, the count each element's standard error was estimated from):
the z of a mean whose variance is estimated from n samples follows Student's t with n − 1 degrees of
freedom (normal samples), heavier-tailed than the normal. The checks then expect its values: robust spread
1.4826·t⁻¹(¾; n − 1) (1.054 at n = 8, 1.012 at 32, 1.001 at 256), tail fraction ≤ 1 % + P(|t| > 4)
(0.52 % at n = 8, 0.037 % at 32; the normal's 0.0063 %), the same tolerances around them; below
`Z_MIN_SAMPLES` the estimated variance is too noisy for any of them and the checks say so instead of
failing (`z_not_meaningful`). ``samples=None`` is the normal limit (a variance known or from many samples).

`sidak_threshold` gives the |z| that n independent normal elements all stay below with probability 1 − α
(family-wise error α): the largest |z| of a set is judged against it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MAD_TO_SIGMA",
    "Z_MEDIAN_TOLERANCE",
    "Z_MIN_SAMPLES",
    "Z_SPREAD_ALPHA",
    "Z_SPREAD_TOLERANCE",
    "Z_TAIL_FRACTION",
    "concat_z_pairs",
    "expected_robust_spread",
    "expected_spread",
    "robust_spread",
    "sidak_threshold",
    "t_tail",
    "z_checks",
    "z_median_tolerance",
    "z_not_meaningful",
    "z_pair",
    "z_spread_tolerance",
]

MAD_TO_SIGMA = 1.4826
"""1/Φ⁻¹(3/4): the median absolute deviation of a normal sample times this is its standard deviation."""
Z_SPREAD_TOLERANCE = 0.15
"""The spread checks' tolerance where the elements are many (`z_spread_tolerance`: the narrowest band)."""
Z_SPREAD_ALPHA = 0.01
"""The false-alarm rate of one spread check (`z_spread_tolerance`): the 1 % of the largest-|z| check
(`sidak_threshold`)."""
MAD_SPREAD_SE = 1.1664
"""√(asymptotic variance) of 1.4826·MAD of n standard normal values, times √n (√1.3605)."""
Z_MEDIAN_TOLERANCE = 0.15
Z_TAIL_FRACTION = 0.01
Z_MIN_SAMPLES = 8
"""Fewest samples per element for which the z checks are judged: below, the variance estimated from n
samples has a relative standard deviation ≥ √(2/(n − 1)) = 0.58 (normal samples, n = 7), so a z-score
says little about the reference."""


def t_dof(samples: int | None) -> float:
    """Degrees of freedom of the z of a mean over ``samples`` values with an estimated variance (n − 1;
    inf for None: the normal limit)."""
    return math.inf if samples is None else float(samples) - 1.0


def expected_robust_spread(samples: int | None = None) -> float:
    """1.4826·(upper quartile of t(n − 1)): the robust spread (`robust_spread`) of exact z-scores whose
    variance is estimated from n = ``samples`` normal samples (1 for None)."""
    if samples is None:
        return 1.0
    from scipy.stats import t

    return float(MAD_TO_SIGMA * t.ppf(0.75, t_dof(samples)))


def expected_spread(samples: int | None = None) -> float:
    """The standard deviation √(ν/(ν − 2)) of t(ν), ν = n − 1 (needs n > 3; 1 for None)."""
    if samples is None:
        return 1.0
    nu = t_dof(samples)
    if nu <= 2:
        raise ValueError(f"the standard deviation of t({nu:g}) is infinite (samples must be > 3)")
    return math.sqrt(nu / (nu - 2))


def t_tail(threshold: float, samples: int | None = None) -> float:
    """P(|T| > threshold) for T ~ t(n − 1) (the standard normal for None)."""
    from scipy.stats import norm, t

    if samples is None:
        return float(2 * norm.sf(threshold))
    return float(2 * t.sf(threshold, t_dof(samples)))


def z_not_meaningful(samples: int | None) -> bool:
    """True when ``samples`` is below `Z_MIN_SAMPLES` (the z checks then report and do not judge)."""
    return samples is not None and samples < Z_MIN_SAMPLES


def _not_meaningful_text(samples: int) -> str:
    return (
        f"not judged: {samples} samples per element (< {Z_MIN_SAMPLES}); the variance each z divides by is "
        f"estimated from them, so z follows t({samples - 1}), too noisy to test (use more spp)"
    )


def robust_spread(z) -> float:
    """1.4826 · median |z − median z|: the standard deviation of the normal core, blind to outliers
    (NaN for no elements)."""
    z = np.asarray(z, dtype=np.float64).ravel()
    if z.size == 0:
        return float("nan")
    return float(MAD_TO_SIGMA * np.median(np.abs(z - np.median(z))))


def z_pair(approx, mean, stderr, sigma, precision_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(z of elements whose statistical error exceeds the precision floor, z of every element with σ > 0).

    Elements whose standard error is below ``precision_floor``·|mean| (e.g. lit by a constant sky alone:
    zero variance on the CPU, a 1-ulp variance on CUDA) carry no statistics; they enter only the tail
    check, through the precision floor included in σ."""
    d = np.asarray(approx, np.float64) - np.asarray(mean, np.float64)
    stderr, sigma, mean = (np.asarray(a, np.float64) for a in (stderr, sigma, mean))
    stat = stderr > precision_floor * np.abs(mean)
    ok = sigma > 0
    return d[stat] / sigma[stat], d[ok] / sigma[ok]


def concat_z_pairs(pairs) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate the two halves of several `z_pair` results."""
    pairs = list(pairs)
    if not pairs:
        return np.zeros(0), np.zeros(0)
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


def z_spread_tolerance(
    n: int,
    *,
    robust: bool = False,
    samples: int | None = None,
    floor: float = Z_SPREAD_TOLERANCE,
    alpha: float = Z_SPREAD_ALPHA,
) -> float:
    """The tolerance of the spread of ``n`` z-scores around its expected value: k·se, k = Φ⁻¹(1 − α/2) (a
    spread check of exact z fails with probability ≈ α), never below ``floor`` (the tolerance of many
    elements). se: the standard error of the sample standard deviation of n values of kurtosis κ,
    σ·√((κ − 1)/(4(n − 1))) (normal values, κ = 3: σ/√(2(n − 1))); σ and κ those of t(samples − 1) with
    ``samples`` (κ = 3 + 6/(ν − 4)); ``robust``: of 1.4826·MAD instead, ≈ 1.1664·σ/√n (`MAD_SPREAD_SE`)."""
    from scipy.stats import norm  # (as `sidak_threshold`)

    n = max(int(n), 2)
    k = float(norm.isf(alpha / 2))
    if robust:
        se = MAD_SPREAD_SE * expected_robust_spread(samples) / math.sqrt(n)
    else:
        nu = t_dof(samples)
        kurtosis = 3.0 if math.isinf(nu) or nu <= 4 else 3.0 + 6.0 / (nu - 4.0)
        se = expected_spread(samples) * math.sqrt((kurtosis - 1.0) / (4.0 * (n - 1)))
    return max(float(floor), k * se)


def z_median_tolerance(
    n: int, *, floor: float = Z_MEDIAN_TOLERANCE, alpha: float = Z_SPREAD_ALPHA, samples: int | None = None
) -> float:
    """The tolerance of the median of ``n`` z-scores around 0: k·√(π/2)/√n (the median's standard error for
    standard normal values; t(samples − 1): 1/(2·f_t(0)·√n)), k as `z_spread_tolerance`'s, never below
    ``floor``."""
    from scipy.stats import norm, t

    nu = t_dof(samples)
    density = float(norm.pdf(0.0)) if math.isinf(nu) else float(t.pdf(0.0, nu))
    return max(float(floor), float(norm.isf(alpha / 2)) / (2.0 * density * math.sqrt(max(int(n), 1))))


def z_checks(
    what: str,
    z,
    z_all=None,
    *,
    spread_tolerance: float = Z_SPREAD_TOLERANCE,
    median_tolerance: float = Z_MEDIAN_TOLERANCE,
    tail_fraction: float = Z_TAIL_FRACTION,
    samples: int | None = None,
) -> list[dict]:
    """Three check records (name, value, expected, passed) for z-scores that should be standard normal:
    robust spread 1 ± tol (``spread_tolerance`` where the elements are many, wider where few:
    `z_spread_tolerance`), median 0 ± tol (likewise: `z_median_tolerance`), and the fraction of ``z_all``
    (default ``z``) beyond |z| > 4.
    No element at all is one failed check. ``samples``: the samples per element the standard errors were
    estimated from; the spread is then expected at `expected_robust_spread` and the tail fraction allowed
    `t_tail` (4) more (module docstring); below `Z_MIN_SAMPLES` each check reports its value, passes and
    says it was not judged."""
    z = np.asarray(z, dtype=np.float64).ravel()
    z_all = z if z_all is None else np.asarray(z_all, dtype=np.float64).ravel()
    if z.size == 0:
        return [
            {"name": f"{what}: z-scores", "value": 0.0, "expected": "at least one element", "passed": False}
        ]
    spread, median = robust_spread(z), float(np.median(z))
    tail = float(np.mean(np.abs(z_all) > 4)) if z_all.size else 0.0
    names = (
        f"{what}: robust z spread (1.4826·MAD, {z.size} elements)",
        f"{what}: median z",
        f"{what}: fraction with |z| > 4 ({z_all.size} elements)",
    )
    if samples is not None and z_not_meaningful(samples):
        text = _not_meaningful_text(samples)
        return [
            {"name": n, "value": v, "expected": text, "passed": True}
            for n, v in zip(names, (spread, median, tail), strict=True)
        ]
    centre = expected_robust_spread(samples)
    tol = z_spread_tolerance(z.size, robust=True, samples=samples, floor=spread_tolerance)
    median_tol = z_median_tolerance(z.size, floor=median_tolerance, samples=samples)
    allowed = tail_fraction + (0.0 if samples is None else t_tail(4.0, samples))
    of_t = "" if samples is None else f" (t({samples - 1}): {samples} samples per element)"
    return [
        {
            "name": names[0],
            "value": spread,
            "expected": (f"1 ± {tol:.3g}" if samples is None else f"{centre:.4g} ± {tol:.3g}") + of_t,
            "passed": bool(abs(spread - centre) <= tol),
        },
        {
            "name": names[1],
            "value": median,
            "expected": f"0 ± {median_tol:.3g}",
            "passed": bool(abs(median) <= median_tol),
        },
        {
            "name": names[2],
            "value": tail,
            "expected": f"≤ {allowed:.4g}" + of_t if samples is not None else f"≤ {tail_fraction}",
            "passed": bool(tail <= allowed),
        },
    ]


def sidak_threshold(n: int, alpha: float = 0.01, samples: int | None = None) -> float:
    """|z| below which n independent standard-normal values all fall with probability 1 − α (two-sided):
    Φ⁻¹(1 − p/2) with p = 1 − (1 − α)^(1/n) (Šidák 1967); with ``samples``, of t(samples − 1) instead."""
    from scipy.stats import norm, t  # scipy is a dependency; imported here to keep `rtfit.fitting` light

    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1) (got {alpha!r})")
    p = -math.expm1(math.log1p(-alpha) / max(int(n), 1))
    if samples is None:
        return float(norm.isf(p / 2))
    return float(t.isf(p / 2, t_dof(samples)))
