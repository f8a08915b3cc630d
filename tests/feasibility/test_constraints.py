"""Feasibility constraints: values against independent computations, gradients against finite differences."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference

from calib_oed.feasibility import Capsule, Cell, FeasibilitySettings, HalfSpace
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.segments import closest_parameters, segment_distance


def skeleton_capsules(robot, radius=0.04):
    """One capsule per moving link, from its joint origin to the next joint origin (link frame)."""
    model = robot.model
    caps = []
    for j in range(1, model.njoints):
        body = next(f for f in model.frames if f.parentJoint == j and f.type == pin.FrameType.BODY)
        if j + 1 < model.njoints:
            end = model.jointPlacements[j + 1].translation
        else:
            end = model.frames[robot.tool_frame_id].placement.translation
        if np.linalg.norm(end) < 1e-3:
            end = end + np.array([0.0, 0.0, 0.02])
        inv = body.placement.inverse()
        caps.append(Capsule(inv.act(np.zeros(3)), inv.act(end), radius, body.name, f"{body.name}#0"))
    return caps


def cell_for(robot):
    """A cell with a capsule obstacle, a floor and a wall, scaled to the robot's size."""
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, np.zeros(robot.nq))
    reach = np.linalg.norm(data.oMf[robot.tool_frame_id].translation) + 0.2
    obstacle = Capsule([0.8 * reach, -0.5, 0.3 * reach], [0.8 * reach, 0.5, 0.5 * reach], 0.1, None, "box")
    return Cell((obstacle,), (HalfSpace([0, 0, 1], -0.3, "floor"), HalfSpace([1, 0, 0], -reach, "wall"))), reach


def model_for(robot, prune=False, **settings):
    cell, reach = cell_for(robot)
    tracker = np.array([0.5 * reach, -2.0 * reach, 0.6 * reach])
    return build_feasibility_model(
        robot, cell, FeasibilitySettings(**settings), tracker,
        np.array([[0.0, 0.0, 0.05], [0.03, 0.0, 0.04]]), ["smr0", "smr1"],
        capsules=skeleton_capsules(robot), prune=prune,
    )


def brute_force_distance(a1, b1, a2, b2, n=2001):
    """Segment distance by a dense scan of one parameter with the exact projection of the other."""
    s = np.linspace(0.0, 1.0, n)
    x = a1 + s[:, None] * (b1 - a1)
    d2 = b2 - a2
    t = np.clip(((x - a2) @ d2) / max(d2 @ d2, 1e-300), 0.0, 1.0)
    y = a2 + t[:, None] * d2
    return np.linalg.norm(x - y, axis=1).min()


def test_segment_distance_matches_brute_force():
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(300, 4, 3))
    # include degenerate cases: a point segment, parallel and collinear segments
    pts[0, 1] = pts[0, 0]
    pts[1, 3] = pts[1, 2]
    pts[2, 3] = pts[2, 2] + (pts[2, 1] - pts[2, 0])
    pts[3, 2:] = pts[3, :2] + 2.5 * (pts[3, 1] - pts[3, 0])
    d = segment_distance(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    ref = np.array([brute_force_distance(*p) for p in pts])
    # the scan is an upper bound; one step of the scan bounds its error
    step = np.linalg.norm(pts[:, 1] - pts[:, 0], axis=1) / 2000
    assert np.all(d <= ref + 1e-12)
    assert np.all(ref - d <= step + 1e-12)


def test_closest_parameters_in_unit_square():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(1000, 4, 3))
    s, t = closest_parameters(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    assert np.all((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1))


def test_capsule_distance_matches_coal():
    coal = pytest.importorskip("coal")
    rng = np.random.default_rng(3)
    for _ in range(50):
        a1, b1, a2, b2 = rng.normal(size=(4, 3))
        r1, r2 = rng.uniform(0.01, 0.2, size=2)
        ours = segment_distance(a1, b1, a2, b2) - r1 - r2

        def placed(a, b, r):
            axis = b - a
            length = np.linalg.norm(axis)
            rot = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), axis / length).matrix()
            return coal.Capsule(r, length), coal.Transform3s(rot, (a + b) / 2)

        g1, t1 = placed(a1, b1, r1)
        g2, t2 = placed(a2, b2, r2)
        res = coal.DistanceResult()
        coal.distance(g1, t1, g2, t2, coal.DistanceRequest(), res)
        if ours > 0:
            assert res.min_distance == pytest.approx(ours, abs=1e-7)
        else:
            assert res.min_distance <= 1e-7


