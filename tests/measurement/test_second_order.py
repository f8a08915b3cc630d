"""Second configuration derivatives of the measurement rows against differences of the mixed derivative."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, make_space, random_parameters, relative_error

from calib_oed import load_robot
from calib_oed.measurement import PoseMeasurement, TrackerPosition, evaluate_setup
from calib_oed.measurement.second_order import tool_point_param_config_hessian
from calib_oed.model.compliance import Compliance
from calib_oed.model.parameters import ParameterSpace

MODELS = {
    "position": lambda: TrackerPosition(1, sigma=(1e-5, 2e-5, 1.5e-5)),
    "pose": lambda: PoseMeasurement(0, sigma=1e-5, sigma_angle=2e-5),
    "tilted-probe": lambda: PoseMeasurement(1, probe_rotation=pin.exp3(np.array([0.1, 0.2, -0.3]))),
}
TOL = 1e-6
#: Step of the differences [rad]: the rotation rows of poses with |log R_TP| near pi carry
#: rounding (log3 there) that 1e-6 amplifies to ~3e-7; at 1e-4 the truncation is ~2e-9.
EPS = 1e-4


@pytest.fixture(params=["nominal", "perturbed"])
def params(request, space):
    return space.zeros() if request.param == "nominal" else random_parameters(space, 4, 5e-3, 5e-3)


def _along_each_pose(fun, q):
    """Central differences of pose k's fun(q)[k] along q_k, stacked over poses: fun's shape + (nv,)."""
    return np.stack([
        central_difference(lambda qk, k=k: fun(np.vstack([q[:k], qk, q[k + 1:]]))[k], q[k], EPS)
        for k in range(len(q))
    ])


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_hessian(space, params, kind):
    """d3h/dp dq_k dq_l against differences of the exact d2h/dp dq; symmetric in k, l."""
    model = MODELS[kind]()
    q = space.robot.random_configurations(3, 15)
    analytic = model.compute_param_config_hessian(evaluate_setup(space, params, q))
    numeric = _along_each_pose(
        lambda qq: model.compute_param_config_jacobian(evaluate_setup(space, params, qq)), q)
    nv = space.robot.nq
    assert analytic.shape == (3, model.dim, space.size, nv, nv)
    assert relative_error(analytic, numeric) < TOL
    assert np.allclose(analytic, np.swapaxes(analytic, 3, 4), rtol=0, atol=1e-12 * np.abs(analytic).max())


@pytest.mark.parametrize("frame", ["world", "tracker"])
def test_tool_point_hessian_in_both_frames(space, frame):
    """The tool-point helper with a fixed point (no reflector columns) in either frame."""
    p = random_parameters(space, 5, 5e-3, 5e-3)
    q = space.robot.random_configurations(2, 16)
    offset = np.array([0.01, 0.02, 0.12])
    analytic = tool_point_param_config_hessian(evaluate_setup(space, p, q), offset, frame)
    numeric = _along_each_pose(
        lambda qq: evaluate_setup(space, p, qq).tool_point_param_config_jacobian(offset, frame), q)
    assert relative_error(analytic, numeric) < TOL


def test_pose_rotation_near_identity(space):
    """R_TP = I exactly at q0 (probe rotation chosen so): J_log's series has no 0/0 there."""
    q = space.robot.random_configurations(2, 17)
    state = evaluate_setup(space, None, q)
    probe = state.kin.rotation[0].T @ state.tracker.rotation  # R_T^T R R_FP = I at pose 0
    model = PoseMeasurement(0, probe_rotation=probe)
    analytic = model.compute_param_config_hessian(state)
    mixed = model.compute_param_config_jacobian(state)
    assert np.all(np.isfinite(analytic)) and np.all(np.isfinite(mixed))
    numeric = _along_each_pose(
        lambda qq: model.compute_param_config_jacobian(evaluate_setup(space, None, qq)), q)
    assert relative_error(analytic, numeric) < TOL
    numeric_mixed = _along_each_pose(
        lambda qq: model.compute_param_jacobian(evaluate_setup(space, None, qq)), q)
    assert relative_error(mixed, numeric_mixed) < TOL


@pytest.mark.parametrize("kind", MODELS)
def test_no_second_derivative_with_compliance(kind):
    base = make_space(load_robot("ur5"))
    space = ParameterSpace(base.robot, base.tracker_placement(None), base.reflector_offsets(None),
                           compliance=Compliance(10.0, [0.0, 0.0, 0.1]))
    state = evaluate_setup(space, None, space.robot.random_configurations(2, 18))
    assert MODELS[kind]().compute_param_config_hessian(state) is None
    with pytest.raises(ValueError, match="compliance"):
        tool_point_param_config_hessian(state, np.zeros(3), "tracker")
