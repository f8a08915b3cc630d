"""The scene's feasibility block drives the pair selection: capsule table, exclusions, pruning."""

from __future__ import annotations

import copy
from importlib import resources

import numpy as np
import pinocchio as pin
import pytest
import yaml

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsule_rows import HalfspaceRows
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.scene.reader import scene_from_dict

# A capsule table for the kr16 in its link frames [mm] (the file's unit): rough, but enough
# to tell it from the fitted capsules, whose names are "<link>#0" and radii differ.
TABLE = [
    {"link": "link_1", "a": [0, 0, 0], "b": [0, 0, 300], "radius": 200, "name": "turret"},
    {"link": "link_2", "a": [0, 0, 0], "b": [680, 0, 0], "radius": 90, "name": "upper_arm"},
    {"link": "link_3", "a": [0, 0, 0], "b": [0, 0, 0], "radius": 150},  # unnamed: link_3#0
    {"link": "link_3", "a": [300, 0, 0], "b": [650, 0, 0], "radius": 70},  # link_3#1
    {"link": "link_5", "a": [0, 0, 0], "b": [0, 0, 0], "radius": 80, "name": "wrist"},
]
TABLE_NAMES = ["turret", "upper_arm", "link_3#0", "link_3#1", "wrist"]


@pytest.fixture(scope="module")
def kr16_data():
    """The shipped fms_kr16 scene as parsed YAML (mm, deg), with a cheaper pruning pass."""
    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    data = yaml.safe_load(text)
    data["feasibility"]["prune"] = {"samples": 500, "seed": 0, "distance": 100}
    return data


def scene_in(tmp_path, data, name="cell.yaml"):
    """Write ``data`` as a scene file in ``tmp_path`` and load it through ``scene_from_dict``."""
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return scene_from_dict(yaml.safe_load(path.read_text()), source=str(path))


def with_feasibility(data, **changes):
    out = copy.deepcopy(data)
    out["feasibility"].update(changes)
    return out


# ----------------------------------------------------------------------------- capsule table


def test_capsule_table_replaces_the_fit(kr16_data, tmp_path):
    scene = scene_in(tmp_path, with_feasibility(kr16_data, robot_capsules=copy.deepcopy(TABLE)))
    model, report = feasibility_from_scene(scene, prune=False)
    seg = model.segments
    robot_rows = [k for k, role in enumerate(seg.roles) if role == "robot"]
    assert [seg.names[k] for k in robot_rows] == TABLE_NAMES
    assert [seg.links[k] for k in robot_rows] == [c["link"] for c in TABLE]
    np.testing.assert_allclose(seg.radius[robot_rows], [c["radius"] * 1e-3 for c in TABLE])
    # the reflector, the obstacles and the beam are still there, from the scene
    assert seg.names[len(TABLE) :] == (
        "reflector(smr0)",
        "car_body",
        "car_cabin",
        "tracker_stand",
        "laser(smr0)",
    )
    assert report.n_links == 4  # link_1, link_2, link_3 (two capsules), link_5
    # every checked label names table capsules only: no fitted "<link>#0" capsule is left
    fitted = {"base_link#0", "link_1#0", "link_2#0", "link_4#0", "link_5#0", "link_6#0"}
    for label in report.checked:
        names = set(label.partition(":")[2].split("|"))
        assert not names & fitted, label
    # the end points are the table's, in the link frames: compare world points with pinocchio
    robot = scene.robot
    q = robot.random_configurations(3, 8)
    states = compute_body_states(robot.model, q, jacobian=False)
    a = states.points(seg.body_a[robot_rows], seg.a_local[robot_rows])
    b = states.points(seg.body_b[robot_rows], seg.b_local[robot_rows])
    data = robot.model.createData()
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qk)
        for s, cap in enumerate(TABLE):
            placement = data.oMf[robot.frame_id(cap["link"])]
            np.testing.assert_allclose(
                a[k, s], placement.act(np.array(cap["a"]) * 1e-3), atol=1e-12
            )
            np.testing.assert_allclose(
                b[k, s], placement.act(np.array(cap["b"]) * 1e-3), atol=1e-12
            )


