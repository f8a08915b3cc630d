"""Mesh feasibility check: self-collision, cell obstacles, floor, beam; cross-checked with capsules."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import ShapeError, UnknownLinkError
from calib_oed.feasibility import Capsule, Cell, HalfSpace
from calib_oed.feasibility.capsules import fit_capsules, load_collision_model
from calib_oed.feasibility.mesh_check import check_design_meshes

HOME = np.array([0.0, -np.pi / 2, np.pi / 2, 0.0, 0.0, 0.0])  # KUKA home: upper arm vertical
REFLECTOR = np.array([[0.0, 0.0, 0.03]])  # 30 mm out of the flange, tool frame


@pytest.fixture(scope="module")
def kr16():
    robot = load_robot("kr16")
    return robot, load_collision_model(robot)


def check(kr16, q, cell=None, **kwargs):
    robot, geom = kr16
    return check_design_meshes(robot, q, cell, geometry_model=geom, **kwargs)


def frame_position(robot, q, name):
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return data.oMf[robot.frame_id(name)].copy()


def volume_samples(geometry, rng, n=4000):
    """Random points inside a kr16 primitive, in its own frame."""
    if isinstance(geometry, coal.Sphere):
        v = rng.normal(size=(n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        return geometry.radius * np.cbrt(rng.random(n))[:, None] * v
    assert isinstance(geometry, coal.Cylinder)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    rho = geometry.radius * np.sqrt(rng.random(n))
    z = rng.uniform(-geometry.halfLength, geometry.halfLength, n)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def inside(geometry, pts):
    if isinstance(geometry, coal.Sphere):
        return np.linalg.norm(pts, axis=1) <= geometry.radius
    return (np.hypot(pts[:, 0], pts[:, 1]) <= geometry.radius) & (
        np.abs(pts[:, 2]) <= geometry.halfLength
    )


def sampled_overlap(robot, geom, q, k, m, rng):
    """Whether random points inside geometry k fall inside geometry m at q (no coal involved)."""
    data, gdata = robot.model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(robot.model, data, q)
    pin.updateGeometryPlacements(robot.model, data, geom, gdata)
    gk, gm = geom.geometryObjects[k].geometry, geom.geometryObjects[m].geometry
    Mk, Mm = gdata.oMg[k], gdata.oMg[m]
    world = volume_samples(gk, rng) @ Mk.rotation.T + Mk.translation
    local = (world - Mm.translation) @ Mm.rotation
    return bool(inside(gm, local).any())


# ---------------------------------------------------------------- pairs


def test_pairs_skip_same_adjacent_and_fixed_links(kr16):
    report = check(kr16, np.zeros(6))
    links = ["base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6"]
    expected = {(links[i], links[j]) for i in range(7) for j in range(i + 2, 7)}
    assert set(report.pairs) == expected
    # link_1 and link_3 have two solids each: 24 geometry pairs for 15 link pairs.
    assert report.n_pairs == 24 and report.kinds == ("robot",) * 24
    excluded = check(kr16, np.zeros(6), excluded_pairs=[("link_4", "link_2")])
    assert ("link_2", "link_4") not in excluded.pairs and excluded.n_pairs == 23
    with pytest.raises(UnknownLinkError, match="'link_9'.*'link_4'"):
        check(kr16, np.zeros(6), excluded_pairs=[("link_2", "link_9")])


def test_zero_pose_in_an_empty_cell_is_feasible(kr16):
    report = check(kr16, np.zeros(6))
    assert report.all_feasible() and report.feasible.shape == (1,)
    assert report.colliding_pairs == ((),)
    # Clearance: the smallest distance decides.
    d = report.min_distance[0]
    assert d > 0.0
    assert check(kr16, np.zeros(6), clearance=d - 1e-4).all_feasible()
    tight = check(kr16, np.zeros(6), clearance=d + 1e-4)
    assert not tight.all_feasible() and tight.colliding_pairs[0] == (report.closest_pair[0],)


def test_folded_pose_reports_the_overlapping_links(kr16):
    robot, geom = kr16
    rng = np.random.default_rng(7)
    q = robot.random_configurations(40, rng)
    q[:, 2] = rng.uniform(2.0, robot.upper[2], len(q))  # elbow folded back towards the upper arm
    report = check(kr16, q)
    robot_pairs = [k for k, kind in enumerate(report.kinds) if kind == "robot"]
    folded = np.flatnonzero(report.distances[:, robot_pairs].min(axis=1) < -0.02)
    assert folded.size, "sampling found no folded pose"
    i = int(folded[0])
    assert not report.feasible[i]
    worst = robot_pairs[int(np.argmin(report.distances[i, robot_pairs]))]
    assert report.pairs[worst] in report.colliding_pairs[i]
    # Independent check by sampling: overlap exactly where coal says so (margins of 2 mm).
    objs = list(geom.geometryObjects)
    links = [robot.model.frames[go.parentFrame].name for go in objs]
    for p, pair in enumerate(report.pairs):
        dist = report.distances[i, p]
        if abs(dist) < 0.002:
            continue
        # The geometry pairs of one link pair come in file order.
        ks = [
            (a, b) for a in range(len(objs)) for b in range(a + 1, len(objs))
            if (links[a], links[b]) == pair
        ]  # fmt: skip
        k = ks[sum(1 for pp in report.pairs[:p] if pp == pair)]
        assert sampled_overlap(robot, geom, q[i], *k, rng) == (dist < 0.0), (pair, dist)


def test_obstacle_through_link_3_collides(kr16):
    robot, _ = kr16
    oMl3 = frame_position(robot, HOME, "link_3")
    centre = oMl3.act(np.array([0.05, 0.0, -0.035]))  # on the forearm solid, next to A3
    post = Capsule(centre - [0, 0.4, 0], centre + [0, 0.4, 0], 0.02, name="post")
    report = check(kr16, HOME, Cell(capsules=(post,)))
    assert not report.feasible[0]
    assert ("link_3", "post") in report.colliding_pairs[0]
    cell_links = {
        a for (a, b), kind in zip(report.pairs, report.kinds, strict=True) if kind == "cell"
    }
    assert "base_link" not in cell_links and len(cell_links) == 6
    away = Capsule(post.a + [0, 0, 3.0], post.b + [0, 0, 3.0], 0.02, name="post")
    assert check(kr16, HOME, Cell(capsules=(away,))).all_feasible()


def test_floor_above_the_tool_collides(kr16):
    robot, _ = kr16
    z_tool = frame_position(robot, np.zeros(6), "tool0").translation[2]
    floor = HalfSpace([0, 0, 1], z_tool + 0.05, name="floor")
    report = check(kr16, np.zeros(6), Cell(halfspaces=(floor,)))
    assert ("link_6", "floor") in report.colliding_pairs[0]
    cell = [pair for pair, kind in zip(report.pairs, report.kinds, strict=True) if kind == "cell"]
    assert ("base_link", "floor") not in cell and len(cell) == 8  # 8 moving solids
    low = HalfSpace([0, 0, 1], 0.0, name="floor")
    assert check(kr16, np.zeros(6), Cell(halfspaces=(low,))).all_feasible()


def test_beam_blocked_by_an_obstacle_and_by_the_arm(kr16):
    robot, _ = kr16
    tool = frame_position(robot, np.zeros(6), "tool0")  # tool z = world +x at q = 0
    start = tool.act(REFLECTOR[0])
    tracker = start + [2.0, 0.0, 0.0]
    mid = 0.5 * (start + tracker)
    blocker = Capsule(mid - [0, 0, 0.5], mid + [0, 0, 0.5], 0.05, name="blocker")
    floor = HalfSpace([0, 0, 1], 0.0, name="floor")
    beam = {"tracker_position": tracker, "reflector_offsets": REFLECTOR}
    report = check(kr16, np.zeros(6), Cell((blocker,), (floor,)), **beam)
    assert report.colliding_pairs[0] == (("beam#0", "blocker"),)
    assert report.distances[0, report.pairs.index(("beam#0", "floor"))] == pytest.approx(
        start[2] - 0.005
    )
    moved = Capsule(blocker.a + [0, 1.0, 0], blocker.b + [0, 1.0, 0], 0.05, name="blocker")
    assert check(kr16, np.zeros(6), Cell((moved,), (floor,)), **beam).all_feasible()
    # The beam leaves from link_6: the tool link is not checked, the rest of the arm is.
    beam_links = {b for (a, b) in report.pairs if a == "beam#0"}
    assert "link_6" not in beam_links and {"base_link", "link_5"} <= beam_links
    behind = check(
        kr16, np.zeros(6), tracker_position=start - [3.0, 0, 0], reflector_offsets=REFLECTOR
    )
    assert ("beam#0", "link_4") in behind.colliding_pairs[0]


def test_bad_inputs(kr16):
    with pytest.raises(ValueError, match="both"):
        check(kr16, np.zeros(6), tracker_position=np.ones(3))
    with pytest.raises(ShapeError, match="reflector_offsets"):
        check(kr16, np.zeros(6), tracker_position=np.ones(3), reflector_offsets=np.ones((2, 2)))
    with pytest.raises(ShapeError):
        check(kr16, np.zeros(5))


def test_summary_speaks_mm(kr16):
    robot, _ = kr16
    q = np.array([np.zeros(6), [0.0, 0.0, 2.6, 0.0, 0.0, 0.0]])
    report = check(kr16, q)
    text = report.summary()
    assert "2 poses" in text and "feasible: 1 / 2" in text and "[mm]" in text
    assert "link_2 / link_4" in text


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_mesh_robots(name):
    robot = load_robot(name)
    q = robot.random_configurations(3, 0)
    report = check_design_meshes(
        robot, q, tracker_position=np.array([2.0, 1.0, 0.5]), reflector_offsets=REFLECTOR
    )
    assert report.distances.shape == (3, report.n_pairs)
    assert report.n_pairs == {"ur5": 20 + 6, "panda": 75 + 7}[name]
    assert np.all(np.isfinite(report.distances))


# ---------------------------------------------------------------- cross-check with capsules


def capsule_distance_lower_bound(c1, c2, n=41):
    """Brute force: grid distance of the two segments minus the grid error, minus the radii."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    p = c1[0] + s * (c1[1] - c1[0])
    r = c2[0] + s * (c2[1] - c2[0])
    grid = np.linalg.norm(p[:, None, :] - r[None, :, :], axis=2).min()
    error = (np.linalg.norm(c1[1] - c1[0]) + np.linalg.norm(c2[1] - c2[0])) / (2 * (n - 1))
    return grid - error - c1[2] - c2[2]


