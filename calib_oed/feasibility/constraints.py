r"""All feasibility constraints of measurement configurations, values and exact gradients.

Every constraint is written :math:`g(q) \ge 0` (feasible), in SI, per pose,
in families of rows (:class:`~calib_oed.feasibility.row_family.RowFamily`), each
owning its values, exact gradients, curvature, labels and speed bound:

- **joint**, **incidence**: :mod:`calib_oed.feasibility.pose_rows`;
- capsule against solid (box, cylinder, mesh; **obstacle**, **beam**):
  :mod:`calib_oed.feasibility.solid_rows`;
- convex pieces of two links (**self**): :mod:`calib_oed.feasibility.hull_rows`;
- capsule pairs (**self**, **obstacle**, **beam**) and capsules against
  half-spaces (**obstacle**, **beam**): :mod:`calib_oed.feasibility.capsule_rows`.

Gradients use witness points and ``LOCAL_WORLD_ALIGNED`` joint Jacobians
(:mod:`calib_oed.feasibility.bodies`). Each pose's constraints depend on that
pose only, so the Jacobian of a design is block diagonal
(:meth:`calib_oed.oed.problem.DesignProblem.compute_constraint_rows` stacks it sparse).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import ShapeError
from calib_oed.feasibility.bodies import BodyStates, compute_body_states
from calib_oed.feasibility.capsule_rows import CapsulePairRows
from calib_oed.feasibility.curvature import lagrangian_hessian
from calib_oed.feasibility.hull_rows import HullRows
from calib_oed.feasibility.hulls import HullPairs
from calib_oed.feasibility.pose_rows import IncidenceRows, JointRows
from calib_oed.feasibility.row_family import RowFamily
from calib_oed.feasibility.shapes import AIMS, Capsule, Cell, FeasibilitySettings
from calib_oed.feasibility.solid_rows import SolidRows
from calib_oed.feasibility.solids import SolidPairs
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
        beam_of: The reflector whose laser line each beam segment is, -1 for other
            segments, (s,).
    """

    body_a: np.ndarray
    a_local: np.ndarray
    body_b: np.ndarray
    b_local: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...]
    links: tuple[str, ...]
    roles: tuple[str, ...]
    beam_of: np.ndarray

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
        rows.append((frame.parentJoint, a, frame.parentJoint, b, cap.radius, cap.name or cap.frame, cap.frame, "robot", -1))
    tool = model.frames[robot.tool_frame_id]
    tool_link = tool.name
    for name, offset in zip(reflector_names, reflector_offsets, strict=True):
        a = tool.placement.translation.copy()
        b = tool.placement.act(np.asarray(offset, dtype=float))
        rows.append((tool.parentJoint, a, tool.parentJoint, b, settings.reflector_radius,
                     f"reflector({name})", tool_link, "reflector", -1))
    for cap in cell.capsules:
        rows.append((0, cap.a, 0, cap.b, cap.radius, cap.name, "", "obstacle", -1))
    t_world = np.asarray(tracker_position, dtype=float)
    for j, (name, offset) in enumerate(zip(reflector_names, reflector_offsets, strict=True)):
        c = tool.placement.act(np.asarray(offset, dtype=float))
        rows.append((tool.parentJoint, c, 0, t_world, settings.beam_radius, f"laser({name})", "", "beam", j))
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
        beam_of=np.array(cols[8], dtype=int),
    )


