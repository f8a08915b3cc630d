"""Design criteria: hand-derived values, finite-difference gradients, batching, errors."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.exceptions import (
    NonFiniteError,
    NotIdentifiableError,
    ShapeError,
    UnknownCriterionError,
)
from calib_oed.oed.criteria import (
    CRITERIA,
    MATRIX_CRITERIA,
    ACriterion,
    DCriterion,
    ECriterion,
    make_criterion,
)
from calib_oed.oed.observability import ObservabilityIndex

G_HAND = np.array([[1.0, 1.0], [1.0, -1.0]])


def random_spd(n, seed):
    """A well-conditioned random SPD matrix with distinct eigenvalues."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((n, n))
    return q.T @ q + n * np.eye(n)


def all_criteria(n_p, seed=0):
    g = np.random.default_rng(seed).standard_normal((3, n_p))
    return [make_criterion(name, kpi_jacobian=g, n_params=n_p) for name in MATRIX_CRITERIA]


# ------------------------------------------------------------ hand values
def test_values_on_diagonal_matrix():
    """M = diag(4, 1): C = diag(1/4, 1), singular values of F are 2 and 1."""
    m = np.diag([4.0, 1.0])
    m_rows = 8
    assert ACriterion.parameters(2).compute_value(m) == pytest.approx((0.25 + 1.0) / 2)  # tr(C)/2, not tr(M)
    # G C G^T has diagonal (1/4 + 1, 1/4 + 1)
    assert ACriterion.kpi(G_HAND).compute_value(m) == pytest.approx(1.25)
    assert DCriterion().compute_value(m) == pytest.approx(-np.log(4.0))
    assert ECriterion().compute_value(m) == pytest.approx(1.0)
    expected = {1: np.sqrt(2.0) / np.sqrt(m_rows), 2: 0.5, 3: 1.0, 4: 0.5, 5: 1.0 / (0.5 + 1.0)}
    for k, o_k in expected.items():
        index = ObservabilityIndex(k)
        assert index.compute_index(m, m_rows) == pytest.approx(o_k)
    for k in (2, 3, 4, 5):
        assert ObservabilityIndex(k).compute_value(m) == pytest.approx(-np.log(expected[k]))
    # O1's value drops the constant sqrt(m)
    assert ObservabilityIndex(1).compute_value(m) == pytest.approx(-0.5 * np.log(2.0))


def test_values_on_full_two_by_two():
    """M = [[2, 1], [1, 2]]: eigenvalues 3 and 1, C = [[2, -1], [-1, 2]]/3."""
    m = np.array([[2.0, 1.0], [1.0, 2.0]])
    assert ACriterion.parameters(2).compute_value(m) == pytest.approx(2.0 / 3.0)
    # g = (1, 1): g C g^T = 2/3; g = (1, -1): 2; mean 4/3
    assert ACriterion.kpi(G_HAND[:1]).compute_value(m) == pytest.approx(2.0 / 3.0)
    assert ACriterion.kpi(G_HAND[1:]).compute_value(m) == pytest.approx(2.0)
    assert ACriterion.kpi(G_HAND).compute_value(m) == pytest.approx(4.0 / 3.0)
    assert ACriterion(G_HAND.T @ G_HAND, 2).compute_value(m) == pytest.approx(4.0 / 3.0)  # root from eigh
    assert DCriterion().compute_value(m) == pytest.approx(-np.log(3.0))
    assert ECriterion().compute_value(m) == pytest.approx(1.0)
    s1, s2 = np.sqrt(3.0), 1.0
    assert ObservabilityIndex(1).compute_index(m, 2) == pytest.approx(np.sqrt(s1 * s2) / np.sqrt(2))
    assert ObservabilityIndex(2).compute_index(m) == pytest.approx(s2 / s1)
    assert ObservabilityIndex(3).compute_index(m) == pytest.approx(s2)
    assert ObservabilityIndex(4).compute_index(m) == pytest.approx(s2**2 / s1)
    assert ObservabilityIndex(5).compute_index(m) == pytest.approx(1.0 / (1 / s1 + 1 / s2))


def test_indices_of_a_criteria_are_their_values():
    m = random_spd(4, 1)
    for crit in all_criteria(4)[:4]:
        assert crit.compute_index(m, 12) == crit.compute_value(m)


