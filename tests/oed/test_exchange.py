"""Point-exchange designs: local and global optimality on tiny problems, paths agree, errors."""

from __future__ import annotations

import dataclasses
import itertools
import json

import numpy as np
import pytest

from calib_oed.exceptions import NonFiniteError, NotIdentifiableError, ShapeError
from calib_oed.oed.criteria import (
    ACriterion,
    DCriterion,
    ECriterion,
    make_criterion,
)
from calib_oed.oed.criterion_base import Criterion
from calib_oed.oed.exchange import ExchangeResult, exchange_design, information_matrix
from calib_oed.oed.observability import ObservabilityIndex

N_CAND, N_DESIGN = 12, 4
SHAPES = [(1, 3), (2, 3), (2, 2)]  # (d, n_p)


def tiny_blocks(d, n_p, seed=0):
    return np.random.default_rng(seed).standard_normal((N_CAND, d, n_p))


def tiny_criteria(n_p, seed=0):
    g = np.random.default_rng(seed + 100).standard_normal((2, n_p))
    return [ACriterion.kpi(g), ACriterion.parameters(n_p), DCriterion()]


class Wrapped(Criterion):
    """A criterion the exchange cannot recognise: the base class's looped batch values."""

    def __init__(self, inner):
        self.inner, self.name, self.label = inner, "wrapped " + inner.name, inner.label

    def compute_value(self, info):
        return self.inner.compute_value(info)

    def compute_gradient(self, info):
        return self.inner.compute_gradient(info)


def global_optimum(blocks, n, crit, prior=None):
    combos = list(itertools.combinations(range(blocks.shape[0]), n))
    infos = np.stack([information_matrix(blocks, c, prior) for c in combos])
    return float(np.min(crit.compute_values(infos, singular="inf")))


def assert_no_improving_swap(blocks, result, crit, prior=None, rtol=1e-10):
    design = list(result.indices)
    for i, c in itertools.product(range(len(design)), range(blocks.shape[0])):
        if c in design:
            continue
        trial = design.copy()
        trial[i] = c
        try:
            value = crit.compute_value(information_matrix(blocks, trial, prior))
        except NotIdentifiableError:
            continue
        assert value >= result.value - 2 * rtol * abs(result.value), (i, c)


# ------------------------------------------------------------- optimality
@pytest.mark.parametrize("d, n_p", SHAPES)
def test_local_and_global_optimum(d, n_p):
    blocks = tiny_blocks(d, n_p)
    for crit in tiny_criteria(n_p):
        results = [exchange_design(blocks, N_DESIGN, crit, rng=seed) for seed in range(8)]
        for res in results:
            assert res.converged and res.method == "rank"
            assert res.check(blocks, crit)
            assert_no_improving_swap(blocks, res, crit)
        best = min(res.value for res in results)
        assert best == pytest.approx(global_optimum(blocks, N_DESIGN, crit), rel=1e-10), crit.name


@pytest.mark.parametrize("crit", [ECriterion()] + [ObservabilityIndex(k) for k in range(1, 6)],
                         ids=lambda c: c.name)
def test_other_criteria_reach_a_local_optimum(crit):
    blocks = tiny_blocks(2, 3, seed=1)
    res = exchange_design(blocks, N_DESIGN, crit, rng=0)
    assert res.converged and res.check(blocks, crit)
    assert res.method == ("rank" if crit.name == "O1" else "generic")
    assert_no_improving_swap(blocks, res, crit)


def test_history_never_increases():
    blocks = np.random.default_rng(5).standard_normal((60, 3, 6))
    for crit in tiny_criteria(6) + [ECriterion(), ObservabilityIndex(4)]:
        res = exchange_design(blocks, 8, crit, rng=2)
        values = (res.initial_value,) + res.history
        assert np.all(np.diff(values) <= 0), crit.name
        assert res.n_sweeps == len(res.history) and res.value == res.history[-1]
        assert res.n_exchanges > 0 and res.value < res.initial_value


# ----------------------------------------------------- paths agree, seeds
@pytest.mark.parametrize("d, n_p", SHAPES)
def test_rank_update_and_generic_paths_agree(d, n_p):
    blocks = tiny_blocks(d, n_p, seed=2)
    crits = tiny_criteria(n_p) + [ObservabilityIndex(1)]
    for crit in crits:
        for seed in range(3):
            fast = exchange_design(blocks, N_DESIGN, crit, rng=seed, method="rank")
            slow = exchange_design(blocks, N_DESIGN, crit, rng=seed, method="generic")
            wrapped = exchange_design(blocks, N_DESIGN, Wrapped(crit), rng=seed)
            assert (fast.method, slow.method, wrapped.method) == ("rank", "generic", "generic")
            for other in (slow, wrapped):
                assert np.array_equal(fast.indices, other.indices), crit.name
                assert fast.value == pytest.approx(other.value, rel=1e-12)
                assert fast.n_sweeps == other.n_sweeps


