r"""The exact second derivative of a self row on convex pieces, for the closest features.

A row of :mod:`calib_oed.feasibility.hulls` is :math:`g = d(P, Q) - m_d`, the
distance of two convex pieces on bodies :math:`A` and :math:`B`. Where the
closest features do not switch (the generic case, away from a set of measure
zero), :math:`d` is the distance of those *features*, each fixed on its body:

- **point / segment against point / segment** (a vertex or an edge of a polytope
  piece; a sphere's centre, a capsule's or a cylinder side's axis, with the
  radius :math:`r`): :math:`d = d(S_A, S_B) - r_A - r_B`, the segment distance
  whose Hessian, witness motion included, is
  :func:`calib_oed.feasibility.curvature.segment_distance_derivatives`;
- **a circle (a cylinder's rim) against a point, segment or circle**:
  :math:`d = \min_z \lVert x_A(z_A) - x_B(z_B)\rVert - r_A - r_B` over the curve
  parameters (the angle on a circle, :math:`t \in [0, 1]` on a segment), solved by
  Newton from coal's witnesses; its Hessian is that of the segments with the
  curves' own second derivatives in :math:`A = e_z^\top e_z + e^\top e_{zz}` and
  :math:`G = E^\top e_z + (\partial_q e_z)^\top e` (docs/feasibility.md §7);
- **face against point** (a polytope face, a cylinder cap; a vertex or a sphere
  centre): with the face's outward unit normal :math:`n` and a point :math:`x`
  of it, both fixed on the face's body, and the point :math:`p` on the other,

  .. math::
      d = n^\top (p - x) - r,\qquad
      \nabla^2 d = n^\top(\partial^2 p - \partial^2 x) + N^\top (J_p - J_x)
      + (J_p - J_x)^\top N + (p - x)^\top \partial^2 n,

  :math:`N = \partial n/\partial q` (columns :math:`\omega_i \times n`, the normal
  turning with its body) and :math:`\partial^2 n` the second derivative of a free
  vector (:mod:`calib_oed.feasibility.curvature`); against a circle, the same at its
  deepest point :math:`c(\theta^*)` minus :math:`g g^\top / (n^\top c_{\theta\theta})`,
  :math:`g = \partial_q (n^\top c_\theta)` (the point sliding along the rim).

The features are read from the pieces and coal's witness: the support set of a
piece in the direction of the other (vertices within :data:`TOL` of the
supporting plane: one is a vertex, collinear ones an edge, others a face), a
sphere's centre, a capsule's axis or end, a cylinder's side (direction normal to
its axis), cap (along it) or rim (otherwise). The feature distance must equal coal's distance to
:data:`TOL`. Where no such pair is found (an edge against a face or two faces,
parallel and not generic; overlapping pieces, :math:`d \le 0`)
:func:`feature_hessian` returns ``None`` and the row keeps the tangent-plane model
of :mod:`calib_oed.feasibility.hulls`. Lengths [m].
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import coal
import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.curvature import (
    body_points,
    point_hessian_along,
    segment_distance_derivatives,
)

__all__ = ["Feature", "feature_hessian", "support_feature"]

#: Tolerance [m] of the support set and of the feature distance against coal's (and,
#: as a direction cosine, of a cylinder's side or cap).
TOL = 1e-7


@dataclass(frozen=True)
class Feature:
    """A closest feature of a piece, in its body frame.

    Attributes:
        kind: ``"point"``, ``"segment"``, ``"face"`` or ``"circle"`` (a cylinder's rim).
        points: The point (1, 3), the segment's end points (2, 3), a point of the face or the
            circle's centre (1, 3) [m].
        radius: Rounding [m] (sphere, capsule, cylinder side; 0 for a polytope).
        normal: The face's outward unit normal, or the circle's axis (3,).
        circle: The circle's radius [m].
    """

    kind: str
    points: np.ndarray
    radius: float = 0.0
    normal: np.ndarray | None = None
    circle: float = 0.0


def _vertices(shape) -> np.ndarray | None:
    if isinstance(shape, coal.ConvexBase):
        return np.asarray(shape.points(), dtype=float).reshape(-1, 3)
    if isinstance(shape, coal.Box):
        return np.array(list(itertools.product(*[(-h, h) for h in shape.halfSide])), dtype=float)
    return None


def support_feature(shape, rotation: np.ndarray, translation: np.ndarray, direction: np.ndarray):
    """The feature of a piece (coal ``shape`` placed by ``rotation``, ``translation`` in its body
    frame) farthest along the unit ``direction`` (body frame): a :class:`Feature` in the body
    frame, or ``None`` (no generic feature: a cylinder's rim, an unsupported shape)."""
    m = rotation.T @ direction  # the piece's own frame

    def body(points):
        return np.asarray(points, dtype=float).reshape(-1, 3) @ rotation.T + translation

    if isinstance(shape, coal.Sphere):
        return Feature("point", body([0.0, 0.0, 0.0]), float(shape.radius))
    if isinstance(shape, (coal.Capsule, coal.Cylinder)):
        h, r = float(shape.halfLength), float(shape.radius)
        axis = body([[0.0, 0.0, -h], [0.0, 0.0, h]])
        if abs(m[2]) < TOL:  # the side: the axis, rounded
            return Feature("segment", axis, r)
        if isinstance(shape, coal.Capsule):  # an end cap: a ball about the axis end
            return Feature("point", axis[1 if m[2] > 0 else 0][None], r)
        if abs(m[2]) > 1.0 - TOL:  # a cylinder's cap: a face
            sign = 1.0 if m[2] > 0 else -1.0
            return Feature("face", axis[1 if sign > 0 else 0][None], 0.0, rotation @ np.array([0.0, 0.0, sign]))
        sign = 1.0 if m[2] > 0 else -1.0  # the rim: a circle about the axis, at the cap on the far side
        return Feature("circle", axis[1 if sign > 0 else 0][None], 0.0, rotation @ np.array([0.0, 0.0, 1.0]), r)
    verts = _vertices(shape)
    if verts is None:
        return None
    s = verts @ m
    top = verts[s >= s.max() - TOL]
    if len(top) == 1:
        return Feature("point", body(top))
    centred = top - top.mean(axis=0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    if len(top) == 2 or sv[1] < TOL * max(1.0, len(top)):
        t = centred @ vt[0]
        return Feature("segment", body(top[[np.argmin(t), np.argmax(t)]]))
    normal = vt[2] if vt[2] @ m > 0 else -vt[2]
    return Feature("face", body(top.mean(axis=0)), 0.0, rotation @ normal)


def _points(states: BodyStates, pose: int, body: int, local: np.ndarray):
    """World points (k, 3), Jacobians (k, 3, nv) and angular Jacobians (k, 3, nv) of ``local`` (k, 3)."""
    k = len(local)
    return body_points(states, np.full(k, pose), np.full(k, body), local)


def _face_point(states, pose, face_body, face: Feature, point_body, point: Feature, dist: float):
    r""":math:`\nabla^2 d` of :math:`d = n^\top(p - x) - r` (module docstring), or ``None`` if
    its value is not coal's ``dist``."""
    rot = states.rotation[pose, face_body]
    n = rot @ face.normal
    local = point.points
    if point.kind == "circle":  # the rim's point deepest towards the face: c(theta*), theta held below
        e1, e2 = _circle_axes(point.normal)
        n_local = states.rotation[pose, point_body].T @ n
        c, s = -(n_local @ e1), -(n_local @ e2)
        if np.hypot(c, s) < TOL:
            return None  # the rim parallel to the face
        theta = np.arctan2(s, c)
        local = point.points + point.circle * (np.cos(theta) * e1 + np.sin(theta) * e2)
    x, jx, ox = _points(states, pose, face_body, face.points)
    p, jp, op = _points(states, pose, point_body, local)
    gap = p[0] - x[0]
    if abs(n @ gap - point.radius - dist) > TOL:
        return None
    dn = np.cross(ox[0].T, n).T[None]  # (1, 3, nv): omega_i x n
    e = jp[0] - jx[0]
    cross = dn[0].T @ e
    hess = (point_hessian_along(op, jp, n[None])[0] - point_hessian_along(ox, jx, n[None])[0]
            + cross + cross.T + point_hessian_along(ox, dn, gap[None])[0])
    if point.kind == "circle":  # theta* moves: minus G G^T / A (sensitivity of the minimum over theta)
        rp = states.rotation[pose, point_body]
        xt = rp @ (point.circle * (-np.sin(theta) * e1 + np.cos(theta) * e2))  # dc/dtheta
        xtt = -(p[0] - (rp @ point.points[0] + states.translation[pose, point_body]))
        g = dn[0].T @ xt + np.cross(op[0].T, xt) @ n  # d/dq (n^T dc/dtheta)
        hess -= np.outer(g, g) / (n @ xtt)
    return hess


def _circle_axes(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit ``axis`` to a right-handed frame."""
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


class _Curve:
    """A point, segment or circle on a body, as :math:`x(z)` with 0 or 1 parameter (body frame)."""

    def __init__(self, feature: Feature):
        self.f = feature
        self.n = 0 if feature.kind == "point" else 1
        if feature.kind == "circle":
            self.e1, self.e2 = _circle_axes(feature.normal)

    def at(self, z: float):
        """x, dx/dz, d2x/dz2 in the body frame; the last two as free vectors."""
        f = self.f
        if f.kind == "point":
            return f.points[0], np.zeros(3), np.zeros(3)
        if f.kind == "segment":
            d = f.points[1] - f.points[0]
            return f.points[0] + z * d, d, np.zeros(3)
        r = f.circle * (np.cos(z) * self.e1 + np.sin(z) * self.e2)
        return f.points[0] + r, f.circle * (-np.sin(z) * self.e1 + np.cos(z) * self.e2), -r

    def start(self, w: np.ndarray) -> float:
        """The parameter of the point nearest ``w`` (body frame)."""
        f = self.f
        if f.kind == "segment":
            d = f.points[1] - f.points[0]
            return float(np.clip((w - f.points[0]) @ d / max(d @ d, 1e-300), 0.0, 1.0))
        if f.kind == "circle":
            v = w - f.points[0]
            return float(np.arctan2(v @ self.e2, v @ self.e1))
        return 0.0


def _curves(states, pose, body_a, fa, body_b, fb, dist, witness=None):
    r""":math:`\nabla^2 d` of :math:`d = \min_z \lVert x_A(z_A) - x_B(z_B)\rVert - r_A - r_B` for
    points, segments and circles (a rim): the value function's Hessian with the Schur term of
    the free parameters, as for two segments (docs/feasibility.md §7)."""
    ca, cb = _Curve(fa), _Curve(fb)
    ra, rb = states.rotation[pose, body_a], states.rotation[pose, body_b]
    ta, tb = states.translation[pose, body_a], states.translation[pose, body_b]
    # Newton on phi(z) = |x_A(z_A) - x_B(z_B)|^2 / 2 from coal's witnesses (world), or else from
    # the points nearest the other feature's centre
    wa, wb = witness if witness is not None else (rb @ cb.f.points.mean(axis=0) + tb,
                                                   ra @ ca.f.points.mean(axis=0) + ta)
    z = np.array([ca.start(ra.T @ (wa - ta)), cb.start(rb.T @ (wb - tb))])
    free = np.array([ca.n == 1, cb.n == 1])
    for _ in range(30):
        (xa, da, dda), (xb, db, ddb) = ca.at(z[0]), cb.at(z[1])
        e = ra @ xa + ta - rb @ xb - tb
        ez = np.stack([ra @ da, -(rb @ db)], axis=1)
        grad = ez.T @ e
        hess = ez.T @ ez + np.diag([e @ (ra @ dda), -(e @ (rb @ ddb))])
        for k, c in enumerate((ca, cb)):  # a segment's end: clamped while the slope points out
            free[k] = c.n == 1 and not (c.f.kind == "segment" and ((z[k] <= 0 and grad[k] > 0)
                                                                  or (z[k] >= 1 and grad[k] < 0)))
        if not free.any():
            break
        f = np.flatnonzero(free)
        try:
            step = -np.linalg.solve(hess[np.ix_(f, f)], grad[f])
        except np.linalg.LinAlgError:
            return None  # parallel or coaxial: no isolated minimum
        z[f] += step
        for k, c in enumerate((ca, cb)):
            if c.f.kind == "segment":
                z[k] = min(max(z[k], 0.0), 1.0)
        if np.abs(step).max() < 1e-14:
            break
    (xa, da, dda), (xb, db, ddb) = ca.at(z[0]), cb.at(z[1])
    pa, ja, oa = _points(states, pose, body_a, xa[None])
    pb, jb, ob = _points(states, pose, body_b, xb[None])
    e = pa[0] - pb[0]
    d = float(np.linalg.norm(e))
    if abs(d - fa.radius - fb.radius - dist) > TOL or d < TOL:
        return None
    u = e / d
    big_e = ja[0] - jb[0]
    out = point_hessian_along(oa, ja, u[None])[0] - point_hessian_along(ob, jb, u[None])[0]
    ge = big_e.T @ u
    out += (big_e.T @ big_e - np.outer(ge, ge)) / d
    f = np.flatnonzero(free)
    if f.size:
        vz = [ra @ da, -(rb @ db)]
        omega = [oa[0], ob[0]]
        cols = [big_e.T @ vz[k] + np.cross(omega[k].T, vz[k]) @ e for k in range(2)]
        ez = np.stack(vz, axis=1)
        a = ez.T @ ez + np.diag([e @ (ra @ dda), -(e @ (rb @ ddb))])
        g = np.stack(cols, axis=1)[:, f]
        try:
            out -= g @ np.linalg.solve(a[np.ix_(f, f)], g.T) / d
        except np.linalg.LinAlgError:
            return None
    return out


def feature_hessian(states: BodyStates, pose: int, body_a: int, fa: Feature, body_b: int, fb: Feature,
                    dist: float, witness: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray | None:
    """The exact Hessian (nv, nv) of the distance of features ``fa`` (on ``body_a``) and ``fb``
    (on ``body_b``) at ``pose`` of ``states`` (with Jacobians), whose value must be coal's
    ``dist`` [m] (> 0); ``None`` for a pair without a formula (edge or face against a face).
    ``witness``: coal's witness points (world) [m], where a circle's or segment's parameter starts."""
    if dist <= 0.0:
        return None
    if fa.kind == "face" and fb.kind in ("point", "circle"):
        return _face_point(states, pose, body_a, fa, body_b, fb, dist)
    if fb.kind == "face" and fa.kind in ("point", "circle"):
        return _face_point(states, pose, body_b, fb, body_a, fa, dist)
    if "face" in (fa.kind, fb.kind):
        return None
    if "circle" in (fa.kind, fb.kind):
        return _curves(states, pose, body_a, fa, body_b, fb, dist, witness)
    ends = [np.repeat(f.points, 3 - len(f.points), axis=0) for f in (fa, fb)]  # a point: a = b
    x, jx, om = (np.concatenate(z) for z in zip(_points(states, pose, body_a, ends[0]),
                                                _points(states, pose, body_b, ends[1]), strict=True))
    nv = jx.shape[-1]

    def hess_along(u):
        return point_hessian_along(om, jx, np.repeat(u, 4, axis=0)).reshape(1, 4, nv, nv)

    d, _, hess, _ = segment_distance_derivatives(x[None], jx[None], hess_along)
    if abs(d[0] - fa.radius - fb.radius - dist) > TOL:
        return None
    return hess[0]
