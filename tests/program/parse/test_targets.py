"""Number formatting and comment insertion keep everything else byte for byte."""

from __future__ import annotations

from calib_oed.program.parse.targets import format_number, insert_after_lines, numbers_in


def test_format_number_keeps_the_originals_precision_and_no_negative_zero():
    assert format_number(1.23456789, "1.5", 4) == "1.2346"
    assert format_number(1.23456789, "1.1234567", 4) == "1.2345679"
    assert format_number(-0.00001, "0.0", 4) == "0.0000"
    assert format_number(2.0, "+1.0", 2) == "+2.00"


def test_numbers_in_skips_digits_of_names():
    text = "{A1 10.5,A2 -3,E1 .25}"
    assert [n.text for n in numbers_in(text, 0, len(text))] == ["10.5", "-3", ".25"]


def test_comments_take_the_lines_own_ending():
    text = "a\r\nb\r\nc"
    assert insert_after_lines(text, [(0, "; x"), (2, "; y")]) == "a\r\n; x\r\nb\r\nc\n; y\n"
