"""A blocked move gets via points whose every move is certified (and holds under dense sampling)."""

from __future__ import annotations

import numpy as np

from calib_oed.program.planner import plan_move


def test_blocked_move_gets_a_certified_path(kr16_checker, kr16_poses):
    ch = kr16_checker
    q = kr16_poses
    pair = next((a, b) for a in range(len(q)) for b in range(a + 1, len(q))
                if ch.check(q[a], q[b]).collision)
    q0, q1 = q[pair[0]], q[pair[1]]
    path = plan_move(ch, q0, q1, time_limit=2.0, seed=0)
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
