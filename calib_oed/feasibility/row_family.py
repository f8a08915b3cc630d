r"""A family of constraint rows: one kind of geometry, its values, derivatives and labels.

Every feasibility row is :math:`g(q) \ge 0` in SI for one pose. A
:class:`RowFamily` owns a set of such rows that share their geometry (joint
limits, incidence, capsule pairs, capsules against half-spaces, against solids,
convex pieces of two links) and answers every question asked of a row:

- values and Jacobians :math:`\partial g/\partial q` (:meth:`RowFamily.compute`),
- second derivatives :math:`\partial^2 g/\partial q^2` of chosen rows
  (:meth:`RowFamily.hessians`; the SQP's exact Hessian,
  :mod:`calib_oed.feasibility.curvature`),
- the kind (``joint``, ``incidence``, ``self``, ``obstacle``, ``beam``) and
  label of each row, the pair each row belongs to (a capsule against a
  half-space gives one row per axis end point, both of one pair),
- which reflector's view of the tracker a row guards (:meth:`RowFamily.row_reflectors`:
  its incidence row, the beam rows of its laser line),
- what moves each side of a row (:meth:`RowFamily.sides`): the data the
  continuous check of moves bounds the row's speed from
  (:mod:`calib_oed.program.continuous`),
- which pairs the sampling pass drops (:meth:`RowFamily.prune_reason`) and the
  family restricted to the pairs kept (:meth:`RowFamily.subset`).

:class:`~calib_oed.feasibility.constraints.FeasibilityModel` stacks its
families in a fixed order; a new kind of constraint is a new family.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from calib_oed.feasibility.bodies import BodyStates

#: Side of a row that is a world-fixed set (half-space, solid, obstacle capsule).
FIXED = -1
#: Side of a row that is a robot link's geometry (not one capsule axis): see :attr:`RowSides.links`.
LINK = -2


@dataclass(frozen=True)
class RowSides:
    """What moves the two sides of each row of a family (for speed bounds).

    Attributes:
        segments: (m, 2) per row and side: the segment (capsule axis) index of the
            model's :class:`~calib_oed.feasibility.constraints.SegmentTable`,
            :data:`FIXED` for a world-fixed set, :data:`LINK` for a link's geometry.
        links: Per row, the two links of a row on link geometry, else ``None``.
    """

    segments: np.ndarray
    links: tuple[tuple[str, str] | None, ...]

    @classmethod
    def unknown(cls, m: int) -> RowSides:
        """Rows that are no distance between two sets (joint limits, incidence)."""
        return cls(np.full((m, 2), LINK), (None,) * m)


def prune_reason(lo: float, hi: float, samples: int, distance: float) -> str | None:
    """Why the sampling pass drops a pair with clearance range [lo, hi] [m], or ``None``."""
    if hi - lo < 1e-9:
        if lo < 0:
            return f"overlapping in every configuration ({lo * 1e3:.1f} mm, constant)"
        return f"constant clearance ({lo * 1e3:.1f} mm)"
    if hi < 0:
        return (f"overlapping in every one of {samples} samples "
                f"(clearance {lo * 1e3:.1f} to {hi * 1e3:.1f} mm): capsules too coarse?")
    if lo > distance:
        return f"never closer than {distance * 1e3:.0f} mm in {samples} samples"
    return None


class RowFamily(abc.ABC):
    """Rows of one kind of geometry (module docstring).

    Subclasses set ``kinds`` and ``labels`` (one per row) and, for rows grouped in
    pairs, ``pair_of_row`` and ``pair_labels``.
    """

    kinds: tuple[str, ...] = ()
    labels: tuple[str, ...] = ()
    #: Rows evaluated per sample and pair by an external library (slow): the continuous
    #: check evaluates them only where it needs them.
    deferred: bool = False
    #: Rows whose second derivative is zero (joint limits): no curvature asked.
    linear: bool = False
    #: The segment table (``SegmentTable``) of families whose rows are on capsule axes, else ``None``.
    segments = None

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def pair_of_row(self) -> np.ndarray:
        """The pair each row belongs to, (m,) (default: one row per pair)."""
        return np.arange(len(self))

    @property
    def pair_labels(self) -> tuple[str, ...]:
        """Label of each pair (default: the row labels)."""
        return self.labels

    @property
    def row_pair_labels(self) -> tuple[str, ...]:
        """Label of the pair of each row, (m,)."""
        pairs = self.pair_labels
        return tuple(pairs[p] for p in self.pair_of_row)

    def row_reflectors(self) -> np.ndarray:
        """Per row, the reflector whose laser line (a beam segment of :attr:`segments`) is one
        side of it, -1 for rows with no beam side, (m,)."""
        if self.segments is None:
            return np.full(len(self), -1)
        seg = self.sides().segments
        return np.where(seg >= 0, self.segments.beam_of[np.maximum(seg, 0)], -1).max(axis=1, initial=-1)

    def row_links(self) -> tuple[frozenset[str] | None, ...]:
        """Per row, the robot links on both sides of a self row (``None`` otherwise)."""
        return (None,) * len(self)

    def pair_links(self) -> tuple[frozenset[str] | None, ...]:
        """Per pair, the robot links on both sides of a self pair (``None`` otherwise)."""
        links = [None] * len(self.pair_labels)
        for row, p in zip(self.row_links(), self.pair_of_row, strict=True):
            links[p] = row
        return tuple(links)

    @abc.abstractmethod
    def compute(self, q: np.ndarray, states: BodyStates, jacobian: bool):
        """Values (n, m) and Jacobians (n, m, nv) (``None`` without ``jacobian``)."""

    def hessians(self, states: BodyStates, pose: np.ndarray, rows: np.ndarray) -> np.ndarray:
        r""":math:`\partial^2 g/\partial q^2` (K, nv, nv) of ``rows`` (K,) of this family at
        poses ``pose`` (K,) of ``states`` (with Jacobians). Default: zero (linear rows)."""
        nv = states.jacobian.shape[-1]
        return np.zeros((len(pose), nv, nv))

    def sides(self) -> RowSides:
        """What moves each side of each row (default: unknown, bounded as any distance)."""
        return RowSides.unknown(len(self))

    def prune_reason(self, lo: float, hi: float, samples: int, distance: float) -> str | None:
        """Why the sampling pass drops a pair with sampled clearance [lo, hi] [m], or ``None``."""
        return prune_reason(lo, hi, samples, distance)

    def subset(self, keep: np.ndarray) -> RowFamily:
        """The family with the pairs ``keep`` (bool per pair) only."""
        raise NotImplementedError(f"{type(self).__name__} has no pairs to drop")

    def pair_clearance(self, values: np.ndarray, margin: float) -> np.ndarray:
        """Clearance of each pair (n, pairs) [m] from the family's row ``values`` (n, m):
        the smallest of its rows plus the margin."""
        out = np.full((len(values), len(self.pair_labels)), np.inf)
        np.minimum.at(out.T, self.pair_of_row, values.T + margin)
        return out
