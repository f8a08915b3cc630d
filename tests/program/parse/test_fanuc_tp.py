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
