"""The witness memo of the convex-piece rows: the same arrays as coal's answer, bit for bit, for
every mix of remembered and new poses; new placements are computed, the oldest poses dropped."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.hull_witness import HullWitness, WitnessMemo
from calib_oed.feasibility.hulls import HullPairs, link_pieces

PAIRS = (("link_1", "link_4"), ("link_2", "link_4"), ("link_2", "link_5"), ("link_4", "link_6"),
         ("base_link", "link_2"))
FIELDS = ("dist", "wa", "wb", "u", "piece_a", "piece_b")


@pytest.fixture(scope="module")
def kr16():
    robot = load_robot("kr16")
    return robot, link_pieces(robot, load_collision_model(robot))


def assert_same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.dtype.kind == y.dtype.kind and np.array_equal(x, y), name


def test_memo_answers_as_coal_does(kr16):
    """Every row's witnesses at remembered poses, alone, in subsets and mixed with new poses, equal
    those of a model without a memo; only the new poses go to coal."""
    robot, pieces = kr16
    hp, fresh = HullPairs(pieces, PAIRS), HullPairs(pieces, PAIRS)
    q = robot.random_configurations(12, 5)
    states = compute_body_states(robot.model, q)
    first = hp.closest(states.take(np.arange(8)))  # every row: remembered
    assert hp.memo.misses == 8 and hp.memo.hits == 0 and first.calls > 0
    for k in range(8):
        for h in range(len(hp)):
            one = states.take(np.array([k]))
            got = hp.closest(one, np.array([h]))
            assert got.calls == 0
            assert_same(got, fresh.closest(one, np.array([h])))
    assert hp.memo.hits == 8 * len(hp)
    mixed = np.array([9, 2, 11, 0, 5])  # new and remembered poses
    hits, misses = hp.memo.hits, hp.memo.misses
    for rows in (None, np.array([3, 1])):
        assert_same(hp.closest(states.take(mixed), rows), fresh.closest(states.take(mixed), rows))
    assert (hp.memo.hits - hits, hp.memo.misses - misses) == (3 + 5, 2)  # 9 and 11 kept by the first


def test_new_placements_are_computed(kr16):
    """A pose that differs in one bit of q is not taken from the memo."""
    robot, pieces = kr16
    hp = HullPairs(pieces, PAIRS)
    q = robot.random_configurations(3, 7)
    hp.closest(compute_body_states(robot.model, q, jacobian=False))
    moved = q.copy()
    moved[1, 2] = np.nextafter(moved[1, 2], np.inf)
    hits = hp.memo.hits
    w = hp.closest(compute_body_states(robot.model, moved, jacobian=False))
    assert hp.memo.hits == hits + 2 and w.calls > 0


def test_memo_keeps_the_newest_poses():
    memo = WitnessMemo(np.array([1, 2]), size=3)
    rot, trans = np.tile(np.eye(3), (5, 3, 1, 1)), np.arange(45.0).reshape(5, 3, 3)
    keys = memo.keys(rot, trans)
    assert len(set(keys)) == 5
    for k in range(5):
        memo.store([keys[k]], _witness(1))
    assert memo.find(keys)[0].tolist() == [2, 3, 4]
    memo.store(keys, _witness(5))  # more poses than the memo holds: none kept
    assert memo.find(keys)[0].tolist() == [2, 3, 4]


def _witness(n):
    z = np.zeros((n, 1))
    return HullWitness(z, np.zeros((n, 1, 3)), np.zeros((n, 1, 3)), np.zeros((n, 1, 3)), 0, z.astype(int),
                       z.astype(int))
