"""Tests of calib_oed.scene.reader: shipped scenes, unit conversion, one test per validation failure."""

from __future__ import annotations

import copy
import math
import shutil
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
import yaml

from calib_oed.exceptions import CalibOedError, SceneError, UnknownSceneError
from calib_oed.feasibility.shapes import Capsule, FeasibilitySettings, Margins
from calib_oed.model import kuka
from calib_oed.scene.reader import load_scene, scene_from_dict, scene_names

# A 2-joint arm, revolute then prismatic, to check that prismatic joints take length units.
RP_URDF = """<robot name="rp">
  <link name="base_link"/><link name="link1"/><link name="link2"/><link name="tool0"/>
  <joint name="turn" type="revolute"><parent link="base_link"/><child link="link1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="link1"/><child link="link2"/>
    <origin xyz="0 0 0.4"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.5" effort="1" velocity="1"/></joint>
  <joint name="flange" type="fixed"><parent link="link2"/><child link="tool0"/></joint>
</robot>
"""


def valid() -> dict:
    """A small valid scene (kr16, mm and deg)."""
    return {
        "version": 1,
        "name": "test",
        "units": {"length": "mm", "angle": "deg"},
        "robot": {"name": "kr16"},
        "tracker": {"position": [600, -2600, 1300], "rpy": [0, 10, 90], "sigma": 0.01},
        "reflectors": [{"name": "smr0", "offset": [0, 0, 50]}],
        "kpi": {"working_configurations": [{"name": "wc", "q": [0, -90, 90, 0, 45, 0]}]},
    }


DELETE = object()


def mutated(path: tuple, value) -> dict:
    """``valid()`` with the entry at ``path`` (keys and list indices) set, appended or deleted."""
    data = valid()
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    if value is DELETE:
        del parent[path[-1]]
    elif isinstance(parent, list) and path[-1] == len(parent):
        parent.append(copy.deepcopy(value))
    else:
        parent[path[-1]] = copy.deepcopy(value)
    return data


FMS_SCENES = ("fms_kr16", "fms_kr300", "fms_kr500")


def test_shipped_scene_names():
    assert {*FMS_SCENES, "ur5_table"} <= set(scene_names())


@pytest.mark.parametrize("name", ["fms_kr16", "ur5_table"])
def test_shipped_scenes_load(name):
    scene = load_scene(name)
    assert scene.name == name
    assert scene.robot.nq == 6
    assert scene.units == {"length": "mm", "angle": "deg"}
    np.testing.assert_allclose(scene.tracker.sigma, [1e-5] * 3)  # 0.01 mm
    np.testing.assert_allclose(scene.tracker.sigma_angle, [1e-5] * 3)  # default 0.01 mrad
    assert 2.0 < np.linalg.norm(scene.tracker.position) < 3.0
    assert scene.measurement == "position" and scene.kpi.frame == "world"
    assert np.all((scene.kpi.q >= scene.robot.lower) & (scene.kpi.q <= scene.robot.upper))
    assert load_scene(scene.source).name == name  # by path too


def test_fms_kr16_numbers():
    """The numbers in fms_kr16.yaml, converted to SI, and the TCP its comment states."""
    scene = load_scene("fms_kr16")
    np.testing.assert_allclose(scene.tracker.position, [0.6, -2.6, 1.3])
    np.testing.assert_allclose(scene.tracker.rpy, [0.0, math.radians(10), math.pi / 2])
    np.testing.assert_allclose(scene.reflectors[0].offset, [0, 0, 0.05])
    np.testing.assert_allclose(scene.kpi.q, np.radians([[-9, -73, 104, -38, -13, 0]]))
    model = scene.robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, scene.kpi.configurations[0].q)
    tcp = data.oMf[scene.robot.tool_frame_id].translation
    np.testing.assert_allclose(tcp, [1.1506, 0.1601, 0.8949], atol=1e-4)
    placement = scene.tracker.placement()
    np.testing.assert_allclose(placement.rotation, pin.rpy.rpyToMatrix(*scene.tracker.rpy))
    np.testing.assert_allclose(placement.translation, scene.tracker.position)
    # yaw 90 deg: the tracker x axis points along +y, toward the robot
    assert placement.rotation[1, 0] > 0.98


def test_si_units_and_options():
    data = valid()
    data["units"] = {"length": "m", "angle": "rad"}
    data["reflectors"] = [{"name": "smr0", "offset": [0, 0, 0.05]}]
    data["tracker"] = {"position": [0.6, -2.6, 1.3], "rpy": [0, 0, 1.5],
                       "sigma": [1e-5, 2e-5, 3e-5], "sigma_angle": 2e-5}
    data["kpi"] = {"point": [0, 0, 0.1], "frame": "tracker",
                   "working_configurations": [{"name": "wc", "q": [0, -1.5, 1.5, 0, 0.7, 0]}]}
    data["robot"]["joint_limits"] = {"joint_a5": [-1, 1]}
    data.update(measurement="pose", generic_design={"n": 50, "seed": 3})
    scene = scene_from_dict(data)
    np.testing.assert_allclose(scene.tracker.sigma, [1e-5, 2e-5, 3e-5])
    np.testing.assert_allclose(scene.tracker.sigma_angle, [2e-5] * 3)
    np.testing.assert_allclose(scene.kpi.point, [0, 0, 0.1])
    assert (scene.robot.lower[4], scene.robot.upper[4]) == (-1.0, 1.0)
    assert scene.measurement == "pose" and scene.kpi.frame == "tracker"
    assert (scene.generic_design.n, scene.generic_design.seed) == (50, 3)
    assert scene.source is None


