"""`calib-oed table`: a scene's robot or its calibration as a parameter table, a table as a URDF,
and bad input as one line with exit 2 and nothing written."""

from __future__ import annotations

import json

import pytest

from calib_oed import load_robot
from calib_oed.calibration.compensation_files import load_calibration
from calib_oed.cli import main
from calib_oed.io.parameter_table import read_parameter_table
from calib_oed.model.dh import compute_table
from calib_oed.scene.reader import load_scene
from tests.calibration.test_compensation_files import write_calibration


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cal_ur5")
    problem, _, _ = write_calibration(folder, scene="ur5_table")
    robot, _, _ = load_calibration(problem.space, folder)
    return folder, robot


@pytest.mark.parametrize("convention, name", [("dh", "classic_dh"), ("mdh", "modified_dh"), ("hayati", "hayati")])
def test_nominal_table_is_the_models_and_exact(tmp_path, capsys, convention, name):
    out = tmp_path / "kr16.yaml"
    assert main(["table", "fms_kr16", "--convention", convention, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    robot = load_scene("fms_kr16").robot
    assert read_parameter_table(out) == compute_table(robot, name)
    assert f"{name} table of kr16 (nominal)" in text and "NAMED" not in text
    assert "joint_a3" in text and f"wrote {out}" in text


def _table_json(folder, convention, tmp_path, capsys):
    """``table ur5_table FOLDER --convention C -o C.yaml --json``: its JSON and the table written."""
    out = tmp_path / f"{convention}.yaml"
    assert main(["table", "ur5_table", str(folder), "--convention", convention, "-o", str(out),
                 "--json"]) == 0
    return json.loads(capsys.readouterr().out), read_parameter_table(out)


def test_calibrated_table_names_what_classic_dh_cannot_hold(calibration, tmp_path, capsys):
    folder, robot = calibration
    nominal = load_scene("ur5_table").robot
    q = robot.random_configurations(20, 5)
    for convention, exact in (("hayati", True), ("dh", False)):
        data, table = _table_json(folder, convention, tmp_path, capsys)
        dp, dr = table.compute_difference(robot, q)
        assert data["exact"] is exact and data["table"]["convention"] == table.convention
        assert (max(dp, dr) <= 1e-9) is exact                  # the calibrated robot's table
        assert table.compute_difference(nominal, q)[0] > 1e-4  # not the nominal robot's
    assert main(["table", "ur5_table", str(folder), "--convention", "dh"]) == 0
    assert "NAMED: the classic_dh table misses the model" in capsys.readouterr().out


def test_to_urdf_round_trip(tmp_path, capsys):
    table_file, urdf = tmp_path / "t.yaml", tmp_path / "t.urdf"
    assert main(["table", "fms_kr16", "--convention", "hayati", "-o", str(table_file), "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    assert main(["table", "--to-urdf", str(table_file), "-o", str(urdf), "fms_kr16", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["round_trip_m"] <= 1e-9 and data["round_trip_rad"] <= 1e-9
    assert data["scene_difference_m"] <= 1e-9                   # the nominal robot's own table
    table = read_parameter_table(table_file)
    loaded = load_robot(urdf, tool_frame=table.tool_frame)
    assert max(table.compute_difference(loaded, loaded.random_configurations(10, 1))) <= 1e-9
    assert loaded.joint_names == load_scene("fms_kr16").robot.joint_names


@pytest.mark.parametrize("args, message", [
    ([], "give SCENE"),
    (["fms_kr16", "-o", "{tmp}/t.urdf"], "a parameter table is YAML"),
    (["fms_kr16", "--parallel-angle", "3"], "with --convention hayati"),
    (["fms_kr16", "--convention", "hayati", "--parallel-angle", "95"], "(0, 90) deg"),
    (["fms_kr16", "--convention", "euler"], "invalid choice"),
    (["--to-urdf", "{tmp}/t.yaml"], "-o FILE.urdf"),
    (["--to-urdf", "{tmp}/t.yaml", "-o", "{tmp}/t.urdf", "--convention", "dh"], "states its convention"),
    (["--to-urdf", "{tmp}/none.yaml", "-o", "{tmp}/t.urdf"], "cannot read the parameter table"),
    (["--to-urdf", "{tmp}/bad.yaml", "-o", "{tmp}/t.urdf"], "convention 'euler'; valid"),
    (["fms_kr16", "{tmp}/nothing_here"], "does not exist"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, args, message):
    (tmp_path / "t.yaml").write_text("convention: hayati\njoints: [{name: j1}]\n")
    (tmp_path / "bad.yaml").write_text("convention: euler\njoints: [{name: j1}]\n")
    before = sorted(tmp_path.iterdir())
    try:
        code = main(["table", *(a.replace("{tmp}", str(tmp_path)) for a in args)])
    except SystemExit as exc:                                  # argparse's own errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert sorted(tmp_path.iterdir()) == before


def test_a_table_exact_only_through_huge_lengths_is_named(tmp_path, capsys):
    """Review finding: on a calibrated UR5 (nearly parallel A2-A4) the default modified DH table
    reproduced the model to 2e-11 m, so nothing was named, through d of hundreds of metres (the
    common normal of nearly parallel axes is far away): a table no controller can use. Rows with
    a or d beyond the arm's stretched length are now named, with the advice to use hayati."""
    from calib_oed.model.inverse_kinematics import characteristic_length

    folder = tmp_path / "cal"
    folder.mkdir()
    problem, _, _ = write_calibration(folder, scene="ur5_table", seed=2)
    robot, _, _ = load_calibration(problem.space, folder)
    length = characteristic_length(robot)
    for convention, far in (("mdh", True), ("hayati", False)):
        data, table = _table_json(folder, convention, tmp_path, capsys)
        assert data["exact"]  # the round trip alone names nothing
        big = [r.joint for r in table.rows if max(abs(r.a), abs(r.d)) > length]
        assert bool(big) is far and data["far_rows"] == big
    assert main(["table", "ur5_table", str(folder)]) == 0
    text = capsys.readouterr().out
    assert "NAMED: " in text and "beyond the arm's stretched length" in text and "hayati" in text
