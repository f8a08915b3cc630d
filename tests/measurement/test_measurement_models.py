"""Measurement models: analytic sensitivities against central finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, random_parameters, relative_error

from calib_oed.exceptions import NonFiniteError, ShapeError
from calib_oed.measurement import PoseMeasurement, TrackerPosition, evaluate_setup
from calib_oed.measurement.sensitivity import weighted_jacobian

MODELS = {
    "position": lambda: TrackerPosition(1, sigma=(1e-5, 2e-5, 1.5e-5)),
    "pose": lambda: PoseMeasurement(0, sigma=1e-5, sigma_angle=2e-5),
}
TOL = 1e-6


@pytest.fixture(params=["nominal", "perturbed"])
def params(request, space):
    return space.zeros() if request.param == "nominal" else random_parameters(space, 4, 5e-3, 5e-3)


@pytest.mark.parametrize("kind", MODELS)
def test_param_jacobian(space, params, kind):
    model = MODELS[kind]()
    q = space.robot.random_configurations(4, 11)
    analytic = model.compute_param_jacobian(evaluate_setup(space, params, q))
    numeric = central_difference(
        lambda p: model.compute_values(evaluate_setup(space, p, q)), params
    )
    assert analytic.shape == (4, model.dim, space.size)
    assert relative_error(analytic, numeric) < TOL


@pytest.mark.parametrize("kind", MODELS)
def test_config_jacobian(space, params, kind):
    model = MODELS[kind]()
    q = space.robot.random_configurations(3, 12)
    analytic = model.compute_config_jacobian(evaluate_setup(space, params, q))
    numeric = np.stack([
        central_difference(lambda qk: model.compute_values(evaluate_setup(space, params, qk))[0],
                           q[k])
        for k in range(len(q))
    ])
    assert relative_error(analytic, numeric) < TOL


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_jacobian(space, params, kind):
    """The mixed derivative d2h/dp dq (rows of dF1/dq) against differences of dh/dp."""
    model = MODELS[kind]()
    q = space.robot.random_configurations(3, 13)
    analytic = model.compute_param_config_jacobian(evaluate_setup(space, params, q))
    numeric = _mixed_differences(model, space, params, q)
    assert analytic.shape == (3, model.dim, space.size, space.robot.nq)
    assert relative_error(analytic, numeric) < TOL


def test_pose_probe_rotation_mixed_derivative(space):
    """A tilted probe exercises every term of the rotation rows (Hlog3, tracker block)."""
    import pinocchio as pin

    model = PoseMeasurement(1, probe_rotation=pin.exp3(np.array([0.1, 0.2, -0.3])))
    p = random_parameters(space, 7, 5e-3, 5e-3)
    q = space.robot.random_configurations(2, 14)
    analytic = model.compute_param_config_jacobian(evaluate_setup(space, p, q))
    assert relative_error(analytic, _mixed_differences(model, space, p, q)) < TOL


def _mixed_differences(model, space, p, q):
    """Central differences of pose k's dh/dp along q_k, stacked over poses: (n, d, n_p, nv)."""
    return np.stack([
        central_difference(
            lambda qk, k=k: model.compute_param_jacobian(
                evaluate_setup(space, p, np.vstack([q[:k], qk, q[k + 1:]]))
            )[k],
            q[k],
        )
        for k in range(len(q))
    ])


def test_position_value_matches_frame_placement(space):
    """h = T_WT^-1 (T_WF c), checked with pinocchio SE3 algebra."""
    import pinocchio as pin

    q = space.robot.random_configurations(2, 5)
    p = random_parameters(space, 6, 1e-3, 1e-3)
    state = evaluate_setup(space, p, q)
    h = TrackerPosition(1).compute_values(state)
    for k in range(2):
        tool = pin.SE3(state.kin.rotation[k], state.kin.translation[k])
        expected = state.tracker.actInv(tool.act(space.reflector_offsets(p)[1]))
        assert np.allclose(h[k], expected, atol=1e-14)


def test_weighted_jacobian_is_stacked_and_scaled(space):
    models = [TrackerPosition(0, 1e-5), TrackerPosition(1, 2e-5)]
    q = space.robot.random_configurations(5, 1)
    f1 = weighted_jacobian(space, models, q)
    state = evaluate_setup(space, None, q)
    expected = np.concatenate([m.compute_param_jacobian(state).reshape(-1, space.size)
                               for m in models]) / np.concatenate([np.tile(m.sigma, 5) for m in models])[:, None]
    assert f1.shape == (2 * 5 * 3, space.size)
    assert np.allclose(f1, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


@pytest.mark.parametrize(
    "q, error",
    [(np.zeros((4, 5)), ShapeError), (np.full((2, 6), np.nan), NonFiniteError)],
)
def test_bad_configurations(q, error):
    from conftest import make_space

    from calib_oed import load_robot

    space = make_space(load_robot("kr16"))
    with pytest.raises(error):
        weighted_jacobian(space, [TrackerPosition(0)], q)


@pytest.mark.parametrize("sigma", [0.0, -1e-5, np.nan])
def test_bad_sigma(sigma):
    with pytest.raises(ValueError, match="sigma"):
        TrackerPosition(0, sigma)
