"""Tests of calib_oed.scene: shipped scenes, unit conversion, one test per validation failure."""

from __future__ import annotations

import copy
import math

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.exceptions import SceneError, UnknownSceneError
from calib_oed.scene import load_scene, scene_from_dict, scene_names

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


def test_shipped_scene_names():
    assert {"fms_kr16", "ur5_table"} <= set(scene_names())


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
    assert np.all(scene.robot.within_limits(scene.kpi.q))
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
