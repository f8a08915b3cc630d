"""Solid obstacles (boxes, cylinders, meshes): distances against coal, gradients and curvature
against central finite differences, ignore_links, and the per-reflector incidence axis."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import central_difference
from test_constraints import skeleton_capsules

from calib_oed import load_robot
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.pairs import build_feasibility_model
from calib_oed.feasibility.shapes import (
    Box,
    Capsule,
    Cell,
    Cylinder,
    FeasibilitySettings,
    HalfSpace,
    MeshObstacle,
)
from calib_oed.feasibility.solids import COAL, EDGE, END_A, END_B, SolidPairs

ROT = pin.rpy.rpyToMatrix(0.3, -0.2, 0.5)
BOX = Box([0.9, 0.1, 0.5], [0.5, 0.8, 0.4], ROT, "car")
CYL = Cylinder([0.2, 0.9, 0.7], 0.15, 0.8, pin.rpy.rpyToMatrix(0.4, 0.2, 0.0), "column")
OCTA = MeshObstacle(np.array([[0.3, -0.9, 0.8]]) + 0.2 * np.vstack([np.eye(3), -np.eye(3)]), "fixture")
TRACKER = np.array([2.4, -1.6, 1.1])
NORMALS = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, 1.0]])


def box_mesh(box: Box) -> MeshObstacle:
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * box.half
    return MeshObstacle(corners @ box.rotation.T + box.center, box.name)


@pytest.fixture(scope="module")
def kr16():
    return load_robot("kr16")


def model(robot, cell):
    return build_feasibility_model(robot, cell, FeasibilitySettings(), TRACKER,
                                   np.array([[0.0, 0.0, 0.05], [0.03, 0.0, 0.04]]), ["smr0", "smr1"],
                                   capsules=skeleton_capsules(robot), prune=False,
                                   reflector_normals=NORMALS)[0]


@pytest.fixture(scope="module")
def solid_model(kr16):
    return model(kr16, Cell(boxes=(BOX,), cylinders=(CYL,), meshes=(OCTA,)))


def random_segments(rng, n, spread=1.2):
    a = rng.uniform(-spread, spread, size=(n, 3)) + BOX.center
    b = a + rng.normal(scale=0.4, size=(n, 3))
    b[: n // 10] = a[: n // 10]  # some points
    return a, b


def test_box_distance_matches_coal():
    """The closed form (end points and edges) against coal's capsule-box distance, every regime."""
    rng = np.random.default_rng(0)
    a, b = random_segments(rng, 3000)
    sp = SolidPairs(Cell(boxes=(BOX,)), np.array([[0, 0]]), np.array([0.01]))
    w = sp.closest(a, b, np.zeros(len(a), dtype=int))
    assert {END_A, END_B, EDGE, COAL} <= set(w.regime.tolist())
    geom, place = coal.Box(*BOX.size), coal.Transform3s(BOX.rotation, BOX.center)
    for k in range(len(a)):
        res = coal.DistanceResult()
        req = coal.DistanceRequest()
        req.enable_signed_distance = True
        axis = b[k] - a[k]
        length = np.linalg.norm(axis)
        if length < 1e-9:
            shape, rot = coal.Sphere(0.01), np.eye(3)
        else:
            shape = coal.Capsule(0.01, length)
            rot = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), axis / length).matrix()
        d = coal.distance(shape, coal.Transform3s(rot, 0.5 * (a[k] + b[k])), geom, place, req, res)
        assert w.dist[k] - 0.01 == pytest.approx(d, abs=1e-7), w.regime[k]
        # the witness on the axis and the normal reproduce the distance
        x = a[k] + w.s[k] * axis
        if w.regime[k] != COAL:
            y = BOX.rotation.T @ (x - w.dist[k] * w.u[k] - BOX.center)
            assert np.all(np.abs(y) <= BOX.half + 1e-9)


