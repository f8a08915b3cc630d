"""The exact structured Hessian in the SQP: PD modification (calib_oed.solver.hessian) and its use.

The test problem has a known optimum by construction: a separable nonconvex
(double-well) objective plus a low-rank coupling, two active constraints with
chosen multipliers, and the linear term that makes that point a KKT point
with a positive definite Hessian of the Lagrangian (a strict local minimum).
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import scipy.sparse as sps

from calib_oed.solver.block_qp import BlockQPWorkspace
from calib_oed.solver.hessian import active_normals, modify_blocks
from calib_oed.solver.lifted import LiftedQPWorkspace
from calib_oed.solver.result import StructuredHessian
from calib_oed.solver.sqp import SQPSettings, SQPSettingsError, SQPStatus, solve_sqp


def _orthogonal(rng, s):
    q, _ = np.linalg.qr(rng.standard_normal((s, s)))
    return q


def test_indefinite_block_is_made_positive_definite():
    rng = np.random.default_rng(0)
    q = _orthogonal(rng, 4)
    theta = np.array([-2.0, 0.5, 3.0, 1e-12])
    q2 = _orthogonal(rng, 4)
    pd = q2 @ np.diag([1.0, 2.0, 3.0, 4.0]) @ q2.T
    pd = 0.5 * (pd + pd.T)
    blocks = np.stack([q @ np.diag(theta) @ q.T, pd])
    eps = 1e-8 * 4.0  # rel_floor * max(1, max |theta| over all blocks)
    expected = [2.0, 0.5, 3.0, eps]
    out, n_mod = modify_blocks(blocks, 1e-8)
    assert n_mod == 2
    np.testing.assert_allclose(out[0], q @ np.diag(expected) @ q.T, atol=1e-12)  # same eigenvectors
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(out[0])), np.sort(expected), atol=1e-12)
    np.testing.assert_array_equal(out[1], 0.5 * (pd + pd.T))  # a definite block is left alone
    assert np.linalg.eigvalsh(out).min() > 0


def _tangent_case(rng, s=5, r=2, tangent=(0.3, 1.0, 2.0), schur=(-4.0, 1.5)):
    """A block with given tangent eigenvalues and Schur complement, and its r constraint normals."""
    q = _orthogonal(rng, s)
    y, z = q[:, :r], q[:, r:]
    o = _orthogonal(rng, s - r)
    rr = o @ np.diag(tangent) @ o.T
    rr = 0.5 * (rr + rr.T)
    c = rng.standard_normal((s - r, r))
    sc = np.diag(schur)
    m = np.block([[rr, c], [c.T, sc + c.T @ np.linalg.solve(rr, c)]])
    normals = rng.standard_normal((r, r)) @ y.T  # any basis of the span of y
    return q[:, list(range(r, s)) + list(range(r))] @ m @ q[:, list(range(r, s)) + list(range(r))].T, z, y, normals


def test_tangent_rule_keeps_the_curvature_the_step_moves_along():
    """Positive tangent curvature kept exactly (the whole-block rule inflates it); the result is definite."""
    rng = np.random.default_rng(1)
    d, z, y, normals = _tangent_case(rng)
    assert np.linalg.eigvalsh(d).min() < -1  # indefinite
    tangent, n_mod = modify_blocks(d[None], 1e-8, normals[None])
    whole, _ = modify_blocks(d[None], 1e-8)
    tangent, whole = tangent[0], whole[0]
    np.testing.assert_allclose(z.T @ tangent @ z, z.T @ d @ z, atol=1e-12)  # tangent part as it was
    np.testing.assert_allclose(z.T @ tangent @ y, z.T @ d @ y, atol=1e-12)  # and its coupling
    assert np.linalg.eigvalsh(tangent).min() > 0 and n_mod == 1  # the one negative Schur eigenvalue
    w = z.T @ d @ y
    schur = y.T @ tangent @ y - w.T @ np.linalg.solve(z.T @ d @ z, w)
    np.testing.assert_allclose(np.linalg.eigvalsh(schur), [1.5, 4.0], atol=1e-10)  # |S - W|
    # the whole-block rule: no less curvature along any tangent direction, more along some
    excess = np.linalg.eigvalsh(z.T @ (whole - d) @ z)
    assert excess.min() > -1e-12 and excess.max() > 0.1  # against 0.3, the least tangent curvature


def test_tangent_rule_flips_negative_tangent_curvature():
    rng = np.random.default_rng(2)
    d, z, _, normals = _tangent_case(rng, tangent=(-0.5, 1.0, 2.0), schur=(1.0, 3.0))
    out, n_mod = modify_blocks(d[None], 1e-8, normals[None])
    np.testing.assert_allclose(np.linalg.eigvalsh(z.T @ out[0] @ z), [0.5, 1.0, 2.0], atol=1e-10)
    assert np.linalg.eigvalsh(out[0]).min() > 0 and n_mod >= 1


def test_tangent_rule_falls_back_to_the_whole_block_and_leaves_definite_blocks():
    """No normals (zero rows) or all directions constrained: the whole-block rule, bit for bit; a definite block as given."""
    rng = np.random.default_rng(3)
    d, _, _, normals = _tangent_case(rng)
    q = _orthogonal(rng, 5)
    pd = q @ np.diag([1.0, 2.0, 3.0, 4.0, 5.0]) @ q.T
    blocks = np.stack([d, d, pd])
    normals_all = np.zeros((3, 5, 5))
    normals_all[1] = _orthogonal(rng, 5)  # every direction constrained
    normals_all[2, :2] = normals
    out, _ = modify_blocks(blocks, 1e-8, normals_all)
    ref, _ = modify_blocks(blocks, 1e-8)
    np.testing.assert_array_equal(out[:2], ref[:2])
    np.testing.assert_array_equal(out[2], 0.5 * (pd + pd.T))


def test_active_normals_per_block_from_rows_and_bounds():
    """Rows within one block give their part; a row over two blocks none; a bound its unit vector."""
    a = np.zeros((4, 6))
    a[0, 0:3] = [1.0, 2.0, 0.0]  # block 0
    a[1, 3:6] = [0.0, 0.0, 5.0]  # block 1
    a[2, 2:4] = [1.0, 1.0]  # blocks 0 and 1: left out
    a[3, 4] = 7.0  # block 1, not active
    at_bound = np.zeros(6, dtype=bool)
    at_bound[4] = True
    for jac in (a, sps.csr_matrix(a), sps.csc_matrix(a)):
        out = active_normals(jac, np.array([0, 1, 2]), at_bound, 2, 3)
        assert out.shape == (2, 2, 3)
        np.testing.assert_array_equal(out[0], [[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
        np.testing.assert_array_equal(out[1], [[0.0, 0.0, 5.0], [0.0, 1.0, 0.0]])
    assert active_normals(a, np.array([], dtype=int), np.zeros(6, dtype=bool), 2, 3).shape == (2, 0, 3)


def test_the_tangent_rule_ends_a_linear_tail_along_a_bound():
    r"""f = 0.005 (u - 2)^2 + u v - v^2/2 + v, v >= 0 (active, multiplier 3 at u* = 2).

    The block [[0.01, 1], [1, -1]] is indefinite; flipping its negative eigenvalue puts
    curvature 0.90 on u, 90 times the true 0.01, so each step is 1/90 of Newton's: a linear
    tail the iteration limit cuts. On the bound's tangent space (u) the true curvature is kept.
    """
    def objective(x):
        u, v = x
        return 0.005 * (u - 2) ** 2 + u * v - v**2 / 2 + v, np.array([0.01 * (u - 2) + v, u - v + 1])

    def hessian(x, lam):
        return StructuredHessian(np.array([[[0.01, 1.0], [1.0, -1.0]]]))

    x0, bounds = np.array([0.0, 0.0]), ([-np.inf, 0.0], [np.inf, np.inf])
    runs = {name: solve_sqp(objective, x0, bounds=bounds, lagrangian_hessian=hessian,
                            settings=SQPSettings(max_iterations=100, **kw))
            for name, kw in (("tangent", dict(hessian_modification="tangent")),
                             ("block", dict(hessian_modification="block")),
                             ("auto", {}),  # 2 variables: tangent
                             ("auto, large", dict(tangent_max_size=1)))}  # above the size: block
    for name in ("tangent", "auto"):
        res = runs[name]
        assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
        np.testing.assert_allclose(res.x, [2.0, 0.0], atol=1e-6)
        assert res.iterations <= 10
    for name in ("block", "auto, large"):
        assert runs[name].status is SQPStatus.MAX_ITERATIONS and abs(runs[name].x[0] - 2.0) > 0.1


@pytest.mark.parametrize("bad, match", [
    (lambda h: "nope", "StructuredHessian"),
    (lambda h: (np.zeros((2, 5, 5)), None), "b \\* s = n"),
    (lambda h: (h.blocks * np.nan, h.low_rank), "non-finite"),
    (lambda h: (h.blocks, np.zeros((3, 1))), "low_rank"),
])
def test_a_malformed_exact_hessian_is_named_and_bfgs_takes_over(bad, match):
    """What the caller's ``lagrangian_hessian`` got wrong is in the result; the SQP still solves on BFGS."""
    objective, constraints, hessian, x_star, _ = _double_well(b=4)
    res = solve_sqp(objective, np.full(x_star.size, 0.5), constraints=constraints,
                    lagrangian_hessian=lambda x, lam: bad(hessian(x, lam)))
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5)
    assert res.hessian_fallbacks == res.iterations
    assert re.search(match, res.hessian_message), res.hessian_message


