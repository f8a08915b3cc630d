r"""The calibration parameters: perturbation frames of the sensor and the joints.

Order (binding, see ``docs/conventions.md``):

1. tracker pose, 6 parameters ``tracker.tx .. tracker.rz``:
   :math:`T_{W,T}(\delta_T) = T^0_{W,T} \exp_6(\delta_T)`;
2. one offset per reflector, 3 parameters each ``reflector{j}.x .. .z`` [m],
   in the tool frame: :math:`c_j = c^0_j + \delta c_j`;
3. for every joint :math:`i = 1..n` from base to tip, 6 parameters
   ``joint{i}.tx .. joint{i}.rz``: the joint placement in its parent
   :math:`M_i \leftarrow M_i \exp_6(\delta_i)`,
   :math:`\delta_i = (t_x, t_y, t_z, r_x, r_y, r_z)` in joint ``i``'s frame
   ([m] then [rad]);
4. only when joint compliance is modelled (:mod:`calib_oed.model.compliance`), one
   compliance per joint ``joint{i}.c`` [rad/(N·m)] ([m/N] for a prismatic
   joint), base to tip: the kinematics run at :math:`q + c \circ \tau_g(q)`;
5. only when joint gains are identified (:mod:`calib_oed.model.joint_map`), one gain
   ``joint{i}.gain`` per chosen joint, then one ratio ``joint{j}.coupling{f}`` per
   coupling [rad/rad] ([m/m] for a prismatic joint): the kinematics run at
   :math:`q_{eff} = q + \sum_m \theta_m E_m q` (plus the compliance deflection).

The nominal value of every parameter is 0. Applying a parameter vector never
mutates the nominal model.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import NonFiniteError, ShapeError, UnknownParameterError
from calib_oed.model.compliance import Compliance, GravityLoad
from calib_oed.model.joint_map import JointGains
from calib_oed.model.robot import Robot, joint_kind

_TWIST = ("tx", "ty", "tz", "rx", "ry", "rz")
_XYZ = ("x", "y", "z")

#: Scale of one unit in reports and in the "unit-scaled" Jacobian: 1 mm, 1 mrad.
LENGTH_SCALE = 1e-3
ANGLE_SCALE = 1e-3
#: Scale of one compliance unit: 1e-6 rad/(N·m) = 1 mrad/(kN·m) (1e-6 m/N = 1 mm/kN).
COMPLIANCE_SCALE = 1e-6

#: Scale of one gain or coupling-ratio unit: 1e-3 (1 mrad per rad of joint motion).
GAIN_SCALE = 1e-3

#: SI unit of a parameter -> (SI value of one report unit, report unit).
REPORT_UNITS = {
    "m": (LENGTH_SCALE, "mm"),
    "rad": (ANGLE_SCALE, "mrad"),
    "rad/(N*m)": (COMPLIANCE_SCALE, "mrad/kNm"),
    "m/N": (COMPLIANCE_SCALE, "mm/kN"),
    "rad/rad": (GAIN_SCALE, "mrad/rad"),
    "m/m": (GAIN_SCALE, "mm/m"),
    "rad/m": (GAIN_SCALE, "mrad/m"),
    "m/rad": (GAIN_SCALE, "mm/rad"),
}


def report_scale_of(unit: str) -> float:
    """SI value of one report unit of a parameter in SI ``unit`` (see :data:`REPORT_UNITS`)."""
    return REPORT_UNITS[unit][0]


def report_unit_of(unit: str) -> str:
    """Report unit of a parameter in SI ``unit``: ``"mm"``, ``"mrad"``, ``"mrad/kNm"``, ``"mm/kN"``."""
    return REPORT_UNITS[unit][1]


class InReportUnits:
    """Mixin of a record with an SI ``unit``: its report unit and that unit's SI value."""

    unit: str

    @property
    def report_scale(self) -> float:
        """SI value of one report unit (1 mm, 1 mrad, 1 mrad/(kN·m))."""
        return report_scale_of(self.unit)

    @property
    def report_unit(self) -> str:
        """Unit used in reports: ``"mm"``, ``"mrad"`` or ``"mrad/kNm"``."""
        return report_unit_of(self.unit)


class Group(str, Enum):
    """Which part of the set-up a parameter belongs to."""

    TRACKER = "tracker"
    REFLECTOR = "reflector"
    JOINT = "joint"
    COMPLIANCE = "compliance"
    GAIN = "gain"
    COUPLING = "coupling"


@dataclass(frozen=True)
class Parameter(InReportUnits):
    """One scalar calibration parameter.

    Attributes:
        index: Position in the parameter vector.
        name: ``"tracker.tx"``, ``"reflector0.z"``, ``"joint3.rz"``.
        unit: ``"m"``, ``"rad"``, for a compliance ``"rad/(N*m)"`` (``"m/N"``), for a
            gain or coupling ratio ``"rad/rad"`` (``"m/m"``, ``"rad/m"``, ``"m/rad"``).
        group: Tracker, reflector, joint, compliance, gain or coupling.
        owner: Index of the reflector or joint (0 for the tracker).
        description: Human-readable meaning (with the URDF joint name).
    """

    index: int
    name: str
    unit: str
    group: Group
    owner: int
    description: str


