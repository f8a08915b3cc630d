r"""Witnesses of the convex-piece rows, and their memo per pose across evaluations.

An SQP evaluates the rows of :mod:`calib_oed.feasibility.hulls` at a trial point (every
row of every pose), and once that point is accepted asks again for the witnesses of a
few rows at the same point: for their curvature
(:meth:`~calib_oed.feasibility.hulls.HullPairs.hessians`) and the pieces of the kinked
ones (:mod:`calib_oed.feasibility.hull_pieces`). Those answers are the same coal calls
on the same placements. :class:`WitnessMemo` keeps, per pose, the witnesses of every row,
keyed by the exact bytes of the placements of the bodies that carry the pieces
(:math:`R_{W,k}, t_{W,k}`): a later call with bit-identical placements (the same
:math:`q` through the same forward kinematics) takes them from the memo instead of
calling coal again. A pose whose placements differ in any bit is computed afresh, so
the memo never changes a value, a witness or a gradient: it is a pure function of the
placements, as the computation it replaces (``tests/feasibility/test_hull_witness.py``
checks both give the same arrays, bit for bit).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ["HullWitness", "WitnessMemo"]

#: Poses the memo keeps (the oldest go first): a few evaluations of a large design.
MEMO_POSES = 4096


@dataclass(frozen=True, eq=False)
class HullWitness:
    """Closest points of the link pairs' pieces, per pose.

    Attributes:
        dist: Signed distance :math:`\\min d(P, Q)` [m], (n, H).
        wa, wb: Witness points on the first and second link, world [m], (n, H, 3).
        u: Unit normal from ``wb`` towards ``wa``, (n, H, 3).
        calls: coal distance calls made (the broad phase's cost; 0 for poses from the memo).
        piece_a, piece_b: The closest pair's pieces (indices into the model's pieces), (n, H).
    """

    dist: np.ndarray
    wa: np.ndarray
    wb: np.ndarray
    u: np.ndarray
    calls: int
    piece_a: np.ndarray | None = None
    piece_b: np.ndarray | None = None

    def pack(self) -> np.ndarray:
        """One row of floats per pose, (n, 12 H): dist, wa, wb, u, piece_a, piece_b (exact)."""
        n = self.dist.shape[0]
        return np.concatenate([self.dist, self.wa.reshape(n, -1), self.wb.reshape(n, -1),
                               self.u.reshape(n, -1), self.piece_a, self.piece_b], axis=1)

    @staticmethod
    def unpack(packed: np.ndarray, calls: int = 0) -> HullWitness:
        """The witnesses of :meth:`pack`'s rows (n, 12 H)."""
        n, h = packed.shape[0], packed.shape[1] // 12
        cut = np.cumsum([h, 3 * h, 3 * h, 3 * h, h])
        dist, wa, wb, u, pa, pb = np.split(packed, cut, axis=1)
        return HullWitness(dist, wa.reshape(n, h, 3), wb.reshape(n, h, 3), u.reshape(n, h, 3), calls,
                           pa.astype(int), pb.astype(int))

    def take(self, rows: np.ndarray) -> HullWitness:
        """The witnesses of rows ``rows`` (indices into H) only."""
        return HullWitness(self.dist[:, rows], self.wa[:, rows], self.wb[:, rows], self.u[:, rows],
                           self.calls, self.piece_a[:, rows], self.piece_b[:, rows])


class WitnessMemo:
    """Witnesses of every row per pose, keyed by the placements of ``bodies`` (module docstring).

    Args:
        bodies: The bodies whose placements the witnesses depend on (the pieces' bodies).
        size: Poses kept, the oldest dropped first.
    """

    def __init__(self, bodies: np.ndarray, size: int = MEMO_POSES):
        self.bodies = np.unique(np.asarray(bodies, dtype=int))
        self.size = int(size)
        self._rows: dict[bytes, np.ndarray] = {}
        #: Poses answered from the memo and poses computed, since the model was built.
        self.hits = 0
        self.misses = 0

    def keys(self, rotation: np.ndarray, translation: np.ndarray) -> list[bytes]:
        """One key per pose of placements ``rotation`` (n, nb, 3, 3), ``translation`` (n, nb, 3)."""
        n = rotation.shape[0]
        flat = np.concatenate([rotation[:, self.bodies].reshape(n, -1),
                               translation[:, self.bodies].reshape(n, -1)], axis=1)
        return [row.tobytes() for row in np.ascontiguousarray(flat)]

    def find(self, keys: list[bytes]) -> tuple[np.ndarray, list[np.ndarray]]:
        """The poses (indices into ``keys``) found, and their packed witnesses."""
        found, rows = [], []
        for k, key in enumerate(keys):
            row = self._rows.get(key)
            if row is not None:
                found.append(k)
                rows.append(row)
        self.hits += len(found)
        self.misses += len(keys) - len(found)
        return np.array(found, dtype=int), rows

    def store(self, keys: list[bytes], witness: HullWitness) -> None:
        """Keep the witnesses of every row of the poses ``keys`` (the oldest beyond ``size`` go)."""
        if len(keys) > self.size:
            return
        for key, row in zip(keys, witness.pack(), strict=True):
            self._rows[key] = row
        excess = len(self._rows) - self.size  # the oldest first (insertion order), no copy of every key
        for old in list(itertools.islice(self._rows, max(0, excess))):
            self._rows.pop(old, None)  # another thread may have dropped it
