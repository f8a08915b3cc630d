r"""Parameter tables: a serial arm as classic DH, modified DH or Hayati rows, with base and tool frames.

A table describes the tool frame :math:`F` in the world (robot base) frame :math:`W` as

.. math::

    T_{W,F}(q) = T_{W,0}\;\prod_{i=1}^{n} A_i(q_i)\;T_{n,F},

:math:`T_{W,0}` the **base** and :math:`T_{n,F}` the **tool** frame (full SE(3) poses,
written as ``xyz`` [m] and ``rpy`` [rad], :math:`R = R_z(y)R_y(p)R_x(r)` as in URDF), and
one row per revolute joint with :math:`\theta_i = q_i + \theta^0_i` (:math:`q_i` the URDF
joint value, positive about the URDF joint axis):

===================  ==============================================================  =================
convention           :math:`A_i(q_i)`                                                 frame :math:`i`
===================  ==============================================================  =================
``classic_dh``       :math:`R_z(\theta_i)T_z(d_i)T_x(a_i)R_x(\alpha_i)`               z on axis i+1
``modified_dh``      :math:`R_x(\alpha_i)T_x(a_i)R_z(\theta_i)T_z(d_i)` (Craig)       z on axis i
``hayati``           classic rows; a row whose axes :math:`i, i+1` are within          z on axis i+1
                     ``parallel_angle`` of parallel is Hayati's
                     :math:`R_z(\theta_i)T_x(a_i)R_x(\alpha_i)R_y(\beta_i)`
===================  ==============================================================  =================

(Denavit and Hartenberg 1955; Craig, *Introduction to Robotics*, 3rd ed., §3.4;
Hayati and Mirmirani 1985, for nearly parallel axes where the common normal of the
DH rows runs away: :math:`d_i \approx a/\delta` for a tilt :math:`\delta`.)

**From a model** (:func:`compute_table`): the joint axes are lines at :math:`q = 0`
(direction: the URDF axis, so :math:`\theta_i = q_i + \theta^0_i` with no sign flip);
each frame is placed on its axis by the convention, at the foot of the common normal
of consecutive axes (for exactly parallel axes the one that makes the row's :math:`d`
zero; for intersecting axes :math:`a = 0`, :math:`x = \pm z_i\times z_{i+1}`); the base and
tool frames take up what the rows cannot. Every revolute serial chain is exactly
representable this way; what is left is rounding, which
:attr:`ParameterTable.residual_m` reports (the largest TCP position and rotation
difference to the model at random configurations), named by :func:`compute_table`'s
caller when it exceeds 1e-9. Prismatic joints are not supported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ParameterTableError
from calib_oed.model.robot import Robot

CONVENTIONS = ("classic_dh", "modified_dh", "hayati")

#: Default angle [rad] below which consecutive axes get a Hayati row (``hayati`` tables): 0.1 rad.
PARALLEL_ANGLE = 0.1

_EPS = 1e-12


def _rx(a: float) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(a, 0.0, 0.0), np.zeros(3))


def _ry(a: float) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(0.0, a, 0.0), np.zeros(3))


def _rz(a: float) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, a), np.zeros(3))


def _t(x: float, y: float, z: float) -> pin.SE3:
    return pin.SE3(np.eye(3), np.array([x, y, z], dtype=float))


@dataclass(frozen=True)
class Row:
    r"""One joint's row [m, rad].

    Attributes:
        joint: URDF joint name.
        kind: ``"dh"`` (classic or modified by the table's convention) or ``"hayati"``.
        alpha, a, theta: :math:`\alpha_i`, :math:`a_i`, :math:`\theta^0_i` (offset added to q).
        d: :math:`d_i` (0 in a Hayati row); beta: :math:`\beta_i` (0 in a DH row).
        lower, upper: Joint limits [rad] (for the URDF written from the table).
    """

    joint: str
    kind: str
    alpha: float
    a: float
    theta: float
    d: float
    beta: float
    lower: float
    upper: float

    def fixed(self, convention: str) -> tuple[pin.SE3, pin.SE3]:
        """(before, after): :math:`A_i(q) = \\text{before}\\,R_z(q)\\,\\text{after}`."""
        if convention == "modified_dh":
            return _rx(self.alpha) * _t(self.a, 0, 0) * _rz(self.theta), _t(0, 0, self.d)
        if self.kind == "hayati":
            return pin.SE3.Identity(), _rz(self.theta) * _t(self.a, 0, 0) * _rx(self.alpha) * _ry(self.beta)
        return pin.SE3.Identity(), _rz(self.theta) * _t(0, 0, self.d) * _t(self.a, 0, 0) * _rx(self.alpha)


@dataclass(frozen=True)
class ParameterTable:
    """A robot as a parameter table (module docstring).

    Attributes:
        convention: One of :data:`CONVENTIONS`.
        robot: Robot name; tool_frame: the name of frame :math:`F`.
        base: :math:`T_{W,0}` as ``(x, y, z, roll, pitch, yaw)`` [m, rad] (URDF ``xyz``, ``rpy``);
            tool: :math:`T_{n,F}` the same way. Stored as written in files, so a table read back
            is bit for bit the table written; ``base_pose``, ``tool_pose`` give the SE(3) poses.
        rows: One :class:`Row` per joint, base to tip.
        residual_m, residual_rad: Largest TCP position [m] and rotation [rad] difference
            between the table and the model it came from (None for a table read from a file).
    """

    convention: str
    robot: str
    tool_frame: str
    base: tuple[float, ...]
    tool: tuple[float, ...]
    rows: tuple[Row, ...]
    residual_m: float | None = field(default=None, compare=False)
    residual_rad: float | None = field(default=None, compare=False)

    @property
    def base_pose(self) -> pin.SE3:
        return xyz_rpy_pose(self.base)

    @property
    def tool_pose(self) -> pin.SE3:
        return xyz_rpy_pose(self.tool)

    def compute_pose(self, q: np.ndarray) -> pin.SE3:
        r""":math:`T_{W,F}(q)` of the table, (nq,) [rad]."""
        q = np.asarray(q, dtype=float)
        if q.shape != (len(self.rows),):
            raise ParameterTableError(f"q has shape {q.shape}; the table has {len(self.rows)} joints")
        pose = self.base_pose
        for row, qi in zip(self.rows, q, strict=True):
            before, after = row.fixed(self.convention)
            pose = pose * before * _rz(qi) * after
        return pose * self.tool_pose

    def compute_difference(self, robot: Robot, q: np.ndarray) -> tuple[float, float]:
        """Largest position [m] and rotation [rad] difference of :math:`T_{W,F}` to ``robot`` over ``q``."""
        model, data = robot.model, robot.model.createData()
        dp = dr = 0.0
        for row in robot.check_configurations(q):
            pin.framesForwardKinematics(model, data, row)
            diff = data.oMf[robot.tool_frame_id].actInv(self.compute_pose(row))
            dp = max(dp, float(np.linalg.norm(diff.translation)))
            dr = max(dr, float(np.linalg.norm(pin.log3(diff.rotation))))
        return dp, dr


def xyz_rpy(m: pin.SE3) -> tuple[float, ...]:
    """``(x, y, z, roll, pitch, yaw)`` of a pose [m, rad], URDF convention, ``-0.0`` as ``0.0``."""
    return tuple(float(v) + 0.0 for v in (*m.translation, *pin.rpy.matrixToRpy(m.rotation)))


def xyz_rpy_pose(v) -> pin.SE3:
    """The pose of ``(x, y, z, roll, pitch, yaw)``: :math:`R = R_z(y)R_y(p)R_x(r)`."""
    return pin.SE3(pin.rpy.rpyToMatrix(*v[3:]), np.array(v[:3], dtype=float))


def _axes(robot: Robot) -> list[tuple[np.ndarray, np.ndarray]]:
    """(point, unit direction) of every joint axis at q = 0, world frame."""
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    out = []
    for i in range(1, model.njoints):
        s = np.asarray(data.joints[i].S).reshape(6)
        if np.linalg.norm(s[:3]) > _EPS or np.linalg.norm(s[3:]) < 0.5:
            raise ParameterTableError(
                f"joint {model.names[i]!r} is not revolute: parameter tables support revolute joints only")
        m = data.oMi[i]
        out.append((m.translation.copy(), m.rotation @ (s[3:] / np.linalg.norm(s[3:]))))
    return out


def _normal(p1, z1, p2, z2, near: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Common normal of lines 1 and 2: (foot on 1, foot on 2, unit x from 1 towards 2).

    Parallel lines: the normal through the point of line 1 nearest ``near``.
    Intersecting lines: x = z1 x z2 (normalised)."""
    cross = np.cross(z1, z2)
    s = float(np.linalg.norm(cross))
    w = p2 - p1
    if s < 1e-9:                                    # parallel: any normal, pick the one at `near`
        c1 = p1 + z1 * float(np.dot(near - p1, z1))
        c2 = p2 + z2 * float(np.dot(c1 - p2, z2))
    else:                                           # closest points of two skew lines
        b = float(np.dot(z1, z2))
        d, e = float(np.dot(z1, w)), float(np.dot(z2, w))
        den = 1.0 - b * b
        t1 = (d - b * e) / den
        t2 = (b * d - e) / den
        c1, c2 = p1 + t1 * z1, p2 + t2 * z2
    gap = c2 - c1
    if np.linalg.norm(gap) > 1e-9:
        x = gap / np.linalg.norm(gap)
    elif s >= 1e-9:
        x = cross / s
    else:                                           # coincident axes: any perpendicular
        x = np.cross(z1, [1.0, 0.0, 0.0] if abs(z1[0]) < 0.9 else [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
    x = x - z1 * float(np.dot(x, z1))               # exactly perpendicular to z1 (and z2 if possible)
    return c1, c2, x / np.linalg.norm(x)


def _frame(origin: np.ndarray, z: np.ndarray, x: np.ndarray) -> pin.SE3:
    x = x - z * float(np.dot(x, z))
    x /= np.linalg.norm(x)
    return pin.SE3(np.column_stack([x, np.cross(z, x), z]), np.asarray(origin, float))


def _classic_params(rel: pin.SE3) -> tuple[float, float, float, float]:
    """(theta, d, a, alpha) of rel = Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    r, t = rel.rotation, rel.translation
    theta = float(np.arctan2(r[1, 0], r[0, 0]))
    alpha = float(np.arctan2(r[2, 1], r[2, 2]))
    return theta, float(t[2]), float(np.cos(theta) * t[0] + np.sin(theta) * t[1]), alpha


def _modified_params(rel: pin.SE3) -> tuple[float, float, float, float]:
    """(alpha, a, theta, d) of rel = Rx(alpha) Tx(a) Rz(theta) Tz(d)."""
    r, t = rel.rotation, rel.translation
    theta = float(np.arctan2(-r[0, 1], r[0, 0]))
    alpha = float(np.arctan2(-r[1, 2], r[2, 2]))
    return alpha, float(t[0]), theta, float(-np.sin(alpha) * t[1] + np.cos(alpha) * t[2])


def _hayati_frame(prev: pin.SE3, p_next: np.ndarray, z_next: np.ndarray):
    """Frame on the next axis reached by Rz(theta) Tx(a) Rx(alpha) Ry(beta) from ``prev``, and the parameters."""
    zl = prev.rotation.T @ z_next                   # next axis in prev's coordinates
    pl = prev.actInv(p_next)
    if abs(zl[2]) < 1e-6:
        raise ParameterTableError("a Hayati row needs an axis not perpendicular to the previous one")
    o = pl - zl * (pl[2] / zl[2])                   # where the next axis crosses prev's xy plane
    a = float(np.hypot(o[0], o[1]))
    theta = float(np.arctan2(o[1], o[0])) if a > 1e-12 else 0.0
    zr = pin.rpy.rpyToMatrix(0.0, 0.0, -theta) @ zl    # = Rx(alpha) Ry(beta) e_z
    beta = float(np.arcsin(np.clip(zr[0], -1.0, 1.0)))
    alpha = float(np.arctan2(-zr[1], zr[2]))
    row = _rz(theta) * _t(a, 0, 0) * _rx(alpha) * _ry(beta)
    return prev * row, (alpha, a, theta, beta)


def _angle(z1: np.ndarray, z2: np.ndarray) -> float:
    """Angle between two axis lines [rad], 0..pi/2."""
    return float(np.arccos(np.clip(abs(float(np.dot(z1, z2))), 0.0, 1.0)))


def compute_table(robot: Robot, convention: str = "modified_dh", *, parallel_angle: float = PARALLEL_ANGLE,
                  check: int = 50, seed: int = 0) -> ParameterTable:
    """The table of ``robot`` (its model as loaded: nominal or calibrated) in ``convention``.

    Args:
        robot: A serial arm of revolute joints.
        convention: ``"classic_dh"``, ``"modified_dh"`` or ``"hayati"``.
        parallel_angle: Hayati rows where consecutive axes are within this angle [rad].
        check: Random configurations for :attr:`ParameterTable.residual_m` (seeded by ``seed``).

    Raises:
        ParameterTableError: an unknown convention, a prismatic joint.
    """
    if convention not in CONVENTIONS:
        raise ParameterTableError(f"unknown convention {convention!r}; valid: {', '.join(CONVENTIONS)}")
    axes = _axes(robot)
    n = len(axes)
    model = robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    tool_w = data.oMf[robot.tool_frame_id]
    names = robot.joint_names
    lims = [tuple(map(float, b)) for b in zip(robot.lower, robot.upper, strict=True)]
    foot_n = axes[-1][0] + axes[-1][1] * float(np.dot(tool_w.translation - axes[-1][0], axes[-1][1]))
    rows = []
    if convention == "modified_dh":
        # frame i on axis i at the foot of the common normal to axis i+1 (exactly parallel axes:
        # the normal through the previous foot, so d_i = 0); the last at the previous normal's foot
        near, frames = axes[0][0], []
        for i in range(n - 1):
            c1, c2, x = _normal(*axes[i], *axes[i + 1], near)
            frames.append(_frame(c1, axes[i][1], x))
            near = c2
        frames.append(_frame(near if n > 1 else foot_n, axes[-1][1],
                             frames[-1].rotation[:, 0] if n > 1 else _normal(*axes[0], *axes[0], near)[2]))
        base = prev = xyz_rpy_pose(xyz_rpy(frames[0]))
        for i, fr in enumerate(frames):
            alpha, a, theta, d = _modified_params(prev.actInv(fr))
            rows.append(Row(names[i], "dh", alpha, a, theta, d, 0.0, *lims[i]))
            prev = fr
    else:
        # frame i on axis i+1 at the foot of the common normal from axis i; frame 0 on axis 1
        c1, _, x = _normal(*axes[0], *axes[1], axes[0][0]) if n > 1 else (foot_n, None, None)
        base = prev = xyz_rpy_pose(xyz_rpy(_frame(c1, axes[0][1], x if n > 1 else
                                                   _normal(*axes[0], *axes[0], c1)[2])))
        for i in range(n):
            if i == n - 1:                          # last frame: on axis n, z along it
                fr = _frame(prev.translation, axes[i][1], prev.rotation[:, 0])
            elif convention == "hayati" and _angle(axes[i][1], axes[i + 1][1]) < parallel_angle:
                prev, (alpha, a, theta, beta) = _hayati_frame(prev, *axes[i + 1])
                rows.append(Row(names[i], "hayati", alpha, a, theta, 0.0, beta, *lims[i]))
                continue
            else:
                _, c2, x = _normal(*axes[i], *axes[i + 1], prev.translation)
                fr = _frame(c2, axes[i + 1][1], x)
            theta, d, a, alpha = _classic_params(prev.actInv(fr))
            rows.append(Row(names[i], "dh", alpha, a, theta, d, 0.0, *lims[i]))
            prev = fr
    last = prev
    table = ParameterTable(convention, robot.name, robot.tool_frame, xyz_rpy(base), xyz_rpy(last.actInv(tool_w)),
                           tuple(rows))
    q = robot.random_configurations(check, seed)
    dp, dr = table.compute_difference(robot, q)
    return ParameterTable(table.convention, table.robot, table.tool_frame, table.base, table.tool, table.rows,
                          dp, dr)


__all__ = ["CONVENTIONS", "PARALLEL_ANGLE", "ParameterTable", "Row", "compute_table", "xyz_rpy", "xyz_rpy_pose"]
