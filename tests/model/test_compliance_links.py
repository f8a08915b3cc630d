"""Compliance without the URDF's inertias: link masses from the scene, or the payload alone."""

from __future__ import annotations

import dataclasses
from importlib import resources

import numpy as np
import pinocchio as pin
import pytest
import yaml
from conftest import central_difference, relative_error

from calib_oed.calibration.export import export_calibration
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.sensor_file import read_sensor_compliance
from calib_oed.exceptions import ParameterError, SceneError, ShapeError
from calib_oed.model.compliance import Compliance, GravityLoad
from calib_oed.model.robot import load_robot
from calib_oed.scene.reader import load_scene, scene_from_dict
from calib_oed.scene.records import ComplianceSpec

MASSES = np.array([40.0, 25.0, 18.0, 6.0, 3.0, 1.0])
COMS = np.array([[0, 0, 0.2], [0.3, 0, 0.05], [0.2, 0, 0.1], [0.1, 0, 0], [0.05, 0, 0], [0, 0, 0.02]])


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


def _reference(robot, compliance):
    """Independent: a copy of the model with every inertia zeroed, bodies appended one by one."""
    model = robot.model.copy()
    for i in range(1, model.njoints):
        model.inertias[i] = pin.Inertia.Zero()
    if compliance.link_masses is not None:
        for i in range(1, model.njoints):
            model.appendBodyToJoint(i, pin.Inertia(compliance.link_masses[i - 1], compliance.link_coms[i - 1],
                                                   np.zeros((3, 3))), pin.SE3.Identity())
    frame = model.frames[robot.tool_frame_id]
    model.appendBodyToJoint(frame.parentJoint, pin.Inertia(compliance.payload_mass,
                                                           np.array(compliance.payload_com), np.zeros((3, 3))),
                            frame.placement)
    return model


@pytest.mark.parametrize("arm", ["scene", "none"])
def test_gravity_torque_with_scene_links_or_payload_alone(kr16, arm):
    masses = MASSES if arm == "scene" else np.zeros(6)
    comp = Compliance(12.0, [0.0, 0.03, 0.1], link_masses=masses, link_coms=COMS if arm == "scene" else None)
    assert comp.arm_weight == arm
    load = GravityLoad(kr16.model, kr16.tool_frame_id, comp)
    ref = _reference(kr16, comp)
    data = ref.createData()
    q = kr16.random_configurations(4, 3)
    expected = np.array([-pin.computeGeneralizedGravity(ref, data, qk) for qk in q])
    np.testing.assert_allclose(load.torques(q), expected, rtol=1e-12, atol=1e-9)
    urdf = GravityLoad(kr16.model, kr16.tool_frame_id, Compliance(12.0, [0.0, 0.03, 0.1]))
    assert np.abs(urdf.torques(q) - load.torques(q)).max() > 1.0  # not the URDF's inertias
    numeric = np.stack([central_difference(lambda x: load.torques(x[None])[0], qk) for qk in q])
    assert relative_error(load.torque_derivatives(q), numeric) < 1e-7
    if arm == "none":  # the payload alone: torque = m g x lever of the payload only
        assert "payload alone" in comp.describe()


def test_link_mass_errors(kr16):
    with pytest.raises(ParameterError, match=">= 0 kg"):
        Compliance(link_masses=[1.0, -2.0])
    with pytest.raises(ShapeError):
        Compliance(link_masses=[1.0, 2.0], link_coms=np.zeros((3, 3)))
    with pytest.raises(ParameterError, match="need link masses"):
        Compliance(link_coms=np.zeros((6, 3)))
    with pytest.raises(ParameterError, match="expected 6"):
        GravityLoad(kr16.model, kr16.tool_frame_id, Compliance(link_masses=np.ones(5)))


def test_scene_links_key():
    raw = yaml.safe_load((resources.files("calib_oed.scene.shipped") / "fms_kr16.yaml").read_text())
    raw["robot"]["compliance"] = {"payload": {"mass": 10}, "links": "none"}
    assert scene_from_dict(raw).compliance.payload.arm_weight == "none"
    raw["robot"]["compliance"]["links"] = [{"mass": float(m), "com": (1e3 * c).tolist()}  # file in mm
                                           for m, c in zip(MASSES, COMS, strict=True)]
    comp = scene_from_dict(raw).compliance.payload
    np.testing.assert_array_equal(comp.link_masses, MASSES)
    np.testing.assert_allclose(comp.link_coms, COMS, atol=1e-15)
    for links, match in [("cad", r"robot\.compliance\.links.*'urdf'.*'none'"),
                         ([{"mass": 1}], r"robot\.compliance\.links.*expected 6"),
                         ([{"weight": 1}] * 6, r"robot\.compliance\.links\[0\]")]:
        raw["robot"]["compliance"]["links"] = links
        with pytest.raises(SceneError, match=match):
            scene_from_dict(raw)


def test_payload_alone_makes_the_main_axes_compliance_identifiable_and_exports(tmp_path):
    comp = Compliance(50.0, [0, 0, 0.1], link_masses=np.zeros(6))
    scene = dataclasses.replace(load_scene("fms_kr16"), compliance=ComplianceSpec(True, comp))
    problem = CalibrationProblem.from_scene(scene)
    free = set(problem.identifiability.free_names)
    assert {"joint2.c", "joint3.c"} <= free and "joint1.c" not in free
    space = problem.space
    p = space.zeros()
    p[space.compliance_slice] = 1e-6
    back, c = read_sensor_compliance(export_calibration(space, p, tmp_path)["sensor"], space.robot.joint_names)
    np.testing.assert_array_equal(back.link_masses, np.zeros(6))
    np.testing.assert_array_equal(c, p[space.compliance_slice])
