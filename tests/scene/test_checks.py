"""Scenes check themselves on load: the robot at the working configurations, the tracker."""

from __future__ import annotations

import copy
import re
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from calib_oed.exceptions import SceneError
from calib_oed.feasibility.mesh_check import check_design_meshes
from calib_oed.feasibility.shapes import Box, Cell, HalfSpace
from calib_oed.scene.checks import TRACKER_HEAD_RADIUS, scene_violations
from calib_oed.scene.reader import load_scene, scene_from_dict, scene_names

BENCH_SCENES = sorted((Path(__file__).parents[2] / "bench" / "scenes").glob("*.yaml"))


@pytest.fixture(scope="module")
def kr16_data():
    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    return yaml.safe_load(text)


def with_working(data, q_deg, **kpi):
    out = copy.deepcopy(data)
    out["kpi"] = {"working_configurations": [{"name": "bad", "q": list(q_deg)}], **kpi}
    return out


def depth_in_message(message: str, pair: str) -> float:
    match = re.search(re.escape(pair) + r" overlap by ([0-9.]+) mm", message)
    assert match, f"{pair!r} not in {message!r}"
    return float(match.group(1))


def tcp(robot, q_deg) -> np.ndarray:
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, np.deg2rad(q_deg))
    return data.oMf[robot.tool_frame_id].translation.copy()


@pytest.mark.parametrize("name", scene_names() + [str(p) for p in BENCH_SCENES])
def test_every_shipped_and_bench_scene_passes_its_own_check(name):
    scene = load_scene(name)
    assert scene_violations(scene) == []


def test_tcp_below_the_floor_is_an_error_with_its_depth(kr16_data):
    q = [-4, 31, 90, -134, -60, 254]
    plain = scene_from_dict(with_working(kr16_data, q), check=False)
    z = tcp(plain.robot, q)[2]
    assert z < -0.1  # the TCP is below the floor z >= 0
    with pytest.raises(SceneError, match="working configuration 'bad'") as err:
        scene_from_dict(with_working(kr16_data, q))
    assert depth_in_message(str(err.value), "TCP / floor") == pytest.approx(-z * 1e3, abs=0.051)


def test_tcp_inside_the_car_is_an_error(kr16_data):
    q = [21, -17, 36, -230, -84, 48]
    plain = scene_from_dict(with_working(kr16_data, q), check=False)
    x = tcp(plain.robot, q)
    car = next(c for c in plain.cell.capsules if c.name == "car_body")
    inside = car.radius - np.hypot(x[0] - car.a[0], x[2] - car.a[2])  # axis along y
    assert inside > 0.1
    with pytest.raises(SceneError) as err:
        scene_from_dict(with_working(kr16_data, q))
    assert depth_in_message(str(err.value), "TCP / car_body") == pytest.approx(inside * 1e3, abs=0.051)


def test_self_collision_at_a_working_configuration_names_the_pair(kr16_data):
    q = [-97, -154, -121, 343, -66, -321]
    plain = scene_from_dict(with_working(kr16_data, q), check=False)
    report = check_design_meshes(plain.robot, np.deg2rad([q]))
    expected = -report.distances[0, report.pairs.index(("link_1", "link_6"))]
    assert expected > 0.01
    found = {v.pair: v for v in scene_violations(plain)}
    assert found["link_1 / link_6"].depth == pytest.approx(expected, abs=1e-9)
    assert found["link_1 / link_6"].geometry == "URDF collision geometry"


def test_tracker_inside_the_car_is_an_error(kr16_data):
    data = copy.deepcopy(kr16_data)
    data["tracker"]["position"] = [1750, 500, 600]  # 50 mm from the car_body axis
    with pytest.raises(SceneError, match=r"tracker: tracker head / car_body") as err:
        scene_from_dict(data)
    expected = (0.45 + TRACKER_HEAD_RADIUS - 0.05) * 1e3
    assert depth_in_message(str(err.value), "tracker head / car_body") == pytest.approx(expected, abs=0.051)
    assert scene_from_dict(data, check=False).tracker.position[0] == pytest.approx(1.75)


