r"""Solid rows: a capsule against a box, cylinder or mesh of the cell.

One row per ``(segment, solid)`` pair, :math:`g = d(S, O) - r - m_d \ge 0` [m]
(kinds ``obstacle`` and ``beam``); distances, witnesses and gradients in
:mod:`calib_oed.feasibility.solids`, the curvature here (derivations in
:mod:`calib_oed.feasibility.curvature`): exact for a box row whose witness is an
end point (point to box), an edge (segment to the world-fixed edge) and a
cylinder's side; the tangent-plane model for the coal rows.
"""

from __future__ import annotations

import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.curvature import (
    TINY,
    _outer,
    body_points,
    point_hessian_along,
    segment_distance_derivatives,
)
from calib_oed.feasibility.row_family import FIXED, RowFamily, RowSides
from calib_oed.feasibility.solids import EDGE, END_B, SolidPairs


def solid_hessians(solids: SolidPairs, pair: np.ndarray, x: np.ndarray, jx: np.ndarray,
                   omega: np.ndarray) -> np.ndarray:
    r""":math:`\nabla^2 d` (K, nv, nv) of solid rows ``pair`` (K,) from their segments' end points
    ``x`` (K, 2, 3), Jacobians ``jx`` and angular Jacobians ``omega`` (K, 2, 3, nv) (module docstring)."""
    w = solids.closest(x[:, 0], x[:, 1], pair)
    nv = jx.shape[-1]
    ua = point_hessian_along(omega[:, 0], jx[:, 0], w.u)
    ub = point_hessian_along(omega[:, 1], jx[:, 1], w.u)
    out = (1.0 - w.s)[:, None, None] * ua + w.s[:, None, None] * ub  # tangent-plane model
    end = np.flatnonzero(w.regime <= END_B)
    if end.size:  # point to box: + J^T (P - u u^T) J / d
        b = (w.regime[end] == END_B).astype(int)
        jac = jx[end, b]
        rot = solids.rotation[pair[end]]
        proj = np.einsum("kij,kj,klj->kil", rot, w.mask[end].astype(float), rot) - _outer(w.u[end], w.u[end])
        out[end] += np.swapaxes(jac, 1, 2) @ proj @ jac / np.maximum(w.dist[end], TINY)[:, None, None]
    edge = np.flatnonzero(w.regime == EDGE)
    if edge.size:  # segment to the world-fixed edge
        pts = np.concatenate([x[edge], w.edge[edge]], axis=1)
        jac = np.concatenate([jx[edge], np.zeros((edge.size, 2, 3, nv))], axis=1)

        def hess_along(u):
            h = np.zeros((edge.size, 4, nv, nv))
            h[:, 0] = point_hessian_along(omega[edge, 0], jx[edge, 0], u)
            h[:, 1] = point_hessian_along(omega[edge, 1], jx[edge, 1], u)
            return h

        out[edge] = segment_distance_derivatives(pts, jac, hess_along)[2]
    return out


class SolidRows(RowFamily):
    """One row per ``(segment, solid)`` pair ((S, 2) indices into the segment table and
    ``cell.solids``) of kinds ``kinds``."""

    def __init__(self, segments, cell, pairs, kinds, clearance: float):
        self.segments, self.cell = segments, cell
        pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.solids = SolidPairs(cell, pairs, segments.radius[pairs[:, 0]])
        self.kinds = tuple(kinds)
        self.clearance = float(clearance)
        names = segments.names
        self.labels = tuple(f"{k}:{names[i]}|{cell.solids[o].name}"
                            for (i, o), k in zip(pairs, self.kinds, strict=True))

    @property
    def pairs(self) -> np.ndarray:
        return self.solids.pairs

    def compute(self, q, states: BodyStates, jacobian):
        sp, seg = self.solids, self.segments
        n, nv = states.rotation.shape[0], q.shape[1]
        if len(sp) == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, nv)) if jacobian else None)
        i = sp.pairs[:, 0]
        a = states.points(seg.body_a[i], seg.a_local[i])
        b = states.points(seg.body_b[i], seg.b_local[i])
        idx = np.tile(np.arange(len(sp)), n)
        w = sp.closest(a.reshape(-1, 3), b.reshape(-1, 3), idx)
        values = w.dist.reshape(n, -1) - seg.radius[i] - self.clearance
        if not jacobian:
            return values, None
        s, u = w.s.reshape(n, -1, 1), w.u.reshape(n, -1, 3)
        ja = states.directional_jacobian(seg.body_a[i], a, u)
        jb = states.directional_jacobian(seg.body_b[i], b, u)
        return values, (1.0 - s) * ja + s * jb

    def hessians(self, states, pose, rows):
        rows, seg = np.asarray(rows, dtype=int), self.segments
        i = self.solids.pairs[rows, 0]
        body = np.stack([seg.body_a[i], seg.body_b[i]], 1)
        local = np.stack([seg.a_local[i], seg.b_local[i]], 1)
        x, jx, omega = body_points(states, np.repeat(pose, 2), body.ravel(), local.reshape(-1, 3))
        nv = jx.shape[-1]
        return solid_hessians(self.solids, rows, x.reshape(-1, 2, 3), jx.reshape(-1, 2, 3, nv),
                              omega.reshape(-1, 2, 3, nv))

    def sides(self):
        return RowSides(np.stack([self.solids.pairs[:, 0], np.full(len(self), FIXED)], axis=1).reshape(-1, 2),
                        (None,) * len(self))

    def prune_reason(self, lo, hi, samples, distance):
        if hi < 0:
            return (f"overlapping in every one of {samples} samples (clearance {lo * 1e3:.1f} to "
                    f"{hi * 1e3:.1f} mm): capsules too coarse?")
        if lo > distance:
            return f"never closer than {distance * 1e3:.0f} mm in {samples} samples"
        return None

    def subset(self, keep):
        keep = np.asarray(keep, dtype=bool)
        return SolidRows(self.segments, self.cell, self.solids.pairs[keep],
                         [k for k, m in zip(self.kinds, keep, strict=True) if m], self.clearance)
