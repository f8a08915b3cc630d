"""KPI covariance: explicit form against the paper's KKT form, and against Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize
import scipy.stats
from conftest import make_space, relative_error

from calib_oed import load_robot
from calib_oed.calibration.covariance import (
    Projection,
    covariance_blocks,
    kkt_covariance,
    kpi_covariance,
    parameter_covariance,
)
from calib_oed.calibration.kpi import TcpKpi
from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.exceptions import NotIdentifiableError, ShapeError
from calib_oed.measurement import TrackerPosition, evaluate_setup
from calib_oed.measurement.sensitivity import stacked_values
from calib_oed.scene.reader import load_scene


@pytest.fixture(scope="module")
def problem():
    robot = load_robot("kr16")
    space = make_space(robot, [(0.03, 0.01, 0.05)])
    kpi = TcpKpi(robot.random_configurations(2, 8), point=np.array([0.0, 0.0, 0.1]))
    return CalibrationProblem(space, [TrackerPosition(0, 1e-5)], kpi)


def test_explicit_equals_kkt_form(problem):
    """C_s = G C_p G^T equals the s-block of [I 0][[F1'F1, F2'],[F2, 0]]^-1[I; 0] (paper Thm. 1)."""
    free = problem.identifiability.free_indices
    q = problem.robot.random_configurations(40, 3)
    f1 = problem.weighted_jacobian(q)[:, free]
    g = problem.kpi_jacobian()[:, free]
    n_p, n_s = f1.shape[1], g.shape[0]
    # v = (p, s); f1 does not depend on s; f2 = TCP(p) - s, so F2 = [G, -I].
    f1v = np.hstack([f1, np.zeros((f1.shape[0], n_s))])
    f2v = np.hstack([g, -np.eye(n_s)])
    kkt = np.block([[f1v.T @ f1v, f2v.T], [f2v, np.zeros((n_s, n_s))]])
    sel = np.vstack([np.eye(n_p + n_s), np.zeros((n_s, n_p + n_s))])
    c_v = sel.T @ np.linalg.solve(kkt, sel)
    c_s = kpi_covariance(f1, g)
    assert np.allclose(c_v[n_p:, n_p:], c_s, rtol=1e-6, atol=1e-6 * np.abs(c_s).max())
    assert np.allclose(c_v[:n_p, :n_p], parameter_covariance(f1), rtol=1e-6,
                       atol=1e-6 * np.abs(c_s).max())


def test_singular_information_names_parameters(problem):
    q = problem.robot.random_configurations(40, 3)
    f1 = problem.weighted_jacobian(q)  # all parameters, gauge not removed
    with pytest.raises(NotIdentifiableError):
        parameter_covariance(f1, problem.space.names)


def test_kpi_covariance_against_monte_carlo(problem):
    """Simulated calibrations: nonlinear least squares on the free parameters.

    1000 seeded runs; the mean squared KPI error must match tr(C_s) within
    15 % and the 95 % ellipsoid must cover 92-98 % of the errors.
    """
    rng = np.random.default_rng(2026)
    space = problem.space
    model = problem.models[0]
    free = problem.identifiability.free_indices
    q = problem.robot.random_configurations(30, 5)
    p_true = np.zeros(space.size)
    p_true[free] = space.random(rng)[free]
    c_s = problem.kpi_covariance(q, p_true)
    s_true = problem.kpi.compute_values(space, p_true).ravel()
    h_true = stacked_values([model], evaluate_setup(space, p_true, q, jacobian=False))
    sigma = np.tile(model.sigma, len(q))

    def estimate(eta):
        def residual(x):
            p = np.zeros(space.size)
            p[free] = x
            return (eta - stacked_values([model], evaluate_setup(space, p, q, jacobian=False))) / sigma

        def jac(x):
            p = np.zeros(space.size)
            p[free] = x
            return -problem.weighted_jacobian(q, p)[:, free]

        sol = scipy.optimize.least_squares(residual, np.zeros(len(free)), jac=jac, method="lm",
                                           xtol=1e-12, ftol=1e-12)
        p = np.zeros(space.size)
        p[free] = sol.x
        return p

    n_runs = 1000
    errors = np.empty((n_runs, len(s_true)))
    for k in range(n_runs):
        eta = h_true + sigma * rng.normal(size=h_true.shape)
        errors[k] = problem.kpi.compute_values(space, estimate(eta)).ravel() - s_true
    ratio = np.mean(np.sum(errors**2, axis=1)) / np.trace(c_s)
    print(f"Monte Carlo: mean squared KPI error / tr(C_s) = {ratio:.3f}")
    assert 0.85 < ratio < 1.15
    c_inv = np.linalg.inv(c_s[:3, :3])
    d2 = np.einsum("ki,ij,kj->k", errors[:, :3], c_inv, errors[:, :3])
    coverage = np.mean(d2 <= scipy.stats.chi2.ppf(0.95, 3))
    print(f"Monte Carlo: coverage of the 95 % KPI ellipsoid = {coverage:.3f}")
    assert 0.92 <= coverage <= 0.98


def test_too_few_poses_is_a_clear_error(problem):
    q = problem.robot.random_configurations(5, 3)  # 15 values for 25+ free parameters
    with pytest.raises(NotIdentifiableError, match="measure more configurations"):
        problem.kpi_covariance(q)


# ------------------------------------------------ KKT form (paper §2.1, eq. 19)
@pytest.fixture(scope="module")
def fms_kr16():
    """The default scene's problem, its free parameters and a random 40-configuration design."""
    pr = CalibrationProblem.from_scene(load_scene("fms_kr16"))
    free = pr.identifiability.free_indices
    q = pr.robot.random_configurations(40, 11)
    f1 = pr.weighted_jacobian(q)[:, free]
    g = pr.kpi_jacobian()[:, free]
    return pr, q, f1, g


