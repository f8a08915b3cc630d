"""Joint gains and coupling ratios: layout, every derivative against central differences, the gauge."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, relative_error
from joint_terms import MODELS, REFLECTORS, TOL, compare_scaled, scaled_difference, tracker

from calib_oed.calibration.kpi import TcpKpi
from calib_oed.exceptions import ParameterError
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.second_order import tool_point_param_config_hessian
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.model.compliance import Compliance
from calib_oed.model.identifiability import select_gauge
from calib_oed.model.joint_map import JointGains, controller_ratio_error
from calib_oed.model.parameters import Group, ParameterSpace

GAINS = JointGains((1, 2, 3, 5), ((3, 2), (1, 4)))


@pytest.fixture(scope="module", params=["gains", "gains+compliance"])
def gspace(robot, request):
    comp = Compliance(8.0, [0.0, 0.02, 0.1]) if "compliance" in request.param else None
    return ParameterSpace(robot, tracker(), REFLECTORS, compliance=comp, joint_gains=GAINS)


@pytest.fixture(scope="module")
def gparams(gspace):
    """Geometric errors of 5 mm / 5 mrad, gains and couplings of 2 % (large: every term shows)."""
    p = gspace.random(4, 5e-3, 5e-3, sigma_gain=2e-2)
    if gspace.compliance is not None:
        q = gspace.robot.random_configurations(50, 0)
        tau = np.abs(gspace.gravity.torques(q)).max(axis=0)
        p[gspace.compliance_slice] = 0.01 / np.maximum(tau, 1.0)
    return p


def test_layout_appends_gains_then_couplings(robot):
    rigid = ParameterSpace(robot, tracker(), REFLECTORS)
    comp = ParameterSpace(robot, tracker(), REFLECTORS, compliance=Compliance())
    both = ParameterSpace(robot, tracker(), REFLECTORS, compliance=Compliance(), joint_gains=GAINS)
    assert both.names[: comp.size] == comp.names and both.size == comp.size + 6
    assert both.names[comp.size:] == ("joint1.gain", "joint2.gain", "joint3.gain", "joint5.gain",
                                      "joint3.coupling2", "joint1.coupling4")
    assert both.compliance_slice == comp.compliance_slice and both.gain_slice == slice(comp.size, both.size)
    assert rigid.gain_slice == slice(rigid.size, rigid.size) and rigid.gain_basis is None
    gain = both.parameters[both.index("joint2.gain")]
    assert gain.group == Group.GAIN and gain.unit == "rad/rad" and gain.report_unit == "mrad/rad"
    assert gain.report_scale == 1e-3
    assert both.parameters[both.index("joint3.coupling2")].group == Group.COUPLING
    # without gains the random draw is the one of the plain space (existing results unchanged)
    np.testing.assert_array_equal(ParameterSpace(robot, tracker(), REFLECTORS).random(3), rigid.random(3))


def test_joint_gains_errors(robot):
    with pytest.raises(ParameterError, match=f"out of range.*joints 1..{robot.nq}"):
        ParameterSpace(robot, tracker(), REFLECTORS, joint_gains=JointGains((1, robot.nq + 1)))
    with pytest.raises(ParameterError, match="two different joints"):
        JointGains((), ((2, 2),))
    with pytest.raises(ParameterError, match="at least one"):
        JointGains()
    with pytest.raises(TypeError, match="JointGains"):
        ParameterSpace(robot, tracker(), REFLECTORS, joint_gains=(1, 2))


def test_effective_configuration_is_the_gain_law(robot):
    space = ParameterSpace(robot, tracker(), REFLECTORS, joint_gains=GAINS)
    p = space.zeros()
    p[space.index("joint2.gain")] = 1e-3
    p[space.index("joint3.coupling2")] = 0.5
    q = robot.random_configurations(3, 2)
    qe = evaluate_setup(space, p, q, regressor=False, jacobian=False).kin.q
    expected = q.copy()
    expected[:, 1] *= 1.001
    expected[:, 2] += 0.5 * q[:, 1]
    np.testing.assert_allclose(qe, expected, rtol=0, atol=1e-15)
    assert controller_ratio_error(0.5, -1.0, 2.0) == -1.0


@pytest.mark.parametrize("kind", MODELS)
def test_param_jacobian(gspace, gparams, kind):
    model = MODELS[kind]()
    q = gspace.robot.random_configurations(3, 11)
    analytic = model.compute_param_jacobian(evaluate_setup(gspace, gparams, q))
    numeric = scaled_difference(lambda p: model.compute_values(evaluate_setup(gspace, p, q)),
                                 gspace, gparams)
    assert compare_scaled(analytic, numeric, gspace.unit_scale) < TOL
    g = gspace.gain_slice
    assert compare_scaled(analytic[:, :, g], numeric[:, :, g], gspace.unit_scale[g]) < TOL
    assert np.abs(analytic[:, :, g]).min(axis=(0, 1)).max() > 0


@pytest.mark.parametrize("kind", MODELS)
def test_config_jacobian(gspace, gparams, kind):
    model = MODELS[kind]()
    q = gspace.robot.random_configurations(3, 12)
    analytic = model.compute_config_jacobian(evaluate_setup(gspace, gparams, q))
    numeric = np.stack([
        central_difference(lambda qk: model.compute_values(evaluate_setup(gspace, gparams, qk))[0], q[k])
        for k in range(len(q))
    ])
    assert relative_error(analytic, numeric) < TOL


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_jacobian(gspace, gparams, kind):
    """d2h/dp dq over every column (the design gradient's input) against differences of dh/dp."""
    model = MODELS[kind]()
    q = gspace.robot.random_configurations(2, 13)
    analytic = model.compute_param_config_jacobian(evaluate_setup(gspace, gparams, q))
    numeric = np.stack([
        central_difference(
            lambda qk, k=k: model.compute_param_jacobian(
                evaluate_setup(gspace, gparams, np.vstack([q[:k], qk, q[k + 1:]])))[k],
            q[k])
        for k in range(len(q))
    ])
    assert compare_scaled(analytic, numeric, gspace.unit_scale, axis=2) < TOL
    g = gspace.gain_slice
    assert compare_scaled(analytic[:, :, g], numeric[:, :, g], gspace.unit_scale[g], axis=2) < TOL


@pytest.mark.parametrize("frame", ["world", "tracker"])
def test_kpi_jacobian(gspace, gparams, frame):
    q = gspace.robot.random_configurations(2, 21)
    kpi = TcpKpi(q, point=np.array([0.01, -0.02, 0.1]), frame=frame)
    g = kpi.compute_param_jacobian(gspace, gparams)
    numeric = scaled_difference(lambda x: kpi.compute_values(gspace, x).ravel(), gspace, gparams)
    assert compare_scaled(g, numeric, gspace.unit_scale) < TOL
    assert np.abs(g[:, gspace.gain_slice]).max() > 0


@pytest.mark.parametrize("kind", MODELS)
def test_zero_gains_give_the_plain_values_exactly(robot, kind):
    plain = ParameterSpace(robot, tracker(), REFLECTORS)
    space = ParameterSpace(robot, tracker(), REFLECTORS, joint_gains=GAINS)
    p = plain.random(2, 5e-3, 5e-3)
    pg = np.concatenate([p, np.zeros(GAINS.size)])
    q = robot.random_configurations(3, 4)
    model = MODELS[kind]()
    a, b = evaluate_setup(plain, p, q), evaluate_setup(space, pg, q)
    n = plain.size
    np.testing.assert_array_equal(model.compute_values(a), model.compute_values(b))
    np.testing.assert_array_equal(model.compute_param_jacobian(a), model.compute_param_jacobian(b)[:, :, :n])
    np.testing.assert_array_equal(model.compute_config_jacobian(a), model.compute_config_jacobian(b))
    np.testing.assert_array_equal(model.compute_param_config_jacobian(a),
                                  model.compute_param_config_jacobian(b)[:, :, :n])


@pytest.mark.parametrize("kind", MODELS)
def test_param_config_hessian(gspace, gparams, kind):
    """d3h/dp dq dq (the design's exact Hessian) against differences of d2h/dp dq; None with compliance."""
    model = MODELS[kind]()
    q = gspace.robot.random_configurations(2, 14)
    analytic = model.compute_param_config_hessian(evaluate_setup(gspace, gparams, q))
    if gspace.compliance is not None:
        assert analytic is None
        return
    numeric = np.stack([
        central_difference(
            lambda qk, k=k: model.compute_param_config_jacobian(
                evaluate_setup(gspace, gparams, np.vstack([q[:k], qk, q[k + 1:]])))[k],
            q[k])
        for k in range(len(q))
    ])
    assert compare_scaled(analytic, numeric, gspace.unit_scale, axis=2) < TOL
    g = gspace.gain_slice
    assert compare_scaled(analytic[:, :, g], numeric[:, :, g], gspace.unit_scale[g], axis=2) < TOL
    assert np.abs(analytic[:, :, g]).max() > 0
    np.testing.assert_allclose(analytic, np.swapaxes(analytic, 3, 4), rtol=0, atol=1e-9 * np.abs(analytic).max())


def test_rigid_second_order_refuses_a_state_with_gains(robot):
    space = ParameterSpace(robot, tracker(), REFLECTORS, joint_gains=GAINS)
    state = evaluate_setup(space, None, robot.random_configurations(2, 1))
    assert not state.rigid
    with pytest.raises(ValueError, match="joint gains"):
        tool_point_param_config_hessian(state, REFLECTORS[0], "tracker", reflector=0)


def test_gauge_fixes_a_gain_the_data_cannot_separate_from_the_offset(robot):
    """A gain is a moment arm q_i on the joint's own motion: with q_i constant it is an offset."""
    space = ParameterSpace(robot, tracker(), REFLECTORS[:1], joint_gains=JointGains.all_joints(robot.nq))
    models = [TrackerPosition(0)]
    q = robot.random_configurations(60, 3)
    spread = select_gauge(weighted_jacobian(space, models, q) * space.unit_scale, space.names)
    q[:, 1] = q[0, 1]  # joint 2 held still
    still = select_gauge(weighted_jacobian(space, models, q) * space.unit_scale, space.names)
    assert "joint2.gain" in spread.free_names
    fixed = {f.name: f for f in still.fixed}
    assert "joint2.gain" in fixed and fixed["joint2.gain"].redundant_with
    # the other gains keep their status (joint 2's own placement merges with joint 3's, too)
    gains = {n for n in space.names if n.endswith(".gain")}
    assert (set(spread.free_names) - set(still.free_names)) & gains == {"joint2.gain"}
