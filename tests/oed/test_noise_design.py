"""The design objective under the full tracker error model: whitened rows and their exact q-derivatives.

Scenes ur5_table, bench/scenes/panda_cell.yaml and fms_kr16 with a
``tracker.noise`` block (Leica AT500 MPE, k = 2) and the KR 16's
repeatability added here: rows, gradient and certificate row derivatives
and Hessian against central differences (docs/uncertainty.md, "The design objective").
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import central_difference, relative_error

from calib_oed.calibration.problem import CalibrationProblem
from calib_oed.calibration.workflow import setup
from calib_oed.measurement import evaluate_setup
from calib_oed.measurement.noise import TrackerNoise
from calib_oed.measurement.sensitivity import weighted_jacobian
from calib_oed.oed.design import design
from calib_oed.oed.objective import DesignObjective
from calib_oed.oed.whitening import point_config_hessian
from calib_oed.scene.reader import load_scene

AT500 = TrackerNoise((5e-6, 1.5e-7), (7.5e-6, 3e-6))
SCENES = ("ur5_table", str(Path(__file__).parents[2] / "bench" / "scenes" / "panda_cell.yaml"),
          "fms_kr16")
_CACHE: dict = {}


def _isotropic(scene):
    """``scene`` without ``tracker.noise`` and ``robot.repeatability``: the isotropic sigma alone."""
    return replace(scene, tracker=replace(scene.tracker, noise=None), repeatability=0.0)


def _problems(scene: str) -> tuple[CalibrationProblem, CalibrationProblem]:
    """The scene with the isotropic ``tracker.sigma`` only, and with the AT500 model and 0.011 mm
    repeatability (the shipped scenes have a noise model and repeatability of their own)."""
    if scene not in _CACHE:
        base = _isotropic(load_scene(scene))
        full = replace(base, tracker=replace(base.tracker, noise=AT500), repeatability=1.1e-5)
        _CACHE[scene] = (CalibrationProblem.from_scene(base), CalibrationProblem.from_scene(full))
    return _CACHE[scene]


def _design(problem, n=12, seed=3):
    return problem.robot.random_configurations(n, seed)


@pytest.mark.parametrize("scene", SCENES)
def test_gradient_under_the_full_model_matches_differences(scene):
    iso, full = _problems(scene)
    q = _design(full)
    obj = DesignObjective(full, "kpi")
    ev = obj.compute(q)
    poses = [0, 7]

    def phi_of(x, j):
        qq = q.copy()
        qq[j] = x
        return obj.compute_value(qq)

    numeric = np.stack([central_difference(lambda x, j=j: phi_of(x, j), q[j], 1e-5) for j in poses])
    assert relative_error(ev.gradient[poses], numeric) < 1e-5
    # the model is on: the variance differs from the isotropic 0.01 mm model's
    assert abs(ev.value / DesignObjective(iso, "kpi").compute_value(q) - 1.0) > 0.2


def test_information_is_the_covariance_whitening():
    """The design's M equals F1^T F1 of measurement.sensitivity (identification and C_p use it)."""
    _, full = _problems("fms_kr16")
    q = _design(full)
    obj = DesignObjective(full, "kpi")
    f1 = weighted_jacobian(full.space, full.models, q)[:, obj.free] * obj.scale
    np.testing.assert_allclose(obj.compute_information(q), f1.T @ f1, rtol=1e-10,
                               atol=1e-12 * np.abs(f1.T @ f1).max())


@pytest.mark.parametrize("scene", SCENES)
def test_certificate_row_derivatives_match_differences(scene):
    """compute_row_derivatives (the certificate's sensitivity gradient) includes dW/dq."""
    _, full = _problems(scene)
    q = _design(full, n=3, seed=5)
    obj = DesignObjective(full, "kpi")
    rd = obj.compute_row_derivatives(q)
    np.testing.assert_array_equal(rd.rows, obj.compute_blocks(q))
    for j in range(3):
        def rows_of(x, j=j):
            qq = q.copy()
            qq[j] = x
            return obj.compute_blocks(qq)[j]

        assert relative_error(rd.derivatives[j], central_difference(rows_of, q[j], 1e-6)) < 1e-6


