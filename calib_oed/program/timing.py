r"""Travel time of a point-to-point joint move from velocity and acceleration limits.

A PTP move from :math:`q_0` to :math:`q_1` drives every joint with a trapezoidal
velocity profile (rest to rest) and synchronises them, so it takes as long as
its slowest joint. Joint :math:`i` with distance :math:`\Delta_i = |q_{1,i} - q_{0,i}|`
[rad], velocity limit :math:`v_i` [rad/s] and acceleration limit :math:`a_i`
[rad/s²] needs

.. math::
    t_i(\Delta_i) = \begin{cases}
      2\sqrt{\Delta_i / a_i} & \Delta_i \le v_i^2 / a_i \quad\text{(triangle: never at full speed)} \\
      \Delta_i / v_i + v_i / a_i & \text{otherwise (trapezoid)}
    \end{cases}
    \qquad T(q_0, q_1) = \max_i t_i(\Delta_i) \;[\mathrm{s}].

The two branches meet at :math:`\Delta_i = v_i^2/a_i` (both :math:`2 v_i / a_i`),
so :math:`T` is continuous, monotone in every :math:`\Delta_i` and symmetric in
:math:`q_0, q_1`. A path through via points stops at each (fine positioning),
so its time is the sum of its moves' times: an upper bound on what a
controller with blending does.

The velocity limits are the URDF's ``<limit velocity>`` (Pinocchio's
``model.velocityLimit``) times ``velocity_scale``, or the scene's
``program.velocities``; the acceleration limits are the scene's
``program.accelerations``, else :math:`a_i = v_i / t_{acc}` with
``acceleration_time`` :math:`t_{acc}` = 0.5 s (URDFs carry no acceleration limits).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.model.robot import Robot
from calib_oed.program.settings import ProgramSettings


@dataclass(frozen=True, eq=False)
class JointDynamics:
    """Per-joint limits of the move timing.

    Attributes:
        velocity: :math:`v_i` [rad/s], (nq,).
        acceleration: :math:`a_i` [rad/s²], (nq,).
    """

    velocity: np.ndarray
    acceleration: np.ndarray

    @classmethod
    def from_robot(cls, robot: Robot, settings: ProgramSettings) -> JointDynamics:
        """The robot's URDF velocity limits, with the settings' overrides and default accelerations."""
        names = list(robot.joint_names)
        v = np.array(robot.model.velocityLimit, dtype=float)[: len(names)].copy()
        for joint, value in settings.velocities.items():
            v[_index(names, joint, "velocities")] = value
        missing = [n for n, x in zip(names, v, strict=True) if not (np.isfinite(x) and x > 0)]
        if missing:
            raise ProgramError("velocities", missing, "the URDF gives no velocity limit > 0 for "
                               "these joints: set them in the scene's program.velocities")
        v = v * settings.velocity_scale
        a = v / settings.acceleration_time
        for joint, value in settings.accelerations.items():
            a[_index(names, joint, "accelerations")] = value
        return cls(v, a)

    def joint_times(self, delta: np.ndarray) -> np.ndarray:
        """:math:`t_i(\\Delta_i)` [s] for joint distances ``delta`` (..., nq) [rad]."""
        d = np.abs(np.asarray(delta, dtype=float))
        v, a = self.velocity, self.acceleration
        return np.where(d <= v * v / a, 2.0 * np.sqrt(d / a), d / v + v / a)

    def move_time(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """:math:`T(q_0, q_1)` [s]; broadcasts over leading axes of (..., nq) arrays."""
        return self.joint_times(np.asarray(q1, float) - np.asarray(q0, float)).max(axis=-1)

    def time_matrix(self, q: np.ndarray) -> np.ndarray:
        """All pairwise move times [s] between configurations ``q`` (n, nq): (n, n), symmetric."""
        q = np.asarray(q, dtype=float)
        return self.move_time(q[:, None, :], q[None, :, :])

    def acceleration_phase(self, q0: np.ndarray, q1: np.ndarray) -> tuple[float, float]:
        r"""``(T, t_a)`` [s] of the move ``q0 -> q1``: its time and the length of its acceleration
        (and deceleration) phase, those of its slowest joint, :math:`t_a = \min(v_i/a_i, T/2)`."""
        t = self.joint_times(np.asarray(q1, float) - np.asarray(q0, float))
        i = int(np.argmax(t))
        total = float(t[i])
        return total, min(float(self.velocity[i] / self.acceleration[i]), 0.5 * total)

    def path_time(self, waypoints: np.ndarray) -> float:
        """Time [s] of a path through ``waypoints`` (k, nq), stopping at each."""
        w = np.asarray(waypoints, dtype=float)
        return float(self.move_time(w[:-1], w[1:]).sum()) if len(w) > 1 else 0.0


def move_fraction(t: np.ndarray, total: float, t_acc: float) -> np.ndarray:
    r"""How far along a synchronised PTP move the joints are at times ``t`` [s], in [0, 1].

    Every joint follows its slowest joint's rest-to-rest trapezoid scaled to its own
    distance, so :math:`q(t) = q_0 + s(t)(q_1 - q_0)` on the straight joint-space segment
    (the one the continuous check certifies), with :math:`T` = ``total``,
    :math:`t_a` = ``t_acc`` (:math:`t_a = T/2`: a triangle):

    .. math::
        s(t) = \begin{cases} t^2 / (2 t_a (T - t_a)) & t \le t_a \\
        (t - t_a/2) / (T - t_a) & t_a < t \le T - t_a \\
        1 - (T - t)^2 / (2 t_a (T - t_a)) & T - t_a < t \end{cases}
    """
    t = np.clip(np.asarray(t, dtype=float), 0.0, total)
    if total <= 0.0:
        return np.ones_like(t)
    ta = min(max(t_acc, 1e-12), 0.5 * total)
    k = 1.0 / (2.0 * ta * (total - ta))
    return np.where(t <= ta, k * t * t, np.where(t <= total - ta, (t - 0.5 * ta) / (total - ta),
                                                 1.0 - k * (total - t) ** 2))


def _index(names: list[str], joint: str, what: str) -> int:
    if joint not in names:
        raise ProgramError(f"{what}.{joint}", joint, "unknown joint", names)
    return names.index(joint)
