"""Confidence ellipsoids: hand-checkable geometry, errors, and seeded Monte Carlo coverage."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats

from calib_oed.calibration.confidence import (
    ConfidenceEllipsoid,
    ConfidenceLevelError,
    NotPositiveDefiniteError,
    chi2_radius2,
    kpi_ellipsoids,
)
from calib_oed.exceptions import ShapeError

N_SAMPLES = 20_000


def _binomial_tol(p: float, n: int = N_SAMPLES) -> float:
    """Four standard deviations of a sample fraction with probability ``p``."""
    return 4.0 * np.sqrt(p * (1.0 - p) / n)


def _random_spd(d: int, rng: np.random.Generator, scale: float = 1e-8) -> np.ndarray:
    """A random SPD matrix [m^2], standard deviations of order 0.1 mm, correlated."""
    a = rng.normal(size=(d, d))
    return scale * (a @ a.T + 0.2 * np.eye(d))


@pytest.fixture(scope="module")
def samples3():
    """20000 Gaussian samples around a centre 1 m from the origin, and their law."""
    rng = np.random.default_rng(20260)
    cov = _random_spd(3, rng)
    center = np.array([1.15, 0.16, 0.89])
    x = rng.multivariate_normal(center, cov, size=N_SAMPLES)
    return center, cov, x


# --------------------------------------------------------------- geometry
def test_diagonal_ellipsoid_by_hand():
    """sigma = (2, 1, 3) mm: half-axes sqrt(7.8147) * (3, 2, 1) mm along z, x, y."""
    cov = np.diag([4.0, 1.0, 9.0]) * 1e-6
    center = np.array([1.0, 2.0, 3.0])
    e = ConfidenceEllipsoid(center, cov, 0.95, name="w")
    assert e.radius2 == pytest.approx(7.814727903251179, rel=1e-12)
    assert np.allclose(e.half_axes, np.sqrt(7.814727903251179) * np.array([3e-3, 2e-3, 1e-3]),
                       rtol=1e-12, atol=0)
    assert np.array_equal(e.axes, [[0, 1, 0], [0, 0, 1], [1, 0, 0]])  # z, x, y: det +1
    a = e.half_axes[0]
    assert e.contains(center + [0, 0, a * (1 - 1e-9)])
    assert not e.contains(center + [0, 0, a * (1 + 1e-9)])
    pts = center + np.array([[0, 0, 0], [e.half_axes[1] * 1.01, 0, 0], [0, e.half_axes[2] * 0.99, 0]])
    assert e.contains(pts).tolist() == [True, False, True]
    assert e.contains(pts[None]).shape == (1, 3)
    assert e.mahalanobis_squared(center + [2e-3, 1e-3, 3e-3]) == pytest.approx(3.0, rel=1e-12)


def test_axes_are_a_rotation_of_unit_eigenvectors(samples3):
    _, cov, _ = samples3
    e = ConfidenceEllipsoid(np.zeros(3), cov)
    assert np.allclose(e.axes.T @ e.axes, np.eye(3), atol=1e-14)
    assert np.linalg.det(e.axes) == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(e.half_axes) <= 0)
    # C = V diag(a^2 / r^2) V^T
    rebuilt = e.axes @ np.diag(e.half_axes**2 / e.radius2) @ e.axes.T
    assert np.allclose(rebuilt, cov, rtol=0, atol=1e-14 * np.abs(cov).max())
    # The tip of every half-axis is on the boundary.
    tips = e.center + (e.axes * e.half_axes).T
    assert np.allclose(e.mahalanobis_squared(tips), e.radius2, rtol=1e-12)


def test_shadow_is_the_projection_of_the_ellipsoid(samples3):
    """Support functions agree: max over E of a.x_J = r sqrt(a' C_JJ a), the shadow's half-width."""
    center, cov, _ = samples3
    e = ConfidenceEllipsoid(center, cov)
    rng = np.random.default_rng(5)
    # Boundary points of E: c + L u r, u on the unit sphere.
    u = rng.normal(size=(20_000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    surface = center + np.sqrt(e.radius2) * u @ np.linalg.cholesky(cov).T
    for dims in ((0, 1), (0, 2), (1, 2)):
        sh = e.shadow(dims)
        assert sh.kind == "shadow" and sh.dims == dims and sh.radius2 == pytest.approx(e.radius2)
        assert np.all(sh.mahalanobis_squared(surface[:, dims]) <= sh.radius2 * (1 + 1e-12))
        for angle in np.linspace(0, np.pi, 7):
            a = np.array([np.cos(angle), np.sin(angle)])
            reach = np.max((surface[:, dims] - center[list(dims)]) @ a)
            support = np.sqrt(sh.radius2 * a @ sh.covariance @ a)
            assert reach <= support * (1 + 1e-12)
            assert reach >= support * (1 - 2e-3)  # sampled boundary comes close
        marg = e.marginal(dims)
        assert marg.kind == "marginal" and marg.radius2 == pytest.approx(chi2_radius2(0.95, 2))
        assert np.all(marg.half_axes < sh.half_axes)
    assert e.projection((0, 2), "shadow").level == pytest.approx(e.shadow((0, 2)).level)
    assert e.projection((0, 2)).kind == "marginal"


def test_boundary_points_lie_on_the_ellipse(samples3):
    center, cov, _ = samples3
    ell = ConfidenceEllipsoid(center, cov).shadow((1, 2))
    pts = ell.boundary(50)
    assert pts.shape == (50, 2)
    assert np.allclose(ell.mahalanobis_squared(pts), ell.radius2, rtol=1e-12)
    with pytest.raises(ValueError, match="2-D"):
        ConfidenceEllipsoid(center, cov).boundary()


def test_to_dict_is_in_mm_and_json():
    e = ConfidenceEllipsoid(np.array([1.0, 0.5, 0.25]), np.diag([4.0, 1.0, 9.0]) * 1e-6, name="w")
    d = e.to_dict()
    json.dumps(d)
    assert d["center_mm"] == [1000.0, 500.0, 250.0]
    assert np.allclose(d["covariance_mm2"], np.diag([4.0, 1.0, 9.0]), rtol=1e-12)
    assert np.allclose(d["half_axes_mm"], np.sqrt(d["radius2"]) * np.array([3.0, 2.0, 1.0]))
    assert d["name"] == "w" and d["kind"] == "joint" and d["level"] == 0.95 and d["dimension"] == 3


def test_kpi_ellipsoids_one_per_working_configuration():
    rng = np.random.default_rng(3)
    c_s = _random_spd(6, rng)
    centers = np.array([[1.0, 0.0, 0.5], [0.8, -0.2, 1.1]])
    ells = kpi_ellipsoids(c_s, centers, level=0.9, names=["a", "b"])
    assert [e.name for e in ells] == ["a", "b"]
    for i, e in enumerate(ells):
        assert np.array_equal(e.center, centers[i])
        assert np.array_equal(e.covariance, c_s[3 * i : 3 * i + 3, 3 * i : 3 * i + 3])
        assert e.radius2 == pytest.approx(scipy.stats.chi2.ppf(0.9, 3))
    assert [e.name for e in kpi_ellipsoids(c_s, centers.ravel())] == ["work0", "work1"]
    with pytest.raises(ShapeError):
        kpi_ellipsoids(c_s[:5, :5], centers)
    with pytest.raises(ShapeError):
        kpi_ellipsoids(c_s, centers[:1])
    with pytest.raises(ShapeError):
        kpi_ellipsoids(c_s, centers, names=["a"])


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    "cov",
    [np.diag([1.0, 0.0, 1.0]), np.diag([1.0, -1e-12, 1.0]), np.zeros((3, 3)),
     np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),  # not symmetric
     np.ones((3, 3))],  # rank 1: eigenvalues 0 within rounding
)
def test_not_positive_definite_is_a_clear_error(cov):
    with pytest.raises(NotPositiveDefiniteError, match="positive definite"):
        ConfidenceEllipsoid(np.zeros(3), cov)


@pytest.mark.parametrize("level", [0.0, 1.0, -0.5, 1.5, float("nan"), "high", None])
def test_level_outside_zero_one_is_a_clear_error(level):
    with pytest.raises(ConfidenceLevelError, match="strictly between 0 and 1"):
        ConfidenceEllipsoid(np.zeros(2), np.eye(2), level)


def test_shape_and_dims_errors():
    with pytest.raises(ShapeError):
        ConfidenceEllipsoid(np.zeros(3), np.eye(2))
    with pytest.raises(ShapeError):
        ConfidenceEllipsoid(np.zeros(2), np.eye(2)).contains(np.zeros(3))
    e = ConfidenceEllipsoid(np.zeros(3), np.eye(3))
    for dims in ((0, 0), (0, 3), ()):
        with pytest.raises(ValueError, match="dims"):
            e.marginal(dims)
    with pytest.raises(ValueError, match="kind"):
        e.projection((0, 1), "side")


# ------------------------------------------------------------- Monte Carlo
@pytest.mark.parametrize("level", [0.95, 0.68])
@pytest.mark.parametrize("d", [3, 2])
def test_coverage_monte_carlo(d, level):
    """20000 seeded Gaussian samples: the fraction inside the region is its level.

    At 95 % the band is +-0.006 (3.9 binomial sigmas); at 68 % a +-0.006 band
    would be only 1.8 sigma, so the 4-sigma band +-0.0132 applies.
    """
    rng = np.random.default_rng(1000 * d + round(100 * level))
    cov = _random_spd(d, rng)
    center = rng.normal(size=d)
    x = rng.multivariate_normal(center, cov, size=N_SAMPLES)
    frac = float(np.mean(ConfidenceEllipsoid(center, cov, level).contains(x)))
    print(f"d = {d}, level {level}: fraction inside = {frac:.4f}")
    tol = 0.006 if level == 0.95 else _binomial_tol(level)
    assert abs(frac - level) <= tol


def test_marginal_and_shadow_coverage_monte_carlo(samples3):
    """Projected samples: the 95 % marginal ellipse holds 95 %; the 3-D ellipsoid's shadow holds
    F_chi2(2)(chi2_3(0.95)) = 1 - exp(-7.8147/2) = 0.97991."""
    center, cov, x = samples3
    e = ConfidenceEllipsoid(center, cov, 0.95)
    predicted = scipy.stats.chi2.cdf(scipy.stats.chi2.ppf(0.95, 3), 2)
    assert predicted == pytest.approx(1.0 - np.exp(-e.radius2 / 2.0), rel=1e-14)
    assert predicted == pytest.approx(0.9799066, abs=1e-7)
    for dims in ((0, 1), (0, 2), (1, 2)):
        y = x[:, dims]
        f_marg = float(np.mean(e.marginal(dims).contains(y)))
        shadow = e.shadow(dims)
        f_shadow = float(np.mean(shadow.contains(y)))
        print(f"dims {dims}: marginal 95 % holds {f_marg:.4f}, shadow holds {f_shadow:.4f} "
              f"(predicted {predicted:.4f})")
        assert abs(f_marg - 0.95) <= 0.006
        assert shadow.level == pytest.approx(predicted, rel=1e-14)
        assert f_shadow >= 0.95
        assert abs(f_shadow - predicted) <= _binomial_tol(predicted)
