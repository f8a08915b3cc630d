"""Atomic writes: plain-file permissions, no partial or temporary files on failure."""

from __future__ import annotations

import os
import stat

import pytest

from calib_oed.exceptions import ExportError
from calib_oed.io.atomic import atomic_write, atomic_write_text


def test_written_files_get_the_permissions_of_a_plain_open(tmp_path):
    mask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "a.txt", "hello")
        plain = tmp_path / "plain.txt"
        plain.write_text("x")
    finally:
        os.umask(mask)
    assert path.read_text() == "hello"
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode) == 0o644


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = atomic_write_text(tmp_path / "a.bin", "old")

    def explode(fh):
        fh.write(b"half")
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="renderer crashed"):
        atomic_write(path, explode, binary=True)
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]


def test_a_missing_folder_is_named(tmp_path):
    with pytest.raises(ExportError, match="does not exist"):
        atomic_write_text(tmp_path / "nope" / "a.txt", "x")


def test_a_set_of_files_is_renamed_only_when_every_one_is_written(tmp_path):
    from calib_oed.io.atomic import atomic_write_files

    src, dat = tmp_path / "p.src", tmp_path / "p.dat"
    atomic_write_files({src: b"old src", dat: b"old dat"})

    with pytest.raises(TypeError):              # the second file's write fails (text, not bytes)
        atomic_write_files({src: b"new src", dat: "new dat"})
    assert (src.read_bytes(), dat.read_bytes()) == (b"old src", b"old dat")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.dat", "p.src"]
    (tmp_path / "q.dat").mkdir()                 # a target that cannot be replaced: nothing is written
    with pytest.raises(ExportError, match="not a regular file"):
        atomic_write_files({tmp_path / "q.src": b"src", tmp_path / "q.dat": b"dat"})
    assert not (tmp_path / "q.src").exists()
