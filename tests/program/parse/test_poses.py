"""The controllers' pose conventions against hand-computed rotations, and the nearest representation."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.program.parse import poses


def test_kuka_abc_and_fanuc_wpr_are_zyx_euler():
    # KUKA A = 90 deg (about z): tool x along base y; FANUC W = 90 deg (about x): tool y along base z
    m = poses.from_euler_mm_deg(100.0, -20.0, 5.0, 0.0, 0.0, 90.0)
    assert np.allclose(m.rotation @ [1, 0, 0], [0, 1, 0]) and np.allclose(m.translation, [0.1, -0.02, 0.005])
    m = poses.from_euler_mm_deg(0, 0, 0, 90.0, 0, 0)
    assert np.allclose(m.rotation @ [0, 1, 0], [0, 0, 1])
    # R = Rz(yaw) Ry(pitch) Rx(roll): the order matters
    r = poses.from_euler_mm_deg(0, 0, 0, 30.0, 20.0, 10.0).rotation
    ref = pin.exp3(np.radians(10) * np.array([0, 0, 1.0])) @ pin.exp3(np.radians(20) * np.array([0, 1.0, 0])) \
        @ pin.exp3(np.radians(30) * np.array([1.0, 0, 0]))
    assert np.allclose(r, ref, atol=1e-15)


def test_abb_quaternion_is_w_first():
    m = poses.from_quaternion_mm(1.0, 2.0, 3.0, np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5))     # 90 deg about z
    assert np.allclose(m.rotation @ [1, 0, 0], [0, 1, 0])
    xyz, q = poses.to_quaternion_mm(m, near=[-1, 0, 0, 0])
    assert np.allclose(xyz, [1, 2, 3]) and q[0] < 0                 # the sign nearest the original


def test_ur_rotation_vector_and_its_sign_near_pi():
    m = poses.from_rotvec_m(0.1, 0.2, 0.3, 0.0, 0.0, np.pi / 2)
    assert np.allclose(m.rotation @ [1, 0, 0], [0, 1, 0])
    flip = poses.from_rotvec_m(0, 0, 0, 0.0, 3.1, 0.0)
    _, r = poses.to_rotvec_m(flip, near=[0.0, -3.18, 0.0])          # pendants show either form near pi
    assert np.allclose(pin.exp3(r), flip.rotation) and r[1] < 0


@pytest.mark.parametrize("near", [None, [170.0, -10.0, 350.0]])
def test_euler_round_trip_and_nearest_angles(near):
    m = poses.from_euler_mm_deg(1.0, 2.0, 3.0, -170.0, -10.0, -10.0)
    xyz, rpy = poses.to_euler_mm_deg(m, near=near)
    assert np.allclose(poses.from_euler_mm_deg(*xyz, *rpy).homogeneous, m.homogeneous)
    if near is not None:
        assert np.all(np.abs(rpy - near) <= 180.0)


def test_in_order_reads_the_numbers_as_arguments_and_writes_the_rotation_nearest_the_old():
    pose_from, pose_to = poses.in_order(poses.from_quaternion_mm, poses.to_quaternion_mm)
    old = np.array([1.0, 2.0, 3.0, -np.sqrt(0.5), 0.0, 0.0, -np.sqrt(0.5)])    # 90 deg about z, w < 0
    m = pose_from(old)
    assert m.isApprox(poses.from_quaternion_mm(*old))
    new = pose_to(pin.SE3(m.rotation, m.translation + [0.001, 0, 0]), old)
    assert new.shape == (7,) and np.allclose(new, old + [1, 0, 0, 0, 0, 0, 0])   # same sign as before