def test_isotropic_noise_model_reproduces_sigma_and_none_is_unchanged():
    """noise=None takes the old path bit for bit; an isotropic TrackerNoise gives the same numbers."""
    iso, _ = _problems("fms_kr16")
    q = _design(iso)
    obj = DesignObjective(iso, "kpi")
    state = obj._state(q, second_order=True)
    old = np.concatenate([m.compute_param_jacobian(state)[:, :, obj.free] / m.sigma[None, :, None]
                          for m in iso.models], axis=1) * obj.scale
    np.testing.assert_array_equal(obj.compute_blocks(q), old)
    base = _isotropic(load_scene("fms_kr16"))
    same = replace(base, tracker=replace(
        base.tracker, noise=TrackerNoise.isotropic(float(base.tracker.sigma[0]))))
    obj_same = DesignObjective(CalibrationProblem.from_scene(same), "kpi")
    ev, ev_same = obj.compute(q), obj_same.compute(q)
    assert ev_same.value == pytest.approx(ev.value, rel=1e-10)
    assert relative_error(ev_same.gradient, ev.gradient) < 1e-9


@pytest.mark.parametrize("scene", SCENES)
def test_hessian_under_the_full_model_matches_differences(scene):
    """Row Hessians (with d2W/dq2) against differences of the row derivatives; the
    criterion's structured Hessian against differences of the gradient."""
    _, full = _problems(scene)
    q = _design(full, n=12, seed=3)
    obj = DesignObjective(full, "kpi")
    j, eps = 1, 1e-6

    def at_pose(fun):
        def of(x):
            qq = q.copy()
            qq[j] = x
            return fun(qq)
        return of

    dd = obj.compute_row_hessians(q)[j]  # (d, nf, nv, nv)
    numeric = central_difference(at_pose(lambda qq: obj.compute_row_derivatives(qq).derivatives[j]),
                                 q[j], eps)
    assert relative_error(dd, numeric) < 1e-6
    h = obj.compute_hessian(q)
    u = h.low_rank.reshape(q.shape[0], q.shape[1], -1)[j]
    numeric = central_difference(at_pose(lambda qq: obj.compute(qq).gradient[j]), q[j], eps)
    assert relative_error(h.blocks[j] + u @ u.T, numeric) < 1e-5


def test_point_config_hessian_matches_differences():
    _, full = _problems(str(SCENES[1]))
    q = _design(full, n=3, seed=7)
    mdl = full.models[0]

    def state_at(qq):
        return evaluate_setup(full.space, None, qq, regressor=True, jacobian=True)

    dd = point_config_hessian(mdl, state_at(q))
    for j in range(3):
        def dy_of(x, j=j):
            qq = q.copy()
            qq[j] = x
            return mdl.compute_config_jacobian(state_at(qq))[j]

        assert relative_error(dd[j], central_difference(dy_of, q[j], 1e-6)) < 1e-6


def test_sqp_with_the_exact_hessian_converges_under_the_full_model():
    """fms_kr16 + AT500 + repeatability, 20 poses: the default SQP (exact Hessian with the
    whitening's second derivatives) converges from the exchange start and improves on it."""
    base = load_scene("fms_kr16")
    s = setup(replace(base, tracker=replace(base.tracker, noise=AT500), repeatability=1.1e-5))
    # the pool alone (no off-pool maxima): a start the SQP has to improve by more than 10 %
    d = design(s, 20, "kpi", pool=200, certificate=False, enrich=False)
    assert d.solver["status"] == "converged", d.solver["message"]
    assert d.solver["hessian"] == "exact"
    assert d.feasible and d.value < 0.9 * d.start_value
    assert d.value == pytest.approx(DesignObjective(s.problem, "kpi").compute_value(d.q), rel=1e-9)
