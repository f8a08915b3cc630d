r"""Second derivatives of the feasibility rows: the constraint part of the Lagrangian Hessian.

For a design's multipliers :math:`\lambda_{ji}` (pose :math:`j`, row :math:`i`)
:func:`lagrangian_hessian` returns, per pose,
:math:`H_j = \sum_i \lambda_{ji}\,\partial^2 g_{ji}/\partial q_j^2` (nq, nq);
the rows of a pose depend on that pose only, so the design's block is
block diagonal. Only rows with :math:`\lambda_{ji} \ne 0` are evaluated (at a
design optimum a handful per pose). Derivations in ``docs/feasibility.md`` §7.

**Points.** A point :math:`x` fixed on a body of a chain of 1-DoF joints has
point-Jacobian columns :math:`c_i = J^{lin}_i + \omega_i\times(x - t)` and

.. math::
    \frac{\partial^2 x}{\partial q_i\,\partial q_j} = \omega_{\min(i,j)} \times c_{\max(i,j)}(x),

:math:`\omega_i` the angular columns of the body's ``LOCAL_WORLD_ALIGNED``
Jacobian (zero for prismatic joints and joints off the body's chain). A free
vector (the tool axis :math:`z`) is the same with :math:`c_i = \omega_i\times z`.

**Segment distance.** :math:`d = \sqrt{\varphi^*}`,
:math:`\varphi^* = \min_{(s,t)\in[0,1]^2}\lVert e(s,t,q)\rVert^2`,
:math:`e = x(s) - y(t)`. With the parameters that are strictly inside (0, 1)
free and the others clamped (the active set is locally constant away from
regime switches), the value function's Hessian is the Schur complement
(sensitivity of a parametric QP):

.. math::
    \nabla^2 d = u^\top\!\partial^2 e + \frac{E^\top(I - uu^\top)E}{d}
    - \frac{G_F A_{FF}^{-1} G_F^\top}{d},

:math:`u = e/d`, :math:`E = \partial e/\partial q` at fixed :math:`(s, t)`,
:math:`A = \begin{bmatrix} d_1^\top d_1 & -d_1^\top d_2 \\ \cdot & d_2^\top d_2\end{bmatrix}`,
:math:`G = [\,E^\top d_1 + D_1^\top e,\; -E^\top d_2 - D_2^\top e\,]`,
:math:`D_k = \partial d_k/\partial q` (the witness points' motion along the
segments). Interior-interior: :math:`F = \{s, t\}`; edge: one parameter clamped;
vertex: both clamped, no Schur term.

**Solids** (:mod:`calib_oed.feasibility.solids`). A box row whose witness is an
end point :math:`x` of the segment is the distance of a point to the box,
:math:`d = \lVert P_m(x_O - \mathrm{clamp}(x_O))\rVert` over the clamped
coordinates :math:`m`:
:math:`\nabla^2 d = u^\top\partial^2 x + J_x^\top(P - uu^\top)J_x/d`,
:math:`P = R_{W,O}\,\mathrm{diag}(m)\,R_{W,O}^\top` (a face: :math:`P = uu^\top`,
no second term); an edge witness is the segment distance above with the
world-fixed edge as second segment, and so is a cylinder's side (its axis as
second segment). All exact. Meshes, cylinder caps and rims, and axes that
meet a box (coal rows) use the **tangent-plane model**: the solid is
replaced by the half-space its separating plane bounds at the witness
(normal :math:`u`), the witness parameter :math:`s` held:
:math:`\nabla^2 g \approx u^\top\big((1-s)\,\partial^2 a + s\,\partial^2 b\big)`.
It is exact where the witness on the solid lies inside a flat face and the
segment's witness is an end point (a mesh face, a cylinder cap); it omits the
solid's own curvature at edges, vertices and the cylinder's rim (a term
:math:`J^\top(I - uu^\top)J/\rho`, :math:`\rho` the radius of curvature
plus the distance), so there it is the Hessian of a valid local model, not of
the row. Self rows on convex pieces of two links (:mod:`calib_oed.feasibility.hulls`)
use the same model with both witness points moving.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from calib_oed.feasibility.bodies import BodyStates, compute_body_states
from calib_oed.feasibility.segments import EPS, closest_parameters
from calib_oed.feasibility.solids import EDGE, END_B

#: Distances [m] below which the curvature of the norm is evaluated at this floor
#: (contact; the gradient row uses the same floor).
TINY = 1e-12


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along axis 1 of broadcast arrays, by components (cheaper than ``np.cross``)."""
    a0, a1, a2, b0, b1, b2 = a[:, 0], a[:, 1], a[:, 2], b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _upper(m: np.ndarray) -> np.ndarray:
    """Entry ``[i, j]`` of ``m`` (..., nv, nv) for i <= j mirrored below the diagonal."""
    upper = np.triu(np.ones(m.shape[-2:], dtype=bool))
    return np.where(upper, m, np.swapaxes(m, -1, -2))


