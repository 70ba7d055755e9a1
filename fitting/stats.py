"""Statistics of reference checks: robust z-spreads, z-test checks with their tolerances, Šidák thresholds.

A reference (Mitsuba Monte Carlo) element has a mean r and a standard error s; an approximation that is
exact for the quantity gives z = (x − r)/σ with σ the per-element standard deviation of the estimate, and
the z-scores are then standard normal. Every experiment checks its exact forms (closed forms,
quadratures) that way, as Mitsuba's own tests do: a robust spread and a pass rate over elements, because
the per-element variance estimate is unreliable where an element got only a few light samples.

Tolerances of `z_checks` (defaults, each derived):

* robust spread 1.4826·MAD of n ≥ 500 normal z-scores has a standard deviation ≈ 1.17/√n ≤ 0.05, so
  |spread − 1| ≤ 0.15 is a 3σ band;
* |median| ≤ 0.15 likewise (the median of n normal values has standard deviation 1.2533/√n ≤ 0.056);
* with normal z-scores only 6.3e-5 of the elements exceed |z| > 4, so a tail fraction ≤ 1 % leaves room
  for the few-hit elements alone.

`sidak_threshold` gives the |z| that n independent normal elements all stay below with probability 1 − α
(family-wise error α): the largest |z| of a set is judged against it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MAD_TO_SIGMA",
    "Z_MEDIAN_TOLERANCE",
    "Z_SPREAD_TOLERANCE",
    "Z_TAIL_FRACTION",
    "concat_z_pairs",
    "robust_spread",
    "sidak_threshold",
    "z_checks",
    "z_pair",
]

MAD_TO_SIGMA = 1.4826
"""1/Φ⁻¹(3/4): the median absolute deviation of a normal sample times this is its standard deviation."""
Z_SPREAD_TOLERANCE = 0.15
Z_MEDIAN_TOLERANCE = 0.15
Z_TAIL_FRACTION = 0.01


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


def z_checks(
    what: str,
    z,
    z_all=None,
    *,
    spread_tolerance: float = Z_SPREAD_TOLERANCE,
    median_tolerance: float = Z_MEDIAN_TOLERANCE,
    tail_fraction: float = Z_TAIL_FRACTION,
) -> list[dict]:
    """Three check records (name, value, expected, passed) for z-scores that should be standard normal:
    robust spread 1 ± tol, median 0 ± tol, and the fraction of ``z_all`` (default ``z``) beyond |z| > 4.
    No element at all is one failed check."""
    z = np.asarray(z, dtype=np.float64).ravel()
    z_all = z if z_all is None else np.asarray(z_all, dtype=np.float64).ravel()
    if z.size == 0:
        return [
            {"name": f"{what}: z-scores", "value": 0.0, "expected": "at least one element", "passed": False}
        ]
    spread, median = robust_spread(z), float(np.median(z))
    tail = float(np.mean(np.abs(z_all) > 4)) if z_all.size else 0.0
    return [
        {
            "name": f"{what}: robust z spread (1.4826·MAD, {z.size} elements)",
            "value": spread,
            "expected": f"1 ± {spread_tolerance}",
            "passed": bool(abs(spread - 1) <= spread_tolerance),
        },
        {
            "name": f"{what}: median z",
            "value": median,
            "expected": f"0 ± {median_tolerance}",
            "passed": bool(abs(median) <= median_tolerance),
        },
        {
            "name": f"{what}: fraction with |z| > 4 ({z_all.size} elements)",
            "value": tail,
            "expected": f"≤ {tail_fraction}",
            "passed": bool(tail <= tail_fraction),
        },
    ]


def sidak_threshold(n: int, alpha: float = 0.01) -> float:
    """|z| below which n independent standard-normal values all fall with probability 1 − α (two-sided):
    Φ⁻¹(1 − p/2) with p = 1 − (1 − α)^(1/n) (Šidák 1967)."""
    from scipy.stats import norm  # scipy is a dependency; imported here to keep `rtfit.fitting` light

    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1) (got {alpha!r})")
    p = -math.expm1(math.log1p(-alpha) / max(int(n), 1))
    return float(norm.isf(p / 2))
