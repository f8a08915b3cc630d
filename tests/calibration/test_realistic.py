"""The realistic simulator: every component has its documented effect; seeds reproduce; the
default level leaves an unmodelled error several times the noise after the geometric fit."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.calibration import realistic_defaults
from calib_oed.calibration.identification import identify
from calib_oed.calibration.realistic import sample_truth
from calib_oed.calibration.realistic_defaults import ARCSEC, RealisticSettings
from calib_oed.calibration.realistic_measure import measure, write_realistic_truth
from calib_oed.calibration.workflow import realistic_measurements, setup
from calib_oed.exceptions import ParameterError
from calib_oed.measurement.base import evaluate_setup

COMPONENTS = ("compliance", "transmission", "balancer", "tracker", "gains")


def only(component: str | None, **extra) -> RealisticSettings:
    """Settings with one unmodelled component on (None: none) and no geometric errors."""
    return RealisticSettings(**{"geometric": False, **{c: c == component for c in COMPONENTS}, **extra})


@pytest.fixture(scope="module")
def ur5():
    return setup("ur5_table")


def test_compliance_deflection_is_c_times_gravity_torque_with_payload(kr16):
    truth = sample_truth(kr16, 3, only("compliance", payload_mass=12.0, payload_com=(0.0, 0.0, 0.1)))
    robot = kr16.problem.robot
    q = robot.random_configurations(5, 1)
    # independent: the URDF model with payload and nest added to the tool's parent joint
    model = robot.model.copy()
    frame = model.frames[robot.tool_frame_id]
    nest = kr16.problem.space.reflector_offsets(kr16.problem.space.zeros()).mean(axis=0)
    for mass, com in ((12.0, np.array([0.0, 0.0, 0.1])), (truth.settings.nest_mass, nest)):
        model.inertias[frame.parentJoint] += frame.placement.act(pin.Inertia(mass, com, np.zeros((3, 3))))
    data = model.createData()
    tau = np.array([-pin.computeGeneralizedGravity(model, data, qk) for qk in q])
    assert np.allclose(truth.compute_joint_errors(q), tau / truth.stiffness, rtol=1e-10, atol=1e-15)
    assert truth.payload_mass == pytest.approx(12.0 + truth.settings.nest_mass)
    # the medium class's J2 stiffness about 1e6 N·m/rad, log-normal spread 0.3
    assert 1e6 * np.exp(-1.5) < truth.stiffness[1] < 1e6 * np.exp(1.5)


def test_transmission_error_amplitudes_and_periods(kr16):
    joint = sample_truth(kr16, 4, only("transmission", motor_cyclic=(0.0, 0.0)))
    motor = sample_truth(kr16, 4, only("transmission", joint_cyclic=(0.0, 0.0)))
    nq = kr16.problem.robot.nq
    angles = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    for i in range(nq):
        q = np.zeros((angles.size, nq))
        q[:, i] = angles
        e = joint.compute_joint_errors(q)
        assert np.allclose(np.delete(e - e[0], i, axis=1), 0.0)  # each joint's error its own angle's
        spectrum = np.abs(np.fft.rfft(e[:, i])) * 2 / angles.size  # amplitude per harmonic
        assert np.allclose(spectrum[1:3], joint.transmission.joint_amplitude[i], rtol=1e-9)
        assert np.allclose(np.delete(spectrum, [1, 2]), 0.0, atol=1e-12)
        typical = np.array(joint.settings.joint_cyclic)
        assert np.all((spectrum[1:3] >= 0.5 * typical) & (spectrum[1:3] <= 1.5 * typical))
        # the motor's errors repeat every motor revolution, 2 pi / N of the joint
        n_i = motor.transmission.gear_ratios[i]
        e0 = motor.compute_joint_errors(q)[:, i]
        q[:, i] += 2 * np.pi / n_i
        assert np.allclose(motor.compute_joint_errors(q)[:, i], e0, atol=1e-15)
        assert np.max(np.abs(e0)) <= np.sum(motor.transmission.motor_amplitude[i]) + 1e-15
        assert np.max(np.abs(e0)) > 0.5 * 5 * ARCSEC


def test_balancer_opposes_gravity_on_j2_only(kr16):
    with_b = sample_truth(kr16, 5, only("compliance"))
    also_b = sample_truth(kr16, 5, dataclasses.replace(only("compliance"), balancer=True))
    b = also_b.balancer
    assert with_b.balancer is None and b is not None and b.joint == 1
    q = np.zeros((91, 6))
    q[:, 1] = np.linspace(-np.pi, np.pi, 91)
    tau_b = b.compute_torques(q)
    assert np.allclose(np.delete(tau_b, 1, axis=1), 0.0)
    tau_g = also_b.compute_gravity_torques(q)[:, 1]
    strong = np.abs(tau_g) > 0.5 * np.abs(tau_g).max()
    assert np.all(np.sign(tau_b[strong, 1]) == -np.sign(tau_g[strong]))  # it carries part of the weight
    assert np.abs(tau_b[:, 1]).max() == pytest.approx(b.torque, rel=1e-3)
    arm = np.abs(tau_g).max()
    assert 0.3 * arm < b.torque < 0.8 * arm  # the medium class's fraction 0.5 (x 0.8..1.2) of it
    extra = also_b.compute_joint_errors(q) - with_b.compute_joint_errors(q)
    assert np.allclose(extra, also_b.compliance * tau_b, atol=1e-15)
    # a collaborative arm has none
    assert sample_truth(setup("ur5_table"), 5).balancer is None


def test_tracker_scale_changes_distances_by_the_ppm_and_encoders_by_their_eccentricity(kr16):
    truth = sample_truth(kr16, 6, only("tracker", tracker_scale_ppm=50.0, encoder_eccentricity=0.0))
    rng = np.random.default_rng(0)
    y = rng.normal(size=(20, 3)) * 2.0
    r = truth.tracker.compute_readings(y)
    s = truth.tracker.scale
    assert abs(s) > 0
    assert np.allclose(np.linalg.norm(r[1:] - r[:-1], axis=1), (1 + s) * np.linalg.norm(y[1:] - y[:-1], axis=1),
                       rtol=1e-12)
    enc = sample_truth(kr16, 6, only("tracker", tracker_scale_ppm=0.0)).tracker
    az = np.linspace(-np.pi, np.pi, 181)
    pts = np.stack([3 * np.cos(az), 3 * np.sin(az), np.zeros_like(az)], axis=1)
    read = enc.compute_readings(pts)
    d_az = np.angle(np.exp(1j * (np.arctan2(read[:, 1], read[:, 0]) - az)))
    assert np.max(np.abs(d_az)) == pytest.approx(enc.azimuth_eccentricity, rel=1e-3)
    assert 0.5 * 1.5 * ARCSEC <= enc.azimuth_eccentricity <= 1.5 * 1.5 * ARCSEC
    assert np.allclose(np.linalg.norm(read, axis=1), 3.0)


def test_joint_gain_errors_scale_each_joint_angle(kr16):
    truth = sample_truth(kr16, 10, only("gains", sigma_gain=1e-3))
    q = kr16.problem.robot.random_configurations(4, 3)
    assert np.allclose(truth.compute_joint_errors(q), truth.gain_errors * q, rtol=1e-12, atol=0)
    assert np.all(np.abs(truth.gain_errors) < 5e-3) and np.any(np.abs(truth.gain_errors) > 1e-4)


def test_level_zero_is_the_geometric_truth_and_level_scales_the_rest(kr16):
    q = kr16.problem.robot.random_configurations(8, 2)
    flat = sample_truth(kr16, 7, RealisticSettings(level=0.0))
    state = evaluate_setup(kr16.problem.space, flat.p, q, regressor=False, jacobian=False)
    assert np.allclose(flat.compute_reflector_points(q)[:, 0], state.tool_point(state.reflectors[0], "world"),
                       atol=1e-13)
    one, two = (sample_truth(kr16, 7, only("transmission", level=lv)) for lv in (1.0, 2.0))
    assert np.allclose(two.compute_joint_errors(q), 2 * one.compute_joint_errors(q), rtol=1e-12)


def test_switching_a_component_off_keeps_the_others(kr16):
    full = sample_truth(kr16, 8)
    part = sample_truth(kr16, 8, RealisticSettings(transmission=False))
    assert np.array_equal(full.p, part.p) and np.array_equal(full.stiffness, part.stiffness)
    assert full.tracker == part.tracker and full.balancer == part.balancer
    assert np.all(part.transmission.joint_amplitude == 0) and np.all(full.transmission.joint_amplitude > 0)


def test_thermal_drift_scales_about_the_base_with_time(kr16):
    truth = sample_truth(kr16, 9, only(None, thermal=True))
    q = kr16.problem.robot.random_configurations(3, 4)
    x0, x1 = truth.compute_tcp(q, time=0.0), truth.compute_tcp(q, time=1.0)
    a = truth.settings.thermal_alpha * truth.settings.thermal_delta_t
    assert 0.5 * a <= truth.thermal_expansion <= 1.5 * a
    assert np.allclose(x1, (1 + truth.thermal_expansion) * x0, rtol=1e-12)
    with pytest.raises(ParameterError, match=r"\[0, 1\]"):
        truth.compute_tcp(q, time=2.0)


def test_gross_errors_on_the_chosen_rows_only(kr16):
    q = kr16.problem.robot.random_configurations(20, 5)
    clean = measure(sample_truth(kr16, 1), kr16.problem.models, q, 3)
    truth = sample_truth(kr16, 1, RealisticSettings(gross_errors=3))
    dirty = measure(truth, kr16.problem.models, q, 3)
    assert len(dirty.gross) == 3
    d = np.linalg.norm(dirty.blocks[0].values - clean.blocks[0].values, axis=1)
    rows = [i for _, i in dirty.gross]
    assert np.allclose(d[rows], 5e-3, rtol=0.05) and np.allclose(np.delete(d, rows), 0.0)


def test_seed_reproduces_the_bytes(kr16, tmp_path):
    q = kr16.problem.robot.random_configurations(10, 6)
    files = []
    for k in range(2):
        mset, truth, meas = realistic_measurements(kr16, q, 11)
        files.append(write_realistic_truth(tmp_path / f"t{k}.yaml", truth, "fms_kr16", 11, meas).read_bytes())
        files.append(np.asarray(mset.positions).tobytes())
    assert files[0] == files[2] and files[1] == files[3]
    other = realistic_measurements(kr16, q, 12)[0]
    assert np.asarray(other.positions).tobytes() != files[1]


def test_bad_settings_name_the_key():
    with pytest.raises(ParameterError, match="realistic.level"):
        RealisticSettings(level=-1.0)
    with pytest.raises(ParameterError, match="realistic.stiffness"):
        RealisticSettings(stiffness=(1e6, 0.0))


@pytest.mark.parametrize("name", ["kr16", "ur5"])
def test_default_level_leaves_several_times_the_noise_after_the_geometric_fit(name, request):
    """The property the statistics rely on: at level 1, identify() with the geometric model
    leaves a held-out error of several times the noise (3 truths)."""
    s = request.getfixturevalue(name)
    space, robot = s.problem.space, s.problem.robot
    ratios, sigma0 = [], []
    for seed in range(3):
        truth = sample_truth(s, seed)
        q, q_new = robot.random_configurations(60, 10 + seed), robot.random_configurations(30, 50 + seed)
        meas = measure(truth, s.problem.models, q, 100 + seed)
        result = identify(space, list(meas.blocks), s.problem.identifiability)
        error = truth.compute_model_errors(result.p, q_new)[:, 0]
        state = evaluate_setup(space, result.p, q_new, regressor=False, jacobian=False)
        assert np.allclose(error, state.tool_point(state.reflectors[0], "world")
                           - truth.compute_reflector_points(q_new)[:, 0], atol=1e-14)
        tcp = truth.compute_model_errors(result.p, q_new, point=np.zeros(3))
        assert np.allclose(tcp, state.kin.translation - truth.compute_tcp(q_new), atol=1e-14)
        noise = s.problem.models[0].noise.sample(meas.exact[0], np.random.default_rng(seed))
        ratios.append(np.sqrt(np.mean(np.sum(error**2, 1)) / np.mean(np.sum(noise**2, 1))))
        sigma0.append(float(result.sigma0))
    band = re.search(r"geometric fit (\d+)-(\d+) times the measurement noise",
                     " ".join(realistic_defaults.__doc__.split()))
    low, high = float(band.group(1)), float(band.group(2))   # what the module's docstring states
    assert np.all((np.array(ratios) >= low) & (np.array(ratios) <= high)), ratios
    assert np.all((np.array(sigma0) > 2.5) & (np.array(sigma0) < 12)), sigma0


def test_cli_simulate_realistic_writes_every_component(tmp_path, capsys):
    import yaml

    from calib_oed.cli import EXIT_BAD_INPUT, EXIT_OK, main

    out = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", "-n", "8", "--realistic", "--without", "balancer",
                 "--gross-errors", "1", "-o", str(out), "--json"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["realistic"] is True
    rec = yaml.safe_load((tmp_path / "m_truth.yaml").read_text())
    for key in ("parameters", "compliance", "transmission", "balancer", "tracker", "gain_errors", "settings",
                "gross_errors"):
        assert key in rec
    assert rec["balancer"] is None and rec["settings"]["balancer"] is False and len(rec["gross_errors"]) == 1
    assert main(["simulate", "fms_kr16", "-n", "8", "--level", "2", "-o", str(out)]) == EXIT_BAD_INPUT
    assert "need --realistic" in capsys.readouterr().err


def test_scene_block_in_file_units(tmp_path):
    from importlib import resources

    from calib_oed.calibration.realistic_defaults import realistic_settings_from_scene
    from calib_oed.exceptions import SceneError
    from calib_oed.scene.reader import load_scene

    text = resources.files("calib_oed.scene.shipped").joinpath("fms_kr16.yaml").read_text()
    block = ("\nrealistic:\n  level: 2\n  thermal: true\n  payload: {mass: 10, com: [0, 0, 100]}\n"
             "  joint_cyclic_arcsec: [20, 10]\n  gross_size: 3\n  sigma_angle: 0.01\n"
             "  stiffness: [1.0e+6, 2.0e+6, 1.0e+6, 2.0e+5, 2.0e+5, 1.0e+5]\n")
    path = tmp_path / "scene.yaml"
    path.write_text(text + block)
    got = realistic_settings_from_scene(load_scene(path))
    want = RealisticSettings(level=2.0, thermal=True, payload_mass=10.0, payload_com=(0.0, 0.0, 0.1),
                             joint_cyclic=(20 * ARCSEC, 10 * ARCSEC), gross_size=3e-3,
                             sigma_angle=np.deg2rad(0.01), stiffness=(1e6, 2e6, 1e6, 2e5, 2e5, 1e5))
    for key, value in want.describe().items():
        assert value is None and got.describe()[key] is None or np.allclose(got.describe()[key], value), key
    assert sample_truth(setup(load_scene(path)), 0).settings.level == 2.0  # the scene's block by default
    path.write_text(text + block.replace("gross_size", "gross_sise"))
    with pytest.raises(SceneError, match="realistic.gross_sise: unknown key"):
        realistic_settings_from_scene(load_scene(path))
    assert realistic_settings_from_scene(load_scene("fms_kr16")) == RealisticSettings()


def test_truth_file_round_trip_and_identify_reports_the_true_tcp_error(kr16, tmp_path, capsys):
    from calib_oed.calibration.workflow import read_truth, tcp_errors
    from calib_oed.cli import EXIT_OK, main

    out = tmp_path / "m.csv"
    assert main(["simulate", "fms_kr16", "-n", "30", "--realistic", "--thermal", "--truth-seed", "4",
                 "-o", str(out), "--quiet"]) == EXIT_OK
    truth = read_truth(tmp_path / "m_truth.yaml", kr16)
    again = sample_truth(kr16, np.random.default_rng(4), RealisticSettings(thermal=True))
    q = kr16.problem.robot.random_configurations(6, 9)
    assert np.array_equal(truth.compute_reflector_points(q, 0.5), again.compute_reflector_points(q, 0.5))
    before = np.linalg.norm(tcp_errors(kr16, truth, None), axis=1)
    rigid = np.linalg.norm(tcp_errors(kr16, truth.p, None), axis=1)
    assert not np.allclose(before, rigid)  # the unmodelled part is in the true TCP
    capsys.readouterr()
    assert main(["identify", "fms_kr16", str(out), "--loss", "linear", "--truth",
                 str(tmp_path / "m_truth.yaml"), "--json"]) == EXIT_OK
    data = json.loads(capsys.readouterr().out)
    assert data["tcp_error_mm"]["before"][0] == pytest.approx(before[0] * 1e3, rel=1e-9)


def test_gain_errors_are_what_the_models_gain_parameters_capture():
    """With gains identified (and the rest of the truth geometric), the fitted gain of each joint is
    the truth's modelled gain plus its gain error (the same convention), within 4 predicted std."""
    from importlib import resources

    import yaml

    from calib_oed.scene.reader import scene_from_dict

    raw = yaml.safe_load((resources.files("calib_oed.scene.shipped") / "fms_kr16.yaml").read_text())
    raw["robot"]["joint_gains"] = True
    s = setup(scene_from_dict(raw))
    space = s.problem.space
    truth = sample_truth(s, 2, only("gains", sigma_gain=1e-3, geometric=True))
    q = s.problem.robot.random_configurations(60, 8)
    fit = identify(space, list(measure(truth, s.problem.models, q, 5).blocks), s.problem.identifiability)
    free = [k for k in fit.free_indices if space.names[k].endswith(".gain")]
    joints = [int(space.names[k][5]) - 1 for k in free]
    assert len(free) == 5  # joint6.gain: no effect with the reflector on the A6 axis
    expected = truth.p[free] + truth.gain_errors[joints]
    std = np.array([fit.estimate(space.names[k]).std for k in free])
    assert np.all(np.abs(fit.p[free] - expected) < 4 * std)  # within the noise's share
    assert np.all(4 * std < 0.2 * np.abs(truth.gain_errors[joints]))  # which is far below the errors


