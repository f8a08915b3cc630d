r"""Per-interval Lipschitz constants of the collision rows of a move.

:func:`calib_oed.program.continuous.row_bounds` gives each row a constant for the whole
move, :math:`L = (\rho_a + \rho_b)^\top|\Delta|` [m per unit t]. Two things make it smaller
on an interval :math:`[t_a, t_b]` of the bisection (:class:`IntervalBounds`):

**Relative motion of a self pair.** A distance between sets on two links is unchanged when
both move rigidly together: the joints that move both links (their common ancestors in the
serial chain, joint :math:`c` and those before it) do not change it. In the frame of the
common ancestor only the other joints move the points, with the same
:math:`R_i(p) = \lVert p - o_i\rVert` bounds, so their components are dropped from
:math:`\rho_a + \rho_b` (for the move's constant too). A row against a fixed set (table,
solids) keeps every joint. On a UR's wrist pair ``wrist_1_link|wrist_3_link`` only the last
two joints remain.

**Interval end points.** :class:`~calib_oed.program.motion_bound.EndpointBounds` bounds
each capsule axis end point's distance :math:`D_i` from joint :math:`i` on the interval from
its values at the ends; the end point's speed is :math:`\sum_i |\Delta_i| \min(R_i, D_i)`,
and a point of the axis moves no faster than its faster end (velocity is affine in the
point on a rigid body).

**Rows on convex pieces** (:mod:`calib_oed.feasibility.hulls`): each piece lies in its
enclosing capsule (axis :math:`[a, b]`, radius :math:`r`, body frame); a point of it is
:math:`p = x + w`, :math:`x` on the axis, :math:`\lVert w\rVert \le r`, so
:math:`\dot p = \dot x + \omega \times w` with the body's angular velocity
:math:`\lVert\omega\rVert \le \sum_i |\dot q_i|` over the (relative) joints moving it:

.. math::
    v_{piece} \le v_{axis} + r \sum_{i} |\Delta_i|,\qquad
    v_{link} = \max_{pieces} v_{piece},\qquad L_{row} = v_{link\,a} + v_{link\,b}.

The pieces' axes are appended to the capsule segments, so one ``EndpointBounds`` serves
both. The interval's constant is :math:`\min(L, L_{row})` per row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.program.motion_bound import EndpointBounds


@dataclass(frozen=True)
class Axes:
    """Capsule axes in body frames: the segment table fields :class:`EndpointBounds` reads."""

    body_a: np.ndarray
    body_b: np.ndarray
    a_local: np.ndarray
    b_local: np.ndarray

    def __len__(self) -> int:
        return len(self.body_a)


def _ancestors(model, body: int) -> set[int]:
    """Joint indices that move ``body`` (itself and its ancestors; empty for the world)."""
    out = set()
    while body > 0:
        out.add(int(body))
        body = int(model.parents[body])
    return out


class IntervalBounds:
    """Local Lipschitz constants of collision rows on the intervals of a move.

    Args:
        robot: The robot (the feasibility model's, with its limits).
        segments: The feasibility model's segment table.
        pieces: ``{link: LinkPieces}`` of the rows on convex pieces (may be empty).
        row_links: Per row, the two links of a row on link geometry, else ``None``
            (:class:`~calib_oed.feasibility.row_family.RowSides`).
        segs: The rows' segments from :func:`~calib_oed.program.continuous.row_bounds`
            ((m, 2); -1 a fixed set, -2 no segment).
    """

    def __init__(self, robot, segments, pieces: dict, row_links, segs: np.ndarray):
        model = robot.model
        self.n_segments = len(segments)
        body, a, b, radius, owner = [], [], [], [], []
        links = tuple(pieces)
        for k, name in enumerate(links):
            lp = pieces[name]
            for ca, cb, cr in zip(lp.cap_a, lp.cap_b, lp.cap_r, strict=True):
                body.append(int(lp.body))
                a.append(ca)
                b.append(cb)
                radius.append(float(cr))
                owner.append(k)
        self.axes = Axes(np.concatenate([np.asarray(segments.body_a, int), np.array(body, dtype=int)]),
                         np.concatenate([np.asarray(segments.body_b, int), np.array(body, dtype=int)]),
                         np.concatenate([np.asarray(segments.a_local, float).reshape(-1, 3),
                                         np.array(a, dtype=float).reshape(-1, 3)]),
                         np.concatenate([np.asarray(segments.b_local, float).reshape(-1, 3),
                                         np.array(b, dtype=float).reshape(-1, 3)]))
        self.ends = EndpointBounds(robot, self.axes)
        self.radius = np.concatenate([np.zeros(self.n_segments), np.array(radius, dtype=float)])
        self.moving = self.ends.ancestor.any(axis=1)  # (axes, nv): joints that move each axis
        owner = np.array(owner, dtype=int)
        link_axes = {name: self.n_segments + np.flatnonzero(owner == k) for k, name in enumerate(links)}
        v_of = {j: model.joints[j].idx_v for j in range(1, model.njoints)}
        seg_body = np.asarray(segments.body_a, int)
        m, nv = len(row_links), model.nv
        #: (m, nv) True for the joints that move one side of the row relative to the other
        self.relative = np.ones((m, nv), dtype=bool)
        self.sides = np.full((m, 2), -1)  # segment rows: each side's segment (-1: fixed set)
        self.link_rows: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.segment_rows = np.flatnonzero(segs[:, 0] != -2)
        for r, parts in enumerate(row_links):
            if segs[r, 0] != -2:
                self.sides[r] = segs[r]
                bodies = [int(seg_body[s]) if s >= 0 else 0 for s in segs[r]]
            elif parts is not None and all(p in link_axes for p in parts):
                self.link_rows.append((r, link_axes[parts[0]], link_axes[parts[1]]))
                bodies = [int(pieces[p].body) for p in parts]
            else:
                continue  # unknown sides: every joint, the move's constant
            common = _ancestors(model, bodies[0]) & _ancestors(model, bodies[1])
            for j in common:
                self.relative[r, v_of[j]] = False

    def local(self, lip: np.ndarray, d_a, d_b, h, dq_abs, growth) -> np.ndarray:
        """Per interval and row, the smaller of the move's constant ``lip`` (m,) and the local
        one [m per unit t], (I, m); ``d_a, d_b`` are ``self.ends.distances`` at the intervals'
        ends, ``growth`` is ``self.ends.growth(dq_abs)``."""
        reach = np.where(self.ends.prismatic, self.ends.reach,
                         np.minimum(self.ends.reach, 0.5 * (d_a + d_b + h[:, None, None, None] * growth)))
        x = reach * dq_abs  # (I, axes, 2, nv): per joint, each end point's speed share
        out = np.broadcast_to(lip, (len(h), len(lip))).copy()
        rows = self.segment_rows
        if rows.size:
            rel = self.relative[rows][None, :, None, :]
            speed = np.zeros((len(h), rows.size))
            for c in range(2):
                side = self.sides[rows, c]
                v = (x[:, np.maximum(side, 0)] * rel).sum(axis=-1).max(axis=-1)  # (I, rows)
                speed += np.where(side >= 0, v, 0.0)
            out[:, rows] = np.minimum(out[:, rows], speed)
        for r, axes_a, axes_b in self.link_rows:
            rel = self.relative[r]
            total = 0.0
            for axes in (axes_a, axes_b):
                spin = self.radius[axes] * ((self.moving[axes] & rel) @ dq_abs)  # r * |omega|
                total = total + ((x[:, axes] * rel).sum(axis=-1).max(axis=-1) + spin).max(axis=1)
            out[:, r] = np.minimum(out[:, r], total)
        return out