def test_constraint_jacobian_matches_finite_differences(robot):
    fm, _ = model_for(robot)
    q = robot.random_configurations(8, 11)
    res = fm.compute(q)
    assert res.values.shape == (8, fm.n_constraints)
    assert set(res.kinds) == {"joint", "incidence", "self", "obstacle", "beam"}
    for k in range(q.shape[0]):
        num = central_difference(lambda x: fm.compute_values(x[None])[0], q[k], eps=1e-6)
        err = np.abs(res.jacobian[k] - num)
        scale = np.maximum(np.abs(num).max(axis=1, keepdims=True), 1e-3)
        assert np.max(err / scale) < 1e-6, fm.labels[int(np.argmax(err.max(axis=1)))]


def test_pair_distances_match_world_capsules(robot):
    """Pair values against capsule end points placed by pinocchio frame placements."""
    fm, _ = model_for(robot)
    caps = {c.name: c for c in skeleton_capsules(robot)}
    cell, _ = cell_for(robot)
    q = robot.random_configurations(5, 5)
    values = fm.compute_values(q)
    data = robot.model.createData()
    clearance = fm.settings.margins.clearance
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qk)

        def world(cap):
            if cap.frame is None:
                return cap.a, cap.b
            m = data.oMf[robot.frame_id(cap.frame)]
            return m.act(cap.a), m.act(cap.b)

        for row, label in enumerate(fm.labels):
            kind, _, names = label.partition(":")
            if kind not in ("self", "obstacle"):
                continue
            n1, n2 = names.split("|")
            if n1 not in caps or (n2 not in caps and n2 != "box"):
                continue
            c1 = caps[n1]
            c2 = caps[n2] if n2 in caps else cell.capsules[0]
            d = brute_force_distance(*world(c1), *world(c2), n=4001) - c1.radius - c2.radius - clearance
            assert values[k, row] == pytest.approx(d, abs=2e-4)


def test_joint_rows_keep_the_margin(robot):
    fm, _ = model_for(robot)
    q = np.clip(robot.random_configurations(3, 0), robot.lower, robot.upper)
    q[0, 0] = robot.lower[0] + np.deg2rad(0.5)  # inside the limit, inside the 1 deg margin
    v = fm.compute_values(q)
    assert v[0, 0] == pytest.approx(-np.deg2rad(0.5))
    assert not fm.compute(q).feasible[0]


def test_incidence_value_is_angle_to_tracker(robot):
    fm, _ = model_for(robot)
    q = robot.random_configurations(6, 4)
    v = fm.compute_values(q)
    row = fm.labels.index("incidence:smr0")
    data = robot.model.createData()
    limit = fm.settings.incidence_limit - fm.settings.margins.incidence
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qk)
        m = data.oMf[robot.tool_frame_id]
        c = m.act(np.array([0.0, 0.0, 0.05]))
        u = fm.tracker_position - c
        beta = np.arccos(m.rotation[:, 2] @ u / np.linalg.norm(u))
        assert v[k, row] == pytest.approx(np.cos(beta) - np.cos(limit), abs=1e-12)


