"""Capsules fitted to the URDF collision geometry enclose it, tightly; capsule tables are validated."""

from __future__ import annotations

from functools import cache

import coal
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial import ConvexHull

from calib_oed import load_robot
from calib_oed.exceptions import RobotLoadError, UnknownLinkError
from calib_oed.feasibility import Capsule, FeasibilitySettings
from calib_oed.feasibility.capsules import (
    capsules_from_table,
    fit_capsule,
    fit_capsules,
    link_names,
    load_collision_model,
    robot_capsules,
)

ROBOTS = ("ur5", "panda", "kr16")
SAMPLES = 2000  # random surface points per primitive


@cache
def fit(name):
    """Robot, collision model and fitted capsules, once per robot."""
    robot = load_robot(name)
    geom = load_collision_model(robot)
    return robot, geom, fit_capsules(robot, geom)


@pytest.fixture(params=ROBOTS)
def fitted(request):
    return fit(request.param)


def unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def surface_samples(geometry, rng, n=SAMPLES):
    """Points of the geometry's surface in its own frame: mesh vertices, or random samples."""
    if isinstance(geometry, coal.BVHModelBase):
        return np.asarray(geometry.vertices(), dtype=float)
    if isinstance(geometry, coal.Sphere):
        return geometry.radius * unit_vectors(rng, n)
    if isinstance(geometry, coal.Cylinder):
        r, h = geometry.radius, geometry.halfLength
        phi = rng.uniform(0.0, 2.0 * np.pi, n)
        side = rng.random(n) < 0.5
        rho = np.where(side, r, r * np.sqrt(rng.random(n)))  # caps: uniform on the disc
        z = np.where(side, rng.uniform(-h, h, n), rng.choice([-h, h], n))
        return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
    if isinstance(geometry, coal.Box):
        half = np.asarray(geometry.halfSide)
        pts = rng.uniform(-1.0, 1.0, size=(n, 3))
        face = rng.integers(0, 3, n)
        pts[np.arange(n), face] = rng.choice([-1.0, 1.0], n)
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        return np.vstack([pts, corners]) * half
    raise AssertionError(f"no sampler for {type(geometry).__name__}")


def link_surface_points(robot, geom, seed=0):
    """Surface points of every link's collision geometry, in the link frame."""
    rng = np.random.default_rng(seed)
    out = {}
    for go in geom.geometryObjects:
        frame = robot.model.frames[go.parentFrame]
        M = frame.placement.actInv(go.placement)
        pts = surface_samples(go.geometry, rng) @ M.rotation.T + M.translation
        out.setdefault(frame.name, []).append(pts)
    return {k: np.vstack(v) for k, v in out.items()}


