r"""Joint compliance: the deflection of each joint under gravity (optional parameters).

With compliance modelled, every joint ``i`` has one more parameter, its
compliance :math:`c_i = 1/k_i` [rad/(N·m)] (prismatic joints [m/N]), nominal 0
(rigid). Under the static gravity load the link side of joint ``i`` lags the
commanded angle by the spring deflection, so the kinematics run at

.. math::
    q_{eff} = q + c \circ \tau_g(q), \qquad \tau_g(q) = -g(q),

with :math:`g(q)` Pinocchio's generalized gravity
(``pin.computeGeneralizedGravity``, the torque the motors hold) and
:math:`\tau_g` the torque gravity exerts on each joint. :math:`\tau_g` is
evaluated on the **nominal** model (URDF inertias, nominal geometry) at the
**commanded** :math:`q`, with the payload added to the link that carries the
tool frame; the geometric parameters and the deflection itself do not change
it (their effect on the torque is second order: a 1 mm or 1 mrad error changes
:math:`\tau_g` by well under 1 %). The same payload is on the arm during the
measurements and at the working configurations.

A deflection :math:`\delta q_i` of a 1-DoF joint about (along) its motion
axis :math:`S_i` commutes with the joint motion, so it is the right
perturbation :math:`\epsilon_i = S_i\,\delta q_i` of the joint placement:
:math:`\partial h/\partial c_i = (\partial h/\partial\epsilon_i)\,S_i\,\tau_i`.
``docs/derivations.md`` (joint compliance) has the configuration and mixed
derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import NonFiniteError, ParameterError, ShapeError

#: Joint stiffness range [N·m/rad] of the simulated true robots: log-uniform,
#: about that of a heavy industrial arm's main axes (1e6..1e7 N·m/rad, i.e.
#: compliance 0.1..1 mrad/(kN·m)).
STIFFNESS_RANGE = (1e6, 1e7)


@dataclass(frozen=True, eq=False)
class Compliance:
    """Joint compliance is modelled, with this payload on the tool.

    Attributes:
        payload_mass: Payload mass [kg] (0: the arm's own weight only).
        payload_com: Payload centre of mass in the tool frame, (3,) [m].
    """

    payload_mass: float = 0.0
    payload_com: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        mass = float(self.payload_mass)
        if not np.isfinite(mass) or mass < 0:
            raise ParameterError(f"payload mass must be a finite number >= 0 kg, got {self.payload_mass!r}")
        com = np.array(self.payload_com, dtype=float)
        if com.shape != (3,):
            raise ShapeError("payload centre of mass", "(3,)", com.shape)
        if not np.all(np.isfinite(com)):
            raise NonFiniteError("payload centre of mass")
        com.setflags(write=False)
        object.__setattr__(self, "payload_mass", mass)
        object.__setattr__(self, "payload_com", com)

    def describe(self) -> str:
        """One line for reports (kg, mm)."""
        com = np.round(self.payload_com * 1e3, 1).tolist()
        return f"joint compliance modelled, payload {self.payload_mass:g} kg at {com} mm in the tool frame"


class GravityLoad:
    r"""Gravity torques :math:`\tau_g(q) = -g(q)` of the nominal robot with a payload.

    Args:
        model: The nominal Pinocchio model (copied, never mutated).
        tool_frame_id: The tool frame; the payload is rigidly attached to its parent joint.
        compliance: The payload.
    """

    def __init__(self, model: pin.Model, tool_frame_id: int, compliance: Compliance):
        self.model = model.copy()
        frame = self.model.frames[tool_frame_id]
        if compliance.payload_mass > 0:
            payload = pin.Inertia(compliance.payload_mass, np.array(compliance.payload_com),
                                  np.zeros((3, 3)))
            joint = frame.parentJoint
            self.model.inertias[joint] = self.model.inertias[joint] + frame.placement.act(payload)
        self.data = self.model.createData()
        # Motion axis S_i of every joint (constant in the joint frame for 1-DoF joints).
        pin.forwardKinematics(self.model, self.data, pin.neutral(self.model))
        self.axes = np.array([np.asarray(self.data.joints[i].S).reshape(6)
                              for i in range(1, self.model.njoints)])
        self.axes.setflags(write=False)

    def torques(self, q: np.ndarray) -> np.ndarray:
        r""":math:`\tau_g` at every row of ``q`` (n, nq), (n, nv) [N·m]."""
        return np.array([-pin.computeGeneralizedGravity(self.model, self.data, qk) for qk in q])

    def torque_derivatives(self, q: np.ndarray) -> np.ndarray:
        r""":math:`\partial\tau_g/\partial q` at every row of ``q``, (n, nv, nv) [N·m/rad]."""
        return np.array([-np.asarray(pin.computeGeneralizedGravityDerivatives(self.model, self.data, qk))
                         for qk in q])


def draw_compliance(rng: np.random.Generator, size: int,
                    stiffness_range: tuple[float, float] = STIFFNESS_RANGE) -> np.ndarray:
    """Compliances 1/k with k log-uniform in ``stiffness_range`` [N·m/rad], (size,) [rad/(N·m)]."""
    lo, hi = np.log(stiffness_range[0]), np.log(stiffness_range[1])
    return 1.0 / np.exp(rng.uniform(lo, hi, size=size))
