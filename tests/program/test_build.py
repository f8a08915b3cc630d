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


class _StubMoves:
    """Moves between home (0) and poses 1..3: pose 2 has no path from home; 1 and 3 have."""

    def __init__(self, robot):
        from types import SimpleNamespace

        from calib_oed.program.build import UNREACHABLE
        from calib_oed.program.continuous import MoveCheck

        self.checker = SimpleNamespace(robot=robot)
        self.joined: list[tuple[int, int]] = []
        blocked = MoveCheck(False, True, 3, -0.05, "self:a|b")
        self.moves = {p: SimpleNamespace(time=UNREACHABLE if p == 2 else 1.0, direct=blocked,
                                         plan=SimpleNamespace(status="Timeout")) for p in (1, 2, 3)}

    def plan(self, i, j):
        return self.moves[j or i]

    def get(self, i, j):
        return self.moves[j or i]

    def via_home(self, i, j):
        self.joined.append((i, j))


def test_an_unreachable_pose_is_left_out_and_named(kr16_scene):
    """A pose home cannot reach is left out with why (or named in an error); two poses home
    reaches both are joined through home, never left out."""
    from calib_oed.program.build import _resolve_unreachable
    from calib_oed.program.settings import ProgramSettings

    robot = kr16_scene.robot
    nodes = np.zeros((4, robot.nq))
    nodes[2, 3] = np.deg2rad(300.0)  # a joint a full turn from a value nearer home (A4: +-350 deg)
    moves, skipped = _StubMoves(robot), {}
    keep = _resolve_unreachable(moves, [(1, 3), (3, 2)], np.array([1, 2, 3]), skipped, ProgramSettings(), nodes)
    assert keep.tolist() == [1, 3] and moves.joined == [(1, 3)] and list(skipped) == [2]
    assert "no certified path from home" in skipped[2] and "Timeout" in skipped[2]
    assert "joint_a4 300.0 deg (= -60.0)" in skipped[2]
    with pytest.raises(ProgramError, match="pose 2"):
        _resolve_unreachable(_StubMoves(robot), [(3, 2)], np.array([1, 2, 3]), {},
                             ProgramSettings(skip_unreachable=False), nodes)


def test_whole_turns_nearest_home_keep_the_geometry():
    """--wrap: every revolute joint moved by whole turns to the value nearest home, within the
    limits; the robot's placements (Pinocchio) are unchanged."""
    import pinocchio as pin

    from calib_oed.program.build import nearest_turns
    from calib_oed.scene.reader import load_scene

    robot = load_scene("ur5_table").robot
    rng = np.random.default_rng(2)
    q = rng.uniform(robot.lower, robot.upper, size=(20, robot.nq))
    home = np.deg2rad([15, -60, 90, -120, -90, 0])
    w, changed = nearest_turns(robot, q, home, np.deg2rad(1))
    turns = (w - q) / (2 * np.pi)
    assert np.allclose(turns, np.round(turns)) and changed
    assert np.all(np.abs(w - home) <= np.abs(q - home) + 1e-12)
    wide = robot.upper - robot.lower >= 2 * np.pi + 2 * np.deg2rad(1)  # all but the elbow (+-180 deg)
    assert wide.sum() == 5 and np.all(np.abs(w - home)[:, wide] <= np.pi + 1e-12)  # within half a turn
    data_q, data_w = robot.model.createData(), robot.model.createData()
    for a, b in zip(q, w, strict=True):
        pin.framesForwardKinematics(robot.model, data_q, a)
        pin.framesForwardKinematics(robot.model, data_w, b)
        assert all(x.isApprox(y, 1e-9) for x, y in zip(data_q.oMf, data_w.oMf, strict=True))


def test_home_winding_note_names_the_wound_poses():
    """The design command's warning (issue 31): the program's own check, a joint a whole turn
    from a value nearer home within the limits less the joint margin, named per pose."""
    from calib_oed.program.build import home_configuration, home_winding_note
    from calib_oed.scene.reader import load_scene

    scene = load_scene("ur5_table")
    home, _ = home_configuration(scene, ProgramSettings())
    q = np.tile(home, (3, 1))
    assert home_winding_note(scene, q) == ""
    q[1, 0] = home[0] - np.deg2rad(125.0) + 2 * np.pi  # 250 deg: the same geometry at -110 deg
    q[2, 1] = scene.robot.upper[1] - np.deg2rad(0.5)  # 359.5 deg: -0.5 deg is nearer home's -60 deg
    note = home_winding_note(scene, q)
    assert note.startswith("2 of 3 poses")
    assert "pose 2: shoulder_pan_joint 250.0 deg (= -110.0)" in note
    assert "pose 3: shoulder_lift_joint 359.5 deg (= -0.5)" in note and "pose 1:" not in note
    from_pose_2 = home_winding_note(scene, q, ProgramSettings(home=q[1]))  # program.home / --home
    assert from_pose_2.startswith("1 of 3 poses") and "pose 3:" in from_pose_2
