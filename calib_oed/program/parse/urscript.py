r"""Universal Robots URScript: joint lists and poses of ``movej``/``movel``/``movep``/``movec``/``servoj``/``servoc``.

Grammar used (Universal Robots *The URScript Programming Language*, "Module motion" and
"pose" type): a move's first argument (``movec``: its first two, the via point and the
end point, named ``line N (via)``, ``line N (end)``) is a joint list ``[q1, ..., q6]`` [rad], a pose
``p[x, y, z, rx, ry, rz]`` [m; rotation vector] (also inside ``get_inverse_kin(p[...])``),
or a variable assigned such a literal once (``name = p[...]``, ``global name = [...]``), which is
then rewritten where it is assigned. A point that is none of these (an expression, a function's
argument, a variable assigned more than once: its value at the move is not known) is left as
written and named in the notes (``file:line``, why). ``set_tcp(p[...])`` declares the TCP :math:`T_{F,E}`;
poses are in the robot base (feature frames built with ``pose_trans`` are not followed:
such moves are named). Comments are ``#`` lines after the target's line. Text in ``#`` comments
and in string literals is not code: a move written there is neither read nor rewritten.
"""

from __future__ import annotations

import re

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.poses import from_rotvec_m, in_order, to_rotvec_m
from calib_oed.program.parse.scan import argument_starts, line_of, numbers_in, skipped_move
from calib_oed.program.parse.targets import Language, ParsedProgram, Target, target_at

_MOVE = re.compile(r"\b(movej|movel|movep|movec|servoj|servoc)[ \t]*\(")
_ASSIGN = re.compile(r"^[ \t]*(?:global[ \t]+|local[ \t]+)?(\w+)[ \t]*=[ \t]*(p?)\[", re.MULTILINE)
_ANY_ASSIGN = re.compile(r"^[ \t]*(?:global[ \t]+|local[ \t]+)?(\w+)[ \t]*=(?!=)", re.MULTILINE)
_TCP = re.compile(r"\bset_tcp[ \t]*\([ \t]*p\[")
_LITERAL = re.compile(r"(p?)\[")


LANGUAGE = Language("urscript", "rad", *in_order(from_rotvec_m, to_rotvec_m), lambda text: f"# {text}", (6, 6, 6))


def _code_only(text: str) -> str:
    """``text`` with every comment and string literal blanked (same length, newlines kept).

    URScript comments run from ``#`` to the end of the line; strings are ``"..."`` or
    ``'...'`` on one line. Offsets into the result are offsets into ``text``.
    """
    out, quote, comment = list(text), None, False
    for k, c in enumerate(text):
        if c == "\n":
            quote, comment = None, False
        elif comment:
            out[k] = " "
        elif quote is not None:
            out[k] = " " if c != quote else c
            if c == quote:
                quote = None
        elif c == "#":
            comment, out[k] = True, " "
        elif c in "\"'":
            quote = c
    return "".join(out)


def _literal(text: str, bracket: int, file: str, name: str, pose: bool) -> Target:
    end = text.find("]", bracket)
    nums = numbers_in(text, bracket + 1, end, file)
    if len(nums) != 6:
        raise ProgramError("program", file, f"{name}: {'p[x, y, z, rx, ry, rz]' if pose else '[q1..q6]'} "
                           f"needs 6 numbers, has {len(nums)}")
    return target_at(text, bracket, end, name, "pose" if pose else "joint", file, nums)


def parse(texts: dict[str, str]) -> ParsedProgram:
    """Targets of URScript files ``{name.script: text}``."""
    targets, tool, notes = {}, None, []
    for file, source in texts.items():
        text = _code_only(source)
        assigned = {m.group(1): (m.end() - 1, bool(m.group(2))) for m in _ASSIGN.finditer(text)}
        times: dict[str, list[int]] = {}
        for m in _ANY_ASSIGN.finditer(text):
            times.setdefault(m.group(1), []).append(line_of(text, m.start()) + 1)
        for m in _TCP.finditer(text):
            t = _literal(text, m.end() - 1, file, "set_tcp", True)
            tool = LANGUAGE.pose_from(t.values)
        for m in _MOVE.finditer(text):
            line, args = line_of(text, m.start()) + 1, argument_starts(text, m.end(), ")") or [m.end()]
            points = [(args[0], f"line {line}", "target")] if m.group(1) != "movec" else \
                [(a, f"line {line} ({w})", f"{w} point") for a, w in zip(args[:2], ("via", "end"), strict=False)]
            for at, name, what in points:
                arg = text[at:]
                lit = _LITERAL.match(arg) or re.match(r"get_inverse_kin[ \t]*\([ \t]*(p)\[", arg)
                if lit is not None:
                    bracket = at + lit.end() - 1
                    targets[(file, bracket)] = _literal(text, bracket, file, name, bool(lit.group(1)))
                    continue
                var = re.match(r"(\w+)[ \t]*[,)]", arg)
                if var and var.group(1) in assigned and len(times[var.group(1)]) == 1:
                    bracket, pose = assigned[var.group(1)]
                    targets[(file, bracket)] = _literal(text, bracket, file, var.group(1), pose)
                elif var and len(times.get(var.group(1), ())) > 1:
                    notes.append(skipped_move(file, source, at, f"the {what} {var.group(1)} is assigned "
                                              f"{len(times[var.group(1)])} times (lines "
                                              f"{', '.join(map(str, times[var.group(1)]))}): its value here is not known"))
                else:
                    notes.append(skipped_move(file, source, at, f"the {what} is not a literal or a variable "
                                              "assigned one"))
    ordered = tuple(targets[k] for k in sorted(targets))
    return ParsedProgram(LANGUAGE, dict(texts), ordered, tool, None, tuple(notes))
