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
