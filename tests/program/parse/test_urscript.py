"""URScript: move targets as literals or variables; set_tcp; moves the parser cannot follow."""

from __future__ import annotations

import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import urscript


def test_get_inverse_kin_and_unfollowed_moves():
    text = ("def f():\n  movej(get_inverse_kin(p[0.4, 0.1, 0.3, 0, 3.14, 0]))\n"
            "  movel(pose_trans(feature, p[0, 0, 0.1, 0, 0, 0]))\nend\n")
    parsed = urscript.parse({"f.script": text})
    assert [t.kind for t in parsed.targets] == ["pose"]
    assert parsed.notes[0].startswith("f.script:3: movel(pose_trans(")


def test_short_joint_list_is_named():
    with pytest.raises(ProgramError, match="needs 6 numbers"):
        urscript.parse({"f.script": "movej([0.1, 0.2, 0.3])\n"})


def test_movec_has_two_targets_via_and_end():
    """movec(pose_via, pose_to, ...): both points are targets (literal or variable); an end point
    the parser cannot follow is named, not silently left."""
    text = ("def f():\n  via = p[0.1, 0.2, 0.3, 0, 3.14, 0]\n"
            "  movec(p[0.4, 0.1, 0.3, 0, 3.14, 0], p[0.5, 0.0, 0.3, 0, 3.14, 0], a=1.2, v=0.25, r=0, mode=1)\n"
            "  movec(via, p[0.6, 0.1, 0.2, 0, 3.14, 0], a=1.2, v=0.25)\n"
            "  movec(p[0.7, 0.1, 0.2, 0, 3.14, 0], pose_trans(feature, p[0, 0, 0.1, 0, 0, 0]))\nend\n")
    parsed = urscript.parse({"f.script": text})
    assert [t.name for t in parsed.targets] == ["via", "line 3 (via)", "line 3 (end)", "line 4 (end)",
                                                "line 5 (via)"]
    assert [t.values[0] for t in parsed.targets] == [0.1, 0.4, 0.5, 0.6, 0.7]
    assert parsed.notes == ("f.script:5: movec(p[0.7, 0.1, 0.2, 0, 3.14, 0], pose_trans(feature, p...: "
                            "NOT compensated: the end point is not a literal or a variable assigned one",)


def test_points_whose_value_is_not_known_are_named():
    """A variable assigned more than once, a function's argument and an expression (servoc too) are
    left as written and named (file:line, why); a literal inside a branch is read."""
    text = ("def f(q_start):\n  p1 = p[0.4, 0.1, 0.3, 0, 3.14, 0]\n  movel(p1, a=1.2, v=0.25)\n"
            "  p1 = pose_trans(p1, p[0, 0, 0.1, 0, 0, 0])\n  movel(p1)\n  servoc(get_actual_tcp_pose())\n"
            "  movej(q_start)\n  if p1 == p1:\n    movej([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])\n  end\nend\n")
    parsed = urscript.parse({"f.script": text})
    assert [t.name for t in parsed.targets] == ["line 9"]
    assert [n.split(": NOT compensated: ") for n in parsed.notes] == [
        ["f.script:3: movel(p1, a=1.2, v=0.25)", "the target p1 is assigned 2 times (lines 2, 4): its value here "
                                                 "is not known"],
        ["f.script:5: movel(p1)", "the target p1 is assigned 2 times (lines 2, 4): its value here is not known"],
        ["f.script:6: servoc(get_actual_tcp_pose())", "the target is not a literal or a variable assigned one"],
        ["f.script:7: movej(q_start)", "the target is not a literal or a variable assigned one"]]


def test_moves_in_comments_and_strings_are_not_code():
    """A move in a ``#`` comment or a string is neither read nor rewritten; a ``#`` inside a
    string does not start a comment, and a variable assigned only in a comment is not assigned."""
    text = ("def f():\n"
            "  # movej([9, 9, 9, 9, 9, 9])  old target, kept for reference\n"
            "  # home = [5, 5, 5, 5, 5, 5]\n"
            "  home = [0.1, -1.5, 1.4, -1.5, -1.6, 0.0]\n"
            "  popup(\"next: movel(p[1, 1, 1, 0, 0, 0]) # not code\")\n"
            "  movej(home)  # movej([8, 8, 8, 8, 8, 8])\n"
            "  textmsg('#', \"x\")\n"
            "  movel(p[0.4, 0.1, 0.3, 0, 3.14, 0])\nend\n")
    parsed = urscript.parse({"f.script": text})
    assert [(t.name, t.line, t.values[0]) for t in parsed.targets] == [("home", 3, 0.1),
                                                                       ("line 8", 7, 0.4)]
    assert parsed.notes == ()


@pytest.mark.parametrize("line", ["movej([-0.44, -1.69.6187, 1.2, 0, 1.5, 0])",
                                  "movej([-0.443734 -1.696187, 1.2, 0, 1.5, 0])"])
def test_a_garbled_joint_list_is_refused_not_read_by_its_numbers(line):
    with pytest.raises(ProgramError, match="'f.script:2': not a comma-separated list of numbers"):
        urscript.parse({"f.script": f"def f():\n  {line}\nend\n"})