def test_joint_limit_override_in_file_units():
    data = mutated(("robot", "joint_limits"), {"joint_a2": [-120, 30]})
    scene = scene_from_dict(data)
    np.testing.assert_allclose([scene.robot.lower[1], scene.robot.upper[1]],
                               np.radians([-120, 30]))


def test_lock_joints_in_file_units():
    data = mutated(("robot", "lock_joints"), {"joint_a6": 90})
    data["kpi"]["working_configurations"][0]["q"] = [0, -90, 90, 0, 45]
    scene = scene_from_dict(data)
    assert scene.robot.nq == 5
    assert scene.robot.locked_joints == {"joint_a6": pytest.approx(math.pi / 2)}


def test_arrays_are_read_only():
    scene = scene_from_dict(valid())
    for arr in (scene.tracker.position, scene.tracker.sigma, scene.reflectors[0].offset,
                scene.kpi.configurations[0].q, scene.kpi.point):
        with pytest.raises(ValueError):
            arr[0] = 1.0


def test_relative_urdf_path_and_prismatic_units(tmp_path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "rp.urdf").write_text(RP_URDF)
    data = valid()
    data["robot"] = {"urdf": "models/rp.urdf", "joint_limits": {"slide": [0, 300]}}
    data["kpi"]["working_configurations"][0]["q"] = [90, 250]
    scene = scene_from_dict(data, source=str(tmp_path / "scene.yaml"))
    assert scene.robot.urdf_path == (tmp_path / "models" / "rp.urdf").resolve()
    np.testing.assert_allclose(scene.kpi.q, [[math.pi / 2, 0.25]])  # deg -> rad, mm -> m
    assert scene.robot.upper[1] == pytest.approx(0.3)
    data["kpi"]["working_configurations"][0]["q"] = [90, 350]
    with pytest.raises(SceneError, match=r"slide = 350 mm is outside its limits \[0, 300\] mm"):
        scene_from_dict(data, source=str(tmp_path / "scene.yaml"))
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source=str(tmp_path / "elsewhere" / "scene.yaml"))
    assert err.value.key == "robot.urdf" and "URDF file not found" in str(err.value)


Q = ("kpi", "working_configurations", 0, "q")
WC = ("kpi", "working_configurations")
BAD_CASES = [
    # (id, path, value, key in the error, text in the message)
    ("unknown-top-key", ("colour",), "red", "colour", "valid keys of the top level are"),
    ("unknown-key", ("tracker", "colour"), "red", "tracker.colour",
     "position, rpy, sigma, sigma_angle"),
    ("missing-top-key", ("kpi",), DELETE, "kpi", "missing required key"),
    ("missing-key", ("tracker", "sigma"), DELETE, "tracker.sigma", "missing required key"),
    ("not-a-list", ("tracker", "position"), "abc", "tracker.position",
     "expected a list of 3 numbers, got 'abc'"),
    ("not-a-number", ("tracker", "position", 1), "x", "tracker.position[1]",
     "expected a number, got 'x'"),
    ("number-as-text", ("tracker", "sigma"), "1e-5", "tracker.sigma", "write 1.0e-5"),
    ("not-a-mapping", ("tracker",), [1, 2], "tracker", "expected a mapping"),
    ("length-unit", ("units", "length"), "inch", "units.length", "m, mm"),
    ("angle-unit", ("units", "angle"), "grad", "units.angle", "rad, deg"),
    ("vector-length", ("reflectors", 0, "offset"), [0, 50], "reflectors[0].offset",
     "expected 3 values"),
    ("nan", ("tracker", "rpy", 0), math.nan, "tracker.rpy[0]", "finite"),
    ("inf", (*Q, 2), math.inf, "kpi.working_configurations[0].q[2]", "finite"),
    ("sigma-zero", ("tracker", "sigma"), 0, "tracker.sigma", "> 0"),
    ("sigma-axis-negative", ("tracker", "sigma"), [0.01, -0.01, 0.01], "tracker.sigma[1]",
     "> 0"),
    ("sigma-angle-negative", ("tracker", "sigma_angle"), -0.1, "tracker.sigma_angle", "> 0"),
    ("joint-count", Q, [0, -90, 90, 0, 45], "kpi.working_configurations[0].q",
     "expected 6 values (one per joint: joint_a1, joint_a2"),
    ("joint-limit", (*Q, 1), 40, "kpi.working_configurations[0].q",
     "joint_a2 = 40 deg is outside its limits [-155, 35] deg"),
    ("joint-limit-override", ("robot", "joint_limits"), {"joint_a5": [-30, 30]},
     "kpi.working_configurations[0].q", "joint_a5 = 45 deg is outside its limits [-30, 30] deg"),
    ("duplicate-reflector", ("reflectors", 1), {"name": "smr0", "offset": [0, 0, 0]},
     "reflectors[1].name", "duplicate reflector name 'smr0'"),
    ("duplicate-configuration", (*WC, 1), {"name": "wc", "q": [0, -90, 90, 0, 45, 0]},
     "kpi.working_configurations[1].name", "duplicate working configuration name 'wc'"),
    ("no-reflector", ("reflectors",), [], "reflectors", "non-empty list"),
    ("no-configuration", WC, [], "kpi.working_configurations", "non-empty list"),
    ("version", ("version",), 2, "version", "supported versions: 1"),
    ("measurement", ("measurement",), "laser", "measurement", "position, pose"),
    ("kpi-frame", ("kpi", "frame"), "tool", "kpi.frame", "world, tracker"),
    ("robot-name-and-urdf", ("robot", "urdf"), "arm.urdf", "robot", "exactly one of"),
    ("unknown-robot", ("robot", "name"), "r2d2", "robot", "unknown robot 'r2d2'"),
    ("unknown-tool-frame", ("robot", "tool_frame"), "nose", "robot", "unknown frame 'nose'"),
    ("unknown-limit-joint", ("robot", "joint_limits"), {"joint_x": [0, 1]},
     "robot.joint_limits.joint_x", "unknown joint"),
    ("inconsistent-limits", ("robot", "joint_limits"), {"joint_a1": [10, -10]},
     "robot.joint_limits.joint_a1", "lower limit 10 is not below upper limit -10"),
    ("limits-not-a-pair", ("robot", "joint_limits"), {"joint_a1": [10]},
     "robot.joint_limits.joint_a1", "expected 2 values (lower, upper)"),
    ("lock-unknown-joint", ("robot", "lock_joints"), {"joint_x": 0}, "robot",
     "unknown joint 'joint_x'"),
    ("design-size", ("generic_design",), {"n": 0}, "generic_design.n", "integer >= 1"),
    ("kpi-reflector", ("kpi", "reflector"), "smr9", "kpi.reflector", "expected one of the reflectors"),
]


