"""The staged start of a large kpi_model design: when it applies, the moved copy, the pipeline."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import calib_oed.oed.model_error as me
import calib_oed.oed.staged as staged
from calib_oed.oed.design import design
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.problem import COLLISION_KINDS
from calib_oed.oed.starts import multiplicities
from calib_oed.solver.sqp import SQPSettings

BIG = staged.STAGED_MIN_POSES


def test_it_applies_to_large_default_kpi_model_designs_only():
    model_error = SimpleNamespace(needs_design=True)
    assert staged.staged_half(model_error, True, BIG, "exchange", None, "mean") == BIG // 2
    assert staged.staged_half(model_error, True, BIG + 1, "exchange", None, "mean") == BIG // 2 + 1
    assert staged.staged_half(model_error, True, BIG - 1, "exchange", None, "mean") == 0
    for args in [(False, BIG, "exchange", None, "mean"),             # damped BFGS (isotropic prior)
                 (True, BIG, "heuristic", None, "mean"),             # another start
                 (True, BIG, np.zeros((BIG, 6)), None, "mean"),      # a given start
                 (True, BIG, "exchange", SQPSettings(), "mean"),     # the user's own budget
                 (True, BIG, "exchange", None, "max")]:
        assert staged.staged_half(model_error, *args) == 0
    assert staged.staged_half(SimpleNamespace(needs_design=False), True, BIG, "exchange", None, "mean") == 0
    final = staged.staged_settings(SQPSettings(max_iterations=72))
    assert final.max_iterations == staged.STAGED_ITERATIONS and final.hessian_every == staged.STAGED_HESSIAN_EVERY


def _design_rows(kr16, q):
    from calib_oed.feasibility.batch_fk import batch_body_states

    return kr16.feasibility.compute_from_states(q, batch_body_states(kr16.problem.robot.model, q),
                                                False, COLLISION_KINDS).feasible


@pytest.fixture(scope="module")
def feasible_poses(kr16):
    from calib_oed.feasibility.sampling import sample_feasible

    return sample_feasible(kr16.feasibility, 40, 5)


def test_the_moved_copy_is_feasible_distinct_and_seeded(kr16, feasible_poses):
    q = feasible_poses
    robot = kr16.problem.robot
    copy, exact = staged.moved_copy(kr16.feasibility, q, np.random.default_rng(3))
    assert copy.shape == q.shape and _design_rows(kr16, copy).all()
    assert np.all(copy >= robot.lower) and np.all(copy <= robot.upper)
    moved = np.abs(copy - q).max(axis=1) > 0
    assert int((~moved).sum()) == exact < len(q) // 4
    # the offsets are of the promised size: at most the first draw's (0.01 rad, 5 sigma)
    assert np.abs(copy - q).max() < 5 * staged.STAGED_OFFSET
    again, _ = staged.moved_copy(kr16.feasibility, q, np.random.default_rng(3))
    assert np.array_equal(again, copy)
    # the first draw is the seeded normal offsets of every pose (the bench's --doubled --perturb)
    first = np.clip(q + staged.STAGED_OFFSET * np.random.default_rng(3).standard_normal(q.shape),
                    robot.lower, robot.upper)
    ok = _design_rows(kr16, first)
    assert ok.any() and np.array_equal(copy[ok], first[ok])
    # no draw can be feasible: every pose is copied exactly, and the copy says so
    far, exact = staged.moved_copy(kr16.feasibility, q, np.random.default_rng(3), offset=50.0, draws=1)
    infeasible = ~_design_rows(kr16, np.clip(q + 50.0 * np.random.default_rng(3).standard_normal(q.shape),
                                             robot.lower, robot.upper))
    assert exact == int(infeasible.sum()) > 0 and np.array_equal(far[infeasible], q[infeasible])


def test_an_interrupted_first_stage_interrupts_the_design(kr16, feasible_poses):
    def half(seed):
        return SimpleNamespace(q=feasible_poses[:4], solver={"interrupted": True}, value=1.0, start_value=2.0)

    with pytest.raises(KeyboardInterrupt):
        staged.staged_starts(half, kr16.feasibility, 8, 0, 1)


def test_a_staged_design_starts_from_half_the_poses_twice(kr16, monkeypatch):
    n = 20
    monkeypatch.setattr(staged, "STAGED_MIN_POSES", n)
    monkeypatch.setattr(staged, "STAGED_ITERATIONS", 6)
    monkeypatch.setattr(me, "MODEL_ERROR_EXACT_ITERATIONS", 10)  # a short first stage
    half = design(kr16, n // 2, None, pool=300, seed=1, enrich=False, certificate=False)
    assert half.method == "exchange+sqp"  # below the threshold: the direct design

    class Progress:  # a callback with a stage hook: told the poses of each SQP's design
        def __init__(self):
            self.log = []

        def stage(self, poses):
            self.log.append(("stage", poses))

        def __call__(self, record):
            self.log.append(("iteration", record.iteration))

    progress = Progress()
    d = design(kr16, n, None, pool=300, seed=1, enrich=False, certificate=False, callback=progress)
    stages = [i for i, (kind, _) in enumerate(progress.log) if kind == "stage"]
    assert [progress.log[i][1] for i in stages] == [n // 2, n] and stages[0] == 0
    final = progress.log[stages[1] + 1:]  # the n-pose SQP's records, from iteration 0
    assert final[0] == ("iteration", 0) and len(final) == d.solver["iterations"]
    assert d.method == "staged+sqp" and d.solver["start"] == "staged" and d.solver["pool"] is None
    stage = d.solver["staged"]["stages"][0]
    assert stage["poses"] == n // 2 and np.isclose(stage["value"], half.value, rtol=1e-12)
    assert d.solver["iterations"] <= 6 and d.q.shape == (n, kr16.problem.robot.nq) and d.feasible
    # the start: the smaller design and its moved copy, whose value the record keeps
    copy, exact = staged.moved_copy(kr16.feasibility, half.q, np.random.default_rng(1))
    assert exact == stage["exact_copies"]
    start = np.vstack([half.q, copy])
    objective = DesignObjective(kr16.problem, me.scene_criterion(kr16, None))
    assert np.isclose(d.start_value, objective.compute_value(start), rtol=1e-12)
    assert d.value < d.start_value and len(multiplicities(start)) == n - exact
    assert f"start: the {n // 2}-pose design" in d.summary()
