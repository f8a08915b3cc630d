"""QP failures inside solve_sqp end in a status, never an exception (calib_oed.solver.subproblem)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_sqp import _hs43 as hs43

import calib_oed.solver.iteration as iteration
from calib_oed.solver.qp import DenseQPWorkspace, QPSizeError, QPSubproblem, SparseQPWorkspace
from calib_oed.solver.result import SQPStatus
from calib_oed.solver.sqp import SQPSettings, solve_sqp
from calib_oed.solver.subproblem import QPSolver


def _hs43():
    """Rosen–Suzuki (Hock & Schittkowski 43): x* = (0, 1, 2, -1); objective and constraints."""
    return hs43()[:2]


def _raise(exc):
    def solve(self, sub, d0=None, lam0=None, nu0=None):
        raise exc
    return solve


def _garbage(self, sub, d0=None, lam0=None, nu0=None):
    from calib_oed.solver.qp import QPStep
    n, k = sub.g.size, sub.lower.size
    return QPStep(np.full(n, np.nan), np.full(k, np.inf), np.zeros(n), "solved", 3, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("backend, workspace", [("dense", DenseQPWorkspace), ("sparse", SparseQPWorkspace)])
@pytest.mark.parametrize("failure, status_word", [
    (_raise(RuntimeError("proxsuite: something broke")), "RuntimeError"),
    (_raise(MemoryError()), "MemoryError"),
    (_raise(np.linalg.LinAlgError("singular")), "LinAlgError"),
    (_garbage, "non-finite"),
])
def test_a_failing_qp_solver_ends_in_a_status(monkeypatch, backend, workspace, failure, status_word):
    monkeypatch.setattr(workspace, "solve", failure)
    obj, con = _hs43()
    res = solve_sqp(obj, np.zeros(4), constraints=con, settings=SQPSettings(qp_backend=backend))
    assert res.status is SQPStatus.QP_FAILED, res.summary()
    assert status_word in res.message
    assert res.history and res.history[-1].qp_status in ("error", "non_finite")
    json.dumps(res.to_dict(), allow_nan=False)
    np.testing.assert_array_equal(res.x, np.zeros(4))  # no step was taken


def test_a_failing_qp_at_an_infeasible_start_ends_in_a_status(monkeypatch):
    """Restoration (its own elastic QP) may move the point; the failing QP still ends the run cleanly."""
    monkeypatch.setattr(DenseQPWorkspace, "solve", _raise(ValueError("wrong dimensions")))
    obj, con = _hs43()
    x0 = np.array([3.0, 3.0, 3.0, 3.0])
    assert con(x0)[0].min() < 0
    res = solve_sqp(obj, x0, constraints=con)
    assert res.status is SQPStatus.QP_FAILED and "ValueError" in res.message, res.summary()
    assert any(r.restoration for r in res.history)  # restoration brought it near feasibility
    assert res.max_violation < 1e-6


def test_numerical_errors_outside_the_qp_end_in_a_status(monkeypatch):
    def broken(*args, **kwargs):
        raise np.linalg.LinAlgError("eigenvalues did not converge")

    monkeypatch.setattr(iteration, "kkt_residuals", broken)
    obj, con = _hs43()
    res = solve_sqp(obj, np.zeros(4), constraints=con)
    assert res.status is SQPStatus.NUMERICAL_ERROR and "LinAlgError" in res.message
    assert res.iterations == 0 and res.x.shape == (4,)


def test_a_qp_too_large_is_refused_before_proxqp_allocates():
    rng = np.random.default_rng(0)
    n, k = 50, 20
    sub = QPSubproblem(np.eye(n), rng.standard_normal(n), rng.standard_normal((k, n)), -np.ones(k),
                       -np.ones(n), np.ones(n))
    with pytest.raises(QPSizeError, match="max_qp_nonzeros"):
        SparseQPWorkspace(n, 1e-9, 100, max_nonzeros=1000).solve(sub)
    with pytest.raises(QPSizeError):
        DenseQPWorkspace(n, 1e-9, 100, max_capacity=10).solve(sub)
    # inside the SQP: a status, with the bound named
    solver = QPSolver(n, SQPSettings(qp_backend="sparse", max_qp_nonzeros=1000))
    step = solver.solve(sub)
    assert step.status == "too_large" and "max_qp_nonzeros" in step.message
    assert not np.any(np.isfinite(step.d))


def test_too_large_qp_inside_solve_sqp_is_a_status():
    obj, con = _hs43()
    res = solve_sqp(obj, np.zeros(4), constraints=con,
                    settings=SQPSettings(qp_backend="sparse", max_qp_nonzeros=5))
    assert res.status is SQPStatus.QP_FAILED and "max_qp_nonzeros" in res.message


def test_dense_workspace_capacity_stays_within_its_bound():
    rng = np.random.default_rng(1)
    n = 8
    ws = DenseQPWorkspace(n, 1e-9, 1000, max_capacity=24)
    for k in (4, 20, 24, 3):
        sub = QPSubproblem(np.eye(n), rng.standard_normal(n), rng.standard_normal((k, n)),
                           -np.ones(k), -np.ones(n), np.ones(n))
        step = ws.solve(sub)
        assert step.is_solved(1e-8, 1e-7) and ws.capacity <= 24


def _crossing_rows():
    r"""min |x|^2 s.t. x_1 - x_2^2 >= 1, 0.5 - x_1 + 2 x_2^2 >= 0 from (0, 0.1): the linearised rows
    contradict each other there (d_1 >= ~1 and d_1 <= ~0.5), each reachable in the box alone."""
    def f(x):
        return float(x @ x), 2 * x

    def cons(x):
        return (np.array([x[0] - x[1] ** 2 - 1.0, 0.5 - x[0] + 2 * x[1] ** 2]),
                np.array([[1.0, -2 * x[1]], [-1.0, 4 * x[1]]]))
    return f, cons, np.array([0.0, 0.1])


def test_a_qp_proved_infeasible_is_not_solved_again(monkeypatch):
    """The multipliers of the first failed QP prove the linearisation infeasible (Farkas): the retries
    of the same iteration (cold, larger box) are not run to ProxQP's limit, and the run is the same."""
    import calib_oed.solver.subproblem as subproblem

    f, cons, x0 = _crossing_rows()
    settings = SQPSettings(step_bound=1.0)
    res = solve_sqp(f, x0, constraints=cons, settings=settings)
    monkeypatch.setattr(subproblem, "CERTIFIED_MARGIN", np.inf)  # no certificate is ever good enough
    plain = solve_sqp(f, x0, constraints=cons, settings=settings)
    assert res.status is plain.status is SQPStatus.CONVERGED
    np.testing.assert_array_equal(res.x, plain.x)
    assert [r.restoration for r in res.history] == [r.restoration for r in plain.history]
    assert res.history[0].restoration and plain.history[0].qp_status == "max_iter"
    assert "infeasible" in [r.qp_status for r in res.history]
    first = [r.qp_iterations for r in res.history if r.restoration]
    assert sum(first) < 0.7 * sum(r.qp_iterations for r in plain.history if r.restoration)
