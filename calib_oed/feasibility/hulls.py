r"""Self pairs checked on convex pieces of the collision geometry (coal), exact gradients.

A capsule around a short, fat or flat link part is loose (its round ends and
cross-section), and two links with few joints between them often stay within
a few centimetres of each other: their capsule rows reject most of the joint
space. For such link pairs the feasibility model uses one row

.. math::
    g = \min_{P \in \mathcal P_a,\ Q \in \mathcal P_b} d(P, Q) - m_d \ge 0 \quad [m]

over convex pieces :math:`\mathcal P_a, \mathcal P_b` of the two links,
:math:`d` coal's (signed) distance of two convex sets, :math:`m_d` the clearance margin.

**Pieces enclose the link.** A link whose collision geometry is all triangle
meshes is cut into ``slabs`` slabs (:data:`SLABS`) along the principal axis of
its vertices, and each slab's piece is the convex hull of the corners of the
triangles clipped to it (:func:`calib_oed.feasibility.link_fit.slab_points`):
it contains the slab's part of the link, so the pieces together enclose the
link as the capsules do (no false accept). The cuts are those of least total
hull volume among ``GRID * slabs - 1`` equally spaced candidates (:func:`_slab_cuts`);
a flat slab is thickened by :data:`THICKEN` so that its hull is a solid. A link of primitives (boxes,
cylinders, spheres, capsules: convex already) keeps them as its pieces (a mesh
among primitives becomes its convex hull).
Every piece has an enclosing capsule (``fit_capsule`` on its points or balls).

**Broad phase.** Per pose and link pair the piece pairs are visited in the
order of their capsule lower bound :math:`d(S_P, S_Q) - r_P - r_Q` and coal is
called until the next bound is at least :math:`\max(g^*, 0)`, :math:`g^*` the
smallest distance so far: the minimum is exact (a bound below zero may
under-estimate a penetration depth, so overlapping capsules are always evaluated).

**Gradient** (envelope theorem): with coal's witness points :math:`w_a` (fixed
on body :math:`a`) and :math:`w_b`, and the unit normal :math:`u` from
:math:`w_b` to :math:`w_a` (:math:`(w_a - w_b)/\lVert w_a - w_b\rVert` when
separated, minus coal's ``normal`` when overlapping, EPA),

.. math::
    \frac{\partial g}{\partial q} = u^\top (J_{w_a} - J_{w_b}),

:math:`J_w` the point Jacobians (:mod:`calib_oed.feasibility.bodies`). Exact
wherever the witness pair is unique and one piece pair is the closest; at a
switch between piece pairs or witness features it is one of the one-sided slopes.

**Curvature** (:func:`HullPairs.hessians`, the SQP's exact-Hessian path): exact
for the closest features of the two pieces (vertex, edge, face, sphere, a
cylinder's side, cap or rim: :mod:`calib_oed.feasibility.hull_curvature`); where
there is no generic feature pair (parallel edge or face against a face,
overlapping pieces) the *tangent-plane model*, the witness points held fixed on
their bodies and the normal held fixed,
:math:`\nabla^2 g \approx u^\top(\partial^2 w_a - \partial^2 w_b)`, symmetric and
finite, the Hessian of a valid local model of the row.

All lengths in [m].
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin
from scipy.spatial import ConvexHull, QhullError

from calib_oed.feasibility import fit_cache
from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.capsules import _local_balls, fit_capsule, link_names
from calib_oed.feasibility.curvature import body_points, point_hessian_along
from calib_oed.feasibility.hull_curvature import _vertices, feature_hessians, support_feature
from calib_oed.feasibility.hull_witness import HullWitness, WitnessMemo
from calib_oed.feasibility.link_fit import (
    LinkFitSettings,
    geometry_key,
    link_meshes,
    slab_partitions,
    slab_points,
)
from calib_oed.feasibility.segments import closest_parameters

__all__ = ["HullPairs", "LinkPieces", "link_pieces"]

#: Slabs per mesh link (measured: bench/bench_feasibility_mesh.py, docs/feasibility.md §3).
SLABS = 4
#: Candidate cut positions per slab (the cuts are chosen among ``GRID * slabs - 1`` positions).
GRID = 3


#: GJK's absolute duality-gap tolerance (coal's distance request); 1e-14 made GJK fail on kr16.
GJK_GAP = 1e-13
#: A signed distance [m] beyond this is a failed GJK/EPA call (coal returns -DBL_MAX).
GJK_FAILED = 1e3


@dataclass(frozen=True, eq=False)
class LinkPieces:
    """Convex pieces enclosing a link's collision geometry, in its body (joint) frame.

    Attributes:
        link: Link name.
        body: Joint index of the body carrying it.
        shapes: coal shapes (``coal.Convex`` hulls or the URDF primitives).
        rotation: Piece placements in the body frame, (k, 3, 3).
        translation: Their origins in the body frame [m], (k, 3).
        cap_a, cap_b: End points of each piece's enclosing capsule (body frame) [m], (k, 3).
        cap_r: Their radii [m], (k,).
    """

    link: str
    body: int
    shapes: tuple
    rotation: np.ndarray
    translation: np.ndarray
    cap_a: np.ndarray
    cap_b: np.ndarray
    cap_r: np.ndarray


#: Half side [m] of the cube put around each point of a flat piece (a slab holding only a flat
#: part of the mesh), so that its hull is a solid that still contains the part.
THICKEN = 1e-6


def _convex(points: np.ndarray):
    """coal's convex hull of ``points`` (m, 3) [m]; a flat set is thickened by :data:`THICKEN`."""
    if len(points) < 4 or np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-9) < 3:
        cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        points = (points[:, None, :] + THICKEN * cube[None]).reshape(-1, 3)
    vec = coal.StdVec_Vec3s()
    for p in points:
        vec.append(np.asarray(p, dtype=float))
    return coal.Convex.convexHull(vec, False, "")


