"""Joint compliance: gravity torques, the compliance columns and every derivative with compliance."""

from __future__ import annotations

import dataclasses
import json
from importlib import resources

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, relative_error
from joint_terms import (
    PAYLOAD,
    REFLECTORS,
    joint_term,
    tracker,
)

from calib_oed.calibration.identification import identify
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.simulation import draw_true_parameters, simulate_observations
from calib_oed.cli import EXIT_OK, main
from calib_oed.exceptions import ParameterError, SceneError
from calib_oed.measurement import evaluate_setup
from calib_oed.model.compliance import STIFFNESS_RANGE, Compliance, GravityLoad
from calib_oed.model.parameters import Group, ParameterSpace
from calib_oed.scene.reader import load_scene, scene_from_dict
from calib_oed.scene.records import ComplianceSpec


def test_layout_appends_one_compliance_per_joint(robot):
    rigid = ParameterSpace(robot, tracker(), REFLECTORS)
    space = ParameterSpace(robot, tracker(), REFLECTORS, compliance=PAYLOAD)
    n = robot.nq
    assert space.size == rigid.size + n and rigid.compliance_slice == slice(rigid.size, rigid.size)
    assert space.names[: rigid.size] == rigid.names
    assert space.names[rigid.size:] == tuple(f"joint{i}.c" for i in range(1, n + 1))
    comp = space.parameters[space.compliance_slice.start]
    assert comp.group == Group.COMPLIANCE and comp.report_unit == "mrad/kNm"
    assert comp.report_scale == 1e-6


def test_gravity_torque_against_pinocchio_with_the_payload(robot):
    """tau_g = -g(q) of the model with the payload appended as a body at the tool frame."""
    load = GravityLoad(robot.model, robot.tool_frame_id, PAYLOAD)
    q = robot.random_configurations(4, 3)
    model = robot.model.copy()
    frame = model.frames[robot.tool_frame_id]
    model.appendBodyToJoint(frame.parentJoint,
                            pin.Inertia(PAYLOAD.payload_mass, np.array(PAYLOAD.payload_com),
                                        np.zeros((3, 3))),
                            frame.placement)
    data = model.createData()
    expected = np.array([-pin.computeGeneralizedGravity(model, data, qk) for qk in q])
    np.testing.assert_allclose(load.torques(q), expected, rtol=1e-12, atol=1e-9)
    # the payload adds torque: its own contribution is m g along the lever arms
    bare = GravityLoad(robot.model, robot.tool_frame_id, Compliance())
    assert np.abs(load.torques(q) - bare.torques(q)).max() > 1.0
    numeric = np.stack([central_difference(lambda x: load.torques(x[None])[0], qk) for qk in q])
    assert relative_error(load.torque_derivatives(q), numeric) < 1e-7


def test_deflection_lowers_the_potential_energy(robot):
    """With c > 0 the arm sags: the effective configuration has less potential energy."""
    term = joint_term(robot, "compliance")
    load = term.space.gravity
    q = robot.random_configurations(5, 8)
    state = evaluate_setup(term.space, term.p, q, regressor=False, jacobian=False)
    data = load.model.createData()
    for qk, qe in zip(q, state.kin.q, strict=True):
        assert pin.computePotentialEnergy(load.model, data, qe) < pin.computePotentialEnergy(
            load.model, data, qk)


def test_scene_block_units_and_errors():
    data = load_scene("fms_kr300").compliance
    assert data is not None and data.enabled is False and data.model() is None
    assert data.payload.payload_mass == 300.0
    np.testing.assert_allclose(data.payload.payload_com, [0, 0, 0.2])
    from importlib import resources

    import yaml

    text = (resources.files("calib_oed.scene.shipped") / "fms_kr300.yaml").read_text()
    raw = yaml.safe_load(text)
    raw["robot"]["compliance"] = {"payload": {"mass": 10, "com": [0, 0, 100]}}
    scene = scene_from_dict(raw)
    assert scene.compliance.enabled and scene.compliance.model().payload_mass == 10.0
    space = CalibrationProblem.from_scene(scene).space
    assert space.compliance is not None and space.names[-1] == "joint6.c"
    raw["robot"]["compliance"] = {"payload": {"weight": 10}}
    with pytest.raises(SceneError, match=r"robot\.compliance\.payload\.weight.*mass, com"):
        scene_from_dict(raw)
    raw["robot"]["compliance"] = {"enabled": "yes"}
    with pytest.raises(SceneError, match="true or false"):
        scene_from_dict(raw)


