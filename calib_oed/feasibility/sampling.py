r"""Seeded random feasible configurations (the paper's heuristic designs).

Configurations are drawn uniformly in the joint ranges and kept if every
constraint holds, so the result is uniform on the feasible set. The incidence
limit alone keeps only about 1 in 500 draws of a 6R arm, so draws are
evaluated in large batches: forward kinematics vectorised over the batch
(:func:`~calib_oed.feasibility.batch_fk.batch_body_states`), then the cheap
joint and incidence rows on the whole batch, and the capsule pairs only on the
survivors.

When too few draws are feasible, :class:`~calib_oed.exceptions.SamplingError`
names the rows that block: for every row :math:`g_k \ge 0` the share of draws
it rejects and the range :math:`[\min g_k, \max g_k]` of its value over the
draws it was evaluated on. A row whose largest value is still negative
(:math:`\max g_k < 0`) rejects every draw: no uniform draw can ever pass it,
whatever the other rows; for a capsule pair that means the pair is never
separated by the clearance margin anywhere in the joint ranges (e.g. a motor
housing enclosed by the capsules of two neighbouring links).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib_oed.exceptions import SamplingError
from calib_oed.feasibility.batch_fk import batch_body_states
from calib_oed.feasibility.constraints import FEASIBILITY_TOL, FeasibilityModel

#: Rows named in a sampling error besides those that block every draw.
_NAMED_ROWS = 3


@dataclass
class RowStatistics:
    """What each constraint row did to the draws so far (SI: m, rad or 1 for incidence).

    Attributes:
        evaluated: Draws each row was evaluated on, (m,) (the capsule rows only
            on the draws that pass the joint and incidence rows).
        rejected: Draws each row rejected, (m,).
        low: Smallest value of each row, (m,) (``+inf`` if never evaluated).
        high: Largest value of each row, (m,) (``-inf`` if never evaluated).
        alone: Draws each row rejected while every other row held, (m,):
            the draws that dropping this row alone would have made feasible
            (counted for the capsule rows, on draws that pass the joint and
            incidence rows).
    """

    evaluated: np.ndarray
    rejected: np.ndarray
    low: np.ndarray
    high: np.ndarray
    alone: np.ndarray

    @classmethod
    def empty(cls, m: int) -> RowStatistics:
        return cls(np.zeros(m, dtype=int), np.zeros(m, dtype=int), np.full(m, np.inf),
                   np.full(m, -np.inf), np.zeros(m, dtype=int))

    def add(self, rows: np.ndarray, values: np.ndarray, alone: bool = False) -> None:
        """Account for ``values`` (n, len(rows)) of the rows ``rows``; with ``alone``, the
        other rows of the model are known to hold on these draws."""
        if values.shape[0] == 0:
            return
        violated = values < -FEASIBILITY_TOL
        self.evaluated[rows] += values.shape[0]
        self.rejected[rows] += np.sum(violated, axis=0)
        self.low[rows] = np.minimum(self.low[rows], values.min(axis=0))
        self.high[rows] = np.maximum(self.high[rows], values.max(axis=0))
        if alone:
            single = violated.sum(axis=1) == 1
            self.alone[rows] += np.sum(violated[single], axis=0)


def sample_feasible(
    model: FeasibilityModel,
    n: int,
    rng: np.random.Generator | int,
    *,
    batch: int = 4096,
    max_draws: int = 500_000,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """``n`` feasible configurations, uniform on the feasible set, (n, nq).

    Args:
        model: The constraints.
        n: How many configurations.
        rng: Seed or generator (same seed, same configurations).
        batch: Draws evaluated together.
        max_draws: Give up after this many draws.
        bounds: Draw in these joint ranges ``(lower, upper)``, each (nq,) [rad or m],
            instead of the robot's (e.g. the ranges of a calibration's training poses);
            None: the robot's joint limits.

    Raises:
        SamplingError: fewer than ``n`` feasible configurations in ``max_draws``
            draws; the message gives the acceptance rate, the share each
            constraint kind rejects, and names the rows that block (those that
            reject every draw, then the most rejecting ones) with their value
            range in mm (capsule pairs, as clearance beyond the margin) or
            degrees (incidence, joints).
    """
    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(rng)
    robot = model.robot
    lower, upper = (robot.lower, robot.upper) if bounds is None else (
        np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float))
    found: list[np.ndarray] = []
    count, draws = 0, 0
    stats = RowStatistics.empty(model.n_constraints)
    cheap_rows = np.flatnonzero(model.row_mask(("joint", "incidence")))
    pair_rows = np.flatnonzero(~model.row_mask(("joint", "incidence")))
    rejected = {kind: 0 for kind in model.kind_slices()}  # draws each kind rejects
    while count < n:
        if draws >= max_draws:
            raise SamplingError(_failure_message(model, n, count, draws, rejected, stats))
        q = rng.uniform(lower, upper, size=(batch, robot.nq))
        draws += batch
        states = batch_body_states(robot.model, q)
        cheap = model.compute_from_states(q, states, jacobian=False, kinds=("joint", "incidence"))
        stats.add(cheap_rows, cheap.values)
        for kind in ("joint", "incidence"):
            cols = [i for i, k in enumerate(cheap.kinds) if k == kind]
            if cols:
                rejected[kind] += int(np.any(cheap.values[:, cols] < 0, axis=1).sum())
        idx = np.flatnonzero(cheap.feasible)
        if idx.size == 0:
            continue
        full = model.compute_from_states(q[idx], states.take(idx), jacobian=False)
        stats.add(pair_rows, full.values[:, pair_rows], alone=True)
        for kind in ("self", "obstacle", "beam"):
            cols = [i for i, k in enumerate(full.kinds) if k == kind]
            if cols:
                rejected[kind] += int(np.any(full.values[:, cols] < 0, axis=1).sum())
        ok = idx[full.feasible]
        found.append(q[ok])
        count += ok.size
    return np.concatenate(found, axis=0)[:n] if found else np.zeros((0, robot.nq))


def _failure_message(model: FeasibilityModel, n: int, count: int, draws: int,
                     rejected: dict[str, int], stats: RowStatistics) -> str:
    worst = ", ".join(f"{kind} {k / draws:.1%}" for kind, k in
                      sorted(rejected.items(), key=lambda kv: -kv[1]) if k)
    text = (f"only {count} of {n} feasible configurations in {draws} uniform draws "
            f"(acceptance {count / max(draws, 1):.2e}); share of draws rejected by each "
            f"constraint kind (self, obstacle and beam are only evaluated on draws that pass "
            f"the joint and incidence rows): {worst}.")
    blocking, named = describe_blocking_rows(model, stats)
    if blocking:
        text += " Blocking every draw: " + "; ".join(blocking) + "."
    if named:
        text += " Rejecting most: " + "; ".join(named) + "."
    alone = [k for k in np.argsort(-stats.alone, kind="stable")[:_NAMED_ROWS] if stats.alone[k]]
    if alone:
        text += (" The only violated row in a draw that passes every other: "
                 + "; ".join(f"{model.labels[k]} in {stats.alone[k]} draw(s)" for k in alone) + ".")
    return text + (" Loosen those constraints or their margins in the scene's feasibility "
                   "block, exclude a pair that cannot collide (feasibility.excluded_pairs), or "
                   "check the cell (tracker visible from the working volume?)")


def describe_blocking_rows(model: FeasibilityModel, stats: RowStatistics,
                           limit: int = _NAMED_ROWS) -> tuple[list[str], list[str]]:
    """Text for the rows that reject every draw they saw, and the ``limit`` most rejecting others.

    Capsule rows are described by their clearance (row value + the clearance
    margin) [mm], incidence rows by the angle to the tracker [deg], joint rows
    by their value [deg or mm].
    """
    seen = stats.evaluated > 0
    share = np.where(seen, stats.rejected / np.maximum(stats.evaluated, 1), 0.0)
    always = np.flatnonzero(seen & (stats.high < 0))
    others = [k for k in np.argsort(-share, kind="stable")
              if seen[k] and 0 < share[k] and k not in set(always)][:limit]
    return ([_describe(model, stats, k, share[k]) for k in always],
            [_describe(model, stats, k, share[k]) for k in others])


def _describe(model: FeasibilityModel, stats: RowStatistics, k: int, share: float) -> str:
    kind, label = model.kinds[k], model.labels[k]
    lo, hi, seen = stats.low[k], stats.high[k], stats.evaluated[k]
    head = f"{label} rejects {share:.1%} of the {seen} draws it was evaluated on"
    if kind in ("self", "obstacle", "beam"):
        m = model.settings.margins.clearance
        return (f"{head}, clearance {(lo + m) * 1e3:.1f} to {(hi + m) * 1e3:.1f} mm "
                f"(margin {m * 1e3:.1f} mm)")
    if kind == "incidence":
        limit = model.settings.incidence_limit - model.settings.margins.incidence
        # g = cos(angle) - cos(limit): the angle to the tracker ranges over
        angles = np.degrees(np.arccos(np.clip(np.array([hi, lo]) + np.cos(limit), -1.0, 1.0)))
        return (f"{head}, angle to the tracker {angles[0]:.1f} to {angles[1]:.1f} deg "
                f"(allowed up to {np.degrees(limit):.1f} deg)")
    return f"{head}, value {lo:.4g} to {hi:.4g} (rad or m)"
