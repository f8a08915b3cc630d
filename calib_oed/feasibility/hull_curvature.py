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
from calib_oed.model.kinematics import cross

__all__ = ["Feature", "curve_hessians", "feature_hessian", "feature_hessians", "support_feature"]

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
    e1 = cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, cross(axis, e1)


class _Curves:
    r"""Points, segments and circles (rims) on bodies, one per row (K,): :math:`x(z)` with 0 or 1
    parameter (body frame): a point; :math:`p_0 + z\,(p_1 - p_0)`, :math:`z \in [0, 1]`; a circle
    of radius :math:`\rho` about :math:`p_0`, :math:`p_0 + \rho(\cos z\,e_1 + \sin z\,e_2)`."""

    def __init__(self, features):
        k = len(features)
        self.p, self.d, self.e1, self.e2 = (np.zeros((k, 3)) for _ in range(4))
        self.rho = np.zeros((k, 1))
        self.segment = np.array([f.kind == "segment" for f in features], dtype=bool)
        self.circle = np.array([f.kind == "circle" for f in features], dtype=bool)
        self.param = self.segment | self.circle
        self.radius = np.array([f.radius for f in features], dtype=float)
        for i, f in enumerate(features):
            self.p[i] = f.points[0]
            if f.kind == "segment":
                self.d[i] = f.points[1] - f.points[0]
            elif f.kind == "circle":
                self.e1[i], self.e2[i] = _circle_axes(f.normal)
                self.rho[i] = f.circle

    def at(self, z: np.ndarray, rows=slice(None)):
        """x, dx/dz, d2x/dz2 (K, 3) each at parameters ``z`` (K,) of ``rows``; the last two free vectors."""
        c, s = np.cos(z)[:, None], np.sin(z)[:, None]
        seg, circ, rho = self.segment[rows, None], self.circle[rows, None], self.rho[rows]
        p, d, e1, e2 = self.p[rows], self.d[rows], self.e1[rows], self.e2[rows]
        r = rho * (c * e1 + s * e2)
        x = np.where(seg, p + z[:, None] * d, np.where(circ, p + r, p))
        dx = np.where(seg, d, np.where(circ, rho * (-s * e1 + c * e2), 0.0))
        return x, dx, np.where(circ, -r, 0.0)

    def start(self, w: np.ndarray) -> np.ndarray:
        """The parameters (K,) of the points nearest ``w`` (K, 3) (body frame)."""
        v = w - self.p
        seg = np.clip(_dot(v, self.d) / np.maximum(_dot(self.d, self.d), 1e-300), 0.0, 1.0)
        return np.where(self.segment, seg, np.where(self.circle, np.arctan2(_dot(v, self.e2), _dot(v, self.e1)), 0.0))


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products (K,) of (K, n) arrays (as ``a[k] @ b[k]``, bit for bit)."""
    return (a[:, None, :] @ b[:, :, None])[:, 0, 0]


def _mv(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise products (K, n) of matrices (K, n, p) and vectors (K, p) (as ``m[k] @ v[k]``)."""
    return (m @ v[:, :, None])[:, :, 0]


def _masked_solve(m: np.ndarray, b: np.ndarray, free: np.ndarray):
    r"""Solve the free block of ``m`` (K, 2, 2) for ``b`` (K, 2, c) (zero where not free), the
    identity on the rest; ``(x, ok)``, ``ok`` False where the free block is singular."""
    both = free[:, :, None] & free[:, None, :]
    m = np.where(both, m, np.eye(2)[None])
    try:
        return np.linalg.solve(m, b), np.ones(len(m), dtype=bool)
    except np.linalg.LinAlgError:  # rare (parallel or coaxial features): one by one
        x, ok = np.zeros_like(b), np.ones(len(m), dtype=bool)
        for k in range(len(m)):
            try:
                x[k] = np.linalg.solve(m[k], b[k])
            except np.linalg.LinAlgError:
                ok[k] = False
        return x, ok