def test_hessian_settings_are_validated():
    for field, value in (("hessian_eigenvalue_floor", 0.0), ("hessian_eigenvalue_floor", 1.0),
                         ("hessian_modification", "whole"), ("tangent_max_size", 0)):
        with pytest.raises(SQPSettingsError, match=field):
            SQPSettings(**{field: value})
    with pytest.raises(SQPSettingsError, match="'auto', 'tangent', 'block'"):
        SQPSettings(hessian_modification="reduced")


def _double_well(b=10, s=6, r=3, seed=0):
    r"""f = sum(x^4/4 - x^2/2) + |V^T x - t|^2 / 2 - q^T x, rows: a ball on block 0, a plane, loose balls.

    x* is drawn in [0.9, 1.3]^n, where every x^4/4 - x^2/2 is convex; the
    ball and the plane are active there with lambda* = (0.8, 0.5). At
    x0 = 0.5 the diagonal curvature 3 x^2 - 1 is negative: indefinite blocks.
    """
    rng = np.random.default_rng(seed)
    n = b * s
    v = rng.standard_normal((n, r)) * 2 / np.sqrt(n)
    t = rng.standard_normal(r)
    x_star = rng.uniform(0.9, 1.3, n)
    radius2 = float(x_star[:s] @ x_star[:s])
    a = rng.standard_normal(n)
    beta = float(a @ x_star)
    lam_star = np.array([0.8, 0.5])

    def constraints(x):
        blocks = x.reshape(b, s)
        c = np.concatenate([[radius2 - blocks[0] @ blocks[0], a @ x - beta], 10.0 * s - np.sum(blocks**2, axis=1)])
        jac = np.zeros((2 + b, n))
        jac[0, :s] = -2 * blocks[0]
        jac[1] = a
        for j in range(b):
            jac[2 + j, j * s:(j + 1) * s] = -2 * blocks[j]
        return c, jac

    q = x_star**3 - x_star + v @ (v.T @ x_star - t) - constraints(x_star)[1][:2].T @ lam_star

    def objective(x):
        res = v.T @ x - t
        return np.sum(x**4 / 4 - x**2 / 2) + 0.5 * res @ res - q @ x, x**3 - x + v @ res - q

    def hessian(x, lam):
        """Hessian of L = f - lam^T c: diag(3x^2 - 1) + 2 lam_ball on the ball's block, + V V^T."""
        blocks = np.zeros((b, s, s))
        diag = (3 * x**2 - 1).reshape(b, s) + 2 * lam[2:, None]
        diag[0] += 2 * lam[0]
        blocks[:, np.arange(s), np.arange(s)] = diag
        return StructuredHessian(blocks, v)

    return objective, constraints, hessian, x_star, lam_star


