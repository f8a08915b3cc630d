"""Tests of calib_oed.scene.scaling: the fms_kr16 cell scaled by the reach ratio."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import SceneError, UnknownRobotError
from calib_oed.model import kuka
from calib_oed.scene.reader import load_scene, scene_from_dict
from calib_oed.scene.scaling import scale_factor, scaled_scene, scaled_scene_dict

# The smallest and the largest arm of the paper's grid, and the KR 16-2's own
# dimensions as a notional arm (a2 = 680 mm, d4 = 670 mm: s = 1).
SMALLEST, LARGEST, KR16_LIKE = "notional_l650_m600", "notional_l1100_m1000", "notional_l680_m670"
DIMENSIONS = {SMALLEST: kuka.notional_dimensions(0.65, 0.60),
              LARGEST: kuka.notional_dimensions(1.10, 1.00), "kr300": kuka.KR300}


def aim_point(scene) -> np.ndarray:
    """Midpoint of the shoulder (joint_a2 origin) and the TCP at the working configuration [m]."""
    model, data = scene.robot.model, scene.robot.model.createData()
    pin.framesForwardKinematics(model, data, scene.kpi.configurations[0].q)
    tcp = data.oMf[scene.robot.tool_frame_id].act(scene.kpi.point)
    return 0.5 * (data.oMi[2].translation + tcp)


@pytest.mark.parametrize("robot", [SMALLEST, LARGEST, "kr300"])
def test_cell_and_tracker_scale_exactly(robot):
    """Tracker position, car capsules and wall times s (to rounding); the stand rebuilt."""
    base, scene = load_scene("fms_kr16"), scaled_scene(robot)
    s = scale_factor(robot)
    assert s == pytest.approx(DIMENSIONS[robot].reach / kuka.KR16.reach, rel=1e-15)
    np.testing.assert_allclose(scene.tracker.position, s * base.tracker.position, rtol=1e-14)
    assert [c.name for c in scene.cell.capsules] == [c.name for c in base.cell.capsules]
    for cap0, cap in zip(base.cell.capsules[:2], scene.cell.capsules[:2], strict=True):
        np.testing.assert_allclose(cap.a, s * cap0.a, rtol=1e-14)
        np.testing.assert_allclose(cap.b, s * cap0.b, rtol=1e-14)
        assert cap.radius == pytest.approx(s * cap0.radius, rel=1e-14)
    floor, wall = scene.cell.halfspaces
    assert floor.offset == 0.0 and np.array_equal(floor.normal, [0, 0, 1])
    assert wall.offset == pytest.approx(s * base.cell.halfspaces[1].offset, rel=1e-14)
    # The stand: under the scaled tracker, from the floor to 300 mm below the head, radius 100 mm.
    stand = scene.cell.capsules[2]
    np.testing.assert_allclose(stand.a, [*scene.tracker.position[:2], 0.0], atol=1e-12)
    np.testing.assert_allclose(stand.b, scene.tracker.position - [0, 0, 0.3], atol=1e-12)
    assert stand.radius == pytest.approx(0.1, abs=1e-15)


@pytest.mark.parametrize("robot", [SMALLEST, LARGEST])
def test_instrument_and_task_are_not_scaled(robot):
    base, scene = load_scene("fms_kr16"), scaled_scene(robot)
    assert scene.robot.name == robot and scene.name == f"fms_{robot}"
    np.testing.assert_array_equal(scene.kpi.q, base.kpi.q)  # joint space
    np.testing.assert_array_equal(scene.kpi.point, base.kpi.point)
    np.testing.assert_array_equal(scene.reflectors[0].offset, base.reflectors[0].offset)
    np.testing.assert_array_equal(scene.tracker.sigma, base.tracker.sigma)
    np.testing.assert_array_equal(scene.tracker.sigma_angle, base.tracker.sigma_angle)
    for f in dataclasses.fields(base.feasibility):  # incidence limit, radii, margins, pruning
        assert getattr(scene.feasibility, f.name) == getattr(base.feasibility, f.name), f.name
    assert scene.units == base.units and scene.measurement == base.measurement


@pytest.mark.parametrize("robot", [SMALLEST, LARGEST, KR16_LIKE])
def test_tracker_aims_at_the_working_volume(robot):
    """Roll 0; the x axis through the shoulder-TCP midpoint (exactly: no rounding)."""
    scene = scaled_scene(robot)
    assert scene.tracker.rpy[0] == 0.0
    aim = aim_point(scene) - scene.tracker.position
    x_axis = scene.tracker.placement().rotation[:, 0]
    angle = math.atan2(np.linalg.norm(np.cross(x_axis, aim)), x_axis @ aim)
    assert angle < 1e-12


@pytest.mark.parametrize("robot", [SMALLEST, LARGEST, KR16_LIKE])
def test_working_configuration_is_feasible(robot):
    """The KPI pose clears the scaled cell: self, obstacle and beam rows and joint limits >= 0.

    (Not incidence: at the working configuration the reflector faces the car,
    as in fms_kr16; it is where the KPI is evaluated, not a measurement.)
    """
    s = setup(scaled_scene(robot))
    res = s.feasibility.compute(s.scene.kpi.q, jacobian=False)
    slices = s.feasibility.kind_slices()
    for kind in ("joint", "self", "obstacle", "beam"):
        assert slices[kind].size > 0 or kind == "self"
        assert np.all(res.values[:, slices[kind]] >= 0.0), kind


def test_kr16_like_arm_is_the_template_cell():
    """s = 1: the cell is fms_kr16's exactly (only the rpy follows the aiming rule)."""
    base, scene = load_scene("fms_kr16"), scaled_scene(KR16_LIKE)
    assert scale_factor(KR16_LIKE) == 1.0
    np.testing.assert_array_equal(scene.tracker.position, base.tracker.position)
    for cap0, cap in zip(base.cell.capsules, scene.cell.capsules, strict=True):
        np.testing.assert_array_equal(cap.a, cap0.a)
        np.testing.assert_array_equal(cap.b, cap0.b)
        assert cap.radius == cap0.radius
    # fms_kr16's hand-rounded (0, 10, 90) deg is within 2.5 deg of the exact aim
    assert np.degrees(np.abs(scene.tracker.rpy - base.tracker.rpy)).max() < 2.5


