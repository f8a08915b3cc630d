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