def test_capsule_table_pairs_follow_the_rules(kr16_data, tmp_path):
    scene = scene_in(tmp_path, with_feasibility(kr16_data, robot_capsules=copy.deepcopy(TABLE)))
    _, report = feasibility_from_scene(scene, prune=False)
    reasons = {d.label: d.reason for d in report.dropped}
    assert reasons["self:link_3#0|link_3#1"] == "same body"
    assert reasons["self:turret|upper_arm"] == "adjacent links"
    assert reasons["self:upper_arm|link_3#1"] == "adjacent links"
    assert "self:turret|link_3#1" in report.checked
    assert "self:wrist|reflector(smr0)" in reasons  # link_5 is adjacent to the tool body
    # without pruning, every candidate is checked: the pairs of capsules on different,
    # non-adjacent bodies (joints 1, 2, 3, 3, 5 and the reflector on joint 6)
    self_pairs = [lbl for lbl in report.checked if lbl.startswith("self:")]
    assert sorted(self_pairs) == sorted([
        "self:turret|link_3#0", "self:turret|link_3#1", "self:turret|wrist",
        "self:turret|reflector(smr0)", "self:upper_arm|wrist", "self:upper_arm|reflector(smr0)",
        "self:link_3#0|wrist", "self:link_3#1|wrist",
        "self:link_3#0|reflector(smr0)", "self:link_3#1|reflector(smr0)",
    ])  # fmt: skip
    assert report.counts["self"] == 10


# ----------------------------------------------------------------------------- exclusions


@pytest.mark.parametrize(
    ("fit", "pair", "checked", "label"),
    [
        # default link_fit (hulls): link_1 and link_4 are 3 joints apart, one row on their pieces;
        # excluded, neither that row nor a capsule row of theirs is left
        ("hulls", ["link_1", "link_4"], "self:link_1|link_4", "self:link_1#0|link_4#0"),
        ("single", ["link_1", "link_4"], "self:link_1#0|link_4#0", "self:link_1#0|link_4#0"),
        ("hulls", ["tool0", "link_2"], "self:link_2#0|reflector(smr0)", "self:link_2#0|reflector(smr0)"),
    ],
)
def test_excluded_pair_is_not_checked(kr16_data, tmp_path, fit, pair, checked, label):
    # no pruning pass: the comparison does not depend on what sampling drops
    data = with_feasibility(kr16_data, link_fit=fit)
    _, plain = feasibility_from_scene(scene_in(tmp_path, data, "plain.yaml"), prune=False)
    assert checked in plain.checked  # checked by default
    scene = scene_in(tmp_path, with_feasibility(data, excluded_pairs=[pair]))
    assert scene.feasibility.excluded_pairs == (tuple(pair),)
    model, report = feasibility_from_scene(scene, prune=False)
    assert checked not in report.checked
    assert checked not in model.labels
    assert not any(lbl.startswith(f"self:{pair[0]}") and f"|{pair[1]}" in lbl for lbl in model.labels)
    excluded = [d for d in report.dropped if d.reason == "excluded by the scene"]
    assert [d.label for d in excluded] == [label]
    assert "dropped 1: excluded by the scene" in report.summary()
    assert set(report.checked) == set(plain.checked) - {checked}
    assert report.counts["self"] == plain.counts["self"] - 1


# ----------------------------------------------------------------------------- pruning


def test_prune_distance_is_monotone(kr16_data, tmp_path):
    """Same seeded samples, larger distance: the pruned pairs are a subset, never more."""
    pruned, checked = [], []
    distances = [20, 100, 300, 1000]  # [mm], the file's unit
    for d in distances:
        data = copy.deepcopy(kr16_data)
        data["feasibility"]["prune"]["distance"] = d
        scene = scene_in(tmp_path, data, f"d{d}.yaml")
        assert scene.feasibility.prune_distance == pytest.approx(d * 1e-3)
        model, report = feasibility_from_scene(scene)
        far = {x.label for x in report.dropped if x.reason.startswith("never closer")}
        # capsule pairs: exactly this reason; pairs on convex pieces add their clearance range
        assert all(
            x.reason == f"never closer than {d} mm in 500 samples"
            or (x.reason.startswith(f"never closer than {d} mm in 500 samples (clearance ")
                and x.min_clearance > d * 1e-3)
            for x in report.dropped
            if x.label in far
        )
        pruned.append(far)
        checked.append(set(report.checked))
        # a capsule pair is one row, a half-space pair one row per capsule end (one for a
        # zero-length capsule: its ends are one point)
        halfspaces = model.family(HalfspaceRows)
        n_halfspace = 0 if halfspaces is None else len(halfspaces) - len(halfspaces.pairs)
        assert len(report.checked) + n_halfspace == sum(
            model.count_per_pose()[k] for k in ("self", "obstacle", "beam")
        )
    for k in range(len(distances) - 1):
        assert pruned[k + 1] <= pruned[k]
        assert checked[k] <= checked[k + 1]
        assert len(checked[k]) + len(pruned[k]) == len(checked[k + 1]) + len(pruned[k + 1])
    counts = [len(p) for p in pruned]
    assert counts[0] > counts[-1], counts  # the distance matters on this cell
