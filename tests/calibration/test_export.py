"""Calibrated URDF and sensor YAML export: round trips through files, errors, no partial files."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import ROBOTS, make_space, random_parameters

from calib_oed import load_robot
from calib_oed.calibration import export_files
from calib_oed.calibration.export import calibrated_urdf_text, export_calibration
from calib_oed.calibration.sensor_file import SENSOR_FORMAT, read_sensor_yaml
from calib_oed.exceptions import ExportError, ShapeError

TOL = 1e-9  # [m], [rad]


def reload(robot, path):
    """The exported URDF as a calib_oed robot, with the original's tool frame and locks."""
    return load_robot(path, tool_frame=robot.tool_frame, lock_joints=robot.locked_joints,
                      package_dirs=robot.package_dirs)


def tool_placements(model, frame_id, qs):
    data = model.createData()
    out = []
    for q in qs:
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        out.append(pin.SE3(data.oMf[frame_id]))
    return out


def fk_errors(robot, model_a, model_b, seed=3, n=20):
    """Largest translation [m], rotation [rad] and 0.1 m tool-z point [m] differences."""
    qs = robot.random_configurations(n, seed)
    fid_a = model_a.getFrameId(robot.tool_frame)
    fid_b = model_b.getFrameId(robot.tool_frame)
    dt = dr = dx = 0.0
    point = np.array([0.0, 0.0, 0.1])
    for a, b in zip(tool_placements(model_a, fid_a, qs), tool_placements(model_b, fid_b, qs),
                    strict=True):
        dt = max(dt, np.linalg.norm(a.translation - b.translation))
        dr = max(dr, np.linalg.norm(pin.log3(a.rotation.T @ b.rotation)))
        dx = max(dx, np.linalg.norm(a.act(point) - b.act(point)))
    return dt, dr, dx


@pytest.fixture(scope="module", params=ROBOTS)
def setup(request):
    robot = load_robot(request.param)
    return robot, make_space(robot)


def test_round_trip_matches_perturbed_model(setup, tmp_path):
    robot, space = setup
    p = random_parameters(space, np.random.default_rng(11), sigma_length=1e-3, sigma_angle=1e-3)
    path = export_calibration(space, p, tmp_path, stem="cal")["urdf"]
    loaded = reload(robot, path)
    assert loaded.joint_names == robot.joint_names
    assert loaded.tool_frame_id == robot.tool_frame_id
    dt, dr, dx = fk_errors(robot, loaded.model, space.perturbed_model(p))
    assert dt < TOL and dr < TOL and dx < TOL
    # the perturbation is visible: the nominal model is far off
    assert fk_errors(robot, loaded.model, robot.model)[0] > 1e-4
    # every joint placement, not only the tool: exact up to rounding
    for a, b in zip(loaded.model.jointPlacements, space.perturbed_model(p).jointPlacements,
                    strict=True):
        assert np.abs(a.homogeneous - b.homogeneous).max() < 1e-14


def test_zero_perturbation_reproduces_nominal(setup, tmp_path):
    robot, space = setup
    path = export_calibration(space, space.zeros(), tmp_path, stem="nominal")["urdf"]
    loaded = reload(robot, path)
    for a, b in zip(loaded.model.jointPlacements, robot.model.jointPlacements, strict=True):
        assert a == b  # the source text is kept, so the parse is identical
    assert max(fk_errors(robot, loaded.model, robot.model)) < 1e-15


def test_only_perturbed_joint_origins_change(setup, tmp_path):
    """Locked joints, fixed joints, mimic, transmissions, limits: all as in the source."""
    robot, space = setup
    p = random_parameters(space, 5, sigma_length=1e-3, sigma_angle=1e-3)
    p[space.joint_slice(2)] = 0.0  # an untouched movable joint keeps its text
    text = calibrated_urdf_text(space, p)
    full_a = pin.buildModelFromXML(robot.urdf_text)
    full_b = pin.buildModelFromXML(text)
    assert list(full_a.names) == list(full_b.names)
    changed = set(robot.joint_names) - {robot.joint_names[1]}
    for name, a, b in zip(full_a.names, full_a.jointPlacements, full_b.jointPlacements,
                          strict=True):
        if name not in changed:
            assert a == b, name
    fixed = [(fa.name, fa.placement, fb.placement) for fa, fb in
             zip(full_a.frames, full_b.frames, strict=True) if fa.type == pin.FrameType.FIXED_JOINT]
    for name, a, b in fixed:  # fixed-joint frames relative to their parent joint
        assert a == b, name
    np.testing.assert_array_equal(full_a.lowerPositionLimit, full_b.lowerPositionLimit)
    src, out = ET.fromstring(robot.urdf_text), ET.fromstring(text.split("\n", 1)[1])
    for tag in ("mimic", "safety_controller", "transmission", "gazebo", "axis", "mesh"):
        assert len(list(src.iter(tag))) == len(list(out.iter(tag))), tag
    joints_a = {j.get("name"): j for j in src.findall("joint")}
    for j in out.findall("joint"):
        if j.get("name") not in changed:
            o_a, o_b = joints_a[j.get("name")].find("origin"), j.find("origin")
            assert (o_a is None and o_b is None) or o_a.attrib == o_b.attrib


