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
