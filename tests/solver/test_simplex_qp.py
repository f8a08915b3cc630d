"""The deterministic simplex QP (calib_oed.solver.simplex_qp): KKT conditions, ProxQP's optimum,
the same bits on every call."""

from __future__ import annotations

import numpy as np
import pytest

from calib_oed.solver import simplex_qp
from calib_oed.solver.proxqp_build import proxsuite
from calib_oed.solver.simplex_qp import solve_simplex_qp


def _problem(seed: int):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(2, 60))
    b = rng.standard_normal((m, int(rng.integers(1, m + 1))))
    h = b @ b.T + 1e-6 * np.eye(m)
    w = rng.random(m) * (rng.random(m) < 0.6)
    w[0] += 1e-3
    w /= w.sum()
    return h, rng.standard_normal(m), w


def _proxqp(h, g, w):
    m = w.size
    qp = proxsuite.proxqp.dense.QP(m, 1, 0, True)
    qp.settings.eps_abs, qp.settings.eps_rel, qp.settings.verbose = 1e-12, 0.0, False
    qp.init(h, g, np.ones((1, m)), np.zeros(1), None, None, None, -w, 1.0 - w)
    qp.solve()
    return np.array(qp.results.x)


@pytest.mark.parametrize("seed", range(12))
def test_kkt_point_and_proxqp_optimum(seed):
    h, g, w = _problem(seed)
    s = solve_simplex_qp(h, g, np.ones(w.size), -w, 1.0 - w, np.zeros(w.size))
    assert s is not None
    assert abs(s.sum()) < 1e-12 and np.all(s >= -w) and np.all(s <= 1.0 - w)
    # KKT: r = Hs + g = lam + nu, nu >= 0 at the lower bound, <= 0 at the upper one, 0 inside
    r = h @ s + g
    inside = (s > -w + 1e-12) & (s < 1.0 - w - 1e-12)
    lam = float(np.mean(r[inside]))
    scale = 1e-8 * (1.0 + np.abs(r).max())
    assert np.all(np.abs(r[inside] - lam) < scale)
    assert np.all(r[np.isclose(s, -w, rtol=0, atol=1e-12)] - lam > -scale)
    obj = lambda x: 0.5 * x @ h @ x + g @ x  # noqa: E731
    assert obj(s) <= obj(_proxqp(h, g, w)) + 1e-9 * (1.0 + abs(obj(s)))


def test_same_bits_whatever_the_memory_layout():
    """Copies at other addresses (ProxQP's answer changes with them, issue 31) give the same bits."""
    h, g, w = _problem(3)
    first = solve_simplex_qp(h, g, np.ones(w.size), -w, 1.0 - w, np.zeros(w.size))
    junk = []
    for k in range(20):
        junk.append(np.empty(97 * k + 1))
        again = solve_simplex_qp(np.asfortranarray(h.copy()), g.copy(), np.ones(w.size), -w.copy(),
                                 1.0 - w, np.zeros(w.size))
        assert again.tobytes() == first.tobytes()


def test_infeasible_cap_gives_none():
    h, g, w = _problem(5)
    assert solve_simplex_qp(h, g, np.ones(w.size), -w, 1.0 - w, np.zeros(w.size), max_iterations=0) is None


@pytest.mark.parametrize("seed", range(6))
def test_the_answer_depends_on_the_final_working_set_only(seed, monkeypatch):
    """Another path (the primal method alone, another start or warm start) gives the same bits."""
    h, g, w = _problem(seed)
    m = w.size
    first = solve_simplex_qp(h, g, np.ones(m), -w, 1.0 - w, np.zeros(m))
    cold = solve_simplex_qp(h, g, np.ones(m), -w, 1.0 - w, np.zeros(m), fixed=np.zeros(m, bool))
    other_start = np.zeros(m)  # another feasible point, a^T s = 0 exactly: candidate 0's weight moved
    other_start[0], other_start[-1] = -w[0], w[0]
    moved = solve_simplex_qp(h, g, np.ones(m), -w, 1.0 - w, other_start)
    monkeypatch.setattr(simplex_qp, "_PRIMAL_DUAL_CAP", 0)
    primal = solve_simplex_qp(h, g, np.ones(m), -w, 1.0 - w, np.zeros(m))
    assert first is not None
    for other in (cold, moved, primal):
        assert other.tobytes() == first.tobytes()


@pytest.mark.parametrize("m", [100, 200])
def test_large_supports_kkt_against_proxqp(m):
    """Supports of the sizes the design pipeline meets: ProxQP's optimum to its tolerance."""
    rng = np.random.default_rng(m)
    b = rng.standard_normal((m, 30))
    h = b @ b.T + 1e-8 * m * np.eye(m)
    w = rng.random(m) * (rng.random(m) < 0.7)
    w /= w.sum()
    g = rng.standard_normal(m)
    s = solve_simplex_qp(h, g, np.ones(m), -w, 1.0 - w, np.zeros(m))
    assert s is not None and abs(s.sum()) < 1e-12 and np.all(w + s >= 0)
    obj = lambda x: 0.5 * x @ h @ x + g @ x  # noqa: E731
    ref = _proxqp(h, g, w)
    assert abs(obj(s) - obj(ref)) <= 1e-8 * (1.0 + abs(obj(ref)))
    assert obj(s) <= obj(ref) + 1e-9 * (1.0 + abs(obj(ref)))
