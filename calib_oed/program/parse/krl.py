r"""KUKA KRL (``.src`` + ``.dat``): ``E6AXIS``/``AXIS`` joint and ``E6POS``/``POS`` Cartesian targets.

Grammar used (KUKA System Software 8.x, *Operating and Programming Instructions for
System Integrators*, "Structure data types" and "Motion programming: KRL"): a target is an
aggregate ``{A1 v, ..., A6 v, E1 v, ...}`` [deg] (``AXIS``/``E6AXIS``) or
``{X v, Y v, Z v, A v, B v, C v, S s, T t, E1 ..}`` [mm, deg] (``POS``/``E6POS``;
:math:`R = R_z(A)R_y(B)R_x(C)`), declared in the ``.dat`` (``DECL E6AXIS XP1={...}``) or
written inline after ``PTP``/``LIN``/``CIRC`` (and the spline moves ``SPTP``/``SLIN``/
``SCIRC``/``SPL``) in the ``.src``; a circular move takes two points, the auxiliary (via)
point and the end point, and each written inline is a target (named ``... (via)`` and
``... (end)``). A move to a name declared in the files read (``PTP XP1``) moves to that
declaration's target. A move whose point is not read is left as written and named in the notes
(``file:line``, why): a relative move (``PTP_REL``, ``LIN_REL``, ``CIRC_REL`` and the spline
``_REL`` moves: an offset from where the robot is), a name not declared as ``E6AXIS``/``AXIS``/
``E6POS``/``POS`` in the files read (``XHOME`` of ``$config.dat``), any other expression
(``XP1:{A1 10}``, ``$POS_ACT``). Only A1..A6 or X..C are
rewritten; ``S``, ``T`` (decimal or ``'B...'``, read into :attr:`Target.declared` and
checked against the joints, :mod:`calib_oed.program.compensate`) and external axes stay as
written. ``$TOOL={X .., ..., C ..}`` and
``$BASE={...}`` literals in the ``.src`` declare the TCP :math:`T_{F,E}` and base
:math:`T_{W,B}` (``$TOOL=TOOL_DATA[1]`` refers to the controller's ``$config.dat``, which is
not read: give the tool in the scene or with ``--tool``). ``FRAME`` declarations are not
targets. Comments are ``;`` lines after the target's line.
"""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.poses import from_euler_mm_deg, to_euler_mm_deg
from calib_oed.program.parse.scan import NUMBER, Number, line_of, skipped_move
from calib_oed.program.parse.targets import Language, ParsedProgram, target_at

_AGG = re.compile(r"\{([^{}]*)\}")
_COMP = re.compile(rf"(?<![\w$])(A[1-6]|[XYZABCST])\s+({NUMBER})")
_DECL = re.compile(r"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(E6AXIS|AXIS|E6POS|POS)[ \t]+(\w+)[ \t]*=[ \t]*\{",
                   re.IGNORECASE | re.MULTILINE)
_MOVE = re.compile(r"^[ \t]*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL)[ \t]+", re.IGNORECASE | re.MULTILINE)
_CIRCULAR = ("CIRC", "SCIRC")
_RELATIVE = re.compile(r"^[ \t]*(S?PTP|S?LIN|S?CIRC)_REL\b", re.IGNORECASE | re.MULTILINE)
_NAME = re.compile(r"(\w+)(?:[ \t]+\w.*)?[ \t]*$")
_FRAME = re.compile(r"^[ \t]*\$(TOOL|BASE)[ \t]*=[ \t]*\{", re.IGNORECASE | re.MULTILINE)
_JOINTS = tuple(f"A{i}" for i in range(1, 7))
_POSE = ("X", "Y", "Z", "A", "B", "C")
_STATUS = re.compile(r"(?<![\w$])([ST])\s+(?:'B([01]+)'|(\d+))(?![\w.])", re.IGNORECASE)


def _pose_from(v: np.ndarray) -> pin.SE3:
    x, y, z, a, b, c = v
    return from_euler_mm_deg(x, y, z, c, b, a)


def _pose_to(m: pin.SE3, old: np.ndarray) -> np.ndarray:
    xyz, rpy = to_euler_mm_deg(m, near=old[[5, 4, 3]])
    return np.r_[xyz, rpy[2], rpy[1], rpy[0]]


LANGUAGE = Language("krl", "deg", _pose_from, _pose_to, lambda text: f"; {text}", (4, 3, 4))


def _aggregate(text: str, brace: int, what: str, file: str) -> tuple[str, dict[str, Number]]:
    """(kind, components) of the aggregate opening at ``brace``."""
    m = _AGG.match(text, brace)
    if m is None:
        raise ProgramError("program", file, f"{what}: the aggregate at line {line_of(text, brace) + 1} does not close")
    comps = {c.group(1).upper(): Number(c.start(2), c.end(2), c.group(2))
             for c in _COMP.finditer(text, m.start(1), m.end(1))}
    if all(k in comps for k in _JOINTS):
        return "joint", {k: comps[k] for k in _JOINTS}
    if all(k in comps for k in _POSE):
        return "pose", {k: comps[k] for k in _POSE}
    raise ProgramError("program", file, f"{what} (line {line_of(text, brace) + 1}): a target needs all of "
                       f"A1..A6 or all of X, Y, Z, A, B, C; it has {sorted(comps)}")


