"""Every derivative of the measurement models and the KPI with joint terms (compliance, gains and
couplings, both) against central differences, and zero terms giving the plain values exactly."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, random_parameters, relative_error
from joint_terms import (
    MODELS,
    REFLECTORS,
    TERMS,
    TOL,
    compare_scaled,
    joint_term,
    scaled_difference,
    tracker,
)

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.measurement import evaluate_setup
from calib_oed.model.parameters import ParameterSpace


@pytest.fixture(scope="module", params=TERMS)
def term(robot, request):
    return joint_term(robot, request.param)


def _per_pose(fun, q):
    """Central differences of fun(q)[k] in pose k's joints, stacked over poses."""
    return np.stack([central_difference(lambda qk, k=k: fun(np.vstack([q[:k], qk, q[k + 1:]]))[k], q[k])
                     for k in range(len(q))])


def _model_at(term, kind: str, n: int, seed: int):
    """A measurement model of ``kind``, ``n`` random configurations and the state at them."""
    q = term.space.robot.random_configurations(n, seed)
    return MODELS[kind](), q, evaluate_setup(term.space, term.p, q)


def _matches_differences(term, analytic, fun, q):
    """``analytic`` (n, d, n_p, ...) against per-pose differences of ``fun``, over every column and
    over the joint terms' columns alone."""
    numeric, scale, added = _per_pose(fun, q), term.space.unit_scale, term.added
    assert compare_scaled(analytic, numeric, scale, axis=2) < TOL
    assert compare_scaled(analytic[:, :, added], numeric[:, :, added], scale[added], axis=2) < TOL


@pytest.mark.parametrize("kind", MODELS)
def test_param_jacobian(term, kind):
    space, p, added = term.space, term.p, term.added
    model, q, state = _model_at(term, kind, 3, 11)
    analytic = model.compute_param_jacobian(state)
    numeric = scaled_difference(lambda x: model.compute_values(evaluate_setup(space, x, q)), space, p)
    assert compare_scaled(analytic, numeric, space.unit_scale) < TOL
    g = space.gain_slice  # the gain columns on their own (the compliance columns' differences are too noisy)
    if g.stop > g.start:
        assert compare_scaled(analytic[:, :, g], numeric[:, :, g], space.unit_scale[g]) < TOL
    assert np.abs(analytic[:, :, added]).max() > 0


@pytest.mark.parametrize("kind", MODELS)
def test_config_jacobian(term, kind):
    space, p = term.space, term.p
    model, q, state = _model_at(term, kind, 3, 12)
    analytic = model.compute_config_jacobian(state)
    assert relative_error(analytic, _per_pose(lambda x: model.compute_values(evaluate_setup(space, p, x)), q)) < TOL
    # the chain dq_eff/dq is far from I here: the rigid formula at q_eff would fail
    chain = state.config_chain
    assert np.abs(chain - np.eye(space.robot.nq)).max() > 1e-3


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_jacobian(term, kind):
    """d2h/dp dq over every column (the design gradient's input) against differences of dh/dp."""
    space, p = term.space, term.p
    model, q, state = _model_at(term, kind, 2, 13)
    analytic = model.compute_param_config_jacobian(state)
    _matches_differences(term, analytic, lambda x: model.compute_param_jacobian(evaluate_setup(space, p, x)), q)


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_hessian(term, kind):
    """d3h/dp dq dq (the design's exact Hessian) against differences of d2h/dp dq; None with compliance."""
    space, p, added = term.space, term.p, term.added
    model, q, state = _model_at(term, kind, 2, 14)
    analytic = model.compute_param_config_hessian(state)
    if space.compliance is not None:
        assert analytic is None
        return
    _matches_differences(term, analytic,
                         lambda x: model.compute_param_config_jacobian(evaluate_setup(space, p, x)), q)
    assert np.abs(analytic[:, :, added]).max() > 0
    np.testing.assert_allclose(analytic, np.swapaxes(analytic, 3, 4), rtol=0, atol=1e-9 * np.abs(analytic).max())


@pytest.mark.parametrize("frame", ["world", "tracker"])
def test_kpi_jacobian(term, frame):
    space, p = term.space, term.p
    q = space.robot.random_configurations(2, 21)
    kpi = TcpKpi(q, point=np.array([0.01, -0.02, 0.1]), frame=frame)
    g = kpi.compute_param_jacobian(space, p)
    numeric = scaled_difference(lambda x: kpi.compute_values(space, x).ravel(), space, p)
    assert compare_scaled(g, numeric, space.unit_scale) < TOL
    assert np.abs(g[:, term.added]).max() > 0


@pytest.mark.parametrize("kind", MODELS)
def test_zero_terms_give_the_plain_values_exactly(term, kind):
    robot, added = term.space.robot, term.added
    plain = ParameterSpace(robot, tracker(), REFLECTORS)
    p = random_parameters(plain, 2, 5e-3, 5e-3)
    q = robot.random_configurations(3, 4)
    model = MODELS[kind]()
    a = evaluate_setup(plain, p, q)
    b = evaluate_setup(term.space, np.concatenate([p, np.zeros(added.stop - added.start)]), q)
    n = plain.size
    np.testing.assert_array_equal(model.compute_values(a), model.compute_values(b))
    np.testing.assert_array_equal(model.compute_param_jacobian(a), model.compute_param_jacobian(b)[:, :, :n])
    np.testing.assert_array_equal(model.compute_config_jacobian(a), model.compute_config_jacobian(b))
    np.testing.assert_array_equal(model.compute_param_config_jacobian(a),
                                  model.compute_param_config_jacobian(b)[:, :, :n])
