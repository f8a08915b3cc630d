r"""How fast the points of the robot can move: per-joint bounds from the kinematic chain.

A point :math:`p` fixed on body :math:`b` moves, when the joints move at rates
:math:`\dot q`, with velocity :math:`\dot p = \sum_{i \preceq b} \dot q_i\, \omega_i \times (p - o_i)`
(revolute joint :math:`i` with unit axis :math:`\omega_i` through its origin
:math:`o_i`) plus :math:`\dot q_i\, e_i` for a prismatic joint with unit direction
:math:`e_i`. The distance :math:`\lVert p - o_i \rVert` depends on the joints between
:math:`i` and :math:`b`, but never exceeds the chain length

.. math::
    R_i(p) = \lVert p_b \rVert + \sum_{j \in (i, b]} \big(\lVert t_j \rVert + \ell_j\big)
    \quad [\mathrm{m}],

with :math:`p_b` the point in body :math:`b`'s frame, :math:`t_j` the translation of
joint :math:`j`'s placement in its parent body and :math:`\ell_j` the largest
travel :math:`\max(|\underline q_j|, |\overline q_j|)` of a prismatic joint (0 for
revolute joints); :math:`R_i = 1` for a prismatic joint :math:`i` itself. So

.. math::
    \lVert \dot p \rVert \le \sum_i |\dot q_i|\, R_i(p)
    \qquad\text{in every configuration.}

On a joint-space linear move :math:`q(t) = q_0 + t\,\Delta`, :math:`t \in [0, 1]`,
every point of a capsule axis moves at most :math:`\rho^\top |\Delta|` per unit of
:math:`t`, with :math:`\rho` the element-wise maximum of :math:`R(a), R(b)` over the
two end points: the axis is a rigid segment, its points are convex combinations
of the end points and so are their displacements. A capsule distance
:math:`d(S_1, S_2) - r_1 - r_2 - m` is 1-Lipschitz in the positions of the axis
points (a distance between sets moves no more than the sets do), so a
constraint row between segments :math:`k, l` is Lipschitz in :math:`t` with
constant :math:`L = (\rho_k + \rho_l)^\top |\Delta|` [m per unit t]; a half-space
row of one end point with :math:`\rho_k^\top |\Delta|`.
"""

from __future__ import annotations

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.feasibility.constraints import SegmentTable
from calib_oed.model.robot import Robot, joint_kind


def point_speed_bounds(robot: Robot, body: int, local: np.ndarray) -> np.ndarray:
    r""":math:`R_i(p)` [m per rad, or 1 for a prismatic joint], (nv,), of a point ``local``
    (3,) [m] fixed on body (joint index) ``body``; zero for joints that do not move it."""
    model = robot.model
    out = np.zeros(model.nv)
    if body == 0:
        return out
    chain = []
    j = int(body)
    while j > 0:
        chain.append(j)
        j = int(model.parents[j])
    lower, upper = robot.lower, robot.upper
    reach = float(np.linalg.norm(local))
    for j in chain:  # from the body down to the base: reach = R_j(p)
        joint = model.joints[j]
        kind = joint_kind(joint)
        if kind == "other":
            raise ProgramError("robot", joint.shortname(), "the continuous collision check "
                               "supports 1-DoF revolute and prismatic joints only")
        iv = joint.idx_v
        out[iv] = 1.0 if kind == "prismatic" else reach
        travel = max(abs(lower[joint.idx_q]), abs(upper[joint.idx_q])) if kind == "prismatic" else 0.0
        reach += travel + float(np.linalg.norm(model.jointPlacements[j].translation))
    return out


def piece_speed_bounds(robot: Robot, pieces) -> np.ndarray:
    r"""A bound (nv,) on the speed of every point of a link's convex pieces
    (:class:`calib_oed.feasibility.hulls.LinkPieces`): no such point moves faster than
    :math:`\bar\rho^\top |\dot q|` [m/s].

    Each piece lies in its enclosing capsule (axis :math:`[a, b]`, radius :math:`r`, body
    frame), so a point :math:`p` of it is within :math:`r` of an axis point :math:`x`:
    :math:`\lVert p_b\rVert \le \lVert x_b\rVert + r` and, the norm being convex along the
    axis, :math:`R_i(p) \le \max(R_i(a), R_i(b)) + r` for every joint :math:`i` that moves
    the body (:func:`point_speed_bounds`; conservative for a prismatic joint, whose
    :math:`R_i = 1`). :math:`\bar\rho` is the element-wise maximum over the pieces.
    """
    out = np.zeros(robot.model.nv)
    for a, b, r in zip(pieces.cap_a, pieces.cap_b, pieces.cap_r, strict=True):
        ends = np.maximum(point_speed_bounds(robot, int(pieces.body), a), point_speed_bounds(robot, int(pieces.body), b))
        out = np.maximum(out, ends + float(r) * (ends > 0))
    return out


