"""Self rows on convex pieces of the link geometry: enclosure, values against coal on the meshes,
exact gradients and the documented curvature model against central differences, pair selection."""

from __future__ import annotations

from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference, smooth_difference

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


def test_witness_normals_are_each_rows_own_arithmetic(ur10):
    """The batched unit normals are, bit for bit, those of one row at a time: the gap of the
    witnesses over its own dot product's root (the arithmetic the designs were computed with)."""
    robot, _, hp = ur10
    q = robot.random_configurations(120, 5)
    w = hp.closest(compute_body_states(robot.model, q, jacobian=False))
    checked = 0
    for k, h in zip(*np.nonzero(w.dist > 0.0), strict=True):
        gap = w.wa[k, h] - w.wb[k, h]
        norm = float(np.sqrt(gap @ gap))
        if norm > 1e-9:
            assert w.u[k, h].tobytes() == (gap / norm).tobytes(), (k, h)
            checked += 1
    assert checked > 100
    assert np.allclose(np.linalg.norm(w.u[w.piece_a >= 0], axis=1), 1.0)


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
            hess = hp.hessians(states, np.array([k]), np.array([h]), exact=False)[0]
            local = [(body, (x - states.translation[k, body]) @ states.rotation[k, body])
                     for body, x in ((hp.body_a[h], w.wa[k, h]), (hp.body_b[h], w.wb[k, h]))]
            num = central_difference(model_gradient(robot, local, w.u[k, h]), q0[k], eps=1e-6)
            scale = max(np.abs(num).max(), 1e-9)
            assert np.abs(hess - num).max() / scale < 1e-6
            np.testing.assert_allclose(hess, hess.T, atol=1e-12 * scale)


def assert_exact_curvature(robot, hp, q, min_exact):
    """The rows' Hessians (hessians: exact for the closest features) against central differences
    of their analytic gradients, where two step sizes agree (no feature switch within the step).
    The gradient rests on coal's witness points (to ~1e-9 m): the differences carry ~1e-7 m/rad^2
    of noise, so the bound is 1e-6 of the largest entry, but at least of 1 m/rad^2."""
    exact = model = 0
    for qk in q:
        states = compute_body_states(robot.model, qk[None])
        for h in range(len(hp)):
            def grad(x, h=h):
                return hp.rows(compute_body_states(robot.model, x[None]), 0.010, True)[1][0, h]
            num, smooth = smooth_difference(grad, qk)
            before = hp.curvature["exact"]
            hess = hp.hessians(states, [0], [h])[0]
            if hp.curvature["exact"] == before:
                model += 1
                continue
            exact += 1
            if smooth.all():
                scale = max(np.abs(num).max(), 1.0)
                assert np.abs(hess - num).max() <= 1e-6 * scale, (hp.link_pairs[h], np.abs(hess - num).max())
                np.testing.assert_allclose(hess, hess.T, atol=1e-12 * scale)
    assert exact >= min_exact * (exact + model), (exact, model)
    return exact, model


def test_curvature_is_exact_for_the_closest_features(ur10):
    """UR10 (convex hulls of mesh slabs): vertex, edge and face features; the tangent-plane model
    it replaces is off by more than 10 % of the largest entry on most rows."""
    robot, _, hp = ur10
    q = robot.random_configurations(6, 3)
    assert_exact_curvature(robot, hp, q, 0.8)
    states = compute_body_states(robot.model, q)
    pose, rows = np.repeat(np.arange(6), len(hp)), np.tile(np.arange(len(hp)), 6)
    exact, model = hp.hessians(states, pose, rows), hp.hessians(states, pose, rows, exact=False)
    off = np.abs(exact - model).max(axis=(1, 2)) / np.abs(exact).max(axis=(1, 2))
    assert np.mean(off > 0.1) > 0.5


def second_difference(fun, x, h):
    """The Hessian of a scalar ``fun`` by central second differences of its values, step ``h``."""
    e = np.eye(x.size) * h
    out = np.zeros((x.size, x.size))
    for i in range(x.size):
        for j in range(i, x.size):
            out[i, j] = out[j, i] = (fun(x + e[i] + e[j]) - fun(x + e[i] - e[j]) - fun(x - e[i] + e[j])
                                     + fun(x - e[i] - e[j])) / (4 * h * h)
    return out


