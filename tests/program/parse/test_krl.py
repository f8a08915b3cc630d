"""KRL: targets of .dat declarations and inline moves; $TOOL/$BASE; the grammar's errors."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import krl
from tests.program.parse import samples


def test_hand_written_module():
    parsed = krl.parse({"weld_demo.src": samples.KRL_SRC, "weld_demo.dat": samples.KRL_DAT})
    assert [(t.name, t.kind, t.file) for t in parsed.targets] == [
        ("XHOME", "joint", "weld_demo.dat"), ("XP2", "pose", "weld_demo.dat"), ("XP4", "pose", "weld_demo.dat"),
        ("weld_demo.src line 16", "joint", "weld_demo.src"), ("weld_demo.src line 18", "pose", "weld_demo.src")]
    assert np.allclose(parsed.targets[1].values, [-16.4, -227.4, 889.6, 80.0, 45.0, 180.0])
    assert np.allclose(parsed.tool.translation, [0.0125, 0.0, 0.18])
    assert [t.declared for t in parsed.targets] == [(), (("S", 6), ("T", 50)), (("S", 2), ("T", 10)), (),
                                                    (("S", 2), ("T", 35))]


def test_status_and_turn_in_binary_are_read():
    parsed = krl.parse({"p.dat": "DECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0,S 'B110',T 'B100011'}\n"
                                 "DECL POS XP2={X 1,Y 2,Z 3,A 0,B 0,C 0,T 5}\n"})
    assert [t.declared for t in parsed.targets] == [(("S", 6), ("T", 35)), (("T", 5),)]


@pytest.mark.parametrize("text, message", [
    ("DECL E6AXIS XP1={A1 0,A2 0,A3 0}\n", "needs all of"),
    ("DECL E6AXIS XP1={X 0,Y 0,Z 0,A 0,B 0,C 0}\n", "holds pose values"),
    ("$TOOL={A1 0,A2 0,A3 0,A4 0,A5 0,A6 0}\n", "FRAME"),
    ("$TOOL={X 1,Y 0,Z 0,A 0,B 0,C 0}\n$TOOL={X 2,Y 0,Z 0,A 0,B 0,C 0}\n", "two different"),
])
def test_errors_name_the_target(text, message):
    with pytest.raises(ProgramError, match=message):
        krl.parse({"p.src": text})


def test_tool_data_reference_is_noted():
    parsed = krl.parse({"p.src": "$TOOL=TOOL_DATA[1]\nPTP {A1 0,A2 -90,A3 90,A4 0,A5 30,A6 0}\n"})
    assert "config.dat" in parsed.notes[0]


def test_a_circular_move_has_two_targets_via_and_end():
    """CIRC {via},{end}: both points are targets (the end point is not left uncompensated); a named
    via point comes from the .dat, an inline end point is still read; spline moves too."""
    src = ("DEF c( )\n"
           "CIRC {X 10,Y 20,Z 30,A 0,B 90,C 0},{X 40,Y 50,Z 60,A 0,B 90,C 0} C_DIS ; arc\n"
           "CIRC XAUX, {X 70,Y 80,Z 90,A 0,B 90,C 0}, CA 90\n"
           "SCIRC {X 1,Y 2,Z 3,A 0,B 90,C 0}, {X 4,Y 5,Z 6,A 0,B 90,C 0}\n"
           "SLIN {X 7,Y 8,Z 9,A 0,B 90,C 0}\n"
           "LIN_REL {X 100}\n"
           "END\n")
    parsed = krl.parse({"c.src": src})
    assert [t.name for t in parsed.targets] == [
        "c.src line 2 (via)", "c.src line 2 (end)", "c.src line 3 (end)", "c.src line 4 (via)",
        "c.src line 4 (end)", "c.src line 5"]
    assert [t.values[0] for t in parsed.targets] == [10, 40, 70, 1, 4, 7]


def test_moves_whose_points_are_not_read_are_named():
    """Relative moves, names not declared in the files read and other expressions are left as
    written and named (file:line, why); a move to a declared name and inline points are not."""
    src = ("DEF m( )\n"
           "PTP XP1 C_PTP\n"
           "PTP_REL {A1 5}\n"
           "LIN_REL {X 100} C_DIS\n"
           "SCIRC_REL {X 1,Y 2,Z 0},{X 2,Y 0,Z 0}\n"
           "PTP XHOME\n"
           "CIRC XAUX, {X 70,Y 80,Z 90,A 0,B 90,C 0}, CA 90\n"
           "LIN XP1:{Z 50}\n"
           "LIN $POS_ACT\n"
           "END\n")
    dat = "DECL E6AXIS XP1={A1 0,A2 -90,A3 90,A4 0,A5 30,A6 0}\n"
    parsed = krl.parse({"m.src": src, "m.dat": dat})
    assert [t.name for t in parsed.targets] == ["XP1", "m.src line 7 (end)"]
    assert [n.split(": NOT compensated: ")[0] for n in parsed.notes] == [
        "m.src:3: PTP_REL {A1 5}", "m.src:4: LIN_REL {X 100} C_DIS", "m.src:5: SCIRC_REL {X 1,Y 2,Z 0},{X 2,Y 0,Z 0}",
        "m.src:6: PTP XHOME", "m.src:7: CIRC XAUX, {X 70,Y 80,Z 90,A 0,B 90,C 0}, CA 90", "m.src:8: LIN XP1:{Z 50}",
        "m.src:9: LIN $POS_ACT"]
    assert "relative move (SCIRC_REL)" in parsed.notes[2] and "the via point XAUX is not" in parsed.notes[4]
    assert "XHOME is not an E6AXIS" in parsed.notes[3] and "'$POS_ACT' is not a declared name" in parsed.notes[6]
    assert "XP1 C_PTP" in krl.parse({"m.src": src}).notes[0]          # without the .dat, XP1 is not read
