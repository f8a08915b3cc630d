r"""The smooth pieces of a convex-piece row where it has a kink: the corners of the contact.

The row of two convex pieces :math:`P` (on body :math:`a`) and :math:`Q` (on
body :math:`b`), :math:`g = d(P, Q) - m_d` (:mod:`calib_oed.feasibility.hulls`),
is only piecewise smooth. With :math:`u` the unit normal from :math:`Q` towards
:math:`P` and the support heights

.. math::
    h_P = \min_{p \in P} u^\top p, \qquad h_Q = \max_{q \in Q} u^\top q, \qquad d = h_P - h_Q,

the *support features* are the vertices of :math:`P` at :math:`h_P` and of
:math:`Q` at :math:`h_Q` (to :data:`~calib_oed.feasibility.hull_curvature.TOL`):
a vertex, an edge or a face each. Where they overlap in more than a point
(projected along :math:`u`: an edge or a face of one resting on a face of the
other, or on an edge across it), :math:`d` is the least of several smooth
distances and has a concave kink, where an optimum likes to sit and where the
row's one gradient is wrong to first order (:mod:`calib_oed.solver.pieces`).
The pieces are the corners :math:`y` of the overlap (the *contact polygon*, the
intersection of the two features' projections, by shapely): each is a vertex
of one feature over the other's face or edge, or the crossing of an edge of
each, and its distance

.. math::
    g_y = h_P - h_Q - m_d, \qquad
    \frac{\partial g_y}{\partial q} = u^\top (J_{y_a} - J_{y_b}),

with :math:`y_a, y_b` the points of the two features over :math:`y` held fixed
on bodies :math:`a` and :math:`b`: the gradient of a vertex-to-plane or an
edge-to-edge distance (the envelope theorem: the turning of :math:`u` does not
enter, as for the row itself). :math:`g` is the least of them to first order.
Vertices a little above the support (within :data:`NEAR`) whose projection lies
inside the other piece's support face add their vertex-to-plane pieces
(:math:`g_p = u^\top p - h_Q - m_d` for :math:`P`), which a step may make active.
Every piece is at least :math:`g`. Rows whose supports meet in a point get no
pieces: there the witness features are unique and the row is smooth.

All lengths in [m].
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import shapely

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.hull_curvature import TOL
from calib_oed.feasibility.hulls import HullPairs

NEAR = 1e-3
r""":math:`\delta` [m]: vertices up to this far above the support height give pieces (a step
of the SQP's trust region moves points by millimetres)."""
MAX_PER_SIDE = 6
"""Most pieces per row and side (the lowest vertices)."""


class HullRowPieces(NamedTuple):
    """The smooth pieces of kinked convex-piece rows.

    Attributes:
        pose: Pose of each piece (k,).
        row: Its row among the model's convex-piece rows (k,).
        values: :math:`g_p` [m] (k,).
        jacobian: :math:`\\partial g_p / \\partial q` (k, nv).
    """

    pose: np.ndarray
    row: np.ndarray
    values: np.ndarray
    jacobian: np.ndarray


def _plane_basis(u: np.ndarray) -> np.ndarray:
    """Two orthonormal vectors (2, 3) normal to the unit vector ``u``."""
    return np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2].T


def _region(flat: np.ndarray):
    """The convex hull of 2-D points (k, 2) [m] as a shapely point, segment or polygon."""
    return shapely.MultiPoint(flat).convex_hull


def _corners(region) -> np.ndarray:
    """The corner points (k, 2) of a point, segment or convex polygon; empty for anything else."""
    if region.is_empty:
        return np.zeros((0, 2))
    if isinstance(region, shapely.Polygon):
        return np.asarray(region.exterior.coords)[:-1]
    if isinstance(region, (shapely.LineString, shapely.Point)):
        return np.asarray(region.coords)
    return np.zeros((0, 2))


def _near_over(face, heights: np.ndarray, flat: np.ndarray, support: float, away: float) -> list[int]:
    """Vertices a little off their piece's support height (``away`` = +1: above it, -1: below;
    by more than TOL, at most NEAR [m]) whose projection lies over ``face``, nearest first."""
    off = away * (heights - support)
    near = np.flatnonzero((off > TOL) & (off <= NEAR))
    near = near[np.argsort(off[near])][:MAX_PER_SIDE]
    return [int(v) for v in near if face.contains(shapely.Point(flat[v]))]


def hull_row_pieces(hull: HullPairs, states: BodyStates, pose: np.ndarray, rows: np.ndarray,
                    clearance: float) -> HullRowPieces:
    """The pieces (module docstring) of convex-piece rows ``rows`` (k,) at poses ``pose`` (k,) of
    ``states`` (with Jacobians); rows without a kink give none."""
    nv = states.jacobian.shape[-1]
    out_pose, out_row, values, jac = [], [], [], []
    for k, h in zip(np.asarray(pose, dtype=int).tolist(), np.asarray(rows, dtype=int).tolist(), strict=True):
        one = states.take(np.array([k]))
        w = hull.closest(one, np.array([h]))
        i, j, dist = int(w.piece_a[0, 0]), int(w.piece_b[0, 0]), float(w.dist[0, 0])
        if i < 0 or dist <= 0.0:
            continue
        verts_p, verts_q = hull.piece_vertices(states, k, i), hull.piece_vertices(states, k, j)
        if verts_p is None or verts_q is None:
            continue
        u = w.u[0, 0]
        sp_, sq = verts_p @ u, verts_q @ u
        h_p, h_q = float(sp_.min()), float(sq.max())
        basis = _plane_basis(u)
        flat_p, flat_q = verts_p @ basis.T, verts_q @ basis.T
        low_p, high_q = _region(flat_p[sp_ <= h_p + TOL]), _region(flat_q[sq >= h_q - TOL])
        # the contact: where the two support features overlap along u; each corner is a vertex
        # over a face (or an edge) or where two edges cross
        feet = [(y @ basis + h_p * u, y @ basis + h_q * u, h_p - h_q)
                for y in _corners(low_p.intersection(high_q))]
        # vertices a little above the support, over the other's face: pieces a step may activate
        if isinstance(high_q, shapely.Polygon):
            feet += [(verts_p[v], flat_p[v] @ basis + h_q * u, sp_[v] - h_q)
                     for v in _near_over(high_q, sp_, flat_p, h_p, 1.0)]
        if isinstance(low_p, shapely.Polygon):
            feet += [(flat_q[v] @ basis + h_p * u, verts_q[v], h_p - sq[v])
                     for v in _near_over(low_p, sq, flat_q, h_q, -1.0)]
        if len(feet) < 2:  # one piece: the row itself, smooth
            continue
        on_a = np.array([f[0] for f in feet])[None]  # (1, s, 3)
        on_b = np.array([f[1] for f in feet])[None]
        dirs = np.broadcast_to(u, on_a.shape)
        bodies = (int(hull.body_a[h]), int(hull.body_b[h]))
        s = len(feet)
        ja = one.directional_jacobian(np.full(s, bodies[0]), on_a, dirs)[0]
        jb = one.directional_jacobian(np.full(s, bodies[1]), on_b, dirs)[0]
        out_pose += [k] * s
        out_row += [h] * s
        values += [f[2] - clearance for f in feet]
        jac.append(ja - jb)
    jacobian = np.concatenate(jac) if jac else np.zeros((0, nv))
    return HullRowPieces(np.array(out_pose, dtype=int), np.array(out_row, dtype=int),
                         np.array(values, dtype=float), jacobian)
