"""validate's predicted error per pose, from identification.json: the same covariance as the
identification's own prediction, and its regions hold the realistic simulator's new poses."""

from __future__ import annotations

import json

import numpy as np
import pytest

from calib_oed.calibration.model_error import Linearisation, start_prior
from calib_oed.calibration.pose_prediction import read_record
from calib_oed.calibration.prediction import error_covariances, new_poses
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_measure import measure
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.trust import assess
from calib_oed.calibration.validation import validate_calibration
from calib_oed.calibration.verdict import pose_lines, pose_table
from calib_oed.calibration.workflow import export_result, setup
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.dataset import MeasurementSet
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """fms_kr16 on a realistic truth: identify's fit of 60 poses written as identify -o writes it,
    and 150 validation poses in the training ranges."""
    s = setup(load_scene("fms_kr16"))
    pr = s.problem
    q = pr.robot.random_configurations(60, 1003)
    q_val = new_poses(q, 150, 2003)
    rng = np.random.default_rng(3)
    (b,) = measure(sample_truth(s, rng), pr.models, np.vstack([q, q_val]), rng).blocks
    train = [ObservationBlock(b.model, q, b.values[:60])]
    rob = identify_robust(pr.space, train, pr.identifiability, model_error=start_prior(s.scene, pr))
    assert rob.model_error.prior.scale is not None  # identify's model error, pose-scaled
    trust = assess(pr, rob)
    folder = tmp_path_factory.mktemp("cal")
    export_result(s, rob.result, folder)
    data = {"model_error": rob.model_error.to_dict(), **trust.to_dict()}
    (folder / "identification.json").write_text(json.dumps(data))
    val = MeasurementSet.from_arrays(pr.robot, q_val, b.values[60:])
    return s, rob, folder, val, data


def test_the_linearisation_round_trips_through_json(calibrated):
    _, rob, _, _, data = calibrated
    lin = rob.linearisation
    back = Linearisation.from_dict(json.loads(json.dumps(data["prediction_data"])))
    for name in ("q", "position", "component", "measurement", "jac", "noise", "residual"):
        assert np.array_equal(getattr(back, name), getattr(lin, name)), name
    record = read_record(data, calibrated[0].problem.space)
    assert record is not None and record[2] == tuple(rob.result.free_names)
    q = rob.linearisation.q[:7]
    assert np.allclose(record[1].covariance_kernel(q, q), rob.model_error.prior.covariance_kernel(q, q),
                       rtol=1e-9, atol=0)  # the pose scale restored
    assert read_record({"model_error": data["model_error"]}, calibrated[0].problem.space) is None  # an older identification.json


@pytest.mark.parametrize("compensated", [False, True])
def test_validate_predicts_each_pose_as_the_identification_does(calibrated, compensated):
    """Per validation row, sqrt(tr V) from the exported files equals the identification's own
    V at its estimate within 1 % (the Jacobian of the calibrated files differs by second-order
    terms); on the realistic truth 85-99 % of the rows lie in their 95 % regions (150 correlated
    rows of one truth; bench/bench_trust.py measures the coverage over many truths)."""
    s, rob, folder, val, _ = calibrated
    result = validate_calibration(s.scene, folder, val, compensated=compensated)
    pred = result.predicted
    assert pred is not None and pred.compensated == compensated
    res = rob.result
    state = evaluate_setup(s.problem.space, res.p, val.q, regressor=True, jacobian=False)
    (model,) = s.problem.models
    h = model.compute_values(state)
    jac = model.compute_param_jacobian(state)[:, :3][:, :, res.free_indices]
    v = error_covariances(rob.linearisation, rob.model_error.prior, jac, val.q,
                          model.noise_covariance(h)[:, :3, :3], compensated)
    direct = np.sqrt(np.trace(v, axis1=1, axis2=2)) * 1e3
    assert np.allclose(pred.rms_mm, direct, rtol=1e-2), np.max(np.abs(pred.rms_mm / direct - 1))
    assert 0.85 <= pred.inside.mean() <= 0.99, pred.inside.mean()
    assert "inside their 95 % prediction regions" in result.summary()
    assert result.to_dict()["predicted_rms_mm"] == pytest.approx(np.sqrt(np.mean(direct**2)), rel=1e-2)
    table = pose_table(val.q, result.calibrated.position_mm, val.lines, val.joint_names, None,
                       pred.rms_mm, pred.inside)
    assert [r["predicted_rms_mm"] for r in table] == pytest.approx(pred.rms_mm.tolist(), rel=1e-12)
    assert sum(r["inside_95"] for r in table) == pred.inside.sum()
    assert "predicted RMS" in pose_lines(table)[1]


def test_validate_judges_against_the_prediction_at_its_own_measurements(calibrated):
    """The realistic truth, validated on the half of the 150 rows where the identification predicts
    the smallest error (a validation set in the easier part of the workspace): validate's ratio
    is the achieved RMS over the prediction at those very rows, within 0.8-1.25; an
    identification.json without prediction_data falls back to the headline on new poses."""
    from calib_oed.calibration.crossval import subset
    from calib_oed.calibration.verdict import (
        AT_MEASUREMENTS,
        ON_NEW_POSES,
        judge,
        validation_prediction,
    )

    s, _, folder, val, data = calibrated
    rows = np.argsort(validate_calibration(s.scene, folder, val).predicted.rms_mm)[:75]
    part = validate_calibration(s.scene, folder, subset(val, np.sort(rows)))
    predicted, where = validation_prediction(part.predicted, data, False)
    assert where == AT_MEASUREMENTS and predicted == part.predicted.total_rms_mm
    ratio = judge(part.calibrated.position_mm, predicted=predicted, predicted_where=where).ratio
    assert 0.8 < ratio < 1.25, ratio
    headline, fallback = validation_prediction(None, data, False)
    assert fallback == ON_NEW_POSES
    assert headline == data["predicted_accuracy"]["uncompensated"]["new_pose_rms_mm"]
