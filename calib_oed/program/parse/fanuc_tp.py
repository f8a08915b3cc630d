r"""FANUC TP (ASCII ``.ls``): positions of the ``/POS`` section, joint or Cartesian.

Grammar used (FANUC *R-30iB Controller Operator's Manual (Basic Operation)*, "Program
structure", "Position data"; the ASCII ``.ls`` form the controller's ASCII upload accepts):
``P[k]{ GP1: UF : u, UT : t, J1= v deg, ..., J6= v deg };`` or with ``CONFIG : '...',
X = v mm, Y = v mm, Z = v mm, W = v deg, P = v deg, R = v deg`` (fixed XYZ angles,
:math:`R = R_z(R)R_y(P)R_x(W)`; ``P[k:"comment"]`` allowed). Only group ``GP1`` is read;
``CONFIG``, ``UF``/``UT`` numbers and other groups stay. User and tool frames are
controller data (numbered), not in the file: give them in the scene or with
``--tool``/``--base``, so every target must be in one tool frame ``UT`` and every
Cartesian target in one user frame ``UF`` (a joint position does not depend on
the user frame); a program that mixes them is refused, naming the frames, and a
note says which frames the targets are in. Comments: TP comment lines ``! text ;`` at most 32 characters, with
no ``;`` inside; they are appended at the end of ``/MN`` with the next line numbers, and
``LINE_COUNT`` in ``/ATTR`` (if present) is raised by their count: the only line besides
the targets that changes.

A motion statement of ``/MN`` (``J``, ``L``, ``C``, ``A``) moves to the ``P[k]`` read from ``/POS``.
Those whose position is not read are left as written and named in the notes (``file:line``,
why): a position register ``PR[..]`` (controller data), an indirect ``P[R[..]]``, a ``P[k]``
without a ``GP1`` position in ``/POS``, an incremental move (``INC``: an offset, not a point),
and a move with ``Offset``/``Tool_Offset``/``VOFFSET`` (its ``P[k]`` is compensated as a
point, the offset added to it is not).
"""

from __future__ import annotations

import re
import textwrap

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.poses import from_euler_mm_deg, in_order, to_euler_mm_deg
from calib_oed.program.parse.scan import NUMBER, Number, line_of, skipped_move
from calib_oed.program.parse.targets import Language, ParsedProgram, Target

_POS = re.compile(r"^[ \t]*P\[(\d+)(?::[^\]]*)?\][ \t]*\{", re.MULTILINE)
_GP1 = re.compile(r"GP1[ \t]*:")
_GROUP = re.compile(r"GP\d+[ \t]*:")
_JOINT = re.compile(rf"\bJ([1-6])[ \t]*=[ \t]*({NUMBER})[ \t]*deg")
_CART = re.compile(rf"\b([XYZWPR])[ \t]*=[ \t]*({NUMBER})[ \t]*(?:mm|deg)")
_FRAMES = re.compile(r"\bUF[ \t]*:[ \t]*(\w+)[ \t]*,[ \t]*UT[ \t]*:[ \t]*(\w+)")
_MN_LINE = re.compile(r"^[ \t]*(\d+):", re.MULTILINE)
_MOTION = re.compile(r"^[ \t]*\d+:[ \t]*([JLCA])[ \t]+([^;]*);", re.MULTILINE)
_POINT = re.compile(r"\b(PR|P)\[(R\[[^\]]*\]|[^\]\[]*)\]")
_OFFSET = re.compile(r"\b(Tool_Offset|VOFFSET|Offset)\b", re.IGNORECASE)
COMMENT_WIDTH = 32


def _comment(text: str) -> str:
    return f"! {text.replace(';', ',')} ;"


def _insert(text: str, comments: list[tuple[int, str]]) -> str:
    """The comments as numbered ``/MN`` lines after its last line; ``LINE_COUNT`` raised."""
    mn = text.find("/MN")
    pos = text.find("/POS", mn)
    end = pos if pos >= 0 else text.find("/END", mn)
    if mn < 0 or end < 0:
        raise ProgramError("program", "tp", "no /MN section: not a TP program")
    numbers = [int(m.group(1)) for m in _MN_LINE.finditer(text, mn, end)]
    last = max(numbers, default=0)
    wrapped = []
    for _, line in comments:
        body = line.strip()[1:-1].strip()          # drop "!" and ";"
        wrapped += textwrap.wrap(body, COMMENT_WIDTH - 4) or [""]
    newline = "\r\n" if "\r\n" in text else "\n"
    added = "".join(f"{last + k:4d}:  ! {c} ;{newline}" for k, c in enumerate(wrapped, start=1))
    text = text[:end] + added + text[end:]
    return re.sub(r"(LINE_COUNT[ \t]*=[ \t]*)(\d+)", lambda m: f"{m.group(1)}{int(m.group(2)) + len(wrapped)}",
                  text, count=1)


