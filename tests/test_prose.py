"""Prose numbers and fitted laws: U+2212 for minus signs, never "+ -" (issue 32, Reports)."""

from __future__ import annotations

import re

from rtfit.experiments.prose import MINUS, law_text, prose_number


def test_prose_number_uses_the_minus_sign():
    assert MINUS == "\u2212"
    assert prose_number(-0.0516) == "\u22120.0516"
    assert prose_number(0.0516) == "0.0516"
    assert prose_number(-2e-5) == "\u22122e\u221205"  # the exponent's sign too: one rule per text
    assert prose_number(-1.23456, ".2f") == "\u22121.23"


def test_law_text_joins_signed_terms():
    assert law_text((1, ""), (-0.0516, "sin α"), (0.02, "sin²α")) == "1 \u2212 0.0516·sin α + 0.02·sin²α"
    assert law_text((-0.5, "x"), (-2, "y")) == "\u22120.5·x \u2212 2·y"  # a leading negative keeps its sign
    assert law_text((0.25, "x"), (0.0, "y")) == "0.25·x + 0·y"
    assert law_text((1.23456, "t"), spec=".2f") == "1.23·t"


def test_diffuse_summary_prints_the_smooth_law_with_minus_signs():
    """The diffuse summary on a synthetic fitted law with negative coefficients: "1 − 0.0516·sin α",
    never "1 + -0.0516·sin α", and no ASCII hyphen as a number's sign anywhere in the text."""
    from rtfit.experiments.diffuse_study import _summary

    params = {"w1": 0.61, "w2": -0.125, "p1": -0.0516, "p2": 0.3}
    smooth = {"parameters": {k: {"value": v} for k, v in params.items()}}
    rows = ("lambert", "half-lambert", "wrap-fitted", "wrap-smooth", "exact")
    table = [{"alpha_deg": a, "rmse": dict.fromkeys(rows, 0.01), "floor": 0.001} for a in (0.27, 30.0)]
    text = _summary(table, smooth)
    assert "w(α) = 0.61·sin α \u2212 0.125·sin²α" in text
    assert "p(α) = 1 \u2212 0.0516·sin α + 0.3·sin²α" in text
    assert "+ -" not in text and "+ \u2212" not in text
    assert not re.search(r"(?<![\w])-(?=\.?\d)", text), text