def capsule(**change) -> dict:
    """A valid cell capsule entry [mm], with ``change`` applied."""
    return {"name": "car", "a": [1750, -1800, 550], "b": [1750, 1800, 550], "radius": 450, **change}


CELL, FEAS = ("cell",), ("feasibility",)
HS = "cell.halfspaces[0]"
CELL_CASES = [
    ("cell-not-a-mapping", CELL, [], "cell", "expected a mapping"),
    ("cell-unknown-key", CELL, {"walls": []}, "cell.walls",
     "valid keys of 'cell' are: capsules, halfspaces"),
    ("capsules-not-a-list", CELL, {"capsules": {"a": 1}}, "cell.capsules", "expected a list"),
    ("capsule-radius-zero", CELL, {"capsules": [capsule(radius=0)]}, "cell.capsules[0].radius",
     "expected a number > 0, got 0"),
    ("capsule-radius-negative", CELL, {"capsules": [capsule(radius=-5)]},
     "cell.capsules[0].radius", "expected a number > 0"),
    ("capsule-vector-length", CELL, {"capsules": [capsule(a=[0, 0])]}, "cell.capsules[0].a",
     "expected 3 values (x, y, z)"),
    ("capsule-unknown-key", CELL, {"capsules": [capsule(colour="red")]},
     "cell.capsules[0].colour", "valid keys of 'cell.capsules[0]' are: name, a, b, radius"),
    ("capsule-missing-radius", CELL, {"capsules": [{"name": "c", "a": [0, 0, 0], "b": [0, 0, 1]}]},
     "cell.capsules[0].radius", "missing required key"),
    ("duplicate-obstacle", CELL, {"capsules": [capsule()], "halfspaces": [{"name": "car",
                                                                            "z_min": 0}]},
     "cell.halfspaces[0].name", "duplicate name 'car'"),
    ("halfspace-both-forms", CELL, {"halfspaces": [{"name": "f", "z_min": 0, "normal": [0, 0, 1],
                                                    "offset": 0}]},
     HS, "exactly one of x_min, x_max, y_min, y_max, z_min, z_max; got normal, offset, z_min"),
    ("halfspace-two-shorthands", CELL, {"halfspaces": [{"name": "f", "z_min": 0, "x_min": 0}]},
     HS, "got x_min, z_min"),
    ("halfspace-no-plane", CELL, {"halfspaces": [{"name": "f"}]}, HS, "got neither"),
    ("halfspace-no-offset", CELL, {"halfspaces": [{"name": "f", "normal": [0, 0, 1]}]},
     f"{HS}.offset", "missing required key"),
    ("halfspace-zero-normal", CELL, {"halfspaces": [{"name": "f", "normal": [0, 0, 0],
                                                     "offset": 0}]},
     f"{HS}.normal", "must be non-zero"),
    ("halfspace-normal-length", CELL, {"halfspaces": [{"name": "f", "normal": [0, 1],
                                                       "offset": 0}]},
     f"{HS}.normal", "expected 3 values (nx, ny, nz)"),
    ("halfspace-unknown-key", CELL, {"halfspaces": [{"name": "f", "z_minimum": 0}]},
     f"{HS}.z_minimum", "normal, offset, x_min"),
    ("feasibility-unknown-key", FEAS, {"beam": 5}, "feasibility.beam",
     "valid keys of 'feasibility' are: incidence_limit, beam_radius, reflector_radius, "
     "capsule_margin, margins, excluded_pairs, robot_capsules, prune"),
    ("margins-unknown-key", FEAS, {"margins": {"clearence": 5}}, "feasibility.margins.clearence",
     "clearance, incidence, joint"),
    ("prune-unknown-key", FEAS, {"prune": {"steps": 5}}, "feasibility.prune.steps",
     "samples, seed, distance"),
    ("incidence-limit-90", FEAS, {"incidence_limit": 90}, "feasibility.incidence_limit",
     "expected an angle in (0, 90) deg, got 90"),
    ("incidence-limit-zero", FEAS, {"incidence_limit": 0}, "feasibility.incidence_limit",
     "(0, 90) deg"),
    ("incidence-limit-negative", FEAS, {"incidence_limit": -10}, "feasibility.incidence_limit",
     "(0, 90) deg"),
    ("beam-radius-zero", FEAS, {"beam_radius": 0}, "feasibility.beam_radius", "> 0"),
    ("reflector-radius-negative", FEAS, {"reflector_radius": -1}, "feasibility.reflector_radius",
     "> 0"),
    ("capsule-margin-negative", FEAS, {"capsule_margin": -1}, "feasibility.capsule_margin",
     ">= 0, got -1"),
    ("clearance-negative", FEAS, {"margins": {"clearance": -1}}, "feasibility.margins.clearance",
     ">= 0, got -1"),
    ("incidence-margin-negative", FEAS, {"margins": {"incidence": -2}},
     "feasibility.margins.incidence", ">= 0"),
    ("joint-margin-negative", FEAS, {"margins": {"joint": -0.5}}, "feasibility.margins.joint",
     ">= 0"),
    ("incidence-margin-above-limit", FEAS, {"incidence_limit": 20, "margins": {"incidence": 25}},
     "feasibility.margins.incidence", "must be below the incidence limit (20 deg), got 25 deg"),
    ("joint-margin-too-wide", FEAS, {"margins": {"joint": 100}}, "feasibility.margins.joint",
     "leaves nothing of the range of joint_a2 (190 deg)"),
    ("excluded-not-a-list", FEAS, {"excluded_pairs": "link_1"}, "feasibility.excluded_pairs",
     "expected a list"),
    ("excluded-unknown-link", FEAS, {"excluded_pairs": [["link_1", "link_9"]]},
     "feasibility.excluded_pairs[0][1]",
     "unknown link 'link_9'; the robot's links are: 'base_link', 'link_1', 'link_2'"),
    ("excluded-not-a-pair", FEAS, {"excluded_pairs": [["link_1"]]},
     "feasibility.excluded_pairs[0]", "expected a pair of link names"),
    ("excluded-self", FEAS, {"excluded_pairs": [["link_1", "link_1"]]},
     "feasibility.excluded_pairs[0]", "never checked against itself"),
    ("excluded-duplicate", FEAS, {"excluded_pairs": [["link_1", "link_3"], ["link_3", "link_1"]]},
     "feasibility.excluded_pairs[1]", "duplicate pair [link_3, link_1]"),
    ("robot-capsule-unknown-link", FEAS,
     {"robot_capsules": [{"link": "arm", "a": [0, 0, 0], "b": [1, 0, 0], "radius": 1}]},
     "feasibility.robot_capsules[0].link", "unknown link 'arm'; the robot's links are:"),
    ("robot-capsule-radius", FEAS,
     {"robot_capsules": [{"link": "link_2", "a": [0, 0, 0], "b": [1, 0, 0], "radius": 0}]},
     "feasibility.robot_capsules[0].radius", "> 0"),
    ("robot-capsule-vector-length", FEAS,
     {"robot_capsules": [{"link": "link_2", "a": [0, 0, 0], "b": [1, 0], "radius": 1}]},
     "feasibility.robot_capsules[0].b", "expected 3 values"),
    ("robot-capsules-empty", FEAS, {"robot_capsules": []}, "feasibility.robot_capsules",
     "omit the key to fit capsules"),
    ("prune-samples", FEAS, {"prune": {"samples": 0}}, "feasibility.prune.samples",
     "integer >= 1"),
    ("prune-distance", FEAS, {"prune": {"distance": 0}}, "feasibility.prune.distance", "> 0"),
]
BAD_CASES += CELL_CASES