def _status(text: str, brace: int) -> tuple[tuple[str, int], ...]:
    """``S`` and ``T`` of the aggregate at ``brace`` (decimal or ``'B0110'``), as declared."""
    m = _AGG.match(text, brace)
    found = {c.group(1).upper(): int(c.group(2), 2) if c.group(2) else int(c.group(3))
             for c in _STATUS.finditer(text, m.start(1), m.end(1))}
    return tuple((k, found[k]) for k in ("S", "T") if k in found)


def _move_points(text: str, move: re.Match, file: str) -> list[tuple[int, str, str]]:
    """(start, name, argument text) of a move's points: the first argument, the first two of a
    circular move (via, end); arguments end at the line's end or a ``;``."""
    args, depth, start = [], 0, move.end()
    for k in range(move.end(), len(text) + 1):
        c = text[k] if k < len(text) else "\n"
        depth += (c == "{") - (c == "}")
        if depth <= 0 and c in ",;\r\n":
            args.append((start + len(text[start:k]) - len(text[start:k].lstrip()), text[start:k].strip()))
            start = k + 1
            if c != ",":
                break
    line = f"{file} line {line_of(text, move.start()) + 1}"
    if move.group(1).upper() not in _CIRCULAR:
        return [(args[0][0], line, args[0][1])]
    return [(a, f"{line} ({which})", arg) for (a, arg), which in zip(args[:2], ("via", "end"), strict=False)]


def _unread_points(texts: dict[str, str]) -> list[str]:
    """Notes naming the moves whose points are not read (module docstring), in file order."""
    declared = {m.group(2).upper() for text in texts.values() for m in _DECL.finditer(text)}
    notes = []
    for file, text in texts.items():
        found = [(m.start(), f"a relative move ({m.group(1).upper()}_REL): its target is an offset from where "
                  "the robot is, not a point") for m in _RELATIVE.finditer(text)]
        for m in _MOVE.finditer(text):
            for start, point, arg in _move_points(text, m, file):
                name = _NAME.match(arg)
                if arg.startswith("{") or (name and name.group(1).upper() in declared):
                    continue
                which = "the " + point[point.index("(") + 1:-1] + " point" if point.endswith(")") else "its point"
                found.append((start, f"{which} {name.group(1)} is not an E6AXIS, AXIS, E6POS or POS declared in "
                              "the files read (its .dat not given, or $config.dat)" if name else
                              f"{which} {arg!r} is not a declared name or an aggregate"))
        notes += [skipped_move(file, text, pos, why) for pos, why in sorted(found)]
    return notes


def parse(texts: dict[str, str]) -> ParsedProgram:
    """Targets of a KRL module: ``{name.src: text, name.dat: text}`` (either may be missing)."""
    targets, tool, base, notes = [], None, None, []
    for file in sorted(texts, key=lambda f: not f.lower().endswith(".dat")):     # .dat first
        text = texts[file]
        found = [(m.end() - 1, m.group(2), m.group(1).upper()) for m in _DECL.finditer(text)]
        found += [(brace, name, None) for m in _MOVE.finditer(text) for brace, name, _ in _move_points(text, m, file)
                  if text.startswith("{", brace)]
        for brace, name, decl in sorted(found):
            what = name
            kind, comps = _aggregate(text, brace, what, file)
            if decl is not None and (kind == "joint") != decl.endswith("AXIS"):
                raise ProgramError("program", file, f"{name}: a {decl} holds {kind} values")
            end = _AGG.match(text, brace).end()
            targets.append(target_at(text, brace, end, what, kind, file, comps.values(),
                                     declared=_status(text, brace) if kind == "pose" else ()))
        for m in _FRAME.finditer(text):
            kind, comps = _aggregate(text, m.end() - 1, f"${m.group(1)}", file)
            if kind != "pose":
                raise ProgramError("program", file, f"${m.group(1)} must be a FRAME {{X, Y, Z, A, B, C}}")
            frame = _pose_from(np.array([n.value for n in comps.values()]))
            if m.group(1).upper() == "TOOL":
                if tool is not None and not np.allclose(tool.homogeneous, frame.homogeneous):
                    raise ProgramError("program", file, "$TOOL is set to two different frames: compensate "
                                       "one tool per program (split the program)")
                tool = frame
            else:
                if base is not None and not np.allclose(base.homogeneous, frame.homogeneous):
                    raise ProgramError("program", file, "$BASE is set to two different frames: compensate "
                                       "one base per program (split the program)")
                base = frame
        if re.search(r"\$TOOL[ \t]*=[ \t]*TOOL_DATA", text, re.IGNORECASE):
            notes.append(f"{file}: $TOOL=TOOL_DATA[..] refers to $config.dat (not read): the tool is the "
                         "scene's or --tool's")
    return ParsedProgram(LANGUAGE, dict(texts), tuple(targets), tool, base, tuple(notes + _unread_points(texts)))
