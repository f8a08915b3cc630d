"""The program formats and writing a program's files (atomically, all of them as one set)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from calib_oed.exceptions import ProgramError
from calib_oed.io.atomic import atomic_write_files
from calib_oed.program.csv_format import write_csv
from calib_oed.program.fanuc_tp import write_tp
from calib_oed.program.krl import write_krl
from calib_oed.program.rapid import write_rapid
from calib_oed.program.records import Program
from calib_oed.program.urscript import write_urscript

#: Format name -> writer ``(program, name) -> {file name: text}``.
FORMATS: dict[str, Callable[[Program, str], dict[str, str]]] = {
    "krl": write_krl,
    "rapid": write_rapid,
    "tp": write_tp,
    "urscript": write_urscript,
    "csv": write_csv,
}


def program_texts(program: Program, fmt: str, name: str = "calib_program") -> dict[str, str]:
    """The files of ``program`` in format ``fmt``: ``{file name: text}``."""
    if fmt not in FORMATS:
        raise ProgramError("format", fmt, "unknown program format", list(FORMATS))
    if not name.isidentifier():
        raise ProgramError("name", name, "a program name must be an identifier (letters, digits, _)")
    return FORMATS[fmt](program, name)


def write_program(program: Program, fmt: str, directory: str | os.PathLike,
                  name: str = "calib_program") -> list[Path]:
    """Write the program's files into ``directory`` (created if missing); returns their paths.

    The texts are all built before the first file is written, and the files are written
    as one set (:func:`~calib_oed.io.atomic.atomic_write_files`): a KRL ``.src`` and its
    ``.dat`` both appear or neither does, never half-written.
    """
    texts = program_texts(program, fmt, name)
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    return atomic_write_files({folder / fname: text.encode("utf-8") for fname, text in texts.items()})
