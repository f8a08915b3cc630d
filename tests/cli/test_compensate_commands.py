"""`calib-oed compensate`: the files written, the report, and bad input as one line with exit 2."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from calib_oed.cli import main
from calib_oed.exceptions import CalibOedNote
from tests.calibration.test_compensation_files import write_calibration
from tests.program.parse import samples


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cal")
    write_calibration(folder)
    return folder


def test_compensates_a_krl_program(calibration, tmp_path, capsys):
    (tmp_path / "weld_demo.src").write_text(samples.KRL_SRC)
    (tmp_path / "weld_demo.dat").write_text(samples.KRL_DAT)
    out = tmp_path / "out"
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "weld_demo.src"), "-o", str(out),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert sorted(p.name for p in out.iterdir()) == ["weld_demo.dat", "weld_demo.src"]
    assert data["tool"] == "file" and len(data["targets"]) == 5
    predicted = [t["predicted_residual_mm"] for t in data["targets"]]
    assert all(0.001 < p < 0.1 for p in predicted)
    assert "predicted residual" in (out / "weld_demo.dat").read_text()
    named = {line.split(":")[0] for line in data["issues"]}
    flagged = {t["name"] for t in data["targets"] if t["sigma_min"] < 0.01 or not t["in_range"] or not t["changed"]
               or t["configuration_changes"] or t["declared_configuration"]}
    assert named == flagged
    # XP4's T 10 says A1 >= 0, but the pose's joints (-15, -100, 110, -20, 40, 60) deg have A1 < 0 (T 11),
    # and A1 = 345 deg is beyond the limit: named
    xp4 = next(t for t in data["targets"] if t["name"] == "XP4")
    assert xp4["declared_configuration"].startswith("declared S 2, T 10, the nominal solution compensated has S 2, T 11")
    # XP2's S 6 (A5 <= 0) is the flipped wrist of the pose taught at (10, -80, 95, 0, 30, 0): compensated there
    xp2 = next(t for t in data["targets"] if t["name"] == "XP2")
    assert xp2["declared_configuration"] is None and not xp2["configuration_changes"]
    assert next(t for t in data["targets"] if t["name"] == "XHOME")["declared_configuration"] is None


def test_a_configuration_change_is_named(calibration, tmp_path, capsys):
    """pApproach is taught at A4 = A6 = 0 (to the pendant's rounding: A4 +0.002 deg): compensated, both
    cross 0 and ABB's cf4 and cf6 change quadrant; as written they ask for A4 and A6 a turn away."""
    (tmp_path / "p.mod").write_text(samples.RAPID_MOD)
    out = tmp_path / "out"
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.mod"), "-o", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    target = next(t for t in data["targets"] if t["name"] == "pApproach")
    assert [c.split(" ")[:3] for c in target["configuration_changes"]] == [["turn", "of", "joint_a4"],
                                                                          ["turn", "of", "joint_a6"]]
    assert any(line.startswith("pApproach: the controller configuration changes (turn of joint_a4")
               for line in data["issues"])
    assert "controller configuration changes: turn of joint_a4" in (out / "p.mod").read_text()
    assert target["declared_configuration"] is None          # its confdata [0, 0, -1, 0] is that of its joints


def test_a_rapid_confdata_of_another_branch_is_named(calibration, tmp_path, capsys):
    """The last MoveL declares confdata [0, 0, 0, 0], but the nominal controller solves its pose at
    (-15, -100, 110, -20, 40, 60) deg, whose axes 1 and 4 are in quadrant -1: the controller would
    refuse the move or take other joints than those compensated, so the target is named."""
    (tmp_path / "p.mod").write_text(samples.RAPID_MOD)
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.mod"), "-o", str(tmp_path / "o"),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    last = data["targets"][-1]
    assert last["declared_configuration"].startswith("declared cf1 0, cf4 0, cf6 0, cfx 0, the nominal solution "
                                                     "compensated has cf1 -1, cf4 -1, cf6 0, cfx 0")
    assert [t["declared_configuration"] for t in data["targets"][:-1]] == [None] * (len(data["targets"]) - 1)
    assert any(line.startswith(f"{last['name']}: declared cf1 0") for line in data["issues"])


def test_text_report_and_default_folder(calibration, tmp_path, capsys):
    (tmp_path / "p.ls").write_text(samples.TP_LS)
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.ls"),
                 "--tool=12.5,0,180,0,0,0", "--base=1000,-200,0,0,0,90"]) == 0
    out = capsys.readouterr().out
    assert "predicted residual after compensation" in out and "tool from given" in out
    assert (tmp_path / "compensated" / "p.ls").is_file()


