"""`rtfit.experiments.zchecks.pixel_z_checks`: the three checks of a reference against an exact value, on
z-scores set by hand; the Šidák threshold recomputed here from its definition."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from rtfit.experiments.records import Check
from rtfit.experiments.zchecks import pixel_z_checks

NAMES = ("spread", "pooled", "largest")


def sidak(n: int) -> float:
    """|z| below which n standard normals all fall with probability 0.99."""
    return float(norm.isf((1.0 - 0.99 ** (1.0 / n)) / 2.0))


def test_unit_spread_small_pooled_and_no_outlier_pass():
    z = np.array([-1.0, 1.0, -1.0, 1.0])  # standard deviation exactly 1
    checks = pixel_z_checks(z, 0.5, NAMES, 0.2)
    assert all(isinstance(c, Check) for c in checks) and [c.name for c in checks] == list(NAMES)
    assert [c.passed for c in checks] == [True, True, True]
    assert checks[0].value == pytest.approx(1.0) and checks[0].expected == "1 ± 0.2"
    assert checks[1].expected == "|z| ≤ 4" and checks[2].value == pytest.approx(1.0)
    assert checks[2].expected == f"≤ {sidak(4):.2f} (Šidák, 1 % family-wise)"


def test_wide_spread_large_pooled_and_an_outlier_fail():
    z = np.array([-10.0, 10.0])
    checks = pixel_z_checks(z, -4.5, NAMES, 0.15)
    assert [c.passed for c in checks] == [False, False, False]
    assert checks[0].value == pytest.approx(10.0) and checks[0].expected == "1 ± 0.15"
    assert checks[2].value == pytest.approx(10.0) and 10.0 > sidak(2)
