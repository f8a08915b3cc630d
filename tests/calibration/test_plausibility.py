"""Plausibility bounds: a warning naming the parameter, its value, the bound and the cause."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from calib_oed import load_robot
from calib_oed.calibration.plausibility import STIFFNESS_PER_REACH3, check_plausibility
from calib_oed.calibration.simulation import draw_true_parameters
from calib_oed.measurement.discrepancy import robot_reach
from calib_oed.model.joint_map import JointGains
from calib_oed.model.parameters import ParameterSpace


def test_the_issues_implausible_values_are_named():
    robot = load_robot("kr300")
    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)))
    k_min = STIFFNESS_PER_REACH3 * robot_reach(robot) ** 3
    names = ["joint4.c", "joint2.gain", "joint2.tz", "joint3.ry", "tracker.tx", "joint2.c", "joint5.gain"]
    values = [1 / 1.05e4, -5e-3, 2e-3, 3e-2, 1.0, 1 / 3e6, 3e-3]
    std = [1e-9, 1e-4, 1e-4, 1e-3, 1e-4, 1e-9, 1e-3]  # joint5.gain: beyond by less than 2 std
    found = {w.name: w for w in check_plausibility(space, names, values, std)}
    assert set(found) == {"joint4 stiffness", "joint2.gain", "joint3.ry"}
    assert found["joint4 stiffness"].value == np.float64(1.05e4) and k_min > 1e5
    assert "absorbing" in found["joint2.gain"].line() and "-0.5 %" in found["joint2.gain"].line()
    assert "mastering" in found["joint3.ry"].cause
    assert check_plausibility(space, ["joint2.c"], [-1e-6], [1e-8])[0].cause.startswith("a negative")


def test_the_simulators_own_gains_are_plausible():
    """Truths drawn by the simulator (gains N(0, 1e-3)) are rarely called implausible: well
    determined gains (std 1e-4) of 2000 truths of a 6-axis arm, Monte Carlo: at most 2 % of the
    truths get a gain warning (3-sigma bound: about 0.6 % expected; a 2-sigma bound gave ~15 %)."""
    robot = load_robot("kr16")
    space = ParameterSpace(robot, pin.SE3.Identity(), np.zeros((1, 3)), joint_gains=JointGains.all_joints(6))
    gains = np.arange(space.gain_slice.start, space.gain_slice.stop)
    names = [space.names[i] for i in gains]
    rng = np.random.default_rng(29)
    flagged = sum(bool(check_plausibility(space, names, draw_true_parameters(space, gains, rng)[gains],
                                          np.full(gains.size, 1e-4)))
                  for _ in range(2000))
    assert flagged / 2000 <= 0.02
