"""The design joint window: one turn about home for joints with more, the real limits elsewhere."""

from __future__ import annotations

import copy
from importlib import resources

import numpy as np
import pytest
import yaml

from calib_oed.exceptions import SceneError
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.feasibility.window import JOINT_WINDOWS, design_home, design_window, windowed_robot
from calib_oed.model.robot import load_robot
from calib_oed.scene.reader import scene_from_dict


def _scene(name: str, **feasibility):
    data = yaml.safe_load(resources.files("calib_oed.scene.shipped").joinpath(f"{name}.yaml").read_text())
    data = copy.deepcopy(data)
    data.setdefault("feasibility", {}).update(feasibility)
    return scene_from_dict(data, source=f"<{name} with feasibility {feasibility}>")


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5")


def test_a_ur_joint_of_two_turns_gets_one_turn_about_home(ur5):
    home = np.radians([15.0, -60.0, 90.0, -120.0, -90.0, 0.0])
    w = design_window(ur5, home, "one_turn", "test")
    two_turns = [i for i in range(ur5.nq) if ur5.upper[i] - ur5.lower[i] > 2 * np.pi + 1e-9]
    assert two_turns, "the UR5's URDF has joints of +-360 deg"
    for i in range(ur5.nq):
        if i in two_turns:
            assert w.lower[i] == pytest.approx(home[i] - np.pi)
            assert w.upper[i] == pytest.approx(home[i] + np.pi)
        else:  # the elbow's +-180 deg: one turn already, untouched
            assert (w.lower[i], w.upper[i]) == (ur5.lower[i], ur5.upper[i])
    assert w.joints == tuple(ur5.joint_names[i] for i in two_turns)
    # the window is the robot's limits for the design, the real robot is unchanged
    narrow = windowed_robot(ur5, w)
    assert narrow.model is ur5.model
    np.testing.assert_array_equal(narrow.lower, w.lower)
    assert np.all(ur5.upper - ur5.lower >= narrow.upper - narrow.lower)
    assert "shoulder_lift_joint -240.0 to 120.0 deg" in w.summary()


def test_the_window_is_cut_by_the_limits(ur5):
    home = np.zeros(ur5.nq)
    home[0] = np.radians(300.0)  # one turn about 300 deg runs past +360
    w = design_window(ur5, home, "one_turn")
    assert w.lower[0] == pytest.approx(np.radians(120.0))
    assert w.upper[0] == pytest.approx(ur5.upper[0])


def test_a_kuka_joint_of_less_than_a_turn_is_untouched():
    kr16 = load_robot("kr16")
    home = (kr16.lower + kr16.upper) / 2
    w = design_window(kr16, home, "one_turn")
    short = [i for i in range(kr16.nq) if kr16.upper[i] - kr16.lower[i] < 2 * np.pi]
    assert short  # A2, A3, A5
    for i in short:
        assert (w.lower[i], w.upper[i]) == (kr16.lower[i], kr16.upper[i])
        assert kr16.joint_names[i] not in w.joints


def test_full_restores_the_robot_limits(ur5):
    w = design_window(ur5, np.zeros(ur5.nq), "full")
    assert w.joints == ()
    assert windowed_robot(ur5, w) is ur5
    scene = _scene("ur5_table", joint_window="full")
    model, report = feasibility_from_scene(scene, prune=False)
    np.testing.assert_array_equal(model.robot.lower, scene.robot.lower)
    np.testing.assert_array_equal(model.robot.upper, scene.robot.upper)
    assert "full" in report.window


def test_the_scene_windows_the_design_and_not_the_robot():
    scene = _scene("ur5_table")
    home, source = design_home(scene)
    np.testing.assert_allclose(np.degrees(home), [15, -60, 90, -120, -90, 0])
    assert "above_part" in source
    model, report = feasibility_from_scene(scene)  # the design's model
    assert model.robot.model is scene.robot.model
    assert np.all(model.robot.upper - model.robot.lower <= 2 * np.pi + 1e-12)
    assert np.degrees(scene.robot.upper[1]) == pytest.approx(360.0)  # identification keeps these
    assert "shoulder_lift_joint -240.0 to 120.0 deg" in report.window
    # the sampler never leaves the window
    q = sample_feasible(model, 40, 0)
    assert q.shape == (40, 6)
    assert np.all((q >= model.robot.lower) & (q <= model.robot.upper))


def test_program_home_centres_the_window():
    scene = _scene("ur5_table")
    scene.program["home"] = [0, -90, 90, -90, -90, 100]
    home, source = design_home(scene)
    assert source == "program.home"
    w = design_window(scene.robot, home, "one_turn")
    assert np.degrees(w.lower[5]) == pytest.approx(-80.0)
    assert np.degrees(w.upper[5]) == pytest.approx(280.0)


def test_a_bad_value_names_the_choices(ur5):
    with pytest.raises(SceneError, match="feasibility.joint_window.*one_turn, full.*'two_turns'"):
        _scene("ur5_table", joint_window="two_turns")
    with pytest.raises(SceneError, match="one_turn, full"):
        design_window(ur5, np.zeros(ur5.nq), "wide")
    with pytest.raises(SceneError, match="outside the joint limits of shoulder_pan_joint"):
        design_window(ur5, np.array([7.0, 0, 0, 0, 0, 0]), "one_turn")
    assert JOINT_WINDOWS == ("one_turn", "full")


def test_identification_keeps_the_robot_limits():
    """The gauge rule's generic design (and measured data) use the robot's own ranges; only
    the design's feasibility model is windowed."""
    from calib_oed.calibration.problem import CalibrationProblem

    scene = _scene("ur5_table")
    problem = CalibrationProblem.from_scene(scene)
    assert problem.robot is scene.robot
    q = problem.generic_configurations()
    window = design_window(scene.robot, design_home(scene)[0], "one_turn")
    outside = np.any((q < window.lower - 1e-9) | (q > window.upper + 1e-9), axis=1)
    assert outside.mean() > 0.5  # uniform in +-360 deg: most draws leave one turn somewhere
