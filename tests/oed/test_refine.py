"""The design SQP's settings (:mod:`calib_oed.oed.refine`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import calib_oed.oed.refine as refine
from calib_oed.oed.design import heuristic_designs
from calib_oed.oed.objective import DesignObjective
from calib_oed.solver.sqp import SQPSettings


@pytest.mark.parametrize("criterion, hessian, given, used", [
    ("kpi", "exact", None, refine.EXACT_TRUST_UPDATE),
    ("params", "exact", None, refine.EXACT_TRUST_UPDATE),
    ("kpi", "exact", "edge", "edge"),  # a rule the caller gives is kept
    ("kpi", "bfgs", None, None),  # damped BFGS: the SQP's own rule
])
def test_an_exact_hessian_design_takes_the_ratio_trust_rule(kr16_setup, monkeypatch, criterion, hessian,
                                                            given, used):
    seen = []
    solve = refine.solve_sqp

    def spy(*args, settings, **kwargs):
        seen.append(settings)
        return solve(*args, settings=settings, **kwargs)

    monkeypatch.setattr(refine, "solve_sqp", spy)
    s = kr16_setup
    q0 = heuristic_designs(s, 12, [0])[0].q
    value, q, phi0, result = refine.optimise_from(
        DesignObjective(s.problem, criterion), s.feasibility, q0,
        settings=SQPSettings(max_iterations=2, trust_update=given), hessian=hessian)
    design_run = seen[0]  # a later run, if any, is the projection onto the feasible set
    assert design_run.trust_update == used
    assert design_run.max_iterations == 2 and result.iterations <= 2 and q.shape == q0.shape


def test_a_design_sqp_takes_the_design_penalty_margin(kr16_setup, monkeypatch):
    """Without settings, a design SQP runs DESIGN_SQP: the penalty margin far below the SQP's
    default (tests/solver/test_sqp.py shows the creep the default causes)."""
    seen = []
    solve = refine.solve_sqp

    def spy(*args, settings, **kwargs):
        seen.append(settings)
        return solve(*args, settings=replace(settings, max_iterations=2), **kwargs)

    monkeypatch.setattr(refine, "solve_sqp", spy)
    s = kr16_setup
    refine.optimise_from(DesignObjective(s.problem, "kpi"), s.feasibility, heuristic_designs(s, 12, [0])[0].q)
    assert seen[0].penalty_margin == refine.DESIGN_PENALTY_MARGIN < SQPSettings().penalty_margin
    assert seen[0].trust_update == refine.EXACT_TRUST_UPDATE


def test_a_design_sqp_starts_in_the_design_trust_box(kr16_setup, monkeypatch):
    """DESIGN_SQP's first box is DESIGN_STEP_BOUND, below the SQP's default; the first QP's box is it,
    and the ratio rule grows it after the full steps the model predicts well."""
    seen, results = [], []
    solve = refine.solve_sqp

    def spy(*args, settings, **kwargs):
        seen.append(settings)
        results.append(solve(*args, settings=replace(settings, max_iterations=8), **kwargs))
        return results[-1]

    monkeypatch.setattr(refine, "solve_sqp", spy)
    s = kr16_setup
    refine.optimise_from(DesignObjective(s.problem, "kpi"), s.feasibility, heuristic_designs(s, 12, [0])[0].q)
    assert seen[0].step_bound == refine.DESIGN_STEP_BOUND == 0.03 < SQPSettings().step_bound
    boxes = [r.step_bound for r in results[0].history]
    assert boxes[0] == refine.DESIGN_STEP_BOUND and max(boxes) > refine.DESIGN_STEP_BOUND


def test_the_projection_takes_pose_blocks_and_the_block_qp(kr16_setup, monkeypatch):
    """A design of 50 poses (300 variables, from ``block_qp_min_size``) pushed off the feasible set,
    its QPs above ``max_dense_qp_size`` (set to 300 here; 3000 by default, 500 poses):
    ``project_feasible`` gives the SQP one BFGS block per pose, so its QPs are block QPs, not
    sparse ProxQP on a dense BFGS matrix, and it ends where the projection with one dense block
    ends (the same problem: the KKT point of min ||y - x||^2 / 2 on the constraints), feasible."""
    from calib_oed.feasibility.constraints import FEASIBILITY_TOL
    from calib_oed.feasibility.sampling import sample_feasible
    from calib_oed.oed.problem import DesignProblem

    s = kr16_setup
    q0 = sample_feasible(s.feasibility, 50, 5)
    nlp = DesignProblem(DesignObjective(s.problem, "kpi"), s.feasibility, len(q0))
    x = q0.ravel() + np.random.default_rng(0).normal(scale=0.05, size=q0.size)
    assert nlp.max_violation(x) > 10 * FEASIBILITY_TOL  # the test's premise
    seen, solve = [], refine.solve_sqp

    def spy(*args, **kwargs):
        seen.append((kwargs.get("block_size"), solve(*args, **kwargs)))
        return seen[-1][1]

    settings = replace(refine.PROJECTION_SQP, max_dense_qp_size=300)
    monkeypatch.setattr(refine, "solve_sqp", spy)
    monkeypatch.setattr(refine, "PROJECTION_SQP", settings)
    y = refine.project_feasible(nlp, x)
    block_size, result = seen[0]
    assert block_size == nlp.nq
    assert result.status.name == "CONVERGED"
    assert {r.qp_backend for r in result.history if r.qp_backend} == {"block"}
    assert nlp.max_violation(y) <= FEASIBILITY_TOL
    one_block = solve(lambda v: (0.5 * float((v - x) @ (v - x)), v - x), x, constraints=nlp.compute_constraints,
                      bounds=nlp.bounds, settings=settings)
    assert one_block.status.name == "CONVERGED"
    assert {r.qp_backend for r in one_block.history if r.qp_backend} == {"sparse"}
    assert np.abs(y - one_block.x).max() < 1e-5
    assert np.linalg.norm(y - x) <= np.linalg.norm(one_block.x - x) + 1e-9