def test_box_mesh_equals_box(kr16):
    """A mesh of the box's 8 corners (coal, convex hull) gives the closed form's rows and gradients."""
    q = kr16.random_configurations(40, 3)
    r_box = model(kr16, Cell(boxes=(BOX,))).compute(q)
    r_mesh = model(kr16, Cell(meshes=(box_mesh(BOX),))).compute(q)
    assert r_box.labels == r_mesh.labels
    rows = np.array(r_box.kinds) != "joint"
    np.testing.assert_allclose(r_mesh.values, r_box.values, atol=1e-7)
    ok = r_box.values[:, rows] > 1e-3  # gradients away from contact
    np.testing.assert_allclose(r_mesh.jacobian[:, rows][ok], r_box.jacobian[:, rows][ok], atol=1e-6)


def solid_row_indices(fm):
    k = len(fm.reflector_names)
    start = 2 * fm.robot.nq + k
    return np.arange(start, start + len(fm.solid_pairs))


#: Relative gradient error against FD: boxes, cylinder sides and segment ends closed form; meshes
#: (polytopes) by coal to rounding; a cylinder's rim seen from inside a segment: coal's GJK
#: witness on a curved surface, ~1e-5 (1.5 m away).
GRADIENT_TOL = {"car": 1e-6, "fixture": 1e-6, "column": 1e-6, "column rim": 1e-4}


def regimes(fm, qk):
    """Witness regime of every solid row at one pose."""
    seg, i = fm.segments, fm.solid_pairs.pairs[:, 0]
    st = compute_body_states(fm.robot.model, qk[None])
    return fm.solid_pairs.closest(st.points(seg.body_a[i], seg.a_local[i])[0],
                                  st.points(seg.body_b[i], seg.b_local[i])[0], np.arange(len(i)))


def test_solid_rows_gradient_matches_finite_differences(kr16, solid_model):
    fm = solid_model
    rows = solid_row_indices(fm)
    kinds = {fm.kinds[r] for r in rows}
    assert kinds == {"obstacle", "beam"}
    q = kr16.random_configurations(12, 5)
    res = fm.compute(q)
    checked, sides, rims = 0, 0, 0
    for k in range(len(q)):
        num = central_difference(lambda x: fm.compute_values(x[None])[0], q[k], eps=1e-6)
        w = regimes(fm, q[k])
        for j, r in enumerate(rows):
            if res.values[k, r] > -0.015:  # not deep inside (EPA depth is not smooth to 1e-6)
                err = np.abs(res.jacobian[k, r] - num[r]).max() / max(np.abs(num[r]).max(), 1e-3)
                name = fm.labels[r].split("|")[1]
                sides += name == "column" and w.regime[j] == EDGE
                rim = name == "column" and w.regime[j] == COAL and 0.0 < w.s[j] < 1.0
                rims += rim
                assert err < GRADIENT_TOL[name + (" rim" if rim else "")], fm.labels[r]
                checked += 1
        assert np.abs(res.jacobian[k, :rows[0]] - num[:rows[0]]).max() < 1e-6  # incidence with normals
    assert checked > 0.8 * len(q) * len(rows) and sides > 10 and rims < 0.3 * checked


def fd_row_hessian(fm, q, row):
    """Central differences of the gradients of rows ``row`` (an index or an array) at one pose."""
    def grad(x):
        return fm.compute_from_states(x[None], compute_body_states(fm.robot.model, x[None])).jacobian[0, row]
    return central_difference(grad, q, eps=1e-6)


def row_hessians(fm, qk, rows):
    """Analytic Hessians (R, nq, nq) of rows ``rows`` at one pose: the pose repeated, one-hot multipliers."""
    lam = np.zeros((len(rows), fm.n_constraints))
    lam[np.arange(len(rows)), rows] = 1.0
    return fm.compute_lagrangian_hessian(np.repeat(qk[None], len(rows), axis=0), lam)