@pytest.mark.parametrize("args, message", [
    (["--tool=1,2,3"], "six numbers"),
    (["-o", "{prog}"], "program's own folder"),
])
def test_bad_input_is_one_line(calibration, tmp_path, capsys, args, message):
    (tmp_path / "p.ls").write_text(samples.TP_LS)
    args = [a.replace("{prog}", str(tmp_path)) for a in args]
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.ls"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "compensated").exists()


def test_missing_calibration_is_one_line(tmp_path, capsys):
    (tmp_path / "p.ls").write_text(samples.TP_LS)
    assert main(["compensate", "fms_kr16", str(tmp_path / "nope"), str(tmp_path / "p.ls")]) == 2
    assert "does not exist" in capsys.readouterr().err
    np.testing.assert_equal((tmp_path / "compensated").exists(), False)


def test_krl_src_and_dat_are_written_as_a_pair(calibration, tmp_path, capsys):
    """A .src that cannot be written: the .dat is not written either (no mismatched pair)."""
    (tmp_path / "weld_demo.src").write_text(samples.KRL_SRC)
    (tmp_path / "weld_demo.dat").write_text(samples.KRL_DAT)
    out = tmp_path / "out"
    (out / "weld_demo.src").mkdir(parents=True)
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "weld_demo.src"), "-o", str(out)]) == 2
    assert "not a regular file" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["weld_demo.src"]


def test_a_tp_program_mixing_tool_frames_is_one_line_exit_2(calibration, tmp_path, capsys):
    text = samples.TP_LS.replace('P[2]{\n   GP1:\n\tUF : 1, UT : 1,', 'P[2]{\n   GP1:\n\tUF : 1, UT : 2,')
    (tmp_path / "p.ls").write_text(text)
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.ls")]) == 2
    err = capsys.readouterr().err.strip()
    assert "P[1] in UT 1, P[2] in UT 2" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "compensated").exists()


def test_moves_not_compensated_are_in_the_report_and_the_json(calibration, tmp_path, capsys):
    """A move whose point is not read (here a KRL LIN_REL) is named in the text report's notes and
    in --json's notes, with its file and line, and left as written."""
    src = samples.KRL_SRC.replace("PTP XP4\n", "PTP XP4\nLIN_REL {X 100} C_DIS\n", 1)
    line = src.splitlines().index("LIN_REL {X 100} C_DIS") + 1
    (tmp_path / "w.src").write_text(src)
    (tmp_path / "w.dat").write_text(samples.KRL_DAT)
    args = ["compensate", "fms_kr16", str(calibration), str(tmp_path / "w.src"), "-o", str(tmp_path / "out")]
    assert main([*args, "--json"]) == 0
    notes = json.loads(capsys.readouterr().out)["notes"]
    assert [n for n in notes if "NOT compensated" in n] == [
        f"w.src:{line}: LIN_REL {{X 100}} C_DIS: NOT compensated: a relative move (LIN_REL): its target is an "
        "offset from where the robot is, not a point"]
    assert "\nLIN_REL {X 100} C_DIS\n" in (tmp_path / "out" / "w.src").read_text()
    assert main(args) == 0
    assert f"  note: w.src:{line}: LIN_REL {{X 100}} C_DIS: NOT compensated" in capsys.readouterr().out


def test_a_calibration_with_compliance_and_gains_is_compensated_with_them(tmp_path, capsys):
    """The files written are the program compensated with the joint deflection (payload: the one
    identified under, the scene declaring none; or --payload-kg), and the report says so."""
    from calib_oed.calibration.compensation_files import load_compensation
    from calib_oed.calibration.problem import CalibrationProblem
    from calib_oed.program.compensate import compensate_program
    from calib_oed.program.parse.files import read_program
    from calib_oed.scene.reader import load_scene
    from tests.calibration.test_compensation import deflecting_scene

    (tmp_path / "cal").mkdir()
    write_calibration(tmp_path / "cal", deflecting_scene())
    (tmp_path / "weld_demo.src").write_text(samples.KRL_SRC)
    (tmp_path / "weld_demo.dat").write_text(samples.KRL_DAT)
    scene = load_scene("fms_kr16")
    problem = CalibrationProblem.from_scene(scene)
    parsed, _ = read_program(tmp_path / "weld_demo.src", scene.robot.joint_names)

    def api(payload_kg=None, rigid=False):
        loaded = load_compensation(problem.space, tmp_path / "cal", payload_kg)
        return compensate_program(parsed, scene.robot, loaded.robot, uncertainty=loaded.uncertainty,
                                  controller=scene.controller, home=problem.kpi.configurations[0],
                                  deflection=None if rigid else loaded.deflection).texts

    for extra, payload in (([], None), (["--payload-kg", "0"], 0.0)):
        out = tmp_path / f"out{len(extra)}"
        assert main(["compensate", "fms_kr16", str(tmp_path / "cal"), str(tmp_path / "weld_demo.src"),
                     "-o", str(out), *extra]) == 0
        report = capsys.readouterr().out
        assert "compensated with joint compliance under gravity, payload" in report and "6 joint gains" in report
        assert ("--payload-kg" in report) == bool(extra)
        written = {name: (out / name).read_text() for name in ("weld_demo.src", "weld_demo.dat")}
        assert written == api(payload)
    assert api(0.0)["weld_demo.dat"] != api()["weld_demo.dat"] != api(rigid=True)["weld_demo.dat"]