def test_kpi_reflector():
    data = mutated(("kpi", "reflector"), "smr0")
    assert scene_from_dict(data).kpi.reflector == 0
    data["kpi"]["point"] = [0, 0, 0]
    with pytest.raises(SceneError, match="not both") as err:
        scene_from_dict(data)
    assert err.value.key == "kpi.reflector"


@pytest.mark.parametrize(("path", "value", "key", "text"), [c[1:] for c in BAD_CASES],
                         ids=[c[0] for c in BAD_CASES])
def test_invalid_scene(path, value, key, text):
    with pytest.raises(SceneError) as err:
        scene_from_dict(mutated(path, value), source="cell.yaml")
    assert err.value.key == key
    message = str(err.value)
    assert message.startswith(f"cell.yaml: {key}: ")
    assert text in message


def test_unknown_scene_name_lists_shipped_scenes():
    with pytest.raises(UnknownSceneError) as err:
        load_scene("no_such_scene")
    assert "no_such_scene" in str(err.value)
    assert {"fms_kr16", "ur5_table"} <= set(err.value.valid)


def test_missing_file(tmp_path):
    path = tmp_path / "missing.yaml"
    with pytest.raises(SceneError, match="scene file not found") as err:
        load_scene(path)
    assert not isinstance(err.value, UnknownSceneError)
    assert str(path) in str(err.value)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("version: 1\nunits: {length: mm\nname: x\n", r"YAML syntax error at line \d+"),
        ("- just\n- a list\n", "expected a mapping with keys version, name"),
        ("", "expected a mapping with keys version, name"),
    ],
    ids=["syntax", "list", "empty"],
)
def test_malformed_file(tmp_path, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(SceneError, match=match) as err:
        load_scene(path)
    assert err.value.source == str(path) and err.value.key is None


# ---------------------------------------------------------------- cell and feasibility


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] of points p (..., 3) to the segment a-b."""
    ab = b - a
    t = np.clip((np.asarray(p) - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def segment_distance_lower_bound(p0, p1, a, b, n: int = 4001) -> float:
    """A lower bound [m] on the distance between segments p0-p1 and a-b, by brute force.

    The distance to a-b is 1-Lipschitz along p0-p1, so the minimum over ``n``
    evenly spaced points, minus half their spacing, bounds the true minimum from below.
    """
    s = np.linspace(0.0, 1.0, n)[:, None]
    points = p0 + s * (p1 - p0)
    spacing = np.linalg.norm(p1 - p0) / (n - 1)
    return float(point_segment_distance(points, a, b).min() - spacing / 2)


def working_pose(scene) -> pin.SE3:
    """Pose of the tool frame in the world at the scene's first working configuration."""
    model = scene.robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, scene.kpi.configurations[0].q)
    return data.oMf[scene.robot.tool_frame_id]


