"""A whole program on fms_kr16: a permutation from home to home, every move certified,
cycle times recomputed from the moves, no worse than nearest neighbour; bad poses named."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.exceptions import ProgramError
from calib_oed.program.build import build_program
from calib_oed.program.settings import ProgramSettings
from calib_oed.program.timing import JointDynamics


@pytest.fixture(scope="module")
def program(kr16_scene, kr16_poses, kr16_checker):
    return build_program(kr16_scene, kr16_poses, ProgramSettings(), checker=kr16_checker,
                         plan_baselines=True)


def test_order_and_moves(program, kr16_poses, kr16_scene):
    n = len(kr16_poses)
    assert sorted(program.order) == list(range(n))
    assert program.moves[0].start == 0 and program.moves[-1].end == 0
    visited = [m.end - 1 for m in program.moves[:-1]]
    assert visited == list(program.order)
    assert np.allclose(program.home, kr16_scene.kpi.configurations[0].q)
    kinds = [k for k, _, _ in program.steps()]
    assert kinds[0] == kinds[-1] == "home" and kinds.count("pose") == n


def test_every_move_is_certified(program, kr16_checker):
    t = np.linspace(0, 1, 300)
    for move in program.moves:
        for a, b in zip(move.waypoints[:-1], move.waypoints[1:], strict=True):
            assert kr16_checker.check(a, b).verified
            assert kr16_checker.clearance(a + t[:, None] * (b - a)).min() >= -kr16_checker.tolerance


def test_cycle_times(program, kr16_scene, kr16_poses):
    dyn = JointDynamics.from_robot(kr16_scene.robot, ProgramSettings())
    moves = sum(dyn.path_time(m.waypoints) for m in program.moves)
    assert program.cycle_time == pytest.approx(moves + len(kr16_poses) * program.dwell)
    t = program.cycle_times
    assert t["optimised"] <= t["nearest neighbour"] + 1e-9
    assert t["optimised"] < t["design order"]
    assert program.stats["design_order_planned"]
    assert "shorter than the design order" in program.summary()


def test_bad_pose_and_home_are_named(kr16_scene, kr16_poses, kr16_checker):
    bad = kr16_poses.copy()
    bad[4] = kr16_scene.kpi.configurations[0].q
    bad[4, 1] += 1.2  # car_side with the arm swung down into the car and the floor
    assert kr16_checker.clearance(bad[4:5])[0] < 0
    with pytest.raises(ProgramError, match="pose 5"):
        build_program(kr16_scene, bad, ProgramSettings(), checker=kr16_checker)
    with pytest.raises(ProgramError, match="home"):
        build_program(kr16_scene, kr16_poses, ProgramSettings(home=bad[4]), checker=kr16_checker)
