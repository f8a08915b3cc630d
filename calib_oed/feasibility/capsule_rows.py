r"""Capsule rows: two capsules, and a capsule against a half-space (paper §2.2).

**Capsule pairs** (kinds ``self``, ``obstacle``, ``beam``):
:math:`d(S_1, S_2) - r_1 - r_2 - m_d \ge 0` [m], :math:`d` the distance of the
axis segments. Gradient by the envelope theorem (closest-point parameters
:math:`s, t` held): with witness points :math:`w_1, w_2` and
:math:`u = (w_1 - w_2)/\lVert w_1 - w_2\rVert`,

.. math::
    \frac{\partial g}{\partial q} = u^\top\!\left(\frac{\partial w_1}{\partial q}
    - \frac{\partial w_2}{\partial q}\right),\qquad
    \frac{\partial w}{\partial q} = (1-s)\,J_{a} + s\,J_{b};

second derivatives in :func:`calib_oed.feasibility.curvature.segment_distance_derivatives`.

**Half-spaces** :math:`n^\top x \ge c_0` (kinds ``obstacle``, ``beam``): one
row per axis end point, :math:`n^\top a - c_0 - r - m_d \ge 0` and the same
for :math:`b`. Together they say the same as
:math:`\min(n^\top a, n^\top b) - c_0 - r - m_d \ge 0`, without its kink when
the segment is parallel to the plane; the two rows are one pair
(``kind:segment|half-space``), their labels mark the end (``segment.a|``).
A segment shorter than :data:`POINT_LENGTH` on one body (a sphere, as the
capsule fit makes of a wrist link: 0 to 4e-7 m on the shipped arms) has one
row, labelled without an end (``segment|half-space``),
:math:`n^\top a - c_0 - r - m_d - \lVert b - a\rVert \ge 0`: it implies both
ends' rows, and with the two nearly the same function both active made the
QP's KKT matrix singular or nearly (singular values 1e-10 of the largest),
which sent the polish of the QP step to least squares
(:mod:`calib_oed.solver.polish`).
"""

from __future__ import annotations

import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.curvature import (
    body_points,
    point_hessian_along,
    segment_distance_derivatives,
)
from calib_oed.feasibility.row_family import FIXED, RowFamily, RowSides
from calib_oed.feasibility.segments import closest_parameters

#: A segment on one body shorter than this [m] has one half-space row (module docstring).
POINT_LENGTH = 1e-6


def _ends(seg, i):
    """Bodies and local points of the end points a, b of segments ``i``."""
    return (seg.body_a[i], seg.a_local[i]), (seg.body_b[i], seg.b_local[i])


class CapsulePairRows(RowFamily):
    """One row per capsule pair ``(i, j)`` (segment indices, (P, 2)) of kinds ``kinds``."""

    def __init__(self, segments, pairs, kinds, clearance: float):
        self.segments = segments
        self.pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.kinds = tuple(kinds)
        self.clearance = float(clearance)
        names = segments.names
        self.labels = tuple(f"{k}:{names[i]}|{names[j]}" for (i, j), k in zip(self.pairs, self.kinds, strict=True))

    def compute(self, q, states: BodyStates, jacobian):
        n = q.shape[0]
        if len(self.pairs) == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, q.shape[1])) if jacobian else None)
        seg = self.segments
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        a1 = states.points(seg.body_a[i], seg.a_local[i])
        b1 = states.points(seg.body_b[i], seg.b_local[i])
        a2 = states.points(seg.body_a[j], seg.a_local[j])
        b2 = states.points(seg.body_b[j], seg.b_local[j])
        s, t = closest_parameters(a1, b1, a2, b2)
        w1 = a1 + s[..., None] * (b1 - a1)
        w2 = a2 + t[..., None] * (b2 - a2)
        diff = w1 - w2
        dist = np.linalg.norm(diff, axis=2)
        values = dist - seg.radius[i] - seg.radius[j] - self.clearance
        if not jacobian:
            return values, None
        u = diff / np.maximum(dist, 1e-12)[..., None]
        d1 = (1 - s)[..., None] * states.directional_jacobian(seg.body_a[i], a1, u) + s[
            ..., None
        ] * states.directional_jacobian(seg.body_b[i], b1, u)
        d2 = (1 - t)[..., None] * states.directional_jacobian(seg.body_a[j], a2, u) + t[
            ..., None
        ] * states.directional_jacobian(seg.body_b[j], b2, u)
        return values, d1 - d2

    def hessians(self, states, pose, rows):
        seg, ij = self.segments, self.pairs[np.asarray(rows, dtype=int)]
        body = np.stack([seg.body_a[ij[:, 0]], seg.body_b[ij[:, 0]], seg.body_a[ij[:, 1]], seg.body_b[ij[:, 1]]], 1)
        local = np.stack([seg.a_local[ij[:, 0]], seg.b_local[ij[:, 0]], seg.a_local[ij[:, 1]],
                          seg.b_local[ij[:, 1]]], 1)
        x, jx, omega = body_points(states, np.repeat(pose, 4), body.ravel(), local.reshape(-1, 3))
        nv = jx.shape[-1]

        def hess_along(u):
            return point_hessian_along(omega, jx, np.repeat(u, 4, axis=0)).reshape(-1, 4, nv, nv)

        return segment_distance_derivatives(x.reshape(-1, 4, 3), jx.reshape(-1, 4, 3, nv), hess_along)[2]

    def sides(self):
        return RowSides(self.pairs.copy(), (None,) * len(self))  # an obstacle's segment has speed 0

    def row_links(self):
        seg = self.segments
        body = ("robot", "reflector")
        return tuple(frozenset((seg.links[i], seg.links[j]))
                     if k == "self" and seg.roles[i] in body and seg.roles[j] in body else None
                     for (i, j), k in zip(self.pairs, self.kinds, strict=True))

    def subset(self, keep):
        keep = np.asarray(keep, dtype=bool)
        return CapsulePairRows(self.segments, self.pairs[keep],
                               [k for k, m in zip(self.kinds, keep, strict=True) if m], self.clearance)


