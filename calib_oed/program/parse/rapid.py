r"""ABB RAPID (``.mod``): ``jointtarget`` and ``robtarget`` targets, ``tooldata`` and ``wobjdata``.

Grammar used (ABB *Technical reference manual - RAPID Instructions, Functions and Data
types*, data types ``jointtarget``, ``robtarget``, ``orient``, ``tooldata``, ``wobjdata``):
``jointtarget`` = ``[[rax_1, ..., rax_6], [eax_a, ..., eax_f]]`` [deg];
``robtarget`` = ``[[x, y, z], [q1, q2, q3, q4], [cf1, cf4, cf6, cfx], [eax..]]``
[mm; quaternion :math:`q_1 = w`]. Targets are declared (``CONST|PERS|VAR [LOCAL]
jointtarget|robtarget name := [...];``) or written inline as the first argument of a
``Move*`` instruction (``MoveC*``: its first two, ``CirPoint`` and ``ToPoint``, named
``... (via)`` and ``... (end)``; switches such as ``\Conc`` before them skipped). Only ``rax`` or ``x, y, z, q1..q4`` are rewritten; ``confdata`` and
external axes stay (``confdata`` is read into :attr:`Target.declared`: a target the nominal
controller would reach with other joints than those compensated is named). A module declaring exactly one ``tooldata`` (``[robhold, [[x, y, z],
[q1..q4]], load]``) and at most one ``wobjdata`` (``[robhold, ufprog, ufmec, uframe,
oframe]``, base :math:`T_{W,B} = uframe\,oframe`) gives the tool and base; with several,
the scene's or ``--tool``/``--base`` apply and a note says so. Comments are ``!`` lines.

A move to a name declared in the modules read moves to that declaration's target. Points the
parser does not read are left as written and named in the notes (``file:line``, why): a name not
declared as ``jointtarget``/``robtarget`` in the modules read, an expression (``Offs(p10, ..)``,
``RelTool(..)``, ``CRobT()``), and inline points of the other motion instructions (by their
point arguments: ``TriggL``/``TriggJ``/``ArcL*``/``CapL``/``SpotL``/``SpotJ``/``DispL``/``PaintL``
the first, ``TriggC``/``ArcC*``/``CapC``/``DispC``/``PaintC`` the first two, ``SearchL`` the
third, ``SearchC`` the third and fourth).
"""

from __future__ import annotations

import re

import pinocchio as pin

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.poses import from_quaternion_mm, in_order, to_quaternion_mm
from calib_oed.program.parse.scan import argument_starts, line_of, numbers_in, skipped_move
from calib_oed.program.parse.targets import Language, ParsedProgram, Target, target_at

_DECL = re.compile(r"^[ \t]*(?:LOCAL[ \t]+|TASK[ \t]+)?(?:CONST|PERS|VAR)[ \t]+(jointtarget|robtarget|tooldata|wobjdata)"
                   r"[ \t]+(\w+)[ \t]*:=[ \t]*\[", re.IGNORECASE | re.MULTILINE)
_MOVE = re.compile(r"^[^!\n]*?\b(Move\w*)[ \t]+", re.IGNORECASE | re.MULTILINE)
#: Motion instructions besides ``Move*`` (their point arguments' positions; module docstring).
_OTHER = re.compile(r"^[^!\n]*?\b(Trigg[LJ]\w*|ArcL\w*|CapL|SpotM?[LJ]|DispL|PaintL|"
                    r"TriggC\w*|ArcC\w*|CapC|DispC|PaintC|SearchL\w*|SearchC\w*)[ \t]+", re.IGNORECASE | re.MULTILINE)
_NAME = re.compile(r"(\w+)[ \t]*(?:[,;\\]|$)")


LANGUAGE = Language("rapid", "deg", *in_order(from_quaternion_mm, to_quaternion_mm), lambda text: f"! {text}", (4, 3, 9))


def _bracket_end(text: str, start: int, file: str) -> int:
    """Index after the ``]`` closing the ``[`` at ``start``."""
    depth = 0
    for k in range(start, len(text)):
        if text[k] == "[":
            depth += 1
        elif text[k] == "]":
            depth -= 1
            if depth == 0:
                return k + 1
    raise ProgramError("program", file, f"the bracket at line {line_of(text, start) + 1} does not close")


def _groups(text: str, start: int, file: str) -> list[tuple[int, int]]:
    """Spans of the top-level ``[...]`` groups inside the literal opening at ``start``."""
    end = _bracket_end(text, start, file)
    out, k = [], start + 1
    while k < end - 1:
        if text[k] == "[":
            e = _bracket_end(text, k, file)
            out.append((k, e))
            k = e
        else:
            k += 1
    return out


def _target(text, start, file, name, kind) -> Target:
    groups = _groups(text, start, file)
    if kind == "joint":
        nums = numbers_in(text, *groups[0], file) if groups else []
        if len(nums) != 6:
            raise ProgramError("program", file, f"{name}: a jointtarget needs [[rax_1..rax_6], [eax..]]")
    else:
        nums = (numbers_in(text, *groups[0], file) + numbers_in(text, *groups[1], file)) if len(groups) >= 2 else []
        if len(nums) != 7:
            raise ProgramError("program", file, f"{name}: a robtarget needs [[x, y, z], [q1, q2, q3, q4], ...]")
    end = text.find(";", _bracket_end(text, start, file))
    return target_at(text, start, end if end >= 0 else start, name, kind, file, nums,
                     declared=_confdata(text, groups, file, name) if kind == "pose" else ())


