"""The validation verdict: the user's tolerance, monotone in the achieved error; poses outside the
training ranges are named."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.crossval import held_out_errors, subset
from calib_oed.calibration.identification import identify
from calib_oed.calibration.verdict import ON_NEW_POSES, judge, pose_lines, pose_table
from calib_oed.calibration.workflow import setup, simulated_measurements
from calib_oed.exceptions import ParameterError
from calib_oed.scene.reader import load_scene


def test_verdict_is_monotone_for_two_calibrations_of_different_accuracy():
    """A 30-pose and a 120-pose calibration of the same robot, judged on the same 100 validation
    poses against a range of tolerances: whenever the less accurate passes, the more accurate
    passes too, and at some tolerance only the more accurate one passes."""
    s = setup(load_scene("fms_kr16"))
    pr, errors = s.problem, s.scene.error_model()
    mset, _ = simulated_measurements(s, pr.robot.random_configurations(250, 3), 4)
    val = subset(mset, np.arange(150, 250))
    achieved = []
    for n in (30, 120):
        fit = identify(pr.space, subset(mset, np.arange(n)).blocks(error_model=errors), pr.identifiability)
        achieved.append(held_out_errors(pr.space, val, fit.p, errors))
    rms = [np.sqrt(np.mean(e**2)) for e in achieved]
    worse, better = (0, 1) if rms[0] > rms[1] else (1, 0)
    assert rms[worse] > 1.05 * rms[better]
    only_better = False
    for tol in np.linspace(0.5, 1.5, 41) * np.mean(rms):
        v_worse, v_better = (judge(achieved[i], max_rms_mm=tol, predicted=0.03) for i in (worse, better))
        assert not (v_worse.passed and not v_better.passed), tol
        only_better |= v_better.passed and not v_worse.passed
    for tol in np.linspace(0.5, 1.5, 41) * np.mean([e.max() for e in achieved]):
        assert not (judge(achieved[worse], max_error_mm=tol).passed
                    and not judge(achieved[better], max_error_mm=tol).passed)
    assert only_better


def test_no_tolerance_no_verdict_and_the_prediction():
    e = np.array([0.1, 0.2, 0.3])
    v = judge(e, predicted=0.1)
    assert v.passed is None and "verdict: none" in v.lines()[-1]
    assert v.ratio == pytest.approx(np.sqrt(np.mean(e**2)) / 0.1) and "WORSE THAN PREDICTED" in v.lines()[0]
    assert "0.1000 mm RMS at these validation measurements" in v.lines()[0]
    assert "mm RMS on new poses" in judge(e, predicted=0.1, predicted_where=ON_NEW_POSES).lines()[0]
    assert judge(e, max_rms_mm=0.25, max_error_mm=0.25).passed is False  # the largest error fails
    assert judge(e, max_rms_mm=0.25).passed is True
    with pytest.raises(ParameterError, match="--max-rms"):
        judge(e, max_rms_mm=0.0)


def test_poses_outside_the_training_ranges_are_warned_about():
    q = np.zeros((3, 2))
    q[1, 0], q[2, 1] = np.radians(50), np.radians(-5)
    table = pose_table(q, np.array([0.1, 0.2, 0.3]), np.array([5, 6, 7]), ("a1", "a2"),
                       {"a1": [np.radians(-40), np.radians(40)], "a2": [np.radians(-4), np.radians(4)]})
    assert [len(r["outside_training_ranges"]) for r in table] == [0, 1, 1]
    text = "\n".join(pose_lines(table))
    assert "pose 2 (line 6) has a1 = 50.0 deg, outside the training range -40.0..40.0" in text


@pytest.mark.parametrize("text", ['{"predicted_accuracy": {"uncompensated": ', "[1, 2]"], ids=["truncated", "a-list"])
def test_a_corrupt_identification_is_named_not_taken_for_none_recorded(tmp_path, text):
    from calib_oed.calibration.verdict import read_identification
    from calib_oed.exceptions import InputFileError

    files = {"urdf": str(tmp_path / "kr16_calibrated.urdf")}
    assert read_identification(files) is None                   # no file: nothing recorded
    (tmp_path / "identification.json").write_text('{"predicted_accuracy": {}}')
    assert read_identification(files) == {"predicted_accuracy": {}}
    (tmp_path / "identification.json").write_text(text)
    with pytest.raises(InputFileError, match="identification.json: the identification is unreadable"):
        read_identification(files)