def assert_defaults(settings: FeasibilitySettings):
    default = FeasibilitySettings()
    for name in ("incidence_limit", "beam_radius", "reflector_radius", "capsule_margin",
                 "prune_distance"):
        assert getattr(settings, name) == pytest.approx(getattr(default, name), abs=1e-15), name
    for name in ("clearance", "incidence", "joint"):
        assert getattr(settings.margins, name) == pytest.approx(getattr(default.margins, name),
                                                                abs=1e-15), name
    assert settings.excluded_pairs == () and settings.robot_capsules is None
    assert (settings.prune_samples, settings.prune_seed) == (2000, 0)


@pytest.mark.parametrize("name", FMS_SCENES)
def test_fms_scenes_cell_matches_file(name):
    """Every cell number of the YAML file, converted from mm to m; the defaults written out."""
    scene = load_scene(name)
    raw = yaml.safe_load(Path(scene.source).read_text())
    assert scene.robot.name == name.removeprefix("fms_")
    assert [c.name for c in scene.cell.capsules] == ["car_body", "car_cabin", "tracker_stand"]
    assert [h.name for h in scene.cell.halfspaces] == ["floor", "wall"]
    for cap, entry in zip(scene.cell.capsules, raw["cell"]["capsules"], strict=True):
        assert cap.frame is None
        np.testing.assert_allclose(cap.a, np.array(entry["a"]) * 1e-3)
        np.testing.assert_allclose(cap.b, np.array(entry["b"]) * 1e-3)
        assert cap.radius == pytest.approx(entry["radius"] * 1e-3)
    floor, wall = scene.cell.halfspaces
    np.testing.assert_array_equal(floor.normal, [0, 0, 1])
    assert floor.offset == 0.0
    np.testing.assert_array_equal(wall.normal, [1, 0, 0])
    assert wall.offset == pytest.approx(raw["cell"]["halfspaces"][1]["x_min"] * 1e-3)
    assert_defaults(scene.feasibility)
    # The stand: vertical, from the floor to 300 mm below the tracker head, radius 100 mm.
    stand = scene.cell.capsules[2]
    np.testing.assert_allclose(stand.a, [*scene.tracker.position[:2], 0.0])
    np.testing.assert_allclose(stand.b, scene.tracker.position - [0, 0, 0.3])
    assert stand.radius == pytest.approx(0.1)
    # The tracker: in the cell, in front of the wall, outside the car, at most 8 m away.
    tracker = scene.tracker.position
    assert 2.0 < np.linalg.norm(tracker) < 8.0
    assert all(h.signed_distance(tracker) > 0 for h in scene.cell.halfspaces)
    for cap in scene.cell.capsules[:2]:
        assert point_segment_distance(tracker, cap.a, cap.b) > cap.radius


def test_fms_wall_is_the_papers():
    wall = load_scene("fms_kr16").cell.halfspaces[1]
    assert wall.offset == pytest.approx(-0.45)


@pytest.mark.parametrize("name", ["fms_kr300", "fms_kr500"])
def test_fms_scaled_scenes(name):
    """The kr16 cell times the reach ratio (to the 1 mm of rounding); the instrument unchanged."""
    base, scene = load_scene("fms_kr16"), load_scene(name)
    s = kuka.KUKA_ROBOTS[scene.robot.name].reach / kuka.KR16.reach
    tol = 0.5e-3 + 1e-12
    for cap0, cap in zip(base.cell.capsules[:2], scene.cell.capsules[:2], strict=True):
        np.testing.assert_allclose(cap.a, s * cap0.a, rtol=0, atol=tol)
        np.testing.assert_allclose(cap.b, s * cap0.b, rtol=0, atol=tol)
        assert cap.radius == pytest.approx(s * cap0.radius, abs=tol)
    assert scene.cell.halfspaces[1].offset == pytest.approx(s * base.cell.halfspaces[1].offset,
                                                           abs=tol)
    np.testing.assert_allclose(scene.tracker.position, s * base.tracker.position, rtol=0, atol=tol)
    np.testing.assert_allclose(scene.reflectors[0].offset, base.reflectors[0].offset)
    np.testing.assert_allclose(scene.tracker.sigma, base.tracker.sigma)
    np.testing.assert_allclose(scene.kpi.q, base.kpi.q)


@pytest.mark.parametrize(("name", "tcp", "max_angle"), [
    ("fms_kr16", [1150.6, 160.1, 894.9], 3.0),
    ("fms_kr300", [1728.4, 240.1, 1140.6], 1.0),
    ("fms_kr500", [1980.7, 273.0, 1611.7], 1.0),
])
def test_fms_tracker_aims_at_working_volume(name, tcp, max_angle):
    """The TCP in the file's comment; the tracker x axis aims at the shoulder-TCP midpoint."""
    scene = load_scene(name)
    pose = working_pose(scene)
    np.testing.assert_allclose(pose.translation, np.array(tcp) * 1e-3, atol=1e-4)
    np.testing.assert_allclose(pose.rotation[:, 2], [0.937, 0.008, -0.350], atol=1e-3)
    model = scene.robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, scene.kpi.configurations[0].q)
    middle = (data.oMi[2].translation + pose.translation) / 2  # joint_a2 origin: the shoulder
    aim = (middle - scene.tracker.position) / np.linalg.norm(middle - scene.tracker.position)
    x_axis = scene.tracker.placement().rotation[:, 0]
    assert math.degrees(math.acos(x_axis @ aim)) < max_angle  # fms_kr16: 2.3 deg (rounder angles)


