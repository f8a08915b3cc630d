"""Several capsules per link: every point of the meshes enclosed, tighter than one capsule,
cached; the model built on them keeps exact first and second derivatives."""

from __future__ import annotations

from functools import cache

import coal
import numpy as np
import pytest

from calib_oed import load_robot
from calib_oed.exceptions import LinkFitSettingsError
from calib_oed.feasibility import FeasibilitySettings
from calib_oed.feasibility.capsules import load_collision_model
from calib_oed.feasibility.link_fit import (
    LinkFitSettings,
    LinkMesh,
    fit_link_capsules,
    fit_robot_links,
    link_meshes,
    slab_points,
)
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.segments import segment_distance
from calib_oed.feasibility.shapes import Cell, HalfSpace


@cache
def fitted(name):
    robot = load_robot(name)
    geom = load_collision_model(robot)
    return robot, geom, fit_robot_links(robot, geom)


def surface_points(mesh_triangles, vertices, rng, per_triangle=2):
    """Random points on every triangle (uniform barycentric), plus the vertices."""
    tri = vertices[mesh_triangles]  # (m, 3, 3)
    u = rng.random((len(tri), per_triangle, 2))
    flip = u.sum(axis=2) > 1.0
    u[flip] = 1.0 - u[flip]
    p = tri[:, None, 0] + u[..., :1] * (tri[:, None, 1] - tri[:, None, 0]) + u[..., 1:] * (tri[:, None, 2] - tri[:, None, 0])
    return np.vstack([p.reshape(-1, 3), vertices])


def link_triangles(robot, geom):
    """Per link, (vertices, triangles) of its meshes in the link frame."""
    from calib_oed.feasibility.link_fit import _triangles

    out = {}
    for go in geom.geometryObjects:
        if not isinstance(go.geometry, coal.BVHModelBase):
            continue  # primitives (a UR10's ee_link box): enclosed as in test_capsules.py
        frame = robot.model.frames[go.parentFrame]
        M = frame.placement.actInv(go.placement)
        v = np.asarray(go.geometry.vertices(), dtype=float) @ M.rotation.T + M.translation
        out.setdefault(frame.name, []).append((v, _triangles(go.geometry)))
    return out


def outside(capsules, pts):
    """Largest excess [m] of points over the union of capsules (<= 0: all inside)."""
    excess = np.full(len(pts), np.inf)
    for c in capsules:
        d = segment_distance(pts, pts, np.broadcast_to(c.a, pts.shape), np.broadcast_to(c.b, pts.shape))
        excess = np.minimum(excess, d - c.radius)
    return float(excess.max())


@pytest.mark.parametrize("name", ["ur10", "panda"])
def test_capsules_enclose_every_point_of_the_meshes(name):
    robot, geom, fits = fitted(name)
    rng = np.random.default_rng(0)
    parts = link_triangles(robot, geom)
    for fit in fits:
        for v, tri in parts.get(fit.link, ()):
            assert outside(fit.capsules, surface_points(tri, v, rng)) <= 1e-9, fit.link


def test_split_links_are_tighter_and_joined():
    robot, geom, fits = fitted("ur10")
    by_link = {f.link: f for f in fits}
    for f in fits:
        assert f.capsule_volume <= f.single_volume * (1 + 1e-9)
        assert [c.name for c in f.capsules] == [f"{f.link}#{k}" for k in range(len(f.capsules))]
    # the long arms of a UR10 are split: a slab more must cut the volume by >= 10 %
    for link in ("upper_arm_link", "forearm_link"):
        f = by_link[link]
        assert len(f.capsules) >= 2
        assert f.capsule_volume <= 0.9 * f.single_volume
        # consecutive capsules overlap (they share the cut's crossing points)
        for c0, c1 in zip(f.capsules[:-1], f.capsules[1:], strict=True):
            gap = segment_distance(c0.a, c0.b, c1.a, c1.b) - c0.radius - c1.radius
            assert gap < 0.0


