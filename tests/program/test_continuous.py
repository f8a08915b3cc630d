"""The continuous check never passes a move that dense sampling finds in collision."""

from __future__ import annotations

import numpy as np

from calib_oed.program.continuous import MoveChecker


def _dense_min(checker: MoveChecker, q0, q1, n=1500) -> float:
    t = np.linspace(0, 1, n)
    return float(checker.clearance(q0 + t[:, None] * (q1 - q0)).min())


def test_verified_moves_hold_under_dense_sampling(kr16_checker, kr16_poses):
    ch = kr16_checker
    q = kr16_poses[:9]
    verified = blocked = 0
    for i in range(len(q)):
        for j in range(i + 1, len(q)):
            res = ch.check(q[i], q[j])
            if ch.screen(q[i], q[j]):  # the screen's "certain collision" is one
                assert res.collision
            dense = _dense_min(ch, q[i], q[j], 400)
            if res.verified:
                verified += 1
                assert dense >= -ch.tolerance, (i, j, dense)
            else:
                blocked += 1
                if res.collision:
                    assert res.min_sampled < -ch.tolerance
    assert verified > 3 and blocked > 0  # the test sees both outcomes


def test_a_move_through_the_floor_is_a_collision(kr16_checker, kr16_scene):
    ch = kr16_checker
    home = kr16_scene.kpi.configurations[0].q
    down = home.copy()
    down[1] += 1.2  # swing the arm down: through the car and the floor
    assert ch.clearance(down[None])[0] < 0
    res = ch.check(home, down)
    assert res.blocked and res.collision and res.worst_row.startswith(("obstacle", "self"))


def test_rows_are_lipschitz_with_the_stated_constant(kr16_checker, kr16_poses):
    """|g_k(t) - g_k(s)| <= L_k |t - s| on 1501 samples: the bound the certificate rests on."""
    ch = kr16_checker
    t = np.linspace(0, 1, 1501)
    worst = 0.0
    for q0, q1 in zip(kr16_poses[:3], kr16_poses[1:4], strict=True):
        g, _ = ch.rows(q0 + t[:, None] * (q1 - q0))
        slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
        lip = ch.lipschitz(q0, q1)
        assert np.all(slope <= lip + 1e-9)
        worst = max(worst, float((slope / lip).max()))
    assert worst > 0.05  # not a vacuous constant


def test_line_of_sight_loss_is_reported_not_blocking(kr16_checker, kr16_poses):
    ch = kr16_checker
    lost = [ch.check(a, b) for a, b in zip(kr16_poses[:-1], kr16_poses[1:], strict=True)]
    assert any(r.sight_lost and r.verified for r in lost)


def test_interval_constants_bound_the_slopes_inside(kr16_checker, kr16_poses):
    """The tightened per-interval constants (motion_bound.EndpointBounds) still bound the
    rows' slopes inside each interval, and are smaller than the move's constant."""
    ch = kr16_checker
    q0, q1 = kr16_poses[2], kr16_poses[5]
    dq = np.abs(q1 - q0)
    growth = ch._ends.growth(dq)
    lip = ch.lipschitz(q0, q1)
    edges = np.linspace(0, 1, 9)
    _, _, d = ch._evaluate(q0 + edges[:, None] * (q1 - q0))
    local = ch._interval_lipschitz(lip, d[:-1], d[1:], np.diff(edges), dq, growth)
    assert np.all(local <= lip + 1e-12) and local.mean() < 0.9 * lip.mean()
    for k in range(8):
        t = np.linspace(edges[k], edges[k + 1], 400)
        g, _ = ch.rows(q0 + t[:, None] * (q1 - q0))
        slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
        assert np.all(slope <= local[k] + 1e-9)