def test_output_is_valid_urdf_with_provenance(tmp_path):
    robot = load_robot("panda")
    space = make_space(robot)
    p = random_parameters(space, 2)
    path = export_calibration(space, p, tmp_path, stem="panda")["urdf"]
    model = pin.buildModelFromUrdf(str(path))  # parses as a URDF file, fingers included
    assert model.nq == robot.nq + len(robot.locked_joints)
    text = path.read_text()
    assert text.startswith('<?xml version="1.0" encoding="utf-8"?>\n<!--\n  Calibrated by calib_oed')
    head = text.split("-->", 1)[0]
    assert f"{space.size} parameters" in head
    assert f"the {6 * robot.nq} joint parameters" in head
    assert ET.fromstring(text.split("\n", 1)[1]).get("name") == ET.fromstring(robot.urdf_text).get("name")
    # date-free: the same calibration gives the same bytes
    again = export_calibration(space, p, tmp_path, stem="again")["urdf"]
    assert again.read_bytes() == path.read_bytes()


TILTED_ARM = """<?xml version="1.0"?>
<robot name="tilted">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="tool"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.4" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/>
  </joint>
  <joint name="j2" type="revolute">
    <parent link="l1"/><child link="l2"/>
    <origin xyz="0.1 0 0.3" rpy="0.3 1.5707963267948966 -0.4"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <joint name="j_tool" type="fixed">
    <parent link="l2"/><child link="tool"/><origin xyz="0.5 0 0" rpy="0 0 0"/>
  </joint>
</robot>
"""


def test_origin_precision_near_gimbal_lock(tmp_path):
    """An origin at pitch pi/2 with roll and yaw, tilted off it by 1e-5..1e-12 rad, stays exact.

    Roll and yaw are ill-determined there (only their sum is); the written rpy
    must still give back the rotation to rounding error.
    """
    source = tmp_path / "tilted.urdf"
    source.write_text(TILTED_ARM)
    robot = load_robot(source, tool_frame="tool")
    space = make_space(robot)
    rng = np.random.default_rng(0)
    for scale in (1e-5, 1e-9, 1e-12):
        p = space.zeros()
        p[space.joint_slice(2)] = rng.normal(size=6) * scale
        path = export_calibration(space, p, tmp_path, stem=f"out_{scale}")["urdf"]
        loaded = reload(robot, path)
        a, b = loaded.model.jointPlacements[2], space.perturbed_model(p).jointPlacements[2]
        assert np.linalg.norm(pin.log6(a.inverse() * b).vector) < 1e-14


def test_generated_robot_without_file(tmp_path):
    robot = load_robot("notional_l650_m600")
    space = make_space(robot, reflectors=((0.0, 0.0, 0.05),))
    p = random_parameters(space, 4, sigma_length=1e-3, sigma_angle=1e-3)
    loaded = reload(robot, export_calibration(space, p, tmp_path, stem="n")["urdf"])
    dt, dr, dx = fk_errors(robot, loaded.model, space.perturbed_model(p))
    assert max(dt, dr, dx) < TOL


def test_sensor_yaml_round_trip(tmp_path):
    robot = load_robot("kr16")
    space = make_space(robot)
    p = random_parameters(space, np.random.default_rng(7), sigma_length=1e-3, sigma_angle=1e-3)
    path = export_calibration(space, p, tmp_path)["sensor"]
    tracker, offsets = read_sensor_yaml(path)
    expected = space.tracker_placement(p)
    assert np.abs(tracker.homogeneous - expected.homogeneous).max() < 1e-12
    assert offsets.shape == (space.n_reflectors, 3)
    assert np.abs(offsets - space.reflector_offsets(p)).max() < 1e-12
    text = path.read_text()
    assert text.startswith("# Sensor set-up identified by calib_oed")
    assert "no place for the laser tracker" in text and f"format: {SENSOR_FORMAT}" in text
    data = yaml.safe_load(text)
    np.testing.assert_allclose(data["tracker"]["position_mm"], 1e3 * expected.translation,
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.radians(data["tracker"]["rpy_deg"]),
                               pin.rpy.matrixToRpy(expected.rotation), rtol=0, atol=1e-12)
    np.testing.assert_allclose(data["reflectors"][1]["offset_mm"],
                               1e3 * space.reflector_offsets(p)[1], rtol=0, atol=1e-9)


