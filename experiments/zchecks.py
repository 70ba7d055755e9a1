"""The three checks of a Mitsuba reference against an exact value per pixel, as `records.Check`: the spread
of the z-scores (1 ± a tolerance), the pooled z-score of the summed difference (|z| ≤ 4) and the largest
|z| (below the Šidák threshold for a 1 % family-wise error). Shared by the families; imports none of them.
"""

from __future__ import annotations

import numpy as np

from rtfit.fitting import sidak_threshold
from rtfit.fitting.stats import (
    Z_MIN_SAMPLES,
    Z_SPREAD_TOLERANCE,
    expected_spread,
    z_not_meaningful,
    z_spread_tolerance,
)

from .records import Check

__all__ = ["pixel_z_checks"]


def pixel_z_checks(
    z: np.ndarray,
    pooled: float,
    names: tuple[str, str, str],
    tolerance: float = Z_SPREAD_TOLERANCE,
    samples: int | None = None,
) -> list[Check]:
    """Checks named ``names`` (spread, pooled, largest) of the per-pixel z-scores ``z`` and of ``pooled``,
    the z-score of the summed difference. ``samples``: the samples per pixel each standard error was
    estimated from; z then follows t(samples − 1) (`rtfit.fitting.stats`): the spread is expected at its
    standard deviation √(ν/(ν − 2)) and the largest |z| below t's Šidák threshold, and below
    `Z_MIN_SAMPLES` the checks report without judging. None: the normal limit (as before). The spread's
    tolerance is ``tolerance`` where the pixels are many, wider where they are few (`z_spread_tolerance`: k
    standard errors of the standard deviation of z.size values, k for a 1 % false alarm)."""
    spread, largest = float(np.std(z)), float(np.max(np.abs(z)))
    if z_not_meaningful(samples):
        text = f"not judged: {samples} samples per pixel (< {Z_MIN_SAMPLES}): z follows a too-noisy t"
        return [
            Check(name=n, value=v, expected=text, passed=True)
            for n, v in zip(names, (spread, pooled, largest), strict=True)
        ]
    sidak = sidak_threshold(z.size, samples=samples)
    centre = expected_spread(samples)
    tol = z_spread_tolerance(z.size, samples=samples, floor=tolerance)
    return [
        Check(
            name=names[0],
            value=spread,
            expected=f"1 ± {tol:.3g}" if samples is None else f"{centre:.4g} ± {tol:.3g} (t({samples - 1}))",
            passed=bool(abs(spread - centre) <= tol),
        ),
        Check.magnitude_at_most(names[1], pooled, "z", "4"),
        Check.at_most(names[2], largest, sidak, fmt=".2f", note="(Šidák, 1 % family-wise)"),
    ]
