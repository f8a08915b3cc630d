"""The OED problem in the solver's terms: stacked objective, constraints and bounds."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.oed import model_error
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import COLLISION_KINDS, DesignProblem
from calib_oed.scene.reader import load_scene


def stacked_labels(problem: DesignProblem) -> list[str]:
    """Label of each stacked constraint row of ``problem``, ``"pose j: <row label>"``."""
    rows = [lbl for k, lbl in zip(problem.feasibility.kinds, problem.feasibility.labels, strict=True)
            if k in problem.kinds]
    return [f"pose {j}: {lbl}" for j in range(problem.n) for lbl in rows]


@pytest.fixture(scope="module")
def nlp(kr16):
    objective = DesignObjective(kr16.problem, "kpi")
    q0 = heuristic_design(kr16, 10, 3)
    return DesignProblem(objective, kr16.feasibility, 10, scale=objective.compute_value(q0)), q0


def test_objective_is_scaled_to_one_at_the_start(nlp):
    problem, q0 = nlp
    f, g = problem.compute_objective(q0.ravel())
    assert np.isclose(f, 1.0, rtol=1e-12) and g.shape == (q0.size,)


def test_stacked_constraint_jacobian(nlp):
    problem, q0 = nlp
    x = q0.ravel() + np.random.default_rng(0).normal(scale=1e-3, size=q0.size)
    c, jac = problem.compute_constraints(x)
    kinds = [k for k in problem.feasibility.kinds if k in COLLISION_KINDS]
    assert c.shape == (10 * len(kinds),) and jac.shape == (c.size, x.size)
    numeric = central_difference(lambda y: problem.compute_constraint_rows(y, False)[0].ravel(), x)
    assert relative_error(jac.toarray(), numeric) < 1e-6
    # block diagonal: pose j's rows depend on q_j only
    dense = jac.toarray().reshape(10, len(kinds), 10, -1)
    off = [dense[i, :, j] for i in range(10) for j in range(10) if i != j]
    assert np.count_nonzero(off) == 0


def test_bounds_and_violation(nlp):
    problem, q0 = nlp
    lb, ub = problem.bounds
    assert np.all(lb <= q0.ravel()) and np.all(q0.ravel() <= ub)
    assert problem.max_violation(q0.ravel()) == 0.0
    x = q0.ravel().copy()
    x[0] = ub[0] + 0.1
    assert problem.max_violation(x) >= 0.1 - 1e-12
    assert len(stacked_labels(problem)) == problem.compute_constraint_rows(x, False)[0].size


def test_without_collisions_only_incidence(kr16):
    objective = DesignObjective(kr16.problem, "params")
    problem = DesignProblem(objective, kr16.feasibility, 3, collisions=False)
    c, _ = problem.compute_constraints(heuristic_design(kr16, 3, 0).ravel())
    assert c.size == 3 * len(kr16.scene.reflectors)


def test_bad_scale(kr16):
    objective = DesignObjective(kr16.problem, "kpi")
    with pytest.raises(ValueError, match="scale"):
        DesignProblem(objective, kr16.feasibility, 3, scale=0.0)


@pytest.mark.parametrize("criterion", ["kpi", "D"])
def test_lagrangian_hessian_matches_differences_of_the_lagrangian_gradient(kr16, criterion):
    """Per-pose blocks (criterion through the rows, constraint curvature) plus the coupling
    U U^T equal central differences of grad(phi/s) - A^T lam, with random multipliers. Rows on
    convex pieces of the link geometry have the tangent-plane model (docs/feasibility.md §7): their
    multipliers are zero in the comparison, and their part is checked to be that model."""
    s = kr16
    n = 10
    nlp = DesignProblem(DesignObjective(s.problem, criterion), s.feasibility, n, scale=2e-5)
    x = heuristic_design(s, n, 0).ravel()
    c, _ = nlp.compute_constraints(x)
    rng = np.random.default_rng(0)
    lam = rng.random(c.size) * (rng.random(c.size) < 0.2)
    hull = np.isin([lbl.split(": ", 1)[1] for lbl in stacked_labels(nlp)], s.feasibility.hull_pairs.labels)
    assert hull.any() and lam[hull].any()
    exact = np.where(hull, 0.0, lam)
    hess = nlp.compute_lagrangian_hessian(x, exact)
    assert hess.blocks.shape == (n, 6, 6) and hess.low_rank.shape[0] == n * 6

    def gradient(y):
        _, g = nlp.compute_objective(y)
        _, jac = nlp.compute_constraints(y)
        return g - jac.T @ exact

    fd = central_difference(gradient, x)
    assert np.abs(hess.dense() - fd).max() <= 1e-6 * np.abs(fd).max()
    # the constraint part is -sum_i lam_i hess g_i of the feasibility model (hull rows: its model)
    q = nlp.configurations(x)
    plain = nlp.compute_lagrangian_hessian(x, np.zeros_like(lam))
    full = nlp.compute_lagrangian_hessian(x, lam)
    part = s.feasibility.compute_lagrangian_hessian(q, lam.reshape(n, -1), kinds=nlp.kinds)
    assert np.abs(part).max() > 0.0
    np.testing.assert_allclose(full.blocks, plain.blocks - part, rtol=1e-12, atol=1e-9 * np.abs(part).max())
    np.testing.assert_allclose(hess.blocks - plain.blocks, full.blocks - plain.blocks + s.feasibility.
                               compute_lagrangian_hessian(q, np.where(hull, lam, 0.0).reshape(n, -1),
                                                          kinds=nlp.kinds), rtol=0, atol=1e-9 * np.abs(part).max())


def test_row_pieces_land_on_their_stacked_rows(nlp, monkeypatch):
    """compute_row_pieces maps the pieces of convex-piece rows (pose, pair) to the stacked rows of
    those pairs and puts each gradient in its pose's columns (the geometry: test_hull_pieces.py)."""
    import calib_oed.oed.problem as problem_module
    from calib_oed.feasibility.hull_pieces import HullRowPieces

    problem, q0 = nlp
    hull = problem.feasibility.hull_pairs
    assert len(hull) >= 2
    seen = {}
    grads = np.random.default_rng(1).standard_normal((2, problem.nq))

    def fake(hp, states, pose, rows, clearance):
        seen["rows"], seen["n_states"] = np.asarray(rows), states.rotation.shape[0]
        return HullRowPieces(np.array([0, 1]), np.array([0, len(hp) - 1]), np.array([0.5, 0.25]), grads)

    monkeypatch.setattr(problem_module, "hull_row_pieces", fake)
    labels = stacked_labels(problem)
    every = np.arange(len(labels))
    stacked, values, g = problem.compute_row_pieces(q0.ravel(), every)
    assert seen["n_states"] == problem.n and sorted(set(seen["rows"].tolist())) == list(range(len(hull)))
    assert labels[stacked[0]] == f"pose 0: {hull.labels[0]}"
    assert labels[stacked[1]] == f"pose 1: {hull.labels[-1]}"
    assert np.array_equal(values, [0.5, 0.25]) and g.shape == (2, q0.size)
    dense = g.toarray()
    assert np.array_equal(dense[0, :problem.nq], grads[0]) and not dense[0, problem.nq:].any()
    assert np.array_equal(dense[1, problem.nq:2 * problem.nq], grads[1])
    # rows that are not convex-piece rows are never passed on
    others = np.array([i for i, lbl in enumerate(labels) if not any(h in lbl for h in hull.labels)])
    assert problem.compute_row_pieces(q0.ravel(), others)[0].size == 0