def test_capsule_separated_poses_are_mesh_feasible(kr16):
    """Capsules enclose the meshes: separated capsules imply separated meshes.

    The round ends of the link_4 and link_6 capsules overlap around the wrist sphere
    (link_5) in every pose, so that pair is excluded here.
    """
    robot, geom = kr16
    capsules = {c.frame: c for c in fit_capsules(robot, geom)}
    box = Capsule([1.2, -0.9, 0.2], [1.2, 0.9, 0.2], 0.15, name="box")
    floor = HalfSpace([0, 0, 1], 0.0, name="floor")
    cell = Cell((box,), (floor,))
    q = robot.random_configurations(100, np.random.default_rng(3))
    report = check(kr16, q, cell, excluded_pairs=[("link_4", "link_6")])
    link_pairs = sorted(set(report.pairs))
    data = robot.model.createData()
    separated = np.zeros(len(q), dtype=bool)
    for i, qi in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, qi)
        world = {}
        for link, c in capsules.items():
            M = data.oMf[robot.frame_id(link)]
            world[link] = (M.act(c.a), M.act(c.b), c.radius)
        world["box"] = (box.a, box.b, box.radius)
        gaps = []
        for a, b in link_pairs:
            if b == "floor":
                gaps.append(min(world[a][0][2], world[a][1][2]) - world[a][2])
            else:
                gaps.append(capsule_distance_lower_bound(world[a], world[b]))
        separated[i] = min(gaps) > 0.0
    assert separated.sum() >= 20, "too few capsule-separated poses to cross-check"
    assert np.all(report.feasible[separated])
    assert (~report.feasible).sum() >= 10, "the sample should also hold infeasible poses"
