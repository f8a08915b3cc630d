"""FANUC TP: /POS positions in joint and Cartesian form; comments within TP's limits."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import fanuc_tp
from tests.program.parse import samples


def test_hand_written_program():
    parsed = fanuc_tp.parse({"WELD_DEMO.ls": samples.TP_LS})
    assert [(t.name, t.kind) for t in parsed.targets] == [("P[1]", "joint"), ("P[2]", "pose"), ("P[3]", "pose")]
    assert np.allclose(parsed.targets[0].values, [10, -80, 95, 0, 30, 0])
    assert np.allclose(parsed.targets[1].values, [-16.4, -227.4, 889.6, 180, 45, 80])


def test_comments_are_numbered_short_and_without_semicolons():
    out = fanuc_tp.LANGUAGE.insert_comments(samples.TP_LS, [(0, fanuc_tp._comment("P[1] res 0.012mm; SING"))])
    lines = out.splitlines()
    assert lines[lines.index("/POS") - 1] == "   6:  ! P[1] res 0.012mm, SING ;"
    assert "LINE_COUNT\t= 6;" in out


def test_incomplete_position_is_named():
    text = samples.TP_LS.replace("\tJ4=      .000 deg,\tJ5=    30.000 deg,\tJ6=      .000 deg\n", "")
    with pytest.raises(ProgramError, match=r"P\[1\]: GP1 needs"):
        fanuc_tp.parse({"p.ls": text})


def test_the_targets_frames_are_noted():
    parsed = fanuc_tp.parse({"WELD_DEMO.ls": samples.TP_LS})
    assert parsed.notes == ("Cartesian targets in UF 1 (--base), targets in UT 1 (--tool): the frames are "
                            "controller data, not in the file",)


def _in_frames(p3_uf: int, p3_ut: int, p1_uf: int = 1) -> str:
    text = samples.TP_LS.replace('P[3:"weld"]{\n   GP1:\n\tUF : 1, UT : 1,',
                                 f'P[3:"weld"]{{\n   GP1:\n\tUF : {p3_uf}, UT : {p3_ut},')
    return text.replace('P[1:"HOME"]{\n   GP1:\n\tUF : 1,', f'P[1:"HOME"]{{\n   GP1:\n\tUF : {p1_uf},')


@pytest.mark.parametrize("text, message", [
    (_in_frames(1, 2), r"targets in different UTs \(P\[1\] in UT 1, P\[3\] in UT 2\)"),
    (_in_frames(3, 1), r"targets in different UFs \(P\[2\] in UF 1, P\[3\] in UF 3\)"),
], ids=["tool-frames", "user-frames"])
def test_a_program_mixing_user_or_tool_frames_is_refused(text, message):
    """One --tool and one --base compensate a program: targets in other frames would be wrong."""
    with pytest.raises(ProgramError, match=message):
        fanuc_tp.parse({"p.ls": text})


def test_a_joint_target_in_another_user_frame_is_accepted():
    """A joint position does not depend on the user frame (a home taught in UF 0)."""
    parsed = fanuc_tp.parse({"p.ls": _in_frames(1, 1, p1_uf=0)})
    assert [t.kind for t in parsed.targets] == ["joint", "pose", "pose"]


def test_moves_whose_positions_are_not_read_are_named():
    """PR[] registers, indirect P[R[]], INC, offsets and a P[k] without a position are left as
    written and named (file:line, why); the moves to positions read are not."""
    moves = ("   5:L P[3:weld] 100mm/sec FINE    ;\n"
             "   6:L PR[4] 100mm/sec FINE    ;\n"
             "   7:L P[2] 100mm/sec FINE INC    ;\n"
             "   8:J P[R[1]] 50% FINE    ;\n"
             "   9:L P[3] 100mm/sec FINE Offset,PR[2]    ;\n"
             "  10:C P[2]    \n"
             "    :  P[7] 100mm/sec FINE    ;\n")
    text = samples.TP_LS.replace("   5:L P[3:weld] 100mm/sec FINE    ;\n", moves)
    parsed = fanuc_tp.parse({"p.ls": text})
    assert [t.name for t in parsed.targets] == ["P[1]", "P[2]", "P[3]"]
    named = [n.split(": NOT compensated: ") for n in parsed.notes[1:]]
    assert [(code.split(":")[1], why) for code, why in named] == [
        ("15", "PR[4] is a position register (controller data, not in the file)"),
        ("16", "INC: the position is an offset from where the robot is, not a point"),
        ("17", "P[R[1]] is indirect (a register's value)"),
        ("18", "PR[2] is a position register (controller data, not in the file); Offset: the position is "
               "compensated, the offset added to it is not"),
        ("19", "P[7] has no GP1 position in /POS")]
    assert named[0][0] == "p.ls:15: 6:L PR[4] 100mm/sec FINE ;"
    assert fanuc_tp.parse({"p.ls": samples.TP_LS}).notes[1:] == ()