def test_an_evaluated_point_keeps_its_body_states(kr16, nlp):
    """After the rows of a point, its Lagrangian Hessian and row pieces reuse the point's body
    states (and the convex-piece witnesses): the same arrays as a problem that evaluates nothing
    before."""
    problem, q0 = nlp
    x = q0.ravel() + np.random.default_rng(4).normal(scale=1e-2, size=q0.size)
    c, _ = problem.compute_constraints(x)
    lam = np.where(c < np.quantile(c, 0.3), 1.0, 0.0)
    warm = problem.compute_lagrangian_hessian(x, lam)
    assert problem._body_states(problem.configurations(x), compute=False) is not None
    objective = problem.objective
    fresh = DesignProblem(objective, setup(load_scene("fms_kr16")).feasibility, 10, scale=problem.scale)
    cold = fresh.compute_lagrangian_hessian(x, lam)
    assert np.array_equal(warm.blocks, cold.blocks)
    rows = np.flatnonzero(lam)
    for a, b in zip(problem.compute_row_pieces(x, rows), fresh.compute_row_pieces(x, rows), strict=True):
        assert np.array_equal(a if isinstance(a, np.ndarray) else a.toarray(),
                              b if isinstance(b, np.ndarray) else b.toarray())


@pytest.mark.parametrize("criterion", ["kpi", "params", None])  # None: the scene's default, kpi_model
def test_values_alone_are_those_with_derivatives_bit_for_bit(kr16, criterion):
    """The SQP's trial points (:meth:`DesignProblem.compute_values`) see the same numbers as its
    accepted points: otherwise a step accepted on one would be measured on the other."""
    objective = DesignObjective(kr16.problem, model_error.scene_criterion(kr16, criterion))
    q0 = heuristic_design(kr16, 10, 3)
    problem = DesignProblem(objective, kr16.feasibility, 10, scale=1.7)
    rng = np.random.default_rng(5)
    for _ in range(3):
        x = q0.ravel() + rng.normal(scale=3e-2, size=q0.size)
        f_alone, c_alone = problem.compute_values(x)  # first: no cache from the full evaluation
        f, _ = problem.compute_objective(x)
        c, _ = problem.compute_constraints(x)
        assert f_alone == f and np.array_equal(c_alone, c)
    assert problem.n_values == 3