def test_index_is_value_of_stacked_f():
    """O_k from the singular values of a stacked F equals compute_index(F^T F, m)."""
    f = np.random.default_rng(3).standard_normal((9, 4))
    sigma = np.linalg.svd(f, compute_uv=False)
    m = f.T @ f
    expected = [np.prod(sigma) ** 0.25 / 3.0, sigma[-1] / sigma[0], sigma[-1], sigma[-1] ** 2 / sigma[0],
                1.0 / np.sum(1.0 / sigma)]
    for k, o_k in enumerate(expected, start=1):
        assert ObservabilityIndex(k).compute_index(m, 9) == pytest.approx(o_k, rel=1e-10)


# -------------------------------------------------------------- gradients
@pytest.mark.parametrize("n", [2, 3, 5, 8])
def test_gradients_match_central_differences(n):
    """d phi = tr(G dM) along every symmetric direction: dphi/dM_ij = 2 G_ij (i != j), G_ii."""
    m0 = random_spd(n, n)
    iu = np.triu_indices(n)

    def sym(x):
        m = np.zeros((n, n))
        m[iu] = x
        return m + np.triu(m, 1).T

    for crit in all_criteria(n, seed=n):
        grad = crit.compute_gradient(m0)
        assert np.allclose(grad, grad.T, rtol=0, atol=1e-14 * np.abs(grad).max())
        numeric = central_difference(lambda x, c=crit: c.compute_value(sym(x)), m0[iu], eps=1e-5)
        analytic = np.where(iu[0] == iu[1], 1.0, 2.0) * grad[iu]
        assert relative_error(analytic, numeric) < 1e-6, crit.name


def test_e_gradient_is_rank_one():
    m = random_spd(5, 2)
    w, v = np.linalg.eigh(m)
    assert np.allclose(ECriterion().compute_gradient(m), -np.outer(v[:, 0], v[:, 0]) / w[0] ** 2)


# ------------------------------------------------------------------ batch
@pytest.mark.parametrize("n", [2, 6])
def test_batched_values_equal_looped(n):
    infos = np.stack([random_spd(n, seed) for seed in range(7)])
    for crit in all_criteria(n):
        batched = crit.compute_values(infos)
        looped = np.array([crit.compute_value(m) for m in infos])
        assert batched.shape == (7,)
        assert np.allclose(batched, looped, rtol=1e-12, atol=1e-14), crit.name


def test_batched_singular_member():
    infos = np.stack([random_spd(3, 0), np.diag([1.0, 1.0, 0.0]), random_spd(3, 1)])
    for crit in all_criteria(3):
        with pytest.raises(NotIdentifiableError, match="batch member 1"):
            crit.compute_values(infos)
        values = crit.compute_values(infos, singular="inf")
        assert np.isinf(values[1]) and np.all(np.isfinite(values[[0, 2]])), crit.name
        assert values[0] == pytest.approx(crit.compute_value(infos[0]))


# ----------------------------------------------------------------- scaling
@pytest.mark.parametrize("n", [2, 5])
def test_scaling_information(n):
    """M -> 2M: covariance halves, so A halves and log det C drops by n log 2."""
    m = random_spd(n, 7)
    for crit in all_criteria(n)[:2]:
        assert crit.compute_value(2 * m) == pytest.approx(crit.compute_value(m) / 2, rel=1e-12)
    assert DCriterion().compute_value(2 * m) == pytest.approx(DCriterion().compute_value(m) - n * np.log(2))
    assert ECriterion().compute_value(2 * m) == pytest.approx(ECriterion().compute_value(m) / 2)
    assert ObservabilityIndex(2).compute_value(2 * m) == pytest.approx(ObservabilityIndex(2).compute_value(m))


# ------------------------------------------------------------------ errors
def test_unknown_criterion_lists_valid_names():
    with pytest.raises(UnknownCriterionError) as info:
        make_criterion("A-optimal")
    assert info.value.name == "A-optimal"
    assert info.value.valid == list(CRITERIA)
    for name in CRITERIA:
        assert repr(name) in str(info.value)