def test_singular_leave_one_out_falls_back():
    """n d = n_p: every M_{-i} is singular, so each rank-update step defers to the generic one."""
    blocks = tiny_blocks(1, 3, seed=3)
    for crit in tiny_criteria(3):
        values = []
        for seed in range(4):
            fast = exchange_design(blocks, 3, crit, rng=seed, method="rank")
            slow = exchange_design(blocks, 3, crit, rng=seed, method="generic")
            assert np.array_equal(fast.indices, slow.indices) and fast.converged
            assert_no_improving_swap(blocks, fast, crit)
            values.append(fast.value)
        assert min(values) == pytest.approx(global_optimum(blocks, 3, crit), rel=1e-10)


def test_same_seed_same_design():
    blocks = tiny_blocks(2, 3)
    crit = DCriterion()
    a = exchange_design(blocks, N_DESIGN, crit, rng=7)
    b = exchange_design(blocks, N_DESIGN, crit, rng=np.random.default_rng(7))
    assert np.array_equal(a.indices, b.indices) and a.value == b.value


def test_start_and_prior():
    blocks = tiny_blocks(1, 3)
    crit = ACriterion.parameters(3)
    res = exchange_design(blocks, N_DESIGN, crit, start=[0, 1, 2, 3])
    assert res.initial_value == pytest.approx(crit.compute_value(information_matrix(blocks, [0, 1, 2, 3])))
    # with a prior, fewer rows than parameters is fine
    prior = np.diag([1.0, 2.0, 3.0])
    results = [exchange_design(blocks, 2, crit, prior=prior, rng=seed) for seed in range(4)]
    for res in results:
        assert res.converged and res.check(blocks, crit, prior=prior)
        assert not res.check(blocks, crit)
        assert_no_improving_swap(blocks, res, crit, prior)
    best = min(res.value for res in results)
    assert best == pytest.approx(global_optimum(blocks, 2, crit, prior), rel=1e-10)


# ----------------------------------------------------------------- result
def test_result_record():
    blocks = tiny_blocks(2, 3)
    crit = make_criterion("kpi", kpi_jacobian=np.ones((1, 3)))
    res = exchange_design(blocks, N_DESIGN, crit, rng=0)
    assert isinstance(res, ExchangeResult) and res.criterion == "kpi" and res.time > 0
    with pytest.raises(ValueError):
        res.indices[0] = 5
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.value = 0.0
    assert not dataclasses.replace(res, value=res.value * (1 + 1e-6)).check(blocks, crit)
    assert not dataclasses.replace(res, indices=[0, 0, 1, 2]).check(blocks, crit)
    with pytest.raises(ValueError, match="out of range"):
        dataclasses.replace(res, indices=[0, 1, 2, 99]).check(blocks, crit)
    data = json.loads(json.dumps(res.to_dict()))
    assert data["indices"] == res.indices.tolist() and data["converged"] is True
    stopped = exchange_design(blocks, N_DESIGN, crit, rng=0, max_sweeps=0)
    assert not stopped.converged and stopped.history == () and stopped.value == stopped.initial_value


# ----------------------------------------------------------------- errors
def test_bad_input():
    blocks = tiny_blocks(1, 3)
    crit = DCriterion()
    with pytest.raises(ValueError, match="between 1 and"):
        exchange_design(blocks, N_CAND + 1, crit)
    with pytest.raises(ValueError, match="rows for n_p = 3"):
        exchange_design(blocks, 2, crit)
    with pytest.raises(ShapeError):
        exchange_design(blocks[0], 2, crit)
    with pytest.raises(NonFiniteError):
        exchange_design(np.where(np.arange(3) == 1, np.nan, blocks), 4, crit)
    with pytest.raises(ValueError, match="distinct"):
        exchange_design(blocks, 4, crit, start=[0, 1, 1, 2])
    with pytest.raises(ValueError, match="must be in"):
        exchange_design(blocks, 4, crit, start=[0, 1, 2, 12])
    with pytest.raises(ShapeError):
        exchange_design(blocks, 4, crit, start=[0, 1, 2])
    with pytest.raises(ValueError, match="integer"):
        exchange_design(blocks, 4, crit, start=[0.0, 1.0, 2.0, 3.0])
    with pytest.raises(ShapeError):
        exchange_design(blocks, 4, crit, prior=np.eye(2))
    with pytest.raises(ValueError, match="semidefinite"):
        exchange_design(blocks, 4, crit, prior=-np.eye(3))
    with pytest.raises(ValueError, match="method"):
        exchange_design(blocks, 4, crit, method="fast")
    with pytest.raises(ValueError, match="method='rank'"):
        exchange_design(blocks, 4, ECriterion(), method="rank")
    with pytest.raises(TypeError):
        exchange_design(blocks, 4, "D")
    with pytest.raises(ValueError, match="rtol"):
        exchange_design(blocks, 4, crit, rtol=-1.0)


def test_singular_starts():
    blocks = tiny_blocks(1, 3)
    blocks[:, :, 2] = 0.0  # no candidate sees parameter 2
    with pytest.raises(NotIdentifiableError, match="random designs") as info:
        exchange_design(blocks, 4, DCriterion(), rng=0)
    assert info.value.names == ["column 2"]
    with pytest.raises(NotIdentifiableError, match="start design"):
        exchange_design(blocks, 4, DCriterion(), start=[0, 1, 2, 3])
