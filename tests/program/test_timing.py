"""Move times: the trapezoidal profile against a simulated profile, limits and overrides."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.settings import ProgramSettings
from calib_oed.program.timing import JointDynamics


def _distance_covered(v, a, t):
    """Distance a rest-to-rest trapezoid with peak min(v, a t/2) covers in time t (integrated numerically)."""
    peak = min(v, a * t / 2)
    s = np.linspace(0.0, t, 200001)
    speed = np.minimum(np.minimum(a * s, a * (t - s)), peak)
    return np.trapezoid(speed, s)


@pytest.mark.parametrize("delta", [0.01, 0.3, 1.0, 2.5])
def test_joint_time_is_the_profile_that_covers_the_distance(delta):
    dyn = JointDynamics(np.array([2.0]), np.array([4.0]))
    t = float(dyn.joint_times(np.array([delta]))[0])
    assert _distance_covered(2.0, 4.0, t) == pytest.approx(delta, rel=1e-6)
    # and no faster profile within the limits covers it
    assert _distance_covered(2.0, 4.0, 0.99 * t) < delta


def test_move_time_is_the_slowest_joint_symmetric_and_continuous():
    dyn = JointDynamics(np.array([1.0, 3.0]), np.array([2.0, 6.0]))
    q0, q1 = np.array([0.0, 0.0]), np.array([0.4, 2.0])
    t = dyn.move_time(q0, q1)
    assert t == pytest.approx(max(dyn.joint_times(q1 - q0)))
    assert dyn.move_time(q1, q0) == pytest.approx(t)
    brk = 1.0 ** 2 / 2.0  # v^2 / a of joint 0: both branches give 2 v / a there
    lo, hi = dyn.joint_times(np.array([brk - 1e-9, 0.0])), dyn.joint_times(np.array([brk + 1e-9, 0.0]))
    assert lo[0] == pytest.approx(1.0, abs=1e-6) and hi[0] == pytest.approx(1.0, abs=1e-6)
    m = dyn.time_matrix(np.array([q0, q1, [1.0, 1.0]]))
    assert np.allclose(m, m.T) and np.allclose(np.diag(m), 0)
    assert dyn.path_time(np.array([q0, [0.2, 1.0], q1])) >= t  # stopping at a via point costs


def test_limits_from_the_urdf_and_overrides(kr16_scene):
    robot = kr16_scene.robot
    dyn = JointDynamics.from_robot(robot, ProgramSettings())
    assert np.allclose(dyn.velocity, robot.model.velocityLimit)
    assert np.allclose(dyn.acceleration, dyn.velocity / 0.5)
    s = ProgramSettings(velocity_scale=0.5, velocities={"joint_a1": 1.0}, accelerations={"joint_a6": 3.0})
    dyn = JointDynamics.from_robot(robot, s)
    assert dyn.velocity[0] == pytest.approx(0.5) and dyn.acceleration[5] == pytest.approx(3.0)
    with pytest.raises(ProgramError, match="joint_a1"):
        JointDynamics.from_robot(robot, ProgramSettings(velocities={"joint_x": 1.0}))


@pytest.mark.parametrize("q1", [[0.4, 2.0], [0.05, 0.02], [-1.5, 0.3]])
def test_move_fraction_keeps_every_joint_within_its_limits_and_ends_on_time(q1):
    """Synchronised PTP: q(t) = q0 + s(t) Δ; central differences of q(t) stay within v and a,
    the slowest joint reaches them (time-optimal), and s runs 0 -> 1 in exactly T."""
    from calib_oed.program.timing import move_fraction

    dyn = JointDynamics(np.array([1.0, 3.0]), np.array([2.0, 6.0]))
    q0, q1 = np.zeros(2), np.array(q1)
    total, t_acc = dyn.acceleration_phase(q0, q1)
    assert total == pytest.approx(dyn.move_time(q0, q1))
    h = 1e-5
    t = np.linspace(h, total - h, 4001)
    s = move_fraction(t, total, t_acc)
    speed = (move_fraction(t + h, total, t_acc) - move_fraction(t - h, total, t_acc)) / (2 * h)
    accel = (move_fraction(t + h, total, t_acc) - 2 * s + move_fraction(t - h, total, t_acc)) / h**2
    qdot, qddot = np.abs(speed[:, None] * q1), np.abs(accel[:, None] * q1)
    assert move_fraction(np.array([0.0, total]), total, t_acc) == pytest.approx([0.0, 1.0], abs=1e-12)
    assert np.all(np.diff(s) >= 0)
    assert np.all(qdot <= dyn.velocity * (1 + 1e-6))
    kinks = np.min(np.abs(t[:, None] - [t_acc, total - t_acc]), axis=1) > 2 * h  # second differences
    assert np.all(qddot[kinks] <= dyn.acceleration * (1 + 1e-4))
    slow = int(np.argmax(dyn.joint_times(q1 - q0)))
    assert qddot[kinks, slow].max() == pytest.approx(dyn.acceleration[slow], rel=1e-4)
    assert qdot[:, slow].max() == pytest.approx(min(dyn.velocity[slow], dyn.acceleration[slow] * total / 2),
                                                rel=1e-4)
