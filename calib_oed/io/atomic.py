"""Atomic file output: a reader never sees a half-written file, nor half of a set of files."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO

from calib_oed.exceptions import ExportError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | os.PathLike, write: Callable[[IO], None], binary: bool = False) -> Path:
    """Call ``write(fh)`` on a temporary file in ``path``'s folder, then rename it to ``path``.

    The file gets the permissions a plain ``open`` would give (0666 less the
    umask), not the temporary file's 0600. On any failure the temporary file is
    removed and ``path`` is unchanged.

    Raises:
        ExportError: the folder does not exist or is not writable.
    """
    path = _check_target(path)
    tmp = _write_temporary(path, write, binary)
    try:
        os.replace(tmp, path)
    except OSError as exc:
        _remove([tmp])
        raise ExportError(f"cannot write {path}: {exc}") from exc
    return path


def atomic_write_files(contents: Mapping[str | os.PathLike, bytes]) -> list[Path]:
    """Write several files as one: each to a temporary file beside it, and only when every
    one is written, rename them into place (a KRL ``.src`` with its ``.dat``).

    Every target is checked before anything is written; a failure while writing leaves
    every target unchanged and no temporary file. (The renames are separate system calls:
    only a crash between two of them can leave part of the set replaced.)

    Raises:
        ExportError: a folder that does not exist or is not writable, a target that is
            not a regular file.
    """
    paths = [_check_target(p) for p in contents]
    tmps: list[str] = []
    try:
        for path, data in zip(paths, contents.values(), strict=True):
            tmps.append(_write_temporary(path, lambda fh, data=data: fh.write(data), True))
        for k, (tmp, path) in enumerate(zip(tmps, paths, strict=True)):
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise ExportError(f"cannot write {path}: {exc}") from exc
            tmps[k] = ""                                  # renamed: nothing left to remove
    except BaseException:
        _remove([t for t in tmps if t])
        raise
    return paths


def _check_target(path: str | os.PathLike) -> Path:
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ExportError(f"cannot write {path}: folder {folder} does not exist")
    if path.exists() and not path.is_file():  # renaming onto a device would replace it
        raise ExportError(f"cannot write {path}: it exists and is not a regular file (a folder, "
                          "a device or a pipe); give the name of a new or a regular file")
    return path


def _write_temporary(path: Path, write: Callable[[IO], None], binary: bool) -> str:
    """``write(fh)`` on a new temporary file in ``path``'s folder (plain-file permissions); its name."""
    folder = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc}") from exc
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="")) as fh:
            write(fh)
    except BaseException as exc:
        _remove([tmp])
        if isinstance(exc, OSError):
            raise ExportError(f"cannot write {path}: {exc}") from exc
        raise
    return tmp


def _remove(tmps: list[str]) -> None:
    for tmp in tmps:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_write`).

    Raises:
        ExportError: the folder does not exist or is not writable.
    """
    return atomic_write(path, lambda fh: fh.write(text))
