r"""Rows on convex pieces of two links' geometry: one ``self`` row per link pair.

:math:`g = d(P_a, P_b) - m_d \ge 0` [m], :math:`d` the smallest signed distance
(coal) between the convex pieces of the two links
(:class:`~calib_oed.feasibility.hulls.HullPairs`: values, witnesses, gradients
and curvature, exact for the closest features, else the tangent-plane model).
coal is called per sample and link pair, so these rows are
:attr:`~calib_oed.feasibility.row_family.RowFamily.deferred`: the continuous
check evaluates them only where it needs them.
"""

from __future__ import annotations

import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.hulls import HullPairs
from calib_oed.feasibility.row_family import LINK, RowFamily, RowSides


class HullRows(RowFamily):
    """The rows of ``hulls`` (a :class:`HullPairs`), less the clearance margin ``clearance`` [m]."""

    deferred = True

    def __init__(self, hulls: HullPairs, clearance: float):
        self.hulls = hulls
        self.clearance = float(clearance)
        self.kinds = ("self",) * len(hulls)
        self.labels = hulls.labels

    def compute(self, q, states: BodyStates, jacobian):
        return self.hulls.rows(states, self.clearance, jacobian)

    def values(self, states: BodyStates, rows: np.ndarray) -> np.ndarray:
        """Values (n, k) [m] of ``rows`` (indices into the family) at every pose of ``states``."""
        return self.hulls.closest(states, rows).dist - self.clearance

    def hessians(self, states, pose, rows):
        return self.hulls.hessians(states, pose, rows)

    def sides(self):
        return RowSides(np.full((len(self), 2), LINK), self.hulls.link_pairs)

    def row_links(self):
        return tuple(frozenset(p) for p in self.hulls.link_pairs)
