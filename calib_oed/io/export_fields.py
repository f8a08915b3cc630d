"""The text of a tracker export as fields: its data lines, their separator, their numbers
(:mod:`calib_oed.io.tracker_import` reads the layouts from them)."""

from __future__ import annotations

import math
import os
import re

from calib_oed.exceptions import InputFileError, MeasurementFileError
from calib_oed.scene.yaml_file import read_text_file

__all__ = ["data_lines", "number", "splitter", "text"]


def text(source) -> tuple[str, str]:
    """The file's text (within calib_oed's bounds on text files) and its name."""
    where = os.fspath(source)
    try:
        return read_text_file(where, "tracker export"), where
    except InputFileError as exc:
        raise MeasurementFileError(where, [(None, exc.problem)], kind="tracker export") from exc


def data_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, stripped line) of every line that is neither blank nor a comment
    (``#`` or ``//``, as SpatialAnalyzer writes its version and frame)."""
    return [(i, line.strip()) for i, line in enumerate(re.split(r"\r\n|\r|\n", text), start=1)
            if line.strip() and not line.strip().startswith(("#", "//"))]


def splitter(line: str):
    """A field splitter for the file's separator and whether a decimal comma is used."""
    for sep in (";", "\t"):
        if sep in line:
            return (lambda s, sep=sep: [f.strip() for f in s.split(sep)]), True
    if "," in line:
        return (lambda s: [f.strip() for f in s.split(",")]), False
    return (lambda s: s.split()), False


def number(field: str, decimal_comma: bool) -> float | None | str:
    """A finite number, None for a missing value (empty, NaN, '-'), or a message."""
    text = field.strip().replace(",", ".") if decimal_comma else field.strip()
    if text.lower() in ("", "nan", "-", "n/a", "none"):
        return None
    try:
        value = float(text)
    except ValueError:
        return f"{field!r} is not a number"
    return value if math.isfinite(value) else f"{field!r} is not finite"
