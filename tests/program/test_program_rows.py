"""The check's rows: the models' own values; the screen and the lazy check agree with dense sampling."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def ur5(ur5_checker):
    """ur5_table's check (tests/program/conftest.py) and 5 of its feasible poses."""
    from calib_oed.feasibility.sampling import sample_feasible

    return ur5_checker, sample_feasible(ur5_checker.feasibility, 5, 1)


def test_the_rows_are_the_models_rows(ur5):
    """The check's collision rows are the design's and the extra model's rows of the same label, its
    line-of-sight rows the design's; the rows on convex pieces are among them."""
    checker, _ = ur5
    q = checker.robot.random_configurations(30, 2)
    g, s = checker.rows(q)
    labels = list(checker.collision_labels)
    assert g.shape == (30, len(labels)) and s.shape == (30, len(checker.sight_labels))
    matched = set()
    for model in (checker.feasibility, checker.extra):
        values = model.compute(q, jacobian=False).values
        for k, label in enumerate(labels):
            if label in model.labels:
                np.testing.assert_allclose(g[:, k], values[:, model.labels.index(label)], atol=1e-12)
                matched.add(label)
    assert matched == set(labels)
    design = checker.feasibility.compute(q, jacobian=False).values
    for k, label in enumerate(checker.sight_labels):
        np.testing.assert_allclose(s[:, k], design[:, checker.feasibility.labels.index(label)])
    assert checker.feasibility.hull_pairs.labels and set(checker.feasibility.hull_pairs.labels) <= set(labels)


def test_the_screen_never_contradicts_the_check(ur5):
    """The screen (rows on convex pieces left out) says "collides" only for a move the check finds
    colliding, and never for a move the check verifies; it does say so for some moves."""
    checker, poses = ur5
    q = np.vstack([poses[:3], checker.robot.random_configurations(4, 4)])
    screened = 0
    for i in range(len(q)):
        for j in range(i + 1, len(q)):
            res = checker.check(q[i], q[j])
            if checker.screen(q[i], q[j]):
                screened += 1
                assert res.collision and not res.verified, (i, j)
    assert screened > 0


def test_lazy_check_holds_under_dense_sampling(ur5):
    """A move the check verifies (rows on convex pieces evaluated only where not yet
    certified) keeps every row >= -delta on 200 samples; a collision is a real one."""
    checker, poses = ur5
    t = np.linspace(0, 1, 200)
    verified = 0
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            q0, q1 = poses[i], poses[j]
            res = checker.check(q0, q1)
            dense = checker.clearance(q0 + t[:, None] * (q1 - q0)).min()
            if res.verified:
                verified += 1
                assert dense >= -checker.tolerance, (i, j, dense)
            elif res.collision:
                assert res.min_sampled < -checker.tolerance and dense < -checker.tolerance
    assert verified >= 3
