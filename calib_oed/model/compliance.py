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
evaluated on the **nominal** model (URDF inertias, or link masses given in the
scene instead, or none at all: the payload alone; nominal geometry) at the
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
#: Mass of the reflector nest(s) and stem on the tool during the measurements [kg], at the
#: reflectors' centroid: a 1.5-inch SMR (about 0.17 kg) in a magnetic nest on a short stem. The
#: realistic simulator's default (:mod:`calib_oed.calibration.realistic_defaults`) and the design
#: prior's load (:meth:`calib_oed.measurement.joint_prior.JointErrorPrior.default_for`).
NEST_MASS = 0.3


@dataclass(frozen=True, eq=False)
class Compliance:
    """Joint compliance is modelled, with this payload on the tool.

    Attributes:
        payload_mass: Payload mass [kg] (0: the arm's own weight only).
        payload_com: Payload centre of mass in the tool frame, (3,) [m].
        link_masses: None (default): the arm weighs what the URDF's inertias say.
            Else (n,) [kg], one per joint base to tip: the link moved by joint ``i``
            is a point mass at ``link_coms[i]`` in joint ``i``'s frame, replacing the
            URDF's inertia (for a URDF without inertias); all zeros: the payload alone.
        link_coms: (n, 3) [m], the point masses' positions; None: the joint origins.
    """

    payload_mass: float = 0.0
    payload_com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    link_masses: np.ndarray | None = None
    link_coms: np.ndarray | None = None

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
        if self.link_masses is None:
            if self.link_coms is not None:
                raise ParameterError("link centres of mass need link masses (link_masses)")
            return
        masses = np.array(self.link_masses, dtype=float)
        if masses.ndim != 1 or not np.all(np.isfinite(masses)) or np.any(masses < 0):
            raise ParameterError(f"link masses must be finite numbers >= 0 kg, one per joint, "
                                 f"got {self.link_masses!r}")
        coms = np.zeros((masses.size, 3)) if self.link_coms is None else np.array(self.link_coms, dtype=float)
        if coms.shape != (masses.size, 3):
            raise ShapeError("link centres of mass", f"({masses.size}, 3)", coms.shape)
        if not np.all(np.isfinite(coms)):
            raise NonFiniteError("link centres of mass")
        for arr, name in ((masses, "link_masses"), (coms, "link_coms")):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def arm_weight(self) -> str:
        """Where the arm's own weight comes from: ``"urdf"``, ``"scene"`` or ``"none"`` (payload alone)."""
        if self.link_masses is None:
            return "urdf"
        return "scene" if np.any(self.link_masses > 0) else "none"

    def with_nest(self, mass: float, com) -> Compliance:
        """This load with a point mass ``mass`` [kg] at ``com`` (3,) [m, tool frame] added to the
        payload (one mass at the common centre of mass; the arm's own weight kept)."""
        total = self.payload_mass + float(mass)
        if total <= 0:
            return self
        centre = (self.payload_mass * self.payload_com + float(mass) * np.asarray(com, dtype=float)) / total
        return Compliance(total, centre, self.link_masses, self.link_coms)

    def to_dict(self) -> dict:
        """JSON form (kg, mm): ``mass_kg``, ``com_mm`` and, with link masses, ``link_masses_kg`` and ``link_coms_mm``."""
        out = {"mass_kg": self.payload_mass, "com_mm": (self.payload_com * 1e3).tolist()}
        if self.link_masses is not None:
            out.update(link_masses_kg=self.link_masses.tolist(), link_coms_mm=(self.link_coms * 1e3).tolist())
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Compliance:
        """From :meth:`to_dict`'s form (KeyError, TypeError, ValueError on a malformed mapping)."""
        masses = data.get("link_masses_kg")
        return cls(float(data["mass_kg"]), 1e-3 * np.asarray(data["com_mm"], dtype=float),
                   None if masses is None else np.asarray(masses, dtype=float),
                   None if masses is None else 1e-3 * np.asarray(data["link_coms_mm"], dtype=float))

    def describe(self) -> str:
        """One line for reports (kg, mm)."""
        com = np.round(self.payload_com * 1e3, 1).tolist()
        arm = {"urdf": "", "none": "; the arm's own weight ignored (payload alone)",
               "scene": f"; link masses from the scene, {float(np.sum(self.link_masses)):g} kg in all"
               if self.link_masses is not None else ""}[self.arm_weight]
        return f"joint compliance modelled, payload {self.payload_mass:g} kg at {com} mm in the tool frame{arm}"


class GravityLoad:
    r"""Gravity torques :math:`\tau_g(q) = -g(q)` of the nominal robot with a payload.

    Args:
        model: The nominal Pinocchio model (copied, never mutated).
        tool_frame_id: The tool frame; the payload is rigidly attached to its parent joint.
        compliance: The payload.
    """

    def __init__(self, model: pin.Model, tool_frame_id: int, compliance: Compliance):
        self.load = compliance  # the payload (and link masses) it was made with
        self.model = model.copy()
        frame = self.model.frames[tool_frame_id]
        if compliance.link_masses is not None:
            n = self.model.njoints - 1
            if compliance.link_masses.size != n:
                raise ParameterError(f"link masses: expected {n} (one per joint), got "
                                     f"{compliance.link_masses.size}")
            for i in range(1, n + 1):  # point masses replace the URDF's inertias
                self.model.inertias[i] = pin.Inertia(float(compliance.link_masses[i - 1]),
                                                     np.array(compliance.link_coms[i - 1]), np.zeros((3, 3)))
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
