"""The check's rows: the models' own values, the rows on convex pieces only where asked."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.feasibility.bodies import compute_body_states


@pytest.fixture(scope="module")
def ur5(ur5_checker):
    """ur5_table's check (tests/program/conftest.py) and 5 of its feasible poses."""
    from calib_oed.feasibility.sampling import sample_feasible

    return ur5_checker, sample_feasible(ur5_checker.feasibility, 5, 1)


def test_the_rows_are_the_models_rows(ur5):
    checker, _ = ur5
    rows = checker._rows
    assert rows.n > rows.n_cheap > 0  # rows on convex pieces are deferred
    q = checker.robot.random_configurations(30, 2)
    states = compute_body_states(checker.robot.model, q, jacobian=False)
    g, s = rows.evaluate(q, states)
    for model in (checker.feasibility, checker.extra):
        values = model.compute_from_states(q, states, jacobian=False).values
        for k, label in enumerate(rows.labels):
            if label in model.labels:
                np.testing.assert_allclose(g[:, k], values[:, model.labels.index(label)], atol=1e-12)
    design = checker.feasibility.compute_from_states(q, states, jacobian=False).values
    for k, label in enumerate(rows.sight_labels):
        np.testing.assert_allclose(s[:, k], design[:, checker.feasibility.labels.index(label)])
    assert set(checker.feasibility.hull_pairs.labels) <= set(rows.labels[rows.n_cheap:])


def test_deferred_rows_only_where_asked(ur5):
    checker, _ = ur5
    rows = checker._rows
    q = checker.robot.random_configurations(20, 3)
    states = compute_body_states(checker.robot.model, q, jacobian=False)
    full, _ = rows.evaluate(q, states)
    need = np.random.default_rng(0).random((20, rows.n - rows.n_cheap)) < 0.3
    part, _ = rows.evaluate(q, states, need)
    np.testing.assert_array_equal(part[:, :rows.n_cheap], full[:, :rows.n_cheap])
    deferred = part[:, rows.n_cheap:]
    np.testing.assert_array_equal(deferred[need], full[:, rows.n_cheap:][need])
    assert np.all(np.isnan(deferred[~need]))


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