@pytest.mark.parametrize("name", FMS_SCENES)
def test_fms_working_configuration_clears_cell(name):
    """At car_side the reflector clears the car, floor and wall by more than
    reflector_radius + clearance; the beam to the tracker clears the car and the
    tracker stand by more than beam_radius + clearance (brute-force distances)."""
    scene = load_scene(name)
    settings = scene.feasibility
    pose = working_pose(scene)
    tool = pose.translation
    reflector = pose.act(scene.reflectors[0].offset)
    tracker = scene.tracker.position
    cars = [c for c in scene.cell.capsules if c.name.startswith("car_")]
    stand = next(c for c in scene.cell.capsules if c.name == "tracker_stand")
    need = settings.reflector_radius + settings.margins.clearance
    for car in cars:
        assert point_segment_distance(reflector, car.a, car.b) - car.radius > need, car.name
        # the whole reflector capsule, tool0 origin to reflector centre
        assert segment_distance_lower_bound(tool, reflector, car.a, car.b) - car.radius > need
    for h in scene.cell.halfspaces:
        assert h.signed_distance(reflector) > need, h.name
    need = settings.beam_radius + settings.margins.clearance
    for obstacle in [*cars, stand]:
        clearance = segment_distance_lower_bound(reflector, tracker, obstacle.a, obstacle.b)
        assert clearance - obstacle.radius > need, obstacle.name


@pytest.mark.parametrize("name", FMS_SCENES)
def test_fms_arm_clears_car_at_working_configuration(name):
    """The arm's URDF collision geometry is clear of the car at car_side (coal distances)."""
    scene = load_scene(name)
    model = scene.robot.model
    geometry = pin.buildGeomFromUrdfString(model, scene.robot.urdf_text,
                                           pin.GeometryType.COLLISION)
    geometry_data = pin.GeometryData(geometry)
    data = model.createData()
    pin.framesForwardKinematics(model, data, scene.kpi.configurations[0].q)
    pin.updateGeometryPlacements(model, data, geometry, geometry_data)
    for car in scene.cell.capsules[:2]:
        axis = car.b - car.a  # the car capsules lie along y: rotate coal's z axis onto y
        assert np.allclose(axis[[0, 2]], 0.0)
        placement = coal.Transform3s(pin.rpy.rpyToMatrix(-math.pi / 2, 0, 0), (car.a + car.b) / 2)
        shape = coal.Capsule(car.radius, float(np.linalg.norm(axis)))
        for obj, placed in zip(geometry.geometryObjects, geometry_data.oMg, strict=True):
            distance = coal.distance(obj.geometry, coal.Transform3s(placed.rotation,
                                                                    placed.translation),
                                     shape, placement, coal.DistanceRequest(),
                                     coal.DistanceResult())
            assert distance > scene.feasibility.margins.clearance, (car.name, obj.name)


def test_cell_and_feasibility_are_optional():
    scene = scene_from_dict(valid())
    assert scene.cell.capsules == () and scene.cell.halfspaces == ()
    assert_defaults(scene.feasibility)
    empty = scene_from_dict(mutated(("cell",), {"capsules": [], "halfspaces": []}))
    assert empty.cell.capsules == () and empty.cell.halfspaces == ()
    assert_defaults(scene_from_dict(mutated(("feasibility",), {})).feasibility)


CELL_MM = {
    "capsules": [capsule(), {"name": "ball", "a": [0, 0, 2000], "b": [0, 0, 2000],
                             "radius": 100}],
    "halfspaces": [{"name": "floor", "z_min": 0}, {"name": "wall", "x_min": -450},
                   {"name": "slope", "normal": [1, 0, 1], "offset": 1000}],
}
FEASIBILITY_DEG_MM = {
    "incidence_limit": 40, "beam_radius": 4, "reflector_radius": 25, "capsule_margin": 15,
    "margins": {"clearance": 20, "incidence": 3, "joint": 2},
    "excluded_pairs": [["base_link", "link_2"]],
    "robot_capsules": [{"link": "link_2", "a": [0, 0, 0], "b": [680, 0, 0], "radius": 120},
                       {"link": "link_2", "a": [100, 0, 0], "b": [200, 0, 0], "radius": 130},
                       {"link": "link_3", "a": [0, 0, 0], "b": [500, 0, -35], "radius": 90,
                        "name": "forearm"}],
    "prune": {"samples": 500, "seed": 7, "distance": 150},
}


def si_file(data: dict) -> dict:
    """The same scene in m and rad: every length / 1000, every angle in rad."""
    data = copy.deepcopy(data)
    data["units"] = {"length": "m", "angle": "rad"}
    mm, deg = 1e-3, math.radians(1)
    t = data["tracker"]
    t.update(position=[v * mm for v in t["position"]], rpy=[v * deg for v in t["rpy"]],
             sigma=t["sigma"] * mm)
    data["reflectors"][0]["offset"] = [v * mm for v in data["reflectors"][0]["offset"]]
    for wc in data["kpi"]["working_configurations"]:
        wc["q"] = [v * deg for v in wc["q"]]
    for cap in data["cell"]["capsules"] + data["feasibility"]["robot_capsules"]:
        cap.update(a=[v * mm for v in cap["a"]], b=[v * mm for v in cap["b"]],
                   radius=cap["radius"] * mm)
    for hs in data["cell"]["halfspaces"]:
        for k in ("offset", "x_min", "z_min"):
            if k in hs:
                hs[k] *= mm
    f = data["feasibility"]
    f["incidence_limit"] *= deg
    for k in ("beam_radius", "reflector_radius", "capsule_margin"):
        f[k] *= mm
    f["margins"] = {"clearance": 20 * mm, "incidence": 3 * deg, "joint": 2 * deg}
    f["prune"]["distance"] *= mm
    return data


