"""Programs of a scene with a controller block: every format writes the controller's joint
values c = A^-1 (q - b) (parsed back and compared with the map, not with the writers'
own step list) and states the convention in its header."""

from __future__ import annotations

import csv
import dataclasses
import io
import re

import numpy as np
import pytest

from calib_oed.model.controller import controller_from_mapping
from calib_oed.program.continuous import MoveCheck
from calib_oed.program.formats import program_texts
from calib_oed.program.records import Move, Program

NUM = r"(-?\d+\.\d+)"
JOINTS = tuple(f"joint_{i}" for i in range(1, 7))
FANUC = {"name": "fanuc", "angle": "deg",
         "joints": [{}, {}, {"sign": -1, "offset": 90}, {}, {}, {"sign": -1}],
         "couplings": [{"joint": 3, "from": 2, "ratio": 1.0}]}


@pytest.fixture(scope="module")
def programs():
    """The same three-pose program without and with a FANUC-style controller block."""
    rng = np.random.default_rng(8)
    home = np.zeros(6)
    poses = rng.uniform(-1.5, 1.5, size=(3, 6))
    ok = MoveCheck(True, False, 3, 0.1, "self:a|b")
    nodes = [0, 2, 3, 1, 0]
    moves = tuple(Move(a, b, np.vstack([home if a == 0 else poses[a - 1],
                                        home if b == 0 else poses[b - 1]]), 1.0, ok)
                  for a, b in zip(nodes[:-1], nodes[1:], strict=True))
    plain = Program("test", JOINTS, home, poses, np.array([1, 2, 0]), moves, 2.0,
                    {"design order": 9.0, "nearest neighbour": 8.0, "optimised": 7.0}, "lkh")
    return plain, dataclasses.replace(plain, controller=controller_from_mapping(FANUC, 6))


def _targets_file(program, fmt) -> str:
    """The text of the file holding the joint targets (KRL: the ``.dat``)."""
    files = program_texts(program, fmt, "calib_program")
    return files.get("calib_program.dat") or next(iter(files.values()))


def _flat(program, fmt) -> str:
    """Every file of the program, comment lines joined (TP wraps its comments at 30 characters)."""
    text = "".join(program_texts(program, fmt, "calib_program").values())
    return re.sub(r"\s*;?\n\s*\d*:?\s*! ", " ", text)


def _poses(fmt, text):
    """Pose number -> joint values as written (deg; URScript and CSV: rad)."""
    if fmt == "krl":
        found = re.findall(r"DECL E6AXIS XCAL_P(\d+)=\{" + ",".join(f"A{i} {NUM}" for i in range(1, 7)), text)
    elif fmt == "rapid":
        found = re.findall(r"CONST jointtarget jP(\d+):=\[\[" + ",".join([NUM] * 6), text)
    elif fmt == "tp":
        index = dict(re.findall(r"J P\[(\d+):pose (\d+)\]", text))
        blocks = re.findall(r"P\[(\d+)\]\{\n   GP1:\n\tUF : 0, UT : 1,\n" + r"\tJ1= {0} deg,\tJ2= {0} deg,"
                            r"\tJ3= {0} deg,\n\tJ4= {0} deg,\tJ5= {0} deg,\tJ6= {0} deg".replace("{0}", NUM),
                            text)
        found = [(index[b[0]], *b[1:]) for b in blocks if b[0] in index]
    elif fmt == "urscript":
        found = re.findall(r"  # pose (\d+)\n  movej\(\[" + ", ".join([NUM] * 6), text)
    else:
        rows = csv.DictReader(io.StringIO("\n".join(ln for ln in text.splitlines() if not ln.startswith("#"))))
        found = [(r["pose"], *(r[f"{j}_rad"] for j in JOINTS)) for r in rows if r["kind"] == "pose"]
    return {int(f[0]): np.array(f[1:], float) for f in found}


@pytest.mark.parametrize("fmt", ["krl", "rapid", "tp", "urscript", "csv"])
def test_programs_write_controller_values(programs, fmt):
    plain, ctrl = programs
    conv = ctrl.controller
    text = _targets_file(ctrl, fmt)
    radians = fmt in ("urscript", "csv")
    got = _poses(fmt, text)
    assert sorted(got) == [1, 2, 3]
    tol = 1e-6 if radians else 0.6e-4
    for k, values in got.items():
        expected = conv.to_controller(ctrl.poses[k - 1])
        np.testing.assert_allclose(values, expected if radians else np.rad2deg(expected), atol=tol)
        # FANUC J3 is J3_urdf relative to the horizontal: c3 = -(q3 - 90 deg) - c2
        q = ctrl.poses[k - 1]
        assert abs(expected[2] - (-(q[2] - np.pi / 2) - q[1])) < 1e-12
    # the plain program writes the URDF angles: the two differ
    plain_got = _poses(fmt, _targets_file(plain, fmt))
    assert not np.allclose(plain_got[1], got[1], atol=1e-3)


@pytest.mark.parametrize("fmt", ["krl", "rapid", "tp", "urscript", "csv"])
def test_headers_state_the_convention(programs, fmt):
    plain, ctrl = programs
    text = _flat(ctrl, fmt)
    assert "controller joint values" in text and "controller fanuc" in text
    assert "no controller block" not in text and "NOT the FANUC J3" not in text
    assert "no controller block" in _flat(plain, fmt)