class FeasibilityModel:
    """Constraint values and Jacobians for batches of configurations.

    Args:
        robot: The robot (nominal model; joint limits).
        segments: Capsule axes (:func:`build_segments`).
        cell: The cell.
        settings: Limits and margins.
        tracker_position: Tracker origin in the world [m], (3,).
        reflector_offsets: Reflector offsets in the tool frame [m], (k, 3).
        reflector_names: Names of the reflectors.
        reflector_normals: Each reflector's axis in the tool frame, (k, 3) (normalised;
            ``None``: tool z for every reflector).
        families: The geometric row families (solids, convex pieces, capsule pairs,
            half-spaces: :func:`calib_oed.feasibility.pairs.build_feasibility_model`).
        reflector_aims: Each reflector's aim, ``"fixed"`` (its axis turns with the tool:
            an incidence row) or ``"manual"`` (the operator turns it towards the tracker at
            each pose: no incidence row, its beam rows stay); ``None``: all fixed.

    Rows per pose, in order: joint, incidence, then ``families`` in their order.
    """

    def __init__(
        self,
        robot: Robot,
        segments: SegmentTable,
        cell: Cell,
        settings: FeasibilitySettings,
        tracker_position: np.ndarray,
        reflector_offsets: np.ndarray,
        reflector_names: Sequence[str],
        reflector_normals: np.ndarray | None = None,
        families: Sequence[RowFamily] = (),
        reflector_aims: Sequence[str] | None = None,
    ):
        self.robot = robot
        self.segments = segments
        self.cell = cell
        self.settings = settings
        self.tracker_position = np.asarray(tracker_position, dtype=float).reshape(3)
        self.reflector_offsets = np.asarray(reflector_offsets, dtype=float).reshape(-1, 3)
        self.reflector_names = tuple(reflector_names)
        k = len(self.reflector_names)
        self.reflector_aims = ("fixed",) * k if reflector_aims is None else tuple(reflector_aims)
        if len(self.reflector_aims) != k or not set(self.reflector_aims) <= set(AIMS):
            raise ValueError(f"reflector_aims must give one of {AIMS} per reflector, got {self.reflector_aims}")
        all_rows = IncidenceRows(robot, self.tracker_position, self.reflector_offsets, self.reflector_names,
                                 reflector_normals, settings.incidence_limit - settings.margins.incidence)
        self.reflector_normals = all_rows.normals
        #: The reflectors with an incidence row (a fixed aim), in row order.
        self.incidence_reflectors = np.flatnonzero(np.array(self.reflector_aims) == "fixed")
        fixed = self.incidence_reflectors
        incidence = all_rows if fixed.size == k else IncidenceRows(
            robot, self.tracker_position, self.reflector_offsets[fixed],
            [self.reflector_names[j] for j in fixed], self.reflector_normals[fixed], all_rows.limit, fixed)
        #: The row families, in row order.
        self.families: tuple[RowFamily, ...] = (JointRows(robot, settings.margins.joint), incidence,
                                                *families)
        self._slices, start = [], 0
        for family in self.families:
            self._slices.append(slice(start, start + len(family)))
            start += len(family)
        self.kinds = tuple(k for f in self.families for k in f.kinds)
        self.labels = tuple(lbl for f in self.families for lbl in f.labels)
        #: Per row, the reflector whose view of the tracker it guards (its incidence row, the
        #: beam rows of its laser line), -1 for the other rows, (m,).
        self.row_reflectors = np.concatenate([f.row_reflectors() for f in self.families]).astype(int)

    # ------------------------------------------------------------ layout
    def family_slices(self) -> list[tuple[RowFamily, slice]]:
        """Each family and its rows."""
        return list(zip(self.families, self._slices, strict=True))

    def family(self, cls: type) -> RowFamily | None:
        """The family of type ``cls``, or ``None``."""
        return next((f for f in self.families if isinstance(f, cls)), None)

    def row_slice(self, family: RowFamily) -> slice:
        """The rows of ``family`` (one of :attr:`families`)."""
        return self._slices[next(k for k, f in enumerate(self.families) if f is family)]

    @property
    def pairs(self) -> np.ndarray:
        """Capsule pairs (P, 2), segment indices."""
        f = self.family(CapsulePairRows)
        return f.pairs if f is not None else np.zeros((0, 2), dtype=int)

    @property
    def solid_pairs(self) -> SolidPairs:
        """The ``(segment, solid)`` rows."""
        f = self.family(SolidRows)
        return f.solids if f is not None else SolidPairs(self.cell, np.zeros((0, 2), dtype=int), np.zeros(0))

    @property
    def hull_pairs(self) -> HullPairs:
        """The link pairs checked on convex pieces."""
        f = self.family(HullRows)
        return f.hulls if f is not None else HullPairs({}, ())

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
        asked = set(kinds)
        n, nv = q.shape
        parts_v, parts_j = [np.zeros((n, 0))], [np.zeros((n, 0, nv))]
        for family in self.families:
            mask = np.array([k in asked for k in family.kinds], dtype=bool)
            if mask.any():
                v, j = family.compute(q, states, jacobian)
                parts_v.append(v[:, mask])
                if jacobian:
                    parts_j.append(j[:, mask])
        rows = self.row_mask(asked)
        values = np.concatenate(parts_v, axis=1)
        jac = np.concatenate(parts_j, axis=1) if jacobian else None
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
