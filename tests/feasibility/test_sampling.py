"""Seeded rejection sampling of feasible configurations."""

from __future__ import annotations

import numpy as np
import pytest
from test_constraints import model_for

from calib_oed import load_robot
from calib_oed.exceptions import SamplingError
from calib_oed.feasibility.sampling import sample_feasible


@pytest.fixture(scope="module")
def kr16_model():
    return model_for(load_robot("kr16"), prune=True)[0]


def test_samples_are_feasible_and_seeded(kr16_model):
    q1 = sample_feasible(kr16_model, 20, 5, batch=2048)
    q2 = sample_feasible(kr16_model, 20, np.random.default_rng(5), batch=2048)
    assert q1.shape == (20, 6)
    np.testing.assert_array_equal(q1, q2)
    assert kr16_model.compute(q1, jacobian=False).feasible.all()
    assert not np.array_equal(q1, sample_feasible(kr16_model, 20, 6, batch=2048))


def test_impossible_constraints_raise_with_rate():
    robot = load_robot("kr16")
    fm, _ = model_for(robot, incidence_limit=np.deg2rad(2.5))  # margin 2 deg leaves 0.5 deg
    with pytest.raises(SamplingError, match="acceptance"):
        sample_feasible(fm, 5, 0, batch=1024, max_draws=2048)


def test_statistics_accumulate_per_row():
    from calib_oed.feasibility.sampling import RowStatistics

    stats = RowStatistics.empty(3)
    stats.add(np.array([0, 2]), np.array([[1.0, -2.0], [-0.5, -1.0]]))
    stats.add(np.array([2]), np.array([[-3.0], [4.0], [-1.0]]))
    np.testing.assert_array_equal(stats.evaluated, [2, 0, 5])
    np.testing.assert_array_equal(stats.rejected, [1, 0, 4])
    np.testing.assert_array_equal(stats.low, [-0.5, np.inf, -3.0])
    np.testing.assert_array_equal(stats.high, [1.0, -np.inf, 4.0])
    np.testing.assert_array_equal(stats.alone, [0, 0, 0])
    # draws 0 and 2 violate one row each, draw 1 two rows, draw 3 none
    stats.add(np.array([0, 1]), np.array([[-1.0, 2.0], [-1.0, -1.0], [3.0, -2.0], [1.0, 1.0]]),
              alone=True)
    np.testing.assert_array_equal(stats.alone, [1, 1, 0])
    np.testing.assert_array_equal(stats.rejected, [3, 2, 4])


def test_a_pair_that_blocks_every_draw_is_named_with_its_clearance_range():
    """A sphere of 1.2 m around link_1's origin encloses link_3's capsule in every
    configuration: the error names that pair as blocking every draw, and an
    independent set of draws confirms that every row named so is never satisfied."""
    import re

    from test_constraints import cell_for, skeleton_capsules

    from calib_oed.feasibility import Capsule, FeasibilitySettings
    from calib_oed.feasibility.pairs import build_feasibility_model

    robot = load_robot("kr16")
    caps = skeleton_capsules(robot)
    link_1 = caps[0].frame
    caps.append(Capsule(np.zeros(3), np.zeros(3), 1.2, link_1, "big"))
    cell, reach = cell_for(robot)
    fm, _ = build_feasibility_model(robot, cell, FeasibilitySettings(), np.array([0.5 * reach, -2 * reach, 0.6 * reach]),
                                    np.array([[0.0, 0.0, 0.05]]), ["smr0"], capsules=caps, prune=False)
    with pytest.raises(SamplingError, match="Blocking every draw: self:") as err:
        sample_feasible(fm, 5, 0, batch=2048, max_draws=8192)
    blocking = re.search(r"Blocking every draw: (.*?)\. Rejecting", str(err.value)).group(1)
    labels = [part.split(" rejects ")[0] for part in blocking.split("; ")]
    assert "self:link_3#0|big" in labels  # (the skeleton's wrist capsules meet at the wrist centre
    # and the sphere reaches below the floor: those rows block every draw too, and are named)
    assert all("rejects 100.0%" in part and "clearance -" in part for part in blocking.split("; "))
    values = fm.compute_values(robot.random_configurations(2000, 99))
    for label in labels:
        assert values[:, fm.labels.index(label)].max() < 0
    # the rows that do not block every draw are not listed as blocking
    others = [k for k, kind in enumerate(fm.kinds) if kind == "self" and fm.labels[k] not in labels]
    assert any(values[:, k].max() > 0 for k in others)