def test_curvature_on_primitives():
    """kr16's pieces are URDF cylinders and a sphere: a sphere, a cylinder's side (its axis, rounded),
    cap (a face) and rim (a circle) are exact. On curved pieces coal's witness points carry ~1e-7 m
    (GJK's duality gap), too much for differences of the gradient: the reference is second
    differences of the row values (step 3e-4; skipped where 6e-4 differs by more than the bound: a
    feature switch within the steps), 1e-5 of
    the largest entry but at least of 1 m/rad^2 (measured: 2e-6 at most)."""
    robot = load_robot("kr16")
    pairs = (("link_1", "link_4"), ("link_2", "link_4"), ("link_2", "link_5"), ("link_4", "link_6"),
             ("base_link", "link_2"), ("link_1", "link_3"), ("link_3", "link_6"))
    hp = HullPairs(link_pieces(robot, load_collision_model(robot)), pairs)
    checked = 0
    for qk in robot.random_configurations(4, 3):
        states = compute_body_states(robot.model, qk[None])
        for h in range(len(hp)):
            before = hp.curvature["exact"]
            hess = hp.hessians(states, [0], [h])[0]
            if hp.curvature["exact"] == before:
                continue

            def value(x, h=h):
                return hp.closest(compute_body_states(robot.model, x[None], jacobian=False), [h]).dist[0, 0]

            ref, wide = second_difference(value, qk, 3e-4), second_difference(value, qk, 6e-4)
            scale = max(np.abs(ref).max(), 1.0)
            if np.abs(ref - wide).max() > 1e-5 * scale:
                continue  # a feature switch within the steps
            assert np.abs(hess - ref).max() <= 1e-5 * scale, (hp.link_pairs[h], np.abs(hess - ref).max())
            checked += 1
    assert hp.curvature["exact"] >= 0.9 * (hp.curvature["exact"] + hp.curvature["model"]) and checked >= 20


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


@pytest.mark.parametrize("fit", ["single", "hulls"])
def test_pairs_the_capsules_never_separate_fall_back_to_pieces(fit):
    """One capsule per link (``link_fit: single``): a UR10's base_link/upper_arm_link capsules are never
    10 mm apart (its shoulder motor), the pieces of the meshes are (11-21 mm): the pair is checked on
    the pieces. With the default (hulls) it is on the pieces anyway, as a near pair."""
    scene = load_scene("ur5_table")
    robot = load_robot("ur10")
    fm, report = build_feasibility_model(robot, scene.cell, FeasibilitySettings(prune_samples=500, link_fit=fit),
                                         np.array([1.5, -2.5, 1.0]), np.array([[0.0, 0.0, 0.04]]))
    assert ("base_link", "upper_arm_link") in fm.hull_pairs.link_pairs
    reason = next(d.reason for d in report.dropped if d.label.startswith("self:base_link#0|upper_arm_link#"))
    assert reason.startswith("checked on convex pieces of the link geometry")
    if fit == "single":
        assert "never separated by the 10 mm margin" in reason
    else:
        assert reason.endswith("links 2 joints apart")
    assert not any(lbl.startswith("self:base_link#") and "|upper_arm_link#" in lbl for lbl in fm.labels)


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


def test_a_failed_coal_call_is_repeated_with_the_defaults(monkeypatch):
    """Curved pieces (kr16's cylinders) use a tight duality-gap request; a result of exactly 0, below
    the capsule lower bound or beyond GJK_FAILED (coal's -DBL_MAX) is a failed call, repeated with
    coal's defaults: the values are those of a model whose every call succeeds."""
    from calib_oed.feasibility import hulls

    scene = load_scene("fms_kr16")
    robot = scene.robot
    pairs = (("link_1", "link_4"), ("link_2", "link_5"))
    hp = HullPairs(link_pieces(robot, load_collision_model(robot)), pairs)
    states = compute_body_states(robot.model, robot.random_configurations(4, 2), jacobian=False)
    expect = hp.closest(states)
    assert hp.fallbacks == 0
    real = coal.distance
    calls = {"n": 0}

    def flaky(s1, t1, s2, t2, request, result):
        calls["n"] += 1
        d = real(s1, t1, s2, t2, request, result)
        if request is hp._request:  # the tight request fails every other call, in the three ways
            return (0.0, -np.finfo(float).max, -1.0, d)[calls["n"] % 4]
        return d

    monkeypatch.setattr(hulls.coal, "distance", flaky)
    hp = HullPairs(hp.pieces, hp.link_pairs)  # a model of its own: no witnesses in its memo
    got = hp.closest(states)
    assert hp.fallbacks >= 3
    np.testing.assert_allclose(got.dist, expect.dist, rtol=0, atol=1e-5)  # default criterion: ~1e-6 m
    assert np.all(np.isfinite(got.u)) and np.allclose(np.linalg.norm(got.u, axis=2), 1.0)
