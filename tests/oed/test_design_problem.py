"""The OED problem in the solver's terms: stacked objective, constraints and bounds."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.calibration.workflow import heuristic_design, setup
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import COLLISION_KINDS, DesignProblem
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def kr16():
    return setup(load_scene("fms_kr16"))


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
    assert len(problem.constraint_labels()) == problem.compute_constraint_rows(x, False)[0].size


def test_without_collisions_only_incidence(kr16):
    objective = DesignObjective(kr16.problem, "params")
    problem = DesignProblem(objective, kr16.feasibility, 3, collisions=False)
    c, _ = problem.compute_constraints(heuristic_design(kr16, 3, 0).ravel())
    assert c.size == 3 * len(kr16.scene.reflectors)


def test_bad_scale(kr16):
    objective = DesignObjective(kr16.problem, "kpi")
    with pytest.raises(ValueError, match="scale"):
        DesignProblem(objective, kr16.feasibility, 3, scale=0.0)