_CACHE: dict[tuple, dict[str, LinkPieces]] = {}


def _hull_volume(points: np.ndarray) -> float:
    try:
        return float(ConvexHull(points).volume)
    except (QhullError, ValueError):  # flat or too few points
        return 0.0


def _slab_cuts(mesh, axis: np.ndarray, slabs: int, key: str) -> np.ndarray:
    r"""Cut positions :math:`-\infty = c_0 < c_1 < \dots < c_k = \infty` of the ``slabs`` slabs along
    ``axis`` whose convex hulls have the smallest total volume, over :data:`GRID` ``* slabs``
    equally spaced candidate cuts (dynamic programming; cached on disk per geometry)."""
    h = hashlib.sha256(repr((key, slabs, GRID, np.round(axis, 12).tolist(), 1)).encode()).hexdigest()
    cached = fit_cache.load("hull_cuts", h)
    if cached is not None:
        return np.array(cached, dtype=float)
    t = mesh.vertices @ axis
    g = GRID * slabs
    pos = np.concatenate([[-np.inf], t.min() + (t.max() - t.min()) * np.arange(1, g) / g, [np.inf]])
    cuts = slab_partitions(mesh, axis, pos, _hull_volume, slabs)[-1][1]
    fit_cache.store("hull_cuts", h, [float(c) for c in cuts])
    return cuts