def curve_hessians(states: BodyStates, pose, body_a, fa, body_b, fb, dist, witness):
    r""":math:`\nabla^2 d` (K, nv, nv) of :math:`d = \min_z \lVert x_A(z_A) - x_B(z_B)\rVert - r_A - r_B`
    for points, segments and circles (a rim), one pair of features per row, and ``ok`` (K,): the
    value function's Hessian with the Schur term of the free parameters, as for two segments
    (docs/feasibility.md §7), where its value is coal's ``dist`` [m] (K,), else not ``ok``.

    Newton on :math:`\varphi(z) = \lVert x_A(z_A) - x_B(z_B)\rVert^2 / 2` from coal's ``witness``
    points (K, 2, 3) (world), every row at once; a row stops when its step is below 1e-14, or no
    parameter is free (a segment's end, clamped while the slope points out), or after 30 steps.
    Every row's arithmetic is that of the row alone, in the same order (the same bits whatever
    rows share the batch).
    """
    pose, body_a, body_b = (np.asarray(x, dtype=int) for x in (pose, body_a, body_b))
    ca, cb = _Curves(fa), _Curves(fb)
    ra, rb = states.rotation[pose, body_a], states.rotation[pose, body_b]
    ta, tb = states.translation[pose, body_a], states.translation[pose, body_b]
    k_rows = len(pose)
    z = np.stack([ca.start(_mv(np.swapaxes(ra, 1, 2), witness[:, 0] - ta)),
                  cb.start(_mv(np.swapaxes(rb, 1, 2), witness[:, 1] - tb))], axis=1)
    has = np.stack([ca.param, cb.param], axis=1)
    seg = np.stack([ca.segment, cb.segment], axis=1)
    free, ok, active = has.copy(), np.ones(k_rows, dtype=bool), np.ones(k_rows, dtype=bool)

    def normal_matrix(rows, e, va, vb, dda, ddb):
        """ez, ez^T ez + diag(e^T R_a x_a'', -e^T R_b x_b'') of ``rows``."""
        ez = np.stack([va, vb], axis=2)
        diag = np.zeros((len(e), 2, 2))
        diag[:, 0, 0], diag[:, 1, 1] = _dot(e, _mv(ra[rows], dda)), -_dot(e, _mv(rb[rows], ddb))
        return ez, np.swapaxes(ez, 1, 2) @ ez + diag

    for _ in range(30):
        rows = np.flatnonzero(active)
        if not rows.size:
            break
        (xa, da, dda), (xb, db, ddb) = ca.at(z[rows, 0], rows), cb.at(z[rows, 1], rows)
        e = _mv(ra[rows], xa) + ta[rows] - _mv(rb[rows], xb) - tb[rows]
        ez, hess = normal_matrix(rows, e, _mv(ra[rows], da), -_mv(rb[rows], db), dda, ddb)
        grad = _mv(np.swapaxes(ez, 1, 2), e)
        zr = z[rows]
        fr = has[rows] & ~(seg[rows] & (((zr <= 0) & (grad > 0)) | ((zr >= 1) & (grad < 0))))
        free[rows] = fr
        stop = ~fr.any(axis=1)
        active[rows[stop]] = False
        rows, fr, hess, grad = rows[~stop], fr[~stop], hess[~stop], grad[~stop]
        step, good = _masked_solve(hess, np.where(fr, grad, 0.0)[:, :, None], fr)
        ok[rows[~good]] = active[rows[~good]] = False
        rows, fr, step = rows[good], fr[good], -step[good, :, 0]
        z[rows] = np.where(fr, z[rows] + step, z[rows])
        z[rows] = np.where(seg[rows], np.clip(z[rows], 0.0, 1.0), z[rows])
        active[rows[np.where(fr, np.abs(step), 0.0).max(axis=1) < 1e-14]] = False
    (xa, da, dda), (xb, db, ddb) = ca.at(z[:, 0]), cb.at(z[:, 1])
    pa, ja, oa = body_points(states, pose, body_a, xa)
    pb, jb, ob = body_points(states, pose, body_b, xb)
    e = pa - pb
    d = np.sqrt(_dot(e, e))
    ok &= ~((np.abs(d - ca.radius - cb.radius - dist) > TOL) | (d < TOL))
    d = np.where(ok, d, 1.0)
    u = e / d[:, None]
    big_e = ja - jb
    big_t = np.swapaxes(big_e, 1, 2)
    out = point_hessian_along(oa, ja, u) - point_hessian_along(ob, jb, u)
    ge = _mv(big_t, u)
    out += (big_t @ big_e - ge[:, :, None] * ge[:, None, :]) / d[:, None, None]
    some = np.flatnonzero(ok & free.any(axis=1))
    if some.size:
        vz = (_mv(ra[some], da[some]), -_mv(rb[some], db[some]))
        cols = [_mv(big_t[some], v) + _mv(cross(np.swapaxes(om[some], 1, 2), v[:, None, :]), e[some])
                for v, om in zip(vz, (oa, ob), strict=True)]
        _, a = normal_matrix(some, e[some], vz[0], vz[1], dda[some], ddb[some])
        g = np.where(free[some, None, :], np.stack(cols, axis=2), 0.0)  # (k, nv, 2)
        x, good = _masked_solve(a, np.swapaxes(g, 1, 2), free[some])
        out[some] -= (g @ x) / d[some, None, None]
        ok[some[~good]] = False
    return out, ok


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
        if witness is None:  # the points nearest the other feature's centre
            witness = tuple(states.rotation[pose, body] @ f.points.mean(axis=0) + states.translation[pose, body]
                            for body, f in ((body_b, fb), (body_a, fa)))
        hess, ok = curve_hessians(states, [pose], [body_a], [fa], [body_b], [fb], np.array([dist]),
                                  np.array(witness)[None])
        return hess[0] if ok[0] else None
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


def feature_hessians(states: BodyStates, pose, body_a, fa, body_b, fb, dist, witness):
    """:func:`feature_hessian` of K rows, (K, nv, nv), and which have one (K,): the pairs with a
    circle (a rim) in one batch (:func:`curve_hessians`), the others one by one.
    ``witness``: coal's witness points (K, 2, 3) (world) [m]."""
    k_rows, nv = len(pose), states.jacobian.shape[-1]
    out, ok = np.zeros((k_rows, nv, nv)), np.zeros(k_rows, dtype=bool)
    kinds = [(a.kind, b.kind) for a, b in zip(fa, fb, strict=True)]
    curves = np.array([k for k, pair in enumerate(kinds) if dist[k] > 0.0 and "circle" in pair
                       and "face" not in pair], dtype=int)
    for k in np.setdiff1d(np.arange(k_rows), curves):
        hess = feature_hessian(states, int(pose[k]), int(body_a[k]), fa[k], int(body_b[k]), fb[k],
                               float(dist[k]), (witness[k, 0], witness[k, 1]))
        if hess is not None:
            out[k], ok[k] = hess, True
    if curves.size:
        hess, good = curve_hessians(states, np.asarray(pose)[curves], np.asarray(body_a)[curves],
                                    [fa[k] for k in curves], np.asarray(body_b)[curves],
                                    [fb[k] for k in curves], np.asarray(dist)[curves], witness[curves])
        out[curves[good]], ok[curves[good]] = hess[good], True
    return out, ok
