r"""All feasibility constraints of measurement configurations, values and exact gradients.

Every constraint is written :math:`g(q) \ge 0` (feasible), in SI, per pose:

- **joint** (2 per joint): :math:`q_i - (\underline q_i + m_q) \ge 0`,
  :math:`(\overline q_i - m_q) - q_i \ge 0` [rad or m];
- **incidence** (1 per reflector with a fixed aim, paper eq. 4; none for a
  reflector the operator turns towards the tracker, ``aim: manual``):
  :math:`z^\top u - \cos(\beta_{max} - m_\beta) \ge 0` [1], with
  :math:`z = R_{W,F}\,n_j` the reflector's axis (its unit ``normal`` :math:`n_j`
  in the tool frame, default tool z) and :math:`u = (t_T - c)/\lVert t_T - c\rVert`
  the unit direction from the reflector :math:`c` to the tracker :math:`t_T`;
- **self**, **obstacle**, **beam** (capsule pairs, paper §2.2):
  :math:`d(S_1, S_2) - r_1 - r_2 - m_d \ge 0` [m] with :math:`d` the distance
  of the axis segments; against a half-space :math:`n^\top x \ge c_0` one
  row per end point, :math:`n^\top a - c_0 - r - m_d \ge 0` and the same for
  :math:`b` (smooth, unlike their minimum); against a box, cylinder or mesh
  one row :math:`d(S, O) - r - m_d \ge 0` (:mod:`calib_oed.feasibility.solids`).

Gradients (envelope theorem: the closest-point parameters are held fixed):
with witness points :math:`w_1, w_2` and :math:`u = (w_1 - w_2)/\lVert w_1 - w_2\rVert`,

.. math::
    \frac{\partial g}{\partial q} = u^\top\!\left(\frac{\partial w_1}{\partial q}
    - \frac{\partial w_2}{\partial q}\right),\qquad
    \frac{\partial w}{\partial q} = (1-s)\,J_{a} + s\,J_{b},

:math:`J_a, J_b` the point Jacobians of the segment's end points (zero for
world-fixed ones, see :mod:`calib_oed.feasibility.bodies`). For incidence,
:math:`\partial(z^\top u) = (z\times u)^\top J^{ang} - z^\top (I - uu^\top) J_c / L`.

Each pose's constraints depend on that pose only, so the Jacobian of a design
is block diagonal (:meth:`FeasibilityModel.sparse_jacobian`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from calib_oed.exceptions import ShapeError
from calib_oed.feasibility.bodies import BodyStates, compute_body_states
from calib_oed.feasibility.curvature import lagrangian_hessian
from calib_oed.feasibility.hulls import HullPairs
from calib_oed.feasibility.segments import closest_parameters
from calib_oed.feasibility.shapes import AIMS, Capsule, Cell, FeasibilitySettings
from calib_oed.feasibility.solids import SolidPairs, solid_candidates, solid_rows
from calib_oed.model.robot import Robot, frame_index

#: Constraint kinds, in row order within a pose.
KINDS = ("joint", "incidence", "self", "obstacle", "beam")


@dataclass(frozen=True, eq=False)
class SegmentTable:
    """All capsule axes: end points fixed on bodies (0 = world).

    Attributes:
        body_a, body_b: Body (joint index) of each end point, (s,).
        a_local, b_local: End points in their body frames [m], (s, 3).
        radius: Radii [m], (s,).
        names: Labels (``"link_2#0"``, ``"reflector(smr0)"``, ``"laser(smr0)"``, ``"car_lower"``).
        links: Link name each robot segment belongs to (``""`` for world-fixed and beams).
        roles: ``"robot"``, ``"reflector"``, ``"beam"`` or ``"obstacle"``.
    """

    body_a: np.ndarray
    a_local: np.ndarray
    body_b: np.ndarray
    b_local: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...]
    links: tuple[str, ...]
    roles: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.names)


#: Feasible means every row :math:`g \\ge -10^{-6}` (m or rad): an optimised design sits
#: on its active constraints, up to the solver's rounding.
FEASIBILITY_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class ConstraintValues:
    """Constraint values of a design (and their Jacobian).

    Attributes:
        values: :math:`g(q)`, (n, m); feasible where every entry is
            >= -:data:`FEASIBILITY_TOL`.
        jacobian: :math:`\\partial g_k/\\partial q_k` per pose, (n, m, nq), or ``None``.
        kinds: Kind of each of the m rows (see :data:`KINDS`).
        labels: Label of each row.
    """

    values: np.ndarray
    jacobian: np.ndarray | None
    kinds: tuple[str, ...]
    labels: tuple[str, ...]

    @property
    def feasible(self) -> np.ndarray:
        """Boolean (n,): every constraint of the pose holds (to :data:`FEASIBILITY_TOL`)."""
        return np.all(self.values >= -FEASIBILITY_TOL, axis=1)


def build_segments(
    robot: Robot,
    capsules: Sequence[Capsule],
    cell: Cell,
    settings: FeasibilitySettings,
    tracker_position: np.ndarray,
    reflector_offsets: np.ndarray,
    reflector_names: Sequence[str],
) -> SegmentTable:
    """Put robot capsules, reflector capsules, beams and obstacle capsules in one table."""
    model = robot.model
    rows: list[tuple] = []
    for cap in capsules:
        fid = frame_index(model, cap.frame)
        frame = model.frames[fid]
        a = frame.placement.act(cap.a)
        b = frame.placement.act(cap.b)
        rows.append((frame.parentJoint, a, frame.parentJoint, b, cap.radius, cap.name or cap.frame, cap.frame, "robot"))
    tool = model.frames[robot.tool_frame_id]
    tool_link = tool.name
    for name, offset in zip(reflector_names, reflector_offsets, strict=True):
        a = tool.placement.translation.copy()
        b = tool.placement.act(np.asarray(offset, dtype=float))
        rows.append((tool.parentJoint, a, tool.parentJoint, b, settings.reflector_radius,
                     f"reflector({name})", tool_link, "reflector"))
    for cap in cell.capsules:
        rows.append((0, cap.a, 0, cap.b, cap.radius, cap.name, "", "obstacle"))
    t_world = np.asarray(tracker_position, dtype=float)
    for name, offset in zip(reflector_names, reflector_offsets, strict=True):
        c = tool.placement.act(np.asarray(offset, dtype=float))
        rows.append((tool.parentJoint, c, 0, t_world, settings.beam_radius, f"laser({name})", "", "beam"))
    cols = list(zip(*rows, strict=True))
    return SegmentTable(
        body_a=np.array(cols[0], dtype=int),
        a_local=np.array(cols[1], dtype=float).reshape(-1, 3),
        body_b=np.array(cols[2], dtype=int),
        b_local=np.array(cols[3], dtype=float).reshape(-1, 3),
        radius=np.array(cols[4], dtype=float),
        names=tuple(cols[5]),
        links=tuple(cols[6]),
        roles=tuple(cols[7]),
    )


class FeasibilityModel:
    """Constraint values and Jacobians for batches of configurations.

    Args:
        robot: The robot (nominal model; joint limits).
        segments: Capsule axes (:func:`build_segments`).
        pairs: Capsule pairs ``(i, j)`` to check, (P, 2) indices into ``segments``.
        pair_kinds: Kind of each pair (``"self"``, ``"obstacle"``, ``"beam"``).
        halfspace_pairs: ``(segment, half-space)`` pairs, (H, 2).
        halfspace_kinds: Kind of each half-space pair.
        cell: The cell (for its half-spaces).
        settings: Limits and margins.
        tracker_position: Tracker origin in the world [m], (3,).
        reflector_offsets: Reflector offsets in the tool frame [m], (k, 3).
        reflector_names: Names of the reflectors.
        reflector_normals: Each reflector's axis in the tool frame, (k, 3) (normalised;
            ``None``: tool z for every reflector).
        reflector_aims: Each reflector's aim, ``"fixed"`` (its axis turns with the tool:
            an incidence row) or ``"manual"`` (the operator turns it towards the tracker at
            each pose: no incidence row, the beam rows stay); ``None``: all fixed.
        solid_pairs: ``(segment, solid)`` pairs against the cell's boxes, cylinders and
            meshes, (S, 2), or ``None`` for every candidate (:func:`solid_candidates`).
        solid_kinds: Kind of each solid pair (``"obstacle"`` or ``"beam"``).
        hull_pairs: Self link pairs checked on convex pieces of their geometry, kind
            ``"self"`` (:class:`calib_oed.feasibility.hulls.HullPairs`), or ``None``.

    Rows per pose, in order: joint, incidence, solid, hull, capsule pairs, half-space pairs.
    """

    def __init__(
        self,
        robot: Robot,
        segments: SegmentTable,
        pairs: np.ndarray,
        pair_kinds: Sequence[str],
        halfspace_pairs: np.ndarray,
        halfspace_kinds: Sequence[str],
        cell: Cell,
        settings: FeasibilitySettings,
        tracker_position: np.ndarray,
        reflector_offsets: np.ndarray,
        reflector_names: Sequence[str],
        reflector_normals: np.ndarray | None = None,
        solid_pairs: np.ndarray | None = None,
        solid_kinds: Sequence[str] | None = None,
        hull_pairs=None,
        reflector_aims: Sequence[str] | None = None,
    ):
        self.robot = robot
        self.segments = segments
        self.pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.pair_kinds = tuple(pair_kinds)
        self.halfspace_pairs = np.asarray(halfspace_pairs, dtype=int).reshape(-1, 2)
        self.halfspace_kinds = tuple(halfspace_kinds)
        self.cell = cell
        self.settings = settings
        self.tracker_position = np.asarray(tracker_position, dtype=float).reshape(3)
        self.reflector_offsets = np.asarray(reflector_offsets, dtype=float).reshape(-1, 3)
        self.reflector_names = tuple(reflector_names)
        self.reflector_aims = (("fixed",) * len(self.reflector_names) if reflector_aims is None
                               else tuple(reflector_aims))
        if len(self.reflector_aims) != len(self.reflector_names) or not set(self.reflector_aims) <= set(AIMS):
            raise ValueError(f"reflector_aims must give one of {AIMS} per reflector, got {self.reflector_aims}")
        #: The reflectors with an incidence row (fixed aim), in row order, and their number.
        self.incidence_reflectors = np.flatnonzero(np.array(self.reflector_aims) == "fixed")
        self.n_incidence = len(self.incidence_reflectors)
        tool = robot.model.frames[robot.tool_frame_id]
        self._tool_body = int(tool.parentJoint)
        self._tool_rotation = tool.placement.rotation.copy()
        self._reflector_local = np.array([tool.placement.act(c) for c in self.reflector_offsets]).reshape(-1, 3)
        k = len(self.reflector_offsets)
        normals = np.tile([0.0, 0.0, 1.0], (k, 1)) if reflector_normals is None else np.array(
            reflector_normals, dtype=float).reshape(-1, 3)
        if normals.shape != (k, 3):
            raise ShapeError("reflector_normals", f"({k}, 3)", normals.shape)
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        if not np.all(np.isfinite(normals)) or np.any(norm < 1e-12):
            raise ValueError(f"reflector normals must be finite and non-zero, got {normals.tolist()}")
        self.reflector_normals = normals / norm
        #: Each reflector's axis in its body (joint) frame.
        self.reflector_axis_local = (self._tool_rotation @ self.reflector_normals.T).T.copy()
        if solid_pairs is None:
            solid_pairs, solid_kinds, _ = solid_candidates(segments, cell)
        solid_pairs = np.asarray(solid_pairs, dtype=int).reshape(-1, 2)
        self.solid_kinds = tuple(solid_kinds or ())
        self.solid_pairs = SolidPairs(cell, solid_pairs, segments.radius[solid_pairs[:, 0]])
        self.hull_pairs = HullPairs({}, ()) if hull_pairs is None else hull_pairs
        if self.halfspace_pairs.size:
            hs = cell.halfspaces
            self._hs_normal = np.array([hs[h].normal for h in self.halfspace_pairs[:, 1]])
            self._hs_offset = np.array([hs[h].offset for h in self.halfspace_pairs[:, 1]])
        else:
            self._hs_normal = np.zeros((0, 3))
            self._hs_offset = np.zeros(0)
        self._pair_clearance = self._clearance(self.pair_kinds)
        self._hs_clearance = self._clearance(self.halfspace_kinds)
        self.kinds, self.labels = self._rows()

    # ------------------------------------------------------------ layout
    def _clearance(self, kinds) -> np.ndarray:
        return np.full(len(kinds), self.settings.margins.clearance)

    def _rows(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        kinds, labels = [], []
        for name in self.robot.joint_names:
            kinds += ["joint", "joint"]
            labels += [f"joint:{name}:lower", f"joint:{name}:upper"]
        for name in np.array(self.reflector_names, dtype=object)[self.incidence_reflectors]:
            kinds.append("incidence")
            labels.append(f"incidence:{name}")
        names = self.segments.names
        for (i, o), kind in zip(self.solid_pairs.pairs, self.solid_kinds, strict=True):
            kinds.append(kind)
            labels.append(f"{kind}:{names[i]}|{self.cell.solids[o].name}")
        kinds += ["self"] * len(self.hull_pairs)
        labels += self.hull_pairs.labels
        for (i, j), kind in zip(self.pairs, self.pair_kinds, strict=True):
            kinds.append(kind)
            labels.append(f"{kind}:{names[i]}|{names[j]}")
        for (i, h), kind in zip(self.halfspace_pairs, self.halfspace_kinds, strict=True):
            for end in ("a", "b"):
                kinds.append(kind)
                labels.append(f"{kind}:{names[i]}.{end}|{self.cell.halfspaces[h].name}")
        return tuple(kinds), tuple(labels)

    @property
    def n_constraints(self) -> int:
        """Constraints per pose, m."""
        return len(self.kinds)

    def kind_slices(self) -> dict[str, np.ndarray]:
        """Row indices of each kind."""
        kinds = np.array(self.kinds)
        return {k: np.flatnonzero(kinds == k) for k in KINDS}

    def count_per_pose(self) -> dict[str, int]:
        """Number of constraints per pose of each kind."""
        return {k: int(len(v)) for k, v in self.kind_slices().items()}

    # ------------------------------------------------------------ evaluation
    def compute(self, q: np.ndarray, jacobian: bool = True) -> ConstraintValues:
        """All constraint values (and Jacobians) at configurations ``q`` (n, nq)."""
        q = self.robot.check_configurations(q)
        states = compute_body_states(self.robot.model, q, jacobian=jacobian)
        return self.compute_from_states(q, states, jacobian)

    def compute_from_states(self, q: np.ndarray, states: BodyStates, jacobian: bool = True,
                            kinds: Sequence[str] = KINDS) -> ConstraintValues:
        """Constraint values from evaluated body states; ``kinds`` restricts the rows
        (``("joint", "incidence")`` is the cheap pre-filter of the sampler)."""
        asked, capsule_kinds = set(kinds), set(KINDS[2:])
        fns = [fn for kind, fn in (("joint", self._joint_rows), ("incidence", self._incidence_rows)) if kind in asked]
        computed = asked
        if capsule_kinds & asked:  # these give every capsule kind: keep the asked ones below
            fns += [lambda q, st, jac: solid_rows(self, st, jac), self._hull_rows, self._pair_rows,
                    self._halfspace_rows]
            computed = asked | capsule_kinds
        parts_v, parts_j = zip(*(fn(q, states, jacobian) for fn in fns), strict=True)
        rows = self.row_mask(asked)
        keep = rows[self.row_mask(computed)]
        values = np.concatenate(parts_v, axis=1)[:, keep]
        jac = np.concatenate(parts_j, axis=1)[:, keep] if jacobian else None
        return ConstraintValues(values, jac, tuple(k for k, r in zip(self.kinds, rows, strict=True) if r),
                                tuple(lbl for lbl, r in zip(self.labels, rows, strict=True) if r))

    def row_mask(self, kinds: Sequence[str] | set[str] = KINDS) -> np.ndarray:
        """Boolean (m,): the rows of the given kinds (the rows ``compute_from_states`` returns)."""
        return np.array([k in kinds for k in self.kinds], dtype=bool)

    def compute_lagrangian_hessian(self, q: np.ndarray, lam: np.ndarray, kinds: Sequence[str] = KINDS,
                                   states: BodyStates | None = None) -> np.ndarray:
        r"""Per pose :math:`H_j = \sum_i \lambda_{ji}\,\partial^2 g_{ji}/\partial q_j^2`, (n, nq, nq).

        Args:
            q: Configurations, (n, nq).
            lam: Multipliers, (n, m_kinds), in the row order of
                ``compute_from_states(..., kinds=kinds)``; rows with a zero multiplier
                are skipped (joint rows are linear: always zero).
            kinds: The row kinds ``lam`` covers.
            states: Body states of ``q`` with Jacobians (reuse those of the rows), or ``None``.

        Exact and analytic (:mod:`calib_oed.feasibility.curvature`); an SQP with
        :math:`L = f - \lambda^\top g` adds :math:`-H_j` to pose j's block.
        """
        q = self.robot.check_configurations(q)
        rows = self.row_mask(kinds)
        lam = np.asarray(lam, dtype=float)
        if lam.shape != (q.shape[0], int(rows.sum())):
            raise ShapeError("lam", f"({q.shape[0]}, {int(rows.sum())})", lam.shape)
        full = np.zeros((q.shape[0], self.n_constraints))
        full[:, rows] = lam
        return lagrangian_hessian(self, q, full, states)

    def compute_values(self, q: np.ndarray) -> np.ndarray:
        """Constraint values :math:`g(q)`, (n, m)."""
        return self.compute(q, jacobian=False).values

    def sparse_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
        """Values (n·m,) and the block-diagonal Jacobian (n·m, n·nq) of the stacked design."""
        res = self.compute(q, jacobian=True)
        n, m, nq = res.jacobian.shape
        bsr = scipy.sparse.bsr_matrix(
            (res.jacobian, np.arange(n), np.arange(n + 1)), shape=(n * m, n * nq)
        )
        return res.values.ravel(), bsr.tocsr()

    def _joint_rows(self, q, states, jacobian):
        margin = self.settings.margins.joint
        lo = q - (self.robot.lower + margin)
        hi = (self.robot.upper - margin) - q
        n, nq = q.shape
        values = np.stack([lo, hi], axis=2).reshape(n, 2 * nq)
        if not jacobian:
            return values, None
        jac = np.zeros((n, 2 * nq, nq))
        idx = np.arange(nq)
        jac[:, 2 * idx, idx] = 1.0
        jac[:, 2 * idx + 1, idx] = -1.0
        return values, jac

    def _incidence_rows(self, q, states: BodyStates, jacobian):
        k = self.n_incidence
        n = q.shape[0]
        if k == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, q.shape[1])) if jacobian else None)
        body = np.full(k, self._tool_body)
        c = states.points(body, self._reflector_local[self.incidence_reflectors])  # (n, k, 3)
        rot = states.rotation[:, self._tool_body] @ self._tool_rotation  # (n, 3, 3)
        z = np.einsum("nij,kj->nki", rot, self.reflector_normals[self.incidence_reflectors])  # (n, k, 3)
        diff = self.tracker_position - c
        length = np.linalg.norm(diff, axis=2, keepdims=True)
        u = diff / length
        limit = self.settings.incidence_limit - self.settings.margins.incidence
        values = np.einsum("nki,nki->nk", z, u) - np.cos(limit)
        if not jacobian:
            return values, None
        jac_ang = states.jacobian[:, self._tool_body, 3:]  # (n, 3, nv)
        d_rot = np.einsum("nki,niv->nkv", np.cross(z, u), jac_ang)
        # -z^T (I - u u^T) / L  applied to the point Jacobian of c
        w = -(z - np.einsum("nki,nki->nk", z, u)[..., None] * u) / length
        d_pt = states.directional_jacobian(body, c, w)
        return values, d_rot + d_pt

    def _hull_rows(self, q, states: BodyStates, jacobian):
        return self.hull_pairs.rows(states, self.settings.margins.clearance, jacobian)

    def _pair_rows(self, q, states: BodyStates, jacobian):
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
        values = dist - seg.radius[i] - seg.radius[j] - self._pair_clearance
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

    def _halfspace_rows(self, q, states: BodyStates, jacobian):
        r"""Two smooth rows per (segment, half-space) pair, one per end point
        (paper §2.2): :math:`n^\top a - c - r - m_d \ge 0`, :math:`n^\top b - c - r - m_d \ge 0`.
        Together they say the same as :math:`\min(n^\top a, n^\top b) - c - r - m_d \ge 0`,
        without its kink when the segment is parallel to the plane."""
        n = q.shape[0]
        if len(self.halfspace_pairs) == 0:
            return np.zeros((n, 0)), (np.zeros((n, 0, q.shape[1])) if jacobian else None)
        seg = self.segments
        i = self.halfspace_pairs[:, 0]
        a = states.points(seg.body_a[i], seg.a_local[i])
        b = states.points(seg.body_b[i], seg.b_local[i])
        base = self._hs_offset + seg.radius[i] + self._hs_clearance
        va = np.einsum("nhi,hi->nh", a, self._hs_normal) - base
        vb = np.einsum("nhi,hi->nh", b, self._hs_normal) - base
        values = np.stack([va, vb], axis=2).reshape(n, -1)
        if not jacobian:
            return values, None
        u = np.broadcast_to(self._hs_normal, a.shape)
        ja = states.directional_jacobian(seg.body_a[i], a, u)
        jb = states.directional_jacobian(seg.body_b[i], b, u)
        return values, np.stack([ja, jb], axis=2).reshape(n, -1, q.shape[1])