def test_a_pose_scene_is_refused_with_the_reason():
    from importlib import resources

    import yaml

    from calib_oed.scene.reader import scene_from_dict

    raw = yaml.safe_load((resources.files("calib_oed.scene.shipped") / "fms_kr16.yaml").read_text())
    raw["measurement"] = "pose"
    del raw["tracker"]["noise"], raw["robot"]["repeatability"]
    s = setup(scene_from_dict(raw))
    with pytest.raises(ParameterError, match="measurement: position"):
        measure(sample_truth(s, 0), s.problem.models, s.problem.robot.random_configurations(3, 0), 0)


def test_compliance_is_what_the_models_compliance_parameters_capture():
    """fms_kr300 with compliance modelled, its 300 kg payload, no nest: the fitted compliances
    are the truth's, within 4 predicted std."""
    from calib_oed.model.compliance import Compliance
    from calib_oed.scene.reader import load_scene
    from calib_oed.scene.records import ComplianceSpec

    scene = load_scene("fms_kr300")
    scene = dataclasses.replace(scene, compliance=ComplianceSpec(True, scene.compliance.payload))
    assert isinstance(scene.compliance.payload, Compliance)
    s = setup(scene)
    space = s.problem.space
    truth = sample_truth(s, 3, only("compliance", geometric=True, nest_mass=0.0))
    q = s.problem.robot.random_configurations(60, 9)
    fit = identify(space, list(measure(truth, s.problem.models, q, 6).blocks), s.problem.identifiability)
    free = [k for k in fit.free_indices if space.names[k].endswith(".c")]
    joints = [int(space.names[k][5]) - 1 for k in free]
    assert {1, 2} <= set(joints)  # A2 and A3 carry the weight
    std = np.array([fit.estimate(space.names[k]).std for k in free])
    assert np.all(np.abs(fit.p[free] - truth.compliance[joints]) < 4 * std)
    a2 = joints.index(1)
    assert 4 * std[a2] < 0.1 * truth.compliance[1]  # a real test: A2's compliance well determined
    assert fit.sigma0 < 1.3


def test_null_gain_errors_are_none_and_malformed_ones_are_named(kr16):
    """``gain_errors: null`` (written for a truth without them) reads as no gain error, not NaN;
    a list of the wrong length or with NaN is refused naming the key."""
    from calib_oed.calibration.realistic_measure import read_realistic_truth, truth_record

    truth = sample_truth(kr16, 5, only("transmission"))
    rec = truth_record(truth, "fms_kr16", 5)
    q = kr16.problem.robot.random_configurations(4, 1)
    back = read_realistic_truth({**rec, "gain_errors": None}, kr16)
    assert back.gain_errors is None
    assert np.array_equal(back.compute_joint_errors(q), truth.compute_joint_errors(q))
    for bad in ([0.0] * 5, [float("nan")] * 6):
        with pytest.raises(ParameterError, match="gain_errors"):
            read_realistic_truth({**rec, "gain_errors": bad}, kr16)
