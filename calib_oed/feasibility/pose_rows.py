r"""The rows of a pose alone: joint limits and reflector incidence.

- **joint** (2 per joint): :math:`q_i - (\underline q_i + m_q) \ge 0`,
  :math:`(\overline q_i - m_q) - q_i \ge 0` [rad or m]; linear.
- **incidence** (1 per reflector, paper eq. 4):
  :math:`z^\top u - \cos(\beta_{max} - m_\beta) \ge 0` [1], with
  :math:`z = R_{W,F}\,n_j` the reflector's axis (its unit ``normal`` :math:`n_j`
  in the tool frame) and :math:`u = (t_T - c)/\lVert t_T - c\rVert` the unit
  direction from the reflector :math:`c` to the tracker :math:`t_T`;
  :math:`\partial(z^\top u) = (z\times u)^\top J^{ang} - z^\top (I - uu^\top) J_c / L`,
  second derivatives in :func:`calib_oed.feasibility.curvature.incidence_derivatives`.
"""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.curvature import (
    _cross,
    body_points,
    incidence_derivatives,
    point_hessian,
)
from calib_oed.feasibility.row_family import RowFamily
from calib_oed.model.kinematics import cross


class JointRows(RowFamily):
    """Lower and upper limit of every joint, with the joint margin ``margin`` [rad or m]."""

    linear = True

    def __init__(self, robot, margin: float):
        self.robot, self.margin = robot, float(margin)
        self.kinds = ("joint",) * (2 * robot.nq)
        self.labels = tuple(f"joint:{name}:{side}" for name in robot.joint_names for side in ("lower", "upper"))

    def compute(self, q, states, jacobian):
        lo = q - (self.robot.lower + self.margin)
        hi = (self.robot.upper - self.margin) - q
        n, nq = q.shape
        values = np.stack([lo, hi], axis=2).reshape(n, 2 * nq)
        if not jacobian:
            return values, None
        jac = np.zeros((n, 2 * nq, nq))
        idx = np.arange(nq)
        jac[:, 2 * idx, idx] = 1.0
        jac[:, 2 * idx + 1, idx] = -1.0
        return values, jac


class IncidenceRows(RowFamily):
    """One incidence row per reflector (module docstring).

    Args:
        robot: The robot (its tool frame carries the reflectors).
        tracker_position: Tracker origin in the world [m], (3,).
        reflector_offsets: Reflector offsets in the tool frame [m], (k, 3).
        reflector_names: Their names.
        reflector_normals: Each reflector's axis in the tool frame, (k, 3) (normalised
            here; ``None``: tool z for every reflector).
        limit: :math:`\beta_{max} - m_\beta` [rad].
        reflectors: Each row's reflector, its index among the model's reflectors (``None``:
            0..k-1).
    """

    def __init__(self, robot, tracker_position, reflector_offsets, reflector_names, reflector_normals,
                 limit: float, reflectors=None):
        tool = robot.model.frames[robot.tool_frame_id]
        self.body = int(tool.parentJoint)
        self.tool_rotation = tool.placement.rotation.copy()
        offsets = np.asarray(reflector_offsets, dtype=float).reshape(-1, 3)
        self.local = np.array([tool.placement.act(c) for c in offsets]).reshape(-1, 3)
        k = len(offsets)
        normals = np.tile([0.0, 0.0, 1.0], (k, 1)) if reflector_normals is None else np.array(
            reflector_normals, dtype=float).reshape(-1, 3)
        if normals.shape != (k, 3):
            raise ShapeError("reflector_normals", f"({k}, 3)", normals.shape)
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        if not np.all(np.isfinite(normals)) or np.any(norm < 1e-12):
            raise ValueError(f"reflector normals must be finite and non-zero, got {normals.tolist()}")
        self.normals = normals / norm
        #: Each reflector's axis in its body (joint) frame.
        self.axis_local = (self.tool_rotation @ self.normals.T).T.copy()
        self.tracker_position = np.asarray(tracker_position, dtype=float).reshape(3)
        self.limit = float(limit)
        self.kinds = ("incidence",) * k
        self.labels = tuple(f"incidence:{name}" for name in reflector_names)
        self.reflectors = np.arange(k) if reflectors is None else np.asarray(reflectors, dtype=int).reshape(k)

    def row_reflectors(self):
        return self.reflectors.copy()

    def compute(self, q, states: BodyStates, jacobian):
        k, n = len(self), q.shape[0]
        if k == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, q.shape[1])) if jacobian else None)
        body = np.full(k, self.body)
        c = states.points(body, self.local)  # (n, k, 3)
        rot = states.rotation[:, self.body] @ self.tool_rotation  # (n, 3, 3)
        z = np.einsum("nij,kj->nki", rot, self.normals)  # (n, k, 3)
        diff = self.tracker_position - c
        length = np.linalg.norm(diff, axis=2, keepdims=True)
        u = diff / length
        values = np.einsum("nki,nki->nk", z, u) - np.cos(self.limit)
        if not jacobian:
            return values, None
        jac_ang = states.jacobian[:, self.body, 3:]  # (n, 3, nv)
        d_rot = np.einsum("nki,niv->nkv", cross(z, u), jac_ang)
        # -z^T (I - u u^T) / L  applied to the point Jacobian of c
        w = -(z - np.einsum("nki,nki->nk", z, u)[..., None] * u) / length
        d_pt = states.directional_jacobian(body, c, w)
        return values, d_rot + d_pt

    def hessians(self, states, pose, rows):
        pose, rows = np.asarray(pose, dtype=int), np.asarray(rows, dtype=int)
        x, jx, omega = body_points(states, pose, np.full(len(pose), self.body), self.local[rows])
        z = np.einsum("kij,kj->ki", states.rotation[pose, self.body], self.axis_local[rows])
        dz = _cross(omega, z[:, :, None])
        return incidence_derivatives(z, dz, point_hessian(omega, dz), x, jx, point_hessian(omega, jx),
                                     self.tracker_position)[2]
