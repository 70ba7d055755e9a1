"""Numbers and fitted laws in prose (summaries, captions): one rule for minus signs.

Prose — a report's summary, captions and section text — writes a negative number with U+2212 MINUS
SIGN (−), as the report's tables and ``tables.tex`` do; code, JSON and file contents keep ASCII ``-``
(Python's own formatting), so a value copied from ``results.json`` parses. A fitted law is written as
its terms joined by " + " or " − ", never "+ −" (issue 32: "1 + -0.0516·sin α").
"""

from __future__ import annotations

__all__ = ["MINUS", "law_text", "prose_number"]

MINUS = "\u2212"


def prose_number(x: float, spec: str = ".3g") -> str:
    """``x`` formatted with ``spec`` for prose: every ``-`` (sign and exponent) as U+2212,
    ``prose_number(-0.0516) == "−0.0516"``, ``prose_number(-2e-5) == "−2e−05"``."""
    return format(x, spec).replace("-", MINUS)


def law_text(*terms: tuple[float, str], spec: str = ".3g") -> str:
    """A linear combination Σ cᵢ·bᵢ as prose: ``terms`` are (coefficient cᵢ, basis text bᵢ; ``""`` for
    a constant). The first term carries its own sign (−0.5·x), each later one joins with " + " or
    " − " and its magnitude: ``law_text((1, ""), (-0.0516, "sin α"), (0.02, "sin²α"))`` is
    "1 − 0.0516·sin α + 0.02·sin²α". A zero coefficient is kept (the law's shape stays visible)."""
    out = []
    for i, (coef, basis) in enumerate(terms):
        mag = prose_number(abs(coef) if i else coef, spec) + (f"·{basis}" if basis else "")
        out.append(mag if i == 0 else f"{MINUS if coef < 0 else '+'} {mag}")
    return " ".join(out)