def distance_to_segment(points, a, b):
    ab = b - a
    denom = float(ab @ ab)
    t = np.zeros(len(points)) if denom == 0.0 else np.clip((points - a) @ ab / denom, 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def capsule_volume(c):
    return np.pi * c.radius**2 * c.length + 4.0 / 3.0 * np.pi * c.radius**3


# ---------------------------------------------------------------- collision model


@pytest.mark.parametrize("name", ROBOTS)
def test_collision_model_matches_the_reduced_urdf_model(name):
    """Same geometry as building on the full URDF model and reducing it with the locks."""
    robot = load_robot(name)
    geom = load_collision_model(robot)
    full = pin.buildModelFromXML(robot.urdf_text)
    full_geom = pin.buildGeomFromUrdfString(
        full, robot.urdf_text, pin.GeometryType.COLLISION, package_dirs=list(robot.package_dirs)
    )
    q_ref = pin.neutral(full)
    for joint, value in robot.locked_joints.items():
        q_ref[full.joints[full.getJointId(joint)].idx_q] = value
    lock_ids = [full.getJointId(j) for j in robot.locked_joints]
    reduced, reduced_geom = pin.buildReducedModel(full, full_geom, lock_ids, q_ref)
    assert list(reduced.names) == list(robot.model.names)
    assert geom.ngeoms == reduced_geom.ngeoms > 0
    for ours, ref in zip(geom.geometryObjects, reduced_geom.geometryObjects, strict=True):
        assert ours.name == ref.name
        assert robot.model.names[ours.parentJoint] == reduced.names[ref.parentJoint]
        assert robot.model.frames[ours.parentFrame].name == reduced.frames[ref.parentFrame].name
        assert ours.placement.isApprox(ref.placement, 1e-12)
        if ours.meshPath.endswith((".stl", ".dae", ".obj")):
            assert isinstance(ours.geometry, coal.BVHModelBase) and ours.geometry.num_vertices > 0


def test_missing_mesh_is_a_clear_load_error(tmp_path):
    (tmp_path / "arm.urdf").write_text(
        """<robot name="arm">
  <link name="base"><collision><geometry><mesh filename="package://nowhere/base.stl"/></geometry>
  </collision></link><link name="l1"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""
    )
    robot = load_robot(tmp_path / "arm.urdf")
    with pytest.raises(RobotLoadError, match="nowhere/base.stl.*package_dirs"):
        load_collision_model(robot)


# ---------------------------------------------------------------- fit


def test_fit_recovers_known_shapes():
    rng = np.random.default_rng(1)
    # Points on a capsule's surface: the fit is that capsule.
    a, b, r = np.array([0.1, -0.2, 0.3]), np.array([0.6, 0.0, 0.2]), 0.05
    axis = (b - a) / np.linalg.norm(b - a)
    t = rng.random(4000)
    dirs = unit_vectors(rng, 4000)
    on_axis = a + t[:, None] * (b - a)
    side = on_axis + r * (dirs - (dirs @ axis)[:, None] * axis) / np.linalg.norm(
        dirs - (dirs @ axis)[:, None] * axis, axis=1, keepdims=True
    )
    caps = np.vstack([a + r * dirs[:2000], b + r * dirs[2000:]])
    fa, fb, fr = fit_capsule(np.vstack([side, caps]))
    if np.linalg.norm(fa - a) > np.linalg.norm(fa - b):
        fa, fb = fb, fa
    assert fr == pytest.approx(r, abs=1e-3)
    assert np.linalg.norm(fa - a) < 3e-3 and np.linalg.norm(fb - b) < 3e-3
    # One ball: a sphere, exactly.
    fa, fb, fr = fit_capsule(np.array([[1.0, 2.0, 3.0]]), np.array([0.2]))
    assert np.allclose(fa, [1, 2, 3]) and np.allclose(fb, fa) and fr == pytest.approx(0.2)


def test_every_vertex_and_surface_sample_is_inside_its_link_capsule(fitted):
    robot, geom, capsules = fitted
    by_link = {c.frame: c for c in capsules}
    points = link_surface_points(robot, geom)
    assert set(by_link) == set(points)
    for link, pts in points.items():
        c = by_link[link]
        excess = distance_to_segment(pts, c.a, c.b) - c.radius
        assert excess.max() <= 1e-9, f"{link}: a point lies {excess.max() * 1e3:.3f} mm outside"


def test_fit_is_tight(fitted):
    """Radius = max distance from the axis (nothing wasted), volume a small multiple of the hull."""
    robot, geom, capsules = fitted
    points = link_surface_points(robot, geom)
    ratios = {}
    for c in capsules:
        pts = points[c.frame]
        if c.length > 0.0:
            u = (c.b - c.a) / c.length
            rel = pts - c.a
            reach = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1).max()
        else:
            reach = np.linalg.norm(pts - c.a, axis=1).max()
        assert c.radius <= 1.05 * reach, c.name
        ratios[c.name] = capsule_volume(c) / ConvexHull(pts).volume
    # One capsule per link cannot hug a flat or L-shaped link; ur5's base disc is the worst (5.7).
    assert max(ratios.values()) < 6.0, ratios
    assert np.median(list(ratios.values())) < 2.5, ratios


def test_capsules_name_links_including_fixed_ones(fitted):
    robot, geom, capsules = fitted
    with_geometry = {robot.model.frames[go.parentFrame].name for go in geom.geometryObjects}
    assert [c.frame for c in capsules] == [n for n in link_names(robot) if n in with_geometry]
    assert all(c.name == f"{c.frame}#0" for c in capsules)
    fixed = [c for c in capsules if robot.model.frames[robot.frame_id(c.frame)].parentJoint == 0]
    assert fixed, "the base link has collision geometry and gets a capsule"


def test_margin_inflates_radius_only():
    robot, geom, plain = fit("kr16")
    fat = fit_capsules(robot, geom, margin=0.01)
    for p, f in zip(plain, fat, strict=True):
        assert f.radius == pytest.approx(p.radius + 0.01)
        assert np.allclose(f.a, p.a) and np.allclose(f.b, p.b)
    with pytest.raises(ValueError, match="margin"):
        fit_capsules(robot, margin=-0.01)


# ---------------------------------------------------------------- tables and settings


def test_capsule_table_is_validated():
    robot = load_robot("kr16")
    table = [
        {"link": "link_2", "a": [0, 0, 0], "b": [0.68, 0, 0], "radius": 0.1},
        {"link": "link_2", "a": [0, 0, 0], "b": [0, 0, 0], "radius": 0.12, "name": "elbow"},
        Capsule([0, 0, 0], [0.1, 0, 0], 0.05, frame="link_6"),
    ]
    caps = capsules_from_table(robot, table)
    assert [c.name for c in caps] == ["link_2#0", "elbow", "link_6#0"]
    assert [c.frame for c in caps] == ["link_2", "link_2", "link_6"]
    with pytest.raises(UnknownLinkError, match="'link_7'.*'link_3'") as err:
        capsules_from_table(
            robot, [{"link": "link_7", "a": [0, 0, 0], "b": [0, 0, 0], "radius": 0.1}]
        )
    assert err.value.valid == link_names(robot)
    with pytest.raises(UnknownLinkError, match="None"):
        capsules_from_table(robot, [Capsule([0, 0, 0], [0, 0, 0], 0.1)])
    with pytest.raises(ValueError, match="missing keys \\['radius'\\]"):
        capsules_from_table(robot, [{"link": "link_2", "a": [0, 0, 0], "b": [0, 0, 0]}])


def test_robot_capsules_follow_the_settings():
    robot, _, plain = fit("kr16")
    table = (Capsule([0, 0, 0], [0.6, 0, 0], 0.1, frame="link_2", name="arm"),)
    assert robot_capsules(robot, FeasibilitySettings(robot_capsules=table))[0].name == "arm"
    fitted = robot_capsules(robot, FeasibilitySettings(capsule_margin=0.02))
    assert [c.radius for c in fitted] == pytest.approx([c.radius + 0.02 for c in plain])
    bad = (Capsule([0, 0, 0], [0.6, 0, 0], 0.1, frame="link_9"),)
    with pytest.raises(UnknownLinkError):
        robot_capsules(robot, FeasibilitySettings(robot_capsules=bad))
