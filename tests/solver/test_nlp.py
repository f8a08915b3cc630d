"""Trial points without derivatives (:mod:`calib_oed.solver.nlp`, ``values`` of ``solve_sqp``)."""

from __future__ import annotations

import numpy as np
import pytest
from test_sqp import HS

from calib_oed.exceptions import ShapeError
from calib_oed.solver.sqp import SQPSettings, SQPStatus, solve_sqp


def _maratos():
    """N&W Example 15.4 as an inequality: every full step near x* is rejected, its SOC taken."""
    def objective(x):
        return 2 * (x @ x - 1) - x[0], np.array([4 * x[0] - 1, 4 * x[1]])

    def constraints(x):
        return np.array([x @ x - 1]), (2 * x)[None, :]

    return objective, constraints, [np.cos(0.3), np.sin(0.3)], None


def _problem(name):
    if name == "maratos":
        return _maratos()
    objective, constraints, x0, bounds, _, _ = HS[name]()
    return objective, constraints, x0, bounds


def _values(objective, constraints):
    return lambda x: (objective(x)[0], constraints(x)[0])


@pytest.mark.parametrize("name", ["hs21", "hs43", "hs100", "maratos"])
@pytest.mark.parametrize("trust_update", [None, "ratio"])
def test_values_only_trials_leave_every_iterate_unchanged(name, trust_update):
    """The same iterates bit for bit, with derivatives at the accepted points only."""
    objective, constraints, x0, bounds = _problem(name)
    settings = SQPSettings(trust_update=trust_update)
    runs = [solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds,
                      settings=settings, values=values)
            for values in (None, _values(objective, constraints))]
    plain, cheap = runs
    assert plain.status is SQPStatus.CONVERGED and cheap.status is plain.status
    assert np.array_equal(plain.x, cheap.x) and plain.fun == cheap.fun
    assert [(r.objective, r.step_norm, r.backtracks, r.second_order_correction) for r in plain.history] == \
        [(r.objective, r.step_norm, r.backtracks, r.second_order_correction) for r in cheap.history]
    taken = sum(r.step_norm > 0 for r in cheap.history)  # points accepted after the start
    assert cheap.n_objective_evaluations == cheap.n_constraint_evaluations == 1 + taken
    tried = plain.n_objective_evaluations - 1  # every trial point of the plain run
    assert cheap.n_value_evaluations == tried
    assert plain.n_value_evaluations == 0 and plain.times["values"] == 0.0


def test_a_rejected_step_costs_no_derivatives():
    """Near x* every full step of N&W's Maratos example is rejected and its correction taken:
    the rejected trials are evaluated by ``values`` alone."""
    objective, constraints, x0, bounds = _problem("maratos")
    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, bounds=bounds,
                    values=_values(objective, constraints))
    rejected = sum(r.backtracks + r.second_order_correction for r in res.history)
    assert rejected > 0
    assert res.n_value_evaluations == res.n_objective_evaluations - 1 + rejected


def test_non_finite_values_reject_the_trial():
    """``values`` NaN at the first trial point (the objective finite there): that trial is
    rejected, the step backtracked, and the run converges to hs43's optimum."""
    objective, constraints, x0, bounds = _problem("hs43")
    values = _values(objective, constraints)
    calls = []

    def first_nan(x):
        calls.append(x)
        f, c = values(x)
        return (np.nan if len(calls) == 1 else f), c

    res = solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints, values=first_nan)
    assert res.history[0].backtracks >= 1
    assert res.status is SQPStatus.CONVERGED
    np.testing.assert_allclose(res.x, [0.0, 1.0, 2.0, -1.0], atol=1e-5)


def test_a_trial_whose_derivatives_are_not_finite_is_not_taken():
    """Finite values but a NaN gradient at the accepted point: the line search goes on backtracking."""
    def objective(x):
        g = np.array([2 * (x[0] - 3.0)])
        return (x[0] - 3.0) ** 2, (g * np.nan if x[0] > 2.0 else g)

    res = solve_sqp(objective, np.array([0.0]), bounds=(-5.0, 5.0),
                    values=lambda x: ((x[0] - 3.0) ** 2, np.zeros(0)),
                    settings=SQPSettings(max_iterations=30))
    assert np.all(np.isfinite(res.x)) and res.x[0] <= 2.0
    assert res.n_objective_evaluations >= 2 and res.fun < 9.0


def test_values_of_the_wrong_shape_raise():
    objective, constraints, x0, bounds = _problem("hs43")
    with pytest.raises(ShapeError, match="values"):
        solve_sqp(objective, np.array(x0, dtype=float), constraints=constraints,
                  values=lambda x: (objective(x)[0], constraints(x)[0][:2]))
