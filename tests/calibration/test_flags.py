"""Flags against noise + model error: model error of 10x the noise keeps every pose, a 5 mm gross
error is flagged alone, whole-pose and joint-end flags are called model error."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.calibration.flags import classify_flags
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.robust import identify_robust
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.scene.reader import load_scene

#: 0.1 mm per axis: about 10x the scene's noise (tracker model + repeatability, ~0.01 mm per axis)
TRUE = DiscrepancyPrior(1e-4, tuple(np.radians([45, 45, 45, 90, 90, 90])))
#: The same size, much of it each joint's own error once and twice per revolution.
HARMONIC = DiscrepancyPrior(6e-5, TRUE.length_scales, "matern52_harmonic",
                            harmonic=[6e-5, 3e-5] * 3 + [3e-5, 2e-5] * 3)


@pytest.fixture(scope="module")
def fms(kr16_setup):
    return kr16_setup  # the session's fms_kr16 set-up (tests/conftest.py)


def _blocks(problem, seed, n=60, prior=TRUE):
    rng = np.random.default_rng(seed)
    q = problem.robot.random_configurations(n, rng)
    p = draw_true_parameters(problem.space, problem.identifiability.free_indices, rng)
    return simulate_observations(problem.space, problem.models, q, p, rng, model_error=prior)


def _three_reflectors(fms):
    scene = load_scene("fms_kr16")
    offsets = [(0.0, 0.0, 0.05), (0.06, 0.0, 0.04), (0.0, 0.06, 0.04)]
    from calib_oed.model.parameters import ParameterSpace

    space = ParameterSpace(scene.robot, scene.tracker.placement(), np.array(offsets))
    return CalibrationProblem(space, scene.error_model().models(range(3)), fms.problem.kpi)


@pytest.mark.parametrize("truth", [TRUE, pytest.param(HARMONIC, id="harmonic")])
def test_model_error_ten_times_the_noise_drops_no_pose(fms, truth):
    """4 data sets of 60 poses, the fit starting from the scene's prior in the truth's kernel:
    no measurement left out, at most 2 % flagged."""
    d = fms.scene.discrepancy()
    start = DiscrepancyPrior(d.sigma, d.length_scales, truth.kernel_name)
    flagged = total = 0
    for seed in range(4):
        rob = identify_robust(fms.problem.space, _blocks(fms.problem, seed, prior=truth),
                              fms.problem.identifiability, model_error=start)
        assert rob.linear.sigma0 > 4  # the model error dominates the noise, as on real arms
        assert not rob.dropped.any() and rob.result is rob.linear
        flagged += rob.n_flagged
        total += rob.flagged.size
    assert flagged <= 0.02 * total, (flagged, total)


@pytest.mark.parametrize("three", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_one_gross_error_among_60_poses_is_flagged_alone(fms, three):
    problem = _three_reflectors(fms) if three else fms.problem
    blocks = _blocks(problem, 7)
    b = blocks[0]
    values = np.array(b.values)
    values[17, 1] += 5e-3  # 5 mm on tracker y of pose 18, reflector 0
    blocks[0] = ObservationBlock(b.model, b.q, values)
    rob = identify_robust(problem.space, blocks, problem.identifiability,
                          model_error=fms.scene.discrepancy())
    assert np.flatnonzero(rob.flagged).tolist() == [17]
    assert rob.dropped[17] and rob.weight[17] == 0 and rob.classes.findings == ()
    assert rob.model_error.prior.sigma < 2 * TRUE.sigma  # the gross error did not inflate it


def test_whole_poses_and_joint_ends_are_called_model_error():
    names = [f"a{i}" for i in range(1, 4)]
    rng = np.random.default_rng(0)
    q_pose = rng.uniform(-1, 1, (20, 3))
    q_pose[0, 1], q_pose[1, 1], q_pose[2, 1] = 1.0, 0.99, 0.98  # three poses at a2's upper end
    pose = np.repeat(np.arange(20), 3)  # 3 reflectors per pose
    q = q_pose[pose]
    flagged = np.zeros(60, bool)
    flagged[[0, 4, 7]] = True  # one reflector at each of poses 1-3
    flagged[[30, 31, 32]] = True  # every reflector of pose 11
    flagged[50] = True  # an isolated flag
    classes = classify_flags(flagged, pose, q, names)
    assert np.flatnonzero(classes.model_error).tolist() == [0, 4, 7, 30, 31, 32]
    assert np.flatnonzero(classes.gross).tolist() == [50]
    assert any("pose(s) 11" in f for f in classes.findings)
    assert any("upper end of a2" in f and "Remedy" in f for f in classes.findings)
    # the isolated flag within 10 standard deviations of noise + model error: suspect, kept
    t = np.full(60, 30.0)
    assert not classify_flags(flagged, pose, q, names, t).gross.any()
    t[50] = 2500.0  # 5 mm against 0.1 mm
    assert np.flatnonzero(classify_flags(flagged, pose, q, names, t).gross).tolist() == [50]


def test_the_gross_error_probability_quoted_is_that_of_chi2_per_dimension():
    from scipy.stats import chi2

    from calib_oed.calibration import flags

    for d in (3, 6):              # a position, a pose
        assert f"{chi2.sf(flags.GROSS_Z ** 2, d):.2g} for a {'position' if d == 3 else 'pose'}" \
            in " ".join(flags.__doc__.split()), d


def test_a_gross_error_at_a_joint_end_is_no_model_error():
    """A 39-sigma flag and a 5-sigma suspect at the same end of a1 (the realistic UR5, truth 5):
    not a cluster of model error; the gross one is left out, the suspect kept."""
    names = [f"a{i}" for i in range(1, 4)]
    q = np.random.default_rng(1).uniform(-1, 1, (60, 3))
    q[17, 0], q[18, 0] = -1.0, -0.98
    flagged = np.zeros(60, bool)
    flagged[[17, 18]] = True
    t = np.full(60, 4.0)
    t[17], t[18] = 38.7**2, 5.1**2
    classes = classify_flags(flagged, np.arange(60), q, names, t)
    assert np.flatnonzero(classes.gross).tolist() == [17] and not classes.model_error.any()
    assert not any("end of a1" in f for f in classes.findings)
    assert any("1 flagged measurement(s) within 10" in f for f in classes.findings)
    # without the statistic both are model error, as before
    assert classify_flags(flagged, np.arange(60), q, names).model_error[[17, 18]].all()