def test_depth_is_given_in_the_scene_length_unit(kr16_data):
    data = copy.deepcopy(kr16_data)
    data["tracker"]["position"] = [1750, 500, 600]
    for key in ("position",):
        data["tracker"][key] = [v / 1000 for v in data["tracker"][key]]
    data["units"] = {"length": "m", "angle": "deg"}
    data["tracker"]["sigma"] = 1e-5
    data["reflectors"][0]["offset"] = [0, 0, 0.05]
    data["cell"] = {"capsules": [{"name": "car", "a": [1.75, -1.8, 0.55], "b": [1.75, 1.8, 0.55],
                                  "radius": 0.45}]}
    data.pop("feasibility")
    with pytest.raises(SceneError, match=r"tracker head / car overlap by 0\.5000 m \(exact\)"):
        scene_from_dict(data)


def test_box_obstacles_and_ignore_links_are_checked():
    scene = load_scene("fms_kr16")
    t = scene.tracker.position
    car = Box(center=t + np.array([0.0, 0.0, -0.3]), size=[1.0, 1.0, 1.0], name="box_car")
    bad = replace(scene, cell=Cell(boxes=(car,)))
    [v] = scene_violations(bad)
    assert (v.where, v.pair) == ("tracker", "tracker head / box_car")
    assert v.depth == pytest.approx(0.5 - 0.3 + TRACKER_HEAD_RADIUS, abs=1e-6)
    # a floor above the base: every moving link below it collides, unless the obstacle ignores it
    q = scene.kpi.q[0]
    floor = HalfSpace(np.array([0.0, 0.0, 1.0]), 0.3, "high_floor")
    pairs = {v.pair for v in scene_violations(replace(scene, cell=Cell(halfspaces=(floor,))))}
    assert "link_1 / high_floor" in pairs
    ignoring = HalfSpace(floor.normal, floor.offset, "high_floor", ignore_links=("link_1",))
    pairs = {v.pair for v in scene_violations(replace(scene, cell=Cell(halfspaces=(ignoring,))))}
    assert "link_1 / high_floor" not in pairs
    assert tcp(scene.robot, np.rad2deg(q))[2] > 0.3  # the TCP itself stays above it


def test_reflector_beam_checked_when_the_kpi_is_the_reflector(kr16_data):
    scene = load_scene("fms_kr16")
    x = tcp(scene.robot, np.rad2deg(scene.kpi.q[0]))
    middle = 0.5 * (x + scene.tracker.position)
    data = copy.deepcopy(kr16_data)
    data["cell"]["capsules"].append({"name": "blocker", "a": (middle * 1e3 - [0, 0, 100]).tolist(),
                                     "b": (middle * 1e3 + [0, 0, 100]).tolist(), "radius": 50})
    scene_from_dict(data)  # the TCP is the KPI: the beam does not matter at work
    data["kpi"]["reflector"] = "smr0"
    data["kpi"].pop("point", None)
    with pytest.raises(SceneError, match="laser beam of smr0 / blocker"):
        scene_from_dict(data)


def test_tracker_head_inside_the_robot_at_a_working_configuration():
    scene = load_scene("fms_kr16")
    data = scene.robot.model.createData()
    pin.forwardKinematics(scene.robot.model, data, scene.kpi.q[0])
    elbow = data.oMi[4].translation.copy()  # joint_a4's origin, inside the forearm
    tracker = replace(scene.tracker, position=elbow)
    found = scene_violations(replace(scene, tracker=tracker))
    at_work = [v for v in found if v.where == "working configuration 'car_side'"]
    assert any(v.pair.endswith("/ tracker head") for v in at_work)
    assert all(v.depth > 0.001 for v in found)
