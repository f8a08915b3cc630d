"""The calibration compensate reads: identify's folder, and what it refuses."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.calibration.compensation_files import load_calibration, load_compensation
from calib_oed.calibration.export import export_calibration
from calib_oed.calibration.identification import identify
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.exceptions import CompensationError, ExportError
from calib_oed.scene.reader import load_scene


def write_calibration(folder, scene="fms_kr16", seed=1):
    """What `identify -o folder` writes (URDF, sensor YAML, identification.json) for a simulated truth
    (``scene``: a name or a Scene)."""
    problem = CalibrationProblem.from_scene(load_scene(scene) if isinstance(scene, str) else scene)
    space = problem.space
    rng = np.random.default_rng(seed)
    p_true = draw_true_parameters(space, problem.identifiability.free_indices, rng)
    q = space.robot.random_configurations(50, 0)
    result = identify(space, simulate_observations(space, problem.models, q, p_true, rng), problem.identifiability)
    export_calibration(space, result.p, folder)
    (folder / "identification.json").write_text(json.dumps(result.to_dict()))
    return problem, result, p_true


def test_reads_what_identify_writes(tmp_path):
    problem, result, _ = write_calibration(tmp_path)
    robot, unc, files = load_calibration(problem.space, tmp_path)
    assert robot.joint_names == problem.space.robot.joint_names
    assert np.array_equal(unc.free_indices, result.free_indices)
    scale = max(1.0, result.noise_factor)
    assert np.allclose(unc.covariance, result.covariance * scale, rtol=1e-12)
    assert np.allclose(unc.p, result.p)
    assert set(files) == {"urdf", "sensor", "identification"}


def test_without_identification_json_there_is_no_prediction(tmp_path):
    problem, _, _ = write_calibration(tmp_path)
    (tmp_path / "identification.json").unlink()
    assert load_calibration(problem.space, tmp_path)[1] is None


def test_another_scenes_calibration_is_refused(tmp_path):
    write_calibration(tmp_path)
    other = CalibrationProblem.from_scene(load_scene("fms_kr300"))
    with pytest.raises(ExportError, match="a calibration of robot 'kr16', not of this scene's robot 'kr300'"):
        load_calibration(other.space, tmp_path)  # named by the sensor file's robot
    sensor = tmp_path / "kr16_sensor.yaml"
    sensor.write_text(sensor.read_text().replace("robot: kr16\n", ""))  # without it: by the joint placements
    with pytest.raises(CompensationError, match="not a calibration of this robot"):
        load_calibration(other.space, tmp_path)
    data = json.loads((tmp_path / "identification.json").read_text())
    own = CalibrationProblem.from_scene(load_scene("fms_kr16")).space
    data["p"]["joint2.tx"] += 1e-4                       # another identification's estimate
    (tmp_path / "identification.json").write_text(json.dumps(data))
    with pytest.raises(CompensationError, match="not from one identification"):
        load_calibration(own, tmp_path)
    data["p"]["joint9.tx"] = 0.0
    (tmp_path / "identification.json").write_text(json.dumps(data))
    with pytest.raises(CompensationError, match="not a calibration of this scene"):
        load_calibration(own, tmp_path)


def test_the_fitted_model_error_enters_the_prediction(tmp_path):
    """identify writes model_error.fitted: C_t = G C_p G^T + sigma^2 I, and C_p is not scaled by sigma0^2."""
    problem, result, _ = write_calibration(tmp_path)
    data = json.loads((tmp_path / "identification.json").read_text())
    data["noise_factor"] = 9.0
    q, point = problem.space.robot.random_configurations(4, 3), np.array([0.0, 0.0, 0.1])
    data.pop("model_error", None)
    (tmp_path / "identification.json").write_text(json.dumps(data))
    _, scaled, _ = load_calibration(problem.space, tmp_path)
    data["model_error"] = {"fitted": {"sigma_mm": 0.1, "sigma_white_mm": 0.02,
                                      "length_scales_deg": [60.0] * 6}}
    (tmp_path / "identification.json").write_text(json.dumps(data))
    _, unc, _ = load_calibration(problem.space, tmp_path)
    assert np.allclose(unc.covariance, result.covariance, rtol=1e-12)
    expected = scaled.compute_covariance(q, point) / 9.0 + (1e-4**2 + 2e-5**2) * np.eye(3)
    assert np.allclose(unc.compute_covariance(q, point), expected, rtol=1e-9, atol=0)
    data["model_error"] = {"fitted": {"sigma_mm": -1.0, "length_scales_deg": [60.0] * 6}}
    (tmp_path / "identification.json").write_text(json.dumps(data))
    with pytest.raises(CompensationError, match="cannot read the identification"):
        load_calibration(problem.space, tmp_path)


def test_identification_json_is_read_bounded(tmp_path, monkeypatch):
    """identification.json is read like every input file: a file over the bound and a folder of
    that name are refused, naming the file (never read whole, never taken for "no file")."""
    import calib_oed.calibration.compensation_files as files_module
    from calib_oed.exceptions import InputFileError

    problem, _, _ = write_calibration(tmp_path)
    size = (tmp_path / "identification.json").stat().st_size
    monkeypatch.setattr(files_module, "MAX_TEXT_BYTES", size - 1)
    with pytest.raises(InputFileError, match=r"identification\.json: the identification has .* more than"):
        load_calibration(problem.space, tmp_path)
    monkeypatch.setattr(files_module, "MAX_TEXT_BYTES", size)
    assert load_calibration(problem.space, tmp_path)[1] is not None
    (tmp_path / "identification.json").unlink()
    (tmp_path / "identification.json").mkdir()
    with pytest.raises(InputFileError, match="is a folder"):
        load_calibration(problem.space, tmp_path)


def test_compliance_and_gains_are_kept_for_compensate(tmp_path):
    """A calibration with joint compliance and gains: ``table``'s reader refuses it (a URDF cannot hold
    them); ``compensate``'s keeps them as the joint deflection, with the working payload named."""
    from calib_oed.model.deflected_kinematics import JointDeflection
    from tests.calibration.test_compensation import deflecting_scene
    from tests.model.test_deflected_kinematics import effective

    problem, result, _ = write_calibration(tmp_path, deflecting_scene())
    with pytest.raises(CompensationError, match="joint compliance, which a URDF or a parameter table cannot hold"):
        load_calibration(problem.space, tmp_path)
    q = problem.space.robot.random_configurations(5, 7)
    expected = effective(JointDeflection.from_space(problem.space, result.p), q)
    loaded = load_compensation(problem.space, tmp_path)              # the scene declares the payload
    assert np.allclose(effective(loaded.deflection, q), expected, rtol=0, atol=1e-14)
    assert "16 kg" in loaded.payload and "the scene's robot.compliance.payload" in loaded.payload
    assert np.allclose(loaded.uncertainty.p, result.p) and len(loaded.deflection.gains) == 6
    plain = CalibrationProblem.from_scene(load_scene("fms_kr16")).space    # no compliance block: the file's
    loaded = load_compensation(plain, tmp_path)
    assert np.allclose(effective(loaded.deflection, q), expected, rtol=0, atol=1e-14)
    assert "identified under" in loaded.payload
    empty = load_compensation(plain, tmp_path, payload_mass=0.0)      # another payload: another deflection
    assert "0 kg" in empty.payload and "--payload-kg" in empty.payload
    assert np.abs(effective(empty.deflection, q) - expected).max() > 1e-6
    data = json.loads((tmp_path / "identification.json").read_text())
    data["p"]["joint2.c"] *= 1.01                                     # not the sensor file's compliance
    (tmp_path / "identification.json").write_text(json.dumps(data))
    with pytest.raises(CompensationError, match="not from one identification"):
        load_compensation(plain, tmp_path)
    (tmp_path / "identification.json").unlink()                       # the sensor file alone
    loaded = load_compensation(plain, tmp_path)
    assert loaded.uncertainty is None
    assert np.allclose(effective(loaded.deflection, q), expected, rtol=0, atol=1e-14)