def test_sensor_yaml_rejects_inconsistent_or_bad_files(tmp_path):
    space = make_space(load_robot("kr16"))
    path = export_calibration(space, space.zeros(), tmp_path)["sensor"]
    data = yaml.safe_load(path.read_text())
    data["tracker"]["position_mm"][0] += 1.0  # a hand edit of one copy only
    edited = tmp_path / "edited.yaml"
    edited.write_text(yaml.safe_dump(data))
    with pytest.raises(ExportError, match="position_mm disagrees"):
        read_sensor_yaml(edited)
    with pytest.raises(ExportError, match="cannot read sensor file"):
        read_sensor_yaml(tmp_path / "missing.yaml")
    other = tmp_path / "other.yaml"
    other.write_text("a: 1\n")
    with pytest.raises(ExportError, match="not a calib_oed sensor file"):
        read_sensor_yaml(other)


def test_export_calibration_writes_both(tmp_path):
    robot = load_robot("ur5")
    space = make_space(robot)
    p = random_parameters(space, 9)
    paths = export_calibration(space, p, tmp_path)
    assert paths == {"urdf": tmp_path / "ur5_calibrated.urdf",
                     "sensor": tmp_path / "ur5_sensor.yaml"}
    named = export_calibration(space, p, tmp_path, stem="cell3")
    assert named["urdf"].name == "cell3_calibrated.urdf"
    assert named["sensor"].name == "cell3_sensor.yaml"
    assert named["urdf"].read_bytes() == paths["urdf"].read_bytes()
    tracker, _ = read_sensor_yaml(named["sensor"])
    assert np.abs(tracker.homogeneous - space.tracker_placement(p).homogeneous).max() < 1e-12


def test_bad_folder_and_bad_p_write_nothing(tmp_path):
    space = make_space(load_robot("kr16"))
    missing = tmp_path / "no_such_folder"
    with pytest.raises(ExportError, match="no_such_folder"):
        export_calibration(space, space.zeros(), missing)
    with pytest.raises(ShapeError):
        export_calibration(space, np.zeros(space.size - 1), tmp_path)
    with pytest.raises(ExportError, match="plain file name"):
        export_calibration(space, space.zeros(), tmp_path, stem="a/b")
    assert not missing.exists()
    assert os.listdir(tmp_path) == []
    (tmp_path / "kr16_calibrated.urdf").mkdir()
    with pytest.raises(ExportError, match="it is a folder"):
        export_calibration(space, space.zeros(), tmp_path)
    assert os.listdir(tmp_path) == ["kr16_calibrated.urdf"]


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    space = make_space(load_robot("kr16"))
    p = random_parameters(space, 1)

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", fail)  # the rename at the end of the atomic write
    with pytest.raises(ExportError, match="disk full"):
        export_calibration(space, p, tmp_path)
    assert os.listdir(tmp_path) == []
    monkeypatch.undo()

    real = export_files.io_utils.atomic_write_text

    def fail_on_yaml(path, text):
        if str(path).endswith(".yaml"):
            raise OSError("disk full")
        return real(path, text)

    monkeypatch.setattr(export_files.io_utils, "atomic_write_text", fail_on_yaml)
    with pytest.raises(ExportError, match="disk full"):
        export_calibration(space, p, tmp_path)
    assert os.listdir(tmp_path) == []  # the URDF written first was removed again


def test_a_one_line_urdf_is_written_indented():
    from lxml import etree

    from calib_oed.calibration.export import _document

    root = etree.fromstring('<robot name="r"><link name="a"/><joint name="j" type="revolute">'
                            '<parent link="a"/><child link="b"/></joint><link name="b"/></robot>')
    text = _document(root)
    assert text.count("\n") >= 5 and '\n  <joint name="j" type="revolute">\n    <parent' in text
    assert etree.tostring(etree.fromstring(text), method="c14n") != b""  # still well-formed


def test_a_calibration_of_another_robot_is_refused_by_its_sensor_file(tmp_path):
    from calib_oed.calibration.validation import find_calibration_files

    space = make_space(load_robot("ur5"))
    paths = export_calibration(space, random_parameters(space, 9), tmp_path)
    assert find_calibration_files(tmp_path, "ur5") == paths
    assert find_calibration_files(paths["urdf"], "ur5") == paths
    # validate, compensate and table name the mismatch instead of failing on the other URDF's joints
    with pytest.raises(ExportError, match="a calibration of robot 'ur5', not of this scene's robot 'panda'"):
        find_calibration_files(tmp_path, "panda")
