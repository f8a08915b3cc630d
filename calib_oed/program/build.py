r"""Build a measurement program: order the poses, certify every move, plan the blocked ones.

The steps (docs/program.md):

1. nodes: home (node 0, from ``program.home``, ``--home`` or the scene's first KPI
   working configuration) and the design's poses; each must keep the collision
   rows of the capsule model (:math:`g \ge -\delta`), else a :class:`ProgramError` names it;
2. cost matrix :math:`C_{ij}` [s]: direct PTP move times (:mod:`calib_oed.program.timing`);
3. solve the tour (:mod:`calib_oed.program.tour`); screen its new moves (one
   batch of samples: a certain collision costs :data:`UNREACHABLE` at once, and
   the tour is solved again), then check every move of it continuously
   (:mod:`calib_oed.program.continuous`); a blocked move costs
   :data:`UNREACHABLE` and the tour is solved again, until the tour's moves are
   all checked; the blocked moves it still uses get via points
   (:mod:`calib_oed.program.planner`) and cost their planned path's time; solve
   again, until nothing changes. Each round checks a new move or plans a new
   one, and there are finitely many: this ends. The same for nearest neighbour;
   the better of the two is the program.

Every move of the returned program is certified and priced with its planned
path. The design order's cycle time uses planned paths with ``plan_baselines``,
else direct times for its blocked moves: a lower bound (a detour only adds
time), so the reported gain of the optimised tour is, if anything, understated.
"""

from __future__ import annotations

import time

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.program.continuous import MoveChecker, overlapping_pairs
from calib_oed.program.planner import plan_move
from calib_oed.program.records import Move, Program
from calib_oed.program.settings import ProgramSettings
from calib_oed.program.timing import JointDynamics
from calib_oed.program.tour import design_order, nearest_neighbour, solve_tour, tour_time

#: Cost [s] of a move no plan connects: the tour avoids it if it can (more than any
#: tour of direct moves takes; small enough for LKH's integer arithmetic).
UNREACHABLE = 1e3


def move_checker(scene, settings: ProgramSettings) -> MoveChecker:
    """The continuous check of a scene: its capsule model without the sampling pass's pruning."""
    from calib_oed.feasibility.pairs import feasibility_from_scene

    _, report = feasibility_from_scene(scene)
    full, _ = feasibility_from_scene(scene, prune=False)
    return MoveChecker(full, settings.move_tolerance, overlapping_pairs(report))


def home_configuration(scene, settings: ProgramSettings) -> tuple[np.ndarray, str]:
    """The home configuration [rad] and where it came from."""
    if settings.home is not None:
        home = np.asarray(settings.home, dtype=float)
        return scene.robot.check_configurations(home[None])[0], "home: given (program.home or --home)"
    configurations = scene.kpi.configurations
    if not configurations:
        raise ProgramError("home", None, "the scene has no program.home and no KPI working "
                           "configuration: give --home")
    wc = configurations[0]
    return np.asarray(wc.q, dtype=float), (f"home: the KPI working configuration {wc.name!r} "
                                           "(no program.home in the scene, no --home)")


