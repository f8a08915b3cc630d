"""Configuration bits of Cartesian targets: the boundaries are the arm's singularities, the turn
rules are the vendors', and a change is named."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.optimize import brentq

from calib_oed import load_robot
from calib_oed.exceptions import ParameterError
from calib_oed.model.arm_configuration import (
    ArmConfiguration,
    abb_confdata,
    compute_arm_configuration,
    configuration_changes,
    kuka_status,
)


def _wrist_sigma_min(robot, q) -> float:
    """Smallest singular value of d(wrist centre)/d(q1..q3) [m/rad], the wrist centre the joint-5 origin."""
    model, data = robot.model, robot.model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    jac = pin.getJointJacobian(model, data, 5, pin.LOCAL_WORLD_ALIGNED)[:3, :3]
    return float(np.linalg.svd(jac, compute_uv=False)[-1])


@pytest.mark.parametrize("name", ["kr16", "kr300"])
def test_elbow_and_shoulder_flip_where_the_arm_is_singular(name):
    """Where the elbow or shoulder margin crosses 0 the wrist-centre Jacobian loses rank (elbow) or
    the wrist centre is over the A1 plane; elsewhere the Jacobian is regular."""
    robot = load_robot(name)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(robot.lower, robot.upper) * 0.5

        def elbow(a3, q=q):
            row = q.copy()
            row[2] = a3
            return compute_arm_configuration(robot, row).elbow[0]

        root = brentq(elbow, np.radians(-30), np.radians(25), xtol=1e-12)
        row = q.copy()
        row[2] = root
        assert _wrist_sigma_min(robot, row) < 1e-9 * robot.model.jointPlacements[3].translation[0] + 1e-9
        row[2] = root + 0.2
        assert _wrist_sigma_min(robot, row) > 1e-2
        # the boundary angle does not depend on the other joints (KUKA's constant phi)
        assert np.isclose(root, brentq(elbow, np.radians(-30), np.radians(25), xtol=1e-12), atol=1e-10)
    base = compute_arm_configuration(robot, np.zeros(6))
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, np.zeros(6))
    assert np.isclose(base.shoulder[0], data.oMi[5].translation[0])     # in front, along x at A1 = 0
    turned = compute_arm_configuration(robot, np.array([np.pi, 0, 0, 0, 0, 0]))
    assert np.isclose(turned.shoulder[0], base.shoulder[0])            # the direction turns with A1


def test_turn_rules_of_the_vendors():
    c = np.radians([[89.9, 0, 0, -0.1, 0, 180.1], [90.1, 0, 0, 0.1, 0, -180.1]])
    cfg = ArmConfiguration(np.ones(2), np.ones(2), c[:, 4], c)
    assert cfg.turns("abb")[0] == (0, 3, 5)
    assert cfg.turns("abb")[1].tolist() == [[0, -1, 2], [1, 0, -3]]
    assert cfg.turns("fanuc")[1].tolist() == [[0, 0, 1], [0, 0, -1]]
    assert cfg.turns("kuka")[1].tolist() == [[0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 0, 1]]
    with pytest.raises(ParameterError, match="valid: abb, fanuc, kuka"):
        cfg.turns("staubli")


def test_changes_are_named_with_their_values():
    robot = load_robot("kr16")
    before = np.radians([[10, -80, 95, 0.05, 30, 45], [10, -80, -2.9, 20, -0.02, 89.95]])
    after = np.radians([[10.1, -80, 95, -0.05, 30, 45], [10, -80, -3.1, 20, 0.03, 90.05]])
    b, a = compute_arm_configuration(robot, before), compute_arm_configuration(robot, after)
    kuka = configuration_changes(b, a, "kuka", robot.joint_names)
    assert kuka[0] == ["turn of joint_a4 +0.050 -> -0.050 deg"]
    assert [s.split(" ")[0:3] for s in kuka[1]] == [["S", "bit", "1"], ["S", "bit", "2"],
                                                    ["turn", "of", "joint_a5"]]    # T bit 4: A5 < 0
    abb = configuration_changes(b, a, "abb")
    assert abb[0] == ["turn of J4 +0.050 -> -0.050 deg"]
    assert any("turn of J6" in s for s in abb[1]) and any("lower arm" in s for s in abb[1])
    fanuc = configuration_changes(b, a, "fanuc")
    assert fanuc[0] == [] and any(s.startswith("Flip/NoFlip -0.020 -> +0.030") for s in fanuc[1])


def test_fewer_than_six_axes_is_refused(tmp_path):
    from calib_oed.model.dh import compute_table
    from calib_oed.model.dh_urdf import table_urdf_text

    table = compute_table(load_robot("kr16"), "classic_dh")
    arm3 = type(table)(table.convention, "arm3", table.tool_frame, table.base, table.tool, table.rows[:3])
    (tmp_path / "arm3.urdf").write_text(table_urdf_text(arm3))
    with pytest.raises(ParameterError, match="6-axis"):
        compute_arm_configuration(load_robot(tmp_path / "arm3.urdf", tool_frame=arm3.tool_frame), np.zeros(3))


def test_kuka_status_and_turn():
    """KSS 8.x: S bit 0 overhead, bit 1 A3 >= phi, bit 2 A5 <= 0; T bit i A(i+1) < 0."""
    robot = load_robot("kr16")
    q = np.radians([[10, -80, 95, 0, 30, 0], [-15, -100, 110, -20, 40, 60], [10, -80, 95, 180, -30, -180],
                    [0, -80, -20, 0, 30, 0], [0, -150, 30, 0, 30, 0]])
    cfg = compute_arm_configuration(robot, q)
    status, turn = kuka_status(cfg)
    assert turn.tolist() == [2, 11, 2 + 16 + 32, 2 + 4, 2]
    assert status[:3].tolist() == [2, 2, 6]                # elbow above the stretched arm; flipped wrist
    assert status[3] & 2 == 0                             # A3 = -20 deg < phi = -3 deg: bit 1 clear
    assert cfg.shoulder[4] < 0 and status[4] & 1 == 1     # A2 = -150 deg: the wrist centre behind A1


def test_elbow_flip_keeps_the_wrist_centre_and_mirrors_the_elbow():
    from calib_oed.model.arm_configuration import ConfigurationKinematics

    robot = load_robot("kr16")
    arm = ConfigurationKinematics(robot)
    q = np.radians([20, -70, 100, 15, 50, -30])
    flipped = arm.compute_elbow_flip(q)
    a, b = arm.compute(q), arm.compute(flipped)
    assert np.isclose(b.elbow[0], -a.elbow[0], atol=1e-12) and np.isclose(b.shoulder[0], a.shoulder[0], atol=1e-12)
    assert np.allclose(flipped[[0, 3, 4, 5]], q[[0, 3, 4, 5]]) and not np.isclose(flipped[2], q[2])
    data = robot.model.createData()
    centres = []
    for row in (q, flipped):
        pin.forwardKinematics(robot.model, data, row)
        centres.append(data.oMi[5].translation.copy())        # the kr16's wrist centre: the A5 origin
    assert np.allclose(centres[0], centres[1], atol=1e-12)


def test_abb_confdata_on_an_abb_arm():
    """The ABB IRB 140 description of the rtb-data wheel (joint directions ABB's): quadrants of axes 1, 4,
    6 (0 from 0 to 90 deg, -1 from -90 to 0) and cfx = 4 behind axis 1 + 2 behind the lower arm +
    1 axis 5 negative; the synchronisation position with axis 5 at 30 deg is [0, 0, 0, 0]."""
    from pathlib import Path

    rtbdata = pytest.importorskip("rtbdata")
    robot = load_robot(str(Path(rtbdata.__file__).parent / "xacro" / "abb_irb140_description" / "urdf" / "irb140.urdf"))
    q = np.radians([[0, 0, 0, 0, 30, 0],          # synchronisation position, axis 5 tilted
                    [100, 0, 0, 185, -30, -200],  # quadrants 1, 2, -3; axis 5 negative
                    [-10, 40, -120, 0, 30, 0],    # lower arm forward, upper arm folded back past it
                    [-10, 0, -120, 0, 30, 0],     # the same with the lower arm upright: wrist centre
                    [0, -90, -150, 0, 30, 0]])    # behind axis 1 too; and with the arm leaning back
    assert abb_confdata(compute_arm_configuration(robot, q)).tolist() == [
        [0, 0, 0, 0], [1, 2, -3, 1], [-1, 0, 0, 2], [-1, 0, 0, 6], [0, 0, 0, 6]]
