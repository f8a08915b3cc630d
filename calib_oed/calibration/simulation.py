r"""Simulated calibrations: a true robot, noisy tracker data, identification, TCP errors.

One trial (paper §1.1, the experiment the covariance predicts):

1. draw a true parameter vector :math:`p^\star`: the free parameters of the
   gauge normal with standard deviations ``sigma_length`` [m] and
   ``sigma_angle`` [rad] (default 0.5 mm, 0.5 mrad), the fixed ones at zero,
   so the truth lies in the gauge the estimate is expressed in; free joint
   compliances (when modelled) are :math:`1/k` with the stiffness :math:`k`
   log-uniform in :data:`calib_oed.model.compliance.STIFFNESS_RANGE` (positive,
   1e6..1e7 N·m/rad); free joint gains and coupling ratios normal, default 1e-3;
2. simulate :math:`\eta = h(p^\star, q) + \varepsilon`,
   :math:`\varepsilon \sim N(0, \Sigma^2)` at the design :math:`q`; a model with a
   full error model (``model.noise``) draws :math:`\varepsilon_i \sim N(0, \Sigma_i)`,
   :math:`\Sigma_i` evaluated at the TRUE positions :math:`h(p^\star, q_i)`;
3. identify :math:`\hat p` from nominal (:func:`calib_oed.calibration.identification.identify`);
4. KPI errors at the working configurations: before calibration
   :math:`s(0) - s(p^\star)` (the nominal model's error) and after
   :math:`s(\hat p) - s(p^\star)`, each (t, 3) [m].

To first order :math:`\hat p - p^\star \sim N(0, C_p)`, hence the error after
calibration is :math:`N(0, C_s)`: :mod:`calib_oed.calibration.montecarlo` checks that.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib_oed.calibration.identification import identify
from calib_oed.measurement.base import MeasurementModel, evaluate_setup
from calib_oed.measurement.discrepancy import DiscrepancyPrior
from calib_oed.measurement.observations import ObservationBlock
from calib_oed.model.compliance import draw_compliance
from calib_oed.model.parameters import ParameterSpace


def draw_true_parameters(
    space: ParameterSpace,
    free: Sequence[int],
    rng: np.random.Generator | int,
    sigma_length: float = 0.5e-3,
    sigma_angle: float = 0.5e-3,
    sigma_gain: float = 1e-3,
) -> np.ndarray:
    """A true robot and sensor: free parameters perturbed, fixed ones zero, (n_p,) SI.

    Geometric parameters normal (``sigma_length`` [m], ``sigma_angle`` [rad]);
    free compliances from :func:`calib_oed.model.compliance.draw_compliance`;
    free joint gains and coupling ratios normal (``sigma_gain`` [1]).
    """
    rng = np.random.default_rng(rng)
    free = np.asarray(free, dtype=int)
    geo = free[free < space.compliance_slice.start]
    sd = np.array([sigma_length if space.parameters[i].unit == "m" else sigma_angle for i in geo])
    p = np.zeros(space.size)
    p[geo] = rng.normal(size=geo.size) * sd
    comp = free[(free >= space.compliance_slice.start) & (free < space.compliance_slice.stop)]
    if comp.size:  # drawn after the geometric ones: the rigid case's draws are unchanged
        p[comp] = draw_compliance(rng, comp.size)
    gains = free[free >= space.gain_slice.start]
    if gains.size:  # drawn last: the draws without gains are unchanged
        p[gains] = rng.normal(size=gains.size) * sigma_gain
    return p


def simulate_observations(
    space: ParameterSpace,
    models: Sequence[MeasurementModel],
    q: np.ndarray,
    p_true: np.ndarray,
    rng: np.random.Generator | int,
    model_error: DiscrepancyPrior | None = None,
    visible: np.ndarray | None = None,
) -> list[ObservationBlock]:
    """Noisy measurements of every model at every configuration of ``q`` (n, nq).

    ``model_error``: a model error drawn from this Gaussian process (after the
    noise, from the same generator), added to the positions; the draw at one
    configuration is shared by every reflector measured there.
    ``visible`` (n, k) bool (:func:`calib_oed.feasibility.visibility.visible_reflectors`):
    a model of reflector j measures only the poses where it is True (a nest of
    several SMRs measures those the tracker sees); None: every pose. The draws of
    the hidden rows are made and discarded, so the seen rows do not depend on it.
    """
    rng = np.random.default_rng(rng)
    q = space.robot.check_configurations(q)
    state = evaluate_setup(space, p_true, q, regressor=False, jacobian=False)
    values = []
    for mdl in models:
        values.append(add_noise(mdl, mdl.compute_values(state), rng))  # at the true positions
    if model_error is not None:  # one draw per distinct configuration, shared by the reflectors
        distinct, inverse = np.unique(q, axis=0, return_inverse=True)
        offset = model_error.sample(distinct, rng)[inverse.ravel()]
        for v in values:
            v[:, :3] += offset
    blocks = []
    for mdl, v in zip(models, values, strict=True):
        seen = slice(None) if visible is None else np.asarray(visible, dtype=bool)[:, mdl.reflector]
        if q[seen].shape[0]:
            blocks.append(ObservationBlock(mdl, q[seen], v[seen]))
    return blocks


def add_noise(model: MeasurementModel, exact: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r"""``exact`` (n, d) plus one draw of ``model``'s measurement noise (its noise contract,
    :math:`\Sigma_i` at the true positions)."""
    return exact + model.sample_noise(exact, rng)


@dataclass(frozen=True, eq=False)
class CalibrationTrial:
    """One simulated calibration.

    Attributes:
        p_true: The true parameters (n_p,) [SI].
        p_est: The identified parameters (n_p,) [SI].
        error_before: KPI error of the nominal model, (t, 3) [m].
        error_after: KPI error after calibration, (t, 3) [m].
        converged: Whether the estimator converged.
        rms: RMS of the fitted point residuals [m].
    """

    p_true: np.ndarray
    p_est: np.ndarray
    error_before: np.ndarray
    error_after: np.ndarray
    converged: bool
    rms: float


def simulate_calibration(
    problem,
    q: np.ndarray,
    rng: np.random.Generator | int,
) -> CalibrationTrial:
    """Run one simulated calibration of ``problem`` (a :class:`CalibrationProblem`) at design ``q``:
    a true robot of :func:`draw_true_parameters` (default deviations), measured and identified."""
    rng = np.random.default_rng(rng)
    space = problem.space
    free = problem.identifiability.free_indices
    p_true = draw_true_parameters(space, free, rng)
    blocks = simulate_observations(space, problem.models, q, p_true, rng)
    result = identify(space, blocks, free)
    s_true = problem.kpi.compute_values(space, p_true)
    before = problem.kpi.compute_values(space, None) - s_true
    after = problem.kpi.compute_values(space, result.p) - s_true
    return CalibrationTrial(p_true, np.asarray(result.p), before, after,
                            result.status.name == "CONVERGED", float(result.rms_mm) * 1e-3)
