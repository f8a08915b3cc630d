"""Which parser reads a program file, and reading it (with its KRL partner file).

=================================  ==========  ======================================
file                               language    module
=================================  ==========  ======================================
``.src`` and/or ``.dat`` (pair)    ``krl``     :mod:`~calib_oed.program.parse.krl`
``.mod``, ``.modx``, ``.prg``      ``rapid``   :mod:`~calib_oed.program.parse.rapid`
``.ls``                            ``tp``      :mod:`~calib_oed.program.parse.fanuc_tp`
``.script``, ``.urscript``         ``urscript``  :mod:`~calib_oed.program.parse.urscript`
``.csv``                           ``csv``     :mod:`~calib_oed.program.parse.csv_targets`
=================================  ==========  ======================================

A KRL program is its ``.src`` and ``.dat`` of the same stem; either may be given, and
both are read when both exist. Files are read as bytes and decoded as UTF-8 (Latin-1 if
that fails, as older KUKA and FANUC files are) with line endings kept, so unchanged lines
are written back byte for byte.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse import csv_targets, fanuc_tp, krl, rapid, urscript
from calib_oed.program.parse.targets import ParsedProgram

EXTENSIONS = {".src": "krl", ".dat": "krl", ".mod": "rapid", ".modx": "rapid", ".prg": "rapid",
              ".ls": "tp", ".script": "urscript", ".urscript": "urscript", ".csv": "csv"}


def _decode(data: bytes) -> tuple[str, str]:
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return data.decode("latin-1"), "latin-1"


def program_files(path: str | os.PathLike) -> list[Path]:
    """The files of the program at ``path`` (a KRL ``.src`` brings its ``.dat`` and back)."""
    path = Path(path)
    if not path.is_file():
        raise ProgramError("program", str(path), "no such file")
    ext = path.suffix.lower()
    if ext not in EXTENSIONS:
        raise ProgramError("program", str(path), "unknown program language (by the file extension)",
                           sorted(EXTENSIONS))
    if EXTENSIONS[ext] != "krl":
        return [path]
    pair = [p for p in (path.with_suffix(".src"), path.with_suffix(".dat"), path.with_suffix(".SRC"),
                        path.with_suffix(".DAT")) if p.is_file()]
    return sorted({p.resolve(): p for p in [path, *pair]}.values())


def read_program(path: str | os.PathLike, joint_names) -> tuple[ParsedProgram, dict[str, str]]:
    """(parsed program, ``{file name: encoding}``) of the program at ``path``.

    Raises:
        ProgramError: unknown extension, a file that cannot be read, no targets, or a
            target the language's grammar does not allow (the message names it).
    """
    files = program_files(path)
    texts, encodings = {}, {}
    for f in files:
        try:
            texts[f.name], encodings[f.name] = _decode(f.read_bytes())
        except OSError as exc:
            raise ProgramError("program", str(f), f"cannot read ({exc})") from exc
    language = EXTENSIONS[Path(path).suffix.lower()]
    if language == "csv":
        parsed = csv_targets.parse(texts, joint_names)
    else:
        parsed = {"krl": krl.parse, "rapid": rapid.parse, "tp": fanuc_tp.parse, "urscript": urscript.parse}[language](texts)
    if not parsed.targets:
        raise ProgramError("program", str(path), f"no targets found ({language}: see docs/compensate.md for "
                           "the target forms read)")
    if language != "csv" and len(joint_names) != 6:
        raise ProgramError("program", str(path), f"{language} programs are read for 6-axis robots; this robot "
                           f"has {len(joint_names)} joints: use a CSV of targets", ["csv"])
    return parsed, encodings


__all__ = ["EXTENSIONS", "program_files", "read_program"]


#: The header line calib_oed writes into every program (:func:`calib_oed.program.format_common.header_lines`).
_WRITTEN = re.compile(r"joint values: (URDF joint angles|controller joint values) in [^,\n]+, in the order ([^\n]+?)\s*$",
                      re.MULTILINE)
_CONTROLLER = re.compile(r"by the scene's controller (\S+)")


def check_written_for(parsed: ParsedProgram, joint_names, controller) -> None:
    """A program calib_oed wrote says in its header which robot's joints it lists and in which
    convention (URDF angles or a controller's values): both must be this scene's, or its joint
    values would be read as other joints or in another convention (tens of mm off, no error).
    A header without that line (another writer, or edited out) is not checked.

    Raises:
        ProgramError: another robot's joints, or the other convention, named with the fix.
    """
    for file, text in parsed.texts.items():
        m = _WRITTEN.search(text)
        if m is None:
            continue
        written = [n.strip() for n in m.group(2).split(",")]
        if written != list(joint_names):
            raise ProgramError("program", file, f"written for a robot with the joints {', '.join(written)}, "
                               f"not this scene's ({', '.join(joint_names)}): compensate it with the scene "
                               "it was written for")
        said = _CONTROLLER.search(text)
        if m.group(1) == "controller joint values" and controller is None:
            name = said.group(1) if said else "?"
            raise ProgramError("program", file, f"its joint values are those of controller {name}, and this scene has "
                               "no controller: block to map them to URDF angles: use the scene it was written with")
        if m.group(1) == "URDF joint angles" and controller is not None:
            raise ProgramError("program", file, "its joint values are URDF joint angles, and this scene's "
                               f"controller {controller.name} would read them as its own: use the scene it "
                               "was written with")
        if said is not None and controller is not None and said.group(1) != controller.name:
            raise ProgramError("program", file, f"its joint values are those of controller {said.group(1)}, not of "
                               f"this scene's controller {controller.name}: use the scene it was written with")
