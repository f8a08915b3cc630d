"""Number formatting and comment insertion keep everything else byte for byte; where a target's
comment goes."""

from __future__ import annotations

from calib_oed.program.parse.scan import numbers_in
from calib_oed.program.parse.targets import format_number, insert_after_lines, target_at


def test_format_number_keeps_the_originals_precision_and_no_negative_zero():
    assert format_number(1.23456789, "1.5", 4) == "1.2346"
    assert format_number(1.23456789, "1.1234567", 4) == "1.2345679"
    assert format_number(-0.00001, "0.0", 4) == "0.0000"
    assert format_number(2.0, "+1.0", 2) == "+2.00"


def test_target_at_comments_after_its_statement_with_its_literals_indent():
    text = "DEF x()\n    P1 = [1.0,\n  2.0];\nEND"
    start, end = text.index("["), text.index(";")
    target = target_at(text, start, end, "P1", "joint", "x.src", numbers_in(text, start, end))
    assert (target.line, target.indent, target.values.tolist()) == (2, "    ", [1.0, 2.0])


def test_comments_take_the_lines_own_ending():
    text = "a\r\nb\r\nc"
    assert insert_after_lines(text, [(0, "; x"), (2, "; y")]) == "a\r\n; x\r\nb\r\nc\n; y\n"