def segment_speed_bounds(robot: Robot, segments: SegmentTable) -> np.ndarray:
    r""":math:`\rho` per segment, (s, nv): no point of segment ``k`` moves faster than
    :math:`\rho_k^\top |\dot q|` [m/s] (world-fixed end points: 0)."""
    rho = np.zeros((len(segments), robot.model.nv))
    for k in range(len(segments)):
        ra = point_speed_bounds(robot, int(segments.body_a[k]), segments.a_local[k])
        rb = point_speed_bounds(robot, int(segments.body_b[k]), segments.b_local[k])
        rho[k] = np.maximum(ra, rb)
    return rho


class EndpointBounds:
    r"""The bound of :func:`point_speed_bounds` per segment end point, tightened on an interval.

    On an interval :math:`[t_a, t_b]` of a move, :math:`h = t_b - t_a`, the distance
    :math:`D_i(t) = \lVert p(t) - o_i(t)\rVert` of an end point from joint :math:`i`'s origin
    changes only through the joints after :math:`i`, at most at the rate
    :math:`C_i = \sum_{j > i} |\Delta_j| R_j(p)`; from its values at both ends,

    .. math::
        D_i(t) \le \min\big(D_i(t_a) + (t - t_a) C_i,\; D_i(t_b) + (t_b - t) C_i\big)
        \le \tfrac12\big(D_i(t_a) + D_i(t_b) + h C_i\big),

    and :math:`\min(R_i, \cdot)` of that replaces :math:`R_i` in the speed bound
    (prismatic joints keep :math:`R_i = 1`). Short intervals far from a joint's
    reach limit get a much smaller Lipschitz constant than the chain length gives.
    """

    def __init__(self, robot: Robot, segments: SegmentTable):
        model = robot.model
        self.body = np.stack([segments.body_a, segments.body_b], axis=1).astype(int)  # (s, 2)
        self.local = np.stack([segments.a_local, segments.b_local], axis=1)  # (s, 2, 3)
        self.reach = np.array([[point_speed_bounds(robot, int(b), p) for b, p in zip(bs, ps, strict=True)]
                               for bs, ps in zip(self.body, self.local, strict=True)])  # (s, 2, nv)
        self.ancestor = self.reach > 0
        joint_of_v = np.zeros(model.nv, dtype=int)
        prismatic = np.zeros(model.nv, dtype=bool)
        for j in range(1, model.njoints):
            joint_of_v[model.joints[j].idx_v] = j
            prismatic[model.joints[j].idx_v] = joint_kind(model.joints[j]) == "prismatic"
        self.joint_of_v, self.prismatic = joint_of_v, prismatic

    def distances(self, states) -> np.ndarray:
        """:math:`D_i` [m] of every end point at evaluated body states, (n, s, 2, nv)."""
        n, (s, _) = states.translation.shape[0], self.body.shape
        body = self.body.ravel()
        # R p + t per end point (a matmul: faster than BodyStates.points' einsum at this size)
        points = (states.rotation[:, body] @ self.local.reshape(-1, 3, 1))[..., 0] + states.translation[:, body]
        points = points.reshape(n, s, 2, 1, 3)
        origins = states.translation[:, self.joint_of_v][:, None, None]  # (n, 1, 1, nv, 3)
        return np.linalg.norm(points - origins, axis=-1) * self.ancestor

    def growth(self, dq_abs: np.ndarray) -> np.ndarray:
        """:math:`C_i = \\sum_{j > i} |\\Delta_j| R_j` [m per unit t], (s, 2, nv)."""
        w = self.reach * dq_abs
        tail = np.cumsum(w[..., ::-1], axis=-1)[..., ::-1]
        return tail - w
