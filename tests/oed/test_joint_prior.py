"""The joint-space model-error prior: kernels and point Jacobians against central differences, the
criterion's gradient, a Monte Carlo of joint-angle errors under the prior's own assumptions, repeats."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import central_difference
from test_model_error_design import (
    two_reflector_problem,  # ur5, two SMRs, weighted working configurations
)

from calib_oed import load_scene
from calib_oed.calibration.joint_prior_choice import joint_prior as default_prior
from calib_oed.calibration.workflow import setup
from calib_oed.exceptions import DesignError, ParameterError
from calib_oed.feasibility.sampling import sample_feasible
from calib_oed.measurement.base import evaluate_setup
from calib_oed.measurement.joint_prior import ARCSEC, MOTOR_RMS, JointErrorPrior, point_jacobians
from calib_oed.model.size_class import TYPICAL
from calib_oed.oed.model_error import KRIGING, MODEL_ERROR
from calib_oed.oed.objective import DesignObjective


@pytest.fixture(scope="module")
def kr16(kr16_setup):
    """The session's fms_kr16 set-up (tests/conftest.py) with feasible poses (24, seed 11)."""
    return kr16_setup, sample_feasible(kr16_setup.feasibility, 24, 11)


def strong_prior(problem) -> JointErrorPrior:
    """Every part of the kernel switched on, large enough to dominate the noise."""
    d = default_prior(problem)
    nq = d.nq
    return JointErrorPrior(np.full(nq, 2e-4), np.full(nq, 1e-4), np.full(nq, 1.5e-4), np.full(nq, 0.9),
                           np.full(nq, 1e-4), d.compliance * 3, d.gravity, "test")


def assert_kernel_gradients(prior: JointErrorPrior, q1: np.ndarray, q2: np.ndarray) -> None:
    """``compute_kernel_gradients`` against central differences of ``compute_kernels``."""
    grad = prior.compute_kernel_gradients(q1, q2)  # (nq, n1, n2, nv)
    for a in range(len(q1)):
        def fun(x, a=a):
            qq = q1.copy()
            qq[a] = x
            return prior.compute_kernels(qq, q2)[:, a, :]
        num = central_difference(fun, q1[a])  # (nq, n2, nv)
        assert np.allclose(grad[:, a], num, rtol=1e-6, atol=1e-6 * np.abs(num).max())


def test_kernel_gradients_match_central_differences(kr16):
    s, q = kr16
    prior = strong_prior(s.problem)
    assert_kernel_gradients(prior, q[:4], q[4:9])
    # symmetric, positive semidefinite per joint, and the variance of one joint is its parts' sum
    k = prior.compute_kernels(q, q)
    assert np.allclose(k, np.swapaxes(k, 1, 2))
    assert np.linalg.eigvalsh(k).min() > -1e-12 * np.abs(k).max()


def test_point_jacobians_and_their_derivatives_match_central_differences(kr16):
    s, q = kr16
    problem = s.problem
    offsets = np.array([[0.03, -0.01, 0.05], [0.0, 0.0, 0.0]])
    pts = point_jacobians(problem, offsets)
    jac, d_jac = pts.compute(q[:3], derivative=True)
    state_points = []
    rot = problem.space.tracker_placement(None).rotation
    for c in offsets:  # independent: positions in the world from the setup state, turned into the tracker frame
        state_points.append(lambda x, c=c: (evaluate_setup(problem.space, None, x.reshape(1, -1)).tool_point(c, "world")
                                            @ rot)[0])
    for r, fun in enumerate(state_points):
        for j in range(3):
            num = central_difference(fun, q[j])  # (3, nv)
            assert np.allclose(jac[j, r], num, atol=1e-7)
            num2 = central_difference(lambda x, r=r: pts.compute(x.reshape(1, -1))[0][0, r], q[j])
            assert np.allclose(d_jac[j, r], num2, atol=1e-6)