def link_pieces(robot, geometry_model: pin.GeometryModel, slabs: int | None = None,
                links: Sequence[str] | None = None) -> dict[str, LinkPieces]:
    """The convex pieces of the ``links`` (default: every link with collision geometry; module
    docstring), cached per geometry, ``slabs`` (default :data:`SLABS`) and links in the process."""
    slabs = SLABS if slabs is None else slabs
    key = (geometry_key(robot, geometry_model, LinkFitSettings()), int(slabs), None if links is None else
           tuple(sorted(links)))
    if key in _CACHE:
        return _CACHE[key]
    meshes = link_meshes(robot, geometry_model)
    parts: dict[str, list] = {}
    bodies: dict[str, int] = {}
    for go in geometry_model.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        if links is not None and frame.name not in links:
            continue
        entry = parts.setdefault(frame.name, [])
        bodies[frame.name] = int(go.parentJoint)
        mesh = meshes.get(frame.name)
        if mesh is None and isinstance(go.geometry, coal.BVHModelBase):  # a mesh beside primitives: its hull
            M = go.placement
            pts = np.asarray(go.geometry.vertices(), dtype=float).reshape(-1, 3) @ M.rotation.T + M.translation
            a, b, r = fit_capsule(pts, refine=False)
            entry.append((_convex(pts), np.eye(3), np.zeros(3), a, b, r + 2.0 * THICKEN))
            continue
        if mesh is None:  # a primitive: convex, placed by go.placement in the joint frame
            centres, radii, axis = _local_balls(go.geometry)
            a, b, r = fit_capsule(centres, radii, [] if axis is None else [axis], refine=False)
            M = go.placement
            entry.append((go.geometry, M.rotation, M.translation, M.act(a), M.act(b), r))
            continue
        if entry:
            continue  # a mesh link is pieced once, from all its meshes (link frame)
        v = mesh.vertices
        axis = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)[2][0]
        cuts = _slab_cuts(mesh, axis, int(slabs), key[0] + frame.name)
        F = frame.placement  # T_{joint, link}
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            pts = slab_points(mesh, axis, lo, hi)
            if len(pts) == 0:
                continue
            pts = pts @ F.rotation.T + F.translation  # joint frame
            a, b, r = fit_capsule(pts, refine=False)
            r += 2.0 * THICKEN  # encloses a thickened flat piece too
            entry.append((_convex(pts), np.eye(3), np.zeros(3), a, b, r))
    out = {}
    order = [n for n in link_names(robot) if parts.get(n)]
    for name in order:
        body = bodies[name]
        shapes, rot, trans, a, b, r = zip(*parts[name], strict=True)
        out[name] = LinkPieces(name, body, tuple(shapes), np.array(rot), np.array(trans), np.array(a),
                               np.array(b), np.array(r, dtype=float))
    _CACHE[key] = out
    return out


