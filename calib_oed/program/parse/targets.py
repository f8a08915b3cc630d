r"""What every program parser returns: targets with the spans of their numbers, and the rewrite.

A :class:`Target` is a joint target (one number per robot axis, in the controller's
joint unit) or a Cartesian target (the language's pose numbers,
:mod:`calib_oed.program.parse.poses`), with the character span of each number in its
file. :func:`rewrite` replaces exactly those spans and inserts one comment line per
target (the language's :attr:`Language.comment`); every other byte stays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.scan import Number, indent_of, line_of


@dataclass(frozen=True)
class Target:
    """One target of a program.

    Attributes:
        name: Its name in the program (``XP1``, ``P[3]``, ``line 12``).
        kind: ``"joint"`` or ``"pose"``.
        file: The file (key of :attr:`ParsedProgram.texts`) holding the numbers.
        line: 0-based line after which its comment goes.
        numbers: The numbers to rewrite: the joint values, or the pose values in the
            language's order (position, then rotation).
        indent: Leading white space of its line (comments take it).
        unit: Joint unit of this target if not the language's (``"deg"``, ``"rad"``, or
            ``"rad+deg"``: the joints in radians, then the same in degrees), else "".
        commented: Whether the target gets a comment (a CSV row's degree copy does not).
        declared: The configuration the file gives a Cartesian target, as ``(name, value)`` pairs
            (KRL: ``("S", s), ("T", t)``; RAPID: ``("cf1", .), ("cf4", .), ("cf6", .), ("cfx", .)``);
            read, never rewritten.
    """

    name: str
    kind: str
    file: str
    line: int
    numbers: tuple[Number, ...]
    indent: str = ""
    unit: str = ""
    commented: bool = True
    declared: tuple[tuple[str, int], ...] = ()

    @property
    def values(self) -> np.ndarray:
        return np.array([n.value for n in self.numbers])


@dataclass(frozen=True)
class Language:
    """How one controller language speaks.

    Attributes:
        name: ``krl``, ``rapid``, ``tp``, ``urscript``, ``csv``.
        joint_unit: ``"deg"`` or ``"rad"`` of joint targets.
        pose_from: Pose numbers -> :class:`pinocchio.SE3` (SI).
        pose_to: (SE3, the old pose numbers) -> new pose numbers (nearest representation).
        comment: Comment text -> one comment line (without indent and newline).
        decimals: Least decimals of (joint, position, rotation) numbers written.
        insert_comments: ``(text, [(line, comment line)]) -> text``; None: each after its line.
    """

    name: str
    joint_unit: str
    pose_from: Callable[[np.ndarray], pin.SE3]
    pose_to: Callable[[pin.SE3, np.ndarray], np.ndarray]
    comment: Callable[[str], str]
    decimals: tuple[int, int, int]
    insert_comments: Callable[[str, list[tuple[int, str]]], str] | None = None


@dataclass(frozen=True, eq=False)
class ParsedProgram:
    """A program's files and targets.

    Attributes:
        language: How the program speaks.
        texts: ``{file name: text}`` as read.
        targets: In program order.
        tool, base: :math:`T_{F,E}` and :math:`T_{W,B}` declared in the files (None: not declared).
        notes: What the parser decided and a reader should know.
    """

    language: Language
    texts: dict[str, str]
    targets: tuple[Target, ...]
    tool: pin.SE3 | None = None
    base: pin.SE3 | None = None
    notes: tuple[str, ...] = field(default=())


def target_at(text: str, start: int, end: int, name: str, kind: str, file: str, numbers,
              declared: tuple[tuple[str, int], ...] = ()) -> Target:
    """The target whose literal opens at character ``start`` of ``text`` and whose statement
    ends at ``end``: its comment goes after the line of ``end``, indented as the line of ``start``."""
    return Target(name, kind, file, line_of(text, end), tuple(numbers), indent_of(text, start), declared=declared)


def format_number(value: float, original: str, decimals: int) -> str:
    """``value`` with at least ``decimals`` decimals (more if ``original`` had more); no ``-0``."""
    have = len(original.split(".")[1]) if "." in original and "e" not in original.lower() else 0
    text = f"{value:.{max(have, decimals)}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return ("+" + text) if original.startswith("+") and not text.startswith("-") else text


def rewrite(parsed: ParsedProgram, values: dict[int, np.ndarray], comments: dict[int, str]) -> dict[str, str]:
    """The files with target ``i``'s numbers replaced by ``values[i]`` and ``comments[i]`` inserted.

    Raises:
        ProgramError: a value count that does not match the target's numbers.
    """
    lang = parsed.language
    edits: dict[str, list[tuple[Number, str]]] = {f: [] for f in parsed.texts}
    notes: dict[str, list[tuple[int, str]]] = {f: [] for f in parsed.texts}
    for i, target in enumerate(parsed.targets):
        if i in values:
            new = np.asarray(values[i], float)
            if new.shape != (len(target.numbers),):
                raise ProgramError("target", target.name, f"{len(target.numbers)} values expected, got {new.shape}")
            for k, (num, v) in enumerate(zip(target.numbers, new, strict=True)):
                if target.kind == "joint":
                    unit = target.unit or lang.joint_unit
                    dec = lang.decimals[0] if not target.unit else (
                        4 if unit.split("+")[k * len(unit.split("+")) // len(target.numbers)] == "deg" else 10)
                else:
                    dec = lang.decimals[1] if k < 3 else lang.decimals[2]
                edits[target.file].append((num, format_number(float(v), num.text, dec)))
        if i in comments and target.commented:
            notes[target.file].append((target.line, target.indent + lang.comment(comments[i])))
    out = {}
    for name, text in parsed.texts.items():
        pieces, at = [], 0
        for num, new_text in sorted(edits[name], key=lambda e: e[0].start):
            pieces += [text[at:num.start], new_text]
            at = num.end
        text = "".join(pieces) + text[at:]
        if notes[name]:
            text = (lang.insert_comments or insert_after_lines)(text, notes[name])
        out[name] = text
    return out


def insert_after_lines(text: str, comments: list[tuple[int, str]]) -> str:
    """Each comment as a new line after its 0-based line (the line's own line ending)."""
    lines = text.splitlines(keepends=True)
    after: dict[int, list[str]] = {}
    for line, comment in comments:
        after.setdefault(line, []).append(comment)
    out = []
    for i, line in enumerate(lines):
        out.append(line)
        if i in after:
            if not line.endswith(("\n", "\r")):
                out[-1] = line + "\n"
            ending = line[len(line.rstrip("\r\n")):] or "\n"
            out += [c + ending for c in after[i]]
    return "".join(out)


__all__ = ["Language", "ParsedProgram", "Target", "format_number", "insert_after_lines", "rewrite", "target_at"]
