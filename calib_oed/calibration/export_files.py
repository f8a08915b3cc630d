"""Writing an export file: the target checked, the text written atomically.

Used by :mod:`calib_oed.calibration.export` (the calibrated URDF) and
:mod:`calib_oed.calibration.sensor_file` (the sensor YAML). The text is
written with :func:`calib_oed.io.atomic.atomic_write_text`, so a failed
write leaves no file behind; every failure is an
:class:`~calib_oed.exceptions.ExportError`.
"""

from __future__ import annotations

import os
from pathlib import Path

from calib_oed.exceptions import ExportError
from calib_oed.io import atomic as io_utils


def _check_target(path: Path) -> None:
    if path.is_dir():
        raise ExportError(f"cannot write {path}: it is a folder")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ExportError(f"cannot write {path}: folder {folder} does not exist")


def _write(path: str | os.PathLike, text: str) -> Path:
    path = Path(path)
    _check_target(path)
    try:
        return io_utils.atomic_write_text(path, text)
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc}") from exc
