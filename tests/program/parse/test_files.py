"""Program files: the language from the extension, KRL's pair, encodings, errors."""

from __future__ import annotations

import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.parse.files import program_files, read_program
from tests.program.parse import samples

JOINTS = tuple(f"joint_a{i}" for i in range(1, 7))


def test_krl_pair_from_either_file(tmp_path):
    (tmp_path / "weld_demo.src").write_text(samples.KRL_SRC)
    (tmp_path / "weld_demo.dat").write_text(samples.KRL_DAT)
    for name in ("weld_demo.src", "weld_demo.dat"):
        assert [p.name for p in program_files(tmp_path / name)] == ["weld_demo.dat", "weld_demo.src"]
    parsed, enc = read_program(tmp_path / "weld_demo.src", JOINTS)
    assert len(parsed.targets) == 5 and enc == {"weld_demo.dat": "utf-8", "weld_demo.src": "utf-8"}


def test_latin1_file_is_kept(tmp_path):
    path = tmp_path / "p.ls"
    path.write_bytes(samples.TP_LS.replace("weld demo", "Schwei\xdfen").encode("latin-1"))
    parsed, enc = read_program(path, JOINTS)
    assert enc["p.ls"] == "latin-1" and "Schwei\xdfen" in parsed.texts["p.ls"]


@pytest.mark.parametrize("name, text, message", [
    ("p.txt", "x", "unknown program language"),
    ("p.script", "def f():\nend\n", "no targets"),
])
def test_errors(tmp_path, name, text, message):
    (tmp_path / name).write_text(text)
    with pytest.raises(ProgramError, match=message):
        read_program(tmp_path / name, JOINTS)


def test_controller_languages_need_six_axes(tmp_path):
    (tmp_path / "p.script").write_text("movej([0, 0, 0, 0, 0, 0, 0])\n")
    with pytest.raises(ProgramError):
        read_program(tmp_path / "p.script", JOINTS + ("j7",))

