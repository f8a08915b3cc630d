"""Optimality certificate: the bound below every design tried, the pool-only certificate, the
sensitivity gradient off the pool, errors, the re-exported approximate-design names."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.exceptions import CertificateError, ShapeError
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.oed import approximate as approximate_design
from calib_oed.oed import certificate as cert
from calib_oed.oed.design import design, exchange_baseline
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.sensitivity_maxima import sensitivity_field
from calib_oed.solver.sqp import SQPSettings


# ------------------------------------------------ the certificate of a design
@pytest.fixture(scope="module")
def kr16_pool(kr16):
    return sample_feasible(kr16.feasibility, 300, 11)


def test_certificate_is_below_random_exchange_and_sqp_designs(kr16, kr16_pool):
    n = 30
    sqp = design(kr16, n, "kpi", start="heuristic", seed=4, settings=SQPSettings(max_iterations=15),
                 certificate=False)
    c = cert.certify(kr16, sqp.q, "kpi", pool=kr16_pool, local_starts=8, verify_starts=16,
                     local_rounds=4, local_iterations=40)
    assert c.converged and c.check() <= c.tol and c.holds()
    assert np.isclose(c.design_value, sqp.value, rtol=1e-10)
    assert c.bound <= c.bound_pool and 0 < c.efficiency <= 1
    assert c.max_sensitivity_local >= c.max_sensitivity_pool * (1 - 1e-9) or c.n_local_added == 0
    objective = DesignObjective(kr16.problem, "kpi")
    rng = np.random.default_rng(0)
    values = [objective.compute_value(kr16_pool[rng.choice(len(kr16_pool), n, replace=False)])
              for _ in range(20)]
    values.append(exchange_baseline(kr16, n, "kpi", pool=kr16_pool).value)
    values.append(sqp.value)
    assert c.bound <= min(values)
    assert c.bound_pool <= min(values[:-1])  # the pool-certified bound covers the pool's designs
    # a certificate of another design, whose pool does not hold the SQP poses: the local
    # maximisation must cover them
    other = cert.certify(kr16, kr16_pool[:n], "kpi", pool=kr16_pool[n:], local_starts=8,
                         verify_starts=16, local_rounds=4, local_iterations=40)
    assert other.holds() and other.bound <= min(values)
    data = c.to_dict()
    json.dumps(data)
    assert data["residual"] == c.check() and data["n"] == n and data["criterion"] == "kpi"
    assert "as good as the local maximisation" in c.summary()
    # why the search ended: complete only if the last maximisation converged below the round limit
    done = dataclasses.replace(c, local_rounds=2, local_status="converged")
    assert done.search_end(4) == cert.SEARCH_COMPLETE
    assert done.search_end(2) == "round limit (2 re-solves)"
    assert "did not converge (max_iterations)" in dataclasses.replace(
        done, local_status="max_iterations").search_end(4)


def test_pool_only_certificate_says_so(kr16, kr16_pool):
    q = kr16_pool[:20]
    c = cert.certify(kr16, q, "D", pool=kr16_pool[20:], local_starts=0)
    assert c.n_local_added == 0 and np.isnan(c.max_sensitivity_local) and c.bound == c.bound_pool
    assert "poses off the pool may beat it" in c.scope and c.holds()
    assert c.to_dict()["max_sensitivity_local"] is None


# ------------------------------------------------ the sensitivity off the pool
@pytest.mark.parametrize("name", ["kpi", "params", "D"])
def test_sensitivity_gradient_matches_central_differences(kr16, kr16_pool, name):
    objective = DesignObjective(kr16.problem, name)
    m = objective.compute_information(kr16_pool[:40])
    gamma = objective.criterion.compute_gradient(m)
    q = kr16_pool[100:103]
    d, grad = sensitivity_field(objective, gamma, q)
    # the field at a pose is the sensitivity of its block
    assert np.allclose(d, cert.sensitivities(objective.compute_blocks(q), gamma), rtol=1e-12)
    for j in range(q.shape[0]):
        def fun(x, j=j):
            qq = q.copy()
            qq[j] = x
            return sensitivity_field(objective, gamma, qq)[0][j]

        assert relative_error(grad[j], central_difference(fun, q[j])) < 1e-6



# ------------------------------------------------------------------- errors
def test_certify_errors(kr16, kr16_pool):
    q = kr16_pool[:20]
    with pytest.raises(CertificateError, match="valid choices are: 'kpi', 'params', 'D'"):
        cert.certify(kr16, q, "O2", pool=kr16_pool)
    for kwargs in ({"pool": -1}, {"local_starts": -2}, {"local_iterations": 0}, {"local_rounds": 1.5}):
        with pytest.raises(CertificateError, match=next(iter(kwargs))):
            cert.certify(kr16, q, "kpi", **{"pool": kr16_pool, **kwargs})
    with pytest.raises(ShapeError):
        cert.certify(kr16, q[:, :3], "kpi", pool=kr16_pool)


def test_approximate_design_names_are_re_exported():
    """Code importing the approximate design from calib_oed.oed.certificate keeps working."""
    assert set(approximate_design.__all__) <= set(cert.__all__)
    for name in approximate_design.__all__:
        assert getattr(cert, name) is getattr(approximate_design, name)


def test_multistart_gap_of_a_criterion_without_a_bound(kr16):
    """kpi_model has no certificate: the record gives the gap of each refined start to the best of
    them, and the design kept is that best (``docs/oed.md``, "No certificate")."""
    d = design(kr16, 30, "kpi_model", pool=300, n_starts=2, enrich=False,
               settings=SQPSettings(max_iterations=3))
    gap = d.certificate["multistart"]
    values = [run["value"] for run in gap["starts"]]
    assert "not a convex function" in d.certificate["skipped"] and [r["seed"] for r in gap["starts"]] == [0, 1]
    assert d.value == pytest.approx(min(values), rel=1e-12) == pytest.approx(gap["best_value"], rel=1e-12)
    assert min(r["gap"] for r in gap["starts"]) == 0.0 and gap["max_gap"] == pytest.approx(max(values) / min(values) - 1)
    assert "2 starts" in d.efficiency_line()
    one = cert.multistart_gap([(0, 2.0, 1.5)], "why")
    assert one["skipped"] == "why" and one["multistart"]["first_start_gap"] == 0.0 and "--starts K" in one["multistart"]["note"]
    assert cert.multistart_gap([], "why") == {"skipped": "why"}