class _Moves:
    """Checked (and planned) moves between nodes, priced into the cost matrix.

    A blocked move costs :data:`UNREACHABLE` until it is planned (:meth:`plan`);
    then the planned path's time (or still :data:`UNREACHABLE` if no plan)."""

    def __init__(self, nodes, checker: MoveChecker, dyn: JointDynamics, settings, joint_margin):
        self.nodes, self.checker, self.dyn, self.settings = nodes, checker, dyn, settings
        self.joint_margin = joint_margin
        self.direct = dyn.time_matrix(nodes)
        self.cost = self.direct.copy()
        self.known: dict[tuple[int, int], Move] = {}
        self.screened: set[tuple[int, int]] = set()
        self.screens = 0

    def screen(self, i: int, j: int) -> None:
        """The cheap first look (one batch of samples): a certain collision is priced at once."""
        a, b = min(i, j), max(i, j)
        if (a, b) in self.screened or (a, b) in self.known:
            return
        self.screened.add((a, b))
        self.screens += 1
        if self.checker.screen(self.nodes[a], self.nodes[b]):
            self.cost[a, b] = self.cost[b, a] = UNREACHABLE

    def get(self, i: int, j: int) -> Move:
        """The move ``i -> j``, checked (not planned) on first use."""
        a, b = min(i, j), max(i, j)
        if (a, b) not in self.known:
            check = self.checker.check(self.nodes[a], self.nodes[b])
            self.known[(a, b)] = Move(a, b, self.nodes[[a, b]], float(self.direct[a, b]), check)
            if not check.verified:
                self.cost[a, b] = self.cost[b, a] = UNREACHABLE
        move = self.known[(a, b)]
        return move if move.start == i else move.reversed()

    def plan(self, i: int, j: int) -> Move:
        """The move ``i -> j`` through via points if its direct move is blocked."""
        move = self.get(i, j)
        a, b = min(i, j), max(i, j)
        if move.direct.verified or move.plan is not None:
            return move
        plan = plan_move(self.checker, self.nodes[a], self.nodes[b], self.settings.planner_time,
                         self.settings.planner_seed, self.joint_margin)
        cost = self.dyn.path_time(plan.waypoints) if plan.success else UNREACHABLE
        self.cost[a, b] = self.cost[b, a] = cost
        self.known[(a, b)] = Move(a, b, plan.waypoints, cost, move.direct, plan)
        return self.get(i, j)

    def settle(self, solve, limit: int) -> np.ndarray:
        """Re-solve until the tour's moves are all checked and its blocked ones planned."""
        order = solve(self.cost)
        for _ in range(limit):
            edges = _edges(order)
            unseen = [e for e in edges if (min(e), max(e)) not in self.screened | self.known.keys()]
            for i, j in unseen:
                self.screen(i, j)
            if any(self.cost[e] >= UNREACHABLE for e in unseen):
                order = solve(self.cost)  # a certain collision: avoid it before certifying
                continue
            fresh = [e for e in edges if (min(e), max(e)) not in self.known]
            for i, j in fresh:
                self.get(i, j)
            if not fresh:
                unplanned = [e for e in edges if self.cost[e] >= UNREACHABLE
                             and self.known[(min(e), max(e))].plan is None]
                if not unplanned:
                    return order
                for i, j in unplanned:
                    self.plan(i, j)
            order = solve(self.cost)
        return order

    def lower_bound(self, order: np.ndarray) -> float:
        """Travel time of a tour with unplanned blocked moves at their direct time (a lower bound)."""
        total = 0.0
        for i, j in _edges(order):
            c = self.cost[i, j]
            total += self.direct[i, j] if c >= UNREACHABLE else c
        return float(total)


def _edges(order: np.ndarray) -> list[tuple[int, int]]:
    nodes = np.concatenate([[0], np.asarray(order, dtype=int), [0]])
    return [(int(i), int(j)) for i, j in zip(nodes[:-1], nodes[1:], strict=True)]