def point_hessian(omega: np.ndarray, jac: np.ndarray) -> np.ndarray:
    r""":math:`\partial^2 x/\partial q^2` (K, 3, nv, nv) from the body's angular Jacobian
    ``omega`` (K, 3, nv) and the point's Jacobian ``jac`` (K, 3, nv):
    entry ``[:, i, j]`` is :math:`\omega_{\min(i,j)}\times c_{\max(i,j)}`."""
    return _upper(_cross(omega[:, :, :, None], jac[:, :, None, :]))


def point_hessian_along(omega: np.ndarray, jac: np.ndarray, u: np.ndarray) -> np.ndarray:
    r""":math:`u^\top\partial^2 x/\partial q^2` (K, nv, nv) for directions ``u`` (K, 3), without the
    full tensor: :math:`u^\top(\omega_i\times c_j) = \omega_i^\top(c_j\times u)` for i <= j."""
    return _upper(np.swapaxes(omega, 1, 2) @ _cross(jac, u[:, :, None]))


def _along(u: np.ndarray, tensor: np.ndarray) -> np.ndarray:
    """Contract directions u (K, 3) with (K, 3, ...)."""
    if tensor.ndim == 3:
        return (u[:, None, :] @ tensor)[:, 0]
    return np.einsum("ki,ki...->k...", u, tensor)


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, :, None] * b[:, None, :]


