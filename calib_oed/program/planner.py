r"""Via points for a blocked move: RRT-Connect from OMPL on the continuous check.

A move the continuous check (:mod:`calib_oed.program.continuous`) cannot certify
gets a path through via points from OMPL's RRT-Connect (``ompl`` 2.x Python
bindings from PyPI) in the box of joint limits less the joint margin. OMPL
only proposes: a state is valid when every collision row keeps its full
margin (:math:`g \ge 0`), and a motion between two states is valid only when
:meth:`MoveChecker.check <calib_oed.program.continuous.MoveChecker.check>`
certifies it (OMPL's own motion validator, which samples, is replaced). The
path is then shortened (OMPL's vertex reduction and rope shortcutting, through
the same validator) and every one of its moves is certified once more before it is
returned, so a returned path is collision-free by the same certificate as a
direct move.

Randomness and budget: OMPL seeds every planner from one process-wide seed, set
here once from the settings' ``planner_seed`` (``ompl.util.RNG.setSeed``), and
the budget is a number of RRT-Connect iterations (a termination condition that
counts its calls), not seconds: the same sequence of plans gives the same paths
under any load.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calib_oed.program.continuous import MoveChecker

_SEEDED: list[int] = []


@dataclass(frozen=True, eq=False)
class PlannedPath:
    """A path for one move.

    Attributes:
        waypoints: Start, via points and goal [rad], (k, nq); start and goal only if no plan.
        success: Every move of the path certified collision-free.
        cpu_time: CPU time of the planning [s].
        status: OMPL's status, or why the path was rejected.
    """

    waypoints: np.ndarray
    success: bool
    cpu_time: float
    status: str

    @property
    def via_points(self) -> np.ndarray:
        """The via points alone, (k - 2, nq)."""
        return self.waypoints[1:-1]


def _iteration_budget(ob, iterations: int):
    """OMPL's termination condition after ``iterations`` checks (RRT-Connect checks once per iteration)."""
    count = [0]

    def done() -> bool:
        count[0] += 1
        return count[0] > iterations

    return ob.PlannerTerminationCondition(done)


def plan_move(checker: MoveChecker, q0: np.ndarray, q1: np.ndarray, iterations: int = 20_000,
              seed: int = 0, joint_margin: float = 0.0, step: float = 0.5,
              span: float = np.pi) -> PlannedPath:
    """A certified path from ``q0`` to ``q1`` through via points (see the module docstring).

    Args:
        checker: The continuous check (and state validity).
        q0, q1: Start and goal [rad], (nq,); both must keep the full margin.
        iterations: RRT-Connect's budget, in iterations (deterministic, unlike seconds).
        seed: The process-wide OMPL seed (used on the first call only).
        joint_margin: Margin kept inside the joint limits by the via points [rad].
        step: RRT-Connect's range, the longest edge it adds [rad, joint-space norm]:
            short edges find their way along obstacles (OMPL's default, a fifth of the
            box's diagonal, is metres of travel in a ±360° box).
        span: The box searched: the joint limits (less the margin), cut to ``span`` [rad]
            around the start and goal on each joint (a path winding a joint further is
            never shorter).
    """
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    start_cpu = time.process_time()
    if not _SEEDED:
        ou.RNG.setSeed(int(seed) + 1)  # OMPL refuses seed 0
        _SEEDED.append(int(seed))
    ou.setLogLevel(ou.LOG_NONE)
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    nq = len(q0)
    robot = checker.robot
    space = ob.RealVectorStateSpace(nq)
    bounds = ob.RealVectorBounds(nq)
    for i in range(nq):
        lo = min(max(robot.lower[i] + joint_margin, min(q0[i], q1[i]) - span), q0[i], q1[i])
        hi = max(min(robot.upper[i] - joint_margin, max(q0[i], q1[i]) + span), q0[i], q1[i])
        bounds.setLow(i, float(lo))
        bounds.setHigh(i, float(hi))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)

    def as_array(state) -> np.ndarray:
        return np.array([state[i] for i in range(nq)])

    def valid(state) -> bool:
        x = as_array(state)
        # start and goal may sit on the design's active constraints (g = -1e-6):
        # they are valid as given; every other state keeps the full margin
        ends = np.allclose(x, q0, rtol=0, atol=1e-12) or np.allclose(x, q1, rtol=0, atol=1e-12)
        return ends or bool(checker.clearance(x)[0] >= 0.0)

    class CertifiedMotion(ob.MotionValidator):
        def checkMotion(self, s1, s2, *rest):  # noqa: N802 - OMPL's name
            return checker.check(as_array(s1), as_array(s2)).verified

    si.setStateValidityChecker(valid)
    motion = CertifiedMotion(si)
    si.setMotionValidator(motion)
    si.setup()
    start, goal = space.allocState(), space.allocState()
    for i in range(nq):
        start[i] = float(q0[i])
        goal[i] = float(q1[i])
    pdef = ob.ProblemDefinition(si)
    pdef.setStartAndGoalStates(start, goal)
    planner = og.RRTConnect(si)
    planner.setRange(float(step))
    planner.setProblemDefinition(pdef)
    planner.setup()
    ptc = _iteration_budget(ob, int(iterations))
    status = str(planner.solve(ptc))
    del ptc
    waypoints = np.array([q0, q1])
    success = False
    if pdef.hasExactSolution():
        path = pdef.getSolutionPath()
        raw = np.array([as_array(s) for s in path.getStates()])
        simplifier = og.PathSimplifier(si)
        simplifier.reduceVertices(path)
        simplifier.ropeShortcutPath(path)
        simplifier.reduceVertices(path)
        short = np.array([as_array(s) for s in path.getStates()])
        for candidate in (short, raw):
            candidate[0], candidate[-1] = q0, q1
            if all(checker.check(a, b).verified for a, b in zip(candidate[:-1], candidate[1:], strict=True)):
                waypoints, success = candidate, True
                break
        else:
            status += "; path rejected by the continuous check"
        del path, simplifier
    del planner, pdef, motion, si, space, bounds, start, goal
    return PlannedPath(waypoints, success, time.process_time() - start_cpu, status)