@pytest.mark.parametrize("name", ["fms_kr300", "fms_kr500"])
def test_reproduces_the_shipped_scaled_scenes(name):
    """The shipped KR 300 and KR 500 cells are this rule rounded to mm and whole degrees."""
    shipped, scene = load_scene(name), scaled_scene(name.removeprefix("fms_"))
    assert scene.name == name
    tol = 0.5e-3 + 1e-12
    np.testing.assert_allclose(scene.tracker.position, shipped.tracker.position, atol=tol, rtol=0)
    np.testing.assert_allclose(scene.tracker.rpy, shipped.tracker.rpy, atol=math.radians(0.5),
                               rtol=0)
    for cap0, cap in zip(shipped.cell.capsules, scene.cell.capsules, strict=True):
        np.testing.assert_allclose(cap.a, cap0.a, atol=tol, rtol=0)
        np.testing.assert_allclose(cap.b, cap0.b, atol=tol, rtol=0)
        assert cap.radius == pytest.approx(cap0.radius, abs=tol)
    for h0, h in zip(shipped.cell.halfspaces, scene.cell.halfspaces, strict=True):
        assert h.offset == pytest.approx(h0.offset, abs=tol)


def test_dict_is_a_valid_scene_file_in_the_template_units():
    data = scaled_scene_dict(LARGEST)
    assert data["units"] == {"length": "mm", "angle": "deg"}
    s = scale_factor(LARGEST)
    assert data["tracker"]["position"] == pytest.approx([600 * s, -2600 * s, 1300 * s])
    assert scene_from_dict(data).name == f"fms_{LARGEST}"
    assert scaled_scene_dict(LARGEST, name="mine")["name"] == "mine"
    # the template is not modified
    assert load_scene("fms_kr16").tracker.position[0] == pytest.approx(0.6)


def test_errors_name_the_valid_choices():
    with pytest.raises(UnknownRobotError, match="kr16.*notional_l<lambda_mm>_m<mu_mm>"):
        scaled_scene("ur5")
    with pytest.raises(SceneError, match="neither a shipped scene"):
        scaled_scene(LARGEST, "no_such_scene")
