r"""The rows the continuous check evaluates, split into cheap rows and rows on convex pieces.

The collision rows of a move (:mod:`calib_oed.program.continuous`) come from two
feasibility models of the scene: the design's (every collision row it keeps) and,
for the pairs its sampling pass dropped as never close, the model without the pass.
Most rows are capsule distances, half-spaces and solids, vectorised over all samples
at once. Rows on convex pieces of the link geometry (``hull_pairs``,
:mod:`calib_oed.feasibility.hulls`) call coal per sample and link pair: on ur5_table
with ``link_fit: hulls`` they are 95 % of an evaluation. The bisection only needs a
row's value at a new midpoint where that row is not yet certified on the interval
being split (a bound that holds on an interval holds on its halves), so
:class:`CollisionRows` evaluates the cheap rows of every sample and the rows on
convex pieces only for the (sample, row) pairs asked for.

The cheap rows are those of every family that is not
:attr:`~calib_oed.feasibility.row_family.RowFamily.deferred`; the rows on convex
pieces (:class:`~calib_oed.feasibility.hull_rows.HullRows`) are deferred. Values
are the model's own: :math:`g = d - m_d` [m], as
:meth:`calib_oed.feasibility.constraints.FeasibilityModel.compute_from_states`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.feasibility.bodies import BodyStates
from calib_oed.feasibility.constraints import FeasibilityModel
from calib_oed.feasibility.row_family import RowFamily, RowSides

COLLISION_KINDS = ("self", "obstacle")
SIGHT_KINDS = ("beam", "incidence")


@dataclass(frozen=True)
class Row:
    """One row of a model: its family, its index in the family, kind, label, pair label, links."""

    family: RowFamily
    index: int
    kind: str
    label: str
    pair: str
    links: frozenset[str] | None


def model_rows(model: FeasibilityModel) -> list[Row]:
    """Every row of ``model``, in the model's order."""
    return [Row(f, k, kind, label, pair, links)
            for f in model.families
            for k, (kind, label, pair, links) in enumerate(zip(f.kinds, f.labels, f.row_pair_labels, f.row_links(),
                                                              strict=True))]


class _Source:
    """The columns one model contributes: cheap rows (evaluated at every sample, with every
    row of their families) and deferred rows (evaluated on request)."""

    def __init__(self, model: FeasibilityModel, rows: list[Row], sight: list[Row] = ()):
        self.cheap_rows = [r for r in rows if not r.family.deferred]
        self.deferred = [r for r in rows if r.family.deferred]
        self.sight_rows = list(sight)
        used = {id(r.family) for r in self.cheap_rows + self.sight_rows}
        self.families = [f for f in model.families if id(f) in used]
        offset = dict(zip(map(id, self.families), np.cumsum([0] + [len(f) for f in self.families]), strict=False))
        self.cheap_cols = np.array([offset[id(r.family)] + r.index for r in self.cheap_rows], dtype=int)
        self.sight_cols = np.array([offset[id(r.family)] + r.index for r in self.sight_rows], dtype=int)

    def cheap(self, q: np.ndarray, states: BodyStates) -> np.ndarray:
        """Every row of the families of the cheap and sight rows, (n, sum of their sizes)."""
        parts = [np.zeros((len(q), 0))] + [f.compute(q, states, False)[0] for f in self.families]
        return np.concatenate(parts, axis=1)


class CollisionRows:
    """The collision and line-of-sight rows of the continuous check.

    Columns: the design's cheap collision rows, the extra model's cheap rows, the design's
    deferred rows, the extra model's deferred rows (``labels``, ``rows``); the first
    ``n_cheap`` are evaluated at every sample, the rest on request (:meth:`evaluate`).

    Args:
        feasibility: The design's model.
        ignore: Pair labels not checked.
        extra: The model without the sampling pass, or ``None``.
        extra_rows: The pairs the pass dropped as far
            (:class:`~calib_oed.feasibility.pairs.DroppedPair`): their rows of ``extra``
            are checked too.
    """

    def __init__(self, feasibility: FeasibilityModel, ignore: frozenset[str] = frozenset(),
                 extra: FeasibilityModel | None = None, extra_rows=()):
        design = model_rows(feasibility)
        mine = [r for r in design if r.kind in COLLISION_KINDS and r.pair not in ignore]
        self.design = _Source(feasibility, mine, [r for r in design if r.kind in SIGHT_KINDS
                                                  and not r.family.deferred])
        sources = [self.design]
        self.extra = None
        if extra is not None:
            have = {r.pair for r in mine}
            far = {d.label for d in extra_rows}
            # link pairs of the far self capsule pairs: the model without the pass may check
            # them on convex pieces
            far_links = {frozenset(d.links) for d in extra_rows if d.links is not None}
            theirs = [r for r in model_rows(extra) if r.kind in COLLISION_KINDS and r.pair not in have
                      and r.pair not in ignore
                      and (r.pair in far or (r.family.deferred and r.links in far_links))]
            self.extra = _Source(extra, theirs)
            sources.append(self.extra)
        cheap = [r for s in sources for r in s.cheap_rows]
        deferred = [r for s in sources for r in s.deferred]
        #: The rows, in column order.
        self.rows = tuple(cheap + deferred)
        self.labels = tuple(r.label for r in self.rows)
        self.n_cheap = len(cheap)
        self.sight_labels = tuple(r.label for r in self.design.sight_rows)
        self._sources = sources

    @property
    def n(self) -> int:
        return len(self.labels)

    def sides(self) -> RowSides:
        """What moves each side of each row (its family's :meth:`RowFamily.sides`)."""
        cache = {}
        for r in self.rows:
            if id(r.family) not in cache:
                cache[id(r.family)] = r.family.sides()
        got = [cache[id(r.family)] for r in self.rows]
        segs = np.array([g.segments[r.index] for g, r in zip(got, self.rows, strict=True)], dtype=int)
        return RowSides(segs.reshape(-1, 2), tuple(g.links[r.index] for g, r in zip(got, self.rows, strict=True)))

    def evaluate(self, q: np.ndarray, states: BodyStates, need: np.ndarray | None = None):
        """Collision rows (n, m) [m] and line-of-sight rows (n, m_s) at configurations ``q``
        with body states ``states``; a deferred column is evaluated where ``need`` (n, m - n_cheap)
        is True (default: everywhere) and NaN elsewhere."""
        n = len(q)
        parts, sight = [], None
        for source in self._sources:
            values = source.cheap(q, states)
            parts.append(values[:, source.cheap_cols])
            if sight is None:
                sight = values[:, source.sight_cols]
        deferred_rows = self.rows[self.n_cheap:]
        deferred = np.full((n, len(deferred_rows)), np.nan)
        if need is None or need.all():  # every deferred row at every sample: one call per family
            groups: dict[int, list[int]] = {}
            for col, r in enumerate(deferred_rows):
                groups.setdefault(id(r.family), []).append(col)
            for cols in groups.values():
                family = deferred_rows[cols[0]].family
                deferred[:, cols] = family.values(states, np.array([deferred_rows[c].index for c in cols]))
            return np.concatenate(parts + [deferred], axis=1), sight
        for col, r in enumerate(deferred_rows):
            idx = np.flatnonzero(need[:, col])
            if idx.size == n:
                deferred[:, col] = r.family.values(states, np.array([r.index]))[:, 0]
            elif idx.size:
                deferred[idx, col] = r.family.values(states.take(idx), np.array([r.index]))[:, 0]
        return np.concatenate(parts + [deferred], axis=1), sight
