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


def test_a_number_is_the_whole_token_and_a_checked_list_only_numbers():
    import pytest

    from calib_oed.exceptions import ProgramError

    garbled = "{A1 10.5,A2 -6.11.68,A3 1}"
    assert [n.text for n in numbers_in(garbled, 0, len(garbled))] == ["10.5", "1"]  # not "-6.11"
    good = "[0.1, -2, .5e-3 ]"
    assert [n.text for n in numbers_in(good, 0, len(good), "f.script")] == ["0.1", "-2", ".5e-3"]
    for bad in ("[-0.44 -1.69, 0.3]", "[0.1, TRUE, 0.3]", "[0.1,, 0.3]"):
        with pytest.raises(ProgramError, match=r"f.script:1.*not a comma-separated list of numbers"):
            numbers_in(bad, 0, len(bad), "f.script")
