"""The exact Hessian of kpi_model (calib_oed.oed.model_error_hessian) against central differences
of its exact gradient, on kr16 (fms_kr16, tracker noise that moves with the pose) and UR5."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference
from test_joint_prior import strong_prior
from test_model_error_design import two_reflector_problem

import calib_oed.oed.model_error_hessian as meh
from calib_oed.calibration.workflow import setup
from calib_oed.oed.hessian import has_exact_hessian
from calib_oed.oed.model_error import scene_criterion
from calib_oed.oed.objective import DesignObjective
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module", params=["fms_kr16", "ur5_table"])
def case(request):
    s = setup(load_scene(request.param))
    objective = DesignObjective(s.problem, scene_criterion(s, "kpi_model"))
    return s, objective, s.problem.robot.random_configurations(10, 3)


def test_exact_hessian_matches_central_differences_of_the_gradient(case, monkeypatch):
    s, objective, q = case
    seen = {}
    exact = meh.compute_hessian

    def keep(*args, **kwargs):
        seen["h"] = exact(*args, **kwargs)
        return seen["h"]

    monkeypatch.setattr(meh, "compute_hessian", keep)
    monkeypatch.setattr(meh, "FULL_COUPLING_MAX_SIZE", 0)  # the lifted form of larger designs
    structured = objective.compute_hessian(q)
    fd = central_difference(lambda x: objective.compute(x.reshape(q.shape)).gradient.ravel(), q.ravel())
    h = seen["h"]
    assert np.abs(h - fd).max() <= 1e-6 * np.abs(fd).max()
    nv = q.shape[1]
    off = ~np.kron(np.eye(len(q)), np.ones((nv, nv))).astype(bool)
    assert np.abs(h[off]).max() > 1e-3 * np.abs(h).max()  # the kernel couples the poses
    theta = np.linalg.eigvalsh(h)
    assert theta[0] < 0 < theta[-1]  # indefinite: the SQP gets |H|
    rank = structured.low_rank.shape[1]
    assert rank == len(h) // 3  # the solver's lifted QP, not a dense one
    # up to FULL_COUPLING_MAX_SIZE, the whole |H|, its eigenvalues floored
    monkeypatch.setattr(meh, "FULL_COUPLING_MAX_SIZE", len(h))
    whole = objective.compute_hessian(q)
    assert whole.low_rank.shape[1] == len(h) and not np.any(whole.blocks)
    vals, vecs = np.linalg.eigh(h)
    mag = np.maximum(np.abs(vals), meh.EIGENVALUE_FLOOR * np.abs(vals).max())
    np.testing.assert_allclose(whole.dense(), (vecs * mag) @ vecs.T, atol=1e-9 * np.abs(vals).max())
    kept = np.linalg.eigvalsh(structured.low_rank.T @ structured.low_rank)
    np.testing.assert_allclose(kept, np.sort(np.abs(theta))[-rank:], rtol=1e-8, atol=1e-8 * np.abs(theta).max())
    assert np.linalg.eigvalsh(structured.blocks).min() >= -1e-10 * np.abs(theta).max()


def assert_hessian_matches_differences(objective, q, monkeypatch):
    """The exact Hessian ``compute_hessian`` builds at ``q`` against central differences of the exact gradient."""
    seen = {}
    exact = meh.compute_hessian
    monkeypatch.setattr(meh, "compute_hessian", lambda *a, **k: seen.setdefault("h", exact(*a, **k)))
    objective.compute_hessian(q)
    fd = central_difference(lambda x: objective.compute(x.reshape(q.shape)).gradient.ravel(), q.ravel())
    assert np.abs(seen["h"] - fd).max() <= 1e-6 * np.abs(fd).max()


def test_exact_hessian_with_two_reflectors_and_two_working_configurations(monkeypatch):
    """Two reflectors per pose (six rows) and two weighted KPI points, every part of the joint prior
    on (ur5, isotropic noise): the Hessian against central differences of the exact gradient."""
    problem = two_reflector_problem()
    objective = DesignObjective(problem, "kpi_model", model_error=strong_prior(problem))
    q = problem.robot.random_configurations(8, 5)
    assert_hessian_matches_differences(objective, q, monkeypatch)


def test_gravity_torque_hessians_match_central_differences(case):
    s, objective, q = case
    load = objective.criterion.prior.gravity
    got = meh.gravity_hessians(load, q[:2])
    for k in range(2):
        fd = central_difference(lambda x: load.torque_derivatives(x[None])[0], q[k])
        assert np.abs(got[k] - fd).max() <= 1e-6 * np.abs(fd).max()


def test_structured_hessian_is_exact_where_positive_definite():
    rng = np.random.default_rng(0)
    a = rng.standard_normal((12, 12))
    h = a @ a.T + np.eye(12)
    np.testing.assert_allclose(meh.structured_hessian(h, 6).dense(), h, rtol=1e-10, atol=1e-10)
    # of low rank: exact on the pose blocks and on the kept eigenvectors
    b = rng.standard_normal((12, 3))
    h = b @ b.T + np.kron(np.eye(2), np.diag(np.arange(1.0, 7.0)))
    low = meh.structured_hessian(h, 6, 4)
    assert low.low_rank.shape == (12, 4)
    blocks = np.kron(np.eye(2), np.ones((6, 6))).astype(bool)
    np.testing.assert_allclose(low.dense()[blocks], h[blocks], rtol=1e-10, atol=1e-10)
    theta, vec = np.linalg.eigh(h)
    np.testing.assert_allclose(low.low_rank @ low.low_rank.T @ vec[:, -4:], vec[:, -4:] * theta[-4:], atol=1e-9)


def test_criteria_it_does_not_cover(case):
    s, objective, _ = case
    assert has_exact_hessian(objective.criterion)
    assert not has_exact_hessian(scene_criterion(s, "kpi_kriging"))
    assert not has_exact_hessian(scene_criterion(s, "kpi_model", s.scene.discrepancy()))  # isotropic


def test_pieces_shared_with_the_gradient_change_no_bit(case, monkeypatch):
    """The Hessian reuses the gradient's covariances and kernel gradients at the same design
    (kept by the criterion): the same bits as a fresh criterion's, none stale once the design moves."""
    s, objective, q = case
    seen = []
    exact = meh.compute_hessian
    monkeypatch.setattr(meh, "compute_hessian", lambda *a, **k: seen.append(exact(*a, **k)) or seen[-1])
    q2 = q.copy()
    q2[3, 1] += 0.05
    fresh = DesignObjective(s.problem, scene_criterion(s, "kpi_model"))
    fresh.compute_hessian(q)  # nothing kept yet: every piece computed here
    grad_fresh = fresh.compute(q2).gradient  # q2 before q on this one
    objective.compute(q2)
    objective.compute(q)  # the gradient at q fills what the Hessian then reuses
    objective.compute_hessian(q)
    assert np.array_equal(seen[1], seen[0])
    assert np.array_equal(objective.compute(q2).gradient, grad_fresh)
    kept = [v for k, v in objective.criterion._memo.items() if k[0] == "covariances"]
    assert len(kept) == 1 and not kept[0][0].flags.writeable  # kept arrays cannot be changed by a caller


def test_exact_hessian_with_the_motor_side_part(monkeypatch):
    """The optional short-length part of the joint prior (calib_oed.measurement.joint_prior) in the
    exact Hessian, against central differences of the exact gradient (fms_kr16; poses near each other)."""
    from calib_oed.calibration.joint_prior_choice import joint_prior
    from calib_oed.measurement.joint_prior import ARCSEC

    s = setup(load_scene("fms_kr16"))
    prior = joint_prior(s.problem).with_motor(20.0 * ARCSEC, 0.05)
    objective = DesignObjective(s.problem, scene_criterion(s, "kpi_model", prior))
    q = s.problem.robot.random_configurations(10, 3)
    q = np.vstack([q, q[:3] + 0.02])  # pairs within the length scale
    assert_hessian_matches_differences(objective, q, monkeypatch)
