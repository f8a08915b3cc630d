"""RAPID: declared and inline jointtargets and robtargets; tooldata and wobjdata."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import rapid
from tests.program.parse import samples


def test_hand_written_module():
    parsed = rapid.parse({"WeldDemo.mod": samples.RAPID_MOD})
    assert [(t.name, t.kind) for t in parsed.targets] == [
        ("jHome", "joint"), ("pApproach", "pose"), ("pWeld", "pose"),
        ("WeldDemo.mod line 11", "joint"), ("WeldDemo.mod line 14", "pose")]
    assert np.allclose(parsed.targets[2].values, [-237.6, -18.8, 620.4, -0.00253, 0.9025, 0.40816, -0.13745])
    assert np.allclose(parsed.base.translation, [1.0, -0.2, 0.0])
    assert np.allclose(parsed.base.rotation @ [1, 0, 0], [0, 1, 0], atol=1e-8)


def test_two_tools_are_not_guessed():
    text = samples.RAPID_MOD.replace("    PERS tooldata tWeld", "    PERS tooldata tA:=[TRUE,[[0,0,1],[1,0,0,0]],"
                                     "[1,[0,0,1],[1,0,0,0],0,0,0]];\n    PERS tooldata tWeld")
    parsed = rapid.parse({"m.mod": text})
    assert parsed.tool is None and "2 tooldata" in parsed.notes[0]


def test_a_short_robtarget_is_named():
    with pytest.raises(ProgramError, match="pX: a robtarget"):
        rapid.parse({"m.mod": "CONST robtarget pX:=[[1,2,3],[1,0,0]];\n"})


def test_movec_has_two_targets_cirpoint_and_topoint():
    """MoveC CirPoint, ToPoint: both inline robtargets are targets; a declared one is read from its
    declaration; a \\Conc switch before them and a commented-out move are skipped."""
    rob = "[[{x},0,500],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]]"
    text = ("MODULE M\n    CONST robtarget pCir:=" + rob.format(x=1) + ";\n    PROC main()\n"
            "        MoveC " + rob.format(x=2) + ", " + rob.format(x=3) + ", v100, z10, tool0;\n"
            "        MoveC \\Conc, pCir, " + rob.format(x=4) + ", v100, fine, tool0\\WObj:=wobj0;\n"
            "        ! MoveL " + rob.format(x=5) + ", v100, fine, tool0;\n"
            "        MoveL " + rob.format(x=6) + ", v100, fine, tool0;\n    ENDPROC\nENDMODULE\n")
    parsed = rapid.parse({"M.mod": text})
    assert [t.name for t in parsed.targets] == ["pCir", "M.mod line 4 (via)", "M.mod line 4 (end)",
                                                "M.mod line 5 (end)", "M.mod line 7"]
    assert [t.values[0] for t in parsed.targets] == [1, 2, 3, 4, 6]


_NINES = "[9E9,9E9,9E9,9E9,9E9,9E9]"
_UNREAD = rf"""MODULE M
  CONST robtarget p10 := [[600,0,800],[0,0,1,0],[0,0,0,0],{_NINES}];
  PROC main()
    MoveL p10, v100, fine, tool0;
    MoveLDO [[600,0,810],[0,0,1,0],[0,0,0,0],{_NINES}], v100, fine, tool0, do1, 1;
    MoveJDO p20, v100, fine, tool0, do1, 1;
    TriggL [[600,0,820],[0,0,1,0],[0,0,0,0],{_NINES}], v100, trig1, fine, tool0;
    TriggL p10, v100, trig1, fine, tool0;
    TriggC p10, [[600,0,830],[0,0,1,0],[0,0,0,0],{_NINES}], v100, trig1, fine, tool0;
    SearchL \Stop, di1, sp, p30, v100, tool0;
    SearchC di1, sp, p10, p10, v100, tool0;
    ArcLStart p10, v100, seam1, weld1, fine, tool0;
    ArcC p40, p10, v100, seam1, weld1, fine, tool0;
    MoveL Offs(p10, 0, 0, 100), v100, fine, tool0;
    MoveAbsJ jhome\NoEOffs, v100, fine, tool0;
  ENDPROC
ENDMODULE
"""


def test_points_not_read_are_named():
    """Inline points of Trigg*/Search*/Arc* and the like, undeclared names and expressions are left
    as written and named (file:line, why); declared names and inline Move* points (MoveLDO too)
    are read."""
    parsed = rapid.parse({"m.mod": _UNREAD})
    assert [t.name for t in parsed.targets] == ["p10", "m.mod line 5"]            # MoveLDO's inline point
    lines = [n.split(": NOT compensated: ") for n in parsed.notes]
    assert [(code.split(":")[1], why) for code, why in lines] == [
        ("6", "p20 is not a jointtarget or robtarget declared in the modules read"),
        ("7", "the inline point of TriggL is not read"),
        ("9", "the inline point of TriggC is not read"),
        ("10", "p30 is not a jointtarget or robtarget declared in the modules read"),
        ("13", "p40 is not a jointtarget or robtarget declared in the modules read"),
        ("14", "the point Offs(..) is computed, not a declared target"),
        ("15", "jhome is not a jointtarget or robtarget declared in the modules read")]
    assert lines[1][0].startswith("m.mod:7: TriggL [[600,0,820]")


def test_confdata_is_read_as_declared_and_checked():
    parsed = rapid.parse({"WeldDemo.mod": samples.RAPID_MOD})
    poses = [t for t in parsed.targets if t.kind == "pose"]
    assert [dict(t.declared) for t in poses] == [{"cf1": 0, "cf4": 0, "cf6": -1, "cfx": 0},
                                                 {"cf1": 0, "cf4": 0, "cf6": -1, "cfx": 0},
                                                 {"cf1": 0, "cf4": 0, "cf6": 0, "cfx": 0}]
    assert all(t.declared == () for t in parsed.targets if t.kind == "joint")
    with pytest.raises(ProgramError, match=r"confdata needs 4 integers \[cf1, cf4, cf6, cfx\], has \[0.0, 0.5"):
        rapid.parse({"m.mod": "MODULE m\n  CONST robtarget p:=[[1,2,3],[1,0,0,0],[0,0.5,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
                              "  PROC r()\n    MoveL p, v100, fine, tool0;\n  ENDPROC\nENDMODULE\n"})
