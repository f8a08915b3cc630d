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
    assert "line 3" in parsed.notes[0]


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
    assert parsed.notes == ("f.script line 5: the move's end point is not a literal or a variable assigned "
                            "one: not compensated",)
