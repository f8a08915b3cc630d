r"""The starts of the design's SQP, and the staged start of a large ``kpi_model`` design.

:func:`start_designs` builds the named starts (``"exchange"``, ``"heuristic"``) or checks a given
one. A ``kpi_model`` design of at least :data:`STAGED_MIN_POSES` poses with the exact Hessian and
the default budget starts instead from a smaller design measured twice (:func:`staged_starts`):

1. the default design of :math:`\lceil n/2\rceil` poses (itself staged when large enough);
2. its poses, then each again moved by seeded normal offsets of :data:`STAGED_OFFSET` rad
   (:func:`moved_copy`): an exact copy would stay one, the criterion being symmetric in the two;
3. :data:`STAGED_ITERATIONS` SQP iterations of the ``n``-pose design from there.

Why (fms_kr16, seed 0, ``docs/benchmarks.md``, "The staged start of a large kpi_model design"): at
500 poses an SQP iteration costs 15-23 s, and the direct design's 72 iterations end where half the
poses measured twice already are. Side by side on one machine the 500-pose design staged from the
direct 250-pose one is 8.75e-5 mm² in 947 s of CPU against the direct 1.314e-4 mm² in 1617 s; on the
realistic simulator (10 truths, paired) the direct design's achieved error is 1.21 +- 0.17 times the
staged one's, the promise held. At 250 poses the staged design's value is 7 % below the direct one's
at 57 % of the CPU, and on the realistic simulator (20 truths, paired) its achieved error is
0.91 +- 0.08 times the direct design's, so the stage starts at 250 poses; on ur5_table and on
fms_kr16 seed 1 (60 truths each) the direct design's is 1.06 +- 0.07 and 1.08 +- 0.06 times the
staged one's at 60-68 % of the CPU. (On another machine the 125-pose design twice with 40
iterations ended 21 % above the direct 250-pose design, with no realistic verdict.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from calib_oed.feasibility.batch_fk import batch_body_states
from calib_oed.oed.approximate_pool import approximate_start
from calib_oed.oed.problem import COLLISION_KINDS, NO_COLLISION_KINDS
from calib_oed.oed.starts import exchange_start, given_start, heuristic_start

#: Fewest poses of a staged ``kpi_model`` design (``docs/benchmarks.md``, "The staged start").
STAGED_MIN_POSES = 250
#: SQP iterations of the ``n``-pose design from the doubled start.
STAGED_ITERATIONS = 20
#: The ``n``-pose design's exact Hessian at every this many accepted points (``SQPSettings.hessian_every``;
#: every third with 36 iterations gained about 1 % at equal CPU at 500 poses, none on average at 250;
#: ``docs/benchmarks.md``, "The exact Hessian every k-th point").
STAGED_HESSIAN_EVERY = 1
#: Standard deviation of the seeded joint offsets of the moved copy [rad].
STAGED_OFFSET = 0.01
#: Draws of a moved pose, each with half the offset of the one before, before it is copied exactly.
STAGED_DRAWS = 6


def start_designs(s, objective, n: int, start, seed: int, n_starts: int, pool, replicates: int,
                  approx) -> list[tuple[int | None, np.ndarray]]:
    """The SQP's starts ``(seed, q0)``: ``n_starts`` named ones from ``seed + k`` (the exchange from
    the rounded approximate design ``approx`` when there is one, else on ``pool``; random feasible
    poses for ``"heuristic"``), or the given design ``start`` checked."""
    if isinstance(start, str):
        if start == "exchange" and approx is not None:  # start 0: the rounded approximate design
            return [(seed + k, approximate_start(objective, approx, n, None if k == 0 else seed + k,
                                                 replicates)[0]) for k in range(n_starts)]
        if start == "exchange":
            return [(seed + k, exchange_start(objective, pool, n, seed + k, replicates)[0])
                    for k in range(n_starts)]
        return [(seed + k, heuristic_start(s, n, seed + k)) for k in range(n_starts)]
    return [(None, given_start(s, start, n))]


def staged_half(objective, exact: bool, n: int, start, settings, aggregate: str) -> int:
    """Poses of the smaller design a design of ``n`` poses starts from, or 0 when it is not staged:
    ``kpi_model`` with the exact Hessian (``exact``), the exchange start, the mean aggregate, the
    default budget (``settings`` None) and ``n`` >= :data:`STAGED_MIN_POSES`."""
    staged = (exact and getattr(objective, "needs_design", False) and isinstance(start, str)
              and start == "exchange" and settings is None and aggregate == "mean" and n >= STAGED_MIN_POSES)
    return -(-int(n) // 2) if staged else 0


def staged_settings(settings):
    """The final stage's SQP settings: ``settings`` with :data:`STAGED_ITERATIONS` iterations and the
    exact Hessian every :data:`STAGED_HESSIAN_EVERY` accepted points."""
    return replace(settings, max_iterations=STAGED_ITERATIONS, hessian_every=STAGED_HESSIAN_EVERY)


def moved_copy(feasibility, q: np.ndarray, rng: np.random.Generator, collisions: bool = True,
               offset: float = STAGED_OFFSET, draws: int = STAGED_DRAWS) -> tuple[np.ndarray, int]:
    """``q`` (m, nq) moved by normal offsets of ``offset`` [rad] from ``rng``, clipped to the joint
    limits; a moved pose that violates a design row (incidence, and with ``collisions`` the capsule and
    beam rows) is drawn again with half the offset, ``draws`` times in all, then copied exactly.

    Returns:
        The copy (m, nq) [rad] and how many of its poses are exact copies.
    """
    robot = feasibility.robot
    kinds = COLLISION_KINDS if collisions else NO_COLLISION_KINDS
    copy, todo, sigma = q.copy(), np.arange(len(q)), float(offset)
    for _ in range(int(draws)):
        if not len(todo):
            break
        moved = np.clip(q[todo] + sigma * rng.standard_normal((len(todo), q.shape[1])), robot.lower, robot.upper)
        ok = feasibility.compute_from_states(moved, batch_body_states(robot.model, moved), False, kinds).feasible
        copy[todo[ok]] = moved[ok]
        todo, sigma = todo[~ok], 0.5 * sigma
    return copy, int(len(todo))


def staged_starts(half_design: Callable, feasibility, n: int, seed: int, n_starts: int,
                  collisions: bool = True) -> tuple[list[tuple[int, np.ndarray]], dict]:
    r"""The doubled starts of a staged design of ``n`` poses, and the record of their first stage.

    Args:
        half_design: ``half_design(seed=k)`` returns the smaller design
            (:class:`~calib_oed.oed.result.Design`) from seed ``k``.
        feasibility: The scene's feasibility model (the moved copy's rows).
        n: Poses of the design (the first ``n`` of the smaller one's twice).
        seed: Start ``k`` uses ``seed + k``, for its smaller design and its copy's offsets.
        n_starts: How many starts.
        collisions: Whether the copy keeps clear of the capsule and beam rows.

    Raises:
        KeyboardInterrupt: the smaller design was interrupted (no ``n``-pose design to return).
    """
    starts, stages = [], []
    for k in range(int(n_starts)):
        d = half_design(seed=seed + k)
        if d.solver.get("interrupted"):
            raise KeyboardInterrupt
        copy, exact = moved_copy(feasibility, d.q, np.random.default_rng(seed + k), collisions)
        starts.append((seed + k, np.vstack([d.q, copy])[:n]))
        stages.append({"seed": seed + k, "poses": len(d.q), "value": d.value, "start_value": d.start_value,
                       "iterations": d.solver.get("iterations"), "cpu_seconds": d.solver.get("cpu_seconds"),
                       "exact_copies": exact})
    return starts, {"iterations": STAGED_ITERATIONS, "hessian_every": STAGED_HESSIAN_EVERY,
                    "offset_rad": STAGED_OFFSET, "stages": stages}


__all__ = ["STAGED_DRAWS", "STAGED_HESSIAN_EVERY", "STAGED_ITERATIONS", "STAGED_MIN_POSES", "STAGED_OFFSET", "moved_copy",
           "staged_half", "staged_settings", "staged_starts", "start_designs"]
