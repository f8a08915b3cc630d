r"""Distances from capsule axes to solid obstacles (boxes, cylinders, meshes), with gradients.

A row is :math:`g = d(S, O) - r - m_d \ge 0` [m]: :math:`d` the distance of the
axis segment :math:`S = [a, b]` of a robot, reflector or beam capsule (radius
:math:`r`) to the solid :math:`O`, :math:`m_d` the clearance margin.

**Boxes, closed form.** In box coordinates :math:`x_O = R_{W,O}^\top (x - c)`
the box is :math:`|x_{O,i}| \le h_i`. If :math:`S` does not meet the box, a
closest pair :math:`(x, y)` has :math:`x` an end point of :math:`S` (then
:math:`y` = the end point clamped to the box), or :math:`y` on one of the 12
edges (a segment–segment distance, :mod:`calib_oed.feasibility.segments`); a
witness inside a face with :math:`x` inside :math:`S` makes :math:`S` parallel
to the face, and the set of closest pairs then reaches an end point or an edge.
So :math:`d = \min` of these 14 closed-form candidates, exact to rounding.
A segment that meets the box (slab test) takes the signed distance of coal
(:math:`d = d_{coal} + r`, negative when the axis is inside, EPA depth).

**Cylinders.** The cylinder (radius :math:`R`, axis segment :math:`A`) lies
inside the capsule of :math:`A` and radius :math:`R`, so
:math:`d \ge d(S, A) - R`, with equality when the closest point on :math:`A` is
strictly inside it and :math:`d(S, A) > R` (the witness is then on the side):
closed form, as for capsules. Otherwise (a cap or the rim) coal; when coal's
witness on the segment is an end point outside the cylinder, its distance and
normal are recomputed in closed form from that point (in the cylinder's
:math:`(\rho, z)`: cap :math:`|z| - \ell/2`, rim
:math:`\sqrt{(\rho - R)^2 + (|z| - \ell/2)^2}`), since GJK places witnesses on a
curved rim only to about 1e-5 relative.

**Meshes and the rest, coal.** ``coal.distance`` of a ``coal.Capsule`` of the
segment against ``coal.Cylinder`` or ``coal.Convex`` (the mesh's convex hull),
signed, with its witness points; :math:`d = d_{coal} + r`.

**Gradient** (envelope theorem, the witnesses held fixed): with :math:`s` the
axis parameter of the witness, :math:`w = (1-s)a + sb` and :math:`u` the unit
normal from the obstacle's witness towards :math:`w` (coal: minus its
``normal``),

.. math::
    \frac{\partial g}{\partial q} = u^\top\big((1-s)J_a + sJ_b\big).

The curvature (second order) is in :mod:`calib_oed.feasibility.curvature`
(exact for boxes and cylinder sides; the tangent-plane model for the coal rows).
All lengths in [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np

from calib_oed.feasibility.segments import EPS, closest_parameters
from calib_oed.feasibility.shapes import Box, Cell, Cylinder

#: Witness regimes of a box row: end point a, end point b, an edge, or coal (axis meets the box).
END_A, END_B, EDGE, COAL = 0, 1, 2, 3


def _box_edges() -> np.ndarray:
    """The 12 box edges in units of the half sizes: (12, 2, 3), start and end corner."""
    out = []
    for k in range(3):
        i, j = (m for m in range(3) if m != k)
        for si in (-1.0, 1.0):
            for sj in (-1.0, 1.0):
                e = np.zeros((2, 3))
                e[:, k] = (-1.0, 1.0)
                e[:, i], e[:, j] = si, sj
                out.append(e)
    return np.array(out)


EDGES = _box_edges()


@dataclass(frozen=True, eq=False)
class Witness:
    """Closest points of axis segments to solids, flat over rows.

    Attributes:
        dist: Axis-to-solid distance :math:`d` [m] (negative: the axis is inside), (N,).
        s: Axis parameter of the witness on the segment, (N,).
        u: Unit normal from the solid towards the axis witness, (N, 3).
        regime: :data:`END_A`, :data:`END_B`, :data:`EDGE` or :data:`COAL`, (N,).
        edge: Edge end points of :data:`EDGE` rows in the world [m], (N, 2, 3) (else 0).
        mask: Box coordinates clamped at an end-point witness, (N, 3) (else False).
    """

    dist: np.ndarray
    s: np.ndarray
    u: np.ndarray
    regime: np.ndarray
    edge: np.ndarray
    mask: np.ndarray


def _frames(axis: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) whose third column is the unit ``axis`` (N, 3)."""
    helper = np.where((np.abs(axis[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u1 = np.cross(helper, axis)
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    return np.stack([u1, np.cross(axis, u1), axis], axis=2)


def _geometry(solid) -> tuple[coal.ShapeBase, coal.Transform3s]:
    """coal geometry of a solid and its placement in the world."""
    if isinstance(solid, Box):
        return coal.Box(*solid.size), coal.Transform3s(solid.rotation, solid.center)
    if isinstance(solid, Cylinder):
        return coal.Cylinder(solid.radius, solid.length), coal.Transform3s(solid.rotation, solid.center)
    points = coal.StdVec_Vec3s()
    for v in solid.vertices:
        points.append(v)
    return coal.Convex.convexHull(points, False, ""), coal.Transform3s()


class SolidPairs:
    """The (segment, solid) rows of a feasibility model and their distances.

    Args:
        cell: The cell (its :attr:`~calib_oed.feasibility.shapes.Cell.solids`).
        pairs: ``(segment, solid)`` index pairs, (P, 2).
        radius: Radius of each pair's capsule [m], (P,).
    """

    def __init__(self, cell: Cell, pairs: np.ndarray, radius: np.ndarray):
        solids = cell.solids
        self.pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.radius = np.asarray(radius, dtype=float).reshape(-1)
        obj = self.pairs[:, 1]
        self.is_box = np.array([isinstance(solids[o], Box) for o in obj], dtype=bool)
        eye = np.eye(3)
        self.center = np.array([getattr(solids[o], "center", np.zeros(3)) for o in obj]).reshape(-1, 3)
        self.rotation = np.array([getattr(solids[o], "rotation", eye) for o in obj]).reshape(-1, 3, 3)
        self.half = np.array([solids[o].half if b else np.ones(3) for o, b in zip(obj, self.is_box, strict=True)]
                             ).reshape(-1, 3)
        self.is_cylinder = np.array([isinstance(solids[o], Cylinder) for o in obj], dtype=bool)
        #: Axis end points of cylinder pairs [m], (P, 2, 3), and their radii (zero for others).
        self.axis = np.array([_axis(solids[o]) for o in obj]).reshape(-1, 2, 3)
        self.axis_radius = np.array([getattr(solids[o], "radius", 0.0) if c else 0.0
                                     for o, c in zip(obj, self.is_cylinder, strict=True)])
        self._coal = [_geometry(s) for s in solids]
        self._request = coal.DistanceRequest()
        self._request.enable_signed_distance = True
        self._request.gjk_tolerance = 1e-10

    def __len__(self) -> int:
        return len(self.pairs)

    def closest(self, a: np.ndarray, b: np.ndarray, index: np.ndarray) -> Witness:
        """Witnesses of segments ``[a, b]`` (N, 3) [m] against the solids of pairs ``index`` (N,)."""
        n = len(index)
        dist, s, u = np.zeros(n), np.zeros(n), np.zeros((n, 3))
        regime = np.full(n, COAL)
        edge, mask = np.zeros((n, 2, 3)), np.zeros((n, 3), dtype=bool)
        box = self.is_box[index]
        if np.any(box):
            k = np.flatnonzero(box)
            out = _box_closest(a[k], b[k], self.center[index[k]], self.rotation[index[k]], self.half[index[k]])
            for arr, val in zip((dist, s, u, regime, edge, mask), out, strict=True):
                arr[k] = val
        cyl = self.is_cylinder[index]
        if np.any(cyl):
            k = np.flatnonzero(cyl)
            out = _cylinder_side(a[k], b[k], self.axis[index[k]], self.axis_radius[index[k]])
            for arr, val in zip((dist, s, u, regime, edge), out, strict=True):
                arr[k] = val
        for k in np.flatnonzero(regime == COAL):
            dist[k], s[k], u[k] = self._coal_closest(a[k], b[k], int(index[k]))
        end = np.flatnonzero(cyl & (regime == COAL) & ((s == 0.0) | (s == 1.0)) & (dist > self.radius[index]))
        if end.size:
            x = np.where((s[end] == 0.0)[:, None], a[end], b[end])
            dist[end], u[end] = _cylinder_point(x, self.axis[index[end]], self.axis_radius[index[end]])
        return Witness(dist, s, u, regime, edge, mask)

    def _coal_closest(self, a: np.ndarray, b: np.ndarray, pair: int) -> tuple[float, float, np.ndarray]:
        """Signed axis distance, witness parameter and normal from coal (one segment)."""
        r = float(self.radius[pair])
        axis = b - a
        length = float(np.linalg.norm(axis))
        if length * length <= EPS:
            shape, rot = coal.Sphere(r), np.eye(3)
        else:
            shape, rot = coal.Capsule(r, length), _frames((axis / length)[None])[0]
        geom, place = self._coal[self.pairs[pair, 1]]
        res = coal.DistanceResult()
        d = coal.distance(shape, coal.Transform3s(rot, 0.5 * (a + b)), geom, place, self._request, res)
        p1 = np.asarray(res.getNearestPoint1())
        s = 0.0 if length * length <= EPS else float(np.clip((p1 - a) @ axis / length**2, 0.0, 1.0))
        n = -np.asarray(res.normal, dtype=float)
        gap = a + s * axis - np.asarray(res.getNearestPoint2())
        if d > -r and gap @ n > 0.0:  # axis outside: the witnesses give the normal to full precision
            n = gap
        return float(d) + r, s, n / max(float(np.linalg.norm(n)), 1e-300)


def _axis(solid) -> np.ndarray:
    """End points (2, 3) of a cylinder's axis segment in the world (zeros for other solids)."""
    if not isinstance(solid, Cylinder):
        return np.zeros((2, 3))
    half = 0.5 * solid.length * solid.rotation[:, 2]
    return np.array([solid.center - half, solid.center + half])


def _cylinder_side(a, b, axis, radius):
    """Closed-form witnesses on the cylinders' sides (module docstring); the other rows get
    regime :data:`COAL`. The side rows are :data:`EDGE` rows whose edge is the axis."""
    s, t = closest_parameters(a, b, axis[:, 0], axis[:, 1])
    gap = a + s[:, None] * (b - a) - (axis[:, 0] + t[:, None] * (axis[:, 1] - axis[:, 0]))
    d = np.linalg.norm(gap, axis=1)
    side = (t > 0.0) & (t < 1.0) & (d > radius)
    u = gap / np.maximum(d, 1e-300)[:, None]
    return d - radius, s, u, np.where(side, EDGE, COAL), np.where(side[:, None, None], axis, 0.0)


def _cylinder_point(x, axis, radius):
    """Distance (K,) and unit normal (K, 3) of points ``x`` (K, 3) outside cylinders (axis end
    points (K, 2, 3), radii (K,)), closed form in each cylinder's (rho, z)."""
    centre, half = 0.5 * (axis[:, 0] + axis[:, 1]), 0.5 * (axis[:, 1] - axis[:, 0])
    half_len = np.linalg.norm(half, axis=1)
    ez = half / half_len[:, None]
    rel = x - centre
    z = np.einsum("ki,ki->k", rel, ez)
    radial = rel - z[:, None] * ez
    rho = np.linalg.norm(radial, axis=1)
    er = radial / np.maximum(rho, 1e-300)[:, None]
    dr, dz = np.maximum(rho - radius, 0.0), np.maximum(np.abs(z) - half_len, 0.0)
    vec = dr[:, None] * er + (np.sign(z) * dz)[:, None] * ez
    d = np.linalg.norm(vec, axis=1)
    return d, vec / np.maximum(d, 1e-300)[:, None]


def _box_closest(a, b, center, rot, half):
    """Closed-form witnesses of segments (K, 3) and boxes (module docstring); rows whose axis
    meets the box get regime :data:`COAL` (filled in by the caller)."""
    al = np.einsum("ki,kij->kj", a - center, rot)
    bl = np.einsum("ki,kij->kj", b - center, rot)
    ends = np.stack([al, bl], axis=1)  # (K, 2, 3)
    clamped = np.clip(ends, -half[:, None], half[:, None])
    d_end = np.linalg.norm(ends - clamped, axis=2)  # (K, 2)
    e = EDGES[None] * half[:, None, None, :]  # (K, 12, 2, 3)
    shape = e[:, :, 0].shape
    se, te = closest_parameters(np.broadcast_to(al[:, None], shape), np.broadcast_to(bl[:, None], shape),
                                e[:, :, 0], e[:, :, 1])
    xe = al[:, None] + se[..., None] * (bl - al)[:, None]
    ye = e[:, :, 0] + te[..., None] * (e[:, :, 1] - e[:, :, 0])
    d_edge = np.linalg.norm(xe - ye, axis=2)  # (K, 12)
    cand = np.concatenate([d_end, d_edge], axis=1)
    best = np.argmin(cand, axis=1)
    rows = np.arange(len(a))
    dist = cand[rows, best]
    on_edge = best >= 2
    ke = np.where(on_edge, best - 2, 0)
    s = np.where(on_edge, se[rows, ke], (best == 1).astype(float))
    x_loc = np.where(on_edge[:, None], xe[rows, ke], ends[rows, np.minimum(best, 1)])
    y_loc = np.where(on_edge[:, None], ye[rows, ke], clamped[rows, np.minimum(best, 1)])
    u = np.einsum("kij,kj->ki", rot, x_loc - y_loc) / np.maximum(dist, 1e-300)[:, None]
    regime = np.where(on_edge, EDGE, best)
    edge = np.einsum("kij,kej->kei", rot, e[rows, ke]) + center[:, None]
    edge = np.where(on_edge[:, None, None], edge, 0.0)
    mask = ~on_edge[:, None] & (np.abs(x_loc) > half)
    regime = np.where(_meets(al, bl, half) | (dist <= 0.0), COAL, regime)
    return dist, s, u, regime, edge, mask


def _meets(al, bl, half) -> np.ndarray:
    """Slab test: does the segment (box coordinates, (K, 3)) meet the box?"""
    d = bl - al
    flat = np.abs(d) < 1e-15
    dsafe = np.where(flat, 1.0, d)
    t1, t2 = (-half - al) / dsafe, (half - al) / dsafe
    lo = np.where(flat, np.where(np.abs(al) <= half, -np.inf, np.inf), np.minimum(t1, t2))
    hi = np.where(flat, np.where(np.abs(al) <= half, np.inf, -np.inf), np.maximum(t1, t2))
    return np.maximum(lo.max(axis=1), 0.0) <= np.minimum(hi.min(axis=1), 1.0)


def solid_candidates(segments, cell: Cell) -> tuple[list[tuple[int, int]], list[str], list[tuple[str, str]]]:
    """Candidate ``(segment, solid)`` pairs, their kinds, and the skipped ones ``(label, reason)``.

    Every moving robot or reflector capsule (kind ``"obstacle"``) and every beam
    (kind ``"beam"``) against every solid, except links the solid ignores.
    """
    pairs, kinds, skipped = [], [], []
    for o, solid in enumerate(cell.solids):
        for i, role in enumerate(segments.roles):
            if role == "obstacle":
                continue
            kind = "beam" if role == "beam" else "obstacle"
            label = f"{kind}:{segments.names[i]}|{solid.name}"
            if role != "beam" and int(segments.body_a[i]) == 0:
                skipped.append((label, "both fixed"))
            elif segments.links[i] and segments.links[i] in solid.ignore_links:
                skipped.append((label, "ignore_links of the obstacle"))
            else:
                pairs.append((i, o))
                kinds.append(kind)
    return pairs, kinds, skipped


def solid_rows(model, states, jacobian: bool):
    """Values (n, P) and Jacobians (n, P, nv) of a model's solid rows."""
    sp, seg = model.solid_pairs, model.segments
    n = states.rotation.shape[0]
    nv = model.robot.model.nv
    if len(sp) == 0:
        return np.zeros((n, 0)), (np.zeros((n, 0, nv)) if jacobian else None)
    i = sp.pairs[:, 0]
    a = states.points(seg.body_a[i], seg.a_local[i])
    b = states.points(seg.body_b[i], seg.b_local[i])
    idx = np.tile(np.arange(len(sp)), n)
    w = sp.closest(a.reshape(-1, 3), b.reshape(-1, 3), idx)
    values = w.dist.reshape(n, -1) - seg.radius[i] - model.settings.margins.clearance
    if not jacobian:
        return values, None
    s, u = w.s.reshape(n, -1, 1), w.u.reshape(n, -1, 3)
    ja = states.directional_jacobian(seg.body_a[i], a, u)
    jb = states.directional_jacobian(seg.body_b[i], b, u)
    return values, (1.0 - s) * ja + s * jb


def solid_collision_objects(cell: Cell) -> list[tuple[str, coal.CollisionGeometry, coal.Transform3s, tuple[str, ...]]]:
    """``(name, coal geometry, placement in the world, ignore_links)`` of each of the cell's
    solids, for the mesh check (:mod:`calib_oed.feasibility.mesh_check`)."""
    return [(s.name, *_geometry(s), s.ignore_links) for s in cell.solids]


def prune_solid_pairs(model, values: np.ndarray, distance: float) -> tuple[np.ndarray, list[str], list[tuple]]:
    """The sampling pass for the solid rows (as for capsule pairs, :mod:`calib_oed.feasibility.pairs`).

    Args:
        model: The unpruned model.
        values: Its constraint values at the sampled configurations, (n, m).
        distance: A pair whose clearance stays above this [m] in every sample is dropped.

    Returns:
        The kept ``(segment, solid)`` pairs (S', 2), their kinds, and
        ``(label, reason, min clearance, max clearance)`` of each dropped pair.
    """
    first = 2 * model.robot.nq + model.n_incidence
    rows = np.arange(first, first + len(model.solid_pairs))
    raw = values[:, rows] + model.settings.margins.clearance
    lo, hi = raw.min(axis=0), raw.max(axis=0)
    keep, dropped = np.ones(len(rows), dtype=bool), []
    for k, r in enumerate(rows):
        reason = None
        if hi[k] < 0:
            reason = (f"overlapping in every one of {len(values)} samples (clearance {lo[k] * 1e3:.1f} to "
                      f"{hi[k] * 1e3:.1f} mm): capsules too coarse?")
        elif lo[k] > distance:
            reason = f"never closer than {distance * 1e3:.0f} mm in {len(values)} samples"
        if reason:
            keep[k] = False
            dropped.append((model.labels[r], reason, float(lo[k]), float(hi[k])))
    kinds = [kind for kind, k in zip(model.solid_kinds, keep, strict=True) if k]
    return model.solid_pairs.pairs[keep], kinds, dropped
