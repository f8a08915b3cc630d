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
   the better of the two is the program;
4. a move of that tour nothing connects: a pose home does not reach (direct or
   planned) is left out with why (``skip_unreachable``, else a :class:`ProgramError`
   names it), two poses home reaches both are joined through home; back to 3.

Every move of the returned program is certified and priced with its planned
path. The design order's cycle time uses planned paths with ``plan_baselines``,
else direct times for its blocked moves: a lower bound (a detour only adds
time), so the reported gain of the optimised tour is, if anything, understated.
"""

from __future__ import annotations

import time

import numpy as np

from calib_oed.exceptions import ProgramError
from calib_oed.feasibility.window import revolute_indices
from calib_oed.program.continuous import MoveChecker
from calib_oed.program.planner import plan_move
from calib_oed.program.records import Move, Program
from calib_oed.program.settings import ProgramSettings
from calib_oed.program.timing import JointDynamics
from calib_oed.program.tour import nearest_neighbour, solve_tour, tour_time

#: Cost [s] of a move no plan connects: the tour avoids it if it can (more than any
#: tour of direct moves takes; small enough for LKH's integer arithmetic).
UNREACHABLE = 1e3


def move_checker(scene, settings: ProgramSettings) -> MoveChecker:
    """The continuous check of a scene: the design's model (every collision row it keeps),
    plus the pairs its sampling pass dropped as never close in the samples (a sample proves
    nothing about a move), from the model without the pass."""
    from calib_oed.feasibility.pairs import feasibility_from_scene

    design, report = feasibility_from_scene(scene)
    full, _ = feasibility_from_scene(scene, prune=False)
    far = tuple(d for d in report.dropped if d.reason.startswith("never closer"))
    return MoveChecker(design, settings.move_tolerance, extra=full, extra_rows=far)


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
        plan = plan_move(self.checker, self.nodes[a], self.nodes[b], self.settings.planner_iterations,
                         self.settings.planner_seed, self.joint_margin)
        cost = self.dyn.path_time(plan.waypoints) if plan.success else UNREACHABLE
        self.cost[a, b] = self.cost[b, a] = cost
        self.known[(a, b)] = Move(a, b, plan.waypoints, cost, move.direct, plan)
        return self.get(i, j)

    def settle(self, solve_sub, limit: int, keep: np.ndarray) -> np.ndarray:
        """Re-solve until the tour's moves are all checked and its blocked ones planned; the
        tour visits home and the nodes ``keep`` (the poses not left out)."""
        sub = np.concatenate([[0], keep])

        def solve(cost):
            return sub[solve_sub(cost[np.ix_(sub, sub)])]

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

    def via_home(self, i: int, j: int) -> None:
        """Connect poses ``i`` and ``j`` through home (both reached from home by certified paths)."""
        a, b = min(i, j), max(i, j)
        first, second = self.plan(a, 0), self.plan(0, b)
        old = self.known[(a, b)]
        way = np.vstack([first.waypoints, second.waypoints[1:]])
        cost = first.time + second.time
        self.cost[a, b] = self.cost[b, a] = cost
        self.known[(a, b)] = Move(a, b, way, cost, old.direct, old.plan)

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
    wrapped: tuple[int, ...] = ()
    if settings.wrap:
        q, wrapped = nearest_turns(robot, q, home, scene.feasibility.margins.joint)
    nodes = np.vstack([home, q])
    clearance = checker.clearance(nodes)
    for k in np.flatnonzero(clearance < -settings.move_tolerance):
        value, row = checker.worst(nodes[k])
        degrees = ", ".join(f"{v:.6g}" for v in np.rad2deg(nodes[k]))
        collides = (f"in collision by the scene's capsule model (margin included): {row} "
                    f"{value * 1e3:.1f} mm")
        if k:
            raise ProgramError(f"pose {k}", f"{degrees} deg", f"{collides}; the design does not fit "
                               "this scene (check it with `calib-oed evaluate`)")
        raise ProgramError("home", f"{degrees} deg", f"{collides}; {note.removeprefix('home: ')}: "
                           "give a collision-free home (--home, or program.home in the scene)")
    moves = _Moves(nodes, checker, dyn, settings, scene.feasibility.margins.joint)
    n = len(q)
    limit = 10 * n + 10
    winner = ["lkh"]

    def solver(cost):
        order, who = solve_tour(cost)
        winner[0] = who
        return order

    keep = np.arange(1, n + 1)
    skipped: dict[int, str] = {}
    while True:
        order = moves.settle(solver, limit, keep)
        nn = moves.settle(nearest_neighbour, limit, keep)
        if tour_time(moves.cost, nn) < tour_time(moves.cost, order):
            order, winner[0] = nn, "nearest neighbour"
        dead = [e for e in _edges(order) if moves.cost[e] >= UNREACHABLE]
        if not dead:
            break
        keep = _resolve_unreachable(moves, dead, keep, skipped, settings, nodes)
    design = keep  # the design's order of the poses measured
    dwell = len(keep) * settings.dwell
    for i, j in _edges(design):  # without plan_baselines only the first batch of samples
        moves.plan(i, j) if plan_baselines else moves.screen(i, j)
    program_moves = tuple(moves.get(i, j) for i, j in _edges(order))
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
    stats["wrapped_poses"] = [k + 1 for k in wrapped]
    stats["cpu_s"] = time.process_time() - start
    return Program(scene.name, tuple(robot.joint_names), home, q, order - 1, program_moves,
                   settings.dwell, cycle, winner[0], stats, note, dyn.velocity, dyn.acceleration,
                   scene.controller, tuple(sorted((k - 1, why) for k, why in skipped.items())),
                   settings.handshake, settings.tool, settings.base, settings.payload)


def _resolve_unreachable(moves: _Moves, dead, keep, skipped: dict[int, str], settings, nodes) -> np.ndarray:
    """Deal with the tour's moves no certified path connects: a pose home cannot reach
    (direct move or planned path) is left out (or, without ``skip_unreachable``, a
    :class:`ProgramError` names it); two poses home reaches both are joined through home."""
    out = set(int(k) for k in keep)
    for i, j in dead:
        lost = [p for p in (i, j) if p and moves.plan(0, p).time >= UNREACHABLE]
        if not lost:
            moves.via_home(i, j)
            continue
        for p in lost:
            move = moves.get(0, p)
            why = (f"no certified path from home found: direct move blocked ({move.direct.worst_row} "
                   f"{move.direct.min_sampled * 1e3:.1f} mm), planner: "
                   f"{move.plan.status if move.plan else '-'} in {settings.planner_iterations} iterations"
                   + _wrap_hint(nodes[p], nodes[0], moves.checker.robot))
            if not settings.skip_unreachable:
                raise ProgramError(f"pose {p}", move.direct.worst_row, why + "; leave it out "
                                   "(skip_unreachable) or raise program.planner_iterations")
            skipped[p] = why
            out.discard(p)
    if not out:
        raise ProgramError("poses", sorted(skipped), "no pose can be reached from home")
    return np.array(sorted(out), dtype=int)


def nearest_turns(robot, q: np.ndarray, home: np.ndarray, margin: float = 0.0) -> tuple[np.ndarray, tuple[int, ...]]:
    """Each pose with every revolute joint moved by whole turns (within the limits less
    ``margin``) to the value nearest home [rad]; and the (0-based) poses that changed.

    Revolute joints only (a full turn of a prismatic joint is not the same geometry)."""
    out = np.array(q, dtype=float, copy=True)
    lo, hi = robot.lower + margin, robot.upper - margin
    for i in revolute_indices(robot):
        for k in (-2, -1, 1, 2):
            x = np.asarray(q, float)[:, i] + 2 * np.pi * k
            better = (x >= lo[i]) & (x <= hi[i]) & (np.abs(x - home[i]) < np.abs(out[:, i] - home[i]))
            out[better, i] = x[better]
    changed = tuple(int(k) for k in np.flatnonzero(np.any(np.abs(out - q) > 0, axis=1)))
    return out, changed


def _turns_nearer_home(q: np.ndarray, home: np.ndarray, robot, margin: float = 0.0) -> list[str]:
    """The pose's joints a whole turn from a value nearer home within the limits less ``margin``
    (the same geometry), each as ``"name q deg (= x deg)"``."""
    turns = []
    for i, name in enumerate(robot.joint_names):
        for k in (-2, -1, 1, 2):
            x = q[i] + 2 * np.pi * k
            if robot.lower[i] + margin <= x <= robot.upper[i] - margin and abs(x - home[i]) < abs(q[i] - home[i]):
                turns.append(f"{name} {np.rad2deg(q[i]):.1f} deg (= {np.rad2deg(x):.1f})")
                break
    return turns


def home_winding_note(scene, q: np.ndarray, settings: ProgramSettings | None = None) -> str:
    """A warning naming the design's poses (1-based) the program may not reach from home, or ``""``.

    The program command's own check (:func:`_wrap_hint`, when it cannot reach a pose): a
    joint a whole turn from a value nearer home, within the limits less the joint margin,
    so the move from home would wind it (through the cell). The design command says it
    before the program fails; ``program --wrap`` measures such poses at those values.
    """
    settings = settings or ProgramSettings()
    try:
        home, _ = home_configuration(scene, settings)
    except ProgramError:  # no home: the program command asks for one
        return ""
    margin = scene.feasibility.margins.joint
    found = [(k + 1, t) for k, pose in enumerate(np.asarray(q, dtype=float))
             if (t := _turns_nearer_home(pose, home, scene.robot, margin))]
    if not found:
        return ""
    shown = "; ".join(f"pose {k}: {', '.join(t)}" for k, t in found[:5])
    more = f" and {len(found) - 5} more" if len(found) > 5 else ""
    return (f"{len(found)} of {len(q)} poses have a joint a whole turn from a value nearer home "
            f"({shown}{more}): the program may not reach them from home (the move would wind the "
            "joint, e.g. through the table); `calib-oed program --wrap` measures them at the "
            "values nearer home (the same robot geometry)")


def _wrap_hint(q: np.ndarray, home: np.ndarray, robot) -> str:
    """A note when a joint of the pose is a full turn from a value nearer home (same geometry)."""
    turns = _turns_nearer_home(q, home, robot)
    if not turns:
        return ""
    return ("; the same robot geometry is nearer home with " + ", ".join(turns)
            + ": the design's joint values may lie where home cannot wind to (e.g. through the table)")