def test_pruning_reports_dropped_pairs():
    from calib_oed import load_robot

    robot = load_robot("kr16")
    fm_all, rep_all = model_for(robot, prune=False)
    fm, rep = model_for(robot, prune=True)
    assert fm.n_constraints <= fm_all.n_constraints
    reasons = {d.reason.split(" ")[0] for d in rep.dropped}
    assert "adjacent" in reasons
    assert rep.samples == FeasibilitySettings().prune_samples
    assert rep.paper_count == 6 * 5 // 2 - 5
    text = rep.summary()
    assert "paper formula" in text and "checked pairs per pose" in text
    # every pruned pair really stayed far (or constant) in a fresh sample
    q = robot.random_configurations(300, 99)
    vals = fm_all.compute_values(q)
    for d in rep.dropped:
        if d.reason.startswith("never closer"):
            if d.label in fm_all.labels:
                rows = [fm_all.labels.index(d.label)]
            else:  # a half-space pair: one row per capsule end
                kind_seg, plane = d.label.split("|")
                rows = [fm_all.labels.index(f"{kind_seg}.{end}|{plane}") for end in "ab"]
            assert vals[:, rows].min() + fm_all.settings.margins.clearance > 0.0


def test_excluded_pair_is_not_checked():
    from calib_oed import load_robot

    robot = load_robot("kr16")
    fm, rep = model_for(robot, excluded_pairs=(("link_1", "link_3"),))
    assert not any("link_1#0|link_3#0" in lbl for lbl in fm.labels)
    assert any(d.reason == "excluded by the scene" for d in rep.dropped)
    from calib_oed.exceptions import UnknownLinkError

    with pytest.raises(UnknownLinkError, match="link_9"):
        model_for(robot, excluded_pairs=(("link_1", "link_9"),))


@pytest.mark.parametrize("length", [0.0, 3e-7])
def test_zero_length_capsule_has_one_halfspace_row(robot, length):
    """A sphere (capsule shorter than POINT_LENGTH) against a half-space: one row, not two (nearly)
    equal ones (both active make the QP's KKT matrix singular), with its value and gradient;
    the row gives away the length, so it implies both ends' rows."""
    caps = skeleton_capsules(robot)
    sphere = caps[-1]
    end = np.asarray(sphere.a, dtype=float) + length * np.array([0.6, 0.0, 0.8])
    caps[-1] = Capsule(sphere.a, end, sphere.radius, sphere.frame, sphere.name)
    cell, reach = cell_for(robot)
    fm, _ = build_feasibility_model(
        robot, cell, FeasibilitySettings(), np.array([0.5 * reach, -2.0 * reach, 0.6 * reach]),
        np.array([[0.0, 0.0, 0.05]]), ["smr0"], capsules=caps, prune=False)
    rows = [k for k, lbl in enumerate(fm.labels) if lbl.startswith(f"obstacle:{sphere.name}")
            and not lbl.endswith("|box")]
    assert [fm.labels[k] for k in rows] == [f"obstacle:{sphere.name}|floor", f"obstacle:{sphere.name}|wall"]
    other = caps[0].name
    assert {f"obstacle:{other}.a|floor", f"obstacle:{other}.b|floor"} <= set(fm.labels)
    q = robot.random_configurations(4, 3)
    res = fm.compute(q)
    data = robot.model.createData()
    clearance = fm.settings.margins.clearance
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qk)
        frame = data.oMf[robot.frame_id(sphere.frame)]
        a, b = frame.act(np.asarray(sphere.a, dtype=float)), frame.act(end)
        for row, hs in zip(rows, cell.halfspaces, strict=True):
            assert res.values[k, row] == pytest.approx(hs.normal @ a - hs.offset - sphere.radius - clearance
                                                       - length, abs=1e-12)
            assert res.values[k, row] <= min(hs.normal @ a, hs.normal @ b) - hs.offset - sphere.radius - clearance + 1e-12
        num = central_difference(lambda x: fm.compute_values(x[None])[0][rows], qk, eps=1e-6)
        assert np.allclose(res.jacobian[k][rows], num, atol=1e-7)
