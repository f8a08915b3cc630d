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


def test_a_program_calib_oed_wrote_is_checked_against_the_scene(tmp_path):
    """The header names the joints and the convention: another robot's program, or controller values
    read as URDF angles (or the reverse), are refused instead of moving the robot elsewhere."""
    from calib_oed.model.controller import controller_from_mapping
    from calib_oed.program.parse.files import check_written_for

    def program(convention):
        path = tmp_path / "p.script"
        path.write_text(f"# calib_oed measurement program, scene s: 1 poses\n# joint values: {convention}\n"
                        "movej([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])\n")
        return read_program(path, JOINTS)[0]

    urdf = program(f"URDF joint angles in radians, in the order {', '.join(JOINTS)}")
    ctrl = program(f"controller joint values in radians, in the order {', '.join(JOINTS)}\n"
                   "# from the URDF angles q by the scene's controller kuka (q = A c + b: identity)")
    kuka, fanuc = controller_from_mapping({"name": "kuka"}, 6), controller_from_mapping({"name": "fanuc"}, 6)
    check_written_for(urdf, JOINTS, None)
    with pytest.raises(ProgramError, match="written for a robot with the joints joint_a1, .*not this scene's"):
        check_written_for(urdf, tuple(f"j{i}" for i in range(6)), None)
    with pytest.raises(ProgramError, match="those of controller kuka, and this scene has no controller"):
        check_written_for(ctrl, JOINTS, None)
    check_written_for(ctrl, JOINTS, kuka)
    with pytest.raises(ProgramError, match="URDF joint angles, and this scene's controller kuka"):
        check_written_for(urdf, JOINTS, kuka)
    with pytest.raises(ProgramError, match="those of controller kuka, not of this scene's controller fanuc"):
        check_written_for(ctrl, JOINTS, fanuc)
    unmarked = tmp_path / "q.script"
    unmarked.write_text("movej([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])\n")
    check_written_for(read_program(unmarked, JOINTS)[0], ("a", "b", "c", "d", "e", "f"), None)  # not ours: unchecked
