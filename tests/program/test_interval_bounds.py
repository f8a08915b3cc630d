"""Local Lipschitz constants: relative motion of self pairs, piece axes, interval end points."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def ur5(ur5_checker):
    """ur5_table's check (tests/program/conftest.py) and 4 of its feasible poses."""
    from calib_oed.feasibility.sampling import sample_feasible

    return ur5_checker, sample_feasible(ur5_checker.feasibility, 4, 5)


def test_a_self_row_drops_the_joints_that_move_both_links(ur5):
    checker, _ = ur5
    names = checker.robot.joint_names
    rel = checker._bounds.relative
    labels = list(checker.collision_labels)
    wrist = labels.index("self:wrist_1_link|wrist_3_link")
    assert [names[i] for i in np.flatnonzero(rel[wrist])] == ["wrist_2_joint", "wrist_3_joint"]
    table = next(k for k, lbl in enumerate(labels) if lbl.startswith("obstacle:") and "table" in lbl)
    assert rel[table].all()  # a fixed set: every joint moves the link relative to it
    # the move's constant of the wrist row ignores the shoulder and elbow
    q0 = checker.robot.random_configurations(1, 0)[0]
    q1 = q0.copy()
    q1[:3] += 0.5
    assert checker.lipschitz(q0, q1)[wrist] == 0.0


def test_local_constants_bound_the_slopes_of_every_row(ur5):
    """Inside each of 6 intervals of 3 moves, no row (capsules, table, convex pieces) changes
    faster than its local constant, and the constants are not vacuous."""
    checker, poses = ur5
    ratios, tighter = [], []
    for q0, q1 in zip(poses[:-1], poses[1:], strict=True):
        dq = np.abs(q1 - q0)
        lip = checker.lipschitz(q0, q1)
        edges = np.linspace(0, 1, 7)
        _, _, d = checker._evaluate(q0 + edges[:, None] * (q1 - q0))
        local = checker._interval_lipschitz(lip, d[:-1], d[1:], np.diff(edges), dq, checker._ends.growth(dq))
        assert np.all(local <= lip + 1e-12)
        tighter.append(local.mean() / lip.mean())
        for k in range(6):
            t = np.linspace(edges[k], edges[k + 1], 120)
            g, _ = checker.rows(q0 + t[:, None] * (q1 - q0))
            slope = np.abs(np.diff(g, axis=0)).max(axis=0) / (t[1] - t[0])
            assert np.all(slope <= local[k] + 1e-9), np.array(checker.collision_labels)[slope > local[k] + 1e-9]
            ratios.append((slope / np.maximum(local[k], 1e-12)).max())
    assert max(ratios) > 0.2 and np.mean(tighter) < 0.9