class HalfspaceRows(RowFamily):
    """Two rows (end points a, b) per ``(segment, half-space)`` pair ((H, 2) indices into the
    segment table and ``cell.halfspaces``) of kinds ``kinds``; one for a zero-length segment."""

    def __init__(self, segments, cell, pairs, kinds, clearance: float):
        self.segments, self.cell = segments, cell
        self.pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.pair_kind = tuple(kinds)
        self.clearance = float(clearance)
        hs = cell.halfspaces
        self.normal = np.array([hs[h].normal for h in self.pairs[:, 1]]).reshape(-1, 3)
        self.offset = np.array([hs[h].offset for h in self.pairs[:, 1]], dtype=float)
        names, i = segments.names, self.pairs[:, 0]
        length = np.linalg.norm(segments.b_local[i] - segments.a_local[i], axis=1)
        point = (segments.body_a[i] == segments.body_b[i]) & (length < POINT_LENGTH)
        ends = np.ones((len(self.pairs), 2), dtype=bool)
        ends[point, 1] = False  # a zero-length segment has only its end a
        #: Per row its pair and end (0: a, 1: b), in pair order.
        self._pair, self._end = np.nonzero(ends)
        #: Per row what the one row of a short segment gives away for its end b [m] (else 0).
        self._slack = np.where(point, length, 0.0)[self._pair]
        self.kinds = tuple(self.pair_kind[p] for p in self._pair)
        self.labels = tuple(f"{self.pair_kind[p]}:{names[i[p]]}{'' if point[p] else '.' + 'ab'[e]}"
                            f"|{hs[self.pairs[p, 1]].name}" for p, e in zip(self._pair, self._end, strict=True))

    @property
    def pair_of_row(self):
        return self._pair.copy()

    @property
    def pair_labels(self):
        names, hs = self.segments.names, self.cell.halfspaces
        return tuple(f"{k}:{names[i]}|{hs[h].name}" for (i, h), k in zip(self.pairs, self.pair_kind, strict=True))

    def compute(self, q, states: BodyStates, jacobian):
        n = q.shape[0]
        if len(self.pairs) == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, q.shape[1])) if jacobian else None)
        seg = self.segments
        i = self.pairs[:, 0]
        a = states.points(seg.body_a[i], seg.a_local[i])
        b = states.points(seg.body_b[i], seg.b_local[i])
        base = self.offset + seg.radius[i] + self.clearance
        va = np.einsum("nhi,hi->nh", a, self.normal) - base
        vb = np.einsum("nhi,hi->nh", b, self.normal) - base
        values = np.stack([va, vb], axis=2)[:, self._pair, self._end] - self._slack
        if not jacobian:
            return values, None
        u = np.broadcast_to(self.normal, a.shape)
        ja = states.directional_jacobian(seg.body_a[i], a, u)
        jb = states.directional_jacobian(seg.body_b[i], b, u)
        return values, np.stack([ja, jb], axis=2)[:, self._pair, self._end]

    def _end_points(self, rows):
        rows = np.asarray(rows, dtype=int)
        h, end = self._pair[rows], self._end[rows]
        i, seg = self.pairs[h, 0], self.segments
        body = np.where(end == 0, seg.body_a[i], seg.body_b[i])
        local = np.where((end == 0)[:, None], seg.a_local[i], seg.b_local[i])
        return h, body, local

    def hessians(self, states, pose, rows):
        h, body, local = self._end_points(rows)
        _, jx, omega = body_points(states, np.asarray(pose, dtype=int), body, local)
        return point_hessian_along(omega, jx, self.normal[h])

    def sides(self):
        return RowSides(np.stack([self.pairs[self._pair, 0], np.full(len(self), FIXED)], axis=1),
                        (None,) * len(self))

    def subset(self, keep):
        keep = np.asarray(keep, dtype=bool)
        return HalfspaceRows(self.segments, self.cell, self.pairs[keep],
                             [k for k, m in zip(self.pair_kind, keep, strict=True) if m], self.clearance)
