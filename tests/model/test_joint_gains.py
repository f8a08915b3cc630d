"""Joint gains and coupling ratios: layout, every derivative against central differences, the gauge."""

from __future__ import annotations

import numpy as np
import pytest
from joint_terms import GAINS, REFLECTORS, tracker

from calib_oed.exceptions import ParameterError
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.second_order import tool_point_param_config_hessian
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.model.compliance import Compliance
from calib_oed.model.identifiability import select_gauge
from calib_oed.model.joint_map import JointGains
from calib_oed.model.parameters import Group, ParameterSpace


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
