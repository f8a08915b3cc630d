"""Fields of a tracker export's text (calib_oed.io.export_fields)."""

from __future__ import annotations

import pytest

from calib_oed.io.export_fields import data_lines, number, splitter


def test_comments_and_blank_lines_are_not_data():
    text = "// SA Version 2026.1\n# a note\n\nRobot P001 A 1 2 3\r\n  \nRobot P002 A 4 5 6"
    assert data_lines(text) == [(4, "Robot P001 A 1 2 3"), (6, "Robot P002 A 4 5 6")]


@pytest.mark.parametrize("line, fields, decimal_comma", [
    ("P1_A;1234,5;-2,25", ["P1_A", "1234,5", "-2,25"], True),
    ("P1_A\t1234,5\t-2,25", ["P1_A", "1234,5", "-2,25"], True),
    ("P1_A, 1234.5 ,-2.25", ["P1_A", "1234.5", "-2.25"], False),
    ("Robot  P1   A 1234.5", ["Robot", "P1", "A", "1234.5"], False),
])
def test_the_separator_follows_the_line(line, fields, decimal_comma):
    split, comma = splitter(line)
    assert split(line) == fields and comma is decimal_comma


def test_numbers_missing_values_and_messages():
    assert number("1234,5", True) == 1234.5 and number("1234.5", False) == 1234.5
    assert number("", False) is None and number("NaN", False) is None and number("-", False) is None
    assert "not a number" in number("P001", False) and "not finite" in number("inf", False)