def test_exact_hessian_converges_in_far_fewer_iterations_than_bfgs():
    objective, constraints, hessian, x_star, lam_star = _double_well()
    x0 = np.full(x_star.size, 0.5)
    seen = []

    def recording(x, lam):
        seen.append(lam.copy())
        return hessian(x, lam)

    exact = solve_sqp(objective, x0, constraints=constraints, lagrangian_hessian=recording)
    bfgs = solve_sqp(objective, x0, constraints=constraints)
    blocks = solve_sqp(objective, x0, constraints=constraints, block_size=6)
    for res in (exact, bfgs, blocks):
        assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
        np.testing.assert_allclose(res.x, x_star, atol=1e-5)
        np.testing.assert_allclose(res.multipliers[:2], lam_star, atol=1e-5)
    assert exact.iterations <= 10 and 2 * exact.iterations <= min(bfgs.iterations, blocks.iterations)
    assert exact.hessian == "exact" and exact.hessian_fallbacks == 0 and bfgs.hessian == "bfgs"
    assert all(r.hessian == "exact" for r in exact.history)
    assert np.linalg.eigvalsh(hessian(x0, seen[0]).dense()).min() < 0  # indefinite at the start
    assert np.all(seen[0] == 0) and all(lam.shape == (12,) and np.all(lam >= 0) for lam in seen)
    record = json.loads(json.dumps(exact.to_dict(), allow_nan=False))
    assert record["hessian"] == "exact" and record["history"][0]["hessian"] == "exact"


