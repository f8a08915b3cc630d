"""Joint gains in a calibration: the scene key, recovery within the predicted std, export and validation."""

from __future__ import annotations

import dataclasses
import json
from importlib import resources

import numpy as np
import pytest
import yaml

from calib_oed.calibration.export import export_calibration
from calib_oed.calibration.identification import identify
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.sensor_file import read_sensor_gains
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.cli import EXIT_OK, main
from calib_oed.exceptions import ExportError, SceneError
from calib_oed.model.joint_map import JointGains
from calib_oed.scene.reader import load_scene, scene_from_dict

FANUC_COUPLING = {"name": "fanuc", "couplings": [{"joint": 3, "from": 2, "ratio": 1.0}]}


def _raw(name="fms_kr16"):
    return yaml.safe_load((resources.files("calib_oed.scene.shipped") / f"{name}.yaml").read_text())


def test_scene_key_and_its_errors():
    raw = _raw()
    assert load_scene("fms_kr16").joint_gains is None
    raw["robot"]["joint_gains"] = True
    assert scene_from_dict(raw).joint_gains == JointGains.all_joints(6)
    raw["robot"]["joint_gains"] = {"joints": [2, 3], "couplings": True}
    raw["controller"] = FANUC_COUPLING
    scene = scene_from_dict(raw)
    assert scene.joint_gains == JointGains((2, 3), ((3, 2),))
    names = CalibrationProblem.from_scene(scene).space.names
    assert names[-3:] == ("joint2.gain", "joint3.gain", "joint3.coupling2")
    raw["robot"]["joint_gains"] = {"enabled": False}
    assert scene_from_dict(raw).joint_gains is None
    del raw["controller"]
    for value, match in [({"couplings": True}, r"robot\.joint_gains\.couplings.*controller"),
                         ({"joints": [0, 7]}, r"robot\.joint_gains\.joints.*1\.\.6"),
                         ({"joints": [], "couplings": False}, "at least one"),
                         ({"gains": True}, r"robot\.joint_gains.*enabled, joints, couplings")]:
        raw["robot"]["joint_gains"] = value
        with pytest.raises(SceneError, match=match):
            scene_from_dict(raw)


@pytest.fixture(scope="module")
def gain_problem():
    """kr16 of fms_kr16 with every joint's gain and the J2 -> J3 coupling ratio."""
    scene = dataclasses.replace(load_scene("fms_kr16"), joint_gains=JointGains.all_joints(6, ((3, 2),)))
    return CalibrationProblem.from_scene(scene)


def test_gauge_of_the_gains(gain_problem):
    """A6's gain cannot be seen: the reflector sits on the A6 axis. The others, and the coupling, are free."""
    report = gain_problem.identifiability
    fixed = {f.name: f for f in report.fixed}
    assert fixed["joint6.gain"].reason == "no effect on the measurements"
    assert {"joint1.gain", "joint2.gain", "joint3.gain", "joint4.gain", "joint5.gain",
            "joint3.coupling2"} <= set(report.free_names)
    assert report.rank == 25 + 6  # the geometric rank plus five gains and the coupling


def test_gains_of_1e3_recovered_within_3_sigma(gain_problem):
    """60 simulated calibrations (40 random poses each), true free gains and coupling 1e-3.

    One calibration: every gain within 3 predicted std. Monte Carlo: the Mahalanobis distance
    of the 6 gain errors under their predicted covariance is chi-square(6) per trial, so its mean
    over 60 independent trials / 6 is 1 with s.e. sqrt(2 / 360) = 0.075 (band +-3 s.e.); and at
    least 98 % of the 360 normalised errors lie within 3 std (expected 99.7 %).
    """
    space, report = gain_problem.space, gain_problem.identifiability
    free = list(report.free_indices)
    gains = [i for i in free if i >= space.gain_slice.start]
    local = [free.index(i) for i in gains]
    z, chi2 = [], []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        p_true = draw_true_parameters(space, report.free_indices, rng)
        p_true[gains] = 1e-3
        q = gain_problem.robot.random_configurations(40, 100 + seed)
        result = identify(space, simulate_observations(space, gain_problem.models, q, p_true, rng), report)
        assert result.status.name == "CONVERGED"
        err = result.p[gains] - p_true[gains]
        cov = result.covariance[np.ix_(local, local)]
        chi2.append(err @ np.linalg.solve(cov, err))
        z.append(err / np.sqrt(np.diag(cov)))
        if seed == 0:
            assert np.all(np.abs(z[0]) < 3)
            assert np.all(np.sqrt(np.diag(cov)) < 1e-4)  # 1e-3 is determined to better than 10 %
    assert 1 - 3 * 0.075 < np.mean(chi2) / 6 < 1 + 3 * 0.075
    assert np.mean(np.abs(np.array(z)) < 3) >= 0.98


