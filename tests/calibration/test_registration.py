"""Rigid registration of the tracker pose and the sanity check before fitting."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.calibration.registration import pose_difference, register_tracker, rigid_registration
from calib_oed.calibration.sanity import check_measurements
from calib_oed.calibration.workflow import setup, simulated_measurements
from calib_oed.exceptions import DataSanityError, ParameterError
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def data():
    s = setup(load_scene("fms_kr16"))
    q = s.problem.robot.random_configurations(40, 3)
    mset, p_true = simulated_measurements(s, q, 4)
    return s, mset, p_true


def test_rigid_registration_recovers_a_known_motion():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(30, 3))
    m = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))
    b = (a - m.translation) @ m.rotation  # b = M^-1 a, so a = R b + t
    reg = rigid_registration(a, b)
    assert np.allclose(reg.rotation, m.rotation, atol=1e-12)
    assert np.allclose(reg.translation, m.translation, atol=1e-12)
    assert reg.rms_mm < 1e-9


def test_registration_of_simulated_data_finds_the_tracker(data):
    s, mset, p_true = data
    space = s.problem.space
    reg = register_tracker(space, mset)
    # the nominal robot's error of a 0.5 mm / 0.5 mrad robot: about a millimetre, far below 10 mm
    assert 0.1 < reg.rms_mm < 3.0
    shift, turn = pose_difference(space.tracker_placement(p_true), reg.placement)
    assert shift < 5.0 and turn < 0.2
    report = check_measurements(space, mset, reflector_names=s.reflector_names)
    assert report.plausible and report.causes == () and "registration" in report.summary()


@pytest.mark.parametrize("edit, kind, words", [
    (lambda m: dataclasses.replace(m, positions=m.positions * 1e3), "units", "1000 times too large"),
    (lambda m: dataclasses.replace(m, positions=m.positions * 1e-3), "units", "1000 times too small"),
    (lambda m: dataclasses.replace(m, positions=m.positions[:, [1, 0, 2]]), "axes",
     "x holds y, y holds x"),
    (lambda m: dataclasses.replace(m, positions=m.positions * [1, 1, -1]), "axes", "z holds -z"),
    (lambda m: dataclasses.replace(m, positions=m.positions + [0.03, 0, 0]), None, None),
])
def test_mistakes_are_named(data, edit, kind, words):
    s, mset, _ = data
    space = s.problem.space
    bad = edit(mset)
    if kind is None:  # a constant shift in the tracker frame is a tracker pose: no error
        assert check_measurements(space, bad).plausible
        return
    with pytest.raises(DataSanityError) as info:
        check_measurements(space, bad, reflector_names=s.reflector_names)
    err = info.value
    assert err.rms_mm > 10 and err.causes and words in err.causes[0][0]
    report = check_measurements(space, bad, raise_error=False)
    assert report.causes[0].kind == kind and report.causes[0].rms_mm < 3.0


def test_joint_offset_sign_and_tool_offset_are_named(data):
    s, mset, _ = data
    space = s.problem.space
    q = mset.q.copy()
    q[:, 2] += np.radians(20)  # the file's A3 zero is 20 deg off the model's
    report = check_measurements(space, dataclasses.replace(mset, q=q), raise_error=False)
    best = report.causes[0]
    assert best.kind == "joint" and "joint_a3: an offset" in best.description
    found = float(best.description.split("model angle is q ")[1].split(" deg")[0])
    assert abs(found + 20.0) < 0.5  # up to the simulated robot's own 0.5 mrad errors
    q = mset.q.copy()
    q[:, 3] *= -1
    report = check_measurements(space, dataclasses.replace(mset, q=q), raise_error=False)
    assert "joint_a4: its sign reversed" in report.causes[0].description
    # a reflector 100 mm off along tool x: the tool-offset fit names the reflector
    offset = space.reflector_offsets0 + [0.1, 0.0, 0.0]
    from calib_oed.calibration.registration import predicted_points

    world = predicted_points(space, mset.q, mset.reflector, offsets=offset)
    tracker = space.tracker_placement(None)
    eta = (world - tracker.translation) @ tracker.rotation
    report = check_measurements(space, dataclasses.replace(mset, positions=eta), raise_error=False,
                                reflector_names=s.reflector_names)
    assert report.causes[0].kind == "tool" and "smr0 by (+100.0, +0.0, +0.0) mm" in \
        report.causes[0].description


def test_bad_limit(data):
    s, mset, _ = data
    with pytest.raises(ParameterError, match="positive"):
        check_measurements(s.problem.space, mset, max_rms=0.0)
