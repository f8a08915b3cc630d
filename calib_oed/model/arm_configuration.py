r"""The configuration a controller reads from a Cartesian target: KUKA's status and turn, ABB's
``confdata``, FANUC's configuration string, as functions of the joints.

A 6R arm with a spherical wrist reaches most poses with up to eight joint solutions, and a
turn of a joint changes nothing of the pose; a controller picks one by the bits its
Cartesian targets carry. All three vendors encode the same three choices, plus joint turns:

=====================  ===================================  ====================================
choice                 boundary (computed here)             KUKA S / ABB cfx / FANUC string
=====================  ===================================  ====================================
**shoulder**           the wrist centre :math:`w` crosses   S bit 0 (overhead area) / wrist
                       the plane through the A1 axis         centre behind axis 1 / Top-Bottom
                       normal to the shoulder direction
**elbow**              :math:`w` crosses the line of the     S bit 1 (A3 vs. the stretched arm
                       A2 and A3 axes (arm stretched or      angle) / wrist centre behind the
                       folded)                               lower arm / Up-Down
**wrist**              joint 5 crosses 0                     S bit 2 / axis 5 negative / Flip
**turns**              KUKA: each joint's sign (T bit i:     T / cf1, cf4, cf6 / the turn
                       :math:`A_i < 0`); ABB: the quadrant   numbers of J1, J4, J6
                       :math:`\lfloor\theta/90°\rfloor` of
                       axes 1, 4, 6; FANUC: the turn
                       :math:`\lfloor(\theta + 180°)/360°\rfloor`
                       of J1, J4, J6
=====================  ===================================  ====================================

(KUKA System Software 8.x, *Operating and Programming Instructions for System Integrators*,
"Status and Turn"; ABB *Technical reference manual - RAPID Instructions, Functions and Data
types*, ``confdata``; FANUC *R-30iB Operator's Manual*, "Configuration".) The joint values
are the controller's (:class:`~calib_oed.model.controller.ControllerConvention` when the
scene has one, else the URDF joints). The wrist centre :math:`w` is the point nearest the
axes of joints 4, 5 and 6 (their intersection on a spherical wrist); the shoulder direction
is the common normal from the A1 axis to the A2 axis, turning with joint 1 (the joint-1
frame's x axis where the two axes meet). Each choice is returned with a signed margin, so a
target near a boundary is visible before it flips.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from calib_oed.exceptions import ParameterError
from calib_oed.model.controller import ControllerConvention
from calib_oed.model.robot import Robot

#: Controller vendors whose Cartesian targets carry configuration bits, by program language.
VENDORS = {"krl": "kuka", "rapid": "abb", "tp": "fanuc"}

_NAMES = {"kuka": ("S bit 0 (overhead)", "S bit 1 (A3 vs. stretched arm)", "S bit 2 (A5 sign)"),
          "abb": ("cfx: wrist centre vs. axis 1", "cfx: wrist centre vs. lower arm", "cfx: axis 5 sign"),
          "fanuc": ("Top/Bottom", "Up/Down", "Flip/NoFlip")}


@dataclass(frozen=True)
class ArmConfiguration:
    """The configuration choices of n joint vectors (module docstring).

    Attributes:
        shoulder: Signed distance [m] of the wrist centre from the A1 plane, + in front (n,).
        elbow: Signed distance [m] of the wrist centre from the A2-A3 line (n,).
        wrist: Joint 5 [rad], the controller's value (n,).
        joints: The controller's joint values [rad] (n, nq).
    """

    shoulder: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray
    joints: np.ndarray

    def turns(self, vendor: str) -> tuple[tuple[int, ...], np.ndarray]:
        """(the 0-based joints whose turn the vendor encodes, their turn values (n, k))."""
        c = self.joints
        if vendor == "kuka":
            return tuple(range(c.shape[1])), (c < 0).astype(int)
        picks = tuple(j for j in (0, 3, 5) if j < c.shape[1])
        if vendor == "abb":
            return picks, np.floor(c[:, picks] / (np.pi / 2) + 1e-12).astype(int)
        if vendor == "fanuc":
            return picks, np.floor((c[:, picks] + np.pi) / (2 * np.pi) + 1e-12).astype(int)
        raise ParameterError(f"unknown controller vendor {vendor!r}; valid: {', '.join(sorted(set(VENDORS.values())))}")


def kuka_status(cfg: ArmConfiguration) -> tuple[np.ndarray, np.ndarray]:
    """KUKA's status ``S`` and turn ``T`` of every row (n,) each: S bit 0 the wrist centre in the
    overhead area (not in front of A1), bit 1 A3 at or past the stretched arm (elbow margin >= 0
    on arms whose joint directions are KUKA's: ROS-Industrial's and ours), bit 2 A5 <= 0; T bit i
    axis i + 1 below 0."""
    s = (cfg.shoulder <= 0).astype(int) + 2 * (cfg.elbow >= 0) + 4 * (cfg.wrist <= 0)
    return s, (cfg.joints < 0).astype(int) @ (1 << np.arange(cfg.joints.shape[1]))


def abb_confdata(cfg: ArmConfiguration) -> np.ndarray:
    r"""ABB's ``confdata`` ``[cf1, cf4, cf6, cfx]`` of every row (n, 4): the quadrants
    :math:`\lfloor\theta/90°\rfloor` of axes 1, 4 and 6, and ``cfx`` = 4 (wrist centre behind
    axis 1) + 2 (wrist centre behind the lower arm) + 1 (axis 5 negative), the robot-series table
    of ABB's *Technical reference manual - RAPID Instructions, Functions and Data types*,
    ``confdata`` (0: in front of both, axis 5 positive). Behind axis 1 is the shoulder margin
    at or below 0, as KUKA's overhead area; behind the lower arm the elbow margin below 0."""
    _, quadrants = cfg.turns("abb")
    cfx = 4 * (cfg.shoulder <= 0) + 2 * (cfg.elbow < 0) + (cfg.wrist < 0)
    return np.column_stack([quadrants, cfx]).astype(int)


