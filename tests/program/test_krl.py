"""KRL as a controller reads it: every line of the written .src and .dat is a KRL statement of
the forms below, the module's structure holds, and the files read back (targets, $TOOL, $BASE)
through the KRL reader of program/parse (issue 31; the ANTLR KRL grammar, run by hand, in
calib_oed/program/krl.py's docstring)."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.model.controller import controller_from_mapping
from calib_oed.program.continuous import MoveCheck
from calib_oed.program.format_common import steps
from calib_oed.program.formats import program_texts
from calib_oed.program.krl import KRL_NAME_LENGTH, TARGET_PREFIX
from calib_oed.program.parse import krl as krl_reader
from calib_oed.program.records import Move, Program
from calib_oed.program.settings import FrameSpec, Handshake, PayloadSpec

NUM = r"-?\d+(?:\.\d+)?"
NAME = r"[A-Za-z_$][A-Za-z0-9_$]{0,23}"     # KRL names: 24 characters
FRAME = r"\{X {0},Y {0},Z {0},A {0},B {0},C {0}\}".replace("{0}", NUM)
COMMENT = r"(?: ; [^\n]*)?"
#: The statements a written module holds, each a whole line (KUKA System Software 8: declarations,
#: PTP to a named target, WAIT SEC / WAIT FOR, outputs, system variables, interrupts, calls).
SRC_LINES = {
    "attribute": r"&ACCESS RVP|&REL 1",
    "def": rf"DEF ({NAME})\( \)",
    "end": r"END",
    "comment": r"; [^\n]*",
    "interrupt": r"  GLOBAL INTERRUPT DECL 3 WHEN \$STOPMESS==TRUE DO IR_STOPM \( \)|  INTERRUPT ON 3",
    "init": r"  BAS \(#INITMOV,0 \)",
    "frame": rf"  \$(TOOL|BASE)=({FRAME}){COMMENT}",
    "load": rf"  \$LOAD\.M={NUM}|  \$LOAD\.CM={FRAME}",
    "velocity": r"  \$VEL_AXIS\[[1-6]\]=100",
    "ptp": rf"  PTP ({NAME}){COMMENT}",
    "dwell": rf"  WAIT SEC {NUM}{COMMENT}",
    "output": rf"  \$OUT\[\d+\]=(?:TRUE|FALSE){COMMENT}",
    "wait": r"  WAIT FOR \$IN\[\d+\]",
    "call": rf"  ({NAME})\( \){COMMENT}",
}
DAT_LINES = {
    "attribute": r"&ACCESS RVP|&REL 1",
    "defdat": rf"DEFDAT ({NAME})",
    "enddat": r"ENDDAT",
    "decl": rf"DECL E6AXIS ({NAME})=\{{" + ",".join(f"A{i} {NUM}" for i in range(1, 7))
            + ",E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}",
}
#: Names of the controller's $config.dat and system modules a module must not declare.
GLOBALS = {"XHOME", "HOME", "BAS", "IR_STOPM", "$CONFIG"}


def _lines(text: str, forms: dict[str, str]) -> list[tuple[str, re.Match]]:
    out = []
    for line in text.splitlines():
        kind = next((k for k, rx in forms.items() if re.fullmatch(rx, line)), None)
        assert kind is not None, f"not a KRL statement of the writer's forms: {line!r}"
        out.append((kind, re.fullmatch(forms[kind], line)))
    return out


@pytest.fixture(scope="module")
def variants() -> dict[str, Program]:
    """Home, three poses, a move through a via point; with no options, a handshake by signals
    with tool, base and payload, a handshake routine, and a controller block."""
    rng = np.random.default_rng(31)
    home, poses, via = np.zeros(6), rng.uniform(-2, 2, size=(3, 6)), rng.uniform(-2, 2, size=(1, 6))
    ok = MoveCheck(True, False, 3, 0.1, "self:a|b")
    nodes = [0, 2, 3, 1, 0]
    moves = tuple(Move(a, b, np.vstack([home if a == 0 else poses[a - 1], *(via if (a, b) == (3, 1) else ()),
                                        home if b == 0 else poses[b - 1]]), 1.0, ok)
                  for a, b in zip(nodes[:-1], nodes[1:], strict=True))
    plain = Program("test", tuple(f"joint_a{i}" for i in range(1, 7)), home, poses, np.array([1, 2, 0]), moves,
                    1.5, {"design order": 9.0, "nearest neighbour": 8.0, "optimised": 7.0}, "lkh")
    frames = {"tool": FrameSpec(2, np.array([0.01, -0.02, 0.18]), np.array([0.1, -0.2, 0.3])),
              "base": FrameSpec(3, np.array([1.0, 0.5, -0.2]), np.array([0.0, 0.0, 1.2])),
              "payload": PayloadSpec(1.25, np.array([0.0, 0.01, 0.05]), 2)}
    kuka = {"name": "kuka", "angle": "deg", "joints": [{"sign": -1}, {}, {"offset": -90}, {}, {}, {}]}
    return {"plain": plain,
            "signals": dataclasses.replace(plain, handshake=Handshake(output=5, input=7), **frames),
            "routine": dataclasses.replace(plain, handshake=Handshake(routine="tracker_measure")),
            "controller": dataclasses.replace(plain, controller=controller_from_mapping(kuka, 6))}


@pytest.mark.parametrize("variant", ["plain", "signals", "routine", "controller"])
def test_every_line_is_a_statement_and_the_module_is_whole(variants, variant):
    program = variants[variant]
    files = program_texts(program, "krl", "cal_31")
    src, dat = _lines(files["cal_31.src"], SRC_LINES), _lines(files["cal_31.dat"], DAT_LINES)
    # one DEF ... END named as the file, the .dat's DEFDAT of the same name, attributes first
    assert [k for k, _ in src[:3]] == ["attribute", "attribute", "def"] and src[-1][0] == "end"
    assert [k for k, _ in dat[:3]] == ["attribute", "attribute", "defdat"] and dat[-1][0] == "enddat"
    assert [m.group(1) for k, m in src if k == "def"] == ["CAL_31"] == [m.group(1) for k, m in dat if k == "defdat"]
    assert sum(k in ("def", "end") for k, _ in src) == 2
    # every move goes to a target the .dat declares once; every declaration is used; none is global
    declared = [m.group(1) for k, m in dat if k == "decl"]
    moved = [m.group(1) for k, m in src if k == "ptp"]
    assert len(declared) == len(set(declared)) and set(declared) == set(moved)
    assert all(d.startswith(TARGET_PREFIX) and d.upper() not in GLOBALS for d in declared)
    # the interrupt is declared and on, and BAS initialises, before the first move; frames after BAS
    kinds = [k for k, _ in src]
    first_move = kinds.index("ptp")
    assert kinds.index("interrupt") < kinds.index("init") < first_move
    assert all(kinds.index("init") < i < first_move for i, k in enumerate(kinds) if k in ("frame", "load", "velocity"))
    # the measurement at each pose: a dwell, the signals, or the routine, never two of them
    hs = program.handshake
    want = "dwell" if hs is None else ("call" if hs.routine else "output")
    assert {"dwell", "call", "output"} & set(kinds) == {want}
    assert kinds.count("wait") == (len(program.poses) if want == "output" else 0)


@pytest.mark.parametrize("variant", ["plain", "signals", "controller"])
def test_files_read_back(variants, variant):
    """The KRL reader finds each declared target with the program's joint values [deg] (the
    controller's with a controller block: tests/program/test_controller_programs.py), and
    $TOOL/$BASE as the scene's frames."""
    program = variants[variant]
    parsed = krl_reader.parse(program_texts(program, "krl", "cal_31"))
    want = {TARGET_PREFIX + step.name: np.rad2deg(step.q) for step in steps(program)}
    assert {t.name for t in parsed.targets} == set(want) and not parsed.notes
    for target in parsed.targets:
        assert target.kind == "joint"
        np.testing.assert_allclose([n.value for n in target.numbers], want[target.name], atol=0.6e-4, rtol=0)
    for frame, got in ((program.tool, parsed.tool), (program.base, parsed.base)):
        if frame is None:
            assert got is None
            continue
        np.testing.assert_allclose(got.translation, frame.xyz, atol=1e-6)
        np.testing.assert_allclose(got.rotation, pin.rpy.rpyToMatrix(*frame.rpy), atol=1e-6)


@pytest.mark.parametrize("name", ["x" * (KRL_NAME_LENGTH + 1), "end", "Bas", "ir_stopm", "xcal_p1", "kalibrierung_ä"])
def test_module_names_the_controller_refuses(variants, name):
    with pytest.raises(ProgramError, match="KRL"):
        program_texts(variants["plain"], "krl", name)


def test_longest_module_name(variants):
    name = "c" * KRL_NAME_LENGTH
    assert f"DEF {name.upper()}( )" in program_texts(variants["plain"], "krl", name)[f"{name}.src"]
