r"""Cartesian pose conventions of the controllers, to and from :class:`pinocchio.SE3` (SI).

=========  =======================================  ==========================================
vendor     values                                   rotation
=========  =======================================  ==========================================
KUKA       X, Y, Z [mm]; A, B, C [deg]              :math:`R = R_z(A)R_y(B)R_x(C)` (ZYX Euler;
                                                    KUKA System Software 8 operating manual,
                                                    "Base, tool and robot coordinate systems")
ABB        [x, y, z] [mm]; [q1, q2, q3, q4]         unit quaternion :math:`q_1 = w`,
                                                    :math:`(q_2, q_3, q_4) = (x, y, z)`
                                                    (RAPID reference manual, data type ``orient``)
FANUC      X, Y, Z [mm]; W, P, R [deg]              fixed XYZ angles :math:`R = R_z(R)R_y(P)R_x(W)`
                                                    (FANUC operator's manual, "user frame"/"XYZWPR")
UR         p[x, y, z, rx, ry, rz] [m, rad]          rotation vector :math:`\exp_3(r_x, r_y, r_z)`
                                                    (URScript manual, "pose" type)
=========  =======================================  ==========================================

KUKA's :math:`R_z(A)R_y(B)R_x(C)` and FANUC's :math:`R_z(R)R_y(P)R_x(W)` are the same product,
``pin.rpy.rpyToMatrix(C, B, A)`` and ``(W, P, R)``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

MM = 1e-3
DEG = np.pi / 180.0


def from_euler_mm_deg(x, y, z, roll, pitch, yaw) -> pin.SE3:
    """Position [mm] and :math:`R = R_z(yaw)R_y(pitch)R_x(roll)` [deg]: KUKA (C, B, A), FANUC (W, P, R)."""
    return pin.SE3(pin.rpy.rpyToMatrix(roll * DEG, pitch * DEG, yaw * DEG), np.array([x, y, z]) * MM)


def to_euler_mm_deg(m: pin.SE3, near=None) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, z [mm], (roll, pitch, yaw) [deg]); each angle the one of its 2*pi family nearest ``near``."""
    rpy = np.asarray(pin.rpy.matrixToRpy(m.rotation)) / DEG
    if near is not None:
        rpy = rpy + 360.0 * np.round((np.asarray(near, float) - rpy) / 360.0)
    return m.translation / MM, rpy


def from_quaternion_mm(x, y, z, q1, q2, q3, q4) -> pin.SE3:
    """ABB: position [mm], quaternion (w, x, y, z) (normalised here)."""
    quat = pin.Quaternion(float(q1), float(q2), float(q3), float(q4))
    quat.normalize()
    return pin.SE3(quat.matrix(), np.array([x, y, z], float) * MM)


def to_quaternion_mm(m: pin.SE3, near=None) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, z [mm], (q1..q4) = (w, x, y, z)), the sign of the quaternion nearest ``near``."""
    q = pin.Quaternion(m.rotation)
    wxyz = np.array([q.w, q.x, q.y, q.z])
    if near is not None and float(np.dot(wxyz, near)) < 0:
        wxyz = -wxyz
    return m.translation / MM, wxyz


def from_rotvec_m(x, y, z, rx, ry, rz) -> pin.SE3:
    """UR: position [m], rotation vector [rad]."""
    return pin.SE3(pin.exp3(np.array([rx, ry, rz], float)), np.array([x, y, z], float))


def to_rotvec_m(m: pin.SE3, near=None) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, z [m], rotation vector [rad]); near angle pi, the vector's sign nearest ``near``."""
    r = np.asarray(pin.log3(m.rotation))
    if near is not None:
        angle = float(np.linalg.norm(r))
        if angle > 1e-9:
            alt = r / angle * (angle - 2 * np.pi)           # the same rotation the other way round
            if np.linalg.norm(alt - near) < np.linalg.norm(r - near):
                r = alt
    return m.translation.copy(), r


def in_order(from_pose: Callable[..., pin.SE3], to_pose: Callable[..., tuple[np.ndarray, np.ndarray]]):
    """``(pose_from, pose_to)`` of a language whose pose numbers are ``from_pose``'s arguments in order.

    ``pose_from(v)`` is ``from_pose(*v)``; ``pose_to(m, old)`` is ``to_pose``'s position, then its
    rotation numbers, the representation nearest the old ones ``old[3:]``.
    """
    def pose_from(v: np.ndarray) -> pin.SE3:
        return from_pose(*v)

    def pose_to(m: pin.SE3, old: np.ndarray) -> np.ndarray:
        xyz, rotation = to_pose(m, near=old[3:])
        return np.r_[xyz, rotation]

    return pose_from, pose_to