@pytest.mark.parametrize("name", [MODEL_ERROR, KRIGING])
@pytest.mark.parametrize("case", ["kr16", "two_reflectors"])
def test_criterion_gradient_matches_central_differences(kr16, case, name):
    """fms_kr16: range-dependent noise (the whitening moves), compliance under gravity; ur5: two SMRs."""
    if case == "kr16":
        s, q = kr16
        problem, q = s.problem, q[:12]
    else:
        problem = two_reflector_problem()
        q = problem.robot.random_configurations(9, 5)
    obj = DesignObjective(problem, name, model_error=strong_prior(problem))
    grad = obj.compute(q).gradient
    num = central_difference(lambda x: obj.compute_value(x.reshape(q.shape)), q.ravel()).reshape(q.shape)
    assert np.abs(grad - num).max() / np.abs(num).max() < 1e-6


def monte_carlo(objective: DesignObjective, q: np.ndarray, draws: int, seed: int) -> float:
    """Weighted mean squared KPI error [mm²] of the linearised fit when every joint's angle error is a
    draw of its own process at the design and the working configurations, moved to the points by the
    world-frame Jacobians of the setup state (not the criterion's), plus noise; the noise-weighted fit
    (``kpi_model``) or GLS + kriging (``kpi_kriging``) built in SI."""
    problem, prior, free = objective.problem, objective.criterion.prior, objective.free
    rng = np.random.default_rng(seed)
    work = problem.kpi.configurations
    n, t, nq = len(q), len(work), prior.nq
    both = np.vstack([q, work])
    kern = prior.compute_kernels(both, both)  # (nq, n + t, n + t)
    eps = np.stack([np.linalg.cholesky(kern[k] + 1e-14 * np.eye(n + t)) @ rng.normal(size=(n + t, draws))
                    for k in range(nq)], axis=1)  # (n + t, nq, draws) [rad]
    state, state_w = evaluate_setup(problem.space, None, q), evaluate_setup(problem.space, None, work)
    rot = problem.space.tracker_placement(None).rotation
    jac, cov, err = [], [], []
    for mdl in problem.models:  # rows model-major
        jac.append(mdl.compute_param_jacobian(state)[:, :, free])
        y = mdl.compute_values(state)
        noise = getattr(mdl, "noise", None)
        cov.append(noise.covariance(y) if noise is not None else np.broadcast_to(np.diag(mdl.sigma**2), (n, 3, 3)))
        j_world = state.tool_point_config_jacobian(problem.space.reflector_offsets(None)[mdl.reflector], "world")
        err.append(np.einsum("ba,jbk,jkd->jad", rot, j_world, eps[:n]))  # tracker frame
    k = len(problem.models)
    f = np.concatenate([j.reshape(-1, j.shape[-1]) for j in jac])
    r = np.zeros((3 * n * k, 3 * n * k))
    for m in range(k):
        for j in range(n):
            a = 3 * (m * n + j)
            r[a:a + 3, a:a + 3] = cov[m][j]
    e_meas = np.concatenate([x.reshape(3 * n, draws) for x in err])
    e_w = np.einsum("ibk,ikd->ibd", state_w.tool_point_config_jacobian(problem.kpi.point, "world"),
                    eps[n:]).reshape(3 * t, draws)
    g = problem.kpi_jacobian(None)[:, free]
    dp = rng.normal(size=(len(free), draws)) * 1e-4
    y = f @ dp + e_meas + np.linalg.cholesky(r) @ rng.normal(size=(3 * n * k, draws))
    if objective.criterion.name == MODEL_ERROR:
        r_inv_f = np.linalg.solve(r, f)
        s_hat = g @ np.linalg.solve(f.T @ r_inv_f, r_inv_f.T @ y)
    else:  # the covariances of the errors from the same draws' kernel, world frame
        b = [np.einsum("ba,jbk->jak", rot, state.tool_point_config_jacobian(
            problem.space.reflector_offsets(None)[m.reflector], "world")) for m in problem.models]
        bm = np.concatenate(b)  # (k n, 3, nq) model-major
        kk = np.tile(kern[:, :n, :n], (1, k, k))
        sigma = np.einsum("kjl,jak,lbk->jalb", kk, bm, bm).reshape(3 * n * k, 3 * n * k) + r
        jw = state_w.tool_point_config_jacobian(problem.kpi.point, "world")
        kw = np.tile(kern[:, n:, :n], (1, 1, k))
        k_wy = np.einsum("kil,ick,lbk->iclb", kw, jw, bm).reshape(3 * t, 3 * n * k)
        s_inv_f = np.linalg.solve(sigma, f)
        dp_hat = np.linalg.solve(f.T @ s_inv_f, s_inv_f.T @ y)
        s_hat = g @ dp_hat + k_wy @ np.linalg.solve(sigma, y - f @ dp_hat)
    miss = (s_hat - (g @ dp + e_w)) * 1e3  # [mm]
    w = np.ones(t) if problem.kpi.weights is None else np.asarray(problem.kpi.weights, dtype=float)
    return float(np.mean(np.repeat(w / (3 * w.sum()), 3) @ miss**2))