def _check_kkt_blocks(f1, g, tol):
    c_v = kkt_covariance(f1, g)
    n_p = f1.shape[1]
    assert c_v.shape == (n_p + g.shape[0],) * 2
    assert np.array_equal(c_v, c_v.T)
    blocks = covariance_blocks(c_v, n_p)
    c_p = parameter_covariance(f1)
    errors = {
        "C_s": relative_error(blocks.s, kpi_covariance(f1, g)),
        "C_p": relative_error(blocks.p, c_p),
        "C_ps": relative_error(blocks.ps, c_p @ g.T),
    }
    print("KKT vs explicit, relative error:", {k: f"{v:.1e}" for k, v in errors.items()})
    assert max(errors.values()) <= tol, errors
    return c_v


def test_kkt_covariance_on_fms_kr16(fms_kr16):
    """KKT C_v: C_s = G C_p G^T, C_p = (F1'F1)^-1, C_ps = C_p G^T to 1e-10 relative."""
    _, _, f1, g = fms_kr16
    _check_kkt_blocks(f1, g, 1e-10)


def test_kkt_covariance_hand_made():
    """F1'F1 = [[2, 1], [1, 5]], so C_p = [[5, -1], [-1, 2]]/9; G = [1, 1] gives C_s = 5/9."""
    f1 = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    g = np.array([[1.0, 1.0]])
    c_v = _check_kkt_blocks(f1, g, 1e-14)
    expected = np.array([[5.0, -1.0, 4.0], [-1.0, 2.0, 1.0], [4.0, 1.0, 5.0]]) / 9.0
    assert np.allclose(c_v, expected, rtol=0, atol=1e-15)


def test_kkt_covariance_badly_scaled_units():
    """Columns spanning 8 decades (mixed units): equilibration keeps 1e-10 agreement."""
    rng = np.random.default_rng(7)
    u, _ = np.linalg.qr(rng.normal(size=(60, 12)))
    v, _ = np.linalg.qr(rng.normal(size=(12, 12)))
    col = np.logspace(-3, 5, 12)
    f1 = (u * np.logspace(0, 3, 12)) @ v * col * 1e5  # cond 1e3 before column scaling
    g = rng.normal(size=(6, 12)) / col
    _check_kkt_blocks(f1, g, 1e-10)


def test_kkt_covariance_errors(fms_kr16):
    pr, q, f1, g = fms_kr16
    with pytest.raises(NotIdentifiableError):
        kkt_covariance(pr.weighted_jacobian(q), pr.kpi_jacobian(), pr.space.names)  # gauge kept
    with pytest.raises(ShapeError):
        kkt_covariance(f1, g[:, :-1])
    with pytest.raises(ShapeError):
        covariance_blocks(np.zeros((3, 4)), 1)
    with pytest.raises(ValueError, match="n_p"):
        covariance_blocks(np.zeros((3, 3)), 4)


