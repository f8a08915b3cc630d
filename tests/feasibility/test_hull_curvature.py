"""The exact curvature of convex-piece rows, every row at once: the same Hessians as one row at a
time, bit for bit (kr16's cylinders and sphere: rims, sides, caps), whatever rows share the batch."""

from __future__ import annotations

import numpy as np

from calib_oed import load_robot
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.hulls import HullPairs, link_pieces

PAIRS = (("link_1", "link_4"), ("link_2", "link_4"), ("link_2", "link_5"), ("link_4", "link_6"),
         ("base_link", "link_2"), ("link_1", "link_3"), ("link_3", "link_6"))


def test_batched_curvature_is_that_of_one_row_at_a_time():
    robot = load_robot("kr16")
    hp = HullPairs(link_pieces(robot, load_collision_model(robot)), PAIRS)
    q = robot.random_configurations(40, 11)
    states = compute_body_states(robot.model, q)
    pose, rows = np.repeat(np.arange(len(q)), len(hp)), np.tile(np.arange(len(hp)), len(q))
    batch = hp.hessians(states, pose, rows)
    exact = hp.curvature["exact"]
    one = np.stack([hp.hessians(states, pose[k:k + 1], rows[k:k + 1])[0] for k in range(len(pose))])
    assert hp.curvature["exact"] == 2 * exact >= 0.9 * len(pose)  # the same rows exact, most of them
    assert np.array_equal(batch, one)
    shuffled = np.random.default_rng(0).permutation(len(pose))  # other neighbours in the batch
    assert np.array_equal(hp.hessians(states, pose[shuffled], rows[shuffled]), batch[shuffled])