def test_slab_points_of_a_cube_include_the_cut():
    # unit cube [0, 1]^3 as 12 triangles; cut at z = 0.25
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    edges = np.unique(np.sort(np.vstack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1), axis=0)
    mesh = LinkMesh(v, edges)
    low = slab_points(mesh, np.array([0.0, 0.0, 1.0]), -np.inf, 0.25)
    assert np.all(low[:, 2] <= 0.25 + 1e-15)
    cut = low[np.isclose(low[:, 2], 0.25)]
    # the four vertical edges cross the plane at the square's corners
    for corner in ([0, 0], [0, 1], [1, 0], [1, 1]):
        assert np.any(np.all(np.isclose(cut[:, :2], corner), axis=1))
    assert len(low[low[:, 2] == 0.0]) == 4


def test_robots_without_meshes_keep_one_capsule_per_link():
    robot, geom, fits = fitted("kr16")
    assert all(link_meshes(robot, geom)[f.link] is None for f in fits)
    assert all(not f.meshes and len(f.capsules) == 1 for f in fits)
    # opt-in: one capsule per primitive where that is >= 10 % smaller (kr16's link_1: two cylinders)
    split = {f.link: f for f in fit_robot_links(robot, geom, LinkFitSettings(split_primitives=True))}
    assert len(split["link_1"].capsules) == 2
    for f in split.values():
        assert f.capsule_volume <= f.single_volume * (1 + 1e-9)


def test_fit_is_repeatable_and_settings_are_checked():
    robot, geom, fits = fitted("ur10")
    again = fit_robot_links(robot, geom)  # the same capsules on every call (cached or fitted anew)
    assert [(c.name, c.radius, *c.a, *c.b) for f in again for c in f.capsules] == [
        (c.name, c.radius, *c.a, *c.b) for f in fits for c in f.capsules]
    fat = fit_link_capsules(robot, geom, margin=0.01)
    assert [c.radius for c in fat] == pytest.approx([c.radius + 0.01 for f in fits for c in f.capsules])
    with pytest.raises(LinkFitSettingsError, match="max_capsules = 0: must be an integer >= 1"):
        LinkFitSettings(max_capsules=0)
    with pytest.raises(LinkFitSettingsError, match=r"min_gain = 1.5: must be a fraction in \[0, 1\)"):
        LinkFitSettings(min_gain=1.5)
    with pytest.raises(ValueError, match="capsule margin"):
        fit_link_capsules(robot, geom, margin=-1.0)


@cache
def ur10_model():
    robot = load_robot("ur10")
    cell = Cell(halfspaces=(HalfSpace((0, 0, 1), -0.1, "floor"),))
    capsules = fit_link_capsules(robot, fitted("ur10")[1])
    model, report = build_feasibility_model(robot, cell, FeasibilitySettings(prune_samples=0),
                                            np.array([1.5, -2.6, 0.7]), np.array([[0.0, 0.0, 0.04]]),
                                            capsules=capsules)
    return robot, model, report


def test_multi_capsule_rows_have_exact_jacobian():
    robot, model, _ = ur10_model()
    assert any(name.endswith("#2") for name in model.segments.names)  # several capsules per link
    q = robot.random_configurations(6, 3)
    res = model.compute(q)
    h = 1e-6
    fd = np.empty_like(res.jacobian)
    for k in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[k] = h
        fd[:, :, k] = (model.compute_values(q + dq) - model.compute_values(q - dq)) / (2 * h)
    pair_rows = np.isin(np.array(res.kinds), ["self", "obstacle", "beam"])
    err = np.abs(fd - res.jacobian)[:, pair_rows]
    assert err.max() < 1e-6


def test_multi_capsule_rows_have_exact_curvature():
    robot, model, _ = ur10_model()
    q = robot.random_configurations(4, 5)
    rng = np.random.default_rng(1)
    lam = rng.random((len(q), model.n_constraints))
    hess = model.compute_lagrangian_hessian(q, lam)
    h = 1e-5
    for k in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[k] = h
        jp, jm = model.compute(q + dq).jacobian, model.compute(q - dq).jacobian
        col = np.einsum("nm,nmv->nv", lam, (jp - jm) / (2 * h))
        np.testing.assert_allclose(hess[:, :, k], col, atol=1e-5, rtol=1e-4)