@pytest.mark.parametrize("failure", ["none", "raise", "nan"])
def test_exact_hessian_falls_back_to_bfgs(failure):
    objective, constraints, hessian, x_star, _ = _double_well(b=4)
    calls = []

    def flaky(x, lam):
        calls.append(1)
        if len(calls) % 2 == 0:
            return hessian(x, lam)
        if failure == "raise":
            raise RuntimeError("curvature not available here")
        if failure == "nan":
            h = hessian(x, lam)
            return StructuredHessian(h.blocks * np.nan, h.low_rank)
        return None

    res = solve_sqp(objective, np.full(x_star.size, 0.5), constraints=constraints, lagrangian_hessian=flaky)
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5)
    assert res.hessian_fallbacks > 0 and res.hessian == "exact"
    assert {"none": "returned None", "raise": "RuntimeError", "nan": "non-finite"}[failure] in res.hessian_message
    fell = [r for r in res.history if r.hessian_fallback]
    assert fell and all(r.hessian == "bfgs" for r in fell)
    assert "BFGS fallbacks" in res.summary()


def test_a_failing_structured_qp_falls_back_to_bfgs(monkeypatch):
    """A QP on the exact Hessian that raises (whichever structured QP runs it): every step on BFGS, same optimum."""
    def broken(self, sub, d0=None, lam0=None, nu0=None):
        raise RuntimeError("structured QP broke")

    monkeypatch.setattr(LiftedQPWorkspace, "solve", broken)
    monkeypatch.setattr(BlockQPWorkspace, "solve", broken)
    objective, constraints, hessian, x_star, _ = _double_well(b=4)
    res = solve_sqp(objective, np.full(x_star.size, 0.5), constraints=constraints, lagrangian_hessian=hessian)
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5)
    assert res.hessian_fallbacks == res.iterations and "structured QP broke" in res.hessian_message


@pytest.mark.parametrize("r", [1, 5, 12])
def test_a_coupling_of_any_rank_gives_the_optimum_with_the_exact_hessian(r):
    """r from 1 to n (n = 12): the coupling U U^T is used exactly (no fallback), Newton-fast, same optimum."""
    objective, constraints, hessian, x_star, lam_star = _double_well(b=2, r=r)
    x0 = np.full(x_star.size, 0.5)
    res = solve_sqp(objective, x0, constraints=constraints, lagrangian_hessian=hessian)
    bfgs = solve_sqp(objective, x0, constraints=constraints)
    assert res.status is SQPStatus.CONVERGED and res.check(), res.summary()
    np.testing.assert_allclose(res.x, x_star, atol=1e-5)
    np.testing.assert_allclose(res.multipliers[:2], lam_star, atol=1e-5)
    assert res.hessian_fallbacks == 0 and res.iterations <= bfgs.iterations


@pytest.mark.parametrize("bounds, x_star", [
    (None, [1.0, 1.0]),
    (([-np.inf, -1.5], [0.5, np.inf]), [0.5, 0.25]),
])
def test_rosenbrock_with_its_exact_hessian_and_no_rows(bounds, x_star):
    """Newton on Rosenbrock (one 2x2 block, m = 0): half the BFGS iterations, same optimum."""
    def rosenbrock(x):
        f = 100 * (x[1] - x[0] ** 2) ** 2 + (1 - x[0]) ** 2
        return f, np.array([-400 * x[0] * (x[1] - x[0] ** 2) - 2 * (1 - x[0]), 200 * (x[1] - x[0] ** 2)])

    def hessian(x, lam):
        assert lam.shape == (0,)
        return StructuredHessian(np.array([[[1200 * x[0] ** 2 - 400 * x[1] + 2, -400 * x[0]],
                                            [-400 * x[0], 200.0]]]))

    x0 = np.array([-1.2, 1.0])
    exact = solve_sqp(rosenbrock, x0, bounds=bounds, lagrangian_hessian=hessian)
    bfgs = solve_sqp(rosenbrock, x0, bounds=bounds)
    assert exact.status is SQPStatus.CONVERGED and exact.check(), exact.summary()
    np.testing.assert_allclose(exact.x, x_star, atol=1e-6)
    assert 2 * exact.iterations <= bfgs.iterations + 2
