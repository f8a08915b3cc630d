"""The tracker error model: covariance, its derivative, whitening, sampling, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference, make_space, relative_error

from calib_oed.exceptions import ParameterError, ShapeError
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.sensitivity import weighted_jacobian

# Leica AT500 MPE (k = 2): ADM 10 um + 0.3 um/m, transverse 15 um + 6 um/m; KR 16 repeatability
NOISE = TrackerNoise(radial=(5e-6, 1.5e-7), lateral=(7.5e-6, 3e-6), repeatability=1.1e-5)


@pytest.fixture
def points():
    rng = np.random.default_rng(3)
    return rng.normal(size=(6, 3)) * 1.5 + np.array([0.5, 2.0, 0.3])


def test_covariance_has_radial_and_lateral_axes(points):
    cov = NOISE.covariance(points)
    sr, st = NOISE.sigmas(points)
    rho2 = NOISE.repeatability**2
    for c, y, r, t in zip(cov, points, sr, st, strict=True):
        u = y / np.linalg.norm(y)
        lateral = np.linalg.svd(u[None, :])[2][1:]  # two unit vectors orthogonal to u
        np.testing.assert_allclose(c, c.T, rtol=0, atol=1e-25)
        assert u @ c @ u == pytest.approx(r**2 + rho2, rel=1e-12)
        for v in lateral:
            assert v @ c @ v == pytest.approx(t**2 + rho2, rel=1e-12)
            assert v @ c @ u == pytest.approx(0.0, abs=1e-12 * (t**2 + rho2))
    d = np.linalg.norm(points, axis=1)
    np.testing.assert_allclose(sr, 5e-6 + 1.5e-7 * d, rtol=1e-14)
    np.testing.assert_allclose(st, 7.5e-6 + 3e-6 * d, rtol=1e-14)


def test_isotropic_reproduces_sigma(points):
    cov = TrackerNoise.isotropic(1e-5).covariance(points)
    np.testing.assert_allclose(cov, np.broadcast_to(1e-10 * np.eye(3), cov.shape), rtol=1e-12,
                               atol=1e-24)


def test_whitening_is_inverse_cholesky(points):
    cov, chol, w = NOISE.covariance(points), NOISE.cholesky(points), NOISE.whitening(points)
    np.testing.assert_allclose(np.triu(chol, 1), 0.0, atol=0)
    np.testing.assert_allclose(chol @ np.swapaxes(chol, 1, 2), cov, rtol=1e-12, atol=1e-25)
    np.testing.assert_allclose(w @ cov @ np.swapaxes(w, 1, 2),
                               np.broadcast_to(np.eye(3), cov.shape), atol=1e-10)


def test_samples_have_the_stated_covariance():
    """Monte Carlo: 40000 draws at one point; each covariance entry within 5 standard errors."""
    y = np.array([[0.4, 2.6, -0.5]])
    n = 40000
    rng = np.random.default_rng(11)
    draws = NOISE.sample(np.repeat(y, n, axis=0), rng)
    cov = NOISE.covariance(y)[0]
    emp = draws.T @ draws / n
    # var of x_a x_b = S_aa S_bb + S_ab^2 for a zero-mean Gaussian
    se = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / n)
    assert np.all(np.abs(emp - cov) < 5 * se)
    u = y[0] / np.linalg.norm(y[0])
    radial = draws @ u
    assert np.var(radial) / (u @ cov @ u) == pytest.approx(1.0, abs=5 * np.sqrt(2 / n))


def test_bad_input_names_the_problem():
    with pytest.raises(ParameterError, match="noise.radial"):
        TrackerNoise((-1e-6, 0.0), (1e-6, 0.0))
    with pytest.raises(ShapeError, match="noise.lateral"):
        TrackerNoise((1e-6, 0.0), (1e-6, 0.0, 1.0))
    with pytest.raises(ParameterError, match="repeatability"):
        TrackerNoise((1e-6, 0.0), (1e-6, 0.0), -1.0)
    with pytest.raises(ParameterError, match="singular"):
        TrackerNoise((0.0, 1e-6), (1e-6, 0.0))
    with pytest.raises(ParameterError, match="tracker origin"):
        NOISE.covariance(np.zeros((1, 3)))
    with pytest.raises(ShapeError, match="reflector positions"):
        NOISE.covariance(np.ones(3))
    with pytest.raises(TypeError, match="TrackerNoise"):
        TrackerPosition(0, 1e-5, noise=1e-5)


def test_weighted_jacobian_whitens_with_cholesky(robot):
    """F_1 rows of a noise model are L_i^-1 dh/dp; an isotropic model gives dh/dp / sigma."""
    space = make_space(robot)
    q = robot.random_configurations(4, 2)
    iso = weighted_jacobian(space, [TrackerPosition(0, 1e-5)], q)
    same = weighted_jacobian(space, [TrackerPosition(0, 1e-5, TrackerNoise.isotropic(1e-5))], q)
    np.testing.assert_allclose(same, iso, rtol=1e-12, atol=0)
    mdl = TrackerPosition(0, 1e-5, NOISE)
    f1 = weighted_jacobian(space, [mdl], q).reshape(4, 3, -1)
    state = evaluate_setup(space, None, q, regressor=True, jacobian=False)
    dh = mdl.compute_param_jacobian(state)
    cov = NOISE.covariance(mdl.compute_values(state))
    # F_i^T F_i = dh^T Sigma^-1 dh: whitening by any square root gives the same information
    for i in range(4):
        np.testing.assert_allclose(f1[i].T @ f1[i], dh[i].T @ np.linalg.solve(cov[i], dh[i]),
                                   rtol=1e-8, atol=1e-8 * np.abs(f1[i].T @ f1[i]).max())


def test_iso9283_repeatability_factor_by_monte_carlo():
    """RP = mean(l) + 3 std(l) of 200000 isotropic Gaussian errors is 3.616 sigma."""
    from calib_oed.measurement.noise import ISO9283_RP_PER_SIGMA, sigma_from_repeatability

    sigma = 1.1e-5
    lengths = np.linalg.norm(np.random.default_rng(5).normal(size=(200000, 3)) * sigma, axis=1)
    rp = lengths.mean() + 3 * lengths.std(ddof=1)
    assert rp / sigma == pytest.approx(ISO9283_RP_PER_SIGMA, rel=5e-3)  # s.e. ~0.1 %
    assert ISO9283_RP_PER_SIGMA == pytest.approx(3.616, abs=1e-3)
    assert sigma_from_repeatability(0.04) == pytest.approx(0.04 / 3.616, rel=1e-3)
    with pytest.raises(ParameterError, match="RP"):
        sigma_from_repeatability(-1.0)


def test_sigma_from_mpe():
    from calib_oed.measurement.noise import sigma_from_mpe

    assert sigma_from_mpe(0.010, 0.0003) == pytest.approx((0.005, 0.00015))
    assert sigma_from_mpe(0.015, 0.006, k=3) == pytest.approx((0.005, 0.002))
    with pytest.raises(ParameterError, match="coverage factor"):
        sigma_from_mpe(0.01, 0.0, k=0)
    with pytest.raises(ParameterError, match="MPE"):
        sigma_from_mpe(-0.01, 0.0)


def test_measurement_set_blocks_carry_the_noise_model(robot):
    from calib_oed.measurement.dataset import MeasurementSet

    q = robot.random_configurations(5, 1)
    positions = np.tile([1.0, 2.0, 0.5], (5, 1))
    mset = MeasurementSet.from_arrays(robot, q, positions, reflector=[0, 1, 0, 1, 0])
    blocks = mset.blocks(sigma=1e-5, noise=NOISE)
    assert [b.model.noise for b in blocks] == [NOISE, NOISE]
    assert all(b.model.noise is None for b in mset.blocks(sigma=1e-5))
    pose = MeasurementSet.from_arrays(robot, q, positions, rotations=np.zeros((5, 3)))
    with pytest.raises(ParameterError, match="position rows only"):
        pose.blocks(noise=NOISE)


def test_symmetric_whitening_is_the_inverse_square_root(points):
    cov = NOISE.covariance(points)
    w = NOISE.symmetric_whitening(points)[0]
    np.testing.assert_allclose(w, np.swapaxes(w, 1, 2), rtol=0, atol=0)
    np.testing.assert_allclose(w @ cov @ w, np.broadcast_to(np.eye(3), cov.shape), atol=1e-12)
    # the same information as the Cholesky whitening of the identification
    chol_w = NOISE.whitening(points)
    np.testing.assert_allclose(np.swapaxes(w, 1, 2) @ w, np.swapaxes(chol_w, 1, 2) @ chol_w,
                               rtol=1e-12)


def test_second_derivatives_match_finite_differences(points):
    """The symmetric whitening's first and second y-derivatives."""
    w, d_w, dd_w = NOISE.symmetric_whitening(points, order=2)
    np.testing.assert_array_equal(d_w, NOISE.symmetric_whitening(points, order=1)[1])
    for i, y in enumerate(points):
        numeric = central_difference(lambda x: NOISE.symmetric_whitening(x[None, :])[0][0], y, 1e-6)
        assert relative_error(d_w[i], numeric) < 1e-6
        numeric = central_difference(lambda x: NOISE.symmetric_whitening(x[None, :], 1)[1][0], y,
                                     1e-6)
        assert relative_error(dd_w[i], numeric) < 1e-6