def test_cell_and_feasibility_in_si():
    """Every new key converted to SI; the same scene in mm/deg and in m/rad gives the same."""
    data = valid()
    data.update(cell=copy.deepcopy(CELL_MM), feasibility=copy.deepcopy(FEASIBILITY_DEG_MM))
    # the slope x + z >= 1000 mm cuts through the robot: reading only, not the scene check
    scenes = [scene_from_dict(data, check=False), scene_from_dict(si_file(data), check=False)]
    cell = scenes[0].cell
    np.testing.assert_allclose(cell.capsules[0].a, [1.75, -1.8, 0.55])
    assert cell.capsules[1].radius == pytest.approx(0.1)
    slope = cell.halfspaces[2]  # x + z >= 1000 mm, normalised: (x + z)/sqrt(2) >= 0.707 m
    np.testing.assert_allclose(slope.normal, np.array([1, 0, 1]) / math.sqrt(2))
    assert slope.offset == pytest.approx(1.0 / math.sqrt(2))
    assert slope.signed_distance(np.array([0.5, 0.0, 0.5])) == pytest.approx(0.0, abs=1e-12)
    f = scenes[0].feasibility
    assert f.incidence_limit == pytest.approx(math.radians(40))
    assert (f.beam_radius, f.reflector_radius, f.capsule_margin) == pytest.approx(
        (0.004, 0.025, 0.015))
    assert isinstance(f.margins, Margins)
    assert (f.margins.clearance, f.margins.incidence, f.margins.joint) == pytest.approx(
        (0.02, math.radians(3), math.radians(2)))
    assert f.excluded_pairs == (("base_link", "link_2"),)
    assert [(c.frame, c.name) for c in f.robot_capsules] == [
        ("link_2", "link_2#0"), ("link_2", "link_2#1"), ("link_3", "forearm")]
    assert all(isinstance(c, Capsule) for c in f.robot_capsules)
    np.testing.assert_allclose(f.robot_capsules[2].b, [0.5, 0, -0.035])
    assert (f.prune_samples, f.prune_seed, f.prune_distance) == (500, 7, pytest.approx(0.15))
    for c0, c1 in zip(scenes[0].cell.capsules + f.robot_capsules,
                      scenes[1].cell.capsules + scenes[1].feasibility.robot_capsules, strict=True):
        np.testing.assert_allclose([c0.a, c0.b], [c1.a, c1.b], rtol=1e-12, atol=1e-15)
        assert c0.radius == pytest.approx(c1.radius, rel=1e-12)
        assert (c0.name, c0.frame) == (c1.name, c1.frame)
    for h0, h1 in zip(cell.halfspaces, scenes[1].cell.halfspaces, strict=True):
        np.testing.assert_allclose(h0.normal, h1.normal)
        assert h0.offset == pytest.approx(h1.offset, rel=1e-12, abs=1e-15)
    f1 = scenes[1].feasibility
    for name in ("incidence_limit", "beam_radius", "reflector_radius", "capsule_margin",
                 "prune_distance"):
        assert getattr(f, name) == pytest.approx(getattr(f1, name), rel=1e-12)
    with pytest.raises(ValueError):
        cell.capsules[0].a[0] = 1.0  # read-only


@pytest.mark.parametrize(("entry", "normal", "offset"), [
    ({"z_min": 0}, [0, 0, 1], 0.0),
    ({"z_max": 2500}, [0, 0, -1], -2.5),
    ({"x_min": -450}, [1, 0, 0], -0.45),
    ({"x_max": 4000}, [-1, 0, 0], -4.0),
    ({"y_min": -3000}, [0, 1, 0], -3.0),
    ({"y_max": 3000}, [0, -1, 0], -3.0),
    ({"normal": [0, 0, 2], "offset": 100}, [0, 0, 1], 0.05),  # 2 z >= 100 mm: z >= 50 mm
])
def test_halfspace_shorthands(entry, normal, offset):
    scene = scene_from_dict(mutated(("cell",), {"halfspaces": [{"name": "plane", **entry}]}))
    (plane,) = scene.cell.halfspaces
    np.testing.assert_allclose(plane.normal, normal)
    assert plane.offset == pytest.approx(offset)
    if len(entry) == 1:  # a point on the plane has zero signed distance
        ((key, value),) = entry.items()
        point = np.zeros(3)
        point["xyz".index(key[0])] = value * 1e-3
        assert plane.signed_distance(point) == pytest.approx(0.0, abs=1e-12)