@pytest.mark.parametrize("name", [MODEL_ERROR, KRIGING])
def test_the_criterion_is_the_monte_carlo_error_under_joint_angle_errors(kr16, name):
    """fms_kr16 (range-dependent noise, one SMR, the default prior): the formula against 4000 draws."""
    s, q = kr16
    obj = DesignObjective(s.problem, name)
    assert isinstance(obj.criterion.prior, JointErrorPrior)  # the default
    assert obj.compute_value(q) == pytest.approx(monte_carlo(obj, q, 4000, 0), rel=0.05)


@pytest.mark.parametrize("name", [MODEL_ERROR, KRIGING])
def test_monte_carlo_with_two_reflectors_and_weighted_points(name):
    problem = two_reflector_problem()
    obj = DesignObjective(problem, name, model_error=strong_prior(problem))
    q = problem.robot.random_configurations(14, 3)
    assert obj.compute_value(q) == pytest.approx(monte_carlo(obj, q, 4000, 1), rel=0.05)


def test_turning_the_joint_that_carries_the_smr_measures_the_same_error_again(kr16):
    """The SMR and the TCP of fms_kr16 lie on the A6 axis: a pose turned about A6 is a repeat
    under the joint-space prior (within 1 % of measuring the pose twice: only the rows of the A6
    geometry and the gravity torques change), while a new arm position helps more."""
    s, q = kr16
    obj = DesignObjective(s.problem, MODEL_ERROR)
    turned = q.copy()
    turned[:, 5] += 1.3
    twice, turned_twice = np.vstack([q, q]), np.vstack([q, turned])
    assert obj.compute_value(turned_twice) == pytest.approx(obj.compute_value(twice), rel=0.01)
    noise_only = DesignObjective(s.problem, "kpi")
    assert noise_only.compute_value(turned_twice) < 0.6 * noise_only.compute_value(q)  # a new measurement to kpi
    more = sample_feasible(s.feasibility, 24, 12)
    assert obj.compute_value(np.vstack([q, more])) < obj.compute_value(turned_twice)


def test_defaults_per_size_class_and_checks(kr16):
    s, _ = kr16
    kr = default_prior(s.problem)
    ur = default_prior(setup(load_scene("ur5_table")).problem)
    assert "medium" in kr.source and "small" in ur.source
    assert np.all(kr.compliance < ur.compliance)  # a small arm's joints are softer
    assert kr.to_dict()["kind"] == "joint" and "arcsec" in kr.describe()
    # J2's compliance: the class's 1/k times 1 - balancer_fraction (medium arm: a balancer; small: none)
    for prior, size in ((kr, "medium"), (ur, "small")):
        typical = TYPICAL[size]
        want = 1.0 / typical.stiffness
        want[1] *= 1.0 - typical.balancer_fraction
        np.testing.assert_allclose(prior.compliance, want, rtol=1e-12)
    assert TYPICAL["medium"].balancer_fraction > 0 and TYPICAL["small"].balancer_fraction == 0
    assert kr.compliance[1] < 1.0 / TYPICAL["medium"].stiffness[1]  # the balancer lowers J2's
    assert ur.compliance[1] == 1.0 / TYPICAL["small"].stiffness[1]
    with pytest.raises(ParameterError, match="length"):
        JointErrorPrior(kr.once, kr.twice, kr.smooth, np.zeros(6), kr.gain, kr.compliance, kr.gravity)
    with pytest.raises(ParameterError, match="gravity load"):
        JointErrorPrior(kr.once, kr.twice, kr.smooth, kr.length, kr.gain, kr.compliance)
    short = JointErrorPrior(kr.once[:5], kr.twice[:5], kr.smooth[:5], kr.length[:5], kr.gain[:5], np.zeros(5))
    with pytest.raises(DesignError, match="one value per joint"):
        DesignObjective(s.problem, MODEL_ERROR, model_error=short)