class ParameterSpace:
    """Parameter vector layout and its action on the robot and the sensor.

    Args:
        robot: The nominal robot.
        tracker_placement: Nominal :math:`T^0_{W,T}`, tracker frame in world.
        reflector_offsets: Nominal reflector positions :math:`c^0_j` in the
            tool frame, shape (k, 3) [m].
        compliance: Model joint compliance with this payload (one parameter
            per joint after the geometric ones); None: rigid joints (default).
        joint_gains: Identify these joint gains and coupling ratios (after the
            compliances, :mod:`calib_oed.model.joint_map`); None: none (default).
    """

    def __init__(self, robot: Robot, tracker_placement: pin.SE3, reflector_offsets: np.ndarray,
                 compliance: Compliance | None = None, joint_gains: JointGains | None = None):
        offsets = np.asarray(reflector_offsets, dtype=float)
        if offsets.ndim == 1:
            offsets = offsets[None, :]
        if offsets.ndim != 2 or offsets.shape[1] != 3 or offsets.shape[0] < 1:
            raise ShapeError("reflector_offsets", "(k, 3) with k >= 1", np.shape(reflector_offsets))
        if not np.all(np.isfinite(offsets)):
            raise NonFiniteError("reflector_offsets")
        if not isinstance(tracker_placement, pin.SE3):
            raise TypeError("tracker_placement must be a pinocchio.SE3")
        self.robot = robot
        self.tracker_placement0 = pin.SE3(tracker_placement)
        self.reflector_offsets0 = offsets.copy()
        self.reflector_offsets0.setflags(write=False)
        self.n_reflectors = offsets.shape[0]
        self.n_joints = robot.nq
        if compliance is not None and not isinstance(compliance, Compliance):
            raise TypeError("compliance must be a calib_oed.model.compliance.Compliance or None")
        self.compliance = compliance
        #: Gravity torques of the nominal robot with the payload (None without compliance).
        self.gravity = (GravityLoad(robot.model, robot.tool_frame_id, compliance)
                        if compliance is not None else None)
        if joint_gains is not None:
            if not isinstance(joint_gains, JointGains):
                raise TypeError("joint_gains must be a calib_oed.model.joint_map.JointGains or None")
            joint_gains.check(self.n_joints)
        self.joint_gains = joint_gains
        #: :math:`E_m` of the gains and couplings, (n, n_gains, n) (None without them).
        self.gain_basis = joint_gains.basis(self.n_joints) if joint_gains is not None else None
        self.parameters = tuple(self._build())
        self.names = tuple(p.name for p in self.parameters)
        self._index = {n: i for i, n in enumerate(self.names)}
        scale = np.array([p.report_scale for p in self.parameters])
        scale.setflags(write=False)
        #: SI value of 1 mm / 1 mrad per parameter; columns times this are "unit-scaled".
        self.unit_scale = scale

    # ----------------------------------------------------------------- layout
    def _build(self):
        idx = 0
        for k, c in enumerate(_TWIST):
            unit = "m" if k < 3 else "rad"
            yield Parameter(idx, f"tracker.{c}", unit, Group.TRACKER, 0,
                            f"tracker pose, right perturbation component {c}")
            idx += 1
        for j in range(self.n_reflectors):
            for c in _XYZ:
                yield Parameter(idx, f"reflector{j}.{c}", "m", Group.REFLECTOR, j,
                                f"reflector {j} offset along tool {c}")
                idx += 1
        for i, jname in enumerate(self.robot.joint_names, start=1):
            for k, c in enumerate(_TWIST):
                unit = "m" if k < 3 else "rad"
                yield Parameter(idx, f"joint{i}.{c}", unit, Group.JOINT, i,
                                f"placement of joint {i} ({jname}) in its parent, component {c}")
                idx += 1
        if self.compliance is not None:
            for i, jname in enumerate(self.robot.joint_names, start=1):
                prismatic = self._prismatic(i)
                yield Parameter(idx, f"joint{i}.c", "m/N" if prismatic else "rad/(N*m)",
                                Group.COMPLIANCE, i,
                                f"compliance of joint {i} ({jname}): deflection per gravity "
                                f"{'force' if prismatic else 'torque'}")
                idx += 1
        if self.joint_gains is None:
            return
        names = self.robot.joint_names
        for i in self.joint_gains.joints:
            unit = "m/m" if self._prismatic(i) else "rad/rad"
            yield Parameter(idx, f"joint{i}.gain", unit, Group.GAIN, i,
                            f"gain (relative encoder scale error) of joint {i} ({names[i - 1]})")
            idx += 1
        for j, f in self.joint_gains.couplings:
            unit = f"{'m' if self._prismatic(j) else 'rad'}/{'m' if self._prismatic(f) else 'rad'}"
            yield Parameter(idx, f"joint{j}.coupling{f}", unit, Group.COUPLING, j,
                            f"coupling ratio error: joint {j} ({names[j - 1]}) moves by it times "
                            f"joint {f} ({names[f - 1]})")
            idx += 1

    def _prismatic(self, i: int) -> bool:
        return joint_kind(self.robot.model.joints[i]) == "prismatic"

    @property
    def size(self) -> int:
        """Number of parameters :math:`n_p = 6 + 3k + 6n` (+ n with compliance, + gains and couplings)."""
        return len(self.parameters)

    @property
    def tracker_slice(self) -> slice:
        return slice(0, 6)

    def reflector_slice(self, j: int) -> slice:
        """Slice of reflector ``j``'s offset (0-based)."""
        start = 6 + 3 * j
        return slice(start, start + 3)

    @property
    def joints_slice(self) -> slice:
        """Slice of all joint parameters, in the order of the kinematic regressor."""
        start = 6 + 3 * self.n_reflectors
        return slice(start, start + 6 * self.n_joints)

    @property
    def compliance_slice(self) -> slice:
        """Slice of the joint compliances (empty when compliance is not modelled)."""
        start = self.joints_slice.stop
        return slice(start, start + (self.n_joints if self.compliance is not None else 0))

    @property
    def gain_slice(self) -> slice:
        """Slice of the joint gains and coupling ratios (empty when not identified), the last entries."""
        return slice(self.compliance_slice.stop, self.size)

    @property
    def joint_axes(self) -> np.ndarray:
        r"""Motion axis :math:`S_i` of every joint in its own frame, (n, 6) (constant for 1-DoF joints)."""
        if self.gravity is not None:
            return self.gravity.axes
        if not hasattr(self, "_axes"):
            model = self.robot.model
            data = model.createData()
            pin.forwardKinematics(model, data, pin.neutral(model))
            axes = np.array([np.asarray(data.joints[i].S).reshape(6) for i in range(1, model.njoints)])
            axes.setflags(write=False)
            self._axes = axes
        return self._axes

    def joint_slice(self, i: int) -> slice:
        """Slice of joint ``i``'s 6 parameters (1-based, Pinocchio joint index)."""
        start = self.joints_slice.start + 6 * (i - 1)
        return slice(start, start + 6)

    def index(self, name: str) -> int:
        """Position of parameter ``name``."""
        try:
            return self._index[name]
        except KeyError:
            raise UnknownParameterError(name, self.names) from None

    def zeros(self) -> np.ndarray:
        """The nominal parameter vector."""
        return np.zeros(self.size)

    def check(self, p: np.ndarray | None, what: str = "p") -> np.ndarray:
        """Validate a parameter vector (None means nominal)."""
        if p is None:
            return self.zeros()
        arr = np.asarray(p, dtype=float)
        if arr.shape != (self.size,):
            raise ShapeError(what, f"({self.size},)", np.shape(p))
        if not np.all(np.isfinite(arr)):
            raise NonFiniteError(what, np.flatnonzero(~np.isfinite(arr)).tolist())
        return arr

    # ----------------------------------------------------------------- action
    def perturbed_model(self, p: np.ndarray | None) -> pin.Model:
        r"""A new model with :math:`M_i \leftarrow M_i \exp_6(\delta_i)`.

        Returns the nominal model itself when every joint parameter is zero
        (it is never mutated).
        """
        p = self.check(p)
        joint_p = p[self.joints_slice]
        if not np.any(joint_p):
            return self.robot.model
        model = self.robot.model.copy()
        for i in range(1, self.n_joints + 1):
            delta = p[self.joint_slice(i)]
            if np.any(delta):
                model.jointPlacements[i] = model.jointPlacements[i] * pin.exp6(delta)
        return model

    def tracker_placement(self, p: np.ndarray | None) -> pin.SE3:
        r""":math:`T_{W,T} = T^0_{W,T} \exp_6(\delta_T)`."""
        p = self.check(p)
        return self.tracker_placement0 * pin.exp6(p[self.tracker_slice])

    def reflector_offsets(self, p: np.ndarray | None) -> np.ndarray:
        r""":math:`c_j = c^0_j + \delta c_j`, shape (k, 3) [m] in the tool frame."""
        p = self.check(p)
        delta = p[6 : 6 + 3 * self.n_reflectors].reshape(self.n_reflectors, 3)
        return self.reflector_offsets0 + delta

    def joint_exp_jacobians(self, p: np.ndarray | None) -> np.ndarray | None:
        r"""Right Jacobians :math:`J_r(\delta_i)` of every joint perturbation.

        :math:`M_i\exp_6(\delta_i + d\delta) = M_i\exp_6(\delta_i)\exp_6(J_r(\delta_i)\,d\delta)`.
        Returns an array (n, 6, 6), or None when all joint perturbations are
        zero (then every :math:`J_r` is the identity).
        """
        p = self.check(p)
        if not np.any(p[self.joints_slice]):
            return None
        return np.stack(
            [pin.Jexp6(p[self.joint_slice(i)]) for i in range(1, self.n_joints + 1)]
        )

