"""A blocked move gets via points whose every move is certified (and holds under dense sampling)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from calib_oed.program.planner import plan_move


def test_blocked_move_gets_a_certified_path(kr16_checker, kr16_poses):
    ch = kr16_checker
    q = kr16_poses
    pair = next((a, b) for a in range(len(q)) for b in range(a + 1, len(q))
                if ch.check(q[a], q[b]).collision)
    q0, q1 = q[pair[0]], q[pair[1]]
    path = plan_move(ch, q0, q1, iterations=20_000, seed=0)
    assert path.success, path.status
    assert np.allclose(path.waypoints[0], q0) and np.allclose(path.waypoints[-1], q1)
    assert len(path.via_points) >= 1
    t = np.linspace(0, 1, 400)
    for a, b in zip(path.waypoints[:-1], path.waypoints[1:], strict=True):
        assert ch.check(a, b).verified
        assert ch.clearance(a + t[:, None] * (b - a)).min() >= -ch.tolerance
    # via points keep the full margin and the joint limits
    assert np.all(ch.clearance(path.via_points) >= 0)
    robot = ch.robot
    assert np.all((path.via_points >= robot.lower) & (path.via_points <= robot.upper))


# One blocked move of the test above, planned in a fresh process (OMPL's seed is per process).
_PLAN = """
import sys, numpy as np
from calib_oed import load_scene
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.program.build import move_checker
from calib_oed.program.planner import plan_move
from calib_oed.program.settings import ProgramSettings
scene = load_scene("fms_kr16")
ch = move_checker(scene, ProgramSettings())
q = sample_feasible(feasibility_from_scene(scene)[0], 12, 3)
a, b = next((a, b) for a in range(len(q)) for b in range(a + 1, len(q)) if ch.check(q[a], q[b]).collision)
path = plan_move(ch, q[a], q[b], iterations=int(sys.argv[1]), seed=0)
sys.stdout.write(path.status + "|" + path.waypoints.tobytes().hex())
"""


def _plans(iterations: int, runs: int) -> list[str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    procs = [subprocess.Popen([sys.executable, "-c", _PLAN, str(iterations)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env) for _ in range(runs)]
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
        outs.append(out)
    return outs


def test_the_budget_is_iterations_same_path_in_every_process():
    """Two processes at once (so each runs slower than alone) plan the same bytes: the budget
    is a count of RRT-Connect iterations, not seconds."""
    first, second = _plans(20_000, 2)
    assert first == second and "Exact solution" in first
