"""`records.Check`'s constructors: each writes ``expected`` and ``passed`` from one bound. The expected texts
and verdicts are written out here by hand (literals), including the boundary (a value equal to its bound),
a bound given as a number with a format, and NaN (passes nothing). No Mitsuba; fast."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtfit.experiments.records import Check, bound_text, from_json, to_json

NAN = float("nan")


def test_bound_text_string_is_shown_as_written_and_parsed():
    assert bound_text("1e-6") == ("1e-6", 1e-6)
    assert bound_text("0.01") == ("0.01", 0.01)
    assert bound_text("4") == ("4", 4.0)


def test_bound_text_number_is_formatted_but_tested_unrounded():
    assert bound_text(0.15) == ("0.15", 0.15)
    assert bound_text(3.14159, ".2f") == ("3.14", 3.14159)
    assert bound_text(0.25, "g") == ("0.25", 0.25)
    assert bound_text(7) == ("7", 7.0)


@pytest.mark.parametrize(
    ("make", "value", "expected", "passed"),
    [
        (Check.at_most, 1e-6, "≤ 1e-6", True),  # equal to the bound: passes
        (Check.at_most, 2e-6, "≤ 1e-6", False),
        (Check.below, 1e-6, "< 1e-6", False),  # equal: fails
        (Check.below, 5e-7, "< 1e-6", True),
        (Check.at_least, 1e-6, "≥ 1e-6", True),
        (Check.at_least, 5e-7, "≥ 1e-6", False),
        (Check.above, 1e-6, "> 1e-6", False),
        (Check.above, 2e-6, "> 1e-6", True),
        (Check.exactly, 1e-6, "= 1e-6", True),
        (Check.exactly, 0.0, "= 1e-6", False),
    ],
)
def test_relations_at_and_beside_the_bound(make, value, expected, passed):
    c = make("n", value, "1e-6")
    assert (c.name, c.value, c.expected, c.passed) == ("n", value, expected, passed)


@pytest.mark.parametrize("make", [Check.at_most, Check.below, Check.at_least, Check.above, Check.exactly])
def test_nan_passes_no_relation(make):
    c = make("n", NAN, "1")
    assert c.passed is False and math.isnan(c.value)


def test_number_bound_shown_with_its_format_tested_unrounded():
    c = Check.at_most("n", 2.004, 2.0049, fmt=".2f")  # shown 2.00, yet 2.004 ≤ 2.0049
    assert (c.expected, c.passed) == ("≤ 2.00", True)
    c = Check.below("n", 0.01, 1e-2, fmt="g")
    assert (c.expected, c.passed) == ("< 0.01", False)
    assert Check.at_least("n", 3, 3).expected == "≥ 3"


def test_quantity_and_note_around_the_relation():
    c = Check.at_most("n", 2.5, 3.0, fmt=".2f", quantity="max |z|", note="(Šidák, α = 0.01, n = 9)")
    assert (c.expected, c.passed) == ("max |z| ≤ 3.00 (Šidák, α = 0.01, n = 9)", True)
    c = Check.at_least("n", 0.5, "0.99", note="of the pixels within 1e-4 relative")
    assert (c.expected, c.passed) == ("≥ 0.99 of the pixels within 1e-4 relative", False)


def test_magnitude_keeps_the_signed_value():
    c = Check.magnitude_at_most("n", -4.0, "z", "4")
    assert (c.value, c.expected, c.passed) == (-4.0, "|z| ≤ 4", True)
    assert Check.magnitude_at_most("n", -4.01, "z", "4").passed is False
    assert Check.magnitude_at_most("n", NAN, "bias", 0.01).expected == "|bias| ≤ 0.01"
    assert Check.magnitude_at_most("n", NAN, "bias", 0.01).passed is False


def test_within_a_centre():
    c = Check.within("n", 1.15, "1", 0.15)
    assert (c.expected, c.passed) == ("1 ± 0.15", abs(1.15 - 1.0) <= 0.15)
    c = Check.within("n", 0.8, "1", "0.2")
    assert (c.expected, c.passed) == ("1 ± 0.2", abs(0.8 - 1.0) <= 0.2)
    assert Check.within("n", 0.475, "0.475", "1e-12").passed is True
    assert Check.within("n", 0.4750001, "0.475", "1e-12").passed is False
    c = Check.within("n", 0.7763932, 0.776393202, "1e-12", fmt=".6f")  # centre shown rounded, tested exactly
    assert (c.expected, c.passed) == ("0.776393 ± 1e-12", False)
    assert Check.within("n", NAN, "1", "0.2").passed is False


def test_zero_counts_and_values():
    assert (Check.zero("n", 0).expected, Check.zero("n", 0).passed) == ("0", True)
    assert Check.zero("n", 0.0).passed is True and Check.zero("n", -0.0).passed is True
    assert Check.zero("n", 2).passed is False and Check.zero("n", 1e-300).passed is False
    assert Check.zero("n", NAN).passed is False


def test_holds_writes_the_flag_as_text():
    c = Check.holds("n", True)
    assert (c.value, c.expected, c.passed) == ("True", "True", True)
    c = Check.holds("n", np.bool_(False))
    assert (c.value, c.expected, c.passed) == ("False", "True", False)
    assert type(c.passed) is bool
    assert Check.holds("n", None).value == "None" and Check.holds("n", None).passed is False


def test_constructed_check_round_trips_as_the_literal_one():
    made = Check.at_most("closed form vs quadrature", 3e-5, "1e-4")
    literal = Check(name="closed form vs quadrature", value=3e-5, expected="≤ 1e-4", passed=True)
    assert made == literal and to_json(made) == to_json(literal)
    assert from_json(Check, to_json(made), "<check>") == literal