class HullPairs:
    """The convex-piece rows of a feasibility model (module docstring).

    Args:
        pieces: :func:`link_pieces` of the robot.
        link_pairs: ``(link_a, link_b)`` pairs checked on their pieces.
    """

    def __init__(self, pieces: dict[str, LinkPieces], link_pairs: Sequence[tuple[str, str]]):
        self.link_pairs = tuple((str(a), str(b)) for a, b in link_pairs)
        names = list(dict.fromkeys(n for p in self.link_pairs for n in p))
        self.pieces = {n: pieces[n] for n in names}
        start, shapes, body, rot, trans, ca, cb, cr = {}, [], [], [], [], [], [], []
        for n in names:
            lp = self.pieces[n]
            start[n] = len(shapes)
            shapes += lp.shapes
            body += [lp.body] * len(lp.shapes)
            rot.append(lp.rotation)
            trans.append(lp.translation)
            ca.append(lp.cap_a)
            cb.append(lp.cap_b)
            cr.append(lp.cap_r)
        self._shapes = shapes
        self._curved = [not isinstance(sh, (coal.ConvexBase, coal.Box)) for sh in shapes]
        self._body = np.array(body, dtype=int)
        if shapes:
            self._rot, self._trans = np.concatenate(rot), np.concatenate(trans)
            self._ca, self._cb, self._cr = np.concatenate(ca), np.concatenate(cb), np.concatenate(cr)
        pa, pb, owner = [], [], []
        for h, (a, b) in enumerate(self.link_pairs):
            for i in range(len(self.pieces[a].shapes)):
                for j in range(len(self.pieces[b].shapes)):
                    pa.append(start[a] + i)
                    pb.append(start[b] + j)
                    owner.append(h)
        self._pa, self._pb = np.array(pa, dtype=int), np.array(pb, dtype=int)
        owner = np.array(owner, dtype=int)
        self._bounds = np.searchsorted(owner, np.arange(len(self.link_pairs) + 1))
        #: Bodies of the two links of each pair, (H,) each.
        self.body_a = np.array([self.pieces[a].body for a, _ in self.link_pairs], dtype=int)
        self.body_b = np.array([self.pieces[b].body for _, b in self.link_pairs], dtype=int)
        self._request = coal.DistanceRequest()
        self._request.enable_signed_distance = True
        # GJK stops on an absolute duality gap: on curved pieces (cylinders, spheres) coal's default
        # relative criterion leaves the witness points off by up to 7e-5 of the gradient (kr16);
        # a gap of GJK_GAP gives 6e-7 at the same cost (docs/feasibility.md §2). So tight a gap
        # sometimes makes GJK/EPA fail: a result beyond GJK_FAILED (EPA: -DBL_MAX), exactly 0
        # (GJK) or below the capsule lower bound (the pieces lie in their capsules) is a failed
        # call, repeated with coal's default criterion.
        self._fallback = coal.DistanceRequest()
        self._fallback.enable_signed_distance = True
        self._fallback.gjk_tolerance = 1e-10
        self._request.gjk_convergence_criterion = coal.GJKConvergenceCriterion.DualityGap
        self._request.gjk_convergence_criterion_type = coal.GJKConvergenceCriterionType.Absolute
        self._request.gjk_tolerance = GJK_GAP
        #: Calls repeated with the fallback request (coal returned a non-finite or absurd distance).
        self.fallbacks = 0
        #: Rows whose curvature was exact (closest features) or the tangent-plane model.
        self.curvature = {"exact": 0, "model": 0}
        #: Every row's witnesses of the poses evaluated last (hull_witness.py): the same placements
        #: are not sent to coal twice (a trial point, then its curvature and pieces).
        self.memo = WitnessMemo(self._body)

    def __len__(self) -> int:
        return len(self.link_pairs)

    @property
    def labels(self) -> tuple[str, ...]:
        """Row labels, ``"self:<link_a>|<link_b>"``."""
        return tuple(f"self:{a}|{b}" for a, b in self.link_pairs)

    def closest(self, states: BodyStates, rows: np.ndarray | None = None) -> HullWitness:
        """Witnesses of every pose of ``states`` and link pairs ``rows`` (default all): those of
        poses whose placements the memo holds from it, the others from coal (kept in the memo when
        every row is asked for)."""
        every = np.arange(len(self))
        rows = every if rows is None else np.asarray(rows, dtype=int)
        if not len(self) or not len(rows):
            return self._closest(states, rows)
        keys = self.memo.keys(states.rotation, states.translation)
        found, packed = self.memo.find(keys)
        if found.size == len(keys):
            return HullWitness.unpack(np.array(packed)).take(rows)
        full = rows.size == every.size and np.array_equal(rows, every)
        missing = np.setdiff1d(np.arange(len(keys)), found)
        fresh = self._closest(states if found.size == 0 else states.take(missing), rows)
        if full:
            self.memo.store([keys[k] for k in missing], fresh)
        if found.size == 0:
            return fresh
        old = HullWitness.unpack(np.array(packed)).take(rows).pack()
        out = np.empty((len(keys), old.shape[1]))
        out[found], out[missing] = old, fresh.pack()
        return HullWitness.unpack(out, fresh.calls)

    def _closest(self, states: BodyStates, rows: np.ndarray) -> HullWitness:
        """Witnesses of every pose of ``states`` and link pairs ``rows`` by coal (module docstring)."""
        n = states.rotation.shape[0]
        H = len(rows)
        dist, wa, wb, u = np.zeros((n, H)), np.zeros((n, H, 3)), np.zeros((n, H, 3)), np.zeros((n, H, 3))
        piece_a, piece_b = np.full((n, H), -1), np.full((n, H), -1)
        calls = 0
        if H == 0:
            return HullWitness(dist, wa, wb, u, 0, piece_a, piece_b)
        sel = np.concatenate([np.arange(self._bounds[h], self._bounds[h + 1]) for h in rows])
        pa, pb = self._pa[sel], self._pb[sel]
        bounds = np.concatenate([[0], np.cumsum(np.diff(self._bounds)[rows])])
        R, t = states.rotation[:, self._body], states.translation[:, self._body]  # (n, P, ...)
        rw = R @ self._rot  # piece placements in the world
        tw = np.einsum("npij,pj->npi", R, self._trans) + t
        A, B = states.points(self._body, self._ca), states.points(self._body, self._cb)
        s, tt = closest_parameters(A[:, pa], B[:, pa], A[:, pb], B[:, pb])
        gap = A[:, pa] + s[..., None] * (B[:, pa] - A[:, pa]) - A[:, pb] - tt[..., None] * (B[:, pb] - A[:, pb])
        lower = np.linalg.norm(gap, axis=2) - self._cr[pa] - self._cr[pb]  # (n, PP)
        res = coal.DistanceResult()
        orders = [(lo + np.argsort(lower[:, lo:hi], axis=1)).tolist()
                  for lo, hi in zip(bounds[:-1], bounds[1:], strict=True)]
        shapes, pa_l, pb_l, low, curved = self._shapes, pa.tolist(), pb.tolist(), lower.tolist(), self._curved
        transform, coal_distance, request, fallback = coal.Transform3s, coal.distance, self._request, self._fallback
        found, best_a, best_b, best_n, best_d = [], [], [], [], []  # the rows' closest pairs, written at the end
        for k in range(n):  # the loops call coal and keep its answers; the arithmetic is done below
            placed: dict[int, coal.Transform3s] = {}  # piece placements of pose k, made once
            low_k, rw_k, tw_k = low[k], rw[k], tw[k]
            for h in range(H):
                best = np.inf
                for c in orders[h][k]:
                    low_c = low_k[c]
                    if low_c >= best and low_c >= 0.0:  # low_c >= max(best, 0)
                        break
                    i, j = pa_l[c], pb_l[c]
                    ti, tj = placed.get(i), placed.get(j)
                    if ti is None:
                        ti = placed[i] = transform(rw_k[i], tw_k[i])
                    if tj is None:
                        tj = placed[j] = transform(rw_k[j], tw_k[j])
                    res.clear()  # a curved pair: the duality-gap request, a failed call (__init__) repeated
                    if curved[i] or curved[j]:
                        d = coal_distance(shapes[i], ti, shapes[j], tj, request, res)
                        if not (abs(d) < GJK_FAILED and d != 0.0 and d >= low_c - 1e-9):
                            self.fallbacks += 1
                            res.clear()
                            d = coal_distance(shapes[i], ti, shapes[j], tj, fallback, res)
                    else:
                        d = coal_distance(shapes[i], ti, shapes[j], tj, fallback, res)
                    if not abs(d) < GJK_FAILED:
                        raise FloatingPointError(f"coal's signed distance of two convex pieces failed ({d})")
                    calls += 1
                    if d < best:
                        best, pi, pj = d, i, j
                        p1, p2, normal = res.getNearestPoint1(), res.getNearestPoint2(), res.normal.copy()
                if best < np.inf:
                    found.append((k, h, pi, pj))
                    best_a.append(p1)
                    best_b.append(p2)
                    best_n.append(normal)
                    best_d.append(best)
        if found:
            kk, hh, ii, jj = np.array(found).T
            piece_a[kk, hh], piece_b[kk, hh], dist[kk, hh] = ii, jj, best_d
            wa[kk, hh], wb[kk, hh] = best_a, best_b
            gap_w = wa[kk, hh] - wb[kk, hh]
            norm = np.sqrt((gap_w[:, None, :] @ gap_w[:, :, None])[:, 0, 0])  # each row's own dot product
            unit = (np.array(best_d) > 0.0) & (norm > 1e-9)
            u[kk[unit], hh[unit]] = gap_w[unit] / norm[unit, None]
            u[kk[~unit], hh[~unit]] = -np.array(best_n)[~unit]
        return HullWitness(dist, wa, wb, u, calls, piece_a, piece_b)

    def piece_vertices(self, states: BodyStates, pose: int, piece: int) -> np.ndarray | None:
        """The vertices of piece ``piece`` at pose ``pose`` of ``states``, world [m] (k, 3); None for
        a curved piece (sphere, cylinder, capsule)."""
        local = _vertices(self._shapes[piece])
        if local is None:
            return None
        body = self._body[piece]
        in_body = local @ self._rot[piece].T + self._trans[piece]
        return in_body @ states.rotation[pose, body].T + states.translation[pose, body]

    def rows(self, states: BodyStates, clearance: float, jacobian: bool):
        """Values :math:`g` (n, H) [m] and Jacobians (n, H, nv) (``None`` without ``jacobian``)."""
        w = self.closest(states)
        values = w.dist - clearance
        if not jacobian:
            return values, None
        ja = states.directional_jacobian(self.body_a, w.wa, w.u)
        jb = states.directional_jacobian(self.body_b, w.wb, w.u)
        return values, ja - jb

    def hessians(self, states: BodyStates, pose: np.ndarray, rows: np.ndarray, exact: bool = True) -> np.ndarray:
        r"""Second derivatives (K, nv, nv) of link pairs ``rows`` (K,) at poses ``pose`` (K,) of
        ``states`` (with Jacobians): exact for the closest features
        (:func:`calib_oed.feasibility.hull_curvature.feature_hessians`, every row at once), else
        (or with ``exact=False``) the tangent-plane model :math:`u^\top(\partial^2 w_a - \partial^2 w_b)`.
        ``self.curvature`` counts both."""
        pose, rows = np.asarray(pose, dtype=int), np.asarray(rows, dtype=int)
        nv = states.jacobian.shape[-1]
        out, ok = np.zeros((len(pose), nv, nv)), np.zeros(len(pose), dtype=bool)
        if not pose.size:
            return out
        used, at = np.unique(pose, return_inverse=True)
        w = self.closest(states.take(used))  # every row of those poses (the memo: no coal call)
        dist, wa, wb, u = w.dist[at, rows], w.wa[at, rows], w.wb[at, rows], w.u[at, rows]
        ba, bb = self.body_a[rows], self.body_b[rows]
        if exact:
            found, fa, fb = [], [], []
            for k, (i, j) in enumerate(zip(w.piece_a[at, rows].tolist(), w.piece_b[at, rows].tolist(), strict=True)):
                if i < 0 or dist[k] <= 0.0:
                    continue
                f_a = support_feature(self._shapes[i], self._rot[i], self._trans[i],
                                      -states.rotation[pose[k], ba[k]].T @ u[k])
                f_b = support_feature(self._shapes[j], self._rot[j], self._trans[j],
                                      states.rotation[pose[k], bb[k]].T @ u[k])
                if f_a is not None and f_b is not None:
                    found.append(k)
                    fa.append(f_a)
                    fb.append(f_b)
            if found:
                sel = np.array(found)
                hess, good = feature_hessians(states, pose[sel], ba[sel], fa, bb[sel], fb, dist[sel],
                                              np.stack([wa[sel], wb[sel]], axis=1))
                out[sel[good]], ok[sel[good]] = hess[good], True
        self.curvature["exact"] += int(ok.sum())
        self.curvature["model"] += int((~ok).sum())
        model = np.flatnonzero(~ok)
        for body, x, sign in ((ba, wa, 1.0), (bb, wb, -1.0)):
            if model.size:
                pk, bk = pose[model], body[model]
                local = np.einsum("ki,kij->kj", x[model] - states.translation[pk, bk], states.rotation[pk, bk])
                _, jx, omega = body_points(states, pk, bk, local)  # R^T (x - t) back on its body
                out[model] += sign * point_hessian_along(omega, jx, u[model])
        return out
