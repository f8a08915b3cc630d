"""Approximate designs: the solver against an independent solve, the equivalence theorem, the
bound formulas at any weights, scaling to n poses, the bound below every exact design of the pool,
errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.optimize

from calib_oed.exceptions import CertificateError, NonFiniteError, NotIdentifiableError, ShapeError
from calib_oed.oed import approximate as ad
from calib_oed.oed.criteria import ACriterion, DCriterion, ECriterion
from calib_oed.oed.exchange import exchange_design, information_matrix

N_CAND, D, P = 40, 2, 6


def synthetic_blocks(seed=0):
    return np.random.default_rng(seed).standard_normal((N_CAND, D, P))


def synthetic_criteria(seed=0):
    g = np.random.default_rng(seed + 100).standard_normal((3, P))  # rank 3 of 6, like the KPI
    return [ACriterion.kpi(g), ACriterion.parameters(P), DCriterion()]


def slsqp_optimum(blocks, criterion):
    """Independent solve: SLSQP on the simplex in w, finite-difference-free analytic gradient."""
    n = blocks.shape[0]

    def fun(w):
        m = ad.information(blocks, np.maximum(w, 0.0))
        return criterion.compute_value(m), -ad.sensitivities(blocks, criterion.compute_gradient(m))

    res = scipy.optimize.minimize(fun, np.full(n, 1.0 / n), jac=True, method="SLSQP",
                                  bounds=[(0.0, 1.0)] * n,
                                  constraints=[{"type": "eq", "fun": lambda w: w.sum() - 1.0,
                                                "jac": lambda w: np.ones_like(w)}],
                                  options={"ftol": 1e-12, "maxiter": 2000})
    # ftol 1e-14 ended with "Positive directional derivative for linesearch" (status 8, at 1e-12
    # of the optimum) under OPENBLAS_NUM_THREADS=1 with scipy 1.17: below rounding, not a failure
    assert res.success, res.message
    return res.fun


# ------------------------------------------- the solver and the bound formulas
@pytest.mark.parametrize("k", range(3), ids=["kpi", "params", "D"])
def test_approximate_optimum_matches_slsqp_and_the_equivalence_theorem(k):
    blocks, crit = synthetic_blocks(), synthetic_criteria()[k]
    res = ad.solve_approximate(blocks, crit, tol=1e-9)
    ref = slsqp_optimum(blocks, crit)
    scale = max(abs(ref), 1.0) if crit.name == "D" else ref
    assert res.converged and res.check() <= 1e-9
    assert abs(res.value - ref) <= 1e-7 * abs(scale)
    # equivalence theorem: max d <= dbar everywhere, equality on the support
    dbar = res.mean_sensitivity
    assert np.isclose(dbar, res.value if crit.name != "D" else P, rtol=1e-12)
    assert np.isclose(res.weights @ res.sensitivities, dbar, rtol=1e-10)  # sum w_i d_i = dbar
    assert res.sensitivities.max() <= dbar * (1 + 1e-9)
    assert res.support_residual() <= 1e-6
    assert np.isclose(res.weights.sum(), 1.0) and res.weights.min() >= 0
    off = np.setdiff1d(np.arange(N_CAND), res.support)
    assert off.size > 0 and np.all(res.sensitivities[off] <= dbar * (1 + 1e-9))
    assert res.lower_bound <= ref * (1 + 1e-12) if crit.name != "D" else res.lower_bound <= ref + 1e-9
    json.dumps(res.to_dict())
    assert "converged" in res.summary()


@pytest.mark.parametrize("k", range(3), ids=["kpi", "params", "D"])
def test_bound_of_any_weights_is_below_the_optimum_and_above_frank_wolfe(k):
    """The bound formula itself, at non-optimal weights: Phi*/(1+rho) (A), Phi - p log(1+rho) (D)."""
    blocks, crit = synthetic_blocks(1), synthetic_criteria(1)[k]
    best = ad.solve_approximate(blocks, crit, tol=1e-10).value
    kind = ad.criterion_kind(crit)
    rng = np.random.default_rng(5)
    for _ in range(20):
        w = rng.dirichlet(np.full(N_CAND, 0.3))
        m = ad.information(blocks, w)
        value = crit.compute_value(m)
        d = ad.sensitivities(blocks, crit.compute_gradient(m))
        dbar = ad.mean_sensitivity(kind, value, P)
        assert np.isclose(w @ d, dbar, rtol=1e-10)
        rho = d.max() / dbar - 1
        bound = ad.lower_bound(kind, value, rho, P)
        frank_wolfe = value + dbar - d.max()  # the linear (duality-gap) bound
        assert frank_wolfe - 1e-12 * abs(value) <= bound <= best + 1e-12 * abs(best)
        if kind == "A":
            assert np.isclose(bound, value**2 / d.max(), rtol=1e-12)


def test_scaling_to_n_poses():
    """An exact n-pose design has M_n = n M(uniform): Phi/n (A), Phi - p log n (D)."""
    blocks = synthetic_blocks(2)
    idx = np.array([0, 3, 3, 7, 11, 12, 20, 31])  # repeats allowed
    w = np.bincount(idx, minlength=N_CAND) / idx.size
    for crit in synthetic_criteria(2):
        kind = ad.criterion_kind(crit)
        exact = crit.compute_value(information_matrix(blocks, idx))
        scaled = ad.scale_to_poses(kind, crit.compute_value(ad.information(blocks, w)), idx.size, P)
        assert np.isclose(exact, scaled, rtol=1e-12)


# ------------------------------------------------- the bound and exact designs
def test_bound_is_below_every_exact_design_of_the_pool():
    blocks = synthetic_blocks(3)
    n = 8
    rng = np.random.default_rng(7)
    for crit in synthetic_criteria(3):
        kind = ad.criterion_kind(crit)
        res = ad.solve_approximate(blocks, crit)
        bound = ad.scale_to_poses(kind, res.lower_bound, n, P)
        values = [crit.compute_value(information_matrix(blocks, rng.choice(N_CAND, n, replace=False)))
                  for _ in range(200)]
        values.append(exchange_design(blocks, n, crit, rng=0).value)
        assert bound <= min(values)
        if kind == "A":  # efficiency of the exchange design well defined and <= 1
            assert 0 < ad.efficiency(kind, bound, values[-1], P) <= 1



# ------------------------------------------------------------------- errors
def test_errors():
    blocks, crit = synthetic_blocks(), synthetic_criteria()[1]
    with pytest.raises(CertificateError, match="'kpi', 'params', 'D'") as err:
        ad.solve_approximate(blocks, ECriterion())
    assert err.value.valid == list(ad.CERTIFIABLE)
    with pytest.raises(CertificateError, match="tol"):
        ad.solve_approximate(blocks, crit, tol=0.0)
    with pytest.raises(CertificateError, match="start"):
        ad.solve_approximate(blocks, crit, start=[0, N_CAND])
    with pytest.raises(CertificateError, match="weights"):
        ad.solve_approximate(blocks, crit, weights=-np.ones(N_CAND))
    with pytest.raises(ShapeError):
        ad.solve_approximate(blocks[0], crit)
    bad = blocks.copy()
    bad[3, 0, 1] = np.nan
    with pytest.raises(NonFiniteError):
        ad.solve_approximate(bad, crit)
    flat = blocks.copy()
    flat[:, :, -1] = 0.0  # no candidate measures the last parameter
    with pytest.raises(NotIdentifiableError):
        ad.solve_approximate(flat, crit)
