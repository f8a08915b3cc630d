"""Reading a program's text: numbers with their spans, argument starts, lines and indents."""

from __future__ import annotations

from calib_oed.program.parse.scan import (
    argument_starts,
    indent_of,
    line_of,
    numbers_in,
    skipped_move,
)


def test_numbers_in_skips_digits_of_names():
    text = "{A1 10.5,A2 -3,E1 .25}"
    assert [n.text for n in numbers_in(text, 0, len(text))] == ["10.5", "-3", ".25"]
    assert [text[n.start:n.end] for n in numbers_in(text, 8, len(text))] == ["-3", ".25"]


def test_arguments_lines_indents_and_the_skipped_move_note():
    text = "x\n  MoveJ [[1, 2], 3], \\V:=v1, z1;\n"
    args = argument_starts(text, text.index("["), ";", "\\")
    assert [text[a:a + 2] for a in args] == ["[[", "z1"]
    assert (line_of(text, 0), line_of(text, text.index("M")), indent_of(text, text.index("M"))) == (0, 1, "  ")
    assert skipped_move("m.mod", text, text.index("z1"), "why") == "m.mod:2: MoveJ [[1, 2], 3], \\V:=v1, z1;: NOT compensated: why"