def _nearest_points(points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Per row, the point nearest (least squares) to the lines ``points + t directions``,
    (n, k, 3) each -> (n, 3)."""
    m = np.eye(3) - directions[..., :, None] * directions[..., None, :]        # (n, k, 3, 3)
    return np.linalg.solve(m.sum(axis=1), np.einsum("nkij,nkj->ni", m, points)[..., None])[..., 0]


class ConfigurationKinematics:
    """What :func:`compute_arm_configuration` needs of a robot, computed once: the joint axes in
    their own frames, the shoulder direction in joint 1's frame, a Pinocchio data.

    Raises:
        ParameterError: fewer than 6 joints.
    """

    def __init__(self, robot: Robot, controller: ControllerConvention | None = None):
        if robot.nq < 6:
            raise ParameterError(f"{robot.name}: configuration bits need a 6-axis arm, it has {robot.nq} joints")
        self.robot, self.controller = robot, controller
        model = robot.model
        self._data = model.createData()
        pin.forwardKinematics(model, self._data, pin.neutral(model))
        local = np.array([np.asarray(self._data.joints[i].S).reshape(6)[3:] for i in range(1, model.njoints)])
        self._local = local / np.linalg.norm(local, axis=1, keepdims=True)   # revolute: constant in its frame
        p0, d0, r0 = (a[0] for a in self._axes(pin.neutral(model)[None]))
        # the shoulder direction at q = 0 in joint 1's own frame: the common normal from A1 to A2
        gap = (p0[1] - p0[0]) - d0[0] * float(np.dot(p0[1] - p0[0], d0[0]))
        self._u_local = r0.T @ (gap / np.linalg.norm(gap) if np.linalg.norm(gap) > 1e-6 else r0[:, 0])
        # the elbow margin is L sin(q3 + c) (the wrist centre turns about A3 with joint 3)
        e = self.compute(np.array([np.r_[0.0, 0.0, a3, np.zeros(model.nq - 3)] for a3 in (0.0, np.pi / 2)]))
        self._elbow_phase = float(np.arctan2(e.elbow[0], e.elbow[1]))

    def _axes(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points and unit directions of the joint axes at every row of ``q``, world frame, (n, nq, 3)
        each, and joint 1's rotation (n, 3, 3)."""
        model, data = self.robot.model, self._data
        n, nj = len(q), model.njoints - 1
        rot, pts = np.empty((n, nj, 3, 3)), np.empty((n, nj, 3))
        for k, row in enumerate(q):
            pin.forwardKinematics(model, data, row)
            for i in range(nj):
                m = data.oMi[i + 1]
                rot[k, i], pts[k, i] = m.rotation, m.translation
        return pts, np.einsum("nijk,ik->nij", rot, self._local), rot[:, 0]

    def compute_elbow_flip(self, q: np.ndarray) -> np.ndarray:
        r"""The mirrored elbow of the URDF joints ``q`` (nq,) [rad] with the same wrist centre:
        :math:`q_3' = -2c - q_3` (the elbow margin :math:`L\sin(q_3 + c)` negated), :math:`q_2` turned
        so the wrist centre is back where it was; joints 1, 4-6 unchanged (a seed for the inverse
        kinematics of the pose on the other elbow). Joint 3 is taken a turn round where that
        brings it inside its limits."""
        robot = self.robot
        q = np.array(q, dtype=float)
        out = q.copy()
        q3 = -2 * self._elbow_phase - q[2]
        turns = [q3 + 2 * np.pi * k for k in (-1, 0, 1)]
        out[2] = min(turns, key=lambda v: (not robot.lower[2] <= v <= robot.upper[2], abs(v - q[2])))
        p, d, _ = self._axes(np.stack([q, out]))
        w = _nearest_points(p[:, 3:6], d[:, 3:6])
        axis, a, b = d[0, 1], w[1] - p[0, 1], w[0] - p[0, 1]
        out[1] += float(np.arctan2(np.dot(axis, np.cross(a, b)), np.dot(a, b)))
        return out

    def compute(self, q: np.ndarray) -> ArmConfiguration:
        """:class:`ArmConfiguration` of the URDF joints ``q`` (n, nq) or (nq,) [rad]."""
        q = self.robot.check_configurations(q)
        p, d, r1 = self._axes(q)
        w = _nearest_points(p[:, 3:6], d[:, 3:6])
        shoulder = np.einsum("ni,ni->n", w - p[:, 0], r1 @ self._u_local)
        arm = p[:, 2] - p[:, 1]
        arm = arm - d[:, 2] * np.einsum("ni,ni->n", arm, d[:, 2])[:, None]      # in the plane normal to A3
        elbow = np.einsum("ni,ni->n", np.cross(arm, w - p[:, 2]), d[:, 2]) / np.linalg.norm(arm, axis=1)
        ctl = self.controller
        c = np.array([ctl.to_controller(row) for row in q]) if ctl is not None else q.copy()
        return ArmConfiguration(shoulder, elbow, c[:, 4].copy(), c)


def compute_arm_configuration(robot: Robot, q: np.ndarray,
                              controller: ControllerConvention | None = None) -> ArmConfiguration:
    """:class:`ArmConfiguration` of the URDF joints ``q`` (n, nq) or (nq,) [rad] of a 6R arm
    (:class:`ConfigurationKinematics`; build that once for many calls).

    Raises:
        ParameterError: fewer than 6 joints.
    """
    return ConfigurationKinematics(robot, controller).compute(q)


def configuration_changes(before: ArmConfiguration, after: ArmConfiguration, vendor: str,
                          joint_names: tuple[str, ...] | None = None) -> list[list[str]]:
    """Per row, what of ``vendor``'s configuration (``kuka``, ``abb``, ``fanuc``) differs between
    ``before`` and ``after``: one phrase per changed bit or turn, with the values."""
    names = _NAMES.get(vendor)
    if names is None:
        raise ParameterError(f"unknown controller vendor {vendor!r}; valid: {', '.join(sorted(_NAMES))}")
    picks, t0 = before.turns(vendor)
    _, t1 = after.turns(vendor)
    label = joint_names or tuple(f"J{j + 1}" for j in range(before.joints.shape[1]))
    out = []
    for k in range(len(before.wrist)):
        found = []
        for name, a, b, unit in ((names[0], before.shoulder[k], after.shoulder[k], "mm"),
                                 (names[1], before.elbow[k], after.elbow[k], "mm"),
                                 (names[2], before.wrist[k], after.wrist[k], "deg")):
            if (a > 0) != (b > 0):
                f = 1e3 if unit == "mm" else 180 / np.pi
                found.append(f"{name} {f * a:+.3f} -> {f * b:+.3f} {unit}")
        for col, j in enumerate(picks):
            if t0[k, col] != t1[k, col]:
                found.append(f"turn of {label[j]} {np.degrees(before.joints[k, j]):+.3f} -> "
                             f"{np.degrees(after.joints[k, j]):+.3f} deg")
        out.append(found)
    return out


__all__ = ["VENDORS", "ArmConfiguration", "ConfigurationKinematics", "abb_confdata", "compute_arm_configuration",
           "configuration_changes", "kuka_status"]