def build_program(scene, q: np.ndarray, settings: ProgramSettings | None = None,
                  checker: MoveChecker | None = None, plan_baselines: bool = False) -> Program:
    """The ordered, collision-checked program of design ``q`` (n, nq) [rad] in ``scene``.

    Args:
        scene: The scene (robot, cell, capsules, margins, ``program:`` block).
        q: The design's poses [rad], (n, nq), in design order.
        settings: Timing, check and planner settings (default: :class:`ProgramSettings`).
        checker: A prepared continuous check (default: built from the scene).
        plan_baselines: Plan the blocked moves of the design order too, so its cycle time
            uses planned paths; otherwise they count at their direct time, a lower bound
            (a detour only adds time), which understates the optimised tour's gain.
    """
    start = time.process_time()
    settings = settings or ProgramSettings()
    robot = scene.robot
    q = robot.check_configurations(np.asarray(q, dtype=float))
    checker = checker or move_checker(scene, settings)
    dyn = JointDynamics.from_robot(robot, settings)
    home, note = home_configuration(scene, settings)
    nodes = np.vstack([home, q])
    clearance = checker.clearance(nodes)
    for k in np.flatnonzero(clearance < -settings.move_tolerance):
        value, row = checker.worst(nodes[k])
        what = "home" if k == 0 else f"pose {k}"
        raise ProgramError(what, f"{row} {value * 1e3:.1f} mm", "in collision by the scene's capsule "
                           "model (margin included): the design does not fit this scene (check it "
                           "with `calib-oed evaluate`)" if k else "in collision by the scene's capsule "
                           "model: choose another --home")
    moves = _Moves(nodes, checker, dyn, settings, scene.feasibility.margins.joint)
    n = len(q)
    dwell = n * settings.dwell
    limit = 10 * n + 10
    winner = [settings.solver]

    def solver(cost):
        order, who = solve_tour(cost, settings.solver)
        winner[0] = who
        return order

    order = moves.settle(solver, limit)
    nn = moves.settle(nearest_neighbour, limit)
    if tour_time(moves.cost, nn) < tour_time(moves.cost, order):
        order, winner[0] = nn, "nearest neighbour"
    design = design_order(n)
    for i, j in _edges(design):  # without plan_baselines only the first batch of samples
        moves.plan(i, j) if plan_baselines else moves.screen(i, j)
    program_moves = tuple(moves.get(i, j) for i, j in _edges(order))
    for m in program_moves:
        if m.time >= UNREACHABLE:
            what = f"pose {m.end if m.end else m.start}"
            raise ProgramError(what, m.direct.worst_row, "no collision-free move to or from it "
                               f"was found (planner: {m.plan.status if m.plan else '-'}); raise "
                               "program planner time or drop the pose")
    known = list(moves.known.values())
    blocked = [m for m in known if m.plan is not None]
    screened_blocked = sum(1 for e in moves.screened if e not in moves.known
                           and moves.cost[e] >= UNREACHABLE)
    stats = dict(
        moves_checked=len(known) + moves.screens - sum(1 for e in moves.screened if e in moves.known),
        blocked=sum(not m.direct.verified for m in known) + screened_blocked,
        planned=sum(m.plan.success for m in blocked),
        planner_failures=sum(not m.plan.success for m in blocked),
        planner_cpu_s=float(sum(m.plan.cpu_time for m in blocked)),
        evaluations=int(sum(m.direct.evaluations for m in known)),
        moves_screened=moves.screens,
        program_blocked=sum(m.plan is not None for m in program_moves),
        via_points=int(sum(len(m.via_points) for m in program_moves)),
        sight_lost_moves=sum(bool(m.direct.sight_lost) for m in program_moves if m.plan is None),
        move_tolerance_mm=settings.move_tolerance * 1e3,
    )
    cycle = {"design order": moves.lower_bound(design) + dwell,
             "nearest neighbour": tour_time(moves.cost, nn) + dwell,
             "optimised": tour_time(moves.cost, order) + dwell}
    # with plan_baselines every design move is certified or planned; else those the first
    # batch of samples found colliding (or a tour's check blocked): at least this many
    stats["design_order_blocked"] = sum(
        (not moves.known[e].direct.verified) if e in moves.known else bool(moves.cost[e] >= UNREACHABLE)
        for e in ((min(i, j), max(i, j)) for i, j in _edges(design)))
    stats["design_order_planned"] = plan_baselines
    stats["cpu_s"] = time.process_time() - start
    return Program(scene.name, tuple(robot.joint_names), home, q, order - 1, program_moves,
                   settings.dwell, cycle, winner[0], stats, note, dyn.velocity, dyn.acceleration,
                   scene.controller)
