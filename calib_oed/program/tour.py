r"""The order of the measurement poses: a closed tour from home through every pose.

Node 0 is the home configuration, nodes :math:`1..n` the design's poses; the
cost :math:`C_{ij}` [s] is the travel time of the move (direct, or through its
planned via points), and a tour's cycle time adds the dwell at every pose:

.. math::
    T_{cycle} = \sum_{k=0}^{n} C_{\pi_k \pi_{k+1}} + n\, t_{dwell},
    \qquad \pi_0 = \pi_{n+1} = 0.

Orders compared: the design's (:math:`\pi = 0, 1, ..., n, 0`), nearest neighbour
from home (always the cheapest next pose), and the optimised tour of a TSP
solver, LKH-3 through ``elkai``. A solver's tour is never returned worse than nearest
neighbour: the better of the two is kept (and the choice reported).
"""

from __future__ import annotations

import numpy as np

#: LKH runs per solve (elkai's default is 10): the build re-solves several times, each
#: run of LKH-3 on 61 nodes is already near-optimal (bench/bench_program.py).
RUNS = 1
#: LKH-3 parameters beyond RUNS: trials per run (LKH's default: the number of nodes) and
#: its initial period. On the 68 re-solves of an fms_kr16 program (60 poses, many moves
#: blocked by the floor) they cut a solve from 29 to 7 ms CPU for tours 0.04 % longer in
#: total (docs/benchmarks.md, issue 20).
LKH_PARAMETERS = "MAX_TRIALS = 10\nINITIAL_PERIOD = 10\n"


def tour_time(cost: np.ndarray, order: np.ndarray) -> float:
    """Travel time [s] of the closed tour home -> ``order`` (pose nodes 1..n) -> home."""
    nodes = np.concatenate([[0], np.asarray(order, dtype=int), [0]])
    return float(cost[nodes[:-1], nodes[1:]].sum())


def nearest_neighbour(cost: np.ndarray) -> np.ndarray:
    """Greedy tour from home (node 0): always the cheapest unvisited node (ties: lowest index)."""
    n = len(cost) - 1
    left = np.ones(n + 1, dtype=bool)
    left[0] = False
    order, here = [], 0
    for _ in range(n):
        row = np.where(left, cost[here], np.inf)
        here = int(np.argmin(row))
        left[here] = False
        order.append(here)
    return np.array(order, dtype=int)


def solve_tour(cost: np.ndarray) -> tuple[np.ndarray, str]:
    """The optimised order of the pose nodes 1..n and which order won.

    Args:
        cost: Move times [s], (n+1, n+1), node 0 = home.

    Returns:
        The order (n,) and ``"lkh"``, or ``"nearest neighbour"`` if LKH's tour was not better.
    """
    cost = np.asarray(cost, dtype=float)
    n = len(cost) - 1
    nn = nearest_neighbour(cost)
    if n <= 2:
        return nn, "nearest neighbour"
    order = _lkh(cost)
    if tour_time(cost, order) > tour_time(cost, nn):
        return nn, "nearest neighbour"
    return order, "lkh"


def _rotate_to_home(tour: list[int]) -> np.ndarray:
    tour = [int(k) for k in tour]
    if len(tour) > 1 and tour[0] == tour[-1]:
        tour = tour[:-1]
    k = tour.index(0)
    tour = tour[k:] + tour[:k]
    return np.array(tour[1:], dtype=int)


def _lkh(cost: np.ndarray) -> np.ndarray:
    import elkai

    # integer arc costs [ms]: LKH multiplies them by its precision (100) in C integers, so
    # costs must stay far below 2**31 / 100 ms (build.UNREACHABLE is 1e3 s = 1e6 ms)
    scaled = np.rint(np.minimum(cost, 1e3) * 1e3).astype(np.int64)
    solve = getattr(getattr(elkai, "_elkai", None), "solve_problem", None)
    if solve is None or not np.array_equal(scaled, scaled.T):  # elkai's own call: RUNS only
        tour = elkai.DistanceMatrix(scaled.tolist()).solve_tsp(runs=RUNS)
    else:  # what DistanceMatrix.solve_tsp sends to LKH-3, with LKH_PARAMETERS added
        n = len(scaled)
        problem = (f"TYPE : TSP\nDIMENSION : {n}\nEDGE_WEIGHT_TYPE : EXPLICIT\n"
                   "EDGE_WEIGHT_FORMAT : FULL_MATRIX\nEDGE_WEIGHT_SECTION\n"
                   + "".join(" ".join(map(str, row)) + "\n" for row in scaled.tolist()))
        tour = [k - 1 for k in solve(f"RUNS = {RUNS}\n{LKH_PARAMETERS}PROBLEM_FILE = :stdin:\n", problem)]
    order = _rotate_to_home(tour)
    # a symmetric cost: both directions are the same tour; keep the one elkai gives
    return order