def test_package_dirs_find_meshes_of_a_urdf_elsewhere(tmp_path):
    """A URDF whose package:// meshes live in another folder loads once
    robot.package_dirs names it; without it the capsule fit says what to set."""
    from calib_oed.calibration.workflow import setup
    from calib_oed.model.registry import example_robot_data_share

    share = example_robot_data_share()
    if share is None:
        pytest.skip("example-robot-data is not installed")
    urdf = share / "example-robot-data" / "robots" / "ur_description" / "urdf" / "ur5_robot.urdf"
    copy = tmp_path / "ur5.urdf"
    copy.write_text(urdf.read_text())
    from importlib import resources

    base = yaml.safe_load(resources.files("calib_oed.scene.shipped").joinpath("ur5_table.yaml").read_text())
    base["robot"] = {"urdf": "ur5.urdf", "tool_frame": "tool0"}
    (tmp_path / "no_packages.yaml").write_text(yaml.safe_dump(base))
    with pytest.raises(CalibOedError, match="robot.package_dirs"):
        setup(load_scene(tmp_path / "no_packages.yaml")).feasibility  # noqa: B018
    base["robot"]["package_dirs"] = [str(share)]
    (tmp_path / "packages.yaml").write_text(yaml.safe_dump(base))
    s = setup(load_scene(tmp_path / "packages.yaml"))
    assert s.feasibility.n_constraints > 0
    base["robot"]["package_dirs"] = ["no/such/folder"]
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(base))
    with pytest.raises(SceneError, match=r"robot.package_dirs\[0\].*folder not found"):
        load_scene(tmp_path / "bad.yaml")


XACRO_PACKAGE = Path(__file__).parents[1] / "model" / "data" / "calib_test_arm"


def xacro_scene(robot: dict) -> dict:
    return {
        "version": 1, "name": "xacro_arm", "units": {"length": "mm", "angle": "deg"},
        "robot": robot,
        "tracker": {"position": [1500, -1500, 500], "rpy": [0, 0, 135], "sigma": 0.01},
        "reflectors": [{"name": "smr0", "offset": [0, 0, 30]}],
        "kpi": {"working_configurations": [{"name": "up", "q": [10, -30]}]},
        "cell": {"halfspaces": [{"name": "floor", "z_min": -10}]},
    }


def test_robot_from_a_xacro_file_with_arguments(tmp_path, monkeypatch):
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    shutil.copytree(XACRO_PACKAGE, tmp_path / "ws" / "calib_test_arm")
    # xacro arguments are passed as written (the xacro's own units), not converted by units:
    data = xacro_scene({"xacro": "ws/calib_test_arm/urdf/arm.urdf.xacro",
                        "args": {"upper_length": 0.6, "prefix": "r1_"}})
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    scene = load_scene(tmp_path / "cell.yaml")
    assert scene.robot.joint_names == ("r1_joint_1", "r1_joint_2")
    assert scene.robot.xacro_args == {"upper_length": "0.6", "prefix": "r1_"}
    tool = scene.robot.model.frames[scene.robot.tool_frame_id]
    np.testing.assert_allclose(tool.placement.translation, [0.6, 0, 0], atol=1e-12)
    assert str((tmp_path / "ws").resolve()) in scene.robot.package_dirs


@pytest.mark.parametrize(("robot", "key", "message"), [
    ({"urdf": "arm.urdf.xacro"}, "robot.urdf", "goes under robot.xacro"),
    ({"name": "kr16", "args": {"a": 1}}, "robot.args", "arguments are for a xacro file"),
    ({"xacro": "arm.urdf.xacro", "args": [1]}, "robot.args", "expected a mapping"),
    ({"xacro": "arm.urdf.xacro", "args": {"prefix": [1]}}, "robot.args.prefix", "expected a string"),
    ({"xacro": "arm.urdf.xacro", "urdf": "x.urdf"}, "robot", "exactly one of"),
    ({"xacro": "absent.urdf.xacro"}, "robot.xacro", "xacro file not found"),
])
def test_xacro_robot_errors(robot, key, message):
    source = str(XACRO_PACKAGE / "urdf" / "cell.yaml")
    with pytest.raises(SceneError, match=message) as err:
        scene_from_dict(xacro_scene(robot), source=source)
    assert err.value.key == key


def test_a_scene_includes_another_and_overrides_keys(tmp_path):
    """``include:`` (issue 34): the shipped scene with its tracker moved and a second SMR."""
    (tmp_path / "moved.yaml").write_text(
        "include: fms_kr16\nname: moved\ntracker: {position: [700, -2600, 1300]}\n"
        "reflectors:\n  - {name: smr0, offset: [0, 0, 50]}\n  - {name: smr1, offset: [60, 0, 40]}\n")
    (tmp_path / "again.yaml").write_text("include: moved.yaml\nname: again\nrobot: {repeatability: 0.02}\n")
    base, scene = load_scene("fms_kr16"), load_scene(tmp_path / "again.yaml")
    assert scene.name == "again" and [r.name for r in scene.reflectors] == ["smr0", "smr1"]
    np.testing.assert_allclose(scene.tracker.position, [0.7, -2.6, 1.3])
    np.testing.assert_allclose(scene.tracker.rpy, base.tracker.rpy)  # merged key by key
    assert scene.tracker.noise == base.tracker.noise and scene.repeatability == pytest.approx(2e-5)
    assert scene.robot.name == base.robot.name


@pytest.mark.parametrize("files, fragment", [
    ({"a.yaml": "include: b.yaml\n", "b.yaml": "include: a.yaml\n"}, "include cycle a.yaml -> b.yaml -> a.yaml"),
    ({"a.yaml": "include: a.yaml\n"}, "include cycle"),
    ({"a.yaml": "include: missing.yaml\n"}, "not found"),
    ({"a.yaml": "include: fms_kr16\nunits: {length: m, angle: rad}\n"}, "differ from those of the included"),
    ({"a.yaml": "include: [fms_kr16]\n"}, "expected a scene file name"),
    ({"a.yaml": "include: b.yaml\n", "b.yaml": "- 1\n"}, "holds no scene mapping"),
])
def test_include_mistakes(tmp_path, files, fragment):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(SceneError, match=fragment):
        load_scene(tmp_path / "a.yaml")