def test_payload_without_compliance_is_one_line(calibration, tmp_path, capsys):
    (tmp_path / "p.ls").write_text(samples.TP_LS)
    assert main(["compensate", "fms_kr16", str(calibration), str(tmp_path / "p.ls"), "--payload-kg", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "identified no joint compliance" in err[0]


def test_the_scenes_payload_is_the_working_one_even_with_compliance_disabled(tmp_path, capsys):
    """fms_kr300 declares its rated 300 kg under robot.compliance with enabled: false; a calibration
    identified under 100 kg is compensated for the scene's 300 kg."""
    import dataclasses

    from calib_oed.model.compliance import Compliance
    from calib_oed.scene.reader import load_scene
    from calib_oed.scene.records import ComplianceSpec

    scene = load_scene("fms_kr300")
    assert scene.compliance is not None and not scene.compliance.enabled
    identified = dataclasses.replace(scene, compliance=ComplianceSpec(True, Compliance(100.0, [0.0, 0.0, 0.1])))
    (tmp_path / "cal").mkdir()
    write_calibration(tmp_path / "cal", identified)
    (tmp_path / "p.src").write_text(samples.KRL_SRC)
    (tmp_path / "p.dat").write_text(samples.KRL_DAT)
    assert main(["compensate", "fms_kr300", str(tmp_path / "cal"), str(tmp_path / "p.src"), "-o",
                 str(tmp_path / "out"), "--json"]) == 0
    text = json.loads(capsys.readouterr().out)["joint_deflection"]
    assert "payload 300 kg at [0.0, 0.0, 200.0] mm" in text and "the scene's robot.compliance.payload" in text


def test_targets_outside_the_measured_joint_ranges_are_named(tmp_path, capsys):
    """The calibrated range is the range the measurements spanned (identification.json's
    training_joint_ranges), not the robot's limits: a joint target with A1 beyond it is named."""
    folder = tmp_path / "cal"
    folder.mkdir()
    write_calibration(folder)
    ident = json.loads((folder / "identification.json").read_text())
    names = ["joint_a1", "joint_a2", "joint_a3", "joint_a4", "joint_a5", "joint_a6"]
    ident["training_joint_ranges"] = {n: [-1.0, 1.0] if n == "joint_a1" else [-3.0, 3.0] for n in names}
    (folder / "identification.json").write_text(json.dumps(ident))
    (tmp_path / "t.csv").write_text(",".join(f"{n}_rad" for n in names) + "\n0.5,-1.4,1.6,0.0,0.5,0.0\n1.2,-1.4,1.6,0.0,0.5,0.0\n")
    assert main(["compensate", "fms_kr16", str(folder), str(tmp_path / "t.csv"), "-o", str(tmp_path / "o"),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [t["in_range"] for t in data["targets"]] == [True, False]


def test_a_negative_compliance_is_named():
    """A negative identified compliance is a negative stiffness (identify calls it implausible):
    compensate says so, as compensating with it can move the targets the wrong way."""
    from types import SimpleNamespace

    from calib_oed.cli.compensate_commands import _note_negative_compliance

    names = [f"joint_a{i}" for i in range(1, 7)]
    loaded = SimpleNamespace(deflection=SimpleNamespace(compliance=np.array([0, -2e-6, 4e-6, 0, 0, 0])))
    with pytest.warns(CalibOedNote, match=r"negative on joint_a2 \(-5e\+05 N·m/rad\): a negative stiffness"):
        _note_negative_compliance(loaded, names)
    for quiet in (SimpleNamespace(deflection=None), SimpleNamespace(deflection=SimpleNamespace(compliance=None)),
                  SimpleNamespace(deflection=SimpleNamespace(compliance=np.array([0, 2e-6, 4e-6, 0, 0, 0])))):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _note_negative_compliance(quiet, names)