def test_motor_side_part_derivatives_and_record(kr16):
    """The short-length part: its kernel gradient and own-angle second derivative against central
    differences (close and far pose pairs), on by default instead of the smooth part, in the record
    only when on."""
    s, q = kr16
    default = default_prior(s.problem)
    np.testing.assert_allclose(default.motor, MOTOR_RMS)
    assert MOTOR_RMS / ARCSEC == pytest.approx(4.123, abs=1e-3) and not np.any(default.smooth)
    base = replace(default, motor=0.0)
    assert not base.has_motor and "motor_arcsec" not in base.to_dict()
    assert "motor_arcsec" in default.to_dict()
    motor = base.with_motor(4.0 * ARCSEC, 0.05)
    nq = motor.nq
    z = np.zeros(nq)
    alone = JointErrorPrior(z, z, z, np.ones(nq), z, z, motor=motor.motor, motor_length=motor.motor_length)
    q1 = q[:3]
    q2 = np.vstack([q[3:6], q1 + 0.01])  # far pairs, and pairs within the length scale
    assert_kernel_gradients(alone, q1, q2)
    second = alone.compute_own_second(q1, q2)  # (n1, n2, nq)
    for a in range(len(q1)):
        for k in range(nq):
            def own_grad(x, a=a, k=k):
                qq = q1.copy()
                qq[a, k] = x[0]
                return alone.compute_kernel_gradients(qq, q2)[k, a, :, k]
            num2 = central_difference(own_grad, q1[a, k:k + 1])[:, 0]
            assert np.allclose(second[a, :, k], num2, rtol=1e-5, atol=1e-6 * np.abs(num2).max())
    np.testing.assert_allclose(motor.compute_own_variance(q1) - base.compute_own_variance(q1),
                               np.broadcast_to(motor.motor**2, (len(q1), nq)), rtol=1e-9)
    back = JointErrorPrior.from_dict(motor.to_dict(), motor.gravity)
    np.testing.assert_allclose(back.motor, motor.motor)
    np.testing.assert_allclose(back.motor_length, motor.motor_length)
    assert "motor-side" in motor.describe()
    with pytest.raises(ParameterError, match="motor_length"):
        base.with_motor(4.0 * ARCSEC, 0.0)
    with pytest.raises(ParameterError, match="motor"):
        base.with_motor(-1.0)


def test_the_criterion_with_the_motor_side_part_is_the_monte_carlo_error(kr16):
    s, q = kr16
    obj = DesignObjective(s.problem, MODEL_ERROR, model_error=default_prior(s.problem).with_motor(4.0 * ARCSEC))
    assert obj.compute_value(q) == pytest.approx(monte_carlo(obj, q, 4000, 2), rel=0.05)
    # a repeated pose does not average the motor-side part: a repeat is worth less with it
    plain = DesignObjective(s.problem, MODEL_ERROR, model_error=replace(default_prior(s.problem), motor=0.0))
    twice = np.vstack([q, q])
    gain_with = obj.compute_value(twice) / obj.compute_value(q)
    gain_without = plain.compute_value(twice) / plain.compute_value(q)
    assert gain_with > gain_without