def test_box_and_cylinder_side_curvature_is_exact(kr16):
    """Box rows (end point: face/edge/vertex; edge) and cylinder sides: Hessian against FD of the gradient."""
    fm = model(kr16, Cell(boxes=(BOX,), cylinders=(CYL,)))
    rows = solid_row_indices(fm)
    q = kr16.random_configurations(8, 8)
    seen = set()
    for k in range(len(q)):
        w = regimes(fm, q[k])
        hess, num = row_hessians(fm, q[k], rows), fd_row_hessian(fm, q[k], rows)
        for j, r in enumerate(rows):
            if w.regime[j] == COAL or w.dist[j] < 1e-3:
                continue
            err = np.abs(hess[j] - num[j]).max() / max(np.abs(num[j]).max(), 1e-9)
            assert err < 1e-5, (fm.labels[r], w.regime[j])
            seen.add((fm.labels[r].split("|")[1], int(w.regime[j]), int(w.mask[j].sum())))
    assert {("car", EDGE, 0), ("column", EDGE, 0)} <= seen, seen
    assert ("car", END_A, 1) in seen or ("car", END_B, 1) in seen, seen


def test_coal_curvature_is_the_tangent_plane_model(kr16):
    """Mesh rows (coal): at a face witness from a segment end the tangent-plane Hessian is the exact
    one (equal to the closed-form box's, itself checked by FD); elsewhere symmetric and finite."""
    q = kr16.random_configurations(30, 9)
    fb = model(kr16, Cell(boxes=(BOX,)))
    fmesh = model(kr16, Cell(meshes=(box_mesh(BOX),)))
    rows = solid_row_indices(fb)
    compared = 0
    for k in range(len(q)):
        w = regimes(fb, q[k])
        for j, r in enumerate(rows):
            lam = np.zeros((1, fb.n_constraints))
            lam[0, r] = 1.0
            h_mesh = fmesh.compute_lagrangian_hessian(q[k:k + 1], lam)[0]
            assert np.all(np.isfinite(h_mesh))
            np.testing.assert_allclose(h_mesh, h_mesh.T, atol=1e-12)
            if w.regime[j] in (END_A, END_B) and w.mask[j].sum() == 1 and w.dist[j] > 1e-3:
                h_box = fb.compute_lagrangian_hessian(q[k:k + 1], lam)[0]
                np.testing.assert_allclose(h_mesh, h_box, atol=1e-6 * max(np.abs(h_box).max(), 1e-3))
                compared += 1
    assert compared >= 10


def test_ignore_links(kr16):
    """An obstacle's ignore_links drop its rows for those links, and only those."""
    link = "link_3"
    caps = skeleton_capsules(kr16)
    assert link in {c.frame for c in caps}
    ignore = (link,)
    cell = Cell(capsules=(Capsule([1.0, 0, 0], [1.0, 0.2, 0], 0.1, None, "post", ignore),),
                halfspaces=(HalfSpace([0, 0, 1], -0.3, "floor", ignore),),
                boxes=(Box(BOX.center, BOX.size, BOX.rotation, "car", ignore),))
    fm = model(kr16, cell)
    obstacle_labels = [lbl for lbl, kind in zip(fm.labels, fm.kinds, strict=True) if kind == "obstacle"]
    for name in ("post", "floor", "car"):
        mine = [lbl for lbl in obstacle_labels if lbl.endswith(f"|{name}")]
        assert mine and not any(f"{link}#" in lbl for lbl in mine)
        assert any("link_2#" in lbl for lbl in mine)


def test_incidence_uses_the_reflector_normal(kr16, solid_model):
    """The incidence row is n_W . u - cos(limit), n_W the reflector's normal placed by pinocchio."""
    fm = solid_model
    q = kr16.random_configurations(6, 2)
    vals = fm.compute_values(q)
    data = kr16.model.createData()
    limit = fm.settings.incidence_limit - fm.settings.margins.incidence
    for k, qk in enumerate(q):
        pin.framesForwardKinematics(kr16.model, data, qk)
        tool = data.oMf[kr16.tool_frame_id]
        for j, (offset, normal) in enumerate(zip(fm.reflector_offsets, NORMALS, strict=True)):
            c = tool.act(offset)
            u = (TRACKER - c) / np.linalg.norm(TRACKER - c)
            n_w = tool.rotation @ (normal / np.linalg.norm(normal))
            assert vals[k, 2 * kr16.nq + j] == pytest.approx(n_w @ u - np.cos(limit), abs=1e-12)


