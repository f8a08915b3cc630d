"""Second derivatives of the feasibility rows (the Lagrangian Hessian blocks) against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference
from test_constraints import model_for

from calib_oed import load_scene
from calib_oed.exceptions import ShapeError
from calib_oed.feasibility.bodies import compute_body_states
from calib_oed.feasibility.constraints import KINDS
from calib_oed.feasibility.curvature import (
    body_points,
    point_hessian,
    point_hessian_along,
    segment_distance_derivatives,
)
from calib_oed.feasibility.pairs import feasibility_from_scene
from calib_oed.feasibility.segments import closest_parameters, segment_distance

#: Relative error allowed against central differences of the gradient (step 1e-6).
TOL = 1e-6


def fd_hessian(fm, q, lam, kinds=KINDS):
    """Central differences of sum_i lam_i grad g_i at one pose q (nq,), lam (m_kinds,)."""
    def grad(x):
        return lam @ fm.compute_from_states(x[None], compute_body_states(fm.robot.model, x[None]),
                                            kinds=kinds).jacobian[0]
    return central_difference(grad, q, eps=1e-6)


def hull_rows(fm) -> np.ndarray:
    """Boolean (m,): the rows on convex pieces (their curvature is the tangent-plane model)."""
    return np.isin(np.array(fm.labels), fm.hull_pairs.labels)


def assert_matches(hess, num):
    scale = max(np.abs(num).max(), 1e-12)
    assert np.abs(hess - num).max() / scale < TOL
    np.testing.assert_allclose(hess, np.swapaxes(hess, -1, -2), rtol=0, atol=1e-12 * scale)


@pytest.fixture(scope="module", params=["fms_kr16", "ur5_table"])
def scene_model(request):
    scene = load_scene(request.param)
    return scene, feasibility_from_scene(scene)[0]


@pytest.mark.parametrize("kind", KINDS)
def test_lagrangian_hessian_matches_finite_differences(scene_model, kind):
    """Each row kind on the shipped scenes: random multipliers (some zero) at random poses."""
    scene, fm = scene_model
    q = scene.robot.random_configurations(5, 21)
    rng = np.random.default_rng(4)
    rows = (np.array(fm.kinds) == kind) & ~hull_rows(fm)  # convex-piece rows: a model, test_hulls.py
    lam = np.zeros((5, fm.n_constraints))
    lam[:, rows] = rng.normal(size=(5, rows.sum())) * (rng.uniform(size=(5, rows.sum())) < 0.7)
    hess = fm.compute_lagrangian_hessian(q, lam)
    assert hess.shape == (5, fm.robot.nq, fm.robot.nq)
    if kind == "joint":
        assert not hess.any()
        return
    for j in range(5):
        assert_matches(hess[j], fd_hessian(fm, q[j], lam[j]))


def pair_regimes(fm, q):
    """Which closest-point parameters are free, per pose and capsule pair: a set of (free s, free t)."""
    states = compute_body_states(fm.robot.model, q)
    seg, n = fm.segments, q.shape[0]
    pose = np.repeat(np.arange(n), len(fm.pairs))
    i, j = np.tile(fm.pairs[:, 0], n), np.tile(fm.pairs[:, 1], n)
    ends = [body_points(states, pose, body[k], local[k])
            for k in (i, j) for body, local in ((seg.body_a, seg.a_local), (seg.body_b, seg.b_local))]
    pts, jac = (np.stack([e[m] for e in ends], axis=1) for m in (0, 1))
    nv = jac.shape[-1]
    free = segment_distance_derivatives(pts, jac, lambda u: np.zeros((len(u), 4, nv, nv)))[3]
    return set(map(tuple, free.tolist()))


def test_lagrangian_hessian_on_skeleton_models(robot):
    """ur5, panda, kr16 with every candidate pair, two reflectors, a floor and a wall: all rows at once,
    every witness regime (interior-interior, either parameter clamped, both clamped) among the pairs."""
    fm, _ = model_for(robot)
    q = robot.random_configurations(4, 8)
    assert pair_regimes(fm, q) == {(True, True), (True, False), (False, True), (False, False)}
    lam = np.random.default_rng(2).normal(size=(4, fm.n_constraints))
    hess = fm.compute_lagrangian_hessian(q, lam)
    for j in range(4):
        assert_matches(hess[j], fd_hessian(fm, q[j], lam[j]))


@pytest.mark.parametrize("kinds", [("incidence", "self", "obstacle", "beam"), ("self",), ("beam", "incidence")])
def test_lagrangian_hessian_follows_the_row_order_of_kinds(kinds):
    scene = load_scene("fms_kr16")
    fm, _ = feasibility_from_scene(scene)
    q = scene.robot.random_configurations(3, 5)
    states = compute_body_states(fm.robot.model, q)
    res = fm.compute_from_states(q, states, kinds=kinds)
    m = int(fm.row_mask(kinds).sum())
    assert res.values.shape == (3, m) and res.jacobian.shape == (3, m, fm.robot.nq) and len(res.labels) == m
    full = fm.compute(q)
    np.testing.assert_array_equal(res.values, full.values[:, fm.row_mask(kinds)])
    lam = np.random.default_rng(0).normal(size=(3, m))
    hess = fm.compute_lagrangian_hessian(q, lam, kinds=kinds, states=states)
    lam_full = np.zeros((3, fm.n_constraints))
    lam_full[:, fm.row_mask(kinds)] = lam
    np.testing.assert_allclose(hess, fm.compute_lagrangian_hessian(q, lam_full), rtol=0, atol=1e-13)
    # rows on convex pieces: the tangent-plane model (test_hulls.py), added in their place in the row
    # order; every other row: exact, against central differences
    hull = hull_rows(fm)[fm.row_mask(kinds)]
    assert hull.any() == ("self" in kinds)
    exact = np.where(hull, 0.0, lam)
    model = np.zeros_like(hess)
    hull_index = {lbl: h for h, lbl in enumerate(fm.hull_pairs.labels)}
    for j in range(3):
        for r in np.flatnonzero(hull):
            model[j] += lam[j, r] * fm.hull_pairs.hessians(states, [j], [hull_index[res.labels[r]]])[0]
    np.testing.assert_allclose(hess, fm.compute_lagrangian_hessian(q, exact, kinds=kinds, states=states) + model,
                               rtol=1e-12, atol=1e-12)
    for j in range(3):
        assert_matches(hess[j] - model[j], fd_hessian(fm, q[j], exact[j], kinds))
    with pytest.raises(ShapeError, match="lam"):
        fm.compute_lagrangian_hessian(q, lam[:, 1:], kinds=kinds)


def test_zero_multipliers_and_independent_poses():
    scene = load_scene("fms_kr16")
    fm, _ = feasibility_from_scene(scene)
    q = scene.robot.random_configurations(4, 6)
    assert not fm.compute_lagrangian_hessian(q, np.zeros((4, fm.n_constraints))).any()
    lam = np.zeros((4, fm.n_constraints))
    lam[2, 2 * fm.robot.nq:] = 1.0  # only pose 2
    hess = fm.compute_lagrangian_hessian(q, lam)
    assert not hess[[0, 1, 3]].any() and hess[2].any()
    np.testing.assert_allclose(hess[2], fm.compute_lagrangian_hessian(q[2:3], lam[2:3])[0], atol=1e-13)


def test_point_hessian_matches_finite_differences(robot):
    """Second derivative of a point fixed on each body, and its contraction with a direction."""
    model = robot.model
    q = robot.random_configurations(1, 3)[0]
    nb = model.njoints
    body = np.arange(nb)
    local = np.random.default_rng(5).normal(scale=0.2, size=(nb, 3))
    pose = np.zeros(nb, dtype=int)

    def jac(x):
        return body_points(compute_body_states(model, x[None]), pose, body, local)[1]

    _, jx, omega = body_points(compute_body_states(model, q[None]), pose, body, local)
    hess = point_hessian(omega, jx)
    num = central_difference(jac, q)  # (nb, 3, nv, nv): d/dq_k of column v
    assert np.abs(hess - num).max() < TOL * np.abs(num).max()
    u = np.random.default_rng(6).normal(size=(nb, 3))
    np.testing.assert_allclose(point_hessian_along(omega, jx, u), np.einsum("ki,kivw->kvw", u, hess), atol=1e-14)


# ---------------------------------------------------------------- hand-built segments
class QuadraticSegments:
    """End points a1, b1, a2, b2 as quadratic functions of q (4,): p0 + A q + B[q, q]/2."""

    def __init__(self, p0, seed, nv=4, scale=0.2):
        rng = np.random.default_rng(seed)
        self.p0 = np.asarray(p0, dtype=float)
        self.lin = rng.normal(scale=scale, size=(4, 3, nv))
        b = rng.normal(scale=scale, size=(4, 3, nv, nv))
        self.quad = (b + np.swapaxes(b, -1, -2)) / 2

    def points(self, q):
        return self.p0 + self.lin @ q + 0.5 * np.einsum("pivw,v,w->pi", self.quad, q, q)

    def derivatives(self, q):
        pts = self.points(q)[None]
        jac = (self.lin + self.quad @ q)[None]
        return segment_distance_derivatives(pts, jac, lambda u: np.einsum("ki,pivw->kpvw", u, self.quad))

    def distance(self, q):
        return segment_distance(*self.points(q))


HORIZONTAL = [[-1.0, 0, 0], [1.0, 0, 0]]
REGIMES = {  # second segment against the first along x, 0.5 above: (free s, free t)
    "interior-interior": (HORIZONTAL + [[0.2, -1, 0.5], [0.3, 1, 0.5]], (True, True)),
    "edge, s clamped at 1": (HORIZONTAL + [[1.6, -1, 0.5], [1.5, 1, 0.5]], (False, True)),
    "edge, s clamped at 0": (HORIZONTAL + [[-1.6, -1, 0.5], [-1.5, 1, 0.5]], (False, True)),
    "edge, t clamped at 0": (HORIZONTAL + [[0.2, 0.5, 0.5], [0.3, 1.5, 0.5]], (True, False)),
    "edge, t clamped at 1": (HORIZONTAL + [[0.2, -1.5, 0.5], [0.3, -0.5, 0.5]], (True, False)),
    "vertex": (HORIZONTAL + [[1.5, 0.5, 0.5], [1.6, 1.5, 0.5]], (False, False)),
    "point segment": (HORIZONTAL + [[0.3, 0.2, 0.5], [0.3, 0.2, 0.5]], (True, False)),
}


@pytest.mark.parametrize("regime", list(REGIMES))
def test_segment_distance_derivatives_by_regime(regime):
    p0, free = REGIMES[regime]
    seg = QuadraticSegments(p0, seed=3)
    if regime == "point segment":  # the second segment stays a point: one end point for both
        seg.lin[3], seg.quad[3] = seg.lin[2], seg.quad[2]
    q0 = np.full(4, 0.01)
    dist, grad, hess, flags = seg.derivatives(q0)
    assert tuple(flags[0]) == free
    assert dist[0] == pytest.approx(seg.distance(q0), abs=1e-15)
    num_grad = central_difference(seg.distance, q0)
    np.testing.assert_allclose(grad[0], num_grad, atol=1e-8)
    num = central_difference(lambda q: seg.derivatives(q)[1][0], q0)
    assert_matches(hess[0], num)
    if any(free):  # the witness points' motion matters: holding (s, t) at their values is wrong
        s, t = closest_parameters(*seg.points(q0))
        w = np.array([1 - s, s, t - 1, -t])

        def fixed_grad(q):
            e = w @ seg.points(q)
            return e / np.linalg.norm(e) @ np.tensordot(w, seg.lin + seg.quad @ q, axes=1)

        fixed = central_difference(fixed_grad, q0)
        assert np.abs(fixed - num).max() > 1e-3 * np.abs(num).max()


def test_parallel_segments_take_the_s0_branch():
    """Axes exactly parallel at q0 (the closest-point system singular, the distance not twice
    differentiable): the derivatives are those of the documented branch s = 0, the
    distance from a1 to the second segment."""
    p0 = [[-1.0, 0, 0], [1.0, 0, 0], [-1.5, 0, 0.5], [0.5, 0, 0.5]]
    seg = QuadraticSegments(p0, seed=4)
    q0 = np.zeros(4)
    a1, b1, a2, b2 = seg.points(q0)
    assert not np.cross(b1 - a1, b2 - a2).any()
    dist, grad, hess, flags = seg.derivatives(q0)
    assert tuple(flags[0]) == (False, True)
    branch = QuadraticSegments(p0, seed=4)  # the same, with b1 replaced by a1
    branch.p0[1], branch.lin[1], branch.quad[1] = branch.p0[0], branch.lin[0], branch.quad[0]
    np.testing.assert_allclose(grad[0], central_difference(branch.distance, q0), atol=1e-8)
    assert_matches(hess[0], central_difference(lambda q: branch.derivatives(q)[1][0], q0))