def test_identification_recovers_the_compliance_within_its_confidence():
    """kr16, 10 kg payload: simulated truth (stiffness 1e6..1e7 N m/rad), 40 random poses."""
    scene = load_scene("fms_kr16")
    scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, Compliance(10.0, [0, 0, 0.1])))
    problem = CalibrationProblem.from_scene(scene)
    space = problem.space
    report = problem.identifiability
    comp_free = [i for i in report.free_indices if i >= space.compliance_slice.start]
    assert {space.names[i] for i in comp_free} >= {"joint2.c", "joint3.c"}
    assert "joint1.c" in {f.name for f in report.fixed}  # vertical axis: no gravity torque
    rng = np.random.default_rng(3)
    p_true = draw_true_parameters(space, report.free_indices, rng)
    c = p_true[comp_free]
    assert np.all((c >= 1 / STIFFNESS_RANGE[1]) & (c <= 1 / STIFFNESS_RANGE[0]))
    q = problem.robot.random_configurations(40, 1)
    blocks = simulate_observations(space, problem.models, q, p_true, rng)
    result = identify(space, blocks, report)
    for i in comp_free:
        est = result.estimate(space.names[i])
        assert abs(est.value - p_true[i]) < 4 * est.std, space.names[i]
        if space.names[i] in ("joint2.c", "joint3.c"):  # the main axes carry the load
            assert est.std < 0.2 * p_true[i]  # determined to better than 20 %


