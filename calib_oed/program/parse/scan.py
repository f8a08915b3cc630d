"""Reading a program's text: numbers and their spans, arguments, lines, indents.

What every language parser (:mod:`calib_oed.program.parse`) uses to find its targets in the
text as written: :func:`numbers_in` gives each number with its character span
(:class:`Number`), which :func:`calib_oed.program.parse.targets.rewrite` later replaces.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ProgramError

#: A decimal number as the controller languages write them (no exponent in target values), whole:
#: not the head of a longer token (``-6.11`` of a garbled ``-6.11.68`` is no number).
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w.])"
#: A list of numbers and nothing else: commas between, a bracket at each end at most.
_LIST = re.compile(rf"\s*\[?\s*(?:{NUMBER}\s*(?:,\s*{NUMBER}\s*)*)?\]?\s*")


@dataclass(frozen=True)
class Number:
    """A number in a file: its span ``[start, end)`` and its text."""

    start: int
    end: int
    text: str

    @property
    def value(self) -> float:
        return float(self.text)


def numbers_in(text: str, start: int, end: int, file: str | None = None) -> list[Number]:
    """The numbers of ``text[start:end]`` (not digits inside names such as ``A1``), spans in ``text``.

    With ``file``, ``text[start:end]`` must be a list of numbers and nothing else (commas between,
    a bracket at each end at most): a garbled or hand-edited list raises a ProgramError naming
    ``file`` and the line, where reading only its numbers would move the robot elsewhere."""
    nums = [Number(start + m.start(), start + m.end(), m.group())
            for m in re.finditer(rf"(?<![\w.]){NUMBER}", text[start:end])]
    if file is not None and not _LIST.fullmatch(text, start, end):
        shown = " ".join(text[start:end].split())
        raise ProgramError("program", f"{file}:{line_of(text, start) + 1}", "not a comma-separated list of "
                           f"numbers ({shown[:60]!r}): a garbled or hand-edited target is not read")
    return nums


_LINE_STARTS: dict[int, tuple[str, np.ndarray]] = {}


def argument_starts(text: str, start: int, end: str, skip: str | None = None) -> list[int]:
    """Where each top-level, comma-separated argument from ``start`` to the closing ``end``
    begins; arguments that open with ``skip`` are left out."""
    args, depth, begin = [], 0, start
    for k in range(start, len(text)):
        c = text[k]
        if depth == 0 and c in "," + end:
            at = begin + len(text[begin:k]) - len(text[begin:k].lstrip())
            if skip is None or not text.startswith(skip, at):
                args.append(at)
            begin = k + 1
            if c == end:
                break
        depth += (c in "([") - (c in ")]")
    return args


def line_of(text: str, pos: int) -> int:
    """0-based line index of character ``pos`` (line starts indexed once per text)."""
    cached = _LINE_STARTS.get(id(text))
    if cached is None or cached[0] is not text:
        starts = np.array([0] + [m.end() for m in re.finditer("\n", text)])
        _LINE_STARTS.clear()
        _LINE_STARTS[id(text)] = cached = (text, starts)
    return int(np.searchsorted(cached[1], pos, side="right") - 1)


def skipped_move(file: str, text: str, pos: int, why: str) -> str:
    """The note naming a move whose target the parser does not read, so it is left as written:
    ``file:line: <the move's line>: NOT compensated: why`` (``pos``: a character of the move)."""
    line = line_of(text, pos)
    start = text.rfind("\n", 0, pos) + 1
    end = text.find("\n", start)
    code = " ".join(text[start:end if end >= 0 else len(text)].split())
    code = code if len(code) <= 60 else code[:57] + "..."
    return f"{file}:{line + 1}: {code}: NOT compensated: {why}"


def indent_of(text: str, pos: int) -> str:
    """The whitespace that opens the line of character ``pos``."""
    start = text.rfind("\n", 0, pos) + 1
    line = text[start:pos]
    return line[: len(line) - len(line.lstrip())]


__all__ = ["NUMBER", "Number", "argument_starts", "indent_of", "line_of", "numbers_in", "skipped_move"]