def _gram(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^T b per entry: (K, 3, nv) x (K, 3, nv) -> (K, nv, nv)."""
    return np.swapaxes(a, 1, 2) @ b


def segment_distance_derivatives(points: np.ndarray, jac: np.ndarray, hess_along: Callable):
    r"""Distance of segments ``[a1, b1]``, ``[a2, b2]`` whose end points move with q.

    Args:
        points: End points ``a1, b1, a2, b2`` [m], (K, 4, 3).
        jac: Their Jacobians, (K, 4, 3, nv).
        hess_along: ``u`` (K, 3) -> (K, 4, nv, nv), :math:`u^\top\partial^2 p/\partial q^2`
            of each end point (e.g. ``lambda u: np.einsum("ki,kpivw->kpvw", u, hess)``).

    Returns:
        ``(d, grad, hess, free)``: distance (K,), gradient (K, nv), Hessian
        (K, nv, nv) and which of ``(s, t)`` are free (strictly inside (0, 1)), (K, 2).
        A clamped parameter (0 or 1, a point segment, or the ``s = 0`` of
        parallel segments) is held fixed: the derivatives are those of that branch.
    """
    a1, b1, a2, b2 = (points[:, k] for k in range(4))
    s, t = closest_parameters(a1, b1, a2, b2)
    wts = np.stack([1.0 - s, s, t - 1.0, -t], axis=1)
    e = np.einsum("kp,kpi->ki", wts, points)
    dist = np.linalg.norm(e, axis=1)
    dsafe = np.maximum(dist, TINY)
    u = e / dsafe[:, None]
    big_e = np.einsum("kp,kpiv->kiv", wts, jac)
    grad = _along(u, big_e)
    out = np.einsum("kp,kpvw->kvw", wts, hess_along(u))
    out += (_gram(big_e, big_e) - _outer(grad, grad)) / dsafe[:, None, None]
    d1, d2 = b1 - a1, b2 - a2
    g_s = _along(d1, big_e) + _along(e, jac[:, 1] - jac[:, 0])
    g_t = -_along(d2, big_e) - _along(e, jac[:, 3] - jac[:, 2])
    aa, bb, ee = (np.einsum("ki,ki->k", x, y) for x, y in ((d1, d1), (d1, d2), (d2, d2)))
    fs = (aa > EPS) & (s > 0.0) & (s < 1.0)
    ft = (ee > EPS) & (t > 0.0) & (t < 1.0)
    if np.any(fs | ft):
        # A_FF^{-1} on the free block, identity on the clamped one (their G columns are zero)
        a11, a22 = np.where(fs, aa, 1.0), np.where(ft, ee, 1.0)
        a12 = np.where(fs & ft, -bb, 0.0)
        det = a11 * a22 - a12 * a12
        gs, gt = g_s * fs[:, None], g_t * ft[:, None]
        schur = (a22[:, None, None] * _outer(gs, gs) + a11[:, None, None] * _outer(gt, gt)
                 - a12[:, None, None] * (_outer(gs, gt) + _outer(gt, gs))) / det[:, None, None]
        out -= schur / dsafe[:, None, None]
    return dist, grad, out, np.stack([fs, ft], axis=1)


def incidence_derivatives(z, dz, hz, c, dc, hc, target):
    r""":math:`z^\top u`, :math:`u = (t - c)/\lVert t - c\rVert`, with gradient and Hessian.

    Args:
        z, dz, hz: The unit axis (K, 3), its Jacobian (K, 3, nv) and second derivative (K, 3, nv, nv).
        c, dc, hc: The point, the same.
        target: The fixed target :math:`t` (3,) (the tracker).

    Returns:
        ``(value, grad, hess)``, (K,), (K, nv), (K, nv, nv).
    """
    y = target - c
    length = np.linalg.norm(y, axis=1)
    yh = y / length[:, None]
    inv = 1.0 / length[:, None, None]
    zy = np.einsum("ki,ki->k", z, yh)
    pz = z - zy[:, None] * yh  # P z, P = I - yh yh^T
    dy = -dc

    def proj(m):  # P m, m (K, 3, nv)
        return m - yh[:, :, None] * _along(yh, m)[:, None, :]

    grad = _along(yh, dz) + _along(pz, dy) / length[:, None]
    hess = _along(yh, hz) - _along(pz, hc) / length[:, None, None]
    cross = _gram(proj(dz), dy) * inv
    hess += cross + np.swapaxes(cross, 1, 2)
    zp, yv = _along(pz, dy), _along(yh, dy)
    hess -= (_outer(zp, yv) + _outer(yv, zp) + zy[:, None, None] * _gram(dy, proj(dy))) * inv**2
    return zy, grad, hess


def body_points(states: BodyStates, pose, body, local):
    """World points (K, 3), their Jacobians (K, 3, nv) and the bodies' angular
    Jacobians (K, 3, nv) of points ``local`` (K, 3) fixed on ``body`` at ``pose``."""
    rot, trans = states.rotation[pose, body], states.translation[pose, body]
    jac = states.jacobian[pose, body]
    x = np.einsum("kij,kj->ki", rot, local) + trans
    omega = jac[:, 3:]
    return x, jac[:, :3] + _cross(omega, (x - trans)[:, :, None]), omega


def _requests(model, pose, row, nq):
    """The points each curved row needs: ``(kind, index, pose, body, local)`` per group."""
    seg, robot = model.segments, model.robot
    tool = robot.model.frames[robot.tool_frame_id]
    k, p, ns = model.n_incidence, len(model.pairs), len(model.solid_pairs)
    r = row - 2 * nq
    out = []
    sel = np.flatnonzero((r >= 0) & (r < k))
    if sel.size:
        local = np.array([tool.placement.act(c) for c in model.reflector_offsets]).reshape(-1, 3)
        out.append(("incidence", sel, pose[sel], np.full(sel.size, tool.parentJoint), local[model.incidence_reflectors[r[sel]]]))
    sel = np.flatnonzero((r >= k) & (r < k + ns))
    if sel.size:  # two end points per solid row: a, b
        i = model.solid_pairs.pairs[r[sel] - k, 0]
        body = np.stack([seg.body_a[i], seg.body_b[i]], 1)
        local = np.stack([seg.a_local[i], seg.b_local[i]], 1)
        out.append(("solid", sel, np.repeat(pose[sel], 2), body.ravel(), local.reshape(-1, 3)))
    k += ns + len(model.hull_pairs)  # the hull rows (own path), then capsule and half-space rows
    sel = np.flatnonzero((r >= k) & (r < k + p))
    if sel.size:  # four end points per pair: a1, b1, a2, b2
        ij = model.pairs[r[sel] - k]
        body = np.stack([seg.body_a[ij[:, 0]], seg.body_b[ij[:, 0]], seg.body_a[ij[:, 1]], seg.body_b[ij[:, 1]]], 1)
        local = np.stack([seg.a_local[ij[:, 0]], seg.b_local[ij[:, 0]], seg.a_local[ij[:, 1]],
                          seg.b_local[ij[:, 1]]], 1)
        out.append(("pair", sel, np.repeat(pose[sel], 4), body.ravel(), local.reshape(-1, 3)))
    sel = np.flatnonzero(r >= k + p)
    if sel.size:  # rows (h, end) of half-space pair h, end 0 = a, 1 = b
        h, end = divmod(r[sel] - k - p, 2)
        i = model.halfspace_pairs[h, 0]
        body = np.where(end == 0, seg.body_a[i], seg.body_b[i])
        local = np.where((end == 0)[:, None], seg.a_local[i], seg.b_local[i])
        out.append(("halfspace", sel, pose[sel], body, local))
    return out


def _row_hessians(model, kind, states, pose, index, x, jx, omega):
    """Hessians (K, nv, nv) of one group's rows from their points."""
    if kind == "incidence":
        tool = model.robot.model.frames[model.robot.tool_frame_id]
        z = np.einsum("kij,kj->ki", states.rotation[pose, tool.parentJoint], model.reflector_axis_local[model.incidence_reflectors[index]])
        dz = _cross(omega, z[:, :, None])
        return incidence_derivatives(z, dz, point_hessian(omega, dz), x, jx, point_hessian(omega, jx),
                                     model.tracker_position)[2]
    if kind == "pair":
        nv = jx.shape[-1]

        def hess_along(u):
            return point_hessian_along(omega, jx, np.repeat(u, 4, axis=0)).reshape(-1, 4, nv, nv)

        return segment_distance_derivatives(x.reshape(-1, 4, 3), jx.reshape(-1, 4, 3, nv), hess_along)[2]
    if kind == "solid":
        return solid_hessians(model.solid_pairs, index - model.n_incidence, x.reshape(-1, 2, 3),
                              jx.reshape(-1, 2, 3, jx.shape[-1]), omega.reshape(-1, 2, 3, jx.shape[-1]))
    first = model.n_incidence + len(model.solid_pairs) + len(model.hull_pairs) + len(model.pairs)
    hs = model.halfspace_pairs[(index - first) // 2, 1]
    normal = np.array([model.cell.halfspaces[h].normal for h in hs]).reshape(-1, 3)
    return point_hessian_along(omega, jx, normal)


def solid_hessians(solids, pair: np.ndarray, x: np.ndarray, jx: np.ndarray, omega: np.ndarray) -> np.ndarray:
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


def lagrangian_hessian(model, q: np.ndarray, lam: np.ndarray, states: BodyStates | None = None) -> np.ndarray:
    r""":math:`H_j = \sum_i \lambda_{ji}\,\nabla^2 g_{ji}(q_j)`, (n, nq, nq).

    Args:
        model: The :class:`~calib_oed.feasibility.constraints.FeasibilityModel`.
        q: Configurations, (n, nq), validated.
        lam: Multipliers of *all* the model's rows, (n, m) (zero: row skipped).
        states: Body states of ``q`` with Jacobians, or ``None`` to compute them
            (then only at the poses with a non-zero multiplier on a curved row).
    """
    n, nq = q.shape
    out = np.zeros((n, nq, nq))
    lam = np.array(lam, dtype=float)
    lam[:, : 2 * nq] = 0.0  # joint rows are linear
    pose, row = np.nonzero(lam)
    if pose.size == 0:
        return out
    if states is None or states.jacobian is None:
        used, local_pose = np.unique(pose, return_inverse=True)
        states = compute_body_states(model.robot.model, q[used], jacobian=True)
    else:
        local_pose = pose
    first = 2 * nq + model.n_incidence + len(model.solid_pairs)
    hull = (row >= first) & (row < first + len(model.hull_pairs))
    if np.any(hull):  # convex-piece rows: the tangent-plane model of their own module
        sel = np.flatnonzero(hull)
        hess = model.hull_pairs.hessians(states, local_pose[sel], row[sel] - first)
        np.add.at(out, pose[sel], lam[pose[sel], row[sel], None, None] * hess)
        pose, row, local_pose = pose[~hull], row[~hull], local_pose[~hull]
        if pose.size == 0:
            return out
    groups = _requests(model, local_pose, row, nq)
    # every point of every group in one batch
    x, jx, omega = body_points(states, *(np.concatenate([g[m] for g in groups]) for m in (2, 3, 4)))
    start = 0
    for kind, sel, gpose, _, _ in groups:
        part = slice(start, start + gpose.size)
        start += gpose.size
        hess = _row_hessians(model, kind, states, local_pose[sel], row[sel] - 2 * nq,
                             x[part], jx[part], omega[part])
        np.add.at(out, pose[sel], lam[pose[sel], row[sel], None, None] * hess)
    return out
