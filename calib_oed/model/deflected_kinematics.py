r"""The TCP kinematics of an arm whose joints deflect: compliance under gravity and joint gains.

A calibration that identifies joint compliance (:mod:`calib_oed.model.compliance`) or
joint gains and coupling ratios (:mod:`calib_oed.model.joint_map`) says that at the
commanded joints :math:`q` [rad] the links stand at

.. math::
    q_{eff}(q) = q + c\circ\tau_g(q) + \sum_m \theta_m E_m q,

:math:`c` the compliances [rad/(N·m)], :math:`\tau_g(q) = -g(q)` the gravity torque of
the nominal arm with the payload at the commanded :math:`q` [N·m]
(:class:`~calib_oed.model.compliance.GravityLoad`, the convention the identification
used: :func:`calib_oed.measurement.base.evaluate_setup`), :math:`\theta_m` the gains and
ratios [1]. The TCP frame is then :math:`T_{W,E}(q_{eff}(q))` on the calibrated joint
placements, and its frame Jacobian along the commanded joints is

.. math::
    {}^{E}J_E^{def}(q) = {}^{E}J_E(q_{eff})\,D(q), \qquad
    D = \partial q_{eff}/\partial q = I + \mathrm{diag}(c)\,\partial\tau_g/\partial q + \sum_m\theta_m E_m,

with :math:`\partial\tau_g/\partial q` from ``pin.computeGeneralizedGravityDerivatives``.
:class:`DeflectedTcpKinematics` is :class:`~calib_oed.model.inverse_kinematics.TcpKinematics`
with these two, so its inverse kinematics (the same damped Gauss-Newton) solves
:math:`T_{W,E}(q_{eff}(q)) = T^\star` for the **commanded** joints.

**Payload.** :math:`\tau_g` is that of the payload the deflection is built with: by default
the one the compliances were identified under (the parameter space's); a program run with
another payload on the tool gives it to :meth:`JointDeflection.from_space` (``payload``); the
arm's own weight stays as identified.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ShapeError
from calib_oed.model.compliance import Compliance, GravityLoad
from calib_oed.model.inverse_kinematics import TcpKinematics
from calib_oed.model.joint_map import config_chain_term
from calib_oed.model.parameters import ParameterSpace
from calib_oed.model.robot import Robot


@dataclass(frozen=True, eq=False)
class JointDeflection:
    r"""The map :math:`q \mapsto q_{eff}` of the module docstring.

    Attributes:
        gravity: The gravity load (nominal arm and payload), or None without compliance.
        compliance: :math:`c` (nq,) [rad/(N·m); m/N prismatic], or None.
        gain_basis: :math:`E_m` (n_gains, nq, nq) of :mod:`calib_oed.model.joint_map`, or None.
        gains: :math:`\theta_m` (n_gains,) [1], or None.
        payload: One line naming the payload :math:`\tau_g` is computed with (reports).
    """

    gravity: GravityLoad | None = None
    compliance: np.ndarray | None = None
    gain_basis: np.ndarray | None = None
    gains: np.ndarray | None = None
    payload: str = "none"

    def __post_init__(self):
        if (self.gravity is None) != (self.compliance is None):
            raise ValueError("a joint deflection needs both the gravity load and the compliances, or neither")
        if (self.gain_basis is None) != (self.gains is None):
            raise ValueError("a joint deflection needs both the gain basis and the gains, or neither")
        # sum_m theta_m E_m once (the map is linear in q); the gravity model's own data for one row
        gain = None if self.gains is None else config_chain_term(self.gain_basis, self.gains)
        object.__setattr__(self, "_gain", gain)
        object.__setattr__(self, "_chain", None if gain is None else np.eye(gain.shape[0]) + gain)   # I + gains
        object.__setattr__(self, "_data", None if self.gravity is None else self.gravity.model.createData())

    @classmethod
    def from_space(cls, space: ParameterSpace, p: np.ndarray,
                   payload: Compliance | None = None) -> JointDeflection | None:
        r"""The deflection of the parameters ``p`` of ``space``; None if ``space`` has neither
        compliance nor gains (a rigid arm: :math:`q_{eff} = q`).

        Args:
            payload: A :class:`~calib_oed.model.compliance.Compliance` whose payload (mass and
                centre of mass in the tool frame) the program runs with; None: the space's (the
                payload the compliances were identified under). The arm's own weight is the space's.
        """
        p = space.check(p)
        if space.compliance is None and space.gain_basis is None:
            return None
        gravity = c = None
        text = "none (no compliance modelled)"
        if space.compliance is not None:
            load = space.compliance if payload is None else dataclasses.replace(
                space.compliance, payload_mass=payload.payload_mass, payload_com=payload.payload_com)
            gravity = space.gravity if payload is None else GravityLoad(space.robot.model,
                                                                        space.robot.tool_frame_id, load)
            c = np.array(p[space.compliance_slice])
            com = np.round(1e3 * np.asarray(load.payload_com), 1).tolist()
            text = f"{load.payload_mass:g} kg at {com} mm in the tool frame"
        gains = None if space.gain_basis is None else np.array(p[space.gain_slice])
        return cls(gravity, c, space.gain_basis, gains, text)

    def compute_effective_one(self, q: np.ndarray) -> np.ndarray:
        r""":math:`q_{eff}` of one configuration (nq,) (the inverse kinematics' call)."""
        out = q.copy()
        if self.compliance is not None:
            out -= self.compliance * pin.computeGeneralizedGravity(self.gravity.model, self._data, q)
        if self._gain is not None:
            out += self._gain @ q
        return out

    def compute_chain_one(self, q: np.ndarray) -> np.ndarray:
        r""":math:`D` of one configuration (nq, nq): :math:`I + \mathrm{diag}(c)\,\partial\tau_g/\partial q + \sum_m\theta_m E_m`."""
        chain = np.eye(q.shape[0]) if self._chain is None else self._chain.copy()
        if self.compliance is not None:
            chain -= self.compliance[:, None] * pin.computeGeneralizedGravityDerivatives(
                self.gravity.model, self._data, q)
        return chain


class DeflectedTcpKinematics(TcpKinematics):
    r""":class:`~calib_oed.model.inverse_kinematics.TcpKinematics` of the commanded joints of an arm
    that deflects: pose :math:`T_{W,E}(q_{eff}(q))` and Jacobian :math:`{}^{E}J_E(q_{eff})\,D(q)`
    (module docstring), so :meth:`solve` and :func:`~calib_oed.model.inverse_kinematics.solve_ik`
    return commanded joints.

    Args:
        robot: The arm with the calibrated joint placements.
        deflection: Its joint deflection.
        tool, length: As :class:`~calib_oed.model.inverse_kinematics.TcpKinematics`.
    """

    def __init__(self, robot: Robot, deflection: JointDeflection, tool: pin.SE3 | None = None,
                 length: float | None = None):
        super().__init__(robot, tool, length)
        self.deflection = deflection

    def _check(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.model.nq,):
            raise ShapeError("q", f"({self.model.nq},)", q.shape)
        return q

    def compute_pose(self, q: np.ndarray) -> pin.SE3:
        """:math:`T_{W,E}(q_{eff}(q))` of one commanded configuration (nq,)."""
        return super().compute_pose(self.deflection.compute_effective_one(self._check(q)))

    def compute_jacobian(self, q: np.ndarray) -> tuple[pin.SE3, np.ndarray]:
        """:math:`T_{W,E}(q_{eff})` and :math:`{}^{E}J_E(q_{eff})\\,D(q)` (6, nq), along the commanded joints."""
        q = self._check(q)
        pose, jac = super().compute_jacobian(self.deflection.compute_effective_one(q))
        return pose, jac @ self.deflection.compute_chain_one(q)


__all__ = ["DeflectedTcpKinematics", "JointDeflection"]
