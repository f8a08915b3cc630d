"""``identify --adopt-registration`` (issue 34): a scene whose tracker pose and reflector
offset are wrong is rewritten with the fitted ones, and the identification goes on with it."""

from __future__ import annotations

import numpy as np

from calib_oed.calibration.workflow import setup, simulated_measurements, write_measurement_file
from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main
from calib_oed.scene.reader import load_scene
from tests.cli.test_bad_inputs import SHIPPED


def test_a_wrong_tracker_pose_and_offset_are_adopted(tmp_path, capsys):
    s = setup("fms_kr16")
    mset, _ = simulated_measurements(s, s.problem.robot.random_configurations(30, 2), 1)
    write_measurement_file(s, tmp_path / "m.csv", mset, "adopt test")
    wrong = (SHIPPED.read_text().replace("position: [600, -2600, 1300]", "position: [680, -2550, 1300]")
             .replace("rpy: [0, 10, 90]", "rpy: [0, 12, 88]").replace("offset: [0, 0, 50]", "offset: [0, 0, 80]"))
    (tmp_path / "wrong.yaml").write_text(wrong)
    m, scene = str(tmp_path / "m.csv"), str(tmp_path / "wrong.yaml")
    assert main(["identify", scene, m, "--json"]) == EXIT_BAD_INPUT  # the data do not fit
    capsys.readouterr()
    adopted = tmp_path / "adopted.yaml"
    assert main(["identify", scene, m, "--adopt-registration", str(adopted), "--json"]) == EXIT_OK
    assert "adopted the registration into" in capsys.readouterr().err
    new, true = load_scene(adopted), s.scene
    # the truth moves the tracker and the offsets by about 0.5 mm: adopted to within a few mm
    assert np.linalg.norm(new.tracker.placement().translation - true.tracker.placement().translation) < 3e-3
    assert np.linalg.norm(new.reflectors[0].offset - true.reflectors[0].offset) < 3e-3
    assert [c.name for c in new.cell.capsules] == [c.name for c in true.cell.capsules]
    assert new.robot.name == true.robot.name and new.tracker.noise == true.tracker.noise


def test_the_adopted_scene_must_not_replace_the_scene(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(SHIPPED.read_text())
    assert main(["identify", str(tmp_path / "s.yaml"), "m.csv", "--adopt-registration",
                 str(tmp_path / "s.yaml")]) == EXIT_BAD_INPUT
    assert "is the input SCENE file" in capsys.readouterr().err