def test_incidence_curvature_with_normal(kr16, solid_model):
    fm = solid_model
    q = kr16.random_configurations(3, 4)
    for k in range(len(q)):
        for j in range(2):
            r = 2 * kr16.nq + j
            lam = np.zeros((1, fm.n_constraints))
            lam[0, r] = 1.0
            hess = fm.compute_lagrangian_hessian(q[k:k + 1], lam)[0]
            num = fd_row_hessian(fm, q[k], r)
            assert np.abs(hess - num).max() / np.abs(num).max() < 1e-5


def test_records_validate():
    with pytest.raises(ValueError, match="size must be > 0"):
        Box([0, 0, 0], [1, 0, 1])
    with pytest.raises(ValueError, match="rotation matrix"):
        Box([0, 0, 0], [1, 1, 1], 2 * np.eye(3))
    with pytest.raises(ValueError, match="flat"):
        MeshObstacle(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]))
    with pytest.raises(ValueError, match="radius must be > 0"):
        Cylinder([0, 0, 0], 0.0, 1.0)


def test_mesh_check_sees_solids_and_ignore_links(kr16):
    """The independent mesh check: a box around the tool at q = 0 collides with the wrist links,
    the beam is checked against it, and its ignore_links drop exactly the named link's pairs."""
    from calib_oed.feasibility.mesh_check import check_design_meshes

    q = np.zeros((1, kr16.nq))
    data = kr16.model.createData()
    pin.framesForwardKinematics(kr16.model, data, q[0])
    tool = data.oMf[kr16.tool_frame_id].translation
    around = Box(tool, [0.3, 0.3, 0.3], np.eye(3), "crate")
    far = MeshObstacle(box_mesh(Box([0.0, 3.0, 0.5], [0.2, 0.2, 0.2])).vertices, "far")
    report = check_design_meshes(kr16, q, Cell(boxes=(around,), meshes=(far,)),
                                 tracker_position=TRACKER, reflector_offsets=np.array([0.0, 0.0, 0.05]))
    crate = {a: d for (a, b), d in zip(report.pairs, report.distances[0], strict=True) if b == "crate"}
    assert crate["link_6"] < 0 and crate["beam#0"] < 0
    assert min(d for (a, b), d in zip(report.pairs, report.distances[0], strict=True) if b == "far") > 1.0
    ignoring = Box(tool, [0.3, 0.3, 0.3], np.eye(3), "crate", ("link_6",))
    names = {p for p in check_design_meshes(kr16, q, Cell(boxes=(ignoring,))).pairs if p[1] == "crate"}
    assert ("link_6", "crate") not in names and ("link_5", "crate") in names


def test_pruning_drops_far_solids_only(kr16):
    """The sampling pass drops a solid no pose comes near, keeps the others, and reports the drop."""
    far = Box([0.0, 6.0, 0.5], [0.2, 0.2, 0.2], np.eye(3), "far")
    cell = Cell(boxes=(BOX, far))
    args = (kr16, cell, FeasibilitySettings(prune_samples=300), TRACKER, np.array([[0.0, 0.0, 0.05]]), ["smr0"])
    pruned, report = build_feasibility_model(*args, capsules=skeleton_capsules(kr16))
    full, _ = build_feasibility_model(*args, capsules=skeleton_capsules(kr16), prune=False)
    assert not any(lbl.endswith("|far") for lbl in pruned.labels)
    assert any(lbl.endswith("|car") for lbl in pruned.labels)
    far_drops = [d for d in report.dropped if d.label.endswith("|far")]
    assert far_drops and all(d.reason.startswith("never closer than") and d.min_clearance > 0.1 for d in far_drops)
    q = kr16.random_configurations(20, 6)
    v_full, v_pruned = full.compute_values(q), pruned.compute_values(q)
    index = {lbl: k for k, lbl in enumerate(full.labels)}
    for k, lbl in enumerate(pruned.labels):
        np.testing.assert_allclose(v_pruned[:, k], v_full[:, index[lbl]], atol=1e-12)
