"""Self-collision pairs decided on the collision meshes: a pair that can collide is never dropped."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.feasibility import FeasibilitySettings
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.mesh_pairs import _path_joints, dropped_mesh_pairs, mesh_pair_clearances
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.shapes import Cell

MARGIN = 0.010


@cache
def robot_and_geometry(name):
    robot = load_robot(name)
    return robot, load_collision_model(robot)


def test_a_pair_that_collides_somewhere_is_kept():
    robot, geom = robot_and_geometry("ur10")
    dropped = {frozenset((p.link_a, p.link_b)) for p in dropped_mesh_pairs(robot, MARGIN)}
    assert dropped  # the wrist pairs that never come near
    # independent evidence: the mesh check on fresh configurations (another seed)
    q = robot.random_configurations(100, 123)
    report = check_design_meshes(robot, q, clearance=MARGIN, geometry_model=geom)
    near = {frozenset(p) for pose in report.colliding_pairs for p in pose}
    assert near  # the draw does find colliding pairs ...
    assert not near & dropped  # ... and none of them was dropped


def test_decisions_follow_the_sampled_clearance_range():
    robot, geom = robot_and_geometry("ur10")
    pairs = mesh_pair_clearances(robot, geom, MARGIN, samples=60, grid=11)
    for p in pairs:
        assert p.min_clearance <= p.max_clearance
        if p.min_clearance <= MARGIN < p.max_clearance:  # in and out of the margin: can collide
            assert p.decision is None and "can collide" in p.reason
        if p.decision == "never within the margin":
            assert p.min_clearance > MARGIN + p.buffer and len(p.joints) <= 2
    by_name = {(p.link_a, p.link_b): p for p in pairs}
    # adjacent bodies are never candidates (dropped by rule in both models)
    assert ("shoulder_link", "upper_arm_link") not in by_name
    assert by_name[("wrist_1_link", "wrist_3_link")].joints == ("wrist_2_joint", "wrist_3_joint")


def test_a_pair_never_separated_by_the_margin_is_dropped():
    robot, geom = robot_and_geometry("kr16")
    # a 3 m margin: no two links are ever 3 m apart, so every pair is a "housing"
    pairs = mesh_pair_clearances(robot, geom, 3.0, samples=20, grid=3)
    assert pairs and all(p.decision == "never separated" for p in pairs)
    assert all("never separated" in p.reason and "3000 mm margin" in p.reason for p in pairs)


def test_path_joints_are_those_between_the_links():
    robot, _ = robot_and_geometry("ur10")
    parents = list(robot.model.parents)
    assert _path_joints(parents, 0, 3) == [1, 2, 3]
    assert _path_joints(parents, 2, 5) == [3, 4, 5]
    assert _path_joints(parents, 4, 4) == []


def test_pair_report_names_the_pairs_decided_on_meshes():
    robot, _ = robot_and_geometry("ur10")
    settings = FeasibilitySettings(prune_samples=0)  # the capsules of the default fit, no convex pieces
    _, report = build_feasibility_model(robot, Cell(), settings, np.array([2.0, 0.0, 1.0]),
                                        np.array([[0.0, 0.0, 0.04]]), hulls=False)
    on_meshes = [d for d in report.dropped if d.reason.startswith("meshes")]
    assert {d.label for d in on_meshes} >= {"self:wrist_1_link#0|wrist_3_link#0"}
    for d in on_meshes:
        assert d.min_clearance > MARGIN and "mesh clearance" in d.reason
    assert "meshes never within the margin" in report.summary()
    # without mesh decisions the pair is checked
    _, plain = build_feasibility_model(robot, Cell(), settings, np.array([2.0, 0.0, 1.0]),
                                       np.array([[0.0, 0.0, 0.04]]), mesh_pairs=False, hulls=False)
    assert "self:wrist_1_link#0|wrist_3_link#0" in plain.checked


@pytest.mark.parametrize("name", ["kr16"])
def test_capsule_tables_skip_the_mesh_pass(name):
    robot, _ = robot_and_geometry(name)
    from calib_oed.feasibility.capsules import fit_capsules

    settings = FeasibilitySettings(prune_samples=0, robot_capsules=fit_capsules(robot))
    _, report = build_feasibility_model(robot, Cell(), settings, np.array([2.0, 0.0, 1.0]),
                                        np.array([[0.0, 0.0, 0.1]]))
    assert not [d for d in report.dropped if d.reason.startswith("meshes")]