def test_factory_needs_its_data():
    with pytest.raises(ValueError, match="kpi_jacobian"):
        make_criterion("kpi")
    with pytest.raises(ValueError, match="n_params"):
        make_criterion("params")
    assert make_criterion("params", kpi_jacobian=np.ones((3, 4))).dim == 4
    for name in MATRIX_CRITERIA:
        assert make_criterion(name, kpi_jacobian=np.ones((1, 2)), n_params=2).name == name
    with pytest.raises(ValueError, match="problem"):
        make_criterion("kpi_model", kpi_jacobian=np.ones((3, 2)))


def test_invalid_information_matrices():
    crit = DCriterion()
    with pytest.raises(ShapeError):
        crit.compute_value(np.ones((2, 3)))
    with pytest.raises(NonFiniteError):
        crit.compute_value(np.array([[1.0, np.nan], [np.nan, 1.0]]))
    with pytest.raises(ValueError, match="not symmetric"):
        crit.compute_value(np.array([[2.0, 1.0], [0.0, 2.0]]))
    with pytest.raises(ShapeError):
        ACriterion.kpi(np.ones((1, 3))).compute_value(np.eye(2))
    with pytest.raises(ShapeError):
        crit.compute_values(np.eye(2))
    for c in all_criteria(2):
        with pytest.raises(NotIdentifiableError, match="column 1"):
            c.compute_value(np.diag([1.0, 0.0]))
        with pytest.raises(NotIdentifiableError):
            c.compute_gradient(np.array([[1.0, 2.0], [2.0, 1.0]]))  # indefinite


def test_invalid_construction():
    with pytest.raises(ValueError, match="k must be"):
        ObservabilityIndex(6)
    with pytest.raises(ValueError, match="semidefinite"):
        ACriterion(np.diag([1.0, -1.0]), 2)
    with pytest.raises(ValueError, match="zero"):
        ACriterion(np.zeros((2, 2)), 2)
    with pytest.raises(ValueError, match="R\\^T R"):
        ACriterion(np.eye(2), 2, root=2 * np.eye(2))
    with pytest.raises(ValueError, match="dim"):
        ACriterion(np.eye(2), 0)
    with pytest.raises(ValueError, match="n_rows"):
        ObservabilityIndex(1).compute_index(np.eye(2))
    crit = ACriterion.parameters(2)
    with pytest.raises(AttributeError):
        crit.dim = 3
    with pytest.raises(ValueError):
        crit.weight[0, 0] = 2.0


# ------------------------------------------------------ weighted KPI criterion
def test_weighted_kpi_is_the_weighted_mean_of_point_variances():
    """sum_i w_i tr(G_i C G_i^T) / (3 sum_i w_i), by hand; unit (or equal) weights: the old criterion."""
    n_p, t = 5, 4
    g = np.random.default_rng(3).standard_normal((3 * t, n_p))
    info = random_spd(n_p, 4)
    c = np.linalg.inv(info)
    v = np.array([np.trace(g[3 * i:3 * i + 3] @ c @ g[3 * i:3 * i + 3].T) / 3 for i in range(t)])
    w = np.array([1.0, 0.0, 2.5, 0.5])
    crit = ACriterion.kpi(g, w)
    assert np.isclose(crit.compute_value(info), (w * v).sum() / w.sum(), rtol=1e-12)
    assert relative_error(crit.compute_gradient(info),
                          central_difference(lambda m: crit.compute_value(0.5 * (m + m.T)), info)
                          .reshape(n_p, n_p)) < 1e-6
    plain = ACriterion.kpi(g)
    for same in (None, np.ones(t), np.full(t, 3.0)):
        eq = ACriterion.kpi(g, same)
        assert np.array_equal(eq.root, plain.root) and eq.compute_value(info) == plain.compute_value(info)
    assert np.isclose(plain.compute_value(info), v.mean(), rtol=1e-12)
    assert make_criterion("kpi", kpi_jacobian=g, kpi_weights=w).compute_value(info) == crit.compute_value(info)
    with pytest.raises(ShapeError):
        ACriterion.kpi(g, np.ones(t + 1))
    for bad in (np.zeros(t), np.array([1.0, -1.0, 1.0, 1.0]), np.array([1.0, np.nan, 1.0, 1.0])):
        with pytest.raises(ValueError, match="weights"):
            ACriterion.kpi(g, bad)
