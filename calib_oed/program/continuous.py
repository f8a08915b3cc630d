r"""Continuous collision check of joint-space moves: a certificate, not a few samples.

A move is the joint-space segment :math:`q(t) = q_0 + t\Delta`, :math:`t \in [0, 1]`,
:math:`\Delta = q_1 - q_0`. Every collision row of the scene's capsule model
(kinds ``self`` and ``obstacle`` of :class:`~calib_oed.feasibility.constraints.FeasibilityModel`,
the design's capsules and margins) is a function :math:`g_k(t)` [m], :math:`\ge 0` when
the margin is kept, and is Lipschitz in :math:`t` with the constant
:math:`L_k = (\rho_a + \rho_b)^\top |\Delta|` of :mod:`calib_oed.program.motion_bound`.
On an interval :math:`[t_a, t_b]` of length :math:`h` with end values
:math:`g_a, g_b` therefore

.. math::
    \min_{t \in [t_a, t_b]} g_k(t) \;\ge\; \max\big(g_a - L_k (t - t_a),\, g_b - L_k (t_b - t)\big)
    \;\ge\; \tfrac12\,(g_a + g_b - L_k h).

The check starts from a uniform grid, keeps every interval whose bound is
:math:`\ge -\delta` for every row (``move_tolerance`` :math:`\delta`, 1 mm: a move may
use up that much of the design's clearance margin, never more), and bisects
the others, evaluating all new midpoints in one batch. It ends

- **verified**: every interval certified: no row drops below :math:`-\delta` anywhere
  on the move (the bound holds between samples, so nothing is missed);
- **collision**: a sample has a row below :math:`-\delta`;
- **unverified**: an interval shorter than ``min_step`` or the evaluation budget
  still uncertified (a grazing contact at exactly :math:`-\delta`): treated as blocked.

Rows checked: every collision row of the design's model (the rows the design
keeps: capsule pairs, half-spaces, solids, rows on the link geometry), plus the
pairs its sampling pass dropped as "never closer than 100 mm in 2000 samples"
(sampling proves nothing about a move), from the model built without the pass;
a pair the pass dropped for another reason stays out, as in the design. Their
Lipschitz constants come from what moves each side of a row, as its family says
(:meth:`~calib_oed.feasibility.row_family.RowFamily.sides`, :func:`row_bounds`). Joint
limits need no check: the segment between two configurations inside the box
of limits stays inside. Laser beam and incidence rows are evaluated at
the same samples and *reported* (line of sight lost during the move: the tracker
re-locks), not enforced.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.constraints import FeasibilityModel
from calib_oed.feasibility.row_family import FIXED, LINK, RowSides
from calib_oed.program.interval_bounds import IntervalBounds
from calib_oed.program.motion_bound import piece_speed_bounds, segment_speed_bounds
from calib_oed.program.rows import CollisionRows


@dataclass(frozen=True)
class MoveCheck:
    """Outcome of the continuous check of one joint-space move.

    Attributes:
        verified: Every collision row is certified :math:`\\ge -\\delta` along the whole move.
        collision: A sample violates a row by more than :math:`\\delta` (certainly blocked).
        evaluations: Configurations evaluated.
        min_sampled: Smallest collision-row value at the samples [m] (0: exactly at the margin).
        worst_row: Label of that row.
        sight_lost: Rows of the laser beam or incidence negative at some sample (line of
            sight lost during the move: reported, allowed).
    """

    verified: bool
    collision: bool
    evaluations: int
    min_sampled: float
    worst_row: str
    sight_lost: tuple[str, ...] = ()

    @property
    def blocked(self) -> bool:
        """Not verified: the move needs via points."""
        return not self.verified


class MoveChecker:
    """Continuous collision checks of moves against a feasibility model.

    Args:
        feasibility: The design's model (with the sampling pass): every one of its collision
            rows is checked, the same rows the design keeps (capsule pairs, half-spaces,
            solids, rows on convex pieces of the link geometry, ...).
        tolerance: :math:`\\delta` [m], the margin a move may use up.
        ignore: Row labels not checked.
        min_step: Shortest interval in :math:`t` the bisection splits.
        max_evaluations: Evaluation budget per move.
        extra: The same scene's model without the sampling pass, for ``extra_rows``.
        extra_rows: The pairs the sampling pass dropped as "never closer than ..."
            (:class:`~calib_oed.feasibility.pairs.DroppedPair`; a sample proves nothing
            about a move): their rows of ``extra`` are checked too.
    """

    def __init__(self, feasibility: FeasibilityModel, tolerance: float = 0.001,
                 ignore: frozenset[str] = frozenset(), min_step: float = 1e-6,
                 max_evaluations: int = 20000, extra: FeasibilityModel | None = None,
                 extra_rows=()):
        self.feasibility = feasibility
        self.robot = feasibility.robot
        self.tolerance = float(tolerance)
        self.min_step = float(min_step)
        self.max_evaluations = int(max_evaluations)
        self.extra = extra
        self._rows = CollisionRows(feasibility, ignore, extra, extra_rows)
        self.collision_labels = self._rows.labels
        self.sight_labels = self._rows.sight_labels
        pieces = {**(extra.hull_pairs.pieces if extra is not None else {}), **feasibility.hull_pairs.pieces}
        sides = self._rows.sides()
        self._lipschitz, self._segments = row_bounds(self.robot, feasibility.segments, sides, pieces)
        # local constants (relative motion of self pairs, interval end points, piece axes)
        self._bounds = IntervalBounds(self.robot, feasibility.segments, pieces, sides.links, self._segments)
        self._lipschitz = self._lipschitz * self._bounds.relative
        self._ends = self._bounds.ends

    # ---------------------------------------------------------------- evaluation
    def rows(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Collision rows (n, m_c) and line-of-sight rows (n, m_s) [m or 1] at configurations (n, nq)."""
        g, s, _ = self._evaluate(q, distances=False)
        return g, s

    def _evaluate(self, q: np.ndarray, distances: bool = True, need: np.ndarray | None = None):
        """Collision rows, line-of-sight rows and end-point distances (or ``None``) at ``q``;
        the deferred rows (convex pieces) only where ``need`` says (:class:`CollisionRows`)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        states = compute_body_states(self.robot.model, q, jacobian=False)
        g, s = self._rows.evaluate(q, states, need)
        return g, s, (self._ends.distances(states) if distances else None)

    def _interval_lipschitz(self, lip, d_a, d_b, h, dq_abs, growth) -> np.ndarray:
        """Per interval and row, the smaller of the move's constant and the local one, (I, m)."""
        return self._bounds.local(lip, d_a, d_b, h, dq_abs, growth)

    def clearance(self, q: np.ndarray) -> np.ndarray:
        """Smallest collision row per configuration [m], (n,); >= 0: the full margin is kept."""
        c, _ = self.rows(q)
        return c.min(axis=1) if c.shape[1] else np.full(len(c), np.inf)

    def worst(self, q: np.ndarray) -> tuple[float, str]:
        """The smallest collision row at one configuration [m] and its label."""
        c, _ = self.rows(q)
        k = int(np.argmin(c[0]))
        return float(c[0, k]), self.collision_labels[k]

    def lipschitz(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """:math:`L_k` [m per unit t] of every collision row on the move ``q0 -> q1``."""
        return self._lipschitz @ np.abs(np.asarray(q1, float) - np.asarray(q0, float))

    def _grid(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """The first samples in t: one per 0.2 m of the largest Lipschitz constant, 2 to 33."""
        n0 = int(np.clip(np.ceil(self.lipschitz(q0, q1).max(initial=0.0) / 0.2), 1, 32)) + 1
        return np.linspace(0.0, 1.0, n0)

    def screen(self, q0: np.ndarray, q1: np.ndarray) -> bool:
        """True if the move certainly collides: a row below :math:`-\\delta` on the first
        grid of :meth:`check` (one batch; False proves nothing: :meth:`check` certifies).
        The rows on convex pieces, evaluated per sample and link pair, are left to
        :meth:`check` (on ur5_table they were two thirds of the screens' cost)."""
        q0 = np.asarray(q0, dtype=float)
        q1 = np.asarray(q1, dtype=float)
        t = self._grid(q0, q1)
        skip = np.zeros((len(t), self._rows.n - self._rows.n_cheap), dtype=bool)
        g, _, _ = self._evaluate(q0 + t[:, None] * (q1 - q0), distances=False, need=skip)
        return bool(np.any(g < -self.tolerance))

    def check(self, q0: np.ndarray, q1: np.ndarray) -> MoveCheck:
        """Certify the move ``q0 -> q1`` (see the module docstring)."""
        q0 = np.asarray(q0, dtype=float)
        q1 = np.asarray(q1, dtype=float)
        lip = self.lipschitz(q0, q1)
        t = self._grid(q0, q1)
        n0 = len(t)
        dq_abs = np.abs(q1 - q0)
        growth = self._ends.growth(dq_abs)
        g, s, d = self._evaluate(q0 + t[:, None] * (q1 - q0))
        gs, ss = [g], [s]
        ta, tb, ga, gb, da, db = t[:-1], t[1:], g[:-1], g[1:], d[:-1], d[1:]
        # rows not yet certified on each interval (a certified row stays so on the halves)
        open_ = np.ones((len(ta), g.shape[1]), dtype=bool)
        cheap = self._rows.n_cheap
        evaluations = n0
        verified = collision = False
        while True:
            if np.any(g < -self.tolerance):
                collision = True
                break
            h = tb - ta
            local = self._interval_lipschitz(lip, da, db, h, dq_abs, growth)
            bound = 0.5 * (ga + gb - local * h[:, None])
            open_ &= ~(bound >= -self.tolerance)
            bad = np.any(open_, axis=1)
            if not bad.any():
                verified = True
                break
            ta, tb, ga, gb, da, db, open_ = ta[bad], tb[bad], ga[bad], gb[bad], da[bad], db[bad], open_[bad]
            if np.min(tb - ta) < self.min_step or evaluations + len(ta) > self.max_evaluations:
                break
            tm = 0.5 * (ta + tb)
            g, s, d = self._evaluate(q0 + tm[:, None] * (q1 - q0), need=open_[:, cheap:])
            evaluations += len(tm)
            gs.append(g)
            ss.append(s)
            ta, tb = np.concatenate([ta, tm]), np.concatenate([tm, tb])
            ga, gb = np.concatenate([ga, g]), np.concatenate([g, gb])
            da, db = np.concatenate([da, d]), np.concatenate([d, db])
            open_ = np.concatenate([open_, open_])
        allg, alls = np.concatenate(gs), np.concatenate(ss)
        allg = np.where(np.isnan(allg), np.inf, allg)  # rows not evaluated at a sample
        if allg.shape[1]:
            k = np.unravel_index(int(np.argmin(allg)), allg.shape)
            min_sampled, worst = float(allg[k]), self.collision_labels[k[1]]
        else:
            min_sampled, worst = float("inf"), ""
        sight_labels = np.array(self.sight_labels)
        lost = tuple(str(x) for x in sight_labels[np.any(alls < 0, axis=0)]) if alls.shape[1] else ()
        return MoveCheck(verified, collision, evaluations, min_sampled, worst, lost)


def row_bounds(robot, segments, sides: RowSides, pieces=None) -> tuple[np.ndarray, np.ndarray]:
    r"""Per collision row, the vector :math:`\rho_a + \rho_b` of its Lipschitz constant (m, nv),
    and its segments (m, 2) (-1: a fixed set; -2: the row's bound only, no local tightening).

    From what moves each side of a row (``sides``, its family's
    :meth:`~calib_oed.feasibility.row_family.RowFamily.sides`): a side on a segment
    contributes :math:`\rho` of that segment (0 if world-fixed); a side on a robot link's
    geometry (rows on convex pieces) contributes the bound
    :func:`~calib_oed.program.motion_bound.piece_speed_bounds` of the link's pieces
    (``pieces``: ``{link: LinkPieces}``, the rows' own geometry: a convex hull of a slab of
    a mesh may reach outside the link's capsules) or, for a link not in ``pieces``,
    :math:`\max_k(\rho_k + r_k)` over the link's capsules, which enclose its geometry (a
    point within :math:`r_k` of an axis is at most :math:`r_k` farther from every joint);
    a fixed set (half-space, solid) contributes 0. A distance between two sets (coal's
    signed distance of convex pieces too) moves no more than their points do. A row whose
    sides are unknown takes twice the largest of these bounds, valid for any distance
    between robot parts or to a fixed set.
    """
    rho = segment_speed_bounds(robot, segments)
    grown = rho + np.asarray(segments.radius, dtype=float)[:, None] * (rho.max(axis=1, keepdims=True) > 0)
    links: dict[str, np.ndarray] = {}
    for k, link in enumerate(segments.links):
        if str(segments.roles[k]) in ("robot", "reflector"):
            links[str(link)] = np.maximum(links.get(str(link), 0.0), grown[k])
    for name, lp in (pieces or {}).items():
        links[str(name)] = piece_speed_bounds(robot, lp)
    fallback = 2.0 * grown.max(axis=0) if len(grown) else np.zeros(robot.model.nv)
    if links:
        fallback = np.maximum(fallback, 2.0 * np.max(list(links.values()), axis=0))
    m = len(sides.segments)
    bounds = np.zeros((m, rho.shape[1]))
    segs = np.asarray(sides.segments, dtype=int).copy()
    for r in range(m):
        pair = sides.links[r]
        if pair is not None and all(name in links for name in pair):
            bounds[r] = links[pair[0]] + links[pair[1]]
        elif np.any(segs[r] == LINK):
            bounds[r], segs[r] = fallback, (LINK, LINK)  # unknown sides: any distance
        else:
            for s in segs[r]:
                if s != FIXED:
                    bounds[r] += rho[s]
    return bounds, segs