def test_sensor_yaml_round_trip_and_errors(gain_problem, tmp_path):
    space = gain_problem.space
    p = space.zeros()
    p[space.gain_slice] = np.arange(1, 8) * 1e-4
    path = export_calibration(space, p, tmp_path)["sensor"]
    layout, values = read_sensor_gains(path, space.robot.joint_names)
    assert layout == space.joint_gains
    np.testing.assert_array_equal(values, p[space.gain_slice])
    rigid = export_calibration(CalibrationProblem.from_scene(load_scene("fms_kr16")).space, None,
                               tmp_path, stem="rigid")["sensor"]
    assert read_sensor_gains(rigid, space.robot.joint_names) is None
    data = yaml.safe_load(path.read_text())
    data["joint_gains"]["joints"][1]["joint"] = "elbow"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ExportError, match=r"joint_gains\.joints\[1\].*elbow"):
        read_sensor_gains(path, space.robot.joint_names)


def test_simulate_identify_validate_with_gains(tmp_path, capsys):
    """The command line on a scene with joint gains: the gains go to the sensor YAML and validate
    applies them, so the calibration predicts fresh poses at the noise floor."""
    raw = _raw()
    raw["robot"]["joint_gains"] = {"joints": "all"}
    scene = tmp_path / "gains.yaml"
    scene.write_text(yaml.safe_dump(raw))
    assert main(["simulate", str(scene), "-n", "42", "--seed", "0", "--truth-seed", "3",
                 "-o", str(tmp_path / "all.csv"), "--quiet"]) == EXIT_OK
    lines = (tmp_path / "all.csv").read_text().splitlines(keepends=True)
    head = [line for line in lines if line.startswith("#")] + [lines[4]]
    rows = lines[5:]
    assert len(rows) == 42 and head[-1].startswith("joint_a1")
    (tmp_path / "m.csv").write_text("".join(head + rows[:30]))  # 30 poses to calibrate
    (tmp_path / "v.csv").write_text("".join(head + rows[30:]))  # 12 fresh poses to validate
    assert main(["identify", str(scene), str(tmp_path / "m.csv"), "-o", str(tmp_path / "c"), "--json"]) == EXIT_OK
    capsys.readouterr()
    assert main(["validate", str(scene), str(tmp_path / "c"), str(tmp_path / "v.csv"), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["calibrated"]["rms_mm"] < 1.3 * data["noise_floor_mm"]
    gains = read_sensor_gains(tmp_path / "c" / "kr16_sensor.yaml", load_scene("fms_kr16").robot.joint_names)
    assert gains is not None and np.abs(gains[1]).max() > 1e-4  # the simulated truth has gains of ~1e-3


def test_a_ratio_the_data_cannot_separate_is_held_and_reported(gain_problem):
    """FANUC-style data: the controller's J3 held while J2 sweeps, so the URDF's q3 = q2 + const.

    Then the coupling's column kappa q2 = kappa (q3 - const) is joint 3's gain plus an offset: the
    generic design separates it, these data do not, and identify holds it at nominal and says why.
    """
    space, report = gain_problem.space, gain_problem.identifiability
    assert "joint3.coupling2" in report.free_names
    rng = np.random.default_rng(7)
    p_true = draw_true_parameters(space, report.free_indices, rng)
    p_true[space.index("joint3.coupling2")] = 0.0
    q = gain_problem.robot.random_configurations(40, 8)
    q[:, 1] = rng.uniform(-2.2, 0.6, len(q))
    q[:, 2] = q[:, 1] + 0.3
    result = identify(space, simulate_observations(space, gain_problem.models, q, p_true, rng), report)
    assert result.status.name == "CONVERGED"
    assert "joint3.coupling2" not in result.free_names and result.p[space.index("joint3.coupling2")] == 0.0
    assert "joint3.coupling2 held at nominal, the data cannot separate it: redundant with joint3.gain" \
        in result.message
    assert set(result.free_names) == set(report.free_names) - {"joint3.coupling2"}
    i = space.index("joint3.gain")
    assert abs(result.estimate("joint3.gain").value - p_true[i]) < 4 * result.estimate("joint3.gain").std
