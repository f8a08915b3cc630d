"""Self rows on convex pieces of the link geometry: enclosure, values against coal on the meshes,
exact gradients and the documented curvature model against central differences, pair selection."""

from __future__ import annotations

from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference

import calib_oed
from calib_oed import load_robot, load_scene
from calib_oed.feasibility import FeasibilitySettings
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.capsules import fit_capsules, load_collision_model
from calib_oed.feasibility.hulls import HullPairs, link_pieces
from calib_oed.feasibility.link_fit import link_meshes
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.shapes import Cell

#: UR10 pairs of every kind: 2 joints apart (a housing at 11-21 mm), 2 apart (the wrist), 3 apart.
UR10_PAIRS = (("base_link", "upper_arm_link"), ("forearm_link", "wrist_2_link"), ("upper_arm_link", "wrist_2_link"))


@pytest.fixture(scope="module")
def ur10():
    robot = load_robot("ur10")
    geom = load_collision_model(robot)
    return robot, geom, HullPairs(link_pieces(robot, geom), UR10_PAIRS)


def test_pieces_enclose_every_vertex_of_the_meshes(ur10):
    """Every mesh vertex of a link lies in one of its pieces (coal: a point's signed distance <= 0)."""
    robot, geom, _ = ur10
    pieces = link_pieces(robot, geom)
    point, req = coal.Sphere(1e-9), coal.DistanceRequest()
    req.enable_signed_distance = True
    for link, mesh in link_meshes(robot, geom).items():
        if mesh is None:
            continue
        lp = pieces[link]
        F = robot.model.frames[robot.model.getFrameId(link, pin.FrameType.BODY)].placement
        verts = mesh.vertices[:: max(1, len(mesh.vertices) // 400)] @ F.rotation.T + F.translation
        for v in verts:
            d = min(coal.distance(point, coal.Transform3s(np.eye(3), v), s, coal.Transform3s(R, t), req,
                                  coal.DistanceResult())
                    for s, R, t in zip(lp.shapes, lp.rotation, lp.translation, strict=True))
            assert d <= 1e-6, (link, v, d)


def test_distance_never_exceeds_the_mesh_distance(ur10):
    """The pieces enclose the meshes: their distance is at most the meshes' (coal), and close to it."""
    robot, geom, hp = ur10
    q = robot.random_configurations(60, 3)
    dist = hp.closest(compute_body_states(robot.model, q, jacobian=False)).dist
    data, gdata = robot.model.createData(), pin.GeometryData(geom)
    names = [robot.model.frames[go.parentFrame].name for go in geom.geometryObjects]
    req = coal.DistanceRequest()
    gap = []
    for k, qk in enumerate(q):
        pin.updateGeometryPlacements(robot.model, data, geom, gdata, qk)
        for h, (la, lb) in enumerate(UR10_PAIRS):
            mesh = min(coal.distance(geom.geometryObjects[i].geometry, gdata.oMg[i],
                                     geom.geometryObjects[j].geometry, gdata.oMg[j], req, coal.DistanceResult())
                       for i in range(len(names)) if names[i] == la for j in range(len(names)) if names[j] == lb)
            if mesh > 0:
                assert dist[k, h] <= mesh + 1e-6
                gap.append(mesh - dist[k, h])
    assert np.median(gap) < 0.01  # tight: a centimetre at most, typically (4 slabs per link)


def test_rows_have_the_exact_gradient(ur10):
    """Jacobian (envelope theorem, coal's witnesses) against central differences of the values,
    at poses where the closest piece pair does not switch within the step."""
    robot, geom, hp = ur10
    clearance = 0.010
    checked = 0
    for q in robot.random_configurations(12, 5):
        states = compute_body_states(robot.model, q[None])
        values, jac = hp.rows(states, clearance, jacobian=True)

        def fun(x):
            return hp.rows(compute_body_states(robot.model, x[None], jacobian=False), clearance, False)[0][0]

        num = central_difference(fun, q, eps=1e-6)
        second = central_difference(fun, q, eps=2e-6)
        smooth = np.abs(num - second).max(axis=1) < 1e-6  # no switch of witness feature within the step
        np.testing.assert_allclose(jac[0][smooth], num[smooth], rtol=0, atol=2e-6)
        checked += int(smooth.sum())
    assert checked >= 30


def model_gradient(robot, local, u):
    r"""The gradient of :math:`\varphi(q) = u^\top(w_a(q) - w_b(q))`, ``local`` = ((body, point in it), ...)."""
    def grad(x):
        st = compute_body_states(robot.model, x[None])
        out = 0.0
        for sign, (body, loc) in zip((1.0, -1.0), local, strict=True):
            p = st.points(np.array([body]), loc[None])
            out = out + sign * st.directional_jacobian(np.array([body]), p, u[None, None])[0, 0]
        return out
    return grad


def test_curvature_is_the_hessian_of_the_tangent_plane_model(ur10):
    r"""The documented model: witness points fixed on their bodies, normal u fixed:
    :math:`\varphi(q) = u^\top(w_a(q) - w_b(q))`; its Hessian by central differences of its gradient."""
    robot, geom, hp = ur10
    q0 = robot.random_configurations(3, 7)
    states = compute_body_states(robot.model, q0)
    w = hp.closest(states)
    for k in range(3):
        for h in range(len(hp)):
            hess = hp.hessians(states, np.array([k]), np.array([h]))[0]
            local = [(body, (x - states.translation[k, body]) @ states.rotation[k, body])
                     for body, x in ((hp.body_a[h], w.wa[k, h]), (hp.body_b[h], w.wb[k, h]))]
            num = central_difference(model_gradient(robot, local, w.u[k, h]), q0[k], eps=1e-6)
            scale = max(np.abs(num).max(), 1e-9)
            assert np.abs(hess - num).max() / scale < 1e-6
            np.testing.assert_allclose(hess, hess.T, atol=1e-12 * scale)


def test_link_fit_hulls_checks_near_pairs_on_pieces(ur10):
    """link_fit: hulls gives one row per near link pair; no capsule row of those pairs remains, and
    the row values are those of HullPairs."""
    robot, _, _ = ur10
    settings = FeasibilitySettings(link_fit="hulls", prune_samples=300)
    fm, report = build_feasibility_model(robot, Cell(), settings, np.array([0.5, -2.0, 0.8]),
                                         np.array([[0.0, 0.0, 0.04]]), capsules=fit_capsules(robot),
                                         mesh_pairs=False, hulls=True)  # one capsule per link: quicker
    assert ("forearm_link", "wrist_2_link") in fm.hull_pairs.link_pairs
    near = {frozenset(p) for p in fm.hull_pairs.link_pairs}
    seg = fm.segments
    for i, j in fm.pairs:
        assert frozenset((seg.links[i], seg.links[j])) not in near or "reflector" in (seg.roles[i], seg.roles[j])
    assert any("checked on convex pieces" in d.reason for d in report.dropped)
    q = robot.random_configurations(5, 1)
    res = fm.compute(q)
    rows = np.isin(np.array(res.labels), fm.hull_pairs.labels)
    expect = fm.hull_pairs.rows(compute_body_states(robot.model, q), 0.010, False)[0]
    np.testing.assert_allclose(res.values[:, rows], expect, rtol=0, atol=1e-12)
    # the Lagrangian Hessian routes these rows to the tangent-plane model, the others as before
    lam = np.zeros((5, fm.n_constraints))
    lam[:, np.flatnonzero(rows)] = np.random.default_rng(0).normal(size=(5, rows.sum()))
    states = compute_body_states(robot.model, q)
    expect = np.zeros((5, robot.nq, robot.nq))
    for k in range(5):
        for h in range(len(fm.hull_pairs)):
            expect[k] += lam[k, np.flatnonzero(rows)[h]] * fm.hull_pairs.hessians(states, [k], [h])[0]
    np.testing.assert_allclose(fm.compute_lagrangian_hessian(q, lam), expect, rtol=1e-12, atol=1e-14)
    lam[:, ~rows] = 1.0  # with every other row too: the hull part is added to theirs
    rest = lam.copy()
    rest[:, rows] = 0.0
    np.testing.assert_allclose(fm.compute_lagrangian_hessian(q, lam),
                               fm.compute_lagrangian_hessian(q, rest) + expect, rtol=1e-10, atol=1e-12)


def test_pairs_the_capsules_never_separate_fall_back_to_pieces():
    """The default fit: a UR10's base_link/upper_arm_link capsules are never 10 mm apart (its shoulder
    motor), the pieces of the meshes are (11-21 mm): the pair is checked on the pieces, and sampling works."""
    scene = load_scene("ur5_table")
    robot = load_robot("ur10")
    fm, report = build_feasibility_model(robot, scene.cell, FeasibilitySettings(prune_samples=500),
                                         np.array([1.5, -2.5, 1.0]), np.array([[0.0, 0.0, 0.04]]))
    assert ("base_link", "upper_arm_link") in fm.hull_pairs.link_pairs
    reason = next(d.reason for d in report.dropped if d.label.startswith("self:base_link#0|upper_arm_link#0"))
    assert "never separated by the 10 mm margin" in reason


def test_scene_key_link_fit_hulls():
    """`feasibility: {link_fit: hulls}` is read; a wrong name is an error listing the choices."""
    import yaml

    from calib_oed.exceptions import CalibOedError
    from calib_oed.scene.reader import scene_from_dict

    path = Path(calib_oed.__file__).parent / "scene" / "shipped" / "fms_kr16.yaml"
    spec = yaml.safe_load(path.read_text())
    spec.setdefault("feasibility", {})["link_fit"] = "hulls"
    assert scene_from_dict(spec, str(path)).feasibility.link_fit == "hulls"
    spec["feasibility"]["link_fit"] = "hull"
    with pytest.raises((CalibOedError, ValueError), match="hulls"):
        scene_from_dict(spec, str(path))
