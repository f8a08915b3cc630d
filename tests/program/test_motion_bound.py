"""The point-speed bound holds: against Pinocchio's point Jacobians and against dense sampling."""

from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin
import pytest

from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.model.robot import load_robot
from calib_oed.program.motion_bound import point_speed_bounds, segment_speed_bounds


@pytest.mark.parametrize("name", ["kr16", "ur5"])
def test_bound_dominates_every_point_velocity(name):
    robot = load_robot(name)
    model, data = robot.model, robot.model.createData()
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.3, 0.3, size=(20, 3))
    bodies = rng.integers(1, model.njoints, size=20)
    ratios = []
    for q in robot.random_configurations(30, 1):
        pin.computeJointJacobians(model, data, q)
        for body, local in zip(bodies, points, strict=True):
            jac = pin.getJointJacobian(model, data, int(body), pin.LOCAL_WORLD_ALIGNED)
            x = data.oMi[int(body)].act(local)
            lever = x - data.oMi[int(body)].translation
            jx = jac[:3] - pin.skew(lever) @ jac[3:]
            rho = point_speed_bounds(robot, int(body), local)
            for dq in rng.normal(size=(5, model.nv)):
                speed, bound = np.linalg.norm(jx @ dq), rho @ np.abs(dq)
                ratios.append(speed / bound)
    assert max(ratios) <= 1.0 + 1e-12
    assert max(ratios) > 0.3  # the bound is not vacuous


def test_segment_bound_against_dense_sampling(kr16_checker):
    robot = kr16_checker.robot
    seg = kr16_checker.feasibility.segments
    rho = segment_speed_bounds(robot, seg)
    q0, q1 = robot.random_configurations(2, 7)
    t = np.linspace(0, 1, 2001)
    states = compute_body_states(robot.model, q0 + t[:, None] * (q1 - q0), jacobian=False)
    for local, body in ((seg.a_local, seg.body_a), (seg.b_local, seg.body_b)):
        p = states.points(body, local)  # (t, s, 3)
        step = np.linalg.norm(np.diff(p, axis=0), axis=2).max(axis=0)  # per segment end
        allowed = (rho @ np.abs(q1 - q0)) * (t[1] - t[0])
        assert np.all(step <= allowed + 1e-12)
    assert np.all(rho[[r == "obstacle" for r in seg.roles]] == 0)


def test_piece_bound_against_dense_sampling():
    """No vertex of a UR10 link's convex pieces (hence no point of them: a rigid body's point
    velocity is affine in the point) moves faster than piece_speed_bounds allows on a move."""
    from calib_oed.feasibility.capsules import load_collision_model
    from calib_oed.feasibility.hulls import link_pieces
    from calib_oed.program.motion_bound import piece_speed_bounds

    robot = load_robot("ur10")
    pieces = link_pieces(robot, load_collision_model(robot))
    t = np.linspace(0, 1, 401)
    ratios = []
    for q0, q1 in zip(*robot.random_configurations(2 * 2, 7).reshape(2, 2, -1), strict=True):
        states = compute_body_states(robot.model, q0 + t[:, None] * (q1 - q0), jacobian=False)
        for lp in pieces.values():
            allowed = piece_speed_bounds(robot, lp) @ np.abs(q1 - q0)
            for shape, rot, trans in zip(lp.shapes, lp.rotation, lp.translation, strict=True):
                if hasattr(shape, "points"):  # a convex hull: its vertices
                    v = np.asarray(shape.points())
                else:  # a URDF box: its corners
                    v = np.array(list(itertools.product(*[(-h, h) for h in shape.halfSide])))
                v = v @ rot.T + trans
                p = states.points(np.full(len(v), lp.body), v)
                speed = np.linalg.norm(np.diff(p, axis=0), axis=2).max() / (t[1] - t[0])
                assert speed <= allowed + 1e-9
                if allowed > 0:
                    ratios.append(speed / allowed)
    assert max(ratios) > 0.3  # not a vacuous bound