# ----------------------------------------------------------- projection P
def _hand_cv():
    """n_p = 2 (a length [m], an angle [rad]), n_s = 3 (a KPI point [m])."""
    c_v = np.diag([1e-6, 4e-6, 1e-8, 2e-8, 3e-8])
    c_v[0, 1] = c_v[1, 0] = 1e-6
    c_v[2, 3] = c_v[3, 2] = -1e-8
    c_v[0, 4] = c_v[4, 0] = 2e-7
    return c_v


def test_projection_matrices():
    assert np.array_equal(Projection.kpi(2, 3).P, np.vstack([np.zeros((2, 3)), 1e3 * np.eye(3)]))
    par = Projection.parameters(2, 3, np.array([1e-3, 1e-3]))
    assert np.array_equal(par.P, np.vstack([1e3 * np.eye(2), np.zeros((3, 2))]))
    both = Projection.both(2, 3, 1e-3)
    assert np.array_equal(both.P, 1e3 * np.eye(5))
    sel = Projection.select([4, 0], [2.0, 10.0], 5)
    assert sel.dim == 2 and sel.n_v == 5
    assert sel.indices.tolist() == [4, 0] and sel.scales.tolist() == [2.0, 10.0]
    assert not sel.P.flags.writeable


def test_projection_hand_numbers():
    c_v = _hand_cv()
    # KPI in mm: diag (1, 2, 3)e-8 m^2 = (0.01, 0.02, 0.03) mm^2; off-diagonal -0.01 mm^2.
    kpi = Projection.kpi(2, 3)
    assert np.allclose(kpi.apply(c_v), [[0.01, -0.01, 0], [-0.01, 0.02, 0], [0, 0, 0.03]],
                       rtol=1e-14, atol=0)
    assert kpi.trace_average(c_v) == pytest.approx(0.02, rel=1e-14)
    # Parameters in mm / mrad: (1, 4) -> mean 2.5 [mm^2, mrad^2].
    par = Projection.parameters(2, 3, [1e-3, 1e-3])
    assert np.allclose(par.apply(c_v), [[1.0, 1.0], [1.0, 4.0]], rtol=1e-14, atol=0)
    assert par.trace_average(c_v) == pytest.approx(2.5, rel=1e-14)
    # Everything: (1 + 4 + 0.01 + 0.02 + 0.03) / 5.
    assert Projection.both(2, 3, 1e-3).trace_average(c_v) == pytest.approx(1.012, rel=1e-14)
    # Select s_z scaled by 2 and p_0 by 10: diag (4*3e-8, 100*1e-6), off-diagonal 20*2e-7.
    sel = Projection.select([4, 0], [2.0, 10.0], 5)
    assert np.allclose(sel.apply(c_v), [[1.2e-7, 4e-6], [4e-6, 1e-4]], rtol=1e-14, atol=0)
    assert sel.trace_average(c_v) == pytest.approx((1.2e-7 + 1e-4) / 2, rel=1e-14)
    for proj in (kpi, par, sel):
        assert np.allclose(proj.apply(c_v), proj.P.T @ c_v @ proj.P, rtol=1e-14, atol=0)


def test_projection_a_criterion_is_kpi_sigma_squared(fms_kr16):
    """For one working configuration tr(P'C_vP)/3 in mm^2 is kpi_sigma^2 (mm)."""
    pr, q, f1, g = fms_kr16
    c_v = kkt_covariance(f1, g)
    phi = Projection.kpi(f1.shape[1], g.shape[0]).trace_average(c_v)
    sigma_mm = pr.kpi_sigma(q)[0] * 1e3
    print(f"fms_kr16, 40 random configurations: phi_A = {phi:.4e} mm^2, sigma = {sigma_mm:.4e} mm")
    assert phi == pytest.approx(sigma_mm**2, rel=1e-10)


def test_projection_errors():
    with pytest.raises(ValueError, match="exactly one"):
        Projection(np.ones((3, 1)))
    with pytest.raises(ValueError, match="twice"):
        Projection(np.array([[1.0, 2.0], [0.0, 0.0]]))
    with pytest.raises(ValueError, match="> 0"):
        Projection(np.array([[-1.0], [0.0]]))
    with pytest.raises(ValueError, match="indices"):
        Projection.select([5], 1.0, 5)
    with pytest.raises(ValueError, match="unit_scale"):
        Projection.parameters(2, 3, [1e-3, 0.0])
    with pytest.raises(ShapeError):
        Projection.parameters(2, 3, [1e-3, 1e-3, 1e-3])
    with pytest.raises(ShapeError):
        Projection.kpi(2, 3).apply(np.eye(4))