def _confdata(text: str, groups: list[tuple[int, int]], file: str, name: str) -> tuple[tuple[str, int], ...]:
    """A robtarget's ``confdata`` ``[cf1, cf4, cf6, cfx]`` as declared (integers), or () if absent."""
    if len(groups) < 3:
        return ()
    cf = [n.value for n in numbers_in(text, *groups[2], file)]
    if len(cf) != 4 or any(v != int(v) for v in cf):
        raise ProgramError("program", file, f"{name}: a robtarget's confdata needs 4 integers "
                           f"[cf1, cf4, cf6, cfx], has {cf}")
    return tuple(zip(("cf1", "cf4", "cf6", "cfx"), (int(v) for v in cf), strict=True))


def _frame(text, start, file, what) -> pin.SE3:
    """tooldata's tframe or wobjdata's uframe * oframe."""
    groups = _groups(text, start, file)
    poses = []
    for g0, _g1 in groups:
        inner = _groups(text, g0, file)
        if len(inner) == 2:
            nums = numbers_in(text, *inner[0], file) + numbers_in(text, *inner[1], file)
            if len(nums) == 7:
                poses.append(from_quaternion_mm(*[n.value for n in nums]))
    if what == "tooldata" and poses:
        return poses[0]
    if what == "wobjdata" and len(poses) >= 2:
        return poses[0] * poses[1]
    raise ProgramError("program", file, f"a {what} at line {line_of(text, start) + 1} has no frame "
                       "[[x, y, z], [q1, q2, q3, q4]]")


def _point_arguments(instruction: str) -> tuple[int, ...]:
    """Which positional arguments of a motion instruction are points (module docstring)."""
    word = instruction.upper()
    if word.startswith("SEARCH"):
        return (2, 3) if word.startswith("SEARCHC") else (2,)
    if word.startswith(("MOVEC", "TRIGGC", "ARCC")) or word in ("CAPC", "DISPC", "PAINTC"):
        return (0, 1)
    return (0,)


def _unread_points(texts: dict[str, str]) -> list[str]:
    """Notes naming the motion instructions with a point that is not read (module docstring)."""
    declared = {m.group(2).upper() for text in texts.values() for m in _DECL.finditer(text)
                if m.group(1).lower() in ("jointtarget", "robtarget")}
    notes = []
    for file, text in texts.items():
        found = []
        for m in [*_MOVE.finditer(text), *_OTHER.finditer(text)]:
            if m.group(1).upper() == "MOVEEXTJ":
                continue
            args = argument_starts(text, m.end(), ";", "\\")
            for k in _point_arguments(m.group(1)):
                if k >= len(args):
                    continue
                start, moved = args[k], m.group(1).upper().startswith("MOVE")
                name = _NAME.match(text, start)
                if moved and text.startswith("[", start) or name and name.group(1).upper() in declared:
                    continue
                end = min((i for i in (text.find(c, start) for c in ",;\n") if i >= 0), default=len(text))
                point = text[start:end].strip()
                point = point[:point.index("(")] + "(..)" if "(" in point else point
                found.append((start, f"the inline point of {m.group(1)} is not read" if text.startswith("[", start)
                              else f"{name.group(1)} is not a jointtarget or robtarget declared in the modules read"
                              if name else f"the point {point} is computed, not a declared target"))
        notes += [skipped_move(file, text, pos, why) for pos, why in sorted(found)]
    return notes


def parse(texts: dict[str, str]) -> ParsedProgram:
    """Targets of RAPID modules ``{name.mod: text}``."""
    targets, frames, notes = [], {"tooldata": [], "wobjdata": []}, []
    for file, text in texts.items():
        found = []
        for m in _DECL.finditer(text):
            kind = m.group(1).lower()
            if kind in frames:
                frames[kind].append(_frame(text, m.end() - 1, file, kind))
            else:
                found.append((m.end() - 1, m.group(2), "joint" if kind == "jointtarget" else "pose"))
        for m in _MOVE.finditer(text):
            if m.group(1).upper() == "MOVEEXTJ":            # external axes only: no robot target
                continue
            name = f"{file} line {line_of(text, m.start(1)) + 1}"
            points = argument_starts(text, m.end(), ";", "\\")[:2 if m.group(1).upper().startswith("MOVEC") else 1]
            for start, which in zip(points, ("via", "end") if len(points) == 2 else ("",), strict=True):
                if text.startswith("[", start):
                    inner = _groups(text, start, file)
                    kind = "pose" if len(inner) >= 3 else "joint"     # robtarget has 4 groups, jointtarget 2
                    found.append((start, f"{name} ({which})" if which else name, kind))
        targets += [_target(text, s, file, name, kind) for s, name, kind in sorted(found)]
    notes += _unread_points(texts)
    tool = base = None
    for kind, values in frames.items():
        if len(values) == 1:
            tool, base = (values[0], base) if kind == "tooldata" else (tool, values[0])
        elif len(values) > 1:
            notes.append(f"{len(values)} {kind} declared: none is used (give --{'tool' if kind == 'tooldata' else 'base'})")
    return ParsedProgram(LANGUAGE, dict(texts), tuple(targets), tool, base, tuple(notes))