def test_cli_identifiability_with_compliance(capsys):
    assert main(["identifiability", "fms_kr300", "--compliance", "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    comp = data["compliance"]
    assert comp["payload_kg"] == 300.0 and comp["parameters"] == [f"joint{i}.c" for i in range(1, 7)]
    assert data["n_parameters"] == 51
    fixed = {f["name"] for f in data["fixed"]}
    assert {"joint1.c", "joint6.c"} <= fixed  # vertical A1; A6 carries the payload on its axis
    assert {"joint2.c", "joint3.c", "joint4.c", "joint5.c"} <= set(data["free"])
    assert main(["identifiability", "fms_kr300", "--payload-kg", "0"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "payload 0 kg" in out and "joint1.c" in out and "no gravity torque" in out


def test_sensor_yaml_carries_the_compliances(tmp_path):
    import yaml

    from calib_oed.calibration.export import export_calibration
    from calib_oed.calibration.sensor_file import read_sensor_yaml
    from calib_oed.model.robot import load_robot

    space = ParameterSpace(load_robot("kr16"), tracker(), REFLECTORS, compliance=PAYLOAD)
    p = space.zeros()
    p[space.index("joint2.c")] = 2e-7
    path = export_calibration(space, p, tmp_path)["sensor"]
    joints = yaml.safe_load(path.read_text())["compliance"]["joints"]
    assert joints[1]["compliance_si"] == 2e-7 and joints[1]["stiffness_si"] == pytest.approx(5e6)
    assert joints[0]["stiffness_si"] is None
    _, offsets = read_sensor_yaml(path)
    np.testing.assert_allclose(offsets, REFLECTORS)


def test_validation_applies_the_exported_compliances(capsys, tmp_path):
    """simulate -> identify -> validate with compliance: the sensor YAML's compliances are used.

    In the isotropic 0.01 mm copy of fms_kr16 (the studies' scene): the test is about the
    compliances being applied, at the signal-to-noise its bands were set for; under the
    shipped scene's realistic noise (floor ~0.031 mm) the 10 kg deflection is only ~2.4x it."""
    iso = str(resources.files("calib_oed.study.shipped") / "scenes" / "fms_kr16_paper.yaml")
    run = [("simulate", iso, "-n", "40", "--seed", "0", "--truth-seed", "3", "--payload-kg", "10",
            "-o", str(tmp_path / "m.csv"), "--quiet"),
           ("simulate", iso, "-n", "20", "--seed", "5", "--truth-seed", "3", "--payload-kg", "10",
            "-o", str(tmp_path / "v.csv"), "--quiet"),
           ("identify", iso, str(tmp_path / "m.csv"), "--payload-kg", "10", "-o", str(tmp_path / "c"),
            "--json"),
           ("identify", iso, str(tmp_path / "m.csv"), "-o", str(tmp_path / "r"), "--json")]
    for argv in run:
        assert main(list(argv)) == EXIT_OK
    capsys.readouterr()
    rms = {}
    for name in ("c", "r"):
        assert main(["validate", iso, str(tmp_path / name), str(tmp_path / "v.csv"), "--json"]) == EXIT_OK
        data = json.loads(capsys.readouterr().out)
        rms[name] = data["calibrated"]["rms_mm"] / data["noise_floor_mm"]
    # the compliance calibration predicts new poses to near the noise floor, the rigid one does not
    assert rms["c"] < 1.6 < 2.5 < rms["r"]


def test_sensor_compliance_section_errors(tmp_path):
    import yaml

    from calib_oed.calibration.export import export_calibration
    from calib_oed.calibration.sensor_file import read_sensor_compliance
    from calib_oed.exceptions import ExportError

    scene = dataclasses.replace(load_scene("fms_kr16"), compliance=ComplianceSpec(True, Compliance(10.0)))
    space = CalibrationProblem.from_scene(scene).space
    p = space.zeros()
    p[space.compliance_slice] = 2e-6
    path = export_calibration(space, p, tmp_path)["sensor"]
    names = space.robot.joint_names
    payload, c = read_sensor_compliance(path, names)
    assert payload.payload_mass == 10.0 and np.allclose(c, 2e-6)
    with pytest.raises(ExportError, match="the robot's joints are"):
        read_sensor_compliance(path, list(reversed(names)))
    data = yaml.safe_load(path.read_text())
    data["compliance"]["joints"][0]["compliance_si"] = "stiff"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ExportError, match=r"compliance.joints\[0\].compliance_si"):
        read_sensor_compliance(path, names)


def test_predicted_kpi_covariance_with_compliance_matches_monte_carlo():
    """600 simulated calibrations of kr16 with a 10 kg payload, compliance identified with the geometry.

    The truth draws the compliances too (stiffness log-uniform 1e6..1e7 N m/rad); the bands are those
    of tests/calibration/test_montecarlo.py (ratio s.e. ~0.033, coverage s.e. ~0.009 at N = 600).
    """
    from calib_oed.calibration.montecarlo import monte_carlo
    from calib_oed.calibration.workflow import heuristic_design, setup

    scene = dataclasses.replace(load_scene("fms_kr16"),
                                compliance=ComplianceSpec(True, Compliance(10.0, [0, 0, 0.1])))
    s = setup(scene)
    assert s.problem.space.compliance is not None
    mc = monte_carlo(s.problem, heuristic_design(s, 30, 4), n_runs=600, seed=2026, n_jobs=2)
    assert mc.converged.all()
    assert 0.85 <= mc.ratio[0] <= 1.15
    assert 0.90 <= mc.coverage[0] <= 0.99
    assert mc.rms_after[0] < 0.05 * mc.rms_before[0]


def test_load_json_round_trip_and_the_nest():
    """``Compliance.to_dict``/``from_dict`` keep the payload and the link masses (kg, mm); a
    malformed record is a ParameterError; ``with_nest`` adds a point mass at the common centre."""
    load = Compliance(16.0, np.array([0.0, 0.0, 0.1]), np.arange(1.0, 7.0), np.full((6, 3), 0.05))
    back = Compliance.from_dict(json.loads(json.dumps(load.to_dict())))
    assert back.payload_mass == 16.0 and np.allclose(back.payload_com, load.payload_com, atol=1e-15)
    assert np.array_equal(back.link_masses, load.link_masses) and np.allclose(back.link_coms, load.link_coms)
    assert Compliance.from_dict(Compliance(2.0).to_dict()).link_masses is None
    with pytest.raises(ParameterError, match="payload mass"):
        Compliance.from_dict({"mass_kg": -1.0, "com_mm": [0, 0, 0]})
    nested = Compliance(16.0, np.zeros(3)).with_nest(0.3, np.array([0.0, 0.0, 0.04]))
    assert nested.payload_mass == pytest.approx(16.3)
    assert np.allclose(nested.payload_com, [0.0, 0.0, 0.3 * 0.04 / 16.3])