LANGUAGE = Language("tp", "deg", *in_order(from_euler_mm_deg, to_euler_mm_deg), _comment, (4, 3, 4), _insert)


def parse(texts: dict[str, str]) -> ParsedProgram:
    """Targets of TP programs ``{name.ls: text}``."""
    targets, frames = [], {}
    for file, text in texts.items():
        start = text.find("/POS")
        if start < 0:
            continue
        for m in _POS.finditer(text, start):
            close = text.find("};", m.end())
            if close < 0:
                raise ProgramError("program", file, f"P[{m.group(1)}] at line {line_of(text, m.start()) + 1} does not close")
            g1 = _GP1.search(text, m.end(), close)
            if g1 is None:
                continue
            nxt = _GROUP.search(text, g1.end(), close)
            stop = nxt.start() if nxt else close
            joints = {int(j.group(1)): Number(j.start(2), j.end(2), j.group(2))
                      for j in _JOINT.finditer(text, g1.end(), stop)}
            cart = {c.group(1): Number(c.start(2), c.end(2), c.group(2)) for c in _CART.finditer(text, g1.end(), stop)}
            name = f"P[{m.group(1)}]"
            uf_ut = _FRAMES.search(text, g1.end(), stop)
            frames[name] = uf_ut.groups() if uf_ut else ("?", "?")
            if len(joints) == 6:
                targets.append(Target(name, "joint", file, 0, tuple(joints[k] for k in range(1, 7))))
            elif all(k in cart for k in "XYZWPR"):
                targets.append(Target(name, "pose", file, 0, tuple(cart[k] for k in "XYZWPR")))
            else:
                raise ProgramError("program", file, f"{name}: GP1 needs J1..J6 (deg) or X, Y, Z (mm), "
                                   "W, P, R (deg)")
    notes = _one_frame_pair(targets, frames) + _unread_points(texts, {(t.file, t.name) for t in targets})
    return ParsedProgram(LANGUAGE, dict(texts), tuple(targets), notes=notes)


def _unread_points(texts: dict[str, str], read: set[tuple[str, str]]) -> tuple[str, ...]:
    """Notes naming the motion statements of ``/MN`` whose positions are not read (module docstring)."""
    notes = []
    for file, text in texts.items():
        mn = text.find("/MN")
        end = min((i for i in (text.find("/POS", mn), text.find("/END", mn)) if i >= 0), default=len(text))
        if mn < 0:
            continue
        for m in _MOTION.finditer(text, mn, end):
            why = []
            for p in _POINT.finditer(m.group(2)):
                number = p.group(2).split(":")[0].strip()
                if p.group(1) == "PR":
                    why.append(f"PR[{p.group(2)}] is a position register (controller data, not in the file)")
                elif not number.isdigit():
                    why.append(f"P[{p.group(2)}] is indirect (a register's value)")
                elif (file, f"P[{number}]") not in read:
                    why.append(f"P[{number}] has no GP1 position in /POS")
            if re.search(r"\bINC\b", m.group(2)):
                why.append("INC: the position is an offset from where the robot is, not a point")
            if _OFFSET.search(m.group(2)):
                why.append(f"{_OFFSET.search(m.group(2)).group(1)}: the position is compensated, the offset "
                           "added to it is not")
            if why:
                notes.append(skipped_move(file, text, m.start(1), "; ".join(why)))
    return tuple(notes)


def _one_frame_pair(targets: list[Target], frames: dict[str, tuple[str, str]]) -> tuple[str, ...]:
    """The note naming the targets' UF/UT; ProgramError when they mix tool frames, or
    Cartesian targets mix user frames (one --tool and one --base per program)."""
    for k, what, option in ((1, "UT", "--tool"), (0, "UF", "--base")):
        first: dict[str, str] = {}
        for t in targets:
            if what == "UT" or t.kind == "pose":
                first.setdefault(frames[t.name][k], t.name)
        if len(first) > 1:
            named = ", ".join(f"{name} in {what} {frame}" for frame, name in first.items())
            raise ProgramError("program", targets[0].file, f"targets in different {what}s ({named}): one "
                               f"{option} compensates one program; split the program by {what}")
    ufs = sorted({frames[t.name][0] for t in targets if t.kind == "pose"})
    uts = sorted({frames[t.name][1] for t in targets})
    uf = f"Cartesian targets in UF {ufs[0]} (--base), " if ufs else ""
    return (f"{uf}targets in UT {uts[0]} (--tool): the frames are controller data, not in the file",)
