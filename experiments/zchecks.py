"""The three checks of a Mitsuba reference against an exact value per pixel, as `records.Check`: the spread
of the z-scores (1 ± a tolerance), the pooled z-score of the summed difference (|z| ≤ 4) and the largest
|z| (below the Šidák threshold for a 1 % family-wise error). Shared by the families; imports none of them.
"""

from __future__ import annotations

import numpy as np

from rtfit.fitting import sidak_threshold

from .records import Check

__all__ = ["pixel_z_checks"]


def pixel_z_checks(
    z: np.ndarray, pooled: float, names: tuple[str, str, str], spread_tolerance: float
) -> list[Check]:
    """Checks named ``names`` (spread, pooled, largest) of the per-pixel z-scores ``z`` and of ``pooled``,
    the z-score of the summed difference."""
    spread, largest, sidak = float(np.std(z)), float(np.max(np.abs(z))), sidak_threshold(z.size)
    return [
        Check(
            name=names[0],
            value=spread,
            expected=f"1 ± {spread_tolerance}",
            passed=bool(abs(spread - 1) <= spread_tolerance),
        ),
        Check(name=names[1], value=pooled, expected="|z| ≤ 4", passed=bool(abs(pooled) <= 4)),
        Check(
            name=names[2],
            value=largest,
            expected=f"≤ {sidak:.2f} (Šidák, 1 % family-wise)",
            passed=bool(largest <= sidak),
        ),
    ]
